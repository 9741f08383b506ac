"""Skeleton extraction (skinkit.skeleton) on the synthetic characters: known openings, kernel centroids and
hierarchy; the parts' sources; the hierarchy-and-limits file's round trip; bad input named."""
import numpy as np
import pytest

from skinkit import SkinkitError
from skinkit.skeleton import (METHODS, Hierarchy, Parts, chain_of_cylinders, extract_skeleton, free_limits,
                              from_vertex_labels, from_weights, loose_parts, read_hierarchy, read_obj_groups,
                              star_of_limbs, write_hierarchy)


def opening_joints(skeleton):
    return {int(part): skeleton.positions[j] for j, part in enumerate(skeleton.parts)
            if skeleton.kinds[j] == 1}


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("make", [chain_of_cylinders, star_of_limbs])
def test_known_joints_and_hierarchy(make, method):
    sample = make()
    skeleton = extract_skeleton(sample.parts, method, parents=sample.parents)
    assert skeleton.part_parents.tolist() == sample.parents.tolist()
    found = opening_joints(skeleton)
    assert sorted(found) == [p for p in range(len(sample.parents)) if sample.parents[p] >= 0]
    for part, position in found.items():
        np.testing.assert_allclose(position, sample.openings[part], atol=1e-9)
    assert all(p < j for j, p in enumerate(skeleton.parents.tolist()))  # parents first, one root
    assert (skeleton.parents == -1).sum() == 1
    assert skeleton.star_shaped.all() and not skeleton.degenerate.any()


def test_kernel_centroids_and_axes_of_the_star():
    sample = star_of_limbs()
    skeleton = extract_skeleton(sample.parts, "centroid")
    np.testing.assert_allclose(skeleton.kernel_centroids[0], 0.0, atol=1e-6)  # the hub's kernel is the cube
    for limb in range(1, 6):
        direction = sample.openings[limb]  # a unit face normal
        np.testing.assert_allclose(skeleton.kernel_centroids[limb], direction * 2.0, atol=0.05)
        assert abs(skeleton.principal_axes[limb, 0] @ direction) > 0.999  # the limb's long axis


def test_derived_hierarchy_roots_at_the_hub():
    skeleton = extract_skeleton(star_of_limbs().parts, "opening")
    assert skeleton.part_parents.tolist() == [-1, 0, 0, 0, 0, 0]


def test_principal_axis_reaches_the_limb_tips():
    skeleton = extract_skeleton(star_of_limbs().parts, "principal-axis", refine=True, max_angle=20)
    ends = skeleton.positions[skeleton.kinds == 4]
    for tip in ([3, 0, 0], [-3, 0, 0], [0, 3, 0], [0, -3, 0], [0, 0, 3]):
        assert np.min(np.linalg.norm(ends - tip, axis=1)) < 1e-6


@pytest.mark.parametrize("order", [[0, 1, 2, 3, 4, 5], [0, 5, 4, 3, 2, 1], [0, 3, 5, 1, 4, 2]])
def test_local_refinement_does_not_depend_on_the_openings_order(order):
    """The hub's openings (+-x, +-y, +z) reach farthest along x and y together, never along z alone: the thesis'
    "last vector's closest direction" rule would make z principal whenever +z is visited last."""
    sample = star_of_limbs()
    labels = np.array(order, np.int32)[sample.parts.triangle_parts]
    names = tuple(np.array(sample.parts.names)[np.argsort(order)])
    parents = np.zeros(6, np.int32)
    parents[order[0]] = -1
    skeleton = extract_skeleton(Parts(sample.parts.positions, sample.parts.triangles, labels, names),
                                "principal-axis", parents=parents, refine=True, max_angle=20.0)
    axis = skeleton.principal_axes[order[0], 0]
    assert abs(axis[2]) < 0.1 and max(abs(axis[0]), abs(axis[1])) == pytest.approx(1.0, abs=1e-6)


def test_joints_for_the_cli_name_their_parents():
    skeleton = extract_skeleton(chain_of_cylinders(3).parts, "centroid")
    joints = skeleton.joints()
    names = {j["name"] for j in joints}
    assert len(names) == len(joints)
    assert sum(j["parent"] is None for j in joints) == 1
    assert all(j["parent"] in names for j in joints if j["parent"] is not None)
    assert set(skeleton.stage_seconds) == {"openings", "hulls", "kernels", "method"}


def test_bone_tails_point_along_each_part():
    sample = chain_of_cylinders(3)
    skeleton = extract_skeleton(sample.parts, "principal-axis")
    heads, tails = skeleton.positions[skeleton.part_joints], skeleton.bone_tails()
    assert (np.linalg.norm(tails - heads, axis=1) > 0.5).all()


def test_loose_pieces_are_welded_into_parts():
    sample = chain_of_cylinders(3)
    parts = sample.parts
    # Split the vertices: every part gets its own copies, as separate objects joined in Blender would.
    positions, triangles = [], []
    for part in range(parts.part_count):
        used = np.unique(parts.triangles[parts.triangle_parts == part])
        remap = -np.ones(len(parts.positions), dtype=np.int64)
        remap[used] = np.arange(len(used)) + sum(len(p) for p in positions)
        positions.append(parts.positions[used])
        triangles.append(remap[parts.triangles[parts.triangle_parts == part]])
    loose = loose_parts(np.vstack(positions), np.vstack(triangles))
    assert loose.part_count == 3 and len(loose.positions) == len(parts.positions)
    skeleton = extract_skeleton(loose, "opening")
    assert len(opening_joints(skeleton)) == 2


def test_weights_and_vertex_labels_give_parts():
    sample = chain_of_cylinders(3)
    labels = sample.parts.vertex_parts()
    weights = np.eye(3)[labels] * 0.8 + 0.1
    parts = from_weights(sample.parts.positions, sample.parts.triangles, weights)
    assert parts.part_count == 3 and parts.names == ("bone_0", "bone_1", "bone_2")
    assert extract_skeleton(parts, "centroid").star_shaped.all()
    with pytest.raises(SkinkitError, match="vertex_labels"):
        from_vertex_labels(sample.parts.positions, sample.parts.triangles, labels[:-1])


def test_obj_groups_and_materials(tmp_path):
    path = tmp_path / "quad.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\ng left\nusemtl red\nf 1 2 3\ng right\nf 1 3 4\n")
    groups = read_obj_groups(str(path))
    assert groups.names == ("left", "right") and groups.triangle_parts.tolist() == [0, 1]
    materials = read_obj_groups(str(path), "materials")
    assert materials.names == ("red",) and materials.triangle_parts.tolist() == [0, 0]


def test_bad_parts_are_named():
    sample = chain_of_cylinders(3)
    p = sample.parts
    apart = Parts(p.positions, p.triangles, np.where(p.triangle_parts == 2, 1, p.triangle_parts), p.names)
    with pytest.raises(SkinkitError, match="part 2 has no triangle"):
        extract_skeleton(apart, "opening")
    with pytest.raises(SkinkitError, match="method"):
        extract_skeleton(p, "medial")
    with pytest.raises(SkinkitError, match="shares no opening"):
        extract_skeleton(p, "opening", parents=[-1, 0, 0])
    # Two parts that do not touch: no opening.
    far = p.positions.copy()
    separate = Parts(np.vstack([far, far + 100]), np.vstack([p.triangles, p.triangles + len(far)]),
                     np.concatenate([np.zeros(len(p.triangles), np.int32), np.ones(len(p.triangles), np.int32)]),
                     ("a", "b"))
    with pytest.raises(SkinkitError, match="part 0 has no opening"):
        extract_skeleton(separate, "centroid")


def test_hierarchy_file_round_trips(tmp_path):
    limits = free_limits(3)
    limits[1] = [[0, 150], [-10, 10], [-5, 5]]
    hierarchy = Hierarchy(("torso", "upper_arm", "forearm"), np.array([-1, 0, 1], np.int32), limits)
    path = write_hierarchy(str(tmp_path / "rig.hier"), hierarchy)
    text = open(path).read()
    assert "End Site" in text and text.splitlines()[0] == "torso -180 180 -180 180 -180 180"
    back = read_hierarchy(path)
    assert back.names == hierarchy.names and back.parents.tolist() == [-1, 0, 1]
    np.testing.assert_array_equal(back.limits, limits)
    reordered = back.reordered(["forearm", "torso", "upper_arm"])
    assert reordered.parents.tolist() == [2, -1, 1]


@pytest.mark.parametrize("text, message", [
    ("a 0 1 0 1 0 1\n{\n", "not closed"),
    ("a 0 1 0 1\n{\n}\n", "six"),
    ("a 0 1 0 1 0 1\n{\n}\nb 0 1 0 1 0 1\n{\n}\n", "second root"),
    ("a 1 0 0 1 0 1\n{\n}\n", "minimum"),
    ("}\n", "closes nothing"),
])
def test_bad_hierarchy_files_name_the_line(tmp_path, text, message):
    path = tmp_path / "bad.hier"
    path.write_text(text)
    with pytest.raises(SkinkitError, match=message):
        read_hierarchy(str(path))


def _tetrahedral_junction(n=5):
    """Four parts meeting at one point, the cow's hips in miniature: a cube surface (each face an n x n grid, each
    square fanned to its centre) split by the nearest of the tetrahedron's directions (1,1,1), (1,-1,-1), (-1,1,-1),
    (-1,-1,1). Every two parts touch along an arc; by symmetry all four turn about the cube's centre."""
    index, positions, triangles = {}, [], []

    def vertex(point):
        key = tuple(np.round(point, 9))
        if key not in index:
            index[key] = len(positions)
            positions.append(key)
        return index[key]

    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3
        for sign in (-1.0, 1.0):
            for i in range(n):
                for j in range(n):
                    corners = []
                    for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1)):
                        corner = np.zeros(3)
                        corner[axis], corner[u], corner[v] = sign, -1 + 2 * (i + di) / n, -1 + 2 * (j + dj) / n
                        corners.append(corner)
                    corners = corners if sign > 0 else corners[::-1]  # counter-clockwise from outside
                    ids, centre = [vertex(c) for c in corners], vertex(np.mean(corners, axis=0))
                    triangles += [(ids[k], ids[(k + 1) % 4], centre) for k in range(4)]
    positions, triangles = np.array(positions), np.array(triangles, np.int32)
    directions = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
    scores = positions[triangles].mean(axis=1) @ directions.T
    ordered = np.sort(scores, axis=1)
    assert (ordered[:, -1] - ordered[:, -2]).min() > 0.1  # no triangle on a tie: the labels keep the symmetry
    return Parts(positions, triangles, np.argmax(scores, axis=1).astype(np.int32), ("torso", "leg_a", "leg_b", "tail"))


@pytest.mark.parametrize("method", METHODS)
def test_a_joint_shared_by_four_parts_is_their_junction_point(method):
    """Children of one part that also touch each other share one joint: the mean of the centroids of all the
    openings among them and their parent (here exactly the centre), not each child's own opening centroid, which
    lies on one side of the junction."""
    parts = _tetrahedral_junction()
    skeleton = extract_skeleton(parts, method, parents=np.array([-1, 0, 0, 0]))
    joints = skeleton.positions[skeleton.part_joints[1:]]
    np.testing.assert_allclose(joints, 0.0, atol=1e-9)
    torso = np.isin(np.arange(len(parts.positions)), parts.triangles[parts.triangle_parts == 0])
    leg = np.isin(np.arange(len(parts.positions)), parts.triangles[parts.triangle_parts == 1])
    assert np.linalg.norm(parts.positions[torso & leg].mean(axis=0)) > 0.3  # the opening centroid is far off


def test_siblings_that_do_not_touch_keep_their_own_joints():
    """The star's limbs touch only the hub: each keeps its opening centroid (no junction)."""
    sample = star_of_limbs()
    skeleton = extract_skeleton(sample.parts, "opening", parents=sample.parents)
    np.testing.assert_allclose(skeleton.positions[skeleton.part_joints[1:]], sample.openings[1:], atol=1e-9)
