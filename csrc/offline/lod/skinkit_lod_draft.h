/*
 * skinkit level of detail, draft declarations: influence simplification (Merry 2007, section 6.3,
 * eq. 6.1 and appendix A.2) and Limit Influences (section 6.4). To be folded into skinkit.h.
 * SPDX-License-Identifier: GPL-3.0-or-later
 *
 * The conventions of skinkit.h hold (destination first, caller-allocated arrays, a status and an error
 * record naming the offending element, no global state).
 *
 * Removing bone i from a homogeneous vector p with influence set I replaces p by p + s where
 *   s_j = 0 for j outside I, s_i = -p_i, the weights (4th components) of s sum to 0,
 *   ||s||_{2,2}^2 = s_I^T P_I s_I is minimal (P_jk = E[G_j^T G_k], from the pose statistics),
 *   and, among the minimisers (P_I is only semi-definite), the Euclidean ||s|| is least.
 * The cost of the removal is ||s||_{2,2}, the RMS over the pose distribution of the distance the
 * skinned vertex moves. The total weight is kept: a position's weights still sum to 1.
 *
 * Tangents: the correction is a linear map of p_i that depends only on (I, i), so the same functions
 * apply unchanged to tangent vectors (homogeneous weight 0; their weights sum to 0 and still do
 * afterwards, since s's weights sum to 0). The thesis chooses the influence to remove from the
 * position alone and removes the same one from the tangents: sk_remove_influence on the tangent's
 * coordinates with the position's `removed` does that, and sk_limit_influences applies the position's
 * choices to any number of tangent sets. Re-orthonormalising the corrected tangents (Gram-Schmidt) is
 * left to the caller.
 */
#ifndef SKINKIT_LOD_DRAFT_H
#define SKINKIT_LOD_DRAFT_H

#include <stddef.h>
#include <stdint.h>

#include "skinkit.h"

#ifdef __cplusplus
extern "C" {
#endif

#ifndef SK_HAS_INFLUENCES_STRUCT
#define SK_HAS_INFLUENCES_STRUCT
/* A CSR influence pattern (see skinkit.h): offsets has vertex_count + 1 entries, bones influence_count. */
typedef struct sk_influences {
    const int32_t *offsets;
    const int32_t *bones;
    size_t vertex_count;
    size_t influence_count;
} sk_influences;
#endif

/* Pose statistics of the independent-joints model (sk_joint_statistics): bone_count 4x4 each. */
typedef struct sk_pose_statistics {
    const double *expected_local; /* E[L_j] */
    const double *expected_gram;  /* E[G_j^T G_j] */
    const int32_t *parents;       /* as in sk_validate_skeleton */
    size_t bone_count;
} sk_pose_statistics;

/* The most influences one vertex may have (the dense work per vertex grows as its cube). */
#define SK_LOD_MAX_VERTEX_INFLUENCES 64

/*
 * Removes influence `removed` (an index in [0, count)) from one homogeneous vector: bones (count
 * distinct bone indices, 2 <= count <= SK_LOD_MAX_VERTEX_INFLUENCES) and coordinates (count 4-vectors,
 * a position or a tangent) describe it. corrected: (count - 1) 4-vectors, the corrected coordinates of
 * the bones kept, in their given order. cost (may be NULL): ||s||_{2,2}.
 */
sk_status sk_remove_influence(double *corrected, double *cost, const int32_t *bones, const double *coordinates,
                              size_t count, size_t removed, const sk_pose_statistics *statistics, sk_error *error);

/*
 * Limit Influences: every vertex with more than max_influences (>= 1) influences loses, one at a time,
 * the influence whose removal costs least, each removal re-fitted to the previous simplified position
 * (equivalent to re-fitting to the original, thesis appendix B.1), until max_influences remain; the
 * kept bones stay in their given order. Vertices with at most max_influences are copied.
 *
 * Outputs, with the capacity of the input (the caller allocates them so):
 *   limited_offsets: vertex_count + 1;  limited_bones: influence_count;
 *   limited_coordinates: influence_count * 4;  *limited_count: the influences kept (limited_offsets' last);
 *   costs (vertex_count, may be NULL): the L2,2 norm of each vertex's total correction (new - original);
 *   limited_tangents (tangent_count * influence_count * 4, NULL when tangent_count is 0): tangent set t
 *   (tangents + t * influence_count * 4, the input's pattern) with the position's removals applied, at
 *   limited_tangents + t * influence_count * 4 in the limited pattern.
 * Bones must be distinct within a vertex; a vertex above max_influences may have at most
 * SK_LOD_MAX_VERTEX_INFLUENCES. thread_count as for evaluation. progress (may be NULL) is called on the
 * calling thread between batches of vertices; a non-zero return cancels (SK_ERROR_CANCELLED).
 */
sk_status sk_limit_influences(int32_t *limited_offsets, int32_t *limited_bones, double *limited_coordinates,
                              size_t *limited_count, double *costs, double *limited_tangents,
                              const sk_influences *influences, const double *coordinates, const double *tangents,
                              size_t tangent_count, const sk_pose_statistics *statistics, size_t max_influences,
                              int thread_count, sk_progress_fn progress, void *progress_user, sk_error *error);

#ifdef __cplusplus
}
#endif

#endif /* SKINKIT_LOD_DRAFT_H */
