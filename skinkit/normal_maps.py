"""Tangent-space normal maps and tangent maps (Merry 2007, section 7.5): MikkTSpace tangents, bakes and tangent maps
in the C core, images written and read with OpenImageIO.

numpy in, numpy out. A surface is a triangle list with a normal and a uv per corner (Blender's split normals and
UV map). Images are (size, size, 3) float32 in 0-1 (0.5 n + 0.5), row 0 at the top (v = 1), as image files store
them.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass

import numpy as np

from . import _core
from ._checks import (CALLBACK, PATH, THREADS, as_array, as_index_array, as_real_array, check_memory, checked,
                      choice, count, optional, real)
from .model import SkinkitError

__all__ = ["BakeSurface", "NormalMap", "MODES", "CORRESPONDENCES", "FORMATS", "mikktspace_tangents", "bake_normals",
           "angular_error", "quantize", "write_image", "read_image", "TangentMap", "bake_tangent_map",
           "write_tangent_map"]

MODES = {"atlas": 0, "ray": 1, "guided": 2}
GUIDE_DEGREES = 10.0  # SK_BAKE_GUIDE_DEGREES
#: How a LOD chain's level finds its LOD0 point (the mode of its bake), the first the default: on the benchmark's
#: chains the guided map renders with 0.18 / 0.44 / 0.54 of the error without a map (arm, horse, creature) where the
#: atlas map renders with 0.23 / 0.51 / 0.55 (BENCHMARKS.md, session 16).
CORRESPONDENCES = ("guided", "atlas")
# Written formats: their OpenImageIO pixel type, file extension and the numpy type of what is stored.
FORMATS = {"png8": ("uint8", ".png", np.uint8), "png16": ("uint16", ".png", np.uint16),
           "exr": ("half", ".exr", np.float16), "exr-float": ("float", ".exr", np.float32)}
DEFAULT_CAGE_FRACTION = 0.05  # of the target's bounding-box diagonal, when a ray-cast bake gives no cage
#: The largest image side a bake takes (its memory is checked against the budget before it is allocated), the
#: widest margin, the most samples per texel side, the largest tile and the most influences a texel keeps.
MAX_SIZE = 16384
MAX_MARGIN = 4096
MAX_SUPERSAMPLE = 16
MAX_TILE = 4096
MAX_TEXEL_INFLUENCES = 256
COVERAGE = {"empty": 0, "filled": 1, "missed": 2, "dilated": 3}


@dataclass(frozen=True)
class BakeSurface:
    """triangles (T, 3) int32, positions (V, 3), normals (T, 3, 3) per corner, uv (T, 3, 2) per corner or None."""
    triangles: np.ndarray
    positions: np.ndarray
    normals: np.ndarray
    uv: np.ndarray | None

    @classmethod
    def from_arrays(cls, triangles, positions, uv=None, normals=None, name: str = "surface") -> "BakeSurface":
        """Checked arrays; normals None: smooth area-weighted vertex normals at every corner."""
        triangles = as_index_array(triangles, f"{name} triangles", (None, 3))
        positions = as_real_array(positions, f"{name} positions", shape=(None, 3))
        if triangles.size and (triangles.min() < 0 or triangles.max() >= len(positions)):
            raise SkinkitError(f"{name} triangles: an index is outside 0-{len(positions) - 1}")
        if normals is None:
            normals = smooth_corner_normals(triangles, positions)
        normals = as_real_array(normals, f"{name} normals", shape=(len(triangles), 3, 3))
        if uv is not None:
            uv = as_real_array(uv, f"{name} uv", shape=(len(triangles), 3, 2))
        return cls(triangles, positions, normals, uv)


def smooth_corner_normals(triangles: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Each corner's vertex normal: the normalised sum of its faces' area-weighted normals."""
    corners = positions[triangles]
    face = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    vertex = np.zeros_like(positions)
    for k in range(3):
        np.add.at(vertex, triangles[:, k], face)
    length = np.linalg.norm(vertex, axis=1, keepdims=True)
    vertex = np.divide(vertex, length, out=np.zeros_like(vertex), where=length > 0)
    return vertex[triangles]


@checked(surface=BakeSurface)
def mikktspace_tangents(surface: BakeSurface) -> np.ndarray:
    """(T, 3, 4): each corner's MikkTSpace tangent (x, y, z) and bitangent sign, as Blender's calc_tangents."""
    if surface.uv is None:
        raise SkinkitError("surface: tangents need uv coordinates (unwrap the mesh first)")
    tangents = np.empty((len(surface.triangles), 3, 4))
    _core.mikktspace_tangents(tangents, surface.triangles, surface.positions, surface.normals, surface.uv)
    return tangents


@dataclass
class NormalMap:
    """A bake: image (size, size, 3) float32 encoded 0.5 n + 0.5; coverage (size, size) uint8 (COVERAGE); exact
    (size, size, 3) the object-space source normal at each texel centre; frames (size, size, 3, 3) the target's
    interpolated tangent and normal there, unnormalised as the Normal Map node decodes, and bitangent sign N x T
    (both None for a bake without diagnostics); the texel counts and the seconds the core took."""
    image: np.ndarray
    coverage: np.ndarray
    exact: np.ndarray | None
    frames: np.ndarray | None
    filled: int
    missed: int
    dilated: int
    empty: int
    seconds: float

    @checked(image=optional(lambda value, name: as_real_array(value, name)))
    def angular_error(self, image: np.ndarray | None = None) -> tuple[float, float]:
        """(mean, max) degrees between `image` (default this bake) decoded in the target's frames and the exact
        source normals, over the filled texels."""
        if self.exact is None or self.frames is None:
            raise SkinkitError("this bake kept no exact normals (bake with diagnostics=True)")
        return angular_error(self.image if image is None else image, self.frames, self.exact,
                             self.coverage == COVERAGE["filled"])


@checked(target=BakeSurface, source=BakeSurface, size=count(1, MAX_SIZE), mode=choice(MODES),
         supersample=count(1, MAX_SUPERSAMPLE), margin=count(0, MAX_MARGIN), cage=optional(real(above=0)),
         thread_count=THREADS, progress=CALLBACK)
def bake_normals(target: BakeSurface, source: BakeSurface, size: int = 1024, mode: str = "atlas",
                 supersample: int = 2, margin: int = 8, cage: float | None = None, tangents: np.ndarray | None = None,
                 thread_count: int = 0, progress=None, diagnostics: bool = True) -> NormalMap:
    """Bakes the source's normals into the target's tangent space. mode "atlas": the same uv point on the source
    (a LOD chain's shared atlas; the source needs uv); "ray": the nearest source hit along the target's normal
    within +-cage (default 5% of the target's diagonal), or where that ray misses, the closest source point within the
    cage; "guided" (a LOD chain's best; the source needs uv): the ray's normal where it is within GUIDE_DEGREES of
    the same uv point's, else the same uv point's. progress(fraction) returning True cancels. diagnostics False:
    exact and frames (96 bytes a texel, for the angular error) are neither computed nor stored (None); the image is
    the same."""
    if mode not in MODES:
        raise SkinkitError(f"mode: {mode!r} is not one of {', '.join(MODES)}")
    if target.uv is None:
        raise SkinkitError("target: no uv coordinates (unwrap it, or build the LOD chain, first)")
    if mode != "ray" and source.uv is None:
        raise SkinkitError(f"source: a {mode} bake needs the source's uv (the shared atlas); use mode='ray'")
    if cage is None:
        cage = DEFAULT_CAGE_FRACTION * float(np.linalg.norm(np.ptp(target.positions, axis=0)))
    if mode != "atlas" and not cage > 0:
        raise SkinkitError(f"cage: {cage} must be positive")
    if tangents is None:
        tangents = mikktspace_tangents(target)
    tangents = as_real_array(tangents, "tangents", shape=(len(target.triangles), 3, 4))
    diagnostics = bool(diagnostics)
    check_memory(size * size * (4 * 3 + 1 + (8 * 3 + 8 * 9) * diagnostics), f"a {size} x {size} bake",
                 "bake a smaller size (and upscale), or free memory")
    image = np.empty((size, size, 3), np.float32)
    coverage = np.empty((size, size), np.uint8)
    exact = np.empty((size, size, 3)) if diagnostics else None
    frames = np.empty((size, size, 3, 3)) if diagnostics else None
    started = time.perf_counter()
    report = _core.bake_normals(image, coverage, exact, frames, target.triangles, target.positions, target.normals,
                                target.uv, tangents, source.triangles, source.positions, source.normals, source.uv,
                                size, MODES[mode], int(supersample), int(margin), float(cage if mode != "atlas" else 0),
                                int(thread_count), progress)
    return NormalMap(image, coverage, exact, frames, report["filled"], report["missed"], report["dilated"],
                     report["empty"], time.perf_counter() - started)


def angular_error(image: np.ndarray, frames: np.ndarray, exact: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """(mean, max) degrees between the encoded tangent-space normals of `image` decoded in `frames` (T, B, N per
    texel, as the Normal Map node: normalize(x T + y B + z N)) and the object-space normals `exact`, over `mask`."""
    image = as_real_array(image, "image", shape=(None, None, 3))
    height, width = image.shape[:2]
    frames = as_real_array(frames, "frames", shape=(height, width, 3, 3))
    exact = as_real_array(exact, "exact", shape=(height, width, 3))
    mask = as_array(mask, "mask")
    if mask.dtype != bool or mask.shape != (height, width):
        raise SkinkitError(f"mask: expected ({height}, {width}) True/False flags, got dtype {mask.dtype} shape "
                           f"{mask.shape}")
    if not mask.any():
        return 0.0, 0.0
    decoded = 2.0 * np.asarray(image, np.float64)[mask] - 1.0
    world = np.einsum("nk,nkj->nj", decoded, frames[mask])
    world /= np.maximum(np.linalg.norm(world, axis=1, keepdims=True), 1e-300)
    cosine = np.clip(np.einsum("nj,nj->n", world, exact[mask]), -1.0, 1.0)
    degrees = np.degrees(np.arccos(cosine))
    return float(degrees.mean()), float(degrees.max())


@checked(format=choice(FORMATS))
def quantize(image: np.ndarray, format: str) -> np.ndarray:  # noqa: A002 - the CLI's word
    """The values `format` stores for a 0-1 image: rounded integers for PNG, half or single floats for EXR."""
    if format not in FORMATS:
        raise SkinkitError(f"format: {format!r} is not one of {', '.join(FORMATS)}")
    stored = FORMATS[format][2]
    clipped = np.clip(as_real_array(image, "image"), 0.0, 1.0)
    if np.issubdtype(stored, np.integer):
        return np.rint(clipped * np.iinfo(stored).max).astype(stored)
    return clipped.astype(stored)


@checked(path=PATH, format=choice(FORMATS))
def write_image(path: str, image: np.ndarray, format: str = "png16") -> str:  # noqa: A002
    """Writes the 0-1 image (rows from the top) as `format`, marked non-colour (raw) data, under a temporary name
    renamed onto `path` once complete; returns the absolute path."""
    import OpenImageIO as oiio

    pixels = quantize(as_real_array(image, "image"), format)
    if pixels.ndim not in (2, 3) or 0 in pixels.shape or (pixels.ndim == 3 and pixels.shape[2] > 4):
        raise SkinkitError(f"image: expected (height, width) or (height, width, 1-4 channels), got {pixels.shape}")
    writable_folder(path)
    height, width = pixels.shape[:2]
    channels = pixels.shape[2] if pixels.ndim == 3 else 1
    spec = oiio.ImageSpec(width, height, channels, getattr(oiio, FORMATS[format][0].upper()))
    spec.attribute("oiio:ColorSpace", "Raw")
    if format.startswith("exr"):
        spec.attribute("compression", "zip")
    return write_whole(oiio, path, spec, pixels)


def writable_folder(path: str) -> str:
    """path's folder, checked before any work to write there is done."""
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
        raise SkinkitError(f"{path}: the folder {folder} does not exist or is not writable")
    return folder


def write_whole(oiio, path: str, spec, pixels: np.ndarray) -> str:
    """Writes pixels under a temporary name in path's folder and renames it onto path once complete, so no
    half-written image is ever left there; returns the absolute path."""
    stem, extension = os.path.splitext(os.path.basename(path))
    temporary = os.path.join(writable_folder(path), f".{stem}.partial-{os.getpid()}{extension}")
    output = oiio.ImageOutput.create(temporary)
    try:
        if output is None or not output.open(temporary, spec):
            raise SkinkitError(f"{path}: cannot write ({oiio.geterror() or (output and output.geterror())})")
        if not output.write_image(pixels):
            raise SkinkitError(f"{path}: writing failed ({output.geterror()})")
        output.close()
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)
    return os.path.abspath(path)


@checked(path=PATH)
def read_image(path: str) -> np.ndarray:
    """An image's stored values (uint8/uint16 for PNG, float16/float32 for EXR), (height, width, channels)."""
    import OpenImageIO as oiio

    image_input = oiio.ImageInput.open(path)
    if image_input is None:
        raise SkinkitError(f"{path}: cannot read ({oiio.geterror()})")
    try:
        pixels = image_input.read_image(image_input.spec().format)
    finally:
        image_input.close()
    return np.asarray(pixels)


# ---- tangent maps (section 7.5) ------------------------------------------------------------------------------------

DEFAULT_TILE = 8  # texels per tile side: the thesis found 8 x 8 always within 10% of the best
DEFAULT_MAX_TEXEL_INFLUENCES = 16


@dataclass
class TangentMap:
    """Per texel of a size x size map: counts (size, size) bones, bones (size, size, K) and tangents
    (size, size, K, 2, 4) the pair (dp/du, dp/dv) of animation-space 4-vectors per bone (slots past the count are
    bone 0 and zero), source_triangles (size, size) (-1 where empty), coverage as a bake's; tile the side of the
    tiles that share one influence count."""
    counts: np.ndarray
    bones: np.ndarray
    tangents: np.ndarray
    source_triangles: np.ndarray
    coverage: np.ndarray
    tile: int

    def tile_counts(self) -> np.ndarray:
        """(tiles, tiles): each tile's common influence count, the largest of its texels'."""
        size, tile = self.counts.shape[0], self.tile
        tiles = -(-size // tile)
        padded = np.zeros((tiles * tile, tiles * tile), np.int32)
        padded[:size, :size] = self.counts
        return padded.reshape(tiles, tile, tiles, tile).max(axis=(1, 3))

    def padded_counts(self) -> np.ndarray:
        """(size, size): every texel's count raised to its tile's (the extra slots are zero: they add nothing)."""
        size = self.counts.shape[0]
        return np.repeat(np.repeat(self.tile_counts(), self.tile, 0), self.tile, 1)[:size, :size].astype(np.int32)

    @checked(thread_count=THREADS)
    def normal_map(self, poses, thread_count: int = 0) -> np.ndarray:
        """(size, size, 3) float32: the object-space normal normalize(G t1 x G t2) per texel in the pose (b, 4, 4),
        encoded 0.5 n + 0.5 (0.5 grey where empty), through the tiles' padded counts."""
        poses = as_real_array(poses, "poses", shape=(None, 4, 4))
        size, slots = self.bones.shape[0], self.bones.shape[2]
        image = np.empty((size, size, 3), np.float32)
        _core.tangent_map_normals(image, self.padded_counts(), self.bones, self.tangents, poses, slots,
                                  int(thread_count))
        return image

    @checked(thread_count=THREADS)
    def downsample(self, statistics=None, thread_count: int = 0) -> "TangentMap":
        """The next level of the mip chain (half the size, the same tile): each texel the A.1 bivector fit of its
        2x2 block's tangent pairs (the block's mean pair projected onto the fitted plane), on the block's bones; in
        the L2,2 metric of `statistics` (a PoseStatistics of the model's skeleton, A.1.2), else Euclidean."""
        size, slots = self.bones.shape[0], self.bones.shape[2]
        if size < 2 or size % 2:
            raise SkinkitError(f"a tangent map of size {size} cannot be halved (it must be even)")
        metric, bone_count = metric_blocks(statistics)
        half = size // 2
        counts = np.empty((half, half), np.int32)
        bones = np.empty((half, half, slots), np.int32)
        tangents = np.empty((half, half, slots, 2, 4))
        _core.tangent_map_downsample(counts, bones, tangents, self.counts, self.bones, self.tangents, metric, half,
                                     size, slots, bone_count, int(thread_count))
        coverage = np.where(counts > 0, COVERAGE["filled"], COVERAGE["empty"]).astype(np.uint8)
        # Each coarse texel's source triangle: the first filled child's (for reference; the tangents are averaged).
        children = self.source_triangles.reshape(half, 2, half, 2).transpose(0, 2, 1, 3).reshape(half, half, 4)
        first = np.argmax(children >= 0, axis=2)
        source_triangles = np.where(counts > 0, np.take_along_axis(children, first[..., None], 2)[..., 0], -1)
        return TangentMap(counts, bones, tangents, source_triangles.astype(np.int32), coverage, self.tile)

    @checked(levels=optional(count(1)), thread_count=THREADS)
    def mip_chain(self, levels: int | None = None, statistics=None, thread_count: int = 0) -> list["TangentMap"]:
        """This map and its halvings (downsample, in the metric of `statistics` when given), down to 1 texel or
        `levels` maps in all."""
        chain = [self]
        while chain[-1].bones.shape[0] > 1 and chain[-1].bones.shape[0] % 2 == 0 and \
                (levels is None or len(chain) < levels):
            chain.append(chain[-1].downsample(statistics, thread_count))
        return chain


def metric_blocks(statistics) -> tuple[np.ndarray | None, int]:
    """P's 4x4 blocks over the skeleton of `statistics` (a PoseStatistics, or None: no metric) and the bone count."""
    from .metrics import PoseStatistics

    if statistics is None:
        return None, 0
    if not isinstance(statistics, PoseStatistics):
        raise SkinkitError(f"statistics: expected a PoseStatistics or None, not {type(statistics).__name__}")
    bone_count = statistics.bone_count
    check_memory(bone_count * bone_count * 16 * 8, f"the metric of {bone_count} bones", "use fewer bones")
    blocks = np.empty(bone_count * bone_count * 16)
    _core.expectation_blocks(blocks, statistics.expected_local.reshape(-1), statistics.expected_gram.reshape(-1),
                             statistics.parents)
    return blocks, bone_count


@checked(target=BakeSurface, source=BakeSurface, size=count(1, MAX_SIZE), tile=count(1, MAX_TILE),
         max_influences=count(1, MAX_TEXEL_INFLUENCES), thread_count=THREADS, progress=CALLBACK)
def bake_tangent_map(target: BakeSurface, source: BakeSurface, model, size: int = 256,
                     tile: int = DEFAULT_TILE, max_influences: int = DEFAULT_MAX_TEXEL_INFLUENCES,
                     thread_count: int = 0, progress=None) -> TangentMap:
    """The tangent map of the target's uv layout from the source's animation-space model (an AnimationSpaceModel
    over the source's vertices) through the shared atlas. progress(fraction), called between batches of rows,
    returning True cancels (SkinkitError)."""
    from .model import AnimationSpaceModel

    if not isinstance(model, AnimationSpaceModel):
        raise SkinkitError("model: expected an AnimationSpaceModel")
    if target.uv is None or source.uv is None:
        raise SkinkitError("target and source need uv coordinates (the shared atlas)")
    if model.vertex_count != len(source.positions):
        raise SkinkitError(f"model: has {model.vertex_count} vertices, the source {len(source.positions)}")
    if int(tile) < 1:
        raise SkinkitError(f"tile: {tile} must be at least 1")
    size, slots = int(size), int(max_influences)
    check_memory(size * size * (4 + 1 + 4 + slots * (4 + 64)), f"a {size} x {size} tangent map",
                 "bake a smaller size or fewer max_influences, or free memory")
    counts = np.empty((size, size), np.int32)
    bones = np.empty((size, size, slots), np.int32)
    tangents = np.empty((size, size, slots, 2, 4))
    source_triangles = np.empty((size, size), np.int32)
    coverage = np.empty((size, size), np.uint8)
    _core.bake_tangent_map(counts, bones, tangents, source_triangles, coverage, target.triangles, target.positions,
                           target.normals, target.uv, source.triangles, source.positions, source.normals, source.uv,
                           model.offsets, model.bones, model.coordinates, size, slots, int(thread_count), progress)
    return TangentMap(counts, bones, tangents, source_triangles, coverage, int(tile))


@checked(path=PATH, tangent_map=TangentMap)
def write_tangent_map(path: str, tangent_map: TangentMap, format: str = "exr-float") -> str:  # noqa: A002
    """One multi-channel EXR of the tiles' influences: for slot k below the largest tile count, channels
    bone<k> (the bone index, exact in float up to 2^24) and t1_<k>.XYZW, t2_<k>.XYZW; the tile side and each tile's
    count in the attributes skinkit:tile and skinkit:tile_counts. Returns the absolute path."""
    import OpenImageIO as oiio

    if not isinstance(format, str) or format not in ("exr", "exr-float"):  # an array compares elementwise
        raise SkinkitError(f"format: a tangent map is an EXR ('exr' half or 'exr-float'), not {format!r}")
    slots = max(int(tangent_map.tile_counts().max(initial=0)), 1)
    size = tangent_map.counts.shape[0]
    names, planes = [], []
    for k in range(slots):
        names.append(f"bone{k}")
        planes.append(tangent_map.bones[:, :, k].astype(np.float32))
        for which, label in ((0, "t1"), (1, "t2")):
            for d, axis in enumerate("XYZW"):
                names.append(f"{label}_{k}.{axis}")
                planes.append(tangent_map.tangents[:, :, k, which, d].astype(np.float32))
    pixels = np.stack(planes, axis=-1)
    writable_folder(path)
    spec = oiio.ImageSpec(size, size, len(names), oiio.HALF if format == "exr" else oiio.FLOAT)
    spec.channelnames = tuple(names)
    spec.attribute("compression", "zip")
    spec.attribute("skinkit:tile", int(tangent_map.tile))
    spec.attribute("skinkit:tile_counts", " ".join(str(int(c)) for c in tangent_map.tile_counts().reshape(-1)))
    if format == "exr":
        pixels = pixels.astype(np.float16)
    return write_whole(oiio, path, spec, pixels)
