"""The runtime (Merry 2007, chapter 7) against the machine's memory bandwidth and its peers, in one run.

    PYTHONPATH=. .venv/bin/python bench/bench_runtime.py [--quick] [--json out.json] [--markdown out.md]

1. Bandwidth: a STREAM-style triad (numpy, float64; two passes a = s c, a += b, so 5 arrays' bytes count per
   element) on one thread and on every core.
2. Throughput at 1M vertices, 4 influences, in two tables that compare like with like:
   a. positions only, no geomorph (what sk_animation_space_evaluate_f32 computes): evaluate beside the runtime's
      CSR pack at f = 0 and its fixed-K pack without dp (sk_runtime_skin_fixed, 16-bit bones, p only);
   b. the full runtime path, geomorph at f = 0.5: the CSR pack and the fixed-K pack (p/dp pairs), then with both
      tangents as well;
   scalar, SSE2 and AVX2+FMA kernels on one thread and the auto kernel on every core, each with the bytes its layout
   must move. One-thread rows also give the thread's CPU time (time.thread_time), which the other processes of a
   shared machine do not inflate. Targets: the best SIMD kernel of table a >= 2x evaluate on one core; the
   geomorph path (table b, every core) >= 60% of the triad.
3. The linear cost model of thesis Tables 8.7/8.8, T = aV + bI + cO + d (V vertices, I influences, O objects), fitted
   by weighted least squares (variance proportional to time) over a grid of mesh sizes, influences per vertex and
   object counts, for scalar, SSE2, AVX2 (one thread), threads (auto kernel, every core), the compute shader on
   Mesa llvmpipe (when an OpenGL 4.3 context exists), numpy, and Blender's Armature modifier (depsgraph update of
   O meshes on one armature, bench_evaluate's scene builder).
4. A crowd: 100 characters of 10-50k vertices (skinkit.crowd), random cameras: culling + level selection + one
   batched skinning call per frame against all characters at full detail (speedup, and the pixel error).
The machine is shared: its load average is recorded before and after, and every time is the minimum over repeats
(what interference from other work leaves of the code's own cost).
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from common import machine_info, machine_line, parallel_speedup, write_outputs

from skinkit import _core, crowd, runtime

CORES = len(os.sched_getaffinity(0))


def load_average() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


# ---- 1-2: bandwidth and throughput -----------------------------------------------------------------------------

def evaluate_bytes(vertices: int, influences: int) -> int:
    """sk_animation_space_evaluate_f32: per influence p 16 bytes and a bone 4, per vertex an offset 4 and its output
    24 (read for ownership, then written)."""
    return influences * 20 + vertices * 28


def best_times(call, repeats: int) -> tuple[float, float]:
    """(wall seconds, thread CPU seconds), each the minimum over repeats after one untimed call."""
    call()
    wall, cpu = [], []
    for _ in range(repeats):
        started, started_cpu = time.perf_counter(), time.thread_time()
        call()
        cpu.append(time.thread_time() - started_cpu)
        wall.append(time.perf_counter() - started)
    return min(wall), min(cpu)


def skin_call(pack, fraction: float, kernel: str, threads: int, tangents: bool = False):
    poses = np.tile(np.eye(4), (1, pack.bone_count, 1, 1))
    poses[:, :, :3, :] = np.random.default_rng(0).uniform(-1, 1, (1, pack.bone_count, 3, 4))
    matrices = runtime.bone_matrices(poses)
    out = np.empty((int(pack.vertex_counts[0]), 3), np.float32)
    return lambda: runtime.skin(pack, [0], [fraction], matrices, tangents=tangents, kernel=kernel, threads=threads,
                                out=out)


def timed_row(call, threads: int, bytes_moved: int, vertices: int, repeats: int) -> dict:
    wall, cpu = best_times(call, repeats)
    row = {"seconds": wall, "bytes": bytes_moved, "mverts_per_s": vertices / wall / 1e6,
           "gb_per_s": bytes_moved / wall / 1e9}
    if threads == 1:
        row.update(cpu_seconds=cpu, cpu_mverts_per_s=vertices / cpu / 1e6)
    return row


def throughput(vertices: int, influences: int, repeats: int) -> dict:
    """{"positions only": rows, "geomorph": rows}, each row named by method, layout, kernel and threads."""
    pack = crowd.synthetic_mesh(vertices, influences)
    with_tangents = runtime.RuntimePack.from_meshes([{
        "offsets": pack.offsets, "bones": pack.bones, "coordinates": pack.positions[:, :4],
        "delta": pack.positions[:, 4:], "tangents": (pack.positions[:, :4], pack.positions[:, :4]),
        "tangent_deltas": (pack.positions[:, 4:], pack.positions[:, 4:])}], pack.bone_count)
    fixed, plain = pack.fixed(), pack.fixed(morphs=False)
    fixed_tangents = with_tangents.fixed()
    slots = fixed.influences_per_vertex
    count = influences * vertices
    coordinates = np.ascontiguousarray(pack.positions[:, :4]).reshape(-1)
    poses = np.tile(np.eye(4, dtype=np.float32), (pack.bone_count, 1, 1))
    poses[:, :3, :] = np.random.default_rng(1).uniform(-1, 1, (pack.bone_count, 3, 4))
    destination = np.empty(3 * vertices, np.float32)
    kernels = [k for k in runtime.available_kernels() if k != "auto"]
    thread_settings = [(1, "1 thread"), (0, f"{CORES} threads")]
    plain_rows, morph_rows = {}, {}
    for threads, label in thread_settings:
        plain_rows[f"evaluate f32 (today), {label}"] = timed_row(lambda threads=threads: _core.animation_space_evaluate(
            destination, pack.offsets, pack.bones, coordinates, poses.reshape(-1), threads), threads,
            evaluate_bytes(vertices, count), vertices, repeats)
    for kernel, threads, label in [(k, 1, "1 thread") for k in kernels] + [("auto", 0, f"{CORES} threads")]:
        plain_rows[f"runtime CSR f = 0, {kernel}, {label}"] = timed_row(
            skin_call(pack, 0.0, kernel, threads), threads, crowd.bytes_moved(vertices, count), vertices, repeats)
        plain_rows[f"runtime fixed-K p only, {kernel}, {label}"] = timed_row(
            skin_call(plain, 0.0, kernel, threads), threads, crowd.fixed_bytes_moved(vertices, slots, 4), vertices,
            repeats)
        morph_rows[f"runtime CSR, {kernel}, {label}"] = timed_row(
            skin_call(pack, 0.5, kernel, threads), threads, crowd.bytes_moved(vertices, count), vertices, repeats)
        morph_rows[f"runtime fixed-K, {kernel}, {label}"] = timed_row(
            skin_call(fixed, 0.5, kernel, threads), threads, crowd.fixed_bytes_moved(vertices, slots, 8), vertices,
            repeats)
    for threads, label in thread_settings:
        morph_rows[f"runtime fixed-K + 2 tangents, auto, {label}"] = timed_row(
            skin_call(fixed_tangents, 0.5, "auto", threads, tangents=True), threads,
            crowd.fixed_bytes_moved(vertices, slots, 8, streams=3), vertices, repeats)
        morph_rows[f"runtime CSR + 2 tangents, auto, {label}"] = timed_row(
            skin_call(with_tangents, 0.5, "auto", threads, tangents=True), threads,
            crowd.bytes_moved(vertices, count) + count * 64 + vertices * 48, vertices, repeats)
    return {"positions only": plain_rows, "geomorph": morph_rows}


def targets(t: dict, triad: dict) -> dict:
    plain, morph = t["positions only"], t["geomorph"]
    evaluate = plain["evaluate f32 (today), 1 thread"]
    simd = {name: row for name, row in plain.items() if name.startswith("runtime") and name.endswith("1 thread")
            and "scalar" not in name}
    best = max(simd, key=lambda name: simd[name]["mverts_per_s"])
    best_cpu = max(simd, key=lambda name: simd[name]["cpu_mverts_per_s"])
    morph_simd = {name: row for name, row in morph.items() if name.endswith("1 thread") and "scalar" not in name
                  and "tangents" not in name}
    best_morph = max(morph_simd, key=lambda name: morph_simd[name]["mverts_per_s"])
    every_core = {name: row for name, row in morph.items() if name.endswith(f"{CORES} threads")
                  and "tangents" not in name}
    best_all = max(every_core, key=lambda name: every_core[name]["gb_per_s"])
    return {"simd_vs_evaluate": simd[best]["mverts_per_s"] / evaluate["mverts_per_s"], "simd_best": best,
            "simd_vs_evaluate_cpu": simd[best_cpu]["cpu_mverts_per_s"] / evaluate["cpu_mverts_per_s"],
            "simd_best_cpu": best_cpu,
            "geomorph_vs_evaluate": morph_simd[best_morph]["mverts_per_s"] / evaluate["mverts_per_s"],
            "geomorph_best": best_morph,
            "share_of_triad": every_core[best_all]["gb_per_s"] * 1e9 / triad["all"], "share_best": best_all}


# ---- 3: the cost model ---------------------------------------------------------------------------------------------

def design(quick: bool) -> list[tuple[int, int, int]]:
    """(vertices per object, influences per vertex, objects)."""
    sizes = (4000, 16000) if quick else (5000, 20000, 80000)
    return [(v, k, o) for v in sizes for k in (1, 2, 4, 8) for o in (1, 4, 16) if v * o <= 1_300_000]


def weighted_fit(rows: list[dict]) -> dict:
    """T = aV + bI + cO + d by least squares with variance proportional to T (weights 1/T), as Merry fitted his
    Tables 8.7/8.8 in R; coefficients with their standard errors."""
    x = np.array([[r["V"], r["I"], r["O"], 1.0] for r in rows])
    t = np.array([r["seconds"] for r in rows])
    w = 1 / np.sqrt(t)
    beta, *_ = np.linalg.lstsq(x * w[:, None], t * w, rcond=None)
    residual = (t - x @ beta) * w
    dof = max(len(t) - 4, 1)
    sigma2 = residual @ residual / dof
    covariance = sigma2 * np.linalg.inv((x * w[:, None]).T @ (x * w[:, None]))
    se = np.sqrt(np.diag(covariance))
    worst = float(np.abs((x @ beta - t) / t).max())
    return {"ns_per_vertex": beta[0] * 1e9, "ns_per_vertex_se": se[0] * 1e9,
            "ns_per_influence": beta[1] * 1e9, "ns_per_influence_se": se[1] * 1e9,
            "us_per_object": beta[2] * 1e6, "us_per_object_se": se[2] * 1e6,
            "us_fixed": beta[3] * 1e6, "us_fixed_se": se[3] * 1e6, "points": len(rows), "worst_relative_residual": worst}


def cpu_rows(kernel: str, threads: int, grid, repeats: int, fixed: bool = False) -> list[dict]:
    """fixed: the fixed-K pack, whose influences I count its slots (k rounded up to even)."""
    rows = []
    for v, k, o in grid:
        pack = crowd.synthetic_mesh(v, k, seed=v + k)
        if fixed:
            pack = pack.fixed()
        slots = pack.influences_per_vertex if fixed else k
        rows.append({"V": v * o, "I": v * o * slots, "O": o, "seconds": crowd.skin_seconds(
            pack, o, kernel, threads, repeats, best=True)})
    return rows


def numpy_rows(grid, repeats: int) -> list[dict]:
    """Animation space in numpy, float32, the same (p, dp) data: q = p + f dp, per influence G q, summed per vertex."""
    rows = []
    for v, k, o in grid:
        if v * o * k > 2_000_000:
            continue  # numpy's temporaries: minutes and gigabytes beyond this
        pack = crowd.synthetic_mesh(v, k, seed=v + k)
        matrices = np.random.default_rng(2).uniform(-1, 1, (o, pack.bone_count, 3, 4)).astype(np.float32)
        p, dp = pack.positions[:, :4], pack.positions[:, 4:]
        starts = pack.offsets[:-1]

        def run():
            for instance in range(o):
                q = p + np.float32(0.5) * dp
                per = np.einsum("kij,kj->ki", matrices[instance][pack.bones], q)
                np.add.reduceat(per, starts, axis=0)

        rows.append({"V": v * o, "I": v * o * k, "O": o, "seconds": crowd.timed_seconds(run, repeats, best=True)})
    return rows


def llvmpipe_rows(grid, repeats: int) -> tuple[list[dict], str]:
    """The compute shader's dispatch (buffers uploaded before, results not read back), finished with glFinish."""
    try:
        from skinkit.shaders import gl
        context = gl.create_context()
    except (ImportError, RuntimeError) as error:
        return [], f"skipped: {error}"
    renderer = context.info["GL_RENDERER"]
    rows = []
    for v, k, o in grid:
        if v * o > 400_000:
            continue  # llvmpipe runs the shader on the CPU: keep the run short
        pack = crowd.synthetic_mesh(v, k, seed=v + k)
        skinner = gl.ComputeSkinner(context, pack)
        matrices = np.random.default_rng(3).uniform(-1, 1, (o, pack.bone_count, 12)).astype(np.float32)
        dispatch = skinner.prepare(np.zeros(o, np.int32), np.full(o, 0.5, np.float32), matrices)
        rows.append({"V": v * o, "I": v * o * k, "O": o, "seconds": crowd.timed_seconds(dispatch, repeats, best=True)})
        skinner.release()
    context.release()
    return rows, renderer


def blender_rows(grid, repeats: int) -> tuple[list[dict], str]:
    """Blender's Armature modifier: O meshes of V/O vertices with k weights each on one 16-bone armature, the time
    of depsgraph.update() after a pose change (bench_evaluate's scene builder and poses)."""
    try:
        import bpy
        import bench_evaluate as scene
    except ImportError as error:
        return [], f"skipped: {error}"
    bpy.ops.wm.read_factory_settings(use_empty=True)
    layout = scene.skeleton_layout(16)
    names, heads, tails, parents, _ = layout
    armature = scene.build_armature(names, heads, tails, parents)
    pose_bones = scene.pose_bones_in_order(armature, names)
    poses = scene.random_poses(repeats + 1, len(names), 5)
    rows = []
    for v, k, o in grid:
        if k > 4 or v * o > 400_000:
            continue  # building Blender meshes dominates the run beyond this
        meshes = [scene.build_skinned_mesh(f"bench_{i}", armature, layout, v, k) for i in range(o)]
        scene.blender_pass(meshes[0], pose_bones, poses, None)  # warm: relations and first evaluation
        vertices = sum(len(m.data.vertices) for m in meshes)
        rows.append({"V": vertices, "I": vertices * k, "O": o, "seconds": min(scene.blender_pass(
            meshes[0], pose_bones, poses, None)["evaluate"] / (repeats + 1) for _ in range(3))})
        for mesh_object in meshes:
            scene.remove_object(mesh_object)
    return rows, bpy.app.version_string


# ---- 4: the crowd -----------------------------------------------------------------------------------------------

def crowd_run(quick: bool, frames: int, repeats: int) -> dict:
    started = time.perf_counter()
    scene = crowd.random_crowd(30 if quick else 100, (10_000, 50_000), kinds=5, seed=0)
    built = time.perf_counter() - started
    rng = np.random.default_rng(1)
    cameras = [crowd.random_camera(rng, 40.0) for _ in range(frames)]
    result = {}
    for tolerance in (1.0, 4.0):
        result[f"{tolerance:g} px"] = crowd.measure_crowd(scene, cameras, tolerance, "auto", 0, repeats, best=True)
    result["characters"] = scene.instance_count
    result["vertices"] = int(scene.pack.vertex_counts[scene.first_mesh[scene.character]].sum())
    result["build_seconds"] = built
    result["level_vertices"] = [c.pack.vertex_counts.tolist() for c in scene.characters]
    result["level_epsilons"] = [c.pack.epsilons.tolist() for c in scene.characters]
    return result


# ---- report --------------------------------------------------------------------------------------------------------

def markdown(results: dict) -> str:
    info = results["machine"]
    lines = [f"# Runtime: culling, LOD selection, geomorphing SIMD skinning", "",
             machine_line(info) + f"; load average {info['load_before']} before, {info['load_after']} after) · "
             f"kernels {', '.join(results['kernels'])}", "", f"`{info['command']}`", "",
             "Every time is the minimum over repeats: the machine is shared with other work.", ""]
    triad = results["triad"]
    lines += ["## Memory bandwidth (STREAM-style triad, numpy float64, 5 arrays counted per element)", "",
              f"1 thread {triad['1 thread'] / 1e9:.2f} GB/s · {CORES} threads {triad['all'] / 1e9:.2f} GB/s", ""]
    titles = {"positions only": "positions only, no geomorph (what evaluate computes)",
              "geomorph": "the runtime path, geomorph at f = 0.5"}
    for table, rows in results["throughput"].items():
        lines += [f"## Throughput at {results['throughput_vertices']:,} vertices, 4 influences: {titles[table]}", "",
                  "| method | Mverts/s (wall) | Mverts/s (thread CPU) | bytes / vertex | GB/s moved | share of triad "
                  "(same threads) |", "|---|---:|---:|---:|---:|---:|"]
        for name, row in rows.items():
            bandwidth = triad["1 thread"] if "1 thread" in name else triad["all"]
            cpu = f"{row['cpu_mverts_per_s']:.1f}" if "cpu_mverts_per_s" in row else ""
            lines.append(f"| {name} | {row['mverts_per_s']:.1f} | {cpu} | "
                         f"{row['bytes'] / results['throughput_vertices']:.0f} | {row['gb_per_s']:.2f} | "
                         f"{row['gb_per_s'] * 1e9 / bandwidth:.0%} |")
        lines.append("")
    g = results["targets"]
    lines += [f"Targets: best SIMD kernel on one core / evaluate on one core, positions only = "
              f"**{g['simd_vs_evaluate']:.2f}x** wall ({g['simd_best']}), **{g['simd_vs_evaluate_cpu']:.2f}x** thread "
              f"CPU time ({g['simd_best_cpu']}) (target 2x); the geomorph path on one core / evaluate = "
              f"{g['geomorph_vs_evaluate']:.2f}x ({g['geomorph_best']}); geomorph on every core = "
              f"**{g['share_of_triad']:.0%}** of the triad ({g['share_best']}) (target 60%).", ""]
    lines += ["## Cost model T = aV + bI + cO + d (weighted least squares, variance proportional to time)", "",
              "| method | ns / vertex | ns / influence | µs / object | µs fixed | points | worst residual |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    for name, fit in results["cost_model"].items():
        if "skipped" in fit:
            lines.append(f"| {name} | {fit['skipped']} | | | | | |")
            continue
        lines.append(f"| {name} | {fit['ns_per_vertex']:.2f} ± {fit['ns_per_vertex_se']:.2f} | "
                     f"{fit['ns_per_influence']:.2f} ± {fit['ns_per_influence_se']:.2f} | "
                     f"{fit['us_per_object']:.1f} ± {fit['us_per_object_se']:.1f} | "
                     f"{fit['us_fixed']:.1f} ± {fit['us_fixed_se']:.1f} | {fit['points']} | "
                     f"{fit['worst_relative_residual']:.0%} |")
    c = results["crowd"]
    lines += ["", f"## Crowd: {c['characters']} characters, {c['vertices']:,} vertices at full detail, "
                  f"{len(c['1 px']['frames'])} random cameras", "",
              "Per frame (median over cameras of each camera's best frame): culling + level selection + one batched skinning call, against one "
              "batched call skinning every character at LOD0. Pixel error: the largest screen distance (1920 px wide, "
              "60° field of view) between a visible full-detail vertex and its image on the drawn, geomorphed level.", "",
              "| tolerance | full detail ms | culled + LOD ms | speedup | visible | mean level | vertices drawn | "
              "max pixel error |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for tolerance in ("1 px", "4 px"):
        m = c[tolerance]["median"]
        lines.append(f"| {tolerance} | {m['full_ms']:.1f} | {m['lod_ms']:.2f} | {m['speedup']:.1f}x | "
                     f"{m['visible']:.0f} | {m['mean_level']:.2f} | {m['drawn_vertices']:,.0f} | "
                     f"{c[tolerance]['max_pixel_error']:.2f} |")
    lines += ["", "Levels per character (vertices): " + "; ".join(str(v) for v in c["level_vertices"]), ""]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a smaller grid and crowd (a smoke run)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--json")
    parser.add_argument("--markdown")
    arguments = parser.parse_args(argv)
    info = machine_info()
    info["load_before"] = load_average()
    info["parallel_speedup_before"] = parallel_speedup()
    repeats = 3 if arguments.quick else arguments.repeats
    vertices = 200_000 if arguments.quick else 1_000_000
    results = {"machine": info, "kernels": runtime.available_kernels(), "throughput_vertices": vertices}
    results["triad"] = {"1 thread": crowd.triad_bandwidth(threads=1), "all": crowd.triad_bandwidth(threads=CORES)}
    results["throughput"] = throughput(vertices, 4, repeats)
    results["targets"] = targets(results["throughput"], results["triad"])
    grid = design(arguments.quick)
    fits = {}
    raw = {}
    for kernel in [k for k in runtime.available_kernels() if k != "auto"]:
        raw[f"runtime {kernel}, 1 thread"] = cpu_rows(kernel, 1, grid, repeats)
    raw[f"runtime auto, {CORES} threads"] = cpu_rows("auto", 0, grid, repeats)
    for kernel in [k for k in runtime.available_kernels() if k in ("sse2", "avx2")]:
        raw[f"runtime fixed-K {kernel}, 1 thread"] = cpu_rows(kernel, 1, grid, repeats, fixed=True)
    raw[f"runtime fixed-K auto, {CORES} threads"] = cpu_rows("auto", 0, grid, repeats, fixed=True)
    raw["numpy AS f32"] = numpy_rows(grid, repeats)
    gpu, renderer = llvmpipe_rows(grid, repeats)
    raw[f"compute shader ({renderer})" if gpu else "compute shader (llvmpipe)"] = gpu or renderer
    blender, version = blender_rows(grid, repeats)
    raw[f"Blender {version} Armature modifier" if blender else "Blender Armature modifier"] = blender or version
    for name, rows in raw.items():
        fits[name] = weighted_fit(rows) if isinstance(rows, list) and len(rows) >= 5 else {"skipped": str(rows)}
    results["cost_model"] = fits
    results["cost_model_points"] = {k: v for k, v in raw.items() if isinstance(v, list)}
    results["crowd"] = crowd_run(arguments.quick, 3 if arguments.quick else arguments.frames, repeats)
    info["load_after"] = load_average()
    info["parallel_speedup_after"] = parallel_speedup()
    write_outputs(results, arguments.json, arguments.markdown, markdown)
    print(markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
