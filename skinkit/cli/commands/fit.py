"""skinkit fit: animation space and linear blend skinning fitted to example meshes of a rigged character."""
from ...fit import (DEFAULT_DELTA, DEFAULT_LAMBDA, DEFAULT_MAX_INFLUENCES, DEFAULT_RINGS, FIT_METHODS,
                   INFLUENCE_SOURCES, VALIDATION_FACTORS)
from ...model import SkinkitError
from .. import progress
from ..inputs import frame_range, is_sequence_file, load_scene, read_sequence
from ..outputs import save_scene, write_frames

STAGE = "Fit from Example Poses"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("fit", help="fit animation space and linear blend skinning to example meshes",
                                   description="Fit animation space and linear blend skinning to example meshes of a "
                                               "rigged character.", parents=[common["json"], common["sequence_scale"]])
    parser.add_argument("--rig", required=True, metavar="RIG",
                        help="a scene with an animated armature: .blend, .fbx, .glb or .gltf")
    parser.add_argument("--sequence", required=True, metavar="SEQ",
                        help="the examples: an .abc file, a folder of same-topology .obj files (world space, one per "
                             "frame), or the name of an object in the rig's scene (with a mesh cache, or the rigged "
                             "mesh itself with one shape key per example)")
    parser.add_argument("--object", help="the rigged mesh (default: the only mesh with an Armature modifier)")
    parser.add_argument("--armature", help="the armature (default: the only one in the scene)")
    parser.add_argument("--rest", help="rest geometry in the rig's bind pose, when the rig has no mesh: an .obj, or "
                                       "an .fbx/.glb holding one mesh")
    parser.add_argument("--frames", help="A:B or A:B:STEP, the frames of the examples (default: the scene's range; "
                                         "the files of an .obj folder pair with these frames in order)")
    parser.add_argument("--method", choices=FIT_METHODS, default=FIT_METHODS[0])
    parser.add_argument("--regularisation", type=float,
                        help=f"λ (per-vertex, default {DEFAULT_LAMBDA:g}) or δ (global, default {DEFAULT_DELTA:g}); "
                             "the per-vertex λ (the global fit's start) is then chosen among it times "
                             f"{', '.join(f'{f:g}' for f in VALIDATION_FACTORS)} by held-out validation on the "
                             "training frames")
    parser.add_argument("--no-validation", dest="validate", action="store_false",
                        help="use λ exactly as given instead of choosing it by validation")
    parser.add_argument("--no-rest-pose", dest="reproduce_rest", action="store_false",
                        help="do not make the fit reproduce the rig's rest pose (a heavily weighted example)")
    parser.add_argument("--bones-from", choices=INFLUENCE_SOURCES, default=INFLUENCE_SOURCES[0],
                        help="influence sets: the rig's weights grown by --rings rings, painted 'influence:<bone>' "
                             "vertex groups, or the bones whose motion best explains each vertex")
    parser.add_argument("--rings", type=int, default=DEFAULT_RINGS)
    parser.add_argument("--max-influences", type=int, default=DEFAULT_MAX_INFLUENCES)
    parser.add_argument("--hold-out", default="", help="frames kept out of training, e.g. '5, 10, 20-24'")
    parser.add_argument("--export-frames", metavar="DIR",
                        help="write each example's animation-space reconstruction as .obj, in the input's vertex "
                             "order, space and units")
    parser.add_argument("--out", help="save the scene with the fitted mesh here (.blend)")
    return parser


def run(arguments) -> dict:
    load_scene(arguments.rig)
    from ...blender import fitting
    from ...blender.scene import find_armature, fitted_mesh, local_to_world
    from ...framelist import parse_frame_list

    armature = find_armature(arguments.armature)
    mesh_object = fitted_mesh(armature, arguments.object, arguments.rest)
    examples, scale = read_examples(arguments, mesh_object, armature)
    report = fitting.fit_object(mesh_object, examples, method=arguments.method,
                                regularisation=arguments.regularisation, source=arguments.bones_from,
                                rings=arguments.rings, max_influences=arguments.max_influences,
                                held_out_frames=parse_frame_list(arguments.hold_out), validate=arguments.validate,
                                reproduce_rest=arguments.reproduce_rest, progress=progress.update)
    reconstruction = report.pop("reconstruction")
    if arguments.export_frames:
        report["export_frames"] = write_frames(arguments.export_frames, examples.frames,
                                               local_to_world(mesh_object, reconstruction), scale)
    if arguments.out:
        report["out"] = save_scene(arguments.out)
    return report


def read_examples(arguments, mesh_object, armature):
    """The examples, and the scale their source was read at (exports divide by it): files (an .obj folder or an .abc,
    paired with the rig's frames from its scene's first), or an object of the rig's scene."""
    import bpy

    from ...blender import fitting

    source = arguments.sequence
    if is_sequence_file(source):
        frames = frame_range(arguments.frames) if arguments.frames else None
        positions, _, numbers = read_sequence(source, arguments.sequence_scale, frames,
                                              first_frame=bpy.context.scene.frame_start)
        return fitting.examples_from_positions(mesh_object, positions, numbers), arguments.sequence_scale
    other = bpy.context.scene.objects.get(source)
    if other is None:
        raise SkinkitError(f"--sequence {source!r}: not a folder, an .abc file, or an object in the rig's scene")
    if other == mesh_object:
        return fitting.examples_from_shape_keys(mesh_object, armature), 1.0
    return fitting.examples_from_sequence(mesh_object, other, frame_range(arguments.frames)), 1.0
