"""`skinkit limit-influences` and `skinkit subdivide` as a user runs them: one JSON object, new objects saved, errors."""
import os

import pytest
from tests.cli.test_cli import skinkit
from tests.conftest import sample_path

from skinkit.lod.influences import SAMPLE_WEIGHTS


def test_limit_influences_reports_both_errors_and_saves_the_new_object(tmp_path):
    out = str(tmp_path / "limited.blend")
    _, result = skinkit("limit-influences", sample_path("creature"), "--max-influences", "2", "--frames", "1:48:6",
                        "--out", out, "--json")
    assert result["vertices"] == 11086 and result["frames"] == 8 and result["limited_object"] == "creature_limited"
    assert result["influences_before"]["max"] == 4 and result["influences_after"]["max"] == 2
    assert result["influences_after"]["total"] < result["influences_before"]["total"]
    error = result["error"]
    assert 0 < error["skinkit"]["rms"] <= error["limit_total"]["rms"] and error["ratio"] <= 1
    assert result["seconds"] > 0 and os.path.isfile(out)
    # The saved file holds the limited model: evaluating it converts nothing.
    _, evaluated = skinkit("eval", out, "--object", "creature_limited", "--frames", "1:3", "--json")
    assert evaluated["converted_in_memory"] is False and evaluated["vertices"] == 11086



def test_limit_influences_with_the_sampled_metric_reports_its_validated_weight():
    """--sampled-metric: the action's frames' own metric, blended by validation on them (on the arm the validation
    keeps the statistics alone: weight 0, the same result); without the flag, no weight."""
    _, plain = skinkit("limit-influences", sample_path("arm"), "--max-influences", "1", "--json")
    _, sampled = skinkit("limit-influences", sample_path("arm"), "--max-influences", "1", "--sampled-metric", "--json")
    assert plain["sample_weight"] is None and sampled["sample_weight"] in SAMPLE_WEIGHTS
    if sampled["sample_weight"] == 0:
        assert sampled["error"]["skinkit"]["rms"] == plain["error"]["skinkit"]["rms"]
    assert sampled["influences_after"]["max"] == 1

def test_limit_influences_glb(tmp_path):
    out = str(tmp_path / "limited.glb")
    _, result = skinkit("limit-influences", sample_path("arm"), "--max-influences", "1", "--frames", "1:40:10",
                        "--out", out, "--json")
    assert os.path.getsize(out) > 0 and result["influences_after"]["max"] == 1


def test_subdivide_saves_a_subdivided_object(tmp_path):
    out = str(tmp_path / "subdivided.blend")
    _, result = skinkit("subdivide", sample_path("arm"), "--levels", "1", "--out", out, "--json")
    assert result["vertices_before"] == 4098 and result["polygons"] == 4032 * 4 + 128 * 3
    assert result["subdivided_object"] == "arm_subdivided" and os.path.isfile(out)
    _, evaluated = skinkit("eval", out, "--object", "arm_subdivided", "--frames", "1:2", "--json")
    assert evaluated["vertices"] == result["vertices"] and evaluated["converted_in_memory"] is False


@pytest.mark.parametrize("arguments, message", [
    (("limit-influences", sample_path("arm"), "--max-influences", "0"), "at least 1"),
    (("limit-influences", sample_path("arm"), "--max-influences", "2", "--object", "arm_rig"),
     "'arm_rig' is a armature, not a mesh"),
    (("limit-influences", "missing.blend", "--max-influences", "2"), "missing.blend: no such file"),
    (("limit-influences", sample_path("arm"), "--max-influences", "2", "--frames", "5:1"), "the range is empty"),
    (("subdivide", sample_path("arm"), "--levels", "1", "--scheme", "loop", "--out", "x.blend"),
     "'arm': has faces that are not triangles"),
    (("subdivide", sample_path("arm"), "--levels", "0", "--out", "x.blend"), "levels: expected a whole number"),
    (("subdivide", sample_path("arm"), "--levels", "1", "--out", "x.obj"), "the output must be a .blend"),
])
def test_bad_input_is_one_json_error(arguments, message):
    status, result = skinkit(*arguments, "--json", expect_success=False)
    assert status == 1 and set(result) == {"error"} and message in result["error"]
