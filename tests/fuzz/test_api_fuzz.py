"""A short seeded pass of the public API fuzzer (`make fuzz` runs the long one): every public function and method
of the numpy API, called with malformed arguments, answers with a result or a SkinkitError, never a raw exception
from deep inside, and no call runs past the fuzzer's time limit."""
import signal

import pytest

from tests.fuzz import api_fuzz
from tests.fuzz.family_entries import NEEDS_BLENDER

SMOKE_CALLS = 40
CALL_TIME_LIMIT = 20  # seconds, as in the fuzzer: a valid call here takes milliseconds


@pytest.fixture(scope="module")
def fixture(tmp_path_factory):
    return api_fuzz.Fixture(str(tmp_path_factory.mktemp("api_fuzz")))


class Hang(Exception):
    pass


def outcomes_of(entry, fixture, calls):
    """(index, changed arguments, outcome) of the entry's first calls, each stopped by an alarm past the limit."""
    def stop(signum, frame):
        raise Hang(f"call ran past {CALL_TIME_LIMIT} s")

    previous = signal.signal(signal.SIGALRM, stop)
    outcomes = []
    try:
        for index in range(calls):
            function, arguments, changed = api_fuzz.generate(entry, 7, index, fixture)
            signal.alarm(CALL_TIME_LIMIT)
            try:
                outcomes.append((index, changed, api_fuzz.outcome_of(entry, function, arguments)))
            finally:
                signal.alarm(0)
    finally:
        signal.signal(signal.SIGALRM, previous)
    return outcomes


def test_every_public_function_and_method_has_an_entry():
    """A public function added without a fuzz entry fails here: the harness grows with the API."""
    assert api_fuzz.public_surface() - NEEDS_BLENDER == set(api_fuzz.ENTRIES)


@pytest.mark.parametrize("entry", sorted(api_fuzz.ENTRIES))
def test_hostile_calls_get_a_skinkit_error(entry, fixture):
    """In this process (the binding fuzzer covers crashes): each call's outcome is a result or a SkinkitError."""
    outcomes = outcomes_of(entry, fixture, SMOKE_CALLS)
    raw = [o for o in outcomes if o[2].startswith("raw ")]
    assert not raw, f"replay with python -m tests.fuzz.api_fuzz --seed 7 --call {entry} INDEX: {raw[:3]}"
    takes_arguments = bool(api_fuzz.ENTRIES[entry](fixture)[1])
    assert any(o[2] == "refused" for o in outcomes) or not takes_arguments  # the mutations reach the checks

