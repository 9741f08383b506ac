"""The `skinkit` command line, run as a user runs it: a separate process, output parsed as JSON."""
import json
import os
import subprocess
import sys

import pytest
from tests.conftest import ROOT, sample_path


def skinkit(*arguments, expect_success=True):
    """Runs `python -m skinkit.cli ARGUMENTS`; returns (exit status, the single JSON object on stdout)."""
    completed = subprocess.run([sys.executable, "-m", "skinkit.cli", *arguments], capture_output=True, text=True,
                               cwd=ROOT, timeout=300)
    if "--json" not in arguments:
        return completed.returncode, completed.stdout
    lines = [line for line in completed.stdout.splitlines() if line.strip()]
    assert len(lines) == 1, f"stdout must hold exactly one JSON object, got: {completed.stdout!r}"
    assert (completed.returncode == 0) == expect_success, completed.stderr
    return completed.returncode, json.loads(lines[0])


def test_version():
    status, output = skinkit("--version")
    assert status == 0 and output.strip() == "skinkit 0.1.0"


def test_convert_then_eval_reproduces_blender(tmp_path):
    out = str(tmp_path / "arm_converted.blend")
    _, converted = skinkit("convert", sample_path("arm"), "--out", out, "--json")
    assert converted["vertices"] == 4098 and converted["bones"] == 3 and os.path.isfile(out)
    _, evaluated = skinkit("eval", out, "--frames", "1:40", "--json")
    assert evaluated["converted_in_memory"] is False
    assert evaluated["frames"] == 40 and evaluated["vertices"] == 4098 and evaluated["bones"] == 3
    assert 0 < evaluated["max_deviation"] < 1e-6 and evaluated["seconds"] > 0


def test_eval_without_a_stored_model_converts_in_memory():
    _, evaluated = skinkit("eval", sample_path("creature"), "--object", "creature", "--json")
    assert evaluated["converted_in_memory"] is True and evaluated["frames"] == 48
    assert evaluated["max_deviation"] < 1e-6


def test_bake(tmp_path):
    converted = str(tmp_path / "c.blend")
    skinkit("convert", sample_path("creature"), "--out", converted, "--json")
    _, baked = skinkit("bake", converted, "--frames", "1:5", "--pc2", str(tmp_path / "c.pc2"),
                       "--out", str(tmp_path / "baked.blend"), "--json")
    assert baked["frames"] == 5 and baked["baked_object"] == "creature_skinkit_baked"
    assert os.path.getsize(tmp_path / "c.pc2") == 32 + 5 * baked["vertices"] * 12


@pytest.mark.parametrize("arguments, message", [
    (("eval", "missing.blend"), "missing.blend: no such file"),
    (("eval", sample_path("arm"), "--object", "nobody"), "no object named 'nobody'"),
    (("eval", sample_path("arm"), "--object", "arm_rig"), "'arm_rig' is a armature, not a mesh"),
    (("eval", sample_path("arm"), "--frames", "9:2"), "the range is empty"),
    (("eval", sample_path("arm"), "--frames", "a:b"), "expected A:B or A:B:STEP"),
    (("bake", sample_path("arm"), "--pc2", "x.pc2"), "has no animation-space model"),
    (("bake", sample_path("arm")), "bake needs --pc2"),
])
def test_errors_are_one_json_object(arguments, message):
    status, result = skinkit(*arguments, "--json", expect_success=False)
    assert status == 1 and message in result["error"]
