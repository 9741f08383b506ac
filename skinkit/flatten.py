"""Flattening charts in a metric, and the stretch of a layout (Merry 2007, section 5.3); packing is skinkit.pack.

The metric is given per triangle (a, b, c) by its squared metric edge lengths (|ab|^2, |bc|^2, |ca|^2), which
are its Gram matrix in another form: rest pose, animation space or a frame average all reach this module the
same way (see skinkit.unwrap). uv arrays are per triangle corner, (T, 3, 2), because a vertex on a chart
boundary has one uv per chart. The work is done by the C core (csrc/sk_flatten.c); this
module checks shapes and types and names what is wrong.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _core
from ._checks import FLAG, THREADS, as_array, as_index_array, as_real_array, checked, count, real
from .model import SkinkitError

__all__ = ["Flattening", "flatten", "triangle_stretch", "mesh_stretch", "metric_area", "checked_uv"]

#: Straightening that raises a chart's L2 stretch by more than this factor gets extra corners (section 8.4).
DEFAULT_STRETCH_LIMIT = 4.0
#: Sweeps of the stretch optimisation (Newton steps, one vertex at a time) per pass; it stops earlier when a
#: sweep gains less than 1e-6.
DEFAULT_SWEEP_LIMIT = 30


@dataclass(frozen=True, eq=False)
class Flattening:
    uv: np.ndarray      # (T, 3, 2) per corner, each chart in its own frame, metric units
    charts: np.ndarray  # (T,) int32, the given charts possibly split further
    report: dict        # counts from the core: charts, splits, passes used, solver work


def _triangles_and_lengths(triangles, edge_lengths_sq) -> tuple[np.ndarray, np.ndarray]:
    triangles = as_index_array(triangles, "triangles", (None, 3))
    if len(triangles) == 0:
        raise SkinkitError("triangles: the mesh has no triangles")
    lengths = as_real_array(edge_lengths_sq, "edge_lengths_sq", shape=(len(triangles), 3))
    return triangles, lengths


@checked(triangle_count=count())
def checked_uv(uv, triangle_count: int) -> np.ndarray:
    return as_real_array(uv, "uv", shape=(triangle_count, 3, 2))


@checked(straight=FLAG, optimise=FLAG, stretch_limit=real(minimum=1), sweep_limit=count(0, 100000),
         threads=THREADS)
def flatten(triangles, edge_lengths_sq, charts, corners, *, straight: bool = True, optimise: bool = True,
            stretch_limit: float = DEFAULT_STRETCH_LIMIT, sweep_limit: int = DEFAULT_SWEEP_LIMIT,
            threads: int = 0) -> Flattening:
    """Flattens each chart (charts (T,) ids in [0, T)) in the metric, each in its own 2D frame, unpacked.

    corners (V,) bool marks the chart corners (skinkit.segmentation.chart_corners); V is len(corners).
    straight: pin each chart's boundary to straight lines between its corners (passes 2 and 3 of section 5.3),
    else keep the free-boundary layout (LSCM with two pins; boundary first flattening, a conformal map that keeps
    the boundary's lengths, for charts of 1000 interior vertices or more). optimise: follow every pass with Sander's
    L2 stretch optimisation.
    A chart whose layout overlaps itself is split, and so is a free-boundary chart of 2000 triangles or more that still
    stretches more than 1.1 when optimised; Flattening.charts numbers the result's charts 0..C-1.
    Raises SkinkitError naming the chart or triangle for a chart that is not a disc, a triangle with a
    non-positive metric area, inconsistent orientation, or arrays of the wrong size.
    """
    triangles, lengths = _triangles_and_lengths(triangles, edge_lengths_sq)
    charts = as_index_array(charts, "charts", (len(triangles),))
    corners = as_array(corners, "corners")
    if corners.ndim != 1 or corners.dtype != np.bool_:
        raise SkinkitError(f"corners: expected a (V,) bool array, got shape {corners.shape} dtype {corners.dtype}")
    if triangles.max() >= len(corners):
        raise SkinkitError(f"corners: {len(corners)} entries, but the triangles use vertex {int(triangles.max())}")
    if not stretch_limit >= 1.0:
        raise SkinkitError(f"stretch_limit must be at least 1 (got {stretch_limit})")
    uv = np.empty((len(triangles), 3, 2))
    charts_out = np.empty(len(triangles), dtype=np.int32)
    report = _core.flatten(uv.reshape(-1), charts_out, triangles.reshape(-1), lengths.reshape(-1), charts,
                           np.ascontiguousarray(corners).view(np.uint8), len(corners), bool(straight), bool(optimise),
                           float(stretch_limit), int(sweep_limit), int(threads))
    return Flattening(uv, charts_out, report)


def triangle_stretch(uv, edge_lengths_sq) -> np.ndarray:
    """(T,) L2 stretch sqrt((s1^2 + s2^2) / 2) of each triangle (eq. 5.6-5.8); inf where flipped or degenerate."""
    lengths = as_real_array(edge_lengths_sq, "edge_lengths_sq", shape=(None, 3))
    uv = checked_uv(uv, len(lengths))
    stretch = np.empty(len(lengths))
    _core.triangle_stretch(stretch, uv.reshape(-1), lengths.reshape(-1))
    return stretch


def mesh_stretch(uv, edge_lengths_sq) -> float:
    """Sander et al. 2001's normalised L2 stretch: the metric-area-weighted RMS of the triangles' stretch with
    uv rescaled to the metric's total area (1.0 for an isometry, never less); inf if any triangle is flipped
    or degenerate in uv."""
    lengths = as_real_array(edge_lengths_sq, "edge_lengths_sq", shape=(None, 3))
    if len(lengths) == 0:
        raise SkinkitError("edge_lengths_sq: no triangles")
    return _core.mesh_stretch(checked_uv(uv, len(lengths)).reshape(-1), lengths.reshape(-1))["stretch"]


def metric_area(edge_lengths_sq) -> np.ndarray:
    """(T,) each triangle's area in the metric (Heron's formula in Gram form), for skinkit.pack's surface_area."""
    lengths = as_real_array(edge_lengths_sq, "edge_lengths_sq", shape=(None, 3))
    g11, g22 = lengths[:, 0], lengths[:, 2]
    g12 = (lengths[:, 0] + lengths[:, 2] - lengths[:, 1]) / 2
    return np.sqrt(np.maximum(g11 * g22 - g12 * g12, 0.0)) / 2
