/*
 * The tangent map's mip chain (Merry 2007, section 7.5 and appendix A.1): each texel of the next level averages a
 * 2x2 block. Its tangent pairs (a_i, b_i), 4-vectors per bone on the union of the block's bones, are fitted by one
 * plane, the bivector fit of A.1: the span of the top singular pair (u, v) of the antisymmetric A = sum_i
 * (a_i b_i^T - b_i a_i^T) (A.2). The texel keeps the block's mean pair projected onto that plane, so its tangents stay
 * aligned with their neighbours' (run-time interpolation is linear) and bones absent from the block stay absent.
 * SPDX-License-Identifier: GPL-3.0-or-later
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
    size_t size, max_influences;
    size_t overfull[SK_MAX_WORKERS], first_overfull[SK_MAX_WORKERS];
    int lapack_failed[SK_MAX_WORKERS];
} mip_task;

typedef struct block_workspace {
    double a[4][MAX_BLOCK_DIMENSION], b[4][MAX_BLOCK_DIMENSION];
    double matrix[MAX_BLOCK_DIMENSION * MAX_BLOCK_DIMENSION], u[MAX_BLOCK_DIMENSION * MAX_BLOCK_DIMENSION];
    double vt[MAX_BLOCK_DIMENSION * MAX_BLOCK_DIMENSION], singular[MAX_BLOCK_DIMENSION], superb[MAX_BLOCK_DIMENSION];
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
    const lapack_int info = LAPACKE_dgesvd(LAPACK_COL_MAJOR, 'S', 'S', (lapack_int)n, (lapack_int)n, work->matrix,
                                           (lapack_int)n, work->singular, work->u, (lapack_int)n, work->vt,
                                           (lapack_int)n, work->superb);
    if (info != 0) {
        task->lapack_failed[worker] = 1;
        return 0;
    }
    if (work->singular[0] > 0) {
        double v[MAX_BLOCK_DIMENSION];
        for (size_t k = 0; k < n; ++k)
            v[k] = work->vt[k * n]; /* row 0 of V^T, column-major */
        project(mean_a, work->u, v, n);
        project(mean_b, work->u, v, n);
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
                                    const double *tangents, size_t size, size_t max_influences, int thread_count,
                                    sk_error *error)
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
            if (bones[texel * max_influences + (size_t)k] < 0)
                return sk_fail(error, SK_ERROR_INDEX, "texel %zu: bone %d is negative", texel,
                               bones[texel * max_influences + (size_t)k]);
    }
    if (!sk_all_finite(tangents, 8 * size * size * max_influences))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "a tangent is not finite");
    mip_task task = {counts_out, bones_out, tangents_out, counts, bones, tangents, size, max_influences, {0}, {0}, {0}};
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
