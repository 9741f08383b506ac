"""Skeleton extraction from a segmented mesh (Vasilakis 2008, chapter 3) over the C core's sk_extract_skeleton:
the Opening, Centroid and Principal Axis methods, with the local and parent refinements."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .. import _core
from .._checks import FLAG, as_index_array, as_optional_index_array, as_real_array, checked, optional, real
from ..model import SkinkitError
from .parts import Parts

__all__ = ["METHODS", "JOINT_KINDS", "Skeleton", "extract_skeleton"]

METHODS = ("opening", "centroid", "principal-axis")
JOINT_KINDS = ("root", "opening", "kernel-centroid", "link", "axis-end")
STAR_SHAPED, DEGENERATE = 1, 2


@dataclass(frozen=True)
class Skeleton:
    """Joints (J): positions (J, 3) in the mesh's coordinates, parents (-1 for the root; a parent precedes its
    child), parts (the part each lies in), kinds (JOINT_KINDS). Parts (P): part_parents (the hierarchy), part_joints
    (each part's root point), kernel_centroids (P, 3), principal_axes (P, 3, 3: rows, principal first), boxes (P, 6:
    centre, half-lengths along the axes), star_shaped and degenerate flags, part_names. seconds: the total;
    stage_seconds: openings, hulls, kernels, method."""
    positions: np.ndarray
    parents: np.ndarray
    parts: np.ndarray
    kinds: np.ndarray
    part_parents: np.ndarray
    part_joints: np.ndarray
    kernel_centroids: np.ndarray
    principal_axes: np.ndarray
    boxes: np.ndarray
    star_shaped: np.ndarray
    degenerate: np.ndarray
    part_names: tuple[str, ...]
    method: str
    seconds: float
    stage_seconds: dict

    @property
    def joint_names(self) -> list[str]:
        """Each joint named by its part and kind: `arm.opening`, `arm.link2` ..."""
        names, counts = [], {}
        for part, kind in zip(self.parts.tolist(), self.kinds.tolist()):
            stem = f"{self.part_names[part]}.{JOINT_KINDS[kind]}"
            counts[stem] = counts.get(stem, 0) + 1
            names.append(stem if counts[stem] == 1 else f"{stem}{counts[stem]}")
        return names

    def joints(self) -> list[dict]:
        """The CLI's `joints`: {name, position, parent (a name, or None)} per joint."""
        names = self.joint_names
        return [{"name": names[j], "position": [float(c) for c in self.positions[j]],
                 "parent": names[p] if p >= 0 else None} for j, p in enumerate(self.parents.tolist())]

    def part_report(self) -> list[dict]:
        """Per part: name, parent, kernel centroid, star-shaped (else the hull centroid stood in), degenerate."""
        return [{"name": self.part_names[p],
                 "parent": self.part_names[q] if q >= 0 else None,
                 "kernel_centroid": [float(c) for c in self.kernel_centroids[p]],
                 "star_shaped": bool(self.star_shaped[p]), "degenerate": bool(self.degenerate[p])}
                for p, q in enumerate(self.part_parents.tolist())]

    ARRAYS = ("positions", "parents", "parts", "kinds", "part_parents", "part_joints", "kernel_centroids",
              "principal_axes", "boxes", "star_shaped", "degenerate")

    def to_dict(self) -> dict:
        """Everything as JSON-ready lists (the CLI's rig file); from_dict reads it back."""
        return {**{name: getattr(self, name).tolist() for name in self.ARRAYS}, "part_names": list(self.part_names),
                "method": self.method, "seconds": self.seconds, "stage_seconds": dict(self.stage_seconds)}

    @classmethod
    def from_dict(cls, data: dict) -> "Skeleton":
        try:
            arrays = {name: np.asarray(data[name]) for name in cls.ARRAYS}
            part_count = len(data["part_names"])
            for name in ("parents", "parts", "kinds", "part_parents", "part_joints"):
                arrays[name] = arrays[name].astype(np.int32)
            for name in ("star_shaped", "degenerate"):
                arrays[name] = arrays[name].astype(bool)
            shapes = {"kernel_centroids": (part_count, 3), "principal_axes": (part_count, 3, 3),
                      "boxes": (part_count, 6), "part_parents": (part_count,), "part_joints": (part_count,)}
            for name, shape in shapes.items():
                if arrays[name].shape != shape:
                    raise ValueError(f"{name} has shape {arrays[name].shape}, expected {shape}")
            return cls(**arrays, part_names=tuple(data["part_names"]), method=str(data["method"]),
                       seconds=float(data.get("seconds", 0.0)), stage_seconds=dict(data.get("stage_seconds", {})))
        except (KeyError, IndexError, TypeError, ValueError) as error:  # IndexError: an array indexed by a name
            raise SkinkitError(f"not a skinkit skeleton ({error})") from None

    def bone_tails(self) -> np.ndarray:
        """One bone per part for an armature: from its root point to the farthest of its own joints (its KC when
        that is the root point itself, or a point along its principal axis when the part has one joint)."""
        heads = self.positions[self.part_joints]
        tails = np.empty_like(heads)
        for p, head in enumerate(heads):
            own = self.positions[self.parts == p]
            distances = np.linalg.norm(own - head, axis=1) if len(own) else np.zeros(0)
            if len(own) and distances.max() > 1e-9 * max(1.0, float(np.abs(head).max())):
                tails[p] = own[int(np.argmax(distances))]
            elif np.linalg.norm(self.kernel_centroids[p] - head) > 1e-9:
                tails[p] = self.kernel_centroids[p]
            else:
                tails[p] = head + self.principal_axes[p, 0] * max(float(self.boxes[p, 3]), 1e-3)
        return tails


@checked(parts=Parts, refine=FLAG, refine_parent=optional(FLAG), max_angle=real(minimum=0, maximum=180),
         closeness=real(minimum=0))
def extract_skeleton(parts: Parts, method: str = "principal-axis", parents=None, refine: bool = False,
                     refine_parent: bool | None = None, max_angle: float = 20.0, closeness: float = 0.25) -> Skeleton:
    """The skeleton of a segmented mesh (skinkit.skeleton.parts builds `parts`). parents: the hierarchy (P ids,
    -1 for the root) or None to grow it over the openings. refine: the local refinement (Algorithm 3) and, unless
    refine_parent says otherwise, the parent refinement (Algorithm 4), turning at most max_angle degrees."""
    if not isinstance(method, str) or method not in METHODS:  # an array's `in` fails or compares elementwise
        raise SkinkitError(f"method {method!r}: expected one of {', '.join(METHODS)}")
    positions = as_real_array(parts.positions, "positions", shape=(None, 3))
    triangles = as_index_array(parts.triangles, "triangles", shape=(None, 3))
    triangle_parts = as_index_array(parts.triangle_parts, "triangle_parts", shape=(len(triangles),))
    count = parts.part_count
    given = as_optional_index_array(parents, "parents", shape=(count,))
    started = time.perf_counter()
    arrays = dict(  # in the order _core.extract_skeleton takes them
        joint_positions=np.zeros(15 * count), joint_parents=np.zeros(5 * count, np.int32),
        joint_parts=np.zeros(5 * count, np.int32), joint_kinds=np.zeros(5 * count, np.int32),
        part_parents=np.zeros(count, np.int32), part_joints=np.zeros(count, np.int32),
        kernel_centroids=np.zeros(3 * count), principal_axes=np.zeros(9 * count), boxes=np.zeros(6 * count),
        part_flags=np.zeros(count, np.int32))
    report = _core.extract_skeleton(*arrays.values(), triangles.reshape(-1), positions.reshape(-1), triangle_parts,
                                    count, given, METHODS.index(method), bool(refine),
                                    bool(refine if refine_parent is None else refine_parent), float(max_angle),
                                    float(closeness))
    seconds = time.perf_counter() - started
    joints = int(report["joint_count"])
    flags = arrays["part_flags"]
    return Skeleton(
        positions=arrays["joint_positions"].reshape(-1, 3)[:joints].copy(),
        parents=arrays["joint_parents"][:joints].copy(), parts=arrays["joint_parts"][:joints].copy(),
        kinds=arrays["joint_kinds"][:joints].copy(), part_parents=arrays["part_parents"],
        part_joints=arrays["part_joints"], kernel_centroids=arrays["kernel_centroids"].reshape(-1, 3),
        principal_axes=arrays["principal_axes"].reshape(-1, 3, 3), boxes=arrays["boxes"].reshape(-1, 6),
        star_shaped=(flags & STAR_SHAPED) != 0, degenerate=(flags & DEGENERATE) != 0, part_names=tuple(parts.names),
        method=method, seconds=seconds,
        stage_seconds={"openings": report["opening_seconds"], "hulls": report["hull_seconds"],
                       "kernels": report["kernel_seconds"], "method": report["method_seconds"]})
