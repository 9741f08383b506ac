"""Every difference between the Blender releases skinkit supports (4.2 LTS, 4.5 LTS, 5.0), in one place.

The bridge and the add-on ask here instead of testing bpy.app.version themselves, so a new Blender means one
edit. `make test-blender-matrix` runs the Blender-facing tests under each release.
"""
from __future__ import annotations

import os
import sys

import bpy

VERSION = tuple(bpy.app.version)

#: StringProperty's PATH_SUPPORTS_BLEND_RELATIVE option ('//' paths shown relative to the .blend) arrived in 4.5.
PATH_PROPERTY_OPTIONS = {"PATH_SUPPORTS_BLEND_RELATIVE"} if VERSION >= (4, 5, 0) else set()

#: Slotted actions (Action.fcurve_ensure_for_datablock, layers, slots, channel bags) arrived in 4.4; 5.0 removed
#: the legacy Action.fcurves that 4.2 has.
SLOTTED_ACTIONS = VERSION >= (4, 4, 0)

#: Blender's USD importer names an imported action after the file's animation (the exported action's name) from 4.5
#: on; 4.2's names it "<armature>Action". The animation itself round-trips on every release.
USD_IMPORT_KEEPS_ACTION_NAMES = VERSION >= (4, 5, 0)


def action_fcurves(action) -> list:
    """Every F-curve of an action: through its layers, strips and channel bags where actions are slotted (4.4 on;
    5.0 has no Action.fcurves), else the legacy list."""
    if not SLOTTED_ACTIONS:
        return list(action.fcurves)
    return [fcurve for layer in action.layers for strip in layer.strips for bag in strip.channelbags
            for fcurve in bag.fcurves]


def gltf_vec4_attribute_type() -> str:
    """The point-attribute type for a float VEC4 custom glTF accessor: QUATERNION (no colour semantics) where the
    glTF exporter writes it (its conversion table knows the type: 4.5 on), else FLOAT_COLOR (4.2's exporter skips
    QUATERNION attributes silently)."""
    try:
        from io_scene_gltf2.blender.com import conversion  # 4.5 on
    except ImportError:
        try:
            from io_scene_gltf2.blender.com import gltf2_blender_conversion as conversion  # 4.2
        except ImportError:
            return "FLOAT_COLOR"
    return "QUATERNION" if conversion.get_component_type("QUATERNION") is not None else "FLOAT_COLOR"


def ensure_fcurve(action, datablock, data_path: str, index: int):
    """The F-curve of action animating datablock's data_path[index], made when missing, in the action's slot for
    datablock (4.4+) or in its one flat list of curves (4.2)."""
    if SLOTTED_ACTIONS:
        return action.fcurve_ensure_for_datablock(datablock, data_path, index=index)
    return action.fcurves.find(data_path, index=index) or action.fcurves.new(data_path, index=index)


def assign_action(animation_data, action, slot=None) -> None:
    """Plays `action` on the datablock of animation_data: from 4.4 an action made for another datablock (an FBX
    import's, or another object's) gets no slot by itself and then animates nothing, so the given slot, or the first
    slot suitable for the datablock, is assigned too."""
    animation_data.action = action
    if not SLOTTED_ACTIONS or action is None:
        return
    if slot is None and animation_data.action_slot is None and len(animation_data.action_suitable_slots):
        slot = animation_data.action_suitable_slots[0]
    if slot is not None:
        animation_data.action_slot = slot


def action_slot(animation_data):
    """The slot the action plays in (4.4 on), to hand back to assign_action; None before 4.4."""
    return animation_data.action_slot if SLOTTED_ACTIONS else None


def action_without_slot(animation_data) -> bool:
    """Whether an action is assigned but animates nothing because no slot is (4.4 on)."""
    return (SLOTTED_ACTIONS and animation_data is not None and animation_data.action is not None
            and animation_data.action_slot is None)


def select_bone(armature_object, name: str, selected: bool = True) -> None:
    """Selects a bone: on its Bone up to 4.5, on its PoseBone from 5.0 (Bone.select is gone there)."""
    if VERSION >= (5, 0, 0):
        armature_object.pose.bones[name].select = selected
    else:
        armature_object.data.bones[name].select = selected


def add_shape_key(mesh_object, name: str, value: float = 0.0):
    """A new shape key (from the Basis, not the mix) with an explicit value: a new key's value is 1.0 from 5.0 on
    (0.0 up to 4.5), so a key added without one would show at full strength on 5.0 and be added to every other."""
    key = mesh_object.shape_key_add(name=name, from_mix=False)
    key.value = value
    return key


#: bpy 4.2 as a Python module can crash in its own teardown at interpreter exit once the glTF exporter has run
#: (the command's work and output are complete by then); 4.5 and 5.0 exit cleanly.
CRASHES_AT_EXIT = VERSION < (4, 5, 0)


def exit_process(status: int) -> None:
    """Ends a CLI process that used bpy: where bpy's teardown would crash, flushes the output and exits at once
    with status instead (nothing is left to clean up: files are written and renamed by then); else returns."""
    if CRASHES_AT_EXIT:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
