"""Level of detail (Merry 2007, chapters 6-7): progressive meshes with influence simplification."""
from .chain import LodChain, LodLevel, build_chain

__all__ = ["build_chain", "LodChain", "LodLevel"]
