"""`skinkit unwrap` as a user runs it: OBJ in, OBJ with uvs out in the same vertex order, one JSON object."""
import numpy as np
import pytest
from tests.conftest import sample_path
from tests.cli.test_cli import skinkit
from tests.core.test_unwrap import capsule

from skinkit.meshio import read_obj, read_obj_texture_corners, write_obj

REPORT_KEYS = {"charts", "seconds", "stretch_rest", "stretch_frames", "stretch_metric", "packing_efficiency",
               "texture_efficiency", "metric", "frames", "seams", "invalid_triangles", "out"}


def texture_coordinates(path) -> np.ndarray:
    with open(path) as stream:
        return np.array([line.split()[1:3] for line in stream if line.startswith("vt ")], dtype=np.float64)


@pytest.fixture
def capsule_obj(tmp_path):
    positions, triangles = capsule()
    path = tmp_path / "capsule.obj"
    write_obj(str(path), positions, triangles)
    return str(path), positions, triangles


def test_writes_the_uvs_as_vt_in_the_input_vertex_order(capsule_obj, tmp_path):
    path, positions, triangles = capsule_obj
    out = str(tmp_path / "atlas.obj")
    _, result = skinkit("unwrap", path, "--out", out, "--json")
    assert REPORT_KEYS <= set(result) and result["metric"] == "rest" and result["stretch_frames"] is None
    assert result["charts"] >= 2 and 1.0 <= result["stretch_rest"] < 1.5 and result["invalid_triangles"] == 0
    # The flattening's counters (sk_flatten_report), as the API reports them.
    flattening = result["flattening"]
    assert flattening["chart_count"] == result["charts"] and flattening["invalid_triangles"] == 0
    assert {"boundary_first_charts", "stretch_splits", "solver_iterations", "tutte_charts"} <= set(flattening)
    read_positions, read_triangles = read_obj(out)
    np.testing.assert_allclose(read_positions, positions, rtol=1e-8)
    np.testing.assert_array_equal(read_triangles, triangles)
    corners = read_obj_texture_corners(out)
    uv = texture_coordinates(out)[corners]
    assert corners.min() >= 0 and uv.min() >= 0 and uv.max() <= 1
    first, second = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    assert np.all(first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0] > 0), "flipped uv triangles"

    # Its uv islands, given back as seams, are the same charts.
    again = str(tmp_path / "again.obj")
    _, seamed = skinkit("unwrap", path, "--seams-from", out, "--mode", "seams", "--out", again, "--json")
    assert seamed["charts"] == result["charts"] and seamed["seams"] == result["seams"]


def test_a_sequence_gives_the_animation_metric_and_the_frames_stretch(capsule_obj, tmp_path):
    path, positions, triangles = capsule_obj
    folder = tmp_path / "frames"
    folder.mkdir()
    for frame in range(4):
        bent = positions.copy()
        bent[:, 0] += 0.2 * frame * np.clip(bent[:, 2], 0, None) ** 2  # the top bends further each frame
        write_obj(str(folder / f"frame{frame + 1}.obj"), bent, triangles)
    _, animated = skinkit("unwrap", path, "--sequence", str(folder), "--out", str(tmp_path / "a.obj"), "--json")
    _, rest = skinkit("unwrap", path, "--sequence", str(folder), "--metric", "rest", "--out",
                      str(tmp_path / "r.obj"), "--json")
    assert animated["metric"] == "animation" and animated["frames"] == 4 and rest["metric"] == "rest"
    assert 1.0 <= animated["stretch_frames"] < 1.5 and 1.0 <= rest["stretch_frames"] < 1.5


def test_a_rig_and_its_action_give_the_animation_metric(tmp_path):
    out = str(tmp_path / "arm.obj")
    _, result = skinkit("unwrap", sample_path("arm"), "--rig", sample_path("arm"), "--action", "arm_twist",
                        "--charts", "8", "--out", out, "--json")
    assert result["metric"] == "animation" and result["frames"] == 40 and result["vertices"] == 4098
    assert 1.0 <= result["stretch_frames"] < 2.0
    assert len(read_obj(out)[0]) == 4098 and len(texture_coordinates(out)) >= 4098


@pytest.mark.parametrize("arguments, message", [
    (("--metric", "animation"), "--metric animation needs the animation"),
    (("--action", "walk"), "--action needs --rig"),
    (("--seams-from", sample_path("arm")), "4098 vertices, but the mesh has"),
    (("--rig", sample_path("arm")), "4098 vertices, but the mesh has"),
    (("--sequence", "missing_folder"), "expected a folder of .obj files or an .abc file"),
])
def test_errors_are_one_json_object(capsule_obj, tmp_path, arguments, message):
    path, _, _ = capsule_obj
    status, result = skinkit("unwrap", path, *arguments, "--out", str(tmp_path / "x.obj"), "--json",
                             expect_success=False)
    assert status == 1 and message in result["error"]


def test_the_output_must_be_an_obj(capsule_obj):
    status, result = skinkit("unwrap", capsule_obj[0], "--out", "atlas.png", "--json", expect_success=False)
    assert status == 1 and "must be an .obj" in result["error"]


def test_seams_from_a_blend_are_the_charts_of_seams_only_mode(open_sample, addon, tmp_path):
    import bpy

    from tests.blender.test_skinning import select

    mesh_object = open_sample("arm")
    select(mesh_object)
    assert bpy.ops.skinkit.animated_unwrap(metric="REST", chart_count=6, mark_seams=True) == {"FINISHED"}
    charts = mesh_object.data["skinkit_unwrap_report"]["charts"]
    seamed = str(tmp_path / "seamed.blend")
    bpy.ops.wm.save_as_mainfile(filepath=seamed, check_existing=False)
    _, result = skinkit("unwrap", sample_path("arm"), "--seams-from", seamed, "--mode", "seams",
                        "--out", str(tmp_path / "arm.obj"), "--json")
    assert result["charts"] == charts and result["metric"] == "rest"
