/*
 * Standalone tests of the skinkit C core (csrc/skinkit.h).
 *
 * Meant to run under AddressSanitizer and UndefinedBehaviorSanitizer: the error cases copy their
 * index arrays to exactly sized heap blocks, so a core that read past them before rejecting the
 * input would be stopped by the sanitizer, not just by a failed CHECK.
 *
 * Numerical results are compared with a reference computed here with plain loops and a
 * Gauss-Jordan inverse (shared with test_fit.c in test_support.c), so the core is not only compared
 * with itself.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "skinkit.h"
#include "sk_internal.h" /* only for sk_worker_count: proves the large mesh really is split */
#include "test_support.h"

/* ---------------------------------------------------------------------------------------------
 * Single-precision helpers (the shared ones are in test_support.h)
 * ------------------------------------------------------------------------------------------- */

static float *to_float(const double *values, size_t count)
{
    float *result = allocate(count, sizeof *result);
    for (size_t i = 0; i < count; ++i)
        result[i] = (float)values[i];
    return result;
}

static double max_abs_difference_f32(const float *a, const double *b, size_t count)
{
    double largest = 0.0;
    for (size_t i = 0; i < count; ++i)
        largest = fmax(largest, fabs((double)a[i] - b[i]));
    return largest;
}

static int close_to_f32(const float *actual, const double *reference, size_t count, double relative_tolerance)
{
    const double difference = max_abs_difference_f32(actual, reference, count);
    return difference <= relative_tolerance * coordinate_scale(reference, count);
}

/* ---------------------------------------------------------------------------------------------
 * 1. Conversion and evaluation agree with linear blend skinning and with the reference
 * ------------------------------------------------------------------------------------------- */

/* Evaluates one pose by every path and compares them with each other and with the reference. */
static void check_pose_by_every_path(const test_mesh *mesh, const double *coordinates, const double *poses)
{
    const size_t V = mesh->vertex_count, K = mesh->influence_count, B = mesh->bone_count;
    double *expected = allocate(3 * V, sizeof *expected);
    double *animation_space = allocate(3 * V, sizeof *animation_space);
    double *linear_blend = allocate(3 * V, sizeof *linear_blend);
    float *animation_space_f32 = allocate(3 * V, sizeof *animation_space_f32);
    float *linear_blend_f32 = allocate(3 * V, sizeof *linear_blend_f32);
    float *coordinates_f32 = to_float(coordinates, 4 * K), *poses_f32 = to_float(poses, 16 * B);
    float *weights_f32 = to_float(mesh->weights, K), *positions_f32 = to_float(mesh->rest_positions, 3 * V);

    reference_linear_blend(expected, mesh, mesh->rest_positions, 1.0, poses);
    double *skinning = skinning_matrices_of("skinning matrices", mesh, poses);
    float *skinning_f32 = to_float(skinning, 16 * B);
    EXPECT_SUCCESS("animation space f64",
                   sk_animation_space_evaluate_f64(animation_space,
                                                   &mesh->influences, coordinates,
                                                   poses, B, 1, error));
    EXPECT_SUCCESS("linear blend f64",
                   sk_lbs_evaluate_f64(linear_blend, &mesh->influences,
                                       mesh->rest_positions, 1.0, mesh->weights, skinning, B, 1, error));
    EXPECT_SUCCESS("animation space f32",
                   sk_animation_space_evaluate_f32(animation_space_f32,
                                                   &mesh->influences,
                                                   coordinates_f32, poses_f32, B, 1, error));
    EXPECT_SUCCESS("linear blend f32",
                   sk_lbs_evaluate_f32(linear_blend_f32, &mesh->influences,
                                       positions_f32, 1.0f, weights_f32, skinning_f32, B, 1, error));

    CHECK(close_to(animation_space, linear_blend, 3 * V, 1e-12));
    CHECK(close_to(animation_space, expected, 3 * V, 1e-12));
    CHECK(close_to(linear_blend, expected, 3 * V, 1e-12));
    CHECK(close_to_f32(animation_space_f32, animation_space, 3 * V, 1e-5));
    CHECK(close_to_f32(linear_blend_f32, linear_blend, 3 * V, 1e-5));
    /* Guards the tolerances: a posed mesh must actually move away from its rest shape. */
    CHECK(max_abs_difference(expected, mesh->rest_positions, 3 * V) > 0.1);

    free(skinning), free(skinning_f32), free(expected), free(animation_space), free(linear_blend);
    free(animation_space_f32), free(linear_blend_f32), free(coordinates_f32), free(poses_f32);
    free(weights_f32), free(positions_f32);
}

static void check_skinning_matrices_match_reference(const test_mesh *mesh, const double *poses)
{
    double *expected = allocate(16 * mesh->bone_count, sizeof *expected);
    double *inverses = reference_inverse_rest_frames(mesh);
    for (size_t bone = 0; bone < mesh->bone_count; ++bone)
        multiply(expected + 16 * bone, poses + 16 * bone, inverses + 16 * bone);
    double *skinning = skinning_matrices_of("skinning matrices", mesh, poses);
    CHECK(close_to(skinning, expected, 16 * mesh->bone_count, 1e-13));
    free(skinning), free(expected), free(inverses);
}

static void test_conversion_reproduces_linear_blend_skinning(void)
{
    test_mesh mesh = make_random_mesh(500, 6);
    const size_t K = mesh.influence_count;
    double *expected_coordinates = allocate(4 * K, sizeof *expected_coordinates);
    double *poses = allocate(16 * mesh.bone_count, sizeof *poses);

    double *coordinates = converted_coordinates("conversion", &mesh, mesh.rest_positions, 1.0);
    reference_coordinates(expected_coordinates, &mesh, mesh.rest_positions, 1.0);
    CHECK(close_to(coordinates, expected_coordinates, 4 * K, 1e-12));
    for (size_t k = 0; k < K; ++k)
        CHECK_IN("a point's p_k has weight w_k", coordinates[4 * k + 3] == mesh.weights[k]);

    for (int pose = 0; pose < 5; ++pose) {
        random_frames(poses, mesh.bone_count);
        check_skinning_matrices_match_reference(&mesh, poses);
        check_pose_by_every_path(&mesh, coordinates, poses);
    }
    free(coordinates), free(expected_coordinates), free(poses);
    free_mesh(&mesh);
}

/* ---------------------------------------------------------------------------------------------
 * 2. Tangent vectors (homogeneous 0)
 * ------------------------------------------------------------------------------------------- */

static void test_tangents_ignore_translation(void)
{
    test_mesh mesh = make_random_mesh(300, 6);
    const size_t V = mesh.vertex_count, K = mesh.influence_count, B = mesh.bone_count;
    double *tangents = allocate(3 * V, sizeof *tangents), *poses = allocate(16 * B, sizeof *poses);
    double *expected = allocate(3 * V, sizeof *expected), *evaluated = allocate(3 * V, sizeof *evaluated);
    double *linear_blend = allocate(3 * V, sizeof *linear_blend), *moved = allocate(3 * V, sizeof *moved);
    random_vectors(tangents, V);
    random_frames(poses, B);

    double *coordinates = converted_coordinates("tangent conversion", &mesh, tangents, 0.0);
    for (size_t k = 0; k < K; ++k)
        CHECK_IN("a tangent's p_k has weight 0", coordinates[4 * k + 3] == 0.0);

    reference_linear_blend(expected, &mesh, tangents, 0.0, poses);
    EXPECT_SUCCESS("tangent evaluation", sk_animation_space_evaluate_f64(evaluated,
                                                                         &mesh.influences,
                                                                         coordinates, poses, B, 1, error));
    double *skinning = skinning_matrices_of("skinning matrices", &mesh, poses);
    EXPECT_SUCCESS("tangent linear blend", sk_lbs_evaluate_f64(linear_blend,
                                                               &mesh.influences,
                                                               tangents, 0.0, mesh.weights, skinning, B, 1, error));
    CHECK(close_to(evaluated, expected, 3 * V, 1e-12));
    CHECK(close_to(linear_blend, expected, 3 * V, 1e-12));

    /* Moving every bone must not move a tangent: only the linear parts act on vectors. */
    for (size_t bone = 1; bone < B; ++bone)
        for (int r = 0; r < 3; ++r)
            poses[16 * bone + 4 * r + 3] += random_uniform(5.0, 10.0);
    EXPECT_SUCCESS("translated tangent evaluation", sk_animation_space_evaluate_f64(moved,
                                                                                    &mesh.influences,
                                                                                    coordinates, poses, B, 1, error));
    CHECK(close_to(moved, evaluated, 3 * V, 1e-13));

    free(tangents), free(coordinates), free(poses), free(skinning), free(expected), free(evaluated);
    free(linear_blend), free(moved);
    free_mesh(&mesh);
}

/* ---------------------------------------------------------------------------------------------
 * 3. The rest pose gives back the rest positions
 * ------------------------------------------------------------------------------------------- */

static void test_rest_pose_reproduces_rest_positions(void)
{
    test_mesh mesh = make_random_mesh(400, 6);
    const size_t V = mesh.vertex_count, K = mesh.influence_count, B = mesh.bone_count;
    double *evaluated = allocate(3 * V, sizeof *evaluated), *linear_blend = allocate(3 * V, sizeof *linear_blend);
    float *evaluated_f32 = allocate(3 * V, sizeof *evaluated_f32);

    double *coordinates = converted_coordinates("conversion", &mesh, mesh.rest_positions, 1.0);
    float *coordinates_f32 = to_float(coordinates, 4 * K), *rest_frames_f32 = to_float(mesh.rest_frames, 16 * B);
    EXPECT_SUCCESS("rest pose", sk_animation_space_evaluate_f64(evaluated,
                                                                &mesh.influences,
                                                                coordinates, mesh.rest_frames, B, 1, error));
    EXPECT_SUCCESS("rest pose f32", sk_animation_space_evaluate_f32(evaluated_f32,
                                                                    &mesh.influences,
                                                                    coordinates_f32, rest_frames_f32, B, 1, error));
    double *skinning = skinning_matrices_of("rest skinning matrices", &mesh, mesh.rest_frames);
    EXPECT_SUCCESS("rest pose linear blend", sk_lbs_evaluate_f64(linear_blend,
                                                                 &mesh.influences,
                                                                 mesh.rest_positions, 1.0, mesh.weights, skinning, B,
                                                                 1, error));

    CHECK(close_to(evaluated, mesh.rest_positions, 3 * V, 1e-12));
    CHECK(close_to_f32(evaluated_f32, mesh.rest_positions, 3 * V, 1e-5));
    CHECK(close_to(linear_blend, mesh.rest_positions, 3 * V, 1e-12));
    double identity[16];
    set_identity(identity);
    for (size_t bone = 0; bone < B; ++bone)
        CHECK_IN("rest skinning matrix is the identity", close_to(skinning + 16 * bone, identity, 16, 1e-13));

    free(coordinates), free(skinning), free(evaluated), free(linear_blend), free(evaluated_f32);
    free(coordinates_f32), free(rest_frames_f32);
    free_mesh(&mesh);
}

/* ---------------------------------------------------------------------------------------------
 * 4. The thread count does not change results
 * ------------------------------------------------------------------------------------------- */

typedef struct large_model {
    test_mesh mesh;
    double *coordinates, *poses, *skinning;
    float *coordinates_f32, *poses_f32, *skinning_f32, *positions_f32, *weights_f32;
} large_model;

static large_model make_large_model(size_t vertex_count)
{
    large_model model = {.mesh = make_random_mesh(vertex_count, 6)};
    const test_mesh *mesh = &model.mesh;
    const size_t K = mesh->influence_count, B = mesh->bone_count;
    model.poses = allocate(16 * B, sizeof *model.poses);
    random_frames(model.poses, B);
    model.coordinates = converted_coordinates("large conversion", mesh, mesh->rest_positions, 1.0);
    model.skinning = skinning_matrices_of("large skinning matrices", mesh, model.poses);
    model.coordinates_f32 = to_float(model.coordinates, 4 * K);
    model.poses_f32 = to_float(model.poses, 16 * B);
    model.skinning_f32 = to_float(model.skinning, 16 * B);
    model.positions_f32 = to_float(mesh->rest_positions, 3 * mesh->vertex_count);
    model.weights_f32 = to_float(mesh->weights, K);
    return model;
}

static void free_large_model(large_model *model)
{
    free(model->coordinates), free(model->poses), free(model->skinning), free(model->coordinates_f32);
    free(model->poses_f32), free(model->skinning_f32), free(model->positions_f32), free(model->weights_f32);
    free_mesh(&model->mesh);
}

/* Evaluates the model by all four paths with one thread count; outputs are 3 * V each. */
static void evaluate_all_paths(const large_model *model, int thread_count, double *as64, float *as32, double *lbs64,
                               float *lbs32)
{
    const test_mesh *m = &model->mesh;
    const size_t B = m->bone_count;
    EXPECT_SUCCESS("threaded animation space f64",
                   sk_animation_space_evaluate_f64(as64, &m->influences,
                                                   model->coordinates, model->poses, B, thread_count, error));
    EXPECT_SUCCESS("threaded animation space f32",
                   sk_animation_space_evaluate_f32(as32, &m->influences,
                                                   model->coordinates_f32, model->poses_f32, B, thread_count, error));
    EXPECT_SUCCESS("threaded linear blend f64",
                   sk_lbs_evaluate_f64(lbs64, &m->influences, m->rest_positions, 1.0,
                                       m->weights, model->skinning, B, thread_count, error));
    EXPECT_SUCCESS("threaded linear blend f32",
                   sk_lbs_evaluate_f32(lbs32, &m->influences, model->positions_f32,
                                       1.0f, model->weights_f32, model->skinning_f32, B, thread_count, error));
}

static void test_thread_count_does_not_change_results(void)
{
    const size_t V = 100000;
    /* Without enough vertices every thread count would run on one thread and prove nothing. */
    CHECK(sk_worker_count(V, SK_EVALUATION_ITEMS_PER_WORKER, 2) == 2);
    CHECK(sk_worker_count(V, SK_EVALUATION_ITEMS_PER_WORKER, 7) == 3); /* capped by size: at least 32768 vertices per worker */
    large_model model = make_large_model(V);
    double *as64[2], *lbs64[2];
    float *as32[2], *lbs32[2];
    for (int i = 0; i < 2; ++i) {
        as64[i] = allocate(3 * V, sizeof(double)), lbs64[i] = allocate(3 * V, sizeof(double));
        as32[i] = allocate(3 * V, sizeof(float)), lbs32[i] = allocate(3 * V, sizeof(float));
    }
    evaluate_all_paths(&model, 1, as64[0], as32[0], lbs64[0], lbs32[0]);
    const int thread_counts[] = {2, 0, 7};
    for (size_t t = 0; t < sizeof thread_counts / sizeof thread_counts[0]; ++t) {
        memset(as64[1], 0, 3 * V * sizeof(double)), memset(lbs64[1], 0, 3 * V * sizeof(double));
        memset(as32[1], 0, 3 * V * sizeof(float)), memset(lbs32[1], 0, 3 * V * sizeof(float));
        evaluate_all_paths(&model, thread_counts[t], as64[1], as32[1], lbs64[1], lbs32[1]);
        char context[64];
        snprintf(context, sizeof context, "thread_count %d vs 1", thread_counts[t]);
        CHECK_IN(context, memcmp(as64[0], as64[1], 3 * V * sizeof(double)) == 0);
        CHECK_IN(context, memcmp(as32[0], as32[1], 3 * V * sizeof(float)) == 0);
        CHECK_IN(context, memcmp(lbs64[0], lbs64[1], 3 * V * sizeof(double)) == 0);
        CHECK_IN(context, memcmp(lbs32[0], lbs32[1], 3 * V * sizeof(float)) == 0);
    }
    /* Spot-check that the single-threaded result is right too, against the reference. */
    double *expected = allocate(3 * V, sizeof *expected);
    reference_linear_blend(expected, &model.mesh, model.mesh.rest_positions, 1.0, model.poses);
    CHECK(close_to(as64[0], expected, 3 * V, 1e-12));
    free(expected);
    for (int i = 0; i < 2; ++i)
        free(as64[i]), free(lbs64[i]), free(as32[i]), free(lbs32[i]);
    free_large_model(&model);
}

/* A bad bone in a range evaluated by a worker thread must still be reported, naming its vertex. */
static void test_worker_thread_reports_bad_vertex(void)
{
    const size_t V = 100000;
    large_model model = make_large_model(V);
    test_mesh *m = &model.mesh;
    const size_t bad_vertex = V - 1, B = m->bone_count;
    m->bones[m->offsets[bad_vertex]] = (int32_t)B;
    double *out = allocate(3 * V, sizeof *out);
    const int thread_counts[] = {1, 2, 7};
    for (size_t t = 0; t < sizeof thread_counts / sizeof thread_counts[0]; ++t) {
        sk_error record = empty_error();
        const sk_status status = sk_animation_space_evaluate_f64(out, &m->influences,
                                                                 model.coordinates, model.poses, B, thread_counts[t],
                                                                 &record);
        CHECK(status == SK_ERROR_INDEX && record.status == SK_ERROR_INDEX);
        CHECK_IN(record.message, strstr(record.message, "vertex 99999") != NULL);
    }
    free(out);
    free_large_model(&model);
}

/* ---------------------------------------------------------------------------------------------
 * 5. Errors
 * ------------------------------------------------------------------------------------------- */

/* A malformed influence pattern over 3 bones with identity frames and poses. */
typedef struct csr_case {
    const char *name;
    const int32_t *offsets;
    const int32_t *bones;
    size_t vertex_count, influence_count;
} csr_case;

/* Every entry point that takes an influence pattern must reject the case with SK_ERROR_INDEX. */
static void expect_every_entry_point_rejects(const csr_case *c)
{
    const size_t B = 3, V = c->vertex_count, K = c->influence_count;
    int32_t *offsets = exact_copy_int32(c->offsets, V + 1), *bones = exact_copy_int32(c->bones, K);
    double *frames = identity_frames(B), *vectors = allocate(3 * V, sizeof(double));
    double *weights = allocate(K, sizeof(double)), *coordinates = allocate(4 * K, sizeof(double));
    double *out = allocate(4 * K + 3 * V, sizeof(double));
    float *frames_f32 = to_float(frames, 16 * B), *vectors_f32 = to_float(vectors, 3 * V);
    float *weights_f32 = to_float(weights, K), *coordinates_f32 = to_float(coordinates, 4 * K);
    float *out_f32 = allocate(3 * V, sizeof(float));

    EXPECT_FAILURE(c->name, SK_ERROR_INDEX, sk_validate_influences(&(sk_influences){offsets, bones, V, K}, B, error));
    EXPECT_FAILURE(c->name, SK_ERROR_INDEX, sk_lbs_to_animation_space(out, &(sk_influences){offsets, bones, V, K},
                                                                      vectors, 1.0, weights, frames, B, error));
    EXPECT_FAILURE(c->name, SK_ERROR_INDEX, sk_animation_space_evaluate_f64(out,
                                                                            &(sk_influences){offsets, bones, V, K},
                                                                            coordinates, frames, B, 1, error));
    EXPECT_FAILURE(c->name, SK_ERROR_INDEX, sk_animation_space_evaluate_f32(out_f32,
                                                                            &(sk_influences){offsets, bones, V, K},
                                                                            coordinates_f32, frames_f32, B, 1, error));
    EXPECT_FAILURE(c->name, SK_ERROR_INDEX, sk_lbs_evaluate_f64(out, &(sk_influences){offsets, bones, V, K}, vectors,
                                                                1.0, weights, frames, B, 1, error));
    EXPECT_FAILURE(c->name, SK_ERROR_INDEX, sk_lbs_evaluate_f32(out_f32, &(sk_influences){offsets, bones, V, K},
                                                                vectors_f32, 1.0f, weights_f32, frames_f32, B, 1,
                                                                error));

    free(offsets), free(bones), free(frames), free(vectors), free(weights), free(coordinates), free(out);
    free(frames_f32), free(vectors_f32), free(weights_f32), free(coordinates_f32), free(out_f32);
}

static void test_bad_influence_patterns_are_rejected(void)
{
    static const int32_t two_vertices[] = {0, 1, 3}, good_bones[] = {0, 1, 2};
    static const int32_t negative_bone[] = {0, -1, 2}, bone_at_count[] = {0, 1, 3}, huge_bone[] = {0, INT32_MAX, 1};
    static const int32_t decreasing[] = {0, 2, 1, 3}, first_not_zero[] = {1, 2, 3}, first_negative[] = {-1, 1, 3};
    static const int32_t last_short[] = {0, 1, 2}, last_beyond[] = {0, 1, 4}, middle_beyond[] = {0, 10, 3};
    static const int32_t middle_huge[] = {0, INT32_MAX, 3}, middle_negative[] = {0, -5, 3};
    const csr_case cases[] = {
        {"negative bone index", two_vertices, negative_bone, 2, 3},
        {"bone index == bone_count", two_vertices, bone_at_count, 2, 3},
        {"bone index INT32_MAX", two_vertices, huge_bone, 2, 3},
        {"decreasing offsets", decreasing, good_bones, 3, 3},
        {"offsets[0] != 0", first_not_zero, good_bones, 2, 3},
        {"offsets[0] negative", first_negative, good_bones, 2, 3},
        {"offsets[last] < influence_count", last_short, good_bones, 2, 3},
        {"offsets[last] > influence_count", last_beyond, good_bones, 2, 3},
        {"offset beyond influence_count mid-array", middle_beyond, good_bones, 2, 3},
        {"offset INT32_MAX mid-array", middle_huge, good_bones, 2, 3},
        {"negative offset mid-array", middle_negative, good_bones, 2, 3},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i)
        expect_every_entry_point_rejects(&cases[i]);

    /* The well-formed pattern these cases were derived from is accepted. */
    EXPECT_SUCCESS("good pattern", sk_validate_influences(&(sk_influences){two_vertices, good_bones, 2, 3}, 3, error));
}

static void test_non_finite_input_is_rejected(void)
{
    test_mesh mesh = make_random_mesh(20, 4);
    const size_t V = mesh.vertex_count, K = mesh.influence_count, B = mesh.bone_count;
    double *coordinates = allocate(4 * K, sizeof(double)), *out = allocate(4 * K, sizeof(double));
    double *poses = identity_frames(B), *skinning = allocate(16 * B, sizeof(double));
    const double bad_values[] = {NAN, INFINITY, -INFINITY};
    for (size_t i = 0; i < sizeof bad_values / sizeof bad_values[0]; ++i) {
        const double bad = bad_values[i];
        poses[16 * 2 + 7] = bad;
        float *poses_f32 = to_float(poses, 16 * B), *coordinates_f32 = to_float(coordinates, 4 * K);
        float *vectors_f32 = to_float(mesh.rest_positions, 3 * V), *weights_f32 = to_float(mesh.weights, K);
        float *out_f32 = allocate(3 * V, sizeof(float));
        EXPECT_FAILURE("pose", SK_ERROR_NOT_FINITE, sk_animation_space_evaluate_f64(out,
                                                                                    &mesh.influences,
                                                                                    coordinates, poses, B, 1, error));
        EXPECT_FAILURE("pose f32", SK_ERROR_NOT_FINITE,
                       sk_animation_space_evaluate_f32(out_f32, &mesh.influences,
                                                       coordinates_f32, poses_f32, B, 1, error));
        EXPECT_FAILURE("skinning matrix", SK_ERROR_NOT_FINITE,
                       sk_lbs_evaluate_f64(out, &mesh.influences, mesh.rest_positions,
                                           1.0, mesh.weights, poses, B, 1, error));
        EXPECT_FAILURE("skinning matrix f32", SK_ERROR_NOT_FINITE,
                       sk_lbs_evaluate_f32(out_f32, &mesh.influences, vectors_f32,
                                           1.0f, weights_f32, poses_f32, B, 1, error));
        EXPECT_FAILURE("pose for skinning matrices", SK_ERROR_NOT_FINITE,
                       sk_skinning_matrices(skinning, poses, mesh.rest_frames, B, error));
        free(poses_f32), free(coordinates_f32), free(vectors_f32), free(weights_f32), free(out_f32);
        poses[16 * 2 + 7] = 0.0;
    }

    mesh.rest_positions[3 * 7 + 1] = NAN;
    EXPECT_FAILURE("rest position", SK_ERROR_NOT_FINITE,
                   sk_lbs_to_animation_space(out, &mesh.influences,
                                             mesh.rest_positions, 1.0, mesh.weights, mesh.rest_frames, B, error));
    mesh.rest_positions[3 * 7 + 1] = 0.5;
    EXPECT_SUCCESS("rest position restored", sk_lbs_to_animation_space(out,
                                                                       &mesh.influences,
                                                                       mesh.rest_positions, 1.0, mesh.weights,
                                                                       mesh.rest_frames, B, error));
    EXPECT_FAILURE("homogeneous", SK_ERROR_NOT_FINITE,
                   sk_lbs_to_animation_space(out, &mesh.influences,
                                             mesh.rest_positions, NAN, mesh.weights, mesh.rest_frames, B, error));
    mesh.weights[K - 1] = NAN;
    EXPECT_FAILURE("weight", SK_ERROR_NOT_FINITE,
                   sk_lbs_to_animation_space(out, &mesh.influences,
                                             mesh.rest_positions, 1.0, mesh.weights, mesh.rest_frames, B, error));
    mesh.weights[K - 1] = INFINITY;
    EXPECT_FAILURE("infinite weight", SK_ERROR_NOT_FINITE,
                   sk_lbs_to_animation_space(out, &mesh.influences,
                                             mesh.rest_positions, 1.0, mesh.weights, mesh.rest_frames, B, error));
    mesh.weights[K - 1] = 1.0;
    mesh.rest_frames[16 * 3 + 5] = NAN;
    EXPECT_FAILURE("rest frame", SK_ERROR_NOT_FINITE,
                   sk_lbs_to_animation_space(out, &mesh.influences,
                                             mesh.rest_positions, 1.0, mesh.weights, mesh.rest_frames, B, error));
    static const int32_t chain[] = {-1, 0, 1, 2};
    EXPECT_FAILURE("rest frame in skeleton", SK_ERROR_NOT_FINITE,
                   sk_validate_skeleton(chain, mesh.rest_frames, B, error));
    free(coordinates), free(out), free(poses), free(skinning);
    free_mesh(&mesh);
}

static void test_bad_skeletons_are_rejected(void)
{
    static const int32_t single[] = {-1}, unordered[] = {-1, 2, 0, 1};
    static const int32_t two_cycle[] = {-1, 2, 1}, self_parent[] = {-1, 1}, three_cycle[] = {-1, 2, 3, 1};
    static const int32_t cycle_beside_tree[] = {-1, 0, 3, 2};
    static const int32_t parent_at_count[] = {-1, 3, 0}, second_root[] = {-1, -1, 0}, very_negative[] = {-1, INT32_MIN};
    static const int32_t root_self_parent[] = {0, 0}, root_has_parent[] = {1, -1};

    EXPECT_SUCCESS("single bone", sk_validate_skeleton(single, NULL, 1, error));
    EXPECT_SUCCESS("parents listed after children", sk_validate_skeleton(unordered, NULL, 4, error));
    EXPECT_FAILURE("1 -> 2 -> 1", SK_ERROR_CYCLE, sk_validate_skeleton(two_cycle, NULL, 3, error));
    EXPECT_FAILURE("1 -> 1", SK_ERROR_CYCLE, sk_validate_skeleton(self_parent, NULL, 2, error));
    EXPECT_FAILURE("1 -> 2 -> 3 -> 1", SK_ERROR_CYCLE, sk_validate_skeleton(three_cycle, NULL, 4, error));
    EXPECT_FAILURE("2 -> 3 -> 2 beside 1 -> 0", SK_ERROR_CYCLE, sk_validate_skeleton(cycle_beside_tree, NULL, 4, error));
    EXPECT_FAILURE("parent == bone_count", SK_ERROR_INDEX, sk_validate_skeleton(parent_at_count, NULL, 3, error));
    EXPECT_FAILURE("second root", SK_ERROR_INDEX, sk_validate_skeleton(second_root, NULL, 3, error));
    EXPECT_FAILURE("parent INT32_MIN", SK_ERROR_INDEX, sk_validate_skeleton(very_negative, NULL, 2, error));
    /* The header files "not a tree rooted at bone 0" under SK_ERROR_CYCLE. */
    EXPECT_FAILURE("parents[0] == 0", SK_ERROR_CYCLE, sk_validate_skeleton(root_self_parent, NULL, 2, error));
    EXPECT_FAILURE("parents[0] == 1", SK_ERROR_CYCLE, sk_validate_skeleton(root_has_parent, NULL, 2, error));
}

/* Scales bone 2's frame by `scale` along one axis, in a rotated basis so the SVD has work to do. */
static void squash_one_axis(double *frames, double scale)
{
    double rotation[9];
    const double scales[3] = {1.5, scale, 0.8}, translation[3] = {0.3, -1.0, 2.0};
    random_rotation(rotation);
    make_frame(frames + 16 * 2, rotation, scales, translation);
}

/* The rest frames must be rejected (or accepted) alike by every function that validates them. */
static void expect_rest_frames_status(const char *context, const double *frames, sk_status expected)
{
    static const int32_t parents[] = {-1, 0, 1, 2}, offsets[] = {0, 2, 4}, bones[] = {0, 2, 1, 3};
    static const double vectors[6] = {1, 2, 3, 4, 5, 6}, weights[4] = {0.5, 0.5, 0.25, 0.75};
    double poses[64], out[64];
    for (size_t bone = 0; bone < 4; ++bone)
        set_identity(poses + 16 * bone);
    if (expected == SK_OK) {
        EXPECT_SUCCESS(context, sk_validate_skeleton(parents, frames, 4, error));
        EXPECT_SUCCESS(context, sk_skinning_matrices(out, poses, frames, 4, error));
        EXPECT_SUCCESS(context, sk_lbs_to_animation_space(out, &(sk_influences){offsets, bones, 2, 4}, vectors, 1.0,
                                                          weights, frames, 4, error));
        return;
    }
    EXPECT_FAILURE(context, expected, sk_validate_skeleton(parents, frames, 4, error));
    EXPECT_FAILURE(context, expected, sk_skinning_matrices(out, poses, frames, 4, error));
    EXPECT_FAILURE(context, expected,
                   sk_lbs_to_animation_space(out, &(sk_influences){offsets, bones, 2, 4}, vectors, 1.0, weights,
                                             frames, 4, error));
}

static void test_bad_rest_frames_are_rejected(void)
{
    double frames[64];
    random_frames(frames, 4);
    expect_rest_frames_status("random well-conditioned frames", frames, SK_OK);
    squash_one_axis(frames, 1e-6);
    expect_rest_frames_status("condition number ~1e6 is accepted", frames, SK_OK);
    squash_one_axis(frames, 0.0);
    expect_rest_frames_status("zero scale on one axis", frames, SK_ERROR_SINGULAR);
    squash_one_axis(frames, 1e-14);
    expect_rest_frames_status("scale 1e-14 on one axis", frames, SK_ERROR_SINGULAR);
    memset(frames + 16 * 2, 0, 12 * sizeof(double));
    expect_rest_frames_status("zero linear part", frames, SK_ERROR_SINGULAR);

    random_frames(frames, 4);
    frames[16 * 3 + 12] = 0.25;
    expect_rest_frames_status("bottom row (0.25 0 0 1)", frames, SK_ERROR_ARGUMENT);
    frames[16 * 3 + 12] = 0.0;
    frames[16 * 3 + 15] = 2.0;
    expect_rest_frames_status("bottom row (0 0 0 2)", frames, SK_ERROR_ARGUMENT);
}

/* A tiny valid model: every null pointer below is its only defect. */
static void test_null_pointers_are_rejected(void)
{
    static const int32_t parents[] = {-1, 0}, offsets[] = {0, 1, 3}, bones[] = {0, 0, 1};
    const double vectors[6] = {1, 2, 3, 4, 5, 6}, weights[3] = {1.0, 0.5, 0.5};
    const float vectors_f32[6] = {1, 2, 3, 4, 5, 6}, weights_f32[3] = {1.0f, 0.5f, 0.5f};
    double frames[32], out[32], coordinates[12] = {0};
    float frames_f32[32], out_f32[32], coordinates_f32[12] = {0};
    set_identity(frames), set_identity(frames + 16);
    for (int i = 0; i < 32; ++i)
        frames_f32[i] = (float)frames[i];
    const size_t V = 2, K = 3, B = 2;

    EXPECT_FAILURE("parents", SK_ERROR_ARGUMENT, sk_validate_skeleton(NULL, frames, B, error));
    EXPECT_FAILURE("no bones", SK_ERROR_ARGUMENT, sk_validate_skeleton(parents, frames, 0, error));
    EXPECT_FAILURE("offsets", SK_ERROR_ARGUMENT, sk_validate_influences(&(sk_influences){NULL, bones, V, K}, B, error));
    EXPECT_FAILURE("bones", SK_ERROR_ARGUMENT, sk_validate_influences(&(sk_influences){offsets, NULL, V, K}, B, error));

    /* Each function once per pointer argument, that argument NULL: names[k] names the call with argument k NULL. */
#define NULL_IF(k, pointer) (nulled == (k) ? NULL : (pointer))
#define EXPECT_EACH_NULL_REFUSED(names, call)                                                                  \
    for (int nulled = 0; nulled < (int)(sizeof names / sizeof names[0]); ++nulled)                            \
        EXPECT_FAILURE(names[nulled], SK_ERROR_ARGUMENT, call)

#define CONVERT(dst, vec, off, bon, wei, fra) sk_lbs_to_animation_space(dst, &(sk_influences){off, bon, V, K}, vec, 1.0, wei, fra, B, error)
    static const char *const conversion[] = {"conversion destination", "conversion vectors", "conversion offsets",
                                             "conversion bones", "conversion weights", "conversion frames"};
    EXPECT_SUCCESS("conversion", CONVERT(out, vectors, offsets, bones, weights, frames));
    EXPECT_EACH_NULL_REFUSED(conversion, CONVERT(NULL_IF(0, out), NULL_IF(1, vectors), NULL_IF(2, offsets),
                                                 NULL_IF(3, bones), NULL_IF(4, weights), NULL_IF(5, frames)));
#undef CONVERT

    static const char *const skinning[] = {"skinning destination", "skinning poses", "skinning frames"};
    EXPECT_SUCCESS("skinning matrices", sk_skinning_matrices(out, frames, frames, B, error));
    EXPECT_EACH_NULL_REFUSED(skinning, sk_skinning_matrices(NULL_IF(0, out), NULL_IF(1, frames), NULL_IF(2, frames),
                                                            B, error));
    EXPECT_FAILURE("skinning no bones", SK_ERROR_ARGUMENT, sk_skinning_matrices(out, frames, frames, 0, error));

#define AS64(dst, off, bon, coo, pos, b) sk_animation_space_evaluate_f64(dst, &(sk_influences){off, bon, V, K}, coo, pos, b, 1, error)
#define AS32(dst, off, bon, coo, pos, b) sk_animation_space_evaluate_f32(dst, &(sk_influences){off, bon, V, K}, coo, pos, b, 1, error)
    static const char *const as64[] = {"as destination", "as offsets", "as bones", "as coordinates", "as poses"};
    static const char *const as32[] = {"as32 destination", "as32 offsets", "as32 bones", "as32 coordinates",
                                       "as32 poses"};
    EXPECT_SUCCESS("animation space", AS64(out, offsets, bones, coordinates, frames, B));
    EXPECT_EACH_NULL_REFUSED(as64, AS64(NULL_IF(0, out), NULL_IF(1, offsets), NULL_IF(2, bones),
                                        NULL_IF(3, coordinates), NULL_IF(4, frames), B));
    EXPECT_FAILURE("as no bones", SK_ERROR_ARGUMENT, AS64(out, offsets, bones, coordinates, frames, 0));
    EXPECT_SUCCESS("animation space f32", AS32(out_f32, offsets, bones, coordinates_f32, frames_f32, B));
    EXPECT_EACH_NULL_REFUSED(as32, AS32(NULL_IF(0, out_f32), NULL_IF(1, offsets), NULL_IF(2, bones),
                                        NULL_IF(3, coordinates_f32), NULL_IF(4, frames_f32), B));
    EXPECT_FAILURE("as32 no bones", SK_ERROR_ARGUMENT, AS32(out_f32, offsets, bones, coordinates_f32, frames_f32, 0));
#undef AS64
#undef AS32

#define LBS64(dst, vec, off, bon, wei, mat) sk_lbs_evaluate_f64(dst, &(sk_influences){off, bon, V, K}, vec, 1.0, wei, mat, B, 1, error)
#define LBS32(dst, vec, off, bon, wei, mat) sk_lbs_evaluate_f32(dst, &(sk_influences){off, bon, V, K}, vec, 1.0f, wei, mat, B, 1, error)
    static const char *const lbs64[] = {"lbs destination", "lbs vectors", "lbs offsets", "lbs bones", "lbs weights",
                                        "lbs matrices"};
    static const char *const lbs32[] = {"lbs32 destination", "lbs32 vectors", "lbs32 offsets", "lbs32 bones",
                                        "lbs32 weights", "lbs32 matrices"};
    EXPECT_SUCCESS("linear blend", LBS64(out, vectors, offsets, bones, weights, frames));
    EXPECT_EACH_NULL_REFUSED(lbs64, LBS64(NULL_IF(0, out), NULL_IF(1, vectors), NULL_IF(2, offsets), NULL_IF(3, bones),
                                          NULL_IF(4, weights), NULL_IF(5, frames)));
    EXPECT_SUCCESS("linear blend f32", LBS32(out_f32, vectors_f32, offsets, bones, weights_f32, frames_f32));
    EXPECT_EACH_NULL_REFUSED(lbs32, LBS32(NULL_IF(0, out_f32), NULL_IF(1, vectors_f32), NULL_IF(2, offsets),
                                          NULL_IF(3, bones), NULL_IF(4, weights_f32), NULL_IF(5, frames_f32)));
#undef LBS64
#undef LBS32
#undef EXPECT_EACH_NULL_REFUSED
#undef NULL_IF
}

/* Successful calls must also accept error == NULL. */
static void test_success_without_error_record(void)
{
    static const int32_t parents[] = {-1, 0}, offsets[] = {0, 1, 3}, bones[] = {0, 0, 1};
    const double vectors[6] = {1, 2, 3, 4, 5, 6}, weights[3] = {1.0, 0.5, 0.5};
    double frames[32], out[32], coordinates[12];
    set_identity(frames), set_identity(frames + 16);
    CHECK(sk_validate_skeleton(parents, frames, 2, NULL) == SK_OK);
    CHECK(sk_validate_influences(&(sk_influences){offsets, bones, 2, 3}, 2, NULL) == SK_OK);
    CHECK(sk_lbs_to_animation_space(coordinates, &(sk_influences){offsets, bones, 2, 3}, vectors, 1.0, weights,
                                    frames, 2, NULL) == SK_OK);
    CHECK(sk_skinning_matrices(out, frames, frames, 2, NULL) == SK_OK);
    CHECK(sk_animation_space_evaluate_f64(out, &(sk_influences){offsets, bones, 2, 3}, coordinates, frames, 2, 1,
                                          NULL) == SK_OK);
    CHECK(sk_lbs_evaluate_f64(out, &(sk_influences){offsets, bones, 2, 3}, vectors, 1.0, weights, frames, 2, 1, NULL) == SK_OK);
    CHECK(close_to(out, vectors, 6, 1e-15));
}

/* ---------------------------------------------------------------------------------------------
 * 6. Empty meshes and vertices without influences
 * ------------------------------------------------------------------------------------------- */

static void test_zero_vertices(void)
{
    static const int32_t offsets[] = {0};
    double frames[16], canary[3] = {7, 7, 7}, dummy[3] = {0, 0, 0};
    float canary_f32[3] = {7, 7, 7}, frame_f32[16];
    set_identity(frames);
    for (int i = 0; i < 16; ++i)
        frame_f32[i] = (float)frames[i];
    /* With no influences, bones, coordinates and weights may be NULL (the header allows it). */
    EXPECT_SUCCESS("validate", sk_validate_influences(&(sk_influences){offsets, NULL, 0, 0}, 1, error));
    EXPECT_SUCCESS("convert", sk_lbs_to_animation_space(canary, &(sk_influences){offsets, NULL, 0, 0}, dummy, 1.0,
                                                        dummy, frames, 1, error));
    EXPECT_SUCCESS("as f64", sk_animation_space_evaluate_f64(canary, &(sk_influences){offsets, NULL, 0, 0}, NULL,
                                                             frames, 1, 0, error));
    EXPECT_SUCCESS("as f32", sk_animation_space_evaluate_f32(canary_f32, &(sk_influences){offsets, NULL, 0, 0}, NULL,
                                                             frame_f32, 1, 0, error));
    EXPECT_SUCCESS("lbs f64", sk_lbs_evaluate_f64(canary, &(sk_influences){offsets, NULL, 0, 0}, NULL, 1.0, NULL,
                                                  frames, 1, 0, error));
    EXPECT_SUCCESS("lbs f32", sk_lbs_evaluate_f32(canary_f32, &(sk_influences){offsets, NULL, 0, 0}, NULL, 1.0f, NULL,
                                                  frame_f32, 1, 0, error));
    CHECK_IN("nothing written for zero vertices", canary[0] == 7 && canary[1] == 7 && canary[2] == 7);
    CHECK_IN("nothing written for zero vertices", canary_f32[0] == 7 && canary_f32[1] == 7 && canary_f32[2] == 7);
}

static int is_origin(const double *v)
{
    return v[0] == 0.0 && v[1] == 0.0 && v[2] == 0.0;
}

static int is_origin_f32(const float *v)
{
    return v[0] == 0.0f && v[1] == 0.0f && v[2] == 0.0f;
}

static void test_vertices_without_influences(void)
{
    /* Vertices 0, 2 and 4 have no influences; 1 and 3 do. */
    test_mesh mesh = {.vertex_count = 5, .influence_count = 3, .bone_count = 3};
    int32_t offsets[] = {0, 0, 2, 2, 3, 3}, bones[] = {1, 2, 1};
    double weights[] = {0.25, 0.75, 1.0}, positions[15], frames[48], poses[48];
    random_vectors(positions, 5);
    random_frames(frames, 3);
    random_frames(poses, 3);
    mesh.offsets = offsets, mesh.bones = bones, mesh.weights = weights;
    mesh.rest_positions = positions, mesh.rest_frames = frames;

    double coordinates[12], out[15], expected[15];
    float out_f32[15];
    for (int i = 0; i < 15; ++i)
        out[i] = 99.0, out_f32[i] = 99.0f; /* garbage the evaluation must overwrite with zeros */
    EXPECT_SUCCESS("convert", sk_lbs_to_animation_space(coordinates, &(sk_influences){offsets, bones, 5, 3},
                                                        positions, 1.0, weights, frames, 3, error));
    float *coordinates_f32 = to_float(coordinates, 12), *poses_f32 = to_float(poses, 48);
    EXPECT_SUCCESS("as f64", sk_animation_space_evaluate_f64(out, &(sk_influences){offsets, bones, 5, 3}, coordinates,
                                                             poses, 3, 1, error));
    EXPECT_SUCCESS("as f32", sk_animation_space_evaluate_f32(out_f32, &(sk_influences){offsets, bones, 5, 3},
                                                             coordinates_f32, poses_f32, 3, 1, error));
    reference_linear_blend(expected, &mesh, positions, 1.0, poses);
    for (int vertex = 0; vertex < 5; vertex += 2) {
        CHECK_IN("unweighted vertex evaluates to the origin", is_origin(out + 3 * vertex));
        CHECK_IN("unweighted vertex evaluates to the origin (f32)", is_origin_f32(out_f32 + 3 * vertex));
    }
    CHECK(close_to(out + 3, expected + 3, 3, 1e-12));
    CHECK(close_to(out + 9, expected + 9, 3, 1e-12));
    CHECK(close_to_f32(out_f32 + 3, expected + 3, 3, 1e-5));

    for (int i = 0; i < 15; ++i)
        out[i] = 99.0;
    EXPECT_SUCCESS("lbs f64", sk_lbs_evaluate_f64(out, &(sk_influences){offsets, bones, 5, 3}, positions, 1.0,
                                                  weights, poses, 3, 1, error));
    CHECK_IN("unweighted vertex evaluates to the origin (lbs)", is_origin(out) && is_origin(out + 6) && is_origin(out + 12));
    free(coordinates_f32), free(poses_f32);
}

static void test_triangles_are_validated(void)
{
    static const int32_t good[] = {0, 1, 2, 0, 2, 3}, out_of_range[] = {0, 1, 2, 0, 2, 4},
                         negative[] = {0, -1, 2}, repeated[] = {0, 1, 2, 3, 3, 1};
    int32_t *exact = exact_copy_int32(out_of_range, 6); /* a read past the end would trip ASan */
    EXPECT_SUCCESS("valid triangles", sk_validate_triangles(&(sk_triangle_mesh){good, 2, 4}, error));
    EXPECT_SUCCESS("no triangles", sk_validate_triangles(&(sk_triangle_mesh){NULL, 0, 0}, error));
    EXPECT_FAILURE("index past the vertices", SK_ERROR_INDEX, sk_validate_triangles(&(sk_triangle_mesh){exact, 2, 4},
                                                                                    error));
    EXPECT_FAILURE("negative index", SK_ERROR_INDEX, sk_validate_triangles(&(sk_triangle_mesh){negative, 1, 4}, error));
    EXPECT_FAILURE("repeated vertex", SK_ERROR_ARGUMENT, sk_validate_triangles(&(sk_triangle_mesh){repeated, 2, 4},
                                                                               error));
    EXPECT_FAILURE("null triangles", SK_ERROR_ARGUMENT, sk_validate_triangles(&(sk_triangle_mesh){NULL, 1, 4}, error));
    free(exact);
}

/* ---------------------------------------------------------------------------------------------
 * 7. Status names
 * ------------------------------------------------------------------------------------------- */

static void test_status_names(void)
{
    const sk_status statuses[] = {SK_OK, SK_ERROR_ARGUMENT, SK_ERROR_INDEX, SK_ERROR_NOT_FINITE,
                                  SK_ERROR_CYCLE, SK_ERROR_SINGULAR, SK_ERROR_MEMORY, SK_ERROR_LAPACK};
    const size_t count = sizeof statuses / sizeof statuses[0];
    for (size_t i = 0; i < count; ++i) {
        const char *name = sk_status_name(statuses[i]);
        CHECK(name != NULL && name[0] != '\0');
        /* Distinct names: a copy-paste slip in the switch would make two statuses read alike. */
        for (size_t j = 0; j < i; ++j)
            CHECK(name && strcmp(name, sk_status_name(statuses[j])) != 0);
    }
    const char *unknown = sk_status_name((sk_status)99);
    CHECK(unknown != NULL && unknown[0] != '\0');
}

int main(void)
{
    test_program_name = "test_core";
    test_conversion_reproduces_linear_blend_skinning();
    test_tangents_ignore_translation();
    test_rest_pose_reproduces_rest_positions();
    test_thread_count_does_not_change_results();
    test_worker_thread_reports_bad_vertex();
    test_bad_influence_patterns_are_rejected();
    test_non_finite_input_is_rejected();
    test_bad_skeletons_are_rejected();
    test_bad_rest_frames_are_rejected();
    test_null_pointers_are_rejected();
    test_success_without_error_record();
    test_zero_vertices();
    test_vertices_without_influences();
    test_triangles_are_validated();
    test_status_names();
    return finish_tests();
}
