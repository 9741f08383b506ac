"""Live animation-space preview: the model, not the Armature modifier, deforms the mesh on screen.

While the preview is on, the Armature modifier is switched off (viewport and render) and a shape key
"skinkit_preview" (value 1, relative to the Basis) holds the model evaluated at the current pose, in
single precision; the add-on's frame-change and depsgraph handlers call `refresh` when the frame or the
armature's pose changes. Other shape keys keep adding their offsets on top. Turning it off removes the
key (and the Basis, if the preview made it) and restores the modifier: the scene is as before.
"""
from __future__ import annotations

import numpy as np

from . import storage
from .rig import rig_of
from .skinning import current_model, model_changes, model_positions, out_of_date

KEY_NAME = "skinkit_preview"
STATE = "skinkit_preview_state"

_models: dict[str, tuple] = {}  # object name -> (mesh session uid, model revision, stored model)


def is_enabled(mesh_object) -> bool:
    return STATE in mesh_object


def stored_model(mesh_object):
    """The stored model, read once per mesh and model revision (a re-conversion invalidates it)."""
    mesh = mesh_object.data
    revision = int(mesh[storage.PROPERTY].get("revision", 0)) if storage.has_model(mesh) else -1
    cached = _models.get(mesh_object.name)
    if cached is None or cached[0] != mesh.session_uid or cached[1] != revision:
        cached = (mesh.session_uid, revision, storage.read_model(mesh, mesh_object.name))
        _models[mesh_object.name] = cached
    return cached[2]


def enable(mesh_object, depsgraph) -> None:
    if is_enabled(mesh_object):
        return
    current_model(mesh_object)  # refuses a mesh without a readable, up-to-date model before anything changes
    modifier = rig_of(mesh_object).modifier
    state = {"modifier": modifier.name, "show_viewport": modifier.show_viewport,
             "show_render": modifier.show_render, "created_basis": mesh_object.data.shape_keys is None}
    if state["created_basis"]:
        mesh_object.shape_key_add(name="Basis", from_mix=False)
    key = mesh_object.shape_key_add(name=KEY_NAME, from_mix=False)
    key.value = 1.0
    modifier.show_viewport = modifier.show_render = False
    mesh_object[STATE] = state
    refresh(mesh_object, depsgraph)


def disable(mesh_object) -> None:
    if not is_enabled(mesh_object):
        return
    state = mesh_object[STATE]
    keys = mesh_object.data.shape_keys
    if keys and KEY_NAME in keys.key_blocks:
        mesh_object.shape_key_remove(keys.key_blocks[KEY_NAME])
    keys = mesh_object.data.shape_keys
    if state["created_basis"] and keys and len(keys.key_blocks) == 1:
        mesh_object.shape_key_remove(keys.key_blocks[0])
    modifier = mesh_object.modifiers.get(state["modifier"])
    if modifier is not None:
        modifier.show_viewport = bool(state["show_viewport"])
        modifier.show_render = bool(state["show_render"])
    del mesh_object[STATE]
    _models.pop(mesh_object.name, None)


def refresh(mesh_object, depsgraph) -> None:
    """Writes the model at the depsgraph's pose into the preview key.

    Skipped in Edit Mode, where Blender keeps its own copy of the shape keys and would discard the write. A model
    that no longer matches the mesh or rig (skinning.model_changes, without reading the weights: those are checked
    when the preview starts) raises SkinkitError; the add-on's handlers then switch the preview off and say why.
    """
    keys = mesh_object.data.shape_keys
    if mesh_object.mode == "EDIT" or not keys or KEY_NAME not in keys.key_blocks:
        return
    stored = stored_model(mesh_object)
    changes = model_changes(mesh_object, stored, check_weights=False)
    if changes:
        raise out_of_date(mesh_object, changes, " (Live Preview is off)")
    positions = model_positions(mesh_object, depsgraph, stored, np.float32)
    keys.key_blocks[KEY_NAME].points.foreach_set("co", positions.reshape(-1))  # .points: the bulk path
    mesh_object.data.update()


def previewed_objects(scene) -> list:
    return [o for o in scene.objects if o.type == "MESH" and is_enabled(o)]
