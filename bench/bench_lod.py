"""Level of detail: skinkit's LOD chain against Blender's Decimate, meshoptimizer and fast-simplification (each
followed by Limit Total). Limit Influences against Limit Total: bench/bench_limit_influences.py.

    cd /work/main && .venv/bin/python bench/bench_lod.py [--data ../shared/data] \
        [--chain-datasets horse,creature,arm,cow,dembones] [--no-blender-decimate] [--no-speed] \
        [--plot docs/images/lod_chain_error.png] [--json bench/lod_results.json] [--markdown bench/lod_results.md]

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

The chain (thesis section 8.5, Fig. 8.12): on the horse, the creature, the arm, the cow and the Dem Bones sample
(each skipped with a message when its files are absent), animated RMS error over the held-out frames at corresponding
surface points (bench/lod_peers.py) against total influences, for skinkit's variants (SKINKIT_VARIANTS: the
defaults from the peers' own linear-blend weights, the defaults from the richer animation-space model, that model
first limited to the engine's 4 influences per vertex, the thesis' ranking, influence costs x3, pose statistics
with a spread of 0.2 and 0.4 rad (PoseStatistics.from_world_samples(spread=...)), the defaults before session 14
(auto collapses, influence costs x1), no influence simplification, the rest pose) and the peers; seconds for the
whole chain, peak memory growth;
the ratio to the best peer at equal influences against the issue's targets (at most 0.5 at half the influences or
fewer, at most 0.25 at one eighth), and a log-log plot. The ratio that compares simplifiers is the first variant's:
it and the peers start from the same model and are measured to the same full detail. From the animation-space model
(the second), skinkit starts with about 3x the peers' influences and is measured to a more detailed reference, so at
equal total influences it sits at a smaller share of its own input than the peers do. The floor (floor_points)
beside the first variant's ratios: a level with one vertex per influence of the budget, each vertex keeping all its
influences, against the same best peer: how close any level within the budget could come as far as this simplifier
places vertices.

Speed and scale (--no-speed leaves them out; skipped with a message without the horse): the 5-level horse chain (one
run of sk_simplify_chain against the level-by-level sk_simplify calls it replaced, least and median wall and CPU
seconds over 5 runs, the load average around them) and the horse subdivided twice in animation space (Loop: 134782
vertices) as a 5-level chain, against the issue's targets (< 1 s; < 10 s below 1 GB).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np

import lod_peers
from bench_fit import measured
from common import finish_run, machine_line, parallel_speedup
from decompose_data import MissingData
from decompose_data import horse as load_horse_frames

from skinkit import convert_lbs
from skinkit.metrics import PoseStatistics

REPOSITORY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# ---- shared pieces ------------------------------------------------------------------------------------------


def unit_box_scale(rest: np.ndarray) -> float:
    """1 / the largest side of the rest mesh's bounding box: distances times this are in a unit box."""
    return 1.0 / float(np.ptp(rest, axis=0).max())


def animated_error(positions: np.ndarray, target: np.ndarray, scale: float) -> dict:
    """RMS and max distance over vertices and frames (F, V, 3), times `scale` (unit box)."""
    distance = np.linalg.norm(positions - target, axis=-1) * scale
    return {"rms": float(np.sqrt(np.mean(distance ** 2))), "max": float(distance.max())}


def load_sample(name: str) -> dict:
    """A Blender sample (blend_samples/<name>.blend): its Armature modifier's frames (the scene's range), even
    frames train and odd frames are held out."""
    import bpy

    from skinkit.blender.frames import armature_modifier_only, depsgraphs_at, evaluated_positions, poses_at
    from skinkit.blender.rig import bind_matrix, deform_weights, mesh_of, rig_of, skeleton_of

    bpy.ops.wm.open_mainfile(filepath=os.path.join(REPOSITORY, "blend_samples", f"{name}.blend"), load_ui=False)
    mesh_object = bpy.data.objects[name]
    rig = rig_of(mesh_object)
    bind = bind_matrix(rig, bpy.context.evaluated_depsgraph_get())
    skeleton = skeleton_of(rig, bind)
    scene = bpy.context.scene
    frames = list(range(scene.frame_start, scene.frame_end + 1))
    with armature_modifier_only(mesh_object):
        positions = np.stack([evaluated_positions(mesh_object, d) for d in depsgraphs_at(frames)])
    poses = poses_at(rig.armature_object, frames, list(skeleton.names), bind)
    mesh = mesh_of(mesh_object)
    count = len(frames)
    return {"skeleton": skeleton, "rest": mesh.positions, "triangles": mesh.triangles, "frames": positions,
            "poses": poses, "weights": deform_weights(rig), "train": np.arange(0, count, 2),
            "test": np.arange(1, count, 2)}


def creature_models(data: dict) -> dict:
    """Animation-space and linear-blend fits on influence sets grown by 2 rings (at most 8, fewer where the training
    frames determine fewer: 4n - 1 unknowns need 3E >= 4n - 1 equations)."""
    from skinkit.fit import fit_animation_space, fit_lbs, influences_from_weights

    skeleton, train = data["skeleton"], data["train"]
    dense = data["weights"].to_dense(skeleton.bone_count)
    influences = influences_from_weights(dense, min(8, (3 * len(train) + 1) // 4), data["triangles"], rings=2)
    fitted = fit_animation_space(data["poses"][train], data["frames"][train], influences, skeleton.bone_count,
                                 rest_positions=data["rest"], rest_frames=skeleton.rest_frames)
    weights = fit_lbs(skeleton, data["rest"], data["poses"][train], data["frames"][train], influences)
    return {"model": fitted.model, "weights": weights,
            "statistics": PoseStatistics.from_world_samples(skeleton.parents, data["poses"][train]),
            "training_poses": data["poses"][train],
            "test_poses": data["poses"][data["test"]], "targets": data["frames"][data["test"]],
            "skeleton": skeleton, "rest": data["rest"], "triangles": data["triangles"]}


def horse_models(data_folder: str) -> dict:
    return decomposed_models(load_horse_frames(data_folder), bone_count=25)


def decomposed_models(frames, bone_count: int) -> dict:
    """skinkit.decompose on a data set's training frames (8 influences, fewer where the frames determine fewer), its
    held-out frames' bone frames solved once with the full animation-space model (the rig's animation is fixed, only
    the skin changes)."""
    from skinkit.decompose import decompose

    most = min(8, (3 * len(frames.train) + 1) // 4)
    result = decompose(frames.train, frames.triangles, bone_count=bone_count, max_influences=most,
                       rest=frames.train[0])
    test_poses = result.solve_poses(frames.held_out, "animation")
    return {"model": result.model, "weights": result.linear_blend,
            "statistics": PoseStatistics.from_world_samples(result.skeleton.parents, result.training_poses),
            "training_poses": result.training_poses, "test_poses": test_poses, "targets": frames.held_out, "skeleton": result.skeleton,
            "rest": result.rest_positions, "triangles": frames.triangles}



# ---- the LOD chain against the peers ------------------------------------------------------------------------

#: The engine's per-vertex budget one variant starts from (the decomposition gives up to 8 per vertex).
ENGINE_BUDGET = 4
#: skinkit's variants: (name, the model it starts from, build_chain options on top of its defaults). "weights": the
#: peers' own linear-blend weights (as an animation-space model, convert_lbs), so skinkit and the peers simplify the
#: same model and their errors are measured to the same full detail; "model": the richer animation-space model (up to
#: 8 influences per vertex), its errors to that model. The first is held to the targets, and the only one also
#: timed as a 5-level chain; the second's ratios are reported too.
SKINKIT_VARIANTS = (
    ("skinkit AS + influence simplification (defaults), from the peers' weights", "weights", {}),
    ("skinkit AS + influence simplification (defaults), from the AS model", "model", {}),
    ("skinkit AS + influence simplification, levels not refitted, from the peers' weights", "weights",
     {"refit": False}),
    (f"skinkit AS + influence simplification, from the AS model limited to {ENGINE_BUDGET} per vertex", "model",
     {"start_influences": ENGINE_BUDGET}),
    ("skinkit AS + influence simplification, thesis ranking", "model",
     {"rank_per_influence": False, "collapse": "half", "influence_cost_scale": 1.0}),
    ("skinkit AS + influence simplification, influence costs x3, from the peers' weights", "weights",
     {"influence_cost_scale": 3.0}),
    ("skinkit AS + influence simplification, statistics spread 0.2 rad, from the peers' weights", "weights",
     {"statistics_spread": 0.2}),
    ("skinkit AS + influence simplification, statistics spread 0.4 rad, from the peers' weights", "weights",
     {"statistics_spread": 0.4}),
    ("skinkit AS + influence simplification, auto collapses, influence costs x1 (the defaults before session 14), "
     "from the peers' weights", "weights", {"collapse": "auto", "influence_cost_scale": 1.0}),
    ("skinkit AS without influence simplification", "model", {"simplify_influences": False}),
    ("skinkit rest-pose 3D", "model", {"metric": "rest", "simplify_influences": False}))
#: The variants held to the targets: the first (same start as the peers) and the second (from the AS model).
TARGET_VARIANTS = 2
#: One run per chain: on the shared 2-core machine seven variants on five data sets take most of an hour already.
CHAIN_REPEATS = 1
CHAIN_LEVELS = 7  # the input and 6 halvings of its influences: down to 1/64
HALF, EIGHTH = 0.5, 0.125
TARGET_HALF, TARGET_EIGHTH = 0.5, 0.25


def chain_models(name: str, data_folder: str) -> dict:
    """The chain benchmark's data set `name` as models (raises MissingData when its files are absent)."""
    import decompose_data

    if name in ("creature", "arm"):
        return creature_models(load_sample(name))
    if name == "horse":
        return horse_models(data_folder)
    frames = decompose_data.LOADERS[name](data_folder)
    return decomposed_models(frames, frames.bone_count)


def skinkit_chains(models: dict, samples, references: dict, frames, scale: float) -> dict:
    """Each variant's chain, its levels' errors to the full detail of the model it started from (references:
    source -> that model's posed samples) and to the frames."""
    from skinkit.lod import build_chain

    results = {}
    for index, (name, source, options) in enumerate(SKINKIT_VARIANTS):
        start = models["lbs_model"] if source == "weights" else models["model"]
        reference = references[source]
        options = dict(options)
        spread = options.pop("statistics_spread", 0.0)
        statistics = models["statistics"] if spread == 0 else \
            PoseStatistics.from_world_samples(models["skeleton"].parents, models["training_poses"], spread=spread)

        def build(levels=CHAIN_LEVELS):
            return build_chain(models["triangles"], models["rest"], start, statistics, levels=levels, **options)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # no UVs on these meshes: every chain warns that it has no atlas
            chain, usage = measured(build, CHAIN_REPEATS)
            five, five_usage = measured(lambda: build(5), CHAIN_REPEATS) if index == 0 else (None, None)
        points = []
        for index, level in enumerate(chain.levels):
            posed = level.model.evaluate(models["test_poses"])
            at = samples.on_level(lod_peers.Level(models["rest"][level.vertices], level.triangles, posed,
                                                  level.influence_count))
            points.append({"level": index, "triangles": level.triangle_count, "vertices": level.vertex_count,
                           "influences": level.influence_count, "epsilon": level.relative_epsilon,
                           "error": lod_peers.rms(at, reference, scale), "to_frames": lod_peers.rms(at, frames, scale)})
        results[name] = {"source": source, "points": points, "seconds": float(np.median(usage["seconds_all"])),
                         "peak_mb": usage["peak_mb"],
                         "five_level_seconds": None if five_usage is None else float(np.median(five_usage["seconds_all"])),
                         "five_level_peak_mb": None if five_usage is None else five_usage["peak_mb"]}
    return results


def floor_points(models: dict, samples, reference, scale: float, budgets: list[int]) -> list[dict]:
    """Per influence budget, a level with as many vertices as the budget has influences, each vertex keeping every
    influence it had (skinkit's chain from the peers' weights without influence simplification, to that many
    vertices): a level within the budget has at most that many vertices, so it is no closer to the full detail than
    the best such level unless a simplifier places them better, and gets as close only if every influence it drops
    costs nothing. A budget of at least the input's vertices allows the full detail: its floor is 0."""
    from skinkit.lod import build_chain

    vertex_count = len(models["rest"])
    per_vertex = len(models["triangles"]) / vertex_count
    below = [budget for budget in budgets if budget < vertex_count]
    points = [{"vertices": vertex_count, "triangles": len(models["triangles"]), "error": 0.0}
              for _ in range(len(budgets) - len(below))]
    if not below:
        return points
    targets = [max(int(round(budget * per_vertex)), 1) for budget in below]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # no UVs on these meshes
        chain = build_chain(models["triangles"], models["rest"], models["lbs_model"], models["statistics"],
                            levels=len(targets) + 1, simplify_influences=False, targets={"triangles": targets})
    for level in chain.levels[1:]:
        posed = level.model.evaluate(models["test_poses"])
        at = samples.on_level(lod_peers.Level(models["rest"][level.vertices], level.triangles, posed,
                                              level.influence_count))
        points.append({"vertices": level.vertex_count, "triangles": level.triangle_count,
                       "error": lod_peers.rms(at, reference, scale)})
    return points


def best_peer(peers: dict, influences: int, key: str = "error"):
    """(error, peer name) of the peer with the least error at `influences` (None, None when none reaches it)."""
    found = [(lod_peers.error_at(lod_peers.frontier(entry["points"], key), influences), name)
             for name, entry in peers.items()]
    found = [f for f in found if f[0] is not None]
    return min(found) if found else (None, None)


def chain_targets(ours: dict, peers: dict, key: str = "error", variant: int = 0, floor=None) -> list[dict]:
    """Per level of SKINKIT_VARIANTS[variant] with at most half its input's influences: its error, the best peer's
    at the same total influences, the ratio and the target it must meet; with `floor` (floor_points at these levels'
    influences, level 1 first), the floor's error and its ratio to the same peer."""
    points = ours[SKINKIT_VARIANTS[variant][0]]["points"]
    total = points[0]["influences"]
    rows = []
    for point in points[1:]:
        share = point["influences"] / total
        if share > HALF + 1e-9:
            continue
        error, peer = best_peer(peers, point["influences"], key)
        ratio_value = None if error is None else point[key] / error
        target = TARGET_EIGHTH if share <= EIGHTH + 0.01 else TARGET_HALF
        floor_point = None if floor is None else floor[point["level"] - 1]
        rows.append({"level": point["level"], "influences": point["influences"], "share": share, "skinkit": point[key],
                     "best_peer": error, "peer": peer, "ratio": ratio_value, "target": target,
                     "met": None if ratio_value is None else ratio_value <= target,
                     "best_variant": best_variant(ours, peers, point["level"], key), "floor": floor_point,
                     "floor_ratio": None if floor_point is None or error is None else floor_point["error"] / error})
    return rows


def best_variant(ours: dict, peers: dict, level: int, key: str):
    """(ratio, variant): the skinkit variant whose level `level` has the least error relative to the best peer at
    its own total influences (the variants' levels hold nearly equal influences: each halves the one before)."""
    found = []
    for variant, entry in ours.items():
        if level < len(entry["points"]):
            point = entry["points"][level]
            error, _ = best_peer(peers, point["influences"], key)
            if error is not None:
                found.append((point[key] / error, variant))
    return min(found) if found else (None, None)


def compare_chains(models: dict, with_blender: bool) -> dict:
    scale = unit_box_scale(models["rest"])
    samples = lod_peers.SurfaceSamples(models["rest"], models["triangles"])
    frames = samples.on_input(models["targets"])
    models = dict(models, lbs_model=convert_lbs(models["skeleton"], models["weights"], models["rest"]))
    references = {"model": samples.on_input(models["model"].evaluate(models["test_poses"])),
                  "weights": samples.on_input(models["lbs_model"].evaluate(models["test_poses"]))}
    ours = skinkit_chains(models, samples, references, frames, scale)
    peers = lod_peers.peer_chains(models, samples, references["weights"], frames, scale, with_blender)
    held = ours[SKINKIT_VARIANTS[0][0]]["points"][1:]  # the floor is drawn at the first variant's budgets
    floor = floor_points(models, samples, references["weights"], scale, [p["influences"] for p in held])
    return {"vertices": len(models["rest"]), "triangles": len(models["triangles"]),
            "bones": models["skeleton"].bone_count, "held_out_frames": len(models["targets"]),
            "skinkit": ours, "peers": peers, "floor": floor,
            "targets": [{"variant": SKINKIT_VARIANTS[v][0],
                         "to_full_detail": chain_targets(ours, peers, "error", v, floor if v == 0 else None),
                         "to_frames": chain_targets(ours, peers, "to_frames", v)} for v in range(TARGET_VARIANTS)]}


def chain_plot(results: dict, path: str) -> None:
    """Error against total influences, log-log, one panel per data set (like the thesis' Fig. 8.12)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = [(n, r) for n, r in results["chain"].items() if "skipped" not in r]
    if not shown:
        return
    # at least 8 inches wide: the legend (one entry per variant and peer) needs it with a single panel
    figure, axes = plt.subplots(1, len(shown), figsize=(max(3.2 * len(shown), 8.0), 4.2), squeeze=False)
    measurable = 1e-9  # level 0 (and a peer's untouched input) is exact: nothing to draw on a log scale

    def drawn(pairs):
        pairs = [(c, e) for c, e in pairs if e > measurable]
        return [c for c, _ in pairs], [e for _, e in pairs]

    for axis, (name, rows) in zip(axes[0], shown):
        for variant, entry in rows["skinkit"].items():
            axis.plot(*drawn((p["influences"], p["error"]) for p in entry["points"]), "o-", markersize=3,
                      label=variant)
        for peer, entry in rows["peers"].items():
            axis.plot(*drawn(lod_peers.frontier(entry["points"])), "x--", markersize=3, label=peer + " + Limit Total")
        axis.set_xscale("log")
        axis.set_yscale("log")
        lowest = axis.get_ylim()[0]  # the methods' range: the floor of a nearly untouched mesh may lie far below
        floor = [(t["influences"], t["floor"]["error"]) for t in rows["targets"][0]["to_full_detail"] if t.get("floor")]
        axis.plot(*drawn(floor), "k:", linewidth=2, label="floor: one vertex per influence of the budget, its "
                                                          "influences free (not a method)")
        axis.set_ylim(bottom=lowest)
        axis.set_title(f"{name} ({rows['vertices']} vertices)", fontsize=9)
        axis.set_xlabel("total influences", fontsize=8)
        axis.tick_params(labelsize=7)
    axes[0][0].set_ylabel("animated RMS error (unit box)", fontsize=8)
    handles, labels = axes[0][0].get_legend_handles_labels()
    figure.legend(handles, labels, fontsize=7, loc="lower center", ncol=2, frameon=False)
    figure.tight_layout(rect=(0, 0.28, 1, 1))
    figure.savefig(path, dpi=80)
    plt.close(figure)


def markdown(results: dict) -> str:
    lines = [machine_line(results["machine"]) + ")", ""] + chain_markdown(results)
    if results.get("speed"):
        lines += speed_markdown(results["speed"])
    return "\n".join(lines) + "\n"


def chain_markdown(results: dict) -> list[str]:
    lines = ["# LOD chain: error against total influences", "",
             "Animated RMS error in a unit box (largest side 1) over the held-out frames, at 20000 corresponding "
             "surface points (area-uniform on the input's rest pose; each one's partner on a level is the closest "
             "rest-pose point of the level, carried through the level's posed vertices). 'error': against the full "
             "detail of the model the method started from (the peers and skinkit's variants marked 'from the peers' "
             "weights': the decomposition's linear-blend weights; the others: its animation-space model, with up to "
             "8 influences per vertex and so about 3x the influences at full detail), as the thesis' Fig. 8.12; "
             "'to frames': against the held-out meshes. Peers: each simplifier at "
             f"{', '.join(f'{f:g}' for f in lod_peers.FRACTIONS)} of the triangles, then Limit Total at K = "
             "4, 3, 2, 1 (and unlimited); the best peer at a budget is the least error along each peer's front, "
             "log-log interpolated between its points (generous to the peers). No UVs: every method runs without "
             "atlas constraints.", ""]
    for name, rows in results["chain"].items():
        lines += [f"## {name}", ""]
        if "skipped" in rows:
            lines += [f"skipped: {rows['skipped']}", ""]
            continue
        lines += [f"{rows['vertices']} vertices, {rows['triangles']} triangles, {rows['bones']} bones, "
                  f"{rows['held_out_frames']} held-out frames.", "",
                  "| method | seconds (whole chain) | peak MB | levels: triangles / influences / error (to frames) |",
                  "|---|---|---|---|"]
        for variant, entry in rows["skinkit"].items():
            shown = "; ".join(f"{p['triangles']} / {p['influences']} / {p['error']:.2e} ({p['to_frames']:.2e})"
                              for p in entry["points"])
            five = "" if entry["five_level_seconds"] is None else f" (5 levels: {entry['five_level_seconds']:.3f})"
            lines.append(f"| {variant} | {entry['seconds']:.3f}{five} | {entry['peak_mb']:.1f} | {shown} |")
        for peer, entry in rows["peers"].items():
            shown = "; ".join(f"{c} / {e:.2e}" for c, e in lod_peers.frontier(entry["points"]))
            grown = max(p["max_influences"] for p in entry["points"] if p["K"] is None)
            lines.append(f"| {peer} + Limit Total (front: influences / error; unlimited sets up to {grown} per "
                         f"vertex) | {entry['seconds']:.3f} | | {shown} |")
        for held, (key, label) in ((h, k) for h in rows["targets"] for k in (("to_full_detail", "to full detail"),
                                                                          ("to_frames", "to frames"))):
            lines += ["", f"Targets ({label}): {held['variant']} against the best peer at equal total "
                          "influences (share: of its level 0's influences).", "",
                      "| level | influences (share) | skinkit | best peer | peer | ratio | target | met | best skinkit "
                      "variant's ratio | floor: vertices, error, ratio |",
                      "|---|---|---|---|---|---|---|---|---|---|"]
            for t in held[key]:
                peer_error = "n/a" if t["best_peer"] is None else f"{t['best_peer']:.2e}"
                shown_ratio = "n/a" if t["ratio"] is None else f"{t['ratio']:.3f}"
                met = "n/a (no peer reaches it)" if t["met"] is None else ("yes" if t["met"] else "no")
                variant_ratio, variant = t["best_variant"]
                shown_variant = "n/a" if variant_ratio is None else f"{variant_ratio:.3f} ({variant})"
                floor = t.get("floor")
                shown_floor = "" if floor is None else \
                    f"{floor['vertices']}, {floor['error']:.2e}, " + \
                    ("n/a" if t["floor_ratio"] is None else f"**{t['floor_ratio']:.3f}**")
                lines.append(f"| {t['level']} | {t['influences']} ({t['share']:.3f}) | {t['skinkit']:.2e} | "
                             f"{peer_error} | {t['peer'] or ''} | {shown_ratio} | <= {t['target']} | {met} | "
                             f"{shown_variant} | {shown_floor} |")
        lines.append("")
    return lines


# ---- speed and scale ----------------------------------------------------------------------------------------

SPEED_REPEATS = 5
SPEED_LEVELS = 5  # the "5-level horse chain"
LARGE_TARGET_SECONDS, LARGE_TARGET_MB, CHAIN_TARGET_SECONDS = 10.0, 1024.0, 1.0


def timed(function, repeats: int) -> tuple[object, dict]:
    """function()'s last result; the least and median wall and CPU seconds over `repeats` runs, the load average
    around them, and the peak memory growth of the first run (bench_fit.measured: VmHWM)."""
    walls, cpus, result, usage = [], [], None, None
    load_before = os.getloadavg()[0]
    for _ in range(repeats):
        result = None
        started_cpu = time.process_time()
        result, measured_usage = measured(function, 1)
        cpus.append(time.process_time() - started_cpu)
        walls.append(measured_usage["seconds_all"][0])
        usage = usage or measured_usage
    return result, {"wall_min": min(walls), "wall_median": float(np.median(walls)), "cpu_min": min(cpus),
                    "cpu_median": float(np.median(cpus)), "repeats": repeats, "peak_mb": usage["peak_mb"],
                    "load_before": load_before, "load_after": os.getloadavg()[0]}


def chain_by_steps(models: dict, levels: int):
    """The level-by-level path the chain replaced: one sk_simplify per level on the level before (each re-costs every
    edge), to half its influences. The same levels as build_chain (tests/core/test_lod_chain.py proves it)."""
    from skinkit.lod.chain import simplify_step

    model = models["model"]
    triangles, offsets = models["triangles"], model.offsets.astype(np.int32)
    bones, coordinates = model.bones.astype(np.int32), np.ascontiguousarray(model.coordinates)
    influences, rest = model.influence_count, models["rest"].reshape(-1)
    for _ in range(levels - 1):
        out = simplify_step(triangles, rest, offsets, bones, coordinates, models["statistics"],
                            target_influences=influences // 2)
        triangles, offsets, bones, coordinates = out["triangles"], out["offsets"], out["bones"], out["coordinates"]
        influences = out["report"]["influence_count"]
    return influences


def large_character(models: dict) -> dict:
    """The horse's decomposed model subdivided twice in animation space (Loop, skinkit.subdivide): a 135k-vertex
    character whose deformation is the subdivided posed horse in every pose."""
    from skinkit.subdivide import subdivide

    subdivision = subdivide(models["triangles"], models["model"], levels=2, scheme="loop")
    return {"triangles": np.ascontiguousarray(subdivision.polygons, np.int32), "model": subdivision.model,
            "rest": subdivision.apply(models["rest"]), "statistics": models["statistics"]}


def speed_results(data_folder: str) -> dict:
    """The 5-level horse chain (one run of the queue against the level-by-level calls it replaced) and a 100k+
    vertex chain, each skinkit AS + influence simplification without UVs."""
    from skinkit.lod import build_chain

    try:
        models = horse_models(data_folder)
    except MissingData as missing:
        print(f"speed: skipped ({missing})", file=sys.stderr)
        return {"skipped": str(missing)}

    def chain_of(data, levels):
        return lambda: build_chain(data["triangles"], data["rest"], data["model"], data["statistics"], levels=levels)

    results = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # no UVs: every chain warns that it has no atlas
        chain, usage = timed(chain_of(models, SPEED_LEVELS), SPEED_REPEATS)
        _, by_steps = timed(lambda: chain_by_steps(models, SPEED_LEVELS), SPEED_REPEATS)
        results["horse"] = {"vertices": len(models["rest"]), "triangles": len(models["triangles"]),
                            "influences": models["model"].influence_count, "levels": len(chain.levels),
                            "level_triangles": [level.triangle_count for level in chain.levels],
                            "one_run": usage, "level_by_level": by_steps, "target_seconds": CHAIN_TARGET_SECONDS}
        large = large_character(models)
        chain, usage = timed(chain_of(large, SPEED_LEVELS), 2)
        results["large"] = {"vertices": len(large["rest"]), "triangles": len(large["triangles"]),
                            "influences": large["model"].influence_count, "levels": len(chain.levels),
                            "level_triangles": [level.triangle_count for level in chain.levels], "one_run": usage,
                            "target_seconds": LARGE_TARGET_SECONDS, "target_mb": LARGE_TARGET_MB}
    for name, row in results.items():
        print(f"speed {name}: {row['vertices']} vertices, {row['levels']} levels, wall min "
              f"{row['one_run']['wall_min']:.3f} s, cpu min {row['one_run']['cpu_min']:.3f} s, peak "
              f"{row['one_run']['peak_mb']:.0f} MB, load {row['one_run']['load_before']:.1f}", file=sys.stderr)
    return results


def speed_markdown(speed: dict) -> list[str]:
    lines = ["# LOD chain: speed and scale", ""]
    if "skipped" in speed:
        return lines + [f"skipped: {speed['skipped']}", ""]
    lines += ["skinkit AS + influence simplification, no UVs, each level at most half the influences of the one before. "
              "Seconds: least (median) over the repeats, wall and CPU (this process); the load average (1 min) "
              "before and after shows how much of the wall time other work on the machine took. Peak MB: resident "
              "memory growth of the first run (VmHWM).", "",
              "| case | vertices / triangles / influences | levels (triangles) | path | wall s | CPU s | peak MB | "
              "load | target |", "|---|---|---|---|---|---|---|---|---|"]
    for name, row in speed.items():
        paths = [("one run of the queue (sk_simplify_chain)", row["one_run"])]
        if "level_by_level" in row:
            paths.append(("level by level (one sk_simplify per level)", row["level_by_level"]))
        target = f"< {row['target_seconds']:g} s" + (f", < {row['target_mb']:g} MB" if "target_mb" in row else "")
        for label, u in paths:
            lines.append(f"| {name} | {row['vertices']} / {row['triangles']} / {row['influences']} | "
                         f"{', '.join(map(str, row['level_triangles']))} | {label} | {u['wall_min']:.3f} "
                         f"({u['wall_median']:.3f}) | {u['cpu_min']:.3f} ({u['cpu_median']:.3f}) | {u['peak_mb']:.1f} | "
                         f"{u['load_before']:.1f} / {u['load_after']:.1f} | {target} |")
    return lines + [""]


def chain_results(names: list[str], data_folder: str, with_blender: bool) -> dict:
    results = {}
    for name in names:
        try:
            models = chain_models(name, data_folder)
        except MissingData as missing:
            print(f"chain {name}: skipped ({missing})", file=sys.stderr)
            results[name] = {"skipped": str(missing)}
            continue
        results[name] = compare_chains(models, with_blender)
        for row in results[name]["targets"][0]["to_full_detail"]:
            print(f"chain {name} level {row['level']} ({row['share']:.3f} of the influences): ratio {row['ratio']} "
                  f"(target {row['target']}), floor's ratio {row['floor_ratio']}", file=sys.stderr)
    return results


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=os.path.join(REPOSITORY, "..", "shared", "data"))
    parser.add_argument("--chain-datasets", default="horse,creature,arm,cow,dembones",
                        help="the chain's data sets ('' for none)")
    parser.add_argument("--no-blender-decimate", action="store_true", help="leave out the Decimate peer")
    parser.add_argument("--no-speed", action="store_true", help="leave out the speed and scale runs")
    parser.add_argument("--skinkit-variants", help="the SKINKIT_VARIANTS to run, as indices (0 and 1, held to "
                                                   "the targets, always run), e.g. 0,1,5,6; default all")
    parser.add_argument("--plot", default=os.path.join(REPOSITORY, "docs", "images", "lod_chain_error.png"))
    parser.add_argument("--json")
    parser.add_argument("--markdown")
    arguments = parser.parse_args(argv)
    if arguments.skinkit_variants:
        global SKINKIT_VARIANTS
        chosen = sorted({*range(TARGET_VARIANTS), *(int(index) for index in arguments.skinkit_variants.split(","))})
        SKINKIT_VARIANTS = tuple(SKINKIT_VARIANTS[index] for index in chosen)
    speedup_before = parallel_speedup()
    results = {"chain": chain_results([n for n in arguments.chain_datasets.split(",") if n], arguments.data,
                                      not arguments.no_blender_decimate),
               "speed": {} if arguments.no_speed else speed_results(arguments.data)}
    if results["chain"] and arguments.plot:
        chain_plot(results, arguments.plot)
    return finish_run(results, arguments, markdown, speedup_before)


if __name__ == "__main__":
    sys.exit(main())
