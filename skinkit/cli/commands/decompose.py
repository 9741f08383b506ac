"""skinkit decompose: a mesh sequence without a rig skinned with a skeleton, weights and an animation-space model."""
import os
import resource
import time

import numpy as np

from ...decompose import DEFAULT_BONES, METHODS
from ..._checks import check_same_units
from ...fit import DEFAULT_MAX_INFLUENCES
from ...model import SkinkitError
from .. import progress
from ..inputs import blender_module, frame_range, load_scene, read_rest, read_sequence
from ..outputs import save_scene, write_frames

STAGE = "Skin from Mesh Sequence"


def add_parser(subparsers, common):
    parser = subparsers.add_parser(
        "decompose", help="skin a mesh sequence that has no rig: a skeleton, weights and an animation-space model",
        description="Skin a same-topology mesh sequence without a rig: automatic proxy bones (or a rough rig's "
                    "skeleton fitted to the sequence), linear-blend weights and an animation-space model; frames not "
                    "used for training are replayed with the model fixed.",
        parents=[common["json"], common["sequence_scale"]])
    parser.add_argument("--sequence", required=True, metavar="SEQ",
                        help="a folder of same-topology .obj files (one per frame, in name order; frames are "
                             "numbered from 1) or an .abc file (scene frames)")
    parser.add_argument("--bones", type=int, default=DEFAULT_BONES,
                        help=f"bone count for automatic bones (default {DEFAULT_BONES})")
    parser.add_argument("--max-influences", type=int, default=DEFAULT_MAX_INFLUENCES)
    parser.add_argument("--train", default="", help="the training frames, e.g. '1-11' or '1, 5, 9-12' "
                                                    "(default: all); the others are held out")
    parser.add_argument("--rest", help="the rest pose (.obj, scaled by --sequence-scale, or .fbx/.glb with one mesh, "
                                       "in its own units); default: the first frame")
    parser.add_argument("--frames", help="A:B or A:B:STEP, the frames of the sequence (default: an .abc's range, an "
                                         ".obj folder's files numbered from 1)")
    parser.add_argument("--method", choices=METHODS, default=METHODS[0])
    parser.add_argument("--rig", help="with --method rough-rig: a .blend with the drawn armature and the mesh, "
                                      "whose vertex groups named like the bones mark their core vertices")
    parser.add_argument("--armature", help="the rough rig's armature (default: the only one)")
    parser.add_argument("--object", help="the rough rig's mesh (default: the only mesh)")
    parser.add_argument("--out", help="save the armature, its action and the skinned mesh: .blend or .glb")
    parser.add_argument("--export-frames", metavar="DIR",
                        help="write every frame's animation-space reconstruction as .obj, in the input's vertex "
                             "order and units")
    return parser


def run(arguments) -> dict:
    """Without --out or a rough rig the job runs on numpy alone (an .abc still needs bpy to be read)."""
    from ...framelist import parse_frame_list

    started = time.perf_counter()
    if arguments.out and os.path.splitext(arguments.out)[1].lower() not in (".blend", ".glb"):
        raise SkinkitError(f"--out {arguments.out}: expected a .blend or .glb file")
    frames, triangles, numbers = read_input_sequence(arguments)
    if arguments.rest:
        rest, rest_triangles = read_rest(arguments.rest, arguments.sequence_scale)
        if len(rest) != frames.shape[1]:
            raise SkinkitError(f"--rest {arguments.rest}: {len(rest)} vertices, the sequence has {frames.shape[1]}")
        check_same_units(rest, frames, "--sequence frame {index}", f"--rest {arguments.rest}",
                         f"set --sequence-scale (now {arguments.sequence_scale:g}) so that both use one unit")
        frames, numbers, triangles = np.concatenate([rest[None], frames]), [0] + numbers, rest_triangles
    wanted = parse_frame_list(arguments.train)
    train = np.isin(numbers, wanted) if wanted else np.ones(len(numbers), bool)
    if arguments.rest:
        train[0] = True  # the rest pose is part of the training data
    if arguments.method == "rough-rig" or arguments.out:
        report, reconstruction = decompose_in_blender(arguments, frames, triangles, numbers, train)
    else:
        from ...decompose import solve_sequence

        _, _, replay, report = solve_sequence(frames, triangles, train, bones=arguments.bones,
                                              max_influences=arguments.max_influences)
        reconstruction = replay["animation"]
    if arguments.export_frames:
        report["export_frames"] = write_frames(arguments.export_frames, numbers, reconstruction,
                                               arguments.sequence_scale)
    report.update(seconds=time.perf_counter() - started,
                  peak_memory_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0)
    return report


def read_input_sequence(arguments):
    """The sequence's frames in world space (an .abc read into an empty scene)."""
    if arguments.sequence.lower().endswith(".abc"):
        blender_module()
        from ...blender.scene import empty_scene

        empty_scene()
    frames = frame_range(arguments.frames) if arguments.frames else None
    return read_sequence(arguments.sequence, arguments.sequence_scale, frames)


def decompose_in_blender(arguments, frames, triangles, numbers, train):
    """Runs the Blender operator's code on the sequence and saves the result (--out); returns the report and the
    animation-space reconstruction of every frame."""
    bpy = blender_module()
    from ...blender import decompose as bridge
    from ...blender import scene

    if arguments.method == "rough-rig":
        if not arguments.rig:
            raise SkinkitError("--method rough-rig needs --rig: a .blend with the drawn armature and the mesh")
        load_scene(arguments.rig)
        armature = scene.find_armature(arguments.armature)
        mesh_object = scene.scene_mesh(arguments.object)
        frames = scene.world_to_local(mesh_object, frames)
    else:
        armature = None
        scene.empty_scene()
        mesh_object = scene.new_mesh_object("sequence", frames[0], triangles)
    sequence = bridge.Sequence(frames, list(numbers), [f"frame {n}" for n in numbers])
    report = bridge.skin_object(mesh_object, sequence, method=arguments.method, bones=arguments.bones,
                                max_influences=arguments.max_influences,
                                train_frames=[n for n, t in zip(numbers, train) if t], armature_object=armature,
                                progress=progress.update)
    reconstruction = report.pop("reconstruction")
    if arguments.method != "rough-rig":
        bpy.data.objects.remove(mesh_object)  # only the skinned copy and its rig are kept
    if arguments.out:
        report["out"] = save_scene(arguments.out, (report["armature"], report["skinned_object"]))
    return report, reconstruction
