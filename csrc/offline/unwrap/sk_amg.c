/*
 * A smoothed-aggregation algebraic multigrid preconditioner (Vanek, Mandel and Brezina 1996) for the flattening's
 * block systems: one 2x2 block (u, v) per pair of neighbouring free vertices. Block SSOR alone needs CG steps that
 * grow as vertices^0.66 (a chart's lowest modes are global and a sweep moves information one ring); a V-cycle over
 * a hierarchy of aggregates corrects them on coarse levels, so the steps stay nearly constant in the chart's size.
 *
 * Each level: strong connections (|A_ij|_F^2 >= theta^2 |A_ii|_F |A_jj|_F), greedy aggregates of a vertex and its
 * strong neighbours, a tentative prolongator that copies each aggregate's (u, v) to its members (the near-kernel:
 * the two translations), smoothed by one damped Jacobi step, and the Galerkin product P^T A P. The coarsest level
 * is solved by a dense Cholesky factorisation. The V-cycle smooths by a forward block Gauss-Seidel sweep before
 * and a backward one after the coarse correction, so it is symmetric positive definite, as CG needs. Everything is
 * sequential within a chart, in a fixed order: the same bits on any thread count.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_flatten.h"

/* Strength threshold of a connection (PyAMG's symmetric strength); 0.08 keeps sliver triangles' huge couplings
 * inside aggregates without letting their weak neighbours dilute them. */
#define AMG_STRENGTH 0.08
/* The coarsest level is solved directly once it has at most this many vertices (2 unknowns each). */
#define AMG_COARSE_VERTICES 200
/* A coarse level bigger than this is never factorised densely (its factor would need gigabytes): it is
 * smoothed instead. */
#define AMG_DENSE_LIMIT 1500
#define AMG_MAX_LEVELS 24
/* Power iterations estimating the spectral radius of D^-1 A for the prolongator's Jacobi smoothing. */
#define AMG_POWER_STEPS 12

/* A square or rectangular matrix of 2x2 blocks in compressed rows. */
typedef struct block_matrix {
    size_t rows, cols;
    size_t *offsets;  /* rows + 1 */
    int32_t *columns; /* per entry */
    double *blocks;   /* 4 per entry, row-major, while the hierarchy is built */
    float *single;    /* the same blocks rounded to single precision, which the V-cycle reads (see to_single) */
} block_matrix;

typedef struct amg_level {
    block_matrix a;  /* this level's operator */
    block_matrix p;  /* prolongation from the next level (a.rows x next a.rows); empty on the coarsest */
    double *inverse; /* 4 per row: the inverse diagonal blocks of a */
    double *x, *b, *residual; /* 2 per row */
} amg_level;

struct amg_hierarchy {
    size_t level_count;
    amg_level levels[AMG_MAX_LEVELS];
    double *factor; /* the coarsest operator's dense Cholesky factor (lower), or NULL when it is smoothed */
    size_t coarse_unknowns;
    int32_t *free_row; /* per chart vertex: its row on level 0, or -1 when pinned */
};

static void free_matrix(block_matrix *m)
{
    SK_FREE_ALL(m->offsets, m->columns, m->blocks, m->single);
    memset(m, 0, sizeof *m);
}

static int allocate_matrix(block_matrix *m, size_t rows, size_t cols, size_t entries)
{
    m->rows = rows;
    m->cols = cols;
    m->offsets = sk_allocate_zeroed(rows + 1, sizeof *m->offsets);
    m->columns = sk_allocate(entries, sizeof *m->columns);
    m->blocks = sk_allocate(4 * entries, sizeof *m->blocks);
    if (m->offsets && m->columns && m->blocks)
        return 1;
    free_matrix(m);
    return 0;
}

void sk_free_amg(amg_hierarchy *h)
{
    if (!h)
        return;
    for (size_t l = 0; l < h->level_count; ++l) {
        amg_level *level = &h->levels[l];
        free_matrix(&level->a);
        free_matrix(&level->p);
        SK_FREE_ALL(level->inverse, level->x, level->b, level->residual);
    }
    SK_FREE_ALL(h->factor, h->free_row);
    free(h);
}

/* ---------------------------------------------------------------------------------------------
 * 2x2 block arithmetic
 * ------------------------------------------------------------------------------------------- */

static inline void add_product(double *out, const double *a, const double *b) /* out += a b */
{
    out[0] += a[0] * b[0] + a[1] * b[2];
    out[1] += a[0] * b[1] + a[1] * b[3];
    out[2] += a[2] * b[0] + a[3] * b[2];
    out[3] += a[2] * b[1] + a[3] * b[3];
}

static inline double block_norm_sq(const double *b)
{
    return b[0] * b[0] + b[1] * b[1] + b[2] * b[2] + b[3] * b[3];
}

/* The inverse of a 2x2 block, or zeros when it is not positive definite (a vertex with no coupling). */
static void invert_block(double *inverse, const double *d)
{
    const double determinant = d[0] * d[3] - d[1] * d[2];
    if (determinant > 0 && d[0] > 0) {
        inverse[0] = d[3] / determinant;
        inverse[1] = -d[1] / determinant;
        inverse[2] = -d[2] / determinant;
        inverse[3] = d[0] / determinant;
    } else {
        inverse[0] = inverse[1] = inverse[2] = inverse[3] = 0.0;
    }
}

static const double *diagonal_block(const block_matrix *a, size_t i)
{
    static const double zero[4] = {0.0, 0.0, 0.0, 0.0};
    for (size_t s = a->offsets[i]; s < a->offsets[i + 1]; ++s)
        if ((size_t)a->columns[s] == i)
            return a->blocks + 4 * s;
    return zero;
}

/* ---------------------------------------------------------------------------------------------
 * Setup: aggregation, the smoothed prolongator and the Galerkin product
 * ------------------------------------------------------------------------------------------- */

/* Is A_ij (entry s of row i) a strong connection? */
static int is_strong(const block_matrix *a, const double *diagonal_norm, size_t i, size_t s)
{
    const size_t j = (size_t)a->columns[s];
    return j != i && block_norm_sq(a->blocks + 4 * s) >= AMG_STRENGTH * AMG_STRENGTH * diagonal_norm[i] *
                                                             diagonal_norm[j];
}

/*
 * Greedy aggregation (PyAMG's standard_aggregation): a vertex whose strong neighbours are all free starts an
 * aggregate with them; then each left-over vertex joins the aggregate of a strong neighbour from the first pass;
 * then the rest start aggregates with their still unaggregated strong neighbours. A vertex with no strong
 * connection stays out (-1): the smoother alone resolves it. Returns the number of aggregates.
 */
static size_t aggregate(int32_t *label, const block_matrix *a, const double *diagonal_norm)
{
    const size_t n = a->rows;
    size_t count = 0;
    for (size_t i = 0; i < n; ++i)
        label[i] = -2; /* not yet aggregated */
    for (size_t i = 0; i < n; ++i) {
        int neighbours = 0, taken = 0;
        for (size_t s = a->offsets[i]; s < a->offsets[i + 1] && !taken; ++s)
            if (is_strong(a, diagonal_norm, i, s)) {
                neighbours = 1;
                taken = label[a->columns[s]] != -2;
            }
        if (label[i] != -2 || taken)
            continue;
        if (!neighbours) {
            label[i] = -1;
            continue;
        }
        label[i] = (int32_t)count;
        for (size_t s = a->offsets[i]; s < a->offsets[i + 1]; ++s)
            if (is_strong(a, diagonal_norm, i, s))
                label[a->columns[s]] = (int32_t)count;
        ++count;
    }
    const size_t first_pass = count;
    for (size_t i = 0; i < n; ++i) {
        if (label[i] != -2)
            continue;
        for (size_t s = a->offsets[i]; s < a->offsets[i + 1]; ++s) {
            const int32_t other = label[a->columns[s]];
            if (other >= 0 && (size_t)other < first_pass && is_strong(a, diagonal_norm, i, s)) {
                label[i] = other;
                break;
            }
        }
    }
    for (size_t i = 0; i < n; ++i) {
        if (label[i] != -2)
            continue;
        label[i] = (int32_t)count;
        for (size_t s = a->offsets[i]; s < a->offsets[i + 1]; ++s)
            if (label[a->columns[s]] == -2 && is_strong(a, diagonal_norm, i, s))
                label[a->columns[s]] = (int32_t)count;
        ++count;
    }
    return count;
}

/* y = D^-1 A x (2 per row). */
static void scaled_product(double *y, const block_matrix *a, const double *inverse, const double *x)
{
    for (size_t i = 0; i < a->rows; ++i) {
        double u = 0.0, v = 0.0;
        for (size_t s = a->offsets[i]; s < a->offsets[i + 1]; ++s) {
            const double *b = a->blocks + 4 * s, *xj = x + 2 * (size_t)a->columns[s];
            u += b[0] * xj[0] + b[1] * xj[1];
            v += b[2] * xj[0] + b[3] * xj[1];
        }
        const double *d = inverse + 4 * i;
        y[2 * i] = d[0] * u + d[1] * v;
        y[2 * i + 1] = d[2] * u + d[3] * v;
    }
}

/* The largest eigenvalue of D^-1 A (real and positive: it is similar to D^-1/2 A D^-1/2), by power iteration
 * from a fixed start; 0 when memory ran out. */
static double spectral_radius(const block_matrix *a, const double *inverse)
{
    const size_t n = 2 * a->rows;
    double *x = sk_allocate(n, sizeof *x), *y = sk_allocate(n, sizeof *y);
    double radius = 0.0;
    if (x && y) {
        for (size_t i = 0; i < n; ++i)
            x[i] = 1.0 + (double)(i % 7) / 7.0; /* not orthogonal to the top eigenvector, whatever the mesh */
        for (int step = 0; step < AMG_POWER_STEPS; ++step) {
            const double norm = sqrt(dot(x, x, n));
            if (!(norm > 0))
                break;
            for (size_t i = 0; i < n; ++i)
                x[i] /= norm;
            scaled_product(y, a, inverse, x);
            radius = sqrt(dot(y, y, n));
            double *swap = x;
            x = y;
            y = swap;
        }
    }
    free(x);
    free(y);
    return radius;
}

/* A growable row of blocks: a dense marker over the columns gives each column's slot in the row. */
typedef struct row_accumulator {
    int32_t *slot;    /* per column: its position in the row being built, or -1 */
    int32_t *columns; /* the row's columns, in first-touch order */
    double *blocks;
    size_t size;
} row_accumulator;

static double *accumulate(row_accumulator *row, int32_t column)
{
    if (row->slot[column] < 0) {
        row->slot[column] = (int32_t)row->size;
        row->columns[row->size] = column;
        memset(row->blocks + 4 * row->size, 0, 4 * sizeof *row->blocks);
        ++row->size;
    }
    return row->blocks + 4 * (size_t)row->slot[column];
}

/* Appends the accumulated row to a growing matrix (capacity in entries, doubled as needed) and clears it. */
static int emit_row(block_matrix *out, size_t *capacity, size_t row, row_accumulator *acc)
{
    const size_t start = out->offsets[row];
    if (start + acc->size > *capacity) {
        size_t grown = *capacity * 2 > start + acc->size ? *capacity * 2 : start + acc->size;
        int32_t *columns = realloc(out->columns, grown * sizeof *columns);
        if (columns)
            out->columns = columns;
        double *blocks = realloc(out->blocks, 4 * grown * sizeof *blocks);
        if (blocks)
            out->blocks = blocks;
        if (!columns || !blocks)
            return 0;
        *capacity = grown;
    }
    for (size_t k = 0; k < acc->size; ++k) {
        out->columns[start + k] = acc->columns[k];
        memcpy(out->blocks + 4 * (start + k), acc->blocks + 4 * k, 4 * sizeof *out->blocks);
        acc->slot[acc->columns[k]] = -1;
    }
    out->offsets[row + 1] = start + acc->size;
    acc->size = 0;
    return 1;
}

/*
 * P = (I - w D^-1 A) T, w = 4 / (3 rho(D^-1 A)), T the tentative prolongator (T_iJ = I when vertex i is in
 * aggregate J): row i of P has a block for each aggregate of i's neighbours.
 */
static int smoothed_prolongator(block_matrix *p, const block_matrix *a, const double *inverse, const int32_t *label,
                                size_t aggregates, row_accumulator *acc)
{
    const double radius = spectral_radius(a, inverse);
    if (!(radius > 0))
        return 0;
    const double weight = 4.0 / (3.0 * radius);
    size_t capacity = a->offsets[a->rows];
    if (!allocate_matrix(p, a->rows, aggregates, capacity))
        return 0;
    for (size_t i = 0; i < a->rows; ++i) {
        if (label[i] >= 0) {
            double *b = accumulate(acc, label[i]);
            b[0] += 1.0;
            b[3] += 1.0;
        }
        double scaled[4] = {0.0, 0.0, 0.0, 0.0};
        for (size_t s = a->offsets[i]; s < a->offsets[i + 1]; ++s) {
            const int32_t j = a->columns[s];
            if (label[j] < 0)
                continue;
            memset(scaled, 0, sizeof scaled);
            add_product(scaled, inverse + 4 * i, a->blocks + 4 * s);
            double *b = accumulate(acc, label[j]);
            for (int k = 0; k < 4; ++k)
                b[k] -= weight * scaled[k];
        }
        if (!emit_row(p, &capacity, i, acc))
            return 0;
    }
    return 1;
}

/* The transpose's pattern and blocks (each block transposed), rows in order: the Galerkin product's P^T. */
static int transpose(block_matrix *t, const block_matrix *p)
{
    if (!allocate_matrix(t, p->cols, p->rows, p->offsets[p->rows]))
        return 0;
    for (size_t s = 0; s < p->offsets[p->rows]; ++s)
        ++t->offsets[p->columns[s] + 1];
    for (size_t j = 0; j < t->rows; ++j)
        t->offsets[j + 1] += t->offsets[j];
    size_t *next = sk_allocate(t->rows + 1, sizeof *next);
    if (!next) {
        free_matrix(t);
        return 0;
    }
    memcpy(next, t->offsets, (t->rows + 1) * sizeof *next);
    for (size_t i = 0; i < p->rows; ++i)
        for (size_t s = p->offsets[i]; s < p->offsets[i + 1]; ++s) {
            const size_t at = next[p->columns[s]]++;
            const double *b = p->blocks + 4 * s;
            t->columns[at] = (int32_t)i;
            double *out = t->blocks + 4 * at;
            out[0] = b[0];
            out[1] = b[2];
            out[2] = b[1];
            out[3] = b[3];
        }
    free(next);
    return 1;
}

/* out = left * right (Gustavson's row-by-row product; acc's marker spans right's columns). */
static int multiply(block_matrix *out, const block_matrix *left, const block_matrix *right, row_accumulator *acc)
{
    size_t capacity = left->offsets[left->rows] + right->offsets[right->rows];
    if (!allocate_matrix(out, left->rows, right->cols, capacity))
        return 0;
    for (size_t i = 0; i < left->rows; ++i) {
        for (size_t s = left->offsets[i]; s < left->offsets[i + 1]; ++s) {
            const size_t k = (size_t)left->columns[s];
            for (size_t t = right->offsets[k]; t < right->offsets[k + 1]; ++t)
                add_product(accumulate(acc, right->columns[t]), left->blocks + 4 * s, right->blocks + 4 * t);
        }
        if (!emit_row(out, &capacity, i, acc))
            return 0;
    }
    return 1;
}

/* The next level's operator P^T A P. */
static int galerkin_product(block_matrix *coarse, const block_matrix *a, const block_matrix *p, row_accumulator *acc)
{
    block_matrix ap = {0}, pt = {0};
    int ok = multiply(&ap, a, p, acc) && transpose(&pt, p) && multiply(coarse, &pt, &ap, acc);
    free_matrix(&ap);
    free_matrix(&pt);
    return ok;
}

static int allocate_level_vectors(amg_level *level)
{
    const size_t n = level->a.rows;
    level->inverse = sk_allocate(4 * n, sizeof *level->inverse);
    level->x = sk_allocate(2 * n, sizeof *level->x);
    level->b = sk_allocate(2 * n, sizeof *level->b);
    level->residual = sk_allocate(2 * n, sizeof *level->residual);
    if (!level->inverse || !level->x || !level->b || !level->residual)
        return 0;
    for (size_t i = 0; i < n; ++i)
        invert_block(level->inverse + 4 * i, diagonal_block(&level->a, i));
    return 1;
}

/* Level 0: the chart's blocks between free vertices, renumbered. */
static int free_operator(block_matrix *a, int32_t *free_row, const double *blocks, const chart_mesh *m,
                         const unsigned char *pinned)
{
    size_t rows = 0, entries = 0;
    for (size_t i = 0; i < m->vertex_count; ++i)
        free_row[i] = pinned[i] ? -1 : (int32_t)rows++;
    for (size_t i = 0; i < m->vertex_count; ++i)
        if (!pinned[i])
            for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s)
                entries += !pinned[m->ring[s]];
    if (!allocate_matrix(a, rows, rows, entries))
        return 0;
    size_t at = 0;
    for (size_t i = 0; i < m->vertex_count; ++i) {
        if (pinned[i])
            continue;
        for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s) {
            if (pinned[m->ring[s]])
                continue;
            a->columns[at] = free_row[m->ring[s]];
            memcpy(a->blocks + 4 * at, blocks + 4 * (size_t)s, 4 * sizeof *a->blocks);
            ++at;
        }
        a->offsets[free_row[i] + 1] = at;
    }
    return 1;
}

/* The dense Cholesky factor of the coarsest operator (n unknowns); a pivot that rounding left non-positive
 * gets a zero row, so that unknown is left to the smoother. */
static int factorise_coarsest(amg_hierarchy *h, const block_matrix *a)
{
    const size_t n = 2 * a->rows;
    double *l = sk_allocate_zeroed(n * n, sizeof *l);
    if (!l)
        return 0;
    for (size_t i = 0; i < a->rows; ++i)
        for (size_t s = a->offsets[i]; s < a->offsets[i + 1]; ++s) {
            const size_t j = (size_t)a->columns[s];
            const double *b = a->blocks + 4 * s;
            l[2 * i * n + 2 * j] = b[0];
            l[2 * i * n + 2 * j + 1] = b[1];
            l[(2 * i + 1) * n + 2 * j] = b[2];
            l[(2 * i + 1) * n + 2 * j + 1] = b[3];
        }
    for (size_t j = 0; j < n; ++j) {
        double pivot = l[j * n + j];
        for (size_t k = 0; k < j; ++k)
            pivot -= l[j * n + k] * l[j * n + k];
        const double scale = fabs(l[j * n + j]);
        if (!(pivot > 1e-14 * scale) || !(scale > 0)) {
            for (size_t k = 0; k <= j; ++k)
                l[j * n + k] = 0.0;
            for (size_t i = j + 1; i < n; ++i)
                l[i * n + j] = 0.0;
            continue;
        }
        const double root = sqrt(pivot);
        l[j * n + j] = root;
        for (size_t i = j + 1; i < n; ++i) {
            double sum = l[i * n + j];
            for (size_t k = 0; k < j; ++k)
                sum -= l[i * n + k] * l[j * n + k];
            l[i * n + j] = sum / root;
        }
    }
    for (size_t i = 0; i < n; ++i) /* only the lower triangle is the factor */
        for (size_t j = i + 1; j < n; ++j)
            l[i * n + j] = 0.0;
    h->factor = l;
    h->coarse_unknowns = n;
    return 1;
}

/* The V-cycle reads the operators and prolongators in single precision, built in double: at a million vertices
 * the smoothers' sweeps over the largest charts' matrices ran at memory speed (61% of the unwrap's time), and
 * single-precision blocks halve their traffic. It stays a symmetric preconditioner (each block of A^T is the rounded
 * transpose, and P^T restricts as P prolongs); CG's own products and residuals stay in double, so only the
 * preconditioner's quality, not the converged solution, depends on it. */
static int to_single(block_matrix *m)
{
    const size_t values = 4 * (m->offsets ? m->offsets[m->rows] : 0);
    m->single = sk_allocate(values ? values : 1, sizeof *m->single);
    if (!m->single)
        return 0;
    for (size_t k = 0; k < values; ++k)
        m->single[k] = (float)m->blocks[k];
    free(m->blocks);
    m->blocks = NULL;
    return 1;
}

/* The hierarchy for the chart's blocks over its free vertices; NULL when memory ran out (the caller then keeps
 * SSOR). */
amg_hierarchy *sk_build_amg(const double *blocks, const chart_mesh *m, const unsigned char *pinned)
{
    amg_hierarchy *h = sk_allocate_zeroed(1, sizeof *h);
    if (!h)
        return NULL;
    h->free_row = sk_allocate(m->vertex_count, sizeof *h->free_row);
    row_accumulator acc = {0};
    int32_t *label = NULL;
    double *diagonal_norm = NULL;
    int ok = h->free_row && free_operator(&h->levels[0].a, h->free_row, blocks, m, pinned);
    const size_t n = ok ? h->levels[0].a.rows : 0;
    h->level_count = ok;
    if (ok) {
        acc.slot = sk_allocate(n + 1, sizeof *acc.slot);
        acc.columns = sk_allocate(n + 1, sizeof *acc.columns);
        acc.blocks = sk_allocate(4 * (n + 1), sizeof *acc.blocks);
        label = sk_allocate(n + 1, sizeof *label);
        diagonal_norm = sk_allocate(n + 1, sizeof *diagonal_norm);
        ok = acc.slot && acc.columns && acc.blocks && label && diagonal_norm;
        for (size_t i = 0; ok && i <= n; ++i)
            acc.slot[i] = -1;
    }
    while (ok) {
        amg_level *level = &h->levels[h->level_count - 1];
        ok = allocate_level_vectors(level);
        const size_t rows = level->a.rows;
        if (!ok || rows <= AMG_COARSE_VERTICES || h->level_count == AMG_MAX_LEVELS)
            break;
        for (size_t i = 0; i < rows; ++i)
            diagonal_norm[i] = sqrt(block_norm_sq(diagonal_block(&level->a, i)));
        const size_t aggregates = aggregate(label, &level->a, diagonal_norm);
        if (aggregates == 0 || aggregates * 10 > rows * 9) /* coarsening stalled */
            break;
        ok = smoothed_prolongator(&level->p, &level->a, level->inverse, label, aggregates, &acc) &&
             galerkin_product(&h->levels[h->level_count].a, &level->a, &level->p, &acc);
        if (ok)
            ++h->level_count;
        else
            free_matrix(&level->p);
    }
    const block_matrix *coarsest = &h->levels[h->level_count - 1].a;
    if (ok && coarsest->rows * 2 <= AMG_DENSE_LIMIT)
        ok = factorise_coarsest(h, coarsest);
    for (size_t l = 0; ok && l < h->level_count; ++l)
        ok = to_single(&h->levels[l].a) && to_single(&h->levels[l].p);
    SK_FREE_ALL(acc.slot, acc.columns, acc.blocks, label, diagonal_norm);
    if (!ok) {
        sk_free_amg(h);
        return NULL;
    }
    return h;
}

/* ---------------------------------------------------------------------------------------------
 * The V-cycle
 * ------------------------------------------------------------------------------------------- */

/* One block Gauss-Seidel sweep on A x = b, forward or backward. */
static void gauss_seidel(amg_level *level, int forward)
{
    const block_matrix *a = &level->a;
    const size_t n = a->rows;
    for (size_t step = 0; step < n; ++step) {
        const size_t i = forward ? step : n - 1 - step;
        double ru = level->b[2 * i], rv = level->b[2 * i + 1];
        for (size_t s = a->offsets[i]; s < a->offsets[i + 1]; ++s) {
            const float *b = a->single + 4 * s;
            const double *xj = level->x + 2 * (size_t)a->columns[s];
            ru -= b[0] * xj[0] + b[1] * xj[1];
            rv -= b[2] * xj[0] + b[3] * xj[1];
        }
        const double *d = level->inverse + 4 * i;
        level->x[2 * i] += d[0] * ru + d[1] * rv;
        level->x[2 * i + 1] += d[2] * ru + d[3] * rv;
    }
}

/* x = L^-T L^-1 b on the coarsest level (rows of a zero pivot give 0). */
static void coarse_solve(const amg_hierarchy *h, amg_level *level)
{
    const size_t n = h->coarse_unknowns;
    const double *l = h->factor;
    double *x = level->x;
    for (size_t i = 0; i < n; ++i) {
        double sum = level->b[i];
        for (size_t k = 0; k < i; ++k)
            sum -= l[i * n + k] * x[k];
        x[i] = l[i * n + i] > 0 ? sum / l[i * n + i] : 0.0;
    }
    for (size_t i = n; i-- > 0;) {
        double sum = x[i];
        for (size_t k = i + 1; k < n; ++k)
            sum -= l[k * n + i] * x[k];
        x[i] = l[i * n + i] > 0 ? sum / l[i * n + i] : 0.0;
    }
}

static void cycle(amg_hierarchy *h, size_t l)
{
    amg_level *level = &h->levels[l];
    const size_t n = level->a.rows;
    if (l + 1 == h->level_count && h->factor) {
        coarse_solve(h, level);
        return;
    }
    memset(level->x, 0, 2 * n * sizeof *level->x);
    gauss_seidel(level, 1);
    if (l + 1 < h->level_count) {
        amg_level *next = &h->levels[l + 1];
        const block_matrix *a = &level->a, *p = &level->p;
        for (size_t i = 0; i < n; ++i) { /* residual */
            double ru = level->b[2 * i], rv = level->b[2 * i + 1];
            for (size_t s = a->offsets[i]; s < a->offsets[i + 1]; ++s) {
                const float *b = a->single + 4 * s;
                const double *xj = level->x + 2 * (size_t)a->columns[s];
                ru -= b[0] * xj[0] + b[1] * xj[1];
                rv -= b[2] * xj[0] + b[3] * xj[1];
            }
            level->residual[2 * i] = ru;
            level->residual[2 * i + 1] = rv;
        }
        memset(next->b, 0, 2 * next->a.rows * sizeof *next->b);
        for (size_t i = 0; i < n; ++i) /* restriction: b_c = P^T r */
            for (size_t s = p->offsets[i]; s < p->offsets[i + 1]; ++s) {
                const float *b = p->single + 4 * s;
                const double *r = level->residual + 2 * i;
                double *out = next->b + 2 * (size_t)p->columns[s];
                out[0] += b[0] * r[0] + b[2] * r[1];
                out[1] += b[1] * r[0] + b[3] * r[1];
            }
        cycle(h, l + 1);
        for (size_t i = 0; i < n; ++i) /* prolongation: x += P x_c */
            for (size_t s = p->offsets[i]; s < p->offsets[i + 1]; ++s) {
                const float *b = p->single + 4 * s;
                const double *xc = next->x + 2 * (size_t)p->columns[s];
                level->x[2 * i] += b[0] * xc[0] + b[1] * xc[1];
                level->x[2 * i + 1] += b[2] * xc[0] + b[3] * xc[1];
            }
    } else {
        gauss_seidel(level, 0); /* a coarsest level too big to factorise: one more symmetric sweep */
        gauss_seidel(level, 1);
    }
    gauss_seidel(level, 0);
}

/* z = M^-1 r over the chart's vertices (pinned entries of z are 0): one V-cycle. */
void sk_apply_amg(double *z, amg_hierarchy *h, const chart_mesh *m, const double *r)
{
    amg_level *top = &h->levels[0];
    for (size_t i = 0; i < m->vertex_count; ++i)
        if (h->free_row[i] >= 0) {
            top->b[2 * (size_t)h->free_row[i]] = r[2 * i];
            top->b[2 * (size_t)h->free_row[i] + 1] = r[2 * i + 1];
        }
    cycle(h, 0);
    for (size_t i = 0; i < m->vertex_count; ++i) {
        const int32_t row = h->free_row[i];
        z[2 * i] = row >= 0 ? top->x[2 * (size_t)row] : 0.0;
        z[2 * i + 1] = row >= 0 ? top->x[2 * (size_t)row + 1] : 0.0;
    }
}
