"""A fingerprint of the whole Blender scene, for tests that an operation which failed or was cancelled left it
exactly as it was: every object (transform, parent, modifiers and their settings, vertex groups and weights,
custom properties, constraints, pose), every mesh (positions, topology, attributes with their data, UV maps,
shape keys, colour attributes), armatures, actions and their keys, images and their pixels, collections,
materials, node groups and the scene's own settings.

    before = scene_fingerprint()
    ... the operation that fails ...
    assert_unchanged(before)          # names what differs
"""
from __future__ import annotations

import hashlib

import bpy
import numpy as np

from skinkit.blender import compat


def digest(*arrays) -> str:
    hasher = hashlib.sha1()
    for array in arrays:
        hasher.update(np.ascontiguousarray(array).tobytes() if isinstance(array, np.ndarray) else repr(array).encode())
    return hasher.hexdigest()


def read(collection, attribute: str, width: int, dtype=np.float32) -> np.ndarray:
    values = np.empty(len(collection) * width, dtype)
    if len(collection):
        collection.foreach_get(attribute, values)
    return values


def simple_properties(struct) -> dict:
    """The struct's own settings (numbers, strings, enums, vectors, pointers by name): what an RNA panel shows."""
    result = {}
    for prop in struct.bl_rna.properties:
        if prop.identifier in ("rna_type",) or prop.type == "COLLECTION":
            continue
        value = getattr(struct, prop.identifier, None)
        if prop.type == "POINTER":
            value = getattr(value, "name", None) if isinstance(value, bpy.types.ID) else None
        elif hasattr(value, "__len__") and not isinstance(value, str):
            value = tuple(value)
        result[prop.identifier] = repr(value)
    return result


def custom_properties(id_or_struct) -> dict:
    return {key: repr(value.to_dict() if hasattr(value, "to_dict") else
                      value.to_list() if hasattr(value, "to_list") else value)
            for key, value in id_or_struct.items()}


def attribute_data(attribute) -> str:
    width = {"FLOAT_VECTOR": 3, "FLOAT_COLOR": 4, "BYTE_COLOR": 4, "FLOAT2": 2, "INT32_2D": 2,
             "QUATERNION": 4, "FLOAT4X4": 16}.get(attribute.data_type, 1)
    field = {"FLOAT_VECTOR": "vector", "FLOAT_COLOR": "color", "BYTE_COLOR": "color", "FLOAT2": "vector",
             "INT32_2D": "value", "QUATERNION": "value", "FLOAT4X4": "value"}.get(attribute.data_type, "value")
    dtype = np.int32 if attribute.data_type in ("INT", "INT8", "INT32_2D") else \
        bool if attribute.data_type == "BOOLEAN" else np.float32
    try:
        return digest(read(attribute.data, field, width, dtype))
    except (TypeError, RuntimeError, AttributeError):  # a type without foreach access: its length stands in
        return f"{len(attribute.data)} values"


def image_pixels(image) -> str:
    pixels = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(pixels)
    return digest(pixels)


def mesh_fingerprint(mesh) -> dict:
    return {
        "positions": digest(read(mesh.vertices, "co", 3)),
        "edges": digest(read(mesh.edges, "vertices", 2, np.int32)),
        "loops": digest(read(mesh.loops, "vertex_index", 1, np.int32)),
        "polygons": digest(read(mesh.polygons, "loop_start", 1, np.int32),
                           read(mesh.polygons, "material_index", 1, np.int32)),
        "attributes": {a.name: (a.domain, a.data_type, attribute_data(a)) for a in mesh.attributes},
        "uv_maps": {uv.name: digest(read(uv.uv, "vector", 2)) for uv in mesh.uv_layers},
        "active_uv": mesh.uv_layers.active.name if mesh.uv_layers.active else None,
        "active_colour": mesh.color_attributes.active_color.name if mesh.color_attributes.active_color else None,
        "shape_keys": None if mesh.shape_keys is None else {
            key.name: (key.value, key.mute, key.relative_key.name, digest(read(key.data, "co", 3)))
            for key in mesh.shape_keys.key_blocks},
        "materials": [m.name if m else None for m in mesh.materials],
        "props": custom_properties(mesh),
    }


def vertex_weights(obj) -> str:
    """Every vertex group weight of a mesh object (no foreach access exists for them)."""
    if obj.type != "MESH" or not obj.vertex_groups:
        return ""
    return digest([(v.index, [(g.group, round(g.weight, 7)) for g in v.groups]) for v in obj.data.vertices])


def object_fingerprint(obj) -> dict:
    entry = {
        "type": obj.type, "data": obj.data.name if obj.data else None,
        "parent": obj.parent.name if obj.parent else None, "parent_type": obj.parent_type,
        # the stored transform (matrix_world is evaluated: a depsgraph update alone changes it on a new object)
        "matrix": digest(np.array(obj.matrix_basis, np.float64), np.array(obj.matrix_parent_inverse, np.float64)),
        "hide": (obj.hide_viewport, obj.hide_render),
        "modifiers": [(m.name, m.type, simple_properties(m)) for m in obj.modifiers],
        "constraints": [(c.name, c.type, simple_properties(c)) for c in obj.constraints],
        "vertex_groups": [g.name for g in obj.vertex_groups], "weights": vertex_weights(obj),
        "active_group": obj.vertex_groups.active_index,
        "action": obj.animation_data.action.name if obj.animation_data and obj.animation_data.action else None,
        "props": custom_properties(obj), "collections": sorted(c.name for c in obj.users_collection),
    }
    if obj.type == "ARMATURE":
        entry["pose"] = digest([(b.name, tuple(np.array(b.matrix_basis).ravel())) for b in obj.pose.bones])
        entry["pose_props"] = {b.name: custom_properties(b) for b in obj.pose.bones}
    return entry


def scene_fingerprint() -> dict:
    scene = bpy.context.scene
    return {
        "objects": {obj.name: object_fingerprint(obj) for obj in bpy.data.objects},
        "meshes": {mesh.name: mesh_fingerprint(mesh) for mesh in bpy.data.meshes},
        "armatures": {arm.name: digest([(b.name, tuple(b.head_local), tuple(b.tail_local), b.parent.name if b.parent
                                         else None) for b in arm.bones]) for arm in bpy.data.armatures},
        "actions": {action.name: digest([(c.data_path, c.array_index, tuple(read(c.keyframe_points, "co", 2)))
                                         for c in compat.action_fcurves(action)]) for action in bpy.data.actions},
        "images": {image.name: (tuple(image.size), image.filepath, image.source,
                                image_pixels(image) if image.has_data else None)
                   for image in bpy.data.images},
        "collections": {c.name: (sorted(o.name for o in c.objects), sorted(k.name for k in c.children))
                        for c in bpy.data.collections},
        "scene_collection": sorted(o.name for o in scene.collection.objects),
        "materials": sorted(m.name for m in bpy.data.materials),
        "node_groups": sorted(g.name for g in bpy.data.node_groups),
        "textures": sorted(t.name for t in bpy.data.textures),
        "texts": sorted(t.name for t in bpy.data.texts),
        # The panel's remembered options (scene.skinkit) are left out: an operator that fails keeps the options
        # it was given there, so that the artist can correct one and run it again.
        "scene": (scene.frame_current, scene.frame_start, scene.frame_end,
                  {key: value for key, value in custom_properties(scene).items() if key != "skinkit"}),
        "active": bpy.context.view_layer.objects.active.name if bpy.context.view_layer.objects.active else None,
        "mode": bpy.context.mode,
    }


def differences(before, after, path: str = "") -> list[str]:
    """Where two fingerprints differ, as paths such as "meshes/arm/attributes/skinkit_error"."""
    if isinstance(before, dict) and isinstance(after, dict):
        found = []
        for key in sorted(set(before) | set(after), key=str):
            if key not in after:
                found.append(f"{path}/{key}: gone")
            elif key not in before:
                found.append(f"{path}/{key}: added")
            else:
                found += differences(before[key], after[key], f"{path}/{key}")
        return found
    return [] if before == after else [f"{path}: {str(before)[:80]} -> {str(after)[:80]}"]


def assert_unchanged(before: dict, what: str = "") -> None:
    changed = differences(before, scene_fingerprint())
    assert not changed, f"{what} changed the scene: {changed[:12]}"
