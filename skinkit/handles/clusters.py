"""Proxy bones by hierarchical triangle clustering (Feng 2010, section 2.3, after Wang et al. 2007).

Every triangle starts as a cluster and touching clusters are merged bottom-up, cheapest first, the cost being the
rigid-fit error the merge adds (vertex prediction error plus edge prediction error, in C:
sk_triangle_cluster_merges). One run gives the whole merge order, so every bone count is a cut of it
(`TriangleHierarchy.labels`). The cut's triangle clusters become vertex clusters (each vertex joins the cluster of
most of its triangles), refined by decompose's rigid k-means, and then get decompose's weights and transforms.
"""
from __future__ import annotations

import time

import numpy as np

from .. import _core
from .._checks import CALLBACK, SkinkitError, as_index_array, as_real_array, check_memory, checked, count, real
from ..decompose import (FEATURE_FRAMES, ITERATIONS, checked_inputs, finish, in_box, rest_diagonal, rigid_kmeans,
                         skin_clusters)
from ..fit import mesh_edges, unit_box

#: The proxy-bone clusterings a rig can be trained with: decompose's (trajectory k-means, merged by rigid error,
#: rigid k-means) and the hierarchical triangle clustering.
CLUSTERINGS = ("rigid", "hierarchical")
#: Weight of the edge prediction error beside the vertex prediction error (both squared lengths, so the ratio is
#: unit-free). The thesis gives no value.
DEFAULT_EDGE_WEIGHT = 1.0
#: Rigid k-means rounds after the cut (0 keeps the hierarchy's clusters as they are).
REFINE_ITERATIONS = 8


class TriangleHierarchy:
    """The merge order of one clustering run: merges (T - 1, 2) [kept, absorbed] and their costs (T - 1,)."""

    def __init__(self, merges, costs, triangle_count: int):
        self.merges, self.costs, self.triangle_count = merges, costs, triangle_count

    @checked(cluster_count=count(1))
    def labels(self, cluster_count: int) -> np.ndarray:
        """Each triangle's cluster 0..cluster_count-1 after the first triangle_count - cluster_count merges."""
        if cluster_count > self.triangle_count:
            raise SkinkitError(f"cluster count {cluster_count}: must be between 1 and the triangle count "
                               f"({self.triangle_count})")
        parent = np.arange(self.triangle_count)
        for kept, absorbed in self.merges[:self.triangle_count - cluster_count]:
            parent[absorbed] = kept
        # Clusters are named by a triangle: follow each chain to its root (a merge only ever points at a live root).
        while True:
            grand = parent[parent]
            if np.array_equal(grand, parent):
                break
            parent = grand
        return np.unique(parent, return_inverse=True)[1].astype(np.int32)


@checked(edge_weight=real(minimum=0), progress=CALLBACK)
def triangle_hierarchy(rest, frames, triangles, edge_weight: float = DEFAULT_EDGE_WEIGHT,
                       progress=None) -> TriangleHierarchy:
    """The hierarchical clustering's merge order on rest (V, 3) and the examples frames (E, V, 3) (at most
    FEATURE_FRAMES of them, evenly spaced, are used: the costs need the motion's gist, not every frame).
    progress(fraction) may return True to cancel."""
    rest = np.ascontiguousarray(as_real_array(rest, "rest", shape=(None, 3)))
    frames = as_real_array(frames, "frames", shape=(None, len(rest), 3))
    triangles = np.ascontiguousarray(as_index_array(triangles, "triangles", shape=(None, 3)))
    if len(frames) == 0 or len(triangles) == 0:
        raise SkinkitError(f"{len(frames)} frames and {len(triangles)} triangles: the clustering needs at least "
                           "one of each")
    sampled = np.ascontiguousarray(frames[::max(1, -(-len(frames) // FEATURE_FRAMES))])
    # Each cluster's sums: 5 numbers plus 13 per example (sk_triangle_clusters.c), twice for the union scratch and
    # the neighbour lists and heap beside them.
    check_memory(2.0 * len(triangles) * (5 + 13 * len(sampled)) * 8, "the triangle clustering's sums",
                 "decimate the mesh or use clustering='rigid'")
    merges = np.empty((len(triangles) - 1, 2), np.int32)
    costs = np.empty(len(triangles) - 1)
    _core.triangle_cluster_merges(merges, costs, triangles, rest, sampled, float(edge_weight), progress)
    return TriangleHierarchy(merges, costs, len(triangles))


def vertex_labels(triangle_labels, triangles, vertex_count: int, cluster_count: int) -> np.ndarray:
    """Each vertex in the cluster of most of its triangles (the lowest cluster among equals); vertices on no
    triangle in cluster 0 (the rigid k-means after moves them to the bone that carries them best)."""
    votes = np.zeros((vertex_count, cluster_count), np.int32)
    np.add.at(votes, (triangles.ravel(), np.repeat(triangle_labels, 3)), 1)
    return votes.argmax(axis=1).astype(np.int32)


def refined_labels(rest, frames, triangles, edges, hierarchy: TriangleHierarchy, bone_count: int, refine: int,
                   threads: int = 0) -> np.ndarray:
    """Each vertex's proxy bone 1..bone_count (0 is the static root): the hierarchy's cut, per vertex, then refine
    rounds of rigid k-means."""
    labels = vertex_labels(hierarchy.labels(bone_count), triangles, len(rest), bone_count) + 1
    if refine:
        labels = rigid_kmeans(np.ascontiguousarray(rest, dtype=float), np.ascontiguousarray(frames, dtype=float),
                              labels, edges, bone_count + 1, refine, threads)[0]
    return labels


def hierarchical_decomposition(frames, triangles, rest, bone_count: int, max_influences: int,
                               hierarchy: TriangleHierarchy | None = None, edge_weight: float = DEFAULT_EDGE_WEIGHT,
                               refine: int | None = None, threads: int = 0, progress=None):
    """skinkit.decompose's result with the proxy bones cut from the triangle hierarchy (given, or built here) at
    bone_count clusters: the same weights, transforms, skeleton and report otherwise. refine: rigid k-means rounds
    after the cut (default REFINE_ITERATIONS)."""
    started = time.perf_counter()
    refine = REFINE_ITERATIONS if refine is None else refine
    frames, rest, triangles = checked_inputs(frames, triangles, rest, bone_count, max_influences)
    if bone_count > len(triangles):
        raise SkinkitError(f"bones {bone_count}: the mesh has only {len(triangles)} triangles to cluster")
    if hierarchy is None:
        hierarchy = triangle_hierarchy(rest, frames, triangles, edge_weight, progress=None if progress is None else
                                       (lambda fraction: progress(0.2 * fraction)))
    edges = mesh_edges(triangles)
    transform = unit_box(rest)
    boxed_rest, boxed_frames = in_box(transform, rest), in_box(transform, frames)
    count = bone_count + 1
    labels = refined_labels(boxed_rest, boxed_frames, triangles, edges, hierarchy, bone_count, refine, threads)
    skeleton, motions, weights, main_bone, history = skin_clusters(rest, boxed_rest, boxed_frames, transform, labels,
                                                                   count, edges, max_influences, ITERATIONS,
                                                                   threads, progress)
    diagonal_scale = transform[0, 0] * rest_diagonal(rest)
    report = {"method": "hierarchical", "bones": bone_count, "max_influences": max_influences,
              "iterations": len(history), "rms_history": [h / diagonal_scale for h in history],
              "refine_iterations": refine, "edge_weight": edge_weight}
    return finish(skeleton, motions, weights, main_bone, rest, frames, triangles, max_influences, None, threads,
                  started, report)
