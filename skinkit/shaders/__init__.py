"""skinkit's GLSL 4.3 shaders, shipped as package data: skin_compute.glsl (geomorphing skinning over the C
runtime's layout in shader storage buffers) and skin_vertex.glsl (the same from per-vertex attributes: JOINTS_0/1
and _SKINKIT_P_<j>, the layout skinkit's glTF export writes; see the comment at its top)."""
from __future__ import annotations

from importlib import resources

from .._core import Error as SkinkitError

__all__ = ["NAMES", "source"]

NAMES = ("skin_compute", "skin_vertex")


def source(name: str, defines: dict | None = None) -> str:
    """The GLSL text of shader `name`, with `#define KEY VALUE` lines for `defines` inserted after #version (GLSL
    requires #version first)."""
    if not isinstance(name, str) or name not in NAMES:
        raise SkinkitError(f"name: expected one of {NAMES}, got {name!r}")
    if defines is not None and (not isinstance(defines, dict) or
                                not all(isinstance(key, str) and key.isidentifier() for key in defines)):
        raise SkinkitError(f"defines: expected a dict of macro names to values, got {defines!r}"[:200])
    text = resources.files(__package__).joinpath(f"{name}.glsl").read_text()
    version, _, rest = text.partition("\n")
    lines = [f"#define {key} {value}".rstrip() for key, value in (defines or {}).items()]
    return "\n".join([version, *lines, rest])
