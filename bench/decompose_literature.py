"""Decomposition at the literature's standard setting, and the whole `skinkit decompose` command against Dem Bones.

    cd /work/main && .venv/bin/python bench/decompose_literature.py [--data ../shared/data] [--bones 10,20,30] \
        [--json bench/decompose_literature_results.json] [--markdown bench/decompose_literature_results.md]

Data: the horse gallop (horse/gallop/0001..0048.obj, 8431 vertices, 48 frames), every frame trained, the first
frame as the rest pose: the setting of the rigid and affine bones papers (SSD with affine bones, hyperspectral
inverse skinning), which report E_RMS = 1000 x RMS / (diagonal / 2), RMS over all vertex coordinates of all
frames, diagonal: the rest pose's bounding box.

For each bone count N, in one run, at most K influences per vertex for both:
  skinkit command: `python -m skinkit.cli decompose --sequence gallop --bones N --max-influences K
    --export-frames DIR --json` in a child process, wall clock from start to exit (interpreter start, imports,
    reading the 48 OBJ files, the solve, the replay, writing 48 OBJ files); its E_RMS from the frames it wrote.
  skinkit API: decompose(frames, triangles, bone_count=N, max_influences=K), then reconstruct(frames, kind) for
    the animation-space model and for its linear-blend weights: E_RMS of both.
  Dem Bones (py-dem-bones, float64, every parameter at its default, its own clustering, nB = N, nnz = K): the
    seconds of compute() alone (no I/O), E_RMS of its linear blend skinning with its own transforms.
The Dem Bones sample (dembones/Bone_Anim.abc, 754 vertices, Bone_Geom.fbx its rest; bench/decompose_data.py) at its
rig's bone count, every frame trained: the whole command (`--sequence Bone_Anim.abc --rest Bone_Geom.fbx
--sequence-scale 0.01`, Blender started to read the .abc and the .fbx) against Dem Bones' compute() alone on
the same frames.
A missing data folder is skipped with a message.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from skinkit.decompose import decompose
from skinkit.meshio import read_obj_sequence, sequence_files

from bench_decompose import dem_bones_decompose, linear_blend
from common import machine_info, machine_line, parallel_speedup, write_outputs

REPOSITORY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MAX_INFLUENCES = 4
#: E_RMS on the horse gallop (48 frames) as the papers report it, per bone count.
PUBLISHED = {10: {"SSD with affine bones": 5.65, "hyperspectral inverse skinning": 4.54},
             20: {"SSD with affine bones": 2.80, "hyperspectral inverse skinning": 1.16},
             30: {"SSD with affine bones": 1.76, "hyperspectral inverse skinning": 0.45}}


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def e_rms(predicted: np.ndarray, frames: np.ndarray) -> float:
    """1000 x RMS over all vertex coordinates / (rest bounding-box diagonal / 2); the rest pose is frame 0."""
    rest = frames[0]
    diagonal = np.linalg.norm(rest.max(axis=0) - rest.min(axis=0))
    return float(1000.0 * np.sqrt(((predicted - frames) ** 2).mean()) / (diagonal / 2.0))


def load_average() -> float:
    return os.getloadavg()[0]


def run_command(folder: str, bone_count: int, frames: np.ndarray | None, *extra: str) -> dict:
    """The whole command in a child process: its wall seconds, its own report and (given the frames it should
    reproduce) the E_RMS of what it wrote."""
    with tempfile.TemporaryDirectory() as output:
        command = [sys.executable, "-m", "skinkit.cli", "decompose", "--sequence", folder, "--bones", str(bone_count),
                   "--max-influences", str(MAX_INFLUENCES), "--export-frames", output, "--json", *extra]
        started = time.perf_counter()
        finished = subprocess.run(command, capture_output=True, text=True, check=False)
        seconds = time.perf_counter() - started
        if finished.returncode != 0:
            raise RuntimeError(f"{' '.join(command)} failed: {finished.stdout}{finished.stderr}")
        report = json.loads(finished.stdout)
        written = read_obj_sequence(sequence_files(output))[0] if frames is not None else None
    return {"seconds": seconds, "decompose_seconds": report["decompose_seconds"],
            "in_process_seconds": report["seconds"],
            "frames": report["frames"], "train_rms": report["animation_space"]["train"]["rms"],
            "e_rms_animation": e_rms(written, frames) if frames is not None else None}


def dem_bones_sample_row(data: str) -> dict | None:
    """The Dem Bones sample: the whole command against Dem Bones' solve on the same frames, at the rig's bone
    count; None when the data is missing."""
    from decompose_data import MissingData, dem_bones_sample
    from skinkit.cli import stdout_to_stderr

    try:
        with stdout_to_stderr(True):  # Blender's importers print from C
            dataset = dem_bones_sample(data)
    except MissingData as missing:
        log(f"skipped the Dem Bones sample: {missing}")
        return None
    folder = os.path.join(data, "dembones")
    bone_count = dataset.bone_count
    load_before = load_average()
    log(f"Dem Bones sample, {bone_count} bones: the skinkit command")
    command = run_command(os.path.join(folder, "Bone_Anim.abc"), bone_count, None, "--rest",
                          os.path.join(folder, "Bone_Geom.fbx"), "--sequence-scale", "0.01")
    log(f"Dem Bones sample, {bone_count} bones: Dem Bones")
    frames = np.concatenate([dataset.rest[None], dataset.train, dataset.held_out])
    dem_bones = run_dem_bones(frames, dataset.triangles, bone_count)
    return {"bones": bone_count, "vertices": int(frames.shape[1]), "command": command, "dem_bones": dem_bones,
            "load_before": load_before, "load_after": load_average()}


def run_api(frames: np.ndarray, triangles: np.ndarray, bone_count: int) -> dict:
    started = time.perf_counter()
    result = decompose(frames, triangles, bone_count=bone_count, max_influences=MAX_INFLUENCES, rest=frames[0])
    seconds = time.perf_counter() - started
    return {"seconds": seconds,
            "e_rms_animation": e_rms(result.reconstruct(frames, kind="animation"), frames),
            "e_rms_linear": e_rms(result.reconstruct(frames, kind="linear"), frames)}


def run_dem_bones(frames: np.ndarray, triangles: np.ndarray, bone_count: int) -> dict:
    started = time.perf_counter()
    solved = dem_bones_decompose(frames[0], triangles, frames, bone_count, MAX_INFLUENCES, clustered_start=False)
    seconds = time.perf_counter() - started
    predicted = linear_blend(frames[0], solved["weights"], solved["transforms"])
    return {"seconds": seconds, "bones_used": int(len(solved["weights"])), "e_rms_linear": e_rms(predicted, frames)}


def run(arguments) -> dict:
    import py_dem_bones

    folder = os.path.join(arguments.data, "horse", "gallop")
    info = machine_info() | {"py_dem_bones": py_dem_bones.__version__, "parallel_speedup_before": parallel_speedup()}
    sample = dem_bones_sample_row(arguments.data) if "dembones" in arguments.datasets else None
    rows, skipped, frames = [], None, np.zeros((0, 0, 3))
    if not os.path.isdir(folder):
        skipped = f"{folder} is missing (the horse gallop; see bench/datasets.py)"
        log(f"skipped: {skipped}")
    else:
        frames, triangles = read_obj_sequence(sequence_files(folder))
        for bone_count in arguments.bones if "horse" in arguments.datasets else ():
            load_before = load_average()
            log(f"{bone_count} bones: the skinkit command")
            command = run_command(folder, bone_count, frames)
            log(f"{bone_count} bones: Dem Bones")
            dem_bones = run_dem_bones(frames, triangles, bone_count)
            log(f"{bone_count} bones: the skinkit API")
            api = run_api(frames, triangles, bone_count)
            rows.append({"bones": bone_count, "command": command, "api": api, "dem_bones": dem_bones,
                         "published": PUBLISHED.get(bone_count, {}), "load_before": load_before,
                         "load_after": load_average()})
            log(json.dumps(rows[-1]))
    info["parallel_speedup_after"] = parallel_speedup()
    return {"machine": info, "skipped": skipped, "vertices": int(frames.shape[1]), "frames": int(frames.shape[0]),
            "max_influences": MAX_INFLUENCES, "rows": rows, "dem_bones_sample": sample,
            "command": "python bench/decompose_literature.py " + " ".join(sys.argv[1:])}


def markdown_report(results: dict) -> str:
    info = results["machine"]
    lines = ["# Decomposition at the literature's setting: horse gallop, E_RMS, and the whole command vs Dem Bones", "",
             f"{machine_line(info)}) · py-dem-bones {info['py_dem_bones']}", ""]
    if results["skipped"]:
        lines += [f"Skipped the horse: {results['skipped']}.", ""]
    if results["rows"]:
        lines += [f"horse/gallop/0001..0048.obj: {results['vertices']} vertices, {results['frames']} frames, all "
                  f"trained, frame 1 the rest pose; K = {results['max_influences']} influences. "
                  "E_RMS = 1000 x RMS / (diagonal / 2).", "",
                  "| bones | skinkit animation space | skinkit linear blend | Dem Bones | best published | "
                  "`skinkit decompose` command s | its solve s | Dem Bones solve s | command / Dem Bones | load avg |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for row in results["rows"]:
            best = min(row["published"].values()) if row["published"] else float("nan")
            command, dem_bones, api = row["command"], row["dem_bones"], row["api"]
            lines.append(f"| {row['bones']} | **{command['e_rms_animation']:.3f}** "
                         f"(API {api['e_rms_animation']:.3f}) | {api['e_rms_linear']:.3f} | "
                         f"{dem_bones['e_rms_linear']:.3f} ({dem_bones['bones_used']} bones) | "
                         f"{best:.2f} | {command['seconds']:.2f} | {command['decompose_seconds']:.2f} | "
                         f"{dem_bones['seconds']:.2f} | **{command['seconds'] / dem_bones['seconds']:.2f}** | "
                         f"{row['load_before']:.1f} / {row['load_after']:.1f} |")
    sample = results.get("dem_bones_sample")
    if sample:
        command, dem_bones = sample["command"], sample["dem_bones"]
        ratio = command["seconds"] / dem_bones["seconds"]
        lines += ["", f"Dem Bones sample (Bone_Anim.abc, {sample['vertices']} vertices, {command['frames']} frames "
                  f"with the rest, {sample['bones']} bones, all trained): the `skinkit decompose` command (Blender "
                  f"started for the .abc and .fbx) {command['seconds']:.2f} s (its solve "
                  f"{command['decompose_seconds']:.2f} s), Dem Bones' solve alone {dem_bones['seconds']:.2f} s: "
                  f"**{ratio:.2f}x**; load average {sample['load_before']:.1f} / {sample['load_after']:.1f}."]
    lines += ["", "Published (horse gallop, 48 frames): " + "; ".join(
        f"{bones} bones: " + ", ".join(f"{name} {value}" for name, value in methods.items())
        for bones, methods in PUBLISHED.items()), "", f"Command: `{results['command']}`", ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", default=os.path.join(REPOSITORY, "..", "shared", "data"))
    parser.add_argument("--bones", default="10,20,30", type=lambda text: [int(part) for part in text.split(",")])
    parser.add_argument("--datasets", default="horse,dembones", type=lambda text: text.split(","))
    parser.add_argument("--json")
    parser.add_argument("--markdown")
    arguments = parser.parse_args()
    results = run(arguments)
    write_outputs(results, arguments.json, arguments.markdown, markdown_report)
    print(markdown_report(results))


if __name__ == "__main__":
    main()
