"""A rig's linear blend skinning as an animation-space model, and what the stored model does in the scene:
converting, evaluating it beside Blender's Armature modifier, baking it to shape keys or a PC2 cache.

Shared by the add-on's operators and the command line. Each operation computes everything first and writes
to the scene last, so an error leaves the scene as it was; scene state changed on the way (frame, modifier
visibility) is restored in `finally` blocks (see frames.py).
"""
from __future__ import annotations

import time

import bpy
import numpy as np

from .. import meshcache
from ..model import SkinkitError, convert_lbs
from . import storage
from .frames import armature_modifier_only, depsgraphs_at, evaluated_positions
from .rig import (bind_matrix, deform_weights, model_signature, pose_matrices, rest_positions, rig_of, signature_changes,
                  skeleton_of)
from .scene import naming


def convert_object(mesh_object, ignore_unmatched_groups: bool = False) -> dict:
    """Converts the object's linear blend skinning to an animation-space model stored on its mesh."""
    started = time.perf_counter()
    with naming(mesh_object):
        rig = rig_of(mesh_object)
        bind = bind_matrix(rig, bpy.context.evaluated_depsgraph_get())
        skeleton = skeleton_of(rig, bind)
        weights = deform_weights(rig, ignore_unmatched_groups)
        model = convert_lbs(skeleton, weights, rest_positions(mesh_object))
        signature = model_signature(rig, weights)
    storage.write_model(mesh_object.data, model, list(skeleton.names), rig.armature_object.name, bind, signature)
    counts = model.counts()
    return {"object": mesh_object.name, "armature": rig.armature_object.name, "vertices": model.vertex_count,
            "bones": skeleton.bone_count - 1, "influences_mean": float(counts.mean()),
            "influences_max": int(counts.max()), "seconds": time.perf_counter() - started,
            "warnings": list(rig.warnings)}


def model_changes(mesh_object, stored=None, check_weights: bool = True) -> list[str]:
    """What changed in the mesh or its rig since the stored model was built, in words (empty: it matches, or the
    model predates signatures). Without check_weights the vertex groups are not read (cheap enough per frame)."""
    stored = stored or storage.read_model(mesh_object.data, mesh_object.name)
    if stored.signature is None:
        return []
    return signature_changes(stored.signature, model_signature(rig_of(mesh_object), with_weights=check_weights))


def current_model(mesh_object, check_weights: bool = True):
    """The stored model, refused when the mesh or rig changed since it was built (see model_changes)."""
    stored = storage.read_model(mesh_object.data, mesh_object.name)
    changes = model_changes(mesh_object, stored, check_weights)
    if changes:
        raise out_of_date(mesh_object, changes)
    return stored


def out_of_date(mesh_object, changes: list[str], consequence: str = "") -> SkinkitError:
    """The one message for a stale model: what changed since it was built."""
    return SkinkitError(f"'{mesh_object.name}': the model is out of date: {'; '.join(changes)} changed since it was "
                        f"built{consequence}; convert (or fit) it again")


def animation_warnings(mesh_object) -> list[str]:
    """A warning when the armature deforming the mesh has no animation: every frame then shows one pose."""
    armature = rig_of(mesh_object).armature_object
    data = armature.animation_data
    if data is None or (data.action is None and not data.nla_tracks and not data.drivers):
        return [f"armature '{armature.name}' has no animation (no action): every frame shows its current pose, "
                "so this covers that one pose only"]
    return []


def model_positions(mesh_object, depsgraph, stored=None, dtype=np.float64) -> np.ndarray:
    """The stored model evaluated at the depsgraph's pose: (V, 3) in the mesh's local space."""
    stored = stored or storage.read_model(mesh_object.data, mesh_object.name)
    rig = rig_of(mesh_object)
    poses = pose_matrices(rig.armature_object, depsgraph, stored.bone_names, stored.bind)
    return stored.model.evaluate(poses.astype(dtype), dtype)


def bounding_box_diagonal(positions: np.ndarray) -> float:
    return float(np.linalg.norm(positions.max(axis=0) - positions.min(axis=0))) if len(positions) else 0.0


def frame_deviations(mesh_object, frames):
    """Yields, per frame, (largest distance between the stored model and Blender's Armature modifier,
    seconds skinkit took to evaluate). Closing the generator restores the frame and the modifiers.
    A stale model (model_changes) is refused at once, before the generator is returned."""
    return each_frame_deviation(mesh_object, current_model(mesh_object), frames)


def each_frame_deviation(mesh_object, stored, frames):
    with armature_modifier_only(mesh_object):
        for depsgraph in depsgraphs_at(frames):
            reference = evaluated_positions(mesh_object, depsgraph)
            started = time.perf_counter()
            ours = model_positions(mesh_object, depsgraph, stored)
            seconds = time.perf_counter() - started
            yield float(np.linalg.norm(ours - reference, axis=1).max(initial=0.0)), seconds


def deviation_report(mesh_object, frame_count: int, deviations) -> dict:
    """Summarises frame_deviations: the largest deviation is divided by the rest bounding-box diagonal."""
    deviations = list(deviations)
    diagonal = bounding_box_diagonal(rest_positions(mesh_object))
    worst = max((d for d, _ in deviations), default=0.0)
    summary = storage.model_summary(mesh_object.data)
    return {"object": mesh_object.name, "vertices": len(mesh_object.data.vertices), "bones": summary["bones"],
            "frames": frame_count, "seconds": sum(s for _, s in deviations),
            "frame_ms_median": 1000 * float(np.median([s for _, s in deviations])) if deviations else 0.0,
            "max_deviation": worst / diagonal if diagonal > 0 else worst, "warnings": animation_warnings(mesh_object)}


def compare_with_armature(mesh_object, frames) -> dict:
    """Evaluates the stored model at each frame beside Blender's own Armature modifier.

    Returns vertices, bones, frames, seconds (skinkit's evaluation time, summed), frame_ms_median and
    the largest deviation over all frames and vertices, divided by the rest bounding-box diagonal.
    """
    frames = list(frames)
    if not frames:
        raise SkinkitError("the frame range is empty")
    return deviation_report(mesh_object, len(frames), frame_deviations(mesh_object, frames))


def frame_positions(mesh_object, frames):
    """Yields the stored model's positions, float32 (V, 3), at each frame in turn.

    A generator, so a modal operator can step it and stop it (closing it restores the current frame); a stale model
    is refused at once, before the generator is returned.
    """
    return each_frame_positions(mesh_object, current_model(mesh_object), frames)


def each_frame_positions(mesh_object, stored, frames):
    for depsgraph in depsgraphs_at(frames):
        yield model_positions(mesh_object, depsgraph, stored, np.float32)


def positions_over_frames(mesh_object, frames, progress=None) -> np.ndarray:
    """The stored model evaluated at each frame: float32 (frames, V, 3)."""
    frames = list(frames)
    if not frames:
        raise SkinkitError("the frame range is empty")
    result = np.empty((len(frames), len(mesh_object.data.vertices), 3), np.float32)
    for step, positions in enumerate(frame_positions(mesh_object, frames)):
        result[step] = positions
        if progress:
            progress(step + 1, len(frames))
    return result


def baked_copy(mesh_object, suffix: str, mesh=None):
    """A new object with a copy of the mesh (or `mesh`), no modifiers, no shape keys and no model, placed like the
    original, with its materials."""
    if mesh is None:
        mesh = mesh_object.data.copy()
        mesh.name = mesh_object.data.name + suffix
    storage.remove_model(mesh)
    copy = bpy.data.objects.new(mesh_object.name + suffix, mesh)
    for collection in mesh_object.users_collection:
        collection.objects.link(copy)
    copy.parent = mesh_object.parent
    copy.parent_type = mesh_object.parent_type
    copy.matrix_parent_inverse = mesh_object.matrix_parent_inverse.copy()
    copy.matrix_basis = mesh_object.matrix_basis.copy()
    if copy.data.shape_keys:
        copy.shape_key_clear()
    for material_slot, source in zip(copy.material_slots, mesh_object.material_slots):
        material_slot.link = source.link
        material_slot.material = source.material
    return copy


def bake_shape_keys(mesh_object, frames, positions: np.ndarray):
    """A new object whose shape keys, one per frame, replay `positions` (frames, V, 3); each key is keyed
    to 1 on its own frame and 0 on its neighbours, so playback interpolates linearly between frames."""
    copy = baked_copy(mesh_object, "_skinkit_baked")
    copy.shape_key_add(name="Basis", from_mix=False)
    for frame, positions_at_frame in zip(frames, positions):
        key = copy.shape_key_add(name=f"frame_{frame:04d}", from_mix=False)
        key.points.foreach_set("co", positions_at_frame.reshape(-1))
        for neighbour, value in ((frame - 1, 0.0), (frame, 1.0), (frame + 1, 0.0)):
            key.value = value
            key.keyframe_insert("value", frame=neighbour)
    copy.data.update()
    return copy


def bake_mesh_cache(mesh_object, path: str, frames, positions: np.ndarray, add_object: bool = True):
    """Writes `positions` (frames, V, 3) as a PC2 point cache (Blender's Mesh Cache modifier reads it).

    With add_object, also adds a copy of the mesh that plays the cache; returns that object or None.
    """
    frames = list(frames)
    meshcache.write_pc2(path, positions, start_frame=frames[0], sample_rate=1.0)
    if not add_object:
        return None
    copy = baked_copy(mesh_object, "_skinkit_cache")
    modifier = copy.modifiers.new("skinkit Mesh Cache", "MESH_CACHE")
    modifier.cache_format = "PC2"
    modifier.filepath = path
    modifier.frame_start = float(frames[0])
    return copy
