"""`skinkit rigid-skin` as a user runs it: a grouped .obj, the rig from `skinkit skeleton`, and a keyframe file or a
folder of .Tmat poses in; one watertight .obj per frame and one JSON report out."""
import numpy as np
import pytest
from tests.cli.test_cli import skinkit

from skinkit.meshio import read_obj
from skinkit.skeleton import Hierarchy, free_limits, star_of_limbs, write_hierarchy, write_obj_groups
from skinkit.skeleton.animation import Channel, Keyframes, write_keyframes
from skinkit.skeleton.seams import boundary_edges, is_consistently_oriented


@pytest.fixture(scope="module")
def rigged(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rigged")
    sample = star_of_limbs()
    mesh = write_obj_groups(str(folder / "star.obj"), sample.parts)
    skinkit("skeleton", mesh, "--method", "centroid", "--out", str(folder / "rig.json"), "--json")
    return folder, mesh, sample


def clip(path, peak):
    channel = Channel(np.array([0.0, 4.0]), np.array([0.0, peak]), ["linear"] * 2, ["linear"] * 2)
    return write_keyframes(str(path), Keyframes(0.0, 4.0, {3: channel}))  # limb +x about X


def test_keyframes_give_watertight_frames(rigged, tmp_path):
    folder, mesh, _ = rigged
    out = tmp_path / "frames"
    _, report = skinkit("rigid-skin", mesh, "--rig", str(folder / "rig.json"), "--keyframes",
                        clip(tmp_path / "a.clip", 80.0), "--export-frames", str(out), "--json")
    assert len(report["frames"]) == 5
    for k, frame in enumerate(report["frames"]):
        assert frame["boundary_edges"] == 0 and frame["constructed_points"] == 5 * 4 * 4
        assert set(frame["seconds"]) == {"add", "normals", "check"}
        positions, triangles = read_obj(str(out / f"frame_{k + 1:04d}.obj"))
        assert len(positions) == report["vertices"] and boundary_edges(triangles) == 0
        assert is_consistently_oriented(triangles)
    last, _ = read_obj(str(out / "frame_0005.obj"))
    assert last[:, 1].max() > 2.0  # limb +x swung up toward +y (80 degrees)


def test_remove_sinking_runs_algorithm_5_per_frame(rigged, tmp_path):
    folder, mesh, _ = rigged
    out = tmp_path / "frames"
    _, report = skinkit("rigid-skin", mesh, "--rig", str(folder / "rig.json"), "--keyframes",
                        clip(tmp_path / "a.clip", 60.0), "--remove-sinking", "--no-collisions", "--export-frames",
                        str(out), "--json")
    frames = report["frames"]
    assert frames[0]["removed_points"] == 0 and sum(f["removed_points"] for f in frames) > 0
    for k, frame in enumerate(frames):
        assert frame["boundary_edges"] == 0 and not frame["fallback"]
        assert set(frame["seconds"]) == {"add", "remove", "triangulate", "normals", "check"}
        positions, triangles = read_obj(str(out / f"frame_{k + 1:04d}.obj"))
        assert boundary_edges(triangles) == 0 and is_consistently_oriented(triangles)
        assert len(positions) - len(triangles) // 2 == 2


def test_limits_and_collisions_are_reported(rigged, tmp_path):
    folder, mesh, sample = rigged
    limits = free_limits(6)
    limits[1, 0] = [-10.0, 40.0]
    hierarchy = write_hierarchy(str(tmp_path / "h.hier"), Hierarchy(sample.parts.names, sample.parents, limits))
    _, report = skinkit("rigid-skin", mesh, "--rig", str(folder / "rig.json"), "--keyframes",
                        clip(tmp_path / "b.clip", 80.0), "--hierarchy", hierarchy, "--export-frames",
                        str(tmp_path / "f"), "--json")
    assert [f["refused_limits"] for f in report["frames"]] == [[], [], [], ["limb_px"], ["limb_px"]]
    _, report = skinkit("rigid-skin", mesh, "--rig", str(folder / "rig.json"), "--keyframes",
                        clip(tmp_path / "c.clip", 160.0), "--export-frames", str(tmp_path / "g"), "--json")
    assert any("limb_px" in f["refused_collisions"] for f in report["frames"])


def test_tmat_poses(rigged, tmp_path):
    folder, mesh, _ = rigged
    poses = tmp_path / "poses"
    poses.mkdir()
    blocks = np.tile(np.vstack([np.eye(3), np.zeros(3)]), (6, 1))
    blocks[4 * 5 + 3] = [0.0, 0.0, 0.5]  # limb +z lifted by 0.5 (it tears the seam: the rings span it)
    (poses / "1.Tmat").write_text("\n".join(" ".join(f"{v:g}" for v in row) for row in blocks) + "\n")
    _, report = skinkit("rigid-skin", mesh, "--rig", str(folder / "rig.json"), "--poses", str(poses),
                        "--export-frames", str(tmp_path / "out"), "--json")
    positions, _ = read_obj(str(tmp_path / "out" / "frame_0001.obj"))
    assert report["frames"][0]["boundary_edges"] == 0 and positions[:, 2].max() == pytest.approx(3.5)


@pytest.mark.parametrize("arguments, message", [
    (["--rig", "missing.json", "--keyframes", "x.clip"], "missing.json"),
    (["--rig", "RIG", "--poses", "nowhere"], "not a folder"),
])
def test_bad_input_is_one_json_error(rigged, tmp_path, arguments, message):
    folder, mesh, _ = rigged
    arguments = [str(folder / "rig.json") if a == "RIG" else a for a in arguments]
    status, report = skinkit("rigid-skin", mesh, *arguments, "--export-frames", str(tmp_path / "x"), "--json",
                             expect_success=False)
    assert status == 1 and message in report["error"]


def test_weight_parts_take_their_bones_tmat_blocks(tmp_path):
    """Parts by dominant weight are named bone_k in order of first appearance, not k: each takes block k."""
    from skinkit.meshio import write_obj
    from skinkit.skeleton import chain_of_cylinders

    sample = chain_of_cylinders(3, sides=8, rings_per_part=2)
    positions = sample.parts.positions
    bones = np.clip((positions[:, 0] // 2).astype(int), 0, 2)
    bones = np.where(positions[:, 0] > 5.999, 2, bones)
    weights = np.eye(3)[[2, 0, 1]][bones]  # x < 2: bone 2, then bone 0, then bone 1
    mesh = str(tmp_path / "chain.obj")
    write_obj(mesh, positions, sample.parts.triangles)
    dmat = tmp_path / "w.dmat"
    dmat.write_text("3 %d\n" % len(positions) + "\n".join(f"{v:g}" for v in weights.T.reshape(-1)) + "\n")
    parts = f"weights:{dmat}"
    skinkit("skeleton", mesh, "--parts", parts, "--out", str(tmp_path / "rig.json"), "--json")
    poses = tmp_path / "poses"
    poses.mkdir()
    blocks = np.tile(np.vstack([np.eye(3), np.zeros(3)]), (3, 1))
    blocks[4 * 1 + 3] = [0.0, 0.0, 0.25]  # bone 1, the far segment, lifted
    (poses / "1.Tmat").write_text("\n".join(" ".join(f"{v:g}" for v in row) for row in blocks) + "\n")
    _, report = skinkit("rigid-skin", mesh, "--parts", parts, "--rig", str(tmp_path / "rig.json"), "--poses",
                        str(poses), "--export-frames", str(tmp_path / "out"), "--json")
    moved, _ = read_obj(str(tmp_path / "out" / "frame_0001.obj"))
    far = moved[:, 0] > 4.5
    assert report["frames"][0]["boundary_edges"] == 0
    assert np.allclose(moved[far, 2].max(), 0.5 + 0.25) and moved[moved[:, 0] < 1.5, 2].max() == pytest.approx(0.5)


def test_conic_arcs_with_sinking_removal(rigged, tmp_path):
    folder, mesh, _ = rigged
    out = tmp_path / "frames"
    _, report = skinkit("rigid-skin", mesh, "--rig", str(folder / "rig.json"), "--keyframes",
                        clip(tmp_path / "a.clip", 70.0), "--remove-sinking", "--arcs", "conic", "--no-collisions",
                        "--export-frames", str(out), "--json")
    frames = report["frames"]
    assert frames[0]["conic_columns"] == 0 and frames[-1]["conic_columns"] > 0  # straight at rest, bent at the end
    for k, frame in enumerate(frames):
        assert frame["boundary_edges"] == 0 and not frame["fallback"]
        positions, triangles = read_obj(str(out / f"frame_{k + 1:04d}.obj"))
        assert boundary_edges(triangles) == 0 and is_consistently_oriented(triangles)
