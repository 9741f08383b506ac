"""What the commands write: frames as .obj files and scenes as .blend or .glb. Every file is written under a
temporary name beside its target and renamed onto it only once complete, so a failed or killed command never
leaves a half-written file where a farm's next step would read it."""
from __future__ import annotations

import os
from contextlib import contextmanager

from ..model import SkinkitError


def check_output_folder(path: str) -> str:
    """The absolute path of an output whose folder exists, else a SkinkitError saying which folder is missing."""
    target = os.path.abspath(path)
    folder = os.path.dirname(target)
    if not os.path.isdir(folder):
        raise SkinkitError(f"{path}: the folder {folder} does not exist")
    return target


@contextmanager
def written_atomically(path: str):
    """Yields a temporary path in the target's folder, with the target's extension (Blender's savers check it);
    it replaces `path` when the block completes and is removed when it fails."""
    target = check_output_folder(path)
    folder, name = os.path.split(target)
    stem, extension = os.path.splitext(name)
    temporary = os.path.join(folder, f".{stem}.partial-{os.getpid()}{extension}")
    try:
        yield temporary
        os.replace(temporary, target)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


def write_frames(folder: str, frame_numbers, positions, scale: float = 1.0) -> str:
    """One .obj per frame, frame_NNNN.obj, with `positions` (F, V, 3) divided by `scale`: the input's units when
    the input was multiplied by it (--sequence-scale), in the given (the input's) vertex order. Returns the
    folder's absolute path for the report."""
    from ..meshio import write_obj

    os.makedirs(folder, exist_ok=True)
    for number, frame in zip(frame_numbers, positions):
        with written_atomically(os.path.join(folder, f"frame_{number:04d}.obj")) as temporary:
            write_obj(temporary, frame / scale)
    return os.path.abspath(folder)


def save_scene(path: str, object_names=None) -> str:
    """Saves the scene as a .blend, or (given the objects to keep) the named objects as a .glb; returns the
    file's absolute path for the report."""
    from ..blender import scene

    as_glb = object_names is not None and path.lower().endswith(".glb")
    if not as_glb and not path.endswith(".blend"):
        raise SkinkitError(f"{path}: the output must be a .blend file" + (" or a .glb" if object_names else ""))
    with written_atomically(path) as temporary:
        scene.export_glb(temporary, object_names) if as_glb else scene.save_blend(temporary)
    return os.path.abspath(path)
