/*
 * Standalone tests of the skinkit fitting solvers (csrc/skinkit.h, "Fitting to example poses"):
 * sk_fit_per_vertex, sk_fit_global and sk_fit_lbs_weights (sk_lsqr itself: test_lsqr.c).
 *
 * Meant to run under AddressSanitizer and UndefinedBehaviorSanitizer: every array handed to the core
 * is an exactly sized heap block, so a solver that read or wrote past its counts would be stopped by
 * the sanitizer, not just by a failed CHECK.
 *
 * Numerical results are compared with references computed here with plain loops: models generated
 * in the test, the KKT systems of the constrained least-squares problems solved by an own Gaussian
 * elimination, normal equations solved by an own Cholesky factorisation, and a brute-force search over
 * the faces of the simplex for the non-negative weights. The core is not only compared with itself.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "skinkit.h"
#include "sk_internal.h" /* only for sk_worker_count and SK_SOLVE_ITEMS_PER_WORKER: proves the work is split */
#include "test_support.h"

/* ---------------------------------------------------------------------------------------------
 * Small dense linear algebra, independent of the core (which uses LAPACK)
 * ------------------------------------------------------------------------------------------- */

/* Solves a x = b in place (x returned in b) by Gaussian elimination with partial pivoting; a (n x n,
 * row-major) is destroyed. Returns 0 when a pivot is exactly zero. */
static int solve_gauss(double *a, double *b, size_t n)
{
    for (size_t column = 0; column < n; ++column) {
        size_t pivot = column;
        for (size_t r = column + 1; r < n; ++r)
            if (fabs(a[r * n + column]) > fabs(a[pivot * n + column]))
                pivot = r;
        if (a[pivot * n + column] == 0.0)
            return 0;
        if (pivot != column) {
            for (size_t c = 0; c < n; ++c) {
                const double t = a[column * n + c];
                a[column * n + c] = a[pivot * n + c];
                a[pivot * n + c] = t;
            }
            const double t = b[column];
            b[column] = b[pivot];
            b[pivot] = t;
        }
        for (size_t r = column + 1; r < n; ++r) {
            const double factor = a[r * n + column] / a[column * n + column];
            if (factor == 0.0)
                continue;
            for (size_t c = column; c < n; ++c)
                a[r * n + c] -= factor * a[column * n + c];
            b[r] -= factor * b[column];
        }
    }
    for (size_t i = n; i-- > 0;) {
        double sum = b[i];
        for (size_t j = i + 1; j < n; ++j)
            sum -= a[i * n + j] * b[j];
        b[i] = sum / a[i * n + i];
    }
    return 1;
}

/* ---------------------------------------------------------------------------------------------
 * An animation-space model generated in the test, and its examples
 * ------------------------------------------------------------------------------------------- */

/* A general affine frame: rotation * diag(scales) * rotation, then a translation. */
static void random_affine(double frame[16])
{
    double first[16], second[16], rotation[9], scales[3] = {1, 1, 1}, translation[3] = {0, 0, 0};
    random_rotation(rotation);
    for (int i = 0; i < 3; ++i) {
        scales[i] = random_uniform(0.5, 2.0);
        translation[i] = random_uniform(-2.0, 2.0);
    }
    make_frame(first, rotation, scales, translation);
    random_rotation(rotation);
    const double unit[3] = {1, 1, 1}, none[3] = {0, 0, 0};
    make_frame(second, rotation, unit, none);
    multiply(frame, first, second);
}

/* example_count poses of bone_count bones: bone 0 is the identity root, the others random affine. */
static double *random_example_poses(size_t example_count, size_t bone_count)
{
    double *poses = allocate(16 * example_count * bone_count, sizeof *poses);
    for (size_t e = 0; e < example_count; ++e) {
        set_identity(poses + 16 * e * bone_count);
        for (size_t bone = 1; bone < bone_count; ++bone)
            random_affine(poses + 16 * (e * bone_count + bone));
    }
    return poses;
}

typedef struct fit_model {
    size_t vertex_count, influence_count, bone_count, example_count;
    int32_t *offsets;     /* vertex_count + 1, exactly sized */
    int32_t *bones;       /* influence_count, exactly sized */
    double *coordinates;  /* the true p: 4 per influence, each vertex's weights summing to 1 */
    double *poses;        /* example_count * bone_count 4x4 (G_j^e) */
    double *examples;     /* example_count * vertex_count * 3 */
    sk_influences influences;   /* offsets and bones with their counts */
    sk_examples example_set;    /* poses and examples with their counts */
} fit_model;

static const double *pose_at(const fit_model *m, size_t example, int32_t bone)
{
    return m->poses + 16 * (example * m->bone_count + (size_t)bone);
}

/* out[(e V + i) 3 ..] = top three rows of sum_k G^e_{bones[k]} p_k, straight from eq. 3.1. */
static void model_positions(double *out, const fit_model *m, const double *coordinates)
{
    for (size_t e = 0; e < m->example_count; ++e)
        for (size_t vertex = 0; vertex < m->vertex_count; ++vertex) {
            double sum[3] = {0, 0, 0};
            for (int32_t k = m->offsets[vertex]; k < m->offsets[vertex + 1]; ++k) {
                const double *g = pose_at(m, e, m->bones[k]), *p = coordinates + 4 * k;
                for (int r = 0; r < 3; ++r)
                    sum[r] += g[4 * r] * p[0] + g[4 * r + 1] * p[1] + g[4 * r + 2] * p[2] + g[4 * r + 3] * p[3];
            }
            memcpy(out + 3 * (e * m->vertex_count + vertex), sum, sizeof sum);
        }
}

/*
 * A random model: vertex i has 1 .. max_influences distinct bones out of bone_count (bone 0 included
 * only when allow_root), random p_j with weights summing to 1 (some negative, as animation space
 * allows), random affine poses, and the exact examples those produce.
 */
static fit_model make_fit_model(size_t vertex_count, size_t bone_count, size_t example_count, size_t max_influences,
                                int allow_root)
{
    fit_model m = {.vertex_count = vertex_count, .bone_count = bone_count, .example_count = example_count};
    const size_t first = allow_root ? 0 : 1;
    int32_t *offsets = allocate(vertex_count + 1, sizeof *offsets);
    int32_t *bones = allocate(vertex_count * max_influences, sizeof *bones);
    size_t k = 0;
    for (size_t vertex = 0; vertex < vertex_count; ++vertex) {
        const size_t count = 1 + random_below(max_influences);
        pick_distinct_bones(bones + k, count, bone_count - first);
        for (size_t i = 0; i < count; ++i)
            bones[k + i] += (int32_t)first;
        k += count;
        offsets[vertex + 1] = (int32_t)k;
    }
    m.influence_count = k;
    m.offsets = exact_copy_int32(offsets, vertex_count + 1);
    m.bones = exact_copy_int32(bones, k);
    free(offsets), free(bones);
    m.coordinates = allocate(4 * k, sizeof *m.coordinates);
    for (size_t vertex = 0; vertex < vertex_count; ++vertex) {
        double weight_sum = 0.0;
        for (int32_t j = m.offsets[vertex]; j < m.offsets[vertex + 1]; ++j) {
            double *p = m.coordinates + 4 * j;
            for (int c = 0; c < 3; ++c)
                p[c] = random_uniform(-1.0, 1.0);
            p[3] = j + 1 < m.offsets[vertex + 1] ? random_uniform(-0.5, 1.0) : 1.0 - weight_sum;
            weight_sum += p[3];
        }
    }
    m.poses = random_example_poses(example_count, bone_count);
    m.examples = allocate(3 * example_count * vertex_count, sizeof *m.examples);
    model_positions(m.examples, &m, m.coordinates);
    m.influences = (sk_influences){m.offsets, m.bones, vertex_count, k};
    m.example_set = (sk_examples){m.poses, m.examples, example_count, bone_count};
    return m;
}

static void free_fit_model(fit_model *m)
{
    free(m->offsets), free(m->bones), free(m->coordinates), free(m->poses), free(m->examples);
}

static void add_noise(double *values, size_t count, double amplitude)
{
    for (size_t i = 0; i < count; ++i)
        values[i] += random_uniform(-amplitude, amplitude);
}

/* sum_i sum_e |G^e p_i - v_i^e|^2 */
static double data_term(const fit_model *m, const double *coordinates)
{
    const size_t count = 3 * m->example_count * m->vertex_count;
    double *positions = allocate(count, sizeof *positions), sum = 0.0;
    model_positions(positions, m, coordinates);
    for (size_t i = 0; i < count; ++i)
        sum += (positions[i] - m->examples[i]) * (positions[i] - m->examples[i]);
    free(positions);
    return sum;
}

/* The influence slot of `bone` in vertex's set, or -1. */
static int32_t slot_of_bone(const fit_model *m, size_t vertex, int32_t bone)
{
    for (int32_t k = m->offsets[vertex]; k < m->offsets[vertex + 1]; ++k)
        if (m->bones[k] == bone)
            return k;
    return -1;
}

/* sum_edges w_k |p_a - p_b|^2, with p a vector over all bones (zero where a bone has no influence). */
static double edge_term(const fit_model *m, const double *coordinates, const int32_t *edges, const double *weights,
                        size_t edge_count)
{
    double sum = 0.0;
    for (size_t e = 0; e < edge_count; ++e) {
        const size_t a = (size_t)edges[2 * e], b = (size_t)edges[2 * e + 1];
        for (int32_t bone = 0; bone < (int32_t)m->bone_count; ++bone) {
            const int32_t ka = slot_of_bone(m, a, bone), kb = slot_of_bone(m, b, bone);
            for (int c = 0; c < 4; ++c) {
                const double d = (ka >= 0 ? coordinates[4 * ka + c] : 0.0) - (kb >= 0 ? coordinates[4 * kb + c] : 0.0);
                sum += weights[e] * d * d;
            }
        }
    }
    return sum;
}

static double worst_weight_sum_error(const fit_model *m, const double *coordinates)
{
    double worst = 0.0;
    for (size_t vertex = 0; vertex < m->vertex_count; ++vertex) {
        double sum = 0.0;
        for (int32_t k = m->offsets[vertex]; k < m->offsets[vertex + 1]; ++k)
            sum += coordinates[4 * k + 3];
        worst = fmax(worst, fabs(sum - 1.0));
    }
    return worst;
}

/*
 * Adds vertex's normal equations (data term only) in the full 4-per-influence unknowns to the dense
 * system `normal` (n x n) and `rhs` at unknown `base`: D^T D and D^T v, D the 3E x 4n_i matrix of
 * the top three rows of the poses.
 */
static void add_vertex_normal_equations(double *normal, double *rhs, size_t n, size_t base, const fit_model *m,
                                        size_t vertex)
{
    const int32_t begin = m->offsets[vertex], end = m->offsets[vertex + 1];
    for (size_t e = 0; e < m->example_count; ++e)
        for (int r = 0; r < 3; ++r) {
            const double target = m->examples[3 * (e * m->vertex_count + vertex) + (size_t)r];
            for (int32_t i = begin; i < end; ++i)
                for (int ci = 0; ci < 4; ++ci) {
                    const double di = pose_at(m, e, m->bones[i])[4 * r + ci];
                    const size_t row = base + 4 * (size_t)(i - begin) + (size_t)ci;
                    rhs[row] += di * target;
                    for (int32_t j = begin; j < end; ++j)
                        for (int cj = 0; cj < 4; ++cj)
                            normal[row * n + base + 4 * (size_t)(j - begin) + (size_t)cj] +=
                                di * pose_at(m, e, m->bones[j])[4 * r + cj];
                }
        }
}

/*
 * Reference for the per-vertex fit with vertex regularisation (eq. 4.3): for each vertex, the KKT
 * system of  min sum_e |G^e p - v^e|^2 + lambda |p|^2  subject to  sum of p's weights = 1,
 * solved by Gaussian elimination. Returns 0 if a system is singular.
 */
static int reference_per_vertex(double *coordinates, const fit_model *m, double lambda)
{
    for (size_t vertex = 0; vertex < m->vertex_count; ++vertex) {
        const size_t count = (size_t)(m->offsets[vertex + 1] - m->offsets[vertex]), n = 4 * count + 1;
        double *kkt = allocate(n * n, sizeof *kkt), *rhs = allocate(n, sizeof *rhs);
        add_vertex_normal_equations(kkt, rhs, n, 0, m, vertex);
        for (size_t s = 0; s < count; ++s) {
            for (int c = 0; c < 4; ++c)
                kkt[(4 * s + (size_t)c) * n + 4 * s + (size_t)c] += lambda;
            kkt[(4 * s + 3) * n + n - 1] = kkt[(n - 1) * n + 4 * s + 3] = 1.0;
        }
        rhs[n - 1] = 1.0;
        const int ok = solve_gauss(kkt, rhs, n);
        memcpy(coordinates + 4 * m->offsets[vertex], rhs, 4 * count * sizeof *rhs);
        free(kkt), free(rhs);
        if (!ok)
            return 0;
    }
    return 1;
}

/*
 * Reference for the global fit (eq. 4.4): the KKT system of data + edge terms over all vertices at
 * once, subject to each vertex's weights summing to 1, solved densely by Gaussian elimination.
 */
static int reference_global(double *coordinates, const fit_model *m, const int32_t *edges, const double *weights,
                            size_t edge_count)
{
    const size_t K = m->influence_count, V = m->vertex_count, n = 4 * K + V;
    double *kkt = allocate(n * n, sizeof *kkt), *rhs = allocate(n, sizeof *rhs);
    for (size_t vertex = 0; vertex < V; ++vertex) {
        add_vertex_normal_equations(kkt, rhs, n, 4 * (size_t)m->offsets[vertex], m, vertex);
        for (int32_t k = m->offsets[vertex]; k < m->offsets[vertex + 1]; ++k)
            kkt[(4 * (size_t)k + 3) * n + 4 * K + vertex] = kkt[(4 * K + vertex) * n + 4 * (size_t)k + 3] = 1.0;
        rhs[4 * K + vertex] = 1.0;
    }
    for (size_t e = 0; e < edge_count; ++e) {
        const size_t a = (size_t)edges[2 * e], b = (size_t)edges[2 * e + 1];
        for (int32_t bone = 0; bone < (int32_t)m->bone_count; ++bone) {
            const int32_t ka = slot_of_bone(m, a, bone), kb = slot_of_bone(m, b, bone);
            for (size_t c = 0; c < 4; ++c) { /* w |pa - pb|^2: +w on the diagonals, -w between them */
                if (ka >= 0)
                    kkt[(4 * (size_t)ka + c) * n + 4 * (size_t)ka + c] += weights[e];
                if (kb >= 0)
                    kkt[(4 * (size_t)kb + c) * n + 4 * (size_t)kb + c] += weights[e];
                if (ka >= 0 && kb >= 0) {
                    kkt[(4 * (size_t)ka + c) * n + 4 * (size_t)kb + c] -= weights[e];
                    kkt[(4 * (size_t)kb + c) * n + 4 * (size_t)ka + c] -= weights[e];
                }
            }
        }
    }
    const int ok = solve_gauss(kkt, rhs, n);
    memcpy(coordinates, rhs, 4 * K * sizeof *rhs);
    free(kkt), free(rhs);
    return ok;
}

/* ---------------------------------------------------------------------------------------------
 * 1. The per-vertex fit recovers an animation-space model exactly
 * ------------------------------------------------------------------------------------------- */

static void fit_per_vertex(double *coordinates, const fit_model *m, double lambda, int thread_count)
{
    EXPECT_SUCCESS("per-vertex fit", sk_fit_per_vertex(coordinates,
                                                       &m->influences,
                                                       &m->example_set,
                                                       NULL, lambda, thread_count, error));
}

static void check_thread_counts_agree(const fit_model *m, double lambda, const double *single_threaded)
{
    const size_t K = m->influence_count;
    const int thread_counts[] = {0, 3};
    for (size_t t = 0; t < sizeof thread_counts / sizeof thread_counts[0]; ++t) {
        double *threaded = allocate(4 * K, sizeof *threaded);
        fit_per_vertex(threaded, m, lambda, thread_counts[t]);
        char context[80];
        snprintf(context, sizeof context, "per-vertex fit, lambda %g: thread_count %d vs 1", lambda, thread_counts[t]);
        CHECK_IN(context, memcmp(threaded, single_threaded, 4 * K * sizeof *threaded) == 0);
        free(threaded);
    }
}

/* A prior pulls the fit towards it: with overwhelming lambda the result is the prior, whatever the data. */
static void test_per_vertex_prior(void)
{
    fit_model m = make_fit_model(40, 4, 6, 3, 0);
    double *prior = allocate(4 * m.influence_count, sizeof *prior);
    double *fitted = allocate(4 * m.influence_count, sizeof *fitted);
    for (size_t k = 0; k < 4 * m.influence_count; ++k)
        prior[k] = m.coordinates[k] + (k % 4 == 3 ? 0.0 : 0.25); /* weights still sum to 1 */
    EXPECT_SUCCESS("fit towards a prior", sk_fit_per_vertex(fitted,
                                                            &m.influences,
                                                            &m.example_set,
                                                            prior, 1e12, 1, error));
    double worst = 0.0;
    for (size_t k = 0; k < 4 * m.influence_count; ++k)
        worst = fabs(fitted[k] - prior[k]) > worst ? fabs(fitted[k] - prior[k]) : worst;
    CHECK_IN("huge lambda returns the prior", worst < 1e-6);
    EXPECT_SUCCESS("fit with a weak prior", sk_fit_per_vertex(fitted,
                                                              &m.influences,
                                                              &m.example_set,
                                                              prior, 1e-12, 1, error));
    worst = 0.0;
    for (size_t k = 0; k < 4 * m.influence_count; ++k)
        worst = fabs(fitted[k] - m.coordinates[k]) > worst ? fabs(fitted[k] - m.coordinates[k]) : worst;
    CHECK_IN("tiny lambda follows the data", worst < 1e-6);
    prior[5] = NAN;
    EXPECT_FAILURE("NaN in the prior", SK_ERROR_NOT_FINITE,
                   sk_fit_per_vertex(fitted, &m.influences,
                                     &m.example_set, prior, 1.0,
                                     1, error));
    free(prior), free(fitted);
    free_fit_model(&m);
}

static void test_per_vertex_recovers_exact_model(int allow_root)
{
    const size_t V = 300, B = 5, E = 10;
    /* With fewer vertices every thread count would run on one thread and prove nothing. */
    CHECK(sk_worker_count(V, SK_SOLVE_ITEMS_PER_WORKER, 3) == 3);
    fit_model m = make_fit_model(V, B, E, 3, allow_root);
    const size_t K = m.influence_count;
    double *fitted = allocate(4 * K, sizeof *fitted);
    for (size_t i = 0; i < 4 * K; ++i)
        fitted[i] = 1e300; /* garbage every entry must be overwritten */

    fit_per_vertex(fitted, &m, 0.0, 1);
    char context[160];
    snprintf(context, sizeof context, "allow_root %d: max |fitted - true| = %.3g", allow_root,
             max_abs_difference(fitted, m.coordinates, 4 * K));
    CHECK_IN(context, close_to(fitted, m.coordinates, 4 * K, 1e-9));
    snprintf(context, sizeof context, "worst |sum of weights - 1| = %.3g", worst_weight_sum_error(&m, fitted));
    CHECK_IN(context, worst_weight_sum_error(&m, fitted) <= 1e-12);
    /* Guards the tolerance: a model far from any trivial answer. */
    CHECK(max_abs(m.coordinates, 4 * K) > 0.5 && data_term(&m, m.coordinates) < 1e-20);
    CHECK(data_term(&m, fitted) <= 1e-16 * (double)(3 * E * V));
    check_thread_counts_agree(&m, 0.0, fitted);

    /* Regularised: the minimiser of data + lambda |p|^2 per vertex, compared with the KKT reference. */
    const double lambdas[] = {1e-6, 1e-3};
    double data_terms[2];
    const double true_norm2 = dot_product(m.coordinates, m.coordinates, 4 * K);
    double *expected = allocate(4 * K, sizeof *expected);
    for (size_t l = 0; l < 2; ++l) {
        const double lambda = lambdas[l];
        fit_per_vertex(fitted, &m, lambda, 1);
        CHECK(all_finite(fitted, 4 * K));
        CHECK(worst_weight_sum_error(&m, fitted) <= 1e-12);
        CHECK(reference_per_vertex(expected, &m, lambda));
        snprintf(context, sizeof context, "lambda %g: max |fitted - reference| = %.3g", lambda,
                 max_abs_difference(fitted, expected, 4 * K));
        CHECK_IN(context, close_to(fitted, expected, 4 * K, 1e-9));
        /* The regulariser really acts: the answer moved off the exact model. */
        CHECK_IN(context, max_abs_difference(fitted, m.coordinates, 4 * K) > 1e-3 * lambda);
        /* A minimiser is no worse than the exact model: data(p) + lambda |p|^2 <= lambda |p_true|^2, so
         * the residual grows only by lambda |p_true|^2 at most, and |p| shrinks. */
        data_terms[l] = data_term(&m, fitted);
        const double fitted_norm2 = dot_product(fitted, fitted, 4 * K);
        snprintf(context, sizeof context, "lambda %g: data %.3g + lambda |p|^2 %.3g vs lambda |p_true|^2 %.3g", lambda,
                 data_terms[l], lambda * fitted_norm2, lambda * true_norm2);
        CHECK_IN(context, data_terms[l] + lambda * fitted_norm2 <= lambda * true_norm2 * (1.0 + 1e-9));
        CHECK_IN(context, data_terms[l] > 0.0 && fitted_norm2 < true_norm2);
        check_thread_counts_agree(&m, lambda, fitted);
    }
    CHECK_IN("the residual grows with lambda", data_terms[0] < data_terms[1]);
    free(fitted), free(expected);
    free_fit_model(&m);
}

/* ---------------------------------------------------------------------------------------------
 * 2. The linear-blend weight fit
 * ------------------------------------------------------------------------------------------- */

/* N_j^e = G_j^e inverse(rest_j) by the independent Gauss-Jordan inverse: example_count * bone_count 4x4. */
static double *reference_skinning_matrices(const test_mesh *mesh, const double *poses, size_t example_count)
{
    const size_t B = mesh->bone_count;
    double *inverses = reference_inverse_rest_frames(mesh);
    double *skinning = allocate(16 * example_count * B, sizeof *skinning);
    for (size_t e = 0; e < example_count; ++e)
        for (size_t bone = 0; bone < B; ++bone)
            multiply(skinning + 16 * (e * B + bone), poses + 16 * (e * B + bone), inverses + 16 * bone);
    free(inverses);
    return skinning;
}

/* Column s of vertex's data matrix: (N_s^e v) over the examples (3E entries). */
static void lbs_columns(double *columns, const test_mesh *mesh, const double *skinning, size_t example_count,
                        size_t vertex)
{
    const size_t rows = 3 * example_count;
    const int32_t begin = mesh->offsets[vertex];
    for (int32_t k = begin; k < mesh->offsets[vertex + 1]; ++k)
        for (size_t e = 0; e < example_count; ++e)
            transform(columns + (size_t)(k - begin) * rows + 3 * e,
                      skinning + 16 * (e * mesh->bone_count + (size_t)mesh->bones[k]), mesh->rest_positions + 3 * vertex,
                      1.0);
}

static double lbs_objective(const double *columns, const double *target, const double *w, size_t count, size_t rows)
{
    double sum = 0.0;
    for (size_t r = 0; r < rows; ++r) {
        double value = -target[r];
        for (size_t s = 0; s < count; ++s)
            value += w[s] * columns[s * rows + r];
        sum += value * value;
    }
    return sum;
}

/*
 * The minimiser over the simplex by brute force: the equality-constrained least-squares solution
 * on every face (every non-empty subset of the influences, its KKT system solved by Gaussian
 * elimination), keeping the best feasible one. The optimum lies in the relative interior of some
 * face, where it is that face's constrained solution. count <= 4.
 */
static double reference_simplex_fit(double *best, const double *columns, const double *target, size_t count,
                                    size_t rows)
{
    double best_value = INFINITY;
    for (unsigned subset = 1; subset < (1u << count); ++subset) {
        size_t members[4], size = 0;
        for (size_t s = 0; s < count; ++s)
            if (subset & (1u << s))
                members[size++] = s;
        const size_t n = size + 1;
        double kkt[25] = {0}, rhs[5] = {0}, w[4] = {0};
        for (size_t i = 0; i < size; ++i) {
            for (size_t j = 0; j < size; ++j)
                kkt[i * n + j] = dot_product(columns + members[i] * rows, columns + members[j] * rows, rows);
            rhs[i] = dot_product(columns + members[i] * rows, target, rows);
            kkt[i * n + size] = kkt[size * n + i] = 1.0;
        }
        rhs[size] = 1.0;
        if (!solve_gauss(kkt, rhs, n))
            continue;
        int feasible = 1;
        for (size_t i = 0; i < size; ++i) {
            feasible = feasible && rhs[i] >= 0.0;
            w[members[i]] = rhs[i];
        }
        const double value = lbs_objective(columns, target, w, count, rows);
        if (feasible && value < best_value) {
            best_value = value;
            memcpy(best, w, count * sizeof *w);
        }
    }
    return best_value;
}

typedef struct lbs_problem {
    test_mesh mesh;
    size_t example_count;
    double *poses, *skinning, *examples;
} lbs_problem;

/* A random mesh with some true weights exactly 0, example poses, skinning matrices and exact examples. */
static lbs_problem make_lbs_problem(size_t vertex_count, size_t bone_count, size_t example_count)
{
    lbs_problem p = {.mesh = make_random_mesh(vertex_count, bone_count), .example_count = example_count};
    test_mesh *mesh = &p.mesh;
    for (size_t vertex = 0; vertex < vertex_count; ++vertex) {
        const int32_t begin = mesh->offsets[vertex], count = mesh->offsets[vertex + 1] - begin;
        if (count >= 2 && random_below(3) == 0) {
            mesh->weights[begin + (int32_t)random_below((size_t)count)] = 0.0;
            normalise(mesh->weights + begin, (size_t)count);
        }
    }
    /* Exactly sized copies of the pattern (make_random_mesh allocates room for 4 influences each). */
    int32_t *bones = exact_copy_int32(mesh->bones, mesh->influence_count);
    double *weights = exact_copy_double(mesh->weights, mesh->influence_count);
    free(mesh->bones), free(mesh->weights);
    mesh->bones = bones, mesh->weights = weights;
    mesh->influences.bones = bones;

    p.poses = allocate(16 * example_count * bone_count, sizeof *p.poses);
    p.examples = allocate(3 * example_count * vertex_count, sizeof *p.examples);
    for (size_t e = 0; e < example_count; ++e) {
        random_frames(p.poses + 16 * e * bone_count, bone_count);
        reference_linear_blend(p.examples + 3 * e * vertex_count, mesh, mesh->rest_positions, 1.0,
                               p.poses + 16 * e * bone_count);
    }
    p.skinning = reference_skinning_matrices(mesh, p.poses, example_count);
    return p;
}

static void free_lbs_problem(lbs_problem *p)
{
    free(p->poses), free(p->skinning), free(p->examples);
    free_mesh(&p->mesh);
}

static void fit_lbs(double *weights, const lbs_problem *p, int thread_count)
{
    const test_mesh *m = &p->mesh;
    EXPECT_SUCCESS("linear-blend weight fit",
                   sk_fit_lbs_weights(weights,
                                      &m->influences,
                                      &(sk_examples){p->skinning, p->examples, p->example_count, m->bone_count},
                                      m->rest_positions, thread_count, error));
}

/* Every weight >= 0 and every vertex's weights summing to 1. */
static void check_weights_are_convex(const test_mesh *mesh, const double *weights, const char *what)
{
    double worst_sum = 0.0, smallest = INFINITY;
    for (size_t vertex = 0; vertex < mesh->vertex_count; ++vertex) {
        double sum = 0.0;
        for (int32_t k = mesh->offsets[vertex]; k < mesh->offsets[vertex + 1]; ++k)
            sum += weights[k], smallest = fmin(smallest, weights[k]);
        worst_sum = fmax(worst_sum, fabs(sum - 1.0));
    }
    char context[160];
    snprintf(context, sizeof context, "%s: smallest weight %.3g, worst |sum - 1| %.3g", what, smallest, worst_sum);
    CHECK_IN(context, smallest >= 0.0);
    CHECK_IN(context, worst_sum <= 1e-12);
}

static void test_lbs_recovers_exact_weights(void)
{
    const size_t V = 300, B = 6, E = 8;
    lbs_problem p = make_lbs_problem(V, B, E);
    const test_mesh *mesh = &p.mesh;
    const size_t K = mesh->influence_count;
    double *weights = allocate(K, sizeof *weights), *core_skinning = allocate(16 * B, sizeof *core_skinning);
    for (size_t k = 0; k < K; ++k)
        weights[k] = -1.0;

    /* The skinning matrices built here are those of the public API. */
    for (size_t e = 0; e < E; ++e) {
        EXPECT_SUCCESS("skinning matrices", sk_skinning_matrices(core_skinning, p.poses + 16 * e * B, mesh->rest_frames,
                                                                  B, error));
        CHECK(close_to(core_skinning, p.skinning + 16 * e * B, 16 * B, 1e-13));
    }
    size_t zero_weights = 0;
    for (size_t k = 0; k < K; ++k)
        zero_weights += mesh->weights[k] == 0.0;
    CHECK_IN("some true weights are exactly 0 (the bound is active)", zero_weights >= 10);

    fit_lbs(weights, &p, 1);
    char context[120];
    snprintf(context, sizeof context, "max |fitted - true weight| = %.3g", max_abs_difference(weights, mesh->weights, K));
    CHECK_IN(context, max_abs_difference(weights, mesh->weights, K) <= 1e-9);
    check_weights_are_convex(mesh, weights, "exact linear-blend data");

    const int thread_counts[] = {0, 3};
    for (size_t t = 0; t < 2; ++t) {
        double *threaded = allocate(K, sizeof *threaded);
        fit_lbs(threaded, &p, thread_counts[t]);
        snprintf(context, sizeof context, "linear-blend fit: thread_count %d vs 1", thread_counts[t]);
        CHECK_IN(context, memcmp(threaded, weights, K * sizeof *weights) == 0);
        free(threaded);
    }
    free(weights), free(core_skinning);
    free_lbs_problem(&p);
}

/* Data no weights reproduce: the answer is the best point of the simplex (brute-force reference). */
static void check_lbs_on_unreproducible_data(double noise, int replace)
{
    const size_t V = 200, B = 6, E = 8, rows = 3 * E;
    lbs_problem p = make_lbs_problem(V, B, E);
    const test_mesh *mesh = &p.mesh;
    const size_t K = mesh->influence_count;
    for (size_t i = 0; i < 3 * E * V; ++i)
        p.examples[i] = (replace ? 0.0 : p.examples[i]) + random_uniform(-noise, noise);
    double *weights = allocate(K, sizeof *weights);
    fit_lbs(weights, &p, 1);
    char what[80];
    snprintf(what, sizeof what, "noise %g%s", noise, replace ? " (examples replaced)" : "");
    check_weights_are_convex(mesh, weights, what);

    double worst_objective = 0.0, worst_weight = 0.0;
    size_t active_bounds = 0;
    for (size_t vertex = 0; vertex < V; ++vertex) {
        const int32_t begin = mesh->offsets[vertex];
        const size_t count = (size_t)(mesh->offsets[vertex + 1] - begin);
        double columns[4 * 3 * 8], target[3 * 8], best[4];
        lbs_columns(columns, mesh, p.skinning, E, vertex);
        for (size_t e = 0; e < E; ++e)
            memcpy(target + 3 * e, p.examples + 3 * (e * V + vertex), 3 * sizeof *target);
        const double reference = reference_simplex_fit(best, columns, target, count, rows);
        const double fitted = lbs_objective(columns, target, weights + begin, count, rows);
        worst_objective = fmax(worst_objective, (fitted - reference) / (reference + 1e-12));
        worst_weight = fmax(worst_weight, max_abs_difference(weights + begin, best, count));
        for (size_t s = 0; s < count; ++s)
            active_bounds += best[s] == 0.0;
    }
    char context[200];
    snprintf(context, sizeof context, "%s: worst relative objective excess %.3g, worst |w - reference| %.3g", what,
             worst_objective, worst_weight);
    CHECK_IN(context, worst_objective <= 1e-8);
    CHECK_IN(context, worst_weight <= 1e-5);
    /* Guards the test: the bounds must bite somewhere, or this is just the exact case again. */
    CHECK_IN(what, active_bounds >= 10);
    free(weights);
    free_lbs_problem(&p);
}

static void test_lbs_on_unreproducible_data(void)
{
    check_lbs_on_unreproducible_data(0.3, 0);
    check_lbs_on_unreproducible_data(3.0, 1);
}

/* 64 influences is the documented maximum: accepted, and a convex answer. */
static void test_lbs_at_64_influences(void)
{
    const size_t B = 64, E = 2;
    test_mesh mesh = {.vertex_count = 2, .influence_count = 65, .bone_count = B};
    int32_t offsets[] = {0, 1, 65}, bones[65];
    bones[0] = 3;
    for (int32_t k = 1; k < 65; ++k)
        bones[k] = k - 1;
    double *weights = allocate(65, sizeof *weights), *poses = allocate(16 * E * B, sizeof *poses);
    double *positions = allocate(6, sizeof *positions), *examples = allocate(3 * E * 2, sizeof *examples);
    for (size_t e = 0; e < E; ++e)
        random_frames(poses + 16 * e * B, B);
    random_vectors(positions, 2);
    random_vectors(examples, 2 * E);
    mesh.offsets = exact_copy_int32(offsets, 3), mesh.bones = exact_copy_int32(bones, 65);
    mesh.rest_positions = positions;
    EXPECT_SUCCESS("64 influences", sk_fit_lbs_weights(weights, &(sk_influences){mesh.offsets, mesh.bones, 2, 65},
                                                       &(sk_examples){poses, examples, E, B}, positions, 1, error));
    check_weights_are_convex(&mesh, weights, "64 influences");
    free(mesh.offsets), free(mesh.bones), free(weights), free(poses), free(positions), free(examples);
}

/* ---------------------------------------------------------------------------------------------
 * 3. The global fit with edge regularisation
 * ------------------------------------------------------------------------------------------- */

typedef struct edge_set {
    size_t count;
    int32_t *edges;   /* 2 per edge, exactly sized */
    double *weights;  /* 1 per edge, exactly sized */
} edge_set;

/* A chain through every vertex plus `extra` random edges, with weights in [low, high]. */
static edge_set make_edges(size_t vertex_count, size_t extra, double low, double high)
{
    const size_t count = vertex_count - 1 + extra;
    int32_t *edges = allocate(2 * count, sizeof *edges);
    double *weights = allocate(count, sizeof *weights);
    for (size_t k = 0; k < count; ++k) {
        size_t a = k, b = k + 1;
        if (k >= vertex_count - 1) {
            a = random_below(vertex_count);
            do
                b = random_below(vertex_count);
            while (b == a);
        }
        edges[2 * k] = (int32_t)a, edges[2 * k + 1] = (int32_t)b;
        weights[k] = high > low ? random_uniform(low, high) : low;
    }
    edge_set set = {count, exact_copy_int32(edges, 2 * count), exact_copy_double(weights, count)};
    free(edges), free(weights);
    return set;
}

static void free_edges(edge_set *set)
{
    free(set->edges), free(set->weights);
}

static sk_lsqr_settings global_settings(int precondition)
{
    sk_lsqr_settings settings = {.atol = 1e-13, .btol = 1e-13, .conlim = 0.0, .iteration_limit = 100000,
                                 .precondition = precondition};
    return settings;
}

/* Runs sk_fit_global from `start` into `coordinates`. */
static void fit_global(double *coordinates, const double *start, const fit_model *m, const edge_set *edges,
                       int precondition, int thread_count, sk_lsqr_report *report)
{
    memcpy(coordinates, start, 4 * m->influence_count * sizeof *coordinates);
    sk_lsqr_settings settings = global_settings(precondition);
    settings.thread_count = thread_count;
    const sk_influences influences = {m->offsets, m->bones, m->vertex_count, m->influence_count};
    const sk_examples examples = {m->poses, m->examples, m->example_count, m->bone_count};
    EXPECT_SUCCESS("global fit", sk_fit_global(coordinates, report, &influences, &examples, edges->edges,
                                               edges->weights, edges->count, &settings, NULL, NULL, error));
}

/* Zero edge weights and an exact start: nothing to improve, the model stays exact. */
static void test_global_stays_exact_without_edge_weights(void)
{
    fit_model m = make_fit_model(60, 5, 10, 3, 1);
    const size_t K = m.influence_count;
    double *start = allocate(4 * K, sizeof *start), *fitted = allocate(4 * K, sizeof *fitted);
    fit_per_vertex(start, &m, 0.0, 1);
    CHECK(close_to(start, m.coordinates, 4 * K, 1e-9));
    edge_set zero = make_edges(m.vertex_count, 30, 0.0, 0.0), none = {0, NULL, NULL};
    for (int precondition = 0; precondition <= 1; ++precondition) {
        sk_lsqr_report report;
        char context[120];
        fit_global(fitted, start, &m, &zero, precondition, 1, &report);
        snprintf(context, sizeof context, "zero edge weights, precondition %d: max |fitted - true| = %.3g",
                 precondition, max_abs_difference(fitted, m.coordinates, 4 * K));
        CHECK_IN(context, close_to(fitted, m.coordinates, 4 * K, 1e-9));
        CHECK_IN(context, worst_weight_sum_error(&m, fitted) <= 1e-12);
        CHECK_IN(context, report.initial_residual_norm <= 1e-10);
        fit_global(fitted, start, &m, &none, precondition, 1, &report);
        snprintf(context, sizeof context, "no edges, precondition %d: max |fitted - true| = %.3g", precondition,
                 max_abs_difference(fitted, m.coordinates, 4 * K));
        CHECK_IN(context, close_to(fitted, m.coordinates, 4 * K, 1e-9));
    }
    free(start), free(fitted);
    free_edges(&zero);
    free_fit_model(&m);
}

/* Positive edge weights on noisy data: both solvers reach the reference minimiser of data + edges. */
static void test_global_minimises_data_and_edges(void)
{
    fit_model m = make_fit_model(40, 5, 10, 3, 1);
    const size_t K = m.influence_count;
    add_noise(m.examples, 3 * m.example_count * m.vertex_count, 0.05);
    edge_set edges = make_edges(m.vertex_count, 25, 0.5, 5.0);
    double *start = allocate(4 * K, sizeof *start), *expected = allocate(4 * K, sizeof *expected);
    double *fitted[2] = {allocate(4 * K, sizeof(double)), allocate(4 * K, sizeof(double))};
    fit_per_vertex(start, &m, 0.0, 1);
    CHECK(reference_global(expected, &m, edges.edges, edges.weights, edges.count));
    const double start_objective = data_term(&m, start) + edge_term(&m, start, edges.edges, edges.weights, edges.count);
    const double best_objective =
        data_term(&m, expected) + edge_term(&m, expected, edges.edges, edges.weights, edges.count);
    char margin[120];
    snprintf(margin, sizeof margin, "start objective %.6g, reference %.6g", start_objective, best_objective);
    CHECK_IN(margin, best_objective < 0.9 * start_objective);

    sk_lsqr_report reports[2];
    for (int precondition = 0; precondition <= 1; ++precondition) {
        double *p = fitted[precondition];
        const sk_lsqr_report *report = &reports[precondition];
        fit_global(p, start, &m, &edges, precondition, 1, &reports[precondition]);
        const double objective = data_term(&m, p) + edge_term(&m, p, edges.edges, edges.weights, edges.count);
        char context[240];
        snprintf(context, sizeof context,
                 "precondition %d: objective %.10g (start %.10g, reference %.10g), stop %d after %d iterations, "
                 "max |p - reference| %.3g",
                 precondition, objective, start_objective, best_objective, report->stop_reason, report->iterations,
                 max_abs_difference(p, expected, 4 * K));
        CHECK_IN(context, objective < start_objective);
        CHECK_IN(context, objective <= best_objective * (1.0 + 1e-9));
        CHECK_IN(context, close_to(p, expected, 4 * K, 1e-6));
        CHECK_IN(context, worst_weight_sum_error(&m, p) <= 1e-12);
        CHECK_IN(context, report->stop_reason >= 1 && report->stop_reason <= 6);
        /* The system LSQR solved has the data and (scaled) edge rows: |r|^2 is the objective. */
        CHECK_IN(context, fabs(report->residual_norm * report->residual_norm - objective) <= 1e-8 * objective);
        CHECK_IN(context, fabs(report->initial_residual_norm * report->initial_residual_norm - start_objective) <=
                              1e-10 * start_objective);
    }
    char context[120];
    snprintf(context, sizeof context, "max |preconditioned - plain| = %.3g",
             max_abs_difference(fitted[0], fitted[1], 4 * K));
    CHECK_IN(context, close_to(fitted[0], fitted[1], 4 * K, 1e-6));
    snprintf(context, sizeof context, "iterations: preconditioned %d, plain %d", reports[1].iterations,
             reports[0].iterations);
    CHECK_IN(context, reports[1].iterations < reports[0].iterations);
    free(start), free(expected), free(fitted[0]), free(fitted[1]);
    free_edges(&edges);
    free_fit_model(&m);
}

static void test_global_thread_count_and_cancel(void)
{
    const size_t V = 256;
    CHECK(sk_worker_count(V, SK_SOLVE_ITEMS_PER_WORKER, 3) == 3);
    fit_model m = make_fit_model(V, 5, 8, 3, 0);
    const size_t K = m.influence_count;
    add_noise(m.examples, 3 * m.example_count * V, 0.05);
    edge_set edges = make_edges(V, 100, 0.05, 0.5);
    double *start = allocate(4 * K, sizeof *start), *single = allocate(4 * K, sizeof *single);
    double *threaded = allocate(4 * K, sizeof *threaded);
    fit_per_vertex(start, &m, 0.0, 1);
    sk_lsqr_report report, threaded_report;
    fit_global(single, start, &m, &edges, 1, 1, &report);
    const int thread_counts[] = {0, 3};
    for (size_t t = 0; t < 2; ++t) {
        fit_global(threaded, start, &m, &edges, 1, thread_counts[t], &threaded_report);
        char context[80];
        snprintf(context, sizeof context, "global fit: thread_count %d vs 1", thread_counts[t]);
        CHECK_IN(context, memcmp(threaded, single, 4 * K * sizeof *single) == 0);
        CHECK_IN(context, threaded_report.iterations == report.iterations);
    }

    /* A progress callback that asks to stop cancels the fit. */
    const sk_lsqr_settings settings = global_settings(0);
    progress_log cancel = {.cancel_at = 1};
    memcpy(threaded, start, 4 * K * sizeof *threaded);
    EXPECT_FAILURE("global fit cancelled", SK_ERROR_CANCELLED,
                   sk_fit_global(threaded, &report, &m.influences,
                                 &m.example_set, edges.edges,
                                 edges.weights, edges.count, &settings, record_progress, &cancel, error));
    CHECK(cancel.calls == 2 && cancel.fractions[0] > 0.0 && cancel.fractions[0] <= 1.0);
    free(start), free(single), free(threaded);
    free_edges(&edges);
    free_fit_model(&m);
}

/* ---------------------------------------------------------------------------------------------
 * 4. Errors
 * ------------------------------------------------------------------------------------------- */

/*
 * One small problem, valid unless a test breaks it, in exactly sized arrays. Each entry point takes
 * it as it stands (lbs reads `poses` as its skinning matrices); `start` and `out` may be set to NULL.
 */
typedef struct fit_case {
    size_t V, K, B, E;
    int32_t *offsets, *bones;
    double *poses, *examples, *start, *out, *rest_positions;
    int32_t *edges;
    double *edge_weights;
    size_t edge_count;
    double lambda;
    sk_lsqr_settings settings;
    sk_lsqr_report report;
    int thread_count;
} fit_case;

static fit_case make_case(const int32_t *offsets, const int32_t *bones, size_t V, size_t K, size_t B, size_t E)
{
    static const int32_t edges[] = {0, 1, 1, 2, 2, 0};
    static const double edge_weights[] = {0.1, 0.2, 0.3};
    fit_case c = {.V = V, .K = K, .B = B, .E = E, .edge_count = V >= 3 ? 3 : 0, .lambda = 0.0, .thread_count = 1,
                  .settings = {1e-10, 1e-10, 0.0, 1000, 1}};
    c.offsets = exact_copy_int32(offsets, V + 1);
    c.bones = exact_copy_int32(bones, K);
    double *poses = random_example_poses(E, B);
    c.poses = exact_copy_double(poses, 16 * E * B);
    free(poses);
    c.examples = allocate(3 * E * V, sizeof *c.examples);
    random_vectors(c.examples, E * V);
    c.rest_positions = allocate(3 * V, sizeof *c.rest_positions);
    random_vectors(c.rest_positions, V);
    c.start = allocate(4 * K, sizeof *c.start);
    c.out = allocate(4 * K, sizeof *c.out);
    for (size_t k = 0; k < K; ++k)
        for (int i = 0; i < 3; ++i)
            c.start[4 * k + (size_t)i] = random_uniform(-1.0, 1.0);
    for (size_t vertex = 0; vertex < V; ++vertex) /* weights 1 / count where the pattern allows */
        if (offsets[vertex] >= 0 && offsets[vertex] < offsets[vertex + 1] && (size_t)offsets[vertex + 1] <= K)
            for (int32_t k = offsets[vertex]; k < offsets[vertex + 1]; ++k)
                c.start[4 * k + 3] = 1.0 / (offsets[vertex + 1] - offsets[vertex]);
    c.edges = exact_copy_int32(edges, 2 * c.edge_count);
    c.edge_weights = exact_copy_double(edge_weights, c.edge_count);
    return c;
}

static void free_case(fit_case *c)
{
    free(c->offsets), free(c->bones), free(c->poses), free(c->examples), free(c->start), free(c->out);
    free(c->rest_positions), free(c->edges), free(c->edge_weights);
}

static sk_status run_per_vertex(fit_case *c, sk_error *error)
{
    return sk_fit_per_vertex(c->out, &(sk_influences){c->offsets, c->bones, c->V, c->K},
                             &(sk_examples){c->poses, c->examples, c->E, c->B}, NULL, c->lambda, c->thread_count,
                             error);
}

static sk_status run_global(fit_case *c, sk_error *error)
{
    if (c->out && c->start)
        memcpy(c->out, c->start, 4 * c->K * sizeof *c->out);
    c->settings.thread_count = c->thread_count;
    return sk_fit_global(c->out, &c->report, &(sk_influences){c->offsets, c->bones, c->V, c->K},
                         &(sk_examples){c->poses, c->examples, c->E, c->B}, c->edges, c->edge_weights, c->edge_count,
                         &c->settings, NULL, NULL, error);
}

static sk_status run_lbs(fit_case *c, sk_error *error)
{
    return sk_fit_lbs_weights(c->out, &(sk_influences){c->offsets, c->bones, c->V, c->K},
                              &(sk_examples){c->poses, c->examples, c->E, c->B}, c->rest_positions, c->thread_count,
                              error);
}

typedef sk_status (*case_runner)(fit_case *c, sk_error *error);

static const struct {
    const char *name;
    case_runner run;
} runners[] = {{"per-vertex", run_per_vertex}, {"global", run_global}, {"lbs", run_lbs}};
#define RUNNER_COUNT (sizeof runners / sizeof runners[0])

/* Expects `expected` from runner r, and (when not NULL) `named` in the message. */
static void expect_case_fails(fit_case *c, size_t r, const char *what, sk_status expected, const char *named)
{
    char context[160];
    snprintf(context, sizeof context, "%s fit: %s", runners[r].name, what);
    EXPECT_FAILURE(context, expected, runners[r].run(c, error));
    if (named) {
        sk_error record = empty_error();
        runners[r].run(c, &record);
        char details[SK_MESSAGE_SIZE + 200];
        snprintf(details, sizeof details, "%s: message \"%s\" should name \"%s\"", context, record.message, named);
        CHECK_IN(details, strstr(record.message, named) != NULL);
    }
}

static void expect_all_fail(fit_case *c, const char *what, sk_status expected, const char *named)
{
    for (size_t r = 0; r < RUNNER_COUNT; ++r)
        expect_case_fails(c, r, what, expected, named);
}

/* The valid problem the error cases are derived from: 3 vertices, 3 bones, 6 examples. */
static const int32_t base_offsets[] = {0, 1, 3, 5}, base_bones[] = {0, 1, 2, 0, 2};

static fit_case make_base_case(void)
{
    return make_case(base_offsets, base_bones, 3, 5, 3, 6);
}

static void test_base_case_is_accepted(void)
{
    fit_case c = make_base_case();
    for (size_t r = 0; r < RUNNER_COUNT; ++r) {
        EXPECT_SUCCESS(runners[r].name, runners[r].run(&c, error));
        CHECK_IN(runners[r].name, runners[r].run(&c, NULL) == SK_OK); /* error == NULL on success */
    }
    free_case(&c);
}

static void test_bad_influence_patterns(void)
{
    static const int32_t empty_offsets[] = {0, 1, 1, 3}, empty_bones[] = {0, 1, 2};
    static const int32_t bone_at_count[] = {0, 1, 3, 0, 2}, negative_bone[] = {0, 1, 2, 0, -1};
    static const int32_t decreasing[] = {0, 3, 1, 5}, beyond[] = {0, 6, 3, 5}, last_short[] = {0, 1, 3, 4};
    struct {
        const char *what;
        const int32_t *offsets, *bones;
        size_t K;
        sk_status expected;
        const char *named;
    } cases[] = {
        {"empty influence set", empty_offsets, empty_bones, 3, SK_ERROR_ARGUMENT, "vertex 1"},
        {"bone index == bone_count", base_offsets, bone_at_count, 5, SK_ERROR_INDEX, "vertex 1"},
        {"negative bone index", base_offsets, negative_bone, 5, SK_ERROR_INDEX, "vertex 2"},
        {"decreasing offsets", decreasing, base_bones, 5, SK_ERROR_INDEX, "vertex 1"},
        {"offset beyond the influence count", beyond, base_bones, 5, SK_ERROR_INDEX, "vertex 0"},
        {"offsets[V] != influence count", last_short, base_bones, 5, SK_ERROR_INDEX, NULL},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i) {
        fit_case c = make_case(cases[i].offsets, cases[i].bones, 3, cases[i].K, 3, 6);
        expect_all_fail(&c, cases[i].what, cases[i].expected, cases[i].named);
        free_case(&c);
    }
}

static void test_non_finite_inputs(void)
{
    const double bad_values[] = {NAN, INFINITY, -INFINITY};
    for (size_t i = 0; i < 3; ++i) {
        fit_case c = make_base_case();
        const double bad = bad_values[i];
        double saved = c.poses[16 * (3 * c.B + 2) + 6]; /* example 3, bone 2 */
        c.poses[16 * (3 * c.B + 2) + 6] = bad;
        expect_all_fail(&c, "non-finite pose", SK_ERROR_NOT_FINITE, NULL);
        c.poses[16 * (3 * c.B + 2) + 6] = saved;
        saved = c.poses[16 * c.E * c.B - 5]; /* the last example's last bone, translation z */
        c.poses[16 * c.E * c.B - 5] = bad;
        expect_all_fail(&c, "non-finite pose (last matrix)", SK_ERROR_NOT_FINITE, NULL);
        c.poses[16 * c.E * c.B - 5] = saved;
        saved = c.examples[3 * c.E * c.V - 1]; /* the very last value */
        c.examples[3 * c.E * c.V - 1] = bad;
        expect_all_fail(&c, "non-finite example", SK_ERROR_NOT_FINITE, NULL);
        c.examples[3 * c.E * c.V - 1] = saved;
        c.rest_positions[3 * c.V - 1] = bad;
        expect_case_fails(&c, 2, "non-finite rest position", SK_ERROR_NOT_FINITE, NULL);
        c.start[4 * c.K - 1] = bad;
        expect_case_fails(&c, 1, "non-finite starting coordinates", SK_ERROR_NOT_FINITE, NULL);
        free_case(&c);
    }
}

/* Found by the binding fuzzer: finite values whose products overflow (a pose entry of -1e308, lambda 1e308) must
 * be refused before LAPACK sees infinities (it printed "DLASCL parameter number 4 had an illegal value"). */
static void test_values_that_overflow_once_multiplied(void)
{
    fit_case c = make_base_case();
    const double saved = c.poses[16 * (3 * c.B + 2) + 3];
    c.poses[16 * (3 * c.B + 2) + 3] = -1e308; /* example 3, bone 2, translation x */
    expect_case_fails(&c, 0, "a pose of -1e308", SK_ERROR_NOT_FINITE, "overflows double precision");
    expect_case_fails(&c, 2, "a pose of -1e308", SK_ERROR_NOT_FINITE, "overflows double precision");
    c.poses[16 * (3 * c.B + 2) + 3] = saved;
    EXPECT_SUCCESS("the same case without the huge value", run_per_vertex(&c, error));
    free_case(&c);
}

static void test_bad_lambda(void)
{
    const double bad_lambdas[] = {-1.0, -1e-300, NAN, INFINITY, -INFINITY};
    fit_case c = make_base_case();
    for (size_t i = 0; i < sizeof bad_lambdas / sizeof bad_lambdas[0]; ++i) {
        c.lambda = bad_lambdas[i];
        char what[64];
        snprintf(what, sizeof what, "lambda %g", bad_lambdas[i]);
        expect_case_fails(&c, 0, what, SK_ERROR_ARGUMENT, NULL);
    }
    c.lambda = 1e-3;
    EXPECT_SUCCESS("lambda 1e-3", run_per_vertex(&c, error));
    free_case(&c);
}

static void test_bad_edges(void)
{
    struct {
        const char *what;
        int32_t a, b;
        double weight;
        sk_status expected;
        const char *named;
    } cases[] = {
        {"edge vertex == vertex count", 1, 3, 0.2, SK_ERROR_INDEX, "edge 1"},
        {"negative edge vertex", -1, 0, 0.2, SK_ERROR_INDEX, "edge 1"},
        {"edge vertex INT32_MAX", INT32_MAX, 0, 0.2, SK_ERROR_INDEX, "edge 1"},
        {"negative edge weight", 1, 2, -0.5, SK_ERROR_ARGUMENT, "edge 1"},
        {"NaN edge weight", 1, 2, NAN, SK_ERROR_ARGUMENT, "edge 1"},
        {"infinite edge weight", 1, 2, INFINITY, SK_ERROR_ARGUMENT, "edge 1"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i) {
        fit_case c = make_base_case();
        c.edges[2] = cases[i].a, c.edges[3] = cases[i].b, c.edge_weights[1] = cases[i].weight;
        expect_case_fails(&c, 1, cases[i].what, cases[i].expected, cases[i].named);
        free_case(&c);
    }
    fit_case c = make_base_case();
    int32_t *edges = c.edges;
    double *weights = c.edge_weights;
    c.edges = NULL;
    expect_case_fails(&c, 1, "null edges", SK_ERROR_ARGUMENT, NULL);
    c.edges = edges, c.edge_weights = NULL;
    expect_case_fails(&c, 1, "null edge weights", SK_ERROR_ARGUMENT, NULL);
    c.edges = NULL, c.edge_count = 0;
    EXPECT_SUCCESS("no edges, null arrays", run_global(&c, error));
    c.edges = edges, c.edge_weights = weights, c.edge_count = 3;
    free_case(&c);
}

/* Each pointer set to NULL in turn, for every entry point that takes it. */
static void test_null_pointers(void)
{
    fit_case c = make_base_case();
    int32_t *offsets = c.offsets, *bones = c.bones;
    double *poses = c.poses, *examples = c.examples, *out = c.out, *rest = c.rest_positions;
    c.out = NULL;
    expect_all_fail(&c, "null destination", SK_ERROR_ARGUMENT, NULL);
    c.out = out, c.offsets = NULL;
    expect_all_fail(&c, "null offsets", SK_ERROR_ARGUMENT, NULL);
    c.offsets = offsets, c.bones = NULL;
    expect_all_fail(&c, "null bones", SK_ERROR_ARGUMENT, NULL);
    c.bones = bones, c.poses = NULL;
    expect_all_fail(&c, "null poses", SK_ERROR_ARGUMENT, NULL);
    c.poses = poses, c.examples = NULL;
    expect_all_fail(&c, "null examples", SK_ERROR_ARGUMENT, NULL);
    c.examples = examples, c.rest_positions = NULL;
    expect_case_fails(&c, 2, "null rest positions", SK_ERROR_ARGUMENT, NULL);
    c.rest_positions = rest;

    sk_lsqr_settings settings = c.settings;
    sk_lsqr_report report;
    EXPECT_FAILURE("global fit: null settings", SK_ERROR_ARGUMENT,
                   sk_fit_global(c.out, &report, &(sk_influences){c.offsets, c.bones, c.V, c.K},
                                 &(sk_examples){c.poses, c.examples, c.E, c.B}, c.edges, c.edge_weights, c.edge_count,
                                 NULL, NULL, NULL, error));
    EXPECT_FAILURE("global fit: null report", SK_ERROR_ARGUMENT,
                   sk_fit_global(c.out, NULL, &(sk_influences){c.offsets, c.bones, c.V, c.K},
                                 &(sk_examples){c.poses, c.examples, c.E, c.B}, c.edges, c.edge_weights, c.edge_count,
                                 &settings, NULL, NULL, error));
    free_case(&c);
}

static void test_zero_counts(void)
{
    fit_case c = make_base_case();
    c.E = 0;
    expect_all_fail(&c, "example_count 0", SK_ERROR_ARGUMENT, NULL);
    c.E = 6, c.B = 0;
    expect_all_fail(&c, "bone_count 0", SK_ERROR_ARGUMENT, NULL);
    free_case(&c);

    static const int32_t no_offsets[] = {0};
    fit_case empty = make_case(no_offsets, NULL, 0, 0, 3, 6);
    expect_all_fail(&empty, "vertex_count 0", SK_ERROR_ARGUMENT, NULL);
    free_case(&empty);
}

static void test_bad_global_settings(void)
{
    struct {
        const char *what;
        sk_lsqr_settings settings;
    } cases[] = {
        {"iteration_limit 0", {1e-10, 1e-10, 0.0, 0, 1, 0}},
        {"iteration_limit -3", {1e-10, 1e-10, 0.0, -3, 0, 0}},
        {"negative atol", {-1.0, 1e-10, 0.0, 100, 1, 0}},
        {"negative btol", {1e-10, -1.0, 0.0, 100, 1, 0}},
        {"NaN atol", {NAN, 1e-10, 0.0, 100, 0, 0}},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i) {
        fit_case c = make_base_case();
        c.settings = cases[i].settings;
        expect_case_fails(&c, 1, cases[i].what, SK_ERROR_ARGUMENT, NULL);
        free_case(&c);
    }
}

/* Too few examples, and bones that always move together: SK_ERROR_RANK naming the vertex. */
static void test_underdetermined_vertices(void)
{
    /* Vertex 1 has 3 influences (11 unknowns) but 2 examples give 6 equations; vertex 0 has 3 unknowns. */
    static const int32_t offsets[] = {0, 1, 4, 5}, bones[] = {0, 0, 1, 2, 2};
    fit_case c = make_case(offsets, bones, 3, 5, 3, 2);
    expect_case_fails(&c, 0, "2 examples for 3 influences", SK_ERROR_RANK, "vertex 1");
    c.lambda = 1e-4;
    EXPECT_SUCCESS("the same with lambda > 0", run_per_vertex(&c, error));
    CHECK(all_finite(c.out, 4 * c.K));
    free_case(&c);

    /* Enough examples, but bones 1 and 2 have the same pose in every one: vertex 2 uses both. */
    static const int32_t together[] = {0, 1, 2, 4}, together_bones[] = {0, 1, 1, 2};
    fit_case same = make_case(together, together_bones, 3, 4, 3, 8);
    for (size_t e = 0; e < same.E; ++e)
        memcpy(same.poses + 16 * (e * same.B + 2), same.poses + 16 * (e * same.B + 1), 16 * sizeof(double));
    expect_case_fails(&same, 0, "bones that move together", SK_ERROR_RANK, "vertex 2");
    same.lambda = 1e-4;
    EXPECT_SUCCESS("bones that move together, lambda > 0", run_per_vertex(&same, error));
    free_case(&same);
}

/* Failures in several workers' ranges: the lowest failing vertex is reported, whatever the threads. */
static void test_rank_failure_in_worker_threads(void)
{
    const size_t V = 300, E = 2;
    int32_t offsets[301], bones[300 + 4];
    size_t k = 0;
    for (size_t vertex = 0; vertex < V; ++vertex) {
        offsets[vertex] = (int32_t)k;
        if (vertex == 130 || vertex == 250) { /* 11 unknowns, 6 equations */
            bones[k++] = 0, bones[k++] = 1, bones[k++] = 2;
        } else {
            bones[k++] = (int32_t)(vertex % 3);
        }
    }
    offsets[V] = (int32_t)k;
    fit_case c = make_case(offsets, bones, V, k, 3, E);
    const int thread_counts[] = {1, 3, 0};
    for (size_t t = 0; t < 3; ++t) {
        c.thread_count = thread_counts[t];
        char what[64];
        snprintf(what, sizeof what, "failures at vertices 130 and 250, thread_count %d", thread_counts[t]);
        expect_case_fails(&c, 0, what, SK_ERROR_RANK, "vertex 130");
    }
    free_case(&c);
}

static void test_lbs_influence_limit(void)
{
    const size_t B = 70, E = 2;
    int32_t offsets[] = {0, 2, 67}, bones[67];
    bones[0] = 0, bones[1] = 1;
    for (int32_t k = 2; k < 67; ++k)
        bones[k] = k;
    fit_case c = make_case(offsets, bones, 2, 67, B, E);
    expect_case_fails(&c, 2, "65 influences", SK_ERROR_ARGUMENT, "65");
    free_case(&c);
}

/* ---------------------------------------------------------------------------------------------
 * Every function accepts error == NULL on success (checked in test_base_case_is_accepted for the
 * fits; here for lsqr too) and the status names of the fitting statuses are distinct.
 * ------------------------------------------------------------------------------------------- */

static void test_fitting_status_names(void)
{
    const char *cancelled = sk_status_name(SK_ERROR_CANCELLED), *rank = sk_status_name(SK_ERROR_RANK);
    CHECK(cancelled && cancelled[0] && rank && rank[0] && strcmp(cancelled, rank) != 0);
    CHECK(strcmp(rank, sk_status_name(SK_ERROR_SINGULAR)) != 0 && strcmp(rank, sk_status_name(SK_ERROR_LAPACK)) != 0);
    CHECK(strcmp(cancelled, sk_status_name((sk_status)99)) != 0);
}

int main(void)
{
    test_program_name = "test_fit";
    test_per_vertex_recovers_exact_model(1);
    test_per_vertex_recovers_exact_model(0);
    test_lbs_recovers_exact_weights();
    test_lbs_on_unreproducible_data();
    test_lbs_at_64_influences();
    test_global_stays_exact_without_edge_weights();
    test_global_minimises_data_and_edges();
    test_global_thread_count_and_cancel();
    test_base_case_is_accepted();
    test_bad_influence_patterns();
    test_non_finite_inputs();
    test_bad_lambda();
    test_values_that_overflow_once_multiplied();
    test_bad_edges();
    test_null_pointers();
    test_zero_counts();
    test_bad_global_settings();
    test_underdetermined_vertices();
    test_rank_failure_in_worker_threads();
    test_lbs_influence_limit();
    test_fitting_status_names();
    test_per_vertex_prior(); /* last: it draws random numbers the other tests' data depend on */
    return finish_tests();
}
