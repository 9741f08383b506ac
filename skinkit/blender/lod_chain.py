"""Build LOD Chain in Blender: a skinned mesh's discrete levels of detail (skinkit.lod.build_chain) written as
new objects that Blender's own Armature modifier plays, so its exporters carry them.

prepare_lod_chain reads the mesh (its stored animation-space model, or its linear blend skinning converted in
memory as Convert to Animation Space does), the pose statistics (stored on the armature, else computed from its
action), the active UV map and the materials; LodChainJob.solve() touches no Blender data; write() adds a
collection `<name>_LOD` holding `<name>_LOD0` ... `<name>_LODn` (the Unreal/Unity naming). Each level has the
source's placement, parent and materials, the UV map (same name), the level's animation-space model (storage.py),
the source vertex of each of its vertices (point attribute skinkit_lod_source_vertex)
and vertex groups with the nearest linear-blend weights, and an Armature modifier on the same armature. LOD0 is
the source as triangles. The source is never changed; an error leaves the scene as it was.

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

from ..lod.chain import LodChain, build_chain
from ..model import AnimationSpaceModel, Mesh, SkinkitError, convert_lbs
from . import pose_statistics, storage
from .attributes import write_point_attribute
from .frames import action_frames
from .rig import bind_matrix, bone_names, deform_weights, mesh_of, rig_of, skeleton_of
from .scene import named, naming

REPORT_PROPERTY = "skinkit_lod"
#: Point attribute of each level: the source vertex each of its vertices is.
SOURCE_VERTEX_ATTRIBUTE = "skinkit_lod_source_vertex"
METRICS = ("animation", "rest")
DEFAULT_MAX_INFLUENCES = 4


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
    options: dict  # levels, metric, simplify_influences
    max_influences: int
    statistics_source: str
    counts: tuple[int, int]

    def solve(self, progress=None) -> "SolvedChain":
        """The chain and each level's linear-blend weights; progress(fraction) may return True to cancel (a
        SkinkitError)."""
        levels = self.options["levels"]
        done = [0]

        def step(fraction):  # the C step reports each level's own fraction; the chain's is their average
            if fraction >= 1.0:
                done[0] += 1
            return bool(progress(min(1.0, (done[0] + (fraction if fraction < 1.0 else 0.0)) / max(levels - 1, 1))))

        with named(self.mesh_object_name):
            with warnings.catch_warnings():  # the chain's warnings come back in the report
                warnings.simplefilter("ignore")
                chain = build_chain(self.mesh.triangles, self.mesh.positions, self.model, self.statistics,
                                    uv=self.uv, materials=self.materials, levels=levels,
                                    metric=self.options["metric"],
                                    simplify_influences=self.options["simplify_influences"],
                                    progress=step if progress is not None else None)
            fits = [linear_weights(level.model, self.mesh.positions[level.vertices], self.rest_frames,
                                   self.statistics, self.max_influences) for level in chain.levels]
        return SolvedChain(chain, fits)

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
            row["lbs_error"] = float(fit[3].max(initial=0.0)) / chain.diagonal
        created = []
        collection = bpy.data.collections.new(name)
        try:
            bpy.context.scene.collection.children.link(collection)
            for index, level in enumerate(chain.levels):
                level_object = self.level_object(mesh_object, armature, level, solved.fits[index],
                                                 f"{mesh_object.name}_LOD{index}")
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
                                       "statistics": self.statistics_source, "diagonal": float(chain.diagonal),
                                       "seconds": float(seconds)}
        return {"object": mesh_object.name, "collection": name, "objects": [o.name for o in created],
                "levels": rows, "warnings": list(chain.warnings), "statistics": self.statistics_source}

    def level_object(self, source, armature, level, fit, name: str):
        positions = self.mesh.positions[level.vertices]
        triangles = level.triangles
        mesh = bpy.data.meshes.new(name)
        mesh.vertices.add(len(positions))
        mesh.vertices.foreach_set("co", positions.astype(np.float32).reshape(-1))
        mesh.loops.add(3 * len(triangles))
        mesh.loops.foreach_set("vertex_index", triangles.astype(np.int32).reshape(-1))
        mesh.polygons.add(len(triangles))
        mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * len(triangles), 3, dtype=np.int32))
        mesh.polygons.foreach_set("loop_total", np.full(len(triangles), 3, np.int32))
        mesh.polygons.foreach_set("material_index", self.materials[level.triangle_origin].astype(np.int32))
        mesh.update(calc_edges=True)
        for material in source.data.materials:
            mesh.materials.append(material)
        if level.uv is not None and self.uv_name is not None:
            layer = mesh.uv_layers.new(name=self.uv_name, do_init=False)
            layer.uv.foreach_set("vector", level.uv.astype(np.float32).reshape(-1))
        storage.write_model(mesh, level.model, self.bone_names, self.armature_name, self.bind)
        write_point_attribute(mesh, SOURCE_VERTEX_ATTRIBUTE, "INT", "value", level.vertices.astype(np.int32))
        level_object = bpy.data.objects.new(name, mesh)
        level_object.parent = source.parent
        level_object.parent_type = source.parent_type
        level_object.matrix_parent_inverse = source.matrix_parent_inverse.copy()
        level_object.matrix_basis = source.matrix_basis.copy()
        vertex, bone, weight, _ = fit
        write_weight_groups(level_object, vertex, bone, weight, self.bone_names)
        modifier = level_object.modifiers.new("Armature", "ARMATURE")
        modifier.object = armature
        return level_object


@dataclass
class SolvedChain:
    chain: LodChain
    fits: list  # per level: linear_weights' (vertex, bone, weight, distance)


def level_rows(chain: LodChain) -> list[dict]:
    """Per level: vertices, triangles, influences and error (ε divided by the rest bounding-box diagonal)."""
    return [{"level": index, "vertices": int(level.vertex_count), "triangles": int(level.triangle_count),
             "influences": int(level.influence_count), "error": float(level.relative_epsilon)}
            for index, level in enumerate(chain.levels)]


def linear_weights(model: AnimationSpaceModel, positions: np.ndarray, rest_frames: np.ndarray, statistics,
                   max_influences: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(vertex, bone, weight) triples of the nearest linear-blend weights (see the module's docstring), at most
    max_influences per vertex, bones >= 1, and each vertex's L2,2 distance between the two skinnings."""
    b = model.bone_count
    blocks = statistics.matrix().reshape(b, 4, b, 4).transpose(0, 2, 1, 3)  # P_jk = E[G_j^T G_k]
    counts = model.counts()
    vertex_of = np.repeat(np.arange(model.vertex_count), counts)
    homogeneous = np.column_stack([positions, np.ones(len(positions))])
    q_all = np.einsum("vij,vj->vi", np.linalg.inv(rest_frames)[model.bones], homogeneous[vertex_of])  # Ĝ^-1 v
    weight = np.where(model.bones > 0, model.coordinates[:, 3], -np.inf)
    order = np.lexsort((-weight, vertex_of))
    first = np.r_[True, vertex_of[order][1:] != vertex_of[order][:-1]] if len(order) else np.zeros(0, bool)
    rank = np.arange(len(order)) - np.maximum.accumulate(np.where(first, np.arange(len(order)), 0))
    chosen = order[(rank < max_influences) & (model.bones[order] > 0)]
    chosen_vertex = vertex_of[chosen]
    k_of = np.bincount(chosen_vertex, minlength=model.vertex_count)
    out_v, out_b, out_w = [], [], []
    distance = np.zeros(model.vertex_count)
    same = {}
    for slot, influence in enumerate(chosen):
        same.setdefault(int(vertex_of[influence]), []).append(slot)
    for vertex_count_k in range(1, max_influences + 1):
        vertices = np.flatnonzero(k_of == vertex_count_k)
        if not len(vertices):
            continue
        slots = np.array([same[int(v)] for v in vertices])  # (n, k)
        picked = chosen[slots]
        bones = model.bones[picked]
        q = q_all[picked]  # (n, k, 4)
        a = np.einsum("nji,njkil,nkl->njk", q, blocks[bones[:, :, None], bones[:, None, :]], q)
        # the model's own influences, padded
        starts, ends = model.offsets[vertices], model.offsets[vertices + 1]
        width = int((ends - starts).max())
        index = np.minimum(starts[:, None] + np.arange(width), ends[:, None] - 1)
        valid = (starts[:, None] + np.arange(width)) < ends[:, None]
        p = np.where(valid[..., None], model.coordinates[index], 0.0)  # (n, m, 4)
        model_bones = model.bones[index]
        # cross_j = q_j^T sum_m P_jm p_m over the model's influences m; the fit's normal equations 2 A w = 2 cross
        cross = np.einsum("nji,njmil,nml->nj", q, blocks[bones[:, :, None], model_bones[:, None, :]], p)
        self_term = np.einsum("nmi,nmoil,nol->n", p, blocks[model_bones[:, :, None], model_bones[:, None, :]], p)
        k = vertex_count_k
        system = np.zeros((len(vertices), k + 1, k + 1))
        system[:, :k, :k] = a
        system[:, :k, k] = system[:, k, :k] = 1.0
        right = np.concatenate([cross, np.ones((len(vertices), 1))], axis=1)
        try:
            solution = np.linalg.solve(system, right[..., None])[..., 0][:, :k]
        except np.linalg.LinAlgError:  # a singular fit (bones alike in the statistics): the least-norm solution
            solution = (np.linalg.pinv(system) @ right[..., None])[..., 0][:, :k]
        w = np.maximum(solution, 0.0)
        total = w.sum(axis=1, keepdims=True)
        fallback = np.zeros_like(w)
        fallback[:, 0] = 1.0
        w = np.where(total > 0, w / np.where(total > 0, total, 1.0), fallback)
        squared = np.einsum("nj,njk,nk->n", w, a, w) - 2 * np.einsum("nj,nj->n", w, cross) + self_term
        distance[vertices] = np.sqrt(np.maximum(squared, 0.0))
        keep = w > 0
        out_v.append(np.repeat(vertices, k).reshape(-1, k)[keep])
        out_b.append(bones[keep])
        out_w.append(w[keep])
    if not out_v:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), distance
    return np.concatenate(out_v), np.concatenate(out_b), np.concatenate(out_w), distance


def write_weight_groups(level_object, vertex, bone, weight, names: list) -> None:
    for j, name in enumerate(names):
        if j == 0:
            continue
        group = level_object.vertex_groups.new(name=name)
        here = bone == j
        members, values = vertex[here], weight[here].astype(np.float32)
        order = np.argsort(values, kind="stable")
        distinct, starts = np.unique(values[order], return_index=True)
        for value, chosen in zip(distinct, np.split(members[order], starts[1:])):
            group.add(chosen.tolist(), float(value), "REPLACE")


def chain_statistics(armature) -> tuple[object, str]:
    """The armature's stored pose statistics, else statistics of its action's frames."""
    if pose_statistics.summary(armature) is not None:
        return pose_statistics.load(armature), "stored"
    action = armature.animation_data.action if armature.animation_data else None
    if action is None:
        raise SkinkitError(f"'{armature.name}' has neither pose statistics nor an action to compute them from "
                           "(run Compute Pose Statistics)")
    return pose_statistics.from_frames(armature, action_frames(action)), "action"


def prepare_lod_chain(mesh_object, *, levels: int = 4, metric: str = "animation", simplify_influences: bool = True,
                      max_influences: int = DEFAULT_MAX_INFLUENCES) -> LodChainJob:
    """Reads everything the chain needs (changing nothing)."""
    with naming(mesh_object):
        if mesh_object.type != "MESH":
            raise SkinkitError(f"is a {mesh_object.type.lower()}, not a mesh")
        if metric not in METRICS:
            raise SkinkitError(f"metric must be one of {METRICS}, not {metric!r}")
        if int(levels) < 2:
            raise SkinkitError(f"levels: expected at least 2 (LOD0 and one coarser), got {levels}")
        if int(max_influences) < 1:
            raise SkinkitError(f"max influences: expected at least 1, got {max_influences}")
        if not mesh_object.data.polygons:
            raise SkinkitError("has no faces")
        if bpy.data.collections.get(f"{mesh_object.name}_LOD") is not None:
            raise SkinkitError(f"a collection '{mesh_object.name}_LOD' already exists: delete or rename it first")
        rig = rig_of(mesh_object)
        if storage.has_model(mesh_object.data):
            stored = storage.read_model(mesh_object.data, mesh_object.name)
            model, bind, names = stored.model, stored.bind, stored.bone_names
            rest_frames = skeleton_of(rig, bind).rest_frames
            if stored.armature_name != rig.armature_object.name:
                raise SkinkitError(f"its model was bound to '{stored.armature_name}', its Armature modifier uses "
                                   f"'{rig.armature_object.name}'")
            if names != bone_names(rig.armature_object):
                raise SkinkitError("its model's bones differ from the armature's (convert it again)")
        else:
            bind = bind_matrix(rig, bpy.context.evaluated_depsgraph_get())
            skeleton = skeleton_of(rig, bind)
            model = convert_lbs(skeleton, deform_weights(rig), mesh_of(mesh_object).positions)
            names, rest_frames = list(skeleton.names), skeleton.rest_frames
        statistics, source = chain_statistics(rig.armature_object)
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
                           polygon_materials[mesh.triangle_polygons], names, rig.armature_object.name, bind,
                           rest_frames, {"levels": int(levels), "metric": metric, "simplify_influences": bool(simplify_influences)},
                           int(max_influences), source, (len(data.vertices), len(data.polygons)))


def build_lod_chain(mesh_object, progress=None, **options) -> dict:
    """Prepares, solves and writes on this thread (options as prepare_lod_chain's); returns the report with
    `seconds`."""
    started = time.perf_counter()
    job = prepare_lod_chain(mesh_object, **options)
    solved = job.solve(progress)
    report = job.write(mesh_object, solved, time.perf_counter() - started)
    report["seconds"] = time.perf_counter() - started
    return report
