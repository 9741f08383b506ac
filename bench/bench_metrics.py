"""The animation-space metrics: skinkit's C core vs vectorised numpy equivalents, on one synthetic rig.

    cd /work/main && .venv/bin/python bench/bench_metrics.py \
        [--bones 100] [--frames 1000] [--vertices 100000] [--pairs 1000000] [--rounds 5] \
        [--json bench/metrics_results.json] [--markdown bench/metrics_results.md]

No bpy. Seeded data (bench/metrics_data.py): a tree skeleton (a spine with limbs of 4 bones branching off it),
`--frames` sampled poses (every joint rotated about a random axis by up to 30 degrees, times its rest
orientation; fixed bone translations), and an animation-space model of `--vertices` vertices scattered on
tubes around the bones, 4 influences each (the vertex's bone and its nearest bones in the tree).
On that data it times, in interleaved rounds (shuffled order each round, median reported):
  1. P for all bones from the sampled frames: skinkit from_local_samples + .matrix(), or + b^2 .block(j, k)
     calls; numpy forward kinematics + the same per-joint statistics + the same common-ancestor recursion,
     all vectorised; and numpy's full sample average of G_j^T G_k (one GEMM), which is a different matrix
     (it does not assume independent joints): only its diagonal blocks must agree.
  2. The L2,2 norm (mean_distance) of `--pairs` differences p_a - p_b of random vertex pairs, sparse over the
     union of the two influence sets: skinkit (block cache cold and warm) vs numpy grouping the vectors by
     influence pattern (one dense quadratic form per pattern), and vs numpy gathering blocks per slot pair.
  3. The L2,inf bound (max_distance) of every vertex relative to the rest centroid, and of the pairs: skinkit
     vs numpy propagating the spheres bone by bone (deepest first), vectorised over the vectors.
Every numpy result is checked against skinkit's (relative to the largest value); diagnostics break the
skinkit calls into their C and numpy parts and run them on one thread.
"""
from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import time

import numpy as np

from skinkit import _core
from skinkit.metrics import PoseStatistics, SparseVectors


from common import machine_info, machine_line, parallel_speedup, write_outputs
from metrics_data import minus_centre, pair_differences, sampled_local, skinned_model, tree_skeleton

MAX_ANGLE_DEGREES = 30.0
INFLUENCES = 4


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


# --------------------------------------------------------------------------------------------------
# numpy equivalents (each takes what the skinkit call takes, and does all of the work itself).


def parents_first(parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth of every bone, and the bones ordered by depth (root first)."""
    depth = np.zeros(len(parents), int)
    for bone in range(1, len(parents)):
        walker = bone
        while walker != 0:
            walker = parents[walker]
            depth[bone] += 1
    return depth, np.argsort(depth, kind="stable")


def forward_kinematics(local: np.ndarray, parents: np.ndarray, order: np.ndarray) -> np.ndarray:
    """G_j = G_parent L_j for every frame, G_0 = I: (S, b, 4, 4)."""
    world = np.empty_like(local)
    world[:, 0] = np.eye(4)
    for bone in order[1:]:
        np.matmul(world[:, parents[bone]], local[:, bone], out=world[:, bone])
    return world


def numpy_full_average(local: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """The (4b, 4b) sample average of G_j^T G_k over the frames (no independence assumed): one GEMM."""
    _, order = parents_first(parents)
    world = forward_kinematics(local, parents, order)
    frames, bones = local.shape[:2]
    stacked = world.transpose(0, 2, 1, 3).reshape(frames * 4, bones * 4)  # rows (s, a), columns (j, c)
    return stacked.T @ stacked / frames


def numpy_independent_p(local: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """skinkit's P, all blocks: E[L_j] over the frames and E[G_j^T G_j] = E[L_j^T E[G_p^T G_p] L_j] (the
    independent-joints model, parents first), then P_jk = X_aj^T E[G_a^T G_a] X_ak with a the lowest common
    ancestor and X_aj the product of E[L] from a down to j (eq. 3.7-3.8)."""
    depth, order = parents_first(parents)
    frames, bones = local.shape[:2]
    expected_local = local.mean(axis=0)
    expected_local[0] = np.eye(4)
    gram = np.tile(np.eye(4), (bones, 1, 1))
    for bone in order[1:]:
        joint = local[:, bone]
        gram[bone] = (joint.transpose(0, 2, 1) @ (gram[parents[bone]] @ joint)).mean(axis=0)
    ancestors = np.zeros((bones, bones), bool)  # ancestors[j, a]: a is j or above it
    paths = np.zeros((bones, bones, 4, 4))      # paths[a, j] = X_aj where a is an ancestor of j
    for bone in order:
        if bone != 0:
            ancestors[bone] = ancestors[parents[bone]]
            np.matmul(paths[:, parents[bone]], expected_local[bone], out=paths[:, bone])
        ancestors[bone, bone] = True
        paths[bone, bone] = np.eye(4)
    common_ancestors = ancestors[:, None, :] & ancestors[None, :, :]
    lca = np.argmax(np.where(common_ancestors, depth, -1), axis=2)
    j, k = np.indices((bones, bones))
    blocks = paths[lca, j].swapaxes(-1, -2) @ (gram[lca] @ paths[lca, k])
    return blocks.transpose(0, 2, 1, 3).reshape(4 * bones, 4 * bones)


def padded_rows(offsets: np.ndarray, bones: np.ndarray, coordinates: np.ndarray):
    """Compressed rows as (n, width) bones (padding: 0) and (n, width, 4) coordinates (padding: 0)."""
    counts = np.diff(offsets)
    n, width = len(counts), int(counts.max(initial=1))
    row = np.repeat(np.arange(n), counts)
    slot = np.arange(len(bones)) - np.repeat(offsets[:-1], counts)
    padded_bones = np.zeros((n, width), np.int64)
    padded_bones[row, slot] = bones
    padded_coordinates = np.zeros((n, width, 4))
    padded_coordinates[row, slot] = coordinates
    return padded_bones, padded_coordinates, counts


def numpy_mean_grouped(p: np.ndarray, offsets, bones, coordinates) -> np.ndarray:
    """s^T P s (before the square root) of every vector, grouping the vectors by their bone pattern: one
    (n, 4w) @ (4w, 4w) product per pattern. Padding slots hold bone 0 with a zero vector."""
    padded_bones, dense, counts = padded_rows(offsets, bones, coordinates)
    n, width = padded_bones.shape
    # The pattern as one int64 key (bones + 1 in 7-bit digits, padding 0) when it fits, else as bytes.
    bits = max(int(p.shape[0] // 4).bit_length(), 1)
    slot = np.arange(width)
    if bits * width <= 62:
        key = ((np.where(slot < counts[:, None], padded_bones + 1, 0)) << (bits * slot)).sum(axis=1)
    else:
        key = np.ascontiguousarray(np.where(slot < counts[:, None], padded_bones + 1, 0)).view(
            np.dtype((np.void, 8 * width))).ravel()
    order = np.argsort(key, kind="stable")
    ordered = key[order]
    starts = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]])
    ends = np.r_[starts[1:], n]
    quadratic = np.empty(n)
    flat = dense.reshape(n, 4 * width)
    component = np.arange(4)
    for begin, end in zip(starts, ends):
        rows = order[begin:end]
        index = (4 * padded_bones[rows[0]][:, None] + component).ravel()
        vectors = flat[rows]
        quadratic[rows] = np.einsum("nk,nk->n", vectors @ p[np.ix_(index, index)], vectors)
    return quadratic


def numpy_mean_slots(p: np.ndarray, offsets, bones, coordinates, chunk: int = 65536) -> np.ndarray:
    """s^T P s of every vector, as sum over slot pairs (i, j) of s_i . P[b_i, b_j] s_j with the blocks gathered
    for a chunk of vectors at a time: general (no repeated patterns needed), but a 4x4 gather per pair."""
    bone_count = p.shape[0] // 4
    blocks = p.reshape(bone_count, 4, bone_count, 4).transpose(0, 2, 1, 3)
    padded_bones, dense, _ = padded_rows(offsets, bones, coordinates)
    n, width = padded_bones.shape
    quadratic = np.empty(n)
    for begin in range(0, n, chunk):
        slot_bones, slot_vectors = padded_bones[begin:begin + chunk], dense[begin:begin + chunk]
        total = np.zeros(len(slot_bones))
        for i in range(width):
            product = np.zeros((len(slot_bones), 4))
            for j in range(width):
                product += np.einsum("nab,nb->na", blocks[slot_bones[:, i], slot_bones[:, j]], slot_vectors[:, j])
            total += np.einsum("na,na->n", slot_vectors[:, i], product)
        quadratic[begin:begin + chunk] = total
    return quadratic


def numpy_max_distance(parents, linear_bound, centre, radius, offsets, bones, coordinates,
                       chunk: int = 16384) -> np.ndarray:
    """The sphere propagation of skinkit's max_distance (eq. 3.27-3.28), vectorised over a chunk of vectors:
    each bone's (w, v, r) as dense (b, n) arrays, pushed into the parent bone by bone, deepest first. Bones
    a vector does not reach stay zero and add nothing."""
    depth, order = parents_first(parents)
    deepest_first = order[::-1][:-1]  # without the root
    counts = np.diff(offsets)
    n, b = len(counts), len(parents)
    result = np.empty(n)
    for begin in range(0, n, chunk):
        end = min(n, begin + chunk)
        size = end - begin
        row = np.repeat(np.arange(size), counts[begin:end])
        entry = slice(offsets[begin], offsets[end])
        weight, vector, sphere = np.zeros((b, size)), np.zeros((b, 3, size)), np.zeros((b, size))
        weight[bones[entry], row] = coordinates[entry, 3]
        vector[bones[entry], :, row] = coordinates[entry, :3]
        for bone in deepest_first:
            parent, w = parents[bone], weight[bone]
            weight[parent] += w
            vector[parent] += centre[bone][:, None] * w
            sphere[parent] += (linear_bound[bone] * (np.sqrt(np.einsum("xn,xn->n", vector[bone], vector[bone]))
                                                     + sphere[bone]) + radius[bone] * np.abs(w))
        result[begin:end] = np.sqrt(np.einsum("xn,xn->n", vector[0], vector[0])) + sphere[0]
    return result


# --------------------------------------------------------------------------------------------------
# skinkit calls used by the diagnostics (the same arguments metrics.py passes, thread count chosen).


def fresh(pose_statistics: PoseStatistics) -> PoseStatistics:
    """The same statistics with an empty block cache."""
    s = pose_statistics
    return PoseStatistics(s.parents, s.expected_local, s.expected_gram, s.linear_bound, s.translation_centre,
                          s.translation_radius)


def core_mean_distance(pose_statistics: PoseStatistics, vectors: SparseVectors, threads: int) -> np.ndarray:
    out = np.empty(vectors.vertex_count)
    cache = pose_statistics._cache  # warm: filled by an earlier mean_distance of the same vectors
    _core.mean_distances(out, vectors.offsets, vectors.bones, vectors.coordinates.reshape(-1),
                         pose_statistics.expected_local.reshape(-1), pose_statistics.expected_gram.reshape(-1),
                         pose_statistics.parents, cache["blocks"], cache["cached"], threads)
    return out


def core_max_distance(pose_statistics: PoseStatistics, vectors: SparseVectors, threads: int) -> np.ndarray:
    out = np.empty(vectors.vertex_count)
    _core.max_distances(out, vectors.offsets, vectors.bones, vectors.coordinates.reshape(-1),
                        pose_statistics.parents, np.ascontiguousarray(pose_statistics.linear_bound),
                        np.ascontiguousarray(pose_statistics.translation_centre),
                        np.ascontiguousarray(pose_statistics.translation_radius), threads)
    return out


def all_blocks_in_c(pose_statistics: PoseStatistics) -> np.ndarray:
    """Every one of the b^2 blocks formed in one C call: mean_distance of a vector on all bones, cold cache."""
    b = pose_statistics.bone_count
    every = SparseVectors(np.array([0, b], np.int32), np.arange(b, dtype=np.int32), np.ones((b, 4)))
    return fresh(pose_statistics).mean_distance(every)


def spectral_bound(local: np.ndarray) -> np.ndarray:
    """The linear-part bound from_local_samples computes (np.linalg.norm ord=2 of every sampled 3x3)."""
    return np.linalg.norm(local[:, :, :3, :3], ord=2, axis=(2, 3)).max(axis=0)


# --------------------------------------------------------------------------------------------------
# Timing harness (as bench_evaluate's: one result alive at a time, interleaved shuffled rounds).


def timed_call(function):
    def run() -> dict:
        before = resource.getrusage(resource.RUSAGE_SELF)
        started = time.perf_counter()
        result = function()
        wall = time.perf_counter() - started
        after = resource.getrusage(resource.RUSAGE_SELF)
        del result
        return {"seconds": wall, "cpu_seconds": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)}
    return run


def round_robin(methods: dict, rounds: int, seed: int, warmup_rounds: int = 1) -> dict:
    samples = {name: [] for name in methods}
    names, rng = list(methods), np.random.default_rng(seed)
    for round_index in range(warmup_rounds + rounds):
        log(f"round {round_index + 1 - warmup_rounds:>2}/{rounds}")
        for name in (names[i] for i in rng.permutation(len(names))):
            sample = methods[name]()
            if round_index >= warmup_rounds:
                samples[name].append(sample)
    return samples


def summary(runs: list[dict]) -> dict:
    seconds = [r["seconds"] for r in runs]
    return {"seconds": statistics.median(seconds), "min": min(seconds), "max": max(seconds),
            "cpu_per_wall": statistics.median(r["cpu_seconds"] / r["seconds"] for r in runs), "runs": runs}


# --------------------------------------------------------------------------------------------------
# Agreement.


def relative_difference(values: np.ndarray, reference: np.ndarray) -> float:
    """max |values - reference| / max |reference|."""
    return float(np.abs(values - reference).max() / np.abs(reference).max())


def diagonal_blocks(p: np.ndarray) -> np.ndarray:
    b = p.shape[0] // 4
    blocks = p.reshape(b, 4, b, 4)
    return blocks[np.arange(b), :, np.arange(b), :]


def distinct_bone_sets(vectors: SparseVectors) -> int:
    padded_bones, _, counts = padded_rows(vectors.offsets, vectors.bones, vectors.coordinates)
    padded_bones[np.arange(padded_bones.shape[1]) >= counts[:, None]] = -1
    return len(np.unique(padded_bones, axis=0))


def checks(data: dict, pose_statistics: PoseStatistics) -> dict:
    """Every numpy result against skinkit's, plus facts about P and the bounds (untimed)."""
    local, parents = data["local"], data["parents"]
    p_skinkit = pose_statistics.matrix()
    p_numpy = numpy_independent_p(local, parents)
    p_full = numpy_full_average(local, parents)
    pairs, centred = data["pairs"], data["centred"]
    mean_skinkit = fresh(pose_statistics).mean_distance(pairs)
    grouped = numpy_mean_grouped(p_numpy, pairs.offsets, pairs.bones, pairs.coordinates)
    slots = numpy_mean_slots(p_numpy, pairs.offsets, pairs.bones, pairs.coordinates)
    bounds = (parents, pose_statistics.linear_bound, pose_statistics.translation_centre,
              pose_statistics.translation_radius)
    max_pairs, max_centred = pose_statistics.max_distance(pairs), pose_statistics.max_distance(centred)
    max_pairs_numpy = numpy_max_distance(*bounds, pairs.offsets, pairs.bones, pairs.coordinates)
    max_centred_numpy = numpy_max_distance(*bounds, centred.offsets, centred.bones, centred.coordinates)

    # P is built from the sample average of G_j^T G_j but the independent-joints recursion off the diagonal:
    # is it still positive semi-definite? And with a Gram recursion consistent with independence?
    eigenvalues = np.linalg.eigvalsh((p_skinkit + p_skinkit.T) / 2)
    order = parents_first(parents)[1]
    consistent_gram = np.tile(np.eye(4), (len(parents), 1, 1))
    for bone in order[1:]:
        consistent_gram[bone] = np.einsum("sba,bc,scd->ad", local[:, bone], consistent_gram[parents[bone]],
                                          local[:, bone], optimize=True) / len(local)
    consistent = PoseStatistics(parents, pose_statistics.expected_local, consistent_gram,
                                pose_statistics.linear_bound, pose_statistics.translation_centre,
                                pose_statistics.translation_radius)
    consistent_eigenvalues = np.linalg.eigvalsh(consistent.matrix())
    negative = np.flatnonzero(grouped < 0)
    # The weight-0 direction P is most negative on (unit length, all bones): mean_distance of it, and the RMS
    # length of G s over the sampled frames (which can never be 0 for a vector that moves).
    constraint = np.zeros(len(p_skinkit))
    constraint[3::4] = 1 / np.sqrt(len(parents))
    projector = np.eye(len(p_skinkit)) - np.outer(constraint, constraint)
    values, vectors = np.linalg.eigh(projector @ ((p_skinkit + p_skinkit.T) / 2) @ projector)
    worst = vectors[:, 0]

    # Against the sampled poses themselves, for a subset of pairs: the L2,inf bound must hold in every frame;
    # the L2,2 norm (independent joints) vs the plain RMS over the frames.
    rng = np.random.default_rng(11)
    subset = rng.choice(pairs.vertex_count, 300, replace=False)
    dense = np.zeros((len(subset), len(parents), 4))
    for row, vector in enumerate(subset):
        entries = slice(pairs.offsets[vector], pairs.offsets[vector + 1])
        dense[row, pairs.bones[entries]] = pairs.coordinates[entries]
    world = forward_kinematics(local, parents, order)
    moved = (world.transpose(0, 2, 1, 3).reshape(len(local) * 4, -1) @ dense.reshape(len(subset), -1).T)
    lengths = np.linalg.norm(moved.reshape(len(local), 4, len(subset))[:, :3], axis=1)  # (S, n)
    rms, reached = np.sqrt((lengths ** 2).mean(axis=0)), lengths.max(axis=0)
    worst_moved = (world.transpose(0, 2, 1, 3).reshape(len(local) * 4, -1) @ worst).reshape(len(local), 4)
    worst_vector = SparseVectors.from_dense(worst.reshape(1, -1, 4))
    positive = mean_skinkit[subset] > 0
    in_rest = np.linalg.norm(data["positions"][data["pair_vertices"][0]] - data["positions"][data["pair_vertices"][1]],
                             axis=1)
    return {
        "p_numpy_recursion_vs_skinkit_all_blocks": relative_difference(p_numpy, p_skinkit),
        "p_full_average_vs_skinkit_diagonal_blocks": relative_difference(diagonal_blocks(p_full),
                                                                         diagonal_blocks(p_skinkit)),
        "p_full_average_vs_skinkit_all_blocks": relative_difference(p_full, p_skinkit),
        "mean_grouped_vs_skinkit": relative_difference(np.sqrt(np.maximum(grouped, 0)), mean_skinkit),
        "mean_slots_vs_skinkit": relative_difference(np.sqrt(np.maximum(slots, 0)), mean_skinkit),
        "max_pairs_vs_skinkit": relative_difference(max_pairs_numpy, max_pairs),
        "max_centred_vs_skinkit": relative_difference(max_centred_numpy, max_centred),
        "p_eigenvalue_min": float(eigenvalues[0]), "p_eigenvalue_max": float(eigenvalues[-1]),
        "p_negative_eigenvalues": int((eigenvalues < -1e-9 * eigenvalues[-1]).sum()),
        "consistent_p_eigenvalue_min": float(consistent_eigenvalues[0]),
        "pairs_with_negative_quadratic_form": int(len(negative)),
        "pairs_skinkit_mean_distance_zero": int((mean_skinkit == 0).sum()),
        "negative_pairs_rest_distance": [float(d) for d in in_rest[negative][:10]],
        "negative_pairs_quadratic_form": [float(q) for q in grouped[negative][:10]],
        "worst_weight0_quadratic_form": float(values[0]),
        "worst_weight0_total_weight": float(worst[3::4].sum()),
        "worst_weight0_mean_distance": float(pose_statistics.mean_distance(worst_vector)[0]),
        "worst_weight0_sample_rms": float(np.sqrt((worst_moved[:, :3] ** 2).sum(axis=1).mean())),
        "worst_weight0_consistent_mean_distance": float(consistent.mean_distance(worst_vector)[0]),
        "pair_patterns": distinct_bone_sets(pairs),
        "sampled_check_pairs": len(subset),
        "max_bound_violations": int((reached > max_pairs[subset] * (1 + 1e-12)).sum()),
        "reached_over_bound_median": float(np.median(reached / max_pairs[subset])),
        "reached_over_bound_max": float(np.max(reached / max_pairs[subset])),
        "mean_vs_sample_rms_median_relative": float(np.median(np.abs(mean_skinkit[subset][positive] / rms[positive] - 1))),
        "mean_vs_sample_rms_max_relative": float(np.max(np.abs(mean_skinkit[subset][positive] / rms[positive] - 1))),
        "mean_distance_clipped_share_in_subset": float((~positive).mean()),
        "consistent_mean_vs_skinkit_max_relative": float(np.max(np.abs(
            consistent.mean_distance(pairs)[subset][positive] / mean_skinkit[subset][positive] - 1))),
    }


# --------------------------------------------------------------------------------------------------


def make_data(args) -> dict:
    rig = tree_skeleton(args.bones, seed=args.seed)
    local = sampled_local(rig, args.frames, np.radians(MAX_ANGLE_DEGREES), args.seed + 1)
    model = skinned_model(rig, args.vertices, INFLUENCES, args.seed + 2)
    pair_vertices, pair_rows = pair_differences(model, args.pairs, args.seed + 3)
    centred_rows = minus_centre(model, model.positions.mean(axis=0))
    pairs = SparseVectors.create(*pair_rows, args.bones)
    centred = SparseVectors.create(*centred_rows, args.bones)
    return {"rig": rig, "parents": rig.parents, "local": local, "positions": model.positions,
            "pair_vertices": pair_vertices, "pairs": pairs, "centred": centred,
            "facts": {"depth_max": int(rig.depth.max()), "spine_bones": int((rig.heads[1:, :2] == 0).all(axis=1).sum()),
                      "influences_per_vertex": float(np.diff(model.offsets).mean()),
                      "entries_per_pair_mean": float(np.diff(pairs.offsets).mean()),
                      "entries_per_centred_mean": float(np.diff(centred.offsets).mean())}}


def methods_for(data: dict, pose_statistics: PoseStatistics, p_numpy: np.ndarray) -> dict:
    local, parents, pairs, centred = data["local"], data["parents"], data["pairs"], data["centred"]
    s = pose_statistics
    bounds = (parents, s.linear_bound, s.translation_centre, s.translation_radius)
    b = len(parents)
    fill = fresh(s)
    fill.mean_distance(pairs)  # the warm cache the "warm" rows use
    return {
        # 1. P
        "skinkit: from_local_samples + .matrix()": lambda: PoseStatistics.from_local_samples(parents, local).matrix(),
        "skinkit: from_local_samples + b² .block(j, k)": lambda: [
            st.block(j, k) for st in [PoseStatistics.from_local_samples(parents, local)]
            for j in range(b) for k in range(b)],
        "numpy: FK + statistics + recursion (all blocks)": lambda: numpy_independent_p(local, parents),
        "numpy: FK + full sample average (GEMM)": lambda: numpy_full_average(local, parents),
        # 2. L2,2
        "skinkit: mean_distance, pairs, cold cache": lambda: fresh(s).mean_distance(pairs),
        "skinkit: mean_distance, pairs, warm cache": lambda: fill.mean_distance(pairs),
        "numpy: mean, grouped by influence pattern": lambda: numpy_mean_grouped(p_numpy, pairs.offsets, pairs.bones,
                                                                                pairs.coordinates),
        "numpy: mean, blocks gathered per slot pair": lambda: numpy_mean_slots(p_numpy, pairs.offsets, pairs.bones,
                                                                               pairs.coordinates),
        # 3. L2,inf
        "skinkit: max_distance, vertices - centre": lambda: s.max_distance(centred),
        "skinkit: max_distance, pairs": lambda: s.max_distance(pairs),
        "numpy: max, vertices - centre": lambda: numpy_max_distance(*bounds, centred.offsets, centred.bones,
                                                                    centred.coordinates),
        "numpy: max, pairs": lambda: numpy_max_distance(*bounds, pairs.offsets, pairs.bones, pairs.coordinates),
        # diagnostics
        "diag: C joint_statistics alone": lambda: _core.joint_statistics(
            np.empty((b, 4, 4)), np.empty((b, 4, 4)), np.ascontiguousarray(local).reshape(-1), parents),
        "diag: spectral-norm bound of from_local_samples (numpy)": lambda: spectral_bound(local),
        "diag: .matrix() alone": lambda: s.matrix(),
        "diag: b² .block(j, k) alone": lambda: [s.block(j, k) for j in range(b) for k in range(b)],
        "diag: all b² blocks in one C call (block cache fill)": lambda: all_blocks_in_c(s),
        "diag: numpy FK alone": lambda: forward_kinematics(local, parents, parents_first(parents)[1]),
        "diag: skinkit mean_distance, pairs, warm, 1 thread": lambda: core_mean_distance(fill, pairs, 1),
        "diag: skinkit max_distance, pairs, 1 thread": lambda: core_max_distance(s, pairs, 1),
        "diag: skinkit max_distance, vertices - centre, 1 thread": lambda: core_max_distance(s, centred, 1),
    }


# operation, skinkit method, numpy method, agreement key, note
TABLE = [
    ("P, {bones} bones from {frames} frames: statistics + all b² blocks (.matrix())",
     "skinkit: from_local_samples + .matrix()", "numpy: FK + statistics + recursion (all blocks)",
     "p_numpy_recursion_vs_skinkit_all_blocks", "all blocks"),
    ("P: statistics + b² .block(j, k) calls",
     "skinkit: from_local_samples + b² .block(j, k)", "numpy: FK + statistics + recursion (all blocks)",
     "p_numpy_recursion_vs_skinkit_all_blocks", "all blocks"),
    ("P vs numpy's full sample average of G_j^T G_k (a different P)",
     "skinkit: from_local_samples + .matrix()", "numpy: FK + full sample average (GEMM)",
     "p_full_average_vs_skinkit_diagonal_blocks", "diagonal blocks"),
    ("L2,2 of {pairs} pairs, cold block cache (numpy: grouped by pattern)",
     "skinkit: mean_distance, pairs, cold cache", "numpy: mean, grouped by influence pattern",
     "mean_grouped_vs_skinkit", ""),
    ("L2,2 of {pairs} pairs, warm block cache (numpy: grouped by pattern)",
     "skinkit: mean_distance, pairs, warm cache", "numpy: mean, grouped by influence pattern",
     "mean_grouped_vs_skinkit", ""),
    ("L2,2 of {pairs} pairs, warm (numpy: blocks gathered per slot pair)",
     "skinkit: mean_distance, pairs, warm cache", "numpy: mean, blocks gathered per slot pair",
     "mean_slots_vs_skinkit", ""),
    ("L2,inf of {vertices} vertices relative to the centroid",
     "skinkit: max_distance, vertices - centre", "numpy: max, vertices - centre", "max_centred_vs_skinkit", ""),
    ("L2,inf of {pairs} pairs", "skinkit: max_distance, pairs", "numpy: max, pairs", "max_pairs_vs_skinkit", ""),
]


def make_table(samples: dict, check: dict, setup: dict) -> list[dict]:
    rows = []
    for operation, ours, theirs, agreement, scope in TABLE:
        skinkit_s, numpy_s = samples[ours]["seconds"], samples[theirs]["seconds"]
        rows.append({"operation": operation.format(**setup), "skinkit_method": ours, "numpy_method": theirs,
                     "skinkit_seconds": skinkit_s, "numpy_seconds": numpy_s, "speedup": numpy_s / skinkit_s,
                     "agreement": check[agreement], "agreement_scope": scope or "every value",
                     "skinkit_cpu_per_wall": samples[ours]["cpu_per_wall"],
                     "numpy_cpu_per_wall": samples[theirs]["cpu_per_wall"]})
    return rows


def print_table(results: dict) -> None:
    print(f"\n{'operation':<74} {'skinkit s':>10} {'numpy s':>9} {'speedup':>8} {'agreement':>10}")
    for r in results["table"]:
        print(f"{r['operation']:<74} {r['skinkit_seconds']:>10.4f} {r['numpy_seconds']:>9.4f} "
              f"{r['speedup']:>8.2f} {r['agreement']:>10.1e}  ({r['agreement_scope']})")
    print(f"\n{'method (median s, CPU/wall)':<74} {'s':>10} {'CPU/wall':>9}")
    for name, row in results["methods"].items():
        print(f"{name:<74} {row['seconds']:>10.4f} {row['cpu_per_wall']:>9.2f}")
    print("\nchecks:")
    for key, value in results["checks"].items():
        print(f"  {key}: {value}")


def markdown_report(results: dict) -> str:
    info, setup, check, methods, facts = (results["info"], results["setup"], results["checks"], results["methods"],
                                          results["facts"])
    lines = [f"# Animation-space metrics: skinkit vs numpy ({setup['bones']} bones, {setup['frames']} frames, "
             f"{setup['vertices']} vertices, {setup['pairs']} pairs)", "",
             f"{machine_line(info)}; 1-minute load average {info['load_before']:.1f} before, "
             f"{info['load_after']:.1f} after) · python {info['python']} · numpy {info['numpy']} · "
             f"skinkit {info['skinkit']} · no bpy", "", f"`{info['command']}`", "",
             f"Data (seeded, `bench/metrics_data.py`): a tree of {setup['bones']} bones (root, a {facts['spine_bones']}-bone "
             f"spine, limbs of up to 4 bones; {facts['depth_max']} levels deep), {setup['frames']} sampled frames of "
             f"local joint matrices (each joint rotated by up to {MAX_ANGLE_DEGREES:.0f}° about a random axis times its "
             f"rest orientation, fixed translations), {setup['vertices']} vertices with "
             f"{facts['influences_per_vertex']:.0f} influences each (the vertex's bone and its tree neighbours). "
             f"Pair vectors s = p_a - p_b over the union of influences have {facts['entries_per_pair_mean']:.2f} "
             f"bones on average; vertex - centroid vectors {facts['entries_per_centred_mean']:.2f}.", "",
             f"Seconds: median of {setup['rounds']} rounds (after one warm-up round), every method once per round in "
             f"shuffled order. skinkit runs with threads=0 (one per core, as metrics.py always passes); numpy "
             f"is single-threaded except its BLAS (GEMM). Speedup = numpy seconds / skinkit seconds. Agreement = "
             f"max |numpy - skinkit| / max |skinkit| over the values compared.", "",
             "| operation | skinkit s | numpy s | speedup | agreement |", "|---|---:|---:|---:|---:|"]
    for r in results["table"]:
        scope = "" if r["agreement_scope"] == "every value" else f" ({r['agreement_scope']})"
        lines.append(f"| {r['operation']} | {r['skinkit_seconds']:.4f} | {r['numpy_seconds']:.4f} | "
                     f"{r['speedup']:.2f} | {r['agreement']:.1e}{scope} |")
    lines += ["", "Every timed method (median, range over rounds, process CPU seconds per wall second):", "",
              "| method | median s | range s | CPU / wall |", "|---|---:|---:|---:|"]
    lines += [f"| {name} | {row['seconds']:.4f} | {row['min']:.4f}–{row['max']:.4f} | {row['cpu_per_wall']:.2f} |"
              for name, row in methods.items()]
    lines += ["", "## Checks (untimed)", "",
              f"- numpy's recursion P vs skinkit's `.matrix()`: {check['p_numpy_recursion_vs_skinkit_all_blocks']:.1e} "
              f"(all blocks). numpy's full sample average vs skinkit: {check['p_full_average_vs_skinkit_diagonal_blocks']:.1e} "
              f"on the diagonal blocks, {check['p_full_average_vs_skinkit_all_blocks']:.1e} over all blocks (expected: "
              "off the diagonal skinkit assumes independent joints; these samples are independent per joint but "
              "finite, so the two agree only approximately).",
              f"- L2,inf bound vs the distance reached in each of the {setup['frames']} sampled frames, for "
              f"{check['sampled_check_pairs']} pairs: {check['max_bound_violations']} violations; reached / bound "
              f"median {check['reached_over_bound_median']:.2f}, max {check['reached_over_bound_max']:.2f}.",
              f"- L2,2 (independent joints) vs the RMS over the sampled frames, same pairs: median relative "
              f"difference {check['mean_vs_sample_rms_median_relative']:.1e}, max "
              f"{check['mean_vs_sample_rms_max_relative']:.1e}.", "",
              "## Findings", "",
              (f"- **P from `from_local_samples` is positive semi-definite**: its eigenvalues range from "
               f"{check['p_eigenvalue_min']:.3g} to {check['p_eigenvalue_max']:.3g} (zero up to rounding at the bottom); "
               f"{check['pairs_skinkit_mean_distance_zero']} of the {setup['pairs']} pairs get a mean distance of 0. "
               "(Before a fix found by this benchmark, the diagonal blocks were whole-pose sample averages and P had "
               "negative eigenvalues; skinkit now forms them in the independent-joints model, E[L_j^T E[G_p^T G_p] L_j].)"
               if check["p_negative_eigenvalues"] == 0 else
               f"- **P from `from_local_samples` is NOT positive semi-definite**: eigenvalues from "
               f"{check['p_eigenvalue_min']:.3g} ({check['p_negative_eigenvalues']} below -1e-9 x the largest)."),
              "- `from_local_samples` spends nearly all its time in numpy, not in C: the spectral-norm bound "
              "(`np.linalg.norm(ord=2)`, a batched SVD of every sampled 3x3) takes "
              f"{methods['diag: spectral-norm bound of from_local_samples (numpy)']['seconds']:.3f} s against "
              f"{methods['diag: C joint_statistics alone']['seconds']:.4f} s for the C statistics.",
              f"- Forming P block by block costs mostly Python calls: b² `.block()` calls take "
              f"{methods['diag: b² .block(j, k) alone']['seconds']:.3f} s, `.matrix()` "
              f"{methods['diag: .matrix() alone']['seconds']:.3f} s, while the same {setup['bones'] ** 2} blocks "
              f"formed in one C call (the block cache) take {methods['diag: all b² blocks in one C call (block cache fill)']['seconds']:.4f} s.",
              f"- `max_distance` on the pairs is the slowest metric per vector: "
              f"{methods['skinkit: max_distance, pairs']['seconds']:.3f} s with threads=0, "
              f"{methods['diag: skinkit max_distance, pairs, 1 thread']['seconds']:.3f} s on one thread, against "
              f"{methods['numpy: max, pairs']['seconds']:.3f} s for the single-threaded numpy propagation over all "
              f"{setup['bones']} bones. See the notes for why.",
              "", "## Notes", "",
              "- `max_distance` used to sort each vector's reached bones by depth (O(n²), about 70% of its time in a "
              "perf profile); it now walks one precomputed deepest-first order of all bones.",
              "- `mean_distance`'s serial pre-pass (checking the block cache for every entry pair of every vector, "
              "even when warm) was about 11% of its C time in the same profile; its per-vector loop does not use "
              "P's symmetry (P_kj = P_jk^T), which would halve the block products.",
              "- The numpy L2,2 version that comes close groups vectors by bone pattern; it depends on patterns "
              f"repeating (here {check['pair_patterns']} distinct bone sets among the {setup['pairs']} pairs). The general gather version is several times "
              "slower. Both use the dense P that numpy built (the recursion's, equal to skinkit's to ~1e-15).",
              "- CPU / wall counts every thread of the process, including OpenBLAS's workers, which keep polling "
              "(yielding) for a while after a BLAS call; a single-threaded numpy row can therefore show more than 1.",
              "- This is a 2-vCPU virtual machine shared with other work; the header shows how much the second core "
              "was worth and the load around the run. Rounds are interleaved so drifts hit every method alike."]
    return "\n".join(lines) + "\n"


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bones", type=int, default=100)
    parser.add_argument("--frames", type=int, default=1000)
    parser.add_argument("--vertices", type=int, default=100000)
    parser.add_argument("--pairs", type=int, default=1000000)
    parser.add_argument("--rounds", type=int, default=5, help="timed rounds over every method (median)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", help="write the results here")
    parser.add_argument("--markdown", help="write a Markdown report here")
    return parser.parse_args(argv)


def main(argv=None) -> dict:
    args = parse_args(argv)
    started = time.perf_counter()
    info = machine_info() | {"parallel_speedup_before": parallel_speedup(), "load_before": os.getloadavg()[0]}
    log("making the data ...")
    data = make_data(args)
    pose_statistics = PoseStatistics.from_local_samples(data["parents"], data["local"])
    log("checking numpy against skinkit ...")
    check = checks(data, pose_statistics)
    p_numpy = numpy_independent_p(data["local"], data["parents"])
    methods = {name: timed_call(function) for name, function in methods_for(data, pose_statistics, p_numpy).items()}
    samples = {name: summary(runs) for name, runs in round_robin(methods, args.rounds, args.seed).items()}
    info |= {"parallel_speedup_after": parallel_speedup(), "load_after": os.getloadavg()[0],
             "total_seconds": time.perf_counter() - started}
    setup = {"bones": args.bones, "frames": args.frames, "vertices": args.vertices, "pairs": args.pairs,
             "rounds": args.rounds, "seed": args.seed, "max_angle_degrees": MAX_ANGLE_DEGREES, "influences": INFLUENCES}
    results = {"info": info, "setup": setup, "facts": data["facts"], "table": make_table(samples, check, setup),
               "methods": samples, "checks": check}
    print_table(results)
    write_outputs(results, args.json, args.markdown, markdown_report)
    log(f"total {info['total_seconds']:.0f} s")
    return results


if __name__ == "__main__":
    main()
