"""The skinkit sidebar panel (3D View > Sidebar > skinkit) and its scene settings."""
import bpy
from bpy.props import BoolProperty, IntProperty, StringProperty

from skinkit.blender import preview, rig, storage

from . import operators


class SkinkitSettings(bpy.types.PropertyGroup):
    use_scene_range: BoolProperty(name="Scene Frame Range", default=True,
                                  description="Use the scene's frame range for comparing and baking")
    frame_start: IntProperty(name="Start", default=1)
    frame_end: IntProperty(name="End", default=250)
    cache_path: StringProperty(name="Cache File", subtype="FILE_PATH", default="//skinkit_cache.pc2",
                               description="Where Bake to Mesh Cache writes its PC2 file")
    add_cache_object: BoolProperty(name="Add Cache Object", default=True,
                                   description="Also add a copy of the mesh that plays the cache")


class SKINKIT_PT_main(bpy.types.Panel):
    bl_label = "skinkit"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "skinkit"

    def draw(self, context):
        layout = self.layout
        mesh_object = operators.active_mesh(context)
        if mesh_object is None:
            layout.label(text="Select a mesh", icon="INFO")
            return
        modifiers = rig.armature_modifiers(mesh_object)
        if not modifiers:
            layout.label(text=f"'{mesh_object.name}' has no Armature modifier", icon="ERROR")
        draw_model(layout, mesh_object)
        layout.operator(operators.SKINKIT_OT_convert.bl_idname, icon="ARMATURE_DATA")
        if storage.has_model(mesh_object.data):
            draw_model_actions(layout, context, mesh_object)


def draw_model(layout, mesh_object):
    """The model's state: bones, influences per vertex, the last comparison with the Armature modifier."""
    summary = storage.model_summary(mesh_object.data)
    box = layout.box()
    if summary is None:
        box.label(text="No animation-space model")
        return
    if summary["layout_version"] != storage.LAYOUT_VERSION:
        box.label(text=f"Model layout v{summary['layout_version']} is not readable", icon="ERROR")
        return
    box.label(text=f"Animation space: {summary['bones']} bones (armature '{summary['armature']}')")
    box.label(text=f"Influences per vertex: {summary['influences_mean']:.2f} mean, "
                   f"{summary['influences_max']} max")
    comparison = operators.LAST_COMPARISON.get(mesh_object.name)
    if comparison:
        box.label(text=f"Max deviation from Armature: {comparison['max_deviation']:.2e} "
                       f"({comparison['frames']} frames)")


def draw_model_actions(layout, context, mesh_object):
    """Preview, compare and bake, for a mesh that has a model."""
    enabled = preview.is_enabled(mesh_object)
    layout.operator(operators.SKINKIT_OT_preview.bl_idname, depress=enabled,
                    text="Live Preview: On" if enabled else "Live Preview: Off", icon="PLAY")
    settings = context.scene.skinkit
    column = layout.column(align=True)
    column.prop(settings, "use_scene_range")
    if not settings.use_scene_range:
        row = column.row(align=True)
        row.prop(settings, "frame_start")
        row.prop(settings, "frame_end")
    column.operator(operators.SKINKIT_OT_compare.bl_idname, icon="VIEWZOOM")
    column.operator(operators.SKINKIT_OT_bake_shape_keys.bl_idname, icon="SHAPEKEY_DATA")
    column.prop(settings, "cache_path")
    column.prop(settings, "add_cache_object")
    column.operator(operators.SKINKIT_OT_bake_mesh_cache.bl_idname, icon="FILE_CACHE")
    layout.operator(operators.SKINKIT_OT_remove_model.bl_idname, icon="X")


classes = (SkinkitSettings, SKINKIT_PT_main)
