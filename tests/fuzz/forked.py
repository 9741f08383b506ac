"""Batches of fuzz calls in forked children: a signal or a hang in a call is caught by the parent, which knows the
call, and the pass goes on after it.

The parent has imported skinkit and made its inputs once; each batch is a fork of it, so a batch costs no start-up
(the subprocess per batch of the first harness spent ~0.3 s CPU importing numpy and skinkit for every 500 calls,
more than the calls themselves on most entry points). The child writes the index of the call it is making, and
how many calls it has finished, into a page shared with the parent, with no system call per call; it writes a line
to a pipe only for an event worth keeping (a raw exception, a library's complaint) and at the end of the batch. The
parent watches the pipe: end of file without the final line is a crash of the call the shared page names; no
progress within the time limit is a hang of that call, and the child is killed.

The skinkit core keeps no thread pool (csrc/common/sk_parallel.c joins its workers before returning) and OpenBLAS
drops its pool at a fork, so a fork of the parent is as good as a fresh interpreter for these calls.
"""
from __future__ import annotations

import mmap
import os
import select
import signal
import struct
import sys
import time
from dataclasses import dataclass

STARTED, FINISHED, REFUSED = 0, 8, 16  # offsets of three int64 in the shared page
POLL_SECONDS = 0.5
#: A call that holds no CPU (a deadlock, a sleep) is a hang after this many times the time limit in wall seconds.
WALL_FACTOR = 6
#: A poll this late means the parent itself did not run (stopped to make room for another job): the wall clock of
#: that gap is not counted against the call.
SUSPENDED_SECONDS = 20


@dataclass
class BatchEnd:
    last: int  # the index of the last call started (start - 1 if none)
    ending: str  # "done", "crash" or "hang"
    finished: int  # calls that returned or raised
    refused: int  # of those, calls the child counted as refused (what an entry point should answer)
    signal: int = 0  # the signal that ended a crashed child, or 0 for an exit status
    status: int = 0


def _child(call, start: int, count: int, shared: mmap.mmap, pipe: int, prepare) -> None:
    """The forked child: prepare(), then the calls; never returns (os._exit, so that nothing of the parent's runs
    at exit: atexit handlers, buffered output, pytest's machinery)."""
    try:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        prepare()
        refused = 0
        for index in range(start, start + count):
            struct.pack_into("q", shared, STARTED, index)
            event, was_refused = call(index)
            refused += was_refused
            struct.pack_into("qq", shared, FINISHED, index - start + 1, refused)
            if event:
                os.write(pipe, (event.replace("\n", " ") + "\n").encode(errors="backslashreplace"))
        os.write(pipe, b"done\n")
    except BaseException as error:  # noqa: BLE001 - the harness's own failure: said on the pipe, then exit
        try:
            os.write(pipe, f"harness {type(error).__name__}: {error}\n".encode(errors="backslashreplace"))
        finally:
            os._exit(3)
    os._exit(0)


def run_batch(call, start: int, count: int, time_limit: float, on_event, prepare=lambda: None) -> BatchEnd:
    """Makes calls start .. start+count-1 in a forked child. call(index) -> (event text or None, 1 if refused else
    0) runs in the child; on_event(text) hears each event in the parent. A harness error in the child (not a
    call's: call catches those) is raised here."""
    shared = mmap.mmap(-1, mmap.PAGESIZE)
    struct.pack_into("qqq", shared, 0, start - 1, 0, 0)
    read_end, write_end = os.pipe()
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:
        os.close(read_end)
        _child(call, start, count, shared, write_end, prepare)
    os.close(write_end)
    try:
        return _watch(pid, read_end, shared, start, time_limit, on_event)
    finally:
        os.close(read_end)
        shared.close()


def run_batches(call, start: int, calls: int, batch_size: int, time_limit: float, on_event, on_failure,
                prepare=lambda: None) -> tuple[int, int, float]:
    """Calls start .. start+calls-1 in forked children of batch_size calls each; after a crash or a hang,
    on_failure(batch) saves its reproducer and the pass goes on after the call that failed. (calls made, calls
    refused, the children's CPU seconds)."""
    made = refused = 0
    cpu = os.times()
    index, end = start, start + calls
    while index < end:
        batch = run_batch(call, index, min(batch_size, end - index), time_limit, on_event, prepare)
        made += batch.finished
        refused += batch.refused
        if batch.ending != "done":
            made += 1
            on_failure(batch)
        index = batch.last + 1
    after = os.times()
    return made, refused, after.children_user + after.children_system - cpu.children_user - cpu.children_system


def _watch(pid: int, read_end: int, shared: mmap.mmap, start: int, time_limit: float, on_event) -> BatchEnd:
    pending = b""
    done = False
    harness = None
    progress = struct.unpack_from("qq", shared, STARTED)
    moved, moved_cpu = time.monotonic(), cpu_seconds(pid)
    polled = moved
    while True:
        readable = select.select([read_end], [], [], POLL_SECONDS)[0]
        if readable:
            data = os.read(read_end, 65536)
            if not data:
                break
            pending += data
            *lines, pending = pending.split(b"\n")
            for line in lines:
                text = line.decode(errors="backslashreplace")
                if text == "done":
                    done = True
                elif text.startswith("harness "):
                    harness = text
                else:
                    on_event(text)
        now_progress, now = struct.unpack_from("qq", shared, STARTED), time.monotonic()
        if now - polled > SUSPENDED_SECONDS:  # this process was stopped (SIGSTOP, a suspended job): not the call's time
            moved += now - polled
        polled = now
        if now_progress != progress:
            progress, moved, moved_cpu = now_progress, time.monotonic(), cpu_seconds(pid)
        elif cpu_seconds(pid) - moved_cpu > time_limit or time.monotonic() - moved > WALL_FACTOR * time_limit:
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            last, finished, refused = struct.unpack_from("qqq", shared, 0)
            return BatchEnd(last, "hang", finished, refused)
    _, status = os.waitpid(pid, 0)
    last, finished, refused = struct.unpack_from("qqq", shared, 0)
    if harness:
        raise RuntimeError(f"the fuzz child failed outside the calls: {harness}")
    if done and os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0:
        return BatchEnd(last, "done", finished, refused)
    return BatchEnd(last, "crash", finished, refused, os.WTERMSIG(status) if os.WIFSIGNALED(status) else 0,
                    os.WEXITSTATUS(status) if os.WIFEXITED(status) else 0)


def cpu_seconds(pid: int) -> float:
    """The CPU seconds a child has used (user + system, from /proc): a call's time limit is CPU time, so that a
    loaded machine does not turn a slow call into a hang. 0 where /proc cannot be read (the wall limit remains)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as file:
            fields = file.read().rsplit(b")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


def capture_stdout():
    """In a child: fd 1 into a temporary file, and a function that returns what was printed there since it was last
    asked (LAPACK's xerbla prints "parameter number 4 had an illegal value" to fd 1: a value the core let
    through). The harness itself writes only to its pipe."""
    import tempfile

    printed = tempfile.TemporaryFile()
    os.dup2(printed.fileno(), 1)
    sys.stdout = open(os.devnull, "w")
    size = [0]

    def new_text() -> str:
        grown = os.fstat(printed.fileno()).st_size
        if grown <= size[0]:
            return ""
        printed.seek(size[0])
        text = printed.read(grown - size[0]).decode(errors="replace").strip().replace("\n", " | ")
        size[0] = grown
        return text

    return new_text


def silence_stderr() -> None:
    """In a child: what numpy, Python's warnings or the core print to fd 2 stays out of the parent's report."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 2)
    os.close(devnull)
