/*
 * The tangent map's mip chain (Merry 2007, section 7.5 and appendix A.1): each texel of the next level averages a
 * 2x2 block. Its tangent pairs (a_i, b_i), 4-vectors per bone on the union S of the block's bones, are fitted by one
 * plane, the bivector fit of A.1 with A = sum_i (a_i b_i^T - b_i a_i^T) (A.2). In the metric of the pose statistics
 * (A.1.2), the top singular pair (u, v) of C A C^T with C^T C = P gives the plane's P-orthonormal basis
 * a = A C^T v / s, b = -A C^T u / s (A.7, A.8); a and b lie in the range of A, so only P's sub-block on S is needed
 * and C is its symmetric square root. Without statistics the plane is the span of A's own top pair (Euclidean).
 * The texel keeps the block's mean pair projected onto the plane (P-orthogonally in the metric), so its tangents
 * stay aligned with their neighbours' (run-time interpolation is linear) and bones absent from the block stay
 * absent. SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_bake_internal.h"
#include "sk_internal.h"

#define MAX_BLOCK_DIMENSION 256 /* 4 x the largest union of a block's bones */

typedef struct mip_task {
    int32_t *counts_out, *bones_out;
    double *tangents_out;
    const int32_t *counts, *bones;
    const double *tangents;
    const double *metric; /* P's 4x4 blocks, (j * bone_count + k) * 16, or NULL: Euclidean */
    size_t bone_count;
    size_t size, max_influences;
    size_t overfull[SK_MAX_WORKERS], first_overfull[SK_MAX_WORKERS];
    int lapack_failed[SK_MAX_WORKERS];
} mip_task;

typedef struct block_workspace {
    double a[4][MAX_BLOCK_DIMENSION], b[4][MAX_BLOCK_DIMENSION];
    double matrix[MAX_BLOCK_DIMENSION * MAX_BLOCK_DIMENSION], u[MAX_BLOCK_DIMENSION * MAX_BLOCK_DIMENSION];
    double vt[MAX_BLOCK_DIMENSION * MAX_BLOCK_DIMENSION], singular[MAX_BLOCK_DIMENSION], superb[MAX_BLOCK_DIMENSION];
    /* the metric fit's P_S, its eigenvectors, C = P_S^(1/2), A C and C A C */
    double p[MAX_BLOCK_DIMENSION * MAX_BLOCK_DIMENSION], eigenvectors[MAX_BLOCK_DIMENSION * MAX_BLOCK_DIMENSION];
    double root[MAX_BLOCK_DIMENSION * MAX_BLOCK_DIMENSION], ac[MAX_BLOCK_DIMENSION * MAX_BLOCK_DIMENSION];
    double cac[MAX_BLOCK_DIMENSION * MAX_BLOCK_DIMENSION], eigen[MAX_BLOCK_DIMENSION];
} block_workspace;

static size_t slot_of(const int32_t *set, size_t size, int32_t bone)
{
    size_t slot = 0;
    while (slot < size && set[slot] != bone)
        ++slot;
    return slot;
}

/* Projects x (n) onto the span of the orthonormal u and v. */
static void project(double *x, const double *u, const double *v, size_t n)
{
    double along_u = 0, along_v = 0;
    for (size_t k = 0; k < n; ++k) {
        along_u += x[k] * u[k];
        along_v += x[k] * v[k];
    }
    for (size_t k = 0; k < n; ++k)
        x[k] = along_u * u[k] + along_v * v[k];
}

/* The square n x n matrix product out = x y (column-major). */
static void multiply(double *out, const double *x, const double *y, size_t n)
{
    for (size_t j = 0; j < n; ++j)
        for (size_t i = 0; i < n; ++i) {
            double sum = 0;
            for (size_t k = 0; k < n; ++k)
                sum += x[k * n + i] * y[j * n + k];
            out[j * n + i] = sum;
        }
}

/* The fit multiplies tangents with tangents and with the metric (C A C): entries beyond this would overflow to
 * infinity there, and LAPACK's SVD does not return on a matrix of NaN (the fuzz pass found one that never did). */
#define MAX_FIT_MAGNITUDE 1e75

/* The index of the first of values beyond limit in magnitude; SIZE_MAX when none is. */
static size_t first_beyond(const double *values, size_t count, double limit)
{
    for (size_t i = 0; i < count; ++i)
        if (fabs(values[i]) > limit)
            return i;
    return SIZE_MAX;
}

/* out = m x for the n x n column-major m. */
static void apply(double *out, const double *m, const double *x, size_t n)
{
    for (size_t i = 0; i < n; ++i) {
        double sum = 0;
        for (size_t k = 0; k < n; ++k)
            sum += m[k * n + i] * x[k];
        out[i] = sum;
    }
}

/* The Euclidean fit: mean_a and mean_b projected onto the span of A's (work->matrix) top singular pair; 0 when
 * LAPACK failed. */
static int euclidean_fit(block_workspace *work, size_t n, double *mean_a, double *mean_b)
{
    const lapack_int info = LAPACKE_dgesvd(LAPACK_COL_MAJOR, 'S', 'S', (lapack_int)n, (lapack_int)n, work->matrix,
                                           (lapack_int)n, work->singular, work->u, (lapack_int)n, work->vt,
                                           (lapack_int)n, work->superb);
    if (info != 0)
        return 0;
    if (work->singular[0] > 0) {
        double v[MAX_BLOCK_DIMENSION];
        for (size_t k = 0; k < n; ++k)
            v[k] = work->vt[k * n]; /* row 0 of V^T, column-major */
        project(mean_a, work->u, v, n);
        project(mean_b, work->u, v, n);
    }
    return 1;
}

/* The fit in the metric (A.1.2): C = P_S^(1/2) from the eigen-decomposition of P's sub-block on the block's bones,
 * the top singular pair (u, v) of C A C, a = A C v / s and b = -A C u / s, and the mean pair projected
 * P-orthogonally onto span(a, b): x -> a (a^T P x) + b (b^T P x). A plane of no extent in the metric (s ~ 0: the
 * block moves only along P's null space) keeps the Euclidean fit. 0 when LAPACK failed. */
static int metric_fit(const mip_task *task, block_workspace *work, const int32_t *set, size_t set_size,
                      double *mean_a, double *mean_b)
{
    const size_t n = 4 * set_size;
    for (size_t s = 0; s < set_size; ++s)
        for (size_t t = 0; t < set_size; ++t) {
            const double *block = task->metric + ((size_t)set[s] * task->bone_count + (size_t)set[t]) * 16;
            for (size_t r = 0; r < 4; ++r)
                for (size_t q = 0; q < 4; ++q)
                    work->p[(4 * t + q) * n + 4 * s + r] = block[4 * r + q];
        }
    memcpy(work->eigenvectors, work->p, n * n * sizeof(double));
    if (LAPACKE_dsyev(LAPACK_COL_MAJOR, 'V', 'U', (lapack_int)n, work->eigenvectors, (lapack_int)n, work->eigen) != 0)
        return 0;
    const double *q = work->eigenvectors;
    double largest = 0, extent = 0;
    for (size_t k = 0; k < n; ++k)
        largest = fmax(largest, work->eigen[k]);
    for (size_t j = 0; j < n; ++j)
        for (size_t i = 0; i < n; ++i) {
            double sum = 0;
            for (size_t k = 0; k < n; ++k)
                sum += q[k * n + i] * sqrt(fmax(work->eigen[k], 0)) * q[k * n + j];
            work->root[j * n + i] = sum;
            extent += work->matrix[j * n + i] * work->matrix[j * n + i];
        }
    multiply(work->ac, work->matrix, work->root, n); /* A C */
    multiply(work->cac, work->root, work->ac, n);    /* C A C */
    if (LAPACKE_dgesvd(LAPACK_COL_MAJOR, 'S', 'S', (lapack_int)n, (lapack_int)n, work->cac, (lapack_int)n,
                       work->singular, work->u, (lapack_int)n, work->vt, (lapack_int)n, work->superb) != 0)
        return 0;
    const double sigma = work->singular[0];
    if (!(sigma > 1e-12 * sqrt(extent) * largest))
        return euclidean_fit(work, n, mean_a, mean_b);
    double top_v[MAX_BLOCK_DIMENSION], a[MAX_BLOCK_DIMENSION], b[MAX_BLOCK_DIMENSION], px[MAX_BLOCK_DIMENSION];
    for (size_t k = 0; k < n; ++k)
        top_v[k] = work->vt[k * n]; /* row 0 of V^T */
    apply(a, work->ac, top_v, n);
    apply(b, work->ac, work->u, n); /* column 0 of U */
    for (size_t k = 0; k < n; ++k)
        a[k] /= sigma, b[k] /= -sigma;
    double *means[2] = {mean_a, mean_b};
    for (int m = 0; m < 2; ++m) {
        apply(px, work->p, means[m], n);
        double along_a = 0, along_b = 0;
        for (size_t k = 0; k < n; ++k)
            along_a += a[k] * px[k], along_b += b[k] * px[k];
        for (size_t k = 0; k < n; ++k)
            means[m][k] = along_a * a[k] + along_b * b[k];
    }
    return 1;
}

/* One output texel from its (up to) four children; 0 when LAPACK failed. */
static int average_block(mip_task *task, block_workspace *work, size_t worker, size_t column, size_t row)
{
    const size_t fine = task->size, coarse = fine / 2, capacity = task->max_influences, out = row * coarse + column;
    int32_t set[4 * 64];
    size_t set_size = 0, children[4], child_count = 0;
    for (size_t dy = 0; dy < 2; ++dy)
        for (size_t dx = 0; dx < 2; ++dx) {
            const size_t texel = (2 * row + dy) * fine + 2 * column + dx;
            if (task->counts[texel] <= 0)
                continue;
            children[child_count++] = texel;
            for (int32_t k = 0; k < task->counts[texel]; ++k)
                sk_insert_sorted_bone(set, &set_size, task->bones[texel * capacity + (size_t)k]);
        }
    task->counts_out[out] = 0;
    memset(task->bones_out + out * capacity, 0, capacity * sizeof(int32_t));
    memset(task->tangents_out + 8 * out * capacity, 0, 8 * capacity * sizeof(double));
    if (child_count == 0)
        return 1;
    if (set_size > capacity) {
        if (task->overfull[worker]++ == 0)
            task->first_overfull[worker] = out;
        return 1;
    }
    const size_t n = 4 * set_size;
    double mean_a[MAX_BLOCK_DIMENSION] = {0}, mean_b[MAX_BLOCK_DIMENSION] = {0};
    for (size_t c = 0; c < child_count; ++c) {
        const size_t texel = children[c];
        memset(work->a[c], 0, n * sizeof(double));
        memset(work->b[c], 0, n * sizeof(double));
        for (int32_t k = 0; k < task->counts[texel]; ++k) {
            const size_t slot = slot_of(set, set_size, task->bones[texel * capacity + (size_t)k]);
            const double *pair = task->tangents + 8 * (texel * capacity + (size_t)k);
            for (int d = 0; d < 4; ++d) {
                work->a[c][4 * slot + (size_t)d] += pair[d];
                work->b[c][4 * slot + (size_t)d] += pair[4 + d];
            }
        }
        for (size_t k = 0; k < n; ++k) {
            mean_a[k] += work->a[c][k] / (double)child_count;
            mean_b[k] += work->b[c][k] / (double)child_count;
        }
    }
    /* A = sum (a b^T - b a^T), column-major for LAPACK (antisymmetric, so its transpose is -A: no matter). */
    for (size_t i = 0; i < n; ++i)
        for (size_t j = 0; j < n; ++j) {
            double value = 0;
            for (size_t c = 0; c < child_count; ++c)
                value += work->a[c][i] * work->b[c][j] - work->b[c][i] * work->a[c][j];
            work->matrix[j * n + i] = value;
        }
    const int fitted = task->metric ? metric_fit(task, work, set, set_size, mean_a, mean_b)
                                    : euclidean_fit(work, n, mean_a, mean_b);
    if (!fitted) {
        task->lapack_failed[worker] = 1;
        return 0;
    }
    for (size_t slot = 0; slot < set_size; ++slot) {
        task->bones_out[out * capacity + slot] = set[slot];
        double *pair = task->tangents_out + 8 * (out * capacity + slot);
        for (int d = 0; d < 4; ++d) {
            pair[d] = mean_a[4 * slot + (size_t)d];
            pair[4 + d] = mean_b[4 * slot + (size_t)d];
        }
    }
    task->counts_out[out] = (int32_t)set_size;
    return 1;
}

static void mip_rows(void *argument, size_t worker, size_t begin, size_t end)
{
    mip_task *task = argument;
    block_workspace *work = malloc(sizeof *work);
    if (!work) {
        task->lapack_failed[worker] = -1;
        return;
    }
    for (size_t row = begin; row < end; ++row)
        for (size_t column = 0; column < task->size / 2; ++column)
            if (!average_block(task, work, worker, column, row))
                break;
    free(work);
}

sk_status sk_tangent_map_downsample(int32_t *counts_out, int32_t *bones_out, double *tangents_out,
                                    size_t half_size, const int32_t *counts, const int32_t *bones,
                                    const double *tangents, size_t size, size_t max_influences,
                                    const double *metric, size_t bone_count, int thread_count, sk_error *error)
{
    if (!counts_out || !bones_out || !tangents_out || !counts || !bones || !tangents)
        return sk_fail(error, SK_ERROR_ARGUMENT, "an array is NULL");
    if (size < 2 || size % 2 != 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "size %zu must be even and at least 2", size);
    if (half_size != size / 2)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the output's size %zu is not half of %zu", half_size, size);
    if (max_influences < 1 || max_influences > MAX_BLOCK_DIMENSION / 4)
        return sk_fail(error, SK_ERROR_ARGUMENT, "max_influences %zu is outside 1-%d", max_influences,
                       MAX_BLOCK_DIMENSION / 4);
    for (size_t texel = 0; texel < size * size; ++texel) {
        if (counts[texel] < 0 || (size_t)counts[texel] > max_influences)
            return sk_fail(error, SK_ERROR_INDEX, "texel %zu has %d influences, outside 0-%zu", texel, counts[texel],
                           max_influences);
        for (int32_t k = 0; k < counts[texel]; ++k)
            if (bones[texel * max_influences + (size_t)k] < 0 ||
                (metric && (size_t)bones[texel * max_influences + (size_t)k] >= bone_count))
                return sk_fail(error, SK_ERROR_INDEX, "texel %zu: bone %d is outside %s", texel,
                               bones[texel * max_influences + (size_t)k],
                               metric ? "the pose statistics' skeleton" : "0 or more");
    }
    if (!sk_all_finite(tangents, 8 * size * size * max_influences))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "a tangent is not finite");
    const size_t too_large = first_beyond(tangents, 8 * size * size * max_influences, MAX_FIT_MAGNITUDE);
    if (too_large != SIZE_MAX)
        return sk_fail(error, SK_ERROR_ARGUMENT, "tangent entry %zu is %g: the block fit multiplies entries, so they "
                       "must be at most %g in magnitude", too_large, tangents[too_large], MAX_FIT_MAGNITUDE);
    if (metric) {
        size_t entries;
        sk_status status = sk_array_size(&entries, bone_count, bone_count, 16, "the metric's blocks", error);
        if (status != SK_OK)
            return status;
        if (!sk_all_finite(metric, entries))
            return sk_fail(error, SK_ERROR_NOT_FINITE, "an entry of the metric P is not finite");
        const size_t metric_too_large = first_beyond(metric, entries, MAX_FIT_MAGNITUDE);
        if (metric_too_large != SIZE_MAX)
            return sk_fail(error, SK_ERROR_ARGUMENT, "metric entry %zu is %g: it must be at most %g in magnitude",
                           metric_too_large, metric[metric_too_large], MAX_FIT_MAGNITUDE);
    }
    mip_task task = {counts_out, bones_out, tangents_out, counts, bones, tangents, metric, bone_count, size,
                     max_influences, {0}, {0}, {0}};
    sk_parallel_for(size / 2, 1, thread_count, mip_rows, &task);
    size_t overfull = 0, first = SIZE_MAX;
    for (size_t w = 0; w < SK_MAX_WORKERS; ++w) {
        if (task.lapack_failed[w] < 0)
            return sk_fail(error, SK_ERROR_MEMORY, "out of memory for a block's workspace");
        if (task.lapack_failed[w])
            return sk_fail(error, SK_ERROR_LAPACK, "dgesvd failed on a 2x2 block's bivector fit");
        overfull += task.overfull[w];
        if (task.overfull[w] && task.first_overfull[w] < first)
            first = task.first_overfull[w];
    }
    if (overfull > 0)
        return sk_fail(error, SK_ERROR_ARGUMENT,
                       "%zu texels of the next level need more than max_influences = %zu bones, the first at column "
                       "%zu, row %zu", overfull, max_influences, first % (size / 2), first / (size / 2));
    return sk_succeed(error);
}
