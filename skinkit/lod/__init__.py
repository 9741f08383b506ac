"""Level of detail for animation-space models (Merry 2007, chapter 6): Limit Influences (section 6.4)."""
from .influences import limit_influences

__all__ = ["limit_influences"]
