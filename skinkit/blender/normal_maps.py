"""Bake Normal Maps in Blender: tangent-space normal maps of a LOD chain's levels (or any mesh), written with
OpenImageIO and wired into each level's material.

prepare_normal_maps reads, at the chosen frame (the pose; the scene's frame is restored), each target's evaluated
triangles in world space with its split normals and UV map, and the source: the chain's LOD0 (the atlas bake: the
same uv point is the correspondence) or any high-resolution object (the ray-cast bake within the cage).
NormalMapJob.solve() touches no Blender data; write() saves `<target>_normal.<ext>` in the output folder, loads
each image as non-colour data (packed into the .blend, or linked beside it), and gives every target's material an
Image Texture -> Normal Map (tangent space, on the target's UV map) -> the Principled BSDF's Normal. A material
that other objects share is copied for the target first, so each level shows its own map. Any failure removes the
files, images and materials it made and restores the material slots: the scene is left as it was.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from ..model import SkinkitError
from ..normal_maps import (CORRESPONDENCES, FORMATS, BakeSurface, NormalMap, bake_normals, mikktspace_tangents,
                           quantize, write_image)
from .frames import depsgraphs_at
from .lod_chain import REPORT_PROPERTY

IMAGE_NODE = "skinkit normal map image"
NORMAL_NODE = "skinkit normal map"
SUFFIX = "_normal"
#: A bake whose target texels miss the source more often than this is refused: the source does not cover it.
MAX_MISSED_FRACTION = 0.1


def read_surface(scene_object, depsgraph, uv_name: str | None = None, name: str = "target") -> tuple[BakeSurface, str]:
    """The evaluated mesh as a BakeSurface in world space (its loop triangles, split normals and UV map) and the
    UV map's name; uv None when the mesh has no UV map."""
    if scene_object.type != "MESH":
        raise SkinkitError(f"'{scene_object.name}' is a {scene_object.type.lower()}, not a mesh")
    evaluated = scene_object.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        mesh.calc_loop_triangles()
        triangle_count = len(mesh.loop_triangles)
        if triangle_count == 0:
            raise SkinkitError(f"'{scene_object.name}' has no faces")
        loops = np.empty(3 * triangle_count, np.int32)
        mesh.loop_triangles.foreach_get("loops", loops)
        corner_vertices = np.empty(len(mesh.loops), np.int32)
        mesh.loops.foreach_get("vertex_index", corner_vertices)
        positions = np.empty(3 * len(mesh.vertices), np.float32)
        mesh.vertices.foreach_get("co", positions)
        normals = np.empty(3 * len(mesh.loops), np.float32)
        mesh.corner_normals.foreach_get("vector", normals)
        layer = mesh.uv_layers.get(uv_name) if uv_name else (mesh.uv_layers.active if mesh.uv_layers else None)
        if uv_name and layer is None:
            raise SkinkitError(f"'{scene_object.name}' has no UV map '{uv_name}' (the source's atlas)")
        uv = None
        if layer is not None:
            uv = np.empty(2 * len(mesh.loops), np.float32)
            layer.uv.foreach_get("vector", uv)
            uv = uv.reshape(-1, 2)[loops].reshape(-1, 3, 2)
        matrix = np.array(scene_object.matrix_world, np.float64)
        world = positions.reshape(-1, 3) @ matrix[:3, :3].T + matrix[:3, 3]
        normal_matrix = np.linalg.inv(matrix[:3, :3]).T
        world_normals = normals.reshape(-1, 3)[loops] @ normal_matrix.T
        world_normals /= np.maximum(np.linalg.norm(world_normals, axis=1, keepdims=True), 1e-30)
        surface = BakeSurface.from_arrays(corner_vertices[loops].reshape(-1, 3), world, uv,
                                          world_normals.reshape(-1, 3, 3), name=f"{name} '{scene_object.name}'")
        return surface, (layer.name if layer is not None else None)
    finally:
        evaluated.to_mesh_clear()


def lod_chains() -> list:
    """The LOD chains in the file: collections Build LOD Chain made (they carry its report)."""
    return [c for c in bpy.data.collections if REPORT_PROPERTY in c]


def chain_levels(collection) -> list:
    """The chain's level objects, LOD0 first."""
    levels = [o for o in collection.objects if o.type == "MESH" and o.name.rsplit("_LOD", 1)[-1].isdigit()]
    return sorted(levels, key=lambda o: int(o.name.rsplit("_LOD", 1)[-1]))


def find_chain(name: str | None):
    """The chain called `name` (its collection or its source object's name), or the only chain in the file."""
    chains = lod_chains()
    if name is not None:
        found = [c for c in chains if name in (c.name, c[REPORT_PROPERTY].get("source"))]
        if not found:
            raise SkinkitError(f"no LOD chain named '{name}' (chains: "
                               f"{', '.join(repr(c.name) for c in chains) or 'none'})")
        return found[0]
    if len(chains) != 1:
        raise SkinkitError(f"the file has {len(chains)} LOD chains "
                           f"({', '.join(repr(c.name) for c in chains) or 'none'}); name one with --chain, or bake "
                           "one object with --object")
    return chains[0]


@dataclass
class NormalMapJob:
    """What the bake needs, read from the scene: solve() runs without Blender, write() adds the results."""
    mesh_object_name: str  # the first target: the operator checks it is still there
    target_names: list[str]
    uv_names: list[str]
    targets: list[BakeSurface]
    source: BakeSurface
    source_name: str
    options: dict
    out_dir: str
    image_format: str
    pack: bool
    frame: int
    tangents: list = field(default_factory=list)

    def solve(self, progress=None) -> list[NormalMap]:
        maps = []
        for index, target in enumerate(self.targets):
            def report(fraction, index=index):
                return bool(progress and progress((index + fraction) / len(self.targets)))

            tangents = mikktspace_tangents(target)
            result = bake_normals(target, self.source, tangents=tangents, progress=report, **self.options)
            covered = result.filled + result.missed
            if result.missed > MAX_MISSED_FRACTION * covered:
                raise SkinkitError(f"the source '{self.source_name}' does not cover '{self.target_names[index]}': "
                                   f"{result.missed} of its {covered} texels found no source (check the source, or "
                                   "raise the cage distance)")
            maps.append(result)
        return maps

    def write(self, mesh_object, solved: list[NormalMap], seconds: float = 0.0) -> dict:
        """Writes the images, loads them and wires the materials; undoes all of it on any failure."""
        created_files, created_images, undo_materials = [], [], []
        extension = FORMATS[self.image_format][1]
        try:
            rows = []
            for name, uv_name, result in zip(self.target_names, self.uv_names, solved):
                target_object = bpy.data.objects.get(name)
                if target_object is None:
                    raise SkinkitError(f"'{name}' is gone; nothing was written")
                path = os.path.join(self.out_dir, f"{bpy.path.clean_name(name)}{SUFFIX}{extension}")
                write_image(path, result.image, self.image_format)
                created_files.append(path)
                image = load_image(path, self.pack)
                created_images.append(image)
                wire_materials(target_object, image, uv_name, undo_materials)
                stored = quantize(result.image, self.image_format).astype(np.float64)
                if np.issubdtype(FORMATS[self.image_format][2], np.integer):
                    stored /= np.iinfo(FORMATS[self.image_format][2]).max
                mean, largest = result.angular_error(stored)
                rows.append({"object": name, "path": os.path.abspath(path), "image": image.name,
                             "size": int(result.image.shape[0]), "texels_filled": result.filled,
                             "texels_missed": result.missed, "texels_dilated": result.dilated,
                             "seconds": result.seconds, "mean_angular_error": mean, "max_angular_error": largest})
        except Exception:
            undo(created_files, created_images, undo_materials)
            raise
        return {"source": self.source_name, "mode": self.options["mode"], "frame": self.frame,
                "format": self.image_format, "packed": self.pack, "maps": rows, "seconds": float(seconds)}


def load_image(path: str, pack: bool):
    """The written file as a Blender image of non-colour data, packed into the .blend or linked to the file."""
    image = bpy.data.images.load(path, check_existing=False)
    image.colorspace_settings.name = "Non-Color"
    if pack:
        image.pack()
    return image


def wire_materials(target_object, image, uv_name: str, undo_materials: list) -> None:
    """Gives each of the target's materials (its own copy when shared; a new one when it has none) an Image Texture
    -> Normal Map -> Principled BSDF Normal chain on the target's UV map. Appends (mesh, slot, old material, made
    material) to undo_materials."""
    mesh = target_object.data
    if len(mesh.materials) == 0:
        material = bpy.data.materials.new(f"{target_object.name}{SUFFIX}")
        material.use_nodes = True
        mesh.materials.append(material)
        undo_materials.append((mesh, 0, None, material))
    for slot, material in enumerate(mesh.materials):
        if material is None:
            continue
        if material.users > 1:
            copy = material.copy()
            copy.name = f"{material.name}_{target_object.name}"
            mesh.materials[slot] = copy
            undo_materials.append((mesh, slot, material, copy))
            material = copy
        material.use_nodes = True
        add_normal_map_nodes(material, image, uv_name)


def add_normal_map_nodes(material, image, uv_name: str) -> None:
    tree = material.node_tree
    shader = next((n for n in tree.nodes if n.type == "BSDF_PRINCIPLED"), None)
    if shader is None:
        raise SkinkitError(f"material '{material.name}' has no Principled BSDF to take the normal map")
    texture = tree.nodes.get(IMAGE_NODE) or tree.nodes.new("ShaderNodeTexImage")
    texture.name = texture.label = IMAGE_NODE
    texture.image = image
    texture.location = (shader.location.x - 600, shader.location.y - 300)
    normal_map = tree.nodes.get(NORMAL_NODE) or tree.nodes.new("ShaderNodeNormalMap")
    normal_map.name = normal_map.label = NORMAL_NODE
    normal_map.space = "TANGENT"
    normal_map.uv_map = uv_name or ""
    normal_map.location = (shader.location.x - 250, shader.location.y - 300)
    tree.links.new(texture.outputs["Color"], normal_map.inputs["Color"])
    tree.links.new(normal_map.outputs["Normal"], shader.inputs["Normal"])


def undo(files, images, materials) -> None:
    for mesh, slot, old, made in reversed(materials):
        if old is None:
            mesh.materials.pop(index=slot)
        else:
            mesh.materials[slot] = old
        bpy.data.materials.remove(made)
    for image in images:
        bpy.data.images.remove(image)
    for path in files:
        if os.path.exists(path):
            os.remove(path)


def checked_bake_inputs(out_dir: str, targets) -> tuple[str, list]:
    """The bakes' output folder as an absolute path (it must exist and be writable) and their targets as a list
    (at least one)."""
    folder = os.path.abspath(out_dir)
    if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
        raise SkinkitError(f"{out_dir}: the output folder does not exist or is not writable")
    targets = list(targets)
    if not targets:
        raise SkinkitError("no target to bake")
    return folder, targets


def prepare_normal_maps(targets, source=None, *, correspondence: str = "guided", size: int = 1024, margin: int = 8,
                        samples: int = 2, cage: float | None = None, frame: int | None = None,
                        image_format: str = "png16", out_dir: str, pack: bool = True,
                        thread_count: int = 0) -> NormalMapJob:
    """Reads the targets (mesh objects) and the source at `frame` (default the current one). source None: the
    targets' chain's LOD0, by `correspondence` through the shared atlas: "guided" (the ray cast within `cage`
    where it agrees with the same uv point, skinkit.normal_maps' "guided" mode) or "atlas" (the same uv point
    only: the fastest); an object: the ray-cast bake from it. cage: default 5% of each target's diagonal."""
    if image_format not in FORMATS:
        raise SkinkitError(f"format: {image_format!r} is not one of {', '.join(FORMATS)}")
    if correspondence not in CORRESPONDENCES:
        raise SkinkitError(f"correspondence: {correspondence!r} is not one of {', '.join(CORRESPONDENCES)}")
    folder, targets = checked_bake_inputs(out_dir, targets)
    mode = "ray" if source is not None else correspondence
    if source is None:
        source = chain_source(targets[0])
        targets = [t for t in targets if t != source]
        if not targets:
            raise SkinkitError(f"'{source.name}' is its chain's LOD0: its map from itself would be flat; pick a "
                               "coarser level or a high-resolution source")
    scene = bpy.context.scene
    frame = scene.frame_current if frame is None else int(frame)
    for depsgraph in depsgraphs_at([frame]):
        surfaces = [read_surface(t, depsgraph) for t in targets]
        uv_name = surfaces[0][1] if mode != "ray" else None
        source_surface, _ = read_surface(source, depsgraph, uv_name, name="source")
    for target, (surface, uv) in zip(targets, surfaces):
        if uv is None:
            raise SkinkitError(f"'{target.name}' has no UV map: unwrap it (or build a LOD chain) first")
    options = {"size": int(size), "mode": mode, "supersample": int(samples), "margin": int(margin), "cage": cage,
               "thread_count": int(thread_count)}
    return NormalMapJob(targets[0].name, [t.name for t in targets], [s[1] for s in surfaces],
                        [s[0] for s in surfaces], source_surface, source.name, options, folder, image_format,
                        bool(pack), frame)


def chain_source(target):
    """The LOD0 of the chain the target belongs to."""
    for collection in target.users_collection:
        if REPORT_PROPERTY in collection:
            levels = chain_levels(collection)
            if levels:
                return levels[0]
    raise SkinkitError(f"'{target.name}' is in no LOD chain: choose a high-resolution source object to bake from")


def bake_normal_maps(targets, source=None, progress=None, **options) -> dict:
    """prepare -> solve -> write in one call (the CLI and scripts)."""
    started = time.perf_counter()
    job = prepare_normal_maps(targets, source, **options)
    solved = job.solve(progress)
    return job.write(bpy.data.objects[job.mesh_object_name], solved, time.perf_counter() - started)


# ---- tangent maps ----------------------------------------------------------------------------------------------------

@dataclass
class TangentMapJob:
    """What the tangent-map bake needs, read from the scene: solve() runs without Blender, write() writes the files
    (the scene is not changed either way)."""
    mesh_object_name: str  # the first target: the operator checks it is still there
    target_names: list[str]
    targets: list[BakeSurface]
    source: BakeSurface
    source_name: str
    model: object  # the AnimationSpaceModel over the source's vertices
    poses: np.ndarray  # the bones' frames at `frame`, for the object-space normal map
    statistics: object  # the rig's PoseStatistics in the model's space (the mip fit's metric), or None: Euclidean
    mip_fit: str  # how the mip chain is fitted, for the report
    options: dict  # size, tile, max_influences, mip_levels, thread_count
    out_dir: str
    image_format: str
    frame: int

    def solve(self, progress=None) -> list[dict]:
        """Per target its tangent map, the object-space normal map in the pose, the mip chain's next maps and the
        seconds; progress(fraction) returning True cancels, inside a map's bake (between batches of rows) or between
        the stages."""
        from ..normal_maps import bake_tangent_map

        steps = 3 * len(self.targets)
        options = dict(self.options)
        mip_levels, thread_count = options.pop("mip_levels"), options["thread_count"]

        def step(done: int) -> None:
            if progress is not None and progress(done / steps):
                raise SkinkitError(f"the tangent-map bake was cancelled after {done} of {steps} steps")

        def within_bake(index: int):
            # The bake is the first of a target's three steps: its fraction of rows fills that step.
            return None if progress is None else lambda fraction: bool(progress((3 * index + fraction) / steps))

        solved = []
        for index, target in enumerate(self.targets):
            started = time.perf_counter()
            tangent_map = bake_tangent_map(target, self.source, self.model, progress=within_bake(index), **options)
            step(3 * index + 1)
            normals = tangent_map.normal_map(self.poses, thread_count)
            step(3 * index + 2)
            mips = tangent_map.mip_chain(mip_levels, self.statistics, thread_count)[1:]
            solved.append({"map": tangent_map, "normals": normals, "mips": mips,
                           "seconds": time.perf_counter() - started})
            step(3 * index + 3)
        return solved

    def posed_faces(self) -> np.ndarray:
        """The source's unit face normals in the pose: what the object-space normal maps are measured against."""
        posed = self.model.evaluate(self.poses)[self.source.triangles]
        faces = np.cross(posed[:, 1] - posed[:, 0], posed[:, 2] - posed[:, 0])
        return faces / np.maximum(np.linalg.norm(faces, axis=1, keepdims=True), 1e-300)

    def write(self, mesh_object=None, solved: list[dict] = (), seconds: float = 0.0) -> dict:
        """Writes `<target>_tangent.exr`, `<target>_object_normal.png` and `<target>_tangent_mip<k>.exr` per target;
        on any failure removes the files written so far."""
        from ..normal_maps import write_tangent_map

        faces = self.posed_faces()
        written, rows = [], []
        try:
            for name, result in zip(self.target_names, solved):
                tangent_map, normals = result["map"], result["normals"]
                stem = os.path.join(self.out_dir, bpy.path.clean_name(name))
                written.append(write_tangent_map(f"{stem}_tangent.exr", tangent_map, self.image_format))
                written.append(write_image(f"{stem}_object_normal.png", normals, "png16"))
                mips = []
                for level, mip in enumerate(result["mips"], start=1):
                    mips.append(write_tangent_map(f"{stem}_tangent_mip{level}.exr", mip, self.image_format))
                    written.append(mips[-1])
                rows.append(tangent_map_row(name, stem, tangent_map, normals, faces, mips, result["seconds"]))
        except Exception:
            for path in written:
                if os.path.exists(path):
                    os.remove(path)
            raise
        return {"source": self.source_name, "frame": self.frame, "mip_fit": self.mip_fit, "maps": rows,
                "seconds": float(seconds)}


def tangent_map_row(name: str, stem: str, tangent_map, normals: np.ndarray, faces: np.ndarray, mips: list,
                    seconds: float) -> dict:
    """A target's report: its files, texels, tile influence counts and the object-space map's angular error
    (degrees, after 16-bit storage) against the posed source faces."""
    filled = tangent_map.coverage == 1
    decoded = 2.0 * quantize(normals, "png16")[filled] / 65535.0 - 1.0
    decoded /= np.maximum(np.linalg.norm(decoded, axis=1, keepdims=True), 1e-300)
    exact = faces[tangent_map.source_triangles[filled]]
    degrees = np.degrees(np.arccos(np.clip((decoded * exact).sum(1), -1.0, 1.0))) if filled.any() else np.zeros(1)
    tiles = tangent_map.tile_counts()
    return {"object": name, "path": f"{stem}_tangent.exr", "normal_map": f"{stem}_object_normal.png", "mips": mips,
            "size": int(tangent_map.counts.shape[0]), "tile": int(tangent_map.tile),
            "texels_filled": int(filled.sum()), "texels_missed": int((tangent_map.coverage == 2).sum()),
            "max_tile_influences": int(tiles.max(initial=0)),
            "mean_tile_influences": float(tiles[tiles > 0].mean()) if (tiles > 0).any() else 0.0,
            "seconds": seconds, "mean_angular_error": float(degrees.mean()), "max_angular_error": float(degrees.max())}


def prepare_tangent_maps(targets, *, size: int = 256, tile: int = 8, max_influences: int = 16,
                         frame: int | None = None, out_dir: str, image_format: str = "exr-float", mip_levels: int = 1,
                         thread_count: int = 0) -> TangentMapJob:
    """Reads the targets (levels of one LOD chain), the chain's LOD0 with its stored animation-space model and the
    armature's pose at `frame` (default the current one; the scene's frame is restored)."""
    from .rig import pose_matrices, rig_of
    from .storage import read_model

    if image_format not in ("exr", "exr-float"):
        raise SkinkitError(f"format: a tangent map is an EXR ('exr' half or 'exr-float'), not {image_format!r}")
    if int(mip_levels) < 1:
        raise SkinkitError(f"mip levels: {mip_levels} must be at least 1")
    folder, targets = checked_bake_inputs(out_dir, targets)
    source = chain_source(targets[0])
    stored = read_model(source.data, source.name)
    armature = rig_of(source).armature_object
    frame = bpy.context.scene.frame_current if frame is None else int(frame)
    for depsgraph in depsgraphs_at([frame]):
        source_surface, uv_name = read_surface(source, depsgraph, name="source")
        surfaces = [read_surface(t, depsgraph, uv_name)[0] for t in targets]
        poses = pose_matrices(armature, depsgraph, stored.bone_names, stored.bind)
    statistics, mip_fit = mip_metric(armature, source, stored, int(mip_levels))
    options = {"size": int(size), "tile": int(tile), "max_influences": int(max_influences),
               "mip_levels": int(mip_levels), "thread_count": int(thread_count)}
    return TangentMapJob(targets[0].name, [t.name for t in targets], surfaces, source_surface, source.name,
                         stored.model, poses, statistics, mip_fit, options, folder, image_format, frame)


def mip_metric(armature, source, stored, mip_levels: int):
    """The mip chain's metric (appendix A.1.2): the rig's pose statistics (stored on the armature, else from its
    action) in the model's space, and how the chain is fitted: "metric (stored)", "metric (action)", or
    "euclidean (...)" with the reason when the rig has neither (or no mip level is asked for)."""
    from . import pose_statistics

    if mip_levels < 2:
        return None, "none (one level)"
    try:
        statistics, origin = pose_statistics.stored_or_from_action(armature, source.name)
    except SkinkitError as error:
        return None, f"euclidean ({error})"
    if statistics.bone_count != len(stored.bone_names):
        return None, (f"euclidean (the statistics have {statistics.bone_count} bones, the model "
                      f"{len(stored.bone_names)})")
    return pose_statistics.in_mesh_space(statistics, stored.bind), f"metric ({origin})"


def bake_tangent_maps(targets, progress=None, **options) -> dict:
    """Tangent maps of the targets (levels of one LOD chain) from the animation-space model stored on the chain's
    LOD0, through the shared atlas, prepare -> solve -> write in one call (the CLI and scripts):
    `<target>_tangent.exr` (the tiles' influences, write_tangent_map) and the object-space normal map they give at
    `frame` (the armature's pose there; LOD0's local space), `<target>_object_normal.png`, with its angular error
    against the posed LOD0 faces; with mip_levels > 1 also the mip chain's next levels (appendix A.1 averaging in
    the metric of the rig's pose statistics, mip_metric), `<target>_tangent_mip<k>.exr`. Writes files only; on a
    failure the files written so far are removed."""
    started = time.perf_counter()
    job = prepare_tangent_maps(targets, **options)
    solved = job.solve(progress)
    return job.write(None, solved, time.perf_counter() - started)
