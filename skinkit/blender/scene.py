"""Finding, loading and placing objects in a Blender scene, for the add-on and the command line alike.

Finders take "the named object, or the only one" and refuse clearly otherwise (naming the candidates);
loaders open a .blend or import an .fbx/.glb/.gltf/.abc/.obj; `named` puts an object's name in front of
errors from the numeric layer; `transform_points` is the one place points are moved by a 4x4 matrix.
"""
from __future__ import annotations

import os
from contextlib import contextmanager

import bpy
import numpy as np

from ..model import SkinkitError
from . import compat
from .rig import armature_modifiers


@contextmanager
def named(name: str):
    """Prefixes an object's name to errors from the numeric layer, which does not know it."""
    try:
        yield
    except SkinkitError as error:
        message = str(error)
        raise SkinkitError(message if message.startswith(f"'{name}'") else f"'{name}': {message}") from None


def naming(scene_object):
    return named(scene_object.name)


# ---- spaces -----------------------------------------------------------------------------------------------------

def transform_points(matrix, points) -> np.ndarray:
    """Points (..., 3) moved by the affine 4x4 `matrix` (row-major, column vectors): M p."""
    matrix = np.asarray(matrix, dtype=np.float64)
    return np.asarray(points) @ matrix[:3, :3].T + matrix[:3, 3]


def world_matrix(scene_object) -> np.ndarray:
    return np.array(scene_object.matrix_world)


def into_local_space(mesh_object, other, positions: np.ndarray) -> np.ndarray:
    """Positions in `other`'s local space, mapped into mesh_object's local space."""
    return transform_points(np.linalg.inv(world_matrix(mesh_object)) @ world_matrix(other), positions)


def world_to_local(mesh_object, world_positions) -> np.ndarray:
    """(..., 3) world-space positions in the object's local space."""
    return transform_points(np.linalg.inv(world_matrix(mesh_object)), world_positions)


def local_to_world(scene_object, positions) -> np.ndarray:
    return transform_points(world_matrix(scene_object), positions)


def check_same_vertex_count(mesh_object, other, count: int) -> None:
    if count != len(mesh_object.data.vertices):
        raise SkinkitError(f"example '{other.name}' has {count} vertices, '{mesh_object.name}' has "
                           f"{len(mesh_object.data.vertices)}: examples need the same vertices in the same order")


# ---- finders ----------------------------------------------------------------------------------------------------

def named_or_only(objects, name: str | None, kind: str, *, among=None, plural: str | None = None,
                  where: str = "in the scene", owner: str = "the scene", option: str = "--object",
                  required: bool = True):
    """The object called `name` among `objects`, or, without a name, the only one of `among` (default
    `objects`). Refuses a missing name; refuses (or, not `required`, answers None) when there is not exactly
    one candidate, listing them."""
    if name is not None:
        found = next((o for o in objects if o.name == name), None)
        if found is None:
            raise SkinkitError(f"no {kind} named '{name}' {where}")
        return found
    candidates = list(objects if among is None else among)
    if len(candidates) == 1:
        return candidates[0]
    if not required:
        return None
    listed = ", ".join(f"'{o.name}'" for o in candidates) or "none"
    raise SkinkitError(f"{owner} has {len(candidates)} {plural or kind + 's'} ({listed}); name one with {option}")


def meshes(scene=None) -> list:
    return [o for o in (scene or bpy.context.scene).objects if o.type == "MESH"]


def skinned_meshes(scene=None) -> list:
    """The meshes with an Armature modifier."""
    return [o for o in meshes(scene) if armature_modifiers(o)]


def find_skinned_mesh(objects, name: str | None = None):
    """The object named `name` (rig_of refuses it if it is not a skinned mesh), or the only mesh with an Armature
    modifier among `objects`."""
    objects = list(objects)
    return named_or_only(objects, name, "object", among=[o for o in objects if o.type == "MESH" and
                                                           armature_modifiers(o)],
                         plural="meshes with an Armature modifier")


def scene_mesh(name: str | None = None):
    """The mesh named `name`, or the scene's only skinned mesh, or its only mesh."""
    every = meshes()
    skinned = skinned_meshes()
    return named_or_only(every, name, "mesh", among=skinned if len(skinned) == 1 else every, plural="meshes")


def find_armature(name: str | None = None):
    """The armature named `name`, or the scene's only armature."""
    armatures = [o for o in bpy.context.scene.objects if o.type == "ARMATURE"]
    return named_or_only(armatures, name, "armature", where="in the rig", owner="the rig", option="--armature")


def skinned_mesh_of(armature, name: str | None = None):
    """The mesh named `name` among those the armature deforms, or the only one (None when it deforms several
    or none)."""
    deformed = [o for o in meshes() if any(m.object == armature for m in armature_modifiers(o))]
    return named_or_only(deformed, name, "mesh", where=f"is deformed by '{armature.name}'", required=False)


def armature_of(mesh_object):
    """The armature object driving the mesh (its first Armature modifier's), or None."""
    return next((m.object for m in armature_modifiers(mesh_object) if m.object is not None), None)


def fitted_mesh(armature, name: str | None, rest_path: str | None):
    """The rigged mesh to fit (named, or the only skinned one), or a new one made from the rest geometry at
    `rest_path` and bound to the armature."""
    if rest_path is None:
        if not skinned_meshes() and name is None:
            raise SkinkitError("the rig has no mesh with an Armature modifier: give the rest geometry in the rig's "
                               "bind pose with --rest (an .obj, or an .fbx/.glb holding one mesh)")
        return find_skinned_mesh(bpy.context.scene.objects, name)
    mesh_object = rest_mesh_object(rest_path)
    modifier = mesh_object.modifiers.new("Armature", "ARMATURE")
    modifier.object = armature
    return mesh_object


@contextmanager
def action_assigned(armature, name: str | None):
    """The named action assigned to the armature while inside (its own action when name is None)."""
    data = armature.animation_data
    current = data.action if data else None
    if name is None:
        if current is None:
            raise SkinkitError(f"'{armature.name}' has no action: name one with --action")
        yield current
        return
    action = bpy.data.actions.get(name)
    if action is None:
        raise SkinkitError(f"no action named '{name}' in the scene")
    data = data or armature.animation_data_create()
    slot = compat.action_slot(data)
    compat.assign_action(data, action)
    try:
        yield action
    finally:
        compat.assign_action(data, current, slot)


# ---- loading and saving -----------------------------------------------------------------------------------------

def open_blend(path: str) -> None:
    if not os.path.isfile(path):
        raise SkinkitError(f"{path}: no such file")
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path), load_ui=False)
    except RuntimeError as error:
        raise SkinkitError(f"{path}: Blender could not open it ({str(error).strip()})") from None


def load_scene(path: str) -> None:
    """Opens a .blend, or imports an .fbx/.glb/.gltf into an empty scene."""
    if not os.path.exists(path):
        raise SkinkitError(f"{path}: no such file")
    extension = os.path.splitext(path)[1].lower()
    if extension == ".blend":
        open_blend(path)
        return
    # anim_offset=0 keeps the file's own frame numbers (Blender's default shifts the first key to frame 1),
    # so the rig's frames line up with an Alembic sequence's.
    importers = {".fbx": lambda: bpy.ops.import_scene.fbx(filepath=os.path.abspath(path), anim_offset=0.0),
                 ".glb": lambda: bpy.ops.import_scene.gltf(filepath=os.path.abspath(path)),
                 ".gltf": lambda: bpy.ops.import_scene.gltf(filepath=os.path.abspath(path))}
    if extension not in importers:
        raise SkinkitError(f"{path}: a rig must be .blend, .fbx, .glb or .gltf")
    empty_scene()
    try:
        importers[extension]()
    except RuntimeError as error:
        raise SkinkitError(f"{path}: Blender could not import it ({str(error).strip()})") from None


def empty_scene() -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)


def imported_meshes(import_file) -> list:
    """The meshes that `import_file()` adds to the scene."""
    before = set(bpy.context.scene.objects)
    import_file()
    return [o for o in bpy.context.scene.objects if o not in before and o.type == "MESH"]


def import_alembic(path: str, scale: float):
    """The one animated mesh of an .abc, scaled by `scale`, with the scene's frame range set to its own."""
    if not os.path.isfile(path):
        raise SkinkitError(f"{path}: no such file")
    found = imported_meshes(lambda: bpy.ops.wm.alembic_import(filepath=os.path.abspath(path), set_frame_range=True,
                                                              scale=scale))
    if len(found) != 1:
        raise SkinkitError(f"{path}: expected one animated mesh, found {len(found)}")
    return found[0]


def new_mesh_object(name: str, positions, triangles):
    """A mesh object in the scene's collection holding the given geometry (for meshes read from files)."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(np.asarray(positions).tolist(), [], np.asarray(triangles).tolist())
    mesh.update()
    mesh_object = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(mesh_object)
    return mesh_object


def triangle_mesh(name: str, positions, triangles):
    """A new mesh of the triangles (n x 3 vertex indices) over the positions, written by foreach_set (no Python
    lists); the caller adds what else it needs, then calls mesh.update."""
    mesh = bpy.data.meshes.new(name)
    write_triangles(mesh, positions, triangles)
    return mesh


def write_triangles(mesh, positions, triangles) -> None:
    """Fills a mesh with no geometry (new, or after clear_geometry) with the triangles over the positions."""
    mesh.vertices.add(len(positions))
    mesh.vertices.foreach_set("co", np.asarray(positions).astype(np.float32).reshape(-1))
    mesh.loops.add(3 * len(triangles))
    mesh.loops.foreach_set("vertex_index", np.asarray(triangles).astype(np.int32).reshape(-1))
    mesh.polygons.add(len(triangles))
    mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * len(triangles), 3, dtype=np.int32))
    mesh.polygons.foreach_set("loop_total", np.full(len(triangles), 3, np.int32))


def rest_mesh_object(path: str):
    """A mesh object holding the rest geometry of --rest, in world space, in the file's vertex order."""
    extension = os.path.splitext(path)[1].lower()
    if extension == ".obj":
        from ..meshio import read_obj

        return new_mesh_object("skinkit_fitted", *read_obj(path))
    if extension not in (".fbx", ".glb", ".gltf"):
        raise SkinkitError(f"--rest {path}: expected an .obj, .fbx, .glb or .gltf file")
    if not os.path.isfile(path):
        raise SkinkitError(f"--rest {path}: no such file")
    importer = bpy.ops.import_scene.fbx if extension == ".fbx" else bpy.ops.import_scene.gltf
    found = imported_meshes(lambda: importer(filepath=os.path.abspath(path)))
    if len(found) != 1:
        raise SkinkitError(f"--rest {path}: expected one mesh, found {len(found)}")
    mesh_object = found[0]
    for modifier in list(mesh_object.modifiers):  # its own skinning, if any, is what we replace
        mesh_object.modifiers.remove(modifier)
    mesh_object.parent = None
    return mesh_object


def save_blend(path: str) -> str:
    """Saves the scene as `path` (a .blend); returns its absolute path for the report."""
    if not path.endswith(".blend"):
        raise SkinkitError(f"{path}: the output must be a .blend file")
    bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(path), check_existing=False)
    return os.path.abspath(path)


def export_glb(path: str, object_names) -> str:
    """Writes the named objects (and their animation) as a binary glTF; returns its absolute path."""
    for scene_object in bpy.context.scene.objects:
        scene_object.select_set(scene_object.name in object_names)
    bpy.ops.export_scene.gltf(filepath=os.path.abspath(path), export_format="GLB", use_selection=True,
                              export_animations=True)
    return os.path.abspath(path)
