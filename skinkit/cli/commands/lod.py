"""Build discrete levels of detail of a skinned mesh (its stored animation-space model, or its linear blend skinning
converted in memory) with the armature's pose statistics (stored, or from its action): a collection <name>_LOD of
objects <name>_LOD0..n, each with the UV map, materials, model, linear-blend vertex groups and an Armature modifier."""
import os
import time

from ...fit import DEFAULT_MAX_INFLUENCES
from ...lod.chain import METRICS
from ...model import SkinkitError
from ..inputs import frame_range, open_scene
from ..outputs import save_scene, written_atomically

HELP = "discrete levels of detail of a skinned mesh (LOD0..n)"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("lod", help=HELP, description=__doc__, parents=[common["scene"]])
    parser.add_argument("--levels", type=int, required=True, help="levels including LOD0 (the input), at least 2")
    parser.add_argument("--metric", choices=tuple(METRICS), default="animation",
                        help="collapse costs over all poses (default) or in the rest pose")
    parser.add_argument("--no-influence-simplification", action="store_true",
                        help="collapse edges only (influences are kept)")
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
    open_scene(arguments.scene)
    import bpy

    from ...blender import lod_chain
    from ...blender.scene import find_skinned_mesh

    mesh_object = find_skinned_mesh(bpy.context.scene.objects, arguments.object)
    frames = frame_range(arguments.frames) if arguments.export_frames is not None else None
    report = lod_chain.build_lod_chain(mesh_object, levels=arguments.levels, metric=arguments.metric,
                                       simplify_influences=not arguments.no_influence_simplification,
                                       max_influences=arguments.max_influences)
    result = {"object": mesh_object.name, "collection": report["collection"],
              "levels": [{key: row[key] for key in ("level", "vertices", "triangles", "influences", "error")}
                         for row in report["levels"]],
              "warnings": report["warnings"]}
    if arguments.export_frames is not None:
        result["export_frames"] = export_frames(arguments.export_frames, report["objects"], frames)
        result["frames"] = len(frames)
    if arguments.out is not None:
        names = report["objects"] + [mesh_object.modifiers[0].object.name]
        result["out"] = save_scene(arguments.out, names)
    result["seconds"] = time.perf_counter() - started
    return result


def export_frames(folder: str, object_names, frames) -> str:
    """DIR/lod<l>/<frame:04d>.obj for every level and frame, in each level's local space and vertex order."""
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
                write_obj(temporary, evaluated_positions(level_object, depsgraph), triangles, uv)
    return os.path.abspath(folder)
