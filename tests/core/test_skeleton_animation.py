"""Keyframes, forward kinematics, motion acceptance and rigid skinning with seams on the synthetic star: the clip
file round-trips; Hermite spans meet their keys with the rules' slopes; a limb turns about its joint; a keyframe
past a limit and a pose that drives one limb into another are refused; every frame of the skinned mesh is
watertight, manifold and consistently oriented, with outward normals."""
import numpy as np
import pytest

from skinkit import SkinkitError
from skinkit.skeleton import chain_of_cylinders, extract_skeleton, free_limits, star_of_limbs
from skinkit.skeleton.animation import (Channel, Keyframes, animate, collision_candidates, collisions,
                                        find_collisions, pose, read_keyframes, write_keyframes)
from skinkit.skeleton.parts import Parts
from skinkit.skeleton.seams import boundary_edges, is_consistently_oriented, prepare_seams, vertex_normals


@pytest.fixture(scope="module")
def star():
    sample = star_of_limbs()
    return sample, extract_skeleton(sample.parts, "centroid", parents=sample.parents)


def swing(part: int, axis: int, peak: float) -> Keyframes:
    channel = Channel(np.array([0.0, 5.0, 10.0]), np.array([0.0, peak, 0.0]), ["linear", "smooth", "linear"],
                      ["linear", "smooth", "linear"])
    return Keyframes(0.0, 10.0, {3 * part + axis: channel})


def test_hermite_spans_hit_keys_and_follow_rules():
    channel = Channel(np.array([0.0, 1.0, 3.0]), np.array([0.0, 2.0, 0.0]), ["flat", "smooth", "linear"],
                      ["linear", "flat", "flat"], ("linear", "cycle"))
    np.testing.assert_allclose(channel.evaluate([0.0, 1.0, 3.0]), [0.0, 2.0, 0.0])
    incoming, outgoing = channel.slopes()
    assert outgoing[0] == pytest.approx(2.0) and incoming[1] == pytest.approx(0.0) and incoming[2] == pytest.approx(-1.0)
    h = 1e-6  # the slope leaving key 0 is the linear rule's
    assert (channel.evaluate(h) - channel.evaluate(0.0)) / h == pytest.approx(2.0, rel=1e-4)
    assert channel.evaluate(-1.0) == pytest.approx(0.0)  # linear before: key 0's incoming slope is flat
    assert channel.evaluate(4.0) == pytest.approx(channel.evaluate(1.0))  # cycles with period 3
    bounce = Channel(channel.times, channel.values, channel.tangent_in, channel.tangent_out, ("constant", "bounce"))
    assert bounce.evaluate(3.5) == pytest.approx(bounce.evaluate(2.5))
    offset = Channel(np.array([0.0, 1.0]), np.array([0.0, 1.0]), ["linear"] * 2, ["linear"] * 2,
                     ("constant", "cycle_offset"))
    assert offset.evaluate(1.5) == pytest.approx(1.5)


def test_keyframe_file_round_trips(tmp_path):
    clip = swing(1, 0, 45.0)
    path = write_keyframes(str(tmp_path / "swing.clip"), clip)
    back = read_keyframes(path)
    assert (back.start, back.end) == (0.0, 10.0) and list(back.channels) == [3]
    np.testing.assert_array_equal(back.channels[3].values, clip.channels[3].values)
    assert back.channels[3].tangent_in == clip.channels[3].tangent_in
    bad = tmp_path / "bad.clip"
    bad.write_text("animation {\n range 0 1\n numchannels 1\n channel 0 {\n extrapolate 0 9\n")
    with pytest.raises(SkinkitError, match="bad.clip:5: extrapolation '9'"):
        read_keyframes(str(bad))


def test_a_limb_turns_about_its_joint(star):
    _, skeleton = star
    angles = np.zeros((6, 3))
    angles[1] = [90.0, 0.0, 0.0]
    world = pose(skeleton, angles)
    joint = np.array([1.0, 0.0, 0.0])
    tip = world[1] @ [3.0, 0.0, 0.0, 1.0]
    assert np.linalg.norm(tip[:3] - joint) == pytest.approx(2.0)
    assert abs((tip[:3] - joint) @ [1, 0, 0]) < 1e-9  # a quarter turn off the limb's axis
    np.testing.assert_allclose(world[1] @ np.append(joint, 1.0), np.append(joint, 1.0), atol=1e-12)
    np.testing.assert_allclose(world[0], np.eye(4), atol=1e-12)  # the hub did not move
    assert collisions(skeleton, world) == []


def test_limits_refuse_a_violating_keyframe(star):
    _, skeleton = star
    limits = free_limits(6)
    limits[1, 0] = [-30.0, 60.0]
    motion = animate(skeleton, swing(1, 0, 90.0), np.linspace(0, 10, 11), limits, check_collisions=False)
    refused = [f for f, parts in enumerate(motion.refused_limits) if parts]
    assert refused and all(motion.refused_limits[f] == [1] for f in refused)
    assert motion.angles[:, 1, 0].max() <= 60.0
    free = animate(skeleton, swing(1, 0, 90.0), np.linspace(0, 10, 11), free_limits(6), check_collisions=False)
    assert free.angles[:, 1, 0].max() == pytest.approx(90.0)


def test_collisions_refuse_an_interpenetrating_pose(star):
    _, skeleton = star
    angles = np.zeros((6, 3))
    angles[1, 0] = 135.0  # limb +x swung through limb +y
    assert (1, 3) in collisions(skeleton, pose(skeleton, angles))
    motion = animate(skeleton, swing(1, 0, 135.0), np.linspace(0, 10, 21))
    assert any(1 in parts for parts in motion.refused_collisions)
    for world in motion.world:
        assert collisions(skeleton, world) == []


@pytest.fixture(scope="module")
def chain():
    sample = chain_of_cylinders(parts=5, sides=12, rings_per_part=3)
    return sample, extract_skeleton(sample.parts, "centroid", parents=sample.parents)


def _subtree(parents, root):
    return {p for p in range(len(parents)) if root in _ancestry(parents, p)}


def _ancestry(parents, p):
    chain = []
    while p >= 0:
        chain.append(p)
        p = int(parents[p])
    return chain


def test_one_joint_tests_only_the_pairs_it_can_change(chain):
    _, skeleton = chain
    parents = skeleton.part_parents
    everything = {tuple(p) for p in collision_candidates(skeleton).tolist()}
    assert not any(parents[a] == b or parents[b] == a for a, b in everything)
    assert len(everything) == 5 * 4 // 2 - 4
    for joint in range(len(parents)):
        inside = _subtree(parents, joint)
        expected = {(a, b) for a, b in everything if (a in inside) != (b in inside)}
        assert {tuple(p) for p in collision_candidates(skeleton, joint).tolist()} == expected
    rng = np.random.default_rng(7)
    collided = 0
    for _ in range(40):
        joint = int(rng.integers(1, len(parents)))
        angles = np.zeros((len(parents), 3))
        angles[joint] = rng.uniform(-170.0, 170.0, 3)
        world = pose(skeleton, angles)
        listed = collision_candidates(skeleton, joint)
        result = find_collisions(skeleton, world, listed)
        listed_set = {tuple(p) for p in listed.tolist()}
        assert {tuple(p) for p in result.tested.tolist()} <= listed_set  # nothing outside the joint's list is tested
        assert sorted(result.pairs) == collisions(skeleton, world)  # the same answer as every pair
        collided += bool(result.pairs)
        first = find_collisions(skeleton, world, listed, first_only=True)
        assert len(first.pairs) == min(1, len(result.pairs)) and set(first.pairs) <= set(result.pairs)
    assert collided  # the poses do fold segments into each other


def test_collision_tests_go_likeliest_first(chain):
    _, skeleton = chain
    angles = np.zeros((5, 3))
    angles[2, 0] = 160.0
    result = find_collisions(skeleton, pose(skeleton, angles))
    assert result.pairs and len(result.tested) == result.sphere_hits
    world = pose(skeleton, angles)
    centres = np.array([w[:3, :3] @ (b[:3] @ np.eye(3)) + w[:3, 3] for w, b in zip(world, skeleton.boxes)])
    radii = np.linalg.norm(skeleton.boxes[:, 3:], axis=1)
    weights = [(np.linalg.norm(centres[a] - centres[b]) / (radii[a] + radii[b])) ** 2 for a, b in result.tested]
    assert weights == sorted(weights) and max(weights) <= 1.0
    with pytest.raises(SkinkitError, match="moved_part"):
        collision_candidates(skeleton, 5)


@pytest.mark.parametrize("steps", [1, 4])
def test_every_frame_is_watertight_with_outward_normals(star, steps):
    sample, skeleton = star
    mesh = prepare_seams(sample.parts, skeleton, steps)
    assert mesh.constructed_points == 5 * 4 * steps  # five square openings of four vertices
    assert boundary_edges(mesh.triangles) == 0 and is_consistently_oriented(mesh.triangles)
    motion = animate(skeleton, swing(1, 1, 70.0), np.linspace(0, 10, 6), check_collisions=False)
    for world in motion.world:
        positions = mesh.positions(world)
        normals = vertex_normals(positions, mesh.triangles)
        centre = positions.mean(axis=0)
        volume = np.einsum("ij,ij->i", positions[mesh.triangles[:, 0]] - centre,
                           np.cross(positions[mesh.triangles[:, 1]] - centre,
                                    positions[mesh.triangles[:, 2]] - centre)).sum() / 6
        assert volume > 0  # outward faces enclose a positive volume
        tip = positions[np.argmax(positions @ world[1, :3, 0])]  # moved rigidly: a limb vertex
        assert np.isfinite(tip).all() and np.isfinite(normals).all()
    rest = mesh.positions(np.tile(np.eye(4), (6, 1, 1)))
    np.testing.assert_allclose(rest[mesh.sources < len(sample.parts.positions)],
                               sample.parts.positions[mesh.sources], atol=1e-12)


def test_the_gap_is_closed_by_arcs(star):
    sample, skeleton = star
    mesh = prepare_seams(sample.parts, skeleton, 3)
    angles = np.zeros((6, 3))
    angles[1, 1] = 60.0
    world = pose(skeleton, angles)
    positions = mesh.positions(world)
    arcs = mesh.parts_b >= 0
    joint = np.array([1.0, 0.0, 0.0])
    radii = np.linalg.norm(positions[arcs] - joint, axis=1)  # arc points keep their distance to the joint
    np.testing.assert_allclose(radii, np.linalg.norm(sample.parts.positions[mesh.sources[arcs]] - joint, axis=1))


def _split_middle(sample):
    """The chain's middle segment cut lengthwise: its y < 0 half becomes a 4th part, a child of segment 0 that
    touches segments 0, 1 and 2, so three parts meet at the cut's ends and two siblings share an opening."""
    parts = sample.parts
    centres = parts.positions[parts.triangles].mean(axis=1)
    labels = np.where((parts.triangle_parts == 1) & (centres[:, 1] < 0), 3, parts.triangle_parts)
    split = Parts(parts.positions, parts.triangles, labels.astype(np.int32), parts.names + ("segment_1b",))
    return split, np.array([-1, 0, 1, 0], np.int32), np.array([[0.0, 0, 0], [2, 0, 0], [4, 0, 0], [2, 0, 0]])


def _frame_is_closed_and_outward(mesh, positions):
    assert np.isfinite(positions).all()
    centre = positions.mean(axis=0)
    a, b, c = (positions[mesh.triangles[:, k]] - centre for k in range(3))
    assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() > 0  # outward faces enclose a positive volume


def test_seams_between_any_touching_parts_over_random_poses():
    from skinkit.skeleton.seams import prepare_seams_for_rig

    sample = chain_of_cylinders(3, sides=12, rings_per_part=4)
    parts, parents, joints = _split_middle(sample)
    steps = 3
    mesh = prepare_seams_for_rig(parts, parents, joints, steps)
    # Topology is fixed, so watertight, manifold and consistently oriented hold in every frame.
    assert boundary_edges(mesh.triangles) == 0 and is_consistently_oriented(mesh.triangles)
    assert set(mesh.ring_sizes) == {"segment_0|segment_1", "segment_0|segment_1b", "segment_1|segment_2",
                                    "segment_1b|segment_2", "segment_1|segment_1b"}
    assert len(mesh.cap_centres) == 4  # the lengthwise cut's two ends on each of its two sides
    vertices, edges = len(mesh.sources), len(mesh.triangles) * 3 // 2
    assert vertices - edges + len(mesh.triangles) == 2  # still a sphere
    rng = np.random.default_rng(3)
    for _ in range(10):
        world = np.tile(np.eye(4), (4, 1, 1))
        for part in (1, 2, 3):  # each part turned about its joint, children after parents
            angle, axis = rng.uniform(-0.6, 0.6), rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
            rotation = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
            local = np.eye(4)
            local[:3, :3], local[:3, 3] = rotation, joints[part] - rotation @ joints[part]
            world[part] = world[parents[part]] @ local
        positions = mesh.positions(world)
        _frame_is_closed_and_outward(mesh, positions)
        centres = mesh.cap_centres
        ring = mesh.cap_members[mesh.cap_members[:, 0] == 0, 1]
        np.testing.assert_allclose(positions[centres[0]], positions[ring].mean(axis=0), atol=1e-12)


def test_parts_off_the_tree_get_seams_and_bad_steps_are_refused():
    sample = chain_of_cylinders(3)
    skeleton = extract_skeleton(sample.parts, "opening", parents=sample.parents)
    wrong = type(skeleton)(**{**skeleton.__dict__, "part_parents": np.array([-1, 0, 0], np.int32)})
    mesh = prepare_seams(sample.parts, wrong)  # part 2 meets part 1, not its parent 0: a seam all the same
    assert boundary_edges(mesh.triangles) == 0 and "segment_1|segment_2" in mesh.ring_sizes
    with pytest.raises(SkinkitError, match="steps"):
        prepare_seams(sample.parts, skeleton, 0)
    assert isinstance(sample.parts, Parts)


def _is_vertex_manifold(triangles) -> bool:
    """Every vertex's triangles form one fan: its link (the opposite edges, oriented) is a single cycle."""
    following = {}
    for a, b, c in triangles.tolist():
        for vertex, edge in ((a, (b, c)), (b, (c, a)), (c, (a, b))):
            link = following.setdefault(vertex, {})
            if edge[0] in link:
                return False
            link[edge[0]] = edge[1]
    for link in following.values():
        start = next(iter(link))
        k, steps = link[start], 1
        while k != start:
            if k not in link or steps > len(link):
                return False
            k, steps = link[k], steps + 1
        if steps != len(link):
            return False
    return True


@pytest.mark.parametrize("make", ["chain", "split"])
def test_sinking_points_are_removed_and_every_frame_stays_closed(make):
    """Algorithm 5 per frame over random keyframed poses: points that sink into the neighbouring part go, the
    holes are filled, and every frame is one closed, manifold, consistently oriented sphere with outward faces."""
    from skinkit.skeleton.seams import prepare_seams_for_rig

    sample = chain_of_cylinders(4, sides=12, rings_per_part=4)
    if make == "chain":
        skeleton = extract_skeleton(sample.parts, "centroid", parents=sample.parents)
        parts, parents = sample.parts, skeleton.part_parents
        joints = skeleton.positions[skeleton.part_joints]
    else:
        parts, parents, joints = _split_middle(chain_of_cylinders(3, sides=12, rings_per_part=4))
    mesh = prepare_seams_for_rig(parts, parents, joints, 3)
    rest = mesh.reconstruct(np.tile(np.eye(4), (len(parents), 1, 1)))
    assert rest.removed_points == 0 and len(rest.triangles) == len(mesh.triangles)  # nothing sinks at rest
    rng = np.random.default_rng(11)
    channels = {3 * part + axis: Channel(np.array([0.0, 3.0, 6.0]), np.array([0.0, *rng.uniform(-50, 50, 2)]),
                                         ["smooth"] * 3, ["smooth"] * 3)
                for part in range(1, len(parents)) for axis in (1, 2)}
    removed = fallbacks = 0
    for time in np.linspace(0.0, 6.0, 13):
        angles = Keyframes(0.0, 6.0, channels).angles(time, len(parents))
        world = np.tile(np.eye(4), (len(parents), 1, 1))
        for part in range(1, len(parents)):  # FK about each part's joint in the parts' order (parents first)
            turn = pose_about(joints[part], angles[part])
            world[part] = world[parents[part]] @ turn
        frame = mesh.reconstruct(world)
        removed += frame.removed_points
        fallbacks += frame.fallback
        triangles = frame.triangles
        assert boundary_edges(triangles) == 0 and is_consistently_oriented(triangles)
        assert _is_vertex_manifold(triangles)
        assert len(frame.positions) - len(triangles) // 2 == 2  # V - E + F: one sphere
        _frame_is_closed_and_outward(type("M", (), {"triangles": triangles}), frame.positions)
        assert np.isfinite(frame.normals).all() and set(frame.seconds) == {"add", "remove", "triangulate",
                                                                             "normals"}
    assert removed > 0 and fallbacks == 0, (removed, fallbacks)  # the bends do sink points, and the fill holds


def pose_about(joint, degrees):
    """A rigid turn about joint by degrees about Y then Z."""
    y, z = np.radians(degrees[1]), np.radians(degrees[2])
    ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    rz = np.array([[np.cos(z), -np.sin(z), 0], [np.sin(z), np.cos(z), 0], [0, 0, 1]])
    turn = np.eye(4)
    turn[:3, :3] = rz @ ry
    turn[:3, 3] = joint - turn[:3, :3] @ joint
    return turn
