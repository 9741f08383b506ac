"""Texture atlases for animated characters: skinkit's unwrap vs Blender's own Unwrap, libigl's LSCM and xatlas.

    .venv/bin/python bench/bench_unwrap.py [--data ../shared/data] [--only NAME ...] \
        [--json bench/unwrap_results.json] [--markdown bench/unwrap_results.md]

Data: the horse of ../shared/data/horse (rest = reference.obj; the animation metric is the frame average
over the rest pose and the 10 example poses; evaluated over the 48 gallop frames, which the metric never
saw), skipped with a message when the folder is absent; the Blender samples arm and creature (animation
space from their skinning with the pose statistics of their action; evaluated over the action's frames as
Blender's Armature modifier deforms them).

On each, one segmentation (skinkit's, in the rest metric, no straightening) gives the charts; then, on those
same charts (marked as seams where a peer needs seams):
  skinkit in the rest metric and in the animation metric (LSCM in the metric with Sander's stretch
  optimisation, free boundaries, as Table 8.4 of the thesis), and the animation metric with straightening;
  Blender's Unwrap (Conformal, Angle Based, Minimum Stretch) in the pinned Blender (bpy 4.5);
  libigl's LSCM per chart (igl.lscm, two boundary vertices pinned far apart), packed by skinkit's packer;
  xatlas with its own charts (it segments by itself; not on the same charts).
Measures: L2 stretch averaged over the evaluation frames (Sander 2001's normalised mesh stretch of each
frame, then the mean), rest-pose stretch, packing efficiency (the fraction of [0, 1]^2 the uv triangles
cover), flipped uv triangles, charts, and the wall-clock seconds of the unwrap call (skinkit's and Blender's: the fastest of 5 runs; skinkit's
includes packing, as Blender's and xatlas' do; libigl's is the sum of its per-chart solves, without packing).
Stretch with flipped or degenerate triangles is infinite; the table then also gives the value over the
other triangles.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import dataclass

import bpy
import igl
import numpy as np
import xatlas

from skinkit.blender import pose_statistics
from skinkit.blender import unwrap as blender_unwrap
from skinkit.blender.rig import mesh_of
from skinkit.flatten import mesh_stretch, triangle_stretch
from skinkit.pack import pack
from skinkit.meshio import read_obj, read_obj_sequence, sequence_files
from skinkit.model import Mesh
from skinkit.unwrap import edge_lengths_sq, sequence_embedding, unwrap

from common import machine_info, write_outputs

REPOSITORY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TEXTURE_SIZE = 1024
MARGIN = 4
#: Timed runs per skinkit and Blender method; the fastest counts (the others are slowed by other work).
ROUNDS = 5
#: Chart counts of the thesis' segmentations (Table 8.3); None: skinkit's own stopping rule.
CHART_COUNTS = {"horse": 30, "arm": 6, "creature": None}
BLENDER_METHODS = ("CONFORMAL", "ANGLE_BASED", "MINIMUM_STRETCH")


@dataclass
class Character:
    name: str
    positions: np.ndarray          # (V, 3) rest
    triangles: np.ndarray          # (T, 3)
    polygons: np.ndarray | None    # (T,) for Blender meshes with quads
    embedding: np.ndarray          # the animation metric
    frames: np.ndarray             # (F, V, 3) evaluation frames
    blender_object: object         # a mesh object to unwrap with Blender's operator
    notes: str


# ---- data ---------------------------------------------------------------------------------------------


def horse(folder: str) -> Character:
    rest, triangles = read_obj(os.path.join(folder, "reference.obj"))
    poses, _ = read_obj_sequence(sequence_files(os.path.join(folder, "poses")))
    gallop, _ = read_obj_sequence(sequence_files(os.path.join(folder, "gallop")))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    mesh = bpy.data.meshes.new("horse")
    mesh.from_pydata(rest.tolist(), [], triangles.tolist())
    mesh_object = bpy.data.objects.new("horse", mesh)
    bpy.context.scene.collection.objects.link(mesh_object)
    return Character("horse", rest, triangles, None, sequence_embedding(np.concatenate([rest[None], poses])), gallop,
                     mesh_object, f"metric: rest + {len(poses)} poses; evaluated on the {len(gallop)} gallop frames")


def blender_sample(name: str) -> Character:
    bpy.ops.wm.open_mainfile(filepath=os.path.join(REPOSITORY, "blend_samples", f"{name}.blend"), load_ui=False)
    mesh_object = next(o for o in bpy.context.scene.objects if o.type == "MESH")
    armature = mesh_object.modifiers["Armature"].object
    frames = blender_unwrap.deforming_action_frames(mesh_object)
    embedding = blender_unwrap.animation_metric(mesh_object, pose_statistics.compute(armature, "action", frames))
    mesh = mesh_of(mesh_object)
    action = armature.animation_data.action.name
    return Character(name, mesh.positions, mesh.triangles, mesh.triangle_polygons, embedding,
                     blender_unwrap.deformed_positions(mesh_object, frames), mesh_object,
                     f"animation space from action '{action}' ({len(frames)} frames), evaluated on the same frames")


# ---- measuring ----------------------------------------------------------------------------------------


def signed_areas(uv: np.ndarray) -> np.ndarray:
    first, second = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return (first[:, 0] * second[:, 1] - first[:, 1] * second[:, 0]) / 2


def stretch_without_flips(uv: np.ndarray, lengths: np.ndarray) -> float:
    """Sander's normalised L2 stretch over the triangles that are neither flipped nor degenerate."""
    valid = signed_areas(uv) > 0
    per_triangle = triangle_stretch(uv[valid], lengths[valid])
    surface = np.sqrt(np.clip(lengths[valid, 0] * lengths[valid, 2] -
                              ((lengths[valid, 0] + lengths[valid, 2] - lengths[valid, 1]) / 2) ** 2, 0, None)) / 2
    parametric = signed_areas(uv[valid])
    return float(np.sqrt((surface * per_triangle ** 2).sum() / surface.sum() * parametric.sum() / surface.sum()))


def measure(character: Character, method: str, uv: np.ndarray, charts: int, seconds: float, same_charts: bool,
            extra=None) -> dict:
    rest = edge_lengths_sq(character.positions, character.triangles)
    per_frame = [edge_lengths_sq(frame, character.triangles) for frame in character.frames]
    flipped = int((signed_areas(uv) <= 0).sum())
    row = {"method": method, "charts": charts, "same_charts": same_charts, "seconds": seconds,
           "flipped": flipped, "stretch_frames": float(np.mean([mesh_stretch(uv, f) for f in per_frame])),
           "stretch_rest": mesh_stretch(uv, rest), "packing_efficiency": float(np.abs(signed_areas(uv)).sum()),
           "outside_unit_square": bool(uv.min() < -1e-6 or uv.max() > 1 + 1e-6)}
    if flipped:
        row["stretch_frames_unflipped"] = float(np.mean([stretch_without_flips(uv, f) for f in per_frame]))
        row["stretch_rest_unflipped"] = stretch_without_flips(uv, rest)
    row.update(extra or {})
    return row


# ---- the methods --------------------------------------------------------------------------------------


def skinkit_rows(character: Character, seams: np.ndarray) -> list[dict]:
    rows = []
    for label, embedding, straighten in (("skinkit, rest metric", None, False),
                                         ("skinkit, animation metric", character.embedding, False),
                                         ("skinkit, animation metric, straightened", character.embedding, True)):
        seconds = np.inf
        for _ in range(ROUNDS):
            started = time.perf_counter()
            result = unwrap(character.positions, character.triangles, embedding=embedding, seams=seams, mode="seams",
                            straighten=straighten, texture_size=TEXTURE_SIZE, margin=MARGIN,
                            polygons=character.polygons)
            seconds = min(seconds, time.perf_counter() - started)
        rows.append(measure(character, label, result.uv, result.report["charts"], seconds, not straighten,
                            {"stretch_metric": result.report["stretch_metric"]}))
    return rows


def blender_rows(character: Character, seams: np.ndarray) -> list[dict]:
    mesh_object = character.blender_object
    data = mesh_object.data
    data.edges.foreach_set("use_seam", np.zeros(len(data.edges), bool))
    blender_unwrap.mark_edges_as_seams(data, seams)
    if not data.uv_layers:
        data.uv_layers.new(name="UVMap")
    for other in bpy.context.view_layer.objects:
        other.select_set(other == mesh_object)
    bpy.context.view_layer.objects.active = mesh_object
    mesh = mesh_of(mesh_object)
    rows = []
    for method in BLENDER_METHODS:
        seconds = np.inf
        for _ in range(ROUNDS):
            bpy.ops.object.mode_set(mode="EDIT")
            bpy.ops.mesh.select_all(action="SELECT")
            started = time.perf_counter()
            bpy.ops.uv.unwrap(method=method, margin_method="FRACTION", margin=MARGIN / TEXTURE_SIZE)
            seconds = min(seconds, time.perf_counter() - started)
            bpy.ops.object.mode_set(mode="OBJECT")
        loop_uv = np.empty(len(data.loops) * 2, np.float32)
        data.uv_layers.active.uv.foreach_get("vector", loop_uv)
        uv = loop_uv.reshape(-1, 2)[mesh.triangle_loops].astype(np.float64)
        rows.append(measure(character, f"Blender Unwrap, {method.replace('_', ' ').title()}", uv,
                            len(np.unique(blender_unwrap.islands_of(mesh, uv))), seconds, True))
    return rows


def libigl_row(character: Character, charts: np.ndarray) -> dict:
    """igl.lscm on each chart with two boundary vertices pinned (the two farthest apart of its boundary)."""
    uv = np.zeros((len(character.triangles), 3, 2))
    seconds = 0.0
    for chart in range(int(charts.max()) + 1):
        members = np.flatnonzero(charts == chart)
        vertices, local = np.unique(character.triangles[members], return_inverse=True)
        faces = local.reshape(-1, 3).astype(np.int64)
        points = character.positions[vertices]
        loop = np.asarray(igl.boundary_loop(faces), dtype=np.int64)
        distances = np.linalg.norm(points[loop][:, None] - points[loop][None], axis=2)
        first, second = np.unravel_index(np.argmax(distances), distances.shape)
        pins = np.array([loop[first], loop[second]], dtype=np.int64)
        started = time.perf_counter()
        solved = igl.lscm(points, faces, pins, np.array([[0.0, 0.0], [1.0, 0.0]]))
        seconds += time.perf_counter() - started
        uv[members] = (solved[0] if isinstance(solved, tuple) else solved)[faces]
    packed = pack(uv, charts, texture_size=TEXTURE_SIZE, margin=MARGIN,
                  surface_area=np.abs(signed_areas_3d(character.positions, character.triangles)))
    return measure(character, "libigl LSCM per chart (skinkit's packer)", packed.uv, int(charts.max()) + 1, seconds,
                   True)


def signed_areas_3d(positions, triangles) -> np.ndarray:
    corners = positions[triangles]
    return np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1) / 2


def xatlas_row(character: Character) -> dict:
    started = time.perf_counter()
    mapping, indices, uvs = xatlas.parametrize(character.positions.astype(np.float32),
                                               character.triangles.astype(np.uint32))
    seconds = time.perf_counter() - started
    indices = indices.reshape(-1, 3)
    if not np.array_equal(mapping[indices], character.triangles):
        raise RuntimeError("xatlas reordered the faces; its uvs cannot be compared triangle by triangle")
    uv = uvs[indices].astype(np.float64)
    islands = blender_unwrap.islands_of(Mesh.create(character.positions, character.triangles), uv)
    return measure(character, "xatlas (its own charts; mirrored ones unmirrored)", unmirrored(uv, islands),
                   len(np.unique(islands)), seconds, False)


def unmirrored(uv: np.ndarray, islands: np.ndarray) -> np.ndarray:
    """xatlas may lay a chart out mirrored, which textures as well as unmirrored; its triangles would count
    as flipped, so such islands are mirrored back (u -> 1 - u) before measuring."""
    mirrored = np.bincount(islands, weights=signed_areas(uv)) < 0
    result = uv.copy()
    result[mirrored[islands], :, 0] = 1 - result[mirrored[islands], :, 0]
    return result


# ---- one character ------------------------------------------------------------------------------------


def run(character: Character) -> dict:
    print(f"{character.name}: segmenting", file=sys.stderr)
    segmentation = unwrap(character.positions, character.triangles, straighten=False,
                          chart_count=CHART_COUNTS[character.name], polygons=character.polygons)
    seams, charts = segmentation.seams, segmentation.charts
    rows = skinkit_rows(character, seams)
    print(f"{character.name}: Blender", file=sys.stderr)
    rows += blender_rows(character, seams)
    print(f"{character.name}: libigl, xatlas", file=sys.stderr)
    rows.append(libigl_row(character, charts))
    rows.append(xatlas_row(character))
    return {"name": character.name, "vertices": len(character.positions), "triangles": len(character.triangles),
            "frames": len(character.frames), "metric_dimensions": int(character.embedding.shape[1]),
            "charts": int(charts.max()) + 1, "notes": character.notes, "rows": rows, "targets": targets(rows)}


def targets(rows: list[dict]) -> dict:
    """The issue's targets: animation-metric stretch over the frames below every peer on the same charts, and
    time within 2x of Blender's Conformal unwrap."""
    ours = next(r for r in rows if r["method"] == "skinkit, animation metric")
    peers = [r for r in rows if r["same_charts"] and not r["method"].startswith("skinkit")]
    conformal = next(r for r in rows if r["method"].endswith("Conformal"))
    return {"stretch_below_every_peer": all(ours["stretch_frames"] < p["stretch_frames"] for p in peers),
            "time_ratio_to_conformal": ours["seconds"] / conformal["seconds"]}


def report(results: dict) -> str:
    lines = ["# Unwrap benchmark", "", f"`{results['machine']['command']}` on {results['machine']['cpu']} "
             f"({results['machine']['usable_cores']} cores), {results['machine']['date']}; Blender "
             f"{results['machine']['bpy']}, numpy {results['machine']['numpy']}, libigl {results['peers']['libigl']},"
             f" xatlas {results['peers']['xatlas']}.", "",
             f"Texture {TEXTURE_SIZE}x{TEXTURE_SIZE}, margin {MARGIN} texels. Stretch: Sander's normalised L2 "
             "stretch (1 is ideal), over the evaluation frames (mean of the frames) and in the rest pose. "
             "Seconds: the fastest of 5 runs of the unwrap call (1 for libigl and xatlas). † infinite (flipped triangles); the value over the other "
             "triangles follows.", ""]
    for skipped in results["skipped"]:
        lines += [f"*Skipped: {skipped}*", ""]
    for character in results["characters"]:
        lines += [f"## {character['name']}: {character['vertices']} vertices, {character['triangles']} triangles, "
                  f"{character['charts']} charts", "", character["notes"] + ".", "",
                  "| method | same charts | charts | stretch over frames | rest stretch | packing | flipped | s |",
                  "|---|---|---|---|---|---|---|---|"]
        for row in character["rows"]:
            lines.append(f"| {row['method']} | {'yes' if row['same_charts'] else 'no'} | {row['charts']} | "
                         f"{stretch_text(row, 'stretch_frames')} | {stretch_text(row, 'stretch_rest')} | "
                         f"{row['packing_efficiency']:.3f} | {row['flipped']} | {row['seconds']:.2f} |")
        target = character["targets"]
        lines += ["", f"Targets: animation-metric stretch over the frames below every peer on the same charts: "
                      f"**{'met' if target['stretch_below_every_peer'] else 'not met'}**; time / Blender Conformal: "
                      f"**{target['time_ratio_to_conformal']:.2f}x** (target at most 2x).", ""]
    return "\n".join(lines)


def stretch_text(row: dict, key: str) -> str:
    if np.isfinite(row[key]):
        return f"{row[key]:.4f}"
    return f"† ({row[key + '_unflipped']:.4f})"


def add_character_arguments(parser) -> None:
    """The options of a benchmark over the characters: where the shared data is, which characters, the outputs."""
    parser.add_argument("--data", default=os.path.join(REPOSITORY, "..", "shared", "data"),
                        help="the shared benchmark data folder (default ../shared/data)")
    parser.add_argument("--only", nargs="+", help="run only these characters (horse, arm, creature)")
    parser.add_argument("--json", help="write the results here")
    parser.add_argument("--markdown", help="write a Markdown report here")


def run_characters(args, run, report, peers: dict) -> dict:
    """run(character) on each character args.only names (all by default) into results["characters"] (the horse is
    skipped, and said so in results["skipped"], when the shared data folder lacks it); the results, with the machine
    and the peers' versions, are written to --json and --markdown (by report) and printed."""
    results = {"machine": machine_info(), "peers": peers, "characters": [], "skipped": []}
    loaders = {"horse": lambda: horse(os.path.join(args.data, "horse")), "arm": lambda: blender_sample("arm"),
               "creature": lambda: blender_sample("creature")}
    for name, load in loaders.items():
        if args.only and name not in args.only:
            continue
        if name == "horse" and not os.path.isdir(os.path.join(args.data, "horse")):
            message = f"horse: {os.path.join(args.data, 'horse')} is absent (the shared data folder)"
            print(message, file=sys.stderr)
            results["skipped"].append(message)
            continue
        results["characters"].append(run(load()))
    write_outputs(results, args.json, args.markdown, report)
    print(report(results))
    return results


def parse_args(argv):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_character_arguments(parser)
    return parser.parse_args(argv)


def main(argv=None) -> dict:
    args = parse_args(argv)
    from importlib.metadata import version

    return run_characters(args, run, report, {"libigl": version("libigl"), "xatlas": version("xatlas")})


if __name__ == "__main__":
    main()
