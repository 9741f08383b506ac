/*
 * Dual quaternions and dual-quaternion skinning (Kavan et al. 2008; Feng 2010, section 2.6.3), and the handle
 * rig's per-frame prediction (section 2.6): kernel vector, one mat-vec, normalisation, the Poisson translations.
 * Runtime code: no LAPACK, no allocation.
 */
#include <math.h>
#include <stdint.h>

#include "sk_internal.h"
#include "sk_math.h"

#define SK_REAL double
#define SK_NAME(x) x##_f64
#define SK_ALL_FINITE sk_all_finite
#define SK_FIRST_NON_FINITE sk_first_non_finite
#include "sk_dqs_template.h"
#undef SK_REAL
#undef SK_NAME
#undef SK_ALL_FINITE
#undef SK_FIRST_NON_FINITE

#define SK_REAL float
#define SK_NAME(x) x##_f32
#define SK_ALL_FINITE sk_all_finite_f32
#define SK_FIRST_NON_FINITE sk_first_non_finite_f32
#include "sk_dqs_template.h"
#undef SK_REAL
#undef SK_NAME
#undef SK_ALL_FINITE
#undef SK_FIRST_NON_FINITE

/* Tolerance on R'R - I and det R - 1 for a matrix to count as rigid. */
#define SK_RIGID_TOLERANCE 1e-6

/* q = (w, x, y, z) of a rotation matrix (row-major 3x3 inside a 4x4 when stride is 4), Shepperd's method: the
 * largest of the four diagonal combinations is the pivot, so no division by a small number. */
static void quaternion_of_rotation(double q[4], const double *m, int stride)
{
#define M(r, c) m[(r) * stride + (c)]
    const double trace = M(0, 0) + M(1, 1) + M(2, 2);
    if (trace > M(0, 0) && trace > M(1, 1) && trace > M(2, 2)) {
        const double s = 2 * sqrt(1 + trace);
        q[0] = s / 4, q[1] = (M(2, 1) - M(1, 2)) / s, q[2] = (M(0, 2) - M(2, 0)) / s, q[3] = (M(1, 0) - M(0, 1)) / s;
    } else if (M(0, 0) >= M(1, 1) && M(0, 0) >= M(2, 2)) {
        const double s = 2 * sqrt(1 + M(0, 0) - M(1, 1) - M(2, 2));
        q[0] = (M(2, 1) - M(1, 2)) / s, q[1] = s / 4, q[2] = (M(0, 1) + M(1, 0)) / s, q[3] = (M(0, 2) + M(2, 0)) / s;
    } else if (M(1, 1) >= M(2, 2)) {
        const double s = 2 * sqrt(1 + M(1, 1) - M(0, 0) - M(2, 2));
        q[0] = (M(0, 2) - M(2, 0)) / s, q[1] = (M(0, 1) + M(1, 0)) / s, q[2] = s / 4, q[3] = (M(1, 2) + M(2, 1)) / s;
    } else {
        const double s = 2 * sqrt(1 + M(2, 2) - M(0, 0) - M(1, 1));
        q[0] = (M(1, 0) - M(0, 1)) / s, q[1] = (M(0, 2) + M(2, 0)) / s, q[2] = (M(1, 2) + M(2, 1)) / s, q[3] = s / 4;
    }
#undef M
    if (q[0] < 0)
        for (int c = 0; c < 4; ++c)
            q[c] = -q[c];
}

static int is_rigid(const double *m)
{
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) {
            const double dot = m[a] * m[b] + m[4 + a] * m[4 + b] + m[8 + a] * m[8 + b];
            if (fabs(dot - (a == b)) > SK_RIGID_TOLERANCE)
                return 0;
        }
    const double r[9] = {m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]};
    return sk_determinant3(r) > 0;
}

/* The dual quaternion of rotation q and translation t: qe = (0, t) q / 2. */
static void dual_quaternion_of(double d[8], const double q[4], const double t[3])
{
    d[0] = q[0], d[1] = q[1], d[2] = q[2], d[3] = q[3];
    d[4] = -0.5 * (t[0] * q[1] + t[1] * q[2] + t[2] * q[3]);
    d[5] = 0.5 * (t[0] * q[0] + t[1] * q[3] - t[2] * q[2]);
    d[6] = 0.5 * (-t[0] * q[3] + t[1] * q[0] + t[2] * q[1]);
    d[7] = 0.5 * (t[0] * q[2] - t[1] * q[1] + t[2] * q[0]);
}

sk_status sk_dq_from_rigid(double *dual_quaternions, const double *matrices, size_t count, sk_error *error)
{
    if (!dual_quaternions || !matrices)
        return sk_fail(error, SK_ERROR_ARGUMENT, "dual quaternions and matrices must not be null");
    size_t values;
    const sk_status sized = sk_array_size(&values, count, 16, 1, "matrix", error);
    if (sized != SK_OK)
        return sized;
    const size_t bad = sk_first_non_finite(matrices, values);
    if (bad < values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "matrix %zu has a NaN or infinity", bad / 16);
    for (size_t i = 0; i < count; ++i) {
        const double *m = matrices + 16 * i;
        if (!is_rigid(m))
            return sk_fail(error, SK_ERROR_ARGUMENT, "matrix %zu is not a rigid motion (its 3x3 part is not a rotation)",
                           i);
        double q[4];
        quaternion_of_rotation(q, m, 4);
        dual_quaternion_of(dual_quaternions + 8 * i, q, (const double[3]){m[3], m[7], m[11]});
    }
    return sk_succeed(error);
}

sk_status sk_dq_to_rigid(double *matrices, const double *dual_quaternions, size_t count, sk_error *error)
{
    if (!dual_quaternions || !matrices)
        return sk_fail(error, SK_ERROR_ARGUMENT, "dual quaternions and matrices must not be null");
    size_t values;
    const sk_status sized = sk_array_size(&values, count, 8, 1, "dual quaternion", error);
    if (sized != SK_OK)
        return sized;
    const size_t bad = sk_first_non_finite(dual_quaternions, values);
    if (bad < values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "dual quaternion %zu has a NaN or infinity", bad / 8);
    for (size_t i = 0; i < count; ++i) {
        const double *d = dual_quaternions + 8 * i;
        if (!(d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + d[3] * d[3] > 1e-30))
            return sk_fail(error, SK_ERROR_SINGULAR, "dual quaternion %zu has a zero real part", i);
        double *m = matrices + 16 * i, columns[3][3];
        for (int c = 0; c < 3; ++c) {
            const double unit[3] = {c == 0, c == 1, c == 2};
            apply_blend_f64(columns[c], d, unit, 0);
        }
        double origin[3];
        apply_blend_f64(origin, d, (const double[3]){0, 0, 0}, 1);
        for (int r = 0; r < 3; ++r) {
            for (int c = 0; c < 3; ++c)
                m[4 * r + c] = columns[c][r];
            m[4 * r + 3] = origin[r];
        }
        m[12] = m[13] = m[14] = 0, m[15] = 1;
    }
    return sk_succeed(error);
}

sk_status sk_dq_align_signs(double *dual_quaternions, size_t example_count, size_t bone_count, sk_error *error)
{
    if (!dual_quaternions)
        return sk_fail(error, SK_ERROR_ARGUMENT, "dual quaternions must not be null");
    size_t values;
    const sk_status sized = sk_array_size(&values, example_count, bone_count, 8, "dual quaternion", error);
    if (sized != SK_OK)
        return sized;
    if (values == 0) /* no bones: nothing to align, however many examples (the loop below would walk them all) */
        return sk_succeed(error);
    const size_t bad = sk_first_non_finite(dual_quaternions, values);
    if (bad < values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "example %zu, bone %zu: a NaN or infinity", bad / 8 / bone_count,
                       bad / 8 % bone_count);
    for (size_t e = 1; e < example_count; ++e)
        for (size_t b = 0; b < bone_count; ++b) {
            const double *reference = dual_quaternions + 8 * b;
            double *d = dual_quaternions + 8 * (e * bone_count + b);
            if (d[0] * reference[0] + d[1] * reference[1] + d[2] * reference[2] + d[3] * reference[3] < 0)
                for (int c = 0; c < 8; ++c)
                    d[c] = -d[c];
        }
    return sk_succeed(error);
}

/* Normalises d in place (unit real part, dual part orthogonal to it); 0 when the real part vanishes. */
static int normalise_dual_quaternion(double d[8])
{
    const double norm2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] + d[3] * d[3];
    if (!(norm2 > 1e-30))
        return 0;
    const double norm = sqrt(norm2), along = (d[0] * d[4] + d[1] * d[5] + d[2] * d[6] + d[3] * d[7]) / norm2;
    for (int c = 0; c < 4; ++c) {
        d[4 + c] = (d[4 + c] - along * d[c]) / norm;
        d[c] /= norm;
    }
    return 1;
}

sk_status sk_dq_blend(double *destination, const double *dual_quaternions, const double *weights, size_t count,
                      sk_error *error)
{
    if (!destination || !dual_quaternions || !weights || count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "a blend needs at least one dual quaternion and its weight");
    size_t values;
    const sk_status sized = sk_array_size(&values, count, 8, 1, "dual quaternion", error);
    if (sized != SK_OK)
        return sized;
    if (!sk_all_finite(dual_quaternions, values) || !sk_all_finite(weights, count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "a dual quaternion or weight has a NaN or infinity");
    for (int c = 0; c < 8; ++c)
        destination[c] = 0;
    for (size_t k = 0; k < count; ++k) {
        const double *q = dual_quaternions + 8 * k;
        const double dot = destination[0] * q[0] + destination[1] * q[1] + destination[2] * q[2] + destination[3] * q[3];
        const double w = dot < 0 ? -weights[k] : weights[k];
        for (int c = 0; c < 8; ++c)
            destination[c] += w * q[c];
    }
    if (!normalise_dual_quaternion(destination))
        return sk_fail(error, SK_ERROR_SINGULAR, "the blend of %zu dual quaternions vanishes", count);
    return sk_succeed(error);
}

/* ---- kernels and the handle rig's prediction -------------------------------------------------------------- */

/* k(x', y) with x' = (x - mean) / scale (mean NULL: x as given), so the rig normalises handles in place. */
static double kernel_value(const double *x, const double *mean, double scale, const double *y, size_t dimension,
                           int kernel, double parameter, int degree)
{
    double sum = 0;
    for (size_t i = 0; i < dimension; ++i) {
        const double xi = mean ? (x[i] - mean[i]) / scale : x[i];
        sum += kernel == SK_KERNEL_GAUSSIAN ? (xi - y[i]) * (xi - y[i]) : xi * y[i];
    }
    if (kernel == SK_KERNEL_GAUSSIAN)
        return exp(-sum / (2 * parameter * parameter));
    if (kernel == SK_KERNEL_LINEAR)
        return sum;
    double power = 1;
    for (int i = 0; i < degree; ++i)
        power *= sum + parameter;
    return power;
}

static sk_status check_kernel(int kernel, double parameter, int degree, sk_error *error)
{
    if (kernel < SK_KERNEL_GAUSSIAN || kernel > SK_KERNEL_LINEAR)
        return sk_fail(error, SK_ERROR_ARGUMENT, "kernel %d: expected 0 (Gaussian), 1 (polynomial) or 2 (linear)",
                       kernel);
    if (!isfinite(parameter) || (kernel == SK_KERNEL_GAUSSIAN && !(parameter > 0)))
        return sk_fail(error, SK_ERROR_ARGUMENT, "kernel parameter %g: the Gaussian's sigma must be finite and > 0",
                       parameter);
    if (kernel == SK_KERNEL_POLYNOMIAL && (degree < 1 || degree > 16))
        return sk_fail(error, SK_ERROR_ARGUMENT, "polynomial degree %d: expected 1 .. 16", degree);
    return SK_OK;
}

sk_status sk_kernel_values(double *destination, const double *points, const double *references, size_t point_count,
                           size_t reference_count, size_t dimension, int kernel, double parameter, int degree,
                           sk_error *error)
{
    if (!destination || !points || !references || dimension == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "kernel values need points, references and a dimension >= 1");
    sk_status status = check_kernel(kernel, parameter, degree, error);
    size_t point_values, reference_values, out_values;
    if (status == SK_OK)
        status = sk_array_size(&point_values, point_count, dimension, 1, "point", error);
    if (status == SK_OK)
        status = sk_array_size(&reference_values, reference_count, dimension, 1, "reference", error);
    if (status == SK_OK)
        status = sk_array_size(&out_values, point_count, reference_count, 1, "kernel value", error);
    if (status != SK_OK)
        return status;
    const size_t bad = sk_first_non_finite(points, point_values);
    if (bad < point_values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "point %zu has a NaN or infinity", bad / dimension);
    if (!sk_all_finite(references, reference_values))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "reference %zu has a NaN or infinity",
                       sk_first_non_finite(references, reference_values) / dimension);
    for (size_t p = 0; p < point_count; ++p)
        for (size_t j = 0; j < reference_count; ++j)
            destination[p * reference_count + j] =
                kernel_value(points + p * dimension, NULL, 1, references + j * dimension, dimension, kernel, parameter,
                             degree);
    return sk_succeed(error);
}

/* Rotation matrix (row-major 3x3) of a unit quaternion. */
static void rotation_of_quaternion(double r[9], const double *q)
{
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    r[0] = 1 - 2 * (y * y + z * z), r[1] = 2 * (x * y - w * z), r[2] = 2 * (x * z + w * y);
    r[3] = 2 * (x * y + w * z), r[4] = 1 - 2 * (x * x + z * z), r[5] = 2 * (y * z - w * x);
    r[6] = 2 * (x * z - w * y), r[7] = 2 * (y * z + w * x), r[8] = 1 - 2 * (x * x + y * y);
}

/* Replaces each bone's translation by the Poisson solve's t_b = sum_a R_a y_ba + sum_l h_bl c_l. */
/* t_b = sum_a R_a y_ba + sum_l h_bl handle_l, then each bone's dual part rebuilt from its rotation and t_b. The
 * sums are kept in the dual parts' last three slots while they build (those are rewritten at the end anyway), so
 * each R_a is formed once instead of once per bone b, in the same order of additions. */
static void poisson_translations(double *dual_quaternions, const sk_handle_rig *rig, const double *handles)
{
    const size_t n = rig->bone_count;
    for (size_t b = 0; b < n; ++b)
        dual_quaternions[8 * b + 5] = dual_quaternions[8 * b + 6] = dual_quaternions[8 * b + 7] = 0;
    for (size_t a = 0; a < n; ++a) {
        double r[9];
        rotation_of_quaternion(r, dual_quaternions + 8 * a);
        for (size_t b = 0; b < n; ++b) {
            const double *y = rig->translation_rotations + 3 * (b * n + a);
            double *t = dual_quaternions + 8 * b + 5;
            for (int row = 0; row < 3; ++row)
                t[row] += r[3 * row] * y[0] + r[3 * row + 1] * y[1] + r[3 * row + 2] * y[2];
        }
    }
    for (size_t b = 0; b < n; ++b) {
        double *d = dual_quaternions + 8 * b, q[4] = {d[0], d[1], d[2], d[3]}, t[3] = {d[5], d[6], d[7]};
        for (size_t l = 0; l < rig->handle_count; ++l) {
            const double h = rig->translation_handles[b * rig->handle_count + l];
            for (int row = 0; row < 3; ++row)
                t[row] += h * handles[3 * l + row];
        }
        dual_quaternion_of(d, q, t);
    }
}

/* The dot product of a and b in four interleaved partial sums: one chain of dependent additions made the
 * prediction's mat-vec wait on the adder's latency, not its throughput. */
static double dot_in_four_sums(const double *a, const double *b, size_t n)
{
    double s0 = 0, s1 = 0, s2 = 0, s3 = 0;
    size_t j = 0;
    for (; j + 4 <= n; j += 4) {
        s0 += a[j] * b[j];
        s1 += a[j + 1] * b[j + 1];
        s2 += a[j + 2] * b[j + 2];
        s3 += a[j + 3] * b[j + 3];
    }
    for (; j < n; ++j)
        s0 += a[j] * b[j];
    return (s0 + s1) + (s2 + s3);
}

static sk_status check_rig(const sk_handle_rig *rig, sk_error *error)
{
    if (!rig || !rig->handle_mean || !rig->training_handles || !rig->mapping || !rig->mapping_offset ||
        (rig->translation_rotations && !rig->translation_handles))
        return sk_fail(error, SK_ERROR_ARGUMENT, "the handle rig's arrays must not be null");
    if (rig->handle_count == 0 || rig->example_count == 0 || rig->bone_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "a handle rig needs handles, examples and bones (counts %zu, %zu, %zu)",
                       rig->handle_count, rig->example_count, rig->bone_count);
    if (!(rig->handle_scale > 0) || !isfinite(rig->handle_scale))
        return sk_fail(error, SK_ERROR_ARGUMENT, "handle scale %g: must be finite and > 0", rig->handle_scale);
    size_t values;
    sk_status status = sk_array_size(&values, rig->bone_count, 8, rig->example_count, "mapping", error);
    if (status == SK_OK)
        status = sk_array_size(&values, rig->example_count, 3, rig->handle_count, "training handle", error);
    if (status == SK_OK)
        status = sk_array_size(&values, rig->bone_count, rig->bone_count, 3, "translation matrix", error);
    if (status == SK_OK)
        status = sk_array_size(&values, rig->bone_count, rig->handle_count, 1, "translation matrix", error);
    if (status == SK_OK)
        status = check_kernel(rig->kernel, rig->parameter, rig->degree, error);
    return status;
}

sk_status sk_handle_predict(double *dual_quaternions, double *kernel_values, const sk_handle_rig *rig,
                            const double *handle_positions, sk_error *error)
{
    if (!dual_quaternions || !kernel_values || !handle_positions)
        return sk_fail(error, SK_ERROR_ARGUMENT, "prediction arrays must not be null");
    const sk_status status = check_rig(rig, error);
    if (status != SK_OK)
        return status;
    const size_t dimension = 3 * rig->handle_count, examples = rig->example_count;
    const size_t bad = sk_first_non_finite(handle_positions, dimension);
    if (bad < dimension)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "handle %zu's position has a NaN or infinity", bad / 3);
    for (size_t j = 0; j < examples; ++j)
        kernel_values[j] = kernel_value(handle_positions, rig->handle_mean, rig->handle_scale,
                                        rig->training_handles + j * dimension, dimension, rig->kernel,
                                        rig->parameter, rig->degree);
    for (size_t row = 0; row < 8 * rig->bone_count; ++row)
        dual_quaternions[row] = rig->mapping_offset[row] +
                                dot_in_four_sums(rig->mapping + row * examples, kernel_values, examples);
    for (size_t b = 0; b < rig->bone_count; ++b)
        if (!normalise_dual_quaternion(dual_quaternions + 8 * b))
            return sk_fail(error, SK_ERROR_SINGULAR, "bone %zu's predicted rotation vanishes (handles far outside "
                                                     "the examples?)", b);
    if (rig->translation_rotations)
        poisson_translations(dual_quaternions, rig, handle_positions);
    if (!sk_all_finite(dual_quaternions, 8 * rig->bone_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "the rig's matrices gave a NaN or infinity (bone %zu)",
                       sk_first_non_finite(dual_quaternions, 8 * rig->bone_count) / 8);
    return sk_succeed(error);
}
