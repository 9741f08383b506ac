"""Skeletons from segmented meshes (Vasilakis 2008, tables 5.2-5.7) beside skeletor and Blender's automatic weights.

    cd /work/main && .venv/bin/python bench/bench_skeleton.py [--data ../shared/data] \
        [--json bench/skeleton_results.json] [--markdown bench/skeleton_results.md]

Models:
  chain, star (skinkit.skeleton.samples, always there; the chain tessellated to ~10k vertices): known joints.
  cow (../shared/data/cow-gt, skipped with a message when absent): parts by each vertex's dominant ground-truth
    weight, the ground-truth skeleton (skeleton.tgf) to compare the joints with.
  horse (../shared/data/horse): parts by skinkit.decompose's rigid clusters (17, the thesis' part count) of the
    reference and its 10 poses; no ground truth, timings only.

Measured:
  Table 5.2: seconds per method (Opening, Centroid, Principal Axis, Principal Axis refined), one call each, with
    the core's stages (openings, hulls, kernels, method).
  Table 5.3 (pre-processing): the seam topology (wedges, columns, strips, caps), built once; the collision
    candidate lists ("others nodes").
  Tables 5.4-5.7 (gap time per step while animating 4 parts), two ways: the fixed topology (add: the arc points
    with every rigid vertex; normals) and Algorithm 5 in full per frame (add, remove the sinking points,
    triangulate: the hole fill, normals); their sum the frame's total; the check (boundary edges left, must be 0,
    and V - E + F = 2) is timed apart, not counted. On the cow also its 7 ground-truth poses.
  Joint error (cow): for every ground-truth joint inside the skeleton (two or more bones), the distance to the
    nearest extracted joint, over the mesh's bounding-box diagonal; target 5%.
Peers, on the same meshes:
  skeletor (PyPI, by_wavefront then mesh contraction is too slow at 10k vertices, so wavefront only): seconds and the
    same joint error over its skeleton's vertices.
  Blender's automatic weights (bone heat, bpy.ops.object.parent_set ARMATURE_AUTO) on the armature skinkit built:
    seconds, and how many vertices' strongest bone is their own part's (rigid skinning's answer).
Targets: joints within 5% of the diagonal on the cow; every method under 1 s at 10k vertices; seams under 50 ms per
frame, watertight on every frame.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from common import finish_run, machine_line, parallel_speedup
from datasets import read_tgf

from skinkit.meshio import read_obj
from skinkit.skeleton import chain_of_cylinders, extract_skeleton, from_vertex_labels, from_weights, read_dmat
from skinkit.skeleton import star_of_limbs
from skinkit.skeleton.animation import pose
from skinkit.skeleton.seams import boundary_edges, is_consistently_oriented, prepare_seams, vertex_normals

REPOSITORY = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TARGET_JOINT_ERROR = 0.05
TARGET_METHOD_SECONDS = 1.0
TARGET_SEAM_SECONDS = 0.05
METHODS = (("opening", False), ("centroid", False), ("principal-axis", False), ("principal-axis", True))


class MissingData(Exception):
    pass


def diagonal(positions) -> float:
    return float(np.linalg.norm(positions.max(axis=0) - positions.min(axis=0)))


def nearest_errors(truth: np.ndarray, found: np.ndarray, scale: float, labels=None) -> dict:
    distances = np.linalg.norm(truth[:, None, :] - found[None, :, :], axis=2).min(axis=1) / scale
    worst = int(np.argmax(distances))
    return {"mean": float(distances.mean()), "max": float(distances.max()), "joints": len(truth),
            "worst_joint": int(labels[worst]) if labels is not None else worst}


def time_methods(parts, parents=None) -> dict:
    rows = {}
    for method, refine in METHODS:
        skeleton = extract_skeleton(parts, method, parents=parents, refine=refine, max_angle=20.0)
        rows[method + (" refined" if refine else "")] = {
            "seconds": skeleton.seconds, "stages": skeleton.stage_seconds, "joints": len(skeleton.positions),
            "star_shaped": int(skeleton.star_shaped.sum()), "parts": parts.part_count}
    return rows


#: The seam modes: the fixed topology (SeamMesh.positions), Algorithm 5 in C with QLERP arcs, and with conic arcs.
SEAM_MODES = {"fixed topology": None, "Algorithm 5 (remove sinking, fill)": "qlerp",
              "Algorithm 5, conic arcs": "conic"}
#: Each frame is timed this many times and its median-total run kept (the machine is shared).
SEAM_REPEATS = 3


def seam_frame(mesh, world, arcs: str | None) -> dict:
    """One frame's gap steps: fixed topology (add = arcs and rigid points, normals) or Algorithm 5 in full in C (add,
    remove, triangulate, normals) with the given arcs; the median of SEAM_REPEATS runs; the watertightness check is
    timed apart, not counted."""
    runs = []
    for _ in range(SEAM_REPEATS):
        if arcs:
            frame = mesh.reconstruct(world, arcs=arcs)
            row = dict(frame.seconds) | {"removed_points": frame.removed_points, "fill_points": frame.fill_points,
                                         "fallback": frame.fallback, "conic_columns": frame.conic_columns}
            triangles, vertices = frame.triangles, len(frame.positions)
        else:
            t0 = time.perf_counter()
            positions = mesh.positions(world)
            t1 = time.perf_counter()
            vertex_normals(positions, mesh.triangles)
            row = {"add": t1 - t0, "normals": time.perf_counter() - t1}
            triangles, vertices = mesh.triangles, len(mesh.sources)
        row["total"] = sum(v for k, v in row.items() if k in ("add", "remove", "triangulate", "normals"))
        runs.append(row)
    row = sorted(runs, key=lambda r: r["total"])[len(runs) // 2]
    t2 = time.perf_counter()
    row["boundary_edges"] = boundary_edges(triangles)
    row["sphere"] = vertices - len(triangles) // 2 == 2 and is_consistently_oriented(triangles)
    row["check"] = time.perf_counter() - t2
    return row


def seam_summary(mesh, rows, prepare, animated) -> dict:
    totals = [r["total"] for r in rows]
    return {"prepare_seconds": prepare, "frames": rows, "mean_total": float(np.mean(totals)),
            "max_total": float(np.max(totals)),
            "watertight_every_frame": all(r["boundary_edges"] == 0 and r["sphere"] for r in rows),
            "fallbacks": sum(bool(r.get("fallback")) for r in rows),
            "constructed_points": mesh.constructed_points, "vertices": len(mesh.sources), "animated_parts": animated}


def animate_seams(parts, skeleton, frames: int = 8, steps: int = 4, arcs: str | None = None) -> dict:
    """Four parts (the first four non-root ones) swing up to 40 degrees; per-frame gap timings."""
    started = time.perf_counter()
    mesh = prepare_seams(parts, skeleton, steps)
    prepare = time.perf_counter() - started
    moving = [p for p in range(parts.part_count) if skeleton.part_parents[p] >= 0][:4]
    rows = []
    for frame in range(frames):
        angles = np.zeros((parts.part_count, 3))
        for k, part in enumerate(moving):
            angles[part, k % 2] = 40.0 * np.sin(np.pi * frame / (frames - 1))
        rows.append(seam_frame(mesh, pose(skeleton, angles), arcs))
    return seam_summary(mesh, rows, prepare, [parts.names[p] for p in moving])


def seams_both_ways(parts, skeleton) -> dict:
    return {mode: animate_seams(parts, skeleton, arcs=arcs) for mode, arcs in SEAM_MODES.items()}


def cow_pose_seams(parts, skeleton, folder) -> dict:
    """The cow's seven ground-truth poses (poses/N.Tmat, bone k driving part bone_k) through every seam mode."""
    from skinkit.cli.commands.rigid_skin import read_tmat_folder

    _, worlds = read_tmat_folder(os.path.join(folder, "poses"), parts.part_count, parts.names)
    started = time.perf_counter()
    mesh = prepare_seams(parts, skeleton, 4)
    prepare = time.perf_counter() - started
    return {mode: seam_summary(mesh, [seam_frame(mesh, world, arcs) for world in worlds], prepare,
                               ["all (ground-truth poses)"])
            for mode, arcs in SEAM_MODES.items()}


def collision_lists(skeleton) -> dict:
    """Table 5.3's "others nodes": the per-joint candidate lists, built once, and how many pairs each leaves."""
    from skinkit.skeleton.animation import collision_candidates

    started = time.perf_counter()
    everything = collision_candidates(skeleton)
    per_joint = [collision_candidates(skeleton, p) for p in range(len(skeleton.part_parents))]
    return {"seconds": time.perf_counter() - started, "all_pairs": len(everything),
            "mean_pairs_per_joint": float(np.mean([len(p) for p in per_joint]))}


# ---- models -------------------------------------------------------------------------------------------------------

def samples() -> dict:
    results = {}
    for name, sample in (("chain", chain_of_cylinders(parts=5, sides=128, rings_per_part=16)), ("star", star_of_limbs())):
        skeleton = extract_skeleton(sample.parts, "centroid", parents=sample.parents)
        found = skeleton.positions[skeleton.kinds == 1]
        truth = sample.openings[sample.parents >= 0]
        results[name] = {"vertices": len(sample.parts.positions), "triangles": len(sample.parts.triangles),
                         "methods": time_methods(sample.parts, sample.parents),
                         "joint_error": nearest_errors(truth, found, diagonal(sample.parts.positions)),
                         "seams": seams_both_ways(sample.parts, skeleton), "collisions": collision_lists(skeleton)}
    return results


def cow_tree(edges: np.ndarray, names) -> np.ndarray:
    """The parts' hierarchy from the ground-truth bones: a bone's parent is the bone ending where it starts; the
    bones leaving the root joint hang from the one among them with the most descendants."""
    bone_of = {int(name.split("_")[1]): k for k, name in enumerate(names)}
    count = len(edges)
    parent_bone = [next((b for b in range(count) if edges[b, 1] == edges[a, 0]), -1) for a in range(count)]
    roots = [b for b in range(count) if parent_bone[b] < 0]

    def descendants(b):
        return sum(1 + descendants(c) for c in range(count) if parent_bone[c] == b)

    top = max(roots, key=descendants)
    for b in roots:
        parent_bone[b] = -1 if b == top else top
    parents = np.full(len(names), -1, np.int32)
    for b in range(count):
        if b in bone_of:
            parents[bone_of[b]] = bone_of[parent_bone[b]] if parent_bone[b] >= 0 else -1
    return parents


def cow(data: str) -> dict:
    folder = os.path.join(data, "cow-gt")
    if not os.path.isdir(folder):
        raise MissingData(f"{folder} is not there")
    positions, triangles = read_obj(os.path.join(folder, "rest.obj"))
    weights = read_dmat(os.path.join(folder, "weights.DMAT"))
    joints, edges = read_tgf(os.path.join(folder, "skeleton.tgf"))
    parts = from_weights(positions, triangles, weights)
    result = {"vertices": len(positions), "triangles": len(triangles), "parts": parts.part_count}
    try:
        parents = cow_tree(edges, parts.names)
        extract_skeleton(parts, "opening", parents=parents)
        result["hierarchy"] = "ground-truth bone tree"
    except Exception as error:  # a bone pair whose dominant-weight regions do not touch
        parents = None
        result["hierarchy"] = f"grown over the openings (the ground-truth tree was refused: {error})"
    result["methods"] = time_methods(parts, parents)
    degree = np.bincount(edges.reshape(-1), minlength=len(joints))
    inner_labels = np.flatnonzero(degree >= 2) + 1  # skeleton.tgf's own joint numbers
    inner = joints[degree >= 2]
    scale = diagonal(positions)
    result["joint_error"] = {}
    for method, refine in METHODS:
        skeleton = extract_skeleton(parts, method, parents=parents, refine=refine)
        result["joint_error"][method + (" refined" if refine else "")] = nearest_errors(inner, skeleton.positions,
                                                                                         scale, inner_labels)
    skeleton = extract_skeleton(parts, "centroid", parents=parents)
    result["seams"] = seams_both_ways(parts, skeleton)
    result["pose_seams"] = cow_pose_seams(parts, skeleton, folder)
    result["collisions"] = collision_lists(skeleton)
    result["skeletor"] = run_skeletor(positions, triangles, inner, scale, inner_labels)
    result["bone_heat"] = run_bone_heat(parts, parents)
    return result


def horse(data: str) -> dict:
    folder = os.path.join(data, "horse")
    if not os.path.isdir(folder):
        raise MissingData(f"{folder} is not there")
    from skinkit.decompose import rigid_clusters

    rest, triangles = read_obj(os.path.join(folder, "reference.obj"))
    frames = np.array([read_obj(os.path.join(folder, "poses", f"{k:02d}.obj"))[0] for k in range(1, 11)])
    edges = np.unique(np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]),
                              axis=1), axis=0)
    started = time.perf_counter()
    labels = rigid_clusters(rest, np.concatenate([rest[None], frames]), edges, 18, np.random.default_rng(1))
    clustering = time.perf_counter() - started
    parts = from_vertex_labels(rest, triangles, labels.astype(np.int32))
    return {"vertices": len(rest), "triangles": len(triangles), "parts": parts.part_count,
            "clustering_seconds": clustering, "methods": time_methods(parts)}


# ---- peers --------------------------------------------------------------------------------------------------------

def run_skeletor(positions, triangles, inner, scale, labels) -> dict:
    try:
        import skeletor
        import trimesh
    except ImportError as error:
        return {"skipped": f"skeletor is not installed ({error}); pip install -r requirements-bench.txt"}
    mesh = trimesh.Trimesh(positions, triangles, process=False)
    started = time.perf_counter()
    skeleton = skeletor.skeletonize.by_wavefront(mesh, waves=1, step_size=1, progress=False)
    seconds = time.perf_counter() - started
    return {"method": "by_wavefront(waves=1, step_size=1)", "seconds": seconds, "nodes": len(skeleton.vertices),
            "joint_error": nearest_errors(inner, np.asarray(skeleton.vertices), scale, labels),
            "note": "skeletor gives a curve skeleton (many nodes, no hierarchy of parts): its error is to its nearest "
                    "node of any kind"}


def run_bone_heat(parts, parents) -> dict:
    try:
        import bpy
    except ImportError:
        return {"skipped": "bpy is not installed"}
    from skinkit.blender import scene
    from skinkit.blender.skeleton import PART_ATTRIBUTE, PART_NAMES, extract_rig

    scene.empty_scene()
    mesh_object = scene.new_mesh_object("cow", parts.positions, parts.triangles)
    attribute = mesh_object.data.attributes.new(PART_ATTRIBUTE, "INT", "FACE")
    attribute.data.foreach_set("value", parts.triangle_parts)
    mesh_object.data[PART_NAMES] = list(parts.names)
    started = time.perf_counter()
    armature, skeleton, _ = extract_rig(mesh_object, "attribute", "centroid")
    rig_seconds = time.perf_counter() - started
    mesh_object.modifiers.clear()
    mesh_object.vertex_groups.clear()
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj in (mesh_object, armature))
    bpy.context.view_layer.objects.active = armature
    started = time.perf_counter()
    bpy.ops.object.parent_set(type="ARMATURE_AUTO")
    heat_seconds = time.perf_counter() - started
    from skinkit.blender.rig import read_vertex_groups

    names = list(parts.names)
    present = [n for n in names if mesh_object.vertex_groups.get(n) is not None]
    weights = read_vertex_groups(mesh_object, present)
    own = parts.vertex_parts()
    painted = weights.sum(axis=1) > 0
    strongest = np.array([names.index(present[k]) for k in np.argmax(weights, axis=1)])
    return {"skinkit_rig_seconds": rig_seconds, "bone_heat_seconds": heat_seconds,
            "vertices_with_weights": float(painted.mean()),
            "strongest_is_own_part": float((strongest[painted] == own[painted]).mean()) if painted.any() else 0.0}


# ---- report -------------------------------------------------------------------------------------------------------

def method_table(rows: dict) -> list[str]:
    lines = ["| method | seconds | openings | hulls | kernels | method step | joints | star-shaped |",
             "|---|---|---|---|---|---|---|---|"]
    for name, row in rows.items():
        s = row["stages"]
        lines.append(f"| {name} | {row['seconds']:.4f} | {s['openings']:.4f} | {s['hulls']:.4f} | {s['kernels']:.4f} "
                     f"| {s['method']:.4f} | {row['joints']} | {row['star_shaped']}/{row['parts']} |")
    return lines


def seam_table(seams: dict) -> list[str]:
    lines = []
    for mode, run in seams.items():
        lines += [f"Seams, {mode}: topology built once in {run['prepare_seconds']:.4f} s; {run['vertices']} vertices, "
                  f"{run['constructed_points']} constructed points; animated: {', '.join(run['animated_parts'])}.", "",
                  "| frame | add (s) | remove (s) | triangulate (s) | normals (s) | total (s) | removed | fallback "
                  "| conic columns | boundary edges | one sphere |", "|---|---|---|---|---|---|---|---|---|---|---|"]
        for k, row in enumerate(run["frames"]):
            lines.append(f"| {k + 1} | {row['add']:.5f} | {row.get('remove', 0.0):.5f} | "
                         f"{row.get('triangulate', 0.0):.5f} | {row['normals']:.5f} | {row['total']:.5f} | "
                         f"{row.get('removed_points', 0)} | {row.get('fallback', False)} | "
                         f"{row.get('conic_columns', 0)} | {row['boundary_edges']} | {row['sphere']} |")
        lines += [f"| mean | | | | | {run['mean_total']:.5f} | | {run['fallbacks']} fallbacks | | watertight every "
                  f"frame: {run['watertight_every_frame']} | |", ""]
    return lines


def markdown(results: dict) -> str:
    lines = ["# Skeletons from segmented meshes (bench/bench_skeleton.py)", "",
             machine_line(results["machine"]) + ")", "", f"Command: `{results['machine']['command']}`", ""]
    for name, model in results["models"].items():
        lines.append(f"## {name}")
        if "skipped" in model:
            lines += [f"Skipped: {model['skipped']}", ""]
            continue
        lines += [f"{model['vertices']} vertices, {model['triangles']} triangles"
                  + (f", {model['parts']} parts" if "parts" in model else "")
                  + (f"; hierarchy: {model['hierarchy']}" if "hierarchy" in model else "")
                  + (f"; rigid clusters in {model['clustering_seconds']:.2f} s" if "clustering_seconds" in model
                     else ""), ""]
        lines += method_table(model["methods"]) + [""]
        error = model.get("joint_error")
        if error and "mean" in error:
            lines += [f"Joint error (known openings, centroid method): mean {error['mean']:.2e}, max {error['max']:.2e} "
                      "of the diagonal", ""]
        elif error:
            lines += ["| method | mean joint error / diagonal | max | worst joint (skeleton.tgf) | target |",
                      "|---|---|---|---|---|"]
            lines += [f"| {m} | {e['mean']:.4f} | {e['max']:.4f} | {e['worst_joint']} | {TARGET_JOINT_ERROR} |"
                      for m, e in error.items()]
            lines.append("")
        if "seams" in model:
            lines += seam_table(model["seams"])
        if "pose_seams" in model:
            lines += ["The cow's 7 ground-truth poses (poses/N.Tmat):", ""] + seam_table(model["pose_seams"])
        if "collisions" in model:
            c = model["collisions"]
            lines += [f"Collision lists (precomputed once): {c['seconds']:.5f} s; {c['all_pairs']} candidate pairs in "
                      f"all, {c['mean_pairs_per_joint']:.1f} per moving joint on average", ""]
        if "skeletor" in model:
            s = model["skeletor"]
            lines += ([f"skeletor: skipped ({s['skipped']})"] if "skipped" in s else
                      [f"skeletor {s['method']}: {s['seconds']:.3f} s, {s['nodes']} nodes, joint error mean "
                       f"{s['joint_error']['mean']:.4f}, max {s['joint_error']['max']:.4f} ({s['note']})"]) + [""]
        if "bone_heat" in model:
            b = model["bone_heat"]
            lines += ([f"Bone heat: skipped ({b['skipped']})"] if "skipped" in b else
                      [f"Blender automatic weights on skinkit's armature: {b['bone_heat_seconds']:.2f} s (skinkit's rig "
                       f"{b['skinkit_rig_seconds']:.2f} s); {100 * b['vertices_with_weights']:.1f}% of vertices "
                       f"weighted, {100 * b['strongest_is_own_part']:.1f}% strongest on their own part"]) + [""]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=os.path.join(REPOSITORY, "..", "shared", "data"))
    parser.add_argument("--json")
    parser.add_argument("--markdown")
    arguments = parser.parse_args(argv)
    speedup_before = parallel_speedup()
    results = {"models": samples(), "targets": {"joint_error": TARGET_JOINT_ERROR,
                                                "method_seconds": TARGET_METHOD_SECONDS,
                                                "seam_seconds": TARGET_SEAM_SECONDS}}
    for name, load in (("cow", cow), ("horse", horse)):
        try:
            results["models"][name] = load(arguments.data)
        except MissingData as missing:
            print(f"{name}: skipped ({missing})", file=sys.stderr)
            results["models"][name] = {"skipped": str(missing)}
    return finish_run(results, arguments, markdown, speedup_before)


if __name__ == "__main__":
    sys.exit(main())
