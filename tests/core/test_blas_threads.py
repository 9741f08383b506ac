"""BLAS threads while skinkit's own workers run LAPACK (skinkit._blas): one BLAS thread per library during a
threaded core call, BLAS's own threads kept for a single-threaded one, and the process's setting restored after."""
import numpy as np
import pytest

import skinkit as sk
from skinkit import _core, fit
from skinkit._blas import blas_threads_for
from tests.core.test_fit import random_poses, random_rig

threadpoolctl = pytest.importorskip("threadpoolctl")


def blas_threads() -> list[int]:
    return [entry["num_threads"] for entry in threadpoolctl.threadpool_info() if entry["user_api"] == "blas"]


@pytest.fixture
def two_blas_threads():
    """Every BLAS library at 2 threads (this machine's default is its core count, which may be 1)."""
    with threadpoolctl.threadpool_limits(limits=2, user_api="blas"):
        assert blas_threads() and set(blas_threads()) == {2}
        yield


def test_a_threaded_call_runs_one_blas_thread_and_restores_the_setting(two_blas_threads):
    for threads in (0, 2):
        with blas_threads_for(threads):
            assert set(blas_threads()) == {1}
        assert set(blas_threads()) == {2}
    with blas_threads_for(1):
        assert set(blas_threads()) == {2}  # skinkit single-threaded: BLAS may use the cores


def test_the_per_vertex_fit_calls_the_core_with_one_blas_thread(two_blas_threads, monkeypatch):
    seen = []
    real = _core.fit_per_vertex

    def recording(*arguments):
        seen.append(blas_threads())
        return real(*arguments)

    monkeypatch.setattr(_core, "fit_per_vertex", recording)
    rng = np.random.default_rng(3)
    skeleton, weights, rest, _ = random_rig(rng, vertices=40, bones=3, influences=2)
    poses = random_poses(rng, 6, skeleton.bone_count)
    examples = sk.lbs_evaluate(skeleton, weights, rest, poses)
    for threads, expected in ((2, {1}), (1, {2})):
        seen.clear()
        fit.fit_animation_space(poses, examples, weights, skeleton.bone_count, method="per-vertex",
                                regularisation=0.0, validate=False, check_order=False, threads=threads)
        assert seen and all(set(counts) == expected for counts in seen)
    assert set(blas_threads()) == {2}
