"""Synthetic segmented characters with known joints and hierarchy, for tests and benchmarks: a chain of capped
cylinders (one part per cylinder) and a star of square limbs on a cubic hub. Watertight, outward-facing, genus 0."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._checks import checked, count, real
from .parts import Parts

__all__ = ["Sample", "chain_of_cylinders", "star_of_limbs"]


#: Bounds of the samples' sizes (made by Python loops: the largest is about 130,000 vertices) and of their lengths.
MAX_PARTS = 32
MAX_SIDES = 128
MAX_RINGS = 32
LENGTH = real(above=0, maximum=1e6)


@dataclass(frozen=True)
class Sample:
    """parts: the segmented mesh; parents: the hierarchy (P); openings: each non-root part's opening centroid with
    its parent ((P, 3), NaN for the root)."""
    parts: Parts
    parents: np.ndarray
    openings: np.ndarray


def _weld(polygons: list[tuple[list, int]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Polygons (corner positions counter-clockwise from outside, part id), fan-triangulated, with coincident corners
    welded: positions, triangles, triangle parts."""
    index, positions, triangles, parts = {}, [], [], []
    for corners, part in polygons:
        ids = []
        for corner in corners:
            key = tuple(np.round(np.asarray(corner, dtype=np.float64), 9))
            if key not in index:
                index[key] = len(positions)
                positions.append(key)
            ids.append(index[key])
        for k in range(1, len(ids) - 1):
            triangles.append((ids[0], ids[k], ids[k + 1]))
            parts.append(part)
    return np.array(positions, dtype=np.float64), np.array(triangles, dtype=np.int32), np.array(parts, dtype=np.int32)


@checked(parts=count(1, MAX_PARTS), length=LENGTH, radius=LENGTH, sides=count(3, MAX_SIDES),
         rings_per_part=count(1, MAX_RINGS))
def chain_of_cylinders(parts: int = 4, length: float = 2.0, radius: float = 0.5, sides: int = 16,
                       rings_per_part: int = 4) -> Sample:
    """Cylinders along x, part k over [k length, (k + 1) length], capped at both ends; part k's parent is k - 1."""
    def ring(r):
        x = length * r / rings_per_part
        angles = 2 * np.pi * np.arange(sides) / sides
        return [(x, radius * np.cos(a), radius * np.sin(a)) for a in angles]

    rings = [ring(r) for r in range(parts * rings_per_part + 1)]
    polygons = []
    for r in range(len(rings) - 1):
        for s in range(sides):
            t = (s + 1) % sides
            polygons.append(([rings[r][s], rings[r][t], rings[r + 1][t], rings[r + 1][s]], r // rings_per_part))
    polygons.append((rings[0][::-1], 0))
    polygons.append((rings[-1], parts - 1))
    positions, triangles, labels = _weld(polygons)
    openings = np.full((parts, 3), np.nan)
    openings[1:] = np.outer(length * np.arange(1, parts), [1.0, 0.0, 0.0])  # (0, 3) for one part
    names = tuple(f"segment_{k}" for k in range(parts))
    return Sample(Parts(positions, triangles, labels, names), np.arange(-1, parts - 1, dtype=np.int32), openings)


def _grid_face(normal, u, v, cells: int, hole: bool, part: int):
    """A cube face (centre = normal, axes u x v = normal) as cells x cells quads; the middle one left out as a hole."""
    normal, u, v = (np.asarray(a, dtype=np.float64) for a in (normal, u, v))
    edges = np.linspace(-1, 1, cells + 1)
    middle = cells // 2
    return [([normal + u * edges[i] + v * edges[j], normal + u * edges[i + 1] + v * edges[j],
              normal + u * edges[i + 1] + v * edges[j + 1], normal + u * edges[i] + v * edges[j + 1]], part)
            for i in range(cells) for j in range(cells) if not (hole and i == middle and j == middle)]


@checked(limb_length=LENGTH, rings=count(1, MAX_RINGS))
def star_of_limbs(limb_length: float = 2.0, rings: int = 4) -> Sample:
    """A cube hub (part 0, half-size 1) with five square limbs (+x, -x, +y, -y, +z) out of holes in its faces' middle
    cells: each limb (part 1..5) is a tube of `rings` segments, capped; every limb's parent is the hub."""
    faces = [((1, 0, 0), (0, 1, 0), (0, 0, 1)), ((-1, 0, 0), (0, 0, 1), (0, 1, 0)), ((0, 1, 0), (0, 0, 1), (1, 0, 0)),
             ((0, -1, 0), (1, 0, 0), (0, 0, 1)), ((0, 0, 1), (1, 0, 0), (0, 1, 0)), ((0, 0, -1), (0, 1, 0), (1, 0, 0))]
    polygons, openings = [], [np.full(3, np.nan)]
    cells, half = 3, 1.0 / 3.0
    for limb, (normal, u, v) in enumerate(faces):
        has_limb = limb < 5
        polygons += _grid_face(normal, u, v, cells, has_limb, 0)
        if not has_limb:
            continue
        n, a, b = (np.asarray(x, dtype=np.float64) for x in (normal, u, v))
        square = [-a - b, a - b, a + b, -a + b]  # counter-clockwise about n
        for k in range(rings):
            near, far = n * (1 + limb_length * k / rings), n * (1 + limb_length * (k + 1) / rings)
            for i in range(4):
                c0, c1 = square[i] * half, square[(i + 1) % 4] * half
                polygons.append(([near + c0, near + c1, far + c1, far + c0], limb + 1))
        tip = n * (1 + limb_length)
        polygons.append(([tip + c * half for c in square], limb + 1))
        openings.append(n)
    positions, triangles, labels = _weld(polygons)
    names = ("hub", "limb_px", "limb_nx", "limb_py", "limb_ny", "limb_pz")
    parents = np.array([-1, 0, 0, 0, 0, 0], dtype=np.int32)
    return Sample(Parts(positions, triangles, labels, names), parents, np.array(openings))
