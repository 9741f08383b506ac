"""The `skinkit` command line, for headless and batch use.

Commands that read .blend files need Blender's Python module (`bpy`, installed by `make venv`) or must
run inside Blender. With --json a command prints exactly one JSON object on stdout (Blender's own
messages are sent to stderr meanwhile), also on failure: {"error": "..."} with exit status 1.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from contextlib import contextmanager

import numpy as np

from . import __version__
from .model import SkinkitError


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    arguments = parser.parse_args(argv)
    if not getattr(arguments, "command", None):
        parser.print_help()
        return 2
    try:
        with stdout_to_stderr(arguments.json):
            result = arguments.command(arguments)
    except (SkinkitError, OSError) as error:
        return report_failure(str(error), arguments.json)
    report(result, arguments.json)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="skinkit", description="Animation-space skinning for Blender scenes.")
    parser.add_argument("--version", action="version", version=f"skinkit {__version__}")
    commands = parser.add_subparsers(metavar="COMMAND")

    convert = add_command(commands, "convert", run_convert,
                          "convert an object's linear blend skinning to animation space and save the scene")
    convert.add_argument("--out", required=True, help="the .blend to write (the input is not modified)")
    convert.add_argument("--ignore-unmatched-groups", action="store_true",
                         help="ignore vertex groups that name no bone instead of refusing the mesh")

    evaluate = add_command(commands, "eval", run_eval,
                           "evaluate the model over frames beside Blender's Armature modifier")
    evaluate.add_argument("--frames", help="A:B, inclusive (default: the scene's frame range)")

    fit = commands.add_parser("fit", help="fit animation space and linear blend skinning to example meshes",
                              description="Fit animation space and linear blend skinning to example meshes of a "
                                          "rigged character.")
    fit.add_argument("--rig", required=True, metavar="RIG",
                     help="a scene with an animated armature: .blend, .fbx, .glb or .gltf")
    fit.add_argument("--sequence", required=True, metavar="SEQ",
                     help="the examples: an .abc file, a folder of same-topology .obj files (world space, "
                          "one per frame), or the name of an object in the rig's scene (with a mesh cache, or the "
                          "rigged mesh itself with one shape key per example)")
    fit.add_argument("--object", help="the rigged mesh (default: the only mesh with an Armature modifier)")
    fit.add_argument("--armature", help="the armature (default: the only one in the scene)")
    fit.add_argument("--rest", help="rest geometry in the rig's bind pose, when the rig has no mesh: an .obj, or "
                                    "an .fbx/.glb holding one mesh")
    fit.add_argument("--sequence-scale", type=float, default=1.0,
                     help="scale applied to the examples of an .abc or .obj folder (e.g. 0.01 when they are in "
                          "centimetres and the rig in metres)")
    fit.add_argument("--frames", help="A:B or A:B:STEP, the frames of the examples (default: the scene's range; "
                                      "the files of an .obj folder pair with these frames in order)")
    fit.add_argument("--method", choices=("per-vertex", "global"), default="per-vertex")
    fit.add_argument("--regularisation", type=float, help="λ (per-vertex) or δ (global); default 1e-4")
    fit.add_argument("--bones-from", choices=("rig", "painted", "automatic"), default="rig",
                     help="influence sets: the rig's weights grown by --rings rings, painted 'influence:<bone>' "
                          "vertex groups, or the bones whose motion best explains each vertex")
    fit.add_argument("--rings", type=int, default=1)
    fit.add_argument("--max-influences", type=int, default=4)
    fit.add_argument("--hold-out", default="", help="frames kept out of training, e.g. '5, 10, 20-24'")
    fit.add_argument("--export-frames", metavar="DIR",
                     help="write each example's animation-space reconstruction as .obj, in the input's vertex order")
    fit.add_argument("--out", help="save the scene with the fitted mesh here (.blend)")
    fit.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    fit.set_defaults(command=run_fit)

    stats = commands.add_parser("stats", help="compute an armature's pose statistics and the culling sphere",
                                description="Compute an armature's pose statistics (for the animation-space "
                                            "metrics), store them on it, and report the rank of P and the culling "
                                            "sphere of its skinned mesh.")
    stats.add_argument("scene", metavar="SCENE.blend")
    stats.add_argument("--armature", help="the armature (default: the only one in the scene)")
    stats.add_argument("--action", help="the action to sample (default: the armature's own)")
    stats.add_argument("--frames", help="A:B or A:B:STEP (default: the action's frame range)")
    stats.add_argument("--from", dest="source", choices=("action", "poses", "limits", "uniform"), default="action",
                       help="sampled from the action or from example poses (--poses), or analytic from Limit Rotation "
                            "constraints or uniform rotations")
    stats.add_argument("--poses", default="", help="with --from poses: the frames of the example poses, e.g. '1,12,30-34'")
    stats.add_argument("--object", help="the skinned mesh for the culling sphere (default: the armature's only one)")
    stats.add_argument("--out", help="save the scene with the statistics stored here (.blend)")
    stats.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    stats.set_defaults(command=run_stats)

    distance = add_command(commands, "distance", run_distance,
                           "mean (L2,2) and max (L2,inf) distances between vertex pairs over all poses")
    distance.add_argument("--from-vertices", required=True, help="vertex indices a_1,a_2,...")
    distance.add_argument("--to-vertices", required=True, help="vertex indices b_1,b_2,... (or one index for all)")

    unwrap = commands.add_parser("unwrap", help="a texture atlas with least stretch over an animation",
                                 description="Unwrap a mesh into a texture atlas that minimises stretch in the rest "
                                             "pose or over an animation (animation-space metric), and write it "
                                             "as an OBJ whose vt carry the uvs, in the input's vertex order.")
    unwrap.add_argument("mesh", metavar="MESH", help="an .obj, or a .blend/.fbx/.glb holding the mesh")
    unwrap.add_argument("--object", help="the mesh in a .blend/.fbx/.glb MESH, or the rig's deformed mesh "
                                         "(default: the only one)")
    animation = unwrap.add_mutually_exclusive_group()
    animation.add_argument("--sequence", metavar="SEQ",
                           help="the animation as an .abc file or a folder of same-topology .obj files")
    animation.add_argument("--rig", metavar="RIG", help="a .blend/.fbx with an armature deforming the mesh")
    unwrap.add_argument("--action", help="with --rig: the action whose frames give the pose statistics and the "
                                         "frames to evaluate (default: the armature's own)")
    unwrap.add_argument("--metric", choices=("rest", "animation"),
                        help="flatten in the rest pose or over the animation (default: animation when --sequence or "
                             "--rig is given)")
    unwrap.add_argument("--seams-from", metavar="MESH_WITH_SEAMS",
                        help="hard chart boundaries: a .blend's edges marked as seams, or an .obj's uv islands")
    unwrap.add_argument("--mode", choices=("auto", "seams"), default="auto",
                        help="auto: merge charts greedily; seams: the charts the seams cut out")
    unwrap.add_argument("--charts", type=int, help="target chart count (auto mode)")
    unwrap.add_argument("--straighten", action="store_true",
                        help="straight chart boundaries between corners (for mip-mapping and LOD; raises stretch)")
    unwrap.add_argument("--segment-in", choices=("rest", "metric"), default="rest",
                        help="segment in 3-D (default) or in the metric's leading directions (auto mode)")
    unwrap.add_argument("--texture-size", type=int, default=1024)
    unwrap.add_argument("--margin", type=int, default=4, help="texels between charts")
    unwrap.add_argument("--out", required=True, metavar="OUT.obj")
    unwrap.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    unwrap.set_defaults(command=run_unwrap)

    bake = add_command(commands, "bake", run_bake, "bake the model's animation to a PC2 cache and/or shape keys")
    bake.add_argument("--frames", help="A:B, inclusive (default: the scene's frame range)")
    bake.add_argument("--pc2", help="write a PC2 point cache here")
    bake.add_argument("--out", help="write the scene with a shape-key baked copy of the object here")

    decompose = commands.add_parser(
        "decompose", help="skin a mesh sequence that has no rig: a skeleton, weights and an animation-space model",
        description="Skin a same-topology mesh sequence without a rig: automatic proxy bones (or a rough rig's "
                    "skeleton fitted to the sequence), linear-blend weights and an animation-space model; frames not "
                    "used for training are replayed with the model fixed.")
    decompose.add_argument("--sequence", required=True, metavar="SEQ",
                           help="a folder of same-topology .obj files (one per frame, in name order; frames are "
                                "numbered from 1) or an .abc file (scene frames)")
    decompose.add_argument("--bones", type=int, default=16, help="bone count for automatic bones (default 16)")
    decompose.add_argument("--max-influences", type=int, default=4)
    decompose.add_argument("--train", default="", help="the training frames, e.g. '1-11' or '1, 5, 9-12' "
                                                       "(default: all); the others are held out")
    decompose.add_argument("--rest", help="the rest pose (.obj, or .fbx/.glb with one mesh); default: the first frame")
    decompose.add_argument("--sequence-scale", type=float, default=1.0,
                           help="scale applied to the sequence and to an .obj --rest (e.g. 0.01 for centimetres; "
                                ".fbx/.glb files carry their own units)")
    decompose.add_argument("--frames", help="A:B or A:B:STEP, the frames read from an .abc (default: its range)")
    decompose.add_argument("--method", choices=("automatic", "rough-rig"), default="automatic")
    decompose.add_argument("--rig", help="with --method rough-rig: a .blend with the drawn armature and the mesh, "
                                         "whose vertex groups named like the bones mark their core vertices")
    decompose.add_argument("--armature", help="the rough rig's armature (default: the only one)")
    decompose.add_argument("--object", help="the rough rig's mesh (default: the only mesh)")
    decompose.add_argument("--out", help="save the armature, its action and the skinned mesh: .blend or .glb")
    decompose.add_argument("--export-frames", metavar="DIR",
                           help="write every frame's animation-space reconstruction as .obj, in the input's vertex "
                                "order and units")
    decompose.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    decompose.set_defaults(command=run_decompose)
    return parser


def add_command(commands, name: str, function, help_text: str) -> argparse.ArgumentParser:
    command = commands.add_parser(name, help=help_text, description=help_text)
    command.add_argument("scene", metavar="SCENE.blend")
    command.add_argument("--object", help="the mesh (default: the only mesh with an Armature modifier)")
    command.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    command.set_defaults(command=function)
    return command


def run_convert(arguments) -> dict:
    bpy, operations = open_scene(arguments.scene)
    mesh_object = find_object(arguments)
    result = operations.convert_object(mesh_object, arguments.ignore_unmatched_groups)
    return {**result, "out": save_scene(bpy, arguments.out)}


def run_eval(arguments) -> dict:
    _, operations = open_scene(arguments.scene)
    from .blender import storage

    mesh_object = find_object(arguments)
    converted = not storage.has_model(mesh_object.data)
    if converted:  # in memory only: the file is not written
        operations.convert_object(mesh_object)
    result = operations.compare_with_armature(mesh_object, frame_range(arguments.frames))
    return {**result, "converted_in_memory": converted}


def run_bake(arguments) -> dict:
    if not arguments.pc2 and not arguments.out:
        raise SkinkitError("bake needs --pc2 FILE, --out FILE.blend, or both")
    bpy, operations = open_scene(arguments.scene)
    from .blender import storage

    mesh_object = find_object(arguments)
    if not storage.has_model(mesh_object.data):
        raise SkinkitError(f"'{mesh_object.name}' has no animation-space model; run `skinkit convert` first")
    frames = frame_range(arguments.frames)
    positions = operations.positions_over_frames(mesh_object, frames)
    result = {"object": mesh_object.name, "frames": len(frames), "vertices": len(mesh_object.data.vertices)}
    if arguments.pc2:
        operations.bake_mesh_cache(mesh_object, os.path.abspath(arguments.pc2), frames, positions, add_object=False)
        result["pc2"] = os.path.abspath(arguments.pc2)
    if arguments.out:
        result["baked_object"] = operations.bake_shape_keys(mesh_object, frames, positions).name
        result["out"] = save_scene(bpy, arguments.out)
    return result


def run_fit(arguments) -> dict:
    bpy = load_rig(arguments.rig)
    from .blender import fitting

    armature = find_armature(bpy, arguments.armature)
    mesh_object = fitted_mesh(bpy, arguments, armature)
    examples = load_examples(bpy, arguments, mesh_object)
    report = fitting.fit_object(mesh_object, examples, method=arguments.method,
                                regularisation=arguments.regularisation, source=arguments.bones_from,
                                rings=arguments.rings, max_influences=arguments.max_influences,
                                held_out_frames=fitting.parse_frame_list(arguments.hold_out))
    reconstruction = report.pop("reconstruction")
    if arguments.export_frames:
        export_frames(arguments.export_frames, reconstruction, examples)
        report["export_frames"] = os.path.abspath(arguments.export_frames)
    if arguments.out:
        report["out"] = save_scene(bpy, arguments.out)
    return report


def run_decompose(arguments) -> dict:
    """Without --out or a rough rig the job runs on numpy alone (an .abc still needs bpy to be read)."""
    import resource
    import time

    import numpy as np

    started = time.perf_counter()
    if arguments.out and os.path.splitext(arguments.out)[1].lower() not in (".blend", ".glb"):
        raise SkinkitError(f"--out {arguments.out}: expected a .blend or .glb file")
    frames, triangles, numbers = read_sequence(arguments)
    if arguments.rest:
        rest, rest_triangles = read_rest(arguments.rest, arguments.sequence_scale)
        if len(rest) != frames.shape[1]:
            raise SkinkitError(f"--rest {arguments.rest}: {len(rest)} vertices, the sequence has {frames.shape[1]}")
        frames, numbers, triangles = np.concatenate([rest[None], frames]), [0] + numbers, rest_triangles
    from .framelist import parse_frame_list

    wanted = parse_frame_list(arguments.train)
    train = np.isin(numbers, wanted) if wanted else np.ones(len(numbers), bool)
    if arguments.rest:
        train[0] = True  # the rest pose is part of the training data
    if arguments.method == "rough-rig" or arguments.out:
        report, reconstruction = decompose_in_blender(arguments, frames, triangles, numbers, train)
    else:
        from .decompose import solve_sequence

        _, _, replay, report = solve_sequence(frames, triangles, train, bones=arguments.bones,
                                           max_influences=arguments.max_influences)
        reconstruction = replay["animation"]
    if arguments.export_frames:
        export_sequence(arguments.export_frames, reconstruction, numbers, arguments.sequence_scale)
        report["export_frames"] = os.path.abspath(arguments.export_frames)
    report.update(seconds=time.perf_counter() - started,
                  peak_memory_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    return report


def run_stats(arguments) -> dict:
    import time

    bpy, operations = open_scene(arguments.scene)
    from .blender import statistics

    armature = find_armature(bpy, arguments.armature)
    started = time.perf_counter()
    frames = []
    if arguments.source in ("action", "poses"):
        from .blender.fitting import parse_frame_list

        with action_assigned(bpy, armature, arguments.action) as action:
            if arguments.source == "poses":
                frames = parse_frame_list(arguments.poses)
                source = f"{len(frames)} example poses"
            else:
                frames = list(frame_range(arguments.frames) if arguments.frames else
                              range(int(action.frame_range[0]), int(action.frame_range[1]) + 1))
                source = f"action '{action.name}' frames {frames[0]}-{frames[-1]}"
            computed = statistics.compute(armature, arguments.source, frames)
    else:
        computed = statistics.compute(armature, arguments.source)
        source = {"limits": "rotation limits", "uniform": "uniform rotations"}[arguments.source]
    seconds = time.perf_counter() - started
    statistics.store(armature, computed, source, len(frames))
    result = {"armature": armature.name, "bones": computed.bone_count - 1, "frames": len(frames), "source": source,
              "seconds": seconds, "rank": statistics.rank_of(computed), "unknowns": 4 * computed.bone_count}
    mesh_object = skinned_mesh_of(bpy, armature, arguments.object)
    if mesh_object is not None:
        from .blender import storage

        if not storage.has_model(mesh_object.data):
            operations.convert_object(mesh_object)  # in memory for the sphere; saved only with --out
        bounds = statistics.mesh_bounds(mesh_object)
        result["culling_sphere"] = {"object": mesh_object.name, "centre": bounds["centre"].tolist(),
                                    "radius": bounds["radius"]}
    if arguments.out:
        result["out"] = save_scene(bpy, arguments.out)
    return result


def run_distance(arguments) -> dict:
    bpy, operations = open_scene(arguments.scene)
    from .blender import statistics, storage
    from .blender.rig import rig_of

    mesh_object = find_object(arguments)
    if not storage.has_model(mesh_object.data):
        operations.convert_object(mesh_object)
    stored = storage.read_model(mesh_object.data, mesh_object.name)
    pose_statistics = statistics.in_mesh_space(statistics.load(rig_of(mesh_object).armature_object), stored.bind)
    first, second = vertex_list(arguments.from_vertices, stored.model), vertex_list(arguments.to_vertices, stored.model)
    if len(second) == 1:
        second = second * len(first)
    if len(first) != len(second):
        raise SkinkitError(f"--from-vertices has {len(first)} vertices, --to-vertices {len(second)}: give as many, "
                           "or one to measure every vertex against")
    from .metrics import SparseVectors

    vectors = SparseVectors.rows(stored.model, first).combined(SparseVectors.rows(stored.model, second), -1.0)
    mean, most = pose_statistics.mean_distance(vectors), pose_statistics.max_distance(vectors)
    return {"object": mesh_object.name, "pairs": [{"from": a, "to": b, "mean": float(m), "max": float(x)}
                                                  for a, b, m, x in zip(first, second, mean, most)]}


def run_unwrap(arguments) -> dict:
    from .meshio import write_obj
    from .unwrap import sequence_embedding, unwrap

    if not arguments.out.lower().endswith(".obj"):
        raise SkinkitError(f"--out {arguments.out}: the output must be an .obj file")
    if arguments.action is not None and arguments.rig is None:
        raise SkinkitError("--action needs --rig RIG")
    metric = arguments.metric or ("animation" if arguments.sequence or arguments.rig else "rest")
    if metric == "animation" and not (arguments.sequence or arguments.rig):
        raise SkinkitError("--metric animation needs the animation: --sequence SEQ or --rig RIG --action NAME")
    positions, triangles = unwrap_input_mesh(arguments)
    seams = seams_from(arguments.seams_from, len(positions)) if arguments.seams_from else None
    embedding, frames = None, None
    if arguments.sequence:
        frames = sequence_positions(arguments.sequence, len(positions))
        embedding = sequence_embedding(frames) if metric == "animation" else None
    elif arguments.rig:
        embedding, frames = rig_animation(arguments, len(positions), metric == "animation")
    result = unwrap(positions, triangles, embedding=embedding, seams=seams, mode=arguments.mode,
                    chart_count=arguments.charts, straighten=arguments.straighten, segment_in=arguments.segment_in,
                    texture_size=arguments.texture_size, margin=arguments.margin, evaluation_frames=frames)
    write_obj(arguments.out, positions, triangles, result.uv)
    report = result.report
    keys = ("charts", "seconds", "stretch_metric", "stretch_rest", "stretch_frames", "packing_efficiency",
            "texture_efficiency", "vertices", "triangles", "loose_vertices")
    # JSON has no infinity: a stretch that is infinite (flipped or degenerate uv triangles, counted in
    # invalid_triangles) is reported as null.
    return {**{key: None if report[key] == np.inf else report[key] for key in keys}, "metric": metric,
            "frames": 0 if frames is None else len(frames), "seams": len(result.seams),
            "invalid_triangles": int(report["flattening"]["invalid_triangles"]), "out": os.path.abspath(arguments.out)}


def unwrap_input_mesh(arguments):
    """(positions, triangles) of MESH in its own vertex order: an .obj as it is, or a scene's mesh object
    in its local space."""
    if arguments.mesh.lower().endswith(".obj"):
        from .meshio import read_obj

        return read_obj(arguments.mesh)
    bpy = load_rig(arguments.mesh)
    from .blender.rig import mesh_of

    mesh = mesh_of(scene_mesh(bpy, arguments.object))
    return mesh.positions, mesh.triangles


def scene_mesh(bpy, name):
    """The mesh named `name`, or the scene's only skinned mesh, or its only mesh."""
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    if name is not None:
        found = [o for o in meshes if o.name == name]
        if not found:
            raise SkinkitError(f"no mesh named '{name}' in the scene")
        return found[0]
    from .blender.rig import armature_modifiers

    skinned = [o for o in meshes if armature_modifiers(o)]
    candidates = skinned if len(skinned) == 1 else meshes
    if len(candidates) != 1:
        listed = ", ".join(f"'{o.name}'" for o in candidates) or "none"
        raise SkinkitError(f"the scene has {len(candidates)} meshes ({listed}); name one with --object")
    return candidates[0]


def seams_from(path: str, vertex_count: int):
    """(S, 2) vertex pairs: a .blend's mesh edges marked as seams, or the edges between an .obj's uv islands."""
    extension = os.path.splitext(path)[1].lower()
    if extension == ".obj":
        from .meshio import read_obj, read_obj_texture_corners
        from .unwrap import texture_seams

        positions, triangles = read_obj(path)
        check_vertex_count(path, len(positions), vertex_count)
        corners = read_obj_texture_corners(path)
        if not len(corners) or (corners < 0).any():
            raise SkinkitError(f"--seams-from {path}: every face needs texture coordinates (f v/vt) to take uv "
                               "islands from")
        return texture_seams(triangles, corners)
    if extension != ".blend":
        raise SkinkitError(f"--seams-from {path}: expected a .blend (edges marked as seams) or an .obj (uv islands)")
    bpy = load_rig(path)
    from .blender.unwrap import seam_pairs

    mesh_object = scene_mesh(bpy, None)
    check_vertex_count(path, len(mesh_object.data.vertices), vertex_count)
    return seam_pairs(mesh_object.data)


def check_vertex_count(path: str, found: int, wanted: int) -> None:
    if found != wanted:
        raise SkinkitError(f"{path}: {found} vertices, but the mesh has {wanted}: it needs the same vertices in "
                           "the same order")


def sequence_positions(source: str, vertex_count: int):
    """(F, V, 3): the frames of an .obj folder or an .abc file (each in its own space: stretch does not see
    rigid motions)."""
    if os.path.isdir(source):
        from .meshio import read_obj_sequence, sequence_files

        positions, _ = read_obj_sequence(sequence_files(source))
    elif source.lower().endswith(".abc"):
        bpy = blender_module()
        bpy.ops.wm.read_factory_settings(use_empty=True)
        from .blender.operations import depsgraphs_at, evaluated_positions

        animated = import_alembic(bpy, source, 1.0)
        positions = np.stack([evaluated_positions(animated, depsgraph)
                              for depsgraph in depsgraphs_at(frame_range(None))])
    else:
        raise SkinkitError(f"--sequence {source}: expected a folder of .obj files or an .abc file")
    check_vertex_count(source, positions.shape[1], vertex_count)
    return positions


def rig_animation(arguments, vertex_count: int, animation_metric: bool):
    """(the animation-space embedding or None, the deformed positions over the action's frames)."""
    bpy = load_rig(arguments.rig)
    from .blender import statistics
    from .blender import unwrap as blender_unwrap

    armature = find_armature(bpy, None)
    mesh_object = skinned_mesh_of(bpy, armature, arguments.object)
    if mesh_object is None:
        raise SkinkitError(f"{arguments.rig}: name the mesh '{armature.name}' deforms with --object")
    check_vertex_count(arguments.rig, len(mesh_object.data.vertices), vertex_count)
    with action_assigned(bpy, armature, arguments.action) as action:
        frames = range(int(round(action.frame_range[0])), int(round(action.frame_range[1])) + 1)
        embedding = None
        if animation_metric:
            embedding = blender_unwrap.animation_metric(mesh_object, statistics.compute(armature, "action", frames))
        return embedding, blender_unwrap.deformed_positions(mesh_object, frames)


def vertex_list(text: str, model) -> list[int]:
    try:
        vertices = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise SkinkitError(f"{text!r}: expected vertex indices such as 0,12,40") from None
    bad = [v for v in vertices if not 0 <= v < model.vertex_count]
    if not vertices or bad:
        raise SkinkitError(f"{text!r}: vertex indices must be in [0, {model.vertex_count})" +
                           (f", not {bad}" if bad else ""))
    return vertices


@contextmanager
def action_assigned(bpy, armature, name):
    """The named action assigned to the armature while inside (its own action when name is None)."""
    data = armature.animation_data
    current = data.action if data else None
    if name is None:
        if current is None:
            raise SkinkitError(f"'{armature.name}' has no action: name one with --action")
        yield current
        return
    action = bpy.data.actions.get(name)
    if action is None:
        raise SkinkitError(f"no action named '{name}' in the scene")
    data = data or armature.animation_data_create()
    data.action = action
    try:
        yield action
    finally:
        data.action = current


def skinned_mesh_of(bpy, armature, name):
    from .blender.rig import armature_modifiers

    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH" and
              any(m.object == armature for m in armature_modifiers(o))]
    if name is not None:
        meshes = [o for o in meshes if o.name == name]
        if not meshes:
            raise SkinkitError(f"no mesh named '{name}' is deformed by '{armature.name}'")
    return meshes[0] if len(meshes) == 1 else None


def load_rig(path: str):
    """Opens a .blend, or imports an .fbx/.glb/.gltf into an empty scene; returns bpy."""
    bpy = blender_module()
    if not os.path.exists(path):
        raise SkinkitError(f"{path}: no such file")
    extension = os.path.splitext(path)[1].lower()
    if extension == ".blend":
        open_scene(path)
        return bpy
    # anim_offset=0 keeps the file's own frame numbers (Blender's default shifts the first key to frame 1),
    # so the rig's frames line up with an Alembic sequence's.
    importers = {".fbx": lambda: bpy.ops.import_scene.fbx(filepath=os.path.abspath(path), anim_offset=0.0),
                 ".glb": lambda: bpy.ops.import_scene.gltf(filepath=os.path.abspath(path)),
                 ".gltf": lambda: bpy.ops.import_scene.gltf(filepath=os.path.abspath(path))}
    if extension not in importers:
        raise SkinkitError(f"{path}: a rig must be .blend, .fbx, .glb or .gltf")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    try:
        importers[extension]()
    except RuntimeError as error:
        raise SkinkitError(f"{path}: Blender could not import it ({str(error).strip()})") from None
    return bpy


def find_armature(bpy, name):
    armatures = [o for o in bpy.context.scene.objects if o.type == "ARMATURE"]
    if name is not None:
        armatures = [o for o in armatures if o.name == name]
        if not armatures:
            raise SkinkitError(f"no armature named '{name}' in the rig")
    if len(armatures) != 1:
        listed = ", ".join(f"'{o.name}'" for o in armatures) or "none"
        raise SkinkitError(f"the rig has {len(armatures)} armatures ({listed}); name one with --armature")
    return armatures[0]


def fitted_mesh(bpy, arguments, armature):
    """The rigged mesh to fit, or a new one made from --rest and bound to the armature."""
    from .blender.rig import armature_modifiers, find_skinned_mesh

    skinned = [o for o in bpy.context.scene.objects if o.type == "MESH" and armature_modifiers(o)]
    if arguments.rest is None:
        if not skinned and arguments.object is None:
            raise SkinkitError("the rig has no mesh with an Armature modifier: give the rest geometry in the rig's "
                               "bind pose with --rest (an .obj, or an .fbx/.glb holding one mesh)")
        return find_skinned_mesh(bpy.context.scene.objects, arguments.object)
    mesh_object = rest_mesh_object(bpy, arguments.rest)
    modifier = mesh_object.modifiers.new("Armature", "ARMATURE")
    modifier.object = armature
    return mesh_object


def rest_mesh_object(bpy, path: str):
    """A mesh object holding the rest geometry of --rest, in world space, in the file's vertex order."""
    extension = os.path.splitext(path)[1].lower()
    if extension == ".obj":
        from .meshio import read_obj

        positions, triangles = read_obj(path)
        mesh = bpy.data.meshes.new("skinkit_fitted")
        mesh.from_pydata(positions.tolist(), [], triangles.tolist())
        mesh_object = bpy.data.objects.new("skinkit_fitted", mesh)
        bpy.context.scene.collection.objects.link(mesh_object)
        return mesh_object
    if extension not in (".fbx", ".glb", ".gltf"):
        raise SkinkitError(f"--rest {path}: expected an .obj, .fbx, .glb or .gltf file")
    if not os.path.isfile(path):
        raise SkinkitError(f"--rest {path}: no such file")
    before = set(bpy.context.scene.objects)
    importer = bpy.ops.import_scene.fbx if extension == ".fbx" else bpy.ops.import_scene.gltf
    importer(filepath=os.path.abspath(path))
    meshes = [o for o in bpy.context.scene.objects if o not in before and o.type == "MESH"]
    if len(meshes) != 1:
        raise SkinkitError(f"--rest {path}: expected one mesh, found {len(meshes)}")
    mesh_object = meshes[0]
    for modifier in list(mesh_object.modifiers):  # its own skinning, if any, is what we replace
        mesh_object.modifiers.remove(modifier)
    mesh_object.parent = None
    return mesh_object


def load_examples(bpy, arguments, mesh_object):
    from .blender import fitting
    from .blender.rig import rig_of

    source = arguments.sequence
    armature = rig_of(mesh_object).armature_object
    if os.path.isdir(source):
        from .meshio import read_obj_sequence, sequence_files

        positions, _ = read_obj_sequence(sequence_files(source))
        positions *= arguments.sequence_scale
        start = bpy.context.scene.frame_start
        frames = frame_range(arguments.frames) if arguments.frames else range(start, start + len(positions))
        if len(frames) != len(positions):
            raise SkinkitError(f"{source}: {len(positions)} .obj files but --frames {arguments.frames} has "
                               f"{len(frames)} frames; give A:B:STEP with one frame per file")
        return fitting.examples_from_positions(mesh_object, positions, frames)
    if source.lower().endswith(".abc"):
        return fitting.examples_from_sequence(mesh_object, import_alembic(bpy, source, arguments.sequence_scale),
                                              frame_range(arguments.frames))
    other = bpy.context.scene.objects.get(source)
    if other is None:
        raise SkinkitError(f"--sequence {source!r}: not a folder, an .abc file, or an object in the rig's scene")
    if other == mesh_object:
        return fitting.examples_from_shape_keys(mesh_object, armature)
    return fitting.examples_from_sequence(mesh_object, other, frame_range(arguments.frames))


def import_alembic(bpy, path: str, scale: float):
    if not os.path.isfile(path):
        raise SkinkitError(f"{path}: no such file")
    before = set(bpy.context.scene.objects)
    bpy.ops.wm.alembic_import(filepath=os.path.abspath(path), set_frame_range=True, scale=scale)
    meshes = [o for o in bpy.context.scene.objects if o not in before and o.type == "MESH"]
    if len(meshes) != 1:
        raise SkinkitError(f"{path}: expected one animated mesh, found {len(meshes)}")
    return meshes[0]


def export_frames(folder: str, reconstruction, examples) -> None:
    """One .obj per example, in the input's coordinates and vertex order."""
    from .meshio import write_obj

    os.makedirs(folder, exist_ok=True)
    to_source = examples.to_source
    for frame, positions in zip(examples.frames, reconstruction):
        write_obj(os.path.join(folder, f"frame_{frame:04d}.obj"), positions @ to_source[:3, :3].T + to_source[:3, 3])


def read_sequence(arguments):
    """(frames (F, V, 3), triangles, frame numbers) from an .obj folder (numbered 1..F) or an .abc (scene frames),
    scaled by --sequence-scale."""
    import numpy as np

    source = arguments.sequence
    if os.path.isdir(source):
        from .meshio import read_obj_sequence, sequence_files

        positions, triangles = read_obj_sequence(sequence_files(source))
        return positions * arguments.sequence_scale, triangles, list(range(1, len(positions) + 1))
    if not source.lower().endswith(".abc"):
        raise SkinkitError(f"--sequence {source}: expected a folder of .obj files or an .abc file")
    bpy = blender_module()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sequence_object = import_alembic(bpy, source, arguments.sequence_scale)
    from .blender.decompose import frames_from_sequence
    from .blender.rig import mesh_of

    numbers = list(frame_range(arguments.frames))
    world = np.array(sequence_object.matrix_world)
    positions = frames_from_sequence(sequence_object, numbers).positions @ world[:3, :3].T + world[:3, 3]
    triangles = mesh_of(sequence_object).triangles
    bpy.data.objects.remove(sequence_object)
    return positions, triangles, numbers


def read_rest(path: str, scale: float):
    """Rest positions (world space) and triangles from an .obj (scaled by `scale`), or an .fbx/.glb holding one mesh
    (in the units Blender imports it in)."""
    import numpy as np

    if path.lower().endswith(".obj"):
        from .meshio import read_obj

        positions, triangles = read_obj(path)
        return positions * scale, triangles
    bpy = blender_module()
    from .blender.rig import mesh_of

    mesh_object = rest_mesh_object(bpy, path)
    world = np.array(mesh_object.matrix_world)
    mesh = mesh_of(mesh_object)
    positions = mesh.positions @ world[:3, :3].T + world[:3, 3]
    bpy.data.objects.remove(mesh_object)
    return positions, mesh.triangles


def decompose_in_blender(arguments, frames, triangles, numbers, train):
    """Runs the Blender operator's code on the sequence and saves the result (--out); returns the report and the
    animation-space reconstruction of every frame."""
    bpy = blender_module()
    from .blender import decompose as bridge

    if arguments.method == "rough-rig":
        if not arguments.rig:
            raise SkinkitError("--method rough-rig needs --rig: a .blend with the drawn armature and the mesh")
        load_rig(arguments.rig)
        armature = find_armature(bpy, arguments.armature)
        mesh_object = scene_mesh(bpy, arguments.object)
        frames = bridge.into_mesh_space(mesh_object, frames)
    else:
        armature = None
        bpy.ops.wm.read_factory_settings(use_empty=True)
        mesh_object = bridge.new_mesh_object("sequence", frames[0], triangles)
    sequence = bridge.Sequence(frames, list(numbers), [f"frame {n}" for n in numbers])
    report = bridge.skin_object(mesh_object, sequence, method=arguments.method.upper().replace("-", "_"),
                                bones=arguments.bones, max_influences=arguments.max_influences,
                                train_frames=[n for n, t in zip(numbers, train) if t], armature_object=armature)
    reconstruction = report.pop("reconstruction")
    if arguments.method != "rough-rig":
        bpy.data.objects.remove(mesh_object)  # only the skinned copy and its rig are kept
    if arguments.out:
        report["out"] = save_result(bpy, arguments.out, report["armature"], report["skinned_object"])
    return report, reconstruction


def save_result(bpy, path: str, armature_name: str, skinned_name: str) -> str:
    if path.lower().endswith(".blend"):
        return save_scene(bpy, path)
    for scene_object in bpy.context.scene.objects:
        scene_object.select_set(scene_object.name in (armature_name, skinned_name))
    bpy.ops.export_scene.gltf(filepath=os.path.abspath(path), export_format="GLB", use_selection=True,
                              export_animations=True)
    return os.path.abspath(path)


def export_sequence(folder: str, reconstruction, numbers, scale: float) -> None:
    """One .obj per frame, in the input's units and vertex order."""
    from .meshio import write_obj

    os.makedirs(folder, exist_ok=True)
    for number, positions in zip(numbers, reconstruction):
        write_obj(os.path.join(folder, f"frame_{number:04d}.obj"), positions / scale)


def blender_module():
    try:
        import bpy
    except ImportError:
        raise SkinkitError("this command needs Blender's Python module: `pip install bpy==4.5.4`, "
                           "or run it inside Blender") from None
    return bpy


def open_scene(path: str):
    """Loads a .blend with Blender's Python module; returns (bpy, skinkit.blender.operations)."""
    bpy = blender_module()
    if not os.path.isfile(path):
        raise SkinkitError(f"{path}: no such file")
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path), load_ui=False)
    except RuntimeError as error:
        raise SkinkitError(f"{path}: Blender could not open it ({str(error).strip()})") from None
    from .blender import operations

    return bpy, operations


def find_object(arguments):
    import bpy

    from .blender.rig import find_skinned_mesh

    return find_skinned_mesh(bpy.context.scene.objects, arguments.object)


def save_scene(bpy, path: str) -> str:
    """Saves the scene as `path` (a .blend); returns its absolute path for the report."""
    if not path.endswith(".blend"):
        raise SkinkitError(f"{path}: the output must be a .blend file")
    bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(path), check_existing=False)
    return os.path.abspath(path)


def frame_range(text: str | None) -> range:
    """'A:B' or 'A:B:STEP' (inclusive), or the scene's own range."""
    import bpy

    if text is None:
        scene = bpy.context.scene
        return range(scene.frame_start, scene.frame_end + 1)
    try:
        first, last, *step = (int(part) for part in text.split(":"))
        if len(step) > 1 or (step and step[0] < 1):
            raise ValueError
    except ValueError:
        raise SkinkitError(f"--frames {text!r}: expected A:B or A:B:STEP with whole numbers, e.g. 1:48") from None
    if last < first:
        raise SkinkitError(f"--frames {text!r}: the range is empty (B < A)")
    return range(first, last + 1, step[0] if step else 1)


@contextmanager
def stdout_to_stderr(active: bool):
    """Sends everything written to file descriptor 1 (Blender prints from C) to stderr while inside."""
    if not active:
        yield
        return
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def report(result: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(result, sort_keys=True))
        return
    for key, value in result.items():
        print(f"{key}: {value}")


def report_failure(message: str, as_json: bool) -> int:
    print(f"skinkit: error: {message}", file=sys.stderr)
    if as_json:
        print(json.dumps({"error": message}))
    return 1


if __name__ == "__main__":
    sys.exit(main())
