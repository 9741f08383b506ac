"""skinkit: animation-space and linear-blend skinning over a native C core.

numpy in, numpy out; importing skinkit never imports Blender (the bridge is skinkit.blender).
"""
from .model import (
    AnimationSpaceModel,
    Mesh,
    Skeleton,
    SkinkitError,
    SparseWeights,
    convert_lbs,
    lbs_evaluate,
    normals_from_tangents,
    skinning_matrices,
)
from .subdivide import subdivide  # skinkit.subdivide(...): the function, as the LOD issue names it
from . import handles  # skinkit.handles.train(...), as the handle-rig issue names it
from ._checks import memory_limit, set_memory_limit  # a budget for big allocations (CLI --memory-limit)

__version__ = "0.1.0"

__all__ = [
    "AnimationSpaceModel",
    "Mesh",
    "Skeleton",
    "SkinkitError",
    "SparseWeights",
    "convert_lbs",
    "lbs_evaluate",
    "normals_from_tangents",
    "skinning_matrices",
    "subdivide",
    "set_memory_limit",
    "memory_limit",
    "__version__",
]
