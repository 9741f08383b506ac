/*
 * skinkit: native core for animation-space and linear-blend skinning.
 * SPDX-License-Identifier: GPL-3.0-or-later
 *
 * Conventions (every function below follows them):
 *   - The destination comes first, then inputs, then counts, then options, then the error record. Inputs
 *     that travel together are structs: sk_influences (a CSR pattern), sk_examples (example meshes with
 *     their bone frames), sk_triangle_mesh (a triangle list), sk_pose_statistics (the metric's per-joint
 *     expectations; the metrics functions predating it still take its three arrays). Options, tolerances
 *     and thread_count live in a function's options struct when it has one; a function without one takes
 *     thread_count (and a progress callback, if it reports progress) last before the error record.
 *   - Each block ends with one line per array, libigl style: `@param[out] coordinates  influence_count*4`
 *     gives the number of elements (doubles, int32 or bytes as the type says) the array holds.
 *   - The caller allocates every input and output array; the core never keeps a pointer after a call
 *     returns and has no global state, so calls on different data may run concurrently from several
 *     threads. Solvers that need scratch memory allocate it and free it before returning (a failed
 *     allocation is SK_ERROR_MEMORY).
 *   - Every function returns a status. On failure the destination is unspecified (it may be partly
 *     written), *error holds the status and a message naming the offending element, and nothing
 *     outside the destination was written. `error` may be NULL when the caller does not want the text.
 *   - No function aborts, exits or reads outside the counts it was given: every index taken from the
 *     data (bone indices, CSR offsets, parents) is range-checked before it is used.
 *   - Matrices are 4x4, row-major (numpy's C order), affine: the bottom row of an input pose is
 *     ignored by evaluation and must be (0 0 0 1) where a function validates it.
 *   - Points and vectors are homogeneous (thesis notation): a point has weight 1, a tangent vector 0.
 *
 * Sparse per-vertex influences use compressed rows (CSR): vertex i owns entries
 * offsets[i] .. offsets[i+1]-1 of `bones` and of the per-entry values (one weight for linear blend
 * skinning, one 4-vector p_j for animation space). offsets has vertex_count + 1 entries, starts at 0,
 * never decreases, and ends at influence_count. The pattern travels as an sk_influences.
 *
 * The animation-space model (Merry 2007, eq. 3.1-3.2): vertex i is v_i = sum_j G_j p_ij, with G_j the
 * 4x4 frame of bone j in model space for the current pose and p_ij a 4-vector in bone j's frame.
 * Bone 0 is the root: it does not animate and its frame is model space (G_0 = I).
 */
#ifndef SKINKIT_H
#define SKINKIT_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define SK_VERSION_MAJOR 0
#define SK_VERSION_MINOR 1
#define SK_VERSION_PATCH 0

/* Marks a declaration whose signature may still change between minor versions (meshoptimizer's
 * MESHOPTIMIZER_EXPERIMENTAL): callers outside this project should pin the version they built against. */
#define SK_EXPERIMENTAL

typedef enum sk_status {
    SK_OK = 0,
    SK_ERROR_ARGUMENT,   /* a null pointer, a zero or inconsistent count, a bad option value */
    SK_ERROR_INDEX,      /* a bone index, parent or CSR offset outside its range */
    SK_ERROR_NOT_FINITE, /* a NaN or infinity in the input */
    SK_ERROR_CYCLE,      /* the parent indices do not form a tree rooted at bone 0 */
    SK_ERROR_SINGULAR,   /* a matrix that must be invertible is not (or is numerically not) */
    SK_ERROR_MEMORY,     /* an allocation failed */
    SK_ERROR_LAPACK,     /* LAPACK reported a failure */
    SK_ERROR_CANCELLED,  /* a progress callback asked to stop */
    SK_ERROR_RANK        /* a least-squares problem does not determine its unknowns */
} sk_status;

#define SK_MESSAGE_SIZE 256

typedef struct sk_error {
    sk_status status;
    char message[SK_MESSAGE_SIZE];
} sk_error;

/* A CSR influence pattern (see above): vertex i owns entries offsets[i] .. offsets[i + 1] - 1. */
typedef struct sk_influences {
    const int32_t *offsets; /* vertex_count + 1 */
    const int32_t *bones;   /* influence_count */
    size_t vertex_count;
    size_t influence_count;
} sk_influences;

/* A triangle list: triangles[3 t .. 3 t + 2] are the vertex indices of triangle t. */
typedef struct sk_triangle_mesh {
    const int32_t *triangles; /* triangle_count * 3 */
    size_t triangle_count;
    size_t vertex_count;
} sk_triangle_mesh;

/* A short, static, human-readable name for a status ("index out of range", ...). */
const char *sk_status_name(sk_status status);

/* ---------------------------------------------------------------------------------------------
 * Validation
 * ------------------------------------------------------------------------------------------- */

/*
 * Checks a skeleton: parents[0] == -1 (bone 0 is the root), every other parent is in
 * [0, bone_count) and following parents from any bone reaches bone 0 without a cycle (bones may be
 * listed in any order). When rest_frames is not NULL (bone_count 4x4 matrices), each must be finite,
 * affine (bottom row 0 0 0 1) and well conditioned: the 3x3 linear part's singular values (one-sided
 * Jacobi, no LAPACK) must have a ratio below 1e12, and not all be zero.
 * @param[in] parents  bone_count
 * @param[in] rest_frames  bone_count*16 (may be NULL)
 */
sk_status sk_validate_skeleton(const int32_t *parents, const double *rest_frames, size_t bone_count,
                               sk_error *error);

/* Checks a CSR influence pattern: offsets as described above, every bone index in [0, bone_count). */
sk_status sk_validate_influences(const sk_influences *influences, size_t bone_count, sk_error *error);

/*
 * Checks a triangle list: every index in [0, vertex_count) and no triangle repeating a vertex.
 * @param[in] mesh  triangle_count*3 indices
 */
sk_status sk_validate_triangles(const sk_triangle_mesh *mesh, sk_error *error);

/*
 * Checks that a triangle mesh is a manifold surface, in this order: indices (as sk_validate_triangles), then
 * edges shared by more than two triangles (the edge shared by the most, the lowest among equals, with all its
 * faces), then neighbouring triangles that run the same way along their edge (the first repeat of a directed
 * edge in slot order 3 t + k), then vertices whose triangles form more than one fan across shared edges (a
 * bowtie; the lowest such vertex). Each is SK_ERROR_ARGUMENT with the messages
 *   "edge (a, b) is shared by N faces [f0, f1, f2]: the mesh is not manifold there (separate or delete the
 *    extra faces)" (a < b),
 *   "faces [f0, f1] run the same way along edge (a, b): their orientations disagree (recalculate the normals
 *    so they point the same way)" (a to b as both faces run),
 *   "vertex v joins separate fans of faces (a bowtie): the mesh is not manifold there (split the vertex)".
 * @param[in] mesh  triangle_count*3 indices
 */
SK_EXPERIMENTAL sk_status sk_validate_surface(const sk_triangle_mesh *mesh, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Conversion from linear blend skinning
 * ------------------------------------------------------------------------------------------- */

/*
 * Converts linear-blend weights to animation-space coordinates (eq. 3.1 for points, eq. 4.8 for
 * tangents): destination[4*k .. 4*k+3] = weights[k] * inverse(rest_frames[bones[k]]) * (x, y, z, h)
 * for every influence k of vertex i, where (x, y, z) = vectors[3*i .. 3*i+2] and h = homogeneous
 * (1 for rest positions, 0 for rest tangent vectors). The weights are used as given: normalise them
 * first if the skinning you reproduce normalises them. Evaluating the result with
 * sk_animation_space_evaluate_f64 reproduces sk_lbs_evaluate_f64 for every pose.
 *
 * rest_frames are validated as in sk_validate_skeleton.
 * @param[out] destination  influence_count*4
 * @param[in] vectors  vertex_count*3
 * @param[in] weights  influence_count
 * @param[in] rest_frames  bone_count*16
 */
sk_status sk_lbs_to_animation_space(double *destination, const sk_influences *influences, const double *vectors,
                                    double homogeneous, const double *weights, const double *rest_frames,
                                    size_t bone_count, sk_error *error);

/*
 * Skinning matrices N_j = G_j * inverse(rest_j) for linear blend skinning (eq. 2.2).
 * @param[out] destination  bone_count*16
 * @param[in] poses  bone_count*16 (G_j)
 * @param[in] rest_frames  bone_count*16
 */
sk_status sk_skinning_matrices(double *destination, const double *poses, const double *rest_frames,
                               size_t bone_count, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Evaluation (animation projection and linear blend skinning)
 *
 * thread_count: 0 uses one thread per online processor, 1 runs on the calling thread, n > 1 uses at
 * most n threads. Small inputs run on the calling thread whatever the value. The result does not
 * depend on the thread count. The poses' finiteness is checked; the per-vertex data are not checked
 * for finiteness here (validate a model once, evaluate it many times), but all indices are.
 * ------------------------------------------------------------------------------------------- */

/*
 * Animation projection: destination[3*i .. 3*i+2] = top three rows of sum_k G_{bones[k]} p_k over the
 * influences k of vertex i. Works for positions (the p_k's weights sum to 1) and tangents (sum 0).
 * @param[out] destination  vertex_count*3
 * @param[in] coordinates  influence_count*4
 * @param[in] poses  bone_count*16
 */
sk_status sk_animation_space_evaluate_f64(double *destination, const sk_influences *influences,
                                          const double *coordinates, const double *poses, size_t bone_count,
                                          int thread_count, sk_error *error);

/* The same in single precision: the fast path for previews and playback. */
sk_status sk_animation_space_evaluate_f32(float *destination, const sk_influences *influences,
                                          const float *coordinates, const float *poses, size_t bone_count,
                                          int thread_count, sk_error *error);

/*
 * Linear blend skinning: destination[3*i..] = sum_k weights[k] * N_{bones[k]} * (x, y, z, h) with
 * (x, y, z) = vectors[3*i..] and h = homogeneous (1 positions, 0 tangent vectors).
 * @param[out] destination  vertex_count*3
 * @param[in] vectors  vertex_count*3
 * @param[in] weights  influence_count
 * @param[in] skinning_matrices  bone_count*16 (from sk_skinning_matrices)
 */
sk_status sk_lbs_evaluate_f64(double *destination, const sk_influences *influences, const double *vectors,
                              double homogeneous, const double *weights, const double *skinning_matrices,
                              size_t bone_count, int thread_count, sk_error *error);

sk_status sk_lbs_evaluate_f32(float *destination, const sk_influences *influences, const float *vectors,
                              float homogeneous, const float *weights, const float *skinning_matrices,
                              size_t bone_count, int thread_count, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Fitting to example poses (Merry 2007, chapter 4)
 *
 * Examples (sk_examples): example_count meshes of the influences' vertex_count vertices
 * (positions[(e * vertex_count + i) * 3 ..]), each with its bone frames poses[(e * bone_count + j) * 16 ..]
 * (G_j^e, 4x4). Influence sets are a CSR pattern as above; the fitted coordinates have the same pattern. The
 * homogeneous weight of each vertex's last influence is eliminated (section 4.1.3), so the weights of
 * every fitted vertex sum to exactly 1. Normalise the data to a unit box first (section 4.1.2): the
 * regularisers are not scale invariant.
 * ------------------------------------------------------------------------------------------- */

/* Example meshes and their bone frames. */
typedef struct sk_examples {
    const double *poses;     /* example_count * bone_count * 16 */
    const double *positions; /* example_count * vertex_count * 3 */
    size_t example_count;
    size_t bone_count;
} sk_examples;

/* Progress report: fraction in [0, 1]; return non-zero to cancel (the call then returns SK_ERROR_CANCELLED). */
typedef int (*sk_progress_fn)(void *user, double fraction);

/*
 * Per-vertex fit with vertex regularisation (eq. 4.3): for each vertex, minimises
 * sum_e |G^e p - v^e|^2 + lambda |p - prior|^2 over its influence set (p with 4 entries per influence),
 * by a small dense least-squares solve (LAPACK dgelsd). prior (influence_count * 4, same pattern) may
 * be NULL for the thesis' pull towards zero; a linear-blend model as the prior makes strong
 * regularisation fall back to linear blend skinning instead of shrinking the mesh. lambda >= 0; with
 * lambda = 0 a vertex whose examples do not determine its coordinates fails with SK_ERROR_RANK naming it.
 * @param[out] coordinates  influence_count*4
 * @param[in] prior  influence_count*4 (may be NULL)
 */
sk_status sk_fit_per_vertex(double *coordinates, const sk_influences *influences, const sk_examples *examples,
                            const double *prior, double lambda, int thread_count, sk_error *error);

/* LSQR stopping rules and options (Paige & Saunders 1982; the names follow their paper). */
typedef struct sk_lsqr_settings {
    double atol;         /* stop when |A^T r| / (|A| |r|) <= atol (relative accuracy of A) */
    double btol;         /* stop when |r| <= btol |b| + atol |A| |x| (relative accuracy of b) */
    double conlim;       /* stop when the estimated condition number of A exceeds conlim (0: no limit) */
    int iteration_limit; /* stop after this many iterations */
    int precondition;    /* sk_fit_global: non-zero for right preconditioning by per-vertex block Jacobi (Cholesky) */
    int thread_count;    /* sk_fit_global: threads applying its operator (0: the online processors) */
} sk_lsqr_settings;

typedef struct sk_lsqr_report {
    int stop_reason;           /* 0 x = 0 solves it, 1 btol, 2 atol, 3 conlim, 4-6 machine precision, 7 iteration limit */
    int iterations;
    double residual_norm;      /* |b - A x| of the system LSQR solved (data and regulariser rows) */
    double normal_residual;    /* |A^T (b - A x)| */
    double matrix_norm;        /* estimate of the Frobenius norm of A */
    double condition;          /* estimate of the condition number of A */
    double solution_norm;      /* |x| */
    double initial_residual_norm; /* |b - A x0| before the first iteration */
} sk_lsqr_report;

/*
 * Matrix-free LSQR: solves min |b - A x| where apply(user, 0, in, out) sets out = A in (in: cols,
 * out: rows) and apply(user, 1, in, out) sets out = A^T in (in: rows, out: cols). x starts at 0.
 * progress (may be NULL) is called about every 10 iterations with iterations / iteration_limit. The
 * operator is the caller's, so settings->precondition and thread_count are not used here.
 * @param[out] x  cols
 * @param[in] b  rows
 */
typedef void (*sk_linear_operator)(void *user, int transpose, const double *in, double *out);
sk_status sk_lsqr(double *x, const double *b, size_t rows, size_t cols, sk_linear_operator apply, void *user,
                  const sk_lsqr_settings *settings, sk_lsqr_report *report, sk_progress_fn progress,
                  void *progress_user, sk_error *error);

/*
 * Global fit with edge regularisation (eq. 4.4): minimises over all vertices at once
 *   sum_i sum_e |G^e p_i - v_i^e|^2 + sum_edges edge_weights[k] |p_a - p_b|^2
 * where edges[2k], edges[2k+1] = (a, b) and edge_weights[k] = delta / (mean length of the edge over the
 * examples), with the matrix-free LSQR above. coordinates holds the starting point on entry (for
 * example the per-vertex fit; every vertex's weights must sum to 1) and the solution on return.
 * settings->thread_count threads apply the operator.
 * @param[in,out] coordinates  influence_count*4
 * @param[in] edges  edge_count*2
 * @param[in] edge_weights  edge_count
 */
sk_status sk_fit_global(double *coordinates, sk_lsqr_report *report, const sk_influences *influences,
                        const sk_examples *examples, const int32_t *edges, const double *edge_weights,
                        size_t edge_count, const sk_lsqr_settings *settings, sk_progress_fn progress,
                        void *progress_user, sk_error *error);

/*
 * Linear-blend baseline: for each vertex, non-negative weights summing to 1 over its influence set
 * that best reproduce the examples from the rest position (sum_e |sum_j w_j N_j^e v - v^e|^2 with
 * N_j^e = G_j^e rest_j^-1), by Lawson-Hanson non-negative least squares with the sum as a heavily
 * weighted extra row, then normalised exactly. The examples' poses are the skinning matrices N_j^e.
 * @param[out] weights  influence_count
 * @param[in] rest_positions  vertex_count*3
 */
sk_status sk_fit_lbs_weights(double *weights, const sk_influences *influences, const sk_examples *examples,
                             const double *rest_positions, int thread_count, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * The animation-space metrics (Merry 2007, chapter 3)
 *
 * Pose statistics per joint, for the "independent joints" model: expected_local[j] = E[L_j] (L_j maps
 * bone j's frame to its parent's; L_0 = I) and expected_gram[j] = E[G_j^T G_j], both 4x4. The full
 * expectation P has blocks P_jk = E[G_j^T G_k]; only the blocks a computation needs are formed.
 * ------------------------------------------------------------------------------------------- */

/* Pose statistics of the independent-joints model (sk_joint_statistics): bone_count 4x4 each. */
typedef struct sk_pose_statistics {
    const double *expected_local; /* E[L_j] */
    const double *expected_gram;  /* E[G_j^T G_j] */
    const int32_t *parents;       /* as in sk_validate_skeleton */
    size_t bone_count;
} sk_pose_statistics;

/*
 * Statistics from sampled poses: local (sample_count * bone_count 4x4, L_j per sample; L_0 is taken as I)
 * gives expected_local = the sample mean of L_j and, in the independent-joints model throughout,
 * expected_gram[j] = the sample mean of L_j^T expected_gram[parent] L_j, parents first. (Averaging
 * G_j^T G_j over whole sampled poses would not agree with the recursion's cross blocks and could make
 * P indefinite.) parents as in sk_validate_skeleton.
 */
sk_status sk_joint_statistics(double *expected_local, double *expected_gram, const double *local,
                              const int32_t *parents, size_t sample_count, size_t bone_count, sk_error *error);

/*
 * One block P_jk = E[G_j^T G_k] by the common-ancestor recursion (eq. 3.7-3.8): with a the lowest
 * common ancestor of j and k, P_jk = (prod E[L] on the path a->j)^T E[G_a^T G_a] (prod E[L] on a->k).
 */
sk_status sk_expectation_block(double *block, const double *expected_local, const double *expected_gram,
                               const int32_t *parents, size_t bone_count, size_t j, size_t k, sk_error *error);

/* Every block of P: blocks[(j * bone_count + k) * 16 ..] = P_jk (bone_count^2 * 16 doubles). */
sk_status sk_expectation_blocks(double *blocks, const double *expected_local, const double *expected_gram,
                                const int32_t *parents, size_t bone_count, sk_error *error);

/*
 * The 2-norm (largest singular value) of the linear 3x3 part of each of matrix_count 4x4 matrices, from the
 * largest eigenvalue of A^T A in closed form. destination: matrix_count.
 */
sk_status sk_linear_norms(double *destination, const double *matrices, size_t matrix_count, sk_error *error);

/*
 * Mean distances (the L2,2 norm, eq. 3.6): destination[i] = sqrt(s_i^T P s_i) for each sparse weight-0
 * vector s_i in CSR form (the pattern's vertex_count is the number of vectors). block_cache and cached
 * (zero on the first call) keep the blocks formed so far between calls.
 * @param[out] destination  vertex_count
 * @param[in] vectors  influence_count*4
 * @param[in] expected_local, expected_gram  bone_count*16
 * @param[in] parents  bone_count
 * @param[in,out] block_cache  bone_count*bone_count*16
 * @param[in,out] cached  bone_count*bone_count
 */
sk_status sk_mean_distances(double *destination, const sk_influences *influences, const double *vectors,
                            const double *expected_local, const double *expected_gram, const int32_t *parents,
                            size_t bone_count, double *block_cache, unsigned char *cached, int thread_count,
                            sk_error *error);

/*
 * Max-distance bounds (the L2,inf norm, eq. 3.18-3.28): destination[i] >= |x, y, z of G s_i| for every pose whose
 * joints satisfy |linear part of L_j|_2 <= linear_bound[j] and |translation of L_j - centre_j| <=
 * translation_radius[j] (translation_centre: bone_count * 3), by propagating spheres up the skeleton.
 * The vectors' weights may be negative (their |w| scales the translation radius); for weight-0 vectors (the
 * difference of two points, the norm's domain) G s has no fourth component. An empty vector's bound is 0.
 * @param[out] destination  vertex_count (one per vector)
 * @param[in] vectors  influence_count*4
 * @param[in] parents, linear_bound, translation_radius  bone_count
 * @param[in] translation_centre  bone_count*3
 */
sk_status sk_max_distances(double *destination, const sk_influences *influences, const double *vectors,
                           const int32_t *parents, const double *linear_bound, const double *translation_centre,
                           const double *translation_radius, size_t bone_count, int thread_count, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Skinning a mesh sequence without a rig (Merry 2007, section 4.1.4; skinning decomposition)
 *
 * Frames: frame_count meshes of vertex_count vertices (frames[(f * vertex_count + i) * 3 ..]). A motion
 * M_j^f maps bone j's rest-pose vertices to frame f (4x4, rigid); bone 0 is the static root (M_0 = I).
 * ------------------------------------------------------------------------------------------- */

/*
 * Bone motions from core vertices (section 4.1.4 steps 2-4): for each bone j >= 1 and frame f, the affine map
 * that best carries the rest positions of bone j's core vertices to frame f (eq. 4.5, minimum-norm least squares),
 * its nearest rotation (polar decomposition; a reflection, from near-planar cores, is fixed by flipping the
 * direction of the smallest singular value), then the translation refitted for that rotation. Core sets are CSR
 * by bone: bone j owns core_vertices[core_offsets[j] .. core_offsets[j+1]-1] (vertex indices); bone 0's set is
 * ignored and its motion is I. A bone with fewer than 3 core vertices, or with collinear ones, is refused
 * (SK_ERROR_RANK naming it). motions: frame_count * bone_count 4x4 (output).
 */
sk_status sk_fit_core_motions(double *motions, const int32_t *core_offsets, const int32_t *core_vertices,
                              const double *rest_positions, const double *frames, size_t vertex_count,
                              size_t core_count, size_t frame_count, size_t bone_count, sk_error *error);

/*
 * Rest joint positions (eq. 4.6): with rest frames (I, h_j), joint j's translation relative to its parent f in
 * frame p is L = -h_f + c + A h_j where (A, c) = M_f^-1 M_j. For each bone, parents first, minimises
 * sum_p |L - m_j|^2 + lambda^2 |h_j - approximate_j|^2 over (h_j, m_j) (lambda = 1e-3 in a unit box: hinge
 * joints leave the centre free along their axis). joints: bone_count * 3 (output; the root's is 0).
 * motions: frame_count * bone_count 4x4.  parents: as in sk_validate_skeleton.
 */
sk_status sk_fit_rest_joints(double *joints, const double *motions, const int32_t *parents,
                             const double *approximate_joints, size_t frame_count, size_t bone_count, double lambda,
                             sk_error *error);

/*
 * Rigid bone frames that best reproduce target frames with a fixed animation-space model (linear blend skinning
 * converted by sk_lbs_to_animation_space included): for each frame, `sweeps` rounds of block coordinate descent
 * over bones 1.., each bone given its exact best rotation and translation with the others fixed (a weighted
 * Procrustes problem), so the error never increases. Bone 0 keeps its pose. poses: frame_count * bone_count 4x4,
 * the starting point on entry (rotations with translations) and the result on return. Frames run in parallel.
 * frame_errors (may be NULL) receives each frame's sum of squared distances to its targets at the end.
 * @param[in,out] poses  frame_count*bone_count*16
 * @param[out] frame_errors  frame_count
 * @param[in] coordinates  influence_count*4
 * @param[in] targets  frame_count*vertex_count*3
 */
sk_status sk_solve_rigid_poses(double *poses, double *frame_errors, const sk_influences *influences,
                               const double *coordinates, const double *targets, size_t frame_count, size_t bone_count,
                               int sweeps, int thread_count, sk_error *error);

/*
 * For each vertex, the candidate_count bones whose rigid motion alone best explains it over the frames:
 * best_errors[i * candidate_count + s] = sum_f |M_b^f x_i - v_i^f|^2 for b = best_bones[..], ascending. allowed
 * (vertex_count * bone_count flags, may be NULL for all) restricts the bones per vertex; unfilled slots hold -1 and
 * infinity. motions: frame_count * bone_count 4x4; rest_positions: vertex_count * 3.
 */
sk_status sk_rank_bones(int32_t *best_bones, double *best_errors, const double *rest_positions, const double *frames,
                        const double *motions, const unsigned char *allowed, size_t vertex_count, size_t frame_count,
                        size_t bone_count, size_t candidate_count, int thread_count, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Segmentation (Merry 2007, section 5.2)
 *
 * A mesh is cut into charts that are topological discs. Every metric quantity comes from a per-vertex
 * embedding (vertex_count * dimension doubles, 2 <= dimension <= SK_SEGMENT_MAX_DIMENSION): lengths
 * are Euclidean distances between embedded vertices and a triangle's plane is the bivector of its
 * embedded edges, so the same code segments in 3D (the rest positions) or in animation space (its
 * principal directions). Charts are numbered per triangle (charts: triangle_count int32). The mesh must
 * be edge-manifold: an edge shared by three or more triangles is SK_ERROR_ARGUMENT naming its vertices.
 * Triangles of zero metric area are allowed (they have no weight in the metric).
 * ------------------------------------------------------------------------------------------- */

#define SK_SEGMENT_MAX_DIMENSION 8

typedef enum sk_segment_mode {
    SK_SEGMENT_GREEDY = 0, /* merge by cost until the chart count or the threshold is reached */
    SK_SEGMENT_SEAMS = 1   /* only the seams cut: merge everything that can stay a disc */
} sk_segment_mode;

typedef struct sk_segment_options {
    sk_segment_mode mode;
    size_t chart_count; /* greedy: stop at this many charts (0: no target) */
    double threshold;   /* greedy: stop before E_mesh (eq. 5.5) would exceed it (0: no threshold); with
                         * neither, stop when every remaining merge would raise E_mesh */
    double rho;         /* weight of the compactness term in eq. 5.4 (the thesis: 0.2) */
} sk_segment_options;

typedef struct sk_segment_report {
    size_t chart_count;
    double mesh_metric;     /* E_mesh of the result (eq. 5.5) */
    size_t component_count; /* connected components across non-seam edges: in seams mode, a result with
                             * more charts had to cut components that are not discs */
} sk_segment_report;

/*
 * Greedy disc-preserving chart merging (Garland et al. 2001, Sander et al. 2001) with the combined
 * metric E = (surface area + rho perimeter^2 / 4 pi) / max projected area (eq. 5.4): each triangle
 * starts as a chart, and the merge of two adjacent charts that least increases sum E_i A_i (eq. 5.5)
 * is applied first. A merge is legal when the two charts share exactly one boundary arc, no seam edge
 * lies on it, and they touch nowhere else (so the result is again a disc). The max projected area is
 * the spectral norm of the chart's summed bivector as an antisymmetric matrix (appendix A.1; |sum of
 * area normals| in 3D). seams: seam_count vertex pairs that must be mesh edges (else SK_ERROR_ARGUMENT
 * naming the pair); merging never crosses them, and the mesh is cut along them first
 * (sk_cut_along_seams), so a chart is a disc of the cut mesh: a tube slit by a seam is one chart. Pass
 * the cut mesh to everything that works per chart afterwards (corners, straightening, flattening). The
 * result may keep more charts than asked when no legal merge is left (a closed surface needs at least
 * two discs). report may be NULL. Charts are numbered 0 .. chart_count - 1 in order of their first triangle.
 * @param[out] charts  triangle_count
 * @param[in] mesh  triangle_count*3 indices
 * @param[in] embedding  vertex_count*dimension
 * @param[in] seams  seam_count*2 vertex indices
 */
sk_status sk_segment(int32_t *charts, sk_segment_report *report, const sk_triangle_mesh *mesh,
                     const double *embedding, size_t dimension, const int32_t *seams, size_t seam_count,
                     const sk_segment_options *options, sk_error *error);

/*
 * Cuts a mesh open along seams: each vertex becomes one vertex per fan of its triangles joined through
 * non-seam edges (a vertex where the surface is pinched is split too), numbered in order of the fan's first
 * corner (3 t + k). cut_triangles: the same triangles on the new vertices; source_vertex: the original vertex
 * of each new one; *cut_vertex_count: how many there are (loose vertices are dropped). Seams as in sk_segment.
 * @param[out] cut_triangles  triangle_count*3
 * @param[out] source_vertex  triangle_count*3 (capacity; *cut_vertex_count are written)
 * @param[in] seams  seam_count*2
 */
sk_status sk_cut_along_seams(int32_t *cut_triangles, int32_t *source_vertex, size_t *cut_vertex_count,
                             const sk_triangle_mesh *mesh, const int32_t *seams, size_t seam_count, sk_error *error);

/*
 * Chart corners: corners[v] = 1 where three or more charts meet, or where two or more meet on the
 * mesh border; then every chart with fewer than three corners on its boundary loop gets artificial ones
 * (Fig 5.6): with none, its lowest-numbered boundary vertex and the vertices nearest a third and two
 * thirds of the way round; with one, the two at a third and two thirds from it; with two, the vertex
 * nearest the middle of the longer arc between them. Lengths are metric lengths in the embedding, or
 * edge counts when embedding is NULL. Every chart (values in [0, triangle_count)) must be a disc, else
 * SK_ERROR_ARGUMENT naming it. sk_flatten completes the corners of its charts by the same rule.
 * @param[out] corners  vertex_count (0 or 1)
 * @param[in] charts  triangle_count
 * @param[in] embedding  vertex_count*dimension (may be NULL)
 */
sk_status sk_chart_corners(unsigned char *corners, const sk_triangle_mesh *mesh, const int32_t *charts,
                           const double *embedding, size_t dimension, sk_error *error);

typedef struct sk_straighten_options {
    double ratio; /* >= 1: how much a chart's metric may grow before the path is constrained (the ratio rule) */
    double rho;   /* weight of the compactness term in eq. 5.4, as in sk_segment_options */
} sk_straighten_options;

typedef struct sk_straighten_report {
    size_t paths;       /* chart boundaries between two corners and two charts (the mesh border stays) */
    size_t shortest;    /* replaced by the shortest path */
    size_t constrained; /* replaced by the path through the old boundary's vertices (the ratio rule) */
    size_t kept;        /* left as they were: already straight, or straightening would break a disc */
} sk_straighten_report;

/*
 * Edge straightening (section 5.2.3): each boundary path between two corners that separates charts L and
 * R is replaced by the shortest path (Dijkstra on mesh edges, metric lengths) between the same corners
 * through the two charts, touching no other boundary; triangles are reassigned by flood fill from the
 * rest of each chart's boundary. If L's or R's metric (eq. 5.4, with rho) grows by more than `ratio`,
 * the path is recomputed through the old boundary's vertices only, short-cutting some of them. A change
 * that would leave either chart not a disc is not made. Corners are computed first as in
 * sk_chart_corners and are kept. Every chart must be a disc on entry; chart ids are unchanged. report may
 * be NULL.
 * @param[in,out] charts  triangle_count
 * @param[out] corners  vertex_count
 * @param[in] embedding  vertex_count*dimension
 */
sk_status sk_straighten_charts(int32_t *charts, unsigned char *corners, sk_straighten_report *report,
                               const sk_triangle_mesh *mesh, const double *embedding, size_t dimension,
                               const sk_straighten_options *options, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Flattening (Merry 2007, section 5.3)
 *
 * The metric is given per triangle (a, b, c) by its squared metric edge lengths |ab|^2, |bc|^2, |ca|^2
 * (edge_lengths_sq: 3 per triangle), which determine its Gram matrix: with e1 = b - a, e2 = c - a,
 * g11 = |ab|^2, g22 = |ca|^2, g12 = (|ab|^2 + |ca|^2 - |bc|^2) / 2. Every triangle must have a positive
 * metric area (g11 g22 - g12^2 > 1e-14 g11 g22). uv is given per triangle corner: 6 doubles per triangle,
 * (u, v) of corners a, b, c. A uv triangle is valid when its signed area (counterclockwise positive) is
 * above 1e-12 times its longest edge squared, else it is flipped or degenerate.
 * ------------------------------------------------------------------------------------------- */

typedef struct sk_flatten_options {
    int straight;         /* nonzero: pin the boundary straight between corners (passes 2 and 3) */
    int optimise;         /* nonzero: follow every pass with the L2 stretch optimisation */
    double stretch_limit; /* >= 1: add corners when straightening raises the stretch more than this factor */
    int sweep_limit;      /* >= 0: the optimisation's sweeps over the vertices, per pass */
    int thread_count;     /* 0: the online processors */
} sk_flatten_options;

typedef struct sk_flatten_report {
    size_t chart_count;         /* charts in the result */
    size_t split_count;         /* overlap splits made (and splits of their pieces that were not discs) */
    size_t flip_splits;         /* splits of charts that every pass left with flipped or degenerate triangles */
    size_t straight_charts;     /* charts with the straight boundary of pass 2 */
    size_t circle_charts;       /* charts with the unit-circle boundary of pass 3 */
    size_t free_charts;         /* charts left with the free boundary (asked for, or straightening failed) */
    size_t extra_corners;       /* corners added because straightening flipped triangles or stretched too much */
    size_t tutte_charts;        /* charts whose free LSCM layout flipped triangles, restarted from Tutte's embedding */
    size_t invalid_triangles;   /* uv triangles still flipped or degenerate (0 unless every pass failed) */
    size_t overlapping_charts;  /* charts whose boundary still crosses itself (no split was possible) */
    size_t solver_iterations;   /* conjugate-gradient iterations, all charts */
    size_t optimisation_sweeps; /* stretch-optimisation sweeps, all charts */
} sk_flatten_report;

/*
 * Flattens each chart (charts: one id in [0, triangle_count) per triangle) into its own 2D frame, in metric units.
 * A chart made of several edge-connected pieces is flattened piece by piece; every piece must be a topological disc
 * whose triangles are consistently oriented (the error names the chart otherwise). Per chart: LSCM (Levy 2002) in
 * the triangles' isometric local frames with two far-apart boundary vertices pinned (or, when that flips a
 * triangle, Tutte's embedding with the boundary on a circle), scaled to the chart's metric area (pass 1, the result
 * when straight == 0); with straight, every boundary vertex is then pinned: corners (corners: vertex_count flags;
 * at least three per chart, completed as in sk_chart_corners when missing) at their pass-1 positions and the others
 * on straight lines spaced by metric edge length (pass 2); if that flips triangles, the corners go on a circle of
 * the chart's perimeter (pass 3); if that flips too or the stretch exceeds stretch_limit times pass 1's, an extra
 * corner is added and the passes restart. With optimise, every pass is followed by the minimisation of the chart's
 * normalised L2 stretch (Sander 2001) by Newton steps on one vertex at a time, none of which flips a triangle,
 * until a sweep gains less than 1e-6 or after sweep_limit sweeps. A chart whose flattened boundary crosses itself
 * is split in two by a two-source breadth-first search over faces and each half flattened again; so is a chart that
 * every pass left with a flipped or degenerate triangle (down to single triangles, which always flatten unless the
 * metric triangle itself is thinner than a valid uv triangle). charts_out receives the result's chart ids, 0 ..
 * report->chart_count - 1, numbered in the order of the given charts.
 * @param[out] uv  triangle_count*6
 * @param[out] charts_out  triangle_count
 * @param[in] edge_lengths_sq  triangle_count*3
 * @param[in] charts  triangle_count
 * @param[in] corners  vertex_count
 */
sk_status sk_flatten(double *uv, int32_t *charts_out, sk_flatten_report *report, const sk_triangle_mesh *mesh,
                     const double *edge_lengths_sq, const int32_t *charts, const unsigned char *corners,
                     const sk_flatten_options *options, sk_error *error);

/*
 * Sander et al. 2001's L2 stretch per triangle: sqrt((s1^2 + s2^2) / 2), s1 and s2 the singular values of the
 * map from uv to the metric (eq. 5.6-5.8); INFINITY for a flipped or degenerate uv triangle. destination:
 * triangle_count.
 */
sk_status sk_triangle_stretch(double *destination, const double *uv, const double *edge_lengths_sq,
                              size_t triangle_count, sk_error *error);

/*
 * Sander's normalised L2 stretch of the whole mesh: the metric-area-weighted RMS of the triangles' stretch
 * with uv rescaled so that the total uv area equals the total metric area (1 for an isometry, never less);
 * INFINITY when any uv triangle is flipped or degenerate.
 */
sk_status sk_mesh_stretch(double *stretch, const double *uv, const double *edge_lengths_sq, size_t triangle_count,
                          sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Packing (section 5.4)
 * ------------------------------------------------------------------------------------------- */

/* The largest texture sk_pack packs for: twice what GPUs sample today (16384-32768), and a bound on its work. */
#define SK_PACK_MAX_TEXTURE_SIZE 65536

typedef struct sk_pack_options {
    int texture_size; /* texels along a side of the square texture, in [1, SK_PACK_MAX_TEXTURE_SIZE] */
    double margin;    /* texels kept free between charts and to the border, >= 0 */
} sk_pack_options;

typedef struct sk_pack_report {
    size_t chart_count;
    double scale;              /* texture units per metric unit once charts are at a common density */
    double packing_efficiency; /* the uv triangles' total area: the fraction of the square covered */
} sk_pack_report;

/*
 * Packs the charts (charts: one id in [0, triangle_count) per triangle; uv: 6 per triangle, each chart in its
 * own frame, valid triangles) into the unit square: each chart is scaled so that its uv area equals its
 * surface area (surface_area: one per triangle, positive; NULL keeps the charts' uv scales), turned to the
 * orientation of its smallest bounding rectangle (rotating calipers on its convex hull), and packed by its
 * outline: rasterized conservatively on a grid of texels (at most 1024 cells a side), grown by the margin, and
 * placed, largest first, at the quarter turn and place whose top is lowest where it covers no earlier chart, so
 * small charts fill the holes larger ones leave; the largest common scale that fits is found by bisection. Charts
 * stay at least `margin` texels (at texture_size) from each other and from the border.
 * destination: 6 per triangle, in [0, 1].
 */
sk_status sk_pack(double *destination, sk_pack_report *report, const double *uv, const int32_t *charts,
                  const double *surface_area, size_t triangle_count, const sk_pack_options *options,
                  sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Level of detail: influence simplification (Merry 2007, section 6.3, eq. 6.1, appendix A.2) and
 * Limit Influences (section 6.4). Experimental.
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
 * ------------------------------------------------------------------------------------------- */

/* The most influences one vertex may have (the dense work per vertex grows as its cube). */
#define SK_LOD_MAX_VERTEX_INFLUENCES 64
/* The most tangent sets sk_limit_influences carries along (a vertex has two tangents; a few more serve
 * normals or extra frames): a bound on the work per vertex even when the arrays are empty. */
#define SK_LOD_MAX_TANGENT_SETS 16

/*
 * Removes influence `removed` (an index in [0, count)) from one homogeneous vector: bones (count
 * distinct bone indices, 2 <= count <= SK_LOD_MAX_VERTEX_INFLUENCES) and coordinates (count 4-vectors,
 * a position or a tangent) describe it. corrected: count 4-vectors in the input's layout, the kept bones'
 * corrected coordinates with the removed influence's slot zero. cost (may be NULL): ||s||_{2,2}.
 */
SK_EXPERIMENTAL sk_status sk_remove_influence(double *corrected, double *cost, const int32_t *bones,
                                              const double *coordinates, size_t count, size_t removed,
                                              const sk_pose_statistics *statistics, sk_error *error);

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
SK_EXPERIMENTAL sk_status sk_limit_influences(int32_t *limited_offsets, int32_t *limited_bones,
                                              double *limited_coordinates, size_t *limited_count, double *costs,
                                              double *limited_tangents, const sk_influences *influences,
                                              const double *coordinates, const double *tangents, size_t tangent_count,
                                              const sk_pose_statistics *statistics, size_t max_influences,
                                              int thread_count, sk_progress_fn progress, void *progress_user,
                                              sk_error *error);


/* ---------------------------------------------------------------------------------------------
 * Level of detail: one progressive-mesh simplification step (Merry 2007, sections 6.2-6.3.1). Experimental.
 *
 * Half-edge collapses u -> v (v keeps its position and coordinates; the surviving triangles' corners of u
 * become v) and influence collapses (sk_remove_influence's least L2,2 correction) share one priority queue and
 * are applied cheapest first, ranked by absolute deviation. An edge collapse costs its memoryless APS
 * deviation: the largest distance, over the cell corners of the overlay in parameter space of u's old one-ring
 * and its new triangulation, between the old and the new interpolated position: ||dp||_{2,2} =
 * sqrt(dp^T P dp) with P's blocks over the neighbourhood's bones (SK_LOD_METRIC_ANIMATION), or the rest-pose
 * Euclidean distance of the interpolated rest positions (SK_LOD_METRIC_REST, the thesis' baseline; influence
 * collapses are still costed in L2,2). Parameter space is the chart's UVs (6 per triangle) when given, else a
 * planar projection of u's one-ring onto its area-weighted normal's plane.
 *
 * A collapse u -> v is refused (and counted by reason in the report) when it would
 *   - flip or degenerate a triangle in UV or in the rest pose (refused_flip; also a one-ring that does not
 *     project one-to-one without UVs);
 *   - take u's UV corners out of their chart: every group of u's corners joined across non-seam edges (one
 *     per chart u is in) must contain a face of edge uv (refused_chart);
 *   - change the mesh boundary or a seam (an edge between two charts or with differing UVs at either end):
 *     a vertex on them must have exactly two such edges, uv one of them, and the boundary must be straight
 *     there in the UVs of every chart containing u, and for the mesh boundary also in 3D (refused_seam);
 *   - cross a locked edge (locked, 3 flags per triangle: side k joins corners k and k + 1) or a material
 *     border: the same rule as a seam, straight in 3D (refused_locked);
 *   - break the link condition (u's and v's neighbours in common are exactly the opposite corners of the
 *     edge's faces) or duplicate a face, or u has more than 256 faces (refused_link).
 * Straight means each turn's sine (and in UV, the cross product over the product of the lengths) is at most
 * options->straightness and the two edges point apart.
 *
 * Memoryless costs depend only on the current mesh and ties are broken by vertex index, edges before
 * influences, so calling this again on its own output (triangles_out, uv_out, locked_out, charts and
 * materials gathered by triangle_origin, the output coordinates) to a lower target gives what one call to that target gives.
 * Memory is O(vertices + triangles + influences).
 * ------------------------------------------------------------------------------------------- */

typedef enum sk_lod_metric {
    SK_LOD_METRIC_ANIMATION = 0, /* ||dp||_{2,2} */
    SK_LOD_METRIC_REST = 1       /* rest-pose Euclidean distance */
} sk_lod_metric;

typedef struct sk_simplify_options {
    size_t target_triangles;  /* stop once at most this many triangles remain; 0: no triangle target */
    size_t target_influences; /* and at most this many influences (over the vertices in use); 0: none */
    int metric;               /* sk_lod_metric */
    int simplify_influences;  /* non-zero: influence collapses share the queue */
    double straightness;      /* 0 <= tolerance of the straight-boundary rule (1e-6 is a good default) */
} sk_simplify_options;

typedef struct sk_simplify_report {
    size_t triangle_count;       /* surviving triangles */
    size_t vertex_count;         /* vertices in use */
    size_t influence_count;      /* influences of the vertices in use */
    size_t edge_collapses, influence_collapses;
    double epsilon;              /* the largest cost applied (0 when nothing was) */
    int exhausted;               /* 1 when no legal collapse remained before the targets were met */
    size_t refused_flip, refused_chart, refused_seam, refused_link, refused_locked; /* candidate evaluations */
} sk_simplify_report;

/*
 * Simplifies to the targets (at least one set). Every triangle must be used by a manifold, consistently
 * oriented surface (sk_validate_surface); a vertex in use needs 1 to SK_LOD_MAX_VERTEX_INFLUENCES distinct
 * influences; vertices no triangle uses are copied. uv (may be NULL), charts and materials (may be NULL,
 * any int32 ids) and locked (may be NULL) are per triangle.
 *
 * Outputs, with the input's capacity: triangles_out (the first report->triangle_count triangles, in input
 * order, on the input's vertex indices, corners in their input order), triangle_origin (each one's input
 * triangle), uv_out (may be NULL; their UVs, u's corners given v's UV in the same chart), locked_out (may be
 * NULL; their locked sides, where merged edges join their flags), vertex_map (every
 * input vertex's survivor: itself when it survives or is unused), offsets_out/bones_out/coordinates_out (a CSR
 * over all input vertices: removed vertices get empty rows, the others their possibly simplified influences,
 * kept bones in their input order; offsets_out's last entry is the total). progress (may be NULL) is
 * called every 256 collapses; a non-zero return cancels (SK_ERROR_CANCELLED).
 * @param[out] triangles_out  triangle_count*3
 * @param[out] triangle_origin  triangle_count
 * @param[out] uv_out  triangle_count*6 (may be NULL)
 * @param[out] locked_out  triangle_count*3 (may be NULL)
 * @param[out] vertex_map  vertex_count
 * @param[out] offsets_out  vertex_count+1
 * @param[out] bones_out  influence_count
 * @param[out] coordinates_out  influence_count*4
 * @param[in] mesh  triangle_count*3
 * @param[in] rest_positions  vertex_count*3
 * @param[in] coordinates  influence_count*4
 * @param[in] uv  triangle_count*6 (may be NULL)
 * @param[in] charts  triangle_count (may be NULL)
 * @param[in] materials  triangle_count (may be NULL)
 * @param[in] locked  triangle_count*3 (may be NULL)
 */
SK_EXPERIMENTAL sk_status sk_simplify(int32_t *triangles_out, int32_t *triangle_origin, double *uv_out,
                                      unsigned char *locked_out, int32_t *vertex_map, int32_t *offsets_out, int32_t *bones_out,
                                      double *coordinates_out, sk_simplify_report *report,
                                      const sk_triangle_mesh *mesh, const double *rest_positions,
                                      const sk_influences *influences, const double *coordinates,
                                      const sk_pose_statistics *statistics, const double *uv, const int32_t *charts,
                                      const int32_t *materials, const unsigned char *locked,
                                      const sk_simplify_options *options, sk_progress_fn progress,
                                      void *progress_user, sk_error *error);

#ifdef __cplusplus
}
#endif

#endif /* SKINKIT_H */
