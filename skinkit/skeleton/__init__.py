"""Skeletons from segmented meshes (Vasilakis 2008): parts from several sources, skeleton extraction by the Opening,
Centroid and Principal Axis methods with refinements, the hierarchy-and-limits file, and synthetic samples."""
from .extract import JOINT_KINDS, METHODS, Skeleton, extract_skeleton
from .hierarchy import Hierarchy, free_limits, read_hierarchy, write_bvh, write_hierarchy
from .parts import Parts, from_vertex_labels, from_weights, loose_parts, read_dmat, read_obj_groups, write_obj_groups
from .samples import Sample, chain_of_cylinders, star_of_limbs

__all__ = ["JOINT_KINDS", "METHODS", "Skeleton", "extract_skeleton", "Hierarchy", "free_limits", "read_hierarchy",
           "write_hierarchy", "write_bvh", "Parts", "from_vertex_labels", "from_weights", "loose_parts", "read_dmat",
           "read_obj_groups", "write_obj_groups", "Sample", "chain_of_cylinders", "star_of_limbs"]
