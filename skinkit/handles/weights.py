"""Per-vertex weights refitted for dual-quaternion skinning (section 2.3: weights "obtained by minimizing the fitting
error of vertex positions in all examples"): the proxy bones' decomposition solves its weights for linear blend
skinning; a handle rig skins with DQS, whose blend is normalised, so the LBS weights are not the DQS optimum.

For each vertex, with the example dual quaternions of its bones held fixed, the weights w (non-negative, summing to
one, on the vertex's existing influences: as sparse as the LBS pattern) minimise
    sum_examples || DQS(w) v - v_example ||^2
by projected Gauss-Newton (the constrained step of the linearised problem, projected onto the simplex, kept only
where it lowers the vertex's error). Vectorised over vertices in chunks; no per-vertex Python loop.
"""
from __future__ import annotations

import numpy as np

from ..model import SkinkitError

#: Gauss-Newton steps at most; the start (the LBS optimum) is close, so a few suffice.
ITERATIONS = 8
#: Stop when a step lowers the chunk's total error by less than this fraction.
CONVERGED = 1e-3
#: Vertices per chunk: bounds the (examples, chunk, influences, 8) blend arrays to a few tens of MB.
CHUNK_VALUES = 4_000_000
#: Forward-difference step for the Jacobian (the weights are O(1)).
STEP = 1e-6
#: Levenberg damping of the normal equations, relative to their mean diagonal.
DAMPING = 1e-9
#: Influences below this weight are dropped after the fit (the pattern only gets sparser).
NEGLIGIBLE = 1e-6


def padded_pattern(offsets, bones, weights):
    """CSR influences as padded (V, K) arrays: bone indices (padding 0), weights (padding 0) and a mask."""
    counts = np.diff(offsets)
    width = int(counts.max())
    mask = np.arange(width)[None, :] < counts[:, None]
    padded_bones = np.zeros(mask.shape, np.int64)
    padded_weights = np.zeros(mask.shape)
    padded_bones[mask] = bones
    padded_weights[mask] = weights
    return padded_bones, padded_weights, mask


def blended_points(candidates, weights, rest):
    """DQS of rest (C, 3) in every example: candidates (E, C, K, 8) sign-aligned, weights (C, K) -> (E, C, 3)."""
    b = np.einsum("eckj,ck->ecj", candidates, weights)
    w, u = b[..., 0], b[..., 1:4]
    wd, dv = b[..., 4], b[..., 5:8]
    norm2 = np.maximum(w * w + (u * u).sum(-1), 1e-30)
    v = np.broadcast_to(rest, u.shape)
    rotated = (v * (w * w - (u * u).sum(-1))[..., None] + 2 * u * (u * v).sum(-1, keepdims=True)
               + 2 * w[..., None] * np.cross(u, v))
    translated = 2 * (w[..., None] * dv - wd[..., None] * u + np.cross(u, dv))
    return (rotated + translated) / norm2[..., None]


def project_to_simplex(values, mask):
    """Each row's nearest point with non-negative entries summing to one, over its masked entries (others 0)."""
    shifted = np.where(mask, values, -1e30)
    ordered = -np.sort(-shifted, axis=1)
    cumulative = np.cumsum(ordered, axis=1)
    ranks = np.arange(1, values.shape[1] + 1)
    positive = ordered - (cumulative - 1) / ranks > 0
    last = values.shape[1] - 1 - np.argmax(positive[:, ::-1], axis=1)
    theta = (cumulative[np.arange(len(values)), last] - 1) / (last + 1)
    return np.where(mask, np.maximum(values - theta[:, None], 0), 0)


def vertex_errors(candidates, weights, rest, targets):
    return ((blended_points(candidates, weights, rest) - targets) ** 2).sum(axis=(0, 2))


def refit_chunk(candidates, weights, mask, rest, targets):
    """Projected Gauss-Newton on one chunk of vertices; returns the weights and each vertex's squared error."""
    error = vertex_errors(candidates, weights, rest, targets)
    width = weights.shape[1]
    for _ in range(ITERATIONS):
        base = blended_points(candidates, weights, rest)
        residual = (base - targets).transpose(1, 0, 2).reshape(len(rest), -1)        # (C, 3E)
        jacobian = np.empty(residual.shape + (width,))
        for k in range(width):
            nudged = weights.copy()
            nudged[:, k] += STEP
            jacobian[..., k] = ((blended_points(candidates, nudged, rest) - base) / STEP).transpose(1, 0, 2) \
                .reshape(len(rest), -1)
        jacobian *= mask[:, None, :]
        normal = np.einsum("cri,crj->cij", jacobian, jacobian)
        damping = DAMPING * np.maximum(np.trace(normal, axis1=1, axis2=2) / width, 1e-30)
        # KKT system of min |J d + r|^2 subject to sum(d) = 0 (padding entries pinned to 0 by identity rows).
        system = np.zeros((len(rest), width + 1, width + 1))
        system[:, :width, :width] = normal + damping[:, None, None] * np.eye(width)
        system[:, :width, :width][~mask] = 0
        pinned = np.nonzero(~mask)
        system[pinned[0], pinned[1], pinned[1]] = 1
        system[:, :width, width] = system[:, width, :width] = mask
        rhs = np.zeros((len(rest), width + 1))
        rhs[:, :width] = -np.einsum("cri,cr->ci", jacobian, residual) * mask
        step = np.linalg.solve(system, rhs[..., None])[..., :width, 0]
        trial = project_to_simplex(weights + step, mask)
        trial_error = vertex_errors(candidates, trial, rest, targets)
        better = trial_error < error
        improved = np.where(better, trial_error, error)
        weights = np.where(better[:, None], trial, weights)
        converged = error.sum() - improved.sum() <= CONVERGED * error.sum()
        error = improved
        if converged:
            break
    return weights, error


def refit_dqs_weights(rest, frames, dual_quaternions, offsets, bones, weights, progress=None):
    """DQS weights on the pattern (offsets, bones) starting from weights (the LBS fit), for rest (V, 3), the
    examples frames (E, V, 3) and their bone dual quaternions (E, B, 8). Returns (offsets, bones, weights) with
    negligible influences dropped (every vertex keeps its largest). progress(fraction) may return True to cancel."""
    padded_bones, padded_weights, mask = padded_pattern(offsets, bones, weights)
    examples, width = len(frames), padded_bones.shape[1]
    chunk = max(1, CHUNK_VALUES // (examples * width * 8))
    fitted = np.empty_like(padded_weights)
    for start in range(0, len(rest), chunk):
        part = slice(start, start + chunk)
        candidates = dual_quaternions[:, padded_bones[part]]                           # (E, C, K, 8)
        # Sign-align each influence with the vertex's first one (the C blend aligns against the running sum,
        # which starts at the first influence).
        dots = (candidates[..., :1, :4] * candidates[..., :4]).sum(-1)
        candidates = candidates * np.where(dots < 0, -1.0, 1.0)[..., None]
        fitted[part], _ = refit_chunk(candidates, padded_weights[part], mask[part], rest[part], frames[:, part])
        if progress is not None and progress(min(1.0, (start + chunk) / len(rest))):
            raise SkinkitError("cancelled")
    keep = mask & (fitted > NEGLIGIBLE)
    keep[np.arange(len(rest)), np.argmax(np.where(mask, fitted, -1), axis=1)] = True
    kept = np.where(keep, fitted, 0)
    kept /= kept.sum(axis=1, keepdims=True)
    new_offsets = np.concatenate([[0], np.cumsum(keep.sum(axis=1))]).astype(np.int32)
    return new_offsets, padded_bones[keep].astype(np.int32), np.ascontiguousarray(kept[keep])
