"""The skinkit sidebar panel (3D View > Sidebar > skinkit) and its scene settings."""
import bpy
import numpy as np
from bpy.props import BoolProperty, PointerProperty

from skinkit.blender import attributes, preview, rig, storage, unwrap

from . import operators, state


class SkinkitSettings(bpy.types.PropertyGroup):
    """The panel's values per scene: what an operator option starts from when it is not passed (see
    operators.OnActiveMesh.recall); scripts pass the options to the operators as keywords instead."""

    show_culling_sphere: BoolProperty(name="Culling Sphere", default=True,
                                      description="Draw the culling sphere of meshes whose bounds were shown")
    # objects are pointers here (the panel picks them); the operators take their names
    fit_sequence: PointerProperty(name="Sequence", type=bpy.types.Object,
                                  poll=lambda self, obj: obj.type == "MESH",
                                  description="The object whose cache modifier plays the example sequence")
    skin_rough_rig: PointerProperty(name="Rough Rig", type=bpy.types.Object,
                                    poll=lambda self, obj: obj.type == "ARMATURE",
                                    description="The drawn armature for Fit Rough Rig")


# Every other setting is an operator option remembered for the panel, defined once, by the operator.
SkinkitSettings.__annotations__.update({setting: definition for setting, definition
                                        in operators.remembered_settings().items()
                                        if setting not in SkinkitSettings.__annotations__})


class SKINKIT_PT_main(bpy.types.Panel):
    bl_label = "skinkit"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "skinkit"

    def draw(self, context):
        layout = self.layout
        mesh_object = operators.active_mesh(context)
        if mesh_object is None:
            if operators.active_armature(context) is not None:
                draw_statistics(layout, context, None)
            else:
                layout.label(text="Select a mesh", icon="INFO")
            return
        modifiers = rig.armature_modifiers(mesh_object)
        if not modifiers:
            layout.label(text=f"'{mesh_object.name}' has no Armature modifier", icon="INFO")
            draw_skinning(layout, context)
        draw_model(layout, mesh_object)
        layout.operator(operators.SKINKIT_OT_convert_to_animation_space.bl_idname, icon="ARMATURE_DATA")
        if storage.has_model(mesh_object.data):
            draw_model_actions(layout, context, mesh_object)
        if modifiers:
            draw_fitting(layout, context, mesh_object)
        draw_statistics(layout, context, mesh_object)
        draw_unwrap(layout, mesh_object)


def draw_unwrap(layout, mesh_object):
    """Animated Unwrap and the last unwrap's report."""
    box = layout.box()
    box.label(text="Texture Atlas", icon="UV")
    box.operator(operators.SKINKIT_OT_animated_unwrap.bl_idname, text="Animated Unwrap...", icon="UV")
    report = mesh_object.data.get(unwrap.REPORT_PROPERTY)
    if report:
        box.label(text=f"{report.get('charts')} charts in UV map '{report.get('uv_map')}'")
        box.label(text=f"L2 stretch: {report.get('stretch_rest', 0):.3f} at rest, "
                       f"{report.get('stretch_metric', 0):.3f} in the metric")
        if "stretch_frames" in report:
            box.label(text=f"L2 stretch over the action: {report['stretch_frames']:.3f}")
        box.label(text=f"Packing {report.get('packing_efficiency', 0):.3f}, "
                       f"texture efficiency {report.get('texture_efficiency', 0):.3f}")
    box.operator(operators.SKINKIT_OT_show_uv_layout.bl_idname, icon="IMAGE_DATA")


def draw_model(layout, mesh_object):
    """The model's state: bones, influences per vertex, the last comparison with the Armature modifier."""
    summary = storage.model_summary(mesh_object.data)
    box = layout.box()
    if summary is None:
        box.label(text="No animation-space model")
        return
    if summary["layout_version"] not in storage.READABLE_VERSIONS:
        box.label(text=f"Model layout v{summary['layout_version']} is not readable", icon="ERROR")
        return
    box.label(text=f"Animation space: {summary['bones']} bones (armature '{summary['armature']}')")
    box.label(text=f"Influences per vertex: {summary['influences_mean']:.2f} mean, "
                   f"{summary['influences_max']} max")
    comparison = state.LAST_COMPARISON.get(state.key(mesh_object))
    if comparison:
        box.label(text=f"Max deviation from Armature: {comparison['max_deviation']:.2e} "
                       f"({comparison['frames']} frames)")


def draw_model_actions(layout, context, mesh_object):
    """Preview, compare and bake, for a mesh that has a model."""
    enabled = preview.is_enabled(mesh_object)
    layout.operator(operators.SKINKIT_OT_toggle_preview.bl_idname, depress=enabled,
                    text="Live Preview: On" if enabled else "Live Preview: Off", icon="PLAY")
    settings = context.scene.skinkit
    column = layout.column(align=True)
    draw_frame_range(column, settings)
    column.operator(operators.SKINKIT_OT_compare_with_armature.bl_idname, icon="VIEWZOOM")
    column.operator(operators.SKINKIT_OT_bake_shape_keys.bl_idname, icon="SHAPEKEY_DATA")
    column.prop(settings, "cache_path")
    column.prop(settings, "add_cache_object")
    column.operator(operators.SKINKIT_OT_bake_mesh_cache.bl_idname, icon="FILE_CACHE")
    layout.operator(operators.SKINKIT_OT_remove_model.bl_idname, icon="X")


def draw_frame_range(column, settings):
    """The scene's frame range, or a start and end of its own."""
    column.prop(settings, "use_scene_range")
    if not settings.use_scene_range:
        row = column.row(align=True)
        row.prop(settings, "frame_start")
        row.prop(settings, "frame_end")


def tool_box(layout, context, title: str, source: str):
    """A tool's box: its title, then a column of its settings starting with where its frames come from."""
    box = layout.box()
    box.label(text=title, icon="MOD_ARMATURE")
    column = box.column(align=True)
    column.prop(context.scene.skinkit, source)
    return box, column


def draw_fitting(layout, context, mesh_object):
    """Settings of Fit from Example Poses and the last fit's errors, both models side by side."""
    settings = context.scene.skinkit
    box, column = tool_box(layout, context, "Fit from Example Poses", "fit_source")
    if settings.fit_source == "SEQUENCE":
        column.prop(settings, "fit_sequence")
    regularisation = "fit_lambda" if settings.fit_method == "PER_VERTEX" else "fit_delta"
    for name in ("fit_method", regularisation, "fit_influences", "fit_rings", "fit_max_influences", "fit_held_out"):
        column.prop(settings, name)
    box.operator(operators.SKINKIT_OT_fit_from_examples.bl_idname, icon="PLAY")
    report = mesh_object.data.get(attributes.REPORT_PROPERTY)
    if not report:
        return
    box.label(text=f"Last fit: {report.get('method')}, {report.get('examples')} examples, "
                   f"{report.get('held_out')} held out")
    for part, title in (("train", "Training"), ("held_out", "Held out")):
        if f"animation_space.{part}.rms" in report:
            box.label(text=title + " (mean / max of diagonal, normal °):")
            for model, short in (("animation_space", "AS"), ("linear_blend", "LBS"), ("input_rig", "Rig")):
                key = f"{model}.{part}"
                if key + ".mean" not in report:
                    continue
                box.label(text=f"  {short}: {report[key + '.mean']:.2e} / {report[key + '.max']:.2e}, "
                               f"{report[key + '.normal_mean_degrees']:.2f}° / {report[key + '.normal_max_degrees']:.1f}°")
    if report.get("fallback"):
        box.label(text="Linear-blend fit kept: animation space was not better in validation", icon="INFO")
    for warning in report.get("warnings", []):
        box.label(text=str(warning), icon="ERROR")
    box.operator(operators.SKINKIT_OT_show_fit_error.bl_idname, icon="COLOR")


def draw_skinning(layout, context):
    """Settings of Skin from Mesh Sequence (for meshes without a rig)."""
    settings = context.scene.skinkit
    box, column = tool_box(layout, context, "Skin from Mesh Sequence", "skin_source")
    if settings.skin_source in ("SEQUENCE", "AUTO"):
        draw_frame_range(column, settings)
    column.prop(settings, "skin_method")
    column.prop(settings, "skin_rough_rig" if settings.skin_method == "ROUGH_RIG" else "skin_bones")
    column.prop(settings, "skin_max_influences")
    column.prop(settings, "skin_train")
    box.operator(operators.SKINKIT_OT_skin_from_sequence.bl_idname, icon="PLAY")


def draw_statistics(layout, context, mesh_object):
    """The armature's pose statistics (state and computing them) and, for a mesh with a model, its bounds."""
    from skinkit.blender import pose_statistics

    armature = operators.active_armature(context)
    if armature is None:
        return
    box = layout.box()
    box.label(text=f"Pose statistics of '{armature.name}'", icon="ARMATURE_DATA")
    summary = pose_statistics.summary(armature)
    if summary is None:
        box.label(text="None yet")
    else:
        box.label(text=f"{summary['bones']} bones, {summary['source']}",
                  icon="CHECKMARK" if summary["up_to_date"] else "ERROR")
        if not summary["up_to_date"]:
            box.label(text="Out of date: the rig changed")
    row = box.row(align=True)
    row.prop(context.scene.skinkit, "stats_step")
    row.prop(context.scene.skinkit, "stats_poses")
    box.prop(context.scene.skinkit, "stats_spread")
    for source, text in (("ACTION", "From Action"), ("POSES", "From Example Poses"), ("LIMITS", "From Limits"),
                         ("UNIFORM", "Uniform")):
        box.operator(operators.SKINKIT_OT_compute_pose_statistics.bl_idname, text=text).source = source
    if mesh_object is not None and storage.has_model(mesh_object.data) and summary is not None:
        box.operator(operators.SKINKIT_OT_show_max_distance.bl_idname, icon="SPHERE")
        box.prop(context.scene.skinkit, "show_culling_sphere")


def draw_culling_spheres():
    """Viewport overlay: three great circles of each shown culling sphere."""
    import gpu
    from gpu_extras.batch import batch_for_shader

    scene = bpy.context.scene
    if not getattr(scene, "skinkit", None) or not scene.skinkit.show_culling_sphere:
        return
    angles = np.linspace(0, 2 * np.pi, 65)
    circle = np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    shown = {state.key(o) for o in scene.objects}
    for key, (centre, radius) in list(state.CULLING_SPHERES.items()):
        if key not in shown:
            continue
        points = []
        for plane in (circle, circle[:, [2, 0, 1]], circle[:, [1, 2, 0]]):
            ring = centre + radius * plane
            points.extend(np.stack([ring[:-1], ring[1:]], axis=1).reshape(-1, 3).tolist())
        batch = batch_for_shader(shader, "LINES", {"pos": points})
        shader.uniform_float("color", (1.0, 0.6, 0.1, 1.0))
        batch.draw(shader)


classes = (SkinkitSettings, SKINKIT_PT_main)
