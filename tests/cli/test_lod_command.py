"""`skinkit lod` as a user runs it: a .blend in, the levels' report as one JSON object, the levels saved as a
.blend and as posed OBJ frames with vt; bad input refused before any output is written."""
import os
import subprocess
import sys

import numpy as np
from tests.cli.test_cli import skinkit
from tests.conftest import ROOT, sample_path

from skinkit.meshio import read_obj, read_obj_texture_corners

LEVEL_KEYS = {"level", "vertices", "triangles", "influences", "error"}


def test_levels_report_and_outputs(tmp_path):
    out = str(tmp_path / "lods.blend")
    frames = str(tmp_path / "frames")
    _, result = skinkit("lod", sample_path("arm"), "--levels", "3", "--out", out, "--export-frames", frames,
                        "--frames", "1:3", "--json")
    assert {"levels", "seconds"} <= set(result) and result["seconds"] > 0
    levels = result["levels"]
    assert [row["level"] for row in levels] == [0, 1, 2] and all(set(row) == LEVEL_KEYS for row in levels)
    assert levels[0]["error"] == 0.0 and levels[0]["triangles"] > levels[1]["triangles"] > levels[2]["triangles"]
    assert 0 < levels[1]["error"] <= levels[2]["error"] < 0.1
    assert levels[2]["influences"] < levels[0]["influences"]
    assert os.path.isfile(out) and result["out"] == out
    for row in levels:
        paths = sorted(os.listdir(os.path.join(frames, f"lod{row['level']}")))
        assert paths == ["0001.obj", "0002.obj", "0003.obj"]
        positions, triangles = read_obj(os.path.join(frames, f"lod{row['level']}", "0002.obj"))
        assert positions.shape == (row["vertices"], 3) and triangles.shape == (row["triangles"], 3)
        assert np.isfinite(positions).all()


def unwrapped_sample(path: str) -> None:
    """The arm sample with a straightened atlas as its active UV map, saved at `path` (in a fresh process)."""
    script = ("import bpy; from skinkit.blender.scene import find_skinned_mesh; from skinkit.blender import unwrap; "
              f"bpy.ops.wm.open_mainfile(filepath={sample_path('arm')!r}, load_ui=False); "
              "o = find_skinned_mesh(bpy.context.scene.objects); "
              "unwrap.unwrap_object(o, metric='rest', straighten=True, make_active=True); "
              f"bpy.ops.wm.save_as_mainfile(filepath={path!r})")
    subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, cwd=ROOT, timeout=300)


def test_rest_metric_without_influence_simplification_exports_uvs(tmp_path):
    scene = str(tmp_path / "unwrapped.blend")
    unwrapped_sample(scene)
    frames = str(tmp_path / "frames")
    _, result = skinkit("lod", scene, "--levels", "2", "--metric", "rest", "--no-influence-simplification",
                        "--max-influences", "2", "--export-frames", frames, "--frames", "1:1", "--json")
    fine, coarse = result["levels"]
    assert coarse["triangles"] < fine["triangles"] and coarse["influences"] < fine["influences"]
    # only edge collapses: every surviving vertex keeps all of its influences (at most 4 in the sample)
    assert coarse["influences"] <= 4 * coarse["vertices"] and coarse["influences"] >= coarse["vertices"]
    positions, triangles = read_obj(os.path.join(frames, "lod1", "0001.obj"))
    corners = read_obj_texture_corners(os.path.join(frames, "lod1", "0001.obj"))
    assert corners.shape == triangles.shape and corners.min() >= 0


def test_full_collapses_and_an_engine_budget_from_the_command_line():
    _, result = skinkit("lod", sample_path("arm"), "--levels", "3", "--collapse", "auto", "--influence-cost-scale", "3",
                        "--start-influences", "1", "--json")
    first, *coarser = result["levels"]
    # LOD0 is the model limited to 1 influence per vertex (the arm blends two bones): its error is the correction
    assert first["error"] > 0 and first["influences"] == first["vertices"]
    assert all(level["influences"] <= first["influences"] // 2 ** (index + 1) for index, level in enumerate(coarser))
    status, result = skinkit("lod", sample_path("arm"), "--levels", "3", "--influence-cost-scale", "0", "--json",
                             expect_success=False)
    assert status != 0 and "influence cost scale" in result["error"]


def test_no_refit_keeps_the_collapses_coordinates(tmp_path):
    """--no-refit: the same levels (the refit moves coordinates only), posed where the collapses left them."""
    posed = {}
    for flag in ((), ("--no-refit",)):
        frames = str(tmp_path / ("plain" if flag else "refitted"))
        _, result = skinkit("lod", sample_path("arm"), "--levels", "3", *flag, "--export-frames", frames,
                            "--frames", "2:2", "--json")
        posed[flag] = (result["levels"], read_obj(os.path.join(frames, "lod2", "0002.obj")))
    (refitted_levels, (refitted, refitted_faces)), (plain_levels, (plain, plain_faces)) = posed.values()
    assert refitted_levels == plain_levels  # triangles, influences and epsilon are the collapses'
    np.testing.assert_array_equal(refitted_faces, plain_faces)
    assert not np.allclose(refitted, plain, atol=1e-9, rtol=0.0)


def test_bad_input_is_refused_without_output(tmp_path):
    out = str(tmp_path / "lods.blend")
    status, result = skinkit("lod", sample_path("arm"), "--levels", "1", "--out", out, "--json",
                             expect_success=False)
    assert status != 0 and "levels" in result["error"] and not os.path.exists(out)
    status, result = skinkit("lod", sample_path("arm"), "--levels", "3", "--out", str(tmp_path / "x.fbx"), "--json",
                             expect_success=False)
    assert status != 0 and ".blend or a .glb" in result["error"]
    status, result = skinkit("lod", sample_path("arm"), "--levels", "3", "--frames", "1:2", "--json",
                             expect_success=False)
    assert status != 0 and "--export-frames" in result["error"]


def test_levels_and_their_armature_as_a_glb(tmp_path):
    out = str(tmp_path / "lods.glb")
    _, result = skinkit("lod", sample_path("arm"), "--levels", "2", "--out", out, "--json")
    assert result["out"] == out and os.path.getsize(out) > 1000
    with open(out, "rb") as stream:
        assert stream.read(4) == b"glTF"
