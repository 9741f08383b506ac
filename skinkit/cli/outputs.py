"""What the commands write: frames as .obj files and scenes as .blend or .glb."""
from __future__ import annotations

import os

from ..model import SkinkitError


def write_frames(folder: str, frame_numbers, positions, scale: float = 1.0) -> str:
    """One .obj per frame, frame_NNNN.obj, with `positions` (F, V, 3) divided by `scale`: the input's units when
    the input was multiplied by it (--sequence-scale), in the given (the input's) vertex order. Returns the
    folder's absolute path for the report."""
    from ..meshio import write_obj

    os.makedirs(folder, exist_ok=True)
    for number, frame in zip(frame_numbers, positions):
        write_obj(os.path.join(folder, f"frame_{number:04d}.obj"), frame / scale)
    return os.path.abspath(folder)


def save_scene(path: str, object_names=None) -> str:
    """Saves the scene as a .blend, or (given the objects to keep) the named objects as a .glb; returns the
    file's absolute path for the report."""
    from ..blender import scene

    if object_names is not None and path.lower().endswith(".glb"):
        return scene.export_glb(path, object_names)
    if not path.endswith(".blend"):
        raise SkinkitError(f"{path}: the output must be a .blend file" + (" or a .glb" if object_names else ""))
    return scene.save_blend(path)
