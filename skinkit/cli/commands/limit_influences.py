"""Reduce every vertex of a skinned mesh (its animation-space model, or its Armature modifier's skinning converted
first) to at most K influences by the removals of least animated error (pose statistics stored on the armature, or
its action's), written as a new object <name>_limited; the animated error over the frames is compared with Blender's
Limit Total."""
from ..inputs import frame_range, open_scene
from ..outputs import save_scene

HELP = "limit every vertex to K influences (a new object), compared with Blender's Limit Total"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("limit-influences", help=HELP, description=__doc__, parents=[common["scene"]])
    parser.add_argument("--max-influences", type=int, required=True, metavar="K")
    parser.add_argument("--frames", help="A:B or A:B:STEP where the error is measured (default: the action's frames)")
    parser.add_argument("--out", help="save the scene (.blend) or the new object with its armature (.glb)")
    parser.add_argument("--sampled-metric", action="store_true",
                        help="also use the action's frames' own metric, blended with the statistics by validation")
    return parser


def run(arguments) -> dict:
    open_scene(arguments.scene)
    import bpy

    from ...blender import lod
    from ...blender.scene import find_skinned_mesh

    mesh_object = find_skinned_mesh(bpy.context.scene.objects, arguments.object)
    frames = frame_range(arguments.frames) if arguments.frames else None
    limited, report = lod.limit_object(mesh_object, arguments.max_influences, frames,
                                       sampled_metric=arguments.sampled_metric)
    result = {**report, "limited_object": limited.name}
    if arguments.out:
        armature = lod.rig_of(limited).armature_object
        result["out"] = save_scene(arguments.out, [limited.name, armature.name])
    return result
