"""The generated binding (scripts/gen_bindings.py, scripts/binding_spec.py): the checked-in files are current, the
struct form of the groups compiles, and every function refuses bad buffers and sizes before the C call, driven
from the spec."""
import ast
import inspect
import os
import re
import shutil
import subprocess
import sys
import sysconfig

import numpy as np
import pytest

from skinkit import _core

from tests.conftest import ROOT
sys.path.insert(0, os.path.join(ROOT, "scripts"))
import gen_bindings  # noqa: E402

SPEC = gen_bindings.load_spec(gen_bindings.SPEC)
FUNCTIONS = {f.name: f for f in SPEC.FUNCTIONS}
SAMPLE_COUNT = 2  # every count of the well-formed calls below
DTYPES = {"d": np.float64, "f": np.float32, "df": np.float64, "i": np.int32, "B": np.uint8, "H": np.uint16}
WRONG_DTYPES = {"d": np.float32, "f": np.float64, "df": np.int32, "i": np.int64, "B": np.float64,
                "H": np.int16}


def is_array(argument) -> bool:
    return hasattr(argument, "types")


def length(argument, counts=None) -> int:
    size = gen_bindings.Size.parse(argument.size)
    value = size.factor
    for count in size.counts:
        value *= (counts or {}).get(count, SAMPLE_COUNT)
    return value + size.bias


def well_formed(function) -> dict:
    """Arguments the binding accepts (all counts SAMPLE_COUNT); the C core may still refuse their values."""
    values = {}
    for a in function.arguments:
        if is_array(a):
            values[a.name] = np.zeros(length(a), DTYPES[a.types])
        else:
            values[a.name] = {"size": SAMPLE_COUNT, "real": 0.0, "integer": max(a.minimum, 0), "flag": False,
                              "progress": None}[a.kind]
    return values


def call(function, values):
    return getattr(_core, function.name)(**values)


def length_is_constrained(function, index) -> bool:
    """False for an array whose length alone sets a count nothing else uses (core_vertices: core_count)."""
    rule = next(r for r in gen_bindings.size_rules(function) if r.argument == index)
    others = [a.size for i, a in enumerate(function.arguments) if is_array(a) and i != index]
    return rule.derives is None or rule.size.factor > 1 or any(rule.derives in size for size in others)


ALL = sorted(FUNCTIONS)
ARRAYS = [(f, a.name) for f in ALL for a in FUNCTIONS[f].arguments if is_array(a)]
CONSTRAINED = [(f, a.name) for f in ALL for i, a in enumerate(FUNCTIONS[f].arguments)
               if is_array(a) and length_is_constrained(FUNCTIONS[f], i)]
DESTINATIONS = [(f, a) for f, a in ARRAYS if next(x for x in FUNCTIONS[f].arguments if x.name == a).role != "in"]
SIZES = [(f, a.name) for f in ALL for a in FUNCTIONS[f].arguments if getattr(a, "kind", "") == "size"]


def argument(function_name, name):
    return next(a for a in FUNCTIONS[function_name].arguments if a.name == name)


# ---- the generated files ------------------------------------------------------------------------------------------

def test_checked_in_files_are_what_the_generator_writes(tmp_path):
    gen_bindings.generate(str(tmp_path))
    for relative in (gen_bindings.C_OUTPUT, gen_bindings.STUB_OUTPUT):
        with open(os.path.join(ROOT, relative)) as checked_in, open(tmp_path / relative) as generated:
            assert checked_in.read() == generated.read(), f"{relative} is stale: run `make bindings`"


def test_every_c_entry_point_is_bound_under_its_c_name():
    with open(os.path.join(ROOT, "csrc", "skinkit.h")) as header:
        declared = set(re.findall(r"^(?:SK_EXPERIMENTAL )?sk_status (sk_\w+)\(", header.read(), re.MULTILINE))
    bound = {re.sub(r"_f(32|64)$", "", name).removeprefix("sk_") for name in declared} - {"lsqr"}
    assert bound == {f.name for f in SPEC.FUNCTIONS if not f.test_helper}
    assert all(callable(getattr(_core, name)) for name in FUNCTIONS)


def test_stubs_and_signatures_follow_the_spec():
    with open(os.path.join(ROOT, gen_bindings.STUB_OUTPUT)) as stubs:
        tree = ast.parse(stubs.read())
    stubbed = {node.name: [arg.arg for arg in node.args.args] for node in tree.body
               if isinstance(node, ast.FunctionDef)}
    for name, function in FUNCTIONS.items():
        parameters = [a.name for a in function.arguments]
        assert stubbed[name] == parameters
        assert list(inspect.signature(getattr(_core, name)).parameters) == parameters
        assert function.doc.split()[0] in getattr(_core, name).__doc__


# ---- refusals, for every function of the spec -----------------------------------------------------------------------

def refuses(function_name, name, replace, error, match):
    """The function, called well formed but for the argument `name` (replace(value) -> the bad value), raises."""
    values = well_formed(FUNCTIONS[function_name])
    values[name] = replace(values[name])
    with pytest.raises(error, match=match):
        call(FUNCTIONS[function_name], values)


@pytest.mark.parametrize("function_name, name", CONSTRAINED)
def test_wrong_length_is_refused(function_name, name):
    refuses(function_name, name, lambda array: np.zeros(len(array) + 1, array.dtype), ValueError, "elements")


@pytest.mark.parametrize("function_name, name", ARRAYS)
def test_wrong_dtype_is_refused(function_name, name):
    wrong = WRONG_DTYPES[argument(function_name, name).types]
    refuses(function_name, name, lambda array: array.astype(wrong), TypeError, f"{name} has element type")


@pytest.mark.parametrize("function_name, name", ARRAYS)
def test_non_contiguous_array_is_refused(function_name, name):
    if length(argument(function_name, name)) < 2:
        pytest.skip("a length of 0 or 1 is contiguous whatever the stride")
    refuses(function_name, name, lambda array: np.zeros(2 * len(array), array.dtype)[::2], TypeError,
            f"{name} must be a C-contiguous")


def read_only(array):
    array.flags.writeable = False
    return array


@pytest.mark.parametrize("function_name, name", DESTINATIONS)
def test_read_only_destination_is_refused(function_name, name):
    refuses(function_name, name, read_only, TypeError, f"{name} must be a C-contiguous writable array")


@pytest.mark.parametrize("function_name, name", SIZES)
def test_negative_size_is_refused(function_name, name):
    refuses(function_name, name, lambda size: -1, ValueError, f"{name} must (not be negative|be at least)")


MULTIPLIED_SIZES = [(f, s) for f, s in SIZES
                    if any(is_array(a) and s in a.size and "*" in a.size for a in FUNCTIONS[f].arguments)]


@pytest.mark.parametrize("function_name, name", MULTIPLIED_SIZES)
def test_a_size_whose_product_would_wrap_around_is_refused(function_name, name):
    """16 * 2**61 and the like do not fit in a size_t: refused, not wrapped around to a small size."""
    refuses(function_name, name, lambda size: 2**62, ValueError, "overflows|not a multiple|elements")


def test_overflow_names_the_array():
    values = well_formed(FUNCTIONS["fit_per_vertex"])
    values["example_count"] = 2**61
    with pytest.raises(ValueError, match=r"poses: its size 16\*example_count\*bone_count overflows"):
        _core.fit_per_vertex(**values)
    values = well_formed(FUNCTIONS["lsqr_dense_matrix"])
    values["x"], values["cols"], values["rows"] = np.zeros(4), 4, 2**62
    with pytest.raises(ValueError, match=r"matrix: its size rows\*cols overflows"):
        _core.lsqr_dense_matrix(**values)


def test_a_missing_or_unknown_argument_is_a_type_error():
    values = well_formed(FUNCTIONS["linear_norms"])
    with pytest.raises(TypeError, match="missing argument 'matrices'"):
        _core.linear_norms(values["destination"])
    with pytest.raises(TypeError, match="unexpected keyword"):
        _core.linear_norms(**values, extra=1)
    with pytest.raises(TypeError, match="takes 2 arguments"):
        _core.linear_norms(*values.values(), 3)
    with pytest.raises(TypeError, match="two values for 'matrices'"):
        _core.linear_norms(values["destination"], values["matrices"], matrices=values["matrices"])


def test_thread_count_and_ranges_are_checked():
    values = well_formed(FUNCTIONS["animation_space_evaluate"])
    for bad in (-1, SPEC.THREAD_LIMIT + 1):
        values["thread_count"] = bad
        with pytest.raises(ValueError, match="thread_count must be between 0 and"):
            _core.animation_space_evaluate(**values)
    values["thread_count"] = 1.5
    with pytest.raises(TypeError, match="thread_count must be an integer"):
        _core.animation_space_evaluate(**values)


# ---- results -----------------------------------------------------------------------------------------------------

def test_results_are_none_or_dicts_with_named_keys():
    triangles = np.array([0, 1, 2, 0, 2, 3], np.int32)
    cut, source = np.empty(6, np.int32), np.empty(6, np.int32)
    assert _core.validate_triangles(triangles, 4) is None
    assert _core.cut_along_seams(cut, source, triangles, np.array([0, 2], np.int32), 4) == {"cut_vertex_count": 6}
    uv = np.array([0, 0, 1, 0, 0, 1], float)
    stretch = _core.mesh_stretch(uv, np.array([1.0, 2.0, 1.0]))
    assert stretch == {"stretch": pytest.approx(1.0)}


def test_flatten_checks_corners_against_the_vertex_count():
    values = well_formed(FUNCTIONS["flatten"])
    values["corners"] = np.zeros(SAMPLE_COUNT + 1, np.uint8)
    with pytest.raises(ValueError, match=r"corners has 3 elements, expected 2 \(vertex_count\)"):
        _core.flatten(**values)
