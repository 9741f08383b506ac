"""Rigid skinning with seam reconstruction (Vasilakis 2008, section 4.4, Algorithm 5) with a fixed topology.

Every vertex follows its part (v' = W v). Where parts meet, each vertex is split into one copy per wedge (a run of
its triangles of one part joined through their edges), so every part carries its own side of each opening. Any two
parts sharing an opening get a seam, parent and child or not (on meshes segmented by dominant weights, siblings and
cousins touch): between the two copies of each opening vertex a column of `steps` arc points, point k the vertex
moved by the shallower part's frame and then turned by the QLERP (eq. 4.1) of the relative motion about the deeper
part's joint at t = k / (steps + 1), the thesis' S1 arcs laid on every opening point. The columns along each shared
edge are joined by a strip of triangles, and where three or more parts meet at a vertex the columns there ring a
small hole that a fan to their mean closes (a local hole fill in place of Tight Cocone). The patch is triangulated
once, so the mesh is watertight and manifold with consistent orientation in every frame and its vertex count never
changes, which shape keys and mesh caches need. The thesis' removal of points sinking into the other part is not
done: they stay, hidden inside it. Normals are the area-weighted normals of the posed mesh.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .. import _core
from .._checks import as_index_array, as_real_array, checked, count
from ..model import SkinkitError
from .extract import Skeleton as BoneSkeleton
from .parts import Parts
from .animation import joint_frame

__all__ = ["SeamMesh", "prepare_seams", "prepare_seams_for_rig", "boundary_edges", "is_consistently_oriented", "vertex_normals"]


#: The most rings of arc points a seam is closed with.
MAX_STEPS = 256


@dataclass(frozen=True)
class SeamMesh:
    """The skinned mesh's fixed topology: for each output vertex its rest vertex (sources), its parts (parts_a, and
    parts_b -1 or the deeper part for arc points) and blend; triangles on the output vertices; per part pair the
    columns of its seam (ring_sizes); the hole-fill centres (cap_centres) with their ring points (cap_members:
    (centre slot, point) rows), each centre placed at the mean of its ring."""
    sources: np.ndarray
    parts_a: np.ndarray
    parts_b: np.ndarray
    blend: np.ndarray
    triangles: np.ndarray
    ring_sizes: dict
    constructed_points: int
    rest_positions: np.ndarray
    joints: np.ndarray
    prepare_seconds: float
    cap_centres: np.ndarray
    cap_members: np.ndarray

    def positions(self, world) -> np.ndarray:
        """The output vertices for world frames (P, 4, 4)."""
        world = as_real_array(world, "world", shape=(len(self.joints), 4, 4))
        out = np.zeros(3 * len(self.sources))
        _core.evaluate_seams(out, self.rest_positions.reshape(-1), np.ascontiguousarray(world, np.float64).reshape(-1),
                             self.joints.reshape(-1), self.sources, self.parts_a, self.parts_b, self.blend)
        out = out.reshape(-1, 3)
        if len(self.cap_centres):
            sums = np.zeros((len(self.cap_centres), 3))
            np.add.at(sums, self.cap_members[:, 0], out[self.cap_members[:, 1]])
            out[self.cap_centres] = sums / np.bincount(self.cap_members[:, 0], minlength=len(self.cap_centres))[:, None]
        return out


def _twins(triangles) -> np.ndarray:
    """Each directed edge 3 t + i (T[t, i] -> T[t, i + 1]) and the edge running back along it (-1 on a border)."""
    n = int(triangles.max(initial=0)) + 1
    start, end = triangles.reshape(-1), triangles[:, [1, 2, 0]].reshape(-1)
    keys = start.astype(np.int64) * n + end
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    repeated = np.flatnonzero(sorted_keys[1:] == sorted_keys[:-1])
    if len(repeated):
        edge = order[repeated[0]]
        raise SkinkitError(f"triangles: the edge ({start[edge]}, {end[edge]}) runs the same way in two triangles "
                           "(a non-manifold edge or inconsistent orientation)")
    reverse = end.astype(np.int64) * n + start
    found = np.clip(np.searchsorted(sorted_keys, reverse), 0, len(keys) - 1)
    return np.where(sorted_keys[found] == reverse, order[found], -1)


def _wedges(triangles, triangle_parts, twins) -> np.ndarray:
    """A wedge label per corner (3 t + i): corners of one vertex joined through edges between triangles of one
    part share it (label propagation with pointer jumping; a wedge spans at most one vertex's fan)."""
    edges = np.arange(len(twins))
    same = (twins >= 0) & (triangle_parts[edges // 3] == triangle_parts[np.maximum(twins, 0) // 3])
    e, t = edges[same], twins[same]
    end_corner = lambda k: 3 * (k // 3) + (k % 3 + 1) % 3  # noqa: E731 - the corner at the edge's end
    links = np.concatenate([np.stack([e, end_corner(t)], axis=1), np.stack([end_corner(e), t], axis=1)])
    label = np.arange(len(twins))
    while True:
        smallest = np.minimum(label[links[:, 0]], label[links[:, 1]])
        updated = label.copy()
        np.minimum.at(updated, links[:, 0], smallest)
        np.minimum.at(updated, links[:, 1], smallest)
        updated = updated[updated]
        if np.array_equal(updated, label):
            return label
        label = updated


def _depths(parents) -> np.ndarray:
    depth = np.zeros(len(parents), np.int64)
    for p in range(len(parents)):
        q, steps = int(parents[p]), 0
        while q >= 0 and steps <= len(parents):
            q, steps = int(parents[q]), steps + 1
        depth[p] = steps
    return depth


@checked(parts=Parts, skeleton=BoneSkeleton, steps=count(1, MAX_STEPS))
def prepare_seams(parts, skeleton, steps: int = 4) -> SeamMesh:
    """The fixed topology of the rigidly skinned mesh with `steps` (>= 1) arc rings at every joint."""
    joints, _ = joint_frame(skeleton)
    return prepare_seams_for_rig(parts, skeleton.part_parents, joints, steps)


@checked(parts=Parts, steps=count(1, MAX_STEPS))
def prepare_seams_for_rig(parts, parents, joints, steps: int = 4) -> SeamMesh:
    """prepare_seams for any rig: parents (P) and each part's joint (P, 3), e.g. an armature's bone heads."""
    if steps < 1:
        raise SkinkitError(f"steps {steps}: at least one ring of arc points closes a seam")
    started = time.perf_counter()
    triangles = np.array(parts.triangles, dtype=np.int64)
    triangle_parts = np.asarray(parts.triangle_parts, dtype=np.int64)
    parents = as_index_array(parents, "parents", shape=(parts.part_count,))
    if ((parents < -1) | (parents >= len(parents))).any():
        raise SkinkitError(f"parents: every parent must be -1 or a part in [0, {len(parents)})")
    joints = as_real_array(joints, "joints", shape=(parts.part_count, 3))
    vertex_count = len(parts.positions)
    twins = _twins(triangles)
    corner_wedge = _wedges(triangles, triangle_parts, twins)
    corner_vertex, corner_part = triangles.reshape(-1), np.repeat(triangle_parts, 3)
    # One output vertex per wedge: a vertex's first wedge keeps its index, the others are appended.
    wedges, first_corner = np.unique(corner_wedge, return_index=True)
    wedge_vertex, wedge_part = corner_vertex[first_corner], corner_part[first_corner]
    keeps = np.zeros(len(wedges), bool)
    keeps[np.unique(wedge_vertex, return_index=True)[1]] = True
    wedge_index = np.empty(len(wedges), np.int64)
    wedge_index[keeps] = wedge_vertex[keeps]
    wedge_index[~keeps] = vertex_count + np.arange((~keeps).sum())
    slot = np.searchsorted(wedges, corner_wedge)
    corner_output = wedge_index[slot]
    sources = [np.arange(vertex_count), wedge_vertex[~keeps]]
    parts_a = [parts.vertex_parts(), wedge_part[~keeps]]
    parts_a[0][wedge_vertex[keeps]] = wedge_part[keeps]
    next_index = vertex_count + int((~keeps).sum())
    # Crossing edges (their two triangles in different parts), once each: side a the triangle running u -> v.
    edges = np.arange(len(twins))
    crossing = edges[(twins >= 0) & (edges < twins) & (corner_part[edges] != corner_part[np.maximum(twins, 0)])]
    back = twins[crossing]
    end_corner = 3 * (crossing // 3) + (crossing % 3 + 1) % 3
    back_end = 3 * (back // 3) + (back % 3 + 1) % 3
    ua, ub, va, vb = slot[crossing], slot[back_end], slot[end_corner], slot[back]  # wedge slots
    # Columns: one per pair of wedges of a vertex that an edge separates, from the shallower part to the deeper.
    depth = _depths(parents)
    rank = depth[wedge_part] * (len(parents) + 1) + wedge_part
    pair_keys = np.concatenate([np.minimum(ua, ub) * len(wedges) + np.maximum(ua, ub),
                                np.minimum(va, vb) * len(wedges) + np.maximum(va, vb)])
    columns, column_of = np.unique(pair_keys, return_inverse=True)
    low, high = columns // len(wedges), columns % len(wedges)
    swap = rank[low] > rank[high]
    column_start, column_end = np.where(swap, high, low), np.where(swap, low, high)
    interior = next_index + np.arange(len(columns) * steps).reshape(len(columns), steps)
    next_index += interior.size
    sources.append(np.repeat(wedge_vertex[column_start], steps))
    parts_a.append(np.repeat(wedge_part[column_start], steps))
    parts_b = [np.full(next_index - interior.size, -1), np.repeat(wedge_part[column_end], steps)]
    blend = [np.zeros(next_index - interior.size), np.tile(np.arange(1, steps + 1) / (steps + 1), len(columns))]
    sequence = np.concatenate([wedge_index[column_start][:, None], interior, wedge_index[column_end][:, None]], axis=1)

    def oriented(column, from_slot):
        rows = sequence[column]
        return np.where((column_start[column] == from_slot)[:, None], rows, rows[:, ::-1])

    u = oriented(column_of[:len(crossing)], ua)
    v = oriented(column_of[len(crossing):], va)
    strips = [np.stack([v[:, :-1], u[:, :-1], u[:, 1:]], axis=2).reshape(-1, 3),
              np.stack([v[:, :-1], u[:, 1:], v[:, 1:]], axis=2).reshape(-1, 3)]
    # Holes where three or more parts meet: each column edge there is used once; a fan to a centre closes them.
    wedges_per_vertex = np.bincount(wedge_vertex, minlength=vertex_count)
    side_edges = np.concatenate([np.stack([u[:, :-1], u[:, 1:]], axis=2).reshape(-1, 2),
                                 np.stack([v[:, 1:], v[:, :-1]], axis=2).reshape(-1, 2)])
    side_vertex = np.concatenate([np.repeat(wedge_vertex[ua], steps + 1), np.repeat(wedge_vertex[va], steps + 1)])
    capped = wedges_per_vertex[side_vertex] >= 3
    cap_vertices, cap_slot = np.unique(side_vertex[capped], return_inverse=True)
    cap_centres = next_index + np.arange(len(cap_vertices))
    next_index += len(cap_vertices)
    sources.append(cap_vertices)
    parts_a.append(parts.vertex_parts()[cap_vertices])  # a placeholder: positions() puts it at its ring's mean
    parts_b.append(np.full(len(cap_vertices), -1))
    blend.append(np.zeros(len(cap_vertices)))
    ring = side_edges[capped]
    caps = np.stack([ring[:, 1], ring[:, 0], cap_centres[cap_slot]], axis=1)
    members = np.unique(np.concatenate([np.stack([cap_slot, ring[:, 0]], axis=1),
                                        np.stack([cap_slot, ring[:, 1]], axis=1)]), axis=0)
    all_triangles = np.vstack([corner_output.reshape(-1, 3)] + strips + [caps]).astype(np.int32)
    ring_sizes = {}
    for a, b in zip(wedge_part[column_start].tolist(), wedge_part[column_end].tolist()):
        name = f"{parts.names[a]}|{parts.names[b]}"
        ring_sizes[name] = ring_sizes.get(name, 0) + 1
    return SeamMesh(np.concatenate(sources).astype(np.int32), np.concatenate(parts_a).astype(np.int32),
                    np.concatenate(parts_b).astype(np.int32), np.concatenate(blend), all_triangles, ring_sizes,
                    int(interior.size + len(cap_vertices)), np.ascontiguousarray(parts.positions, np.float64), joints,
                    time.perf_counter() - started, cap_centres.astype(np.int64), members.astype(np.int64))


def _edge_keys(triangles, undirected: bool) -> np.ndarray:
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]).astype(np.int64)
    if undirected:
        edges.sort(axis=1)
    return edges[:, 0] * (int(triangles.max(initial=0)) + 1) + edges[:, 1]


def boundary_edges(triangles) -> int:
    """Edges with one triangle, plus those with more than two (0 for a closed manifold)."""
    _, counts = np.unique(_edge_keys(as_index_array(triangles, "triangles", shape=(None, 3)), True),
                          return_counts=True)
    return int((counts != 2).sum())


def is_consistently_oriented(triangles) -> bool:
    """Every directed edge once: neighbours run opposite ways along their shared edge."""
    keys = _edge_keys(as_index_array(triangles, "triangles", shape=(None, 3)), False)
    return len(np.unique(keys)) == len(keys)


def vertex_normals(positions, triangles) -> np.ndarray:
    """Area-weighted vertex normals (unit; zero where every face around is degenerate)."""
    positions = as_real_array(positions, "positions", shape=(None, 3))
    triangles = as_index_array(triangles, "triangles", shape=(None, 3))
    if triangles.size and (triangles.min() < 0 or triangles.max() >= len(positions)):
        raise SkinkitError(f"triangles: a vertex index outside [0, {len(positions)})")
    a, b, c = (positions[triangles[:, k]] for k in range(3))
    faces = np.cross(b - a, c - a)
    normals = np.zeros_like(positions)
    for k in range(3):
        np.add.at(normals, triangles[:, k], faces)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
