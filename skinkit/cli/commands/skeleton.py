"""Extract a skeleton from a mesh segmented into parts (Vasilakis 2008): the Opening, Centroid or Principal Axis
method, optionally refined. Parts come from an OBJ's g/o groups or materials, loose pieces meeting at coincident
vertices, a DMAT of linear-blend weights (each vertex's dominant bone), or, in a .blend, the mesh's vertex groups,
materials, loose parts or `skinkit_part` face attribute. Writes the joints as JSON, a BVH, the thesis' hierarchy
file (.hier) or a .blend with an armature (one bone per part, Limit Rotation constraints, rigid vertex groups)."""
from __future__ import annotations

import json
import os

from ...model import SkinkitError
from ..outputs import save_scene, written_atomically

HELP = "extract a skeleton from a mesh segmented into parts (Vasilakis 2008)"
OUTPUTS = (".json", ".bvh", ".hier", ".blend")


def add_parser(subparsers, common):
    from ...skeleton import METHODS

    parser = subparsers.add_parser("skeleton", help=HELP, description=__doc__, parents=[common["json"]])
    parser.add_argument("mesh", metavar="MESH.obj|SCENE.blend")
    parser.add_argument("--object", help="in a .blend: the mesh (default: the only mesh)")
    parser.add_argument("--parts", default="groups",
                        help="groups | materials | loose | attribute (.blend) | weights:FILE.dmat (default groups)")
    parser.add_argument("--method", choices=METHODS, default="principal-axis")
    parser.add_argument("--refine", action="store_true", help="local and parent refinement (Algorithms 3-4)")
    parser.add_argument("--max-angle", type=float, default=20.0, help="the refinements' largest turn, degrees")
    parser.add_argument("--hierarchy", help="a hierarchy-and-limits file naming the parts (their tree and limits)")
    parser.add_argument("--out", required=True, help="RIG.json | RIG.bvh | RIG.hier | RIG.blend")
    return parser


def part_source(text: str) -> tuple[str, str | None]:
    if text.startswith("weights:"):
        return "weights", text.split(":", 1)[1]
    if text not in ("groups", "materials", "loose", "attribute"):
        raise SkinkitError(f"--parts {text!r}: expected groups, materials, loose, attribute or weights:FILE.dmat")
    return text, None


def obj_parts(path: str, source: str, weights_path: str | None):
    from ...meshio import read_obj
    from ...skeleton import from_weights, loose_parts, read_dmat, read_obj_groups

    if source in ("groups", "materials"):
        return read_obj_groups(path, source)
    positions, triangles = read_obj(path)
    if source == "loose":
        return loose_parts(positions, triangles)
    if source == "weights":
        return from_weights(positions, triangles, read_dmat(weights_path))
    raise SkinkitError(f"--parts {source}: an .obj has no face attribute; use groups, materials, loose or weights")


def write_json(path: str, result: dict) -> str:
    with written_atomically(path) as temporary:
        with open(temporary, "w", encoding="utf-8") as stream:
            json.dump(result, stream, indent=1)
    return os.path.abspath(path)


def run(arguments) -> dict:
    from ...skeleton import extract_skeleton, read_hierarchy

    extension = os.path.splitext(arguments.out)[1].lower()
    if extension not in OUTPUTS:
        raise SkinkitError(f"--out {arguments.out}: expected one of {', '.join(OUTPUTS)}")
    source, weights_path = part_source(arguments.parts)
    hierarchy = read_hierarchy(arguments.hierarchy) if arguments.hierarchy else None
    is_blend = arguments.mesh.lower().endswith(".blend")
    if not is_blend and not arguments.mesh.lower().endswith(".obj"):
        raise SkinkitError(f"{arguments.mesh}: expected an .obj or a .blend")
    if is_blend or extension == ".blend":
        return run_in_blender(arguments, source, weights_path, hierarchy, is_blend)
    parts = obj_parts(arguments.mesh, source, weights_path)
    ordered = hierarchy.reordered(parts.names) if hierarchy else None
    skeleton = extract_skeleton(parts, arguments.method, parents=None if ordered is None else ordered.parents,
                                refine=arguments.refine, max_angle=arguments.max_angle)
    return write_files(arguments, skeleton, parts, summary(skeleton), None if ordered is None else ordered.limits)


def summary(skeleton) -> dict:
    """The JSON report; with --out RIG.json also the rig file `skinkit rigid-skin --rig` reads (its "rig" entry)."""
    return {"joints": skeleton.joints(), "parts": skeleton.part_report(), "method": skeleton.method,
            "seconds": skeleton.seconds, "stage_seconds": skeleton.stage_seconds}


def run_in_blender(arguments, source, weights_path, hierarchy, is_blend) -> dict:
    from ..inputs import blender_module, open_scene

    bpy = blender_module()
    from ...blender import scene
    from ...blender.skeleton import extract_rig

    if is_blend:
        open_scene(arguments.mesh)
        mesh_object = scene.named_or_only(bpy.context.scene.objects, arguments.object, "mesh",
                                          among=scene.meshes())
        if mesh_object.type != "MESH":
            raise SkinkitError(f"'{mesh_object.name}' is not a mesh")
    else:
        scene.empty_scene()
        parts = obj_parts(arguments.mesh, source, weights_path)
        mesh_object = scene.new_mesh_object(os.path.splitext(os.path.basename(arguments.mesh))[0], parts.positions,
                                            parts.triangles)
        write_face_parts(mesh_object, parts)
        source, weights_path = "attribute", None
    armature, skeleton, parts = extract_rig(mesh_object, source, arguments.method, arguments.refine,
                                            arguments.max_angle, weights_path, hierarchy)
    result = summary(skeleton)
    result["armature"] = armature.name
    if arguments.out.lower().endswith(".blend"):
        result["out"] = save_scene(arguments.out)
        return result
    data = armature.data
    bpy.data.objects.remove(armature)  # a file output: the scene is not saved
    bpy.data.armatures.remove(data)
    ordered = hierarchy.reordered(parts.names) if hierarchy else None
    return write_files(arguments, skeleton, parts, result, None if ordered is None else ordered.limits)


def write_files(arguments, skeleton, parts, result, limits) -> dict:
    """Writes --out as JSON (the result itself), BVH or the hierarchy-and-limits file."""
    from ...skeleton import free_limits, write_bvh, write_hierarchy
    from ...skeleton.hierarchy import Hierarchy

    extension = os.path.splitext(arguments.out)[1].lower()
    if extension == ".json":
        result["out"] = write_json(arguments.out, {**result, "rig": skeleton.to_dict()})
    elif extension == ".bvh":
        result["out"] = os.path.abspath(write_bvh(arguments.out, skeleton))
    else:
        tree = Hierarchy(parts.names, skeleton.part_parents,
                         free_limits(parts.part_count) if limits is None else limits)
        result["out"] = os.path.abspath(write_hierarchy(arguments.out, tree))
    return result


def write_face_parts(mesh_object, parts) -> None:
    """The parts of an .obj as the skinkit_part face attribute of its new mesh (one polygon per triangle)."""
    from ...blender.skeleton import PART_ATTRIBUTE, PART_NAMES

    attribute = mesh_object.data.attributes.new(PART_ATTRIBUTE, "INT", "FACE")
    attribute.data.foreach_set("value", parts.triangle_parts)
    mesh_object.data[PART_NAMES] = list(parts.names)
