"""Texture atlases for animated characters (Merry 2007, chapter 5): segmentation, flattening in a metric
that knows how the character moves, stretch optimisation and packing, composed into one call.

Every metric is Euclidean in a per-vertex embedding y_i in R^D (see docs: the rest positions, C p_i with
C = P^(1/2) in animation space, or a mesh sequence's frames stacked and divided by sqrt(F)). Flattening and
stretch need only each triangle's squared metric edge lengths (its 3x3 Gram matrix, by polarisation);
segmentation needs areas and perimeters, measured in the embedding's leading principal directions.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from . import _core
from .flatten import flatten, mesh_stretch, metric_area
from .pack import DEFAULT_MARGIN, DEFAULT_TEXTURE_SIZE, pack, texture_efficiency
from .metrics import PoseStatistics
from ._checks import (FLAG, as_index_array, as_optional_index_array, as_real_array, check_memory, checked, choice,
                      count, optional, real)
from .model import AnimationSpaceModel, SkinkitError
from .segmentation import checked_seams, chart_corners, cut_along_seams, segment, segment_report
from .segmentation import straighten as straighten_boundaries

#: The public API (what tests/fuzz/api_fuzz.py calls with hostile arguments); the rest are helpers.
__all__ = ["unwrap", "rest_embedding", "animation_embedding", "sampled_animation_embedding", "sequence_embedding",
           "texture_seams"]

#: The largest texture the packer takes (SK_PACK_MAX_TEXTURE_SIZE in csrc/skinkit.h).
MAX_TEXTURE_SIZE = 65536
#: Segmenting in the metric measures areas and perimeters in at most this many principal directions of the
#: embedding; up to 4 the largest projected area has a closed form (the Pfaffian), above it needs an eigensolve
#: per merge (8 dimensions took 1.6 s on the horse against 0.06 s in 3-D).
SEGMENTATION_DIMENSIONS = 4

#: Sweeps (a global step, then a Newton step per vertex) of the stretch optimisation per flattening pass, at most;
#: most charts stop earlier (relative gain below 1e-6). Measured over the horse's unseen gallop: 1.0566 after 30
#: sweeps, 1.0472 after 50, 1.0470 after 300 (0.28 s, 0.36 s, 0.69 s for the whole unwrap); the arm and the
#: creature converge within 10. 30 keeps the unwrap near Blender's Conformal unwrap time.
OPTIMISATION_SWEEPS = 30

#: A triangle whose area is below this fraction of the median triangle's is degenerate.
DEGENERATE_AREA = 1e-12


@dataclass(frozen=True, eq=False)
class UnwrapResult:
    """uv float64 (T, 3, 2): each corner's texture coordinate, packed in [0, 1]^2; charts int32 (T,);
    seams int32 (S, 2): the vertex pairs of the edges between two charts (sorted pairs); report: charts,
    seconds, stretch_metric, stretch_rest, stretch_frames (None without evaluation frames),
    packing_efficiency, texture_efficiency and what the passes reported."""

    uv: np.ndarray
    charts: np.ndarray
    seams: np.ndarray
    report: dict


# ---- metrics: embeddings and what is derived from them ---------------------------------------------


def rest_embedding(positions) -> np.ndarray:
    """The rest pose's metric: the positions themselves (V, 3)."""
    return as_real_array(positions, "positions", shape=(None, 3))


@checked(model=AnimationSpaceModel, statistics=PoseStatistics)
def animation_embedding(model: AnimationSpaceModel, statistics: PoseStatistics) -> np.ndarray:
    """The animation-space metric (eq. 3.6): y_i = C p_i with C = P^(1/2), so that dot products of
    differences are the L2,2 inner products <p_a - p_b, p_c - p_d>. (V, 4b); statistics in the model's space."""
    if statistics.bone_count != model.bone_count:
        raise SkinkitError(f"the statistics have {statistics.bone_count} bones, the model {model.bone_count}")
    check_memory(2 * model.vertex_count * model.bone_count * 4 * 8, "the animation-space embedding",
                 "unwrap in the rest pose's metric, or with fewer bones")
    dense = np.zeros((model.vertex_count, model.bone_count, 4))
    dense[model.vertex_of_each_influence(), model.bones] += model.coordinates
    root = statistics.normalised_coordinates()
    return dense.reshape(model.vertex_count, -1) @ root  # C is symmetric: rows p_i^T C = (C p_i)^T


@checked(model=AnimationSpaceModel)
def sampled_animation_embedding(model: AnimationSpaceModel, poses) -> np.ndarray:
    """The animation-space metric of sampled poses (n, b, 4, 4), exactly: y_i = C p_i with C = P^(1/2) and
    P = the poses' mean of G^T G (4b, 4b), so that dot products of differences are the frame averages of the
    model's edge inner products over those poses. PoseStatistics (animation_embedding) keep each joint's own moments
    and take the joints as independent, which a real action's are not (a walk swings the legs together): on the
    creature sample its metric's squared edge lengths were 0.76 to 1.22 times the action's; these are the action's to
    rounding. For an action the mesh is unwrapped for and measured over (Animated Unwrap, unwrap --rig)."""
    poses = as_real_array(poses, "poses", shape=(None, model.bone_count, 4, 4))
    if len(poses) == 0:
        raise SkinkitError("poses: at least one sampled pose is needed")
    check_memory(2 * model.vertex_count * model.bone_count * 4 * 8, "the animation-space embedding",
                 "unwrap in the rest pose's metric, or with fewer bones")
    rows = poses.transpose(0, 2, 1, 3).reshape(len(poses), 4, 4 * model.bone_count)  # [G_0 | G_1 | ...] per pose
    second_moment = np.einsum("fri,frj->ij", rows, rows) / len(poses)
    if not np.isfinite(second_moment).all():  # entries near 1e154 and above overflow their squares
        raise SkinkitError(f"poses: too large (largest magnitude {np.abs(poses).max():.3g}): their second moment "
                           "overflows")
    values, vectors = np.linalg.eigh(second_moment)
    root = (vectors * np.sqrt(np.clip(values, 0.0, None))) @ vectors.T
    dense = np.zeros((model.vertex_count, model.bone_count, 4))
    dense[model.vertex_of_each_influence(), model.bones] += model.coordinates
    return dense.reshape(model.vertex_count, -1) @ root


def sequence_embedding(frames) -> np.ndarray:
    """The metric of a mesh sequence (F, V, 3): each vertex's F positions stacked and divided by sqrt(F), so
    dot products of differences are the frame averages of the edge inner products. (V, 3F)."""
    frames = as_real_array(frames, "frames", shape=(None, None, 3))
    if len(frames) == 0:
        raise SkinkitError("frames: a sequence needs at least one frame")
    return np.ascontiguousarray(frames.transpose(1, 0, 2).reshape(frames.shape[1], -1)) / np.sqrt(len(frames))


def edge_lengths_sq(embedding, triangles) -> np.ndarray:
    """(T, 3): per triangle (a, b, c) the squared metric lengths |y_b - y_a|^2, |y_c - y_b|^2, |y_a - y_c|^2.
    Each mesh edge is measured once (D may be in the hundreds) in blocks of edges, to bound the memory."""
    embedding = np.asarray(embedding, dtype=np.float64)
    corners = np.sort(triangle_edges(np.asarray(triangles)).reshape(-1, 2), axis=1)
    edges, inverse = unique_pairs(corners, return_inverse=True)
    squared = np.empty(len(edges))
    for start in range(0, len(edges), 65536):
        block = edges[start:start + 65536]
        difference = embedding[block[:, 1]] - embedding[block[:, 0]]
        squared[start:start + 65536] = np.einsum("ed,ed->e", difference, difference)
    return squared[inverse.reshape(-1)].reshape(-1, 3)


def segmentation_embedding(embedding, triangles, dimensions: int = SEGMENTATION_DIMENSIONS) -> np.ndarray:
    """The embedding projected on the top `dimensions` principal directions of its edge vectors (V, d),
    d = min(D, dimensions); exact (the embedding itself) when D <= dimensions, as for the rest pose."""
    embedding = np.asarray(embedding, dtype=np.float64)
    if embedding.shape[1] <= dimensions:
        return embedding.copy()
    edges = unique_edges(np.asarray(triangles))
    vectors = embedding[edges[:, 1]] - embedding[edges[:, 0]]
    _, directions = np.linalg.eigh(vectors.T @ vectors)
    leading = directions[:, ::-1][:, :dimensions]
    return np.ascontiguousarray((embedding - embedding.mean(axis=0)) @ leading)


# ---- mesh topology ------------------------------------------------------------------------------------


def unique_edges(triangles: np.ndarray) -> np.ndarray:
    """(E, 2): every edge once, as a sorted vertex pair."""
    return unique_pairs(np.sort(triangle_edges(triangles).reshape(-1, 2), axis=1))


def unique_pairs(pairs: np.ndarray, **options):
    """np.unique(pairs, axis=0, **options) for non-negative int pairs, by one int64 key per pair (several times
    faster than sorting rows); returns the same tuple np.unique would."""
    pairs = np.asarray(pairs, dtype=np.int64)
    width = int(pairs.max(initial=0)) + 1
    result = np.unique(pairs[:, 0] * width + pairs[:, 1], **options)
    keys = result[0] if isinstance(result, tuple) else result
    decoded = np.column_stack([keys // width, keys % width]).astype(pairs.dtype)
    return (decoded, *result[1:]) if isinstance(result, tuple) else decoded


def triangle_edges(triangles: np.ndarray) -> np.ndarray:
    """(T, 3, 2): the directed edges (a, b), (b, c), (c, a) of each triangle."""
    return np.stack([triangles, np.roll(triangles, -1, axis=1)], axis=2)


def chart_boundaries(triangles, charts) -> np.ndarray:
    """(S, 2) sorted vertex pairs of the edges whose two triangles are in different charts."""
    triangles, charts = np.asarray(triangles), np.asarray(charts)
    edges = np.sort(triangle_edges(triangles).reshape(-1, 2), axis=1)
    owners = np.repeat(charts, 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owners = edges[order], owners[order]
    same_edge = np.all(edges[1:] == edges[:-1], axis=1)
    between = same_edge & (owners[1:] != owners[:-1])
    return np.unique(edges[1:][between], axis=0).astype(np.int32).reshape(-1, 2)


def texture_seams(triangles, texture_corners) -> np.ndarray:
    """(S, 2) sorted vertex pairs of the edges between uv islands: edges whose two faces give either end a
    different texture coordinate (texture_corners (T, 3): an index per corner, as OBJ's vt)."""
    triangles = as_index_array(triangles, "triangles", (None, 3))
    texture_corners = as_index_array(texture_corners, "texture_corners", triangles.shape)
    vertices = triangle_edges(triangles).reshape(-1, 2)
    textures = triangle_edges(texture_corners).reshape(-1, 2)
    backwards = vertices[:, 0] > vertices[:, 1]
    vertices = np.where(backwards[:, None], vertices[:, ::-1], vertices)
    textures = np.where(backwards[:, None], textures[:, ::-1], textures)
    order = np.lexsort((vertices[:, 1], vertices[:, 0]))
    vertices, textures = vertices[order], textures[order]
    same_edge = np.all(vertices[1:] == vertices[:-1], axis=1)
    cut = same_edge & np.any(textures[1:] != textures[:-1], axis=1)
    return np.unique(vertices[1:][cut], axis=0).astype(np.int32).reshape(-1, 2)


def check_areas(areas: np.ndarray, triangles: np.ndarray, where: str) -> None:
    """Refuses triangles of (near) zero area, naming the first one."""
    reference = float(np.median(areas))
    degenerate = np.flatnonzero(~(areas > DEGENERATE_AREA * reference))
    if len(degenerate):
        t = int(degenerate[0])
        raise SkinkitError(f"face {t} (vertices {tuple(int(v) for v in triangles[t])}) has zero area {where}"
                           f"{f' (and {len(degenerate) - 1} more)' if len(degenerate) > 1 else ''}: dissolve "
                           "degenerate faces first (Blender: Mesh > Clean Up > Degenerate Dissolve)")


def used_vertices(triangles: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """(the vertices some triangle uses, the triangles renumbered over them): loose vertices have no
    corners, so no uv; they are left out of every step."""
    used = np.flatnonzero(np.bincount(triangles.reshape(-1), minlength=vertex_count))
    renumber = np.full(vertex_count, -1, np.int32)
    renumber[used] = np.arange(len(used), dtype=np.int32)
    return used, renumber[triangles]


# ---- the pipeline -------------------------------------------------------------------------------------


@checked(mode=str, chart_count=optional(count(1)), threshold=optional(real(above=0)), straighten=FLAG,
         segment_in=choice(("rest", "metric")), texture_size=count(1, MAX_TEXTURE_SIZE), margin=count(0, 4096))
def unwrap(positions, triangles, *, embedding=None, seams=None, mode: str = "auto", chart_count=None,
           threshold=None, straighten: bool = False, segment_in: str = "rest",
           texture_size: int = DEFAULT_TEXTURE_SIZE, margin: int = DEFAULT_MARGIN, evaluation_frames=None,
           polygons=None) -> UnwrapResult:
    """A texture atlas of the mesh that minimises stretch in the metric of `embedding` (V, D) (default: the
    rest positions): segmentation (mode "auto" merges charts greedily down to chart_count or threshold, with
    `seams` (S, 2) vertex pairs as hard boundaries; "seams" takes the charts the seams cut), boundary and
    parametric straightening, LSCM with stretch optimisation, packing for a texture_size texture with
    `margin` texels between charts. evaluation_frames (F, V, 3): positions over an animation, reported as
    the mean of each frame's mesh L2 stretch. polygons (T,): the polygon each triangle came from; charts
    then never split a polygon (a Blender face has one uv per corner). segment_in: "rest" segments in 3-D (the
    default: the thesis found segmenting in animation space aligns boundaries with joints but does not lower
    stretch), "metric" in the metric's leading principal directions (appendix A.1's bivectors); "seams" mode
    always uses 3-D, whose charts are the same. Straightening (boundaries straight between corners, for
    mip-mapping and LOD) is off by default because it raises stretch (the thesis' Table 8.5)."""
    started = time.perf_counter()
    positions = as_real_array(positions, "positions", shape=(None, 3))
    triangles = as_index_array(triangles, "triangles", (None, 3))
    if len(triangles) == 0:
        raise SkinkitError("the mesh has no faces to unwrap")
    embedding = positions if embedding is None else as_real_array(embedding, "embedding",
                                                                  shape=(len(positions), None))
    polygons = as_optional_index_array(polygons, "polygons", (len(triangles),))
    if evaluation_frames is not None:
        evaluation_frames = as_real_array(evaluation_frames, "evaluation_frames", shape=(None, len(positions), 3))
    # Indices in range, no edge on three faces, neighbours oriented alike, no bowtie: else no disc charts.
    _core.validate_surface(triangles, len(positions))
    used, local_triangles = used_vertices(triangles, len(positions))
    rest_lengths = edge_lengths_sq(positions, triangles)
    check_areas(metric_area(rest_lengths), triangles, "in the rest pose")
    lengths = edge_lengths_sq(embedding, triangles)
    areas = metric_area(lengths)
    check_areas(areas, triangles, "in the metric (its corners move as one point)")
    local_seams = local_seam_pairs(seams, used, len(positions))
    if not isinstance(segment_in, str) or segment_in not in ("rest", "metric"):  # an array compares elementwise
        raise SkinkitError(f"segment_in: expected 'rest' or 'metric', got {segment_in!r}")
    layout = segmentation_embedding(embedding[used], local_triangles) if segment_in == "metric" and mode != "seams" \
        else np.ascontiguousarray(positions[used])

    charts, segmentation = segment_report(layout, local_triangles, seams=local_seams, mode=mode,
                                          chart_count=chart_count, threshold=threshold)
    # Charts are discs of the mesh cut open along the seams (a tube slit by one seam is one chart), so the
    # steps after segmentation work on the cut mesh; triangles keep their numbers.
    cut_triangles, source = cut_along_seams(local_triangles, local_seams, len(used))
    cut_layout = layout[source]
    corners = None
    if straighten:
        charts, corners = straighten_boundaries(cut_layout, cut_triangles, charts)
    if polygons is not None and polygons_across_charts(polygons, charts):
        charts = charts_of_whole_polygons(layout, local_triangles, charts, areas, polygons, local_seams)
        corners = None
    if corners is None:
        corners = chart_corners(cut_triangles, charts, embedding=cut_layout)
    flattening = flatten(cut_triangles, lengths, charts, corners, straight=straighten,
                         sweep_limit=OPTIMISATION_SWEEPS)
    if polygons is not None and polygons_across_charts(polygons, flattening.charts):
        # The overlap check split a chart through a polygon: flatten once more with whole polygons.
        charts = charts_of_whole_polygons(layout, local_triangles, flattening.charts, areas, polygons, local_seams)
        flattening = flatten(cut_triangles, lengths, charts, chart_corners(cut_triangles, charts, embedding=cut_layout),
                             straight=straighten, sweep_limit=OPTIMISATION_SWEEPS)
    packing = pack(flattening.uv, flattening.charts, texture_size=texture_size, margin=margin, surface_area=areas)
    seconds = time.perf_counter() - started

    stretch_metric = mesh_stretch(packing.uv, lengths)
    report = {"charts": int(flattening.charts.max()) + 1, "seconds": seconds, "stretch_metric": stretch_metric,
              "stretch_rest": mesh_stretch(packing.uv, rest_lengths),
              "stretch_frames": frames_stretch(packing.uv, triangles, evaluation_frames),
              "packing_efficiency": float(packing.packing_efficiency),
              "texture_efficiency": texture_efficiency(packing.packing_efficiency, stretch_metric),
              "segmented_charts": int(segmentation["chart_count"]), "mesh_metric": float(segmentation["mesh_metric"]),
              "vertices": len(positions), "triangles": len(triangles), "loose_vertices": len(positions) - len(used),
              "metric_dimensions": int(embedding.shape[1]), "flattening": flattening.report, "packing": packing.report}
    report.update(worst_triangles(packing.uv, lengths, flattening.charts))
    report.update(atlas_status(report))
    return UnwrapResult(packing.uv, flattening.charts.astype(np.int32),
                        chart_boundaries(triangles, flattening.charts), report)


#: An atlas whose L2 stretch (in the metric, at rest or over the frames) exceeds this is broken, not a success.
ABSURD_STRETCH = 100.0
#: ... and so is one whose texture efficiency is below this (charts collapsed to nothing).
TINY_TEXTURE_EFFICIENCY = 1e-4


def worst_triangles(uv, lengths, charts) -> dict:
    """Per chart, its worst triangle by L2 stretch in the metric: {"chart_worst_triangle": [...],
    "chart_worst_stretch": [...]} (index into the mesh's triangles; infinity for a flipped or collapsed one)."""
    from .flatten import triangle_stretch

    stretch = triangle_stretch(uv, lengths)
    chart_count = int(charts.max()) + 1 if len(charts) else 0
    order = np.lexsort((-np.nan_to_num(stretch, nan=np.inf, posinf=np.inf), charts))  # by chart, worst first
    first = order[np.searchsorted(charts[order], np.arange(chart_count))]
    return {"chart_worst_triangle": first.astype(int).tolist(), "chart_worst_stretch": stretch[first].tolist()}


def atlas_status(report: dict) -> dict:
    """"status": "ok", or "failed" with the "problems" that make the atlas unusable (invalid triangles, a stretch that
    is not finite or absurd, a texture efficiency near zero): such an atlas is never reported as a success."""
    problems = []
    invalid = int(report["flattening"].get("invalid_triangles", 0))
    if invalid:
        problems.append(f"{invalid} uv triangles are flipped, degenerate or collapsed")
    for key, words in (("stretch_metric", "in the metric"), ("stretch_rest", "at rest"),
                       ("stretch_frames", "over the frames")):
        value = report.get(key)
        if value is not None and not (np.isfinite(value) and value <= ABSURD_STRETCH):
            problems.append(f"L2 stretch {words} is {value:.3g} (above {ABSURD_STRETCH:g}, or not finite)")
    if not report["texture_efficiency"] >= TINY_TEXTURE_EFFICIENCY:
        problems.append(f"texture efficiency {report['texture_efficiency']:.3g} is near zero (charts collapsed)")
    return {"status": "failed" if problems else "ok", "problems": problems}


def local_seam_pairs(seams, used: np.ndarray, vertex_count: int) -> np.ndarray | None:
    """User seams (S, 2) renumbered over the used vertices; seams touching a loose vertex bound nothing."""
    if seams is None:
        return None
    seams = checked_seams(seams, vertex_count)
    renumber = np.full(vertex_count, -1, np.int32)
    renumber[used] = np.arange(len(used), dtype=np.int32)
    local = renumber[seams]
    return np.ascontiguousarray(local[np.all(local >= 0, axis=1)])


def charts_of_whole_polygons(layout, triangles, charts, areas, polygons, seams) -> np.ndarray:
    """Each polygon's triangles moved into the chart holding most of its area, then the charts cut again
    along the resulting boundaries (and the user's seams) in "seams" mode, which keeps every chart a disc."""
    pairs, inverse = np.unique(np.column_stack([polygons, charts]), axis=0, return_inverse=True)
    share = np.bincount(inverse.reshape(-1), weights=areas, minlength=len(pairs))
    order = np.lexsort((-share, pairs[:, 0]))
    leading = order[np.r_[True, pairs[order[1:], 0] != pairs[order[:-1], 0]]]
    chart_of_polygon = np.zeros(int(polygons.max()) + 1, np.int32)
    chart_of_polygon[pairs[leading, 0]] = pairs[leading, 1]
    whole = chart_of_polygon[polygons]
    boundaries = chart_boundaries(triangles, whole)
    if seams is not None and len(seams):
        boundaries = np.concatenate([boundaries, seams])
    return segment(layout, triangles, seams=boundaries, mode="seams")


def polygons_across_charts(polygons, charts) -> int:
    """How many polygons have triangles in more than one chart."""
    pairs = unique_pairs(np.column_stack([polygons, charts]))
    return int(len(pairs) - len(np.unique(pairs[:, 0])))


def frames_stretch(uv: np.ndarray, triangles: np.ndarray, frames: np.ndarray | None) -> float | None:
    """The mean over frames (F, V, 3) of each frame's mesh L2 stretch, or None without frames."""
    if frames is None:
        return None
    if len(frames) == 0:
        raise SkinkitError("evaluation_frames: no frames")
    return float(np.mean([mesh_stretch(uv, edge_lengths_sq(frame, triangles)) for frame in frames]))
