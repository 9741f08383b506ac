"""Packing flattened charts into a texture atlas (Merry 2007, section 5.4), and the atlas' texture efficiency.

uv arrays are per triangle corner, (T, 3, 2), as skinkit.flatten makes them. The work is done by the C core
(csrc/sk_pack.c); this module checks shapes and types and names what is wrong.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _core
from ._checks import as_index_array, as_real_array, checked, count, real
from .flatten import checked_uv
from .model import SkinkitError

__all__ = ["Packing", "pack", "texture_efficiency", "DEFAULT_TEXTURE_SIZE", "DEFAULT_MARGIN"]

#: The texture the atlas is packed for, in texels on a side, and the gap kept between charts, in texels.
DEFAULT_TEXTURE_SIZE = 1024
DEFAULT_MARGIN = 4
#: The largest texture the packer takes (SK_PACK_MAX_TEXTURE_SIZE in csrc/skinkit.h), and the widest margin.
MAX_TEXTURE_SIZE = 65536
MAX_MARGIN = 4096


@dataclass(frozen=True, eq=False)
class Packing:
    uv: np.ndarray             # (T, 3, 2) in [0, 1]^2
    packing_efficiency: float  # the uv triangles' total area: the fraction of the texture covered
    report: dict


@checked(texture_size=count(1, MAX_TEXTURE_SIZE), margin=real(minimum=0, maximum=MAX_MARGIN))
def pack(uv, charts, *, texture_size: int = DEFAULT_TEXTURE_SIZE,
         margin: float = DEFAULT_MARGIN, surface_area=None) -> Packing:
    """Packs the charts into [0, 1]^2 (section 5.4): each chart scaled so its uv area is its surface area
    (surface_area (T,), e.g. skinkit.flatten.metric_area(edge_lengths_sq); None keeps the uv scales), turned to its
    smallest bounding rectangle, and placed by its rasterised outline, largest first, at the quarter turn and place
    whose top is lowest (small charts fill the holes larger ones leave), at the largest common scale that fits
    (sk_pack in csrc/skinkit.h), at least `margin` texels of a texture_size texture apart and from the border."""
    charts = as_index_array(charts, "charts", (None,))
    if len(charts) == 0:
        raise SkinkitError("charts: no triangles to pack")
    uv = checked_uv(uv, len(charts))
    if surface_area is not None:
        surface_area = as_real_array(surface_area, "surface_area", shape=(len(charts),))
    packed = np.empty_like(uv)
    report = _core.pack(packed.reshape(-1), uv.reshape(-1), charts, surface_area, int(texture_size), float(margin))
    return Packing(packed, report["packing_efficiency"], report)


def positive_stretch(value, name: str) -> float:
    """A stretch above 0; infinity (a collapsed chart) is allowed and gives a texture efficiency of 0."""
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)) and \
            float(value) == np.inf:
        return np.inf
    return real(above=0)(value, name)


@checked(packing_efficiency=real(minimum=0), stretch=positive_stretch)
def texture_efficiency(packing_efficiency: float, stretch: float) -> float:
    """Table 8.6: the packing efficiency divided by the squared L2 stretch (0 for infinite stretch)."""
    return packing_efficiency / stretch / stretch  # two divisions: a huge stretch's square would overflow
