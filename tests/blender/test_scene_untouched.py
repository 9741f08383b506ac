"""The scene is untouched on every failure (issue 16): every skinkit operator run on inputs that make it fail, made
to fail half-way through writing its result, and cancelled midway leaves the whole scene's fingerprint
(tests/blender/fingerprint.py) exactly as it was; one undo restores it after each operator that changes it.

Cancelling midway is tested through what the modal operators run (a frame loop's generator closed after a few
frames, a background job's solve stopped by its progress callback): headless Blender has no window to send Esc."""
import bpy
import numpy as np
import pytest
from tests.blender.fingerprint import assert_unchanged, differences, scene_fingerprint
from tests.blender.test_decompose import mesh_with_shape_keys
from tests.blender.test_operators import prepared_arm
from tests.blender.test_skinning import select
from tests.sequences import rigid_chain_sequence

from skinkit import SkinkitError
from skinkit.blender import decompose, fitting, pose_statistics, skinning, unwrap
from skinkit.blender.rig import rig_of

RANGE = {"use_scene_range": False, "frame_start": 1, "frame_end": 3}
BACKWARDS = {"use_scene_range": False, "frame_start": 5, "frame_end": 2}


def failing(name: str, **keywords) -> None:
    """Runs bpy.ops.skinkit.<name> expecting it to fail (poll refusing, or an error reported and cancelled)."""
    try:
        result = getattr(bpy.ops.skinkit, name)("EXEC_DEFAULT", **keywords)
    except RuntimeError:  # Blender raises for an operator that reported an error or whose poll refused
        return
    assert result == {"CANCELLED"}, f"{name} {keywords} did not fail"


@pytest.fixture(scope="module")
def prepared_file(tmp_path_factory, addon):
    """The arm with a model, pose statistics, a fit's heat map and an atlas, saved once (preparing takes long)."""
    import addon as skinkit_addon  # noqa: F401 - registered by the session's addon fixture

    from tests.conftest import sample_path
    from skinkit.blender.scene import find_skinned_mesh

    def open_sample(name):
        bpy.ops.wm.open_mainfile(filepath=sample_path(name), load_ui=False)
        return find_skinned_mesh(bpy.context.scene.objects)

    prepared_arm(open_sample)
    path = str(tmp_path_factory.mktemp("untouched") / "prepared_arm.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    return path


@pytest.fixture
def arm(prepared_file):
    bpy.ops.wm.open_mainfile(filepath=prepared_file, load_ui=False)
    return bpy.data.objects["arm"]


def tube_sequence():
    frames, triangles, _, _ = rigid_chain_sequence(segments=3, frames=8)
    mesh_object = mesh_with_shape_keys(frames, triangles)
    select(mesh_object)
    return mesh_object


# ---- inputs that make each operator fail --------------------------------------------------------------------------

ARM_FAILURES = [
    ("compare_with_armature", BACKWARDS),
    ("bake_shape_keys", BACKWARDS),
    ("bake_mesh_cache", dict(RANGE, filepath="//cache.txt")),
    ("bake_mesh_cache", dict(RANGE, filepath="/no/such/folder/cache.pc2")),
    ("fit_from_examples", {"source": "SHAPE_KEYS", "held_out": "5-1"}),
    ("fit_from_examples", {"source": "SHAPE_KEYS", "held_out": "every frame"}),
    ("fit_from_examples", {"source": "SEQUENCE", "use_scene_range": False, "frame_start": 1, "frame_end": 1}),
    ("animated_unwrap", {"mode": "SEAMS", "metric": "FRAMES", "texture_size": 16, "margin": 256}),
    ("skin_from_sequence", {"train": "9-2"}),
]


def test_an_operator_refusing_its_input_leaves_the_scene_untouched(arm):
    select(arm)
    before = scene_fingerprint()
    for name, keywords in ARM_FAILURES:
        failing(name, **keywords)
        assert_unchanged(before, f"{name} failing on {keywords}")


def test_pose_statistics_and_sequences_refused_leave_the_scene_untouched(arm):
    select(rig_of(arm).armature_object)
    before = scene_fingerprint()
    failing("compute_pose_statistics", source="POSES", poses="3, x")
    failing("compute_pose_statistics", source="POSES", poses="9-2")
    assert_unchanged(before, "compute_pose_statistics failing")
    tube = tube_sequence()
    before = scene_fingerprint()
    failing("skin_from_sequence", bones=10000, max_influences=2)
    failing("skin_from_sequence", bones=3, max_influences=2, train="7-3")
    assert_unchanged(before, f"skin_from_sequence failing on '{tube.name}'")


def test_operators_that_cannot_run_here_leave_the_scene_untouched(open_sample, addon):
    """Poll refusing: no model, no rig, or the wrong kind of active object."""
    mesh_object = open_sample("arm")
    assert mesh_object is not None
    select(mesh_object)
    before = scene_fingerprint()
    for name in ("toggle_preview", "remove_model", "compare_with_armature", "bake_shape_keys", "bake_mesh_cache",
                 "show_fit_error", "show_max_distance"):
        failing(name)
    assert_unchanged(before, "operators refused by poll on a mesh without a model")
    select(rig_of(mesh_object).armature_object)
    before = scene_fingerprint()
    for name in ("convert_to_animation_space", "fit_from_examples", "animated_unwrap", "show_uv_layout"):
        failing(name)
    assert_unchanged(before, "operators refused by poll on an armature")


# ---- a failure half-way through writing the result -----------------------------------------------------------------

def broken(*arguments, **keywords):
    raise SkinkitError("injected failure while writing")


WRITE_FAILURES = [
    # (operator, keywords, module, function the write calls after it has changed something)
    ("fit_from_examples", {"source": "SHAPE_KEYS", "method": "PER_VERTEX"}, fitting, "write_heat_map"),
    ("fit_from_examples", {"source": "SHAPE_KEYS", "method": "PER_VERTEX"}, fitting.storage, "write_model"),
    ("convert_to_animation_space", {}, skinning.storage, "write_model"),
    ("animated_unwrap", {"metric": "REST", "make_active": True, "mark_seams": True}, unwrap, "mark_edges_as_seams"),
    ("compute_pose_statistics", {"source": "LIMITS"}, pose_statistics, "rig_signature"),
    ("show_max_distance", {}, pose_statistics, "write_heat_map"),
]


def test_a_failure_while_writing_leaves_the_scene_untouched(arm):
    for name, keywords, module, function in WRITE_FAILURES:
        assert hasattr(module, function), f"{module.__name__} no longer calls {function}: update WRITE_FAILURES"
        select(rig_of(arm).armature_object if name == "compute_pose_statistics" else arm)
        before = scene_fingerprint()
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(module, function, broken)
            failing(name, **keywords)
        assert_unchanged(before, f"{name} failing in {function}")


def test_a_decomposition_failing_while_writing_leaves_the_scene_untouched(arm, monkeypatch):
    tube_sequence()
    before = scene_fingerprint()
    monkeypatch.setattr(decompose, "write_heat_map", broken)
    failing("skin_from_sequence", bones=3, max_influences=2)
    assert_unchanged(before, "skin_from_sequence failing in write_heat_map")


# ---- cancelled midway ----------------------------------------------------------------------------------------------

def test_a_frame_loop_cancelled_midway_leaves_the_scene_untouched(arm):
    """What Esc does to Compare / Bake: the frame generator is closed after a few frames."""
    select(arm)
    bpy.context.scene.frame_set(7)
    before = scene_fingerprint()
    for steps in ("frame_positions", "frame_deviations"):
        generator = getattr(skinning, steps)(arm, list(range(1, 30)))
        for _ in range(3):
            next(generator)
        assert differences(before, scene_fingerprint())  # the loop really is midway: it moved the frame
        generator.close()
        assert_unchanged(before, f"{steps} closed midway")


def test_background_jobs_cancelled_midway_leave_the_scene_untouched(arm):
    """What Esc does to Fit, Skin from Sequence and Animated Unwrap: their solve stops through the progress
    callback, after prepare (which only reads the scene)."""
    select(arm)
    before = scene_fingerprint()
    examples = fitting.examples_from_shape_keys(arm, rig_of(arm).armature_object)
    jobs = {"fit": fitting.prepare_fit(arm, examples, method="global"),
            "unwrap": unwrap.prepare_unwrap(arm, metric="animation", mode="auto", chart_count=None, straighten=False,
                                            segment_in="rest", texture_size=256, margin=2, make_active=False,
                                            mark_seams=False)}
    for name, job in jobs.items():
        calls = []

        def cancel_after_first(fraction):
            calls.append(fraction)
            return len(calls) > 1

        try:
            job.solve(cancel_after_first)
        except SkinkitError as error:
            assert "cancel" in str(error), name
        assert_unchanged(before, f"the {name} job cancelled")
    tube = tube_sequence()
    before = scene_fingerprint()
    sequence = decompose.frames_from(tube, "shape-keys")
    job = decompose.prepare(tube, sequence, bones=3, max_influences=2)
    with pytest.raises(SkinkitError, match="cancel"):
        job.solve(lambda fraction: True)
    assert_unchanged(before, "the decomposition cancelled")


# ---- one undo ------------------------------------------------------------------------------------------------------

UNDOABLE = {
    "convert_to_animation_space": {},
    "toggle_preview": {},
    "bake_shape_keys": RANGE,
    "fit_from_examples": {"source": "SHAPE_KEYS", "method": "PER_VERTEX"},
    "show_max_distance": {},
    "animated_unwrap": {"metric": "REST", "make_active": True, "mark_seams": True},
    "show_uv_layout": {},
    "remove_model": {},
}


def test_one_undo_restores_the_whole_scene_after_each_operator(arm):
    """Undo works headless (bpy.ops.ed.undo after an operator called with undo=True)."""
    for name, keywords in UNDOABLE.items():
        select(bpy.data.objects["arm"])
        bpy.ops.ed.undo_push(message=f"before {name}")
        before = scene_fingerprint()
        assert getattr(bpy.ops.skinkit, name)("EXEC_DEFAULT", True, **keywords) == {"FINISHED"}
        assert differences(before, scene_fingerprint()), f"{name} changed nothing"
        bpy.ops.ed.undo()
        changed = differences(before, scene_fingerprint())
        assert not changed, f"one undo after {name} left: {changed[:8]}"
