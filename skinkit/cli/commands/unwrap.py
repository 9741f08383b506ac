"""skinkit unwrap: a texture atlas with the least stretch in the rest pose or over an animation, as an OBJ."""
import os

import numpy as np

from ..._checks import check_same_units
from ...model import SkinkitError
from ...pack import DEFAULT_MARGIN, DEFAULT_TEXTURE_SIZE
from ..inputs import blender_module, check_vertex_count, load_scene, read_mesh, read_sequence
from ..outputs import written_atomically

STAGE = "Animated Unwrap"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("unwrap", help="a texture atlas with least stretch over an animation",
                                   description="Unwrap a mesh into a texture atlas that minimises stretch in the rest "
                                               "pose or over an animation (animation-space metric), and write it "
                                               "as an OBJ whose vt carry the uvs, in the input's vertex order.",
                                   parents=[common["json"]])
    parser.add_argument("mesh", metavar="MESH", help="an .obj, or a .blend/.fbx/.glb holding the mesh")
    parser.add_argument("--object", help="the mesh in a .blend/.fbx/.glb MESH, or the rig's deformed mesh "
                                         "(default: the only one)")
    animation = parser.add_mutually_exclusive_group()
    animation.add_argument("--sequence", metavar="SEQ",
                           help="the animation as an .abc file or a folder of same-topology .obj files")
    animation.add_argument("--rig", metavar="RIG", help="a .blend/.fbx with an armature deforming the mesh")
    parser.add_argument("--action", help="with --rig: the action whose frames give the pose statistics and the "
                                         "frames to evaluate (default: the armature's own)")
    parser.add_argument("--metric", choices=("rest", "animation"),
                        help="flatten in the rest pose or over the animation (default: animation when --sequence or "
                             "--rig is given)")
    parser.add_argument("--seams-from", metavar="MESH_WITH_SEAMS",
                        help="hard chart boundaries: a .blend's edges marked as seams, or an .obj's uv islands")
    parser.add_argument("--mode", choices=("auto", "seams"), default="auto",
                        help="auto: merge charts greedily; seams: the charts the seams cut out")
    parser.add_argument("--charts", type=int, help="target chart count (auto mode)")
    parser.add_argument("--straighten", action="store_true",
                        help="straight chart boundaries between corners (for mip-mapping and LOD; raises stretch)")
    parser.add_argument("--segment-in", choices=("rest", "metric"), default="rest",
                        help="segment in 3-D (default) or in the metric's leading directions (auto mode)")
    parser.add_argument("--texture-size", type=int, default=DEFAULT_TEXTURE_SIZE)
    parser.add_argument("--margin", type=int, default=DEFAULT_MARGIN, help="texels between charts")
    parser.add_argument("--out", required=True, metavar="OUT.obj")
    return parser


def run(arguments) -> dict:
    from ...meshio import write_obj
    from ...unwrap import sequence_embedding, unwrap

    if not arguments.out.lower().endswith(".obj"):
        raise SkinkitError(f"--out {arguments.out}: the output must be an .obj file")
    if arguments.action is not None and arguments.rig is None:
        raise SkinkitError("--action needs --rig RIG")
    metric = arguments.metric or ("animation" if arguments.sequence or arguments.rig else "rest")
    if metric == "animation" and not (arguments.sequence or arguments.rig):
        raise SkinkitError("--metric animation needs the animation: --sequence SEQ or --rig RIG --action NAME")
    positions, triangles = read_mesh(arguments.mesh, arguments.object)
    seams = seams_from(arguments.seams_from, len(positions)) if arguments.seams_from else None
    embedding, frames = None, None
    if arguments.sequence:
        frames = animation_frames(arguments.sequence, len(positions))
        check_same_units(positions, frames, "--sequence frame {index}", f"the mesh of {arguments.mesh}",
                         "rescale one of the files to the other's units")
        embedding = sequence_embedding(frames) if metric == "animation" else None
    elif arguments.rig:
        embedding, frames = rig_animation(arguments, len(positions), metric == "animation")
    result = unwrap(positions, triangles, embedding=embedding, seams=seams, mode=arguments.mode,
                    chart_count=arguments.charts, straighten=arguments.straighten, segment_in=arguments.segment_in,
                    texture_size=arguments.texture_size, margin=arguments.margin, evaluation_frames=frames)
    with written_atomically(arguments.out) as temporary:
        write_obj(temporary, positions, triangles, result.uv)
    report = result.report
    keys = ("charts", "seconds", "stretch_metric", "stretch_rest", "stretch_frames", "packing_efficiency",
            "texture_efficiency", "vertices", "triangles", "loose_vertices")
    # JSON has no infinity: a stretch that is infinite (flipped or degenerate uv triangles, counted in
    # invalid_triangles) is reported as null.
    return {**{key: None if report[key] == np.inf else report[key] for key in keys}, "metric": metric,
            "frames": 0 if frames is None else len(frames), "seams": len(result.seams),
            "invalid_triangles": int(report["flattening"]["invalid_triangles"]), "out": os.path.abspath(arguments.out),
            "flattening": {key: int(value) for key, value in report["flattening"].items()},
            "status": report["status"], "problems": report["problems"],
            "chart_worst": [{"chart": chart, "triangle": triangle, "stretch": None if not np.isfinite(value) else value}
                            for chart, (triangle, value) in enumerate(zip(report["chart_worst_triangle"],
                                                                          report["chart_worst_stretch"]))]}


def seams_from(path: str, vertex_count: int):
    """(S, 2) vertex pairs: a .blend's mesh edges marked as seams, or the edges between an .obj's uv islands."""
    extension = os.path.splitext(path)[1].lower()
    if extension == ".obj":
        from ...meshio import read_obj, read_obj_texture_corners
        from ...unwrap import texture_seams

        positions, triangles = read_obj(path)
        check_vertex_count(path, len(positions), vertex_count)
        corners = read_obj_texture_corners(path)
        if not len(corners) or (corners < 0).any():
            raise SkinkitError(f"--seams-from {path}: every face needs texture coordinates (f v/vt) to take uv "
                               "islands from")
        return texture_seams(triangles, corners)
    if extension != ".blend":
        raise SkinkitError(f"--seams-from {path}: expected a .blend (edges marked as seams) or an .obj (uv islands)")
    load_scene(path)
    from ...blender.scene import scene_mesh
    from ...blender.unwrap import seam_pairs

    mesh_object = scene_mesh()
    check_vertex_count(path, len(mesh_object.data.vertices), vertex_count)
    return seam_pairs(mesh_object.data)


def animation_frames(source: str, vertex_count: int):
    """(F, V, 3): the frames of an .obj folder or an .abc file (read into an empty scene)."""
    if source.lower().endswith(".abc"):
        blender_module()
        from ...blender.scene import empty_scene

        empty_scene()
    positions, _, _ = read_sequence(source)
    check_vertex_count(source, positions.shape[1], vertex_count)
    return positions


def rig_animation(arguments, vertex_count: int, animation_metric: bool):
    """(the animation-space embedding or None, the deformed positions over the action's frames)."""
    load_scene(arguments.rig)
    from ...blender import unwrap as blender_unwrap
    from ...blender.frames import action_frames
    from ...blender.scene import action_assigned, find_armature, skinned_mesh_of

    armature = find_armature()
    mesh_object = skinned_mesh_of(armature, arguments.object)
    if mesh_object is None:
        raise SkinkitError(f"{arguments.rig}: name the mesh '{armature.name}' deforms with --object")
    check_vertex_count(arguments.rig, len(mesh_object.data.vertices), vertex_count)
    with action_assigned(armature, arguments.action) as action:
        frames = action_frames(action)
        embedding = None
        if animation_metric:
            embedding = blender_unwrap.animation_metric(mesh_object, frames=frames)  # the action's own metric
        return embedding, blender_unwrap.deformed_positions(mesh_object, frames)
