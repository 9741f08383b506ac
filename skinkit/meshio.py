"""Reading and writing mesh files without Blender: Wavefront OBJ meshes and folders of them (sequences).

Vertex order is kept exactly as in the file, so per-vertex results line up with the input.
"""
from __future__ import annotations

import io
import os
import re
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ._checks import PATH, as_index_array, as_real_array, checked
from .model import SkinkitError

#: The public API (what tests/fuzz/api_fuzz.py calls with hostile arguments); the rest are helpers.
__all__ = ["read_obj", "read_obj_sequence", "read_obj_texture_corners", "sequence_files", "write_obj"]

MAX_INDEX = 2**31 - 1  # indices are int32 in the core
READER_THREADS = min(8, os.cpu_count() or 1)


def read_text_lines(path: str) -> list[str]:
    """The file's lines; a missing, unreadable or binary file is a SkinkitError naming it."""
    return read_text(path).splitlines()


def read_text(path: str) -> str:
    """The file's text; a missing, unreadable or binary file is a SkinkitError naming it."""
    try:
        with open(path, encoding="utf-8") as stream:
            return stream.read()
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
    text = read_text(path)
    try:
        return parse_obj_vectorised(text)
    except (ValueError, OverflowError):
        # Irregular or malformed: the line-by-line parser accepts the same files and names the offending line.
        return parse_obj_by_line(text.splitlines(), path)


#: The rest of every vertex line and of every face line (the keyword and one space dropped).
VERTEX_LINE = re.compile(r"^v ([^\r\n]*)", re.MULTILINE)
FACE_LINE = re.compile(r"^f ([^\r\n]*)", re.MULTILINE)
#: A corner's texture and normal indices ("/vt/vn", "/vt", "//vn"): only its vertex index makes the triangles.
SLASHED_PART = re.compile(r"/[^\s]*")
#: Line breaks other than "\n" that str.splitlines (the line-by-line parser) also breaks at.
OTHER_LINE_BREAK = re.compile("[\r\v\f\x1c-\x1e\x85\u2028\u2029]")
#: What face lines hold besides whole numbers ("1.0", "1e3", "nan" are refused line by line, naming the line).
NOT_WHOLE_NUMBERS = re.compile(r"[^0-9\s+\-]")


def with_plain_line_breaks(text: str) -> str:
    """`text` with CRLF turned into LF; ValueError where another break remains, for the line-by-line parser."""
    text = text.replace("\r\n", "\n") if "\r" in text else text
    if OTHER_LINE_BREAK.search(text):
        raise ValueError("line breaks the regular expressions do not split at")
    return text


@checked(path=PATH)
def read_obj_positions(path: str) -> np.ndarray:
    """read_obj's positions alone (a sequence's later frames, whose faces are the first frame's)."""
    text = read_text(path)
    try:
        return parse_positions(text)
    except (ValueError, OverflowError):
        return parse_obj_by_line(text.splitlines(), path, with_faces=False)[0]


def parse_positions(text: str) -> np.ndarray:
    """(V, 3) float64 from every vertex line at once; ValueError where a line is not 'v x y z [w]'."""
    values, counts = line_values(VERTEX_LINE.findall(with_plain_line_breaks(text)))
    if counts.size and counts.min() < 3:
        raise ValueError("a vertex with fewer than three coordinates")
    return values[((np.cumsum(counts) - counts)[:, None] + np.arange(3))].reshape(-1, 3)


def parse_obj_vectorised(text: str) -> tuple[np.ndarray, np.ndarray]:
    """read_obj's result from numpy's text parser over all vertex lines and all face lines at once (face indices
    counting from 1); ValueError for anything else, which parse_obj_by_line then reads and names."""
    text = with_plain_line_breaks(text)
    positions = parse_positions(text)
    face_lines = FACE_LINE.findall(text)
    if any("/" in line for line in face_lines):
        face_lines = [SLASHED_PART.sub("", line) for line in face_lines]
    if NOT_WHOLE_NUMBERS.search("\n".join(face_lines)):
        raise ValueError("a face index that is not a whole number")
    values, counts = line_values(face_lines)
    return positions, fan_triangles(values, counts, len(positions))


def line_values(lines: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Every number of `lines` (float64, flat) and how many each line has: numpy's C parser when every line has
    as many as the first (the usual 'x y z' and 'a b c'), a split per line otherwise. ValueError for a token that
    is not a number."""
    if not lines:
        return np.zeros(0), np.zeros(0, np.int64)
    try:
        table = np.loadtxt(io.StringIO("\n".join(lines)), dtype=np.float64, ndmin=2, comments=None)
        if len(table) == len(lines):  # the parser skips blank lines, which would shift the rows
            return table.reshape(-1), np.full(len(lines), table.shape[1], np.int64)
    except ValueError:
        pass  # lines of different lengths, or not numbers: the split below tells which
    split = [line.split() for line in lines]
    counts = np.fromiter((len(tokens) for tokens in split), dtype=np.int64, count=len(split))
    return np.array([float(token) for tokens in split for token in tokens]), counts


def fan_triangles(values: np.ndarray, counts: np.ndarray, vertex_count: int) -> np.ndarray:
    """int32 (T, 3): each face line's corners (1-based, in `values`) split into a fan (c0, ck, ck+1)."""
    if counts.size and counts.min() < 3:
        raise ValueError("a face with fewer than three corners")
    per_face = counts - 2  # triangles in each face's fan
    face_of_triangle = np.repeat(np.arange(len(counts)), per_face)
    step = np.arange(len(face_of_triangle)) - np.repeat(np.cumsum(per_face) - per_face, per_face)
    first = (np.cumsum(counts) - counts)[face_of_triangle]  # each face's first corner
    indices = values[np.stack([first, first + step + 1, first + step + 2], axis=1)]
    if indices.size and not (np.all(indices >= 1) and np.all(indices <= vertex_count)
                             and np.array_equal(indices, np.floor(indices))):
        raise ValueError("a face index that is not a vertex counted from 1")
    return (indices - 1).astype(np.int32).reshape(-1, 3)


def parse_obj_by_line(lines: list[str], path: str, with_faces: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """read_obj's result, one line at a time: negative indices, and errors naming the line (no faces read
    without with_faces)."""
    vertices, triangles = [], []
    for number, line in enumerate(lines, 1):
        if line.startswith("v "):
            parts = line.split()
            if len(parts) < 4:
                raise SkinkitError(f"{path}:{number}: a vertex needs three coordinates")
            try:
                vertices.append([float(part) for part in parts[1:4]])
            except ValueError:
                raise SkinkitError(f"{path}:{number}: a vertex coordinate is not a number") from None
        elif with_faces and line.startswith("f "):
            corners = [corner_index(token.split("/")[0], len(vertices), path, number, "vertex")
                       for token in line.split()[1:]]
            if len(corners) < 3:
                raise SkinkitError(f"{path}:{number}: a face needs at least three corners")
            triangles.extend((corners[0], corners[k], corners[k + 1]) for k in range(1, len(corners) - 1))
    positions = np.array(vertices, dtype=np.float64).reshape(-1, 3)
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
    """(positions (F, V, 3), triangles of the first file); every file must have the same vertex count. The later
    files' faces are not read (a sequence has one topology). Files are read by a pool of threads (file reads and
    numpy's parser release the interpreter lock)."""
    if not isinstance(paths, (list, tuple)) or not paths:
        raise SkinkitError(f"paths: expected a list of OBJ files, got {paths!r:.60}")
    with ThreadPoolExecutor(max_workers=min(len(paths), READER_THREADS)) as pool:
        later = pool.map(read_obj_positions, paths[1:])
        first, triangles = read_obj(paths[0])
        frames = [first] + list(later)
    for path, positions in zip(paths, frames):
        if len(positions) != len(first):
            raise SkinkitError(f"{path}: {len(positions)} vertices, but {paths[0]} has {len(first)}; "
                               "a sequence needs the same vertices in the same order in every file")
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
    stream.write(formatted_rows("v %.9g %.9g %.9g\n", positions))
    if triangles is None or not len(triangles):
        return
    if corner_uv is None:
        stream.write(formatted_rows("f %d %d %d\n", triangles + 1))
        return
    keys = np.column_stack([triangles.reshape(-1), corner_uv.reshape(-1, 2)])
    distinct, texture_index = np.unique(keys, axis=0, return_inverse=True)
    stream.write(formatted_rows("vt %.9g %.9g\n", distinct[:, 1:]))
    corners = np.stack([triangles.reshape(-1) + 1, texture_index.reshape(-1) + 1], axis=1).reshape(-1, 6)
    stream.write(formatted_rows("f %d/%d %d/%d %d/%d\n", corners))


def formatted_rows(row_format: str, rows: np.ndarray) -> str:
    """Every row of `rows` through `row_format`, as one string: a single %-operation over the whole array, many
    times faster than formatting row by row."""
    return (row_format * len(rows)) % tuple(rows.reshape(-1).tolist())


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
