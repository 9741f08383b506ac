/* Validation of skeletons, sparse influence patterns, triangle lists and finiteness. */
#include <math.h>

#include "sk_internal.h"
#include "sk_math.h"

/* Largest accepted ratio of a rest frame's extreme singular values; beyond it the inverse is noise. */
#define SK_MAX_CONDITION 1e12

/* Values are tested a block at a time, with one branch a block rather than one a value (a bake's input checks took
 * about 7 instructions a value, now 4.5); the first block holding a non-finite value is then searched one by one. */
#define FINITE_BLOCK 8

size_t sk_first_non_finite(const double *values, size_t count)
{
    size_t i = 0;
    for (; i + FINITE_BLOCK <= count; i += FINITE_BLOCK) {
        /* x - x is +0 for a finite x and NaN for an infinity or a NaN, so the sum is +0 unless one is not finite */
        double probe = 0;
        for (int k = 0; k < FINITE_BLOCK; ++k)
            probe += values[i + (size_t)k] - values[i + (size_t)k];
        if (probe != 0)
            break;
    }
    for (; i < count; ++i)
        if (!isfinite(values[i]))
            return i;
    return count;
}

int sk_all_finite(const double *values, size_t count)
{
    return sk_first_non_finite(values, count) == count;
}

size_t sk_first_non_finite_f32(const float *values, size_t count)
{
    for (size_t i = 0; i < count; ++i)
        if (!isfinite(values[i]))
            return i;
    return count;
}

int sk_all_finite_f32(const float *values, size_t count)
{
    return sk_first_non_finite_f32(values, count) == count;
}

static sk_status validate_parents(const int32_t *parents, size_t bone_count, sk_error *error)
{
    if (parents[0] != -1)
        return sk_fail(error, SK_ERROR_CYCLE, "bone 0 must be the root (parent -1), its parent is %d",
                       (int)parents[0]);
    for (size_t bone = 1; bone < bone_count; ++bone) {
        const int32_t parent = parents[bone];
        if (parent < 0 || (size_t)parent >= bone_count)
            return sk_fail(error, SK_ERROR_INDEX, "bone %zu: parent %d is outside [0, %zu)", bone,
                           (int)parent, bone_count);
    }
    /* Every walk towards the root must reach bone 0 in fewer than bone_count steps. */
    for (size_t bone = 1; bone < bone_count; ++bone) {
        size_t current = bone, steps = 0;
        while (current != 0) {
            current = (size_t)parents[current];
            if (++steps >= bone_count)
                return sk_fail(error, SK_ERROR_CYCLE, "bone %zu: its parents form a cycle", bone);
        }
    }
    return SK_OK;
}

static sk_status validate_rest_frame(const double *frame, size_t bone, sk_error *error)
{
    if (!sk_all_finite(frame, 16))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "bone %zu: rest frame has a NaN or infinity", bone);
    if (frame[12] != 0.0 || frame[13] != 0.0 || frame[14] != 0.0 || frame[15] != 1.0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "bone %zu: rest frame is not affine (bottom row %g %g %g %g)",
                       bone, frame[12], frame[13], frame[14], frame[15]);
    double linear[9], singular_values[3];
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            linear[3 * r + c] = frame[4 * r + c];
    sk_svd3(singular_values, NULL, NULL, linear);
    if (!(singular_values[0] > 0.0) || singular_values[2] * SK_MAX_CONDITION < singular_values[0])
        return sk_fail(error, SK_ERROR_SINGULAR,
                       "bone %zu: rest frame is singular (singular values %g, %g, %g)", bone,
                       singular_values[0], singular_values[1], singular_values[2]);
    return SK_OK;
}

sk_status sk_validate_skeleton(const int32_t *parents, const double *rest_frames, size_t bone_count,
                               sk_error *error)
{
    if (!parents || bone_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "a skeleton needs at least the root bone");
    sk_status status = validate_parents(parents, bone_count, error);
    if (status == SK_OK && rest_frames)
        status = sk_validate_rest_frames(rest_frames, bone_count, error);
    return status == SK_OK ? sk_succeed(error) : status;
}

sk_status sk_validate_rest_frames(const double *rest_frames, size_t bone_count, sk_error *error)
{
    for (size_t bone = 0; bone < bone_count; ++bone) {
        const sk_status status = validate_rest_frame(rest_frames + 16 * bone, bone, error);
        if (status != SK_OK)
            return status;
    }
    return SK_OK;
}

sk_status sk_validate_influences(const sk_influences *influences, size_t bone_count, sk_error *error)
{
    if (!influences)
        return sk_fail(error, SK_ERROR_ARGUMENT, "influence arrays must not be null");
    const int32_t *offsets = influences->offsets, *bones = influences->bones;
    const size_t vertex_count = influences->vertex_count, influence_count = influences->influence_count;
    if (!offsets || (!bones && influence_count > 0))
        return sk_fail(error, SK_ERROR_ARGUMENT, "influence arrays must not be null");
    if (offsets[0] != 0)
        return sk_fail(error, SK_ERROR_INDEX, "offsets[0] must be 0, it is %d", (int)offsets[0]);
    if ((size_t)offsets[vertex_count] != influence_count || offsets[vertex_count] < 0)
        return sk_fail(error, SK_ERROR_INDEX, "offsets[%zu] must equal the influence count %zu, it is %d",
                       vertex_count, influence_count, (int)offsets[vertex_count]);
    for (size_t vertex = 0; vertex < vertex_count; ++vertex) {
        if (offsets[vertex + 1] < offsets[vertex])
            return sk_fail(error, SK_ERROR_INDEX, "vertex %zu: offsets decrease (%d then %d)", vertex,
                           (int)offsets[vertex], (int)offsets[vertex + 1]);
        /* Checked before the bones loop: a later decrease would be caught too late to stop it reading
         * past bones[influence_count - 1]. offsets[vertex + 1] >= offsets[vertex] >= 0 here. */
        if ((size_t)offsets[vertex + 1] > influence_count)
            return sk_fail(error, SK_ERROR_INDEX, "vertex %zu: offset %d is beyond the influence count %zu",
                           vertex, (int)offsets[vertex + 1], influence_count);
        for (int32_t k = offsets[vertex]; k < offsets[vertex + 1]; ++k)
            if (bones[k] < 0 || (size_t)bones[k] >= bone_count)
                return sk_fail(error, SK_ERROR_INDEX, "vertex %zu: bone index %d is outside [0, %zu)", vertex,
                               (int)bones[k], bone_count);
    }
    return sk_succeed(error);
}

sk_status sk_validate_triangles(const sk_triangle_mesh *mesh, sk_error *error)
{
    if (!mesh)
        return sk_fail(error, SK_ERROR_ARGUMENT, "triangles must not be null");
    const int32_t *triangles = mesh->triangles;
    const size_t triangle_count = mesh->triangle_count, vertex_count = mesh->vertex_count;
    if (!triangles && triangle_count > 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "triangles must not be null");
    for (size_t t = 0; t < triangle_count; ++t) {
        const int32_t *corner = triangles + 3 * t;
        for (int c = 0; c < 3; ++c)
            if (corner[c] < 0 || (size_t)corner[c] >= vertex_count)
                return sk_fail(error, SK_ERROR_INDEX, "triangle %zu: vertex index %d is outside [0, %zu)", t,
                               (int)corner[c], vertex_count);
        if (corner[0] == corner[1] || corner[1] == corner[2] || corner[0] == corner[2])
            return sk_fail(error, SK_ERROR_ARGUMENT, "triangle %zu: repeats a vertex (%d, %d, %d)", t,
                           (int)corner[0], (int)corner[1], (int)corner[2]);
    }
    return sk_succeed(error);
}
