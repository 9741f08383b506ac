"""The refit of a level's coordinates to the full detail (skinkit.lod.refit_level, sk_lod_refit)."""
import numpy as np
import pytest

from skinkit._checks import SkinkitError
from skinkit.lod import build_chain, refit_level
from skinkit.model import AnimationSpaceModel

from tests.core.test_lod_chain import bending_model, grid, statistics


def dense(model: AnimationSpaceModel) -> np.ndarray:
    """Each vertex's coordinates as one 4 * bone_count row."""
    out = np.zeros((model.vertex_count, 4 * model.bone_count))
    vertex = np.repeat(np.arange(model.vertex_count), np.diff(model.offsets))
    for c in range(4):
        out[vertex, 4 * model.bones + c] = model.coordinates[:, c]
    return out


def perturbed(model: AnimationSpaceModel, scale: float, seed: int = 3) -> AnimationSpaceModel:
    """Noise on the positional parts only: the weights keep their sums, as every level's do."""
    noise = np.random.default_rng(seed).normal(scale=scale, size=model.coordinates.shape)
    noise[:, 3] = 0.0
    return AnimationSpaceModel(model.offsets, model.bones, model.coordinates + noise, model.bone_count)


class CentroidEnergy:
    """The refit's energy for a level with the mesh's own triangles: each triangle's centroid then lies on the same
    triangle of the level, so a sample's level corners are its own corners at 1/3 each."""

    def __init__(self, level: AnimationSpaceModel, full: AnimationSpaceModel, rest, tris, stats):
        P = stats.matrix()
        self.area = 0.5 * np.linalg.norm(np.cross(rest[tris[:, 1]] - rest[tris[:, 0]],
                                                  rest[tris[:, 2]] - rest[tris[:, 0]]), axis=1)
        vertex = np.repeat(np.arange(level.vertex_count), np.diff(level.offsets))
        self.columns = (4 * level.bones[:, None] + np.arange(4)).reshape(-1)  # each unknown's dense column
        self.owner = np.repeat(vertex, 4)
        width = 4 * level.bone_count
        average = np.zeros((len(tris), level.vertex_count))
        np.put_along_axis(average, tris, 1.0 / 3.0, axis=1)
        select = np.zeros((level.vertex_count * width, len(self.columns)))
        select[self.owner * width + self.columns, np.arange(len(self.columns))] = 1.0
        self.rows = np.kron(average, np.eye(width)) @ select  # the samples' coordinates from the unknowns
        self.targets = (average @ dense(full)).reshape(-1)
        self.weight = np.kron(np.diag(self.area), P)
        self.P, self.vertex_count = P, level.vertex_count

    def __call__(self, coordinates) -> float:
        e = self.rows @ coordinates.reshape(-1) - self.targets
        return float(e @ self.weight @ e)

    def pulled(self, pull: float) -> np.ndarray:
        mbar = self.area.sum() / self.vertex_count
        return pull * mbar * self.P[np.ix_(self.columns, self.columns)] * (self.owner[:, None] == self.owner[None, :])

    def objective(self, coordinates, start: AnimationSpaceModel, pull: float) -> float:
        """E(x) + pull * mbar * sum_j (x_j - x0_j)^T P_jj (x_j - x0_j): what the refit minimises."""
        step = coordinates.reshape(-1) - start.coordinates.reshape(-1)
        return self(coordinates) + float(step @ self.pulled(pull) @ step)

    def minimiser(self, start: AnimationSpaceModel, pull: float) -> np.ndarray:
        """The least objective over steps that keep every vertex's weight sum (the fourth coordinates of its
        influences), through a basis of those steps."""
        normal = self.rows.T @ self.weight @ self.rows
        x0 = start.coordinates.reshape(-1)
        sums = np.zeros((self.vertex_count, len(x0)))
        sums[self.owner[3::4], np.arange(3, len(x0), 4)] = 1.0
        _, singular, vt = np.linalg.svd(sums)
        basis = vt[int((singular > 1e-12).sum()):].T
        hessian = basis.T @ (normal + self.pulled(pull)) @ basis
        gradient = basis.T @ (self.rows.T @ self.weight @ self.targets - normal @ x0)
        return (x0 + basis @ np.linalg.lstsq(hessian, gradient, rcond=1e-12)[0]).reshape(-1, 4)


@pytest.fixture(scope="module")
def bent():
    rest, tris = grid(6, curvature=0.4)
    return rest, tris, bending_model(rest), statistics()


def test_an_exact_level_stays_where_it_is(bent):
    rest, tris, model, stats = bent
    refitted, report = refit_level(tris, rest, model, tris, rest, model, stats)
    np.testing.assert_allclose(refitted.coordinates, model.coordinates, atol=1e-12)
    assert report["samples"] == len(tris) and report["unmatched"] == 0


@pytest.mark.parametrize("pull", [0.1, 1.0])
def test_the_refit_is_the_dense_minimiser(bent, pull):
    rest, tris, model, stats = bent
    level = perturbed(model, 0.05)
    refitted, report = refit_level(tris, rest, level, tris, rest, model, stats, pull=pull, max_steps=500,
                                   tolerance=1e-14)
    energy = CentroidEnergy(level, model, rest, tris, stats)
    least = energy.objective(energy.minimiser(level, pull), level, pull)
    assert energy.objective(refitted.coordinates, level, pull) == pytest.approx(least, rel=1e-9)
    assert report["final_residual"] < 1e-10 * report["start_residual"]
    assert energy(refitted.coordinates) < 0.5 * energy(level.coordinates)


def test_a_few_steps_lower_the_error_and_threads_do_not_change_bits(bent):
    rest, tris, model, stats = bent
    level = perturbed(model, 0.05)
    one, _ = refit_level(tris, rest, level, tris, rest, model, stats, threads=1)
    two, _ = refit_level(tris, rest, level, tris, rest, model, stats, threads=2)
    np.testing.assert_array_equal(one.coordinates, two.coordinates)
    energy = CentroidEnergy(level, model, rest, tris, stats)
    assert energy(one.coordinates) < 0.5 * energy(level.coordinates)


def test_the_chain_refits_every_level_but_the_first(bent):
    rest, tris, model, stats = bent
    plain = build_chain(tris, rest, model, stats, uv=rest[tris][:, :, :2].reshape(-1, 6), levels=3, refit=False)
    refitted = build_chain(tris, rest, model, stats, uv=rest[tris][:, :, :2].reshape(-1, 6), levels=3)
    np.testing.assert_array_equal(refitted.levels[0].model.coordinates, model.coordinates)
    for a, b in zip(plain.levels[1:], refitted.levels[1:]):
        np.testing.assert_array_equal(a.triangles, b.triangles)
        np.testing.assert_array_equal(a.model.bones, b.model.bones)
        assert a.epsilon == b.epsilon
        assert b.report["refit"]["steps"] >= 1
        assert not np.array_equal(a.model.coordinates, b.model.coordinates)
    # the geomorph data follow the refitted levels: at an integer level the geomorph is that level
    for level in refitted.levels:  # the weights of every vertex still sum to one
        np.testing.assert_allclose(np.add.reduceat(level.model.coordinates[:, 3], level.model.offsets[:-1]), 1.0,
                                   atol=1e-12)
    morph, _, _ = refitted.geomorph(1.0)
    np.testing.assert_array_equal(morph.coordinates, refitted.levels[1].model.coordinates)


def test_the_rest_metric_chain_is_not_refitted(bent):
    rest, tris, model, stats = bent
    with pytest.warns(UserWarning, match="no UVs"):
        chain = build_chain(tris, rest, model, stats, levels=2, metric="rest")
    assert "refit" not in chain.levels[1].report


def test_bad_inputs_are_named(bent):
    rest, tris, model, stats = bent
    bad = model.coordinates.copy()
    bad[3, 1] = np.nan
    nan_model = AnimationSpaceModel(model.offsets, model.bones, bad, model.bone_count)
    with pytest.raises(SkinkitError, match="level: coordinates of influence 3 are not finite"):
        refit_level(tris, rest, nan_model, tris, rest, model, stats)
    with pytest.raises(SkinkitError, match="pull"):
        refit_level(tris, rest, model, tris, rest, model, stats, pull=-1.0)
    with pytest.raises(SkinkitError, match="same bones"):
        refit_level(tris, rest, model, tris, rest, model, statistics(bones=3))
    with pytest.raises(SkinkitError, match="level_rest"):
        refit_level(tris, rest[:-1], model, tris, rest, model, stats)


def test_a_true_progress_return_cancels(bent):
    rest, tris, model, stats = bent
    with pytest.raises(SkinkitError, match="cancelled"):
        refit_level(tris, rest, perturbed(model, 0.05), tris, rest, model, stats, progress=lambda fraction: True)
