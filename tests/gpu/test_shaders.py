"""skinkit/shaders on Mesa's software OpenGL (llvmpipe through EGL, installed by the Makefile) against the C runtime,
to 1e-5: the compute shader (geomorph, tangents, a batch of instances) and the vertex shader in the glTF attribute
layout. Skipped, saying why, only when no OpenGL 4.3 context can be created."""
import numpy as np
import pytest

from skinkit import runtime
from skinkit.shaders import NAMES, source

from ..core.test_runtime import random_pack, random_poses

moderngl = pytest.importorskip("moderngl", reason="moderngl is not installed (requirements-dev.txt pins it)")
from skinkit.shaders import gl  # noqa: E402  (needs moderngl)


@pytest.fixture(scope="module")
def ctx():
    try:
        context = gl.create_context()
    except RuntimeError as exc:
        pytest.skip(str(exc))
    yield context
    context.release()


def test_sources_are_shipped_and_defines_follow_the_version_line():
    for name in NAMES:
        assert source(name).startswith("#version 430")
    text = source("skin_vertex", {"SKINKIT_SLOTS": 4})
    assert text.splitlines()[:2] == ["#version 430", "#define SKINKIT_SLOTS 4"]


def test_compute_shader_matches_the_cpu_runtime(ctx):
    rng = np.random.default_rng(11)
    pack, _ = random_pack(rng, vertices=(700, 130, 64))
    meshes = np.array([0, 2, 1, 0, 1])
    fractions = np.array([0.0, 1.0, 0.3, 0.77, 0.5], np.float32)
    poses = random_poses(rng, len(meshes), pack.bone_count)
    cpu = runtime.skin(pack, meshes, fractions, poses, tangents=True, kernel="scalar")
    skinner = gl.ComputeSkinner(ctx, pack)
    positions, tangents = skinner.skin(meshes, fractions, runtime.bone_matrices(poses), tangents=True)
    skinner.release()
    scale = 1 + np.abs(cpu.positions).max()
    assert np.abs(positions - cpu.positions).max() < 1e-5 * scale
    for slot in range(2):
        assert np.abs(tangents[slot] - cpu.tangents[slot]).max() < 1e-5 * (1 + np.abs(cpu.tangents[slot]).max())


@pytest.mark.parametrize("slots, geomorph", [(4, False), (8, False), (4, True)])
def test_vertex_shader_reads_the_gltf_layout(ctx, slots, geomorph):
    """Per-vertex slots (JOINTS_0/1, _SKINKIT_P_<j>, zero-padded) give what the CPU runtime gives on CSR data."""
    rng = np.random.default_rng(12 + slots)
    count, bones = 400, 9
    used = rng.integers(1, slots + 1, count)
    joints = np.zeros((count, slots), np.uint32)
    p = np.zeros((count, slots, 4))
    dp = np.zeros((count, slots, 4))
    for v in range(count):
        joints[v, :used[v]] = rng.choice(bones, used[v], replace=False)
        p[v, :used[v]] = rng.normal(size=(used[v], 4))
        dp[v, :used[v]] = rng.normal(size=(used[v], 4))
    mask = np.arange(slots)[None] < used[:, None]
    offsets = np.concatenate(([0], np.cumsum(used))).astype(np.int32)
    pack = runtime.RuntimePack.from_meshes([{"offsets": offsets, "bones": joints[mask], "coordinates": p[mask],
                                             "delta": dp[mask]}], bones)
    poses = random_poses(rng, 1, bones)
    fraction = 0.375 if geomorph else 0.0
    cpu = runtime.skin(pack, [0], [fraction], poses, kernel="scalar").positions
    gpu = gl.vertex_shader_skin(ctx, joints, p, runtime.bone_matrices(poses)[0], dp if geomorph else None, fraction)
    assert np.abs(gpu - cpu).max() < 1e-5 * (1 + np.abs(cpu).max())


def test_vertex_shader_refuses_geomorph_over_eight_slots(ctx):
    with pytest.raises(moderngl.Error, match="SKINKIT_SLOTS 4"):
        ctx.program(vertex_shader=source("skin_vertex", {"SKINKIT_SLOTS": 8, "SKINKIT_GEOMORPH": ""}),
                    varyings=["skinned_position"])
