"""skinkit.lod.build_chain: progressive meshes with influence simplification (Merry 2007, chapters 6-7)."""
import numpy as np
import pytest

from skinkit import _core
from skinkit._checks import SkinkitError
from skinkit.lod import LodChain, build_chain
from skinkit.metrics import PoseStatistics
from skinkit.model import AnimationSpaceModel


def grid(n, curvature=0.0):
    xs = np.linspace(0.0, 1.0, n)
    x, y = np.meshgrid(xs, xs)
    x, y = x.ravel(), y.ravel()
    rest = np.stack([x, y, curvature * 16 * x * (1 - x) * y * (1 - y)], 1)  # the sides stay straight
    tris = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            tris += [(a, a + 1, a + n + 1), (a, a + n + 1, a + n)]
    return rest, np.array(tris, np.int32)


def statistics(bones=2, samples=16):
    parents = np.array([-1] + [0] * (bones - 1), np.int32)
    local = np.tile(np.eye(4), (samples, bones, 1, 1))
    for s in range(samples):
        for b in range(1, bones):
            a = 0.5 * np.sin(1.7 * s + b)
            local[s, b, :3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
            local[s, b, :3, 3] = [0.5, 0.0, 0.0]
    return PoseStatistics.from_local_samples(parents, local)


def bending_model(rest):
    """Bone 1's weight grows with x: a blend of the root and the bending bone (both at the rest pose = identity)."""
    v = len(rest)
    w = 0.8 * rest[:, 0]
    coords = np.zeros((2 * v, 4))
    coords[0::2, :3] = (1 - w)[:, None] * rest
    coords[0::2, 3] = 1 - w
    coords[1::2, :3] = w[:, None] * (rest - [0.5, 0.0, 0.0])
    coords[1::2, 3] = w
    return AnimationSpaceModel.create(np.arange(0, 2 * v + 1, 2), np.tile([0, 1], v), coords, 2)


def rigid_redundant_model(rest):
    v = len(rest)
    coords = np.zeros((2 * v, 4))
    coords[0::2, :3] = rest
    coords[0::2, 3] = 1.0
    return AnimationSpaceModel.create(np.arange(0, 2 * v + 1, 2), np.tile([0, 1], v), coords, 2)


def two_charts(rest, tris, split=0.5):
    charts = (rest[tris][:, :, 0].mean(1) > split).astype(np.int32)
    uv = rest[tris][:, :, :2].copy()
    uv[charts == 1, :, 0] += 2.0
    return uv.reshape(-1, 6), charts


def uv_areas(uv):
    c = uv.reshape(-1, 3, 2)
    e1, e2 = c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]
    return e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]


def rest_normals(positions, tris):
    p = positions[tris]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def test_flat_grid_chart_collapses_to_two_triangles():
    rest, tris = grid(9)
    uv = rest[tris][:, :, :2].reshape(-1, 6)
    chain = build_chain(tris, rest, bending_model(rest), statistics(), uv=uv, targets={"triangles": [2]})
    coarse = chain.levels[1]
    assert coarse.triangle_count == 2
    assert (uv_areas(coarse.uv) > 0).all()
    assert sorted(coarse.vertices) == [0, 8, 72, 80]


def squashed_fan(height):
    """Six faces around u (vertex 0) on a hexagon squashed to a band 0.1 wide, u raised by `height`: collapsing u onto
    any corner leaves faces thinner than 0.05 (twice the area over the longest edge squared), in the plane."""
    angles = np.arange(6) * np.pi / 3
    ring = np.stack([np.cos(angles), 0.05 * np.sin(angles), np.zeros(6)], 1)
    tris = np.array([(0, 1 + i, 1 + (i + 1) % 6) for i in range(6)], np.int32)
    return np.vstack([[0.0, 0.0, height], ring]), tris


@pytest.mark.parametrize("height, collapsed", [(0.0, True), (0.5, False)])
def test_no_collapse_makes_a_thin_face_that_turns(height, collapsed):
    # Flat, the thin faces lie where the old ones did and u goes; raised, each would turn about 85 degrees from the
    # face it replaces (a dent in the shading), so u stays and the chain stops with a warning.
    rest, tris = squashed_fan(height)
    model = AnimationSpaceModel.create(np.arange(8), np.zeros(7, np.int32), np.hstack([rest, np.ones((7, 1))]), 1)
    with pytest.warns(UserWarning):
        chain = build_chain(tris, rest, model, statistics(bones=1), levels=2, metric="rest",
                            simplify_influences=False, targets={"triangles": [4]})
    assert (len(chain.levels) == 2) == collapsed
    if collapsed:
        assert chain.levels[1].triangle_count == 4


def test_rigid_redundant_influences_go_at_zero_cost():
    rest, tris = grid(6, curvature=0.4)
    model = rigid_redundant_model(rest)
    chain = build_chain(tris, rest, model, statistics(), uv=rest[tris][:, :, :2].reshape(-1, 6),
                        targets={"influences": [len(rest)]}, refit=False)  # the collapses' own coordinates
    coarse = chain.levels[1]
    assert coarse.triangle_count == len(tris)
    assert coarse.epsilon == 0.0
    assert coarse.report["influence_collapses"] == len(rest)
    assert (coarse.model.bones == 0).all()
    np.testing.assert_array_equal(coarse.model.coordinates, model.coordinates[0::2])


@pytest.fixture(scope="module")
def chain():
    rest, tris = grid(11, curvature=0.5)
    uv, charts = two_charts(rest, tris)
    model = bending_model(rest)
    built = build_chain(tris, rest, model, statistics(), uv=uv, charts=charts, levels=4)
    return rest, tris, uv, charts, model, built


def test_level_zero_is_the_input(chain):
    rest, tris, uv, charts, model, built = chain
    assert isinstance(built, LodChain) and len(built.levels) == 4
    lod0 = built.levels[0]
    np.testing.assert_array_equal(lod0.vertices, np.arange(len(rest)))
    np.testing.assert_array_equal(lod0.triangles, tris)
    np.testing.assert_array_equal(lod0.model.coordinates, model.coordinates)
    np.testing.assert_array_equal(lod0.uv, uv)
    assert lod0.epsilon == 0.0


def test_levels_halve_influences_and_are_sound(chain):
    rest, tris, uv, charts, model, built = chain
    original_boundary = set(np.where((rest[:, 0] % 1 == 0) | (rest[:, 1] % 1 == 0))[0])
    for previous, level in zip(built.levels, built.levels[1:]):
        assert level.influence_count <= previous.influence_count // 2
        assert level.epsilon >= previous.epsilon
        assert level.relative_epsilon == pytest.approx(level.epsilon / built.diagonal)
        global_tris = level.vertices[level.triangles]
        _core.validate_surface(np.ascontiguousarray(global_tris, np.int32), len(rest))
        # no flipped or degenerate triangle in UV or the rest pose
        assert (uv_areas(level.uv) > 0).all()
        assert (np.einsum("ij,ij->i", rest_normals(rest, global_tris), rest_normals(rest, tris[level.triangle_origin]))
                > 0).all()
        # every UV inside its chart's original region (chart 0: [0, .5] x [0, 1], chart 1: [2.5, 3] x [0, 1])
        c = level.uv.reshape(-1, 3, 2)
        low = np.where(level.charts == 0, 0.0, 2.5)[:, None]
        assert ((c[..., 0] >= low - 1e-12) & (c[..., 0] <= low + 0.5 + 1e-12)).all()
        assert level.charts.tolist() == charts[level.triangle_origin].tolist()
        # boundary edges: ends on the original boundary, midpoints on the square's sides (straight in 3D)
        edges = np.sort(np.concatenate([global_tris[:, [0, 1]], global_tris[:, [1, 2]], global_tris[:, [2, 0]]]), 1)
        unique, count = np.unique(edges, axis=0, return_counts=True)
        border = unique[count == 1]
        assert set(border.ravel()) <= original_boundary
        mid = rest[border].mean(1)
        assert (np.isclose(mid[:, 0] % 1, 0) | np.isclose(mid[:, 1] % 1, 0)).all()
        # seam edges (between the two charts) lie along x = 0.5 in 3D
        sides = {}
        for t, tri in enumerate(global_tris):
            for k in range(3):
                key = tuple(sorted((tri[k], tri[(k + 1) % 3])))
                sides.setdefault(key, []).append(level.charts[t])
        seam = np.array([key for key, owners in sides.items() if len(set(owners)) == 2])
        assert len(seam) and np.allclose(rest[seam][:, :, 0], 0.5)


def test_geomorph_exact_at_integers_and_continuous(chain):
    rest, tris, uv, charts, model, built = chain
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, :3, :3] = [[0.8, -0.6, 0], [0.6, 0.8, 0], [0, 0, 1]]
    for index, level in enumerate(built.levels):
        m, u, t = built.geomorph(index)
        assert m is level.model and u is level.uv and t is level.triangles
    for index, (fine, coarse) in enumerate(zip(built.levels, built.levels[1:])):
        m, u, t = built.geomorph(index + 1 - 1e-12)
        near = m.evaluate(poses)
        np.testing.assert_allclose(near, coarse.model.evaluate(poses)[fine.to_coarser], atol=1e-9)
        a, _, _ = built.geomorph(index + 0.5)
        b, _, _ = built.geomorph(index + 0.5 + 1e-6)
        assert np.abs(a.evaluate(poses) - b.evaluate(poses)).max() < 1e-5
        m0, _, _ = built.geomorph(index + 1e-12)
        np.testing.assert_allclose(m0.evaluate(poses), fine.model.evaluate(poses), atol=1e-9)
        # the common influence set: the fine vertex's bones plus its coarser vertex's, padded with zeros
        assert m.influence_count >= fine.influence_count
        assert u is not None and u.shape == fine.uv.shape


def test_chain_by_steps_equals_one_call():
    rest, tris = grid(10, curvature=0.5)
    uv, charts = two_charts(rest, tris, split=0.45)
    model, stats = bending_model(rest), statistics()
    steps = build_chain(tris, rest, model, stats, uv=uv, charts=charts, targets={"triangles": [60, 20]})
    once = build_chain(tris, rest, model, stats, uv=uv, charts=charts, targets={"triangles": [20]})
    a, b = steps.levels[2], once.levels[1]
    np.testing.assert_array_equal(a.vertices[a.triangles], b.vertices[b.triangles])
    np.testing.assert_array_equal(a.model.coordinates, b.model.coordinates)
    np.testing.assert_array_equal(a.uv, b.uv)
    assert a.epsilon == b.epsilon


def test_rest_metric_and_no_influence_collapses():
    rest, tris = grid(8, curvature=0.5)
    uv, charts = two_charts(rest, tris)
    built = build_chain(tris, rest, bending_model(rest), statistics(), uv=uv, charts=charts, metric="rest",
                        simplify_influences=False, targets={"triangles": [30]})
    assert built.levels[1].report["influence_collapses"] == 0
    assert built.levels[1].triangle_count <= 30


def test_no_uv_warns_and_builds():
    rest, tris = grid(8, curvature=0.3)
    with pytest.warns(UserWarning, match="no UVs"):
        built = build_chain(tris, rest, bending_model(rest), statistics(), levels=3)
    assert any("no UVs" in w for w in built.warnings)
    assert built.levels[-1].triangle_count < len(tris)


def test_too_many_levels_stop_early():
    rest, tris = grid(4)
    with pytest.warns(UserWarning, match="stopped at"):
        built = build_chain(tris, rest, bending_model(rest), statistics(), uv=rest[tris][:, :, :2].reshape(-1, 6),
                            levels=12)
    assert len(built.levels) < 12


def test_bad_inputs():
    rest, tris = grid(5)
    model, stats = bending_model(rest), statistics()
    uv = rest[tris][:, :, :2].reshape(-1, 6)
    with pytest.raises(SkinkitError, match="levels"):
        build_chain(tris, rest, model, stats, uv=uv, levels=0)
    with pytest.raises(SkinkitError, match="stale"):
        build_chain(tris, rest, model, statistics(bones=3), uv=uv)
    with pytest.raises(SkinkitError, match="metric"):
        build_chain(tris, rest, model, stats, uv=uv, metric="euclid")
    bad = np.concatenate([tris, [[0, 1, 7]]]).astype(np.int32)  # a third face on edge (0, 1)... and disagreeing
    with pytest.raises(SkinkitError, match="faces"):
        build_chain(bad, rest, model, stats)
    flat = rest.copy()
    flat[:, 1] = 0.0
    with pytest.raises(SkinkitError, match="degenerate"):
        build_chain(tris, flat, model, stats, uv=uv)
    with pytest.raises(SkinkitError, match="uv"):
        build_chain(tris, rest, model, stats, uv=uv[:-1])
    with pytest.raises(SkinkitError, match="not an edge"):
        build_chain(tris, rest, model, stats, uv=uv, locked_edges=[[0, 24]])
    with pytest.raises(SkinkitError, match="targets"):
        build_chain(tris, rest, model, stats, uv=uv, targets={"vertices": [3]})


def test_locked_edges_survive():
    rest, tris = grid(7)
    uv = rest[tris][:, :, :2].reshape(-1, 6)
    path = [8, 16, 24, 25, 26]  # bent at 24
    with pytest.warns(UserWarning, match="no legal collapse"):
        built = build_chain(tris, rest, bending_model(rest), statistics(), uv=uv,
                            locked_edges=list(zip(path[:-1], path[1:])), targets={"triangles": [2]})
    kept = set(built.levels[-1].vertices)
    assert {8, 24, 26} <= kept


def chain_by_steps(tris, rest, model, stats, uv, charts, locked, levels, metric="animation", influences=True):
    """The level-by-level path: one simplify_step per level on the level before, to half its influences."""
    from skinkit.lod.chain import simplify_step

    current = {"triangles": tris, "uv": uv, "origin": np.arange(len(tris), dtype=np.int32),
               "offsets": model.offsets.astype(np.int32), "bones": model.bones.astype(np.int32),
               "coordinates": np.ascontiguousarray(model.coordinates), "locked": locked, "influences":
               model.influence_count}
    steps, epsilon = [], 0.0
    for _ in range(levels):
        out = simplify_step(current["triangles"], rest.reshape(-1), current["offsets"], current["bones"],
                            current["coordinates"], stats, uv=current["uv"],
                            charts=np.ascontiguousarray(charts[current["origin"]]), locked=current["locked"],
                            target_influences=current["influences"] // 2, metric=metric,
                            simplify_influences=influences)
        epsilon = max(epsilon, out["report"]["epsilon"])
        current = {"triangles": out["triangles"], "uv": out["uv"], "origin": current["origin"][out["triangle_origin"]],
                   "offsets": out["offsets"], "bones": out["bones"], "coordinates": out["coordinates"],
                   "locked": out["locked"], "influences": out["report"]["influence_count"]}
        steps.append((current, out["vertex_map"], epsilon))
        if out["report"]["exhausted"]:
            break
    return steps


def survivors(offsets, bones, coordinates, vertices):
    return [(bones[offsets[x]:offsets[x + 1]].tolist(), coordinates[offsets[x]:offsets[x + 1]]) for x in vertices]


@pytest.mark.parametrize("metric,influences", [("animation", True), ("animation", False), ("rest", False)])
def test_one_run_equals_chained_single_calls(metric, influences):
    """sk_simplify_chain's levels equal sk_simplify called on each level before (costs are memoryless)."""
    from skinkit.lod.chain import simplify_levels

    rest, tris = grid(12, curvature=0.5)
    rest[:, 2] += 0.03 * np.sin(7.0 * rest[:, 0]) * np.cos(5.0 * rest[:, 1])  # no ties of cost
    uv, charts = two_charts(rest, tris, split=0.45)
    model, stats = bending_model(rest), statistics()
    locked = np.zeros((len(tris), 3), np.uint8)
    locked[40, 0] = 1
    levels = 4
    steps = chain_by_steps(tris, rest, model, stats, uv, charts, locked, levels, metric, influences)
    written, report = simplify_levels(tris, rest.reshape(-1), model.offsets.astype(np.int32),
                                      model.bones.astype(np.int32), np.ascontiguousarray(model.coordinates), stats,
                                      targets=[(0, 0)] * levels, uv=uv, charts=charts, locked=locked, metric=metric,
                                      simplify_influences=influences)
    assert report["level_count"] == len(steps) >= 2
    assert report["exhausted"] == (len(steps) < levels)
    for (step, step_map, step_epsilon), level in zip(steps, written):
        np.testing.assert_array_equal(level["triangles"], step["triangles"])
        np.testing.assert_array_equal(level["triangle_origin"], step["origin"])
        np.testing.assert_array_equal(level["uv"], step["uv"])
        np.testing.assert_array_equal(level["locked"], step["locked"])
        kept = np.unique(step["triangles"])
        np.testing.assert_array_equal(level["vertex_map"][kept], kept)
        ours = survivors(level["offsets"], level["bones"], level["coordinates"], kept)
        theirs = survivors(step["offsets"], step["bones"], step["coordinates"], kept)
        for (bones_a, coordinates_a), (bones_b, coordinates_b) in zip(ours, theirs):
            assert bones_a == bones_b
            np.testing.assert_array_equal(coordinates_a, coordinates_b)
        assert level["report"]["epsilon"] == step_epsilon
        assert level["report"]["influence_count"] == step["influences"]
    assert written[-1]["report"]["triangle_count"] < len(tris) // 2


def test_chain_vertex_maps_point_to_the_level_above(chain):
    rest, tris, uv, charts, model, built = chain
    for fine, coarse in zip(built.levels, built.levels[1:]):
        assert (coarse.vertices[fine.to_coarser] >= 0).all()
        assert set(coarse.vertices) <= set(fine.vertices)
        # a surviving vertex maps to itself
        same = np.isin(fine.vertices, coarse.vertices)
        np.testing.assert_array_equal(coarse.vertices[fine.to_coarser[same]], fine.vertices[same])


def test_chain_progress_cancels():
    rest, tris = grid(40, curvature=0.4)
    calls = []

    def cancel(fraction):
        calls.append(fraction)
        return True

    with pytest.raises(SkinkitError, match="cancel"):
        build_chain(tris, rest, bending_model(rest), statistics(), uv=rest[tris][:, :, :2].reshape(-1, 6), levels=5,
                    progress=cancel)
    assert len(calls) == 1 and 0.0 <= calls[0] <= 1.0


def test_chain_progress_rises_through_the_levels():
    rest, tris = grid(40, curvature=0.4)
    seen = []
    build_chain(tris, rest, bending_model(rest), statistics(), uv=rest[tris][:, :, :2].reshape(-1, 6), levels=5,
                progress=lambda fraction: seen.append(fraction) or False)
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(seen) > 2


def test_two_costing_threads_give_the_same_bits():
    """A 2,500-vertex grid with two charts (threads=2 starts the helper thread at any size), its chain refitted: every
    level's triangles, UVs, influences and coordinates, epsilon and geomorph data the same on one thread and on two."""
    rest, tris = grid(50, curvature=0.5)
    uv, charts = two_charts(rest, tris)
    model, stats = bending_model(rest), statistics()
    one, two = (build_chain(tris, rest, model, stats, uv=uv, charts=charts, levels=5, threads=threads)
                for threads in (1, 2))
    assert len(one.levels) == len(two.levels) == 5
    for a, b in zip(one.levels, two.levels):
        assert np.array_equal(a.triangles, b.triangles) and np.array_equal(a.vertices, b.vertices)
        assert np.array_equal(a.uv, b.uv) and a.epsilon == b.epsilon
        assert np.array_equal(a.model.offsets, b.model.offsets) and np.array_equal(a.model.bones, b.model.bones)
        assert np.array_equal(a.model.coordinates, b.model.coordinates)
    for a, b in zip(one.levels[:-1], two.levels[:-1]):
        assert np.array_equal(a.morph_delta, b.morph_delta)
