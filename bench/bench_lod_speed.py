"""LOD chain speed and memory (issue 11): the 5-level chain of the decomposed horse (8 influences per vertex) and of
the horse subdivided twice in animation space (134,782 vertices), plus the creature's and the arm's chains, each
skinkit AS + influence simplification without UVs; seconds (wall and CPU), peak memory and every level's error.

    .venv/bin/python bench/bench_lod_speed.py [--data ../shared/data] [--baseline-python PATH] [--repeats 3] \
        [--cases horse,large,creature,arm] [--json bench/lod_speed_results.json] \
        [--markdown bench/lod_speed_results.md]

Each case runs in its own child process (so each peak is its own): the child loads the prepared models (not timed),
resets its resident-set high-water mark, builds the chain `--repeats` times (the large one once) and reports the
least and median wall and CPU seconds, the peak resident memory above what it held before the first build (VmHWM),
and each level's triangles, vertices, influences and error (epsilon, the largest collapse cost met on the way, a
fraction of the bounding-box diagonal), with a digest of the levels' triangles and coordinates.

--baseline-python runs the same children with another interpreter whose skinkit is the build to compare against
(e.g. the main tree's venv: per-candidate costing of influence removals), so both builds are measured in one run, on
the same models and the same machine load; the table says whether the levels are bit-identical and how far their
errors differ. The horse needs the horse data (../shared/data/horse): without it every case is skipped with a
message. The creature and the arm come from blend_samples/ through bpy.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

LEVELS = 5  # the "5-level horse chain"
CASES = ("horse", "large", "creature", "arm")
HORSE_TARGET_SECONDS, LARGE_TARGET_SECONDS, LARGE_TARGET_MB = 1.0, 10.0, 1024.0


# ---- the child: one case, timed --------------------------------------------------------------------------------

def high_water_mb() -> float:
    with open("/proc/self/status") as stream:
        line = next(line for line in stream if line.startswith("VmHWM:"))
    return int(line.split()[1]) / 1024.0


def reset_high_water() -> None:
    """Linux: writing 5 to clear_refs resets VmHWM to the current resident set."""
    try:
        with open("/proc/self/clear_refs", "w") as stream:
            stream.write("5")
    except OSError:
        pass


def level_digest(chain) -> str:
    digest = hashlib.sha1()
    for level in chain.levels:
        digest.update(np.ascontiguousarray(level.triangles).tobytes())
        digest.update(np.ascontiguousarray(level.model.coordinates).tobytes())
    return digest.hexdigest()


def run_child(path: str, repeats: int) -> dict:
    import skinkit
    from skinkit.lod import build_chain

    with open(path, "rb") as stream:
        data = pickle.load(stream)
    walls, cpus, chain, peak = [], [], None, None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # no UVs: every chain warns that it has no atlas
        for repeat in range(repeats):
            chain = None
            reset_high_water()
            before = high_water_mb()
            wall, cpu = time.perf_counter(), time.process_time()
            chain = build_chain(data["triangles"], data["rest"], data["model"], data["statistics"], levels=LEVELS)
            walls.append(time.perf_counter() - wall)
            cpus.append(time.process_time() - cpu)
            if repeat == 0:
                peak = high_water_mb() - before
    return {"skinkit": os.path.dirname(skinkit.__file__), "wall_min": min(walls),
            "wall_median": float(np.median(walls)), "cpu_min": min(cpus), "cpu_median": float(np.median(cpus)),
            "repeats": repeats, "peak_mb": peak, "digest": level_digest(chain),
            "levels": [{"triangles": level.triangle_count, "vertices": level.vertex_count,
                        "influences": level.influence_count, "error": level.relative_epsilon}
                       for level in chain.levels]}


# ---- the parent: models, children, comparison ------------------------------------------------------------------

def prepare_models(cases: list[str], data_folder: str) -> dict:
    """Each case's (triangles, rest, model, statistics), or the reason it is skipped."""
    import bench_lod
    from bench_lod import MissingData

    models = {}
    horse = None
    if "horse" in cases or "large" in cases:
        try:
            horse = bench_lod.horse_models(data_folder)
        except MissingData as missing:
            print(f"horse and large: skipped ({missing})", file=sys.stderr)
            models["horse"] = models["large"] = {"skipped": str(missing)}
    if horse is not None and "horse" in cases:
        models["horse"] = horse
    if horse is not None and "large" in cases:
        models["large"] = bench_lod.large_character(horse)
    for name in ("creature", "arm"):
        if name in cases:
            try:
                models[name] = bench_lod.creature_models(bench_lod.load_sample(name))
            except Exception as failure:  # noqa: BLE001 - no bpy or no sample: the case is skipped, said why
                print(f"{name}: skipped ({failure})", file=sys.stderr)
                models[name] = {"skipped": str(failure)}
    return models


def tree_commit(skinkit_folder: str) -> str:
    try:
        return subprocess.run(["git", "-C", skinkit_folder, "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def run_case(python: str, path: str, repeats: int) -> dict:
    load_before = os.getloadavg()[0]
    done = subprocess.run([python, os.path.abspath(__file__), "--child", path, "--repeats", str(repeats)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        return {"failed": done.stderr.strip().splitlines()[-1:] or ["no output"]}
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result.update(load_before=load_before, load_after=os.getloadavg()[0], commit=tree_commit(result["skinkit"]))
    return result


def compare_levels(ours: dict, baseline: dict) -> dict:
    """Bit-identical levels, or the largest relative difference of the levels' errors and the counts that differ."""
    pairs = list(zip(ours["levels"], baseline["levels"]))
    differences = [abs(a["error"] - b["error"]) / b["error"] for a, b in pairs if b["error"] > 0]
    return {"identical": ours["digest"] == baseline["digest"],
            "error_relative_difference": max(differences, default=0.0),
            "same_counts": all(a["triangles"] == b["triangles"] and a["influences"] == b["influences"]
                               for a, b in pairs) and len(ours["levels"]) == len(baseline["levels"])}


def run(cases: list[str], data_folder: str, baseline_python: str | None, repeats: int) -> dict:
    from common import machine_info, parallel_speedup

    models = prepare_models(cases, data_folder)
    results = {"machine": machine_info() | {"parallel_speedup_before": parallel_speedup()}, "levels": LEVELS,
               "cases": {}}
    with tempfile.TemporaryDirectory() as folder:
        for name in cases:
            data = models[name]
            if "skipped" in data:
                results["cases"][name] = {"skipped": data["skipped"]}
                continue
            path = os.path.join(folder, f"{name}.pickle")
            with open(path, "wb") as stream:
                pickle.dump({key: data[key] for key in ("triangles", "rest", "model", "statistics")}, stream)
            times = 1 if name == "large" else repeats
            row = {"vertices": len(data["rest"]), "triangles": len(data["triangles"]),
                   "influences": data["model"].influence_count, "skinkit": run_case(sys.executable, path, times)}
            if baseline_python:
                row["baseline"] = run_case(baseline_python, path, times)
                if "failed" not in row["baseline"] and "failed" not in row["skinkit"]:
                    row["comparison"] = compare_levels(row["skinkit"], row["baseline"])
            results["cases"][name] = row
            print(f"{name}: {json.dumps({k: v for k, v in row.items() if k != 'baseline'})[:400]}", file=sys.stderr)
    results["machine"]["parallel_speedup_after"] = parallel_speedup()
    return results


def markdown(results: dict) -> str:
    from common import machine_line

    lines = ["# LOD chain speed", "", machine_line(results["machine"]) + f"; command `{results['machine']['command']}`)",
             "",
             f"{results['levels']}-level chains, skinkit AS + influence simplification, no UVs, each level at most half "
             "the influences of the one before. Seconds: least (median) over the repeats, wall and CPU of the child "
             "process; load: the 1-minute load average before / after the child (the machine's other work). Peak MB: "
             "resident memory above what the child held before the build (VmHWM). Error: each level's epsilon "
             "(fraction of the diagonal).", "",
             "| case | vertices / triangles / influences | build | wall s | CPU s | peak MB | load | levels' triangles | "
             "levels' errors |", "|---|---|---|---|---|---|---|---|---|"]
    for name, row in results["cases"].items():
        if "skipped" in row:
            lines.append(f"| {name} | skipped: {row['skipped']} | | | | | | | |")
            continue
        for label in ("skinkit", "baseline"):
            u = row.get(label)
            if u is None:
                continue
            if "failed" in u:
                lines.append(f"| {name} | | {label}: failed ({u['failed']}) | | | | | | |")
                continue
            lines.append(
                f"| {name} | {row['vertices']} / {row['triangles']} / {row['influences']} | {label} ({u['commit']}) | "
                f"{u['wall_min']:.3f} ({u['wall_median']:.3f}) | {u['cpu_min']:.3f} ({u['cpu_median']:.3f}) | "
                f"{u['peak_mb']:.1f} | {u['load_before']:.1f} / {u['load_after']:.1f} | "
                f"{', '.join(str(level['triangles']) for level in u['levels'])} | "
                f"{', '.join(format(level['error'], '.4e') for level in u['levels'][1:])} |")
    compared = {name: row["comparison"] for name, row in results["cases"].items() if "comparison" in row}
    if compared:
        lines += ["", "Levels against the baseline: bit-identical (triangles and coordinates of every level), or the "
                  "largest relative difference of the levels' errors.", "", "| case | identical | same counts | "
                  "largest error difference |", "|---|---|---|---|"]
        for name, c in compared.items():
            lines.append(f"| {name} | {'yes' if c['identical'] else 'no'} | {'yes' if c['same_counts'] else 'no'} | "
                         f"{c['error_relative_difference']:.2e} |")
    lines += ["", f"Targets: the horse chain under {HORSE_TARGET_SECONDS:g} s, the large one under "
              f"{LARGE_TARGET_SECONDS:g} s and {LARGE_TARGET_MB:g} MB.", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", default=os.path.join(os.path.dirname(os.path.dirname(HERE)), "shared", "data"))
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--baseline-python", default=None,
                        help="an interpreter whose skinkit is the build to compare against, measured in the same run")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", default=None)
    parser.add_argument("--markdown", default=None)
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(run_child(args.child, args.repeats)))
        return 0
    cases = [name for name in args.cases.split(",") if name]
    unknown = sorted(set(cases) - set(CASES))
    if unknown:
        parser.error(f"unknown cases {unknown}: choose from {list(CASES)}")
    from common import write_outputs

    results = run(cases, args.data, args.baseline_python, args.repeats)
    write_outputs(results, args.json, args.markdown, markdown)
    print(markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
