"""Skinning a mesh sequence that has no rig, on numpy arrays.

Two ways in, one result (a skeleton, bone frames per training frame, linear-blend weights and an animation-space
model fitted on top):

* `decompose`: automatic proxy bones for a requested bone count (the job Dem Bones does). Vertices are clustered by
  how they move (k-means on trajectories, then rigid k-means: each vertex joins the bone whose rigid motion carries
  it best), then weights and rigid bone transforms are updated in turn (non-negative weights summing to 1, at most
  K per vertex; each bone's exact best rotation and translation with the others fixed) until the error stops
  improving. A hierarchy is built from which clusters touch, with joints placed by eq. 4.6.
* `fit_rough_rig`: skeleton fitting from a rough rig (Merry 2007, section 4.1.4): per bone and frame the motion of
  its core vertices (affine fit, polar decomposition, translation refit), rest joints by eq. 4.6.

Frames outside the training set are replayed by `Decomposition.solve_poses`: only the bone transforms are solved,
with the fitted model held fixed.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import _core
from .fit import (DEFAULT_LAMBDA, DEFAULT_MAX_INFLUENCES, check_vertex_order, chunks, fit_animation_space, fit_errors,
                  mesh_edges, model_errors, pattern_from_mask, unit_box)
from ._checks import (CALLBACK, THREADS, as_index_array, as_mask, as_real_array, check_memory, checked, choice, count,
                      optional, real)
from .model import AnimationSpaceModel, Mesh, Skeleton, SkinkitError, SparseWeights, convert_lbs

#: The public API (what tests/fuzz/api_fuzz.py calls with hostile arguments); the rest are helpers.
__all__ = ["Decomposition", "decompose", "fit_rough_rig", "solve_sequence"]

#: How the skeleton is found: automatic proxy bones (decompose) or a drawn rough rig fitted to the sequence
#: (fit_rough_rig).
METHODS = ("automatic", "rough-rig")
#: The two models a decomposition holds (Decomposition.skinned): animation space and linear blend skinning.
KINDS = ("animation", "linear")
#: What solve_sequence's `rough` rig must give fit_rough_rig, and what it may.
ROUGH_RIG_NEEDS = {"parents", "approximate_joints_hint", "core_vertices"}
ROUGH_RIG_OPTIONS = {"names", "orientations", "regularisation", "threads", "progress"}
#: Proxy bones of an automatic decomposition, besides the static root.
DEFAULT_BONES = 16
#: Joint regulariser of eq. 4.6 in the unit box (the thesis' value).
JOINT_LAMBDA = 1e-3
#: Stop alternating weights and transforms when an iteration improves the rms error by less than this fraction,
#: or after ITERATIONS (measured on the horse and the Dem Bones sample: later iterations gain < 2% each).
CONVERGENCE = 1e-3
ITERATIONS = 12
#: Block-coordinate sweeps over the bones per transform update (training) and per replayed frame.
TRAINING_SWEEPS = 1
REPLAY_SWEEPS = 12
#: A vertex may be influenced by the bones of clusters up to this many steps from its own in the graph of touching
#: clusters (the weight update's candidates).
CANDIDATE_HOPS = 1
#: Frames used for the trajectory features of the first clustering (more add cost, not quality).
FEATURE_FRAMES = 32


@dataclass
class Decomposition:
    """A skinned mesh fitted to a sequence. Bone 0 is the static root (model space); bones 1.. are the fitted ones.

    training_poses (F, b, 4, 4): each bone's frame G_j in each training frame; rest_positions (V, 3) the rest mesh
    the linear-blend weights refer to; labels (V,) each vertex's main bone.
    """

    skeleton: Skeleton
    training_poses: np.ndarray
    linear_blend: SparseWeights
    model: AnimationSpaceModel
    rest_positions: np.ndarray
    triangles: np.ndarray
    labels: np.ndarray
    seconds: float = 0.0
    report: dict = field(default_factory=dict)
    _linear_model: AnimationSpaceModel | None = field(default=None, repr=False)

    @checked(kind=choice(KINDS))
    def skinned(self, kind: str) -> AnimationSpaceModel:
        """The model of `kind`: "animation" (animation space) or "linear" (linear blend skinning)."""
        if kind == "animation":
            return self.model
        if kind == "linear":
            if self._linear_model is None:
                self._linear_model = convert_lbs(self.skeleton, self.linear_blend, self.rest_positions)
            return self._linear_model
        raise SkinkitError(f"kind: expected 'animation' or 'linear', got {kind!r}")

    @checked(kind=choice(KINDS), threads=THREADS)
    def solve_poses(self, targets, kind: str = "animation", threads: int = 0) -> np.ndarray:
        """Bone frames (G, b, 4, 4) that best reproduce each target frame (G, V, 3) with the model held fixed."""
        targets = checked_frames(targets, self.rest_positions.shape[0], minimum=1)
        motions = cluster_motions(self.rest_positions, targets, self.labels, self.skeleton.bone_count, threads)
        poses = np.ascontiguousarray(motions @ self.skeleton.rest_frames)
        model = self.skinned(kind)
        _core.solve_rigid_poses(poses, model.offsets, model.bones, model.coordinates, targets, None, len(targets),
                                REPLAY_SWEEPS, threads)
        return poses

    @checked(kind=choice(KINDS), threads=THREADS)
    def reconstruct(self, targets, kind: str = "animation", threads: int = 0) -> np.ndarray:
        """The model's best reproduction (G, V, 3) of each target frame: poses solved, then evaluated."""
        return self.skinned(kind).evaluate(self.solve_poses(targets, kind, threads), threads=threads)

    @checked(kind=choice(KINDS))
    def errors(self, targets, kind: str = "animation") -> dict:
        """rms, mean and max distance to the targets, divided by the rest bounding-box diagonal."""
        targets = checked_frames(targets, self.rest_positions.shape[0], minimum=1)
        return fit_errors(self.reconstruct(targets, kind), targets, rest_diagonal(self.rest_positions), self.triangles)


# ---- input checks -----------------------------------------------------------------------------------------------

def checked_frames(frames, vertex_count: int | None = None, minimum: int = 2) -> np.ndarray:
    frames = np.ascontiguousarray(as_real_array(frames, "frames", shape=(None, None, 3)))
    if len(frames) < minimum:
        raise SkinkitError(f"frames: {len(frames)} frame(s) given; skinning a sequence needs at least {minimum}"
                           + (" (a single frame shows no motion)" if minimum == 2 else ""))
    if vertex_count is not None and frames.shape[1] != vertex_count:
        raise SkinkitError(f"frames: {frames.shape[1]} vertices per frame, the rest mesh has {vertex_count}")
    return frames


def rest_diagonal(rest_positions) -> float:
    return float(np.linalg.norm(np.ptp(rest_positions, axis=0))) or 1.0


def checked_inputs(frames, triangles, rest, bone_count: int, max_influences: int):
    frames = checked_frames(frames)
    rest = frames[0] if rest is None else as_real_array(rest, "rest", shape=(None, 3))
    if len(rest) != frames.shape[1]:
        raise SkinkitError(f"rest: {len(rest)} vertices, the frames have {frames.shape[1]}")
    mesh = Mesh.create(rest, triangles)
    if not 1 <= bone_count <= len(rest):
        raise SkinkitError(f"bone count {bone_count}: must be between 1 and the vertex count ({len(rest)})")
    if max_influences < 1:
        raise SkinkitError(f"max influences must be at least 1, got {max_influences}")
    if np.abs(frames - rest).max(initial=0.0) <= 1e-12 * rest_diagonal(rest):  # before any of the expensive work
        raise SkinkitError("frames: no vertex moves in any frame, so there are no bones to find")
    # the working set: boxed copies of the frames and their trajectories, and per vertex rows over the bones (their
    # candidates, errors and masks: 60 bytes per vertex and bone, measured by bench/bench_scale.py at 100k vertices,
    # 100 bones and 25 frames: a peak of 9.0 KB per vertex above the inputs; 9 bytes undercounted it 2.3x)
    check_memory(5 * frames.nbytes + len(rest) * (bone_count + 1) * 60, f"decomposing {len(frames)} frames of "
                 f"{len(rest)} vertices into {bone_count} bones", "use fewer frames (--train) or fewer bones")
    check_vertex_order(rest, frames, mesh.triangles)
    return frames, np.ascontiguousarray(rest), mesh.triangles


def in_box(transform, points):
    return np.ascontiguousarray(points * transform[0, 0] + transform[:3, 3])


# ---- clustering ------------------------------------------------------------------------------------------------

#: Bytes of the trajectory k-means' temporaries at a time: it works through the vertices in row chunks of this
#: size (each row's differences to a seed, or its distances to every centre), so they stay in cache instead of
#: being whole-mesh arrays (594 centres x 1M vertices of float32 was 2.4 GB a temporary). Rows are independent:
#: the same labels in any chunking.
CLUSTER_CHUNK_BYTES = 4 * 2**20


def row_chunks(row_count: int, bytes_per_row: int) -> list[slice]:
    return chunks(row_count, max(1, CLUSTER_CHUNK_BYTES // max(bytes_per_row, 1)))


def trajectory_clusters(rest, frames, cluster_count: int, rng, iterations: int = 12) -> np.ndarray:
    """k-means (k-means++ seeds) on each vertex's rest position and trajectory: motion-coherent, compact seeds."""
    step = max(1, len(frames) // FEATURE_FRAMES)
    features = np.concatenate([rest[None], frames[::step]]).transpose(1, 0, 2).reshape(len(rest), -1)
    features = features.astype(np.float32)
    squared = (features ** 2).sum(axis=1)
    seed_chunks = row_chunks(len(features), features.shape[1] * features.itemsize)

    def squared_distances(centre):
        out = np.empty(len(features), np.float32)
        for part in seed_chunks:
            out[part] = ((features[part] - centre) ** 2).sum(axis=1)
        return out

    centres = [features[rng.integers(len(features))]]
    nearest = squared_distances(centres[0])
    for _ in range(1, cluster_count):
        centre = features[rng.choice(len(features), p=nearest / nearest.sum())] if nearest.sum() > 0 else \
            features[rng.integers(len(features))]
        centres.append(centre)
        np.minimum(nearest, squared_distances(centre), out=nearest)
    centres = np.array(centres)
    labels = np.empty(len(features), np.int64)
    for _ in range(iterations):
        centre_squares = (centres ** 2).sum(axis=1)[None]
        for part in row_chunks(len(features), cluster_count * features.itemsize):
            distance = squared[part, None] - 2 * features[part] @ centres.T + centre_squares
            labels[part] = distance.argmin(axis=1)
        # each cluster's members in ascending order (a stable sort), as a mask would take them, found once
        order = np.argsort(labels, kind="stable")
        bounds = np.searchsorted(labels[order], np.arange(cluster_count + 1))
        for k in np.flatnonzero(bounds[1:] > bounds[:-1]):
            centres[k] = features[order[bounds[k]:bounds[k + 1]]].mean(axis=0)
    return labels.astype(np.int32)


def single_influence_model(rest, labels, bone_count: int) -> AnimationSpaceModel:
    """Each vertex rigidly on its label's bone (identity rest frames): p = (x, 1)."""
    one_each = SparseWeights(np.arange(len(rest) + 1, dtype=np.int32), labels.astype(np.int32), np.ones(len(rest)))
    return lbs_model(rest, one_each, bone_count)


def cluster_motions(rest, frames, labels, bone_count: int, threads: int = 0) -> np.ndarray:
    """Each cluster's best rigid motion (F, b, 4, 4) from the rest pose to each frame (Kabsch; bone 0 stays I)."""
    motions = np.ascontiguousarray(np.broadcast_to(np.eye(4), (len(frames), bone_count, 4, 4)))
    model = single_influence_model(rest, labels, bone_count)
    _core.solve_rigid_poses(motions, model.offsets, model.bones, model.coordinates, frames, None, len(frames), 1,
                            threads)
    return motions


def rank_bones(rest, frames, motions, allowed, candidates: int, threads: int = 0):
    best = np.empty((len(rest), candidates), np.int32)
    errors = np.empty((len(rest), candidates))
    _core.rank_bones(best, errors, rest, frames, np.ascontiguousarray(motions), allowed, len(frames), candidates,
                     threads)
    return best, errors


def keep_connected(labels, edges, bone_count: int) -> np.ndarray:
    """Each cluster keeps its largest connected piece; stray pieces join the neighbouring cluster they touch most."""
    labels = labels.copy()
    for _ in range(3):
        same = labels[edges[:, 0]] == labels[edges[:, 1]]
        component = connected_components(len(labels), edges[same])
        sizes = np.bincount(component)
        largest = np.zeros(bone_count, np.int64) - 1
        order = np.argsort(sizes[component], kind="stable")
        largest[labels[order]] = component[order]  # the last write per label is its largest piece
        stray = component != largest[labels]
        if not stray.any():
            break
        across = edges[~same]
        votes = {}
        for a, b in ((across[:, 0], across[:, 1]), (across[:, 1], across[:, 0])):
            pick = stray[a] & ~stray[b]
            for piece, label in zip(component[a[pick]], labels[b[pick]]):
                votes.setdefault(piece, {}).setdefault(label, 0)
                votes[piece][label] += 1
        new_label = {piece: max(counts, key=counts.get) for piece, counts in votes.items()}
        moved = np.array([new_label.get(c, labels[i]) for i, c in enumerate(component)])
        labels = np.where(stray, moved, labels).astype(np.int32)
    return labels


def connected_components(count: int, edges) -> np.ndarray:
    """Component of each of `count` nodes under undirected edges: the smallest node index reachable, by
    min-label propagation with pointer jumping (vectorised; rounds grow with the log of the diameter)."""
    component = np.arange(count)
    if len(edges) == 0:
        return component
    a, b = np.asarray(edges[:, 0]), np.asarray(edges[:, 1])
    while True:
        smaller = np.minimum(component[a], component[b])
        updated = component.copy()
        np.minimum.at(updated, a, smaller)
        np.minimum.at(updated, b, smaller)
        np.minimum.at(updated, component, updated)  # a root takes the best label any of its members found
        updated = updated[updated]
        if np.array_equal(updated, component):
            return component
        component = updated


def reseed_empty(labels, errors, bone_count: int) -> np.ndarray:
    """A bone left without vertices takes the worst-explained vertex of the worst cluster, and its neighbours."""
    labels = labels.copy()
    for bone in range(1, bone_count):
        if (labels == bone).any():
            continue
        totals = np.bincount(labels, errors, minlength=bone_count)
        worst = int(np.argmax(totals))
        members = np.flatnonzero(labels == worst)
        if len(members) < 2:
            continue
        seed = members[np.argmax(errors[members])]
        labels[seed] = bone
    return labels


def rigid_kmeans(rest, frames, labels, edges, bone_count: int, iterations: int, threads: int):
    """Rigid k-means: each cluster's best rigid motion, then each vertex to the bone that carries it best (pieces
    cut off from their cluster rejoin a neighbour). Returns labels, each vertex's best and second-best errors."""
    allowed = not_root(len(rest), bone_count)
    for _ in range(iterations):
        motions = cluster_motions(rest, frames, labels, bone_count, threads)
        best, errors = rank_bones(rest, frames, motions, allowed, 2, threads)
        updated = reseed_empty(keep_connected(best[:, 0], edges, bone_count), errors[:, 0], bone_count)
        if np.array_equal(updated, labels):
            break
        labels = updated
    motions = cluster_motions(rest, frames, labels, bone_count, threads)
    own = rank_bones(rest, frames, motions, single_bone_allowed(labels, bone_count), 1, threads)[1][:, 0]
    return labels.astype(np.int32), own, errors


def single_bone_allowed(labels, bone_count: int) -> np.ndarray:
    allowed = np.zeros((len(labels), bone_count), np.uint8)
    allowed[np.arange(len(labels)), labels] = 1
    return allowed


class RigidStatistics:
    """Sums over a cluster's vertices that fix its best rigid motion per frame and that motion's error (Kabsch):
    adding two clusters' sums gives their union's, so merge costs need no pass over the vertices."""

    def __init__(self, rest, frames, labels, cluster_count: int):
        """labels: 0..cluster_count-1, every cluster non-empty."""
        order = np.argsort(labels, kind="stable")
        starts = np.searchsorted(labels[order], np.arange(cluster_count))
        rest = rest[order]
        self.count = np.bincount(labels, minlength=cluster_count).astype(float)
        self.rest_sum = np.add.reduceat(rest, starts, axis=0)
        self.rest_square = np.add.reduceat((rest ** 2).sum(axis=1), starts)
        self.frame_sum = np.empty((cluster_count, len(frames), 3))
        self.frame_square = np.empty((cluster_count, len(frames)))
        self.cross = np.empty((cluster_count, len(frames), 3, 3))
        for index, frame in enumerate(frames):
            frame = frame[order]
            self.frame_sum[:, index] = np.add.reduceat(frame, starts, axis=0)
            self.frame_square[:, index] = np.add.reduceat((frame ** 2).sum(axis=1), starts)
            self.cross[:, index] = np.add.reduceat(frame[:, :, None] * rest[:, None, :], starts, axis=0)

    def error(self, clusters) -> np.ndarray:
        """Rigid-fit error of the union of each row of `clusters` (an index array, (..., k))."""
        n = self.count[clusters].sum(-1)
        sx = self.rest_sum[clusters].sum(-2)
        sv = self.frame_sum[clusters].sum(-3)
        centred = self.cross[clusters].sum(-4) - sv[..., :, None] * sx[..., None, None, :] / n[..., None, None, None]
        singular = np.linalg.svd(centred, compute_uv=False)
        singular[..., 2] *= np.sign(np.linalg.det(centred))
        spread = (self.frame_square[clusters].sum(-2) - (sv ** 2).sum(-1) / n[..., None]
                  + (self.rest_square[clusters].sum(-1) - (sx ** 2).sum(-1) / n)[..., None])
        return (spread - 2 * singular.sum(-1)).sum(-1)

    def merge(self, keep: int, gone: int) -> None:
        for name in ("count", "rest_sum", "rest_square", "frame_sum", "frame_square", "cross"):
            values = getattr(self, name)
            values[keep] += values[gone]
            values[gone] = 0


def merge_clusters(rest, frames, labels, edges, target: int) -> np.ndarray:
    """Agglomerative merging of touching clusters (after Wang et al., as in Feng chapter 2): the pair whose union's
    best rigid motion adds the least error goes first, until `target` clusters are left. Labels 0..n-1 in, 0..target-1
    out."""
    cluster_count = int(labels.max()) + 1
    statistics = RigidStatistics(rest, frames, labels, cluster_count)
    own = statistics.error(np.arange(cluster_count)[:, None])
    a, b = labels[edges[:, 0]], labels[edges[:, 1]]
    pairs = {(int(min(x, y)), int(max(x, y))) for x, y in zip(a[a != b], b[a != b])}
    neighbours = {k: set() for k in range(cluster_count)}
    for x, y in pairs:
        neighbours[x].add(y)
        neighbours[y].add(x)
    costs = pair_costs(statistics, own, list(pairs))
    alive = cluster_count
    while alive > target:
        if not costs:  # separate pieces of the mesh: let any two clusters merge
            living = np.unique(labels)
            costs = pair_costs(statistics, own, [(int(x), int(y)) for k, x in enumerate(living) for y in living[k + 1:]])
        keep, gone = min(costs, key=costs.get)
        statistics.merge(keep, gone)
        labels = np.where(labels == gone, keep, labels)
        own[keep] = statistics.error(np.array([[keep]]))[0]
        for other in neighbours.pop(gone):
            neighbours[other].discard(gone)
            if other != keep:
                neighbours[other].add(keep)
                neighbours[keep].add(other)
        neighbours[keep].discard(keep)
        costs = {pair: cost for pair, cost in costs.items() if keep not in pair and gone not in pair}
        costs.update(pair_costs(statistics, own, [(min(keep, o), max(keep, o)) for o in neighbours[keep]]))
        alive -= 1
    return np.unique(labels, return_inverse=True)[1].astype(np.int32)


def pair_costs(statistics: RigidStatistics, own, pairs) -> dict:
    if not pairs:
        return {}
    index = np.array(pairs)
    increase = statistics.error(index) - own[index].sum(axis=1)
    return dict(zip(pairs, increase.tolist()))


def rigid_clusters(rest, frames, edges, bone_count: int, rng, iterations: int = 8, oversegment: int = 6,
                   threads: int = 0):
    """Labels 1..b-1 (bone 0 is the static root): a fine trajectory k-means, merged down by rigid error
    (merge_clusters), then refined by rigid k-means."""
    fine = min(len(rest), oversegment * (bone_count - 1))
    labels = trajectory_clusters(rest, frames, fine, rng)
    labels = keep_connected(labels, edges, fine)
    sampled = frames[::max(1, len(frames) // FEATURE_FRAMES)]  # merge costs need the motion's gist, not every frame
    labels = merge_clusters(rest, sampled, np.unique(labels, return_inverse=True)[1], edges, bone_count - 1) + 1
    return rigid_kmeans(rest, frames, labels, edges, bone_count, iterations, threads)[0]


# ---- weights and transforms ------------------------------------------------------------------------------------

def pattern_from_ranked(best) -> tuple[np.ndarray, np.ndarray]:
    valid = best >= 0
    offsets = np.zeros(len(best) + 1, np.int32)
    np.cumsum(valid.sum(axis=1), out=offsets[1:])
    return offsets, best[valid].astype(np.int32)


def nnls_weights(rest, frames, motions, offsets, bones, threads) -> np.ndarray:
    weights = np.empty(len(bones))
    _core.fit_lbs_weights(weights, offsets, bones, np.ascontiguousarray(motions).reshape(-1), frames.reshape(-1),
                          len(frames), rest, threads)
    return weights


def update_weights(rest, frames, motions, labels, edges, bone_count: int, max_influences: int,
                   threads: int = 0) -> SparseWeights:
    """Non-negative weights summing to 1 over the bones of nearby clusters, at most max_influences per vertex."""
    touching = cluster_adjacency(labels, edges, bone_count) > 0
    reach = np.eye(bone_count, dtype=bool)
    for _ in range(CANDIDATE_HOPS):
        reach = reach | (reach.astype(np.int32) @ touching.astype(np.int32) > 0)
    allowed = reach[labels]
    allowed[:, 0] = False
    candidates = min(bone_count - 1, max_influences + 2)
    best, _ = rank_bones(rest, frames, motions, allowed.astype(np.uint8), candidates, threads)
    offsets, bones = pattern_from_ranked(best)
    weights = nnls_weights(rest, frames, motions, offsets, bones, threads)
    if candidates > max_influences:
        dense = np.full(best.shape, -1.0)
        dense[best >= 0] = weights
        keep = np.argsort(-dense, axis=1, kind="stable")[:, :max_influences]
        chosen = np.take_along_axis(best, keep, axis=1)
        chosen[np.take_along_axis(dense, keep, axis=1) <= 0] = -1
        chosen[:, 0] = np.take_along_axis(best, keep[:, :1], axis=1)[:, 0]  # never empty
        offsets, bones = pattern_from_ranked(chosen)
        weights = nnls_weights(rest, frames, motions, offsets, bones, threads)
    return SparseWeights(offsets, bones, weights)


def lbs_model(rest, weights: SparseWeights, bone_count: int) -> AnimationSpaceModel:
    coordinates = np.column_stack([rest, np.ones(len(rest))])[weights.vertex_of_each_influence()]
    return AnimationSpaceModel(weights.offsets, weights.bones, coordinates * weights.weights[:, None], bone_count)


def update_motions(motions, rest, frames, weights, bone_count: int, threads: int = 0):
    """Each bone's best rigid transforms with the weights fixed; returns them and the rms error after."""
    model = lbs_model(rest, weights, bone_count)
    motions = np.ascontiguousarray(motions)
    frame_errors = np.empty(len(frames))
    _core.solve_rigid_poses(motions, model.offsets, model.bones, model.coordinates, frames, frame_errors, len(frames),
                            TRAINING_SWEEPS, threads)
    return motions, float(np.sqrt(frame_errors.sum() / (len(frames) * frames.shape[1])))


def alternate(rest, frames, motions, labels, edges, bone_count, max_influences, iterations, threads, progress):
    """Weights, then transforms, in turn; stops when the rms error improves by less than CONVERGENCE."""
    history = []
    weights = None
    for iteration in range(iterations):
        weights = update_weights(rest, frames, motions, labels, edges, bone_count, max_influences, threads)
        motions, error = update_motions(motions, rest, frames, weights, bone_count, threads)
        history.append(error)
        if progress is not None and progress(0.2 + 0.6 * (iteration + 1) / iterations):
            raise SkinkitError("cancelled")
        if len(history) > 1 and history[-2] - error < CONVERGENCE * history[-2]:
            break
    return weights, motions, history


# ---- skeleton ----------------------------------------------------------------------------------------------------

def cluster_adjacency(labels, edges, bone_count: int) -> np.ndarray:
    """(b, b) count of mesh edges joining each pair of clusters."""
    a, b = labels[edges[:, 0]], labels[edges[:, 1]]
    across = a != b
    adjacency = np.zeros((bone_count, bone_count))
    np.add.at(adjacency, (a[across], b[across]), 1)
    return adjacency + adjacency.T


def spanning_tree(adjacency) -> np.ndarray:
    """Parents of bones 1..b-1 by a maximum spanning tree over touching clusters (Prim), rooted at the cluster with
    the most contact (the body's centre); clusters touching nothing hang from the static root 0."""
    bone_count = len(adjacency)
    parents = np.zeros(bone_count, np.int32)
    parents[0] = -1
    placed = np.zeros(bone_count, bool)
    placed[0] = True
    while not placed.all():
        free = np.flatnonzero(~placed)
        root = free[np.argmax(adjacency[np.ix_(free, free)].sum(axis=1))]
        placed[root] = True
        parents[root] = 0
        while True:
            links = np.where(placed[:, None] & ~placed[None, :], adjacency, 0.0)
            links[0] = 0.0
            if links.max() <= 0:
                break
            parent, child = np.unravel_index(np.argmax(links), links.shape)
            parents[child] = parent
            placed[child] = True
    return parents


def approximate_joints(rest, labels, edges, parents) -> np.ndarray:
    """Where each bone meets its parent: the centroid of the vertices on edges joining the two clusters (the
    cluster's centroid for bones hanging from the root)."""
    joints = np.zeros((len(parents), 3))
    for bone in range(1, len(parents)):
        members = labels == bone
        joints[bone] = rest[members].mean(axis=0) if members.any() else rest.mean(axis=0)
        parent = parents[bone]
        if parent <= 0:
            continue
        a, b = labels[edges[:, 0]], labels[edges[:, 1]]
        border = ((a == bone) & (b == parent)) | ((a == parent) & (b == bone))
        if border.any():
            joints[bone] = rest[np.unique(edges[border])].mean(axis=0)
    return joints


def bone_frames(joints, tails) -> np.ndarray:
    """Rest frames (b, 4, 4) with origin at each joint and Y along the bone (how Blender orients bones)."""
    frames = np.eye(4)[None].repeat(len(joints), 0)
    for bone in range(1, len(joints)):
        y = tails[bone] - joints[bone]
        length = np.linalg.norm(y)
        y = y / length if length > 1e-12 else np.array([0.0, 1.0, 0.0])
        helper = np.array([0.0, 0.0, 1.0]) if abs(y[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        x = np.cross(y, helper)
        x /= np.linalg.norm(x)
        z = np.cross(x, y)
        frames[bone, :3, :3] = np.column_stack([x, y, z])
        frames[bone, :3, 3] = joints[bone]
    return frames


def bone_tails(rest, labels, joints, parents) -> np.ndarray:
    """Each bone points from its joint to its cluster's centroid (or to its children's joints, when it has any)."""
    tails = joints.copy()
    diagonal = rest_diagonal(rest)
    for bone in range(1, len(joints)):
        children = np.flatnonzero(parents == bone)
        members = labels == bone
        target = joints[children].mean(axis=0) if len(children) else \
            (rest[members].mean(axis=0) if members.any() else joints[bone])
        if np.linalg.norm(target - joints[bone]) < 0.02 * diagonal:
            target = joints[bone] + np.array([0.0, 0.0, 0.05 * diagonal])
        tails[bone] = target
    return tails


def skeleton_from_motions(rest, motions, labels, edges, parents, names=None, joint_hints=None, orientations=None):
    """Skeleton (rest frames with joints from eq. 4.6) for the rest mesh, in its own units; motions are rest->frame.
    orientations (b, 3, 3), when given (a drawn rig's bones), keep their axes; else Y points along each bone."""
    transform = unit_box(rest)
    inverse = np.linalg.inv(transform)
    boxed_motions = np.ascontiguousarray(transform @ motions @ inverse)
    hints = approximate_joints(rest, labels, edges, parents) if joint_hints is None else joint_hints
    boxed_joints = np.empty((len(parents), 3))
    _core.fit_rest_joints(boxed_joints, boxed_motions, parents, in_box(transform, hints), JOINT_LAMBDA)
    joints = (boxed_joints - transform[:3, 3]) / transform[0, 0]
    joints[0] = 0.0
    frames = bone_frames(joints, bone_tails(rest, labels, joints, parents))
    if orientations is not None:
        frames[1:, :3, :3] = orientations[1:]
    names = names or ("root",) + tuple(f"proxy_{bone:02d}" for bone in range(1, len(parents)))
    return Skeleton.create(parents, frames, names), joints


# ---- the animation-space fit on top ------------------------------------------------------------------------------

#: The animation-space model is refined by this many rounds of its fit with the bone frames fixed, then a rigid
#: re-solve of the bone frames with the model fixed (REFIT_SWEEPS block-coordinate sweeps): the linear-blend frames
#: are not the best ones for the animation-space model. Measured on the horse gallop at 30 bones, K = 4 (the setting
#: of bench/decompose_literature.py, λ = 1e-6): E_RMS 0.45 after one round, 0.34 after two, 0.31 after three.
REFIT_ROUNDS = 3
REFIT_SWEEPS = 4


def animation_influences(rest, frames, motions, weights: SparseWeights, bone_count: int, max_influences: int,
                         threads: int = 0) -> SparseWeights:
    """The animation-space model's influence sets: the linear-blend weights' bones (most have 2-3 of the K allowed:
    the non-negative weights are sparse), filled up to max_influences with the bones whose rigid motion best
    carries the vertex; returned as the linear-blend weights on them (0 on the added bones), the fit's prior. With
    too few frames for K influences' unknowns the weights' own sets are kept."""
    vertex_count = len(rest)
    if 3 * len(frames) < 4 * max_influences - 1:  # too few frames to determine more unknowns: keep the weights' sets
        return weights
    ranked, _ = rank_bones(rest, frames, motions, not_root(vertex_count, bone_count), min(max_influences,
                                                                                          bone_count - 1), threads)
    # rows over every bone a chunk of vertices at a time (rows are independent: the same sets in any chunking); for
    # the whole mesh they were five (V, b) temporaries, 0.8 GB each at 1M vertices and 100 bones, the peak of decompose
    offsets, bones, prior = [np.zeros(1, np.int32)], [], []
    for part in row_chunks(vertex_count, bone_count * 8):
        chunk_offsets, chunk_bones, chunk_prior = influences_of_rows(weights, ranked, part.start,
                                                                     min(part.stop, vertex_count), bone_count,
                                                                     max_influences)
        offsets.append(chunk_offsets[1:] + offsets[-1][-1])
        bones.append(chunk_bones)
        prior.append(chunk_prior)
    return SparseWeights(np.concatenate(offsets), np.concatenate(bones), np.concatenate(prior))


def influences_of_rows(weights: SparseWeights, ranked, begin: int, end: int, bone_count: int, max_influences: int):
    """animation_influences' sets for vertices begin..end-1: (offsets from 0, bones, prior weights)."""
    first, last = weights.offsets[begin], weights.offsets[end]
    rows = np.arange(end - begin)
    dense = np.zeros((end - begin, bone_count))
    dense[np.repeat(rows, np.diff(weights.offsets[begin:end + 1])), weights.bones[first:last]] = \
        weights.weights[first:last]
    mask = dense > 0
    score = dense.copy()  # the weighted bones first, then the added ones in rank order
    ranked = ranked[begin:end]
    for rank in range(ranked.shape[1]):
        valid = ranked[:, rank] >= 0
        mask[rows[valid], ranked[valid, rank]] = True
        score[rows[valid], ranked[valid, rank]] += 1e-9 * (ranked.shape[1] - rank)
    pattern = pattern_from_mask(mask, score, max_influences)
    return pattern.offsets, pattern.bones, dense[pattern.vertex_of_each_influence(), pattern.bones]


def fit_on_top(skeleton, rest, frames, weights, poses, max_influences, regularisation, threads):
    """The animation-space model on its own influence sets (animation_influences), pulled towards the linear-blend
    fit, refined by REFIT_ROUNDS rounds of fit and rigid re-solve of the frames. Returns it, its poses (F, b, 4, 4)
    and the first fit's report (the chosen λ, or the fall-back to linear blend skinning)."""
    motions = np.ascontiguousarray(poses @ np.linalg.inv(skeleton.rest_frames))
    transform = unit_box(rest)
    boxed_motions = transform @ motions @ np.linalg.inv(transform)
    prior_weights = animation_influences(in_box(transform, rest), in_box(transform, frames), boxed_motions, weights,
                                         skeleton.bone_count, max_influences, threads)
    prior = convert_lbs(skeleton, prior_weights, rest)
    lam, first_report, poses = (DEFAULT_LAMBDA if regularisation is None else regularisation), None, poses.copy()
    for round_index in range(REFIT_ROUNDS):
        result = fit_animation_space(poses, frames, prior_weights, skeleton.bone_count, method="per-vertex",
                                     regularisation=lam, rest_positions=rest, rest_frames=skeleton.rest_frames,
                                     prior=prior, threads=threads, bone_names=skeleton.names,
                                     validate=round_index == 0)
        first_report = first_report or result.report
        lam = result.report["lambda"]
        if lam is None:  # the validation fell back to linear blend skinning: its frames are already the best
            break
        model = result.model
        _core.solve_rigid_poses(poses, model.offsets, model.bones, model.coordinates, frames, None, len(frames),
                                REFIT_SWEEPS, threads)
    return result.model, poses, first_report


def finish(skeleton, motions, weights, labels, rest, frames, triangles, max_influences, regularisation, threads,
           started, report):
    lbs_poses = np.ascontiguousarray(motions @ skeleton.rest_frames)
    model, poses, fit_report = fit_on_top(skeleton, rest, frames, weights, lbs_poses, max_influences, regularisation,
                                          threads)
    diagonal, every_frame = rest_diagonal(rest), np.ones(len(frames), bool)
    predictions = {"animation_space": lambda: model.evaluate(poses, threads=threads),
                   "linear_blend": lambda: lbs_model(rest, weights, skeleton.bone_count).evaluate(motions,
                                                                                                threads=threads)}
    for name, predict in predictions.items():  # one model's (frames, V, 3) positions alive at a time
        report.update(model_errors({name: predict()}, frames, every_frame, diagonal))
    report.update(regularisation_lambda=fit_report.get("lambda"), fallback=bool(fit_report.get("fallback")),
                  animation_influences=int(np.diff(model.offsets).max(initial=0)))
    return Decomposition(skeleton, poses, weights, model, rest, triangles, labels, time.perf_counter() - started, report)


def skin_clusters(rest, boxed_rest, boxed_frames, transform, labels, count: int, edges, max_influences: int,
                  iterations: int, threads: int, progress):
    """From vertex labels (0 the static root, 1..count-1 the bones, in the unit box `transform` makes): the alternating
    weight/transform solve and the skeleton. Returns (skeleton, motions in the mesh's units, weights, main bone per
    vertex, the solve's rms history in the box). progress(0.2) is asked first and may cancel."""
    if progress is not None and progress(0.2):
        raise SkinkitError("cancelled")
    motions = cluster_motions(boxed_rest, boxed_frames, labels, count, threads)
    weights, motions, history = alternate(boxed_rest, boxed_frames, motions, labels, edges, count, max_influences,
                                          iterations, threads, progress)
    main_bone = main_bones(weights)
    motions = np.linalg.inv(transform) @ motions @ transform
    parents = spanning_tree(cluster_adjacency(main_bone, edges, count))
    skeleton, _ = skeleton_from_motions(rest, motions, main_bone, edges, parents)
    return skeleton, motions, weights, main_bone, history


@checked(bone_count=count(1), max_influences=count(1), iterations=count(1, 10000),
         regularisation=optional(real(minimum=0)), threads=THREADS, seed=count(0, 2**63 - 1), progress=CALLBACK)
def decompose(frames, triangles, *, bone_count: int, max_influences: int = DEFAULT_MAX_INFLUENCES, rest=None,
              iterations: int = ITERATIONS, regularisation: float | None = None, threads: int = 0, seed: int = 0,
              progress=None) -> Decomposition:
    """Automatic proxy bones: `bone_count` bones (plus the static root 0) skinning the training frames (F, V, 3).

    rest (V, 3) is the mesh the weights refer to (default frames[0]). regularisation is the animation-space fit's
    λ (see skinkit.fit.DEFAULT_LAMBDA). progress(fraction) may return True to cancel.
    """
    started = time.perf_counter()
    frames, rest, triangles = checked_inputs(frames, triangles, rest, bone_count, max_influences)
    edges = mesh_edges(triangles)
    transform = unit_box(rest)
    boxed_rest = in_box(transform, rest)
    boxed_frames = in_box(transform, frames)
    count = bone_count + 1
    labels = rigid_clusters(boxed_rest, boxed_frames, edges, count, np.random.default_rng(seed), threads=threads)
    skeleton, motions, weights, main_bone, history = skin_clusters(rest, boxed_rest, boxed_frames, transform, labels,
                                                                   count, edges, max_influences, iterations,
                                                                   threads, progress)
    del boxed_rest, boxed_frames  # finish boxes what it needs: kept, they doubled the frames at its peak (0.6 GB at 1M)
    report = {"method": "automatic", "bones": bone_count, "max_influences": max_influences,
              "iterations": len(history), "rms_history": [h / transform[0, 0] / rest_diagonal(rest) for h in history]}
    return finish(skeleton, motions, weights, main_bone, rest, frames, triangles, max_influences, regularisation,
                  threads, started, report)


@checked(bones=count(1), max_influences=count(1), rough=optional(dict), progress=CALLBACK)
def solve_sequence(frames, triangles, train, *, bones: int = DEFAULT_BONES,
                   max_influences: int = DEFAULT_MAX_INFLUENCES, rough=None, progress=None):
    """The whole job on a sequence: fit on frames[train] (automatic bones, or `rough`: a dict of fit_rough_rig's
    rig arguments), then replay every frame with the model fixed. frames[0] is the rest pose. Returns the
    decomposition, the poses {"animation", "linear"} (F, b, 4, 4) solved for every frame, the replays they give
    (F, V, 3) and the error report."""
    frames = checked_frames(frames)
    train = as_mask(train, "train", len(frames))
    if rough is not None and not ROUGH_RIG_NEEDS <= set(rough) <= ROUGH_RIG_NEEDS | ROUGH_RIG_OPTIONS:
        raise SkinkitError(f"rough: expected the rig arguments {sorted(ROUGH_RIG_NEEDS)} (and optionally "
                           f"{sorted(ROUGH_RIG_OPTIONS)}), got {sorted(map(str, rough))}")
    if train.sum() < 2:
        raise SkinkitError(f"{int(train.sum())} training frame(s): at least two are needed")
    if rough is None:
        result = decompose(frames[train], triangles, bone_count=bones, max_influences=max_influences, rest=frames[0],
                           progress=progress)
    else:
        result = fit_rough_rig(frames[train], triangles, max_influences=max_influences, rest=frames[0], **rough)
    poses = {kind: result.solve_poses(frames, kind) for kind in ("animation", "linear")}
    replay = {kind: result.skinned(kind).evaluate(poses[kind]) for kind in poses}
    return result, poses, replay, sequence_report(result, frames, train, replay)


def sequence_report(result: Decomposition, frames, train, replay: dict) -> dict:
    """Errors (rms, mean, max over the rest diagonal) of both models on the training and held-out frames, from
    replay[kind] (F, V, 3): every frame reproduced with its poses solved and the model fixed."""
    report = {"vertices": int(frames.shape[1]), "frames": int(len(frames)), "training_frames": int(train.sum()),
              "examples": int(train.sum()), "held_out": int((~train).sum()),
              "bones": int(result.skeleton.bone_count - 1), "decompose_seconds": result.seconds}
    predictions = {"animation_space": replay["animation"], "linear_blend": replay["linear"]}
    report.update(model_errors(predictions, frames, train, rest_diagonal(result.rest_positions), result.triangles))
    return report


def main_bones(weights: SparseWeights) -> np.ndarray:
    """Each vertex's most heavily weighted bone."""
    order = np.lexsort((-weights.weights, weights.vertex_of_each_influence()))
    return weights.bones[order[weights.offsets[:-1]]].astype(np.int32)


@checked(core_vertices=(list, tuple), names=optional((list, tuple)), max_influences=count(1),
         regularisation=optional(real(minimum=0)), threads=THREADS, progress=CALLBACK)
def fit_rough_rig(frames, triangles, parents, approximate_joints_hint, core_vertices, *, names=None,
                  orientations=None, max_influences: int = DEFAULT_MAX_INFLUENCES, rest=None,
                  regularisation: float | None = None, threads: int = 0, progress=None) -> Decomposition:
    """Skeleton fitting from a rough rig (section 4.1.4): parents (b,) with bone 0 the static root, approximate
    joint positions (b, 3) and, per bone 1.., a list of core vertices that move rigidly with it."""
    started = time.perf_counter()
    parents = as_index_array(parents, "parents", (None,))
    _core.validate_skeleton(parents, None)
    count = len(parents)
    frames, rest, triangles = checked_inputs(frames, triangles, rest, max(count - 1, 1), max_influences)
    if len(core_vertices) != count:
        raise SkinkitError(f"core vertices: {len(core_vertices)} sets for {count} bones (bone 0, the root, included)")
    core_vertices = [as_index_array(core, f"core_vertices[{bone}]", (None,)) for bone, core in enumerate(core_vertices)]
    if orientations is not None:
        orientations = as_real_array(orientations, "orientations", shape=(count, 3, 3))
    offsets = np.zeros(count + 1, np.int32)
    np.cumsum([len(core) for core in core_vertices], out=offsets[1:])
    cores = np.ascontiguousarray(np.concatenate(core_vertices))
    if len(cores) and (cores.min() < 0 or cores.max() >= len(rest)):
        raise SkinkitError(f"core vertices: indices must be in [0, {len(rest)})")
    motions = np.empty((len(frames), count, 4, 4))
    _core.fit_core_motions(motions, offsets, cores, rest, frames, len(frames))
    labels = np.zeros(len(rest), np.int32)
    for bone, core in enumerate(core_vertices):
        labels[np.asarray(core, np.int64)] = bone
    edges = mesh_edges(triangles)
    skeleton, _ = skeleton_from_motions(rest, motions, labels, edges, parents, names,
                                        as_real_array(approximate_joints_hint, "approximate joints", shape=(count, 3)),
                                        orientations)
    transform = unit_box(rest)
    boxed_rest, boxed_frames = in_box(transform, rest), in_box(transform, frames)
    boxed_motions = transform @ motions @ np.linalg.inv(transform)
    nearest = rank_bones(boxed_rest, boxed_frames, boxed_motions, not_root(len(rest), count), 1, threads)[0][:, 0]
    labels = np.where(labels > 0, labels, nearest).astype(np.int32)
    weights = update_weights(boxed_rest, boxed_frames, boxed_motions, labels, edges, count, max_influences, threads)
    del boxed_rest, boxed_frames  # as in decompose
    report = {"method": "rough-rig", "bones": count - 1, "max_influences": max_influences}
    return finish(skeleton, motions, weights, main_bones(weights), rest, frames, triangles, max_influences,
                  regularisation, threads, started, report)


def not_root(vertex_count: int, bone_count: int) -> np.ndarray:
    allowed = np.ones((vertex_count, bone_count), np.uint8)
    allowed[:, 0] = 0
    return allowed
