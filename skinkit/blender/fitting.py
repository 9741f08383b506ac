"""Fitting a rigged mesh to example poses inside Blender: gathering examples, fitting, writing results.

Examples are posed meshes in correspondence with the rigged mesh (same vertices, same order), each paired
with a frame of the armature's animation that gives its bone poses:
  - shape keys of the mesh, each holding a posed shape; its frame is that of a timeline marker or an
    action pose marker named like the key;
  - other mesh objects, each paired by a marker named like the object (or its "skinkit_frame" property);
  - a mesh sequence: an object whose Mesh Sequence Cache (Alembic) or Mesh Cache modifier animates it,
    sampled over a frame range.
Positions are taken into the rigged mesh's local space. Results written back: the animation-space model
(storage layout), the linear-blend weights as the bone vertex groups (usable by the Armature modifier as
they are), a per-vertex error attribute with a heat-map colour attribute, and a report on the mesh.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import bpy
import numpy as np

from ..fit import (DEFAULT_MAX_INFLUENCES, DEFAULT_RINGS, FIT_METHODS, INFLUENCE_SOURCES, INPUT_RIG, LsqrSettings,
                   fit_animation_space, fit_errors, fit_lbs, influences_automatic, influences_from_weights,
                   model_errors, per_vertex_error, rigid_explanation_error, worse_than_input_rig)
from ..model import SkinkitError, convert_lbs, lbs_evaluate
from . import storage
from .attributes import (ERROR_ATTRIBUTE, HEAT_ATTRIBUTE, REPORT_PROPERTY, flatten_report, write_bone_groups,
                         write_heat_map)
from .frames import armature_modifier_only, depsgraphs_at, evaluated_positions, poses_at, world_positions_at
from .rig import (bind_matrix, deform_weights, mesh_of, mesh_positions, model_signature, read_vertex_groups, rig_of,
                  skeleton_of)
from .scene import check_same_vertex_count, into_local_space, named, naming, world_to_local
from .skinning import bounding_box_diagonal

PAINTED_PREFIX = "influence:"  # painted influence maps: vertex groups "influence:<bone name>"


@dataclass
class Examples:
    positions: np.ndarray  # (E, V, 3), in the rigged mesh's local space
    frames: list[int]
    labels: list[str]


def marker_frames(scene, armature_object) -> dict[str, int]:
    """Frames of timeline markers and of the armature action's pose markers, by name."""
    frames = {m.name: m.frame for m in scene.timeline_markers}
    action = armature_object.animation_data.action if armature_object.animation_data else None
    if action is not None:
        frames.update({m.name: m.frame for m in action.pose_markers})
    return frames


def paired_frame(name: str, markers: dict, fallback=None) -> int:
    if name in markers:
        return int(markers[name])
    if fallback is not None:
        return int(fallback)
    raise SkinkitError(f"example '{name}' has no frame: add a timeline marker named '{name}' at the frame of its pose")


def examples_from_shape_keys(mesh_object, armature_object, skip=("skinkit_preview",)) -> Examples:
    keys = mesh_object.data.shape_keys
    blocks = [k for k in (keys.key_blocks[1:] if keys else []) if k.name not in skip]
    if not blocks:
        raise SkinkitError(f"'{mesh_object.name}' has no shape keys besides the Basis to use as examples")
    markers = marker_frames(bpy.context.scene, armature_object)
    positions = np.empty((len(blocks), len(mesh_object.data.vertices) * 3), np.float32)
    for row, block in zip(positions, blocks):
        block.points.foreach_get("co", row)
    return Examples(positions.reshape(len(blocks), -1, 3).astype(np.float64),
                    [paired_frame(b.name, markers) for b in blocks], [b.name for b in blocks])


def examples_from_objects(mesh_object, armature_object, objects) -> Examples:
    if not objects:
        raise SkinkitError("no example objects were given")
    markers = marker_frames(bpy.context.scene, armature_object)
    positions, frames = [], []
    for other in objects:
        if other.type != "MESH":
            raise SkinkitError(f"example '{other.name}' is a {other.type.lower()}, not a mesh")
        check_same_vertex_count(mesh_object, other, len(other.data.vertices))
        positions.append(into_local_space(mesh_object, other, mesh_positions(other.data)))
        frames.append(paired_frame(other.name, markers, other.get("skinkit_frame")))
    return Examples(np.stack(positions), frames, [o.name for o in objects])


def examples_from_positions(mesh_object, positions, frames) -> Examples:
    """Examples given as world-space arrays (E, V, 3), e.g. read from OBJ files."""
    positions = np.asarray(positions, dtype=np.float64)
    frames = list(frames)
    if len(frames) != len(positions):
        raise SkinkitError(f"{len(positions)} example meshes but {len(frames)} frames to pair them with")
    if positions.shape[1] != len(mesh_object.data.vertices):
        raise SkinkitError(f"the examples have {positions.shape[1]} vertices, '{mesh_object.name}' has "
                           f"{len(mesh_object.data.vertices)}: they need the same vertices in the same order")
    return Examples(world_to_local(mesh_object, positions), frames, [f"frame {f}" for f in frames])


def examples_from_sequence(mesh_object, sequence_object, frames) -> Examples:
    """The sequence object's evaluated mesh at each frame (its cache modifier animates it)."""
    frames = list(frames)
    if not frames:
        raise SkinkitError("the frame range is empty")
    if not any(m.type in ("MESH_SEQUENCE_CACHE", "MESH_CACHE") for m in sequence_object.modifiers):
        raise SkinkitError(f"'{sequence_object.name}' has no Mesh Sequence Cache or Mesh Cache modifier")
    world = world_positions_at(sequence_object, frames)
    check_same_vertex_count(mesh_object, sequence_object, world.shape[1])
    return Examples(world_to_local(mesh_object, world), frames, [f"frame {f}" for f in frames])


def examples_from_armature(mesh_object, frames, preserve_volume: bool = True) -> Examples:
    """Examples made by Blender's own Armature modifier over `frames`, by default with Preserve Volume (dual
    quaternions): fitting them gives linear models that imitate Blender's dual-quaternion skinning. The
    modifier's setting and the scene's frame are restored."""
    modifier = rig_of(mesh_object).modifier
    frames, saved = list(frames), modifier.use_deform_preserve_volume
    try:
        modifier.use_deform_preserve_volume = preserve_volume
        with armature_modifier_only(mesh_object):
            positions = [evaluated_positions(mesh_object, depsgraph) for depsgraph in depsgraphs_at(frames)]
    finally:
        modifier.use_deform_preserve_volume = saved
    return Examples(np.stack(positions), frames, [f"frame {f}" for f in frames])


def existing_influences(rig, source: str, skeleton) -> np.ndarray | None:
    """(V, b) weights marking where bones may act, read from the scene (None for automatic sets)."""
    if source == "automatic":
        return None
    if source == "rig":
        dense = deform_weights(rig).to_dense(skeleton.bone_count)
        if not dense[:, 1:].any():
            raise SkinkitError(f"'{rig.mesh_object.name}' has no bone weights to take influences from: "
                               "use automatic influences")
        dense[:, 0] = 0.0  # unweighted vertices (bound to the root) get bones from their neighbours instead
        return dense
    if source == "painted":
        return painted_influences(rig.mesh_object, skeleton.names)
    raise SkinkitError(f"influence source must be one of {INFLUENCE_SOURCES}, not {source!r}")


def painted_influences(mesh_object, bone_names) -> np.ndarray:
    """(V, b): the painted influence maps, vertex groups named 'influence:<bone>'."""
    painted = [g.name for g in mesh_object.vertex_groups if g.name.startswith(PAINTED_PREFIX)]
    index = {name: j for j, name in enumerate(bone_names)}
    unknown = [g for g in painted if g[len(PAINTED_PREFIX):] not in index]
    if not painted or unknown:
        raise SkinkitError(f"'{mesh_object.name}': painted influences need vertex groups named "
                           f"'{PAINTED_PREFIX}<bone>'" + (f"; these name no bone: {unknown}" if unknown else ""))
    values = read_vertex_groups(mesh_object, painted)
    dense = np.zeros((values.shape[0], len(bone_names)))
    dense[:, [index[g[len(PAINTED_PREFIX):]] for g in painted]] = values
    return dense


@dataclass
class FitJob:
    """Everything a fit needs, read from the scene, so that solve() touches no Blender data and may run on
    another thread (a modal operator's), while prepare and write stay on Blender's."""

    mesh_object_name: str
    rig: object
    bind: np.ndarray
    skeleton: object
    mesh: object
    poses: np.ndarray
    examples: np.ndarray
    held: np.ndarray
    dense_influences: np.ndarray | None
    options: dict
    input_weights: object = None  # the rig's own weights (SparseWeights), the baseline; None when it has none

    def solve(self, progress=None) -> dict:
        """Influence sets, the linear-blend fit, then the animation-space fit pulled towards it; the report."""
        options, skeleton, mesh = self.options, self.skeleton, self.mesh
        train_poses, train_examples = self.poses[~self.held], self.examples[~self.held]
        with named(self.mesh_object_name):
            if self.dense_influences is None:
                influences = influences_automatic(skeleton, mesh.positions, train_poses, train_examples,
                                                          options["max_influences"])
            else:
                explanation = rigid_explanation_error(skeleton, mesh.positions, train_poses, train_examples)
                influences = influences_from_weights(self.dense_influences, options["max_influences"],
                                                             mesh.triangles, options["rings"], explanation)
            weights = fit_lbs(skeleton, mesh.positions, train_poses, train_examples, influences)
            result = fit_animation_space(
                train_poses, train_examples, influences, skeleton.bone_count, method=options["method"],
                regularisation=options["regularisation"], triangles=mesh.triangles, rest_positions=mesh.positions,
                rest_frames=skeleton.rest_frames, prior=convert_lbs(skeleton, weights, mesh.positions),
                settings=options["settings"], progress=progress, bone_names=skeleton.names,
                validate=options["validate"], reproduce_rest=options["reproduce_rest"])
        report = error_report(result, weights, skeleton, mesh, self.poses, self.examples, self.held,
                              self.input_weights)
        held_out_errors = {model: parts for model, parts in report.items() if model != "rest_pose"}
        report.update(warnings=worse_than_input_rig(held_out_errors), object=self.mesh_object_name,
                      method=options["method"], influence_source=options["source"],
                      bones=skeleton.bone_count - 1, examples=int((~self.held).sum()), held_out=int(self.held.sum()),
                      vertices=mesh.vertex_count, iterations=int(result.report.get("iterations", 0)),
                      regularisation_lambda=result.report.get("lambda"), validation=result.report.get("validation", {}),
                      fallback=bool(result.report.get("fallback", False)),
                      fit_seconds=result.seconds)
        return {"model": result.model, "weights": weights, "report": report,
                "per_vertex_error": per_vertex_error(result.model.evaluate(train_poses), train_examples,
                                                             bounding_box_diagonal(mesh.positions)),
                "reconstruction": result.model.evaluate(self.poses)}

    def write(self, mesh_object, solved: dict) -> None:
        write_results(mesh_object, self.rig, solved["model"], solved["weights"], self.skeleton.names, self.bind,
                      solved["per_vertex_error"], solved["report"])


def prepare_fit(mesh_object, examples: Examples, *, method=FIT_METHODS[0], regularisation=None,
                source=INFLUENCE_SOURCES[0], rings=DEFAULT_RINGS, max_influences=DEFAULT_MAX_INFLUENCES,
                held_out_frames=(), settings=LsqrSettings(), validate=True, reproduce_rest=True) -> FitJob:
    """Reads what the fit needs from the scene (changing nothing) and checks the choices."""
    with naming(mesh_object):
        rig = rig_of(mesh_object)
        bind = bind_matrix(rig, bpy.context.evaluated_depsgraph_get())
        skeleton = skeleton_of(rig, bind)
        held = np.isin(examples.frames, list(held_out_frames))
        if held.all():
            raise SkinkitError("every example is held out: keep at least one for training")
        return FitJob(mesh_object.name, rig, bind, skeleton, mesh_of(mesh_object),
                      poses_at(rig.armature_object, examples.frames, list(skeleton.names), bind), examples.positions,
                      held, existing_influences(rig, source, skeleton),
                      {"method": method, "regularisation": regularisation, "source": source, "rings": rings,
                       "max_influences": max_influences, "settings": settings, "validate": validate,
                       "reproduce_rest": reproduce_rest}, rig_weights(rig))


def fit_object(mesh_object, examples: Examples, progress=None, **options) -> dict:
    """Fits animation space and linear blend skinning to the examples and writes both to the object (the
    options are prepare_fit's). Everything is computed before anything is written, so an error leaves the
    scene unchanged. The report's "reconstruction" holds every example's animation-space reconstruction."""
    started = time.perf_counter()
    job = prepare_fit(mesh_object, examples, **options)
    solved = job.solve(progress)
    job.write(mesh_object, solved)
    return {**solved["report"], "seconds": time.perf_counter() - started, "reconstruction": solved["reconstruction"]}


def rig_weights(rig):
    """The rig's own deforming weights, or None when no vertex has any (then there is no baseline to report)."""
    weights = deform_weights(rig, ignore_unmatched_groups=True)
    return weights if (weights.bones > 0).any() else None


def error_report(result, weights, skeleton, mesh, poses, examples, held, input_weights=None) -> dict:
    """Geometric and normal errors of both fitted models and of the rig's own weights (INPUT_RIG, when it has
    some), for training and held-out examples."""
    predictions = {"animation_space": result.model.evaluate(poses),
                   "linear_blend": lbs_evaluate(skeleton, weights, mesh.positions, poses)}
    if input_weights is not None:
        predictions[INPUT_RIG] = lbs_evaluate(skeleton, input_weights, mesh.positions, poses)
    diagonal = bounding_box_diagonal(mesh.positions)
    report = model_errors(predictions, examples, ~held, diagonal, mesh.triangles)
    report["rest_pose"] = rest_pose_errors(result.model, weights, skeleton, mesh, input_weights, diagonal)
    return report


def rest_pose_errors(model, weights, skeleton, mesh, input_weights, diagonal) -> dict:
    """How far each model moves the bind pose (the rest mesh at the rest frames): {model: fit_errors}."""
    rest_pose = skeleton.rest_frames[None]
    predictions = {"animation_space": model.evaluate(rest_pose),
                   "linear_blend": lbs_evaluate(skeleton, weights, mesh.positions, rest_pose)}
    if input_weights is not None:
        predictions[INPUT_RIG] = lbs_evaluate(skeleton, input_weights, mesh.positions, rest_pose)
    return {name: fit_errors(predicted, mesh.positions[None], diagonal) for name, predicted in predictions.items()}


def write_results(mesh_object, rig, model, weights, bone_names, bind, per_vertex_error, report) -> None:
    mesh = mesh_object.data
    write_bone_groups(mesh_object, weights, bone_names)
    storage.write_model(mesh, model, list(bone_names), rig.armature_object.name, bind,
                        model_signature(rig_of(mesh_object)))  # the weights as written, read back
    write_heat_map(mesh, ERROR_ATTRIBUTE, HEAT_ATTRIBUTE, per_vertex_error)
    mesh[REPORT_PROPERTY] = flatten_report(report)
    mesh.update()
