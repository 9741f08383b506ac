"""skinkit's LOD chain variants alone (no peers), per level: the error to full detail and to the held-out frames
at bench_lod's corresponding surface points, and the chain's CPU seconds. The quick way to compare build_chain's
options (the queue's ranking, full-edge collapses, the start budget) on bench_lod's data sets.

    .venv/bin/python bench/lod_variants.py [--data ../shared/data] [--datasets horse,creature,arm,cow,dembones] \
        [--variants 'thesis:rank_per_influence=False,collapse=half;defaults:'] [--levels 7] [--from weights]

--from weights starts every variant from the peers' linear-blend weights (bench_lod's variant held to the targets,
its errors to that model's full detail); the default starts from the data set's animation-space model.

A variant is `label:key=value,...` (build_chain keyword arguments; values parsed as bool, int, float or str).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import bench_lod
import lod_peers
from decompose_data import MissingData

from skinkit.lod import build_chain

DEFAULT_VARIANTS = ("thesis:rank_per_influence=False,collapse=half,influence_cost_scale=1;"
                    "nois:simplify_influences=False;x3:rank_per_influence=False,collapse=half,influence_cost_scale=3;"
                    "before-session-14:collapse=auto,influence_cost_scale=1;defaults:")


def parsed_value(text: str):
    if text in ("True", "False"):
        return text == "True"
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def parsed_variants(text: str) -> list[tuple[str, dict]]:
    variants = []
    for spec in filter(None, text.split(";")):
        label, _, options = spec.partition(":")
        pairs = (item.split("=", 1) for item in filter(None, options.split(",")))
        variants.append((label, {key: parsed_value(value) for key, value in pairs}))
    return variants


def variant_rows(models: dict, variants, levels: int, start: str = "model") -> list[dict]:
    if start == "weights":
        models = dict(models, model=bench_lod.convert_lbs(models["skeleton"], models["weights"], models["rest"]))
    scale = bench_lod.unit_box_scale(models["rest"])
    samples = lod_peers.SurfaceSamples(models["rest"], models["triangles"])
    frames = samples.on_input(models["targets"])
    reference = samples.on_input(models["model"].evaluate(models["test_poses"]))
    rows = []
    for label, options in variants:
        started = time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # no UVs on these meshes
            chain = build_chain(models["triangles"], models["rest"], models["model"], models["statistics"],
                                levels=levels, **options)
        seconds = time.process_time() - started
        points = []
        for level in chain.levels:
            posed = level.model.evaluate(models["test_poses"])
            at = samples.on_level(lod_peers.Level(models["rest"][level.vertices], level.triangles, posed,
                                                  level.influence_count))
            points.append((level.triangle_count, level.influence_count, lod_peers.rms(at, reference, scale),
                           lod_peers.rms(at, frames, scale)))
        rows.append({"variant": label, "cpu_seconds": seconds, "points": points})
    return rows


def markdown(name: str, rows: list[dict]) -> str:
    count = max(len(row["points"]) for row in rows)
    header = " | ".join(f"1/{2 ** level}" for level in range(1, count))
    lines = [f"## {name}", "", "error to full detail (to the held-out frames) per level; CPU seconds of the chain", "",
             f"| variant | CPU s | {header} |", "|---|---:|" + "---:|" * (count - 1)]
    for row in rows:
        cells = [f"{error:.2e} ({to_frames:.2e})" for _, _, error, to_frames in row["points"][1:]]
        lines.append(f"| {row['variant']} | {row['cpu_seconds']:.1f} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=os.path.join(bench_lod.REPOSITORY, "..", "shared", "data"))
    parser.add_argument("--datasets", default="horse,creature,arm,cow,dembones")
    parser.add_argument("--variants", default=DEFAULT_VARIANTS)
    parser.add_argument("--levels", type=int, default=bench_lod.CHAIN_LEVELS)
    parser.add_argument("--from", dest="start", choices=("model", "weights"), default="model")
    arguments = parser.parse_args(argv)
    variants = parsed_variants(arguments.variants)
    for name in filter(None, arguments.datasets.split(",")):
        try:
            models = bench_lod.chain_models(name, arguments.data)
        except MissingData as missing:
            print(f"{name}: skipped ({missing})", file=sys.stderr)
            continue
        print(markdown(name, variant_rows(models, variants, arguments.levels, arguments.start)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
