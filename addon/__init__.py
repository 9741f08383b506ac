# SPDX-License-Identifier: GPL-3.0-or-later
"""skinkit for Blender: animation-space skinning of rigged meshes.

All maths lives in the `skinkit` wheel (numpy over a C core) and the scene-level work in
skinkit.blender, shared with the `skinkit` command line; this package holds only Blender's UI glue:
operators, the sidebar panel, settings and the live-preview handlers.
"""
import bpy
from bpy.app.handlers import persistent

from skinkit.blender import preview
from skinkit.blender.scene import armature_of
from skinkit.model import SkinkitError

from . import export, lod, lod_chain, operators, state, ui
from . import cli_command, handles, normal_maps, runtime, skeleton

# The modules whose `classes` register with Blender, in order (unregistered in reverse).
CLASS_MODULES = (operators, ui, lod, lod_chain, normal_maps, export, skeleton, handles)

_refreshing = False  # a preview refresh tags the mesh, which must not trigger another refresh


def refresh_previews(scene, depsgraph, armatures=None) -> None:
    """Re-evaluates every previewed mesh (whose armature is in `armatures`, if given)."""
    global _refreshing
    if _refreshing:
        return
    _refreshing = True
    try:
        for mesh_object in preview.previewed_objects(scene):
            try:
                if armatures is None or armature_of(mesh_object) in armatures:
                    preview.refresh(mesh_object, depsgraph)
            except SkinkitError as error:
                print(f"skinkit preview of '{mesh_object.name}' is off: {error}")
                preview.disable(mesh_object)
    finally:
        _refreshing = False


@persistent
def on_frame_change(scene, depsgraph):
    refresh_previews(scene, depsgraph)


@persistent
def on_depsgraph_update(scene, depsgraph):
    changed = {update.id.original for update in depsgraph.updates
               if isinstance(update.id, bpy.types.Object) and update.id.type == "ARMATURE"}
    if changed:
        refresh_previews(scene, depsgraph, changed)


_draw_handler = None


def _registered_classes() -> list:
    return [cls for module in CLASS_MODULES for cls in module.classes]


def register():
    global _draw_handler
    for cls in _registered_classes():
        bpy.utils.register_class(cls)
    runtime.register()  # its classes, the scene's LOD preview settings and the redraw handlers
    bpy.types.Scene.skinkit = bpy.props.PointerProperty(type=ui.SkinkitSettings)
    bpy.app.handlers.frame_change_post.append(on_frame_change)
    bpy.app.handlers.frame_change_post.append(skeleton.update_live_seams)
    bpy.app.handlers.depsgraph_update_post.append(on_depsgraph_update)
    bpy.app.handlers.load_post.append(state.clear)
    bpy.app.handlers.frame_change_post.append(handles.on_frame_change)
    bpy.app.handlers.depsgraph_update_post.append(handles.on_depsgraph_update)
    cli_command.register()
    if not bpy.app.background:  # no viewport to draw in otherwise
        _draw_handler = bpy.types.SpaceView3D.draw_handler_add(ui.draw_culling_spheres, (), "WINDOW", "POST_VIEW")


def unregister():
    global _draw_handler
    if _draw_handler is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_draw_handler, "WINDOW")
        _draw_handler = None
    bpy.app.handlers.depsgraph_update_post.remove(handles.on_depsgraph_update)
    bpy.app.handlers.frame_change_post.remove(handles.on_frame_change)
    cli_command.unregister()
    bpy.app.handlers.load_post.remove(state.clear)
    state.clear()
    bpy.app.handlers.depsgraph_update_post.remove(on_depsgraph_update)
    bpy.app.handlers.frame_change_post.remove(skeleton.update_live_seams)
    bpy.app.handlers.frame_change_post.remove(on_frame_change)
    del bpy.types.Scene.skinkit
    runtime.unregister()
    for cls in reversed(_registered_classes()):
        bpy.utils.unregister_class(cls)
