"""Algorithm 5 in C (sk_reconstruct_seams) on synthetic posed cylinder chains and stars of limbs, and the conic arcs
of its add step (sk_conic_arc)."""
import numpy as np
import pytest

from skinkit import SkinkitError
from skinkit.skeleton import chain_of_cylinders, extract_skeleton, star_of_limbs
from skinkit.skeleton.seams import boundary_edges, conic_arc, is_consistently_oriented, prepare_seams_for_rig

from .test_skeleton_animation import _frame_is_closed_and_outward, _is_vertex_manifold, pose_about


def _rig(sample):
    skeleton = extract_skeleton(sample.parts, "centroid", parents=sample.parents)
    return skeleton.part_parents, skeleton.positions[skeleton.part_joints]


def _bent(parents, joints, degrees):
    world = np.tile(np.eye(4), (len(parents), 1, 1))
    for part in range(1, len(parents)):  # parents come first in both samples
        world[part] = world[parents[part]] @ pose_about(joints[part], degrees)
    return world


def _telescoped(parents, depth):
    """Every child pushed along -x into its parent: its whole opening ring sinks."""
    world = np.tile(np.eye(4), (len(parents), 1, 1))
    world[1:, 0, 3] = -depth
    return world


def _assert_closed_sphere(frame, unit_normals=True):
    triangles = frame.triangles
    assert not frame.fallback
    assert boundary_edges(triangles) == 0 and is_consistently_oriented(triangles)
    assert _is_vertex_manifold(triangles)
    assert len(frame.positions) - len(triangles) // 2 == 2  # V - E + F: one sphere
    _frame_is_closed_and_outward(type("M", (), {"triangles": triangles}), frame.positions)
    lengths = np.linalg.norm(frame.normals, axis=1)
    assert np.isfinite(lengths).all() and (np.isclose(lengths, 1.0) | (lengths == 0)).all()
    if unit_normals:  # zero only where the faces around are degenerate or fold flat (arcs of a limb's twist)
        a, b, c = (frame.positions[triangles[:, k]] for k in range(3))
        faces = np.cross(b - a, c - a)
        for vertex in np.flatnonzero(lengths == 0):
            around = faces[(triangles == vertex).any(axis=1)]
            around = around[np.linalg.norm(around, axis=1) > 1e-12]
            if len(around):
                assert np.abs(np.cross(around, around[0])).max() < 1e-9 * np.abs(around).max() ** 2


@pytest.mark.parametrize("arcs", ["qlerp", "conic"])
@pytest.mark.parametrize("make", ["chain", "star"])
def test_sharp_bends_stay_closed_manifold_spheres(make, arcs):
    """Posed cylinder chains and a star of limbs bent 60-150 degrees at every joint, and every child pushed into
    its parent: each frame is one closed, manifold sphere with consistent outward faces and unit normals."""
    sample = chain_of_cylinders(4, sides=12, rings_per_part=4) if make == "chain" else star_of_limbs()
    parents, joints = _rig(sample)
    mesh = prepare_seams_for_rig(sample.parts, parents, joints, 3)
    worlds = [_bent(parents, joints, (0.0, tilt, turn)) for turn in (60.0, 90.0, 150.0) for tilt in (0.0, 35.0)]
    worlds += [_telescoped(parents, depth) for depth in (0.3, 0.6)]
    frames = mesh.reconstruct_sequence(np.array(worlds), arcs=arcs)
    for k, frame in enumerate(frames):
        _assert_closed_sphere(frame, unit_normals=k < len(frames) - 2)  # a pushed child folds its arc tube flat
    assert sum(frame.removed_points > 0 for frame in frames) >= len(frames) - 1  # the poses sink points
    assert all(frame.conic_columns > 0 for frame in frames[:-2]) == (arcs == "conic")


def test_a_sunk_band_all_round_an_opening_is_bridged_not_fallen_back():
    """Children pushed over a ring deep into their parents sink their whole opening rings (12 points each) and more,
    which cuts the kept surface into pieces; they are joined again by strips, so the frame is one sphere without
    fallback (the Python path this replaced fell back to the fixed topology here)."""
    sample = chain_of_cylinders(4, sides=12, rings_per_part=4)
    parents, joints = _rig(sample)
    mesh = prepare_seams_for_rig(sample.parts, parents, joints, 3)
    frame = mesh.reconstruct(_telescoped(parents, 0.6))
    assert frame.removed_points > 3 * 12  # more than a whole ring at each of the three seams
    _assert_closed_sphere(frame, unit_normals=False)


def test_remove_sinking_off_keeps_the_fixed_topology():
    sample = chain_of_cylinders(3, sides=12, rings_per_part=4)
    parents, joints = _rig(sample)
    mesh = prepare_seams_for_rig(sample.parts, parents, joints, 3)
    world = _bent(parents, joints, (0.0, 0.0, 90.0))
    frame = mesh.reconstruct(world, remove_sinking=False)
    assert frame.removed_points == 0 and not frame.fallback
    np.testing.assert_array_equal(frame.triangles, mesh.triangles)
    np.testing.assert_allclose(frame.positions, mesh.positions(world), atol=1e-12)


def _barycentric(point, c, x, d):
    """Barycentric coordinates of a point of the plane (c, x, d), by least squares."""
    matrix = np.stack([c - d, x - d], axis=1)
    (b0, b1), *_ = np.linalg.lstsq(matrix, point - d, rcond=None)
    return b0, b1, 1.0 - b0 - b1


def test_conic_arc_points_lie_on_the_conic_through_the_point():
    """The implicit form of the rational quadratic Bezier with weights (1, w, 1) on the triangle (C, X, D):
    b1^2 = 4 w^2 b0 b2; every point, and the through point, satisfy it, and the points are evenly spaced."""
    c, d, x = np.array([0.0, 0, 0]), np.array([3.0, 1, 0]), np.array([1.0, 2.5, 0])
    for through in (np.array([1.3, 1.2, 0.0]), np.array([1.2, 1.7, 0.0]), np.array([1.6, 0.9, 0.0])):
        points, w = conic_arc(c, x - c, d, x - d, through, 9)
        for point in [*points, through]:
            b0, b1, b2 = _barycentric(point, c, x, d)
            assert abs(b1 * b1 - 4 * w * w * b0 * b2) < 1e-6, (point, w)
        gaps = np.linalg.norm(np.diff(np.vstack([c, points, d]), axis=0), axis=1)
        assert gaps.max() / gaps.min() < 1.02  # equal arc lengths, chords of a smooth curve
    with pytest.raises(SkinkitError, match="no conic"):
        conic_arc(c, x - c, d, x - d, np.array([-1.0, 1.0, 0.0]), 4)  # behind c's tangent line


def test_conic_middle_points_lie_on_the_thesis_parabola():
    """Seam columns on conic arcs: in the plane PL (the deeper part's joint and both parts' centres), each column
    from C to D runs on the conic through V_m = (I_P + InB) / 2, InB = (C + D) / 2, I_P the tangents' crossing;
    that conic is the parabola b1^2 = 4 b0 b2 on (C, I_P, D) (w = 1)."""
    sample = chain_of_cylinders(2, sides=12, rings_per_part=4)
    parents, joints = _rig(sample)
    mesh = prepare_seams_for_rig(sample.parts, parents, joints, 4)
    world = _bent(parents, joints, (0.0, 20.0, 70.0))
    frame = mesh.reconstruct(world, remove_sinking=False, arcs="conic")
    assert frame.conic_columns > 0
    qlerp = mesh.positions(world)
    centres = mesh.removal.box_centres
    joint = world[1, :3, :3] @ mesh.joints[1] + world[1, :3, 3]
    axis_a = joint - (world[0, :3, :3] @ centres[0] + world[0, :3, 3])
    axis_b = joint - (world[1, :3, :3] @ centres[1] + world[1, :3, 3])
    normal = np.cross(axis_a, axis_b)
    normal /= np.linalg.norm(normal)
    checked_columns = 0
    for row in mesh.columns:
        inner = frame.positions[row[1:-1]]
        if np.allclose(inner, qlerp[row[1:-1]]):
            continue  # a degenerate conic: the QLERP arc kept
        flat = lambda p: p - ((p - joint) @ normal) * normal  # noqa: E731 - onto PL
        c, d = flat(frame.positions[row[0]]), flat(frame.positions[row[-1]])
        along = np.linalg.lstsq(np.stack([axis_a, -axis_b], axis=1), d - c, rcond=None)[0]
        crossing = c + along[0] * axis_a
        for point in inner:
            b0, b1, b2 = _barycentric(flat(point), c, crossing, d)
            assert abs(b1 * b1 - 4 * b0 * b2) < 1e-6
        checked_columns += 1
    assert checked_columns == frame.conic_columns


def test_a_sequence_reports_progress_and_cancels():
    sample = chain_of_cylinders(2, sides=8, rings_per_part=2)
    parents, joints = _rig(sample)
    mesh = prepare_seams_for_rig(sample.parts, parents, joints, 2)
    worlds = np.array([_bent(parents, joints, (0.0, 0.0, angle)) for angle in (10.0, 40.0, 80.0)])
    seen = []
    frames = mesh.reconstruct_sequence(worlds, progress=lambda fraction: seen.append(fraction))
    assert len(frames) == 3 and seen == pytest.approx([1 / 3, 2 / 3, 1.0])
    with pytest.raises(SkinkitError, match="cancel"):
        mesh.reconstruct_sequence(worlds, progress=lambda fraction: fraction > 0.5)
    with pytest.raises(SkinkitError, match="arcs"):
        mesh.reconstruct(worlds[0], arcs="bezier")


def test_the_cli_arc_choices_are_the_library_kinds():
    from skinkit.cli.commands.rigid_skin import ARC_CHOICES
    from skinkit.skeleton.seams import ARC_KINDS

    assert ARC_CHOICES == ARC_KINDS


def test_a_single_part_has_no_seam_and_stays_whole():
    sample = chain_of_cylinders(1, sides=8, rings_per_part=2)
    mesh = prepare_seams_for_rig(sample.parts, np.array([-1]), np.zeros((1, 3)), 2)
    turn = pose_about(np.zeros(3), (0.0, 30.0, 45.0))
    frame = mesh.reconstruct(turn[None])
    assert frame.removed_points == 0 and not frame.fallback
    np.testing.assert_array_equal(frame.triangles, mesh.triangles)
    np.testing.assert_allclose(frame.positions, sample.parts.positions @ turn[:3, :3].T, atol=1e-12)
