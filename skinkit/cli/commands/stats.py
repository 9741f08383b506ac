"""skinkit stats: an armature's pose statistics, stored on it, with the rank of P and the culling sphere."""
import time

import numpy as np

from ...metrics import STATISTICS_SOURCES
from ...model import SkinkitError
from ..inputs import frame_range, open_scene
from ..outputs import save_scene

HELP = "compute an armature's pose statistics and the culling sphere"

STAGE = "Compute Pose Statistics"


def add_parser(subparsers, common):
    parser = subparsers.add_parser(
        "stats", help=HELP, parents=[common["json"]],
        description="Compute an armature's pose statistics (for the animation-space metrics), store them on it, "
                    "and report the rank of P and the culling sphere of its skinned mesh.")
    parser.add_argument("scene", metavar="SCENE.blend")
    parser.add_argument("--armature", help="the armature (default: the only one in the scene)")
    parser.add_argument("--action", help="the action to sample (default: the armature's own)")
    parser.add_argument("--frames", help="A:B or A:B:STEP (default: the action's frame range)")
    parser.add_argument("--from", dest="source", choices=STATISTICS_SOURCES, default="action",
                        help="sampled from the action or from example poses (--poses), or analytic from Limit "
                             "Rotation constraints or uniform rotations")
    parser.add_argument("--poses", default="",
                        help="with --from poses: the frames of the example poses, e.g. '1,12,30-34'")
    parser.add_argument("--spread", type=float, default=0.0, metavar="DEGREES",
                        help="with --from action or poses: each sampled joint rotation also turned by +-DEGREES about "
                             "the joint's axes, so a few example poses also price the poses around them (default 0)")
    parser.add_argument("--object", help="the skinned mesh for the culling sphere (default: the armature's only one)")
    parser.add_argument("--out", help="save the scene with the statistics stored here (.blend)")
    return parser


def run(arguments) -> dict:
    open_scene(arguments.scene)
    from ...blender import pose_statistics, skinning, storage
    from ...blender.frames import action_frames
    from ...blender.scene import action_assigned, find_armature, skinned_mesh_of
    from ...framelist import parse_frame_list

    armature = find_armature(arguments.armature)
    spread = spread_radians(arguments.spread)
    started = time.perf_counter()
    frames = []
    if arguments.source in ("action", "poses"):
        with action_assigned(armature, arguments.action) as action:
            if arguments.source == "poses":
                frames = parse_frame_list(arguments.poses)
                source = f"{len(frames)} example poses"
            else:
                frames = list(frame_range(arguments.frames) if arguments.frames else action_frames(action))
                source = f"action '{action.name}' frames {frames[0]}-{frames[-1]}"
            computed = pose_statistics.compute(armature, arguments.source, frames, spread)
            if spread:
                source += f", spread {arguments.spread:g} degrees"
    else:
        computed = pose_statistics.compute(armature, arguments.source, spread=spread)
        source = {"limits": "rotation limits", "uniform": "uniform rotations"}[arguments.source]
    seconds = time.perf_counter() - started
    pose_statistics.store(armature, computed, source, len(frames))
    result = {"armature": armature.name, "bones": computed.bone_count - 1, "frames": len(frames), "source": source,
              "spread_degrees": arguments.spread,
              "seconds": seconds, "rank": pose_statistics.rank_of(computed), "unknowns": 4 * computed.bone_count}
    mesh_object = skinned_mesh_of(armature, arguments.object)
    if mesh_object is not None:
        if not storage.has_model(mesh_object.data):
            skinning.convert_object(mesh_object)  # in memory for the sphere; saved only with --out
        bounds = pose_statistics.mesh_bounds(mesh_object)
        result["culling_sphere"] = {"object": mesh_object.name, "centre": bounds["centre"].tolist(),
                                    "radius": bounds["radius"]}
    if arguments.out:
        result["out"] = save_scene(arguments.out)
    return result


def spread_radians(degrees: float) -> float:
    if not 0 <= degrees <= 180:  # also refuses nan
        raise SkinkitError(f"--spread: expected degrees in [0, 180], got {degrees:g}")
    return float(np.radians(degrees))
