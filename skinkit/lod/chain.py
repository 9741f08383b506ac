"""Discrete levels of detail of an animation-space model (Merry 2007, chapters 6-7): a progressive mesh of
half-edge collapses costed by memoryless APS in the animation-space metric, with influence collapses in the
same queue (section 6.3.1), cut into levels that each keep at most half the influences of the one before
(section 7.3), with geomorph data on common influence sets (eq. 7.1).

The whole chain is one run of the C collapse queue (`skinkit._core.simplify_chain`, `sk_simplify_chain` in
csrc/skinkit.h), each level snapshotted when its targets are met: memoryless costs depend only on the current mesh,
so every level equals one call of the single step (`simplify_step`) on the level before, and each candidate is
costed once for the whole chain instead of once per level.
"""
from __future__ import annotations

import warnings as _warnings
from dataclasses import dataclass, field

import numpy as np

from .. import _core, _memory
from .._blas import blas_threads_for
from .._checks import (CALLBACK, FLAG, THREADS, SkinkitError, as_index_array, as_real_array, checked, count,
                       optional, real)
from ..decompose import connected_components
from ..metrics import PoseStatistics
from ..model import AnimationSpaceModel

# simplify_step and simplify_levels are build_chain's calls of the C step on its own checked arrays (a flat rest,
# int32 rows): internal, not API (they check nothing the binding does not; the public call is build_chain).
__all__ = ["build_chain", "refit_level", "LodChain", "LodLevel"]

METRICS = {"animation": 0, "rest": 1}
#: Edge collapses: half-edge (u -> v, v unchanged), full (interior edges also re-solve v's coordinates to the
#: least APS cost), auto (per candidate the cheaper of the two). See sk_simplify_chain_tuned.
COLLAPSES = {"half": 0, "full": 1, "auto": 2}
#: The defaults: half-edge collapses, influence collapses ranked at twice their cost. Since every level is refitted
#: to the full detail, re-solving a survivor in the collapse ("auto") no longer pays: against auto at scale 1, half
#: at 2 lowered the error of 46 of 48 levels (6 levels each of 5 data sets from linear-blend weights and of 3 from
#: 8-influence animation-space models; 1-34% on the weights) and builds 1.2-2x faster (BENCHMARKS.md, session 14).
DEFAULT_COLLAPSE = "half"
DEFAULT_INFLUENCE_COST_SCALE = 2.0
#: Each level has at most half the influences of the one before: past 64 levels nothing is left to halve.
MAX_LEVELS = 64
STRAIGHTNESS = 1e-6
#: The refit's pull towards the collapses' coordinates, per unit of a vertex's mean sample mass: with 1e-6 the cow
#: chain's first level got 11% worse on held-out poses (directions the training poses hardly determine moved);
#: 0.1 improved every level of the horse, creature and cow chains (BENCHMARKS.md, session 12).
REFIT_PULL = 0.1
#: CG steps of the refit: 2 came within 0.5% of 4 steps' error on every level of the horse chain, 1 within 3%
#: (BENCHMARKS.md, session 12).
REFIT_STEPS = 2
REFIT_TOLERANCE = 1e-3
#: Where the refit's share of a chain's progress starts.
REFIT_PROGRESS_START = 0.9


@dataclass
class LodLevel:
    """One level: its vertices (indices into the input), triangles on them, the model and UVs they carry.

    epsilon is the largest simplification cost applied on the way from the input to this level (absolute, model
    units; relative_epsilon divides it by the rest bounding-box diagonal). to_coarser maps each vertex to its
    index in the next coarser level (None on the coarsest). The geomorph data (eq. 7.1), for all but the
    coarsest level: morph_model holds p^l on the union of each vertex's bones and its coarser vertex's (padded
    with zero influences), morph_delta the matching p^{l+1}(mapped vertex) - p^l, and morph_uv / morph_delta_uv
    the corners' UVs and their motion to the mapped vertex's UV in the same chart.
    """
    vertices: np.ndarray
    triangles: np.ndarray
    model: AnimationSpaceModel
    uv: np.ndarray | None
    charts: np.ndarray | None
    triangle_origin: np.ndarray
    epsilon: float
    relative_epsilon: float
    report: dict
    to_coarser: np.ndarray | None = None
    morph_model: AnimationSpaceModel | None = None
    morph_delta: np.ndarray | None = None
    morph_uv: np.ndarray | None = None
    morph_delta_uv: np.ndarray | None = None

    @property
    def vertex_count(self) -> int:
        return len(self.vertices)

    @property
    def triangle_count(self) -> int:
        return len(self.triangles)

    @property
    def influence_count(self) -> int:
        return self.model.influence_count


@dataclass
class LodChain:
    levels: list[LodLevel]
    diagonal: float
    warnings: list[str] = field(default_factory=list)

    @checked(level=real())
    def geomorph(self, level: float) -> tuple[AnimationSpaceModel, np.ndarray | None, np.ndarray]:
        """(model, uv, triangles) at a real-valued level: exactly level l at an integer l, else level floor(l)'s
        mesh with p = p^l + f dp and uv = uv^l + f duv, f = l - floor(l) (eq. 7.1), continuous in l."""
        level = float(level)
        last = len(self.levels) - 1
        if not 0.0 <= level <= last:
            raise SkinkitError(f"level: {level} is outside [0, {last}]")
        base = int(np.floor(level))
        fraction = level - base
        lod = self.levels[base]
        if fraction == 0.0:
            return lod.model, lod.uv, lod.triangles
        m = lod.morph_model
        model = AnimationSpaceModel(m.offsets, m.bones, m.coordinates + fraction * lod.morph_delta, m.bone_count)
        uv = None if lod.morph_uv is None else lod.morph_uv + fraction * lod.morph_delta_uv
        return model, uv, lod.triangles


def _side_flags(triangles: np.ndarray, locked_edges: np.ndarray, vertex_count: int) -> np.ndarray:
    a = triangles.astype(np.int64)
    b = np.roll(a, -1, axis=1)
    keys = np.minimum(a, b) * vertex_count + np.maximum(a, b)
    lk = np.minimum(locked_edges[:, 0], locked_edges[:, 1]).astype(np.int64) * vertex_count + \
        np.maximum(locked_edges[:, 0], locked_edges[:, 1])
    flags = np.isin(keys, lk)
    missing = np.setdiff1d(lk, keys.ravel())
    if len(missing):
        e = int(missing[0])
        raise SkinkitError(f"locked_edges: ({e // vertex_count}, {e % vertex_count}) is not an edge of the mesh")
    return np.ascontiguousarray(flags, dtype=np.uint8)


def _uv_charts(triangles: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Charts from UV continuity: triangles joined across edges whose two ends have the same UVs on both sides
    (numbered by their smallest triangle)."""
    count = len(triangles)
    a = triangles.astype(np.int64)
    b = np.roll(a, -1, axis=1)
    corner_uv = uv.reshape(count, 3, 2)
    next_uv = np.roll(corner_uv, -1, axis=1)
    swap = (a > b)[..., None]
    low_uv = np.where(swap, next_uv, corner_uv).reshape(-1, 2)
    high_uv = np.where(swap, corner_uv, next_uv).reshape(-1, 2)
    keys = (np.minimum(a, b) * (int(a.max(initial=0)) + 1) + np.maximum(a, b)).reshape(-1)
    order = np.argsort(keys, kind="stable")
    first, second = order[:-1], order[1:]
    pair = keys[first] == keys[second]
    first, second = first[pair], second[pair]
    same = np.all(low_uv[first] == low_uv[second], axis=1) & np.all(high_uv[first] == high_uv[second], axis=1)
    edges = np.stack((first[same] // 3, second[same] // 3), axis=1)
    return np.unique(connected_components(count, edges), return_inverse=True)[1].astype(np.int32)


def simplify_step(triangles, rest_positions, offsets, bones, coordinates, statistics, *, uv=None, charts=None,
                  materials=None, locked=None, target_triangles=0, target_influences=0, metric="animation",
                  simplify_influences=True, straightness=STRAIGHTNESS, progress=None) -> dict:
    """One call of the C step on arrays in the input's vertex numbering; returns its outputs (trimmed) and report."""
    if not isinstance(metric, str) or metric not in METRICS:
        raise SkinkitError(f"metric: expected 'animation' or 'rest', got {metric!r}")
    triangles = np.ascontiguousarray(triangles, dtype=np.int32)
    t, v, n = len(triangles), len(offsets) - 1, len(bones)
    tri_out = np.empty((t, 3), np.int32)
    origin = np.empty(t, np.int32)
    uv_out = None if uv is None else np.empty((t, 6))
    locked_out = None if locked is None else np.empty((t, 3), np.uint8)
    vertex_map = np.empty(v, np.int32)
    offsets_out = np.empty(v + 1, np.int32)
    bones_out = np.empty(n, np.int32)
    coordinates_out = np.empty((n, 4))
    report = _core.simplify(tri_out, origin, uv_out, locked_out, vertex_map, offsets_out, bones_out, coordinates_out,
                            triangles, rest_positions, offsets, bones, coordinates, statistics.expected_local,
                            statistics.expected_gram, statistics.parents, uv, charts, materials, locked,
                            int(target_triangles), int(target_influences), METRICS[metric], bool(simplify_influences),
                            float(straightness), progress)
    count, total = report["triangle_count"], int(offsets_out[-1])
    return {"triangles": tri_out[:count], "triangle_origin": origin[:count],
            "uv": None if uv_out is None else uv_out[:count],
            "locked": None if locked_out is None else locked_out[:count], "vertex_map": vertex_map, "offsets": offsets_out,
            "bones": bones_out[:total], "coordinates": coordinates_out[:total], "report": report}


def checked_collapse(collapse, name: str = "collapse") -> str:
    if not isinstance(collapse, str) or collapse not in COLLAPSES:
        raise SkinkitError(f"{name}: expected 'half', 'full' or 'auto', got {collapse!r}")
    return collapse


def checked_cost_scale(scale, name: str = "influence_cost_scale") -> float:
    if isinstance(scale, bool) or not isinstance(scale, (int, float, np.integer, np.floating)) or \
            not np.isfinite(scale) or not scale > 0:
        raise SkinkitError(f"{name}: expected a finite number > 0, got {scale!r}")
    return float(scale)


def simplify_levels(triangles, rest_positions, offsets, bones, coordinates, statistics, *, targets, uv=None,
                    charts=None, materials=None, locked=None, metric="animation", simplify_influences=True,
                    straightness=STRAIGHTNESS, collapse="half", influence_cost_scale=1.0,
                    rank_per_influence=False, threads=0, progress=None) -> tuple[list[dict], dict]:
    """Every level of a chain in one C call. targets: one (target_triangles, target_influences) per level, 0 for
    unset (both 0: half the previous level's influences). Returns the levels written (each as simplify_step's
    outputs, its offsets absolute into its bones and coordinates, its report with full_collapses) and the chain's
    report."""
    if not isinstance(metric, str) or metric not in METRICS:
        raise SkinkitError(f"metric: expected 'animation' or 'rest', got {metric!r}")
    collapse = checked_collapse(collapse)
    influence_cost_scale = checked_cost_scale(influence_cost_scale)
    triangles = np.ascontiguousarray(triangles, dtype=np.int32)
    t, v, n, levels = len(triangles), len(offsets) - 1, len(bones), len(targets)
    wanted = np.asarray(targets, dtype=np.int64).reshape(levels, 2)
    if (wanted > np.iinfo(np.int32).max).any():
        raise SkinkitError("targets: a target exceeds int32")
    tri_out = np.empty((levels, t, 3), np.int32)
    origin = np.empty((levels, t), np.int32)
    uv_out = None if uv is None else np.empty((levels, t, 6))
    locked_out = None if locked is None else np.empty((levels, t, 3), np.uint8)
    vertex_map = np.empty((levels, v), np.int32)
    offsets_out = np.empty(levels * v + 1, np.int32)
    bones_out = np.empty(levels * n, np.int32)
    coordinates_out = np.empty((levels * n, 4))
    counts = np.zeros((levels, 5), np.int32)
    epsilon = np.zeros(levels)
    full_counts = np.zeros(levels, np.int32)
    with blas_threads_for(threads):  # the two costing threads' small factorisations: one BLAS thread each
        report = _core.simplify_chain_tuned(tri_out, origin, uv_out, locked_out, vertex_map, offsets_out, bones_out,
                                            coordinates_out, counts, epsilon, full_counts, triangles, rest_positions,
                                            offsets, bones, coordinates, statistics.expected_local,
                                            statistics.expected_gram, statistics.parents, uv, charts, materials,
                                            locked, levels, np.ascontiguousarray(wanted[:, 0], np.int32),
                                            np.ascontiguousarray(wanted[:, 1], np.int32), METRICS[metric],
                                            bool(simplify_influences), float(straightness),
                                            COLLAPSES[collapse], bool(rank_per_influence), influence_cost_scale,
                                            int(threads), progress)
    written = []
    for level in range(report["level_count"]):
        kept = int(counts[level, 0])
        # triangle_origin is kept by the level: a copy, so that the chain's big output arrays can be freed
        written.append({"triangles": tri_out[level, :kept], "triangle_origin": origin[level, :kept].copy(),
                        "uv": None if uv_out is None else uv_out[level, :kept],
                        "locked": None if locked_out is None else locked_out[level, :kept],
                        "vertex_map": vertex_map[level], "offsets": offsets_out[level * v:(level + 1) * v + 1],
                        "bones": bones_out, "coordinates": coordinates_out,
                        "report": {"triangle_count": kept, "vertex_count": int(counts[level, 1]),
                                   "influence_count": int(counts[level, 2]), "edge_collapses": int(counts[level, 3]),
                                   "influence_collapses": int(counts[level, 4]), "epsilon": float(epsilon[level]),
                                   "full_collapses": int(full_counts[level]),
                                   "exhausted": int(report["exhausted"] and level == report["level_count"] - 1)}})
    return written, report


@checked(level_model=AnimationSpaceModel, model=AnimationSpaceModel, statistics=PoseStatistics, pull=real(0.0),
         max_steps=count(0, 1000), tolerance=real(0.0, 0.5), threads=THREADS, progress=CALLBACK)
def refit_level(level_triangles, level_rest, level_model: AnimationSpaceModel, triangles, rest_positions,
                model: AnimationSpaceModel, statistics: PoseStatistics, *, pull: float = REFIT_PULL,
                max_steps: int = REFIT_STEPS, tolerance: float = REFIT_TOLERANCE, threads: int = 0,
                progress=None) -> tuple[AnimationSpaceModel, dict]:
    """A level's coordinates refitted to the full detail (Hoppe et al. 1993's distance energy in animation
    space): its triangles and influence sets kept, the coordinates moved to the least expected squared distance
    over the poses between the full-detail surface (`triangles` on `rest_positions`, `model`) and the level, each
    full-detail sample matched to its closest rest-pose point on the level (`level_triangles` on `level_rest`),
    pulled towards the level's own coordinates by `pull`. Returns the refitted model and the C report (samples,
    CG steps, residuals). See sk_lod_refit in csrc/skinkit.h."""
    level_tris = as_index_array(level_triangles, "level_triangles", shape=(None, 3))
    level_rest = as_real_array(level_rest, "level_rest", shape=(level_model.vertex_count, 3))
    tris = as_index_array(triangles, "triangles", shape=(None, 3))
    rest = as_real_array(rest_positions, "rest_positions", shape=(model.vertex_count, 3))
    if statistics.bone_count != model.bone_count or level_model.bone_count != model.bone_count:
        raise SkinkitError(f"statistics, level_model and model must have the same bones ({statistics.bone_count}, "
                           f"{level_model.bone_count}, {model.bone_count})")
    _memory.check_lod_refit(level_model.vertex_count, len(level_tris), level_model.influence_count,
                            _distinct_set_entries(level_model), len(tris), len(rest), threads)
    coordinates = np.empty((level_model.influence_count, 4))
    with blas_threads_for(threads):  # the workers' block factorisations: one BLAS thread each
        report = _core.lod_refit(coordinates, level_tris.astype(np.int32), level_rest.reshape(-1),
                                 level_model.offsets.astype(np.int32), level_model.bones.astype(np.int32),
                                 np.ascontiguousarray(level_model.coordinates, np.float64), tris.astype(np.int32),
                                 rest.reshape(-1), model.offsets.astype(np.int32), model.bones.astype(np.int32),
                                 np.ascontiguousarray(model.coordinates, np.float64), statistics.expected_local,
                                 statistics.expected_gram, statistics.parents, float(pull), int(max_steps),
                                 float(tolerance), int(threads), progress)
    return AnimationSpaceModel(level_model.offsets, level_model.bones, coordinates, level_model.bone_count), report


def _distinct_set_entries(model: AnimationSpaceModel) -> int:
    """About the sum of (4n)^2 over the model's distinct influence sets (bones in order, as sk_lod_refit tells them
    apart): what the refit's kept inverses hold. Sets are told apart by a 64-bit hash of their bones and places
    (8 bytes a vertex, so that the estimate itself allocates little; a collision only lowers the estimate)."""
    counts = np.diff(model.offsets).astype(np.uint64)
    if model.vertex_count == 0:
        return 0
    # in place, one influence-sized temporary at a time: it runs before the refit's memory check
    terms = np.arange(1, model.influence_count + 1, dtype=np.uint64)  # each influence's place in its vertex, + 1
    terms -= np.repeat(model.offsets[:-1], np.diff(model.offsets)).astype(np.uint64)
    with np.errstate(over="ignore"):
        terms *= np.uint64(0x9E3779B97F4A7C15)
        terms *= model.bones.astype(np.uint64) + np.uint64(1)
        sums = np.add.reduceat(terms, np.minimum(model.offsets[:-1], max(len(terms) - 1, 0))) if len(terms) else 0
        keys = counts * np.uint64(0xD6E8FEB86659FD93) + np.where(counts > 0, sums, np.uint64(0))
    _, first = np.unique(keys, return_index=True)
    return int(((4 * counts[first].astype(np.int64)) ** 2).sum())


def _restrict(offsets, bones, coordinates, vertices, bone_count) -> AnimationSpaceModel:
    counts = offsets[vertices + 1] - offsets[vertices]
    new_offsets = np.zeros(len(vertices) + 1, np.int32)
    np.cumsum(counts, out=new_offsets[1:])
    index = np.repeat(offsets[vertices] - new_offsets[:-1], counts) + np.arange(new_offsets[-1])
    return AnimationSpaceModel(new_offsets, np.ascontiguousarray(bones[index], np.int32),
                               np.ascontiguousarray(coordinates[index]), bone_count)


def _unique_inverse(keys: np.ndarray):
    """np.unique(keys, return_inverse=True) by a stable sort: the keys come as runs ascending by vertex (each side's),
    which the stable sort merges at a third of the time of np.unique's quicksort (2.2M keys: 0.11 s against 0.29)."""
    order = np.argsort(keys, kind="stable")
    ordered = keys[order]
    first = np.empty(len(keys), bool)
    first[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    inverse = np.empty(len(keys), np.intp)
    inverse[order] = np.cumsum(first) - 1
    return ordered[first], inverse


def _common_set(fine: AnimationSpaceModel, coarse: AnimationSpaceModel, mapped: np.ndarray):
    """p^l and p^{l+1}(mapped) on the union of their bones per fine vertex (bones ascending)."""
    vf = fine.vertex_of_each_influence()
    counts = np.diff(coarse.offsets)[mapped]
    starts = coarse.offsets[mapped]
    index = np.repeat(starts - np.concatenate(([0], np.cumsum(counts)[:-1])), counts) + np.arange(counts.sum())
    vc = np.repeat(np.arange(len(mapped)), counts)
    b = fine.bone_count
    keys = np.concatenate((vf.astype(np.int64) * b + fine.bones, vc.astype(np.int64) * b + coarse.bones[index]))
    unique, inverse = _unique_inverse(keys)
    p = np.zeros((len(unique), 4))
    q = np.zeros((len(unique), 4))
    # bones are distinct within a vertex: each (vertex, bone) key comes at most once from each side
    p[inverse[:len(vf)]] = fine.coordinates
    q[inverse[len(vf):]] = coarse.coordinates[index]
    vertex = (unique // b).astype(np.int64)
    offsets = np.zeros(fine.vertex_count + 1, np.int32)
    np.cumsum(np.bincount(vertex, minlength=fine.vertex_count), out=offsets[1:])
    model = AnimationSpaceModel(offsets, (unique % b).astype(np.int32), p, b)
    return model, q - p


def checked_targets(targets, name: str) -> dict:
    """{"triangles": [...]} and/or {"influences": [...]}: lists of whole numbers, alike in length."""
    if not isinstance(targets, dict) or not targets or set(targets) - {"triangles", "influences"}:
        raise SkinkitError(f"{name}: expected {{'triangles': [...]}} and/or {{'influences': [...]}}, got "
                           f"{type(targets).__name__}")
    lists = {}
    for key, values in targets.items():
        if isinstance(values, (str, bytes)) or not hasattr(values, "__len__"):
            raise SkinkitError(f"{name}[{key!r}]: expected a list of counts, got {type(values).__name__}")
        lists[key] = [count(1)(value, f"{name}[{key!r}][{index}]") for index, value in enumerate(values)]
    if len({len(values) for values in lists.values()}) != 1:
        raise SkinkitError(f"{name}: the lists must have one entry per level after the first, alike in length")
    return lists


@checked(model=AnimationSpaceModel, levels=count(1, MAX_LEVELS), simplify_influences=FLAG,
         targets=optional(checked_targets), progress=CALLBACK, collapse=checked_collapse,
         influence_cost_scale=checked_cost_scale, rank_per_influence=FLAG, start_influences=optional(count(1)),
         refit=FLAG, threads=THREADS)
def build_chain(triangles, rest_positions, model: AnimationSpaceModel, statistics, *, uv=None, charts=None,
                materials=None, locked_edges=None, levels: int = 4, metric: str = "animation",
                simplify_influences: bool = True, targets: dict | None = None, collapse: str = DEFAULT_COLLAPSE,
                influence_cost_scale: float = DEFAULT_INFLUENCE_COST_SCALE, rank_per_influence: bool = True,
                start_influences: int | None = None, refit: bool = True, threads: int = 0,
                progress=None) -> LodChain:
    """Builds `levels` discrete levels (level 0 is the input), each with at most half the influences of the one
    before, or to `targets` ({"triangles": [...]} and/or {"influences": [...]}, one entry per level after the
    first). uv: 6 per triangle (per-corner UVs, as skinkit.unwrap gives them) or None (no atlas constraints);
    charts, materials: per triangle; locked_edges: (E, 2) vertex pairs kept as features. Stops early, with a
    warning, when no legal collapse remains.

    collapse: "half" (the default: half-edge collapses, the thesis), "full" (interior edges also re-solve the
    survivor's coordinates to the least APS cost) or "auto" (the half-edge target, its survivor re-solved). Ranking
    in the queue: rank_per_influence (the default, measured in BENCHMARKS.md) ranks an edge collapse at its cost over
    the square root of the influences it removes, so collapses go by squared cost per influence removed, as an
    influence budget asks (False: by cost, the thesis); influence_cost_scale multiplies the influence collapses'
    rank (1: as costed; the default 2 keeps influences a little longer). start_influences (the
    engine's per-vertex budget, e.g. 4): level 0 is the model first limited to that many influences per vertex
    (skinkit.lod.limit_influences), its epsilon the largest correction; the levels after it halve from there.
    refit (animation metric only): each level's coordinates are then refitted to the input's surface
    (refit_level), its triangles and influence sets unchanged; epsilon stays the collapses' largest cost.
    threads (0: one per core): the collapses' costing runs on two threads when there are (by default from 16,384
    influences, where it pays), the refit on all; the chain is the same bits on any count."""
    rest = as_real_array(rest_positions, "rest_positions", shape=(None, 3))
    tris = as_index_array(triangles, "triangles", shape=(None, 3))
    vertex_count = len(rest)
    if not isinstance(model, AnimationSpaceModel):
        raise SkinkitError("model: expected an AnimationSpaceModel")
    if model.vertex_count != vertex_count:
        raise SkinkitError(f"model: has {model.vertex_count} vertices but rest_positions has {vertex_count}")
    if not isinstance(statistics, PoseStatistics):
        raise SkinkitError(f"statistics: expected a skinkit.metrics.PoseStatistics, got {type(statistics).__name__}")
    if statistics.bone_count != model.bone_count:
        raise SkinkitError(f"statistics: has {statistics.bone_count} bones but the model has {model.bone_count} "
                           "(stale pose statistics?)")
    if not isinstance(metric, str) or metric not in METRICS:
        raise SkinkitError(f"metric: expected 'animation' or 'rest', got {metric!r}")
    if len(tris) == 0:
        raise SkinkitError("triangles: the mesh has no triangles")
    if tris.min() < 0 or tris.max() >= vertex_count:
        raise SkinkitError(f"triangles: vertex indices must lie in [0, {vertex_count})")
    _memory.check_lod_chain(vertex_count, len(tris), model.influence_count, threads, collapse)
    chain_warnings: list[str] = []
    if uv is None:
        chain_warnings.append("no UVs: built without atlas constraints (parameter space is a planar projection of "
                              "each one-ring; seams and charts are not preserved)")
        if charts is not None:
            chain_warnings.append("charts ignored without UVs")
            charts = None
    else:
        uv = as_real_array(uv, "uv").reshape(-1)
        if uv.size != 6 * len(tris):
            raise SkinkitError(f"uv: expected 6 values per triangle ({6 * len(tris)}), got {uv.size}")
        charts = _uv_charts(tris, uv) if charts is None else as_index_array(charts, "charts", shape=(len(tris),))
    if materials is not None:
        materials = as_index_array(materials, "materials", shape=(len(tris),))
    locked = None
    if locked_edges is not None:
        locked_edges = as_index_array(locked_edges, "locked_edges", shape=(None, 2))
        locked = _side_flags(tris, locked_edges, vertex_count)
    if targets is None:
        plan = [{"influences": None} for _ in range(levels - 1)]
    else:
        plan = [dict(zip(targets, step)) for step in zip(*targets.values())]

    low, high = rest.min(axis=0), rest.max(axis=0)
    diagonal = float(np.linalg.norm(high - low)) or 1.0
    start_epsilon = 0.0
    full_model = model
    if start_influences is not None and int(np.diff(model.offsets).max(initial=0)) > start_influences:
        from .influences import limit_influences
        model, start_costs = limit_influences(model, statistics, start_influences)
        start_epsilon = float(start_costs.max(initial=0.0))
    offsets, bones = model.offsets.astype(np.int32), model.bones.astype(np.int32)
    coordinates = np.ascontiguousarray(model.coordinates, dtype=np.float64)
    flat_rest = rest.reshape(-1)

    def make_level(level_tris, level_uv, origin, offs, bns, crd, epsilon, report):
        vertices = np.unique(level_tris)
        local = np.searchsorted(vertices, level_tris).astype(np.int32)
        level_model = _restrict(offs, bns, crd, vertices, model.bone_count)
        level_charts = None if charts is None else charts[origin]
        return LodLevel(vertices, local, level_model, None if level_uv is None else level_uv.reshape(-1, 6).copy(),
                        level_charts, origin, float(epsilon), float(epsilon) / diagonal, report)

    refitting = refit and metric == "animation"
    simplify_share = REFIT_PROGRESS_START if refitting else 1.0
    simplify_progress = None if progress is None else (lambda fraction: progress(simplify_share * fraction))
    wanted = [(step.get("triangles", 0), step.get("influences") or 0) for step in plan]
    # the C call checks the surface (manifold, oriented, no degenerate triangle) before anything is built
    written, chain_report = simplify_levels(tris, flat_rest, offsets, bones, coordinates, statistics, targets=wanted,
                                            uv=uv, charts=charts, materials=materials, locked=locked, metric=metric,
                                            simplify_influences=simplify_influences, collapse=collapse,
                                            influence_cost_scale=influence_cost_scale,
                                            rank_per_influence=rank_per_influence, threads=threads,
                                            progress=simplify_progress)
    origin = np.arange(len(tris), dtype=np.int32)
    result = [make_level(tris, uv, origin, offsets, bones, coordinates, start_epsilon, {})]
    maps = []
    for index, out in enumerate(written):
        report = out["report"]
        if report["edge_collapses"] + report["influence_collapses"] == 0:
            chain_warnings.append(f"level {index + 1}: no legal collapse remains; stopped at {len(result)} levels")
            break
        result.append(make_level(out["triangles"], out["uv"], out["triangle_origin"], out["offsets"], out["bones"],
                                 out["coordinates"], max(report["epsilon"], start_epsilon), report))
        maps.append(out["vertex_map"])
        if report["exhausted"]:
            chain_warnings.append(f"level {index + 1}: no legal collapse remained before the target "
                                  f"({report['triangle_count']} triangles, {report['influence_count']} influences); "
                                  f"stopped at {len(result)} levels")
    else:
        if len(written) < len(plan) and not chain_report["exhausted"]:
            chain_warnings.append(f"level {len(written) + 1}: fewer than 2 influences left; stopped at {len(result)} "
                                  "levels")
    if refitting:
        _refit_levels(result[1:], tris, rest, full_model, statistics, threads, progress)
    for level, (fine, coarse, vertex_map) in enumerate(zip(result[:-1], result[1:], maps)):
        fine.to_coarser = np.searchsorted(coarse.vertices, vertex_map[fine.vertices]).astype(np.int32)
        fine.morph_model, fine.morph_delta = _common_set(fine.model, coarse.model, fine.to_coarser)
        if fine.uv is not None:
            fine.morph_uv = fine.uv
            fine.morph_delta_uv = _uv_motion(fine, coarse, fine.to_coarser) - fine.uv
    for message in chain_warnings:
        _warnings.warn(message, stacklevel=2)
    return LodChain(result, diagonal, chain_warnings)


def _refit_levels(levels: list[LodLevel], triangles, rest, model, statistics, threads, progress) -> None:
    """refit_level on each level in place, progress from REFIT_PROGRESS_START to 1 (a true return cancels)."""
    for index, level in enumerate(levels):
        step = None
        if progress is not None:
            begin = REFIT_PROGRESS_START + (1.0 - REFIT_PROGRESS_START) * index / len(levels)
            width = (1.0 - REFIT_PROGRESS_START) / len(levels)
            step = lambda fraction, begin=begin, width=width: progress(begin + width * fraction)  # noqa: E731
        level.model, level.report["refit"] = refit_level(level.triangles, rest[level.vertices], level.model,
                                                         triangles, rest, model, statistics, threads=threads,
                                                         progress=step)


def _uv_motion(fine: LodLevel, coarse: LodLevel, to_coarser: np.ndarray) -> np.ndarray:
    """Each fine corner's UV at the coarser level: its mapped vertex's UV in the same chart."""
    key_vertex = coarse.triangles.reshape(-1).astype(np.int64)
    key_chart = np.repeat(coarse.charts.astype(np.int64), 3)
    chart_span = int(max(coarse.charts.max(initial=0), fine.charts.max(initial=0))) + 1
    keys = key_vertex * chart_span + key_chart
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    corner_uv = coarse.uv.reshape(-1, 2)[order]
    want = to_coarser[fine.triangles.reshape(-1)].astype(np.int64) * chart_span + \
        np.repeat(fine.charts.astype(np.int64), 3)
    at = np.searchsorted(sorted_keys, want)
    at_clipped = np.minimum(at, len(sorted_keys) - 1)
    found = sorted_keys[at_clipped] == want
    moved = fine.uv.reshape(-1, 2).copy()
    moved[found] = corner_uv[at_clipped[found]]
    return moved.reshape(-1, 6)
