"""Tangent-space normal maps (Merry 2007, section 7.5): MikkTSpace tangents and bakes in the C core, images written
and read with OpenImageIO.

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
from ._checks import as_index_array, as_real_array
from .model import SkinkitError

__all__ = ["BakeSurface", "NormalMap", "MODES", "FORMATS", "mikktspace_tangents", "bake_normals", "angular_error",
           "quantize", "write_image", "read_image"]

MODES = {"atlas": 0, "ray": 1}
# Written formats: their OpenImageIO pixel type, file extension and the numpy type of what is stored.
FORMATS = {"png8": ("uint8", ".png", np.uint8), "png16": ("uint16", ".png", np.uint16),
           "exr": ("half", ".exr", np.float16), "exr-float": ("float", ".exr", np.float32)}
DEFAULT_CAGE_FRACTION = 0.05  # of the target's bounding-box diagonal, when a ray-cast bake gives no cage
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
    tangent, bitangent and normal there; the texel counts and the seconds the core took."""
    image: np.ndarray
    coverage: np.ndarray
    exact: np.ndarray
    frames: np.ndarray
    filled: int
    missed: int
    dilated: int
    empty: int
    seconds: float

    def angular_error(self, image: np.ndarray | None = None) -> tuple[float, float]:
        """(mean, max) degrees between `image` (default this bake) decoded in the target's frames and the exact
        source normals, over the filled texels."""
        return angular_error(self.image if image is None else image, self.frames, self.exact,
                             self.coverage == COVERAGE["filled"])


def bake_normals(target: BakeSurface, source: BakeSurface, size: int = 1024, mode: str = "atlas",
                 supersample: int = 2, margin: int = 8, cage: float | None = None, tangents: np.ndarray | None = None,
                 thread_count: int = 0, progress=None) -> NormalMap:
    """Bakes the source's normals into the target's tangent space. mode "atlas": the same uv point on the source
    (a LOD chain's shared atlas; the source needs uv); "ray": the nearest source hit along the target's normal
    within +-cage (default 5% of the target's diagonal). progress(fraction) returning True cancels."""
    if mode not in MODES:
        raise SkinkitError(f"mode: {mode!r} is not one of {', '.join(MODES)}")
    if target.uv is None:
        raise SkinkitError("target: no uv coordinates (unwrap it, or build the LOD chain, first)")
    if mode == "atlas" and source.uv is None:
        raise SkinkitError("source: an atlas bake needs the source's uv (the shared atlas); use mode='ray'")
    if cage is None:
        cage = DEFAULT_CAGE_FRACTION * float(np.linalg.norm(np.ptp(target.positions, axis=0)))
    if mode == "ray" and not cage > 0:
        raise SkinkitError(f"cage: {cage} must be positive")
    if tangents is None:
        tangents = mikktspace_tangents(target)
    tangents = as_real_array(tangents, "tangents", shape=(len(target.triangles), 3, 4))
    size = int(size)
    image = np.empty((size, size, 3), np.float32)
    coverage = np.empty((size, size), np.uint8)
    exact = np.empty((size, size, 3))
    frames = np.empty((size, size, 3, 3))
    started = time.perf_counter()
    report = _core.bake_normals(image, coverage, exact, frames, target.triangles, target.positions, target.normals,
                                target.uv, tangents, source.triangles, source.positions, source.normals, source.uv,
                                size, MODES[mode], int(supersample), int(margin), float(cage if mode == "ray" else 0),
                                int(thread_count), progress)
    return NormalMap(image, coverage, exact, frames, report["filled"], report["missed"], report["dilated"],
                     report["empty"], time.perf_counter() - started)


def angular_error(image: np.ndarray, frames: np.ndarray, exact: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """(mean, max) degrees between the encoded tangent-space normals of `image` decoded in `frames` (T, B, N per
    texel, as the Normal Map node: normalize(x T + y B + z N)) and the object-space normals `exact`, over `mask`."""
    if not mask.any():
        return 0.0, 0.0
    decoded = 2.0 * np.asarray(image, np.float64)[mask] - 1.0
    world = np.einsum("nk,nkj->nj", decoded, frames[mask])
    world /= np.maximum(np.linalg.norm(world, axis=1, keepdims=True), 1e-300)
    cosine = np.clip(np.einsum("nj,nj->n", world, exact[mask]), -1.0, 1.0)
    degrees = np.degrees(np.arccos(cosine))
    return float(degrees.mean()), float(degrees.max())


def quantize(image: np.ndarray, format: str) -> np.ndarray:  # noqa: A002 - the CLI's word
    """The values `format` stores for a 0-1 image: rounded integers for PNG, half or single floats for EXR."""
    if format not in FORMATS:
        raise SkinkitError(f"format: {format!r} is not one of {', '.join(FORMATS)}")
    stored = FORMATS[format][2]
    clipped = np.clip(np.asarray(image, np.float64), 0.0, 1.0)
    if np.issubdtype(stored, np.integer):
        return np.rint(clipped * np.iinfo(stored).max).astype(stored)
    return clipped.astype(stored)


def write_image(path: str, image: np.ndarray, format: str = "png16") -> str:  # noqa: A002
    """Writes the 0-1 image (rows from the top) as `format`, marked non-colour (raw) data, under a temporary name
    renamed onto `path` once complete; returns the absolute path."""
    import OpenImageIO as oiio

    pixels = quantize(image, format)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
        raise SkinkitError(f"{path}: the folder {folder} does not exist or is not writable")
    stem, extension = os.path.splitext(os.path.basename(path))
    temporary = os.path.join(folder, f".{stem}.partial-{os.getpid()}{extension}")
    height, width = pixels.shape[:2]
    channels = pixels.shape[2] if pixels.ndim == 3 else 1
    spec = oiio.ImageSpec(width, height, channels, getattr(oiio, FORMATS[format][0].upper()))
    spec.attribute("oiio:ColorSpace", "Raw")
    if format.startswith("exr"):
        spec.attribute("compression", "zip")
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
