"""Level of detail for animation-space models (Merry 2007, chapters 6-7): progressive meshes simplified in the
animation-space metric with influence simplification, geomorphs, and Limit Influences (section 6.4)."""
from .chain import LodChain, LodLevel, build_chain, refit_level
from .influences import limit_influences
from .influences import choose_sample_weight, sampled_metric

__all__ = ["build_chain", "refit_level", "LodChain", "LodLevel", "limit_influences"]
__all__ += ["choose_sample_weight", "sampled_metric"]
