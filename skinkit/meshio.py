"""Reading and writing mesh files without Blender: Wavefront OBJ meshes and folders of them (sequences).

Vertex order is kept exactly as in the file, so per-vertex results line up with the input.
"""
from __future__ import annotations

import os
import re

import numpy as np

from ._checks import PATH, as_index_array, as_real_array, checked
from .model import SkinkitError

#: The public API (what tests/fuzz/api_fuzz.py calls with hostile arguments); the rest are helpers.
__all__ = ["read_obj", "read_obj_sequence", "read_obj_texture_corners", "sequence_files", "write_obj"]

MAX_INDEX = 2**31 - 1  # indices are int32 in the core


def read_text_lines(path: str) -> list[str]:
    """The file's lines; a missing, unreadable or binary file is a SkinkitError naming it."""
    try:
        with open(path, encoding="utf-8") as stream:
            return stream.read().splitlines()
    except OSError as error:
        raise SkinkitError(f"{path}: {error.strerror}") from None
    except UnicodeDecodeError as error:
        raise SkinkitError(f"{path}: not a text OBJ file (byte {error.start} is not UTF-8)") from None


def corner_index(token: str, defined: int, path: str, number: int, what: str) -> int:
    """The 0-based index an OBJ corner token names: 1-based, or negative counting back from the `defined`
    elements read so far; -1 for an empty token."""
    if not token:
        return -1
    try:
        index = int(token)
    except ValueError:
        raise SkinkitError(f"{path}:{number}: a {what} index {token!r} is not a number") from None
    resolved = index - 1 if index > 0 else defined + index
    if index == 0 or resolved < 0 or resolved >= MAX_INDEX:
        raise SkinkitError(f"{path}:{number}: {what} index {index} refers to no {what}")
    return resolved


@checked(path=PATH)
def read_obj(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(positions float64 (V, 3), triangles int32 (T, 3)); polygons are split into fans."""
    vertices, triangles = [], []
    for number, line in enumerate(read_text_lines(path), 1):
        if line.startswith("v "):
            parts = line.split()
            if len(parts) < 4:
                raise SkinkitError(f"{path}:{number}: a vertex needs three coordinates")
            vertices.append(parts[1:4])
        elif line.startswith("f "):
            corners = [corner_index(token.split("/")[0], len(vertices), path, number, "vertex")
                       for token in line.split()[1:]]
            if len(corners) < 3:
                raise SkinkitError(f"{path}:{number}: a face needs at least three corners")
            triangles.extend((corners[0], corners[k], corners[k + 1]) for k in range(1, len(corners) - 1))
    try:
        positions = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    except ValueError:
        raise SkinkitError(f"{path}: a vertex coordinate is not a number") from None
    faces = np.array(triangles, dtype=np.int64).reshape(-1, 3)
    if faces.size and faces.max() >= len(positions):
        raise SkinkitError(f"{path}: a face refers to vertex {faces.max() + 1}, but the file has {len(positions)}")
    return positions, faces.astype(np.int32)


@checked(folder=PATH)
def sequence_files(folder: str) -> list[str]:
    """The .obj files of a folder in natural order (frame2 before frame10)."""
    if not os.path.isdir(folder):
        raise SkinkitError(f"{folder}: not a folder")
    names = [n for n in os.listdir(folder) if n.lower().endswith(".obj")]
    if not names:
        raise SkinkitError(f"{folder}: has no .obj files")

    def natural(name):
        return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]

    return [os.path.join(folder, n) for n in sorted(names, key=natural)]


def read_obj_sequence(paths: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(positions (F, V, 3), triangles of the first file); every file must have the same vertex count."""
    if not isinstance(paths, (list, tuple)) or not paths:
        raise SkinkitError(f"paths: expected a list of OBJ files, got {paths!r:.60}")
    frames, triangles = [], None
    for path in paths:
        positions, faces = read_obj(path)
        if frames and len(positions) != len(frames[0]):
            raise SkinkitError(f"{path}: {len(positions)} vertices, but {paths[0]} has {len(frames[0])}; "
                               "a sequence needs the same vertices in the same order in every file")
        if triangles is None:
            triangles = faces
        frames.append(positions)
    return np.stack(frames), triangles


@checked(path=PATH)
def write_obj(path: str, positions, triangles=None, corner_uv=None) -> None:
    """Writes vertices (in the given order) and triangles (1-based); with corner_uv (T, 3, 2), texture
    coordinates as `vt` (one per distinct vertex and uv, so a chart's vertices share theirs) and faces
    as `f v/vt`."""
    positions = as_real_array(positions, "positions", shape=(None, 3))
    if triangles is not None:
        triangles = as_index_array(triangles, "triangles", (None, 3))
        if triangles.size and (triangles.min() < 0 or triangles.max() >= len(positions)):
            raise SkinkitError(f"triangles: corners must be vertices 0 to {len(positions) - 1}")
    if corner_uv is not None:
        if triangles is None:
            raise SkinkitError("corner_uv: texture coordinates need the triangles they belong to")
        corner_uv = as_real_array(corner_uv, "corner_uv", shape=(len(triangles), 3, 2))
    try:
        with open(path, "w") as stream:
            write_obj_lines(stream, positions, triangles, corner_uv)
    except OSError as error:
        raise SkinkitError(f"{path}: {error.strerror}") from None


def write_obj_lines(stream, positions, triangles, corner_uv) -> None:
    np.savetxt(stream, positions, fmt="v %.9g %.9g %.9g")
    if triangles is None or not len(triangles):
        return
    if corner_uv is None:
        np.savetxt(stream, triangles + 1, fmt="f %d %d %d")
        return
    keys = np.column_stack([triangles.reshape(-1), corner_uv.reshape(-1, 2)])
    distinct, texture_index = np.unique(keys, axis=0, return_inverse=True)
    np.savetxt(stream, distinct[:, 1:], fmt="vt %.9g %.9g")
    corners = np.stack([triangles.reshape(-1) + 1, texture_index.reshape(-1) + 1], axis=1).reshape(-1, 6)
    np.savetxt(stream, corners, fmt="f %d/%d %d/%d %d/%d")


@checked(path=PATH)
def read_obj_texture_corners(path: str) -> np.ndarray:
    """int32 (T, 3): the 0-based `vt` index of each corner of read_obj's triangles (the same fans),
    -1 where a face gives none."""
    texture_count, corners = 0, []
    for number, line in enumerate(read_text_lines(path), 1):
        if line.startswith("vt "):
            texture_count += 1
        elif line.startswith("f "):
            parts = [token.split("/") for token in line.split()[1:]]
            indices = [corner_index(p[1] if len(p) > 1 else "", texture_count, path, number, "texture")
                       for p in parts]
            corners.extend((indices[0], indices[k], indices[k + 1]) for k in range(1, len(indices) - 1))
    result = np.array(corners, dtype=np.int64).reshape(-1, 3)
    if result.size and result.max() >= texture_count:
        raise SkinkitError(f"{path}: a face refers to a texture coordinate (vt) that does not exist")
    return result.astype(np.int32)
