"""Export for Engines in real Blender: the glTF file carries the animation-space model in the layout of
docs/engine-format.md (JOINTS_0 with `_SKINKIT_P_<s>`, and `_SKINKIT_JOINTS_1` for slots 4-7), read back from the
.glb bytes and evaluated as an engine would (v = Σ_s G[joint_s] p_s); the operator takes every option as a
property, refuses what it cannot export with the scene unchanged, and leaves no partial file."""
import json
import os
import struct

import bpy
import numpy as np
import pytest
from tests.blender.test_round_trip import nearest, released_exporter_caches, rest_world  # noqa: F401
from tests.blender.test_skinning import scene_fingerprint, select

from skinkit import SkinkitError
from skinkit.blender import export, lod_chain, storage
from skinkit.blender.frames import depsgraphs_at
from skinkit.blender.scene import local_to_world
from skinkit.blender.skinning import model_positions

#: glTF is Y up: Blender's (x, y, z) is glTF's (x, z, -y).
Y_UP = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], np.float64)
COMPONENTS = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}
WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def read_glb(path: str):
    """(the JSON document, accessor(index) -> numpy array) of a binary glTF."""
    with open(path, "rb") as file:
        data = file.read()
    magic, _, _ = struct.unpack_from("<4sII", data, 0)
    assert magic == b"glTF"
    json_length, _ = struct.unpack_from("<II", data, 12)
    document = json.loads(data[20:20 + json_length])
    binary_start = 20 + json_length + 8
    binary = data[binary_start:binary_start + struct.unpack_from("<I", data, 20 + json_length)[0]]

    def accessor(index: int) -> np.ndarray:
        spec = document["accessors"][index]
        view = document["bufferViews"][spec["bufferView"]]
        dtype = np.dtype(COMPONENTS[spec["componentType"]])
        width = WIDTHS[spec["type"]]
        stride = view.get("byteStride", dtype.itemsize * width)
        assert stride == dtype.itemsize * width  # Blender writes tightly packed views
        start = view.get("byteOffset", 0) + spec.get("byteOffset", 0)
        values = np.frombuffer(binary, dtype, spec["count"] * width, start)
        return values.reshape(spec["count"], width) if width > 1 else values

    return document, accessor


def gltf_mesh(document, accessor, name: str) -> dict:
    """The attributes of the mesh node called `name` (all primitives stacked) and its skin."""
    node = next(n for n in document["nodes"] if n.get("name") == name)
    primitives = document["meshes"][node["mesh"]]["primitives"]
    attributes = {}
    for key in primitives[0]["attributes"]:
        attributes[key] = np.concatenate([accessor(p["attributes"][key]) for p in primitives])
    skin = document["skins"][node["skin"]]
    joints = [document["nodes"][j]["name"] for j in skin["joints"]]
    inverse_binds = accessor(skin["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
    return {"attributes": attributes, "joints": joints, "inverse_binds": inverse_binds.astype(np.float64)}


def slot_joints(attributes) -> np.ndarray:
    """(N, S) joint index of every slot: JOINTS_0, then _SKINKIT_JOINTS_1 when there are 8 slots."""
    joints = attributes["JOINTS_0"].astype(np.int64)
    if export.JOINTS_1_ATTRIBUTE in attributes:
        joints = np.concatenate([joints, attributes[export.JOINTS_1_ATTRIBUTE].round().astype(np.int64)], axis=1)
    return joints


def slot_positions(attributes, slot_count: int) -> np.ndarray:
    return np.stack([attributes[export.P_ATTRIBUTE.format(s)].astype(np.float64) for s in range(slot_count)], axis=1)


def evaluate(joint_frames: np.ndarray, joints: np.ndarray, p: np.ndarray) -> np.ndarray:
    """v = Σ_s G[joint_s] p_s, as the engine's shader does (joint_frames (J, 4, 4))."""
    return np.einsum("nsij,nsj->ni", joint_frames[joints], p)[:, :3]


@pytest.fixture
def creature_chain(open_sample, addon):
    """The creature's stored model, its chain of 2 levels (a non-deforming root bone, 3-4 influences)."""
    mesh_object = open_sample("creature")
    select(mesh_object)
    assert bpy.ops.skinkit.convert_to_animation_space() == {"FINISHED"}
    report = lod_chain.build_lod_chain(mesh_object, levels=2)
    return [bpy.data.objects[name] for name in report["objects"]]


@pytest.mark.parametrize("unit_scale", [1.0, 0.01])
def test_the_gltf_attributes_reproduce_the_animation_space_model(creature_chain, tmp_path, unit_scale):
    """In a metre scene and in a centimetre one (scale_length 0.01), where the file is in metres: positions, joint
    rests and animation, and the _SKINKIT_P_<s> translation rows all scaled alike."""
    levels = creature_chain
    bpy.context.scene.unit_settings.scale_length = unit_scale
    armature = levels[0].modifiers[0].object
    path = str(tmp_path / "creature.glb")
    report = export.export_for_engines(levels, path, "glb")
    assert report["animation_space"] and set(report["slots"].values()) <= {4, 8}
    assert report["units"] == "metres" and report["unit_scale"] == pytest.approx(unit_scale)
    document, accessor = read_glb(path)
    frames = [1, 13, 25, 37]
    model_world = {o.name: [] for o in levels}
    joint_frames = []
    order = export.joint_order(armature)
    to_metres = np.diag([unit_scale, unit_scale, unit_scale, 1.0])
    for depsgraph in depsgraphs_at(frames):
        world = to_metres @ np.array(armature.matrix_world)
        joint_frames.append(np.array([Y_UP @ world @ np.array(armature.pose.bones[name].matrix) @
                                      np.linalg.inv(to_metres) for name in order]))
        for level in levels:
            model_world[level.name].append(unit_scale * local_to_world(level, model_positions(level, depsgraph)))
    armature.data.pose_position = "REST"  # the model in the rest pose (a coarse level's differs from its mesh)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    model_at_rest = {o.name: unit_scale * local_to_world(o, model_positions(o, depsgraph)) @ Y_UP[:3, :3].T
                     for o in levels}
    armature.data.pose_position = "POSE"
    for level in levels:
        found = gltf_mesh(document, accessor, level.name)
        assert found["joints"] == order  # the joint order the bridge computes is the exporter's
        attributes = found["attributes"]
        slots = sum(1 for key in attributes if key.startswith("_SKINKIT_P_"))
        assert slots == report["slots"][level.name] and (export.JOINTS_1_ATTRIBUTE in attributes) == (slots == 8)
        joints, p = slot_joints(attributes), slot_positions(attributes, slots)
        rest = unit_scale * rest_world(level) @ Y_UP[:3, :3].T
        diagonal = np.linalg.norm(np.ptp(rest, axis=0))
        np.testing.assert_allclose(p[..., 3].sum(axis=1), 1.0, atol=1e-5)  # a point's homogeneous weights
        match, distance = nearest(rest, attributes["POSITION"].astype(np.float64))
        assert distance.max() <= 1e-5 * diagonal
        # In the rest pose the joints' global frames are the inverse bind matrices' inverses (the file's own).
        at_rest = evaluate(np.linalg.inv(found["inverse_binds"]), joints, p)
        assert np.abs(at_rest - model_at_rest[level.name][match]).max() <= 1e-5 * diagonal
        worst = 0.0
        for frame_joints, expected in zip(joint_frames, model_world[level.name]):
            posed = evaluate(frame_joints, joints, p)
            expected_y_up = expected @ Y_UP[:3, :3].T
            worst = max(worst, np.linalg.norm(posed - expected_y_up[match], axis=1).max() / diagonal)
        assert worst <= 1e-5, (level.name, worst)
        print(f"{level.name}: {slots} slots, the attributes evaluated as an engine does are {worst:.2e} of the "
              "diagonal from the model")
        weights = attributes["WEIGHTS_0"]
        np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-5)
        assert "JOINTS_1" not in attributes and "WEIGHTS_1" not in attributes


def test_slots_follow_joints_0_and_extra_bones_go_to_joints_1():
    """A model with a bone the linear-blend weights do not have: it takes slot 4, its joint in _SKINKIT_JOINTS_1."""
    from skinkit.model import AnimationSpaceModel, SparseWeights

    weights = SparseWeights.create(np.array([0, 2, 3]), np.array([1, 2, 3]), np.array([0.25, 0.75, 1.0]), 5)
    model = AnimationSpaceModel.create(np.array([0, 3, 4]), np.array([1, 2, 4, 3]),
                                       np.array([[1, 0, 0, 0.25], [0, 1, 0, 0.5], [0, 0, 1, 0.25], [2, 2, 2, 1.0]]), 5)
    bone_joint = np.array([0, 10, 20, 30, 40])
    p, joints_1 = export.animation_space_slots(model, weights, bone_joint, "test")
    assert p.shape == (2, 8, 4)
    np.testing.assert_array_equal(p[0, 0], [0, 1, 0, 0.5])  # bone 2 weighs most: JOINTS_0[0]
    np.testing.assert_array_equal(p[0, 1], [1, 0, 0, 0.25])
    np.testing.assert_array_equal(p[0, 4], [0, 0, 1, 0.25])
    assert joints_1[0, 0] == 40 and not p[1, 1:].any()
    root = AnimationSpaceModel.create(np.array([0, 1, 2]), np.array([0, 3]), np.array([[0, 0, 0, 1.0]] * 2), 5)
    with pytest.raises(SkinkitError, match="1 vertices are influenced by skinkit's root"):
        export.animation_space_slots(root, weights, bone_joint, "test")


def test_the_operator_exports_with_every_option_and_leaves_the_scene(open_sample, addon, tmp_path):
    mesh_object = open_sample("arm")
    select(mesh_object)
    assert bpy.ops.skinkit.build_lod_chain(levels=2) == {"FINISHED"}
    select(bpy.data.objects["arm_LOD1"])  # any level names its chain
    before = scene_fingerprint()
    for fmt, name in (("GLB", "arm.glb"), ("FBX", "arm.fbx"), ("USD", "arm.usdc")):
        path = str(tmp_path / name)
        assert bpy.ops.skinkit.export_for_engines(filepath=path, format=fmt, chain="arm", animation_space=True,
                                                  unit_scale=0.0) == {"FINISHED"}
        assert os.path.getsize(path) > 0
    assert scene_fingerprint() == before
    assert sorted(os.listdir(tmp_path)) == ["arm.fbx", "arm.glb", "arm.usdc"]
    # an explicit unit scale: the file in metres at 0.01 m per unit (every position 0.01x the metre file's)
    metres = str(tmp_path / "arm_cm.glb")
    assert bpy.ops.skinkit.export_for_engines(filepath=metres, format="GLB", chain="arm",
                                              unit_scale=0.01) == {"FINISHED"}
    assert scene_fingerprint() == before
    (plain, plain_accessor), (scaled, scaled_accessor) = read_glb(str(tmp_path / "arm.glb")), read_glb(metres)
    for name in ("arm_LOD0", "arm_LOD1"):
        np.testing.assert_allclose(gltf_mesh(scaled, scaled_accessor, name)["attributes"]["POSITION"],
                                   0.01 * gltf_mesh(plain, plain_accessor, name)["attributes"]["POSITION"],
                                   rtol=1e-6, atol=1e-7)
    with pytest.raises(RuntimeError, match="FBX writes the scene's own unit"):
        bpy.ops.skinkit.export_for_engines(filepath=str(tmp_path / "x.fbx"), format="FBX", chain="arm",
                                           unit_scale=0.01)
    assert scene_fingerprint() == before and "x.fbx" not in os.listdir(tmp_path)


def test_the_operator_refuses_and_changes_nothing(open_sample, addon, tmp_path):
    mesh_object = open_sample("arm")
    select(mesh_object)
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="must end in .fbx"):
        bpy.ops.skinkit.export_for_engines(filepath=str(tmp_path / "arm.glb"), format="FBX")
    with pytest.raises(RuntimeError, match="no LOD chain 'ghost_LOD0..n'"):
        bpy.ops.skinkit.export_for_engines(filepath=str(tmp_path / "arm.glb"), chain="ghost")
    assert scene_fingerprint() == before and not os.listdir(tmp_path)
    mesh_object.modifiers.remove(mesh_object.modifiers[0])
    assert not bpy.ops.skinkit.export_for_engines.poll()


@pytest.mark.parametrize("unit_scale", [1.0, 0.01])
def test_a_failing_exporter_leaves_no_copy_and_no_file(open_sample, addon, tmp_path, monkeypatch, unit_scale):
    """Also in a centimetre scene, where the armature and its action are copied and scaled too."""
    mesh_object = open_sample("arm")
    bpy.context.scene.unit_settings.scale_length = unit_scale
    datablocks = (len(bpy.data.objects), len(bpy.data.armatures), len(bpy.data.actions), len(bpy.data.meshes))
    before = scene_fingerprint()
    selected_before = [o.name for o in bpy.context.view_layer.objects if o.select_get()]

    real = export.exporter

    class Broken:  # Blender's exporter, failing half-way (its options still read from the real one)
        def __init__(self, fmt):
            self.real = real(fmt)

        def get_rna_type(self):
            return self.real.get_rna_type()

        def __call__(self, **options):
            assert bpy.data.objects["arm"] != mesh_object  # the copy stands in while it runs
            with open(options["filepath"], "wb") as partial:
                partial.write(b"glTF")
            raise RuntimeError("Error: disk full")

    monkeypatch.setattr(export, "exporter", Broken)
    with pytest.raises(SkinkitError, match="disk full"):
        export.export_for_engines([mesh_object], str(tmp_path / "arm.glb"), "glb")
    assert scene_fingerprint() == before and not os.listdir(tmp_path)
    assert [o.name for o in bpy.context.view_layer.objects if o.select_get()] == selected_before
    assert storage.has_model(mesh_object.data) is False
    assert (len(bpy.data.objects), len(bpy.data.armatures), len(bpy.data.actions), len(bpy.data.meshes)) == datablocks
    assert bpy.data.objects["arm_rig"].animation_data.action.name == "arm_twist"


def test_a_model_bound_elsewhere_is_refused(open_sample, addon, tmp_path):
    mesh_object = open_sample("arm")
    select(mesh_object)
    assert bpy.ops.skinkit.convert_to_animation_space() == {"FINISHED"}
    mesh_object.location.x += 1.0
    bpy.context.view_layer.update()
    with pytest.raises(SkinkitError, match="moved since its model was converted"):
        export.export_for_engines([mesh_object], str(tmp_path / "arm.glb"), "glb")
    report = export.export_for_engines([mesh_object], str(tmp_path / "arm.glb"), "glb", animation_space=False)
    assert not report["animation_space"] and os.path.isfile(tmp_path / "arm.glb")


def test_the_panel_offers_each_format_for_the_active_levels_chain(open_sample, addon):
    from tests.blender.test_skinning import RecordingLayout

    def drawn():
        panel = type("Panel", (), {"layout": RecordingLayout()})()
        addon.export.SKINKIT_PT_export.draw(panel, bpy.context)
        return panel.layout

    mesh_object = open_sample("arm")
    select(mesh_object)
    assert "arm: 1 object(s)" in drawn().texts()
    lod_chain.build_lod_chain(mesh_object, levels=2)
    select(bpy.data.objects["arm_LOD1"])
    layout = drawn()
    assert "arm: 2 object(s)" in layout.texts()
    assert [args[0] for name, args, _ in layout.record if name == "operator"] == \
        [addon.export.SKINKIT_OT_export_for_engines.bl_idname] * 3
    select(bpy.data.objects["arm_rig"])
    assert "Select a skinned mesh or a LOD level" in drawn().texts()
