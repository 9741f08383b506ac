"""Animated Unwrap in real Blender: the operator on the sample characters, the UV map it writes (and the
ones it keeps), the layout image, the metrics read from the scene, and bad input refused with the scene
unchanged."""
import bpy
import numpy as np
import pytest
from tests.blender.test_skinning import scene_fingerprint, select

from skinkit import SkinkitError
from skinkit.blender import pose_statistics
from skinkit.blender import unwrap as blender_unwrap
from skinkit.blender.rig import mesh_of, skeleton_parents
from skinkit.metrics import PoseStatistics
from skinkit.unwrap import edge_lengths_sq, sequence_embedding


def written_uv(mesh_object, name=blender_unwrap.UV_MAP_NAME) -> np.ndarray:
    """(T, 3, 2): the UV map's coordinates at each loop triangle's corners."""
    data = mesh_object.data
    loop_uv = np.empty(len(data.loops) * 2, np.float32)
    data.uv_layers[name].uv.foreach_get("vector", loop_uv)
    return loop_uv.reshape(-1, 2)[mesh_of(mesh_object).triangle_loops].astype(np.float64)


def uv_state(mesh_object) -> dict:
    data = mesh_object.data
    seams = np.empty(len(data.edges), bool)
    data.edges.foreach_get("use_seam", seams)
    return {"maps": [layer.name for layer in data.uv_layers],
            "active": data.uv_layers.active.name if data.uv_layers.active else None, "seams": int(seams.sum())}


def signed_uv_areas(uv: np.ndarray) -> np.ndarray:
    first, second = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return (first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0]) / 2


@pytest.mark.parametrize("name", ["arm", "creature"])
def test_unwrap_over_the_action_writes_a_new_uv_map_without_flips(open_sample, addon, name):
    mesh_object = open_sample(name)
    select(mesh_object)
    mesh_object.data.uv_layers.new(name="artist")
    assert bpy.ops.skinkit.animated_unwrap(metric="FRAMES", mark_seams=True) == {"FINISHED"}
    state = uv_state(mesh_object)
    assert state["maps"] == ["artist", blender_unwrap.UV_MAP_NAME] and state["active"] == "artist"
    uv = written_uv(mesh_object)
    areas = signed_uv_areas(uv)
    assert np.all(areas > 1e-12 * areas.sum()), "flipped or degenerate uv triangles"
    assert uv.min() >= 0 and uv.max() <= 1
    report = mesh_object.data[blender_unwrap.REPORT_PROPERTY]
    assert report["charts"] >= 2 and state["seams"] > 0
    assert 1.0 <= report["stretch_rest"] < 2.0 and 1.0 <= report["stretch_frames"] < 2.0
    assert 0.2 < report["packing_efficiency"] <= 1 and report["texture_efficiency"] < report["packing_efficiency"]

    assert bpy.ops.skinkit.show_uv_layout(size=256) == {"FINISHED"}
    image = bpy.data.images[f"{mesh_object.name} UV layout"]
    pixels = np.empty(256 * 256 * 4, np.float32)
    image.pixels.foreach_get(pixels)
    covered = (pixels.reshape(-1, 4)[:, 3] > 0).mean()
    assert covered == pytest.approx(report["packing_efficiency"], abs=0.1)


def test_unwrap_again_replaces_its_map_and_can_make_it_active(open_sample, addon):
    mesh_object = open_sample("arm")
    select(mesh_object)
    assert bpy.ops.skinkit.animated_unwrap(metric="REST", mode="AUTO", chart_count=6) == {"FINISHED"}
    assert bpy.ops.skinkit.animated_unwrap(metric="REST", make_active=True, straighten=False) == {"FINISHED"}
    assert uv_state(mesh_object) == {"maps": [blender_unwrap.UV_MAP_NAME], "active": blender_unwrap.UV_MAP_NAME,
                                     "seams": 0}


def test_seams_only_mode_follows_the_marked_seams(open_sample, addon):
    mesh_object = open_sample("arm")
    select(mesh_object)
    assert bpy.ops.skinkit.animated_unwrap(metric="REST", mark_seams=True) == {"FINISHED"}
    first = mesh_object.data[blender_unwrap.REPORT_PROPERTY]["charts"]
    assert bpy.ops.skinkit.animated_unwrap(metric="REST", mode="SEAMS") == {"FINISHED"}
    assert mesh_object.data[blender_unwrap.REPORT_PROPERTY]["charts"] == first


def test_animation_metric_of_the_rest_pose_is_the_rest_metric(open_sample):
    mesh_object = open_sample("creature")
    armature = mesh_object.modifiers["Armature"].object
    fixed = PoseStatistics.fixed_skeleton(skeleton_parents(armature), pose_statistics.rest_local(armature))
    mesh = mesh_of(mesh_object)
    np.testing.assert_allclose(edge_lengths_sq(blender_unwrap.animation_metric(mesh_object, fixed), mesh.triangles),
                               edge_lengths_sq(mesh.positions, mesh.triangles), rtol=1e-5, atol=1e-9)


def test_animation_metric_uses_the_stored_pose_statistics(open_sample, addon):
    mesh_object = open_sample("arm")
    armature = mesh_object.modifiers["Armature"].object
    select(mesh_object)
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="'arm_rig' has no pose statistics"):
        bpy.ops.skinkit.animated_unwrap(metric="ANIMATION")
    assert scene_fingerprint() == before and blender_unwrap.UV_MAP_NAME not in mesh_object.data.uv_layers
    pose_statistics.store(armature, pose_statistics.compute(armature, "action", range(1, 41)), "action", 40)
    assert bpy.ops.skinkit.animated_unwrap(metric="ANIMATION") == {"FINISHED"}
    assert mesh_object.data[blender_unwrap.REPORT_PROPERTY]["metric_dimensions"] == 16  # 4 x (root + 3 bones)


def test_the_animation_metric_of_an_action_is_that_action_s_and_beats_the_rest_pose_over_it(open_sample):
    """Issue 18: with statistics computed from the action, Animated Unwrap's metric is the action's own (the joint
    statistics' independent-joints estimate was 0.76-1.22x its squared edge lengths on the creature), and over that
    action it stretches less than the rest-pose atlas, so the fall-back is not needed."""
    mesh_object = open_sample("creature")
    armature = mesh_object.modifiers["Armature"].object
    frames = blender_unwrap.deforming_action_frames(mesh_object)
    pose_statistics.store(armature, pose_statistics.compute(armature, "action", frames), "action", len(frames))
    job = blender_unwrap.prepare_unwrap(mesh_object, metric="animation")
    triangles = job.mesh.triangles
    action = edge_lengths_sq(sequence_embedding(job.evaluation_frames), triangles)
    ratio = edge_lengths_sq(job.embedding, triangles) / action
    assert np.abs(ratio - 1).max() < 1e-3  # Blender deforms in single precision
    independent = edge_lengths_sq(blender_unwrap.animation_metric(mesh_object), triangles) / action
    assert np.abs(independent - 1).max() > 0.1  # guards the test: the stored joint statistics are not the action's
    report = job.solve().report
    assert report["status"] == "ok" and report["metric_used"] == "metric" and report["fallback"] == ""
    rest = blender_unwrap.prepare_unwrap(mesh_object, metric="rest").solve().report
    assert report["stretch_frames"] < rest["stretch_frames"]


def broken_copy(mesh_object, damage):
    """A new object with a damaged copy of the mesh, made active."""
    import bmesh  # Blender's module, importable once bpy is

    mesh = mesh_object.data.copy()
    editable = bmesh.new()
    editable.from_mesh(mesh)
    damage(editable)
    editable.to_mesh(mesh)
    editable.free()
    copy = bpy.data.objects.new("broken", mesh)
    bpy.context.scene.collection.objects.link(copy)
    select(copy)
    return copy


def add_fin(editable):
    """A third face on an existing edge: a non-manifold edge."""
    editable.edges.ensure_lookup_table()
    edge = editable.edges[0]
    tip = editable.verts.new(edge.verts[0].co + edge.verts[1].co.cross(edge.verts[0].co).normalized() * 0.1)
    editable.faces.new((edge.verts[0], edge.verts[1], tip))


def collapse_face(editable):
    """Every vertex of one face moved onto one point: a face of zero area."""
    editable.faces.ensure_lookup_table()
    face = editable.faces[10]
    for vertex in face.verts[1:]:
        vertex.co = face.verts[0].co.copy()


@pytest.mark.parametrize("damage, message", [(add_fin, "'broken': edge .* is shared by 3 faces"),
                                             (collapse_face, "'broken': face .* has zero area")])
def test_bad_meshes_are_refused_with_the_scene_unchanged(open_sample, addon, damage, message):
    mesh_object = open_sample("arm")
    copy = broken_copy(mesh_object, damage)
    before, uv_before = scene_fingerprint(), uv_state(copy)
    with pytest.raises(RuntimeError, match=message):
        bpy.ops.skinkit.animated_unwrap(metric="REST", mark_seams=True)
    assert scene_fingerprint() == before and uv_state(copy) == uv_before


def test_a_mesh_with_every_uv_map_slot_taken_is_refused(open_sample, addon):
    mesh_object = open_sample("arm")
    select(mesh_object)
    for number in range(blender_unwrap.MAX_UV_MAPS):
        mesh_object.data.uv_layers.new(name=f"map {number}")
    before = uv_state(mesh_object)
    with pytest.raises(RuntimeError, match="already has 8 UV maps"):
        bpy.ops.skinkit.animated_unwrap(metric="REST")
    assert uv_state(mesh_object) == before


def test_frames_metric_needs_an_action(open_sample, addon):
    mesh_object = open_sample("arm")
    mesh_object.modifiers["Armature"].object.animation_data.action = None
    select(mesh_object)
    with pytest.raises(RuntimeError, match="needs an armature with an action"):
        bpy.ops.skinkit.animated_unwrap(metric="FRAMES")


def test_a_job_does_not_write_to_a_mesh_changed_while_it_was_solved(open_sample):
    """What the operator's worker thread relies on: prepare, then the user edits, then nothing is written."""
    mesh_object = open_sample("arm")
    job = blender_unwrap.prepare_unwrap(mesh_object, metric="rest", chart_count=6)
    result = job.solve()
    mesh_object.data.vertices.add(1)
    before = uv_state(mesh_object)
    with pytest.raises(SkinkitError, match="'arm': the mesh changed while it was being unwrapped"):
        job.write(mesh_object, result)
    assert uv_state(mesh_object) == before and blender_unwrap.REPORT_PROPERTY not in mesh_object.data
