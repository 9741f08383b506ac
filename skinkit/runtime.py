"""The real-time runtime of animation-space characters (Merry 2007, chapter 7) on numpy arrays: frustum culling
with the culling sphere, level selection for a pixel tolerance with a real-valued level, and batched geomorphing
skinning (CPU algorithm 1: scalar, SSE2 or AVX2+FMA, threaded) over a RuntimePack of meshes.

The C side (csrc/runtime/sk_runtime_*.c, the "Runtime" section of csrc/skinkit.h) is what an engine embeds; this
module only shapes the arrays. Everything is single precision, as an engine would draw it.

    pack = RuntimePack.from_chain(chain)             # one mesh per level, geomorph data on common sets
    visible = cull(spheres, frustum_planes(view_projection))
    levels = select_levels(spheres, epsilons, position, forward, fov, width, pixel_tolerance=1.0)
    out = skin(pack, meshes, fractions, poses)       # or pack.draw(levels, poses) for one chain
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _core
from ._checks import FLAG, THREADS, SkinkitError, as_array, as_index_array, as_real_array, checked, count, optional, real
from .metrics import PoseStatistics
from .model import AnimationSpaceModel

__all__ = ["KERNELS", "available_kernels", "frustum_planes", "cull", "select_levels", "morph_uv", "culling_sphere",
           "RuntimePack", "FixedPack", "SkinResult", "skin", "bone_matrices"]

#: The fixed-K layout's bounds (sk_runtime_fixed_pack): 16-bit bone indices, at most 64 slots per vertex.
MAX_FIXED_BONES = 65535
MAX_FIXED_SLOTS = 64

#: The vertex transformation kernels by name; "auto" is the fastest this CPU runs.
KERNELS = {"auto": 0, "scalar": 1, "sse2": 2, "avx2": 3}


def available_kernels() -> list[str]:
    """The kernels this build and CPU can run ("auto" and "scalar" always)."""
    return [name for name, value in KERNELS.items() if _core.runtime_kernel_supported(value)["supported"]]


def _kernel_value(kernel: str) -> int:
    if not isinstance(kernel, str) or kernel not in KERNELS:
        raise SkinkitError(f"kernel: expected one of {sorted(KERNELS)}, got {kernel!r}")
    return KERNELS[kernel]


def _f32(value, name, shape=None) -> np.ndarray:
    return as_real_array(value, name, np.float32, shape)


def frustum_planes(view_projection) -> np.ndarray:
    """(6, 4) inward unit planes (left, right, bottom, top, near, far) of a row-major OpenGL view-projection
    matrix (4, 4): a point x is inside plane (n, d) when n . x + d >= 0."""
    matrix = _f32(view_projection, "view_projection", (4, 4))
    planes = np.empty((6, 4), np.float32)
    _core.runtime_frustum_planes(planes.reshape(-1), matrix.reshape(-1))
    return planes


def cull(spheres, planes) -> np.ndarray:
    """(N,) bool: False where sphere (x, y, z, r) (N, 4) lies wholly outside one of planes (P, 4) (section 7.2)."""
    spheres = _f32(spheres, "spheres", (None, 4))
    planes = _f32(planes, "planes", (None, 4))
    visible = np.empty(len(spheres), np.uint8)
    _core.runtime_cull(visible, spheres.reshape(-1), planes.reshape(-1))
    return visible.astype(bool)


@checked(horizontal_fov=real(above=0), viewport_width=real(above=0), pixel_tolerance=real(above=0))
def select_levels(spheres, epsilons, position, forward, horizontal_fov: float, viewport_width: float,
                  pixel_tolerance: float) -> np.ndarray:
    """(N,) float32 real levels (eq. 7.2): for each sphere (N, 4) the level between the two discrete levels whose
    epsilons (N, L) or (L,) (non-decreasing from 0, +inf padding shorter chains) bracket the error that
    pixel_tolerance pixels allow at the sphere's minimum depth along forward (a unit vector) from position, for
    a horizontal field of view (radians) over viewport_width pixels."""
    spheres = _f32(spheres, "spheres", (None, 4))
    eps = as_real_array(epsilons, "epsilons", np.float32)
    if eps.ndim == 1:
        eps = np.tile(eps, (len(spheres), 1))
    if eps.ndim != 2 or eps.shape[0] != len(spheres) or eps.shape[1] < 1:
        raise SkinkitError(f"epsilons: expected shape (L,) or ({len(spheres)}, L), got {np.shape(epsilons)}")
    if np.isnan(eps).any():
        raise SkinkitError("epsilons: contains NaN")
    levels = np.empty(len(spheres), np.float32)
    _core.runtime_select_levels(levels, spheres.reshape(-1), np.ascontiguousarray(eps).reshape(-1), eps.shape[1],
                                _f32(position, "position", (3,)), _f32(forward, "forward", (3,)),
                                float(horizontal_fov), float(viewport_width), float(pixel_tolerance))
    return levels


@checked(fraction=real(minimum=0, maximum=1))
def morph_uv(uv_morph, fraction: float) -> np.ndarray:
    """(C, 2) texture coordinates uv + fraction duv from uv_morph (C, 4) = (u, v, du, dv) (listing C.5)."""
    morph = _f32(uv_morph, "uv_morph", (None, 4))
    out = np.empty((len(morph), 2), np.float32)
    _core.runtime_morph_uv(out.reshape(-1), morph.reshape(-1), float(fraction))
    return out


@checked(model=AnimationSpaceModel, statistics=PoseStatistics, centre_statistics=optional(PoseStatistics))
def culling_sphere(model: AnimationSpaceModel, statistics, centre_statistics=None) -> np.ndarray:
    """(4,) float32 (x, y, z, r) in object space holding the model in every pose within the statistics' joint
    bounds (section 7.2): the centre is the expected centroid under uniformly random rotations with fixed
    translations (the thesis' unbiased choice; pass centre_statistics to override), the radius the largest
    max-distance bound of a vertex from it."""
    if centre_statistics is None:
        centre_statistics = PoseStatistics.uniform_rotations(statistics.parents, statistics.translation_centre)
    centre, radius = statistics.culling_sphere(model, centre_statistics)
    return np.array([*centre, radius], np.float32)


def bone_matrices(poses) -> np.ndarray:
    """(..., B, 12) float32: the top three rows of each 4x4 bone frame G_j (..., B, 4, 4), as the runtime reads
    them."""
    poses = as_array(poses, "poses")
    if poses.ndim < 3 or poses.shape[-2:] != (4, 4):
        raise SkinkitError(f"poses: expected (..., bones, 4, 4), got shape {poses.shape}")
    return _f32(poses[..., :3, :], "poses").reshape(*poses.shape[:-2], 12)


def _interleave(coordinates, delta, name) -> np.ndarray:
    p = as_real_array(coordinates, name, np.float32, (None, 4))
    d = np.zeros_like(p) if delta is None else as_real_array(delta, name + " delta", np.float32, (len(p), 4))
    return np.ascontiguousarray(np.concatenate([p, d], axis=1))


def tangent_pair(value, name: str) -> tuple:
    """The two tangents' coordinates ((n, 4), (n, 4)) of a mesh."""
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise SkinkitError(f"{name}: expected two tangents' coordinates ((n, 4), (n, 4)), got {type(value).__name__}")
    return tuple(value)


def mesh_dicts(value, name: str) -> list:
    """A non-empty list of dicts, each with offsets, bones and coordinates (see RuntimePack.from_meshes)."""
    if not isinstance(value, (list, tuple)) or not value:
        raise SkinkitError(f"{name}: expected a non-empty list of meshes (dicts), got {type(value).__name__}")
    for index, mesh in enumerate(value):
        if not isinstance(mesh, dict) or not {"offsets", "bones", "coordinates"} <= set(mesh):
            raise SkinkitError(f"{name}[{index}]: expected a dict with offsets, bones and coordinates")
    return list(value)


class _MeshRanges:
    """The meshes (levels) of a pack, from its mesh_starts: shared by both pack layouts."""

    @property
    def mesh_count(self) -> int:
        return len(self.mesh_starts) - 1

    @property
    def vertex_counts(self) -> np.ndarray:
        return np.diff(self.mesh_starts)


@dataclass(frozen=True, eq=False)
class RuntimePack(_MeshRanges):
    """Meshes to skin, as the C runtime reads them: one CSR pattern over all meshes' vertices (mesh m owns
    vertices mesh_starts[m] .. mesh_starts[m + 1] - 1), per influence p and dp interleaved (8 floats) for positions
    and optionally (16 floats) for two tangents. epsilons[m] is the mesh's simplification error when the pack is a
    LOD chain (mesh = level)."""
    offsets: np.ndarray
    bones: np.ndarray
    positions: np.ndarray          # (n, 8) float32
    tangents: np.ndarray | None    # (n, 16) float32
    mesh_starts: np.ndarray        # (M + 1,) int32
    bone_count: int
    epsilons: np.ndarray | None = None

    def influence_counts(self) -> np.ndarray:
        """Influences per mesh (each mesh's share of the pattern, zero-padded slots included)."""
        return np.diff(self.offsets[self.mesh_starts])

    @classmethod
    @checked(meshes=mesh_dicts, bone_count=count(1))
    def from_meshes(cls, meshes, bone_count: int, epsilons=None) -> "RuntimePack":
        """From a list of dicts with offsets, bones, coordinates (n, 4) and optionally delta (n, 4), tangents
        ((n, 4), (n, 4)) and tangent_deltas: one mesh each, in order."""
        if not meshes:
            raise SkinkitError("meshes: at least one mesh is needed")
        offsets, bones, positions, tangents, starts = [np.zeros(1, np.int32)], [], [], [], [0]
        influence_total = 0
        with_tangents = meshes[0].get("tangents") is not None
        for index, mesh in enumerate(meshes):
            mesh_offsets = as_index_array(mesh["offsets"], f"meshes[{index}].offsets", (None,))
            mesh_bones = as_index_array(mesh["bones"], f"meshes[{index}].bones", (None,))
            if len(mesh_offsets) < 1 or mesh_offsets[0] != 0 or mesh_offsets[-1] != len(mesh_bones):
                raise SkinkitError(f"meshes[{index}].offsets: must run from 0 to its {len(mesh_bones)} influences")
            offsets.append(mesh_offsets[1:] + influence_total)
            influence_total += len(mesh_bones)
            bones.append(mesh_bones)
            positions.append(_interleave(mesh["coordinates"], mesh.get("delta"), f"meshes[{index}].coordinates"))
            if (mesh.get("tangents") is not None) != with_tangents:
                raise SkinkitError(f"meshes[{index}].tangents: give tangents for every mesh or for none")
            if with_tangents:
                deltas = mesh.get("tangent_deltas") or (None, None)
                tangents.append(np.concatenate([_interleave(t, d, f"meshes[{index}].tangents[{s}]")
                                                for s, (t, d) in enumerate(zip(mesh["tangents"], deltas))], axis=1))
            starts.append(starts[-1] + len(mesh_offsets) - 1)
        eps = None if epsilons is None else as_real_array(epsilons, "epsilons", np.float32)
        if eps is not None and eps.shape != (len(meshes),):
            raise SkinkitError(f"epsilons: expected one per mesh ({len(meshes)}), got shape {eps.shape}")
        return cls(np.ascontiguousarray(np.concatenate(offsets), np.int32), np.concatenate(bones).astype(np.int32),
                   np.ascontiguousarray(np.concatenate(positions)),
                   np.ascontiguousarray(np.concatenate(tangents)) if with_tangents else None,
                   np.asarray(starts, np.int32), int(bone_count), eps)

    @classmethod
    @checked(model=AnimationSpaceModel, tangents=optional(tangent_pair))
    def from_model(cls, model: AnimationSpaceModel, tangents=None) -> "RuntimePack":
        """One mesh that does not morph: the model's coordinates with dp = 0 (tangents: two (n, 4) arrays)."""
        return cls.from_meshes([{"offsets": model.offsets, "bones": model.bones, "coordinates": model.coordinates,
                                 "tangents": tangents}], model.bone_count, [0.0])

    @classmethod
    def from_chain(cls, chain) -> "RuntimePack":
        from .lod import LodChain

        if not isinstance(chain, LodChain):
            raise SkinkitError(f"chain: expected a skinkit.lod.LodChain, got {type(chain).__name__}")
        """One mesh per level of a skinkit.lod.LodChain: level l's geomorph data on the common influence sets
        (p^l and p^{l+1}(mapped) - p^l, eq. 7.1), the coarsest level with dp = 0; epsilons from the chain."""
        meshes = []
        for level in chain.levels:
            if level.morph_model is None:
                model, delta = level.model, None
            else:
                model, delta = level.morph_model, level.morph_delta
            meshes.append({"offsets": model.offsets, "bones": model.bones, "coordinates": model.coordinates,
                           "delta": delta})
        return cls.from_meshes(meshes, chain.levels[0].model.bone_count, [lv.epsilon for lv in chain.levels])

    def level_epsilons(self) -> np.ndarray:
        return _level_epsilons(self)

    @checked(tangents=FLAG, threads=THREADS)
    def draw(self, levels, poses, *, tangents: bool = False, kernel: str = "auto", threads: int = 0) -> "SkinResult":
        """Skins one instance per entry of levels (real, in [0, mesh_count - 1]) of this chain, each with its
        poses (I, B, 4, 4) (or one (B, 4, 4) for all): mesh floor(l) at fraction l - floor(l)."""
        return _draw(self, levels, poses, tangents, kernel, threads)

    def fixed_layout_problem(self) -> str | None:
        """Why the fixed-K layout (fixed()) cannot hold this pack, or None when it can: more bones than 16-bit
        indices reach, or a vertex with more influences than the layout's slots (K rounded up to even)."""
        if self.bone_count > MAX_FIXED_BONES:
            return f"the fixed layout holds at most {MAX_FIXED_BONES} bones, this pack has {self.bone_count}"
        most = int(np.diff(self.offsets).max(initial=0))
        if most + most % 2 > MAX_FIXED_SLOTS:
            return f"a vertex has {most} influences, the fixed layout holds at most {MAX_FIXED_SLOTS}"
        return None

    @checked(morphs=optional(FLAG))
    def fixed(self, morphs: bool | None = None) -> "FixedPack":
        """The same meshes in the fixed-K layout (FixedPack): every vertex padded to K slots (the most influences
        of any vertex, rounded up to even; padding is bone 0 with zero coordinates), 16-bit bones, no offsets.
        morphs False drops dp (a pack that no longer geomorphs, read as animation-space evaluation reads its
        coordinates); None keeps it when any dp is non-zero."""
        problem = self.fixed_layout_problem()
        if problem is not None:
            raise SkinkitError(f"pack: {problem}")
        counts = np.diff(self.offsets)
        slots = max(2, int(counts.max(initial=0)) + int(counts.max(initial=0)) % 2)
        if morphs is None:
            morphs = bool(self.positions[:, 4:].any() or (self.tangents is not None and (
                self.tangents[:, 4:8].any() or self.tangents[:, 12:].any())))
        floats = 8 if morphs else 4
        vertices = len(counts)
        slot = np.arange(len(self.bones)) - np.repeat(self.offsets[:-1], counts)
        vertex = np.repeat(np.arange(vertices), counts)
        bones = np.zeros(vertices * slots, np.uint16)
        bones[vertex * slots + slot] = self.bones
        # first float of each influence's p: vertex block, then its pair of slots, then its half of the pair
        start = vertex * slots * floats + (slot // 2) * 2 * floats + (slot % 2) * 4

        def laid_out(morph: np.ndarray) -> np.ndarray:
            data = np.zeros(vertices * slots * floats, np.float32)
            data[start[:, None] + np.arange(4)] = morph[:, :4]
            if morphs:
                data[start[:, None] + 8 + np.arange(4)] = morph[:, 4:]
            return data

        tangents = None if self.tangents is None else (laid_out(self.tangents[:, :8]), laid_out(self.tangents[:, 8:]))
        return FixedPack(bones, laid_out(self.positions), tangents, self.mesh_starts, self.bone_count, slots, floats,
                         self.epsilons)


@dataclass(frozen=True, eq=False)
class FixedPack(_MeshRanges):
    """A RuntimePack's meshes in the fixed-K layout the runtime skins fastest (sk_runtime_fixed_pack, build it
    with RuntimePack.fixed): K = influences_per_vertex slots per vertex, 16-bit bones (V * K,), and per pair of
    slots (p, p, dp, dp) (floats_per_slot 8) or (p, p) (4: no geomorph data, every fraction must be 0)."""
    bones: np.ndarray                                  # (V * K,) uint16
    positions: np.ndarray                              # (V * K * floats_per_slot,) float32
    tangents: tuple[np.ndarray, np.ndarray] | None     # each as positions
    mesh_starts: np.ndarray                            # (M + 1,) int32
    bone_count: int
    influences_per_vertex: int
    floats_per_slot: int
    epsilons: np.ndarray | None = None

    @property
    def morphs(self) -> bool:
        return self.floats_per_slot == 8

    def level_epsilons(self) -> np.ndarray:
        return _level_epsilons(self)

    @checked(tangents=FLAG, threads=THREADS)
    def draw(self, levels, poses, *, tangents: bool = False, kernel: str = "auto", threads: int = 0) -> "SkinResult":
        """As RuntimePack.draw (a pack that does not morph takes whole levels only)."""
        return _draw(self, levels, poses, tangents, kernel, threads)


def _level_epsilons(pack) -> np.ndarray:
    if pack.epsilons is None:
        raise SkinkitError("this pack has no epsilons: build it with RuntimePack.from_chain")
    return pack.epsilons


def _draw(pack, levels, poses, tangents: bool, kernel: str, threads: int) -> "SkinResult":
    levels = as_real_array(levels, "levels", shape=(None,))
    last = pack.mesh_count - 1
    if ((levels < 0) | (levels > last)).any():
        raise SkinkitError(f"levels: every level must be in [0, {last}]")
    meshes = np.floor(levels).astype(np.int32)
    fractions = levels - meshes  # 0 on the last level: it does not morph
    poses = as_array(poses, "poses")
    if poses.ndim == 3:
        poses = np.broadcast_to(poses, (len(levels), *poses.shape))
    return skin(pack, meshes, fractions, poses, tangents=tangents, kernel=kernel, threads=threads)


@dataclass(frozen=True)
class SkinResult:
    """Skinned vertices of every instance, back to back: instance i owns rows output_starts[i] .. [i + 1] - 1."""
    positions: np.ndarray               # (V, 3) float32
    tangents: tuple[np.ndarray, np.ndarray] | None
    output_starts: np.ndarray           # (I + 1,) int32

    @checked(index=count())
    def instance(self, index: int) -> np.ndarray:
        if index >= len(self.output_starts) - 1:
            raise SkinkitError(f"index: {index} is past the last of {len(self.output_starts) - 1} instances")
        return self.positions[self.output_starts[index]:self.output_starts[index + 1]]


def runtime_pack(value, name: str):
    if not isinstance(value, (RuntimePack, FixedPack)):
        raise SkinkitError(f"{name}: expected a RuntimePack or a FixedPack, got {type(value).__name__}")
    return value


@checked(pack=runtime_pack, tangents=FLAG, threads=THREADS)
def skin(pack, meshes, fractions, poses, *, tangents: bool = False, kernel: str = "auto",
         threads: int = 0, out: np.ndarray | None = None) -> SkinResult:
    """Batched geomorphing skinning (CPU algorithm 1): instance i draws mesh meshes[i] (I,) at geomorph fraction
    fractions[i] in [0, 1] with bone frames poses[i] (I, B, 4, 4) (or 3x4 matrices (I, B, 12)), positions and,
    with tangents=True, both tangents. pack: a RuntimePack (CSR) or a FixedPack (the same results, fewer bytes;
    without dp every fraction must be 0). kernel: "auto", "scalar", "sse2" or "avx2"; threads 0: every processor.
    out: a float32 C-contiguous (N, 3) array with N >= the instances' vertices, reused for the positions (a frame
    loop then allocates nothing; the result's positions are a view of its first rows)."""
    meshes = as_index_array(meshes, "meshes", (None,))
    count = len(meshes)
    fractions = _f32(fractions, "fractions", (count,))
    poses = as_array(poses, "poses")
    matrices = bone_matrices(poses) if poses.shape[-2:] == (4, 4) else _f32(poses, "poses")
    if matrices.shape != (count, pack.bone_count, 12):
        raise SkinkitError(f"poses: expected ({count}, {pack.bone_count}, 4, 4) or ({count}, {pack.bone_count}, 12), "
                           f"got shape {poses.shape}")
    if tangents and pack.tangents is None:
        raise SkinkitError("tangents: this pack has no tangent data")
    if ((meshes < 0) | (meshes >= pack.mesh_count)).any():
        raise SkinkitError(f"meshes: every mesh must be in [0, {pack.mesh_count})")
    output_starts = np.zeros(count + 1, np.int32)
    np.cumsum(pack.vertex_counts[meshes], out=output_starts[1:])
    total = int(output_starts[-1])
    if out is None:
        positions = np.empty((total, 3), np.float32)
    elif not (isinstance(out, np.ndarray) and out.dtype == np.float32 and out.ndim == 2 and out.shape[1] == 3 and
              out.flags.c_contiguous and out.flags.writeable and len(out) >= total):
        raise SkinkitError(f"out: expected a writable C-contiguous float32 array of at least ({total}, 3)")
    else:
        positions = out[:total]
    tangent_out = (np.empty((total, 3), np.float32), np.empty((total, 3), np.float32)) if tangents else (None, None)
    outputs = (positions.reshape(-1), *(None if t is None else t.reshape(-1) for t in tangent_out))
    if isinstance(pack, FixedPack):
        if not pack.morphs and fractions.any():
            raise SkinkitError("fractions: this FixedPack has no geomorph data (floats_per_slot 4): every fraction "
                               "must be 0")
        _core.runtime_skin_fixed(*outputs, pack.bones, pack.positions,
                                 *((None, None) if pack.tangents is None else pack.tangents), pack.mesh_starts,
                                 int(pack.mesh_starts[-1]), pack.influences_per_vertex, pack.floats_per_slot, meshes,
                                 fractions, pack.bone_count, np.ascontiguousarray(matrices).reshape(-1), output_starts,
                                 _kernel_value(kernel), int(threads))
        return SkinResult(positions, tangent_out if tangents else None, output_starts)
    _core.runtime_skin(*outputs, pack.offsets, pack.bones, pack.positions.reshape(-1),
                       None if pack.tangents is None else pack.tangents.reshape(-1), pack.mesh_starts, meshes,
                       fractions, pack.bone_count, np.ascontiguousarray(matrices).reshape(-1), output_starts,
                       _kernel_value(kernel), int(threads))
    return SkinResult(positions, tangent_out if tangents else None, output_starts)
