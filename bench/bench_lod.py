"""Level of detail: skinkit's Limit Influences against Blender's Limit Total, on the creature sample and the horse.

    cd /work/main && .venv/bin/python bench/bench_lod.py [--data ../shared/data] [--datasets creature,horse] \
        [--json bench/lod_results.json] [--markdown bench/lod_results.md]

Data:
  creature (blend_samples/creature.blend, always there): the Armature modifier's 48 walk frames; even frames train,
    odd frames are held out. Its painted skinning has at most 4 influences, so to make the influences exceed K
    honestly both models are FITTED on influence sets grown by 2 rings (skinkit.fit.influences_from_weights,
    at most 8): animation space (fit_animation_space, per-vertex) and linear blend skinning (fit_lbs) on the same
    sets. skinkit limits the animation-space fit with pose statistics of the training frames; Blender's Limit Total
    (reproduced exactly, checked against bpy.ops.object.vertex_group_limit_total in tests/blender/test_lod.py)
    limits the linear-blend fit.
  horse (../shared/data/horse, skipped with a message when absent): decompose the 11 training poses with 25 bones
    and 8 influences (skinkit.decompose), limit to K: skinkit on the animation-space model, Limit Total on the
    decomposition's linear-blend weights. Held out: the 48-frame gallop, its bone frames solved once with the full
    animation-space model and used for every limited model (the rig's animation is fixed, only the skin changes).

Error (animated_error): RMS and max of the distance to the target meshes over vertices and held-out frames, with
the rest mesh scaled into a unit box (largest side 1), as the thesis' section 8.5 measures LOD. Both the error to
the ground truth (the frames) and to the unlimited model are reported. Seconds and peak memory: one limit call
(bench_fit.measured: VmHWM growth). Target: skinkit's error to the unlimited model at most 0.3x Limit Total's.

Peers to come (the same loaders and error function): the progressive-mesh chain (skinkit.lod.build_chain),
meshoptimizer, fast-simplification and Blender's Decimate at equal triangle budgets, with errors at corresponding
surface points.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from bench_fit import measured
from common import machine_info, machine_line, parallel_speedup, write_outputs
from decompose_data import MissingData
from decompose_data import horse as load_horse_frames

from skinkit import convert_lbs
from skinkit.lod import limit_influences
from skinkit.lod.influences import limit_total
from skinkit.metrics import PoseStatistics

REPOSITORY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TARGET_RATIO = 0.3
LIMITS = (4, 2)


# ---- shared pieces ------------------------------------------------------------------------------------------


def unit_box_scale(rest: np.ndarray) -> float:
    """1 / the largest side of the rest mesh's bounding box: distances times this are in a unit box."""
    return 1.0 / float(np.ptp(rest, axis=0).max())


def animated_error(positions: np.ndarray, target: np.ndarray, scale: float) -> dict:
    """RMS and max distance over vertices and frames (F, V, 3), times `scale` (unit box)."""
    distance = np.linalg.norm(positions - target, axis=-1) * scale
    return {"rms": float(np.sqrt(np.mean(distance ** 2))), "max": float(distance.max())}


def load_creature() -> dict:
    import bpy

    from skinkit.blender.frames import armature_modifier_only, depsgraphs_at, evaluated_positions, poses_at
    from skinkit.blender.rig import bind_matrix, deform_weights, mesh_of, rig_of, skeleton_of

    bpy.ops.wm.open_mainfile(filepath=os.path.join(REPOSITORY, "blend_samples", "creature.blend"), load_ui=False)
    mesh_object = bpy.data.objects["creature"]
    rig = rig_of(mesh_object)
    bind = bind_matrix(rig, bpy.context.evaluated_depsgraph_get())
    skeleton = skeleton_of(rig, bind)
    frames = list(range(1, 49))
    with armature_modifier_only(mesh_object):
        positions = np.stack([evaluated_positions(mesh_object, d) for d in depsgraphs_at(frames)])
    poses = poses_at(rig.armature_object, frames, list(skeleton.names), bind)
    mesh = mesh_of(mesh_object)
    return {"skeleton": skeleton, "rest": mesh.positions, "triangles": mesh.triangles, "frames": positions,
            "poses": poses, "weights": deform_weights(rig), "train": np.arange(0, 48, 2), "test": np.arange(1, 48, 2)}


def creature_models(data: dict) -> dict:
    """Animation-space and linear-blend fits on influence sets grown by 2 rings (at most 8)."""
    from skinkit.fit import fit_animation_space, fit_lbs, influences_from_weights

    skeleton, train = data["skeleton"], data["train"]
    dense = data["weights"].to_dense(skeleton.bone_count)
    influences = influences_from_weights(dense, 8, data["triangles"], rings=2)
    fitted = fit_animation_space(data["poses"][train], data["frames"][train], influences, skeleton.bone_count,
                                 rest_positions=data["rest"], rest_frames=skeleton.rest_frames)
    weights = fit_lbs(skeleton, data["rest"], data["poses"][train], data["frames"][train], influences)
    return {"model": fitted.model, "weights": weights,
            "statistics": PoseStatistics.from_world_samples(skeleton.parents, data["poses"][train]),
            "test_poses": data["poses"][data["test"]], "targets": data["frames"][data["test"]],
            "skeleton": skeleton, "rest": data["rest"]}


def horse_models(data_folder: str) -> dict:
    from skinkit.decompose import decompose

    frames = load_horse_frames(data_folder)
    result = decompose(frames.train, frames.triangles, bone_count=25, max_influences=8, rest=frames.train[0])
    test_poses = result.solve_poses(frames.held_out, "animation")
    return {"model": result.model, "weights": result.linear_blend,
            "statistics": PoseStatistics.from_world_samples(result.skeleton.parents, result.training_poses),
            "test_poses": test_poses, "targets": frames.held_out, "skeleton": result.skeleton,
            "rest": result.rest_positions}


def ratio(ours: float, theirs: float):
    """ours / theirs; None when theirs is zero to rounding (nothing to compare with)."""
    return ours / theirs if theirs > 1e-12 else None


def compare(models: dict, limits=LIMITS) -> dict:
    scale = unit_box_scale(models["rest"])
    full = models["model"].evaluate(models["test_poses"])
    lbs_full = convert_lbs(models["skeleton"], models["weights"], models["rest"]).evaluate(models["test_poses"])
    rows = {"influences": {"animation_space_max": int(models["model"].counts().max()),
                           "animation_space_mean": float(models["model"].counts().mean()),
                           "linear_blend_max": int(models["weights"].counts().max()),
                           "linear_blend_mean": float(models["weights"].counts().mean())},
            "unlimited": {"skinkit animation space": animated_error(full, models["targets"], scale),
                          "linear blend": animated_error(lbs_full, models["targets"], scale)}}
    for k in limits:
        (limited, _), usage = measured(lambda: limit_influences(models["model"], models["statistics"], k), 3)
        totals, total_usage = measured(lambda: limit_total(models["weights"], k), 3)
        ours = limited.evaluate(models["test_poses"])
        theirs = convert_lbs(models["skeleton"], totals, models["rest"]).evaluate(models["test_poses"])
        entry = {"skinkit": {"to_frames": animated_error(ours, models["targets"], scale),
                             "to_unlimited": animated_error(ours, full, scale),
                             "seconds": float(np.median(usage["seconds_all"])), "peak_mb": usage["peak_mb"],
                             "influences": limited.influence_count},
                 "limit_total": {"to_frames": animated_error(theirs, models["targets"], scale),
                                 "to_unlimited": animated_error(theirs, lbs_full, scale),
                                 "seconds": float(np.median(total_usage["seconds_all"])),
                                 "peak_mb": total_usage["peak_mb"], "influences": totals.influence_count}}
        entry["ratio_to_unlimited"] = ratio(entry["skinkit"]["to_unlimited"]["rms"],
                                            entry["limit_total"]["to_unlimited"]["rms"])
        entry["ratio_to_frames"] = ratio(entry["skinkit"]["to_frames"]["rms"], entry["limit_total"]["to_frames"]["rms"])
        rows[f"K={k}"] = entry
    return rows


def markdown(results: dict) -> str:
    lines = ["# Limit Influences vs Blender's Limit Total", "",
             machine_line(results["machine"]) + ")", "",
             "Errors: RMS (max) distance over vertices and held-out frames, rest mesh in a unit box. 'to unlimited': "
             "against the same model before limiting; 'to frames': against the held-out meshes. Ratio: skinkit's RMS "
             f"over Limit Total's (target at most {TARGET_RATIO} to unlimited).", ""]
    for name, rows in results["datasets"].items():
        if "skipped" in rows:
            lines += [f"## {name}", "", f"skipped: {rows['skipped']}", ""]
            continue
        influences = rows["influences"]
        lines += [f"## {name}", "",
                  f"Influences before: animation space {influences['animation_space_mean']:.2f} mean / "
                  f"{influences['animation_space_max']} max; linear blend {influences['linear_blend_mean']:.2f} / "
                  f"{influences['linear_blend_max']}. Unlimited error to frames: animation space "
                  f"{rows['unlimited']['skinkit animation space']['rms']:.2e}, linear blend "
                  f"{rows['unlimited']['linear blend']['rms']:.2e}.", "",
                  "| K | method | to unlimited rms (max) | to frames rms (max) | influences | seconds | peak MB |",
                  "|---|---|---|---|---|---|---|"]
        for key, entry in rows.items():
            if not key.startswith("K="):
                continue
            for method, label in (("skinkit", "skinkit Limit Influences"), ("limit_total", "Blender Limit Total")):
                e = entry[method]
                lines.append(f"| {key[2:]} | {label} | {e['to_unlimited']['rms']:.2e} ({e['to_unlimited']['max']:.2e}) "
                             f"| {e['to_frames']['rms']:.2e} ({e['to_frames']['max']:.2e}) | {e['influences']} | "
                             f"{e['seconds']:.3f} | {e['peak_mb']:.1f} |")
            shown = ["n/a" if r is None else f"{r:.3f}" for r in (entry["ratio_to_unlimited"], entry["ratio_to_frames"])]
            lines.append(f"| {key[2:]} | ratio | {shown[0]} | {shown[1]} | | | |")
        lines.append("")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=os.path.join(REPOSITORY, "..", "shared", "data"))
    parser.add_argument("--datasets", default="creature,horse")
    parser.add_argument("--json")
    parser.add_argument("--markdown")
    arguments = parser.parse_args(argv)
    speedup_before = parallel_speedup()
    results = {"datasets": {}, "target_ratio": TARGET_RATIO}
    for name in arguments.datasets.split(","):
        try:
            models = creature_models(load_creature()) if name == "creature" else horse_models(arguments.data)
        except MissingData as missing:
            print(f"{name}: skipped ({missing})", file=sys.stderr)
            results["datasets"][name] = {"skipped": str(missing)}
            continue
        results["datasets"][name] = compare(models)
        for key, entry in results["datasets"][name].items():
            if key.startswith("K="):
                print(f"{name} {key}: skinkit/Limit Total rms to unlimited {entry['ratio_to_unlimited']}, to "
                      f"frames {entry['ratio_to_frames']}", file=sys.stderr)
    results["machine"] = machine_info() | {"parallel_speedup_before": speedup_before,
                                           "parallel_speedup_after": parallel_speedup()}
    write_outputs(results, arguments.json, arguments.markdown, markdown)
    if not arguments.json and not arguments.markdown:
        print(markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
