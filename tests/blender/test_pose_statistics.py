"""Pose statistics in real Blender: from an action, from rotation limits, stored and invalidated on the
armature; the culling sphere and max-distance heat map of a mesh; the stats and distance commands."""
import bpy
import numpy as np
import pytest
from tests.conftest import sample_path
from tests.blender.test_skinning import scene_fingerprint, select
from tests.blender.test_fitting import run_cli

from skinkit import SkinkitError
from skinkit.blender import pose_statistics, skinning
from skinkit.blender.rig import rig_of


def test_statistics_from_the_action_bound_the_animated_mesh(open_sample):
    mesh_object = open_sample("creature")
    armature = rig_of(mesh_object).armature_object
    skinning.convert_object(mesh_object)
    computed = pose_statistics.from_frames(armature, range(1, 49))
    pose_statistics.store(armature, computed, "test", 48)
    assert pose_statistics.summary(armature)["up_to_date"]
    loaded = pose_statistics.load(armature)
    assert np.array_equal(loaded.expected_gram, computed.expected_gram)
    bounds = pose_statistics.write_bound_heat_map(mesh_object)
    posed = skinning.positions_over_frames(mesh_object, range(1, 49))
    distance_from_centre = np.linalg.norm(posed - bounds["centre"], axis=2)
    assert distance_from_centre.max() <= bounds["radius"]
    assert np.all(distance_from_centre.max(axis=0) <= bounds["per_vertex"] * (1 + 1e-6))
    assert pose_statistics.BOUND_HEAT_ATTRIBUTE in mesh_object.data.color_attributes


def test_stored_statistics_go_out_of_date_when_the_rig_changes(open_sample):
    mesh_object = open_sample("arm")
    armature = rig_of(mesh_object).armature_object
    pose_statistics.store(armature, pose_statistics.from_limits(armature), "limits", 0)
    armature.data.bones["hand"].name = "palm"
    assert not pose_statistics.summary(armature)["up_to_date"]
    with pytest.raises(SkinkitError, match="out of date"):
        pose_statistics.load(armature)


def test_bad_statistics_requests(open_sample):
    mesh_object = open_sample("arm")
    armature = rig_of(mesh_object).armature_object
    with pytest.raises(SkinkitError, match="the frame range is empty"):
        pose_statistics.from_frames(armature, [])
    armature.animation_data.action = bpy.data.actions.new("still")
    with pytest.raises(SkinkitError, match="does not move over frames 1-40"):
        pose_statistics.from_frames(armature, range(1, 41))
    with pytest.raises(SkinkitError, match="has no pose statistics"):
        pose_statistics.load(armature)


def test_operator_computes_and_stores(open_sample, addon):
    mesh_object = open_sample("creature")
    select(rig_of(mesh_object).armature_object)
    bpy.context.scene.skinkit.stats_step = 4
    assert bpy.ops.skinkit.compute_pose_statistics(source="ACTION") == {"FINISHED"}
    summary = pose_statistics.summary(rig_of(mesh_object).armature_object)
    assert summary["bones"] == 26 and summary["up_to_date"] and "step 4" in summary["source"]
    assert bpy.ops.skinkit.compute_pose_statistics(source="UNIFORM") == {"FINISHED"}
    bpy.context.scene.skinkit.stats_poses = "1, 13, 25-27"
    assert bpy.ops.skinkit.compute_pose_statistics(source="POSES") == {"FINISHED"}
    assert pose_statistics.summary(rig_of(mesh_object).armature_object)["frames"] == 5
    assert bpy.ops.skinkit.compute_pose_statistics(source="POSES", spread=0.2) == {"FINISHED"}
    assert "spread 11.5 degrees" in pose_statistics.summary(rig_of(mesh_object).armature_object)["source"]
    assert bpy.ops.skinkit.compute_pose_statistics(source="UNIFORM", spread=0.2) == {"FINISHED"}  # analytic: none
    select(mesh_object)
    skinning.convert_object(mesh_object)
    assert bpy.ops.skinkit.show_max_distance() == {"FINISHED"}
    before = scene_fingerprint()
    rig_of(mesh_object).armature_object.animation_data.action = None
    bpy.context.scene.frame_set(1)
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="does not move"):
        bpy.ops.skinkit.compute_pose_statistics(source="ACTION")
    assert scene_fingerprint() == before


def test_stats_and_distance_commands(tmp_path):
    out = str(tmp_path / "with_statistics.blend")
    status, result = run_cli("stats", sample_path("creature"), "--frames", "1:48:2", "--out", out)
    assert status == 0 and result["bones"] == 26 and result["frames"] == 24
    assert 0 < result["rank"] < result["unknowns"]  # P is singular (appendix B.3)
    assert result["culling_sphere"]["radius"] > 0
    status, result = run_cli("distance", out, "--from-vertices", "0,100", "--to-vertices", "5000")
    assert status == 0 and len(result["pairs"]) == 2
    assert all(0 < pair["mean"] <= pair["max"] for pair in result["pairs"])
    status, result = run_cli("distance", out, "--from-vertices", "0", "--to-vertices", "99999")
    assert status == 1 and "vertex indices must be in [0, 11086)" in result["error"]
    status, result = run_cli("stats", sample_path("arm"), "--action", "missing")
    assert status == 1 and "no action named 'missing'" in result["error"]
    status, result = run_cli("stats", sample_path("arm"), "--from", "limits")
    assert status == 0 and result["source"] == "rotation limits"
    status, result = run_cli("stats", sample_path("arm"), "--from", "poses", "--poses", "1, 10, 20-22")
    assert status == 0 and result["frames"] == 5 and result["source"] == "5 example poses"
    status, result = run_cli("stats", sample_path("arm"), "--from", "poses", "--poses", "1, 20", "--spread", "10")
    assert status == 0 and result["source"] == "2 example poses, spread 10 degrees" and result["spread_degrees"] == 10
    status, result = run_cli("stats", sample_path("arm"), "--spread", "200")
    assert status == 1 and "--spread: expected degrees in [0, 180], got 200" in result["error"]
    status, result = run_cli("stats", sample_path("arm"), "--from", "uniform", "--spread", "5")
    assert status == 1 and "only sampled statistics" in result["error"]
    status, result = run_cli("stats", sample_path("arm"), "--from", "poses")
    assert status == 1 and "the frame range is empty" in result["error"]
