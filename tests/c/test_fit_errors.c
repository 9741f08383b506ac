/*
 * Standalone tests of what the skinkit fitting solvers (csrc/skinkit.h, "Fitting to example poses")
 * refuse: sk_fit_per_vertex, sk_fit_global and sk_fit_lbs_weights given bad influence patterns,
 * non-finite or overflowing values, bad lambdas, edges, settings and pointers, zero counts, too few
 * examples and too many influences (their results: test_fit.c).
 *
 * Meant to run under AddressSanitizer and UndefinedBehaviorSanitizer: every array handed to the core
 * is an exactly sized heap block, so a solver that read past its counts (or past a bad index before
 * rejecting it) would be stopped by the sanitizer, not just by a failed CHECK.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "skinkit.h"
#include "fit_cases.h"
#include "test_support.h"

/* ---------------------------------------------------------------------------------------------
 * Errors: one small valid problem, broken one way at a time
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
                  .settings = {1e-10, 1e-10, 0.0, 1000, 1, 1}};
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
    test_program_name = "test_fit_errors";
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
    return finish_tests();
}
