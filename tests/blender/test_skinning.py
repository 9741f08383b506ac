"""skinkit inside real (headless) Blender: conversion against the Armature modifier, storage, preview,
baking, operators, and bad scenes that must be refused with the scene left as it was."""
import hashlib

import bpy
import numpy as np
import pytest
from tests.conftest import SAMPLE_NAMES

from skinkit import SkinkitError, meshcache
from skinkit.blender import preview, skinning, storage
from skinkit.blender.frames import armature_modifier_only, evaluated_positions
from skinkit.blender.rig import rest_positions, rig_of

TOLERANCE = 1e-6  # of the bounding-box diagonal


def random_pose(armature_object, rng, max_angle=1.2, scale_spread=0.2):
    """Random rotation, small translation and mild non-uniform scale (1 +- scale_spread; none, a rigid pose, at 0)
    on every pose bone."""
    for pose_bone in armature_object.pose.bones:
        axis = rng.normal(size=3)
        angle = rng.uniform(0, max_angle)
        pose_bone.rotation_mode = "QUATERNION"
        pose_bone.rotation_quaternion = (np.cos(angle / 2), *(np.sin(angle / 2) * axis / np.linalg.norm(axis)))
        pose_bone.location = rng.normal(scale=0.05, size=3)
        pose_bone.scale = rng.uniform(1 - scale_spread, 1 + scale_spread, size=3) if scale_spread else (1, 1, 1)
    bpy.context.view_layer.update()


def deviation_now(mesh_object) -> float:
    depsgraph = bpy.context.evaluated_depsgraph_get()
    reference = evaluated_positions(mesh_object, depsgraph)
    ours = skinning.model_positions(mesh_object, depsgraph)
    return float(np.linalg.norm(ours - reference, axis=1).max())


def scene_fingerprint() -> dict:
    """Everything a failed operation must not have touched."""
    objects = {}
    for obj in bpy.data.objects:
        entry = {"modifiers": [(m.name, m.type, m.show_viewport, m.show_render) for m in obj.modifiers],
                 "groups": [g.name for g in obj.vertex_groups], "props": sorted(obj.keys())}
        if obj.type == "MESH":
            mesh = obj.data
            positions = np.empty(len(mesh.vertices) * 3, np.float32)
            mesh.vertices.foreach_get("co", positions)
            entry.update(attributes=sorted(a.name for a in mesh.attributes), mesh_props=sorted(mesh.keys()),
                         shape_keys=[k.name for k in mesh.shape_keys.key_blocks] if mesh.shape_keys else [],
                         positions=hashlib.sha1(positions.tobytes()).hexdigest())
        objects[obj.name] = entry
    return {"objects": objects, "node_groups": sorted(g.name for g in bpy.data.node_groups),
            "meshes": sorted(m.name for m in bpy.data.meshes), "frame": bpy.context.scene.frame_current}


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_conversion_reproduces_the_armature_modifier_over_50_random_poses(open_sample, name):
    mesh_object = open_sample(name)
    skinning.convert_object(mesh_object)
    armature = rig_of(mesh_object).armature_object
    armature.animation_data_clear()
    diagonal = skinning.bounding_box_diagonal(rest_positions(mesh_object))
    rng = np.random.default_rng(42)
    worst = 0.0
    with armature_modifier_only(mesh_object):
        for _ in range(50):
            random_pose(armature, rng)
            worst = max(worst, deviation_now(mesh_object))
    assert worst / diagonal < TOLERANCE
    assert worst > 0.0  # the poses were really evaluated by both


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_compare_over_the_action(open_sample, name):
    mesh_object = open_sample(name)
    skinning.convert_object(mesh_object)
    frame = bpy.context.scene.frame_current
    report = skinning.compare_with_armature(mesh_object, range(1, 41))
    assert report["max_deviation"] < TOLERANCE
    assert report["frames"] == 40 and report["vertices"] == len(mesh_object.data.vertices)
    assert bpy.context.scene.frame_current == frame


def test_model_survives_saving_and_reloading(open_sample, tmp_path):
    mesh_object = open_sample("creature")
    name = mesh_object.name
    summary = skinning.convert_object(mesh_object)
    original = storage.read_model(mesh_object.data, name)
    path = str(tmp_path / "saved.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    reloaded_object = bpy.data.objects[name]
    reloaded = storage.read_model(reloaded_object.data, reloaded_object.name)
    assert reloaded.bone_names == original.bone_names
    assert np.array_equal(reloaded.model.offsets, original.model.offsets)
    assert np.array_equal(reloaded.model.bones, original.model.bones)
    assert np.array_equal(reloaded.model.coordinates, original.model.coordinates)
    assert storage.model_summary(reloaded_object.data)["bones"] == summary["bones"]
    assert skinning.compare_with_armature(reloaded_object, range(1, 48, 5))["max_deviation"] < TOLERANCE


def test_stored_model_keeps_full_float32_precision(open_sample):
    mesh_object = open_sample("arm")
    skinning.convert_object(mesh_object)
    stored = storage.read_model(mesh_object.data, mesh_object.name)
    homogeneous = stored.model.homogeneous_weights()
    assert np.abs(homogeneous - 1).max() < 1e-6


def test_mesh_without_model_is_detected_cleanly(open_sample):
    mesh_object = open_sample("arm")
    assert not storage.has_model(mesh_object.data)
    assert storage.model_summary(mesh_object.data) is None
    with pytest.raises(SkinkitError, match="'arm' has no animation-space model"):
        storage.read_model(mesh_object.data, "arm")


def test_damaged_or_newer_models_are_refused(open_sample):
    mesh_object = open_sample("arm")
    skinning.convert_object(mesh_object)
    mesh = mesh_object.data
    mesh.attributes.remove(mesh.attributes["skinkit_as_p_0"])
    with pytest.raises(SkinkitError, match="missing point attribute 'skinkit_as_p_0'"):
        storage.read_model(mesh, "arm")
    skinning.convert_object(mesh_object)
    mesh[storage.PROPERTY]["layout_version"] = 99
    with pytest.raises(SkinkitError, match="layout version 99 is not supported"):
        storage.read_model(mesh, "arm")


def refuse(mesh_object, message):
    before = scene_fingerprint()
    with pytest.raises(SkinkitError, match=message):
        skinning.convert_object(mesh_object)
    assert scene_fingerprint() == before


def test_bad_scenes_are_refused_and_left_unchanged(open_sample):
    mesh_object = open_sample("arm")
    armature = rig_of(mesh_object).armature_object

    group = mesh_object.vertex_groups.new(name="not_a_bone")
    group.add([0, 1, 2], 1.0, "REPLACE")
    refuse(mesh_object, r"vertex groups \['not_a_bone'\] name no bone of armature 'arm_rig'")
    assert skinning.convert_object(mesh_object, ignore_unmatched_groups=True)["bones"] == 3
    storage.remove_model(mesh_object.data)
    mesh_object.vertex_groups.remove(group)

    refuse(armature, "'arm_rig' is a armature, not a mesh")

    modifier = rig_of(mesh_object).modifier
    modifier.use_bone_envelopes = True
    refuse(mesh_object, "uses bone envelopes")
    modifier.use_bone_envelopes = False

    modifier.object = None
    refuse(mesh_object, "has no armature object")
    modifier.object = armature

    positions = np.empty(len(mesh_object.data.vertices) * 3, np.float32)
    mesh_object.data.vertices.foreach_get("co", positions)
    positions[7] = np.nan
    mesh_object.data.vertices.foreach_set("co", positions)
    refuse(mesh_object, r"'arm': rest_vectors: contains NaN or infinity \(first at index \(2, 1\)\)")

    mesh_object.modifiers.remove(modifier)
    refuse(mesh_object, "'arm' has no Armature modifier")


def test_preview_deforms_like_the_armature_and_turns_off_cleanly(open_sample, addon):
    mesh_object = open_sample("creature")
    skinning.convert_object(mesh_object)
    before = scene_fingerprint()
    armature = rig_of(mesh_object).armature_object
    preview.enable(mesh_object, bpy.context.evaluated_depsgraph_get())
    assert not rig_of(mesh_object).modifier.show_viewport
    assert preview.KEY_NAME in mesh_object.data.shape_keys.key_blocks

    bpy.context.scene.frame_set(17)  # the frame-change handler refreshes the preview
    previewed = evaluated_positions(mesh_object, bpy.context.evaluated_depsgraph_get())
    expected = skinning.model_positions(mesh_object, bpy.context.evaluated_depsgraph_get())
    diagonal = skinning.bounding_box_diagonal(rest_positions(mesh_object))
    assert np.linalg.norm(previewed - expected, axis=1).max() / diagonal < TOLERANCE

    armature.animation_data_clear()
    random_pose(armature, np.random.default_rng(3))  # the depsgraph handler sees the pose change
    previewed = evaluated_positions(mesh_object, bpy.context.evaluated_depsgraph_get())
    expected = skinning.model_positions(mesh_object, bpy.context.evaluated_depsgraph_get())
    assert np.linalg.norm(previewed - expected, axis=1).max() / diagonal < TOLERANCE

    preview.disable(mesh_object)
    after = scene_fingerprint()
    before["frame"] = after["frame"]
    assert after == before


def test_bake_to_shape_keys_replays_the_model(open_sample):
    mesh_object = open_sample("arm")
    skinning.convert_object(mesh_object)
    frames = range(5, 15)
    positions = skinning.positions_over_frames(mesh_object, frames)
    baked = skinning.bake_shape_keys(mesh_object, frames, positions)
    assert not baked.modifiers and not storage.has_model(baked.data)
    assert len(baked.data.shape_keys.key_blocks) == 1 + len(frames)
    for index in (0, 4, 9):
        bpy.context.scene.frame_set(frames[index])
        played = evaluated_positions(baked, bpy.context.evaluated_depsgraph_get())
        assert np.abs(played - positions[index]).max() < 1e-5


def test_bake_to_mesh_cache_plays_back(open_sample, tmp_path):
    mesh_object = open_sample("creature")
    skinning.convert_object(mesh_object)
    frames = range(1, 13)
    positions = skinning.positions_over_frames(mesh_object, frames)
    path = str(tmp_path / "creature.pc2")
    player = skinning.bake_mesh_cache(mesh_object, path, frames, positions, add_object=True)
    stored, start, _ = meshcache.read_pc2(path)
    assert start == 1 and np.array_equal(stored, positions)
    bpy.context.scene.frame_set(7)
    played = evaluated_positions(player, bpy.context.evaluated_depsgraph_get())
    assert np.abs(played - positions[6]).max() < 1e-5


def select(mesh_object):
    bpy.context.view_layer.objects.active = mesh_object


def test_operators_run_and_refuse_bad_input(open_sample, addon, tmp_path):
    mesh_object = open_sample("arm")
    select(mesh_object)
    mesh_object.vertex_groups.new(name="stray").add([0], 1.0, "REPLACE")
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="name no bone"):
        bpy.ops.skinkit.convert_to_animation_space()
    assert scene_fingerprint() == before

    assert bpy.ops.skinkit.convert_to_animation_space(ignore_unmatched_groups=True) == {"FINISHED"}
    assert storage.has_model(mesh_object.data)
    settings = bpy.context.scene.skinkit
    settings.use_scene_range, settings.frame_start, settings.frame_end = False, 1, 10
    assert bpy.ops.skinkit.compare_with_armature() == {"FINISHED"}
    assert addon.state.LAST_COMPARISON[addon.state.key(mesh_object)]["max_deviation"] < TOLERANCE
    assert bpy.ops.skinkit.toggle_preview() == {"FINISHED"} and preview.is_enabled(mesh_object)
    assert bpy.ops.skinkit.toggle_preview() == {"FINISHED"} and not preview.is_enabled(mesh_object)
    assert bpy.ops.skinkit.bake_shape_keys() == {"FINISHED"}
    assert "arm_skinkit_baked" in bpy.data.objects
    settings.cache_path = str(tmp_path / "arm.pc2")
    assert bpy.ops.skinkit.bake_mesh_cache() == {"FINISHED"}
    assert meshcache.read_pc2(settings.cache_path)[0].shape == (10, len(mesh_object.data.vertices), 3)
    settings.cache_path = str(tmp_path / "arm.txt")
    with pytest.raises(RuntimeError, match="must end in .pc2"):
        bpy.ops.skinkit.bake_mesh_cache()
    assert bpy.ops.skinkit.remove_model() == {"FINISHED"} and not storage.has_model(mesh_object.data)


class RecordingLayout:
    """Stands in for bpy.types.UILayout (which only exists while Blender draws a window)."""

    def __init__(self, record=None):
        self.record = [] if record is None else record

    def __getattr__(self, name):
        def call(*args, **kwargs):
            self.record.append((name, args, kwargs))
            return RecordingLayout(self.record)
        return call

    def texts(self):
        return [kwargs.get("text", args[0] if args else "") for _, args, kwargs in self.record]


def draw_panel(addon):
    panel = type("Panel", (), {"layout": RecordingLayout()})()
    addon.ui.SKINKIT_PT_main.draw(panel, bpy.context)
    return panel.layout


def test_panel_shows_the_model_state(open_sample, addon):
    mesh_object = open_sample("arm")
    select(mesh_object)
    assert "No animation-space model" in draw_panel(addon).texts()
    skinning.convert_object(mesh_object)
    texts = draw_panel(addon).texts()
    assert "Animation space: 3 bones (armature 'arm_rig')" in texts
    assert any(t.startswith("Influences per vertex: 1.16 mean, 2 max") for t in texts)
    operators = [args[0] for name, args, _ in draw_panel(addon).record if name == "operator"]
    assert "skinkit.toggle_preview" in operators and "skinkit.bake_mesh_cache" in operators
    mesh_object.modifiers.remove(rig_of(mesh_object).modifier)
    assert "'arm' has no Armature modifier" in draw_panel(addon).texts()


def test_mesh_triangles_map_back_to_polygons_and_loops(open_sample):
    from skinkit.blender.rig import mesh_of

    mesh_object = open_sample("arm")
    mesh = mesh_of(mesh_object)
    blender_mesh = mesh_object.data
    assert mesh.vertex_count == len(blender_mesh.vertices)
    quads = sum(1 for p in blender_mesh.polygons if p.loop_total == 4)
    assert len(mesh.triangles) == 2 * quads + (len(blender_mesh.polygons) - quads)
    loop_vertices = np.empty(len(blender_mesh.loops), np.int32)
    blender_mesh.loops.foreach_get("vertex_index", loop_vertices)
    assert np.array_equal(loop_vertices[mesh.triangle_loops], mesh.triangles)
    polygon_starts = np.array([p.loop_start for p in blender_mesh.polygons])
    polygon_totals = np.array([p.loop_total for p in blender_mesh.polygons])
    first_loops = mesh.triangle_loops.min(axis=1)
    assert np.all(first_loops >= polygon_starts[mesh.triangle_polygons])
    assert np.all(mesh.triangle_loops.max(axis=1) < (polygon_starts + polygon_totals)[mesh.triangle_polygons])


def test_session_state_does_not_survive_opening_a_file(open_sample, addon):
    """The last comparison and the culling spheres belong to this session's objects: after another file is
    loaded (even one with an object of the same name) none remains, and the panel shows no comparison."""
    mesh_object = open_sample("arm")
    select(mesh_object)
    assert bpy.ops.skinkit.convert_to_animation_space() == {"FINISHED"}
    settings = bpy.context.scene.skinkit
    settings.use_scene_range, settings.frame_start, settings.frame_end = False, 1, 10
    assert bpy.ops.skinkit.compare_with_armature() == {"FINISHED"}
    assert bpy.ops.skinkit.compute_pose_statistics(source="ACTION") == {"FINISHED"}
    assert bpy.ops.skinkit.show_max_distance() == {"FINISHED"}
    assert addon.state.LAST_COMPARISON and addon.state.CULLING_SPHERES
    assert any(str(t).startswith("Max deviation from Armature") for t in draw_panel(addon).texts())

    reopened = open_sample("arm")
    assert not addon.state.LAST_COMPARISON and not addon.state.CULLING_SPHERES
    select(reopened)
    skinning.convert_object(reopened)
    assert not any(str(t).startswith("Max deviation from Armature") for t in draw_panel(addon).texts())
