"""Limit Influences (Merry 2007, section 6.4): every vertex reduced to at most K influences by the cheapest removals,
each with the correction of least L2,2 norm (eq. 6.1), over the C core's `limit_influences`.

Also the two linear-blend counterparts the bridge and the benchmark compare it with: Blender's Limit Total (drop
the smallest weights; the Armature modifier renormalises) and the nearest linear-blend weights of a limited model.
"""
from __future__ import annotations

import numpy as np

from .. import _core, _memory
from .._blas import one_blas_thread
from .._checks import CALLBACK, FLAG, THREADS, as_count, as_real_array, checked
from ..metrics import PoseStatistics, SparseVectors
from ..model import AnimationSpaceModel, InfluencePattern, Skeleton, SkinkitError, SparseWeights, convert_lbs

__all__ = ["limit_influences", "limit_total", "nearest_linear_blend", "sampled_metric", "choose_sample_weight"]

#: The share of the sampled metric that choose_sample_weight tries (0: the joint statistics' P alone).
SAMPLE_WEIGHTS = (0.0, 0.25, 0.5, 0.75, 1.0)
#: Validation folds of choose_sample_weight (fewer when there are fewer poses).
VALIDATION_FOLDS = 5


def checked_max_influences(max_influences) -> int:
    if isinstance(max_influences, bool) or not isinstance(max_influences, (int, np.integer)):
        raise SkinkitError(f"max_influences: expected a whole number, got {max_influences!r}")
    return as_count(max_influences, "max_influences", minimum=1)


def checked_statistics(model: AnimationSpaceModel, statistics) -> PoseStatistics:
    if not isinstance(statistics, PoseStatistics):
        raise SkinkitError(f"statistics: expected a skinkit.metrics.PoseStatistics, got {type(statistics).__name__}")
    if statistics.bone_count != model.bone_count:
        raise SkinkitError(f"statistics: {statistics.bone_count} bones, the model has {model.bone_count}")
    return statistics


def as_tangents(value, name: str) -> tuple:
    """A sequence of tangent models (checked against the model's pattern in limit_influences)."""
    if isinstance(value, (str, bytes, dict, np.ndarray)) or not hasattr(value, "__iter__"):
        raise SkinkitError(f"{name}: expected a sequence of AnimationSpaceModels, got {type(value).__name__}")
    return tuple(value)


def as_pose_samples(value, name: str = "poses") -> np.ndarray:
    poses = as_real_array(value, name, shape=(None, None, 4, 4))
    if len(poses) == 0:
        raise SkinkitError(f"{name}: at least one pose is needed")
    return poses


def as_sample_weight(value, name: str = "sample_weight"):
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not 0 <= value <= 1:
        raise SkinkitError(f"{name}: expected a number in [0, 1] or None, got {value!r}")
    return float(value)


def sampled_metric(poses) -> np.ndarray:
    """P's blocks (b, b, 4, 4) as the sample second moments P_jk = mean over the poses of G_j^T G_k, poses
    (S, b, 4, 4) the bone frames G_j: the L2,2 norm in this metric is exactly the RMS distance over those poses
    (the least-squares fit to them), where PoseStatistics' P multiplies per-joint expectations as if the joints
    moved independently."""
    poses = as_pose_samples(poses)
    return np.einsum("sjab,skac->jkbc", poses, poses) / len(poses)


def statistics_metric(statistics: PoseStatistics) -> np.ndarray:
    """The joint statistics' P as blocks (b, b, 4, 4)."""
    b = statistics.bone_count
    return statistics.matrix().reshape(b, 4, b, 4).transpose(0, 2, 1, 3)


def blended_metric(statistics: PoseStatistics, poses: np.ndarray, sample_weight: float) -> np.ndarray:
    blocks = statistics_metric(statistics)
    if sample_weight == 0:
        return blocks
    return (1 - sample_weight) * blocks + sample_weight * sampled_metric(poses)


@checked(poses=as_pose_samples, threads=THREADS)
def choose_sample_weight(model: AnimationSpaceModel, parents, poses, max_influences: int, *,
                         threads: int = 0) -> tuple[float, dict]:
    """(sample weight, validation errors): the share w of the sampled metric in (1 - w) P_statistics + w P_sampled
    (limit_influences' poses) that generalises best, by cross-validation on `poses` alone: the poses are dealt into
    up to VALIDATION_FOLDS interleaved folds; for each fold, both metrics are formed from the other poses, the model
    limited, and the RMS distance to the unlimited model measured in the fold's poses. Errors: w -> that RMS over
    every fold. One pose cannot be validated: w is then 0 (the statistics alone)."""
    if not isinstance(model, AnimationSpaceModel):
        raise SkinkitError(f"model: expected a skinkit.AnimationSpaceModel, got {type(model).__name__}")
    max_influences = checked_max_influences(max_influences)
    if poses.shape[1] != model.bone_count:
        raise SkinkitError(f"poses: {poses.shape[1]} bones, the model has {model.bone_count}")
    folds = min(VALIDATION_FOLDS, len(poses))
    if folds < 2:
        return 0.0, {}
    errors = {}
    for weight in SAMPLE_WEIGHTS:
        squared = 0.0
        for fold in range(folds):
            held = np.arange(fold, len(poses), folds)
            kept = np.setdiff1d(np.arange(len(poses)), held)
            statistics = PoseStatistics.from_world_samples(parents, poses[kept])
            limited, _ = limit_in_metric(model, blended_metric(statistics, poses[kept], weight), max_influences,
                                         threads=threads)
            difference = limited.evaluate(poses[held], threads=threads) - model.evaluate(poses[held], threads=threads)
            squared += float(np.sum(difference ** 2))
        errors[weight] = float(np.sqrt(squared / (len(poses) * model.vertex_count)))
    return min(errors, key=lambda w: (errors[w], w)), errors


def limit_in_metric(model: AnimationSpaceModel, metric, max_influences: int, *, tangents=(),
                    threads: int = 0, progress=None, largest_weights: bool = True):
    """limit_influences in the metric of a PoseStatistics or of P's blocks (b, b, 4, 4)."""
    count = model.influence_count
    offsets = np.empty(model.vertex_count + 1, np.int32)
    bones = np.empty(count, np.int32)
    coordinates = np.empty((count, 4))
    costs = np.empty(model.vertex_count)
    stacked = np.ascontiguousarray(np.stack([t.coordinates for t in tangents])) if tangents else None
    limited_tangents = np.empty((len(tangents), count, 4)) if tangents else None
    arrays = (offsets, bones, coordinates.reshape(-1), costs,
              None if limited_tangents is None else limited_tangents.reshape(-1), model.offsets, model.bones,
              np.ascontiguousarray(model.coordinates).reshape(-1), None if stacked is None else stacked.reshape(-1),
              len(tangents))
    with one_blas_thread():  # the core's LAPACK solves, like the projection's: the same bits whatever BLAS's threads
        if isinstance(metric, PoseStatistics):
            result = _core.limit_influences(*arrays, np.ascontiguousarray(metric.expected_local).reshape(-1),
                                            np.ascontiguousarray(metric.expected_gram).reshape(-1), metric.parents,
                                            max_influences, threads, progress)
        else:
            result = _core.limit_influences_in_metric(*arrays, np.ascontiguousarray(metric).reshape(-1),
                                                      model.bone_count, max_influences, threads, progress)
    used = int(result["limited_count"])
    limited = AnimationSpaceModel(offsets, bones[:used].copy(), coordinates[:used].copy(), model.bone_count)
    if not tangents:
        if largest_weights:
            blocks = statistics_metric(metric) if isinstance(metric, PoseStatistics) else metric
            limited, costs = better_of(limited, costs, largest_weight_projection(model, blocks, max_influences))
        return limited, costs
    return limited, costs, tuple(AnimationSpaceModel(offsets, limited.bones, t[:used].copy(), model.bone_count)
                                 for t in limited_tangents)


@checked(tangents=as_tangents, threads=THREADS, progress=CALLBACK, largest_weights=FLAG, sample_weight=as_sample_weight)
def limit_influences(model: AnimationSpaceModel, statistics: PoseStatistics, max_influences: int, *, tangents=(),
                     threads: int = 0, progress=None, largest_weights: bool = True, poses=None,
                     sample_weight: float | None = None):
    """(limited model, costs): every vertex with more than max_influences influences loses, one at a time, the
    influence whose removal moves it least in the L2,2 norm of `statistics` (the RMS distance over the pose
    distribution), the others corrected optimally (eq. 6.1); the kept bones stay in their order.

    poses (S, b, 4, 4, optional): the sampled bone frames the statistics came from. Given, the metric is
    (1 - w) P_statistics + w P_sampled (sampled_metric: exactly the RMS over those poses, where the statistics
    treat the joints as independent); w = sample_weight, or when None the share choose_sample_weight validates
    on the poses themselves.

    costs (V,): the L2,2 norm of each vertex's total correction (0 for vertices already within the limit).
    largest_weights: the removals are greedy (the cheapest first, as in the thesis), which can end on a worse set
    than Blender's Limit Total keeps; with this on, a vertex whose max_influences largest-weight influences admit a
    cheaper optimal correction than the greedy result takes that one instead (positions only: not with tangents).
    tangents: AnimationSpaceModels of tangent vectors on the model's pattern (homogeneous weight 0); given, the
    result is (limited model, costs, limited tangents), the same removals applied to each (section 6.3).
    progress(fraction) may return True to cancel (SkinkitError).
    """
    if not isinstance(model, AnimationSpaceModel):
        raise SkinkitError(f"model: expected a skinkit.AnimationSpaceModel, got {type(model).__name__}")
    max_influences = checked_max_influences(max_influences)
    statistics = checked_statistics(model, statistics)
    given_tangents = tuple(tangents)
    counts = model.counts()
    _memory.check_limit_influences(model.vertex_count, model.influence_count, int((counts > max_influences).sum()),
                                   int(counts.max(initial=1)), largest_weights and not given_tangents)
    for index, tangent in enumerate(given_tangents):
        if not isinstance(tangent, AnimationSpaceModel) or not (
                np.array_equal(tangent.offsets, model.offsets) and np.array_equal(tangent.bones, model.bones)):
            raise SkinkitError(f"tangents[{index}]: expected an AnimationSpaceModel on the model's influence pattern")
    if poses is None:
        if sample_weight is not None:
            raise SkinkitError("sample_weight: needs the poses the sampled metric is formed from")
        metric = statistics
    else:
        poses = as_pose_samples(poses)
        if poses.shape[1] != model.bone_count:
            raise SkinkitError(f"poses: {poses.shape[1]} bones, the model has {model.bone_count}")
        if sample_weight is None:
            sample_weight, _ = choose_sample_weight(model, statistics.parents, poses, max_influences, threads=threads)
        metric = blended_metric(statistics, poses, sample_weight)
    return limit_in_metric(model, metric, max_influences, tangents=given_tangents, threads=threads,
                           progress=progress, largest_weights=largest_weights)


def limit_total(weights: SparseWeights, max_influences: int) -> SparseWeights:
    """Blender's Limit Total (`object.vertex_group_limit_total`): each vertex keeps its max_influences largest
    weights (ties: the earlier entry) and loses the others; the weights are then divided by their total, as the
    Armature modifier does when it deforms (a vertex whose kept total is at most 1e-4 stays at the root)."""
    if not isinstance(weights, SparseWeights):
        raise SkinkitError(f"weights: expected a skinkit.SparseWeights, got {type(weights).__name__}")
    max_influences = checked_max_influences(max_influences)
    counts = weights.counts()
    vertex = weights.vertex_of_each_influence()
    # Rank within each vertex by decreasing weight, stable (the earlier entry wins a tie).
    order = np.lexsort((np.arange(weights.influence_count), -weights.weights, vertex))
    rank = np.empty(weights.influence_count, np.int64)
    rank[order] = np.arange(weights.influence_count) - np.repeat(weights.offsets[:-1], counts)
    keep = rank < max_influences
    offsets = np.zeros(weights.vertex_count + 1, np.int32)
    np.cumsum(np.bincount(vertex[keep], minlength=weights.vertex_count), out=offsets[1:])
    return SparseWeights(offsets, weights.bones[keep].copy(), weights.weights[keep].copy()).normalized_like_blender()


def nearest_linear_blend(model: AnimationSpaceModel, statistics: PoseStatistics, rest_frames,
                         rest_positions, pattern: InfluencePattern | None = None) -> SparseWeights:
    """Linear-blend weights on `pattern` (default: the model's own influence pattern; each vertex's bones a subset
    of the model's) whose skinning of `rest_positions` (V, 3) is nearest the model in the L2,2 norm of
    `statistics`: per vertex, the weights w (summing to 1) minimising E|Σ_j w_j G_j Ĝ_j^-1 v̂ - Σ_k G_k p_k|², then
    negative weights dropped and the rest renormalised (Blender's vertex groups cannot hold negative weights).
    rest_frames (b, 4, 4) are the Ĝ_j."""
    if not isinstance(model, AnimationSpaceModel):
        raise SkinkitError(f"model: expected a skinkit.AnimationSpaceModel, got {type(model).__name__}")
    statistics = checked_statistics(model, statistics)
    rest_frames = as_real_array(rest_frames, "rest_frames", shape=(model.bone_count, 4, 4))
    rest_positions = as_real_array(rest_positions, "rest_positions", shape=(model.vertex_count, 3))
    pattern = model if pattern is None else checked_pattern(pattern, model)
    present, bones, _ = padded(pattern)
    model_present, model_bones, p = padded(model, model.coordinates)
    V, width = present.shape
    counts = pattern.counts()
    # q_j = Ĝ_j^-1 v̂: the linear-blend 4-vector of bone j with weight 1.
    inverse = inverted_rest_frames(rest_frames)
    homogeneous = np.column_stack([rest_positions, np.ones(V)])
    q = np.einsum("vkab,vb->vka", inverse[bones], homogeneous) * present[..., None]
    blocks = statistics.matrix().reshape(model.bone_count, 4, model.bone_count, 4).transpose(0, 2, 1, 3)
    gram = np.einsum("vaA,vabAB,vbB->vab", q, blocks[bones[:, :, None], bones[:, None, :]], q)
    target = np.einsum("vaA,vabAB,vbB->va", q, blocks[bones[:, :, None], model_bones[:, None, :]], p)
    # Minimise w^T gram w - 2 w^T target subject to Σ w = 1 (a KKT system per vertex), absent slots pinned to 0.
    scale = np.maximum(np.abs(gram).max(axis=(1, 2)), 1e-300)[:, None, None]
    system = np.zeros((V, width + 1, width + 1))
    system[:, :width, :width] = gram / scale + 1e-12 * np.eye(width)
    system[:, :width, width] = present
    system[:, width, :width] = present
    absent = ~present
    system[:, :width, :width][absent] = 0.0
    diagonal = system[:, np.arange(width), np.arange(width)]
    diagonal[absent] = 1.0
    system[:, np.arange(width), np.arange(width)] = diagonal
    right = np.zeros((V, width + 1))
    right[:, :width] = np.where(present, target / scale[:, 0], 0.0)
    right[:, width] = counts > 0
    system[:, width, width] = counts == 0  # a vertex with no bones: its (empty) row stays regular
    try:
        with one_blas_thread():  # the same bits whatever BLAS's thread count
            w = np.linalg.solve(system, right[..., None])[..., 0][:, :width]
    except np.linalg.LinAlgError:
        w = np.stack([np.linalg.lstsq(a, b, rcond=None)[0] for a, b in zip(system, right)])[:, :width]
    # Where the solve is not finite: the model's own homogeneous weights of the same bones.
    same_bone = (bones[:, :, None] == model_bones[:, None, :]) & model_present[:, None, :]
    model_weights = np.einsum("vam,vm->va", same_bone, p[..., 3])
    fallback = np.where(present, np.maximum(model_weights, 0.0), 0.0)
    w = np.where(np.isfinite(w).all(axis=1, keepdims=True), w, fallback)
    w = np.where(present, np.maximum(w, 0.0), 0.0)
    totals = w.sum(axis=1, keepdims=True)
    w = np.where(totals > 0, w / np.where(totals > 0, totals, 1.0), present / np.maximum(counts, 1)[:, None])
    vertex = pattern.vertex_of_each_influence()
    slot = np.arange(pattern.influence_count) - np.repeat(pattern.offsets[:-1], counts)
    return SparseWeights(pattern.offsets, pattern.bones, w[vertex, slot])


def checked_pattern(pattern, model: AnimationSpaceModel) -> InfluencePattern:
    """An influence pattern (SparseWeights and the models are ones) over the model's vertices and bones."""
    if not isinstance(pattern, InfluencePattern):
        raise SkinkitError(f"pattern: expected an influence pattern (skinkit.SparseWeights), got "
                           f"{type(pattern).__name__}")
    if pattern.vertex_count != model.vertex_count:
        raise SkinkitError(f"pattern: {pattern.vertex_count} vertices, the model has {model.vertex_count}")
    if len(pattern.bones) and int(pattern.bones.max()) >= model.bone_count:
        raise SkinkitError(f"pattern: bone {int(pattern.bones.max())} out of range for the model's {model.bone_count}")
    return pattern


def inverted_rest_frames(rest_frames: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.inv(rest_frames)
    except np.linalg.LinAlgError:
        singular = [j for j, frame in enumerate(rest_frames) if np.linalg.matrix_rank(frame) < 4]
        raise SkinkitError(f"rest_frames: bone {singular[0] if singular else '?'}'s frame is singular") from None


def largest_weight_pattern(model: AnimationSpaceModel, max_influences: int) -> InfluencePattern:
    """Each vertex's at most max_influences bones of largest homogeneous weight (p_j's 4th component), the root
    (bone 0, which has no vertex group) left out; in the model's slot order."""
    present, bones, p = padded(model, model.coordinates)
    weight = np.where(present & (bones > 0), p[..., 3], -np.inf)
    order = np.argsort(-weight, axis=1, kind="stable")
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.arange(present.shape[1])[None].repeat(len(present), 0), axis=1)
    keep = present & (bones > 0) & (rank < max_influences)
    offsets = np.zeros(model.vertex_count + 1, np.int32)
    np.cumsum(keep.sum(axis=1), out=offsets[1:])
    return InfluencePattern(offsets, bones[keep].astype(np.int32))


def limited_linear_blend(model: AnimationSpaceModel, statistics: PoseStatistics, rest_frames, rest_positions,
                         max_influences: int) -> tuple[SparseWeights, np.ndarray]:
    """(weights, distances): the nearest linear-blend weights on each vertex's max_influences bones of largest
    homogeneous weight (the root left out), and each vertex's L2,2 distance between that linear blend skinning and
    the model: how far Blender's Armature modifier playing the weights may stray from the model."""
    weights = nearest_linear_blend(model, statistics, rest_frames, rest_positions,
                                   largest_weight_pattern(model, checked_max_influences(max_influences)))
    skeleton = Skeleton.create(statistics.parents, rest_frames)
    linear = convert_lbs(skeleton, weights, rest_positions)
    b = model.bone_count
    difference = SparseVectors.create(model.offsets, model.bones, model.coordinates, b).combined(
        SparseVectors.create(linear.offsets, linear.bones, linear.coordinates, b), -1.0)
    return weights, statistics.mean_distance(difference)


# ---- the largest-weight set, corrected optimally ---------------------------------------------------------------


def padded(pattern, values=None):
    """(present (V, w), bones (V, w), values (V, w, ...)): the CSR rows as padded slots."""
    counts = pattern.counts()
    width = max(int(counts.max(initial=0)), 1)
    vertex = pattern.vertex_of_each_influence()
    slot = np.arange(pattern.influence_count) - np.repeat(pattern.offsets[:-1], counts)
    present = np.zeros((pattern.vertex_count, width), bool)
    present[vertex, slot] = True
    bones = np.zeros((pattern.vertex_count, width), np.int64)
    bones[vertex, slot] = pattern.bones
    if values is None:
        return present, bones, None
    out = np.zeros((pattern.vertex_count, width) + values.shape[1:])
    out[vertex, slot] = values
    return present, bones, out


def padded_rows(pattern, rows: np.ndarray, values: np.ndarray):
    """(present (R, w), bones (R, w), values (R, w, ...)) of the given vertices' CSR rows as padded slots, w the
    widest row of the whole pattern (so each row's system has the same size whichever rows are taken)."""
    counts = pattern.counts()
    width = max(int(counts.max(initial=0)), 1)
    present = np.arange(width)[None, :] < counts[rows, None]
    index = np.where(present, pattern.offsets[rows, None] + np.arange(width)[None, :], 0)
    bones = np.where(present, pattern.bones[index], 0).astype(np.int64)
    out = np.where(present.reshape(present.shape + (1,) * (values.ndim - 1)), values[index], 0.0)
    return present, bones, out


def projection_corrections(blocks: np.ndarray, present, bones, p, keep) -> tuple[np.ndarray, np.ndarray]:
    """(corrections (R, n), costs (R,)) of rows whose kept slots take the correction of least L2,2 norm, n = 4w:
    each row's (n + 1)-square KKT system (eq. 6.1 with the weights' total kept) formed and solved on its own."""
    rows, width = present.shape
    n = 4 * width
    full = blocks[bones[:, :, None], bones[:, None, :]].transpose(0, 1, 3, 2, 4).reshape(rows, n, n)
    full *= np.repeat(present, 4, axis=1)[:, :, None] * np.repeat(present, 4, axis=1)[:, None, :]
    free = np.repeat(keep, 4, axis=1)  # (R, n) the kept slots' coordinates move
    fixed = np.where(free, 0.0, -p.reshape(rows, n) * np.repeat(present, 4, axis=1))
    is_weight = np.tile(np.array([0, 0, 0, 1.0]), width)
    scale = np.maximum(np.abs(full).max(axis=(1, 2)), 1e-300)[:, None, None]
    system = np.zeros((rows, n + 1, n + 1))
    system[:, :n, :n] = np.where(free[:, :, None] & free[:, None, :], full / scale, 0.0)
    system[:, np.arange(n), np.arange(n)] += np.where(free, 1e-10, 1.0)
    system[:, :n, n] = free * is_weight
    system[:, n, :n] = free * is_weight
    right = np.zeros((rows, n + 1))
    right[:, :n] = -np.einsum("rab,rb->ra", full / scale, fixed) * free
    right[:, n] = -(fixed * is_weight).sum(axis=1)
    solved = np.linalg.solve(system, right[..., None])[..., 0][:, :n]
    correction = np.where(free, solved, fixed)
    costs = np.sqrt(np.maximum(np.einsum("ra,rab,rb->r", correction, full, correction), 0.0))
    return correction, costs


def largest_weight_projection(model: AnimationSpaceModel, blocks: np.ndarray, max_influences: int,
                              chunk_rows: int | None = None):
    """(rows, model of those rows, costs (R,)): each vertex above the limit (rows, ascending) keeps its
    max_influences influences of largest homogeneous weight (Limit Total's choice) with the correction of least
    L2,2 norm (eq. 6.1, the weights' total kept; a tiny ridge picks among equally cheap corrections, as the
    thesis' least Euclidean norm does). The dense systems are formed chunk_rows rows at a time (by default as many
    as fit _memory.PROJECTION_CHUNK_BYTES), so memory grows with the influences, not with rows x (4w)^2."""
    rows = np.flatnonzero(model.counts() > max_influences)
    present, bones, p = padded_rows(model, rows, model.coordinates)
    width = present.shape[1]
    weight = np.where(present, p[..., 3], -np.inf)
    order = np.argsort(-weight, axis=1, kind="stable")
    rank = np.empty_like(order)
    np.put_along_axis(rank, order, np.arange(width)[None].repeat(len(rows), 0), axis=1)
    keep = present & (rank < max_influences)
    if chunk_rows is None:
        chunk_rows = _memory.projection_chunk_rows(width)
    correction = np.empty((len(rows), 4 * width))
    costs = np.empty(len(rows))
    with one_blas_thread():  # the same bits whatever BLAS's thread count
        for begin in range(0, len(rows), chunk_rows):
            part = slice(begin, begin + chunk_rows)
            correction[part], costs[part] = projection_corrections(blocks, present[part], bones[part], p[part],
                                                                   keep[part])
    corrected = p + correction.reshape(len(rows), width, 4)
    offsets = np.zeros(len(rows) + 1, np.int32)
    np.cumsum(keep.sum(axis=1), out=offsets[1:])
    return rows, AnimationSpaceModel(offsets, bones[keep].astype(np.int32), corrected[keep], model.bone_count), costs


def better_of(first: AnimationSpaceModel, first_costs, projection):
    """Per vertex, the first model, or the projection (rows, their model, their costs) where that costs less (the
    first on a tie)."""
    rows, second, second_costs = projection
    take = second_costs < first_costs[rows] * (1 - 1e-9)
    if not take.any():
        return first, first_costs
    taken = np.zeros(first.vertex_count, bool)
    taken[rows[take]] = True
    counts = first.counts()
    counts[rows[take]] = second.counts()[take]
    offsets = np.zeros(first.vertex_count + 1, np.int32)
    np.cumsum(counts, out=offsets[1:])
    from_first = ~np.repeat(taken, first.counts())
    from_second = np.repeat(take, second.counts())
    # Interleave by vertex: the kept entries of each, ordered by their vertex (stable keeps the slot order).
    vertex = np.concatenate([first.vertex_of_each_influence()[from_first],
                             rows[second.vertex_of_each_influence()[from_second]]])
    order = np.argsort(vertex, kind="stable")
    bones = np.concatenate([first.bones[from_first], second.bones[from_second]])[order]
    coordinates = np.concatenate([first.coordinates[from_first], second.coordinates[from_second]])[order]
    costs = first_costs.copy()
    costs[rows[take]] = second_costs[take]
    return AnimationSpaceModel(offsets, bones, coordinates, first.bone_count), costs
