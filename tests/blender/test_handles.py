"""Handle rigs in real (headless) Blender: Learn Handle Rig from shape keys, Empties driving the mesh live, the
toggle, baking, the rig stored in the .blend, and refused input leaving the scene as it was."""
import bpy
import numpy as np
import pytest
from tests.sequences import rigid_chain_sequence

from skinkit import meshcache
from skinkit.blender import compat
from skinkit.blender import handles as bridge
from skinkit.blender.scene import empty_scene, new_mesh_object

HANDLES = [5, 60, 125]


@pytest.fixture
def sequence_object(addon):
    """A tube with 24 example poses as shape keys (values 0), the vertex group 'handles' and the mesh active."""
    frames, triangles, _, _ = rigid_chain_sequence(3, 24, seed=8)
    empty_scene()
    mesh_object = new_mesh_object("tube", frames[0], triangles)
    compat.add_shape_key(mesh_object, "Basis")
    for number, frame in enumerate(frames[1:], start=1):
        key = compat.add_shape_key(mesh_object, f"pose_{number:02d}")
        key.data.foreach_set("co", frame.astype(np.float32).ravel())
    mesh_object.vertex_groups.new(name="handles").add(HANDLES, 1.0, "REPLACE")
    bpy.context.view_layer.objects.active = mesh_object
    mesh_object.select_set(True)
    return mesh_object, frames


def evaluated(mesh_object) -> np.ndarray:
    depsgraph = bpy.context.evaluated_depsgraph_get()
    mesh = mesh_object.evaluated_get(depsgraph).to_mesh()
    positions = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", positions)
    mesh_object.evaluated_get(depsgraph).to_mesh_clear()
    return positions.reshape(-1, 3).astype(np.float64)


def test_learn_then_drive_the_mesh_with_the_empties(sequence_object, tmp_path):
    mesh_object, frames = sequence_object
    assert bpy.ops.skinkit.learn_handle_rig("EXEC_DEFAULT", True, bones=3, kernel="LINEAR") == {"FINISHED"}
    collection = bpy.data.collections["tube_handles"]
    empties = sorted(collection.objects, key=lambda o: o.name)
    assert [o.type for o in empties] == ["EMPTY"] * 3
    np.testing.assert_allclose([e.location for e in empties], frames[0][HANDLES], atol=1e-6)
    assert bridge.is_live(mesh_object)
    # Move the empties to a held-out-like pose: the mesh follows (through the depsgraph handler).
    target = frames[17]
    for empty, vertex in zip(empties, HANDLES):
        empty.location = target[vertex]
    bpy.context.view_layer.update()
    shown = evaluated(mesh_object)
    model = bridge.stored_model(mesh_object)
    np.testing.assert_allclose(shown, model.predict(target[HANDLES]), atol=1e-5)
    extent = np.ptp(frames[0], axis=0).max()
    assert np.sqrt(((shown - target) ** 2).sum(-1).mean()) / extent < 0.05
    assert np.abs(shown - frames[0]).max() > 0.1 * extent  # it moved
    # Off and on again.
    assert bpy.ops.skinkit.toggle_handle_rig(enable=False) == {"FINISHED"}
    assert not bridge.is_live(mesh_object)
    np.testing.assert_allclose(evaluated(mesh_object), frames[0], atol=1e-6)
    assert bpy.ops.skinkit.toggle_handle_rig(enable=True) == {"FINISHED"}
    np.testing.assert_allclose(evaluated(mesh_object), shown, atol=1e-5)
    # The rig survives saving and reopening the .blend.
    path = str(tmp_path / "rig.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    reopened = bpy.data.objects["tube"]
    np.testing.assert_array_equal(bridge.stored_model(reopened).predict(target[HANDLES]),
                                  model.predict(target[HANDLES]))


def test_bake_keys_one_shape_per_frame(sequence_object):
    mesh_object, frames = sequence_object
    assert bpy.ops.skinkit.learn_handle_rig("EXEC_DEFAULT", True, bones=3) == {"FINISHED"}
    empty = bpy.data.objects["tube_handle_01"]
    empty.location = frames[5][HANDLES[1]]
    empty.keyframe_insert("location", frame=1)
    empty.location = frames[9][HANDLES[1]]
    empty.keyframe_insert("location", frame=3)
    assert bpy.ops.skinkit.bake_handle_rig(frame_start=1, frame_end=3) == {"FINISHED"}
    keys = mesh_object.data.shape_keys.key_blocks
    baked = [k for k in keys if k.name.startswith("skinkit_handles_")]
    assert [k.name for k in baked] == ["skinkit_handles_0001", "skinkit_handles_0002", "skinkit_handles_0003"]
    first = np.empty(len(frames[0]) * 3, np.float32)
    baked[0].data.foreach_get("co", first)
    last = np.empty_like(first)
    baked[2].data.foreach_get("co", last)
    assert np.abs(first - last).max() > 1e-3  # the keyframed handle moved the bake
    np.testing.assert_allclose(last.reshape(-1, 3), bridge.predicted_frames(mesh_object, [3])[0], atol=1e-6)


def test_bake_to_a_mesh_cache(sequence_object, tmp_path):
    mesh_object, frames = sequence_object
    assert bpy.ops.skinkit.learn_handle_rig("EXEC_DEFAULT", True, bones=3) == {"FINISHED"}
    empty = bpy.data.objects["tube_handle_02"]
    empty.location = frames[4][HANDLES[2]]
    empty.keyframe_insert("location", frame=2)
    empty.location = frames[11][HANDLES[2]]
    empty.keyframe_insert("location", frame=4)
    path = str(tmp_path / "rig.pc2")
    assert bpy.ops.skinkit.bake_handle_rig(frame_start=2, frame_end=4, target="MESH_CACHE", filepath=path) == \
        {"FINISHED"}
    positions, start, _ = meshcache.read_pc2(path)
    assert positions.shape == (3, len(frames[0]), 3) and start == 2
    np.testing.assert_allclose(positions, bridge.predicted_frames(mesh_object, [2, 3, 4]), atol=1e-5)
    assert np.abs(positions[0] - positions[2]).max() > 1e-3
    with pytest.raises(RuntimeError, match="PC2 file"):
        bpy.ops.skinkit.bake_handle_rig(frame_start=2, frame_end=4, target="MESH_CACHE", filepath="")


def test_learn_with_the_hierarchical_clustering_and_bone_counts(sequence_object):
    mesh_object, _ = sequence_object
    assert bpy.ops.skinkit.learn_handle_rig("EXEC_DEFAULT", True, bone_counts="2, 3", clustering="HIERARCHICAL",
                                            kernel="LINEAR") == {"FINISHED"}
    assert bridge.stored_model(mesh_object).bone_count - 1 in (2, 3)
    assert bridge.is_live(mesh_object)


def test_bad_bone_counts_are_refused_and_nothing_changes(sequence_object):
    mesh_object, _ = sequence_object
    before = (sorted(o.name for o in bpy.data.objects), sorted(c.name for c in bpy.data.collections),
              sorted(mesh_object.keys()))
    with pytest.raises(RuntimeError, match="whole numbers"):
        bpy.ops.skinkit.learn_handle_rig(bone_counts="3,many", clustering="HIERARCHICAL")
    assert (sorted(o.name for o in bpy.data.objects), sorted(c.name for c in bpy.data.collections),
            sorted(mesh_object.keys())) == before


def test_missing_handles_group_is_refused_and_nothing_changes(sequence_object):
    mesh_object, _ = sequence_object
    mesh_object.vertex_groups.remove(mesh_object.vertex_groups["handles"])
    before = (sorted(o.name for o in bpy.data.objects), sorted(c.name for c in bpy.data.collections),
              [k.name for k in mesh_object.data.shape_keys.key_blocks], sorted(mesh_object.keys()))
    with pytest.raises(RuntimeError, match="no vertex group 'handles'"):
        bpy.ops.skinkit.learn_handle_rig(bones=3)
    after = (sorted(o.name for o in bpy.data.objects), sorted(c.name for c in bpy.data.collections),
             [k.name for k in mesh_object.data.shape_keys.key_blocks], sorted(mesh_object.keys()))
    assert after == before


def test_toggle_needs_a_rig(sequence_object):
    assert not bpy.ops.skinkit.toggle_handle_rig.poll()
