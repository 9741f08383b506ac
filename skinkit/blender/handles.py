"""Handle rigs in Blender (Feng 2010, chapter 2): learn from a mesh sequence, drive the mesh with Empties.

* `prepare_learn(mesh_object, source, ...)` reads the sequence (the mesh's shape keys, the frames its modifiers
  give over the scene range - a Mesh Sequence Cache or Mesh Cache -, or other selected meshes of the same vertex
  count) and the control points (the vertex group `handles`, or an automatic count) -> a LearnJob whose solve()
  trains (no bpy) and whose write() creates one Empty per control point in the collection `<name>_handles`,
  stores the model on the mesh object and switches the live deformer on. Nothing is changed before write().
* The live deformer: a shape key `skinkit_handles` (value 1) holds the mesh predicted from the Empties' current
  positions; the add-on's handlers call `refresh_all` on frame changes and depsgraph updates. Off removes the key.
* `bake_shape_keys(mesh_object, frames)`: one shape key per frame, keyed to show on its frame only;
  `bake_mesh_cache(mesh_object, frames, path)`: a PC2 point cache.

The model is stored on the object as the ID property `skinkit_handle_rig` (docs/data-model.md): format version,
the Empties' names and the model's arrays as a compressed .npz, base64-encoded.
"""
from __future__ import annotations

import base64
import io
from dataclasses import dataclass

import bpy
import numpy as np

from .. import handles
from ..model import SkinkitError
from . import compat, skinning
from .rig import mesh_of, mesh_positions, read_vertex_groups

PROPERTY = "skinkit_handle_rig"
LIVE_KEY = "skinkit_handles"
GROUP = "handles"
SOURCES = ("shape_keys", "modifiers", "selected")
_models: dict[str, tuple] = {}  # object name -> (stored text's hash, model): decoded once per stored model


# ---- reading the sequence -------------------------------------------------------------------------------------

def shape_key_frames(mesh_object) -> np.ndarray:
    keys = mesh_object.data.shape_keys
    if keys is None or len(keys.key_blocks) < 2:
        raise SkinkitError(f"'{mesh_object.name}' has no shape keys besides the Basis to learn from")
    frames = []
    for block in keys.key_blocks:
        positions = np.empty(len(block.data) * 3, np.float32)
        block.data.foreach_get("co", positions)
        frames.append(positions.reshape(-1, 3))
    return np.asarray(frames, np.float64)


def modifier_frames(mesh_object, scene) -> np.ndarray:
    """The evaluated mesh at every frame of the scene range (what a Mesh Sequence Cache or Mesh Cache gives)."""
    if not any(m.type in ("MESH_SEQUENCE_CACHE", "MESH_CACHE") for m in mesh_object.modifiers):
        raise SkinkitError(f"'{mesh_object.name}' has no Mesh Sequence Cache or Mesh Cache modifier")
    current = scene.frame_current
    frames = []
    try:
        for number in range(scene.frame_start, scene.frame_end + 1):
            scene.frame_set(number)
            depsgraph = bpy.context.evaluated_depsgraph_get()
            evaluated = mesh_object.evaluated_get(depsgraph)
            mesh = evaluated.to_mesh()
            try:
                if len(mesh.vertices) != len(mesh_object.data.vertices):
                    raise SkinkitError(f"'{mesh_object.name}': frame {number} has {len(mesh.vertices)} vertices, "
                                       f"the mesh {len(mesh_object.data.vertices)}")
                frames.append(mesh_positions(mesh))
            finally:
                evaluated.to_mesh_clear()
    finally:
        scene.frame_set(current)
    return np.asarray(frames)


def selected_frames(mesh_object, selected) -> np.ndarray:
    """The active mesh first, then the other selected meshes in name order, in the active mesh's space."""
    others = sorted((o for o in selected if o.type == "MESH" and o != mesh_object), key=lambda o: o.name)
    if not others:
        raise SkinkitError("select the example meshes too (same vertex count and order as the active mesh)")
    to_local = np.linalg.inv(np.array(mesh_object.matrix_world))
    frames = [mesh_positions(mesh_object.data)]
    for other in others:
        if len(other.data.vertices) != len(mesh_object.data.vertices):
            raise SkinkitError(f"'{other.name}' has {len(other.data.vertices)} vertices, '{mesh_object.name}' "
                               f"{len(mesh_object.data.vertices)}")
        world = to_local @ np.array(other.matrix_world)
        frames.append(mesh_positions(other.data) @ world[:3, :3].T + world[:3, 3])
    return np.asarray(frames)


def group_vertices(mesh_object, name: str = GROUP) -> np.ndarray:
    if mesh_object.vertex_groups.get(name) is None:
        raise SkinkitError(f"'{mesh_object.name}' has no vertex group '{name}' marking the control points")
    chosen = np.flatnonzero(read_vertex_groups(mesh_object, [name])[:, 0] > 0).astype(np.int32)
    if not len(chosen):
        raise SkinkitError(f"'{mesh_object.name}': vertex group '{name}' is empty")
    return chosen


# ---- learning ---------------------------------------------------------------------------------------------------

@dataclass
class LearnJob:
    mesh_object_name: str
    frames: np.ndarray
    triangles: np.ndarray
    handle_vertices: np.ndarray | None
    handle_count: int | None
    options: dict

    def solve(self, progress=None) -> dict:
        model = handles.train(self.frames, self.triangles, handle_vertices=self.handle_vertices,
                              handle_count=self.handle_count, progress=progress, **self.options)
        return {"model": model, "report": model.report}

    def write(self, mesh_object, solved) -> dict:
        """Empties at the control points (in the mesh's world space), the stored model, the live deformer on."""
        if len(mesh_object.data.vertices) != len(self.frames[0]):
            raise SkinkitError(f"'{mesh_object.name}' changed while learning; nothing was written")
        model = solved["model"]
        disable_live(mesh_object)
        collection = handle_collection(mesh_object)
        world = np.array(mesh_object.matrix_world)
        empties = []
        for number, vertex in enumerate(model.handle_vertices):
            empty = bpy.data.objects.new(f"{mesh_object.name}_handle_{number:02d}", None)
            empty.empty_display_type = "SPHERE"
            empty.empty_display_size = 0.02 * float(np.ptp(model.rest_positions, axis=0).max())
            empty.location = world[:3, :3] @ model.rest_positions[vertex] + world[:3, 3]
            collection.objects.link(empty)
            empties.append(empty.name)
        store_model(mesh_object, model, empties)
        enable_live(mesh_object)
        return {"empties": empties, "collection": collection.name, **solved["report"]}


def prepare_learn(mesh_object, source: str, selected=(), handle_count: int | None = None, **options) -> LearnJob:
    """Reads the sequence and control points; handle_count None uses the vertex group 'handles'."""
    if source not in SOURCES:
        raise SkinkitError(f"source: expected one of {', '.join(SOURCES)}, got {source!r}")
    if source == "shape_keys":
        frames = shape_key_frames(mesh_object)
    elif source == "modifiers":
        frames = modifier_frames(mesh_object, bpy.context.scene)
    else:
        frames = selected_frames(mesh_object, selected)
    vertices = group_vertices(mesh_object) if handle_count is None else None
    return LearnJob(mesh_object.name, frames, mesh_of(mesh_object).triangles, vertices, handle_count, options)


def handle_collection(mesh_object):
    """The collection `<name>_handles` (emptied of old handles), linked under the scene's collection."""
    name = f"{mesh_object.name}_handles"
    collection = bpy.data.collections.get(name)
    if collection is None:
        collection = bpy.data.collections.new(name)
        bpy.context.scene.collection.children.link(collection)
    for old in list(collection.objects):
        bpy.data.objects.remove(old)
    return collection


# ---- storage ----------------------------------------------------------------------------------------------------

def store_model(mesh_object, model, empties) -> None:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **model.arrays())
    mesh_object[PROPERTY] = {"version": handles.FORMAT_VERSION, "empties": list(empties),
                             "model": base64.b64encode(buffer.getvalue()).decode("ascii")}


def has_rig(mesh_object) -> bool:
    return mesh_object is not None and PROPERTY in mesh_object


def stored_model(mesh_object):
    """The stored HandleModel, decoded once per stored text."""
    if not has_rig(mesh_object):
        raise SkinkitError(f"'{mesh_object.name}' has no handle rig (run Learn Handle Rig)")
    stored = mesh_object[PROPERTY]
    if int(stored.get("version", -1)) != handles.FORMAT_VERSION:
        raise SkinkitError(f"'{mesh_object.name}': handle rig version {stored.get('version')}, this skinkit reads "
                           f"{handles.FORMAT_VERSION}")
    text = stored["model"]
    cached = _models.get(mesh_object.name)
    if cached is None or cached[0] != hash(text):
        with np.load(io.BytesIO(base64.b64decode(text)), allow_pickle=False) as arrays:
            model = handles.HandleModel.from_arrays({key: arrays[key] for key in arrays.files})
        cached = (hash(text), model)
        _models[mesh_object.name] = cached
    return cached[1]


def handle_positions(mesh_object) -> np.ndarray:
    """The Empties' current world positions, in the mesh's space (H, 3)."""
    names = list(mesh_object[PROPERTY]["empties"])
    missing = [n for n in names if n not in bpy.data.objects]
    if missing:
        raise SkinkitError(f"'{mesh_object.name}': handle Empties {missing} are gone")
    to_local = np.linalg.inv(np.array(mesh_object.matrix_world))
    world = np.array([bpy.data.objects[n].matrix_world.translation for n in names])
    return world @ to_local[:3, :3].T + to_local[:3, 3]


# ---- the live deformer and baking -------------------------------------------------------------------------------

def is_live(mesh_object) -> bool:
    keys = mesh_object.data.shape_keys
    return keys is not None and LIVE_KEY in keys.key_blocks


def enable_live(mesh_object) -> None:
    if is_live(mesh_object):
        return
    stored_model(mesh_object)  # refuses a mesh without a readable rig before anything changes
    if mesh_object.data.shape_keys is None:
        compat.add_shape_key(mesh_object, "Basis")
    compat.add_shape_key(mesh_object, LIVE_KEY, 1.0)
    refresh(mesh_object)


def disable_live(mesh_object) -> None:
    if is_live(mesh_object):
        mesh_object.shape_key_remove(mesh_object.data.shape_keys.key_blocks[LIVE_KEY])


def write_key(block, positions) -> None:
    block.data.foreach_set("co", np.ascontiguousarray(positions, np.float32).ravel())


def refresh(mesh_object) -> None:
    """The live key from the Empties' positions now (skipped in Edit Mode, where Blender keeps its own keys)."""
    if mesh_object.mode == "EDIT" or not is_live(mesh_object):
        return
    model = stored_model(mesh_object)
    write_key(mesh_object.data.shape_keys.key_blocks[LIVE_KEY], model.predict(handle_positions(mesh_object)))
    mesh_object.data.update()


def live_objects(scene):
    return [o for o in scene.objects if o.type == "MESH" and has_rig(o) and is_live(o)]


def refresh_all(scene) -> list[str]:
    """Refreshes every live mesh of the scene; a broken one is switched off. Returns the messages."""
    messages = []
    for mesh_object in live_objects(scene):
        try:
            refresh(mesh_object)
        except SkinkitError as error:
            disable_live(mesh_object)
            messages.append(f"skinkit handle rig of '{mesh_object.name}' is off: {error}")
    return messages


def predicted_frames(mesh_object, frames) -> np.ndarray:
    """The mesh (F, V, 3) predicted from the Empties at each frame; the scene's frame is restored."""
    scene = bpy.context.scene
    model = stored_model(mesh_object)
    current = scene.frame_current
    predicted = []
    try:
        for number in frames:
            scene.frame_set(number)
            predicted.append(model.predict(handle_positions(mesh_object)))
    finally:
        scene.frame_set(current)
    return np.asarray(predicted)


def bake_shape_keys(mesh_object, frames) -> list[str]:
    """One shape key `skinkit_handles_NNNN` per frame, keyed 1 on its frame and 0 on its neighbours. Predicts every
    frame before writing anything."""
    frames = list(frames)
    predicted = predicted_frames(mesh_object, frames)
    if mesh_object.data.shape_keys is None:
        compat.add_shape_key(mesh_object, "Basis")
    names = []
    for number, positions in zip(frames, predicted):
        block = compat.add_shape_key(mesh_object, f"{LIVE_KEY}_{number:04d}")
        write_key(block, positions)
        for frame, value in ((number - 1, 0.0), (number, 1.0), (number + 1, 0.0)):
            block.value = value
            block.keyframe_insert("value", frame=frame)
        names.append(block.name)
    return names


def bake_mesh_cache(mesh_object, frames, path: str) -> str:
    """The predicted frames as a PC2 point cache (what Blender's Mesh Cache modifier plays), in the mesh's space."""
    frames = list(frames)
    skinning.bake_mesh_cache(mesh_object, path, frames, predicted_frames(mesh_object, frames), add_object=False)
    return path
