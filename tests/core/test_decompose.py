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


def blended_angle_sequence(frame_count=16, seed=5):
    """A two-part tube bent by each vertex's own angle, weight x the bend (as dual-quaternion skinning blends):
    linear blend skinning cannot reproduce it, animation space can come closer."""
    positions, triangles, _ = tube(2, rings_per_segment=8)
    weight = np.clip((positions[:, 1] - 0.6) / 0.8, 0, 1)
    rng = np.random.default_rng(seed)
    frames = [positions]
    hinge = np.array([0.0, 1.0, 0.0])
    for _ in range(frame_count - 1):
        axis, angle = [1, 0, rng.uniform(-0.3, 0.3)], rng.uniform(-1.2, 1.2)
        moved = np.empty_like(positions)
        for index, (point, w) in enumerate(zip(positions, weight)):
            moved[index] = rotation(axis, w * angle) @ (point - hinge) + hinge
        frames.append(moved)
    return np.array(frames), triangles


def test_animation_space_gets_its_own_influence_sets_and_refined_frames(monkeypatch):
    import skinkit.decompose as module

    frames, triangles = blended_angle_sequence()
    refined = decompose(frames, triangles, bone_count=3, max_influences=3)
    monkeypatch.setattr(module, "REFIT_ROUNDS", 1)
    first_round = decompose(frames, triangles, bone_count=3, max_influences=3)
    assert refined.report["animation_influences"] == 3 and not refined.report["fallback"]
    assert np.diff(refined.model.offsets).min() == 3  # filled up to K, beyond the linear-blend weights' bones
    assert np.diff(refined.linear_blend.offsets).min() < 3
    rms = {name: result.report["animation_space"]["train"]["rms"]
           for name, result in (("refined", refined), ("first", first_round))}
    assert rms["refined"] < rms["first"]
    assert rms["refined"] < 0.5 * refined.report["linear_blend"]["train"]["rms"]
    # the stored training poses are the animation-space model's: they reproduce its report
    replay = refined.model.evaluate(refined.training_poses)
    diagonal = np.linalg.norm(np.ptp(frames[0], axis=0))
    assert np.sqrt((((replay - frames) ** 2).sum(-1)).mean()) / diagonal == pytest.approx(rms["refined"])


def test_animation_influences_keep_the_weights_and_add_zero_weighted_bones():
    from skinkit.decompose import animation_influences, cluster_motions
    from skinkit.model import SparseWeights

    frames, triangles = blended_angle_sequence(8)
    labels = np.where(frames[0][:, 1] < 1.0, 1, 2).astype(np.int32)
    motions = cluster_motions(frames[0], frames, labels, 4)
    weights = SparseWeights(np.arange(len(labels) + 1, dtype=np.int32), labels, np.ones(len(labels)))
    filled = animation_influences(frames[0], frames, motions, weights, 4, 2)
    assert (np.diff(filled.offsets) == 2).all()
    dense = np.zeros((len(labels), 4))
    dense[filled.vertex_of_each_influence(), filled.bones] = filled.weights
    assert np.allclose(dense[np.arange(len(labels)), labels], 1.0) and np.allclose(dense.sum(axis=1), 1.0)
    assert not (dense[:, 0] > 0).any()  # never the static root
    assert animation_influences(frames[0], frames[:2], motions[:2], weights, 4, 3) is weights  # too few frames


def test_trajectory_clusters_give_the_same_labels_in_any_row_chunking(chain, monkeypatch):
    """The k-means works through the vertices in row chunks (its temporaries stay in cache); rows are independent,
    so chunks of one row and of the whole mesh give the same labels, and each rigid segment falls in its own
    clusters."""
    from skinkit import decompose as module
    frames, _, segment, _ = chain
    whole = module.trajectory_clusters(frames[0], frames, 6, np.random.default_rng(5))
    monkeypatch.setattr(module, "CLUSTER_CHUNK_BYTES", 1)  # one row at a time
    assert np.array_equal(module.trajectory_clusters(frames[0], frames, 6, np.random.default_rng(5)), whole)
    assert len(np.unique(whole)) == 6
    for label in np.unique(whole):  # motion-coherent: no cluster spans two rigid segments
        assert len(np.unique(segment[whole == label])) == 1
