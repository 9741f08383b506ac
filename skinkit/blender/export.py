# SPDX-License-Identifier: GPL-3.0-or-later
"""Export for Engines: a LOD chain (<name>_LOD0..n, written by lod_chain.py) or any skinned result skinkit writes
(Skin from Mesh Sequence, Fit from Example Poses, one LOD level) through Blender's OWN exporters: glTF binary
(`export_scene.gltf`), FBX (`export_scene.fbx`) and USD (`wm.usd_export`), with the armature and its action.

Each level leaves as a linear-blend-skinned mesh named <name>_LOD<n> (the Unreal/Unity naming) with at most
MAX_JOINTS joints per vertex: the Armature modifier's own weights (normalised as it applies them), the largest
MAX_JOINTS kept, weights at or below GLTF_MIN_WEIGHT dropped (glTF's exporter drops them; dropping them for every
format keeps the formats alike) and the rest divided by their total, so every importer reads normalised weights.

For glTF the animation-space model travels too, as custom vertex attributes (docs/engine-format.md): per slot s a
VEC4 `_SKINKIT_P_<s>` holding p_j in bone j's rest frame, where slot s < 4 is the joint of JOINTS_0[s] (the order
Blender's exporter writes: decreasing weight, ties by vertex-group order) and slots 4..7 hold the model's other
bones, their joints in `_SKINKIT_JOINTS_1` (a VEC4 of float joint indices: Blender writes JOINTS_1 only for more
than four weights, which the LBS levels never have). An engine evaluates v = Σ_s G[joint_s] p_s with G the joint
node's global (world) transform: the thesis' G_j in glTF's world, since p_j is in bone j's own frame.

Units: glTF is metres by definition and engines read USD in metres, so for those two the export converts the scene's
Blender units to metres (unit_scale metres per Blender unit, by default the scene's unit scale_length): on
temporary copies of the levels and of the armature and its action, the vertex positions, the bones' rests, the
objects' translations, the action's location curves and the `_SKINKIT_P_<s>` translation rows (x, y, z; the weight
w is unitless) are all multiplied by it, which is one uniform scaling of the whole exported world about the origin,
so the file deforms as the scene does, in metres. FBX carries the scene's unit in its header and Blender's importer
converts it, so FBX keeps the scene's units through the exporter's own unit scale.

The scene is never changed: the exporters run on temporary copies of the levels (carrying the limited weights and
the attributes) that take the levels' (and their meshes') names while the exporter runs; the copies are deleted and
every name, the selection, the active object and the frame range restored afterwards, also when the exporter fails.
What each format loses and how it is kept (FBX's takes and curve simplification, USD's frame range and names) is
handled in exporter_options and action_frame_range, the one place that knows the exporters.
"""
from __future__ import annotations

import os
import re
import shutil
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass

import bpy
import numpy as np
from mathutils import Matrix

from ..lod.influences import limit_total
from ..model import SkinkitError, SparseWeights, convert_lbs
from . import compat, storage
from .attributes import write_bone_groups
from .rig import bind_matrix, bone_names, deform_weights, mesh_of, rig_of, skeleton_of
from .scene import naming

FORMATS = ("glb", "fbx", "usd")
EXTENSIONS = {"glb": (".glb",), "fbx": (".fbx",), "usd": (".usd", ".usdc", ".usda", ".usdz")}
#: Joints per vertex in every exported level (what real-time engines take by default).
MAX_JOINTS = 4
#: Blender's glTF exporter drops weights at or below this (primitive_extract.py, min_influence).
GLTF_MIN_WEIGHT = 1e-4
#: Influence slots of the animation-space attributes: JOINTS_0's four, then four more (_SKINKIT_JOINTS_1).
MAX_SLOTS = 8
P_ATTRIBUTE = "_SKINKIT_P_{}"
JOINTS_1_ATTRIBUTE = "_SKINKIT_JOINTS_1"
#: How much the bind may have moved since the model was converted before its p_j no longer match the rig.
BIND_TOLERANCE = 1e-5
_ORIGINAL_SUFFIX = ".skinkit-export"


# ---- Blender version differences, in one place -------------------------------------------------------------------

def vec4_field(data_type: str) -> str:
    return "value" if data_type == "QUATERNION" else "color"


def exporter_options(fmt: str, path: str, animation_space: bool) -> dict:
    """Keyword options for the format's Blender exporter: the selection (the copies and the armature), the
    armature's action, no leaf bones (FBX would add <bone>_end bones), Blender units kept through FBX's unit scale
    (the importer applies it back), every frame kept (FBX simplifies its curves by default), and for glTF the
    custom attributes. FBX exports every action the armature can play, one take each named after it (its
    single-take mode names the take after the scene); each take starts at time 0, and Blender's importer puts it on
    frame 1 by default. Options a Blender lacks are dropped by `supported` and reported."""
    if fmt == "glb":
        return dict(filepath=path, export_format="GLB", use_selection=True, export_animations=True,
                    export_skins=True, export_all_influences=False, export_def_bones=False, export_apply=False,
                    export_yup=True, export_attributes=animation_space, export_morph=False)
    if fmt == "fbx":
        return dict(filepath=path, use_selection=True, object_types={"ARMATURE", "MESH"}, add_leaf_bones=False,
                    bake_anim=True, bake_anim_use_all_actions=True, bake_anim_use_nla_strips=False,
                    bake_anim_simplify_factor=0.0,
                    apply_unit_scale=True, apply_scale_options="FBX_SCALE_NONE", use_mesh_modifiers=False,
                    use_armature_deform_only=False)
    # Images keep their own paths (USD would copy them into textures/ beside the file).
    return dict(filepath=path, selected_objects_only=True, export_animation=True, export_armatures=True,
                only_deform_bones=False, export_shapekeys=False, export_textures_mode="KEEP", export_textures=False)


def exporter(fmt: str):
    return {"glb": bpy.ops.export_scene.gltf, "fbx": bpy.ops.export_scene.fbx, "usd": bpy.ops.wm.usd_export}[fmt]


def supported(operator, options: dict) -> tuple[dict, list[str]]:
    """The options this Blender's operator takes, and the names of those it lacks (an older or newer Blender)."""
    known = {prop.identifier for prop in operator.get_rna_type().properties}
    return ({k: v for k, v in options.items() if k in known}, sorted(k for k in options if k not in known))


# ---- what is exported ---------------------------------------------------------------------------------------------

def chain_objects(name: str) -> list:
    """The objects `<name>_LOD0..n` (in the collection `<name>_LOD`, else anywhere in the scene) in level order, or
    the one skinned mesh called `name`."""
    pattern = re.compile(rf"^{re.escape(name)}_LOD(\d+)$")
    collection = bpy.data.collections.get(f"{name}_LOD")
    candidates = collection.all_objects if collection is not None else bpy.context.scene.objects
    levels = sorted(((int(m.group(1)), o) for o in candidates if (m := pattern.match(o.name))), key=lambda x: x[0])
    if levels:
        numbers = [number for number, _ in levels]
        if numbers != list(range(len(levels))):
            raise SkinkitError(f"the chain '{name}' has levels {numbers}: expected {name}_LOD0 .. "
                               f"{name}_LOD{len(levels) - 1} without gaps")
        return [o for _, o in levels]
    found = bpy.context.scene.objects.get(name)
    if found is None:
        raise SkinkitError(f"no LOD chain '{name}_LOD0..n' and no object named '{name}' in the scene")
    return [found]


def chain_name(scene_object) -> str:
    """The chain a level belongs to (`arm` for `arm_LOD2`), else the object's own name."""
    found = re.match(r"^(.*)_LOD\d+$", scene_object.name)
    return found.group(1) if found else scene_object.name


def limited_weights(weights: SparseWeights) -> SparseWeights:
    """At most MAX_JOINTS weights per vertex, none at or below GLTF_MIN_WEIGHT, normalised (a vertex left with none
    keeps the root, i.e. stays in place, as in Blender)."""
    weights = limit_total(weights, MAX_JOINTS)
    keep = (weights.weights > GLTF_MIN_WEIGHT) & (weights.bones > 0)
    offsets = np.zeros(weights.vertex_count + 1, np.int32)
    np.cumsum(np.bincount(weights.vertex_of_each_influence()[keep], minlength=weights.vertex_count), out=offsets[1:])
    return SparseWeights(offsets, weights.bones[keep].copy(), weights.weights[keep].copy()).normalized_like_blender()


def joint_order(armature_object) -> list[str]:
    """Bone names in the order of the glTF skin's joints: depth first from each root bone, children in Blender's
    order (the exporter's tree walk; tests/blender/test_export.py reads it back from the file)."""
    order = []

    def visit(bone):
        order.append(bone.name)
        for child in bone.children:
            visit(child)

    for bone in armature_object.data.bones:
        if bone.parent is None:
            visit(bone)
    return order


def joints_0_slots(weights: SparseWeights, bone_count: int) -> np.ndarray:
    """(V, bone_count) int: the JOINTS_0 slot Blender's glTF exporter gives each (vertex, bone) of `weights`, -1
    where none. It sorts a vertex's groups by decreasing weight (float32 as stored), ties in vertex-group order,
    which on the copies is bone order (write_bone_groups creates them so)."""
    vertex = weights.vertex_of_each_influence()
    stored = weights.weights.astype(np.float32)
    order = np.lexsort((weights.bones, -stored, vertex))
    rank = np.empty(weights.influence_count, np.int64)
    rank[order] = np.arange(weights.influence_count) - np.repeat(weights.offsets[:-1], weights.counts())
    slots = np.full((weights.vertex_count, bone_count), -1, np.int64)
    slots[vertex, weights.bones] = rank
    return slots


def animation_space_slots(model, weights: SparseWeights, bone_joint: np.ndarray, owner: str):
    """(p (V, S, 4) float32, joints_1 (V, 4) float32 or None): the model's p_j placed in the slots of
    docs/engine-format.md, S = 4, or 8 when some vertex has a bone outside its JOINTS_0."""
    vertex = model.vertex_of_each_influence()
    if np.any(model.bones == 0):
        count = len(np.unique(vertex[model.bones == 0]))
        raise SkinkitError(f"'{owner}': {count} vertices are influenced by skinkit's root (no bone, e.g. unweighted "
                           "vertices); glTF joints cannot carry them: weight them to a bone, or export without the "
                           "animation-space attributes")
    lbs_slot = joints_0_slots(weights, model.bone_count)[vertex, model.bones]
    extra = lbs_slot < 0
    extra_rank = np.zeros(model.influence_count, np.int64)
    if extra.any():  # the k-th extra influence of a vertex goes to slot 4 + k
        extra_vertex = vertex[extra]
        first = np.searchsorted(extra_vertex, extra_vertex)
        extra_rank[extra] = np.arange(extra.sum()) - first
    slot = np.where(extra, MAX_JOINTS + extra_rank, lbs_slot)
    if slot.max(initial=0) >= MAX_SLOTS:
        worst = int(vertex[np.argmax(slot)])
        raise SkinkitError(f"'{owner}': vertex {worst} has more than {MAX_SLOTS} influences (limit them first)")
    slot_count = MAX_SLOTS if extra.any() else MAX_JOINTS
    p = np.zeros((model.vertex_count, slot_count, 4), np.float32)
    p[vertex, slot] = model.coordinates
    joints_1 = None
    if extra.any():
        joints_1 = np.zeros((model.vertex_count, MAX_JOINTS), np.float32)
        joints_1[vertex[extra], slot[extra] - MAX_JOINTS] = bone_joint[model.bones[extra]]
    return p, joints_1


@dataclass
class ExportLevel:
    """One level, ready to be written onto its temporary copy."""

    name: str
    weights: SparseWeights
    limited_vertices: int  # vertices whose weights the MAX_JOINTS limit or the GLTF_MIN_WEIGHT cut changed
    p: np.ndarray | None  # (V, S, 4) float32
    joints_1: np.ndarray | None
    model_source: str | None  # "stored" or "linear blend" (converted in memory)


@dataclass
class ExportJob:
    format: str
    armature_name: str
    bone_names: list
    action: str | None
    levels: list
    animation_space: bool
    warnings: list
    unit_scale: float = 1.0  # what the copies are scaled by: metres per Blender unit (glTF, USD), 1 for FBX


def scene_unit_scale() -> float:
    """Metres per Blender unit in this scene (its unit settings' scale_length; 0.01 for a centimetre scene)."""
    return float(bpy.context.scene.unit_settings.scale_length)


def copy_scale(fmt: str, unit_scale: float | None) -> float:
    """The factor the exported copies are scaled by: metres per Blender unit for glTF and USD (unit_scale, or the
    scene's), 1 for FBX, whose exporter writes the scene's unit into the file itself."""
    scene_scale = scene_unit_scale()
    if unit_scale is None:
        unit_scale = scene_scale
    if not (isinstance(unit_scale, (int, float)) and np.isfinite(unit_scale) and unit_scale > 0):
        raise SkinkitError(f"unit_scale must be a positive number of metres per Blender unit, not {unit_scale!r}")
    if fmt == "fbx":
        if abs(unit_scale - scene_scale) > 1e-9 * scene_scale:
            raise SkinkitError(f"unit_scale {unit_scale:g}: FBX writes the scene's own unit ({scene_scale:g} m per "
                               "Blender unit) into the file; set the scene's Unit Scale instead")
        return 1.0
    return float(unit_scale)


def prepare_export(objects, fmt: str, animation_space: bool = True, unit_scale: float | None = None) -> ExportJob:
    """Reads and checks everything the export needs (changing nothing)."""
    if fmt not in FORMATS:
        raise SkinkitError(f"format must be one of {FORMATS}, not {fmt!r}")
    scale = copy_scale(fmt, unit_scale)
    objects = list(objects)
    if not objects:
        raise SkinkitError("nothing to export")
    armature = None
    levels = []
    for mesh_object in objects:
        rig = rig_of(mesh_object)
        if armature is not None and rig.armature_object != armature:
            raise SkinkitError(f"'{mesh_object.name}' is deformed by '{rig.armature_object.name}', "
                               f"'{objects[0].name}' by '{armature.name}': a chain shares one armature")
        armature = rig.armature_object
        with naming(mesh_object):
            levels.append(prepare_level(rig, fmt == "glb" and animation_space))
    data = armature.animation_data
    action = data.action.name if data is not None and data.action is not None else None
    warnings = [] if action else [f"'{armature.name}' has no action: the export carries the rest pose only"]
    return ExportJob(fmt, armature.name, bone_names(armature), action, levels, fmt == "glb" and animation_space,
                     warnings, scale)


def prepare_level(rig, with_model: bool) -> ExportLevel:
    mesh_object = rig.mesh_object
    weights = deform_weights(rig, ignore_unmatched_groups=True)
    limited = limited_weights(weights)
    bone_count = len(bone_names(rig.armature_object))
    changed = np.abs(weights.to_dense(bone_count)[:, 1:] -
                     limited.to_dense(bone_count)[:, 1:]).max(axis=1, initial=0.0) > 1e-7
    p = joints_1 = source = None
    if with_model:
        model, source = level_model(rig, limited)
        bones = joint_order(rig.armature_object)
        joint_of_name = {name: index for index, name in enumerate(bones)}
        bone_joint = np.array([0] + [joint_of_name[name] for name in bone_names(rig.armature_object)[1:]], np.int64)
        p, joints_1 = animation_space_slots(model, limited, bone_joint, mesh_object.name)
    return ExportLevel(mesh_object.name, limited, int(changed.sum()), p, joints_1, source)


def level_model(rig, weights: SparseWeights):
    """The stored animation-space model (checked against the rig), else the limited weights converted (p_j = w_j
    Ĝ_j⁻¹ v̂, which the glTF LBS reproduces exactly)."""
    mesh_object = rig.mesh_object
    current_bind = bind_matrix(rig)
    if storage.has_model(mesh_object.data):
        stored = storage.read_model(mesh_object.data, mesh_object.name)
        if stored.bone_names != bone_names(rig.armature_object):
            raise SkinkitError("its model's bones differ from the armature's (convert it again)")
        scale = max(1.0, float(np.abs(current_bind[:3, 3]).max()))
        if np.abs(stored.bind - current_bind).max() > BIND_TOLERANCE * scale:
            raise SkinkitError("the mesh or its armature moved since its model was converted: its p_j no longer "
                               "sit in the bones' frames (convert it again)")
        return stored.model, "stored"
    skeleton = skeleton_of(rig, current_bind)
    return convert_lbs(skeleton, weights, mesh_of(mesh_object).positions), "linear blend"


# ---- writing ------------------------------------------------------------------------------------------------------

def run_export(job: ExportJob, path: str) -> dict:
    """Writes `path` with the format's exporter on temporary copies; returns the report."""
    started = time.perf_counter()
    armature = bpy.data.objects.get(job.armature_name)
    if armature is None:
        raise SkinkitError(f"its armature '{job.armature_name}' is gone; nothing was written")
    options, missing = supported(exporter(job.format), exporter_options(job.format, path, job.animation_space))
    warnings = list(job.warnings) + [f"this Blender's {job.format} exporter has no option {name}" for name in missing]
    with exported_copies(job, armature), action_frame_range(armature):
        try:
            result = exporter(job.format)(**options)
        except RuntimeError as error:
            raise SkinkitError(f"{path}: Blender's {job.format} exporter failed ({str(error).strip()})") from None
    if "FINISHED" not in result or not os.path.isfile(path):
        raise SkinkitError(f"{path}: Blender's {job.format} exporter wrote nothing")
    return {"format": job.format, "objects": [level.name for level in job.levels], "armature": job.armature_name,
            "bones": len(job.bone_names) - 1, "action": job.action, "max_joints": MAX_JOINTS,
            "limited_vertices": {level.name: level.limited_vertices for level in job.levels},
            "animation_space": job.animation_space,
            "slots": {level.name: level.p.shape[1] for level in job.levels if level.p is not None},
            "model": {level.name: level.model_source for level in job.levels if level.model_source},
            "units": "scene units (FBX unit scale)" if job.format == "fbx" else "metres",
            "unit_scale": job.unit_scale, "warnings": warnings, "seconds": time.perf_counter() - started}


@contextmanager
def action_frame_range(armature):
    """The scene's frame range set to the armature's action's while inside: USD's exporter writes the scene's range
    (glTF and FBX take the action's own), so a longer action would come back cut."""
    scene = bpy.context.scene
    saved = scene.frame_start, scene.frame_end
    data = armature.animation_data
    if data is not None and data.action is not None:
        first, last = (int(round(f)) for f in data.action.frame_range)
        scene.frame_start, scene.frame_end = first, max(first, last)
    try:
        yield
    finally:
        scene.frame_start, scene.frame_end = saved


def scaled_world(scene_object, scale: float) -> Matrix:
    """The object's world matrix in a world scaled by `scale` about the origin, its own data scaled instead of its
    transform: the translation scaled, rotation and scale kept (S W S^-1 for a uniform S)."""
    world = scene_object.matrix_world.copy()
    world.translation = world.translation * scale
    return world


def scale_locations(action, scale: float) -> None:
    """Every location curve of the action (the object's and each pose bone's) scaled, keys and handles alike;
    rotations and scales are unitless."""
    for fcurve in compat.action_fcurves(action):
        if fcurve.data_path.endswith("location"):
            for key in fcurve.keyframe_points:
                for point in (key.co, key.handle_left, key.handle_right):
                    point[1] *= scale


class exported_copies:
    """While inside: each level replaced, under its own name, by a selected copy carrying the limited weights and
    the attributes; when the job converts units, the armature, its data and action likewise, everything scaled by
    job.unit_scale. On leaving (also on failure) the copies are removed and names, selection and active restored."""

    def __init__(self, job: ExportJob, armature):
        self.job, self.armature = job, armature
        self.copies, self.renamed = [], []
        self.rig_copies = []  # (bpy.data collection, datablock): the scaled rig's object, bones and action
        self.rig = armature

    def __enter__(self):
        layer = bpy.context.view_layer
        self.selected = [o for o in layer.objects if o.select_get()]
        self.active = layer.objects.active
        try:
            if self.job.unit_scale != 1.0:
                self.rig = self.scaled_rig(self.armature, self.job.unit_scale)
            for level in self.job.levels:
                self.copies.append(self.copy_of(bpy.data.objects[level.name], level))
            for scene_object in layer.objects:
                scene_object.select_set(scene_object in self.copies or scene_object == self.rig)
            layer.objects.active = self.rig
        except Exception:
            self.__exit__(None, None, None)
            raise
        return self.copies

    def take_name(self, copy, original) -> None:
        """The copy takes the original's name, the original moving aside until __exit__."""
        name = original.name
        self.renamed.append((original, name))
        original.name = name + _ORIGINAL_SUFFIX
        copy.name = name

    def scaled_rig(self, armature, scale: float):
        """A copy of the armature (object, bones, action) in a world scaled by `scale`, under their names."""
        rig = armature.copy()
        self.rig_copies.append((bpy.data.objects, rig))
        rig.data = armature.data.copy()
        self.rig_copies.append((bpy.data.armatures, rig.data))
        self.take_name(rig, armature)
        self.take_name(rig.data, armature.data)
        bpy.context.scene.collection.objects.link(rig)
        rig.data.transform(Matrix.Scale(scale, 4))
        rig.matrix_world = scaled_world(armature, scale)
        data = armature.animation_data
        if data is not None and data.action is not None:
            action = data.action.copy()
            self.rig_copies.append((bpy.data.actions, action))
            self.take_name(action, data.action)
            rig.animation_data.action = action  # the copy keeps the original's slot identifier (4.4 on)
            scale_locations(action, scale)
        return rig

    def copy_of(self, original, level: ExportLevel):
        copy = original.copy()
        copy.data = original.data.copy()
        self.take_name(copy, original)
        self.take_name(copy.data, original.data)  # USD names an imported object after its mesh: both move aside
        bpy.context.scene.collection.objects.link(copy)
        copy.vertex_groups.clear()
        write_bone_groups(copy, level.weights, self.job.bone_names)
        if level.p is not None:
            write_animation_space(copy.data, level, self.job.unit_scale)
        if self.rig is not self.armature:
            self.scale_onto_rig(copy, original, self.job.unit_scale)
        return copy

    def scale_onto_rig(self, copy, original, scale: float) -> None:
        """The level's copy deformed by the scaled rig: its vertices scaled, parented and bound to the rig."""
        copy.data.transform(Matrix.Scale(scale, 4), shape_keys=True)
        for modifier in copy.modifiers:
            if modifier.type == "ARMATURE" and modifier.object == self.armature:
                modifier.object = self.rig
        if copy.parent == self.armature:
            copy.parent = self.rig
        copy.matrix_world = scaled_world(original, scale)

    def __exit__(self, *exception):
        for copy in self.copies:
            mesh = copy.data
            bpy.data.objects.remove(copy)
            bpy.data.meshes.remove(mesh)
        for collection, datablock in self.rig_copies:  # the object before its bones and action
            collection.remove(datablock)
        for original, name in reversed(self.renamed):
            original.name = name
        layer = bpy.context.view_layer
        for scene_object in layer.objects:
            scene_object.select_set(scene_object in self.selected)
        layer.objects.active = self.active
        return False


def write_animation_space(mesh, level: ExportLevel, unit_scale: float = 1.0) -> None:
    """The `_SKINKIT_P_<s>` attributes (p_j's x, y, z in the file's units, w the weight) and `_SKINKIT_JOINTS_1`."""
    data_type = compat.gltf_vec4_attribute_type()
    units = np.array([unit_scale, unit_scale, unit_scale, 1.0], np.float32)
    for slot in range(level.p.shape[1]):
        attribute = mesh.attributes.new(P_ATTRIBUTE.format(slot), data_type, "POINT")
        attribute.data.foreach_set(vec4_field(data_type), (level.p[:, slot] * units).reshape(-1))
    if level.joints_1 is not None:
        attribute = mesh.attributes.new(JOINTS_1_ATTRIBUTE, data_type, "POINT")
        attribute.data.foreach_set(vec4_field(data_type), level.joints_1.reshape(-1))


def check_extension(path: str, fmt: str) -> None:
    if not path.lower().endswith(EXTENSIONS[fmt]):
        raise SkinkitError(f"{path}: a {fmt} export must end in {' or '.join(EXTENSIONS[fmt])}")


@contextmanager
def staged(path: str):
    """Yields a path in a private folder beside `path` (same file system); the file replaces `path` when the block
    completes, and the folder goes, with whatever an exporter left beside its file (USD's empty textures/), either
    way: no half-written file ever sits under the target's name."""
    target = os.path.abspath(path)
    folder, name = os.path.split(target)
    if not os.path.isdir(folder):
        raise SkinkitError(f"{path}: the folder {folder} does not exist")
    staging = tempfile.mkdtemp(prefix=f".{name}.partial-", dir=folder)
    try:
        written = os.path.join(staging, name)
        yield written
        os.replace(written, target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def export_for_engines(objects, path: str, fmt: str, animation_space: bool = True,
                       unit_scale: float | None = None) -> dict:
    """Prepares and writes `path` (staged: renamed onto it only when complete); returns the report with `out`.
    unit_scale: metres per Blender unit for glTF and USD (None: the scene's unit scale); FBX takes the scene's."""
    if fmt in EXTENSIONS:
        check_extension(path, fmt)
    job = prepare_export(objects, fmt, animation_space, unit_scale)
    with staged(path) as temporary:
        report = run_export(job, temporary)
    report["out"] = os.path.abspath(path)
    return report
