"""Skinning decomposition from a mesh animation alone: skinkit's decompose vs Dem Bones, side by side.

    cd /work/main && .venv/bin/python bench/bench_decompose.py [--data ../shared/data] \
        [--datasets horse,dembones,cow] [--bones N] [--max-influences K] \
        [--json bench/decompose_results.json] [--markdown bench/decompose_results.md]

Data (bench/decompose_data.py): the horse (train on reference.obj + poses/01..10, the thesis' 11 poses; the
48-frame gallop held out), the Dem Bones sample (Bone_Geom.fbx rest, Bone_Anim.abc; first 2/3 of the frames
train, the rest held out) and libigl's cow-gt (rest + poses 1..5 train, poses 6 and 7 held out). A set
whose files are missing is skipped and the report says so.

Both methods get the same training frames, rest mesh, bone count N and at most K influences per vertex:
  Dem Bones (py-dem-bones, DemBones in float64): nB = N, nnz = K, every other parameter at its documented
  default (nIters 30, nInitIters 10, nTransIters 5, transAffine 10, transAffineNorm 4, nWeightsIters 3,
  weightsSmooth 1e-4, weightsSmoothStep 1). Two runs: from its own clustering (LBG-VQ; it grows one seed
  region per bone, and when a new bone's region swallows an old bone's seed the old bone is pruned, so it
  can end with fewer than N bones: on the horse's 11 poses it ends with 1), and from a rigid binding to
  N k-means clusters of the vertex trajectories (given as its initial weights; the clustering's time is
  counted). The targets use the run with the lower training error. Training error: its own transforms. Held-out frames: a second solver with its weights set and fixed (nWeightsIters = 0) and no
  transforms, so init() starts every bone at the identity and compute() runs only its transform updates
  (30 x 5 rigid-transform sweeps); the result is linear blend skinning with those transforms.
  skinkit: decompose(train, triangles, bone_count=N, max_influences=K, rest, threads=0), then
  result.reconstruct(frames, kind) for training and held-out frames alike (the bone transforms solved per
  frame with the model fixed), for the animation-space model and for its linear-blend weights.

Errors: per-vertex distance to the target; rms and max over vertices and frames, divided by the rest
bounding-box diagonal; and as in the thesis' Table 8.2, mean and max with the rest mesh scaled to a unit
box (largest side 1), over all frames and over the held-out ones. Seconds: wall clock of one decomposition
(Dem Bones: setting its inputs and compute(); skinkit: the decompose call). Peak MB: growth of the
process's resident high-water mark (VmHWM, reset before each call, after handing freed heap pages back to
the system), so C allocations count.
"""
from __future__ import annotations

import argparse
import ctypes
import os
import sys
import time

import numpy as np

from skinkit.decompose import decompose

from bench_fit import measured
from common import machine_info, machine_line, parallel_speedup, write_outputs
from datasets import farthest_point_centres
from decompose_data import LOADERS, MissingData

REPOSITORY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_MAX_INFLUENCES = 4
#: Thesis Table 8.2 (horse, 11 training poses, 25 bones, errors over all poses incl. the gallop, model in a
#: unit box; the thesis states no unit).
THESIS_TABLE_8_2 = {"skinkit animation space": {"mean": 0.73e-3, "max": 53.3e-3},
                    "skinkit linear blend": {"mean": 1.17e-3, "max": 68.7e-3}}
#: Target: skinkit's animation-space training rms at most this times Dem Bones'.
TRAINING_RATIO_TARGET = 0.7
ANIMATION, LINEAR = "skinkit animation space", "skinkit linear blend"
DEM_BONES, DEM_BONES_CLUSTERED = "Dem Bones", "Dem Bones, k-means start"


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def measured_once(function) -> tuple[object, dict]:
    """function()'s result, its wall seconds and peak memory growth (bench_fit.measured, one run). Every
    method runs in this one process, so the heap pages earlier runs freed are first handed back to the
    system (glibc's malloc_trim); otherwise a run reusing them would show no growth."""
    ctypes.CDLL("libc.so.6").malloc_trim(0)
    return measured(function, 1)


# ---- Dem Bones ------------------------------------------------------------------------------------------

def dem_bones_solver(rest: np.ndarray, triangles: np.ndarray, frames: np.ndarray, bone_count: int,
                     max_influences: int):
    """A DemBones (float64) holding one subject: rest `u` (3, V), frames `v` (3F, V), the mesh, nB, nnz."""
    from py_dem_bones._py_dem_bones import DemBones

    count, vertices = frames.shape[:2]
    solver = DemBones()
    solver.nV, solver.nF, solver.nS, solver.nB, solver.nnz = vertices, count, 1, bone_count, max_influences
    solver.fStart = np.array([0, count], np.int32)
    solver.subjectID = np.zeros(count, np.int32)
    solver.u = np.ascontiguousarray(rest.T)
    solver.v = np.ascontiguousarray(frames.transpose(0, 2, 1).reshape(3 * count, vertices))
    solver.fv = triangles.tolist()  # its weight smoothing needs the mesh
    return solver


def dem_bones_transforms(solver) -> np.ndarray:
    """Its m (4F, 4B), block (k, j) bone j's rest-to-frame-k transform, as (F, B, 4, 4)."""
    m = np.asarray(solver.m)
    return m.reshape(solver.nF, 4, solver.nB, 4).transpose(0, 2, 1, 3)


def trajectory_clusters(frames: np.ndarray, bone_count: int) -> np.ndarray:
    """(N', V) one-hot weights: each vertex bound to one of up to bone_count k-means clusters of the vertex
    trajectories (positions over the training frames), deterministic (datasets.farthest_point_centres)."""
    trajectories = frames.transpose(1, 0, 2).reshape(frames.shape[1], -1)
    centres = farthest_point_centres(trajectories, bone_count)
    labels = np.argmin(((trajectories[:, None] - centres[None]) ** 2).sum(axis=2), axis=1)
    return (np.unique(labels)[:, None] == labels[None]).astype(np.float64)


def dem_bones_decompose(rest, triangles, frames, bone_count: int, max_influences: int, clustered_start: bool) -> dict:
    """Dem Bones' decomposition; clustered_start: from trajectory_clusters' rigid binding instead of its own
    clustering (with w given and m empty, init() starts every transform at the identity and compute()'s first
    transform update fits each cluster's rigid motion)."""
    solver = dem_bones_solver(rest, triangles, frames, bone_count, max_influences)
    if clustered_start:
        start = trajectory_clusters(frames, bone_count)
        solver.nB = len(start)
        solver.set_weights(start)
    solver.compute()
    return {"weights": np.asarray(solver.get_weights()), "transforms": dem_bones_transforms(solver),
            "rmse": solver.rmse(), "parameters": dem_bones_parameters(solver)}


def dem_bones_parameters(solver) -> dict:
    names = ("nB", "nnz", "nIters", "nInitIters", "nTransIters", "transAffine", "transAffineNorm", "nWeightsIters",
             "weightsSmooth", "weightsSmoothStep", "weightEps")
    return {name: getattr(solver, name) for name in names}


def dem_bones_fixed_weights(rest, triangles, weights: np.ndarray, targets: np.ndarray, max_influences: int):
    """Dem Bones' bone transforms (G, B, 4, 4) for `targets` with its weights (B, V) held: with w set and m
    empty, init() sets every transform to the identity; nWeightsIters = 0 turns the weight updates off."""
    solver = dem_bones_solver(rest, triangles, targets, len(weights), max_influences)
    solver.set_weights(weights)
    solver.nWeightsIters = 0
    solver.compute()
    return dem_bones_transforms(solver)


def linear_blend(rest: np.ndarray, weights: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """(G, V, 3): each vertex moved by its weights' blend of the bone transforms; weights (B, V)."""
    frames = []
    for matrices in transforms:  # (B, 4, 4) per frame: B moved copies of the mesh at a time, not G * B
        moved = np.einsum("bij,vj->bvi", matrices[:, :3, :3], rest) + matrices[:, None, :3, 3]
        frames.append(np.einsum("bv,bvi->vi", weights, moved))
    return np.stack(frames)


def run_dem_bones(dataset, bone_count: int, max_influences: int, clustered_start: bool) -> dict:
    rest, triangles = dataset.rest, dataset.triangles
    solved, usage = measured_once(lambda: dem_bones_decompose(rest, triangles, dataset.train, bone_count,
                                                              max_influences, clustered_start))
    weights = solved["weights"]
    started = time.perf_counter()
    held_out = linear_blend(rest, weights, dem_bones_fixed_weights(rest, triangles, weights, dataset.held_out,
                                                                   max_influences))
    held_out_seconds = time.perf_counter() - started
    # The held-out solve applied to the training frames: how far it is from Dem Bones' own transforms.
    train_resolved = linear_blend(rest, weights, dem_bones_fixed_weights(rest, triangles, weights, dataset.train,
                                                                         max_influences))
    return {"method": DEM_BONES_CLUSTERED if clustered_start else DEM_BONES, "bones_used": int(len(weights)),
            "influences_max": int((weights > 0).sum(axis=0).max()),
            "seconds": usage["seconds_all"][0], "peak_mb": usage["peak_mb"], "held_out_solve_seconds": held_out_seconds,
            "train_positions": linear_blend(rest, weights, solved["transforms"]), "held_out_positions": held_out,
            "report": {"rmse": solved["rmse"], "parameters": solved["parameters"],
                       "train_rms_with_held_out_solve": errors(train_resolved, dataset.train, dataset.rest)["rms"]}}


# ---- skinkit --------------------------------------------------------------------------------------------

def run_skinkit(dataset, bone_count: int, max_influences: int) -> list[dict]:
    result, usage = measured_once(lambda: decompose(dataset.train, dataset.triangles, bone_count=bone_count,
                                                    max_influences=max_influences, rest=dataset.rest, threads=0))
    rows = []
    for label, kind, pattern in ((ANIMATION, "animation", result.model), (LINEAR, "linear", result.linear_blend)):
        started = time.perf_counter()
        held_out = result.reconstruct(dataset.held_out, kind=kind)
        held_out_seconds = time.perf_counter() - started
        rows.append({"method": label, "bones_used": int(result.training_poses.shape[1]) - 1,  # not the static root
                     "influences_max": int(pattern.counts().max()), "seconds": usage["seconds_all"][0],
                     "peak_mb": usage["peak_mb"], "held_out_solve_seconds": held_out_seconds,
                     "train_positions": result.reconstruct(dataset.train, kind=kind), "held_out_positions": held_out,
                     "report": {"decompose_seconds": result.seconds} | result.report})
    return rows


# ---- errors and targets ---------------------------------------------------------------------------------

def errors(predicted: np.ndarray, targets: np.ndarray, rest: np.ndarray) -> dict:
    """rms and max distance / rest bounding-box diagonal."""
    distance = np.linalg.norm(predicted - targets, axis=2)
    diagonal = np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))
    return {"rms": float(np.sqrt((distance ** 2).mean()) / diagonal), "max": float(distance.max() / diagonal)}


def unit_box_errors(predicted: np.ndarray, targets: np.ndarray, rest: np.ndarray) -> dict:
    """Table 8.2's form: mean and max distance with the rest mesh scaled to a unit box (largest side 1)."""
    distance = np.linalg.norm(predicted - targets, axis=2)
    side = (rest.max(axis=0) - rest.min(axis=0)).max()
    return {"mean": float(distance.mean() / side), "max": float(distance.max() / side)}


def measured_row(dataset, row: dict) -> dict:
    """The row with its positions replaced by their errors."""
    train, held_out = row.pop("train_positions"), row.pop("held_out_positions")
    every_frame = np.concatenate([dataset.train, dataset.held_out])
    return row | {"train": errors(train, dataset.train, dataset.rest),
                  "held_out": errors(held_out, dataset.held_out, dataset.rest),
                  "unit_box_all_frames": unit_box_errors(np.concatenate([train, held_out]), every_frame, dataset.rest),
                  "unit_box_held_out": unit_box_errors(held_out, dataset.held_out, dataset.rest)}


def dem_bones_baseline(rows: dict) -> dict:
    """The Dem Bones run with the lower training error (chosen without the held-out frames)."""
    return min((rows[DEM_BONES], rows[DEM_BONES_CLUSTERED]), key=lambda row: row["train"]["rms"])


def targets(name: str, rows: dict) -> dict:
    """Issue 4's targets against the better Dem Bones run: name -> {"met", "numbers"}."""
    ours, theirs = rows[ANIMATION], dem_bones_baseline(rows)
    ratio = ours["train"]["rms"] / theirs["train"]["rms"]
    found = {
        f"training rms: animation space <= {TRAINING_RATIO_TARGET} x Dem Bones": {
            "met": ratio <= TRAINING_RATIO_TARGET, "numbers": {"ratio": ratio, ANIMATION: ours["train"]["rms"],
                                                               theirs["method"]: theirs["train"]["rms"]}},
        "held-out rms: animation space < Dem Bones": {
            "met": ours["held_out"]["rms"] < theirs["held_out"]["rms"],
            "numbers": {ANIMATION: ours["held_out"]["rms"], theirs["method"]: theirs["held_out"]["rms"]}},
        "seconds: skinkit <= Dem Bones": {
            "met": ours["seconds"] <= theirs["seconds"],
            "numbers": {"skinkit": ours["seconds"], theirs["method"]: theirs["seconds"]}}}
    if name == "horse":
        for label, thesis in THESIS_TABLE_8_2.items():
            measured_here = rows[label]["unit_box_all_frames"]
            found[f"{label} vs thesis Table 8.2 (all frames, mean and max)"] = {
                "met": all(measured_here[key] <= thesis[key] for key in ("mean", "max")),
                "numbers": {"mean": measured_here["mean"], "thesis mean": thesis["mean"],
                            "max": measured_here["max"], "thesis max": thesis["max"]}}
    return found


# ---- running --------------------------------------------------------------------------------------------

def benchmark_dataset(dataset, bone_count: int, max_influences: int) -> dict:
    load_before = os.getloadavg()
    log(f"{dataset.name}: Dem Bones, {bone_count} bones, at most {max_influences} influences")
    raw = [run_dem_bones(dataset, bone_count, max_influences, clustered_start) for clustered_start in (False, True)]
    log(f"{dataset.name}: skinkit")
    raw += run_skinkit(dataset, bone_count, max_influences)
    rows = [measured_row(dataset, row) for row in raw]
    by_method = {row["method"]: row for row in rows}
    return {"name": dataset.name, "split": dataset.split, "unit": dataset.unit, "notes": dataset.notes,
            "vertices": len(dataset.rest), "triangles": len(dataset.triangles), "bones": bone_count,
            "max_influences": max_influences, "train_frames": len(dataset.train),
            "held_out_frames": len(dataset.held_out), "load_average_before": load_before,
            "load_average_after": os.getloadavg(), "rows": rows, "targets": targets(dataset.name, by_method)}


def load(name: str, data: str):
    from skinkit.cli import stdout_to_stderr

    with stdout_to_stderr(True):  # Blender's importers print from C
        return LOADERS[name](data)


def run(arguments) -> dict:
    import py_dem_bones
    from py_dem_bones import _py_dem_bones

    names = arguments.datasets.split(",")
    unknown = [n for n in names if n not in LOADERS]
    if unknown:
        raise SystemExit(f"unknown data sets {unknown}; known: {', '.join(LOADERS)}")
    speedup_before = parallel_speedup()
    results, skipped = [], []
    for name in names:
        try:
            dataset = load(name, arguments.data)
        except MissingData as missing:
            skipped.append(f"{name}: skipped, {missing} (the shared benchmark data is not on this machine)")
            log(skipped[-1])
            continue
        results.append(benchmark_dataset(dataset, arguments.bones or dataset.bone_count, arguments.max_influences))
    info = machine_info() | {"py_dem_bones": py_dem_bones.__version__,
                             "dem_bones": _py_dem_bones.__dem_bones_version__,
                             "parallel_speedup_before": speedup_before, "parallel_speedup_after": parallel_speedup()}
    return {"info": info, "thesis_table_8_2": THESIS_TABLE_8_2, "skipped": skipped, "datasets": results}


# ---- reports --------------------------------------------------------------------------------------------

def pair(values: dict, first: str, second: str) -> str:
    return f"{values[first]:.2e} / {values[second]:.2e}"


def dataset_section(result: dict) -> list[str]:
    lines = ["", f"## {result['name']}", "",
             f"{result['vertices']} vertices, N = {result['bones']} bones, K = {result['max_influences']}; "
             f"{result['split']}; unit: {result['unit']}. 1-minute load average {result['load_average_before'][0]:.1f} "
             f"before, {result['load_average_after'][0]:.1f} after.", ""]
    lines += [f"- {note}" for note in result["notes"]]
    lines += ["", "| method | bones | max infl. | seconds | peak MB | train rms / max | held-out rms / max | "
                  "unit box, all frames: mean / max | unit box, held out: mean / max | held-out solve s |",
              "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in result["rows"]:
        lines.append(f"| {r['method']} | {r['bones_used']} | {r['influences_max']} | {r['seconds']:.2f} | "
                     f"{r['peak_mb']:.1f} | {pair(r['train'], 'rms', 'max')} | {pair(r['held_out'], 'rms', 'max')} | "
                     f"{pair(r['unit_box_all_frames'], 'mean', 'max')} | {pair(r['unit_box_held_out'], 'mean', 'max')} "
                     f"| {r['held_out_solve_seconds']:.2f} |")
    resolved = "; ".join(f"{r['method']}: {r['report']['train_rms_with_held_out_solve']:.2e} vs {r['train']['rms']:.2e}"
                         for r in result["rows"] if r["method"] in (DEM_BONES, DEM_BONES_CLUSTERED))
    lines += ["", "Dem Bones' held-out solve (weights fixed, transforms from the identity) applied to the training "
                  f"frames, rms vs its own transforms': {resolved}.", "",
              "Targets compare with the Dem Bones run of lower training error.", "",
              "| target | met | numbers |", "|---|---|---|"]
    for name, target in result["targets"].items():
        shown = ", ".join(f"{k}: {v:.3g}" for k, v in target["numbers"].items())
        lines.append(f"| {name} | {'yes' if target['met'] else 'NO'} | {shown} |")
    return lines


def table_8_2(result: dict) -> list[str]:
    """The horse in the form of the thesis' Table 8.2, our numbers beside the thesis'."""
    rows = {r["method"]: r for r in result["rows"]}
    every_count = result["train_frames"] + result["held_out_frames"]
    lines = ["", "### Horse in the form of thesis Table 8.2", "",
             "Distances with the rest mesh (reference.obj) scaled to a unit box (largest side 1). Thesis: 11 "
             "training poses, 25 bones, over all poses (its unit is not stated).", "",
             f"| | mean, all {every_count} frames | max, all {every_count} frames | mean, gallop | max, gallop | "
             "thesis mean | thesis max |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for label in (ANIMATION, LINEAR, DEM_BONES, DEM_BONES_CLUSTERED):
        every, gallop = rows[label]["unit_box_all_frames"], rows[label]["unit_box_held_out"]
        thesis = THESIS_TABLE_8_2.get(label)
        quoted = f"{thesis['mean'] * 1e3:.2f}e-3 | {thesis['max'] * 1e3:.1f}e-3" if thesis else "|"
        lines.append(f"| {label} | {every['mean'] * 1e3:.2f}e-3 | {every['max'] * 1e3:.1f}e-3 | "
                     f"{gallop['mean'] * 1e3:.2f}e-3 | {gallop['max'] * 1e3:.1f}e-3 | {quoted} |")
    return lines


def markdown_report(results: dict) -> str:
    info = results["info"]
    lines = ["# Skinning decomposition: skinkit decompose vs Dem Bones", "",
             f"{machine_line(info)}: below 2 when other work shares the cores, and the "
             f"seconds are then noisy) · bpy {info['bpy']} · numpy {info['numpy']} · "
             f"skinkit {info['skinkit']} · py-dem-bones {info['py_dem_bones']} (Dem Bones {info['dem_bones']})", "",
             f"`{info['command']}`", "",
             "Both methods see only the training frames, with the same bone count N and at most K influences per "
             "vertex. Dem Bones: documented defaults besides nB = N and nnz = K, once from its own clustering "
             "(which can prune bones down to fewer than N) and once from a rigid binding to N k-means clusters "
             "of the vertex trajectories (clustering time included); its held-out frames are "
             "solved with its weights fixed (nWeightsIters = 0, transforms started at the identity) and skinned "
             "linearly. skinkit: `decompose`, then `reconstruct` on training and held-out frames alike; its bone "
             "count leaves out the static root bone 0 every skinkit skeleton has. Errors: "
             "vertex distance / rest bounding-box diagonal (rms / max over vertices and frames), and in Table 8.2's "
             "form with the rest mesh in a unit box (mean / max). Seconds: one decomposition, wall clock, both "
             "using every core; peak MB: growth of the process's resident high-water mark during it. Held-out "
             "solve: seconds to solve and evaluate the held-out frames with the model fixed."]
    for skipped in results["skipped"]:
        lines += ["", f"*{skipped}*"]
    for result in results["datasets"]:
        lines += dataset_section(result)
        if result["name"] == "horse":
            lines += table_8_2(result)
    return "\n".join(lines) + "\n"


def print_summary(results: dict) -> None:
    for skipped in results["skipped"]:
        print(skipped)
    for result in results["datasets"]:
        print(f"\n{result['name']}: {result['vertices']} vertices, N = {result['bones']}, K = {result['max_influences']}")
        for r in result["rows"]:
            print(f"  {r['method']:<24} {r['seconds']:7.2f} s  {r['peak_mb']:7.1f} MB  train rms {r['train']['rms']:.2e}"
                  f"  held-out rms {r['held_out']['rms']:.2e}  unit box all mean {r['unit_box_all_frames']['mean']:.2e}"
                  f" max {r['unit_box_all_frames']['max']:.2e}")
        for name, target in result["targets"].items():
            print(f"  {'met ' if target['met'] else 'MISS'} {name}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", default=os.path.join(os.path.dirname(REPOSITORY), "shared", "data"))
    parser.add_argument("--datasets", default="horse,dembones,cow", help="comma-separated: horse, dembones, cow")
    parser.add_argument("--bones", type=int, help="N for every set (default: horse 25, dembones its rig's, cow 15)")
    parser.add_argument("--max-influences", type=int, default=DEFAULT_MAX_INFLUENCES)
    parser.add_argument("--json", default=os.path.join(REPOSITORY, "bench", "decompose_results.json"))
    parser.add_argument("--markdown", default=os.path.join(REPOSITORY, "bench", "decompose_results.md"))
    arguments = parser.parse_args()
    results = run(arguments)
    write_outputs(results, arguments.json, arguments.markdown, markdown_report)
    print_summary(results)


if __name__ == "__main__":
    main()
