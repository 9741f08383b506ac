"""The hierarchy-and-limits file (Vasilakis 2008, section 3.1, Fig. 3.1): BVH-like nesting without OFFSET, CHANNELS
or MOTION. Each segment is `name MIN_X MAX_X MIN_Y MAX_Y MIN_Z MAX_Z` (degrees), then `{`, its children or
`End Site { }`, then `}`. Braces are read as tokens: indentation does not matter (the thesis' alignment rule is
only a layout)."""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

import numpy as np

from ..meshio import read_text_lines
from .._checks import INPUT_FILE, OUTPUT_FILE, checked, count
from ..model import SkinkitError
from .extract import Skeleton as BoneSkeleton

__all__ = ["Hierarchy", "read_hierarchy", "write_hierarchy", "free_limits", "write_bvh"]

NAME = re.compile(r"^[A-Za-z0-9_.:\-]+$")


#: The most joints a hierarchy has (far above any character's).
MAX_JOINTS = 2**16


def names_list(value, name: str) -> list:
    """A list of joint names (strings)."""
    if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)) or \
            not all(isinstance(item, str) for item in value):
        raise SkinkitError(f"{name}: expected a list of joint names, got {type(value).__name__}")
    return list(value)


@dataclass(frozen=True)
class Hierarchy:
    """names (P), parents (P, -1 for the root, parents before children), limits (P, 3, 2): degrees, [axis][min, max]
    for X, Y, Z."""
    names: tuple[str, ...]
    parents: np.ndarray
    limits: np.ndarray

    @checked(names=names_list)
    def reordered(self, names) -> "Hierarchy":
        """The same hierarchy indexed by `names` (a mesh's part names); every name must appear once."""
        names = list(names)
        missing = sorted(set(names) ^ set(self.names))
        if missing or len(names) != len(self.names):
            raise SkinkitError(f"the hierarchy's segments and the mesh's parts differ: {', '.join(missing[:5])}")
        where = {name: k for k, name in enumerate(self.names)}
        old = [where[name] for name in names]
        new_of_old = {o: n for n, o in enumerate(old)}
        parents = np.array([-1 if self.parents[o] < 0 else new_of_old[int(self.parents[o])] for o in old], np.int32)
        return Hierarchy(tuple(names), parents, self.limits[old])


@checked(count=count(0, MAX_JOINTS))
def free_limits(count: int) -> np.ndarray:
    """Limits that allow any rotation: [-180, 180] on every axis."""
    limits = np.empty((count, 3, 2))
    limits[..., 0], limits[..., 1] = -180.0, 180.0
    return limits


def _tokens(path: str):
    for number, line in enumerate(read_text_lines(path), 1):
        for token in line.replace("{", " { ").replace("}", " } ").split():
            yield number, token


@checked(path=INPUT_FILE)
def read_hierarchy(path: str) -> Hierarchy:
    """Parses a hierarchy file; a malformed one is a SkinkitError naming the line."""
    tokens = list(_tokens(path))
    names, parents, limits, stack, k = [], [], [], [], 0

    def fail(message):
        line = tokens[min(k, len(tokens) - 1)][0] if tokens else 1
        raise SkinkitError(f"{path}:{line}: {message}")

    while k < len(tokens):
        number, token = tokens[k]
        if token == "}":
            if not stack:
                fail("a '}' closes nothing")
            stack.pop()
            k += 1
        elif token.lower() == "end" and k + 1 < len(tokens) and tokens[k + 1][1].lower() == "site":
            if not stack or k + 3 >= len(tokens) or tokens[k + 2][1] != "{" or tokens[k + 3][1] != "}":
                fail("`End Site` must be inside a segment and followed by `{ }`")
            k += 4
        else:
            if not NAME.match(token):
                fail(f"expected a segment name, got {token!r}")
            if not stack and names:
                fail(f"a second root segment {token!r}: the file holds one tree")
            try:
                values = [float(t) for _, t in tokens[k + 1:k + 7]]
            except ValueError:
                fail(f"segment {token!r} needs six angle limits (MIN_X MAX_X MIN_Y MAX_Y MIN_Z MAX_Z)")
            if len(values) != 6 or not all(math.isfinite(v) for v in values):
                fail(f"segment {token!r} needs six finite angle limits")
            pairs = np.array(values).reshape(3, 2)
            if (pairs[:, 0] > pairs[:, 1]).any():
                fail(f"segment {token!r}: a minimum angle is above its maximum")
            if k + 7 >= len(tokens) or tokens[k + 7][1] != "{":
                fail(f"segment {token!r} must be followed by '{{'")
            if token in names:
                fail(f"segment {token!r} appears twice")
            names.append(token)
            parents.append(stack[-1] if stack else -1)
            limits.append(pairs)
            stack.append(len(names) - 1)
            k += 8
    if stack:
        raise SkinkitError(f"{path}: {len(stack)} segment(s) not closed by '}}'")
    if not names:
        raise SkinkitError(f"{path}: no segment")
    return Hierarchy(tuple(names), np.array(parents, dtype=np.int32), np.array(limits, dtype=np.float64))


@checked(path=OUTPUT_FILE, hierarchy=Hierarchy)
def write_hierarchy(path: str, hierarchy: Hierarchy) -> str:
    """Writes the file (atomically: a temporary beside it, then renamed); returns the path."""
    children = {k: [] for k in range(len(hierarchy.names))}
    roots = []
    for k, p in enumerate(hierarchy.parents.tolist()):
        (children[p] if p >= 0 else roots).append(k)
    if len(roots) != 1:
        raise SkinkitError(f"the hierarchy has {len(roots)} roots; the file holds one tree")
    lines = []

    def segment(k, depth):
        pad = "  " * depth
        limits = " ".join(f"{v:g}" for v in hierarchy.limits[k].reshape(-1))
        lines.append(f"{pad}{hierarchy.names[k]} {limits}")
        lines.append(f"{pad}{{")
        for child in children[k]:
            segment(child, depth + 1)
        if not children[k]:
            lines.extend([f"{pad}  End Site", f"{pad}  {{", f"{pad}  }}"])
        lines.append(f"{pad}}}")

    segment(roots[0], 0)
    temporary = f"{path}.partial"
    with open(temporary, "w", encoding="utf-8") as stream:
        stream.write("\n".join(lines) + "\n")
    os.replace(temporary, path)
    return path


@checked(path=OUTPUT_FILE, skeleton=BoneSkeleton)
def write_bvh(path: str, skeleton) -> str:
    """The skeleton's joints as a BVH motion-capture file (HIERARCHY with offsets from each parent, one rest frame
    of zero channels), which Blender and most tools import; joints without children end in an End Site."""
    names = skeleton.joint_names
    children = {j: [] for j in range(len(names))}
    for j, p in enumerate(skeleton.parents.tolist()):
        if p >= 0:
            children[p].append(j)
    lines, channels = ["HIERARCHY"], []

    def offset(j):
        p = int(skeleton.parents[j])
        delta = skeleton.positions[j] - (skeleton.positions[p] if p >= 0 else 0.0)
        return " ".join(f"{v:.9g}" for v in delta)

    def joint(j, depth):
        pad = "\t" * depth
        root = skeleton.parents[j] < 0
        lines.append(f"{pad}{'ROOT' if root else 'JOINT'} {names[j]}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}\tOFFSET {offset(j)}")
        if root:
            lines.append(f"{pad}\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation")
            channels.append(6)
        else:
            lines.append(f"{pad}\tCHANNELS 3 Zrotation Xrotation Yrotation")
            channels.append(3)
        for child in children[j]:
            joint(child, depth + 1)
        if not children[j]:
            lines.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET 0 0 0", f"{pad}\t}}"])
        lines.append(f"{pad}}}")

    for root in np.flatnonzero(skeleton.parents < 0):
        joint(int(root), 0)
    lines += ["MOTION", "Frames: 1", "Frame Time: 0.0416667", " ".join(["0"] * sum(channels))]
    temporary = f"{path}.partial"
    with open(temporary, "w", encoding="utf-8") as stream:
        stream.write("\n".join(lines) + "\n")
    os.replace(temporary, path)
    return path
