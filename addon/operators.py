"""skinkit's operators: thin wrappers over skinkit.blender (the CLI calls the same functions).

Errors from skinkit arrive as SkinkitError with a message naming the object and the problem; the
operators report them and cancel (`reports_errors`, the one error path), and the bridge guarantees the
scene is unchanged in that case. Class names are SKINKIT_OT_<bl_idname after "skinkit.">.
Frame loops run as modal operators when there is a window (progress in the status bar, Esc cancels);
in background mode they run to completion in execute().
"""
import functools
import math
import threading
import time

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from skinkit.blender import attributes, compat, fitting, preview, skinning, storage, unwrap
from skinkit.blender.rollback import restored_on_failure
from skinkit.blender.rig import edit_mode_problem, rig_of
from skinkit.blender.scene import armature_of, transform_points
from skinkit.decompose import DEFAULT_BONES
from skinkit.fit import (DEFAULT_DELTA, DEFAULT_LAMBDA, DEFAULT_MAX_INFLUENCES, DEFAULT_RINGS, FIT_METHODS,
                         VALIDATION_MARGIN)
from skinkit.framelist import parse_frame_list
from skinkit.model import SkinkitError
from skinkit.pack import DEFAULT_MARGIN, DEFAULT_TEXTURE_SIZE

from . import state
from .options import (FIT_INFLUENCE_ITEMS, FIT_METHOD_ITEMS, FIT_SOURCE_ITEMS, SKIN_METHOD_ITEMS, SKIN_SOURCE_ITEMS,
                      STATISTICS_SOURCE_ITEMS, option)

#: Where Bake to Mesh Cache writes by default: beside the .blend.
DEFAULT_CACHE_PATH = "//skinkit_cache.pc2"

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
    """The mesh an operator acts on: the active object (the last clicked, selected or not), when it is a mesh."""
    obj = context.active_object
    return obj if obj is not None and obj.type == "MESH" else None


def active_mesh_with_model(context):
    obj = active_mesh(context)
    return obj if obj is not None and storage.has_model(obj.data) else None


def an(kind: str) -> str:
    return ("an " if kind[:1] in "aeiou" else "a ") + kind


def mesh_problem(context) -> str | None:
    """Why no mesh operator can run now (None when the active object is a mesh in a mode skinkit reads)."""
    obj = context.active_object
    if obj is None:
        return "no active object: click the mesh to work on (skinkit acts on the active object, selected or not)"
    if obj.type != "MESH":
        return f"the active object '{obj.name}' is {an(obj.type.lower())}, not a mesh"
    return edit_mode_problem(obj)


def refused(cls, problem: str | None) -> bool:
    """poll's answer: False with Blender's poll message set to the problem, when there is one."""
    if problem:
        cls.poll_message_set(problem)
        return False
    return True


def show_vertex_colours(context) -> None:
    """Solid shading of every 3D view colours meshes by their active colour attribute (a heat map)."""
    for area in (context.screen.areas if context.screen else []):
        for space in area.spaces:
            if space.type == "VIEW_3D":
                space.shading.color_type = "VERTEX"
        area.tag_redraw()


class OnActiveMesh:
    """An operator on the active mesh (the active object, selected or not; see active_mesh), refused through poll,
    saying why, when there is none, when it is in Edit Mode, or when `missing` names something else it needs.

    Options are operator properties, so scripts pass them as keywords (bpy.ops.skinkit.X(option=...)) and the redo
    panel shows them. An option not passed starts from the panel's last value for this scene (scene.skinkit, by
    `remembered`: operator property -> setting), whose defaults are the operators' own.
    """

    bl_options = {"REGISTER", "UNDO"}
    remembered: dict = {}

    @staticmethod
    def missing(mesh_object) -> str | None:
        return None

    @classmethod
    def poll(cls, context):
        problem = mesh_problem(context)
        return refused(cls, problem or cls.missing(context.active_object))

    def recall(self, context) -> None:
        """Options not passed take the panel's values for this scene."""
        settings = context.scene.skinkit
        for name, setting in self.remembered.items():
            if not self.properties.is_property_set(name):
                value = getattr(settings, setting)
                setattr(self, name, value.name if isinstance(value, bpy.types.ID) else ("" if value is None else value))


def needs_model(mesh_object) -> str | None:
    if not storage.has_model(mesh_object.data):
        return f"'{mesh_object.name}' has no animation-space model: run Convert to Animation Space (or a fit) first"
    return None


FRAME_RANGE_SETTINGS = {"use_scene_range": "use_scene_range", "frame_start": "frame_start", "frame_end": "frame_end"}


class FrameRange:
    """Operator properties: the frames to work over (the scene's range, or a start and end of their own)."""

    use_scene_range: BoolProperty(name="Scene Frame Range", default=True,
                                  description="Use the scene's frame range (else Start to End)")
    frame_start: IntProperty(name="Start", default=1)
    frame_end: IntProperty(name="End", default=250)

    def frames(self, context) -> range:
        scene = context.scene
        if self.use_scene_range:
            return range(scene.frame_start, scene.frame_end + 1)
        return range(self.frame_start, self.frame_end + 1)


class SKINKIT_OT_convert_to_animation_space(OnActiveMesh, bpy.types.Operator):
    """Convert the active object's linear blend skinning (Armature modifier and vertex groups) to an
    animation-space model stored on the mesh (the active object is used, selected or not)"""

    bl_idname = "skinkit.convert_to_animation_space"
    bl_label = "Convert to Animation Space"

    ignore_unmatched_groups: BoolProperty(
        name="Ignore Non-Bone Groups",
        description="Ignore vertex groups that name no bone instead of refusing the mesh",
        default=False,
    )

    @reports_errors
    def execute(self, context):
        mesh_object = active_mesh(context)
        with restored_on_failure(mesh_object):
            result = skinning.convert_object(mesh_object, self.ignore_unmatched_groups)
            if preview.is_enabled(mesh_object):
                preview.refresh(mesh_object, context.evaluated_depsgraph_get())
        for warning in result["warnings"]:
            self.report({"WARNING"}, warning)
        self.report({"INFO"}, f"'{mesh_object.name}': {result['vertices']} vertices, {result['bones']} bones, "
                              f"{result['influences_mean']:.2f} influences per vertex on average")
        return {"FINISHED"}


class OnMeshWithModel(OnActiveMesh):
    """For operators that act on the active mesh's stored model: available only when there is one."""

    missing = staticmethod(needs_model)


class SKINKIT_OT_toggle_preview(OnMeshWithModel, bpy.types.Operator):
    """Deform the active mesh with its animation-space model instead of the Armature modifier, live (a model
    that no longer matches the mesh or rig is refused, and switches the preview off)"""

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


class FrameLoopOperator(FrameRange, OnMeshWithModel):
    """Runs a per-frame generator: modal with progress and Esc to cancel, or all at once in background.

    Subclasses define start(context) -> generator over the frames, and finish(context, results).
    """

    remembered = FRAME_RANGE_SETTINGS

    @reports_errors
    def execute(self, context):
        self.recall(context)
        return self.finish_or_restore(context, list(self.start(context)))

    @reports_errors
    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        self.recall(context)
        self._steps = self.start(context)
        self._results = []
        self._timer = context.window_manager.event_timer_add(0.001, window=context.window)
        context.window_manager.progress_begin(0, len(self.frame_list))
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
            return self.finish_or_restore(context, self._results)
        except SkinkitError:
            self.stop(context)
            raise
        return {"RUNNING_MODAL"}

    def finish_or_restore(self, context, results):
        """finish(context, results), with what it changed put back if it fails half-way."""
        with restored_on_failure(active_mesh(context)):
            return self.finish(context, results)

    def stop(self, context):
        self._steps.close()  # restores the frame and anything the generator changed
        context.window_manager.event_timer_remove(self._timer)
        context.window_manager.progress_end()

    def start_frames(self, context) -> list:
        self.frame_list = list(self.frames(context))
        if not self.frame_list:
            raise SkinkitError("the frame range is empty")
        return self.frame_list


class SKINKIT_OT_compare_with_armature(FrameLoopOperator, bpy.types.Operator):
    """Evaluate the active mesh's model over the frame range beside Blender's Armature modifier and report the
    largest deviation, relative to the bounding-box diagonal (changes nothing, so it has no undo step)"""

    bl_idname = "skinkit.compare_with_armature"
    bl_label = "Compare with Armature"
    bl_options = {"REGISTER"}

    def start(self, context):
        return skinning.frame_deviations(active_mesh(context), self.start_frames(context))

    def finish(self, context, results):
        mesh_object = active_mesh(context)
        report = skinning.deviation_report(mesh_object, len(self.frame_list), results)
        state.LAST_COMPARISON[state.key(mesh_object)] = report
        for warning in report["warnings"]:
            self.report({"WARNING"}, warning)
        self.report({"INFO"}, f"'{mesh_object.name}': max deviation {report['max_deviation']:.3g} of the "
                              f"diagonal over {report['frames']} frames")
        return {"FINISHED"}


class SKINKIT_OT_bake_shape_keys(FrameLoopOperator, bpy.types.Operator):
    """Bake the active mesh's model over the frame range into a new object with one shape key per frame"""

    bl_idname = "skinkit.bake_shape_keys"
    bl_label = "Bake to Shape Keys"

    def start(self, context):
        return skinning.frame_positions(active_mesh(context), self.start_frames(context))

    def finish(self, context, results):
        baked = skinning.bake_shape_keys(active_mesh(context), self.frame_list, np.stack(results))
        self.report({"INFO"}, f"baked {len(self.frame_list)} frames into '{baked.name}'")
        return {"FINISHED"}


class SKINKIT_OT_bake_mesh_cache(FrameLoopOperator, bpy.types.Operator):
    """Bake the active mesh's model over the frame range into a PC2 mesh cache file"""

    bl_idname = "skinkit.bake_mesh_cache"
    bl_label = "Bake to Mesh Cache"

    filepath: StringProperty(name="Cache File", subtype="FILE_PATH", default=DEFAULT_CACHE_PATH,
                             options=compat.PATH_PROPERTY_OPTIONS,
                             description="The PC2 file to write ('//' starts a path relative to the .blend)")
    add_object: BoolProperty(name="Add Cache Object", default=True,
                             description="Also add a copy of the mesh that plays the cache")
    remembered = {**FRAME_RANGE_SETTINGS, "filepath": "cache_path", "add_object": "add_cache_object"}

    def start(self, context):
        path = bpy.path.abspath(self.filepath)
        if not path.lower().endswith(".pc2"):
            raise SkinkitError(f"cache path '{path}' must end in .pc2")
        return skinning.frame_positions(active_mesh(context), self.start_frames(context))

    def finish(self, context, results):
        path = bpy.path.abspath(self.filepath)
        try:
            added = skinning.bake_mesh_cache(active_mesh(context), path, self.frame_list, np.stack(results),
                                             self.add_object)
        except OSError as error:
            self.report({"ERROR"}, f"could not write '{path}': {error.strerror}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"wrote {len(self.frame_list)} frames to {path}"
                              + (f", played by '{added.name}'" if added else ""))
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
        with restored_on_failure(mesh_object):  # a write failing half-way leaves the object as it was
            messages = list(self.write(context, mesh_object, solved))
        for level, message in messages:
            self.report({level}, message)
        return {"FINISHED"}


class DialogJobOperator(BackgroundJobOperator):
    """A background job whose options are asked in a dialog first when there is a window, then solved on a worker
    thread (progress, Esc); in background mode and for scripts without a window it all runs in execute().
    `seconds_taken()` times the run from execute, for the write's report."""

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context):
        self._started = time.perf_counter()
        if bpy.app.background or context.window is None:
            return super().execute(context)
        return self.prepare_and_start(context)

    def seconds_taken(self) -> float:
        return time.perf_counter() - getattr(self, "_started", 0.0)


def fallback_message(name: str) -> str:
    return (f"'{name}': animation space did not predict the training frames {VALIDATION_MARGIN:.0%} better than "
            "linear blend skinning in validation, so the linear-blend fit is kept")


def fit_messages(name: str, report: dict) -> list[tuple[str, str]]:
    """What Fit from Example Poses reports: the warnings, the fall-back to the linear-blend fit, the errors."""
    train = report["animation_space"]["train"]
    messages = [("WARNING", warning) for warning in report.get("warnings", [])]
    if report.get("fallback"):
        messages.append(("INFO", fallback_message(name)))
    return messages + [("INFO", f"'{name}': fitted {report['examples']} examples, animation space "
                                f"{train['mean']:.2e} mean / {train['max']:.2e} max of the diagonal "
                                f"(linear blend {report['linear_blend']['train']['mean']:.2e})")]


class SKINKIT_OT_fit_from_examples(BackgroundJobOperator, FrameRange, OnActiveMesh, bpy.types.Operator):
    """Fit animation space and linear blend skinning to example poses of the active rigged mesh; writes the
    model, the fitted weights as vertex groups, an error heat map and a report (with the rig's own weights' error
    beside both, and a warning when a fitted model is worse than them on held-out frames)"""

    bl_idname = "skinkit.fit_from_examples"
    bl_label = "Fit from Example Poses"

    source: EnumProperty(name="Examples", default="SHAPE_KEYS", items=FIT_SOURCE_ITEMS)
    sequence: StringProperty(name="Sequence", default="",
                             description="The object whose cache modifier plays the example sequence (Mesh Sequence)")
    method: EnumProperty(name="Method", default="PER_VERTEX", items=FIT_METHOD_ITEMS)
    regularisation_lambda: FloatProperty(
        name="Regularisation λ", default=DEFAULT_LAMBDA, min=0.0, precision=6,
        description="λ of the per-vertex fit, in the unit box (pulls towards the linear-blend fit)")
    regularisation_delta: FloatProperty(
        name="Regularisation δ", default=DEFAULT_DELTA, min=0.0, precision=6,
        description="δ of the global fit, in the unit box (neighbours pulled towards each other)")
    validate: BoolProperty(
        name="Choose λ by Validation", default=True,
        description="Choose the per-vertex λ (the global fit's start) around the given one by held-out validation "
                    "on the training frames, so the fit does not lose to linear blend skinning")
    reproduce_rest: BoolProperty(name="Keep Rest Pose", default=True,
                                 description="Make the fitted model reproduce the rig's rest pose exactly")
    influences: EnumProperty(name="Influences", default="RIG", items=FIT_INFLUENCE_ITEMS)
    rings: IntProperty(name="Rings", default=DEFAULT_RINGS, min=0, max=8)
    max_influences: IntProperty(name="Max Influences", default=DEFAULT_MAX_INFLUENCES, min=1, max=16)
    held_out: StringProperty(name="Held Out", default="",
                             description="Frames kept out of training and reported separately, e.g. '5, 20-24'")
    remembered = {**FRAME_RANGE_SETTINGS, "source": "fit_source", "sequence": "fit_sequence",
                  "method": "fit_method", "regularisation_lambda": "fit_lambda", "regularisation_delta": "fit_delta",
                  "influences": "fit_influences", "rings": "fit_rings", "max_influences": "fit_max_influences",
                  "held_out": "fit_held_out"}

    def examples(self, context, mesh_object):
        armature = rig_of(mesh_object).armature_object
        if self.source == "SHAPE_KEYS":
            return fitting.examples_from_shape_keys(mesh_object, armature)
        if self.source == "OBJECTS":
            others = [o for o in context.selected_objects if o != mesh_object and o.type == "MESH"]
            return fitting.examples_from_objects(mesh_object, armature, others)
        sequence = bpy.data.objects.get(self.sequence) if self.sequence else None
        if sequence is None:
            raise SkinkitError("choose the object that plays the example sequence"
                               + (f" (there is no object '{self.sequence}')" if self.sequence else ""))
        return fitting.examples_from_sequence(mesh_object, sequence, self.frames(context))

    def prepare(self, context):
        self.recall(context)
        mesh_object = active_mesh(context)
        method = option(self.method)
        return fitting.prepare_fit(
            mesh_object, self.examples(context, mesh_object), method=method,
            regularisation=self.regularisation_lambda if method == FIT_METHODS[0] else self.regularisation_delta,
            source=option(self.influences), rings=self.rings, max_influences=self.max_influences,
            held_out_frames=parse_frame_list(self.held_out), validate=self.validate,
            reproduce_rest=self.reproduce_rest)

    def write(self, context, mesh_object, solved):
        self._job.write(mesh_object, solved)
        return fit_messages(mesh_object.name, solved["report"])


class SKINKIT_OT_skin_from_sequence(BackgroundJobOperator, FrameRange, OnActiveMesh, bpy.types.Operator):
    """Skin a mesh sequence that has no rig (the active mesh's shape keys, its Mesh Sequence Cache, or the selected
    meshes: by default what it has): a new armature with an action on every frame, and a skinned copy of the mesh
    with weights, the animation-space model, an error heat map and a report. The source objects are not changed"""

    bl_idname = "skinkit.skin_from_sequence"
    bl_label = "Skin from Mesh Sequence"

    source: EnumProperty(name="Frames", default="AUTO", items=SKIN_SOURCE_ITEMS)
    method: EnumProperty(name="Method", default="AUTOMATIC", items=SKIN_METHOD_ITEMS)
    bones: IntProperty(name="Bones", default=DEFAULT_BONES, min=1, max=1000)
    max_influences: IntProperty(name="Max Influences", default=DEFAULT_MAX_INFLUENCES, min=1, max=16)
    train: StringProperty(name="Training Frames", default="",
                          description="Frames to fit, e.g. '1-10, 20' (empty: all); the others are replayed with the "
                                      "fitted model and reported as held out")
    rough_rig: StringProperty(name="Rough Rig", default="", description="The drawn armature for Fit Rough Rig")
    remembered = {**FRAME_RANGE_SETTINGS, "source": "skin_source", "method": "skin_method", "bones": "skin_bones",
                  "max_influences": "skin_max_influences", "train": "skin_train", "rough_rig": "skin_rough_rig"}

    def prepare(self, context):
        from skinkit.blender import decompose

        self.recall(context)
        mesh_object = active_mesh(context)
        sequence = decompose.frames_from(mesh_object, option(self.source), self.frames(context),
                                         context.selected_objects)
        rough_rig = None
        if self.method == "ROUGH_RIG":
            rough_rig = bpy.data.objects.get(self.rough_rig) if self.rough_rig else None
            if rough_rig is None:
                raise SkinkitError("Fit Rough Rig needs the drawn armature"
                                   + (f" (there is no object '{self.rough_rig}')" if self.rough_rig else ""))
        return decompose.prepare(mesh_object, sequence, method=option(self.method), bones=self.bones,
                                 max_influences=self.max_influences, train_frames=parse_frame_list(self.train),
                                 armature_object=rough_rig)

    def write(self, context, mesh_object, solved):
        from skinkit.blender import decompose

        armature_object, skinned = decompose.write(mesh_object, self._job, solved)
        report = solved["report"]
        train = report["animation_space"]["train"]
        return [("INFO", f"'{skinned.name}' on '{armature_object.name}': {report['bones']} bones, animation space "
                         f"{train['rms']:.2e} rms / {train['max']:.2e} max of the diagonal (linear blend "
                         f"{report['linear_blend']['train']['rms']:.2e} rms)")]


class SKINKIT_OT_show_fit_error(OnActiveMesh, bpy.types.Operator):
    """Show the last fit's per-vertex error of the active mesh as colours in the 3D views (blue: none, red: the
    largest)"""

    bl_idname = "skinkit.show_fit_error"
    bl_label = "Show Error Heat Map"

    @staticmethod
    def missing(mesh_object):
        if attributes.HEAT_ATTRIBUTE not in mesh_object.data.color_attributes:
            return f"'{mesh_object.name}' has no fit error to show: run Fit from Example Poses first"
        return None

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


class SKINKIT_OT_compute_pose_statistics(FrameRange, OnActiveMesh, bpy.types.Operator):
    """Compute the pose statistics of the active armature, or of the one deforming the active mesh (from its
    animation, its Limit Rotation constraints, or uniform rotations) and store them on it, for the animation-space
    metrics"""

    bl_idname = "skinkit.compute_pose_statistics"
    bl_label = "Compute Pose Statistics"

    source: EnumProperty(name="From", default="ACTION", items=STATISTICS_SOURCE_ITEMS)
    step: IntProperty(name="Step", default=1, min=1, description="Use every Step-th frame (From Action)")
    poses: StringProperty(name="Poses", default="",
                          description="Frames of example poses (From Example Poses), e.g. '1, 12, 30-34'")
    spread: FloatProperty(name="Spread", default=0.0, min=0.0, max=math.pi, subtype="ANGLE",
                          description="Also turn each sampled joint rotation by this angle either way about the joint's "
                                      "axes, so a few example poses also price the poses around them (From Action or "
                                      "Example Poses)")
    remembered = {**FRAME_RANGE_SETTINGS, "step": "stats_step", "poses": "stats_poses", "spread": "stats_spread"}

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        if obj is None:
            return refused(cls, "no active object: click an armature, or a mesh it deforms")
        armature = active_armature(context)
        if armature is None:
            return refused(cls, f"the active object '{obj.name}' is no armature and no armature deforms it")
        return refused(cls, edit_mode_problem(armature))

    @reports_errors
    def execute(self, context):
        from skinkit.blender import pose_statistics

        self.recall(context)
        armature = active_armature(context)
        source, frames = option(self.source), []
        if source == "action":
            frames = list(self.frames(context))[::max(self.step, 1)]
            description = f"action frames {frames[0]}-{frames[-1]} step {self.step}" if frames else ""
        elif source == "poses":
            frames = parse_frame_list(self.poses)
            description = f"{len(frames)} example poses"
        else:
            description = {"limits": "rotation limits", "uniform": "uniform rotations"}[source]
        spread = self.spread if source in ("action", "poses") else 0.0
        if spread:
            description += f", spread {math.degrees(spread):.3g} degrees"
        computed = pose_statistics.compute(armature, source, frames, spread)
        pose_statistics.store(armature, computed, description, len(frames))
        self.report({"INFO"}, f"'{armature.name}': pose statistics of {computed.bone_count - 1} bones from "
                              f"{description}")
        return {"FINISHED"}


class SKINKIT_OT_show_max_distance(OnMeshWithModel, bpy.types.Operator):
    """Colour each vertex of the active mesh by how far it can move from the culling centre in any pose (its
    max-distance bound), and draw the culling sphere"""

    bl_idname = "skinkit.show_max_distance"
    bl_label = "Show Max-Distance Bounds"

    @reports_errors
    def execute(self, context):
        from skinkit.blender import pose_statistics

        mesh_object = active_mesh(context)
        with restored_on_failure(mesh_object):
            bounds = pose_statistics.write_bound_heat_map(mesh_object)
        world = np.array(mesh_object.matrix_world)
        scale = float(np.cbrt(abs(np.linalg.det(world[:3, :3]))))
        state.CULLING_SPHERES[state.key(mesh_object)] = (transform_points(world, bounds["centre"]),
                                                          bounds["radius"] * scale)
        show_vertex_colours(context)
        self.report({"INFO"}, f"'{mesh_object.name}': culling sphere radius {bounds['radius']:.4g}, largest vertex "
                              f"bound {bounds['per_vertex'].max():.4g}")
        return {"FINISHED"}


class SKINKIT_OT_animated_unwrap(DialogJobOperator, OnActiveMesh, bpy.types.Operator):
    """Unwrap the active mesh into a texture atlas with the least stretch over its animation, written as a
    new UV map (the active UV map is kept unless Make Active is on)"""

    bl_idname = "skinkit.animated_unwrap"
    bl_label = "Animated Unwrap"
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
        if report.get("fallback"):
            messages.append(("WARNING", f"'{mesh_object.name}': {report['fallback']}"))
        messages.append(("INFO", f"'{mesh_object.name}': {report['charts']} charts, L2 stretch "
                                 f"{report['stretch_rest']:.3f} at rest{over_frames}, texture efficiency "
                                 f"{report['texture_efficiency']:.3f} (UV map '{report['uv_map']}')"))
        return messages


class SKINKIT_OT_show_uv_layout(OnActiveMesh, bpy.types.Operator):
    """Draw the active mesh's Animated Unwrap layout into an image (shown in the Image Editor)"""

    bl_idname = "skinkit.show_uv_layout"
    bl_label = "Show UV Layout"

    size: IntProperty(name="Size", default=1024, min=64, max=8192)

    @staticmethod
    def missing(mesh_object):
        if unwrap.UV_MAP_NAME not in mesh_object.data.uv_layers:
            return f"'{mesh_object.name}' has no UV map '{unwrap.UV_MAP_NAME}': run Animated Unwrap first"
        return None

    @reports_errors
    def execute(self, context):
        image = unwrap.show_layout(active_mesh(context), self.size)
        self.report({"INFO"}, f"UV layout drawn in image '{image.name}'")
        return {"FINISHED"}


def remembered_settings() -> dict:
    """scene.skinkit's settings by name, each the very definition of the operator option it remembers (so a default
    is stated once: DEFAULT_LAMBDA, DEFAULT_RINGS, ... reach panel, redo panel and scripts alike)."""
    found = {}
    for cls in classes:
        definitions = {}
        for base in reversed(cls.__mro__):
            definitions.update(base.__dict__.get("__annotations__", {}))
        for name, setting in getattr(cls, "remembered", {}).items():
            found.setdefault(setting, definitions[name])
    return found


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
