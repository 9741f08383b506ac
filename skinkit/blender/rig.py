"""Reading a rigged mesh out of Blender into skinkit's arrays (bulk transfers, no per-vertex Python loops).

Spaces: Blender's Armature modifier deforms a vertex v of the mesh (in the mesh object's local space) by
    v' = B^-1 Σ_j w_j P_j R_j^-1 B v,    B = armature_world^-1 @ mesh_world,
with P_j the pose bone's matrix and R_j the bone's rest matrix (both in armature space). So in the
thesis' notation, in mesh space, G_j = B^-1 P_j and Ĝ_j = B^-1 R_j. The model is bound with the B of the
moment of conversion (stored with it), as an artist's bind pose is.
Bone 0 is skinkit's root (model space, identity); Blender's bones follow as 1..n in armature order.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass

import bpy
import numpy as np

from ..model import Mesh, Skeleton, SkinkitError, SparseWeights

ROOT_NAME = ""  # skinkit's bone 0: the mesh's own space, never animated


@dataclass(frozen=True)
class Rig:
    """A mesh object, its Armature modifier and what skinning needs from them."""

    mesh_object: bpy.types.Object
    armature_object: bpy.types.Object
    modifier: bpy.types.ArmatureModifier
    warnings: tuple[str, ...]


def armature_modifiers(mesh_object) -> list:
    return [m for m in mesh_object.modifiers if m.type == "ARMATURE"]


def edit_mode_problem(scene_object) -> str | None:
    """Why skinkit cannot read the object now, if it is in Edit Mode (None otherwise).

    While a mesh is edited Blender keeps its data in an edit mesh apart from the mesh, whose attributes are then
    not there to read or write; so skinkit works in Object Mode (and the other modes that keep the mesh data)."""
    return edit_mode_message(scene_object.name) if scene_object.mode == "EDIT" else None


def edit_mode_message(name: str) -> str:
    return (f"'{name}' is in Edit Mode: switch to Object Mode first (skinkit reads and writes the mesh data, which "
            "Blender holds apart while editing)")


def require_object_mode(scene_object) -> None:
    problem = edit_mode_problem(scene_object)
    if problem:
        raise SkinkitError(problem)


def rig_of(mesh_object) -> Rig:
    """Checks that the object is a mesh deformed by exactly one usable Armature modifier."""
    name = mesh_object.name
    if mesh_object.type != "MESH":
        raise SkinkitError(f"'{name}' is a {mesh_object.type.lower()}, not a mesh")
    require_object_mode(mesh_object)
    modifiers = armature_modifiers(mesh_object)
    if not modifiers:
        raise SkinkitError(f"'{name}' has no Armature modifier")
    if len(modifiers) > 1:
        raise SkinkitError(f"'{name}' has {len(modifiers)} Armature modifiers; skinkit handles exactly one")
    modifier = modifiers[0]
    armature = modifier.object
    if armature is None or armature.type != "ARMATURE":
        raise SkinkitError(f"'{name}': its Armature modifier '{modifier.name}' has no armature object")
    if not modifier.use_vertex_groups:
        raise SkinkitError(f"'{name}': modifier '{modifier.name}' does not use vertex groups (enable Vertex Groups)")
    if modifier.use_bone_envelopes:
        raise SkinkitError(f"'{name}': modifier '{modifier.name}' uses bone envelopes, which skinkit does not convert")
    if modifier.use_multi_modifier:
        raise SkinkitError(f"'{name}': modifier '{modifier.name}' uses Multi Modifier, which skinkit does not support")
    if modifier.vertex_group:
        raise SkinkitError(f"'{name}': modifier '{modifier.name}' is masked by vertex group '{modifier.vertex_group}'")
    warnings = []
    if modifier.use_deform_preserve_volume:
        warnings.append(
            f"'{name}': modifier '{modifier.name}' uses Preserve Volume (dual quaternions); animation space "
            "reproduces its linear blend skinning, so results differ where joints twist"
        )
    if not armature.data.bones:
        raise SkinkitError(f"'{name}': armature '{armature.name}' has no bones")
    return Rig(mesh_object, armature, modifier, tuple(warnings))


def bind_matrix(rig: Rig, depsgraph=None) -> np.ndarray:
    """B = armature_world^-1 @ mesh_world (mesh space to armature space), evaluated if a depsgraph is given."""
    mesh_object, armature = rig.mesh_object, rig.armature_object
    if depsgraph is not None:
        mesh_object, armature = mesh_object.evaluated_get(depsgraph), armature.evaluated_get(depsgraph)
    return np.linalg.inv(np.array(armature.matrix_world)) @ np.array(mesh_object.matrix_world)


def bone_names(armature_object) -> list[str]:
    """skinkit's bone order: the root, then Blender's bones in armature order."""
    return [ROOT_NAME] + [bone.name for bone in armature_object.data.bones]


def skeleton_parents(armature_object) -> np.ndarray:
    """int32 (b,): skinkit's parents (the root first, then the armature's bones, roots hanging from it)."""
    bones = armature_object.data.bones
    index = {bone.name: j + 1 for j, bone in enumerate(bones)}
    return np.array([-1] + [index[bone.parent.name] if bone.parent else 0 for bone in bones], np.int32)


def armature_rest_frames(armature_object) -> np.ndarray:
    """(b, 4, 4): the bones' rest frames R_j in armature space, the root's the identity."""
    bones = armature_object.data.bones
    rest = np.empty(len(bones) * 16, np.float32)
    bones.foreach_get("matrix_local", rest)
    return np.concatenate([np.eye(4)[None], column_major(rest)])


def skeleton_of(rig: Rig, bind: np.ndarray) -> Skeleton:
    """Parents and rest frames Ĝ_j = B^-1 R_j in mesh space."""
    rest_frames = armature_rest_frames(rig.armature_object)
    rest_frames[1:] = np.linalg.inv(bind) @ rest_frames[1:]
    return Skeleton.create(skeleton_parents(rig.armature_object), rest_frames, bone_names(rig.armature_object))


def column_major(flat: np.ndarray) -> np.ndarray:
    """Blender's foreach_get gives matrices column by column; numpy wants rows."""
    return flat.reshape(-1, 4, 4).transpose(0, 2, 1).astype(np.float64)


def pose_matrices(armature_object, depsgraph, names: list[str], bind: np.ndarray) -> np.ndarray:
    """G_j = B^-1 P_j (b, 4, 4) for the skeleton `names`, read from the evaluated armature."""
    pose_bones = armature_object.evaluated_get(depsgraph).pose.bones
    flat = np.empty(len(pose_bones) * 16, np.float32)
    pose_bones.foreach_get("matrix", flat)
    by_name = dict(zip(pose_bones.keys(), column_major(flat)))
    missing = [n for n in names[1:] if n not in by_name]
    if missing:
        raise SkinkitError(f"armature '{armature_object.name}' has no bones named {missing}")
    inverse_bind = np.linalg.inv(bind)
    return np.concatenate([np.eye(4)[None], inverse_bind @ np.stack([by_name[n] for n in names[1:]])])


def mesh_positions(mesh) -> np.ndarray:
    """A mesh's vertex positions, float64 (V, 3), through the `position` attribute (far faster to read
    in bulk than `vertices[].co`)."""
    if mesh.is_editmode:
        raise SkinkitError(edit_mode_message(f"mesh {mesh.name}"))
    positions = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.attributes["position"].data.foreach_get("vector", positions)
    return positions.reshape(-1, 3).astype(np.float64)


def rest_positions(mesh_object) -> np.ndarray:
    """The mesh's own vertex positions (the Basis, before shape keys and modifiers), float64 (V, 3)."""
    require_object_mode(mesh_object)
    return mesh_positions(mesh_object.data)


def mesh_of(mesh_object) -> Mesh:
    """The object's own mesh (no modifiers) as triangles, with the map back to polygons and loops."""
    mesh = mesh_object.data
    mesh.calc_loop_triangles()
    count = len(mesh.loop_triangles)
    triangles = np.empty(count * 3, np.int32)
    polygons = np.empty(count, np.int32)
    loops = np.empty(count * 3, np.int32)
    mesh.loop_triangles.foreach_get("vertices", triangles)
    mesh.loop_triangles.foreach_get("polygon_index", polygons)
    mesh.loop_triangles.foreach_get("loops", loops)
    return Mesh.create(rest_positions(mesh_object), triangles.reshape(-1, 3), polygons, loops.reshape(-1, 3))


def deform_weights(rig: Rig, ignore_unmatched_groups: bool = False) -> SparseWeights:
    """Vertex-group weights of the deforming bones, normalised as Blender's Armature modifier does."""
    mesh_object, armature = rig.mesh_object, rig.armature_object
    names = bone_names(armature)
    bone_index = {n: j for j, n in enumerate(names) if j > 0}
    deforming = {bone.name for bone in armature.data.bones if bone.use_deform}
    group_names = [g.name for g in mesh_object.vertex_groups]
    unmatched = [g for g in group_names if g not in bone_index]
    if unmatched and not ignore_unmatched_groups:
        raise SkinkitError(
            f"'{mesh_object.name}': vertex groups {unmatched} name no bone of armature '{armature.name}' "
            "(rename them, or ignore vertex groups that are not bones)"
        )
    used = [g for g in group_names if g in deforming]
    dense = read_vertex_groups(mesh_object, used)
    columns = [bone_index[g] for g in used]
    full = np.zeros((dense.shape[0], len(names)))
    full[:, columns] = dense
    return SparseWeights.from_dense(full).normalized_like_blender()


def read_vertex_groups(mesh_object, group_names: list[str]) -> np.ndarray:
    """Weights (V, len(group_names)) of the named vertex groups, read in bulk.

    Blender has no bulk accessor for vertex-group weights, but geometry nodes see them as named
    attributes: a temporary node group copies each into a float attribute of the evaluated mesh, read with
    foreach_get. Other modifiers are switched off meanwhile so the vertex order is the mesh's own, and
    everything is restored before returning, also on error.
    """
    vertex_count = len(mesh_object.data.vertices)
    if not group_names:
        return np.zeros((vertex_count, 0))
    group = bpy.data.node_groups.new("skinkit_read_vertex_groups", "GeometryNodeTree")
    modifier = None
    hidden = [m for m in mesh_object.modifiers if m.show_viewport]
    try:
        build_group_reader(group, group_names)
        for other in hidden:
            other.show_viewport = False
        modifier = mesh_object.modifiers.new("skinkit_read_vertex_groups", "NODES")
        modifier.node_group = group
        depsgraph = bpy.context.evaluated_depsgraph_get()
        evaluated = mesh_object.evaluated_get(depsgraph)
        mesh = evaluated.to_mesh()
        try:
            if len(mesh.vertices) != vertex_count:
                raise SkinkitError(f"'{mesh_object.name}': could not read vertex groups (vertex count changed)")
            weights = np.empty((len(group_names), vertex_count), np.float32)
            for column in range(len(group_names)):
                mesh.attributes[f"skinkit_weight_{column}"].data.foreach_get("value", weights[column])
        finally:
            evaluated.to_mesh_clear()
    finally:
        if modifier is not None:
            mesh_object.modifiers.remove(modifier)
        for other in hidden:
            other.show_viewport = True
        bpy.data.node_groups.remove(group)
    return weights.T.astype(np.float64)


def build_group_reader(group, group_names: list[str]) -> None:
    """Geometry nodes: for each name, Store Named Attribute skinkit_weight_i = Named Attribute(name)."""
    group.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    geometry = group.nodes.new("NodeGroupInput").outputs[0]
    for column, name in enumerate(group_names):
        read = group.nodes.new("GeometryNodeInputNamedAttribute")
        read.data_type = "FLOAT"
        read.inputs["Name"].default_value = name
        store = group.nodes.new("GeometryNodeStoreNamedAttribute")
        store.data_type = "FLOAT"
        store.domain = "POINT"
        store.inputs["Name"].default_value = f"skinkit_weight_{column}"
        group.links.new(geometry, store.inputs["Geometry"])
        group.links.new(read.outputs["Attribute"], store.inputs["Value"])
        geometry = store.outputs["Geometry"]
    group.links.new(geometry, group.nodes.new("NodeGroupOutput").inputs[0])


# ---- what a stored model was built from ---------------------------------------------------------------------------

def digest(*arrays) -> str:
    hasher = hashlib.sha1()
    for array in arrays:
        hasher.update(np.ascontiguousarray(array).tobytes())
    return hasher.hexdigest()


def topology_digest(mesh) -> str:
    """Changes when vertices, edges or faces are added, removed or reconnected."""
    corner_vertices = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", corner_vertices)
    sizes = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_total", sizes)
    return digest(corner_vertices, sizes)


def weights_digest(weights: SparseWeights) -> str:
    """The weights as the Armature modifier applies them, to 1e-6 (float32 vertex groups reread alike)."""
    return digest(weights.offsets.astype(np.int64), weights.bones.astype(np.int64),
                  np.round(weights.weights, 6))


def model_signature(rig: Rig, weights: SparseWeights | None = None, with_weights: bool = True) -> dict:
    """What a model converted (or fitted) from the rig depends on, to tell later whether it still matches: the
    vertex count, a topology and a rest-position digest, the bones' names and deform flags, a rest-pose digest and
    a digest of the deforming weights (read now unless given; left out without with_weights, which reads no
    vertex groups). Stored with the model (see storage.py)."""
    mesh_object, armature = rig.mesh_object, rig.armature_object
    signature = {"vertices": len(mesh_object.data.vertices), "topology": topology_digest(mesh_object.data),
            "rest_positions": digest(mesh_positions(mesh_object.data).astype(np.float32)),
            "bones": bone_names(armature)[1:],
            "deform": "".join("1" if bone.use_deform else "0" for bone in armature.data.bones),
            "rest_pose": digest(np.round(armature_rest_frames(armature), 6))}
    if with_weights:
        signature["weights"] = weights_digest(weights if weights is not None else
                                              deform_weights(rig, ignore_unmatched_groups=True))
    return signature


#: What each signature entry is, in the words of the message that says it changed.
SIGNATURE_WORDS = {"vertices": "the vertex count", "topology": "the mesh's faces (topology)",
                   "rest_positions": "the mesh's rest positions", "bones": "the armature's bones",
                   "deform": "which bones deform", "rest_pose": "the armature's rest pose",
                   "weights": "the vertex-group weights"}


def signature_changes(stored: dict, current: dict) -> list[str]:
    """What changed between two model signatures, in words (empty when they match)."""
    changes = []
    for key, words in SIGNATURE_WORDS.items():
        if key not in stored or key not in current:
            continue
        was, now = stored[key], current[key]
        if key == "vertices" and was != now:
            changes.append(f"{words} ({was} then, {now} now)")
        elif key == "deform" and was != now and stored.get("bones") == current["bones"]:
            flipped = [name for name, a, b in zip(current["bones"], was, now) if a != b]
            changes.append(f"{words} ({', '.join(repr(n) for n in flipped)})")
        elif was != now:
            changes.append(words)
    return changes
