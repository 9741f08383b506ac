"""How skinkit scales: the synthetic 100-bone, 8-influence creature (scripts/make_large_character.py) at 10k to
1M vertices through every offline stage, seconds and peak memory of each.

    .venv/bin/python bench/bench_scale.py [--sizes 10000,30000,...] [--stages convert,...] [--timeout 600] \
        [--memory-limit 8G] [--json bench/scale_results.json] [--markdown bench/scale_results.md] \
        [--plot docs/images/scale.png] [--profile-sizes 300000]

Each stage of each size runs in its own child process (so each peak is its own): the child makes the character
(not timed), notes its resident-set high-water mark, runs the stage once and notes the high-water mark again.
Stages: convert (linear blend skinning to animation space), evaluate (the 24 poses, float32), fit (the
per-vertex animation-space fit to the 24 linear-blend examples, on the true influence sets), metrics (pose
statistics from the poses, then the L2,2 and L2,inf norms of every edge vector), decompose (25 frames: the
rest and the 24 examples; 100 bones, 8 influences), unwrap (segmentation, flattening, stretch optimisation,
packing), lod (skinkit.lod.build_chain, 4 levels, on the creature's own atlas) and bake (a 1024^2 tangent-space
normal map of the 10k creature from the creature at this size, by the shared atlas). One stage runs only when
named in --stages: rigid_poses, the rigid pose solve decompose repeats (skinkit._core.solve_rigid_poses, 4 sweeps
as its animation-space refit does) on the creature's own animation-space model (8 influences) and the 25 frames,
from the rest frames.

A stage that raises skinkit's memory-estimate error (the budget is --memory-limit, or free memory) is recorded
as "refused" with the message; one past --timeout seconds is killed and recorded as "timed out". Sizes run from
the smallest; a size's stages one at a time. The slope of each stage is the least-squares fit of log(seconds)
and log(peak) against log(vertices) over the sizes it finished.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPOSITORY = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(REPOSITORY, "scripts"))
import make_large_character  # noqa: E402

import skinkit  # noqa: E402
from common import machine_info, parallel_speedup, write_outputs  # noqa: E402

SIZES = (10_000, 30_000, 100_000, 300_000, 1_000_000)
STAGES = ("convert", "evaluate", "fit", "metrics", "decompose", "unwrap", "lod", "bake")
#: Stages that need the linear-blend examples (the 24 posed meshes); the others skip making them.
NEEDS_EXAMPLES = ("fit", "decompose", "rigid_poses")
BAKE_TARGET_VERTICES = 10_000
BAKE_SIZE = 1024
LOD_LEVELS = 4
DECOMPOSE_BONES = make_large_character.BONE_COUNT


# ---- the stages (in the child) ----------------------------------------------------------------------------------

def animation_model(c):
    return skinkit.convert_lbs(c["skeleton"], c["weights"], c["rest"])


def pose_statistics(c):
    from skinkit.metrics import PoseStatistics
    return PoseStatistics.from_world_samples(c["skeleton"].parents, c["poses"])


def prepare(stage: str, c: dict) -> dict:
    """What a stage needs besides the character, made before the clock starts."""
    if stage in ("evaluate", "metrics", "lod", "rigid_poses"):
        c["model"] = animation_model(c)
    if stage == "rigid_poses":
        c["frames"] = np.concatenate([c["rest"][None], c["examples"]])
        rest_frames = c["skeleton"].rest_frames
        c["start"] = np.ascontiguousarray(np.broadcast_to(rest_frames, (len(c["frames"]),) + rest_frames.shape))
    if stage == "lod":
        c["statistics"] = pose_statistics(c)
    if stage == "metrics":
        from skinkit.unwrap import unique_edges
        c["edges"] = unique_edges(c["triangles"])
    if stage == "bake":
        from skinkit import normal_maps
        low = make_large_character.make_character(BAKE_TARGET_VERTICES, with_examples=False)
        c["low"] = normal_maps.BakeSurface.from_arrays(low["triangles"], low["rest"], low["corner_uv"].reshape(-1, 3, 2),
                                                       name="low")
    return c


def run_stage(stage: str, c: dict) -> dict:
    """Runs one stage on the prepared character; returns a few facts about its result."""
    if stage == "convert":
        model = animation_model(c)
        return {"influences": int(model.influence_count)}
    if stage == "evaluate":
        posed = c["model"].evaluate(c["poses"], dtype=np.float32)
        return {"poses": len(posed)}
    if stage == "fit":
        from skinkit import fit
        result = fit.fit_animation_space(c["poses"], c["examples"], c["weights"], make_large_character.BONE_COUNT,
                                         method="per-vertex", rest_positions=c["rest"],
                                         rest_frames=c["skeleton"].rest_frames, validate=False)
        return {"influences": int(result.model.influence_count)}
    if stage == "metrics":
        from skinkit.metrics import SparseVectors
        statistics = pose_statistics(c)
        model, edges = c["model"], c["edges"]
        vectors = SparseVectors.rows(model, edges[:, 0]).combined(SparseVectors.rows(model, edges[:, 1]), -1.0)
        mean, most = statistics.mean_distance(vectors), statistics.max_distance(vectors)
        return {"edges": len(edges), "mean_edge": float(mean.mean()), "max_edge": float(most.max())}
    if stage == "decompose":
        from skinkit.decompose import decompose
        frames = np.concatenate([c["rest"][None], c["examples"]])
        result = decompose(frames, c["triangles"], bone_count=DECOMPOSE_BONES,
                           max_influences=make_large_character.MAX_INFLUENCES)
        return {"bones": int(result.skeleton.bone_count)}
    if stage == "rigid_poses":
        from skinkit.decompose import REFIT_SWEEPS
        model, poses = c["model"], c["start"].copy()
        frame_errors = np.empty(len(c["frames"]))
        skinkit._core.solve_rigid_poses(poses, model.offsets, model.bones, model.coordinates, c["frames"], frame_errors,
                                        len(c["frames"]), REFIT_SWEEPS, 0)
        return {"rms": float(np.sqrt(frame_errors.sum() / c["frames"][..., 0].size)),
                "poses_digest": hashlib.sha256(poses.tobytes()).hexdigest()[:16]}
    if stage == "unwrap":
        from skinkit.unwrap import unwrap
        result = unwrap(c["rest"], c["triangles"])
        return {"charts": int(result.report["charts"])}
    if stage == "lod":
        from skinkit import lod
        chain = lod.build_chain(c["triangles"], c["rest"], c["model"], c["statistics"], uv=c["corner_uv"],
                                charts=c["charts"], levels=LOD_LEVELS)
        return {"level_triangles": [int(len(level.triangles)) for level in chain.levels]}
    if stage == "bake":
        from skinkit import normal_maps
        high = normal_maps.BakeSurface.from_arrays(c["triangles"], c["rest"], c["corner_uv"].reshape(-1, 3, 2),
                                                   name="high")
        result = normal_maps.bake_normals(c["low"], high, size=BAKE_SIZE, mode="atlas")
        return {"size": int(result.image.shape[0])}
    raise ValueError(f"unknown stage {stage}")


def peak_rss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # Linux reports KiB


def cpu_seconds() -> float:
    """User and system time of this process, all its threads: what the stage cost on a loaded machine."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


PROFILE_ROWS = 12
#: Seconds past the timeout before the parent kills a child that has not stopped itself.
KILL_GRACE = 120


def profiled(stage: str, c: dict) -> tuple[dict, list]:
    """run_stage under cProfile on the process's CPU clock (all threads: a C call's workers count against the
    Python line that waits on them); the PROFILE_ROWS functions of most own CPU time, heaviest first."""
    import cProfile
    import pstats
    profiler = cProfile.Profile(time.process_time)
    try:
        detail = profiler.runcall(run_stage, stage, c)
    except StageTimeout:
        detail = None
    rows = []
    for (path, line, name), (_, calls, own, total, _) in pstats.Stats(profiler).stats.items():
        rows.append({"function": f"{os.path.relpath(path, REPOSITORY) if path.startswith('/') else path}:{line}({name})",
                     "calls": calls, "own_cpu": round(own, 3), "total_cpu": round(total, 3)})
    rows.sort(key=lambda row: -row["own_cpu"])
    if detail is None:
        raise StageTimeout(rows[:PROFILE_ROWS])
    return detail, rows[:PROFILE_ROWS]


class StageTimeout(Exception):
    """The child's own deadline passed (so a profiled stage still reports where its time went)."""


def on_deadline(signal_number, frame):
    raise StageTimeout


def child(stage: str, vertex_count: int, memory_limit: int | None, out_path: str, timeout: float,
          profile: bool = False) -> None:
    """Makes the character, runs one stage (under the profiler when asked), writes what happened as JSON to
    out_path. Past timeout seconds (inputs included) the stage is interrupted at its next Python line."""
    signal.signal(signal.SIGALRM, on_deadline)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    if memory_limit:
        skinkit.set_memory_limit(memory_limit)
    started = time.perf_counter()
    c = make_large_character.make_character(vertex_count, with_examples=stage in NEEDS_EXAMPLES)
    c = prepare(stage, c)
    made = time.perf_counter() - started
    baseline = peak_rss_bytes()
    record = {"vertices": len(c["rest"]), "triangles": len(c["triangles"]), "inputs_seconds": round(made, 3),
              "inputs_rss": baseline}
    started, cpu_started = time.perf_counter(), cpu_seconds()
    try:
        if profile:
            record["detail"], record["profile"] = profiled(stage, c)
        else:
            record["detail"] = run_stage(stage, c)
        record["status"] = "ok"
    except skinkit.SkinkitError as error:
        record["status"] = "refused" if "would need about" in str(error) else "failed"
        record["message"] = str(error)
    except StageTimeout as stopped:
        if stopped.args:
            record["profile"] = stopped.args[0]
        record["status"] = "timed out"
        record["message"] = f"stopped after {timeout:.0f} s (inputs included)"
    signal.setitimer(signal.ITIMER_REAL, 0)
    record["seconds"] = round(time.perf_counter() - started, 4)
    record["cpu_seconds"] = round(cpu_seconds() - cpu_started, 4)
    record["peak_rss"] = peak_rss_bytes()
    with open(out_path, "w") as stream:
        json.dump(record, stream)


# ---- the parent --------------------------------------------------------------------------------------------------

def run_child(stage: str, vertex_count: int, timeout: float, memory_limit: int | None, profile: bool) -> dict:
    with tempfile.TemporaryDirectory() as scratch:
        out_path = os.path.join(scratch, "result.json")
        command = [sys.executable, os.path.abspath(__file__), "--child", stage, str(vertex_count), out_path,
                   "--timeout", str(timeout)]
        if memory_limit:
            command += ["--memory-limit", str(memory_limit)]
        if profile:
            command += ["--profile-sizes", str(vertex_count)]
        started = time.perf_counter()
        try:
            # the child stops itself at the timeout; this kill is for a stage stuck inside one C call
            finished = subprocess.run(command, cwd=REPOSITORY, timeout=timeout + KILL_GRACE, capture_output=True,
                                      text=True)
        except subprocess.TimeoutExpired:
            return {"status": "timed out", "seconds": None,
                    "message": f"killed after {timeout + KILL_GRACE:.0f} s (inputs included)"}
        if finished.returncode != 0 or not os.path.exists(out_path):
            return {"status": "crashed", "seconds": None, "message": (finished.stderr or "")[-800:],
                    "returncode": finished.returncode, "wall": round(time.perf_counter() - started, 2)}
        with open(out_path) as stream:
            return json.load(stream)


def reason_to_skip(rows: list, vertex_count: int, timeout: float) -> str | None:
    """Why a stage need not run at this size: it timed out at a smaller one, or the smaller sizes predict it
    would take over twice the timeout (no faster than linear from the largest finished size)."""
    if any(r.get("status") in ("timed out", "skipped") for r in rows):
        return "not run: it did not finish at a smaller size"
    ok = [r for r in rows if r.get("status") == "ok"]
    if not ok:
        return None
    growth = max(1.0, slope([(r["vertices"], r["seconds"]) for r in ok]) or 1.0)
    predicted = ok[-1]["seconds"] * (vertex_count / ok[-1]["vertices"]) ** growth
    if predicted > 2 * timeout:
        return (f"not run: the smaller sizes predict about {predicted:.0f} s (slope {growth:.2f} from "
                f"{ok[-1]['seconds']:.1f} s at {ok[-1]['vertices']:,}), over twice the {timeout:.0f} s timeout")
    return None


def slope(points: list[tuple[float, float]]) -> float | None:
    """The least-squares slope of log(y) on log(x); None with fewer than two points."""
    points = [(x, y) for x, y in points if y and y > 0]
    if len(points) < 2:
        return None
    x, y = np.log([p[0] for p in points]), np.log([p[1] for p in points])
    return float(np.polyfit(x, y, 1)[0])


def slopes(results: dict) -> dict:
    out = {}
    for stage, rows in results["stages"].items():
        ok = [r for r in rows if r.get("status") == "ok"]
        out[stage] = {"seconds": slope([(r["vertices"], r["seconds"]) for r in ok]),
                      "cpu_seconds": slope([(r["vertices"], r["cpu_seconds"]) for r in ok]),
                      "peak_rss": slope([(r["vertices"], r["peak_rss"]) for r in ok]),
                      "stage_rss": slope([(r["vertices"], r["peak_rss"] - r["inputs_rss"]) for r in ok])}
    return out


def gib(value) -> str:
    return f"{value / 2**30:.2f}"


def cell(row: dict) -> str:
    if row.get("status") == "ok":
        return f"{row['seconds']:.3g} s ({row['cpu_seconds']:.3g} CPU), {gib(row['peak_rss'])} GiB"
    return row.get("status", "not run")


def short_name(function: str) -> str:
    """A profile entry's name for the report: a built-in by its name, a Python function by file:line(name)."""
    if function.startswith("~:0(<"):
        return function[5:-2].replace("built-in method ", "").replace("method ", "")
    return function.split("site-packages/")[-1]


def markdown_report(results: dict) -> str:
    info = results["machine"]
    sizes = results["sizes"]
    lines = ["# Scale: the synthetic creature from 10k to 1M vertices", "",
             f"{info['date']} · {info['cpu']} · {info['cores']} cores (two CPU-bound processes ran "
             f"{info['parallel_speedup_before']:.2f}x as fast as one before the run, "
             f"{info.get('parallel_speedup_after', float('nan')):.2f}x after; load average {info['load_before']} "
             f"before, {info.get('load_after', '?')} after) · "
             f"memory limit {results['memory_limit_text']} · timeout {results['timeout']:.0f} s per stage · "
             f"`{info['command']}`", "",
             "100 bones, 8 influences per vertex, 24 poses (scripts/make_large_character.py). Each cell: the stage's "
             "wall-clock seconds, its CPU seconds (user + system, all threads: what it cost on a shared machine) and "
             "the child's peak resident set (inputs included). Slopes: log-log least squares over the sizes that "
             "finished (1 is linear); stage RSS is the peak minus the inputs' high-water mark.",
             "", "| stage | " + " | ".join(f"{n:,}" for n in sizes) +
             " | slope s | slope CPU s | slope peak | slope stage RSS |",
             "|---|" + "---|" * (len(sizes) + 4)]
    for stage, rows in results["stages"].items():
        by_size = {r["requested"]: r for r in rows}
        s = results["slopes"][stage]
        lines.append(f"| {stage} | " + " | ".join(cell(by_size.get(n, {})) for n in sizes) + " | " +
                     " | ".join("-" if s[k] is None else f"{s[k]:.2f}"
                                for k in ("seconds", "cpu_seconds", "peak_rss", "stage_rss"))
                     + " |")
    notes = [(stage, r) for stage, rows in results["stages"].items() for r in rows if r.get("status") != "ok"]
    if notes:
        lines += ["", "Not finished:", ""]
        lines += [f"- {stage} at {r['requested']:,}: {r['status']}: {r.get('message', '')[:400]}" for stage, r in notes]
    limit = results.get("memory_limit")
    over = [(stage, r) for stage, rows in results["stages"].items() for r in rows
            if limit and r.get("status") == "ok" and r["peak_rss"] > limit]
    lines += ["", "Peaks over the memory limit (the stage did not refuse up front): " +
              (", ".join(f"{stage} at {r['requested']:,} ({gib(r['peak_rss'])} GiB)" for stage, r in over)
               if over else "none.")]
    profiled_rows = [(stage, r) for stage, rows in results["stages"].items() for r in rows if r.get("profile")]
    if profiled_rows:
        lines += ["", "Where the CPU time went (cProfile on the process CPU clock, own time, the heaviest functions; "
                  "a C entry point's time includes its worker threads):", ""]
        lines += [f"- {stage} at {r['requested']:,} ({r['status']}, {r['cpu_seconds']:.1f} CPU s): " +
                  "; ".join(f"`{short_name(entry['function'])}` {entry['own_cpu']:.1f} s" for entry in r["profile"][:5]
                            if entry["own_cpu"] >= 0.05)
                  for stage, r in profiled_rows]
    if results.get("notes"):
        lines += ["", "Notes:", ""] + [f"- {note}" for note in results["notes"]]
    lines += ["", "Inputs (made before each stage, not timed): " +
              ", ".join(f"{int(n):,} requested -> {v:,} vertices" for n, v in results["vertex_counts"].items()), ""]
    return "\n".join(lines)


def plot(results: dict, path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    figure, (time_axes, memory_axes) = plt.subplots(1, 2, figsize=(10, 4.2), dpi=90)
    for stage, rows in results["stages"].items():
        ok = [r for r in rows if r.get("status") == "ok"]
        if not ok:
            continue
        s = results["slopes"][stage]
        vertices = [r["vertices"] for r in ok]
        label_s = f"{stage} ({s['cpu_seconds']:.2f})" if s["cpu_seconds"] is not None else stage
        label_m = f"{stage} ({s['peak_rss']:.2f})" if s["peak_rss"] is not None else stage
        time_axes.loglog(vertices, [r["cpu_seconds"] for r in ok], "o-", label=label_s, markersize=3)
        memory_axes.loglog(vertices, [r["peak_rss"] / 2**30 for r in ok], "o-", label=label_m, markersize=3)
    sizes = np.array(results["sizes"], float)
    for axes in (time_axes, memory_axes):  # slope 1 through the middle of the view, for the eye
        low, high = axes.get_ylim()
        middle = np.sqrt(low * high) * sizes / np.sqrt(sizes.min() * sizes.max())
        axes.loglog(sizes, middle, "k--", linewidth=0.8, alpha=0.5, label="linear")
    time_axes.set(xlabel="vertices", ylabel="CPU seconds", title="CPU time (slope)")
    memory_axes.set(xlabel="vertices", ylabel="peak RSS, GiB", title="peak memory (slope)")
    for axes in (time_axes, memory_axes):
        axes.grid(True, which="both", alpha=0.3)
        axes.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path)


def parse_size(text: str) -> int:
    units = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
    text = text.strip().upper().rstrip("B")
    return int(float(text[:-1]) * units[text[-1]]) if text and text[-1] in units else int(text)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", default=",".join(map(str, SIZES)))
    parser.add_argument("--stages", default=",".join(STAGES))
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds per stage and size")
    parser.add_argument("--memory-limit", default="8G", help="skinkit's memory budget in each child")
    parser.add_argument("--json")
    parser.add_argument("--markdown")
    parser.add_argument("--plot")
    parser.add_argument("--profile-sizes", default="",
                        help="sizes (comma-separated) whose stages run under cProfile; the top functions by own "
                             "CPU time go into the JSON (a stage's own CPU time includes the profiler's overhead)")
    parser.add_argument("--from-json", metavar="FILE", help="write --markdown and --plot from saved results")
    parser.add_argument("--child", nargs=3, metavar=("STAGE", "VERTICES", "OUT"), help=argparse.SUPPRESS)
    arguments = parser.parse_args(argv)
    memory_limit = parse_size(arguments.memory_limit) if arguments.memory_limit else None
    profile_sizes = {int(s) for s in arguments.profile_sizes.split(",") if s}
    if arguments.child:
        stage, vertices, out_path = arguments.child
        child(stage, int(vertices), memory_limit, out_path, arguments.timeout, profile=int(vertices) in profile_sizes)
        return 0
    if arguments.from_json:
        with open(arguments.from_json) as stream:
            results = json.load(stream)
        for rows in results["stages"].values():  # JSON keeps the sizes as numbers in rows, as strings in keys
            rows.sort(key=lambda row: row["requested"])
        results["slopes"] = slopes(results)
        write_outputs(results, arguments.json, arguments.markdown, markdown_report)
        if arguments.plot:
            plot(results, arguments.plot)
        return 0
    sizes = [int(s) for s in arguments.sizes.split(",")]
    stages = arguments.stages.split(",")
    info = machine_info()
    info["parallel_speedup_before"] = parallel_speedup()
    info["load_before"] = " ".join(f"{x:.1f}" for x in os.getloadavg())
    results = {"machine": info, "sizes": sizes, "timeout": arguments.timeout, "memory_limit": memory_limit,
               "memory_limit_text": arguments.memory_limit or "free memory", "stages": {s: [] for s in stages},
               "vertex_counts": {}}
    for n in sorted(sizes):
        for stage in stages:
            reason = reason_to_skip(results["stages"][stage], n, arguments.timeout)
            row = {"status": "skipped", "message": reason} if reason else run_child(stage, n, arguments.timeout,
                                                                                      memory_limit, n in profile_sizes)
            row["requested"] = n
            row.setdefault("vertices", n)
            results["vertex_counts"][n] = row["vertices"]
            results["stages"][stage].append(row)
            print(f"{n:>9,} {stage:10s} {cell(row)}" + (f"  {row.get('message', '')[:200]}"
                                                        if row.get("status") != "ok" else ""), flush=True)
            if arguments.json:  # partial results survive an interrupted run
                results["slopes"] = slopes(results)
                write_outputs(results, arguments.json, None, markdown_report)
    info["parallel_speedup_after"] = parallel_speedup()
    info["load_after"] = " ".join(f"{x:.1f}" for x in os.getloadavg())
    results["slopes"] = slopes(results)
    write_outputs(results, arguments.json, arguments.markdown, markdown_report)
    if arguments.plot:
        plot(results, arguments.plot)
    print(markdown_report(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
