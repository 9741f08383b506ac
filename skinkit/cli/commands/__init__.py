"""The commands of the `skinkit` command line, in the order `skinkit --help` lists them."""
from . import bake, convert, decompose, distance, evaluate, fit, limit_influences, lod, stats, subdivide, unwrap
from . import export

COMMANDS = (convert, evaluate, fit, stats, distance, unwrap, bake, decompose, lod, limit_influences, subdivide)
COMMANDS += (export,)
