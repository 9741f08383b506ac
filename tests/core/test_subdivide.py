"""Subdivision in animation space: the subdivided model deforms as the subdivided posed mesh (Loop against a direct
numpy Loop written here vertex by vertex; Catmull-Clark on a cube against its known first level), bad input refused."""
import numpy as np
import pytest
from tests.core.test_limit_influences import CHAIN, chain_rig, smooth_lbs

from skinkit import Skeleton, SkinkitError, convert_lbs
from skinkit.subdivide import subdivide


def icosphere_like():
    """An octahedron (closed triangle mesh, valence 4) stretched along x, and a strip with a boundary."""
    positions = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    triangles = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return positions, triangles


def grid(n=4):
    """A triangulated n x n grid, gently curved: boundaries, and two corners that lie in a single triangle."""
    x, y = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    positions = np.column_stack([x.ravel(), y.ravel(), 0.1 * (x.ravel() - 1.5) ** 2]).astype(float)
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return positions, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


def direct_loop(positions, triangles, boundary="all"):
    """Loop subdivision of one posed mesh, rule by rule with Python loops (edge map, rings)."""
    edges = {}
    for t in triangles:
        for i in range(3):
            a, b, c = int(t[i]), int(t[(i + 1) % 3]), int(t[(i + 2) % 3])
            edges.setdefault((min(a, b), max(a, b)), []).append(c)
    V = len(positions)
    new = [None] * V
    neighbours = {v: set() for v in range(V)}
    boundary_neighbours = {v: set() for v in range(V)}
    faces = np.bincount(np.asarray(triangles).reshape(-1), minlength=V)
    for (a, b), opposite in edges.items():
        neighbours[a].add(b)
        neighbours[b].add(a)
        if len(opposite) == 1:
            boundary_neighbours[a].add(b)
            boundary_neighbours[b].add(a)
    for v in range(V):
        if boundary_neighbours[v]:
            if boundary == "preserve-corners" and faces[v] == 1:
                new[v] = positions[v]
            else:
                new[v] = 0.75 * positions[v] + 0.125 * sum(positions[u] for u in boundary_neighbours[v])
        else:
            n = len(neighbours[v])
            beta = (5 / 8 - (3 / 8 + np.cos(2 * np.pi / n) / 4) ** 2) / n
            new[v] = (1 - n * beta) * positions[v] + beta * sum(positions[u] for u in neighbours[v])
    edge_index = {}
    for (a, b), opposite in sorted(edges.items()):
        edge_index[(a, b)] = len(new)
        if len(opposite) == 2:
            new.append(0.375 * (positions[a] + positions[b]) + 0.125 * (positions[opposite[0]] + positions[opposite[1]]))
        else:
            new.append(0.5 * (positions[a] + positions[b]))
    return np.array(new)


def rigged(positions, seed=0):
    rng = np.random.default_rng(seed)
    rest, poses = chain_rig(rng, 5)
    span = positions[:, 0].max() - positions[:, 0].min()
    placed = positions.copy()
    placed[:, 0] = (positions[:, 0] - positions[:, 0].min()) / span * (len(CHAIN) - 2)
    _, weights = smooth_lbs(rng, rest, vertex_count=len(placed))
    skeleton = Skeleton.create(CHAIN, rest)
    return convert_lbs(skeleton, weights, placed), poses


@pytest.mark.parametrize("boundary", ["all", "preserve-corners"])
@pytest.mark.parametrize("open_mesh", [False, True])
def test_loop_in_animation_space_is_loop_of_every_posed_mesh(boundary, open_mesh):
    positions, triangles = grid() if open_mesh else icosphere_like()
    model, poses = rigged(positions)
    result = subdivide(triangles, model, levels=2, scheme="loop", boundary=boundary)
    assert result.polygons.shape == (len(triangles) * 16, 3)
    for pose in poses:
        posed = model.evaluate(pose)
        once = direct_loop(posed, triangles, boundary)
        # the second level of the direct Loop needs the first level's triangles: ours (same vertex order)
        first = subdivide(triangles, model, levels=1, scheme="loop", boundary=boundary)
        assert np.abs(first.model.evaluate(pose) - once).max() < 1e-12
        twice = direct_loop(once, first.polygons, boundary)
        assert np.abs(result.model.evaluate(pose) - twice).max() < 1e-12
    assert np.allclose(result.model.homogeneous_weights(), 1.0)


def test_catmull_clark_of_a_cube_is_the_known_first_level():
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    quads = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])
    model, _ = rigged(corners)
    result = subdivide(quads, model)
    moved = result.apply(corners)
    assert moved.shape == (8 + 12 + 6, 3) and result.polygons.shape == (24, 4)
    # Corners (valence 3): (Q + 2R + (n - 3) S) / n = (1/3 * face points + 2/3 * edge midpoints) -> 5/9 of the corner.
    assert np.allclose(np.abs(moved[:8]), 5 / 9)
    assert np.allclose(np.sort(np.abs(moved[8:20]), axis=1), [[0, 0.75, 0.75]] * 12)  # edge points
    assert np.allclose(np.sort(np.abs(moved[20:]), axis=1), [[0, 0, 1]] * 6)  # face centres


def test_mixed_polygons_and_the_model_follow_every_pose():
    positions = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [1, 1, 0], [2, 1, 0.3], [1, 2, 0]], float)
    polygons = [[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 6], [4, 5, 6]]
    model, poses = rigged(positions, seed=3)
    result = subdivide(polygons, model, levels=2)
    assert result.polygons.shape == ((4 + 4 + 3 + 3) * 4, 4)
    for pose in poses:
        assert np.abs(result.model.evaluate(pose) - result.apply(model.evaluate(pose))).max() < 1e-12


def test_bad_input_is_refused():
    positions, triangles = icosphere_like()
    model, _ = rigged(positions)
    with pytest.raises(SkinkitError, match="scheme: must be one of"):
        subdivide(triangles, model, scheme="doo-sabin")
    with pytest.raises(SkinkitError, match="levels: expected a whole number"):
        subdivide(triangles, model, levels=0)
    with pytest.raises(SkinkitError, match="polygons: polygon 0 uses vertex 9"):
        subdivide([[0, 1, 9]], model)
    with pytest.raises(SkinkitError, match="the Loop scheme needs triangles"):
        subdivide([[0, 2, 1, 3]], model, scheme="loop")
    with pytest.raises(SkinkitError, match=r"uv: expected shape \(24, 2\)"):
        subdivide(triangles, model, uv=np.zeros((3, 2)))
    with pytest.raises(SkinkitError, match="non-manifold"):
        subdivide([[0, 2, 4], [0, 2, 5], [0, 2, 3]], model)
    with pytest.raises(SkinkitError, match="model: expected"):
        subdivide(triangles, positions)
