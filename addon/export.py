# SPDX-License-Identifier: GPL-3.0-or-later
"""Export for Engines: the operator (over skinkit.blender.export, which `skinkit export` also calls) and its panel
in skinkit's sidebar tab."""
import os

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, StringProperty

from skinkit.blender import export
from skinkit.blender.rig import armature_modifiers
from skinkit.model import SkinkitError

from .operators import active_mesh, reports_errors

#: Blender enum identifiers of the formats, as the bridge's strings (export.FORMATS).
FORMAT_ITEMS = (("GLB", "glTF Binary (.glb)", "glTF 2.0 with the animation-space model as _SKINKIT_* attributes"),
                ("FBX", "FBX (.fbx)", "FBX 7.4, Blender units kept through FBX's unit scale"),
                ("USD", "USD (.usdc)", "Universal Scene Description with UsdSkel"))
FORMAT_OPTION = {identifier: identifier.lower() for identifier, _, _ in FORMAT_ITEMS}
DEFAULT_EXTENSION = {"GLB": ".glb", "FBX": ".fbx", "USD": ".usdc"}


def skinned_mesh(context):
    obj = active_mesh(context)
    return obj if obj is not None and armature_modifiers(obj) else None


class SKINKIT_OT_export_for_engines(bpy.types.Operator):
    """Export the active mesh's LOD chain (<name>_LOD0..n), or the active skinned mesh alone, with its armature and
    action through Blender's own glTF, FBX or USD exporter: at most 4 normalised weights per vertex, and for glTF the
    animation-space model as custom vertex attributes. The scene is not changed"""

    bl_idname = "skinkit.export_for_engines"
    bl_label = "Export for Engines"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="File Path", subtype="FILE_PATH", description="The file to write")
    format: EnumProperty(name="Format", items=FORMAT_ITEMS, default="GLB")
    chain: StringProperty(name="Chain", description="The chain <chain>_LOD0..n or the object to export (empty: the "
                                                    "active mesh's chain, or the active mesh)")
    animation_space: BoolProperty(name="Animation-Space Attributes", default=True,
                                  description="glTF only: the model's p_j as _SKINKIT_P_<slot> vertex attributes "
                                              "(docs/engine-format.md) for engines that evaluate animation space")
    unit_scale: FloatProperty(name="Unit Scale", default=0.0, min=0.0, soft_max=100.0, precision=4,
                              description="glTF and USD: metres per Blender unit, the file being in metres (0: the "
                                          "scene's Unit Scale, 0.01 in a centimetre scene). FBX records the scene's "
                                          "unit itself")

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        if obj is None or obj.type != "MESH":
            cls.poll_message_set("The active object must be a skinned mesh (a LOD level or a skinkit result)")
            return False
        if not armature_modifiers(obj):
            cls.poll_message_set(f"'{obj.name}' needs an Armature modifier (a rig) to be exported for engines")
            return False
        return True

    def chain_name(self, context) -> str:
        return self.chain or export.chain_name(skinned_mesh(context))

    def invoke(self, context, event):
        """The file browser, on `<chain>.<format's extension>` beside the .blend (or the last path, re-suffixed: the
        panel's buttons change the format between calls)."""
        if self.filepath:
            stem = os.path.splitext(self.filepath)[0]
        else:
            folder = os.path.dirname(bpy.data.filepath) if bpy.data.filepath else os.getcwd()
            stem = os.path.join(folder, self.chain_name(context))
        self.filepath = stem + DEFAULT_EXTENSION[self.format]
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    @reports_errors
    def execute(self, context):
        if not self.filepath:
            self.report({"ERROR"}, "no file path: give filepath")
            return {"CANCELLED"}
        objects = export.chain_objects(self.chain_name(context))
        report = export.export_for_engines(objects, bpy.path.abspath(self.filepath), FORMAT_OPTION[self.format],
                                           animation_space=self.animation_space, unit_scale=self.unit_scale or None)
        for warning in report["warnings"]:
            self.report({"WARNING"}, warning)
        limited = sum(report["limited_vertices"].values())
        self.report({"INFO"}, f"{report['out']}: {len(report['objects'])} object(s), {report['bones']} bones, "
                              f"action {report['action']!r}" + (f", {limited} vertices' weights limited to "
                                                                 f"{report['max_joints']}" if limited else ""))
        return {"FINISHED"}


class SKINKIT_PT_export(bpy.types.Panel):
    bl_label = "Export for Engines"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "skinkit"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        mesh_object = skinned_mesh(context)
        if mesh_object is None:
            layout.label(text="Select a skinned mesh or a LOD level", icon="INFO")
            return
        name = export.chain_name(mesh_object)
        try:
            objects = export.chain_objects(name)
        except SkinkitError as error:
            layout.label(text=str(error), icon="ERROR")
            return
        layout.label(text=f"{name}: {len(objects)} object(s)", icon="OUTLINER_COLLECTION")
        layout.label(text=f"glTF and USD in metres: 1 unit = {export.scene_unit_scale():g} m (the scene's Unit "
                          "Scale)", icon="DRIVER_DISTANCE")
        for identifier, label, _ in FORMAT_ITEMS:
            operator = layout.operator(SKINKIT_OT_export_for_engines.bl_idname, text=f"Export {label}...",
                                       icon="EXPORT")
            operator.format, operator.chain = identifier, name


classes = (SKINKIT_OT_export_for_engines, SKINKIT_PT_export)
