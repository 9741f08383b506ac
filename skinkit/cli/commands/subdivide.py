"""Subdivide a skinned mesh together with its animation-space model (or its Armature modifier's skinning converted
first): the new object <name>_subdivided deforms as Blender's Subdivision Surface (Limit Surface off) after the
Armature modifier, in every pose."""
from ...subdivide import BOUNDARIES, MAX_LEVELS, SCHEMES, UV_SMOOTHING
from ..inputs import open_scene
from ..outputs import save_scene

HELP = "subdivide a skinned mesh and its animation-space model (a new object)"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("subdivide", help=HELP, description=__doc__, parents=[common["scene"]])
    parser.add_argument("--levels", type=int, required=True, help=f"1 to {MAX_LEVELS}")
    parser.add_argument("--scheme", choices=SCHEMES, default=SCHEMES[0])
    parser.add_argument("--boundary", choices=BOUNDARIES, default=BOUNDARIES[0])
    parser.add_argument("--uv-smooth", choices=UV_SMOOTHING, default="preserve-corners")
    parser.add_argument("--out", required=True, help="the .blend to write (the input is not modified)")
    return parser


def run(arguments) -> dict:
    open_scene(arguments.scene)
    import bpy

    from ...blender import lod
    from ...blender.scene import find_skinned_mesh
    from ...model import SkinkitError

    if not arguments.out.endswith(".blend"):
        raise SkinkitError(f"--out {arguments.out}: the output must be a .blend file")
    mesh_object = find_skinned_mesh(bpy.context.scene.objects, arguments.object)
    subdivided, report = lod.subdivide_object(mesh_object, levels=arguments.levels, scheme=arguments.scheme,
                                              boundary=arguments.boundary, uv_smooth=arguments.uv_smooth)
    return {**report, "subdivided_object": subdivided.name, "out": save_scene(arguments.out)}
