"""Fitting skinning to example poses (Merry 2007, chapter 4), on numpy arrays.

Inputs: example meshes in correspondence, examples (E, V, 3), each with its bone frames poses
(E, b, 4, 4) (bone 0 the root, identity), and an influence set per vertex. The data are moved to a unit
box before solving and the model mapped back after (section 4.1.2), so λ and δ mean the same thing
whatever the scene's units.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import _core, _memory
from ._blas import blas_threads_for
from ._checks import (CALLBACK, FLAG, THREADS, as_index_array, as_instance, as_mask, as_real, as_real_array,
                      check_same_units, checked, choice, count, optional, real)
from .model import (AnimationSpaceModel, InfluencePattern, Mesh, Skeleton, SkinkitError, SparseWeights,
                    skinning_matrices)

#: The public API (what tests/fuzz/api_fuzz.py calls with hostile arguments); the rest are helpers.
__all__ = [
    "FitResult", "LsqrSettings", "fit_animation_space", "fit_lbs", "influences_from_weights",
    "influences_automatic", "rigid_explanation_error", "fit_errors", "model_errors", "worse_than_input_rig",
    "per_vertex_error", "vertex_normals", "mesh_edges"
]

#: Default regularisation, in the unit box and rest space. The thesis used λ = 0.02 (its figure of the
#: per-vertex fit) and δ = 0.005 (horse) to 0.02 (arm), pulling towards zero; that over-smooths (on the
#: creature fitted to dual-quaternion examples it was worse than linear blend skinning). skinkit's
#: operator and CLI pull λ towards the linear-blend fit instead, which makes the result robust across
#: λ = 1e-5 .. 1e-2 and never worse than linear blend skinning on training data; 1e-3 keeps some of that
#: pull for held-out poses. Measured in bench/bench_fit.py.
DEFAULT_LAMBDA = 1e-3
DEFAULT_DELTA = 1e-4
#: With validation on (the default of panel, CLI and API), the per-vertex λ is the one of DEFAULT_LAMBDA (or the
#: given one) times these factors with the lowest VALIDATION_FOLDS-fold cross-validated error on the training
#: examples (example e is predicted by the fit on all the others but those of its fold e % VALIDATION_FOLDS): one λ
#: cannot serve every character (on the synthetic horses 1e-3 lost to linear blend skinning on held-out poses). The
#: prior itself (the linear-blend fit, refitted without each fold) is a candidate too: when no λ predicts the
#: examples clearly better (VALIDATION_MARGIN), the fit falls back to the prior (report "fallback"); with few
#: examples animation space's 4x more unknowns per influence overfit, and linear blend skinning is the better model.
VALIDATION_FACTORS = (0.01, 0.1, 1.0, 10.0, 100.0, 1e4, 1e6)
VALIDATION_FOLDS = 4
#: The validation report's key of the prior's own error (what the fit falls back to).
PRIOR_CANDIDATE = "prior"
#: Animation space is kept only when its best cross-validated rms is below the prior's by more than this fraction:
#: with few examples the estimate is noisy. On the synthetic horses (11 examples) its 1.4 % and 1.7 % lead in
#: validation became a 0.5 % and 8 % loss on the held-out poses; where it truly helps (arm, creature, the Dem Bones
#: sample) its validation rms is 37 % to 75 % below the linear-blend fit's (bench/bench_fit.py).
VALIDATION_MARGIN = 0.05
#: The rest pose is an example the user always has: given rest_positions and rest_frames, it joins the examples
#: with this many times the weight of all of them together, so the fitted model reproduces the bind pose.
REST_POSE_WEIGHT = 1e3
#: The fits: each vertex on its own (eq. 4.3, regularised by λ) or all together (eq. 4.4, by δ).
FIT_METHODS = ("per-vertex", "global")
#: Where influence sets come from: the rig's weights grown by some rings of neighbours, painted influence maps, or
#: the bones whose motion best explains each vertex (influences_from_weights, influences_automatic).
INFLUENCE_SOURCES = ("rig", "painted", "automatic")
DEFAULT_RINGS = 1
DEFAULT_MAX_INFLUENCES = 4
#: An edge is "scrambled" when its length changes by more than this factor from the rest mesh.
ORDER_MISMATCH_FACTOR = 3.0
#: What to do when the examples and the rest mesh disagree in units (the sentence is _checks.units_sentence's).
UNITS_REMEDY = "scale one to the other's units (import the FBX at 0.01 or 100, or give the CLI's --sequence-scale)"


@dataclass(frozen=True)
class LsqrSettings:
    atol: float = 1e-8
    btol: float = 1e-8
    conlim: float = 1e10
    iteration_limit: int = 20000
    precondition: bool = True

    def as_tuple(self) -> tuple:
        return (self.atol, self.btol, self.conlim, self.iteration_limit, self.precondition)


@dataclass
class FitResult:
    """A fitted model and how the solve went (iterations and residuals are the global fit's LSQR)."""

    model: AnimationSpaceModel
    method: str
    seconds: float
    report: dict = field(default_factory=dict)


# ---- data checks and normalisation ------------------------------------------------------------------

def checked_examples(poses, examples, vertex_count: int, bone_count: int) -> tuple[np.ndarray, np.ndarray]:
    examples = as_real_array(examples, "examples", shape=(None, None, 3))
    if examples.shape[1] != vertex_count:
        raise SkinkitError(f"examples: {examples.shape[1]} vertices per example, the mesh has {vertex_count}")
    poses = as_real_array(poses, "poses", shape=(len(examples), bone_count, 4, 4))
    if len(examples) == 0:
        raise SkinkitError("examples: at least one example is needed")
    return poses, examples


#: Edges measured at a time by the vertex-order check and the global fit's mean edge lengths: gathering both ends of
#: every edge in 16 frames at once, (frames, edges, 3) three times, was the decomposition's peak (3.5 GB of a 4.7 GB
#: peak at 1M vertices). Edges are independent: the same lengths in any chunking.
EDGE_CHUNK = 2**15


def chunks(count: int, size: int) -> list[slice]:
    """Consecutive slices of at most size items covering range(count)."""
    return [slice(begin, begin + size) for begin in range(0, count, size)]


def edge_length(points: np.ndarray, first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """(..., edges): the distance between points[..., first] and points[..., second], for points (..., V, 3)."""
    return np.linalg.norm(points[..., first, :] - points[..., second, :], axis=-1)


def check_vertex_order(rest_positions: np.ndarray, examples: np.ndarray, triangles: np.ndarray) -> None:
    """Refuses examples at another scale than the rest mesh (different units), or whose vertex order
    differs from it (their edges change length wildly)."""
    check_same_units(rest_positions, examples, "example {index}", "the rest mesh", UNITS_REMEDY)
    edges = mesh_edges(triangles)
    if len(edges) == 0:
        return
    rest_length = edge_length(rest_positions, edges[:, 0], edges[:, 1])
    usable = rest_length > 1e-12 * max(rest_length.max(), 1e-300)
    first, second, rest_length = edges[usable, 0], edges[usable, 1], rest_length[usable]
    for index, example in enumerate(examples):
        length = np.concatenate([edge_length(example, first[part], second[part])
                                 for part in chunks(len(first), EDGE_CHUNK)])
        change = np.maximum(length, 1e-300) / rest_length
        factor = np.median(np.maximum(change, 1.0 / change))
        if factor > ORDER_MISMATCH_FACTOR:
            raise SkinkitError(f"example {index}: its vertex order does not match the rest mesh (edges change "
                               f"length {factor:.1f}x on median)")


def check_determined(influences: InfluencePattern, example_count: int) -> None:
    """Each vertex has 4n - 1 unknowns; E examples give 3E equations."""
    most = int(influences.counts().max(initial=0))
    if 3 * example_count < 4 * most - 1:
        vertex = int(np.argmax(influences.counts()))
        raise SkinkitError(f"vertex {vertex} has {most} influences ({4 * most - 1} unknowns) but {example_count} "
                           f"examples give only {3 * example_count} equations: add examples or lower the maximum "
                           f"influences to {max((3 * example_count + 1) // 4, 1)}")


def check_bones_move(poses: np.ndarray, influences: InfluencePattern, names=None) -> None:
    """A bone (other than the root) whose frame is the same in every example cannot be told apart."""
    used = np.unique(influences.bones)
    spread = np.abs(poses - poses[:1]).max(axis=(0, 2, 3))
    scale = max(float(np.abs(poses[:, :, :3, 3]).max()), 1.0)
    still = [int(j) for j in used if j != 0 and spread[j] <= 1e-12 * scale]
    if still and len(poses) > 1:
        label = [names[j] if names else j for j in still]
        raise SkinkitError(f"bones {label} do not move in any example, so the examples cannot determine their "
                           "influence: pose them differently in some examples or drop them from the influence sets")


def check_influences(influences: InfluencePattern) -> None:
    empty = np.flatnonzero(influences.counts() == 0)
    if len(empty):
        raise SkinkitError(f"vertex {int(empty[0])} has an empty influence set ({len(empty)} vertices do)")


def unit_box(reference_positions: np.ndarray) -> np.ndarray:
    """T: the reference's bounding box to maximum side 1, centred at the origin (section 4.1.2)."""
    low, high = reference_positions.min(axis=0), reference_positions.max(axis=0)
    side = float((high - low).max())
    scale = 1.0 / side if side > 0 else 1.0
    transform = np.eye(4) * scale
    transform[3, 3] = 1.0
    transform[:3, 3] = -scale * (low + high) / 2
    return transform


def to_box(transform, poses, examples):
    """Poses T G T^-1 and examples T v: the same animation, measured in the box."""
    inverse = np.linalg.inv(transform)
    boxed_poses = np.ascontiguousarray(transform @ poses @ inverse)
    boxed_examples = np.ascontiguousarray(examples * transform[0, 0])
    boxed_examples += transform[:3, 3]  # in place: one (E, V, 3) temporary, not two
    return boxed_poses, boxed_examples


def from_box(transform, coordinates):
    """p = T^-1 p' for every influence, so that G p reproduces the unboxed examples."""
    return coordinates @ np.linalg.inv(transform).T


# ---- the fits ---------------------------------------------------------------------------------------

def as_names(value, name: str):
    if not isinstance(value, (list, tuple)) or not all(isinstance(item, str) for item in value):
        raise SkinkitError(f"{name}: expected a list of bone names (strings)")
    return tuple(value)


def as_triangles(triangles, vertex_count: int, name: str = "triangles") -> np.ndarray:
    """(T, 3) int32 corners, each a vertex of the vertex_count."""
    triangles = as_index_array(triangles, name, (None, 3))
    if triangles.size and (triangles.min() < 0 or triangles.max() >= vertex_count):
        raise SkinkitError(f"{name}: corners must be vertices 0 to {vertex_count - 1}, got "
                           f"{int(triangles.min())} to {int(triangles.max())}")
    return triangles


@checked(influences=InfluencePattern, bone_count=count(1), method=choice(FIT_METHODS),
         regularisation=optional(real(minimum=0)), prior=optional(AnimationSpaceModel), settings=LsqrSettings,
         threads=THREADS, progress=CALLBACK, bone_names=optional(as_names), check_order=FLAG, validate=FLAG,
         reproduce_rest=FLAG)
def fit_animation_space(poses, examples, influences: InfluencePattern, bone_count: int, *, method=FIT_METHODS[0],
                        regularisation: float | None = None, triangles=None, rest_positions=None, rest_frames=None,
                        prior: AnimationSpaceModel | None = None, settings: LsqrSettings = LsqrSettings(),
                        threads: int = 0, progress=None, bone_names=None, check_order: bool = True,
                        validate: bool = True, reproduce_rest: bool = True) -> FitResult:
    """Fits an animation-space model with the given influence sets.

    method "per-vertex" (eq. 4.3, regularisation = λ) or "global" (eq. 4.4, regularisation = δ, needs the
    triangles for the edges; starts from the per-vertex fit); see DEFAULT_LAMBDA and DEFAULT_DELTA.
    rest_frames (b, 4, 4), when given, makes the fit work on q_j = Ĝ_j p_j (rest-pose model space) so the
    regularisers do not depend on how the bones' frames are scaled (an armature imported at 0.01 scale
    would otherwise regularise 10^4 times harder). prior (an animation-space model on the same influence
    sets, e.g. linear blend skinning converted) is what λ pulls towards instead of zero, so strong
    regularisation falls back to it. rest_positions (default: the first example) sets the unit box and is
    used to check the vertex order when triangles are given (check_order=False skips that for synthetic
    data whose neighbours do not move alike). progress(fraction) may return True to cancel the global fit.
    With reproduce_rest, rest_positions and rest_frames (the mesh at the rig's rest frames), the rest pose is a
    heavily weighted example (REST_POSE_WEIGHT), so the model keeps the user's bind pose.
    validate chooses the per-vertex λ (also the global fit's start) by cross-validation on the training examples
    (VALIDATION_FACTORS, VALIDATION_FOLDS); the report then holds the chosen λ and each candidate's validation
    rms. When no λ predicts the examples better than the prior by more than VALIDATION_MARGIN, both methods
    return the prior (report "fallback": True, "lambda": None).
    """
    started = time.perf_counter()
    _core.validate_influences(influences.offsets, influences.bones, bone_count)
    if prior is not None and (prior.influence_count != influences.influence_count or
                              not np.array_equal(prior.bones, influences.bones)):
        raise SkinkitError("prior: its influence sets are not the influences' (fit the prior on the same ones)")
    if bone_names is not None and len(bone_names) != bone_count:
        raise SkinkitError(f"bone_names: {len(bone_names)} names for {bone_count} bones")
    poses, examples = checked_examples(poses, examples, influences.vertex_count, bone_count)
    _memory.check_fit_animation_space(method, influences.vertex_count, influences.influence_count, len(examples),
                                      _memory.row_count(triangles), validate)
    reference = examples[0] if rest_positions is None else as_real_array(rest_positions, "rest_positions",
                                                                          shape=examples.shape[1:])
    check_influences(influences)
    check_determined(influences, len(examples))
    check_bones_move(poses, influences, bone_names)
    if triangles is not None and check_order:
        check_vertex_order(reference, examples, Mesh.create(reference, triangles).triangles)
    frames = np.eye(4)[None].repeat(bone_count, 0) if rest_frames is None else \
        as_real_array(rest_frames, "rest_frames", shape=(bone_count, 4, 4))
    singular = np.flatnonzero(np.linalg.matrix_rank(frames) < 4)
    if len(singular):  # found by make fuzz-sanitized: np.linalg.inv below raised a raw LinAlgError
        raise SkinkitError(f"rest_frames: bone {int(singular[0])}'s frame is singular (it has no inverse)")
    transform = unit_box(reference)
    boxed_poses, boxed_examples = to_box(transform, poses @ np.linalg.inv(frames), examples)
    boxed_prior = None if prior is None else \
        to_rest_space(prior.coordinates, frames, influences.bones) @ transform.T
    rest_weight = REST_POSE_WEIGHT * len(examples) if reproduce_rest and rest_positions is not None and \
        rest_frames is not None else 0.0
    boxed_rest = reference * transform[0, 0] + transform[:3, 3]
    if method == "global" and triangles is None:
        raise SkinkitError("the global fit needs the mesh's triangles (its edges carry the regulariser)")
    delta = DEFAULT_DELTA if regularisation is None else regularisation
    # the global fit's start: the validated default λ, or (unvalidated) the thesis's λ = δ
    lam = (DEFAULT_LAMBDA if validate else max(delta, 1e-6)) if method == "global" else \
        DEFAULT_LAMBDA if regularisation is None else regularisation
    validation = {}
    if validate:
        lam, validation = validated_lambda(boxed_poses, boxed_examples, boxed_rest, rest_weight, influences, lam,
                                           boxed_prior, threads)
    edge_data = edge_lengths(boxed_examples, triangles) if method == "global" else None
    poses_used, examples_used = with_rest_pose(boxed_poses, boxed_examples, boxed_rest, rest_weight)
    del boxed_examples  # the fits read its copy with the rest pose: one whole copy of the examples alive, not two
    if validation.get("fallback"):  # the prior predicted the training examples better than any λ: keep it, exactly
        model = AnimationSpaceModel(influences.offsets, influences.bones, prior.coordinates, bone_count)
        report = {"lambda": None, "prior": True, **validation, "rest_pose_weight": rest_weight}
        return FitResult(model, method, time.perf_counter() - started, report)
    if method == "per-vertex":
        coordinates, report = per_vertex(poses_used, examples_used, influences, lam, boxed_prior, threads)
    elif method == "global":
        coordinates, report = global_fit(poses_used, examples_used, edge_data, influences, lam, delta, boxed_prior,
                                         settings, threads, progress)
    else:
        raise SkinkitError(f"method: expected one of {FIT_METHODS}, got {method!r}")
    del poses_used, examples_used
    coordinates = from_box(transform, coordinates)  # rebound, so the boxed coordinates are freed: rest space
    coordinates = to_rest_space(coordinates, np.linalg.inv(frames), influences.bones)  # then bone space
    model = AnimationSpaceModel(influences.offsets, influences.bones, coordinates, bone_count)
    report.update(rest_pose_weight=rest_weight, **validation)
    return FitResult(model, method, time.perf_counter() - started, report)


def with_rest_pose(poses, examples, rest, weight):
    """The examples and the rest pose (identity frames in rest space) scaled by sqrt(weight): the fits use the
    top three rows of each frame, so scaling frame and example by s weights that example's squares by s^2."""
    if weight <= 0:
        return poses, examples
    root = np.sqrt(weight)
    rest_pose = np.eye(4)[None, None].repeat(poses.shape[1], 1) * root
    return (np.ascontiguousarray(np.concatenate([poses, rest_pose])),
            np.ascontiguousarray(np.concatenate([examples, rest[None] * root])))


def vertex_chunks(offsets: np.ndarray, example_count: int) -> list[tuple[int, int]]:
    """(begin, end) vertex ranges for the validation (at least one vertex each): at most
    _memory.VALIDATION_CHUNK_INFLUENCES influences and _memory.VALIDATION_CHUNK_VALUES example coordinates."""
    vertex_count = len(offsets) - 1
    most_vertices = max(1, _memory.VALIDATION_CHUNK_VALUES // (3 * max(example_count, 1)))
    bounds = [0]
    while bounds[-1] < vertex_count:
        by_influences = int(np.searchsorted(offsets, int(offsets[bounds[-1]]) + _memory.VALIDATION_CHUNK_INFLUENCES,
                                            "right")) - 1
        bounds.append(max(bounds[-1] + 1, min(vertex_count, bounds[-1] + most_vertices, by_influences)))
    return list(zip(bounds[:-1], bounds[1:]))


def validated_lambda(poses, examples, rest, rest_weight, influences, lam, prior, threads):
    """λ times the VALIDATION_FACTORS with the lowest cross-validated rms (VALIDATION_FOLDS folds of the examples,
    each fitted on the others and the rest pose; one factorisation per vertex and fold serves every λ), or None
    when the prior's rms is not above it by more than VALIDATION_MARGIN (fall back to it); λ itself when too few
    examples remain to fit or to validate. A linear-blend prior is refitted without each fold's examples, for the
    fold's fits to pull towards and for its own score: the caller's was fitted to every example, and would let the
    validation see them. Vertices are independent: it works through them a chunk at a time (vertex_chunks), so
    a chunk's fold priors, kept examples and prior predictions are temporaries of bounded size (for a 1M-vertex,
    8-influence mesh the whole fold priors were 1 GB), with the same scores for every λ in any chunking."""
    folds = min(VALIDATION_FOLDS, len(examples))
    fitted = len(examples) - -(-len(examples) // folds)  # the smallest training part of any fold
    if folds < 2 or 3 * fitted + (rest_weight > 0) * 3 < 4 * int(influences.counts().max(initial=0)) - 1:
        return lam, {}
    fold_of = np.arange(len(examples)) % folds
    refit_prior = prior is not None and is_linear_blend(prior, rest, influences)
    candidates = np.array([lam * factor for factor in VALIDATION_FACTORS])
    squared = np.empty((influences.vertex_count, len(candidates)))
    prior_squared = 0.0
    for begin, end in vertex_chunks(influences.offsets, len(examples)):
        first, last = int(influences.offsets[begin]), int(influences.offsets[end])
        part = InfluencePattern(influences.offsets[begin:end + 1] - first, influences.bones[first:last])
        part_examples, part_rest = np.ascontiguousarray(examples[:, begin:end]), rest[begin:end]
        part_prior = None if prior is None else prior[first:last]
        fold_priors = lbs_fold_priors(poses, part_examples, part_rest, part, fold_of, folds, threads) \
            if refit_prior else None
        poses_used, examples_used = with_rest_pose(poses, part_examples, part_rest,
                                                   rest_weight * fitted / len(examples))
        with blas_threads_for(threads):  # each worker solves its vertices' systems with LAPACK
            _core.validate_per_vertex(squared[begin:end], part.offsets, part.bones, poses_used.reshape(-1),
                                      examples_used.reshape(-1), len(examples_used), int(rest_weight > 0), folds,
                                      None if prior is None or refit_prior else np.ascontiguousarray(part_prior),
                                      fold_priors, candidates, threads)
        if prior is not None:
            prior_squared += prior_squared_error(poses, part_examples, part, part_prior, fold_priors, fold_of)
    values = examples.shape[0] * examples.shape[1]
    scores = {f"{value:g}": float(np.sqrt(total / values)) for value, total in zip(candidates, squared.sum(axis=0))}
    chosen = float(candidates[int(np.argmin(squared.sum(axis=0)))])
    if prior is not None:
        scores[PRIOR_CANDIDATE] = float(np.sqrt(prior_squared / values))
        if scores[PRIOR_CANDIDATE] <= (1.0 + VALIDATION_MARGIN) * scores[f"{chosen:g}"]:
            chosen = None
    return chosen, {"validation": scores, "validation_examples": int(len(examples)), "validation_folds": folds,
                    "fallback": chosen is None}


def is_linear_blend(coordinates, rest, influences) -> bool:
    """Whether rest-space coordinates are linear blend skinning's, w_j (x, 1), on the rest mesh."""
    points = rest[influences.vertex_of_each_influence()]
    scale = max(float(np.abs(coordinates).max(initial=0.0)), 1.0)
    return bool(np.abs(coordinates[:, :3] - coordinates[:, 3:] * points).max(initial=0.0) <= 1e-9 * scale)


def lbs_fold_priors(poses, examples, rest, influences, fold_of, folds, threads):
    """(folds, influences, 4): the linear-blend fit without each fold's examples, in rest space (for a linear-blend
    prior; another, such as the rig's own weights, did not see the examples)."""
    points = np.column_stack([rest, np.ones(len(rest))])[influences.vertex_of_each_influence()]
    fold_priors = np.empty((folds, influences.influence_count, 4))
    for fold in range(folds):
        kept = fold_of != fold
        weights = np.empty(influences.influence_count)
        _core.fit_lbs_weights(weights, influences.offsets, influences.bones,
                              np.ascontiguousarray(poses[kept]).reshape(-1),
                              np.ascontiguousarray(examples[kept]).reshape(-1), int(kept.sum()),
                              np.ascontiguousarray(rest).reshape(-1), threads)
        fold_priors[fold] = weights[:, None] * points
    return fold_priors


def prior_squared_error(poses, examples, influences, prior, fold_priors, fold_of) -> float:
    """The prior's squared error on the examples: each fold's refitted prior on that fold's, when there are such."""
    bone_count = poses.shape[1]
    if fold_priors is None:
        model = AnimationSpaceModel(influences.offsets, influences.bones, prior, bone_count)
        return float(((model.evaluate(poses) - examples) ** 2).sum())
    total = 0.0
    for fold, coordinates in enumerate(fold_priors):
        model = AnimationSpaceModel(influences.offsets, influences.bones, coordinates, bone_count)
        total += float(((model.evaluate(poses[fold_of == fold]) - examples[fold_of == fold]) ** 2).sum())
    return total


#: Influences mapped at a time by to_rest_space: their gathered frames are 4 MiB (for all 8M influences of a
#: 1M-vertex mesh they were a 1 GB temporary). Rows are independent: the same values in any chunking.
REST_SPACE_CHUNK = 2**15


def to_rest_space(coordinates: np.ndarray, frames: np.ndarray, bones: np.ndarray) -> np.ndarray:
    """Each influence's 4-vector mapped by its bone's frame: q_j = frames[j] p_j."""
    out = np.empty((len(bones), 4))
    for part in chunks(len(bones), REST_SPACE_CHUNK):
        out[part] = np.einsum("kij,kj->ki", frames[bones[part]], coordinates[part])
    return out


def per_vertex(poses, examples, influences, lam, prior, threads):
    if not lam >= 0:
        raise SkinkitError(f"regularisation λ must be >= 0, got {lam}")
    coordinates = np.empty((influences.influence_count, 4))
    with blas_threads_for(threads):  # each worker solves its vertices' systems with LAPACK
        _core.fit_per_vertex(coordinates, influences.offsets, influences.bones, poses.reshape(-1),
                             examples.reshape(-1), len(examples), float(lam),
                             None if prior is None else np.ascontiguousarray(prior), threads)
    return coordinates, {"lambda": float(lam), "prior": prior is not None}


def edge_lengths(examples, triangles):
    """The mesh's edges and each one's mean length over the examples (unweighted: the rest pose is among them)."""
    edges = mesh_edges(np.asarray(triangles))
    return edges, np.concatenate([edge_length(examples, edges[part, 0], edges[part, 1]).mean(axis=0)
                                  for part in chunks(len(edges), EDGE_CHUNK)] or [np.empty(0)])


def global_fit(poses, examples, edge_data, influences, lam, delta, prior, settings, threads, progress):
    """Eq. 4.4 started from the per-vertex fit with λ (pulled towards the prior)."""
    if not delta >= 0:
        raise SkinkitError(f"regularisation δ must be >= 0, got {delta}")
    edges, mean_length = edge_data
    edge_weights = np.ascontiguousarray(delta / np.maximum(mean_length, 1e-12))
    coordinates, _ = per_vertex(poses, examples, influences, lam, prior, threads)
    report = _core.fit_global(coordinates, influences.offsets, influences.bones, poses.reshape(-1),
                              examples.reshape(-1), len(examples), np.ascontiguousarray(edges, np.int32).reshape(-1),
                              edge_weights, *settings.as_tuple(), threads, progress)
    return coordinates, {**report, "lambda": float(lam), "delta": float(delta), "edges": int(len(edges)),
                         "preconditioned": bool(settings.precondition)}


@checked(skeleton=Skeleton, influences=InfluencePattern, threads=THREADS)
def fit_lbs(skeleton: Skeleton, rest_positions, poses, examples, influences: InfluencePattern,
            threads: int = 0) -> SparseWeights:
    """Linear-blend baseline: non-negative weights summing to 1 on the same influence sets."""
    rest_positions = as_real_array(rest_positions, "rest_positions", shape=(influences.vertex_count, 3))
    poses, examples = checked_examples(poses, examples, influences.vertex_count, skeleton.bone_count)
    _memory.check_fit_lbs(influences.vertex_count, influences.influence_count, len(examples))
    check_influences(influences)
    check_bones_move(poses, influences, skeleton.names)
    transform = unit_box(rest_positions)
    boxed_poses, boxed_examples = to_box(transform, poses, examples)
    boxed_rest = Skeleton(skeleton.parents, transform @ skeleton.rest_frames @ np.linalg.inv(transform), skeleton.names)
    matrices = np.ascontiguousarray(skinning_matrices(boxed_rest, boxed_poses))
    weights = np.empty(influences.influence_count)
    _core.fit_lbs_weights(weights, influences.offsets, influences.bones, matrices.reshape(-1),
                          boxed_examples.reshape(-1), len(examples),
                          np.ascontiguousarray(rest_positions * transform[0, 0] + transform[:3, 3]).reshape(-1), threads)
    return SparseWeights(influences.offsets, influences.bones, weights)


# ---- influence sets ---------------------------------------------------------------------------------

def mesh_edges(triangles) -> np.ndarray:
    """Unique undirected edges (M, 2) of a triangle list, lower index first."""
    triangles = as_index_array(triangles, "triangles", (None, 3)).astype(np.int64)
    pairs = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    pairs.sort(axis=1)
    if not len(pairs):
        return np.zeros((0, 2), np.int32)
    # one int64 key per pair sorts like the rows (lower index first), and np.unique on keys is ~10x faster than on rows
    span = int(pairs.max()) + 1
    keys = np.unique(pairs[:, 0] * span + pairs[:, 1])
    return np.column_stack([keys // span, keys % span]).astype(np.int32)


def pattern_from_mask(mask: np.ndarray, score: np.ndarray, max_influences: int) -> InfluencePattern:
    """The set bones of each row of mask, at most max_influences of them, those with the best score kept."""
    if max_influences < 1:
        raise SkinkitError(f"max_influences must be at least 1, got {max_influences}")
    ranked = np.where(mask, score, -np.inf)
    keep = np.argsort(-ranked, axis=1, kind="stable")[:, :max_influences]
    kept_mask = np.zeros_like(mask)
    np.put_along_axis(kept_mask, keep, True, axis=1)
    kept_mask &= mask
    rows, bones = np.nonzero(kept_mask)
    offsets = np.zeros(mask.shape[0] + 1, np.int32)
    np.cumsum(np.bincount(rows, minlength=mask.shape[0]), out=offsets[1:])
    return InfluencePattern(offsets, bones.astype(np.int32))


def grow_by_rings(mask: np.ndarray, triangles, rings: int, edges=None) -> np.ndarray:
    """Each vertex also gets the bones of the vertices up to `rings` edges away (edges: mesh_edges, if known)."""
    edges = mesh_edges(triangles) if edges is None else edges
    grown = mask.copy()
    for _ in range(rings):
        previous = grown.copy()
        np.logical_or.at(grown, edges[:, 0], previous[edges[:, 1]])
        np.logical_or.at(grown, edges[:, 1], previous[edges[:, 0]])
        if np.array_equal(grown, previous):  # every connected piece is filled: more rings add nothing
            break
    return grown


def rigid_explanation_error(skeleton: Skeleton, rest_positions, poses, examples) -> np.ndarray:
    """(V, b): how far each bone's rigid motion alone carries each rest vertex from its examples."""
    as_instance(skeleton, "skeleton", Skeleton)
    rest_positions = as_real_array(rest_positions, "rest_positions", shape=(None, 3))
    poses, examples = checked_examples(poses, examples, len(rest_positions), skeleton.bone_count)
    matrices = skinning_matrices(skeleton, poses)[:, :, :3, :]  # (E, b, 3, 4)
    rest = np.column_stack([rest_positions, np.ones(len(rest_positions))]).T  # (4, V)
    error = np.zeros((skeleton.bone_count, len(rest_positions)))
    for example, pose_matrices in zip(examples, matrices):
        moved = pose_matrices @ rest  # (b, 3, V)
        error += ((moved - example.T[None]) ** 2).sum(axis=1)
    return error.T


@checked(max_influences=count(1), rings=count(0))
def influences_from_weights(dense_weights, max_influences: int, triangles=None, rings: int = 0,
                            explanation_error=None) -> InfluencePattern:
    """Influence sets from existing weights (a rig's or painted vertex groups), grown by `rings` rings.

    dense_weights: (V, b). Bones beyond max_influences are dropped: the heaviest first, and among grown
    bones (weight 0) those whose motion best explains the vertex (explanation_error, lower is better).
    """
    dense = as_real_array(dense_weights, "weights", shape=(None, None))
    mask = dense > 0
    if rings > 0:
        if triangles is None:
            raise SkinkitError("growing influence sets by rings needs the mesh's triangles")
        mask = grow_by_rings(mask, triangles, rings, mesh_edges(as_triangles(triangles, len(dense))))
    score = dense.copy()
    if explanation_error is not None:
        # ties among grown bones: the best explainer first
        score += 1e-9 / (1.0 + np.abs(as_real_array(explanation_error, "explanation_error", shape=dense.shape)))
    return pattern_from_mask(mask, score, max_influences)


@checked(skeleton=Skeleton, max_influences=count(1), include_root=FLAG)
def influences_automatic(skeleton: Skeleton, rest_positions, poses, examples, max_influences: int,
                         include_root: bool = False) -> InfluencePattern:
    """The max_influences bones whose rigid motion best explains each vertex over the examples."""
    error = rigid_explanation_error(skeleton, rest_positions, poses, examples)
    mask = np.ones_like(error, dtype=bool)
    if not include_root:
        mask[:, 0] = False
    return pattern_from_mask(mask, -error, max_influences)


# ---- errors ---------------------------------------------------------------------------------------

def vertex_normals(positions, triangles) -> np.ndarray:
    """Area-weighted unit vertex normals of (V, 3) positions, or of each (E, V, 3) example."""
    positions = as_real_array(positions, "positions")
    if positions.ndim not in (2, 3) or positions.shape[-1] != 3:
        raise SkinkitError(f"positions: expected shape (V, 3) or (E, V, 3), got {positions.shape}")
    triangles = as_triangles(triangles, positions.shape[-2])
    if positions.ndim == 3:
        return np.stack([vertex_normals(example, triangles) for example in positions])
    a, b, c = (positions[triangles[:, k]] for k in range(3))
    face = np.cross(b - a, c - a)
    corners = triangles.reshape(-1)
    normals = np.column_stack([np.bincount(corners, np.repeat(face[:, axis], 3), minlength=len(positions))
                               for axis in range(3)])
    length = np.linalg.norm(normals, axis=-1, keepdims=True)
    return normals / np.where(length > 0, length, 1)


def fit_errors(predicted, examples, diagonal: float, triangles=None) -> dict:
    """Geometric error (distance / diagonal: mean, rms, max) and, with triangles, normal error in degrees."""
    predicted, examples = checked_pair(predicted, examples)
    diagonal = as_real(diagonal, "diagonal", above=0)
    # one example at a time (each value is its own vertex's): whole-array differences and normals were several
    # copies of the positions, 0.6 GB each for 25 frames of 1M vertices
    shape = predicted.shape[-2:]
    each_predicted, each_example = predicted.reshape(-1, *shape), examples.reshape(-1, *shape)
    distance = np.empty(predicted.shape[:-1])
    for row, (p, e) in zip(distance.reshape(-1, shape[0]), zip(each_predicted, each_example)):
        row[:] = np.linalg.norm(p - e, axis=-1) / diagonal
    result = {"mean": float(distance.mean()), "rms": float(np.sqrt((distance ** 2).mean())),
              "max": float(distance.max())}
    if triangles is not None:
        cosine = np.empty(predicted.shape[:-1])
        for row, (p, e) in zip(cosine.reshape(-1, shape[0]), zip(each_predicted, each_example)):
            row[:] = np.sum(vertex_normals(p, triangles) * vertex_normals(e, triangles), axis=-1)
        angle = np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))
        result.update(normal_mean_degrees=float(angle.mean()), normal_max_degrees=float(angle.max()))
    return result


def checked_pair(predicted, examples) -> tuple[np.ndarray, np.ndarray]:
    """Predicted and example positions (..., V, 3) of one shape, with at least one vertex."""
    predicted = as_real_array(predicted, "predicted")
    examples = as_real_array(examples, "examples")
    if predicted.shape != examples.shape or predicted.ndim < 2 or predicted.shape[-1] != 3 or not predicted.size:
        raise SkinkitError(f"predicted, examples: expected two arrays of one shape (..., V, 3), got {predicted.shape} "
                           f"and {examples.shape}")
    return predicted, examples


def model_errors(predictions: dict, examples, train, diagonal: float, triangles=None) -> dict:
    """The report of a fit or a decomposition (docs/data-model.md, "Reports"): for each model of `predictions`
    ("animation_space", "linear_blend", and INPUT_RIG when the rig had weights: (E, V, 3) each), fit_errors on the training examples (`train`, a bool
    mask over E) and on the held-out ones, {"animation_space": {"train": {...}, "held_out": {...}}, ...}; a part
    with no examples is left out."""
    examples = as_real_array(examples, "examples", shape=(None, None, 3))
    train = as_mask(train, "train", len(examples))
    if not isinstance(predictions, dict):
        raise SkinkitError(f"predictions: expected a dict of model name to (E, V, 3) positions, got "
                           f"{type(predictions).__name__}")
    predictions = {model: as_real_array(predicted, f"predictions[{model!r}]", shape=examples.shape)
                   for model, predicted in predictions.items()}
    return {model: {part: fit_errors(*((predicted, examples) if mask.all() else (predicted[mask], examples[mask])),
                                     diagonal, triangles)
                    for part, mask in (("train", train), ("held_out", ~train)) if mask.any()}
            for model, predicted in predictions.items()}


#: The report key of the rig's own weights, the baseline a fit must beat to be worth keeping.
INPUT_RIG = "input_rig"
#: The report keys of the fitted models, in the words of the warnings.
FITTED_MODELS = {"animation_space": "animation space", "linear_blend": "the fitted linear blend skinning"}


def worse_than_input_rig(errors: dict) -> list[str]:
    """Warnings for each fitted model of a model_errors report (with an INPUT_RIG entry) whose held-out rms error
    is above the input rig's: the user keeps the rig's weights unless a fit is better."""
    if not isinstance(errors, dict) or not all(isinstance(parts, dict) and all(isinstance(e, dict) and "rms" in e
                                                                              for e in parts.values())
                                               for parts in errors.values()):
        raise SkinkitError("errors: expected a model_errors report ({model: {part: {'rms': ...}}})")
    baseline = errors.get(INPUT_RIG, {}).get("held_out")
    if baseline is None:
        return []
    warnings = []
    for model, words in FITTED_MODELS.items():
        held = errors.get(model, {}).get("held_out")
        if held is not None and held["rms"] > baseline["rms"]:
            warnings.append(f"{words} is worse than the rig's own weights on the held-out frames (rms "
                            f"{held['rms']:.3g} against {baseline['rms']:.3g} of the diagonal): keep the rig's "
                            "weights, or fit with more examples or another regularisation")
    return warnings


def per_vertex_error(predicted, examples, diagonal: float) -> np.ndarray:
    """(V,): each vertex's largest distance over the examples, divided by the diagonal (for heat maps)."""
    predicted, examples = checked_pair(predicted, examples)
    diagonal = as_real(diagonal, "diagonal", above=0)
    return (np.linalg.norm(predicted - examples, axis=-1) / diagonal).max(axis=0)
