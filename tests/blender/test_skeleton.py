"""Extract Skeleton in real Blender: the operator on a segmented sample (parts by face attribute, vertex groups,
materials) builds an armature with one bone per part, its hierarchy, Limit Rotation constraints and rigid vertex
groups; parts that do not meet are refused with the scene unchanged; the hierarchy file exports and imports."""
import bpy
import numpy as np
import pytest
from tests.blender.test_skinning import scene_fingerprint, select

from skinkit.blender import scene
from skinkit.blender import skeleton as bridge
from skinkit.skeleton import Hierarchy, chain_of_cylinders, free_limits, read_hierarchy, star_of_limbs, write_hierarchy


def segmented_object(sample, source="attribute"):
    scene.empty_scene()
    parts = sample.parts
    mesh_object = scene.new_mesh_object("character", parts.positions, parts.triangles)
    if source == "attribute":
        attribute = mesh_object.data.attributes.new(bridge.PART_ATTRIBUTE, "INT", "FACE")
        attribute.data.foreach_set("value", parts.triangle_parts)
        mesh_object.data[bridge.PART_NAMES] = list(parts.names)
    elif source == "groups":
        labels = parts.vertex_parts()
        for p, name in enumerate(parts.names):
            mesh_object.vertex_groups.new(name=name).add(np.flatnonzero(labels == p).tolist(), 1.0, "REPLACE")
    elif source == "materials":
        for name in parts.names:
            mesh_object.data.materials.append(bpy.data.materials.new(name))
        mesh_object.data.polygons.foreach_set("material_index", parts.triangle_parts)
    select(mesh_object)
    return mesh_object


@pytest.mark.parametrize("source", ["attribute", "materials"])
def test_extract_skeleton_builds_the_rig(addon, source):
    sample = star_of_limbs()
    mesh_object = segmented_object(sample, source)
    assert bpy.ops.skinkit.extract_skeleton(part_source=source, method="centroid") == {"FINISHED"}
    armature = bpy.data.objects["character_skeleton"]
    bones = armature.data.bones
    assert [b.name for b in bones] == list(sample.parts.names)
    assert [b.parent.name if b.parent else None for b in bones] == [None] + ["hub"] * 5
    for part in range(1, 6):  # each limb's bone starts at its opening with the hub
        np.testing.assert_allclose(bones[part].head_local, sample.openings[part], atol=1e-6)
        assert armature.pose.bones[part].constraints[0].type == "LIMIT_ROTATION"
    assert mesh_object.modifiers[0].type == "ARMATURE" and mesh_object.modifiers[0].object == armature
    assert [g.name for g in mesh_object.vertex_groups] == list(sample.parts.names)


def test_vertex_groups_and_principal_axis(addon):
    sample = chain_of_cylinders(3)
    mesh_object = segmented_object(sample, "groups")
    assert bpy.ops.skinkit.extract_skeleton(part_source="groups", method="principal-axis", refine=True,
                                            max_angle=15) == {"FINISHED"}
    assert len(bpy.data.objects["character_skeleton"].data.bones) == 3
    assert len(mesh_object.modifiers) == 1


def test_parts_that_do_not_meet_leave_the_scene_unchanged(addon):
    parts = chain_of_cylinders(2).parts
    apart = type(parts)(np.vstack([parts.positions, parts.positions + 50]),
                        np.vstack([parts.triangles, parts.triangles + len(parts.positions)]),
                        np.repeat(np.array([0, 1], np.int32), len(parts.triangles)), ("a", "b"))
    segmented_object(type("Sample", (), {"parts": apart})())
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="has no opening"):
        bpy.ops.skinkit.extract_skeleton(part_source="attribute")
    with pytest.raises(RuntimeError, match="no vertex groups"):
        bpy.ops.skinkit.extract_skeleton(part_source="groups")
    assert scene_fingerprint() == before
    assert "character_skeleton" not in bpy.data.objects


def test_hierarchy_export_and_import(addon, tmp_path):
    sample = star_of_limbs()
    segmented_object(sample)
    bpy.ops.skinkit.extract_skeleton(part_source="attribute", method="opening")
    armature = bpy.data.objects["character_skeleton"]
    limits = free_limits(6)
    limits[1] = [[0, 150], [-10, 10], [-5, 5]]
    path = str(tmp_path / "star.hier")
    write_hierarchy(path, Hierarchy(sample.parts.names, sample.parents, limits))
    bpy.context.view_layer.objects.active = armature
    assert bpy.ops.skinkit.import_hierarchy(filepath=path) == {"FINISHED"}
    constraint = armature.pose.bones["limb_px"].constraints[0]
    assert constraint.max_x == pytest.approx(np.radians(150))
    out = str(tmp_path / "back.hier")
    assert bpy.ops.skinkit.export_hierarchy(filepath=out) == {"FINISHED"}
    back = read_hierarchy(out)
    assert back.names == sample.parts.names and back.parents.tolist() == sample.parents.tolist()
    np.testing.assert_allclose(back.limits, limits, atol=1e-4)
    bad = tmp_path / "bad.hier"
    bad.write_text("nobody 0 1 0 1 0 1\n{\n}\n")
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="nobody"):
        bpy.ops.skinkit.import_hierarchy(filepath=str(bad))
    assert scene_fingerprint() == before


def test_rigid_skin_with_seams_bakes_watertight_frames(addon):
    from skinkit.blender.rig import mesh_of
    from skinkit.skeleton.seams import boundary_edges, is_consistently_oriented

    sample = star_of_limbs()
    mesh_object = segmented_object(sample)
    bpy.ops.skinkit.extract_skeleton(part_source="attribute", method="centroid")
    armature = bpy.data.objects["character_skeleton"]
    bone = armature.pose.bones["limb_px"]
    bone.rotation_mode = "XYZ"
    for frame, angle in ((1, 0.0), (3, 1.2)):
        bone.rotation_euler = (angle, 0.0, 0.0)
        bone.keyframe_insert("rotation_euler", frame=frame)
    select(mesh_object)
    assert bpy.ops.skinkit.rigid_skin_seams(frame_start=1, frame_end=3, steps=3) == {"FINISHED"}
    baked = bpy.data.objects["character_seamed"]
    triangles = mesh_of(baked).triangles
    assert boundary_edges(triangles) == 0 and is_consistently_oriented(triangles)
    keys = baked.data.shape_keys.key_blocks
    assert [k.name for k in keys] == ["Basis", "frame_0001", "frame_0002", "frame_0003"]
    last = np.empty(len(baked.data.vertices) * 3, np.float32)
    keys["frame_0003"].points.foreach_get("co", last)
    first = np.empty_like(last)
    keys["frame_0001"].points.foreach_get("co", first)
    assert np.abs(last - first).max() > 0.5  # the limb moved; its seam followed without tearing
    bpy.context.view_layer.objects.active = armature
    with pytest.raises(RuntimeError):
        bpy.ops.skinkit.rigid_skin_seams()  # poll: an armature is not a mesh


def test_live_seams_follow_the_armature_every_frame(addon):
    from skinkit.blender.rig import mesh_of
    from skinkit.skeleton.seams import boundary_edges

    mesh_object = segmented_object(star_of_limbs())
    bpy.ops.skinkit.extract_skeleton(part_source="attribute", method="centroid")
    armature = bpy.data.objects["character_skeleton"]
    bone = armature.pose.bones["limb_py"]
    bone.rotation_mode = "XYZ"
    for frame, angle in ((1, 0.0), (5, -1.0)):
        bone.rotation_euler = (angle, 0.0, 0.0)
        bone.keyframe_insert("rotation_euler", frame=frame)
    bpy.context.scene.frame_set(1)
    select(mesh_object)
    assert bpy.ops.skinkit.rigid_skin_seams(live=True, steps=2) == {"FINISHED"}
    seamed = bpy.data.objects["character_seamed"]
    at_rest = mesh_of(seamed).positions.copy()
    bpy.context.scene.frame_set(5)
    moved = mesh_of(seamed).positions
    assert np.abs(moved - at_rest).max() > 0.5 and boundary_edges(mesh_of(seamed).triangles) == 0
    bpy.context.scene.frame_set(1)
    np.testing.assert_allclose(mesh_of(seamed).positions, at_rest, atol=1e-5)


def _swinging_star(bone_name, angle_at_frame):
    mesh_object = segmented_object(star_of_limbs())
    bpy.ops.skinkit.extract_skeleton(part_source="attribute", method="centroid")
    bone = bpy.data.objects["character_skeleton"].pose.bones[bone_name]
    bone.rotation_mode = "XYZ"
    for frame, angle in angle_at_frame:
        bone.rotation_euler = (angle, 0.0, 0.0)
        bone.keyframe_insert("rotation_euler", frame=frame)
    bpy.context.scene.frame_set(1)
    select(mesh_object)
    return mesh_object


def test_rigid_skin_with_sinking_removal_bakes_one_closed_object_per_frame(addon):
    """Remove Sinking: Algorithm 5 per frame, so the vertex count changes; the bake is a collection of one object
    per frame, each shown only on its frame, every one watertight and consistently oriented."""
    from skinkit.blender.rig import mesh_of
    from skinkit.skeleton.seams import boundary_edges, is_consistently_oriented

    _swinging_star("limb_px", ((1, 0.0), (3, 1.2)))
    assert bpy.ops.skinkit.rigid_skin_seams(frame_start=1, frame_end=3, steps=3, remove_sinking=True,
                                            arcs="conic") == {"FINISHED"}
    collection = bpy.data.collections["character_seamed"]
    frames = [bpy.data.objects[f"character_seamed_{k:04d}"] for k in (1, 2, 3)]
    assert set(collection.objects) == set(frames)
    for frame in frames:
        triangles = mesh_of(frame).triangles
        assert boundary_edges(triangles) == 0 and is_consistently_oriented(triangles)
        assert len(frame.data.vertices) - len(triangles) // 2 == 2
    assert len(frames[2].data.vertices) != len(frames[0].data.vertices)  # points sank at frame 3 and went
    bpy.context.scene.frame_set(3)
    assert [f.hide_viewport for f in frames] == [True, True, False]
    bpy.context.scene.frame_set(1)
    assert [f.hide_render for f in frames] == [False, True, True]


def test_live_seams_with_sinking_removal_rewrite_the_mesh_every_frame(addon):
    from skinkit.blender.rig import mesh_of
    from skinkit.skeleton.seams import boundary_edges, is_consistently_oriented

    _swinging_star("limb_py", ((1, 0.0), (5, -1.2)))
    assert bpy.ops.skinkit.rigid_skin_seams(live=True, steps=2, remove_sinking=True) == {"FINISHED"}
    seamed = bpy.data.objects["character_seamed"]
    at_rest = len(seamed.data.vertices)
    bpy.context.scene.frame_set(5)
    triangles = mesh_of(seamed).triangles
    assert len(seamed.data.vertices) < at_rest  # the sinking points are gone
    assert boundary_edges(triangles) == 0 and is_consistently_oriented(triangles)
    bpy.context.scene.frame_set(1)
    assert len(seamed.data.vertices) == at_rest
