"""`skinkit decompose` as a user runs it: an .obj folder in, JSON and reconstructed .obj frames out."""
import os

import numpy as np
import pytest
from tests.sequences import rigid_chain_sequence
from tests.cli.obj_folders import write_obj_folder
from tests.cli.test_cli import skinkit

from skinkit.meshio import read_obj, write_obj


@pytest.fixture(scope="module")
def obj_folder(tmp_path_factory):
    frames, triangles, _, _ = rigid_chain_sequence(segments=3, frames=10)
    return write_obj_folder(tmp_path_factory.mktemp("tube_sequence"), frames, triangles), frames


def test_decompose_reports_and_exports_every_frame(obj_folder, tmp_path):
    folder, frames = obj_folder
    exported = tmp_path / "frames"
    _, report = skinkit("decompose", "--sequence", folder, "--bones", "3", "--max-influences", "2", "--train", "1-7",
                        "--sequence-scale", "0.01", "--export-frames", str(exported), "--json")
    assert report["vertices"] == frames.shape[1] and report["frames"] == 10 and report["bones"] == 3
    assert report["training_frames"] == 7 and report["seconds"] > 0 and report["peak_memory_mb"] > 0
    for part in ("train", "held_out"):
        for model in ("animation_space", "linear_blend"):
            assert report[model][part]["rms"] < 1e-6 and report[model][part]["max"] < 1e-5
    files = sorted(os.listdir(exported))
    assert len(files) == 10
    replayed, _ = read_obj(str(exported / files[-1]))
    assert np.abs(replayed / 100.0 - frames[-1]).max() < 1e-5  # the input's units and vertex order


def test_decompose_saves_a_blend_with_the_rig(obj_folder, tmp_path):
    folder, _ = obj_folder
    out = tmp_path / "skinned.blend"
    _, report = skinkit("decompose", "--sequence", folder, "--bones", "3", "--out", str(out), "--json")
    assert os.path.isfile(out) and report["armature"] and report["skinned_object"]


@pytest.mark.parametrize("arguments, message", [
    (["--bones", "100000"], "bone count"),
    (["--train", "1"], "training frame"),
    (["--out", "x.fbx"], "expected a .blend or .glb"),
    (["--memory-limit", "1K"], "of memory, but 1.0 KiB is available (the memory limit)"),
])
def test_decompose_errors_are_clear(obj_folder, arguments, message):
    status, report = skinkit("decompose", "--sequence", obj_folder[0], *arguments, "--json", expect_success=False)
    assert status == 1 and message in report["error"]


def test_a_folder_with_different_vertex_counts_is_refused(tmp_path):
    frames, triangles, _, _ = rigid_chain_sequence(segments=2, frames=3)
    write_obj(str(tmp_path / "a.obj"), frames[0], triangles)
    write_obj(str(tmp_path / "b.obj"), frames[1][:-2])
    status, report = skinkit("decompose", "--sequence", str(tmp_path), "--json", expect_success=False)
    assert status == 1 and "vertices" in report["error"]


def test_rough_rig_from_a_blend(obj_folder, tmp_path):
    """A drawn armature and the mesh with core-vertex groups, saved by Blender; the sequence from the .obj folder."""
    import bpy

    folder, frames = obj_folder
    from tests.sequences import rigid_chain_sequence

    _, triangles, segment, _ = rigid_chain_sequence(segments=3, frames=10)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = bpy.data.meshes.new("tube")
    mesh.from_pydata(frames[0].tolist(), [], triangles.tolist())
    mesh_object = bpy.data.objects.new("tube", mesh)
    bpy.context.scene.collection.objects.link(mesh_object)
    armature = bpy.data.objects.new("drawn", bpy.data.armatures.new("drawn"))
    bpy.context.scene.collection.objects.link(armature)
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    previous = None
    for index in range(3):
        bone = armature.data.edit_bones.new(f"seg{index}")
        bone.head, bone.tail, bone.parent = (0.0, index + 0.1, 0.0), (0.0, index + 0.9, 0.0), previous
        previous = bone
    bpy.ops.object.mode_set(mode="OBJECT")
    for index in range(3):
        core = np.flatnonzero((segment == index) & (np.abs(frames[0][:, 1] - (index + 0.5)) < 0.3))
        mesh_object.vertex_groups.new(name=f"seg{index}").add(core.tolist(), 1.0, "REPLACE")
    rig_path = str(tmp_path / "drawn.blend")
    bpy.ops.wm.save_as_mainfile(filepath=rig_path)
    out = str(tmp_path / "fitted.blend")
    _, report = skinkit("decompose", "--sequence", folder, "--sequence-scale", "0.01", "--method", "rough-rig",
                        "--rig", rig_path, "--train", "1-7", "--out", out, "--json")
    assert report["bones"] == 3 and report["animation_space"]["held_out"]["max"] < 1e-5 and os.path.isfile(out)
