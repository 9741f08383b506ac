"""What the commands read: Blender scenes, mesh sequences (a folder of .obj files or an .abc), rest meshes,
frame ranges and vertex lists typed on the command line.

One rule for every sequence: positions are in world space, multiplied by --sequence-scale (an .obj folder's
files are taken as world space; an .abc's objects are placed by Blender's importer, which applies the scale).
"""
from __future__ import annotations

import os

from ..model import SkinkitError


def blender_module():
    try:
        import bpy
    except ImportError:
        raise SkinkitError("this command needs Blender's Python module: `pip install bpy==4.5.15`, "
                           "or run it inside Blender") from None
    return bpy


def open_scene(path: str):
    """Loads a .blend with Blender's Python module; returns bpy."""
    bpy = blender_module()
    from ..blender import scene

    scene.open_blend(path)
    return bpy


def load_scene(path: str):
    """Opens a .blend, or imports an .fbx/.glb/.gltf into an empty scene; returns bpy."""
    bpy = blender_module()
    from ..blender import scene

    scene.load_scene(path)
    return bpy


def scene_frames() -> range:
    import bpy

    current = bpy.context.scene
    return range(current.frame_start, current.frame_end + 1)


def frame_range(text: str | None) -> range:
    """'A:B' or 'A:B:STEP' (inclusive), or the scene's own range."""
    if text is None:
        return scene_frames()
    try:
        first, last, *step = (int(part) for part in text.split(":"))
        if len(step) > 1 or (step and step[0] < 1):
            raise ValueError
    except ValueError:
        raise SkinkitError(f"--frames {text!r}: expected A:B or A:B:STEP with whole numbers, e.g. 1:48") from None
    if last < first:
        raise SkinkitError(f"--frames {text!r}: the range is empty (B < A)")
    return range(first, last + 1, step[0] if step else 1)


def is_sequence_file(source: str) -> bool:
    """Whether --sequence names files (an .obj folder or an .abc) rather than an object in a scene."""
    return os.path.isdir(source) or source.lower().endswith(".abc")


def read_sequence(source: str, scale: float = 1.0, frames: range | None = None, first_frame: int = 1):
    """(positions (F, V, 3) in world space times `scale`, triangles (T, 3), frame numbers) of a mesh sequence.

    An .obj folder (one file per frame, in natural name order) pairs its files with `frames` in order (as many
    as files), or without them with first_frame, first_frame + 1, ...: the caller says where its frames start
    (a rig's animation starts at its scene's first frame, a bare sequence at 1). An .abc is read over
    `frames`, by default its own range, with Blender (into the current scene, which keeps nothing of it).
    """
    if os.path.isdir(source):
        from ..meshio import read_obj_sequence, sequence_files

        positions, triangles = read_obj_sequence(sequence_files(source))
        numbers = list(range(first_frame, first_frame + len(positions)) if frames is None else frames)
        if len(numbers) != len(positions):
            raise SkinkitError(f"{source}: {len(positions)} .obj files but --frames has {len(numbers)} frames; "
                               "give A:B:STEP with one frame per file")
        return positions * scale, triangles, numbers
    if not source.lower().endswith(".abc"):
        raise SkinkitError(f"--sequence {source}: expected a folder of .obj files or an .abc file")
    bpy = blender_module()
    from ..blender import scene
    from ..blender.frames import world_positions_at
    from ..blender.rig import mesh_of

    animated = scene.import_alembic(source, scale)
    try:
        numbers = list(scene_frames() if frames is None else frames)  # the import set the scene's range to its own
        return world_positions_at(animated, numbers), mesh_of(animated).triangles, numbers
    finally:
        bpy.data.objects.remove(animated)


def read_rest(path: str, scale: float):
    """Rest positions (world space) and triangles from an .obj (scaled by `scale`), or an .fbx/.glb holding one mesh
    (in the units Blender imports it in)."""
    if path.lower().endswith(".obj"):
        from ..meshio import read_obj

        positions, triangles = read_obj(path)
        return positions * scale, triangles
    bpy = blender_module()
    from ..blender import scene
    from ..blender.rig import mesh_of

    mesh_object = scene.rest_mesh_object(path)
    mesh = mesh_of(mesh_object)
    positions = scene.local_to_world(mesh_object, mesh.positions)
    bpy.data.objects.remove(mesh_object)
    return positions, mesh.triangles


def read_mesh(path: str, name: str | None):
    """(positions, triangles) in the file's vertex order: an .obj as it is, or a scene's mesh object (`name`, or the
    only one) in its local space."""
    if path.lower().endswith(".obj"):
        from ..meshio import read_obj

        return read_obj(path)
    load_scene(path)
    from ..blender.rig import mesh_of
    from ..blender.scene import scene_mesh

    mesh = mesh_of(scene_mesh(name))
    return mesh.positions, mesh.triangles


def check_vertex_count(path: str, found: int, wanted: int) -> None:
    if found != wanted:
        raise SkinkitError(f"{path}: {found} vertices, but the mesh has {wanted}: it needs the same vertices in "
                           "the same order")


def vertex_list(text: str, vertex_count: int) -> list[int]:
    """'0,12,40' -> [0, 12, 40], each index checked against the mesh's vertex count."""
    try:
        vertices = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise SkinkitError(f"{text!r}: expected vertex indices such as 0,12,40") from None
    bad = [v for v in vertices if not 0 <= v < vertex_count]
    if not vertices or bad:
        raise SkinkitError(f"{text!r}: vertex indices must be in [0, {vertex_count})" +
                           (f", not {bad}" if bad else ""))
    return vertices
