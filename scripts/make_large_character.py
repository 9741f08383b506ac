"""A synthetic character of any size for the scale benchmark (bench/bench_scale.py): a tube-limbed creature
(a torso and four legs, each a tube of rings), a 100-bone hierarchy (a chain of 20 bones along each tube, every
leg hanging from a torso bone), smooth weights on the 8 nearest bones of the vertex's tube, per-corner UVs (each
tube one rectangle of the unit square) and random poses deformed by linear blend skinning. Deterministic: the
same vertex count and seed give the same character.

    .venv/bin/python scripts/make_large_character.py 1000000 character.npz [--poses 24] [--seed 1]
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

import skinkit

TUBES = 5  # the torso, then four legs
BONES_PER_TUBE = 20
BONE_COUNT = TUBES * BONES_PER_TUBE
MAX_INFLUENCES = 8
#: The weights' Gaussian width along a tube, in bone lengths: wide enough that all 8 kept weights matter.
WEIGHT_WIDTH = 1.5
#: Each joint turns by up to this many degrees per pose (20 joints in a chain add up).
MAX_DEGREES = 8.0
#: The torso bone each leg hangs from (front pair, back pair).
LEG_ROOTS = (3, 3, 16, 16)


def tube_axes() -> list[tuple[np.ndarray, np.ndarray, float, float]]:
    """(start, direction, length, radius) of each tube: the torso along x, the legs straight down from its sides."""
    axes = [(np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), 4.0, 0.5)]
    for root, side in zip(LEG_ROOTS, (1, -1, 1, -1)):
        x = 4.0 * (root + 0.5) / BONES_PER_TUBE
        axes.append((np.array([x, 0.3 * side, -0.6]), np.array([0.0, 0.0, -1.0]), 2.0, 0.15))
    return axes


def grid_shape(vertex_count: int) -> tuple[int, int]:
    """(rings, points per ring) of one tube so that the creature has about vertex_count vertices, rings about
    four times as many as the points on each (the tubes are long)."""
    columns = max(6, int(round(np.sqrt(vertex_count / (TUBES * 4.0)))))
    rings = max(BONES_PER_TUBE, int(round(vertex_count / (TUBES * columns))))
    return rings, columns


def tube_surface(rings: int, columns: int, start, direction, length: float, radius: float):
    """Positions (rings*columns, 3), each vertex's position along the axis (0..length), and triangles of one open
    tube; its radius bulges a little (a few bumps around and along) so a normal map has something to show."""
    along = np.linspace(0.0, length, rings)
    around = np.linspace(0.0, 2 * np.pi, columns, endpoint=False)
    side = np.cross(direction, [0.0, 0.0, 1.0] if abs(direction[2]) < 0.9 else [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    up = np.cross(direction, side)
    s, theta = np.meshgrid(along, around, indexing="ij")
    r = radius * (1.0 + 0.04 * np.sin(6 * theta) * np.sin(9 * np.pi * s / length))
    positions = (start + s[..., None] * direction + r[..., None] * (np.cos(theta)[..., None] * side +
                                                                 np.sin(theta)[..., None] * up))
    ring, column = np.meshgrid(np.arange(rings - 1), np.arange(columns), indexing="ij")
    a = ring * columns + column
    b = ring * columns + (column + 1) % columns
    c, d = a + columns, b + columns
    triangles = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return positions.reshape(-1, 3), s.reshape(-1), triangles


def tube_corner_uv(rings: int, columns: int, tube: int) -> np.ndarray:
    """(T, 6) per-corner UVs of one tube in the same triangle order as tube_surface: the tube cut along its first
    column and laid out as the tube-th strip of the unit square (the last column's corners at u = 1, not 0)."""
    ring, column = np.meshgrid(np.arange(rings - 1), np.arange(columns), indexing="ij")
    u0, u1 = column / columns, (column + 1) / columns
    v0, v1 = ring / (rings - 1), (ring + 1) / (rings - 1)
    first = np.stack([u0, v0, u1, v0, u1, v1], -1).reshape(-1, 6)
    second = np.stack([u0, v0, u1, v1, u0, v1], -1).reshape(-1, 6)
    uv = np.concatenate([first, second])
    uv[:, 0::2] = (tube + 0.02 + 0.96 * uv[:, 0::2]) / TUBES
    uv[:, 1::2] = 0.02 + 0.96 * uv[:, 1::2]
    return uv


def skeleton_of(axes) -> skinkit.Skeleton:
    """Bone b of tube k starts at its b-th twentieth; identity rotations. Bone 0 (the torso's first) is the root."""
    parents, heads = [], []
    for k, (start, direction, length, _) in enumerate(axes):
        for b in range(BONES_PER_TUBE):
            heads.append(start + direction * length * b / BONES_PER_TUBE)
            if b:
                parents.append(k * BONES_PER_TUBE + b - 1)
            else:
                parents.append(-1 if k == 0 else LEG_ROOTS[k - 1])
    rest_frames = np.tile(np.eye(4), (BONE_COUNT, 1, 1))
    rest_frames[:, :3, 3] = heads
    return skinkit.Skeleton.create(np.array(parents), rest_frames)


def tube_weights(along: np.ndarray, length: float, tube: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 8) bones and weights: a Gaussian in the distance along the tube to each of its bones' middles, the 8
    nearest bones kept (a contiguous run of the chain), normalised."""
    bone_length = length / BONES_PER_TUBE
    nearest = np.clip(np.floor(along / bone_length).astype(int) - MAX_INFLUENCES // 2 + 1, 0,
                      BONES_PER_TUBE - MAX_INFLUENCES)
    local = nearest[:, None] + np.arange(MAX_INFLUENCES)
    distance = (along[:, None] - (local + 0.5) * bone_length) / bone_length
    weights = np.exp(-0.5 * (distance / WEIGHT_WIDTH) ** 2)
    return (local + tube * BONES_PER_TUBE).astype(np.int32), weights / weights.sum(axis=1, keepdims=True)


def rotation_matrices(rng, count: int, max_degrees: float) -> np.ndarray:
    """(count, 3, 3) rotations about random axes by up to max_degrees (Rodrigues)."""
    axes = rng.normal(size=(count, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.radians(rng.uniform(-max_degrees, max_degrees, count))
    cross = np.zeros((count, 3, 3))
    cross[:, 0, 1], cross[:, 0, 2], cross[:, 1, 2] = -axes[:, 2], axes[:, 1], -axes[:, 0]
    cross -= cross.transpose(0, 2, 1)
    return np.eye(3) + np.sin(angles)[:, None, None] * cross + (1 - np.cos(angles))[:, None, None] * cross @ cross


def random_poses(skeleton: skinkit.Skeleton, count: int, rng) -> np.ndarray:
    """(count, b, 4, 4) world frames: every bone turned about its head after its parent, the root moved too (so
    every bone moves and a fit is determined)."""
    heads = skeleton.rest_frames[:, :3, 3]
    poses = np.empty((count, BONE_COUNT, 4, 4))
    for n in range(count):
        rotations = rotation_matrices(rng, BONE_COUNT, MAX_DEGREES)
        skinning = np.tile(np.eye(4), (BONE_COUNT, 1, 1))
        for j in range(BONE_COUNT):  # parents come before their children
            local = np.eye(4)
            local[:3, :3] = rotations[j]
            local[:3, 3] = heads[j] - rotations[j] @ heads[j]
            if skeleton.parents[j] < 0:
                local[:3, 3] += rng.uniform(-0.2, 0.2, 3)
            skinning[j] = local if skeleton.parents[j] < 0 else skinning[skeleton.parents[j]] @ local
        poses[n] = skinning @ skeleton.rest_frames
    return poses


def make_character(vertex_count: int, pose_count: int = 24, seed: int = 1, with_examples: bool = True) -> dict:
    """The creature with about vertex_count vertices: rest (V, 3), triangles (T, 3), corner_uv (T, 6), charts
    (T,) (its tube), skeleton, weights (skinkit.SparseWeights, 8 per vertex), poses (n, b, 4, 4) world frames
    and, with_examples, examples (n, V, 3): the poses by linear blend skinning."""
    rings, columns = grid_shape(vertex_count)
    axes = tube_axes()
    positions, triangles, uvs, charts, bones, weights = [], [], [], [], [], []
    for tube, (start, direction, length, radius) in enumerate(axes):
        p, along, t = tube_surface(rings, columns, start, direction, length, radius)
        triangles.append(t + tube * len(p))
        positions.append(p)
        uvs.append(tube_corner_uv(rings, columns, tube))
        charts.append(np.full(len(t), tube, np.int32))
        b, w = tube_weights(along, length, tube)
        bones.append(b)
        weights.append(w)
    rest = np.concatenate(positions)
    skeleton = skeleton_of(axes)
    offsets = np.arange(len(rest) + 1, dtype=np.int32) * MAX_INFLUENCES
    sparse = skinkit.SparseWeights.create(offsets, np.concatenate(bones).reshape(-1),
                                          np.concatenate(weights).reshape(-1), BONE_COUNT)
    poses = random_poses(skeleton, pose_count, np.random.default_rng(seed))
    character = {"rest": rest, "triangles": np.concatenate(triangles).astype(np.int32),
                 "corner_uv": np.concatenate(uvs), "charts": np.concatenate(charts), "skeleton": skeleton,
                 "weights": sparse, "poses": poses}
    if with_examples:
        character["examples"] = skinkit.lbs_evaluate(skeleton, sparse, rest, poses)
    return character


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("vertex_count", type=int)
    parser.add_argument("out", help="an .npz file")
    parser.add_argument("--poses", type=int, default=24)
    parser.add_argument("--seed", type=int, default=1)
    arguments = parser.parse_args(argv)
    c = make_character(arguments.vertex_count, arguments.poses, arguments.seed)
    np.savez(arguments.out, rest=c["rest"], triangles=c["triangles"], corner_uv=c["corner_uv"], charts=c["charts"],
             parents=c["skeleton"].parents, rest_frames=c["skeleton"].rest_frames, offsets=c["weights"].offsets,
             bones=c["weights"].bones, weights=c["weights"].weights, poses=c["poses"], examples=c["examples"])
    print(f"{len(c['rest'])} vertices, {len(c['triangles'])} triangles, {BONE_COUNT} bones, "
          f"{arguments.poses} poses -> {arguments.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
