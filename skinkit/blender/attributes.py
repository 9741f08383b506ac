"""Writing results onto a mesh: point attributes, heat maps, bone vertex groups and reports.

Fitting, skinning from a sequence and the pose statistics' bounds all write through these, so the names
of what they leave on a mesh are defined here once.
"""
from __future__ import annotations

import numpy as np

REPORT_PROPERTY = "skinkit_fit_report"
ERROR_ATTRIBUTE = "skinkit_fit_error"
HEAT_ATTRIBUTE = "skinkit_fit_error_color"


def write_point_attribute(mesh, name, data_type, field, values) -> None:
    """Replaces the point attribute `name` with `values` (written in bulk through `field`)."""
    if name in mesh.attributes:
        mesh.attributes.remove(mesh.attributes[name])
    mesh.attributes.new(name, data_type, "POINT").data.foreach_set(field, values)


def heat_colours(error: np.ndarray, largest: float | None = None) -> np.ndarray:
    """Blue (no error) through green and yellow to red (`largest`, default the largest error), RGBA (V, 4)."""
    largest = float(error.max()) if largest is None else largest
    t = np.clip(error / largest, 0.0, 1.0) if largest > 0 else np.zeros_like(error)
    stops = np.array([[0.05, 0.15, 0.9], [0.1, 0.8, 0.3], [0.95, 0.85, 0.1], [0.9, 0.1, 0.05]])
    position = t * (len(stops) - 1)
    low = np.minimum(position.astype(int), len(stops) - 2)
    blend = (position - low)[:, None]
    rgb = stops[low] * (1 - blend) + stops[low + 1] * blend
    return np.column_stack([rgb, np.ones(len(t))]).astype(np.float32)


def write_heat_map(mesh, value_attribute: str, colour_attribute: str, values: np.ndarray, largest=None) -> None:
    """The per-vertex `values` as a float attribute and as heat-map colours."""
    write_point_attribute(mesh, value_attribute, "FLOAT", "value", np.asarray(values, np.float32))
    write_point_attribute(mesh, colour_attribute, "FLOAT_COLOR", "color", heat_colours(values, largest).reshape(-1))


def write_bone_groups(mesh_object, weights, bone_names) -> None:
    """The fitted weights replace the bone vertex groups (bone 0, the root, has no group).

    Vertex groups have no bulk setter; VertexGroup.add takes many vertices with one weight, so each group
    is written with one call per distinct weight value.
    """
    dense = weights.to_dense(len(bone_names)).astype(np.float32)
    for bone, name in enumerate(bone_names):
        if bone == 0:
            continue
        old = mesh_object.vertex_groups.get(name)
        if old is not None:
            mesh_object.vertex_groups.remove(old)  # the Armature modifier finds groups by name, not index
        group = mesh_object.vertex_groups.new(name=name)
        vertices = np.flatnonzero(dense[:, bone] > 0)
        values = dense[vertices, bone]
        order = np.argsort(values, kind="stable")
        distinct, starts = np.unique(values[order], return_index=True)
        for value, members in zip(distinct, np.split(vertices[order], starts[1:])):
            group.add(members.tolist(), float(value), "REPLACE")


def flatten_report(report: dict, prefix: str = "") -> dict:
    """ID properties take flat values: nested dicts become 'outer.inner' keys (at any depth, e.g.
    'animation_space.train.rms'); arrays are left out."""
    flat = {}
    for key, value in report.items():
        name = f"{prefix}{key}"
        if isinstance(value, np.ndarray):
            continue
        if isinstance(value, dict):
            flat.update(flatten_report(value, f"{name}."))
        else:
            flat[name] = float(value) if prefix and isinstance(value, (int, float, np.number)) else value
    return flat
