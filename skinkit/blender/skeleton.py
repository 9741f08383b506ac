"""Blender side of skeleton extraction (Vasilakis 2008): a mesh object's parts (vertex groups, materials, loose parts,
a face integer attribute, or weights from a file), and the rig built from an extracted skeleton: an armature with one
bone per part, Limit Rotation constraints from the hierarchy's limits, one rigid vertex group per part and an
Armature modifier. Shared by the add-on and the CLI; on any failure nothing is left behind."""
from __future__ import annotations

import bpy
import numpy as np

from ..model import SkinkitError
from ..skeleton import Skeleton, extract_skeleton, free_limits, from_vertex_labels, from_weights, read_dmat
from ..skeleton.parts import Parts, compact, loose_parts
from .rig import mesh_of, read_vertex_groups
from .scene import local_to_world, naming, triangle_mesh, write_triangles

#: The part sources a mesh object offers, as the CLI spells them.
PART_SOURCES = ("groups", "materials", "loose", "attribute")
#: The face attribute read by the "attribute" source.
PART_ATTRIBUTE = "skinkit_part"
#: The mesh's custom property naming those parts (indexed by the attribute's values), when there is one.
PART_NAMES = "skinkit_part_names"


def face_labels(mesh_object, source: str, polygons: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Per-triangle labels and names from the mesh's materials or its integer face attribute."""
    mesh = mesh_object.data
    if source == "materials":
        indices = np.empty(len(mesh.polygons), np.int32)
        mesh.polygons.foreach_get("material_index", indices)
        names = [slot.material.name if slot.material else f"material_{k}"
                 for k, slot in enumerate(mesh_object.material_slots)]
        names += [f"material_{k}" for k in range(len(names), int(indices.max(initial=0)) + 1)]
        return indices[polygons], names
    attribute = mesh.attributes.get(PART_ATTRIBUTE)
    if attribute is None or attribute.domain != "FACE" or attribute.data_type != "INT":
        raise SkinkitError(f"no integer face attribute '{PART_ATTRIBUTE}' holds the parts")
    values = np.empty(len(mesh.polygons), np.int32)
    attribute.data.foreach_get("value", values)
    stored = mesh.get(PART_NAMES)
    names = [str(n) for n in stored] if stored is not None else None
    if names is not None and values.size and (values.min() < 0 or values.max() >= len(names)):
        names = None  # the attribute was edited past its names
    labels, kept = compact(values[polygons], names)
    return labels, list(kept)


def mesh_parts(mesh_object, source: str = "groups", weights_path: str | None = None) -> Parts:
    """The object's parts in world space: `groups` (each vertex's strongest vertex group), `materials`, `loose`
    (pieces meeting at coincident vertices, welded), `attribute` (the skinkit_part face attribute) or, with
    weights_path, the dominant bone of a DMAT's weights."""
    with naming(mesh_object):
        mesh = mesh_of(mesh_object)
        positions = local_to_world(mesh_object, mesh.positions)
        if weights_path is not None:
            return from_weights(positions, mesh.triangles, read_dmat(weights_path))
        if source == "loose":
            return loose_parts(positions, mesh.triangles)
        if source == "groups":
            names = [g.name for g in mesh_object.vertex_groups]
            if not names:
                raise SkinkitError("has no vertex groups to take the parts from")
            weights = read_vertex_groups(mesh_object, names)
            return from_vertex_labels(positions, mesh.triangles, np.argmax(weights, axis=1).astype(np.int32), names)
        if source in ("materials", "attribute"):
            labels, names = face_labels(mesh_object, source, mesh.triangle_polygons)
            triangle_labels, kept = compact(labels, names)
            return Parts(positions, mesh.triangles, triangle_labels, kept)
        raise SkinkitError(f"part source {source!r}: expected one of {', '.join(PART_SOURCES)}")


def _remove_rig(armature_object, groups, modifier, mesh_object):
    if modifier is not None:
        mesh_object.modifiers.remove(modifier)
    for group in groups:
        mesh_object.vertex_groups.remove(group)
    if armature_object is not None:
        data = armature_object.data
        bpy.data.objects.remove(armature_object)
        bpy.data.armatures.remove(data)


def build_rig(mesh_object, parts: Parts, skeleton: Skeleton, limits=None, name: str | None = None):
    """An armature '<mesh>_skeleton' (world space, at the origin) with one bone per part from its root point, joint
    limits (degrees, (P, 3, 2)) as Limit Rotation constraints in local space, one vertex group per part (weight 1
    on the part's vertices) and an Armature modifier on the mesh. Vertex groups named like parts are replaced.
    Returns the armature object; on failure everything it made is removed."""
    limits = free_limits(parts.part_count) if limits is None else np.asarray(limits, dtype=np.float64)
    if len(mesh_object.data.vertices) != len(parts.positions):
        raise SkinkitError(f"'{mesh_object.name}': the parts have {len(parts.positions)} vertices, the mesh "
                           f"{len(mesh_object.data.vertices)} (loose parts are welded: rig the welded mesh)")
    armature_object, groups, modifier = None, [], None
    previous = bpy.context.view_layer.objects.active
    try:
        data = bpy.data.armatures.new(name or f"{mesh_object.name}_skeleton")
        armature_object = bpy.data.objects.new(data.name, data)
        bpy.context.scene.collection.objects.link(armature_object)
        bpy.context.view_layer.objects.active = armature_object
        bpy.ops.object.mode_set(mode="EDIT")
        heads, tails = skeleton.positions[skeleton.part_joints], skeleton.bone_tails()
        bones = []
        for p, part_name in enumerate(parts.names):
            bone = data.edit_bones.new(part_name)
            bone.head, bone.tail = heads[p].tolist(), tails[p].tolist()
            bones.append(bone)
        for p, parent in enumerate(skeleton.part_parents.tolist()):
            if parent >= 0:
                bones[p].parent = bones[parent]
        bpy.ops.object.mode_set(mode="OBJECT")
        for p, part_name in enumerate(parts.names):
            constraint = armature_object.pose.bones[part_name].constraints.new("LIMIT_ROTATION")
            constraint.owner_space = "LOCAL"
            for axis, (low, high) in zip("xyz", np.radians(limits[p])):
                setattr(constraint, f"use_limit_{axis}", True)
                setattr(constraint, f"min_{axis}", float(low))
                setattr(constraint, f"max_{axis}", float(high))
        vertex_parts = parts.vertex_parts()
        for p, part_name in enumerate(parts.names):
            old = mesh_object.vertex_groups.get(part_name)
            if old is not None:
                mesh_object.vertex_groups.remove(old)
            group = mesh_object.vertex_groups.new(name=part_name)
            groups.append(group)
            group.add(np.flatnonzero(vertex_parts == p).tolist(), 1.0, "REPLACE")
        modifier = mesh_object.modifiers.new("skinkit_skeleton", "ARMATURE")
        modifier.object = armature_object
        mesh_object.parent = None  # the bones are in world space
        return armature_object
    except Exception:
        if armature_object is not None and armature_object.mode != "OBJECT":
            bpy.ops.object.mode_set(mode="OBJECT")
        _remove_rig(armature_object, groups, modifier, mesh_object)
        raise
    finally:
        bpy.context.view_layer.objects.active = previous


def extract_rig(mesh_object, source: str = "groups", method: str = "principal-axis", refine: bool = False,
                max_angle: float = 20.0, weights_path: str | None = None, hierarchy=None):
    """Parts, skeleton and rig of a mesh object in one call: (armature object, skeleton, parts). hierarchy: a
    skinkit.skeleton.Hierarchy whose segments name the parts (their parents and limits are used)."""
    parts = mesh_parts(mesh_object, source, weights_path)
    parents = limits = None
    if hierarchy is not None:
        ordered = hierarchy.reordered(parts.names)
        parents, limits = ordered.parents, ordered.limits
    with naming(mesh_object):
        skeleton = extract_skeleton(parts, method, parents=parents, refine=refine, max_angle=max_angle)
    if len(parts.positions) != len(mesh_object.data.vertices):
        raise SkinkitError(f"'{mesh_object.name}': loose parts were welded ({len(mesh_object.data.vertices)} -> "
                           f"{len(parts.positions)} vertices); merge by distance first to rig the mesh")
    return build_rig(mesh_object, parts, skeleton, limits), skeleton, parts


def part_frames(armature_object, bone_names, depsgraph) -> np.ndarray:
    """World frames (P, 4, 4) taking each bone's rest placement to its pose: world @ pose @ rest^-1."""
    evaluated = armature_object.evaluated_get(depsgraph)
    world = np.array(evaluated.matrix_world)
    frames = []
    for name in bone_names:
        pose_bone = evaluated.pose.bones[name]
        frames.append(world @ np.array(pose_bone.matrix) @ np.linalg.inv(np.array(pose_bone.bone.matrix_local)) @
                      np.linalg.inv(world))
    return np.array(frames)


def rigid_rig_parts(mesh_object):
    """The parts of a rigidly skinned mesh (its strongest vertex group per vertex, groups naming bones), the
    armature, the parts' parents and joints (bone heads, world space)."""
    from .rig import armature_modifiers

    modifiers = armature_modifiers(mesh_object)
    if not modifiers or modifiers[0].object is None:
        raise SkinkitError(f"'{mesh_object.name}' has no Armature modifier with an armature")
    armature = modifiers[0].object
    bones = armature.data.bones
    names = [g.name for g in mesh_object.vertex_groups if g.name in bones]
    if not names:
        raise SkinkitError(f"'{mesh_object.name}': no vertex group names a bone of '{armature.name}'")
    parts = mesh_parts(mesh_object, "groups")
    parts = Parts(parts.positions, parts.triangles, parts.triangle_parts, parts.names)
    missing = [n for n in parts.names if n not in bones]
    if missing:
        raise SkinkitError(f"'{mesh_object.name}': vertex groups {missing[:5]} name no bone of '{armature.name}'")
    world = np.array(armature.matrix_world)
    index = {name: k for k, name in enumerate(parts.names)}
    parents, joints = [], []
    for name in parts.names:
        bone = bones[name]
        parent = bone.parent
        while parent is not None and parent.name not in index:
            parent = parent.parent
        parents.append(index[parent.name] if parent is not None else -1)
        joints.append((world @ np.append(np.array(bone.head_local), 1.0))[:3])
    if parents.count(-1) != 1:
        raise SkinkitError(f"'{mesh_object.name}': its parts hang from {parents.count(-1)} root bones; one is needed")
    return parts, armature, np.array(parents, np.int32), np.array(joints)


#: On a live seamed object: the name of the rigidly skinned mesh it follows, its rings per seam, whether each frame
#: removes the sinking points (Algorithm 5 in full: the vertex count then changes per frame) and its arcs.
LIVE_SOURCE = "skinkit_seamed_source"
LIVE_STEPS = "skinkit_seam_steps"
LIVE_REMOVE_SINKING = "skinkit_seam_remove_sinking"
LIVE_ARCS = "skinkit_seam_arcs"


def seamed_topology(mesh_object, steps: int = 4):
    """(SeamMesh, parts, armature) of a rigidly skinned mesh: the topology its seamed copy has in every frame."""
    from ..skeleton.seams import prepare_seams_for_rig

    with naming(mesh_object):
        parts, armature, parents, joints = rigid_rig_parts(mesh_object)
        return prepare_seams_for_rig(parts, parents, joints, steps), parts, armature


def _seamed_object(name: str, mesh, part_count: int):
    """A new object '<name>' holding the seam topology at rest."""
    new_mesh = triangle_mesh(name, mesh.positions(np.tile(np.eye(4), (part_count, 1, 1))), mesh.triangles)
    new_mesh.update()
    seamed = bpy.data.objects.new(new_mesh.name, new_mesh)
    bpy.context.scene.collection.objects.link(seamed)
    return seamed


def seamed_frame(mesh, world, remove_sinking: bool = False, arcs: str = "qlerp"):
    """(positions, triangles) of one frame: the fixed topology with QLERP arcs (SeamMesh.positions), else Algorithm 5
    in C with the sinking points removed and/or the conic arcs (SeamMesh.reconstruct)."""
    if not remove_sinking and arcs == "qlerp":
        return mesh.positions(world), mesh.triangles
    frame = mesh.reconstruct(world, remove_sinking=remove_sinking, arcs=arcs)
    return frame.positions, frame.triangles


def _write_geometry(target, positions, triangles) -> None:
    """Replaces a mesh's vertices and triangles in place (foreach_set, as triangle_mesh writes a new one)."""
    target.clear_geometry()
    write_triangles(target, positions, triangles)


def pose_seamed(seamed_object, mesh, parts, armature, depsgraph) -> None:
    """Moves a live seamed object to the armature's current pose (the live deformer's one step); with sinking
    removal its geometry is rewritten, since the vertex count changes."""
    remove_sinking = bool(seamed_object.get(LIVE_REMOVE_SINKING, False))
    positions, triangles = seamed_frame(mesh, part_frames(armature, parts.names, depsgraph), remove_sinking,
                                        str(seamed_object.get(LIVE_ARCS, "qlerp")))
    if remove_sinking:
        _write_geometry(seamed_object.data, positions, triangles)
    else:
        seamed_object.data.vertices.foreach_set("co", positions.astype(np.float32).reshape(-1))
    seamed_object.data.update()


def make_live_seamed(mesh_object, steps: int = 4, remove_sinking: bool = False, arcs: str = "qlerp"):
    """A new object '<mesh>_seamed' that the add-on's frame handler re-poses every frame (LIVE_SOURCE names the
    mesh it follows). Returns (object, SeamMesh, parts, armature)."""
    _check_arcs(arcs)
    mesh, parts, armature = seamed_topology(mesh_object, steps)
    seamed = _seamed_object(f"{mesh_object.name}_seamed", mesh, parts.part_count)
    seamed[LIVE_SOURCE] = mesh_object.name
    seamed[LIVE_STEPS] = int(steps)
    seamed[LIVE_REMOVE_SINKING] = bool(remove_sinking)
    seamed[LIVE_ARCS] = arcs
    pose_seamed(seamed, mesh, parts, armature, bpy.context.evaluated_depsgraph_get())
    return seamed, mesh, parts, armature


def _check_arcs(arcs: str) -> None:
    from ..skeleton.seams import ARC_KINDS

    if arcs not in ARC_KINDS:
        raise SkinkitError(f"arcs {arcs!r}: one of {', '.join(ARC_KINDS)}")


def bake_seamed(mesh_object, frames, steps: int = 4, remove_sinking: bool = False, arcs: str = "qlerp"):
    """The rigidly skinned mesh with its seams closed (skinkit.skeleton.seams), from the armature's pose at each
    frame. Without sinking removal: a new object '<mesh>_seamed' with one shape key per frame keyed on its frame.
    With it (Algorithm 5 in full, the vertex count changing per frame): a new collection '<mesh>_seamed' of one
    object per frame, each shown only on its frame. Computed first, written last. Returns (the object or the
    collection, SeamMesh, the frames' reports: removed points, fill points, fallback)."""
    from .frames import depsgraphs_at

    _check_arcs(arcs)
    mesh, parts, armature = seamed_topology(mesh_object, steps)
    frames = list(frames)
    if not frames:
        raise SkinkitError("the frame range is empty")
    worlds = np.array([part_frames(armature, parts.names, depsgraph) for depsgraph in depsgraphs_at(frames)])
    if not remove_sinking and arcs == "qlerp":
        posed = [mesh.positions(world) for world in worlds]
        reports = [{"removed_points": 0, "fill_points": 0, "fallback": False} for _ in frames]
    else:
        results = mesh.reconstruct_sequence(worlds, remove_sinking=remove_sinking, arcs=arcs)
        posed = [(result.positions, result.triangles) for result in results]
        reports = [{"removed_points": r.removed_points, "fill_points": r.fill_points, "fallback": r.fallback}
                   for r in results]
    if remove_sinking:
        return _frame_objects(f"{mesh_object.name}_seamed", frames, posed), mesh, reports
    if arcs != "qlerp":
        posed = [positions for positions, _ in posed]
    baked = _seamed_object(f"{mesh_object.name}_seamed", mesh, parts.part_count)
    baked.shape_key_add(name="Basis", from_mix=False)
    for frame, positions_at_frame in zip(frames, posed):
        key = baked.shape_key_add(name=f"frame_{frame:04d}", from_mix=False)
        key.points.foreach_set("co", positions_at_frame.astype(np.float32).reshape(-1))
        for neighbour, value in ((frame - 1, 0.0), (frame, 1.0), (frame + 1, 0.0)):
            key.value = value
            key.keyframe_insert("value", frame=neighbour)
    return baked, mesh, reports


def _frame_objects(name: str, frames, posed):
    """A new collection of one mesh object per frame ('<name>_0001', ...), each hidden (viewport and render) except
    on its own frame."""
    collection = bpy.data.collections.new(name)
    bpy.context.scene.collection.children.link(collection)
    for frame, (positions, triangles) in zip(frames, posed):
        new_mesh = triangle_mesh(f"{name}_{frame:04d}", positions, triangles)
        new_mesh.update()
        frame_object = bpy.data.objects.new(new_mesh.name, new_mesh)
        collection.objects.link(frame_object)
        for at, hidden in ((frame - 1, True), (frame, False), (frame + 1, True)):
            frame_object.hide_viewport = frame_object.hide_render = hidden
            frame_object.keyframe_insert("hide_viewport", frame=at)
            frame_object.keyframe_insert("hide_render", frame=at)
    return collection
