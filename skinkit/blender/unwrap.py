"""Animated Unwrap in Blender: reading a mesh, its seams and its metric, writing the atlas as a new UV map.

The metric is the rest pose's, animation space's (the mesh's skinkit model, or its linear blend skinning
converted in memory, with the pose statistics stored on its armature), or the average over the frames of
the armature's action as Blender deforms the mesh. Everything is computed before the scene is written, so
an error leaves it as it was. The UV map gets its own name: other UV maps, and which one is active, are
kept unless the user asks for the new one to become active.
"""
from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from ..model import Mesh, SkinkitError, convert_lbs
from ..pack import DEFAULT_MARGIN, DEFAULT_TEXTURE_SIZE
from ..unwrap import (UnwrapResult, animation_embedding, polygons_across_charts, sampled_animation_embedding,
                      sequence_embedding, unwrap)
from . import pose_statistics, storage
from .frames import action_frames, armature_modifier_only, depsgraphs_at, evaluated_positions, poses_at
from .rig import bind_matrix, bone_names, deform_weights, mesh_of, rig_of, skeleton_of
from .scene import armature_of, named, naming

UV_MAP_NAME = "skinkit_animated"
REPORT_PROPERTY = "skinkit_unwrap_report"
#: The metric to flatten in: the rest pose's, animation space's, or the average over the action's frames.
METRICS = ("rest", "animation", "frames")
#: Blender keeps at most this many UV maps on a mesh.
MAX_UV_MAPS = 8


def seam_pairs(mesh) -> np.ndarray:
    """(S, 2) int32: the vertex pairs of the edges marked as seams."""
    vertices = np.empty(len(mesh.edges) * 2, np.int32)
    marked = np.empty(len(mesh.edges), bool)
    mesh.edges.foreach_get("vertices", vertices)
    mesh.edges.foreach_get("use_seam", marked)
    return vertices.reshape(-1, 2)[marked]


def deforming_action_frames(mesh_object) -> range | None:
    """The frames of the action of the armature deforming the mesh, or None when it has none."""
    armature = armature_of(mesh_object)
    action = armature.animation_data.action if armature is not None and armature.animation_data else None
    return None if action is None else action_frames(action)


def deformed_positions(mesh_object, frames) -> np.ndarray:
    """(F, V, 3): the mesh as Blender's Armature modifier alone deforms it at each frame, in its local space
    (the frame and the modifiers' visibility are restored)."""
    with armature_modifier_only(mesh_object):
        return np.stack([evaluated_positions(mesh_object, depsgraph) for depsgraph in depsgraphs_at(frames)])


def animation_metric(mesh_object, statistics=None, frames=None) -> np.ndarray:
    """The animation-space embedding of the mesh's vertices: its stored model (or its linear blend skinning
    converted in memory) under `statistics` in armature space (default: those stored on its armature), or, given
    `frames`, exactly the metric of the armature's poses at those frames (sampled_animation_embedding: the joint
    statistics take the joints as independent, an action's are not)."""
    rig = rig_of(mesh_object)
    if storage.has_model(mesh_object.data):
        stored = storage.read_model(mesh_object.data, mesh_object.name)
        model, bind = stored.model, stored.bind
    else:
        bind = bind_matrix(rig, bpy.context.evaluated_depsgraph_get())
        model = convert_lbs(skeleton_of(rig, bind), deform_weights(rig), mesh_of(mesh_object).positions)
    if frames is not None:
        armature = rig.armature_object
        return sampled_animation_embedding(model, poses_at(armature, list(frames), bone_names(armature), bind))
    if statistics is None:
        statistics = pose_statistics.load(rig.armature_object)
    return animation_embedding(model, pose_statistics.in_mesh_space(statistics, bind))


def statistics_frames(mesh_object, frames):
    """The action frames to take the animation metric from exactly, when its armature's stored statistics were
    computed from an action and it has one (else None: the stored statistics serve)."""
    armature = armature_of(mesh_object)
    summary = pose_statistics.summary(armature) if armature is not None else None
    return frames if frames is not None and summary is not None and summary["source"] == "action" else None


def metric_embedding(mesh_object, metric: str, deformed: np.ndarray | None) -> np.ndarray | None:
    """The embedding of `metric` (one of METRICS); None for the rest pose (unwrap's default). deformed: the
    mesh over its action's frames (None without an action)."""
    if metric == "rest":
        return None
    if metric == "animation":
        return animation_metric(mesh_object, frames=statistics_frames(mesh_object, deforming_action_frames(mesh_object)))
    if metric == "frames":
        if deformed is None:
            raise SkinkitError("the metric 'frames of the action' needs an armature with an action")
        return sequence_embedding(deformed)
    raise SkinkitError(f"metric must be one of {METRICS}, not {metric!r}")


@dataclass
class UnwrapJob:
    """What an unwrap needs, read from the scene, so that solve() touches no Blender data and may run on
    another thread (a modal operator's), while prepare_unwrap and write stay on Blender's."""

    mesh_object_name: str
    mesh: Mesh
    embedding: np.ndarray | None
    seams: np.ndarray
    evaluation_frames: np.ndarray | None
    options: dict
    output: dict  # name, make_active, mark_seams
    counts: tuple[int, int, int]  # vertices, polygons, loops when read: write() refuses a mesh changed since

    def solve(self, progress=None) -> UnwrapResult:
        """progress: accepted like the other jobs' solve, but the unwrap reports none (it is a fraction of a second
        to a few seconds)."""
        with named(self.mesh_object_name):
            result = unwrap(self.mesh.positions, self.mesh.triangles, embedding=self.embedding, seams=self.seams,
                            evaluation_frames=self.evaluation_frames, polygons=self.mesh.triangle_polygons,
                            **self.options)
            if self.embedding is None or self.evaluation_frames is None:
                return result
            # A metric built from the animation should never lose to the rest pose over that animation; where it
            # does (statistics of another source, translations the metric does not model), the rest-pose atlas is
            # kept instead, and the report says so.
            rest = unwrap(self.mesh.positions, self.mesh.triangles, seams=self.seams,
                          evaluation_frames=self.evaluation_frames, polygons=self.mesh.triangle_polygons,
                          **self.options)
            ours, theirs = result.report["stretch_frames"], rest.report["stretch_frames"]
            if rest.report["status"] == "ok" and (result.report["status"] != "ok" or theirs < ours):
                rest.report.update(metric_used="rest", fallback=(
                    f"the rest-pose atlas stretches less over the action ({theirs:.4f} against {ours:.4f} in the "
                    "metric's): kept it instead"))
                return rest
            result.report.update(metric_used="metric", fallback="")
            return result

    def write(self, mesh_object, result: UnwrapResult) -> dict:
        """Writes the atlas to the object it was read from; returns the report."""
        with naming(mesh_object):
            if mesh_object.name != self.mesh_object_name or mesh_counts(mesh_object.data) != self.counts:
                raise SkinkitError("the mesh changed while it was being unwrapped; nothing was written")
            if result.report["status"] != "ok":
                raise SkinkitError(f"the atlas is broken ({'; '.join(result.report['problems'])}); nothing was written")
        split = write_uv_map(mesh_object, self.mesh, result, **self.output)
        return {**result.report, "object": mesh_object.name, "uv_map": self.output["name"],
                "split_polygons": split,
                "frames": 0 if self.evaluation_frames is None else len(self.evaluation_frames)}


def mesh_counts(mesh) -> tuple[int, int, int]:
    return len(mesh.vertices), len(mesh.polygons), len(mesh.loops)


def prepare_unwrap(mesh_object, *, metric="animation", mode="auto", chart_count=None, straighten=False,
                   segment_in="rest", texture_size=DEFAULT_TEXTURE_SIZE, margin=DEFAULT_MARGIN, name=UV_MAP_NAME,
                   make_active=False, mark_seams=False) -> UnwrapJob:
    """Reads the mesh, its seams, the metric and the action's frames for evaluation (changing nothing)."""
    with naming(mesh_object):
        if mesh_object.type != "MESH":
            raise SkinkitError(f"is a {mesh_object.type.lower()}, not a mesh")
        if not mesh_object.data.polygons:
            raise SkinkitError("has no faces to unwrap")
    check_room_for_uv_map(mesh_object, name)
    with naming(mesh_object):
        mesh = mesh_of(mesh_object)
        frames = deforming_action_frames(mesh_object)
        deformed = deformed_positions(mesh_object, frames) if frames is not None else None
        return UnwrapJob(mesh_object.name, mesh, metric_embedding(mesh_object, metric, deformed),
                         seam_pairs(mesh_object.data), deformed,
                         {"mode": mode, "chart_count": chart_count, "straighten": straighten, "segment_in": segment_in,
                          "texture_size": texture_size, "margin": margin},
                         {"name": name, "make_active": make_active, "mark_seams": mark_seams},
                         mesh_counts(mesh_object.data))


def check_room_for_uv_map(mesh_object, name: str) -> None:
    mesh = mesh_object.data
    if name not in mesh.uv_layers and len(mesh.uv_layers) >= MAX_UV_MAPS:
        raise SkinkitError(f"'{mesh_object.name}' already has {MAX_UV_MAPS} UV maps, Blender's limit: remove one "
                           f"or name '{name}' to be replaced")


def write_uv_map(mesh_object, mesh: Mesh, result: UnwrapResult, name=UV_MAP_NAME, make_active=False,
                 mark_seams=False) -> int:
    """Writes the atlas as the UV map `name` (replacing a map of that name); returns how many polygons
    span two charts (their shared corners take one triangle's uv; triangulate them to avoid it)."""
    check_room_for_uv_map(mesh_object, name)
    data = mesh_object.data
    loop_uv = np.zeros((len(data.loops), 2), np.float32)
    loop_uv[mesh.triangle_loops.reshape(-1)] = result.uv.reshape(-1, 2)
    split = polygons_across_charts(mesh.triangle_polygons, result.charts)
    layer = data.uv_layers.get(name) or data.uv_layers.new(name=name, do_init=False)
    layer.uv.foreach_set("vector", loop_uv.reshape(-1))
    if make_active:
        data.uv_layers.active = layer
    if mark_seams:
        mark_edges_as_seams(data, result.seams)
    data[REPORT_PROPERTY] = {key: value for key, value in result.report.items()
                             if isinstance(value, (int, float, str))}
    data[REPORT_PROPERTY]["uv_map"] = name
    data.update()
    return split


def mark_edges_as_seams(mesh, pairs: np.ndarray) -> None:
    """Marks the edges with these vertex pairs as seams, keeping the seams already marked."""
    vertices = np.empty(len(mesh.edges) * 2, np.int32)
    mesh.edges.foreach_get("vertices", vertices)
    marked = np.empty(len(mesh.edges), bool)
    mesh.edges.foreach_get("use_seam", marked)
    keys = np.sort(vertices.reshape(-1, 2), axis=1).astype(np.int64) @ np.array([len(mesh.vertices), 1])
    wanted = np.sort(pairs, axis=1).astype(np.int64) @ np.array([len(mesh.vertices), 1])
    mesh.edges.foreach_set("use_seam", marked | np.isin(keys, wanted))


def unwrap_object(mesh_object, **options) -> dict:
    """Prepares, solves and writes on this thread (options as prepare_unwrap's); returns the report."""
    job = prepare_unwrap(mesh_object, **options)
    return job.write(mesh_object, job.solve())


# ---- showing the layout --------------------------------------------------------------------------------


def layout_pixels(uv: np.ndarray, charts: np.ndarray, size: int) -> np.ndarray:
    """An RGBA float32 (size, size, 4) picture of the atlas: each chart's triangles filled in its own colour,
    their edges drawn dark, on a transparent background (row 0 at v = 0, as Blender's images are stored)."""
    picture = np.zeros((size, size, 4), np.float32)
    colours = chart_colours(int(charts.max()) + 1)
    pixels = uv * size - 0.5
    for triangle, chart in zip(pixels, charts):
        fill_triangle(picture, triangle, colours[chart])
    draw_edges(picture, pixels)
    return picture


def chart_colours(count: int) -> np.ndarray:
    """Distinct, light colours: hues spaced by the golden ratio."""
    hues = (np.arange(count) * 0.618033988749895) % 1.0
    channels = np.stack([hues, hues + 1 / 3, hues + 2 / 3], axis=1)
    rgb = 0.55 + 0.35 * np.cos(2 * np.pi * channels)
    return np.column_stack([rgb, np.ones(count)]).astype(np.float32)


def fill_triangle(picture: np.ndarray, corners: np.ndarray, colour: np.ndarray) -> None:
    size = picture.shape[0]
    low = np.clip(np.floor(corners.min(axis=0)).astype(int), 0, size - 1)
    high = np.clip(np.ceil(corners.max(axis=0)).astype(int), 0, size - 1)
    xs, ys = np.meshgrid(np.arange(low[0], high[0] + 1), np.arange(low[1], high[1] + 1))
    a, b, c = corners
    area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    if area == 0:
        return
    sides = [((q[0] - p[0]) * (ys - p[1]) - (q[1] - p[1]) * (xs - p[0])) * np.sign(area)
             for p, q in ((a, b), (b, c), (c, a))]
    inside = (sides[0] >= 0) & (sides[1] >= 0) & (sides[2] >= 0)
    picture[ys[inside], xs[inside]] = colour


def draw_edges(picture: np.ndarray, pixels: np.ndarray) -> None:
    """Every triangle edge as dark dots about half a pixel apart."""
    size = picture.shape[0]
    starts = pixels.reshape(-1, 2)
    ends = np.roll(pixels, -1, axis=1).reshape(-1, 2)
    steps = np.maximum(np.ceil(2 * np.linalg.norm(ends - starts, axis=1)).astype(int), 1)
    edge = np.repeat(np.arange(len(starts)), steps + 1)
    offsets = np.arange(len(edge)) - np.repeat(np.cumsum(steps + 1) - (steps + 1), steps + 1)
    t = (offsets / np.repeat(steps, steps + 1))[:, None]
    points = np.clip(np.rint(starts[edge] * (1 - t) + ends[edge] * t).astype(int), 0, size - 1)
    picture[points[:, 1], points[:, 0]] = (0.1, 0.1, 0.1, 1.0)


def show_layout(mesh_object, size: int = 1024, name=UV_MAP_NAME):
    """The layout of the UV map `name` as an image in bpy.data.images ("<object> UV layout", replaced if
    present), shown in every open image editor; returns the image."""
    with naming(mesh_object):
        data = mesh_object.data
        if name not in data.uv_layers:
            raise SkinkitError(f"has no UV map '{name}': run Animated Unwrap first")
        mesh = mesh_of(mesh_object)
        loop_uv = np.empty(len(data.loops) * 2, np.float32)
        data.uv_layers[name].uv.foreach_get("vector", loop_uv)
        uv = loop_uv.reshape(-1, 2)[mesh.triangle_loops]
        islands = islands_of(mesh, uv)
        picture = layout_pixels(uv.astype(np.float64), islands, size)
    title = f"{mesh_object.name} UV layout"
    image = bpy.data.images.get(title)
    if image is not None and tuple(image.size) != (size, size):
        bpy.data.images.remove(image)
        image = None
    image = image or bpy.data.images.new(title, size, size, alpha=True)
    image.pixels.foreach_set(picture.reshape(-1))
    image.update()
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "IMAGE_EDITOR":
                area.spaces.active.image = image
    return image


def islands_of(mesh: Mesh, uv: np.ndarray) -> np.ndarray:
    """(T,): the uv islands, triangles joined across edges whose two ends have the same uv on both sides,
    for colouring (the charts themselves are not stored in the scene)."""
    corner_keys = np.column_stack([mesh.triangles.reshape(-1), np.round(uv.reshape(-1, 2), 6)])
    corner_id = np.unique(corner_keys, axis=0, return_inverse=True)[1].reshape(-1, 3)
    edges = np.sort(np.stack([corner_id, np.roll(corner_id, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    owner = np.repeat(np.arange(len(corner_id)), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    shared = np.flatnonzero(np.all(edges[order[1:]] == edges[order[:-1]], axis=1))
    parent = list(range(len(corner_id)))

    def root(t):
        while parent[t] != t:
            parent[t] = parent[parent[t]]
            t = parent[t]
        return t

    for first, second in zip(owner[order[shared]].tolist(), owner[order[shared + 1]].tolist()):
        parent[root(first)] = root(second)
    return np.unique([root(t) for t in range(len(corner_id))], return_inverse=True)[1]
