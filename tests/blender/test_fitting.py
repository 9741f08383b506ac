"""Fit from Example Poses in real Blender: the three example sources, the operator, the outputs, the CLI,
and bad input refused with the scene unchanged."""
import json
import os
import subprocess
import sys

import bpy
import numpy as np
import pytest
from tests.conftest import ROOT, sample_path
from tests.blender.test_skinning import draw_panel, scene_fingerprint, select

from skinkit import SkinkitError
from skinkit.blender import attributes, fitting, skinning, storage
from skinkit.framelist import parse_frame_list
from skinkit.blender.rig import deform_weights, rig_of
from skinkit.meshio import read_obj, write_obj

FRAMES = list(range(1, 41, 3))


def dual_quaternion_examples(mesh_object, frames):
    """Blender's Preserve Volume skinning at each frame: examples linear blend skinning cannot reproduce."""
    examples = fitting.examples_from_armature(mesh_object, frames)
    bpy.context.scene.frame_set(1)
    return examples.positions


def add_shape_key_examples(mesh_object, positions, frames):
    if mesh_object.data.shape_keys is None:
        mesh_object.shape_key_add(name="Basis", from_mix=False)
    for frame, frame_positions in zip(frames, positions):
        name = f"pose_{frame}"
        mesh_object.shape_key_add(name=name, from_mix=False).points.foreach_set("co", frame_positions.reshape(-1))
        bpy.context.scene.timeline_markers.new(name, frame=frame)


@pytest.fixture
def arm_with_examples(open_sample, addon):
    mesh_object = open_sample("arm")
    add_shape_key_examples(mesh_object, dual_quaternion_examples(mesh_object, FRAMES), FRAMES)
    select(mesh_object)
    return mesh_object


def configure(method="PER_VERTEX", held_out="19, 31"):
    settings = bpy.context.scene.skinkit
    settings.fit_source, settings.fit_method, settings.fit_held_out = "SHAPE_KEYS", method, held_out
    return settings


@pytest.mark.parametrize("method", ["PER_VERTEX", "GLOBAL"])
def test_operator_fits_shape_key_examples_and_writes_everything(arm_with_examples, method):
    mesh_object = arm_with_examples
    configure(method)
    assert bpy.ops.skinkit.fit_from_examples() == {"FINISHED"}
    mesh = mesh_object.data
    assert storage.has_model(mesh)
    stored = storage.read_model(mesh, mesh_object.name)
    assert np.abs(stored.model.homogeneous_weights() - 1).max() < 1e-6
    weights = deform_weights(rig_of(mesh_object))
    assert np.abs(weights.totals() - 1).max() < 1e-6 and np.all(weights.weights >= 0)
    assert attributes.ERROR_ATTRIBUTE in mesh.attributes and attributes.HEAT_ATTRIBUTE in mesh.color_attributes
    report = mesh[attributes.REPORT_PROPERTY]
    assert report["examples"] == len(FRAMES) - 2 and report["held_out"] == 2
    assert report["rest_pose.animation_space.max"] < 1e-4  # the bind pose is kept
    assert report["regularisation_lambda"] > 0 and report["validation.0.001"] > 0  # λ chosen by validation
    for part in ("train", "held_out"):  # animation space beats linear blend on dual-quaternion examples
        assert report[f"animation_space.{part}.rms"] < 0.5 * report[f"linear_blend.{part}.rms"]
    assert bpy.ops.skinkit.show_fit_error() == {"FINISHED"}
    assert mesh.color_attributes.active_color.name == attributes.HEAT_ATTRIBUTE


def test_objects_and_mesh_cache_sources(open_sample, tmp_path):
    mesh_object = open_sample("arm")
    frames = list(range(10, 22))
    positions = dual_quaternion_examples(mesh_object, frames)
    objects = []
    for frame, frame_positions in zip(frames, positions):
        copy = bpy.data.objects.new(f"example_{frame}", mesh_object.data.copy())
        copy.matrix_world = mesh_object.matrix_world
        copy.data.vertices.foreach_set("co", frame_positions.astype(np.float32).reshape(-1))
        copy["skinkit_frame"] = frame
        bpy.context.scene.collection.objects.link(copy)
        objects.append(copy)
    armature = rig_of(mesh_object).armature_object
    from_objects = fitting.examples_from_objects(mesh_object, armature, objects)
    assert np.abs(from_objects.positions - positions).max() < 1e-5 and from_objects.frames == frames
    cache_path = str(tmp_path / "examples.pc2")
    player = skinning.bake_mesh_cache(mesh_object, cache_path, frames, positions.astype(np.float32))
    from_cache = fitting.examples_from_sequence(mesh_object, player, frames)
    assert np.abs(from_cache.positions - positions).max() < 1e-5
    report = fitting.fit_object(mesh_object, from_cache, held_out_frames=[frames[-1]])
    assert report["animation_space"]["train"]["rms"] < report["linear_blend"]["train"]["rms"]


def test_bad_examples_are_refused_and_the_scene_left_unchanged(arm_with_examples):
    mesh_object = arm_with_examples
    configure()
    mesh_object.shape_key_add(name="stray", from_mix=False)  # no marker pairs it with a frame
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="example 'stray' has no frame"):
        bpy.ops.skinkit.fit_from_examples()
    assert scene_fingerprint() == before
    mesh_object.shape_key_remove(mesh_object.data.shape_keys.key_blocks["stray"])
    configure(held_out=", ".join(str(f) for f in FRAMES))
    with pytest.raises(RuntimeError, match="every example is held out"):
        bpy.ops.skinkit.fit_from_examples()
    configure(held_out="")
    keys = mesh_object.data.shape_keys.key_blocks
    for key in list(keys)[3:]:
        mesh_object.shape_key_remove(key)  # two examples left: 6 equations for the 7 unknowns of 2 bones
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="examples give only 6 equations"):
        bpy.ops.skinkit.fit_from_examples()
    assert scene_fingerprint() == before


def test_examples_with_other_vertex_counts_are_refused(open_sample):
    mesh_object = open_sample("arm")
    with pytest.raises(SkinkitError, match="the examples have 10 vertices, 'arm' has 4098"):
        fitting.examples_from_positions(mesh_object, np.zeros((3, 10, 3)), [1, 2, 3])
    with pytest.raises(SkinkitError, match="3 example meshes but 2 frames"):
        fitting.examples_from_positions(mesh_object, np.zeros((3, 4098, 3)), [1, 2])


def test_parse_frame_list():
    assert parse_frame_list("5, 10, 20-22") == [5, 10, 20, 21, 22]
    assert parse_frame_list("") == []
    with pytest.raises(SkinkitError, match="expected numbers and ranges"):
        parse_frame_list("5, x")


def run_cli(*arguments):
    completed = subprocess.run([sys.executable, "-m", "skinkit.cli", *arguments, "--json"], capture_output=True,
                               text=True, cwd=ROOT, timeout=300)
    lines = [line for line in completed.stdout.splitlines() if line.strip()]
    assert len(lines) == 1, completed.stdout + completed.stderr
    return completed.returncode, json.loads(lines[0])


def test_cli_fits_an_obj_sequence_and_exports_reconstructions(open_sample, tmp_path):
    mesh_object = open_sample("arm")
    positions = dual_quaternion_examples(mesh_object, FRAMES)
    world = np.array(mesh_object.matrix_world)
    folder = tmp_path / "sequence"
    folder.mkdir()
    for index, frame_positions in enumerate(positions):
        write_obj(str(folder / f"example_{index}.obj"), frame_positions @ world[:3, :3].T + world[:3, 3])
    exported = tmp_path / "reconstructed"
    status, result = run_cli("fit", "--rig", sample_path("arm"), "--sequence", str(folder), "--frames", "1:40:3",
                             "--hold-out", "19", "--method", "global", "--export-frames", str(exported))
    assert status == 0, result
    assert result["vertices"] == 4098 and result["bones"] == 3 and result["examples"] == len(FRAMES) - 1
    assert result["iterations"] > 0
    assert result["rest_pose"]["animation_space"]["max"] < 1e-4 and result["warnings"] == []
    # every λ candidate and the linear-blend prior; animation space wins on the arm, so no fall-back
    assert len(result["validation"]) == 8 and result["regularisation_lambda"] > 0
    for part in ("train", "held_out"):
        assert result["animation_space"][part]["rms"] < result["linear_blend"][part]["rms"]
    files = sorted(os.listdir(exported))
    assert len(files) == len(FRAMES)
    reconstructed, _ = read_obj(str(exported / "frame_0019.obj"))
    original, _ = read_obj(str(folder / f"example_{FRAMES.index(19)}.obj"))
    diagonal = np.linalg.norm(original.max(0) - original.min(0))
    assert np.linalg.norm(reconstructed - original, axis=1).max() / diagonal < 0.02  # same order, same space

    status, result = run_cli("fit", "--rig", sample_path("arm"), "--sequence", str(folder), "--frames", "1:40:3",
                             "--sequence-scale", "100")
    assert status == 1 and "example 0 is 100 times the size of the rest mesh" in result["error"]

    (folder / "example_3.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    status, result = run_cli("fit", "--rig", sample_path("arm"), "--sequence", str(folder), "--frames", "1:40:3")
    assert status == 1 and "3 vertices" in result["error"]
    status, result = run_cli("fit", "--rig", sample_path("arm"), "--sequence", str(folder), "--frames", "1:40")
    assert status == 1 and ("14 .obj files" in result["error"] or "vertices" in result["error"])


def test_a_prepared_fit_solves_on_a_worker_thread_and_cancels_cleanly(arm_with_examples):
    """The modal operator's contract: prepare reads the scene, solve runs on another thread (touching no
    Blender data) and can be cancelled through its progress callback, write changes the scene."""
    import threading

    mesh_object = arm_with_examples
    examples = fitting.examples_from_shape_keys(mesh_object, rig_of(mesh_object).armature_object)
    before = scene_fingerprint()
    job = fitting.prepare_fit(mesh_object, examples, method="global")
    assert scene_fingerprint() == before
    outcome = {}

    def run(cancel):
        try:
            outcome[cancel] = job.solve(lambda fraction: cancel)
        except SkinkitError as error:
            outcome[cancel] = error

    for cancel in (True, False):
        worker = threading.Thread(target=run, args=(cancel,))
        worker.start()
        worker.join(timeout=120)
    assert isinstance(outcome[True], SkinkitError) and "cancelled" in str(outcome[True])
    assert scene_fingerprint() == before
    job.write(mesh_object, outcome[False])
    assert storage.has_model(mesh_object.data)
    assert outcome[False]["report"]["iterations"] > 0


def test_rest_pose_and_validation_are_operator_options_a_script_can_turn_off(arm_with_examples):
    """Without the rest pose as an example the fitted model moves the bind pose (what issue 18 saw)."""
    mesh_object = arm_with_examples
    configure()
    rest_error = {}
    for keep in (False, True):
        assert bpy.ops.skinkit.fit_from_examples(reproduce_rest=keep, validate=keep) == {"FINISHED"}
        report = mesh_object.data[attributes.REPORT_PROPERTY]
        rest_error[keep] = report["rest_pose.animation_space.max"]
        assert report["rest_pose.linear_blend.max"] < 1e-6  # linear blend skinning keeps it by construction
    assert rest_error[True] < 1e-4 < rest_error[False]


def test_examples_linear_blend_skinning_reproduces_fall_back_to_its_fit_and_say_so(open_sample, addon):
    """The arm's own linear-blend skinning as examples: animation space cannot predict them better, so validation
    keeps the linear-blend fit, the report says so, and the operator's messages tell the artist why."""
    mesh_object = open_sample("arm")
    examples = fitting.examples_from_armature(mesh_object, FRAMES, preserve_volume=False)
    bpy.context.scene.frame_set(1)
    add_shape_key_examples(mesh_object, examples.positions, FRAMES)
    select(mesh_object)
    configure("PER_VERTEX")
    assert bpy.ops.skinkit.fit_from_examples() == {"FINISHED"}
    report = mesh_object.data[attributes.REPORT_PROPERTY]
    assert report["fallback"]
    assert report["animation_space.train.rms"] == pytest.approx(report["linear_blend.train.rms"], rel=1e-6, abs=1e-12)
    assert any(str(text).startswith("Linear-blend fit kept") for text in draw_panel(addon).texts())
    operators = addon.operators
    summary = {"fallback": True, "examples": 3, "animation_space": {"train": {"mean": 1e-3, "max": 2e-3}},
               "linear_blend": {"train": {"mean": 1e-3}}}
    assert ("INFO", operators.fallback_message("arm")) in operators.fit_messages("arm", summary)
    assert ("INFO", operators.fallback_message("arm")) not in operators.fit_messages("arm", summary | {"fallback": False})
