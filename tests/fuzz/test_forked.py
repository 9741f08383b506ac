"""The fuzz passes' batch runner (tests/fuzz/forked.py): a call that kills its child or runs past the CPU time
limit is named, and the pass goes on after it; events and refusals reach the parent."""
import os
import signal

from tests.fuzz import forked


def test_a_crash_and_a_hang_are_named_and_the_calls_after_them_made():
    def call(index):
        if index == 3:
            os.kill(os.getpid(), signal.SIGSEGV)
        if index == 6:
            while True:  # spins: CPU time runs past the limit
                pass
        return (f"event {index}" if index % 4 == 0 else None), index % 2

    events, ends, index = [], [], 0
    while index < 10:
        end = forked.run_batch(call, index, 10 - index, 0.5, events.append)
        ends.append((end.last, end.ending, end.finished, end.refused, end.signal))
        index = end.last + 1
    assert ends == [(3, "crash", 3, 1, signal.SIGSEGV), (6, "hang", 2, 1, 0), (9, "done", 3, 2, 0)]
    assert events == ["event 0", "event 4", "event 8"]


def test_what_a_library_prints_is_captured_in_the_child():
    def prepare():
        printed.append(forked.capture_stdout())

    def call(index):
        os.write(1, b"On entry to DLASCL parameter number 4 had an illegal value\n" if index == 1 else b"")
        return (printed[0]() or None), 0

    printed, events = [], []
    end = forked.run_batch(call, 0, 3, 5.0, events.append, prepare)
    assert end.ending == "done" and end.finished == 3
    assert events == ["On entry to DLASCL parameter number 4 had an illegal value"]
