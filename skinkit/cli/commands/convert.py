"""skinkit convert: a rig's linear blend skinning as an animation-space model, saved in a new .blend."""
from ..inputs import open_scene
from ..outputs import save_scene

HELP = "convert an object's linear blend skinning to animation space and save the scene"

#: The progress bar's stage: the operator's label.
STAGE = "Convert to Animation Space"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("convert", help=HELP, description=HELP, parents=[common["scene"]])
    parser.add_argument("--out", required=True, help="the .blend to write (the input is not modified)")
    parser.add_argument("--ignore-unmatched-groups", action="store_true",
                        help="ignore vertex groups that name no bone instead of refusing the mesh")
    return parser


def run(arguments) -> dict:
    open_scene(arguments.scene)
    import bpy

    from ...blender import skinning
    from ...blender.scene import find_skinned_mesh

    mesh_object = find_skinned_mesh(bpy.context.scene.objects, arguments.object)
    result = skinning.convert_object(mesh_object, arguments.ignore_unmatched_groups)
    return {**result, "out": save_scene(arguments.out)}
