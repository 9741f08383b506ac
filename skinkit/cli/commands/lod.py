"""Build discrete levels of detail of a skinned mesh (its stored animation-space model, or its linear blend skinning
converted in memory) with the armature's pose statistics (stored, or from its action): a collection <name>_LOD of
objects <name>_LOD0..n, each with the UV map, materials, model, linear-blend vertex groups and an Armature modifier.
With --sequence FOLDER|FILE.abc --bones N in place of the scene, the bare mesh sequence is decomposed first (as
`skinkit decompose` does, --rest included; the `vt` of a --rest OBJ become the UV map every level keeps)."""
import argparse
import os
import time

import numpy as np

from ...fit import DEFAULT_MAX_INFLUENCES
from ...lod.chain import COLLAPSES, DEFAULT_COLLAPSE, DEFAULT_INFLUENCE_COST_SCALE, METRICS
from ...model import SkinkitError
from ..inputs import frame_range, open_scene, read_rest
from ..outputs import save_scene, written_atomically
from .stats import spread_radians

HELP = "discrete levels of detail of a skinned mesh (LOD0..n)"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("lod", help=HELP, description=__doc__,
                                   parents=[common["json"], common["sequence_scale"]])
    parser.add_argument("scene", nargs="?", metavar="SCENE.blend", help="the scene (or give --sequence)")
    parser.add_argument("--object", help="the mesh (default: the only mesh with an Armature modifier)")
    parser.add_argument("--sequence", metavar="FOLDER|FILE.abc",
                        help="in place of the scene: a bare mesh sequence (a folder of .obj files, frames numbered "
                             "from 1, or an .abc), decomposed with --bones first")
    parser.add_argument("--bones", type=int, help="with --sequence: the decomposition's bone count")
    parser.add_argument("--rest", help="with --sequence: the rest pose (.obj, whose vt become the levels' UV map, or "
                                       ".fbx/.glb with one mesh); default: the first frame")
    parser.add_argument("--spread", type=float, default=0.0, metavar="DEGREES",
                        help="with --sequence: the pose statistics of the decomposition's frames with each joint "
                             "rotation also turned by +-DEGREES about its axes, as `skinkit stats --spread` (default 0)")
    parser.add_argument("--levels", type=int, required=True, help="levels including LOD0 (the input), at least 2")
    parser.add_argument("--metric", choices=tuple(METRICS), default="animation",
                        help="collapse costs over all poses (default) or in the rest pose")
    parser.add_argument("--no-influence-simplification", action="store_true",
                        help="collapse edges only (influences are kept)")
    parser.add_argument("--collapse", choices=tuple(COLLAPSES), default=DEFAULT_COLLAPSE,
                        help="half-edge collapses, full (interior edges re-solve the survivor to the least error) "
                             f"or auto (the cheaper per edge); default {DEFAULT_COLLAPSE}")
    parser.add_argument("--influence-cost-scale", type=float, default=DEFAULT_INFLUENCE_COST_SCALE, metavar="S",
                        help="influence collapses are ranked at their cost times S against edge collapses (default "
                             f"{DEFAULT_INFLUENCE_COST_SCALE:g})")
    parser.add_argument("--rank-by-cost", action="store_true",
                        help="rank collapses by cost, as the thesis (default: edge collapses by cost over the square "
                             "root of the influences they remove)")
    parser.add_argument("--start-influences", type=int, default=0, metavar="K0",
                        help="first limit every vertex to K0 influences (the engine's budget), LOD0 included "
                             "(default 0: none)")
    parser.add_argument("--no-refit", action="store_true",
                        help="keep the collapses' coordinates (default: each level refitted to the full detail)")
    parser.add_argument("--max-influences", type=int, default=DEFAULT_MAX_INFLUENCES, metavar="K",
                        help=f"bones per vertex in the levels' vertex groups (default {DEFAULT_MAX_INFLUENCES})")
    parser.add_argument("--out", metavar="OUT.blend|OUT.glb",
                        help="save the scene with the levels (.blend), or the levels and their armature (.glb)")
    parser.add_argument("--export-frames", metavar="DIR",
                        help="write DIR/lod<l>/<frame:04d>.obj: each level as its Armature modifier poses it, with "
                             "vt and faces")
    parser.add_argument("--frames", help="with --export-frames: A:B or A:B:STEP, inclusive (default: the scene's "
                                         "frame range)")
    return parser


def run(arguments) -> dict:
    started = time.perf_counter()
    if arguments.frames is not None and arguments.export_frames is None:
        raise SkinkitError("--frames needs --export-frames DIR")
    if arguments.out is not None and not arguments.out.lower().endswith((".blend", ".glb")):
        raise SkinkitError(f"--out {arguments.out}: the output must be a .blend or a .glb file")
    if arguments.export_frames is not None and os.path.exists(arguments.export_frames) and \
            not os.path.isdir(arguments.export_frames):
        raise SkinkitError(f"--export-frames {arguments.export_frames}: not a folder")
    from ...blender import lod_chain

    if arguments.sequence is not None:
        mesh_object, numbers = decomposed_sequence(arguments)
        frames = sequence_frames(arguments.frames, numbers) if arguments.export_frames is not None else None
    else:
        mesh_object = scene_mesh(arguments)
        frames = frame_range(arguments.frames) if arguments.export_frames is not None else None
    report = lod_chain.build_lod_chain(mesh_object, levels=arguments.levels, metric=arguments.metric,
                                       simplify_influences=not arguments.no_influence_simplification,
                                       max_influences=arguments.max_influences, collapse=arguments.collapse,
                                       influence_cost_scale=arguments.influence_cost_scale,
                                       rank_per_influence=not arguments.rank_by_cost,
                                       start_influences=arguments.start_influences,
                                       refit=not arguments.no_refit)
    result = {"object": mesh_object.name, "collection": report["collection"],
              "levels": [{key: row[key] for key in ("level", "vertices", "triangles", "influences", "error")}
                         for row in report["levels"]],
              "warnings": report["warnings"]}
    if arguments.export_frames is not None:
        unit = arguments.sequence_scale if arguments.sequence is not None else 1.0
        result["export_frames"] = export_frames(arguments.export_frames, report["objects"], frames, unit)
        result["frames"] = len(frames)
    if arguments.sequence is not None:
        result["spread_degrees"] = arguments.spread
    if arguments.out is not None:
        names = report["objects"] + [mesh_object.modifiers[0].object.name]
        result["out"] = save_scene(arguments.out, names)
    result["seconds"] = time.perf_counter() - started
    return result


def scene_mesh(arguments):
    if arguments.scene is None:
        raise SkinkitError("give a SCENE.blend, or --sequence FOLDER|FILE.abc --bones N")
    for flag in ("bones", "rest"):
        if getattr(arguments, flag) is not None:
            raise SkinkitError(f"--{flag} goes with --sequence (a scene brings its own rig)")
    if arguments.spread:
        raise SkinkitError("--spread goes with --sequence (for a scene, store spread statistics first with "
                           "`skinkit stats --spread`)")
    bpy = open_scene(arguments.scene)
    from ...blender.scene import find_skinned_mesh

    return find_skinned_mesh(bpy.context.scene.objects, arguments.object)


def decomposed_sequence(arguments):
    """The sequence skinned by `skinkit decompose`'s own code (automatic bones, every frame trains); returns the
    skinned mesh and the sequence's frame numbers (the action's keys), without the rest pose's frame 0."""
    from . import decompose

    if arguments.scene is not None or arguments.object is not None:
        raise SkinkitError("--sequence replaces SCENE.blend and --object: give one or the other")
    if arguments.bones is None:
        raise SkinkitError("--sequence needs --bones N (the decomposition's bone count)")
    spread = spread_radians(arguments.spread)
    options = argparse.Namespace(sequence=arguments.sequence, sequence_scale=arguments.sequence_scale, frames=None,
                                 method=decompose.METHODS[0], bones=arguments.bones,
                                 max_influences=arguments.max_influences, rig=None, armature=None, object=None,
                                 out=None)
    frames, triangles, numbers = decompose.read_input_sequence(options)
    sequence_numbers = list(numbers)
    corner_uv = None
    if arguments.rest:
        rest, triangles = read_rest(arguments.rest, arguments.sequence_scale)
        if len(rest) != frames.shape[1]:
            raise SkinkitError(f"--rest {arguments.rest}: {len(rest)} vertices, the sequence has {frames.shape[1]}")
        corner_uv = obj_corner_uv(arguments.rest, len(triangles))
        frames, numbers = np.concatenate([rest[None], frames]), [0] + list(numbers)
    report, _ = decompose.decompose_in_blender(options, frames, triangles, numbers, np.ones(len(numbers), bool))
    import bpy

    skinned = bpy.data.objects[report["skinned_object"]]
    if corner_uv is not None:
        layer = skinned.data.uv_layers.new(name="UVMap", do_init=False)
        layer.uv.foreach_set("vector", corner_uv.astype(np.float32).reshape(-1))  # one loop per triangle corner
        skinned.data.uv_layers.active = layer
    if spread:
        store_spread_statistics(skinned, spread, arguments.spread)
    return skinned, sequence_numbers


def store_spread_statistics(skinned, spread: float, degrees: float) -> None:
    """The decomposition's action frames as pose statistics with a spread, stored on its armature, where the chain
    takes its statistics from."""
    from ...blender import pose_statistics
    from ...blender.frames import action_frames
    from ...blender.rig import rig_of

    armature = rig_of(skinned).armature_object
    frames = list(action_frames(armature.animation_data.action))
    statistics = pose_statistics.compute(armature, "action", frames, spread)
    pose_statistics.store(armature, statistics, f"action frames {frames[0]}-{frames[-1]}, spread {degrees:g} degrees",
                          len(frames))


def obj_corner_uv(path: str, triangle_count: int):
    """(T, 3, 2) the `vt` of every triangle corner of an .obj rest pose, or None when it has none (or not on every
    face: the chain is then built without an atlas and says so)."""
    if not path.lower().endswith(".obj"):
        return None
    from ...meshio import read_obj_texture_corners, read_text_lines

    corners = read_obj_texture_corners(path)
    if len(corners) != triangle_count or not len(corners) or (corners < 0).any():
        return None
    texture = np.array([line.split()[1:3] for line in read_text_lines(path) if line.startswith("vt ")], float)
    return texture[corners]


def sequence_frames(text, numbers):
    """The frames to export: the sequence's own numbers, or those of them in --frames A:B[:STEP]."""
    if text is None:
        return list(numbers)
    wanted = set(frame_range(text))
    chosen = [n for n in numbers if n in wanted]
    if not chosen:
        raise SkinkitError(f"--frames {text}: none of the sequence's frames ({numbers[0]}..{numbers[-1]}) is in it")
    return chosen


def export_frames(folder: str, object_names, frames, unit: float = 1.0) -> str:
    """DIR/lod<l>/<frame:04d>.obj for every level and frame, in each level's local space and vertex order, divided
    by `unit` (a sequence read with --sequence-scale is written back in its own units)."""
    import bpy
    import numpy as np

    from ...blender.frames import depsgraphs_at, evaluated_positions
    from ...blender.rig import mesh_of
    from ...meshio import write_obj

    levels = [bpy.data.objects[name] for name in object_names]
    topology = []
    for index, level_object in enumerate(levels):
        mesh = mesh_of(level_object)
        data = level_object.data
        uv = None
        if data.uv_layers.active is not None:
            loop_uv = np.empty(len(data.loops) * 2, np.float32)
            data.uv_layers.active.uv.foreach_get("vector", loop_uv)
            uv = loop_uv.reshape(-1, 2)[mesh.triangle_loops].astype(np.float64)
        os.makedirs(os.path.join(folder, f"lod{index}"), exist_ok=True)
        topology.append((mesh.triangles, uv))
    for frame, depsgraph in zip(frames, depsgraphs_at(frames)):
        for index, (level_object, (triangles, uv)) in enumerate(zip(levels, topology)):
            path = os.path.join(folder, f"lod{index}", f"{frame:04d}.obj")
            with written_atomically(path) as temporary:
                write_obj(temporary, evaluated_positions(level_object, depsgraph) / unit, triangles, uv)
    return os.path.abspath(folder)
