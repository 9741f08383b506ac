"""LOD Preview: a LOD chain (Build LOD Chain's <name>_LOD<n> objects) drawn by skinkit's runtime, geomorphed at a
real-valued level from a slider or from the scene camera by pixel tolerance (skinkit.blender.preview's LOD
section). The operator toggles it with every setting as an option; the panel's slider and checkboxes change the
running preview; frame changes, pose changes and camera moves redraw it."""
import bpy
from bpy.app.handlers import persistent
from bpy.props import BoolProperty, FloatProperty, PointerProperty

from skinkit.blender import preview
from skinkit.model import SkinkitError

from .common import SidebarPanel, not_reentrant, object_mode_problem
from .operators import active_mesh, refused, reports_errors


FIXED_LAYOUT_DESCRIPTION = ("Skin from the fixed-K pack (K slots per vertex, 16-bit bones: fewer bytes) where every "
                            "vertex's influences fit its 64 slots; from the CSR pack otherwise")


def apply_settings(settings, context) -> None:
    """An update callback of the panel's values: pushes them into the running preview of the active chain."""
    mesh_object = active_mesh(context)
    if mesh_object is None or not preview.lod_is_enabled(mesh_object):
        return
    try:
        preview.lod_set(mesh_object, context.evaluated_depsgraph_get(), level=settings.level,
                        from_camera=settings.from_camera, pixel_tolerance=settings.pixel_tolerance,
                        fixed_layout=settings.fixed_layout)
    except SkinkitError as error:
        print(f"skinkit LOD preview of '{mesh_object.name}' is off: {error}")
        preview.lod_disable(mesh_object)


class SkinkitRuntimeSettings(bpy.types.PropertyGroup):
    """The LOD preview's values per scene (the operator's options start from them)."""

    level: FloatProperty(name="Level", default=0.0, min=0.0, max=16.0, soft_max=8.0, step=5, precision=2,
                         update=apply_settings,
                         description="Real-valued level of detail: between two levels the finer one geomorphs "
                                     "towards the coarser (eq. 7.1)")
    from_camera: BoolProperty(name="From Camera", default=False, update=apply_settings,
                              description="Choose the level from the scene camera by pixel tolerance (eq. 7.2)")
    pixel_tolerance: FloatProperty(name="Pixel Tolerance", default=1.0, min=0.0, soft_max=10.0, update=apply_settings,
                                   description="Screen error allowed, in pixels of the render width")
    fixed_layout: BoolProperty(name="Fixed-K Layout", default=True, update=apply_settings,
                               description=FIXED_LAYOUT_DESCRIPTION)


def chain_head(context):
    mesh_object = active_mesh(context)
    levels = preview.chain_levels(mesh_object)
    return levels[0] if levels else None


class SKINKIT_OT_toggle_lod_preview(bpy.types.Operator):
    """Draw the active object's LOD chain with skinkit's runtime (culling sphere, level selection, geomorph) instead
    of the levels' Armature modifiers, or stop drawing it"""

    bl_idname = "skinkit.toggle_lod_preview"
    bl_label = "LOD Preview"
    bl_options = {"REGISTER", "UNDO"}

    level: FloatProperty(name="Level", default=0.0, min=0.0, max=16.0, description="Real-valued level to draw")
    from_camera: BoolProperty(name="From Camera", default=False,
                              description="Choose the level from the scene camera by pixel tolerance")
    pixel_tolerance: FloatProperty(name="Pixel Tolerance", default=1.0, min=0.0,
                                   description="Screen error allowed, in pixels")
    fixed_layout: BoolProperty(name="Fixed-K Layout", default=True, description=FIXED_LAYOUT_DESCRIPTION)

    @classmethod
    def poll(cls, context):
        no_chain = "The active object must be a level of a LOD chain (<name>_LOD<n>, from Build LOD Chain)"
        return refused(cls, no_chain if chain_head(context) is None else object_mode_problem(context))

    def invoke(self, context, event):
        settings = context.scene.skinkit_runtime  # the panel's values, when the button is pressed
        self.level, self.from_camera, self.pixel_tolerance, self.fixed_layout = (
            settings.level, settings.from_camera, settings.pixel_tolerance, settings.fixed_layout)
        return self.execute(context)

    @reports_errors
    def execute(self, context):
        mesh_object = active_mesh(context)
        if preview.lod_is_enabled(mesh_object):
            preview.lod_disable(mesh_object)
            return {"FINISHED"}
        preview.lod_enable(mesh_object, context.evaluated_depsgraph_get(), level=self.level,
                           from_camera=self.from_camera, pixel_tolerance=self.pixel_tolerance,
                           fixed_layout=self.fixed_layout)
        drawn = preview.lod_settings(mesh_object)
        self.report({"INFO"}, f"'{chain_head(context).name}': level {drawn['drawn_level']:.2f}, "
                              f"{drawn['drawn_influences']} influences drawn")
        return {"FINISHED"}


class SKINKIT_PT_lod_preview(SidebarPanel, bpy.types.Panel):
    bl_label = "LOD Preview"
    bl_parent_id = "SKINKIT_PT_level_of_detail"

    def draw(self, context):
        layout = self.layout
        mesh_object = active_mesh(context)
        enabled = mesh_object is not None and preview.lod_is_enabled(mesh_object)
        layout.operator(SKINKIT_OT_toggle_lod_preview.bl_idname, depress=enabled,
                        text="LOD Preview: On" if enabled else "LOD Preview: Off", icon="PLAY")
        settings = context.scene.skinkit_runtime
        column = layout.column(align=True)
        column.prop(settings, "from_camera")
        row = column.row()
        row.enabled = not settings.from_camera
        row.prop(settings, "level", slider=True)
        column.prop(settings, "pixel_tolerance")
        column.prop(settings, "fixed_layout")
        if enabled:
            drawn = preview.lod_settings(mesh_object)
            level = drawn["drawn_level"]
            box = layout.box()
            box.label(text=f"Drawn: level {level:.2f} (LOD{int(level)}, geomorph {level - int(level):.0%})")
            box.label(text=f"Influences drawn: {drawn['drawn_influences']}")
            box.label(text=layout_line(drawn))


def layout_line(drawn: dict) -> str:
    """The panel's line on the pack the runtime skinned from, and why not the fixed-K one when it could not be."""
    if drawn.get("drawn_layout") == "fixed":
        return f"Layout: fixed-K, {drawn['slots_per_vertex']} slots per vertex"
    if drawn.get("fixed_layout") and drawn.get("fixed_layout_problem"):
        return f"Layout: CSR ({drawn['fixed_layout_problem']})"
    return "Layout: CSR"


@not_reentrant  # a redraw tags the level objects, which must not trigger another redraw
def refresh_lod_previews(scene, depsgraph, changed=None) -> None:
    """Redraws every running LOD preview (those whose armature or scene camera is in `changed`, if given)."""
    for head in preview.lod_previewed_objects(scene):
        try:
            if changed is None or changed & {scene.camera, *(m.object for m in head.modifiers
                                                             if m.type == "ARMATURE")}:
                preview.lod_refresh(head, depsgraph)
        except SkinkitError as error:
            print(f"skinkit LOD preview of '{head.name}' is off: {error}")
            preview.lod_disable(head)


@persistent
def on_frame_change(scene, depsgraph):
    refresh_lod_previews(scene, depsgraph)


@persistent
def on_depsgraph_update(scene, depsgraph):
    changed = {update.id.original for update in depsgraph.updates
               if isinstance(update.id, bpy.types.Object) and update.id.type in {"ARMATURE", "CAMERA"}}
    if changed:
        refresh_lod_previews(scene, depsgraph, changed)


classes = (SkinkitRuntimeSettings, SKINKIT_OT_toggle_lod_preview, SKINKIT_PT_lod_preview)


def register():
    """The classes, the scene's settings and the redraw handlers."""
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.skinkit_runtime = PointerProperty(type=SkinkitRuntimeSettings)
    bpy.app.handlers.frame_change_post.append(on_frame_change)
    bpy.app.handlers.depsgraph_update_post.append(on_depsgraph_update)


def unregister():
    bpy.app.handlers.depsgraph_update_post.remove(on_depsgraph_update)
    bpy.app.handlers.frame_change_post.remove(on_frame_change)
    del bpy.types.Scene.skinkit_runtime
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
