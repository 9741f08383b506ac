"""skinkit bake-normals: tangent-space normal maps of a LOD chain's levels from its LOD0 through the shared atlas
(or of any mesh from a high-resolution --source by ray casting within the cage), written as PNG or EXR with
OpenImageIO and wired into each level's material (Image Texture -> Normal Map on its UV map). One JSON row per map:
its path, texels filled and missed, seconds, and the mean and max angular error (degrees) of the stored map against
the exact source normals at the texel centres."""
import os
import time

from ...model import SkinkitError
from ...normal_maps import CORRESPONDENCES, FORMATS
from .. import progress
from ..inputs import open_scene
from ..outputs import save_scene

HELP = "bake tangent-space normal maps for a LOD chain (or a mesh from a high-resolution source)"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("bake-normals", help=HELP, description=__doc__, parents=[common["json"]])
    parser.add_argument("scene", metavar="SCENE.blend")
    add_target_arguments(parser, "bake this one mesh", "bake this chain's levels")
    parser.add_argument("--source", metavar="HIGH", help="a high-resolution mesh to ray-cast from (default: the "
                                                         "chain's LOD0, by --correspondence)")
    parser.add_argument("--correspondence", choices=CORRESPONDENCES, default=CORRESPONDENCES[0],
                        help="from the chain's LOD0: guided (a ray cast along each level's normals, checked against "
                             "the shared atlas; the default) or atlas (the same uv point only: the fastest)")
    parser.add_argument("--size", type=int, required=True, help="texels per side (e.g. 2048)")
    parser.add_argument("--margin", type=int, default=8, help="dilation margin in texels (default 8)")
    parser.add_argument("--samples", type=int, default=2, help="supersampling: N x N samples per texel (default 2)")
    parser.add_argument("--cage", type=float, help="ray-cast distance each way along the normal, in scene units "
                                                   "(default 5%% of the target's diagonal)")
    parser.add_argument("--format", choices=tuple(FORMATS), default="png16", help="the image format (default png16)")
    parser.add_argument("--frame", type=int, help="the pose to bake (default: the scene's current frame)")
    parser.add_argument("--out-dir", required=True, metavar="DIR", help="where the images are written")
    parser.add_argument("--no-pack", action="store_true", help="link the images from DIR instead of packing them "
                                                               "into the saved .blend")
    parser.add_argument("--out", metavar="OUT.blend", help="save the scene with the maps wired in")
    return parser


def run(arguments) -> dict:
    started = time.perf_counter()
    targets = open_targets(arguments)
    import bpy

    from ...blender import normal_maps

    source = None
    if arguments.source is not None:
        source = bpy.data.objects.get(arguments.source)
        if source is None:
            raise SkinkitError(f"--source: no object named '{arguments.source}'")
        if arguments.correspondence != CORRESPONDENCES[0]:
            raise SkinkitError("--correspondence: a --source mesh is ray cast; the correspondence is for a chain's "
                               "LOD0")
    progress.stage("Bake Normal Maps")
    report = normal_maps.bake_normal_maps(targets, source, progress=progress.update,
                                          correspondence=arguments.correspondence, size=arguments.size,
                                          margin=arguments.margin,
                                          samples=arguments.samples, cage=arguments.cage, frame=arguments.frame,
                                          image_format=arguments.format, out_dir=arguments.out_dir,
                                          pack=not arguments.no_pack)
    if arguments.out is not None:
        report["out"] = save_scene(arguments.out)
    report["seconds"] = time.perf_counter() - started
    return report


def add_target_arguments(parser, one_object: str, one_chain: str) -> None:
    """--object or --chain (one at most): what a bake command bakes, as open_targets reads them."""
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--object", help=f"{one_object} (default: every level of the scene's only LOD chain)")
    which.add_argument("--chain", help=f"{one_chain} (its collection or its source mesh's name)")


def open_targets(arguments) -> list:
    """Checks --out-dir, opens the scene and returns the meshes to bake: --object, or the levels of --chain (or of
    the scene's only LOD chain)."""
    if not os.path.isdir(arguments.out_dir) or not os.access(arguments.out_dir, os.W_OK):
        raise SkinkitError(f"--out-dir {arguments.out_dir}: not a writable folder")
    open_scene(arguments.scene)
    import bpy

    from ...blender import normal_maps

    if arguments.object is not None:
        target = bpy.data.objects.get(arguments.object)
        if target is None:
            raise SkinkitError(f"--object: no object named '{arguments.object}'")
        return [target]
    return normal_maps.chain_levels(normal_maps.find_chain(arguments.chain))
