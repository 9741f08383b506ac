"""skinkit.handles: kernel CCA against a dense primal reference, training, prediction, storage, bad input."""
import numpy as np
import pytest

from skinkit import SkinkitError, _core, handles
from tests.sequences import rigid_chain_sequence


def features(x, kernel):
    """Explicit feature maps of the linear kernel and of (x.y + c)^2, so kernel CCA has a primal twin."""
    if kernel == "linear":
        return x
    c = 0.5
    i, j = np.triu_indices(x.shape[1])
    pairs = x[:, i] * x[:, j] * np.where(i == j, 1.0, np.sqrt(2.0))
    return np.column_stack([pairs, np.sqrt(2 * c) * x, np.full(len(x), c)])


def inverse_root(matrix):
    values, vectors = np.linalg.eigh(matrix)
    return vectors @ np.diag(values ** -0.5) @ vectors.T


def primal_cca_predictor(phi, targets, kappa, pairs):
    """Regularised CCA in feature space (Sigma_cc + kappa I, as f'(Kc^2 + kappa Kc) f is with u = phi' f), then
    the regressions 2.8 and 2.9: returns the correlations and a predictor of new feature rows."""
    phi_mean, d_mean = phi.mean(axis=0), targets.mean(axis=0)
    pc, dc = phi - phi_mean, targets - d_mean
    sdd = dc.T @ dc
    sdd += 1e-9 * np.trace(sdd) / len(sdd) * np.eye(len(sdd))
    wc, wd = inverse_root(pc.T @ pc + kappa * np.eye(phi.shape[1])), inverse_root(sdd)
    u, s, vt = np.linalg.svd(wc @ pc.T @ dc @ wd)
    uc, ud = wc @ u[:, :pairs], wd @ vt[:pairs].T
    cr, dr = pc @ uc, dc @ ud
    b = np.linalg.lstsq(cr, dr, rcond=None)[0]
    h = np.linalg.lstsq(dr, dc, rcond=None)[0]
    return s[:pairs], lambda rows: d_mean + (rows - phi_mean) @ uc @ b @ h


@pytest.mark.parametrize("kernel", ["linear", "polynomial"])
def test_kernel_cca_equals_the_primal_reference(kernel):
    rng = np.random.default_rng(3)
    x = rng.normal(size=(30, 5))
    targets = np.column_stack([np.sin(x[:, 0]), x[:, 1] * x[:, 2], x[:, 0] ** 2, rng.normal(size=30) * 0.1])
    phi = features(x, kernel)
    gram = phi @ phi.T
    centred = gram - gram.mean(0) - gram.mean(1)[:, None] + gram.mean()
    kappa = 1e-2 * np.trace(centred) / 30
    mapping, offset, correlations = np.empty((4, 30)), np.empty(4), np.empty(4)
    _core.kernel_cca(mapping, offset, correlations, gram, targets, 1, 4, 4, kappa, 1)
    rho, predict = primal_cca_predictor(phi, targets, kappa, 4)
    np.testing.assert_allclose(correlations, rho, atol=1e-8)
    new = rng.normal(size=(5, 5))
    np.testing.assert_allclose(mapping @ (phi @ features(new, kernel).T) + offset[:, None], predict(features(new, kernel)).T,
                               atol=1e-6)


@pytest.fixture(scope="module")
def chain():
    frames, triangles, _, _ = rigid_chain_sequence(3, 36, seed=4)
    return frames, triangles


@pytest.fixture(scope="module")
def model(chain):
    frames, triangles = chain
    return handles.train(frames[:30], triangles, handle_vertices=[5, 60, 125], bones=3, ridge=1e-7,
                         validate=False)


def test_training_poses_are_reproduced_to_the_proxy_bone_fit(model, chain):
    frames, _ = chain
    extent = np.ptp(frames[0], axis=0).max()
    predicted = model.predict(model.handle_positions_of(frames[:30]))
    rms = np.sqrt(((predicted - frames[:30]) ** 2).sum(-1).mean()) / extent
    assert rms == pytest.approx(model.report["training_rms"])
    assert rms <= model.report["proxy_bone_fit_rms"] + 2e-3
    # The poses are far from rest: reproducing them is not the rest mesh.
    assert np.sqrt(((frames[0] - frames[:30]) ** 2).sum(-1).mean()) / extent > 20 * rms


def test_held_out_frames_and_the_poisson_solve(chain):
    frames, triangles = chain
    extent = np.ptp(frames[0], axis=0).max()
    errors = {}
    for poisson in (True, False):
        rig = handles.train(frames[:30], triangles, handle_vertices=[5, 60, 125], bones=3, kernel="linear",
                            poisson=poisson)
        predicted = rig.predict(rig.handle_positions_of(frames[30:]))
        errors[poisson] = np.sqrt(((predicted - frames[30:]) ** 2).sum(-1).mean()) / extent
    assert errors[True] < 0.05
    # The solve puts the handle vertices where the handles are, which the mapping's own translations do not.
    assert errors[True] < errors[False]


def test_save_and_load_give_the_same_prediction(model, chain, tmp_path):
    frames, _ = chain
    path = tmp_path / "rig.npz"
    model.save(path)
    loaded = handles.load(path)
    targets = model.handle_positions_of(frames[30:])
    np.testing.assert_array_equal(loaded.predict(targets), model.predict(targets))
    single = model.predict(targets[0])
    assert single.shape == (len(frames[0]), 3)
    stored = dict(np.load(path))
    stored["format_version"] = np.array(99)
    with pytest.raises(SkinkitError, match="format version 99"):
        handles.HandleModel.from_arrays(stored)


def reference_suggestion(frames, count):
    """A dense numpy twin of sk_suggest_handles: PCA by SVD, Kaiser's varimax, extremes along each component."""
    data = frames.reshape(len(frames), -1)
    _, singular, vt = np.linalg.svd(data - data.mean(axis=0), full_matrices=False)
    components = (count + 1) // 2
    loadings = vt[:components].T * singular[:components]
    rotation, objective = np.eye(components), 0.0
    for _ in range(100):
        rotated = loadings @ rotation
        gradient = loadings.T @ (rotated ** 3 - rotated * (rotated ** 2).sum(axis=0) / len(loadings))
        u, s, v = np.linalg.svd(gradient)
        rotation = u @ v
        if s.sum() < objective * (1 + 1e-8):
            break
        objective = s.sum()
    chosen = []
    for component in (loadings @ rotation).T:
        per_vertex = component.reshape(-1, 3)
        score = per_vertex @ np.linalg.eigh(per_vertex.T @ per_vertex)[1][:, -1]
        free = np.array([v not in chosen for v in range(len(score))])
        sign = 1.0 if score[free].max() >= -score[free].min() else -1.0  # the farther extreme first
        for side in (sign, -sign):
            if len(chosen) < count:
                chosen.append(next(int(v) for v in np.argsort(-side * score) if int(v) not in chosen))
    return chosen


def test_suggested_handles_equal_the_reference(chain):
    frames, _ = chain
    for count in (1, 4, 7):
        assert handles.suggest_handles(frames, count).tolist() == reference_suggestion(frames, count)


def test_suggested_handles_are_distinct_and_move(chain):
    frames, _ = chain
    chosen = handles.suggest_handles(frames, 5)
    assert len(chosen) == 5 and len(set(chosen.tolist())) == 5
    assert (np.ptp(frames[:, chosen], axis=0).max(axis=1) > 0.05).all()
    np.testing.assert_array_equal(chosen, handles.suggest_handles(frames, 5))


@pytest.mark.parametrize("change, message", [
    (dict(frames=2), "at least 3"),
    (dict(handle_vertices=[1, 10 ** 6]), "out of range"),
    (dict(handle_vertices=[4, 4]), "more than once"),
    (dict(kernel="cubic"), "kernel"),
    (dict(nan=True), "NaN"),
    (dict(handle_vertices=[0, 1], still=True), "do not move"),
    (dict(handle_vertices=None, handle_count=6, frames=3), "needs at least 4"),
    # the long fuzz pass, seed 1 call 85278: a weights object as the count was a raw TypeError from int()
    (dict(handle_vertices=None, handle_count=object()),
     "handle_count: expected a whole number"),
    (dict(handle_vertices=None, handle_count=0), "handle_count: must be at least 1"),
])
def test_bad_input_is_named(chain, change, message):
    frames, triangles = chain
    frames = frames[:change.get("frames", 10)].copy()
    if change.get("nan"):
        frames[3, 7, 1] = np.nan
    if change.get("still"):
        frames[:, :2] = frames[0, :2]
    with pytest.raises(SkinkitError, match=message):
        handles.train(frames, triangles, handle_vertices=change.get("handle_vertices", [5, 60]),
                      handle_count=change.get("handle_count"), bones=3, kernel=change.get("kernel", "gaussian"))


def test_wrong_handle_shape_is_refused(model):
    with pytest.raises(SkinkitError, match="handle_positions"):
        model.predict(np.zeros((4, 3)))


def random_rigid_dual_quaternions(rng, count):
    """count random rigid motions as dual quaternions (count, 8)."""
    matrices = np.tile(np.eye(4), (count, 1, 1))
    for matrix in matrices:
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        matrix[:3, :3] = q * np.sign(np.linalg.det(q))
        matrix[:3, 3] = rng.normal(size=3)
    dqs = np.empty((count, 8))
    _core.dq_from_rigid(dqs, matrices)
    return dqs


def test_dqs_weights_recover_the_weights_that_made_a_dqs_sequence():
    from skinkit.handles.weights import refit_dqs_weights

    rng = np.random.default_rng(11)
    vertices, bones, examples = 40, 4, 12
    rest = rng.normal(size=(vertices, 3))
    offsets = np.arange(0, 3 * vertices + 1, 3, dtype=np.int32)
    influence_bones = np.concatenate([rng.choice(bones, 3, replace=False) for _ in range(vertices)]).astype(np.int32)
    true_weights = rng.dirichlet(np.ones(3), size=vertices).ravel()
    dual_quaternions = np.stack([random_rigid_dual_quaternions(rng, bones) for _ in range(examples)])
    # Mild rotations only: keep every blend's quaternions in one hemisphere, as a fitted rig's are.
    dual_quaternions[..., :4] += 3 * np.array([1.0, 0, 0, 0])
    dual_quaternions[..., :4] /= np.linalg.norm(dual_quaternions[..., :4], axis=-1, keepdims=True)
    real, dual = dual_quaternions[..., :4], dual_quaternions[..., 4:]
    dual -= (real * dual).sum(-1, keepdims=True) * real  # back to unit dual quaternions
    frames = np.empty((examples, vertices, 3))
    for frame, pose in zip(frames, dual_quaternions):
        _core.dqs_evaluate(frame, rest, 1.0, offsets, influence_bones, true_weights, np.ascontiguousarray(pose), 1)
    start = np.full(len(influence_bones), 1 / 3)
    new_offsets, new_bones, weights = refit_dqs_weights(rest, frames, dual_quaternions, offsets, influence_bones, start)
    assert (weights >= 0).all() and len(new_bones) <= len(influence_bones)
    np.testing.assert_allclose(np.add.reduceat(weights, new_offsets[:-1]), 1, atol=1e-12)
    dense = np.zeros((vertices, bones))
    dense[np.repeat(np.arange(vertices), np.diff(new_offsets)), new_bones] = weights
    expected = np.zeros((vertices, bones))
    expected[np.repeat(np.arange(vertices), 3), influence_bones] = true_weights
    np.testing.assert_allclose(dense, expected, atol=1e-4)


def test_simplex_projection_is_the_nearest_point_on_the_simplex():
    from skinkit.handles.weights import project_to_simplex

    rng = np.random.default_rng(5)
    values = rng.normal(size=(200, 4))
    mask = rng.random((200, 4)) < 0.8
    mask[:, 0] = True
    projected = project_to_simplex(values, mask)
    assert (projected >= 0).all() and (projected[~mask] == 0).all()
    np.testing.assert_allclose(projected.sum(axis=1), 1, atol=1e-12)
    # Optimality: no random point of the same face's simplex is closer.
    for row in range(0, 200, 20):
        candidates = np.zeros((500, 4))
        candidates[:, mask[row]] = rng.dirichlet(np.ones(mask[row].sum()), size=500)
        best = ((projected[row] - values[row])[mask[row]] ** 2).sum()
        assert (((candidates - values[row])[:, mask[row]] ** 2).sum(axis=1) >= best - 1e-12).all()


def test_dqs_weights_fit_the_examples_no_worse_than_the_lbs_weights(chain):
    frames, triangles = chain
    lbs = handles.train(frames[:30], triangles, handle_vertices=[5, 60, 125], bones=2, dqs_weights=False)
    dqs = handles.train(frames[:30], triangles, handle_vertices=[5, 60, 125], bones=2, dqs_weights=True)
    assert lbs.report["proxy_bone_fit_rms"] == pytest.approx(lbs.report["lbs_weights_fit_rms"])
    assert dqs.report["lbs_weights_fit_rms"] == pytest.approx(lbs.report["lbs_weights_fit_rms"])
    assert dqs.report["proxy_bone_fit_rms"] <= lbs.report["proxy_bone_fit_rms"] * (1 + 1e-9)
    assert np.diff(dqs.offsets).max() <= np.diff(lbs.offsets).max()


def test_validation_chooses_the_kernel_scale_and_ridge_from_the_grid(chain):
    from skinkit.handles import train as train_module

    frames, triangles = chain
    model = handles.train(frames[:30], triangles, handle_vertices=[5, 60, 125], bones=3, validate=True)
    chosen = model.report["validation"]
    module = __import__("sys").modules[train_module.__module__]
    assert chosen["kernel_scale"] in module.KERNEL_SCALES and chosen["ridge"] in module.RIDGES
    assert model.parameter == pytest.approx(chosen["kernel_scale"] * 1.0)
    assert chosen["rms"] > 0


def test_validation_folds_keep_a_repeated_pose_in_one_fold():
    from skinkit.handles import train as train_module

    module = __import__("sys").modules[train_module.__module__]
    rng = np.random.default_rng(2)
    poses = rng.normal(size=(10, 6))
    looped = np.concatenate([poses, poses + 1e-9])  # one cycle played twice, as the horse gallop is
    folds = module.validation_folds(looped)
    np.testing.assert_array_equal(folds[:10], folds[10:])
    assert set(folds) == set(range(module.VALIDATION_FOLDS))
    np.testing.assert_array_equal(module.validation_folds(poses), np.arange(10) % module.VALIDATION_FOLDS)


@pytest.mark.parametrize("stop_at", [0.5, 0.82, 0.9])
def test_training_cancels_in_each_stage(chain, stop_at):
    """The decomposition (< 0.8), the DQS weight refit (0.8-0.85) and the predictor (0.9) all honour a cancel."""
    frames, triangles = chain
    seen = []

    def progress(fraction):
        seen.append(fraction)
        return fraction >= stop_at

    with pytest.raises(SkinkitError, match="cancelled"):
        handles.train(frames[:30], triangles, handle_vertices=[5, 60, 125], bones=2, progress=progress)
    assert seen[-1] >= stop_at and all(f < stop_at for f in seen[:-1])
