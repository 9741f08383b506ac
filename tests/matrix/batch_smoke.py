"""The batch smoke the Blender matrix runs under each release (tests/matrix/blender_matrix.py): one pipeline on a
LocalCluster of 2 workers over one sample (convert, then bake 3 frames to PC2, each step a `skinkit` process under
that release's bpy) beside a character whose input is not a .blend. The sample completes, the bad one fails alone
naming its step and file. tests/batch (about 3 min per release, fault injection included) runs under the pinned
bpy in `make test`. The file name keeps `make test` from collecting it a second time; the matrix names it."""
import pytest
from tests.batch.test_batch import check_complete, write_jobs
from tests.conftest import sample_path

from skinkit.batch import load_jobs, run_batch

distributed = pytest.importorskip("distributed")


def test_one_sample_completes_and_a_bad_input_fails_alone(tmp_path):
    broken = tmp_path / "broken.blend"
    broken.write_text("not a blend file")
    jobs = write_jobs(tmp_path, {"arm": sample_path("arm"), "broken": str(broken)}, retries=0)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        with distributed.Client(cluster) as client:
            result = run_batch(load_jobs(jobs), client=client)
    statuses = {c["name"]: c["status"] for c in result["characters"]}
    assert statuses == {"arm": "done", "broken": "failed"} and result["status"] == "failed", result
    error = next(c["error"] for c in result["characters"] if c["name"] == "broken")
    assert "character 'broken', step 1 (convert)" in error and "broken.blend" in error
    check_complete(tmp_path / "out", ["arm"])
