"""The skinning data model on numpy arrays: skeletons, linear-blend weights, animation-space models.

Shapes and dtypes are checked here, before anything reaches the C core, so a mistake is reported with
the parameter's name; the core re-checks every index it reads. All matrices are 4x4 row-major affine.
Notation follows Merry 2007: G_j maps bone j's frame to model space in the current pose, the rest
frame is Ĝ_j, bone 0 is the root (G_0 = I, model space).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import _core
from ._checks import (THREADS, as_array, as_count, as_index_array, as_optional_index_array, as_real_array,
                      check_memory, checked, real)
from ._core import Error as SkinkitError

__all__ = [
    "SkinkitError",
    "Mesh",
    "Skeleton",
    "SparseWeights",
    "AnimationSpaceModel",
    "convert_lbs",
    "lbs_evaluate",
    "skinning_matrices",
    "normals_from_tangents",
]

#: Blender's Armature modifier leaves a vertex undeformed when its total weight is below this.
BLENDER_MIN_TOTAL_WEIGHT = 1e-4


def checked_precision(dtype) -> np.dtype:
    try:
        dtype = np.dtype(dtype)
    except (TypeError, ValueError, SyntaxError):  # numpy parses some strings as Python: "(" raises SyntaxError
        raise SkinkitError(f"dtype: expected float32 or float64, got {dtype!r:.40}") from None
    if dtype not in (np.float32, np.float64):
        raise SkinkitError(f"dtype: expected float32 or float64, got {dtype}")
    return dtype


def output_array(out, shape: tuple, dtype, single: bool) -> np.ndarray:
    """`out` viewed with a leading pose axis (checked), or a new array of `shape`."""
    if out is None:
        return np.empty(shape, dtype)
    if not isinstance(out, np.ndarray) or out.dtype != dtype or not out.flags.c_contiguous or \
            not out.flags.writeable or out.shape != (shape[1:] if single else shape):
        wanted = shape[1:] if single else shape
        raise SkinkitError(f"out: expected a writable C-contiguous {np.dtype(dtype).name} array of shape {wanted}")
    return out[None] if single else out


def as_pose_stack(poses, bone_count: int, dtype=np.float64) -> tuple[np.ndarray, bool]:
    """Poses as (n, b, 4, 4) of `dtype`, and whether a single (b, 4, 4) pose was given."""
    array = as_array(poses, "poses")
    single = array.ndim == 3
    stack = as_real_array(array[None] if single else array, "poses", dtype, (None, bone_count, 4, 4))
    return stack, single


@dataclass(frozen=True, eq=False)
class Mesh:
    """Triangle mesh in Blender's vertex order, with the map back to Blender's polygons and loops.

    positions float64 (V, 3); triangles int32 (T, 3); triangle_polygons int32 (T,) the polygon each
    triangle came from; triangle_loops int32 (T, 3) the face corners (loops) of its three corners, where
    per-corner data such as UVs live. The last two may be None for a mesh that did not come from Blender.
    """

    positions: np.ndarray
    triangles: np.ndarray
    triangle_polygons: np.ndarray | None = None
    triangle_loops: np.ndarray | None = None

    @classmethod
    def create(cls, positions, triangles, triangle_polygons=None, triangle_loops=None) -> "Mesh":
        positions = as_real_array(positions, "positions", shape=(None, 3))
        triangles = as_index_array(triangles, "triangles", (None, 3))
        _core.validate_triangles(triangles, len(positions))
        triangle_polygons = as_optional_index_array(triangle_polygons, "triangle_polygons", (len(triangles),))
        triangle_loops = as_optional_index_array(triangle_loops, "triangle_loops", (len(triangles), 3))
        return cls(positions, triangles, triangle_polygons, triangle_loops)

    @property
    def vertex_count(self) -> int:
        return len(self.positions)


@dataclass(frozen=True, eq=False)
class Skeleton:
    """Bone hierarchy and rest frames. parents[0] == -1; rest_frames[j] is Ĝ_j (4x4, model space)."""

    parents: np.ndarray
    rest_frames: np.ndarray
    names: tuple[str, ...]

    @classmethod
    def create(cls, parents, rest_frames, names=None) -> "Skeleton":
        parents = as_index_array(parents, "parents", (None,))
        rest_frames = as_real_array(rest_frames, "rest_frames", shape=(len(parents), 4, 4))
        if names is not None and (not isinstance(names, (list, tuple)) or
                                  not all(isinstance(name, str) for name in names)):
            raise SkinkitError("names: expected a list of bone names (strings)")
        names = tuple(names) if names is not None else tuple(f"bone{j}" for j in range(len(parents)))
        if len(names) != len(parents):
            raise SkinkitError(f"names: {len(names)} names for {len(parents)} bones")
        if len(set(names)) != len(names):
            duplicates = sorted({n for n in names if names.count(n) > 1})
            raise SkinkitError(f"names: bone names must be unique, repeated: {duplicates}")
        _core.validate_skeleton(parents, rest_frames.reshape(-1))
        return cls(parents, rest_frames, names)

    @property
    def bone_count(self) -> int:
        return len(self.parents)


@dataclass(frozen=True, eq=False)
class InfluencePattern:
    """Which bones influence each vertex, in compressed rows: vertex i has bones[offsets[i]:offsets[i+1]]."""

    offsets: np.ndarray
    bones: np.ndarray

    @staticmethod
    def checked_pattern(offsets, bones, bone_count: int) -> tuple[np.ndarray, np.ndarray]:
        as_count(bone_count, "bone_count")
        offsets = as_index_array(offsets, "offsets", (None,))
        bones = as_index_array(bones, "bones", (None,))
        if len(offsets) == 0:
            raise SkinkitError("offsets: needs vertex_count + 1 entries, got none")
        _core.validate_influences(offsets, bones, bone_count)
        return offsets, bones

    @classmethod
    def checked_with_values(cls, offsets, bones, bone_count: int, values, name: str, width: int | None = None):
        """(offsets, bones, values): the pattern checked over bone_count bones and `values`, one row (of `width`
        columns, or a scalar) per influence, checked as the parameter `name`; what every `create` takes."""
        offsets, bones = cls.checked_pattern(offsets, bones, bone_count)
        shape = (len(bones),) if width is None else (len(bones), width)
        return offsets, bones, as_real_array(values, name, shape=shape)

    @property
    def vertex_count(self) -> int:
        return len(self.offsets) - 1

    @property
    def influence_count(self) -> int:
        return len(self.bones)

    def counts(self) -> np.ndarray:
        """Influences per vertex."""
        return np.diff(self.offsets)

    def vertex_of_each_influence(self) -> np.ndarray:
        return np.repeat(np.arange(self.vertex_count), self.counts())


@dataclass(frozen=True, eq=False)
class SparseWeights(InfluencePattern):
    """Linear-blend weights, one per influence."""

    weights: np.ndarray

    @classmethod
    def create(cls, offsets, bones, weights, bone_count: int) -> "SparseWeights":
        return cls(*cls.checked_with_values(offsets, bones, bone_count, weights, "weights"))

    @classmethod
    @checked(threshold=real())
    def from_dense(cls, dense, threshold: float = 0.0) -> "SparseWeights":
        """From a (vertices, bones) matrix, keeping entries whose magnitude exceeds threshold."""
        dense = as_real_array(dense, "weights", shape=(None, None))
        rows, columns = np.nonzero(np.abs(dense) > threshold)
        offsets = np.zeros(dense.shape[0] + 1, np.int32)
        np.cumsum(np.bincount(rows, minlength=dense.shape[0]), out=offsets[1:])
        return cls.create(offsets, columns, dense[rows, columns], dense.shape[1])

    def totals(self) -> np.ndarray:
        """Sum of the weights of each vertex."""
        return np.bincount(self.vertex_of_each_influence(), self.weights, minlength=self.vertex_count)

    def to_dense(self, bone_count: int) -> np.ndarray:
        needed = int(self.bones.max(initial=-1)) + 1
        as_count(bone_count, "bone_count", minimum=needed)
        check_memory(self.vertex_count * bone_count * 8, "a dense weight matrix", "ask for fewer bones")
        dense = np.zeros((self.vertex_count, bone_count))
        np.add.at(dense, (self.vertex_of_each_influence(), self.bones), self.weights)
        return dense

    def normalized_like_blender(self) -> "SparseWeights":
        """Weights as Blender's Armature modifier applies them (eq. 2.2 needs sum 1).

        Blender divides each vertex's weights by their total when it exceeds 1e-4 and leaves the
        other vertices at their rest position; that is the root bone 0 with weight 1 here.
        """
        totals = self.totals()
        deforming = totals > BLENDER_MIN_TOTAL_WEIGHT
        keep = np.repeat(deforming, self.counts())
        scale = np.repeat(np.where(deforming, totals, 1.0), self.counts())
        per_vertex = np.where(deforming, self.counts(), 1)
        offsets = np.zeros(self.vertex_count + 1, np.int32)
        np.cumsum(per_vertex, out=offsets[1:])
        bones = np.zeros(offsets[-1], np.int32)
        weights = np.ones(offsets[-1])
        kept_slots = np.repeat(deforming, per_vertex)
        bones[kept_slots] = self.bones[keep]
        weights[kept_slots] = (self.weights / scale)[keep]
        return SparseWeights(offsets, bones, weights)


@dataclass(frozen=True, eq=False)
class AnimationSpaceModel(InfluencePattern):
    """Per vertex a sparse list of (bone, 4-vector p_j) with v = Σ_j G_j p_j (Merry eq. 3.1-3.2).

    coordinates has shape (influences, 4): (x, y, z, weight) of each p_j in its bone's frame. For a
    point the weights of a vertex sum to 1, for a tangent vector to 0.
    """

    coordinates: np.ndarray
    bone_count: int
    _single: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def create(cls, offsets, bones, coordinates, bone_count: int) -> "AnimationSpaceModel":
        return cls(*cls.checked_with_values(offsets, bones, bone_count, coordinates, "coordinates", 4), int(bone_count))

    def homogeneous_weights(self) -> np.ndarray:
        """Σ_j of the weight of p_j per vertex: 1 for points, 0 for vectors (the thesis' underline p)."""
        return np.bincount(self.vertex_of_each_influence(), self.coordinates[:, 3], minlength=self.vertex_count)

    def coordinates_f32(self) -> np.ndarray:
        """Single-precision copy for the fast path, made once per model."""
        if "coordinates" not in self._single:
            self._single["coordinates"] = self.coordinates.astype(np.float32)
        return self._single["coordinates"]

    @checked(threads=THREADS)
    def evaluate(self, poses, dtype=np.float64, threads: int = 0, out: np.ndarray | None = None) -> np.ndarray:
        """Animation projection. poses: (b, 4, 4) -> (V, 3), or (n, b, 4, 4) -> (n, V, 3).

        dtype float32 takes the fast single-precision path; threads 0 means one per core. `out`, a
        C-contiguous array of the result's shape and dtype, is filled instead of a new array (replaying
        many frames into one buffer saves the page faults of a fresh allocation each time).
        """
        dtype = checked_precision(dtype)
        stack, single = as_pose_stack(poses, self.bone_count, dtype)
        coordinates = self.coordinates if dtype == np.float64 else self.coordinates_f32()
        result = output_array(out, (len(stack), self.vertex_count, 3), dtype, single)
        for pose, destination in zip(stack, result):
            _core.animation_space_evaluate(destination, self.offsets, self.bones, coordinates, pose.reshape(-1),
                                           threads)
        return result[0] if single else result


@checked(skeleton=Skeleton)
def skinning_matrices(skeleton: Skeleton, poses) -> np.ndarray:
    """N_j = G_j Ĝ_j^-1 for each pose: (b, 4, 4) -> (b, 4, 4), (n, b, 4, 4) -> (n, b, 4, 4)."""
    stack, single = as_pose_stack(poses, skeleton.bone_count)
    result = np.empty_like(stack)
    rest = skeleton.rest_frames.reshape(-1)
    for pose, out in zip(stack, result):
        _core.skinning_matrices(out.reshape(-1), pose.reshape(-1), rest)
    return result[0] if single else result


@checked(skeleton=Skeleton, weights=SparseWeights, homogeneous=real())
def convert_lbs(skeleton: Skeleton, weights: SparseWeights, rest_vectors, homogeneous: float = 1.0) -> AnimationSpaceModel:
    """Linear blend skinning as an animation-space model: p_j = w_j Ĝ_j^-1 v̂ (eq. 3.1).

    rest_vectors: (V, 3) rest positions (homogeneous=1), or rest tangent vectors (homogeneous=0,
    eq. 4.8); the model then evaluates to the skinned tangents. Weights are used as given.
    """
    rest_vectors = as_real_array(rest_vectors, "rest_vectors", shape=(weights.vertex_count, 3))
    coordinates = np.empty((weights.influence_count, 4))
    _core.lbs_to_animation_space(
        coordinates, rest_vectors, float(homogeneous), weights.offsets, weights.bones, weights.weights,
        skeleton.rest_frames.reshape(-1),
    )
    return AnimationSpaceModel(weights.offsets, weights.bones, coordinates, skeleton.bone_count)


@checked(skeleton=Skeleton, weights=SparseWeights, homogeneous=real(), threads=THREADS)
def lbs_evaluate(skeleton: Skeleton, weights: SparseWeights, rest_vectors, poses, homogeneous: float = 1.0,
                 dtype=np.float64, threads: int = 0, out: np.ndarray | None = None) -> np.ndarray:
    """Linear blend skinning v = Σ_j w_j G_j Ĝ_j^-1 v̂ (eq. 2.2) of positions or (homogeneous=0) vectors.

    Shapes, dtype, threads and out as in AnimationSpaceModel.evaluate.
    """
    dtype = checked_precision(dtype)
    rest_vectors = as_real_array(rest_vectors, "rest_vectors", dtype, (weights.vertex_count, 3))
    matrices = np.asarray(skinning_matrices(skeleton, poses))
    single = matrices.ndim == 3
    matrices = (matrices[None] if single else matrices).astype(dtype)
    values = weights.weights.astype(dtype)
    result = output_array(out, (len(matrices), weights.vertex_count, 3), dtype, single)
    for matrix, destination in zip(matrices, result):
        _core.lbs_evaluate(destination, rest_vectors, float(homogeneous), weights.offsets, weights.bones, values,
                           matrix.reshape(-1), threads)
    return result[0] if single else result


def normals_from_tangents(s, t) -> np.ndarray:
    """Unit normals n = normalize(s x t) from two evaluated tangents per vertex (section 3.5)."""
    s = as_real_array(s, "s")
    t = as_real_array(t, "t")
    if s.shape != t.shape or s.ndim == 0 or s.shape[-1] != 3:
        raise SkinkitError(f"s, t: expected two arrays of the same shape (..., 3), got {s.shape} and {t.shape}")
    normal = np.cross(s, t)
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    return normal / np.where(length > 0, length, 1)
