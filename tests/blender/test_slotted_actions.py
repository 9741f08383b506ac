"""Issue 18: an action made for another datablock (an FBX import's, another object's) gets no slot when assigned on
Blender 4.4+, and then animates nothing; where skinkit assigns an action (the CLI's --action) it assigns a slot too,
and where it reads one that plays nothing it says why."""
import bpy
import pytest

from skinkit import SkinkitError
from skinkit.blender import compat, pose_statistics
from skinkit.blender.scene import action_assigned


def objects_and_an_action_made_for_the_first():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    first, second = (bpy.data.objects.new(name, None) for name in ("First", "Second"))
    for item in (first, second):
        bpy.context.scene.collection.objects.link(item)
    action = bpy.data.actions.new("walk")
    first.animation_data_create().action = action
    curve = compat.ensure_fcurve(action, first, "location", 0)
    curve.keyframe_points.insert(1, 0.0)
    curve.keyframe_points.insert(10, 5.0)
    first.animation_data.action = None
    return second, action


def x_at(item, frame: int) -> float:
    bpy.context.scene.frame_set(frame)
    return item.location.x


def test_an_assigned_action_plays_on_an_object_it_was_not_made_for():
    second, action = objects_and_an_action_made_for_the_first()
    with action_assigned(second, "walk"):
        assert second.animation_data.action == action
        assert x_at(second, 10) == pytest.approx(5.0)
    assert second.animation_data.action is None  # handed back as it was


@pytest.mark.skipif(not compat.SLOTTED_ACTIONS, reason="actions have slots from Blender 4.4")
def test_plain_assignment_plays_nothing_and_is_named_as_the_reason():
    second, action = objects_and_an_action_made_for_the_first()
    second.animation_data_create().action = action  # what a user's script or an importer does
    assert compat.action_without_slot(second.animation_data) and x_at(second, 10) == 0.0  # the reason for the fix
    compat.assign_action(second.animation_data, action)
    assert not compat.action_without_slot(second.animation_data) and x_at(second, 10) == pytest.approx(5.0)


@pytest.mark.skipif(not compat.SLOTTED_ACTIONS, reason="actions have slots from Blender 4.4")
def test_pose_statistics_of_an_armature_whose_action_has_no_slot_say_so():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    armature = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    bpy.context.scene.collection.objects.link(armature)
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    bone = armature.data.edit_bones.new("bone")
    bone.tail = (0.0, 0.0, 1.0)
    bpy.ops.object.mode_set(mode="OBJECT")
    other = bpy.data.objects.new("Other", None)
    bpy.context.scene.collection.objects.link(other)
    action = bpy.data.actions.new("turn")
    other.animation_data_create().action = action
    curve = compat.ensure_fcurve(action, other, "location", 0)
    curve.keyframe_points.insert(1, 0.0)
    curve.keyframe_points.insert(10, 1.0)
    other.animation_data.action = None
    armature.animation_data_create().action = action
    with pytest.raises(SkinkitError, match="it has no action slot"):
        pose_statistics.from_frames(armature, range(1, 11))
