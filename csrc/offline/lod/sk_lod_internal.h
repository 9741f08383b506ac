/*
 * What the level-of-detail family's files share (not part of the public contract): a persistent influence
 * remover (sk_influence.c's solver with its workspace, its 128-entry cache, its kept splits of P's factor and the
 * P blocks kept between calls), used by the progressive simplifier (sk_progressive.c) to cost and apply influence
 * collapses.
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#ifndef SK_LOD_INTERNAL_H
#define SK_LOD_INTERNAL_H

#include <lapacke.h>

#include "sk_internal.h"

typedef struct sk_influence_remover sk_influence_remover;

/* Validates the statistics, forms P's blocks (bone_count <= 256; above, on demand) and a workspace for sets of
 * up to `capacity` (<= SK_LOD_MAX_VERTEX_INFLUENCES) influences. */
sk_status sk_influence_remover_create(sk_influence_remover **remover, const sk_pose_statistics *statistics,
                                      size_t capacity, sk_error *error);
void sk_influence_remover_free(sk_influence_remover *remover);

/* sk_remove_influence without its checks (bones distinct and in range, 2 <= count <= capacity, finite
 * coordinates): corrected (may be NULL: only the cost) in the input's layout, the removed slot zero. vertex
 * names the vertex in messages. Same bits as sk_remove_influence. */
sk_status sk_influence_remover_apply(sk_influence_remover *remover, double *corrected, double *cost,
                                     const int32_t *bones, const double *coordinates, size_t count, size_t removed,
                                     size_t vertex, sk_error *error);

/* The costs of removing each influence of the set (costs[k]: removing bones[k], what sk_influence_remover_apply
 * gives, to rounding) from one factorization of P over the set; the same preconditions. fallbacks (may be
 * NULL) is incremented once per candidate that needed the per-candidate solve (a rank decision near a
 * threshold). */
sk_status sk_influence_remover_costs(sk_influence_remover *remover, double *costs, size_t *fallbacks,
                                     const int32_t *bones, const double *coordinates, size_t count, size_t vertex,
                                     sk_error *error);

/* P_jk = E[G_j^T G_k] (4x4, row-major). */
void sk_influence_remover_block(double block[16], const sk_influence_remover *remover, int32_t j, int32_t k);

/* P_jk in place where the remover keeps every block, else formed into scratch: the same values. */
const double *sk_influence_remover_block_ref(double scratch[16], const sk_influence_remover *remover, int32_t j,
                                             int32_t k);

/* P = Pi U^T U Pi^T by pivoted Cholesky (dpstrf, column-major U in p, pivots 1-based), P being only semi-definite:
 * stopped once every remaining pivot is <= relative_threshold times P's largest diagonal entry; *rank rows of U
 * hold the factor (0 for P = 0). what and element name the matrix in the message of a LAPACK failure. */
sk_status sk_factor_semidefinite(double *p, size_t d, lapack_int *pivots, double relative_threshold, size_t *rank,
                                 const char *what, size_t element, sk_error *error);

#endif
