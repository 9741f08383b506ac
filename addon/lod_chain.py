"""Build LOD Chain: the operator (over skinkit.blender.lod_chain) and its small panel under skinkit's sidebar."""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty

from skinkit.blender import lod_chain
from skinkit.blender.rig import armature_modifiers

from .common import SidebarPanel
from .operators import DialogJobOperator, active_mesh, refused
from .options import option


class SKINKIT_OT_build_lod_chain(DialogJobOperator, bpy.types.Operator):
    """Build discrete levels of detail of the active skinned mesh (progressive mesh in animation space) as new
    objects <name>_LOD0..n in a collection <name>_LOD, each played by an Armature modifier on the same armature"""

    bl_idname = "skinkit.build_lod_chain"
    bl_label = "Build LOD Chain"
    bl_options = {"REGISTER", "UNDO"}

    levels: IntProperty(name="Levels", default=4, min=2, max=16,
                        description="Levels including LOD0 (the input); each keeps at most half the influences of "
                                    "the one before")
    metric: EnumProperty(name="Metric", default="ANIMATION", items=(
        ("ANIMATION", "Animation Space", "Collapse costs over all poses (the pose statistics)"),
        ("REST", "Rest Pose", "Collapse costs in the rest pose (the thesis' baseline)")))
    simplify_influences: BoolProperty(name="Simplify Influences", default=True,
                                      description="Influence collapses share the queue with edge collapses")
    max_influences: IntProperty(name="Max Influences", default=lod_chain.DEFAULT_MAX_INFLUENCES, min=1, max=16,
                                description="Bones per vertex in the levels' vertex groups (the linear-blend "
                                            "weights Blender's Armature modifier plays)")
    collapse: EnumProperty(name="Collapse", default=lod_chain.DEFAULT_COLLAPSE.upper(), items=(
        ("HALF", "Half-Edge", "A vertex moves onto a neighbour, which keeps its coordinates (the thesis)"),
        ("FULL", "Full-Edge", "Interior edges also re-solve the survivor's coordinates to the least animated error"),
        ("AUTO", "Automatic", "Per candidate edge, the cheaper of the two")))
    influence_cost_scale: FloatProperty(name="Influence Cost Scale", default=lod_chain.DEFAULT_INFLUENCE_COST_SCALE,
                                        min=1e-3, max=1e3,
                                        description="Influence collapses are ranked at their cost times this against "
                                                    "edge collapses (1: as costed; above 1 keeps influences longer)")
    rank_per_influence: BoolProperty(name="Rank per Influence", default=True,
                                     description="Rank an edge collapse at its cost over the square root of the "
                                                 "influences it removes (off: by cost, as the thesis)")
    start_influences: IntProperty(name="Start Influences", default=0, min=0, max=16,
                                  description="First limit every vertex to this many influences (the engine's "
                                              "budget), LOD0 included; 0: start from the model as it is")
    refit: BoolProperty(name="Refit Levels", default=True,
                        description="Move each level's coordinates to the least animated distance from the full "
                                    "detail (its triangles and influences kept; animation metric only)")

    @classmethod
    def poll(cls, context):
        mesh_object = active_mesh(context)
        if mesh_object is None:
            return refused(cls, "The active object must be a mesh")
        return refused(cls, None if armature_modifiers(mesh_object) else
                       "The active mesh needs an Armature modifier (a rig)")

    def prepare(self, context):
        return lod_chain.prepare_lod_chain(active_mesh(context), levels=self.levels, metric=option(self.metric),
                                           simplify_influences=self.simplify_influences,
                                           max_influences=self.max_influences, collapse=option(self.collapse),
                                           influence_cost_scale=self.influence_cost_scale,
                                           rank_per_influence=self.rank_per_influence,
                                           start_influences=self.start_influences, refit=self.refit)

    def write(self, context, mesh_object, solved):
        report = self._job.write(mesh_object, solved, self.seconds_taken())
        messages = [("WARNING", f"'{mesh_object.name}': {warning}") for warning in report["warnings"]]
        sizes = ", ".join(f"{row['triangles']}" for row in report["levels"])
        messages.append(("INFO", f"'{report['collection']}': {len(report['levels'])} levels ({sizes} triangles), "
                                 f"coarsest error {report['levels'][-1]['error']:.2e} of the diagonal"))
        return messages


class SKINKIT_PT_lod_chain(SidebarPanel, bpy.types.Panel):
    bl_label = "LOD Chain"
    bl_parent_id = "SKINKIT_PT_level_of_detail"  # the family's panel (addon/lod.py), registered first

    def draw(self, context):
        layout = self.layout
        layout.operator(SKINKIT_OT_build_lod_chain.bl_idname, text="Build LOD Chain...", icon="MOD_DECIM")
        mesh_object = active_mesh(context)
        collection = bpy.data.collections.get(f"{mesh_object.name}_LOD") if mesh_object else None
        if collection is None:
            return
        column = layout.column(align=True)
        for level_object in sorted(collection.objects, key=lambda o: o.name):
            row = level_object.get(lod_chain.REPORT_PROPERTY)
            if row is not None:
                column.label(text=f"{level_object.name}: {row['triangles']} tris, {row['influences']} infl., "
                                  f"error {row['error']:.1e}")


classes = (SKINKIT_OT_build_lod_chain, SKINKIT_PT_lod_chain)
