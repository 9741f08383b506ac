"""Training a handle rig from example meshes (section 2.3): proxy bones, per-example dual quaternions, kernel CCA
per bone and the Poisson translation solver."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .. import _core
from .._blas import blas_threads_for
from .._checks import (CALLBACK, FLAG, THREADS, SkinkitError, as_count, as_index_array, as_real_array, checked, choice,
                       count, real)
from ..decompose import decompose
from ..fit import mesh_edges
from ..model import SparseWeights
from .clusters import CLUSTERINGS, hierarchical_decomposition, triangle_hierarchy
from .model import KERNELS, HandleModel
from .suggest import suggest_handles
from .weights import refit_dqs_weights

#: Proxy bones besides the static root.
DEFAULT_BONES = 16
#: How the proxy bones are found (skinkit.handles.clusters.CLUSTERINGS).
DEFAULT_CLUSTERING = "rigid"
#: CCA pairs kept per bone (Table 2.1: 8 for every data set with a DQ target of 8 numbers).
DEFAULT_BASIS_COUNT = 8
#: The kernel CCA ridge kappa, relative to the centred kernel's mean eigenvalue (not in the thesis; pitfall 1).
DEFAULT_RIDGE = 1e-3
#: The polynomial kernel of the face (section 2.7): degree 5, constant 0.1 x the average handle-vector norm.
POLYNOMIAL_DEGREE = 5
POLYNOMIAL_CONSTANT = 0.1
#: The Poisson solve's handle weight beta (not given in the thesis), relative to edge_count / handle_count so that
#: the handles together weigh as much as the edges together whatever the mesh size.
DEFAULT_BETA = 1.0
#: The Poisson translation solve is off by default: measured with 16-30 proxy bones it integrates the per-edge fit's
#: error (eq. 2.10 cannot express the translation differences across a weight gradient) into 0.021 rms on the
#: horse gallop's training frames even with their true rotations, against 0.005 for the predicted translations
#: (bench/bench_handles.py reports both). The thesis too ran without it on two of its six data sets.
DEFAULT_POISSON = False
#: Refit the decomposition's linear-blend weights for DQS (skinkit.handles.weights): the rig skins with DQS.
DEFAULT_DQS_WEIGHTS = True
#: Choose the kernel parameter's scale and the ridge kappa by validation on the training frames (never on anything
#: else): VALIDATION_FOLDS interleaved folds, each predicted by a predictor fitted on the others (the proxy bones
#: and weights stay those of all training frames: only the predictor is being chosen).
DEFAULT_VALIDATE = False
VALIDATION_FOLDS = 4
#: Multipliers of section 2.7's kernel parameter (the Gaussian's sigma, the polynomial's constant) tried.
KERNEL_SCALES = (0.5, 0.7, 1.0, 1.4, 2.0)
#: Relative ridges tried (see DEFAULT_RIDGE).
RIDGES = (1e-4, 1e-3, 1e-2, 1e-1)
#: Handles whose positions vary less than this fraction of the rest bounding box do not move in the examples.
STILL_HANDLE = 1e-6


def checked_handles(frames, handle_vertices, handle_count):
    if (handle_vertices is None) == (handle_count is None):
        raise SkinkitError("give either handle_vertices or handle_count")
    if handle_vertices is None:
        return suggest_handles(frames, as_count(handle_count, "handle_count", minimum=1))
    handles = as_index_array(handle_vertices, "handle_vertices", shape=(None,))
    if len(handles) == 0:
        raise SkinkitError("handle_vertices: at least one control point is needed")
    out_of_range = handles[(handles < 0) | (handles >= frames.shape[1])]
    if len(out_of_range):
        raise SkinkitError(f"handle_vertices: vertex {int(out_of_range[0])} is out of range "
                           f"(the mesh has {frames.shape[1]} vertices)")
    values, counts = np.unique(handles, return_counts=True)
    if (counts > 1).any():
        raise SkinkitError(f"handle_vertices: vertex {int(values[counts > 1][0])} is given more than once")
    return handles


def kernel_parameter(kernel: str, normalised: np.ndarray) -> float:
    """Section 2.7's automatic parameters on the normalised handle vectors (mean 0, rms distance to the mean 1):
    the Gaussian's sigma is the handle vectors' standard deviation (1 by construction; the thesis does not say
    whether it is pooled, we pool over the whole vector); the polynomial's constant is 0.1 x their average norm."""
    if kernel == "gaussian":
        return float(np.sqrt((normalised ** 2).sum(axis=1).mean()))
    if kernel == "polynomial":
        return POLYNOMIAL_CONSTANT * float(np.linalg.norm(normalised, axis=1).mean())
    return 0.0


def skinning_motions(decomposition) -> np.ndarray:
    """Each proxy bone's rigid skinning motion (F, B, 4, 4) rest -> example, its rotation re-orthonormalised
    (the fit's rounding would fail sk_dq_from_rigid's rigidity test)."""
    motions = decomposition.training_poses @ np.linalg.inv(decomposition.skeleton.rest_frames)
    u, _, vt = np.linalg.svd(motions[..., :3, :3])
    motions[..., :3, :3] = u @ vt
    motions[..., 3, :] = (0, 0, 0, 1)
    return np.ascontiguousarray(motions)


#: The most canonical correlation bases a rig keeps: each costs one kernel column per bone coordinate.
MAX_BASIS_COUNT = 4096


@checked(bones=count(1), kernel=choice(KERNELS), clustering=choice(CLUSTERINGS), basis_count=count(1, MAX_BASIS_COUNT),
         ridge=real(above=0), beta=real(above=0), poisson=FLAG, dqs_weights=FLAG, validate=FLAG,
         max_influences=count(1), seed=count(0, 2**63 - 1), threads=THREADS, progress=CALLBACK)
def train(frames, triangles, *, handle_vertices=None, handle_count=None, bones: int = DEFAULT_BONES,
          bone_counts=None, clustering: str = DEFAULT_CLUSTERING, kernel: str = "gaussian",
          basis_count: int = DEFAULT_BASIS_COUNT, ridge: float = DEFAULT_RIDGE, beta: float = DEFAULT_BETA,
          poisson: bool = DEFAULT_POISSON, dqs_weights: bool = DEFAULT_DQS_WEIGHTS, validate: bool = DEFAULT_VALIDATE,
          rest=None, max_influences: int = 4, seed: int = 0, threads: int = 0, progress=None) -> HandleModel:
    """A handle rig trained on the example meshes frames (E, V, 3) with triangles (T, 3).

    Control points: handle_vertices (vertex indices) or handle_count (suggested by suggest_handles). rest (V, 3)
    is the mesh the weights refer to (default frames[0]). clustering: how the proxy bones are found, "rigid"
    (skinkit.decompose's) or "hierarchical" (the triangle hierarchy, skinkit.handles.clusters). bone_counts (a
    sequence of counts), when given instead of bones, are each tried and the one with the least validation error on
    the training frames is kept (choose_bone_count; with the hierarchical clustering every count is a cut of one
    hierarchy). kernel: "gaussian", "polynomial" or "linear". poisson: replace the predicted translations by the
    Poisson solve (beta: the handles' weight, see DEFAULT_BETA). dqs_weights: refit the proxy bones' weights for DQS
    (else the decomposition's LBS weights). validate: choose the kernel parameter's scale and the ridge by K-fold
    validation on the training frames (else section 2.7's parameter and ridge as given). progress(fraction) may
    return True to cancel.
    """
    started = time.perf_counter()
    frames = np.ascontiguousarray(as_real_array(frames, "frames", shape=(None, None, 3)))
    if kernel not in KERNELS:
        raise SkinkitError(f"kernel: expected one of {', '.join(KERNELS)}, got {kernel!r}")
    if len(frames) < 3:
        raise SkinkitError(f"frames: {len(frames)} example(s); a handle rig needs at least 3 (kernel CCA on fewer "
                           "has nothing to correlate)")
    if not (ridge > 0 and np.isfinite(ridge)):
        raise SkinkitError(f"ridge {ridge}: must be finite and > 0")
    if not (beta > 0 and np.isfinite(beta)):
        raise SkinkitError(f"beta {beta}: must be finite and > 0")
    handles = checked_handles(frames, handle_vertices, handle_count)
    rest = frames[0] if rest is None else as_real_array(rest, "rest", shape=(frames.shape[1], 3))
    vectors = frames[:, handles].reshape(len(frames), -1)
    extent = float(np.ptp(rest, axis=0).max()) or 1.0
    spread = np.ptp(frames[:, handles], axis=0).max(axis=1)
    if (spread <= STILL_HANDLE * extent).all():
        raise SkinkitError("handle_vertices: the handles do not move in the examples, so they cannot drive anything")
    if bone_counts is not None:
        counts = checked_bone_counts(bone_counts, len(as_index_array(triangles, "triangles", shape=(None, 3))))
        chosen = choose_bone_count(frames, triangles, rest, handles, counts, clustering=clustering, kernel=kernel,
                                   basis_count=basis_count, max_influences=max_influences, dqs_weights=dqs_weights,
                                   seed=seed, threads=threads, progress=progress)
        proxy = chosen["proxy"]
    else:
        proxy = proxy_bones(frames, triangles, rest, bones, max_influences, dqs_weights, seed, threads, progress,
                            clustering=clustering)
    model = rig_on_proxy_bones(frames, rest, handles, proxy, kernel=kernel, basis_count=basis_count, ridge=ridge,
                               beta=beta, poisson=poisson, validate=validate, threads=threads, progress=progress,
                               started=started)
    model.report["clustering"] = clustering
    if bone_counts is not None:
        model.report["bone_validation"] = chosen["validation"]
    return model


#: Validation errors within this fraction of the least are a tie, won by the fewest bones: a bone that only splits
#: a rigid part in two changes the validation error by rounding, not by fit.
BONE_COUNT_TIE = 0.02


def checked_bone_counts(bone_counts, triangle_count: int) -> list[int]:
    counts = as_index_array(bone_counts, "bone_counts", shape=(None,))
    if len(counts) == 0:
        raise SkinkitError("bone_counts: give at least one proxy-bone count")
    if (counts < 1).any():
        raise SkinkitError(f"bone_counts: {int(counts[counts < 1][0])} proxy bones; each count must be >= 1")
    if (counts > triangle_count).any():
        raise SkinkitError(f"bone_counts: {int(counts.max())} proxy bones but only {triangle_count} triangles")
    return sorted(set(int(c) for c in counts))


def bone_count_list(text: str) -> list[int] | None:
    """'16, 32,48' -> [16, 32, 48]; '' -> None (the single Proxy Bones count)."""
    items = [item.strip() for item in text.split(",") if item.strip()]
    if not items:
        return None
    try:
        return [int(item) for item in items]
    except ValueError:
        raise SkinkitError(f"bone counts {text!r}: expected whole numbers separated by commas, e.g. '16,32,48'") \
            from None


def choose_bone_count(frames, triangles, rest, handles, bone_counts, *, clustering: str = DEFAULT_CLUSTERING,
                      kernel: str = "gaussian", basis_count: int = DEFAULT_BASIS_COUNT, max_influences: int = 4,
                      dqs_weights: bool = DEFAULT_DQS_WEIGHTS, seed: int = 0, threads: int = 0, progress=None) -> dict:
    """The proxy-bone count (of bone_counts, ascending) whose rig predicts the training frames best under
    VALIDATION_FOLDS-fold validation (each fold predicted from its handles by a kernel CCA fitted on the others,
    kernel scale and ridge chosen as validated_parameters does); ties within BONE_COUNT_TIE go to fewer bones.
    Returns {"bones", "proxy", "validation": {count: rms}}: only the training frames ever choose."""
    frames = np.ascontiguousarray(frames, dtype=float)
    rest = np.ascontiguousarray(rest, dtype=float)
    hierarchy = triangle_hierarchy(rest, frames, triangles) if clustering == "hierarchical" else None
    validation, proxies = {}, {}
    for index, bones in enumerate(bone_counts):
        staged = None if progress is None else \
            (lambda fraction, index=index: progress(0.8 * (index + fraction) / len(bone_counts)))
        proxies[bones] = proxy_bones(frames, triangles, rest, bones, max_influences, dqs_weights, seed, threads,
                                     staged, clustering=clustering, hierarchy=hierarchy)
        validation[bones] = validation_rms(frames, rest, handles, proxies[bones], kernel, basis_count, threads)
    least = min(validation.values())
    chosen = min(count for count, rms in validation.items() if rms <= (1 + BONE_COUNT_TIE) * least)
    return {"bones": chosen, "proxy": proxies[chosen], "validation": validation}


def validation_rms(frames, rest, handles, proxy, kernel: str, basis_count: int, threads: int) -> float:
    """validated_parameters' least validation rms for a rig on these proxy bones."""
    vectors = frames[:, handles].reshape(len(frames), -1)
    mean = vectors.mean(axis=0)
    scale = float(np.sqrt(((vectors - mean) ** 2).sum(axis=1).mean()))
    normalised = np.ascontiguousarray((vectors - mean) / scale)
    degree = POLYNOMIAL_DEGREE if kernel == "polynomial" else 1
    return validated_parameters(rest, frames, handles, normalised, mean, scale, proxy, kernel,
                                kernel_parameter(kernel, normalised), degree, basis_count, threads)["rms"]


def rig_on_proxy_bones(frames, rest, handles, proxy, *, kernel: str, basis_count: int, ridge: float, beta: float,
                       poisson: bool, validate: bool, threads: int, progress=None, started=None) -> HandleModel:
    """train()'s second half on checked input: the predictor (and the Poisson solver) on given proxy bones, so a
    caller comparing predictors on one data set fits the proxy bones once."""
    started = time.perf_counter() if started is None else started
    extent = float(np.ptp(rest, axis=0).max()) or 1.0
    vectors = frames[:, handles].reshape(len(frames), -1)
    motions, dual_quaternions, weights = proxy.motions, proxy.dual_quaternions, proxy.weights
    bone_count = motions.shape[1]
    mean = vectors.mean(axis=0)
    scale = float(np.sqrt(((vectors - mean) ** 2).sum(axis=1).mean()))
    normalised = np.ascontiguousarray((vectors - mean) / scale)
    degree = POLYNOMIAL_DEGREE if kernel == "polynomial" else 1
    parameter = kernel_parameter(kernel, normalised)
    validation = None
    if validate:
        validation = validated_parameters(rest, frames, handles, normalised, mean, scale, proxy, kernel, parameter,
                                          degree, basis_count, threads)
        parameter *= validation["kernel_scale"]
        ridge = validation["ridge"]
    mapping, offset, correlations, kappa = fitted_predictor(normalised, dual_quaternions, kernel, parameter, degree,
                                                            basis_count, ridge, threads)
    if progress is not None and progress(0.9):
        raise SkinkitError("cancelled")
    translation_rotations = translation_handles = None
    report = {"bones": bone_count - 1, "examples": len(frames), "handle_vertices": handles.tolist(),
              "kernel": kernel, "kernel_parameter": parameter, "ridge": kappa, "poisson": poisson}
    if validation is not None:
        report["validation"] = validation
    if poisson:
        edges = mesh_edges(proxy.decomposition.triangles)
        translation_rotations = np.empty((bone_count, bone_count, 3))
        translation_handles = np.empty((bone_count, len(handles)))
        absolute_beta = beta * len(edges) / len(handles)
        solved = _core.handle_translation_solver(
            translation_rotations, translation_handles, weights.offsets, weights.bones, rest, weights.weights, edges,
            np.ascontiguousarray(motions[..., :3, :3]), frames, handles, bone_count, absolute_beta, threads)
        report.update(beta=absolute_beta, edge_fit_rms=solved["edge_error"] / extent)
    model = HandleModel(np.ascontiguousarray(rest), proxy.decomposition.triangles, weights.offsets, weights.bones,
                        weights.weights, handles, mean, scale, normalised, kernel, parameter, degree, mapping, offset,
                        translation_rotations, translation_handles)
    training = model.predict(model.handle_positions_of(frames), threads=threads)
    bone_fit = model.skin(dual_quaternions, threads=threads)
    report.update(training_rms=rms_error(training, frames, extent), proxy_bone_fit_rms=rms_error(bone_fit, frames, extent),
                  dqs_weights=proxy.dqs_weights, lbs_weights_fit_rms=proxy.lbs_weights_fit_rms / extent,
                  correlations=correlations.mean(axis=0).tolist(), seconds=time.perf_counter() - started)
    model.report = report
    return model


def fitted_predictor(normalised, dual_quaternions, kernel: str, parameter: float, degree: int, basis_count: int,
                     ridge: float, threads: int):
    """Kernel CCA per bone with the fused regression (section 2.4): the mapping (B * 8, E), its offset, the
    correlations (B, basis_count) and the absolute kappa (ridge x the centred kernel's mean eigenvalue)."""
    examples, bone_count = dual_quaternions.shape[:2]
    kernel_matrix = np.empty((examples, examples))
    _core.kernel_values(kernel_matrix, normalised, normalised, normalised.shape[1], KERNELS.index(kernel), parameter,
                        degree)
    centred = kernel_matrix - kernel_matrix.mean(axis=0) - kernel_matrix.mean(axis=1)[:, None] + kernel_matrix.mean()
    kappa = ridge * max(float(np.trace(centred)) / examples, 1e-300)
    mapping = np.empty((bone_count * 8, examples))
    offset = np.empty(bone_count * 8)
    correlations = np.empty((bone_count, basis_count))
    with blas_threads_for(threads):  # each worker runs its bones' eigenproblems with LAPACK
        _core.kernel_cca(mapping, offset, correlations, kernel_matrix, np.ascontiguousarray(dual_quaternions),
                         bone_count, 8, basis_count, kappa, threads)
    return mapping, offset, correlations, kappa


#: Examples whose normalised handle vectors are closer than this (relative to their spread) are one pose (a looped
#: take repeats its poses).
SAME_POSE = 1e-3


def validation_folds(normalised) -> np.ndarray:
    """Each example's fold: the distinct poses interleaved over VALIDATION_FOLDS folds, the repeats of a pose in its
    first occurrence's fold, so that no fold is predicted from copies of itself (the horse gallop is one cycle
    played twice: interleaving the frames themselves validates on poses the predictor has seen)."""
    distances = np.sqrt(((normalised[:, None] - normalised[None]) ** 2).sum(-1))
    first = np.argmax(distances <= SAME_POSE * np.sqrt(normalised.shape[1]), axis=1)  # the pose's first example
    _, pose_of_example = np.unique(first, return_inverse=True)
    return pose_of_example % VALIDATION_FOLDS


def validated_parameters(rest, frames, handles, normalised, mean, scale, proxy, kernel: str, parameter: float,
                         degree: int, basis_count: int, threads: int) -> dict:
    """The kernel scale and ridge with the least rms vertex error over VALIDATION_FOLDS interleaved folds of the
    training frames, each predicted from its handles by a predictor fitted on the other folds."""
    folds = validation_folds(normalised)
    scales = KERNEL_SCALES if kernel != "linear" else (1.0,)
    weights = proxy.weights
    errors = {}
    for kernel_scale in scales:
        for ridge in RIDGES:
            total = 0.0
            for fold in range(VALIDATION_FOLDS):
                fitting, held = folds != fold, folds == fold
                if fitting.sum() < 2 or not held.any():
                    continue
                known = np.ascontiguousarray(normalised[fitting])
                mapping, offset, _, _ = fitted_predictor(known, proxy.dual_quaternions[fitting], kernel,
                                                         parameter * kernel_scale, degree, basis_count, ridge, threads)
                model = HandleModel(rest, proxy.decomposition.triangles, weights.offsets, weights.bones,
                                    weights.weights, handles, mean, scale, known, kernel, parameter * kernel_scale,
                                    degree, mapping, offset, None, None)
                predicted = model.predict(frames[held][:, handles], threads=threads)
                total += float(((predicted - frames[held]) ** 2).sum())
            errors[(kernel_scale, ridge)] = total
    best = min(errors, key=errors.get)
    extent = float(np.ptp(rest, axis=0).max()) or 1.0
    return {"kernel_scale": best[0], "ridge": best[1], "folds": VALIDATION_FOLDS,
            "rms": float(np.sqrt(errors[best] / frames.shape[0] / frames.shape[1])) / extent}


@dataclass
class ProxyBones:
    """The proxy-bone skinned mesh of the examples: the decomposition, each bone's rigid skinning motion (E, B, 4, 4)
    and sign-aligned dual quaternion (E, B, 8) per example, the weights the rig skins with (LBS, or refitted for
    DQS) and the DQS fit's rms with the LBS weights (unnormalised, for the before/after)."""
    decomposition: object
    motions: np.ndarray
    dual_quaternions: np.ndarray
    weights: SparseWeights
    lbs_weights_fit_rms: float
    dqs_weights: bool


def proxy_bones(frames, triangles, rest, bones: int, max_influences: int, dqs_weights: bool, seed: int, threads: int,
                progress=None, clustering: str = DEFAULT_CLUSTERING, hierarchy=None) -> ProxyBones:
    """The proxy bones by `clustering` ("rigid": decompose's; "hierarchical": cut from the triangle hierarchy,
    given or built here)."""
    staged = None if progress is None else (lambda fraction: progress(0.8 * fraction))
    if clustering == "hierarchical":
        decomposition = hierarchical_decomposition(frames, triangles, rest, bones, max_influences, hierarchy,
                                                   threads=threads, progress=staged)
    else:
        decomposition = decompose(frames, triangles, bone_count=bones, max_influences=max_influences, rest=rest,
                                  threads=threads, seed=seed, progress=staged)
    motions = skinning_motions(decomposition)
    dual_quaternions = np.empty((len(frames), motions.shape[1], 8))
    _core.dq_from_rigid(dual_quaternions, motions)
    _core.dq_align_signs(dual_quaternions, len(frames))
    weights = decomposition.linear_blend
    lbs_fit = dqs_fit_rms(rest, frames, weights, dual_quaternions, threads)
    if dqs_weights:
        weights = SparseWeights(*refit_dqs_weights(rest, frames, dual_quaternions, weights.offsets, weights.bones,
                                                   weights.weights, progress=None if progress is None else
                                                   (lambda fraction: progress(0.8 + 0.05 * fraction))))
    return ProxyBones(decomposition, motions, dual_quaternions, weights, lbs_fit, dqs_weights)


def dqs_fit_rms(rest, frames, weights, dual_quaternions, threads: int) -> float:
    """rms vertex distance of the DQS-skinned examples with these weights (not normalised)."""
    skinned = np.empty(frames.shape[1:])
    total = 0.0
    for frame, pose in zip(frames, dual_quaternions):
        _core.dqs_evaluate(skinned, rest, 1.0, weights.offsets, weights.bones, weights.weights,
                           np.ascontiguousarray(pose), threads)
        total += float(((skinned - frame) ** 2).sum())
    return float(np.sqrt(total / (frames.shape[0] * frames.shape[1])))


def rms_error(predicted, frames, extent: float) -> float:
    """Root mean square vertex distance over all frames, divided by the largest bounding-box side (the thesis'
    measure, section 2.7)."""
    return float(np.sqrt(((predicted - frames) ** 2).sum(axis=-1).mean()) / extent)
