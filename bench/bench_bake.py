"""Normal-map baking: skinkit's atlas-correspondence, ray-cast and guided bakes against Blender's own Cycles bake
(selected to active, tangent space, same resolution, margin and cage) on the coarsest level of a LOD chain, from its
LOD0.

Per dataset (the arm and the creature samples: unwrapped with a straightened atlas, then a 4-level chain; the horse
from ../shared/data when present: decomposed, unwrapped and simplified to 10% of its triangles) and resolution:
seconds on one thread (the least of REPEATS runs, as wall-clock and as this process's CPU time: on a loaded shared
machine the CPU time is the fair measure, both bakers being one-threaded in this process), mean angular error
(degrees) against the exact source normals at the texel centres (the
same-uv point for the atlas bake, the nearest hit along the level's normal for the ray casts, Cycles' included,
the point it took for the guided bake), over the chart-interior texels (whose 3x3 neighbours all lie in a chart),
and texels inside the charts left unfilled. Then Cycles renders LOD0, the level without its map and with it (image
RMSE to LOD0): with the guided map (a chain's default), whose three renders side by side go to
docs/images/bake_<dataset>.png, and with the atlas map.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

# One BLAS thread, set before numpy loads OpenBLAS: every bake timed here runs on one thread, but OpenBLAS's idle
# threads spin for a while after a numpy call, and the process's CPU time counts them (the atlas bake at 512 read
# twice its wall time, 0.033 s CPU for 0.017 s, when a second core was free for them to spin on).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import bpy  # noqa: E402
import mathutils  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from bench.common import machine_info, machine_line, parallel_speedup, write_outputs  # noqa: E402
from skinkit import normal_maps as nm  # noqa: E402
from skinkit.blender import lod_chain, unwrap  # noqa: E402
from skinkit.blender import normal_maps as bridge  # noqa: E402
from skinkit.blender.scene import find_skinned_mesh, triangle_mesh  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(os.path.dirname(ROOT), "shared", "data")
MARGIN = 8
CAGE_FRACTION = 0.02  # of LOD0's diagonal
CYCLES_SAMPLES = (1, 4, 16)
# At 160 pixels and 64 samples, written as dithered 8-bit PNGs, the renders' own noise (LOD0 against LOD0 with another
# seed) was 0.0057 on the creature, about its whole error with the map (0.0055), and its 2400 covered pixels were
# mostly silhouette: the ratio measured the renders, not the map. 320 pixels, 128 samples, 16 bits, no dither, and
# the noise's variance taken out of the errors (render_comparison).
RENDER_SIZE = 320
RENDER_SAMPLES = 128
# The interior: pixels at least this far inside both silhouettes. Next to a silhouette the two surfaces differ in
# what they cover (a level's outline is not LOD0's), which no normal map can change.
INTERIOR_PIXELS = 3
# A pixel shows the same surface point in two renders when their visible points lie within this many pixel widths:
# elsewhere (outlines, the contours where a limb passes in front of the body, surface the coarse level moved) the
# two renders show different parts of the surface, which no normal map can make alike.
SAME_POINT_PIXELS = 1.0
MODES = ("atlas", "ray", "guided")
REPEATS = 3  # each timing is the least of this many runs (Cycles' 4- and 16-sample bakes: one run)


def sample_chain(name: str, levels: int = 4) -> list:
    """Every level of a `levels`-level chain of the sample (LOD0 first, the coarsest last), with a straightened
    atlas, as Blender objects."""
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "blend_samples", f"{name}.blend"), load_ui=False)
    mesh_object = find_skinned_mesh(bpy.context.scene.objects)
    unwrap.unwrap_object(mesh_object, metric="rest", straighten=True, make_active=True)
    report = lod_chain.build_lod_chain(mesh_object, levels=levels)
    return [bpy.data.objects[level_name] for level_name in report["objects"]]


def horse_chain(shares=(0.1,)) -> list:
    """The horse decomposed (25 bones), unwrapped and simplified to each share of its triangles in turn, as Blender
    meshes (LOD0 first)."""
    from skinkit.decompose import decompose
    from skinkit.lod.chain import build_chain
    from skinkit.metrics import PoseStatistics
    from skinkit.unwrap import unwrap as unwrap_mesh

    sys.path.insert(0, os.path.join(ROOT, "bench"))
    from bench_lod import load_horse_frames

    frames = load_horse_frames(DATA)
    result = decompose(frames.train, frames.triangles, bone_count=25, max_influences=8, rest=frames.train[0])
    atlas = unwrap_mesh(result.rest_positions, frames.triangles, straighten=True)
    statistics = PoseStatistics.from_world_samples(result.skeleton.parents, result.training_poses)
    targets = [int(len(frames.triangles) * share) for share in shares]
    chain = build_chain(frames.triangles, result.rest_positions, result.model, statistics,
                        uv=atlas.uv.reshape(-1, 6), charts=atlas.charts, levels=len(targets) + 1,
                        targets={"triangles": targets})
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return [mesh_from_arrays(f"horse_LOD{i}", result.rest_positions[level.vertices], level.triangles, level.uv)
            for i, level in enumerate(chain.levels)]


def mesh_from_arrays(name, positions, triangles, uv):
    mesh = triangle_mesh(name, positions, triangles)
    mesh.polygons.foreach_set("use_smooth", np.ones(len(triangles), bool))
    mesh.update(calc_edges=True)
    layer = mesh.uv_layers.new(name="UVMap", do_init=False)
    layer.uv.foreach_set("vector", np.asarray(uv, np.float32).reshape(-1))
    scene_object = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(scene_object)
    return scene_object


def own_material(scene_object, name):
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    scene_object.data.materials.clear()
    scene_object.data.materials.append(material)
    return material


def interior(coverage: np.ndarray) -> np.ndarray:
    """Texels whose 3x3 neighbourhood is all covered by charts (filled): away from chart borders."""
    filled = np.pad(coverage == nm.COVERAGE["filled"], 1)
    result = np.ones_like(coverage, bool)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            result &= filled[dy:dy + coverage.shape[0], dx:dx + coverage.shape[1]]
    return result


def cage_of(source) -> float:
    """The cage (and Cycles' cage extrusion): CAGE_FRACTION of the source's bounding-box diagonal."""
    return CAGE_FRACTION * float(np.linalg.norm(np.ptp(np.array([v.co for v in source.data.vertices]), axis=0)))


def cycles_bake(scene, source, target, size: int, cage: float, samples: int,
                threads: int = 1) -> tuple[np.ndarray, float, float]:
    """Cycles' selected-to-active tangent-space normal bake on `threads` threads (0: all): (the image, rows from the
    top, 0-1 encoded, (size, size, 3)), wall seconds, CPU seconds), the least of REPEATS runs at 1 sample."""
    image = bpy.data.images.new(f"cycles_{size}_{samples}", size, size, float_buffer=True, alpha=False)
    image.colorspace_settings.name = "Non-Color"
    image.generated_color = (0.0, 0.0, 0.0, 1.0)
    material = own_material(target, f"cycles_bake_{size}_{samples}")
    node = material.node_tree.nodes.new("ShaderNodeTexImage")
    node.image = image
    material.node_tree.nodes.active = node
    for scene_object in scene.objects:
        scene_object.select_set(scene_object in (source, target))
    bpy.context.view_layer.objects.active = target
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.render.threads_mode = "FIXED" if threads else "AUTO"
    scene.render.threads = max(threads, 1)
    bake = scene.render.bake
    bake.margin, bake.margin_type = MARGIN, "EXTEND"
    seconds = cpu_seconds = np.inf
    for _ in range(REPEATS if samples == 1 else 1):
        started, cpu_started = time.perf_counter(), time.process_time()
        bpy.ops.object.bake(type="NORMAL", use_selected_to_active=True, cage_extrusion=cage,
                            max_ray_distance=2 * cage, margin=MARGIN, normal_space="TANGENT", use_clear=True)
        seconds = min(seconds, time.perf_counter() - started)
        cpu_seconds = min(cpu_seconds, time.process_time() - cpu_started)
    pixels = np.empty(size * size * 4, np.float32)
    image.pixels.foreach_get(pixels)
    bpy.data.images.remove(image)
    return pixels.reshape(size, size, 4)[::-1, :, :3].copy(), seconds, cpu_seconds


def skinkit_bakes(lod0, level, size: int, cage: float) -> dict:
    depsgraph = bpy.context.evaluated_depsgraph_get()
    target, uv_name = bridge.read_surface(level, depsgraph)
    source, _ = bridge.read_surface(lod0, depsgraph, uv_name, name="source")
    rows = {}
    for mode in MODES:
        for threads in (1, 0):
            seconds = cpu_seconds = np.inf
            for _ in range(REPEATS):
                # Timed as Cycles is: the map only (diagnostics off: no exact normals and frames, which Cycles
                # does not make either); the tangents are included.
                started, cpu_started = time.perf_counter(), time.process_time()
                timed = nm.bake_normals(target, source, size=size, mode=mode, supersample=1, margin=MARGIN,
                                        cage=cage, thread_count=threads, diagnostics=False)
                seconds = min(seconds, time.perf_counter() - started)
                cpu_seconds = min(cpu_seconds, time.process_time() - cpu_started)
            # The errors from one more run with the exact normals: the same image, bit for bit.
            result = nm.bake_normals(target, source, size=size, mode=mode, supersample=1, margin=MARGIN, cage=cage,
                                     thread_count=threads)
            assert np.array_equal(result.image, timed.image), "diagnostics changed the bake"
            rows[(mode, threads)] = (result, seconds, cpu_seconds)
    return rows


def errors(result: nm.NormalMap, image: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    return nm.angular_error(image, result.frames, result.exact, mask)


def measure(name: str, lod0, level, sizes) -> dict:
    scene = bpy.context.scene
    cage = cage_of(lod0)
    rows = []
    maps = {}
    for size in sizes:
        ours = skinkit_bakes(lod0, level, size, cage)
        ray = ours[("ray", 1)][0]
        mask = np.logical_and.reduce([interior(ours[(mode, 1)][0].coverage) for mode in MODES])
        for (mode, threads), (result, seconds, cpu_seconds) in ours.items():
            mean, largest = errors(result, result.image, mask)
            rows.append({"dataset": name, "size": size, "baker": f"skinkit {mode}", "threads": threads or "all",
                         "seconds": seconds, "cpu_seconds": cpu_seconds, "mean_error": mean, "max_error": largest,
                         "unfilled_in_charts": int(result.missed)})
        maps[size] = {mode: ours[(mode, 1)][0] for mode in ("guided", "atlas")}
        for samples, threads in [(samples, 1) for samples in CYCLES_SAMPLES] + [(1, 0)]:
            image, seconds, cpu_seconds = cycles_bake(scene, lod0, level, size, cage, samples, threads)
            mean, largest = errors(ray, image, mask)
            covered = ray.coverage != nm.COVERAGE["empty"]
            unfilled = int((covered & (np.abs(image).sum(-1) == 0)).sum())
            rows.append({"dataset": name, "size": size, "baker": f"Cycles {samples} sample" + "s" * (samples > 1),
                         "threads": threads or "all", "seconds": seconds, "cpu_seconds": cpu_seconds,
                         "mean_error": mean, "max_error": largest, "unfilled_in_charts": unfilled})
    return {"rows": rows, "cage": cage, "triangles": [len(lod0.data.polygons), len(level.data.polygons)],
            "maps": maps[max(sizes)]}


# ---- renders -----------------------------------------------------------------------------------------------------

def render_setup(scene, lod0):
    # matrix_world is only current after the view layer's update: right after a chain is built the camera would
    # frame a stale transform (the creature's bake_render_experiments renders were framed so until session 16).
    bpy.context.view_layer.update()
    corners = np.array([lod0.matrix_world @ v.co for v in lod0.data.vertices])
    low, high = corners.min(0), corners.max(0)
    centre, extent = (low + high) / 2, high - low
    axis = int(np.argmin(extent))  # look along the thinnest axis: the widest view
    camera = bpy.data.objects.new("bench_camera", bpy.data.cameras.new("bench_camera"))
    camera.data.type = "ORTHO"
    camera.data.ortho_scale = float(np.max(np.delete(extent, axis))) * 1.1
    camera.data.clip_end = float(10 * np.max(extent))
    location = centre.copy()
    location[axis] += 3 * float(np.max(extent))
    camera.location = location
    direction = camera.location - mathutils.Vector(centre)
    camera.rotation_euler = direction.to_track_quat("Z", "Y").to_euler()
    sun = bpy.data.objects.new("bench_sun", bpy.data.lights.new("bench_sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (direction.to_track_quat("Z", "Y") @ mathutils.Euler((0.7, 0.4, 0.0)).to_quaternion()).to_euler()
    for scene_object in (camera, sun):
        scene.collection.objects.link(scene_object)
    scene.camera = camera
    scene.render.engine = "CYCLES"
    scene.cycles.samples = RENDER_SAMPLES
    scene.cycles.use_denoising = False
    scene.render.threads_mode = "AUTO"
    scene.render.resolution_x = scene.render.resolution_y = RENDER_SIZE
    scene.render.film_transparent = True  # alpha: where each render has the surface
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.image_settings.color_depth = "16"
    scene.render.dither_intensity = 0.0  # dither is noise of its own, different in every render


def render(scene, path, visible) -> np.ndarray:
    for scene_object in scene.objects:
        if scene_object.type == "MESH":
            scene_object.hide_render = scene_object != visible
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    pixels = nm.read_image(path)
    return pixels.astype(np.float64) / float(np.iinfo(pixels.dtype).max)


def visible_points(scene, scene_object, path) -> np.ndarray:
    """Per pixel, the world-space point of `scene_object` that the camera sees at the pixel's centre ((H, W, 3),
    rows from the top; NaN where the object is not)."""
    return emitted_per_pixel(scene, scene_object, path,
                             lambda material: material.node_tree.nodes.new("ShaderNodeNewGeometry").outputs["Position"])


def emitted_per_pixel(scene, scene_object, path, emitted) -> np.ndarray:
    """Per pixel, the value of a shader socket at the point of `scene_object` the camera sees at the pixel's centre
    ((H, W, 3), rows from the top; NaN where the object is not): the socket that `emitted(material)` makes in a
    new material's empty node tree, as an emission colour, one sample, a float EXR. The scene's render settings and
    the object's materials are put back."""
    material = bpy.data.materials.new("bench_emitted")
    material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    nodes.clear()
    emission = nodes.new("ShaderNodeEmission")
    links.new(emitted(material), emission.inputs["Color"])
    links.new(emission.outputs["Emission"], nodes.new("ShaderNodeOutputMaterial").inputs["Surface"])
    kept_materials = list(scene_object.data.materials)
    settings = scene.render.image_settings
    kept = (scene.cycles.samples, scene.cycles.filter_width, settings.file_format, settings.color_depth,
            scene.view_settings.view_transform)
    scene_object.data.materials.clear()
    scene_object.data.materials.append(material)
    scene.cycles.samples, scene.cycles.filter_width = 1, 0.01  # the pixel's centre, not a filtered mix
    settings.file_format, settings.color_depth = "OPEN_EXR", "32"
    scene.view_settings.view_transform = "Raw"
    try:
        for other in scene.objects:
            if other.type == "MESH":
                other.hide_render = other != scene_object
        scene.render.filepath = path
        bpy.ops.render.render(write_still=True)
    finally:
        (scene.cycles.samples, scene.cycles.filter_width, settings.file_format, settings.color_depth,
         scene.view_settings.view_transform) = kept
        scene_object.data.materials.clear()
        for kept_material in kept_materials:
            scene_object.data.materials.append(kept_material)
        bpy.data.materials.remove(material)
    pixels = nm.read_image(path).astype(np.float64)
    return np.where(pixels[..., 3:] > 0.99, pixels[..., :3], np.nan)


def same_points(scene, lod0, level, folder: str, name: str) -> np.ndarray:
    """The pixels where LOD0 and the level show the same surface point (within SAME_POINT_PIXELS pixel widths)."""
    width = scene.camera.data.ortho_scale / RENDER_SIZE
    full = visible_points(scene, lod0, os.path.join(folder, f"{name}_points_full.exr"))
    coarse = visible_points(scene, level, os.path.join(folder, f"{name}_points_level.exr"))
    with np.errstate(invalid="ignore"):
        return np.linalg.norm(full - coarse, axis=-1) <= SAME_POINT_PIXELS * width


def on_white(rgba: np.ndarray) -> np.ndarray:
    return rgba[..., :3] * rgba[..., 3:] + (1.0 - rgba[..., 3:])


def eroded(mask: np.ndarray, pixels: int) -> np.ndarray:
    """The pixels of the mask whose square of side 2 pixels + 1 around them lies inside it."""
    height, width = mask.shape
    padded = np.pad(mask, pixels)
    result = np.ones_like(mask)
    for dy in range(2 * pixels + 1):
        for dx in range(2 * pixels + 1):
            result &= padded[dy:dy + height, dx:dx + width]
    return result


def render_comparison(name: str, lod0, level, normal_maps: dict, folder: str, picture: str) -> dict:
    """LOD0, the level without a map and with each of `normal_maps` (label -> NormalMap; the first is the picture's
    and its errors' keys carry no label, the others' are prefixed with theirs) rendered alike."""
    scene = bpy.context.scene
    render_setup(scene, lod0)
    own_material(lod0, "bench_lod0")
    # Every render has its own seed, so that the noise of any two is independent: then the expected squared
    # difference of two renders is the squared error between what they show plus twice the per-render noise
    # variance, which LOD0 against LOD0 measures, and subtracting it leaves the error itself.
    scene.cycles.seed = 0
    full = render(scene, os.path.join(folder, f"{name}_full.png"), lod0)
    scene.cycles.seed = 1
    full_again = render(scene, os.path.join(folder, f"{name}_full_again.png"), lod0)
    own_material(level, "bench_level")
    scene.cycles.seed = 2
    without = render(scene, os.path.join(folder, f"{name}_without.png"), level)
    masks = render_masks(full, without, same_points(scene, lod0, level, folder, name))
    row = {"shaded_pixels": int(masks["shading"].sum()), "interior_pixels": int(masks["interior"].sum()),
           "same_point_pixels": int(masks["same_point"].sum())}
    for index, (label, normal_map) in enumerate(normal_maps.items()):
        material = own_material(level, f"bench_level_{label}")
        path = nm.write_image(os.path.join(folder, f"{name}_{label}_map.png"), normal_map.image, "png16")
        bridge.add_normal_map_nodes(material, bridge.load_image(path, pack=True), level.data.uv_layers.active.name)
        scene.cycles.seed = 3 + index
        with_map = render(scene, os.path.join(folder, f"{name}_{label}_with.png"), level)
        prefix = f"{label}_" if index else ""
        if not index:
            gap = np.ones((RENDER_SIZE, 4, 3))
            nm.write_image(picture, np.concatenate([on_white(full), gap, on_white(without), gap, on_white(with_map)],
                                                   axis=1), "png8")
            row["picture"] = os.path.relpath(picture, ROOT)
        by_mask = render_errors(full, full_again, without, with_map,
                                {"image": np.ones_like(masks["shading"]), **masks})
        for key, error in by_mask.items():
            row.update({f"{prefix}{key}_rmse_without": error["without"], f"{prefix}{key}_rmse_with": error["with"],
                        f"{prefix}{key}_ratio": error["ratio"], f"{prefix}{key}_noise_rmse": error["noise"],
                        f"{prefix}{key}_denoised_ratio": error["denoised_ratio"]})
    scene.cycles.seed = 0
    return row


def render_masks(full, without, same) -> dict:
    """The pixels both surfaces cover (the shading error), those at least INTERIOR_PIXELS inside both silhouettes,
    and those of the interior where both show the same surface point (`same`, from same_points)."""
    both = (full[..., 3] > 0.99) & (without[..., 3] > 0.99)
    inside = eroded(both, INTERIOR_PIXELS)
    return {"shading": both, "interior": inside, "same_point": inside & same}


def render_errors(full, again, without, with_map, masks: dict) -> dict:
    """Per mask: its pixels, the RMSE to LOD0 (`full`) without and with the map, the renders' noise (LOD0 against
    LOD0 with another seed, `again`), their ratio, and the ratio with the noise's variance taken out."""
    by_mask = {}
    for key, mask in masks.items():
        def rmse(image):
            return float(np.sqrt(np.mean((on_white(image) - on_white(full))[mask] ** 2)))

        def denoised(error):
            return float(np.sqrt(max(error ** 2 - noise ** 2, 0.0)))

        error_without, error_with, noise = rmse(without), rmse(with_map), rmse(again)
        by_mask[key] = {"pixels": int(mask.sum()), "without": error_without, "with": error_with, "noise": noise,
                        "ratio": error_with / error_without,
                        "denoised_ratio": denoised(error_with) / max(denoised(error_without), 1e-12)}
    return by_mask


# ---- report ------------------------------------------------------------------------------------------------------

def markdown(results: dict) -> str:
    info = results["machine"]
    lines = ["# Normal-map baking: skinkit against Cycles' bake (selected to active)", "",
             f"{machine_line(info)}; Blender {info['bpy']}; load average {info['load_before']:.1f} before the run, "
             f"{info['load_after']:.1f} after). Command: `{info['command']}`.", "",
             f"Times are the least of {REPEATS} runs (Cycles at 4 and 16 samples: one run), wall-clock and CPU time "
             "of this process (both bakers one-threaded in it; the speed-ups are on CPU time, the fair measure on "
             "a shared, loaded machine), and wall-clock with all threads each (threads 'all'). Both make the map "
             "only: skinkit's timed runs keep no diagnostics (its errors come from one more run with the exact "
             "normals, checked to give the same image); skinkit's time includes its MikkTSpace tangents, Cycles' "
             "its scene synchronisation.", "",
             f"Margin {MARGIN} texels, cage {CAGE_FRACTION:.0%} of LOD0's diagonal, skinkit 1 sample per texel. Errors "
             "in degrees against the exact source normals at the texel centres, over chart-interior texels.", ""]
    for name, data in results["datasets"].items():
        if "skipped" in data:
            lines += [f"## {name}", "", f"Skipped: {data['skipped']}", ""]
            continue
        lines += [f"## {name} (LOD0 {data['triangles'][0]} triangles, level {data['triangles'][1]})", "",
                  "| size | baker | threads | seconds | CPU seconds | mean error | max error | unfilled in charts |",
                  "|---:|---|---:|---:|---:|---:|---:|---:|"]
        for row in data["rows"]:
            lines.append(f"| {row['size']} | {row['baker']} | {row['threads']} | {row['seconds']:.3f} | "
                         f"{row['cpu_seconds']:.3f} | {row['mean_error']:.3f} | {row['max_error']:.2f} | "
                         f"{row['unfilled_in_charts']} |")
        for size, speed in data["speedups"].items():
            lines.append(f"\nAt {size}: atlas bake {speed['atlas']:.1f}x, ray-cast bake {speed['ray']:.1f}x, guided "
                         f"bake {speed['guided']:.1f}x faster than Cycles at 1 sample in CPU time (wall-clock "
                         f"{speed['atlas_wall']:.1f}x, {speed['ray_wall']:.1f}x and {speed['guided_wall']:.1f}x; one "
                         f"thread each); all threads each, wall-clock: atlas {speed['atlas_all_wall']:.1f}x, ray cast "
                         f"{speed['ray_all_wall']:.1f}x, guided {speed['guided_all_wall']:.1f}x.")
        render_row = data["render"]
        lines += ["", f"Render RMSE to LOD0 over the whole image: without the map {render_row['image_rmse_without']:.4f}, "
                      f"with it {render_row['image_rmse_with']:.4f} (ratio {render_row['image_ratio']:.2f}); over the "
                      f"{render_row['shaded_pixels']} pixels both cover (shading only): "
                      f"{render_row['shading_rmse_without']:.4f} vs {render_row['shading_rmse_with']:.4f} (ratio "
                      f"{render_row['shading_ratio']:.2f}); the renders' own noise there ({RENDER_SAMPLES} samples; "
                      f"LOD0 against LOD0 with another seed) is {render_row['shading_noise_rmse']:.4f}. Over the "
                      f"{render_row['interior_pixels']} of them at least {INTERIOR_PIXELS} pixels inside both "
                      f"silhouettes: {render_row['interior_rmse_without']:.4f} vs "
                      f"{render_row['interior_rmse_with']:.4f} (ratio {render_row['interior_ratio']:.2f}; noise "
                      f"{render_row['interior_noise_rmse']:.4f}). With the renders' noise variance taken out (each "
                      f"render has its own seed; sqrt(RMSE^2 - noise^2)) the ratio is "
                      f"{render_row['shading_denoised_ratio']:.2f} over the pixels both cover and "
                      f"{render_row['interior_denoised_ratio']:.2f} over the interior. Over the "
                      f"{render_row['same_point_pixels']} interior pixels where the level shows the same surface point "
                      f"as LOD0 (within {SAME_POINT_PIXELS:g} pixel width): "
                      f"{render_row['same_point_rmse_without']:.4f} vs {render_row['same_point_rmse_with']:.4f}, ratio "
                      f"{render_row['same_point_ratio']:.2f}, "
                      f"{render_row['same_point_denoised_ratio']:.2f} with the noise taken out. Picture "
                      f"`{render_row['picture']}` (LOD0 | level without | level with). All with the guided map; "
                      f"with the atlas map instead, the interior's ratio with the noise taken out is "
                      f"{render_row['atlas_interior_denoised_ratio']:.2f} (same point: "
                      f"{render_row['atlas_same_point_denoised_ratio']:.2f}).", ""]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--datasets", default="arm,creature,horse")
    parser.add_argument("--sizes", default="512,1024")
    parser.add_argument("--markdown")
    parser.add_argument("--json")
    parser.add_argument("--scratch", default=os.path.join(ROOT, "build", "bench_bake"))
    arguments = parser.parse_args(argv)
    os.makedirs(arguments.scratch, exist_ok=True)
    info = machine_info()
    info["parallel_speedup_before"] = parallel_speedup()
    info["load_before"] = os.getloadavg()[0]
    sizes = [int(s) for s in arguments.sizes.split(",")]
    results = {"machine": info, "datasets": {}}
    for name in arguments.datasets.split(","):
        if name == "horse" and not os.path.isdir(os.path.join(DATA, "horse")):
            results["datasets"][name] = {"skipped": f"no horse data at {DATA}/horse (see its README)"}
            print(f"{name}: skipped, no data at {DATA}/horse", file=sys.stderr)
            continue
        chain = horse_chain() if name == "horse" else sample_chain(name)
        lod0, level = chain[0], chain[-1]
        # The horse's decomposition leaves OpenBLAS's threads spinning for a moment, and process CPU time counts
        # them: its first timed bakes read 40% slow until they are let go idle.
        time.sleep(1.0)
        data = measure(name, lod0, level, sizes)
        data["speedups"] = {}
        for size in sizes:
            at = {row["baker"]: row for row in data["rows"] if row["size"] == size and row["threads"] in (1,)}
            every = {row["baker"]: row for row in data["rows"] if row["size"] == size and row["threads"] == "all"}
            cycles, cycles_cpu = at["Cycles 1 sample"]["seconds"], at["Cycles 1 sample"]["cpu_seconds"]
            cycles_all = every["Cycles 1 sample"]["seconds"]
            data["speedups"][size] = {}
            for mode in MODES:
                baker = f"skinkit {mode}"
                data["speedups"][size].update({mode: cycles_cpu / at[baker]["cpu_seconds"],
                                               f"{mode}_wall": cycles / at[baker]["seconds"],
                                               f"{mode}_all_wall": cycles_all / every[baker]["seconds"]})
        picture = os.path.join(ROOT, "docs", "images", f"bake_{name}.png")
        data["render"] = render_comparison(name, lod0, level, data.pop("maps"), arguments.scratch, picture)
        results["datasets"][name] = data
        print(name, data["speedups"], data["render"], file=sys.stderr)
    info["parallel_speedup_after"] = parallel_speedup()
    info["load_after"] = os.getloadavg()[0]
    write_outputs(results, arguments.json, arguments.markdown, markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
