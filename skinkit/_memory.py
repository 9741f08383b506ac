"""Up-front memory estimates of the fits, the metrics and the LOD stages (bytes), each checked against the budget
(skinkit._checks.check_memory) before the operation's first large allocation.

Each estimate adds up the large arrays the operation holds at once, in the Python layer and in the C core, from
the sizes that drive them, plus FIXED_BYTES for what does not grow (thread stacks' touched pages, LAPACK work,
numpy's small temporaries). tests/core/test_memory_estimates.py measures each one's resident-set growth at two
sizes and holds the estimate within 0.7x..2x of it.
"""
from __future__ import annotations

import os

from ._checks import check_memory

FIXED_BYTES = 2 * 2**20
#: SparseVectors.combined forms its scaled side this many entries at a time (32 MiB of 4-vectors)
COMBINE_CHUNK = 1 << 20
DOUBLE = 8
#: The C fits' working data per influence (rows of the normal equations, the per-thread factorisations' share).
LBS_BYTES_PER_INFLUENCE = 72
#: The cross-validation of the per-vertex fit works through the vertices in chunks of at most this many influences
#: and this many example coordinates (skinkit.fit.vertex_chunks): 16 MiB of fold priors, 8 MiB an examples copy.
VALIDATION_CHUNK_INFLUENCES = 2**17
VALIDATION_CHUNK_VALUES = 2**20
#: A chunk's per-influence temporaries: 4 folds' priors (4 doubles each), the linear-blend fit's rows, the points.
VALIDATION_BYTES_PER_INFLUENCE = 4 * 4 * DOUBLE + LBS_BYTES_PER_INFLUENCE + 4 * DOUBLE
#: The validation's scores per vertex: one per candidate λ (skinkit.fit.VALIDATION_FACTORS).
VALIDATION_SCORES = 7
#: fit_animation_space's per-influence arrays after the solve: the coordinates in two spaces at a time while they
#: are mapped from the box to the bones' frames (those frames are gathered a bounded chunk at a time), the prior.
FIT_BYTES_PER_INFLUENCE = 3 * 4 * DOUBLE
#: The global fit's C solve holds about this many dense (unknowns x unknowns) blocks per vertex (its normal
#: equations' diagonal blocks and their factors, for the preconditioner); it does not grow with the examples.
GLOBAL_BLOCKS_PER_VERTEX = 1.5
#: The largest-weight projection of limit_influences forms its dense systems a chunk of rows at a time: about
#: this many (n x n) doubles per row of a chunk (n = 4 x the widest influence set): the gathered metric, its scaled
#: copy, the KKT system and LAPACK's copy.
PROJECTION_MATRICES = 3.4
#: What one chunk of the projection's dense systems may hold (projection_chunk_rows).
PROJECTION_CHUNK_BYTES = 16 * 2**20
#: The projection's per-slot arrays of the vertices over the limit (w slots each): the padded coordinates, their
#: correction and corrected copy, the bones, weights, ranks and masks, and the projected model's rows.
PROJECTION_BYTES_PER_SLOT = 3 * 4 * DOUBLE + 4 * 8 + 4 + 4 * DOUBLE
LIMIT_FIXED_BYTES = 8 * 2**20
#: build_chain's C simplifier: the quadrics, the per-influence collapse state and the levels written (400 bytes an
#: influence), and its caches: each one-ring's metric rows, for up to CHAIN_ROW_SLOTS vertices, with the factors of
#: their bone sets (1,600 bytes a vertex: with these constants the estimate is 1.5-1.7x the measured peak of
#: half-edge chains at 2,000, 8,000 and 20,000 vertices, 1.4x the horse's 8-influence chain, 1.2x the 134k one),
#: and the influence remover's kept splits and preprocessings (up to 16 MiB each). Collapses that re-solve the
#: survivor ("full", "auto") also keep the queued collapses' moves (4 doubles an influence) and their bases (2,048
#: slots: 3.5-6.5 MB more than half-edge collapses at 2,000-20,000 vertices, measured).
CHAIN_BYTES_PER_INFLUENCE = 400
CHAIN_BYTES_PER_RING = 1600
CHAIN_ROW_SLOTS = 16384  # ROW_SLOTS_MAX in csrc/offline/lod/sk_progressive.c: change both together
CHAIN_FIXED_BYTES = 18 * 2**20
CHAIN_FULL_BYTES_PER_INFLUENCE = 4 * DOUBLE
CHAIN_FULL_FIXED_BYTES = 6 * 2**20
#: The second costing thread's own factor and basis caches (the fixed bytes' share of them) and vertex marks, from
#: HELPER_MIN_INFLUENCES in csrc/offline/lod/sk_progressive.c (threads=0), or threads >= 2.
CHAIN_HELPER_FIXED_BYTES = 8 * 2**20
CHAIN_HELPER_MIN_INFLUENCES = 16384
#: refit_level (sk_lod_refit): per full-detail triangle its sample and its three level contributions (52 bytes); per
#: level triangle the BVH over the level (its share of nodes, order and corner blocks, about 160 bytes); per level
#: influence the CG vectors and the result (6 x 4 doubles); per level vertex its sample-mass row (about 7 neighbours
#: and itself) with its scale, ridge and set (150 bytes); the influence sets' inverses, at most REFIT_INVERSE_BUDGET
#: (FACTOR_BUDGET in csrc/offline/lod/sk_refit.c: change both together), and the influence remover's P blocks.
REFIT_BYTES_PER_TRIANGLE = 52
REFIT_BYTES_PER_LEVEL_TRIANGLE = 160
REFIT_BYTES_PER_INFLUENCE = 6 * 4 * DOUBLE
REFIT_BYTES_PER_VERTEX = 150
REFIT_INVERSE_BUDGET = 64 * 2**20
REFIT_FIXED_BYTES = 4 * 2**20
REFIT_BYTES_PER_SOURCE_VERTEX = DOUBLE + 2 * 4
#: SK_MAX_WORKERS in csrc/common/sk_internal.h
MAX_WORKERS = 64
#: The distances' C loops hold only per-thread scratch.
DISTANCES_FIXED_BYTES = 128 * 2**10


def row_count(value) -> int:
    """len(value) for a sized argument (None or anything else: 0); the argument's own check comes later."""
    try:
        return 0 if value is None else len(value)
    except TypeError:
        return 0


def examples_bytes(example_count: int, vertex_count: int) -> int:
    """One (examples, vertices, 3) copy of the examples in float64."""
    return example_count * vertex_count * 3 * DOUBLE


def check_fit_lbs(vertex_count: int, influence_count: int, example_count: int) -> float:
    """fit_lbs: the boxed examples and the C fit's per-influence rows."""
    needed = FIXED_BYTES + examples_bytes(example_count, vertex_count) + influence_count * LBS_BYTES_PER_INFLUENCE
    check_memory(needed, f"the linear-blend fit of {vertex_count} vertices to {example_count} examples",
                 "fit fewer examples or a lower-resolution mesh")
    return needed


def fit_animation_space_bytes(method: str, vertex_count: int, influence_count: int, example_count: int,
                              triangle_count: int, validate: bool) -> float:
    edge_count = 3 * triangle_count // 2  # a closed surface's; an open one has a few more
    # the boxed examples and, while it is made, their copy with the rest pose appended (the fit keeps only that);
    # then that copy and the coordinates
    examples = examples_bytes(example_count + 1, vertex_count)
    needed = FIXED_BYTES + examples + max(examples, influence_count * FIT_BYTES_PER_INFLUENCE)
    if validate:  # one chunk's examples (and their kept and rest-pose copies) and fold priors; the scores
        chunk_vertices = min(vertex_count, max(1, VALIDATION_CHUNK_VALUES // (3 * max(example_count, 1))))
        needed += 3 * examples_bytes(example_count + 1, chunk_vertices) + vertex_count * VALIDATION_SCORES * DOUBLE \
            + min(influence_count, VALIDATION_CHUNK_INFLUENCES) * VALIDATION_BYTES_PER_INFLUENCE
    if method == "global":  # first each edge's endpoints in every example, then (freed by then) the C solve's blocks
        unknowns = 4 * influence_count / max(vertex_count, 1)
        needed += max(3 * examples_bytes(example_count, edge_count),
                      GLOBAL_BLOCKS_PER_VERTEX * vertex_count * unknowns * unknowns * DOUBLE)
    return needed


def check_fit_animation_space(method: str, vertex_count: int, influence_count: int, example_count: int,
                              triangle_count: int, validate: bool) -> float:
    needed = fit_animation_space_bytes(method, vertex_count, influence_count, example_count, triangle_count, validate)
    check_memory(needed, f"the {method} animation-space fit of {vertex_count} vertices to {example_count} examples",
                 "fit fewer examples, fewer influences per vertex or a lower-resolution mesh"
                 + (", or use the per-vertex method" if method == "global" else ""))
    return needed


def check_pose_statistics(sample_count: int, bone_count: int) -> float:
    """PoseStatistics from sampled frames: the parents' frames, the local matrices, LAPACK's batched copies."""
    needed = FIXED_BYTES + 3 * sample_count * bone_count * 16 * DOUBLE
    check_memory(needed, f"pose statistics of {sample_count} sampled poses of {bone_count} bones",
                 "sample fewer poses")
    return needed


def check_distances(vector_count: int, bone_count: int, cached_blocks: bool) -> float:
    """mean_distance / max_distance: the result, and (mean, first call) the cache of P's b x b blocks."""
    blocks = bone_count * bone_count * (16 * DOUBLE + 1) if cached_blocks else 0
    needed = DISTANCES_FIXED_BYTES + vector_count * DOUBLE + blocks
    check_memory(needed, f"the distances of {vector_count} vectors", "measure fewer vectors at once")
    return needed


def check_vector_rows(entry_count: int) -> float:
    """SparseVectors.rows: the gathered entries' indices (int64), bones and 4-vectors."""
    needed = DISTANCES_FIXED_BYTES + entry_count * (8 + 2 * 4 + 4 * DOUBLE)
    check_memory(needed, f"{entry_count} vector entries", "take the rows of fewer vertices at once")
    return needed


def check_combined_vectors(entry_count: int) -> float:
    """SparseVectors.combined: each entry's place (int64, with the repeat and range that make one side's), the bones
    and 4-vectors written there (entry_count: both sides' entries together), and one chunk of the scaled side."""
    chunk = min(entry_count, COMBINE_CHUNK) * 4 * DOUBLE
    needed = DISTANCES_FIXED_BYTES + chunk + entry_count * (2 * 8 + 4 + 4 * DOUBLE)
    check_memory(needed, f"combining {entry_count} vector entries", "combine fewer vectors at once")
    return needed


def projection_chunk_rows(widest: int) -> int:
    """Rows of limit_influences' largest-weight projection whose dense systems fit PROJECTION_CHUNK_BYTES."""
    n = 4 * max(widest, 1)
    return max(1, int(PROJECTION_CHUNK_BYTES // (PROJECTION_MATRICES * (n + 1) * (n + 1) * DOUBLE)))


def check_limit_influences(vertex_count: int, influence_count: int, over_count: int, widest: int,
                           largest_weights: bool) -> float:
    """limit_influences: the limited copy of the model, and the largest-weight projection of the vertices over
    (their padded slots, and one chunk of dense systems)."""
    needed = LIMIT_FIXED_BYTES + influence_count * 2 * (4 * DOUBLE + 4) + vertex_count * 3 * DOUBLE
    if largest_weights and over_count:
        n = 4 * widest
        chunk = min(over_count, projection_chunk_rows(widest))
        needed += (over_count * widest * PROJECTION_BYTES_PER_SLOT +
                   PROJECTION_MATRICES * chunk * (n + 1) * (n + 1) * DOUBLE)
    check_memory(needed, f"limiting the influences of {over_count} of {vertex_count} vertices",
                 "limit a lower-resolution mesh, or pass largest_weights=False")
    return needed


def check_lod_refit(level_vertices: int, level_triangles: int, level_influences: int, set_entries: int,
                    triangle_count: int, vertex_count: int, threads: int = 0) -> float:
    """refit_level: the samples of the full detail, the BVH over the level and the CG over its coordinates.
    set_entries: the sum of (4n)^2 over the level's distinct influence sets (n bones each); vertex_count: the full
    detail's, of which each worker keeps a weight, a stamp and a place (REFIT_BYTES_PER_SOURCE_VERTEX)."""
    inverses = min(REFIT_INVERSE_BUDGET, set_entries * DOUBLE)
    workers = max(1, min(threads or os.cpu_count() or 1, MAX_WORKERS))
    needed = (REFIT_FIXED_BYTES + triangle_count * REFIT_BYTES_PER_TRIANGLE +
              level_triangles * REFIT_BYTES_PER_LEVEL_TRIANGLE + level_influences * REFIT_BYTES_PER_INFLUENCE +
              level_vertices * REFIT_BYTES_PER_VERTEX + inverses +
              workers * vertex_count * REFIT_BYTES_PER_SOURCE_VERTEX)
    check_memory(needed, f"refitting a level of {level_influences} influences to {triangle_count} triangles",
                 "build the chain with refit=False (skinkit lod --no-refit), or simplify a lower-resolution mesh")
    return needed


def check_lod_chain(vertex_count: int, triangle_count: int, influence_count: int, threads: int = 0,
                    collapse: str = "half") -> float:
    """build_chain: the C simplifier's state and the levels it writes (with its second costing thread's caches, and
    the full collapses' state unless `collapse` is "half")."""
    needed = (CHAIN_FIXED_BYTES + influence_count * CHAIN_BYTES_PER_INFLUENCE +
              min(vertex_count, CHAIN_ROW_SLOTS) * CHAIN_BYTES_PER_RING)
    if collapse != "half":
        needed += CHAIN_FULL_FIXED_BYTES + influence_count * CHAIN_FULL_BYTES_PER_INFLUENCE
    if threads >= 2 or (threads == 0 and influence_count >= CHAIN_HELPER_MIN_INFLUENCES):
        needed += CHAIN_HELPER_FIXED_BYTES + 4 * vertex_count
    check_memory(needed, f"an LOD chain of {triangle_count} triangles and {influence_count} influences",
                 "simplify a lower-resolution mesh, or split it into parts")
    return needed
