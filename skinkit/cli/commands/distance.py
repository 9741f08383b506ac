"""skinkit distance: the animation-space distances between vertex pairs over every pose."""
from ...model import SkinkitError
from ..inputs import open_scene, vertex_list

HELP = "mean (L2,2) and max (L2,inf) distances between vertex pairs over all poses"

STAGE = "Show Max-Distance Bounds"


def add_parser(subparsers, common):
    parser = subparsers.add_parser("distance", help=HELP, description=HELP, parents=[common["scene"]])
    parser.add_argument("--from-vertices", required=True, help="vertex indices a_1,a_2,...")
    parser.add_argument("--to-vertices", required=True, help="vertex indices b_1,b_2,... (or one index for all)")
    return parser


def run(arguments) -> dict:
    open_scene(arguments.scene)
    import bpy

    from ...blender import pose_statistics, skinning, storage
    from ...blender.rig import rig_of
    from ...blender.scene import find_skinned_mesh
    from ...metrics import SparseVectors

    mesh_object = find_skinned_mesh(bpy.context.scene.objects, arguments.object)
    if not storage.has_model(mesh_object.data):
        skinning.convert_object(mesh_object)
    stored = storage.read_model(mesh_object.data, mesh_object.name)
    statistics = pose_statistics.in_mesh_space(pose_statistics.load(rig_of(mesh_object).armature_object),
                                               stored.bind)
    vertex_count = stored.model.vertex_count
    first, second = vertex_list(arguments.from_vertices, vertex_count), vertex_list(arguments.to_vertices, vertex_count)
    if len(second) == 1:
        second = second * len(first)
    if len(first) != len(second):
        raise SkinkitError(f"--from-vertices has {len(first)} vertices, --to-vertices {len(second)}: give as many, "
                           "or one to measure every vertex against")
    vectors = SparseVectors.rows(stored.model, first).combined(SparseVectors.rows(stored.model, second), -1.0)
    mean, most = statistics.mean_distance(vectors), statistics.max_distance(vectors)
    return {"object": mesh_object.name, "pairs": [{"from": a, "to": b, "mean": float(m), "max": float(x)}
                                                  for a, b, m, x in zip(first, second, mean, most)]}
