"""skinkit.runtime: the C runtime through numpy (chapter 7): kernels against a float64 definition, geomorph of a
real LOD chain (LOD0 exact at l = 0, continuous in l), culling and level selection."""
import numpy as np
import pytest

from skinkit import runtime
from skinkit._checks import SkinkitError
from skinkit.lod import build_chain
from skinkit.metrics import PoseStatistics

from .test_lod_chain import bending_model, grid, statistics


def random_pack(rng, vertices=(500, 300, 200), bones=6, tangents=True):
    meshes = []
    for count in vertices:
        counts = rng.integers(1, 5, count)
        offsets = np.concatenate(([0], np.cumsum(counts))).astype(np.int32)
        n = int(offsets[-1])
        bone_ids = rng.integers(0, bones, n).astype(np.int32)
        mesh = {"offsets": offsets, "bones": bone_ids, "coordinates": rng.normal(size=(n, 4)),
                "delta": rng.normal(size=(n, 4))}
        if tangents:
            mesh["tangents"] = (rng.normal(size=(n, 4)), rng.normal(size=(n, 4)))
            mesh["tangent_deltas"] = (rng.normal(size=(n, 4)), rng.normal(size=(n, 4)))
        meshes.append(mesh)
    return runtime.RuntimePack.from_meshes(meshes, bones), meshes


def reference(meshes, mesh_ids, fractions, poses, key="coordinates", delta="delta", slot=None):
    """sum_k G_k (p_k + f dp_k) in float64, instance after instance."""
    out = []
    for mesh_id, f, pose in zip(mesh_ids, fractions, poses):
        m = meshes[mesh_id]
        p = m[key] if slot is None else m[key][slot]
        d = m[delta] if slot is None else m[delta][slot]
        q = p + np.float64(np.float32(f)) * d
        per = np.einsum("kij,kj->ki", pose.astype(np.float32).astype(np.float64)[m["bones"], :3], q)
        vertex = np.repeat(np.arange(len(m["offsets"]) - 1), np.diff(m["offsets"]))
        v = np.zeros((len(m["offsets"]) - 1, 3))
        np.add.at(v, vertex, per)
        out.append(v)
    return np.concatenate(out)


def random_poses(rng, count, bones):
    poses = np.tile(np.eye(4), (count, bones, 1, 1))
    poses[:, :, :3, :] = rng.uniform(-1, 1, (count, bones, 3, 4))
    return poses


@pytest.mark.parametrize("kernel", ["scalar", "sse2", "avx2", "auto"])
def test_kernels_agree_with_the_definition_to_1e5(kernel):
    if kernel not in runtime.available_kernels():
        pytest.skip(f"this CPU does not run the {kernel} kernel")
    rng = np.random.default_rng(1)
    pack, meshes = random_pack(rng)
    ids = np.array([2, 0, 1, 0, 2])
    fractions = np.array([0.0, 1.0, 0.25, 0.5, 0.9])
    poses = random_poses(rng, len(ids), pack.bone_count)
    result = runtime.skin(pack, ids, fractions, poses, tangents=True, kernel=kernel, threads=2)
    scale = 1 + np.abs(reference(meshes, ids, fractions, poses)).max()
    assert np.abs(result.positions - reference(meshes, ids, fractions, poses)).max() < 1e-5 * scale
    for slot in range(2):
        expected = reference(meshes, ids, fractions, poses, "tangents", "tangent_deltas", slot)
        assert np.abs(result.tangents[slot] - expected).max() < 1e-5 * (1 + np.abs(expected).max())
    assert result.instance(1).shape == (500, 3)


def test_simd_and_scalar_agree():
    rng = np.random.default_rng(2)
    pack, _ = random_pack(rng, tangents=False)
    ids, fractions = np.array([0, 1, 2]), np.array([0.3, 0.7, 0.1])
    poses = random_poses(rng, 3, pack.bone_count)
    scalar = runtime.skin(pack, ids, fractions, poses, kernel="scalar").positions
    for kernel in set(runtime.available_kernels()) - {"scalar"}:
        simd = runtime.skin(pack, ids, fractions, poses, kernel=kernel).positions
        assert np.abs(simd - scalar).max() < 1e-5 * (1 + np.abs(scalar).max())


@pytest.mark.parametrize("kernel", ["scalar", "sse2", "avx2", "auto"])
def test_fixed_layout_agrees_with_the_definition_to_1e5(kernel):
    """The fixed-K pack (16-bit bones, K slots padded with zeros, p/dp pairs) gives the CSR pack's results; meshes of
    500, 301 and 203 vertices leave partial blocks of four."""
    if kernel not in runtime.available_kernels():
        pytest.skip(f"this CPU does not run the {kernel} kernel")
    rng = np.random.default_rng(3)
    pack, meshes = random_pack(rng, vertices=(500, 301, 203))
    fixed = pack.fixed()
    assert fixed.morphs and fixed.influences_per_vertex == 4 and fixed.bones.dtype == np.uint16
    ids = np.array([2, 0, 1, 0, 2])
    fractions = np.array([0.0, 1.0, 0.25, 0.5, 0.9])
    poses = random_poses(rng, len(ids), pack.bone_count)
    result = runtime.skin(fixed, ids, fractions, poses, tangents=True, kernel=kernel, threads=2)
    expected = reference(meshes, ids, fractions, poses)
    assert np.abs(result.positions - expected).max() < 1e-5 * (1 + np.abs(expected).max())
    for slot in range(2):
        expected = reference(meshes, ids, fractions, poses, "tangents", "tangent_deltas", slot)
        assert np.abs(result.tangents[slot] - expected).max() < 1e-5 * (1 + np.abs(expected).max())


def test_fixed_layout_without_dp_is_animation_space_evaluation():
    """morphs=False keeps p only (half the floats) and refuses a non-zero fraction; at fraction 0 it is the CSR
    pack's result for every kernel."""
    rng = np.random.default_rng(4)
    pack, meshes = random_pack(rng, vertices=(257,), tangents=False)
    plain = pack.fixed(morphs=False)
    assert not plain.morphs and plain.positions.size == 257 * plain.influences_per_vertex * 4
    poses = random_poses(rng, 2, pack.bone_count)
    expected = reference(meshes, [0, 0], [0.0, 0.0], poses)
    for kernel in runtime.available_kernels():
        got = runtime.skin(plain, [0, 0], [0.0, 0.0], poses, kernel=kernel, threads=1).positions
        assert np.abs(got - expected).max() < 1e-5 * (1 + np.abs(expected).max())
    with pytest.raises(SkinkitError, match="fractions"):
        runtime.skin(plain, [0], [0.5], poses[:1])
    with pytest.raises(SkinkitError, match="tangents"):
        runtime.skin(plain, [0], [0.0], poses[:1], tangents=True)


def test_fixed_layout_refusals():
    rng = np.random.default_rng(5)
    pack, _ = random_pack(rng, vertices=(40,), tangents=False)
    fixed = pack.fixed()
    bad_bones = fixed.bones.copy()
    bad_bones[13] = pack.bone_count
    broken = runtime.FixedPack(bad_bones, fixed.positions, None, fixed.mesh_starts, fixed.bone_count,
                               fixed.influences_per_vertex, fixed.floats_per_slot)
    with pytest.raises(SkinkitError, match="pack vertex 3"):
        runtime.skin(broken, [0], [0.5], random_poses(rng, 1, pack.bone_count), kernel="scalar")
    wide = runtime.RuntimePack.from_meshes([{"offsets": np.array([0, 1]), "bones": np.array([0]),
                                             "coordinates": np.zeros((1, 4))}], 70000)
    with pytest.raises(SkinkitError, match="65535 bones"):
        wide.fixed()
    with pytest.raises(SkinkitError, match="pack"):
        runtime.skin("not a pack", [0], [0.0], np.eye(4)[None, None])


def test_fixed_layout_problem_says_why_a_pack_does_not_fit():
    """What fixed() would refuse, asked without building the pack (the LOD Preview's fallback to CSR)."""
    rng = np.random.default_rng(6)
    pack, _ = random_pack(rng, vertices=(40,), tangents=False)
    assert pack.fixed_layout_problem() is None
    many = runtime.MAX_FIXED_SLOTS + 1
    crowded = runtime.RuntimePack.from_meshes([{"offsets": np.array([0, many]), "bones": np.arange(many),
                                                "coordinates": np.zeros((many, 4))}], many)
    assert f"{many} influences" in crowded.fixed_layout_problem()
    with pytest.raises(SkinkitError, match=f"pack: a vertex has {many} influences"):
        crowded.fixed()
    at_the_bound = runtime.RuntimePack.from_meshes([{"offsets": np.array([0, many - 1]), "bones": np.arange(many - 1),
                                                     "coordinates": np.zeros((many - 1, 4))}], many)
    assert at_the_bound.fixed_layout_problem() is None
    assert at_the_bound.fixed().influences_per_vertex == runtime.MAX_FIXED_SLOTS


def chain_fixture():
    rest, tris = grid(13)
    model = bending_model(rest)
    return build_chain(tris, rest, model, statistics(), levels=3), model


def bent_pose():
    pose = np.tile(np.eye(4), (2, 1, 1))
    a = 0.6
    pose[1, :3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    pose[1, :3, 3] = [0.5, 0.0, 0.0]
    return pose


def test_lod0_at_level_zero_is_the_model_exactly_and_every_level_matches_the_chain():
    chain, model = chain_fixture()
    assert len(chain.levels) >= 2
    pack = runtime.RuntimePack.from_chain(chain)
    pose = bent_pose()
    exact = model.evaluate(pose) if hasattr(model, "evaluate") else None
    drawn = pack.draw([0.0], pose).positions
    full = reference([{"offsets": model.offsets, "bones": model.bones, "coordinates": model.coordinates,
                       "delta": np.zeros_like(model.coordinates)}], [0], [0.0], [pose])
    assert np.abs(drawn - full).max() < 1e-5
    if exact is not None:
        assert np.abs(drawn - np.asarray(exact).reshape(-1, 3)).max() < 1e-5
    for level in np.linspace(0, len(chain.levels) - 1, 7):
        lod_model, _, _ = chain.geomorph(level)
        expected = reference([{"offsets": lod_model.offsets, "bones": lod_model.bones,
                               "coordinates": lod_model.coordinates, "delta": np.zeros_like(lod_model.coordinates)}],
                             [0], [0.0], [pose])
        assert np.abs(pack.draw([level], pose).positions - expected).max() < 1e-5


def test_geomorph_is_continuous_in_the_level():
    """No pop: as l rises to an integer k from below, level k-1's vertices reach level k's (through to_coarser)."""
    chain, _ = chain_fixture()
    pack = runtime.RuntimePack.from_chain(chain)
    pose = bent_pose()
    for k in range(1, len(chain.levels)):
        below = pack.draw([k - 1e-6], pose).positions
        at = pack.draw([float(k)], pose).positions
        mapped = at[chain.levels[k - 1].to_coarser]
        assert np.abs(below - mapped).max() < 1e-4
        steps = [pack.draw([k - 1 + t], pose).positions for t in np.linspace(0, 0.999, 12)]
        jumps = max(np.abs(b - a).max() for a, b in zip(steps, steps[1:]))
        total = np.abs(steps[-1] - steps[0]).max()
        assert jumps <= total / 11 * 1.01 + 1e-6  # linear in l: equal steps


def test_culling_keeps_every_visible_sphere():
    rng = np.random.default_rng(3)
    eye = np.array([0.0, 0.0, 5.0])
    fov, aspect, near, far = 1.0, 1.5, 0.1, 50.0
    f = 1 / np.tan(fov / 2)
    projection = np.array([[f, 0, 0, 0], [0, f * aspect, 0, 0],
                           [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)], [0, 0, -1, 0]])
    view = np.eye(4)
    view[:3, 3] = -eye
    vp = projection @ view
    spheres = np.concatenate([rng.uniform(-30, 30, (2000, 3)), rng.uniform(0, 3, (2000, 1))], axis=1)
    visible = runtime.cull(spheres, runtime.frustum_planes(vp))
    for sphere, kept in zip(spheres, visible):
        directions = rng.normal(size=(64, 3))
        points = sphere[:3] + sphere[3] * directions / np.linalg.norm(directions, axis=1, keepdims=True)
        clip = np.c_[np.vstack([sphere[:3], points]), np.ones(65)] @ vp.T
        inside = (clip[:, 3] > 0) & (np.abs(clip[:, :3]) <= clip[:, 3:4]).all(axis=1)
        assert kept or not inside.any()
    assert 0 < visible.sum() < len(spheres)


def test_selected_level_never_exceeds_the_allowed_error():
    rng = np.random.default_rng(4)
    epsilons = np.array([0.0, 0.01, 0.05, 0.2], np.float32)
    spheres = np.concatenate([np.zeros((500, 2)), -rng.uniform(0.5, 300, (500, 1)), rng.uniform(0, 1, (500, 1))], 1)
    spheres[0] = [0, 0, 0.5, 1]  # the camera inside: full detail
    levels = runtime.select_levels(spheres, epsilons, [0, 0, 0], [0, 0, -1], 1.0, 1280, 1.5)
    single = spheres.astype(np.float32).astype(np.float64)
    depth = np.maximum(-single[:, 2] - single[:, 3], 0)
    allowed = 2 * 1.5 * depth * np.sin(0.5) / 1280
    interpolated = np.interp(levels, np.arange(4), epsilons.astype(np.float64))
    assert (interpolated <= allowed * (1 + 1e-6) + 1e-12).all()
    assert levels.min() == 0 and levels.max() == 3
    assert len(np.unique(levels)) > 100  # real-valued, not just the discrete levels
    farther = np.argsort(depth)
    assert (np.diff(levels[farther]) >= -1e-6).all()  # coarser with distance


def test_culling_sphere_holds_every_sampled_pose():
    rest, _ = grid(6)
    model = bending_model(rest)
    stats = statistics()
    sphere = runtime.culling_sphere(model, stats)
    for a in np.linspace(-0.5, 0.5, 9):
        pose = bent_pose()
        pose[1, :3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
        positions = runtime.skin(runtime.RuntimePack.from_model(model), [0], [0.0], [pose]).positions
        assert (np.linalg.norm(positions - sphere[:3], axis=1) <= sphere[3] * (1 + 1e-5)).all()


def test_morph_uv_and_refusals():
    uv = runtime.morph_uv([[0.0, 1.0, 1.0, -1.0]], 0.25)
    assert np.allclose(uv, [[0.25, 0.75]])
    rng = np.random.default_rng(5)
    pack, _ = random_pack(rng, tangents=False)
    poses = random_poses(rng, 1, pack.bone_count)
    with pytest.raises(SkinkitError, match="kernel"):
        runtime.skin(pack, [0], [0.0], poses, kernel="neon")
    with pytest.raises(SkinkitError, match="fraction"):
        runtime.skin(pack, [0], [1.5], poses)
    with pytest.raises(SkinkitError, match="meshes"):
        runtime.skin(pack, [3], [0.0], poses)
    with pytest.raises(SkinkitError, match="poses"):
        runtime.skin(pack, [0], [0.0], poses[:, :2])
    with pytest.raises(SkinkitError, match="tangents"):
        runtime.skin(pack, [0], [0.0], poses, tangents=True)
    with pytest.raises(SkinkitError, match="forward"):
        runtime.select_levels([[0, 0, -1, 0]], [0.0], [0, 0, 0], [0, 0, -2], 1.0, 100, 1.0)
