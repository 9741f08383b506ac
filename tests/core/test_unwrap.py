"""The unwrap pipeline on numpy meshes: developable surfaces flatten without stretch, the metrics agree
with each other where they must, charts are discs, and bad meshes are refused by name."""
import numpy as np
import pytest

from skinkit import SkinkitError, Skeleton, SparseWeights, convert_lbs
from skinkit.flatten import triangle_stretch
from skinkit.metrics import PoseStatistics
from skinkit.unwrap import (SEGMENTATION_DIMENSIONS, animation_embedding, chart_boundaries, edge_lengths_sq, segmentation_embedding,
                            sampled_animation_embedding, sequence_embedding, texture_seams, unwrap)


def grid_triangles(columns: int, rows: int) -> np.ndarray:
    """Two triangles per cell of a columns x rows vertex grid, numbered row by row."""
    cells = [(r * columns + c) for r in range(rows - 1) for c in range(columns - 1)]
    return np.array([t for q in cells for t in ((q, q + 1, q + columns + 1), (q, q + columns + 1, q + columns))])


def cylinder_patch(columns=24, rows=12, angle=3.0, radius=1.0, height=2.0):
    a, z = np.meshgrid(np.linspace(0, angle, columns), np.linspace(0, height, rows))
    return np.column_stack([radius * np.cos(a.ravel()), radius * np.sin(a.ravel()), z.ravel()]), \
        grid_triangles(columns, rows)


def cone_patch(columns=24, rows=12, angle=2.5):
    a, s = np.meshgrid(np.linspace(0, angle, columns), np.linspace(0.3, 1.5, rows))
    return np.column_stack([0.5 * s.ravel() * np.cos(a.ravel()), 0.5 * s.ravel() * np.sin(a.ravel()),
                            0.8 * s.ravel()]), grid_triangles(columns, rows)


def capsule(columns=16, rows=20):
    """A closed surface (a cylinder with pointed caps): it must be cut into several disc charts."""
    a = np.linspace(0, 2 * np.pi, columns, endpoint=False)
    heights = np.linspace(-1.5, 1.5, rows)
    radii = np.sqrt(np.clip(1.0 - np.clip(np.abs(heights) - 0.5, 0, None) ** 2, 0.05, None))
    ring = np.column_stack([np.cos(a), np.sin(a)])
    positions = np.concatenate([np.column_stack([r * ring, np.full(columns, h)]) for r, h in zip(radii, heights)])
    positions = np.vstack([positions, [0, 0, -1.6], [0, 0, 1.6]])
    bottom, top = len(positions) - 2, len(positions) - 1
    triangles = []
    for row in range(rows - 1):
        for c in range(columns):
            a0, a1 = row * columns + c, row * columns + (c + 1) % columns
            b0, b1 = a0 + columns, a1 + columns
            triangles += [(a0, a1, b1), (a0, b1, b0)]
    for c in range(columns):
        triangles.append((bottom, (c + 1) % columns, c))
        last = (rows - 1) * columns
        triangles.append((top, last + c, last + (c + 1) % columns))
    return positions, np.array(triangles)


def signed_uv_areas(uv: np.ndarray) -> np.ndarray:
    first, second = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return (first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0]) / 2


def is_disc(triangles: np.ndarray) -> bool:
    """Connected, Euler characteristic 1 and one boundary loop: a topological disc."""
    edges = np.sort(np.stack([triangles, np.roll(triangles, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    vertices = np.unique(triangles)
    if len(vertices) - len(unique) + len(triangles) != 1:
        return False
    boundary = unique[counts == 1]
    if len(boundary) == 0 or len(np.unique(boundary)) != len(boundary):  # one loop: as many vertices as edges
        return False
    neighbours = {}
    for a, b in boundary:
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    start = boundary[0, 0]
    previous, current, length = start, neighbours[start][0], 1
    while current != start:
        previous, current = current, next(n for n in neighbours[current] if n != previous)
        length += 1
    return length == len(boundary)


@pytest.mark.parametrize("surface", [cylinder_patch, cone_patch])
def test_developable_surfaces_unwrap_without_stretch(surface):
    positions, triangles = surface()
    result = unwrap(positions, triangles, straighten=False)
    assert abs(result.report["stretch_rest"] - 1.0) < 1e-6
    assert result.report["stretch_metric"] == result.report["stretch_rest"]
    assert np.all(signed_uv_areas(result.uv) > 0)
    assert result.uv.min() >= 0 and result.uv.max() <= 1
    assert 0 < result.report["packing_efficiency"] <= 1
    assert result.report["texture_efficiency"] == pytest.approx(result.report["packing_efficiency"]
                                                                / result.report["stretch_metric"] ** 2)


def test_closed_mesh_charts_are_discs_without_flips():
    positions, triangles = capsule()
    result = unwrap(positions, triangles, evaluation_frames=np.stack([positions, positions * 1.5]))
    assert result.report["charts"] >= 2
    for chart in range(result.report["charts"]):
        assert is_disc(triangles[result.charts == chart]), f"chart {chart} is not a disc"
    assert np.all(signed_uv_areas(result.uv) > 0)
    assert np.isfinite(triangle_stretch(result.uv, edge_lengths_sq(positions, triangles))).all()
    assert result.report["stretch_frames"] == pytest.approx(result.report["stretch_rest"])  # scaling: no stretch
    np.testing.assert_array_equal(result.seams, chart_boundaries(triangles, result.charts))


def test_seams_only_mode_takes_the_seams_as_the_charts():
    positions, triangles = cylinder_patch(columns=10, rows=6)
    seams = np.array([(r * 10 + 4, (r + 1) * 10 + 4) for r in range(5)])  # a vertical line of vertex column 4
    result = unwrap(positions, triangles, seams=seams, mode="seams", straighten=False)
    assert result.report["charts"] == 2
    np.testing.assert_array_equal(result.seams, np.sort(seams, axis=1))


def test_loose_vertices_are_left_out_of_the_atlas():
    positions, triangles = cone_patch(columns=8, rows=5)
    with_loose = np.vstack([positions[:3], [[5.0, 5.0, 5.0]], positions[3:]])
    shifted = np.where(triangles >= 3, triangles + 1, triangles)
    plain, loose = unwrap(positions, triangles), unwrap(with_loose, shifted)
    assert loose.report["loose_vertices"] == 1 and plain.report["loose_vertices"] == 0
    np.testing.assert_allclose(loose.uv, plain.uv, atol=1e-12)


def test_sequence_metric_is_the_frame_average_of_edge_inner_products():
    positions, triangles = cylinder_patch(columns=6, rows=4)
    rng = np.random.default_rng(7)
    frames = positions + rng.normal(scale=0.05, size=(5,) + positions.shape)
    averaged = np.mean([edge_lengths_sq(frame, triangles) for frame in frames], axis=0)
    np.testing.assert_allclose(edge_lengths_sq(sequence_embedding(frames), triangles), averaged, rtol=1e-12)


def two_bone_model(positions):
    """A chain of two bones along z with blended weights, its rest frames moved off the identity."""
    rest = np.tile(np.eye(4), (3, 1, 1))
    rest[1, :3, 3], rest[2, :3, 3] = (0.1, 0.0, 0.2), (0.0, 0.3, 1.0)
    rest[2, :3, :3] = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    skeleton = Skeleton.create([-1, 0, 1], rest)
    upper = np.clip(positions[:, 2], 0, 1)
    weights = SparseWeights.from_dense(np.column_stack([np.zeros(len(positions)), 1 - upper, upper]))
    return skeleton, convert_lbs(skeleton, weights, positions)


def test_animation_metric_of_a_fixed_skeleton_is_the_euclidean_metric():
    positions, triangles = cylinder_patch(columns=8, rows=5)
    skeleton, model = two_bone_model(positions)
    fixed = PoseStatistics.from_world_samples(skeleton.parents, skeleton.rest_frames[None])
    embedding = animation_embedding(model, fixed)
    assert embedding.shape == (len(positions), 12)
    np.testing.assert_allclose(edge_lengths_sq(embedding, triangles), edge_lengths_sq(positions, triangles),
                               rtol=1e-9, atol=1e-12)


def test_animation_metric_of_sampled_poses_matches_their_sequence():
    """With one joint sampled (the other fixed), P's independent-joints estimate is exact, so animation space
    and the mesh sequence of the same poses give the same metric."""
    positions, triangles = cylinder_patch(columns=8, rows=5)
    skeleton, model = two_bone_model(positions)
    angles = np.linspace(-0.8, 0.8, 7)
    poses = np.tile(skeleton.rest_frames, (len(angles), 1, 1, 1))
    for pose, angle in zip(poses, angles):
        turn = np.eye(4)
        turn[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
        pose[2] = pose[1] @ np.linalg.solve(skeleton.rest_frames[1], skeleton.rest_frames[2]) @ turn
    statistics = PoseStatistics.from_world_samples(skeleton.parents, poses)
    np.testing.assert_allclose(edge_lengths_sq(animation_embedding(model, statistics), triangles),
                               edge_lengths_sq(sequence_embedding(model.evaluate(poses)), triangles), rtol=1e-8)


def y_turn(angle: float) -> np.ndarray:
    turn = np.eye(4)
    turn[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    return turn


def test_sampled_animation_metric_is_the_action_s_when_its_joints_move_together():
    """Issue 18 (Animated Unwrap lost to the rest pose over its own action): PoseStatistics take the joints as
    independent, so when an action swings two sibling bones together (two legs of one body), their metric is not
    the action's; sampled_animation_embedding's is, to rounding."""
    positions, triangles = cylinder_patch(columns=8, rows=5)
    rest = np.tile(np.eye(4), (3, 1, 1))
    rest[1, :3, 3], rest[2, :3, 3] = (0.1, 0.0, 0.2), (0.0, 0.3, 1.0)
    skeleton = Skeleton.create([-1, 0, 0], rest)  # siblings, both children of the root
    upper = np.clip(positions[:, 2] / 2, 0, 1)
    model = convert_lbs(skeleton, SparseWeights.from_dense(np.column_stack([np.zeros(len(positions)), 1 - upper,
                                                                            upper])), positions)
    angles = np.linspace(-0.8, 0.8, 9)
    poses = np.tile(rest, (len(angles), 1, 1, 1))
    for pose, angle in zip(poses, angles):
        shift = np.eye(4)
        shift[:3, 3] = (0.3 * angle, 0.0, 0.1 * angle ** 2)  # and the body moves with them
        pose[1], pose[2] = shift @ rest[1] @ y_turn(angle), shift @ rest[2] @ y_turn(angle)
    action = edge_lengths_sq(sequence_embedding(model.evaluate(poses)), triangles)
    sampled = sampled_animation_embedding(model, poses)
    assert sampled.shape == (len(positions), 12)
    np.testing.assert_allclose(edge_lengths_sq(sampled, triangles), action, rtol=1e-9)
    independent = edge_lengths_sq(animation_embedding(model, PoseStatistics.from_world_samples(skeleton.parents,
                                                                                                 poses)), triangles)
    assert np.abs(independent / action - 1).max() > 0.1  # guards the test: the joint statistics are off here
    with pytest.raises(SkinkitError, match="poses"):
        sampled_animation_embedding(model, poses[:0])


def test_segmentation_embedding_keeps_a_low_dimensional_metric_exactly():
    positions, triangles = capsule(columns=8, rows=6)
    rotation = np.linalg.qr(np.random.default_rng(3).normal(size=(12, 12)))[0][:, :3]
    lifted = positions @ rotation.T + 4.0  # the same metric in 12 dimensions
    projected = segmentation_embedding(lifted, triangles)
    assert projected.shape == (len(positions), SEGMENTATION_DIMENSIONS)
    np.testing.assert_allclose(edge_lengths_sq(projected, triangles), edge_lengths_sq(positions, triangles),
                               rtol=1e-9)
    np.testing.assert_array_equal(segmentation_embedding(positions, triangles), positions)


def test_texture_seams_are_the_edges_between_uv_islands():
    triangles = np.array([(0, 1, 2), (0, 2, 3), (2, 1, 4)])
    texture = np.array([(0, 1, 2), (0, 2, 3), (5, 6, 7)])  # the third face is its own island
    np.testing.assert_array_equal(texture_seams(triangles, texture), [[1, 2]])


@pytest.mark.parametrize("change, message", [
    (lambda p, t: (p, np.vstack([t, [[0, 7, len(p) - 1]]])), r"edge \(0, 7\) is shared by 3 faces"),
    (lambda p, t: (np.vstack([p, p[0] - (0, 0, 1)]), np.vstack([t, [[0, 1, len(p)]]])),
     "faces .* orientations disagree"),
    (lambda p, t: (np.where(np.arange(len(p))[:, None] == 7, p[6], p), t), r"face \d+ .* has zero area"),
    (lambda p, t: (np.vstack([p, p[0] + 1, p[0] + (1, 2, 0)]), np.vstack([t, [[0, len(p), len(p) + 1]]])),
     "vertex 0 joins separate fans"),
])
def test_bad_meshes_are_refused_by_name(change, message):
    positions, triangles = cylinder_patch(columns=6, rows=4)
    positions, triangles = change(positions, triangles)
    with pytest.raises(SkinkitError, match=message):
        unwrap(positions, triangles)


def scan_like_mesh(n=50, seed=0, sliver_fraction=0.06):
    """A jittered, dense height field like a scan, with sliver triangles (vertices moved onto the segment between
    two neighbours) and near-degenerate fans (vertices moved almost onto a neighbour)."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    h = 1.0 / (n - 1)
    x, y = x + rng.uniform(-0.3, 0.3, x.shape) * h, y + rng.uniform(-0.3, 0.3, y.shape) * h
    z = 0.15 * np.sin(6 * x) * np.cos(5 * y) + rng.normal(0, 0.02 * h, x.shape)
    positions = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    triangles = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])]).astype(np.int32)
    chosen = rng.choice(index[1:-1, 1:-1].ravel(), int(sliver_fraction * (n - 2) ** 2), replace=False)
    slivers, fans = chosen[: len(chosen) // 2], chosen[len(chosen) // 2:]
    positions[slivers] = 0.5 * (positions[slivers - 1] + positions[slivers + 1]) + rng.normal(0, 1e-9, (len(slivers), 3))
    positions[fans] = positions[fans + 1] + rng.normal(0, 1e-5 * h, (len(fans), 3))
    return positions, triangles


def test_slivers_and_near_degenerate_fans_give_a_valid_atlas_with_each_chart_s_worst_triangle():
    from skinkit.flatten import metric_area, triangle_stretch

    positions, triangles = scan_like_mesh()
    lengths = edge_lengths_sq(positions, triangles)
    areas = metric_area(lengths)
    assert areas.min() / areas.sum() < 1e-9  # slivers as small as a scan's
    result = unwrap(positions, triangles)
    report = result.report
    assert report["status"] == "ok" and report["problems"] == [] and report["flattening"]["invalid_triangles"] == 0
    assert np.isfinite(report["stretch_metric"]) and report["stretch_metric"] < 2
    assert report["texture_efficiency"] > 0.1
    # no uv triangle collapsed relative to its chart: its share of the chart's uv area is not far below its share
    # of the chart's surface
    uv = result.uv
    twice_uv = np.abs((uv[:, 1, 0] - uv[:, 0, 0]) * (uv[:, 2, 1] - uv[:, 0, 1])
                      - (uv[:, 1, 1] - uv[:, 0, 1]) * (uv[:, 2, 0] - uv[:, 0, 0]))
    charts = result.charts
    uv_share = twice_uv / np.bincount(charts, twice_uv)[charts]
    surface_share = areas / np.bincount(charts, areas)[charts]
    assert np.all(uv_share >= 1e-8 * surface_share)
    # the worst triangle of each chart, by its stretch
    stretch = triangle_stretch(uv, lengths)
    assert len(report["chart_worst_triangle"]) == report["charts"] == len(report["chart_worst_stretch"])
    for chart, (triangle, worst) in enumerate(zip(report["chart_worst_triangle"], report["chart_worst_stretch"])):
        assert charts[triangle] == chart and worst == pytest.approx(stretch[charts == chart].max())


def test_an_atlas_with_absurd_or_infinite_stretch_is_never_a_success():
    from skinkit.unwrap import atlas_status

    good = {"flattening": {"invalid_triangles": 0}, "stretch_metric": 1.05, "stretch_rest": 1.1,
            "stretch_frames": 1.2, "texture_efficiency": 0.6}
    assert atlas_status(good) == {"status": "ok", "problems": []}
    for change in ({"stretch_frames": 9.4e6}, {"stretch_metric": np.inf}, {"texture_efficiency": 6e-15},
                   {"flattening": {"invalid_triangles": 300}}):
        status = atlas_status({**good, **change})
        assert status["status"] == "failed" and len(status["problems"]) == 1, change
