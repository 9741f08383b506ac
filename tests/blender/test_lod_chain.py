"""Build LOD Chain in real Blender: the operator on a sample character writes <name>_LOD0..n that Blender's own
Armature modifier plays within each level's error plus its linear-blend approximation error; the source is
untouched; a mesh without a rig is refused with the scene unchanged."""
import bpy
import bmesh  # noqa: E402 (after bpy)
import numpy as np
import pytest
from tests.blender.test_skinning import scene_fingerprint, select

from skinkit.blender import lod_chain, storage
from skinkit.blender.lod import read_source
from skinkit.blender.frames import depsgraphs_at, evaluated_positions
from skinkit.blender.rig import mesh_of, rest_positions
from skinkit.blender.skinning import model_positions


def played_frames(mesh_object):
    action = mesh_object.modifiers[0].object.animation_data.action
    first, last = (int(round(f)) for f in action.frame_range)
    return list(range(first, last + 1, max(1, (last - first) // 6)))


@pytest.mark.parametrize("options", [{}, {"metric": "REST", "simplify_influences": False, "max_influences": 2},
                                     {"collapse": "AUTO", "influence_cost_scale": 3.0}])
def test_operator_writes_levels_that_the_armature_modifier_plays(open_sample, addon, options):
    mesh_object = open_sample("arm")
    select(mesh_object)
    source_before = scene_fingerprint()["objects"][mesh_object.name]
    assert bpy.ops.skinkit.build_lod_chain(levels=3, **options) == {"FINISHED"}
    assert scene_fingerprint()["objects"][mesh_object.name] == source_before
    collection = bpy.data.collections[f"{mesh_object.name}_LOD"]
    levels = [bpy.data.objects[f"{mesh_object.name}_LOD{i}"] for i in range(3)]
    assert sorted(o.name for o in collection.objects) == [o.name for o in levels]
    assert collection[lod_chain.REPORT_PROPERTY]["levels"] == 3
    source = mesh_of(mesh_object)
    first = mesh_of(levels[0])
    np.testing.assert_allclose(first.positions, source.positions, atol=1e-6)
    np.testing.assert_array_equal(first.triangles, source.triangles)
    rows = [o[lod_chain.REPORT_PROPERTY] for o in levels]
    assert [r["triangles"] for r in rows] == sorted((r["triangles"] for r in rows), reverse=True)
    assert rows[-1]["triangles"] < rows[0]["triangles"] and rows[0]["error"] == 0.0
    max_influences = options.get("max_influences", 4)
    diagonal = np.linalg.norm(np.ptp(rest_positions(mesh_object), axis=0))
    rest_frames = read_source(mesh_object).skeleton.rest_frames  # in mesh space, as the levels' models are
    kept = {}
    for level_object in levels:
        assert storage.has_model(level_object.data)
        assert level_object.modifiers[0].type == "ARMATURE"
        assert level_object.modifiers[0].object == mesh_object.modifiers[0].object
        assert level_object.parent == mesh_object.parent
        mesh = bmesh.new()
        mesh.from_mesh(level_object.data)
        assert all(edge.is_manifold or edge.is_boundary for edge in mesh.edges)
        assert all(vertex.is_manifold for vertex in mesh.verts)
        weights = [[g.weight for g in v.groups] for v in level_object.data.vertices]
        assert max(len(w) for w in weights) <= max_influences
        assert np.allclose([sum(w) for w in weights if w], 1.0, atol=1e-5)
        found = np.empty(len(level_object.data.vertices), np.int32)
        level_object.data.attributes[lod_chain.SOURCE_VERTEX_ATTRIBUTE].data.foreach_get("value", found)
        # LOD0 stands on the source; a coarser level where its model puts it in the rest pose
        expected = source.positions[found] if level_object is levels[0] else \
            storage.read_model(level_object.data, level_object.name).model.evaluate(rest_frames[None])[0]
        np.testing.assert_allclose(rest_positions(level_object), expected, atol=1e-5)
        kept[level_object.name] = found
    worst = {o.name: [0.0, 0.0] for o in levels}
    for depsgraph in depsgraphs_at(played_frames(mesh_object)):
        reference = evaluated_positions(mesh_object, depsgraph)
        for level_object in levels:
            played = evaluated_positions(level_object, depsgraph)
            ours = model_positions(level_object, depsgraph)
            w = worst[level_object.name]
            w[0] = max(w[0], np.linalg.norm(played - ours, axis=1).max() / diagonal)
            w[1] = max(w[1], np.linalg.norm(played - reference[kept[level_object.name]], axis=1).max() / diagonal)
    for level_object, row in zip(levels, rows):
        to_model, to_source = worst[level_object.name]
        assert to_model <= 2 * row["lbs_error"] + 1e-6, (level_object.name, to_model, row)
        assert to_source <= 2 * (row["error"] + row["lbs_error"]) + 1e-6, (level_object.name, to_source, row)


def test_a_uv_map_and_materials_are_carried_to_every_level(open_sample, addon):
    mesh_object = open_sample("arm")
    select(mesh_object)
    assert bpy.ops.skinkit.animated_unwrap(metric="REST", straighten=True, make_active=True) == {"FINISHED"}
    material = bpy.data.materials.new("skin")
    mesh_object.data.materials.append(material)
    report = lod_chain.build_lod_chain(mesh_object, levels=3)
    assert [row["level"] for row in report["levels"]] == [0, 1, 2] and not report["warnings"]
    for name in report["objects"]:
        level_object = bpy.data.objects[name]
        data = level_object.data
        assert data.uv_layers.active.name == mesh_object.data.uv_layers.active.name
        assert list(data.materials) == [material]
        uv = np.empty(len(data.loops) * 2, np.float32)
        data.uv_layers.active.uv.foreach_get("vector", uv)
        assert uv.min() >= 0 and uv.max() <= 1


def test_refused_without_a_rig_and_the_scene_is_unchanged(open_sample, addon):
    mesh_object = open_sample("arm")
    mesh_object.modifiers.remove(mesh_object.modifiers[0])
    select(mesh_object)
    assert not bpy.ops.skinkit.build_lod_chain.poll()
    before = scene_fingerprint()
    collections = len(bpy.data.collections)
    with pytest.raises(Exception, match="Armature modifier"):
        lod_chain.prepare_lod_chain(mesh_object)
    assert scene_fingerprint() == before and len(bpy.data.collections) == collections


def test_a_second_chain_is_refused_while_the_first_exists(open_sample, addon):
    mesh_object = open_sample("arm")
    select(mesh_object)
    assert bpy.ops.skinkit.build_lod_chain(levels=2) == {"FINISHED"}
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="already exists"):
        bpy.ops.skinkit.build_lod_chain(levels=2)
    assert scene_fingerprint() == before


def test_a_stored_model_and_stored_statistics_are_used(open_sample, addon):
    mesh_object = open_sample("creature")
    select(mesh_object)
    assert bpy.ops.skinkit.convert_to_animation_space() == {"FINISHED"}
    assert bpy.ops.skinkit.compute_pose_statistics(source="UNIFORM") == {"FINISHED"}
    stored = storage.read_model(mesh_object.data, mesh_object.name).model
    report = lod_chain.build_lod_chain(mesh_object, levels=2, metric="animation")
    assert report["statistics"] == "stored"
    first = storage.read_model(bpy.data.objects[report["objects"][0]].data, "LOD0").model
    np.testing.assert_array_equal(first.offsets, stored.offsets)
    np.testing.assert_array_equal(first.bones, stored.bones)
    np.testing.assert_allclose(first.coordinates, stored.coordinates, rtol=1e-6, atol=1e-7)
    assert report["levels"][1]["triangles"] < report["levels"][0]["triangles"]
