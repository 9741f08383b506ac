"""The spec of skinkit._core: one `fn(...)` per C entry point; scripts/gen_bindings.py turns it into
csrc/binding/pymodule.c and skinkit/_core.pyi (`make bindings`).

The vocabulary, in Python order of the arguments:
  inp/out/inout(name, types, size)  an array: types "d" float64, "f" float32, "df" either (all "df" arrays of a
                                    call share one precision and the call goes to sk_..._f64 or sk_..._f32), "i"
                                    int32, "B" uint8 or bool, "H" uint16. size: "4*influence_count",
                                    "vertex_count+1", "16".
                                    A count is known from a size() argument, or derived from the first array
                                    whose size has it as the only unknown (inputs first), then checked in every
                                    other array; every product is overflow-checked.
  opt/opt_out(...)                  the same, None allowed (the C call gets NULL).
  size(name, min=0)                 a count given by the caller (a Py_ssize_t; negative refused).
  real(name), integer(name, min, max), flag(name), progress(), threads()
  report(c_type, fields)            a struct the C call fills; the function then returns it as a dict.
  result(name, code)                a scalar the C call writes (size_t "n" or double "d"), returned as a dict.
  Groups (influences(), examples(), triangle_mesh(), pose_statistics()) expand to their arrays and counts.

The C call is a template: {name} stands for an argument, a count, a group, a report ({report}), {progress}
(the callback and its user pointer), {error} and, in the function's name, {precision} (f64 or f32). A group
with a C struct passes a pointer to it, built in place: `&(const sk_influences){offsets, bones, vertex_count,
influence_count}` (a C11 compound literal); pose_statistics() passes its members loose
unless asked for the struct.
"""
from __future__ import annotations

from dataclasses import dataclass

THREAD_LIMIT = 1024


@dataclass(frozen=True)
class Array:
    name: str
    types: str
    size: str
    role: str = "in"  # "in", "out" (written) or "inout" (read and written)
    optional: bool = False


@dataclass(frozen=True)
class Scalar:
    name: str
    kind: str  # "size", "real", "integer", "flag" or "progress"
    minimum: int = 0
    maximum: int = 0  # integer: with minimum 0, no bound but int's


@dataclass(frozen=True)
class Group:
    """Arguments that travel together, and the struct that will carry them (fields in the struct's order)."""
    name: str
    c_type: str
    members: tuple[Array | Scalar, ...]
    fields: tuple[str, ...]
    as_struct: bool


@dataclass(frozen=True)
class Result:
    """What the C call writes besides arrays: a report struct (fields) or one scalar (c_type size_t or double)."""
    name: str
    c_type: str
    fields: tuple[tuple[str, str], ...]  # (name, "n" size_t, "i" int or "d" double)

    @property
    def member(self) -> str:
        return self.c_type.removeprefix("sk_") if self.c_type.startswith("sk_") else self.name


@dataclass(frozen=True)
class Function:
    name: str
    items: tuple[Array | Scalar | Group | Result, ...]
    call: str
    doc: str
    test_helper: bool = False  # not a C entry point of its own: exempt from the 1:1 name rule

    @property
    def arguments(self) -> list[Array | Scalar]:
        flat = []
        for item in self.items:
            if isinstance(item, Group):
                flat.extend(item.members)
            elif not isinstance(item, Result):
                flat.append(item)
        return flat

    @property
    def groups(self) -> list[Group]:
        return [item for item in self.items if isinstance(item, Group)]

    @property
    def result(self) -> Result | None:
        return next((item for item in self.items if isinstance(item, Result)), None)


def fn(name, *items, call, doc, test_helper=False) -> Function:
    return Function(name, items, call, " ".join(doc.split()), test_helper)


def inp(name, types, size) -> Array:
    return Array(name, types, size)


def out(name, types, size) -> Array:
    return Array(name, types, size, role="out")


def inout(name, types, size) -> Array:
    return Array(name, types, size, role="inout")


def opt(name, types, size) -> Array:
    return Array(name, types, size, optional=True)


def opt_out(name, types, size) -> Array:
    return Array(name, types, size, role="out", optional=True)


def size(name, min=0) -> Scalar:  # noqa: A002 - the spec's word
    return Scalar(name, "size", minimum=min)


def real(name) -> Scalar:
    return Scalar(name, "real")


def integer(name, min=0, max=0) -> Scalar:  # noqa: A002
    return Scalar(name, "integer", minimum=min, maximum=max)


def flag(name) -> Scalar:
    return Scalar(name, "flag")


def progress() -> Scalar:
    return Scalar("progress", "progress")


def threads() -> Scalar:
    return integer("thread_count", min=0, max=THREAD_LIMIT)


def report(c_type, fields) -> Result:
    return Result("report", c_type, tuple(tuple(f.split(":")) for f in fields.split()))


def result(name, code) -> Result:
    return Result(name, {"n": "size_t", "d": "double"}[code], ((name, code),))


# ---- groups ----------------------------------------------------------------------------------------------------

def influences() -> Group:
    """CSR influence sets: offsets (vertex_count + 1, at least one element) and bones (influence_count)."""
    members = (inp("offsets", "i", "vertex_count+1"), inp("bones", "i", "influence_count"))
    return Group("influences", "sk_influences", members, ("offsets", "bones", "vertex_count", "influence_count"), True)


def examples(poses="poses") -> Group:
    """Example poses (4x4 per bone per example) and meshes (3 per vertex per example); vertex_count comes from the
    influences."""
    members = (inp(poses, "d", "16*example_count*bone_count"), inp("positions", "d", "3*example_count*vertex_count"),
               size("example_count", min=1))
    return Group("examples", "sk_examples", members, (poses, "positions", "example_count", "bone_count"), True)


def triangle_mesh() -> Group:
    """triangles (3 per triangle); vertex_count comes from another argument."""
    return Group("mesh", "sk_triangle_mesh", (inp("triangles", "i", "3*triangle_count"),),
                 ("triangles", "triangle_count", "vertex_count"), True)


def pose_statistics(as_struct=False) -> Group:
    """expected_local and expected_gram (4x4 per bone) and parents (bone_count), from joint_statistics; passed as
    an sk_pose_statistics by the level-of-detail functions, loose by the metrics (which predate the struct)."""
    members = (inp("expected_local", "d", "16*bone_count"), inp("expected_gram", "d", "16*bone_count"),
               inp("parents", "i", "bone_count"))
    return Group("statistics", "sk_pose_statistics", members,
                 ("expected_local", "expected_gram", "parents", "bone_count"), as_struct)


LSQR_REPORT = report("sk_lsqr_report", "stop_reason:i iterations:i residual_norm:d normal_residual:d matrix_norm:d "
                                       "condition:d solution_norm:d initial_residual_norm:d")

# ---- the entry points, in csrc/skinkit.h's order -----------------------------------------------------------------

FUNCTIONS = [
    # Validation
    fn("validate_skeleton", inp("parents", "i", "bone_count"), opt("rest_frames", "d", "16*bone_count"),
       call="sk_validate_skeleton({parents}, {rest_frames}, {bone_count}, {error})",
       doc="Checks a skeleton: parents[0] == -1, every other parent in range, no cycle; rest frames (or None) finite, "
           "affine and well conditioned."),
    fn("validate_influences", influences(), size("bone_count"),
       call="sk_validate_influences({influences}, {bone_count}, {error})",
       doc="Checks a CSR influence pattern: offsets start at 0, never decrease, end at the influence count; every "
           "bone index in [0, bone_count)."),
    fn("validate_triangles", triangle_mesh(), size("vertex_count"),
       call="sk_validate_triangles({mesh}, {error})",
       doc="Checks a triangle list: every index in [0, vertex_count), no triangle repeating a vertex."),
    fn("validate_surface", triangle_mesh(), size("vertex_count"),
       call="sk_validate_surface({mesh}, {error})",
       doc="Checks that a triangle mesh can be cut into discs: no edge shared by more than two faces, neighbours "
           "oriented alike, no vertex joining separate fans of faces (a bowtie)."),

    # Conversion from linear blend skinning
    fn("lbs_to_animation_space", out("destination", "d", "4*influence_count"),
       inp("vectors", "d", "3*vertex_count"), real("homogeneous"), influences(),
       inp("weights", "d", "influence_count"), inp("rest_frames", "d", "16*bone_count"),
       call="sk_lbs_to_animation_space({destination}, {influences}, {vectors}, {homogeneous}, {weights}, "
            "{rest_frames}, {bone_count}, {error})",
       doc="Linear-blend weights to animation-space coordinates (eq. 3.1 for points with homogeneous 1, eq. 4.8 for "
           "tangents with 0)."),
    fn("skinning_matrices", out("destination", "d", "16*bone_count"), inp("poses", "d", "16*bone_count"),
       inp("rest_frames", "d", "16*bone_count"),
       call="sk_skinning_matrices({destination}, {poses}, {rest_frames}, {bone_count}, {error})",
       doc="Skinning matrices N_j = G_j inverse(rest_j) (eq. 2.2)."),

    # Evaluation
    fn("animation_space_evaluate", out("destination", "df", "3*vertex_count"), influences(),
       inp("coordinates", "df", "4*influence_count"), inp("poses", "df", "16*bone_count"), threads(),
       call="sk_animation_space_evaluate_{precision}({destination}, {influences}, {coordinates}, {poses}, "
            "{bone_count}, {thread_count}, {error})",
       doc="Animation projection: each vertex is the top three rows of sum_k G_bones[k] p_k. All float64 or all "
           "float32."),
    fn("lbs_evaluate", out("destination", "df", "3*vertex_count"), inp("vectors", "df", "3*vertex_count"),
       real("homogeneous"), influences(), inp("weights", "df", "influence_count"),
       inp("skinning_matrices", "df", "16*bone_count"), threads(),
       call="sk_lbs_evaluate_{precision}({destination}, {influences}, {vectors}, {homogeneous}, {weights}, "
            "{skinning_matrices}, {bone_count}, {thread_count}, {error})",
       doc="Linear blend skinning of positions (homogeneous 1) or tangent vectors (0). All float64 or all float32."),

    # Fitting to example poses
    fn("fit_per_vertex", out("coordinates", "d", "4*influence_count"), influences(), examples(), real("lambda_"),
       opt("prior", "d", "4*influence_count"), threads(),
       call="sk_fit_per_vertex({coordinates}, {influences}, {examples}, {prior}, {lambda_}, {thread_count}, {error})",
       doc="Per-vertex fit with vertex regularisation lambda_ towards prior (or zero) (eq. 4.3)."),
    fn("fit_global", inout("coordinates", "d", "4*influence_count"), influences(), examples(),
       inp("edges", "i", "2*edge_count"), inp("edge_weights", "d", "edge_count"), real("atol"), real("btol"),
       real("conlim"), integer("iteration_limit", min=0, max=2**31 - 1), flag("precondition"), threads(), progress(),
       LSQR_REPORT,
       call="sk_fit_global({coordinates}, {report}, {influences}, {examples}, {edges}, {edge_weights}, {edge_count}, "
            "&(sk_lsqr_settings){{atol}, {btol}, {conlim}, {iteration_limit}, {precondition}, {thread_count}}, "
            "{progress}, {error})",
       doc="Global fit with edge regularisation (eq. 4.4) by LSQR, from the coordinates given; progress(fraction) "
           "returning true cancels."),
    fn("lsqr_dense_matrix", out("x", "d", "cols"), inp("matrix", "d", "rows*cols"), inp("b", "d", "rows"),
       size("rows", min=1), size("cols", min=1), real("atol"), real("btol"), real("conlim"),
       integer("iteration_limit", min=0, max=2**31 - 1), LSQR_REPORT,
       call="sk_lsqr({x}, {b}, {rows}, {cols}, dense_apply, &(dense_matrix){{matrix}, {rows}, {cols}}, "
            "&(sk_lsqr_settings){{atol}, {btol}, {conlim}, {iteration_limit}, 0, 1}, {report}, NULL, NULL, {error})",
       doc="Test helper: sk_lsqr on a dense row-major matrix (dense_apply in csrc/binding/runtime.h), "
           "min |b - matrix x|.",
       test_helper=True),
    fn("fit_lbs_weights", out("weights", "d", "influence_count"), influences(), examples(poses="skinning_matrices"),
       inp("rest_positions", "d", "3*vertex_count"), threads(),
       call="sk_fit_lbs_weights({weights}, {influences}, {examples}, {rest_positions}, {thread_count}, {error})",
       doc="Linear-blend baseline: non-negative weights summing to 1 per vertex that best reproduce the examples."),

    # The animation-space metrics
    fn("joint_statistics", out("expected_local", "d", "16*bone_count"), out("expected_gram", "d", "16*bone_count"),
       inp("local", "d", "16*sample_count*bone_count"), inp("parents", "i", "bone_count"),
       call="sk_joint_statistics({expected_local}, {expected_gram}, {local}, {parents}, {sample_count}, "
            "{bone_count}, {error})",
       doc="Pose statistics E[L_j] and E[G_j^T G_j] of the independent-joints model from sampled local frames."),
    fn("expectation_block", out("block", "d", "16"), pose_statistics(), size("j"), size("k"),
       call="sk_expectation_block({block}, {expected_local}, {expected_gram}, {parents}, {bone_count}, {j}, {k}, "
            "{error})",
       doc="One block P_jk = E[G_j^T G_k] by the common-ancestor recursion (eq. 3.7-3.8)."),
    fn("expectation_blocks", out("blocks", "d", "16*bone_count*bone_count"), pose_statistics(),
       call="sk_expectation_blocks({blocks}, {expected_local}, {expected_gram}, {parents}, {bone_count}, {error})",
       doc="Every block of P: blocks[(j * bone_count + k) * 16 ..] = P_jk."),
    fn("linear_norms", out("destination", "d", "matrix_count"), inp("matrices", "d", "16*matrix_count"),
       call="sk_linear_norms({destination}, {matrices}, {matrix_count}, {error})",
       doc="The 2-norm of the linear 3x3 part of each 4x4 matrix."),
    fn("mean_distances", out("destination", "d", "vertex_count"), influences(),
       inp("vectors", "d", "4*influence_count"), pose_statistics(),
       inout("block_cache", "d", "16*bone_count*bone_count"), inout("cached", "B", "bone_count*bone_count"),
       threads(),
       call="sk_mean_distances({destination}, {influences}, {vectors}, {expected_local}, {expected_gram}, "
            "{parents}, {bone_count}, {block_cache}, {cached}, {thread_count}, {error})",
       doc="Mean distances sqrt(s_i^T P s_i) (the L2,2 norm, eq. 3.6) of CSR weight-0 vectors; block_cache and "
           "cached (zero on the first call) keep the blocks formed between calls."),
    fn("max_distances", out("destination", "d", "vertex_count"), influences(),
       inp("vectors", "d", "4*influence_count"), inp("parents", "i", "bone_count"),
       inp("linear_bound", "d", "bone_count"), inp("translation_centre", "d", "3*bone_count"),
       inp("translation_radius", "d", "bone_count"), threads(),
       call="sk_max_distances({destination}, {influences}, {vectors}, {parents}, {linear_bound}, "
            "{translation_centre}, {translation_radius}, {bone_count}, {thread_count}, {error})",
       doc="Max-distance bounds (the L2,inf norm, eq. 3.18-3.28) for poses within the joints' bounds."),

    # Skinning a mesh sequence without a rig
    fn("fit_core_motions", out("motions", "d", "16*frame_count*bone_count"),
       inp("core_offsets", "i", "bone_count+1"), inp("core_vertices", "i", "core_count"),
       inp("rest_positions", "d", "3*vertex_count"), inp("frames", "d", "3*frame_count*vertex_count"),
       size("frame_count", min=1),
       call="sk_fit_core_motions({motions}, {core_offsets}, {core_vertices}, {rest_positions}, {frames}, "
            "{vertex_count}, {core_count}, {frame_count}, {bone_count}, {error})",
       doc="Rigid bone motions from core vertices (section 4.1.4 steps 2-4)."),
    fn("fit_rest_joints", out("joints", "d", "3*bone_count"), inp("motions", "d", "16*frame_count*bone_count"),
       inp("parents", "i", "bone_count"), inp("approximate_joints", "d", "3*bone_count"), real("lambda_"),
       call="sk_fit_rest_joints({joints}, {motions}, {parents}, {approximate_joints}, {frame_count}, {bone_count}, "
            "{lambda_}, {error})",
       doc="Rest joint positions (eq. 4.6), parents first."),
    fn("solve_rigid_poses", inout("poses", "d", "16*frame_count*bone_count"), influences(),
       inp("coordinates", "d", "4*influence_count"), inp("targets", "d", "3*frame_count*vertex_count"),
       opt_out("frame_errors", "d", "frame_count"), size("frame_count", min=1), integer("sweeps"), threads(),
       call="sk_solve_rigid_poses({poses}, {frame_errors}, {influences}, {coordinates}, {targets}, {frame_count}, "
            "{bone_count}, {sweeps}, {thread_count}, {error})",
       doc="Rigid bone frames that best reproduce the targets with a fixed model, in place; frame_errors (or None) "
           "gets each frame's squared error."),
    fn("rank_bones", out("best_bones", "i", "vertex_count*candidate_count"),
       out("best_errors", "d", "vertex_count*candidate_count"), inp("rest_positions", "d", "3*vertex_count"),
       inp("frames", "d", "3*frame_count*vertex_count"), inp("motions", "d", "16*frame_count*bone_count"),
       opt("allowed", "B", "vertex_count*bone_count"), size("frame_count", min=1), size("candidate_count", min=1),
       threads(),
       call="sk_rank_bones({best_bones}, {best_errors}, {rest_positions}, {frames}, {motions}, {allowed}, "
            "{vertex_count}, {frame_count}, {bone_count}, {candidate_count}, {thread_count}, {error})",
       doc="For each vertex, the candidate_count bones whose rigid motion best explains it, ascending by error; "
           "allowed (or None) restricts the bones per vertex."),

    # Segmentation
    fn("segment", out("charts", "i", "triangle_count"), inp("embedding", "d", "vertex_count*dimension"),
       size("dimension", min=1), triangle_mesh(), inp("seams", "i", "2*seam_count"), integer("mode", min=0, max=1),
       size("chart_count"), real("threshold"), real("rho"),
       report("sk_segment_report", "chart_count:n mesh_metric:d component_count:n"),
       call="sk_segment({charts}, {report}, {mesh}, {embedding}, {dimension}, {seams}, {seam_count}, "
            "&(sk_segment_options){{mode}, {chart_count}, {threshold}, {rho}}, {error})",
       doc="Greedy disc-preserving chart merging (mode 0) or seams-only charts (mode 1), section 5.2."),
    fn("cut_along_seams", out("cut_triangles", "i", "3*triangle_count"),
       out("source_vertex", "i", "3*triangle_count"), triangle_mesh(), inp("seams", "i", "2*seam_count"),
       size("vertex_count"), result("cut_vertex_count", "n"),
       call="sk_cut_along_seams({cut_triangles}, {source_vertex}, {cut_vertex_count}, {mesh}, {seams}, {seam_count}, "
            "{error})",
       doc="Cuts the mesh open along the seams; source_vertex[:cut_vertex_count] is each new vertex's original."),
    fn("chart_corners", out("corners", "B", "vertex_count"), triangle_mesh(), inp("charts", "i", "triangle_count"),
       opt("embedding", "d", "vertex_count*dimension"), size("dimension"), size("vertex_count"),
       call="sk_chart_corners({corners}, {mesh}, {charts}, {embedding}, {dimension}, {error})",
       doc="Chart corners (Fig 5.6), spread by metric length in the embedding, or by edge count when it is None."),
    fn("straighten_charts", inout("charts", "i", "triangle_count"), out("corners", "B", "vertex_count"),
       inp("embedding", "d", "vertex_count*dimension"), size("dimension", min=1), triangle_mesh(), real("ratio"),
       real("rho"), report("sk_straighten_report", "paths:n shortest:n constrained:n kept:n"),
       call="sk_straighten_charts({charts}, {corners}, {report}, {mesh}, {embedding}, {dimension}, "
            "&(sk_straighten_options){{ratio}, {rho}}, {error})",
       doc="Edge straightening (section 5.2.3) of the charts in place; corners are computed and kept."),

    # Flattening and packing
    fn("flatten", out("uv", "d", "6*triangle_count"), out("charts_out", "i", "triangle_count"), triangle_mesh(),
       inp("edge_lengths_sq", "d", "3*triangle_count"), inp("charts", "i", "triangle_count"),
       inp("corners", "B", "vertex_count"), size("vertex_count"), flag("straight"), flag("optimise"),
       real("stretch_limit"), integer("sweep_limit", min=0, max=2**31 - 1), threads(),
       report("sk_flatten_report", "chart_count:n split_count:n flip_splits:n straight_charts:n circle_charts:n "
                                   "free_charts:n extra_corners:n tutte_charts:n invalid_triangles:n "
                                   "overlapping_charts:n solver_iterations:n optimisation_sweeps:n "
                                   "boundary_first_charts:n stretch_splits:n"),
       call="sk_flatten({uv}, {charts_out}, {report}, {mesh}, {edge_lengths_sq}, {charts}, {corners}, "
            "&(sk_flatten_options){{straight}, {optimise}, {stretch_limit}, {sweep_limit}, {thread_count}}, {error})",
       doc="Flattens each chart into its own 2D frame in metric units (section 5.3), splitting overlapping ones."),
    fn("triangle_stretch", out("destination", "d", "triangle_count"), inp("uv", "d", "6*triangle_count"),
       inp("edge_lengths_sq", "d", "3*triangle_count"),
       call="sk_triangle_stretch({destination}, {uv}, {edge_lengths_sq}, {triangle_count}, {error})",
       doc="Sander's L2 stretch per triangle; infinity for a flipped or degenerate uv triangle."),
    fn("mesh_stretch", inp("uv", "d", "6*triangle_count"), inp("edge_lengths_sq", "d", "3*triangle_count"),
       result("stretch", "d"),
       call="sk_mesh_stretch({stretch}, {uv}, {edge_lengths_sq}, {triangle_count}, {error})",
       doc="Sander's normalised L2 stretch of the whole mesh (1 for an isometry)."),
    fn("pack", out("destination", "d", "6*triangle_count"), inp("uv", "d", "6*triangle_count"),
       inp("charts", "i", "triangle_count"), opt("surface_area", "d", "triangle_count"),
       integer("texture_size", min=1, max=2**31 - 1), real("margin"),
       report("sk_pack_report", "chart_count:n scale:d packing_efficiency:d"),
       call="sk_pack({destination}, {report}, {uv}, {charts}, {surface_area}, {triangle_count}, "
            "&(sk_pack_options){{texture_size}, {margin}}, {error})",
       doc="Packs the charts into the unit square (section 5.4); surface_area (or None) sets each chart's scale."),

    # Level of detail
    fn("remove_influence", out("corrected", "d", "4*influence_count"), inp("bones", "i", "influence_count"),
       inp("coordinates", "d", "4*influence_count"), size("removed"), pose_statistics(as_struct=True), result("cost", "d"),
       call="sk_remove_influence({corrected}, {cost}, {bones}, {coordinates}, {influence_count}, {removed}, {statistics}, "
            "{error})",
       doc="Removes influence `removed` from one vector with the correction of least L2,2 norm (eq. 6.1, appendix "
           "A.2), written in the input's layout with the removed slot zero; returns its cost."),
    fn("limit_influences", out("limited_offsets", "i", "vertex_count+1"), out("limited_bones", "i", "influence_count"),
       out("limited_coordinates", "d", "4*influence_count"), opt_out("costs", "d", "vertex_count"),
       opt_out("limited_tangents", "d", "4*tangent_count*influence_count"), influences(),
       inp("coordinates", "d", "4*influence_count"), opt("tangents", "d", "4*tangent_count*influence_count"),
       size("tangent_count"), pose_statistics(as_struct=True), size("max_influences", min=1), threads(), progress(),
       result("limited_count", "n"),
       call="sk_limit_influences({limited_offsets}, {limited_bones}, {limited_coordinates}, {limited_count}, "
            "{costs}, {limited_tangents}, {influences}, {coordinates}, {tangents}, {tangent_count}, {statistics}, "
            "{max_influences}, {thread_count}, {progress}, {error})",
       doc="Limit Influences (section 6.4): every vertex down to max_influences by the cheapest removals; the "
           "outputs have the input's capacity and limited_count says how much is used."),
    fn("simplify", out("triangles_out", "i", "3*triangle_count"), out("triangle_origin", "i", "triangle_count"),
       opt_out("uv_out", "d", "6*triangle_count"), opt_out("locked_out", "B", "3*triangle_count"),
       out("vertex_map", "i", "vertex_count"),
       out("offsets_out", "i", "vertex_count+1"), out("bones_out", "i", "influence_count"),
       out("coordinates_out", "d", "4*influence_count"), triangle_mesh(), inp("rest_positions", "d", "3*vertex_count"),
       influences(), inp("coordinates", "d", "4*influence_count"), pose_statistics(as_struct=True),
       opt("uv", "d", "6*triangle_count"), opt("charts", "i", "triangle_count"), opt("materials", "i", "triangle_count"),
       opt("locked", "B", "3*triangle_count"), size("target_triangles"), size("target_influences"),
       integer("metric", min=0, max=1), flag("simplify_influences"), real("straightness"), progress(),
       report("sk_simplify_report", "triangle_count:n vertex_count:n influence_count:n edge_collapses:n "
                                    "influence_collapses:n epsilon:d exhausted:i refused_flip:n refused_chart:n "
                                    "refused_seam:n refused_link:n refused_locked:n"),
       call="sk_simplify({triangles_out}, {triangle_origin}, {uv_out}, {locked_out}, {vertex_map}, {offsets_out}, {bones_out}, "
            "{coordinates_out}, {report}, {mesh}, {rest_positions}, {influences}, {coordinates}, {statistics}, {uv}, "
            "{charts}, {materials}, {locked}, &(sk_simplify_options){{target_triangles}, {target_influences}, "
            "{metric}, {simplify_influences}, {straightness}}, {progress}, {error})",
       doc="One progressive-mesh step (sections 6.2-6.3.1): half-edge collapses costed by memoryless APS (metric 0 "
           "animation space, 1 rest pose) and influence collapses in one queue, to the targets (0: unset); outputs "
           "have the input's capacity, the report says how much is used."),

    # Runtime: culling, level selection, geomorphing skinning (csrc/runtime/sk_runtime_*.c)
    fn("runtime_kernel_supported", integer("kernel", min=0, max=3), result("supported", "n"),
       call="sk_runtime_kernel_supported({supported}, {kernel}, {error})",
       doc="Whether this build and CPU run a skinning kernel (0 auto, 1 scalar, 2 SSE2, 3 AVX2+FMA): 1 or 0."),
    fn("runtime_frustum_planes", out("planes", "f", "24"), inp("view_projection", "f", "16"),
       call="sk_runtime_frustum_planes({planes}, {view_projection}, {error})",
       doc="The six inward unit planes (left, right, bottom, top, near, far) of a row-major OpenGL view-projection "
           "matrix (Gribb-Hartmann)."),
    fn("runtime_cull", out("visible", "B", "sphere_count"), inp("spheres", "f", "4*sphere_count"),
       inp("planes", "f", "4*plane_count"),
       call="sk_runtime_cull({visible}, {spheres}, {sphere_count}, {planes}, {plane_count}, {error})",
       doc="Frustum culling (section 7.2): visible 0 where a sphere (x, y, z, r) is wholly outside a plane."),
    fn("runtime_select_levels", out("levels", "f", "instance_count"), inp("spheres", "f", "4*instance_count"),
       inp("epsilons", "f", "instance_count*level_count"), size("level_count", min=1), inp("position", "f", "3"),
       inp("forward", "f", "3"), real("horizontal_fov"), real("viewport_width"), real("pixel_tolerance"),
       call="sk_runtime_select_levels({levels}, {spheres}, {epsilons}, {instance_count}, {level_count}, "
            "&(const sk_runtime_camera){{position}, {forward}, (float){horizontal_fov}, (float){viewport_width}}, "
            "(float){pixel_tolerance}, {error})",
       doc="Level selection (eq. 7.2): the real level whose interpolated epsilon is the error a pixel tolerance "
           "allows at each sphere's minimum depth."),
    fn("runtime_morph_uv", out("destination", "f", "2*corner_count"), inp("uv_morph", "f", "4*corner_count"),
       real("fraction"),
       call="sk_runtime_morph_uv({destination}, {uv_morph}, {corner_count}, (float){fraction}, {error})",
       doc="Geomorphed texture coordinates: (u, v) + fraction (du, dv) per corner."),
    fn("runtime_skin", out("positions", "f", "3*output_count"), opt_out("tangent_0", "f", "3*output_count"),
       opt_out("tangent_1", "f", "3*output_count"), influences(), inp("morph_positions", "f", "8*influence_count"),
       opt("morph_tangents", "f", "16*influence_count"), inp("mesh_starts", "i", "mesh_count+1"),
       inp("meshes", "i", "instance_count"), inp("fractions", "f", "instance_count"), size("bone_count", min=1),
       inp("matrices", "f", "12*instance_count*bone_count"), inp("output_starts", "i", "instance_count+1"),
       integer("kernel", min=0, max=3), threads(),
       call="sk_runtime_skin({positions}, {tangent_0}, {tangent_1}, {output_count}, "
            "&(const sk_runtime_pack){*{influences}, {morph_positions}, {morph_tangents}, {mesh_starts}, "
            "{mesh_count}}, &(const sk_runtime_instances){{meshes}, {fractions}, {matrices}, {output_starts}, "
            "{instance_count}, {bone_count}}, {kernel}, {thread_count}, {error})",
       doc="Batched geomorphing skinning (algorithm 1): every instance's mesh at its fraction with its own 3x4 bone "
           "matrices, positions and (optionally) both tangents."),
    # Skeletons from segmented meshes (Vasilakis 2008)
    fn("extract_skeleton", out("joint_positions", "d", "15*part_count"), out("joint_parents", "i", "5*part_count"),
       out("joint_parts", "i", "5*part_count"), out("joint_kinds", "i", "5*part_count"),
       out("part_parents", "i", "part_count"), out("part_joints", "i", "part_count"),
       out("kernel_centroids", "d", "3*part_count"), out("principal_axes", "d", "9*part_count"),
       out("boxes", "d", "6*part_count"), out("part_flags", "i", "part_count"), triangle_mesh(),
       inp("positions", "d", "3*vertex_count"), inp("triangle_parts", "i", "triangle_count"), size("part_count"),
       opt("parents", "i", "part_count"), integer("method", min=0, max=2), flag("refine_local"),
       flag("refine_parent"), real("max_angle_degrees"), real("closeness"),
       report("sk_skeleton_report", "joint_count:n opening_count:n star_shaped_count:n degenerate_count:n "
                                    "opening_seconds:d hull_seconds:d kernel_seconds:d method_seconds:d"),
       call="sk_extract_skeleton({joint_positions}, {joint_parents}, {joint_parts}, {joint_kinds}, {part_parents}, "
            "{part_joints}, {kernel_centroids}, {principal_axes}, {boxes}, {part_flags}, {report}, {mesh}, "
            "{positions}, {triangle_parts}, {part_count}, {parents}, &(sk_skeleton_options){{method}, "
            "{refine_local}, {refine_parent}, {max_angle_degrees}, {closeness}}, {error})",
       doc="A skeleton from a mesh segmented into parts (Vasilakis 2008, chapter 3): openings, kernel centroids, "
           "principal directions and boxes per part, and the joints of the Opening (0), Centroid (1) or Principal "
           "Axis (2) method; the joint arrays have 5 per part and the report says how many are used."),
    fn("forward_kinematics", out("world", "d", "16*part_count"), inp("joints", "d", "3*part_count"),
       inp("parent_axes", "d", "3*part_count"), inp("angles", "d", "3*part_count"), inp("parents", "i", "part_count"),
       opt("root_frame", "d", "16"),
       call="sk_forward_kinematics({world}, {joints}, {parent_axes}, {angles}, {parents}, {root_frame}, {part_count}, "
            "{error})",
       doc="QT-pair forward kinematics (section 4.3): each part turns about its joint by its X, Y, Z angles (degrees) "
           "in the frame whose z-axis is its parent axis; world frames, parents' first."),
    fn("detect_collisions", out("pairs", "i", "2*pair_capacity"), inp("world", "d", "16*part_count"),
       inp("boxes", "d", "6*part_count"), inp("principal_axes", "d", "9*part_count"), inp("parents", "i", "part_count"),
       result("pair_count", "n"),
       call="sk_detect_collisions({pairs}, {pair_count}, {world}, {boxes}, {principal_axes}, {parents}, {part_count}, "
            "{pair_capacity}, {error})",
       doc="The colliding pairs of a pose (bounding spheres, then the oriented boxes' separating axes), parent-child "
           "pairs excepted; returns pair_count."),
    fn("collision_candidates", out("pairs", "i", "2*pair_capacity"), inp("parents", "i", "part_count"),
       integer("moved_part", min=-1, max=2**31 - 1), result("pair_count", "n"),
       call="sk_collision_candidates({pairs}, {pair_count}, {parents}, {part_count}, {moved_part}, {pair_capacity}, "
            "{error})",
       doc="The pairs a motion can make collide (section 4.3's precomputed lists): all but parent-child pairs, or "
           "with moved_part >= 0 only those across its subtree's border; returns pair_count."),
    fn("detect_collisions_among", out("pairs", "i", "2*pair_capacity"), out("tested", "i", "candidate_count"),
       out("sphere_weights", "d", "candidate_count"), inp("world", "d", "16*part_count"),
       inp("boxes", "d", "6*part_count"), inp("principal_axes", "d", "9*part_count"),
       inp("candidates", "i", "2*candidate_count"), flag("stop_at_first"),
       report("sk_collision_report", "pair_count:n sphere_hits:n box_tests:n"),
       call="sk_detect_collisions_among({pairs}, {tested}, {sphere_weights}, {report}, {world}, {boxes}, "
            "{principal_axes}, {candidates}, {candidate_count}, {part_count}, {stop_at_first}, {pair_capacity}, "
            "{error})",
       doc="The colliding candidate pairs of a pose: sphere weights (l / r)^2, then the box test likeliest first "
           "(tested: the candidate indices in that order), optionally stopping at the first collision."),
    fn("evaluate_seams", out("positions", "d", "3*point_count"), inp("rest_positions", "d", "3*vertex_count"),
       inp("world", "d", "16*part_count"), inp("joints", "d", "3*part_count"), inp("sources", "i", "point_count"),
       inp("parts_a", "i", "point_count"), inp("parts_b", "i", "point_count"), inp("blend", "d", "point_count"),
       call="sk_evaluate_seams({positions}, {rest_positions}, {world}, {joints}, {sources}, {parts_a}, {parts_b}, "
            "{blend}, {point_count}, {vertex_count}, {part_count}, {error})",
       doc="Rigid skinning with seams (section 4.4): each point its rest vertex moved by part a, or by QLERP between "
           "parts a and b about b's joint at its blend."),
    # Dual-quaternion skinning and handle rigs (Feng 2010, chapter 2)
    fn("dq_from_rigid", out("dual_quaternions", "d", "8*count"), inp("matrices", "d", "16*count"),
       call="sk_dq_from_rigid({dual_quaternions}, {matrices}, {count}, {error})",
       doc="Dual quaternions (real w x y z, dual w x y z) of rigid 4x4 matrices."),
    fn("dq_to_rigid", out("matrices", "d", "16*count"), inp("dual_quaternions", "d", "8*count"),
       call="sk_dq_to_rigid({matrices}, {dual_quaternions}, {count}, {error})",
       doc="Rigid 4x4 matrices of dual quaternions, each normalised first."),
    fn("dq_align_signs", inout("dual_quaternions", "d", "8*example_count*bone_count"), size("example_count", min=1),
       call="sk_dq_align_signs({dual_quaternions}, {example_count}, {bone_count}, {error})",
       doc="Per bone, negates each example's dual quaternion whose real part points away from example 0's."),
    fn("dq_blend", out("destination", "d", "8"), inp("dual_quaternions", "d", "8*count"), inp("weights", "d", "count"),
       call="sk_dq_blend({destination}, {dual_quaternions}, {weights}, {count}, {error})",
       doc="Sign-aligned, normalised weighted blend of dual quaternions."),
    fn("dqs_evaluate", out("destination", "df", "3*vertex_count"), inp("vectors", "df", "3*vertex_count"),
       real("homogeneous"), influences(), inp("weights", "df", "influence_count"),
       inp("dual_quaternions", "df", "8*bone_count"), threads(),
       call="sk_dqs_evaluate_{precision}({destination}, {influences}, {vectors}, {homogeneous}, {weights}, "
            "{dual_quaternions}, {bone_count}, {thread_count}, {error})",
       doc="Dual-quaternion skinning of positions (homogeneous 1) or tangent vectors (0). All float64 or all "
           "float32."),
    fn("kernel_values", out("destination", "d", "point_count*reference_count"),
       inp("points", "d", "point_count*dimension"), inp("references", "d", "reference_count*dimension"),
       size("dimension", min=1), integer("kernel", min=0, max=2), real("parameter"), integer("degree", min=0, max=16),
       call="sk_kernel_values({destination}, {points}, {references}, {point_count}, {reference_count}, {dimension}, "
            "{kernel}, {parameter}, {degree}, {error})",
       doc="Kernel values k(points_p, references_j): 0 Gaussian (parameter sigma), 1 polynomial (x.y + parameter) "
           "** degree, 2 linear."),
    fn("handle_predict", out("dual_quaternions", "d", "8*bone_count"), out("kernel_values", "d", "example_count"),
       inp("handle_positions", "d", "3*handle_count"), inp("handle_mean", "d", "3*handle_count"),
       real("handle_scale"), inp("training_handles", "d", "3*example_count*handle_count"),
       integer("kernel", min=0, max=2), real("parameter"), integer("degree", min=0, max=16),
       inp("mapping", "d", "8*bone_count*example_count"), inp("mapping_offset", "d", "8*bone_count"),
       opt("translation_rotations", "d", "3*bone_count*bone_count"),
       opt("translation_handles", "d", "bone_count*handle_count"),
       call="sk_handle_predict({dual_quaternions}, {kernel_values}, &(const sk_handle_rig){{handle_count}, "
            "{example_count}, {bone_count}, {kernel}, {parameter}, {degree}, {handle_scale}, {handle_mean}, "
            "{training_handles}, {mapping}, {mapping_offset}, {translation_rotations}, {translation_handles}}, "
            "{handle_positions}, {error})",
       doc="A handle rig's bone dual quaternions for one frame of handle positions (translation matrices None: "
           "the mapping's own translations)."),
    fn("kernel_cca", out("mapping", "d", "group_count*dimension*example_count"),
       out("offset", "d", "group_count*dimension"), out("correlations", "d", "group_count*basis_count"),
       inp("kernel", "d", "example_count*example_count"), inp("targets", "d", "example_count*group_count*dimension"),
       size("group_count", min=1), size("dimension", min=1), size("basis_count", min=1), real("ridge"), threads(),
       call="sk_kernel_cca({mapping}, {offset}, {correlations}, {kernel}, {targets}, {example_count}, {group_count}, "
            "{dimension}, {basis_count}, {ridge}, {thread_count}, {error})",
       doc="Regularised kernel CCA per target group with the fused regression: d = mapping_g k(x) + offset_g."),
    fn("handle_translation_solver", out("translation_rotations", "d", "3*bone_count*bone_count"),
       out("translation_handles", "d", "bone_count*handle_count"), influences(),
       inp("rest_positions", "d", "3*vertex_count"), inp("weights", "d", "influence_count"),
       inp("edges", "i", "2*edge_count"), inp("rotations", "d", "9*example_count*bone_count"),
       inp("example_positions", "d", "3*example_count*vertex_count"), inp("handle_vertices", "i", "handle_count"),
       size("bone_count", min=1), real("beta"), threads(), result("edge_error", "d"),
       call="sk_handle_translation_solver({translation_rotations}, {translation_handles}, {edge_error}, "
            "{influences}, {rest_positions}, {weights}, {edges}, {edge_count}, {rotations}, {example_positions}, "
            "{example_count}, {bone_count}, {handle_vertices}, {handle_count}, {beta}, {thread_count}, {error})",
       doc="The Poisson translation solver's prefactored matrices (eq. 2.10-2.11, Cholesky of A'A) and the rms "
           "edge error of the per-edge weight fit."),
    fn("suggest_handles", out("handle_vertices", "i", "handle_count"),
       inp("frames", "d", "3*frame_count*vertex_count"), size("frame_count", min=1), size("vertex_count", min=1),
       call="sk_suggest_handles({handle_vertices}, {frames}, {frame_count}, {vertex_count}, {handle_count}, {error})",
       doc="Control points from example frames: PCA, varimax, two extreme vertices per component."),
    # Baking normal maps and tangent maps
    fn("mikktspace_tangents", out("tangents", "d", "12*triangle_count"), inp("triangles", "i", "3*triangle_count"),
       inp("positions", "d", "3*vertex_count"), inp("normals", "d", "9*triangle_count"),
       inp("uv", "d", "6*triangle_count"),
       call="sk_mikktspace_tangents({tangents}, &(const sk_bake_surface){{triangles}, {positions}, {normals}, {uv}, "
            "{triangle_count}, {vertex_count}}, {error})",
       doc="MikkTSpace tangents (x, y, z, sign) of every corner 3 t + k, from corner normals and uv."),
    fn("bake_normals", out("image", "f", "3*size*size"), out("coverage", "B", "size*size"),
       opt_out("exact", "d", "3*size*size"), opt_out("frames", "d", "9*size*size"),
       inp("target_triangles", "i", "3*target_triangle_count"), inp("target_positions", "d", "3*target_vertex_count"),
       inp("target_normals", "d", "9*target_triangle_count"), inp("target_uv", "d", "6*target_triangle_count"),
       inp("tangents", "d", "12*target_triangle_count"),
       inp("source_triangles", "i", "3*source_triangle_count"), inp("source_positions", "d", "3*source_vertex_count"),
       inp("source_normals", "d", "9*source_triangle_count"), opt("source_uv", "d", "6*source_triangle_count"),
       size("size", min=1), integer("mode", min=0, max=2), size("supersample", min=1), size("margin"), real("cage"),
       threads(), progress(), report("sk_bake_report", "filled:n missed:n dilated:n empty:n"),
       call="sk_bake_normals({image}, {coverage}, {exact}, {frames}, {report}, &(const sk_bake_surface){{target_triangles}, "
            "{target_positions}, {target_normals}, {target_uv}, {target_triangle_count}, {target_vertex_count}}, "
            "{tangents}, &(const sk_bake_surface){{source_triangles}, {source_positions}, {source_normals}, "
            "{source_uv}, {source_triangle_count}, {source_vertex_count}}, &(sk_bake_options){{size}, {mode}, "
            "{supersample}, {margin}, {cage}, {thread_count}}, {progress}, {error})",
       doc="Tangent-space normal map of the source on the target (mode 0: the same uv point, 1: the nearest hit "
           "along the target normal within +-cage, 2: that hit's normal where it agrees with the same uv point's), "
           "encoded 0.5 n + 0.5, row 0 at the top (v = 1); coverage per "
           "texel (0 empty, 1 filled, 2 missed, 3 dilated); exact and frames (or None) get the object-space source "
           "normal and the target's (T, B, N) at each texel centre."),
    fn("bake_tangent_map", out("counts", "i", "size*size"), out("texel_bones", "i", "size*size*max_influences"),
       out("tangents", "d", "8*size*size*max_influences"), out("source_triangles", "i", "size*size"),
       out("coverage", "B", "size*size"),
       inp("target_triangles", "i", "3*target_triangle_count"), inp("target_positions", "d", "3*target_vertex_count"),
       inp("target_normals", "d", "9*target_triangle_count"), inp("target_uv", "d", "6*target_triangle_count"),
       inp("source_triangles_in", "i", "3*source_triangle_count"),
       inp("source_positions", "d", "3*vertex_count"), inp("source_normals", "d", "9*source_triangle_count"),
       inp("source_uv", "d", "6*source_triangle_count"), influences(), inp("coordinates", "d", "4*influence_count"),
       size("size", min=1), size("max_influences", min=1), threads(), progress(),
       call="sk_bake_tangent_map({counts}, {texel_bones}, {tangents}, {source_triangles}, {coverage}, "
            "&(const sk_bake_surface){{target_triangles}, {target_positions}, {target_normals}, {target_uv}, "
            "{target_triangle_count}, {target_vertex_count}}, &(const sk_bake_surface){{source_triangles_in}, "
            "{source_positions}, {source_normals}, {source_uv}, {source_triangle_count}, {vertex_count}}, "
            "{influences}, {coordinates}, {size}, {max_influences}, {thread_count}, {progress}, {error})",
       doc="Tangent map (section 7.5): per texel the source triangle's bones and the model's (dp/du, dp/dv) there, "
           "max_influences slots per texel padded with bone 0 and zeros; the influences are over the source's "
           "vertices."),
    fn("tangent_map_normals", out("image", "f", "3*texel_count"), inp("counts", "i", "texel_count"),
       inp("texel_bones", "i", "texel_count*max_influences"), inp("tangents", "d", "8*texel_count*max_influences"),
       inp("poses", "d", "16*bone_count"), size("max_influences", min=1), threads(),
       call="sk_tangent_map_normals({image}, {counts}, {texel_bones}, {tangents}, {poses}, {texel_count}, "
            "{max_influences}, {bone_count}, {thread_count}, {error})",
       doc="The object-space normal map of a tangent map in one pose: normalize(G t1 x G t2) per texel, encoded "
           "0.5 n + 0.5."),
    fn("tangent_map_downsample", out("counts_out", "i", "half_size*half_size"),
       out("bones_out", "i", "half_size*half_size*max_influences"),
       out("tangents_out", "d", "8*half_size*half_size*max_influences"), inp("counts", "i", "size*size"),
       inp("texel_bones", "i", "size*size*max_influences"), inp("tangents", "d", "8*size*size*max_influences"),
       opt("metric", "d", "16*bone_count*bone_count"),
       size("half_size", min=1), size("size", min=2), size("max_influences", min=1), size("bone_count"), threads(),
       call="sk_tangent_map_downsample({counts_out}, {bones_out}, {tangents_out}, {half_size}, {counts}, {texel_bones}, "
            "{tangents}, {size}, {max_influences}, {metric}, {bone_count}, {thread_count}, {error})",
       doc="The next mip level of a tangent map: each texel the bivector fit (appendix A.1) of its 2x2 block in "
           "the L2,2 metric of P's blocks (metric, as expectation_blocks writes them; None: Euclidean), the "
           "block's mean pair projected onto the fitted plane; half_size must be size / 2."),
    # Level of detail: the whole chain in one run (csrc/offline/lod/sk_progressive.c)
    fn("simplify_chain", out("triangles_out", "i", "3*level_count*triangle_count"),
       out("triangle_origin", "i", "level_count*triangle_count"),
       opt_out("uv_out", "d", "6*level_count*triangle_count"), opt_out("locked_out", "B", "3*level_count*triangle_count"),
       out("vertex_map", "i", "level_count*vertex_count"), out("offsets_out", "i", "level_count*vertex_count+1"),
       out("bones_out", "i", "level_count*influence_count"), out("coordinates_out", "d", "4*level_count*influence_count"),
       out("level_counts", "i", "5*level_count"), out("level_epsilon", "d", "level_count"),
       triangle_mesh(), inp("rest_positions", "d", "3*vertex_count"), influences(),
       inp("coordinates", "d", "4*influence_count"), pose_statistics(as_struct=True),
       opt("uv", "d", "6*triangle_count"), opt("charts", "i", "triangle_count"), opt("materials", "i", "triangle_count"),
       opt("locked", "B", "3*triangle_count"), size("level_count", min=1),
       opt("target_triangles", "i", "level_count"), opt("target_influences", "i", "level_count"),
       integer("metric", min=0, max=1), flag("simplify_influences"), real("straightness"), progress(),
       report("sk_simplify_chain_report", "level_count:n exhausted:i edge_collapses:n influence_collapses:n "
                                          "refused_flip:n refused_chart:n refused_seam:n refused_link:n "
                                          "refused_locked:n"),
       call="sk_simplify_chain({triangles_out}, {triangle_origin}, {uv_out}, {locked_out}, {vertex_map}, "
            "{offsets_out}, {bones_out}, {coordinates_out}, {level_counts}, {level_epsilon}, {report}, {mesh}, "
            "{rest_positions}, {influences}, {coordinates}, {statistics}, {uv}, {charts}, {materials}, {locked}, "
            "&(sk_simplify_chain_options){{level_count}, {target_triangles}, {target_influences}, {metric}, "
            "{simplify_influences}, {straightness}}, {progress}, {error})",
       doc="Every level of a chain in one run of the collapse queue (section 7.3): level l's outputs at l times the "
           "input's capacity, its influences rows offsets_out[l*V : (l+1)*V+1] of one CSR; level_counts per level: "
           "triangles, vertices, influences, edge and influence collapses since the level before; targets 0 or "
           "None: half the previous level's influences."),
    # Level of detail: a level refitted to the full detail (csrc/offline/lod/sk_refit.c)
    fn("lod_refit", out("coordinates_out", "d", "4*level_influence_count"),
       Group("level", "sk_triangle_mesh", (inp("level_triangles", "i", "3*level_triangle_count"),),
             ("level_triangles", "level_triangle_count", "level_vertex_count"), True),
       inp("level_rest", "d", "3*level_vertex_count"),
       Group("level_influences", "sk_influences", (inp("level_offsets", "i", "level_vertex_count+1"),
                                                   inp("level_bones", "i", "level_influence_count")),
             ("level_offsets", "level_bones", "level_vertex_count", "level_influence_count"), True),
       inp("level_coordinates", "d", "4*level_influence_count"),
       triangle_mesh(), inp("rest_positions", "d", "3*vertex_count"), influences(),
       inp("coordinates", "d", "4*influence_count"), pose_statistics(as_struct=True), real("pull"),
       size("max_steps"), real("tolerance"), threads(), progress(),
       report("sk_lod_refit_report", "samples:n unmatched:n steps:n influence_sets:n kept_factors:i start_residual:d "
                                     "final_residual:d"),
       call="sk_lod_refit({coordinates_out}, {report}, {level}, {level_rest}, {level_influences}, "
            "{level_coordinates}, {mesh}, {rest_positions}, {influences}, {coordinates}, {statistics}, "
            "&(sk_lod_refit_options){{pull}, {max_steps}, {tolerance}, {thread_count}}, {progress}, {error})",
       doc="A level's coordinates refitted to the full-detail surface (mesh): the least expected squared distance "
           "over the poses between the mesh's samples and their closest rest-pose points on the level, pulled "
           "towards level_coordinates by pull; at most max_steps CG steps."),
    # ---- choosing the per-vertex fit's lambda by cross-validation (issue 18, solvers) ----
    fn("validate_per_vertex", out("squared_errors", "d", "vertex_count*lambda_count"), influences(), examples(),
       size("fitted_tail"), size("fold_count", min=2), opt("prior", "d", "4*influence_count"),
       opt("fold_priors", "d", "4*influence_count*fold_count"), inp("lambdas", "d", "lambda_count"), threads(),
       call="sk_validate_per_vertex({squared_errors}, {influences}, {examples}, {fitted_tail}, {fold_count}, {prior}, "
            "{fold_priors}, {lambdas}, {lambda_count}, {thread_count}, {error})",
       doc="Cross-validated squared error (vertex_count, lambda_count) of the per-vertex fit for every lambda, one "
           "QR factorisation per vertex and fold reused across them; example e is validated in fold e % fold_count, "
           "the last fitted_tail examples are always fitted; fold_priors (one prior per fold, fitted without its "
           "examples) replace prior when given."),
    # Runtime, fixed-K layout (issue 13): 16-bit bones, no offsets, four vertices per SIMD step
    fn("runtime_skin_fixed", out("positions", "f", "3*output_count"), opt_out("tangent_0", "f", "3*output_count"),
       opt_out("tangent_1", "f", "3*output_count"), inp("fixed_bones", "H", "vertex_count*influences_per_vertex"),
       inp("fixed_positions", "f", "vertex_count*influences_per_vertex*floats_per_slot"),
       opt("fixed_tangent_0", "f", "vertex_count*influences_per_vertex*floats_per_slot"),
       opt("fixed_tangent_1", "f", "vertex_count*influences_per_vertex*floats_per_slot"),
       inp("mesh_starts", "i", "mesh_count+1"), size("vertex_count"), size("influences_per_vertex", min=2),
       size("floats_per_slot"), inp("meshes", "i", "instance_count"), inp("fractions", "f", "instance_count"),
       size("bone_count", min=1), inp("matrices", "f", "12*instance_count*bone_count"),
       inp("output_starts", "i", "instance_count+1"), integer("kernel", min=0, max=3), threads(),
       call="sk_runtime_skin_fixed({positions}, {tangent_0}, {tangent_1}, {output_count}, "
            "&(const sk_runtime_fixed_pack){{fixed_bones}, {fixed_positions}, {fixed_tangent_0}, {fixed_tangent_1}, "
            "{mesh_starts}, {mesh_count}, {vertex_count}, {influences_per_vertex}, {floats_per_slot}}, "
            "&(const sk_runtime_instances){{meshes}, {fractions}, {matrices}, {output_starts}, {instance_count}, "
            "{bone_count}}, {kernel}, {thread_count}, {error})",
       doc="sk_runtime_skin over a fixed-K pack: K slots per vertex (even), 16-bit bones, per pair of slots "
           "(p, p, dp, dp) (floats_per_slot 8) or (p, p) (4, no geomorph: fractions 0)."),
    # Limit Influences in a given metric (issue 11)
    fn("limit_influences_in_metric", out("limited_offsets", "i", "vertex_count+1"),
       out("limited_bones", "i", "influence_count"), out("limited_coordinates", "d", "4*influence_count"),
       opt_out("costs", "d", "vertex_count"), opt_out("limited_tangents", "d", "4*tangent_count*influence_count"),
       influences(), inp("coordinates", "d", "4*influence_count"),
       opt("tangents", "d", "4*tangent_count*influence_count"), size("tangent_count"),
       inp("metric_blocks", "d", "16*bone_count*bone_count"), size("bone_count", min=1),
       size("max_influences", min=1), threads(), progress(), result("limited_count", "n"),
       call="sk_limit_influences_in_metric({limited_offsets}, {limited_bones}, {limited_coordinates}, "
            "{limited_count}, {costs}, {limited_tangents}, {influences}, {coordinates}, {tangents}, {tangent_count}, "
            "{metric_blocks}, {bone_count}, {max_influences}, {thread_count}, {progress}, {error})",
       doc="limit_influences with P given as bone_count^2 4x4 blocks (P_jk at 16 * (j * bone_count + k)), e.g. "
           "sample second moments E[G_j^T G_k]."),
    # Hierarchical triangle clustering for handle rigs' proxy bones (issue 14)
    fn("triangle_cluster_merges", out("merges", "i", "2*merge_count"), out("costs", "d", "merge_count"),
       inp("triangles", "i", "3*triangle_count"), inp("rest_positions", "d", "3*vertex_count"),
       inp("frames", "d", "3*frame_count*vertex_count"), real("edge_weight"), progress(),
       call="sk_triangle_cluster_merges({merges}, {costs}, {merge_count}, {triangles}, {triangle_count}, {rest_positions}, "
            "{vertex_count}, {frames}, {frame_count}, {edge_weight}, {progress}, {error})",
       doc="The merge order of the hierarchical triangle clustering (merge m joins merges[2m+1] into merges[2m], "
           "adding costs[m] to the rigid-fit error); merge_count = triangle_count - 1; the first triangle_count - k "
           "merges leave k clusters."),
    # Level of detail: the tuned chain (issue 11: full-edge collapses, the queue's influence weighting)
    fn("simplify_chain_tuned", out("triangles_out", "i", "3*level_count*triangle_count"),
       out("triangle_origin", "i", "level_count*triangle_count"),
       opt_out("uv_out", "d", "6*level_count*triangle_count"), opt_out("locked_out", "B", "3*level_count*triangle_count"),
       out("vertex_map", "i", "level_count*vertex_count"), out("offsets_out", "i", "level_count*vertex_count+1"),
       out("bones_out", "i", "level_count*influence_count"), out("coordinates_out", "d", "4*level_count*influence_count"),
       out("level_counts", "i", "5*level_count"), out("level_epsilon", "d", "level_count"),
       out("level_full_collapses", "i", "level_count"),
       triangle_mesh(), inp("rest_positions", "d", "3*vertex_count"), influences(),
       inp("coordinates", "d", "4*influence_count"), pose_statistics(as_struct=True),
       opt("uv", "d", "6*triangle_count"), opt("charts", "i", "triangle_count"), opt("materials", "i", "triangle_count"),
       opt("locked", "B", "3*triangle_count"), size("level_count", min=1),
       opt("target_triangles", "i", "level_count"), opt("target_influences", "i", "level_count"),
       integer("metric", min=0, max=1), flag("simplify_influences"), real("straightness"),
       integer("collapse", min=0, max=2), flag("rank_per_influence"), real("influence_cost_scale"), threads(),
       progress(),
       report("sk_simplify_chain_report", "level_count:n exhausted:i edge_collapses:n influence_collapses:n "
                                          "refused_flip:n refused_chart:n refused_seam:n refused_link:n "
                                          "refused_locked:n"),
       call="sk_simplify_chain_tuned({triangles_out}, {triangle_origin}, {uv_out}, {locked_out}, {vertex_map}, "
            "{offsets_out}, {bones_out}, {coordinates_out}, {level_counts}, {level_epsilon}, {report}, "
            "{level_full_collapses}, {mesh}, {rest_positions}, {influences}, {coordinates}, {statistics}, {uv}, "
            "{charts}, {materials}, {locked}, &(sk_simplify_chain_options){{level_count}, {target_triangles}, "
            "{target_influences}, {metric}, {simplify_influences}, {straightness}}, "
            "&(sk_simplify_tuning){{collapse}, {influence_cost_scale}, {rank_per_influence}, {thread_count}}, "
            "{progress}, {error})",
       doc="simplify_chain with full-edge collapses and the queue's ranking (sk_simplify_chain_tuned): "
           "collapse 0 half, 1 full, 2 auto; rank_per_influence ranks an edge collapse at its cost / sqrt(influences "
           "it removes); influence collapses ranked at their cost times "
           "influence_cost_scale; level_full_collapses per level: the full collapses among its edge collapses."),
    # Seam reconstruction per frame, Algorithm 5 (csrc/offline/skeleton/sk_seam_fill.c, issue 15)
    fn("reconstruct_seams", out("positions", "d", "3*frame_count*position_capacity"),
       out("triangles", "i", "3*frame_count*triangle_capacity"), out("normals", "d", "3*frame_count*position_capacity"),
       out("frame_counts", "i", "6*frame_count"), out("frame_seconds", "d", "4*frame_count"),
       inp("rest_positions", "d", "3*vertex_count"), inp("joints", "d", "3*part_count"),
       inp("sources", "i", "point_count"), inp("parts_a", "i", "point_count"), inp("parts_b", "i", "point_count"),
       inp("blend", "d", "point_count"), inp("seam_triangles", "i", "3*triangle_count"),
       inp("twins", "i", "3*triangle_count"), inp("cap_members", "i", "2*cap_member_count"), inp("columns", "i", "column_count*column_width"),
       size("column_width"), inp("ring_offsets", "i", "point_count+1"), inp("ring", "i", "ring_size"),
       inp("boxes", "d", "15*part_count"), inp("seam_parts", "i", "2*seam_count"),
       inp("start_offsets", "i", "2*seam_count+1"), inp("starts", "i", "start_size"),
       inp("planes", "d", "6*seam_count"),
       inp("world", "d", "16*part_count*frame_count"), size("position_capacity", min=1),
       size("triangle_capacity", min=1), flag("remove_sinking"), flag("conic_arcs"), progress(),
       call="sk_reconstruct_seams({positions}, {triangles}, {normals}, {frame_counts}, {frame_seconds}, "
            "&(const sk_seam_topology){{rest_positions}, {vertex_count}, {joints}, {part_count}, {sources}, "
            "{parts_a}, {parts_b}, {blend}, {point_count}, {seam_triangles}, {twins}, {triangle_count}, "
            "{cap_members}, {cap_member_count}, {columns}, {column_count}, {column_width}}, "
            "&(const sk_seam_removal){{ring_offsets}, {ring}, {boxes}, {seam_parts}, {start_offsets}, {starts}, "
            "{planes}, {seam_count}}, {world}, {frame_count}, {position_capacity}, {triangle_capacity}, {remove_sinking}, "
            "{conic_arcs}, {progress}, {error})",
       doc="Algorithm 5 per frame on the fixed seam topology: add (arcs, optionally conic), remove sinking points, "
           "fill the holes, normals; per frame counts (points, triangles, removed, fill points, conic columns, "
           "fallback) and seconds (add, remove, triangulate, normals)."),
    fn("conic_arc", out("points", "d", "3*point_count"), out("weight", "d", "1"), inp("start", "d", "3"),
       inp("start_tangent", "d", "3"), inp("end", "d", "3"), inp("end_tangent", "d", "3"), inp("through", "d", "3"),
       size("point_count"),
       call="sk_conic_arc({points}, {weight}, {point_count}, {start}, {start_tangent}, {end}, {end_tangent}, "
            "{through}, {error})",
       doc="The Fudos-Hoffmann conic arc (section 2.1.3, M2 corrected) from start to end with tangents pointing at "
           "their crossing, through a point: point_count points at equal arc lengths and the middle weight."),
]
