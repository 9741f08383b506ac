"""The scale benchmark's synthetic creature (scripts/make_large_character.py): the size asked for, 100 bones in one
hierarchy, 8 normalised influences per vertex, a valid oriented surface, per-corner UVs inside the unit square
with one strip per tube, and the same character every time."""
import os
import sys

import numpy as np
import pytest

import skinkit
from skinkit import _core

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "scripts"))
import make_large_character as character  # noqa: E402


@pytest.fixture(scope="module")
def creature():
    return character.make_character(12_000, pose_count=6)


def test_size_bones_and_influences(creature):
    rest, weights, skeleton = creature["rest"], creature["weights"], creature["skeleton"]
    assert abs(len(rest) - 12_000) < 0.02 * 12_000
    assert skeleton.bone_count == 100 and (skeleton.parents < 0).sum() == 1
    assert all(skeleton.parents[j] < j for j in range(1, 100))  # parents first: one tree
    assert np.all(np.diff(weights.offsets) == 8)
    assert np.allclose(np.add.reduceat(weights.weights, weights.offsets[:-1]), 1.0)
    assert weights.weights.min() > 0


def test_surface_and_uvs(creature):
    triangles, uv = creature["triangles"], creature["corner_uv"]
    _core.validate_triangles(triangles, len(creature["rest"]))
    assert len(uv) == len(triangles) and uv.min() > 0 and uv.max() < 1
    for tube in range(character.TUBES):  # each tube's strip of the square, apart from the others
        u = uv[creature["charts"] == tube][:, 0::2]
        assert tube / character.TUBES < u.min() and u.max() < (tube + 1) / character.TUBES
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    _, uses = np.unique(edges, axis=0, return_counts=True)
    assert uses.max() == 2  # manifold: open tubes, every edge in one or two triangles


def test_examples_are_the_poses_by_linear_blend_skinning(creature):
    expected = skinkit.lbs_evaluate(creature["skeleton"], creature["weights"], creature["rest"], creature["poses"])
    assert np.allclose(creature["examples"], expected)
    assert np.abs(creature["examples"] - creature["rest"]).max() > 0.1  # the poses move it
    at_rest = skinkit.lbs_evaluate(creature["skeleton"], creature["weights"], creature["rest"],
                                   creature["skeleton"].rest_frames)
    assert np.allclose(at_rest, creature["rest"])  # the bones' frames and the weights agree on the rest pose


def test_deterministic():
    first, second = character.make_character(3000, pose_count=2), character.make_character(3000, pose_count=2)
    for key in ("rest", "triangles", "corner_uv", "poses", "examples"):
        assert np.array_equal(first[key], second[key]), key
