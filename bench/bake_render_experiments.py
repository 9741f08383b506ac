"""Where the rendered error that a level keeps with its normal map comes from (issue 12's render ratio): the same
renders as bench_bake.py's (Cycles, the same camera, sun, size and samples; every render its own seed, the noise's
variance taken out), in these set-ups on one dataset:

- selfflat: LOD0's own geometry shaded flat, carrying the map baked from LOD0's smooth normals. Only the map and
  its decoding can differ from LOD0, so a tangent-space mismatch shows here and nothing else does.
- atlas: the coarsest level with its atlas-correspondence map (what the benchmark reports).
- ray: the same level with a ray-cast map (the nearest source hit along the level's normal).
- guided: the same level with the guided map (the ray's normal where it agrees with the same uv point's; a chain's
  default, what bench_bake.py's renders show).
- direct: the atlas map with the sun alone (no world light, no bounces, no shadows): what is left is the shading of
  the normals the pixels show, without occlusion.
- cycles: the level with Cycles' own selected-to-active bake (16 samples, the same size, margin and cage), rendered
  the same way: what the renderer's own baker reaches on the same geometry.
- levels: every level of the chain with its own guided map, finest first (the samples' 4-level chain; the horse at
  50%, 25% and 10% of its triangles): how the ratio follows the level's distance from LOD0's surface.
- normals: no lighting at all: per pixel, the shading normal the renderer uses at the point the camera sees (the
  Normal Map node's output for the level with its atlas, ray-cast or guided map, the interpolated normal without;
  one sample at the pixel's centre) against LOD0's, as angles and as the error of a Lambert term max(0, n.l) with
  the benchmark's sun (a sample's own lights are left out of this term): how much of the render's error the map's normals leave, and in how few pixels it lies.

Usage: bench/bake_render_experiments.py creature [--json out.json] [--experiments selfflat,atlas] [--frontal-sun]
    [--terminator GEOMETRY,NORMAL,SHADING]
(--frontal-sun: the sun shines along the camera's view instead of grazing the surface; --terminator: the levels'
Cycles shadow-terminator offsets, Object.shadow_terminator_geometry_offset, _normal_offset and _shading_offset,
which Blender offers against the shadow terminator of low-poly geometry; Blender's defaults are 0.1,0,0)
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from bench import bench_bake as bench  # noqa: E402
from skinkit import normal_maps as nm  # noqa: E402
from skinkit.blender import normal_maps as bridge  # noqa: E402

EXPERIMENTS = ("selfflat", "atlas", "ray", "guided", "direct", "cycles", "levels", "normals")
MAP_SIZE = 1024
CYCLES_MAP_SAMPLES = 16
HORSE_LEVEL_SHARES = (0.5, 0.25, 0.1)  # of the horse's triangles: the last is bench_bake's 10% level
WORST_SHARE = 0.01  # normals: the share of the interior's pixels whose part of the Lambert error is reported
TURNED_DEGREES = 30.0  # normals: LOD0 turned this far from the level at a pixel shows a face the level lacks


def bake(target_object, source_object, mode: str):
    """(skinkit's map image, the UV map's name)."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    target, uv_name = bridge.read_surface(target_object, depsgraph)
    source, _ = bridge.read_surface(source_object, depsgraph, uv_name, name="source")
    result = nm.bake_normals(target, source, size=MAP_SIZE, mode=mode, supersample=1, margin=bench.MARGIN,
                             cage=bench.cage_of(source_object))
    return result.image, uv_name


def cycles_map(scene, target_object, source_object):
    """(Cycles' selected-to-active map image, the UV map's name); the render settings put back after the bake."""
    image, _, _ = bench.cycles_bake(scene, source_object, target_object, MAP_SIZE, bench.cage_of(source_object),
                                    CYCLES_MAP_SAMPLES, threads=0)
    scene.cycles.samples = bench.RENDER_SAMPLES
    return image.astype(np.float32), target_object.data.uv_layers.active.name


def run(scene, folder, name, tag, lod0, level, image, uv_name) -> dict:
    def shot(scene_object, what, seed):
        scene.cycles.seed = seed
        return bench.render(scene, os.path.join(folder, f"{name}_{tag}_{what}.png"), scene_object)

    bench.own_material(level, f"plain_{tag}")
    full, again, without = shot(lod0, "full", 0), shot(lod0, "again", 1), shot(level, "without", 2)
    path = nm.write_image(os.path.join(folder, f"{name}_{tag}_map.png"), image, "png16")
    bridge.add_normal_map_nodes(bench.own_material(level, f"mapped_{tag}"), bridge.load_image(path, pack=True),
                                uv_name)
    with_map = shot(level, "with", 3)
    masks = bench.render_masks(full, without, bench.same_points(scene, lod0, level, folder, f"{name}_{tag}"))
    return bench.render_errors(full, again, without, with_map, masks)


def level_rows(scene, folder, name, chain) -> list[dict]:
    """Each level after LOD0 with its guided map: its triangles and the render errors."""
    rows = []
    for index, level in enumerate(chain[1:], start=1):
        image, uv_name = bake(level, chain[0], "guided")
        row = {"level": index, "triangles": len(level.data.polygons),
               **run(scene, folder, name, f"level{index}", chain[0], level, image, uv_name)}
        print("level", row, file=sys.stderr)
        rows.append(row)
    return rows


def shading_normals(scene, scene_object, path, image=None, uv_name=None) -> np.ndarray:
    """Per pixel, the unit shading normal at the point of `scene_object` the camera sees (NaN off the object): the
    product's Normal Map node set-up (add_normal_map_nodes) decoding `image`, or the interpolated normal."""
    def emitted(material):
        nodes = material.node_tree.nodes
        if image is None:
            normal = nodes.new("ShaderNodeNewGeometry").outputs["Normal"]
        else:
            nodes.new("ShaderNodeBsdfPrincipled")
            bridge.add_normal_map_nodes(material, image, uv_name)
            normal = nodes[bridge.NORMAL_NODE].outputs["Normal"]
        encode = nodes.new("ShaderNodeVectorMath")  # 0.5 n + 0.5: an emission colour is not negative
        encode.operation = "MULTIPLY_ADD"
        material.node_tree.links.new(normal, encode.inputs[0])
        encode.inputs[1].default_value = encode.inputs[2].default_value = (0.5, 0.5, 0.5)
        return encode.outputs["Vector"]

    normals = 2.0 * bench.emitted_per_pixel(scene, scene_object, path, emitted) - 1.0
    return normals / np.linalg.norm(normals, axis=-1, keepdims=True)


def normal_errors(full, without, with_map, sun, masks: dict) -> dict:
    """Per mask: the angle between the level's shading normals and LOD0's without and with the map (mean, 95th
    percentile), the Lambert terms' RMSE ratio, the share of the with-map squared Lambert error in the worst
    WORST_SHARE of the pixels and the ratio over the other pixels (without them in both), and the same for the
    pixels where LOD0's normal is turned over TURNED_DEGREES from the level's own (a face the level lacks)."""
    def angles(normals):
        return np.degrees(np.arccos(np.clip(np.sum(normals * full, axis=-1), -1.0, 1.0)))

    def lambert(normals):
        return np.maximum(normals @ sun, 0.0)

    rows = {}
    for key, mask in masks.items():
        angle_without, angle_with = angles(without)[mask], angles(with_map)[mask]
        squared_without = (lambert(without) - lambert(full))[mask] ** 2
        squared_with = (lambert(with_map) - lambert(full))[mask] ** 2
        worst = np.argsort(squared_with)[::-1][:max(int(WORST_SHARE * mask.sum()), 1)]
        rest = np.ones(squared_with.size, bool)
        rest[worst] = False
        turned = angle_without > TURNED_DEGREES
        rows[key] = {"pixels": int(mask.sum()),
                     "angle_without_mean": float(angle_without.mean()),
                     "angle_without_p95": float(np.percentile(angle_without, 95)),
                     "angle_with_mean": float(angle_with.mean()),
                     "angle_with_p95": float(np.percentile(angle_with, 95)),
                     "lambert_ratio": float(np.sqrt(squared_with.mean() / squared_without.mean())),
                     "worst_share_of_error": float(squared_with[worst].sum() / squared_with.sum()),
                     "lambert_ratio_without_worst": float(np.sqrt(squared_with[rest].mean() /
                                                                  squared_without[rest].mean())),
                     "turned_pixels": int(turned.sum()),
                     "turned_share_of_error": float(squared_with[turned].sum() / squared_with.sum()),
                     "lambert_ratio_without_turned": float(np.sqrt(squared_with[~turned].mean() /
                                                                   squared_without[~turned].mean()))}
    return rows


def normal_rows(scene, folder, name, lod0, level) -> dict:
    """The normals experiment on the level, with its atlas, ray-cast and guided maps."""
    def normals(scene_object, what, image=None, uv_name=None):
        return shading_normals(scene, scene_object, os.path.join(folder, f"{name}_normals_{what}.exr"), image,
                               uv_name)

    full, without = normals(lod0, "full"), normals(level, "without")
    sun = np.array(bpy.data.objects["bench_sun"].matrix_world.to_3x3().col[2])  # towards the sun
    both = np.isfinite(full[..., 0]) & np.isfinite(without[..., 0])
    interior = bench.eroded(both, bench.INTERIOR_PIXELS)
    masks = {"interior": interior, "same_point": interior & bench.same_points(scene, lod0, level, folder, name)}
    rows = {}
    for mode in ("atlas", "ray", "guided"):
        image, uv_name = bake(level, lod0, mode)
        path = nm.write_image(os.path.join(folder, f"{name}_normals_{mode}_map.png"), image, "png16")
        with_map = normals(level, mode, bridge.load_image(path, pack=True), uv_name)
        rows[mode] = normal_errors(full, without, with_map, sun, masks)
        print("normals", mode, rows[mode], file=sys.stderr)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", choices=("arm", "creature", "horse"))
    parser.add_argument("--json")
    parser.add_argument("--experiments", default=",".join(EXPERIMENTS))
    parser.add_argument("--frontal-sun", action="store_true")
    parser.add_argument("--terminator", type=lambda text: [float(x) for x in text.split(",")],
                        help="GEOMETRY,NORMAL,SHADING offsets of every level (Blender's defaults: 0.1,0,0)")
    parser.add_argument("--scratch", default=os.path.join(bench.ROOT, "build", "bake_render_experiments"))
    arguments = parser.parse_args(argv)
    unknown = set(arguments.experiments.split(",")) - set(EXPERIMENTS)
    if unknown:
        parser.error(f"--experiments: {', '.join(sorted(unknown))} not among {', '.join(EXPERIMENTS)}")
    os.makedirs(arguments.scratch, exist_ok=True)
    name = arguments.dataset
    experiments = arguments.experiments.split(",")
    shares = HORSE_LEVEL_SHARES if "levels" in experiments else (0.1,)
    chain = bench.horse_chain(shares) if name == "horse" else bench.sample_chain(name)
    lod0, level = chain[0], chain[-1]
    scene = bpy.context.scene
    bench.render_setup(scene, lod0)
    if arguments.frontal_sun:
        bpy.data.objects["bench_sun"].rotation_euler = scene.camera.rotation_euler.copy()
    bench.own_material(lod0, "full")
    if arguments.terminator:
        for coarse in chain[1:]:
            (coarse.shadow_terminator_geometry_offset, coarse.shadow_terminator_normal_offset,
             coarse.shadow_terminator_shading_offset) = arguments.terminator
    results = {}
    for tag in experiments:
        if tag == "levels":
            results[tag] = level_rows(scene, arguments.scratch, name, chain)
            continue
        if tag == "normals":
            results[tag] = normal_rows(scene, arguments.scratch, name, lod0, level)
            continue
        if tag == "selfflat":
            flat = lod0.copy()
            flat.data = lod0.data.copy()
            flat.name = "flat_copy"
            scene.collection.objects.link(flat)
            flat.data.shade_flat()
            image, uv_name = bake(flat, lod0, "atlas")
            results[tag] = run(scene, arguments.scratch, name, tag, lod0, flat, image, uv_name)
            bpy.data.objects.remove(flat)
            continue
        if tag == "direct":
            world = bpy.data.worlds.new("black")
            world.use_nodes = False
            world.color = (0.0, 0.0, 0.0)
            scene.world = world
            scene.cycles.max_bounces = 0
            bpy.data.objects["bench_sun"].data.use_shadow = False
        image, uv_name = cycles_map(scene, level, lod0) if tag == "cycles" else \
            bake(level, lod0, tag if tag in ("ray", "guided") else "atlas")
        results[tag] = run(scene, arguments.scratch, name, tag, lod0, level, image, uv_name)
        print(tag, results[tag], file=sys.stderr)
    if arguments.json:
        with open(arguments.json, "w") as out:
            json.dump({name: results}, out, indent=1)
    print(json.dumps({name: results}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
