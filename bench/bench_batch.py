"""skinkit batch throughput: characters per hour on a LocalCluster of 1 and of 2 workers, and the overhead of the
batch (a process per step, Dask scheduling, hashing, publishing) against the same steps run in one process.

    .venv/bin/python bench/bench_batch.py [--copies 2] [--json bench/batch_results.json] \
        [--markdown bench/batch_results.md]

Characters: the Blender samples arm and creature, each listed --copies times under its own name; each goes through
convert, bake (PC2, frames 1-24) and unwrap (6 charts). "One process": the same commands, one after the other,
through skinkit.cli.main in this process (Blender's module loaded once). Every run starts from an empty output
folder, so nothing is skipped.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time

from common import machine_info, parallel_speedup, write_outputs

REPOSITORY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SAMPLES = ("arm", "creature")
STEPS = ('[[character.step]]\ncommand = "convert"\noutput = "{name}.blend"\n'
         '[[character.step]]\ncommand = "bake"\noutput = "{name}.pc2"\noptions = {{ frames = "1:24" }}\n'
         '[[character.step]]\ncommand = "unwrap"\noutput = "{name}.obj"\noptions = {{ charts = 6 }}\n')


def write_jobs(folder: str, copies: int) -> str:
    text = 'retries = 1\nout = "out"\n'
    for copy in range(copies):
        for sample in SAMPLES:
            name = f"{sample}_{copy}"
            text += (f'[[character]]\nname = "{name}"\n'
                     f'input = "{os.path.join(REPOSITORY, "blend_samples", sample + ".blend")}"\n'
                     + STEPS.format(name=name))
    path = os.path.join(folder, "jobs.toml")
    with open(path, "w") as file:
        file.write(text)
    return path


def batch_seconds(jobs: str, workers: int) -> float:
    from skinkit.batch import load_jobs, run_batch

    shutil.rmtree(os.path.join(os.path.dirname(jobs), "out"), ignore_errors=True)
    started = time.perf_counter()
    result = run_batch(load_jobs(jobs), workers=workers)
    seconds = time.perf_counter() - started
    if result["done"] != len(result["characters"]):
        raise RuntimeError(f"the batch did not complete: {result}")
    return seconds


def one_process_seconds(jobs: str) -> float:
    """The same steps through skinkit.cli.main, in this process."""
    from skinkit.batch import load_jobs
    from skinkit.batch.pipeline import step_arguments
    from skinkit.cli import main

    out = os.path.join(os.path.dirname(jobs), "out")
    shutil.rmtree(out, ignore_errors=True)
    started = time.perf_counter()
    for character in load_jobs(jobs):
        os.makedirs(character.folder)
        scene = character.input
        for step in character.steps:
            if main(step_arguments(step, step.input or scene, character.folder)) != 0:
                raise RuntimeError(f"{character.name}: {step.command} failed")
            if step.output.endswith(".blend"):
                scene = os.path.join(character.folder, step.output)
    return time.perf_counter() - started


def report(results: dict) -> str:
    machine = results["machine"]
    rows = results["runs"]
    lines = ["# Batch benchmark", "", f"`{machine['command']}` on {machine['cpu']} ({machine['usable_cores']} cores; "
             f"two CPU-bound processes ran {results['parallel_speedup']:.2f}x as fast as one), {machine['date']}; "
             f"Blender {machine['bpy']}.", "",
             f"{results['characters']} characters (arm and creature, {results['copies']} copies each), each through "
             "convert, bake (24 frames to PC2) and unwrap (6 charts).", "",
             "| run | seconds | characters / hour | vs one process |", "|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['run']} | {row['seconds']:.1f} | {row['characters_per_hour']:.0f} | "
                     f"{row['ratio_to_one_process']:.2f}x |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--copies", type=int, default=2, help="copies of each sample (default 2: 4 characters)")
    parser.add_argument("--json", help="write the results here")
    parser.add_argument("--markdown", help="write a Markdown report here")
    args = parser.parse_args(argv)
    import bpy  # noqa: F401 - loaded for the one-process run, and so that machine_info names Blender

    speedup = parallel_speedup()
    with tempfile.TemporaryDirectory() as folder:
        jobs = write_jobs(folder, args.copies)
        count = args.copies * len(SAMPLES)
        timings = [("one process (skinkit.cli.main, no Dask)", one_process_seconds(jobs))]
        for workers in (1, 2):
            print(f"batch with {workers} worker(s)", file=sys.stderr)
            timings.append((f"skinkit batch, LocalCluster of {workers} worker(s)", batch_seconds(jobs, workers)))
    base = timings[0][1]
    results = {"machine": machine_info(), "parallel_speedup": speedup, "copies": args.copies, "characters": count,
               "runs": [{"run": run, "seconds": seconds, "characters_per_hour": count * 3600 / seconds,
                         "ratio_to_one_process": seconds / base} for run, seconds in timings]}
    write_outputs(results, args.json, args.markdown, report)
    print(report(results))
    return results


if __name__ == "__main__":
    main()
