"""`skinkit export` as a technical director runs it: a .blend holding a LOD chain in, one .glb/.fbx/.usdc out
(written only when complete), one JSON object on stdout, errors too; the levels re-import with their names."""
import os

import pytest
from tests.cli.test_cli import skinkit
from tests.conftest import sample_path

from skinkit.cli.commands import export as command


@pytest.fixture(scope="module")
def chain_scene(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("chain") / "arm_chain.blend")
    _, result = skinkit("lod", sample_path("arm"), "--levels", "2", "--out", path, "--json")
    assert result["collection"] == "arm_LOD"
    return path


@pytest.mark.parametrize("name", ["arm.glb", "arm.fbx", "arm.usdc"])
def test_a_chain_exports_in_each_format(chain_scene, tmp_path, name):
    out = str(tmp_path / name)
    _, report = skinkit("export", chain_scene, "--chain", "arm", "--out", out, "--json")
    assert report["out"] == out and os.path.getsize(out) > 0 and os.listdir(tmp_path) == [name]
    assert report["objects"] == ["arm_LOD0", "arm_LOD1"] and report["armature"] == "arm_rig"
    assert report["action"] == "arm_twist" and report["bones"] == 3 and report["max_joints"] == 4
    assert report["format"] == command.SUFFIXES[os.path.splitext(name)[1]]
    assert report["animation_space"] == name.endswith(".glb") and report["seconds"] > 0


def test_glb_without_the_animation_space_attributes(chain_scene, tmp_path):
    out = str(tmp_path / "plain.glb")
    _, report = skinkit("export", chain_scene, "--chain", "arm", "--format", "glb", "--out", out,
                        "--no-animation-space", "--json")
    assert not report["animation_space"] and report["slots"] == {}
    with open(out, "rb") as file:
        assert b"_SKINKIT_P_0" not in file.read()


def test_glb_and_usd_in_metres_at_a_given_unit_scale(chain_scene, tmp_path):
    for name in ("arm.glb", "arm.usdc"):
        _, report = skinkit("export", chain_scene, "--chain", "arm", "--out", str(tmp_path / name), "--unit-scale",
                            "0.01", "--json")
        assert report["units"] == "metres" and report["unit_scale"] == 0.01
    _, report = skinkit("export", chain_scene, "--chain", "arm", "--out", str(tmp_path / "arm.fbx"), "--json")
    assert report["units"] == "scene units (FBX unit scale)" and report["unit_scale"] == 1.0


def test_a_single_skinned_mesh_exports_when_there_is_no_chain(tmp_path):
    out = str(tmp_path / "arm.glb")
    _, report = skinkit("export", sample_path("arm"), "--chain", "arm", "--out", out, "--json")
    assert report["objects"] == ["arm"] and report["model"] == {"arm": "linear blend"}


@pytest.mark.parametrize("arguments, message", [
    (["--chain", "ghost", "--out", "{tmp}/x.glb"], "no LOD chain 'ghost_LOD0..n'"),
    (["--chain", "arm", "--format", "fbx", "--out", "{tmp}/x.glb"], "must end in .fbx"),
    (["--chain", "arm", "--out", "{tmp}/x.obj"], "give --format"),
    (["--chain", "arm", "--out", "{tmp}/missing/x.glb"], "does not exist"),
    (["--chain", "arm", "--out", "{tmp}/x.glb", "--unit-scale", "-1"], "unit_scale must be a positive number"),
    (["--chain", "arm", "--out", "{tmp}/x.fbx", "--unit-scale", "0.01"], "FBX writes the scene's own unit"),
])
def test_bad_requests_fail_with_one_json_error_and_no_file(tmp_path, arguments, message):
    arguments = [a.replace("{tmp}", str(tmp_path)) for a in arguments]
    status, report = skinkit("export", sample_path("arm"), *arguments, "--json", expect_success=False)
    assert status == 1 and message in report["error"] and os.listdir(tmp_path) == []


def test_the_command_knows_the_bridges_formats():
    from skinkit.blender import export

    assert command.FORMATS == export.FORMATS
    assert set(command.SUFFIXES.values()) == set(export.FORMATS)
    assert all(suffix in export.EXTENSIONS[fmt] for suffix, fmt in command.SUFFIXES.items())
