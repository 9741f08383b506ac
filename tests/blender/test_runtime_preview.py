"""LOD Preview in real Blender: a chain from Build LOD Chain drawn by the runtime at a real level (LOD0 exact at
l = 0, each level exact at its integer, continuous across them), the level chosen from the scene camera, the panel's
numbers, and the scene exactly as before once the preview is off."""
import bpy
import numpy as np
import pytest
from tests.blender.test_skinning import scene_fingerprint, select

from skinkit.blender import lod_chain, preview
from skinkit.blender.skinning import model_positions


def preview_positions(level_object):
    key = level_object.data.shape_keys.key_blocks[preview.KEY_NAME]
    values = np.empty(3 * len(key.data), np.float32)
    key.data.foreach_get("co", values)
    return values.reshape(-1, 3)


@pytest.fixture
def chain(open_sample, addon):
    mesh_object = open_sample("arm")
    select(mesh_object)
    assert bpy.ops.skinkit.build_lod_chain(levels=3) == {"FINISHED"}
    levels = [bpy.data.objects[f"{mesh_object.name}_LOD{i}"] for i in range(3)]
    select(levels[0])
    bpy.context.scene.frame_set(bpy.context.scene.frame_start + 5)  # a bent pose
    return levels


def test_levels_are_exact_at_integers_and_continuous_between(chain):
    before = scene_fingerprint()
    assert bpy.ops.skinkit.toggle_lod_preview(level=0.0) == {"FINISHED"}
    depsgraph = bpy.context.evaluated_depsgraph_get()
    np.testing.assert_allclose(preview_positions(chain[0]), model_positions(chain[0], depsgraph), atol=1e-5)
    assert not chain[0].hide_get() and chain[1].hide_get() and chain[2].hide_get()
    assert not chain[0].modifiers[0].show_viewport
    to_coarser = np.empty(len(chain[0].data.vertices), np.int32)
    chain[0].data.attributes[lod_chain.TO_COARSER_ATTRIBUTE].data.foreach_get("value", to_coarser)
    preview.lod_set(chain[0], depsgraph, level=1.0 - 1e-6)
    almost = preview_positions(chain[0]).copy()
    preview.lod_set(chain[0], depsgraph, level=1.0)
    assert chain[0].hide_get() and not chain[1].hide_get()
    at_one = preview_positions(chain[1])
    np.testing.assert_allclose(at_one, model_positions(chain[1], depsgraph), atol=1e-5)
    np.testing.assert_allclose(almost, at_one[to_coarser], atol=1e-4)  # no pop
    settings = preview.lod_settings(chain[0])
    assert settings["drawn_level"] == 1.0 and settings["drawn_influences"] > 0
    assert bpy.ops.skinkit.toggle_lod_preview() == {"FINISHED"}  # off again
    assert scene_fingerprint() == before
    assert not any(o.hide_get() for o in chain)


def test_level_from_the_camera_grows_with_distance(chain):
    camera = bpy.data.objects.new("preview_camera", bpy.data.cameras.new("preview_camera"))
    bpy.context.scene.collection.objects.link(camera)
    bpy.context.scene.camera = camera
    centre = np.array(chain[0].matrix_world.translation)
    levels = []
    for distance in (0.5, 200.0, 1e5):
        camera.location = (centre[0], centre[1] - distance, centre[2])
        camera.rotation_euler = (np.pi / 2, 0.0, 0.0)  # looking along +y, at the chain
        bpy.context.view_layer.update()
        if not preview.lod_is_enabled(chain[0]):
            assert bpy.ops.skinkit.toggle_lod_preview(from_camera=True, pixel_tolerance=1.0) == {"FINISHED"}
        else:
            preview.lod_refresh(chain[0], bpy.context.evaluated_depsgraph_get())
        levels.append(preview.lod_settings(chain[0])["drawn_level"])
    assert levels[0] == 0.0 and levels == sorted(levels) and levels[-1] == 2.0
    preview.lod_disable(chain[0])


def test_an_object_outside_a_chain_is_refused(open_sample, addon):
    mesh_object = open_sample("arm")
    select(mesh_object)
    assert not bpy.ops.skinkit.toggle_lod_preview.poll()
    with pytest.raises(Exception, match="not a level of a LOD chain"):
        preview.lod_enable(mesh_object, bpy.context.evaluated_depsgraph_get())


def test_the_fixed_layout_draws_what_the_csr_pack_draws(chain, monkeypatch):
    """Fixed-K Layout on (the default) skins from the chain's fixed-K pack: the same positions as the CSR pack at
    every level, the panel's layout line saying so; a chain whose vertices do not fit the slots falls back to CSR
    and says why."""
    from addon.runtime import layout_line
    from skinkit import runtime

    depsgraph = bpy.context.evaluated_depsgraph_get()
    drawn = {}
    for fixed_layout in (True, False):
        assert bpy.ops.skinkit.toggle_lod_preview(level=0.5, fixed_layout=fixed_layout) == {"FINISHED"}
        drawn[fixed_layout] = preview_positions(chain[0]).copy(), preview.lod_settings(chain[0])
        preview.lod_set(chain[0], depsgraph, level=1.0)
        drawn[fixed_layout] += (preview_positions(chain[1]).copy(),)
        assert bpy.ops.skinkit.toggle_lod_preview() == {"FINISHED"}  # off
    (fixed_half, fixed_settings, fixed_one), (csr_half, csr_settings, csr_one) = drawn[True], drawn[False]
    assert fixed_settings["drawn_layout"] == "fixed" and csr_settings["drawn_layout"] == "csr"
    assert fixed_settings["slots_per_vertex"] >= 2 and fixed_settings["slots_per_vertex"] % 2 == 0
    assert layout_line(fixed_settings).startswith("Layout: fixed-K") and layout_line(csr_settings) == "Layout: CSR"
    np.testing.assert_allclose(fixed_half, csr_half, atol=1e-5)
    np.testing.assert_allclose(fixed_one, csr_one, atol=1e-5)

    monkeypatch.setattr(runtime, "MAX_FIXED_SLOTS", 1)  # no chain fits one slot
    assert bpy.ops.skinkit.toggle_lod_preview(level=0.5, fixed_layout=True) == {"FINISHED"}
    settings = preview.lod_settings(chain[0])
    assert settings["drawn_layout"] == "csr" and "the fixed layout holds at most 1" in settings["fixed_layout_problem"]
    assert layout_line(settings).startswith("Layout: CSR (a vertex has")
    np.testing.assert_allclose(preview_positions(chain[0]), csr_half, atol=1e-5)
    preview.lod_disable(chain[0])
