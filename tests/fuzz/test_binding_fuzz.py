"""A short seeded pass of the binding fuzzer (`make fuzz` runs the long one): no hostile call to any skinkit._core
entry point kills the process, hangs or makes LAPACK complain."""
import pytest

from tests.fuzz import binding_fuzz

SMOKE_CALLS = 200


@pytest.mark.parametrize("function_name", sorted(binding_fuzz.FUNCTIONS))
def test_hostile_calls_neither_crash_nor_hang(function_name, tmp_path):
    outcome = binding_fuzz.fuzz_function(function_name, SMOKE_CALLS, seed=7, out_dir=str(tmp_path),
                                         time_limit=binding_fuzz.CALL_TIME_LIMIT)
    assert outcome.calls == SMOKE_CALLS
    failures = outcome.crashes + outcome.hangs + outcome.complaints
    assert not failures, f"reproducers (python -m tests.fuzz.binding_fuzz --replay FILE): {failures}"


def test_every_core_entry_point_has_a_generator():
    """The generators come from the binding spec: an entry point of skinkit._core the spec does not describe (one
    added by hand, or a spec entry the module lost) fails here."""
    from skinkit import _core

    entry_points = {name for name in dir(_core) if not name.startswith("_") and callable(getattr(_core, name))}
    assert entry_points - {"Error"} == set(binding_fuzz.FUNCTIONS)
    for name in binding_fuzz.FUNCTIONS:  # every argument kind of the spec has a value
        assert set(binding_fuzz.generate(name, 7, 0)) <= {a.name for a in binding_fuzz.FUNCTIONS[name].arguments}


def test_the_generated_calls_reach_the_core():
    """Most calls must get past the binding's argument checks, or the pass tests only those checks."""
    from skinkit import _core

    reached = total = 0
    for name in sorted(binding_fuzz.FUNCTIONS):
        for index in range(50):
            total += 1
            try:
                getattr(_core, name)(**binding_fuzz.generate(name, 7, index))
                reached += 1
            except _core.Error:
                reached += 1  # refused by the C core: it looked at the values
            except (TypeError, ValueError, OverflowError, MemoryError):
                pass
    assert reached / total > 0.4
