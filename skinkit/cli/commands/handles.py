"""skinkit handles: train a handle rig on a mesh sequence (Feng 2010, chapter 2), or predict whole meshes from
handle positions alone with a trained one."""
import os
import time

import numpy as np

from ... import handles
from ...framelist import parse_frame_list
from ...handles.clusters import CLUSTERINGS
from ...handles.train import DEFAULT_BONES, DEFAULT_CLUSTERING, bone_count_list, rms_error
from ...model import SkinkitError
from ..inputs import vertex_list
from ..outputs import check_output_folder, written_atomically
from .decompose import read_input_sequence

HELP = "learn a handle rig from a mesh sequence, or deform a mesh with one from a few handle positions"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("handles", help=HELP, description=__doc__)
    actions = parser.add_subparsers(metavar="ACTION", required=True)
    train = actions.add_parser("train", help="train a handle rig on a mesh sequence",
                               parents=[common["json"], common["sequence_scale"]])
    train.add_argument("--sequence", required=True, metavar="FOLDER|FILE.abc",
                       help="a folder of same-topology .obj files (frames numbered from 1) or an .abc")
    train.add_argument("--frames", help="A:B or A:B:STEP, the frames of an .abc (default: its range)")
    train.add_argument("--train", default="", help="the training frames, e.g. '1-300' (default: all); the first "
                                                   "frame given is the rest pose")
    choice = train.add_mutually_exclusive_group(required=True)
    choice.add_argument("--handles", type=int, metavar="N", help="suggest N control points automatically")
    choice.add_argument("--handle-vertices", metavar="I,J,...", help="the control points' vertex indices")
    train.add_argument("--bones", type=int, default=DEFAULT_BONES, help=f"proxy bones (default {DEFAULT_BONES})")
    train.add_argument("--bone-counts", metavar="B,B,...",
                       help="proxy-bone counts to try instead of --bones: the one with the least validation error "
                            "on the training frames is kept")
    train.add_argument("--clustering", choices=CLUSTERINGS, default=DEFAULT_CLUSTERING,
                       help="how the proxy bones are found: decompose's rigid clustering or the hierarchical "
                            f"triangle clustering (default {DEFAULT_CLUSTERING})")
    train.add_argument("--kernel", choices=handles.KERNELS, default="gaussian")
    train.add_argument("--poisson", action="store_true",
                       help="replace the predicted bone translations by the Poisson solve (eq. 2.11)")
    train.add_argument("--lbs-weights", action="store_true",
                       help="keep the proxy bones' linear-blend weights (default: refitted for DQS)")
    train.add_argument("--validate", action="store_true",
                       help="choose the kernel parameter's scale and the ridge by validation on the training frames")
    train.add_argument("--out", required=True, metavar="MODEL.npz")
    train.set_defaults(action=run_train)
    predict = actions.add_parser("predict", help="deform the mesh from handle positions with a trained rig",
                                 parents=[common["json"], common["sequence_scale"]])
    predict.add_argument("model", metavar="MODEL.npz")
    source = predict.add_mutually_exclusive_group(required=True)
    source.add_argument("--sequence", metavar="FOLDER|FILE.abc",
                        help="frames whose control-point vertices give the handles; the prediction is compared "
                             "with them")
    source.add_argument("--targets", metavar="HANDLES.npy", help="handle positions (frames, handles, 3)")
    predict.add_argument("--frames", help="A:B or A:B:STEP, the frames of an .abc (default: its range)")
    predict.add_argument("--export-frames", required=True, metavar="DIR",
                         help="write DIR/<frame:04d>.obj, in the input's vertex order and units")
    predict.set_defaults(action=run_predict)
    return parser


def run(arguments) -> dict:
    return arguments.action(arguments)


def run_train(arguments) -> dict:
    started = time.perf_counter()
    if not arguments.out.lower().endswith(".npz"):
        raise SkinkitError(f"--out {arguments.out}: expected a .npz file")
    frames, triangles, numbers = read_input_sequence(arguments)
    wanted = parse_frame_list(arguments.train)
    train = np.isin(numbers, wanted) if wanted else np.ones(len(numbers), bool)
    vertices = None if arguments.handle_vertices is None else vertex_list(arguments.handle_vertices, frames.shape[1])
    model = handles.train(frames[train], triangles, handle_vertices=vertices, handle_count=arguments.handles,
                          bones=arguments.bones, bone_counts=bone_count_list(arguments.bone_counts or ""),
                          clustering=arguments.clustering, kernel=arguments.kernel, poisson=arguments.poisson,
                          dqs_weights=not arguments.lbs_weights, validate=arguments.validate)
    with written_atomically(arguments.out) as temporary:
        model.save(temporary)
    report = model.report
    return {"handle_vertices": report["handle_vertices"], "bones": report["bones"], "kernel": report["kernel"],
            "examples": report["examples"], "poisson": report["poisson"], "training_error": report["training_rms"],
            "proxy_bone_fit_error": report["proxy_bone_fit_rms"], "dqs_weights": report["dqs_weights"],
            "validation": report.get("validation"), "clustering": report["clustering"],
            "bone_validation": report.get("bone_validation"), "out": os.path.abspath(arguments.out),
            "seconds": time.perf_counter() - started}


def run_predict(arguments) -> dict:
    started = time.perf_counter()
    model = handles.load(arguments.model)
    check_output_folder(arguments.export_frames)
    frames = None
    if arguments.sequence:
        frames, _, numbers = read_input_sequence(arguments)
        if frames.shape[1] != len(model.rest_positions):
            raise SkinkitError(f"--sequence {arguments.sequence}: {frames.shape[1]} vertices, the model has "
                               f"{len(model.rest_positions)}")
        targets = model.handle_positions_of(frames)
    else:
        targets = read_targets(arguments.targets, model) * arguments.sequence_scale
        numbers = list(range(1, len(targets) + 1))
    predicting = time.perf_counter()
    predicted = model.predict(targets)
    milliseconds = (time.perf_counter() - predicting) * 1000 / len(targets)
    report = {"frames": len(targets), "handles": model.handle_count, "ms_per_frame": milliseconds,
              "export_frames": write_numbered_frames(arguments.export_frames, numbers, predicted,
                                                     arguments.sequence_scale)}
    if frames is not None:
        extent = float(np.ptp(model.rest_positions, axis=0).max()) or 1.0
        distances = np.linalg.norm(predicted - frames, axis=-1)
        report.update(rms_error=rms_error(predicted, frames, extent), max_error=float(distances.max() / extent),
                      error_unit="largest side of the rest bounding box")
    report["seconds"] = time.perf_counter() - started
    return report


def read_targets(path: str, model) -> np.ndarray:
    try:
        targets = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as error:
        raise SkinkitError(f"--targets {path}: not a .npy array ({error})") from None
    if targets.ndim == 2:
        targets = targets[None]
    if targets.ndim != 3 or targets.shape[1:] != (model.handle_count, 3):
        raise SkinkitError(f"--targets {path}: expected shape (frames, {model.handle_count}, 3), got {targets.shape}")
    return np.asarray(targets, np.float64)


def write_numbered_frames(folder: str, numbers, positions, scale: float) -> str:
    """DIR/<frame:04d>.obj for each frame, divided by scale (the input's units), in the input's vertex order."""
    from ...meshio import write_obj

    os.makedirs(folder, exist_ok=True)
    for number, frame in zip(numbers, positions):
        with written_atomically(os.path.join(folder, f"{number:04d}.obj")) as temporary:
            write_obj(temporary, frame / scale)
    return os.path.abspath(folder)
