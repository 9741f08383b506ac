"""Synthetic, seeded data for the metrics benchmark: a tree skeleton (a spine with branching limbs), sampled
local joint matrices, and an animation-space model around the bones. numpy only (no bpy).

Conventions follow skinkit.metrics: bone 0 is the root, G_0 = I (model space) and L_0 = I; every other
bone j has a rest frame Ĝ_j (origin at its head, y axis along the bone, as Blender's bones do) and a local
joint matrix L_j = Ĝ_p^-1 G_j, so G_j = G_p L_j. A sampled pose rotates each joint about its head:
L_j = [R̂_j R_j, t_j] with R̂_j the rest orientation relative to the parent, R_j a random rotation of
moderate angle about a random axis, t_j the fixed rest translation.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Rig:
    parents: np.ndarray      # (b,) int32, parents[0] = -1
    heads: np.ndarray        # (b, 3) model-space joint positions (bone 0: the origin)
    tails: np.ndarray        # (b, 3)
    rest_world: np.ndarray   # (b, 4, 4) Ĝ_j (Ĝ_0 = I)
    rest_local: np.ndarray   # (b, 4, 4) L̂_j = Ĝ_p^-1 Ĝ_j (L̂_0 = I)
    depth: np.ndarray        # (b,) steps to the root

    @property
    def bone_count(self) -> int:
        return len(self.parents)

    def parents_first(self) -> np.ndarray:
        return np.argsort(self.depth, kind="stable")


def bone_frame(head: np.ndarray, tail: np.ndarray) -> np.ndarray:
    """A rigid frame at head whose y axis points along the bone."""
    y = (tail - head) / np.linalg.norm(tail - head)
    reference = np.array([0.3, 0.5, 0.8]) if abs(y @ np.array([0.3, 0.5, 0.8])) < 0.9 else np.array([1.0, 0, 0])
    x = np.cross(y, reference)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    frame = np.eye(4)
    frame[:3, 0], frame[:3, 1], frame[:3, 2], frame[:3, 3] = x, y, z, head
    return frame


def tree_skeleton(bone_count: int = 100, limb_length: int = 4, seed: int = 0) -> Rig:
    """Bone 0 is a fixed root at the origin; about a quarter of the rest form a spine (+z, hips at 0.9 to head
    top at 1.9), the others limbs of up to `limb_length` bones branching off spine bones alternately left and
    right at varying angles: the first four are arms and legs, then tails, horns, tentacles."""
    rng = np.random.default_rng(seed)
    spine_count = max(1, round((bone_count - 1) / 4))
    z = np.linspace(0.9, 1.9, spine_count + 1)
    heads = [np.zeros(3)] + [np.array([0.0, 0.0, z[i]]) for i in range(spine_count)]
    tails = [np.array([0.0, 0.0, 0.9])] + [np.array([0.0, 0.0, z[i + 1]]) for i in range(spine_count)]
    parents = [-1] + list(range(spine_count))
    remaining, limb = bone_count - 1 - spine_count, 0
    while remaining > 0:
        chain = min(limb_length, remaining)
        if limb < 4:  # arms from the chest, legs from the hips
            spine = spine_count - 3 if limb < 2 else 0
            side = 1.0 if limb % 2 == 0 else -1.0
            direction = np.array([side, 0.0, 0.0]) if limb < 2 else np.array([0.1 * side, 0.0, -1.0])
            length = 0.75 if limb < 2 else 0.85
        else:
            spine = int(rng.integers(0, spine_count))
            side = 1.0 if limb % 2 == 0 else -1.0
            direction = np.array([side, rng.uniform(-0.8, 0.8), rng.uniform(-0.6, 0.6)])
            length = rng.uniform(0.3, 0.6)
        bone = 1 + max(0, min(spine, spine_count - 1))
        start = heads[bone] + np.array([0.1 * side, 0.0, 0.5 * (tails[bone][2] - heads[bone][2])])
        end = start + length * direction / np.linalg.norm(direction)
        points = start + np.linspace(0, 1, chain + 1)[:, None] * (end - start)
        for link in range(chain):
            parents.append(bone if link == 0 else len(heads) - 1)
            heads.append(points[link])
            tails.append(points[link + 1])
        remaining -= chain
        limb += 1
    parents = np.array(parents, np.int32)
    heads, tails = np.array(heads), np.array(tails)
    rest_world = np.stack([np.eye(4)] + [bone_frame(h, t) for h, t in zip(heads[1:], tails[1:])])
    rest_local = np.linalg.solve(rest_world[np.maximum(parents, 0)], rest_world)
    rest_local[0] = np.eye(4)
    depth = np.zeros(len(parents), int)
    for j in range(1, len(parents)):
        depth[j] = depth[parents[j]] + 1  # parents come before children here
    return Rig(parents, heads, tails, rest_world, rest_local, depth)


def random_rotations(rng, shape, max_angle: float) -> np.ndarray:
    """Rotations (shape + (3, 3)) about uniformly random axes by angles uniform in [-max_angle, max_angle]."""
    axes = rng.normal(size=shape + (3,))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    angles = rng.uniform(-max_angle, max_angle, shape)
    k = np.zeros(shape + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -axes[..., 2], axes[..., 1], -axes[..., 0]
    k -= np.swapaxes(k, -1, -2)
    s, c = np.sin(angles)[..., None, None], np.cos(angles)[..., None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def sampled_local(rig: Rig, frames: int, max_angle: float, seed: int) -> np.ndarray:
    """(frames, b, 4, 4) local joint matrices: each joint independently rotated about its head."""
    rng = np.random.default_rng(seed)
    local = np.tile(rig.rest_local, (frames, 1, 1, 1))
    local[:, :, :3, :3] = rig.rest_local[:, :3, :3] @ random_rotations(rng, (frames, rig.bone_count), max_angle)
    local[:, 0] = np.eye(4)
    return local


@dataclass(frozen=True)
class Model:
    """An animation-space model in compressed rows: vertex i has bones[offsets[i]:offsets[i+1]] (sorted) and
    coordinates p_j = w_j Ĝ_j^-1 (v, 1), so the rest pose reproduces v."""
    positions: np.ndarray    # (V, 3) rest positions
    offsets: np.ndarray      # (V + 1,) int32
    bones: np.ndarray        # (K,) int32
    coordinates: np.ndarray  # (K, 4)


def neighbourhood(rig: Rig, bone: int, count: int) -> list[int]:
    """`bone` and its nearest bones in the tree (breadth first: parent, children, grandparent, siblings ...)."""
    children = [[] for _ in range(rig.bone_count)]
    for j in range(1, rig.bone_count):
        children[rig.parents[j]].append(j)
    seen, queue = [bone], [bone]
    while queue and len(seen) < count:
        current = queue.pop(0)
        for other in ([int(rig.parents[current])] if current != 0 else []) + children[current]:
            if other not in seen and len(seen) < count:
                seen.append(other)
                queue.append(other)
    return seen


def skinned_model(rig: Rig, vertex_count: int, influences: int, seed: int) -> Model:
    """Vertices scattered on tubes around the bones (bone 0, the fixed root, carries none), each influenced by
    its bone and the nearest ones in the tree, weights falling off with distance to each bone's segment."""
    rng = np.random.default_rng(seed)
    lengths = np.linalg.norm(rig.tails - rig.heads, axis=1)
    lengths[0] = 0.0
    owner = rng.choice(rig.bone_count, vertex_count, p=lengths / lengths.sum())
    along = rng.uniform(0, 1, vertex_count)
    angle = rng.uniform(0, 2 * np.pi, vertex_count)
    radius = rng.uniform(0.03, 0.12, vertex_count)
    frames = rig.rest_world[owner]
    positions = (rig.heads[owner] + along[:, None] * (rig.tails - rig.heads)[owner]
                 + radius[:, None] * (np.cos(angle)[:, None] * frames[:, :3, 0] + np.sin(angle)[:, None] * frames[:, :3, 2]))
    table = np.full((rig.bone_count, influences), -1, np.int32)
    for j in range(rig.bone_count):
        near = sorted(neighbourhood(rig, j, influences))
        table[j, :len(near)] = near
    rows = table[owner]
    counts = (rows >= 0).sum(axis=1)
    offsets = np.zeros(vertex_count + 1, np.int32)
    np.cumsum(counts, out=offsets[1:])
    bones = rows[rows >= 0]  # row by row, sorted within each row
    vertex = np.repeat(np.arange(vertex_count), counts)
    distance = segment_distance(positions[vertex], rig.heads[bones], rig.tails[bones])
    weight = np.exp(-distance / 0.05) + 1e-3
    weight /= np.bincount(vertex, weight)[vertex]
    local = np.einsum("kij,kj->ki", np.linalg.inv(rig.rest_world)[bones], np.c_[positions[vertex], np.ones(len(vertex))])
    return Model(positions, offsets, bones, local * weight[:, None])


def segment_distance(points, heads, tails) -> np.ndarray:
    axis = tails - heads
    t = np.clip(np.einsum("ki,ki->k", points - heads, axis) / np.einsum("ki,ki->k", axis, axis), 0, 1)
    return np.linalg.norm(points - heads - t[:, None] * axis, axis=1)


def padded(model: Model, vertices: np.ndarray, width: int):
    """The influences of `vertices` as (n, width) bones (padding: -1) and (n, width, 4) coordinates (padding: 0)."""
    counts = np.diff(model.offsets)[vertices]
    slot = np.arange(width)
    valid = slot < counts[:, None]
    index = np.where(valid, model.offsets[vertices][:, None] + slot, 0)
    bones = np.where(valid, model.bones[index], -1)
    coordinates = np.where(valid[..., None], model.coordinates[index], 0.0)
    return bones, coordinates


def compressed(bones: np.ndarray, coordinates: np.ndarray):
    """Rows of padded entries (bones -1 = none; each bone at most twice per row) as merged compressed rows
    (offsets, bones sorted within each row, coordinates): a bone's two entries are added together."""
    sentinel = np.iinfo(np.int32).max
    keys = np.where(bones < 0, sentinel, bones)
    order = np.argsort(keys, axis=1, kind="stable")
    keys = np.take_along_axis(keys, order, axis=1)
    coordinates = np.take_along_axis(coordinates, order[..., None], axis=1)
    repeated = (keys[:, 1:] == keys[:, :-1]) & (keys[:, 1:] != sentinel)
    coordinates[:, :-1][repeated] += coordinates[:, 1:][repeated]
    keep = keys != sentinel
    keep[:, 1:] &= ~repeated
    offsets = np.zeros(len(keys) + 1, np.int32)
    np.cumsum(keep.sum(axis=1), out=offsets[1:])
    return offsets, keys[keep].astype(np.int32), coordinates[keep]


def pair_differences(model: Model, pair_count: int, seed: int):
    """s = p_a - p_b for random pairs of distinct vertices, over the union of their influences."""
    rng = np.random.default_rng(seed)
    a = rng.integers(0, len(model.positions), pair_count)
    b = (a + rng.integers(1, len(model.positions), pair_count)) % len(model.positions)
    width = int(np.diff(model.offsets).max())
    bones_a, coordinates_a = padded(model, a, width)
    bones_b, coordinates_b = padded(model, b, width)
    return (a, b), compressed(np.concatenate([bones_a, bones_b], axis=1),
                              np.concatenate([coordinates_a, -coordinates_b], axis=1))


def minus_centre(model: Model, centre: np.ndarray):
    """p_v - (centre, 1) on the root, for every vertex (the culling-sphere form, section 7.2)."""
    vertex_count = len(model.positions)
    bones, coordinates = padded(model, np.arange(vertex_count), int(np.diff(model.offsets).max()))
    root = np.broadcast_to(np.r_[-centre, -1.0], (vertex_count, 1, 4))
    return compressed(np.concatenate([bones, np.zeros((vertex_count, 1), bones.dtype)], axis=1),
                      np.concatenate([coordinates, root], axis=1))
