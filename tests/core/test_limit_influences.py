"""Limit Influences (thesis section 6.4) on numpy arrays: zero cost for redundant influences, never worse than
Blender's Limit Total on animated error, the limit honoured, bad input refused."""
import numpy as np
import pytest
from tests.core.test_metrics import joint_samples, world_frames

from skinkit import AnimationSpaceModel, Skeleton, SkinkitError, SparseWeights, convert_lbs
from skinkit.lod import limit_influences
from skinkit.lod.influences import (SAMPLE_WEIGHTS, choose_sample_weight, largest_weight_projection, limit_total,
                                   nearest_linear_blend, sampled_metric, statistics_metric)
from skinkit.metrics import PoseStatistics

CHAIN = np.array([-1, 0, 1, 2, 3, 4, 5, 6])


def chain_rig(rng, pose_count, parents=CHAIN, max_degrees=60.0):
    """A chain along x with unit bones: rest frames, world poses (S, b, 4, 4) of random joint rotations."""
    b = len(parents)
    rest_local = np.tile(np.eye(4), (b, 1, 1))
    rest_local[1:, 0, 3] = 1.0
    rest_local[1, 0, 3] = 0.0
    rest = world_frames(rest_local[None], parents)[0]
    local = joint_samples(rng, pose_count, parents, translations=rest_local[:, :3, 3])
    angles = np.radians(max_degrees) * rng.uniform(-1, 1, (pose_count, b))
    axes = rng.normal(size=(pose_count, b, 3))
    axes /= np.linalg.norm(axes, axis=2, keepdims=True)
    for s in range(pose_count):
        for j in range(1, b):
            k = np.array([[0, -axes[s, j, 2], axes[s, j, 1]], [axes[s, j, 2], 0, -axes[s, j, 0]],
                          [-axes[s, j, 1], axes[s, j, 0], 0]])
            local[s, j, :3, :3] = np.eye(3) + np.sin(angles[s, j]) * k + (1 - np.cos(angles[s, j])) * k @ k
    local[:, 0] = np.eye(4)
    return rest, world_frames(local, parents)


def smooth_lbs(rng, rest, vertex_count=400, width=1.3):
    """Vertices along the chain with smooth weights over every bone (most vertices have 3 to 6 influences)."""
    b = len(rest)
    positions = np.column_stack([rng.uniform(0, b - 1.5, vertex_count), rng.normal(0, 0.2, (vertex_count, 2))])
    heads = rest[1:, :3, 3] + np.array([0.5, 0, 0])
    dense = np.zeros((vertex_count, b))
    dense[:, 1:] = np.exp(-((positions[:, None, 0] - heads[None, :, 0]) / width) ** 2)
    dense[dense < 0.02] = 0.0
    dense /= dense.sum(axis=1, keepdims=True)
    return positions, SparseWeights.from_dense(dense)


def animated_error(model_positions, reference) -> tuple[float, float]:
    distance = np.linalg.norm(model_positions - reference, axis=-1)
    return float(np.sqrt(np.mean(distance ** 2))), float(distance.max())


@pytest.fixture
def smooth_problem():
    rng = np.random.default_rng(7)
    rest, training = chain_rig(rng, 200)
    _, test_poses = chain_rig(np.random.default_rng(8), 60)
    skeleton = Skeleton.create(CHAIN, rest)
    positions, weights = smooth_lbs(rng, rest)
    model = convert_lbs(skeleton, weights, positions)
    statistics = PoseStatistics.from_world_samples(CHAIN, training)
    return skeleton, positions, weights, model, statistics, test_poses


def test_redundant_influences_of_a_rigid_model_cost_nothing_and_change_no_pose():
    """Bones 2 and 3 never move against bone 1 (a rigid block), and a zero influence on bone 4: each vertex's p
    spread over them can lose all but one at zero cost, and the model deforms exactly as before."""
    rng = np.random.default_rng(3)
    parents = np.array([-1, 0, 1, 2, 3])
    local = joint_samples(rng, 50, parents, translations=np.array([[0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0],
                                                                     [1, 0, 0]]))
    local[:, 2, :3, :3] = np.eye(3)  # bones 2 and 3 are rigidly fixed to bone 1
    local[:, 3, :3, :3] = np.eye(3)
    poses = world_frames(local, parents)
    statistics = PoseStatistics.from_world_samples(parents, poses)
    rest = poses[0]
    vertex_count = 30
    points = rng.normal(size=(vertex_count, 3))
    split = rng.dirichlet(np.ones(3), vertex_count)  # the rigid point's weight spread over bones 1, 2, 3
    offsets = np.arange(0, 4 * vertex_count + 1, 4, dtype=np.int32)
    bones = np.tile(np.array([1, 2, 3, 4], np.int32), vertex_count)
    coordinates = np.zeros((vertex_count, 4, 4))
    for slot, bone in enumerate((1, 2, 3)):
        local_point = np.linalg.inv(rest[bone]) @ np.column_stack([points, np.ones(vertex_count)]).T
        coordinates[:, slot] = (local_point.T * split[:, slot:slot + 1])
    model = AnimationSpaceModel.create(offsets, bones, coordinates.reshape(-1, 4), len(parents))
    limited, costs = limit_influences(model, statistics, 1)
    assert np.all(limited.counts() == 1)
    assert costs.max() < 1e-6
    scale = np.abs(model.evaluate(poses)).max()
    assert np.abs(limited.evaluate(poses) - model.evaluate(poses)).max() < 1e-6 * scale
    assert np.allclose(limited.homogeneous_weights(), 1.0)


@pytest.mark.parametrize("max_influences", [1, 2, 3, 4])
def test_never_worse_than_limit_total_on_animated_error(smooth_problem, max_influences):
    skeleton, positions, weights, model, statistics, test_poses = smooth_problem
    assert model.counts().max() > max_influences
    reference = model.evaluate(test_poses)
    limited, costs = limit_influences(model, statistics, max_influences)
    assert limited.counts().max() <= max_influences
    assert np.allclose(limited.homogeneous_weights(), 1.0)
    ours = animated_error(limited.evaluate(test_poses), reference)
    blender = animated_error(convert_lbs(skeleton, limit_total(weights, max_influences), positions)
                             .evaluate(test_poses), reference)
    assert ours[0] <= blender[0], (ours, blender)
    # The costs are the RMS distance each vertex moves under the statistics' poses.
    assert np.all(costs >= 0) and np.all(costs[model.counts() <= max_influences] == 0)


@pytest.mark.parametrize("max_influences", [2, 4])
def test_the_largest_weight_projection_gives_the_same_bits_in_any_chunking(smooth_problem, max_influences):
    """Its dense systems are formed a chunk of rows at a time (memory O(influences)); each row's solve is its own,
    so chunks of 1, 7 and all rows agree bit for bit, and only the vertices over the limit are projected."""
    _, _, _, model, statistics, _ = smooth_problem
    blocks = statistics_metric(statistics)
    rows, whole, costs = largest_weight_projection(model, blocks, max_influences, chunk_rows=model.vertex_count)
    assert np.array_equal(rows, np.flatnonzero(model.counts() > max_influences)) and len(rows) > 7
    assert whole.vertex_count == len(rows) and whole.counts().max() == max_influences
    for chunk_rows in (1, 7, None):
        _, chunked, chunked_costs = largest_weight_projection(model, blocks, max_influences, chunk_rows=chunk_rows)
        assert np.array_equal(chunked.offsets, whole.offsets) and np.array_equal(chunked.bones, whole.bones)
        assert np.array_equal(chunked.coordinates, whole.coordinates) and np.array_equal(chunked_costs, costs)
    # Each row keeps its largest homogeneous weights, with the weights' total kept.
    assert np.allclose(np.add.reduceat(whole.coordinates[:, 3], whole.offsets[:-1]), 1.0)
    for row, vertex in list(enumerate(rows))[::5]:
        weights = model.coordinates[model.offsets[vertex]:model.offsets[vertex + 1], 3]
        largest = set(model.bones[model.offsets[vertex]:model.offsets[vertex + 1]][
            np.argsort(-weights, kind="stable")[:max_influences]])
        assert set(whole.bones[whole.offsets[row]:whole.offsets[row + 1]]) == largest


def test_limit_influences_gives_the_same_bits_whatever_blas_threads_it_is_given():
    """The core's LAPACK solves of each removal and the largest-weight projection's numpy solves of its
    (4w + 1)-square KKT systems: from about 25 influences per vertex OpenBLAS threads them and, with 2 threads
    instead of 1, the limited coordinates differed in the last bits (as the creature's did; this case needed the core's
    solves limited too). Now both run one BLAS thread."""
    from threadpoolctl import threadpool_limits

    chain = np.arange(-1, 29)
    rng = np.random.default_rng(7)
    rest, training = chain_rig(rng, 40, parents=chain)
    positions, weights = smooth_lbs(rng, rest, vertex_count=20, width=8.0)
    model = convert_lbs(Skeleton.create(chain, rest), weights, positions)
    assert model.counts().max() >= 25
    statistics = PoseStatistics.from_world_samples(chain, training)
    results = []
    for blas_threads in (1, 2):
        with threadpool_limits(limits=blas_threads, user_api="blas"):
            limited, costs = limit_influences(model, statistics, 4)
            results.append((limited.coordinates.tobytes(), costs.tobytes()))
    assert results[0] == results[1]


def test_vertices_within_the_limit_are_copied_and_the_kept_bones_keep_their_order(smooth_problem):
    _, _, _, model, statistics, _ = smooth_problem
    limited, _ = limit_influences(model, statistics, 3)
    for vertex in range(0, model.vertex_count, 7):
        before = model.bones[model.offsets[vertex]:model.offsets[vertex + 1]]
        after = limited.bones[limited.offsets[vertex]:limited.offsets[vertex + 1]]
        assert list(after) == [b for b in before if b in set(after)]
        if len(before) <= 3:
            assert np.array_equal(limited.coordinates[limited.offsets[vertex]:limited.offsets[vertex + 1]],
                                  model.coordinates[model.offsets[vertex]:model.offsets[vertex + 1]])


def test_tangents_follow_the_position_removals(smooth_problem):
    skeleton, positions, weights, model, statistics, test_poses = smooth_problem
    tangent = convert_lbs(skeleton, weights, np.tile([0.0, 1.0, 0.0], (len(positions), 1)), homogeneous=0.0)
    limited, costs, (limited_tangent,) = limit_influences(model, statistics, 2, tangents=[tangent])
    assert np.array_equal(limited_tangent.offsets, limited.offsets)
    assert np.array_equal(limited_tangent.bones, limited.bones)
    assert np.allclose(limited_tangent.homogeneous_weights(), 0.0, atol=1e-12)
    alone, alone_costs = limit_influences(model, statistics, 2)
    assert np.array_equal(alone.coordinates, limited.coordinates) and np.array_equal(alone_costs, costs)


def test_limit_total_reproduces_blender_on_a_small_case():
    weights = SparseWeights.create([0, 3, 4], [1, 2, 3, 2], [0.2, 0.5, 0.3, 1.0], 4)
    limited = limit_total(weights, 2)
    assert list(limited.offsets) == [0, 2, 3]
    assert list(limited.bones) == [2, 3, 2] and np.allclose(limited.weights, [0.625, 0.375, 1.0])


def test_nearest_linear_blend_weights_reproduce_a_linear_blend_model(smooth_problem):
    skeleton, positions, weights, model, statistics, _ = smooth_problem
    nearest = nearest_linear_blend(model, statistics, skeleton.rest_frames, positions)
    assert np.allclose(nearest.weights, weights.weights, atol=1e-6)
    limited, _ = limit_influences(model, statistics, 2)
    blended = nearest_linear_blend(limited, statistics, skeleton.rest_frames, positions)
    assert np.all(blended.weights >= 0) and np.allclose(blended.totals(), 1.0)


@pytest.mark.parametrize("bad, message", [(0, "at least 1"), (-3, "at least 1"), (2.5, "whole number"),
                                          (True, "whole number")])
def test_bad_limits_are_refused(smooth_problem, bad, message):
    _, _, _, model, statistics, _ = smooth_problem
    with pytest.raises(SkinkitError, match=f"max_influences: .*{message}"):
        limit_influences(model, statistics, bad)


def test_mismatched_statistics_and_models_are_refused(smooth_problem):
    _, _, weights, model, statistics, _ = smooth_problem
    other = PoseStatistics.fixed_skeleton(np.array([-1, 0]), np.tile(np.eye(4), (2, 1, 1)))
    with pytest.raises(SkinkitError, match="statistics: 2 bones, the model has 8"):
        limit_influences(model, other, 2)
    with pytest.raises(SkinkitError, match="model: expected"):
        limit_influences(weights, statistics, 2)
    with pytest.raises(SkinkitError, match=r"tangents\[0\]"):
        limit_influences(model, statistics, 2, tangents=[weights])


def test_cancelling_stops_it(smooth_problem):
    _, _, _, model, statistics, _ = smooth_problem
    with pytest.raises(SkinkitError, match="cancel"):
        limit_influences(model, statistics, 1, progress=lambda fraction: True)


# ---- the sampled metric (issue 11: the joint statistics multiply per-joint expectations as if joints were independent)


def curling_rig(rng, pose_count):
    """The chain's joints all bend by the same random angle about z in each pose (a curl): strongly correlated
    joints, which the independent-joint statistics cannot describe."""
    b = len(CHAIN)
    rest_local = np.tile(np.eye(4), (b, 1, 1))
    rest_local[2:, 0, 3] = 1.0
    local = np.tile(rest_local, (pose_count, 1, 1, 1))
    angles = rng.uniform(-1.0, 1.0, pose_count)
    c, s = np.cos(angles), np.sin(angles)
    for j in range(1, b):
        local[:, j, 0, 0], local[:, j, 0, 1], local[:, j, 1, 0], local[:, j, 1, 1] = c, -s, s, c
    return world_frames(rest_local[None], CHAIN)[0], world_frames(local, CHAIN)


def constrained_least_squares(poses, kept_bones, target, weight_total):
    """Brute force: the 4-vectors q_j (j in kept_bones) minimising sum_s |sum_j G_j(s) q_j - target(s)|^2 over the
    poses (3 rows of each G), subject to sum_j (q_j)_w = weight_total, by a KKT system (least squares, minimum
    norm for ties)."""
    n = 4 * len(kept_bones)
    design = np.concatenate([poses[:, kept_bones, :3, :].transpose(0, 2, 1, 3).reshape(len(poses) * 3, n)])
    constraint = np.tile([0, 0, 0, 1.0], len(kept_bones))
    system = np.block([[design.T @ design, constraint[:, None]], [constraint[None], np.zeros((1, 1))]])
    right = np.concatenate([design.T @ target.reshape(-1), [weight_total]])
    return np.linalg.lstsq(system, right, rcond=1e-13)[0][:n]


def test_the_sampled_metric_refit_is_the_least_squares_fit_over_those_poses(smooth_problem):
    """With sample_weight 1 each limited vertex is the constrained least-squares refit of its kept bones to the
    unlimited model over the given poses, and its cost the RMS distance over them."""
    _, _, _, model, statistics, test_poses = smooth_problem
    poses = test_poses[:25]
    limited, costs = limit_influences(model, statistics, 2, poses=poses, sample_weight=1.0)
    reference = model.evaluate(poses)
    ours = limited.evaluate(poses)
    scale = np.abs(reference).max()
    over = np.flatnonzero(model.counts() > 2)
    assert len(over) > 100
    for v in over[:40]:
        kept = limited.bones[limited.offsets[v]:limited.offsets[v + 1]]
        q = constrained_least_squares(poses, kept, reference[:, v], model.homogeneous_weights()[v])
        brute = np.einsum("sjab,jb->sa", poses[:, kept, :3, :], q.reshape(-1, 4))
        assert np.abs(ours[:, v] - brute).max() < 1e-8 * scale
        rms = np.sqrt(np.mean(np.sum((ours[:, v] - reference[:, v]) ** 2, axis=-1)))
        assert abs(costs[v] - rms) < 1e-8 * scale


def test_sampled_metric_blocks_are_the_second_moments_of_the_poses(smooth_problem):
    *_, test_poses = smooth_problem
    blocks = sampled_metric(test_poses[:7])
    expected = np.mean([pose[2].T @ pose[5] for pose in test_poses[:7]], axis=0)
    assert np.allclose(blocks[2, 5], expected) and np.allclose(blocks[5, 2], expected.T)


def test_correlated_joints_are_limited_better_with_the_poses():
    """A curling chain: the poses' own metric, chosen by validation on the training poses, generalises to held-out
    curls better than the independent-joint statistics (and validation never picks a weight that is worse on its
    folds than the statistics alone)."""
    rng = np.random.default_rng(11)
    rest, training = curling_rig(rng, 40)
    _, held_out = curling_rig(np.random.default_rng(12), 30)
    positions, weights = smooth_lbs(rng, rest)
    model = convert_lbs(Skeleton.create(CHAIN, rest), weights, positions)
    statistics = PoseStatistics.from_world_samples(CHAIN, training)
    weight, errors = choose_sample_weight(model, CHAIN, training, 2)
    assert weight in SAMPLE_WEIGHTS and set(errors) == set(SAMPLE_WEIGHTS)
    assert errors[weight] == min(errors.values()) and errors[weight] <= errors[0.0]
    assert weight > 0
    reference = model.evaluate(held_out)
    before = animated_error(limit_influences(model, statistics, 2)[0].evaluate(held_out), reference)[0]
    after = animated_error(limit_influences(model, statistics, 2, poses=training)[0].evaluate(held_out), reference)[0]
    assert after < 0.8 * before, (after, before)


def test_one_pose_cannot_be_validated_so_the_statistics_are_kept(smooth_problem):
    _, _, _, model, statistics, test_poses = smooth_problem
    assert choose_sample_weight(model, CHAIN, test_poses[:1], 2) == (0.0, {})


@pytest.mark.parametrize("arguments, message", [
    (dict(sample_weight=0.5), "sample_weight: needs the poses"),
    (dict(poses="rest", sample_weight=0.5), "poses"),
    (dict(poses=np.tile(np.eye(4), (3, 2, 1, 1))), "poses: 2 bones, the model has 8"),
    (dict(poses=np.zeros((0, 8, 4, 4))), "poses: at least one pose"),
    (dict(poses=np.tile(np.eye(4), (3, 8, 1, 1)), sample_weight=1.5), r"sample_weight: expected a number in \[0, 1\]"),
    (dict(poses=np.tile(np.eye(4), (3, 8, 1, 1)), sample_weight=True), "sample_weight: expected")])
def test_bad_poses_and_sample_weights_are_refused(smooth_problem, arguments, message):
    _, _, _, model, statistics, _ = smooth_problem
    with pytest.raises(SkinkitError, match=message):
        limit_influences(model, statistics, 2, **arguments)
