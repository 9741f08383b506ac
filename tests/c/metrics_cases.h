/*
 * What the metrics tests share (metrics_cases.c): kinematics, random sparse 4-vectors, every
 * combination of independently sampled joints, skeletons listed out of order, a mean-distance fixture.
 */
#ifndef SKINKIT_METRICS_CASES_H
#define SKINKIT_METRICS_CASES_H

#include <stddef.h>
#include <stdint.h>

#include "skinkit.h"
#include "sk_internal.h" /* only for SK_SOLVE_ITEMS_PER_WORKER */

/* The metrics' per-worker minimum (sk_metrics.c): below it every thread count runs on one thread. */
#define METRIC_ITEMS_PER_WORKER ((size_t)SK_SOLVE_ITEMS_PER_WORKER * 64)

/* G_j of every bone: L_a1 L_a2 ... L_j along the path from the root (G_0 = I). */
void world_frames(double *frames, const double *local, const int32_t *parents, size_t bone_count);
void add_transposed_product(double destination[16], const double a[16], const double b[16]); /* += a^T b */

/* Sparse 4-vectors in CSR form, every array exactly sized. */
typedef struct sparse_vectors {
    size_t count, influence_count;
    int32_t *offsets, *bones;
    double *values;
} sparse_vectors;

/* `count` vectors with 1..max_bones distinct bones (0..max_bones with allow_empty); weight_zero: weights sum to 0. */
sparse_vectors random_vectors_on(size_t count, size_t bone_count, size_t max_bones, int allow_empty,
                                 int weight_zero);
void free_vectors(sparse_vectors *v);
/* The spatial part (top three rows) of G s for vector i, with G given per bone. */
void apply_frames(double out[3], const double *frames, const sparse_vectors *v, size_t i);

typedef struct combinations {
    size_t bone_count, count;
    const int32_t *parents;
    double *local;         /* count * bone_count 4x4: L_j of each combination */
    double *world;         /* count * bone_count 4x4: G_j of each combination (own forward kinematics) */
    double *mean_local;    /* bone_count 4x4: the per-joint sample means, L_0 = I */
    double *mean_gram;     /* bone_count 4x4: the mean of G_j^T G_j over all combinations */
} combinations;

/* per_joint[j] samples of joint j, and every combination of them. */
combinations make_combinations(const int32_t *parents, const size_t *per_joint, size_t bone_count);
void free_combinations(combinations *c);

/* Skeletons listed out of order (drawn in metrics_cases.c). */
extern const int32_t branching6[6], branching5[5], chain5[5], branching7[7];

typedef struct metric_fixture {
    size_t bone_count;
    int32_t *parents;
    combinations c;
    double *mean_local, *mean_gram; /* exact copies */
} metric_fixture;

metric_fixture make_metric_fixture(void); /* branching5, 1 x 3 x 2 x 3 x 2 combinations */
void free_metric_fixture(metric_fixture *f);
sk_status mean_distances(double *out, const sparse_vectors *v, const metric_fixture *f, double *cache,
                         unsigned char *cached, int thread_count, sk_error *error);

/* Whether message contains a and (unless b is NULL) b. */
int message_has(const char *message, const char *a, const char *b);

#endif
