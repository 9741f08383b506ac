"""Bake Tangent Maps in real Blender: the operator bakes every level of a LOD chain through the bridge function the
CLI's bake-tangent-maps calls (the same files, the same numbers), writes files only, and a failure (an unwritable
folder, a texel needing more bones than allowed, a write failing half-way) or a cancel leaves the scene's
fingerprint identical and no file behind."""
import os

import bpy
import numpy as np
import pytest
from tests.blender.fingerprint import assert_unchanged, scene_fingerprint
from tests.blender.test_skinning import select

from skinkit import normal_maps as nm
from skinkit.blender import lod_chain, storage, unwrap
from skinkit.blender import normal_maps as bridge
from skinkit.model import SkinkitError

OPTIONS = {"resolution": 32, "tile": 8, "max_influences": 16, "mip_levels": 2, "frame": 10}


@pytest.fixture(scope="module")
def chain_file(tmp_path_factory):
    """The arm sample unwrapped into a 2-level chain, saved: each test opens its own copy of the scene."""
    from tests.conftest import sample_path

    from skinkit.blender.scene import find_skinned_mesh

    bpy.ops.wm.open_mainfile(filepath=sample_path("arm"), load_ui=False)
    mesh_object = find_skinned_mesh(bpy.context.scene.objects)
    unwrap.unwrap_object(mesh_object, metric="rest", straighten=True, make_active=True)
    lod_chain.build_lod_chain(mesh_object, levels=2)
    path = str(tmp_path_factory.mktemp("tangent_maps") / "chain.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    return path


@pytest.fixture
def level(chain_file):
    bpy.ops.wm.open_mainfile(filepath=chain_file, load_ui=False)
    scene_object = bpy.data.objects["arm_LOD1"]
    select(scene_object)
    return scene_object


def bake(folder, **changes):
    return bpy.ops.skinkit.bake_tangent_maps(directory=str(folder), **{**OPTIONS, **changes})


def test_the_operator_bakes_what_the_cli_bakes(level, addon, tmp_path):
    before = scene_fingerprint()
    ours, theirs = tmp_path / "operator", tmp_path / "bridge"
    ours.mkdir(), theirs.mkdir()
    assert bake(ours) == {"FINISHED"}
    assert_unchanged(before, "Bake Tangent Maps writes files only")
    expected = [f"arm_LOD{i}{suffix}" for i in (0, 1) for suffix in
                ("_object_normal.png", "_tangent.exr", "_tangent_mip1.exr")]
    assert sorted(os.listdir(ours)) == expected
    report = bridge.bake_tangent_maps(bridge.chain_levels(bridge.find_chain(None)), size=32, tile=8, max_influences=16,
                                      frame=10, out_dir=str(theirs), mip_levels=2)
    assert sorted(os.listdir(theirs)) == expected
    for name in expected:
        np.testing.assert_array_equal(nm.read_image(str(ours / name)), nm.read_image(str(theirs / name)))
    assert report["mip_fit"].startswith("metric")  # the mips fitted in the rig's pose statistics
    for row in report["maps"]:
        assert row["texels_filled"] > 0.3 * 32 * 32 and row["max_angular_error"] < 0.1
    # The active mesh only.
    only = tmp_path / "only"
    only.mkdir()
    assert bake(only, targets="ACTIVE", mip_levels=1, image_format="EXR") == {"FINISHED"}
    assert sorted(os.listdir(only)) == ["arm_LOD1_object_normal.png", "arm_LOD1_tangent.exr"]
    assert nm.read_image(str(only / "arm_LOD1_tangent.exr")).dtype == np.float16


def test_failures_and_cancel_leave_the_scene_and_the_folder_as_they_were(level, addon, tmp_path, monkeypatch):
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="not writable"):
        bake(tmp_path / "missing")
    with pytest.raises(RuntimeError, match="need more than max_influences = 1"):
        bake(tmp_path, max_influences=1)
    # The second target's mip failing to write: the files already written are removed.
    write = nm.write_tangent_map
    calls = []

    def failing_write(path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 4:
            raise SkinkitError(f"{path}: the disk is full")
        return write(path, *args, **kwargs)

    monkeypatch.setattr(nm, "write_tangent_map", failing_write)
    with pytest.raises(RuntimeError, match="the disk is full"):
        bake(tmp_path)
    monkeypatch.undo()
    assert len(calls) == 4
    # Esc midway through the first map's bake: 80 rows are three batches, the C bake stops at the second report.
    job = bridge.prepare_tangent_maps(bridge.chain_levels(bridge.find_chain(None)), size=80, out_dir=str(tmp_path))
    steps = []
    with pytest.raises(SkinkitError, match="cancelled at row 64 of 80"):
        job.solve(lambda fraction: steps.append(fraction) or len(steps) == 2)
    assert steps == [pytest.approx(32 / 80 / 6), pytest.approx(64 / 80 / 6)]
    # Esc between the stages: after the first map's posed normals.
    steps.clear()
    with pytest.raises(SkinkitError, match="cancelled after 2 of 6 steps"):
        job.solve(lambda fraction: steps.append(fraction) or fraction > 1.5 / 6)
    assert steps[-1] == pytest.approx(2 / 6) and len(steps) == 5
    assert_unchanged(before, "Bake Tangent Maps failed or cancelled")
    assert os.listdir(tmp_path) == []


def test_poll_says_what_is_missing(level, addon):
    bpy.ops.mesh.primitive_plane_add()
    assert not bpy.ops.skinkit.bake_tangent_maps.poll()
    select(level)
    assert bpy.ops.skinkit.bake_tangent_maps.poll()
    source = bpy.data.objects["arm_LOD0"]
    del source.data[storage.PROPERTY]
    assert not bpy.ops.skinkit.bake_tangent_maps.poll()
