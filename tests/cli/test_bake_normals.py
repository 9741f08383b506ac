"""`skinkit bake-normals` as a user runs it: a LOD chain found on its own (no --object or --chain) and baked through
its atlas, a plane baked from a high-resolution --source, one JSON object with a row per map, the scene saved with
the maps wired in; bad input refused with nothing written."""
import os
import subprocess
import sys

import numpy as np
from tests.cli.test_cli import skinkit
from tests.conftest import ROOT, sample_path

from skinkit import normal_maps as nm

MAP_KEYS = {"object", "path", "image", "size", "texels_filled", "texels_missed", "texels_dilated", "seconds",
            "mean_angular_error", "max_angular_error"}


def make_scene(path: str, script: str) -> None:
    subprocess.run([sys.executable, "-c", "import bpy, bmesh, numpy as np\n" + script +
                    f"\nbpy.ops.wm.save_as_mainfile(filepath={path!r})"],
                   check=True, capture_output=True, cwd=ROOT, timeout=300)


CHAIN = f"""
from skinkit.blender import lod_chain, unwrap
from skinkit.blender.scene import find_skinned_mesh
bpy.ops.wm.open_mainfile(filepath={sample_path('arm')!r}, load_ui=False)
o = find_skinned_mesh(bpy.context.scene.objects)
unwrap.unwrap_object(o, metric="rest", straighten=True, make_active=True)
lod_chain.build_lod_chain(o, levels=2)
"""

PLANES = """
bpy.ops.wm.read_factory_settings(use_empty=True)
for name, cuts in (("low", 2), ("high", 64)):
    mesh = bpy.data.meshes.new(name)
    editable = bmesh.new()
    editable.loops.layers.uv.new("UVMap")
    bmesh.ops.create_grid(editable, x_segments=cuts, y_segments=cuts, size=1.0, calc_uvs=True)
    if name == "high":
        for vertex in editable.verts:
            vertex.co.z = 0.05 * np.sin(3 * vertex.co.x) * np.cos(2 * vertex.co.y)
    editable.to_mesh(mesh)
    bpy.context.scene.collection.objects.link(bpy.data.objects.new(name, mesh))
"""


def test_the_only_chain_is_baked_through_its_atlas(tmp_path):
    scene = str(tmp_path / "chain.blend")
    make_scene(scene, CHAIN)
    maps, out = tmp_path / "maps", str(tmp_path / "out.blend")
    maps.mkdir()
    _, result = skinkit("bake-normals", scene, "--size", "64", "--margin", "2", "--format", "png8", "--frame", "1",
                        "--out-dir", str(maps), "--out", out, "--json")
    assert result["mode"] == "guided" and result["source"] == "arm_LOD0" and result["frame"] == 1
    (row,) = result["maps"]  # LOD0 is the source: only LOD1 is baked
    assert set(row) == MAP_KEYS and row["object"] == "arm_LOD1"
    assert row["texels_filled"] > 0.3 * 64 * 64 and row["texels_missed"] == 0
    assert 0 < row["mean_angular_error"] < 2.0
    assert os.path.isfile(out) and result["out"] == out
    stored = nm.read_image(row["path"])
    assert stored.shape == (64, 64, 3) and stored.dtype == np.uint8
    # The same uv point only: the same texels, another map.
    _, atlas = skinkit("bake-normals", scene, "--correspondence", "atlas", "--size", "64", "--margin", "2",
                       "--format", "png8", "--frame", "1", "--out-dir", str(tmp_path), "--json")
    (atlas_row,) = atlas["maps"]
    assert atlas["mode"] == "atlas" and atlas_row["texels_filled"] == row["texels_filled"]
    assert 0 < atlas_row["mean_angular_error"] < 2.0
    assert not np.array_equal(nm.read_image(atlas_row["path"]), stored)


def test_a_plane_from_a_high_resolution_source(tmp_path):
    scene = str(tmp_path / "planes.blend")
    make_scene(scene, PLANES)
    _, result = skinkit("bake-normals", scene, "--object", "low", "--source", "high", "--size", "32",
                        "--cage", "0.2", "--format", "exr-float", "--out-dir", str(tmp_path), "--json")
    (row,) = result["maps"]
    assert result["mode"] == "ray" and row["texels_filled"] == 32 * 32 and row["texels_missed"] == 0
    assert row["path"] == str(tmp_path / "low_normal.exr") and nm.read_image(row["path"]).dtype == np.float32
    assert row["mean_angular_error"] < 0.5


def test_bad_input_is_refused_and_nothing_is_written(tmp_path):
    scene = str(tmp_path / "planes.blend")
    make_scene(scene, PLANES)
    status, result = skinkit("bake-normals", scene, "--size", "32", "--out-dir", str(tmp_path), "--json",
                             expect_success=False)
    assert status == 1 and "0 LOD chains" in result["error"]
    _, result = skinkit("bake-normals", scene, "--object", "low", "--size", "32", "--out-dir",
                        str(tmp_path / "missing"), "--json", expect_success=False)
    assert "not a writable folder" in result["error"]
    _, result = skinkit("bake-normals", scene, "--object", "low", "--size", "32", "--out-dir", str(tmp_path),
                        "--json", expect_success=False)
    assert "in no LOD chain" in result["error"]
    _, result = skinkit("bake-normals", scene, "--object", "low", "--source", "nothing", "--size", "32",
                        "--out-dir", str(tmp_path), "--json", expect_success=False)
    assert "no object named 'nothing'" in result["error"]
    _, result = skinkit("bake-normals", scene, "--object", "low", "--source", "high", "--correspondence", "atlas",
                        "--size", "32", "--out-dir", str(tmp_path), "--json", expect_success=False)
    assert "--correspondence" in result["error"]
    assert sorted(os.listdir(tmp_path)) == ["planes.blend"]


def test_tangent_maps_of_the_only_chain(tmp_path):
    import OpenImageIO as oiio

    scene = str(tmp_path / "chain.blend")
    make_scene(scene, CHAIN)
    maps = tmp_path / "maps"
    maps.mkdir()
    _, result = skinkit("bake-tangent-maps", scene, "--size", "64", "--tile", "8", "--frame", "10",
                        "--mip-levels", "3", "--out-dir", str(maps), "--json")
    assert result["source"] == "arm_LOD0" and result["frame"] == 10 and result["mip_fit"].startswith("metric")
    assert [row["object"] for row in result["maps"]] == ["arm_LOD0", "arm_LOD1"]
    for row in result["maps"]:
        assert row["texels_filled"] > 0.3 * 64 * 64 and 1 <= row["max_tile_influences"] <= 16
        assert row["max_angular_error"] < 0.1  # the posed LOD0 faces, to 16-bit storage
        image_input = oiio.ImageInput.open(row["path"])
        assert image_input.spec().getattribute("skinkit:tile") == 8
        assert image_input.spec().nchannels == 9 * row["max_tile_influences"]
        image_input.close()
        assert nm.read_image(row["normal_map"]).dtype == np.uint16
        assert [nm.read_image(path).shape[:2] for path in row["mips"]] == [(32, 32), (16, 16)]
    _, result = skinkit("bake-tangent-maps", scene, "--size", "64", "--max-influences", "1", "--out-dir", str(maps),
                        "--json", expect_success=False)
    assert "need more than max_influences = 1" in result["error"]
