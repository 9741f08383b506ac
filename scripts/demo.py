"""`make demo`: convert the bundled samples to animation space, measure them against Blender's own
Armature modifier over their animations, and render the creature posed both ways side by side; then fit
the arm to examples linear blend skinning cannot make (Blender's dual-quaternion skinning) and render each
model's per-vertex error as a heat map on one colour scale. Last, forget the creature's rig: skin its animation
(every vertex position on every frame) from a third of the frames alone, and render the result playing a
held-out frame beside the original, coloured by its error. Then unwrap the creature in the animation-space
metric of its walk and write the texture atlas's layout; finally turn it into a game-ready LOD chain on that atlas,
bake each level's normal map from LOD0, and render the levels walking, each played by Blender's Armature modifier
with its map.

Writes out/demo.png, out/fit_heatmap.png, out/decompose.png, out/unwrap_layout.png, out/lod_chain.png, the normal
maps in out/normal_maps/ and out/demo.json, and prints tables. Runs headless with bpy.
"""
import json
import os
import sys
import time

import bpy
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from skinkit import fit, lbs_evaluate  # noqa: E402
from skinkit.blender import attributes, fitting, preview, skinning, storage  # noqa: E402
from skinkit.blender.frames import armature_modifier_only, depsgraphs_at, evaluated_positions, poses_at  # noqa: E402
from skinkit.blender.rig import bind_matrix, deform_weights, rest_positions, rig_of, skeleton_of  # noqa: E402
from skinkit.blender.scene import find_skinned_mesh  # noqa: E402

OUT = os.path.join(ROOT, "out")
RENDER_FRAME = 14


def open_sample(name):
    bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, "blend_samples", f"{name}.blend"), load_ui=False)
    return find_skinned_mesh(bpy.context.scene.objects)


def measure(name) -> dict:
    mesh_object = open_sample(name)
    converted = skinning.convert_object(mesh_object)
    scene = bpy.context.scene
    compared = skinning.compare_with_armature(mesh_object, range(scene.frame_start, scene.frame_end + 1))
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
    skinning.convert_object(mesh_object)
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


def fit_arm_and_render_errors(path) -> dict:
    """Fits the arm, then paints both models' largest per-vertex error (same scale) and renders them."""
    mesh_object = open_sample("arm")
    frames = list(range(1, 41, 3))
    examples = fitting.examples_from_armature(mesh_object, frames)
    report = fitting.fit_object(mesh_object, examples, held_out_frames=[19, 31])
    rig = rig_of(mesh_object)
    bind = bind_matrix(rig, bpy.context.evaluated_depsgraph_get())
    skeleton = skeleton_of(rig, bind)
    poses = poses_at(rig.armature_object, frames, list(skeleton.names), bind)
    rest = rest_positions(mesh_object)
    diagonal = skinning.bounding_box_diagonal(rest)
    stored = storage.read_model(mesh_object.data, mesh_object.name)
    linear = fit.per_vertex_error(lbs_evaluate(skeleton, deform_weights(rig), rest, poses),
                                  examples.positions, diagonal)
    animation = fit.per_vertex_error(stored.model.evaluate(poses), examples.positions, diagonal)
    images = []
    for name, error in (("linear_blend", linear), ("animation_space", animation)):
        attributes.write_point_attribute(mesh_object.data, attributes.HEAT_ATTRIBUTE, "FLOAT_COLOR", "color",
                                         attributes.heat_colours(error, linear.max()).reshape(-1))
        show_colours(mesh_object)
        bpy.context.scene.frame_set(25)
        images.append(os.path.join(OUT, f"{name}_error.png"))
        render(images[-1])
    combine_horizontally(images, path)
    return {"sample": "arm", "largest_error_linear_blend": float(linear.max()),
            "largest_error_animation_space": float(animation.max()),
            **{model: report[model] for model in ("animation_space", "linear_blend")}}


def decompose_creature_and_render(path, bones: int = 12) -> dict:
    """The creature's animation as a bare mesh sequence, skinned again from every third frame; rendered on a
    held-out frame: left the original, right the new rig with its per-vertex error (largest over all frames)."""
    from skinkit.blender import decompose

    mesh_object = open_sample("creature")
    scene = bpy.context.scene
    numbers = list(range(scene.frame_start, scene.frame_end + 1))
    with armature_modifier_only(mesh_object):
        positions = np.stack([evaluated_positions(mesh_object, depsgraph)
                              for depsgraph in depsgraphs_at(numbers)])
    sequence = decompose.Sequence(positions, numbers, [f"frame {n}" for n in numbers])
    report = decompose.skin_object(mesh_object, sequence, bones=bones, max_influences=4, train_frames=numbers[::3])
    report.pop("reconstruction")
    skinned = bpy.data.objects[report["skinned_object"]]
    show_colours(skinned)
    held_out_frame = numbers[::3][len(numbers) // 6] + 1
    scene.frame_set(held_out_frame)
    images = [os.path.join(OUT, "decompose_original.png"), os.path.join(OUT, "decompose_skinned.png")]
    for image, shown, hidden in zip(images, (mesh_object, skinned), (skinned, mesh_object)):
        shown.hide_render, hidden.hide_render = False, True
        render(image)
    combine_horizontally(images, path)
    return {**{model: report[model] for model in ("animation_space", "linear_blend")},
            "frames": report["frames"], "training_frames": report["training_frames"], "bones": report["bones"],
            "original_bones": len(rig_of(mesh_object).armature_object.data.bones), "seconds": report["seconds"],
            "rendered_frame": held_out_frame}


def unwrap_creature(path) -> dict:
    """Animated Unwrap of the creature (animation-space metric, its walk's pose statistics), layout saved."""
    from skinkit.blender import pose_statistics, unwrap

    mesh_object = open_sample("creature")
    armature = rig_of(mesh_object).armature_object
    scene = bpy.context.scene
    frames = range(scene.frame_start, scene.frame_end + 1)
    pose_statistics.store(armature, pose_statistics.from_frames(armature, frames), "action", len(frames))
    report = unwrap.unwrap_object(mesh_object, metric="animation", make_active=True)  # the LOD chain's atlas
    image = unwrap.show_layout(mesh_object, size=512)
    image.filepath_raw = path
    image.file_format = "PNG"
    image.save()
    return {key: report[key] for key in ("charts", "seconds", "stretch_rest", "stretch_frames", "packing_efficiency",
                                         "texture_efficiency")}


def lod_chain_of_creature(path, maps_folder, levels: int = 4) -> dict:
    """Build LOD Chain on the unwrapped creature (the scene unwrap_creature left), Bake Normal Maps for every
    coarser level through the shared atlas, and the levels rendered side by side at RENDER_FRAME, each alone."""
    from skinkit.blender import lod_chain, normal_maps

    mesh_object = find_skinned_mesh(bpy.context.scene.objects)
    chain = lod_chain.build_lod_chain(mesh_object, levels=levels)
    level_objects = [bpy.data.objects[name] for name in chain["objects"]]
    os.makedirs(maps_folder, exist_ok=True)
    baked = normal_maps.bake_normal_maps(level_objects[1:], size=1024, out_dir=maps_folder)
    scene = bpy.context.scene
    scene.frame_set(RENDER_FRAME)
    images = []
    for index, shown in enumerate(level_objects):
        for scene_object in scene.objects:
            if scene_object.type == "MESH":
                scene_object.hide_render = scene_object != shown
        images.append(os.path.join(OUT, f"lod{index}.png"))
        render(images[-1])
    combine_horizontally(images, path)
    maps = {row["object"]: row for row in baked["maps"]}
    rows = [dict(level, map_seconds=maps[name]["seconds"] if name in maps else None)
            for level, name in zip(chain["levels"], chain["objects"])]
    return {"levels": rows, "chain_seconds": chain["seconds"], "bake_seconds": baked["seconds"]}


def show_colours(mesh_object) -> None:
    """A material showing the heat-map colour attribute."""
    material = bpy.data.materials.get("skinkit_heat") or bpy.data.materials.new("skinkit_heat")
    material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    attribute = nodes.get("Attribute") or nodes.new("ShaderNodeAttribute")
    attribute.attribute_name = attributes.HEAT_ATTRIBUTE
    links.new(attribute.outputs["Color"], nodes["Principled BSDF"].inputs["Base Color"])
    mesh_object.data.materials.clear()
    mesh_object.data.materials.append(material)


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


def print_model_errors(report: dict) -> None:
    """rms / max of both models on the training and held-out frames (docs/data-model.md, "Reports")."""
    space, blend = report["animation_space"], report["linear_blend"]
    for part in ("train", "held_out"):
        print(f"  {part:<9} animation space {space[part]['rms']:.2e} / {space[part]['max']:.2e}   linear blend "
              f"{blend[part]['rms']:.2e} / {blend[part]['max']:.2e}")


def print_fit(fitted: dict, image: str) -> None:
    print("\nfit of the arm to 14 dual-quaternion poses (12 trained, 2 held out), rms / max of the diagonal:")
    print_model_errors(fitted)
    print(f"rendered {image} (left: linear blend error, right: animation space error; blue none, red "
          f"{fitted['largest_error_linear_blend']:.2e} of the diagonal)")


def print_decompose(decomposed: dict, image: str) -> None:
    print(f"\nthe creature's animation skinned again without its rig ({decomposed['original_bones']} bones): "
          f"{decomposed['bones']} automatic bones from {decomposed['training_frames']} of {decomposed['frames']} frames "
          f"in {decomposed['seconds']:.1f} s; rms / max of the diagonal:")
    print_model_errors(decomposed)
    print(f"rendered {image} (held-out frame {decomposed['rendered_frame']}; left: the original, right: the new rig, "
          "coloured by its error)")


def print_unwrap(unwrapped: dict, image: str) -> None:
    print(f"\nthe creature unwrapped in the animation-space metric of its walk: {unwrapped['charts']} charts in "
          f"{unwrapped['seconds']:.2f} s; L2 stretch {unwrapped['stretch_frames']:.4f} over the walk's frames, "
          f"{unwrapped['stretch_rest']:.4f} at rest; packing {unwrapped['packing_efficiency']:.3f}, texture efficiency "
          f"{unwrapped['texture_efficiency']:.3f}; layout written to {image}")


def print_lod_chain(chain: dict, image: str, maps_folder: str) -> None:
    print(f"\nthe creature as a LOD chain on that atlas in {chain['chain_seconds']:.2f} s, its levels' normal maps "
          f"(1024 px) baked from LOD0 in {chain['bake_seconds']:.2f} s:")
    header = f"{'level':<7}{'vertices':>9}{'triangles':>11}{'influences':>12}{'epsilon':>10}{'bake s':>8}"
    print(header)
    print("-" * len(header))
    for row in chain["levels"]:
        bake = "" if row["map_seconds"] is None else f"{row['map_seconds']:.3f}"
        print(f"LOD{row['level']:<4}{row['vertices']:>9}{row['triangles']:>11}{row['influences']:>12}"
              f"{row['error']:>10.2e}{bake:>8}")
    print("epsilon: the largest collapse cost met on the way to the level, a fraction of the bounding-box diagonal.")
    print(f"rendered {image} (frame {RENDER_FRAME}, LOD0 to LOD{len(chain['levels']) - 1}, each played by Blender's "
          f"Armature modifier with its normal map); maps in {maps_folder}")


def main() -> None:
    os.makedirs(OUT, exist_ok=True)
    rows = [measure(name) for name in ("arm", "creature")]
    started = time.perf_counter()
    image = os.path.join(OUT, "demo.png")
    render_side_by_side(image)
    heatmap = os.path.join(OUT, "fit_heatmap.png")
    fitted = fit_arm_and_render_errors(heatmap)
    decomposed_image = os.path.join(OUT, "decompose.png")
    decomposed = decompose_creature_and_render(decomposed_image)
    layout_image = os.path.join(OUT, "unwrap_layout.png")
    unwrapped = unwrap_creature(layout_image)
    chain_image, maps_folder = os.path.join(OUT, "lod_chain.png"), os.path.join(OUT, "normal_maps")
    chain = lod_chain_of_creature(chain_image, maps_folder)
    with open(os.path.join(OUT, "demo.json"), "w") as stream:
        json.dump({"conversion": rows, "fit": fitted, "decompose": decomposed, "unwrap": unwrapped,
                   "lod_chain": chain}, stream, indent=2)
    print()
    print_table(rows)
    print(f"\nrendered {image} in {time.perf_counter() - started:.1f} s "
          f"(left: Blender's Armature modifier, right: skinkit animation space, frame {RENDER_FRAME})")
    print_fit(fitted, heatmap)
    print_decompose(decomposed, decomposed_image)
    print_unwrap(unwrapped, layout_image)
    print_lod_chain(chain, chain_image, maps_folder)


if __name__ == "__main__":
    main()
