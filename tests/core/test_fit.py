"""Fitting on numpy arrays: exact recovery, the solvers against independent dense solves, bad input."""
import numpy as np
import pytest
from tests.core.test_model import random_frames, random_rig

import skinkit as sk
from skinkit import _core, fit

EXACT = 1e-8


def examples_of(model_or_function, poses):
    return model_or_function.evaluate(poses) if hasattr(model_or_function, "evaluate") else model_or_function(poses)


def random_poses(rng, count, bones):
    poses = np.stack([random_frames(rng, bones) for _ in range(count)])
    poses[:, 0] = np.eye(4)
    return poses


def strip_triangles(vertex_count):
    """A triangle strip through the vertices in order: enough connectivity for edge regularisers."""
    return np.array([[i, i + 1, i + 2] for i in range(vertex_count - 2)], np.int32)


def random_animation_space_model(rng, pattern, bone_count, scale=3.0):
    """Arbitrary p_j per influence (not from any linear blend), weights summing to 1 per vertex."""
    coordinates = rng.normal(scale=scale, size=(pattern.influence_count, 4))
    vertex = pattern.vertex_of_each_influence()
    totals = np.bincount(vertex, coordinates[:, 3], minlength=pattern.vertex_count)
    coordinates[:, 3] += ((1.0 - totals) / pattern.counts())[vertex]
    return sk.AnimationSpaceModel.create(pattern.offsets, pattern.bones, coordinates, bone_count)


@pytest.mark.parametrize("method", ["per-vertex", "global"])
def test_exact_recovery_of_an_animation_space_model(method):
    rng = np.random.default_rng(1)
    skeleton, weights, rest, _ = random_rig(rng, vertices=200, bones=6, influences=3)
    truth = random_animation_space_model(rng, weights, skeleton.bone_count)
    poses = random_poses(rng, 10, skeleton.bone_count)
    examples = truth.evaluate(poses)
    result = fit.fit_animation_space(poses, examples, weights, skeleton.bone_count, method=method,
                                     regularisation=0.0, triangles=strip_triangles(200), rest_positions=rest,
                                     settings=fit.LsqrSettings(atol=1e-14, btol=1e-14), check_order=False)
    assert np.abs(result.model.evaluate(poses) - examples).max() < EXACT
    assert np.abs(result.model.coordinates - truth.coordinates).max() < EXACT
    assert np.array_equal(result.model.bones, weights.bones)  # influence sets respected
    assert np.abs(result.model.homogeneous_weights() - 1).max() < 1e-12


def test_exact_recovery_of_linear_blend_skinning_by_both_models():
    rng = np.random.default_rng(2)
    skeleton, weights, rest, _ = random_rig(rng, vertices=300, bones=5, influences=3)
    rest = rest * 40 + 100  # far from the unit box: normalisation must undo itself
    poses = random_poses(rng, 9, skeleton.bone_count)
    examples = sk.lbs_evaluate(skeleton, weights, rest, poses)
    model = fit.fit_animation_space(poses, examples, weights, skeleton.bone_count, regularisation=0.0,
                                    rest_positions=rest).model
    assert np.abs(model.evaluate(poses) - examples).max() < EXACT * 100
    recovered = fit.fit_lbs(skeleton, rest, poses, examples, weights)
    assert np.abs(recovered.weights - weights.weights).max() < EXACT
    assert np.all(recovered.weights >= 0)
    assert np.abs(recovered.totals() - 1).max() < 1e-12


def test_linear_blend_weights_stay_non_negative_on_data_it_cannot_reproduce():
    rng = np.random.default_rng(3)
    skeleton, weights, rest, _ = random_rig(rng, vertices=100, bones=5, influences=3)
    truth = random_animation_space_model(rng, weights, skeleton.bone_count)
    poses = random_poses(rng, 8, skeleton.bone_count)
    fitted = fit.fit_lbs(skeleton, rest, poses, truth.evaluate(poses), weights)
    assert np.all(fitted.weights >= 0) and np.abs(fitted.totals() - 1).max() < 1e-12


def dense_global_solution(poses, examples, pattern, edges, edge_weights):
    """Eq. 4.4 solved densely in numpy, independently: all 4 entries of every p free, the sum-to-one
    constraints as very heavy rows."""
    vertex_of = pattern.vertex_of_each_influence()
    unknowns = 4 * pattern.influence_count
    rows, rhs = [], []
    for pose, example in zip(poses, examples):
        for v in range(pattern.vertex_count):
            block = np.zeros((3, unknowns))
            for k in range(pattern.offsets[v], pattern.offsets[v + 1]):
                block[:, 4 * k:4 * k + 4] = pose[pattern.bones[k], :3, :]
            rows.append(block)
            rhs.append(example[v])
    for (a, b), weight in zip(edges, edge_weights):
        bones_a = dict(zip(pattern.bones[pattern.offsets[a]:pattern.offsets[a + 1]], range(pattern.offsets[a], pattern.offsets[a + 1])))
        bones_b = dict(zip(pattern.bones[pattern.offsets[b]:pattern.offsets[b + 1]], range(pattern.offsets[b], pattern.offsets[b + 1])))
        for bone in set(bones_a) | set(bones_b):
            block = np.zeros((4, unknowns))
            if bone in bones_a:
                block[:, 4 * bones_a[bone]:4 * bones_a[bone] + 4] += np.sqrt(weight) * np.eye(4)
            if bone in bones_b:
                block[:, 4 * bones_b[bone]:4 * bones_b[bone] + 4] -= np.sqrt(weight) * np.eye(4)
            rows.append(block)
            rhs.append(np.zeros(4))
    heavy = 1e6
    for v in range(pattern.vertex_count):
        block = np.zeros((1, unknowns))
        block[0, 4 * np.flatnonzero(vertex_of == v) + 3] = heavy
        rows.append(block)
        rhs.append([heavy])
    solution = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)[0]
    return solution.reshape(-1, 4)


@pytest.mark.parametrize("precondition", [True, False])
def test_global_fit_matches_a_dense_solve(precondition):
    rng = np.random.default_rng(4)
    skeleton, weights, _, _ = random_rig(rng, vertices=12, bones=4, influences=2)
    truth = random_animation_space_model(rng, weights, skeleton.bone_count)
    poses = random_poses(rng, 5, skeleton.bone_count)
    examples = truth.evaluate(poses) + rng.normal(scale=0.05, size=(5, 12, 3))  # not exactly representable
    edges = fit.mesh_edges(strip_triangles(12))
    edge_weights = rng.uniform(0.01, 0.5, len(edges))
    start = np.empty((weights.influence_count, 4))
    flat_poses, flat_examples = np.ascontiguousarray(poses).reshape(-1), np.ascontiguousarray(examples).reshape(-1)
    _core.fit_per_vertex(start, weights.offsets, weights.bones, flat_poses, flat_examples, 5, 1e-3, None, 1)
    report = _core.fit_global(start, weights.offsets, weights.bones, flat_poses, flat_examples, 5, edges.reshape(-1),
                              edge_weights, 1e-15, 1e-15, 0.0, 10000, precondition, 1, None)
    expected = dense_global_solution(poses, examples, weights, edges, edge_weights)
    assert np.abs(start - expected).max() < 1e-6
    assert report["stop_reason"] in (1, 2, 4, 5) and report["iterations"] > 0


def test_preconditioner_saves_iterations():
    rng = np.random.default_rng(5)
    skeleton, weights, rest, _ = random_rig(rng, vertices=400, bones=6, influences=3)
    truth = random_animation_space_model(rng, weights, skeleton.bone_count)
    poses = random_poses(rng, 8, skeleton.bone_count)
    examples = truth.evaluate(poses) + rng.normal(scale=0.01, size=(8, 400, 3))
    iterations = {}
    for precondition in (True, False):
        result = fit.fit_animation_space(poses, examples, weights, skeleton.bone_count, method="global",
                                         regularisation=1e-3, triangles=strip_triangles(400), rest_positions=rest,
                                         settings=fit.LsqrSettings(precondition=precondition), check_order=False)
        iterations[precondition] = result.report["iterations"]
    assert iterations[True] < iterations[False] / 2


def test_lsqr_matches_dense_least_squares():
    rng = np.random.default_rng(6)
    for rows, cols in ((30, 10), (10, 10), (200, 37)):
        matrix, b = rng.normal(size=(rows, cols)), rng.normal(size=rows)
        x = np.empty(cols)
        report = _core.lsqr_dense_matrix(x, matrix.reshape(-1).copy(), b, rows, cols, 1e-15, 1e-15, 0.0, 10 * cols)
        assert np.abs(x - np.linalg.lstsq(matrix, b, rcond=None)[0]).max() < 1e-9
        assert report["residual_norm"] == pytest.approx(np.linalg.norm(matrix @ x - b), rel=1e-6)


def test_influence_sets():
    rng = np.random.default_rng(7)
    skeleton, weights, rest, dense = random_rig(rng, vertices=60, bones=6, influences=2)
    poses = random_poses(rng, 6, skeleton.bone_count)
    examples = sk.lbs_evaluate(skeleton, weights, rest, poses)
    automatic = fit.influences_automatic(skeleton, rest, poses, examples, 2)
    assert automatic.counts().max() == 2 and 0 not in automatic.bones
    single = sk.SparseWeights.from_dense(np.eye(6)[rng.integers(1, 6, 60)])  # rigidly attached vertices
    rigid_examples = sk.lbs_evaluate(skeleton, single, rest, poses)
    found = fit.influences_automatic(skeleton, rest, poses, rigid_examples, 1)
    assert np.array_equal(found.bones, single.bones)  # the bone that carries a vertex explains it exactly
    grown = fit.influences_from_weights(dense, 6, strip_triangles(60), rings=1)
    assert np.all(grown.counts() >= weights.counts())
    capped = fit.influences_from_weights(dense, 1)
    assert np.array_equal(capped.bones, np.argmax(dense, axis=1))


# ---- bad input: clear errors -----------------------------------------------------------------

@pytest.fixture
def problem():
    rng = np.random.default_rng(8)
    skeleton, weights, rest, _ = random_rig(rng, vertices=50, bones=4, influences=2)
    poses = random_poses(rng, 6, skeleton.bone_count)
    return skeleton, weights, rest, poses, sk.lbs_evaluate(skeleton, weights, rest, poses)


def test_mismatched_vertex_counts(problem):
    skeleton, weights, rest, poses, examples = problem
    with pytest.raises(sk.SkinkitError, match="examples: 49 vertices per example, the mesh has 50"):
        fit.fit_animation_space(poses, examples[:, :49], weights, skeleton.bone_count)


def test_mismatched_vertex_order():
    """A smooth strip carried by one bone: correct examples pass the check, a shuffled one fails it."""
    rng = np.random.default_rng(9)
    rest = np.cumsum(rng.normal(scale=0.05, size=(50, 3)), axis=0)
    skeleton = sk.Skeleton.create([-1, 0], np.stack([np.eye(4), np.eye(4)]))
    weights = sk.SparseWeights.from_dense(np.tile([0.0, 1.0], (50, 1)))
    poses = np.stack([np.stack([np.eye(4), f]) for f in random_frames(rng, 6, scale=(1.0, 1.0))])
    examples = sk.lbs_evaluate(skeleton, weights, rest, poses)
    fit.fit_animation_space(poses, examples, weights, 2, triangles=strip_triangles(50), rest_positions=rest)
    examples[2] = examples[2][rng.permutation(50)]
    with pytest.raises(sk.SkinkitError, match="example 2: its vertex order does not match the rest mesh"):
        fit.fit_animation_space(poses, examples, weights, 2, triangles=strip_triangles(50), rest_positions=rest)


def test_too_few_examples(problem):
    skeleton, weights, rest, poses, examples = problem
    with pytest.raises(sk.SkinkitError, match=r"has 2 influences \(7 unknowns\) but 2 examples give only 6"):
        fit.fit_animation_space(poses[:2], examples[:2], weights, skeleton.bone_count)


def test_bone_that_never_moves(problem):
    skeleton, weights, rest, poses, examples = problem
    still = poses.copy()
    still[:, 2] = poses[0, 2]
    with pytest.raises(sk.SkinkitError, match=r"bones \['bone2'\] do not move in any example"):
        fit.fit_lbs(skeleton, rest, still, examples, weights)
    with pytest.raises(sk.SkinkitError, match="do not move"):
        fit.fit_animation_space(still, examples, weights, skeleton.bone_count, bone_names=skeleton.names)


def test_nan_in_examples(problem):
    skeleton, weights, rest, poses, examples = problem
    bad = examples.copy()
    bad[1, 7, 2] = np.nan
    with pytest.raises(sk.SkinkitError, match=r"examples: contains NaN or infinity \(first at index \(1, 7, 2\)\)"):
        fit.fit_animation_space(poses, bad, weights, skeleton.bone_count)


def test_empty_influence_set(problem):
    skeleton, weights, rest, poses, examples = problem
    pattern = sk.model.InfluencePattern(np.r_[0, 0, weights.offsets[2:] - weights.offsets[1]].astype(np.int32),
                                        weights.bones[weights.offsets[1]:])
    with pytest.raises(sk.SkinkitError, match="vertex 0 has an empty influence set"):
        fit.fit_animation_space(poses, examples, pattern, skeleton.bone_count)


def test_core_reports_underdetermined_vertices_without_regularisation(problem):
    skeleton, weights, rest, poses, examples = problem
    coordinates = np.empty((weights.influence_count, 4))
    with pytest.raises(sk.SkinkitError, match=r"^vertex \d+: 2 influences need 7 unknowns but 2 examples give 6 equations") as raised:
        _core.fit_per_vertex(coordinates, weights.offsets, weights.bones, poses[:2].reshape(-1),
                             examples[:2].reshape(-1), 2, 0.0, None, 1)
    assert raised.value.status == "underdetermined"


def test_global_fit_can_be_cancelled(problem):
    skeleton, weights, rest, poses, examples = problem
    with pytest.raises(sk.SkinkitError, match="cancelled"):
        fit.fit_animation_space(poses, examples + 0.01, weights, skeleton.bone_count, method="global",
                                regularisation=1.0, triangles=strip_triangles(50), rest_positions=rest,
                                settings=fit.LsqrSettings(atol=0, btol=0, precondition=False),
                                progress=lambda fraction: True, check_order=False)


def test_regularisation_does_not_depend_on_how_bone_frames_are_scaled():
    """The same motion with bone frames scaled by 0.01 (an FBX armature) fits to the same shapes."""
    rng = np.random.default_rng(10)
    skeleton, weights, rest, _ = random_rig(rng, vertices=80, bones=4, influences=2)
    poses = random_poses(rng, 7, skeleton.bone_count)
    truth = random_animation_space_model(rng, weights, skeleton.bone_count)
    examples = truth.evaluate(poses)
    scale = np.diag([0.01, 0.01, 0.01, 1.0])
    results = []
    for frame_scale in (np.eye(4), scale):
        fitted = fit.fit_animation_space(poses @ frame_scale, examples, weights, skeleton.bone_count,
                                         regularisation=0.05, rest_positions=rest,
                                         rest_frames=skeleton.rest_frames @ frame_scale)
        results.append(fitted.model.evaluate(poses @ frame_scale))
    assert np.abs(results[0] - results[1]).max() < 1e-9 * np.abs(examples).max()


def test_strong_regularisation_falls_back_to_the_prior():
    rng = np.random.default_rng(11)
    skeleton, weights, rest, _ = random_rig(rng, vertices=60, bones=4, influences=2)
    poses = random_poses(rng, 7, skeleton.bone_count)
    examples = random_animation_space_model(rng, weights, skeleton.bone_count).evaluate(poses)
    lbs = fit.fit_lbs(skeleton, rest, poses, examples, weights)
    prior = sk.convert_lbs(skeleton, lbs, rest)
    fitted = fit.fit_animation_space(poses, examples, weights, skeleton.bone_count, regularisation=1e9,
                                     rest_positions=rest, rest_frames=skeleton.rest_frames, prior=prior,
                                     validate=False)  # exactly this λ
    assert np.abs(fitted.model.evaluate(poses) - sk.lbs_evaluate(skeleton, lbs, rest, poses)).max() < 1e-6
    free = fit.fit_animation_space(poses, examples, weights, skeleton.bone_count, regularisation=1e-3,
                                   rest_positions=rest, rest_frames=skeleton.rest_frames, prior=prior)
    diagonal = np.linalg.norm(rest.max(0) - rest.min(0))
    assert fit.fit_errors(free.model.evaluate(poses), examples, diagonal)["rms"] < \
        fit.fit_errors(sk.lbs_evaluate(skeleton, lbs, rest, poses), examples, diagonal)["rms"]


def noisy_linear_blend_problem(seed):
    """LBS examples with noise of 1 % of the diagonal: the animation-space fit's extra freedom fits the noise, so
    only enough pull towards the linear-blend prior keeps it from losing on held-out poses."""
    rng = np.random.default_rng(seed)
    skeleton, weights, rest, _ = random_rig(rng, vertices=150, bones=5, influences=3)
    poses = random_poses(rng, 24, skeleton.bone_count)
    diagonal = np.linalg.norm(rest.max(0) - rest.min(0))
    clean = sk.lbs_evaluate(skeleton, weights, rest, poses)
    examples = clean + rng.normal(scale=0.01 * diagonal, size=clean.shape)
    train = np.arange(len(poses)) < 12
    prior = sk.convert_lbs(skeleton, fit.fit_lbs(skeleton, rest, poses[train], examples[train], weights), rest)
    return skeleton, weights, rest, poses, examples, train, prior, diagonal


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_default_fit_does_not_lose_to_linear_blend_skinning_on_held_out_poses(seed):
    skeleton, weights, rest, poses, examples, train, prior, diagonal = noisy_linear_blend_problem(seed)

    def held_out_rms(model):
        return fit.fit_errors(model.evaluate(poses[~train]), examples[~train], diagonal)["rms"]

    def fitted(**options):
        return fit.fit_animation_space(poses[train], examples[train], weights, skeleton.bone_count,
                                       rest_positions=rest, rest_frames=skeleton.rest_frames, prior=prior,
                                       **options)

    default = fitted()
    assert held_out_rms(default.model) <= 1.001 * held_out_rms(prior)
    # chosen: the noise needs a stronger pull, or the linear-blend prior itself
    assert default.report["fallback"] or default.report["lambda"] > fit.DEFAULT_LAMBDA
    assert set(default.report["validation"]) == {f"{fit.DEFAULT_LAMBDA * f:g}" for f in fit.VALIDATION_FACTORS} | \
        {fit.PRIOR_CANDIDATE}
    # the fixed λ of before loses by more than 5 %: what the validation is for
    assert held_out_rms(fitted(validate=False).model) > 1.05 * held_out_rms(prior)


@pytest.mark.parametrize("method", ["per-vertex", "global"])
def test_the_default_fit_reproduces_the_rest_pose(method):
    rng = np.random.default_rng(12)
    skeleton, weights, rest, _ = random_rig(rng, vertices=120, bones=5, influences=3)
    poses = random_poses(rng, 10, skeleton.bone_count)
    examples = random_animation_space_model(rng, weights, skeleton.bone_count, scale=1.0).evaluate(poses)
    diagonal = np.linalg.norm(rest.max(0) - rest.min(0))

    def rest_error(**options):
        model = fit.fit_animation_space(poses, examples, weights, skeleton.bone_count, method=method,
                                        triangles=strip_triangles(120), rest_positions=rest,
                                        rest_frames=skeleton.rest_frames, check_order=False, **options).model
        return np.linalg.norm(model.evaluate(skeleton.rest_frames) - rest, axis=1).max() / diagonal

    assert rest_error() < 1e-3
    assert rest_error(reproduce_rest=False) > 10 * rest_error()  # without the rest example the bind pose moves


def test_validation_falls_back_to_the_prior_when_no_lambda_predicts_better():
    """Linear-blend examples with noise and few poses: animation space's extra unknowns fit the noise, so the
    cross-validation keeps the linear-blend prior, exactly, and says so."""
    skeleton, weights, rest, poses, examples, train, prior, diagonal = noisy_linear_blend_problem(0)
    train = np.arange(len(poses)) < 6
    prior = sk.convert_lbs(skeleton, fit.fit_lbs(skeleton, rest, poses[train], examples[train], weights), rest)
    for method in fit.FIT_METHODS:
        result = fit.fit_animation_space(poses[train], examples[train], weights, skeleton.bone_count, method=method,
                                         triangles=strip_triangles(len(rest)), rest_positions=rest,
                                         rest_frames=skeleton.rest_frames, prior=prior, check_order=False)
        assert result.report["fallback"] and result.report["lambda"] is None
        scores = result.report["validation"]
        assert scores[fit.PRIOR_CANDIDATE] <= (1 + fit.VALIDATION_MARGIN) * min(
            value for key, value in scores.items() if key != fit.PRIOR_CANDIDATE)
        assert np.array_equal(result.model.coordinates, prior.coordinates)  # exactly: it cannot lose to it


def test_validation_keeps_animation_space_where_it_predicts_better():
    """Examples made by an animation-space model: every λ candidate beats the linear-blend prior in validation."""
    rng = np.random.default_rng(5)
    skeleton, weights, rest, _ = random_rig(rng, vertices=80, bones=5, influences=3)
    poses = random_poses(rng, 16, skeleton.bone_count)
    examples = random_animation_space_model(rng, weights, skeleton.bone_count, scale=1.0).evaluate(poses)
    prior = sk.convert_lbs(skeleton, fit.fit_lbs(skeleton, rest, poses, examples, weights), rest)
    result = fit.fit_animation_space(poses, examples, weights, skeleton.bone_count, prior=prior)
    assert not result.report["fallback"] and result.report["lambda"] > 0
    assert result.report["validation_folds"] == fit.VALIDATION_FOLDS
    chosen = result.report["validation"][f"{result.report['lambda']:g}"]
    assert (1 + fit.VALIDATION_MARGIN) * chosen < result.report["validation"][fit.PRIOR_CANDIDATE]


def test_cross_validation_equals_fits_made_fold_by_fold():
    rng = np.random.default_rng(8)
    skeleton, weights, rest, _ = random_rig(rng, vertices=40, bones=4, influences=3)
    poses = random_poses(rng, 9, skeleton.bone_count)
    examples = sk.lbs_evaluate(skeleton, weights, rest, poses) + rng.normal(scale=0.01, size=(9, 40, 3))
    lambdas = np.array([1e-3, 1.0])
    squared = np.empty((40, 2))
    _core.validate_per_vertex(squared, weights.offsets, weights.bones, np.ascontiguousarray(poses).reshape(-1),
                              np.ascontiguousarray(examples).reshape(-1), 9, 0, 4, None, None, lambdas, 0)
    expected = np.zeros((40, 2))
    for fold in range(4):
        held = np.arange(9) % 4 == fold
        for column, lam in enumerate(lambdas):
            coordinates = np.empty((weights.influence_count, 4))
            _core.fit_per_vertex(coordinates, weights.offsets, weights.bones,
                                 np.ascontiguousarray(poses[~held]).reshape(-1),
                                 np.ascontiguousarray(examples[~held]).reshape(-1), int((~held).sum()), lam, None, 0)
            model = sk.AnimationSpaceModel(weights.offsets, weights.bones, coordinates, skeleton.bone_count)
            expected[:, column] += ((model.evaluate(poses[held]) - examples[held]) ** 2).sum(axis=(0, 2))
    np.testing.assert_allclose(squared, expected, rtol=1e-9, atol=1e-14)


@pytest.mark.parametrize("prior_kind", ["linear blend", "other", "none"])
def test_validation_in_vertex_chunks_scores_every_lambda_as_in_one(monkeypatch, prior_kind):
    """The validation works through the vertices in chunks (bounded temporaries at a million vertices): every λ's
    score is the same bits in any chunking, the prior's the same up to rounding, so the same λ is chosen."""
    skeleton, weights, rest, poses, examples, train, prior, _ = noisy_linear_blend_problem(1)
    if prior_kind == "other":  # not linear blend skinning on this rest mesh: not refitted per fold
        prior = sk.AnimationSpaceModel(prior.offsets, prior.bones, prior.coordinates + [0.01, 0, 0, 0],
                                       prior.bone_count)

    def report():
        return fit.fit_animation_space(poses[train], examples[train], weights, skeleton.bone_count,
                                       rest_positions=rest, rest_frames=skeleton.rest_frames,
                                       prior=None if prior_kind == "none" else prior).report

    whole = report()
    assert len(fit.vertex_chunks(weights.offsets, int(train.sum()))) == 1
    monkeypatch.setattr(fit._memory, "VALIDATION_CHUNK_INFLUENCES", 7)  # chunks of 2 or 3 vertices
    assert len(fit.vertex_chunks(weights.offsets, int(train.sum()))) > 50
    chunked = report()
    for key, value in whole["validation"].items():
        if key == fit.PRIOR_CANDIDATE:
            assert chunked["validation"][key] == pytest.approx(value, rel=1e-12)
        else:
            assert chunked["validation"][key] == value
    assert chunked["lambda"] == whole["lambda"] and chunked["fallback"] == whole["fallback"]


def test_vertex_chunks_cover_every_vertex_once_within_their_bounds(monkeypatch):
    offsets = np.concatenate([[0], np.cumsum(np.random.default_rng(3).integers(0, 9, size=500))]).astype(np.int32)
    monkeypatch.setattr(fit._memory, "VALIDATION_CHUNK_INFLUENCES", 20)
    monkeypatch.setattr(fit._memory, "VALIDATION_CHUNK_VALUES", 3 * 10 * 30)  # 10 examples: at most 30 vertices
    chunks = fit.vertex_chunks(offsets, 10)
    assert chunks[0][0] == 0 and chunks[-1][1] == 500
    assert all(end == next_begin for (_, end), (next_begin, _) in zip(chunks, chunks[1:]))
    for begin, end in chunks:
        assert 1 <= end - begin <= 30
        assert end - begin == 1 or offsets[end] - offsets[begin] <= 20
