"""Export a LOD chain (<NAME>_LOD0..n, from `skinkit lod`) or one skinned mesh (a fit, a decomposition) with its
armature and action through Blender's own glTF, FBX or USD exporter, for game engines: at most 4 normalised weights
per vertex, <NAME>_LOD<n> naming, and for glTF the animation-space model as custom vertex attributes
(docs/engine-format.md). glTF and USD files are in metres (the scene's Unit Scale, or --unit-scale, converts); FBX
records the scene's unit. The file appears only once complete; the scene is not saved."""
import time

from ...model import SkinkitError
from ..inputs import open_scene

HELP = "a LOD chain or a skinned mesh as .glb, .fbx or .usd for game engines"
FORMATS = ("glb", "fbx", "usd")  # skinkit.blender.export.FORMATS (read here without importing bpy)
SUFFIXES = {".glb": "glb", ".fbx": "fbx", ".usd": "usd", ".usdc": "usd", ".usda": "usd", ".usdz": "usd"}


def add_parser(subparsers, common):
    parser = subparsers.add_parser("export", help=HELP, description=__doc__, parents=[common["json"]])
    parser.add_argument("scene", metavar="SCENE.blend")
    parser.add_argument("--chain", required=True, metavar="NAME",
                        help="the chain NAME_LOD0..n, or the skinned mesh NAME when there is no such chain")
    parser.add_argument("--format", choices=FORMATS,
                        help="glb, fbx or usd (default: from the extension of --out)")
    parser.add_argument("--out", required=True, metavar="FILE", help="the file to write (.glb, .fbx, .usd/.usdc)")
    parser.add_argument("--no-animation-space", action="store_true",
                        help="glTF: leave out the _SKINKIT_* animation-space vertex attributes")
    parser.add_argument("--unit-scale", type=float, metavar="METRES",
                        help="glb and usd: metres per Blender unit (default: the scene's Unit Scale, 0.01 for a "
                             "centimetre scene); the file is written in metres")
    return parser


def output_format(arguments) -> str:
    suffix = next((s for s in sorted(SUFFIXES, key=len, reverse=True) if arguments.out.lower().endswith(s)), None)
    if arguments.format is not None:
        return arguments.format
    if suffix is None:
        raise SkinkitError(f"--out {arguments.out}: give --format, or end the name in .glb, .fbx or .usdc")
    return SUFFIXES[suffix]


def run(arguments) -> dict:
    started = time.perf_counter()
    fmt = output_format(arguments)
    open_scene(arguments.scene)
    from ...blender import export

    export.check_extension(arguments.out, fmt)
    report = export.export_for_engines(export.chain_objects(arguments.chain), arguments.out, fmt,
                                       animation_space=not arguments.no_animation_space,
                                       unit_scale=arguments.unit_scale)
    report["seconds"] = time.perf_counter() - started
    return report
