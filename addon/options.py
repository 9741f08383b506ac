"""The one place Blender enum identifiers become skinkit's option strings (the numpy layer's and the bridge's).

Operators and panels keep Blender's convention (upper-case identifiers in EnumProperty items); everything below
them speaks skinkit's lower-case strings ("per-vertex", "rough-rig", "animation", ...).
"""
from skinkit.blender.decompose import FRAME_SOURCES
from skinkit.blender.unwrap import METRICS
from skinkit.decompose import METHODS as SKIN_METHODS
from skinkit.fit import FIT_METHODS, INFLUENCE_SOURCES
from skinkit.metrics import STATISTICS_SOURCES

#: Each skinkit option string by its Blender enum identifier.
SKINKIT_OPTION = {
    **{option.upper().replace("-", "_"): option
       for option in FIT_METHODS + INFLUENCE_SOURCES + SKIN_METHODS + STATISTICS_SOURCES + METRICS
       + FRAME_SOURCES},
    "AUTO": "auto", "SEAMS": "seams", "METRIC": "metric",
    # Level of detail (addon/lod.py): subdivision schemes, boundaries and UV smoothing.
    "CATMULL_CLARK": "catmull-clark", "LOOP": "loop", "ALL": "all", "PRESERVE_CORNERS": "preserve-corners",
    "NONE": "none", "PRESERVE_BOUNDARIES": "preserve-boundaries", "SMOOTH_ALL": "all",
    # LOD chain (addon/lod_chain.py): edge collapses ("AUTO" above serves it too).
    "HALF": "half", "FULL": "full",
}


def option(identifier: str) -> str:
    """skinkit's string for the Blender enum identifier."""
    return SKINKIT_OPTION[identifier]


# ---- enum items shared by the operators' properties and the panel's remembered values (scene.skinkit) -----------

FIT_SOURCE_ITEMS = (
    ("SHAPE_KEYS", "Shape Keys", "The mesh's shape keys, each paired with the frame of a marker named like it"),
    ("OBJECTS", "Selected Objects", "Selected meshes of the same topology, each paired with the frame of a marker "
                                    "named like it (or its 'skinkit_frame' property)"),
    ("SEQUENCE", "Mesh Sequence", "An object animated by a Mesh Sequence Cache (Alembic) or Mesh Cache, over the "
                                  "frame range"))
FIT_METHOD_ITEMS = (
    ("PER_VERTEX", "Per Vertex", "Each vertex on its own, regularised towards small coordinates (fast)"),
    ("GLOBAL", "Global", "All vertices together, neighbours regularised towards each other (smoother)"))
FIT_INFLUENCE_ITEMS = (
    ("RIG", "Rig Weights", "The bones weighting each vertex now, grown by some rings of neighbours"),
    ("PAINTED", "Painted", "Vertex groups named 'influence:<bone>' mark where each bone may act"),
    ("AUTOMATIC", "Automatic", "The bones whose motion best explains each vertex over the examples"))
SKIN_SOURCE_ITEMS = (
    ("AUTO", "What It Has", "Its shape keys if it has some, else its Mesh Sequence Cache or Mesh Cache, else the "
                            "other selected meshes"),
    ("SHAPE_KEYS", "Shape Keys", "The Basis and the mesh's other shape keys, one frame each"),
    ("SEQUENCE", "Mesh Sequence", "The mesh as its Mesh Sequence Cache or Mesh Cache plays it over the frame range"),
    ("OBJECTS", "Selected Objects", "The active mesh, then the other selected meshes of the same topology"))
SKIN_METHOD_ITEMS = (
    ("AUTOMATIC", "Automatic Bones", "Proxy bones found from how the vertices move (like Dem Bones)"),
    ("ROUGH_RIG", "Fit Rough Rig", "A drawn armature gives the hierarchy and rough joints; vertex groups named like "
                                   "its bones mark vertices that move rigidly with them"))
STATISTICS_SOURCE_ITEMS = (
    ("ACTION", "Action", "The armature's animation over the frame range, every Step frames"),
    ("POSES", "Example Poses", "The armature's poses at the listed frames (e.g. '1, 12, 30-34')"),
    ("LIMITS", "Rotation Limits", "Analytic: hinges from Limit Rotation constraints, other bones uniform"),
    ("UNIFORM", "Uniform Rotations", "Analytic: every joint rotates freely (the skeleton-only metric)"))
