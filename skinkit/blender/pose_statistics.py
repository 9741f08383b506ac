"""Pose statistics of a Blender armature: computing them, storing them on the armature, using them on meshes.

Statistics are taken in armature space, with skinkit's bone order (the root, then the armature's bones) and
stored on the armature data as one versioned ID property. A signature of the rig (bone names, parents, rest
matrices) is stored with them: when the rig changes they are refused as out of date instead of silently
describing another skeleton. For a mesh, they are moved into its space with the bind B (a rigid motion).
"""
from __future__ import annotations

import hashlib

import numpy as np

from ..metrics import STATISTICS_SOURCES as SOURCES
from ..metrics import PoseStatistics
from ..model import SkinkitError
from . import compat, storage
from .attributes import write_heat_map
from .frames import action_frames, poses_at
from .rig import armature_rest_frames, bone_names, rig_of, skeleton_parents

PROPERTY = "skinkit_pose_statistics"
LAYOUT_VERSION = 1
BOUND_ATTRIBUTE = "skinkit_max_distance"
BOUND_HEAT_ATTRIBUTE = "skinkit_max_distance_color"


def rest_local(armature_object) -> np.ndarray:
    """(b, 4, 4): each bone's rest frame relative to its parent's (root children: to armature space)."""
    return relative_to_parents(armature_rest_frames(armature_object), skeleton_parents(armature_object))


def relative_to_parents(frames: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """L_j = G_parent^-1 G_j for (..., b, 4, 4) frames; L_0 = I."""
    local = np.linalg.solve(frames[..., np.maximum(parents, 0), :, :], frames)
    local[..., 0, :, :] = np.eye(4)
    return local


def rig_signature(armature_object) -> str:
    """Changes when bones are added, removed, renamed, re-parented or moved in the rest pose."""
    digest = hashlib.sha1()
    digest.update("\0".join(bone_names(armature_object)).encode())
    digest.update(skeleton_parents(armature_object).tobytes())
    digest.update(np.round(rest_local(armature_object), 6).tobytes())
    return digest.hexdigest()


def from_frames(armature_object, frames, spread: float = 0.0) -> PoseStatistics:
    """Statistics of the armature's animation over `frames` (its action, as the scene plays it); spread (radians):
    PoseStatistics.from_local_samples' turns of each sampled joint rotation."""
    frames = list(frames)
    if not frames:
        raise SkinkitError(f"'{armature_object.name}': the frame range is empty")
    world = poses_at(armature_object, frames, bone_names(armature_object), np.eye(4))  # armature space
    if len(frames) > 1 and np.abs(world - world[:1]).max() < 1e-9:
        unplayed = " (it has no action slot: set one in the Action editor)" if \
            compat.action_without_slot(armature_object.animation_data) else ""
        raise SkinkitError(f"'{armature_object.name}' does not move over frames {frames[0]}-{frames[-1]}: "
                           f"its action does not animate it there{unplayed}")
    return PoseStatistics.from_local_samples(skeleton_parents(armature_object),
                                             relative_to_parents(world, skeleton_parents(armature_object)), spread)


def from_limits(armature_object) -> PoseStatistics:
    """Analytic statistics from the bones' Limit Rotation constraints (see joint_model); bones must not
    translate or scale (rigid-only models)."""
    parents, rest = skeleton_parents(armature_object), rest_local(armature_object)
    linear = rest[:, :3, :3]
    if np.abs(np.einsum("bji,bjk->bik", linear, linear) - np.eye(3)).max() > 1e-4:
        raise SkinkitError(f"'{armature_object.name}': the rotation models need rigid bones, but some rest "
                           "frames are scaled (apply the scale)")
    models = [("fixed",)] + [joint_model(pose_bone) for pose_bone in ordered_pose_bones(armature_object)]
    return PoseStatistics.joints(parents, rest[:, :3, 3], linear, models)


def ordered_pose_bones(armature_object):
    pose_bones = armature_object.pose.bones
    return [pose_bones[name] for name in bone_names(armature_object)[1:]]


def joint_model(pose_bone) -> tuple:
    """The rotation model of a Limit Rotation constraint: fixed when every axis is locked, an axis range for a
    hinge, independent Euler-angle ranges (X, then Y, then Z, Blender's XYZ order) when several axes are
    limited, and uniform rotation when the bone is unconstrained or an axis is free without limits."""
    limit = next((c for c in pose_bone.constraints if c.type == "LIMIT_ROTATION" and c.enabled), None)
    if limit is None:
        return ("uniform",)
    ranges = [(getattr(limit, f"min_{a}"), getattr(limit, f"max_{a}")) if getattr(limit, f"use_limit_{a}") else None
              for a in "xyz"]
    if any(r is None for r in ranges):
        return ("uniform",)
    moving = [axis for axis, (low, high) in enumerate(ranges) if high - low > 1e-6]
    if not moving:
        return ("fixed",)
    if len(moving) == 1:
        return ("range", np.eye(3)[moving[0]], *ranges[moving[0]])
    return ("euler", [(np.eye(3)[axis], *ranges[axis]) for axis in moving])


def uniform(armature_object) -> PoseStatistics:
    """Analytic: every joint rotates freely about its rest position (the skeleton-only metric, eq. 3.15)."""
    return PoseStatistics.uniform_rotations(skeleton_parents(armature_object), rest_local(armature_object)[:, :3, 3])


def compute(armature_object, source: str, frames=(), spread: float = 0.0) -> PoseStatistics:
    """Statistics from sampled frames ("action" or "poses": the frames given, each joint's rotations turned by
    +-spread radians too), "limits" or "uniform" (analytic: no spread)."""
    if source in ("action", "poses"):
        return from_frames(armature_object, frames, spread)
    if spread != 0:
        raise SkinkitError(f"spread: only sampled statistics (action or poses) take a spread, not {source!r}")
    if source == "limits":
        return from_limits(armature_object)
    if source == "uniform":
        return uniform(armature_object)
    raise SkinkitError(f"statistics source must be one of {SOURCES}, not {source!r}")


def store(armature_object, statistics: PoseStatistics, source: str, frames: int) -> None:
    armature_object.data[PROPERTY] = {
        "layout_version": LAYOUT_VERSION, "source": source, "frames": frames,
        "rig_signature": rig_signature(armature_object), "bones": bone_names(armature_object),
        "expected_local": statistics.expected_local.reshape(-1).tolist(),
        "expected_gram": statistics.expected_gram.reshape(-1).tolist(),
        "linear_bound": statistics.linear_bound.tolist(),
        "translation_centre": statistics.translation_centre.reshape(-1).tolist(),
        "translation_radius": statistics.translation_radius.tolist()}


def summary(armature_object) -> dict | None:
    if PROPERTY not in armature_object.data:
        return None
    meta = armature_object.data[PROPERTY]
    return {"source": str(meta.get("source", "")), "frames": int(meta.get("frames", 0)),
            "bones": len(meta.get("bones", [])) - 1,
            "up_to_date": str(meta.get("rig_signature", "")) == rig_signature(armature_object)}


def load(armature_object) -> PoseStatistics:
    """The stored statistics; refuses missing, newer or out-of-date ones clearly."""
    if PROPERTY not in armature_object.data:
        raise SkinkitError(f"'{armature_object.name}' has no pose statistics (run Compute Pose Statistics)")
    meta = armature_object.data[PROPERTY]
    if int(meta.get("layout_version", 0)) != LAYOUT_VERSION:
        raise SkinkitError(f"'{armature_object.name}': pose statistics layout {meta.get('layout_version')} is not "
                           f"supported (this skinkit reads {LAYOUT_VERSION})")
    if str(meta["rig_signature"]) != rig_signature(armature_object):
        raise SkinkitError(f"'{armature_object.name}': the pose statistics are out of date (the rig changed since "
                           "they were computed); compute them again")
    b = len(meta["bones"])
    return PoseStatistics(skeleton_parents(armature_object),
                          np.array(meta["expected_local"], dtype=np.float64).reshape(b, 4, 4),
                          np.array(meta["expected_gram"], dtype=np.float64).reshape(b, 4, 4),
                          np.array(meta["linear_bound"], dtype=np.float64),
                          np.array(meta["translation_centre"], dtype=np.float64).reshape(b, 3),
                          np.array(meta["translation_radius"], dtype=np.float64))


def stored_or_from_action(armature_object, owner_name: str) -> tuple[PoseStatistics, str]:
    """(statistics, "stored" or "action"): those stored on the armature, else those of its action's frames, in
    armature space; owner_name names the mesh that needs them in the message when there are neither."""
    if summary(armature_object) is not None:
        return load(armature_object), "stored"
    action = armature_object.animation_data.action if armature_object.animation_data else None
    if action is None:
        raise SkinkitError(f"'{owner_name}': armature '{armature_object.name}' has no pose statistics and no action "
                           "to compute them from (run Compute Pose Statistics)")
    return from_frames(armature_object, action_frames(action)), "action"


def in_mesh_space(statistics: PoseStatistics, bind: np.ndarray) -> PoseStatistics:
    """Statistics for a mesh bound with B (mesh space to armature space): its G_j are B^-1 times the armature's."""
    if np.abs(bind[:3, :3].T @ bind[:3, :3] - np.eye(3)).max() > 1e-6:
        raise SkinkitError("the mesh and its armature differ in scale; apply the scale of both objects")
    return statistics.transformed(np.linalg.inv(bind))


def mesh_bounds(mesh_object) -> dict:
    """For a mesh with a model: the culling sphere (centred on the expected centroid under uniform rotations)
    and each vertex's max-distance bound from that centre, under the armature's stored statistics."""
    stored = storage.read_model(mesh_object.data, mesh_object.name)
    armature = rig_of(mesh_object).armature_object
    statistics = in_mesh_space(load(armature), stored.bind)
    centre = in_mesh_space(uniform(armature), stored.bind).expected_centroid(stored.model)
    per_vertex = statistics.vertex_bounds(stored.model, centre)
    radius = float(per_vertex.max(initial=0.0))
    return {"centre": centre, "radius": radius, "per_vertex": per_vertex}


def write_bound_heat_map(mesh_object) -> dict:
    bounds = mesh_bounds(mesh_object)
    mesh = mesh_object.data
    write_heat_map(mesh, BOUND_ATTRIBUTE, BOUND_HEAT_ATTRIBUTE, bounds["per_vertex"])
    mesh.color_attributes.active_color = mesh.color_attributes[BOUND_HEAT_ATTRIBUTE]
    mesh.update()
    return bounds


def rank_of(statistics: PoseStatistics, threshold: float = 1e-9) -> int:
    """The numerical rank of P (4b x 4b): how many directions the poses can tell apart."""
    values = np.linalg.eigvalsh(statistics.matrix())
    return int((values > threshold * max(values.max(), 1e-300)).sum())
