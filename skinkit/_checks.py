"""What Python checks before an array reaches the C core: its shape and dtype, named by the parameter.

The rule (see model.py): Python checks shapes and dtypes and names the parameter; the C core checks values
(index ranges, orientation, degenerate input) and names the element. Python adds only what C cannot see:
units and vertex order (skinkit.fit.check_vertex_order), and finiteness, whose message here names the
parameter and the first bad index.
"""
from __future__ import annotations

import functools
import inspect
import os

import numpy as np

from ._core import Error as SkinkitError

__all__ = ["as_real_array", "as_index_array", "as_mask", "as_optional_index_array", "check_shape", "as_count",
           "as_real", "as_flag", "as_choice", "as_path", "as_callback", "count", "real", "choice", "optional", "checked",
           "THREADS", "FLAG", "CALLBACK", "PATH", "INPUT_FILE", "OUTPUT_FILE"]

#: The core's limits: counts and indices are int32, and it runs at most this many threads.
MAX_COUNT = 2**31 - 1
MAX_THREADS = 1024


def as_real_array(value, name: str, dtype=np.float64, shape: tuple | None = None) -> np.ndarray:
    """`value` as a C-contiguous array of `dtype`; `shape` entries of None match any length."""
    array = as_array(value, name)
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
    array = as_array(value, name)
    if array.size == 0:
        array = array.astype(np.int32)
    if array.dtype.kind not in "iu":
        raise SkinkitError(f"{name}: expected integers, got dtype {array.dtype}")
    check_shape(array, name, shape)
    if array.size and (array.min() < np.iinfo(np.int32).min or array.max() > np.iinfo(np.int32).max):
        raise SkinkitError(f"{name}: values do not fit in 32-bit integers")
    return np.ascontiguousarray(array, dtype=np.int32)


def as_array(value, name: str) -> np.ndarray:
    try:
        return np.asarray(value)
    except Exception as exc:  # noqa: BLE001 - ragged lists, objects numpy cannot read: the caller's mistake
        raise SkinkitError(f"{name}: not an array ({exc})") from None


def as_mask(value, name: str, length: int) -> np.ndarray:
    """`value` as a (length,) bool array (one flag per item)."""
    array = as_array(value, name)
    if array.dtype != bool or array.shape != (length,):
        raise SkinkitError(f"{name}: expected {length} True/False flags, got dtype {array.dtype} shape {array.shape}")
    return array


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


# ---- scalars and objects ------------------------------------------------------------------------------------------
# Python checks them because the binding's own argument errors are TypeErrors and OverflowErrors that name the C
# parameter, and because numpy turns a wrong scalar into an error from deep inside (a string threshold, a NaN count).

def shown(value) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def as_count(value, name: str, minimum: int = 0, maximum: int = MAX_COUNT) -> int:
    """A whole number in [minimum, maximum] (a bool or a float is refused: 2.5 bones is a mistake)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise SkinkitError(f"{name}: expected a whole number, got {type(value).__name__} {shown(value)}")
    if int(value) < minimum:
        raise SkinkitError(f"{name}: must be at least {minimum}, got {int(value)}")
    if int(value) > maximum:
        raise SkinkitError(f"{name}: must be at most {maximum}, got {int(value)}")
    return int(value)


def as_real(value, name: str, minimum: float | None = None, maximum: float | None = None,
            above: float | None = None) -> float:
    """A finite real number, at least `minimum`, at most `maximum`, greater than `above` (those given)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise SkinkitError(f"{name}: expected a number, got {type(value).__name__} {shown(value)}")
    number = float(value)
    if not np.isfinite(number):
        raise SkinkitError(f"{name}: expected a finite number, got {number}")
    if (minimum is not None and number < minimum) or (maximum is not None and number > maximum) or \
            (above is not None and number <= above):
        bounds = [f">= {minimum}" if minimum is not None else "", f"<= {maximum}" if maximum is not None else "",
                  f"> {above}" if above is not None else ""]
        raise SkinkitError(f"{name}: expected a number {' and '.join(b for b in bounds if b)}, got {number}")
    return number


def as_flag(value, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise SkinkitError(f"{name}: expected True or False, got {type(value).__name__} {shown(value)}")
    return bool(value)


def as_choice(value, name: str, choices) -> str:
    if not isinstance(value, str) or value not in choices:
        raise SkinkitError(f"{name}: expected one of {list(choices)}, got {shown(value)}")
    return value


def as_path(value, name: str) -> str:
    if not isinstance(value, (str, os.PathLike)):
        raise SkinkitError(f"{name}: expected a file path, got {type(value).__name__} {shown(value)}")
    path = os.fspath(value)
    if not isinstance(path, str) or not path or "\0" in path:
        raise SkinkitError(f"{name}: {shown(path)} is not a usable path")
    return path


def as_input_file(value, name: str) -> str:
    """A path to an existing regular file (what a reader opens)."""
    path = as_path(value, name)
    if not os.path.isfile(path):
        raise SkinkitError(f"{name}: {shown(path)} is not a file" if os.path.exists(path) else
                           f"{name}: {shown(path)} does not exist")
    return path


def as_output_file(value, name: str) -> str:
    """A path a writer can create: its folder exists and is writable, and it is not a folder itself."""
    path = as_path(value, name)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
        raise SkinkitError(f"{name}: the folder {shown(folder)} does not exist or is not writable")
    if os.path.isdir(path):
        raise SkinkitError(f"{name}: {shown(path)} is a folder, not a file")
    return path


def as_callback(value, name: str):
    """None, or a function skinkit can call with one argument (the fraction done)."""
    if value is None:
        return None
    if not callable(value):
        raise SkinkitError(f"{name}: expected a function called with the fraction done, or None, got "
                           f"{type(value).__name__} {shown(value)}")
    try:
        inspect.signature(value).bind(0.5)
    except TypeError:
        raise SkinkitError(f"{name}: must take one argument, the fraction done") from None
    except ValueError:  # a builtin without a signature: it is the caller's to know
        pass
    return value


def as_instance(value, name: str, kinds):
    if not isinstance(value, kinds):
        wanted = " or ".join(k.__name__ for k in (kinds if isinstance(kinds, tuple) else (kinds,)))
        raise SkinkitError(f"{name}: expected a {wanted}, got {type(value).__name__} {shown(value)}")
    return value


# ---- rules for `checked` -------------------------------------------------------------------------------------------

def count(minimum: int = 0, maximum: int = MAX_COUNT):
    return lambda value, name: as_count(value, name, minimum, maximum)


def real(minimum: float | None = None, maximum: float | None = None, above: float | None = None):
    return lambda value, name: as_real(value, name, minimum, maximum, above)


def choice(choices):
    return lambda value, name: as_choice(value, name, choices)


def optional(rule):
    """None, or what `rule` accepts."""
    return lambda value, name: None if value is None else apply_rule(rule, value, name)


THREADS = count(0, MAX_THREADS)  # 0: one per core
FLAG = as_flag
CALLBACK = as_callback
PATH = as_path
INPUT_FILE = as_input_file
OUTPUT_FILE = as_output_file


def apply_rule(rule, value, name: str):
    if isinstance(rule, type) or isinstance(rule, tuple):
        return as_instance(value, name, rule)
    return rule(value, name)


def checked(**rules):
    """Checks a public function's arguments before its body runs: each keyword names a parameter and its rule, a
    class (or tuple of classes) the value must be an instance of, or a function (value, name) -> the value to use
    that raises SkinkitError naming the parameter. Arguments left at their defaults are not checked."""
    def decorate(function):
        signature = inspect.signature(function)
        unknown = set(rules) - set(signature.parameters)
        if unknown:
            raise TypeError(f"{function.__qualname__} has no parameters {sorted(unknown)}")

        @functools.wraps(function)
        def wrapper(*args, **kwargs):
            bound = signature.bind(*args, **kwargs)
            for name, rule in rules.items():
                if name in bound.arguments:
                    bound.arguments[name] = apply_rule(rule, bound.arguments[name], name)
            return function(*bound.args, **bound.kwargs)

        return wrapper

    return decorate


# ---- memory ---------------------------------------------------------------------------------------------------------
# A big allocation is estimated before it is made and refused with what it needs, what is available and how to need
# less: better than Blender killed for memory half-way through. The budget is the memory free now, or less where a
# limit is set (memory_limit: a farm node shared with other jobs).

_LIMIT = {"bytes": None}


def set_memory_limit(limit_bytes: int | None) -> None:
    """The most memory (bytes) one skinkit operation may plan to use in this process; None: what is free."""
    _LIMIT["bytes"] = None if limit_bytes is None else as_count(limit_bytes, "memory_limit", 1, 2**62)


def memory_limit() -> int | None:
    return _LIMIT["bytes"]


def available_memory() -> int:
    """Bytes of memory free for use now (MemAvailable), or the physical memory where that is unknown."""
    try:
        with open("/proc/meminfo") as file:
            for line in file:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return 2**62


def memory_budget() -> tuple[int, str]:
    """(bytes, where the number comes from)."""
    free = available_memory()
    limit = memory_limit()
    if limit is not None and limit < free:
        return limit, "the memory limit"
    return free, "free memory"


def size_text(nbytes: float) -> str:
    if nbytes >= 2**27:
        return f"{nbytes / 2**30:.2f} GiB"
    return f"{nbytes / 2**20:.1f} MiB" if nbytes >= 2**20 else f"{nbytes / 2**10:.1f} KiB"


def check_memory(needed_bytes: float, what: str, how_to_reduce: str) -> None:
    """Refuses, before allocating, an operation whose estimate `needed_bytes` exceeds the budget."""
    budget, source = memory_budget()
    if needed_bytes > budget:
        raise SkinkitError(f"{what} would need about {size_text(needed_bytes)} of memory, but {size_text(budget)} is "
                           f"available ({source}): {how_to_reduce}")


# ---- unit disagreements ------------------------------------------------------------------------------

#: Two inputs meant to be one mesh whose bounding boxes differ by more than this factor are taken to use different
#: units (a pose stretches a box far less; FBX files often store centimetres where Alembic stores metres: 100x).
SCALE_MISMATCH_FACTOR = 3.0


def bounding_size(positions) -> np.ndarray:
    """The bounding-box diagonal of (V, 3) positions, or of each of (..., V, 3)."""
    positions = np.asarray(positions, dtype=np.float64)
    return np.linalg.norm(positions.max(axis=-2) - positions.min(axis=-2), axis=-1)


def units_sentence(what: str, ratio: float, reference: str, remedy: str = "") -> str:
    """The one wording of a unit disagreement, used by every check that compares two inputs' sizes."""
    return (f"{what} is {ratio:.3g} times the size of {reference}: the files use different units or scales"
            + (f"; {remedy}" if remedy else ""))


def check_same_units(reference_positions, frames, what: str, reference: str, remedy: str = "") -> None:
    """Refuses frames (F, V, 3) whose size is not within SCALE_MISMATCH_FACTOR of the reference mesh's (V, 3); `what`
    names the frames (with {index} for the first one off) and `remedy` says what to do."""
    sizes = bounding_size(frames)
    ratios = sizes / max(float(bounding_size(reference_positions)), 1e-300)
    for index in np.flatnonzero(~((1 / SCALE_MISMATCH_FACTOR < ratios) & (ratios < SCALE_MISMATCH_FACTOR)))[:1]:
        raise SkinkitError(units_sentence(what.format(index=index), float(ratios[index]), reference, remedy))
