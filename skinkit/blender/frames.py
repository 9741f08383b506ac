"""Stepping the scene through frames and reading what Blender evaluates there.

Every helper restores what it changes (the current frame, modifier visibility, the active shape key) in a
`finally` block, also when a generator is closed early (a cancelled modal operator).
"""
from __future__ import annotations

from contextlib import contextmanager

import bpy
import numpy as np

from ..model import SkinkitError
from .rig import mesh_positions, pose_matrices, rig_of
from .scene import transform_points


def depsgraphs_at(frames):
    """Yields the evaluated depsgraph at each frame in turn. The scene's current frame is restored when the
    loop ends, fails or is abandoned (closing the generator, as a cancelled modal operator does)."""
    scene = bpy.context.scene
    frame, subframe = scene.frame_current, scene.frame_subframe
    try:
        for each in frames:
            scene.frame_set(each)
            yield bpy.context.evaluated_depsgraph_get()
    finally:
        scene.frame_set(frame, subframe=subframe)


def action_frames(action) -> range:
    """The whole frames an action's keys span (its frame range rounded to the nearest frame)."""
    first, last = (int(round(f)) for f in action.frame_range)
    return range(first, last + 1)


def evaluated_positions(mesh_object, depsgraph) -> np.ndarray:
    """Vertex positions of the evaluated object (after its visible modifiers), float64 (V, 3)."""
    evaluated = mesh_object.evaluated_get(depsgraph)
    try:
        return mesh_positions(evaluated.to_mesh())
    finally:
        evaluated.to_mesh_clear()


def world_positions_at(mesh_object, frames) -> np.ndarray:
    """(F, V, 3): the evaluated mesh in world space at each frame (moved by that frame's own transform)."""
    positions = []
    for depsgraph, frame in zip(depsgraphs_at(frames), frames):
        local = evaluated_positions(mesh_object, depsgraph)
        if positions and len(local) != len(positions[0]):
            raise SkinkitError(f"'{mesh_object.name}' has {len(local)} vertices at frame {frame} but "
                               f"{len(positions[0])} at the first: a sequence needs the same vertices in every frame")
        positions.append(transform_points(np.array(mesh_object.evaluated_get(depsgraph).matrix_world), local))
    return np.stack(positions)


@contextmanager
def armature_modifier_only(mesh_object):
    """Shows only the Basis shape and the Armature modifier while inside, to compare with it alone."""
    modifier = rig_of(mesh_object).modifier
    saved = [(m, m.show_viewport) for m in mesh_object.modifiers]
    saved_shape = (mesh_object.show_only_shape_key, mesh_object.active_shape_key_index)
    try:
        for other, _ in saved:
            other.show_viewport = other == modifier
        mesh_object.show_only_shape_key = True
        mesh_object.active_shape_key_index = 0
        yield
    finally:
        for other, visible in saved:
            other.show_viewport = visible
        mesh_object.show_only_shape_key, mesh_object.active_shape_key_index = saved_shape


def poses_at(armature_object, frames, names, bind) -> np.ndarray:
    """(E, b, 4, 4): the skeleton's G_j = B^-1 P_j at each frame (restoring the current frame)."""
    return np.stack([pose_matrices(armature_object, depsgraph, names, bind) for depsgraph in depsgraphs_at(frames)])
