"""skinkit eval: the stored model over frames beside Blender's Armature modifier."""
from ..inputs import frame_range, open_scene

HELP = "evaluate the model over frames beside Blender's Armature modifier"

STAGE = "Compare with Armature"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("eval", help=HELP, description=HELP, parents=[common["scene"]])
    parser.add_argument("--frames", help="A:B or A:B:STEP, inclusive (default: the scene's frame range)")
    return parser


def run(arguments) -> dict:
    open_scene(arguments.scene)
    import bpy

    from ...blender import skinning, storage
    from ...blender.scene import find_skinned_mesh

    mesh_object = find_skinned_mesh(bpy.context.scene.objects, arguments.object)
    converted = not storage.has_model(mesh_object.data)
    if converted:  # in memory only: the file is not written
        skinning.convert_object(mesh_object)
    result = skinning.compare_with_armature(mesh_object, frame_range(arguments.frames))
    return {**result, "converted_in_memory": converted}
