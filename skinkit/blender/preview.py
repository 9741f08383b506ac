"""Live animation-space preview: the model, not the Armature modifier, deforms the mesh on screen.

While the preview is on, the Armature modifier is switched off (viewport and render) and a shape key
"skinkit_preview" (value 1, relative to the Basis) holds the model evaluated at the current pose, in
single precision; the add-on's frame-change and depsgraph handlers call `refresh` when the frame or the
armature's pose changes. Other shape keys keep adding their offsets on top. Turning it off removes the
key (and the Basis, if the preview made it) and restores the modifier: the scene is as before.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import bpy
import numpy as np

from ..model import SkinkitError
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


def restore_previewed(mesh_object, state) -> None:
    """Undoes what a preview did to an object: its shape key (and the Basis it added) removed, the modifier it
    muted shown again as it was."""
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


def disable(mesh_object) -> None:
    if not is_enabled(mesh_object):
        return
    restore_previewed(mesh_object, mesh_object[STATE])
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


# ---- Level-of-detail preview through the runtime (Merry 2007, chapter 7) ------------------------------------------
#
# For a chain written by Build LOD Chain (objects <name>_LOD0 .. <name>_LODn in the collection <name>_LOD), the
# preview shows one level at a time, geomorphed by skinkit.runtime at a real level l: the object of level floor(l)
# is shown with its Armature modifier off and a "skinkit_preview" shape key holding the runtime's positions (mesh
# floor(l) at fraction l - floor(l), eq. 7.1); the other levels are hidden. l comes from a slider, or from the
# scene camera by pixel tolerance (eq. 7.2 on the chain's culling sphere, section 7.2). This is the runtime's CPU
# path, drawn from the chain's fixed-K pack when fixed_layout is on and every vertex's influences fit its slots
# (RuntimePack.fixed_layout_problem), from the CSR pack otherwise; turning the preview off restores every level's
# modifier, visibility and shape keys.

LOD_STATE = "skinkit_lod_preview_state"
LOD_NAME = re.compile(r"^(?P<base>.+)_LOD(?P<index>\d+)$")


def chain_levels(scene_object) -> list:
    """The level objects LOD0 .. LODn of the chain scene_object belongs to, in order, or [] when it belongs to none
    (or the chain is incomplete)."""
    match = LOD_NAME.match(scene_object.name) if scene_object is not None else None
    collection = bpy.data.collections.get(f"{match['base']}_LOD") if match else None
    if collection is None or scene_object.name not in collection.objects:
        return []
    by_index = {}
    for level_object in collection.objects:
        found = LOD_NAME.match(level_object.name)
        if found and found["base"] == match["base"] and level_object.type == "MESH":
            by_index[int(found["index"])] = level_object
    if sorted(by_index) != list(range(len(by_index))) or len(by_index) < 2:
        return []
    return [by_index[i] for i in range(len(by_index))]


@dataclass
class ChainRuntime:
    """A chain as the runtime draws it: one pack mesh per level, the epsilons in mesh units, LOD0's culling sphere
    (mesh space), and the stored models' bones and bind; fixed: the same pack in the fixed-K layout, None (with
    fixed_problem saying why) when it does not fit."""
    pack: object
    epsilons: np.ndarray
    sphere: np.ndarray
    bone_names: list
    bind: np.ndarray
    armature_name: str
    fixed: object = None
    fixed_problem: str | None = None


_chains: dict[str, tuple] = {}  # LOD0 name -> (the levels' mesh session uids and revisions, ChainRuntime)


def _revision(level_object) -> tuple:
    mesh = level_object.data
    return mesh.session_uid, int(mesh[storage.PROPERTY].get("revision", 0)) if storage.has_model(mesh) else -1


def chain_runtime(levels) -> ChainRuntime:
    """The levels' runtime data, read once per chain and model revisions."""
    signature = tuple(_revision(o) for o in levels)
    cached = _chains.get(levels[0].name)
    if cached is None or cached[0] != signature:
        cached = (signature, load_chain_runtime(levels))
        _chains[levels[0].name] = cached
    return cached[1]


def load_chain_runtime(levels) -> ChainRuntime:
    from ..lod.chain import _common_set
    from ..runtime import RuntimePack, culling_sphere
    from .lod_chain import REPORT_PROPERTY, TO_COARSER_ATTRIBUTE
    from .pose_statistics import in_mesh_space, stored_or_from_action

    stored = [storage.read_model(o.data, o.name) for o in levels]
    first = stored[0]
    for level_object, model in zip(levels[1:], stored[1:]):
        if model.bone_names != first.bone_names or model.armature_name != first.armature_name:
            raise SkinkitError(f"'{level_object.name}': its model's bones or armature differ from LOD0's")
    meshes = []
    for index, (level_object, model) in enumerate(zip(levels, stored)):
        if index + 1 == len(levels):
            meshes.append({"offsets": model.model.offsets, "bones": model.model.bones,
                           "coordinates": model.model.coordinates})
            continue
        mapped = storage.read_attribute(level_object.data, level_object.name, TO_COARSER_ATTRIBUTE, "INT", "value", 1,
                                        model.model.vertex_count)
        coarse_count = stored[index + 1].model.vertex_count
        if len(mapped) and (mapped.min() < 0 or mapped.max() >= coarse_count):
            raise SkinkitError(f"'{level_object.name}': its geomorph map points outside the next level")
        morph, delta = _common_set(model.model, stored[index + 1].model, mapped)
        meshes.append({"offsets": morph.offsets, "bones": morph.bones, "coordinates": morph.coordinates,
                       "delta": delta})
    collection = bpy.data.collections.get(LOD_NAME.match(levels[0].name)["base"] + "_LOD")
    diagonal = float(collection.get(REPORT_PROPERTY, {}).get("diagonal", 1.0))
    epsilons = np.array([float(o.get(REPORT_PROPERTY, {}).get("error", 0.0)) * diagonal for o in levels])
    epsilons = np.maximum.accumulate(epsilons)
    epsilons[0] = 0.0
    pack = RuntimePack.from_meshes(meshes, first.model.bone_count, epsilons)
    armature = bpy.data.objects.get(first.armature_name)
    if armature is None:
        raise SkinkitError(f"'{levels[0].name}': its armature '{first.armature_name}' is gone")
    statistics, _ = stored_or_from_action(armature, levels[0].name)
    sphere = culling_sphere(first.model, in_mesh_space(statistics, first.bind))
    problem = pack.fixed_layout_problem()
    fixed = pack.fixed(morphs=True) if problem is None else None
    return ChainRuntime(pack, epsilons, sphere, first.bone_names, first.bind, first.armature_name, fixed, problem)


def lod_is_enabled(scene_object) -> bool:
    levels = chain_levels(scene_object)
    return bool(levels) and LOD_STATE in levels[0]


def lod_enable(scene_object, depsgraph, level: float = 0.0, from_camera: bool = False,
               pixel_tolerance: float = 1.0, fixed_layout: bool = True) -> None:
    """Starts the chain's preview (the chain is read and checked first: a failure changes nothing). fixed_layout:
    draw from the fixed-K pack where the chain fits it."""
    levels = chain_levels(scene_object)
    if not levels:
        raise SkinkitError(f"'{scene_object.name}' is not a level of a LOD chain (<name>_LOD<n> objects in a "
                           "<name>_LOD collection, from Build LOD Chain)")
    if LOD_STATE in levels[0]:
        return
    chain_runtime(levels)
    for level_object in levels:
        if is_enabled(level_object):
            raise SkinkitError(f"'{level_object.name}' has Live Preview on: turn it off first")
    saved = []
    for level_object in levels:
        modifier = rig_of(level_object).modifier
        saved.append({"object": level_object.name, "modifier": modifier.name, "show_viewport": modifier.show_viewport,
                      "show_render": modifier.show_render, "hidden": level_object.hide_get(),
                      "created_basis": level_object.data.shape_keys is None})
    for level_object, entry in zip(levels, saved):
        if entry["created_basis"]:
            level_object.shape_key_add(name="Basis", from_mix=False)
        level_object.shape_key_add(name=KEY_NAME, from_mix=False).value = 1.0
        modifier = level_object.modifiers[entry["modifier"]]
        modifier.show_viewport = modifier.show_render = False
    levels[0][LOD_STATE] = {"levels": saved, "level": float(level), "from_camera": bool(from_camera),
                            "pixel_tolerance": float(pixel_tolerance), "fixed_layout": bool(fixed_layout),
                            "drawn_level": 0.0, "drawn_influences": 0, "drawn_layout": "", "slots_per_vertex": 0,
                            "fixed_layout_problem": ""}
    lod_refresh(levels[0], depsgraph)


def lod_disable(scene_object) -> None:
    levels = chain_levels(scene_object)
    if not levels or LOD_STATE not in levels[0]:
        return
    for entry in levels[0][LOD_STATE]["levels"]:
        level_object = bpy.data.objects.get(entry["object"])
        if level_object is None:
            continue
        restore_previewed(level_object, entry)
        level_object.hide_set(bool(entry["hidden"]))
    del levels[0][LOD_STATE]
    _chains.pop(levels[0].name, None)


def lod_settings(scene_object) -> dict:
    """The running preview's settings and what it drew: level, from_camera, pixel_tolerance, fixed_layout,
    drawn_level, drawn_influences, drawn_layout ("fixed" or "csr"), slots_per_vertex (K of the fixed layout, 0 for
    CSR) and fixed_layout_problem (why the chain does not fit the fixed layout, "" when it does) (empty when off)."""
    levels = chain_levels(scene_object)
    if not levels or LOD_STATE not in levels[0]:
        return {}
    return {k: v for k, v in levels[0][LOD_STATE].items() if k != "levels"}


def lod_set(scene_object, depsgraph, **settings) -> None:
    """Changes level, from_camera, pixel_tolerance or fixed_layout of the running preview and redraws it."""
    levels = chain_levels(scene_object)
    if not levels or LOD_STATE not in levels[0]:
        raise SkinkitError(f"'{scene_object.name}': the LOD preview is off")
    state = levels[0][LOD_STATE]
    for name, value in settings.items():
        if name not in ("level", "from_camera", "pixel_tolerance", "fixed_layout"):
            raise SkinkitError(f"unknown LOD preview setting {name!r}")
        state[name] = value
    lod_refresh(levels[0], depsgraph)


def camera_level(scene, level_object, chain: ChainRuntime, pixel_tolerance: float) -> float:
    """The real level for the scene camera (eq. 7.2): the chain's culling sphere in world space against the
    camera's position, viewing direction, horizontal field of view and render width."""
    from ..runtime import select_levels
    camera = scene.camera
    if camera is None or camera.type != "CAMERA":
        raise SkinkitError("the scene has no camera to choose the level from")
    world = np.array(level_object.matrix_world, dtype=np.float64)
    centre = world[:3, :3] @ chain.sphere[:3] + world[:3, 3]
    radius = chain.sphere[3] * np.linalg.norm(world[:3, :3], axis=0).max()
    view = np.array(camera.matrix_world, dtype=np.float64)
    forward = -view[:3, 2] / np.linalg.norm(view[:3, 2])
    width = scene.render.resolution_x * scene.render.resolution_percentage / 100
    return float(select_levels([[*centre, radius]], chain.epsilons, view[:3, 3], forward, camera.data.angle_x,
                               width, pixel_tolerance)[0])


def lod_refresh(scene_object, depsgraph) -> None:
    """Draws the chain at its level (the slider's, or the camera's) and the current pose."""
    from .rig import pose_matrices
    levels = chain_levels(scene_object)
    if not levels or LOD_STATE not in levels[0] or any(o.mode == "EDIT" for o in levels):
        return
    state = levels[0][LOD_STATE]
    chain = chain_runtime(levels)
    last = len(levels) - 1
    level = (camera_level(depsgraph.scene, levels[0], chain, float(state["pixel_tolerance"]))
             if state["from_camera"] else min(max(float(state["level"]), 0.0), float(last)))
    armature = bpy.data.objects.get(chain.armature_name)
    if armature is None:
        raise SkinkitError(f"'{levels[0].name}': its armature '{chain.armature_name}' is gone (LOD preview is off)")
    poses = pose_matrices(armature, depsgraph, chain.bone_names, chain.bind)
    fixed = chain.fixed if state.get("fixed_layout", False) else None  # a state saved before the option: CSR
    drawn = (fixed or chain.pack).draw([level], poses)
    shown = int(np.floor(level))
    target = levels[shown]
    keys = target.data.shape_keys
    if keys is None or KEY_NAME not in keys.key_blocks:
        raise SkinkitError(f"'{target.name}' lost its preview shape key (LOD preview is off)")
    keys.key_blocks[KEY_NAME].points.foreach_set("co", drawn.positions.reshape(-1))
    target.data.update()
    for index, level_object in enumerate(levels):
        if level_object.hide_get() != (index != shown):
            level_object.hide_set(index != shown)
    state["drawn_level"] = level
    state["drawn_influences"] = int(chain.pack.influence_counts()[shown])
    state["drawn_layout"] = "csr" if fixed is None else "fixed"
    state["slots_per_vertex"] = 0 if fixed is None else fixed.influences_per_vertex
    state["fixed_layout_problem"] = chain.fixed_problem or ""


def lod_previewed_objects(scene) -> list:
    """LOD0 of every chain whose preview is on."""
    return [o for o in scene.objects if o.type == "MESH" and LOD_STATE in o]
