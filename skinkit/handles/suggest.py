"""Control points from the examples (section 2.3, after Meyer & Anderson): PCA of the vertex positions over the
examples, a varimax rotation that localises each component, and the two extreme vertices of each rotated
component."""
from __future__ import annotations

import numpy as np

from .. import _core
from .._checks import SkinkitError, as_real_array, checked, count


@checked(count=count(1))
def suggest_handles(frames, count: int) -> np.ndarray:
    """`count` control-point vertex indices for frames (F, V, 3): ceil(count / 2) principal components of the
    positions, varimax-rotated; per component the vertex whose loading is largest along the component's main
    direction and the one whose loading is smallest ("two representative points with largest differences"),
    skipping vertices already chosen (sk_suggest_handles)."""
    frames = as_real_array(frames, "frames", shape=(None, None, 3))
    if len(frames) == 0:
        raise SkinkitError("frames: no frames to choose handles from")
    if not 1 <= count <= frames.shape[1]:
        raise SkinkitError(f"handle count {count}: must be between 1 and the vertex count ({frames.shape[1]})")
    chosen = np.empty(count, np.int32)
    try:
        _core.suggest_handles(chosen, frames, len(frames), frames.shape[1])
    except SkinkitError as error:
        raise SkinkitError(f"frames: {error}") from None
    return chosen
