"""skinkit bake: the stored model's animation as a PC2 point cache and/or a shape-key baked copy."""
import os

from ...model import SkinkitError
from .. import progress
from ..inputs import frame_range, open_scene
from ..outputs import save_scene

HELP = "bake the model's animation to a PC2 cache and/or shape keys"

STAGE = "Bake"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("bake", help=HELP, description=HELP, parents=[common["scene"]])
    parser.add_argument("--frames", help="A:B or A:B:STEP, inclusive (default: the scene's frame range)")
    parser.add_argument("--pc2", help="write a PC2 point cache here")
    parser.add_argument("--out", help="write the scene with a shape-key baked copy of the object here")
    return parser


def run(arguments) -> dict:
    if not arguments.pc2 and not arguments.out:
        raise SkinkitError("bake needs --pc2 FILE, --out FILE.blend, or both")
    open_scene(arguments.scene)
    import bpy

    from ...blender import skinning, storage
    from ...blender.scene import find_skinned_mesh

    mesh_object = find_skinned_mesh(bpy.context.scene.objects, arguments.object)
    if not storage.has_model(mesh_object.data):
        raise SkinkitError(f"'{mesh_object.name}' has no animation-space model; run `skinkit convert` first")
    frames = frame_range(arguments.frames)
    positions = skinning.positions_over_frames(mesh_object, frames, progress=progress.update)
    result = {"object": mesh_object.name, "frames": len(frames), "vertices": len(mesh_object.data.vertices)}
    if arguments.pc2:
        skinning.bake_mesh_cache(mesh_object, os.path.abspath(arguments.pc2), frames, positions, add_object=False)
        result["pc2"] = os.path.abspath(arguments.pc2)
    if arguments.out:
        result["baked_object"] = skinning.bake_shape_keys(mesh_object, frames, positions).name
        result["out"] = save_scene(arguments.out)
    return result
