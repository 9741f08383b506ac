"""The Level of Detail family: Limit Influences and Subdivide Model, and the "Level of Detail" panel.

Both operators write a new object (`<name>_limited`, `<name>_subdivided`) through skinkit.blender.lod; the source is
never changed. Limit Influences runs as a background job (progress in the status bar, Esc cancels); both report
their errors through the add-on's one error path.
"""
import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty

from skinkit.blender import lod, storage
from skinkit.blender.rig import armature_modifiers
from skinkit.subdivide import MAX_LEVELS

from .common import SidebarPanel, object_mode_problem
from .operators import DialogJobOperator, active_mesh, refused

#: Blender enum identifiers of this family, as skinkit's option strings (see addon/options.py for the others).
SCHEME_ITEMS = (("CATMULL_CLARK", "Catmull-Clark", "Quads from any polygons, as Blender's Subdivision Surface"),
                ("LOOP", "Loop", "Triangles into four (triangle meshes only)"))
BOUNDARY_ITEMS = (("ALL", "All", "Smooth boundaries and corners"),
                  ("PRESERVE_CORNERS", "Keep Corners", "Smooth boundaries, keep corners (vertices in one face) sharp"))
UV_ITEMS = (("NONE", "None", "UVs are not smoothed (linear)"),
            ("PRESERVE_CORNERS", "Keep Corners", "UVs smoothed, island corners kept"),
            ("PRESERVE_BOUNDARIES", "Keep Boundaries", "UVs smoothed inside islands, their boundaries linear"),
            ("SMOOTH_ALL", "All", "UVs smoothed everywhere"))


def skinned_mesh(context):
    """The active mesh when it has an Armature modifier (a model is converted in memory when it has none)."""
    obj = active_mesh(context)
    return obj if obj is not None and armature_modifiers(obj) else None


def poll_skinned(cls, context) -> bool:
    no_mesh = "Select a mesh with an Armature modifier"
    return refused(cls, no_mesh if skinned_mesh(context) is None else object_mode_problem(context))


class OnSkinnedMeshWithDialog(DialogJobOperator):
    """The LOD operators: on the active skinned mesh, options asked in a dialog when there is a window, the job on
    a worker thread with progress and Esc (on this thread headless)."""

    @classmethod
    def poll(cls, context):
        return poll_skinned(cls, context)


class SKINKIT_OT_limit_influences(OnSkinnedMeshWithDialog, bpy.types.Operator):
    """Reduce every vertex to at most K influences with the least animated error (thesis section 6.4); a new
    object '<name>_limited' gets the limited model, linear-blend vertex groups and an Armature modifier"""

    bl_idname = "skinkit.limit_influences"
    bl_label = "Limit Influences"
    bl_options = {"REGISTER", "UNDO"}

    max_influences: IntProperty(name="Max Influences", default=lod.DEFAULT_MAX_INFLUENCES, min=1, max=64,
                                description="The most bones any vertex keeps")
    sampled_metric: BoolProperty(name="Sampled Metric", default=False,
                                 description="Also measure the error on the armature action's frames themselves "
                                             "(their exact metric, blended with the pose statistics by validation "
                                             "on those frames); needs an action")

    def prepare(self, context):
        return lod.prepare_limit(skinned_mesh(context), self.max_influences, sampled_metric=self.sampled_metric)

    def write(self, context, mesh_object, solved):
        copy = self._job.write(mesh_object, solved)
        report = solved["report"]
        message = (f"'{copy.name}': at most {report['max_influences']} influences per vertex "
                   f"({report['influences_before']['total']} -> {report['influences_after']['total']})")
        if "error" in report:
            error = report["error"]
            message += (f"; animated error {error['skinkit']['rms']:.2e} rms of the diagonal, Blender's Limit Total "
                        f"{error['limit_total']['rms']:.2e} over {report['frames']} frames")
        return [("INFO", message)]


class SKINKIT_OT_subdivide_model(OnSkinnedMeshWithDialog, bpy.types.Operator):
    """Subdivide the mesh and its animation-space model together: a new object '<name>_subdivided' that deforms
    exactly as Blender's Subdivision Surface (Limit Surface off) after the Armature modifier, in every pose"""

    bl_idname = "skinkit.subdivide_model"
    bl_label = "Subdivide Model"
    bl_options = {"REGISTER", "UNDO"}

    levels: IntProperty(name="Levels", default=1, min=1, max=MAX_LEVELS)
    scheme: EnumProperty(name="Scheme", default="CATMULL_CLARK", items=SCHEME_ITEMS)
    boundary: EnumProperty(name="Boundary", default="ALL", items=BOUNDARY_ITEMS)
    uv_smooth: EnumProperty(name="UV Smooth", default="PRESERVE_CORNERS", items=UV_ITEMS)

    def prepare(self, context):
        from .options import option

        return lod.prepare_subdivide(skinned_mesh(context), levels=self.levels, scheme=option(self.scheme),
                                     boundary=option(self.boundary), uv_smooth=option(self.uv_smooth))

    def write(self, context, mesh_object, solved):
        copy = self._job.write(mesh_object, solved)
        report = solved["report"]
        return [("INFO", f"'{copy.name}': {report['vertices']} vertices, {report['polygons']} faces, up to "
                         f"{report['influences_max']} influences per vertex")]


class SKINKIT_PT_level_of_detail(SidebarPanel, bpy.types.Panel):
    bl_label = "Level of Detail"

    def draw(self, context):
        layout = self.layout
        mesh_object = skinned_mesh(context)
        if mesh_object is None:
            layout.label(text="Select a mesh with an Armature modifier", icon="INFO")
            return
        summary = storage.model_summary(mesh_object.data)
        if summary is not None:
            layout.label(text=f"{summary['influences_mean']:.2f} influences per vertex, at most "
                              f"{summary['influences_max']}")
        else:
            layout.label(text="No model: its skinning is converted first", icon="INFO")
        layout.operator(SKINKIT_OT_limit_influences.bl_idname, text="Limit Influences...", icon="MOD_VERTEX_WEIGHT")
        layout.operator(SKINKIT_OT_subdivide_model.bl_idname, text="Subdivide Model...", icon="MOD_SUBSURF")


classes = (SKINKIT_OT_limit_influences, SKINKIT_OT_subdivide_model, SKINKIT_PT_level_of_detail)
