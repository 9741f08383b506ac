"""'Skin from Mesh Sequence' in real headless Blender: the armature, its action and the skinned copy reproduce the
sequence; bad input leaves the scene as it was."""
import bpy
import numpy as np
import pytest
from tests.sequences import rigid_chain_sequence

from skinkit.blender.frames import depsgraphs_at, evaluated_positions


def mesh_with_shape_keys(frames, triangles):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = bpy.data.meshes.new("tube")
    mesh.from_pydata(frames[0].tolist(), [], triangles.tolist())
    mesh_object = bpy.data.objects.new("tube", mesh)
    bpy.context.scene.collection.objects.link(mesh_object)
    mesh_object.location = (1.0, 2.0, 0.5)  # results must not depend on where the object is
    mesh_object.shape_key_add(name="Basis")
    for index, frame in enumerate(frames[1:], start=1):
        key = mesh_object.shape_key_add(name=f"frame {index}")
        key.points.foreach_set("co", frame.astype(np.float32).reshape(-1))
    bpy.context.view_layer.objects.active = mesh_object
    mesh_object.select_set(True)
    return mesh_object


def scene_state():
    return (sorted(o.name for o in bpy.data.objects), len(bpy.data.actions), len(bpy.data.armatures),
            len(bpy.data.meshes))


def test_skin_from_shape_keys_makes_an_animated_rig(addon):
    frames, triangles, _, _ = rigid_chain_sequence(segments=3, frames=10)
    mesh_object = mesh_with_shape_keys(frames, triangles)
    settings = bpy.context.scene.skinkit
    settings.skin_source, settings.skin_method, settings.skin_bones = "SHAPE_KEYS", "AUTOMATIC", 3
    settings.skin_max_influences, settings.skin_train = 2, "1-7"
    assert bpy.ops.skinkit.skin_from_sequence() == {"FINISHED"}
    armature = bpy.data.objects["tube_rig"]
    skinned = bpy.data.objects["tube_skinned"]
    assert len(armature.data.bones) == 3
    assert armature.animation_data.action is not None
    assert {g.name for g in skinned.vertex_groups} == {b.name for b in armature.data.bones}
    report = skinned.data["skinkit_fit_report"]
    assert report["examples"] == 7 and report["held_out"] == 3 and report["animation_space.held_out.max"] < 1e-5
    # Blender's own Armature modifier, driven by the action, plays the sequence (training and held-out frames)
    first = bpy.context.scene.frame_start
    numbers = list(range(first, first + len(frames)))
    for number, depsgraph in zip(numbers, depsgraphs_at(numbers)):
        played = evaluated_positions(skinned, depsgraph)
        assert np.abs(played - frames[number - first]).max() < 1e-4, number
    assert mesh_object.data.shape_keys is not None and len(mesh_object.modifiers) == 0  # the source is untouched


def test_a_mesh_without_frames_is_refused_and_nothing_changes(addon):
    frames, triangles, _, _ = rigid_chain_sequence(segments=2, frames=3)
    mesh_object = mesh_with_shape_keys(frames[:1], triangles)
    before = scene_state()
    bpy.context.scene.skinkit.skin_source = "SHAPE_KEYS"
    with pytest.raises(RuntimeError, match="needs shape keys"):
        bpy.ops.skinkit.skin_from_sequence()
    assert scene_state() == before and mesh_object.name == "tube"


def test_too_many_bones_are_refused_naming_the_object(addon):
    frames, triangles, _, _ = rigid_chain_sequence(segments=2, frames=4)
    mesh_with_shape_keys(frames, triangles)
    before = scene_state()
    settings = bpy.context.scene.skinkit
    settings.skin_source, settings.skin_method, settings.skin_bones, settings.skin_train = \
        "SHAPE_KEYS", "AUTOMATIC", 1000, ""
    with pytest.raises(RuntimeError, match="'tube'.*bone count 1000"):
        bpy.ops.skinkit.skin_from_sequence()
    assert scene_state() == before


def test_rough_rig_from_a_drawn_armature(addon):
    frames, triangles, segment, _ = rigid_chain_sequence(segments=3, frames=8)
    mesh_object = mesh_with_shape_keys(frames, triangles)
    rest = frames[0]
    armature = bpy.data.objects.new("drawn", bpy.data.armatures.new("drawn"))
    bpy.context.scene.collection.objects.link(armature)
    armature.location = mesh_object.location
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    previous = None
    for index in range(3):
        bone = armature.data.edit_bones.new(f"seg{index}")
        bone.head, bone.tail = (0.05, index + 0.1, 0.0), (0.0, index + 0.9, 0.05)
        bone.parent = previous
        previous = bone
    bpy.ops.object.mode_set(mode="OBJECT")
    for index in range(3):
        group = mesh_object.vertex_groups.new(name=f"seg{index}")
        core = np.flatnonzero((segment == index) & (np.abs(rest[:, 1] - (index + 0.5)) < 0.3))
        group.add(core.tolist(), 1.0, "REPLACE")
    bpy.context.view_layer.objects.active = mesh_object
    settings = bpy.context.scene.skinkit
    settings.skin_source, settings.skin_method, settings.skin_rough_rig = "SHAPE_KEYS", "ROUGH_RIG", armature
    settings.skin_train = ""
    assert bpy.ops.skinkit.skin_from_sequence() == {"FINISHED"}
    rig = bpy.data.objects["tube_rig"]
    assert [b.name for b in rig.data.bones] == ["seg0", "seg1", "seg2"]
    assert rig.data.bones["seg1"].parent.name == "seg0"
    heads = np.array([rig.data.bones[f"seg{k}"].head_local for k in (1, 2)])
    assert np.allclose(heads, [[0, 1, 0], [0, 2, 0]], atol=2e-2)  # joints fitted to the hinges (eq. 4.6)
