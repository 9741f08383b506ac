"""The animation-space metrics: pose statistics, P by the common-ancestor recursion, mean distances,
max-distance bounds, null space, analytic models (property-based where it fits)."""
import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tests.core.test_model import random_rotations

from skinkit import SkinkitError
from skinkit.metrics import PoseStatistics, SparseVectors, pixel_tolerance

PARENTS = np.array([-1, 0, 1, 1, 2])


def joint_samples(rng, count, parents=PARENTS, translations=None, scale=(1.0, 1.0)):
    """(count, b, 4, 4) local joint matrices: random rotations (and uniform scales), fixed or random translations."""
    b = len(parents)
    local = np.tile(np.eye(4), (count, b, 1, 1))
    local[:, :, :3, :3] = random_rotations(rng, count * b).reshape(count, b, 3, 3) * \
        rng.uniform(*scale, (count, b, 1, 1))
    local[:, :, :3, 3] = rng.normal(size=(count, b, 3)) if translations is None else translations
    local[:, 0] = np.eye(4)
    return local


def world_frames(local, parents=PARENTS):
    world = np.empty_like(local)
    for j in range(local.shape[1]):
        world[:, j] = local[:, j] if j == 0 else world[:, parents[j]] @ local[:, j]
    return world


def weight_zero_vectors(rng, count, b):
    dense = rng.normal(size=(count, b, 4))
    dense[:, :, 3] -= dense[:, :, 3].mean(axis=1, keepdims=True)
    return dense


def test_recursion_equals_brute_force_over_independently_sampled_joints():
    rng = np.random.default_rng(1)
    combinations = independent_combinations(joint_samples(rng, 3, scale=(0.7, 1.3)))
    statistics = PoseStatistics.from_local_samples(PARENTS, combinations)
    world = world_frames(combinations)
    brute = np.einsum("sjab,skac->jkbc", world, world) / len(world)  # E[G_j^T G_k]
    for j, k in itertools.product(range(len(PARENTS)), repeat=2):
        assert np.abs(statistics.block(j, k) - brute[j, k]).max() < 1e-10 * np.abs(brute).max()
    dense = weight_zero_vectors(rng, 20, len(PARENTS))
    expected = np.sqrt(np.mean(np.linalg.norm(np.einsum("sjab,njb->sna", world, dense)[..., :3], axis=2) ** 2, axis=0))
    assert np.allclose(statistics.mean_distance(SparseVectors.from_dense(dense)), expected, rtol=1e-10)


def test_expectation_matrix_is_positive_semidefinite_for_any_samples():
    """Regression: with diagonal blocks averaged over whole poses but cross blocks from the recursion, P was
    indefinite (98 negative eigenvalues on a 100-bone rig) and moving vectors got a mean distance of 0."""
    rng = np.random.default_rng(2)
    parents = np.array([-1, 0, 1, 2, 3, 1, 5, 0, 7, 8])
    statistics = PoseStatistics.from_local_samples(parents, joint_samples(rng, 30, parents, scale=(0.5, 2.0)))
    values = np.linalg.eigvalsh(statistics.matrix())
    assert values.min() >= -1e-10 * values.max()


def test_mean_distance_of_one_bone_equals_the_sample_mean_over_independent_joints():
    rng = np.random.default_rng(2)
    local = independent_combinations(joint_samples(rng, 3, scale=(0.5, 2.0)))
    statistics = PoseStatistics.from_local_samples(PARENTS, local)
    world = world_frames(local)
    dense = np.zeros((len(PARENTS), len(PARENTS), 4))
    for j in range(len(PARENTS)):
        dense[j, j, :3] = rng.normal(size=3)
    expected = np.sqrt(np.mean(np.linalg.norm(np.einsum("sjab,njb->sna", world, dense)[..., :3], axis=2) ** 2, axis=0))
    assert np.allclose(statistics.mean_distance(SparseVectors.from_dense(dense)), expected, rtol=1e-12)


def test_spread_prices_a_bend_no_example_shows():
    """Two bones that never move apart in the examples: the difference of one point carried by each has no length,
    until the spread turns bone 1 by +-spread about each of its axes. Point (1, 0, 0): the two turns about x leave
    it, the four about y and z move it by |R p - p|^2 = 2 - 2 cos(spread), so E = 4 (2 - 2 cos) / 7 over the 7
    samples."""
    parents = np.array([-1, 0])
    local = np.tile(np.eye(4), (3, 2, 1, 1))
    difference = np.zeros((1, 2, 4))
    difference[0, 1, 0], difference[0, 0, 0] = 1.0, -1.0
    vectors = SparseVectors.from_dense(difference)
    assert PoseStatistics.from_local_samples(parents, local).mean_distance(vectors)[0] < 1e-12
    spread = 0.3
    widened = PoseStatistics.from_local_samples(parents, local, spread=spread)
    assert np.isclose(widened.mean_distance(vectors)[0] ** 2, 4 * (2 - 2 * np.cos(spread)) / 7, rtol=1e-12)
    world = np.tile(np.eye(4), (3, 2, 1, 1))
    assert np.allclose(PoseStatistics.from_world_samples(parents, world, spread=spread).expected_gram,
                       widened.expected_gram, atol=1e-14)


def test_spread_keeps_the_bounds_and_zero_spread_changes_nothing():
    rng = np.random.default_rng(8)
    local = joint_samples(rng, 5, translations=rng.normal(size=(len(PARENTS), 3)))
    plain = PoseStatistics.from_local_samples(PARENTS, local)
    zero = PoseStatistics.from_local_samples(PARENTS, local, spread=0.0)
    widened = PoseStatistics.from_local_samples(PARENTS, local, spread=0.5)
    assert np.array_equal(plain.expected_gram, zero.expected_gram)
    assert np.allclose(widened.linear_bound, plain.linear_bound, rtol=1e-12)
    assert np.allclose(widened.translation_centre, plain.translation_centre)
    assert np.allclose(widened.translation_radius, plain.translation_radius)
    assert not np.allclose(widened.expected_gram, plain.expected_gram)
    for bad in (-0.1, float("nan"), 4.0, "wide"):
        with pytest.raises(SkinkitError, match="spread"):
            PoseStatistics.from_local_samples(PARENTS, local, spread=bad)


def test_null_vectors_of_fixed_translations_have_no_length():
    """Appendix B.3: with fixed joint translations there are b - 1 null vectors. Here t_i is L_i's translation,
    in the parent's frame, so r_i = (0, 0, 0, 1) with r_parent = (-t_i; -1): G_p L_i r_i = G_p (t_i; 1)."""
    rng = np.random.default_rng(3)
    translations = rng.normal(size=(len(PARENTS), 3))
    local = joint_samples(rng, 50, translations=translations)
    statistics = PoseStatistics.from_local_samples(PARENTS, local)
    dense = np.zeros((len(PARENTS) - 1, len(PARENTS), 4))
    for row, bone in enumerate(range(1, len(PARENTS))):
        dense[row, bone, 3] = 1.0
        dense[row, PARENTS[bone]] += np.r_[-translations[bone], -1.0]
    world = world_frames(local)
    assert np.abs(np.einsum("sjab,njb->sna", world, dense)).max() < 1e-12
    assert statistics.mean_distance(SparseVectors.from_dense(dense)).max() < 1e-6
    assert statistics.null_space().shape[1] >= len(PARENTS) - 1


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_max_distance_bounds_every_pose_within_the_bounds(seed):
    rng = np.random.default_rng(seed)
    centres = rng.normal(size=(len(PARENTS), 3))
    bounded = joint_samples(rng, 300, scale=(0.5, 1.5))
    offsets = rng.normal(size=(300, len(PARENTS), 3))
    offsets *= (rng.uniform(0, 0.4, (300, len(PARENTS), 1)) / np.linalg.norm(offsets, axis=2, keepdims=True))
    bounded[:, :, :3, 3] = centres + offsets
    bounded[:, 0] = np.eye(4)
    statistics = PoseStatistics.from_local_samples(PARENTS, bounded)
    dense = weight_zero_vectors(rng, 10, len(PARENTS))
    bound = statistics.max_distance(SparseVectors.from_dense(dense))
    reached = np.linalg.norm(np.einsum("sjab,njb->sna", world_frames(bounded), dense)[..., :3], axis=2).max(axis=0)
    assert np.all(reached <= bound * (1 + 1e-12))


def test_max_distance_bound_is_reached_by_a_worst_case():
    """A weight-only vector on a child of the root moves by w t: the bound |w| (|c| + r) is attained."""
    centre, radius, weight = np.array([1.0, 2.0, 2.0]), 0.5, -0.75
    statistics = PoseStatistics(np.array([-1, 0], np.int32), np.tile(np.eye(4), (2, 1, 1)), np.tile(np.eye(4), (2, 1, 1)),
                                np.ones(2), np.stack([np.zeros(3), centre]), np.array([0.0, radius]))
    vectors = SparseVectors.from_dense(np.array([[[0, 0, 0, -weight], [0, 0, 0, weight]]]))
    worst = centre + radius * centre / np.linalg.norm(centre)
    assert statistics.max_distance(vectors)[0] == pytest.approx(abs(weight) * np.linalg.norm(worst))


def test_fixed_skeleton_gives_the_rest_pose_distance():
    rng = np.random.default_rng(4)
    rest = joint_samples(rng, 1)[0]
    statistics = PoseStatistics.fixed_skeleton(PARENTS, rest)
    dense = weight_zero_vectors(rng, 5, len(PARENTS))
    world = world_frames(rest[None])[0]
    expected = np.linalg.norm(np.einsum("jab,njb->na", world, dense)[:, :3], axis=1)
    assert np.allclose(statistics.mean_distance(SparseVectors.from_dense(dense)), expected, rtol=1e-10)
    assert np.allclose(statistics.max_distance(SparseVectors.from_dense(dense)) >= expected - 1e-12, True)


@pytest.mark.parametrize("model", ["uniform", "range"])
def test_analytic_models_match_sampling(model):
    rng = np.random.default_rng(5)
    translations = rng.normal(size=(len(PARENTS), 3))
    samples = 40000
    if model == "uniform":
        statistics = PoseStatistics.uniform_rotations(PARENTS, translations)
        rotations = random_rotations(rng, samples * len(PARENTS)).reshape(samples, len(PARENTS), 3, 3)
    else:
        axes = rng.normal(size=(len(PARENTS), 3))
        ranges = np.sort(rng.uniform(-1.5, 1.5, (len(PARENTS), 2)), axis=1)
        statistics = PoseStatistics.rotation_ranges(PARENTS, translations, axes, ranges)
        angles = rng.uniform(ranges[:, 0], ranges[:, 1], (samples, len(PARENTS)))
        rotations = axis_angle(axes / np.linalg.norm(axes, axis=1, keepdims=True), angles)
    local = np.tile(np.eye(4), (samples, len(PARENTS), 1, 1))
    local[:, :, :3, :3], local[:, :, :3, 3] = rotations, translations
    local[:, 0] = np.eye(4)
    sampled = PoseStatistics.from_local_samples(PARENTS, local)
    scale = np.abs(sampled.expected_gram).max()
    assert np.abs(statistics.expected_local - sampled.expected_local).max() < 0.03
    assert np.abs(statistics.expected_gram - sampled.expected_gram).max() < 0.03 * scale


def test_euler_ranges_match_sampling():
    rng = np.random.default_rng(11)
    translations = rng.normal(size=(len(PARENTS), 3))
    ranges = [(np.eye(3)[0], -0.5, 1.0), (np.eye(3)[2], -1.2, 0.3)]
    models = [("fixed",)] + [("euler", ranges)] * (len(PARENTS) - 1)
    rest = random_rotations(rng, len(PARENTS))
    analytic = PoseStatistics.joints(PARENTS, translations, rest, models)
    samples = 40000
    x = axis_angle(np.tile(np.eye(3)[0], (len(PARENTS), 1)), rng.uniform(-0.5, 1.0, (samples, len(PARENTS))))
    z = axis_angle(np.tile(np.eye(3)[2], (len(PARENTS), 1)), rng.uniform(-1.2, 0.3, (samples, len(PARENTS))))
    local = np.tile(np.eye(4), (samples, len(PARENTS), 1, 1))
    local[:, :, :3, :3], local[:, :, :3, 3] = rest @ z @ x, translations  # X applied first
    local[:, 0] = np.eye(4)
    sampled = PoseStatistics.from_local_samples(PARENTS, local)
    assert np.abs(analytic.expected_local - sampled.expected_local).max() < 0.02
    assert np.abs(analytic.expected_gram - sampled.expected_gram).max() < 0.02 * np.abs(sampled.expected_gram).max()


def test_inner_product_by_polarisation_matches_the_dense_form():
    rng = np.random.default_rng(12)
    statistics = PoseStatistics.from_local_samples(PARENTS, joint_samples(rng, 20))
    s, t = weight_zero_vectors(rng, 6, len(PARENTS)), weight_zero_vectors(rng, 6, len(PARENTS))
    s[2] = 0.0  # an empty vector pairs too
    dense = np.einsum("ni,ij,nj->n", s.reshape(6, -1), statistics.matrix(), t.reshape(6, -1))
    sparse = statistics.inner_product(SparseVectors.from_dense(s), SparseVectors.from_dense(t))
    assert np.allclose(sparse, dense, rtol=1e-9, atol=1e-12)


def axis_angle(axes, angles):
    """Rodrigues: (S, b, 3, 3) rotations about axes (b, 3) by angles (S, b)."""
    k = np.zeros(axes.shape[:1] + (3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -axes[:, 2], axes[:, 1], -axes[:, 0]
    k -= k.transpose(0, 2, 1)
    s, c = np.sin(angles)[..., None, None], np.cos(angles)[..., None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def test_normalised_coordinates_reproduce_the_inner_product():
    rng = np.random.default_rng(6)
    statistics = PoseStatistics.from_local_samples(PARENTS, joint_samples(rng, 30))
    c = statistics.normalised_coordinates()
    s, t = weight_zero_vectors(rng, 2, len(PARENTS)).reshape(2, -1)
    assert (c @ s) @ (c @ t) == pytest.approx(s @ statistics.matrix() @ t, rel=1e-9)


def test_culling_sphere_holds_the_model_in_sampled_poses():
    import skinkit as sk
    from tests.core.test_model import random_rig

    rng = np.random.default_rng(7)
    skeleton, weights, rest, _ = random_rig(rng, vertices=200, bones=len(PARENTS), influences=2)
    skeleton = sk.Skeleton.create(PARENTS, skeleton.rest_frames)
    model = sk.convert_lbs(skeleton, weights, rest)
    translations = rng.normal(size=(len(PARENTS), 3))
    local = joint_samples(rng, 100, translations=translations)
    statistics = PoseStatistics.from_local_samples(PARENTS, local)
    centre, radius = statistics.culling_sphere(model, PoseStatistics.uniform_rotations(PARENTS, translations))
    posed = model.evaluate(world_frames(local))
    assert np.linalg.norm(posed - centre, axis=2).max() <= radius * (1 + 1e-12)


def independent_combinations(per_joint):
    """Every combination of the joints' own samples: the sample set on which the independent-joints
    model is exact."""
    count, bones = per_joint.shape[:2]
    return np.stack([np.stack([per_joint[choice[j], j] for j in range(bones)])
                     for choice in itertools.product(range(count), repeat=bones)])


def test_scaling_and_rigid_motion_match_recomputation_from_transformed_samples():
    rng = np.random.default_rng(9)
    local = independent_combinations(joint_samples(rng, 3, scale=(0.8, 1.2)))
    statistics = PoseStatistics.from_local_samples(PARENTS, local)
    scaled_samples = local.copy()
    scaled_samples[:, :, :3, 3] *= 2.5
    expected = PoseStatistics.from_local_samples(PARENTS, scaled_samples)
    scaled = statistics.scaled(2.5)
    assert np.allclose(scaled.expected_local, expected.expected_local) and \
        np.allclose(scaled.expected_gram, expected.expected_gram)
    assert np.allclose(scaled.translation_radius, expected.translation_radius)
    motion = np.eye(4)
    motion[:3, :3], motion[:3, 3] = random_rotations(rng, 1)[0], rng.normal(size=3)
    moved_samples = local.copy()
    children = np.flatnonzero(PARENTS == 0)
    moved_samples[:, children] = motion @ local[:, children]
    expected = PoseStatistics.from_local_samples(PARENTS, moved_samples)
    moved = statistics.transformed(motion)
    assert np.allclose(moved.expected_local, expected.expected_local)
    assert np.allclose(moved.expected_gram, expected.expected_gram)
    for j, k in itertools.product(range(len(PARENTS)), repeat=2):
        assert np.allclose(moved.block(j, k), expected.block(j, k))
    with pytest.raises(SkinkitError, match="rigid motion"):
        statistics.transformed(np.diag([2.0, 1, 1, 1]))


def test_rows_and_root_vectors_build_differences():
    import skinkit as sk
    from tests.core.test_model import random_rig

    rng = np.random.default_rng(14)
    skeleton, weights, rest, _ = random_rig(rng, vertices=30, bones=len(PARENTS), influences=3)
    model = sk.convert_lbs(sk.Skeleton.create(PARENTS, skeleton.rest_frames), weights, rest)
    pose = world_frames(joint_samples(rng, 1))[0]
    differences = SparseVectors.rows(model, [3, 7]).combined(SparseVectors.rows(model, [12, 3]), -1.0)
    posed = model.evaluate(pose)
    dense = np.zeros((2, len(PARENTS), 4))
    np.add.at(dense, (differences.vertex_of_each_influence(), differences.bones), differences.coordinates)
    moved = np.einsum("jab,njb->na", pose, dense)[:, :3]
    assert np.allclose(moved, [posed[3] - posed[12], posed[7] - posed[3]])
    centre = rng.normal(size=3)
    from_centre = SparseVectors.rows(model, [5]).combined(SparseVectors.at_root(np.r_[centre, 1.0], 1), -1.0)
    dense = np.zeros((1, len(PARENTS), 4))
    np.add.at(dense, (from_centre.vertex_of_each_influence(), from_centre.bones), from_centre.coordinates)
    assert np.allclose(np.einsum("jab,njb->na", pose, dense)[0, :3], posed[5] - centre)


def test_pixel_tolerance():
    assert pixel_tolerance(1.0, 10.0, np.pi / 6, 1000) == pytest.approx(0.01)


def test_bad_input():
    rng = np.random.default_rng(8)
    local = joint_samples(rng, 3)
    local[1, 2, 0, 0] = np.nan
    with pytest.raises(SkinkitError, match="local: contains NaN"):
        PoseStatistics.from_local_samples(PARENTS, local)
    with pytest.raises(SkinkitError, match="cycle"):
        PoseStatistics.from_local_samples([-1, 2, 1], joint_samples(rng, 2, parents=np.array([-1, 2, 1])))
    with pytest.raises(SkinkitError, match="at least one sampled pose"):
        PoseStatistics.from_local_samples(PARENTS, np.zeros((0, len(PARENTS), 4, 4)))
    with pytest.raises(SkinkitError, match="ends before it starts"):
        PoseStatistics.rotation_ranges(PARENTS, np.zeros((5, 3)), np.ones((5, 3)), [[0, 1], [1, 0], [0, 1], [0, 1], [0, 1]])
    statistics = PoseStatistics.from_local_samples(PARENTS, joint_samples(rng, 3))
    with pytest.raises(SkinkitError, match="outside"):
        statistics.block(0, 9)


def test_empty_vectors_have_zero_distance_whatever_comes_before():
    """Regression: an empty vector's max-distance bound was the previous vector's (or uninitialised)."""
    rng = np.random.default_rng(10)
    statistics = PoseStatistics.from_local_samples(PARENTS, joint_samples(rng, 10))
    dense = weight_zero_vectors(rng, 4, len(PARENTS))
    dense[[0, 2, 3]] = 0.0
    vectors = SparseVectors.from_dense(dense)
    assert vectors.counts()[0] == 0
    bounds, means = statistics.max_distance(vectors), statistics.mean_distance(vectors)
    assert bounds[0] == 0 and bounds[2] == 0 and bounds[3] == 0 and bounds[1] > 0
    assert means[0] == 0 and means[3] == 0


def test_all_blocks_at_once_and_linear_norms_agree_with_the_references():
    rng = np.random.default_rng(13)
    statistics = PoseStatistics.from_local_samples(PARENTS, joint_samples(rng, 12, scale=(0.3, 3.0)))
    dense = statistics.matrix()
    scale = np.abs(dense).max()
    for j, k in itertools.product(range(len(PARENTS)), repeat=2):  # mirrored blocks agree to rounding
        assert np.abs(dense[4 * j:4 * j + 4, 4 * k:4 * k + 4] - statistics.block(j, k)).max() < 1e-13 * scale
    from skinkit import _core

    matrices = np.tile(np.eye(4), (500, 1, 1))
    matrices[:, :3, :3] = rng.normal(size=(500, 3, 3))
    matrices[:3, :3, :3] = [np.diag([2.0, -3.0, 1.0]), np.zeros((3, 3)), np.eye(3) * 1e-8]  # diagonal, zero, tiny
    norms = np.empty(500)
    _core.linear_norms(norms, matrices.reshape(-1))
    assert np.allclose(norms, np.linalg.norm(matrices[:, :3, :3], ord=2, axis=(1, 2)), rtol=1e-9, atol=1e-15)
