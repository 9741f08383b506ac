"""The commands of the `skinkit` command line, in the order `skinkit --help` lists them."""
from . import bake, convert, decompose, distance, evaluate, fit, limit_influences, lod, stats, subdivide, unwrap
from . import bake_normals, bake_tangent_maps, batch, export, handles, rigid_skin, runtime_bench, skeleton

COMMANDS = (convert, evaluate, fit, stats, distance, unwrap, bake, decompose, lod, limit_influences, subdivide,
            bake_normals, bake_tangent_maps, export, runtime_bench, skeleton, rigid_skin, handles, batch)
