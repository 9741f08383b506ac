"""Skinning a mesh sequence that has no rig, inside Blender: reading the frames, solving, and writing a new
armature with an action and a skinned copy of the mesh.

Frames come from the mesh's shape keys (the Basis first), from its own Mesh Sequence Cache / Mesh Cache
modifier over a frame range, or from other mesh objects with the same vertices. The source objects are never
changed: the result is a new armature "<mesh>_rig" (bones, rest pose, an action keyed on every frame, held-out
frames solved with the model fixed) and a new mesh "<mesh>_skinned" bound to it with an Armature modifier, the
linear-blend weights as vertex groups, the animation-space model (storage layout), an error attribute with its
heat map and a report.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import bpy
import numpy as np

from .. import decompose as decomposition
from ..decompose import DEFAULT_BONES, METHODS
from ..fit import DEFAULT_MAX_INFLUENCES
from ..model import AnimationSpaceModel, Skeleton, SkinkitError, SparseWeights
from . import compat, storage
from .attributes import (ERROR_ATTRIBUTE, HEAT_ATTRIBUTE, REPORT_PROPERTY, flatten_report, write_bone_groups,
                         write_heat_map)
from .frames import depsgraphs_at, evaluated_positions
from .rig import column_major, mesh_of, mesh_positions, model_signature, read_vertex_groups, rig_of
from .scene import check_same_vertex_count, into_local_space, named, world_matrix


@dataclass
class Sequence:
    """Frames (F, V, 3) in the mesh's local space, with the scene frame of each (keys of the action)."""

    positions: np.ndarray
    frame_numbers: list[int]
    labels: list[str]


#: Where Skin from Mesh Sequence reads the frames: "auto" picks the one the object has (sequence_source).
FRAME_SOURCES = ("auto", "shape-keys", "sequence", "objects")


def has_cache_modifier(mesh_object) -> bool:
    return any(m.type in ("MESH_SEQUENCE_CACHE", "MESH_CACHE") for m in mesh_object.modifiers)


def sequence_source(mesh_object, selected=()) -> str:
    """The frame source the object has: its shape keys, else its Mesh Sequence Cache or Mesh Cache, else the other
    selected meshes; refused naming what is missing when it has none."""
    keys = mesh_object.data.shape_keys
    if keys is not None and len(keys.key_blocks) >= 2:
        return "shape-keys"
    if has_cache_modifier(mesh_object):
        return "sequence"
    if any(o != mesh_object and o.type == "MESH" for o in selected):
        return "objects"
    raise SkinkitError(f"'{mesh_object.name}' has no frames to skin: give it shape keys (besides the Basis), a Mesh "
                       "Sequence Cache or Mesh Cache modifier, or select the other frames' meshes too")


def frames_from(mesh_object, source: str, frame_numbers=(), selected=()) -> Sequence:
    """The sequence from `source` (one of FRAME_SOURCES): shape keys, the cache over frame_numbers, or the
    selected meshes."""
    if source == "auto":
        source = sequence_source(mesh_object, selected)
    if source == "shape-keys":
        return frames_from_shape_keys(mesh_object)
    if source == "sequence":
        return frames_from_sequence(mesh_object, frame_numbers)
    if source == "objects":
        return frames_from_objects(mesh_object, [o for o in selected if o.type == "MESH"])
    raise SkinkitError(f"frame source must be one of {FRAME_SOURCES}, not {source!r}")


def frames_from_shape_keys(mesh_object) -> Sequence:
    """The Basis and every other shape key, as frames 1, 2, ..."""
    keys = mesh_object.data.shape_keys
    if keys is None or len(keys.key_blocks) < 2:
        raise SkinkitError(f"'{mesh_object.name}' needs shape keys (besides the Basis) holding the sequence's frames")
    blocks = list(keys.key_blocks)
    positions = np.empty((len(blocks), len(mesh_object.data.vertices) * 3), np.float32)
    for row, block in zip(positions, blocks):
        block.points.foreach_get("co", row)
    start = bpy.context.scene.frame_start
    return Sequence(positions.reshape(len(blocks), -1, 3).astype(np.float64),
                    list(range(start, start + len(blocks))), [b.name for b in blocks])


def frames_from_sequence(mesh_object, frame_numbers) -> Sequence:
    """The mesh as its Mesh Sequence Cache or Mesh Cache modifier deforms it at each frame."""
    frame_numbers = list(frame_numbers)
    if len(frame_numbers) < 2:
        raise SkinkitError("the frame range needs at least two frames")
    if not any(m.type in ("MESH_SEQUENCE_CACHE", "MESH_CACHE") for m in mesh_object.modifiers):
        raise SkinkitError(f"'{mesh_object.name}' has no Mesh Sequence Cache or Mesh Cache modifier")
    positions = []
    for depsgraph in depsgraphs_at(frame_numbers):
        frame = evaluated_positions(mesh_object, depsgraph)
        check_same_vertex_count(mesh_object, mesh_object, len(frame))
        positions.append(frame)
    return Sequence(np.stack(positions), frame_numbers, [f"frame {f}" for f in frame_numbers])


def frames_from_objects(mesh_object, objects) -> Sequence:
    """The mesh itself, then each of `objects` (meshes with the same vertices), as frames 1, 2, ..."""
    others = [o for o in objects if o != mesh_object]
    if not others:
        raise SkinkitError("select the other frames' mesh objects as well as the active mesh")
    positions = [mesh_positions(mesh_object.data)]
    for other in others:
        if other.type != "MESH":
            raise SkinkitError(f"'{other.name}' is a {other.type.lower()}, not a mesh")
        check_same_vertex_count(mesh_object, other, len(other.data.vertices))
        positions.append(into_local_space(mesh_object, other, mesh_positions(other.data)))
    start = bpy.context.scene.frame_start
    return Sequence(np.stack(positions), list(range(start, start + len(positions))),
                    [mesh_object.name] + [o.name for o in others])


@dataclass
class RoughRig:
    """A user-drawn armature giving the hierarchy and approximate joints, with core vertices per bone (vertex
    groups of the mesh named like the bones), in the mesh's space."""

    armature_name: str
    parents: np.ndarray
    names: tuple
    joints: np.ndarray
    orientations: np.ndarray
    lengths: np.ndarray
    cores: list


def rough_rig_of(mesh_object, armature_object) -> RoughRig:
    if armature_object is None or armature_object.type != "ARMATURE":
        raise SkinkitError("the rough-rig method needs an armature: select it (or name it) with the mesh")
    bones = armature_object.data.bones
    if len(bones) == 0:
        raise SkinkitError(f"armature '{armature_object.name}' has no bones")
    names = [b.name for b in bones]
    missing = [n for n in names if n not in mesh_object.vertex_groups]
    if missing:
        raise SkinkitError(f"'{mesh_object.name}' needs a vertex group marking the core vertices of each bone; "
                           f"missing: {missing}")
    to_mesh = np.linalg.inv(world_matrix(mesh_object)) @ world_matrix(armature_object)
    flat = np.empty(len(bones) * 16, np.float32)
    bones.foreach_get("matrix_local", flat)
    frames = to_mesh @ column_major(flat)
    weights = read_vertex_groups(mesh_object, names)
    index = {n: j + 1 for j, n in enumerate(names)}
    parents = np.array([-1] + [index[b.parent.name] if b.parent else 0 for b in bones], np.int32)
    lengths = np.array([0.0] + [b.length for b in bones]) * np.linalg.norm(to_mesh[:3, 0])
    orientations = np.concatenate([np.eye(3)[None], frames[:, :3, :3] / np.linalg.norm(frames[:, :3, :1], axis=1,
                                                                                          keepdims=True)])
    cores = [np.zeros(0, np.int32)] + [np.flatnonzero(weights[:, j] > 0.5).astype(np.int32) for j in range(len(names))]
    return RoughRig(armature_object.name, parents, ("root",) + tuple(names),
                    np.concatenate([np.zeros((1, 3)), frames[:, :3, 3]]), orientations, lengths, cores)


@dataclass
class DecomposeJob:
    """What a decomposition needs, read from the scene; solve() touches no Blender data (it may run on a thread)."""

    mesh_object_name: str
    triangles: np.ndarray
    sequence: Sequence
    train: np.ndarray
    options: dict
    rough: RoughRig | None = None
    result: dict = field(default_factory=dict)

    def solve(self, progress=None) -> dict:
        options, frames = self.options, self.sequence.positions
        rough = None if self.rough is None else {
            "parents": self.rough.parents, "approximate_joints_hint": self.rough.joints,
            "core_vertices": self.rough.cores, "names": self.rough.names, "orientations": self.rough.orientations}
        with named(self.mesh_object_name):
            result, poses, replay, report = decomposition.solve_sequence(
                frames, self.triangles, self.train, bones=options["bones"], max_influences=options["max_influences"],
                rough=rough, progress=progress)
        report.update(object=self.mesh_object_name, method=options["method"])
        diagonal = decomposition.rest_diagonal(result.rest_positions)
        error = (np.linalg.norm(replay["animation"] - frames, axis=-1) / diagonal).max(axis=0)
        self.result = {"decomposition": result, "poses": poses["animation"], "report": report,
                       "per_vertex_error": error, "reconstruction": replay["animation"]}
        return self.result


def prepare(mesh_object, sequence: Sequence, *, method=METHODS[0], bones=DEFAULT_BONES,
            max_influences=DEFAULT_MAX_INFLUENCES, train_frames=(),
            armature_object=None) -> DecomposeJob:
    """Reads the mesh and checks the choices (changing nothing). train_frames: scene frames used for fitting
    (empty: all); the others are held out and replayed."""
    if method not in METHODS:
        raise SkinkitError(f"method must be one of {METHODS}, not {method!r}")
    train = np.isin(sequence.frame_numbers, list(train_frames)) if len(train_frames) else \
        np.ones(len(sequence.frame_numbers), bool)
    if train.sum() < 2:
        raise SkinkitError(f"{int(train.sum())} training frame(s) among the sequence's frames "
                           f"{sequence.frame_numbers[0]}..{sequence.frame_numbers[-1]}: at least two are needed")
    with named(mesh_object.name):
        mesh = mesh_of(mesh_object)
        rough = rough_rig_of(mesh_object, armature_object) if method == "rough-rig" else None
    return DecomposeJob(mesh_object.name, mesh.triangles, sequence, train,
                        {"method": method, "bones": bones, "max_influences": max_influences}, rough)


def skin_object(mesh_object, sequence: Sequence, progress=None, **options) -> dict:
    """Solves, then writes the armature, the action and the skinned copy; everything is computed before anything is
    written, and a failure while writing removes what was made, so the scene is left as it was."""
    started = time.perf_counter()
    job = prepare(mesh_object, sequence, **options)
    solved = job.solve(progress)
    armature_object, skinned = write(mesh_object, job, solved)
    return {**solved["report"], "armature": armature_object.name, "skinned_object": skinned.name,
            "seconds": time.perf_counter() - started, "reconstruction": solved["reconstruction"]}


# ---- writing the result -----------------------------------------------------------------------------------------

def write(mesh_object, job: DecomposeJob, solved: dict):
    made = []
    try:
        return write_all(mesh_object, job, solved, made)
    except Exception:
        for datablock in reversed(made):
            collection = getattr(bpy.data, datablock[0])
            if datablock[1] in collection:
                collection.remove(collection[datablock[1]])
        raise


def write_all(mesh_object, job, solved, made):
    result = solved["decomposition"]
    base = mesh_object.name
    armature_object = new_armature(f"{base}_rig", mesh_object, result.skeleton, made)
    skeleton, model, poses, weights = rebind(result, armature_object, solved["poses"])
    write_action(armature_object, skeleton, poses, job.sequence.frame_numbers, made)
    skinned = skinned_copy(mesh_object, result.rest_positions, armature_object, made)
    write_bone_groups(skinned, weights, skeleton.names)
    storage.write_model(skinned.data, model, list(skeleton.names), armature_object.name, np.eye(4),
                        model_signature(rig_of(skinned)))
    error = solved["per_vertex_error"]
    write_heat_map(skinned.data, ERROR_ATTRIBUTE, HEAT_ATTRIBUTE, error)
    skinned.data[REPORT_PROPERTY] = flatten_report(solved["report"])
    return armature_object, skinned


def link_like(new_object, source_object) -> None:
    collections = source_object.users_collection or (bpy.context.scene.collection,)
    for collection in collections:
        collection.objects.link(new_object)


def new_armature(name: str, mesh_object, skeleton: Skeleton, made: list):
    """An armature at the mesh's transform with one bone per skeleton bone (the root is the armature itself)."""
    from mathutils import Matrix

    data = bpy.data.armatures.new(name)
    made.append(("armatures", data.name))
    armature_object = bpy.data.objects.new(name, data)
    made.append(("objects", armature_object.name))
    armature_object.matrix_world = mesh_object.matrix_world.copy()
    link_like(armature_object, mesh_object)
    view_layer = bpy.context.view_layer
    previous_active = view_layer.objects.active
    view_layer.objects.active = armature_object
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        lengths = bone_lengths(skeleton)
        edit_bones = [None]
        for bone in range(1, skeleton.bone_count):
            edit_bone = data.edit_bones.new(skeleton.names[bone])
            edit_bone.head, edit_bone.tail = (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)
            edit_bone.matrix = Matrix(skeleton.rest_frames[bone].tolist())
            edit_bone.length = lengths[bone]
            edit_bones.append(edit_bone)
        for bone in range(1, skeleton.bone_count):
            parent = int(skeleton.parents[bone])
            if parent > 0:
                edit_bones[bone].parent = edit_bones[parent]
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
        view_layer.objects.active = previous_active
    return armature_object


def bone_lengths(skeleton: Skeleton) -> np.ndarray:
    """Bone length: to the farthest child joint along the bone's Y axis, else a quarter of the distance to the
    parent's joint (at least 1% of the skeleton's size)."""
    joints = skeleton.rest_frames[:, :3, 3]
    size = float(np.ptp(joints[1:], axis=0).max()) if skeleton.bone_count > 2 else 1.0
    lengths = np.full(skeleton.bone_count, 0.05 * size)
    for bone in range(1, skeleton.bone_count):
        axis = skeleton.rest_frames[bone, :3, 1]
        children = np.flatnonzero(skeleton.parents == bone)
        reach = [(joints[c] - joints[bone]) @ axis for c in children]
        if reach and max(reach) > 0.01 * size:
            lengths[bone] = max(reach)
    return np.maximum(lengths, 0.01 * size)


def rebind(result, armature_object, poses):
    """The skeleton as Blender stored it (its float32 bone matrices), with the model and poses expressed in it."""
    from .rig import armature_rest_frames, bone_names, skeleton_parents

    stored = armature_rest_frames(armature_object)
    names = bone_names(armature_object)
    order = [result.skeleton.names.index(n) if n in result.skeleton.names else 0 for n in names]
    order[0] = 0
    frames = result.skeleton.rest_frames[order]
    change = np.linalg.inv(stored) @ frames  # old bone frame -> new bone frame coordinates
    skeleton = Skeleton.create(skeleton_parents(armature_object), stored, names)
    position = np.argsort(order)
    new_bones = position[result.model.bones].astype(np.int32)
    coordinates = np.einsum("kij,kj->ki", change[new_bones], result.model.coordinates)
    model = AnimationSpaceModel.create(result.model.offsets, new_bones, coordinates, skeleton.bone_count)
    new_poses = poses[:, order] @ np.linalg.inv(change)
    weights = SparseWeights(result.linear_blend.offsets, position[result.linear_blend.bones].astype(np.int32),
                            result.linear_blend.weights)
    return skeleton, model, new_poses, weights


def write_action(armature_object, skeleton: Skeleton, poses, frame_numbers, made) -> None:
    """Keys location and rotation (quaternion) of every bone on every frame: the basis that puts bone j at G_j."""
    action = bpy.data.actions.new(f"{armature_object.name}_action")
    made.append(("actions", action.name))
    armature_object.animation_data_create()
    armature_object.animation_data.action = action
    rest = skeleton.rest_frames
    basis = np.empty_like(poses)
    for bone in range(1, skeleton.bone_count):
        parent = int(skeleton.parents[bone])
        if parent > 0:
            local_rest = np.linalg.inv(rest[parent]) @ rest[bone]
            basis[:, bone] = np.linalg.inv(local_rest) @ np.linalg.inv(poses[:, parent]) @ poses[:, bone]
        else:
            basis[:, bone] = np.linalg.inv(rest[bone]) @ poses[:, bone]
    frames = np.asarray(frame_numbers, np.float64)
    for bone in range(1, skeleton.bone_count):
        pose_bone = armature_object.pose.bones[skeleton.names[bone]]
        pose_bone.rotation_mode = "QUATERNION"
        quaternions = continuous_quaternions(basis[:, bone, :3, :3])
        channels = [("location", basis[:, bone, :3, 3]), ("rotation_quaternion", quaternions)]
        for path, values in channels:
            for index in range(values.shape[1]):
                curve = compat.ensure_fcurve(action, armature_object, f'pose.bones["{pose_bone.name}"].{path}', index)
                curve.keyframe_points.add(len(frames))
                curve.keyframe_points.foreach_set("co", np.column_stack([frames, values[:, index]]).reshape(-1))
                curve.keyframe_points.foreach_set("interpolation", [2] * len(frames))  # LINEAR
                curve.update()


def continuous_quaternions(rotations) -> np.ndarray:
    """(F, 4) w, x, y, z of each rotation matrix, signs chosen so neighbouring frames do not flip."""
    from mathutils import Matrix

    quaternions = np.array([list(Matrix(r.tolist()).to_quaternion()) for r in rotations])
    for index in range(1, len(quaternions)):
        if quaternions[index] @ quaternions[index - 1] < 0:
            quaternions[index] = -quaternions[index]
    return quaternions


def skinned_copy(mesh_object, rest_positions, armature_object, made):
    """A copy of the mesh at the rest positions, without its shape keys or modifiers, bound to the armature."""
    data = mesh_object.data.copy()
    data.name = f"{mesh_object.name}_skinned"
    made.append(("meshes", data.name))
    skinned = bpy.data.objects.new(f"{mesh_object.name}_skinned", data)
    made.append(("objects", skinned.name))
    link_like(skinned, mesh_object)
    if data.shape_keys is not None:
        skinned.shape_key_clear()
    data.attributes["position"].data.foreach_set("vector", rest_positions.astype(np.float32).reshape(-1))
    skinned.matrix_world = mesh_object.matrix_world.copy()
    skinned.parent = armature_object
    skinned.matrix_parent_inverse = armature_object.matrix_world.inverted()
    modifier = skinned.modifiers.new("Armature", "ARMATURE")
    modifier.object = armature_object
    data.update()
    return skinned
