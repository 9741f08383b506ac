"""Throughput of skinning evaluation: skinkit's C core vs numpy vs Blender's Armature modifier, on one scene.

    cd /work/main && PYTHONPATH=. .venv/bin/python bench/bench_evaluate.py \
        [--vertices 100000] [--bones 24] [--influences 4] [--poses 100] [--json out.json] [--markdown out.md]

Builds with bpy one deterministic scene (a tube-shaped body around a tree of bones, exactly `--influences`
weights per vertex summing to 1, an Armature modifier) and `--poses` seeded random poses, then on that
same data measures vertices per second of:
  skinkit LBS float32, skinkit AS float32 and float64 (threads=0, plus 1-thread and one-call-per-pose
  variants), numpy LBS and AS (float32), and Blender's Armature modifier (linear and preserve volume)
  through the depsgraph, "evaluate only" and "evaluate + read" (two ways of reading the positions).
It checks skinkit's and numpy's results against Blender's linear result for every pose (the poses given to
skinkit are read back from Blender's evaluated pose bones, as skinkit.blender does), and measures one live
preview refresh (skinkit.blender.preview) on a smaller mesh against Blender's own re-evaluation.
"""
from __future__ import annotations

import argparse
import json
import resource
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np

import skinkit
from skinkit.blender import preview, rig, skinning
from skinkit.blender.frames import evaluated_positions

from common import machine_info, machine_line, parallel_speedup, write_outputs

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "blend_samples"))
from make_samples import add_armature_modifier  # noqa: E402 (the sample scenes' own Armature set-up)

SIDES = 80  # vertices per ring of every tube; 100k and 20k vertices are then whole numbers of rings
QUANTUM = 1024  # weights are multiples of 1/QUANTUM: exact in float32, sum exactly 1, few vg.add calls
MAX_ANGLE_DEGREES = 30.0  # "moderate" random rotation per bone
ROOT_TRANSLATION = 0.05  # random offset of the root bone, in scene units (the body is ~2 units tall)
WEIGHT_FALLOFF = 0.03  # distance over which a farther bone's weight drops by e


# --------------------------------------------------------------------------------------------------
# Skeleton: a spine chain with limbs (arms, legs, a tail, then extra limbs) branching off it.


@dataclass(frozen=True)
class Limb:
    parent_spine: int  # index of the spine bone the limb hangs off
    start: tuple
    direction: tuple
    length: float
    radius: float


@dataclass(frozen=True)
class Tube:
    """A straight open tube from start to end, tapering to 70 % of its radius at the end."""

    start: np.ndarray
    end: np.ndarray
    radius: float


def spine_joints(spine_count: int) -> np.ndarray:
    """Joints of the spine (hips to head top), along +Z from z = 0.9 to 1.9."""
    z = np.linspace(0.9, 1.9, spine_count + 1)
    return np.column_stack([np.zeros_like(z), np.zeros_like(z), z])


def limb_slots(spine_count: int, count: int) -> list[Limb]:
    """Where limbs attach: two arms, two legs, a tail, then extra limbs along the spine, alternating sides."""
    chest = max(spine_count - 3, 0)
    joints = spine_joints(spine_count)
    shoulder_z = joints[chest + 1][2] - 0.05 if spine_count > 1 else joints[0][2]
    slots = [
        Limb(chest, (0.12, 0.0, shoulder_z), (1.0, 0.0, 0.0), 0.75, 0.05),
        Limb(chest, (-0.12, 0.0, shoulder_z), (-1.0, 0.0, 0.0), 0.75, 0.05),
        Limb(0, (0.09, 0.0, 0.9), (0.0, 0.0, -1.0), 0.85, 0.07),
        Limb(0, (-0.09, 0.0, 0.9), (0.0, 0.0, -1.0), 0.85, 0.07),
        Limb(0, (0.0, 0.12, 0.95), (0.0, 0.9, -0.45), 0.5, 0.04),
    ]
    for extra in range(max(count - len(slots), 0)):
        spine = extra % spine_count
        side = 1.0 if extra % 2 == 0 else -1.0
        z = (joints[spine][2] + joints[spine + 1][2]) / 2
        slots.append(Limb(spine, (0.12 * side, 0.0, z), (side, 0.3, 0.4), 0.5, 0.035))
    return slots[:count]


def skeleton_layout(bone_count: int):
    """Bone names, heads, tails, parents (-1 for the root) and the tubes of the body, for `bone_count` bones.

    About a quarter of the bones form the spine; the rest go to limbs of up to 4 bones each.
    """
    spine_count = max(1, min(bone_count, round(bone_count / 4)))
    joints = spine_joints(spine_count)
    names = [f"spine_{j}" for j in range(spine_count)]
    heads, tails = list(joints[:-1]), list(joints[1:])
    parents = [-1] + list(range(spine_count - 1))
    tubes = [Tube(joints[0], joints[-1], 0.15)]
    remaining = bone_count - spine_count
    limbs = limb_slots(spine_count, -(-remaining // 4))
    for number, limb in enumerate(limbs):
        chain = min(4, remaining)
        remaining -= chain
        start = np.array(limb.start)
        end = start + limb.length * np.array(limb.direction) / np.linalg.norm(limb.direction)
        points = start + np.linspace(0, 1, chain + 1)[:, None] * (end - start)
        for link in range(chain):
            names.append(f"limb_{number}_{link}")
            heads.append(points[link])
            tails.append(points[link + 1])
            parents.append(limb.parent_spine if link == 0 else len(names) - 2)
        tubes.append(Tube(start, end, limb.radius))
    return names, np.array(heads), np.array(tails), parents, tubes


# --------------------------------------------------------------------------------------------------
# Mesh and weights, all numpy.


def rings_per_tube(tubes: list[Tube], ring_count: int) -> np.ndarray:
    """Ring counts proportional to tube length (at least 2), summing to ring_count (largest remainder)."""
    lengths = np.array([np.linalg.norm(t.end - t.start) for t in tubes])
    share = 2 + lengths / lengths.sum() * (ring_count - 2 * len(tubes))
    rings = np.floor(share).astype(int)
    rings[np.argsort(rings - share)[: ring_count - rings.sum()]] += 1
    return rings


def tube_geometry(tube: Tube, rings: int, first_index: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (rings * SIDES, 3) and quads (as vertex indices offset by first_index) of an open tube."""
    axis = tube.end - tube.start
    tangent = axis / np.linalg.norm(axis)
    reference = np.array([0.3, 0.5, 0.8])  # not parallel to any tube's axis
    normal = np.cross(reference, tangent)
    normal /= np.linalg.norm(normal)
    binormal = np.cross(tangent, normal)
    along = np.linspace(0.0, 1.0, rings)
    angles = np.linspace(0.0, 2 * np.pi, SIDES, endpoint=False)
    radius = tube.radius * (1.0 - 0.3 * along)
    ring_directions = np.cos(angles)[:, None] * normal + np.sin(angles)[:, None] * binormal
    vertices = (tube.start + along[:, None, None] * axis
                + radius[:, None, None] * ring_directions[None]).reshape(-1, 3)
    index = first_index + np.arange(rings * SIDES).reshape(rings, SIDES)
    following = np.roll(index, -1, axis=1)
    quads = np.stack([index[:-1], following[:-1], following[1:], index[1:]], axis=-1).reshape(-1, 4)
    return vertices, quads


def body_geometry(tubes: list[Tube], vertex_target: int) -> tuple[np.ndarray, np.ndarray]:
    rings = rings_per_tube(tubes, max(round(vertex_target / SIDES), 2 * len(tubes)))
    parts, first = [], 0
    for tube, count in zip(tubes, rings):
        parts.append(tube_geometry(tube, int(count), first))
        first += count * SIDES
    return np.vstack([p[0] for p in parts]), np.vstack([p[1] for p in parts])


def segment_distances(points: np.ndarray, heads: np.ndarray, tails: np.ndarray) -> np.ndarray:
    """(V, bones) distance of each point to each bone segment, computed in chunks to bound memory."""
    axes = tails - heads
    lengths_squared = (axes * axes).sum(axis=1)
    result = np.empty((len(points), len(heads)))
    for begin in range(0, len(points), 20000):
        relative = points[begin:begin + 20000, None, :] - heads[None]
        t = np.clip((relative * axes).sum(axis=2) / lengths_squared, 0.0, 1.0)
        result[begin:begin + 20000] = np.linalg.norm(relative - t[..., None] * axes, axis=2)
    return result


def skin_weights(points, heads, tails, influences: int) -> tuple[np.ndarray, np.ndarray]:
    """Exactly `influences` bones per vertex (the nearest ones) and integer weights summing to QUANTUM.

    Weights fall off exponentially with distance beyond the nearest bone; every weight is at least 1/QUANTUM
    so each vertex really has `influences` influences.
    """
    distances = segment_distances(points, heads, tails)
    bones = np.argsort(distances, axis=1, kind="stable")[:, :influences]
    near = np.take_along_axis(distances, bones, axis=1)
    falloff = np.exp(-(near - near[:, :1]) / WEIGHT_FALLOFF)
    share = falloff / falloff.sum(axis=1, keepdims=True) * (QUANTUM - influences)
    counts = 1 + np.floor(share).astype(np.int64)
    shortfall = QUANTUM - counts.sum(axis=1)  # < influences: give it to the largest remainders
    order = np.argsort(np.floor(share) - share, axis=1, kind="stable")
    rank = np.argsort(order, axis=1, kind="stable")
    counts += rank < shortfall[:, None]
    return bones.astype(np.int32), counts


# --------------------------------------------------------------------------------------------------
# Blender scene.


def build_armature(names, heads, tails, parents):
    armature = bpy.data.armatures.new("bench_rig")
    armature_object = bpy.data.objects.new("bench_rig", armature)
    bpy.context.scene.collection.objects.link(armature_object)
    # Edit bones exist only in edit mode; there is no data-API alternative.
    bpy.context.view_layer.objects.active = armature_object
    bpy.ops.object.mode_set(mode="EDIT")
    edit_bones = []
    for name, head, tail, parent in zip(names, heads, tails, parents):
        bone = armature.edit_bones.new(name)
        bone.head, bone.tail = head.tolist(), tail.tolist()
        if parent >= 0:
            bone.parent = edit_bones[parent]
        edit_bones.append(bone)
    bpy.ops.object.mode_set(mode="OBJECT")
    for pose_bone in armature_object.pose.bones:
        pose_bone.rotation_mode = "QUATERNION"
    return armature_object


def build_mesh(name: str, vertices: np.ndarray, quads: np.ndarray):
    """A mesh from numpy arrays with foreach_set (from_pydata would go through Python lists)."""
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(vertices))
    mesh.vertices.foreach_set("co", vertices.astype(np.float32).reshape(-1))
    mesh.loops.add(quads.size)
    mesh.loops.foreach_set("vertex_index", quads.astype(np.int32).reshape(-1))
    mesh.polygons.add(len(quads))
    mesh.polygons.foreach_set("loop_start", np.arange(0, quads.size, 4, dtype=np.int32))
    mesh.update(calc_edges=True)
    if mesh.validate():
        raise RuntimeError(f"{name}: generated mesh was invalid")
    return mesh


def write_vertex_groups(mesh_object, names, bones: np.ndarray, counts: np.ndarray) -> None:
    """One vg.add per (bone, weight value): weights are quantised, so that is a few thousand calls."""
    groups = [mesh_object.vertex_groups.new(name=n) for n in names]
    vertex = np.repeat(np.arange(len(bones)), bones.shape[1])
    key = bones.reshape(-1).astype(np.int64) * (QUANTUM + 1) + counts.reshape(-1)
    order = np.argsort(key, kind="stable")
    unique, starts = np.unique(key[order], return_index=True)
    for value, members in zip(unique, np.split(vertex[order], starts[1:])):
        bone, count = divmod(int(value), QUANTUM + 1)
        groups[bone].add(members.tolist(), count / QUANTUM, "REPLACE")


def build_skinned_mesh(name, armature_object, layout, vertex_target: int, influences: int):
    names, heads, tails, _, tubes = layout
    vertices, quads = body_geometry(tubes, vertex_target)
    mesh_object = bpy.data.objects.new(name, build_mesh(name, vertices, quads))
    bpy.context.scene.collection.objects.link(mesh_object)
    bones, counts = skin_weights(vertices, heads, tails, influences)
    write_vertex_groups(mesh_object, names, bones, counts)
    add_armature_modifier(mesh_object, armature_object)
    return mesh_object


def remove_object(mesh_object) -> None:
    mesh = mesh_object.data
    bpy.data.objects.remove(mesh_object)
    bpy.data.meshes.remove(mesh)


# --------------------------------------------------------------------------------------------------
# Poses.


@dataclass(frozen=True)
class PoseSet:
    rotations: np.ndarray  # (poses, bones, 4) quaternions w, x, y, z
    root_offsets: np.ndarray  # (poses, 3) location of the root pose bone


def random_poses(count: int, bone_count: int, seed: int) -> PoseSet:
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(count, bone_count, 3))
    axes /= np.linalg.norm(axes, axis=2, keepdims=True)
    half = np.radians(rng.uniform(-MAX_ANGLE_DEGREES, MAX_ANGLE_DEGREES, (count, bone_count))) / 2
    rotations = np.concatenate([np.cos(half)[..., None], np.sin(half)[..., None] * axes], axis=2)
    return PoseSet(rotations, rng.uniform(-ROOT_TRANSLATION, ROOT_TRANSLATION, (count, 3)))


def apply_pose(pose_bones, poses: PoseSet, index: int) -> None:
    """Assigns through RNA (not foreach_set) so Blender's update callbacks tag the armature as a user would."""
    for pose_bone, rotation in zip(pose_bones, poses.rotations[index].tolist()):
        pose_bone.rotation_quaternion = rotation
    pose_bones[0].location = poses.root_offsets[index].tolist()


def pose_bones_in_order(armature_object, names):
    return [armature_object.pose.bones[n] for n in names]


# --------------------------------------------------------------------------------------------------
# Blender timing.


def read_to_mesh(mesh_object, depsgraph, out: np.ndarray) -> None:
    """The usual way: a copy of the evaluated mesh, read with vertices.foreach_get('co')."""
    evaluated = mesh_object.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    mesh.vertices.foreach_get("co", out)
    evaluated.to_mesh_clear()


def read_to_mesh_position_attribute(mesh_object, depsgraph, out: np.ndarray) -> None:
    """The same copy, read through the "position" attribute: Blender's foreach_get then takes its raw
    memcpy path, while MeshVertex.co goes through RNA per vertex (~50x slower at 100k vertices)."""
    evaluated = mesh_object.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    mesh.attributes["position"].data.foreach_get("vector", out)
    evaluated.to_mesh_clear()


def blender_reference(armature_object, mesh_object, pose_bones, poses: PoseSet, names):
    """Per pose: G (from the evaluated pose bones, as skinkit.blender reads them) and Blender's positions.

    Also the first warm-up of the depsgraph (relations, first evaluation, allocations).
    """
    depsgraph = bpy.context.evaluated_depsgraph_get()
    vertex_count = len(mesh_object.data.vertices)
    matrices = np.empty((len(poses.rotations), len(names) + 1, 4, 4))
    positions = np.empty((len(poses.rotations), vertex_count, 3), np.float32)
    for index in range(len(poses.rotations)):
        apply_pose(pose_bones, poses, index)
        depsgraph.update()
        matrices[index] = rig.pose_matrices(armature_object, depsgraph, [rig.ROOT_NAME] + names, np.eye(4))
        read_to_mesh_position_attribute(mesh_object, depsgraph, positions[index].reshape(-1))
    return matrices, positions


def blender_pass(mesh_object, pose_bones, poses: PoseSet, reader) -> dict:
    """One pass over all poses; seconds summed per phase: set the pose, evaluate, read positions."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    out = np.empty(len(mesh_object.data.vertices) * 3, np.float32)
    totals = {"set": 0.0, "evaluate": 0.0, "read": 0.0}
    for index in range(len(poses.rotations)):
        started = time.perf_counter()
        apply_pose(pose_bones, poses, index)
        set_done = time.perf_counter()
        depsgraph.update()
        evaluated = time.perf_counter()
        if reader is not None:
            reader(mesh_object, depsgraph, out)
        totals["set"] += set_done - started
        totals["evaluate"] += evaluated - set_done
        totals["read"] += time.perf_counter() - evaluated
    return totals


BLENDER_READERS = (
    ("evaluate only", None, "depsgraph.update(): armature pose + Armature modifier"),
    ("evaluate + read (to_mesh, co)", read_to_mesh, "to_mesh() + vertices.foreach_get('co') + to_mesh_clear()"),
    ("evaluate + read (to_mesh, position attr.)", read_to_mesh_position_attribute,
     "to_mesh() + attributes['position'].data.foreach_get('vector') + to_mesh_clear()"),
)


def blender_methods(mesh_object, pose_bones, poses: PoseSet) -> dict:
    """Linear and preserve volume, each without reading and with each way of reading the positions."""
    modifier = mesh_object.modifiers["Armature"]

    def method(preserve: bool, reader):
        def run() -> dict:
            if modifier.use_deform_preserve_volume != preserve:
                modifier.use_deform_preserve_volume = preserve
                bpy.context.evaluated_depsgraph_get().update()  # the switch's own re-evaluation is not timed
            totals, usage = with_usage(lambda: blender_pass(mesh_object, pose_bones, poses, reader))
            return {"seconds": totals["evaluate"] + totals["read"]} | totals | usage
        return run

    return {f"Blender {label}, {how}": (method(preserve, reader), note)
            for label, preserve in (("linear", False), ("preserve volume", True))
            for how, reader, note in BLENDER_READERS}


# --------------------------------------------------------------------------------------------------
# skinkit and numpy.


@dataclass
class SkinData:
    """The rig as skinkit sees it, plus dense (V, K) views for the numpy implementations."""

    skeleton: skinkit.Skeleton
    weights: skinkit.SparseWeights
    rest: np.ndarray  # (V, 3) float64
    model: skinkit.AnimationSpaceModel
    dense_bones: np.ndarray  # (V, K) int32
    dense_weights: np.ndarray  # (V, K) float32
    dense_coordinates: np.ndarray  # (V, K, 4) float32


def skin_data(mesh_object, influences: int) -> SkinData:
    """Reads skeleton, weights and rest positions back from Blender exactly as convert_object does."""
    found = rig.rig_of(mesh_object)
    bind = rig.bind_matrix(found, bpy.context.evaluated_depsgraph_get())
    skeleton = rig.skeleton_of(found, bind)
    weights = rig.deform_weights(found)
    rest = rig.rest_positions(mesh_object)
    if not (weights.counts() == influences).all() or not np.allclose(weights.totals(), 1.0, atol=1e-12):
        raise RuntimeError("the scene's weights are not exactly `influences` per vertex summing to 1")
    model = skinkit.convert_lbs(skeleton, weights, rest)
    shape = (weights.vertex_count, influences)
    return SkinData(skeleton, weights, rest, model, weights.bones.reshape(shape),
                    weights.weights.reshape(shape).astype(np.float32),
                    model.coordinates.reshape(*shape, 4).astype(np.float32))


def numpy_lbs(data: SkinData, poses: np.ndarray, rest_inverse: np.ndarray, rest32: np.ndarray) -> np.ndarray:
    """Vectorised LBS in float32: blend the K skinning matrices per vertex first (one einsum over the
    gathered (V, K, 3, 4) stack), then apply the blended 3x4 matrix (the fastest of the variants tried)."""
    out = np.empty((len(poses), len(rest32), 3), np.float32)
    for pose, result in zip(poses, out):
        skinning = (pose @ rest_inverse)[:, :3, :].astype(np.float32)
        blended = np.einsum("vk,vkij->vij", data.dense_weights, skinning[data.dense_bones])
        np.add(np.einsum("vij,vj->vi", blended[:, :, :3], rest32), blended[:, :, 3], out=result)
    return out


def numpy_as(data: SkinData, poses: np.ndarray) -> np.ndarray:
    """Vectorised animation space in float32: v = sum_k G[bone_k] p_k, one gather + einsum per slot
    (one einsum over the whole (V, K, 3, 4) stack is ~3x slower: numpy does not vectorise its k sum)."""
    out = np.empty((len(poses), data.model.vertex_count, 3), np.float32)
    bones, coordinates = data.dense_bones, data.dense_coordinates
    for pose, result in zip(poses, out):
        frames = pose[:, :3, :].astype(np.float32)
        np.einsum("vij,vj->vi", frames[bones[:, 0]], coordinates[:, 0], out=result)
        for slot in range(1, bones.shape[1]):
            result += np.einsum("vij,vj->vi", frames[bones[:, slot]], coordinates[:, slot])
    return out


def library_functions(data: SkinData, poses: np.ndarray, threads: int) -> dict:
    """name -> (function evaluating all poses, whether it returns the (poses, V, 3) stack to check)."""
    rest32 = data.rest.astype(np.float32)
    rest_inverse = np.linalg.inv(data.skeleton.rest_frames)
    poses32 = poses.astype(np.float32)
    model, skeleton, weights = data.model, data.skeleton, data.weights

    # Batched rows fill one preallocated (poses, V, 3) buffer through `out=`, as a caller replaying many
    # frames should: a fresh 120-240 MB array per call would time the kernel's page faults instead.
    out32 = np.empty((len(poses), model.vertex_count, 3), np.float32)
    out64 = np.empty((len(poses), model.vertex_count, 3), np.float64)

    def per_pose_calls():  # what a live preview does: one call, one new (V, 3) result per pose
        for pose in poses32:
            model.evaluate(pose, dtype=np.float32, threads=threads)

    return {
        "skinkit LBS f32": (lambda: skinkit.lbs_evaluate(skeleton, weights, rest32, poses, dtype=np.float32,
                                                         threads=threads, out=out32), True),
        "skinkit LBS f32, 1 thread": (lambda: skinkit.lbs_evaluate(skeleton, weights, rest32, poses,
                                                                   dtype=np.float32, threads=1, out=out32), True),
        "skinkit AS f32": (lambda: model.evaluate(poses32, dtype=np.float32, threads=threads, out=out32), True),
        "skinkit AS f32, 1 thread": (lambda: model.evaluate(poses32, dtype=np.float32, threads=1, out=out32), True),
        "skinkit AS f32, one call per pose": (per_pose_calls, False),
        "skinkit AS f64": (lambda: model.evaluate(poses, dtype=np.float64, threads=threads, out=out64), True),
        "numpy LBS f32": (lambda: numpy_lbs(data, poses, rest_inverse, rest32), True),
        "numpy AS f32": (lambda: numpy_as(data, poses32), True),
    }


def with_usage(function) -> tuple:
    """function()'s result, and the wall seconds, minor page faults and user and system CPU seconds of the
    whole process meanwhile: CPU / wall shows how many threads ran, system time mostly the kernel
    providing fresh zeroed pages for large new arrays."""
    before = resource.getrusage(resource.RUSAGE_SELF)
    started = time.perf_counter()
    result = function()
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_SELF)
    return result, {"wall_seconds": wall, "minor_faults": after.ru_minflt - before.ru_minflt,
                    "user_seconds": after.ru_utime - before.ru_utime,
                    "system_seconds": after.ru_stime - before.ru_stime}


def timed_call(function):
    """One timed run of `function`; its result is freed outside the timed region, so only one is alive."""
    def run() -> dict:
        result, usage = with_usage(function)
        del result
        return {"seconds": usage["wall_seconds"]} | usage
    return run


def deviations_from(reference: np.ndarray, functions: dict, diagonal: float) -> dict:
    """Max |v - v_blender| / diagonal over all poses and vertices, for each function returning the stack."""
    result = {}
    for name, (function, returns_stack) in functions.items():
        if returns_stack:
            values = function()
            result[name] = float(np.linalg.norm(values - reference, axis=2).max()) / diagonal
            del values
    return result


# --------------------------------------------------------------------------------------------------
# Timing harness.


def round_robin(methods: dict, rounds: int, seed: int, warmup_rounds: int = 1) -> dict:
    """Runs every method once per round and returns each one's samples of the timed rounds.

    Interleaving makes slow drifts of the machine hit every method alike: on the 2-vCPU KVM guest this was
    written on, the same depsgraph update took 4 ms in one phase of a run and 8-20 ms in another. The order
    is shuffled (seeded) each round because a method could be slowed by the one before it: there, threaded
    skinkit calls right after Blender's passes were sometimes twice as slow, all of it system time.
    """
    samples = {name: [] for name in methods}
    names, rng = list(methods), np.random.default_rng(seed)
    for round_index in range(warmup_rounds + rounds):
        for name in (names[i] for i in rng.permutation(len(names))):
            run = methods[name]
            log(f"round {round_index + 1 - warmup_rounds:>2}/{rounds}: {name}")
            sample = run()
            if round_index >= warmup_rounds:
                samples[name].append(sample)
    return samples


# --------------------------------------------------------------------------------------------------
# Live preview, on a smaller copy of the body.


def median_ms(values) -> float:
    return 1e3 * statistics.median(values)


def time_updates(pose_bones, poses: PoseSet, changes: int) -> list[float]:
    """Seconds of the depsgraph update after each of `changes` pose changes."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    times = []
    for index in range(changes):
        apply_pose(pose_bones, poses, index % len(poses.rotations))
        started = time.perf_counter()
        depsgraph.update()
        times.append(time.perf_counter() - started)
    return times


def time_preview_refreshes(mesh_object, pose_bones, poses: PoseSet, changes: int, references) -> dict:
    """Per pose change with the preview on: the depsgraph update the change triggers, preview.refresh, and
    the update that applies the new shape key; checks what is shown against Blender's linear result."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    phases = {"pose_update": [], "refresh": [], "mesh_update": []}
    worst = 0.0
    for index in range(changes):
        apply_pose(pose_bones, poses, index % len(poses.rotations))
        started = time.perf_counter()
        depsgraph.update()
        pose_done = time.perf_counter()
        preview.refresh(mesh_object, depsgraph)
        refreshed = time.perf_counter()
        depsgraph.update()
        phases["pose_update"].append(pose_done - started)
        phases["refresh"].append(refreshed - pose_done)
        phases["mesh_update"].append(time.perf_counter() - refreshed)
        if index < len(references):
            shown = evaluated_positions(mesh_object, depsgraph)
            worst = max(worst, float(np.linalg.norm(shown - references[index], axis=1).max()))
    return {"phases": phases, "max_deviation": worst}


def refresh_breakdown(mesh_object, armature_object, pose_bones, poses: PoseSet, changes: int) -> dict:
    """Median ms of the parts of preview.refresh, and of two alternatives for its two costly parts."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    stored = preview.stored_model(mesh_object)
    key = mesh_object.data.shape_keys.key_blocks[preview.KEY_NAME]
    pose = rig.pose_matrices(armature_object, depsgraph, stored.bone_names, stored.bind).astype(np.float32)
    flat = stored.model.evaluate(pose, np.float32).reshape(-1)
    parts = {
        "pose_matrices": lambda: rig.pose_matrices(armature_object, depsgraph, stored.bone_names, stored.bind),
        "model.evaluate f32, threads=0 (as refresh does)": lambda: stored.model.evaluate(pose, np.float32),
        "model.evaluate f32, threads=1": lambda: stored.model.evaluate(pose, np.float32, 1),
        "key_block.data.foreach_set('co') (the slow per-item path)": lambda: key.data.foreach_set("co", flat),
        "key_block.points.foreach_set('co') (as refresh does)": lambda: key.points.foreach_set("co", flat),
    }
    times = {name: [] for name in parts}
    for index in range(changes):
        apply_pose(pose_bones, poses, index % len(poses.rotations))
        depsgraph.update()  # the parts run between updates, as they do in refresh
        for name, part in parts.items():
            started = time.perf_counter()
            part()
            times[name].append(time.perf_counter() - started)
    return {name: median_ms(values) for name, values in times.items()}


def preview_benchmark(armature_object, layout, poses: PoseSet, vertex_count: int, influences: int,
                      changes: int) -> dict:
    names = layout[0]
    mesh_object = build_skinned_mesh("bench_preview_body", armature_object, layout, vertex_count, influences)
    pose_bones = pose_bones_in_order(armature_object, names)
    started = time.perf_counter()
    skinning.convert_object(mesh_object)
    convert_seconds = time.perf_counter() - started
    diagonal = skinning.bounding_box_diagonal(rig.rest_positions(mesh_object))
    modifier = mesh_object.modifiers["Armature"]
    depsgraph = bpy.context.evaluated_depsgraph_get()

    time_updates(pose_bones, poses, changes)  # warm-up
    with_modifier = time_updates(pose_bones, poses, changes)
    references = []
    for index in range(min(changes, 5)):
        apply_pose(pose_bones, poses, index)
        depsgraph.update()
        references.append(evaluated_positions(mesh_object, depsgraph))
    modifier.show_viewport = False
    time_updates(pose_bones, poses, changes)
    armature_only = time_updates(pose_bones, poses, changes)
    modifier.show_viewport = True
    depsgraph.update()

    preview.enable(mesh_object, depsgraph)
    try:
        time_preview_refreshes(mesh_object, pose_bones, poses, changes, [])  # warm-up
        measured = time_preview_refreshes(mesh_object, pose_bones, poses, changes, references)
        breakdown = refresh_breakdown(mesh_object, armature_object, pose_bones, poses, changes)
    finally:
        preview.disable(mesh_object)
    phases = measured["phases"]
    total = [sum(step) for step in zip(*phases.values())]
    return {
        "vertices": len(mesh_object.data.vertices), "changes": changes, "convert_seconds": convert_seconds,
        "blender_update_with_modifier_ms": median_ms(with_modifier),
        "blender_update_armature_only_ms": median_ms(armature_only),
        "preview_pose_update_ms": median_ms(phases["pose_update"]),
        "preview_refresh_ms": median_ms(phases["refresh"]),
        "preview_mesh_update_ms": median_ms(phases["mesh_update"]),
        "preview_total_ms": median_ms(total),
        "preview_max_deviation_over_diagonal": measured["max_deviation"] / diagonal,
        "refresh_breakdown_ms": breakdown,
    }


# --------------------------------------------------------------------------------------------------
# Reporting.


def make_rows(samples: dict, notes: dict, vertex_count: int, pose_count: int, baseline: str) -> list[dict]:
    """One row per method: the median run, throughput, per-pose time, ratio to the baseline, all samples."""
    rows = []
    for method, runs in samples.items():
        seconds = statistics.median(r["seconds"] for r in runs)
        every = [1e3 * r["seconds"] / pose_count for r in runs]
        rows.append({"method": method, "seconds": seconds, "ms_per_pose": 1e3 * seconds / pose_count,
                     "ms_per_pose_min": min(every), "ms_per_pose_max": max(every),
                     "cpu_per_wall": statistics.median(
                         (r["user_seconds"] + r["system_seconds"]) / r["wall_seconds"] for r in runs),
                     "system_per_wall": statistics.median(r["system_seconds"] / r["wall_seconds"] for r in runs),
                     "mverts_per_s": vertex_count * pose_count / seconds / 1e6, "note": notes.get(method, ""),
                     "runs": runs})
    reference = next(r for r in rows if r["method"] == baseline)["mverts_per_s"]
    for r in rows:
        r["ratio_to_blender_linear"] = r["mverts_per_s"] / reference
    return rows


def markdown_report(results: dict) -> str:
    info, setup, rows = results["info"], results["setup"], results["rows"]
    deviations, live = results["max_deviation_over_diagonal"], results["live_preview"]
    lines = [f"# Skinning evaluation: {setup['vertices']} vertices, {setup['bones']} bones, "
             f"{setup['influences']} influences, {setup['poses']} poses", "",
             f"{machine_line(info)}) · bpy {info['bpy']} · "
             f"numpy {info['numpy']} · skinkit {info['skinkit']}", "", f"`{info['command']}`", "",
             f"Median of {setup['rounds']} rounds over all poses, methods in shuffled order each round. "
             "Ratio: throughput / throughput of *Blender linear, evaluate only*.", "",
             "Last columns: the range over rounds, and the process's CPU time per wall second (all threads; "
             "in brackets its system part, mostly page faults of new result arrays).", "",
             "| method | Mverts/s | ms per pose | ratio to Blender linear | ms per pose, all rounds | CPU / wall |",
             "|---|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['method']} | {r['mverts_per_s']:.1f} | {r['ms_per_pose']:.3f} | "
              f"{r['ratio_to_blender_linear']:.2f} | {r['ms_per_pose_min']:.2f}–{r['ms_per_pose_max']:.2f} | "
              f"{r['cpu_per_wall']:.2f} ({r['system_per_wall']:.2f}) |" for r in rows]
    lines += ["", "Max deviation from Blender's linear Armature modifier over all poses and vertices, "
              "divided by the rest bounding-box diagonal:", "", "| method | max deviation / diagonal |",
              "|---|---:|"]
    lines += [f"| {method} | {value:.2e} |" for method, value in deviations.items()]
    lines += ["", f"Live preview, {live['vertices']} vertices, median over {live['changes']} pose changes:", "",
              "| step | ms |", "|---|---:|",
              f"| Blender: depsgraph update, armature + Armature modifier | {live['blender_update_with_modifier_ms']:.3f} |",
              f"| Blender: depsgraph update, armature only (modifier off) | {live['blender_update_armature_only_ms']:.3f} |",
              f"| preview: depsgraph update after the pose change | {live['preview_pose_update_ms']:.3f} |",
              f"| preview: `preview.refresh` | {live['preview_refresh_ms']:.3f} |",
              f"| preview: depsgraph update applying the shape key | {live['preview_mesh_update_ms']:.3f} |",
              f"| preview: total | {live['preview_total_ms']:.3f} |", "",
              "Parts of `preview.refresh`, and alternatives:", "", "| part | ms |", "|---|---:|"]
    lines += [f"| {name} | {value:.3f} |" for name, value in live["refresh_breakdown_ms"].items()]
    lines += ["", f"Preview vs Blender linear, max deviation / diagonal: "
              f"{live['preview_max_deviation_over_diagonal']:.2e}; `convert_object` took "
              f"{live['convert_seconds']:.2f} s."]
    return "\n".join(lines) + "\n"


def print_summary(results: dict) -> None:
    print(f"\n{'method':<58} {'Mverts/s':>9} {'ms/pose':>9} {'x Blender lin.':>15}")
    for r in results["rows"]:
        print(f"{r['method']:<58} {r['mverts_per_s']:>9.1f} {r['ms_per_pose']:>9.3f} "
              f"{r['ratio_to_blender_linear']:>15.2f}")
    print("\nmax deviation from Blender linear / bounding-box diagonal:")
    for method, value in results["max_deviation_over_diagonal"].items():
        print(f"  {method:<40} {value:.2e}")
    print("\nlive preview:", json.dumps(results["live_preview"], indent=1))


# --------------------------------------------------------------------------------------------------


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--vertices", type=int, default=100000, help=f"target vertex count (whole rings of {SIDES})")
    parser.add_argument("--bones", type=int, default=24)
    parser.add_argument("--influences", type=int, default=4)
    parser.add_argument("--poses", type=int, default=100)
    parser.add_argument("--rounds", type=int, default=7, help="timed rounds over every method (median)")
    parser.add_argument("--threads", type=int, default=0, help="skinkit threads, 0 = one per core")
    parser.add_argument("--preview-vertices", type=int, default=20000)
    parser.add_argument("--preview-changes", type=int, default=30)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", help="write the results here")
    parser.add_argument("--markdown", help="write a Markdown report here")
    args = parser.parse_args(argv)
    if not 1 <= args.influences <= args.bones:
        parser.error("--influences must be between 1 and --bones")
    return args


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def main(argv=None) -> dict:
    args = parse_args(argv)
    info = machine_info() | {"parallel_speedup_before": parallel_speedup()}
    bpy.ops.wm.read_factory_settings(use_empty=True)
    layout = skeleton_layout(args.bones)
    names = layout[0]
    armature_object = build_armature(*layout[:4])
    log("building the scene ...")
    mesh_object = build_skinned_mesh("bench_body", armature_object, layout, args.vertices, args.influences)
    pose_bones = pose_bones_in_order(armature_object, names)
    poses = random_poses(args.poses, len(names), args.seed)
    vertex_count, face_count = len(mesh_object.data.vertices), len(mesh_object.data.polygons)

    data = skin_data(mesh_object, args.influences)
    diagonal = skinning.bounding_box_diagonal(data.rest)
    log("reading Blender's poses and positions ...")
    matrices, reference = blender_reference(armature_object, mesh_object, pose_bones, poses, names)
    functions = library_functions(data, matrices, args.threads)
    deviations = deviations_from(reference, functions, diagonal)
    del reference
    blender = blender_methods(mesh_object, pose_bones, poses)
    methods = {name: run for name, (run, _) in blender.items()}
    methods |= {name: timed_call(function) for name, (function, _) in functions.items()}
    samples = round_robin(methods, args.rounds, args.seed)
    notes = {name: note for name, (_, note) in blender.items()}
    rows = make_rows(samples, notes, vertex_count, args.poses, "Blender linear, evaluate only")

    remove_object(mesh_object)  # the preview mesh must be the only one the armature deforms
    log("live preview ...")
    live = preview_benchmark(armature_object, layout, poses, args.preview_vertices, args.influences,
                             args.preview_changes)

    info["parallel_speedup_after"] = parallel_speedup()
    setup = {"vertices": vertex_count, "faces": face_count, "bones": len(names), "influences": args.influences,
             "poses": args.poses, "rounds": args.rounds, "seed": args.seed, "threads": args.threads,
             "max_angle_degrees": MAX_ANGLE_DEGREES, "diagonal": diagonal}
    results = {"info": info, "setup": setup, "rows": rows, "max_deviation_over_diagonal": deviations,
               "live_preview": live}
    print_summary(results)
    write_outputs(results, args.json, args.markdown, markdown_report)
    return results


if __name__ == "__main__":
    main()
