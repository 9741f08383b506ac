"""Limit Influences and Subdivide Model in real headless Blender: against Blender's own Limit Total and Subdivision
Surface modifier (after the Armature modifier, in random poses), new objects only, refusals, undo."""
import bpy
import bmesh  # noqa: E402 (after bpy, which provides it)
import numpy as np
import pytest
from tests.blender.test_skinning import random_pose, scene_fingerprint
from tests.conftest import SAMPLE_NAMES

from skinkit import SkinkitError
from skinkit.blender import lod, skinning, storage
from skinkit.blender.frames import evaluated_positions
from skinkit.blender.rig import bone_names, deform_weights, mesh_positions, pose_matrices, rig_of
from skinkit.lod.influences import limit_total
from skinkit.subdivide import subdivide

TOLERANCE = 1e-5  # of the bounding-box diagonal


def matched(ours: np.ndarray, theirs: np.ndarray, tolerance: float) -> np.ndarray:
    """For each of our points the index of the same point of theirs (within tolerance), by cell hashing; refuses
    points with no partner or two of ours on one of theirs."""
    cell = 4 * tolerance
    keys = np.floor(theirs / cell).astype(np.int64)
    packed = (keys[:, 0] * 1_000_003 + keys[:, 1]) * 1_000_033 + keys[:, 2]
    order = np.argsort(packed)
    sorted_keys = packed[order]
    best = np.full(len(ours), -1)
    best_distance = np.full(len(ours), np.inf)
    base = np.floor(ours / cell).astype(np.int64)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                k = ((base[:, 0] + dx) * 1_000_003 + base[:, 1] + dy) * 1_000_033 + base[:, 2] + dz
                start = np.searchsorted(sorted_keys, k, "left")
                stop = np.searchsorted(sorted_keys, k, "right")
                for offset in range(int((stop - start).max(initial=0))):
                    here = start + offset < stop
                    candidate = order[np.minimum(start + offset, len(order) - 1)]
                    distance = np.where(here, np.linalg.norm(theirs[candidate] - ours, axis=1), np.inf)
                    better = distance < best_distance
                    best[better], best_distance[better] = candidate[better], distance[better]
    assert np.all(best_distance < tolerance), f"{np.sum(best_distance >= tolerance)} points have no partner"
    assert len(np.unique(best)) == len(best)
    return best


def polygons_of(mesh):
    starts = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_start", starts)
    corners = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", corners)
    return np.append(starts, len(mesh.loops)).astype(np.int32), corners


def cut_open(mesh_object):
    """Removes the caps and a stepped patch, so the mesh has boundaries with corners (vertices in one face)."""
    mesh = mesh_object.data
    bm = bmesh.new()
    bm.from_mesh(mesh)
    low = min(v.co.x for v in bm.verts)
    doomed = [f for f in bm.faces if len(f.verts) != 4 or f.calc_center_median().x < low + 0.4 or
              (f.calc_center_median().x < low + 0.8 and f.calc_center_median().y > 0)]
    bmesh.ops.delete(bm, geom=doomed, context="FACES")
    bm.to_mesh(mesh)
    bm.free()
    mesh.update()


def subsurf(mesh_object, levels, boundary, uv_smooth="PRESERVE_CORNERS"):
    modifier = mesh_object.modifiers.new("Subdivision", "SUBSURF")  # after the Armature modifier
    modifier.levels = levels
    modifier.use_limit_surface = False
    modifier.boundary_smooth = boundary
    modifier.uv_smooth = uv_smooth
    return modifier


def evaluated_mesh_data(mesh_object):
    depsgraph = bpy.context.evaluated_depsgraph_get()
    evaluated = mesh_object.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        positions = mesh_positions(mesh)
        offsets, corners = polygons_of(mesh)
        uv = None
        if mesh.uv_layers.active is not None:
            uv = np.empty(len(mesh.loops) * 2, np.float32)
            mesh.uv_layers.active.uv.foreach_get("vector", uv)
            uv = uv.reshape(-1, 2)
        return positions, offsets, corners, uv
    finally:
        evaluated.to_mesh_clear()


def without(fingerprint: dict, new_object) -> dict:
    """The fingerprint as it was before `new_object` (and its mesh) were added."""
    objects = {k: v for k, v in fingerprint["objects"].items() if k != new_object.name}
    meshes = [m for m in fingerprint["meshes"] if m != new_object.data.name]
    return {**fingerprint, "objects": objects, "meshes": meshes}


def diagonal_of(positions):
    return float(np.linalg.norm(positions.max(axis=0) - positions.min(axis=0)))


@pytest.mark.parametrize("name, levels, boundary, cut", [
    ("arm", 1, "all", False), ("arm", 2, "all", False), ("creature", 1, "all", False),
    ("creature", 2, "preserve-corners", False), ("arm", 2, "all", True), ("arm", 2, "preserve-corners", True)])
def test_catmull_clark_matches_blenders_subdivision_surface_after_the_armature(open_sample, name, levels, boundary,
                                                                               cut):
    mesh_object = open_sample(name)
    if cut:
        cut_open(mesh_object)
    job = lod.prepare_subdivide(mesh_object, levels=levels, boundary=boundary)
    solved = job.solve()
    model = solved["result"].model
    subsurf(mesh_object, levels, boundary.upper().replace("-", "_"))
    armature = rig_of(mesh_object).armature_object
    rng = np.random.default_rng(levels)
    permutation = None
    for _ in range(2):
        random_pose(armature, rng)
        blender, offsets, corners, _ = evaluated_mesh_data(mesh_object)
        poses = pose_matrices(armature, bpy.context.evaluated_depsgraph_get(), bone_names(armature), job.source.bind)
        ours = model.evaluate(poses)
        tolerance = TOLERANCE * diagonal_of(blender)
        if permutation is None:
            assert len(ours) == len(blender) and len(solved["result"].polygons) == len(offsets) - 1
            permutation = matched(ours, blender, tolerance)
        assert np.linalg.norm(ours - blender[permutation], axis=1).max() < tolerance
    # The polygons are Blender's, as sets of matched vertices.
    ours_faces = {frozenset(f) for f in permutation[solved["result"].polygons].tolist()}
    theirs = {frozenset(corners[a:b].tolist()) for a, b in zip(offsets[:-1], offsets[1:])}
    assert ours_faces == theirs


def cylindrical_uv(mesh_object):
    """A UV map with seams: u the angle around the arm's axis (a seam where it wraps), v along it; caps planar."""
    mesh = mesh_object.data
    offsets, corners = polygons_of(mesh)
    positions = mesh_positions(mesh)
    centre = positions.mean(axis=0)
    p = positions[corners] - centre
    u = (np.arctan2(p[:, 2], p[:, 1]) / (2 * np.pi)) % 1.0
    v = (p[:, 0] - p[:, 0].min()) / np.ptp(p[:, 0])
    polygon = np.repeat(np.arange(len(offsets) - 1), np.diff(offsets))
    wraps = np.zeros(len(offsets) - 1, bool)
    np.logical_or.at(wraps, polygon, u > 0.75)
    low = wraps[polygon] & (u < 0.25)
    u = np.where(low, u + 1.0, u)
    cap = np.diff(offsets)[polygon] != 4
    u = np.where(cap, 0.5 + 0.3 * p[:, 1], u)
    v = np.where(cap, 0.5 + 0.3 * p[:, 2] + 2.0 * (p[:, 0] > 0), v)
    layer = mesh.uv_layers.new(name="UVMap")
    layer.uv.foreach_set("vector", np.column_stack([u, v]).astype(np.float32).reshape(-1))
    mesh.uv_layers.active = layer


@pytest.mark.parametrize("uv_smooth", ["none", "preserve-corners", "preserve-boundaries", "all"])
def test_uvs_match_blenders_uv_smooth(open_sample, uv_smooth):
    mesh_object = open_sample("arm")
    cut_open(mesh_object)
    cylindrical_uv(mesh_object)
    job = lod.prepare_subdivide(mesh_object, levels=1, uv_smooth=uv_smooth)
    solved = job.solve()
    result = solved["result"]
    subsurf(mesh_object, 1, "ALL", {"none": "NONE", "all": "SMOOTH_ALL"}.get(uv_smooth,
                                                                            uv_smooth.upper().replace("-", "_")))
    armature = rig_of(mesh_object).armature_object
    for bone in armature.pose.bones:
        bone.matrix_basis.identity()
    bpy.context.view_layer.update()
    blender, offsets, corners, uv = evaluated_mesh_data(mesh_object)
    ours = solved["positions"]
    permutation = matched(ours, blender, TOLERANCE * diagonal_of(blender))
    # Each Blender corner (polygon, vertex) -> its uv; compare with ours corner by corner.
    theirs = {}
    for face, (a, b) in enumerate(zip(offsets[:-1], offsets[1:])):
        key = frozenset(corners[a:b].tolist())
        for corner in range(a, b):
            theirs[(key, int(corners[corner]))] = uv[corner]
    ours_uv = result.uv.reshape(len(result.polygons), 4, 2)
    worst = 0.0
    for face, quad in enumerate(permutation[result.polygons]):
        key = frozenset(quad.tolist())
        for corner, vertex in enumerate(quad):
            worst = max(worst, float(np.abs(theirs[(key, int(vertex))] - ours_uv[face, corner]).max()))
    assert worst < 1e-5


def test_limit_total_is_blenders_operator(open_sample):
    mesh_object = open_sample("creature")
    rig = rig_of(mesh_object)
    weights = deform_weights(rig)
    ours = limit_total(weights, 2)
    copy = mesh_object.copy()
    copy.data = mesh_object.data.copy()
    bpy.context.scene.collection.objects.link(copy)
    bpy.context.view_layer.objects.active = copy
    for scene_object in bpy.context.view_layer.objects:
        scene_object.select_set(scene_object == copy)
    assert bpy.ops.object.vertex_group_limit_total(group_select_mode="BONE_DEFORM", limit=2) == {"FINISHED"}
    theirs = deform_weights(rig_of(copy))
    assert np.array_equal(theirs.offsets, ours.offsets) and np.array_equal(theirs.bones, ours.bones)
    assert np.abs(theirs.weights - ours.weights).max() < 1e-6


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_limit_influences_writes_a_new_object_and_beats_limit_total(open_sample, name):
    mesh_object = open_sample(name)
    before = scene_fingerprint()
    limited, report = lod.limit_object(mesh_object, 1 if name == "arm" else 2)
    after = scene_fingerprint()
    assert limited.name == f"{name}_limited" and limited.name not in before
    assert without(after, limited) == before  # the source and the rest untouched
    stored = storage.read_model(limited.data, limited.name)
    assert stored.model.counts().max() <= report["max_influences"]
    assert report["influences_before"]["max"] > report["max_influences"]
    error = report["error"]
    assert error["skinkit"]["rms"] <= error["limit_total"]["rms"], error
    # Its vertex groups deform it under the Armature modifier as the linear-blend error says.
    weights = deform_weights(rig_of(limited))
    assert np.all(np.diff(weights.offsets) <= report["max_influences"])
    assert np.allclose(weights.totals(), 1.0, atol=1e-5)
    assert rig_of(limited).armature_object == rig_of(mesh_object).armature_object
    assert evaluated_positions(limited, bpy.context.evaluated_depsgraph_get()).shape == (report["vertices"], 3)


def test_limit_influences_refuses_a_mesh_without_a_rig_naming_it():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_cube_add()
    cube = bpy.context.active_object
    before = scene_fingerprint()
    with pytest.raises(SkinkitError, match=f"'{cube.name}' has no Armature modifier"):
        lod.prepare_limit(cube, 2)
    with pytest.raises(SkinkitError, match="at least 1"):
        lod.prepare_limit(cube, 0)
    with pytest.raises(SkinkitError, match=f"'{cube.name}' has no Armature modifier"):
        lod.prepare_subdivide(cube)
    assert scene_fingerprint() == before


def test_statistics_are_needed_when_there_is_no_action(open_sample):
    mesh_object = open_sample("arm")
    armature = rig_of(mesh_object).armature_object
    armature.animation_data.action = None
    before = scene_fingerprint()
    with pytest.raises(SkinkitError, match="'arm': armature 'arm_rig' has no pose statistics and no action"):
        lod.prepare_limit(mesh_object, 1)
    assert scene_fingerprint() == before


def test_loop_refuses_quads_and_subdivide_keeps_the_source(open_sample):
    mesh_object = open_sample("arm")
    before = scene_fingerprint()
    with pytest.raises(SkinkitError, match="'arm': has faces that are not triangles"):
        lod.prepare_subdivide(mesh_object, scheme="loop")
    subdivided, report = lod.subdivide_object(mesh_object, levels=1)
    assert subdivided.name == "arm_subdivided" and report["vertices"] == len(subdivided.data.vertices)
    assert without(scene_fingerprint(), subdivided) == before
    # The new object's stored model reproduces Blender's Subdivision Surface of the source after its armature.
    subsurf(mesh_object, 1, "ALL")
    random_pose(rig_of(mesh_object).armature_object, np.random.default_rng(5))
    depsgraph = bpy.context.evaluated_depsgraph_get()
    ours = skinning.model_positions(subdivided, depsgraph)
    theirs = evaluated_positions(mesh_object, depsgraph)
    tolerance = TOLERANCE * diagonal_of(theirs)
    assert np.linalg.norm(ours - theirs[matched(ours, theirs, tolerance)], axis=1).max() < tolerance


def test_operators_are_undoable(open_sample, addon):
    mesh_object = open_sample("creature")
    bpy.context.view_layer.objects.active = mesh_object
    names = set(bpy.data.objects.keys())
    bpy.ops.ed.undo_push(message="before")
    assert bpy.ops.skinkit.limit_influences("EXEC_DEFAULT", True, max_influences=2) == {"FINISHED"}
    assert "creature_limited" in bpy.data.objects
    bpy.ops.ed.undo()
    assert set(bpy.data.objects.keys()) == names
    bpy.context.view_layer.objects.active = bpy.data.objects["creature"]
    assert bpy.ops.skinkit.subdivide_model("EXEC_DEFAULT", True, levels=1) == {"FINISHED"}
    assert "creature_subdivided" in bpy.data.objects
    bpy.ops.ed.undo()
    assert set(bpy.data.objects.keys()) == names


def test_operator_errors_are_reported_and_change_nothing(open_sample, addon):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_cube_add()
    with pytest.raises(RuntimeError, match="poll.*Select a mesh with an Armature modifier"):
        bpy.ops.skinkit.limit_influences(max_influences=2)
    mesh_object = open_sample("arm")
    rig_of(mesh_object).armature_object.animation_data.action = None
    bpy.context.view_layer.objects.active = mesh_object
    before = scene_fingerprint()
    with pytest.raises(RuntimeError, match="'arm': armature 'arm_rig' has no pose statistics and no action"):
        bpy.ops.skinkit.limit_influences(max_influences=1)
    with pytest.raises(RuntimeError, match="'arm': has faces that are not triangles"):
        bpy.ops.skinkit.subdivide_model(scheme="LOOP")
    assert scene_fingerprint() == before
