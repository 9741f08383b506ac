"""Where a character's parts come from (Vasilakis 2008 assumes a segmented mesh; issue 15 lists the sources): loose
parts that share their opening vertices, OBJ `g`/`o` groups or `usemtl` materials, a face attribute, per-vertex
labels such as the dominant bone of linear-blend weights or the rigid clusters of `skinkit.decompose`.

Every source ends as one part id per triangle, numbered 0..P-1 in order of first appearance, with the parts' names.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._checks import INPUT_FILE, OUTPUT_FILE, as_index_array, as_real_array, checked, choice, real
from ..meshio import corner_index, read_text_lines
from ..model import SkinkitError

__all__ = ["Parts", "compact", "from_vertex_labels", "from_weights", "loose_parts", "read_obj_groups", "read_dmat",
           "write_obj_groups"]


@dataclass(frozen=True)
class Parts:
    """A mesh and its triangles' parts: positions (V, 3), triangles (T, 3), triangle_parts (T,), names (P)."""
    positions: np.ndarray
    triangles: np.ndarray
    triangle_parts: np.ndarray
    names: tuple[str, ...]

    @property
    def part_count(self) -> int:
        return len(self.names)

    def vertex_parts(self) -> np.ndarray:
        """Each vertex's part: that of the first triangle using it (opening vertices go to one side); -1 unused."""
        labels = np.full(len(self.positions), -1, dtype=np.int32)
        order = np.arange(len(self.triangles) * 3)[::-1]  # assign backwards so the first triangle wins
        labels[self.triangles.reshape(-1)[order]] = np.repeat(self.triangle_parts, 3)[order]
        return labels


def compact(labels, names=None) -> tuple[np.ndarray, tuple[str, ...]]:
    """Renumbers labels 0..P-1 in order of first appearance; names (indexed by the old label) follow them."""
    labels = as_index_array(labels, "labels", shape=(None,))
    if names is not None:
        if isinstance(names, (str, bytes)) or not isinstance(names, (list, tuple, np.ndarray)):
            raise SkinkitError(f"names: expected a list of part names, got {type(names).__name__}")
        if len(labels) and (labels.min() < 0 or labels.max() >= len(names)):
            raise SkinkitError(f"names: {len(names)} names, but the labels run from {labels.min()} to {labels.max()}")
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.argsort(np.argsort(first))
    kept = labels[np.sort(first)]
    new_names = tuple(str(names[int(k)]) if names is not None else f"part_{int(k)}" for k in kept)
    return rank[inverse].astype(np.int32), new_names


def from_vertex_labels(positions, triangles, vertex_labels, names=None) -> Parts:
    """Parts from one label per vertex (dominant bone, rigid cluster, vertex group): each triangle takes the label
    most of its corners have (the first corner's when all differ)."""
    positions = as_real_array(positions, "positions", shape=(None, 3))
    triangles = as_index_array(triangles, "triangles", shape=(None, 3))
    labels = as_index_array(vertex_labels, "vertex_labels", shape=(len(positions),))
    check_corners(triangles, len(positions))
    corners = labels[triangles]
    majority = np.where(corners[:, 1] == corners[:, 2], corners[:, 1], corners[:, 0])
    triangle_labels, part_names = compact(majority, names)
    return Parts(positions, triangles, triangle_labels, part_names)


@checked(path=INPUT_FILE)
def read_dmat(path: str) -> np.ndarray:
    """A libigl dense matrix file (`cols rows`, then the values column by column) as (rows, cols)."""
    lines = read_text_lines(path)
    try:
        cols, rows = (int(v) for v in lines[0].split()[:2])
        values = np.array(" ".join(lines[1:]).split(), dtype=np.float64)
    except (ValueError, IndexError):
        raise SkinkitError(f"{path}: not a DMAT file (a first line `cols rows`, then numbers)") from None
    if values.size != rows * cols:
        raise SkinkitError(f"{path}: {values.size} values for a {rows} x {cols} matrix")
    return values.reshape(cols, rows).T


def check_corners(triangles: np.ndarray, vertex_count: int) -> None:
    if triangles.size and (triangles.min() < 0 or triangles.max() >= vertex_count):
        bad = int(np.flatnonzero((triangles < 0).any(axis=1) | (triangles >= vertex_count).any(axis=1))[0])
        raise SkinkitError(f"triangles: triangle {bad} uses a vertex outside [0, {vertex_count})")


def from_weights(positions, triangles, weights, names=None) -> Parts:
    """Parts from linear-blend weights (V, B): each vertex's dominant bone."""
    positions = as_real_array(positions, "positions", shape=(None, 3))
    weights = as_real_array(weights, "weights", shape=(len(positions), None))
    return from_vertex_labels(positions, triangles, np.argmax(weights, axis=1).astype(np.int32),
                              names if names is not None else [f"bone_{b}" for b in range(weights.shape[1])])


def _components(triangles: np.ndarray, vertex_count: int) -> np.ndarray:
    """Connected components of triangles through shared vertices (union-find), one id per triangle."""
    parent = np.arange(vertex_count)

    def find(v):
        root = v
        while parent[root] != root:
            root = parent[root]
        while parent[v] != root:
            parent[v], v = root, parent[v]
        return root

    for a, b, c in triangles.tolist():
        ra, rb, rc = find(a), find(b), find(c)
        parent[rb] = ra
        parent[find(rc)] = ra
    return np.array([find(int(v)) for v in triangles[:, 0]], dtype=np.int64)


@checked(tolerance=real(minimum=0))
def loose_parts(positions, triangles, tolerance: float = 1e-6) -> Parts:
    """Parts from loose pieces that meet at coincident opening vertices: each connected piece is a part, then
    vertices closer than tolerance times the diagonal are welded so the pieces share their openings."""
    positions = as_real_array(positions, "positions", shape=(None, 3))
    triangles = as_index_array(triangles, "triangles", shape=(None, 3))
    check_corners(triangles, len(positions))
    labels, names = compact(_components(triangles, len(positions)))
    diagonal = float(np.linalg.norm(positions.max(axis=0) - positions.min(axis=0))) if len(positions) else 0.0
    step = max(tolerance * diagonal, 1e-300)
    keys = np.round(positions / step).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    welded = positions[first]
    return Parts(welded, inverse.reshape(-1)[triangles].astype(np.int32), labels,
                 tuple(f"piece_{k}" for k in range(len(names))))


@checked(path=INPUT_FILE, key=choice(("groups", "materials")))
def read_obj_groups(path: str, key: str = "groups") -> Parts:
    """An OBJ's triangles with their `g`/`o` group (key "groups") or `usemtl` material (key "materials") as parts;
    polygons split into fans as skinkit.meshio.read_obj splits them."""
    if key not in ("groups", "materials"):
        raise SkinkitError(f"key {key!r}: expected 'groups' or 'materials'")
    statements = ("g ", "o ") if key == "groups" else ("usemtl ",)
    vertices, triangles, labels, names, current = [], [], [], {}, "default"
    for number, line in enumerate(read_text_lines(path), 1):
        if line.startswith("v "):
            vertices.append(line.split()[1:4])
        elif line.startswith(statements):
            current = line.split(maxsplit=1)[1].strip() if len(line.split()) > 1 else "default"
        elif line.startswith("f "):
            corners = [corner_index(token.split("/")[0], len(vertices), path, number, "vertex")
                       for token in line.split()[1:]]
            if len(corners) < 3:
                raise SkinkitError(f"{path}:{number}: a face needs at least three corners")
            label = names.setdefault(current, len(names))
            for k in range(1, len(corners) - 1):
                triangles.append((corners[0], corners[k], corners[k + 1]))
                labels.append(label)
    try:
        positions = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    except ValueError:
        raise SkinkitError(f"{path}: a vertex coordinate is not a number") from None
    if not triangles:
        raise SkinkitError(f"{path}: no faces")
    faces = np.array(triangles, dtype=np.int64)
    if faces.max() >= len(positions):
        raise SkinkitError(f"{path}: a face refers to vertex {faces.max() + 1}, but the file has {len(positions)}")
    by_label = {label: name for name, label in names.items()}
    part_ids, part_names = compact(np.array(labels), [by_label[k] for k in range(len(by_label))])
    return Parts(positions, faces.astype(np.int32), part_ids, part_names)


@checked(path=OUTPUT_FILE, parts=Parts)
def write_obj_groups(path: str, parts: Parts) -> str:
    """The parts as an OBJ with one `g` group per part (read_obj_groups reads it back in the same vertex order)."""
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in parts.positions.tolist()]
    for part, name in enumerate(parts.names):
        lines.append(f"g {name}")
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in parts.triangles[parts.triangle_parts == part].tolist()]
    with open(path, "w", encoding="utf-8") as stream:
        stream.write("\n".join(lines) + "\n")
    return path
