/*
 * Standalone tests of the animation-space metrics (csrc/skinkit.h, "The animation-space metrics"):
 * sk_joint_statistics, sk_expectation_block (and sk_expectation_blocks, sk_linear_norms) and
 * sk_mean_distances give the expectations they define, and the first two refuse bad input
 * (sk_max_distances and the distance functions' refusals: test_metric_bounds.c).
 *
 * Meant to run under AddressSanitizer and UndefinedBehaviorSanitizer: the arrays handed to the core
 * are exactly sized heap blocks, so a function that read past its counts (or past a bad index before
 * rejecting it) would be stopped by the sanitizer, not just by a failed CHECK.
 *
 * References are computed with plain loops (here and in metrics_cases.c): forward kinematics by
 * walking each bone up to the root, plain sample averages, and brute-force averages over every
 * combination of independently sampled joints (whose empirical distribution really is a product of
 * per-joint distributions, so the common-ancestor recursion must reproduce them to rounding).
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "skinkit.h"
#include "sk_internal.h" /* only for sk_worker_count and SK_SOLVE_ITEMS_PER_WORKER: proves the work is split */
#include "metrics_cases.h"
#include "test_support.h"

/* ---------------------------------------------------------------------------------------------
 * Brute-force references over the combinations
 * ------------------------------------------------------------------------------------------- */

static int is_ancestor(const int32_t *parents, size_t ancestor, size_t bone)
{
    for (size_t node = bone; node != 0;) {
        node = (size_t)parents[node];
        if (node == ancestor)
            return 1;
    }
    return 0;
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
    random_scaled_frames(local_data, S * B, 3.0); /* L_0 too: it must be treated as I */
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
 * 4. Errors of sk_joint_statistics and sk_expectation_block
 * ------------------------------------------------------------------------------------------- */

static void test_joint_statistics_errors(void)
{
    const size_t B = 4, S = 3;
    static const int32_t good_parents[] = {-1, 2, 0, 2};
    double *local = allocate(16 * S * B, sizeof(double));
    random_scaled_frames(local, S * B, 1.0);
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

/* ---------------------------------------------------------------------------------------------
 * All blocks at once, and the 2-norms of linear parts
 * ------------------------------------------------------------------------------------------- */

static void test_all_blocks_and_linear_norms(void)
{
    const size_t B = 5, S = 4;
    double *local_data = allocate(16 * S * B, sizeof(double));
    random_scaled_frames(local_data, S * B, 3.0);
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
    test_joint_statistics_errors();
    test_expectation_block_errors();
    test_all_blocks_and_linear_norms();
    return finish_tests();
}
