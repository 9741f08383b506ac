"""Bake Normal Maps in real Blender: skinkit's MikkTSpace tangents equal Blender's calc_tangents; the operator bakes
a LOD chain through its atlas and a plane from a bumpy high-resolution copy, wires each map into the level's own
material, and a Cycles render of the level with its map is at most half as far from the full-detail render as the
level without it; failures leave the scene as it was."""
import os

import bpy
import bmesh  # noqa: E402 (after bpy)
import numpy as np
import pytest
from tests.blender.test_skinning import scene_fingerprint, select

from skinkit import normal_maps as nm
from skinkit.blender import lod_chain, unwrap
from skinkit.blender import normal_maps as bridge


def read(collection, attribute, width, dtype=np.float64):
    values = np.empty(len(collection) * width, dtype)
    collection.foreach_get(attribute, values)
    return values


def triangulated(name, build, smooth=True):
    mesh = bpy.data.meshes.new(name)
    editable = bmesh.new()
    editable.loops.layers.uv.new("UVMap")
    build(editable)
    bmesh.ops.triangulate(editable, faces=editable.faces[:])
    editable.to_mesh(mesh)
    editable.free()
    for polygon in mesh.polygons:
        polygon.use_smooth = smooth
    return mesh


SHAPES = {
    "sphere": lambda m: bmesh.ops.create_uvsphere(m, u_segments=24, v_segments=12, radius=1.0, calc_uvs=True),
    "cube": lambda m: bmesh.ops.create_cube(m, size=1.0, calc_uvs=True),
    "cone": lambda m: bmesh.ops.create_cone(m, cap_ends=True, segments=12, radius1=1.0, radius2=0.3, depth=2.0,
                                            calc_uvs=True),
}


@pytest.mark.parametrize("smooth", [True, False])
@pytest.mark.parametrize("shape", list(SHAPES))
def test_tangents_match_blenders_mikktspace(shape, smooth):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = triangulated(shape, SHAPES[shape], smooth)
    mesh.calc_tangents()
    count = len(mesh.polygons)
    triangles = read(mesh.polygons, "vertices", 3, np.int32).reshape(-1, 3)
    surface = nm.BakeSurface.from_arrays(triangles, read(mesh.vertices, "co", 3).reshape(-1, 3),
                                         read(mesh.uv_layers.active.uv, "vector", 2).reshape(count, 3, 2),
                                         read(mesh.corner_normals, "vector", 3).reshape(count, 3, 3))
    ours = nm.mikktspace_tangents(surface)
    np.testing.assert_allclose(ours[..., :3], read(mesh.loops, "tangent", 3).reshape(count, 3, 3), atol=1e-5)
    np.testing.assert_array_equal(ours[..., 3], read(mesh.loops, "bitangent_sign", 1).reshape(count, 3))


def degenerate_sphere(kind, smooth):
    """A triangulated uv sphere with degenerate triangles of one kind: "uv-point" (all three uvs on one point),
    "uv-line" (two uvs equal), "position" (a vertex moved onto its neighbour, uvs kept) or "welded" (moved with its
    uvs too, so the coinciding corners weld)."""
    mesh = bpy.data.meshes.new(kind)
    editable = bmesh.new()
    uv = editable.loops.layers.uv.new("UVMap")
    bmesh.ops.create_uvsphere(editable, u_segments=12, v_segments=8, radius=1.0, calc_uvs=True)
    bmesh.ops.triangulate(editable, faces=editable.faces[:])
    editable.faces.ensure_lookup_table()
    editable.verts.ensure_lookup_table()
    if kind == "uv-point":
        for index in range(5, 40, 7):
            point = editable.faces[index].loops[0][uv].uv.copy()
            for loop in editable.faces[index].loops:
                loop[uv].uv = point
    elif kind == "uv-line":
        for index in range(3, 40, 5):
            loops = editable.faces[index].loops
            loops[1][uv].uv = loops[0][uv].uv.copy()
    else:
        vertex = editable.verts[20]
        other = vertex.link_edges[0].other_vert(vertex)
        vertex.co = other.co.copy()
        if kind == "welded":
            shared = other.link_loops[0][uv].uv.copy()
            for loop in list(vertex.link_loops) + list(other.link_loops):
                loop[uv].uv = shared
    editable.to_mesh(mesh)
    editable.free()
    for polygon in mesh.polygons:
        polygon.use_smooth = smooth
    return mesh


@pytest.mark.parametrize("smooth", [True, False])
@pytest.mark.parametrize("kind", ["uv-point", "uv-line", "position", "welded"])
def test_tangents_match_blenders_mikktspace_on_degenerate_triangles(kind, smooth):
    """MikkTSpace's degenerate rules: with-any triangles join their neighbours' groups (or keep (1, 0, 0), -1),
    triangles with coinciding corners copy a welded neighbour's tangent."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = degenerate_sphere(kind, smooth)
    mesh.calc_tangents()
    count = len(mesh.polygons)
    triangles = read(mesh.polygons, "vertices", 3, np.int32).reshape(-1, 3)
    positions = read(mesh.vertices, "co", 3).reshape(-1, 3)
    uv = read(mesh.uv_layers.active.uv, "vector", 2).reshape(count, 3, 2)
    corners = positions[triangles]
    uv_area = np.cross(uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0])
    coinciding = (corners[:, [0, 0, 1]] == corners[:, [1, 2, 2]]).all(-1).any(-1)
    assert (uv_area == 0).any() if kind.startswith("uv") else coinciding.any()  # the mesh has its degenerates
    surface = nm.BakeSurface.from_arrays(triangles, positions, uv,
                                         read(mesh.corner_normals, "vector", 3).reshape(count, 3, 3))
    ours = nm.mikktspace_tangents(surface)
    np.testing.assert_allclose(ours[..., :3], read(mesh.loops, "tangent", 3).reshape(count, 3, 3), atol=1e-5)
    np.testing.assert_array_equal(ours[..., 3], read(mesh.loops, "bitangent_sign", 1).reshape(count, 3))


def test_tangents_keep_minus_zero_uvs_apart_as_blender_does():
    """Blender's MikkTSpace hashes the bits of a corner's values, so a corner with u = -0 and one with u = +0 at
    the same vertex are two vertices (the reference's float comparison would weld them): on a smooth sphere
    whose seam corners have u = -0 in every other face, ours equal Blender's, and welding the zeros gives others."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = triangulated("sphere", SHAPES["sphere"])
    uv = read(mesh.uv_layers.active.uv, "vector", 2).reshape(-1, 2)
    loop_faces = np.repeat(np.arange(len(mesh.polygons)), 3)
    signed = (uv[:, 0] == 0) & (loop_faces % 2 == 1)
    assert signed.sum() >= 6 and ((uv[:, 0] == 0) & ~signed).sum() >= 6
    uv[signed, 0] = -0.0
    mesh.uv_layers.active.uv.foreach_set("vector", uv.astype(np.float32).reshape(-1))
    mesh.calc_tangents()
    count = len(mesh.polygons)
    triangles = read(mesh.polygons, "vertices", 3, np.int32).reshape(-1, 3)
    positions, normals = read(mesh.vertices, "co", 3).reshape(-1, 3), read(mesh.corner_normals, "vector", 3)
    uv = read(mesh.uv_layers.active.uv, "vector", 2).reshape(count, 3, 2)
    assert np.signbit(uv[..., 0][uv[..., 0] == 0]).sum() == signed.sum()
    blender = read(mesh.loops, "tangent", 3).reshape(count, 3, 3)
    ours = nm.mikktspace_tangents(nm.BakeSurface.from_arrays(triangles, positions, uv, normals.reshape(count, 3, 3)))
    np.testing.assert_allclose(ours[..., :3], blender, atol=1e-5)
    np.testing.assert_array_equal(ours[..., 3], read(mesh.loops, "bitangent_sign", 1).reshape(count, 3))
    welded = nm.mikktspace_tangents(nm.BakeSurface.from_arrays(triangles, positions, uv + 0.0,
                                                               normals.reshape(count, 3, 3)))
    assert np.abs(welded[..., :3] - blender).max() > 1e-3


def grid_object(name, cuts, height=None):
    mesh = triangulated(name, lambda m: bmesh.ops.create_grid(m, x_segments=cuts, y_segments=cuts, size=1.0,
                                                              calc_uvs=True))
    if height is not None:
        positions = read(mesh.vertices, "co", 3).reshape(-1, 3)
        positions[:, 2] = height(positions[:, 0], positions[:, 1])
        mesh.vertices.foreach_set("co", positions.astype(np.float32).reshape(-1))
        mesh.update()
    material = bpy.data.materials.new(f"{name}_material")
    material.use_nodes = True
    mesh.materials.append(material)
    scene_object = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(scene_object)
    return scene_object


def bump(x, y):
    return 0.08 * np.sin(2.5 * np.pi * x) * np.sin(2.5 * np.pi * y)


@pytest.fixture
def plane_pair():
    """A coarse plane (active) and its bumpy high-resolution copy (selected)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    low, high = grid_object("low", 4), grid_object("high", 160, bump)
    for scene_object in (low, high):
        scene_object.select_set(True)
    select(low)
    return low, high


def render(scene, path, visible):
    for scene_object in scene.objects:
        if scene_object.type == "MESH":
            scene_object.hide_render = scene_object not in visible
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    return nm.read_image(path)[..., :3].astype(np.float64) / 255.0


def lit_scene(scene):
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 4
    scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = 64
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_depth = "8"
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    camera.data.type = "ORTHO"
    camera.data.ortho_scale = 1.6
    camera.location = (0.0, 0.0, 3.0)
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.rotation_euler = (0.9, 0.0, 0.6)  # grazing light: the bump's shading shows
    sun.data.energy = 3.0
    for scene_object in (camera, sun):
        scene.collection.objects.link(scene_object)
    scene.camera = camera


def test_ray_cast_bake_renders_closer_to_the_full_detail(plane_pair, addon, tmp_path):
    low, high = plane_pair
    assert bpy.ops.skinkit.bake_normal_maps(source="SELECTED", targets="ACTIVE", resolution=64, margin=4, samples=2,
                                            cage=0.2, directory=str(tmp_path), image_format="PNG16") == {"FINISHED"}
    path = tmp_path / "low_normal.png"
    assert path.is_file() and os.listdir(tmp_path) == ["low_normal.png"]
    tree = low.data.materials[0].node_tree
    image_node, normal_node = tree.nodes[bridge.IMAGE_NODE], tree.nodes[bridge.NORMAL_NODE]
    assert image_node.image.colorspace_settings.name == "Non-Color" and image_node.image.packed_file is not None
    assert normal_node.space == "TANGENT" and normal_node.uv_map == "UVMap"
    assert tree.nodes["Principled BSDF"].inputs["Normal"].links[0].from_node == normal_node
    stored = nm.read_image(str(path))
    assert stored.dtype == np.uint16
    scene = bpy.context.scene
    lit_scene(scene)
    full = render(scene, str(tmp_path / "full.png"), {high})
    with_map = render(scene, str(tmp_path / "with.png"), {low})
    tree.links.remove(tree.nodes["Principled BSDF"].inputs["Normal"].links[0])
    without_map = render(scene, str(tmp_path / "without.png"), {low})
    error_with = np.sqrt(np.mean((with_map - full) ** 2))
    error_without = np.sqrt(np.mean((without_map - full) ** 2))
    assert error_without > 0.02  # the bump shows in the full-detail render
    assert error_with <= 0.5 * error_without


def test_operator_bakes_a_lod_chain_guided_or_through_its_atlas_only(open_sample, addon, tmp_path):
    mesh_object = open_sample("arm")
    unwrap.unwrap_object(mesh_object, metric="rest", straighten=True, make_active=True)
    material = bpy.data.materials.new("skin")
    material.use_nodes = True
    mesh_object.data.materials.append(material)
    lod_chain.build_lod_chain(mesh_object, levels=3)
    level = bpy.data.objects[f"{mesh_object.name}_LOD2"]
    select(level)
    shared = level.data.materials[0]
    assert bpy.ops.skinkit.bake_normal_maps(resolution=64, margin=2, directory=str(tmp_path),
                                            image_format="EXR", pack=False) == {"FINISHED"}
    assert sorted(os.listdir(tmp_path)) == [f"{mesh_object.name}_LOD1_normal.exr", f"{mesh_object.name}_LOD2_normal.exr"]
    materials = {bpy.data.objects[f"{mesh_object.name}_LOD{i}"].data.materials[0] for i in range(3)}
    assert len(materials) == 3 and shared in materials  # LOD1 and LOD2 got their own copies, LOD0 kept its own
    for index in (1, 2):
        tree = bpy.data.objects[f"{mesh_object.name}_LOD{index}"].data.materials[0].node_tree
        image = tree.nodes[bridge.IMAGE_NODE].image
        assert image.packed_file is None and image.filepath.endswith(f"_LOD{index}_normal.exr")
        assert tree.nodes[bridge.NORMAL_NODE].uv_map == level.data.uv_layers.active.name
        stored = nm.read_image(bpy.path.abspath(image.filepath))
        assert stored.dtype == np.float16
        filled = stored[..., 2] > 0.0
        # Normals near the level's own: z (along the level's normal) dominates, and the map is not flat everywhere.
        assert np.median(stored[filled][:, 2]) > 0.95 and np.abs(stored[filled][:, :2] - 0.5).max() > 0.05
    # The atlas-only correspondence: the active level again, the same texels, another map.
    atlas_folder = tmp_path / "atlas"
    atlas_folder.mkdir()
    assert bpy.ops.skinkit.bake_normal_maps(source="LOD0_ATLAS", targets="ACTIVE", resolution=64, margin=2,
                                            directory=str(atlas_folder), image_format="EXR", pack=False) == {"FINISHED"}
    guided = nm.read_image(str(tmp_path / f"{mesh_object.name}_LOD2_normal.exr"))
    atlas = nm.read_image(str(atlas_folder / f"{mesh_object.name}_LOD2_normal.exr"))
    assert np.array_equal(guided[..., 2] > 0, atlas[..., 2] > 0) and not np.array_equal(guided, atlas)


def test_failures_leave_the_scene_as_it_was(plane_pair, addon, tmp_path):
    low, high = plane_pair
    images, materials = len(bpy.data.images), len(bpy.data.materials)
    # The source far away: nothing within the cage.
    high.location.z = 5.0
    bpy.context.view_layer.update()
    with pytest.raises(RuntimeError, match="does not cover 'low'"):
        bpy.ops.skinkit.bake_normal_maps(source="SELECTED", targets="ACTIVE", resolution=32, cage=0.2,
                                         directory=str(tmp_path))
    high.location.z = 0.0
    bpy.context.view_layer.update()
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="not writable"):
        bpy.ops.skinkit.bake_normal_maps(source="SELECTED", targets="ACTIVE", resolution=32, cage=0.2,
                                         directory=str(tmp_path / "missing"))
    with pytest.raises(RuntimeError, match="no LOD chain"):
        bpy.ops.skinkit.bake_normal_maps(source="SELECTED", targets="CHAIN", resolution=32, directory=str(tmp_path))
    assert scene_fingerprint() == before
    assert (len(bpy.data.images), len(bpy.data.materials)) == (images, materials)
    assert os.listdir(tmp_path) == []
    assert low.data.materials[0].node_tree.nodes.get(bridge.IMAGE_NODE) is None
