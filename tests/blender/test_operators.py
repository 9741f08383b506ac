"""Every operator as an artist and a technical director meet it (issue 18): in Edit Mode, with no active object,
called from a script with every option as a keyword, undone, and on a model that no longer matches its rig."""
import hashlib
import os
import warnings

import bpy
import numpy as np
import pytest
from tests.blender.test_fitting import FRAMES, add_shape_key_examples, dual_quaternion_examples
from tests.blender.test_skinning import draw_panel, scene_fingerprint, select

from skinkit import SkinkitError
from skinkit.blender import attributes, compat, fitting, pose_statistics, preview, skinning, storage
from skinkit.blender.rig import rig_of
from skinkit.fit import DEFAULT_LAMBDA

#: Every operator that works on the active mesh, with keywords that make it runnable on the prepared arm.
MESH_OPERATORS = ("convert_to_animation_space", "toggle_preview", "remove_model", "compare_with_armature",
                  "bake_shape_keys", "bake_mesh_cache", "fit_from_examples", "skin_from_sequence", "show_fit_error",
                  "show_max_distance", "animated_unwrap", "show_uv_layout")


def operator(name):
    return getattr(bpy.ops.skinkit, name)


def prepared_arm(open_sample):
    """The arm with a model, pose statistics, a fit's heat map and an atlas, active: every operator can run."""
    mesh_object = open_sample("arm")
    select(mesh_object)
    add_shape_key_examples(mesh_object, dual_quaternion_examples(mesh_object, FRAMES), FRAMES)
    assert bpy.ops.skinkit.fit_from_examples(source="SHAPE_KEYS") == {"FINISHED"}
    assert bpy.ops.skinkit.compute_pose_statistics(source="UNIFORM") == {"FINISHED"}
    assert bpy.ops.skinkit.animated_unwrap(metric="REST") == {"FINISHED"}
    return bpy.data.objects["arm"]


def full_fingerprint() -> dict:
    """scene_fingerprint, plus what the display operators and the statistics change."""
    state = scene_fingerprint()
    for obj in bpy.data.objects:
        entry = state["objects"][obj.name]
        data = obj.data
        entry["data_props"] = "" if data is None else hashlib.sha1(repr(sorted(
            (key, str(value.to_dict() if hasattr(value, "to_dict") else value)) for key, value in data.items()
        )).encode()).hexdigest()
        if obj.type == "MESH":
            active = obj.data.color_attributes.active_color
            entry["active_colour"] = active.name if active else None
            entry["uv_maps"] = [layer.name for layer in obj.data.uv_layers]
            groups = np.zeros(0)
            if obj.vertex_groups:
                groups = np.array([[g.weight for g in v.groups] + [g.group for g in v.groups]
                                   for v in obj.data.vertices[:200]], dtype=object)
            entry["weights"] = hashlib.sha1(repr(groups.tolist()).encode()).hexdigest()
    state["images"] = sorted(image.name for image in bpy.data.images)
    state["actions"] = sorted(action.name for action in bpy.data.actions)
    return state


def test_every_operator_refuses_edit_mode_through_poll_saying_why(open_sample, addon):
    mesh_object = prepared_arm(open_sample)
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        for name in MESH_OPERATORS:
            with pytest.raises(RuntimeError, match="'arm' is in Edit Mode: switch to Object Mode"):
                operator(name)()
        # the statistics belong to the armature, which is not being edited
        assert bpy.ops.skinkit.compute_pose_statistics(source="UNIFORM") == {"FINISHED"}
        # the Python and CLI path: a SkinkitError naming the object, not a KeyError
        with pytest.raises(SkinkitError, match="'arm' is in Edit Mode"):
            skinning.compare_with_armature(mesh_object, range(1, 3))
        with pytest.raises(SkinkitError, match="'arm' is in Edit Mode"):
            skinning.convert_object(mesh_object)
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
    assert bpy.ops.skinkit.compare_with_armature(use_scene_range=False, frame_start=1, frame_end=3) == {"FINISHED"}


def test_no_active_object_is_refused_saying_what_is_missing(open_sample, addon):
    prepared_arm(open_sample)
    bpy.context.view_layer.objects.active = None
    for name in MESH_OPERATORS + ("compute_pose_statistics",):
        with pytest.raises(RuntimeError) as refused:
            operator(name)()
        assert "context is incorrect" not in str(refused.value) and "no active object" in str(refused.value), name
    bpy.context.view_layer.objects.active = bpy.data.objects["arm_rig"]
    with pytest.raises(RuntimeError, match="the active object 'arm_rig' is an armature, not a mesh"):
        bpy.ops.skinkit.convert_to_animation_space()


def test_the_active_object_is_acted_on_even_when_it_is_not_selected(open_sample, addon):
    mesh_object = open_sample("arm")
    for obj in bpy.context.scene.objects:
        obj.select_set(False)
    rig_of(mesh_object).armature_object.select_set(True)
    bpy.context.view_layer.objects.active = mesh_object
    assert not mesh_object.select_get()
    assert bpy.ops.skinkit.convert_to_animation_space() == {"FINISHED"}
    assert storage.has_model(mesh_object.data)
    assert "active object" in bpy.types.SKINKIT_OT_convert_to_animation_space.__doc__


def test_every_option_is_an_operator_keyword(open_sample, addon, tmp_path):
    mesh_object = open_sample("arm")
    select(mesh_object)
    add_shape_key_examples(mesh_object, dual_quaternion_examples(mesh_object, FRAMES), FRAMES)
    assert bpy.ops.skinkit.fit_from_examples(source="SHAPE_KEYS", method="GLOBAL", regularisation_delta=0.01,
                                             influences="RIG", rings=1, max_influences=3,
                                             held_out="19, 31") == {"FINISHED"}
    report = bpy.data.objects["arm"].data[attributes.REPORT_PROPERTY]
    assert report["method"] == "global" and report["held_out"] == 2
    assert bpy.ops.skinkit.compare_with_armature(use_scene_range=False, frame_start=2, frame_end=6) == {"FINISHED"}
    assert addon.state.LAST_COMPARISON[addon.state.key(mesh_object)]["frames"] == 5
    assert bpy.ops.skinkit.bake_shape_keys(use_scene_range=False, frame_start=1, frame_end=4) == {"FINISHED"}
    assert len(bpy.data.objects["arm_skinkit_baked"].data.shape_keys.key_blocks) == 5
    path = str(tmp_path / "keyword.pc2")
    assert bpy.ops.skinkit.bake_mesh_cache(use_scene_range=False, frame_start=1, frame_end=3, filepath=path,
                                           add_object=False) == {"FINISHED"}
    assert os.path.isfile(path) and "arm_skinkit_cache" not in bpy.data.objects
    select(rig_of(mesh_object).armature_object)
    assert bpy.ops.skinkit.compute_pose_statistics(source="ACTION", step=5) == {"FINISHED"}
    assert "step 5" in pose_statistics.summary(rig_of(mesh_object).armature_object)["source"]
    assert bpy.ops.skinkit.compute_pose_statistics(source="POSES", poses="1, 5-7") == {"FINISHED"}
    assert pose_statistics.summary(rig_of(mesh_object).armature_object)["frames"] == 4
    # the panel's values (scene.skinkit) are what an option not passed starts from
    assert bpy.ops.skinkit.fit_from_examples.get_rna_type().properties["regularisation_lambda"].default == \
        pytest.approx(DEFAULT_LAMBDA)
    assert bpy.context.scene.skinkit.bl_rna.properties["fit_lambda"].default == pytest.approx(DEFAULT_LAMBDA)


def test_bl_options_match_what_each_operator_changes(addon):
    assert "UNDO" not in bpy.types.SKINKIT_OT_compare_with_armature.bl_options
    for name in MESH_OPERATORS + ("compute_pose_statistics",):
        options = getattr(bpy.types, f"SKINKIT_OT_{name}").bl_options
        assert "REGISTER" in options, name
        if name != "compare_with_armature":
            assert "UNDO" in options, name


def undo_restores(call) -> None:
    bpy.ops.ed.undo_push(message="before")
    before = full_fingerprint()
    assert call() == {"FINISHED"}
    assert full_fingerprint() != before  # it did change something
    bpy.ops.ed.undo()
    after = full_fingerprint()
    assert after == before, {name: (before["objects"].get(name), entry) for name, entry in after["objects"].items()
                             if before["objects"].get(name) != entry}


def test_one_undo_restores_the_scene_after_every_operator(open_sample, addon, tmp_path):
    prepared_arm(open_sample)
    select(bpy.data.objects["arm"])
    frames = {"use_scene_range": False, "frame_start": 1, "frame_end": 3}
    run = {
        "convert_to_animation_space": {},
        "toggle_preview": {},
        "remove_model": {},
        "bake_shape_keys": frames,
        "bake_mesh_cache": dict(frames, filepath=str(tmp_path / "undo.pc2")),
        "fit_from_examples": {"source": "SHAPE_KEYS", "method": "PER_VERTEX"},
        "show_max_distance": {},
        "animated_unwrap": {"metric": "REST", "make_active": True},
        "show_uv_layout": {},
    }
    for name, keywords in run.items():
        select(bpy.data.objects["arm"])
        undo_restores(lambda: operator(name)("EXEC_DEFAULT", True, **keywords))
    select(bpy.data.objects["arm"])
    mesh = bpy.data.objects["arm"].data
    mesh.color_attributes.active_color = mesh.color_attributes.new("painted", "FLOAT_COLOR", "POINT")
    undo_restores(lambda: bpy.ops.skinkit.show_fit_error("EXEC_DEFAULT", True))
    select(bpy.data.objects["arm_rig"])
    undo_restores(lambda: bpy.ops.skinkit.compute_pose_statistics("EXEC_DEFAULT", True, source="LIMITS"))


def test_skin_from_sequence_undo_and_its_source_follows_the_object(addon, tmp_path):
    from tests.blender.test_decompose import mesh_with_shape_keys
    from tests.sequences import rigid_chain_sequence

    frames, triangles, _, _ = rigid_chain_sequence(segments=3, frames=8)
    mesh_object = mesh_with_shape_keys(frames, triangles)
    undo_restores(lambda: bpy.ops.skinkit.skin_from_sequence("EXEC_DEFAULT", True, bones=3, max_influences=2))
    # an object that only has a Mesh Cache: the default source is what it has
    from skinkit import meshcache
    path = str(tmp_path / "tube.pc2")
    meshcache.write_pc2(path, frames.astype(np.float32))
    mesh_object = bpy.data.objects["tube"]
    mesh_object.shape_key_clear()
    modifier = mesh_object.modifiers.new("cache", "MESH_CACHE")
    modifier.cache_format, modifier.filepath, modifier.frame_start = "PC2", path, 1.0
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, len(frames)
    select(mesh_object)
    assert bpy.ops.skinkit.skin_from_sequence(bones=3, max_influences=2) == {"FINISHED"}
    assert bpy.data.objects["tube_skinned"].data["skinkit_fit_report"]["examples"] == len(frames)


def test_a_stale_model_is_refused_by_compare_and_bakes_and_switches_the_preview_off(open_sample, addon):
    mesh_object = open_sample("arm")
    select(mesh_object)
    skinning.convert_object(mesh_object)
    armature = rig_of(mesh_object).armature_object
    assert skinning.model_changes(mesh_object) == []
    bpy.ops.skinkit.toggle_preview()
    assert preview.is_enabled(mesh_object)
    armature.data.bones[1].use_deform = False
    with pytest.raises(SkinkitError, match="'arm': the model is out of date.*deform"):
        skinning.compare_with_armature(mesh_object, range(1, 4))
    for name in ("compare_with_armature", "bake_shape_keys", "bake_mesh_cache"):
        with pytest.raises(RuntimeError, match="out of date"):
            operator(name)(use_scene_range=False, frame_start=1, frame_end=3)
    bpy.context.scene.frame_set(5)  # the preview's refresh sees it and switches itself off
    assert not preview.is_enabled(mesh_object)
    with pytest.raises(RuntimeError, match="out of date"):
        bpy.ops.skinkit.toggle_preview()
    armature.data.bones[1].use_deform = True
    assert skinning.model_changes(mesh_object) == []

    mesh_object.vertex_groups[0].add([0, 1, 2], 0.5, "REPLACE")
    mesh_object.vertex_groups[1].add([0, 1, 2], 0.25, "REPLACE")
    assert any("weights" in c for c in skinning.model_changes(mesh_object))
    skinning.convert_object(mesh_object)
    positions = np.empty(len(mesh_object.data.vertices) * 3, np.float32)
    mesh_object.data.vertices.foreach_get("co", positions)
    positions[:3] += 0.01
    mesh_object.data.vertices.foreach_set("co", positions)
    mesh_object.data.update()
    assert any("rest positions" in c for c in skinning.model_changes(mesh_object))
    skinning.convert_object(mesh_object)
    compat.select_bone(armature, armature.data.bones[1].name)
    select(armature)
    bpy.ops.object.mode_set(mode="EDIT")
    armature.data.edit_bones[1].head.x += 0.1
    bpy.ops.object.mode_set(mode="OBJECT")
    assert any("rest pose" in c for c in skinning.model_changes(mesh_object))


def test_compare_on_a_rig_without_animation_says_so(open_sample):
    mesh_object = open_sample("arm")
    skinning.convert_object(mesh_object)
    rig_of(mesh_object).armature_object.animation_data_clear()
    report = skinning.compare_with_armature(mesh_object, range(1, 11))
    assert any("no animation" in w for w in report["warnings"])


def test_a_blend_relative_cache_path_warns_nothing(open_sample, addon, tmp_path):
    mesh_object = open_sample("arm")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "arm.blend"))
    select(bpy.data.objects["arm"])
    skinning.convert_object(bpy.data.objects["arm"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bpy.context.scene.skinkit.cache_path = "//relative.pc2"
        assert bpy.ops.skinkit.bake_mesh_cache(use_scene_range=False, frame_start=1, frame_end=2,
                                               filepath="//relative2.pc2") == {"FINISHED"}
    assert os.path.isfile(tmp_path / "relative2.pc2")
    del mesh_object


def test_a_fit_reports_the_rig_s_own_error_and_warns_when_it_loses_to_it(open_sample, addon):
    mesh_object = open_sample("arm")
    select(mesh_object)
    frames = list(range(1, 41, 3))
    # examples made by the rig's own linear blend skinning: its weights are exact, a fit can only tie or lose
    positions = fitting.examples_from_armature(mesh_object, frames, preserve_volume=False).positions
    bpy.context.scene.frame_set(1)
    add_shape_key_examples(mesh_object, positions, frames)
    assert bpy.ops.skinkit.fit_from_examples(source="SHAPE_KEYS", held_out="19, 31", regularisation_lambda=10.0,
                                             max_influences=1) == {"FINISHED"}
    report = bpy.data.objects["arm"].data[attributes.REPORT_PROPERTY]
    assert report["input_rig.held_out.rms"] < 1e-5
    assert report["input_rig.held_out.rms"] < report["animation_space.held_out.rms"]
    warnings_given = [str(w) for w in report["warnings"]]
    assert any(w.startswith("animation space is worse than the rig's own weights") for w in warnings_given)
    texts = [str(t) for t in draw_panel(addon).texts()]
    assert any(t.startswith("  Rig: ") for t in texts) and any("worse than the rig's own" in t for t in texts)
