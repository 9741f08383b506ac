/*
 * LSCM (Levy et al. 2002) and Tutte's embedding over a chart: block-CSR assembly (one 2x2 block per pair of
 * neighbouring vertices) and preconditioned conjugate gradients. Once two or more vertices are pinned, LSCM's
 * normal equations are symmetric positive definite, which is what CG needs; no sparse Cholesky library is among
 * the project's dependencies (LAPACK is dense only and a dense factorisation of a 17k-triangle chart would take
 * gigabytes), while CG needs O(nnz) memory and only matrix-vector products. The preconditioner is a symmetric
 * block SSOR sweep on small charts and a smoothed-aggregation multigrid V-cycle (sk_amg.c) on charts of
 * AMG_MIN_FREE_VERTICES free vertices or more, whose steps SSOR's would grow as vertices^0.66.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_flatten.h"

/* ---------------------------------------------------------------------------------------------
 * LSCM: assembly and preconditioned conjugate gradients
 * ------------------------------------------------------------------------------------------- */

/* The triangle's isometric local frame (digest 3.2): x1 = 0, x2 = (sqrt g11, 0), x3 above the x axis. */
static void local_frame(double x[3][2], const double gram[3])
{
    const double first = sqrt(gram[0]);
    x[0][0] = x[0][1] = 0.0;
    x[1][0] = first;
    x[1][1] = 0.0;
    x[2][0] = gram[1] / first;
    x[2][1] = sqrt(fmax(gram[2] - gram[1] * gram[1] / gram[0], 0.0));
}

/*
 * Adds each triangle's LSCM term |sum_k W_k U_k|^2 / (2 area) (W_k = z_{k+2} - z_{k+1} in the local frame,
 * U_k = u_k + i v_k) to the normal matrix, stored as one 2x2 block (u, v rows and columns) per ring entry. The term
 * is the Dirichlet energy of u and v (the blocks' diagonals: the cotangent Laplacian) minus the signed uv area (the
 * u-v coupling, left out without with_area).
 */
static void assemble_conformal(double *blocks, const chart_mesh *m, int with_area)
{
    memset(blocks, 0, 4 * (size_t)m->ring_offsets[m->vertex_count] * sizeof *blocks);
    for (size_t t = 0; t < m->triangle_count; ++t) {
        double x[3][2];
        local_frame(x, m->gram + 3 * t);
        double w_re[3], w_im[3];
        for (int k = 0; k < 3; ++k) {
            w_re[k] = x[(k + 2) % 3][0] - x[(k + 1) % 3][0];
            w_im[k] = x[(k + 2) % 3][1] - x[(k + 1) % 3][1];
        }
        const double weight = 1.0 / (4.0 * m->area[t]); /* 1 / (2 * twice the area) */
        for (int k = 0; k < 3; ++k) {
            const int32_t row = m->corner[3 * t + (size_t)k];
            for (int l = 0; l < 3; ++l) {
                double *block = blocks + 4 * (size_t)ring_slot(m, row, m->corner[3 * t + (size_t)l]);
                /* Columns of the residual rows: u_k -> (a_k, b_k), v_k -> (-b_k, a_k). */
                const double same = w_re[k] * w_re[l] + w_im[k] * w_im[l];
                block[0] += weight * same;
                block[3] += weight * same;
                if (with_area) {
                    const double mixed = w_im[k] * w_re[l] - w_re[k] * w_im[l];
                    block[1] += weight * mixed;
                    block[2] -= weight * mixed;
                }
            }
        }
    }
}

void sk_assemble_lscm(double *blocks, const chart_mesh *m)
{
    assemble_conformal(blocks, m, 1);
}

void sk_assemble_dirichlet(double *blocks, const chart_mesh *m)
{
    assemble_conformal(blocks, m, 0);
}

/* y = A x over the free vertices (pinned rows give 0, pinned columns are skipped). */
static void free_product(double *y, const double *blocks, const chart_mesh *m, const unsigned char *pinned,
                         const double *x)
{
    for (size_t i = 0; i < m->vertex_count; ++i) {
        double u = 0.0, v = 0.0;
        if (!pinned[i])
            for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s) {
                const size_t j = (size_t)m->ring[s];
                if (pinned[j])
                    continue;
                const double *b = blocks + 4 * (size_t)s;
                u += b[0] * x[2 * j] + b[1] * x[2 * j + 1];
                v += b[2] * x[2 * j] + b[3] * x[2 * j + 1];
            }
        y[2 * i] = u;
        y[2 * i + 1] = v;
    }
}

/* z_i += w D_i^-1 (r_i - sum of A_ij z_j over i's free neighbours j before i, or after it): one vertex's step of
 * a block Gauss-Seidel sweep. */
static void sweep_vertex(double *z, const linear_system *system, const chart_mesh *m, const unsigned char *pinned,
                         size_t i, double ru, double rv, int before)
{
    for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s) {
        const size_t j = (size_t)m->ring[s];
        if (pinned[j] || j == i || (j < i) != before)
            continue;
        const double *b = system->blocks + 4 * (size_t)s;
        ru -= b[0] * z[2 * j] + b[1] * z[2 * j + 1];
        rv -= b[2] * z[2 * j] + b[3] * z[2 * j + 1];
    }
    const double *d = system->inverse + 4 * i;
    z[2 * i] += SSOR_OMEGA * (d[0] * ru + d[1] * rv);
    z[2 * i + 1] += SSOR_OMEGA * (d[2] * ru + d[3] * rv);
}

/*
 * z = M^-1 r on the free vertices, M the symmetric block SSOR preconditioner (D/w + L)(D/w)^-1(D/w + U): a forward
 * block Gauss-Seidel sweep from z = 0, then a backward one, which in place needs no D itself (the backward step
 * is z_i -= w D_i^-1 sum_{j>i} A_ij z_j). Each application costs about one product with A; against block Jacobi
 * (D^-1 alone) it cut the steps of an 80 x 80 grid's free-boundary solve from 1923 to 481 (tests/core/test_flatten.py).
 * SPD for 0 < w < 2, as CG needs.
 */
static void ssor(double *z, const linear_system *system, const chart_mesh *m, const unsigned char *pinned,
                 const double *r)
{
    const size_t v = m->vertex_count;
    memset(z, 0, 2 * v * sizeof *z);
    for (size_t i = 0; i < v; ++i)
        if (!pinned[i])
            sweep_vertex(z, system, m, pinned, i, r[2 * i], r[2 * i + 1], 1);
    for (size_t i = v; i-- > 0;)
        if (!pinned[i])
            sweep_vertex(z, system, m, pinned, i, 0.0, 0.0, 0);
}

/* z = M^-1 r: a multigrid V-cycle when the system has a hierarchy, else block SSOR. */
static void precondition(double *z, const linear_system *system, const chart_mesh *m, const unsigned char *pinned,
                         const double *r)
{
    if (system->amg)
        sk_apply_amg(z, system->amg, m, r);
    else
        ssor(z, system, m, pinned, r);
}

/*
 * Tutte's barycentric embedding (uniform weights): each vertex's block row says it sits at the average of
 * its neighbours. With the boundary pinned on a convex polygon no triangle flips (Tutte 1963).
 */
void sk_assemble_tutte(double *blocks, const chart_mesh *m)
{
    for (size_t i = 0; i < m->vertex_count; ++i) {
        const double neighbours = (double)(m->ring_offsets[i + 1] - m->ring_offsets[i] - 1);
        for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s) {
            const double weight = (size_t)m->ring[s] == i ? neighbours : -1.0;
            double *block = blocks + 4 * (size_t)s;
            block[0] = block[3] = weight;
            block[1] = block[2] = 0.0;
        }
    }
}

void sk_free_system(linear_system *system)
{
    sk_free_amg(system->amg);
    system->amg = NULL;
    SK_FREE_ALL(system->blocks, system->inverse, system->r, system->z, system->p, system->q);
}

int sk_allocate_system(linear_system *system, const chart_mesh *m)
{
    const size_t v = m->vertex_count, n = 2 * v, slots = (size_t)m->ring_offsets[v];
    system->amg = NULL;
    system->blocks = sk_allocate(4 * slots, sizeof *system->blocks);
    system->inverse = sk_allocate_zeroed(4 * v, sizeof *system->inverse);
    system->r = sk_allocate_zeroed(n, sizeof *system->r);
    system->z = sk_allocate(n, sizeof *system->z);
    system->p = sk_allocate(n, sizeof *system->p);
    system->q = sk_allocate(n, sizeof *system->q);
    if (system->blocks && system->inverse && system->r && system->z && system->p && system->q)
        return 1;
    sk_free_system(system);
    return 0;
}

/* The inverse of each free vertex's diagonal block, which the preconditioner's sweeps apply. */
void sk_invert_diagonal(linear_system *system, const chart_mesh *m, const unsigned char *pinned)
{
    for (size_t i = 0; i < m->vertex_count; ++i) {
        if (pinned[i])
            continue;
        const double *d = system->blocks + 4 * (size_t)ring_slot(m, (int32_t)i, (int32_t)i);
        const double determinant = d[0] * d[3] - d[1] * d[2];
        if (determinant > 0) {
            system->inverse[4 * i] = d[3] / determinant;
            system->inverse[4 * i + 1] = -d[1] / determinant;
            system->inverse[4 * i + 2] = -d[2] / determinant;
            system->inverse[4 * i + 3] = d[0] / determinant;
        }
    }
}

/* Preconditioned CG from x, whose residual is in system->r, until |r|^2 <= tolerance_sq or `limit` steps;
 * returns the steps. */
size_t sk_conjugate_gradients(double *x, linear_system *system, const chart_mesh *m, const unsigned char *pinned,
                                  double tolerance_sq, size_t limit)
{
    const size_t v = m->vertex_count, n = 2 * v;
    double *r = system->r, *z = system->z, *p = system->p, *q = system->q;
    precondition(z, system, m, pinned, r);
    memcpy(p, z, n * sizeof *p);
    double rz = dot(r, z, n);
    size_t step = 0;
    while (step < limit && dot(r, r, n) > tolerance_sq) {
        free_product(q, system->blocks, m, pinned, p);
        const double curvature = dot(p, q, n);
        if (!(curvature > 0))
            break;
        const double alpha = rz / curvature;
        for (size_t i = 0; i < n; ++i) {
            x[i] += alpha * p[i];
            r[i] -= alpha * q[i];
        }
        precondition(z, system, m, pinned, r);
        const double rz_next = dot(r, z, n);
        const double beta = rz_next / rz;
        rz = rz_next;
        for (size_t i = 0; i < n; ++i)
            p[i] = z[i] + beta * p[i];
        ++step;
    }
    return step;
}

/* The system's blocks and preconditioner: the multigrid from AMG_MIN_FREE_VERTICES free vertices, else SSOR. */
int sk_prepare_system(linear_system *system, const chart_mesh *m, const unsigned char *pinned, assembler assemble)
{
    if (!sk_allocate_system(system, m))
        return 0;
    assemble(system->blocks, m);
    sk_invert_diagonal(system, m, pinned);
    size_t free_count = 0;
    for (size_t i = 0; i < m->vertex_count; ++i)
        free_count += !pinned[i];
    if (free_count >= AMG_MIN_FREE_VERTICES)
        system->amg = sk_build_amg(system->blocks, m, pinned); /* NULL (out of memory): SSOR still solves it */
    return 1;
}

size_t sk_solve_to_tolerance(double *x, linear_system *system, const chart_mesh *m, const unsigned char *pinned,
                             double rhs_sq)
{
    return sk_conjugate_gradients(x, system, m, pinned, CG_RELATIVE_TOLERANCE * CG_RELATIVE_TOLERANCE * rhs_sq,
                                  4 * m->vertex_count + 200);
}

/*
 * Minimises the quadratic energy `assemble` builds (LSCM's, or Tutte's) over the free vertices of uv (2 per
 * local vertex; pinned entries are the pins, free entries the starting guess). Returns 0 when memory ran
 * out; *iterations counts CG steps.
 */
int sk_solve_quadratic(double *uv, const chart_mesh *m, const unsigned char *pinned, assembler assemble,
                           size_t *iterations)
{
    linear_system system;
    if (!sk_prepare_system(&system, m, pinned, assemble))
        return 0;
    /* r = b - A x with b = -(pinned columns) x_pinned: both together are -(all columns) x on free rows. */
    double rhs_sq = 0.0;
    for (size_t i = 0; i < m->vertex_count; ++i) {
        double ru = 0.0, rv = 0.0, bu = 0.0, bv = 0.0;
        if (!pinned[i])
            for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s) {
                const size_t j = (size_t)m->ring[s];
                const double *b = system.blocks + 4 * (size_t)s;
                const double pu = b[0] * uv[2 * j] + b[1] * uv[2 * j + 1];
                const double pv = b[2] * uv[2 * j] + b[3] * uv[2 * j + 1];
                ru -= pu;
                rv -= pv;
                if (pinned[j]) {
                    bu -= pu;
                    bv -= pv;
                }
            }
        system.r[2 * i] = ru;
        system.r[2 * i + 1] = rv;
        rhs_sq += bu * bu + bv * bv;
    }
    *iterations += sk_solve_to_tolerance(uv, &system, m, pinned, rhs_sq);
    sk_free_system(&system);
    return 1;
}
