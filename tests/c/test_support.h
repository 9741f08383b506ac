/*
 * Helpers shared by the standalone C test programs (test_core.c, test_fit.c).
 *
 * Checks count into passed_checks / failed_checks; finish_tests() prints the closing
 * "N passed, M failed" line and returns the exit status. Random numbers come from one fixed-seed
 * generator, so a program's sequence (and any failure) reproduces exactly from run to run.
 */
#ifndef SKINKIT_TEST_SUPPORT_H
#define SKINKIT_TEST_SUPPORT_H

#include <stddef.h>
#include <stdint.h>

#include "skinkit.h"

/* Names the program in fatal messages (out of memory); each main() sets it. */
extern const char *test_program_name;

/* ---------------------------------------------------------------------------------------------
 * Checks
 * ------------------------------------------------------------------------------------------- */

extern int passed_checks, failed_checks;

int record_check(int ok, const char *file, int line, const char *expression, const char *context);

#define CHECK(expression) record_check((expression) != 0, __FILE__, __LINE__, #expression, NULL)
#define CHECK_IN(context, expression) record_check((expression) != 0, __FILE__, __LINE__, #expression, (context))

/* A record a failing call must overwrite: the checks below would pass on it only if it did. */
sk_error empty_error(void);

/* A record a successful call must clear. */
sk_error stale_error(void);

void expect_failure_at(const char *file, int line, const char *context, sk_status returned,
                       const sk_error *record, sk_status expected);
void expect_success_at(const char *file, int line, const char *context, sk_status returned,
                       const sk_error *record);

/*
 * Runs `call` twice: with an error record (status and message checked) and with error == NULL,
 * which every function must accept. `call` names the record pointer `error`.
 */
#define EXPECT_FAILURE(context, expected, call)                                                            \
    do {                                                                                                   \
        sk_error record_ = empty_error();                                                                  \
        sk_error *error = &record_;                                                                        \
        const sk_status with_record_ = (call);                                                             \
        error = NULL;                                                                                      \
        const sk_status without_record_ = (call);                                                          \
        expect_failure_at(__FILE__, __LINE__, (context), with_record_, &record_, (expected));              \
        record_check(without_record_ == (expected), __FILE__, __LINE__, "status with error == NULL",       \
                     (context));                                                                           \
    } while (0)

#define EXPECT_SUCCESS(context, call)                                                                      \
    do {                                                                                                   \
        sk_error record_ = stale_error();                                                                  \
        sk_error *error = &record_;                                                                        \
        const sk_status returned_ = (call);                                                                \
        expect_success_at(__FILE__, __LINE__, (context), returned_, &record_);                             \
    } while (0)

/* Prints "N passed, M failed" and returns the process exit status (0 when nothing failed). */
int finish_tests(void);

/* ---------------------------------------------------------------------------------------------
 * Small utilities: deterministic random numbers, allocation, array comparison
 * ------------------------------------------------------------------------------------------- */

uint64_t random_bits(void); /* splitmix64 with a fixed seed */
double random_uniform(double low, double high);
size_t random_below(size_t bound);

/* calloc that exits on failure (allocation failure in a test is not something to recover from). */
void *allocate(size_t count, size_t size);

/* Exactly sized heap copies (even of zero elements), so the sanitizer flags any read past them. */
int32_t *exact_copy_int32(const int32_t *values, size_t count);
double *exact_copy_double(const double *values, size_t count);

double max_abs(const double *values, size_t count);
int all_finite(const double *values, size_t count);
double max_abs_difference(const double *a, const double *b, size_t count);

/* Tolerances are relative to the coordinate scale (at least 1), so they mean the same at any size. */
double coordinate_scale(const double *reference, size_t count);
int close_to(const double *actual, const double *reference, size_t count, double relative_tolerance);
/* Results at two thread counts agree: bit for bit with Debian's OpenBLAS. The Windows build's scipy-openblas32 rounds
 * LAPACK calls on worker threads differently from the main thread (measured up to 3e-12 relative in the fits), so
 * there they must agree to 1e-10 of the array's scale (close_to). */
int same_across_threads(const double *threaded, const double *single, size_t count);

/* Dense vectors and a dense rows x cols row-major operator: y = A x (transpose 0) or A^T x (transpose 1). */
double dot_product(const double *a, const double *b, size_t n);
double euclidean_norm(const double *v, size_t n);
void dense_apply(const double *a, size_t rows, size_t cols, int transpose, const double *x, double *y);

/* A progress callback (sk_progress_fn) that logs the first 64 fractions and cancels at call cancel_at (0: never). */
typedef struct progress_log {
    int calls, cancel_at;
    double fractions[64];
} progress_log;
int record_progress(void *user, double fraction);

/* ---------------------------------------------------------------------------------------------
 * Independent 4x4 algebra (row-major, like the core): Gauss-Jordan inverse, random frames
 * ------------------------------------------------------------------------------------------- */

void set_identity(double m[16]);
void multiply(double destination[16], const double a[16], const double b[16]);
int invert_gauss_jordan(double inverse[16], const double matrix[16]); /* 0 for a singular matrix */
void transform(double out[3], const double m[16], const double v[3], double h); /* top rows of m (v, h) */
void random_rotation(double r[9]);
void make_frame(double frame[16], const double rotation[9], const double scales[3], const double translation[3]);
void random_frame(double frame[16], double min_scale, double max_scale, double max_translation);
void random_frames(double *frames, size_t bone_count); /* bone 0 = identity, the others random */
/* count random frames with scales in [0.5, 2] and translations up to max_translation (sampled local frames). */
void random_scaled_frames(double *frames, size_t count, double max_translation);
double *identity_frames(size_t bone_count);

/* ---------------------------------------------------------------------------------------------
 * A random skinned mesh
 * ------------------------------------------------------------------------------------------- */

typedef struct test_mesh {
    size_t vertex_count, influence_count, bone_count;
    int32_t *offsets;        /* vertex_count + 1 */
    int32_t *bones;          /* influence_count, distinct within a vertex */
    double *weights;         /* influence_count, positive, summing to 1 per vertex */
    double *rest_positions;  /* 3 per vertex */
    double *rest_frames;     /* 16 per bone, bone 0 = identity */
    sk_influences influences; /* offsets and bones with their counts, as the core takes them */
} test_mesh;

void pick_distinct_bones(int32_t *chosen, size_t count, size_t bone_count); /* bone_count <= 64 */
void normalise(double *weights, size_t count);
test_mesh make_random_mesh(size_t vertex_count, size_t bone_count); /* 1-4 influences per vertex */
void free_mesh(test_mesh *mesh);

/* The per-bone inverse rest frames, by the independent Gauss-Jordan inverse (CHECKed invertible). */
double *reference_inverse_rest_frames(const test_mesh *mesh);

/* Linear blend skinning straight from its definition: sum_k w_k G_j inverse(R_j) (v, h). */
void reference_linear_blend(double *destination, const test_mesh *mesh, const double *vectors, double h,
                            const double *poses);

/* Animation-space coordinates straight from eq. 3.1: p_k = w_k inverse(R_j) (v, h). */
void reference_coordinates(double *coordinates, const test_mesh *mesh, const double *vectors, double h);

void random_vectors(double *vectors, size_t vertex_count);

/* The mesh's animation-space coordinates of vectors (positions: homogeneous 1, tangents: 0), 4 per influence,
 * by sk_lbs_to_animation_space (EXPECT_SUCCESS under context). */
double *converted_coordinates(const char *context, const test_mesh *mesh, const double *vectors, double homogeneous);

/* The skinning matrices of poses against the mesh's rest frames, 16 per bone, by sk_skinning_matrices
 * (EXPECT_SUCCESS under context). */
double *skinning_matrices_of(const char *context, const test_mesh *mesh, const double *poses);

#endif
