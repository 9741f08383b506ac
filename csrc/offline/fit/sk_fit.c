/*
 * Fitting skinning models to example poses (Merry 2007, chapter 4): the per-vertex animation-space fit
 * with vertex regularisation (eq. 4.3), the global fit with edge regularisation (eq. 4.4) by
 * matrix-free LSQR with a block-Jacobi preconditioner, and the non-negative linear-blend baseline.
 *
 * A vertex with n influences has m = 4n - 1 unknowns x: (x, y, z) of every p_j, then the homogeneous
 * weights of all influences but the last, whose weight is 1 minus their sum (section 4.1.3). So
 * p = M x + c, with c = 1 at the last weight. Its 3E data rows are D x = v^e - t_last^e.
 */
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_internal.h"

/* Singular values below this fraction of the largest count as zero in the small dense solves. */
#define SK_RANK_TOLERANCE 1e-12

/* The influences and examples unpacked (checked non-null by make_problem). */
typedef struct fit_problem {
    const int32_t *offsets, *bones;
    size_t vertex_count, influence_count, example_count, bone_count;
    const double *poses, *examples;
} fit_problem;

static sk_status make_problem(fit_problem *p, const sk_influences *influences, const sk_examples *examples,
                              sk_error *error)
{
    if (!influences || !examples)
        return sk_fail(error, SK_ERROR_ARGUMENT, "fitting needs at least one example, one bone and one vertex");
    *p = (fit_problem){influences->offsets,   influences->bones,    influences->vertex_count,
                       influences->influence_count, examples->example_count, examples->bone_count,
                       examples->poses,      examples->positions};
    return SK_OK;
}

static size_t influences_of(const fit_problem *p, size_t vertex)
{
    return (size_t)(p->offsets[vertex + 1] - p->offsets[vertex]);
}

static size_t unknowns_of(size_t influences)
{
    return 4 * influences - 1;
}

static const double *pose_of(const fit_problem *p, size_t example, size_t influence)
{
    return p->poses + 16 * (example * p->bone_count + (size_t)p->bones[influence]);
}

/* The 3 data rows of example e (row-major, leading dimension `stride`) and their right-hand sides. */
static void example_rows(double *out, size_t stride, double *rhs, const fit_problem *p, size_t vertex, size_t e)
{
    const size_t begin = (size_t)p->offsets[vertex], n = influences_of(p, vertex), last = n - 1;
    const double *last_pose = pose_of(p, e, begin + last);
    for (int r = 0; r < 3; ++r, out += stride) {
        rhs[r] = p->examples[3 * (e * p->vertex_count + vertex) + (size_t)r] - last_pose[4 * r + 3];
        for (size_t s = 0; s < n; ++s) {
            const double *g = pose_of(p, e, begin + s);
            for (int c = 0; c < 3; ++c)
                out[3 * s + (size_t)c] = g[4 * r + c];
            if (s < last)
                out[3 * n + s] = g[4 * r + 3] - last_pose[4 * r + 3];
        }
    }
}

/* The 3E x m data block (row-major, leading dimension `stride`) and its right-hand side. */
static void data_block(double *block, size_t stride, double *rhs, const fit_problem *p, size_t vertex)
{
    for (size_t e = 0; e < p->example_count; ++e)
        example_rows(block + 3 * e * stride, stride, rhs + 3 * e, p, vertex, e);
}

/* p (4n) from x (4n - 1): the weights of the last influence complete the sum to 1. */
static void expand(double *coordinates, const double *x, size_t n)
{
    double weight_sum = 0.0;
    for (size_t s = 0; s < n; ++s) {
        for (int c = 0; c < 3; ++c)
            coordinates[4 * s + (size_t)c] = x[3 * s + (size_t)c];
        if (s + 1 < n) {
            coordinates[4 * s + 3] = x[3 * n + s];
            weight_sum += x[3 * n + s];
        }
    }
    coordinates[4 * (n - 1) + 3] = 1.0 - weight_sum;
}

static void compress(double *x, const double *coordinates, size_t n)
{
    for (size_t s = 0; s < n; ++s) {
        for (int c = 0; c < 3; ++c)
            x[3 * s + (size_t)c] = coordinates[4 * s + (size_t)c];
        if (s + 1 < n)
            x[3 * n + s] = coordinates[4 * s + 3];
    }
}

/* ---------------------------------------------------------------------------------------------
 * Running a per-vertex job on several threads, each with its own scratch memory
 * ------------------------------------------------------------------------------------------- */

typedef sk_status (*vertex_job)(const void *context, size_t vertex, double *scratch, sk_error *error);

typedef struct vertex_jobs {
    vertex_job job;
    const void *context;
    size_t scratch_doubles;
    size_t failed_vertex[SK_MAX_WORKERS];
    sk_error errors[SK_MAX_WORKERS];
} vertex_jobs;

static void run_vertex_range(void *context, size_t worker, size_t begin, size_t end)
{
    vertex_jobs *jobs = context;
    double *scratch = sk_allocate(jobs->scratch_doubles, sizeof *scratch);
    if (!scratch) {
        jobs->failed_vertex[worker] = begin;
        sk_fail(&jobs->errors[worker], SK_ERROR_MEMORY, "out of memory for a solver's workspace");
        return;
    }
    for (size_t vertex = begin; vertex < end; ++vertex) {
        if (jobs->job(jobs->context, vertex, scratch, &jobs->errors[worker]) != SK_OK) {
            jobs->failed_vertex[worker] = vertex;
            break;
        }
    }
    free(scratch);
}

/* Runs job for every vertex; on failure reports the error of the lowest failing vertex. */
static sk_status for_each_vertex(size_t vertex_count, int thread_count, size_t scratch_doubles, vertex_job job,
                                 const void *context, sk_error *error)
{
    vertex_jobs *jobs = sk_allocate_zeroed(1, sizeof *jobs);
    if (!jobs)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory");
    jobs->job = job;
    jobs->context = context;
    jobs->scratch_doubles = scratch_doubles;
    for (size_t w = 0; w < SK_MAX_WORKERS; ++w)
        jobs->failed_vertex[w] = SIZE_MAX;
    sk_parallel_for(vertex_count, SK_SOLVE_ITEMS_PER_WORKER, thread_count, run_vertex_range, jobs);
    size_t worst = SK_MAX_WORKERS;
    for (size_t w = 0; w < SK_MAX_WORKERS; ++w)
        if (jobs->failed_vertex[w] != SIZE_MAX && (worst == SK_MAX_WORKERS || jobs->failed_vertex[w] < jobs->failed_vertex[worst]))
            worst = w;
    sk_status status = SK_OK;
    if (worst < SK_MAX_WORKERS) {
        status = jobs->errors[worst].status;
        if (error)
            *error = jobs->errors[worst];
    }
    free(jobs);
    return status == SK_OK ? sk_succeed(error) : status;
}

/* ---------------------------------------------------------------------------------------------
 * Input checks shared by the solvers
 * ------------------------------------------------------------------------------------------- */

static sk_status check_problem(const fit_problem *p, sk_error *error)
{
    if (!p->poses || !p->examples || p->example_count == 0 || p->bone_count == 0 || p->vertex_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "fitting needs at least one example, one bone and one vertex");
    const sk_influences influences = {p->offsets, p->bones, p->vertex_count, p->influence_count};
    sk_status status = sk_validate_influences(&influences, p->bone_count, error);
    if (status != SK_OK)
        return status;
    for (size_t vertex = 0; vertex < p->vertex_count; ++vertex)
        if (influences_of(p, vertex) == 0)
            return sk_fail(error, SK_ERROR_ARGUMENT, "vertex %zu: its influence set is empty", vertex);
    size_t pose_values, example_values;
    sk_status sizes = sk_array_size(&pose_values, p->example_count, p->bone_count, 16, "example pose", error);
    if (sizes == SK_OK)
        sizes = sk_array_size(&example_values, p->example_count, p->vertex_count, 3, "example position", error);
    if (sizes != SK_OK)
        return sizes;
    const size_t bad_pose = sk_first_non_finite(p->poses, pose_values);
    if (bad_pose < pose_values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "example %zu, bone %zu: the pose matrix has a NaN or infinity",
                       bad_pose / 16 / p->bone_count, bad_pose / 16 % p->bone_count);
    const size_t bad_position = sk_first_non_finite(p->examples, example_values);
    if (bad_position < example_values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "example %zu, vertex %zu: the position has a NaN or infinity",
                       bad_position / 3 / p->vertex_count, bad_position / 3 % p->vertex_count);
    return SK_OK;
}

static size_t max_influences(const fit_problem *p)
{
    size_t most = 0;
    for (size_t vertex = 0; vertex < p->vertex_count; ++vertex)
        if (influences_of(p, vertex) > most)
            most = influences_of(p, vertex);
    return most;
}

/* ---------------------------------------------------------------------------------------------
 * Per-vertex fit (eq. 4.3)
 * ------------------------------------------------------------------------------------------- */

typedef struct per_vertex_fit {
    fit_problem problem;
    double *coordinates;
    const double *prior; /* NULL: towards zero */
    double lambda;
    size_t max_rows, max_columns;
} per_vertex_fit;

/* Rows sqrt(lambda) (M x + c) = sqrt(lambda) prior appended below the data rows (prior NULL: zero). */
static void regulariser_rows(double *block, size_t stride, double *rhs, size_t n, double root_lambda,
                             const double *prior)
{
    const size_t m = unknowns_of(n);
    memset(block, 0, 4 * n * stride * sizeof *block);
    for (size_t s = 0; s < n; ++s) {
        for (int c = 0; c < 4; ++c)
            rhs[4 * s + (size_t)c] = prior ? root_lambda * prior[4 * s + (size_t)c] : 0.0;
        for (int c = 0; c < 3; ++c)
            block[(4 * s + (size_t)c) * stride + 3 * s + (size_t)c] = root_lambda;
        double *weight_row = block + (4 * s + 3) * stride;
        if (s + 1 < n) {
            weight_row[3 * n + s] = root_lambda;
        } else {
            for (size_t k = 3 * n; k < m; ++k)
                weight_row[k] = -root_lambda;
            rhs[4 * s + 3] -= root_lambda; /* the constant 1 of the eliminated weight */
        }
    }
}

/*
 * With many examples (3E rows) and few influences (n), the active-set iterations would each solve a 3E x n problem:
 * replace A, b by R, Q^T b of A = QR (n rows; |A w - b|^2 differs only by a constant), in place. Returns the rows
 * now used (rows when there are not more rows than columns), or 0 when LAPACK fails. tau: n doubles of scratch.
 */
static size_t compress_rows(double *a, double *b, size_t rows, size_t n, double *tau)
{
    if (rows <= n)
        return rows;
    /* The row-major A is the column-major A^T, whose LQ factorisation A^T = L Q gives R = L^T in the same memory:
     * no transposed copy and no allocation, unlike LAPACKE's row-major QR wrappers (n <= 255 here). */
    double work[256];
    if (LAPACKE_dgelqf_work(LAPACK_COL_MAJOR, (lapack_int)n, (lapack_int)rows, a, (lapack_int)n, tau, work,
                            (lapack_int)n) != 0 ||
        LAPACKE_dormlq_work(LAPACK_COL_MAJOR, 'L', 'N', (lapack_int)rows, 1, (lapack_int)n, a, (lapack_int)n, tau, b,
                            (lapack_int)rows, work, 256) != 0)
        return 0;
    for (size_t r = 0; r < n; ++r)
        for (size_t c = 0; c < r; ++c)
            a[r * n + c] = 0.0; /* here dgelqf left its reflectors */
    return n;
}

/* Finite inputs can still overflow inside LAPACK (a pose entry of -1e308, lambda 1e308: its norms square them), and
 * LAPACK then complains on stdout and returns garbage; so each vertex's system must have a finite sum of squares. */
static sk_status overflowed(size_t vertex, sk_error *error)
{
    return sk_fail(error, SK_ERROR_NOT_FINITE,
                   "vertex %zu: its least-squares system overflows double precision (values near 1e308 in the "
                   "examples, poses or regularisation); normalise the data to a unit box", vertex);
}

static sk_status check_system_finite(const double *a, const double *b, size_t rows, size_t columns, size_t vertex,
                                     sk_error *error)
{
    double squares = 0.0;
    for (size_t i = 0; i < rows * columns; ++i)
        squares += a[i] * a[i];
    for (size_t i = 0; i < rows; ++i)
        squares += b[i] * b[i];
    return isfinite(squares) ? SK_OK : overflowed(vertex, error);
}

/* Normal equations of a least-squares problem in m unknowns: the lower triangle of a^T a (m*m, row-major) then
 * a^T b (m). The row-major lower triangle is the column-major upper one, which dposv reads in place. */
static size_t normal_size(size_t m)
{
    return m * m + m;
}

static void clear_normal(double *normal, size_t m)
{
    memset(normal, 0, normal_size(m) * sizeof *normal);
}

/* normal += scale * (the normal equations of rows a (rows x m, row-major) and their right-hand sides b). */
static void add_to_normal(double *normal, const double *a, const double *b, size_t rows, size_t m, double scale)
{
    double *right = normal + m * m;
    for (size_t r = 0; r < rows; ++r) {
        const double *row = a + r * m;
        for (size_t i = 0; i < m; ++i) {
            if (row[i] == 0.0)
                continue;
            const double entry = scale * row[i];
            right[i] += entry * b[r];
            for (size_t j = 0; j <= i; ++j)
                normal[i * m + j] += entry * row[j];
        }
    }
}

/* x from the normal equations (kept) by Cholesky in work (normal_size(m) doubles); 0 if not positive definite. */
static int solve_normal(double *x, const double *normal, size_t m, double *work)
{
    memcpy(work, normal, normal_size(m) * sizeof *work);
    if (LAPACKE_dposv_work(LAPACK_COL_MAJOR, 'U', (lapack_int)m, 1, work, (lapack_int)m, work + m * m,
                           (lapack_int)m) != 0)
        return 0;
    memcpy(x, work + m * m, m * sizeof *x);
    return 1;
}

/* x minimising |a x - b| (rows x m) by the normal equations' Cholesky factorisation: with lambda > 0 the regulariser
 * rows make a^T a positive definite, and an m x m solve is far cheaper than dgelsd's SVD. Returns 0 when the
 * factorisation fails. normal: 2 normal_size(m) doubles of scratch. */
static int normal_equations_solve(double *x, const double *a, const double *b, size_t rows, size_t m, double *normal)
{
    clear_normal(normal, m);
    add_to_normal(normal, a, b, rows, m, 1.0);
    return solve_normal(x, normal, m, normal + normal_size(m));
}

static size_t longest_of(const per_vertex_fit *fit)
{
    return fit->max_rows > fit->max_columns ? fit->max_rows : fit->max_columns;
}

static sk_status fit_vertex(const void *context, size_t vertex, double *scratch, sk_error *error)
{
    const per_vertex_fit *fit = context;
    const fit_problem *p = &fit->problem;
    const size_t n = influences_of(p, vertex), m = unknowns_of(n);
    const size_t data_rows = 3 * p->example_count;
    if (fit->lambda == 0.0 && data_rows < m)
        return sk_fail(error, SK_ERROR_RANK,
                       "vertex %zu: %zu influences need %zu unknowns but %zu examples give %zu equations", vertex, n,
                       m, p->example_count, data_rows);
    double *block = scratch, *rhs = scratch + fit->max_rows * fit->max_columns;
    double *singular_values = rhs + longest_of(fit);
    data_block(block, m, rhs, p, vertex);
    sk_status status = check_system_finite(block, rhs, data_rows, m, vertex, error);
    if (status != SK_OK)
        return status;
    const size_t used = compress_rows(block, rhs, data_rows, m, singular_values);
    if (used == 0)
        return sk_fail(error, SK_ERROR_LAPACK, "vertex %zu: the QR factorisation of its examples failed", vertex);
    const size_t rows = used + (fit->lambda > 0.0 ? 4 * n : 0);
    if (fit->lambda > 0.0)
        regulariser_rows(block + used * m, m, rhs + used, n, sqrt(fit->lambda),
                         fit->prior ? fit->prior + 4 * (size_t)p->offsets[vertex] : NULL);
    status = check_system_finite(block, rhs, rows, m, vertex, error);
    if (status != SK_OK)
        return status;
    if (fit->lambda > 0.0 && normal_equations_solve(rhs, block, rhs, rows, m, singular_values + longest_of(fit))) {
        expand(fit->coordinates + 4 * (size_t)p->offsets[vertex], rhs, n);
        return SK_OK;
    }
    lapack_int rank = 0;
    const lapack_int info = LAPACKE_dgelsd(LAPACK_ROW_MAJOR, (lapack_int)rows, (lapack_int)m, 1, block,
                                           (lapack_int)m, rhs, 1, singular_values, SK_RANK_TOLERANCE, &rank);
    if (info != 0)
        return sk_fail(error, SK_ERROR_LAPACK, "vertex %zu: dgelsd failed (info %d)", vertex, (int)info);
    if ((size_t)rank < m)
        return sk_fail(error, SK_ERROR_RANK,
                       "vertex %zu: the examples determine only %d of its %zu unknowns (bones that move "
                       "together, or too few examples); add regularisation or examples",
                       vertex, (int)rank, m);
    expand(fit->coordinates + 4 * (size_t)p->offsets[vertex], rhs, n);
    return SK_OK;
}

sk_status sk_fit_per_vertex(double *coordinates, const sk_influences *influences, const sk_examples *examples,
                            const double *prior, double lambda, int thread_count, sk_error *error)
{
    per_vertex_fit fit = {.coordinates = coordinates, .prior = prior, .lambda = lambda};
    if (!coordinates)
        return sk_fail(error, SK_ERROR_ARGUMENT, "coordinates must not be null");
    if (!(lambda >= 0.0) || !isfinite(lambda))
        return sk_fail(error, SK_ERROR_ARGUMENT, "lambda must be finite and >= 0, it is %g", lambda);
    sk_status status = make_problem(&fit.problem, influences, examples, error);
    if (status == SK_OK)
        status = check_problem(&fit.problem, error);
    const size_t vertex_count = fit.problem.vertex_count, influence_count = fit.problem.influence_count;
    const size_t example_count = fit.problem.example_count;
    if (status != SK_OK)
        return status;
    if (prior && !sk_all_finite(prior, 4 * influence_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "the prior coordinates have a NaN or infinity");
    const size_t n = max_influences(&fit.problem);
    if (n > 64)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the per-vertex fit takes at most 64 influences per vertex, not %zu", n);
    fit.max_columns = unknowns_of(n);
    fit.max_rows = 3 * example_count + 4 * n;
    /* the block, its right-hand side, singular values, then the normal equations and their Cholesky factor */
    const size_t scratch = fit.max_rows * fit.max_columns + 2 * longest_of(&fit) + 2 * normal_size(fit.max_columns);
    return for_each_vertex(vertex_count, thread_count, scratch, fit_vertex, &fit, error);
}

/* ---------------------------------------------------------------------------------------------
 * Cross-validation of the per-vertex fit over several lambdas: per vertex and fold, the QR factorisation of the
 * fitted examples' rows is made once and reused by every lambda (only the 4n regulariser rows change).
 * ------------------------------------------------------------------------------------------- */

typedef struct per_vertex_validation {
    fit_problem problem;
    const double *prior, *fold_priors;
    const double *lambdas;
    size_t lambda_count, fold_count, fitted_tail;
    double *squared_errors; /* vertex_count * lambda_count */
    size_t max_rows, max_columns;
} per_vertex_validation;

/* A vertex's scratch: the rows of one fold for the slow path (block, right-hand side, singular values), four
 * normal equations (all examples', the regulariser's at lambda 1, one fold's, the Cholesky's work), the rows of one
 * example, the coordinates and the unknowns. */
typedef struct validation_scratch {
    double *block, *rhs, *singular_values, *total, *regulariser, *fold, *work, *example, *example_rhs,
        *coordinates, *x;
} validation_scratch;

static size_t validation_scratch_size(const per_vertex_validation *v)
{
    return v->max_rows * v->max_columns + 2 * v->max_rows + 4 * normal_size(v->max_columns) + 5 * v->max_columns + 4;
}

static validation_scratch split_scratch(const per_vertex_validation *v, double *scratch)
{
    validation_scratch w;
    w.block = scratch;
    w.rhs = w.block + v->max_rows * v->max_columns;
    w.singular_values = w.rhs + v->max_rows;
    w.total = w.singular_values + v->max_rows;
    w.regulariser = w.total + normal_size(v->max_columns);
    w.fold = w.regulariser + normal_size(v->max_columns);
    w.work = w.fold + normal_size(v->max_columns);
    w.example = w.work + normal_size(v->max_columns);
    w.example_rhs = w.example + 3 * v->max_columns;
    w.coordinates = w.example_rhs + 3;
    w.x = w.coordinates + v->max_columns + 1;
    return w;
}

/* What a fold's fits pull towards at a vertex: its own prior (one not fitted to its validated examples), the shared
 * one, or NULL (zero). */
static const double *prior_of(const per_vertex_validation *v, size_t fold, size_t vertex)
{
    const size_t first = 4 * (size_t)v->problem.offsets[vertex];
    if (v->fold_priors)
        return v->fold_priors + 4 * v->problem.influence_count * fold + first;
    return v->prior ? v->prior + first : NULL;
}

/* Example e is validated in fold e % fold_count, except the last fitted_tail examples, which are always fitted. */
static int validated_in(const per_vertex_validation *v, size_t e, size_t fold)
{
    return e + v->fitted_tail < v->problem.example_count && e % v->fold_count == fold;
}

/* Squared distance, summed over the fold's examples, between the vertex's model (4n coordinates) and them. */
static double fold_error(const per_vertex_validation *v, size_t vertex, size_t fold, const double *coordinates)
{
    const fit_problem *p = &v->problem;
    const size_t begin = (size_t)p->offsets[vertex], n = influences_of(p, vertex);
    double total = 0.0;
    for (size_t e = fold; e < p->example_count; e += v->fold_count) {
        if (!validated_in(v, e, fold))
            continue;
        for (int r = 0; r < 3; ++r) {
            double predicted = 0.0;
            for (size_t s = 0; s < n; ++s) {
                const double *g = pose_of(p, e, begin + s);
                for (int c = 0; c < 4; ++c)
                    predicted += g[4 * r + c] * coordinates[4 * s + (size_t)c];
            }
            const double difference = predicted - p->examples[3 * (e * p->vertex_count + vertex) + (size_t)r];
            total += difference * difference;
        }
    }
    return total;
}

/* The slow path, for lambda 0 or a normal matrix that is not positive definite: the fold's rows and the regulariser's
 * by dgelsd (rank-deficient folds keep its minimum-norm fit: a valid, if poor, model). */
static sk_status least_squares_fold(const per_vertex_validation *v, size_t vertex, size_t fold, double lambda,
                                    validation_scratch *w, sk_error *error)
{
    const fit_problem *p = &v->problem;
    const size_t n = influences_of(p, vertex), m = unknowns_of(n);
    size_t rows = 0;
    for (size_t e = 0; e < p->example_count; ++e)
        if (!validated_in(v, e, fold)) {
            example_rows(w->block + rows * m, m, w->rhs + rows, p, vertex, e);
            rows += 3;
        }
    if (lambda > 0.0) {
        regulariser_rows(w->block + rows * m, m, w->rhs + rows, n, sqrt(lambda), prior_of(v, fold, vertex));
        rows += 4 * n;
    }
    for (size_t k = rows; k < m; ++k)
        w->rhs[k] = 0.0; /* dgelsd reads max(rows, m) right-hand sides */
    lapack_int rank = 0;
    const lapack_int info = LAPACKE_dgelsd(LAPACK_ROW_MAJOR, (lapack_int)rows, (lapack_int)m, 1, w->block,
                                           (lapack_int)m, w->rhs, 1, w->singular_values, SK_RANK_TOLERANCE, &rank);
    if (info != 0)
        return sk_fail(error, SK_ERROR_LAPACK, "vertex %zu: dgelsd failed (info %d) validating lambda %g", vertex,
                       (int)info, lambda);
    memcpy(w->x, w->rhs, m * sizeof *w->x);
    return SK_OK;
}

/* Per vertex: the normal equations of all examples once; each fold's are the total less its own examples', and each
 * lambda adds lambda times the fold's regulariser's before one small Cholesky solve. */
static sk_status validate_vertex(const void *context, size_t vertex, double *scratch, sk_error *error)
{
    const per_vertex_validation *v = context;
    const fit_problem *p = &v->problem;
    const size_t n = influences_of(p, vertex), m = unknowns_of(n);
    validation_scratch w = split_scratch(v, scratch);
    clear_normal(w.total, m);
    for (size_t e = 0; e < p->example_count; ++e) {
        example_rows(w.example, m, w.example_rhs, p, vertex, e);
        add_to_normal(w.total, w.example, w.example_rhs, 3, m, 1.0);
    }
    if (!sk_all_finite(w.total, normal_size(m)))
        return overflowed(vertex, error);
    double *errors = v->squared_errors + vertex * v->lambda_count;
    for (size_t l = 0; l < v->lambda_count; ++l)
        errors[l] = 0.0;
    for (size_t fold = 0; fold < v->fold_count; ++fold) {
        regulariser_rows(w.block, m, w.rhs, n, 1.0, prior_of(v, fold, vertex));
        clear_normal(w.regulariser, m);
        add_to_normal(w.regulariser, w.block, w.rhs, 4 * n, m, 1.0);
        memcpy(w.fold, w.total, normal_size(m) * sizeof *w.fold);
        for (size_t e = fold; e < p->example_count; e += v->fold_count)
            if (validated_in(v, e, fold)) {
                example_rows(w.example, m, w.example_rhs, p, vertex, e);
                add_to_normal(w.fold, w.example, w.example_rhs, 3, m, -1.0);
            }
        for (size_t l = 0; l < v->lambda_count; ++l) {
            const double lambda = v->lambdas[l];
            for (size_t k = 0; k < normal_size(m); ++k)
                w.work[k] = w.fold[k] + lambda * w.regulariser[k];
            if (!sk_all_finite(w.work, normal_size(m)))
                return overflowed(vertex, error);
            /* the slow path's block is free memory for the Cholesky factor (it holds >= normal_size(m) doubles) */
            if (!(lambda > 0.0 && solve_normal(w.x, w.work, m, w.block))) {
                const sk_status status = least_squares_fold(v, vertex, fold, lambda, &w, error);
                if (status != SK_OK)
                    return status;
            }
            expand(w.coordinates, w.x, n);
            errors[l] += fold_error(v, vertex, fold, w.coordinates);
        }
    }
    return SK_OK;
}

static sk_status check_validation(const per_vertex_validation *v, sk_error *error)
{
    const size_t example_count = v->problem.example_count;
    if (!v->squared_errors || !v->lambdas || v->lambda_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "validation needs an output and at least one lambda");
    for (size_t l = 0; l < v->lambda_count; ++l)
        if (!(v->lambdas[l] >= 0.0) || !isfinite(v->lambdas[l]))
            return sk_fail(error, SK_ERROR_ARGUMENT, "lambda %zu must be finite and >= 0, it is %g", l, v->lambdas[l]);
    if (v->fitted_tail >= example_count)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%zu always-fitted examples leave none of the %zu to validate",
                       v->fitted_tail, example_count);
    if (v->fold_count < 2 || v->fold_count > example_count - v->fitted_tail)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%zu folds: need 2 to %zu (one validated example each at least)",
                       v->fold_count, example_count - v->fitted_tail);
    size_t outputs;
    return sk_array_size(&outputs, v->problem.vertex_count, v->lambda_count, 1, "validation error", error);
}

sk_status sk_validate_per_vertex(double *squared_errors, const sk_influences *influences, const sk_examples *examples,
                                 size_t fitted_tail, size_t fold_count, const double *prior, const double *fold_priors,
                                 const double *lambdas, size_t lambda_count, int thread_count, sk_error *error)
{
    per_vertex_validation v = {.prior = prior, .fold_priors = fold_priors, .lambdas = lambdas, .lambda_count = lambda_count,
                               .fold_count = fold_count, .fitted_tail = fitted_tail, .squared_errors = squared_errors};
    sk_status status = make_problem(&v.problem, influences, examples, error);
    if (status == SK_OK)
        status = check_problem(&v.problem, error);
    if (status == SK_OK)
        status = check_validation(&v, error);
    if (status != SK_OK)
        return status;
    if (prior && !sk_all_finite(prior, 4 * v.problem.influence_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "the prior coordinates have a NaN or infinity");
    if (fold_priors && !sk_all_finite(fold_priors, 4 * v.problem.influence_count * fold_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "the folds' prior coordinates have a NaN or infinity");
    const size_t n = max_influences(&v.problem);
    if (n > 64)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the per-vertex fit takes at most 64 influences per vertex, not %zu", n);
    v.max_columns = unknowns_of(n);
    v.max_rows = 3 * v.problem.example_count + 4 * n;
    return for_each_vertex(v.problem.vertex_count, thread_count, validation_scratch_size(&v), validate_vertex, &v,
                           error);
}

/* ---------------------------------------------------------------------------------------------
 * Global fit (eq. 4.4): the system, its operator and its block-Jacobi preconditioner
 * ------------------------------------------------------------------------------------------- */

typedef struct global_system {
    fit_problem problem;
    size_t *column_start;     /* vertex_count + 1: x_v = x[column_start[v] ..] */
    double *factors;          /* upper Cholesky factor R_v of each vertex's normal block */
    size_t *factor_start;
    int *factored;            /* 0 where the normal block was not positive definite (identity is used) */
    const int32_t *edges;
    double *edge_scale;       /* sqrt(edge_weights) */
    size_t edge_count;
    int32_t *pair_offsets;    /* edge_count + 1, into pair_slots: one pair per bone of I(a) u I(b) */
    int32_t *pair_slots;      /* 2 per pair: the bone's influence slot in a and in b, -1 if absent */
    size_t pair_count, rows, columns;
    double *full;             /* 4 per influence: M x (operator) or gradients (transpose) */
    double *unknowns;         /* columns: x = R^-1 z when preconditioned */
    int precondition;
    int thread_count;
} global_system;

static size_t slot_of(const fit_problem *p, size_t vertex, int32_t bone)
{
    for (int32_t k = p->offsets[vertex]; k < p->offsets[vertex + 1]; ++k)
        if (p->bones[k] == bone)
            return (size_t)(k - p->offsets[vertex]);
    return SIZE_MAX;
}

/* Enumerates the union of the two influence sets of each edge, as pairs of slots. */
static sk_status build_edge_pairs(global_system *g, sk_error *error)
{
    const fit_problem *p = &g->problem;
    size_t capacity = 0;
    for (size_t k = 0; k < g->edge_count; ++k)
        capacity += influences_of(p, (size_t)g->edges[2 * k]) + influences_of(p, (size_t)g->edges[2 * k + 1]);
    g->pair_offsets = sk_allocate(g->edge_count + 1, sizeof *g->pair_offsets);
    g->pair_slots = sk_allocate(2 * (capacity + 1), sizeof *g->pair_slots);
    if (!g->pair_offsets || !g->pair_slots)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu edges", g->edge_count);
    size_t pairs = 0;
    for (size_t k = 0; k < g->edge_count; ++k) {
        const size_t a = (size_t)g->edges[2 * k], b = (size_t)g->edges[2 * k + 1];
        g->pair_offsets[k] = (int32_t)pairs;
        for (size_t s = 0; s < influences_of(p, a); ++s) {
            const size_t in_b = slot_of(p, b, p->bones[(size_t)p->offsets[a] + s]);
            g->pair_slots[2 * pairs] = (int32_t)s;
            g->pair_slots[2 * pairs + 1] = in_b == SIZE_MAX ? -1 : (int32_t)in_b;
            ++pairs;
        }
        for (size_t s = 0; s < influences_of(p, b); ++s) {
            if (slot_of(p, a, p->bones[(size_t)p->offsets[b] + s]) != SIZE_MAX)
                continue;
            g->pair_slots[2 * pairs] = -1;
            g->pair_slots[2 * pairs + 1] = (int32_t)s;
            ++pairs;
        }
    }
    g->pair_offsets[g->edge_count] = (int32_t)pairs;
    g->pair_count = pairs;
    return SK_OK;
}

/* full = M x (the linear part of p = M x + c) for one vertex. */
static void linear_part(double *full, const double *x, size_t n)
{
    expand(full, x, n);
    full[4 * (n - 1) + 3] -= 1.0;
}

/* x += M^T g for one vertex. */
static void add_linear_part_transposed(double *x, const double *gradient, size_t n)
{
    for (size_t s = 0; s < n; ++s) {
        for (int c = 0; c < 3; ++c)
            x[3 * s + (size_t)c] += gradient[4 * s + (size_t)c];
        if (s + 1 < n)
            x[3 * n + s] += gradient[4 * s + 3] - gradient[4 * (n - 1) + 3];
    }
}

/* Solves R x = z (transpose 0) or R^T x = z (transpose 1) in place, R upper triangular m x m. */
static void triangular_solve(const double *r, double *x, size_t m, int transpose)
{
    if (!transpose) {
        for (size_t i = m; i-- > 0;) {
            double sum = x[i];
            for (size_t j = i + 1; j < m; ++j)
                sum -= r[i * m + j] * x[j];
            x[i] = sum / r[i * m + i];
        }
    } else {
        for (size_t i = 0; i < m; ++i) {
            double sum = x[i];
            for (size_t j = 0; j < i; ++j)
                sum -= r[j * m + i] * x[j];
            x[i] = sum / r[i * m + i];
        }
    }
}

static void precondition_vertex(const global_system *g, double *x, size_t vertex, int transpose)
{
    if (g->precondition && g->factored[vertex])
        triangular_solve(g->factors + g->factor_start[vertex], x, g->column_start[vertex + 1] - g->column_start[vertex],
                         transpose);
}

typedef struct operator_call {
    const global_system *g;
    const double *in;
    double *out;
} operator_call;

/*
 * The data rows of a vertex are D x = G (M x) per example (the constant c only moves the right-hand side),
 * so they are applied from the poses directly: no per-vertex blocks are stored, and memory stays
 * proportional to the unknowns, not to vertices x examples.
 */
static void data_rows_forward(void *context, size_t worker, size_t begin, size_t end)
{
    (void)worker;
    const operator_call *call = context;
    const global_system *g = call->g;
    const fit_problem *p = &g->problem;
    double linear[4 * 64];
    for (size_t v = begin; v < end; ++v) {
        const size_t first = (size_t)p->offsets[v], n = influences_of(p, v);
        linear_part(linear, call->in + g->column_start[v], n);
        for (size_t e = 0; e < p->example_count; ++e) {
            double *y = call->out + 3 * (p->example_count * v + e);
            y[0] = y[1] = y[2] = 0.0;
            for (size_t s = 0; s < n; ++s) {
                const double *m = pose_of(p, e, first + s), *q = linear + 4 * s;
                for (int r = 0; r < 3; ++r)
                    y[r] += m[4 * r] * q[0] + m[4 * r + 1] * q[1] + m[4 * r + 2] * q[2] + m[4 * r + 3] * q[3];
            }
        }
    }
}

static void data_rows_transposed(void *context, size_t worker, size_t begin, size_t end)
{
    (void)worker;
    const operator_call *call = context;
    const global_system *g = call->g;
    const fit_problem *p = &g->problem;
    double gradient[4 * 64];
    for (size_t v = begin; v < end; ++v) {
        const size_t first = (size_t)p->offsets[v], n = influences_of(p, v);
        memset(gradient, 0, 4 * n * sizeof *gradient);
        for (size_t e = 0; e < p->example_count; ++e) {
            const double *y = call->in + 3 * (p->example_count * v + e);
            for (size_t s = 0; s < n; ++s) {
                const double *m = pose_of(p, e, first + s);
                for (int c = 0; c < 4; ++c)
                    gradient[4 * s + (size_t)c] += m[c] * y[0] + m[4 + c] * y[1] + m[8 + c] * y[2];
            }
        }
        double *x = call->out + g->column_start[v];
        memset(x, 0, unknowns_of(n) * sizeof *x);
        add_linear_part_transposed(x, gradient, n);
    }
}

/* The 4-vector of p's linear part of vertex v at `slot`, or NULL when v lacks that bone (a zero). */
static const double *full_at(const global_system *g, size_t vertex, int32_t slot)
{
    return slot < 0 ? NULL : g->full + 4 * ((size_t)g->problem.offsets[vertex] + (size_t)slot);
}

static void edge_rows_forward(global_system *g, double *y)
{
    const fit_problem *p = &g->problem;
    for (size_t v = 0; v < p->vertex_count; ++v)
        linear_part(g->full + 4 * (size_t)p->offsets[v], g->unknowns + g->column_start[v], influences_of(p, v));
    for (size_t k = 0; k < g->edge_count; ++k) {
        const size_t a = (size_t)g->edges[2 * k], b = (size_t)g->edges[2 * k + 1];
        for (int32_t q = g->pair_offsets[k]; q < g->pair_offsets[k + 1]; ++q) {
            const double *pa = full_at(g, a, g->pair_slots[2 * q]), *pb = full_at(g, b, g->pair_slots[2 * q + 1]);
            for (int c = 0; c < 4; ++c)
                y[4 * (size_t)q + (size_t)c] = g->edge_scale[k] * ((pa ? pa[c] : 0.0) - (pb ? pb[c] : 0.0));
        }
    }
}

static void edge_rows_transposed(global_system *g, const double *y, double *x)
{
    const fit_problem *p = &g->problem;
    memset(g->full, 0, 4 * p->influence_count * sizeof *g->full);
    for (size_t k = 0; k < g->edge_count; ++k) {
        const size_t a = (size_t)g->edges[2 * k], b = (size_t)g->edges[2 * k + 1];
        for (int32_t q = g->pair_offsets[k]; q < g->pair_offsets[k + 1]; ++q) {
            double *pa = (double *)full_at(g, a, g->pair_slots[2 * q]);
            double *pb = (double *)full_at(g, b, g->pair_slots[2 * q + 1]);
            for (int c = 0; c < 4; ++c) {
                const double value = g->edge_scale[k] * y[4 * (size_t)q + (size_t)c];
                if (pa)
                    pa[c] += value;
                if (pb)
                    pb[c] -= value;
            }
        }
    }
    for (size_t v = 0; v < p->vertex_count; ++v)
        add_linear_part_transposed(x + g->column_start[v], g->full + 4 * (size_t)p->offsets[v], influences_of(p, v));
}

/* The LSQR operator: A R^-1 (and its transpose), rows = data rows then edge rows. */
static void apply_system(void *user, int transpose, const double *in, double *out)
{
    global_system *g = user;
    const fit_problem *p = &g->problem;
    const size_t data_rows = 3 * p->example_count * p->vertex_count;
    if (!transpose) {
        memcpy(g->unknowns, in, g->columns * sizeof *in);
        for (size_t v = 0; v < p->vertex_count; ++v)
            precondition_vertex(g, g->unknowns + g->column_start[v], v, 0);
        operator_call call = {g, g->unknowns, out};
        sk_parallel_for(p->vertex_count, SK_SOLVE_ITEMS_PER_WORKER, g->thread_count, data_rows_forward, &call);
        edge_rows_forward(g, out + data_rows);
    } else {
        operator_call call = {g, in, out};
        sk_parallel_for(p->vertex_count, SK_SOLVE_ITEMS_PER_WORKER, g->thread_count, data_rows_transposed, &call);
        edge_rows_transposed(g, in + data_rows, out);
        for (size_t v = 0; v < p->vertex_count; ++v)
            precondition_vertex(g, out + g->column_start[v], v, 1);
    }
}

/* R_v with R_v^T R_v = D_v^T D_v + (sum of the vertex's edge weights) M_v^T M_v (the normal block).
 * block and rhs are scratch for the vertex's 3E x m data block. */
static void factor_vertex(global_system *g, size_t vertex, const double *edge_weight_sum, double *block,
                          double *rhs)
{
    const size_t m = g->column_start[vertex + 1] - g->column_start[vertex], n = (m + 1) / 4;
    const size_t data_rows = 3 * g->problem.example_count;
    double *r = g->factors + g->factor_start[vertex];
    data_block(block, m, rhs, &g->problem, vertex);
    for (size_t i = 0; i < m; ++i)
        for (size_t j = 0; j < m; ++j) {
            double sum = 0.0;
            for (size_t row = 0; row < data_rows; ++row)
                sum += block[row * m + i] * block[row * m + j];
            const int both_weights = i >= 3 * n && j >= 3 * n; /* M^T M: identity, plus 1 between weights */
            r[i * m + j] = sum + edge_weight_sum[vertex] * ((i == j ? 1.0 : 0.0) + (both_weights ? 1.0 : 0.0));
        }
    g->factored[vertex] = LAPACKE_dpotrf(LAPACK_ROW_MAJOR, 'U', (lapack_int)m, r, (lapack_int)m) == 0;
    for (size_t i = 0; i < m; ++i)
        for (size_t j = 0; j < i; ++j)
            r[i * m + j] = 0.0; /* dpotrf leaves the lower triangle as it was */
}

static void free_system(global_system *g)
{
    free(g->column_start), free(g->factors), free(g->factor_start);
    free(g->factored), free(g->edge_scale), free(g->pair_offsets), free(g->pair_slots), free(g->full);
    free(g->unknowns);
}

static sk_status build_preconditioner(global_system *g, const double *edge_weights, sk_error *error)
{
    const fit_problem *p = &g->problem;
    const size_t V = p->vertex_count, data_rows = 3 * p->example_count, m_max = unknowns_of(max_influences(p));
    g->factors = sk_allocate(g->factor_start[V], sizeof *g->factors);
    double *edge_weight_sum = sk_allocate_zeroed(V, sizeof *edge_weight_sum);
    double *block = sk_allocate(data_rows * m_max, sizeof *block), *rhs = sk_allocate(data_rows, sizeof *rhs);
    sk_status status = SK_OK;
    if (!g->factors || !edge_weight_sum || !block || !rhs) {
        status = sk_fail(error, SK_ERROR_MEMORY, "out of memory for the preconditioner");
    } else {
        for (size_t k = 0; k < g->edge_count; ++k) {
            edge_weight_sum[g->edges[2 * k]] += edge_weights[k];
            edge_weight_sum[g->edges[2 * k + 1]] += edge_weights[k];
        }
        for (size_t v = 0; v < V; ++v)
            factor_vertex(g, v, edge_weight_sum, block, rhs);
    }
    free(edge_weight_sum), free(block), free(rhs);
    return status;
}

static sk_status build_system(global_system *g, const double *edge_weights, sk_error *error)
{
    const fit_problem *p = &g->problem;
    const size_t V = p->vertex_count, data_rows = 3 * p->example_count;
    if (max_influences(p) > 64)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the global fit takes at most 64 influences per vertex, not %zu",
                       max_influences(p));
    g->column_start = sk_allocate(V + 1, sizeof *g->column_start);
    g->factor_start = sk_allocate(V + 1, sizeof *g->factor_start);
    g->factored = sk_allocate_zeroed(V, sizeof *g->factored);
    g->edge_scale = sk_allocate(g->edge_count + 1, sizeof *g->edge_scale);
    g->full = sk_allocate(4 * p->influence_count, sizeof *g->full);
    if (!g->column_start || !g->factor_start || !g->factored || !g->edge_scale || !g->full)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the global system");
    g->column_start[0] = g->factor_start[0] = 0;
    for (size_t v = 0; v < V; ++v) {
        const size_t m = unknowns_of(influences_of(p, v));
        g->column_start[v + 1] = g->column_start[v] + m;
        g->factor_start[v + 1] = g->factor_start[v] + m * m;
    }
    g->columns = g->column_start[V];
    g->unknowns = sk_allocate(g->columns, sizeof *g->unknowns);
    if (!g->unknowns)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu unknowns", g->columns);
    for (size_t k = 0; k < g->edge_count; ++k)
        g->edge_scale[k] = sqrt(edge_weights[k]);
    sk_status status = build_edge_pairs(g, error);
    if (status != SK_OK)
        return status;
    g->rows = data_rows * V + 4 * g->pair_count;
    return g->precondition ? build_preconditioner(g, edge_weights, error) : SK_OK;
}

/* b - A x0 for the starting coordinates (the constants c of p = M x + c included). */
static sk_status starting_residual(global_system *g, const double *coordinates, double *x0, double *residual,
                                   sk_error *error)
{
    const fit_problem *p = &g->problem;
    const size_t data_rows = 3 * p->example_count;
    size_t block_size;
    double *rhs = sk_allocate(data_rows, sizeof *rhs);
    double *block = sk_mul_size(data_rows, 4 * max_influences(p), &block_size) ? sk_allocate(block_size, sizeof *block)
                                                                               : NULL;
    if (!rhs || !block) {
        free(rhs), free(block);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory");
    }
    for (size_t v = 0; v < p->vertex_count; ++v) {
        const size_t n = influences_of(p, v), m = unknowns_of(n);
        double *x = x0 + g->column_start[v];
        compress(x, coordinates + 4 * (size_t)p->offsets[v], n);
        data_block(block, m, rhs, p, v);
        for (size_t r = 0; r < data_rows; ++r) {
            double sum = 0.0;
            for (size_t c = 0; c < m; ++c)
                sum += block[r * m + c] * x[c];
            residual[data_rows * v + r] = rhs[r] - sum;
        }
        expand(g->full + 4 * (size_t)p->offsets[v], x, n); /* full p, constants included */
    }
    free(rhs), free(block);
    double *edge_residual = residual + data_rows * p->vertex_count;
    for (size_t k = 0; k < g->edge_count; ++k) {
        const size_t a = (size_t)g->edges[2 * k], b = (size_t)g->edges[2 * k + 1];
        for (int32_t q = g->pair_offsets[k]; q < g->pair_offsets[k + 1]; ++q) {
            const double *pa = full_at(g, a, g->pair_slots[2 * q]), *pb = full_at(g, b, g->pair_slots[2 * q + 1]);
            for (int c = 0; c < 4; ++c)
                edge_residual[4 * (size_t)q + (size_t)c] = -g->edge_scale[k] * ((pa ? pa[c] : 0.0) - (pb ? pb[c] : 0.0));
        }
    }
    return SK_OK;
}

static sk_status check_edges(const int32_t *edges, const double *edge_weights, size_t edge_count, size_t vertex_count,
                             sk_error *error)
{
    if (edge_count > 0 && (!edges || !edge_weights))
        return sk_fail(error, SK_ERROR_ARGUMENT, "edges and edge weights must not be null");
    for (size_t k = 0; k < edge_count; ++k) {
        if (edges[2 * k] < 0 || (size_t)edges[2 * k] >= vertex_count || edges[2 * k + 1] < 0 ||
            (size_t)edges[2 * k + 1] >= vertex_count)
            return sk_fail(error, SK_ERROR_INDEX, "edge %zu: vertex (%d, %d) is outside [0, %zu)", k,
                           (int)edges[2 * k], (int)edges[2 * k + 1], vertex_count);
        if (!(edge_weights[k] >= 0.0) || !isfinite(edge_weights[k]))
            return sk_fail(error, SK_ERROR_ARGUMENT, "edge %zu: weight %g must be finite and >= 0", k, edge_weights[k]);
    }
    return SK_OK;
}

sk_status sk_fit_global(double *coordinates, sk_lsqr_report *report, const sk_influences *influences,
                        const sk_examples *examples, const int32_t *edges, const double *edge_weights,
                        size_t edge_count, const sk_lsqr_settings *settings, sk_progress_fn progress,
                        void *progress_user, sk_error *error)
{
    global_system g = {.edges = edges, .edge_count = edge_count};
    if (!coordinates || !settings || !report)
        return sk_fail(error, SK_ERROR_ARGUMENT, "coordinates, settings and report must not be null");
    g.precondition = settings->precondition;
    g.thread_count = settings->thread_count;
    sk_status status = make_problem(&g.problem, influences, examples, error);
    if (status == SK_OK)
        status = check_problem(&g.problem, error);
    const size_t vertex_count = g.problem.vertex_count, influence_count = g.problem.influence_count;
    const int32_t *offsets = g.problem.offsets;
    if (status == SK_OK)
        status = check_edges(edges, edge_weights, edge_count, vertex_count, error);
    if (status == SK_OK && !sk_all_finite(coordinates, 4 * influence_count))
        status = sk_fail(error, SK_ERROR_NOT_FINITE, "the starting coordinates have a NaN or infinity");
    if (status == SK_OK)
        status = build_system(&g, edge_weights, error);
    double *x0 = NULL, *b = NULL, *z = NULL;
    if (status == SK_OK) {
        x0 = sk_allocate(g.columns, sizeof *x0);
        b = sk_allocate(g.rows, sizeof *b);
        z = sk_allocate(g.columns, sizeof *z);
        if (!x0 || !b || !z)
            status = sk_fail(error, SK_ERROR_MEMORY, "out of memory for a %zu x %zu system", g.rows, g.columns);
    }
    if (status == SK_OK)
        status = starting_residual(&g, coordinates, x0, b, error);
    if (status == SK_OK)
        status = sk_lsqr(z, b, g.rows, g.columns, apply_system, &g, settings, report, progress, progress_user, error);
    if (status == SK_OK) {
        for (size_t v = 0; v < vertex_count; ++v) {
            double *dz = z + g.column_start[v];
            precondition_vertex(&g, dz, v, 0); /* dx = R^-1 dz */
            for (size_t c = 0; c < g.column_start[v + 1] - g.column_start[v]; ++c)
                x0[g.column_start[v] + c] += dz[c];
            expand(coordinates + 4 * (size_t)offsets[v], x0 + g.column_start[v], influences_of(&g.problem, v));
        }
    }
    free(x0), free(b), free(z);
    free_system(&g);
    return status == SK_OK ? sk_succeed(error) : status;
}

/* ---------------------------------------------------------------------------------------------
 * Linear-blend baseline: non-negative least squares per vertex (Lawson & Hanson 1974, chapter 23)
 * ------------------------------------------------------------------------------------------- */

typedef struct lbs_fit {
    fit_problem problem; /* poses hold the skinning matrices N_j^e */
    const double *rest_positions;
    double *weights;
    size_t max_influences;
} lbs_fit;

/*
 * min |a x - b| (rows x columns, row-major, rows >= columns; both overwritten) by Householder QR and back substitution.
 * Returns 0, leaving the caller to use dgelsd, when a is numerically rank-deficient (a diagonal entry of R at or
 * below SK_RANK_TOLERANCE of the largest): then the minimum-norm solution is wanted. The active-set solver's systems
 * have at most 65 rows after compress_rows, where dgelsd's SVD, workspace queries and row-major copies cost several
 * times this arithmetic (it was most of the linear-blend fit's time).
 */
static int householder_solve(double *x, double *a, double *b, size_t rows, size_t columns)
{
    double diagonal[64], largest = 0.0;
    for (size_t j = 0; j < columns; ++j) {
        double norm = 0.0;
        for (size_t i = j; i < rows; ++i)
            norm += a[i * columns + j] * a[i * columns + j];
        norm = sqrt(norm);
        const double alpha = a[j * columns + j] > 0.0 ? -norm : norm;
        diagonal[j] = alpha;
        largest = fabs(alpha) > largest ? fabs(alpha) : largest;
        a[j * columns + j] -= alpha; /* v = column - alpha e_j, stored in place */
        const double v_squared = 2.0 * norm * norm - 2.0 * alpha * (a[j * columns + j] + alpha);
        if (!(v_squared > 0.0))
            continue; /* a zero column: R_jj = 0, caught below */
        for (size_t c = j + 1; c <= columns; ++c) { /* c == columns: the right-hand side */
            double dot = 0.0;
            for (size_t i = j; i < rows; ++i)
                dot += a[i * columns + j] * (c < columns ? a[i * columns + c] : b[i]);
            const double factor = 2.0 * dot / v_squared;
            for (size_t i = j; i < rows; ++i) {
                if (c < columns)
                    a[i * columns + c] -= factor * a[i * columns + j];
                else
                    b[i] -= factor * a[i * columns + j];
            }
        }
    }
    for (size_t j = 0; j < columns; ++j)
        if (!(fabs(diagonal[j]) > SK_RANK_TOLERANCE * largest))
            return 0;
    for (size_t j = columns; j-- > 0;) {
        double sum = b[j];
        for (size_t c = j + 1; c < columns; ++c)
            sum -= a[j * columns + c] * x[c];
        x[j] = sum / diagonal[j];
    }
    return 1;
}

/* The passive columns of a (rows x n) into sub (rows x columns) and b into rhs. */
static void copy_passive(double *sub, double *rhs, const double *a, const double *b, size_t rows, size_t n,
                         const int *index, size_t columns)
{
    for (size_t r = 0; r < rows; ++r) {
        rhs[r] = b[r];
        for (size_t c = 0; c < columns; ++c)
            sub[r * columns + c] = a[r * n + (size_t)index[c]];
    }
}

/* Least squares on the passive columns only; returns 0 when LAPACK fails. */
static int passive_solve(double *solution, const double *a, const double *b, size_t rows, size_t n, const int *passive,
                         double *scratch)
{
    size_t columns = 0;
    int index[64];
    for (size_t j = 0; j < n; ++j)
        if (passive[j])
            index[columns++] = (int)j;
    double *sub = scratch, *rhs = scratch + rows * n, *singular = rhs + rows + n; /* dgelsd: max(rows, n) each */
    double x[64];
    copy_passive(sub, rhs, a, b, rows, n, index, columns);
    if (rows < columns || !householder_solve(x, sub, rhs, rows, columns)) {
        /* rank-deficient: dgelsd's minimum-norm solution, on fresh copies */
        copy_passive(sub, rhs, a, b, rows, n, index, columns);
        lapack_int rank;
        if (LAPACKE_dgelsd(LAPACK_ROW_MAJOR, (lapack_int)rows, (lapack_int)columns, 1, sub, (lapack_int)columns, rhs,
                           1, singular, SK_RANK_TOLERANCE, &rank) != 0)
            return 0;
        memcpy(x, rhs, columns * sizeof *x);
    }
    for (size_t j = 0; j < n; ++j)
        solution[j] = 0.0;
    for (size_t c = 0; c < columns; ++c)
        solution[index[c]] = x[c];
    return 1;
}

/* Lawson-Hanson active set: min |A w - b| subject to w >= 0. A is rows x n (n <= 64). */
static int non_negative_least_squares(double *w, const double *a, const double *b, size_t rows, size_t n,
                                      double *scratch)
{
    int passive[64] = {0};
    double z[64], gradient[64], tolerance = 0.0;
    double *residual = scratch;
    scratch += rows;
    for (size_t j = 0; j < n; ++j)
        w[j] = 0.0;
    for (size_t outer = 0; outer < 3 * n + 10; ++outer) {
        for (size_t r = 0; r < rows; ++r) {
            double sum = b[r];
            for (size_t j = 0; j < n; ++j)
                sum -= a[r * n + j] * w[j];
            residual[r] = sum;
        }
        for (size_t j = 0; j < n; ++j) {
            gradient[j] = 0.0;
            for (size_t r = 0; r < rows; ++r)
                gradient[j] += a[r * n + j] * residual[r];
            if (outer == 0 && fabs(gradient[j]) * 1e-12 > tolerance)
                tolerance = fabs(gradient[j]) * 1e-12; /* "zero" relative to the starting gradient */
        }
        size_t best = n;
        for (size_t j = 0; j < n; ++j)
            if (!passive[j] && gradient[j] > tolerance && (best == n || gradient[j] > gradient[best]))
                best = j;
        if (best == n)
            return 1;
        passive[best] = 1;
        for (size_t inner = 0; inner < 3 * n + 10; ++inner) {
            if (!passive_solve(z, a, b, rows, n, passive, scratch))
                return 0;
            double step = 1.0;
            int feasible = 1;
            for (size_t j = 0; j < n; ++j)
                if (passive[j] && z[j] <= 0.0) {
                    feasible = 0;
                    const double t = w[j] / (w[j] - z[j]);
                    if (t < step)
                        step = t;
                }
            if (feasible)
                break;
            for (size_t j = 0; j < n; ++j) {
                w[j] += step * (z[j] - w[j]);
                if (passive[j] && w[j] <= 1e-15) {
                    passive[j] = 0;
                    w[j] = 0.0;
                }
            }
        }
        for (size_t j = 0; j < n; ++j)
            w[j] = passive[j] && z[j] > 0.0 ? z[j] : 0.0;
    }
    return 1;
}

static sk_status fit_lbs_vertex(const void *context, size_t vertex, double *scratch, sk_error *error)
{
    const lbs_fit *fit = context;
    const fit_problem *p = &fit->problem;
    const size_t begin = (size_t)p->offsets[vertex], n = influences_of(p, vertex);
    const size_t rows = 3 * p->example_count + 1;
    double *a = scratch, *b = a + rows * n, *w = b + rows, *work = w + n;
    const double *v = fit->rest_positions + 3 * vertex;
    double scale = 0.0;
    for (size_t e = 0; e < p->example_count; ++e)
        for (int r = 0; r < 3; ++r) {
            const size_t row = 3 * e + (size_t)r;
            b[row] = p->examples[3 * (e * p->vertex_count + vertex) + (size_t)r];
            for (size_t s = 0; s < n; ++s) {
                const double *m = pose_of(p, e, begin + s);
                a[row * n + s] = m[4 * r] * v[0] + m[4 * r + 1] * v[1] + m[4 * r + 2] * v[2] + m[4 * r + 3];
                scale += a[row * n + s] * a[row * n + s];
            }
        }
    /* The sum-to-one row, weighted far above the data so it holds to rounding (normalised below). */
    const double sum_weight = 1e3 * sqrt(scale / (double)(rows - 1) + 1.0);
    const sk_status status = check_system_finite(a, b, rows - 1, n, vertex, error);
    if (status != SK_OK)
        return status;
    if (!isfinite(sum_weight))
        return overflowed(vertex, error);
    double tau[64];
    const size_t used = compress_rows(a, b, rows - 1, n, tau);
    if (used == 0)
        return sk_fail(error, SK_ERROR_LAPACK, "vertex %zu: the QR factorisation of its examples failed", vertex);
    for (size_t s = 0; s < n; ++s)
        a[used * n + s] = sum_weight;
    b[used] = sum_weight;
    if (!non_negative_least_squares(w, a, b, used + 1, n, work))
        return sk_fail(error, SK_ERROR_LAPACK, "vertex %zu: the non-negative least-squares solve failed", vertex);
    double total = 0.0;
    for (size_t s = 0; s < n; ++s)
        total += w[s];
    if (!(total > 0.0))
        return sk_fail(error, SK_ERROR_RANK, "vertex %zu: no non-negative weights reproduce its examples", vertex);
    for (size_t s = 0; s < n; ++s)
        fit->weights[begin + s] = w[s] / total;
    return SK_OK;
}

sk_status sk_fit_lbs_weights(double *weights, const sk_influences *influences, const sk_examples *examples,
                             const double *rest_positions, int thread_count, sk_error *error)
{
    lbs_fit fit = {.rest_positions = rest_positions, .weights = weights};
    if (!weights || !rest_positions)
        return sk_fail(error, SK_ERROR_ARGUMENT, "weights and rest positions must not be null");
    sk_status status = make_problem(&fit.problem, influences, examples, error);
    if (status == SK_OK)
        status = check_problem(&fit.problem, error);
    const size_t vertex_count = fit.problem.vertex_count, example_count = fit.problem.example_count;
    if (status != SK_OK)
        return status;
    if (!sk_all_finite(rest_positions, 3 * vertex_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "a rest position has a NaN or infinity");
    fit.max_influences = max_influences(&fit.problem);
    if (fit.max_influences > 64)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the linear-blend fit takes at most 64 influences per vertex, not %zu",
                       fit.max_influences);
    const size_t rows = 3 * example_count + 1, n = fit.max_influences;
    /* a, b, w; then the solver's residual, sub-matrix, right-hand side and singular values */
    const size_t scratch = rows * n + rows + n + rows + rows * n + 2 * (rows + n);
    return for_each_vertex(vertex_count, thread_count, scratch, fit_lbs_vertex, &fit, error);
}
