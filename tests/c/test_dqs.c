/*
 * Dual quaternions, dual-quaternion skinning and the handle rig's prediction (csrc/runtime/sk_dual_quaternion.c),
 * linked without LAPACK like test_runtime_link: the runtime claim holds for this family too.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "test_support.h"

static void random_rigid(double m[16], double max_translation)
{
    double r[9];
    random_rotation(r);
    const double ones[3] = {1, 1, 1};
    const double t[3] = {random_uniform(-max_translation, max_translation),
                         random_uniform(-max_translation, max_translation),
                         random_uniform(-max_translation, max_translation)};
    make_frame(m, r, ones, t);
}

static void single_bone_reproduces_the_motion(void)
{
    for (int trial = 0; trial < 50; ++trial) {
        double m[16], dq[8], v[30], out[30];
        random_rigid(m, 5);
        EXPECT_SUCCESS("from rigid", sk_dq_from_rigid(dq, m, 1, error));
        CHECK(dq[0] >= 0);
        CHECK(fabs(dq[0] * dq[0] + dq[1] * dq[1] + dq[2] * dq[2] + dq[3] * dq[3] - 1) < 1e-14);
        int32_t offsets[11], bones[10];
        double weights[10];
        for (int i = 0; i < 10; ++i) {
            offsets[i] = i, bones[i] = 0, weights[i] = 1;
            for (int c = 0; c < 3; ++c)
                v[3 * i + c] = random_uniform(-3, 3);
        }
        offsets[10] = 10;
        const sk_influences influences = {offsets, bones, 10, 10};
        EXPECT_SUCCESS("skin", sk_dqs_evaluate_f64(out, &influences, v, 1, weights, dq, 1, 1, error));
        double worst = 0;
        for (int i = 0; i < 10; ++i) {
            double expected[3];
            transform(expected, m, v + 3 * i, 1);
            for (int c = 0; c < 3; ++c)
                worst = fmax(worst, fabs(out[3 * i + c] - expected[c]));
        }
        CHECK_IN("R v + t to 1e-12", worst < 1e-12);
        double back[16];
        EXPECT_SUCCESS("to rigid", sk_dq_to_rigid(back, dq, 1, error));
        CHECK_IN("round trip", max_abs_difference(back, m, 16) < 1e-12);
    }
}

/* A blend of rigid dual quaternions, applied to points, is a rigid motion: distances and orientation kept. */
static void blend_is_rigid(void)
{
    for (int trial = 0; trial < 50; ++trial) {
        double m[3 * 16], dq[3 * 8], weights[3], blend[8], matrix[16];
        for (int k = 0; k < 3; ++k) {
            random_rigid(m + 16 * k, 2);
            weights[k] = random_uniform(0.05, 1);
        }
        EXPECT_SUCCESS("from rigid", sk_dq_from_rigid(dq, m, 3, error));
        dq[8] = -dq[8], dq[9] = -dq[9], dq[10] = -dq[10], dq[11] = -dq[11]; /* the same motion, antipodal */
        for (int c = 12; c < 16; ++c)
            dq[c] = -dq[c];
        EXPECT_SUCCESS("blend", sk_dq_blend(blend, dq, weights, 3, error));
        EXPECT_SUCCESS("to rigid", sk_dq_to_rigid(matrix, blend, 1, error));
        double rtr_error = 0;
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) {
                const double dot = matrix[a] * matrix[b] + matrix[4 + a] * matrix[4 + b] + matrix[8 + a] * matrix[8 + b];
                rtr_error = fmax(rtr_error, fabs(dot - (a == b)));
            }
        CHECK_IN("blend rotation orthonormal", rtr_error < 1e-12);
        /* The skinning path gives the same rigid motion on points (signs aligned against the running sum). */
        int32_t offsets[2] = {0, 3}, bones[3] = {0, 1, 2};
        const sk_influences influences = {offsets, bones, 1, 3};
        double p[3] = {0.3, -1.2, 2.0}, out[3], expected[3];
        EXPECT_SUCCESS("skin", sk_dqs_evaluate_f64(out, &influences, p, 1, weights, dq, 3, 1, error));
        transform(expected, matrix, p, 1);
        CHECK_IN("skinning = blend", max_abs_difference(out, expected, 3) < 1e-12);
    }
}

static void sign_alignment(void)
{
    double m[2 * 16], dq[2 * 2 * 8];
    random_rigid(m, 1), random_rigid(m + 16, 1);
    EXPECT_SUCCESS("from", sk_dq_from_rigid(dq, m, 2, error));
    memcpy(dq + 16, dq, 16 * sizeof *dq);
    for (int c = 16; c < 24; ++c) /* example 1, bone 0 flipped */
        dq[c] = -dq[c];
    EXPECT_SUCCESS("align", sk_dq_align_signs(dq, 2, 2, error));
    CHECK(max_abs_difference(dq, dq + 16, 16) == 0);
    dq[3] = NAN;
    EXPECT_FAILURE("NaN", SK_ERROR_NOT_FINITE, sk_dq_align_signs(dq, 2, 2, error));
}

/* make fuzz-sanitized, seed 1, calls 90 and 142: no bones and 2^32 + 1 examples (an empty buffer) walked the
 * examples one by one with nothing to do, over 10 s under ASan (an optimised build drops the empty loop). */
static void no_bones_is_no_work_however_many_examples(void)
{
    double dq[8] = {1, 0, 0, 0, 0, 0, 0, 0};
    const clock_t started = clock();
    EXPECT_SUCCESS("no bones", sk_dq_align_signs(dq, ((size_t)1 << 32) + 1, 0, error));
    CHECK_IN("no bones: under 0.1 s CPU", (double)(clock() - started) / CLOCKS_PER_SEC < 0.1);
    CHECK(dq[0] == 1);
}

static void float_matches_double(void)
{
    test_mesh mesh = make_random_mesh(3000, 6);
    double *dq = allocate(8 * 6, sizeof *dq), *m = allocate(16 * 6, sizeof *m);
    for (size_t b = 0; b < 6; ++b)
        random_rigid(m + 16 * b, 1);
    EXPECT_SUCCESS("from", sk_dq_from_rigid(dq, m, 6, error));
    double *out = allocate(3 * 3000, sizeof *out), *threaded = allocate(3 * 3000, sizeof *threaded);
    float *out32 = allocate(3 * 3000, sizeof *out32), *rest32 = allocate(3 * 3000, sizeof *rest32);
    float *weights32 = allocate(mesh.influence_count, sizeof *weights32), dq32[48];
    for (size_t i = 0; i < 3 * 3000; ++i)
        rest32[i] = (float)mesh.rest_positions[i];
    for (size_t k = 0; k < mesh.influence_count; ++k)
        weights32[k] = (float)mesh.weights[k];
    for (int c = 0; c < 48; ++c)
        dq32[c] = (float)dq[c];
    EXPECT_SUCCESS("f64", sk_dqs_evaluate_f64(out, &mesh.influences, mesh.rest_positions, 1, mesh.weights, dq, 6, 1,
                                              error));
    EXPECT_SUCCESS("f64 threaded", sk_dqs_evaluate_f64(threaded, &mesh.influences, mesh.rest_positions, 1,
                                                       mesh.weights, dq, 6, 4, error));
    EXPECT_SUCCESS("f32", sk_dqs_evaluate_f32(out32, &mesh.influences, rest32, 1, weights32, dq32, 6, 1, error));
    double worst = 0;
    for (size_t i = 0; i < 3 * 3000; ++i)
        worst = fmax(worst, fabs(out32[i] - out[i]));
    CHECK_IN("f32 within 1e-5 of f64", worst < 1e-5 * coordinate_scale(out, 3 * 3000));
    CHECK_IN("threads do not change the result", max_abs_difference(out, threaded, 3 * 3000) == 0);
    /* Bad input is refused and named. */
    mesh.bones[5] = 6;
    EXPECT_FAILURE("bone index", SK_ERROR_INDEX, sk_dqs_evaluate_f64(out, &mesh.influences, mesh.rest_positions, 1,
                                                                     mesh.weights, dq, 6, 1, error));
    mesh.bones[5] = 0;
    dq[9] = INFINITY;
    EXPECT_FAILURE("infinite dq", SK_ERROR_NOT_FINITE, sk_dqs_evaluate_f64(out, &mesh.influences, mesh.rest_positions,
                                                                           1, mesh.weights, dq, 6, 1, error));
    EXPECT_FAILURE("no bones", SK_ERROR_ARGUMENT, sk_dqs_evaluate_f64(out, &mesh.influences, mesh.rest_positions, 1,
                                                                      mesh.weights, dq, 0, 1, error));
    m[0] = 2; /* a scaled matrix is not rigid */
    EXPECT_FAILURE("not rigid", SK_ERROR_ARGUMENT, sk_dq_from_rigid(dq, m, 6, error));
    const double zero[8] = {0};
    EXPECT_FAILURE("zero dq", SK_ERROR_SINGULAR, sk_dq_to_rigid(m, zero, 1, error));
    free(dq), free(m), free(out), free(threaded), free(out32), free(rest32), free(weights32);
    free_mesh(&mesh);
}

/* The prediction: one bone, linear kernel; the mapping picks the handle's x coordinate into the dual part, so the
 * predicted translation is the handle's normalised x (the arithmetic is simple enough to state exactly). */
static void handle_prediction(void)
{
    const double mean[3] = {1, 2, 3}, training[2 * 3] = {1, 0, 0, 0, 1, 0};
    double mapping[8 * 2] = {0}, offset[8] = {1, 0, 0, 0, 0, 0, 0, 0};
    mapping[5 * 2 + 0] = 0.5; /* qe.x = 0.5 * k(c, e0) = 0.5 * c'_x: translation (c'_x, 0, 0) */
    const sk_handle_rig rig = {.handle_count = 1, .example_count = 2, .bone_count = 1, .kernel = SK_KERNEL_LINEAR,
                               .degree = 1, .handle_scale = 2, .handle_mean = mean, .training_handles = training,
                               .mapping = mapping, .mapping_offset = offset};
    const double handle[3] = {5, 2, 3};
    double dq[8], xi[2], matrix[16];
    EXPECT_SUCCESS("predict", sk_handle_predict(dq, xi, &rig, handle, error));
    CHECK(fabs(xi[0] - 2) < 1e-15 && fabs(xi[1]) < 1e-15);
    EXPECT_SUCCESS("matrix", sk_dq_to_rigid(matrix, dq, 1, error));
    CHECK_IN("translation from the handle", fabs(matrix[3] - 2) < 1e-14 && fabs(matrix[7]) < 1e-14);
    /* With the Poisson matrices the translation is theirs: t = R y + h c. */
    const double y[3] = {0, 0, 1}, h[1] = {0.25};
    sk_handle_rig poisson = rig;
    poisson.translation_rotations = y, poisson.translation_handles = h;
    EXPECT_SUCCESS("poisson", sk_handle_predict(dq, xi, &poisson, handle, error));
    EXPECT_SUCCESS("matrix", sk_dq_to_rigid(matrix, dq, 1, error));
    CHECK_IN("Poisson translation", fabs(matrix[3] - 1.25) < 1e-14 && fabs(matrix[7] - 0.5) < 1e-14 &&
                                        fabs(matrix[11] - 1.75) < 1e-14);
    const double bad[3] = {NAN, 0, 0};
    EXPECT_FAILURE("NaN handle", SK_ERROR_NOT_FINITE, sk_handle_predict(dq, xi, &rig, bad, error));
    offset[0] = 0;
    EXPECT_FAILURE("vanishing rotation", SK_ERROR_SINGULAR, sk_handle_predict(dq, xi, &rig, handle, error));
    sk_handle_rig gaussian = rig;
    gaussian.kernel = SK_KERNEL_GAUSSIAN, gaussian.parameter = 0;
    EXPECT_FAILURE("zero sigma", SK_ERROR_ARGUMENT, sk_handle_predict(dq, xi, &gaussian, handle, error));
    double k[4];
    EXPECT_SUCCESS("kernel", sk_kernel_values(k, training, training, 2, 2, 3, SK_KERNEL_GAUSSIAN, 1, 1, error));
    CHECK(fabs(k[0] - 1) < 1e-15 && fabs(k[1] - exp(-1)) < 1e-15);
    EXPECT_SUCCESS("kernel", sk_kernel_values(k, training, training, 2, 2, 3, SK_KERNEL_POLYNOMIAL, 1, 5, error));
    CHECK(fabs(k[0] - 32) < 1e-12 && fabs(k[1] - 1) < 1e-15);
}

/* The prediction at a realistic shape (several bones, an example count that is no multiple of four, the Gaussian
 * kernel, the Poisson translations) against the plain formulas: xi_j = exp(-|c' - e_j|^2 / 2 sigma^2) with
 * c' = (c - mean) / scale, d = M xi + offset normalised, t_b = sum_a R_a y_ba + sum_l h_bl c_l. */
static void handle_prediction_matches_the_formulas(void)
{
    enum { HANDLES = 2, EXAMPLES = 7, BONES = 3, DIMENSION = 3 * HANDLES };
    double mean[DIMENSION], training[EXAMPLES * DIMENSION], mapping[8 * BONES * EXAMPLES], offset[8 * BONES];
    double y[BONES * BONES * 3], h[BONES * HANDLES], handle[DIMENSION];
    for (int i = 0; i < DIMENSION; ++i)
        mean[i] = random_uniform(-1, 1), handle[i] = random_uniform(-1, 1);
    for (int i = 0; i < EXAMPLES * DIMENSION; ++i)
        training[i] = random_uniform(-1, 1);
    for (int i = 0; i < 8 * BONES * EXAMPLES; ++i)
        mapping[i] = random_uniform(-0.2, 0.2);
    for (int i = 0; i < 8 * BONES; ++i)
        offset[i] = i % 8 == 0 ? 1 : random_uniform(-0.1, 0.1);
    for (int i = 0; i < BONES * BONES * 3; ++i)
        y[i] = random_uniform(-1, 1);
    for (int i = 0; i < BONES * HANDLES; ++i)
        h[i] = random_uniform(-1, 1);
    const double scale = 1.5, sigma = 0.8;
    const sk_handle_rig rig = {.handle_count = HANDLES, .example_count = EXAMPLES, .bone_count = BONES,
                               .kernel = SK_KERNEL_GAUSSIAN, .parameter = sigma, .degree = 1, .handle_scale = scale,
                               .handle_mean = mean, .training_handles = training, .mapping = mapping,
                               .mapping_offset = offset, .translation_rotations = y, .translation_handles = h};
    double dq[8 * BONES], xi[EXAMPLES];
    EXPECT_SUCCESS("predict", sk_handle_predict(dq, xi, &rig, handle, error));
    double expected_xi[EXAMPLES], real[BONES][4];
    for (int j = 0; j < EXAMPLES; ++j) {
        double distance2 = 0;
        for (int i = 0; i < DIMENSION; ++i) {
            const double difference = (handle[i] - mean[i]) / scale - training[j * DIMENSION + i];
            distance2 += difference * difference;
        }
        expected_xi[j] = exp(-distance2 / (2 * sigma * sigma));
        CHECK_IN("kernel value", fabs(xi[j] - expected_xi[j]) < 1e-14);
    }
    for (int b = 0; b < BONES; ++b) {
        double norm = 0;
        for (int c = 0; c < 4; ++c) {
            real[b][c] = offset[8 * b + c];
            for (int j = 0; j < EXAMPLES; ++j)
                real[b][c] += mapping[(8 * b + c) * EXAMPLES + j] * expected_xi[j];
            norm += real[b][c] * real[b][c];
        }
        for (int c = 0; c < 4; ++c)
            real[b][c] /= sqrt(norm);
    }
    for (int b = 0; b < BONES; ++b) {
        double t[3] = {0, 0, 0};
        for (int a = 0; a < BONES; ++a) {
            double m[16];
            const double rotation_only[8] = {real[a][0], real[a][1], real[a][2], real[a][3], 0, 0, 0, 0};
            EXPECT_SUCCESS("rotation", sk_dq_to_rigid(m, rotation_only, 1, error));
            for (int row = 0; row < 3; ++row)
                for (int column = 0; column < 3; ++column)
                    t[row] += m[4 * row + column] * y[3 * (b * BONES + a) + column];
        }
        for (int l = 0; l < HANDLES; ++l)
            for (int row = 0; row < 3; ++row)
                t[row] += h[b * HANDLES + l] * handle[3 * l + row];
        double m[16];
        EXPECT_SUCCESS("matrix", sk_dq_to_rigid(m, dq + 8 * b, 1, error));
        for (int c = 0; c < 4; ++c)
            CHECK_IN("predicted rotation", fabs(dq[8 * b + c] - real[b][c]) < 1e-13);
        for (int row = 0; row < 3; ++row)
            CHECK_IN("Poisson translation", fabs(m[4 * row + 3] - t[row]) < 1e-12);
    }
}

int main(void)
{
    test_program_name = "test_dqs";
    single_bone_reproduces_the_motion();
    blend_is_rigid();
    sign_alignment();
    no_bones_is_no_work_however_many_examples();
    float_matches_double();
    handle_prediction();
    handle_prediction_matches_the_formulas();
    return finish_tests();
}
