"""Full-edge collapses and the queue's influence weighting (skinkit.lod.build_chain's collapse=, influence_cost_scale=,
start_influences=): the survivor's solved coordinates are the minimiser of the memoryless APS cost, found here by
sampling the cost densely over the parameter domain and searching around the solution."""
import numpy as np
import pytest

from skinkit._checks import SkinkitError
from skinkit.lod import build_chain
from skinkit.model import AnimationSpaceModel

from tests.core.test_lod_chain import bending_model, grid, statistics, uv_areas


def lattice(steps: int) -> np.ndarray:
    """Barycentric points of a triangle on a lattice of `steps` divisions."""
    i, j = np.meshgrid(np.arange(steps + 1), np.arange(steps + 1), indexing="ij")
    keep = i + j <= steps
    a, b = i[keep] / steps, j[keep] / steps
    return np.stack([1 - a - b, a, b], 1)


def dense_coordinates(model: AnimationSpaceModel) -> np.ndarray:
    """(V, 4b): each vertex's coordinates laid out by bone."""
    out = np.zeros((model.vertex_count, 4 * model.bone_count))
    vertex = model.vertex_of_each_influence()
    for c in range(4):
        out[vertex, 4 * model.bones + c] = model.coordinates[:, c]
    return out


def locate(points: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each 2D point, a triangle (of corners (T, 3, 2)) containing it and its barycentric coordinates there."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    e1, e2 = b - a, c - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    d = points[:, None, :] - a[None]
    s = (d[..., 0] * e2[:, 1] - d[..., 1] * e2[:, 0]) / det
    t = (e1[:, 0] * d[..., 1] - e1[:, 1] * d[..., 0]) / det
    inside = np.minimum(np.minimum(s, t), 1 - s - t)
    face = inside.argmax(1)
    rows = np.arange(len(points))
    assert (inside[rows, face] > -1e-9).all()
    return face, np.stack([1 - s[rows, face] - t[rows, face], s[rows, face], t[rows, face]], 1)


class SampledCost:
    """The memoryless APS cost of replacing level `fine` by level `coarse`, sampled: the largest L2,2 deviation over
    lattice points of every fine triangle, each point's partner the coarse triangle holding it in UV."""

    def __init__(self, fine, coarse, stats, steps=20):
        weights = lattice(steps)
        points = np.einsum("pk,tkd->tpd", weights, fine.uv.reshape(-1, 3, 2)).reshape(-1, 2)
        fine_values = dense_coordinates(fine.model)[fine.triangles]
        self.old = np.einsum("pk,tkd->tpd", weights, fine_values).reshape(len(points), -1)
        face, self.weights = locate(points, coarse.uv.reshape(-1, 3, 2))
        self.corners = coarse.triangles[face]
        self.values = dense_coordinates(coarse.model)
        self.p = stats.matrix()

    def __call__(self, survivor: int, coordinates: np.ndarray) -> float:
        """The cost with the coarse level's vertex `survivor` (its index there) at `coordinates` (4b)."""
        values = self.values.copy()
        values[survivor] = coordinates
        deviation = self.old - np.einsum("pk,pkd->pd", self.weights, values[self.corners])
        return float(np.sqrt(np.einsum("pd,de,pe->p", deviation, self.p, deviation).max()))


def first_full_collapse():
    """A chain of single collapses on a curved grid and the first one that is a full collapse: (fine, coarse)."""
    rest, tris = grid(7, curvature=0.4)
    uv = rest[tris][:, :, :2].reshape(-1, 6)
    model, stats = bending_model(rest), statistics()
    chain = build_chain(tris, rest, model, stats, uv=uv, simplify_influences=False, collapse="full", refit=False,
                        targets={"triangles": [len(tris) - 2 * k for k in range(1, 25)]})
    for fine, coarse in zip(chain.levels[:-1], chain.levels[1:]):
        if coarse.report["full_collapses"] == 1:
            assert coarse.report["edge_collapses"] == 1
            return stats, fine, coarse
    raise AssertionError("no full collapse in the first 24 collapses")


def pattern_search(cost, start: np.ndarray, directions: np.ndarray, step: float, rounds: int = 40) -> float:
    """Compass search: the least cost found moving along +-directions, halving the step when none helps."""
    best_x, best = start.copy(), cost(start)
    for _ in range(rounds):
        improved = False
        for d in np.concatenate([directions, -directions]):
            value = cost(best_x + step * d)
            if value < best:
                best_x, best, improved = best_x + step * d, value, True
        if not improved:
            step /= 2
    return best


def test_full_collapse_position_is_the_brute_force_minimiser():
    stats, fine, coarse = first_full_collapse()
    sampled = SampledCost(fine, coarse, stats)
    fine_values = dense_coordinates(fine.model)
    at_fine = np.searchsorted(fine.vertices, coarse.vertices)
    moved = np.flatnonzero(np.abs(sampled.values - fine_values[at_fine]).max(1) > 0)
    assert len(moved) == 1
    survivor = int(moved[0])
    solved, original = sampled.values[survivor], fine_values[at_fine[survivor]]
    solved_cost, half_cost = sampled(survivor, solved), sampled(survivor, original)
    cost = coarse.epsilon  # the largest cost so far: this collapse's, or an earlier one's
    # the C cost is the exact maximum at the overlay's corners; lattice points come close from below
    assert solved_cost <= cost * (1 + 1e-9)
    assert solved_cost < 0.95 * half_cost  # the solve gains over keeping v where it was
    # moves of v's coordinates that keep its weights' sum: x, y, z per bone, weight 0 minus weight 1
    directions = np.zeros((7, 8))
    for k, index in enumerate((0, 1, 2, 4, 5, 6)):
        directions[k, index] = 1.0
    directions[6, 3], directions[6, 7] = 1.0, -1.0
    searched = pattern_search(lambda x: sampled(survivor, x), solved, directions, step=0.05)
    from_half = pattern_search(lambda x: sampled(survivor, x), original, directions, step=0.05)
    assert solved_cost <= 1.02 * min(searched, from_half)


def test_full_collapses_keep_the_mesh_sound_and_lower_epsilon():
    rest, tris = grid(12, curvature=0.4)
    uv = rest[tris][:, :, :2].reshape(-1, 6)
    model, stats = bending_model(rest), statistics()
    targets = {"triangles": [120, 60, 30]}
    half = build_chain(tris, rest, model, stats, uv=uv, targets=targets, collapse="half")
    for collapse in ("full", "auto"):
        chain = build_chain(tris, rest, model, stats, uv=uv, targets=targets, collapse=collapse)
        assert sum(level.report["full_collapses"] for level in chain.levels[1:]) > 0
        for ours, theirs, target in zip(chain.levels[1:], half.levels[1:], targets["triangles"]):
            assert ours.triangle_count <= target
            assert ours.epsilon < theirs.epsilon
            assert (uv_areas(ours.uv) > 0).all()
            assert ours.influence_count <= model.influence_count
            # manifold and closed where the input was: every interior edge has two faces, each edge at most two
            edges = np.sort(np.concatenate([ours.triangles[:, [0, 1]], ours.triangles[:, [1, 2]],
                                            ours.triangles[:, [2, 0]]]), axis=1)
            _, uses = np.unique(edges, axis=0, return_counts=True)
            assert uses.max() <= 2
            # the homogeneous weights still sum to one
            sums = np.add.reduceat(ours.model.coordinates[:, 3], ours.model.offsets[:-1])
            np.testing.assert_allclose(sums, 1.0, atol=1e-12)


@pytest.mark.parametrize("collapse", ["full", "auto"])
def test_tuned_chains_stay_memoryless(collapse):
    """A level reached in two runs of the queue is the level reached in one (costs depend on the current mesh only,
    full collapses' moved survivors included)."""
    rest, tris = grid(10, curvature=0.5)
    uv = rest[tris][:, :, :2].reshape(-1, 6)
    model, stats = bending_model(rest), statistics()
    options = dict(uv=uv, collapse=collapse, rank_per_influence=True, influence_cost_scale=2.0)
    steps = build_chain(tris, rest, model, stats, targets={"triangles": [60, 20]}, **options)
    once = build_chain(tris, rest, model, stats, targets={"triangles": [20]}, **options)
    a, b = steps.levels[2], once.levels[1]
    np.testing.assert_array_equal(a.vertices[a.triangles], b.vertices[b.triangles])
    np.testing.assert_array_equal(a.model.coordinates, b.model.coordinates)
    assert a.epsilon == b.epsilon and sum(level.report["full_collapses"] for level in steps.levels[1:]) > 0


def test_influence_cost_scale_moves_the_balance():
    rest, tris = grid(9, curvature=0.3)
    model, stats = bending_model(rest), statistics()
    cheap = build_chain(tris, rest, model, stats, levels=2, influence_cost_scale=1e-3)
    dear = build_chain(tris, rest, model, stats, levels=2, influence_cost_scale=1e3)
    assert cheap.levels[1].report["influence_collapses"] > dear.levels[1].report["influence_collapses"]
    assert cheap.levels[1].report["edge_collapses"] < dear.levels[1].report["edge_collapses"]


def test_rank_per_influence_prefers_removing_vertices_with_more_influences():
    """Vertices with x < 0.5 blend two bones, the others one: ranked per influence removed, the edge collapses that
    remove two-influence vertices come earlier than ranked by cost."""
    rest, tris = grid(11, curvature=0.3)
    blended = bending_model(rest)
    single = rest[:, 0] >= 0.5
    counts = np.where(single, 1, 2)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    coordinates = blended.coordinates.reshape(-1, 2, 4).copy()
    coordinates[single, 0] = np.column_stack([rest[single], np.ones(single.sum())])
    keep = np.repeat(~single, 2) | np.tile([True, False], len(rest))
    model = AnimationSpaceModel.create(offsets, np.tile([0, 1], len(rest))[keep],
                                       coordinates.reshape(-1, 4)[keep], 2)
    stats = statistics()

    def removed_share(rank_per_influence):
        chain = build_chain(tris, rest, model, stats, simplify_influences=False, targets={"triangles": [120]},
                            rank_per_influence=rank_per_influence)
        gone = np.setdiff1d(np.arange(len(rest)), chain.levels[1].vertices)
        return np.mean(counts[gone] == 2)

    assert removed_share(True) > removed_share(False)


def test_start_influences_limits_level_zero():
    rest, tris = grid(7, curvature=0.3)
    model, stats = bending_model(rest), statistics()
    chain = build_chain(tris, rest, model, stats, levels=3, start_influences=1)
    assert np.diff(chain.levels[0].model.offsets).max() == 1
    assert chain.levels[0].epsilon > 0
    assert chain.levels[1].influence_count <= chain.levels[0].influence_count // 2
    same = build_chain(tris, rest, model, stats, levels=2, start_influences=2)  # already within the budget
    np.testing.assert_array_equal(same.levels[0].model.coordinates, model.coordinates)
    assert same.levels[0].epsilon == 0.0


@pytest.mark.parametrize("options, message", [({"collapse": "quarter"}, "collapse"),
                                              ({"collapse": 1}, "collapse"),
                                              ({"influence_cost_scale": 0.0}, "influence_cost_scale"),
                                              ({"influence_cost_scale": float("nan")}, "influence_cost_scale"),
                                              ({"start_influences": 0}, "start_influences")])
def test_bad_tuning(options, message):
    rest, tris = grid(4)
    with pytest.raises(SkinkitError, match=message):
        build_chain(tris, rest, bending_model(rest), statistics(), levels=2, **options)
