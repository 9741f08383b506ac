/*
 * The per-pose normal map of a tangent map (Merry 2007, section 7.5, listing C.8): each texel's object-space normal
 * normalize(G t1 x G t2), encoded 0.5 n + 0.5. What an engine runs once per frame before shading: no LAPACK, no
 * allocation. SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <math.h>

#include "sk_internal.h"

typedef struct normal_task {
    float *image;
    const int32_t *counts, *bones;
    const double *tangents, *poses;
    size_t max_influences;
} normal_task;

static void normals_range(void *argument, size_t worker, size_t begin, size_t end)
{
    (void)worker;
    const normal_task *task = argument;
    for (size_t texel = begin; texel < end; ++texel) {
        double a[3] = {0, 0, 0}, b[3] = {0, 0, 0};
        for (int32_t k = 0; k < task->counts[texel]; ++k) {
            const size_t slot = texel * task->max_influences + (size_t)k;
            const double *frame = task->poses + 16 * (size_t)task->bones[slot], *pair = task->tangents + 8 * slot;
            for (int r = 0; r < 3; ++r)
                for (int c = 0; c < 4; ++c) {
                    a[r] += frame[4 * r + c] * pair[c];
                    b[r] += frame[4 * r + c] * pair[4 + c];
                }
        }
        double n[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
        const double length = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for (int r = 0; r < 3; ++r)
            task->image[3 * texel + (size_t)r] = (float)(length > 0 ? 0.5 * n[r] / length + 0.5 : 0.5);
    }
}

sk_status sk_tangent_map_normals(float *image, const int32_t *counts, const int32_t *bones, const double *tangents,
                                 const double *poses, size_t texel_count, size_t max_influences, size_t bone_count,
                                 int thread_count, sk_error *error)
{
    if (!image || !counts || !bones || !tangents || !poses)
        return sk_fail(error, SK_ERROR_ARGUMENT, "an array is NULL");
    if (max_influences < 1 || bone_count < 1)
        return sk_fail(error, SK_ERROR_ARGUMENT, "max_influences and bone_count must be at least 1");
    for (size_t texel = 0; texel < texel_count; ++texel) {
        if (counts[texel] < 0 || (size_t)counts[texel] > max_influences)
            return sk_fail(error, SK_ERROR_INDEX, "texel %zu has %d influences, outside 0-%zu", texel, counts[texel],
                           max_influences);
        for (int32_t k = 0; k < counts[texel]; ++k) {
            const int32_t bone = bones[texel * max_influences + (size_t)k];
            if (bone < 0 || (size_t)bone >= bone_count)
                return sk_fail(error, SK_ERROR_INDEX, "texel %zu: bone %d is outside 0-%zu", texel, bone,
                               bone_count - 1);
        }
    }
    if (!sk_all_finite(poses, 16 * bone_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "a pose matrix is not finite");
    normal_task task = {image, counts, bones, tangents, poses, max_influences};
    sk_parallel_for(texel_count, SK_EVALUATION_ITEMS_PER_WORKER, thread_count, normals_range, &task);
    return sk_succeed(error);
}
