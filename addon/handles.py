# SPDX-License-Identifier: GPL-3.0-or-later
"""Handle rigs (Feng 2010, chapter 2): Learn Handle Rig, the live deformer's toggle, Bake to Shape Keys and their
panel. The work is skinkit.blender.handles'; this module maps Blender's enums to its strings (their lower case)."""
import bpy
from bpy.app.handlers import persistent
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from skinkit.blender import handles as bridge
from skinkit.handles.train import DEFAULT_BONES, bone_count_list

from .common import SidebarPanel, not_reentrant, object_mode_problem
from .operators import BackgroundJobOperator, active_mesh, refused, reports_errors

SOURCE_ITEMS = (("SHAPE_KEYS", "Shape Keys", "The mesh's shape keys (the Basis and every other key)"),
                ("MODIFIERS", "Mesh Cache", "The frames its Mesh Sequence Cache or Mesh Cache gives over the scene "
                                            "range"),
                ("SELECTED", "Selected Meshes", "The active mesh and the other selected meshes (same vertex order)"))
HANDLE_ITEMS = (("GROUP", "Vertex Group", "The vertices of the vertex group 'handles'"),
                ("AUTOMATIC", "Automatic", "Suggested: PCA of the examples, varimax, two extreme vertices each"))
KERNEL_ITEMS = (("GAUSSIAN", "Gaussian", "Gaussian kernel, sigma from the handles' spread (section 2.7)"),
                ("POLYNOMIAL", "Polynomial", "(x.y + c)^5, c from the handles' norm (the thesis' face)"),
                ("LINEAR", "Linear", "Linear CCA"))
CLUSTERING_ITEMS = (("RIGID", "Rigid", "The decomposition's clustering: trajectory k-means, merged by rigid error, "
                                       "rigid k-means"),
                    ("HIERARCHICAL", "Hierarchical", "Triangles merged bottom-up by the rigid-fit error they add "
                                                     "(section 2.3), cut at the bone count, then rigid k-means"))


def poll_mesh(cls, context) -> bool:
    no_mesh = "Select a mesh with example poses (shape keys, a mesh cache, or selected meshes)"
    return refused(cls, no_mesh if active_mesh(context) is None else object_mode_problem(context))


def poll_rig(cls, context) -> bool:
    if not poll_mesh(cls, context):
        return False
    if not bridge.has_rig(active_mesh(context)):
        cls.poll_message_set("The active mesh has no handle rig: run Learn Handle Rig first")
        return False
    return True


class SKINKIT_OT_learn_handle_rig(BackgroundJobOperator, bpy.types.Operator):
    """Learn a handle rig from the mesh's example poses: proxy bones, kernel CCA from the control points, dual-
    quaternion skinning; one Empty per control point in '<name>_handles' then deforms the mesh live"""

    bl_idname = "skinkit.learn_handle_rig"
    bl_label = "Learn Handle Rig"
    bl_options = {"REGISTER", "UNDO"}

    source: EnumProperty(name="Examples", items=SOURCE_ITEMS, default="SHAPE_KEYS")
    handles: EnumProperty(name="Control Points", items=HANDLE_ITEMS, default="GROUP")
    handle_count: IntProperty(name="Count", default=8, min=1, max=64, description="Automatic control points")
    bones: IntProperty(name="Proxy Bones", default=DEFAULT_BONES, min=1, max=256)
    bone_counts: StringProperty(name="Bone Counts", default="",
                                description="Proxy-bone counts to try, e.g. '16,32,48': the one with the least "
                                            "validation error on the examples is kept (empty: Proxy Bones)")
    clustering: EnumProperty(name="Clustering", items=CLUSTERING_ITEMS, default="RIGID")
    kernel: EnumProperty(name="Kernel", items=KERNEL_ITEMS, default="GAUSSIAN")
    poisson: BoolProperty(name="Poisson Translations", default=False,
                          description="Replace the predicted bone translations by the Poisson solve (eq. 2.11)")
    dqs_weights: BoolProperty(name="DQS Weights", default=True,
                              description="Refit the proxy bones' weights for dual-quaternion skinning")
    validate: BoolProperty(name="Validate", default=False,
                           description="Choose the kernel parameter and the ridge by validation on the examples")

    @classmethod
    def poll(cls, context):
        return poll_mesh(cls, context)

    def prepare(self, context):
        return bridge.prepare_learn(active_mesh(context), self.source.lower(), selected=context.selected_objects,
                                    handle_count=self.handle_count if self.handles == "AUTOMATIC" else None,
                                    bones=self.bones, bone_counts=bone_count_list(self.bone_counts),
                                    clustering=self.clustering.lower(), kernel=self.kernel.lower(),
                                    poisson=self.poisson,
                                    dqs_weights=self.dqs_weights, validate=self.validate)

    def write(self, context, mesh_object, solved):
        report = self._job.write(mesh_object, solved)
        return [("INFO", f"'{mesh_object.name}': {len(report['empties'])} handles in '{report['collection']}', "
                         f"{report['bones']} proxy bones; training error {report['training_rms']:.2e} of the "
                         "largest bounding-box side")]


class SKINKIT_OT_toggle_handle_rig(bpy.types.Operator):
    """Switch the handle rig's live deformation of the active mesh on or off"""

    bl_idname = "skinkit.toggle_handle_rig"
    bl_label = "Live Handle Deformation"
    bl_options = {"REGISTER", "UNDO"}

    enable: BoolProperty(name="On", default=True)

    @classmethod
    def poll(cls, context):
        return poll_rig(cls, context)

    @reports_errors
    def execute(self, context):
        mesh_object = active_mesh(context)
        (bridge.enable_live if self.enable else bridge.disable_live)(mesh_object)
        return {"FINISHED"}


BAKE_ITEMS = (("SHAPE_KEYS", "Shape Keys", "One shape key per frame, keyed to show on its frame"),
              ("MESH_CACHE", "Mesh Cache", "A PC2 point cache file (Blender's Mesh Cache modifier plays it)"))


class SKINKIT_OT_bake_handle_rig(bpy.types.Operator):
    """Bake the handle rig's deformation over a frame range to shape keys (one per frame, keyed to show on it) or
    to a PC2 mesh cache"""

    bl_idname = "skinkit.bake_handle_rig"
    bl_label = "Bake Handle Rig"
    bl_options = {"REGISTER", "UNDO"}

    frame_start: IntProperty(name="Start", default=1)
    frame_end: IntProperty(name="End", default=250)
    target: EnumProperty(name="To", items=BAKE_ITEMS, default="SHAPE_KEYS")
    filepath: StringProperty(name="PC2 File", subtype="FILE_PATH", description="The mesh cache to write")

    @classmethod
    def poll(cls, context):
        return poll_rig(cls, context)

    def invoke(self, context, event):
        self.frame_start, self.frame_end = context.scene.frame_start, context.scene.frame_end
        return self.execute(context)

    @reports_errors
    def execute(self, context):
        if self.frame_end < self.frame_start:
            self.report({"ERROR"}, f"frame range {self.frame_start}-{self.frame_end} is empty")
            return {"CANCELLED"}
        frames = range(self.frame_start, self.frame_end + 1)
        if self.target == "MESH_CACHE":
            if not self.filepath:
                self.report({"ERROR"}, "give the PC2 file to write")
                return {"CANCELLED"}
            path = bridge.bake_mesh_cache(active_mesh(context), frames, bpy.path.abspath(self.filepath))
            self.report({"INFO"}, f"baked {len(frames)} frames to '{path}'")
        else:
            names = bridge.bake_shape_keys(active_mesh(context), frames)
            self.report({"INFO"}, f"baked {len(names)} shape keys")
        return {"FINISHED"}


class SKINKIT_PT_handle_rig(SidebarPanel, bpy.types.Panel):
    bl_label = "Handle Rig"

    def draw(self, context):
        layout = self.layout
        mesh_object = active_mesh(context)
        if mesh_object is None:
            layout.label(text="Select a mesh with example poses", icon="INFO")
            return
        layout.operator(SKINKIT_OT_learn_handle_rig.bl_idname)
        if bridge.has_rig(mesh_object):
            live = bridge.is_live(mesh_object)
            toggle = layout.operator(SKINKIT_OT_toggle_handle_rig.bl_idname, text="Live: On" if live else "Live: Off",
                                     depress=live)
            toggle.enable = not live
            layout.operator(SKINKIT_OT_bake_handle_rig.bl_idname)


@not_reentrant  # a refresh writes a shape key, which must not trigger another refresh
def refresh_handle_rigs(scene) -> None:
    for message in bridge.refresh_all(scene):
        print(message)


@persistent
def on_frame_change(scene, depsgraph):
    refresh_handle_rigs(scene)


@persistent
def on_depsgraph_update(scene, depsgraph):
    if any(isinstance(update.id, bpy.types.Object) and update.id.type == "EMPTY" and update.is_updated_transform
           for update in depsgraph.updates):
        refresh_handle_rigs(scene)


classes = (SKINKIT_OT_learn_handle_rig, SKINKIT_OT_toggle_handle_rig, SKINKIT_OT_bake_handle_rig,
           SKINKIT_PT_handle_rig)
