/*
 * Forward kinematics, collision tests and seam evaluation for rigid parts (Vasilakis 2008, sections 2.2, 4.3-4.4):
 * QT pairs (unit quaternion, translation) per joint, the thesis' quaternion-to-matrix with its two typos fixed
 * (entries (2,3) and (3,2) are 2yz - 2sx and 2yz + 2sx), bounding spheres then the 15-axis separating-axis test
 * between oriented boxes, and QLERP about a joint for the points that close a seam. Nothing here allocates.
 */
#include <math.h>
#include <string.h>

#include "sk_math.h"
#include "sk_skeleton_internal.h"

static const double PI = 3.14159265358979323846;

/* q = (s, x, y, z). */
static void quaternion_multiply(double out[4], const double a[4], const double b[4])
{
    const double s = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    const double x = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    const double y = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    const double z = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
    out[0] = s, out[1] = x, out[2] = y, out[3] = z;
}

static void axis_quaternion(double q[4], int axis, double degrees)
{
    const double half = 0.5 * degrees * PI / 180.0;
    q[0] = cos(half);
    q[1] = q[2] = q[3] = 0.0;
    q[1 + axis] = sin(half);
}

/* The shortest-arc rotation taking the direction a onto +z (the digest's replacement for the thesis' two-angle
 * alignment, which fails when a lies along x). */
static void align_to_z(double q[4], const double a[3])
{
    const double length = sqrt(sk_dot3(a, a));
    if (!(length > 1e-300)) {
        q[0] = 1.0, q[1] = q[2] = q[3] = 0.0;
        return;
    }
    const double u[3] = {a[0] / length, a[1] / length, a[2] / length};
    if (u[2] < -1.0 + 1e-12) { /* opposite: half a turn about x */
        q[0] = 0.0, q[1] = 1.0, q[2] = q[3] = 0.0;
        return;
    }
    /* q = (1 + u.z, u x z) normalised */
    double v[4] = {1.0 + u[2], u[1], -u[0], 0.0};
    const double norm = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int k = 0; k < 4; ++k)
        q[k] = v[k] / norm;
}

/* The rotation matrix of q (any length: the homogeneous form divided by q.q, as eq. 4.1's QLERP needs). */
static void quaternion_matrix(double m[9], const double q[4])
{
    const double s = q[0], x = q[1], y = q[2], z = q[3], n = s * s + x * x + y * y + z * z;
    const double k = n > 0.0 ? 1.0 / n : 0.0;
    m[0] = (s * s + x * x - y * y - z * z) * k, m[1] = 2 * (x * y - s * z) * k, m[2] = 2 * (x * z + s * y) * k;
    m[3] = 2 * (x * y + s * z) * k, m[4] = (s * s - x * x + y * y - z * z) * k, m[5] = 2 * (y * z - s * x) * k;
    m[6] = 2 * (x * z - s * y) * k, m[7] = 2 * (y * z + s * x) * k, m[8] = (s * s - x * x - y * y + z * z) * k;
}

/* The unit quaternion of a rotation matrix (Shepperd's method: the largest of the four squares first). */
static void matrix_quaternion(double q[4], const double m[9])
{
    const double trace = m[0] + m[4] + m[8];
    if (trace > m[0] && trace > m[4] && trace > m[8]) {
        const double r = sqrt(1.0 + trace);
        q[0] = 0.5 * r, q[1] = (m[7] - m[5]) / (2 * r), q[2] = (m[2] - m[6]) / (2 * r), q[3] = (m[3] - m[1]) / (2 * r);
    } else if (m[0] >= m[4] && m[0] >= m[8]) {
        const double r = sqrt(fmax(1e-300, 1.0 + m[0] - m[4] - m[8]));
        q[1] = 0.5 * r, q[0] = (m[7] - m[5]) / (2 * r), q[2] = (m[1] + m[3]) / (2 * r), q[3] = (m[2] + m[6]) / (2 * r);
    } else if (m[4] >= m[8]) {
        const double r = sqrt(fmax(1e-300, 1.0 - m[0] + m[4] - m[8]));
        q[2] = 0.5 * r, q[0] = (m[2] - m[6]) / (2 * r), q[1] = (m[1] + m[3]) / (2 * r), q[3] = (m[5] + m[7]) / (2 * r);
    } else {
        const double r = sqrt(fmax(1e-300, 1.0 - m[0] - m[4] + m[8]));
        q[3] = 0.5 * r, q[0] = (m[3] - m[1]) / (2 * r), q[1] = (m[2] + m[6]) / (2 * r), q[2] = (m[5] + m[7]) / (2 * r);
    }
}

static void linear_part(double out[9], const double m[16])
{
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            out[3 * r + c] = m[4 * r + c];
}

static void apply(double out[3], const double m[16], const double p[3])
{
    double result[3];
    for (int r = 0; r < 3; ++r)
        result[r] = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
    memcpy(out, result, sizeof result);
}

/* Parents: one root (-1), the others in range, no cycle. Every entry's range is checked before any walk up the
 * tree, which reads the parents of parents (an out-of-range entry further up would be read out of bounds). */
static sk_status check_tree(const int32_t *parents, size_t part_count, sk_error *error)
{
    size_t roots = 0;
    for (size_t p = 0; p < part_count; ++p) {
        if (parents[p] == -1)
            ++roots;
        else if (parents[p] < 0 || (size_t)parents[p] >= part_count)
            return sk_fail(error, SK_ERROR_INDEX, "parents[%zu] = %d is not -1 or in [0, %zu)", p, parents[p],
                           part_count);
    }
    for (size_t p = 0; p < part_count; ++p) {
        size_t steps = 0;
        for (int32_t q = parents[p]; q != -1; q = parents[q])
            if (++steps > part_count)
                return sk_fail(error, SK_ERROR_CYCLE, "the parents of part %zu form a cycle", p);
    }
    return roots == 1 ? SK_OK : sk_fail(error, SK_ERROR_ARGUMENT, "parents has %zu roots; a tree has one", roots);
}

/* The joint's local transform L = T(J) R(T_q) T(-J), T_q = Q_align^-1 Q(X, a) Q(Y, b) Q(Z, c) Q_align. */
static void joint_transform(double local[16], const double joint[3], const double axis[3], const double angles[3])
{
    double align[4], inverse[4], qx[4], qy[4], qz[4], rotation[4], step[4], rotation_matrix[9];
    align_to_z(align, axis);
    inverse[0] = align[0], inverse[1] = -align[1], inverse[2] = -align[2], inverse[3] = -align[3];
    axis_quaternion(qx, 0, angles[0]);
    axis_quaternion(qy, 1, angles[1]);
    axis_quaternion(qz, 2, angles[2]);
    quaternion_multiply(step, qy, qz);
    quaternion_multiply(rotation, qx, step);
    quaternion_multiply(step, rotation, align);
    quaternion_multiply(rotation, inverse, step);
    quaternion_matrix(rotation_matrix, rotation);
    double rotated[3], translation[3];
    for (int r = 0; r < 3; ++r)
        rotated[r] = sk_dot3(rotation_matrix + 3 * r, joint);
    for (int r = 0; r < 3; ++r)
        translation[r] = joint[r] - rotated[r];
    sk_rigid_matrix(local, rotation_matrix, translation);
}

sk_status sk_forward_kinematics(double *world, const double *joints, const double *parent_axes, const double *angles,
                                const int32_t *parents, const double *root_frame, size_t part_count, sk_error *error)
{
    if (!world || !joints || !parent_axes || !angles || !parents)
        return sk_fail(error, SK_ERROR_ARGUMENT, "world, joints, parent_axes, angles and parents must not be NULL");
    if (part_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "part_count is 0");
    sk_status status = check_tree(parents, part_count, error);
    if (status != SK_OK)
        return status;
    size_t values;
    if ((status = sk_array_size(&values, part_count, 3, 1, "joints", error)) != SK_OK)
        return status;
    for (size_t k = 0; k < values; ++k)
        if (!isfinite(joints[k]) || !isfinite(parent_axes[k]) || !isfinite(angles[k]))
            return sk_fail(error, SK_ERROR_NOT_FINITE, "joints, parent_axes or angles of part %zu are not finite",
                           k / 3);
    if (root_frame && !sk_all_finite(root_frame, 16))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "root_frame is not finite");
    /* Parents may come after their children: each pass places the parts whose parent is placed (at most the
     * tree's depth in passes; the flags live in the bottom row's first entry until the end). */
    for (size_t p = 0; p < part_count; ++p)
        world[16 * p + 12] = -1.0;
    for (size_t placed = 0, pass = 0; placed < part_count && pass <= part_count; ++pass)
        for (size_t p = 0; p < part_count; ++p) {
            if (world[16 * p + 12] == 0.0 || (parents[p] >= 0 && world[16 * (size_t)parents[p] + 12] != 0.0))
                continue;
            double local[16];
            joint_transform(local, joints + 3 * p, parent_axes + 3 * p, angles + 3 * p);
            if (parents[p] >= 0)
                sk_multiply4(world + 16 * p, world + 16 * (size_t)parents[p], local);
            else if (root_frame)
                sk_multiply4(world + 16 * p, root_frame, local);
            else
                memcpy(world + 16 * p, local, sizeof local);
            world[16 * p + 12] = 0.0; /* placed: the bottom row is (0 0 0 1) again */
            ++placed;
        }
    return sk_succeed(error);
}

/* ---------------------------------------------------------------------------------------------
 * Collisions: spheres, then oriented boxes by the separating-axis theorem
 * ------------------------------------------------------------------------------------------- */

typedef struct posed_box {
    double centre[3], axes[9], half[3], radius;
} posed_box;

static void pose_box(posed_box *b, const double *world, const double *box, const double *axes)
{
    double rotation[9];
    linear_part(rotation, world);
    apply(b->centre, world, box);
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c)
            b->axes[3 * r + c] = sk_dot3(rotation + 3 * c, axes + 3 * r);
        b->half[r] = box[3 + r];
    }
    b->radius = sqrt(sk_dot3(b->half, b->half));
}

/* Whether the boxes' projections on the axis are apart (a zero axis separates nothing). */
static int separated_on(const double axis[3], const posed_box *a, const posed_box *b, const double d[3])
{
    const double length = sk_dot3(axis, axis);
    if (!(length > 1e-18))
        return 0;
    double ra = 0.0, rb = 0.0;
    for (int k = 0; k < 3; ++k) {
        ra += a->half[k] * fabs(sk_dot3(a->axes + 3 * k, axis));
        rb += b->half[k] * fabs(sk_dot3(b->axes + 3 * k, axis));
    }
    return fabs(sk_dot3(d, axis)) > ra + rb;
}

static int boxes_overlap(const posed_box *a, const posed_box *b)
{
    const double d[3] = {b->centre[0] - a->centre[0], b->centre[1] - a->centre[1], b->centre[2] - a->centre[2]};
    for (int k = 0; k < 3; ++k)
        if (separated_on(a->axes + 3 * k, a, b, d) || separated_on(b->axes + 3 * k, a, b, d))
            return 0;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            double axis[3];
            sk_cross3(axis, a->axes + 3 * i, b->axes + 3 * j);
            if (separated_on(axis, a, b, d))
                return 0;
        }
    return 1;
}

sk_status sk_detect_collisions(int32_t *pairs, size_t *pair_count, const double *world, const double *boxes,
                               const double *principal_axes, const int32_t *parents, size_t part_count,
                               size_t pair_capacity, sk_error *error)
{
    if (!pairs || !pair_count || !world || !boxes || !principal_axes || !parents)
        return sk_fail(error, SK_ERROR_ARGUMENT, "an array or pair_count is NULL");
    sk_status status = check_tree(parents, part_count, error);
    if (status != SK_OK)
        return status;
    if (!sk_all_finite(world, 16 * part_count) || !sk_all_finite(boxes, 6 * part_count) ||
        !sk_all_finite(principal_axes, 9 * part_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "world, boxes or principal_axes are not finite");
    *pair_count = 0;
    /* Every pair but a parent and its child (they share an opening, so their boxes always touch): bounding
     * spheres first, the box test only when they meet. */
    for (size_t a = 0; a < part_count; ++a) {
        posed_box box_a;
        pose_box(&box_a, world + 16 * a, boxes + 6 * a, principal_axes + 9 * a);
        for (size_t b = a + 1; b < part_count; ++b) {
            if (parents[a] == (int32_t)b || parents[b] == (int32_t)a)
                continue;
            posed_box box_b;
            pose_box(&box_b, world + 16 * b, boxes + 6 * b, principal_axes + 9 * b);
            if (sk_distance3(box_a.centre, box_b.centre) > box_a.radius + box_b.radius || !boxes_overlap(&box_a, &box_b))
                continue;
            if (*pair_count >= pair_capacity)
                return sk_fail(error, SK_ERROR_ARGUMENT, "more than pair_capacity = %zu colliding pairs", pair_capacity);
            pairs[2 * *pair_count] = (int32_t)a;
            pairs[2 * *pair_count + 1] = (int32_t)b;
            ++*pair_count;
        }
    }
    return sk_succeed(error);
}

/* Whether part p lies in the subtree under root (p itself included); the parents are a checked tree. */
/* At most part_count steps up: the tree was checked, but a caller's pairs buffer aliasing parents rewrites it into
 * a cycle while the candidates are written. */
static int in_subtree(const int32_t *parents, size_t part_count, int32_t p, int32_t root)
{
    for (size_t steps = 0; p != -1 && steps <= part_count; p = parents[p], ++steps)
        if (p == root)
            return 1;
    return 0;
}

sk_status sk_collision_candidates(int32_t *pairs, size_t *pair_count, const int32_t *parents, size_t part_count,
                                  int32_t moved_part, size_t pair_capacity, sk_error *error)
{
    if (!pairs || !pair_count || !parents)
        return sk_fail(error, SK_ERROR_ARGUMENT, "pairs, pair_count and parents must not be NULL");
    sk_status status = check_tree(parents, part_count, error);
    if (status != SK_OK)
        return status;
    if (moved_part < -1 || moved_part >= (int32_t)part_count)
        return sk_fail(error, SK_ERROR_INDEX, "moved_part = %d is not -1 or in [0, %zu)", moved_part, part_count);
    *pair_count = 0;
    for (size_t a = 0; a < part_count; ++a)
        for (size_t b = a + 1; b < part_count; ++b) {
            if (parents[a] == (int32_t)b || parents[b] == (int32_t)a)
                continue;
            /* One joint turning moves its subtree rigidly: pairs on one side of it keep their distance. */
            if (moved_part >= 0 &&
                in_subtree(parents, part_count, (int32_t)a, moved_part) ==
                    in_subtree(parents, part_count, (int32_t)b, moved_part))
                continue;
            if (*pair_count >= pair_capacity)
                return sk_fail(error, SK_ERROR_ARGUMENT, "more than pair_capacity = %zu candidate pairs",
                               pair_capacity);
            pairs[2 * *pair_count] = (int32_t)a;
            pairs[2 * *pair_count + 1] = (int32_t)b;
            ++*pair_count;
        }
    return sk_succeed(error);
}

/* Heap sort of the candidate indices by their sphere weights (ascending): no allocation, O(n log n). */
static void sift_down(int32_t *order, size_t root, size_t count, const double *weights)
{
    for (size_t child; (child = 2 * root + 1) < count; root = child) {
        if (child + 1 < count && weights[order[child + 1]] > weights[order[child]])
            ++child;
        if (!(weights[order[child]] > weights[order[root]]))
            return;
        const int32_t swap = order[root];
        order[root] = order[child], order[child] = swap;
    }
}

static void sort_by_weight(int32_t *order, size_t count, const double *weights)
{
    for (size_t k = count / 2; k-- > 0;)
        sift_down(order, k, count, weights);
    for (size_t end = count; end > 1; --end) {
        const int32_t swap = order[0];
        order[0] = order[end - 1], order[end - 1] = swap;
        sift_down(order, 0, end - 1, weights);
    }
}

sk_status sk_detect_collisions_among(int32_t *pairs, int32_t *tested, double *sphere_weights,
                                     sk_collision_report *report, const double *world, const double *boxes,
                                     const double *principal_axes, const int32_t *candidates, size_t candidate_count,
                                     size_t part_count, int stop_at_first, size_t pair_capacity, sk_error *error)
{
    if (!pairs || !tested || !sphere_weights || !report || !world || !boxes || !principal_axes ||
        (!candidates && candidate_count))
        return sk_fail(error, SK_ERROR_ARGUMENT, "an array or report is NULL");
    memset(report, 0, sizeof *report);
    if (!sk_all_finite(world, 16 * part_count) || !sk_all_finite(boxes, 6 * part_count) ||
        !sk_all_finite(principal_axes, 9 * part_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "world, boxes or principal_axes are not finite");
    for (size_t k = 0; k < candidate_count; ++k) {
        const int32_t a = candidates[2 * k], b = candidates[2 * k + 1];
        if (a < 0 || b < 0 || (size_t)a >= part_count || (size_t)b >= part_count || a == b)
            return sk_fail(error, SK_ERROR_INDEX, "candidate %zu = (%d, %d) is not two parts in [0, %zu)", k, a, b,
                           part_count);
    }
    /* Broad phase: w = (l / r)^2 per candidate, l the distance of the spheres' centres and r their radii's sum;
     * the pairs whose spheres meet (w <= 1) go to the box test likeliest first. */
    size_t meeting = 0;
    for (size_t k = 0; k < candidate_count; ++k) {
        posed_box box_a, box_b;
        const size_t a = (size_t)candidates[2 * k], b = (size_t)candidates[2 * k + 1];
        pose_box(&box_a, world + 16 * a, boxes + 6 * a, principal_axes + 9 * a);
        pose_box(&box_b, world + 16 * b, boxes + 6 * b, principal_axes + 9 * b);
        const double l = sk_distance3(box_a.centre, box_b.centre), r = box_a.radius + box_b.radius;
        sphere_weights[k] = r > 0.0 ? (l / r) * (l / r) : (l > 0.0 ? INFINITY : 0.0);
        if (sphere_weights[k] <= 1.0)
            tested[meeting++] = (int32_t)k;
    }
    sort_by_weight(tested, meeting, sphere_weights);
    report->sphere_hits = meeting;
    for (size_t t = 0; t < meeting; ++t) {
        const size_t k = (size_t)tested[t], a = (size_t)candidates[2 * k], b = (size_t)candidates[2 * k + 1];
        posed_box box_a, box_b;
        pose_box(&box_a, world + 16 * a, boxes + 6 * a, principal_axes + 9 * a);
        pose_box(&box_b, world + 16 * b, boxes + 6 * b, principal_axes + 9 * b);
        ++report->box_tests;
        if (!boxes_overlap(&box_a, &box_b))
            continue;
        if (report->pair_count >= pair_capacity)
            return sk_fail(error, SK_ERROR_ARGUMENT, "more than pair_capacity = %zu colliding pairs", pair_capacity);
        pairs[2 * report->pair_count] = (int32_t)(a < b ? a : b);
        pairs[2 * report->pair_count + 1] = (int32_t)(a < b ? b : a);
        ++report->pair_count;
        if (stop_at_first)
            break;
    }
    return sk_succeed(error);
}

/* ---------------------------------------------------------------------------------------------
 * Seams: rigid points and QLERP arcs about a joint
 * ------------------------------------------------------------------------------------------- */

/* Out = W_a M(t) p, M = W_a^-1 W_b interpolated about the joint: M(t) p = R(t)(p - J) + J + t (M J - J), R(t) the
 * QLERP of the identity and M's rotation (eq. 4.1). */
static int seam_point(double out[3], const double *world_a, const double *world_b, const double joint[3],
                      double t, const double p[3])
{
    double inverse[16], relative[16], rotation[9], q[4], interpolated[9];
    if (!sk_affine_inverse(inverse, world_a))
        return 0;
    sk_multiply4(relative, inverse, world_b);
    linear_part(rotation, relative);
    matrix_quaternion(q, rotation);
    if (q[0] < 0.0)
        for (int k = 0; k < 4; ++k)
            q[k] = -q[k]; /* the short way round */
    const double blended[4] = {(1.0 - t) + t * q[0], t * q[1], t * q[2], t * q[3]};
    quaternion_matrix(interpolated, blended);
    double moved_joint[3], local[3];
    apply(moved_joint, relative, joint);
    const double offset[3] = {p[0] - joint[0], p[1] - joint[1], p[2] - joint[2]};
    for (int r = 0; r < 3; ++r)
        local[r] = sk_dot3(interpolated + 3 * r, offset) + joint[r] + t * (moved_joint[r] - joint[r]);
    apply(out, world_a, local);
    return 1;
}

sk_status sk_evaluate_seams(double *positions, const double *rest_positions, const double *world, const double *joints,
                            const int32_t *sources, const int32_t *parts_a, const int32_t *parts_b,
                            const double *blend, size_t point_count, size_t vertex_count, size_t part_count,
                            sk_error *error)
{
    if (!positions || !rest_positions || !world || !joints || !sources || !parts_a || !parts_b || !blend)
        return sk_fail(error, SK_ERROR_ARGUMENT, "an array is NULL");
    if (!sk_all_finite(world, 16 * part_count) || !sk_all_finite(joints, 3 * part_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "world or joints are not finite");
    for (size_t k = 0; k < point_count; ++k) {
        if (sources[k] < 0 || (size_t)sources[k] >= vertex_count)
            return sk_fail(error, SK_ERROR_INDEX, "sources[%zu] = %d is not in [0, %zu)", k, sources[k], vertex_count);
        if (parts_a[k] < 0 || (size_t)parts_a[k] >= part_count || parts_b[k] < -1 || parts_b[k] >= (int32_t)part_count)
            return sk_fail(error, SK_ERROR_INDEX, "point %zu: parts %d, %d are not parts (b may be -1)", k, parts_a[k],
                           parts_b[k]);
        if (!(blend[k] >= 0.0 && blend[k] <= 1.0))
            return sk_fail(error, SK_ERROR_ARGUMENT, "blend[%zu] = %g is not in [0, 1]", k, blend[k]);
    }
    for (size_t k = 0; k < point_count; ++k) {
        const double *p = rest_positions + 3 * (size_t)sources[k], *world_a = world + 16 * (size_t)parts_a[k];
        if (!sk_all_finite(p, 3))
            return sk_fail(error, SK_ERROR_NOT_FINITE, "rest position %d is not finite", sources[k]);
        if (parts_b[k] < 0) {
            apply(positions + 3 * k, world_a, p);
            continue;
        }
        if (!seam_point(positions + 3 * k, world_a, world + 16 * (size_t)parts_b[k], joints + 3 * (size_t)parts_b[k],
                        blend[k], p))
            return sk_fail(error, SK_ERROR_SINGULAR, "the frame of part %d is singular", parts_a[k]);
    }
    return sk_succeed(error);
}
