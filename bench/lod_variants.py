"""skinkit's LOD chain variants alone (no peers), per level: the error to full detail and to the held-out frames
at bench_lod's corresponding surface points, and the chain's CPU seconds. The quick way to compare build_chain's
options (the queue's ranking, full-edge collapses, the start budget) on bench_lod's data sets.

    .venv/bin/python bench/lod_variants.py [--data ../shared/data] [--datasets horse,creature,arm,cow,dembones] \
        [--variants 'thesis:rank_per_influence=False,collapse=half;defaults:'] [--levels 7] [--from weights] \
        [--statistics held-out] [--spread RADIANS] [--two-stage] [--peers bench/lod_results.json]

--from weights starts every variant from the peers' linear-blend weights (bench_lod's variant held to the targets,
its errors to that model's full detail); the default starts from the data set's animation-space model.
--statistics held-out builds every chain from the pose statistics of the held-out frames themselves instead of the
training frames': an oracle no user has, which measures how much of a level's error is what the training poses do
not say about the held-out ones. --spread turns each sampled joint rotation by +-RADIANS about its axes as well
(PoseStatistics' spread, `skinkit stats --spread`): statistics that trust few poses less.
--two-stage also builds levels geometry first (the chain without influence simplification to a share of the
triangles), then limits every vertex to K = 1, 2 or 3 influences (Limit Influences) and refits: the other way to
spend an influence budget, printed beside the last variant's chain.
--peers reads bench_lod's results (its --json) and prints every level's ratio to the best peer at its total
influences, as bench_lod's targets do (the peers' levels do not depend on skinkit's options: re-use a run of them);
with --from weights, as the peers simplify those weights and the ratios compare errors to the same full detail.

A variant is `label:key=value,...` (build_chain keyword arguments; values parsed as bool, int, float or str).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings

import bench_lod
import lod_peers
from decompose_data import MissingData

from skinkit.lod import build_chain, limit_influences, refit_level
from skinkit.metrics import PoseStatistics

DEFAULT_VARIANTS = ("thesis:rank_per_influence=False,collapse=half,influence_cost_scale=1;"
                    "nois:simplify_influences=False;x3:rank_per_influence=False,collapse=half,influence_cost_scale=3;"
                    "before-session-14:collapse=auto,influence_cost_scale=1;defaults:")
#: --two-stage: the shares of the triangles the geometry is simplified to, and the influences each vertex keeps then.
TWO_STAGE_SHARES = (0.4, 0.3, 0.22, 0.16, 0.12, 0.09, 0.065, 0.045, 0.032, 0.022)
TWO_STAGE_INFLUENCES = (1, 2, 3)


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


def prepared(models: dict, start: str, statistics: str, spread: float = 0.0) -> dict:
    """The data set's models with the chain's start (`weights`: the peers' linear-blend weights as an
    animation-space model) and statistics (`held-out`: the held-out frames' own; either with `spread`) swapped in."""
    if start == "weights":
        models = dict(models, model=bench_lod.convert_lbs(models["skeleton"], models["weights"], models["rest"]))
    if statistics == "held-out" or spread:
        poses = models["test_poses"] if statistics == "held-out" else models["training_poses"]
        models = dict(models, statistics=PoseStatistics.from_world_samples(models["skeleton"].parents, poses,
                                                                            spread=spread))
    return models


class Measure:
    """A level's error to the full detail and to the held-out frames at bench_lod's corresponding surface points."""

    def __init__(self, models: dict):
        self.models = models
        self.scale = bench_lod.unit_box_scale(models["rest"])
        self.samples = lod_peers.SurfaceSamples(models["rest"], models["triangles"])
        self.frames = self.samples.on_input(models["targets"])
        self.reference = self.samples.on_input(models["model"].evaluate(models["test_poses"]))

    def __call__(self, level, model=None) -> tuple[float, float]:
        model = level.model if model is None else model
        posed = model.evaluate(self.models["test_poses"])
        at = self.samples.on_level(lod_peers.Level(self.models["rest"][level.vertices], level.triangles, posed,
                                                   model.influence_count))
        return lod_peers.rms(at, self.reference, self.scale), lod_peers.rms(at, self.frames, self.scale)


def variant_rows(models: dict, variants, levels: int) -> list[dict]:
    measure = Measure(models)
    rows = []
    for label, options in variants:
        started = time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # no UVs on these meshes
            chain = build_chain(models["triangles"], models["rest"], models["model"], models["statistics"],
                                levels=levels, **options)
        seconds = time.process_time() - started
        points = [(level.triangle_count, level.influence_count, *measure(level)) for level in chain.levels]
        rows.append({"variant": label, "cpu_seconds": seconds, "points": points})
    return rows


def two_stage_rows(models: dict) -> list[dict]:
    """Geometry first, influences after: the chain without influence simplification to each of TWO_STAGE_SHARES
    of the triangles, then every vertex limited to K influences (Limit Influences, eq. 6.1) and the level refitted
    to the full detail on its new sets: per K, (vertices, influences, error to full detail, to the frames). What
    the default chain's single queue is measured against at equal total influences."""
    triangles, rest, model = models["triangles"], models["rest"], models["model"]
    measure = Measure(models)
    targets = sorted({max(int(len(triangles) * share), 2) for share in TWO_STAGE_SHARES}, reverse=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        chain = build_chain(triangles, rest, model, models["statistics"], levels=len(targets) + 1,
                            simplify_influences=False, targets={"triangles": targets})
    rows = []
    for per_vertex in TWO_STAGE_INFLUENCES:
        points = []
        for level in chain.levels[1:]:
            limited, _ = limit_influences(level.model, models["statistics"], per_vertex)
            refitted, _ = refit_level(level.triangles, rest[level.vertices], limited, triangles, rest, model,
                                      models["statistics"])
            points.append((level.vertex_count, refitted.influence_count, *measure(level, refitted)))
        rows.append({"per_vertex": per_vertex, "points": points})
    return rows


def markdown(name: str, rows: list[dict], peers: dict | None = None) -> str:
    """The variants' levels; with `peers` (a bench_lod results file's peers of this data set), also each level's
    ratio to the best peer at its total influences, as bench_lod's targets compute it."""
    count = max(len(row["points"]) for row in rows)
    header = " | ".join(f"1/{2 ** level}" for level in range(1, count))
    lines = [f"## {name}", "", "error to full detail (to the held-out frames) per level; CPU seconds of the chain", "",
             f"| variant | CPU s | {header} |", "|---|---:|" + "---:|" * (count - 1)]
    for row in rows:
        cells = [f"{error:.2e} ({to_frames:.2e})" for _, _, error, to_frames in row["points"][1:]]
        lines.append(f"| {row['variant']} | {row['cpu_seconds']:.1f} | " + " | ".join(cells) + " |")
        if peers:
            ratios = [peer_ratio(peers, influences, error) for _, influences, error, _ in row["points"][1:]]
            lines.append("| ratio to the best peer | | " + " | ".join(ratios) + " |")
    return "\n".join(lines) + "\n"


def peer_ratio(peers: dict, influences: int, error: float) -> str:
    best, _ = bench_lod.best_peer(peers, influences)
    return "-" if best is None else f"{error / best:.3f}"


def two_stage_markdown(name: str, rows: list[dict], chain_row: dict, peers: dict | None = None) -> str:
    """The two-stage levels, and at each of the chain's levels the best two-stage error at its total influences
    (log-log along each K's front, the least over K) beside the chain's; with `peers`, both as ratios."""
    fronts = [lod_peers.frontier([{"influences": influences, "error": error}
                                  for _, influences, error, _ in row["points"]]) for row in rows]
    lines = [f"## {name}: geometry first, then K influences a vertex", "",
             "| level | influences | chain | best two-stage | chain / two-stage |"
             + (" chain, two-stage: ratio to the best peer |" if peers else ""),
             "|---|---:|---:|---:|---:|" + ("---|" if peers else "")]
    for level, (_, influences, error, _) in enumerate(chain_row["points"][1:], start=1):
        found = [at for at in (lod_peers.error_at(front, influences) for front in fronts) if at is not None]
        two_stage = min(found) if found else None
        cells = [f"1/{2 ** level}", str(influences), f"{error:.2e}",
                 "-" if two_stage is None else f"{two_stage:.2e}",
                 "-" if two_stage is None else f"{error / two_stage:.2f}"]
        if peers:
            cells.append(f"{peer_ratio(peers, influences, error)}, "
                         + ("-" if two_stage is None else peer_ratio(peers, influences, two_stage)))
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "two-stage levels (vertices, influences: error to full detail):", ""]
    for row in rows:
        lines.append(f"- K = {row['per_vertex']}: " + "; ".join(f"{vertices}, {influences}: {error:.2e}"
                                                              for vertices, influences, error, _ in row["points"]))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=os.path.join(bench_lod.REPOSITORY, "..", "shared", "data"))
    parser.add_argument("--datasets", default="horse,creature,arm,cow,dembones")
    parser.add_argument("--variants", default=DEFAULT_VARIANTS)
    parser.add_argument("--levels", type=int, default=bench_lod.CHAIN_LEVELS)
    parser.add_argument("--from", dest="start", choices=("model", "weights"), default="model")
    parser.add_argument("--statistics", choices=("training", "held-out"), default="training")
    parser.add_argument("--spread", type=float, default=0.0, metavar="RADIANS")
    parser.add_argument("--peers", metavar="RESULTS.json",
                        help="bench_lod's results (--json) whose peers give each level's ratio to the best peer")
    parser.add_argument("--two-stage", action="store_true",
                        help="also the two-stage levels: geometry first, then K = 1, 2, 3 influences a vertex")
    arguments = parser.parse_args(argv)
    variants = parsed_variants(arguments.variants)
    peer_results = {}
    if arguments.peers:
        with open(arguments.peers) as results:
            peer_results = json.load(results)["chain"]
    for name in filter(None, arguments.datasets.split(",")):
        try:
            models = bench_lod.chain_models(name, arguments.data)
        except MissingData as missing:
            print(f"{name}: skipped ({missing})", file=sys.stderr)
            continue
        models = prepared(models, arguments.start, arguments.statistics, arguments.spread)
        rows = variant_rows(models, variants, arguments.levels)
        peers = peer_results.get(name, {}).get("peers")
        print(markdown(name, rows, peers), flush=True)
        if arguments.two_stage:
            print(two_stage_markdown(name, two_stage_rows(models), rows[-1], peers), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
