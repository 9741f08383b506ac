"""`skinkit lod --sequence`: a bare .obj sequence decomposed, then its levels built and exported frame by frame in the
sequence's numbering and units; a --rest .obj's vt is the UV map every level keeps."""
import os

import numpy as np
import pytest
from tests.cli.obj_folders import write_obj_folder
from tests.cli.test_cli import skinkit
from tests.sequences import rigid_chain_sequence

from skinkit.meshio import read_obj, read_obj_texture_corners, read_text_lines, write_obj

SEGMENTS, FRAMES, SIDES, RINGS_PER_SEGMENT = 3, 10, 10, 4


def cylinder_uv(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(T, 3, 2) corner UVs: the side unrolled (angle, height) with one seam, each cap a disc of its own."""
    height = positions[:, 1] / positions[:, 1].max()
    angle = np.mod(np.arctan2(positions[:, 2], positions[:, 0]), 2 * np.pi) / (2 * np.pi)
    side_count = 2 * SEGMENTS * RINGS_PER_SEGMENT * SIDES
    corner_uv = np.zeros(triangles.shape + (2,))
    side = triangles[:side_count]
    u = angle[side]
    u = np.where((u.max(axis=1, keepdims=True) > 0.75) & (u < 0.25), u + 1.0, u)  # the triangles across the seam
    corner_uv[:side_count] = np.stack([0.5 * u, height[side]], axis=-1)
    for index in range(side_count, len(triangles)):
        cap_top = positions[triangles[index], 1].max() > 0.5 * positions[:, 1].max()
        xz = positions[triangles[index]][:, [0, 2]]
        corner_uv[index] = 0.5 + 0.25 * np.array([1.0 if cap_top else 0.0, 0.0]) + xz
    return corner_uv


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    frames, triangles, _, _ = rigid_chain_sequence(segments=SEGMENTS, frames=FRAMES)
    folder = tmp_path_factory.mktemp("lod_sequence")
    frame_folder = folder / "frames"
    frame_folder.mkdir()
    write_obj_folder(frame_folder, frames[1:], triangles)
    rest = str(folder / "rest.obj")
    write_obj(rest, frames[0] * 100.0, triangles, cylinder_uv(frames[0], triangles))
    return str(frame_folder), rest, frames, triangles


def test_a_bare_sequence_becomes_levels_exported_in_its_numbering(sequence, tmp_path):
    folder, _, frames, _ = sequence
    exported = tmp_path / "levels"
    _, result = skinkit("lod", "--sequence", folder, "--bones", str(SEGMENTS), "--sequence-scale", "0.01",
                        "--levels", "3", "--export-frames", str(exported), "--json")
    levels = result["levels"]
    assert [row["level"] for row in levels] == [0, 1, 2]
    # each level at most half the influences of the one before (here the rigid tube's redundant ones go first)
    assert all(coarser["influences"] <= finer["influences"] // 2 for finer, coarser in zip(levels, levels[1:]))
    assert levels[0]["triangles"] >= levels[1]["triangles"] >= levels[2]["triangles"]
    assert result["frames"] == FRAMES - 1
    assert any("no UV" in warning for warning in result["warnings"])  # no --rest .obj: no atlas, and it says so
    for row in levels:
        files = sorted(os.listdir(exported / f"lod{row['level']}"))
        assert files == [f"{n:04d}.obj" for n in range(1, FRAMES)]
    # LOD0 is the decomposed input: posed, it reproduces the sequence's frames in their own units
    posed, faces = read_obj(str(exported / "lod0" / "0005.obj"))
    assert faces.shape == (levels[0]["triangles"], 3)
    assert np.abs(posed / 100.0 - frames[5]).max() < 1e-3
    coarse, _ = read_obj(str(exported / "lod2" / "0005.obj"))
    assert len(coarse) == levels[2]["vertices"] and np.isfinite(coarse).all()


def test_the_rest_objs_uvs_are_the_atlas_of_every_level(sequence, tmp_path):
    folder, rest, _, triangles = sequence
    exported = tmp_path / "levels"
    _, result = skinkit("lod", "--sequence", folder, "--bones", str(SEGMENTS), "--sequence-scale", "0.01",
                        "--rest", rest, "--levels", "2", "--no-influence-simplification", "--export-frames", str(exported), "--frames", "2:3",
                        "--json")
    assert not any("no UV" in warning for warning in result["warnings"])
    rest_uv = {tuple(np.round(uv, 6)) for uv in cylinder_uv(read_obj(rest)[0] / 100.0, triangles).reshape(-1, 2)}
    for level in ("lod0", "lod1"):
        assert sorted(os.listdir(exported / level)) == ["0002.obj", "0003.obj"]
        path = str(exported / level / "0003.obj")
        corners = read_obj_texture_corners(path)
        assert len(corners) and corners.min() >= 0
        texture = np.array([line.split()[1:3] for line in read_text_lines(path) if line.startswith("vt ")], float)
        assert {tuple(np.round(uv, 6)) for uv in texture} <= rest_uv  # surviving vertices keep their UVs
    assert result["levels"][1]["triangles"] < result["levels"][0]["triangles"]


@pytest.mark.parametrize("arguments, message", [
    (["--levels", "2"], "--bones"),
    (["--bones", "3", "--levels", "2", "--frames", "2:3"], "--export-frames"),
    (["--bones", "3", "--levels", "2", "--object", "x"], "one or the other"),
])
def test_sequence_mistakes_are_refused(sequence, arguments, message):
    status, result = skinkit("lod", "--sequence", sequence[0], *arguments, "--json", expect_success=False)
    assert status != 0 and message in result["error"]


def test_neither_scene_nor_sequence_is_refused():
    status, result = skinkit("lod", "--levels", "2", "--json", expect_success=False)
    assert status != 0 and "--sequence" in result["error"]



def test_a_spread_prices_the_poses_around_the_sequences_and_changes_the_levels(sequence):
    folder = sequence[0]
    common = ("lod", "--sequence", folder, "--bones", str(SEGMENTS), "--levels", "3", "--json")
    _, plain = skinkit(*common)
    _, spread = skinkit(*common, "--spread", "20")
    assert spread["spread_degrees"] == 20 and plain["spread_degrees"] == 0
    # the turned rotations bend the tube where its frames do not: a collapse that was free may now cost something
    assert [row["error"] for row in spread["levels"]] != [row["error"] for row in plain["levels"]]


@pytest.mark.parametrize("arguments, message", [
    (["--sequence", "SEQUENCE", "--bones", "3", "--spread", "200"], "--spread"),
    (["missing.blend", "--spread", "5"], "skinkit stats --spread"),
])
def test_spread_mistakes_are_refused(sequence, arguments, message):
    arguments = [sequence[0] if argument == "SEQUENCE" else argument for argument in arguments]
    status, result = skinkit("lod", *arguments, "--levels", "2", "--json", expect_success=False)
    assert status != 0 and message in result["error"]
