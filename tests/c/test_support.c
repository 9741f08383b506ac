/*
 * Helpers shared by the standalone C test programs (test_core.c, test_fit.c): check counting, the
 * EXPECT_FAILURE / EXPECT_SUCCESS error-record protocol, deterministic random numbers, exactly
 * sized heap copies for the sanitizers, an independent 4x4 algebra and a random skinned mesh.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "test_support.h"

const char *test_program_name = "test";

/* ---------------------------------------------------------------------------------------------
 * Checks
 * ------------------------------------------------------------------------------------------- */

int passed_checks, failed_checks;

int record_check(int ok, const char *file, int line, const char *expression, const char *context)
{
    if (ok) {
        ++passed_checks;
        return 1;
    }
    ++failed_checks;
    fprintf(stderr, "%s:%d: CHECK failed: %s%s%s\n", file, line, expression, context ? "  -- " : "",
            context ? context : "");
    return 0;
}

/* A record a failing call must overwrite: the checks below would pass on it only if it did. */
sk_error empty_error(void)
{
    sk_error error = {.status = SK_OK, .message = ""};
    return error;
}

/* A record a successful call must clear. */
sk_error stale_error(void)
{
    sk_error error = {.status = SK_ERROR_MEMORY, .message = "stale message"};
    return error;
}

void expect_failure_at(const char *file, int line, const char *context, sk_status returned,
                       const sk_error *record, sk_status expected)
{
    char details[SK_MESSAGE_SIZE + 160];
    snprintf(details, sizeof details, "%s: returned \"%s\", expected \"%s\", message \"%s\"", context,
             sk_status_name(returned), sk_status_name(expected), record->message);
    record_check(returned == expected, file, line, "returned status", details);
    record_check(record->status == expected, file, line, "error->status", details);
    record_check(record->message[0] != '\0', file, line, "error->message is not empty", details);
}

void expect_success_at(const char *file, int line, const char *context, sk_status returned,
                       const sk_error *record)
{
    char details[SK_MESSAGE_SIZE + 160];
    snprintf(details, sizeof details, "%s: returned \"%s\", message \"%s\"", context, sk_status_name(returned),
             record->message);
    record_check(returned == SK_OK, file, line, "returned SK_OK", details);
    record_check(record->status == SK_OK && record->message[0] == '\0', file, line, "error record cleared",
                 details);
}

/* ---------------------------------------------------------------------------------------------
 * Small utilities: deterministic random numbers, allocation, array comparison
 * ------------------------------------------------------------------------------------------- */

static uint64_t random_state = 0x2545F4914F6CDD1DULL;

/* splitmix64: fixed seed, so a failure reproduces exactly. */
uint64_t random_bits(void)
{
    uint64_t z = (random_state += 0x9E3779B97F4A7C15ULL);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    return z ^ (z >> 31);
}

double random_uniform(double low, double high)
{
    return low + (high - low) * ((double)(random_bits() >> 11) * 0x1.0p-53);
}

size_t random_below(size_t bound)
{
    return (size_t)(random_bits() % bound);
}

/* Allocation failure in a test is not something to recover from. */
void *allocate(size_t count, size_t size)
{
    void *block = calloc(count ? count : 1, size);
    if (!block) {
        fprintf(stderr, "%s: out of memory\n", test_program_name);
        exit(2);
    }
    return block;
}

/* An exactly sized heap copy (even of zero elements), so the sanitizer flags any read past it. */
static void *exact_copy(const void *values, size_t count, size_t size)
{
    void *copy = malloc(count * size);
    if (!copy && count) {
        fprintf(stderr, "%s: out of memory\n", test_program_name);
        exit(2);
    }
    if (count)
        memcpy(copy, values, count * size);
    return copy;
}

int32_t *exact_copy_int32(const int32_t *values, size_t count)
{
    return exact_copy(values, count, sizeof *values);
}

double *exact_copy_double(const double *values, size_t count)
{
    return exact_copy(values, count, sizeof *values);
}

double max_abs(const double *values, size_t count)
{
    double largest = 0.0;
    for (size_t i = 0; i < count; ++i)
        largest = fmax(largest, fabs(values[i]));
    return largest;
}

int all_finite(const double *values, size_t count)
{
    for (size_t i = 0; i < count; ++i)
        if (!isfinite(values[i]))
            return 0;
    return 1;
}

double max_abs_difference(const double *a, const double *b, size_t count)
{
    double largest = 0.0;
    for (size_t i = 0; i < count; ++i)
        largest = fmax(largest, fabs(a[i] - b[i]));
    return largest;
}

/* Tolerances are relative to the coordinate scale (at least 1), so they mean the same at any size. */
double coordinate_scale(const double *reference, size_t count)
{
    return fmax(1.0, max_abs(reference, count));
}

int same_across_threads(const double *threaded, const double *single, size_t count)
{
#ifdef _WIN32
    /* Relative to the whole array's scale: a weight the main thread's LAPACK rounds to 0 may come out 1e-17 on a
     * worker, which no per-entry relative tolerance allows. */
    return close_to(threaded, single, count, 1e-10);
#else
    return count == 0 || memcmp(threaded, single, count * sizeof *threaded) == 0;
#endif
}

int close_to(const double *actual, const double *reference, size_t count, double relative_tolerance)
{
    const double difference = max_abs_difference(actual, reference, count);
    return difference <= relative_tolerance * coordinate_scale(reference, count);
}

double dot_product(const double *a, const double *b, size_t n)
{
    double sum = 0.0;
    for (size_t i = 0; i < n; ++i)
        sum += a[i] * b[i];
    return sum;
}

double euclidean_norm(const double *v, size_t n)
{
    return sqrt(dot_product(v, v, n));
}

void dense_apply(const double *a, size_t rows, size_t cols, int transpose, const double *x, double *y)
{
    if (!transpose) {
        for (size_t r = 0; r < rows; ++r)
            y[r] = dot_product(a + r * cols, x, cols);
    } else {
        for (size_t c = 0; c < cols; ++c)
            y[c] = 0.0;
        for (size_t r = 0; r < rows; ++r)
            for (size_t c = 0; c < cols; ++c)
                y[c] += a[r * cols + c] * x[r];
    }
}

int record_progress(void *user, double fraction)
{
    progress_log *log = user;
    if (log->calls < 64)
        log->fractions[log->calls] = fraction;
    ++log->calls;
    return log->cancel_at > 0 && log->calls >= log->cancel_at;
}

/* ---------------------------------------------------------------------------------------------
 * Independent 4x4 algebra (row-major, like the core), written without looking at the core's
 * cofactor inverse: Gauss-Jordan elimination with partial pivoting on the full 4x4 matrix.
 * ------------------------------------------------------------------------------------------- */

void set_identity(double m[16])
{
    for (int i = 0; i < 16; ++i)
        m[i] = (i % 5 == 0) ? 1.0 : 0.0;
}

void multiply(double destination[16], const double a[16], const double b[16])
{
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) {
            double sum = 0.0;
            for (int k = 0; k < 4; ++k)
                sum += a[4 * r + k] * b[4 * k + c];
            destination[4 * r + c] = sum;
        }
}

static void swap_rows(double m[16], int a, int b)
{
    for (int c = 0; c < 4; ++c) {
        const double t = m[4 * a + c];
        m[4 * a + c] = m[4 * b + c];
        m[4 * b + c] = t;
    }
}

static int largest_pivot_row(const double m[16], int column)
{
    int best = column;
    for (int r = column + 1; r < 4; ++r)
        if (fabs(m[4 * r + column]) > fabs(m[4 * best + column]))
            best = r;
    return best;
}

/* Returns 0 for a singular matrix. */
int invert_gauss_jordan(double inverse[16], const double matrix[16])
{
    double m[16];
    memcpy(m, matrix, sizeof m);
    set_identity(inverse);
    for (int column = 0; column < 4; ++column) {
        const int pivot = largest_pivot_row(m, column);
        if (m[4 * pivot + column] == 0.0)
            return 0;
        swap_rows(m, column, pivot);
        swap_rows(inverse, column, pivot);
        const double scale = 1.0 / m[4 * column + column];
        for (int c = 0; c < 4; ++c) {
            m[4 * column + c] *= scale;
            inverse[4 * column + c] *= scale;
        }
        for (int r = 0; r < 4; ++r) {
            const double factor = m[4 * r + column];
            if (r == column || factor == 0.0)
                continue;
            for (int c = 0; c < 4; ++c) {
                m[4 * r + c] -= factor * m[4 * column + c];
                inverse[4 * r + c] -= factor * inverse[4 * column + c];
            }
        }
    }
    return 1;
}

/* out = top three rows of m * (v, h) */
void transform(double out[3], const double m[16], const double v[3], double h)
{
    for (int r = 0; r < 3; ++r)
        out[r] = m[4 * r] * v[0] + m[4 * r + 1] * v[1] + m[4 * r + 2] * v[2] + m[4 * r + 3] * h;
}

/* A uniformly random rotation from a normalised random quaternion. */
void random_rotation(double r[9])
{
    double w, x, y, z, norm;
    do {
        w = random_uniform(-1, 1), x = random_uniform(-1, 1), y = random_uniform(-1, 1), z = random_uniform(-1, 1);
        norm = sqrt(w * w + x * x + y * y + z * z);
    } while (norm < 0.1 || norm > 1.0);
    w /= norm, x /= norm, y /= norm, z /= norm;
    const double rotation[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - w * z),     2 * (x * z + w * y),
                                2 * (x * y + w * z),     1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                                2 * (x * z - w * y),     2 * (y * z + w * x),     1 - 2 * (x * x + y * y)};
    memcpy(r, rotation, sizeof rotation);
}

/* rotation * diag(scales), then translation: an affine frame with condition number max/min scale. */
void make_frame(double frame[16], const double rotation[9], const double scales[3], const double translation[3])
{
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c)
            frame[4 * r + c] = rotation[3 * r + c] * scales[c];
        frame[4 * r + 3] = translation[r];
    }
    frame[12] = frame[13] = frame[14] = 0.0;
    frame[15] = 1.0;
}

void random_frame(double frame[16], double min_scale, double max_scale, double max_translation)
{
    double rotation[9], scales[3], translation[3];
    random_rotation(rotation);
    for (int i = 0; i < 3; ++i) {
        scales[i] = random_uniform(min_scale, max_scale);
        translation[i] = random_uniform(-max_translation, max_translation);
    }
    make_frame(frame, rotation, scales, translation);
}

void random_scaled_frames(double *frames, size_t count, double max_translation)
{
    for (size_t k = 0; k < count; ++k)
        random_frame(frames + 16 * k, 0.5, 2.0, max_translation);
}

/* Bone 0 never animates (G_0 = I); the others get random well-conditioned frames. */
void random_frames(double *frames, size_t bone_count)
{
    set_identity(frames);
    for (size_t bone = 1; bone < bone_count; ++bone)
        random_frame(frames + 16 * bone, 0.5, 2.0, 3.0);
}

double *identity_frames(size_t bone_count)
{
    double *frames = allocate(16 * bone_count, sizeof *frames);
    for (size_t bone = 0; bone < bone_count; ++bone)
        set_identity(frames + 16 * bone);
    return frames;
}

/* ---------------------------------------------------------------------------------------------
 * A random skinned mesh
 * ------------------------------------------------------------------------------------------- */

/* Picks `count` distinct bones with a partial Fisher-Yates shuffle. */
void pick_distinct_bones(int32_t *chosen, size_t count, size_t bone_count)
{
    int32_t all[64];
    for (size_t bone = 0; bone < bone_count; ++bone)
        all[bone] = (int32_t)bone;
    for (size_t i = 0; i < count; ++i) {
        const size_t j = i + random_below(bone_count - i);
        const int32_t t = all[i];
        all[i] = all[j];
        all[j] = t;
        chosen[i] = all[i];
    }
}

void normalise(double *weights, size_t count)
{
    double sum = 0.0;
    for (size_t i = 0; i < count; ++i)
        sum += weights[i];
    for (size_t i = 0; i < count; ++i)
        weights[i] /= sum;
}

test_mesh make_random_mesh(size_t vertex_count, size_t bone_count)
{
    const size_t max_influences = bone_count < 4 ? bone_count : 4;
    test_mesh mesh = {.vertex_count = vertex_count, .bone_count = bone_count};
    mesh.offsets = allocate(vertex_count + 1, sizeof *mesh.offsets);
    mesh.bones = allocate(vertex_count * max_influences, sizeof *mesh.bones);
    mesh.weights = allocate(vertex_count * max_influences, sizeof *mesh.weights);
    mesh.rest_positions = allocate(3 * vertex_count, sizeof *mesh.rest_positions);
    mesh.rest_frames = allocate(16 * bone_count, sizeof *mesh.rest_frames);
    random_frames(mesh.rest_frames, bone_count);
    size_t k = 0;
    for (size_t vertex = 0; vertex < vertex_count; ++vertex) {
        const size_t count = 1 + random_below(max_influences);
        pick_distinct_bones(mesh.bones + k, count, bone_count);
        for (size_t i = 0; i < count; ++i)
            mesh.weights[k + i] = random_uniform(0.05, 1.0);
        normalise(mesh.weights + k, count);
        k += count;
        mesh.offsets[vertex + 1] = (int32_t)k;
        for (int axis = 0; axis < 3; ++axis)
            mesh.rest_positions[3 * vertex + axis] = random_uniform(-2.0, 2.0);
    }
    mesh.influence_count = k;
    mesh.influences = (sk_influences){mesh.offsets, mesh.bones, vertex_count, k};
    return mesh;
}

void free_mesh(test_mesh *mesh)
{
    free(mesh->offsets);
    free(mesh->bones);
    free(mesh->weights);
    free(mesh->rest_positions);
    free(mesh->rest_frames);
}

/* The per-bone inverse rest frames, by the independent Gauss-Jordan inverse. */
double *reference_inverse_rest_frames(const test_mesh *mesh)
{
    double *inverses = allocate(16 * mesh->bone_count, sizeof *inverses);
    for (size_t bone = 0; bone < mesh->bone_count; ++bone)
        CHECK(invert_gauss_jordan(inverses + 16 * bone, mesh->rest_frames + 16 * bone));
    return inverses;
}

/* Linear blend skinning straight from its definition: sum_k w_k G_j inverse(R_j) (v, h). */
void reference_linear_blend(double *destination, const test_mesh *mesh, const double *vectors, double h,
                            const double *poses)
{
    double *inverses = reference_inverse_rest_frames(mesh);
    for (size_t vertex = 0; vertex < mesh->vertex_count; ++vertex) {
        double sum[3] = {0, 0, 0};
        for (int32_t k = mesh->offsets[vertex]; k < mesh->offsets[vertex + 1]; ++k) {
            double skinning[16], moved[3];
            multiply(skinning, poses + 16 * mesh->bones[k], inverses + 16 * mesh->bones[k]);
            transform(moved, skinning, vectors + 3 * vertex, h);
            for (int axis = 0; axis < 3; ++axis)
                sum[axis] += mesh->weights[k] * moved[axis];
        }
        memcpy(destination + 3 * vertex, sum, sizeof sum);
    }
    free(inverses);
}

/* Animation-space coordinates straight from eq. 3.1: p_k = w_k inverse(R_j) (v, h). */
void reference_coordinates(double *coordinates, const test_mesh *mesh, const double *vectors, double h)
{
    double *inverses = reference_inverse_rest_frames(mesh);
    for (size_t vertex = 0; vertex < mesh->vertex_count; ++vertex)
        for (int32_t k = mesh->offsets[vertex]; k < mesh->offsets[vertex + 1]; ++k) {
            double *p = coordinates + 4 * k;
            transform(p, inverses + 16 * mesh->bones[k], vectors + 3 * vertex, h);
            for (int axis = 0; axis < 3; ++axis)
                p[axis] *= mesh->weights[k];
            p[3] = mesh->weights[k] * h;
        }
    free(inverses);
}

void random_vectors(double *vectors, size_t vertex_count)
{
    for (size_t i = 0; i < 3 * vertex_count; ++i)
        vectors[i] = random_uniform(-1.0, 1.0);
}

int finish_tests(void)
{
    printf("%d passed, %d failed\n", passed_checks, failed_checks);
    return failed_checks > 0;
}

double *converted_coordinates(const char *context, const test_mesh *mesh, const double *vectors, double homogeneous)
{
    double *coordinates = allocate(4 * mesh->influence_count, sizeof *coordinates);
    EXPECT_SUCCESS(context, sk_lbs_to_animation_space(coordinates, &mesh->influences, vectors, homogeneous,
                                                      mesh->weights, mesh->rest_frames, mesh->bone_count, error));
    return coordinates;
}

double *skinning_matrices_of(const char *context, const test_mesh *mesh, const double *poses)
{
    double *skinning = allocate(16 * mesh->bone_count, sizeof *skinning);
    EXPECT_SUCCESS(context, sk_skinning_matrices(skinning, poses, mesh->rest_frames, mesh->bone_count, error));
    return skinning;
}
