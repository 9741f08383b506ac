"""The ray-cast bake alone (issue 12's 2x against Cycles), for quick iteration without Cycles.

The surfaces are bench_bake.py's (the arm's and creature's 4-level chains, the horse's 10% level, each baked from its
LOD0 with a cage of 2% of LOD0's diagonal). Building them needs Blender's Python module and takes minutes, so they
are cached as .npz under --scratch the first time; every later run (and `--callgrind`, which runs under valgrind)
reads the cache without importing bpy.

Per dataset and size: the ray-cast bake's CPU time on one thread (the least of --repeats runs of
time.thread_time(): the fair measure on a loaded shared machine) as bench_bake.py times it (map only, tangents
included). `--save-reference` stores each bake's image, coverage and exact source normals; `--check-reference` holds
every later bake to them (image and coverage identical, exact normals within 1e-12) on 1 and 3 threads.
`--callgrind` runs one one-thread bake per dataset and size, for `valgrind --tool=callgrind
--toggle-collect=sk_bake_normals`. `--cycles` builds the chains afresh and times Blender's Cycles bake (1 sample, one
thread, bench_bake.cycles_bake: the least of its repeats, as process CPU time) beside the ray cast in the same
process, for the speed-up at equal load.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, "bench"))  # bench_bake, imported only where Blender is needed

from skinkit import normal_maps as nm  # noqa: E402

MARGIN = 8
EXACT_TOLERANCE = 1e-12


def build_chain(name: str):
    """bench_bake.py's dataset as Blender objects: (LOD0, the level baked)."""
    import bench_bake

    chain = bench_bake.horse_chain() if name == "horse" else bench_bake.sample_chain(name)
    return chain[0], chain[-1]


def build_surfaces(name: str, chain=None) -> dict:
    """(target, source, cage) of bench_bake.py's dataset, read through the Blender bridge as bench_bake.py does."""
    import bpy

    import bench_bake
    from skinkit.blender import normal_maps as bridge

    lod0, level = chain or build_chain(name)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    target, uv_name = bridge.read_surface(level, depsgraph)
    source, _ = bridge.read_surface(lod0, depsgraph, uv_name, name="source")
    diagonal = float(np.linalg.norm(np.ptp(np.array([v.co for v in lod0.data.vertices]), axis=0)))
    arrays = {"cage": bench_bake.CAGE_FRACTION * diagonal}
    for prefix, surface in (("target", target), ("source", source)):
        for field in ("triangles", "positions", "normals", "uv"):
            arrays[f"{prefix}_{field}"] = getattr(surface, field)
    return arrays


def surfaces(name: str, scratch: str) -> tuple[nm.BakeSurface, nm.BakeSurface, float]:
    path = os.path.join(scratch, f"{name}_surfaces.npz")
    if not os.path.exists(path):
        os.makedirs(scratch, exist_ok=True)
        np.savez(path, **build_surfaces(name))
    arrays = np.load(path)
    made = [nm.BakeSurface(*(arrays[f"{prefix}_{field}"] for field in ("triangles", "positions", "normals", "uv")))
            for prefix in ("target", "source")]
    return made[0], made[1], float(arrays["cage"])


def bake(target, source, cage, size, threads=1, diagnostics=False) -> nm.NormalMap:
    return nm.bake_normals(target, source, size=size, mode="ray", supersample=1, margin=MARGIN, cage=cage,
                           thread_count=threads, diagnostics=diagnostics)


def cpu_seconds(target, source, cage, size, repeats) -> float:
    best = np.inf
    for _ in range(repeats):
        started = time.thread_time()
        bake(target, source, cage, size)
        best = min(best, time.thread_time() - started)
    return best


def cycles_rows(name: str, sizes, repeats) -> list[dict]:
    """The ray cast's and Cycles' CPU seconds on one thread, measured in turn on the same chain."""
    import bpy

    import bench_bake

    chain = build_chain(name)
    arrays = build_surfaces(name, chain)
    target, source = (nm.BakeSurface(*(arrays[f"{prefix}_{field}"] for field in ("triangles", "positions", "normals",
                                                                                  "uv"))) for prefix in ("target", "source"))
    rows = []
    for size in sizes:
        ours = cpu_seconds(target, source, arrays["cage"], size, repeats)
        _, _, cycles = bench_bake.cycles_bake(bpy.context.scene, chain[0], chain[1], size, arrays["cage"], 1, 1)
        rows.append({"dataset": name, "size": size, "cpu_seconds": ours, "cycles_cpu_seconds": cycles,
                     "speedup": cycles / ours})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def check_reference(path, target, source, cage, size) -> str:
    reference = np.load(path)
    for threads in (1, 3):
        result = bake(target, source, cage, size, threads, diagnostics=True)
        if not np.array_equal(result.image, reference["image"]):
            return f"image differs on {threads} threads at {int((result.image != reference['image']).sum())} values"
        if not np.array_equal(result.coverage, reference["coverage"]):
            return f"coverage differs on {threads} threads"
        gap = float(np.abs(result.exact - reference["exact"]).max())
        if gap > EXACT_TOLERANCE:
            return f"exact normals differ by {gap:.3g} on {threads} threads"
    return "identical"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--datasets", default="arm,creature,horse")
    parser.add_argument("--sizes", default="512,1024")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scratch", default=os.path.join(ROOT, "build", "bench_raycast"))
    parser.add_argument("--save-reference", action="store_true")
    parser.add_argument("--check-reference", action="store_true")
    parser.add_argument("--callgrind", action="store_true")
    parser.add_argument("--cycles", action="store_true")
    parser.add_argument("--json")
    parser.add_argument("--markdown")
    args = parser.parse_args(argv)
    load_before = os.getloadavg()
    rows = []
    for name in args.datasets.split(","):
        if name == "horse" and not os.path.isdir(os.path.join(os.path.dirname(ROOT), "shared", "data", "horse")) \
                and not os.path.exists(os.path.join(args.scratch, "horse_surfaces.npz")):
            print("horse: skipped, no data at ../shared/data/horse (see its README)", file=sys.stderr)
            continue
        if args.cycles:
            rows += cycles_rows(name, [int(s) for s in args.sizes.split(",")], args.repeats)
            continue
        target, source, cage = surfaces(name, args.scratch)
        for size in (int(s) for s in args.sizes.split(",")):
            reference = os.path.join(args.scratch, f"{name}_{size}_reference.npz")
            row = {"dataset": name, "size": size, "source_triangles": len(source.triangles),
                   "target_triangles": len(target.triangles)}
            if args.callgrind:
                bake(target, source, cage, size)
            else:
                row["cpu_seconds"] = cpu_seconds(target, source, cage, size, args.repeats)
            if args.save_reference:
                result = bake(target, source, cage, size, diagnostics=True)
                np.savez(reference, image=result.image, coverage=result.coverage, exact=result.exact)
            if args.check_reference:
                row["reference"] = check_reference(reference, target, source, cage, size)
            rows.append(row)
            print(json.dumps(row), flush=True)
    from bench.common import machine_info, write_outputs

    results = {"machine": machine_info() | {"load_average_before": load_before, "load_average_after": os.getloadavg()},
               "rows": rows}
    write_outputs(results, args.json, args.markdown, markdown)
    return 0


def markdown(results: dict) -> str:
    machine = results["machine"]
    lines = [f"Ray-cast bake, one thread, CPU seconds (`time.thread_time`, least of the repeats); {machine['date']}, "
             f"{machine['cpu']}, load average {machine['load_average_before'][0]:.1f} before, "
             f"{machine['load_average_after'][0]:.1f} after; `{machine['command']}`", "",
             "| data, size | ray-cast CPU s | Cycles 1 sample CPU s | speed-up |", "|---|---:|---:|---:|"]
    for row in results["rows"]:
        cycles = row.get("cycles_cpu_seconds")
        lines.append(f"| {row['dataset']} {row['size']} | {row['cpu_seconds']:.4f} | "
                     + (f"{cycles:.4f} | {row['speedup']:.2f}x |" if cycles else "- | - |"))
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
