/*
 * Skinning a mesh sequence without a usable rig: bone motions from core vertices and rest joints
 * (Merry 2007, section 4.1.4), rigid bone transforms that best reproduce target frames with a fixed model
 * (the transform step of a skinning decomposition, and replaying held-out frames), and ranking the bones
 * whose rigid motion best explains each vertex (clustering and influence candidates).
 */
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_internal.h"
#include "sk_math.h"

/* ---------------------------------------------------------------------------------------------
 * Small dense helpers
 * ------------------------------------------------------------------------------------------- */

/* out = top three rows of matrix * (a, w). */
static void transform_point(double out[3], const double matrix[16], const double a[3], double w)
{
    for (int r = 0; r < 3; ++r)
        out[r] = matrix[4 * r] * a[0] + matrix[4 * r + 1] * a[1] + matrix[4 * r + 2] * a[2] + matrix[4 * r + 3] * w;
}

/* Checks the a * b * c values of an array the caller describes by counts, naming the group of `group` values
 * (a vertex, a frame, a motion) that holds the first NaN or infinity. */
static sk_status check_finite_array(const double *values, size_t a, size_t b, size_t c, size_t group, const char *what,
                                    sk_error *error)
{
    size_t count;
    const sk_status status = sk_array_size(&count, a, b, c, what, error);
    if (status != SK_OK)
        return status;
    const size_t bad = sk_first_non_finite(values, count);
    if (bad < count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "%s %zu has a NaN or infinity", what, bad / group);
    return SK_OK;
}

/* ---------------------------------------------------------------------------------------------
 * Bone motions from core vertices (section 4.1.4, steps 2-4)
 * ------------------------------------------------------------------------------------------- */

/* Rejects a core set that cannot fix a rotation: fewer than three vertices or (nearly) collinear ones. */
static sk_status check_core_spread(const double *rest, const int32_t *core, size_t count, size_t bone,
                                   sk_error *error)
{
    if (count < 3)
        return sk_fail(error, SK_ERROR_RANK, "bone %zu: %zu core vertices; at least 3 that are not in a line are needed",
                       bone, count);
    double centre[3] = {0, 0, 0}, scatter[9] = {0}, singular[3];
    for (size_t k = 0; k < count; ++k)
        for (int c = 0; c < 3; ++c)
            centre[c] += rest[3 * (size_t)core[k] + (size_t)c] / (double)count;
    for (size_t k = 0; k < count; ++k) {
        double d[3];
        for (int c = 0; c < 3; ++c)
            d[c] = rest[3 * (size_t)core[k] + (size_t)c] - centre[c];
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c)
                scatter[3 * r + c] += d[r] * d[c];
    }
    sk_svd3(singular, NULL, NULL, scatter);
    if (!(singular[1] > 1e-12 * singular[0]) || singular[0] == 0.0)
        return sk_fail(error, SK_ERROR_RANK,
                       "bone %zu: its %zu core vertices lie on a line (or a point), so they cannot fix its rotation",
                       bone, count);
    return SK_OK;
}

/*
 * One bone in one frame: the affine map that best carries the core's rest positions to the frame (eq. 4.5,
 * minimum-norm least squares by dgelsd, so a planar core still gives an answer), its rotation, then the
 * translation refitted for that rotation.
 */
static sk_status core_motion(double motion[16], const double *rest, const double *target, const int32_t *core,
                             size_t count, size_t bone, size_t frame, double *scratch, sk_error *error)
{
    double *a = scratch, *b = scratch + 4 * count;
    for (size_t k = 0; k < count; ++k) {
        const size_t vertex = (size_t)core[k];
        for (int c = 0; c < 3; ++c) {
            a[4 * k + (size_t)c] = rest[3 * vertex + (size_t)c];
            b[3 * k + (size_t)c] = target[3 * vertex + (size_t)c];
        }
        a[4 * k + 3] = 1.0;
    }
    double singular[4];
    lapack_int rank = 0;
    if (LAPACKE_dgelsd(LAPACK_ROW_MAJOR, (lapack_int)count, 4, 3, a, 4, b, 3, singular, 1e-12, &rank) != 0)
        return sk_fail(error, SK_ERROR_LAPACK, "bone %zu, frame %zu: LAPACK dgelsd failed", bone, frame);
    double linear[9], rotation[9], translation[3] = {0, 0, 0};
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            linear[3 * r + c] = b[3 * c + r]; /* b holds M^T: row c of it is column c of M */
    sk_nearest_rotation3(rotation, linear);
    for (size_t k = 0; k < count; ++k) {
        const size_t vertex = (size_t)core[k];
        double rotated[3];
        transform_point(rotated, (double[16]){rotation[0], rotation[1], rotation[2], 0, rotation[3], rotation[4],
                                              rotation[5], 0, rotation[6], rotation[7], rotation[8], 0},
                        rest + 3 * vertex, 0.0);
        for (int c = 0; c < 3; ++c)
            translation[c] += (target[3 * vertex + (size_t)c] - rotated[c]) / (double)count;
    }
    sk_rigid_matrix(motion, rotation, translation);
    return SK_OK;
}

sk_status sk_fit_core_motions(double *motions, const int32_t *core_offsets, const int32_t *core_vertices,
                              const double *rest_positions, const double *frames, size_t vertex_count,
                              size_t core_count, size_t frame_count, size_t bone_count, sk_error *error)
{
    if (!motions || !core_offsets || !rest_positions || !frames || vertex_count == 0 || frame_count == 0 ||
        bone_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "core motions need vertices, at least one frame and one bone");
    /* the core sets are a CSR pattern by bone whose entries are vertices */
    const sk_influences cores = {core_offsets, core_vertices, bone_count, core_count};
    sk_status status = sk_validate_influences(&cores, vertex_count, error);
    if (status != SK_OK)
        return status;
    if ((status = check_finite_array(rest_positions, vertex_count, 3, 1, 3, "rest vertex", error)) != SK_OK ||
        (status = check_finite_array(frames, frame_count, vertex_count, 3, 3 * vertex_count, "frame", error)) != SK_OK)
        return status;
    size_t largest = 0;
    for (size_t bone = 1; bone < bone_count; ++bone) {
        const size_t count = (size_t)(core_offsets[bone + 1] - core_offsets[bone]);
        largest = count > largest ? count : largest;
        if ((status = check_core_spread(rest_positions, core_vertices + core_offsets[bone], count, bone, error)) != SK_OK)
            return status;
    }
    /* dgelsd wants the right-hand side padded to max(rows, columns) rows */
    double *scratch = sk_allocate(7 * largest + 12, sizeof *scratch);
    if (!scratch)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the core fits");
    for (size_t frame = 0; frame < frame_count && status == SK_OK; ++frame) {
        sk_rigid_matrix(motions + 16 * frame * bone_count, (double[9]){1, 0, 0, 0, 1, 0, 0, 0, 1}, (double[3]){0, 0, 0});
        for (size_t bone = 1; bone < bone_count && status == SK_OK; ++bone)
            status = core_motion(motions + 16 * (frame * bone_count + bone), rest_positions,
                                 frames + 3 * vertex_count * frame, core_vertices + core_offsets[bone],
                                 (size_t)(core_offsets[bone + 1] - core_offsets[bone]), bone, frame, scratch, error);
    }
    free(scratch);
    return status == SK_OK ? sk_succeed(error) : status;
}

/* ---------------------------------------------------------------------------------------------
 * Rest joints (section 4.1.4, eq. 4.6, solved top-down)
 * ------------------------------------------------------------------------------------------- */

/* Bones ordered so that every parent comes before its children (parents already validated as a tree). */
static void top_down_order(size_t *order, const int32_t *parents, size_t bone_count, unsigned char *placed)
{
    size_t filled = 0;
    memset(placed, 0, bone_count);
    while (filled < bone_count)
        for (size_t bone = 0; bone < bone_count; ++bone)
            if (!placed[bone] && (parents[bone] < 0 || placed[parents[bone]])) {
                placed[bone] = 1;
                order[filled++] = bone;
            }
}

/*
 * For joint j with parent f: in frame p, M_f^-1 M_j = (A_p, c_p) and the joint's translation relative to its
 * parent is L_p = -h_f + c_p + A_p h_j (eq. 4.6). Minimise sum_p |L_p - m|^2 + lambda^2 |h_j - u_j|^2 over
 * (h_j, m): the 6x6 normal equations, solved by Cholesky.
 */
static sk_status rest_joint(double joint[3], const double *motions, size_t bone, size_t parent, const double parent_joint[3],
                            const double approximate[3], size_t frame_count, size_t bone_count, double lambda,
                            sk_error *error)
{
    double normal[36] = {0}, rhs[6] = {0};
    for (size_t frame = 0; frame < frame_count; ++frame) {
        double parent_inverse[16], relative[16];
        if (!sk_affine_inverse(parent_inverse, motions + 16 * (frame * bone_count + parent)))
            return sk_fail(error, SK_ERROR_SINGULAR, "bone %zu, frame %zu: the motion is singular", parent, frame);
        sk_multiply4(relative, parent_inverse, motions + 16 * (frame * bone_count + bone));
        /* rows [A_p, -I] x = h_f - c_p, x = (h_j, m) */
        for (int r = 0; r < 3; ++r) {
            double row[6] = {0};
            for (int c = 0; c < 3; ++c)
                row[c] = relative[4 * r + c];
            row[3 + r] = -1.0;
            const double value = parent_joint[r] - relative[4 * r + 3];
            for (int a = 0; a < 6; ++a) {
                rhs[a] += row[a] * value;
                for (int b = 0; b < 6; ++b)
                    normal[6 * a + b] += row[a] * row[b];
            }
        }
    }
    for (int c = 0; c < 3; ++c) {
        normal[7 * c] += lambda * lambda;
        rhs[c] += lambda * lambda * approximate[c];
    }
    if (LAPACKE_dposv(LAPACK_ROW_MAJOR, 'U', 6, 1, normal, 6, rhs, 1) != 0)
        return sk_fail(error, SK_ERROR_RANK, "bone %zu: its joint position is not determined (use lambda > 0)", bone);
    memcpy(joint, rhs, 3 * sizeof *joint);
    return SK_OK;
}

sk_status sk_fit_rest_joints(double *joints, const double *motions, const int32_t *parents,
                             const double *approximate_joints, size_t frame_count, size_t bone_count, double lambda,
                             sk_error *error)
{
    if (!joints || !motions || !approximate_joints || frame_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "rest joints need motions for at least one frame");
    if (!(lambda >= 0.0) || !isfinite(lambda))
        return sk_fail(error, SK_ERROR_ARGUMENT, "lambda must be finite and >= 0, got %g", lambda);
    sk_status status = sk_validate_skeleton(parents, NULL, bone_count, error);
    if (status != SK_OK)
        return status;
    if ((status = check_finite_array(motions, frame_count, bone_count, 16, 16, "motion", error)) != SK_OK ||
        (status = check_finite_array(approximate_joints, bone_count, 3, 1, 3, "approximate joint of bone", error)) != SK_OK)
        return status;
    size_t *order = sk_allocate(bone_count, sizeof *order);
    unsigned char *placed = sk_allocate(bone_count, 1);
    if (!order || !placed) {
        free(order);
        free(placed);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory");
    }
    top_down_order(order, parents, bone_count, placed);
    joints[0] = joints[1] = joints[2] = 0.0; /* the root is model space */
    for (size_t k = 1; k < bone_count && status == SK_OK; ++k) {
        const size_t bone = order[k], parent = (size_t)parents[bone];
        status = rest_joint(joints + 3 * bone, motions, bone, parent, joints + 3 * parent, approximate_joints + 3 * bone,
                            frame_count, bone_count, lambda, error);
    }
    free(order);
    free(placed);
    return status == SK_OK ? sk_succeed(error) : status;
}

/* ---------------------------------------------------------------------------------------------
 * Rigid bone transforms for a fixed model (block coordinate descent, one bone at a time)
 * ------------------------------------------------------------------------------------------- */

typedef struct pose_problem {
    const int32_t *offsets, *bones;
    const double *coordinates, *targets;
    size_t vertex_count, influence_count, frame_count, bone_count;
    int sweeps;
    /* bone-major copy: bone j's influences are slots bone_offsets[j] .. bone_offsets[j + 1] - 1, each with its
     * vertex and its 4 coordinates, so a bone's update streams them instead of gathering them from the
     * vertex-major arrays (a cache line per influence at 1M vertices) */
    size_t *bone_offsets, *bone_vertices;
    double *bone_coordinates;
    double *poses, *frame_errors;
    int out_of_memory; /* a worker could not allocate its frame positions */
} pose_problem;

/* Counts each bone's influences, then fills its slots in vertex order (the order the solve sums them in). */
static int gather_by_bone(pose_problem *p)
{
    p->bone_offsets = sk_allocate_zeroed(p->bone_count + 1, sizeof *p->bone_offsets);
    p->bone_vertices = sk_allocate(p->influence_count + 1, sizeof *p->bone_vertices);
    p->bone_coordinates = sk_allocate(p->influence_count + 1, 4 * sizeof *p->bone_coordinates);
    size_t *fill = sk_allocate_zeroed(p->bone_count + 1, sizeof *fill);
    if (!p->bone_offsets || !p->bone_vertices || !p->bone_coordinates || !fill) {
        free(fill);
        return 0;
    }
    for (size_t k = 0; k < p->influence_count; ++k)
        ++p->bone_offsets[p->bones[k] + 1];
    for (size_t j = 0; j < p->bone_count; ++j)
        p->bone_offsets[j + 1] += p->bone_offsets[j];
    for (size_t vertex = 0; vertex < p->vertex_count; ++vertex)
        for (size_t k = (size_t)p->offsets[vertex]; k < (size_t)p->offsets[vertex + 1]; ++k) {
            const size_t j = (size_t)p->bones[k], slot = p->bone_offsets[j] + fill[j]++;
            p->bone_vertices[slot] = vertex;
            memcpy(p->bone_coordinates + 4 * slot, p->coordinates + 4 * k, 4 * sizeof *p->bone_coordinates);
        }
    free(fill);
    return 1;
}

static void evaluate_frame(double *current, const pose_problem *p, const double *poses)
{
    for (size_t vertex = 0; vertex < p->vertex_count; ++vertex) {
        double sum[3] = {0, 0, 0};
        for (size_t k = (size_t)p->offsets[vertex]; k < (size_t)p->offsets[vertex + 1]; ++k) {
            double moved[3];
            const double *q = p->coordinates + 4 * k;
            transform_point(moved, poses + 16 * (size_t)p->bones[k], q, q[3]);
            for (int c = 0; c < 3; ++c)
                sum[c] += moved[c];
        }
        memcpy(current + 3 * vertex, sum, sizeof sum);
    }
}

/*
 * Bone j's best rigid transform with the other bones fixed: with a = xyz and w = weight of each p_ij and r the
 * target minus the other bones' contributions, minimise sum |R a + w t - r|^2. t = (sum w r - R sum w a) / sum w^2
 * leaves a Procrustes problem on the cross-covariance M = sum r a^T - (sum w r)(sum w a)^T / sum w^2. A small pull
 * towards the previous rotation keeps directions the data do not fix (collinear influences) where they were.
 */
static void update_bone(double *pose, const pose_problem *p, size_t bone, const double *target, double *current)
{
    double sww = 0.0, swa[3] = {0, 0, 0}, swr[3] = {0, 0, 0}, m[9] = {0}, saa = 0.0;
    for (size_t slot = p->bone_offsets[bone]; slot < p->bone_offsets[bone + 1]; ++slot) {
        const size_t vertex = p->bone_vertices[slot];
        const double *q = p->bone_coordinates + 4 * slot;
        double own[3], r[3];
        transform_point(own, pose, q, q[3]);
        for (int c = 0; c < 3; ++c)
            r[c] = target[3 * vertex + (size_t)c] - current[3 * vertex + (size_t)c] + own[c];
        sww += q[3] * q[3];
        for (int c = 0; c < 3; ++c) {
            swa[c] += q[3] * q[c];
            swr[c] += q[3] * r[c];
            saa += q[c] * q[c];
            for (int d = 0; d < 3; ++d)
                m[3 * c + d] += r[c] * q[d];
        }
    }
    if (p->bone_offsets[bone] == p->bone_offsets[bone + 1])
        return;
    double translation[3] = {pose[3], pose[7], pose[11]}, rotation[9], old[16];
    const int has_weight = sww > 1e-12 * (saa > 1.0 ? saa : 1.0);
    for (int c = 0; c < 3; ++c)
        for (int d = 0; d < 3; ++d) {
            m[3 * c + d] -= has_weight ? swr[c] * swa[d] / sww : translation[c] * swa[d];
            m[3 * c + d] += 1e-12 * saa * pose[4 * c + d];
        }
    sk_nearest_rotation3(rotation, m);
    if (has_weight)
        for (int c = 0; c < 3; ++c)
            translation[c] = (swr[c] - (rotation[3 * c] * swa[0] + rotation[3 * c + 1] * swa[1] +
                                        rotation[3 * c + 2] * swa[2])) / sww;
    memcpy(old, pose, sizeof old);
    sk_rigid_matrix(pose, rotation, translation);
    for (size_t slot = p->bone_offsets[bone]; slot < p->bone_offsets[bone + 1]; ++slot) {
        const size_t vertex = p->bone_vertices[slot];
        const double *q = p->bone_coordinates + 4 * slot;
        double before[3], after[3];
        transform_point(before, old, q, q[3]);
        transform_point(after, pose, q, q[3]);
        for (int c = 0; c < 3; ++c)
            current[3 * vertex + (size_t)c] += after[c] - before[c];
    }
}

static void solve_frame_range(void *context, size_t worker, size_t begin, size_t end)
{
    (void)worker;
    pose_problem *p = context;
    double *current = sk_allocate(3 * p->vertex_count, sizeof *current);
    if (!current) {
        p->out_of_memory = 1;
        return;
    }
    for (size_t frame = begin; frame < end; ++frame) {
        double *poses = p->poses + 16 * frame * p->bone_count;
        const double *target = p->targets + 3 * frame * p->vertex_count;
        evaluate_frame(current, p, poses);
        for (int sweep = 0; sweep < p->sweeps; ++sweep)
            for (size_t bone = 1; bone < p->bone_count; ++bone)
                update_bone(poses + 16 * bone, p, bone, target, current);
        if (p->frame_errors) {
            double sum = 0.0;
            for (size_t k = 0; k < 3 * p->vertex_count; ++k)
                sum += (current[k] - target[k]) * (current[k] - target[k]);
            p->frame_errors[frame] = sum;
        }
    }
    free(current);
}

sk_status sk_solve_rigid_poses(double *poses, double *frame_errors, const sk_influences *influences,
                               const double *coordinates, const double *targets, size_t frame_count, size_t bone_count,
                               int sweeps, int thread_count, sk_error *error)
{
    if (!poses || !influences || !coordinates || !targets || influences->vertex_count == 0 || frame_count == 0 ||
        bone_count == 0 || sweeps < 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "solving poses needs vertices, frames, bones and sweeps >= 0");
    const int32_t *offsets = influences->offsets, *bones = influences->bones;
    const size_t vertex_count = influences->vertex_count, influence_count = influences->influence_count;
    sk_status status = sk_validate_influences(influences, bone_count, error);
    if (status != SK_OK)
        return status;
    if ((status = check_finite_array(coordinates, influence_count, 4, 1, 4, "influence", error)) != SK_OK ||
        (status = check_finite_array(targets, frame_count, vertex_count, 3, 3 * vertex_count, "frame", error)) != SK_OK ||
        (status = check_finite_array(poses, frame_count, bone_count, 16, 16 * bone_count, "starting pose of frame",
                                     error)) != SK_OK)
        return status;
    pose_problem p = {offsets, bones, coordinates, targets, vertex_count, influence_count, frame_count, bone_count,
                      sweeps, NULL, NULL, NULL, poses, frame_errors, 0};
    if (!gather_by_bone(&p))
        status = sk_fail(error, SK_ERROR_MEMORY, "out of memory for the bones' influence lists");
    else
        sk_parallel_for(frame_count, 1, thread_count, solve_frame_range, &p);
    free(p.bone_offsets);
    free(p.bone_vertices);
    free(p.bone_coordinates);
    if (status != SK_OK)
        return status;
    if (p.out_of_memory)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for a frame's positions");
    return sk_succeed(error);
}

/* ---------------------------------------------------------------------------------------------
 * Ranking bones by how well their rigid motion explains each vertex
 * ------------------------------------------------------------------------------------------- */

typedef struct ranking {
    int32_t *best_bones;
    double *best_errors;
    const double *rest, *frames, *motions;
    const unsigned char *allowed;
    size_t vertex_count, frame_count, bone_count, candidate_count;
} ranking;

static void rank_vertex_range(void *context, size_t worker, size_t begin, size_t end)
{
    (void)worker;
    const ranking *g = context;
    const size_t keep = g->candidate_count;
    for (size_t vertex = begin; vertex < end; ++vertex) {
        int32_t *best = g->best_bones + keep * vertex;
        double *errors = g->best_errors + keep * vertex;
        for (size_t s = 0; s < keep; ++s) {
            best[s] = -1;
            errors[s] = INFINITY;
        }
        for (size_t bone = 0; bone < g->bone_count; ++bone) {
            if (g->allowed && !g->allowed[vertex * g->bone_count + bone])
                continue;
            double total = 0.0;
            for (size_t frame = 0; frame < g->frame_count && total < errors[keep - 1]; ++frame) {
                double moved[3];
                transform_point(moved, g->motions + 16 * (frame * g->bone_count + bone), g->rest + 3 * vertex, 1.0);
                const double *target = g->frames + 3 * (frame * g->vertex_count + vertex);
                for (int c = 0; c < 3; ++c)
                    total += (moved[c] - target[c]) * (moved[c] - target[c]);
            }
            if (!(total < errors[keep - 1]))
                continue;
            size_t s = keep - 1;
            for (; s > 0 && errors[s - 1] > total; --s) {
                errors[s] = errors[s - 1];
                best[s] = best[s - 1];
            }
            errors[s] = total;
            best[s] = (int32_t)bone;
        }
    }
}

sk_status sk_rank_bones(int32_t *best_bones, double *best_errors, const double *rest_positions, const double *frames,
                        const double *motions, const unsigned char *allowed, size_t vertex_count, size_t frame_count,
                        size_t bone_count, size_t candidate_count, int thread_count, sk_error *error)
{
    if (!best_bones || !best_errors || !rest_positions || !frames || !motions || vertex_count == 0 || frame_count == 0 ||
        bone_count == 0 || candidate_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "ranking bones needs vertices, frames, bones and candidates");
    if (bone_count > (size_t)INT32_MAX)
        return sk_fail(error, SK_ERROR_ARGUMENT, "too many bones: %zu", bone_count);
    size_t unused;
    sk_status status;
    if ((status = sk_array_size(&unused, vertex_count, candidate_count, 1, "best bones", error)) != SK_OK ||
        (status = sk_array_size(&unused, vertex_count, bone_count, 1, "allowed", error)) != SK_OK ||
        (status = check_finite_array(rest_positions, vertex_count, 3, 1, 3, "rest vertex", error)) != SK_OK ||
        (status = check_finite_array(frames, frame_count, vertex_count, 3, 3 * vertex_count, "frame", error)) != SK_OK ||
        (status = check_finite_array(motions, frame_count, bone_count, 16, 16 * bone_count, "motion of frame",
                                     error)) != SK_OK)
        return status;
    ranking g = {best_bones, best_errors, rest_positions, frames, motions, allowed, vertex_count, frame_count,
                 bone_count, candidate_count};
    sk_parallel_for(vertex_count, SK_SOLVE_ITEMS_PER_WORKER, thread_count, rank_vertex_range, &g);
    return sk_succeed(error);
}
