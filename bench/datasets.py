"""Fitting problems for bench_fit.py: example meshes with their bone frames, a train/held-out split and
influence sets, loaded from ../shared/data, the Blender samples, or generated.

Every loader returns a Problem in skinkit's conventions (bone 0 the identity root, 4x4 matrices acting on
column vectors, G^e the bone frames of each frame and Ĝ the rest frames in the skeleton). The data are read
in place; nothing is copied into the repository.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field

import bpy
import numpy as np

from skinkit import Skeleton, SparseWeights, lbs_evaluate, skinning_matrices
from skinkit.blender import rig, skinning
from skinkit.blender.scene import find_skinned_mesh, transform_points
from skinkit.blender.frames import armature_modifier_only, depsgraphs_at, evaluated_positions
from skinkit.fit import fit_lbs, influences_automatic, influences_from_weights, rigid_explanation_error
from skinkit.meshio import read_obj
from skinkit.model import InfluencePattern

# One Rodrigues helper for every synthetic pose: the scale benchmark's creature generator has it (scripts/).
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts"))
from make_large_character import rotation_matrices  # noqa: E402

HOLD_OUT_EVERY = 4  # frames 3, 7, 11, ... are held out; the fits never see them
DEFAULT_MAX_INFLUENCES = 4


@dataclass
class Problem:
    name: str
    rest: np.ndarray  # (V, 3) rest positions (Ĝ's pose)
    triangles: np.ndarray  # (T, 3) int32
    skeleton: Skeleton
    poses: np.ndarray  # (F, b, 4, 4): G per frame
    frames: np.ndarray  # (F, V, 3): the example positions per frame
    held_out: np.ndarray  # (F,) bool
    influences: InfluencePattern  # used by every skinkit fit
    notes: list = field(default_factory=list)
    ground_truth_weights: np.ndarray | None = None  # (V, b), when the data were made by LBS with them

    @property
    def diagonal(self) -> float:
        return skinning.bounding_box_diagonal(self.rest)

    @property
    def train(self) -> np.ndarray:
        return ~self.held_out

    @property
    def max_influences(self) -> int:
        """The largest influence set: Dem Bones gets it as its nnz."""
        return int(self.influences.counts().max())


def every_fourth_held_out(count: int) -> np.ndarray:
    return np.arange(count) % HOLD_OUT_EVERY == HOLD_OUT_EVERY - 1


def determined_maximum(train_count: int, cap: int) -> int:
    """The most influences fit_animation_space accepts: 4n - 1 unknowns need 3E >= 4n - 1 equations."""
    return max(1, min(cap, (3 * train_count + 1) // 4))


def influence_summary(influences: InfluencePattern) -> str:
    counts = influences.counts()
    return f"influences per vertex: mean {counts.mean():.2f}, max {counts.max()}"


# ---- libigl ground truth (cylinder-gt, cow-gt) --------------------------------------------------------

def read_tgf(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions (J, 3) and bone edges (m, 2) as 0-based joint indices."""
    with open(path) as stream:
        sections = stream.read().split("#")
    joints = np.array([line.split()[1:4] for line in sections[0].splitlines() if line.strip()], float)
    edges = np.array([line.split()[:2] for line in sections[1].splitlines() if line.strip()], int) - 1
    return joints, edges


def read_dmat(path: str) -> np.ndarray:
    """libigl dense matrix: first line "cols rows", then the values column by column."""
    with open(path) as stream:
        cols, rows = map(int, stream.readline().split())
        values = np.array(stream.read().split(), float)
    return values.reshape(cols, rows).T


def read_tmat(path: str) -> np.ndarray:
    """Per bone a 4x3 block [A^T; t] acting on row vectors ([v 1] @ block), as 4x4 column-vector matrices.

    The convention was found by reproducing poses/N.obj from the rest mesh and weights (see the notes).
    """
    blocks = np.loadtxt(path).reshape(-1, 4, 3)
    matrices = np.tile(np.eye(4), (len(blocks), 1, 1))
    matrices[:, :3, :] = blocks.transpose(0, 2, 1)
    return matrices


def libigl_skeleton(joints: np.ndarray, edges: np.ndarray) -> Skeleton:
    """Bone k of the TGF becomes skinkit bone k + 1; its rest frame is the identity rotation at its head,
    so the per-vertex regulariser pulls towards the joint rather than the model origin."""
    parents = [-1] + [next((p + 1 for p, other in enumerate(edges) if other[1] == head), 0) for head, _ in edges]
    rest_frames = np.tile(np.eye(4), (len(edges) + 1, 1, 1))
    rest_frames[1:, :3, 3] = joints[edges[:, 0]]
    return Skeleton.create(parents, rest_frames)


def read_libigl_set(folder: str):
    """rest positions, triangles, skeleton, dense true weights (V, b; root column 0), skinning matrices
    N (F, b, 4, 4) and positions (F, V, 3), where frame 0 is the rest pose (N = I) and frame k poses/k."""
    rest, triangles = read_obj(os.path.join(folder, "rest.obj"))
    skeleton = libigl_skeleton(*read_tgf(os.path.join(folder, "skeleton.tgf")))
    weights = np.column_stack([np.zeros(len(rest)), read_dmat(os.path.join(folder, "weights.DMAT"))])
    count = len([n for n in os.listdir(os.path.join(folder, "poses")) if n.endswith(".Tmat")])
    pose_files = [os.path.join(folder, "poses", str(k)) for k in range(1, count + 1)]
    identity = np.eye(4)[None]
    skinning = np.stack([identity.repeat(skeleton.bone_count, 0)] +
                        [np.concatenate([identity, read_tmat(path + ".Tmat")]) for path in pose_files])
    frames = np.stack([rest] + [read_obj(path + ".obj")[0] for path in pose_files])
    return rest, triangles, skeleton, weights, skinning, frames


def libigl_ground_truth(folder: str, name: str, cap: int = 6) -> Problem:
    """The rest mesh plus poses/N.obj as examples. The rest pose is example 0 (G = Ĝ): with 4 or 7 poses
    every example counts towards the 3E >= 4n - 1 equations the animation-space fit needs."""
    rest, triangles, skeleton, weights, skinning, frames = read_libigl_set(folder)
    poses = skinning @ skeleton.rest_frames  # N = G Ĝ^-1, so G = N Ĝ
    held_out, split_note = split_keeping_every_bone(skinning)
    train_count = int((~held_out).sum())
    count = determined_maximum(train_count, cap)
    influences = influences_from_weights(weights, count)
    notes = [f"{name}: {len(rest)} vertices, {skeleton.bone_count - 1} bones, frames = rest + {len(frames) - 1} "
             "poses", convention_note(skeleton, weights, rest, poses, frames),
             support_note(weights, train_count, count), influence_summary(influences), split_note]
    return Problem(name, rest, triangles, skeleton, poses, frames, held_out, influences, notes, weights)


def convention_note(skeleton, weights, rest, poses, frames) -> str:
    """How well LBS with the Tmat reading reproduces poses/N.obj, and how badly the other reading does."""
    truth = SparseWeights.from_dense(weights)
    diagonal = skinning.bounding_box_diagonal(rest)
    error = np.linalg.norm(lbs_evaluate(skeleton, truth, rest, poses) - frames, axis=2).max() / diagonal
    other = transposed_error(skeleton, truth, rest, poses, frames) / diagonal
    return ("Tmat convention: per bone 4 rows of 3 = [A^T; t], v' = sum_j w_j [v 1] T_j (row vectors); LBS with "
            f"it reproduces poses/N.obj to max {error:.1e} of the diagonal (the files have 6-7 significant "
            f"digits); the untransposed reading is off by {other:.2f}")


def support_note(weights: np.ndarray, train_count: int, count: int) -> str:
    kept = np.take_along_axis(weights, np.argsort(-weights, axis=1)[:, :count], axis=1).sum(axis=1)
    return (f"ground-truth weights: up to {int((weights > 0).sum(axis=1).max())} bones per vertex; {train_count} "
            f"training frames allow at most {count} influences (3E >= 4n - 1); the top-{count} true bones leave "
            f"out up to {1 - kept.min():.1e} (mean {1 - kept.mean():.1e}) of a vertex's weight, so the "
            "animation-space fits cannot be exact where that is large")


def split_keeping_every_bone(skinning: np.ndarray) -> tuple[np.ndarray, str]:
    """Every fourth frame held out, unless that leaves a bone still in all training frames: the fits cannot
    learn such a bone's influence (fit_animation_space refuses), so then nothing is held out."""
    held_out = every_fourth_held_out(len(skinning))
    moves = np.abs(skinning - np.eye(4)).max(axis=(2, 3)) > 1e-9  # (F, b)
    unseen = np.flatnonzero(moves[held_out].any(axis=0) & ~moves[~held_out].any(axis=0))
    if len(unseen) == 0:
        return held_out, f"held out: frames {np.flatnonzero(held_out).tolist()} (frame 0 is the rest pose)"
    return np.zeros(len(skinning), bool), (
        f"no frame held out: every pose moves a different part (bones {unseen.tolist()} move only in frames "
        f"{np.flatnonzero(held_out).tolist()}), so holding any out leaves bones the fits cannot learn")


def transposed_error(skeleton, truth, rest, poses, frames) -> float:
    """The other reading of the 3x3 block (not transposed), to show the convention is not ambiguous."""
    skinning = skinning_matrices(skeleton, poses)
    skinning[:, :, :3, :3] = skinning[:, :, :3, :3].transpose(0, 1, 3, 2)
    wrong = lbs_evaluate(Skeleton.create(skeleton.parents, np.tile(np.eye(4), (skeleton.bone_count, 1, 1))),
                         truth, rest, skinning)
    return float(np.linalg.norm(wrong - frames, axis=2).max())


# ---- Blender samples, deformed with dual quaternions ----------------------------------------------------

def blender_sample(path: str, cap: int = 6) -> Problem:
    """Examples from Blender's Armature modifier with Preserve Volume (dual quaternions), over the scene's
    frames: data that linear blend skinning did not make. Influence sets: the rig's weights grown by one
    ring (at most `cap`, the grown bones that best explain the vertex first)."""
    bpy.ops.wm.open_mainfile(filepath=path)
    scene = bpy.context.scene
    mesh_object = find_skinned_mesh(scene.objects)
    found = rig.rig_of(mesh_object)
    found.modifier.use_deform_preserve_volume = True
    depsgraph = bpy.context.evaluated_depsgraph_get()
    bind = rig.bind_matrix(found, depsgraph)
    skeleton = rig.skeleton_of(found, bind)
    weights = rig.deform_weights(found)
    mesh = rig.mesh_of(mesh_object)
    frame_numbers = list(range(scene.frame_start, scene.frame_end + 1))
    poses, frames = [], []
    with armature_modifier_only(mesh_object):
        for depsgraph in depsgraphs_at(frame_numbers):
            frames.append(evaluated_positions(mesh_object, depsgraph))
            poses.append(rig.pose_matrices(found.armature_object, depsgraph, list(skeleton.names), bind))
    poses, frames = np.stack(poses), np.stack(frames)
    held_out = every_fourth_held_out(len(frames))
    explanation = rigid_explanation_error(skeleton, mesh.positions, poses[~held_out], frames[~held_out])
    influences = influences_from_weights(weights.to_dense(skeleton.bone_count), cap, mesh.triangles, rings=1,
                                         explanation_error=explanation)
    name = os.path.splitext(os.path.basename(path))[0]
    notes = [f"{name}: {len(mesh.positions)} vertices, {skeleton.bone_count - 1} bones, frames "
             f"{frame_numbers[0]}-{frame_numbers[-1]} of its action, deformed by the Armature modifier with "
             "Preserve Volume (dual quaternions)",
             f"rig weights: max {weights.counts().max()} per vertex; grown by 1 ring, capped at {cap}; "
             + influence_summary(influences)]
    return Problem(name, mesh.positions, mesh.triangles, skeleton, poses, frames, held_out, influences, notes)


# ---- the Dem Bones sample ---------------------------------------------------------------------------

def import_new(operator, **options) -> list:
    before = set(bpy.data.objects)
    operator(**options)
    return [o for o in bpy.data.objects if o not in before]


def positions_in(space: np.ndarray, mesh_object, depsgraph) -> np.ndarray:
    """The evaluated mesh's vertices mapped by `space` @ its world matrix."""
    matrix = space @ np.array(mesh_object.evaluated_get(depsgraph).matrix_world)
    return transform_points(matrix, evaluated_positions(mesh_object, depsgraph))


def dem_bones_sample(folder: str, cap: int = DEFAULT_MAX_INFLUENCES) -> Problem:
    """Bone_Geom.fbx (rest mesh), Bone_Trans.fbx (animated joints, no weights) and Bone_Anim.abc (the mesh
    sequence), in the armature's space (the FBX's centimetres). Blender gives the FBX objects a 0.01 scale;
    the Alembic file is unitless and imported at scale 0.01 to match. Working in world space instead would
    put that 0.01 into every bone frame, and skinkit's λ and δ act on coordinates in the bone frames, so
    they would be 10^4 times stronger. Alembic frame f matches the joints at FBX frame f with
    anim_offset=0 (checked by a linear-blend fit, see the notes)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    geometry = next(o for o in import_new(bpy.ops.import_scene.fbx, filepath=os.path.join(folder, "Bone_Geom.fbx"))
                    if o.type == "MESH")
    armature = next(o for o in import_new(bpy.ops.import_scene.fbx, filepath=os.path.join(folder, "Bone_Trans.fbx"),
                                          anim_offset=0.0) if o.type == "ARMATURE")
    sequence = import_new(bpy.ops.wm.alembic_import, filepath=os.path.join(folder, "Bone_Anim.abc"), scale=0.01)[0]
    depsgraph = bpy.context.evaluated_depsgraph_get()
    to_armature = np.linalg.inv(np.array(armature.evaluated_get(depsgraph).matrix_world))
    rest = positions_in(to_armature, geometry, depsgraph)
    triangles = rig.mesh_of(geometry).triangles
    names = rig.bone_names(armature)
    parents = [-1] + [names.index(b.parent.name) if b.parent else 0 for b in armature.data.bones]
    rest_frames = np.concatenate([np.eye(4)[None], [np.array(b.matrix_local) for b in armature.data.bones]])
    skeleton = Skeleton.create(parents, rest_frames, names)
    frame_numbers = list(range(scene.frame_start, scene.frame_end + 1))
    poses, frames = [], []
    for number in frame_numbers:
        scene.frame_set(number)
        depsgraph = bpy.context.evaluated_depsgraph_get()
        moved = to_armature @ np.array(armature.evaluated_get(depsgraph).matrix_world)  # identity unless animated
        pose = rig.pose_matrices(armature, depsgraph, names, np.eye(4))
        poses.append(np.concatenate([np.eye(4)[None], moved @ pose[1:]]))
        frames.append(positions_in(to_armature, sequence, depsgraph))
    poses, frames = np.stack(poses), np.stack(frames)
    if frames.shape[1] != len(rest):
        raise RuntimeError(f"Bone_Anim.abc has {frames.shape[1]} vertices, Bone_Geom.fbx {len(rest)}")
    held_out = every_fourth_held_out(len(frames))
    influences = influences_automatic(skeleton, rest, poses[~held_out], frames[~held_out], cap)
    notes = [f"dembones: {len(rest)} vertices, {skeleton.bone_count - 1} joints, frames "
             f"{frame_numbers[0]}-{frame_numbers[-1]}; Bone_Geom.fbx and every Bone_Anim.abc frame have the same "
             f"vertex count and order (frame 1 equals the rest mesh to {np.abs(frames[0] - rest).max():.1e} cm)",
             "time alignment: " + alignment_check(skeleton, rest, poses, frames, cap),
             f"influence sets: the {cap} joints whose rigid motion best explains each vertex "
             "(influences_automatic; the sample has no weights for these joints); " + influence_summary(influences)]
    return Problem("dembones", rest, triangles, skeleton, poses, frames, held_out, influences, notes)


def alignment_check(skeleton, rest, poses, frames, cap) -> str:
    """Rms error of a linear-blend fit on every 8th frame, with the joints shifted by -1, 0, +1 frames."""
    picked = np.arange(1, len(frames) - 1, 8)
    errors = {}
    for shift in (-1, 0, 1):
        examples, shifted = frames[picked], poses[picked + shift]
        influences = influences_automatic(skeleton, rest, shifted, examples, cap)
        weights = fit_lbs(skeleton, rest, shifted, examples, influences)
        distance = np.linalg.norm(lbs_evaluate(skeleton, weights, rest, shifted) - examples, axis=2)
        errors[shift] = float(np.sqrt((distance ** 2).mean())) / skinning.bounding_box_diagonal(rest)
    listed = ", ".join(f"{shift:+d}: {error:.2e}" for shift, error in errors.items())
    return f"LBS rms / diagonal with the joints shifted by {listed} frames (0 is used)"


# ---- a horse-sized synthetic problem --------------------------------------------------------------------

def farthest_point_centres(points: np.ndarray, count: int, iterations: int = 10) -> np.ndarray:
    """Deterministic k-means: farthest-point seeds from the point nearest the centroid, then Lloyd steps."""
    centres = [points[np.argmin(np.linalg.norm(points - points.mean(axis=0), axis=1))]]
    distance = np.linalg.norm(points - centres[0], axis=1)
    for _ in range(count - 1):
        centres.append(points[np.argmax(distance)])
        distance = np.minimum(distance, np.linalg.norm(points - centres[-1], axis=1))
    centres = np.array(centres)
    for _ in range(iterations):
        label = np.argmin(np.linalg.norm(points[:, None] - centres[None], axis=2), axis=1)
        centres = np.array([points[label == j].mean(axis=0) for j in range(count)])
    return centres


def spanning_tree(centres: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """Prim's minimum spanning tree from centre 0: the centres in the order they joined the tree (so every
    parent comes before its children) and, in that order, each one's parent (-1 for the first)."""
    order, parent_of = [0], {0: -1}
    distance = np.linalg.norm(centres - centres[0], axis=1)
    nearest = np.zeros(len(centres), int)
    for _ in range(len(centres) - 1):
        j = int(np.argmin(np.where(np.isin(np.arange(len(centres)), order), np.inf, distance)))
        parent_of[j] = int(nearest[j])
        order.append(j)
        to_j = np.linalg.norm(centres - centres[j], axis=1)
        nearest[to_j < distance] = j
        distance = np.minimum(distance, to_j)
    position = {centre: k for k, centre in enumerate(order)}
    return centres[order], [-1] + [position[parent_of[c]] for c in order[1:]]


def smooth_weights(points, centres, mean_influences: float, most: int) -> np.ndarray:
    """Gaussian falloff from each centre, bones below 5 % of a vertex's strongest dropped (at most `most`
    kept), normalised; the falloff width is bisected so the mean influence count is `mean_influences`."""
    squared = ((points[:, None] - centres[None]) ** 2).sum(axis=2)
    relative = squared - squared.min(axis=1, keepdims=True)

    def weights_for(width):
        weights = np.exp(-relative / (2 * width ** 2))
        weights[weights < 0.05] = 0.0
        np.put_along_axis(weights, np.argsort(-weights, axis=1)[:, most:], 0.0, axis=1)
        return weights / weights.sum(axis=1, keepdims=True)

    low, high = 1e-6, float(np.sqrt(relative.max()))
    for _ in range(40):
        width = (low + high) / 2
        if (weights_for(width) > 0).sum(axis=1).mean() < mean_influences:
            low = width
        else:
            high = width
    return weights_for((low + high) / 2)


def forward_kinematics(parents, heads: np.ndarray, rotations: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Skinning matrices N (b, 4, 4): bone j turns by rotations[j] about its head, after its parent (parents
    come first); bone 0 is skinkit's root (identity), its children are also moved by `offset`."""
    matrices = np.tile(np.eye(4), (len(parents), 1, 1))
    for j in range(1, len(parents)):
        local = np.eye(4)
        local[:3, :3] = rotations[j]
        local[:3, 3] = heads[j] - rotations[j] @ heads[j] + (offset if parents[j] == 0 else 0.0)
        matrices[j] = matrices[parents[j]] @ local
    return matrices


def quaternions(rotations: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations to (..., 4) unit quaternions (w, x, y, z), either sign."""
    r = rotations
    trace = np.stack([1 + r[..., 0, 0] + r[..., 1, 1] + r[..., 2, 2], 1 + r[..., 0, 0] - r[..., 1, 1] - r[..., 2, 2],
                      1 - r[..., 0, 0] + r[..., 1, 1] - r[..., 2, 2], 1 - r[..., 0, 0] - r[..., 1, 1] + r[..., 2, 2]],
                     axis=-1)
    magnitude = np.sqrt(np.maximum(trace, 0.0)) / 2
    signs = np.stack([np.ones_like(r[..., 0, 0]), np.sign(r[..., 2, 1] - r[..., 1, 2]),
                      np.sign(r[..., 0, 2] - r[..., 2, 0]), np.sign(r[..., 1, 0] - r[..., 0, 1])], axis=-1)
    result = magnitude * np.where(signs == 0, 1.0, signs)  # a zero difference: that component is 0 anyway
    return result / np.linalg.norm(result, axis=-1, keepdims=True)


def quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, av, bw, bv = a[..., :1], a[..., 1:], b[..., :1], b[..., 1:]
    return np.concatenate([aw * bw - (av * bv).sum(-1, keepdims=True),
                           aw * bv + bw * av + np.cross(av, bv)], axis=-1)


def dual_quaternion_skinning(rest: np.ndarray, weights: np.ndarray, skinning: np.ndarray) -> np.ndarray:
    """Kavan et al. 2007: blend the bones' unit dual quaternions (signs aligned with each vertex's heaviest
    bone), normalise, apply. rest (V, 3), weights (V, b) dense, skinning (b, 4, 4) rigid."""
    real = quaternions(skinning[:, :3, :3])
    dual = 0.5 * quaternion_product(np.column_stack([np.zeros(len(skinning)), skinning[:, :3, 3]]), real)
    pivot = real[np.argmax(weights, axis=1)]  # (V, 4)
    signed = weights * np.where(pivot @ real.T < 0, -1.0, 1.0)
    blend_real, blend_dual = signed @ real, signed @ dual
    length = np.linalg.norm(blend_real, axis=1, keepdims=True)
    blend_real, blend_dual = blend_real / length, blend_dual / length
    w0, v0, we, ve = blend_real[:, :1], blend_real[:, 1:], blend_dual[:, :1], blend_dual[:, 1:]
    rotated = rest + 2 * np.cross(v0, np.cross(v0, rest) + w0 * rest)  # q v q*
    return rotated + 2 * (w0 * ve - we * v0 + np.cross(v0, ve))


def synthetic_rig(rest: np.ndarray, bone_count: int) -> tuple[Skeleton, np.ndarray]:
    """A made-up skeleton for a mesh (k-means centres joined by a minimum spanning tree, each bone's rest
    frame the identity at its centre) and smooth weights (V, b) with 2.6 influences per vertex on average
    and at most 6, like the thesis' horse."""
    heads, tree = spanning_tree(farthest_point_centres(rest, bone_count))
    heads = np.vstack([np.zeros(3), heads])
    rest_frames = np.tile(np.eye(4), (bone_count + 1, 1, 1))
    rest_frames[:, :3, 3] = heads
    skeleton = Skeleton.create([-1] + [p + 1 for p in tree], rest_frames)
    return skeleton, np.column_stack([np.zeros(len(rest)), smooth_weights(rest, heads[1:], 2.6, 6)])


def random_skinning(skeleton: Skeleton, count: int, max_degrees: float, scale: float, seed: int) -> np.ndarray:
    """(count + 1, b, 4, 4) skinning matrices: the rest pose, then `count` random poses (every bone turned
    by up to max_degrees about its head, the whole body shifted by up to 5 % of `scale`)."""
    rng = np.random.default_rng(seed)
    heads = skeleton.rest_frames[:, :3, 3]
    poses = [forward_kinematics(skeleton.parents, heads, rotation_matrices(rng, skeleton.bone_count, max_degrees),
                                rng.uniform(-0.05, 0.05, 3) * scale) for _ in range(count)]
    return np.stack([np.tile(np.eye(4), (skeleton.bone_count, 1, 1))] + poses)


def synthetic_horse(path: str, max_degrees: float, bone_count: int = 25, train_poses: int = 10,
                    held_out_poses: int = 8, seed: int = 1) -> Problem:
    """The horse's reference mesh with a synthetic rig and random poses deformed by dual-quaternion skinning.
    Training: the rest pose and `train_poses` poses (11 examples, as in the thesis); held out:
    `held_out_poses` further poses from the same generator."""
    rest, triangles = read_obj(path)
    skeleton, weights = synthetic_rig(rest, bone_count)
    scale = skinning.bounding_box_diagonal(rest)
    skinning_poses = random_skinning(skeleton, train_poses + held_out_poses, max_degrees, scale, seed)
    frames = np.stack([dual_quaternion_skinning(rest, weights, matrices) for matrices in skinning_poses])
    poses = skinning_poses @ skeleton.rest_frames
    held_out = np.arange(len(frames)) > train_poses
    influences = influences_from_weights(weights, 6)
    linear = np.linalg.norm(lbs_evaluate(skeleton, SparseWeights.from_dense(weights), rest, poses) - frames, axis=2)
    name = f"horse-synthetic-{max_degrees:g}deg"
    notes = [f"{name}: horse/reference.obj ({len(rest)} vertices) with a synthetic {bone_count}-bone tree, "
             f"smooth synthetic weights, every bone turned by up to {max_degrees:.0f} degrees per pose, positions "
             f"by dual-quaternion skinning (numpy); training = rest + {train_poses} poses, held out = "
             f"{held_out_poses} more poses",
             f"how far from linear blend skinning the examples are: LBS with the true weights is off by rms "
             f"{np.sqrt((linear ** 2).mean()) / scale:.1e}, max {linear.max() / scale:.1e} of the diagonal",
             "influence sets: the true weights' support; " + influence_summary(influences)]
    return Problem(name, rest, triangles, skeleton, poses, frames, held_out, influences, notes)
