"""skinkit batch on a LocalCluster of 2 workers over the Blender samples: every output complete, a re-run that does
no work, a bad character failing alone, and a worker killed mid-task (fault injection) without losing or duplicating
anything."""
import json
import os
import signal
import subprocess
import sys
import threading
import time

import pytest
from tests.conftest import ROOT, sample_path

from skinkit import SkinkitError
from skinkit.batch import MANIFEST_NAME, load_jobs, run_batch
from skinkit.batch.pipeline import PARTIAL_MARK

distributed = pytest.importorskip("distributed")


def write_jobs(folder, characters: dict, retries: int = 1) -> str:
    """A JOBS.toml converting each sample (name -> .blend) and baking 3 frames of it to PC2."""
    lines = [f"retries = {retries}", 'out = "out"']
    for name, blend in characters.items():
        lines += ["[[character]]", f'name = "{name}"', f'input = "{blend}"',
                  "[[character.step]]", 'command = "convert"', f'output = "{name}.blend"',
                  "[[character.step]]", 'command = "bake"', f'output = "{name}.pc2"', 'options = { frames = "1:3" }']
    path = os.path.join(folder, "jobs.toml")
    with open(path, "w") as file:
        file.write("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
    with distributed.Client(cluster) as connected:
        yield connected
    cluster.close()


def check_complete(out, names):
    """Each character's folder holds exactly its outputs and manifest; nothing else is left in out."""
    assert sorted(os.listdir(out)) == sorted(names)
    for name in names:
        manifest = json.load(open(os.path.join(out, name, MANIFEST_NAME)))
        assert manifest["outputs"] == [f"{name}.blend", f"{name}.pc2"]
        assert sorted(os.listdir(os.path.join(out, name))) == sorted(manifest["outputs"] + [MANIFEST_NAME])
        assert os.path.getsize(os.path.join(out, name, f"{name}.pc2")) > 0


def test_a_batch_completes_a_rerun_skips_and_a_bad_character_fails_alone(tmp_path, client):
    broken = tmp_path / "broken.blend"
    broken.write_text("not a blend file")
    jobs = write_jobs(tmp_path, {"arm": sample_path("arm"), "creature": sample_path("creature"),
                                 "broken": str(broken)}, retries=1)
    result = run_batch(load_jobs(jobs), client=client)
    statuses = {c["name"]: c["status"] for c in result["characters"]}
    assert statuses == {"arm": "done", "creature": "done", "broken": "failed"} and result["status"] == "failed"
    error = next(c["error"] for c in result["characters"] if c["name"] == "broken")
    assert "character 'broken', step 1 (convert)" in error and "broken.blend" in error
    check_complete(tmp_path / "out", ["arm", "creature"])
    stamps = {name: os.stat(tmp_path / "out" / name / MANIFEST_NAME).st_mtime_ns for name in ("arm", "creature")}

    rerun = run_batch(load_jobs(jobs)[:2], client=client)
    assert [c["status"] for c in rerun["characters"]] == ["skipped", "skipped"]
    assert all(os.stat(tmp_path / "out" / n / MANIFEST_NAME).st_mtime_ns == t for n, t in stamps.items())

    (tmp_path / "arm.blend").write_bytes(open(sample_path("arm"), "rb").read())  # same content, another file
    changed = write_jobs(tmp_path, {"arm": str(tmp_path / "arm.blend"), "creature": sample_path("creature")})
    assert [c["status"] for c in run_batch(load_jobs(changed), client=client)["characters"]] == ["done", "skipped"]


def test_a_worker_killed_mid_task_loses_and_duplicates_nothing(tmp_path, client):
    jobs = write_jobs(tmp_path, {"arm": sample_path("arm"), "creature": sample_path("creature")}, retries=0)
    outcome = {}
    runner = threading.Thread(target=lambda: outcome.update(run_batch(load_jobs(jobs), client=client)))
    runner.start()
    out = tmp_path / "out"
    deadline = time.monotonic() + 120
    while not (out.exists() and any(PARTIAL_MARK in entry for entry in os.listdir(out))):
        assert time.monotonic() < deadline, "no task started"
        time.sleep(0.2)
    busy = [address for address, keys in client.processing().items() if keys]
    pids = client.run(os.getpid)
    os.kill(pids[busy[0]], signal.SIGKILL)  # the worker dies mid-task; its nanny starts another
    runner.join(timeout=600)
    assert not runner.is_alive()
    assert [c["status"] for c in outcome["characters"]] == ["done", "done"], outcome
    check_complete(out, ["arm", "creature"])


def test_jobs_files_are_checked_naming_the_character_and_step(tmp_path):
    path = tmp_path / "jobs.toml"
    for text, message in (("", "no \\[\\[character\\]\\]"),
                          ('[[character]]\nname = "a"\ninput = "x.blend"\n', "character 'a': needs at least one"),
                          ('[[character]]\nname = "a"\ninput = "x"\n[[character.step]]\ncommand = "paint"\n',
                           "character 'a', step 1: command must be one of"),
                          ('[[character]]\nname = "a"\ninput = "x"\n[[character.step]]\ncommand = "convert"\n'
                           'output = "../escape.blend"\n', "output must be a file name"),
                          ("retries = -1\n", "retries must be"), ("= broken", "not valid TOML")):
        path.write_text(text)
        with pytest.raises(SkinkitError, match=message):
            load_jobs(str(path))


def test_the_command_prints_one_json_object_and_fails_on_a_bad_jobs_file(tmp_path):
    (tmp_path / "jobs.toml").write_text("retries = 1\n")
    completed = subprocess.run([sys.executable, "-m", "skinkit.cli", "batch", str(tmp_path / "jobs.toml"), "--json"],
                               capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert completed.returncode == 1
    assert "no [[character]] tables" in json.loads(completed.stdout)["error"]
