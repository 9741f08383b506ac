"""How the unwrap's flattening solver scales (issue 16): CG steps and CPU seconds against the vertex count.

    .venv/bin/python bench/bench_unwrap_scaling.py [--sizes 10000 30000 100000 300000] [--sliver-side 205] \
        [--json bench/unwrap_scaling_results.json] [--markdown bench/unwrap_scaling_results.md]

Whole unwraps (segmentation, flattening with stretch optimisation, packing; defaults) of the synthetic creature
(scripts/make_large_character.py) at each size and of the scan-like sliver mesh of issue 18
(tests/core/test_unwrap.py::scan_like_mesh, sliver_side^2 vertices, one or two charts); then single-chart solves
without the stretch optimisation (free boundary with two pins, and the straight pinned passes) of the jittered
height field without and with slivers, where the steps are the LSCM and Tutte solves alone. CPU is this process's
user + system time (all threads), so it means something on the shared, loaded machine; the load average is recorded.
No data files are needed.
"""
from __future__ import annotations

import argparse
import os
import resource
import sys

import numpy as np

REPOSITORY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(REPOSITORY, "scripts"))
sys.path.insert(0, os.path.join(REPOSITORY, "tests", "core"))

import make_large_character  # noqa: E402
from test_unwrap import scan_like_mesh  # noqa: E402

from skinkit.flatten import flatten  # noqa: E402
from skinkit.unwrap import edge_lengths_sq, unwrap  # noqa: E402

from common import machine_info, write_outputs  # noqa: E402

SINGLE_CHART_SIDES = (50, 100, 200)


def cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def whole_unwrap(name: str, positions, triangles) -> dict:
    started = cpu_seconds()
    result = unwrap(positions, triangles)
    cpu = cpu_seconds() - started
    report = result.report
    return {"mesh": name, "vertices": len(positions), "cpu_s": round(cpu, 3), "charts": report["charts"],
            "solver_steps": report["flattening"]["solver_iterations"],
            "optimisation_sweeps": report["flattening"]["optimisation_sweeps"],
            "stretch_metric": report["stretch_metric"], "texture_efficiency": report["texture_efficiency"],
            "invalid_triangles": report["flattening"]["invalid_triangles"], "status": report["status"]}


def single_chart(side: int, slivers: bool) -> list[dict]:
    positions, triangles = scan_like_mesh(n=side, sliver_fraction=0.06 if slivers else 0.0)
    lengths = edge_lengths_sq(positions, triangles)
    rows = []
    for straight in (False, True):
        started = cpu_seconds()
        result = flatten(triangles, lengths, np.zeros(len(triangles), np.int32), np.zeros(len(positions), bool),
                         straight=straight, optimise=False, threads=1)
        rows.append({"mesh": f"{'sliver' if slivers else 'jittered'} {side} x {side}", "vertices": len(positions),
                     "boundary": "straight" if straight else "free", "solver_steps": result.report["solver_iterations"],
                     "cpu_s": round(cpu_seconds() - started, 3), "tutte_charts": result.report["tutte_charts"],
                     "invalid_triangles": result.report["invalid_triangles"]})
        print(rows[-1], flush=True)
    return rows


def markdown(results: dict) -> str:
    lines = ["# The unwrap's flattening solver against the vertex count", "",
             f"Machine: {results['machine'].get('cpu', '')}; load average before / after: "
             f"{results['load_before']} / {results['load_after']}. CPU: process user + system seconds.", "",
             "| mesh | vertices | charts | CG steps (all solves) | sweeps | CPU s | stretch | efficiency | invalid |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in results["unwrap"]:
        lines.append(f"| {r['mesh']} | {r['vertices']} | {r['charts']} | {r['solver_steps']} | "
                     f"{r['optimisation_sweeps']} | {r['cpu_s']} | {r['stretch_metric']:.6f} | "
                     f"{r['texture_efficiency']:.4f} | {r['invalid_triangles']} |")
    lines += ["", "Single chart, no stretch optimisation (the LSCM / Tutte solves alone):", "",
              "| mesh | vertices | boundary | CG steps | CPU s | Tutte | invalid |", "|---|---|---|---|---|---|---|"]
    for r in results["single_chart"]:
        lines.append(f"| {r['mesh']} | {r['vertices']} | {r['boundary']} | {r['solver_steps']} | {r['cpu_s']} | "
                     f"{r['tutte_charts']} | {r['invalid_triangles']} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="*", default=[10000, 30000, 100000, 300000])
    parser.add_argument("--sliver-side", type=int, default=205)
    parser.add_argument("--json")
    parser.add_argument("--markdown")
    arguments = parser.parse_args()
    results = {"load_before": round(os.getloadavg()[0], 1), "unwrap": [], "single_chart": []}
    for side in SINGLE_CHART_SIDES:
        results["single_chart"] += single_chart(side, slivers=False)
    results["single_chart"] += single_chart(100, slivers=True)
    for size in arguments.sizes:
        c = make_large_character.make_character(size, with_examples=False)
        results["unwrap"].append(whole_unwrap(f"creature {size}", c["rest"], c["triangles"]))
        print(results["unwrap"][-1], flush=True)
    if arguments.sliver_side:
        positions, triangles = scan_like_mesh(n=arguments.sliver_side)
        results["unwrap"].append(whole_unwrap(f"scan-like slivers {arguments.sliver_side} x {arguments.sliver_side}",
                                              positions, triangles))
        print(results["unwrap"][-1], flush=True)
    results["load_after"] = round(os.getloadavg()[0], 1)
    results["machine"] = machine_info()
    write_outputs(results, arguments.json, arguments.markdown, markdown)
    if not arguments.json and not arguments.markdown:
        print(markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
