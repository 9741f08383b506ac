"""skinkit bake-tangent-maps: tangent maps (Merry 2007, section 7.5) of a LOD chain's levels from the animation-space
model on its LOD0, through the shared atlas: per texel the bones of the LOD0 triangle there and the model's tangent
pair (dp/du, dp/dv), in tiles of n x n texels sharing one influence count (padded with zeros), as one multi-channel
EXR per level (and its mip chain, by the appendix A.1 averaging of 2x2 blocks in the metric of the rig's pose
statistics, with --mip-levels); and the object-space normal map they give at --frame, with its mean and max angular
error (degrees) against the posed LOD0 faces at the texel centres."""
import time

from .. import progress
from .bake_normals import add_target_arguments, open_targets

HELP = "bake tangent maps (per-texel animation-space tangents) for a LOD chain"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("bake-tangent-maps", help=HELP, description=__doc__, parents=[common["json"]])
    parser.add_argument("scene", metavar="SCENE.blend")
    add_target_arguments(parser, "one level", "this chain's levels")
    parser.add_argument("--size", type=int, default=256, help="texels per side (default 256, the thesis' 8.6.2)")
    parser.add_argument("--tile", type=int, default=8, help="tile side in texels (default 8, the thesis' advice)")
    parser.add_argument("--max-influences", type=int, default=16, help="bones a texel may need (default 16)")
    parser.add_argument("--format", choices=("exr", "exr-float"), default="exr-float",
                        help="half or float EXR (default float)")
    parser.add_argument("--mip-levels", type=int, default=1,
                        help="maps in the mip chain, this one included (each next by appendix A.1 averaging of 2x2 "
                             "blocks; default 1)")
    parser.add_argument("--frame", type=int, help="the pose of the object-space normal map (default: current)")
    parser.add_argument("--out-dir", required=True, metavar="DIR", help="where the maps are written")
    return parser


def run(arguments) -> dict:
    started = time.perf_counter()
    targets = open_targets(arguments)
    from ...blender import normal_maps

    progress.stage("Bake Tangent Maps")
    report = normal_maps.bake_tangent_maps(targets, progress=progress.update, size=arguments.size,
                                           tile=arguments.tile, max_influences=arguments.max_influences,
                                           frame=arguments.frame, out_dir=arguments.out_dir,
                                           image_format=arguments.format, mip_levels=arguments.mip_levels)
    report["seconds"] = time.perf_counter() - started
    return report
