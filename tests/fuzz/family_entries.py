"""The fuzz entries of the families merged after the first fuzz pass: skinkit.handles, skinkit.skeleton (and its
submodules), skinkit.normal_maps, skinkit.runtime, skinkit.crowd and skinkit.batch. Their fixture objects are made
on first use (`Families`), so that a fuzz child builds only what its entry point needs."""
from __future__ import annotations

import functools
import os

import numpy as np

#: Public entry points left out of the fuzz pass: a valid call of each runs Blender (a subprocess per step) or
#: a Dask cluster, seconds per call.
NEEDS_BLENDER = {"batch.run_character", "batch.run_batch"}


class Families:
    """Small synthetic inputs for the new families, each made once, when first asked for."""

    def __init__(self, base):
        self.base = base  # the api_fuzz Fixture: its tube character, model and statistics

    @functools.cached_property
    def handle_model(self):
        from skinkit import handles

        return handles.train(self.base.frames, self.base.triangles, handle_vertices=[5, 60, 90], bones=2,
                             basis_count=3, threads=1)

    @functools.cached_property
    def triangle_hierarchy(self):
        from skinkit import handles

        return handles.triangle_hierarchy(self.base.frames[0], self.base.frames, self.base.triangles)

    @functools.cached_property
    def handle_file(self):
        path = os.path.join(self.base.folder, "handles.npz")
        self.handle_model.save(path)
        return path

    @functools.cached_property
    def sample(self):
        from skinkit.skeleton import chain_of_cylinders

        return chain_of_cylinders(parts=3, sides=6, rings_per_part=2)

    @functools.cached_property
    def bones(self):
        from skinkit.skeleton import extract_skeleton

        return extract_skeleton(self.sample.parts, "centroid", parents=self.sample.parents)

    @functools.cached_property
    def hierarchy(self):
        from skinkit.skeleton import Hierarchy, free_limits

        return Hierarchy(("a", "b", "c"), np.array([-1, 0, 1], np.int32), free_limits(3))

    @functools.cached_property
    def hierarchy_file(self):
        from skinkit.skeleton import write_hierarchy

        return write_hierarchy(os.path.join(self.base.folder, "rig.hier"), self.hierarchy)

    @functools.cached_property
    def groups_file(self):
        from skinkit.skeleton import write_obj_groups

        return write_obj_groups(os.path.join(self.base.folder, "groups.obj"), self.sample.parts)

    @functools.cached_property
    def dmat_file(self):
        path = os.path.join(self.base.folder, "labels.dmat")
        labels = self.sample.parts.vertex_parts()
        with open(path, "w") as file:
            file.write(f"1 {len(labels)}\n" + "\n".join(str(int(label)) for label in labels) + "\n")
        return path

    @functools.cached_property
    def clip(self):
        from skinkit.skeleton.animation import Channel, Keyframes

        channel = Channel(np.array([0.0, 5.0, 10.0]), np.array([0.0, 0.3, 0.0]), ["linear", "smooth", "linear"],
                          ["linear", "smooth", "linear"])
        return Keyframes(0.0, 10.0, {4: channel})

    @functools.cached_property
    def clip_file(self):
        from skinkit.skeleton.animation import write_keyframes

        return write_keyframes(os.path.join(self.base.folder, "swing.clip"), self.clip)

    @functools.cached_property
    def world(self):
        from skinkit.skeleton.animation import pose

        return pose(self.bones, np.zeros((3, 3)))

    @functools.cached_property
    def seam_mesh(self):
        from skinkit.skeleton.seams import prepare_seams

        return prepare_seams(self.sample.parts, self.bones, 2)

    @functools.cached_property
    def plane(self):
        """A 3 x 3 grid on the unit square: triangles, positions and per-corner uv."""
        xs = np.linspace(0.0, 1.0, 4)
        x, y = np.meshgrid(xs, xs)
        positions = np.stack([x, y, 0.05 * np.sin(3 * x) * y], -1).reshape(-1, 3)
        index = np.arange(16).reshape(4, 4)
        a, b, c, d = index[:-1, :-1], index[:-1, 1:], index[1:, 1:], index[1:, :-1]
        triangles = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                                    np.stack([a, c, d], -1).reshape(-1, 3)]).astype(np.int32)
        return triangles, positions, positions[:, :2][triangles]

    @functools.cached_property
    def surface(self):
        from skinkit.normal_maps import BakeSurface

        return BakeSurface.from_arrays(*self.plane)

    @functools.cached_property
    def plane_model(self):
        import skinkit

        positions = self.plane[1]
        rest_frames = np.stack([np.eye(4), np.eye(4)])
        rest_frames[1, :3, 3] = (0.5, 0.0, 0.0)
        skeleton = skinkit.Skeleton.create(np.array([-1, 0], np.int32), rest_frames)
        child = np.clip((positions[:, 0] - 0.3) / 0.4, 0.0, 1.0)
        weights = skinkit.SparseWeights.from_dense(np.stack([1 - child, child], axis=1))
        return skinkit.convert_lbs(skeleton, weights, positions)

    @functools.cached_property
    def normal_map(self):
        from skinkit.normal_maps import bake_normals

        return bake_normals(self.surface, self.surface, size=8, margin=1, thread_count=1)

    @functools.cached_property
    def tangent_map(self):
        from skinkit.normal_maps import bake_tangent_map

        return bake_tangent_map(self.surface, self.surface, self.plane_model, size=8, tile=4, max_influences=2,
                                thread_count=1)

    @functools.cached_property
    def image_file(self):
        from skinkit.normal_maps import write_image

        return write_image(os.path.join(self.base.folder, "map.png"), np.full((4, 4, 3), 0.5), "png8")

    @functools.cached_property
    def pack(self):
        from skinkit.runtime import RuntimePack

        return RuntimePack.from_chain(self.base.chain)

    @functools.cached_property
    def skin_result(self):
        from skinkit.runtime import skin

        return skin(self.pack, np.zeros(2, np.int32), np.zeros(2, np.float32), self.runtime_poses, threads=1)

    @functools.cached_property
    def runtime_poses(self):
        return np.ascontiguousarray(np.broadcast_to(self.base.poses[1], (2, 3, 4, 4)))

    @functools.cached_property
    def character(self):
        from skinkit import crowd

        return crowd.tube_character(200, bones=3, influences=2, levels=2, seed=1)

    @functools.cached_property
    def crowd(self):
        from skinkit import crowd

        return crowd.random_crowd(3, (200, 300), kinds=1, bones=3, influences=2, levels=2, extent=5.0, seed=2)

    @functools.cached_property
    def camera(self):
        from skinkit import crowd

        return crowd.look_camera([-10.0, -10.0, 1.7], [0.0, 0.0, 0.9])

    @functools.cached_property
    def jobs_file(self):
        path = os.path.join(self.base.folder, "jobs.toml")
        with open(path, "w") as file:
            file.write('retries = 1\nout = "out"\n[[character]]\nname = "tube"\n'
                       f'input = "{self.base.obj}"\n[[character.step]]\ncommand = "convert"\n'
                       'output = "tube.blend"\n')
        return path

    @functools.cached_property
    def batch_character(self):
        from skinkit.batch import load_jobs

        return load_jobs(self.jobs_file)[0]


def entries() -> dict:
    """Each entry: the public name, and how to make a valid call of it on the fixture `f` (f.families: Families)."""
    from skinkit import batch, crowd, handles, normal_maps, runtime, skeleton
    from skinkit.handles import HandleModel
    from skinkit.normal_maps import BakeSurface
    from skinkit.runtime import RuntimePack
    from skinkit.skeleton import animation, seams
    from skinkit.skeleton import Skeleton as BoneSkeleton

    def g(f):
        return f.families

    from skinkit import lod

    return {
        # skinkit.lod: Limit Influences in the sampled metric (issue 11)
        "lod.choose_sample_weight": lambda f: (lod.choose_sample_weight, dict(
            model=f.model, parents=f.parents, poses=f.poses, max_influences=1, threads=1)),
        "lod.sampled_metric": lambda f: (lod.sampled_metric, dict(poses=f.poses)),
        # skinkit.handles
        "handles.train": lambda f: (handles.train, dict(
            frames=f.frames, triangles=f.triangles, handle_vertices=[5, 60, 90], handle_count=None, bones=2,
            bone_counts=None, clustering="hierarchical", kernel="gaussian", basis_count=3, ridge=1e-3, beta=1.0, poisson=False, dqs_weights=True, validate=False,
            rest=None, max_influences=2,
            seed=0, threads=1, progress=f.progress)),
        "handles.triangle_hierarchy": lambda f: (handles.triangle_hierarchy, dict(
            rest=f.frames[0], frames=f.frames, triangles=f.triangles, edge_weight=1.0, progress=f.progress)),
        "TriangleHierarchy.labels": lambda f: (g(f).triangle_hierarchy.labels, dict(cluster_count=3)),
        "handles.suggest_handles": lambda f: (handles.suggest_handles, dict(frames=f.frames, count=3)),
        "handles.load": lambda f: (handles.load, dict(path=g(f).handle_file)),
        "HandleModel.handle_positions_of": lambda f: (g(f).handle_model.handle_positions_of, dict(frames=f.frames)),
        "HandleModel.predict_bones": lambda f: (g(f).handle_model.predict_bones, dict(
            handle_positions=f.frames[:2, [5, 60, 90]])),
        "HandleModel.skin": lambda f: (g(f).handle_model.skin, dict(
            dual_quaternions=np.tile([1.0, 0, 0, 0, 0, 0, 0, 0], (2, 1)), threads=1)),
        "HandleModel.predict": lambda f: (g(f).handle_model.predict, dict(handle_positions=f.frames[1, [5, 60, 90]],
                                                                          threads=1)),
        "HandleModel.arrays": lambda f: (g(f).handle_model.arrays, {}),
        "HandleModel.save": lambda f: (g(f).handle_model.save, dict(path=f.out + ".npz")),
        "HandleModel.from_arrays": lambda f: (HandleModel.from_arrays, dict(stored=g(f).handle_model.arrays())),
        # skinkit.skeleton
        "Skeleton.joints": lambda f: (g(f).bones.joints, {}),
        "Skeleton.part_report": lambda f: (g(f).bones.part_report, {}),
        "Skeleton.to_dict": lambda f: (g(f).bones.to_dict, {}),
        "Skeleton.from_dict": lambda f: (BoneSkeleton.from_dict, dict(data=g(f).bones.to_dict())),
        "Skeleton.bone_tails": lambda f: (g(f).bones.bone_tails, {}),
        "extract.extract_skeleton": lambda f: (skeleton.extract_skeleton, dict(
            parts=g(f).sample.parts, method="principal-axis", parents=g(f).sample.parents, refine=False,
            refine_parent=None, max_angle=20.0, closeness=0.25)),
        "Hierarchy.reordered": lambda f: (g(f).hierarchy.reordered, dict(names=["c", "a", "b"])),
        "hierarchy.free_limits": lambda f: (skeleton.free_limits, dict(count=3)),
        "hierarchy.read_hierarchy": lambda f: (skeleton.read_hierarchy, dict(path=g(f).hierarchy_file)),
        "hierarchy.write_hierarchy": lambda f: (skeleton.write_hierarchy, dict(path=f.out + ".hier",
                                                                               hierarchy=g(f).hierarchy)),
        "hierarchy.write_bvh": lambda f: (skeleton.write_bvh, dict(path=f.out + ".bvh", skeleton=g(f).bones)),
        "Parts.vertex_parts": lambda f: (g(f).sample.parts.vertex_parts, {}),
        "parts.compact": lambda f: (skeleton.parts.compact, dict(labels=np.array([2, 2, 0, 1]),
                                                                 names=["x", "y", "z"])),
        "parts.from_vertex_labels": lambda f: (skeleton.from_vertex_labels, dict(
            positions=g(f).sample.parts.positions, triangles=g(f).sample.parts.triangles,
            vertex_labels=g(f).sample.parts.vertex_parts(), names=None)),
        "parts.from_weights": lambda f: (skeleton.from_weights, dict(
            positions=f.rest, triangles=f.triangles, weights=f.dense, names=("a", "b", "c"))),
        "parts.loose_parts": lambda f: (skeleton.loose_parts, dict(positions=f.rest, triangles=f.triangles,
                                                                   tolerance=1e-6)),
        "parts.read_dmat": lambda f: (skeleton.read_dmat, dict(path=g(f).dmat_file)),
        "parts.read_obj_groups": lambda f: (skeleton.read_obj_groups, dict(path=g(f).groups_file, key="groups")),
        "parts.write_obj_groups": lambda f: (skeleton.write_obj_groups, dict(path=f.out + "-groups.obj",
                                                                             parts=g(f).sample.parts)),
        "samples.chain_of_cylinders": lambda f: (skeleton.chain_of_cylinders, dict(
            parts=2, length=2.0, radius=0.5, sides=5, rings_per_part=2)),
        "samples.star_of_limbs": lambda f: (skeleton.star_of_limbs, dict(limb_length=2.0, rings=2)),
        "Channel.slopes": lambda f: (g(f).clip.channels[4].slopes, {}),
        "Channel.evaluate": lambda f: (g(f).clip.channels[4].evaluate, dict(times=np.linspace(-1.0, 11.0, 5))),
        "Keyframes.angles": lambda f: (g(f).clip.angles, dict(time=2.5, part_count=3)),
        "animation.read_keyframes": lambda f: (animation.read_keyframes, dict(path=g(f).clip_file)),
        "animation.write_keyframes": lambda f: (animation.write_keyframes, dict(path=f.out + ".clip",
                                                                                clip=g(f).clip)),
        "animation.joint_frame": lambda f: (animation.joint_frame, dict(skeleton=g(f).bones)),
        "animation.pose": lambda f: (animation.pose, dict(skeleton=g(f).bones, angles=np.full((3, 3), 0.1),
                                                          root_frame=np.eye(4))),
        "animation.collisions": lambda f: (animation.collisions, dict(skeleton=g(f).bones, world=g(f).world)),
        "animation.collision_candidates": lambda f: (animation.collision_candidates, dict(skeleton=g(f).bones,
                                                                                          moved_part=1)),
        "animation.find_collisions": lambda f: (animation.find_collisions, dict(
            skeleton=g(f).bones, world=g(f).world, candidates=np.array([[1, 2]]), first_only=True)),
        "animation.animate": lambda f: (animation.animate, dict(
            skeleton=g(f).bones, clip=g(f).clip, times=np.linspace(0.0, 10.0, 3), limits=None,
            check_collisions=True)),
        "SeamMesh.positions": lambda f: (g(f).seam_mesh.positions, dict(world=g(f).world)),
        "SeamMesh.reconstruct": lambda f: (g(f).seam_mesh.reconstruct, dict(world=g(f).world, remove_sinking=True,
                                                                            arcs="conic")),
        "SeamMesh.reconstruct_sequence": lambda f: (g(f).seam_mesh.reconstruct_sequence, dict(
            worlds=np.stack([g(f).world, g(f).world]), remove_sinking=True, arcs="qlerp", progress=None)),
        "seams.conic_arc": lambda f: (seams.conic_arc, dict(start=np.zeros(3), start_tangent=np.array([1.0, 2.5, 0.0]),
                                                            end=np.array([3.0, 1.0, 0.0]),
                                                            end_tangent=np.array([-2.0, 1.5, 0.0]),
                                                            through=np.array([1.3, 1.2, 0.0]), count=5)),
        "seams.prepare_seams": lambda f: (seams.prepare_seams, dict(parts=g(f).sample.parts, skeleton=g(f).bones,
                                                                    steps=2)),
        "seams.prepare_seams_for_rig": lambda f: (seams.prepare_seams_for_rig, dict(
            parts=g(f).sample.parts, parents=g(f).bones.part_parents, joints=animation.joint_frame(g(f).bones)[0], steps=2)),
        "seams.boundary_edges": lambda f: (seams.boundary_edges, dict(triangles=f.triangles)),
        "seams.is_consistently_oriented": lambda f: (seams.is_consistently_oriented, dict(triangles=f.triangles)),
        "seams.vertex_normals": lambda f: (seams.vertex_normals, dict(positions=f.rest, triangles=f.triangles)),
        # skinkit.normal_maps
        "BakeSurface.from_arrays": lambda f: (BakeSurface.from_arrays, dict(
            triangles=g(f).plane[0], positions=g(f).plane[1], uv=g(f).plane[2], normals=None, name="plane")),
        "NormalMap.angular_error": lambda f: (g(f).normal_map.angular_error, dict(image=g(f).normal_map.image)),
        "normal_maps.mikktspace_tangents": lambda f: (normal_maps.mikktspace_tangents, dict(surface=g(f).surface)),
        "normal_maps.bake_normals": lambda f: (normal_maps.bake_normals, dict(
            target=g(f).surface, source=g(f).surface, size=8, mode="atlas", supersample=1, margin=1, cage=None,
            tangents=None, thread_count=1, progress=f.progress)),
        "normal_maps.angular_error": lambda f: (normal_maps.angular_error, dict(
            image=g(f).normal_map.image, frames=g(f).normal_map.frames, exact=g(f).normal_map.exact,
            mask=g(f).normal_map.coverage == 1)),
        "normal_maps.quantize": lambda f: (normal_maps.quantize, dict(image=np.full((4, 4, 3), 0.5), format="png16")),
        "normal_maps.write_image": lambda f: (normal_maps.write_image, dict(
            path=f.out + ".png", image=np.full((4, 4, 3), 0.5), format="png8")),
        "normal_maps.read_image": lambda f: (normal_maps.read_image, dict(path=g(f).image_file)),
        "TangentMap.tile_counts": lambda f: (g(f).tangent_map.tile_counts, {}),
        "TangentMap.padded_counts": lambda f: (g(f).tangent_map.padded_counts, {}),
        "TangentMap.normal_map": lambda f: (g(f).tangent_map.normal_map, dict(
            poses=np.tile(np.eye(4), (2, 1, 1)), thread_count=1)),
        "TangentMap.downsample": lambda f: (g(f).tangent_map.downsample, dict(thread_count=1)),
        "TangentMap.mip_chain": lambda f: (g(f).tangent_map.mip_chain, dict(levels=2, thread_count=1)),
        "normal_maps.bake_tangent_map": lambda f: (normal_maps.bake_tangent_map, dict(
            target=g(f).surface, source=g(f).surface, model=g(f).plane_model, size=8, tile=4, max_influences=2,
            thread_count=1)),
        "normal_maps.write_tangent_map": lambda f: (normal_maps.write_tangent_map, dict(
            path=f.out + ".exr", tangent_map=g(f).tangent_map, format="exr-float")),
        # skinkit.runtime
        "runtime.available_kernels": lambda f: (runtime.available_kernels, {}),
        "runtime.frustum_planes": lambda f: (runtime.frustum_planes, dict(view_projection=g(f).camera.view_projection)),
        "runtime.cull": lambda f: (runtime.cull, dict(spheres=np.array([[0.0, 0, 0, 1], [0, 0, -50, 1]]),
                                                      planes=runtime.frustum_planes(g(f).camera.view_projection))),
        "runtime.select_levels": lambda f: (runtime.select_levels, dict(
            spheres=np.array([[0.0, 0, 0, 1], [5, 5, 0, 1]]), epsilons=np.array([0.0, 0.01, 0.1]),
            position=np.array([-10.0, -10.0, 1.7]), forward=g(f).camera.forward, horizontal_fov=1.0,
            viewport_width=1920.0, pixel_tolerance=1.0)),
        "runtime.morph_uv": lambda f: (runtime.morph_uv, dict(uv_morph=np.zeros((4, 4)), fraction=0.5)),
        "runtime.culling_sphere": lambda f: (runtime.culling_sphere, dict(model=f.model, statistics=f.statistics,
                                                                          centre_statistics=None)),
        "runtime.bone_matrices": lambda f: (runtime.bone_matrices, dict(poses=f.poses)),
        "RuntimePack.influence_counts": lambda f: (g(f).pack.influence_counts, {}),
        "RuntimePack.from_meshes": lambda f: (RuntimePack.from_meshes, dict(
            meshes=[{"offsets": f.model.offsets, "bones": f.model.bones, "coordinates": f.model.coordinates}],
            bone_count=3, epsilons=[0.0])),
        "RuntimePack.from_model": lambda f: (RuntimePack.from_model, dict(model=f.model, tangents=None)),
        "RuntimePack.from_chain": lambda f: (RuntimePack.from_chain, dict(chain=f.chain)),
        "RuntimePack.level_epsilons": lambda f: (g(f).pack.level_epsilons, {}),
        "RuntimePack.draw": lambda f: (g(f).pack.draw, dict(levels=np.array([0.0, 0.5]), poses=f.poses[1],
                                                           tangents=False, kernel="scalar", threads=1)),
        "SkinResult.instance": lambda f: (g(f).skin_result.instance, dict(index=1)),
        "RuntimePack.fixed": lambda f: (g(f).pack.fixed, dict(morphs=None)),
        "RuntimePack.fixed_layout_problem": lambda f: (g(f).pack.fixed_layout_problem, {}),
        "FixedPack.level_epsilons": lambda f: (g(f).pack.fixed().level_epsilons, {}),
        "FixedPack.draw": lambda f: (g(f).pack.fixed().draw, dict(levels=np.array([0.0, 0.5]), poses=f.poses[1],
                                                                  tangents=False, kernel="scalar", threads=1)),
        "runtime.skin": lambda f: (runtime.skin, dict(
            pack=g(f).pack, meshes=np.array([0, 1], np.int32), fractions=np.array([0.5, 0.0], np.float32),
            poses=g(f).runtime_poses, tangents=False, kernel="scalar", threads=1, out=None)),
        # skinkit.crowd
        "crowd.tube_character": lambda f: (crowd.tube_character, dict(vertices=200, bones=3, influences=2, levels=2,
                                                                      seed=0)),
        "Crowd.spheres": lambda f: (g(f).crowd.spheres, {}),
        "Crowd.epsilons": lambda f: (g(f).crowd.epsilons, {}),
        "Crowd.matrices": lambda f: (g(f).crowd.matrices, dict(
            poses=[np.tile(np.eye(4), (3, 1, 1)) for _ in range(g(f).crowd.instance_count)])),
        "crowd.random_crowd": lambda f: (crowd.random_crowd, dict(
            count=2, vertex_range=(200, 300), kinds=1, bones=3, influences=2, levels=2, extent=5.0, seed=0)),
        "Camera.pixels": lambda f: (g(f).camera.pixels, dict(points=np.zeros((2, 3)))),
        "crowd.look_camera": lambda f: (crowd.look_camera, dict(
            position=[-10.0, -10.0, 1.7], target=[0.0, 0.0, 0.9], horizontal_fov=1.0, width=640, height=480,
            near=0.1, far=100.0)),
        "crowd.random_camera": lambda f: (crowd.random_camera, dict(rng=np.random.default_rng(0), extent=5.0)),
        "crowd.plan_frame": lambda f: (crowd.plan_frame, dict(crowd=g(f).crowd, camera=g(f).camera,
                                                              pixel_tolerance=1.0, spheres=None, epsilons=None)),
        "crowd.measure_crowd": lambda f: (crowd.measure_crowd, dict(
            crowd=g(f).crowd, cameras=[g(f).camera], pixel_tolerance=1.0, kernel="scalar", threads=1, repeats=1,
            seed=0, best=False, layout="fixed")),
        "crowd.timed_seconds": lambda f: (crowd.timed_seconds, dict(call=lambda: None, repeats=1, best=False)),
        "crowd.synthetic_mesh": lambda f: (crowd.synthetic_mesh, dict(vertices=50, influences=2, bones=4, seed=0)),
        "crowd.skin_seconds": lambda f: (crowd.skin_seconds, dict(
            pack=g(f).pack, instances=2, kernel="scalar", threads=1, repeats=1, seed=0, best=False, fraction=0.5,
            tangents=False)),
        "crowd.bytes_moved": lambda f: (crowd.bytes_moved, dict(vertices=100, influences=4)),
        "crowd.fixed_bytes_moved": lambda f: (crowd.fixed_bytes_moved, dict(vertices=100, slots=4, floats_per_slot=8,
                                                                             streams=1)),
        "crowd.triad_bandwidth": lambda f: (crowd.triad_bandwidth, dict(elements=1000, threads=1, repeats=1)),
        # skinkit.batch (run_character and run_batch: NEEDS_BLENDER)
        "batch.load_jobs": lambda f: (batch.load_jobs, dict(path=g(f).jobs_file)),
        "batch.is_current": lambda f: (batch.is_current, dict(character=g(f).batch_character, expected=None)),
    }
