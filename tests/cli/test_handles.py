"""`skinkit handles train|predict` as a user runs it: an .obj folder in, a model, JSON and predicted frames out."""
import os

import numpy as np
import pytest
from tests.cli.obj_folders import write_obj_folder
from tests.cli.test_cli import skinkit
from tests.sequences import rigid_chain_sequence

from skinkit.meshio import read_obj


@pytest.fixture(scope="module")
def obj_folder(tmp_path_factory):
    frames, triangles, _, _ = rigid_chain_sequence(segments=3, frames=24, seed=6)
    return write_obj_folder(tmp_path_factory.mktemp("handle_sequence"), frames, triangles), frames


def test_train_then_predict_the_held_out_frames(obj_folder, tmp_path):
    folder, frames = obj_folder
    model = tmp_path / "rig.npz"
    status, trained = skinkit("handles", "train", "--sequence", folder, "--train", "1-20", "--handle-vertices",
                              "5,60,125", "--bones", "3", "--kernel", "linear", "--sequence-scale", "0.01",
                              "--out", str(model), "--json")
    assert status == 0 and trained["handle_vertices"] == [5, 60, 125] and trained["bones"] == 3
    assert trained["examples"] == 20 and trained["seconds"] > 0 and 0 <= trained["training_error"] < 0.05
    exported = tmp_path / "frames"
    status, predicted = skinkit("handles", "predict", str(model), "--sequence", folder, "--sequence-scale", "0.01",
                                "--export-frames", str(exported), "--json")
    assert status == 0 and predicted["frames"] == 24 and predicted["ms_per_frame"] > 0
    assert 0 < predicted["rms_error"] < 0.05 and predicted["rms_error"] <= predicted["max_error"]
    files = sorted(os.listdir(exported))
    assert files[0] == "0001.obj" and len(files) == 24
    last, _ = read_obj(str(exported / files[-1]))
    extent = np.ptp(frames[0], axis=0).max()
    assert np.abs(last / 100.0 - frames[-1]).max() < 0.2 * extent  # the input's units and vertex order
    targets = tmp_path / "handles.npy"
    np.save(targets, frames[-2:, [5, 60, 125]] * 100.0)
    status, from_targets = skinkit("handles", "predict", str(model), "--targets", str(targets), "--sequence-scale",
                                   "0.01", "--export-frames", str(tmp_path / "targets"), "--json")
    assert status == 0 and from_targets["frames"] == 2 and "rms_error" not in from_targets
    again, _ = read_obj(str(tmp_path / "targets" / "0002.obj"))
    np.testing.assert_allclose(again, last, atol=1e-6)


def test_train_weights_and_validation_options(obj_folder, tmp_path):
    folder, _ = obj_folder
    reports = {}
    for extra in ([], ["--lbs-weights"], ["--validate"]):
        status, reports[tuple(extra)] = skinkit("handles", "train", "--sequence", folder, "--handle-vertices",
                                                "5,60,125", "--bones", "3", *extra, "--out",
                                                str(tmp_path / "rig.npz"), "--json")
        assert status == 0
    assert reports[()]["dqs_weights"] and not reports[("--lbs-weights",)]["dqs_weights"]
    assert reports[()]["validation"] is None
    chosen = reports[("--validate",)]["validation"]
    assert chosen["folds"] == 4 and chosen["kernel_scale"] > 0 and chosen["ridge"] > 0


@pytest.mark.parametrize("arguments, message", [
    (["--handle-vertices", "3,3"], "more than once"),
    (["--handle-vertices", "99999"], "vertex indices must be in"),
    (["--handles", "2", "--train", "1-2"], "at least 3"),
])
def test_train_errors_are_one_json_object(obj_folder, tmp_path, arguments, message):
    folder, _ = obj_folder
    status, report = skinkit("handles", "train", "--sequence", folder, "--bones", "3", *arguments,
                             "--out", str(tmp_path / "rig.npz"), "--json", expect_success=False)
    assert status == 1 and message in report["error"]
    assert not (tmp_path / "rig.npz").exists()


def test_predict_refuses_a_file_that_is_no_model(tmp_path):
    bad = tmp_path / "bad.npz"
    np.savez(bad, something=np.zeros(3))
    np.save(tmp_path / "t.npy", np.zeros((1, 2, 3)))
    status, report = skinkit("handles", "predict", str(bad), "--targets", str(tmp_path / "t.npy"),
                             "--export-frames", str(tmp_path / "out"), "--json", expect_success=False)
    assert status == 1 and "format version" in report["error"]


def test_train_with_the_hierarchical_clustering_and_validated_bone_counts(obj_folder, tmp_path):
    folder, _ = obj_folder
    status, trained = skinkit("handles", "train", "--sequence", folder, "--handle-vertices", "5,60,125",
                              "--clustering", "hierarchical", "--bone-counts", "2,3,4", "--out",
                              str(tmp_path / "rig.npz"), "--json")
    assert status == 0 and trained["clustering"] == "hierarchical"
    assert sorted(trained["bone_validation"]) == ["2", "3", "4"]  # JSON keys
    least = min(trained["bone_validation"].values())
    chosen = trained["bone_validation"][str(trained["bones"])]
    assert chosen <= 1.02 * least
    status, report = skinkit("handles", "train", "--sequence", folder, "--handle-vertices", "5,60,125",
                             "--bone-counts", "2,x", "--out", str(tmp_path / "bad.npz"), "--json",
                             expect_success=False)
    assert status == 1 and "whole numbers" in report["error"]
    assert not (tmp_path / "bad.npz").exists()
