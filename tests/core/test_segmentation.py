"""skinkit.segmentation on meshes made here: charts are discs, seams cut, straightening keeps discs and corners."""
import numpy as np
import pytest

from skinkit import SkinkitError
from skinkit.segmentation import chart_corners, cut_along_seams, segment, segment_report, straighten


def uv_sphere(rings=8, around=12):
    positions = [(0.0, 0.0, 1.0)]
    for r in range(1, rings):
        polar = np.pi * r / rings
        for k in range(around):
            azimuth = 2 * np.pi * k / around
            positions.append((np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)))
    positions.append((0.0, 0.0, -1.0))
    south = len(positions) - 1

    def ring(r, k):
        return 1 + (r - 1) * around + k % around

    triangles = [(0, ring(1, k), ring(1, k + 1)) for k in range(around)]
    for r in range(1, rings - 1):
        for k in range(around):
            triangles += [(ring(r, k), ring(r + 1, k), ring(r + 1, k + 1)), (ring(r, k), ring(r + 1, k + 1), ring(r, k + 1))]
    triangles += [(south, ring(rings - 1, k + 1), ring(rings - 1, k)) for k in range(around)]
    return np.array(positions), np.array(triangles)


def capped_cylinder(around=12, rings=4):
    """Tube triangles first (2 per quad), then the bottom and top fans alternating."""
    positions = [(np.cos(2 * np.pi * k / around), np.sin(2 * np.pi * k / around), 2.0 * r / rings)
                 for r in range(rings + 1) for k in range(around)]
    bottom, top = len(positions), len(positions) + 1
    positions += [(0.0, 0.0, 0.0), (0.0, 0.0, 2.0)]
    triangles = []
    for r in range(rings):
        for k in range(around):
            a, b = r * around + k, r * around + (k + 1) % around
            triangles += [(a, b, b + around), (a, b + around, a + around)]
    for k in range(around):
        a, b = k, (k + 1) % around
        triangles += [(bottom, b, a), (top, a + rings * around, b + rings * around)]
    return np.array(positions), np.array(triangles)


def box(n=3):
    positions, triangles, index = [], [], {}

    def vertex(p):
        return index.setdefault(p, len(index))

    for axis in range(3):
        for high in (0, n):
            for j in range(n):
                for i in range(n):
                    def corner(di, dj):
                        p = [0, 0, 0]
                        p[axis], p[(axis + 1) % 3], p[(axis + 2) % 3] = high, i + di, j + dj
                        return vertex(tuple(p))
                    quad = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)]
                    if not high:
                        quad.reverse()
                    triangles += [(quad[0], quad[1], quad[2]), (quad[0], quad[2], quad[3])]
    positions = np.array(sorted(index, key=index.get), dtype=float)
    return positions, np.array(triangles)


def is_disc(triangles, charts, chart):
    """Independent check: V - E + F = 1, each boundary vertex on two boundary edges, edge-connected."""
    faces = triangles[charts == chart]
    edges = {}
    for f, tri in enumerate(faces):
        for k in range(3):
            edges.setdefault(tuple(sorted((tri[k], tri[(k + 1) % 3]))), []).append(f)
    vertices = np.unique(faces)
    boundary = [e for e, owners in edges.items() if len(owners) == 1]
    boundary_degree = np.bincount(np.array(boundary, dtype=int).reshape(-1), minlength=triangles.max() + 1)
    if len(vertices) - len(edges) + len(faces) != 1 or not boundary:
        return False
    if not set(boundary_degree[boundary_degree > 0]) <= {2}:
        return False
    reached, stack = {0}, [0]
    neighbours = {}
    for owners in edges.values():
        if len(owners) == 2:
            neighbours.setdefault(owners[0], []).append(owners[1])
            neighbours.setdefault(owners[1], []).append(owners[0])
    while stack:
        for other in neighbours.get(stack.pop(), []):
            if other not in reached:
                reached.add(other)
                stack.append(other)
    return len(reached) == len(faces)


def all_discs(triangles, charts):
    return all(is_disc(triangles, charts, c) for c in range(charts.max() + 1))


@pytest.mark.parametrize("make", [uv_sphere, box, lambda: capped_cylinder()], ids=["sphere", "box", "cylinder"])
def test_closed_meshes_segment_into_disc_charts(make):
    positions, triangles = make()
    charts, report = segment_report(positions, triangles, chart_count=1)
    assert charts.dtype == np.int32 and charts.shape == (len(triangles),)
    assert report["chart_count"] == charts.max() + 1 >= 2  # a closed surface is never one disc
    assert all_discs(triangles, charts)
    charts = segment(positions, triangles, chart_count=8)
    assert charts.max() + 1 == 8 and all_discs(triangles, charts)
    assert set(np.unique(charts)) == set(range(8))


def test_seams_mode_gives_the_pieces_between_seams():
    around, rings = 12, 4
    positions, triangles = capped_cylinder(around, rings)
    line = [(r * around, (r + 1) * around) for r in range(rings)]
    rims = [(ring * around + k, ring * around + (k + 1) % around) for k in range(around) for ring in (0, rings)]
    charts, report = segment_report(positions, triangles, seams=line + rims, mode="seams")
    tube = 2 * around * rings
    assert report["chart_count"] == 3 and report["components"] == 3
    assert len(set(charts[:tube])) == 1
    assert set(charts[tube::2]) == {charts[tube]} and set(charts[tube + 1::2]) == {charts[tube + 1]}
    assert len({charts[0], charts[tube], charts[tube + 1]}) == 3
    # The slit tube is a disc once the mesh is opened along the seams (and an annulus before).
    cut, source = cut_along_seams(triangles, line + rims)
    assert np.array_equal(source[cut], triangles)
    assert all_discs(cut, charts) and not is_disc(triangles, charts, charts[0])
    # Without the line seam the tube is an annulus: it is cut into discs.
    charts, report = segment_report(positions, triangles, seams=rims, mode="seams")
    assert report["components"] == 3 and report["chart_count"] > 3
    assert all_discs(cut_along_seams(triangles, rims)[0], charts)


def test_straightening_keeps_discs_and_corners():
    positions, triangles = uv_sphere(rings=12, around=16)
    rng = np.random.default_rng(1)
    positions = positions + rng.uniform(-0.02, 0.02, positions.shape)
    charts = segment(positions, triangles, chart_count=6)
    corners = chart_corners(triangles, charts, embedding=positions)
    straight, straight_corners = straighten(positions, triangles, charts)
    assert np.array_equal(straight_corners, corners)
    assert set(np.unique(straight)) == set(np.unique(charts))
    assert all_discs(triangles, straight)
    for c in range(straight.max() + 1):
        assert straight_corners[np.unique(triangles[straight == c])].sum() >= 3


def test_corners_of_a_lone_chart():
    positions, triangles = capped_cylinder()
    tube = 2 * 12 * 4
    # One cap on its own: a single chart, no chart meets it, so all three corners are added.
    cap = triangles[tube::2]
    used = np.unique(cap)
    remap = np.full(len(positions), -1)
    remap[used] = np.arange(len(used))
    corners = chart_corners(remap[cap], np.zeros(len(cap), np.int32), embedding=positions[used])
    assert corners.sum() == 3


def test_non_manifold_edge_is_refused():
    positions, triangles = box(1)
    a, b = triangles[0][:2]
    fin = np.vstack([triangles, [(a, b, len(positions))]])
    positions = np.vstack([positions, [[5.0, 5.0, 5.0]]])
    with pytest.raises(SkinkitError, match=rf"edge \({min(a, b)}, {max(a, b)}\).*not manifold"):
        segment(positions, fin, chart_count=2)


def test_bad_arguments_are_named():
    positions, triangles = box(1)
    with pytest.raises(SkinkitError, match="mode"):
        segment(positions, triangles, mode="manual")
    with pytest.raises(SkinkitError, match="seams"):
        segment(positions, triangles, seams=[(0, 99)])
    with pytest.raises(SkinkitError, match="not joined by a mesh edge"):
        segment(positions, triangles, seams=[(0, 7)])
    with pytest.raises(SkinkitError, match="embedding"):
        segment(np.zeros((8, 9)), triangles)
    with pytest.raises(SkinkitError, match="chart 0 is not a disc"):
        chart_corners(triangles, np.zeros(len(triangles), np.int32))
    with pytest.raises(SkinkitError, match="ratio"):
        straighten(positions, triangles, segment(positions, triangles, chart_count=6), ratio=0.5)
