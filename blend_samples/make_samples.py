"""Build the skinkit sample scenes procedurally and save them as .blend files.

    .venv/bin/python blend_samples/make_samples.py --out blend_samples

writes arm.blend and creature.blend, reloads each one, checks it and prints a
summary. Exits non-zero if a check fails. Nothing is random, so every run
produces the same geometry, weights and animation.
"""

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import bpy
import numpy as np
from mathutils import Euler, Matrix, Quaternion, Vector

MAX_INFLUENCES = 4
# A bone gets weight while its score is within BLEND_WIDTH of the best bone's score.
BLEND_WIDTH = 0.2
# Distance past a bone's end counts this many times more than distance from its
# axis, so thick body parts do not blend across whole segments.
AXIAL_STIFFNESS = 3.0
MIN_DISPLACEMENT = 0.05
WEIGHT_SUM_TOLERANCE = 1e-6


@dataclass(frozen=True)
class BoneSpec:
    name: str
    head: tuple
    tail: tuple
    parent: str | None = None
    connect: bool = False
    deform: bool = True


@dataclass(frozen=True)
class TubeSpec:
    """A capped tube around a polyline, skinned to a set of candidate bones."""

    path: tuple
    radius: Callable[[np.ndarray], np.ndarray]  # arc-length fraction 0..1 -> radius
    sides: int
    rings: int
    bones: tuple


# --------------------------------------------------------------------------
# Geometry


def radius_profile(*points):
    """Piecewise-linear radius over the tube's arc-length fraction."""
    fractions, radii = zip(*points)
    return lambda u: np.interp(u, fractions, radii)


def cut_corners(points, iterations=3):
    """Chaikin corner cutting, keeping the end points: rings around a sharp
    corner of the path would intersect each other on the inside of the bend."""
    for _ in range(iterations):
        starts, ends = points[:-1], points[1:]
        cuts = np.stack([0.75 * starts + 0.25 * ends, 0.25 * starts + 0.75 * ends], axis=1).reshape(-1, 3)
        points = np.vstack([points[0], cuts, points[-1]])
    return points


def resample_polyline(points, count):
    """`count` points evenly spaced by arc length, and their arc-length fractions."""
    points = cut_corners(np.asarray(points, dtype=float))
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    samples = np.linspace(0.0, arc[-1], count)
    resampled = np.column_stack([np.interp(samples, arc, points[:, k]) for k in range(3)])
    return resampled, samples / arc[-1]


def tube_geometry(spec, reference_axis, first_index=0):
    """Vertices and faces (quads plus triangle-fan caps) with outward normals;
    face indices start at first_index so tubes can be joined into one mesh.

    reference_axis must never be parallel to the path; it fixes where each
    ring starts so rings do not twist.
    """
    path, fractions = resample_polyline(spec.path, spec.rings)
    tangents = np.gradient(path, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    normals = np.cross(reference_axis, tangents)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    binormals = np.cross(tangents, normals)

    angles = np.linspace(0.0, 2.0 * math.pi, spec.sides, endpoint=False)
    directions = (np.cos(angles)[None, :, None] * normals[:, None, :]
                  + np.sin(angles)[None, :, None] * binormals[:, None, :])
    rings = path[:, None, :] + spec.radius(fractions)[:, None, None] * directions
    vertices = np.vstack([rings.reshape(-1, 3), path[0], path[-1]])

    ring_index = first_index + np.arange(spec.rings * spec.sides).reshape(spec.rings, spec.sides)
    next_index = np.roll(ring_index, -1, axis=1)
    quads = np.stack([ring_index[:-1], next_index[:-1], next_index[1:], ring_index[1:]], axis=-1)
    start_center, end_center = first_index + len(vertices) - 2, first_index + len(vertices) - 1
    start_fan = np.stack([np.full(spec.sides, start_center), next_index[0], ring_index[0]], axis=-1)
    end_fan = np.stack([np.full(spec.sides, end_center), ring_index[-1], next_index[-1]], axis=-1)
    faces = quads.reshape(-1, 4).tolist() + start_fan.tolist() + end_fan.tolist()
    return vertices, faces


def transform_points(matrix, points):
    matrix = np.array(matrix)
    return points @ matrix[:3, :3].T + matrix[:3, 3]


# --------------------------------------------------------------------------
# Weights


def segment_scores(points, heads, tails):
    """(points x bones) distance to each bone segment, with the part beyond the
    segment's ends scaled by AXIAL_STIFFNESS."""
    axes = tails - heads
    lengths = np.linalg.norm(axes, axis=1)
    units = axes / lengths[:, None]
    relative = points[:, None, :] - heads[None, :, :]
    along = np.einsum("nbk,bk->nb", relative, units)
    radial = np.linalg.norm(relative - along[..., None] * units[None], axis=2)
    overshoot = np.maximum(0.0, np.maximum(-along, along - lengths))
    return np.hypot(radial, AXIAL_STIFFNESS * overshoot)


def skin_weights(points, heads, tails):
    """Smooth weights: the closest bone gets 1 before normalising, bones fade out
    over BLEND_WIDTH beyond it, only the MAX_INFLUENCES largest survive."""
    scores = segment_scores(points, heads, tails)
    closeness = np.clip(1.0 - (scores - scores.min(axis=1, keepdims=True)) / BLEND_WIDTH, 0.0, 1.0)
    weights = closeness * closeness * (3.0 - 2.0 * closeness)  # smoothstep
    if weights.shape[1] > MAX_INFLUENCES:
        weakest = np.argpartition(weights, -MAX_INFLUENCES, axis=1)[:, :-MAX_INFLUENCES]
        np.put_along_axis(weights, weakest, 0.0, axis=1)
    return weights / weights.sum(axis=1, keepdims=True)


def build_skinned_tubes(tubes, bones, reference_axis):
    """Join the tubes into one vertex/face list and a (vertices x deform bones) weight matrix."""
    deform_names = [bone.name for bone in bones if bone.deform]
    bone_by_name = {bone.name: bone for bone in bones}
    all_vertices, all_faces, weight_blocks = [], [], []
    for tube in tubes:
        vertices, faces = tube_geometry(tube, reference_axis, first_index=sum(map(len, all_vertices)))
        heads = np.array([bone_by_name[name].head for name in tube.bones], dtype=float)
        tails = np.array([bone_by_name[name].tail for name in tube.bones], dtype=float)
        block = np.zeros((len(vertices), len(deform_names)))
        block[:, [deform_names.index(name) for name in tube.bones]] = skin_weights(vertices, heads, tails)
        all_vertices.append(vertices)
        all_faces += faces
        weight_blocks.append(block)
    return np.vstack(all_vertices), all_faces, np.vstack(weight_blocks), deform_names


# --------------------------------------------------------------------------
# Scene building


def new_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = 'CYCLES'
    scene.cycles.device = 'CPU'
    scene.cycles.samples = 16
    scene.render.resolution_x, scene.render.resolution_y = 640, 400
    scene.render.resolution_percentage = 100
    # Without a world Cycles renders everything the sun misses pitch black.
    scene.world = bpy.data.worlds.new("world")
    scene.world.color = (0.05, 0.05, 0.06)
    return scene


def build_armature(scene, name, bones, bend_axis, world_matrix):
    armature = bpy.data.armatures.new(name)
    armature_obj = bpy.data.objects.new(name, armature)
    scene.collection.objects.link(armature_obj)
    armature_obj.matrix_world = world_matrix
    # Edit bones can only be created in edit mode; no data-API alternative exists.
    bpy.context.view_layer.objects.active = armature_obj
    bpy.ops.object.mode_set(mode='EDIT')
    for spec in bones:
        edit_bone = armature.edit_bones.new(spec.name)
        edit_bone.head, edit_bone.tail = spec.head, spec.tail
        # Pin every bone's local X to bend_axis (align_roll sets local Z) so
        # rotations about X bend in one known plane; Blender's default roll
        # flips X for bones that point exactly along -Y.
        direction = np.subtract(spec.tail, spec.head)
        edit_bone.align_roll(Vector(np.cross(bend_axis, direction)))
        edit_bone.use_deform = spec.deform
        if spec.parent:
            edit_bone.parent = armature.edit_bones[spec.parent]
            edit_bone.use_connect = spec.connect
    bpy.ops.object.mode_set(mode='OBJECT')
    return armature_obj


def write_vertex_groups(mesh_obj, bone_names, weights):
    for column, name in enumerate(bone_names):
        group = mesh_obj.vertex_groups.new(name=name)
        influenced = np.flatnonzero(weights[:, column])
        values = weights[influenced, column]
        rigid = values == 1.0
        if rigid.any():
            group.add(influenced[rigid].tolist(), 1.0, 'REPLACE')
        for index, value in zip(influenced[~rigid].tolist(), values[~rigid].tolist()):
            group.add([index], value, 'REPLACE')


def build_skinned_mesh(scene, name, vertices, faces, weights, bone_names,
                       armature_obj, armature_world, offset):
    """Mesh parented to the armature, sitting at `offset` relative to it.

    `vertices` are in armature space; they are stored in the mesh's own space
    so the skin lines up with the bones while the two objects' matrices differ.
    """
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(transform_points(offset.inverted(), vertices).tolist(), [], faces)
    if mesh.validate():
        raise RuntimeError(f"{name}: generated mesh was invalid and had to be repaired")
    mesh.shade_smooth()

    mesh_obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(mesh_obj)
    mesh_obj.matrix_world = armature_world @ offset
    # Same as Ctrl+P > Object: the parent inverse cancels the armature's
    # transform so the mesh stays where it is.
    mesh_obj.parent = armature_obj
    mesh_obj.parent_type = 'OBJECT'
    mesh_obj.matrix_parent_inverse = armature_world.inverted()

    write_vertex_groups(mesh_obj, bone_names, weights)
    add_armature_modifier(mesh_obj, armature_obj)
    return mesh_obj


def add_armature_modifier(mesh_obj, armature_obj):
    """Deforms mesh_obj by armature_obj through its vertex groups alone (no bone envelopes), by plain linear
    blending (no preserve volume): the skinning that skinkit reproduces."""
    modifier = mesh_obj.modifiers.new("Armature", 'ARMATURE')
    modifier.object = armature_obj
    modifier.use_vertex_groups = True
    modifier.use_bone_envelopes = False
    modifier.use_deform_preserve_volume = False
    return modifier


def animate(scene, armature_obj, action_name, rotation_mode, keyed_poses):
    """keyed_poses: (frame, {bone: {pose-bone property: value}}) pairs."""
    action = bpy.data.actions.new(action_name)
    armature_obj.animation_data_create().action = action
    for pose_bone in armature_obj.pose.bones:
        pose_bone.rotation_mode = rotation_mode
    for frame, pose in keyed_poses:
        for bone_name, channels in pose.items():
            pose_bone = armature_obj.pose.bones[bone_name]
            for prop, value in channels.items():
                setattr(pose_bone, prop, value)
                pose_bone.keyframe_insert(prop, frame=frame, group=bone_name)
    scene.frame_start, scene.frame_end = (int(round(f)) for f in action.frame_range)
    scene.frame_set(scene.frame_start)


def evaluated_local_coords(scene, obj, frame):
    scene.frame_set(frame)
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    mesh = evaluated.to_mesh()
    coords = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", coords)
    evaluated.to_mesh_clear()
    return coords.reshape(-1, 3)


def animated_world_points(scene, mesh_obj):
    """World positions of the deformed mesh at every 4th frame of the animation."""
    frames = list(range(scene.frame_start, scene.frame_end + 1, 4)) + [scene.frame_end]
    points = np.vstack([transform_points(mesh_obj.matrix_world, evaluated_local_coords(scene, mesh_obj, f))
                        for f in frames])
    scene.frame_set(scene.frame_start)
    return points


def add_camera(scene, points, view_direction):
    """Look at the points' box centre from view_direction (world), close enough
    that every point stays inside the frame with a small margin."""
    camera = bpy.data.cameras.new("camera")
    camera.sensor_fit = 'HORIZONTAL'
    tan_half_x = camera.sensor_width / 2.0 / camera.lens
    tan_half_y = tan_half_x * scene.render.resolution_y / scene.render.resolution_x
    direction = Vector(view_direction).normalized()
    rotation = (-direction).to_track_quat('-Z', 'Y')
    right, up = np.array(rotation.to_matrix()).T[:2]

    center = (points.min(axis=0) + points.max(axis=0)) / 2.0
    relative = points - center
    # A point at depth d towards the camera and lateral offset s is in frame
    # when s <= (distance - d) * tan(half field of view).
    needed = relative @ np.array(direction) + np.maximum(np.abs(relative @ right) / tan_half_x,
                                                          np.abs(relative @ up) / tan_half_y)
    # Plain float: a numpy scalar times a mathutils Vector gives an ndarray.
    distance = 1.1 * float(needed.max())
    camera.clip_end = 2.0 * distance
    camera_obj = bpy.data.objects.new("camera", camera)
    camera_obj.location = Vector(center) + distance * direction
    camera_obj.rotation_euler = rotation.to_euler()
    scene.collection.objects.link(camera_obj)
    scene.camera = camera_obj


def add_sun(scene, view_direction):
    sun = bpy.data.lights.new("sun", 'SUN')
    sun.energy = 3.0
    sun_obj = bpy.data.objects.new("sun", sun)
    # Light from the camera's side and above so the visible faces are lit.
    toward_sun = Vector(view_direction).normalized() + Vector((0.0, 0.0, 1.5))
    sun_obj.rotation_euler = (-toward_sun).to_track_quat('-Z', 'Y').to_euler()
    scene.collection.objects.link(sun_obj)


def save(path):
    # Remove the old file first so Blender does not leave a .blend1 backup.
    path.unlink(missing_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True)


def build_sample(path, bones, tubes, bend_axis, reference_axis, armature_world, mesh_offset,
                 action_name, rotation_mode, keyed_poses, view_direction):
    scene = new_scene()
    name = path.stem
    armature_obj = build_armature(scene, name + "_rig", bones, bend_axis, armature_world)
    vertices, faces, weights, deform_names = build_skinned_tubes(tubes, bones, reference_axis)
    mesh_obj = build_skinned_mesh(scene, name, vertices, faces, weights, deform_names,
                                  armature_obj, armature_world, mesh_offset)
    animate(scene, armature_obj, action_name, rotation_mode, keyed_poses)
    # view_direction is given relative to the character, so turn it with the armature.
    world_view_direction = armature_world.to_3x3() @ Vector(view_direction)
    add_camera(scene, animated_world_points(scene, mesh_obj), world_view_direction)
    add_sun(scene, world_view_direction)
    save(path)


# --------------------------------------------------------------------------
# Sample 1: arm


ARM_BONES = (
    BoneSpec("upper", (0.0, 0.0, 0.0), (1.2, 0.0, 0.0)),
    BoneSpec("fore", (1.2, 0.0, 0.0), (2.3, 0.0, 0.0), parent="upper", connect=True),
    BoneSpec("hand", (2.3, 0.0, 0.0), (3.0, 0.0, 0.0), parent="fore", connect=True),
)

# frame, shoulder lift, elbow bend, forearm twist, wrist bend (degrees), shoulder shrug (units)
ARM_KEYS = (
    (1, 0, 0, 0, 0, 0.0),
    (10, 10, 45, 30, -20, 0.04),
    (20, 20, 100, 90, -40, 0.08),
    (30, 10, 70, 45, 30, 0.04),
    (40, 0, 10, 0, 0, 0.0),
)


def arm_radius(u):
    """Tapering from shoulder to hand, with a biceps swelling 40% wider mid upper arm."""
    x = 3.0 * u
    taper = np.interp(x, (0.0, 1.2, 2.3, 3.0), (0.25, 0.23, 0.19, 0.17))
    biceps = 1.0 + 0.4 * np.exp(-(((x - 0.6) / 0.25) ** 2))
    return taper * biceps


def arm_pose(shoulder_lift, elbow_bend, forearm_twist, wrist_bend, shrug):
    # Bone local X is world -Y (see bend_axis), so positive X rotations bend the
    # arm upwards; local Y runs along the bone, so rotating about Y twists it.
    def about(axis, degrees):
        return Quaternion(axis, math.radians(degrees))

    return {
        "upper": {"rotation_quaternion": about((1, 0, 0), shoulder_lift), "location": (0.0, 0.0, shrug)},
        "fore": {"rotation_quaternion": about((1, 0, 0), elbow_bend) @ about((0, 1, 0), forearm_twist)},
        "hand": {"rotation_quaternion": about((1, 0, 0), wrist_bend)},
    }


def build_arm(path):
    build_sample(
        path,
        bones=ARM_BONES,
        tubes=[TubeSpec(((0.0, 0.0, 0.0), (3.0, 0.0, 0.0)), arm_radius, 64, 64, ("upper", "fore", "hand"))],
        bend_axis=(0.0, -1.0, 0.0),
        reference_axis=(0.0, 0.0, 1.0),
        armature_world=Matrix.LocRotScale((0.3, -0.2, 0.1), Euler((0.0, 0.0, math.radians(25))), None),
        mesh_offset=Matrix.LocRotScale((0.04, -0.03, 0.02), Euler((0.0, 0.0, math.radians(4))), None),
        action_name="arm_twist",
        rotation_mode='QUATERNION',
        keyed_poses=[(frame, arm_pose(*angles)) for frame, *angles in ARM_KEYS],
        view_direction=(0.35, -1.0, 0.45),
    )


# --------------------------------------------------------------------------
# Sample 2: creature (head towards -Y, every bone in a plane x = const)


SPINE_JOINTS = ((0, 1.00, 1.00), (0, 0.68, 1.03), (0, 0.34, 1.06), (0, 0.00, 1.08),
                (0, -0.34, 1.08), (0, -0.67, 1.06), (0, -1.00, 1.04))
NECK_JOINTS = ((0, -1.00, 1.04), (0, -1.22, 1.30), (0, -1.42, 1.56), (0, -1.85, 1.50))
TAIL_JOINTS = ((0, 1.00, 1.00), (0, 1.30, 0.92), (0, 1.60, 0.80), (0, 1.88, 0.72), (0, 2.15, 0.70))
HIND_LEG_JOINTS = ((0.85, 0.95), (0.98, 0.55), (0.82, 0.18), (0.68, 0.03))  # (y, z) hip to toe
FRONT_LEG_JOINTS = ((-0.82, 0.95), (-0.88, 0.55), (-0.82, 0.18), (-0.93, 0.02))
LEG_X = {"L": 0.2, "R": -0.2}
SPINE_NAMES = tuple(f"spine_{i}" for i in range(1, 6))
TAIL_NAMES = tuple(f"tail_{i}" for i in range(1, 5))
# A walk: each leg starts its stride a quarter cycle after the previous one.
LEG_PHASES = {"hind_L": 0.0, "front_L": 0.25, "hind_R": 0.5, "front_R": 0.75}
LEG_PARTS = {"hind": ("thigh", "shin", "foot"), "front": ("upper", "lower", "foot")}


def chain(names, joints, parent):
    """Connected bones through consecutive joints; the first one hangs off `parent`."""
    bones = []
    for index, name in enumerate(names):
        bones.append(BoneSpec(name, joints[index], joints[index + 1],
                              parent=bones[-1].name if bones else parent, connect=bool(bones)))
    return bones


def leg_names(leg):
    end, side = leg.split("_")
    return tuple(f"{end}_{part}_{side}" for part in LEG_PARTS[end])


def leg_joints(leg):
    end, side = leg.split("_")
    yz = HIND_LEG_JOINTS if end == "hind" else FRONT_LEG_JOINTS
    return tuple((LEG_X[side], y, z) for y, z in yz)


def creature_bones():
    # "root" is a non-deforming control bone: it has no vertex group but its
    # animation must still reach every bone below it.
    bones = [BoneSpec("root", (0.0, 0.0, 0.0), (0.0, 0.0, 0.4), deform=False)]
    bones += chain(("pelvis",) + SPINE_NAMES, SPINE_JOINTS, parent="root")
    bones += chain(("neck_1", "neck_2", "head"), NECK_JOINTS, parent="spine_5")
    bones += chain(TAIL_NAMES, TAIL_JOINTS, parent="pelvis")
    for leg in LEG_PHASES:
        bones += chain(leg_names(leg), leg_joints(leg), parent="pelvis" if leg.startswith("hind") else "spine_5")
    return bones


def creature_tubes():
    # The body also listens to the upper leg bones so hips and shoulders follow
    # the legs, which is where vertices get up to four influences.
    upper_legs = tuple(leg_names(leg)[0] for leg in LEG_PHASES)
    body = TubeSpec(((0, 1.14, 0.99),) + SPINE_JOINTS + ((0, -1.12, 1.03),),
                    radius_profile((0.0, 0.22), (0.12, 0.31), (0.5, 0.38), (0.88, 0.33), (1.0, 0.24)),
                    48, 80, ("tail_1", "pelvis") + SPINE_NAMES + ("neck_1",) + upper_legs)
    neck_and_head = TubeSpec(((0, -0.92, 0.98),) + NECK_JOINTS[1:] + ((0, -1.92, 1.49),),
                             radius_profile((0.0, 0.2), (0.45, 0.16), (0.7, 0.24), (0.85, 0.2), (1.0, 0.09)),
                             40, 56, ("spine_5", "neck_1", "neck_2", "head"))
    tail = TubeSpec(((0, 0.95, 1.01),) + TAIL_JOINTS[1:],
                    radius_profile((0.0, 0.13), (0.3, 0.1), (1.0, 0.03)),
                    24, 48, ("pelvis",) + TAIL_NAMES)
    legs = []
    for leg in LEG_PHASES:
        joints = leg_joints(leg)
        hip_above = (joints[0][0], joints[0][1], joints[0][2] + 0.1)
        legs.append(TubeSpec((hip_above,) + joints[1:],
                             radius_profile((0.0, 0.12), (0.45, 0.1), (0.8, 0.07), (1.0, 0.06)),
                             24, 40, ("pelvis" if leg.startswith("hind") else "spine_5",) + leg_names(leg)))
    return [body, neck_and_head, tail] + legs


def walk_pose(phase):
    """Pose at `phase` (0..1) of the cycle; bone local X is world X, so X
    rotations pitch in the side view and Z rotations sway sideways."""
    cycle = 2.0 * math.pi * phase

    def euler(pitch=0.0, sway=0.0):
        return {"rotation_euler": Euler((math.radians(pitch), 0.0, math.radians(sway)))}

    pose = {
        "root": {"location": (0.04 * math.sin(cycle), 0.0, 0.0)},
        "pelvis": {"location": (0.0, 0.0, 0.03 * math.sin(2.0 * cycle)), **euler(sway=4.0 * math.sin(cycle))},
        "neck_1": euler(pitch=6.0 * math.sin(2.0 * cycle)),
        "neck_2": euler(sway=-5.0 * math.sin(cycle)),
        "head": euler(pitch=-8.0 * math.sin(2.0 * cycle + 0.5)),
    }
    for index, name in enumerate(SPINE_NAMES):
        pose[name] = euler(pitch=2.0 * math.sin(2.0 * cycle), sway=4.0 * math.sin(cycle + 0.6 * index))
    for index, name in enumerate(TAIL_NAMES):
        pose[name] = euler(sway=15.0 * math.sin(cycle - 0.8 * index))
    for leg, offset in LEG_PHASES.items():
        stride = cycle + 2.0 * math.pi * offset
        upper, middle, foot = leg_names(leg)
        pose[upper] = euler(pitch=25.0 * math.sin(stride))
        pose[middle] = euler(pitch=-20.0 * (1.0 + math.cos(stride)))
        pose[foot] = euler(pitch=15.0 * math.sin(stride))
    return pose


def build_creature(path):
    # Frame 48 repeats frame 1 so the cycle loops.
    key_frames = np.rint(np.linspace(1, 48, 9)).astype(int).tolist()
    build_sample(
        path,
        bones=creature_bones(),
        tubes=creature_tubes(),
        bend_axis=(1.0, 0.0, 0.0),
        reference_axis=(1.0, 0.0, 0.0),
        armature_world=Matrix.LocRotScale((-0.2, 0.4, 0.05), Euler((0.0, 0.0, math.radians(-20))), None),
        mesh_offset=Matrix.LocRotScale((-0.03, 0.05, 0.02), Euler((0.0, 0.0, math.radians(-3))), None),
        action_name="walk",
        rotation_mode='XYZ',
        keyed_poses=[(frame, walk_pose((frame - 1) / 47.0)) for frame in key_frames],
        view_direction=(0.8, -1.0, 0.5),
    )


# --------------------------------------------------------------------------
# Verification of the saved files


def vertex_weight_stats(mesh):
    """Per-vertex weight sums and counts of non-zero influences."""
    sums = np.zeros(len(mesh.vertices))
    counts = np.zeros(len(mesh.vertices), dtype=int)
    for vertex in mesh.vertices:
        weights = [element.weight for element in vertex.groups if element.weight > 0.0]
        sums[vertex.index], counts[vertex.index] = sum(weights), len(weights)
    return sums, counts


def verify(path):
    """Reload `path`, print its summary and return a list of failed checks."""
    bpy.ops.wm.open_mainfile(filepath=str(path))
    scene = bpy.context.scene
    armatures = [obj for obj in scene.objects if obj.type == 'ARMATURE']
    meshes = [obj for obj in scene.objects if obj.type == 'MESH']
    if len(armatures) != 1 or len(meshes) != 1:
        return [f"{path}: expected one armature and one mesh, found {len(armatures)} and {len(meshes)}"]
    armature_obj, mesh_obj = armatures[0], meshes[0]
    problems = []

    modifiers = [m for m in mesh_obj.modifiers if m.type == 'ARMATURE' and m.object == armature_obj]
    if (len(modifiers) != 1 or not modifiers[0].use_vertex_groups or modifiers[0].use_bone_envelopes
            or modifiers[0].use_deform_preserve_volume):
        problems.append("no single Armature modifier doing plain vertex-group skinning")
    if mesh_obj.parent != armature_obj or mesh_obj.parent_type != 'OBJECT':
        problems.append("mesh is not object-parented to the armature")

    bones = armature_obj.data.bones
    deform_names = {bone.name for bone in bones if bone.use_deform}
    group_names = {group.name for group in mesh_obj.vertex_groups}
    if group_names != deform_names:
        problems.append(f"vertex groups differ from deform bones: {sorted(group_names ^ deform_names)}")

    sums, counts = vertex_weight_stats(mesh_obj.data)
    worst_sum_error = np.abs(sums - 1.0).max()
    if worst_sum_error > WEIGHT_SUM_TOLERANCE:
        problems.append(f"weight sums off by up to {worst_sum_error:.2e}")

    rest = np.empty(len(mesh_obj.data.vertices) * 3)
    mesh_obj.data.vertices.foreach_get("co", rest)
    middle_frame = (scene.frame_start + scene.frame_end) // 2
    posed = evaluated_local_coords(scene, mesh_obj, middle_frame)
    displacement = np.linalg.norm(posed - rest.reshape(-1, 3), axis=1).max()
    if displacement <= MIN_DISPLACEMENT:
        problems.append(f"frame {middle_frame} moves vertices by only {displacement:.4f}")

    print(f"{path}: vertices={len(rest) // 3} bones={len(bones)} deform_bones={len(deform_names)} "
          f"max_influences={counts.max()} frames={scene.frame_start}..{scene.frame_end} "
          f"max_displacement@{middle_frame}={displacement:.3f}")
    return [f"{path}: {problem}" for problem in problems]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent,
                        help="directory to write arm.blend and creature.blend to")
    out = parser.parse_args().out
    out.mkdir(parents=True, exist_ok=True)

    paths = [out / "arm.blend", out / "creature.blend"]
    build_arm(paths[0])
    build_creature(paths[1])

    problems = [problem for path in paths for problem in verify(path)]
    for problem in problems:
        print("FAILED:", problem, file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
