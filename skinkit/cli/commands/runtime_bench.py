"""skinkit runtime-bench: the runtime on a synthetic crowd (no scene needed): culling + level selection + one batched
skinning call per frame against the whole crowd at full detail, the kernels' throughput and the memory bandwidth."""
import os

from ...model import SkinkitError

HELP = "time the runtime (culling, LOD selection, geomorphing SIMD skinning) on a synthetic crowd"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("runtime-bench", help=HELP, description=HELP, parents=[common["json"]])
    parser.add_argument("--characters", type=int, default=100, help="instances in the crowd (default 100)")
    parser.add_argument("--vertices", default="10000:50000",
                        help="vertices per character, N or MIN:MAX spread over --kinds characters (default 10000:50000)")
    parser.add_argument("--kinds", type=int, default=5, help="distinct characters (default 5)")
    parser.add_argument("--bones", type=int, default=16, help="bones per character, root included (default 16)")
    parser.add_argument("--influences", type=int, default=4, help="influences per vertex (default 4)")
    parser.add_argument("--levels", type=int, default=4, help="levels of detail per character (default 4)")
    parser.add_argument("--frames", type=int, default=5, help="random cameras (default 5)")
    parser.add_argument("--pixel-tolerance", type=float, default=1.0, help="allowed error in pixels (default 1)")
    parser.add_argument("--kernel", default="auto", choices=["auto", "scalar", "sse2", "avx2"])
    parser.add_argument("--layout", default="csr", choices=["csr", "fixed"],
                        help="the pack skinned: csr (any influences per vertex) or fixed (K slots per vertex, "
                             "16-bit bones: fewer bytes; default csr)")
    parser.add_argument("--threads", type=int, default=0, help="0: every processor (default)")
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats per frame (default 5)")
    parser.add_argument("--seed", type=int, default=0)
    return parser


def vertex_range(text: str) -> tuple[int, int]:
    try:
        low, _, high = text.partition(":")
        bounds = (int(low), int(high or low))
    except ValueError:
        raise SkinkitError(f"--vertices: expected N or MIN:MAX, got {text!r}") from None
    if not 0 < bounds[0] <= bounds[1]:
        raise SkinkitError(f"--vertices: expected 0 < MIN <= MAX, got {text!r}")
    return bounds


def run(arguments) -> dict:
    import numpy as np

    from ... import crowd, runtime

    for name in ("characters", "kinds", "frames", "repeats", "levels"):
        if getattr(arguments, name) < 1:
            raise SkinkitError(f"--{name}: must be at least 1")
    if arguments.threads < 0:
        raise SkinkitError("--threads: must be 0 (every processor) or more")
    if arguments.kernel not in runtime.available_kernels():
        raise SkinkitError(f"--kernel: {arguments.kernel} does not run on this CPU")
    low, high = vertex_range(arguments.vertices)
    kinds = min(arguments.kinds, arguments.characters)
    scene = crowd.random_crowd(arguments.characters, (low, high), kinds, arguments.bones, arguments.influences,
                               arguments.levels, seed=arguments.seed)
    rng = np.random.default_rng(arguments.seed + 1)
    cameras = [crowd.random_camera(rng, 40.0) for _ in range(arguments.frames)]
    measured = crowd.measure_crowd(scene, cameras, arguments.pixel_tolerance, arguments.kernel, arguments.threads,
                                   arguments.repeats, arguments.seed, layout=arguments.layout)
    median = measured["median"]
    full_seconds = median["full_ms"] / 1e3
    layout = {"layout": arguments.layout}
    if arguments.layout == "fixed":
        fixed = scene.pack.fixed()
        layout.update(slots_per_vertex=fixed.influences_per_vertex, floats_per_slot=fixed.floats_per_slot)
        full_bytes = crowd.fixed_bytes_moved(int(median["full_vertices"]), fixed.influences_per_vertex,
                                             fixed.floats_per_slot)
    else:
        influences = int(scene.pack.influence_counts()[scene.first_mesh[scene.character]].sum())
        full_bytes = crowd.bytes_moved(int(median["full_vertices"]), influences)
    return {"characters": arguments.characters, "kinds": kinds, "vertices": [low, high], **layout,
            "kernel": arguments.kernel, "kernels_available": runtime.available_kernels(),
            "threads": arguments.threads, "pixel_tolerance": arguments.pixel_tolerance,
            "full_detail_ms": median["full_ms"], "culled_lod_ms": median["lod_ms"], "speedup": median["speedup"],
            "visible": median["visible"], "mean_level": median["mean_level"],
            "pixel_error_max": measured["max_pixel_error"],
            "full_detail_mverts_per_s": median["full_vertices"] / full_seconds / 1e6,
            "full_detail_gb_per_s": full_bytes / full_seconds / 1e9,
            "triad_gb_per_s": crowd.triad_bandwidth(threads=arguments.threads or len(os.sched_getaffinity(0))) / 1e9,
            "frames": measured["frames"]}
