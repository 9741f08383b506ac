"""Algorithm 5 in C (sk_reconstruct_seams) on synthetic posed cylinder chains: the same frames as the Python path
it replaces, point for point."""
import numpy as np
import pytest

from skinkit.skeleton import chain_of_cylinders, extract_skeleton
from skinkit.skeleton.animation import Channel, Keyframes
from skinkit.skeleton.seams import boundary_edges, is_consistently_oriented, prepare_seams_for_rig

from .test_skeleton_animation import _split_middle, pose_about


def _random_poses(parents, joints, seed, count=13):
    rng = np.random.default_rng(seed)
    channels = {3 * part + axis: Channel(np.array([0.0, 3.0, 6.0]), np.array([0.0, *rng.uniform(-50, 50, 2)]),
                                         ["smooth"] * 3, ["smooth"] * 3)
                for part in range(1, len(parents)) for axis in (1, 2)}
    for time in np.linspace(0.0, 6.0, count):
        angles = Keyframes(0.0, 6.0, channels).angles(time, len(parents))
        world = np.tile(np.eye(4), (len(parents), 1, 1))
        for part in range(1, len(parents)):
            world[part] = world[parents[part]] @ pose_about(joints[part], angles[part])
        yield world


@pytest.mark.parametrize("make", ["chain", "split"])
def test_c_reconstruction_equals_the_python_path(make):
    sample = chain_of_cylinders(4, sides=12, rings_per_part=4)
    if make == "chain":
        skeleton = extract_skeleton(sample.parts, "centroid", parents=sample.parents)
        parts, parents, joints = sample.parts, skeleton.part_parents, skeleton.positions[skeleton.part_joints]
    else:
        parts, parents, joints = _split_middle(chain_of_cylinders(3, sides=12, rings_per_part=4))
    mesh = prepare_seams_for_rig(parts, parents, joints, 3)
    removed = 0
    for world in _random_poses(parents, joints, 11):
        old, new = mesh._reconstruct_python(world), mesh.reconstruct(world)
        assert (new.removed_points, new.fill_points, new.fallback) == (old.removed_points, old.fill_points,
                                                                       old.fallback)
        np.testing.assert_array_equal(new.triangles, old.triangles)
        np.testing.assert_allclose(new.positions, old.positions, atol=1e-12)
        np.testing.assert_allclose(new.normals, old.normals, atol=1e-9)
        assert boundary_edges(new.triangles) == 0 and is_consistently_oriented(new.triangles)
        removed += new.removed_points
    assert removed > 0  # the poses do sink points, so the removal and the fill were compared too
