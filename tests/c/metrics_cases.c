/*
 * What the metrics tests (test_metrics.c, test_metric_bounds.c) share, independent of the core:
 * forward kinematics and products, random sparse 4-vectors, every combination of independently
 * sampled joints, the skeletons listed out of order, and a small fixture for sk_mean_distances.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "metrics_cases.h"
#include "test_support.h"

/* ---------------------------------------------------------------------------------------------
 * Kinematics, products and sparse vectors
 * ------------------------------------------------------------------------------------------- */

/* G_bone = L_a1 L_a2 ... L_bone along the path from the root (L_0 never enters: G_0 = I). */
static void world_frame(double frame[16], const double *local, const int32_t *parents, size_t bone)
{
    set_identity(frame);
    for (size_t node = bone; node != 0; node = (size_t)parents[node]) {
        double product[16];
        multiply(product, local + 16 * node, frame);
        memcpy(frame, product, sizeof product);
    }
}

void world_frames(double *frames, const double *local, const int32_t *parents, size_t bone_count)
{
    for (size_t bone = 0; bone < bone_count; ++bone)
        world_frame(frames + 16 * bone, local, parents, bone);
}

/* destination += a^T b (the same sums, in the same order, as multiply's) */
void add_transposed_product(double destination[16], const double a[16], const double b[16])
{
    double transposed[16], product[16];
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c)
            transposed[4 * r + c] = a[4 * c + r];
    multiply(product, transposed, b);
    for (int e = 0; e < 16; ++e)
        destination[e] += product[e];
}

/* `count` vectors with 1..max_bones distinct bones each (0..max_bones with allow_empty) and random
 * entries; with weight_zero the weights are shifted to sum to 0 (the last one is minus the others'). */
sparse_vectors random_vectors_on(size_t count, size_t bone_count, size_t max_bones, int allow_empty,
                                 int weight_zero)
{
    sparse_vectors v = {.count = count};
    size_t *sizes = allocate(count, sizeof *sizes);
    const size_t cap = max_bones < bone_count ? max_bones : bone_count;
    for (size_t i = 0; i < count; ++i) {
        sizes[i] = allow_empty ? random_below(cap + 1) : 1 + random_below(cap);
        v.influence_count += sizes[i];
    }
    v.offsets = malloc((count + 1) * sizeof *v.offsets);
    v.bones = malloc((v.influence_count ? v.influence_count : 1) * sizeof *v.bones);
    v.values = malloc((v.influence_count ? 4 * v.influence_count : 1) * sizeof *v.values);
    if (!v.offsets || !v.bones || !v.values) {
        fprintf(stderr, "%s: out of memory\n", test_program_name);
        exit(2);
    }
    size_t k = 0;
    v.offsets[0] = 0;
    for (size_t i = 0; i < count; ++i) {
        pick_distinct_bones(v.bones + k, sizes[i], bone_count);
        double mean = 0.0;
        for (size_t a = k; a < k + sizes[i]; ++a) {
            for (int c = 0; c < 4; ++c)
                v.values[4 * a + (size_t)c] = random_uniform(-1.0, 1.0);
            mean += v.values[4 * a + 3] / (double)sizes[i];
        }
        if (weight_zero) {
            double sum = 0.0;
            for (size_t a = k; a < k + sizes[i]; ++a)
                v.values[4 * a + 3] -= mean;
            for (size_t a = k; a + 1 < k + sizes[i]; ++a)
                sum += v.values[4 * a + 3];
            if (sizes[i] > 0)
                v.values[4 * (k + sizes[i] - 1) + 3] = -sum; /* exactly zero in floating point too */
        }
        k += sizes[i];
        v.offsets[i + 1] = (int32_t)k;
    }
    free(sizes);
    return v;
}

void free_vectors(sparse_vectors *v)
{
    free(v->offsets), free(v->bones), free(v->values);
}

/* The spatial part (top three rows) of G s for one vector, with G given per bone. */
void apply_frames(double out[3], const double *frames, const sparse_vectors *v, size_t i)
{
    out[0] = out[1] = out[2] = 0.0;
    for (int32_t a = v->offsets[i]; a < v->offsets[i + 1]; ++a) {
        const double *g = frames + 16 * (size_t)v->bones[a], *s = v->values + 4 * (size_t)a;
        for (int r = 0; r < 3; ++r)
            out[r] += g[4 * r] * s[0] + g[4 * r + 1] * s[1] + g[4 * r + 2] * s[2] + g[4 * r + 3] * s[3];
    }
}

/* ---------------------------------------------------------------------------------------------
 * Independently sampled joints: every combination of per-joint samples
 * ------------------------------------------------------------------------------------------- */

/* per_joint[j] samples of joint j (the root's L_0 is random too: it must be ignored). */
combinations make_combinations(const int32_t *parents, const size_t *per_joint, size_t bone_count)
{
    combinations c = {.bone_count = bone_count, .count = 1, .parents = parents};
    size_t total = 0;
    for (size_t bone = 0; bone < bone_count; ++bone)
        c.count *= per_joint[bone], total += per_joint[bone];
    double *samples = allocate(16 * total, sizeof *samples);
    size_t *first = allocate(bone_count, sizeof *first);
    for (size_t bone = 0, at = 0; bone < bone_count; at += per_joint[bone], ++bone) {
        first[bone] = at;
        for (size_t s = 0; s < per_joint[bone]; ++s)
            random_frame(samples + 16 * (at + s), 0.6, 1.5, 1.5);
    }
    c.local = allocate(16 * c.count * bone_count, sizeof *c.local);
    c.world = allocate(16 * c.count * bone_count, sizeof *c.world);
    c.mean_local = allocate(16 * bone_count, sizeof *c.mean_local);
    c.mean_gram = allocate(16 * bone_count, sizeof *c.mean_gram);
    for (size_t index = 0; index < c.count; ++index) {
        size_t rest = index; /* mixed-radix digits: one sample choice per joint */
        for (size_t bone = 0; bone < bone_count; ++bone) {
            const size_t choice = rest % per_joint[bone];
            rest /= per_joint[bone];
            memcpy(c.local + 16 * (index * bone_count + bone), samples + 16 * (first[bone] + choice),
                   16 * sizeof(double));
        }
        world_frames(c.world + 16 * index * bone_count, c.local + 16 * index * bone_count, parents, bone_count);
        for (size_t bone = 0; bone < bone_count; ++bone) {
            const double *g = c.world + 16 * (index * bone_count + bone);
            add_transposed_product(c.mean_gram + 16 * bone, g, g);
        }
    }
    for (size_t k = 0; k < 16 * bone_count; ++k)
        c.mean_gram[k] /= (double)c.count;
    set_identity(c.mean_local);
    for (size_t bone = 1; bone < bone_count; ++bone) {
        for (size_t s = 0; s < per_joint[bone]; ++s)
            for (int e = 0; e < 16; ++e)
                c.mean_local[16 * bone + (size_t)e] += samples[16 * (first[bone] + s) + (size_t)e];
        for (int e = 0; e < 16; ++e)
            c.mean_local[16 * bone + (size_t)e] /= (double)per_joint[bone];
    }
    free(samples), free(first);
    return c;
}

void free_combinations(combinations *c)
{
    free(c->local), free(c->world), free(c->mean_local), free(c->mean_gram);
}

/* A branching skeleton listed out of order: 0 -> {2, 3}, 3 -> {1, 5}, 1 -> {4}; bones 1 and 4 come
 * before (or between) their ancestors. */
const int32_t branching6[] = {-1, 3, 0, 0, 1, 3};
/* 0 -> 2 -> {1, 3}, 1 -> 4: a child (1) before its parent (2), siblings (1, 3), cousins (4, 3). */
const int32_t branching5[] = {-1, 2, 0, 2, 1};
/* A chain listed out of order: 0 -> 2 -> 3 -> 1 -> 4. */
const int32_t chain5[] = {-1, 3, 0, 2, 1};
/* 0 -> {1, 4}, 1 -> 3, 4 -> {2, 5}, 2 -> 6. */
const int32_t branching7[] = {-1, 0, 4, 1, 0, 4, 2};

/* ---------------------------------------------------------------------------------------------
 * A small problem for sk_mean_distances, and error messages
 * ------------------------------------------------------------------------------------------- */

metric_fixture make_metric_fixture(void)
{
    static const size_t per_joint[] = {1, 3, 2, 3, 2};
    metric_fixture f = {.bone_count = 5, .parents = exact_copy_int32(branching5, 5)};
    f.c = make_combinations(f.parents, per_joint, f.bone_count);
    f.mean_local = exact_copy_double(f.c.mean_local, 16 * f.bone_count);
    f.mean_gram = exact_copy_double(f.c.mean_gram, 16 * f.bone_count);
    return f;
}

void free_metric_fixture(metric_fixture *f)
{
    free_combinations(&f->c);
    free(f->parents), free(f->mean_local), free(f->mean_gram);
}

sk_status mean_distances(double *out, const sparse_vectors *v, const metric_fixture *f, double *cache,
                         unsigned char *cached, int thread_count, sk_error *error)
{
    return sk_mean_distances(out, &(sk_influences){v->offsets, v->bones, v->count, v->influence_count}, v->values,
                             f->mean_local, f->mean_gram, f->parents, f->bone_count, cache, cached, thread_count,
                             error);
}

int message_has(const char *message, const char *a, const char *b)
{
    return strstr(message, a) != NULL && (!b || strstr(message, b) != NULL);
}
