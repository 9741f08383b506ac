/*
 * Standalone tests of the animation-space metrics (csrc/skinkit.h, "The animation-space metrics"):
 * sk_joint_statistics, sk_expectation_block, sk_mean_distances and sk_max_distances.
 *
 * Meant to run under AddressSanitizer and UndefinedBehaviorSanitizer: the arrays handed to the core
 * are exactly sized heap blocks, so a function that read past its counts (or past a bad index before
 * rejecting it) would be stopped by the sanitizer, not just by a failed CHECK.
 *
 * References are computed here with plain loops: forward kinematics by walking each bone up to the
 * root, plain sample averages, brute-force averages over every combination of independently sampled
 * joints (whose empirical distribution really is a product of per-joint distributions, so the
 * common-ancestor recursion must reproduce them to rounding), explicit poses within the joint bounds,
 * and worst-case poses built by hand that attain the max-distance bound.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "skinkit.h"
#include "sk_internal.h" /* only for sk_worker_count and SK_SOLVE_ITEMS_PER_WORKER: proves the work is split */
#include "test_support.h"

/* The metrics' per-worker minimum (sk_metrics.c): below it every thread count runs on one thread. */
#define METRIC_ITEMS_PER_WORKER ((size_t)SK_SOLVE_ITEMS_PER_WORKER * 64)

/* ---------------------------------------------------------------------------------------------
 * Independent helpers: kinematics, products, random joints and sparse vectors
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

static void world_frames(double *frames, const double *local, const int32_t *parents, size_t bone_count)
{
    for (size_t bone = 0; bone < bone_count; ++bone)
        world_frame(frames + 16 * bone, local, parents, bone);
}

/* destination += a^T b */
static void add_transposed_product(double destination[16], const double a[16], const double b[16])
{
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) {
            double sum = 0.0;
            for (int k = 0; k < 4; ++k)
                sum += a[4 * k + r] * b[4 * k + c];
            destination[4 * r + c] += sum;
        }
}

static int is_ancestor(const int32_t *parents, size_t ancestor, size_t bone)
{
    for (size_t node = bone; node != 0;) {
        node = (size_t)parents[node];
        if (node == ancestor)
            return 1;
    }
    return 0;
}

static double norm3(const double v[3])
{
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

static void random_unit_vector(double v[3])
{
    double length;
    do {
        for (int axis = 0; axis < 3; ++axis)
            v[axis] = random_uniform(-1.0, 1.0);
        length = norm3(v);
    } while (length < 0.1 || length > 1.0);
    for (int axis = 0; axis < 3; ++axis)
        v[axis] /= length;
}

/* A joint within the bounds: rotation times per-axis scales in [0, linear_bound] (so the 2-norm of the
 * linear part is <= linear_bound), translation inside the sphere (centre, radius). `extreme` puts every
 * scale at the bound and the translation on the sphere's surface. */
static void random_bounded_joint(double joint[16], double linear_bound, const double centre[3], double radius,
                                 int extreme)
{
    double rotation[9], scales[3], direction[3], translation[3];
    random_rotation(rotation);
    random_unit_vector(direction);
    const double distance = extreme ? radius : radius * random_uniform(0.0, 1.0);
    for (int axis = 0; axis < 3; ++axis) {
        scales[axis] = extreme ? linear_bound : linear_bound * random_uniform(0.0, 1.0);
        translation[axis] = centre[axis] + distance * direction[axis];
    }
    make_frame(joint, rotation, scales, translation);
}

/* The rotation taking unit vector a to unit vector b (a != -b): I + K + K^2 / (1 + a.b), K = [a x b]. */
static void rotation_between(double rotation[9], const double a[3], const double b[3])
{
    const double v[3] = {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    const double c = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    const double k[9] = {0, -v[2], v[1], v[2], 0, -v[0], -v[1], v[0], 0};
    for (int r = 0; r < 3; ++r)
        for (int col = 0; col < 3; ++col) {
            double k2 = 0.0;
            for (int m = 0; m < 3; ++m)
                k2 += k[3 * r + m] * k[3 * m + col];
            rotation[3 * r + col] = (r == col) + k[3 * r + col] + k2 / (1.0 + c);
        }
}

/* Sparse 4-vectors in CSR form, every array exactly sized. */
typedef struct sparse_vectors {
    size_t count, influence_count;
    int32_t *offsets, *bones;
    double *values;
} sparse_vectors;

/* `count` vectors with 1..max_bones distinct bones each (0..max_bones with allow_empty) and random
 * entries; with weight_zero the weights are shifted to sum to 0 (the last one is minus the others'). */
static sparse_vectors random_vectors_on(size_t count, size_t bone_count, size_t max_bones, int allow_empty,
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

static void free_vectors(sparse_vectors *v)
{
    free(v->offsets), free(v->bones), free(v->values);
}

/* The spatial part (top three rows) of G s for one vector, with G given per bone. */
static void apply_frames(double out[3], const double *frames, const sparse_vectors *v, size_t i)
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

typedef struct combinations {
    size_t bone_count, count;
    const int32_t *parents;
    double *local;         /* count * bone_count 4x4: L_j of each combination */
    double *world;         /* count * bone_count 4x4: G_j of each combination (own forward kinematics) */
    double *mean_local;    /* bone_count 4x4: the per-joint sample means, L_0 = I */
    double *mean_gram;     /* bone_count 4x4: the mean of G_j^T G_j over all combinations */
} combinations;

/* per_joint[j] samples of joint j (the root's L_0 is random too: it must be ignored). */
static combinations make_combinations(const int32_t *parents, const size_t *per_joint, size_t bone_count)
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

static void free_combinations(combinations *c)
{
    free(c->local), free(c->world), free(c->mean_local), free(c->mean_gram);
}

/* The brute-force E[G_j^T G_k] over every combination. */
static void brute_force_block(double block[16], const combinations *c, size_t j, size_t k)
{
    memset(block, 0, 16 * sizeof *block);
    for (size_t index = 0; index < c->count; ++index)
        add_transposed_product(block, c->world + 16 * (index * c->bone_count + j),
                               c->world + 16 * (index * c->bone_count + k));
    for (int e = 0; e < 16; ++e)
        block[e] /= (double)c->count;
}

/* sqrt(mean over combinations of |G s_i|^2), straight from the definition. */
static void brute_force_mean_distances(double *destination, const combinations *c, const sparse_vectors *v)
{
    for (size_t i = 0; i < v->count; ++i) {
        double sum = 0.0;
        for (size_t index = 0; index < c->count; ++index) {
            double moved[3];
            apply_frames(moved, c->world + 16 * index * c->bone_count, v, i);
            sum += moved[0] * moved[0] + moved[1] * moved[1] + moved[2] * moved[2];
        }
        destination[i] = sqrt(sum / (double)c->count);
    }
}

/* A branching skeleton listed out of order: 0 -> {2, 3}, 3 -> {1, 5}, 1 -> {4}; bones 1 and 4 come
 * before (or between) their ancestors. */
static const int32_t branching6[] = {-1, 3, 0, 0, 1, 3};
/* 0 -> 2 -> {1, 3}, 1 -> 4: a child (1) before its parent (2), siblings (1, 3), cousins (4, 3). */
static const int32_t branching5[] = {-1, 2, 0, 2, 1};
/* A chain listed out of order: 0 -> 2 -> 3 -> 1 -> 4. */
static const int32_t chain5[] = {-1, 3, 0, 2, 1};
/* 0 -> {1, 4}, 1 -> 3, 4 -> {2, 5}, 2 -> 6. */
static const int32_t branching7[] = {-1, 0, 4, 1, 0, 4, 2};

/* ---------------------------------------------------------------------------------------------
 * 1. sk_joint_statistics: plain averages of L_j, and the independent-joints E[G_j^T G_j]
 * ------------------------------------------------------------------------------------------- */

/* E[G_j^T G_j] = mean over samples of L_j^T E[G_p^T G_p] L_j, parents before children (at most 16 bones). */
static void independent_joint_grams(double *gram, const double *local, const int32_t *parents, size_t S, size_t B)
{
    size_t depth[16], deepest = 0;
    for (size_t bone = 0; bone < B; ++bone) {
        depth[bone] = 0;
        for (size_t node = bone; node != 0; node = (size_t)parents[node])
            ++depth[bone];
        deepest = depth[bone] > deepest ? depth[bone] : deepest;
    }
    memset(gram, 0, 16 * B * sizeof *gram);
    set_identity(gram);
    for (size_t level = 1; level <= deepest; ++level)
        for (size_t bone = 0; bone < B; ++bone) {
            if (depth[bone] != level)
                continue;
            for (size_t s = 0; s < S; ++s) {
                const double *joint = local + 16 * (B * s + bone);
                double parent_times_joint[16];
                multiply(parent_times_joint, gram + 16 * (size_t)parents[bone], joint);
                add_transposed_product(gram + 16 * bone, joint, parent_times_joint);
            }
            for (int e = 0; e < 16; ++e)
                gram[16 * bone + (size_t)e] /= (double)S;
        }
}

static void test_joint_statistics_are_plain_averages(void)
{
    const size_t B = 6, S = 7;
    double *local_data = allocate(16 * S * B, sizeof(double));
    for (size_t k = 0; k < S * B; ++k)
        random_frame(local_data + 16 * k, 0.5, 2.0, 3.0); /* L_0 too: it must be treated as I */
    double *local = exact_copy_double(local_data, 16 * S * B);
    int32_t *parents = exact_copy_int32(branching6, B);

    double expected_local[96] = {0}, expected_gram[96] = {0}, world[96];
    for (size_t s = 0; s < S; ++s)
        for (size_t bone = 0; bone < B; ++bone)
            for (int e = 0; e < 16; ++e)
                expected_local[16 * bone + (size_t)e] += bone == 0 ? (e % 5 == 0) : local[16 * (B * s + bone) + (size_t)e];
    for (size_t k = 0; k < 16 * B; ++k)
        expected_local[k] /= (double)S;
    independent_joint_grams(expected_gram, local, parents, S, B);

    double *mean_local = allocate(16 * B, sizeof(double)), *mean_gram = allocate(16 * B, sizeof(double));
    EXPECT_SUCCESS("joint statistics", sk_joint_statistics(mean_local, mean_gram, local, parents, S, B, error));
    CHECK(close_to(mean_local, expected_local, 16 * B, 1e-13));
    CHECK(close_to(mean_gram, expected_gram, 16 * B, 1e-12));
    double identity[16];
    set_identity(identity);
    CHECK_IN("E[L_0] is exactly I", memcmp(mean_local, identity, sizeof identity) == 0);
    CHECK_IN("E[G_0^T G_0] is exactly I", memcmp(mean_gram, identity, sizeof identity) == 0);
    /* Guards the comparison: the grams are far from the identity and differ between bones. */
    CHECK(max_abs_difference(expected_gram + 16 * 4, identity, 16) > 0.5);
    CHECK(max_abs_difference(expected_gram + 16 * 4, expected_gram + 16 * 1, 16) > 0.1);

    /* Another L_0 in every sample changes nothing, bit for bit. */
    double *other_local = allocate(16 * B, sizeof(double)), *other_gram = allocate(16 * B, sizeof(double));
    for (size_t s = 0; s < S; ++s)
        random_frame(local + 16 * B * s, 0.1, 5.0, 10.0);
    EXPECT_SUCCESS("joint statistics, other L_0",
                   sk_joint_statistics(other_local, other_gram, local, parents, S, B, error));
    CHECK_IN("L_0 is ignored", memcmp(other_local, mean_local, 16 * B * sizeof(double)) == 0);
    CHECK_IN("L_0 is ignored", memcmp(other_gram, mean_gram, 16 * B * sizeof(double)) == 0);

    /* One sample: the statistics are that pose's own L_j and G_j^T G_j. */
    double gram_one[96] = {0};
    world_frames(world, local, parents, B);
    for (size_t bone = 0; bone < B; ++bone)
        add_transposed_product(gram_one + 16 * bone, world + 16 * bone, world + 16 * bone);
    EXPECT_SUCCESS("one sample", sk_joint_statistics(other_local, other_gram, local, parents, 1, B, error));
    CHECK(close_to(other_local + 16, local + 16, 16 * (B - 1), 1e-15));
    CHECK(close_to(other_gram, gram_one, 16 * B, 1e-12));

    /* The same skeleton relabelled parents-first gives the same statistics, permuted. */
    static const size_t relabel[] = {0, 3, 1, 2, 5, 4}; /* old bone -> new bone: 0,2,3 | 1,5 | 4 by depth */
    int32_t sorted_parents_data[6];
    double *sorted_local_data = allocate(16 * S * B, sizeof(double));
    for (size_t bone = 0; bone < B; ++bone) {
        sorted_parents_data[relabel[bone]] = bone == 0 ? -1 : (int32_t)relabel[parents[bone]];
        for (size_t s = 0; s < S; ++s)
            memcpy(sorted_local_data + 16 * (B * s + relabel[bone]), local_data + 16 * (B * s + bone), 16 * sizeof(double));
    }
    for (size_t bone = 1; bone < B; ++bone)
        CHECK_IN("relabelled parents come first", sorted_parents_data[bone] < (int32_t)bone);
    int32_t *sorted_parents = exact_copy_int32(sorted_parents_data, B);
    double *sorted_local = exact_copy_double(sorted_local_data, 16 * S * B);
    EXPECT_SUCCESS("relabelled",
                   sk_joint_statistics(other_local, other_gram, sorted_local, sorted_parents, S, B, error));
    for (size_t bone = 0; bone < B; ++bone) {
        CHECK_IN("relabelled E[L]", close_to(other_local + 16 * relabel[bone], expected_local + 16 * bone, 16, 1e-13));
        CHECK_IN("relabelled E[G^T G]", close_to(other_gram + 16 * relabel[bone], expected_gram + 16 * bone, 16, 1e-12));
    }

    free(local_data), free(local), free(parents), free(mean_local), free(mean_gram), free(other_local);
    free(other_gram), free(sorted_local_data), free(sorted_parents), free(sorted_local);
}

/* ---------------------------------------------------------------------------------------------
 * 2. sk_expectation_block equals brute force over independently sampled joints
 * ------------------------------------------------------------------------------------------- */

static void test_blocks_equal_brute_force(void)
{
    const size_t B = 5, per_joint[] = {2, 3, 2, 3, 2}; /* 72 combinations; L_0's two samples are ignored */
    int32_t *parents = exact_copy_int32(branching5, B);
    combinations c = make_combinations(parents, per_joint, B);
    double *mean_local = exact_copy_double(c.mean_local, 16 * B), *mean_gram = exact_copy_double(c.mean_gram, 16 * B);

    /* The statistics of the combinations are the per-joint means (the core's own pipeline). */
    double *local = exact_copy_double(c.local, 16 * c.count * B);
    double *core_local = allocate(16 * B, sizeof(double)), *core_gram = allocate(16 * B, sizeof(double));
    EXPECT_SUCCESS("statistics of the combinations",
                   sk_joint_statistics(core_local, core_gram, local, parents, c.count, B, error));
    CHECK(close_to(core_local, c.mean_local, 16 * B, 1e-13));
    CHECK(close_to(core_gram, c.mean_gram, 16 * B, 1e-12));

    static const char *const kinds[] = {"j == k", "j ancestor of k", "k ancestor of j", "siblings", "cousins"};
    size_t kind_count[5] = {0};
    double largest = 0.0;
    for (size_t j = 0; j < B; ++j)
        for (size_t k = 0; k < B; ++k) {
            double brute[16], block[16], from_core_statistics[16];
            brute_force_block(brute, &c, j, k);
            largest = fmax(largest, max_abs(brute, 16));
            EXPECT_SUCCESS("block", sk_expectation_block(block, mean_local, mean_gram, parents, B, j, k, error));
            EXPECT_SUCCESS("block from core statistics",
                           sk_expectation_block(from_core_statistics, core_local, core_gram, parents, B, j, k, error));
            const int kind = j == k                       ? 0
                             : is_ancestor(parents, j, k) ? 1
                             : is_ancestor(parents, k, j) ? 2
                             : parents[j] == parents[k]   ? 3
                                                          : 4;
            ++kind_count[kind];
            char context[96];
            snprintf(context, sizeof context, "P_%zu%zu (%s)", j, k, kinds[kind]);
            CHECK_IN(context, close_to(block, brute, 16, 1e-12));
            CHECK_IN(context, close_to(from_core_statistics, brute, 16, 1e-12));
        }
    CHECK_IN("every kind of pair is covered", kind_count[0] == B && kind_count[1] > 0 && kind_count[2] > 0 &&
                                                  kind_count[3] > 0 && kind_count[4] > 0);
    CHECK_IN("blocks are not trivially small", largest > 1.0);

    /* Guards the brute force itself: independent joints really differ from "E[G_j]^T E[G_k]" products,
     * so a recursion that dropped the ancestor's gram would fail above. */
    double naive[16] = {0}, brute[16], g1[16] = {0}, g3[16] = {0};
    for (size_t index = 0; index < c.count; ++index)
        for (int e = 0; e < 16; ++e)
            g1[e] += c.world[16 * (index * B + 1) + (size_t)e] / (double)c.count,
                g3[e] += c.world[16 * (index * B + 3) + (size_t)e] / (double)c.count;
    add_transposed_product(naive, g1, g3);
    brute_force_block(brute, &c, 1, 3);
    CHECK(max_abs_difference(naive, brute, 16) > 0.01);

    free_combinations(&c);
    free(parents), free(mean_local), free(mean_gram), free(local), free(core_local), free(core_gram);
}

/* ---------------------------------------------------------------------------------------------
 * 3. sk_mean_distances: definition, block cache, thread counts
 * ------------------------------------------------------------------------------------------- */

typedef struct metric_fixture {
    size_t bone_count;
    int32_t *parents;
    combinations c;
    double *mean_local, *mean_gram; /* exact copies */
} metric_fixture;

static metric_fixture make_metric_fixture(void)
{
    static const size_t per_joint[] = {1, 3, 2, 3, 2};
    metric_fixture f = {.bone_count = 5, .parents = exact_copy_int32(branching5, 5)};
    f.c = make_combinations(f.parents, per_joint, f.bone_count);
    f.mean_local = exact_copy_double(f.c.mean_local, 16 * f.bone_count);
    f.mean_gram = exact_copy_double(f.c.mean_gram, 16 * f.bone_count);
    return f;
}

static void free_metric_fixture(metric_fixture *f)
{
    free_combinations(&f->c);
    free(f->parents), free(f->mean_local), free(f->mean_gram);
}

static sk_status mean_distances(double *out, const sparse_vectors *v, const metric_fixture *f, double *cache,
                                unsigned char *cached, int thread_count, sk_error *error)
{
    return sk_mean_distances(out, &(sk_influences){v->offsets, v->bones, v->count, v->influence_count}, v->values,
                             f->mean_local, f->mean_gram, f->parents, f->bone_count, cache, cached, thread_count,
                             error);
}

static void test_mean_distances_match_definition_and_cache(void)
{
    metric_fixture f = make_metric_fixture();
    const size_t B = f.bone_count, pairs = B * B;
    /* Vectors on bones {1, 2, 4} only, so some blocks are not needed. */
    sparse_vectors v = random_vectors_on(60, 3, 3, 1, 1);
    static const int32_t used[] = {1, 2, 4};
    for (size_t a = 0; a < v.influence_count; ++a)
        v.bones[a] = used[v.bones[a]];
    double *cache = allocate(16 * pairs, sizeof(double)), *out = allocate(v.count, sizeof(double));
    double *again = allocate(v.count, sizeof(double)), *expected = allocate(v.count, sizeof(double));
    unsigned char *cached = allocate(pairs, 1);
    for (size_t k = 0; k < 16 * pairs; ++k)
        cache[k] = 12345.0; /* sentinel: blocks no vector needs must stay unformed */

    brute_force_mean_distances(expected, &f.c, &v);
    EXPECT_SUCCESS("mean distances", mean_distances(out, &v, &f, cache, cached, 1, error));
    CHECK(close_to(out, expected, v.count, 1e-12));
    for (size_t i = 0; i < v.count; ++i)
        if (v.offsets[i] == v.offsets[i + 1])
            CHECK_IN("a vector without influences has length 0", out[i] == 0.0);
    CHECK_IN("distances are not trivially small", max_abs(expected, v.count) > 0.5);

    /* The cache holds exactly the blocks these vectors needed, each equal to sk_expectation_block's. */
    unsigned char needed[25] = {0};
    for (size_t i = 0; i < v.count; ++i)
        for (int32_t a = v.offsets[i]; a < v.offsets[i + 1]; ++a)
            for (int32_t b = v.offsets[i]; b < v.offsets[i + 1]; ++b)
                needed[(size_t)v.bones[a] * B + (size_t)v.bones[b]] = 1;
    for (size_t j = 0; j < B; ++j)
        for (size_t k = 0; k < B; ++k) {
            const size_t pair = j * B + k;
            char context[64];
            snprintf(context, sizeof context, "cache of P_%zu%zu", j, k);
            CHECK_IN(context, (cached[pair] != 0) == needed[pair]);
            double block[16];
            EXPECT_SUCCESS("block", sk_expectation_block(block, f.mean_local, f.mean_gram, f.parents, B, j, k, error));
            if (needed[pair])
                CHECK_IN(context, close_to(cache + 16 * pair, block, 16, 1e-14));
            else
                CHECK_IN(context, cache[16 * pair] == 12345.0 && cache[16 * pair + 15] == 12345.0);
        }

    /* A second call with the cache filled gives identical results. */
    EXPECT_SUCCESS("mean distances, cache filled", mean_distances(again, &v, &f, cache, cached, 1, error));
    CHECK_IN("cached call is bitwise identical", memcmp(again, out, v.count * sizeof(double)) == 0);

    /* New vectors over every bone: a partly filled cache gives the same as a fresh one, and the truth. */
    sparse_vectors w = random_vectors_on(80, B, 4, 0, 1);
    double *partly = allocate(w.count, sizeof(double)), *fresh = allocate(w.count, sizeof(double));
    double *expected_w = allocate(w.count, sizeof(double)), *fresh_cache = allocate(16 * pairs, sizeof(double));
    unsigned char *fresh_cached = allocate(pairs, 1);
    brute_force_mean_distances(expected_w, &f.c, &w);
    EXPECT_SUCCESS("mean distances, partly cached", mean_distances(partly, &w, &f, cache, cached, 1, error));
    EXPECT_SUCCESS("mean distances, fresh cache", mean_distances(fresh, &w, &f, fresh_cache, fresh_cached, 1, error));
    CHECK(close_to(partly, expected_w, w.count, 1e-12));
    CHECK_IN("partly cached == fresh", memcmp(partly, fresh, w.count * sizeof(double)) == 0);

    /* A bone listed twice in one vector counts as the sum of its entries. */
    static const int32_t twice_offsets[] = {0, 3, 5}, twice_bones[] = {4, 3, 4, 1, 2};
    double twice_values[20], merged_values[8];
    for (int k = 0; k < 20; ++k)
        twice_values[k] = random_uniform(-1, 1);
    twice_values[3] = 0.25, twice_values[7] = -0.5, twice_values[11] = 0.25, twice_values[15] = 1, twice_values[19] = -1;
    for (int c = 0; c < 4; ++c)
        merged_values[c] = twice_values[c] + twice_values[8 + c], merged_values[4 + c] = twice_values[4 + c];
    sparse_vectors twice = {2, 5, exact_copy_int32(twice_offsets, 3), exact_copy_int32(twice_bones, 5),
                            exact_copy_double(twice_values, 20)};
    static const int32_t merged_offsets[] = {0, 2}, merged_bones[] = {4, 3};
    sparse_vectors merged = {1, 2, exact_copy_int32(merged_offsets, 2), exact_copy_int32(merged_bones, 2),
                             exact_copy_double(merged_values, 8)};
    double twice_out[2], merged_out[1], twice_expected[2];
    brute_force_mean_distances(twice_expected, &f.c, &twice);
    EXPECT_SUCCESS("repeated bone", mean_distances(twice_out, &twice, &f, cache, cached, 1, error));
    EXPECT_SUCCESS("merged bone", mean_distances(merged_out, &merged, &f, cache, cached, 1, error));
    CHECK(close_to(twice_out, twice_expected, 2, 1e-12));
    CHECK(fabs(twice_out[0] - merged_out[0]) <= 1e-12 * fmax(1.0, merged_out[0]));

    free_vectors(&v), free_vectors(&w), free_vectors(&twice), free_vectors(&merged);
    free(cache), free(out), free(again), free(expected), free(cached), free(partly), free(fresh), free(expected_w);
    free(fresh_cache), free(fresh_cached);
    free_metric_fixture(&f);
}

static void test_mean_distances_thread_counts(void)
{
    const size_t V = 3 * METRIC_ITEMS_PER_WORKER + 517;
    /* Without enough vectors every thread count would run on one thread and prove nothing. */
    CHECK(sk_worker_count(V, METRIC_ITEMS_PER_WORKER, 3) == 3);
    CHECK(sk_worker_count(V, METRIC_ITEMS_PER_WORKER, 2) == 2);
    metric_fixture f = make_metric_fixture();
    const size_t pairs = f.bone_count * f.bone_count;
    sparse_vectors v = random_vectors_on(V, f.bone_count, 4, 1, 1);
    double *expected = allocate(V, sizeof(double)), *first = allocate(V, sizeof(double));
    double *other = allocate(V, sizeof(double)), *cache = allocate(16 * pairs, sizeof(double));
    unsigned char *cached = allocate(pairs, 1);
    brute_force_mean_distances(expected, &f.c, &v);
    EXPECT_SUCCESS("mean distances, 1 thread", mean_distances(first, &v, &f, cache, cached, 1, error));
    CHECK(close_to(first, expected, V, 1e-12));
    const int thread_counts[] = {0, 3, 2};
    for (size_t t = 0; t < sizeof thread_counts / sizeof thread_counts[0]; ++t) {
        /* A fresh cache each time, so the threaded call also forms its blocks itself. */
        memset(cached, 0, pairs);
        for (size_t i = 0; i < V; ++i)
            other[i] = -1.0;
        EXPECT_SUCCESS("mean distances, threads",
                       mean_distances(other, &v, &f, cache, cached, thread_counts[t], error));
        char context[64];
        snprintf(context, sizeof context, "mean distances: thread_count %d vs 1", thread_counts[t]);
        CHECK_IN(context, memcmp(first, other, V * sizeof(double)) == 0);
    }
    free_vectors(&v);
    free(expected), free(first), free(other), free(cache), free(cached);
    free_metric_fixture(&f);
}

/* ---------------------------------------------------------------------------------------------
 * 4. sk_max_distances: a bound over every pose within the joint bounds, attained by worst cases
 * ------------------------------------------------------------------------------------------- */

typedef struct joint_bounds {
    double *linear, *centre, *radius; /* exact copies: bone_count, 3 * bone_count, bone_count */
} joint_bounds;

static joint_bounds random_joint_bounds(size_t bone_count)
{
    double linear[16], centre[48], radius[16];
    for (size_t bone = 0; bone < bone_count; ++bone) {
        linear[bone] = random_uniform(0.5, 1.5);
        radius[bone] = random_uniform(0.0, 0.5);
        for (int axis = 0; axis < 3; ++axis)
            centre[3 * bone + (size_t)axis] = random_uniform(-1.0, 1.0);
    }
    linear[0] = 1.0, radius[0] = 0.0, centre[0] = centre[1] = centre[2] = 0.0; /* the root never moves */
    joint_bounds b = {exact_copy_double(linear, bone_count), exact_copy_double(centre, 3 * bone_count),
                      exact_copy_double(radius, bone_count)};
    return b;
}

static void free_joint_bounds(joint_bounds *b)
{
    free(b->linear), free(b->centre), free(b->radius);
}

static sk_status max_distances(double *out, const sparse_vectors *v, const int32_t *parents, size_t bone_count,
                               const joint_bounds *b, int thread_count, sk_error *error)
{
    return sk_max_distances(out, &(sk_influences){v->offsets, v->bones, v->count, v->influence_count}, v->values,
                            parents, b->linear, b->centre, b->radius, bone_count, thread_count, error);
}

static void check_bound_holds_for_poses(const int32_t *parent_data, size_t bone_count, const char *name)
{
    int32_t *parents = exact_copy_int32(parent_data, bone_count);
    joint_bounds b = random_joint_bounds(bone_count);
    sparse_vectors v = random_vectors_on(40, bone_count, 4, 0, 1);
    double *bound = allocate(v.count, sizeof(double)), *reached = allocate(v.count, sizeof(double));
    double local[16 * 16], world[16 * 16];
    EXPECT_SUCCESS(name, max_distances(bound, &v, parents, bone_count, &b, 1, error));
    for (int pose = 0; pose < 600; ++pose) {
        set_identity(local);
        for (size_t bone = 1; bone < bone_count; ++bone)
            random_bounded_joint(local + 16 * bone, b.linear[bone], b.centre + 3 * bone, b.radius[bone], pose % 2);
        world_frames(world, local, parents, bone_count);
        for (size_t i = 0; i < v.count; ++i) {
            double moved[3];
            apply_frames(moved, world, &v, i);
            reached[i] = fmax(reached[i], norm3(moved));
        }
    }
    size_t violations = 0;
    double tightest = 0.0;
    for (size_t i = 0; i < v.count; ++i) {
        violations += !(reached[i] <= bound[i] * (1 + 1e-12));
        tightest = fmax(tightest, reached[i] / bound[i]);
    }
    char context[96];
    snprintf(context, sizeof context, "%s: bound >= |G s| for every sampled pose", name);
    CHECK_IN(context, violations == 0);
    /* Guards the test: the poses come close enough to the bound for a wrong bound to show. */
    snprintf(context, sizeof context, "%s: some pose reaches half the bound (best %.3f)", name, tightest);
    CHECK_IN(context, tightest > 0.5);
    free(parents), free(bound), free(reached);
    free_vectors(&v);
    free_joint_bounds(&b);
}

static void test_max_distance_bounds_every_pose(void)
{
    check_bound_holds_for_poses(chain5, 5, "chain");
    check_bound_holds_for_poses(branching7, 7, "branching");
    check_bound_holds_for_poses(branching6, 6, "branching, child first");
}

/* A weight-only vector on a child of the root moves by w t: the bound |w| (|c| + r) is attained. */
static void test_max_distance_weight_only_worst_case(void)
{
    static const int32_t parent_data[] = {-1, 0};
    const double linear_data[] = {1.0, 1.0}, centre_data[] = {0, 0, 0, 1.0, 2.0, 2.0}, radius_data[] = {0.0, 0.5};
    joint_bounds b = {exact_copy_double(linear_data, 2), exact_copy_double(centre_data, 6),
                      exact_copy_double(radius_data, 2)};
    int32_t *parents = exact_copy_int32(parent_data, 2);
    static const int32_t offsets[] = {0, 2}, bones[] = {0, 1};
    const double weights[] = {-0.75, 0.75, 1.5};
    double bounds[3];
    for (int n = 0; n < 3; ++n) {
        const double w = weights[n], values[] = {0, 0, 0, -w, 0, 0, 0, w};
        sparse_vectors v = {1, 2, exact_copy_int32(offsets, 2), exact_copy_int32(bones, 2), exact_copy_double(values, 8)};
        EXPECT_SUCCESS("weight-only vector", max_distances(bounds + n, &v, parents, 2, &b, 1, error));
        const double expected = fabs(w) * (3.0 + 0.5); /* |c| = 3 */
        char context[64];
        snprintf(context, sizeof context, "bound |w| (|c| + r) for w = %g", w);
        CHECK_IN(context, fabs(bounds[n] - expected) <= 1e-14 * expected);
        /* The pose that attains it: t = c + r c / |c|, any rotation. */
        double local[32], world[32], moved[3], rotation[9];
        const double scales[] = {1, 1, 1}, t[] = {1.0 + 0.5 / 3.0, 2.0 + 1.0 / 3.0, 2.0 + 1.0 / 3.0};
        random_rotation(rotation);
        set_identity(local);
        make_frame(local + 16, rotation, scales, t);
        world_frames(world, local, parents, 2);
        apply_frames(moved, world, &v, 0);
        CHECK_IN(context, fabs(norm3(moved) - bounds[n]) <= 1e-14 * expected);
        free_vectors(&v);
    }
    CHECK_IN("a negative weight uses |w|", bounds[0] == bounds[1]);
    free_joint_bounds(&b);
    free(parents);
}

/* On a chain 0 -> 2 -> 1 with a vector (v, w) on bone 1 (and -w on the root), the bound
 *   |w| (|c_2| + r_2) + s_2 (|w| (|c_1| + r_1) + s_1 |v|)
 * is attained by a pose lining everything up: every scale at its bound, each rotation turning the
 * child's contribution onto sign(w) c / |c|, each translation at c + r c / |c|. */
static void test_max_distance_chain_worst_case(void)
{
    static const int32_t parent_data[] = {-1, 2, 0};
    int32_t *parents = exact_copy_int32(parent_data, 3);
    static const int32_t offsets[] = {0, 2}, bones[] = {0, 1};
    for (int trial = 0; trial < 20; ++trial) {
        double linear[3] = {1.0, random_uniform(0.3, 2.0), random_uniform(0.3, 2.0)}, centre[9] = {0}, radius[3] = {0};
        for (size_t bone = 1; bone < 3; ++bone) {
            radius[bone] = random_uniform(0.0, 1.0);
            for (int axis = 0; axis < 3; ++axis)
                centre[3 * bone + (size_t)axis] = random_uniform(-2.0, 2.0);
        }
        const double w = trial % 2 ? random_uniform(0.2, 1.5) : -random_uniform(0.2, 1.5); /* both signs */
        double values[8] = {0, 0, 0, -w, 0, 0, 0, w};
        for (int axis = 0; axis < 3; ++axis)
            values[4 + axis] = random_uniform(-1.0, 1.0);
        joint_bounds b = {exact_copy_double(linear, 3), exact_copy_double(centre, 9), exact_copy_double(radius, 3)};
        sparse_vectors v = {1, 2, exact_copy_int32(offsets, 2), exact_copy_int32(bones, 2), exact_copy_double(values, 8)};
        double bound;
        EXPECT_SUCCESS("chain worst case", max_distances(&bound, &v, parents, 3, &b, 1, error));

        const double *c1 = centre + 3, *c2 = centre + 6, aw = fabs(w), sign = w < 0 ? -1.0 : 1.0;
        const double inner = aw * (norm3(c1) + radius[1]) + linear[1] * norm3(values + 4);
        const double expected = aw * (norm3(c2) + radius[2]) + linear[2] * inner;
        CHECK_IN("chain bound formula", fabs(bound - expected) <= 1e-13 * expected);

        /* Bone 1 (in bone 2's frame): its linear part turns v onto d1 = sign(w) c1 / |c1|. */
        double d1[3], d2[3], v_unit[3], rotation[9], local[48], world[48], moved[3], t1[3], t2[3];
        for (int axis = 0; axis < 3; ++axis) {
            d1[axis] = sign * c1[axis] / norm3(c1), d2[axis] = sign * c2[axis] / norm3(c2);
            v_unit[axis] = values[4 + axis] / norm3(values + 4);
            t1[axis] = c1[axis] + radius[1] * c1[axis] / norm3(c1);
            t2[axis] = c2[axis] + radius[2] * c2[axis] / norm3(c2);
        }
        set_identity(local);
        const double s1[3] = {linear[1], linear[1], linear[1]}, s2[3] = {linear[2], linear[2], linear[2]};
        rotation_between(rotation, v_unit, d1);
        make_frame(local + 16, rotation, s1, t1);
        rotation_between(rotation, d1, d2); /* bone 2 turns bone 1's contribution (along d1) onto d2 */
        make_frame(local + 32, rotation, s2, t2);
        world_frames(world, local, parents, 3);
        apply_frames(moved, world, &v, 0);
        CHECK_IN("the lined-up pose attains the bound", fabs(norm3(moved) - bound) <= 1e-12 * expected);
        free_vectors(&v);
        free_joint_bounds(&b);
    }
    free(parents);
}

/* Vectors without influences have length 0 (the bound must not be left over from another vector). */
static void test_max_distance_of_empty_vectors(void)
{
    const size_t B = 5;
    int32_t *parents = exact_copy_int32(chain5, B);
    joint_bounds b = random_joint_bounds(B);
    static const int32_t offsets_data[] = {0, 0, 2, 2, 2, 3, 3}, bones_data[] = {4, 1, 3};
    double values_data[12];
    for (int k = 0; k < 12; ++k)
        values_data[k] = random_uniform(-1, 1);
    sparse_vectors v = {6, 3, exact_copy_int32(offsets_data, 7), exact_copy_int32(bones_data, 3),
                        exact_copy_double(values_data, 12)};
    double out[6] = {-1, -1, -1, -1, -1, -1}, mean_out[6];
    EXPECT_SUCCESS("empty vectors", max_distances(out, &v, parents, B, &b, 1, error));
    CHECK_IN("non-empty vectors have a positive bound", out[1] > 0.0 && out[4] > 0.0);
    CHECK_IN("first vector, empty", out[0] == 0.0);
    CHECK_IN("empty after a non-empty vector", out[2] == 0.0);
    CHECK_IN("second empty in a row", out[3] == 0.0);
    CHECK_IN("last vector, empty", out[5] == 0.0);

    metric_fixture f = make_metric_fixture();
    double *cache = allocate(16 * B * B, sizeof(double));
    unsigned char *cached = allocate(B * B, 1);
    EXPECT_SUCCESS("empty vectors, mean", mean_distances(mean_out, &v, &f, cache, cached, 1, error));
    CHECK_IN("empty vectors, mean", mean_out[0] == 0.0 && mean_out[2] == 0.0 && mean_out[3] == 0.0 && mean_out[5] == 0.0);

    /* No vectors at all: nothing written, no arrays needed beyond offsets. */
    static const int32_t none[] = {0};
    double canary[2] = {7.0, 7.0};
    EXPECT_SUCCESS("no vectors, max", sk_max_distances(canary, &(sk_influences){none, NULL, 0, 0}, NULL, parents,
                                                       b.linear, b.centre, b.radius, B, 0, error));
    EXPECT_SUCCESS("no vectors, mean", sk_mean_distances(canary, &(sk_influences){none, NULL, 0, 0}, NULL,
                                                         f.mean_local, f.mean_gram, f.parents, B, cache, cached, 0,
                                                         error));
    CHECK_IN("nothing written for zero vectors", canary[0] == 7.0 && canary[1] == 7.0);

    free(cache), free(cached), free(parents);
    free_metric_fixture(&f);
    free_vectors(&v);
    free_joint_bounds(&b);
}

static void test_max_distance_thread_counts(void)
{
    const size_t V = 3 * METRIC_ITEMS_PER_WORKER + 517, B = 7;
    CHECK(sk_worker_count(V, METRIC_ITEMS_PER_WORKER, 3) == 3);
    int32_t *parents = exact_copy_int32(branching7, B);
    joint_bounds b = random_joint_bounds(B);
    sparse_vectors v = random_vectors_on(V, B, 4, 1, 1);
    double *first = allocate(V, sizeof(double)), *other = allocate(V, sizeof(double));
    EXPECT_SUCCESS("max distances, 1 thread", max_distances(first, &v, parents, B, &b, 1, error));
    const int thread_counts[] = {0, 3, 2};
    for (size_t t = 0; t < sizeof thread_counts / sizeof thread_counts[0]; ++t) {
        for (size_t i = 0; i < V; ++i)
            other[i] = -1.0;
        EXPECT_SUCCESS("max distances, threads", max_distances(other, &v, parents, B, &b, thread_counts[t], error));
        char context[64];
        snprintf(context, sizeof context, "max distances: thread_count %d vs 1", thread_counts[t]);
        CHECK_IN(context, memcmp(first, other, V * sizeof(double)) == 0);
    }
    /* Spot-check the large run: the bound holds for extreme poses, and empty vectors give 0. */
    double local[16 * 7], world[16 * 7];
    size_t violations = 0, empty_wrong = 0;
    for (int pose = 0; pose < 20; ++pose) {
        set_identity(local);
        for (size_t bone = 1; bone < B; ++bone)
            random_bounded_joint(local + 16 * bone, b.linear[bone], b.centre + 3 * bone, b.radius[bone], 1);
        world_frames(world, local, parents, B);
        for (size_t i = 0; i < V; ++i) {
            double moved[3];
            apply_frames(moved, world, &v, i);
            violations += !(norm3(moved) <= first[i] * (1 + 1e-12));
        }
    }
    for (size_t i = 0; i < V; ++i)
        empty_wrong += v.offsets[i] == v.offsets[i + 1] && first[i] != 0.0;
    CHECK_IN("large run: bound holds", violations == 0);
    CHECK_IN("large run: empty vectors give 0", empty_wrong == 0);
    free(parents), free(first), free(other);
    free_vectors(&v);
    free_joint_bounds(&b);
}

/* ---------------------------------------------------------------------------------------------
 * 5. Errors
 * ------------------------------------------------------------------------------------------- */

static int message_has(const char *message, const char *a, const char *b)
{
    return strstr(message, a) != NULL && (!b || strstr(message, b) != NULL);
}

static void test_joint_statistics_errors(void)
{
    const size_t B = 4, S = 3;
    static const int32_t good_parents[] = {-1, 2, 0, 2};
    double *local = allocate(16 * S * B, sizeof(double));
    for (size_t k = 0; k < S * B; ++k)
        random_frame(local + 16 * k, 0.5, 2.0, 1.0);
    double *exact_local = exact_copy_double(local, 16 * S * B);
    int32_t *parents = exact_copy_int32(good_parents, B);
    double *el = allocate(16 * B, sizeof(double)), *eg = allocate(16 * B, sizeof(double));

    EXPECT_SUCCESS("valid statistics", sk_joint_statistics(el, eg, exact_local, parents, S, B, error));
    CHECK(sk_joint_statistics(el, eg, exact_local, parents, S, B, NULL) == SK_OK);
    EXPECT_FAILURE("null expected_local", SK_ERROR_ARGUMENT,
                   sk_joint_statistics(NULL, eg, exact_local, parents, S, B, error));
    EXPECT_FAILURE("null expected_gram", SK_ERROR_ARGUMENT,
                   sk_joint_statistics(el, NULL, exact_local, parents, S, B, error));
    EXPECT_FAILURE("null local", SK_ERROR_ARGUMENT, sk_joint_statistics(el, eg, NULL, parents, S, B, error));
    EXPECT_FAILURE("null parents", SK_ERROR_ARGUMENT, sk_joint_statistics(el, eg, exact_local, NULL, S, B, error));
    EXPECT_FAILURE("sample_count 0", SK_ERROR_ARGUMENT, sk_joint_statistics(el, eg, exact_local, parents, 0, B, error));
    EXPECT_FAILURE("bone_count 0", SK_ERROR_ARGUMENT, sk_joint_statistics(el, eg, exact_local, parents, S, 0, error));

    const double bad_values[] = {NAN, INFINITY, -INFINITY};
    for (size_t n = 0; n < 3; ++n) {
        double *bad = exact_copy_double(local, 16 * S * B);
        bad[16 * (B * 1 + 2) + 6] = bad_values[n]; /* sample 1, bone 2 */
        EXPECT_FAILURE("non-finite sample", SK_ERROR_NOT_FINITE,
                       sk_joint_statistics(el, eg, bad, parents, S, B, error));
        sk_error record = empty_error();
        sk_joint_statistics(el, eg, bad, parents, S, B, &record);
        CHECK_IN(record.message, message_has(record.message, "sample 1", "bone 2"));
        free(bad);
        bad = exact_copy_double(local, 16 * S * B);
        bad[16 * (B * (S - 1) + B - 1) + 15] = bad_values[n]; /* the very last value: sample 2, bone 3 */
        record = empty_error();
        CHECK(sk_joint_statistics(el, eg, bad, parents, S, B, &record) == SK_ERROR_NOT_FINITE);
        CHECK_IN(record.message, message_has(record.message, "sample 2", "bone 3"));
        free(bad);
    }

    static const int32_t cycle[] = {-1, 2, 3, 1}, self[] = {-1, 1, 0, 0}, no_root[] = {0, 0, 1, 2};
    static const int32_t beyond[] = {-1, 0, 4, 1}, negative[] = {-1, 0, -1, 1}, huge[] = {-1, INT32_MAX, 0, 0};
    const struct { const char *name; const int32_t *parents; sk_status status; } skeletons[] = {
        {"cyclic parents", cycle, SK_ERROR_CYCLE},          {"bone its own parent", self, SK_ERROR_CYCLE},
        {"root with a parent", no_root, SK_ERROR_CYCLE},    {"parent == bone_count", beyond, SK_ERROR_INDEX},
        {"negative parent", negative, SK_ERROR_INDEX},      {"parent INT32_MAX", huge, SK_ERROR_INDEX},
    };
    for (size_t n = 0; n < sizeof skeletons / sizeof skeletons[0]; ++n) {
        int32_t *bad = exact_copy_int32(skeletons[n].parents, B);
        EXPECT_FAILURE(skeletons[n].name, skeletons[n].status,
                       sk_joint_statistics(el, eg, exact_local, bad, S, B, error));
        free(bad);
    }
    free(local), free(exact_local), free(parents), free(el), free(eg);
}

static void test_expectation_block_errors(void)
{
    const size_t B = 4;
    static const int32_t good_parents[] = {-1, 2, 0, 2}, cycle[] = {-1, 2, 3, 1}, beyond[] = {-1, 0, 4, 1};
    double local[64], gram[64];
    for (size_t bone = 0; bone < B; ++bone)
        random_frame(local + 16 * bone, 0.5, 2.0, 1.0), random_frame(gram + 16 * bone, 0.5, 2.0, 1.0);
    double *el = exact_copy_double(local, 16 * B), *eg = exact_copy_double(gram, 16 * B), block[16];
    int32_t *parents = exact_copy_int32(good_parents, B), *cyclic = exact_copy_int32(cycle, B);
    int32_t *out_of_range = exact_copy_int32(beyond, B);

    EXPECT_SUCCESS("valid block", sk_expectation_block(block, el, eg, parents, B, 3, 1, error));
    CHECK(sk_expectation_block(block, el, eg, parents, B, 1, 3, NULL) == SK_OK);
    EXPECT_FAILURE("null block", SK_ERROR_ARGUMENT, sk_expectation_block(NULL, el, eg, parents, B, 1, 3, error));
    EXPECT_FAILURE("null expected_local", SK_ERROR_ARGUMENT,
                   sk_expectation_block(block, NULL, eg, parents, B, 1, 3, error));
    EXPECT_FAILURE("null expected_gram", SK_ERROR_ARGUMENT,
                   sk_expectation_block(block, el, NULL, parents, B, 1, 3, error));
    EXPECT_FAILURE("null parents", SK_ERROR_ARGUMENT, sk_expectation_block(block, el, eg, NULL, B, 1, 3, error));
    EXPECT_FAILURE("j == bone_count", SK_ERROR_INDEX, sk_expectation_block(block, el, eg, parents, B, B, 1, error));
    EXPECT_FAILURE("k == bone_count", SK_ERROR_INDEX, sk_expectation_block(block, el, eg, parents, B, 0, B, error));
    EXPECT_FAILURE("j huge", SK_ERROR_INDEX, sk_expectation_block(block, el, eg, parents, B, SIZE_MAX, 0, error));
    EXPECT_FAILURE("k huge", SK_ERROR_INDEX,
                   sk_expectation_block(block, el, eg, parents, B, 2, (size_t)1 << 40, error));
    EXPECT_FAILURE("no bones", SK_ERROR_INDEX, sk_expectation_block(block, el, eg, parents, 0, 0, 0, error));
    EXPECT_FAILURE("cyclic parents", SK_ERROR_CYCLE, sk_expectation_block(block, el, eg, cyclic, B, 1, 3, error));
    EXPECT_FAILURE("parent out of range", SK_ERROR_INDEX,
                   sk_expectation_block(block, el, eg, out_of_range, B, 1, 3, error));
    el[16 * 3 + 5] = NAN;
    EXPECT_FAILURE("NaN in expected_local", SK_ERROR_NOT_FINITE,
                   sk_expectation_block(block, el, eg, parents, B, 0, 0, error));
    el[16 * 3 + 5] = 1.0, eg[16 * 0 + 2] = INFINITY;
    EXPECT_FAILURE("infinity in expected_gram", SK_ERROR_NOT_FINITE,
                   sk_expectation_block(block, el, eg, parents, B, 1, 1, error));
    free(el), free(eg), free(parents), free(cyclic), free(out_of_range);
}

/* A malformed vector pattern over 4 bones, rejected by both distance functions. */
typedef struct pattern_case {
    const char *name;
    const int32_t *offsets, *bones;
    size_t count, influence_count;
} pattern_case;

typedef struct error_fixture {
    size_t bone_count;
    int32_t *parents, *cyclic;
    double *el, *eg;
    joint_bounds b;
    double *cache;
    unsigned char *cached;
} error_fixture;

static void expect_distances_reject(const error_fixture *x, const pattern_case *p, sk_status expected)
{
    const size_t B = x->bone_count;
    int32_t *offsets = exact_copy_int32(p->offsets, p->count + 1), *bones = exact_copy_int32(p->bones, p->influence_count);
    double values[64];
    for (int k = 0; k < 64; ++k)
        values[k] = 0.125 * (k % 7) - 0.25;
    double *vectors = exact_copy_double(values, 4 * p->influence_count), out[16];
    EXPECT_FAILURE(p->name, expected,
                   sk_mean_distances(out, &(sk_influences){offsets, bones, p->count, p->influence_count}, vectors,
                                     x->el, x->eg, x->parents, B, x->cache, x->cached, 1, error));
    EXPECT_FAILURE(p->name, expected, sk_max_distances(out,
                                                       &(sk_influences){offsets, bones, p->count, p->influence_count},
                                                       vectors, x->parents, x->b.linear, x->b.centre, x->b.radius, B,
                                                       1, error));
    free(offsets), free(bones), free(vectors);
}

static void test_distance_errors(void)
{
    const size_t B = 4;
    static const int32_t good_parents[] = {-1, 2, 0, 2}, cycle[] = {-1, 3, 1, 2};
    error_fixture x = {.bone_count = B, .parents = exact_copy_int32(good_parents, B), .cyclic = exact_copy_int32(cycle, B),
                       .b = random_joint_bounds(B), .cache = allocate(16 * B * B, sizeof(double)),
                       .cached = allocate(B * B, 1)};
    double local[64], gram[64];
    for (size_t bone = 0; bone < B; ++bone)
        random_frame(local + 16 * bone, 0.5, 2.0, 1.0), random_frame(gram + 16 * bone, 0.5, 2.0, 1.0);
    x.el = exact_copy_double(local, 16 * B), x.eg = exact_copy_double(gram, 16 * B);

    /* The well-formed pattern the bad ones are derived from. */
    static const int32_t offsets_data[] = {0, 2, 3}, bones_data[] = {1, 3, 2};
    const double values_data[] = {0.5, -1, 2, 0.25, 1, 1, -1, -0.25, 3, 0, 1, 0};
    int32_t *offsets = exact_copy_int32(offsets_data, 3), *bones = exact_copy_int32(bones_data, 3);
    double *vectors = exact_copy_double(values_data, 12), out[2];
    const size_t V = 2, K = 3;
#define MEAN(dst, off, bon, vec, el, eg, par, cache, flags)                                                            \
    sk_mean_distances(dst, &(sk_influences){off, bon, V, K}, vec, el, eg, par, B, cache, flags, 1, error)
#define MAX(dst, off, bon, vec, par, lin, cen, rad) sk_max_distances(dst, &(sk_influences){off, bon, V, K}, vec, par, lin, cen, rad, B, 1, error)
    EXPECT_SUCCESS("valid mean", MEAN(out, offsets, bones, vectors, x.el, x.eg, x.parents, x.cache, x.cached));
    EXPECT_SUCCESS("valid max", MAX(out, offsets, bones, vectors, x.parents, x.b.linear, x.b.centre, x.b.radius));
    CHECK(sk_mean_distances(out, &(sk_influences){offsets, bones, V, K}, vectors, x.el, x.eg, x.parents, B, x.cache,
                            x.cached, 1, NULL) == SK_OK);
    CHECK(sk_max_distances(out, &(sk_influences){offsets, bones, V, K}, vectors, x.parents, x.b.linear, x.b.centre,
                           x.b.radius, B, 1, NULL) == SK_OK);
    memset(x.cached, 0, B * B); /* every mean-distance call from here on fails: none may touch the cache */

    EXPECT_FAILURE("mean: null destination", SK_ERROR_ARGUMENT,
                   MEAN(NULL, offsets, bones, vectors, x.el, x.eg, x.parents, x.cache, x.cached));
    EXPECT_FAILURE("mean: null offsets", SK_ERROR_ARGUMENT,
                   MEAN(out, NULL, bones, vectors, x.el, x.eg, x.parents, x.cache, x.cached));
    EXPECT_FAILURE("mean: null bones", SK_ERROR_ARGUMENT,
                   MEAN(out, offsets, NULL, vectors, x.el, x.eg, x.parents, x.cache, x.cached));
    EXPECT_FAILURE("mean: null vectors", SK_ERROR_ARGUMENT,
                   MEAN(out, offsets, bones, NULL, x.el, x.eg, x.parents, x.cache, x.cached));
    EXPECT_FAILURE("mean: null expected_local", SK_ERROR_ARGUMENT,
                   MEAN(out, offsets, bones, vectors, NULL, x.eg, x.parents, x.cache, x.cached));
    EXPECT_FAILURE("mean: null expected_gram", SK_ERROR_ARGUMENT,
                   MEAN(out, offsets, bones, vectors, x.el, NULL, x.parents, x.cache, x.cached));
    EXPECT_FAILURE("mean: null parents", SK_ERROR_ARGUMENT,
                   MEAN(out, offsets, bones, vectors, x.el, x.eg, NULL, x.cache, x.cached));
    EXPECT_FAILURE("mean: null block cache", SK_ERROR_ARGUMENT,
                   MEAN(out, offsets, bones, vectors, x.el, x.eg, x.parents, NULL, x.cached));
    EXPECT_FAILURE("mean: null cached flags", SK_ERROR_ARGUMENT,
                   MEAN(out, offsets, bones, vectors, x.el, x.eg, x.parents, x.cache, NULL));
    EXPECT_FAILURE("mean: cyclic parents", SK_ERROR_CYCLE,
                   MEAN(out, offsets, bones, vectors, x.el, x.eg, x.cyclic, x.cache, x.cached));
    EXPECT_FAILURE("mean: no bones", SK_ERROR_ARGUMENT,
                   sk_mean_distances(out, &(sk_influences){offsets, bones, V, K}, vectors, x.el, x.eg, x.parents, 0,
                                     x.cache, x.cached, 1, error));

    EXPECT_FAILURE("max: null destination", SK_ERROR_ARGUMENT,
                   MAX(NULL, offsets, bones, vectors, x.parents, x.b.linear, x.b.centre, x.b.radius));
    EXPECT_FAILURE("max: null offsets", SK_ERROR_ARGUMENT,
                   MAX(out, NULL, bones, vectors, x.parents, x.b.linear, x.b.centre, x.b.radius));
    EXPECT_FAILURE("max: null bones", SK_ERROR_ARGUMENT,
                   MAX(out, offsets, NULL, vectors, x.parents, x.b.linear, x.b.centre, x.b.radius));
    EXPECT_FAILURE("max: null vectors", SK_ERROR_ARGUMENT,
                   MAX(out, offsets, bones, NULL, x.parents, x.b.linear, x.b.centre, x.b.radius));
    EXPECT_FAILURE("max: null parents", SK_ERROR_ARGUMENT,
                   MAX(out, offsets, bones, vectors, NULL, x.b.linear, x.b.centre, x.b.radius));
    EXPECT_FAILURE("max: null linear_bound", SK_ERROR_ARGUMENT,
                   MAX(out, offsets, bones, vectors, x.parents, NULL, x.b.centre, x.b.radius));
    EXPECT_FAILURE("max: null centre", SK_ERROR_ARGUMENT,
                   MAX(out, offsets, bones, vectors, x.parents, x.b.linear, NULL, x.b.radius));
    EXPECT_FAILURE("max: null radius", SK_ERROR_ARGUMENT,
                   MAX(out, offsets, bones, vectors, x.parents, x.b.linear, x.b.centre, NULL));
    EXPECT_FAILURE("max: cyclic parents", SK_ERROR_CYCLE,
                   MAX(out, offsets, bones, vectors, x.cyclic, x.b.linear, x.b.centre, x.b.radius));
    EXPECT_FAILURE("max: no bones", SK_ERROR_ARGUMENT,
                   sk_max_distances(out, &(sk_influences){offsets, bones, V, K}, vectors, x.parents, x.b.linear,
                                    x.b.centre, x.b.radius, 0, 1, error));

    /* Non-finite vectors and statistics. */
    const double bad_values[] = {NAN, INFINITY, -INFINITY};
    for (size_t n = 0; n < 3; ++n) {
        double *bad = exact_copy_double(values_data, 12);
        bad[4 * 2 + 3] = bad_values[n];
        EXPECT_FAILURE("mean: non-finite vector", SK_ERROR_NOT_FINITE,
                       MEAN(out, offsets, bones, bad, x.el, x.eg, x.parents, x.cache, x.cached));
        EXPECT_FAILURE("max: non-finite vector", SK_ERROR_NOT_FINITE,
                       MAX(out, offsets, bones, bad, x.parents, x.b.linear, x.b.centre, x.b.radius));
        sk_error record = empty_error();
        sk_max_distances(out, &(sk_influences){offsets, bones, V, K}, bad, x.parents, x.b.linear, x.b.centre,
                         x.b.radius, B, 1, &record);
        CHECK_IN(record.message, message_has(record.message, "influence 2", NULL));
        free(bad);
        double *bad_local = exact_copy_double(local, 16 * B), *bad_gram = exact_copy_double(gram, 16 * B);
        bad_local[16 * 2 + 1] = bad_values[n], bad_gram[16 * 3 + 10] = bad_values[n];
        EXPECT_FAILURE("mean: non-finite expected_local", SK_ERROR_NOT_FINITE,
                       MEAN(out, offsets, bones, vectors, bad_local, x.eg, x.parents, x.cache, x.cached));
        EXPECT_FAILURE("mean: non-finite expected_gram", SK_ERROR_NOT_FINITE,
                       MEAN(out, offsets, bones, vectors, x.el, bad_gram, x.parents, x.cache, x.cached));
        free(bad_local), free(bad_gram);
    }

    /* Bad joint bounds: negative, NaN or infinite; the message names the bone. */
    const struct { const char *name; int which; double value; } bounds_cases[] = {
        {"negative linear bound", 0, -0.5}, {"NaN linear bound", 0, NAN},     {"infinite linear bound", 0, INFINITY},
        {"negative radius", 2, -1e-300},    {"NaN radius", 2, NAN},           {"infinite radius", 2, INFINITY},
        {"NaN centre", 1, NAN},             {"infinite centre", 1, -INFINITY},
    };
    for (size_t n = 0; n < sizeof bounds_cases / sizeof bounds_cases[0]; ++n) {
        joint_bounds bad = random_joint_bounds(B);
        double *target = bounds_cases[n].which == 0   ? bad.linear + 2
                         : bounds_cases[n].which == 1 ? bad.centre + 3 * 2 + 1
                                                      : bad.radius + 2;
        *target = bounds_cases[n].value; /* bone 2 */
        EXPECT_FAILURE(bounds_cases[n].name, SK_ERROR_ARGUMENT,
                       MAX(out, offsets, bones, vectors, x.parents, bad.linear, bad.centre, bad.radius));
        sk_error record = empty_error();
        sk_max_distances(out, &(sk_influences){offsets, bones, V, K}, vectors, x.parents, bad.linear, bad.centre,
                         bad.radius, B, 1, &record);
        CHECK_IN(record.message, message_has(record.message, "bone 2", NULL));
        free_joint_bounds(&bad);
    }
    /* Zero bounds are allowed (a joint that cannot move or scale at all). */
    joint_bounds zero = random_joint_bounds(B);
    zero.linear[1] = 0.0, zero.radius[3] = 0.0;
    EXPECT_SUCCESS("zero bounds", MAX(out, offsets, bones, vectors, x.parents, zero.linear, zero.centre, zero.radius));
    free_joint_bounds(&zero);
#undef MEAN
#undef MAX

    /* Malformed vector patterns: bone indices out of range, offsets decreasing or beyond the count. */
    static const int32_t two[] = {0, 2, 3}, three[] = {0, 1, 3, 3};
    static const int32_t bone_at_count[] = {1, 4, 2}, negative_bone[] = {1, -1, 2}, huge_bone[] = {INT32_MAX, 1, 2};
    static const int32_t good3[] = {1, 3, 2}, decreasing[] = {0, 2, 1, 3}, last_beyond[] = {0, 2, 4};
    static const int32_t last_short[] = {0, 1, 2}, first_not_zero[] = {1, 2, 3}, middle_beyond[] = {0, 9, 3};
    const pattern_case patterns[] = {
        {"vector bone == bone_count", two, bone_at_count, 2, 3},
        {"negative vector bone", two, negative_bone, 2, 3},
        {"vector bone INT32_MAX", two, huge_bone, 2, 3},
        {"decreasing offsets", decreasing, good3, 3, 3},
        {"offsets[last] > influence_count", last_beyond, good3, 2, 3},
        {"offsets[last] < influence_count", last_short, good3, 2, 3},
        {"offsets[0] != 0", first_not_zero, good3, 2, 3},
        {"offset beyond influence_count mid-array", middle_beyond, good3, 2, 3},
    };
    for (size_t n = 0; n < sizeof patterns / sizeof patterns[0]; ++n)
        expect_distances_reject(&x, &patterns[n], SK_ERROR_INDEX);
    const pattern_case fine = {"valid three-vector pattern", three, good3, 3, 3};
    int32_t *fine_offsets = exact_copy_int32(fine.offsets, 4), *fine_bones = exact_copy_int32(fine.bones, 3);
    double fine_out[3];
    EXPECT_SUCCESS(fine.name,
                   sk_max_distances(fine_out, &(sk_influences){fine_offsets, fine_bones, 3, 3}, vectors, x.parents,
                                    x.b.linear, x.b.centre, x.b.radius, B, 1, error));

    /* None of the failing mean-distance calls above formed (or flagged) a block. */
    size_t flagged = 0;
    for (size_t pair = 0; pair < B * B; ++pair)
        flagged += x.cached[pair] != 0;
    CHECK_IN("failed calls leave the cache alone", flagged == 0);

    free(fine_offsets), free(fine_bones), free(offsets), free(bones), free(vectors);
    free(x.parents), free(x.cyclic), free(x.el), free(x.eg), free(x.cache), free(x.cached);
    free_joint_bounds(&x.b);
}

/* ---------------------------------------------------------------------------------------------
 * All blocks at once, and the 2-norms of linear parts
 * ------------------------------------------------------------------------------------------- */

static void test_all_blocks_and_linear_norms(void)
{
    const size_t B = 5, S = 4;
    double *local_data = allocate(16 * S * B, sizeof(double));
    for (size_t k = 0; k < S * B; ++k)
        random_frame(local_data + 16 * k, 0.5, 2.0, 3.0);
    double *local = exact_copy_double(local_data, 16 * S * B);
    int32_t *parents = exact_copy_int32(branching5, B);
    double *mean_local = allocate(16 * B, sizeof(double)), *mean_gram = allocate(16 * B, sizeof(double));
    EXPECT_SUCCESS("statistics", sk_joint_statistics(mean_local, mean_gram, local, parents, S, B, error));
    double *blocks = allocate(16 * B * B, sizeof(double));
    EXPECT_SUCCESS("all blocks", sk_expectation_blocks(blocks, mean_local, mean_gram, parents, B, error));
    for (size_t j = 0; j < B; ++j)
        for (size_t k = 0; k < B; ++k) {
            double one[16];
            EXPECT_SUCCESS("one block", sk_expectation_block(one, mean_local, mean_gram, parents, B, j, k, error));
            CHECK_IN("the bulk block equals the single one", close_to(blocks + 16 * (j * B + k), one, 16, 1e-13));
        }
    EXPECT_FAILURE("null blocks", SK_ERROR_ARGUMENT, sk_expectation_blocks(NULL, mean_local, mean_gram, parents, B, error));
    mean_gram[20] = NAN;
    EXPECT_FAILURE("NaN statistics", SK_ERROR_NOT_FINITE,
                   sk_expectation_blocks(blocks, mean_local, mean_gram, parents, B, error));

    /* 2-norms: a rotation times a scale has norm = the scale; diagonal and zero matrices; against power iteration. */
    double matrices[16 * 4], norms[4];
    random_frame(matrices, 2.5, 2.5, 1.0);
    memset(matrices + 16, 0, 16 * sizeof(double));
    matrices[16] = 2.0, matrices[21] = -3.0, matrices[26] = 1.0, matrices[31] = 1.0;
    memset(matrices + 32, 0, 16 * sizeof(double));
    random_frame(matrices + 48, 0.5, 2.0, 1.0);
    matrices[48 + 1] += 0.7; /* not a scaled rotation any more */
    double *exact = exact_copy_double(matrices, 64);
    EXPECT_SUCCESS("linear norms", sk_linear_norms(norms, exact, 4, error));
    CHECK(fabs(norms[0] - 2.5) < 1e-12 && fabs(norms[1] - 3.0) < 1e-12 && norms[2] == 0.0);
    double v[3] = {1.0, 0.3, -0.2}, largest = 0.0;
    for (int iteration = 0; iteration < 500; ++iteration) { /* power iteration on A^T A */
        double av[3], atav[3];
        for (int r = 0; r < 3; ++r)
            av[r] = matrices[48 + 4 * r] * v[0] + matrices[48 + 4 * r + 1] * v[1] + matrices[48 + 4 * r + 2] * v[2];
        for (int c = 0; c < 3; ++c)
            atav[c] = matrices[48 + c] * av[0] + matrices[48 + 4 + c] * av[1] + matrices[48 + 8 + c] * av[2];
        largest = sqrt(atav[0] * atav[0] + atav[1] * atav[1] + atav[2] * atav[2]);
        for (int c = 0; c < 3; ++c)
            v[c] = atav[c] / largest;
    }
    CHECK_IN("the general case matches power iteration", fabs(norms[3] - sqrt(largest)) < 1e-9 * sqrt(largest));
    exact[5] = NAN;
    EXPECT_FAILURE("NaN matrix", SK_ERROR_NOT_FINITE, sk_linear_norms(norms, exact, 4, error));
    EXPECT_FAILURE("null destination", SK_ERROR_ARGUMENT, sk_linear_norms(NULL, exact, 4, error));
    free(local_data), free(local), free(parents), free(mean_local), free(mean_gram), free(blocks), free(exact);
}

int main(void)
{
    test_program_name = "test_metrics";
    test_joint_statistics_are_plain_averages();
    test_blocks_equal_brute_force();
    test_mean_distances_match_definition_and_cache();
    test_mean_distances_thread_counts();
    test_max_distance_bounds_every_pose();
    test_max_distance_weight_only_worst_case();
    test_max_distance_chain_worst_case();
    test_max_distance_of_empty_vectors();
    test_max_distance_thread_counts();
    test_joint_statistics_errors();
    test_expectation_block_errors();
    test_distance_errors();
    test_all_blocks_and_linear_norms();
    return finish_tests();
}
