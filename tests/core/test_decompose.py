"""Skinning a mesh sequence without a rig (skinkit.decompose), on sequences made from known rigs."""
import numpy as np
import pytest
from tests.sequences import rigid_chain_sequence, rotation, tube

from skinkit import SkinkitError, _core
from skinkit.decompose import decompose, fit_rough_rig, solve_sequence


@pytest.fixture(scope="module")
def chain():
    return rigid_chain_sequence(segments=3, frames=12)


@pytest.fixture(scope="module")
def chain_result(chain):
    frames, triangles, _, _ = chain
    return decompose(frames[:8], triangles, bone_count=3, max_influences=2)


def test_a_rigid_chain_is_recovered_to_near_zero_error(chain, chain_result):
    frames = chain[0]
    assert chain_result.skeleton.bone_count == 4  # the static root and three bones
    for kind in ("animation", "linear"):
        assert chain_result.errors(frames[:8], kind)["max"] < 1e-6
        assert chain_result.errors(frames[8:], kind)["max"] < 1e-6  # held out: poses solved, model fixed


def test_rigid_pieces_map_to_one_bone_each(chain, chain_result):
    segment = chain[2]
    interior = np.abs(chain[0][0][:, 1] - np.round(chain[0][0][:, 1])) > 1e-9  # not on a joint ring
    pairs = {(int(s), int(label)) for s, label in zip(segment[interior], chain_result.labels[interior])}
    assert len(pairs) == 3 and len({label for _, label in pairs}) == 3


def test_the_hierarchy_links_touching_segments_and_joints_sit_at_the_hinges(chain, chain_result):
    skeleton, segment, rest = chain_result.skeleton, chain[2], chain[0][0]
    bone_of_segment = [int(np.bincount(chain_result.labels[segment == s]).argmax()) for s in range(3)]
    links = {frozenset((bone, int(skeleton.parents[bone]))) for bone in range(1, 4) if skeleton.parents[bone] > 0}
    assert links == {frozenset(bone_of_segment[:2]), frozenset(bone_of_segment[1:])}
    for bone in range(1, 4):
        parent = int(skeleton.parents[bone])
        if parent > 0:  # the joint is on the tube's axis at the hinge the two segments share (eq. 4.6)
            hinge = 1 + min(bone_of_segment.index(bone), bone_of_segment.index(parent))
            assert np.allclose(skeleton.rest_frames[bone, :3, 3], [0, hinge, 0], atol=2e-2)
    assert np.isclose(rest[:, 1].max(), 3.0)


def test_bone_frames_are_rigid(chain_result):
    linear = chain_result.training_poses[:, 1:, :3, :3]
    gram = np.einsum("fbki,fbkj->fbij", linear, linear)
    assert np.allclose(gram, np.eye(3), atol=1e-9)


def test_rough_rig_recovers_the_chain(chain):
    frames, triangles, segment, _ = chain
    rest = frames[0]
    cores = [np.zeros(0, int)] + [np.flatnonzero((segment == s) & (np.abs(rest[:, 1] - (s + 0.5)) < 0.3))
                                  for s in range(3)]
    rough_joints = np.array([[0, 0, 0], [0.05, 0.1, 0], [0, 1.1, 0.05], [0.1, 1.9, 0]])
    result = fit_rough_rig(frames[:8], triangles, [-1, 0, 1, 2], rough_joints, cores)
    assert result.errors(frames[8:])["max"] < 1e-6
    assert np.allclose(result.skeleton.rest_frames[2:, :3, 3], [[0, 1, 0], [0, 2, 0]], atol=2e-2)


def test_a_smoothly_skinned_sequence_is_recovered_to_near_zero_error():
    """Linear blend skinning with smooth weights between two bones is found again, both models."""
    positions, triangles, _ = tube(2, rings_per_segment=8)
    weight = np.clip((positions[:, 1] - 0.6) / 0.8, 0, 1)
    rng = np.random.default_rng(3)
    frames = [positions]
    for _ in range(11):
        bend = np.eye(4)
        bend[:3, :3] = rotation([1, 0, rng.uniform(-0.3, 0.3)], rng.uniform(-1.0, 1.0))
        bend[:3, 3] = np.array([0, 1, 0]) - bend[:3, :3] @ np.array([0, 1, 0])
        moved = positions @ bend[:3, :3].T + bend[:3, 3]
        frames.append((1 - weight)[:, None] * positions + weight[:, None] * moved)
    frames = np.array(frames)
    _, _, replay, report = solve_sequence(frames, triangles, np.ones(len(frames), bool), bones=2, max_influences=2)
    assert report["linear_blend"]["train"]["max"] < 1e-4 and report["animation_space"]["train"]["max"] < 1e-4
    assert report["bones"] == 2


@pytest.mark.parametrize("change, message", [
    (lambda f, t: (f[:1], t, {}), "at least 2"),
    (lambda f, t: (f, t, {"rest": f[0][:-1]}), "vertices"),
    (lambda f, t: (f[:, :-3], t, {}), "index"),
    (lambda f, t: (f, t, {"bone_count": 10 ** 6}), "between 1 and the vertex count"),
    (lambda f, t: (f, t, {"max_influences": 0}), "at least 1"),
])
def test_bad_input_is_refused_clearly(chain, change, message):
    frames, triangles, _, _ = chain
    frames, triangles, options = change(frames, triangles)
    arguments = {"bone_count": 3} | options
    with pytest.raises((SkinkitError, _core.Error), match=message):
        decompose(frames, triangles, **arguments)


def test_different_vertex_counts_are_refused(chain):
    frames, triangles, _, _ = chain
    ragged = [frames[0], frames[1][:-1]]
    with pytest.raises((SkinkitError, ValueError)):
        decompose(ragged, triangles, bone_count=3)


def test_degenerate_core_sets_are_refused(chain):
    frames, triangles, segment, _ = chain
    rest = frames[0]
    on_a_line = np.flatnonzero((np.abs(rest[:, 0] - 0.15) < 1e-9) & (segment == 1))  # one column of the tube
    cores = [[], np.flatnonzero(segment == 0), on_a_line, np.flatnonzero(segment == 2)]
    with pytest.raises(_core.Error, match="bone 2.*line"):
        fit_rough_rig(frames, triangles, [-1, 0, 1, 2], np.zeros((4, 3)), cores)
    with pytest.raises(_core.Error, match="bone 1: 2 core vertices"):
        fit_rough_rig(frames, triangles, [-1, 0, 1, 2], np.zeros((4, 3)), [[], [0, 1], cores[2], cores[3]])
