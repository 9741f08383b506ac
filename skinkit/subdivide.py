"""Subdivision in animation space (Merry 2007, section 4.2): V' = V S with S from the connectivity alone, so
P' = P S and G P' = V S: the subdivided model deforms exactly as the subdivided posed mesh, in every pose.

Each new vertex's p is the same linear combination of its parents' p's as its position is of theirs, on the union
of their influence sets, summed per bone. Two schemes, with Blender's Subdivision Surface conventions (OpenSubdiv,
"Limit Surface" off, so the vertices are the refined cage's):
  "catmull-clark": any polygons (quads, triangles, n-gons), each n-gon becoming n quads;
  "loop": triangles only, each becoming 4.
Boundaries: "all" (Blender's Smooth "All": boundary vertices 3/4 v + 1/8 of their two boundary neighbours) or
"preserve-corners" (the same, but a vertex in a single face stays where it is). Creases are not read.
UVs (per face corner) are subdivided face-varying, as Blender's UV Smooth: "none" (linear), "preserve-corners",
"preserve-boundaries" or "all" (see UV_SMOOTHING). New vertices are ordered: the old vertices, then one per edge,
then (Catmull-Clark) one per face.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._checks import CALLBACK, as_index_array, as_real_array, checked
from .model import AnimationSpaceModel, SkinkitError

__all__ = ["subdivide", "Subdivision", "SCHEMES", "BOUNDARIES", "UV_SMOOTHING"]

SCHEMES = ("catmull-clark", "loop")
#: Blender's boundary_smooth: "ALL" and "PRESERVE_CORNERS".
BOUNDARIES = ("all", "preserve-corners")
#: Blender's uv_smooth: "NONE", "PRESERVE_CORNERS", "PRESERVE_BOUNDARIES", "SMOOTH_ALL".
UV_SMOOTHING = ("none", "preserve-corners", "preserve-boundaries", "all")
MAX_LEVELS = 6


@dataclass(frozen=True, eq=False)
class Polygons:
    """Polygons in compressed rows: polygon f has corners[offsets[f]:offsets[f+1]] (vertex indices)."""

    offsets: np.ndarray
    corners: np.ndarray

    @property
    def count(self) -> int:
        return len(self.offsets) - 1

    def sizes(self) -> np.ndarray:
        return np.diff(self.offsets)

    def as_array(self):
        """(F, n) when every polygon has n corners, else (offsets, corners)."""
        sizes = self.sizes()
        if self.count and np.all(sizes == sizes[0]):
            return self.corners.reshape(self.count, int(sizes[0]))
        return self.offsets, self.corners


def polygon_rows(polygons) -> list:
    """A list of index sequences as lists of vertex indices, each of at least 3 corners."""
    try:
        rows = [list(p) for p in polygons]
    except TypeError:
        raise SkinkitError(f"polygons: expected (F, n) vertex indices, a list of index lists or (offsets, corners), "
                           f"got {type(polygons).__name__}") from None
    if any(len(r) < 3 for r in rows):
        raise SkinkitError("polygons: each needs at least 3 corners")
    return rows


def checked_polygons(polygons, vertex_count: int) -> Polygons:
    """(F, n) int array, a list of index sequences, or (offsets, corners)."""
    if isinstance(polygons, Polygons):
        result = polygons
    elif isinstance(polygons, tuple) and len(polygons) == 2 and np.ndim(polygons[0]) == 1 and \
            np.ndim(polygons[1]) == 1 and len(polygons[0]) and np.asarray(polygons[0])[0] == 0:
        offsets = as_index_array(polygons[0], "polygons offsets", (None,))
        corners = as_index_array(polygons[1], "polygons corners", (None,))
        if np.any(np.diff(offsets) < 3) or offsets[-1] != len(corners):
            raise SkinkitError("polygons: offsets must start at 0, grow by at least 3 and end at the corner count")
        result = Polygons(offsets, corners)
    else:
        try:
            array = np.asarray(polygons)
        except ValueError:
            array = None
        if array is not None and array.ndim == 2 and array.dtype.kind in "iu":
            array = as_index_array(array, "polygons", (None, None))
            if array.shape[1] < 3:
                raise SkinkitError(f"polygons: each needs at least 3 corners, got {array.shape[1]}")
            result = Polygons(np.arange(0, array.size + 1, array.shape[1], dtype=np.int32), array.reshape(-1))
        else:
            rows = polygon_rows(polygons)
            offsets = np.zeros(len(rows) + 1, np.int32)
            np.cumsum([len(r) for r in rows], out=offsets[1:])
            result = Polygons(offsets, as_index_array(np.concatenate(rows) if rows else [], "polygons", (None,)))
    if result.count == 0:
        raise SkinkitError("polygons: there are none")
    if result.corners.min() < 0 or result.corners.max() >= vertex_count:
        bad = int(np.flatnonzero((result.corners < 0) | (result.corners >= vertex_count))[0])
        polygon = int(np.searchsorted(result.offsets, bad, side="right") - 1)
        raise SkinkitError(f"polygons: polygon {polygon} uses vertex {int(result.corners[bad])}, outside "
                           f"[0, {vertex_count})")
    return result


# ---- one level: the sparse matrix of new vertices over old ones --------------------------------------------------


@dataclass(frozen=True, eq=False)
class Stencils:
    """new = S old as COO entries (rows, columns, weights) of shape (new_count, old_count)."""

    rows: np.ndarray
    columns: np.ndarray
    weights: np.ndarray
    new_count: int

    def apply(self, values: np.ndarray) -> np.ndarray:
        out = np.zeros((self.new_count,) + values.shape[1:])
        np.add.at(out, self.rows, self.weights.reshape((-1,) + (1,) * (values.ndim - 1)) * values[self.columns])
        return out


def entries(*parts):
    rows, columns, weights = zip(*parts) if parts else ((), (), ())
    return (np.concatenate([np.asarray(r, np.int64).reshape(-1) for r in rows]),
            np.concatenate([np.asarray(c, np.int64).reshape(-1) for c in columns]),
            np.concatenate([np.asarray(w, np.float64).reshape(-1) for w in weights]))


@dataclass(frozen=True, eq=False)
class Topology:
    vertex_count: int
    polygons: Polygons
    edges: np.ndarray          # (E, 2) sorted vertex pairs
    corner_edge: np.ndarray    # (corners,) the edge from corner i to the next corner of its polygon
    edge_faces: np.ndarray     # (E,) how many polygons use the edge
    corner_polygon: np.ndarray  # (corners,)

    @classmethod
    def of(cls, polygons: Polygons, vertex_count: int, what: str = "the mesh") -> "Topology":
        sizes = polygons.sizes()
        corner_polygon = np.repeat(np.arange(polygons.count), sizes)
        start = np.repeat(polygons.offsets[:-1], sizes)
        position = np.arange(len(polygons.corners)) - start
        following = polygons.corners[start + (position + 1) % np.repeat(sizes, sizes)]
        pairs = np.sort(np.column_stack([polygons.corners, following]), axis=1)
        if np.any(pairs[:, 0] == pairs[:, 1]):
            polygon = int(corner_polygon[np.flatnonzero(pairs[:, 0] == pairs[:, 1])[0]])
            raise SkinkitError(f"{what}: polygon {polygon} repeats a vertex")
        key = pairs[:, 0].astype(np.int64) * vertex_count + pairs[:, 1]
        unique, corner_edge = np.unique(key, return_inverse=True)
        edges = np.column_stack([unique // vertex_count, unique % vertex_count])
        edge_faces = np.bincount(corner_edge, minlength=len(unique))
        if edge_faces.max() > 2:
            a, b = edges[int(np.argmax(edge_faces))]
            raise SkinkitError(f"{what}: edge ({a}, {b}) is shared by {edge_faces.max()} faces (non-manifold); "
                               "subdivision needs each edge in at most 2")
        return cls(vertex_count, polygons, edges, corner_edge.astype(np.int64), edge_faces, corner_polygon)

    def next_corner(self) -> np.ndarray:
        sizes = self.polygons.sizes()
        start = np.repeat(self.polygons.offsets[:-1], sizes)
        position = np.arange(len(self.polygons.corners)) - start
        return start + (position + 1) % np.repeat(sizes, sizes)

    def previous_corner(self) -> np.ndarray:
        sizes = self.polygons.sizes()
        start = np.repeat(self.polygons.offsets[:-1], sizes)
        position = np.arange(len(self.polygons.corners)) - start
        return start + (position - 1) % np.repeat(sizes, sizes)


def vertex_rules(topology: Topology, boundary: str, interior_weights):
    """The entries of the old vertices' new positions (rows 0..V-1).

    interior_weights(valence) -> (self weight, per-neighbour weight, per-face-point weight or None).
    Returns (entries of the vertex-point rows over old vertices, face-point entries (row, face, weight) or empty).
    """
    V = topology.vertex_count
    edges = topology.edges
    faces_of_vertex = np.bincount(topology.polygons.corners, minlength=V)
    boundary_edge = topology.edge_faces == 1
    ends = edges.reshape(-1)
    others = edges[:, ::-1].reshape(-1)
    edge_of_end = np.repeat(np.arange(len(edges)), 2)
    valence = np.bincount(ends, minlength=V)
    boundary_count = np.bincount(ends[np.repeat(boundary_edge, 2)], minlength=V)
    is_boundary = boundary_count > 0
    corner = (boundary_count > 2) | (faces_of_vertex == 0)  # non-manifold vertices and loose vertices stay
    if boundary == "preserve-corners":
        corner |= is_boundary & (faces_of_vertex == 1)
    smooth_boundary = is_boundary & ~corner
    interior = ~is_boundary & ~corner
    parts = [(np.flatnonzero(corner), np.flatnonzero(corner), np.ones(int(corner.sum())))]
    # Boundary: 3/4 v + 1/8 of each of its two boundary neighbours.
    on = smooth_boundary[ends] & boundary_edge[edge_of_end]
    parts.append((np.flatnonzero(smooth_boundary), np.flatnonzero(smooth_boundary),
                  np.full(int(smooth_boundary.sum()), 0.75)))
    parts.append((ends[on], others[on], np.full(int(on.sum()), 0.125)))
    # Interior.
    n = valence[interior]
    own, neighbour, face = interior_weights(n)
    parts.append((np.flatnonzero(interior), np.flatnonzero(interior), own))
    inner = interior[ends]
    per_vertex_neighbour = np.zeros(V)
    per_vertex_neighbour[interior] = neighbour
    parts.append((ends[inner], others[inner], per_vertex_neighbour[ends[inner]]))
    face_parts = None
    if face is not None:
        per_vertex_face = np.zeros(V)
        per_vertex_face[interior] = face
        corners = topology.polygons.corners
        mask = interior[corners]
        face_parts = (corners[mask], topology.corner_polygon[mask], per_vertex_face[corners[mask]])
    return parts, face_parts


def catmull_clark_level(topology: Topology, boundary: str):
    """(stencils, new polygons (F', 4) as Polygons)."""
    V, E, F = topology.vertex_count, len(topology.edges), topology.polygons.count
    polygons = topology.polygons
    sizes = polygons.sizes()
    # Face points over old vertices.
    face_rows = topology.corner_polygon
    face_entries = (face_rows, polygons.corners, 1.0 / sizes[face_rows])

    def expand_faces(rows, faces, weights):
        """Entries weight * facepoint(face) expanded onto old vertices."""
        counts = sizes[faces]
        corner_index = np.repeat(polygons.offsets[:-1][faces], counts) + \
            (np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts))
        return (np.repeat(rows, counts), polygons.corners[corner_index], np.repeat(weights / counts, counts))

    # Vertex points: (n-2)/n v + 1/n^2 Σ neighbours + 1/n^2 Σ face points.
    vertex_parts, face_parts = vertex_rules(
        topology, boundary, lambda n: ((n - 2.0) / n, 1.0 / n ** 2, 1.0 / n ** 2))
    parts = list(vertex_parts)
    parts.append(expand_faces(*face_parts))
    # Edge points: interior (a + b + f0 + f1) / 4, boundary (a + b) / 2.
    interior_edge = topology.edge_faces == 2
    edge_weight = np.where(interior_edge, 0.25, 0.5)
    rows = V + np.arange(E)
    parts.append((rows, topology.edges[:, 0], edge_weight))
    parts.append((rows, topology.edges[:, 1], edge_weight))
    inner_corner = interior_edge[topology.corner_edge]
    parts.append(expand_faces(V + topology.corner_edge[inner_corner], topology.corner_polygon[inner_corner],
                              np.full(int(inner_corner.sum()), 0.25)))
    parts.append((V + E + face_entries[0], face_entries[1], face_entries[2]))
    stencils = Stencils(*entries(*parts), V + E + F)
    return stencils, quads_of(topology, V, V + E)


def quads_of(topology: Topology, edge_base: int, face_base: int) -> Polygons:
    """Each polygon's corner i becomes the quad (v_i, edge(i, i+1), face, edge(i-1, i))."""
    corners = topology.polygons.corners
    quads = np.column_stack([corners, edge_base + topology.corner_edge, face_base + topology.corner_polygon,
                             edge_base + topology.corner_edge[topology.previous_corner()]])
    return Polygons(np.arange(0, quads.size + 1, 4, dtype=np.int32), quads.reshape(-1).astype(np.int32))


def loop_beta(n):
    n = np.asarray(n, np.float64)
    return (0.625 - (0.375 + 0.25 * np.cos(2 * np.pi / n)) ** 2) / n


def loop_level(topology: Topology, boundary: str):
    """(stencils, new triangles as Polygons)."""
    V, E = topology.vertex_count, len(topology.edges)
    if np.any(topology.polygons.sizes() != 3):
        raise SkinkitError("polygons: the Loop scheme needs triangles (triangulate, or use Catmull-Clark)")
    vertex_parts, _ = vertex_rules(topology, boundary, lambda n: (1.0 - n * loop_beta(n), loop_beta(n), None))
    parts = list(vertex_parts)
    interior_edge = topology.edge_faces == 2
    rows = V + np.arange(E)
    edge_weight = np.where(interior_edge, 0.375, 0.5)
    parts.append((rows, topology.edges[:, 0], edge_weight))
    parts.append((rows, topology.edges[:, 1], edge_weight))
    # The opposite vertex of each triangle across an interior edge: 1/8.
    corners = topology.polygons.corners
    opposite = corners[topology.next_corner()[topology.next_corner()]]
    inner = interior_edge[topology.corner_edge]
    parts.append((V + topology.corner_edge[inner], opposite[inner], np.full(int(inner.sum()), 0.125)))
    stencils = Stencils(*entries(*parts), V + E)
    triangles = corners.reshape(-1, 3)
    e = (V + topology.corner_edge).reshape(-1, 3)  # e[:, 0] = edge ab, 1 = bc, 2 = ca
    new = np.concatenate([np.column_stack([triangles[:, 0], e[:, 0], e[:, 2]]),
                          np.column_stack([triangles[:, 1], e[:, 1], e[:, 0]]),
                          np.column_stack([triangles[:, 2], e[:, 2], e[:, 1]]),
                          e], axis=1).reshape(-1, 3)
    return stencils, Polygons(np.arange(0, new.size + 1, 3, dtype=np.int32), new.reshape(-1).astype(np.int32))


# ---- UVs: the same rules on the face-varying topology -----------------------------------------------------------


def uv_level(topology: Topology, uv: np.ndarray, scheme: str, smoothing: str):
    """Per-corner uv of the new polygons."""
    corners = topology.polygons.corners
    # Face-varying values: one per (vertex, uv) pair.
    rounded = np.round(uv, 9)
    keys = np.column_stack([corners.astype(np.float64), rounded])
    value_of_corner = np.unique(keys, axis=0, return_inverse=True)[1].reshape(-1).astype(np.int32)
    value_count = int(value_of_corner.max()) + 1
    values = np.zeros((value_count, 2))
    values[value_of_corner] = uv
    fvar_topology = Topology.of(Polygons(topology.polygons.offsets, value_of_corner), value_count, "the uv map")
    if smoothing == "none":
        stencils = linear_level(fvar_topology, scheme)
    else:
        stencils = fvar_smooth_level(fvar_topology, scheme, smoothing)
    new_values = stencils.apply(values)
    # Map new polygons' corners to new fvar values: the same construction with fvar indices.
    fvar_new = (catmull_clark_corners if scheme == "catmull-clark" else loop_corners)(fvar_topology)
    return new_values[fvar_new]


def catmull_clark_corners(topology: Topology) -> np.ndarray:
    V, E = topology.vertex_count, len(topology.edges)
    return quads_of(topology, V, V + E).corners


def loop_corners(topology: Topology) -> np.ndarray:
    V = topology.vertex_count
    corners = topology.polygons.corners.reshape(-1, 3)
    e = (V + topology.corner_edge).reshape(-1, 3)
    return np.concatenate([np.column_stack([corners[:, 0], e[:, 0], e[:, 2]]),
                           np.column_stack([corners[:, 1], e[:, 1], e[:, 0]]),
                           np.column_stack([corners[:, 2], e[:, 2], e[:, 1]]), e], axis=1).reshape(-1)


def linear_level(topology: Topology, scheme: str) -> Stencils:
    """Linear interpolation: old values kept, edge midpoints, face centroids (Catmull-Clark)."""
    V, E, F = topology.vertex_count, len(topology.edges), topology.polygons.count
    rows = V + np.arange(E)
    parts = [(np.arange(V), np.arange(V), np.ones(V)), (rows, topology.edges[:, 0], np.full(E, 0.5)),
             (rows, topology.edges[:, 1], np.full(E, 0.5))]
    if scheme == "catmull-clark":
        sizes = topology.polygons.sizes()
        parts.append((V + E + topology.corner_polygon, topology.polygons.corners, 1.0 / sizes[topology.corner_polygon]))
        return Stencils(*entries(*parts), V + E + F)
    return Stencils(*entries(*parts), V + E)


def fvar_smooth_level(topology: Topology, scheme: str, smoothing: str) -> Stencils:
    """The scheme's rules on the uv values' own topology; its boundaries are the mesh's and the seams.
    preserve-corners: island corners (a value in one face) stay; preserve-boundaries: every boundary value stays and
    boundary edges take midpoints (they are linear); all: boundaries smoothed like the mesh's ("all")."""
    stencils = (catmull_clark_level if scheme == "catmull-clark" else loop_level)(
        topology, "preserve-corners" if smoothing == "preserve-corners" else "all")[0]
    if smoothing != "preserve-boundaries":
        return stencils
    V = topology.vertex_count
    boundary_edge = topology.edge_faces == 1
    on_boundary = np.zeros(V, bool)
    on_boundary[topology.edges[boundary_edge].reshape(-1)] = True
    keep = ~(on_boundary[np.minimum(stencils.rows, V - 1)] & (stencils.rows < V))
    parts = [(stencils.rows[keep], stencils.columns[keep], stencils.weights[keep]),
             (np.flatnonzero(on_boundary), np.flatnonzero(on_boundary), np.ones(int(on_boundary.sum())))]
    return Stencils(*entries(*parts), stencils.new_count)


# ---- the model ------------------------------------------------------------------------------------------------


def subdivided_model(stencils: Stencils, model: AnimationSpaceModel) -> AnimationSpaceModel:
    """p'_r = Σ_c S_rc p_c on the union of the parents' influence sets, summed per bone."""
    counts = model.counts()
    repeats = counts[stencils.columns]
    total = int(repeats.sum())
    row = np.repeat(stencils.rows, repeats)
    influence = np.repeat(model.offsets[:-1][stencils.columns], repeats) + \
        (np.arange(total) - np.repeat(np.cumsum(repeats) - repeats, repeats))
    key = row * model.bone_count + model.bones[influence]
    unique, slot = np.unique(key, return_inverse=True)
    coordinates = np.zeros((len(unique), 4))
    weights = np.repeat(stencils.weights, repeats)[:, None] * model.coordinates[influence]
    for axis in range(4):
        coordinates[:, axis] = np.bincount(slot, weights[:, axis], minlength=len(unique))
    rows = unique // model.bone_count
    offsets = np.zeros(stencils.new_count + 1, np.int32)
    np.cumsum(np.bincount(rows, minlength=stencils.new_count), out=offsets[1:])
    return AnimationSpaceModel(offsets, (unique % model.bone_count).astype(np.int32), coordinates, model.bone_count)


@dataclass(frozen=True, eq=False)
class Subdivision:
    """The result: polygons ((F', 4) quads or (F', 3) triangles), the model on the new vertices, uv per new corner
    ((F' * n, 2), in the polygons' corner order) or None, and the stencils of each level (apply() subdivides any
    per-vertex data, such as the rest positions, the same way)."""

    polygons: np.ndarray
    model: AnimationSpaceModel
    uv: np.ndarray | None
    levels: tuple

    def apply(self, values) -> np.ndarray:
        """values: (V, ...) one row per vertex of the mesh that was subdivided."""
        values = as_real_array(values, "values")
        needed = int(self.levels[0].columns.max()) + 1 if self.levels else 0
        if values.ndim == 0 or len(values) < needed:
            raise SkinkitError(f"values: expected one row per vertex of the subdivided mesh (at least {needed}), "
                               f"got shape {values.shape}")
        for stencils in self.levels:
            values = stencils.apply(values)
        return values


@checked(progress=CALLBACK)
def subdivide(polygons, model: AnimationSpaceModel, *, levels: int = 1, scheme: str = "catmull-clark", uv=None,
              boundary: str = "all", uv_smooth: str = "preserve-corners", progress=None) -> Subdivision:
    """Subdivides the mesh `polygons` ((F, n) vertex indices, a list of index lists, or (offsets, corners)) of the
    model's vertices `levels` times with `scheme` (SCHEMES), applied to the animation-space coordinates.

    boundary: one of BOUNDARIES; uv: (corners, 2) per face corner in the polygons' corner order, smoothed by
    uv_smooth (UV_SMOOTHING). progress(fraction) may return True to cancel (SkinkitError).
    """
    if not isinstance(model, AnimationSpaceModel):
        raise SkinkitError(f"model: expected a skinkit.AnimationSpaceModel, got {type(model).__name__}")
    if not isinstance(scheme, str) or scheme not in SCHEMES:  # an array's `in` compares elementwise
        raise SkinkitError(f"scheme: must be one of {SCHEMES}, not {scheme!r}")
    if not isinstance(boundary, str) or boundary not in BOUNDARIES:  # an array's `in` compares elementwise
        raise SkinkitError(f"boundary: must be one of {BOUNDARIES}, not {boundary!r}")
    if not isinstance(uv_smooth, str) or uv_smooth not in UV_SMOOTHING:  # an array's `in` compares elementwise
        raise SkinkitError(f"uv_smooth: must be one of {UV_SMOOTHING}, not {uv_smooth!r}")
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or not 1 <= levels <= MAX_LEVELS:
        raise SkinkitError(f"levels: expected a whole number in [1, {MAX_LEVELS}], got {levels!r}")
    mesh = checked_polygons(polygons, model.vertex_count)
    if uv is not None:
        uv = as_real_array(uv, "uv", shape=(len(mesh.corners), 2))
    level_function = catmull_clark_level if scheme == "catmull-clark" else loop_level
    done = []
    for level in range(int(levels)):
        topology = Topology.of(mesh, model.vertex_count, "polygons")
        stencils, new_mesh = level_function(topology, boundary)
        if uv is not None:
            uv = uv_level(topology, uv, scheme, uv_smooth)
        model = subdivided_model(stencils, model)
        mesh = new_mesh
        done.append(stencils)
        if progress is not None and progress((level + 1) / levels):
            raise SkinkitError("subdivision cancelled")
    width = 4 if scheme == "catmull-clark" else 3
    return Subdivision(mesh.corners.reshape(-1, width), model, uv, tuple(done))
