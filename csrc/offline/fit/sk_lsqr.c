/*
 * LSQR (Paige & Saunders 1982, "LSQR: An algorithm for sparse linear equations and sparse least
 * squares", ACM TOMS 8(1)): Golub-Kahan bidiagonalisation with the QR update of the bidiagonal,
 * matrix-free through a callback, with the paper's stopping rules and norm estimates (no damping).
 */
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_internal.h"

static double norm2(const double *v, size_t n)
{
    double sum = 0.0;
    for (size_t i = 0; i < n; ++i)
        sum += v[i] * v[i];
    return sqrt(sum);
}

static void scale(double *v, size_t n, double factor)
{
    for (size_t i = 0; i < n; ++i)
        v[i] *= factor;
}

/* The scalar state of the bidiagonalisation and of the norm estimates, between iterations. */
typedef struct lsqr_state {
    double alpha, beta, rhobar, phibar, bnorm, anorm, ddnorm, xxnorm, z, cs2, sn2;
} lsqr_state;

/* One stopping test per the paper; returns the stop reason or 0 to continue. */
static int stop_reason(const sk_lsqr_settings *settings, const lsqr_state *s, double rnorm, double arnorm,
                       double acond, double xnorm, int iteration)
{
    const double test1 = rnorm / s->bnorm;
    const double test2 = arnorm / (s->anorm * rnorm + DBL_MIN);
    const double test3 = 1.0 / (acond + DBL_MIN);
    const double scaled = test1 / (1.0 + s->anorm * xnorm / s->bnorm);
    const double rtol = settings->btol + settings->atol * s->anorm * xnorm / s->bnorm;
    const double ctol = settings->conlim > 0.0 ? 1.0 / settings->conlim : 0.0;
    if (test1 <= rtol)
        return 1;
    if (test2 <= settings->atol)
        return 2;
    if (test3 <= ctol)
        return 3;
    if (1.0 + scaled <= 1.0)
        return 4;
    if (1.0 + test2 <= 1.0)
        return 5;
    if (1.0 + test3 <= 1.0)
        return 6;
    return iteration >= settings->iteration_limit ? 7 : 0;
}

sk_status sk_lsqr(double *x, const double *b, size_t rows, size_t cols, sk_linear_operator apply, void *user,
                  const sk_lsqr_settings *settings, sk_lsqr_report *report, sk_progress_fn progress,
                  void *progress_user, sk_error *error)
{
    if (!x || !b || !apply || !settings || !report || rows == 0 || cols == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "lsqr needs x, b, an operator, settings and a report");
    if (settings->iteration_limit < 1 || !(settings->atol >= 0.0) || !(settings->btol >= 0.0) ||
        !(settings->conlim >= 0.0))
        return sk_fail(error, SK_ERROR_ARGUMENT, "lsqr settings: tolerances must be >= 0, the iteration limit >= 1");
    if (!sk_all_finite(b, rows))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "lsqr: the right-hand side has a NaN or infinity");
    double *u = sk_allocate(rows, sizeof *u), *v = sk_allocate(cols, sizeof *v), *w = sk_allocate(cols, sizeof *w);
    double *product_rows = sk_allocate(rows, sizeof *product_rows);
    double *product_cols = sk_allocate(cols, sizeof *product_cols);
    if (!u || !v || !w || !product_rows || !product_cols) {
        free(u), free(v), free(w), free(product_rows), free(product_cols);
        return sk_fail(error, SK_ERROR_MEMORY, "lsqr: out of memory for %zu x %zu", rows, cols);
    }
    memset(x, 0, cols * sizeof *x);
    memset(report, 0, sizeof *report);
    lsqr_state s = {0};
    memcpy(u, b, rows * sizeof *u);
    s.beta = norm2(u, rows);
    s.bnorm = s.beta;
    report->initial_residual_norm = s.beta;
    report->residual_norm = s.beta;
    if (s.beta > 0.0) {
        scale(u, rows, 1.0 / s.beta);
        apply(user, 1, u, v);
        s.alpha = norm2(v, cols);
    }
    if (s.alpha > 0.0)
        scale(v, cols, 1.0 / s.alpha);
    memcpy(w, v, cols * sizeof *w);
    s.rhobar = s.alpha;
    s.phibar = s.beta;
    s.cs2 = -1.0;
    sk_status status = SK_OK;
    if (s.alpha * s.beta == 0.0) /* b = 0 or A^T b = 0: x = 0 is the least-squares solution */
        goto done;
    for (int iteration = 1;; ++iteration) {
        /* Bidiagonalisation: beta u = A v - alpha u, alpha v = A^T u - beta v. */
        apply(user, 0, v, product_rows);
        for (size_t i = 0; i < rows; ++i)
            u[i] = product_rows[i] - s.alpha * u[i];
        s.beta = norm2(u, rows);
        if (s.beta > 0.0) {
            scale(u, rows, 1.0 / s.beta);
            s.anorm = sqrt(s.anorm * s.anorm + s.alpha * s.alpha + s.beta * s.beta);
            apply(user, 1, u, product_cols);
            for (size_t i = 0; i < cols; ++i)
                v[i] = product_cols[i] - s.beta * v[i];
            s.alpha = norm2(v, cols);
            if (s.alpha > 0.0)
                scale(v, cols, 1.0 / s.alpha);
        }
        /* Plane rotation eliminating beta; update x and the search direction w. */
        const double rho = sqrt(s.rhobar * s.rhobar + s.beta * s.beta);
        const double cs = s.rhobar / rho, sn = s.beta / rho;
        const double theta = sn * s.alpha, phi = cs * s.phibar;
        s.rhobar = -cs * s.alpha;
        s.phibar = sn * s.phibar;
        const double tau = sn * phi;
        double direction_norm2 = 0.0;
        for (size_t i = 0; i < cols; ++i) {
            const double d = w[i] / rho;
            direction_norm2 += d * d;
            x[i] += phi * d;
            w[i] = v[i] - (theta / rho) * w[i];
        }
        s.ddnorm += direction_norm2;
        /* Estimate |x| by a second rotation (the paper's section 5.2). */
        const double delta = s.sn2 * rho, gambar = -s.cs2 * rho;
        const double rhs = phi - delta * s.z, zbar = rhs / gambar;
        const double xnorm = sqrt(s.xxnorm + zbar * zbar);
        const double gamma = sqrt(gambar * gambar + theta * theta);
        s.cs2 = gambar / gamma;
        s.sn2 = theta / gamma;
        s.z = rhs / gamma;
        s.xxnorm += s.z * s.z;
        const double acond = s.anorm * sqrt(s.ddnorm);
        const double rnorm = fabs(s.phibar), arnorm = s.alpha * fabs(tau);
        *report = (sk_lsqr_report){.iterations = iteration, .residual_norm = rnorm, .normal_residual = arnorm,
                                   .matrix_norm = s.anorm, .condition = acond, .solution_norm = xnorm,
                                   .initial_residual_norm = s.bnorm};
        report->stop_reason = stop_reason(settings, &s, rnorm, arnorm, acond, xnorm, iteration);
        if (report->stop_reason)
            break;
        if (progress && iteration % 10 == 0 && progress(progress_user, (double)iteration / settings->iteration_limit)) {
            status = sk_fail(error, SK_ERROR_CANCELLED, "lsqr cancelled after %d iterations", iteration);
            break;
        }
    }
done:
    free(u), free(v), free(w), free(product_rows), free(product_cols);
    if (status == SK_OK && !sk_all_finite(x, cols))
        status = sk_fail(error, SK_ERROR_NOT_FINITE, "lsqr diverged (NaN in the solution)");
    return status == SK_OK ? sk_succeed(error) : status;
}
