"""BLAS threads inside skinkit's own threaded work: kernel CCA (the handle rig's predictor, section 2.4 of Feng
2010), whose workers each run LAPACK eigenproblems, timed through skinkit's own path (skinkit.handles.train's
fitted_predictor) with skinkit._blas's limit (one BLAS thread while the core's workers run), without it (OpenBLAS's
own threads inside every worker), and single-threaded, on the same synthetic problem in one run.

    .venv/bin/python bench/bench_blas_threads.py [--examples 240] [--bones 24] [--repeats 7] [--markdown M] [--json J]
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import time

import numpy as np

from common import machine_info, machine_line, parallel_speedup, write_outputs

# The module, not skinkit.handles.train (the package exports its train function under the module's name).
train = importlib.import_module("skinkit.handles.train")


def timed(call, repeats: int) -> dict:
    call()
    seconds = []
    for _ in range(repeats):
        started = time.perf_counter()
        call()
        seconds.append(time.perf_counter() - started)
    return {"median_s": float(np.median(seconds)), "min_s": float(np.min(seconds)), "all_s": seconds}


def measure(examples: int, bones: int, repeats: int) -> dict:
    rng = np.random.default_rng(0)
    normalised = rng.normal(size=(examples, 3 * 10))
    dual_quaternions = rng.normal(size=(examples, bones, 8))

    def predictor(threads: int):
        return lambda: train.fitted_predictor(normalised, dual_quaternions, "gaussian", 1.0, 2, 8, 1e-3, threads)

    rows = {"limited (shipped), every core": timed(predictor(0), repeats)}
    shipped = train.blas_threads_for
    train.blas_threads_for = lambda threads: contextlib.nullcontext()
    try:
        rows["OpenBLAS's own threads, every core"] = timed(predictor(0), repeats)
    finally:
        train.blas_threads_for = shipped
    rows["one skinkit thread (BLAS's own threads)"] = timed(predictor(1), repeats)
    return rows


def markdown(results: dict) -> str:
    info = results["machine"]
    lines = [f"Kernel CCA, {results['examples']} examples x {results['bones']} bones, {results['repeats']} repeats "
             f"on {machine_line(info)}; load {info['load_before']} before).", "",
             "| configuration | median s | min s |", "|---|---|---|"]
    for name, row in results["rows"].items():
        lines.append(f"| {name} | {row['median_s']:.4f} | {row['min_s']:.4f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--examples", type=int, default=240)
    parser.add_argument("--bones", type=int, default=24)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--markdown")
    parser.add_argument("--json")
    arguments = parser.parse_args()
    info = machine_info()
    info["load_before"] = [round(x, 2) for x in os.getloadavg()]
    info["parallel_speedup_before"] = parallel_speedup()
    rows = measure(arguments.examples, arguments.bones, arguments.repeats)
    info["parallel_speedup_after"] = parallel_speedup()
    results = {"machine": info, "examples": arguments.examples, "bones": arguments.bones,
               "repeats": arguments.repeats, "rows": rows}
    write_outputs(results, arguments.json, arguments.markdown, markdown)
    print(markdown(results))


if __name__ == "__main__":
    main()
