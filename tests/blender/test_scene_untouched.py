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


# ---- the newer families: normal maps, export, handle rigs, skeletons, levels of detail ----------------------------

def cancelled_midway(job, what: str) -> None:
    """What Esc does to a dialog or background job: its solve stops through the progress callback, after it has
    reported progress at least once (so the solve really was under way)."""
    calls = []

    def cancel_after_first(fraction):
        calls.append(fraction)
        return len(calls) > 1

    with pytest.raises(SkinkitError, match="cancel"):
        job.solve(cancel_after_first)
    assert calls, f"{what} never reported progress, so Esc could not stop it"


def undone(name: str, keywords: dict, select_first) -> None:
    """Runs bpy.ops.skinkit.<name> with undo, checks it changed the scene, undoes once and checks the scene is back."""
    select_first()
    bpy.ops.ed.undo_push(message=f"before {name}")
    before = scene_fingerprint()
    assert getattr(bpy.ops.skinkit, name)("EXEC_DEFAULT", True, **keywords) == {"FINISHED"}
    assert differences(before, scene_fingerprint()), f"{name} changed nothing"
    bpy.ops.ed.undo()
    changed = differences(before, scene_fingerprint())
    assert not changed, f"one undo after {name} left: {changed[:8]}"


def plain_cube():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_cube_add()
    return bpy.context.active_object


def test_lod_operators_refused_by_poll_leave_the_scene_untouched(addon):
    """A mesh without a rig: Limit Influences, Subdivide Model, Build LOD Chain, Export for Engines, Rigid Skin,
    Bake Normal Maps (no UV map), LOD Preview (no chain) and the handle rig's toggle and bake (no rig) all refuse."""
    cube = plain_cube()
    cube.data.uv_layers.remove(cube.data.uv_layers[0])
    select(cube)
    before = scene_fingerprint()
    for name in ("limit_influences", "subdivide_model", "build_lod_chain", "export_for_engines", "rigid_skin_seams",
                 "bake_normal_maps", "toggle_lod_preview", "toggle_handle_rig", "bake_handle_rig",
                 "export_hierarchy", "import_hierarchy"):
        assert not getattr(bpy.ops.skinkit, name).poll(), f"{name} ran on a bare cube"
        failing(name)
        assert_unchanged(before, f"{name} refused by poll")


def test_lod_operators_failing_and_cancelled_leave_the_scene_untouched(arm):
    from skinkit.blender import lod, lod_chain

    select(arm)
    before = scene_fingerprint()
    failing("subdivide_model", scheme="LOOP")  # the arm has quads
    assert_unchanged(before, "subdivide_model failing on quads")
    for name, keywords, module, function in (
            ("limit_influences", {"max_influences": 2}, lod.storage, "write_model"),
            ("subdivide_model", {"levels": 1}, lod.storage, "write_model"),
            ("build_lod_chain", {"levels": 2}, lod_chain.storage, "write_model")):
        assert hasattr(module, function), f"{module.__name__} no longer calls {function}"
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(module, function, broken)
            failing(name, **keywords)
        assert_unchanged(before, f"{name} failing in {function}")
    for what, job in (("limit influences", lod.prepare_limit(arm, 2)),
                      ("subdivide", lod.prepare_subdivide(arm, levels=2)),
                      ("the LOD chain", lod_chain.prepare_lod_chain(arm, levels=3))):
        cancelled_midway(job, what)
        assert_unchanged(before, f"{what} cancelled")


def test_lod_operators_are_undone_in_one_step(arm):
    for name, keywords in (("limit_influences", {"max_influences": 2}), ("subdivide_model", {"levels": 1}),
                           ("build_lod_chain", {"levels": 2})):
        undone(name, keywords, lambda: select(bpy.data.objects["arm"]))


def test_lod_preview_refused_and_undone(arm):
    from skinkit.blender import preview

    select(arm)
    before = scene_fingerprint()
    with pytest.raises(SkinkitError, match="not a level of a LOD chain"):
        preview.lod_enable(arm, bpy.context.evaluated_depsgraph_get())
    assert_unchanged(before, "LOD Preview refused outside a chain")
    assert bpy.ops.skinkit.build_lod_chain(levels=2) == {"FINISHED"}
    undone("toggle_lod_preview", {}, lambda: select(bpy.data.objects["arm_LOD0"]))


def test_export_for_engines_failing_leaves_the_scene_untouched(arm, tmp_path, monkeypatch):
    """Export changes nothing when it succeeds either (so there is nothing to undo): checked here too."""
    from skinkit.blender import export

    select(arm)
    before = scene_fingerprint()
    failing("export_for_engines", filepath=str(tmp_path / "arm.glb"), format="FBX")  # the wrong extension
    failing("export_for_engines", filepath=str(tmp_path / "arm.glb"), chain="ghost")
    failing("export_for_engines", filepath=str(tmp_path / "missing" / "arm.glb"), format="GLB")
    assert_unchanged(before, "export_for_engines refusing")

    def disk_full(fmt):
        def exporter(**options):
            with open(options["filepath"], "wb") as partial:
                partial.write(b"glTF")
            raise RuntimeError("Error: disk full")
        return exporter

    with monkeypatch.context() as patch:
        patch.setattr(export, "exporter", disk_full)
        failing("export_for_engines", filepath=str(tmp_path / "arm.glb"), format="GLB", animation_space=False)
    assert_unchanged(before, "export_for_engines failing half-way through the exporter")
    assert not (tmp_path / "arm.glb").exists()
    assert bpy.ops.skinkit.export_for_engines(filepath=str(tmp_path / "arm.glb"), format="GLB") == {"FINISHED"}
    assert_unchanged(before, "export_for_engines succeeding")


def handle_tube():
    """A tube with 12 example poses as shape keys and the vertex group 'handles', active."""
    from skinkit.blender.scene import empty_scene, new_mesh_object

    frames, triangles, _, _ = rigid_chain_sequence(3, 12, seed=8)
    empty_scene()
    mesh_object = new_mesh_object("tube", frames[0], triangles)
    mesh_object.shape_key_add(name="Basis", from_mix=False)
    for number, frame in enumerate(frames[1:], start=1):
        key = mesh_object.shape_key_add(name=f"pose_{number:02d}", from_mix=False)
        key.data.foreach_set("co", frame.astype(np.float32).ravel())
    mesh_object.vertex_groups.new(name="handles").add([5, 60, 125], 1.0, "REPLACE")
    select(mesh_object)
    return mesh_object


def test_handle_rig_failing_cancelled_and_undone(addon, monkeypatch):
    from skinkit.blender import handles as bridge

    tube = handle_tube()
    tube.vertex_groups["handles"].name = "spare"
    before = scene_fingerprint()
    failing("learn_handle_rig", bones=3)  # no vertex group 'handles'
    assert_unchanged(before, "learn_handle_rig without its control points")
    tube.vertex_groups["spare"].name = "handles"
    before = scene_fingerprint()
    with monkeypatch.context() as patch:
        assert hasattr(bridge, "store_model"), "skinkit.blender.handles no longer calls store_model"
        patch.setattr(bridge, "store_model", broken)  # after the Empties are made
        failing("learn_handle_rig", bones=3)
    assert_unchanged(before, "learn_handle_rig failing while writing")
    cancelled_midway(bridge.prepare_learn(tube, "shape_keys", bones=3), "learning a handle rig")
    assert_unchanged(before, "learning a handle rig cancelled")
    undone("learn_handle_rig", {"bones": 3}, lambda: select(bpy.data.objects["tube"]))
    assert bpy.ops.skinkit.learn_handle_rig(bones=3) == {"FINISHED"}
    before = scene_fingerprint()
    failing("bake_handle_rig", target="MESH_CACHE", filepath="/no/such/folder/tube.pc2")
    assert_unchanged(before, "bake_handle_rig failing on a missing folder")
    undone("bake_handle_rig", {"target": "SHAPE_KEYS"}, lambda: select(bpy.data.objects["tube"]))
    undone("toggle_handle_rig", {"enable": False}, lambda: select(bpy.data.objects["tube"]))


def test_skeleton_operators_failing_and_undone(addon, tmp_path):
    from tests.blender.test_skeleton import segmented_object

    from skinkit.skeleton import chain_of_cylinders, star_of_limbs

    parts = chain_of_cylinders(2).parts
    apart = type(parts)(np.vstack([parts.positions, parts.positions + 50]),
                        np.vstack([parts.triangles, parts.triangles + len(parts.positions)]),
                        np.repeat(np.array([0, 1], np.int32), len(parts.triangles)), ("a", "b"))
    segmented_object(type("Sample", (), {"parts": apart})())
    before = scene_fingerprint()
    failing("extract_skeleton", part_source="attribute")  # parts that do not meet
    failing("extract_skeleton", part_source="groups")  # no vertex groups
    assert_unchanged(before, "extract_skeleton failing")
    mesh_object = segmented_object(star_of_limbs())
    undone("extract_skeleton", {"part_source": "attribute", "method": "centroid"}, lambda: select(mesh_object))
    assert bpy.ops.skinkit.extract_skeleton(part_source="attribute", method="centroid") == {"FINISHED"}
    armature = bpy.data.objects["character_skeleton"]
    before = scene_fingerprint()
    select(armature)
    failing("import_hierarchy", filepath=str(tmp_path / "missing.hier"))
    (tmp_path / "broken.hier").write_text("not a hierarchy\n")
    failing("import_hierarchy", filepath=str(tmp_path / "broken.hier"))
    failing("export_hierarchy", filepath=str(tmp_path / "no" / "folder.hier"))
    select(bpy.data.objects["character"])
    failing("rigid_skin_seams", frame_start=3, frame_end=1)
    assert_unchanged(before, "hierarchy files and rigid skin failing")
    undone("rigid_skin_seams", {"frame_start": 1, "frame_end": 2, "steps": 2},
           lambda: select(bpy.data.objects["character"]))
    undone("rigid_skin_seams", {"frame_start": 1, "frame_end": 2, "steps": 2, "remove_sinking": True},
           lambda: select(bpy.data.objects["character"]))


def test_normal_maps_failing_cancelled_and_undone(addon, tmp_path):
    from tests.blender.test_normal_maps import bump, grid_object

    from skinkit.blender import normal_maps

    bpy.ops.wm.read_factory_settings(use_empty=True)
    low, high = grid_object("low", 4), grid_object("high", 60, bump)
    for scene_object in (low, high):
        scene_object.select_set(True)
    select(low)
    before = scene_fingerprint()
    options = {"source": "SELECTED", "targets": "ACTIVE", "resolution": 32, "cage": 0.2}
    failing("bake_normal_maps", directory=str(tmp_path / "missing"), **options)
    failing("bake_normal_maps", **dict(options, targets="CHAIN"), directory=str(tmp_path))
    with pytest.MonkeyPatch.context() as patch:
        assert hasattr(normal_maps, "wire_materials"), "skinkit.blender.normal_maps no longer calls wire_materials"
        patch.setattr(normal_maps, "wire_materials", broken)  # after the image is written and loaded
        failing("bake_normal_maps", directory=str(tmp_path), **options)
    assert_unchanged(before, "bake_normal_maps failing")
    assert not list(tmp_path.iterdir()), "a failed bake left its image file"
    job = normal_maps.prepare_normal_maps([low], high, size=64, margin=2, samples=1, cage=0.2, frame=None,
                                          image_format="png16", out_dir=str(tmp_path), pack=True)
    cancelled_midway(job, "baking a normal map")
    assert_unchanged(before, "baking a normal map cancelled")
    undone("bake_normal_maps", dict(options, directory=str(tmp_path)), lambda: (select(low), high.select_set(True)))
