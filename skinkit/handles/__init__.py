"""Handle-driven deformation learned from examples (Feng 2010, chapter 2).

An animator moves a few control points ("handles") and the whole mesh deforms the way its examples did:

* `suggest_handles`: control points from the examples (PCA of the vertex positions, varimax rotation, the two
  extreme vertices of each rotated component; section 2.3).
* `triangle_hierarchy`: the hierarchical triangle clustering's merge order (section 2.3, after Wang et al.), cut
  at any bone count by `TriangleHierarchy.labels`.
* `train`: proxy bones fitted to the examples (skinkit.decompose's rigid clustering, or the hierarchical one, and
  decompose's weights; the bone count given or chosen by validation), each bone's
  rigid motion per example as a sign-aligned dual quaternion, one regularised kernel CCA per bone from the
  handle positions to its dual quaternion (sections 2.4, 2.7), and the Poisson solver that replaces the predicted
  translations (section 2.5).
* `HandleModel.predict(handle_positions)`: bone dual quaternions (C runtime), then dual-quaternion skinning.
"""
from .clusters import CLUSTERINGS, TriangleHierarchy, triangle_hierarchy
from .model import FORMAT_VERSION, KERNELS, HandleModel, load
from .suggest import suggest_handles
from .train import train

__all__ = ["CLUSTERINGS", "FORMAT_VERSION", "KERNELS", "HandleModel", "TriangleHierarchy", "load", "suggest_handles",
           "train", "triangle_hierarchy"]
