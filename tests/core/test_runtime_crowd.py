"""skinkit.crowd: synthetic characters' levels (half the influences each, epsilons measured and non-decreasing,
geomorph continuous) and a crowd frame whose culling keeps what the camera sees and whose pixel error stays within
the tolerance."""
import numpy as np
import pytest

from skinkit import crowd, runtime
from skinkit._checks import SkinkitError


@pytest.fixture(scope="module")
def character():
    return crowd.tube_character(3000, bones=8, influences=3, levels=3, seed=4)


def test_levels_halve_and_epsilons_rise(character):
    counts = character.pack.vertex_counts
    assert len(counts) == 3 and all(1.8 < a / b < 2.2 for a, b in zip(counts, counts[1:]))
    eps = character.pack.epsilons
    assert eps[0] == 0 and (np.diff(eps) > 0).all()


def test_sphere_holds_random_poses(character):
    rng = np.random.default_rng(5)
    poses = crowd.random_poses(rng, 20, character.joints)
    drawn = character.pack.draw(np.zeros(20), poses).positions
    assert (np.linalg.norm(drawn - character.sphere[:3], axis=1) <= character.sphere[3] * (1 + 1e-5)).all()


def test_geomorph_reaches_the_coarser_level(character):
    pose = crowd.random_poses(np.random.default_rng(6), 1, character.joints)[0]
    for k, mapped in enumerate(character.to_coarser):
        almost = character.pack.draw([k + 1 - 1e-7], pose).positions
        coarse = character.pack.draw([float(k + 1)], pose).positions
        assert np.abs(almost - coarse[mapped]).max() < 1e-4


def test_crowd_frame_within_tolerance_and_faster_than_full_detail():
    scene = crowd.random_crowd(12, (2000, 6000), kinds=2, bones=8, influences=3, levels=3, extent=15.0, seed=7)
    camera = crowd.look_camera([-60.0, -60.0, 1.7], [0.0, 0.0, 0.9])  # far: coarser levels
    result = crowd.measure_crowd(scene, [camera], pixel_tolerance=2.0, threads=1, repeats=1)
    frame = result["frames"][0]
    assert 0 < frame["visible"] <= 12
    assert frame["drawn_vertices"] < frame["full_vertices"]
    assert frame["pixel_error"] <= 2.0 * (1 + 1e-3)
    plan = crowd.plan_frame(scene, camera, 2.0)
    spheres = scene.spheres()
    behind = crowd.look_camera([-60.0, -60.0, 1.7], [-90.0, -90.0, 0.9])
    assert runtime.cull(spheres, runtime.frustum_planes(behind.view_projection)).sum() < plan.visible.sum()


def test_triad_and_bad_sizes():
    assert crowd.triad_bandwidth(elements=200_000, threads=2, repeats=2) > 0
    with pytest.raises(SkinkitError, match="vertices"):
        crowd.tube_character(10)
