"""Per-phase thread CPU seconds of skinkit's default fit on the synthetic horses (issue 18: the horse-sized time
targets), one thread, the best of a few runs each, so that a loaded machine distorts little; then the wall time of
the whole call with one thread per core.

    .venv/bin/python bench/profile_fit.py [--rounds 3] [--json bench/profile_fit_results.json]

Phases: the caller's linear-blend prior (fit_lbs, C sk_fit_lbs_weights), the vertex-order check, the cross-validation
(C sk_validate_per_vertex, after the 4 folds' refitted priors), the final per-vertex fit (C sk_fit_per_vertex, run
here with the fall-back disabled, since both horses fall back), and the whole call per method. Needs
../shared/data/horse (skipped with a message without it).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from skinkit import _core, convert_lbs  # noqa: E402
from skinkit import fit  # noqa: E402

HORSE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data", "horse",
                     "reference.obj")


def captured_calls(problem, names=("validate_per_vertex", "fit_per_vertex", "fit_lbs_weights")) -> dict:
    """The arguments of each C call of one whole fit (fall-back disabled, so that the final fit runs too)."""
    originals, calls = {name: getattr(_core, name) for name in names}, {}

    def recording(name):
        def call(*arguments):
            calls.setdefault(name, []).append([np.copy(a) if isinstance(a, np.ndarray) else a for a in arguments])
            return originals[name](*arguments)
        return call

    margin = fit.VALIDATION_MARGIN
    try:
        for name in names:
            setattr(_core, name, recording(name))
        fit.VALIDATION_MARGIN = -1.0
        whole_fit(problem, "per-vertex", 1)
    finally:
        fit.VALIDATION_MARGIN = margin
        for name in names:
            setattr(_core, name, originals[name])
    return {name: (originals[name], calls[name]) for name in names}


def whole_fit(problem, method: str, threads: int):
    """As the operator runs it: the linear-blend prior, then the validated default fit."""
    prior = convert_lbs(problem.skeleton, fit.fit_lbs(problem.skeleton, problem.rest, problem.train_poses,
                                                      problem.train_frames, problem.influences, threads=threads),
                        problem.rest)
    return fit.fit_animation_space(problem.train_poses, problem.train_frames, problem.influences,
                                   problem.skeleton.bone_count, method=method, triangles=problem.triangles,
                                   rest_positions=problem.rest, rest_frames=problem.skeleton.rest_frames, prior=prior,
                                   threads=threads)


def best_seconds(function, rounds: int, clock=time.thread_time) -> float:
    seconds = []
    for _ in range(rounds):
        started = clock()
        function()
        seconds.append(clock() - started)
    return min(seconds)


def profile(problem, rounds: int) -> dict:
    calls = captured_calls(problem)
    run_c = {name: (lambda c=c, a=a: c(*a[0])) for name, (c, a) in calls.items()}
    phases = {
        "linear-blend prior (one fit)": run_c["fit_lbs_weights"],
        "4 folds' refitted priors": lambda: [calls["fit_lbs_weights"][0](*a) for a in calls["fit_lbs_weights"][1][1:]],
        "vertex-order check": lambda: fit.check_vertex_order(problem.rest, problem.train_frames, problem.triangles),
        "cross-validation (C)": run_c["validate_per_vertex"],
        "final per-vertex fit (C; skipped on a fall-back)": run_c["fit_per_vertex"],
        "whole call, per-vertex": lambda: whole_fit(problem, "per-vertex", 1),
        "whole call, global": lambda: whole_fit(problem, "global", 1),
    }
    result = {name: best_seconds(function, rounds) for name, function in phases.items()}
    for method in fit.FIT_METHODS:
        result[f"whole call, {method}, wall, one thread per core"] = best_seconds(
            lambda m=method: whole_fit(problem, m, 0), rounds, time.perf_counter)
    report = whole_fit(problem, "per-vertex", 0).report
    result["fell back"] = bool(report.get("fallback"))
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--json")
    arguments = parser.parse_args()
    if not os.path.exists(HORSE):
        print(f"skipped: {HORSE} not found (the shared benchmark data is not on this machine)")
        return
    import datasets  # imports bpy, so only when the data are there

    results = {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "cores": os.cpu_count(),
               "load_average_before": os.getloadavg()[0], "rounds": arguments.rounds, "sets": {}}
    for degrees in (15, 30):
        problem = datasets.synthetic_horse(HORSE, degrees)
        train = ~problem.held_out
        problem.train_poses, problem.train_frames = problem.poses[train], problem.frames[train]
        results["sets"][problem.name] = profile(problem, arguments.rounds)
        print(problem.name, json.dumps(results["sets"][problem.name], indent=1))
    results["load_average_after"] = os.getloadavg()[0]
    if arguments.json:
        with open(arguments.json, "w") as stream:
            json.dump(results, stream, indent=1)


if __name__ == "__main__":
    main()
