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
 * Runtime: culling, level selection, geomorphing skinning (Merry 2007, chapter 7)
 *
 * What a game engine embeds per frame: single precision, no LAPACK, no allocation. The caller keeps a
 * character's discrete levels of detail (from the offline LOD chain) in one sk_runtime_pack and, each frame,
 * (1) culls each instance's bounding sphere against the view frustum (section 7.2), (2) selects a real-valued
 * level l per visible instance from a pixel tolerance (eq. 7.2), and (3) skins every visible instance at its
 * level in one batched call: mesh floor(l) evaluated at the geomorph fraction f = l - floor(l) (eq. 7.1).
 *
 * Geomorph data (algorithm 1, section 7.4): each influence k of a morphing mesh stores p_k and dp_k interleaved
 * as 8 floats (p_k, then dp_k = p_k^{l+1} - p_k^l on the common influence set, zero-padded), and the vertex is
 * v = sum_k G_{bones[k]} (p_k + f dp_k). A mesh that does not morph (the coarsest) stores dp = 0. Tangents use
 * the same pattern with weight-0 vectors. Bone matrices are 3x4 row-major floats (the top rows of G_j), 12 per
 * bone; bone 0 is the root (usually the object's identity).
 * ------------------------------------------------------------------------------------------- */

/* Vertex transformation kernels. AUTO picks the fastest the CPU supports (AVX2+FMA, then SSE2, then scalar);
 * the others are chosen explicitly for testing and benchmarks. All give the same results to float rounding. */
typedef enum sk_runtime_kernel {
    SK_RUNTIME_KERNEL_AUTO = 0,
    SK_RUNTIME_KERNEL_SCALAR = 1,
    SK_RUNTIME_KERNEL_SSE2 = 2,
    SK_RUNTIME_KERNEL_AVX2 = 3
} sk_runtime_kernel;

/*
 * *supported = 1 when this build and this CPU can run kernel (AUTO and SCALAR always), else 0.
 * SK_ERROR_ARGUMENT for an unknown kernel value.
 */
SK_EXPERIMENTAL sk_status sk_runtime_kernel_supported(size_t *supported, int kernel, sk_error *error);

/*
 * The six planes of the frustum of a view-projection matrix (row-major, clip = M (x, y, z, 1), the OpenGL
 * convention -w <= x, y, z <= w) by Gribb and Hartmann's row sums: plane i is (a, b, c, d) with (a, b, c) a unit
 * normal pointing inside, a point being inside when a x + b y + c z + d >= 0. Order: left, right, bottom, top,
 * near, far. SK_ERROR_ARGUMENT when a plane has no normal (a degenerate matrix), naming it.
 * @param[out] planes  24
 * @param[in] view_projection  16
 */
SK_EXPERIMENTAL sk_status sk_runtime_frustum_planes(float *planes, const float *view_projection, sk_error *error);

/*
 * Frustum culling (section 7.2): visible[i] = 0 when sphere i (centre x, y, z and radius, in the planes' space)
 * lies entirely outside one of the planes, else 1. Conservative: a sphere that touches the frustum is never
 * culled. Radii must be >= 0; every value finite (the element is named otherwise).
 * @param[out] visible  sphere_count
 * @param[in] spheres  sphere_count*4
 * @param[in] planes  plane_count*4
 */
SK_EXPERIMENTAL sk_status sk_runtime_cull(uint8_t *visible, const float *spheres, size_t sphere_count,
                                          const float *planes, size_t plane_count, sk_error *error);

/* A perspective camera for level selection: its position and unit viewing direction in the spheres' space,
 * its horizontal field of view 2 theta (radians, in (0, pi)) and its viewport width w in pixels. */
typedef struct sk_runtime_camera {
    const float *position; /* 3 */
    const float *forward;  /* 3, unit length */
    float horizontal_fov;
    float viewport_width;
} sk_runtime_camera;

/*
 * Level selection (section 7.3): for instance i with bounding sphere (c, r), d is the sphere's minimum depth
 * max(forward . (c - position) - r, 0), the allowed error e = 2 pixel_tolerance d sin(theta) / w (eq. 7.2), and
 * levels[i] the real level between the two discrete levels whose epsilons bracket e, by linear interpolation:
 * with epsilons[i*level_count + k] = eps^k (non-decreasing in k, eps^0 = 0, +infinity pads a chain with fewer
 * levels), l = k + (e - eps^k) / (eps^{k+1} - eps^k) for eps^k <= e < eps^{k+1}, and the last finite level
 * when e is at least its epsilon. The interpolated epsilon never exceeds e.
 * @param[out] levels  instance_count
 * @param[in] spheres  instance_count*4
 * @param[in] epsilons  instance_count*level_count
 */
SK_EXPERIMENTAL sk_status sk_runtime_select_levels(float *levels, const float *spheres, const float *epsilons,
                                                   size_t instance_count, size_t level_count,
                                                   const sk_runtime_camera *camera, float pixel_tolerance,
                                                   sk_error *error);

/* Geomorphed texture coordinates (listing C.5: texcoords.xy + f texcoords.zw): destination[2c..2c+1] =
 * (u, v) + fraction (du, dv) with uv_morph[4c..4c+3] = (u, v, du, dv) for each of corner_count corners.
 * @param[out] destination  corner_count*2
 * @param[in] uv_morph  corner_count*4
 */
SK_EXPERIMENTAL sk_status sk_runtime_morph_uv(float *destination, const float *uv_morph, size_t corner_count,
                                              float fraction, sk_error *error);

/* The meshes an engine skins, as one CSR pattern over all their vertices: mesh m owns vertices
 * mesh_starts[m] .. mesh_starts[m + 1] - 1 (and their influences). tangents may be NULL (positions only). */
typedef struct sk_runtime_pack {
    sk_influences influences;    /* over all meshes' vertices */
    const float *positions;      /* influence_count * 8: p_k then dp_k */
    const float *tangents;       /* influence_count * 16: the two tangents' (p_k, dp_k), or NULL */
    const int32_t *mesh_starts;  /* mesh_count + 1, from 0 to vertex_count, non-decreasing */
    size_t mesh_count;
} sk_runtime_pack;

/* The instances to skin: instance i draws mesh meshes[i] at geomorph fraction fractions[i] in [0, 1] with its
 * own bone_count 3x4 matrices, into output vertices output_starts[i] .. output_starts[i + 1] - 1 (which must be
 * exactly the mesh's vertex count long; ranges may not overlap: output_starts is non-decreasing from 0). */
typedef struct sk_runtime_instances {
    const int32_t *meshes;        /* instance_count */
    const float *fractions;       /* instance_count */
    const float *matrices;        /* instance_count * bone_count * 12 */
    const int32_t *output_starts; /* instance_count + 1 */
    size_t instance_count;
    size_t bone_count;
} sk_runtime_instances;

/*
 * Batched geomorphing skinning, CPU algorithm 1: for every instance i and vertex v of its mesh, output vertex
 * o = output_starts[i] + (v - mesh start) gets positions[3o..3o+2] = sum_k G_{bones[k]} (p_k + f_i dp_k), and
 * likewise each tangent (tangent_0 and tangent_1, each output_vertex_count*3, or both NULL, which needs no
 * pack tangents). Work is split over all instances' vertices at once, so a crowd of small characters uses every
 * thread (thread_count as for evaluation). Matrices and fractions are checked finite; bone indices and offsets
 * are range-checked as they are read (the first bad vertex is named); the coordinates are not checked.
 * @param[out] positions, tangent_0, tangent_1  output_vertex_count*3 (tangents may be NULL)
 */
SK_EXPERIMENTAL sk_status sk_runtime_skin(float *positions, float *tangent_0, float *tangent_1,
                                          size_t output_vertex_count, const sk_runtime_pack *pack,
                                          const sk_runtime_instances *instances, int kernel, int thread_count,
                                          sk_error *error);

/* The same meshes in a fixed-K layout that moves fewer bytes per vertex (a fixed number of influences, no
 * offsets, 16-bit bone indices): every vertex has exactly influences_per_vertex = K slots (K even, padded with
 * zero coordinates on any valid bone), bone_count <= 65535, and per pair of slots (2j, 2j + 1) the floats
 *   floats_per_slot 8 (morphing): p_2j, p_2j+1, dp_2j, dp_2j+1 (p and dp side by side in 256-bit lanes),
 *   floats_per_slot 4 (no geomorph data, as animation-space evaluation reads it): p_2j, p_2j+1,
 * so vertex v's floats start at v K floats_per_slot. tangent_0 and tangent_1 use the positions' layout
 * (weight-0 vectors), or are both NULL. */
typedef struct sk_runtime_fixed_pack {
    const uint16_t *bones;        /* vertex_count * K */
    const float *positions;       /* vertex_count * K * floats_per_slot */
    const float *tangent_0;       /* as positions, or NULL */
    const float *tangent_1;       /* as positions, or NULL */
    const int32_t *mesh_starts;   /* mesh_count + 1, from 0 to vertex_count, non-decreasing */
    size_t mesh_count;
    size_t vertex_count;
    size_t influences_per_vertex; /* K: even, 2 .. 64 */
    size_t floats_per_slot;       /* 8: p and dp, fractions in [0, 1]; 4: p only, every fraction must be 0 */
} sk_runtime_fixed_pack;

/*
 * sk_runtime_skin over a fixed-K pack: the same outputs (positions[3o..3o+2] = sum_k G_{bones[k]} (p_k + f_i dp_k)
 * and the tangents likewise) for the same instances, computed four vertices at a time by the chosen kernel.
 * Bone indices are range-checked as they are read (the first bad vertex is named); matrices and fractions are
 * checked finite; SK_ERROR_ARGUMENT for an odd or out-of-range K, floats_per_slot other than 4 or 8, or a non-zero
 * fraction on a pack that does not morph; SK_ERROR_INDEX when mesh_starts do not run from 0 to vertex_count.
 * @param[out] positions, tangent_0, tangent_1  output_vertex_count*3 (tangents may be NULL)
 */
SK_EXPERIMENTAL sk_status sk_runtime_skin_fixed(float *positions, float *tangent_0, float *tangent_1,
                                                size_t output_vertex_count, const sk_runtime_fixed_pack *pack,
                                                const sk_runtime_instances *instances, int kernel, int thread_count,
                                                sk_error *error);

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
 * Choosing the per-vertex fit's lambda by cross-validation (issue 18)
 * ------------------------------------------------------------------------------------------- */

/*
 * Cross-validated error of the per-vertex fit (sk_fit_per_vertex, towards prior or zero) for each of lambda_count
 * lambdas at once. Example e (of the first example_count - fitted_tail) is validated in fold e % fold_count: the
 * fit on every other example (the last fitted_tail, e.g. a weighted rest pose, are always fitted) predicts it.
 * Per vertex and fold the QR factorisation of the fitted rows is made once and reused by every lambda.
 * squared_errors[v * lambda_count + l]: vertex v's squared distance to its validated examples, summed over the
 * folds, under lambdas[l]. 2 <= fold_count <= example_count - fitted_tail; lambdas finite and >= 0. Each fold's
 * fits pull towards fold_priors' fold-th block (a prior fitted without that fold's examples, so that validation
 * does not see them through it) when given, else towards prior (or zero when both are NULL).
 * @param[out] squared_errors  vertex_count*lambda_count
 * @param[in] prior  influence_count*4 (may be NULL)
 * @param[in] fold_priors  fold_count*influence_count*4 (may be NULL)
 * @param[in] lambdas  lambda_count
 */
sk_status sk_validate_per_vertex(double *squared_errors, const sk_influences *influences, const sk_examples *examples,
                                 size_t fitted_tail, size_t fold_count, const double *prior, const double *fold_priors,
                                 const double *lambdas, size_t lambda_count, int thread_count, sk_error *error);

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
    size_t tutte_charts;        /* charts whose free layout flipped triangles, restarted from Tutte's embedding */
    size_t invalid_triangles;   /* uv triangles still flipped or degenerate (0 unless every pass failed) */
    size_t overlapping_charts;  /* charts whose boundary still crosses itself (no split was possible) */
    size_t solver_iterations;   /* conjugate-gradient iterations, all charts */
    size_t optimisation_sweeps; /* stretch-optimisation sweeps, all charts */
    size_t boundary_first_charts; /* charts whose free pass was boundary first flattening (1000+ interior vertices) */
    size_t stretch_splits;      /* splits of large free-boundary charts still stretched more than 1.1 when optimised */
} sk_flatten_report;

/*
 * Flattens each chart (charts: one id in [0, triangle_count) per triangle) into its own 2D frame, in metric units.
 * A chart made of several edge-connected pieces is flattened piece by piece; every piece must be a topological disc
 * whose triangles are consistently oriented (the error names the chart otherwise). Per chart: LSCM (Levy 2002) in
 * the triangles' isometric local frames with two far-apart boundary vertices pinned, or, for a chart with 1000
 * interior vertices or more, boundary first flattening (Sawhney and Crane 2017: a conformal map whose boundary keeps
 * its metric lengths, from solves whose steps do not grow with the chart); when that flips a triangle, Tutte's
 * embedding with the boundary on a circle; scaled to the chart's metric area (pass 1, the result when
 * straight == 0); with straight, every boundary vertex is then pinned: corners (corners: vertex_count flags; at least
 * three per chart, completed as in sk_chart_corners when missing) at their pass-1 positions and the others on
 * straight lines spaced by metric edge length (pass 2); if that flips triangles, the corners go on a circle of the
 * chart's perimeter (pass 3); if that flips too or the stretch exceeds stretch_limit times pass 1's, an extra corner
 * is added and the passes restart. With optimise, every pass is followed by the minimisation of the chart's
 * normalised L2 stretch (Sander 2001) by Newton steps on one vertex at a time, none of which flips a triangle,
 * until a sweep gains less than 1e-6 or after sweep_limit sweeps. A chart whose flattened boundary crosses itself
 * is split in two by a two-source breadth-first search over faces and each half flattened again; so is a
 * free-boundary chart of 2000 triangles or more whose optimised layout still stretches more than 1.1 (too curved to
 * lie flat whole; split around its most stretched triangle), and a chart that every pass left with a flipped or
 * degenerate triangle (down to single triangles, which always flatten unless the
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
 * Limit Influences in a given metric (issue 11). Experimental.
 *
 * sk_limit_influences with the metric's P given as blocks rather than formed from joint statistics:
 * metric_blocks holds bone_count^2 row-major 4x4 blocks, P_jk at metric_blocks + 16 * (j * bone_count + k),
 * symmetric (P_jk = P_kj^T) and positive semi-definite; for example the sample second moments
 * E[G_j^T G_k] over posed frames, which the joint-independence product of sk_pose_statistics only
 * approximates, or a blend of the two. Every other argument and output as sk_limit_influences.
 * ------------------------------------------------------------------------------------------- */

SK_EXPERIMENTAL sk_status sk_limit_influences_in_metric(int32_t *limited_offsets, int32_t *limited_bones,
                                                        double *limited_coordinates, size_t *limited_count,
                                                        double *costs, double *limited_tangents,
                                                        const sk_influences *influences, const double *coordinates,
                                                        const double *tangents, size_t tangent_count,
                                                        const double *metric_blocks, size_t bone_count,
                                                        size_t max_influences, int thread_count,
                                                        sk_progress_fn progress, void *progress_user,
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
 *   - flip or degenerate a triangle in UV or in the rest pose, or make a rest-pose triangle thinner than 0.05
 *     (twice its area over its longest edge squared) that is thinner than the one it replaces and turned from it
 *     by more than 5 degrees: a thin face that turns dents the shading (refused_flip; also a one-ring that does
 *     not project one-to-one without UVs);
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
 * triangle), uv_out (may be NULL, and must be when uv is; their UVs, u's corners given v's UV in the same chart), locked_out (may be
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

/* ---------------------------------------------------------------------------------------------
 * Level of detail: a whole chain of levels in one run (Merry 2007, section 7.3). Experimental.
 *
 * One priority queue of sk_simplify's collapses, run once from the input: each level is snapshotted when its
 * targets are met and the queue carries on to the next, so every candidate is costed once for the whole chain
 * (memoryless costs depend only on the current mesh, so level l equals sk_simplify called on level l - 1's
 * outputs to level l's targets). Memory: O(vertices + triangles + influences) besides the outputs.
 * ------------------------------------------------------------------------------------------- */

typedef struct sk_simplify_chain_options {
    size_t level_count;               /* levels after the input (>= 1) */
    const int32_t *target_triangles;  /* level_count entries >= 0, or NULL; 0: no triangle target */
    const int32_t *target_influences; /* level_count entries >= 0, or NULL; 0: no influence target. A level with
                                         neither gets at most half the influences of the level before (7.3) */
    int metric;                       /* sk_lod_metric */
    int simplify_influences;          /* non-zero: influence collapses share the queue */
    double straightness;              /* as sk_simplify_options */
} sk_simplify_chain_options;

typedef struct sk_simplify_chain_report {
    size_t level_count;   /* levels written: fewer than asked when the queue ran dry (exhausted) or a halving
                             level found fewer than 2 influences to halve */
    int exhausted;        /* 1: no legal collapse remained before the last written level's targets */
    size_t edge_collapses, influence_collapses; /* over the whole chain */
    size_t refused_flip, refused_chart, refused_seam, refused_link, refused_locked; /* candidate evaluations */
} sk_simplify_chain_report;

/*
 * Builds options->level_count levels from the input (sk_simplify's inputs and rules). Level l's outputs lie at
 * l times the input's capacity in each array, in sk_simplify's layout on the input's vertex indices:
 * triangles_out + 3*T*l, triangle_origin + T*l (input triangles), uv_out + 6*T*l (may be NULL; written when uv
 * is given), locked_out + 3*T*l (may be NULL), vertex_map + V*l (every input vertex's survivor at level l:
 * mapping level l - 1's vertices through it gives the map to the level above); the influences are one CSR
 * over the rows (level, vertex): level l's rows are offsets_out + V*l (V + 1 entries, level l's last shared with
 * level l + 1's first) into bones_out and coordinates_out, the levels one after another (level 0's first entry
 * 0; each level takes at most I, so I*level_count must fit int32). level_counts + 5*l: its triangles, vertices
 * in use, influences,
 * and the edge and influence collapses since level l - 1; level_epsilon[l]: the largest cost applied from the
 * input to it. Levels past report->level_count are not written. progress (may be NULL) gets the fraction of
 * the chain every 256 collapses; a non-zero return cancels (SK_ERROR_CANCELLED).
 * @param[out] triangles_out  level_count*3*triangle_count
 * @param[out] triangle_origin  level_count*triangle_count
 * @param[out] uv_out  level_count*6*triangle_count (may be NULL)
 * @param[out] locked_out  level_count*3*triangle_count (may be NULL)
 * @param[out] vertex_map  level_count*vertex_count
 * @param[out] offsets_out  level_count*vertex_count+1
 * @param[out] bones_out  level_count*influence_count
 * @param[out] coordinates_out  level_count*4*influence_count
 * @param[out] level_counts  level_count*5
 * @param[out] level_epsilon  level_count
 */
SK_EXPERIMENTAL sk_status sk_simplify_chain(int32_t *triangles_out, int32_t *triangle_origin, double *uv_out,
                                            unsigned char *locked_out, int32_t *vertex_map, int32_t *offsets_out,
                                            int32_t *bones_out, double *coordinates_out, int32_t *level_counts,
                                            double *level_epsilon, sk_simplify_chain_report *report,
                                            const sk_triangle_mesh *mesh, const double *rest_positions,
                                            const sk_influences *influences, const double *coordinates,
                                            const sk_pose_statistics *statistics, const double *uv,
                                            const int32_t *charts, const int32_t *materials,
                                            const unsigned char *locked, const sk_simplify_chain_options *options,
                                            sk_progress_fn progress, void *progress_user, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Level of detail: a tuned chain (issue 11: full-edge collapses, the queue's influence weighting). Experimental.
 *
 * sk_simplify_chain with choices the thesis leaves open:
 *   - collapse: SK_LOD_COLLAPSE_HALF (sk_simplify_chain's half-edge collapses u -> v), SK_LOD_COLLAPSE_FULL (an
 *     edge whose two ends touch no boundary, seam, material border or locked edge, in the animation metric, is
 *     costed with the survivor v's coordinates re-solved on v's own bones, their homogeneous weights' sum kept,
 *     to the minimiser of the memoryless APS cost: the largest L2,2 deviation over the overlay's cell corners and
 *     v itself; so a full collapse never adds influences; v keeps its UVs, which serve every level unchanged,
 *     and the legality checks are the half-edge ones) or SK_LOD_COLLAPSE_AUTO (the target chosen by the
 *     half-edge cost, then its survivor re-solved the same way: one solve per vertex costed instead of one per
 *     candidate). The minimax is solved by Lawson's reweighted least squares (32 steps), the best step kept, and
 *     used only where it lowers the half-edge cost and moves v's coordinates no farther than the farthest of the
 *     one-ring's are from them (a trust region: larger moves fit directions the poses barely show).
 *   - influence_cost_scale (> 0, finite; 1 is sk_simplify_chain): influence collapses rank in the queue at their
 *     cost times this against edge collapses (edges are queued at cost / scale); epsilon keeps the costs.
 *   - rank_per_influence (0 or 1): 1 ranks an edge collapse at its cost over the square root of the influences it
 *     removes (u's), so the queue orders collapses by squared cost per influence removed, as an influence budget
 *     asks; 0 ranks by cost (the thesis).
 * Every other argument, output and rule as sk_simplify_chain; SK_LOD_COLLAPSE_HALF, scale 1 and rank 0 give its bits.
 * ------------------------------------------------------------------------------------------- */

typedef enum sk_lod_collapse {
    SK_LOD_COLLAPSE_HALF = 0,
    SK_LOD_COLLAPSE_FULL = 1,
    SK_LOD_COLLAPSE_AUTO = 2
} sk_lod_collapse;

typedef struct sk_simplify_tuning {
    int collapse;                /* sk_lod_collapse */
    double influence_cost_scale; /* > 0: the queue ranks an influence collapse at its cost times this */
    int rank_per_influence;      /* 1: an edge collapse ranks at its cost over sqrt(the influences it removes) */
    int thread_count;            /* 0: two threads for 16,384 influences or more (where it pays), else one; 1: one;
                                    2 or more: two. Every level is the same bits on any count */
} sk_simplify_tuning;

/*
 * sk_simplify_chain with tuning (not NULL); level_full_collapses[l]: the full collapses among level l's edge
 * collapses since level l - 1.
 * @param[out] triangles_out  level_count*3*triangle_count
 * @param[out] triangle_origin  level_count*triangle_count
 * @param[out] uv_out  level_count*6*triangle_count (may be NULL)
 * @param[out] locked_out  level_count*3*triangle_count (may be NULL)
 * @param[out] vertex_map  level_count*vertex_count
 * @param[out] offsets_out  level_count*vertex_count+1
 * @param[out] bones_out  level_count*influence_count
 * @param[out] coordinates_out  level_count*4*influence_count
 * @param[out] level_counts  level_count*5
 * @param[out] level_epsilon  level_count
 * @param[out] level_full_collapses  level_count
 */
SK_EXPERIMENTAL sk_status sk_simplify_chain_tuned(int32_t *triangles_out, int32_t *triangle_origin, double *uv_out,
                                                  unsigned char *locked_out, int32_t *vertex_map, int32_t *offsets_out,
                                                  int32_t *bones_out, double *coordinates_out, int32_t *level_counts,
                                                  double *level_epsilon, sk_simplify_chain_report *report,
                                                  int32_t *level_full_collapses, const sk_triangle_mesh *mesh,
                                                  const double *rest_positions, const sk_influences *influences,
                                                  const double *coordinates, const sk_pose_statistics *statistics,
                                                  const double *uv, const int32_t *charts, const int32_t *materials,
                                                  const unsigned char *locked,
                                                  const sk_simplify_chain_options *options,
                                                  const sk_simplify_tuning *tuning, sk_progress_fn progress,
                                                  void *progress_user, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Level of detail: refitting a level to the full detail (issue 11). Experimental.
 *
 * With a level's triangles and influence sets fixed, moves its coordinates to the least expected squared distance
 * over the poses (the L2,2 norm of P, as the collapses are costed) between the full-detail surface and the level:
 * samples of the mesh (each triangle's centroid, at weight its area) are matched to their closest rest-pose points
 * on the level (level_rest), and the coordinates minimise sum_s w_s e_s^T P e_s plus options->pull times the mean sample
 * mass of a vertex times sum_j (x_j - x0_j)^T P_jj (x_j - x0_j), a pull towards level_coordinates that holds what
 * the samples hardly determine. Solved by at most options->max_steps block-Jacobi-preconditioned CG steps from
 * level_coordinates, stopping once the preconditioned residual falls below options->tolerance times its start.
 * The level and the mesh are separate meshes (the level's vertices numbered on their own); bones distinct within
 * a vertex, at most SK_LOD_MAX_VERTEX_INFLUENCES a vertex. coordinates_out: 4 per level influence (may be
 * level_coordinates). Same bits on any thread_count. progress (may be NULL) is called between steps.
 * ------------------------------------------------------------------------------------------- */
typedef struct sk_lod_refit_options {
    double pull;      /* the pull's weight per unit of mean vertex mass (0.1 measured: see BENCHMARKS.md) */
    size_t max_steps; /* CG steps at most (<= 1000) */
    double tolerance; /* in [0, 1) */
    int thread_count; /* as for evaluation */
} sk_lod_refit_options;

typedef struct sk_lod_refit_report {
    size_t samples;        /* samples of the mesh */
    size_t unmatched;      /* samples with no closest point (none on a level with triangles) */
    size_t steps;          /* CG steps taken */
    size_t influence_sets; /* distinct influence sets of the level (one diagonal-block factorisation each) */
    int kept_factors;      /* 1: the sets' inverses were kept for the solve; 0: refactored at each step (memory) */
    double start_residual, final_residual; /* the preconditioned residual's norm, before and after */
} sk_lod_refit_report;

SK_EXPERIMENTAL sk_status sk_lod_refit(double *coordinates_out, sk_lod_refit_report *report,
                                       const sk_triangle_mesh *level, const double *level_rest,
                                       const sk_influences *level_influences, const double *level_coordinates,
                                       const sk_triangle_mesh *mesh, const double *rest_positions,
                                       const sk_influences *influences, const double *coordinates,
                                       const sk_pose_statistics *statistics, const sk_lod_refit_options *options,
                                       sk_progress_fn progress, void *progress_user, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Skeletons from segmented meshes (Vasilakis 2008). Experimental.
 *
 * A mesh whose triangles are labelled with parts (triangle_parts: one id in [0, part_count) per triangle; every
 * part used) gets a skeleton from its parts' geometry. The opening between two parts is the set of vertices on
 * the edges where a triangle of one meets a triangle of the other; its centroid (oc) is their mean. The parts'
 * hierarchy is `parents` (part_count entries, -1 for the one root; every parent-child pair must share an
 * opening) or, when parents is NULL, a breadth-first tree over the openings from the part with the most
 * openings (ties: most triangles, then lowest id).
 *
 * Per part: the convex hull (Qhull) and its area-weighted surface centroid m_H; the kernel, the half-space
 * intersection of the part's triangles' inner sides and its openings' planes (each opening capped by its
 * best-fit plane), and the kernel centroid KC, the surface centroid of the kernel's hull. A part whose kernel is
 * empty (not star-shaped) uses m_H as its KC, and a part too flat or small for a hull (degenerate) the mean of
 * its vertices and their covariance: documented fallbacks, counted in the report. The principal directions are
 * the eigenvectors (LAPACKE) of Gottschalk's continuous covariance over the hull triangles, by decreasing
 * eigenvalue; the oriented box has each half-length (m1 + m2) / 2 along them. Triangles must be oriented
 * consistently (outward by the mesh's signed volume).
 *
 * Methods (section 3.2), each a depth-first walk of the hierarchy; every non-root part's root point is its
 * opening centroid with its parent:
 *   SK_SKELETON_OPENING: the root's vertex mean joins the ocs of its children; each part's oc joins its
 *     children's ocs (leaves add nothing).
 *   SK_SKELETON_CENTROID: root point -> KC -> each child's oc (the root's KC is the global root).
 *   SK_SKELETON_PRINCIPAL_AXIS: the line through KC along the principal axis, clipped to the hull; the ocs
 *     projected onto it (clamped to its ends), sorted, and grouped by the interval dynamic programme of
 *     Algorithm 2 (eqs 3.1-3.5; split loop k = i..j-1, zero denominators guarded); each oc joins its group's link
 *     point, consecutive link points join, and the first (last) link point joins the near (far) end of the axis
 *     unless it lies within closeness * length of it (the connecting rules 1-2 as one rule). The root part's
 *     middle link point is the global root.
 * Refinements (section 3.3), before the methods use the directions: local (Algorithm 3: each feature vector
 * oc - KC turns the frame toward it by weight * angle, weight 2 / (N + 1) for the parent's oc and 1 / (N + 1) for
 * the others, N the part's ocs; a turn above max_angle_degrees is skipped; then the direction along which the ocs
 * reach farthest from KC, sum of weight * (d . (oc - KC))^2, becomes the principal axis: the thesis' "each vector's
 * closest direction in turn" depended on the ocs' order); parent (Algorithm 4, top-down: the child's principal axis onto its parent's nearest
 * direction, then the nearest remaining pair about it; skipped when the first turn exceeds max_angle_degrees).
 * Angles between directions ignore sign.
 *
 * Joints: at most SK_SKELETON_JOINTS_PER_PART * part_count; joint_positions (3 each), joint_parents (-1 for the
 * root, else an earlier joint), joint_parts (the part it lies in; an oc belongs to the child part) and
 * joint_kinds (sk_skeleton_joint_kind). Per part: part_parents (the hierarchy used), part_joints (the joint at
 * its root point), kernel_centroids (3), principal_axes (9, rows), boxes (6: centre, half-lengths along the
 * axes), part_flags (SK_SKELETON_STAR_SHAPED, SK_SKELETON_DEGENERATE). Bad input: a part with no triangle or no
 * opening, a non-manifold edge, parts that do not connect into one tree, more than SK_SKELETON_MAX_OPENINGS
 * openings on one part: SK_ERROR_ARGUMENT naming the part.
 * ------------------------------------------------------------------------------------------- */

#define SK_SKELETON_JOINTS_PER_PART 5
#define SK_SKELETON_MAX_OPENINGS 512 /* per part: the grouping programme is cubic in them */
#define SK_SKELETON_STAR_SHAPED 1
#define SK_SKELETON_DEGENERATE 2

typedef enum sk_skeleton_method {
    SK_SKELETON_OPENING = 0,
    SK_SKELETON_CENTROID = 1,
    SK_SKELETON_PRINCIPAL_AXIS = 2
} sk_skeleton_method;

typedef enum sk_skeleton_joint_kind {
    SK_JOINT_ROOT_POINT = 0,      /* the root part's root point (vertex mean, KC or middle link point) */
    SK_JOINT_OPENING = 1,         /* an opening centroid */
    SK_JOINT_KERNEL_CENTROID = 2, /* a part's KC */
    SK_JOINT_LINK_POINT = 3,      /* a group's link point on the principal axis */
    SK_JOINT_AXIS_END = 4         /* an end of the clipped principal axis */
} sk_skeleton_joint_kind;

typedef struct sk_skeleton_options {
    int method;               /* sk_skeleton_method */
    int refine_local;         /* non-zero: Algorithm 3 */
    int refine_parent;        /* non-zero: Algorithm 4 */
    double max_angle_degrees; /* > 0: the refinements' largest turn (the thesis used 10-22) */
    double closeness;         /* in [0, 1): a link point this fraction of the axis from an end is "near" it */
} sk_skeleton_options;

typedef struct sk_skeleton_report {
    size_t joint_count, opening_count, star_shaped_count, degenerate_count;
    double opening_seconds, hull_seconds, kernel_seconds, method_seconds;
} sk_skeleton_report;

/*
 * @param[out] joint_positions  15*part_count
 * @param[out] joint_parents  5*part_count
 * @param[out] joint_parts  5*part_count
 * @param[out] joint_kinds  5*part_count
 * @param[out] part_parents  part_count
 * @param[out] part_joints  part_count
 * @param[out] kernel_centroids  part_count*3
 * @param[out] principal_axes  part_count*9
 * @param[out] boxes  part_count*6
 * @param[out] part_flags  part_count
 * @param[in] mesh  triangle_count*3
 * @param[in] positions  vertex_count*3
 * @param[in] triangle_parts  triangle_count
 * @param[in] parents  part_count (may be NULL)
 */
SK_EXPERIMENTAL sk_status sk_extract_skeleton(double *joint_positions, int32_t *joint_parents, int32_t *joint_parts,
                                              int32_t *joint_kinds, int32_t *part_parents, int32_t *part_joints,
                                              double *kernel_centroids, double *principal_axes, double *boxes,
                                              int32_t *part_flags, sk_skeleton_report *report,
                                              const sk_triangle_mesh *mesh, const double *positions,
                                              const int32_t *triangle_parts, size_t part_count,
                                              const int32_t *parents, const sk_skeleton_options *options,
                                              sk_error *error);

/*
 * Forward kinematics (section 4.3): each part p turns about its joint joints[p] (its opening with its parent) by
 * angles[p] (degrees about X, Y, Z) in the frame whose z-axis is parent_axes[p] (the thesis: joint -> parent's KC):
 * L_p = T(J) R(Q_align^-1 Q(X) Q(Y) Q(Z) Q_align) T(-J), world_p = world_parent L_p, the root's world
 * root_frame L_root (root_frame may be NULL: the identity). Parents may come in any order.
 * @param[out] world  part_count*16
 * @param[in] joints  part_count*3
 * @param[in] parent_axes  part_count*3
 * @param[in] angles  part_count*3
 * @param[in] parents  part_count
 * @param[in] root_frame  16 (may be NULL)
 */
SK_EXPERIMENTAL sk_status sk_forward_kinematics(double *world, const double *joints, const double *parent_axes,
                                                const double *angles, const int32_t *parents,
                                                const double *root_frame, size_t part_count, sk_error *error);

/*
 * Collision test of a pose (section 4.3): every pair of parts but a parent and its child whose bounding spheres
 * (about the posed boxes' centres) meet and whose oriented boxes (boxes and principal_axes as sk_extract_skeleton
 * gives them, moved by world) overlap by the 15-axis separating-axis test. pairs: 2 per pair (a < b), in order.
 * @param[out] pairs  pair_capacity*2
 * @param[in] world  part_count*16
 * @param[in] boxes  part_count*6
 * @param[in] principal_axes  part_count*9
 * @param[in] parents  part_count
 */
SK_EXPERIMENTAL sk_status sk_detect_collisions(int32_t *pairs, size_t *pair_count, const double *world,
                                               const double *boxes, const double *principal_axes,
                                               const int32_t *parents, size_t part_count, size_t pair_capacity,
                                               sk_error *error);

/*
 * The "others" lists of section 4.3, precomputed once per skeleton: the pairs a motion can bring into collision.
 * moved_part = -1: every pair but a parent and its child. Otherwise only the pairs with one part in moved_part's
 * subtree and the other outside it, again without a parent and its child: one joint turning moves its subtree
 * rigidly, so pairs on one side of it keep their relative pose. pairs: 2 per pair (a < b), in order.
 * @param[out] pairs  pair_capacity*2
 * @param[in] parents  part_count
 */
SK_EXPERIMENTAL sk_status sk_collision_candidates(int32_t *pairs, size_t *pair_count, const int32_t *parents,
                                                  size_t part_count, int32_t moved_part, size_t pair_capacity,
                                                  sk_error *error);

typedef struct sk_collision_report {
    size_t pair_count;  /* colliding pairs written */
    size_t sphere_hits; /* candidates whose bounding spheres meet */
    size_t box_tests;   /* separating-axis tests run (fewer than sphere_hits after an early stop) */
} sk_collision_report;

/*
 * sk_detect_collisions over candidate pairs (e.g. sk_collision_candidates'), in the thesis' order: each
 * candidate's sphere weight w = (l / r)^2 (l the posed spheres' centre distance, r their radii's sum), then the
 * separating-axis test on those with w <= 1, smallest w (likeliest) first. stop_at_first non-zero: return after
 * the first colliding pair (motion acceptance needs one). pairs: the colliding pairs (a < b) in test order.
 * @param[out] pairs  pair_capacity*2
 * @param[out] tested  candidate_count (the first sphere_hits: candidate indices in test order)
 * @param[out] sphere_weights  candidate_count
 * @param[in] world  part_count*16
 * @param[in] boxes  part_count*6
 * @param[in] principal_axes  part_count*9
 * @param[in] candidates  candidate_count*2
 */
SK_EXPERIMENTAL sk_status sk_detect_collisions_among(int32_t *pairs, int32_t *tested, double *sphere_weights,
                                                     sk_collision_report *report, const double *world,
                                                     const double *boxes, const double *principal_axes,
                                                     const int32_t *candidates, size_t candidate_count,
                                                     size_t part_count, int stop_at_first, size_t pair_capacity,
                                                     sk_error *error);

/*
 * Rigid skinning with seams (section 4.4): point k is rest vertex sources[k] moved by part parts_a[k] (v' = W v),
 * or, when parts_b[k] >= 0, a seam point: W_a M(t) v with M = W_a^-1 W_b turned about joints[parts_b[k]] by the
 * QLERP (eq. 4.1) of the identity and M's rotation at t = blend[k] in [0, 1] (its translation by t): the arcs that
 * close the gap a rotating child opens at its joint. Allocates nothing (one call per frame).
 * @param[out] positions  point_count*3
 * @param[in] rest_positions  vertex_count*3
 * @param[in] world  part_count*16
 * @param[in] joints  part_count*3
 * @param[in] sources  point_count
 * @param[in] parts_a  point_count
 * @param[in] parts_b  point_count
 * @param[in] blend  point_count
 */
SK_EXPERIMENTAL sk_status sk_evaluate_seams(double *positions, const double *rest_positions, const double *world,
                                            const double *joints, const int32_t *sources, const int32_t *parts_a,
                                            const int32_t *parts_b, const double *blend, size_t point_count,
                                            size_t vertex_count, size_t part_count, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Seam reconstruction per frame (Vasilakis 2008, section 4.4, Algorithm 5; csrc/offline/skeleton/sk_seam_fill.c)
 *
 * On the fixed seam topology that skinkit.skeleton.seams prepares (every vertex split into one copy per part that
 * touches it, a column of arc points between the copies of each opening vertex, fans where three parts meet), each
 * frame runs the thesis' four gap steps: add (sk_evaluate_seams' rigid points and QLERP arcs; with conic_arcs the
 * columns of a bent joint on the conic middle-point arcs instead), remove (the points of each part that sink into
 * the other part of a seam: inside its posed box and past its posed opening plane, found by region growing from the
 * opening over same-part 1-rings), triangulate (each hole the removal opens closed by an advancing front clipping
 * its smallest corner first, refusing a diagonal that is already an edge, then a fan to its mean; border vertices
 * on two holes and small cut-off pieces removed too) and normals (area-weighted). A frame whose result would not be
 * one closed sphere falls back to the fixed topology, so every frame is watertight, manifold and consistently
 * oriented. Allocates its scratch once per call; the frames' outputs are caller-visible.
 * ------------------------------------------------------------------------------------------- */

/* The seamed mesh: points (rigid points, seam copies, arc points, cap centres) and its triangles. */
typedef struct sk_seam_topology {
    const double *rest_positions; /* vertex_count * 3 */
    size_t vertex_count;
    const double *joints; /* part_count * 3: each part's joint at rest */
    size_t part_count;
    const int32_t *sources, *parts_a, *parts_b; /* point_count each, as in sk_evaluate_seams */
    const double *blend;                        /* point_count */
    size_t point_count;
    const int32_t *triangles; /* triangle_count * 3 */
    const int32_t *twins;     /* triangle_count * 3: the half-edge 3 t + i (T[t][i] -> T[t][i + 1]) running back, or -1 */
    size_t triangle_count;
    const int32_t *cap_members; /* cap_member_count * 2: (cap centre, ring point): each centre at its ring's mean */
    size_t cap_member_count;
    const int32_t *columns; /* column_count * column_width: start copy (shallower part a), the arc points, end copy */
    size_t column_count;
    size_t column_width; /* 3 .. 258 when there are columns: 1 to 256 arc points */
} sk_seam_topology;

/* What the removal step needs, built once. */
typedef struct sk_seam_removal {
    const int32_t *ring_offsets; /* point_count + 1: CSR of each point's same-part 1-ring */
    const int32_t *ring;
    const double *boxes; /* part_count * 15: each part's rest box (centre 3, axes as rows 9, half-lengths 3) */
    const int32_t *seam_parts;    /* seam_count * 2: (a, b) */
    const int32_t *start_offsets; /* seam_count * 2 + 1: CSR of the opening copies on side a, then side b, per seam */
    const int32_t *starts;
    const double *planes; /* seam_count * 6: the rest opening plane (centre, unit normal into b) */
    size_t seam_count;
} sk_seam_removal;

/*
 * Algorithm 5 on frame_count frames (world: part_count 4x4 rigid matrices per frame). Frame f writes its points,
 * triangles and unit normals at f * position_capacity (* 3) and f * triangle_capacity (* 3); position_capacity >=
 * point_count + triangle_count and triangle_capacity >= 2 * position_capacity always suffice. frame_counts (6 per
 * frame): points, triangles, removed points, fill points, conic columns, fallback (1: the fixed topology).
 * frame_seconds (4 per frame): add, remove, triangulate, normals. remove_sinking 0 skips the removal (the fixed
 * topology with its arcs). progress(fraction) after each frame; non-zero cancels (SK_ERROR_CANCELLED).
 * @param[out] positions  frame_count*position_capacity*3
 * @param[out] triangles  frame_count*triangle_capacity*3
 * @param[out] normals  frame_count*position_capacity*3
 * @param[out] frame_counts  frame_count*6
 * @param[out] frame_seconds  frame_count*4
 * @param[in] world  frame_count*part_count*16
 */
SK_EXPERIMENTAL sk_status sk_reconstruct_seams(double *positions, int32_t *triangles, double *normals,
                                               int32_t *frame_counts, double *frame_seconds,
                                               const sk_seam_topology *topology, const sk_seam_removal *removal,
                                               const double *world, size_t frame_count, size_t position_capacity,
                                               size_t triangle_capacity, int remove_sinking, int conic_arcs,
                                               sk_progress_fn progress, void *progress_user, sk_error *error);

/*
 * The conic arc of section 2.1.3 (Fudos and Hoffmann, the rational quadratic Bezier with the thesis' M2 typo
 * fixed: M2 = D_x u_y - D_y u_x): from start (tangent start_tangent) to end (tangent end_tangent, both tangents
 * pointing at the tangent lines' crossing) through the point `through`, in the plane of the chord and the start
 * tangent (inputs off it are projected). points: point_count points strictly between the ends at equal arc lengths;
 * weight: the middle control point's weight w (the curve is ((1-t)^2 C + 2t(1-t) w X + t^2 D) / ((1-t)^2 +
 * 2wt(1-t) + t^2), X the tangents' crossing). SK_ERROR_ARGUMENT when no such conic exists.
 * @param[out] points  point_count*3
 * @param[out] weight  1
 * @param[in] start  3
 * @param[in] start_tangent  3
 * @param[in] end  3
 * @param[in] end_tangent  3
 * @param[in] through  3
 */
SK_EXPERIMENTAL sk_status sk_conic_arc(double *points, double *weight, size_t point_count, const double *start,
                                       const double *start_tangent, const double *end, const double *end_tangent,
                                       const double *through, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Dual-quaternion skinning and handle rigs (Feng 2010, chapter 2)
 *
 * A dual quaternion is 8 doubles: the real part q0 (w, x, y, z) then the dual part qe (w, x, y, z); a
 * rigid motion v -> R v + t is q0 = rotation(R), qe = (0, t) q0 / 2. Runtime functions (csrc/runtime/, no
 * LAPACK, no allocation); training (csrc/offline/handles/) uses LAPACK.
 *
 * A handle rig (sk_handle_rig) predicts one dual quaternion per proxy bone from the positions of a few
 * control points ("handles"): the handle vector c (3 * handle_count, normalised as
 * (c - handle_mean) / handle_scale) gives the kernel vector xi_j = k(c, training_handles_j) over the
 * example_count training examples, the fused kernel-CCA mapping gives d = mapping xi + mapping_offset (8 per
 * bone), and each bone's real part is normalised. When translation_rotations is not NULL the translations
 * are replaced by the Poisson solve (eq. 2.11): t_b = sum_a R_a translation_rotations[b][a] (a 3-vector) +
 * sum_l translation_handles[b][l] c_l (the prefactored least-squares solution, see sk_handle_translation_solver).
 * ------------------------------------------------------------------------------------------- */

typedef enum sk_kernel {
    SK_KERNEL_GAUSSIAN = 0,   /* exp(-|x - y|^2 / (2 parameter^2)) */
    SK_KERNEL_POLYNOMIAL = 1, /* (x.y + parameter)^degree */
    SK_KERNEL_LINEAR = 2      /* x.y */
} sk_kernel;

typedef struct sk_handle_rig {
    size_t handle_count, example_count, bone_count;
    int kernel;       /* an sk_kernel */
    double parameter; /* the Gaussian's sigma or the polynomial's constant */
    int degree;       /* the polynomial's degree (>= 1) */
    double handle_scale;
    const double *handle_mean;           /* 3*handle_count */
    const double *training_handles;      /* example_count*3*handle_count, normalised */
    const double *mapping;               /* 8*bone_count*example_count */
    const double *mapping_offset;        /* 8*bone_count */
    const double *translation_rotations; /* bone_count*bone_count*3 or NULL: no Poisson solve */
    const double *translation_handles;   /* bone_count*handle_count */
} sk_handle_rig;

/*
 * Dual quaternions of rigid 4x4 matrices (rotation part orthonormal within 1e-6, else SK_ERROR_ARGUMENT
 * naming the matrix). q0 has w >= 0.
 * @param[out] dual_quaternions  count*8
 * @param[in] matrices  count*16
 */
SK_EXPERIMENTAL sk_status sk_dq_from_rigid(double *dual_quaternions, const double *matrices, size_t count,
                                           sk_error *error);

/*
 * Rigid 4x4 matrices of dual quaternions, each normalised first (a zero real part is SK_ERROR_SINGULAR).
 * @param[out] matrices  count*16
 * @param[in] dual_quaternions  count*8
 */
SK_EXPERIMENTAL sk_status sk_dq_to_rigid(double *matrices, const double *dual_quaternions, size_t count,
                                         sk_error *error);

/*
 * Sign alignment across examples, in place: every example's dual quaternion of bone b is negated when its
 * real part points away from example 0's (dot < 0), so that regression never averages q and -q.
 * @param[in,out] dual_quaternions  example_count*bone_count*8
 */
SK_EXPERIMENTAL sk_status sk_dq_align_signs(double *dual_quaternions, size_t example_count, size_t bone_count,
                                            sk_error *error);

/*
 * Dual-quaternion linear blending (Kavan et al. 2008): sum_k weights_k (+-) q_k, each sign chosen against
 * the running sum (as Blender's Armature modifier does), normalised. A zero blend is SK_ERROR_SINGULAR.
 * @param[out] destination  8
 * @param[in] dual_quaternions  count*8
 * @param[in] weights  count
 */
SK_EXPERIMENTAL sk_status sk_dq_blend(double *destination, const double *dual_quaternions, const double *weights,
                                      size_t count, sk_error *error);

/*
 * Dual-quaternion skinning of positions (homogeneous 1) or tangent vectors (0): per vertex the blend of
 * its influences' dual quaternions (sk_dq_blend's rule) applied to its rest vector. A vertex whose blend
 * vanishes keeps its rest vector. Threaded like sk_lbs_evaluate.
 * @param[out] destination  vertex_count*3
 * @param[in] vectors  vertex_count*3
 * @param[in] weights  influence_count
 * @param[in] dual_quaternions  bone_count*8
 */
SK_EXPERIMENTAL sk_status sk_dqs_evaluate_f64(double *destination, const sk_influences *influences,
                                              const double *vectors, double homogeneous, const double *weights,
                                              const double *dual_quaternions, size_t bone_count, int thread_count,
                                              sk_error *error);
SK_EXPERIMENTAL sk_status sk_dqs_evaluate_f32(float *destination, const sk_influences *influences,
                                              const float *vectors, float homogeneous, const float *weights,
                                              const float *dual_quaternions, size_t bone_count, int thread_count,
                                              sk_error *error);

/*
 * Kernel values destination[p * reference_count + j] = k(points_p, references_j) of vectors of `dimension`.
 * @param[out] destination  point_count*reference_count
 * @param[in] points  point_count*dimension
 * @param[in] references  reference_count*dimension
 */
SK_EXPERIMENTAL sk_status sk_kernel_values(double *destination, const double *points, const double *references,
                                           size_t point_count, size_t reference_count, size_t dimension, int kernel,
                                           double parameter, int degree, sk_error *error);

/*
 * A handle rig's prediction for one frame: bone dual quaternions (normalised) from raw handle positions.
 * kernel_values is the caller's scratch (and gets xi). Allocation-free.
 * @param[out] dual_quaternions  bone_count*8
 * @param[out] kernel_values  example_count
 * @param[in] handle_positions  3*handle_count
 */
SK_EXPERIMENTAL sk_status sk_handle_predict(double *dual_quaternions, double *kernel_values,
                                            const sk_handle_rig *rig, const double *handle_positions,
                                            sk_error *error);

/*
 * Regularised kernel CCA with fused regression, for group_count independent targets (one per proxy bone):
 * for group g with targets D_g (example_count x dimension) and the kernel matrix K of the examples' inputs,
 * K and D_g are centred, the canonical pairs maximise f'Kc Dc u / sqrt(f'(Kc^2 + ridge Kc) f u'(Dc'Dc + ridge_d I) u)
 * (ridge_d = 1e-9 trace / dimension keeps constant targets solvable), basis_count pairs (<= dimension) are kept,
 * the reduced inputs are regressed onto the reduced targets (eq. 2.8), the targets rebuilt from theirs (2.9),
 * and the chain is fused (with the centring) into mapping_g (dimension x example_count) and offset_g so that
 * d = mapping_g k(x) + offset_g for the uncentred kernel vector k(x). correlations gets each pair's rho
 * (0 past the data's rank).
 * @param[out] mapping  group_count*dimension*example_count
 * @param[out] offset  group_count*dimension
 * @param[out] correlations  group_count*basis_count
 * @param[in] kernel  example_count*example_count
 * @param[in] targets  example_count*group_count*dimension
 */
SK_EXPERIMENTAL sk_status sk_kernel_cca(double *mapping, double *offset, double *correlations, const double *kernel,
                                        const double *targets, size_t example_count, size_t group_count,
                                        size_t dimension, size_t basis_count, double ridge, int thread_count,
                                        sk_error *error);

/*
 * The Poisson translation solver's prefactored matrices (eq. 2.10-2.11). Per edge, skinning weights over the
 * bones influencing either endpoint are fitted to the examples' edge vectors with the examples' rotations
 * (2.10, a tiny ridge keeps an edge that never turns determined); then the linear-blend translations that
 * best keep the skinned edges and put the handle vertices at the handles (weight beta > 0) are solved once
 * for a basis of right-hand sides: A'A (bone_count x bone_count, SPD once beta > 0 and every mesh part holds
 * a handle) is factored by dense LAPACK Cholesky (dpotrf): it is small and dense (every pair of bones that
 * share an edge couples, and the rotation-to-translation matrices fill in anyway), so a sparse factorisation
 * would buy nothing. t_b gets R_a times the 3-vector translation_rotations[(b * bone_count + a) * 3 ..] and
 * translation_handles[b * handle_count + l] times handle l's position, as sk_handle_rig uses them.
 * edge_error gets the rms edge-vector error of the fit (2.10) over the examples.
 * @param[out] translation_rotations  bone_count*bone_count*3
 * @param[out] translation_handles  bone_count*handle_count
 * @param[in] rest_positions  vertex_count*3
 * @param[in] weights  influence_count
 * @param[in] edges  edge_count*2
 * @param[in] rotations  example_count*bone_count*9
 * @param[in] example_positions  example_count*vertex_count*3
 * @param[in] handle_vertices  handle_count
 */
SK_EXPERIMENTAL sk_status sk_handle_translation_solver(double *translation_rotations, double *translation_handles,
                                                       double *edge_error, const sk_influences *influences,
                                                       const double *rest_positions, const double *weights,
                                                       const int32_t *edges, size_t edge_count,
                                                       const double *rotations, const double *example_positions,
                                                       size_t example_count, size_t bone_count,
                                                       const int32_t *handle_vertices, size_t handle_count,
                                                       double beta, int thread_count, sk_error *error);

/*
 * Control points suggested from example frames (section 2.3, after Meyer & Anderson): ceil(handle_count / 2)
 * principal components of the vertex positions (through the frames' Gram matrix), varimax-rotated; per component
 * the two extreme vertices of its loadings along the component's main direction ("two representative points with
 * largest differences"), the farther one first, skipping vertices already chosen.
 * @param[out] handle_vertices  handle_count
 * @param[in] frames  frame_count*vertex_count*3
 */
SK_EXPERIMENTAL sk_status sk_suggest_handles(int32_t *handle_vertices, const double *frames, size_t frame_count,
                                             size_t vertex_count, size_t handle_count, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Hierarchical triangle clustering for handle rigs' proxy bones (Feng 2010, section 2.3, after Wang et al.
 * 2007; issue 14). Experimental.
 *
 * Every triangle starts as a cluster; the touching pair (sharing an edge; separate pieces of the mesh are
 * linked by rest centroid once nothing touches) whose union one rigid motion per example carries worst is merged
 * last. A cluster's error sums, over the examples, its best rigid motion's squared vertex error over its
 * triangles' corners plus edge_weight times the squared error of its triangles' edges under that rotation (edge
 * orientation and length). Merge m joins cluster merges[2 m + 1] into merges[2 m] (a cluster is named by one of
 * its triangles) at cost costs[m] (the error it adds); applying the first triangle_count - k merges leaves k
 * clusters; merge_count must be triangle_count - 1. Progress every 256 merges; a non-zero return cancels
 * (SK_ERROR_CANCELLED).
 * ------------------------------------------------------------------------------------------- */

/*
 * @param[out] merges  2*merge_count
 * @param[out] costs  merge_count
 * @param[in] triangles  3*triangle_count
 * @param[in] rest_positions  3*vertex_count
 * @param[in] frames  3*frame_count*vertex_count
 */
SK_EXPERIMENTAL sk_status sk_triangle_cluster_merges(int32_t *merges, double *costs, size_t merge_count,
                                                     const int32_t *triangles, size_t triangle_count, const double *rest_positions,
                                                     size_t vertex_count, const double *frames, size_t frame_count,
                                                     double edge_weight, sk_progress_fn progress,
                                                     void *progress_user, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Baking normal maps and tangent maps (Merry 2007, section 7.5). Experimental.
 *
 * A bake surface is a triangle list with per-corner normals (the split normals a renderer shades with) and
 * per-corner uv. Images are size x size texels, row-major from the top: texel (column c, row r) covers
 * u in [c, c + 1] / size and v in [1 - (r + 1) / size, 1 - r / size] (v up, as Blender's uv; row 0 is the top
 * row of an image file). Normals are encoded 0.5 n + 0.5, three floats per texel.
 * ------------------------------------------------------------------------------------------- */

typedef struct sk_bake_surface {
    const int32_t *triangles; /* triangle_count * 3 vertex indices */
    const double *positions;  /* vertex_count * 3 */
    const double *normals;    /* triangle_count * 9: each corner's normal */
    const double *uv;         /* triangle_count * 6: each corner's uv (may be NULL for a ray-cast source) */
    size_t triangle_count;
    size_t vertex_count;
} sk_bake_surface;

/*
 * MikkTSpace tangents of a surface, the convention of Blender's Mesh.calc_tangents, Unreal, Unity and glTF:
 * corners welded by equal position, normal and uv; each corner's tangent is the normalised angle-weighted sum of
 * its triangles' uv-gradient directions projected onto its normal's plane, over the welded vertex's triangles
 * that share edges and uv orientation; the sign is +1 where the uv map preserves orientation, else -1 (the
 * bitangent is sign * normal x tangent). tangents[4 c .. 4 c + 3] = (x, y, z, sign) of corner c = 3 t + k.
 * Degenerate triangles follow the reference (Blender's port): a triangle with no uv area or no 3D extent along u
 * or v contributes nothing and joins (and takes the orientation of) the first group that reaches it; one with two
 * corners at one position copies the tangent of the first other triangle's corner welded to each of its corners;
 * a corner reached by neither gets (1, 0, 0) with sign -1.
 * @param[out] tangents  triangle_count*12
 */
SK_EXPERIMENTAL sk_status sk_mikktspace_tangents(double *tangents, const sk_bake_surface *surface, sk_error *error);

typedef enum sk_bake_mode {
    SK_BAKE_ATLAS = 0,   /* the same uv point on the source (a LOD chain's shared atlas) */
    SK_BAKE_RAY_CAST = 1, /* the nearest hit along the target's interpolated normal within +-cage; where that ray
                             misses (normals grazing a sharply folded level), the closest source point within cage */
    SK_BAKE_GUIDED = 2    /* a LOD chain's best: the ray cast's normal where it is within SK_BAKE_GUIDE_DEGREES of
                             the same uv point's, else the same uv point's (the ray finds the point a view along the
                             normal sees; where it hits another part of the surface, the atlas knows better) */
} sk_bake_mode;

#define SK_BAKE_GUIDE_DEGREES 10.0

#define SK_BAKE_MAX_SIZE 16384

typedef struct sk_bake_options {
    size_t size;        /* texels per side, 1 to SK_BAKE_MAX_SIZE */
    int mode;           /* sk_bake_mode */
    size_t supersample; /* s: s x s samples per texel, 1 to 8 */
    size_t margin;      /* dilation passes, in texels, 0 to 127 */
    double cage;        /* ray cast and guided: the distance searched each way along the normal (> 0) */
    int thread_count;   /* 0: every online processor */
} sk_bake_options;

/* What each texel of a bake became (the coverage image). */
enum {
    SK_TEXEL_EMPTY = 0,  /* no target triangle touches it, and the margin did not reach it */
    SK_TEXEL_FILLED = 1, /* baked */
    SK_TEXEL_MISSED = 2, /* a triangle touches it but the source was not found (no source point within the cage,
                            or no source uv there): written flat (0, 0, 1) */
    SK_TEXEL_DILATED = 3 /* filled by the margin */
};

typedef struct sk_bake_report {
    size_t filled, missed, dilated, empty; /* texels by their coverage */
} sk_bake_report;

/*
 * Bakes the source's normals into the target's tangent space (target tangents from sk_mikktspace_tangents).
 * Texels are covered conservatively (every texel a uv triangle overlaps); each averages its supersample^2
 * samples inside the target's triangles, in tangent space, normalised; a touched texel with no sample inside
 * takes the value at the triangle point nearest its centre. The tangent-space normal x solves
 * [T B N] x = n_source with T, N the interpolated tangent and normal left unnormalised and B = sign N x T (so
 * normalize(x.x T + x.y B + x.z N) = n_source: the decoding of Blender's Normal Map node and MikkTSpace's rule),
 * normalised. exact (may be NULL) gets the object-space source normal at each texel centre's nearest target point,
 * frames (may be NULL) the target frame (T, B, N) there, unnormalised; both zero where the texel is empty or missed.
 * Fails with SK_ERROR_ARGUMENT naming the first texel when a texel sample lies strictly inside two target
 * triangles (overlapping uvs), and on uv outside 0-1. progress (may be NULL) is called between batches of
 * rows; a non-zero return cancels (SK_ERROR_CANCELLED). Any thread count gives the same bits.
 * @param[out] image  size*size*3
 * @param[out] coverage  size*size
 * @param[out] exact  size*size*3 (may be NULL)
 * @param[out] frames  size*size*9 (may be NULL)
 * @param[in] tangents  target triangle_count*12
 */
SK_EXPERIMENTAL sk_status sk_bake_normals(float *image, unsigned char *coverage, double *exact, double *frames,
                                          sk_bake_report *report, const sk_bake_surface *target,
                                          const double *tangents, const sk_bake_surface *source,
                                          const sk_bake_options *options, sk_progress_fn progress,
                                          void *progress_user, sk_error *error);

/*
 * A tangent map (section 7.5) of the target's uv layout from the source's animation-space model (influences and
 * coordinates over the source's vertices, through the shared atlas): for each texel whose centre (or, touched
 * conservatively, the nearest point of a touching triangle) maps to a source triangle, the union of that triangle's
 * bones, sorted, and per bone the pair (dp/du, dp/dv) of 4-vectors of the model interpolated linearly over the
 * triangle in uv, the second negated where the triangle's uv runs against its 3D orientation, so that
 * normalize(G t1 x G t2) is the posed source face's normal in every pose. counts gets each texel's bone count (0
 * when empty), bones and tangents (t1 xyzw then t2 xyzw per slot) have max_influences slots per texel, unused
 * slots bone 0 and zero (the padding a tile's common count needs), source_triangles the source triangle (-1 none).
 * Fails naming the first texel when one needs more than max_influences bones. Any thread count, same bits.
 * progress (may be NULL) is called between batches of rows; a non-zero return cancels (SK_ERROR_CANCELLED).
 * @param[out] counts  size*size
 * @param[out] bones  size*size*max_influences
 * @param[out] tangents  size*size*max_influences*8
 * @param[out] source_triangles  size*size
 * @param[out] coverage  size*size
 * @param[in] coordinates  influence_count*4
 */
SK_EXPERIMENTAL sk_status sk_bake_tangent_map(int32_t *counts, int32_t *bones, double *tangents,
                                              int32_t *source_triangles, unsigned char *coverage,
                                              const sk_bake_surface *target, const sk_bake_surface *source,
                                              const sk_influences *influences, const double *coordinates, size_t size,
                                              size_t max_influences, int thread_count, sk_progress_fn progress,
                                              void *progress_user, sk_error *error);

/*
 * The object-space normal map of a tangent map in one pose (runtime: no LAPACK, no allocation): per texel
 * normalize(sum_k G_bones[k] t1_k x sum_k G_bones[k] t2_k), encoded 0.5 n + 0.5 ((0.5, 0.5, 0.5) where the texel is
 * empty or degenerate). poses are the bone frames G_j (4x4 row-major).
 * @param[out] image  texel_count*3
 * @param[in] counts  texel_count
 * @param[in] bones  texel_count*max_influences
 * @param[in] tangents  texel_count*max_influences*8
 * @param[in] poses  bone_count*16
 */
SK_EXPERIMENTAL sk_status sk_tangent_map_normals(float *image, const int32_t *counts, const int32_t *bones,
                                                 const double *tangents, const double *poses, size_t texel_count,
                                                 size_t max_influences, size_t bone_count, int thread_count,
                                                 sk_error *error);

/*
 * The next level of a tangent map's mip chain (section 7.5, appendix A.1): each output texel (size / 2 per side)
 * averages the 2x2 block of input texels with a count: its tangent pairs, on the union S of their bones (sorted),
 * are fitted by one plane, the bivector fit of A = sum_i (a_i b_i^T - b_i a_i^T) (A.2), and the block's mean pair
 * projected onto that plane is kept. With metric (P's 4x4 blocks, as sk_expectation_blocks writes them, over
 * bone_count bones) the fit is the one in the L2,2 metric (A.1.2, A.3-A.8: the top singular pair (u, v) of C A C
 * with C the symmetric square root of P's sub-block on S, the plane a = A C v / s, b = -A C u / s, the mean pair
 * projected P-orthogonally); metric NULL: the Euclidean fit (the span of A's top singular pair, projected
 * orthogonally). LAPACK's dsyev and dgesvd. Bones absent from a block stay absent; a block without texels gives
 * count 0. Layout as sk_bake_tangent_map's; size even. Fails naming the first output texel whose block needs more
 * than max_influences (at most 64) bones, and the first texel with a bone outside the metric's skeleton. half_size
 * (the outputs' side) must be size / 2.
 * @param[out] counts_out  (size/2)*(size/2)
 * @param[out] bones_out  (size/2)*(size/2)*max_influences
 * @param[out] tangents_out  (size/2)*(size/2)*max_influences*8
 * @param[in] counts  size*size
 * @param[in] bones  size*size*max_influences
 * @param[in] tangents  size*size*max_influences*8
 * @param[in] metric  bone_count*bone_count*16 (may be NULL)
 */
SK_EXPERIMENTAL sk_status sk_tangent_map_downsample(int32_t *counts_out, int32_t *bones_out, double *tangents_out,
                                                    size_t half_size, const int32_t *counts, const int32_t *bones,
                                                    const double *tangents, size_t size, size_t max_influences,
                                                    const double *metric, size_t bone_count, int thread_count,
                                                    sk_error *error);

#ifdef __cplusplus
}
#endif

#endif /* SKINKIT_H */
