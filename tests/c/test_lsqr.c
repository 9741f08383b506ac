/*
 * Standalone tests of LSQR (csrc/skinkit.h, sk_lsqr) with a dense operator: the solution, the report's norm
 * estimates recomputed from x, rank deficiency, progress and cancellation, and the refusals, under the
 * sanitizers.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "skinkit.h"
#include "test_support.h"

/* ---------------------------------------------------------------------------------------------
 * Least-squares references, independent of the core
 * ------------------------------------------------------------------------------------------- */

/* Solves s x = b in place for a symmetric positive definite s (n x n, destroyed: its lower triangle
 * becomes the Cholesky factor L, s = L L^T). Returns 0 when s is not numerically positive definite. */
static int solve_cholesky(double *s, double *b, size_t n)
{
    for (size_t j = 0; j < n; ++j) {
        double diagonal = s[j * n + j];
        for (size_t k = 0; k < j; ++k)
            diagonal -= s[j * n + k] * s[j * n + k];
        if (!(diagonal > 0.0))
            return 0;
        s[j * n + j] = sqrt(diagonal);
        for (size_t i = j + 1; i < n; ++i) {
            double sum = s[i * n + j];
            for (size_t k = 0; k < j; ++k)
                sum -= s[i * n + k] * s[j * n + k];
            s[i * n + j] = sum / s[j * n + j];
        }
    }
    for (size_t i = 0; i < n; ++i) { /* L y = b */
        double sum = b[i];
        for (size_t k = 0; k < i; ++k)
            sum -= s[i * n + k] * b[k];
        b[i] = sum / s[i * n + i];
    }
    for (size_t i = n; i-- > 0;) { /* L^T x = y */
        double sum = b[i];
        for (size_t k = i + 1; k < n; ++k)
            sum -= s[k * n + i] * b[k];
        b[i] = sum / s[i * n + i];
    }
    return 1;
}

/* The least-squares solution of A x = b by the normal equations (A^T A) x = A^T b; 0 if rank-deficient. */
static int normal_equations_solution(double *x, const double *a, const double *b, size_t rows, size_t cols)
{
    double *normal = allocate(cols * cols, sizeof *normal);
    for (size_t i = 0; i < cols; ++i)
        for (size_t j = 0; j < cols; ++j)
            for (size_t r = 0; r < rows; ++r)
                normal[i * cols + j] += a[r * cols + i] * a[r * cols + j];
    dense_apply(a, rows, cols, 1, b, x);
    const int ok = solve_cholesky(normal, x, cols);
    free(normal);
    return ok;
}

/* ---------------------------------------------------------------------------------------------
 * LSQR with a dense operator
 * ------------------------------------------------------------------------------------------- */

typedef struct dense_operator {
    const double *a;
    size_t rows, cols;
    int forward_calls, transpose_calls;
} dense_operator;

static void apply_dense(void *user, int transpose, const double *in, double *out)
{
    dense_operator *op = user;
    dense_apply(op->a, op->rows, op->cols, transpose, in, out);
    if (transpose)
        ++op->transpose_calls;
    else
        ++op->forward_calls;
}

static sk_lsqr_settings tight_settings(int iteration_limit)
{
    sk_lsqr_settings settings = {.atol = 1e-14, .btol = 1e-14, .conlim = 0.0, .iteration_limit = iteration_limit};
    return settings;
}

static double *random_matrix(size_t rows, size_t cols)
{
    double *a = allocate(rows * cols, sizeof *a);
    for (size_t i = 0; i < rows * cols; ++i)
        a[i] = random_uniform(-1.0, 1.0);
    return a;
}

static double frobenius_norm(const double *a, size_t count)
{
    return euclidean_norm(a, count);
}

/* Solves with sk_lsqr and checks the report against quantities recomputed from x; rank is A's rank. */
static void lsqr_and_check_report(double *x, const double *a, const double *b, size_t rows, size_t cols, int rank,
                                  sk_lsqr_report *report, const char *what)
{
    dense_operator op = {a, rows, cols, 0, 0};
    const sk_lsqr_settings settings = tight_settings((int)(20 * cols));
    EXPECT_SUCCESS(what, sk_lsqr(x, b, rows, cols, apply_dense, &op, &settings, report, NULL, NULL, error));
    double *residual = allocate(rows, sizeof *residual), *normal = allocate(cols, sizeof *normal);
    dense_apply(a, rows, cols, 0, x, residual);
    for (size_t r = 0; r < rows; ++r)
        residual[r] = b[r] - residual[r];
    dense_apply(a, rows, cols, 1, residual, normal);
    const double b_norm = euclidean_norm(b, rows), a_norm = frobenius_norm(a, rows * cols);
    char context[240];
    snprintf(context, sizeof context,
             "%s: stop %d after %d iterations; |r| %.6g (report %.6g), |A^T r| %.3g (report %.3g), |x| %.6g "
             "(report %.6g), |A|_F %.6g (report %.6g), condition %.3g",
             what, report->stop_reason, report->iterations, euclidean_norm(residual, rows), report->residual_norm,
             euclidean_norm(normal, cols), report->normal_residual, euclidean_norm(x, cols), report->solution_norm, a_norm,
             report->matrix_norm, report->condition);
    CHECK_IN(context, report->stop_reason >= 1 && report->stop_reason <= 6);
    CHECK_IN(context, report->iterations >= 1 && report->iterations <= settings.iteration_limit);
    CHECK_IN(context, op.forward_calls >= report->iterations && op.transpose_calls >= report->iterations);
    CHECK_IN(context, fabs(report->residual_norm - euclidean_norm(residual, rows)) <= 1e-9 * b_norm);
    CHECK_IN(context, fabs(report->normal_residual - euclidean_norm(normal, cols)) <= 1e-9 * a_norm * b_norm);
    CHECK_IN(context, fabs(report->solution_norm - euclidean_norm(x, cols)) <= 1e-9 * euclidean_norm(x, cols));
    CHECK_IN(context, fabs(report->initial_residual_norm - b_norm) <= 1e-15 * b_norm);
    /* An estimate of |B_k|_F: at least alpha_1 = |A^T b| / |b| (the first step), and of the order of |A|_F
     * (it can pass |A|_F when rounding makes LSQR take more iterations than A has columns). */
    double *atb = allocate(cols, sizeof *atb);
    dense_apply(a, rows, cols, 1, b, atb);
    CHECK_IN(context, report->matrix_norm >= euclidean_norm(atb, cols) / b_norm * (1.0 - 1e-12) &&
                          report->matrix_norm <= 2.0 * a_norm);
    free(atb);
    /* After exactly rank(A) steps the bidiagonalisation is complete: |B_k|_F = |A|_F. */
    if (report->iterations == rank)
        CHECK_IN(context, fabs(report->matrix_norm - a_norm) <= 1e-10 * a_norm);
    CHECK_IN(context, report->condition >= 1.0);
    /* The answer is a least-squares solution: the normal residual vanishes. */
    CHECK_IN(context, euclidean_norm(normal, cols) <= 1e-10 * a_norm * fmax(euclidean_norm(residual, rows), 1e-300) + 1e-12 * a_norm * b_norm);
    free(residual), free(normal);
}

static void test_lsqr_full_rank(size_t rows, size_t cols, const char *what)
{
    double *a = random_matrix(rows, cols), *b = allocate(rows, sizeof *b);
    for (size_t r = 0; r < rows; ++r)
        b[r] = random_uniform(-1.0, 1.0);
    double *x = allocate(cols, sizeof *x), *expected = allocate(cols, sizeof *expected);
    sk_lsqr_report report;
    lsqr_and_check_report(x, a, b, rows, cols, (int)cols, &report, what);
    CHECK_IN(what, normal_equations_solution(expected, a, b, rows, cols));
    char context[160];
    snprintf(context, sizeof context, "%s: max |x - normal-equations x| = %.3g", what,
             max_abs_difference(x, expected, cols));
    CHECK_IN(context, close_to(x, expected, cols, 1e-9));
    if (rows == cols) { /* a consistent system: the residual vanishes */
        CHECK_IN(what, report.residual_norm <= 1e-10 * euclidean_norm(b, rows));
        CHECK_IN(what, report.stop_reason == 1 || report.stop_reason == 4);
    }
    free(a), free(b), free(x), free(expected);
}

/* A = U W with U (rows x rank) and W (rank x cols): LSQR from x = 0 gives the minimum-norm solution
 * A^+ b = W^T (W W^T)^-1 (U^T U)^-1 U^T b. */
static void test_lsqr_rank_deficient(void)
{
    const size_t rows = 20, cols = 8, rank = 5;
    double *u = random_matrix(rows, rank), *w = random_matrix(rank, cols), *a = allocate(rows * cols, sizeof *a);
    for (size_t r = 0; r < rows; ++r)
        for (size_t c = 0; c < cols; ++c)
            for (size_t k = 0; k < rank; ++k)
                a[r * cols + c] += u[r * rank + k] * w[k * cols + c];
    double *b = allocate(rows, sizeof *b), *x = allocate(cols, sizeof *x);
    for (size_t r = 0; r < rows; ++r)
        b[r] = random_uniform(-1.0, 1.0);
    sk_lsqr_report report;
    lsqr_and_check_report(x, a, b, rows, cols, (int)rank, &report, "rank-deficient 20 x 8 (rank 5)");
    /* In exact arithmetic LSQR stops after rank(A) steps; rounding may cost one more. */
    CHECK_IN("the rank-deficient case stops after about rank(A) steps (checks the matrix-norm estimate)",
             report.iterations >= (int)rank && report.iterations <= (int)rank + 1);

    double y[5], wwt[25] = {0}, expected[8];
    CHECK(normal_equations_solution(y, u, b, rows, rank)); /* (U^T U)^-1 U^T b */
    for (size_t i = 0; i < rank; ++i)
        for (size_t j = 0; j < rank; ++j)
            wwt[i * rank + j] = dot_product(w + i * cols, w + j * cols, cols);
    CHECK(solve_cholesky(wwt, y, rank));
    dense_apply(w, rank, cols, 1, y, expected);
    char context[120];
    snprintf(context, sizeof context, "max |x - minimum-norm x| = %.3g", max_abs_difference(x, expected, cols));
    CHECK_IN(context, close_to(x, expected, cols, 1e-9));
    free(u), free(w), free(a), free(b), free(x);
}

static void test_lsqr_progress_and_cancel(void)
{
    const size_t rows = 80, cols = 60;
    double *a = random_matrix(rows, cols), *b = allocate(rows, sizeof *b);
    double *x = allocate(cols, sizeof *x), *x_quiet = allocate(cols, sizeof *x_quiet);
    for (size_t r = 0; r < rows; ++r)
        b[r] = random_uniform(-1.0, 1.0);
    dense_operator op = {a, rows, cols, 0, 0};
    const sk_lsqr_settings settings = tight_settings(1000);
    sk_lsqr_report report, quiet_report;

    progress_log log = {0};
    EXPECT_SUCCESS("lsqr with progress", sk_lsqr(x, b, rows, cols, apply_dense, &op, &settings, &report,
                                                 record_progress, &log, error));
    EXPECT_SUCCESS("lsqr without progress", sk_lsqr(x_quiet, b, rows, cols, apply_dense, &op, &settings,
                                                    &quiet_report, NULL, NULL, error));
    CHECK_IN("a problem long enough to report progress", report.iterations > 20);
    CHECK(log.calls == report.iterations / 10 || log.calls == (report.iterations - 1) / 10);
    int fractions_ok = 1;
    for (int i = 0; i < log.calls && i < 64; ++i)
        fractions_ok = fractions_ok && log.fractions[i] == (double)(10 * (i + 1)) / settings.iteration_limit &&
                       log.fractions[i] >= 0.0 && log.fractions[i] <= 1.0;
    CHECK_IN("progress fractions are iterations / iteration_limit, in [0, 1]", fractions_ok);
    CHECK_IN("a progress callback does not change the answer", memcmp(x, x_quiet, cols * sizeof *x) == 0);
    CHECK(report.iterations == quiet_report.iterations);

    progress_log cancel = {.cancel_at = 1};
    EXPECT_FAILURE("lsqr cancelled", SK_ERROR_CANCELLED, sk_lsqr(x, b, rows, cols, apply_dense, &op, &settings, &report,
                                                                 record_progress, &cancel, error));
    CHECK_IN("cancelled at the first report, by each of the two calls", cancel.calls == 2);
    /* The iteration limit stops it (reason 7) after exactly that many iterations. */
    sk_lsqr_settings short_settings = settings;
    short_settings.iteration_limit = 3;
    EXPECT_SUCCESS("lsqr at its iteration limit", sk_lsqr(x, b, rows, cols, apply_dense, &op, &short_settings, &report,
                                                          NULL, NULL, error));
    CHECK(report.stop_reason == 7 && report.iterations == 3 && all_finite(x, cols));

    progress_log later = {.cancel_at = 2};
    sk_error record = empty_error();
    CHECK(sk_lsqr(x, b, rows, cols, apply_dense, &op, &settings, &report, record_progress, &later, &record) ==
          SK_ERROR_CANCELLED);
    CHECK(later.calls == 2 && report.iterations == 20 && strstr(record.message, "20") != NULL);
    free(a), free(b), free(x), free(x_quiet);
}

static void test_lsqr_zero_solution(void)
{
    const size_t rows = 6, cols = 3;
    /* A = [I; 0] */
    double *a = allocate(rows * cols, sizeof *a), *b = allocate(rows, sizeof *b), *x = allocate(cols, sizeof *x);
    for (size_t i = 0; i < cols; ++i)
        a[i * cols + i] = 1.0;
    dense_operator op = {a, rows, cols, 0, 0};
    const sk_lsqr_settings settings = tight_settings(100);
    sk_lsqr_report report;
    for (size_t i = 0; i < cols; ++i)
        x[i] = 7.0;
    EXPECT_SUCCESS("b = 0", sk_lsqr(x, b, rows, cols, apply_dense, &op, &settings, &report, NULL, NULL, error));
    CHECK(x[0] == 0.0 && x[1] == 0.0 && x[2] == 0.0);
    CHECK(report.stop_reason == 0 && report.iterations == 0 && report.residual_norm == 0.0);

    /* b orthogonal to the range of A: A^T b = 0, so x = 0 again and the residual is |b|. */
    b[3] = 1.0, b[4] = 2.0, b[5] = 2.0;
    for (size_t i = 0; i < cols; ++i)
        x[i] = 7.0;
    EXPECT_SUCCESS("A^T b = 0", sk_lsqr(x, b, rows, cols, apply_dense, &op, &settings, &report, NULL, NULL, error));
    CHECK(x[0] == 0.0 && x[1] == 0.0 && x[2] == 0.0);
    CHECK(report.stop_reason == 0 && report.residual_norm == 3.0 && report.initial_residual_norm == 3.0);
    free(a), free(b), free(x);
}

static void test_lsqr_rejects_bad_arguments(void)
{
    const size_t rows = 4, cols = 3;
    double *a = random_matrix(rows, cols), *b = allocate(rows, sizeof *b), *x = allocate(cols, sizeof *x);
    for (size_t r = 0; r < rows; ++r)
        b[r] = (double)r + 1.0;
    dense_operator op = {a, rows, cols, 0, 0};
    const sk_lsqr_settings good = tight_settings(50);
    sk_lsqr_report report;
    EXPECT_SUCCESS("valid lsqr", sk_lsqr(x, b, rows, cols, apply_dense, &op, &good, &report, NULL, NULL, error));
    CHECK(sk_lsqr(x, b, rows, cols, apply_dense, &op, &good, &report, NULL, NULL, NULL) == SK_OK);

#define LSQR(x_, b_, r_, c_, apply_, settings_, report_) \
    sk_lsqr(x_, b_, r_, c_, apply_, &op, settings_, report_, NULL, NULL, error)
    EXPECT_FAILURE("null x", SK_ERROR_ARGUMENT, LSQR(NULL, b, rows, cols, apply_dense, &good, &report));
    EXPECT_FAILURE("null b", SK_ERROR_ARGUMENT, LSQR(x, NULL, rows, cols, apply_dense, &good, &report));
    EXPECT_FAILURE("null operator", SK_ERROR_ARGUMENT, LSQR(x, b, rows, cols, NULL, &good, &report));
    EXPECT_FAILURE("null settings", SK_ERROR_ARGUMENT, LSQR(x, b, rows, cols, apply_dense, NULL, &report));
    EXPECT_FAILURE("null report", SK_ERROR_ARGUMENT, LSQR(x, b, rows, cols, apply_dense, &good, NULL));
    EXPECT_FAILURE("zero rows", SK_ERROR_ARGUMENT, LSQR(x, b, 0, cols, apply_dense, &good, &report));
    EXPECT_FAILURE("zero columns", SK_ERROR_ARGUMENT, LSQR(x, b, rows, 0, apply_dense, &good, &report));

    struct {
        const char *name;
        sk_lsqr_settings settings;
    } bad[] = {
        {"iteration_limit 0", {1e-8, 1e-8, 0.0, 0, 0, 0}},
        {"iteration_limit -1", {1e-8, 1e-8, 0.0, -1, 0, 0}},
        {"negative atol", {-1e-8, 1e-8, 0.0, 50, 0, 0}},
        {"negative btol", {1e-8, -1e-8, 0.0, 50, 0, 0}},
        {"negative conlim", {1e-8, 1e-8, -1.0, 50, 0, 0}},
        {"NaN atol", {NAN, 1e-8, 0.0, 50, 0, 0}},
        {"NaN btol", {1e-8, NAN, 0.0, 50, 0, 0}},
        {"NaN conlim", {1e-8, 1e-8, NAN, 50, 0, 0}},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; ++i)
        EXPECT_FAILURE(bad[i].name, SK_ERROR_ARGUMENT, LSQR(x, b, rows, cols, apply_dense, &bad[i].settings, &report));
    b[rows - 1] = NAN;
    EXPECT_FAILURE("NaN in b", SK_ERROR_NOT_FINITE, LSQR(x, b, rows, cols, apply_dense, &good, &report));
    b[rows - 1] = INFINITY;
    EXPECT_FAILURE("infinity in b", SK_ERROR_NOT_FINITE, LSQR(x, b, rows, cols, apply_dense, &good, &report));
#undef LSQR
    free(a), free(b), free(x);
}

int main(void)
{
    test_program_name = "test_lsqr";
    test_lsqr_full_rank(30, 8, "overdetermined 30 x 8");
    test_lsqr_full_rank(12, 12, "square 12 x 12");
    test_lsqr_rank_deficient();
    test_lsqr_progress_and_cancel();
    test_lsqr_zero_solution();
    test_lsqr_rejects_bad_arguments();
    return finish_tests();
}
