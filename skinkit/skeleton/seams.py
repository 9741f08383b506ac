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
changes, which shape keys and mesh caches need (SeamMesh.positions). SeamMesh.reconstruct runs the whole of
Algorithm 5 per frame in C (sk_reconstruct_seams): the points sinking into the other part of a seam are removed, the
holes filled, pieces cut off by a sunk band bridged back, optionally the arcs laid on the thesis' conic middle
points; its vertex count changes from frame to frame. Normals are the area-weighted normals of the posed mesh.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .. import _core
from .._checks import CALLBACK, FLAG, as_index_array, as_real_array, checked, choice, count
from ..model import SkinkitError
from .extract import Skeleton as BoneSkeleton
from .parts import Parts
from .animation import joint_frame

__all__ = ["SeamMesh", "Frame", "SinkingData", "ARC_KINDS", "conic_arc", "prepare_seams", "prepare_seams_for_rig",
           "boundary_edges", "is_consistently_oriented", "vertex_normals"]


#: The most rings of arc points a seam is closed with.
MAX_STEPS = 256
#: The arcs the add step lays between the two copies of an opening point.
ARC_KINDS = ("qlerp", "conic")
#: The most points conic_arc samples.
MAX_CONIC_POINTS = 1 << 20


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
    removal: "SinkingData"
    columns: np.ndarray

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


    @checked(remove_sinking=FLAG, arcs=choice(ARC_KINDS))
    def reconstruct(self, world, remove_sinking: bool = True, arcs: str = "qlerp") -> "Frame":
        """One frame of Algorithm 5 (see reconstruct_sequence)."""
        return self.reconstruct_sequence(as_real_array(world, "world", shape=(len(self.joints), 4, 4))[None],
                                         remove_sinking, arcs)[0]

    @checked(remove_sinking=FLAG, arcs=choice(ARC_KINDS), progress=CALLBACK)
    def reconstruct_sequence(self, worlds, remove_sinking: bool = True, arcs: str = "qlerp",
                             progress=None) -> list:
        """Algorithm 5 per frame (worlds: (F, P, 4, 4)), in C (sk_reconstruct_seams): add the rigid points and the
        arcs (arcs "qlerp": the S1 arcs about the deeper part's joint; "conic": the columns of a bent joint on the
        thesis' conic middle-point arcs, the QLERP arc where the conic is degenerate), remove the points of each
        part that sink into the other part of a seam (inside its posed box and past its posed opening plane, found
        by growing from the opening through the part's 1-rings; remove_sinking False keeps them), close each hole
        by a local fill (an advancing front clipping the smallest corner first, then a fan to the border's mean),
        and the area-weighted normals. A border vertex on two holes is removed too (filling both would pinch it),
        as are kept pieces cut off inside a sunk region; should that still leave a surface other than one closed
        sphere, the frame falls back to the fixed topology (fallback: True). So every frame is watertight,
        manifold and consistently oriented; the vertex count changes from frame to frame (positions() keeps it
        fixed, as shape keys need). progress(fraction) after each frame; a true return cancels (SkinkitError)."""
        worlds = as_real_array(worlds, "worlds", shape=(None, len(self.joints), 4, 4))
        if not len(worlds):
            return []
        removal = self.removal
        position_capacity = len(self.sources) + len(self.triangles)
        triangle_capacity = 2 * position_capacity
        frames = len(worlds)
        positions = np.empty(3 * frames * position_capacity)  # written up to each frame's counts
        normals = np.empty_like(positions)
        triangles = np.empty(3 * frames * triangle_capacity, np.int32)
        counts = np.zeros(6 * frames, np.int32)
        seconds = np.zeros(4 * frames)
        i32 = lambda values: np.ascontiguousarray(values, dtype=np.int32).reshape(-1)  # noqa: E731
        _core.reconstruct_seams(
            positions, triangles, normals, counts, seconds, self.rest_positions.reshape(-1), self.joints.reshape(-1),
            self.sources, self.parts_a, self.parts_b, self.blend, i32(self.triangles), i32(removal.twins),
            i32(np.stack([self.cap_centres[self.cap_members[:, 0]], self.cap_members[:, 1]], axis=1).reshape(-1, 2)),
            i32(self.columns), self.columns.shape[1], i32(removal.ring_offsets), i32(removal.ring),
            np.hstack([removal.box_centres, removal.box_axes.reshape(-1, 9), removal.box_halves]).reshape(-1),
            i32(removal.seam_parts), i32(removal.start_offsets), i32(removal.starts),
            np.hstack([removal.plane_centres, removal.plane_normals]).reshape(-1),
            np.ascontiguousarray(worlds).reshape(-1), position_capacity, triangle_capacity, bool(remove_sinking),
            arcs == "conic", progress)
        positions = positions.reshape(frames, position_capacity, 3)
        normals = normals.reshape(frames, position_capacity, 3)
        triangles = triangles.reshape(frames, triangle_capacity, 3)
        result = []
        for f, (points, faces, removed, filled, conics, fallback) in enumerate(counts.reshape(-1, 6).tolist()):
            add, remove, triangulate, normal = seconds[4 * f:4 * f + 4].tolist()
            result.append(Frame(positions[f, :points].copy(), triangles[f, :faces].copy(), normals[f, :points].copy(),
                                removed, filled, bool(fallback),
                                {"add": add, "remove": remove, "triangulate": triangulate, "normals": normal},
                                conics))
        return result


@dataclass(frozen=True)
class Frame:
    """A reconstructed frame: positions, triangles, unit normals; how many points sank and were removed, how many
    the hole fill added, whether it fell back to the fixed topology; seconds per gap step (add: the arcs and rigid
    points, remove, triangulate: the hole fill and bridges with their checks, normals); how many columns lie on
    conic arcs."""
    positions: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    removed_points: int
    fill_points: int
    fallback: bool
    seconds: dict
    conic_columns: int = 0


@dataclass(frozen=True)
class SinkingData:
    """What the removal step needs, built once: the half-edge twins of the seamed mesh; the same-part 1-ring of
    every rigid point (CSR); per part an oriented box of its rest vertices (centre, axes as rows, half-lengths); per
    seam (a, b) its parts, the opening copies on side a then side b (CSR over 2 * seams) and the opening plane at
    rest (centre, unit normal pointing into b)."""
    twins: np.ndarray
    ring_offsets: np.ndarray
    ring: np.ndarray
    box_centres: np.ndarray
    box_axes: np.ndarray
    box_halves: np.ndarray
    seam_parts: np.ndarray
    start_offsets: np.ndarray
    starts: np.ndarray
    plane_centres: np.ndarray
    plane_normals: np.ndarray


@checked(count=count(0, MAX_CONIC_POINTS))
def conic_arc(start, start_tangent, end, end_tangent, through, count: int = 8) -> tuple[np.ndarray, float]:
    """The thesis' conic arc (section 2.1.3, Fudos and Hoffmann's rational quadratic Bezier, its M2 typo fixed) from
    start to end, the tangents pointing at their lines' crossing X, through the point `through`: `count` points
    strictly between the ends at equal arc lengths, and the weight w of the middle control point (the curve is
    ((1-t)^2 C + 2t(1-t) w X + t^2 D) / ((1-t)^2 + 2wt(1-t) + t^2)). SkinkitError when no such conic exists."""
    vectors = {name: as_real_array(value, name, shape=(3,)) for name, value in
               (("start", start), ("start_tangent", start_tangent), ("end", end), ("end_tangent", end_tangent),
                ("through", through))}
    points, weight = np.zeros(3 * count), np.zeros(1)
    _core.conic_arc(points, weight, vectors["start"], vectors["start_tangent"], vectors["end"],
                    vectors["end_tangent"], vectors["through"], count)
    return points.reshape(-1, 3), float(weight[0])


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
    removal = _sinking_data(parts, all_triangles, next_index, wedge_index, wedge_part, column_start, column_end,
                            np.concatenate(sources))
    ring_sizes = {}
    for a, b in zip(wedge_part[column_start].tolist(), wedge_part[column_end].tolist()):
        name = f"{parts.names[a]}|{parts.names[b]}"
        ring_sizes[name] = ring_sizes.get(name, 0) + 1
    return SeamMesh(np.concatenate(sources).astype(np.int32), np.concatenate(parts_a).astype(np.int32),
                    np.concatenate(parts_b).astype(np.int32), np.concatenate(blend), all_triangles, ring_sizes,
                    int(interior.size + len(cap_vertices)), np.ascontiguousarray(parts.positions, np.float64), joints,
                    time.perf_counter() - started, cap_centres.astype(np.int64), members.astype(np.int64), removal,
                    np.ascontiguousarray(sequence, dtype=np.int32))


def _part_boxes(positions, triangles, triangle_parts, part_count):
    """Per part: the oriented box of its vertices along their principal directions (centre, axes, halves)."""
    centres, axes, halves = np.zeros((part_count, 3)), np.tile(np.eye(3), (part_count, 1, 1)), np.zeros((part_count, 3))
    for part in range(part_count):
        points = positions[np.unique(triangles[triangle_parts == part])]
        if len(points) == 0:
            continue
        _, vectors = np.linalg.eigh(np.cov((points - points.mean(axis=0)).T) if len(points) > 1 else np.eye(3))
        local = points @ vectors
        low, high = local.min(axis=0), local.max(axis=0)
        axes[part], halves[part] = vectors.T, (high - low) / 2
        centres[part] = vectors @ ((low + high) / 2)
    return centres, axes, halves


def _sinking_data(parts, triangles, point_count, wedge_index, wedge_part, column_start, column_end,
                  sources) -> SinkingData:
    positions = np.asarray(parts.positions, dtype=np.float64)
    part_triangles = triangles[:len(parts.triangles)].astype(np.int64)
    pairs = np.concatenate([part_triangles[:, [0, 1]], part_triangles[:, [1, 2]], part_triangles[:, [2, 0]]])
    pairs = np.unique(np.concatenate([pairs, pairs[:, ::-1]]), axis=0)
    ring_offsets = np.concatenate([[0], np.cumsum(np.bincount(pairs[:, 0], minlength=point_count))])
    centres, axes, halves = _part_boxes(positions, np.asarray(parts.triangles), np.asarray(parts.triangle_parts),
                                        parts.part_count)
    seam_keys = wedge_part[column_start] * parts.part_count + wedge_part[column_end]
    seam_parts, starts, plane_centres, plane_normals = [], [], [], []
    for key in np.unique(seam_keys).tolist():
        a, b = divmod(key, parts.part_count)
        mine = seam_keys == key
        side_a, side_b = np.unique(wedge_index[column_start[mine]]), np.unique(wedge_index[column_end[mine]])
        opening = positions[sources[side_a]]
        centre = opening.mean(axis=0)
        _, vectors = np.linalg.eigh(np.cov((opening - centre).T) if len(opening) > 2 else np.eye(3))
        normal = vectors[:, 0]
        if (positions[np.unique(np.asarray(parts.triangles)[np.asarray(parts.triangle_parts) == b])].mean(axis=0)
                - centre) @ normal < 0:
            normal = -normal  # into b
        seam_parts.append((a, b))
        starts.append((side_a, side_b))
        plane_centres.append(centre)
        plane_normals.append(normal)
    flat_starts = [side for pair in starts for side in pair]
    start_offsets = np.concatenate([[0], np.cumsum([len(side) for side in flat_starts])]).astype(np.int64)
    return SinkingData(_twins(triangles.astype(np.int64)), ring_offsets,
                       pairs[:, 1], centres, axes, halves, np.array(seam_parts, np.int64).reshape(-1, 2),
                       start_offsets, np.concatenate(flat_starts + [np.zeros(0, np.int64)]).astype(np.int64),
                       np.array(plane_centres).reshape(-1, 3), np.array(plane_normals).reshape(-1, 3))


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
    corners = triangles.reshape(-1)
    normals = np.stack([np.bincount(corners, np.repeat(faces[:, axis], 3), len(positions)) for axis in range(3)],
                       axis=1).astype(np.float64)  # (bincount of nothing is integer)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
