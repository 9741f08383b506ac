"""Control points from the examples (section 2.3, after Meyer & Anderson): PCA of the vertex positions over the
examples, a varimax rotation that localises each component, and the two extreme vertices of each rotated
component."""
from __future__ import annotations

import numpy as np

from .._checks import SkinkitError, as_real_array

VARIMAX_ITERATIONS = 100
VARIMAX_TOLERANCE = 1e-8


def varimax(loadings: np.ndarray, iterations: int = VARIMAX_ITERATIONS, tolerance: float = VARIMAX_TOLERANCE):
    """Kaiser's varimax rotation of loadings (p, k): the orthogonal rotation maximising the variance of the
    squared loadings per column, which concentrates each component on few variables (here: few vertices)."""
    p, k = loadings.shape
    rotation = np.eye(k)
    objective = 0.0
    for _ in range(iterations):
        rotated = loadings @ rotation
        gradient = loadings.T @ (rotated ** 3 - rotated @ np.diag((rotated ** 2).sum(axis=0)) / p)
        u, s, vt = np.linalg.svd(gradient)
        rotation = u @ vt
        if s.sum() < objective * (1 + tolerance):
            break
        objective = s.sum()
    return loadings @ rotation


def suggest_handles(frames, count: int) -> np.ndarray:
    """`count` control-point vertex indices for frames (F, V, 3): ceil(count / 2) principal components of the
    positions, varimax-rotated; per component the vertex whose loading is largest along the component's main
    direction and the one whose loading is smallest ("two representative points with largest differences"),
    skipping vertices already chosen."""
    frames = as_real_array(frames, "frames", shape=(None, None, 3))
    if count < 1 or count > frames.shape[1]:
        raise SkinkitError(f"handle count {count}: must be between 1 and the vertex count ({frames.shape[1]})")
    components = (count + 1) // 2
    if len(frames) < components + 1:
        raise SkinkitError(f"frames: {len(frames)} examples; suggesting {count} handles needs at least "
                           f"{components + 1} (one more than the {components} components)")
    data = frames.reshape(len(frames), -1)
    data = data - data.mean(axis=0)
    _, singular, vt = np.linalg.svd(data, full_matrices=False)
    if singular[0] <= 0:
        raise SkinkitError("frames: the examples do not move, so there is nothing to place handles on")
    loadings = varimax(vt[:components].T * singular[:components])
    chosen: list[int] = []
    for component in loadings.T:
        per_vertex = component.reshape(-1, 3)
        direction = np.linalg.svd(per_vertex, full_matrices=False)[2][0]
        score = per_vertex @ direction
        for order in (np.argsort(-score), np.argsort(score)):
            pick = next(int(v) for v in order if int(v) not in chosen)
            chosen.append(pick)
            if len(chosen) == count:
                return np.array(chosen, np.int32)
    return np.array(chosen, np.int32)
