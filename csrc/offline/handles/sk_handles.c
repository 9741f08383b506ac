/*
 * Training a handle rig (Feng 2010, chapter 2): regularised kernel CCA with the fused regression (sections
 * 2.4.2-2.4.3) and the Poisson translation solver's prefactored matrices (section 2.5). Offline: LAPACK, scratch
 * memory per call.
 */
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_internal.h"

/* Eigenvalues below this fraction of the largest are the centred kernel's null space (centring removes one). */
#define SK_KERNEL_RANK_TOLERANCE 1e-10
/* The target side's ridge, relative to its mean variance: keeps a bone whose DQ never changes (or changes in
 * fewer directions than 8) solvable without changing the correlations measurably. */
#define SK_TARGET_RIDGE 1e-9
/* Ridge of the small regressions (2.8, 2.9) and of each edge's weight fit (2.10), relative to the trace. */
#define SK_REGRESSION_RIDGE 1e-10
#define SK_EDGE_RIDGE 1e-6

/* ---- small dense helpers (row-major) ----------------------------------------------------------------------- */

/* c (n x m) = a (n x k) b (k x m), with a read transposed (k x n) when transpose_a and b read transposed (m x k)
 * when transpose_b; each entry sums its k products in order. */
static void multiply(double *c, const double *a, const double *b, size_t n, size_t k, size_t m, int transpose_a,
                     int transpose_b)
{
    for (size_t i = 0; i < n; ++i)
        for (size_t j = 0; j < m; ++j) {
            double sum = 0;
            for (size_t l = 0; l < k; ++l)
                sum += (transpose_a ? a[l * n + i] : a[i * k + l]) * (transpose_b ? b[j * k + l] : b[l * m + j]);
            c[i * m + j] = sum;
        }
}

/* x (n x rhs) = solve of the SPD system (a + ridge * trace(a) / n * I) x = b by Cholesky; a is overwritten. */
static int solve_spd(double *a, double *b, size_t n, size_t rhs, double ridge)
{
    double trace = 0;
    for (size_t i = 0; i < n; ++i)
        trace += a[i * n + i];
    const double shift = trace > 0 ? ridge * trace / (double)n : ridge;
    for (size_t i = 0; i < n; ++i)
        a[i * n + i] += shift;
    return LAPACKE_dposv(LAPACK_ROW_MAJOR, 'U', (lapack_int)n, (lapack_int)rhs, a, (lapack_int)n, b,
                         (lapack_int)rhs) == 0;
}

/* ---- kernel CCA ------------------------------------------------------------------------------------------------ */

typedef struct kcca_task {
    double *mapping, *offset, *correlations;
    const double *targets;
    const double *eigenvectors, *eigenvalues; /* the centred kernel's kept eigenpairs: n x rank, rank */
    const double *kernel_row_means;           /* K 1 / n */
    size_t example_count, group_count, dimension, basis_count, rank;
    double ridge;
    sk_status failed[SK_MAX_WORKERS];
    size_t failed_group[SK_MAX_WORKERS];
} kcca_task;

/* One group's canonical pairs, regressions and fused mapping; 0 when LAPACK fails or memory runs out. */
static int kcca_group(const kcca_task *task, size_t group, double *scratch)
{
    const size_t n = task->example_count, m = task->dimension, r = task->rank;
    double *dc = scratch, *mean = dc + n * m, *sdd = mean + m, *whiten = sdd + m * m, *values = whiten + m * m;
    double *t = values + m, *singular = t + r * m, *u = singular + m, *vt = u + r * r, *superb = vt + m * m;
    double *fc = superb + m + r, *cr = fc + n * m, *dr = cr + m * n, *b = dr + m * n, *crt = b + m * m;
    double *hd = crt + m * m, *w = hd + m * m, *gram = w + m * n;
    double *map = task->mapping + group * m * n, *off = task->offset + group * m;
    double *rho = task->correlations + group * task->basis_count;
    /* Centred targets Dc (n x m). */
    for (size_t c = 0; c < m; ++c) {
        double sum = 0;
        for (size_t i = 0; i < n; ++i)
            sum += task->targets[(i * task->group_count + group) * m + c];
        mean[c] = sum / (double)n;
        for (size_t i = 0; i < n; ++i)
            dc[i * m + c] = task->targets[(i * task->group_count + group) * m + c] - mean[c];
    }
    multiply(sdd, dc, dc, m, n, m, 1, 0);
    double trace = 0;
    for (size_t c = 0; c < m; ++c)
        trace += sdd[c * m + c];
    for (size_t k = 0; k < task->basis_count; ++k)
        rho[k] = 0;
    memcpy(off, mean, m * sizeof *off);
    if (!(trace > 0) || r == 0) { /* a target that never changes: predict its mean */
        memset(map, 0, m * n * sizeof *map);
        return 1;
    }
    for (size_t c = 0; c < m; ++c)
        sdd[c * m + c] += SK_TARGET_RIDGE * trace / (double)m;
    /* whiten = Sdd^(-1/2) by its eigen-decomposition (sdd becomes the eigenvectors). */
    if (LAPACKE_dsyev(LAPACK_ROW_MAJOR, 'V', 'U', (lapack_int)m, sdd, (lapack_int)m, values) != 0)
        return 0;
    for (size_t i = 0; i < m; ++i)
        for (size_t j = 0; j < m; ++j) {
            double sum = 0;
            for (size_t l = 0; l < m; ++l)
                sum += sdd[i * m + l] * sdd[j * m + l] / sqrt(values[l]);
            whiten[i * m + j] = sum;
        }
    /* T = diag(lambda / sqrt(lambda^2 + ridge lambda)) U' Dc Sdd^(-1/2) (r x m). */
    double *udc = cr; /* r x m, scratch until cr is computed */
    multiply(udc, task->eigenvectors, dc, r, n, m, 1, 0);
    for (size_t i = 0; i < r; ++i) {
        const double lambda = task->eigenvalues[i];
        const double scale = lambda / sqrt(lambda * lambda + task->ridge * lambda);
        for (size_t c = 0; c < m; ++c)
            udc[i * m + c] *= scale;
    }
    multiply(t, udc, whiten, r, m, m, 0, 0);
    const size_t pairs_possible = r < m ? r : m;
    if (LAPACKE_dgesvd(LAPACK_ROW_MAJOR, 'S', 'S', (lapack_int)r, (lapack_int)m, t, (lapack_int)m, singular, u,
                       (lapack_int)pairs_possible, vt, (lapack_int)m, superb) != 0)
        return 0;
    size_t p = task->basis_count < pairs_possible ? task->basis_count : pairs_possible;
    for (size_t k = 0; k < p; ++k)
        rho[k] = singular[k];
    /* Fc (n x p) = U diag(1 / sqrt(lambda^2 + ridge lambda)) calU; the reduced inputs Cr = Fc' Kc (p x n) =
     * calU' diag(lambda / sqrt(...)) U'. Ud (m x p) = Sdd^(-1/2) calV; Dr = Ud' Dc' (p x n). */
    for (size_t i = 0; i < n; ++i)
        for (size_t k = 0; k < p; ++k) {
            double f = 0, c = 0;
            for (size_t l = 0; l < r; ++l) {
                const double lambda = task->eigenvalues[l], root = sqrt(lambda * lambda + task->ridge * lambda);
                const double both = task->eigenvectors[i * r + l] * u[l * pairs_possible + k];
                f += both / root;
                c += both * lambda / root;
            }
            fc[i * p + k] = f;
            cr[k * n + i] = c;
        }
    double *ud = b; /* m x p, scratch until b is computed */
    multiply(ud, whiten, vt, m, m, p, 0, 1);
    multiply(dr, ud, dc, p, m, n, 1, 1);
    /* Eq. 2.8: B (p x p) = Dr Cr' (Cr Cr')^-1, solved as (Cr Cr') B' = Cr Dr'. */
    multiply(gram, cr, cr, p, n, p, 0, 1);
    multiply(crt, cr, dr, p, n, p, 0, 1);
    if (!solve_spd(gram, crt, p, p, SK_REGRESSION_RIDGE))
        return 0;
    /* crt now holds B'. Eq. 2.9: Hd (m x p) = Dc' Dr' (Dr Dr')^-1, solved as (Dr Dr') Hd' = Dr Dc. */
    double *hdt = hd; /* p x m */
    multiply(gram, dr, dr, p, n, p, 0, 1);
    multiply(hdt, dr, dc, p, n, m, 0, 0);
    if (!solve_spd(gram, hdt, p, m, SK_REGRESSION_RIDGE))
        return 0;
    /* W = Hd B Fc' (m x n): HB (m x p) = Hd B = (hdt)' (crt)'. */
    double *hb = whiten; /* m x p: whiten is no longer needed */
    multiply(hb, hdt, crt, m, p, p, 1, 1);
    multiply(w, hb, fc, m, p, n, 0, 1);
    /* Centring folded in: the centred kernel vector is H k(x) - H K 1/n, so mapping = W H and
     * offset = mean - W H K 1/n. */
    for (size_t c = 0; c < m; ++c) {
        double row_mean = 0;
        for (size_t i = 0; i < n; ++i)
            row_mean += w[c * n + i];
        row_mean /= (double)n;
        double shift = 0;
        for (size_t i = 0; i < n; ++i) {
            map[c * n + i] = w[c * n + i] - row_mean;
            shift += map[c * n + i] * task->kernel_row_means[i];
        }
        off[c] = mean[c] - shift;
    }
    return 1;
}

static size_t kcca_scratch_size(size_t n, size_t m, size_t r)
{
    return n * m + m + 3 * m * m + m + r * m + m + r * r + m * m + m + r + n * m + 2 * m * n + 2 * m * m +
           m * m + m * n + m * m;
}

static void kcca_range(void *context, size_t worker, size_t begin, size_t end)
{
    kcca_task *task = context;
    double *scratch = sk_allocate(kcca_scratch_size(task->example_count, task->dimension, task->rank),
                                  sizeof *scratch);
    if (!scratch) {
        task->failed[worker] = SK_ERROR_MEMORY, task->failed_group[worker] = begin;
        return;
    }
    for (size_t group = begin; group < end && task->failed[worker] == SK_OK; ++group)
        if (!kcca_group(task, group, scratch))
            task->failed[worker] = SK_ERROR_LAPACK, task->failed_group[worker] = group;
    free(scratch);
}

/* The centred kernel Kc = H K H's eigenpairs above the rank tolerance, largest first, into vectors (n x rank). */
static sk_status centred_kernel_eigen(double *vectors, double *values, size_t *rank, double *row_means,
                                      const double *kernel, size_t n, sk_error *error)
{
    double *centred = sk_allocate(n * n, sizeof *centred), *all = sk_allocate(n, sizeof *all);
    if (!centred || !all) {
        SK_FREE_ALL(centred, all);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the %zu x %zu kernel", n, n);
    }
    double total = 0;
    for (size_t i = 0; i < n; ++i) {
        double sum = 0;
        for (size_t j = 0; j < n; ++j)
            sum += kernel[i * n + j];
        row_means[i] = sum / (double)n;
        total += row_means[i];
    }
    total /= (double)n;
    for (size_t i = 0; i < n; ++i)
        for (size_t j = 0; j < n; ++j) /* symmetrised: the caller's kernel may differ from K' by rounding */
            centred[i * n + j] = 0.5 * (kernel[i * n + j] + kernel[j * n + i]) - row_means[i] - row_means[j] + total;
    if (LAPACKE_dsyev(LAPACK_ROW_MAJOR, 'V', 'U', (lapack_int)n, centred, (lapack_int)n, all) != 0) {
        SK_FREE_ALL(centred, all);
        return sk_fail(error, SK_ERROR_LAPACK, "the kernel matrix's eigen-decomposition failed");
    }
    const double largest = all[n - 1];
    size_t kept = 0;
    for (size_t l = n; l-- > 0;)
        if (largest > 0 && all[l] > SK_KERNEL_RANK_TOLERANCE * largest)
            ++kept;
    for (size_t k = 0; k < kept; ++k) {
        const size_t l = n - 1 - k;
        values[k] = all[l];
        for (size_t i = 0; i < n; ++i)
            vectors[i * kept + k] = centred[i * n + l];
    }
    *rank = kept;
    SK_FREE_ALL(centred, all);
    return SK_OK;
}

sk_status sk_kernel_cca(double *mapping, double *offset, double *correlations, const double *kernel,
                        const double *targets, size_t example_count, size_t group_count, size_t dimension,
                        size_t basis_count, double ridge, int thread_count, sk_error *error)
{
    if (!mapping || !offset || !correlations || !kernel || !targets)
        return sk_fail(error, SK_ERROR_ARGUMENT, "kernel CCA arrays must not be null");
    if (example_count < 2 || group_count == 0 || dimension == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT,
                       "kernel CCA needs >= 2 examples, >= 1 group and a dimension >= 1 (got %zu, %zu, %zu)",
                       example_count, group_count, dimension);
    if (basis_count == 0 || basis_count > dimension)
        return sk_fail(error, SK_ERROR_ARGUMENT, "basis count %zu: expected 1 .. the target dimension %zu",
                       basis_count, dimension);
    if (!(ridge > 0) || !isfinite(ridge))
        return sk_fail(error, SK_ERROR_ARGUMENT, "ridge %g: kernel CCA needs a finite ridge > 0 (without one every "
                                                 "direction correlates perfectly)", ridge);
    size_t kernel_values, target_values;
    sk_status status = sk_array_size(&kernel_values, example_count, example_count, 1, "kernel", error);
    if (status == SK_OK)
        status = sk_array_size(&target_values, example_count, group_count, dimension, "target", error);
    if (status != SK_OK)
        return status;
    size_t bad = sk_first_non_finite(kernel, kernel_values);
    if (bad < kernel_values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "kernel entry (%zu, %zu) is a NaN or infinity",
                       bad / example_count, bad % example_count);
    bad = sk_first_non_finite(targets, target_values);
    if (bad < target_values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "example %zu's target %zu is a NaN or infinity",
                       bad / (group_count * dimension), bad / dimension % group_count);
    const size_t n = example_count;
    double *vectors = sk_allocate(n * n, sizeof *vectors), *values = sk_allocate(n, sizeof *values);
    double *row_means = sk_allocate(n, sizeof *row_means);
    if (!vectors || !values || !row_means) {
        SK_FREE_ALL(vectors, values, row_means);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for kernel CCA of %zu examples", n);
    }
    size_t rank = 0;
    status = centred_kernel_eigen(vectors, values, &rank, row_means, kernel, n, error);
    if (status == SK_OK) {
        kcca_task task = {.mapping = mapping, .offset = offset, .correlations = correlations, .targets = targets,
                          .eigenvectors = vectors, .eigenvalues = values, .kernel_row_means = row_means,
                          .example_count = n, .group_count = group_count, .dimension = dimension,
                          .basis_count = basis_count, .rank = rank, .ridge = ridge};
        sk_parallel_for(group_count, 1, thread_count, kcca_range, &task);
        for (size_t w = 0; w < SK_MAX_WORKERS && status == SK_OK; ++w)
            if (task.failed[w] != SK_OK)
                status = sk_fail(error, task.failed[w], "kernel CCA of group %zu failed (%s)", task.failed_group[w],
                                 task.failed[w] == SK_ERROR_MEMORY ? "out of memory" : "LAPACK");
    }
    SK_FREE_ALL(vectors, values, row_means);
    return status == SK_OK ? sk_succeed(error) : status;
}

/* ---- the Poisson translation solver ---------------------------------------------------------------------- */

typedef struct edge_fit_task {
    double *edge_weights;  /* per edge, its slots: the union of its endpoints' bones, then -1 (unused) */
    int32_t *edge_bones;
    const size_t *edge_offsets;
    const int32_t *offsets, *bones, *edges;
    const double *weights, *rest, *rotations, *positions;
    size_t vertex_count, example_count, bone_count, max_slots;
    double squared_error[SK_MAX_WORKERS];
    int failed[SK_MAX_WORKERS];
} edge_fit_task;

/* The union of the bones of vertices i and j into slots (returns their count), with each one's average weight
 * over the two endpoints (the fit's prior) in prior. */
static size_t edge_support(int32_t *slots, double *prior, const edge_fit_task *task, int32_t i, int32_t j)
{
    size_t count = 0;
    const int32_t ends[2] = {i, j};
    for (int e = 0; e < 2; ++e)
        for (int32_t k = task->offsets[ends[e]]; k < task->offsets[ends[e] + 1]; ++k) {
            size_t s = 0;
            while (s < count && slots[s] != task->bones[k])
                ++s;
            if (s == count)
                slots[count] = task->bones[k], prior[count++] = 0;
            prior[s] += 0.5 * task->weights[k];
        }
    return count;
}

/* Eq. 2.10 for one edge: min over w of sum_e |e^e - sum_b w_b R_b^e e^0|^2 + ridge |w - prior|^2. */
static int fit_edge(edge_fit_task *task, size_t edge, size_t worker, double *scratch)
{
    const int32_t i = task->edges[2 * edge], j = task->edges[2 * edge + 1];
    int32_t *slots = task->edge_bones + task->edge_offsets[edge];
    double *w = task->edge_weights + task->edge_offsets[edge];
    const size_t s = edge_support(slots, w, task, i, j);
    double *normal = scratch, *columns = normal + task->max_slots * task->max_slots;
    const double *vi = task->rest + 3 * (size_t)i, *vj = task->rest + 3 * (size_t)j;
    const double e0[3] = {vi[0] - vj[0], vi[1] - vj[1], vi[2] - vj[2]};
    memset(normal, 0, s * s * sizeof *normal);
    double rhs[64 * 2], edge_norm = 0;
    for (size_t a = 0; a < s; ++a)
        rhs[a] = 0;
    for (size_t e = 0; e < task->example_count; ++e) {
        const double *pi = task->positions + 3 * (e * task->vertex_count + (size_t)i);
        const double *pj = task->positions + 3 * (e * task->vertex_count + (size_t)j);
        const double target[3] = {pi[0] - pj[0], pi[1] - pj[1], pi[2] - pj[2]};
        edge_norm += target[0] * target[0] + target[1] * target[1] + target[2] * target[2];
        for (size_t a = 0; a < s; ++a) {
            const double *r = task->rotations + 9 * (e * task->bone_count + (size_t)slots[a]);
            for (int row = 0; row < 3; ++row)
                columns[3 * a + row] = r[3 * row] * e0[0] + r[3 * row + 1] * e0[1] + r[3 * row + 2] * e0[2];
        }
        for (size_t a = 0; a < s; ++a) {
            for (size_t b = 0; b < s; ++b)
                normal[a * s + b] += columns[3 * a] * columns[3 * b] + columns[3 * a + 1] * columns[3 * b + 1] +
                                     columns[3 * a + 2] * columns[3 * b + 2];
            rhs[a] += columns[3 * a] * target[0] + columns[3 * a + 1] * target[1] + columns[3 * a + 2] * target[2];
        }
    }
    /* The ridge pulls towards the endpoints' own weights, so an edge that turns with fewer bones than it has
     * (pitfall 4: 3 equations per example) keeps them; relative to the edge's size, so units do not matter. */
    const double ridge = SK_EDGE_RIDGE * (edge_norm > 0 ? edge_norm : 1);
    for (size_t a = 0; a < s; ++a) {
        normal[a * s + a] += ridge;
        rhs[a] += ridge * w[a];
    }
    if (LAPACKE_dposv(LAPACK_ROW_MAJOR, 'U', (lapack_int)s, 1, normal, (lapack_int)s, rhs, 1) != 0)
        return 0;
    memcpy(w, rhs, s * sizeof *w);
    for (size_t a = s; a < task->edge_offsets[edge + 1] - task->edge_offsets[edge]; ++a)
        slots[a] = -1, w[a] = 0; /* unused capacity: a bone both endpoints share is listed once */
    for (size_t e = 0; e < task->example_count; ++e) {
        const double *pi = task->positions + 3 * (e * task->vertex_count + (size_t)i);
        const double *pj = task->positions + 3 * (e * task->vertex_count + (size_t)j);
        double residual[3] = {pi[0] - pj[0], pi[1] - pj[1], pi[2] - pj[2]};
        for (size_t a = 0; a < s; ++a) {
            const double *r = task->rotations + 9 * (e * task->bone_count + (size_t)slots[a]);
            for (int row = 0; row < 3; ++row)
                residual[row] -= w[a] * (r[3 * row] * e0[0] + r[3 * row + 1] * e0[1] + r[3 * row + 2] * e0[2]);
        }
        task->squared_error[worker] += residual[0] * residual[0] + residual[1] * residual[1] + residual[2] * residual[2];
    }
    return 1;
}

static void edge_fit_range(void *context, size_t worker, size_t begin, size_t end)
{
    edge_fit_task *task = context;
    double *scratch = sk_allocate(task->max_slots * task->max_slots + 3 * task->max_slots, sizeof *scratch);
    if (!scratch) {
        task->failed[worker] = 1;
        return;
    }
    for (size_t edge = begin; edge < end && !task->failed[worker]; ++edge)
        task->failed[worker] = !fit_edge(task, edge, worker, scratch);
    free(scratch);
}

/* The rows of A (eq. 2.11, one unknown translation per bone, shared by x, y and z) and their right-hand sides'
 * dependence on the rotations: g[slot] is the 3-vector that R_{bone of slot} multiplies. Edge rows first. */
typedef struct poisson_row {
    size_t count;
    int32_t bones[128];
    double a[128];      /* A's entries in this row */
    double g[128][3];
} poisson_row;

static void add_vertex_terms(poisson_row *row, const edge_fit_task *task, int32_t vertex, double sign, double scale)
{
    const double *v = task->rest + 3 * (size_t)vertex;
    for (int32_t k = task->offsets[vertex]; k < task->offsets[vertex + 1]; ++k) {
        size_t s = 0;
        while (s < row->count && row->bones[s] != task->bones[k])
            ++s;
        if (s == row->count) {
            row->bones[s] = task->bones[k], row->a[s] = 0;
            row->g[s][0] = row->g[s][1] = row->g[s][2] = 0;
            ++row->count;
        }
        const double w = sign * scale * task->weights[k];
        row->a[s] += w;
        for (int c = 0; c < 3; ++c)
            row->g[s][c] -= w * v[c];
    }
}

static void edge_row(poisson_row *row, const edge_fit_task *task, size_t edge)
{
    const int32_t i = task->edges[2 * edge], j = task->edges[2 * edge + 1];
    row->count = 0;
    add_vertex_terms(row, task, i, 1, 1);
    add_vertex_terms(row, task, j, -1, 1);
    const double *vi = task->rest + 3 * (size_t)i, *vj = task->rest + 3 * (size_t)j;
    const double e0[3] = {vi[0] - vj[0], vi[1] - vj[1], vi[2] - vj[2]};
    for (size_t k = task->edge_offsets[edge]; k < task->edge_offsets[edge + 1] && task->edge_bones[k] >= 0; ++k) {
        size_t s = 0; /* every fitted bone is an endpoint's bone, so it is in the row already */
        while (row->bones[s] != task->edge_bones[k])
            ++s;
        for (int c = 0; c < 3; ++c)
            row->g[s][c] += task->edge_weights[k] * e0[c];
    }
}

/* Accumulates one row into N = A'A (n x n) and Y = A' G (n x n x 3), Y[a][b] the 3-vector R_b multiplies. */
static void accumulate_row(double *normal, double *y, const poisson_row *row, size_t n)
{
    for (size_t p = 0; p < row->count; ++p) {
        const size_t a = (size_t)row->bones[p];
        for (size_t q = 0; q < row->count; ++q) {
            const size_t b = (size_t)row->bones[q];
            normal[a * n + b] += row->a[p] * row->a[q];
            for (int c = 0; c < 3; ++c)
                y[(a * n + b) * 3 + c] += row->a[p] * row->g[q][c];
        }
    }
}

static sk_status check_translation_inputs(const sk_influences *influences, const double *rest, const double *weights,
                                          const int32_t *edges, size_t edge_count, const double *rotations,
                                          const double *positions, size_t example_count, size_t bone_count,
                                          const int32_t *handles, size_t handle_count, double beta, sk_error *error)
{
    if (!influences || !rest || !weights || !edges || !rotations || !positions || !handles)
        return sk_fail(error, SK_ERROR_ARGUMENT, "translation solver arrays must not be null");
    if (edge_count == 0 || example_count == 0 || bone_count == 0 || handle_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the translation solver needs edges, examples, bones and at least "
                                                 "one handle (the edges fix translations only up to a shift)");
    if (!(beta > 0) || !isfinite(beta))
        return sk_fail(error, SK_ERROR_ARGUMENT, "beta %g: must be finite and > 0 (with beta = 0 the translations "
                                                 "are free to shift)", beta);
    sk_status status = sk_validate_influences(influences, bone_count, error);
    if (status != SK_OK)
        return status;
    const size_t v = influences->vertex_count;
    for (size_t i = 0; i < v; ++i)
        if (influences->offsets[i + 1] - influences->offsets[i] > 64)
            return sk_fail(error, SK_ERROR_ARGUMENT, "vertex %zu has more than 64 influences", i);
    for (size_t k = 0; k < 2 * edge_count; ++k)
        if (edges[k] < 0 || (size_t)edges[k] >= v)
            return sk_fail(error, SK_ERROR_INDEX, "edge %zu's vertex %d is outside 0 .. %zu", k / 2, edges[k], v - 1);
    for (size_t l = 0; l < handle_count; ++l)
        if (handles[l] < 0 || (size_t)handles[l] >= v)
            return sk_fail(error, SK_ERROR_INDEX, "handle %zu's vertex %d is outside 0 .. %zu", l, handles[l], v - 1);
    size_t values;
    status = sk_array_size(&values, example_count, v, 3, "example position", error);
    if (status != SK_OK)
        return status;
    if (!sk_all_finite(positions, values) || !sk_all_finite(rest, 3 * v) || !sk_all_finite(weights, influences->influence_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "an example position, rest position or weight is a NaN or infinity");
    status = sk_array_size(&values, example_count, bone_count, 9, "rotation", error);
    if (status == SK_OK && !sk_all_finite(rotations, values))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "rotation %zu is a NaN or infinity",
                       sk_first_non_finite(rotations, values) / 9);
    return status;
}

/* Factors N (Cholesky) and solves N X = rhs for the translation matrices. A bone no vertex uses gets t = 0; a
 * used bone that nothing constrains is a part of the mesh without a handle. */
static sk_status solve_translations(double *y, double *z, double *normal, const unsigned char *used, size_t n,
                                    size_t handle_count, sk_error *error)
{
    double largest = 0;
    for (size_t a = 0; a < n; ++a)
        largest = normal[a * n + a] > largest ? normal[a * n + a] : largest;
    for (size_t a = 0; a < n; ++a) {
        if (normal[a * n + a] > 0)
            continue;
        if (used[a])
            return sk_fail(error, SK_ERROR_SINGULAR, "bone %zu's translation is undetermined: its part of the mesh "
                                                     "holds no handle", a);
        normal[a * n + a] = largest > 0 ? largest : 1;
    }
    if (LAPACKE_dpotrf(LAPACK_ROW_MAJOR, 'U', (lapack_int)n, normal, (lapack_int)n) != 0)
        return sk_fail(error, SK_ERROR_SINGULAR, "the translation system is singular: a part of the mesh holds no handle");
    for (size_t a = 0; a < n; ++a) /* a pivot this small means a gauge freedom that rounding hid */
        if (normal[a * n + a] * normal[a * n + a] < 1e-12 * largest)
            return sk_fail(error, SK_ERROR_SINGULAR,
                           "the translation system is singular at bone %zu: a part of the mesh holds no handle", a);
    if (LAPACKE_dpotrs(LAPACK_ROW_MAJOR, 'U', (lapack_int)n, (lapack_int)(3 * n), normal, (lapack_int)n, y,
                       (lapack_int)(3 * n)) != 0 ||
        LAPACKE_dpotrs(LAPACK_ROW_MAJOR, 'U', (lapack_int)n, (lapack_int)handle_count, normal, (lapack_int)n, z,
                       (lapack_int)handle_count) != 0)
        return sk_fail(error, SK_ERROR_LAPACK, "the translation solve failed");
    return SK_OK;
}

sk_status sk_handle_translation_solver(double *translation_rotations, double *translation_handles,
                                       double *edge_error, const sk_influences *influences,
                                       const double *rest_positions, const double *weights, const int32_t *edges,
                                       size_t edge_count, const double *rotations, const double *example_positions,
                                       size_t example_count, size_t bone_count, const int32_t *handle_vertices,
                                       size_t handle_count, double beta, int thread_count, sk_error *error)
{
    if (!translation_rotations || !translation_handles || !edge_error)
        return sk_fail(error, SK_ERROR_ARGUMENT, "translation solver outputs must not be null");
    sk_status status = check_translation_inputs(influences, rest_positions, weights, edges, edge_count, rotations,
                                                example_positions, example_count, bone_count, handle_vertices,
                                                handle_count, beta, error);
    if (status != SK_OK)
        return status;
    const size_t n = bone_count;
    size_t *edge_offsets = sk_allocate(edge_count + 1, sizeof *edge_offsets);
    size_t max_slots = 1;
    if (edge_offsets) {
        edge_offsets[0] = 0;
        for (size_t k = 0; k < edge_count; ++k) {
            const int32_t i = edges[2 * k], j = edges[2 * k + 1];
            const size_t slots = (size_t)(influences->offsets[i + 1] - influences->offsets[i] +
                                          influences->offsets[j + 1] - influences->offsets[j]);
            edge_offsets[k + 1] = edge_offsets[k] + slots;
            max_slots = slots > max_slots ? slots : max_slots;
        }
    }
    size_t y_values;
    status = sk_array_size(&y_values, n, n, 3, "translation matrix", error);
    if (status != SK_OK) {
        free(edge_offsets);
        return status;
    }
    double *edge_weights = edge_offsets ? sk_allocate(edge_offsets[edge_count], sizeof *edge_weights) : NULL;
    int32_t *edge_bones = edge_offsets ? sk_allocate(edge_offsets[edge_count], sizeof *edge_bones) : NULL;
    double *normal = sk_allocate_zeroed(n * n, sizeof *normal);
    poisson_row *row = sk_allocate(1, sizeof *row);
    unsigned char *used = sk_allocate_zeroed(n, 1);
    if (!edge_offsets || !edge_weights || !edge_bones || !normal || !row || !used) {
        SK_FREE_ALL(edge_offsets, edge_weights, edge_bones, normal, row, used);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the translation solver");
    }
    for (size_t k = 0; k < influences->influence_count; ++k)
        used[influences->bones[k]] |= weights[k] != 0;
    edge_fit_task task = {.edge_weights = edge_weights, .edge_bones = edge_bones, .edge_offsets = edge_offsets,
                          .offsets = influences->offsets, .bones = influences->bones, .edges = edges,
                          .weights = weights, .rest = rest_positions, .rotations = rotations,
                          .positions = example_positions, .vertex_count = influences->vertex_count,
                          .example_count = example_count, .bone_count = n, .max_slots = max_slots};
    sk_parallel_for(edge_count, SK_SOLVE_ITEMS_PER_WORKER, thread_count, edge_fit_range, &task);
    double squared = 0;
    for (size_t w = 0; w < SK_MAX_WORKERS; ++w) {
        squared += task.squared_error[w];
        if (task.failed[w] && status == SK_OK)
            status = sk_fail(error, SK_ERROR_LAPACK, "an edge's skinning-weight fit (eq. 2.10) failed");
    }
    *edge_error = sqrt(squared / (double)(edge_count * example_count));
    double *y = translation_rotations, *z = translation_handles;
    memset(y, 0, y_values * sizeof *y);
    memset(z, 0, n * handle_count * sizeof *z);
    for (size_t k = 0; k < edge_count && status == SK_OK; ++k) {
        edge_row(row, &task, k);
        accumulate_row(normal, y, row, n);
    }
    /* Handle rows, weighted by sqrt(beta): A's entries sqrt(beta) w, right-hand side sqrt(beta) (c - sum w R v). */
    const double root_beta = sqrt(beta);
    for (size_t l = 0; l < handle_count && status == SK_OK; ++l) {
        row->count = 0;
        add_vertex_terms(row, &task, handle_vertices[l], 1, root_beta);
        accumulate_row(normal, y, row, n);
        for (size_t p = 0; p < row->count; ++p)
            z[(size_t)row->bones[p] * handle_count + l] += row->a[p] * root_beta;
    }
    if (status == SK_OK)
        status = solve_translations(y, z, normal, used, n, handle_count, error);
    SK_FREE_ALL(edge_offsets, edge_weights, edge_bones, normal, row, used);
    return status == SK_OK ? sk_succeed(error) : status;
}

/* ---- control-point suggestion (section 2.3, after Meyer & Anderson) -------------------------------------------- */

#define SK_VARIMAX_ITERATIONS 100
#define SK_VARIMAX_TOLERANCE 1e-8

/* Kaiser's varimax rotation of loadings (p x k, row-major) in place: the orthogonal rotation maximising the
 * variance of the squared loadings per column, which concentrates each component on few vertices. */
static int varimax(double *loadings, size_t p, size_t k, double *scratch)
{
    double *rotation = scratch, *rotated = rotation + k * k, *gradient = rotated + p * k, *u = gradient + k * k;
    double *vt = u + k * k, *singular = vt + k * k, *superb = singular + k, *column_sums = superb + k;
    for (size_t i = 0; i < k * k; ++i)
        rotation[i] = i % (k + 1) == 0;
    double objective = 0;
    for (int iteration = 0; iteration < SK_VARIMAX_ITERATIONS; ++iteration) {
        multiply(rotated, loadings, rotation, p, k, k, 0, 0);
        for (size_t c = 0; c < k; ++c) {
            column_sums[c] = 0;
            for (size_t r = 0; r < p; ++r)
                column_sums[c] += rotated[r * k + c] * rotated[r * k + c];
        }
        for (size_t r = 0; r < p; ++r)
            for (size_t c = 0; c < k; ++c) {
                const double x = rotated[r * k + c];
                rotated[r * k + c] = x * x * x - x * column_sums[c] / (double)p;
            }
        multiply(gradient, loadings, rotated, k, p, k, 1, 0);
        if (LAPACKE_dgesvd(LAPACK_ROW_MAJOR, 'A', 'A', (lapack_int)k, (lapack_int)k, gradient, (lapack_int)k,
                           singular, u, (lapack_int)k, vt, (lapack_int)k, superb) != 0)
            return 0;
        multiply(rotation, u, vt, k, k, k, 0, 0);
        double total = 0;
        for (size_t c = 0; c < k; ++c)
            total += singular[c];
        if (total < objective * (1 + SK_VARIMAX_TOLERANCE))
            break;
        objective = total;
    }
    multiply(rotated, loadings, rotation, p, k, k, 0, 0);
    memcpy(loadings, rotated, p * k * sizeof *loadings);
    return 1;
}

/* The main direction of a component's per-vertex 3-vectors (the top eigenvector of sum l l', of either sign); 0
 * when LAPACK fails. */
static int main_direction(double direction[3], const double *component, size_t stride, size_t vertex_count)
{
    double scatter[9] = {0}, values[3];
    for (size_t v = 0; v < vertex_count; ++v)
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b)
                scatter[3 * a + b] += component[(3 * v + a) * stride] * component[(3 * v + b) * stride];
    if (LAPACKE_dsyev(LAPACK_ROW_MAJOR, 'V', 'U', 3, scatter, 3, values) != 0)
        return 0;
    for (int a = 0; a < 3; ++a)
        direction[a] = scatter[3 * a + 2];
    return 1;
}

/* Picks the unchosen vertex of largest (sign +1) or smallest (-1) score along direction; *extent gets its score
 * times sign. */
static int32_t extreme_vertex(double *extent, const double *component, size_t stride, size_t vertex_count,
                              const double direction[3], double sign, const int32_t *chosen, size_t chosen_count)
{
    int32_t best = -1;
    double best_score = 0;
    for (size_t v = 0; v < vertex_count; ++v) {
        int taken = 0;
        for (size_t c = 0; c < chosen_count && !taken; ++c)
            taken = chosen[c] == (int32_t)v;
        if (taken)
            continue;
        const double score = sign * (component[3 * v * stride] * direction[0] +
                                     component[(3 * v + 1) * stride] * direction[1] +
                                     component[(3 * v + 2) * stride] * direction[2]);
        if (best < 0 || score > best_score)
            best = (int32_t)v, best_score = score;
    }
    *extent = best_score;
    return best;
}

sk_status sk_suggest_handles(int32_t *handle_vertices, const double *frames, size_t frame_count, size_t vertex_count,
                             size_t handle_count, sk_error *error)
{
    if (!handle_vertices || !frames)
        return sk_fail(error, SK_ERROR_ARGUMENT, "suggestion arrays must not be null");
    if (handle_count == 0 || handle_count > vertex_count || vertex_count > INT32_MAX)
        return sk_fail(error, SK_ERROR_ARGUMENT, "handle count %zu: must be between 1 and the vertex count (%zu)",
                       handle_count, vertex_count);
    const size_t k = (handle_count + 1) / 2;
    if (frame_count < k + 1)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%zu frames: suggesting %zu handles needs at least %zu (one more "
                                                 "than the %zu components)", frame_count, handle_count, k + 1, k);
    size_t values, p = 3 * vertex_count;
    sk_status status = sk_array_size(&values, frame_count, vertex_count, 3, "frame position", error);
    if (status != SK_OK)
        return status;
    const size_t bad = sk_first_non_finite(frames, values);
    if (bad < values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "frame %zu, vertex %zu: a NaN or infinity", bad / p, bad % p / 3);
    const size_t f = frame_count;
    double *centred = sk_allocate(values, sizeof *centred), *gram = sk_allocate(f * f, sizeof *gram);
    double *eigen = sk_allocate(f, sizeof *eigen), *loadings = sk_allocate(p * k, sizeof *loadings);
    double *scratch = sk_allocate(4 * k * k + p * k + 3 * k, sizeof *scratch);
    if (!centred || !gram || !eigen || !loadings || !scratch) {
        SK_FREE_ALL(centred, gram, eigen, loadings, scratch);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the PCA of %zu frames", f);
    }
    /* PCA through the frames' Gram matrix (f x f, far smaller than the 3V x 3V covariance): loadings
     * X' u_i = s_i v_i are the components scaled by their singular values. */
    double magnitude = 0; /* sum of squares, the scale below which a variance is rounding */
    for (size_t c = 0; c < p; ++c) {
        double mean = 0;
        for (size_t e = 0; e < f; ++e)
            mean += frames[e * p + c], magnitude += frames[e * p + c] * frames[e * p + c];
        mean /= (double)f;
        for (size_t e = 0; e < f; ++e)
            centred[e * p + c] = frames[e * p + c] - mean;
    }
    for (size_t a = 0; a < f; ++a)
        for (size_t b = a; b < f; ++b) {
            double sum = 0;
            for (size_t c = 0; c < p; ++c)
                sum += centred[a * p + c] * centred[b * p + c];
            gram[a * f + b] = gram[b * f + a] = sum;
        }
    if (LAPACKE_dsyev(LAPACK_ROW_MAJOR, 'V', 'U', (lapack_int)f, gram, (lapack_int)f, eigen) != 0)
        status = sk_fail(error, SK_ERROR_LAPACK, "the frames' PCA failed");
    else if (!(eigen[f - 1] > 1e-24 * magnitude))
        status = sk_fail(error, SK_ERROR_ARGUMENT, "the frames do not move, so there is nothing to place handles on");
    for (size_t i = 0; i < k && status == SK_OK; ++i)
        for (size_t c = 0; c < p; ++c) {
            double sum = 0;
            for (size_t e = 0; e < f; ++e)
                sum += centred[e * p + c] * gram[e * f + (f - 1 - i)];
            loadings[c * k + i] = sum;
        }
    if (status == SK_OK && !varimax(loadings, p, k, scratch))
        status = sk_fail(error, SK_ERROR_LAPACK, "the varimax rotation failed");
    size_t chosen = 0;
    for (size_t i = 0; i < k && status == SK_OK; ++i) {
        double direction[3];
        if (!main_direction(direction, loadings + i, k, vertex_count)) {
            status = sk_fail(error, SK_ERROR_LAPACK, "component %zu's direction failed", i);
            break;
        }
        /* The component's sign is arbitrary too: its farther extreme comes first, then the other side's. */
        double high, low;
        const double *component = loadings + i;
        const int32_t top = extreme_vertex(&high, component, k, vertex_count, direction, 1, handle_vertices, chosen);
        const int32_t bottom = extreme_vertex(&low, component, k, vertex_count, direction, -1, handle_vertices, chosen);
        const double first_sign = low > high ? -1 : 1;
        handle_vertices[chosen++] = first_sign > 0 ? top : bottom;
        if (chosen < handle_count) {
            double ignored;
            handle_vertices[chosen] = extreme_vertex(&ignored, component, k, vertex_count, direction, -first_sign,
                                                     handle_vertices, chosen);
            ++chosen;
        }
    }
    SK_FREE_ALL(centred, gram, eigen, loadings, scratch);
    return status == SK_OK ? sk_succeed(error) : status;
}
