"""The numpy API and the C core beneath it: conversion, evaluation, tangents, precision, bad input."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import skinkit as sk
from skinkit import _core


def random_rotations(rng, count):
    """Uniformly distributed proper rotations (det +1)."""
    q, r = np.linalg.qr(rng.normal(size=(count, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    q[:, :, 0] *= np.sign(np.linalg.det(q))[:, None]
    return q


def random_frames(rng, count, scale=(0.5, 2.0)):
    """Random affine frames (rotation, uniform scale, translation); frame 0 is the identity (the root)."""
    frames = np.tile(np.eye(4), (count, 1, 1))
    frames[:, :3, :3] = random_rotations(rng, count) * rng.uniform(*scale, (count, 1, 1))
    frames[:, :3, 3] = rng.normal(size=(count, 3))
    frames[0] = np.eye(4)
    return frames


def random_rig(rng, vertices=500, bones=6, influences=4):
    """A chain skeleton, random weights (1..influences per vertex, summing to 1) and rest positions."""
    skeleton = sk.Skeleton.create(np.arange(bones) - 1, random_frames(rng, bones))
    dense = np.zeros((vertices, bones))
    for _ in range(influences):
        dense[np.arange(vertices), rng.integers(0, bones, vertices)] += rng.uniform(0.1, 1.0, vertices)
    dense /= dense.sum(axis=1, keepdims=True)
    return skeleton, sk.SparseWeights.from_dense(dense), rng.normal(size=(vertices, 3)), dense


def reference_lbs(skeleton, dense, vectors, pose, homogeneous=1.0):
    """Plain numpy linear blend skinning, independent of the core."""
    matrices = pose @ np.linalg.inv(skeleton.rest_frames)
    points = np.column_stack([vectors, np.full(len(vectors), homogeneous)])
    return np.einsum("vb,bij,vj->vi", dense, matrices, points)[:, :3]


def test_conversion_reproduces_linear_blend_skinning():
    rng = np.random.default_rng(1)
    skeleton, weights, rest, dense = random_rig(rng)
    model = sk.convert_lbs(skeleton, weights, rest)
    assert np.allclose(model.homogeneous_weights(), 1.0)
    for _ in range(10):
        pose = random_frames(rng, skeleton.bone_count)
        expected = reference_lbs(skeleton, dense, rest, pose)
        assert np.abs(model.evaluate(pose) - expected).max() < 1e-12
        assert np.abs(sk.lbs_evaluate(skeleton, weights, rest, pose) - expected).max() < 1e-12


def test_rest_pose_returns_rest_positions():
    rng = np.random.default_rng(2)
    skeleton, weights, rest, _ = random_rig(rng)
    model = sk.convert_lbs(skeleton, weights, rest)
    assert np.abs(model.evaluate(skeleton.rest_frames) - rest).max() < 1e-12


def test_float32_path_matches_float64():
    rng = np.random.default_rng(3)
    skeleton, weights, rest, _ = random_rig(rng, vertices=3000)
    model = sk.convert_lbs(skeleton, weights, rest)
    poses = np.stack([random_frames(rng, skeleton.bone_count) for _ in range(5)])
    exact = model.evaluate(poses)
    fast = model.evaluate(poses, dtype=np.float32)
    assert fast.dtype == np.float32 and fast.shape == exact.shape == (5, 3000, 3)
    assert np.abs(fast - exact).max() < 1e-4 * np.abs(exact).max()
    lbs_fast = sk.lbs_evaluate(skeleton, weights, rest, poses, dtype=np.float32)
    assert np.abs(lbs_fast - exact).max() < 1e-4 * np.abs(exact).max()


def test_evaluate_into_a_caller_buffer():
    rng = np.random.default_rng(10)
    skeleton, weights, rest, _ = random_rig(rng, vertices=100)
    model = sk.convert_lbs(skeleton, weights, rest)
    poses = np.stack([random_frames(rng, skeleton.bone_count) for _ in range(3)]).astype(np.float32)
    buffer = np.empty((3, 100, 3), np.float32)
    assert model.evaluate(poses, np.float32, out=buffer) is buffer
    assert np.array_equal(buffer, model.evaluate(poses, np.float32))
    single = np.empty((100, 3), np.float32)
    model.evaluate(poses[1], np.float32, out=single)
    assert np.array_equal(single, buffer[1])
    with pytest.raises(sk.SkinkitError, match=r"out: expected a writable C-contiguous float32 array of shape \(100, 3\)"):
        model.evaluate(poses[1], np.float32, out=np.empty((100, 3)))


def test_thread_count_does_not_change_results():
    rng = np.random.default_rng(4)
    skeleton, weights, rest, _ = random_rig(rng, vertices=100000, bones=8)
    model = sk.convert_lbs(skeleton, weights, rest)
    pose = random_frames(rng, skeleton.bone_count)
    serial = model.evaluate(pose, dtype=np.float32, threads=1)
    for threads in (0, 2, 7):
        assert np.array_equal(model.evaluate(pose, dtype=np.float32, threads=threads), serial)


def test_tangents_follow_the_blended_transform():
    """Eq. 4.8-4.9: q_j = w_j Ĝ_j^-1 ŝ evaluates to M ŝ, M the blended skinning matrix."""
    rng = np.random.default_rng(5)
    skeleton, weights, rest, dense = random_rig(rng)
    tangents = rng.normal(size=rest.shape)
    tangent_model = sk.convert_lbs(skeleton, weights, tangents, homogeneous=0.0)
    assert np.allclose(tangent_model.homogeneous_weights(), 0.0)
    assert np.all(tangent_model.coordinates[:, 3] == 0.0)
    pose = random_frames(rng, skeleton.bone_count)
    expected = reference_lbs(skeleton, dense, tangents, pose, homogeneous=0.0)
    assert np.abs(tangent_model.evaluate(pose) - expected).max() < 1e-12


def test_normals_from_tangents_of_a_rigid_piece_rotate_with_it():
    rng = np.random.default_rng(6)
    skeleton = sk.Skeleton.create([-1, 0], random_frames(rng, 2))
    weights = sk.SparseWeights.from_dense(np.tile([0.0, 1.0], (20, 1)))
    s, t = rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    pose = random_frames(rng, 2, scale=(1.0, 1.0))
    s_model = sk.convert_lbs(skeleton, weights, s, 0.0)
    t_model = sk.convert_lbs(skeleton, weights, t, 0.0)
    normals = sk.normals_from_tangents(s_model.evaluate(pose), t_model.evaluate(pose))
    # A uniformly scaled rotation: normals turn with it and keep unit length.
    rotation = pose[1, :3, :3] @ np.linalg.inv(skeleton.rest_frames[1, :3, :3])
    rotated = sk.normals_from_tangents(s, t) @ rotation.T
    expected = rotated / np.linalg.norm(rotated, axis=1, keepdims=True)
    assert np.abs(normals - expected).max() < 1e-12


def test_vertices_without_weights_stay_put_like_blender():
    """Blender leaves a vertex with total weight below 1e-4 undeformed: skinkit binds it to the root."""
    dense = np.array([[0.0, 0.5, 0.5], [0.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    normalized = sk.SparseWeights.from_dense(dense).normalized_like_blender()
    assert np.allclose(normalized.to_dense(3), [[0, 0.5, 0.5], [1, 0, 0], [0, 1, 0]])


def test_sparse_weights_round_trip():
    rng = np.random.default_rng(7)
    dense = rng.uniform(size=(50, 5)) * (rng.uniform(size=(50, 5)) > 0.6)
    weights = sk.SparseWeights.from_dense(dense)
    assert np.allclose(weights.to_dense(5), dense)
    assert np.array_equal(weights.counts(), (dense > 0).sum(axis=1))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), vertices=st.integers(0, 40), bones=st.integers(1, 7),
       influences=st.integers(1, 4))
def test_conversion_matches_lbs_for_any_rig(seed, vertices, bones, influences):
    rng = np.random.default_rng(seed)
    skeleton = sk.Skeleton.create([-1] + [int(rng.integers(0, j)) for j in range(1, bones)],
                                  random_frames(rng, bones))
    dense = np.zeros((vertices, bones))
    for _ in range(influences):
        dense[np.arange(vertices), rng.integers(0, bones, vertices)] += rng.uniform(0.0, 1.0, vertices)
    weights = sk.SparseWeights.from_dense(dense)
    rest = rng.normal(size=(vertices, 3)) * 10
    pose = random_frames(rng, bones)
    expected = reference_lbs(skeleton, dense, rest, pose)
    assert np.allclose(sk.convert_lbs(skeleton, weights, rest).evaluate(pose), expected, atol=1e-9)


# ---- bad input: a clear exception naming the problem, never a crash -----------------------------------

def identity_frames(count):
    return np.tile(np.eye(4), (count, 1, 1))


@pytest.mark.parametrize("parents, message", [
    ([-1, 2, 1], "cycle"),
    ([-1, 5], "outside"),
    ([0, 0], "root"),
    ([-1, 1], "cycle"),
])
def test_bad_parents(parents, message):
    with pytest.raises(sk.SkinkitError, match=message):
        sk.Skeleton.create(parents, identity_frames(len(parents)))


@pytest.mark.parametrize("scale", [0.0, 1e-14])
def test_singular_rest_frames(scale):
    frames = identity_frames(2)
    frames[1, 2, 2] = scale
    with pytest.raises(sk.SkinkitError, match="bone 1: rest frame is singular"):
        sk.Skeleton.create([-1, 0], frames)


def test_non_affine_and_non_finite_rest_frames():
    frames = identity_frames(2)
    frames[1, 3, 0] = 1.0
    with pytest.raises(sk.SkinkitError, match="not affine"):
        sk.Skeleton.create([-1, 0], frames)
    frames = identity_frames(2)
    frames[1, 0, 3] = np.nan
    with pytest.raises(sk.SkinkitError, match="rest_frames: contains NaN"):
        sk.Skeleton.create([-1, 0], frames)


def test_bad_shapes_and_dtypes():
    rng = np.random.default_rng(8)
    skeleton, weights, rest, _ = random_rig(rng, vertices=10, bones=3)
    model = sk.convert_lbs(skeleton, weights, rest)
    with pytest.raises(sk.SkinkitError, match=r"poses: expected shape \(N, 3, 4, 4\)"):
        model.evaluate(identity_frames(2))
    with pytest.raises(sk.SkinkitError, match="rest_vectors: expected shape"):
        sk.convert_lbs(skeleton, weights, rest[:5])
    with pytest.raises(sk.SkinkitError, match="expected real numbers"):
        sk.convert_lbs(skeleton, weights, rest.astype(complex))
    with pytest.raises(sk.SkinkitError, match="parents: expected integers"):
        sk.Skeleton.create(["a", "b"], identity_frames(2))
    with pytest.raises(sk.SkinkitError, match="dtype"):
        model.evaluate(skeleton.rest_frames, dtype=np.int32)
    with pytest.raises(sk.SkinkitError, match="parents: expected integers"):
        sk.Skeleton.create([-1.0, 0.5], identity_frames(2))


def test_nan_in_inputs():
    rng = np.random.default_rng(9)
    skeleton, weights, rest, _ = random_rig(rng, vertices=10, bones=3)
    bad = rest.copy()
    bad[3, 1] = np.nan
    with pytest.raises(sk.SkinkitError, match=r"rest_vectors: contains NaN or infinity \(first at index \(3, 1\)\)"):
        sk.convert_lbs(skeleton, weights, bad)
    pose = skeleton.rest_frames.copy()
    pose[2, 0, 0] = np.inf
    with pytest.raises(sk.SkinkitError, match="poses: contains NaN"):
        sk.convert_lbs(skeleton, weights, rest).evaluate(pose)


def test_out_of_range_indices():
    with pytest.raises(sk.SkinkitError, match="vertex 1: bone index 3 is outside"):
        sk.SparseWeights.create([0, 1, 2], [0, 3], [1.0, 1.0], bone_count=3)
    with pytest.raises(sk.SkinkitError, match="vertex 0: bone index -1"):
        sk.AnimationSpaceModel.create([0, 1], [-1], [[0, 0, 0, 1.0]], bone_count=2)
    with pytest.raises(sk.SkinkitError, match="offsets decrease"):
        sk.SparseWeights.create([0, 2, 1, 3], [0, 0, 0], [1.0, 1.0, 1.0], bone_count=1)
    with pytest.raises(sk.SkinkitError, match="must equal the influence count"):
        sk.SparseWeights.create([0, 1, 5], [0, 0], [1.0, 1.0], bone_count=1)


def test_core_refuses_inconsistent_buffers_without_touching_memory():
    """The binding re-checks counts and types, whatever the Python layer passes."""
    offsets = np.array([0, 1, 2], np.int32)
    bones = np.array([0, 1], np.int32)
    coordinates = np.zeros((2, 4))
    poses = identity_frames(2).reshape(-1)
    with pytest.raises(ValueError, match="destination has 3 elements, expected 6"):
        _core.animation_space_evaluate(np.empty(3), offsets, bones, coordinates, poses, 1)
    with pytest.raises(TypeError, match="same precision"):
        _core.animation_space_evaluate(np.empty(6, np.float32), offsets, bones, coordinates, poses, 1)
    with pytest.raises(TypeError, match="element type"):
        _core.animation_space_evaluate(np.empty(6), offsets.astype(np.int64), bones, coordinates, poses, 1)
    with pytest.raises(TypeError, match="writable"):
        read_only = np.empty(6)
        read_only.flags.writeable = False
        _core.animation_space_evaluate(read_only, offsets, bones, coordinates, poses, 1)
    with pytest.raises(ValueError, match="bone index 1 is outside"):
        _core.animation_space_evaluate(np.empty(6), offsets, bones, coordinates, poses[:16], 1)
    with pytest.raises(ValueError, match="offsets"):
        _core.animation_space_evaluate(np.empty(0), np.array([], np.int32), bones, coordinates, poses, 1)


def test_mesh_validation():
    mesh = sk.Mesh.create(np.zeros((4, 3)), [[0, 1, 2], [0, 2, 3]], [0, 0], [[0, 1, 2], [0, 2, 3]])
    assert mesh.vertex_count == 4 and mesh.triangles.dtype == np.int32
    with pytest.raises(sk.SkinkitError, match=r"triangle 1: vertex index 4 is outside \[0, 4\)"):
        sk.Mesh.create(np.zeros((4, 3)), [[0, 1, 2], [0, 2, 4]])
    with pytest.raises(sk.SkinkitError, match="triangle 0: repeats a vertex"):
        sk.Mesh.create(np.zeros((4, 3)), [[0, 1, 1]])
    with pytest.raises(sk.SkinkitError, match=r"triangle_loops: expected shape \(1, 3\)"):
        sk.Mesh.create(np.zeros((3, 3)), [[0, 1, 2]], [0], [[0, 1]])
