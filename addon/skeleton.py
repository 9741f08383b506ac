"""The Skeleton family (Vasilakis 2008): Extract Skeleton (an armature from a mesh segmented into parts), Rigid Skin
with Seams (a baked copy whose joints close as they turn), and the import and export of the thesis'
hierarchy-and-limits file, in the "Skeleton" panel.

Extraction takes well under a second on a 10k-vertex character (BENCHMARKS.md), so it runs in execute rather than
as a background job. Everything goes through skinkit.blender.skeleton; on any failure the scene is left as it was.
"""
import os

import bpy
import numpy as np
from bpy.app.handlers import persistent
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from skinkit.blender import skeleton as bridge
from skinkit.model import SkinkitError
from skinkit.skeleton import Hierarchy, read_hierarchy, write_hierarchy

from .common import SidebarPanel, object_mode_problem
from .operators import active_mesh, refused, reports_errors

PART_SOURCE_ITEMS = (("groups", "Vertex Groups", "Each vertex's strongest vertex group"),
                     ("materials", "Materials", "The faces' materials"),
                     ("loose", "Loose Parts", "Pieces that meet at coincident vertices"),
                     ("attribute", "Face Attribute", f"The integer face attribute '{bridge.PART_ATTRIBUTE}'"))
ARC_ITEMS = (("qlerp", "QLERP", "Arcs about the joint (section 4.4.2, S1)"),
             ("conic", "Conic", "The conic middle-point arcs where the joint bends (section 4.4.2, S2)"))
METHOD_ITEMS = (("principal-axis", "Principal Axis", "Link points on each part's principal axis (section 3.2.3)"),
                ("centroid", "Centroid", "Through each part's kernel centroid (section 3.2.2)"),
                ("opening", "Opening", "Between the openings only (section 3.2.1)"))


#: The live seamed objects' topology this session, by session_uid: (SeamMesh, parts, armature name), rebuilt when
#: missing (after loading a file) from the mesh the object names.
LIVE_SEAMS: dict[int, tuple] = {}


@persistent
def update_live_seams(scene, depsgraph):
    """The live deformer: every live seamed object follows its armature's pose (frame_change_post)."""
    for seamed in [o for o in scene.objects if bridge.LIVE_SOURCE in o]:
        try:
            entry = LIVE_SEAMS.get(seamed.session_uid)
            if entry is None:
                source = bpy.data.objects.get(seamed[bridge.LIVE_SOURCE])
                if source is None:
                    raise SkinkitError(f"its source '{seamed[bridge.LIVE_SOURCE]}' is gone")
                mesh, parts, armature = bridge.seamed_topology(source, int(seamed.get(bridge.LIVE_STEPS, 4)))
                if not seamed.get(bridge.LIVE_REMOVE_SINKING) and len(mesh.sources) != len(seamed.data.vertices):
                    raise SkinkitError("its source's parts changed; make it again")
                entry = LIVE_SEAMS[seamed.session_uid] = (mesh, parts, armature.name)
            mesh, parts, armature_name = entry
            bridge.pose_seamed(seamed, mesh, parts, bpy.data.objects[armature_name], depsgraph)
        except (SkinkitError, KeyError) as error:
            print(f"skinkit: live seams of '{seamed.name}' are off: {error}")
            del seamed[bridge.LIVE_SOURCE]


def active_armature(context):
    obj = context.active_object
    return obj if obj is not None and obj.type == "ARMATURE" else None


class SKINKIT_OT_extract_skeleton(bpy.types.Operator):
    """Build an armature from the active mesh's parts: one bone per part, Limit Rotation constraints, one rigid
    vertex group per part and an Armature modifier (Vasilakis 2008)"""

    bl_idname = "skinkit.extract_skeleton"
    bl_label = "Extract Skeleton"
    bl_options = {"REGISTER", "UNDO"}

    part_source: EnumProperty(name="Parts", items=PART_SOURCE_ITEMS, default="groups")
    method: EnumProperty(name="Method", items=METHOD_ITEMS, default="principal-axis")
    refine: BoolProperty(name="Refine", default=False, description="Local and parent refinement (Algorithms 3-4)")
    max_angle: FloatProperty(name="Max Angle", default=20.0, min=0.1, max=180.0,
                             description="The refinements' largest turn, in degrees (the thesis used 10-22)")
    hierarchy_path: StringProperty(name="Hierarchy", subtype="FILE_PATH", default="",
                                   description="Optional hierarchy-and-limits file naming the parts")

    @classmethod
    def poll(cls, context):
        no_mesh = "Select a mesh segmented into parts"
        return refused(cls, no_mesh if active_mesh(context) is None else object_mode_problem(context))

    @reports_errors
    def execute(self, context):
        mesh_object = active_mesh(context)
        hierarchy = read_hierarchy(bpy.path.abspath(self.hierarchy_path)) if self.hierarchy_path else None
        armature, skeleton, parts = bridge.extract_rig(mesh_object, self.part_source, self.method, self.refine,
                                                       self.max_angle, hierarchy=hierarchy)
        fallbacks = [parts.names[p] for p in np.flatnonzero(~skeleton.star_shaped)]
        self.report({"INFO"}, f"'{armature.name}': {parts.part_count} bones, {len(skeleton.positions)} joints in "
                              f"{skeleton.seconds:.3f} s" +
                    (f"; not star-shaped (hull centroid used): {', '.join(fallbacks)}" if fallbacks else ""))
        return {"FINISHED"}


def armature_hierarchy(armature_object) -> Hierarchy:
    """The armature's bones as a hierarchy, with limits from their Limit Rotation constraints (free without)."""
    bones = list(armature_object.data.bones)
    index = {bone.name: k for k, bone in enumerate(bones)}
    parents = np.array([index[b.parent.name] if b.parent else -1 for b in bones], dtype=np.int32)
    if (parents < 0).sum() != 1:
        raise SkinkitError(f"'{armature_object.name}' has {(parents < 0).sum()} root bones; the file holds one tree")
    limits = np.tile(np.array([[-180.0, 180.0]] * 3), (len(bones), 1, 1))
    for k, bone in enumerate(bones):
        constraint = next((c for c in armature_object.pose.bones[bone.name].constraints
                           if c.type == "LIMIT_ROTATION"), None)
        if constraint is not None:
            for axis, name in enumerate("xyz"):
                if getattr(constraint, f"use_limit_{name}"):
                    limits[k, axis] = np.degrees([getattr(constraint, f"min_{name}"), getattr(constraint, f"max_{name}")])
    order = np.argsort([_depth(parents, k) for k in range(len(bones))], kind="stable")
    return Hierarchy(tuple(bones[k].name for k in order), _reindex(parents, order), limits[order])


def _depth(parents, k):
    depth = 0
    while parents[k] >= 0:
        k, depth = parents[k], depth + 1
    return depth


def _reindex(parents, order):
    where = {int(old): new for new, old in enumerate(order)}
    return np.array([-1 if parents[old] < 0 else where[int(parents[old])] for old in order], dtype=np.int32)


class HierarchyFileOnArmature:
    """Export and Import Limits: a hierarchy-and-limits file, and the active armature (refused without one)."""

    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="File", subtype="FILE_PATH", default="//skeleton.hier")

    @classmethod
    def poll(cls, context):
        return refused(cls, None if active_armature(context) is not None else "Select an armature")


class SKINKIT_OT_export_hierarchy(HierarchyFileOnArmature, bpy.types.Operator):
    """Write the active armature's bones and rotation limits as a hierarchy-and-limits file (thesis section 3.1)"""

    bl_idname = "skinkit.export_hierarchy"
    bl_label = "Export Hierarchy"

    @reports_errors
    def execute(self, context):
        path = bpy.path.abspath(self.filepath)
        if not os.path.isdir(os.path.dirname(os.path.abspath(path))):
            raise SkinkitError(f"{path}: the folder does not exist")
        write_hierarchy(path, armature_hierarchy(active_armature(context)))
        self.report({"INFO"}, f"wrote {path}")
        return {"FINISHED"}


class SKINKIT_OT_import_hierarchy(HierarchyFileOnArmature, bpy.types.Operator):
    """Set the active armature's Limit Rotation constraints from a hierarchy-and-limits file whose segments name
    its bones"""

    bl_idname = "skinkit.import_hierarchy"
    bl_label = "Import Limits"

    @reports_errors
    def execute(self, context):
        armature = active_armature(context)
        hierarchy = read_hierarchy(bpy.path.abspath(self.filepath))
        missing = [n for n in hierarchy.names if n not in armature.pose.bones]
        if missing:
            raise SkinkitError(f"'{armature.name}' has no bones {', '.join(missing[:5])} named in the file")
        for name, limits in zip(hierarchy.names, np.radians(hierarchy.limits)):  # all checked before any change
            bone = armature.pose.bones[name]
            constraint = next((c for c in bone.constraints if c.type == "LIMIT_ROTATION"), None)
            constraint = constraint or bone.constraints.new("LIMIT_ROTATION")
            constraint.owner_space = "LOCAL"
            for axis, (low, high) in zip("xyz", limits):
                setattr(constraint, f"use_limit_{axis}", True)
                setattr(constraint, f"min_{axis}", float(low))
                setattr(constraint, f"max_{axis}", float(high))
        self.report({"INFO"}, f"limits of {len(hierarchy.names)} bones set")
        return {"FINISHED"}


class SKINKIT_OT_rigid_skin_seams(bpy.types.Operator):
    """Close the seams of the rigidly skinned mesh at every joint in a new object '<name>_seamed': baked, one shape
    key per frame, or live, following the armature every frame (the mesh needs one vertex group per bone, as
    Extract Skeleton makes). Remove Sinking runs Algorithm 5 in full: the points sinking into the next part go and
    the holes are filled, so the vertex count changes per frame and a bake is a collection of one object per frame"""

    bl_idname = "skinkit.rigid_skin_seams"
    bl_label = "Rigid Skin with Seams"
    bl_options = {"REGISTER", "UNDO"}

    frame_start: IntProperty(name="Start", default=1)
    frame_end: IntProperty(name="End", default=24)
    steps: IntProperty(name="Rings", default=4, min=1, max=32, description="Rings of arc points per seam")
    live: BoolProperty(name="Live", default=False,
                       description="A copy that follows the armature every frame instead of a baked one")
    remove_sinking: BoolProperty(name="Remove Sinking", default=False,
                                 description="Remove the points sinking into the neighbouring part and fill the holes "
                                             "every frame (the vertex count then changes per frame)")
    arcs: EnumProperty(name="Arcs", items=ARC_ITEMS, default="qlerp", description="The arcs closing each seam")

    @classmethod
    def poll(cls, context):
        obj = active_mesh(context)
        if obj is None or not any(m.type == "ARMATURE" for m in obj.modifiers):
            return refused(cls, "Select a mesh with an Armature modifier (Extract Skeleton makes one)")
        return refused(cls, object_mode_problem(context))

    @reports_errors
    def execute(self, context):
        if self.live:
            seamed, mesh, parts, armature = bridge.make_live_seamed(active_mesh(context), self.steps,
                                                                    self.remove_sinking, self.arcs)
            LIVE_SEAMS[seamed.session_uid] = (mesh, parts, armature.name)
            self.report({"INFO"}, f"'{seamed.name}' follows '{armature.name}' live; {mesh.constructed_points} seam "
                                  "points")
            return {"FINISHED"}
        if self.frame_end < self.frame_start:
            raise SkinkitError("the frame range is empty (End < Start)")
        baked, mesh, frames = bridge.bake_seamed(active_mesh(context), range(self.frame_start, self.frame_end + 1),
                                                 self.steps, self.remove_sinking, self.arcs)
        removed = sum(frame["removed_points"] for frame in frames)
        fallbacks = sum(frame["fallback"] for frame in frames)
        self.report({"INFO"}, f"'{baked.name}': {len(frames)} frames, {mesh.constructed_points} seam points"
                              + (f", {removed} sinking points removed, {fallbacks} frames kept whole"
                                 if self.remove_sinking else "") + ", watertight")
        return {"FINISHED"}


class SKINKIT_PT_skeleton(SidebarPanel, bpy.types.Panel):
    bl_label = "Skeleton"

    def draw(self, context):
        layout = self.layout
        layout.operator(SKINKIT_OT_extract_skeleton.bl_idname, icon="ARMATURE_DATA")
        row = layout.row(align=True)
        row.operator(SKINKIT_OT_rigid_skin_seams.bl_idname, icon="MOD_ARMATURE")
        row.operator(SKINKIT_OT_rigid_skin_seams.bl_idname, text="Remove Sinking").remove_sinking = True
        row = layout.row(align=True)
        row.operator(SKINKIT_OT_import_hierarchy.bl_idname, icon="IMPORT")
        row.operator(SKINKIT_OT_export_hierarchy.bl_idname, icon="EXPORT")


classes = (SKINKIT_OT_extract_skeleton, SKINKIT_OT_rigid_skin_seams, SKINKIT_OT_export_hierarchy,
           SKINKIT_OT_import_hierarchy, SKINKIT_PT_skeleton)
