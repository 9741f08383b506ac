"""Packing flattened charts into a texture atlas (Merry 2007, section 5.4), and the atlas' texture efficiency.

uv arrays are per triangle corner, (T, 3, 2), as skinkit.flatten makes them. The work is done by the C core
(csrc/sk_pack.c); this module checks shapes and types and names what is wrong.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _core
from ._checks import as_index_array, as_real_array
from .flatten import checked_uv
from .model import SkinkitError

__all__ = ["Packing", "pack", "texture_efficiency", "DEFAULT_TEXTURE_SIZE", "DEFAULT_MARGIN"]

#: The texture the atlas is packed for, in texels on a side, and the gap kept between charts, in texels.
DEFAULT_TEXTURE_SIZE = 1024
DEFAULT_MARGIN = 4


@dataclass(frozen=True, eq=False)
class Packing:
    uv: np.ndarray             # (T, 3, 2) in [0, 1]^2
    packing_efficiency: float  # the uv triangles' total area: the fraction of the texture covered
    report: dict


def pack(uv, charts, *, texture_size: int = DEFAULT_TEXTURE_SIZE,
         margin: float = DEFAULT_MARGIN, surface_area=None) -> Packing:
    """Packs the charts into [0, 1]^2 (section 5.4): each chart scaled so its uv area is its surface area
    (surface_area (T,), e.g. skinkit.flatten.metric_area(edge_lengths_sq); None keeps the uv scales), turned to its smallest
    bounding rectangle, and the rectangles placed in alternating rows at the largest scale that fits, at least
    `margin` texels of a texture_size texture apart and from the border."""
    charts = as_index_array(charts, "charts", (None,))
    if len(charts) == 0:
        raise SkinkitError("charts: no triangles to pack")
    uv = checked_uv(uv, len(charts))
    if surface_area is not None:
        surface_area = as_real_array(surface_area, "surface_area", shape=(len(charts),))
    packed = np.empty_like(uv)
    report = _core.pack(packed.reshape(-1), uv.reshape(-1), charts, surface_area, int(texture_size), float(margin))
    return Packing(packed, report["packing_efficiency"], report)


def texture_efficiency(packing_efficiency: float, stretch: float) -> float:
    """Table 8.6: the packing efficiency divided by the squared L2 stretch (0 for infinite stretch)."""
    return float(packing_efficiency) / float(stretch) ** 2
