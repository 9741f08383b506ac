"""`skinkit skeleton` as a user runs it: a grouped .obj (or weights) in; JSON, BVH, the hierarchy file or a rigged
.blend out; bad input answered with one JSON error."""
import json

import numpy as np
import pytest
from tests.cli.test_cli import skinkit

from skinkit.skeleton import chain_of_cylinders, read_hierarchy, star_of_limbs, write_obj_groups


@pytest.fixture(scope="module")
def star_obj(tmp_path_factory):
    sample = star_of_limbs()
    path = tmp_path_factory.mktemp("star") / "star.obj"
    return str(write_obj_groups(str(path), sample.parts)), sample


def test_json_names_joints_in_mesh_coordinates(star_obj, tmp_path):
    path, sample = star_obj
    out = tmp_path / "rig.json"
    _, report = skinkit("skeleton", path, "--method", "centroid", "--out", str(out), "--json")
    assert report["seconds"] > 0 and set(report["stage_seconds"]) == {"openings", "hulls", "kernels", "method"}
    by_name = {j["name"]: j for j in report["joints"]}
    for part, name in enumerate(sample.parts.names[1:], start=1):
        np.testing.assert_allclose(by_name[f"{name}.opening"]["position"], sample.openings[part], atol=1e-9)
        assert by_name[f"{name}.opening"]["parent"] == "hub.root"  # the hub's KC, the global root
    assert json.loads(out.read_text())["joints"] == report["joints"]


def test_bvh_and_hierarchy_outputs(star_obj, tmp_path):
    path, sample = star_obj
    _, report = skinkit("skeleton", path, "--method", "principal-axis", "--refine", "--out", str(tmp_path / "r.bvh"),
                        "--json")
    text = (tmp_path / "r.bvh").read_text()
    assert text.startswith("HIERARCHY") and text.count("JOINT") == len(report["joints"]) - 1
    _, report = skinkit("skeleton", path, "--out", str(tmp_path / "r.hier"), "--json")
    hierarchy = read_hierarchy(str(tmp_path / "r.hier"))
    assert hierarchy.names[0] == "hub" and (hierarchy.parents[1:] == 0).all()


def test_weights_give_the_parts(tmp_path):
    sample = chain_of_cylinders(3)
    mesh = tmp_path / "chain.obj"
    write_obj_groups(str(mesh), sample.parts)
    labels = sample.parts.vertex_parts()
    weights = np.eye(3)[labels]
    dmat = tmp_path / "w.dmat"
    dmat.write_text(f"3 {len(labels)}\n" + "\n".join(f"{v:g}" for v in weights.T.reshape(-1)) + "\n")
    _, report = skinkit("skeleton", str(mesh), "--parts", f"weights:{dmat}", "--method", "opening",
                        "--out", str(tmp_path / "w.json"), "--json")
    openings = sorted(j["position"][0] for j in report["joints"] if j["name"].endswith(".opening"))
    # Per-vertex labels move the border by up to one ring (0.5) from the cylinders' seams at x = 2 and 4.
    np.testing.assert_allclose(openings, [2.0, 4.0], atol=0.5)


def test_blend_output_has_the_rig(star_obj, tmp_path):
    path, _ = star_obj
    out = tmp_path / "rig.blend"
    _, report = skinkit("skeleton", path, "--method", "centroid", "--out", str(out), "--json")
    assert report["armature"] == "star_skeleton" and out.exists()


@pytest.mark.parametrize("arguments, message", [
    (["--parts", "bones"], "--parts"),
    (["--out", "rig.txt"], "expected one of"),
    (["--hierarchy", "missing.hier"], "missing.hier"),
])
def test_bad_arguments_are_one_json_error(star_obj, tmp_path, arguments, message):
    path, _ = star_obj
    base = ["skeleton", path, "--out", str(tmp_path / "rig.json"), "--json"]
    status, report = skinkit(*base, *arguments, expect_success=False)
    assert status == 1 and message in report["error"]


def test_parts_that_do_not_meet_are_named(tmp_path):
    sample = chain_of_cylinders(2)
    parts = sample.parts
    mesh = tmp_path / "apart.obj"
    lines = [f"v {x} {y} {z}" for x, y, z in np.vstack([parts.positions, parts.positions + 50]).tolist()]
    lines += ["g a"] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in parts.triangles.tolist()]
    n = len(parts.positions)
    lines += ["g b"] + [f"f {a + 1 + n} {b + 1 + n} {c + 1 + n}" for a, b, c in parts.triangles.tolist()]
    mesh.write_text("\n".join(lines) + "\n")
    status, report = skinkit("skeleton", str(mesh), "--out", str(tmp_path / "r.json"), "--json", expect_success=False)
    assert "has no opening" in report["error"]
