"""The one place Blender enum identifiers become skinkit's option strings (the numpy layer's and the bridge's).

Operators and panels keep Blender's convention (upper-case identifiers in EnumProperty items); everything below
them speaks skinkit's lower-case strings ("per-vertex", "rough-rig", "animation", ...).
"""
from skinkit.blender.unwrap import METRICS
from skinkit.decompose import METHODS as SKIN_METHODS
from skinkit.fit import FIT_METHODS, INFLUENCE_SOURCES
from skinkit.metrics import STATISTICS_SOURCES

#: Each skinkit option string by its Blender enum identifier.
SKINKIT_OPTION = {
    **{option.upper().replace("-", "_"): option
       for option in FIT_METHODS + INFLUENCE_SOURCES + SKIN_METHODS + STATISTICS_SOURCES + METRICS},
    "AUTO": "auto", "SEAMS": "seams", "METRIC": "metric",
    # Level of detail (addon/lod.py): subdivision schemes, boundaries and UV smoothing.
    "CATMULL_CLARK": "catmull-clark", "LOOP": "loop", "ALL": "all", "PRESERVE_CORNERS": "preserve-corners",
    "NONE": "none", "PRESERVE_BOUNDARIES": "preserve-boundaries", "SMOOTH_ALL": "all",
}


def option(identifier: str) -> str:
    """skinkit's string for the Blender enum identifier."""
    return SKINKIT_OPTION[identifier]
