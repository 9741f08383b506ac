/* Linear blend skinning, its conversion to animation space, and evaluation of both. */
#include <stdint.h>

#include "sk_internal.h"
#include "sk_math.h"

#define SK_REAL double
#define SK_NAME(x) x##_f64
#define SK_ALL_FINITE sk_all_finite
#include "sk_evaluate_template.h"
#undef SK_REAL
#undef SK_NAME
#undef SK_ALL_FINITE

#define SK_REAL float
#define SK_NAME(x) x##_f32
#define SK_ALL_FINITE sk_all_finite_f32
#include "sk_evaluate_template.h"
#undef SK_REAL
#undef SK_NAME
#undef SK_ALL_FINITE

sk_status sk_skinning_matrices(double *destination, const double *poses, const double *rest_frames,
                               size_t bone_count, sk_error *error)
{
    if (!destination || !poses || !rest_frames || bone_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "skinning matrices need poses and rest frames of >= 1 bone");
    size_t pose_values;
    const sk_status sized = sk_array_size(&pose_values, bone_count, 16, 1, "pose", error);
    if (sized != SK_OK)
        return sized;
    if (!sk_all_finite(poses, pose_values))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "a pose matrix has a NaN or infinity");
    const sk_status status = sk_validate_rest_frames(rest_frames, bone_count, error);
    if (status != SK_OK)
        return status;
    for (size_t bone = 0; bone < bone_count; ++bone) {
        double inverse[16];
        sk_affine_inverse(inverse, rest_frames + 16 * bone); /* cannot fail: validated above */
        sk_multiply4(destination + 16 * bone, poses + 16 * bone, inverse);
    }
    return sk_succeed(error);
}

sk_status sk_lbs_to_animation_space(double *destination, const sk_influences *influences, const double *vectors,
                                    double homogeneous, const double *weights, const double *rest_frames,
                                    size_t bone_count, sk_error *error)
{
    if (!destination || !vectors || !weights || !rest_frames || !influences)
        return sk_fail(error, SK_ERROR_ARGUMENT, "conversion arrays must not be null");
    sk_status status = sk_validate_influences(influences, bone_count, error);
    const int32_t *offsets = influences->offsets, *bones = influences->bones;
    const size_t vertex_count = influences->vertex_count, influence_count = influences->influence_count;
    if (status == SK_OK)
        status = sk_validate_rest_frames(rest_frames, bone_count, error);
    if (status != SK_OK)
        return status;
    if (!sk_all_finite(vectors, 3 * vertex_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "a rest position or vector has a NaN or infinity");
    if (!sk_all_finite(weights, influence_count) || !sk_all_finite(&homogeneous, 1))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "a weight has a NaN or infinity");
    for (size_t vertex = 0; vertex < vertex_count; ++vertex) {
        const double *v = vectors + 3 * vertex;
        for (int32_t k = offsets[vertex]; k < offsets[vertex + 1]; ++k) {
            /* Inverting per influence keeps the core allocation-free; conversion runs once per model. */
            double inverse[16];
            sk_affine_inverse(inverse, rest_frames + 16 * (size_t)bones[k]);
            double *p = destination + 4 * (size_t)k;
            for (int r = 0; r < 3; ++r)
                p[r] = weights[k] * (inverse[4 * r] * v[0] + inverse[4 * r + 1] * v[1] + inverse[4 * r + 2] * v[2] +
                                     inverse[4 * r + 3] * homogeneous);
            p[3] = weights[k] * homogeneous;
        }
    }
    return sk_succeed(error);
}
