"""BLAS threads while skinkit's own workers run LAPACK.

The C core splits its LAPACK-heavy work (kernel CCA per bone, per-vertex fits, ...) over its own worker threads.
OpenBLAS, which both the core's LAPACK and numpy link, starts threads of its own inside each of those calls, so the
machine runs workers x BLAS threads: on this 2-core machine under load, a kernel CCA took 2.79 s (median of 5)
with OpenBLAS's default threads against 0.60 s with one (BENCHMARKS.md, "BLAS threads").

While skinkit's workers are more than one, every BLAS library in the process runs one thread. OpenBLAS has only a
process-wide setting, so it is changed for the call and restored after it: nothing outlives the call, and skinkit
keeps no state of its own but the list of BLAS libraries threadpoolctl found (a cache, read once). Calls made at
the same time from several Python threads share that process-wide setting. Without threadpoolctl (a Python that
lacks it) nothing is limited.
"""
from contextlib import nullcontext
from functools import lru_cache


@lru_cache(maxsize=1)
def _controller():
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:
        return None
    return ThreadpoolController()


def one_blas_thread():
    """A context in which BLAS runs one thread: for LAPACK calls on many small systems (Limit Influences' removals in
    the core and its (4w + 1)-square KKT systems in numpy), whose results OpenBLAS's threads change in the last
    bits, so that a result does not depend on how many threads BLAS was given."""
    controller = _controller()
    return nullcontext() if controller is None else controller.limit(limits=1, user_api="blas")


def blas_threads_for(threads: int):
    """A context for a core call that runs `threads` workers (0: one per core): one BLAS thread while it runs
    unless the call itself is single-threaded (then BLAS keeps its own threads)."""
    return nullcontext() if threads == 1 else one_blas_thread()
