/*
 * Standalone tests of the skinkit fitting solvers (csrc/skinkit.h, "Fitting to example poses"):
 * sk_fit_per_vertex, sk_validate_per_vertex, sk_fit_global and sk_fit_lbs_weights find the right answers (their refusals:
 * test_fit_errors.c; sk_lsqr itself: test_lsqr.c).
 *
 * Meant to run under AddressSanitizer and UndefinedBehaviorSanitizer: every array handed to the core
 * is an exactly sized heap block, so a solver that read or wrote past its counts would be stopped by
 * the sanitizer, not just by a failed CHECK.
 *
 * Numerical results are compared with references computed with plain loops (here and in fit_cases.c):
 * models generated in the test, the KKT systems of the constrained least-squares problems solved by an
 * own Gaussian elimination, normal equations solved by an own Cholesky factorisation, and a brute-force
 * search over the faces of the simplex for the non-negative weights. The core is not only compared
 * with itself.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "skinkit.h"
#include "sk_internal.h" /* only for sk_worker_count and SK_SOLVE_ITEMS_PER_WORKER: proves the work is split */
#include "fit_cases.h"
#include "test_support.h"

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
        CHECK_IN(context, same_across_threads(threaded, single_threaded, 4 * K));
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
        CHECK_IN(context, same_across_threads(threaded, weights, K));
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
 * Cross-validation over several lambdas equals the per-vertex fit made fold by fold
 * ------------------------------------------------------------------------------------------- */

/* Vertex errors of the fit on the examples outside `fold` (and the always-fitted tail) on those inside it. */
static void reference_fold_errors(double *errors, const fit_model *m, size_t folds, size_t tail, size_t fold,
                                  double lambda, const double *prior)
{
    const size_t E = m->example_count, V = m->vertex_count, B = m->bone_count;
    double *poses = allocate(16 * E * B, sizeof *poses), *positions = allocate(3 * E * V, sizeof *positions);
    size_t kept = 0;
    for (size_t e = 0; e < E; ++e)
        if (!(e + tail < E && e % folds == fold)) {
            memcpy(poses + 16 * B * kept, m->poses + 16 * B * e, 16 * B * sizeof *poses);
            memcpy(positions + 3 * V * kept, m->examples + 3 * V * e, 3 * V * sizeof *positions);
            ++kept;
        }
    double *fitted = allocate(4 * m->influence_count, sizeof *fitted);
    const sk_examples subset = {poses, positions, kept, B};
    EXPECT_SUCCESS("a fold's reference fit", sk_fit_per_vertex(fitted, &m->influences, &subset, prior, lambda, 1,
                                                               error));
    for (size_t v = 0; v < V; ++v) {
        errors[v] = 0.0;
        for (size_t e = fold; e + tail < E; e += folds)
            for (int r = 0; r < 3; ++r) {
                double predicted = 0.0;
                for (int32_t k = m->offsets[v]; k < m->offsets[v + 1]; ++k)
                    for (int c = 0; c < 4; ++c)
                        predicted += m->poses[16 * (e * B + (size_t)m->bones[k]) + 4 * (size_t)r + (size_t)c] *
                                     fitted[4 * (size_t)k + (size_t)c];
                const double difference = predicted - m->examples[3 * (e * V + v) + (size_t)r];
                errors[v] += difference * difference;
            }
    }
    free(fitted);
    free(positions);
    free(poses);
}

static void test_validation_matches_fold_by_fold_fits(void)
{
    fit_model m = make_fit_model(25, 4, 10, 3, 0);
    add_noise(m.examples, 3 * m.example_count * m.vertex_count, 0.05);
    const double lambdas[] = {0.0, 1e-4, 0.1, 10.0}; /* 0: dgelsd's path, the others the normal equations' */
    const size_t L = 4, folds = 3, tail = 1, V = m.vertex_count;
    double *validated = allocate(V * L, sizeof *validated);
    const size_t K = m.influence_count;
    double *fold_priors = allocate(folds * 4 * K, sizeof *fold_priors); /* each fold its own prior */
    for (size_t k = 0; k < folds * 4 * K; ++k)
        fold_priors[k] = m.coordinates[k % (4 * K)] + (k % 4 == 3 ? 0.0 : 0.1 * (double)(k / (4 * K) + 1));
    EXPECT_SUCCESS("cross-validation", sk_validate_per_vertex(validated, &m.influences, &m.example_set, tail, folds,
                                                              NULL, fold_priors, lambdas, L, 2, error));
    double *expected = allocate(V * L, sizeof *expected), *fold_errors = allocate(V, sizeof *fold_errors);
    for (size_t k = 0; k < V * L; ++k)
        expected[k] = 0.0;
    for (size_t fold = 0; fold < folds; ++fold)
        for (size_t l = 0; l < L; ++l) {
            reference_fold_errors(fold_errors, &m, folds, tail, fold, lambdas[l], fold_priors + fold * 4 * K);
            for (size_t v = 0; v < V; ++v)
                expected[v * L + l] += fold_errors[v];
        }
    double worst = 0.0, largest = 0.0;
    for (size_t k = 0; k < V * L; ++k) {
        worst = fabs(validated[k] - expected[k]) > worst ? fabs(validated[k] - expected[k]) : worst;
        largest = expected[k] > largest ? expected[k] : largest;
    }
    CHECK_IN("validation errors equal the fold-by-fold fits'", largest > 0.0 && worst <= 1e-9 * largest);
    EXPECT_FAILURE("one fold", SK_ERROR_ARGUMENT, sk_validate_per_vertex(validated, &m.influences, &m.example_set, 0,
                                                                         1, NULL, NULL, lambdas, L, 1, error));
    EXPECT_FAILURE("every example always fitted", SK_ERROR_ARGUMENT,
                   sk_validate_per_vertex(validated, &m.influences, &m.example_set, m.example_count, 2, NULL, NULL,
                                          lambdas, L, 1, error));
    EXPECT_FAILURE("more folds than validated examples", SK_ERROR_ARGUMENT,
                   sk_validate_per_vertex(validated, &m.influences, &m.example_set, 1, m.example_count, NULL, NULL,
                                          lambdas, L, 1, error));
    const double negative[] = {0.1, -1.0};
    EXPECT_FAILURE("a negative lambda", SK_ERROR_ARGUMENT,
                   sk_validate_per_vertex(validated, &m.influences, &m.example_set, 0, 2, NULL, NULL, negative, 2, 1,
                                          error));
    free(fold_errors);
    free(expected);
    free(fold_priors);
    free(validated);
    free_fit_model(&m);
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
    test_per_vertex_prior(); /* after the others: it draws random numbers their data depend on */
    test_validation_matches_fold_by_fold_fits();
    return finish_tests();
}
