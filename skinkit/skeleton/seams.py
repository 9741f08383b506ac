"""Rigid skinning with seam reconstruction (Vasilakis 2008, section 4.4, Algorithm 5) with a fixed topology.

Every vertex follows its part (v' = W v). At each joint the opening is split: the parent keeps the opening loop,
the child gets a copy, and `steps` rings of arc points join them. Ring k's point i is the opening vertex moved by
the parent's frame and then turned about the joint by the QLERP (eq. 4.1) of the parent-to-child motion at
t = k / (steps + 1): the thesis' S1 arcs, laid on every opening point rather than only the "Circle" ones. The rings
are joined by a strip of triangles (a local hole fill in place of Tight Cocone: the patch is triangulated once,
so the mesh is watertight and manifold in every frame and its vertex count never changes, which shape keys and
mesh caches need). The thesis' removal of points sinking into the other part is not done: they stay, hidden
inside it. Normals are the area-weighted normals of the posed mesh.
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
    parts_b -1 or the child for arc points) and blend; triangles on the output vertices; per joint its ring size."""
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

    def positions(self, world) -> np.ndarray:
        """The output vertices for world frames (P, 4, 4)."""
        world = as_real_array(world, "world", shape=(len(self.joints), 4, 4))
        out = np.zeros(3 * len(self.sources))
        _core.evaluate_seams(out, self.rest_positions.reshape(-1), np.ascontiguousarray(world, np.float64).reshape(-1),
                             self.joints.reshape(-1), self.sources, self.parts_a, self.parts_b, self.blend)
        return out.reshape(-1, 3)


def _directed_owners(triangles, triangle_parts) -> dict:
    """Each directed edge (u, v) of a triangle, with that triangle's part."""
    owners = {}
    for (a, b, c), part in zip(triangles.tolist(), triangle_parts.tolist()):
        owners[(a, b)] = owners[(b, c)] = owners[(c, a)] = part
    return owners


def _opening_loop(owners, child, parent, names) -> list[int]:
    """The child's border with its parent as one closed loop, in the child's triangles' direction."""
    following = {}
    for (u, v), part in owners.items():
        if part == child and owners.get((v, u)) == parent:
            if u in following:
                raise SkinkitError(f"the opening between parts {names[parent]} and {names[child]} branches at "
                                   f"vertex {u}: it must be one closed loop")
            following[u] = v
    if not following:
        raise SkinkitError(f"parts {names[parent]} and {names[child]} share no edge")
    start = min(following)
    loop, vertex = [start], following[start]
    while vertex != start:
        if vertex not in following or len(loop) > len(following):
            raise SkinkitError(f"the opening between parts {names[parent]} and {names[child]} is not one closed loop")
        loop.append(vertex)
        vertex = following[vertex]
    if len(loop) != len(following):
        raise SkinkitError(f"the opening between parts {names[parent]} and {names[child]} has several loops")
    return loop


def _check_tree_openings(triangles, triangle_parts, parents, names) -> None:
    """Parts may only meet their parent or their children (the seams are per joint)."""
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    sides = np.tile(triangle_parts, 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, sides = edges[order], sides[order]
    same = (edges[1:] == edges[:-1]).all(axis=1)
    for a, b in zip(sides[:-1][same], sides[1:][same]):
        if a != b and parents[a] != b and parents[b] != a:
            raise SkinkitError(f"parts {names[a]} and {names[b]} meet but neither is the other's parent: seams are "
                               "reconstructed per joint, so parts may only meet their parent and children")


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
    triangles = np.array(parts.triangles, dtype=np.int32)
    triangle_parts = np.asarray(parts.triangle_parts)
    parents = as_index_array(parents, "parents", shape=(parts.part_count,))
    if ((parents < -1) | (parents >= len(parents))).any():
        raise SkinkitError(f"parents: every parent must be -1 or a part in [0, {len(parents)})")
    joints = as_real_array(joints, "joints", shape=(parts.part_count, 3))
    _check_tree_openings(triangles, triangle_parts, parents, parts.names)
    vertex_count = len(parts.positions)
    sources, parts_a, parts_b, blend = [np.arange(vertex_count)], [parts.vertex_parts()], [np.full(vertex_count, -1)], \
        [np.zeros(vertex_count)]
    new_triangles, ring_sizes, next_index = triangles.copy(), {}, vertex_count
    strips, owners = [], _directed_owners(triangles, triangle_parts)
    for child, parent in enumerate(parents.tolist()):
        if parent < 0:
            continue
        loop = np.array(_opening_loop(owners, child, parent, parts.names), dtype=np.int32)
        n = len(loop)
        parts_a[0][loop] = parent  # the parent keeps the opening
        rings = [loop]
        for k in range(1, steps + 2):
            rings.append(np.arange(next_index, next_index + n, dtype=np.int32))
            next_index += n
            sources.append(loop)
            last = k == steps + 1
            parts_a.append(np.full(n, child if last else parent))
            parts_b.append(np.full(n, -1 if last else child))
            blend.append(np.full(n, 0.0 if last else k / (steps + 1)))
        copy = np.arange(vertex_count, dtype=np.int32)  # the child's corners move to its copy of the loop
        copy[loop] = rings[-1]
        mine = triangle_parts == child
        new_triangles[mine] = copy[new_triangles[mine]]
        for k in range(steps + 1):
            a, b = rings[k], np.roll(rings[k], -1)
            d, c = rings[k + 1], np.roll(rings[k + 1], -1)
            strips.append(np.stack([a, b, c], axis=1))
            strips.append(np.stack([a, c, d], axis=1))
        ring_sizes[parts.names[child]] = n
    all_triangles = np.vstack([new_triangles] + strips).astype(np.int32)
    constructed = int(sum(ring_sizes.values()) * steps)
    return SeamMesh(np.concatenate(sources).astype(np.int32), np.concatenate(parts_a).astype(np.int32),
                    np.concatenate(parts_b).astype(np.int32), np.concatenate(blend), all_triangles, ring_sizes,
                    constructed, np.ascontiguousarray(parts.positions, np.float64), joints,
                    time.perf_counter() - started)


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
