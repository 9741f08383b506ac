"""`make demo`: convert the bundled samples to animation space, measure them against Blender's own
Armature modifier over their animations, and render the creature posed both ways side by side.

Writes out/demo.png and out/demo.json and prints a table. Runs headless with Blender's bpy module.
"""
import json
import os
import sys
import time

import bpy
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from skinkit.blender import operations, preview  # noqa: E402
from skinkit.blender.rig import find_skinned_mesh  # noqa: E402

OUT = os.path.join(ROOT, "out")
RENDER_FRAME = 14


def open_sample(name):
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "blend_samples", f"{name}.blend"), load_ui=False)
    return find_skinned_mesh(bpy.context.scene.objects)


def measure(name) -> dict:
    mesh_object = open_sample(name)
    converted = operations.convert_object(mesh_object)
    scene = bpy.context.scene
    compared = operations.compare_with_armature(mesh_object, range(scene.frame_start, scene.frame_end + 1))
    return {"sample": name, **{k: converted[k] for k in ("vertices", "bones", "influences_mean", "influences_max")},
            "convert_seconds": converted["seconds"], "frames": compared["frames"],
            "eval_ms_per_frame": compared["frame_ms_median"],
            "max_deviation": compared["max_deviation"]}


def render(path):
    scene = bpy.context.scene
    scene.render.filepath = path
    scene.render.image_settings.file_format = "PNG"
    bpy.ops.render.render(write_still=True)


def render_side_by_side(path) -> None:
    """Left: Blender's Armature modifier. Right: skinkit's animation-space model (live preview)."""
    mesh_object = open_sample("creature")
    operations.convert_object(mesh_object)
    scene = bpy.context.scene
    scene.frame_set(RENDER_FRAME)
    left, right = os.path.join(OUT, "armature.png"), os.path.join(OUT, "animation_space.png")
    render(left)
    preview.enable(mesh_object, bpy.context.evaluated_depsgraph_get())
    preview.refresh(mesh_object, bpy.context.evaluated_depsgraph_get())
    render(right)
    combine_horizontally([left, right], path)


def combine_horizontally(paths, out_path) -> None:
    images = [bpy.data.images.load(p) for p in paths]
    width, height = images[0].size
    pixels = []
    for image in images:
        buffer = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(buffer)
        pixels.append(buffer.reshape(height, width, 4))
    combined = np.concatenate(pixels, axis=1)
    result = bpy.data.images.new("skinkit_demo", width * len(images), height, alpha=True)
    result.pixels.foreach_set(combined.reshape(-1))
    result.filepath_raw = out_path
    result.file_format = "PNG"
    result.save()


def print_table(rows) -> None:
    header = f"{'sample':<10}{'vertices':>9}{'bones':>7}{'infl.':>7}{'frames':>8}{'eval ms/frame':>15}{'max deviation':>16}"
    print(header)
    print("-" * len(header))
    for r in rows:
        print(f"{r['sample']:<10}{r['vertices']:>9}{r['bones']:>7}{r['influences_mean']:>7.2f}{r['frames']:>8}"
              f"{r['eval_ms_per_frame']:>15.3f}{r['max_deviation']:>16.2e}")
    print("eval ms/frame: median time of skinkit's evaluation of one frame (float64, pose read from Blender).")
    print("max deviation: largest distance between skinkit's animation-space evaluation and Blender's "
          "Armature modifier over all frames and vertices, divided by the bounding-box diagonal.")


def main() -> None:
    os.makedirs(OUT, exist_ok=True)
    rows = [measure(name) for name in ("arm", "creature")]
    started = time.perf_counter()
    image = os.path.join(OUT, "demo.png")
    render_side_by_side(image)
    with open(os.path.join(OUT, "demo.json"), "w") as stream:
        json.dump(rows, stream, indent=2)
    print()
    print_table(rows)
    print(f"\nrendered {image} in {time.perf_counter() - started:.1f} s "
          f"(left: Blender's Armature modifier, right: skinkit animation space, frame {RENDER_FRAME})")


if __name__ == "__main__":
    main()
