"""skinkit's operators: thin wrappers over skinkit.blender (the CLI calls the same functions).

Errors from skinkit arrive as SkinkitError with a message naming the object and the problem; the
operators report them and cancel (`reports_errors`, the one error path), and the bridge guarantees the
scene is unchanged in that case. Class names are SKINKIT_OT_<bl_idname after "skinkit.">.
Frame loops run as modal operators when there is a window (progress in the status bar, Esc cancels);
in background mode they run to completion in execute().
"""
import functools
import threading
import time

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, IntProperty

from skinkit.blender import attributes, fitting, preview, skinning, storage, unwrap
from skinkit.blender.rig import rig_of
from skinkit.blender.scene import armature_of, transform_points
from skinkit.fit import FIT_METHODS
from skinkit.framelist import parse_frame_list
from skinkit.model import SkinkitError
from skinkit.pack import DEFAULT_MARGIN, DEFAULT_TEXTURE_SIZE

from . import state
from .options import option

#: How long a modal operator may work between two redraws.
STEP_SECONDS = 0.05


def reports_errors(method):
    """An operator method (execute, invoke, modal, ...) whose SkinkitError is reported as an error and cancels it."""
    def guarded(self, *arguments):
        try:
            return method(self, *arguments)
        except SkinkitError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}

    # Blender checks how many arguments an operator's callbacks take, so the wrapper takes as many as `method`.
    if method.__code__.co_argcount == 3:
        return functools.wraps(method)(lambda self, context, event: guarded(self, context, event))
    return functools.wraps(method)(lambda self, context: guarded(self, context))


def active_mesh(context):
    obj = context.active_object
    return obj if obj is not None and obj.type == "MESH" else None


def active_mesh_with_model(context):
    obj = active_mesh(context)
    return obj if obj is not None and storage.has_model(obj.data) else None


def show_vertex_colours(context) -> None:
    """Solid shading of every 3D view colours meshes by their active colour attribute (a heat map)."""
    for area in (context.screen.areas if context.screen else []):
        for space in area.spaces:
            if space.type == "VIEW_3D":
                space.shading.color_type = "VERTEX"
        area.tag_redraw()


def settings_frames(context) -> range:
    settings = context.scene.skinkit
    scene = context.scene
    if settings.use_scene_range:
        return range(scene.frame_start, scene.frame_end + 1)
    return range(settings.frame_start, settings.frame_end + 1)


class SKINKIT_OT_convert_to_animation_space(bpy.types.Operator):
    """Convert the active mesh's linear blend skinning (Armature modifier and vertex groups) to an
    animation-space model stored on the mesh"""

    bl_idname = "skinkit.convert_to_animation_space"
    bl_label = "Convert to Animation Space"
    bl_options = {"REGISTER", "UNDO"}

    ignore_unmatched_groups: BoolProperty(
        name="Ignore Non-Bone Groups",
        description="Ignore vertex groups that name no bone instead of refusing the mesh",
        default=False,
    )

    @classmethod
    def poll(cls, context):
        return active_mesh(context) is not None

    @reports_errors
    def execute(self, context):
        mesh_object = active_mesh(context)
        result = skinning.convert_object(mesh_object, self.ignore_unmatched_groups)
        if preview.is_enabled(mesh_object):
            preview.refresh(mesh_object, context.evaluated_depsgraph_get())
        for warning in result["warnings"]:
            self.report({"WARNING"}, warning)
        self.report({"INFO"}, f"'{mesh_object.name}': {result['vertices']} vertices, {result['bones']} bones, "
                              f"{result['influences_mean']:.2f} influences per vertex on average")
        return {"FINISHED"}


class OnMeshWithModel:
    """For operators that act on the active mesh's stored model: available only when there is one."""

    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return active_mesh_with_model(context) is not None


class SKINKIT_OT_toggle_preview(OnMeshWithModel, bpy.types.Operator):
    """Deform the mesh with its animation-space model instead of the Armature modifier, live"""

    bl_idname = "skinkit.toggle_preview"
    bl_label = "Live Preview"

    @reports_errors
    def execute(self, context):
        mesh_object = active_mesh(context)
        if preview.is_enabled(mesh_object):
            preview.disable(mesh_object)
        else:
            preview.enable(mesh_object, context.evaluated_depsgraph_get())
        return {"FINISHED"}


class SKINKIT_OT_remove_model(OnMeshWithModel, bpy.types.Operator):
    """Remove the animation-space model from the active mesh"""

    bl_idname = "skinkit.remove_model"
    bl_label = "Remove Model"

    def execute(self, context):
        mesh_object = active_mesh(context)
        preview.disable(mesh_object)
        storage.remove_model(mesh_object.data)
        mesh_object.data.update()
        return {"FINISHED"}


class FrameLoopOperator(OnMeshWithModel):
    """Runs a per-frame generator: modal with progress and Esc to cancel, or all at once in background.

    Subclasses define start(context) -> generator over the frames, and finish(context, results).
    """

    @reports_errors
    def execute(self, context):
        return self.finish(context, list(self.start(context)))

    @reports_errors
    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        self._steps = self.start(context)
        self._results = []
        self._timer = context.window_manager.event_timer_add(0.001, window=context.window)
        context.window_manager.progress_begin(0, len(self.frames))
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    @reports_errors
    def modal(self, context, event):
        if event.type == "ESC":
            self.stop(context)
            self.report({"WARNING"}, f"{self.bl_label}: cancelled, nothing was changed")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            deadline = time.perf_counter() + STEP_SECONDS
            while time.perf_counter() < deadline:
                self._results.append(next(self._steps))
                context.window_manager.progress_update(len(self._results))
        except StopIteration:
            self.stop(context)
            return self.finish(context, self._results)
        except SkinkitError:
            self.stop(context)
            raise
        return {"RUNNING_MODAL"}

    def stop(self, context):
        self._steps.close()  # restores the frame and anything the generator changed
        context.window_manager.event_timer_remove(self._timer)
        context.window_manager.progress_end()

    def start_frames(self, context) -> list:
        self.frames = list(settings_frames(context))
        if not self.frames:
            raise SkinkitError("the frame range is empty")
        return self.frames


class SKINKIT_OT_compare_with_armature(FrameLoopOperator, bpy.types.Operator):
    """Evaluate the model over the frame range beside Blender's Armature modifier and report the
    largest deviation, relative to the bounding-box diagonal"""

    bl_idname = "skinkit.compare_with_armature"
    bl_label = "Compare with Armature"

    def start(self, context):
        return skinning.frame_deviations(active_mesh(context), self.start_frames(context))

    def finish(self, context, results):
        mesh_object = active_mesh(context)
        report = skinning.deviation_report(mesh_object, len(self.frames), results)
        state.LAST_COMPARISON[state.key(mesh_object)] = report
        self.report({"INFO"}, f"'{mesh_object.name}': max deviation {report['max_deviation']:.3g} of the "
                              f"diagonal over {report['frames']} frames")
        return {"FINISHED"}


class SKINKIT_OT_bake_shape_keys(FrameLoopOperator, bpy.types.Operator):
    """Bake the model's animation over the frame range into a new object with one shape key per frame"""

    bl_idname = "skinkit.bake_shape_keys"
    bl_label = "Bake to Shape Keys"

    def start(self, context):
        return skinning.frame_positions(active_mesh(context), self.start_frames(context))

    def finish(self, context, results):
        baked = skinning.bake_shape_keys(active_mesh(context), self.frames, np.stack(results))
        self.report({"INFO"}, f"baked {len(self.frames)} frames into '{baked.name}'")
        return {"FINISHED"}


class SKINKIT_OT_bake_mesh_cache(FrameLoopOperator, bpy.types.Operator):
    """Bake the model's animation over the frame range into a PC2 mesh cache file"""

    bl_idname = "skinkit.bake_mesh_cache"
    bl_label = "Bake to Mesh Cache"

    def start(self, context):
        path = bpy.path.abspath(context.scene.skinkit.cache_path)
        if not path.lower().endswith(".pc2"):
            raise SkinkitError(f"cache path '{path}' must end in .pc2")
        return skinning.frame_positions(active_mesh(context), self.start_frames(context))

    def finish(self, context, results):
        path = bpy.path.abspath(context.scene.skinkit.cache_path)
        try:
            added = skinning.bake_mesh_cache(active_mesh(context), path, self.frames, np.stack(results),
                                               context.scene.skinkit.add_cache_object)
        except OSError as error:
            self.report({"ERROR"}, f"could not write '{path}': {error.strerror}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"wrote {len(self.frames)} frames to {path}" + (f", played by '{added.name}'" if added else ""))
        return {"FINISHED"}


class BackgroundJobOperator:
    """An operator whose work is prepare (read the scene) -> job.solve(progress) -> write (to the job's object,
    returning (level, message) reports). With a window the
    solve runs on a worker thread (the C solvers release the GIL) while Blender stays responsive, shows progress and
    stops on Esc without changing anything; in background mode and from scripts it all runs in execute()."""

    @reports_errors
    def execute(self, context):
        self._job = self.prepare(context)
        return self.finish(context, self._job.solve())

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        return self.prepare_and_start(context)

    @reports_errors
    def prepare_and_start(self, context):
        """Reads the scene, then solves on a worker thread; a window manager that refuses the modal handler gets
        the solve on this thread instead."""
        self._job = self.prepare(context)
        window_manager = context.window_manager
        if not window_manager.modal_handler_add(self):
            return self.finish(context, self._job.solve())
        self._state = {"fraction": 0.0, "cancel": False, "solved": None, "error": None}
        self._thread = threading.Thread(target=self.solve_in_background, daemon=True)
        self._thread.start()
        self._timer = window_manager.event_timer_add(0.1, window=context.window)
        window_manager.progress_begin(0, 100)
        context.workspace.status_text_set(f"{self.bl_label}: Esc to cancel")
        return {"RUNNING_MODAL"}

    def solve_in_background(self):
        state = self._state

        def report_progress(fraction):  # called by the solvers; True stops them
            state["fraction"] = fraction
            return state["cancel"]

        try:
            state["solved"] = self._job.solve(report_progress)
        except SkinkitError as error:
            state["error"] = str(error)

    def modal(self, context, event):
        if event.type == "ESC":
            self._state["cancel"] = True
        if event.type != "TIMER":
            return {"RUNNING_MODAL"} if event.type == "ESC" else {"PASS_THROUGH"}
        context.window_manager.progress_update(int(100 * self._state["fraction"]))
        if self._thread.is_alive():
            return {"RUNNING_MODAL"}
        context.window_manager.event_timer_remove(self._timer)
        context.window_manager.progress_end()
        context.workspace.status_text_set(None)
        if self._state["cancel"]:
            self.report({"WARNING"}, f"{self.bl_label}: cancelled, nothing was changed")
            return {"CANCELLED"}
        if self._state["error"]:
            self.report({"ERROR"}, self._state["error"])
            return {"CANCELLED"}
        return self.finish(context, self._state["solved"])

    @reports_errors
    def finish(self, context, solved):
        """Writes the solved job to the object it was read from, if it is still there, and reports what was done."""
        mesh_object = bpy.data.objects.get(self._job.mesh_object_name)
        if mesh_object is None:
            self.report({"ERROR"}, f"'{self._job.mesh_object_name}' is gone; nothing was written")
            return {"CANCELLED"}
        for level, message in self.write(context, mesh_object, solved):
            self.report({level}, message)
        return {"FINISHED"}


class SKINKIT_OT_fit_from_examples(BackgroundJobOperator, bpy.types.Operator):
    """Fit animation space and linear blend skinning to example poses of the active rigged mesh; writes the
    model, the fitted weights as vertex groups, an error heat map and a report"""

    bl_idname = "skinkit.fit_from_examples"
    bl_label = "Fit from Example Poses"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return active_mesh(context) is not None

    @staticmethod
    def examples(context, mesh_object, settings):
        armature = rig_of(mesh_object).armature_object
        if settings.fit_source == "SHAPE_KEYS":
            return fitting.examples_from_shape_keys(mesh_object, armature)
        if settings.fit_source == "OBJECTS":
            others = [o for o in context.selected_objects if o != mesh_object and o.type == "MESH"]
            return fitting.examples_from_objects(mesh_object, armature, others)
        if settings.fit_sequence is None:
            raise SkinkitError("choose the object that plays the example sequence")
        return fitting.examples_from_sequence(mesh_object, settings.fit_sequence, settings_frames(context))

    @staticmethod
    def prepare(context):
        mesh_object, settings = active_mesh(context), context.scene.skinkit
        method = option(settings.fit_method)
        return fitting.prepare_fit(
            mesh_object, SKINKIT_OT_fit_from_examples.examples(context, mesh_object, settings), method=method,
            regularisation=settings.fit_lambda if method == FIT_METHODS[0] else settings.fit_delta,
            source=option(settings.fit_influences), rings=settings.fit_rings,
            max_influences=settings.fit_max_influences, held_out_frames=parse_frame_list(settings.fit_held_out))

    def write(self, context, mesh_object, solved):
        self._job.write(mesh_object, solved)
        report = solved["report"]
        train = report["animation_space"]["train"]
        return [("INFO", f"'{mesh_object.name}': fitted {report['examples']} examples, animation space "
                         f"{train['mean']:.2e} mean / {train['max']:.2e} max of the diagonal "
                         f"(linear blend {report['linear_blend']['train']['mean']:.2e})")]


class SKINKIT_OT_skin_from_sequence(BackgroundJobOperator, bpy.types.Operator):
    """Skin a mesh sequence that has no rig (shape keys, a Mesh Sequence Cache, or selected meshes): a new armature
    with an action on every frame, and a skinned copy of the mesh with weights, the animation-space model, an error
    heat map and a report. The source objects are not changed"""

    bl_idname = "skinkit.skin_from_sequence"
    bl_label = "Skin from Mesh Sequence"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return active_mesh(context) is not None and context.mode == "OBJECT"

    @staticmethod
    def prepare(context):
        from skinkit.blender import decompose

        mesh_object, settings = active_mesh(context), context.scene.skinkit
        if settings.skin_source == "SHAPE_KEYS":
            sequence = decompose.frames_from_shape_keys(mesh_object)
        elif settings.skin_source == "OBJECTS":
            sequence = decompose.frames_from_objects(mesh_object, [o for o in context.selected_objects
                                                                   if o.type == "MESH"])
        else:
            sequence = decompose.frames_from_sequence(mesh_object, settings_frames(context))
        return decompose.prepare(mesh_object, sequence, method=option(settings.skin_method),
                                 bones=settings.skin_bones, max_influences=settings.skin_max_influences,
                                 train_frames=parse_frame_list(settings.skin_train),
                                 armature_object=settings.skin_rough_rig)

    def write(self, context, mesh_object, solved):
        from skinkit.blender import decompose

        armature_object, skinned = decompose.write(mesh_object, self._job, solved)
        report = solved["report"]
        train = report["animation_space"]["train"]
        return [("INFO", f"'{skinned.name}' on '{armature_object.name}': {report['bones']} bones, animation space "
                         f"{train['rms']:.2e} rms / {train['max']:.2e} max of the diagonal (linear blend "
                         f"{report['linear_blend']['train']['rms']:.2e} rms)")]


class SKINKIT_OT_show_fit_error(bpy.types.Operator):
    """Show the last fit's per-vertex error as colours in the 3D views (blue: none, red: the largest)"""

    bl_idname = "skinkit.show_fit_error"
    bl_label = "Show Error Heat Map"

    @classmethod
    def poll(cls, context):
        obj = active_mesh(context)
        return obj is not None and attributes.HEAT_ATTRIBUTE in obj.data.color_attributes

    def execute(self, context):
        mesh = active_mesh(context).data
        mesh.color_attributes.active_color = mesh.color_attributes[attributes.HEAT_ATTRIBUTE]
        show_vertex_colours(context)
        return {"FINISHED"}


def active_armature(context):
    """The active armature, or the armature deforming the active mesh."""
    obj = context.active_object
    if obj is not None and obj.type == "ARMATURE":
        return obj
    mesh_object = active_mesh(context)
    return armature_of(mesh_object) if mesh_object is not None else None


class SKINKIT_OT_compute_pose_statistics(bpy.types.Operator):
    """Compute the pose statistics of the armature (from its animation, its Limit Rotation constraints, or
    uniform rotations) and store them on it, for the animation-space metrics"""

    bl_idname = "skinkit.compute_pose_statistics"
    bl_label = "Compute Pose Statistics"
    bl_options = {"REGISTER", "UNDO"}

    source: bpy.props.EnumProperty(name="From", default="ACTION", items=(
        ("ACTION", "Action", "The armature's animation over the frame range, every Step frames"),
        ("POSES", "Example Poses", "The armature's poses at the listed frames (e.g. '1, 12, 30-34')"),
        ("LIMITS", "Rotation Limits", "Analytic: hinges from Limit Rotation constraints, other bones uniform"),
        ("UNIFORM", "Uniform Rotations", "Analytic: every joint rotates freely (the skeleton-only metric)")))

    @classmethod
    def poll(cls, context):
        return active_armature(context) is not None

    @reports_errors
    def execute(self, context):
        from skinkit.blender import pose_statistics

        armature = active_armature(context)
        settings = context.scene.skinkit
        source, frames = option(self.source), []
        if source == "action":
            frames = list(settings_frames(context))[::max(settings.stats_step, 1)]
            description = f"action frames {frames[0]}-{frames[-1]} step {settings.stats_step}" if frames else ""
        elif source == "poses":
            frames = parse_frame_list(settings.stats_poses)
            description = f"{len(frames)} example poses"
        else:
            description = {"limits": "rotation limits", "uniform": "uniform rotations"}[source]
        computed = pose_statistics.compute(armature, source, frames)
        pose_statistics.store(armature, computed, description, len(frames))
        self.report({"INFO"}, f"'{armature.name}': pose statistics of {computed.bone_count - 1} bones from "
                              f"{description}")
        return {"FINISHED"}


class SKINKIT_OT_show_max_distance(OnMeshWithModel, bpy.types.Operator):
    """Colour each vertex by how far it can move from the culling centre in any pose (its max-distance bound),
    and draw the culling sphere"""

    bl_idname = "skinkit.show_max_distance"
    bl_label = "Show Max-Distance Bounds"

    @reports_errors
    def execute(self, context):
        from skinkit.blender import pose_statistics

        mesh_object = active_mesh(context)
        bounds = pose_statistics.write_bound_heat_map(mesh_object)
        world = np.array(mesh_object.matrix_world)
        scale = float(np.cbrt(abs(np.linalg.det(world[:3, :3]))))
        state.CULLING_SPHERES[state.key(mesh_object)] = (transform_points(world, bounds["centre"]),
                                                          bounds["radius"] * scale)
        show_vertex_colours(context)
        self.report({"INFO"}, f"'{mesh_object.name}': culling sphere radius {bounds['radius']:.4g}, largest vertex "
                              f"bound {bounds['per_vertex'].max():.4g}")
        return {"FINISHED"}


class SKINKIT_OT_animated_unwrap(BackgroundJobOperator, bpy.types.Operator):
    """Unwrap the active mesh into a texture atlas with the least stretch over its animation, written as a
    new UV map (the active UV map is kept unless Make Active is on)"""

    bl_idname = "skinkit.animated_unwrap"
    bl_label = "Animated Unwrap"
    bl_options = {"REGISTER", "UNDO"}

    mode: EnumProperty(name="Segmentation", default="AUTO", items=(
        ("AUTO", "Automatic", "Merge charts greedily by flatness and compactness; seams stay chart boundaries"),
        ("SEAMS", "Seams Only", "The charts the marked seams cut out (an artist's own segmentation)")))
    chart_count: IntProperty(name="Charts", default=0, min=0,
                             description="Target chart count for automatic segmentation (0: its own stopping rule)")
    metric: EnumProperty(name="Metric", default="ANIMATION", items=(
        ("REST", "Rest Pose", "Flatten the mesh as it is"),
        ("ANIMATION", "Animation Space", "Least stretch over all poses: the skinkit model (or the rig's weights) "
                                         "with the armature's pose statistics"),
        ("FRAMES", "Frames of the Action", "Least stretch averaged over the frames of the armature's action")))
    straighten: BoolProperty(name="Straighten", default=False,
                             description="Straight chart boundaries between corners (for mip-mapping and LOD; raises "
                                         "stretch)")
    segment_in: EnumProperty(name="Segment In", default="REST", items=(
        ("REST", "Rest Pose", "Charts from the rest pose's shape (fast)"),
        ("METRIC", "Metric", "Charts from the metric's leading directions (boundaries follow the joints)")))
    texture_size: IntProperty(name="Texture Size", default=DEFAULT_TEXTURE_SIZE, min=16, max=16384)
    margin: IntProperty(name="Margin", default=DEFAULT_MARGIN, min=0, max=256, description="Texels between charts")
    make_active: BoolProperty(name="Make Active", default=False, description="Make the new UV map the active one")
    mark_seams: BoolProperty(name="Mark Seams", default=False, description="Mark the chart boundaries as seams")

    @classmethod
    def poll(cls, context):
        return active_mesh(context) is not None

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context):
        """After the options dialog: solved on a worker thread with a window (Esc discards the result without
        changing anything), on this thread in background mode and for scripts without a window."""
        if bpy.app.background or context.window is None:
            return super().execute(context)
        return self.prepare_and_start(context)

    def prepare(self, context):
        return unwrap.prepare_unwrap(
            active_mesh(context), metric=option(self.metric), mode=option(self.mode),
            chart_count=self.chart_count or None, straighten=self.straighten, segment_in=option(self.segment_in),
            texture_size=self.texture_size,
            margin=self.margin, make_active=self.make_active, mark_seams=self.mark_seams)

    def write(self, context, mesh_object, solved):
        report = self._job.write(mesh_object, solved)
        messages = []
        if report["split_polygons"]:
            messages.append(("WARNING", f"'{mesh_object.name}': {report['split_polygons']} faces span two charts; "
                                        "triangulate them for exact uvs"))
        over_frames = f", {report['stretch_frames']:.3f} over the action" if report["stretch_frames"] else ""
        messages.append(("INFO", f"'{mesh_object.name}': {report['charts']} charts, L2 stretch "
                                 f"{report['stretch_rest']:.3f} at rest{over_frames}, texture efficiency "
                                 f"{report['texture_efficiency']:.3f} (UV map '{report['uv_map']}')"))
        return messages


class SKINKIT_OT_show_uv_layout(bpy.types.Operator):
    """Draw the Animated Unwrap layout into an image (shown in the Image Editor)"""

    bl_idname = "skinkit.show_uv_layout"
    bl_label = "Show UV Layout"

    size: IntProperty(name="Size", default=1024, min=64, max=8192)

    @classmethod
    def poll(cls, context):
        obj = active_mesh(context)
        return obj is not None and unwrap.UV_MAP_NAME in obj.data.uv_layers

    @reports_errors
    def execute(self, context):
        image = unwrap.show_layout(active_mesh(context), self.size)
        self.report({"INFO"}, f"UV layout drawn in image '{image.name}'")
        return {"FINISHED"}


classes = (
    SKINKIT_OT_animated_unwrap,
    SKINKIT_OT_show_uv_layout,
    SKINKIT_OT_compute_pose_statistics,
    SKINKIT_OT_show_max_distance,
    SKINKIT_OT_fit_from_examples,
    SKINKIT_OT_skin_from_sequence,
    SKINKIT_OT_show_fit_error,
    SKINKIT_OT_convert_to_animation_space,
    SKINKIT_OT_toggle_preview,
    SKINKIT_OT_remove_model,
    SKINKIT_OT_compare_with_armature,
    SKINKIT_OT_bake_shape_keys,
    SKINKIT_OT_bake_mesh_cache,
)
