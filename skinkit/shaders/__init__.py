"""skinkit's GLSL 4.3 shaders, shipped as package data: skin_compute.glsl (geomorphing skinning over the C
runtime's layout in shader storage buffers) and skin_vertex.glsl (the same from per-vertex attributes: JOINTS_0/1
and _SKINKIT_P_<j>, the layout skinkit's glTF export writes; see the comment at its top)."""
from __future__ import annotations

from importlib import resources

__all__ = ["NAMES", "source"]

NAMES = ("skin_compute", "skin_vertex")


def source(name: str, defines: dict | None = None) -> str:
    """The GLSL text of shader `name`, with `#define KEY VALUE` lines for `defines` inserted after #version (GLSL
    requires #version first)."""
    if name not in NAMES:
        raise ValueError(f"name: expected one of {NAMES}, got {name!r}")
    text = resources.files(__package__).joinpath(f"{name}.glsl").read_text()
    version, _, rest = text.partition("\n")
    lines = [f"#define {key} {value}".rstrip() for key, value in (defines or {}).items()]
    return "\n".join([version, *lines, rest])
