"""Segmentation of a mesh into disc-shaped charts for unwrapping (Merry 2007, section 5.2).

Everything is measured in an embedding of the vertices (V, d), 2 <= d <= 8: the rest positions, or the
animation-space metric projected on its principal directions (see skinkit.unwrap). The work is done by
the C core (csrc/sk_segment.c); this module checks shapes and types and names what is wrong.
"""
from __future__ import annotations

import numpy as np

from . import _core
from ._checks import as_index_array, as_real_array, checked, count, optional, real
from .model import SkinkitError

__all__ = ["segment", "straighten", "chart_corners", "cut_along_seams"]

#: Weight of the compactness term in the combined metric (eq. 5.4); the thesis' value (section 8.4).
DEFAULT_RHO = 0.2
#: Largest growth of a chart's metric that a straightened boundary may cause before the constrained
#: (short-cut only) form is used (section 5.2.3 and 8.4).
DEFAULT_STRAIGHTEN_RATIO = 1.2
#: E_mesh (eq. 5.5) at which "auto" stops when neither a chart count nor a threshold is given: the
#: thesis' automatic segmentations of its characters ended between 1.91 and 2.15 (Table 8.3).
DEFAULT_THRESHOLD = 2.0
MAX_EMBEDDING_DIMENSION = 8
_MODES = {"auto": 0, "seams": 1}


@checked(mode=str, chart_count=optional(count(1)), threshold=optional(real(above=0)), rho=real(minimum=0))
def segment(embedding, triangles, *, seams=None, mode: str = "auto", chart_count: int | None = None,
            threshold: float | None = None, rho: float = DEFAULT_RHO) -> np.ndarray:
    """Charts (T,) int32 numbered 0..C-1, every chart a topological disc.

    mode "auto": greedy merging with the combined metric until `chart_count` charts remain or the next
    merge would lift E_mesh (eq. 5.5) above `threshold` (either or both; with neither, the threshold is
    DEFAULT_THRESHOLD). Seams ((S, 2) vertex pairs, mesh edges) are never
    merged across. mode "seams": the charts are the pieces the seams cut out; a piece that is not a disc
    (a closed or tubular part the seams leave whole) is cut where the greedy merge must stop (see
    `segment_report` for how many charts that added).
    """
    return segment_report(embedding, triangles, seams=seams, mode=mode, chart_count=chart_count,
                          threshold=threshold, rho=rho)[0]


def segment_report(embedding, triangles, *, seams=None, mode: str = "auto", chart_count: int | None = None,
                   threshold: float | None = None, rho: float = DEFAULT_RHO) -> tuple[np.ndarray, dict]:
    """`segment` and a report: chart_count, mesh_metric (E_mesh) and components (the pieces between seams;
    in seams mode chart_count - components charts come from cutting pieces that are not discs)."""
    embedding, triangles = _checked_mesh(embedding, triangles)
    seam_pairs = checked_seams(seams, len(embedding))
    if not isinstance(mode, str) or mode not in _MODES:  # an array's `in` fails or compares elementwise
        raise SkinkitError(f"mode: expected one of {sorted(_MODES)}, got {mode!r}")
    if chart_count is not None and (int(chart_count) != chart_count or chart_count < 1):
        raise SkinkitError(f"chart_count: expected a positive whole number, got {chart_count!r}")
    if threshold is not None and not (np.isfinite(threshold) and threshold > 0):
        raise SkinkitError(f"threshold: expected a positive number, got {threshold!r}")
    if not (np.isfinite(rho) and rho >= 0):
        raise SkinkitError(f"rho: expected a number >= 0, got {rho!r}")
    if mode == "auto" and chart_count is None and threshold is None:
        threshold = DEFAULT_THRESHOLD
    charts = np.empty(len(triangles), np.int32)
    result = _core.segment(
        charts, embedding.reshape(-1), embedding.shape[1], triangles.reshape(-1), seam_pairs.reshape(-1),
        _MODES[mode], int(chart_count or 0), float(threshold or 0.0), float(rho))
    report = {"chart_count": result["chart_count"], "mesh_metric": result["mesh_metric"],
              "components": result["component_count"]}
    return charts, report


@checked(vertex_count=optional(count()))
def cut_along_seams(triangles, seams, vertex_count: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(cut triangles (T, 3) int32, source vertex of each new vertex (V',) int32): the mesh opened along
    the seams, each vertex split into one copy per fan of triangles joined through non-seam edges.

    `segment` charts are discs of this cut mesh (a tube slit by a seam is one chart), so corners,
    straightening and flattening take the cut triangles and embedding[source]."""
    triangles = as_index_array(triangles, "triangles", (None, 3))
    if vertex_count is None:
        vertex_count = int(triangles.max()) + 1 if triangles.size else 0
    seam_pairs = checked_seams(seams, vertex_count)
    cut = np.empty_like(triangles)
    source = np.empty(triangles.size, np.int32)
    count = _core.cut_along_seams(cut, source, triangles.reshape(-1), seam_pairs.reshape(-1),
                                  vertex_count)["cut_vertex_count"]
    return cut, source[:count].copy()


def chart_corners(triangles, charts, *, embedding=None) -> np.ndarray:
    """Corners (V,) bool: vertices where 3+ charts meet or where 2+ meet on the mesh border, plus
    artificial ones so that every chart has at least three (Fig 5.6), spread by metric length along
    the boundary when `embedding` is given, else by edge count. Every chart must be a disc."""
    triangles = as_index_array(triangles, "triangles", (None, 3))
    charts = _checked_charts(charts, len(triangles))
    vertex_count = max(int(triangles.max()) + 1, 0) if triangles.size else 0  # negative indices: the core says
    dimension = 0
    if embedding is not None:
        embedding = _checked_embedding(embedding)
        vertex_count, dimension = embedding.shape
    corners = np.zeros(vertex_count, np.bool_)
    _core.chart_corners(corners, triangles.reshape(-1), charts,
                        None if embedding is None else embedding.reshape(-1), dimension, vertex_count)
    return corners


@checked(ratio=real(minimum=1), rho=real(minimum=0))
def straighten(embedding, triangles, charts, *, ratio: float = DEFAULT_STRAIGHTEN_RATIO,
               rho: float = DEFAULT_RHO) -> tuple[np.ndarray, np.ndarray]:
    """(charts (T,) int32, corners (V,) bool) after edge straightening (section 5.2.3): every boundary
    between two corners and two charts becomes the shortest path between its corners inside those
    charts; when that makes either chart's metric grow by more than `ratio`, the path may only short-cut
    vertices of the old boundary. Chart numbers, corners and disc topology are kept."""
    return straighten_report(embedding, triangles, charts, ratio=ratio, rho=rho)[:2]


def straighten_report(embedding, triangles, charts, *, ratio: float = DEFAULT_STRAIGHTEN_RATIO,
                      rho: float = DEFAULT_RHO) -> tuple[np.ndarray, np.ndarray, dict]:
    """`straighten` and a report: paths, shortest, constrained, kept (boundary paths by outcome)."""
    embedding, triangles = _checked_mesh(embedding, triangles)
    result = _checked_charts(charts, len(triangles)).copy()
    if not (np.isfinite(ratio) and ratio >= 1):
        raise SkinkitError(f"ratio: expected a number >= 1, got {ratio!r}")
    if not (np.isfinite(rho) and rho >= 0):
        raise SkinkitError(f"rho: expected a number >= 0, got {rho!r}")
    corners = np.zeros(len(embedding), np.bool_)
    report = _core.straighten_charts(
        result, corners, embedding.reshape(-1), embedding.shape[1], triangles.reshape(-1), float(ratio), float(rho))
    return result, corners, report


def _checked_embedding(embedding) -> np.ndarray:
    embedding = as_real_array(embedding, "embedding", shape=(None, None))
    if not 2 <= embedding.shape[1] <= MAX_EMBEDDING_DIMENSION:
        raise SkinkitError(f"embedding: expected 2 to {MAX_EMBEDDING_DIMENSION} columns, got {embedding.shape[1]}")
    return embedding


def _checked_mesh(embedding, triangles) -> tuple[np.ndarray, np.ndarray]:
    embedding = _checked_embedding(embedding)
    triangles = as_index_array(triangles, "triangles", (None, 3))
    if len(triangles) == 0:
        raise SkinkitError("triangles: the mesh has no triangles")
    return embedding, triangles


def checked_seams(seams, vertex_count: int) -> np.ndarray:
    """(S, 2) int32 vertex pairs, each in [0, vertex_count) (the core checks it too, but its message does not name
    the parameter; skinkit.unwrap renumbers the pairs, so it needs them in range first)."""
    if seams is None:
        return np.zeros((0, 2), np.int32)
    seams = as_index_array(seams, "seams", (None, 2))
    outside = (seams < 0) | (seams >= vertex_count)
    if outside.any():
        row = int(np.argwhere(outside)[0][0])
        raise SkinkitError(f"seams: pair {row} {tuple(int(v) for v in seams[row])} names a vertex outside "
                           f"[0, {vertex_count})")
    return seams


def _checked_charts(charts, triangle_count: int) -> np.ndarray:
    """One chart id per triangle; the core refuses ids outside [0, T), naming the triangle."""
    return as_index_array(charts, "charts", (triangle_count,))
