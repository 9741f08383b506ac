"""The animation-space metrics (Merry 2007, chapter 3): distances measured over every pose a character takes.

PoseStatistics holds, per joint j, E[L_j] (L_j maps bone j's frame to its parent's) and E[G_j^T G_j]
(the "independent joints" model), plus the bounds the max-distance norm needs: a bound on the 2-norm
of L_j's linear part and a sphere holding its translation. They come from sampled poses or from analytic
models (fixed skeleton, uniform rotations, rotation ranges about an axis). The expectation matrix P,
with blocks E[G_j^T G_k], is formed block by block as computations need it (eq. 3.7-3.8).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import _core
from ._checks import as_count, as_index_array, as_real, as_real_array, check_memory, checked, real
from ._memory import COMBINE_CHUNK, check_combined_vectors, check_distances, check_pose_statistics, check_vector_rows
from .model import AnimationSpaceModel, InfluencePattern, SkinkitError

#: The public API (what tests/fuzz/api_fuzz.py calls with hostile arguments); the rest are helpers.
__all__ = ["PoseStatistics", "SparseVectors", "pixel_tolerance"]

#: Where a rig's statistics come from: the frames of its action or of example poses (sampled), its rotation limits
#: (PoseStatistics.joints) or uniform rotations (PoseStatistics.uniform_rotations).
STATISTICS_SOURCES = ("action", "poses", "limits", "uniform")


@dataclass(frozen=True, eq=False)
class PoseStatistics:
    parents: np.ndarray
    expected_local: np.ndarray       # (b, 4, 4)
    expected_gram: np.ndarray        # (b, 4, 4)
    linear_bound: np.ndarray         # (b,)
    translation_centre: np.ndarray   # (b, 3)
    translation_radius: np.ndarray   # (b,)
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def bone_count(self) -> int:
        return len(self.parents)

    # ---- making statistics ----------------------------------------------------------------------

    @classmethod
    def from_local_samples(cls, parents, local, spread: float = 0.0) -> "PoseStatistics":
        """From sampled joint matrices local (S, b, 4, 4) (L_0, the root's, is ignored: it is I). spread (radians,
        0 to pi; see spread_rotations): each joint's sampled rotations also turned by +-spread about its own axes,
        for statistics of a few example poses that must also price the poses between and around them."""
        parents = as_index_array(parents, "parents", (None,))
        local = as_real_array(local, "local", shape=(None, len(parents), 4, 4))
        spread = as_real(spread, "spread", minimum=0.0, maximum=float(np.pi))
        if len(local) == 0:
            raise SkinkitError("local: at least one sampled pose is needed")
        check_pose_statistics(len(local) * (SPREAD_TURNS + 1 if spread > 0 else 1), len(parents))
        if spread > 0:
            local = spread_rotations(local, spread)
        expected_local = np.empty((len(parents), 4, 4))
        expected_gram = np.empty((len(parents), 4, 4))
        _core.joint_statistics(expected_local, expected_gram, np.ascontiguousarray(local).reshape(-1), parents)
        norms = np.empty(local.shape[0] * local.shape[1])
        _core.linear_norms(norms, np.ascontiguousarray(local).reshape(-1))
        linear = norms.reshape(local.shape[:2]).max(axis=0)
        translations = local[:, :, :3, 3]
        centre = (translations.max(axis=0) + translations.min(axis=0)) / 2
        radius = np.linalg.norm(translations - centre, axis=2).max(axis=0)
        linear[0], centre[0], radius[0] = 1.0, 0.0, 0.0
        return cls(parents, expected_local, expected_gram, linear, centre, radius)

    @classmethod
    def from_world_samples(cls, parents, world, spread: float = 0.0) -> "PoseStatistics":
        """From sampled bone frames world (S, b, 4, 4) (G_j in model space, G_0 = I); spread as from_local_samples."""
        parents = as_index_array(parents, "parents", (None,))
        world = as_real_array(world, "world", shape=(None, len(parents), 4, 4))
        _core.validate_skeleton(parents, None)
        check_pose_statistics(len(world), len(parents))
        parent_frames = world[:, np.maximum(parents, 0)]
        singular = np.abs(np.linalg.det(parent_frames[..., :3, :3])) < 1e-12
        if singular.any():
            sample, bone = (int(i) for i in np.argwhere(singular)[0])
            raise SkinkitError(f"world: sample {sample}, bone {int(parents[bone])}'s frame is singular (its "
                               "children's local matrices are undefined)")
        local = np.linalg.solve(parent_frames, world)
        local[:, 0] = np.eye(4)
        return cls.from_local_samples(parents, local, spread)

    @classmethod
    def fixed_skeleton(cls, parents, local) -> "PoseStatistics":
        """The rest pose only: the metric is then the rest pose's Euclidean one."""
        return cls.from_local_samples(parents, as_real_array(local, "local", shape=(None, 4, 4))[None])

    @classmethod
    def uniform_rotations(cls, parents, translations) -> "PoseStatistics":
        """Every joint uniformly rotated (Haar measure), fixed translations (b, 3) (eq. 3.15)."""
        parents, translations = checked_joints(parents, translations)
        return cls.joints(parents, translations, np.tile(np.eye(3), (len(parents), 1, 1)),
                          [("uniform",)] * len(parents))

    @classmethod
    def rotation_ranges(cls, parents, translations, axes, ranges) -> "PoseStatistics":
        """Each joint rotated about its axis (b, 3) by an angle uniform in ranges (b, 2) radians, fixed
        translations (eq. 3.14 generalised to any axis)."""
        parents, translations = checked_joints(parents, translations)
        axes = as_real_array(axes, "axes", shape=(len(parents), 3))
        ranges = as_real_array(ranges, "ranges", shape=(len(parents), 2))
        return cls.joints(parents, translations, np.tile(np.eye(3), (len(parents), 1, 1)),
                          [("range", a, r[0], r[1]) for a, r in zip(axes, ranges)])

    @classmethod
    def joints(cls, parents, translations, rest_rotations, models) -> "PoseStatistics":
        """Independent joints L_j = [R0_j R_j, t_j; 0 1] with fixed translations t_j, rest rotations R0_j and,
        per joint, a model of R_j: ("uniform",) Haar-random, ("range", axis, first, last) an angle uniform
        on [first, last] about axis (in the bone's own frame), ("euler", [(axis, first, last), ...])
        independent uniform Euler angles in application order, or ("fixed",) the rest rotation only."""
        parents, translations = checked_joints(parents, translations)
        rest_rotations = as_real_array(rest_rotations, "rest_rotations", shape=(len(parents), 3, 3))
        if not isinstance(models, (list, tuple)) or len(models) != len(parents):
            raise SkinkitError(f"models: expected a list of {len(parents)} joint models, one per bone")
        laws = [rotation_law(joint, model) for joint, model in enumerate(models)]
        rotation_mean = np.stack([rest @ mean for rest, (mean, _) in zip(rest_rotations, laws)])

        def second_moment(joint, a):  # E[(R0 R)^T A (R0 R)] = E[R^T (R0^T A R0) R]
            rest = rest_rotations[joint]
            return laws[joint][1](rest.T @ a @ rest)

        return analytic(parents, translations, rotation_mean, second_moment)

    # ---- using them -----------------------------------------------------------------------------

    def block(self, j: int, k: int) -> np.ndarray:
        """P_jk = E[G_j^T G_k] (4x4)."""
        as_count(j, "j")  # the core says when a bone is outside the skeleton
        as_count(k, "k")
        block = np.empty(16)
        _core.expectation_block(block, self.expected_local.reshape(-1), self.expected_gram.reshape(-1), self.parents,
                                int(j), int(k))
        return block.reshape(4, 4)

    def matrix(self) -> np.ndarray:
        """The whole P as a dense (4b, 4b) matrix: only for small skeletons, when asked for."""
        b = self.bone_count
        blocks = np.empty(b * b * 16)
        _core.expectation_blocks(blocks, self.expected_local.reshape(-1), self.expected_gram.reshape(-1), self.parents)
        return blocks.reshape(b, b, 4, 4).transpose(0, 2, 1, 3).reshape(4 * b, 4 * b)

    def mean_distance(self, vectors: "SparseVectors") -> np.ndarray:
        """The L2,2 norm sqrt(E |G s|^2) of each weight-0 vector (eq. 3.6)."""
        self._check_vectors(vectors, "vectors")
        b = self.bone_count
        check_distances(vectors.vertex_count, b, cached_blocks="blocks" not in self._cache)
        if "blocks" not in self._cache:
            self._cache["blocks"] = np.zeros(b * b * 16)
            self._cache["cached"] = np.zeros(b * b, np.uint8)
        out = np.empty(vectors.vertex_count)
        _core.mean_distances(out, vectors.offsets, vectors.bones, vectors.coordinates.reshape(-1),
                             self.expected_local.reshape(-1), self.expected_gram.reshape(-1), self.parents,
                             self._cache["blocks"], self._cache["cached"], 0)
        return out

    def inner_product(self, first: "SparseVectors", second: "SparseVectors") -> np.ndarray:
        """<s_i, t_i>_{2,2} = E[G s_i . G t_i] for each pair (eq. 3.16), by polarisation of the norm."""
        self._check_vectors(as_vectors(first, "first"), "first")
        self._check_vectors(as_vectors(second, "second"), "second")
        total, difference = first.combined(second, 1.0), first.combined(second, -1.0)
        return (self.mean_distance(total) ** 2 - self.mean_distance(difference) ** 2) / 4

    def max_distance(self, vectors: "SparseVectors") -> np.ndarray:
        """An upper bound on |G s| over every pose within the joints' bounds (the L2,inf norm, eq. 3.18-3.28)."""
        self._check_vectors(vectors, "vectors")
        check_distances(vectors.vertex_count, self.bone_count, cached_blocks=False)
        out = np.empty(vectors.vertex_count)
        _core.max_distances(out, vectors.offsets, vectors.bones, vectors.coordinates.reshape(-1), self.parents,
                            np.ascontiguousarray(self.linear_bound), np.ascontiguousarray(self.translation_centre),
                            np.ascontiguousarray(self.translation_radius), 0)
        return out

    def _check_vectors(self, vectors, name: str) -> None:
        """vectors must be SparseVectors (or a model: its rows) on this skeleton's bones."""
        if not isinstance(vectors, (SparseVectors, AnimationSpaceModel)):
            raise SkinkitError(f"{name}: expected SparseVectors, got {type(vectors).__name__}")
        if vectors.influence_count and int(vectors.bones.max()) >= self.bone_count:
            raise SkinkitError(f"{name}: bone {int(vectors.bones.max())} is not one of the statistics' "
                               f"{self.bone_count} bones")

    def _check_model(self, model, name: str = "model") -> None:
        if not isinstance(model, AnimationSpaceModel):
            raise SkinkitError(f"{name}: expected an AnimationSpaceModel, got {type(model).__name__}")
        if model.bone_count != self.bone_count:
            raise SkinkitError(f"{name}: {model.bone_count} bones, the statistics have {self.bone_count}")

    @checked(threshold=real(minimum=0))
    def null_space(self, threshold: float = 1e-9) -> np.ndarray:
        """Columns spanning the (numerical) null space of P among weight-0 vectors (appendix B.3)."""
        values, vectors = np.linalg.eigh(self.matrix())
        return vectors[:, values <= threshold * max(values.max(), 1e-300)]

    def normalised_coordinates(self) -> np.ndarray:
        """C = P^(1/2), so that (C s) . (C t) = <s, t>_{2,2} (eq. 3.17); dense, for small skeletons."""
        values, vectors = np.linalg.eigh(self.matrix())
        return (vectors * np.sqrt(np.clip(values, 0.0, None))) @ vectors.T

    @checked(scale=real(above=0, maximum=1e100))
    def scaled(self, scale: float) -> "PoseStatistics":
        """The statistics of the same poses with the model scaled uniformly by `scale` (eq. 3.29-3.31):
        joint translations scale, linear parts do not; a self block [[A, B], [C, D]] becomes
        [[A, sB], [sC, s^2 (D - 1) + 1]]; translation spheres scale, linear bounds stay."""
        if not (np.isfinite(scale) and scale > 0):
            raise SkinkitError(f"scale must be finite and > 0, got {scale}")
        local = self.expected_local.copy()
        local[:, :3, 3] *= scale
        gram = self.expected_gram.copy()
        gram[:, :3, 3] *= scale
        gram[:, 3, :3] *= scale
        gram[:, 3, 3] = scale ** 2 * (gram[:, 3, 3] - 1) + 1
        return PoseStatistics(self.parents, local, gram, self.linear_bound.copy(), self.translation_centre * scale,
                              self.translation_radius * scale)

    def transformed(self, matrix) -> "PoseStatistics":
        """The statistics after a rigid motion M of the model (eq. 3.32-3.33): the root's children get
        L'_j = M L_j, so every other G'_j = M G_j and E[G'_j^T G'_j] = E[G_j^T (M^T M) G_j]."""
        matrix = as_real_array(matrix, "matrix", shape=(4, 4)).copy()
        linear = matrix[:3, :3]
        # Blender's object matrices are single precision: rigid to about 1e-7, which is rigid enough here.
        if np.abs(linear.T @ linear - np.eye(3)).max() > 1e-5 or np.abs(matrix[3] - [0, 0, 0, 1]).max() > 1e-9:
            raise SkinkitError("matrix must be a rigid motion (rotation and translation)")
        matrix[3] = [0, 0, 0, 1]
        children = np.flatnonzero(self.parents == 0)
        local = self.expected_local.copy()
        local[children] = matrix @ local[children]
        centre = self.translation_centre.copy()
        centre[children] = centre[children] @ linear.T + matrix[:3, 3]
        difference = matrix.T @ matrix - np.eye(4)  # [[0, B], [B^T, C - 1]] for a rigid M
        b, c = difference[:3, 3], difference[3, 3]
        gram = self.expected_gram.copy()
        for j in range(1, self.bone_count):
            # G^T (M^T M - I) G = [[0, Ḡ^T B], [B^T Ḡ, 2 B.g + C - 1]] is linear in G = [[Ḡ, g], [0, 1]], so its
            # expectation needs only E[G_j], the block (0, j).
            expected_frame = self.block(0, j)
            gram[j, :3, 3] += expected_frame[:3, :3].T @ b
            gram[j, 3, :3] += expected_frame[:3, :3].T @ b
            gram[j, 3, 3] += 2 * b @ expected_frame[:3, 3] + c
        return PoseStatistics(self.parents, local, gram, self.linear_bound.copy(), centre, self.translation_radius.copy())

    def expected_centroid(self, model: AnimationSpaceModel) -> np.ndarray:
        """The mean over vertices of E[G p_v] (3,): E[G_j] is the block (0, j)."""
        self._check_model(model)
        expected_frames = np.stack([self.block(0, j) for j in range(self.bone_count)])
        per_influence = np.einsum("kij,kj->ki", expected_frames[model.bones], model.coordinates)
        return per_influence[:, :3].sum(axis=0) / max(model.vertex_count, 1)  # sum over vertices of their sums

    def vertex_bounds(self, model: AnimationSpaceModel, centre) -> np.ndarray:
        """(V,): each vertex's max-distance bound from the fixed point `centre` (in model space)."""
        self._check_model(model)
        centre = as_real_array(centre, "centre", shape=(3,))
        everything = SparseVectors.rows(model, np.arange(model.vertex_count))
        return self.max_distance(everything.combined(SparseVectors.at_root(np.r_[centre, 1.0], model.vertex_count), -1.0))

    def culling_sphere(self, model: AnimationSpaceModel, centre_statistics: "PoseStatistics") -> tuple[np.ndarray, float]:
        """A sphere holding the model in every pose within the bounds (section 7.2): centred on the expected
        centroid under centre_statistics (use uniform rotations, to avoid bias), radius the largest
        max-distance bound of a vertex from that centre."""
        if not isinstance(centre_statistics, PoseStatistics):
            raise SkinkitError(f"centre_statistics: expected PoseStatistics, got {type(centre_statistics).__name__}")
        self._check_model(model)
        centre = centre_statistics.expected_centroid(model)
        return centre, float(self.vertex_bounds(model, centre).max(initial=0.0))


@dataclass(frozen=True, eq=False)
class SparseVectors(InfluencePattern):
    """Sparse animation-space vectors (one 4-vector per entry), e.g. differences p - q of two points."""

    coordinates: np.ndarray

    @classmethod
    def create(cls, offsets, bones, coordinates, bone_count: int) -> "SparseVectors":
        return cls(*cls.checked_with_values(offsets, bones, bone_count, coordinates, "coordinates", 4))

    @classmethod
    def rows(cls, model: InfluencePattern, vertices) -> "SparseVectors":
        """The given vertices' rows of an animation-space model (its p_v), one vector each."""
        if not isinstance(model, (AnimationSpaceModel, SparseVectors)):
            raise SkinkitError(f"model: expected an AnimationSpaceModel, got {type(model).__name__}")
        vertices = as_index_array(vertices, "vertices", (None,))
        if len(vertices) and not (0 <= vertices.min() and vertices.max() < model.vertex_count):
            raise SkinkitError(f"vertices: indices must be in [0, {model.vertex_count})")
        counts = model.counts()[vertices]
        check_vector_rows(int(counts.sum()))
        offsets = np.zeros(len(vertices) + 1, np.int32)
        np.cumsum(counts, out=offsets[1:])
        entries = np.repeat(model.offsets[vertices] - offsets[:-1], counts) + np.arange(offsets[-1])
        return cls(offsets, model.bones[entries], np.ascontiguousarray(model.coordinates[entries]))

    @classmethod
    def at_root(cls, vector, count: int) -> "SparseVectors":
        """`count` copies of one 4-vector on the root (bone 0): a fixed point or direction in model space."""
        vector = as_real_array(vector, "vector", shape=(4,))
        as_count(count, "count")
        check_memory(count * 44, f"{count} vectors", "ask for fewer")
        return cls(np.arange(count + 1, dtype=np.int32), np.zeros(count, np.int32),
                   np.tile(np.asarray(vector, dtype=np.float64), (count, 1)))

    @checked(other=lambda value, name: as_vectors(value, name), sign=real())
    def combined(self, other: "SparseVectors", sign: float) -> "SparseVectors":
        """s_i + sign * t_i for each i, as the entries of both (a bone may appear twice: the norms are bilinear)."""
        if other.vertex_count != self.vertex_count:
            raise SkinkitError(f"{self.vertex_count} vectors cannot pair with {other.vertex_count}")
        check_combined_vectors(self.influence_count + other.influence_count)
        first_counts, second_counts = self.counts(), other.counts()
        offsets = np.zeros(len(first_counts) + 1, np.int32)
        np.cumsum(first_counts + second_counts, out=offsets[1:])
        # Each vector's entries are this one's, then the other's, in their own order: every entry's place follows from
        # its vector's offsets, written in place (a stable sort of both by vector gave the same order with 1.7x the
        # memory above the inputs: 76 against 45 bytes an entry on the 3M edges of a 1M-vertex character)
        first_at = np.repeat(offsets[:-1] - self.offsets[:-1], first_counts) + np.arange(self.influence_count)
        second_at = np.repeat(offsets[:-1] + first_counts - other.offsets[:-1], second_counts) + \
            np.arange(other.influence_count)
        bones = np.empty(offsets[-1], np.int32)
        bones[first_at], bones[second_at] = self.bones, other.bones
        coordinates = np.empty((offsets[-1], 4))
        coordinates[first_at] = self.coordinates
        for begin in range(0, len(second_at), COMBINE_CHUNK):
            end = begin + COMBINE_CHUNK
            coordinates[second_at[begin:end]] = sign * other.coordinates[begin:end]
        return SparseVectors(offsets, bones, coordinates)

    @classmethod
    def from_dense(cls, dense) -> "SparseVectors":
        """From (n, b, 4) vectors, keeping the bones with a non-zero 4-vector."""
        dense = as_real_array(dense, "vectors", shape=(None, None, 4))
        rows, bones = np.nonzero(np.any(dense != 0, axis=2))
        offsets = np.zeros(len(dense) + 1, np.int32)
        np.cumsum(np.bincount(rows, minlength=len(dense)), out=offsets[1:])
        return cls.create(offsets, bones, dense[rows, bones], dense.shape[1])


def as_vectors(value, name: str) -> "SparseVectors":
    if not isinstance(value, SparseVectors):
        raise SkinkitError(f"{name}: expected SparseVectors, got {type(value).__name__}")
    return value


@checked(pixels=real(minimum=0), distance=real(minimum=0), field_of_view=real(above=0, maximum=np.pi / 2),
         width=real(above=0))
def pixel_tolerance(pixels: float, distance: float, field_of_view: float, width: float) -> float:
    """The model-space error that projects to `pixels` pixels at `distance` (eq. 7.2: 2 p d sin(θ) / w),
    for a view `width` pixels wide with half field of view `field_of_view` radians."""
    return 2 * pixels * distance * np.sin(field_of_view) / width


#: spread_rotations' turns per sample: +-spread about each of a joint's three axes.
SPREAD_TURNS = 6


def spread_rotations(local: np.ndarray, spread: float) -> np.ndarray:
    """The samples (S, b, 4, 4) followed by six copies in which every joint's rotation is turned by +spread or
    -spread about one of its own x, y and z axes (translations kept, so the max-distance bounds are unchanged).
    Why: a metric from a few example poses prices at zero any change that none of them shows, so a collapse or
    an influence removal can be free in the examples and visible in the first new pose (on libigl's cow, 6
    example poses: 0.2 rad lowered the LOD chain's held-out error 1.5-3.3x; BENCHMARKS.md). The six turns are a
    symmetric rule (its mean rotation is isotropic) and deterministic, unlike random draws."""
    copies = [local]
    for axis in range(3):
        for sign in (1.0, -1.0):
            turn = axis_rotation(axis, sign * spread)
            turned = local.copy()
            turned[:, 1:, :3, :3] = local[:, 1:, :3, :3] @ turn
            copies.append(turned)
    return np.concatenate(copies)


def axis_rotation(axis: int, angle: float) -> np.ndarray:
    """The 3x3 rotation by `angle` about coordinate axis `axis` (0: x, 1: y, 2: z)."""
    first, second = [(1, 2), (2, 0), (0, 1)][axis]
    rotation = np.eye(3)
    rotation[first, first] = rotation[second, second] = np.cos(angle)
    rotation[first, second], rotation[second, first] = -np.sin(angle), np.sin(angle)
    return rotation


def checked_joints(parents, translations):
    parents = as_index_array(parents, "parents", (None,))
    translations = as_real_array(translations, "translations", shape=(len(parents), 3))
    _core.validate_skeleton(parents, None)
    return parents, translations


def rotation_law(joint: int, model: tuple):
    """(E[R], A -> E[R^T A R]) for one joint's rotation model."""
    if not isinstance(model, (tuple, list)) or not model or not isinstance(model[0], str):
        raise SkinkitError(f"models: bone {joint}'s model must be a tuple such as ('uniform',), got {model!r:.60}")
    kind = model[0]
    if kind == "euler":
        return euler_law(joint, model[1])
    if kind == "uniform":
        return np.zeros((3, 3)), lambda a: np.trace(a) / 3 * np.eye(3)
    if kind == "fixed":
        return np.eye(3), lambda a: a
    if kind != "range":
        raise SkinkitError(f"bone {joint}: unknown rotation model {kind!r}")
    if len(model) != 4:
        raise SkinkitError(f"models: bone {joint}'s range must be ('range', axis, first, last), got {model!r:.60}")
    axis = as_real_array(model[1], f"bone {joint}'s axis", shape=(3,))
    first, last = (as_real(angle, f"bone {joint}'s angle range", -1e6, 1e6) for angle in model[2:])
    if not np.linalg.norm(axis) > 0:
        raise SkinkitError(f"axes: bone {joint} has a zero axis")
    if last < first:
        raise SkinkitError(f"ranges: bone {joint} ends before it starts")
    terms = rotation_basis(axis / np.linalg.norm(axis))
    m = angle_moments(first, last)
    weights = {(0, 0): 1, (0, 1): m["c"], (0, 2): m["s"], (1, 1): m["cc"], (1, 2): m["cs"], (2, 2): m["ss"]}

    def second_moment(a):
        total = np.zeros((3, 3))
        for (i, n), weight in weights.items():
            pair = terms[i].T @ a @ terms[n]
            total += weight * (pair if i == n else pair + terms[n].T @ a @ terms[i])
        return total

    return terms[0] + m["c"] * terms[1] + m["s"] * terms[2], second_moment


def euler_law(joint: int, axis_ranges) -> tuple:
    """Euler angles, independent and uniform over their ranges: R = R_n ... R_2 R_1 for the (axis, first,
    last) in application order (Blender's XYZ mode applies X first: R = Rz Ry Rx). Independence gives
    E[R] = E[R_n] ... E[R_1] and E[R^T A R] = S_1(S_2(... S_n(A))), S_i(A) = E[R_i^T A R_i]."""
    if not isinstance(axis_ranges, (list, tuple)) or not all(isinstance(a, (list, tuple)) for a in axis_ranges):
        raise SkinkitError(f"models: bone {joint}'s Euler model needs a list of (axis, first, last)")
    laws = [rotation_law(joint, ("range",) + tuple(axis_range)) for axis_range in axis_ranges]
    mean = np.eye(3)
    for axis_mean, _ in laws:
        mean = axis_mean @ mean

    def second_moment(a):
        for _, moment in reversed(laws):
            a = moment(a)
        return a

    return mean, second_moment


def rotation_basis(axis: np.ndarray):
    """R(θ) = P + cos θ Q + sin θ K about `axis`: the projection on it, its complement and its cross matrix."""
    projection = np.outer(axis, axis)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return projection, np.eye(3) - projection, cross


def angle_moments(first: float, last: float) -> dict:
    """E[cos], E[sin], E[cos^2], E[sin^2], E[cos sin] for an angle uniform on [first, last]."""
    width = last - first
    if width < 1e-12:
        c, s = np.cos(first), np.sin(first)
        return {"c": c, "s": s, "cc": c * c, "ss": s * s, "cs": c * s}
    c = (np.sin(last) - np.sin(first)) / width
    s = (np.cos(first) - np.cos(last)) / width
    cc = 0.5 + (np.sin(2 * last) - np.sin(2 * first)) / (4 * width)
    cs = (np.sin(last) ** 2 - np.sin(first) ** 2) / (2 * width)
    return {"c": c, "s": s, "cc": cc, "ss": 1.0 - cc, "cs": cs}


def analytic(parents, translations, rotation_mean, rotation_second_moment) -> PoseStatistics:
    """Statistics of independent joints L_j = [R_j t_j; 0 1] with fixed t_j, parents first:
    E[G_j^T G_j] = E[L_j^T E[G_p^T G_p] L_j], whose linear block needs E[R^T A R] (rotation_second_moment)."""
    b = len(parents)
    expected_local = np.tile(np.eye(4), (b, 1, 1))
    expected_local[:, :3, :3] = rotation_mean
    expected_local[:, :3, 3] = translations
    expected_local[0] = np.eye(4)
    gram = np.tile(np.eye(4), (b, 1, 1))
    depth = np.array([depth_of(parents, j) for j in range(b)])
    for joint in sorted(range(1, b), key=lambda j: depth[j]):
        x = gram[parents[joint]]
        linear, column, corner, t = x[:3, :3], x[:3, 3], x[3, 3], translations[joint]
        cross = rotation_mean[joint].T @ (linear @ t + column)
        gram[joint][:3, :3] = rotation_second_moment(joint, linear)
        gram[joint][:3, 3] = cross
        gram[joint][3, :3] = cross
        gram[joint][3, 3] = t @ linear @ t + 2 * column @ t + corner
    radius = np.zeros(b)
    return PoseStatistics(parents, expected_local, gram, np.ones(b), translations.copy(), radius)


def depth_of(parents, joint: int) -> int:
    depth = 0
    while joint != 0:
        joint = int(parents[joint])
        depth += 1
    return depth
