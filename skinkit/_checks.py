"""What Python checks before an array reaches the C core: its shape and dtype, named by the parameter.

The rule (see model.py): Python checks shapes and dtypes and names the parameter; the C core checks values
(index ranges, orientation, degenerate input) and names the element. Python adds only what C cannot see:
units and vertex order (skinkit.fit.check_vertex_order), and finiteness, whose message here names the
parameter and the first bad index.
"""
from __future__ import annotations

import numpy as np

from ._core import Error as SkinkitError

__all__ = ["as_real_array", "as_index_array", "as_optional_index_array", "check_shape"]


def as_real_array(value, name: str, dtype=np.float64, shape: tuple | None = None) -> np.ndarray:
    """`value` as a C-contiguous array of `dtype`; `shape` entries of None match any length."""
    try:
        array = np.asarray(value)
    except Exception as exc:  # ragged lists and the like
        raise SkinkitError(f"{name}: not an array ({exc})") from None
    if array.dtype.kind not in "fiu":
        raise SkinkitError(f"{name}: expected real numbers, got dtype {array.dtype}")
    check_shape(array, name, shape)
    array = np.ascontiguousarray(array, dtype=dtype)
    if not np.isfinite(array).all():
        bad = np.argwhere(~np.isfinite(array))[0]
        raise SkinkitError(f"{name}: contains NaN or infinity (first at index {tuple(int(i) for i in bad)})")
    return array


def as_index_array(value, name: str, shape: tuple | None = None) -> np.ndarray:
    """`value` as a C-contiguous int32 array; refuses fractions and values that do not fit in int32."""
    array = np.asarray(value)
    if array.size == 0:
        array = array.astype(np.int32)
    if array.dtype.kind not in "iu":
        raise SkinkitError(f"{name}: expected integers, got dtype {array.dtype}")
    check_shape(array, name, shape)
    if array.size and (array.min() < np.iinfo(np.int32).min or array.max() > np.iinfo(np.int32).max):
        raise SkinkitError(f"{name}: values do not fit in 32-bit integers")
    return np.ascontiguousarray(array, dtype=np.int32)


def as_optional_index_array(value, name: str, shape: tuple | None = None) -> np.ndarray | None:
    """None for an optional argument left out, else `value` checked as by as_index_array."""
    return None if value is None else as_index_array(value, name, shape)


def check_shape(array: np.ndarray, name: str, shape: tuple | None) -> None:
    if shape is None:
        return
    matches = array.ndim == len(shape) and all(want is None or want == got for want, got in zip(shape, array.shape))
    if not matches:
        wanted = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise SkinkitError(f"{name}: expected shape {wanted}, got {array.shape}")
