"""Level of detail in Blender: Limit Influences and Subdivide Model, each writing a NEW object (the source is never
changed): `<name>_limited` and `<name>_subdivided`, with the model stored on their mesh, vertex groups and an
Armature modifier on the same armature.

prepare_* reads the scene (the stored model, or the Armature modifier's skinning converted in memory; pose
statistics stored on the armature, or computed from its action), Job.solve() touches no Blender data (any thread;
progress(fraction) may return True to cancel), write() adds the new object last, so a failure or a cancel leaves
the scene as it was.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import bpy
import numpy as np

from ..fit import DEFAULT_MAX_INFLUENCES
from ..lod.influences import choose_sample_weight, limit_influences, limit_total, nearest_linear_blend
from ..model import AnimationSpaceModel, Skeleton, SkinkitError, SparseWeights, convert_lbs
from ..subdivide import BOUNDARIES, SCHEMES, UV_SMOOTHING, subdivide, subdivided_model
from . import pose_statistics, storage
from .attributes import flatten_report, write_bone_groups
from .frames import action_frames, poses_at
from .rig import bind_matrix, bone_names, deform_weights, rest_positions, rig_of, skeleton_of
from .scene import named, naming
from .skinning import baked_copy, bounding_box_diagonal

LIMITED_SUFFIX = "_limited"
SUBDIVIDED_SUFFIX = "_subdivided"
REPORT_PROPERTY = "skinkit_lod_report"


@dataclass
class Source:
    """A skinned mesh's model as the LOD operations read it."""

    model: AnimationSpaceModel
    skeleton: Skeleton       # rest frames in mesh space, with the model's bind
    weights: SparseWeights   # its vertex groups as the Armature modifier applies them
    rest: np.ndarray         # (V, 3) the mesh's own positions
    bind: np.ndarray
    armature_name: str
    converted: bool          # True: no stored model, the Armature modifier's skinning converted in memory


def read_source(mesh_object) -> Source:
    """The model every LOD operation (Limit Influences, Subdivide Model, Build LOD Chain) starts from: the stored
    animation-space model, checked against the rig, or the Armature modifier's skinning converted in memory."""
    with naming(mesh_object):
        rig = rig_of(mesh_object)
        names = bone_names(rig.armature_object)
        if storage.has_model(mesh_object.data):
            stored = storage.read_model(mesh_object.data, mesh_object.name)
            if stored.armature_name != rig.armature_object.name:
                raise SkinkitError(f"'{mesh_object.name}': its model was bound to '{stored.armature_name}', its "
                                   f"Armature modifier uses '{rig.armature_object.name}'")
            if stored.bone_names != names:
                raise SkinkitError(f"'{mesh_object.name}': its model's bones differ from armature "
                                   f"'{rig.armature_object.name}''s; convert it again")
            model, bind, converted = stored.model, stored.bind, False
        else:
            bind = bind_matrix(rig, bpy.context.evaluated_depsgraph_get())
            model, converted = None, True
        skeleton = skeleton_of(rig, bind)
        weights = deform_weights(rig, ignore_unmatched_groups=True)
        rest = rest_positions(mesh_object)
        if model is None:
            model = convert_lbs(skeleton, weights, rest)
        return Source(model, skeleton, weights, rest, bind, rig.armature_object.name, converted)


def armature_action_frames(armature) -> list[int] | None:
    action = armature.animation_data.action if armature.animation_data else None
    return None if action is None else list(action_frames(action))


def statistics_of(mesh_object, source: Source):
    """The pose statistics stored on the armature, else those of its action's frames, in the mesh's space."""
    statistics, _ = pose_statistics.stored_or_from_action(bpy.data.objects[source.armature_name], mesh_object.name)
    return pose_statistics.in_mesh_space(statistics, source.bind)


def animated_error(positions: np.ndarray, reference: np.ndarray, diagonal: float) -> dict:
    """rms and max distance over frames and vertices, as fractions of the rest diagonal."""
    distance = np.linalg.norm(positions - reference, axis=-1)
    return {"rms": float(np.sqrt(np.mean(distance ** 2))) / diagonal, "max": float(distance.max(initial=0)) / diagonal}


# ---- Limit Influences -------------------------------------------------------------------------------------------


@dataclass
class LimitJob:
    mesh_object_name: str
    source: Source
    statistics: object
    poses: np.ndarray  # (F, b, 4, 4) the frames the error is measured on
    frames: list
    max_influences: int
    sampled_poses: np.ndarray | None = None  # (S, b, 4, 4): the action's frames, for the sampled metric

    def solve(self, progress=None) -> dict:
        started = time.perf_counter()
        source, K = self.source, self.max_influences
        with named(self.mesh_object_name):
            sample_weight = None
            if self.sampled_poses is not None:
                sample_weight, _ = choose_sample_weight(source.model, self.statistics.parents, self.sampled_poses, K)
            limited, costs = limit_influences(source.model, self.statistics, K, progress=progress,
                                              poses=self.sampled_poses, sample_weight=sample_weight)
            blend = nearest_linear_blend(limited, self.statistics, source.skeleton.rest_frames, source.rest)
            seconds = time.perf_counter() - started
            totals = limit_total(source.weights, K)
        report = {"object": self.mesh_object_name, "vertices": source.model.vertex_count, "max_influences": K,
                  "influences_before": {"total": source.model.influence_count,
                                        "max": int(source.model.counts().max(initial=0)),
                                        "mean": float(source.model.counts().mean())},
                  "influences_after": {"total": limited.influence_count, "max": int(limited.counts().max(initial=0)),
                                       "mean": float(limited.counts().mean())},
                  "converted_in_memory": source.converted, "frames": len(self.frames), "seconds": seconds,
                  "cost_max": float(costs.max(initial=0)), "sample_weight": sample_weight}
        if len(self.poses):
            diagonal = bounding_box_diagonal(source.rest) or 1.0
            reference = source.model.evaluate(self.poses)
            report["error"] = {
                "skinkit": animated_error(limited.evaluate(self.poses), reference, diagonal),
                "skinkit_linear_blend": animated_error(
                    convert_lbs(source.skeleton, blend, source.rest).evaluate(self.poses), reference, diagonal),
                "limit_total": animated_error(
                    convert_lbs(source.skeleton, totals, source.rest).evaluate(self.poses), reference, diagonal)}
            limit = report["error"]["limit_total"]["rms"]
            report["error"]["ratio"] = report["error"]["skinkit"]["rms"] / limit if limit > 0 else None
        return {"model": limited, "weights": blend, "report": report}

    def write(self, mesh_object, solved) -> object:
        """The new object `<name>_limited`; returns it."""
        with naming(mesh_object):
            if mesh_object.name != self.mesh_object_name or len(mesh_object.data.vertices) != \
                    self.source.model.vertex_count:
                raise SkinkitError("the mesh changed while its influences were being limited; nothing was written")
        copy = skinned_copy(mesh_object, LIMITED_SUFFIX, bpy.data.objects[self.source.armature_name])
        write_result(copy, solved["model"], solved["weights"], self.source, solved["report"])
        return copy


def prepare_limit(mesh_object, max_influences: int = DEFAULT_MAX_INFLUENCES, frames=None,
                  sampled_metric: bool = False) -> LimitJob:
    """frames: where the animated error is measured (default the armature's action; none without one).
    sampled_metric: the metric also takes the action's frames themselves (limit_influences' poses: their exact
    least-squares metric, blended with the statistics by validation on those frames)."""
    if isinstance(max_influences, bool) or not isinstance(max_influences, (int, np.integer)) or max_influences < 1:
        raise SkinkitError(f"max_influences must be a whole number of at least 1, not {max_influences!r}")
    source = read_source(mesh_object)
    with naming(mesh_object):
        statistics = statistics_of(mesh_object, source)
        armature = bpy.data.objects[source.armature_name]
        frames = list(frames) if frames is not None else (armature_action_frames(armature) or [])
        poses = poses_at(armature, frames, list(source.skeleton.names), source.bind) if frames else \
            np.zeros((0, source.model.bone_count, 4, 4))
        sampled = None
        if sampled_metric:
            action_frames = armature_action_frames(armature)
            if not action_frames:
                raise SkinkitError(f"the sampled metric needs armature '{armature.name}' to have an action")
            sampled = poses_at(armature, action_frames, list(source.skeleton.names), source.bind)
    return LimitJob(mesh_object.name, source, statistics, poses, frames, int(max_influences), sampled)


def limit_object(mesh_object, max_influences: int = DEFAULT_MAX_INFLUENCES, frames=None, progress=None,
                 sampled_metric: bool = False):
    """Prepare, solve, write on this thread: (the new object, the report)."""
    job = prepare_limit(mesh_object, max_influences, frames, sampled_metric)
    solved = job.solve(progress)
    return job.write(mesh_object, solved), solved["report"]


# ---- writing ----------------------------------------------------------------------------------------------------


def skinned_copy(mesh_object, suffix: str, armature, mesh=None):
    """A new object (with a copy of the mesh, or `mesh`) placed like the source, its only modifier an Armature
    modifier on `armature` with the source's settings; no stored model."""
    copy = baked_copy(mesh_object, suffix, mesh)
    original = rig_of(mesh_object).modifier
    modifier = copy.modifiers.new(original.name, "ARMATURE")
    modifier.object = armature
    modifier.use_deform_preserve_volume = original.use_deform_preserve_volume
    return copy


def write_result(copy, model, weights, source: Source, report: dict) -> None:
    names = list(source.skeleton.names)
    write_bone_groups(copy, weights, names)
    storage.write_model(copy.data, model, names, source.armature_name, source.bind)
    copy.data[REPORT_PROPERTY] = flatten_report(report)
    copy.data.update()


# ---- Subdivide Model ------------------------------------------------------------------------------------------


def mesh_polygons(mesh):
    """(offsets, corner vertices, material per polygon, smooth per polygon)."""
    count = len(mesh.polygons)
    starts = np.empty(count, np.int32)
    mesh.polygons.foreach_get("loop_start", starts)
    corners = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    materials = np.empty(count, np.int32)
    mesh.polygons.foreach_get("material_index", materials)
    smooth = np.empty(count, bool)
    mesh.polygons.foreach_get("use_smooth", smooth)
    order = np.argsort(starts, kind="stable")
    if not np.array_equal(order, np.arange(count)):  # Blender keeps polygons in loop order; be safe
        raise SkinkitError(f"mesh '{mesh.name}': polygons are not in loop order")
    return np.append(starts, len(mesh.loops)).astype(np.int32), corners, materials, smooth


@dataclass
class SubdivideJob:
    mesh_object_name: str
    source: Source
    polygons: tuple
    materials: np.ndarray
    smooth: np.ndarray
    uv: np.ndarray | None
    uv_name: str | None
    options: dict

    def solve(self, progress=None) -> dict:
        started = time.perf_counter()
        with named(self.mesh_object_name):
            result = subdivide(self.polygons, self.source.model, uv=self.uv, progress=progress, **self.options)
            positions = result.apply(self.source.rest)
            weights = self.source.weights
            as_model = AnimationSpaceModel(weights.offsets, weights.bones,
                                           np.column_stack([weights.weights, np.zeros((weights.influence_count, 3))]),
                                           self.source.model.bone_count)
            for stencils in result.levels:
                as_model = subdivided_model(stencils, as_model)
            blend = SparseWeights(as_model.offsets, as_model.bones, as_model.coordinates[:, 0].copy())
        report = {"object": self.mesh_object_name, "levels": self.options["levels"], "scheme": self.options["scheme"],
                  "vertices_before": self.source.model.vertex_count, "vertices": result.model.vertex_count,
                  "polygons_before": len(self.materials), "polygons": len(result.polygons),
                  "influences_max": int(result.model.counts().max(initial=0)),
                  "influences_mean": float(result.model.counts().mean()),
                  "converted_in_memory": self.source.converted, "seconds": time.perf_counter() - started}
        return {"result": result, "positions": positions, "weights": blend, "report": report}

    def write(self, mesh_object, solved):
        with naming(mesh_object):
            if mesh_object.name != self.mesh_object_name or len(mesh_object.data.vertices) != \
                    self.source.model.vertex_count:
                raise SkinkitError("the mesh changed while it was being subdivided; nothing was written")
        result = solved["result"]
        mesh = new_mesh(mesh_object.data.name + SUBDIVIDED_SUFFIX, solved["positions"], result.polygons)
        sizes = np.diff(self.polygons[0])
        levels = self.options["levels"]
        per_polygon = np.full(len(sizes), 4 ** levels) if self.options["scheme"] == "loop" else \
            sizes * 4 ** (levels - 1)
        mesh.polygons.foreach_set("material_index", np.repeat(self.materials, per_polygon))
        mesh.polygons.foreach_set("use_smooth", np.repeat(self.smooth, per_polygon))
        if result.uv is not None:
            layer = mesh.uv_layers.new(name=self.uv_name)
            layer.uv.foreach_set("vector", result.uv.astype(np.float32).reshape(-1))
        for material in mesh_object.data.materials:
            mesh.materials.append(material)
        copy = skinned_copy(mesh_object, SUBDIVIDED_SUFFIX, bpy.data.objects[self.source.armature_name], mesh)
        write_result(copy, result.model, solved["weights"], self.source, solved["report"])
        return copy


def new_mesh(name: str, positions: np.ndarray, polygons: np.ndarray):
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(positions))
    mesh.vertices.foreach_set("co", positions.astype(np.float32).reshape(-1))
    width = polygons.shape[1]
    mesh.loops.add(polygons.size)
    mesh.loops.foreach_set("vertex_index", polygons.reshape(-1).astype(np.int32))
    mesh.polygons.add(len(polygons))
    mesh.polygons.foreach_set("loop_start", np.arange(0, polygons.size, width, dtype=np.int32))
    mesh.update(calc_edges=True)
    mesh.validate(verbose=False)
    return mesh


def prepare_subdivide(mesh_object, levels: int = 1, scheme: str = "catmull-clark", boundary: str = "all",
                      uv_smooth: str = "preserve-corners") -> SubdivideJob:
    for name, value, allowed in (("scheme", scheme, SCHEMES), ("boundary", boundary, BOUNDARIES),
                                 ("uv_smooth", uv_smooth, UV_SMOOTHING)):
        if value not in allowed:
            raise SkinkitError(f"{name} must be one of {allowed}, not {value!r}")
    source = read_source(mesh_object)
    with naming(mesh_object):
        mesh = mesh_object.data
        if not mesh.polygons:
            raise SkinkitError("has no faces to subdivide")
        offsets, corners, materials, smooth = mesh_polygons(mesh)
        if scheme == "loop" and np.any(np.diff(offsets) != 3):
            raise SkinkitError("has faces that are not triangles: the Loop scheme needs triangles (triangulate it, "
                               "or use Catmull-Clark)")
        layer = mesh.uv_layers.active
        uv = None
        if layer is not None:
            uv = np.empty(len(mesh.loops) * 2, np.float32)
            layer.uv.foreach_get("vector", uv)
            uv = uv.reshape(-1, 2).astype(np.float64)
    return SubdivideJob(mesh_object.name, source, (offsets, corners), materials, smooth, uv,
                        layer.name if layer is not None else None,
                        {"levels": int(levels), "scheme": scheme, "boundary": boundary, "uv_smooth": uv_smooth})


def subdivide_object(mesh_object, progress=None, **options):
    """Prepare, solve, write on this thread: (the new object, the report)."""
    job = prepare_subdivide(mesh_object, **options)
    solved = job.solve(progress)
    return job.write(mesh_object, solved), solved["report"]
