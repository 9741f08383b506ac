"""Build LOD Chain in Blender: a skinned mesh's discrete levels of detail (skinkit.lod.build_chain) written as
new objects that Blender's own Armature modifier plays, so its exporters carry them.

prepare_lod_chain reads the mesh (its stored animation-space model, or its linear blend skinning converted in
memory as Convert to Animation Space does), the pose statistics (stored on the armature, else computed from its
action), the active UV map and the materials; LodChainJob.solve() touches no Blender data; write() adds a
collection `<name>_LOD` holding `<name>_LOD0` ... `<name>_LODn` (the Unreal/Unity naming). Each level has the
source's placement, parent and materials, the UV map (same name), the level's animation-space model (storage.py),
the source vertex of each of its vertices (point attribute skinkit_lod_source_vertex)
and vertex groups with the nearest linear-blend weights, and an Armature modifier on the same armature. LOD0 is
the source as triangles; a coarser level's vertices stand where its model puts them in the rest pose (where the
collapses and the refit moved them), not at their source vertices. The source is never changed; an error leaves the scene as it was.

Linear-blend weights of a level (what its vertex groups hold): per vertex, the K bones with the largest
homogeneous weights (each p_j's 4th component; for a model converted from linear blend skinning these are exactly
its weights), then the weights w on them, summing to 1, that minimise the expected squared distance under the pose
statistics between linear blend skinning (Σ_j w_j G_j Ĝ_j^-1 v) and the level's model (Σ_j G_j p_j): a small
least-squares fit in the L2,2 metric; negative weights are clipped at 0 and the rest renormalised. The root
(skinkit's bone 0) has no group: it takes no weight, as Blender's Armature modifier normalises over the groups it
finds. The report's lbs_error is the largest such distance (the L2,2 norm) over the level's vertices, divided by
the diagonal: how far Blender's playback of the level may stray from the level's model.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import bpy
import numpy as np

from ..fit import DEFAULT_MAX_INFLUENCES
from ..lod.chain import (COLLAPSES, DEFAULT_COLLAPSE, DEFAULT_INFLUENCE_COST_SCALE, METRICS, LodChain, build_chain,
                         checked_cost_scale)
from ..lod.influences import limited_linear_blend
from ..model import AnimationSpaceModel, Mesh, SkinkitError
from . import pose_statistics, storage
from .attributes import write_bone_groups, write_point_attribute
from .lod import read_source
from .rig import mesh_of
from .scene import named, naming, triangle_mesh

REPORT_PROPERTY = "skinkit_lod"
#: Point attribute of each level: the source vertex each of its vertices is.
SOURCE_VERTEX_ATTRIBUTE = "skinkit_lod_source_vertex"
#: Point attribute of each level but the coarsest: the next level's vertex each vertex collapses into (the geomorph
#: map of eq. 7.1, read by the runtime's live preview, skinkit.blender.preview).
TO_COARSER_ATTRIBUTE = "skinkit_lod_to_coarser"


@dataclass
class LodChainJob:
    """What a chain needs, read from the scene, so that solve() touches no Blender data."""

    mesh_object_name: str
    mesh: Mesh
    model: AnimationSpaceModel
    statistics: object
    uv: np.ndarray | None
    uv_name: str | None
    materials: np.ndarray
    bone_names: list
    armature_name: str
    bind: np.ndarray
    rest_frames: np.ndarray  # Ĝ_j in mesh space (for the linear-blend weights)
    options: dict  # levels, metric, simplify_influences, collapse, influence_cost_scale, start_influences, refit
    max_influences: int
    statistics_source: str
    counts: tuple[int, int]

    def solve(self, progress=None) -> "SolvedChain":
        """The chain and each level's linear-blend weights; progress(fraction) may return True to cancel (a
        SkinkitError)."""
        levels = self.options["levels"]

        def step(fraction):  # build_chain reports the whole chain's fraction (the queue's, then the refit's)
            return bool(progress(fraction))

        with named(self.mesh_object_name):
            with warnings.catch_warnings():  # the chain's warnings come back in the report
                warnings.simplefilter("ignore")
                chain = build_chain(self.mesh.triangles, self.mesh.positions, self.model, self.statistics,
                                    uv=self.uv, materials=self.materials, levels=levels,
                                    metric=self.options["metric"],
                                    simplify_influences=self.options["simplify_influences"],
                                    collapse=self.options["collapse"],
                                    influence_cost_scale=self.options["influence_cost_scale"],
                                    rank_per_influence=self.options["rank_per_influence"],
                                    start_influences=self.options["start_influences"],
                                    refit=self.options["refit"], progress=step if progress is not None else None)
            positions = [self.level_rest(index, level) for index, level in enumerate(chain.levels)]
            fits = [limited_linear_blend(level.model, self.statistics, self.rest_frames, rest, self.max_influences)
                    for level, rest in zip(chain.levels, positions)]
        return SolvedChain(chain, fits, positions)

    def level_rest(self, index: int, level) -> np.ndarray:
        """A level's mesh positions: LOD0's are the source's; a coarser level's are its model in the rest pose, where
        the collapses and the refit moved its vertices, so that its linear-blend weights (fitted on these positions)
        can follow the model (measured on the horse and the creature chains: the mean playback distance to the model
        2-5x lower on the coarser levels than on the source vertices' positions; BENCHMARKS.md, session 12)."""
        if index == 0:
            return self.mesh.positions[level.vertices]
        return level.model.evaluate(self.rest_frames[None])[0]

    def write(self, mesh_object, solved: "SolvedChain", seconds: float = 0.0) -> dict:
        """Adds the collection and the level objects; returns the report."""
        chain = solved.chain
        with naming(mesh_object):
            if mesh_object.name != self.mesh_object_name or \
                    (len(mesh_object.data.vertices), len(mesh_object.data.polygons)) != self.counts:
                raise SkinkitError("the mesh changed while its LOD chain was being built; nothing was written")
            name = f"{mesh_object.name}_LOD"
            if bpy.data.collections.get(name) is not None:
                raise SkinkitError(f"a collection '{name}' already exists: delete or rename it first")
            armature = bpy.data.objects.get(self.armature_name)
            if armature is None:
                raise SkinkitError(f"its armature '{self.armature_name}' is gone; nothing was written")
        rows = level_rows(chain)
        for row, fit in zip(rows, solved.fits):
            row["lbs_error"] = float(fit[1].max(initial=0.0)) / chain.diagonal
        created = []
        collection = bpy.data.collections.new(name)
        try:
            bpy.context.scene.collection.children.link(collection)
            for index, level in enumerate(chain.levels):
                level_object = self.level_object(mesh_object, armature, level, solved.fits[index],
                                                 solved.positions[index], f"{mesh_object.name}_LOD{index}")
                created.append(level_object)
                collection.objects.link(level_object)
                level_object[REPORT_PROPERTY] = rows[index]
        except Exception:
            for level_object in created:
                mesh = level_object.data
                bpy.data.objects.remove(level_object)
                bpy.data.meshes.remove(mesh)
            bpy.data.collections.remove(collection)
            raise
        collection[REPORT_PROPERTY] = {"source": mesh_object.name, "levels": len(rows), "metric":
                                       self.options["metric"], "max_influences": self.max_influences,
                                       "simplify_influences": bool(self.options["simplify_influences"]),
                                       "collapse": self.options["collapse"],
                                       "influence_cost_scale": float(self.options["influence_cost_scale"]),
                                       "rank_per_influence": bool(self.options["rank_per_influence"]),
                                       "start_influences": int(self.options["start_influences"] or 0),
                                       "refit": bool(self.options["refit"]),
                                       "statistics": self.statistics_source, "diagonal": float(chain.diagonal),
                                       "seconds": float(seconds)}
        return {"object": mesh_object.name, "collection": name, "objects": [o.name for o in created],
                "levels": rows, "warnings": list(chain.warnings), "statistics": self.statistics_source}

    def level_object(self, source, armature, level, fit, positions, name: str):
        mesh = triangle_mesh(name, positions, level.triangles)
        mesh.polygons.foreach_set("material_index", self.materials[level.triangle_origin].astype(np.int32))
        mesh.update(calc_edges=True)
        for material in source.data.materials:
            mesh.materials.append(material)
        if level.uv is not None and self.uv_name is not None:
            layer = mesh.uv_layers.new(name=self.uv_name, do_init=False)
            layer.uv.foreach_set("vector", level.uv.astype(np.float32).reshape(-1))
        storage.write_model(mesh, level.model, self.bone_names, self.armature_name, self.bind)
        write_point_attribute(mesh, SOURCE_VERTEX_ATTRIBUTE, "INT", "value", level.vertices.astype(np.int32))
        if level.to_coarser is not None:
            write_point_attribute(mesh, TO_COARSER_ATTRIBUTE, "INT", "value", level.to_coarser.astype(np.int32))
        level_object = bpy.data.objects.new(name, mesh)
        level_object.parent = source.parent
        level_object.parent_type = source.parent_type
        level_object.matrix_parent_inverse = source.matrix_parent_inverse.copy()
        level_object.matrix_basis = source.matrix_basis.copy()
        write_bone_groups(level_object, fit[0], self.bone_names)
        modifier = level_object.modifiers.new("Armature", "ARMATURE")
        modifier.object = armature
        return level_object


@dataclass
class SolvedChain:
    chain: LodChain
    fits: list  # per level: limited_linear_blend's (weights, distances)
    positions: list  # per level: its mesh positions (LodChainJob.level_rest)


def level_rows(chain: LodChain) -> list[dict]:
    """Per level: vertices, triangles, influences and error (ε divided by the rest bounding-box diagonal)."""
    return [{"level": index, "vertices": int(level.vertex_count), "triangles": int(level.triangle_count),
             "influences": int(level.influence_count), "error": float(level.relative_epsilon)}
            for index, level in enumerate(chain.levels)]


def prepare_lod_chain(mesh_object, *, levels: int = 4, metric: str = "animation", simplify_influences: bool = True,
                      max_influences: int = DEFAULT_MAX_INFLUENCES, collapse: str = DEFAULT_COLLAPSE,
                      influence_cost_scale: float = DEFAULT_INFLUENCE_COST_SCALE, rank_per_influence: bool = True,
                      start_influences: int = 0, refit: bool = True) -> LodChainJob:
    """Reads everything the chain needs (changing nothing). collapse, influence_cost_scale, rank_per_influence,
    start_influences (0: none) and refit as skinkit.lod.build_chain's."""
    with naming(mesh_object):
        if mesh_object.type != "MESH":
            raise SkinkitError(f"is a {mesh_object.type.lower()}, not a mesh")
        if metric not in METRICS:
            raise SkinkitError(f"metric must be one of {tuple(METRICS)}, not {metric!r}")
        if int(levels) < 2:
            raise SkinkitError(f"levels: expected at least 2 (LOD0 and one coarser), got {levels}")
        if int(max_influences) < 1:
            raise SkinkitError(f"max influences: expected at least 1, got {max_influences}")
        if collapse not in COLLAPSES:
            raise SkinkitError(f"collapse must be one of {tuple(COLLAPSES)}, not {collapse!r}")
        influence_cost_scale = checked_cost_scale(influence_cost_scale, "influence cost scale")
        if int(start_influences) < 0:
            raise SkinkitError(f"start influences: expected 0 (none) or more, got {start_influences}")
        if not mesh_object.data.polygons:
            raise SkinkitError("has no faces")
        if bpy.data.collections.get(f"{mesh_object.name}_LOD") is not None:
            raise SkinkitError(f"a collection '{mesh_object.name}_LOD' already exists: delete or rename it first")
        source = read_source(mesh_object)
        model, bind, armature = source.model, source.bind, bpy.data.objects[source.armature_name]
        names, rest_frames = list(source.skeleton.names), source.skeleton.rest_frames
        statistics, origin = pose_statistics.stored_or_from_action(armature, mesh_object.name)
        statistics = pose_statistics.in_mesh_space(statistics, bind)
        mesh = mesh_of(mesh_object)
        data = mesh_object.data
        layer = data.uv_layers.active
        uv = None
        if layer is not None:
            loop_uv = np.empty(len(data.loops) * 2, np.float32)
            layer.uv.foreach_get("vector", loop_uv)
            uv = loop_uv.reshape(-1, 2)[mesh.triangle_loops].astype(np.float64).reshape(-1, 6)
        polygon_materials = np.empty(len(data.polygons), np.int32)
        data.polygons.foreach_get("material_index", polygon_materials)
        return LodChainJob(mesh_object.name, mesh, model, statistics, uv, layer.name if layer else None,
                           polygon_materials[mesh.triangle_polygons], names, armature.name, bind,
                           rest_frames, {"levels": int(levels), "metric": metric, "simplify_influences": bool(simplify_influences),
                            "collapse": collapse, "influence_cost_scale": influence_cost_scale,
                            "rank_per_influence": bool(rank_per_influence),
                            "start_influences": int(start_influences) or None, "refit": bool(refit)},
                           int(max_influences), origin, (len(data.vertices), len(data.polygons)))


def build_lod_chain(mesh_object, progress=None, **options) -> dict:
    """Prepares, solves and writes on this thread (options as prepare_lod_chain's); returns the report with
    `seconds`."""
    started = time.perf_counter()
    job = prepare_lod_chain(mesh_object, **options)
    solved = job.solve(progress)
    report = job.write(mesh_object, solved, time.perf_counter() - started)
    report["seconds"] = time.perf_counter() - started
    return report
