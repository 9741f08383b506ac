"""The LOD chain benchmark's shared pieces: the error measured at corresponding surface points (thesis section 8.5)
and the peers' chains (Blender's Decimate, meshoptimizer's simplifier, fast-simplification), each followed by
Blender's Limit Total at K = 1..4 so every peer offers a range of total influences.

Correspondence: points are sampled uniformly by area on the input mesh in the rest pose (fixed seed); on a level,
each point's partner is the closest point of the level's rest-pose mesh (libigl's point_mesh_squared_distance),
kept as a triangle and barycentric coordinates. Both points are then carried through every held-out pose by
their meshes' posed vertices, so the error is the distance between the same surface point on the full model
and on the level over the animation (the thesis renders geometry images to match parameter-space points; with no
atlas on the horse, the rest-pose surface is the common parameter space).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from skinkit import convert_lbs
from skinkit.lod.influences import limit_total
from skinkit.model import SparseWeights

SAMPLE_COUNT = 20000
SAMPLE_SEED = 7
#: Triangle fractions every peer is run at (a chain: each is a separate call from the input, as the peers offer).
FRACTIONS = (1.0, 1 / 2, 1 / 4, 1 / 8, 1 / 16, 1 / 32, 1 / 64)
#: Limit Total's K after each peer's simplification; None keeps the weights the peer produced.
PEER_LIMITS = (None, 4, 3, 2, 1)
#: meshoptimizer's simplifyWithAttributes accepts at most this many attributes (its kMaxAttributes).
MESHOPT_MAX_ATTRIBUTES = 32


@dataclass
class Level:
    """A level as the error measure needs it: rest-pose surface (for the correspondence) and posed vertices."""
    rest: np.ndarray  # (V, 3)
    triangles: np.ndarray  # (T, 3)
    posed: np.ndarray  # (F, V, 3) in the held-out poses
    influences: int


class SurfaceSamples:
    """Points spread uniformly by area over the input mesh, with their (triangle, barycentric) on it."""

    def __init__(self, rest: np.ndarray, triangles: np.ndarray, count: int = SAMPLE_COUNT, seed: int = SAMPLE_SEED):
        corners = rest[triangles]
        areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
        rng = np.random.default_rng(seed)
        self.triangle = rng.choice(len(triangles), size=count, p=areas / areas.sum())
        root, second = np.sqrt(rng.random(count)), rng.random(count)
        self.barycentric = np.column_stack([1 - root, root * (1 - second), root * second])
        self.triangles = triangles
        self.points = interpolate(rest[None], triangles, self.triangle, self.barycentric)[0]

    def on_input(self, posed: np.ndarray) -> np.ndarray:
        return interpolate(posed, self.triangles, self.triangle, self.barycentric)

    def on_level(self, level: Level) -> np.ndarray:
        """The samples' partners on a level (closest rest-pose points), carried through its posed vertices."""
        import igl

        _, face, closest = igl.point_mesh_squared_distance(self.points, level.rest,
                                                           np.ascontiguousarray(level.triangles, np.int64))
        face = np.asarray(face, np.int64).reshape(-1)
        return interpolate(level.posed, level.triangles, face,
                           barycentric(closest, level.rest[level.triangles[face]]))


def interpolate(posed: np.ndarray, triangles: np.ndarray, face: np.ndarray, weights: np.ndarray) -> np.ndarray:
    corners = triangles[face]
    return sum(posed[:, corners[:, k]] * weights[None, :, k, None] for k in range(3))


def barycentric(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of points lying on triangles (S, 3, 3); degenerate triangles give the first corner."""
    e1, e2, d = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], points - corners[:, 0]
    a, b, c = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    p, q = (d * e1).sum(1), (d * e2).sum(1)
    determinant = a * c - b * b
    safe = np.where(np.abs(determinant) > 1e-300, determinant, 1.0)
    v = np.where(np.abs(determinant) > 1e-300, (c * p - b * q) / safe, 0.0)
    w = np.where(np.abs(determinant) > 1e-300, (a * q - b * p) / safe, 0.0)
    return np.column_stack([1 - v - w, v, w])


def rms(distance_points: np.ndarray, reference_points: np.ndarray, scale: float) -> float:
    return float(np.sqrt(np.mean(np.sum((distance_points - reference_points) ** 2, axis=-1)))) * scale


# ---- the peers' levels ----------------------------------------------------------------------------------------


def lbs_level(skeleton, weights: SparseWeights, rest: np.ndarray, triangles: np.ndarray, poses) -> Level:
    posed = convert_lbs(skeleton, weights, rest).evaluate(poses)
    return Level(rest, triangles, posed, weights.influence_count)


def restricted(weights: SparseWeights, vertices: np.ndarray) -> SparseWeights:
    counts = np.diff(weights.offsets)[vertices]
    offsets = np.zeros(len(vertices) + 1, np.int32)
    np.cumsum(counts, out=offsets[1:])
    index = np.repeat(weights.offsets[vertices] - offsets[:-1], counts) + np.arange(offsets[-1])
    return SparseWeights(offsets, weights.bones[index].copy(), weights.weights[index].copy())


def compacted(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(kept vertices ascending, triangles renumbered onto them)."""
    vertices = np.unique(triangles)
    return vertices, np.searchsorted(vertices, triangles).astype(np.int32)


def declare_simplify_with_attributes():
    """The PyPI wrapper (0.2.30a0) declares no argument types for meshopt_simplifyWithAttributes, so ctypes refuses
    its float target_error and would pass the size_t counts as C ints: declared here as meshoptimizer.h has it."""
    import ctypes

    from meshoptimizer._loader import lib

    floats, uints = ctypes.POINTER(ctypes.c_float), ctypes.POINTER(ctypes.c_uint)
    size = ctypes.c_size_t
    function = lib.meshopt_simplifyWithAttributes
    function.argtypes = [uints, uints, size, floats, size, size, floats, size, floats, size,
                         ctypes.POINTER(ctypes.c_ubyte), size, ctypes.c_float, ctypes.c_uint, floats]
    function.restype = size


def meshopt_simplify(rest, triangles, weights: SparseWeights, bone_count: int, fraction: float):
    """meshoptimizer's simplifyWithAttributes with the dense weights of the heaviest bones (at most 32) as
    attributes, weight 1 each (weights are already in [0, 1]); a subset of the input vertices survives."""
    import meshoptimizer

    declare_simplify_with_attributes()
    dense = weights.to_dense(bone_count)
    heaviest = np.sort(np.argsort(-dense.sum(axis=0))[:MESHOPT_MAX_ATTRIBUTES])
    attributes = np.ascontiguousarray(dense[:, heaviest], np.float32)
    indices = np.ascontiguousarray(triangles.reshape(-1), np.uint32)
    destination = np.empty_like(indices)
    count = meshoptimizer.simplify_with_attributes(
        destination, indices, np.ascontiguousarray(rest, np.float32), attributes,
        np.ones(attributes.shape[1], np.float32), target_index_count=3 * max(1, int(len(triangles) * fraction)),
        target_error=1.0)
    vertices, local = compacted(destination[:count].reshape(-1, 3).astype(np.int64))
    return rest[vertices], local, restricted(weights, vertices)


def fast_simplify(rest, triangles, weights: SparseWeights, fraction: float):
    """fast-simplification's quadric decimation (moves vertices); each new vertex takes the weights of the nearest
    input vertex in the rest pose."""
    import fast_simplification
    from scipy.spatial import cKDTree

    points, faces = fast_simplification.simplify(rest, triangles.astype(np.int32), target_reduction=1 - fraction)
    nearest = cKDTree(rest).query(points)[1]
    return np.asarray(points, float), np.asarray(faces, np.int32), restricted(weights, nearest)


def blender_decimate(rest, triangles, weights: SparseWeights, bone_count: int, fraction: float):
    """Blender's Decimate modifier (Collapse, the given ratio) applied to a mesh carrying the weights as vertex
    groups; Decimate interpolates the groups at the collapsed vertices."""
    import bpy

    from skinkit.blender.attributes import write_bone_groups
    from skinkit.blender.rig import mesh_of, read_vertex_groups
    from skinkit.blender.scene import new_mesh_object

    names = ["root"] + [f"bone{j}" for j in range(1, bone_count)]
    mesh_object = new_mesh_object("decimate_peer", rest, triangles)
    try:
        write_bone_groups(mesh_object, weights, names)
        modifier = mesh_object.modifiers.new("decimate", "DECIMATE")
        modifier.decimate_type, modifier.ratio = "COLLAPSE", fraction
        started = time.perf_counter()
        with bpy.context.temp_override(object=mesh_object, active_object=mesh_object):
            bpy.ops.object.modifier_apply(modifier=modifier.name)
        seconds = time.perf_counter() - started
        mesh = mesh_of(mesh_object)
        dense = np.column_stack([np.zeros(len(mesh.positions)), read_vertex_groups(mesh_object, names[1:])])
        return mesh.positions, mesh.triangles, SparseWeights.from_dense(dense).normalized_like_blender(), seconds
    finally:
        data = mesh_object.data
        bpy.data.objects.remove(mesh_object)
        bpy.data.meshes.remove(data)


def peer_chains(model_data: dict, samples: SurfaceSamples, reference: np.ndarray, frames: np.ndarray, scale: float,
                with_blender: bool) -> dict:
    """Each peer at every fraction of FRACTIONS and Limit Total K of PEER_LIMITS: points of (influences, error to
    its own full detail, error to the frames), and the seconds of its simplification calls over the fractions."""
    skeleton, weights, rest = model_data["skeleton"], model_data["weights"], model_data["rest"]
    triangles, poses, bones = model_data["triangles"], model_data["test_poses"], skeleton.bone_count
    simplifiers = {"meshoptimizer (weights as attributes)": lambda f: meshopt_simplify(rest, triangles, weights, bones, f),
                   "fast-simplification (quadric)": lambda f: fast_simplify(rest, triangles, weights, f)}
    if with_blender:
        simplifiers["Blender Decimate (collapse)"] = lambda f: blender_decimate(rest, triangles, weights, bones, f)
    results = {}
    for name, simplify in simplifiers.items():
        points, seconds = [], 0.0
        for fraction in FRACTIONS:
            started = time.perf_counter()
            if fraction == 1.0:
                out = (rest, triangles, weights)
            else:
                out = simplify(fraction)
            elapsed = time.perf_counter() - started
            if len(out) == 4:
                out, elapsed = out[:3], out[3]
            seconds += elapsed
            level_rest, level_triangles, level_weights = out
            for k in PEER_LIMITS:
                limited = level_weights if k is None else limit_total(level_weights, k)
                level = lbs_level(skeleton, limited, level_rest, level_triangles, poses)
                at = samples.on_level(level)
                points.append({"fraction": fraction, "K": k, "triangles": int(len(level_triangles)),
                               "vertices": int(len(level_rest)), "influences": int(limited.influence_count),
                               "mean_influences": float(limited.influence_count / max(1, len(level_rest))),
                               "max_influences": int(limited.counts().max()),
                               "error": rms(at, reference, scale), "to_frames": rms(at, frames, scale)})
        results[name] = {"points": points, "seconds": seconds}
    return results


def frontier(points: list[dict], key: str = "error") -> list[tuple[int, float]]:
    """The Pareto front (influences ascending, error strictly falling) of a peer's points."""
    front, best = [], np.inf
    for point in sorted(points, key=lambda p: (p["influences"], p[key])):
        if point[key] < best:
            front.append((point["influences"], point[key]))
            best = point[key]
    return front


def error_at(front: list[tuple[int, float]], influences: int) -> float | None:
    """A peer's error at a total influence count, log-log interpolated along its front; below its fewest
    influences it cannot go (None); above its most, its best error."""
    if not front or influences < front[0][0]:
        return None
    counts = np.log([c for c, _ in front])
    errors = np.log([max(e, 1e-300) for _, e in front])
    return float(np.exp(np.interp(np.log(influences), counts, errors)))
