"""Putting the scene back when writing a result fails half-way (Blender has no transactions).

    with restored_on_failure(mesh_object):
        ... write vertex groups, attributes, UV maps, custom properties, new objects ...

Before the block runs, the object's mesh is copied (in Blender's C code: vertex groups and their weights, attributes,
UV maps, seams, shape keys and custom properties all live on the mesh), its custom properties are kept and the
datablocks that exist are listed. If the block raises, every datablock it added is removed, the copy takes the
place of the half-written mesh for every object that uses it (and its name), and the exception goes on to the
operator, which reports it. If the block succeeds, the copy is removed.
"""
from __future__ import annotations

from contextlib import contextmanager

import bpy

#: The datablock collections a write may add to (objects first: a mesh still used by an object cannot go first).
COLLECTIONS = ("objects", "meshes", "armatures", "actions", "images", "materials", "collections", "node_groups",
               "textures")


def plain(value):
    """An ID property as plain Python (a copy that outlives the property)."""
    return value.to_dict() if hasattr(value, "to_dict") else value.to_list() if hasattr(value, "to_list") else value


def remove_added(existing: dict) -> None:
    for name in COLLECTIONS:
        collection = getattr(bpy.data, name)
        for added in set(collection.keys()) - existing[name]:
            collection.remove(collection[added])


def put_back(mesh_object, saved_mesh, object_properties: dict, existing: dict) -> None:
    written = mesh_object.data
    name = written.name
    written.user_remap(saved_mesh)  # every object using the half-written mesh now uses the copy
    bpy.data.meshes.remove(written)
    saved_mesh.name = name
    remove_added(existing)
    for key in [key for key in mesh_object.keys() if key not in object_properties]:
        del mesh_object[key]
    for key, value in object_properties.items():
        mesh_object[key] = value


@contextmanager
def restored_on_failure(mesh_object):
    if mesh_object is None or mesh_object.type != "MESH":
        yield
        return
    saved_mesh = mesh_object.data.copy()
    object_properties = {key: plain(value) for key, value in mesh_object.items()}
    existing = {name: set(getattr(bpy.data, name).keys()) for name in COLLECTIONS}
    try:
        yield
    except BaseException:
        put_back(mesh_object, saved_mesh, object_properties, existing)
        raise
    bpy.data.meshes.remove(saved_mesh)
