/*
 * Standalone tests of influence simplification and Limit Influences (csrc/skinkit.h, level of detail):
 * sk_remove_influence and sk_limit_influences.
 *
 * Meant to run under AddressSanitizer and UndefinedBehaviorSanitizer, on exactly sized heap copies.
 * References: a brute-force KKT system of the removal solved for its minimum-norm solution by LAPACK
 * dgelsd (its null space is exactly the ties, so the minimum-norm solution is the least Euclidean
 * correction); direct evaluation of the animated vertices over the sampled poses; Blender's Limit Total
 * (drop the smallest weights, renormalise) as the baseline.
 */
#include <lapacke.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "offline/lod/sk_lod_internal.h" /* the simplifier's remover: every removal's cost from one factor */
#include "skinkit.h"
#include "test_support.h"

/* ---------------------------------------------------------------------------------------------
 * A rig with sampled poses and its statistics
 * ------------------------------------------------------------------------------------------- */

typedef struct rig {
    size_t bone_count, sample_count;
    int32_t *parents;
    double *local;      /* sample_count * bone_count 4x4 */
    double *world;      /* sample_count * bone_count 4x4: G_j per sample */
    double *expected_local, *expected_gram;
    sk_pose_statistics statistics;
} rig;

/* A rotation by angle about a random axis (Rodrigues). */
static void axis_rotation(double r[9], double angle)
{
    double axis[3], length;
    do {
        for (int a = 0; a < 3; ++a)
            axis[a] = random_uniform(-1, 1);
        length = sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
    } while (length < 0.1 || length > 1.0);
    for (int a = 0; a < 3; ++a)
        axis[a] /= length;
    const double c = cos(angle), s = sin(angle), t = 1 - c, x = axis[0], y = axis[1], z = axis[2];
    const double m[9] = {t * x * x + c,     t * x * y - s * z, t * x * z + s * y, t * x * y + s * z, t * y * y + c,
                         t * y * z - s * x, t * x * z - s * y, t * y * z + s * x, t * z * z + c};
    memcpy(r, m, sizeof m);
}

/*
 * Bones 1.. get a random parent below them; every sample rotates each joint by up to max_angle about a
 * random axis from a rest rotation, and translates it by its fixed rest translation (fixed: the P of
 * appendix B.3, with a null space) or by that plus noise of size 0.3. redundant >= 1: that bone's joint is
 * the identity in every sample, so it moves exactly with its parent.
 */
static rig make_rig(size_t bone_count, size_t sample_count, int fixed, double max_angle, int32_t redundant)
{
    rig rg = {bone_count, sample_count, NULL, NULL, NULL, NULL, NULL, {0}};
    int32_t *parents = allocate(bone_count, sizeof *parents);
    parents[0] = -1;
    for (size_t b = 1; b < bone_count; ++b)
        parents[b] = (int32_t)random_below(b);
    double *rest_rotation = allocate(9 * bone_count, sizeof(double)), *rest_translation = allocate(3 * bone_count, sizeof(double));
    for (size_t b = 0; b < bone_count; ++b) {
        random_rotation(rest_rotation + 9 * b);
        for (int a = 0; a < 3; ++a)
            rest_translation[3 * b + a] = random_uniform(-1, 1);
    }
    double *local = allocate(16 * sample_count * bone_count, sizeof(double));
    double *world = allocate(16 * sample_count * bone_count, sizeof(double));
    for (size_t s = 0; s < sample_count; ++s)
        for (size_t b = 0; b < bone_count; ++b) {
            double *l = local + 16 * (s * bone_count + b), *g = world + 16 * (s * bone_count + b);
            if (b == 0 || (int32_t)b == redundant) {
                set_identity(l);
            } else {
                double turn[9], rotation[9], translation[3];
                axis_rotation(turn, random_uniform(0, max_angle));
                for (int r = 0; r < 3; ++r)
                    for (int c = 0; c < 3; ++c)
                        rotation[3 * r + c] = rest_rotation[9 * b + 3 * r] * turn[c] +
                                              rest_rotation[9 * b + 3 * r + 1] * turn[3 + c] +
                                              rest_rotation[9 * b + 3 * r + 2] * turn[6 + c];
                for (int a = 0; a < 3; ++a)
                    translation[a] = rest_translation[3 * b + a] + (fixed ? 0.0 : random_uniform(-0.3, 0.3));
                const double ones[3] = {1, 1, 1};
                make_frame(l, rotation, ones, translation);
            }
            if (b == 0)
                set_identity(g);
            else
                multiply(g, world + 16 * (s * bone_count + (size_t)parents[b]), l);
        }
    rg.parents = exact_copy_int32(parents, bone_count);
    rg.local = local;
    rg.world = world;
    rg.expected_local = allocate(16 * bone_count, sizeof(double));
    rg.expected_gram = allocate(16 * bone_count, sizeof(double));
    EXPECT_SUCCESS("statistics", sk_joint_statistics(rg.expected_local, rg.expected_gram, local, rg.parents,
                                                    sample_count, bone_count, error));
    rg.statistics = (sk_pose_statistics){rg.expected_local, rg.expected_gram, rg.parents, bone_count};
    free(parents), free(rest_rotation), free(rest_translation);
    return rg;
}

static void free_rig(rig *rg)
{
    free(rg->parents), free(rg->local), free(rg->world), free(rg->expected_local), free(rg->expected_gram);
}

/* P over the given bones, from sk_expectation_block. */
static void form_p(double *p, const rig *rg, const int32_t *bones, size_t n)
{
    const size_t d = 4 * n;
    for (size_t a = 0; a < n; ++a)
        for (size_t b = 0; b < n; ++b) {
            double block[16];
            CHECK(sk_expectation_block(block, rg->expected_local, rg->expected_gram, rg->parents, rg->bone_count,
                                       (size_t)bones[a], (size_t)bones[b], NULL) == SK_OK);
            for (int r = 0; r < 4; ++r)
                for (int c = 0; c < 4; ++c)
                    p[(4 * a + (size_t)r) * d + 4 * b + (size_t)c] = block[4 * r + c];
        }
}

static double quadratic(const double *p, const double *s, size_t d)
{
    double sum = 0.0;
    for (size_t r = 0; r < d; ++r)
        for (size_t c = 0; c < d; ++c)
            sum += s[r] * p[r * d + c] * s[c];
    return sum;
}

/* How many eigenvalues of the d x d PSD matrix p are below 1e-10 of the largest (its null space's dimension). */
static size_t null_dimension(const double *p, size_t d)
{
    double *copy = exact_copy_double(p, d * d), *eigenvalues = allocate(d, sizeof(double));
    CHECK(LAPACKE_dsyev(LAPACK_ROW_MAJOR, 'N', 'U', (lapack_int)d, copy, (lapack_int)d, eigenvalues) == 0);
    size_t count = 0;
    for (size_t k = 0; k < d; ++k)
        count += eigenvalues[k] < 1e-10 * eigenvalues[d - 1];
    free(copy), free(eigenvalues);
    return count;
}

/*
 * Brute force: the KKT system [2P A^T; A 0] (s, nu) = (0, b) of min s^T P s subject to s_c = -p_c and
 * sum of s's weights = 0, by dgelsd's minimum-norm solution. Its null space is {(t, 0): P t = 0, A t = 0},
 * the ties, so the minimum-norm solution has the least ||s||.
 */
static void brute_force_removal(double *corrected, double *cost, const rig *rg, const int32_t *bones,
                                const double *coordinates, size_t n, size_t c)
{
    const size_t d = 4 * n, size = d + 5;
    double *p = allocate(d * d, sizeof(double)), *k = allocate(size * size, sizeof(double));
    double *rhs = allocate(size, sizeof(double)), *sv = allocate(size, sizeof(double));
    form_p(p, rg, bones, n);
    for (size_t r = 0; r < d; ++r)
        for (size_t col = 0; col < d; ++col)
            k[r * size + col] = 2.0 * p[r * d + col];
    for (size_t a = 0; a < 4; ++a) { /* s_c = -p_c */
        k[(d + a) * size + 4 * c + a] = k[(4 * c + a) * size + d + a] = 1.0;
        rhs[d + a] = -coordinates[4 * c + a];
    }
    for (size_t b = 0; b < n; ++b) /* weights of s sum to 0 */
        k[(d + 4) * size + 4 * b + 3] = k[(4 * b + 3) * size + d + 4] = 1.0;
    lapack_int rank = 0;
    CHECK(LAPACKE_dgelsd(LAPACK_ROW_MAJOR, (lapack_int)size, (lapack_int)size, 1, k, (lapack_int)size, rhs, 1, sv,
                         1e-10, &rank) == 0);
    for (size_t b = 0, t = 0; b < n; ++b) {
        if (b == c)
            continue;
        for (int a = 0; a < 4; ++a)
            corrected[4 * t + (size_t)a] = coordinates[4 * b + (size_t)a] + rhs[4 * b + (size_t)a];
        ++t;
    }
    *cost = sqrt(fmax(quadratic(p, rhs, d), 0.0));
    free(p), free(k), free(rhs), free(sv);
}

static void random_coordinates(double *coordinates, size_t n, double weight_total)
{
    double sum = 0.0;
    for (size_t k = 0; k < n; ++k) {
        for (int a = 0; a < 4; ++a)
            coordinates[4 * k + (size_t)a] = random_uniform(-1, 1);
        sum += coordinates[4 * k + 3];
    }
    for (size_t k = 0; k < n; ++k) /* shift the weights to the total */
        coordinates[4 * k + 3] += (weight_total - sum) / (double)n;
}

/* Animated positions of one vertex over every sample: out (sample_count * 3). */
static void animate(double *out, const rig *rg, const int32_t *bones, const double *coordinates, size_t n)
{
    for (size_t s = 0; s < rg->sample_count; ++s) {
        double *v = out + 3 * s;
        v[0] = v[1] = v[2] = 0.0;
        for (size_t k = 0; k < n; ++k) {
            double moved[3];
            transform(moved, rg->world + 16 * (s * rg->bone_count + (size_t)bones[k]), coordinates + 4 * k,
                      coordinates[4 * k + 3]);
            for (int a = 0; a < 3; ++a)
                v[a] += moved[a];
        }
    }
}

/* ---------------------------------------------------------------------------------------------
 * 1. One removal equals the brute-force KKT solve
 * ------------------------------------------------------------------------------------------- */

/* sk_remove_influence into an exact-size buffer of the input's layout, checked to zero the removed slot, then
 * compacted to the kept bones' coordinates in their given order (what the tests compare). */
static sk_status remove_compact(double *compact, double *cost, const int32_t *bones, const double *coordinates,
                                size_t n, size_t removed, const sk_pose_statistics *statistics, sk_error *error)
{
    double *full = allocate(4 * n, sizeof(double));
    const sk_status status = sk_remove_influence(full, cost, bones, coordinates, n, removed, statistics, error);
    if (status == SK_OK) {
        const double zero[4] = {0.0, 0.0, 0.0, 0.0};
        CHECK(memcmp(full + 4 * removed, zero, sizeof zero) == 0);
        for (size_t k = 0, t = 0; k < n; ++k)
            if (k != removed)
                memcpy(compact + 4 * t++, full + 4 * k, 4 * sizeof(double));
    }
    free(full);
    return status;
}

static void test_removal_matches_brute_force(void)
{
    for (int fixed = 0; fixed < 2; ++fixed) {
        rig rg = make_rig(7, 30, fixed, 1.2, -1);
        double worst = 0.0, worst_cost = 0.0;
        int trials = 0, singular = 0; /* removals whose P_I has a null space: the tie-break matters */
        for (int trial = 0; trial < 40; ++trial) {
            const size_t n = 2 + random_below(5), c = random_below(n);
            int32_t chosen[8];
            double coordinates_data[32];
            pick_distinct_bones(chosen, n, rg.bone_count);
            random_coordinates(coordinates_data, n, trial % 3 == 0 ? 0.0 : 1.0); /* tangents too */
            int32_t *bones = exact_copy_int32(chosen, n);
            double *coordinates = exact_copy_double(coordinates_data, 4 * n);
            double *corrected = allocate(4 * (n - 1), sizeof(double)), brute[32], cost = -1, brute_cost = -1;
            EXPECT_SUCCESS("removal", remove_compact(corrected, &cost, bones, coordinates, n, c, &rg.statistics,
                                                          error));
            brute_force_removal(brute, &brute_cost, &rg, bones, coordinates, n, c);
            const double scale = coordinate_scale(brute, 4 * (n - 1));
            worst = fmax(worst, max_abs_difference(corrected, brute, 4 * (n - 1)) / scale);
            worst_cost = fmax(worst_cost, fabs(cost - brute_cost) / fmax(1.0, brute_cost));
            /* The total weight is kept. */
            double before = 0.0, after = 0.0;
            for (size_t k = 0; k < n; ++k)
                before += coordinates[4 * k + 3];
            for (size_t k = 0; k + 1 < n; ++k)
                after += corrected[4 * k + 3];
            CHECK(fabs(before - after) <= 1e-12);
            /* The cost is the L2,2 norm of the correction. */
            double s[32], p[32 * 32];
            for (size_t k = 0, t = 0; k < n; ++k) {
                for (int a = 0; a < 4; ++a)
                    s[4 * k + (size_t)a] =
                        (k == c ? 0.0 : corrected[4 * t + (size_t)a]) - coordinates[4 * k + (size_t)a];
                t += k != c;
            }
            form_p(p, &rg, bones, n);
            CHECK(fabs(sqrt(fmax(quadratic(p, s, 4 * n), 0.0)) - cost) <= 1e-9 * fmax(1.0, cost));
            singular += null_dimension(p, 4 * n) > 0;
            ++trials;
            free(bones), free(coordinates), free(corrected);
        }
        char context[128];
        snprintf(context, sizeof context, "%s translations: worst %.2e, cost %.2e over %d removals (%d singular P_I)",
                 fixed ? "fixed" : "varying", worst, worst_cost, trials, singular);
        CHECK_IN(context, fixed ? singular >= 10 : singular == 0);
        CHECK_IN(context, worst <= 1e-9);
        CHECK_IN(context, worst_cost <= 1e-9);
        printf("brute force, %s\n", context);
        free_rig(&rg);
    }
}

/* ---------------------------------------------------------------------------------------------
 * 2. A redundant influence goes at zero cost and nothing moves
 * ------------------------------------------------------------------------------------------- */

static void test_redundant_influence(void)
{
    for (int fixed = 0; fixed < 2; ++fixed) {
        rig rg = make_rig(6, 25, fixed, 1.0, 4); /* bone 4 moves exactly with its parent */
        const int32_t parent = rg.parents[4];
        int32_t others[2], count = 0;
        for (int32_t b = 1; b < 6 && count < 2; ++b)
            if (b != 4 && b != parent)
                others[count++] = b;
        const int32_t chosen[4] = {others[0], 4, parent, others[1]};
        double coordinates_data[16];
        random_coordinates(coordinates_data, 4, 1.0);
        int32_t *bones = exact_copy_int32(chosen, 4);
        double *coordinates = exact_copy_double(coordinates_data, 16);
        double corrected[12], cost = -1;
        EXPECT_SUCCESS("redundant", remove_compact(corrected, &cost, bones, coordinates, 4, 1, &rg.statistics,
                                                        error));
        char context[64];
        snprintf(context, sizeof context, "%s translations: cost %.2e", fixed ? "fixed" : "varying", cost);
        CHECK_IN(context, cost >= 0.0 && cost < 1e-12);
        const int32_t kept[3] = {others[0], parent, others[1]};
        double before[75], after[75];
        animate(before, &rg, bones, coordinates, 4);
        animate(after, &rg, kept, corrected, 3);
        CHECK_IN(context, close_to(after, before, 3 * rg.sample_count, 1e-12));
        printf("redundant influence, %s, largest move over the poses %.2e\n", context,
               max_abs_difference(after, before, 3 * rg.sample_count));
        /* Limit Influences to 3 removes bone 4 or its parent (the two are interchangeable: both cost 0). */
        const int32_t offsets_data[2] = {0, 4};
        int32_t *offsets = exact_copy_int32(offsets_data, 2);
        const sk_influences influences = {offsets, bones, 1, 4};
        int32_t out_offsets[2], out_bones[4];
        double out_coordinates[16], costs[1];
        size_t out_count = 0;
        EXPECT_SUCCESS("limit redundant",
                       sk_limit_influences(out_offsets, out_bones, out_coordinates, &out_count, costs, NULL,
                                           &influences, coordinates, NULL, 0, &rg.statistics, 3, 1, NULL, NULL, error));
        CHECK(out_count == 3 && out_offsets[1] == 3);
        CHECK(out_bones[0] == others[0] && (out_bones[1] == 4 || out_bones[1] == parent) && out_bones[2] == others[1]);
        CHECK_IN(context, costs[0] < 1e-12);
        animate(after, &rg, out_bones, out_coordinates, 3);
        CHECK_IN(context, close_to(after, before, 3 * rg.sample_count, 1e-12));
        free(bones), free(coordinates), free(offsets);
        free_rig(&rg);
    }
}

/* ---------------------------------------------------------------------------------------------
 * 3. Limit Influences against Limit Total on a smooth model
 * ------------------------------------------------------------------------------------------- */

typedef struct smooth_model {
    size_t vertex_count, influence_count;
    int32_t *offsets, *bones;
    double *weights, *rest_positions, *coordinates, *rest_frames;
} smooth_model;

/* Weights exp(-|v - joint|^2 / 2 sigma^2) over the `per_vertex` nearest joints (the rest pose: sample 0). */
static smooth_model make_smooth_model(const rig *rg, size_t vertex_count, size_t per_vertex)
{
    smooth_model m = {vertex_count, vertex_count * per_vertex, NULL, NULL, NULL, NULL, NULL, NULL};
    const size_t b = rg->bone_count;
    m.rest_frames = exact_copy_double(rg->world, 16 * b);
    int32_t *offsets = allocate(vertex_count + 1, sizeof(int32_t)), *bones = allocate(m.influence_count, sizeof(int32_t));
    double *weights = allocate(m.influence_count, sizeof(double)), *rest = allocate(3 * vertex_count, sizeof(double));
    for (size_t v = 0; v < vertex_count; ++v) {
        offsets[v + 1] = (int32_t)((v + 1) * per_vertex);
        const size_t anchor = 1 + random_below(b - 1); /* near a random joint */
        for (int a = 0; a < 3; ++a)
            rest[3 * v + (size_t)a] = m.rest_frames[16 * anchor + 4 * (size_t)a + 3] + random_uniform(-0.6, 0.6);
        double distance[64];
        int used[64] = {0};
        for (size_t j = 0; j < b; ++j) {
            double sum = 0.0;
            for (int a = 0; a < 3; ++a) {
                const double delta = rest[3 * v + (size_t)a] - m.rest_frames[16 * j + 4 * (size_t)a + 3];
                sum += delta * delta;
            }
            distance[j] = sum;
        }
        for (size_t k = 0; k < per_vertex; ++k) {
            size_t best = b;
            for (size_t j = 0; j < b; ++j)
                if (!used[j] && (best == b || distance[j] < distance[best]))
                    best = j;
            used[best] = 1;
            bones[v * per_vertex + k] = (int32_t)best;
            weights[v * per_vertex + k] = exp(-distance[best] / (2 * 0.5 * 0.5)) + 1e-3;
        }
        normalise(weights + v * per_vertex, per_vertex);
    }
    m.offsets = exact_copy_int32(offsets, vertex_count + 1);
    m.bones = exact_copy_int32(bones, m.influence_count);
    m.weights = exact_copy_double(weights, m.influence_count);
    m.rest_positions = exact_copy_double(rest, 3 * vertex_count);
    m.coordinates = allocate(4 * m.influence_count, sizeof(double));
    const sk_influences pattern = {m.offsets, m.bones, vertex_count, m.influence_count};
    EXPECT_SUCCESS("convert", sk_lbs_to_animation_space(m.coordinates, &pattern, m.rest_positions, 1.0, m.weights,
                                                        m.rest_frames, b, error));
    free(offsets), free(bones), free(weights), free(rest);
    return m;
}

static void free_smooth_model(smooth_model *m)
{
    free(m->offsets), free(m->bones), free(m->weights), free(m->rest_positions), free(m->coordinates);
    free(m->rest_frames);
}

/* Sum over samples and vertices of the squared distance between two models' animated vertices. */
static double pose_error(const rig *rg, const int32_t *offsets_a, const int32_t *bones_a, const double *a, size_t count_a,
                         const int32_t *offsets_b, const int32_t *bones_b, const double *b, size_t count_b,
                         size_t vertex_count, double *per_vertex)
{
    double *va = allocate(3 * vertex_count, sizeof(double)), *vb = allocate(3 * vertex_count, sizeof(double));
    double total = 0.0;
    const sk_influences pattern_a = {offsets_a, bones_a, vertex_count, count_a};
    const sk_influences pattern_b = {offsets_b, bones_b, vertex_count, count_b};
    if (per_vertex)
        memset(per_vertex, 0, vertex_count * sizeof *per_vertex);
    for (size_t s = 0; s < rg->sample_count; ++s) {
        const double *poses = rg->world + 16 * s * rg->bone_count;
        CHECK(sk_animation_space_evaluate_f64(va, &pattern_a, a, poses, rg->bone_count, 1, NULL) == SK_OK);
        CHECK(sk_animation_space_evaluate_f64(vb, &pattern_b, b, poses, rg->bone_count, 1, NULL) == SK_OK);
        for (size_t v = 0; v < vertex_count; ++v) {
            double sum = 0.0;
            for (int x = 0; x < 3; ++x)
                sum += (va[3 * v + (size_t)x] - vb[3 * v + (size_t)x]) * (va[3 * v + (size_t)x] - vb[3 * v + (size_t)x]);
            total += sum;
            if (per_vertex)
                per_vertex[v] += sum / (double)rg->sample_count;
        }
    }
    free(va), free(vb);
    return total;
}

static void test_limit_beats_limit_total(void)
{
    rig rg = make_rig(14, 60, 0, 0.8, -1);
    const size_t vertices = 400, per_vertex = 6, max_influences = 3;
    smooth_model m = make_smooth_model(&rg, vertices, per_vertex);
    const sk_influences influences = {m.offsets, m.bones, vertices, m.influence_count};
    int32_t *out_offsets = allocate(vertices + 1, sizeof(int32_t)), *out_bones = allocate(m.influence_count, sizeof(int32_t));
    double *out = allocate(4 * m.influence_count, sizeof(double)), *costs = allocate(vertices, sizeof(double));
    size_t out_count = 0;
    EXPECT_SUCCESS("limit", sk_limit_influences(out_offsets, out_bones, out, &out_count, costs, NULL, &influences,
                                                m.coordinates, NULL, 0, &rg.statistics, max_influences, 0, NULL, NULL,
                                                error));
    CHECK(out_count == vertices * max_influences);
    double worst_sum = 0.0;
    for (size_t v = 0; v < vertices; ++v) {
        CHECK(out_offsets[v + 1] - out_offsets[v] == (int32_t)max_influences);
        double sum = 0.0;
        for (int32_t k = out_offsets[v]; k < out_offsets[v + 1]; ++k)
            sum += out[4 * k + 3];
        worst_sum = fmax(worst_sum, fabs(sum - 1.0));
        /* The kept bones are a subset of the vertex's, in their given order. */
        int32_t from = m.offsets[v];
        for (int32_t k = out_offsets[v]; k < out_offsets[v + 1]; ++k) {
            while (from < m.offsets[v + 1] && m.bones[from] != out_bones[k])
                ++from;
            CHECK(from < m.offsets[v + 1]);
        }
    }
    CHECK_IN("weights sum to 1", worst_sum <= 1e-12);

    /* Limit Total: keep the largest weights, renormalise, convert. */
    int32_t *total_offsets = allocate(vertices + 1, sizeof(int32_t)), *total_bones = allocate(vertices * max_influences, sizeof(int32_t));
    double *total_weights = allocate(vertices * max_influences, sizeof(double));
    for (size_t v = 0; v < vertices; ++v) {
        total_offsets[v + 1] = (int32_t)((v + 1) * max_influences);
        int used[8] = {0};
        for (size_t k = 0; k < max_influences; ++k) {
            size_t best = per_vertex;
            for (size_t j = 0; j < per_vertex; ++j)
                if (!used[j] && (best == per_vertex || m.weights[v * per_vertex + j] > m.weights[v * per_vertex + best]))
                    best = j;
            used[best] = 1;
            total_bones[v * max_influences + k] = m.bones[v * per_vertex + best];
            total_weights[v * max_influences + k] = m.weights[v * per_vertex + best];
        }
        normalise(total_weights + v * max_influences, max_influences);
    }
    double *total = allocate(4 * vertices * max_influences, sizeof(double));
    const sk_influences total_pattern = {total_offsets, total_bones, vertices, vertices * max_influences};
    EXPECT_SUCCESS("limit total", sk_lbs_to_animation_space(total, &total_pattern, m.rest_positions, 1.0,
                                                            total_weights, m.rest_frames, rg.bone_count, error));
    double *ours_per_vertex = allocate(vertices, sizeof(double)), *total_per_vertex = allocate(vertices, sizeof(double));
    const double ours_error = pose_error(&rg, m.offsets, m.bones, m.coordinates, m.influence_count, out_offsets,
                                         out_bones, out, out_count, vertices, ours_per_vertex);
    const double total_error = pose_error(&rg, m.offsets, m.bones, m.coordinates, m.influence_count, total_offsets,
                                          total_bones, total, vertices * max_influences, vertices, total_per_vertex);
    size_t better = 0;
    for (size_t v = 0; v < vertices; ++v)
        better += ours_per_vertex[v] <= total_per_vertex[v];
    char context[160];
    snprintf(context, sizeof context, "squared error over %zu poses: ours %.4e, Limit Total %.4e (%zu of %zu vertices no worse)",
             rg.sample_count, ours_error, total_error, better, vertices);
    printf("%s\n", context);
    CHECK_IN(context, ours_error < 0.5 * total_error);
    CHECK_IN(context, better >= vertices * 9 / 10);

    /* The reported costs are the L2,2 norms of the total corrections. */
    double worst_cost = 0.0;
    for (size_t v = 0; v < vertices; ++v) {
        const size_t n = per_vertex;
        double s[32], p[32 * 32];
        const int32_t *bones = m.bones + v * per_vertex;
        for (size_t k = 0; k < n; ++k) {
            const double *original = m.coordinates + 4 * (v * per_vertex + k);
            const double *kept = NULL;
            for (int32_t x = out_offsets[v]; x < out_offsets[v + 1]; ++x)
                if (out_bones[x] == bones[k])
                    kept = out + 4 * x;
            for (int a = 0; a < 4; ++a)
                s[4 * k + (size_t)a] = (kept ? kept[a] : 0.0) - original[a];
        }
        form_p(p, &rg, bones, n);
        worst_cost = fmax(worst_cost, fabs(sqrt(fmax(quadratic(p, s, 4 * n), 0.0)) - costs[v]) / fmax(1.0, costs[v]));
    }
    CHECK_IN("costs are the total corrections' norms", worst_cost <= 1e-9);

    free(out_offsets), free(out_bones), free(out), free(costs), free(total_offsets), free(total_bones);
    free(total_weights), free(total), free(ours_per_vertex), free(total_per_vertex);
    free_smooth_model(&m);
    free_rig(&rg);
}

/* ---------------------------------------------------------------------------------------------
 * 4. Consistency: one step is the cheapest removal, tangents, thread counts, copies, progress, big rigs
 * ------------------------------------------------------------------------------------------- */

static int cancel_at_once(void *user, double fraction)
{
    (void)fraction;
    ++*(int *)user;
    return 1;
}

static int count_progress(void *user, double fraction)
{
    double *last = user;
    CHECK(fraction >= *last && fraction <= 1.0);
    *last = fraction;
    return 0;
}

static void test_limit_consistency(void)
{
    rig rg = make_rig(10, 30, 1, 1.0, -1);
    /* Vertices of 1 to 7 influences. */
    const size_t vertices = 300;
    int32_t *offsets_data = allocate(vertices + 1, sizeof(int32_t)), *bones_data = allocate(7 * vertices, sizeof(int32_t));
    double *coordinates_data = allocate(28 * vertices, sizeof(double)), *tangent_data = allocate(2 * 28 * vertices, sizeof(double));
    size_t count = 0;
    for (size_t v = 0; v < vertices; ++v) {
        const size_t n = 1 + random_below(7);
        pick_distinct_bones(bones_data + count, n, rg.bone_count);
        random_coordinates(coordinates_data + 4 * count, n, 1.0);
        count += n;
        offsets_data[v + 1] = (int32_t)count;
    }
    for (size_t v = 0; v < vertices; ++v) {
        const size_t begin = (size_t)offsets_data[v], n = (size_t)offsets_data[v + 1] - begin;
        random_coordinates(tangent_data + 4 * begin, n, 0.0); /* a tangent: weights sum to 0 */
        memcpy(tangent_data + 4 * (count + begin), coordinates_data + 4 * begin, 4 * n * sizeof(double));
    }
    int32_t *offsets = exact_copy_int32(offsets_data, vertices + 1), *bones = exact_copy_int32(bones_data, count);
    double *coordinates = exact_copy_double(coordinates_data, 4 * count);
    double *tangents = exact_copy_double(tangent_data, 2 * 4 * count); /* set 1 = the positions themselves */
    const sk_influences influences = {offsets, bones, vertices, count};
    const size_t K = 3;
    int32_t *oo = allocate(vertices + 1, sizeof(int32_t)), *ob = allocate(count, sizeof(int32_t));
    double *oc = allocate(4 * count, sizeof(double)), *costs = allocate(vertices, sizeof(double));
    double *ot = allocate(2 * 4 * count, sizeof(double));
    size_t out_count = 0;
    double last = 0.0;
    EXPECT_SUCCESS("limit with tangents", sk_limit_influences(oo, ob, oc, &out_count, costs, ot, &influences, coordinates,
                                                              tangents, 2, &rg.statistics, K, 1, count_progress, &last,
                                                              error));
    CHECK(last == 1.0);
    CHECK_IN("the positions as a tangent set come out as the positions",
             memcmp(ot + 4 * count, oc, 4 * out_count * sizeof(double)) == 0);
    size_t expected_count = 0;
    for (size_t v = 0; v < vertices; ++v) {
        const size_t n = (size_t)(offsets[v + 1] - offsets[v]);
        expected_count += n < K ? n : K;
        double tangent_sum = 0.0;
        for (int32_t k = oo[v]; k < oo[v + 1]; ++k)
            tangent_sum += ot[4 * k + 3];
        CHECK(fabs(tangent_sum) <= 1e-12);
        if (n <= K) { /* copied */
            CHECK(oo[v + 1] - oo[v] == (int32_t)n && costs[v] == 0.0);
            CHECK(memcmp(ob + oo[v], bones + offsets[v], n * sizeof(int32_t)) == 0);
            CHECK(memcmp(oc + 4 * oo[v], coordinates + 4 * offsets[v], 4 * n * sizeof(double)) == 0);
            CHECK(memcmp(ot + 4 * oo[v], tangents + 4 * offsets[v], 4 * n * sizeof(double)) == 0);
        }
    }
    CHECK(out_count == expected_count && (size_t)oo[vertices] == out_count);

    /* Two threads give the same bits (the cache only saves work: a preprocessing depends on (I, i) alone). */
    int32_t *oo2 = allocate(vertices + 1, sizeof(int32_t)), *ob2 = allocate(count, sizeof(int32_t));
    double *oc2 = allocate(4 * count, sizeof(double)), *costs2 = allocate(vertices, sizeof(double));
    size_t out_count2 = 0;
    EXPECT_SUCCESS("two threads", sk_limit_influences(oo2, ob2, oc2, &out_count2, costs2, NULL, &influences, coordinates,
                                                      NULL, 0, &rg.statistics, K, 2, NULL, NULL, error));
    CHECK(out_count2 == out_count && memcmp(oo2, oo, (vertices + 1) * sizeof(int32_t)) == 0);
    CHECK(memcmp(ob2, ob, out_count * sizeof(int32_t)) == 0 && same_across_threads(oc2, oc, 4 * out_count));
    CHECK(same_across_threads(costs2, costs, vertices));

    /* Limiting to n - 1 is the cheapest single removal. */
    for (size_t v = 0; v < vertices; ++v) {
        const size_t begin = (size_t)offsets[v], n = (size_t)offsets[v + 1] - begin;
        if (n < 2)
            continue;
        int32_t *vb = exact_copy_int32(bones + begin, n);
        double *vc = exact_copy_double(coordinates + begin * 4, 4 * n);
        double best_cost = INFINITY, best[28], corrected[28];
        for (size_t c = 0; c < n; ++c) {
            double cost;
            CHECK(remove_compact(corrected, &cost, vb, vc, n, c, &rg.statistics, NULL) == SK_OK);
            if (cost < best_cost)
                best_cost = cost, memcpy(best, corrected, 4 * (n - 1) * sizeof(double));
        }
        const int32_t one_offsets_data[2] = {0, (int32_t)n};
        int32_t *one_offsets = exact_copy_int32(one_offsets_data, 2);
        const sk_influences one = {one_offsets, vb, 1, n};
        int32_t o_off[2], o_b[7];
        double o_c[28], o_cost;
        size_t o_count;
        CHECK(sk_limit_influences(o_off, o_b, o_c, &o_count, &o_cost, NULL, &one, vc, NULL, 0, &rg.statistics, n - 1, 1,
                                  NULL, NULL, NULL) == SK_OK);
        CHECK(o_count == n - 1 && fabs(o_cost - best_cost) <= 1e-10 * fmax(1.0, best_cost));
        CHECK(close_to(o_c, best, 4 * (n - 1), 1e-10));
        free(vb), free(vc), free(one_offsets);
    }

    /* Limiting to K is the greedy of per-candidate solves (sk_remove_influence: each step the cheapest removal, the
     * first on a tie), to the bit: the one-split costs only narrow the candidates the per-candidate solve picks from. */
    for (size_t v = 0; v < vertices; ++v) {
        const size_t begin = (size_t)offsets[v];
        size_t n = (size_t)offsets[v + 1] - begin;
        if (n <= K)
            continue;
        int32_t greedy_bones[7];
        double greedy[28], corrected[28], best[28] = {0.0};
        memcpy(greedy_bones, bones + begin, n * sizeof(int32_t));
        memcpy(greedy, coordinates + 4 * begin, 4 * n * sizeof(double));
        for (; n > K; --n) {
            int32_t *vb = exact_copy_int32(greedy_bones, n);
            double *vc = exact_copy_double(greedy, 4 * n);
            double best_cost = INFINITY;
            size_t removed = 0;
            for (size_t c = 0; c < n; ++c) {
                double cost;
                CHECK(remove_compact(corrected, &cost, vb, vc, n, c, &rg.statistics, NULL) == SK_OK);
                if (cost < best_cost)
                    best_cost = cost, removed = c, memcpy(best, corrected, 4 * (n - 1) * sizeof(double));
            }
            memmove(greedy_bones + removed, greedy_bones + removed + 1, (n - 1 - removed) * sizeof(int32_t));
            memcpy(greedy, best, sizeof best); /* the first 4 (n - 1) entries are the corrected set */
            free(vb), free(vc);
        }
        CHECK_IN("the limit's bones are the greedy's", memcmp(ob + oo[v], greedy_bones, K * sizeof(int32_t)) == 0);
        CHECK_IN("the limit's coordinates are the greedy's, to the bit",
                 memcmp(oc + 4 * oo[v], greedy, 4 * K * sizeof(double)) == 0);
    }

    /* Cancelling. */
    int calls = 0;
    EXPECT_FAILURE("cancelled", SK_ERROR_CANCELLED,
                   sk_limit_influences(oo2, ob2, oc2, &out_count2, NULL, NULL, &influences, coordinates, NULL, 0,
                                       &rg.statistics, K, 1, cancel_at_once, &calls, error));
    CHECK(calls == 2);

    /* A rig above the block table's size (blocks formed per vertex) gives the same bits as the small one
     * it extends with unused leaves. */
    const size_t big = 300;
    int32_t *big_parents_data = allocate(big, sizeof(int32_t));
    double *big_local = allocate(16 * big, sizeof(double)), *big_gram = allocate(16 * big, sizeof(double));
    memcpy(big_parents_data, rg.parents, rg.bone_count * sizeof(int32_t));
    memcpy(big_local, rg.expected_local, 16 * rg.bone_count * sizeof(double));
    memcpy(big_gram, rg.expected_gram, 16 * rg.bone_count * sizeof(double));
    for (size_t b = rg.bone_count; b < big; ++b) {
        big_parents_data[b] = (int32_t)(b % rg.bone_count);
        set_identity(big_local + 16 * b);
        set_identity(big_gram + 16 * b);
    }
    int32_t *big_parents = exact_copy_int32(big_parents_data, big);
    double *bl = exact_copy_double(big_local, 16 * big), *bg = exact_copy_double(big_gram, 16 * big);
    const sk_pose_statistics big_statistics = {bl, bg, big_parents, big};
    EXPECT_SUCCESS("300 bones", sk_limit_influences(oo2, ob2, oc2, &out_count2, costs2, NULL, &influences, coordinates,
                                                    NULL, 0, &big_statistics, K, 1, NULL, NULL, error));
    CHECK(out_count2 == out_count && memcmp(ob2, ob, out_count * sizeof(int32_t)) == 0);
    CHECK(memcmp(oc2, oc, 4 * out_count * sizeof(double)) == 0 && memcmp(costs2, costs, vertices * sizeof(double)) == 0);

    free(offsets_data), free(bones_data), free(coordinates_data), free(tangent_data), free(offsets), free(bones);
    free(coordinates), free(tangents), free(oo), free(ob), free(oc), free(costs), free(ot), free(oo2), free(ob2);
    free(oc2), free(costs2), free(big_parents_data), free(big_local), free(big_gram), free(big_parents), free(bl), free(bg);
    free_rig(&rg);
}

/* ---------------------------------------------------------------------------------------------
 * 5. Bad inputs
 * ------------------------------------------------------------------------------------------- */

static void test_bad_inputs(void)
{
    rig rg = make_rig(5, 10, 1, 1.0, -1);
    const int32_t offsets_data[3] = {0, 3, 5}, bones_data[5] = {1, 2, 3, 0, 4};
    double coordinates_data[20];
    random_coordinates(coordinates_data, 3, 1.0);
    random_coordinates(coordinates_data + 12, 2, 1.0);
    int32_t *offsets = exact_copy_int32(offsets_data, 3), *bones = exact_copy_int32(bones_data, 5);
    double *coordinates = exact_copy_double(coordinates_data, 20);
    const sk_influences in = {offsets, bones, 2, 5};
    int32_t oo[3], ob[5];
    double oc[20], costs[2], ot[20];
    size_t n = 0;
    const sk_pose_statistics *st = &rg.statistics;
    EXPECT_SUCCESS("valid", sk_limit_influences(oo, ob, oc, &n, costs, NULL, &in, coordinates, NULL, 0, st, 2, 1, NULL,
                                                NULL, error));
    CHECK(n == 4);

    EXPECT_FAILURE("K = 0", SK_ERROR_ARGUMENT,
                   sk_limit_influences(oo, ob, oc, &n, costs, NULL, &in, coordinates, NULL, 0, st, 0, 1, NULL, NULL, error));
    EXPECT_FAILURE("null influences", SK_ERROR_ARGUMENT,
                   sk_limit_influences(oo, ob, oc, &n, costs, NULL, NULL, coordinates, NULL, 0, st, 2, 1, NULL, NULL, error));
    EXPECT_FAILURE("null outputs", SK_ERROR_ARGUMENT,
                   sk_limit_influences(oo, NULL, oc, &n, costs, NULL, &in, coordinates, NULL, 0, st, 2, 1, NULL, NULL, error));
    EXPECT_FAILURE("null statistics", SK_ERROR_ARGUMENT,
                   sk_limit_influences(oo, ob, oc, &n, costs, NULL, &in, coordinates, NULL, 0, NULL, 2, 1, NULL, NULL, error));
    EXPECT_FAILURE("tangents missing", SK_ERROR_ARGUMENT,
                   sk_limit_influences(oo, ob, oc, &n, costs, ot, &in, coordinates, NULL, 1, st, 2, 1, NULL, NULL, error));
    {
        const int32_t bad_data[5] = {1, 2, 5, 0, 4};
        int32_t *bad = exact_copy_int32(bad_data, 5);
        const sk_influences bad_in = {offsets, bad, 2, 5};
        EXPECT_FAILURE("bone out of range", SK_ERROR_INDEX,
                       sk_limit_influences(oo, ob, oc, &n, costs, NULL, &bad_in, coordinates, NULL, 0, st, 2, 1, NULL,
                                           NULL, error));
        bad[2] = -1;
        EXPECT_FAILURE("negative bone", SK_ERROR_INDEX,
                       sk_limit_influences(oo, ob, oc, &n, costs, NULL, &bad_in, coordinates, NULL, 0, st, 2, 1, NULL,
                                           NULL, error));
        bad[2] = 1; /* vertex 0 lists bone 1 twice */
        EXPECT_FAILURE("repeated bone", SK_ERROR_ARGUMENT,
                       sk_limit_influences(oo, ob, oc, &n, costs, NULL, &bad_in, coordinates, NULL, 0, st, 2, 1, NULL,
                                           NULL, error));
        free(bad);
    }
    {
        const int32_t bad_offsets_data[3] = {0, 6, 5};
        int32_t *bad_offsets = exact_copy_int32(bad_offsets_data, 3);
        const sk_influences bad_in = {bad_offsets, bones, 2, 5};
        EXPECT_FAILURE("offset beyond the count", SK_ERROR_INDEX,
                       sk_limit_influences(oo, ob, oc, &n, costs, NULL, &bad_in, coordinates, NULL, 0, st, 2, 1, NULL,
                                           NULL, error));
        free(bad_offsets);
    }
    {
        double *bad = exact_copy_double(coordinates_data, 20);
        bad[13] = NAN;
        EXPECT_FAILURE("NaN coordinate", SK_ERROR_NOT_FINITE,
                       sk_limit_influences(oo, ob, oc, &n, costs, NULL, &in, bad, NULL, 0, st, 2, 1, NULL, NULL, error));
        sk_error record;
        sk_limit_influences(oo, ob, oc, &n, costs, NULL, &in, bad, NULL, 0, st, 2, 1, NULL, NULL, &record);
        CHECK_IN(record.message, strstr(record.message, "vertex 1") && strstr(record.message, "bone 0"));
        double *tangents = exact_copy_double(coordinates_data, 20);
        tangents[2] = INFINITY;
        EXPECT_FAILURE("infinite tangent", SK_ERROR_NOT_FINITE,
                       sk_limit_influences(oo, ob, oc, &n, costs, ot, &in, coordinates, tangents, 1, st, 2, 1, NULL,
                                           NULL, error));
        free(bad), free(tangents);
    }
    {
        int32_t bad_parents_data[5];
        memcpy(bad_parents_data, rg.parents, sizeof bad_parents_data);
        bad_parents_data[1] = 3, bad_parents_data[3] = 1; /* a cycle */
        int32_t *bad_parents = exact_copy_int32(bad_parents_data, 5);
        const sk_pose_statistics bad = {rg.expected_local, rg.expected_gram, bad_parents, 5};
        EXPECT_FAILURE("cyclic parents", SK_ERROR_CYCLE,
                       sk_limit_influences(oo, ob, oc, &n, costs, NULL, &in, coordinates, NULL, 0, &bad, 2, 1, NULL,
                                           NULL, error));
        bad_parents[1] = 7;
        EXPECT_FAILURE("parent out of range", SK_ERROR_INDEX,
                       sk_limit_influences(oo, ob, oc, &n, costs, NULL, &in, coordinates, NULL, 0, &bad, 2, 1, NULL,
                                           NULL, error));
        double *gram = exact_copy_double(rg.expected_gram, 80);
        gram[40] = NAN;
        const sk_pose_statistics bad_gram = {rg.expected_local, gram, rg.parents, 5};
        EXPECT_FAILURE("NaN statistics", SK_ERROR_NOT_FINITE,
                       sk_limit_influences(oo, ob, oc, &n, costs, NULL, &in, coordinates, NULL, 0, &bad_gram, 2, 1,
                                           NULL, NULL, error));
        free(bad_parents), free(gram);
    }
    {
        /* Huge counts are refused before anything is read at them. */
        const sk_influences huge = {offsets, bones, SIZE_MAX, 5};
        EXPECT_FAILURE("vertex_count SIZE_MAX", SK_ERROR_ARGUMENT,
                       sk_limit_influences(oo, ob, oc, &n, costs, NULL, &huge, coordinates, NULL, 0, st, 2, 1, NULL,
                                           NULL, error));
        const sk_influences huge_influences = {offsets, bones, 2, (size_t)1 << 40};
        EXPECT_FAILURE("influence_count 2^40", SK_ERROR_ARGUMENT,
                       sk_limit_influences(oo, ob, oc, &n, costs, NULL, &huge_influences, coordinates, NULL, 0, st, 2,
                                           1, NULL, NULL, error));
        EXPECT_FAILURE("tangent sets overflow", SK_ERROR_ARGUMENT,
                       sk_limit_influences(oo, ob, oc, &n, costs, ot, &in, coordinates, coordinates, SIZE_MAX / 8, st,
                                           2, 1, NULL, NULL, error));
        /* Found by the binding fuzzer: with no influences every tangent size is 0, so only a bound on the count
         * keeps 2^32 + 1 empty tangent sets from being scanned per vertex. */
        const sk_influences none = {in.offsets, in.bones, in.vertex_count, 0};
        EXPECT_FAILURE("2^32 + 1 empty tangent sets", SK_ERROR_ARGUMENT,
                       sk_limit_influences(oo, ob, oc, &n, costs, ot, &none, coordinates, coordinates,
                                           (size_t)1 << 32 | 1, st, 2, 1, NULL, NULL, error));
        const sk_pose_statistics huge_bones = {rg.expected_local, rg.expected_gram, rg.parents, SIZE_MAX};
        EXPECT_FAILURE("bone_count SIZE_MAX", SK_ERROR_ARGUMENT,
                       sk_limit_influences(oo, ob, oc, &n, costs, NULL, &in, coordinates, NULL, 0, &huge_bones, 2, 1,
                                           NULL, NULL, error));
    }
    {
        /* Too many influences on a vertex that must be reduced. */
        const size_t many = SK_LOD_MAX_VERTEX_INFLUENCES + 1;
        rig wide = make_rig(many + 1, 4, 1, 1.0, -1);
        int32_t many_offsets_data[2] = {0, (int32_t)many}, many_bones_data[SK_LOD_MAX_VERTEX_INFLUENCES + 1];
        double *many_coordinates_data = allocate(4 * many, sizeof(double));
        for (size_t k = 0; k < many; ++k)
            many_bones_data[k] = (int32_t)(k + 1);
        random_coordinates(many_coordinates_data, many, 1.0);
        int32_t *mo = exact_copy_int32(many_offsets_data, 2), *mb = exact_copy_int32(many_bones_data, many);
        double *mc = exact_copy_double(many_coordinates_data, 4 * many);
        int32_t *moo = allocate(2, sizeof(int32_t)), *mob = allocate(many, sizeof(int32_t));
        double *moc = allocate(4 * many, sizeof(double));
        const sk_influences many_in = {mo, mb, 1, many};
        EXPECT_FAILURE("65 influences", SK_ERROR_ARGUMENT,
                       sk_limit_influences(moo, mob, moc, &n, NULL, NULL, &many_in, mc, NULL, 0, &wide.statistics, 4, 1,
                                           NULL, NULL, error));
        EXPECT_SUCCESS("65 influences copied", sk_limit_influences(moo, mob, moc, &n, NULL, NULL, &many_in, mc, NULL, 0,
                                                                   &wide.statistics, many, 1, NULL, NULL, error));
        free(many_coordinates_data), free(mo), free(mb), free(mc), free(moo), free(mob), free(moc);
        free_rig(&wide);
    }

    /* sk_remove_influence */
    double corrected[12], cost;
    EXPECT_SUCCESS("remove", sk_remove_influence(corrected, &cost, bones, coordinates, 3, 2, st, error));
    EXPECT_SUCCESS("remove, no cost", sk_remove_influence(corrected, NULL, bones, coordinates, 3, 0, st, error));
    EXPECT_FAILURE("one influence", SK_ERROR_ARGUMENT, sk_remove_influence(corrected, &cost, bones, coordinates, 1, 0, st, error));
    EXPECT_FAILURE("removed out of range", SK_ERROR_INDEX,
                   sk_remove_influence(corrected, &cost, bones, coordinates, 3, 3, st, error));
    EXPECT_FAILURE("null corrected", SK_ERROR_ARGUMENT, sk_remove_influence(NULL, &cost, bones, coordinates, 3, 0, st, error));
    EXPECT_FAILURE("null statistics", SK_ERROR_ARGUMENT,
                   sk_remove_influence(corrected, &cost, bones, coordinates, 3, 0, NULL, error));
    EXPECT_FAILURE("huge count", SK_ERROR_ARGUMENT,
                   sk_remove_influence(corrected, &cost, bones, coordinates, SIZE_MAX, 0, st, error));
    {
        const int32_t bad_data[3] = {1, 9, 3};
        int32_t *bad = exact_copy_int32(bad_data, 3);
        EXPECT_FAILURE("remove: bone out of range", SK_ERROR_INDEX,
                       sk_remove_influence(corrected, &cost, bad, coordinates, 3, 0, st, error));
        bad[1] = 3;
        EXPECT_FAILURE("remove: repeated bone", SK_ERROR_ARGUMENT,
                       sk_remove_influence(corrected, &cost, bad, coordinates, 3, 0, st, error));
        double *nan = exact_copy_double(coordinates_data, 12);
        nan[5] = NAN;
        EXPECT_FAILURE("remove: NaN", SK_ERROR_NOT_FINITE,
                       sk_remove_influence(corrected, &cost, bones, nan, 3, 0, st, error));
        free(bad), free(nan);
    }
    free(offsets), free(bones), free(coordinates);
    free_rig(&rg);
}

/* sk_limit_influences_in_metric: with sk_expectation_blocks' table it is sk_limit_influences to the bit; with the
 * sample second moments E[G_j^T G_k] of the rig's own poses each cost is exactly the RMS distance the limited vertex
 * moves over those poses; bad tables are refused naming the block. */
static void test_limit_in_given_metric(void)
{
    rig rg = make_rig(8, 30, 0, 0.8, -1);
    const size_t vertices = 120, per_vertex = 5, max_influences = 2, b = rg.bone_count;
    smooth_model m = make_smooth_model(&rg, vertices, per_vertex);
    const sk_influences influences = {m.offsets, m.bones, vertices, m.influence_count};
    int32_t *offsets_a = allocate(vertices + 1, sizeof(int32_t)), *bones_a = allocate(m.influence_count, sizeof(int32_t));
    int32_t *offsets_b = allocate(vertices + 1, sizeof(int32_t)), *bones_b = allocate(m.influence_count, sizeof(int32_t));
    double *out_a = allocate(4 * m.influence_count, sizeof(double)), *out_b = allocate(4 * m.influence_count, sizeof(double));
    double *costs_a = allocate(vertices, sizeof(double)), *costs_b = allocate(vertices, sizeof(double));
    double *blocks = allocate(16 * b * b, sizeof(double)), *per_vertex_error = allocate(vertices, sizeof(double));
    size_t count_a = 0, count_b = 0;
    EXPECT_SUCCESS("statistics", sk_limit_influences(offsets_a, bones_a, out_a, &count_a, costs_a, NULL, &influences,
                                                     m.coordinates, NULL, 0, &rg.statistics, max_influences, 0, NULL,
                                                     NULL, error));
    EXPECT_SUCCESS("expectation blocks", sk_expectation_blocks(blocks, rg.expected_local, rg.expected_gram, rg.parents,
                                                               b, error));
    EXPECT_SUCCESS("their table", sk_limit_influences_in_metric(offsets_b, bones_b, out_b, &count_b, costs_b, NULL,
                                                                &influences, m.coordinates, NULL, 0, blocks, b,
                                                                max_influences, 0, NULL, NULL, error));
    CHECK(count_a == count_b);
    CHECK_IN("same bones", memcmp(bones_a, bones_b, count_a * sizeof *bones_a) == 0);
    CHECK_IN("same coordinates", memcmp(out_a, out_b, 4 * count_a * sizeof *out_a) == 0);
    CHECK_IN("same costs", memcmp(costs_a, costs_b, vertices * sizeof *costs_a) == 0);

    /* The sampled metric: P_jk = mean_s G_j(s)^T G_k(s). */
    memset(blocks, 0, 16 * b * b * sizeof *blocks);
    for (size_t sample = 0; sample < rg.sample_count; ++sample)
        for (size_t j = 0; j < b; ++j)
            for (size_t k = 0; k < b; ++k) {
                const double *gj = rg.world + 16 * (sample * b + j), *gk = rg.world + 16 * (sample * b + k);
                for (int r = 0; r < 4; ++r)
                    for (int c = 0; c < 4; ++c)
                        for (int x = 0; x < 4; ++x)
                            blocks[16 * (j * b + k) + 4 * r + c] += gj[4 * x + r] * gk[4 * x + c] / (double)rg.sample_count;
            }
    EXPECT_SUCCESS("sampled table", sk_limit_influences_in_metric(offsets_b, bones_b, out_b, &count_b, costs_b, NULL,
                                                                  &influences, m.coordinates, NULL, 0, blocks, b,
                                                                  max_influences, 0, NULL, NULL, error));
    pose_error(&rg, m.offsets, m.bones, m.coordinates, m.influence_count, offsets_b, bones_b, out_b, count_b, vertices,
               per_vertex_error);
    double worst = 0.0, moved = 0.0;
    for (size_t v = 0; v < vertices; ++v) {
        worst = fmax(worst, fabs(sqrt(per_vertex_error[v]) - costs_b[v]) / fmax(costs_b[v], 1e-12));
        moved = fmax(moved, costs_b[v]);
    }
    CHECK_IN("sampled costs are the RMS over the samples", worst <= 1e-7 && moved > 1e-6);

    /* A table that is not symmetric, or not finite, is refused with the block named. */
    blocks[16 * (0 * b + 1) + 2] += 1.0;
    EXPECT_FAILURE("asymmetric block", SK_ERROR_ARGUMENT,
                   sk_limit_influences_in_metric(offsets_b, bones_b, out_b, &count_b, NULL, NULL, &influences,
                                                 m.coordinates, NULL, 0, blocks, b, max_influences, 0, NULL, NULL,
                                                 error));
    sk_error named = empty_error();
    sk_limit_influences_in_metric(offsets_b, bones_b, out_b, &count_b, NULL, NULL, &influences, m.coordinates, NULL, 0,
                                  blocks, b, max_influences, 0, NULL, NULL, &named);
    CHECK_IN(named.message, strstr(named.message, "block (0, 1)") != NULL);
    blocks[16 * (0 * b + 1) + 2] -= 1.0;
    blocks[16 * (3 * b + 2) + 5] = NAN;
    EXPECT_FAILURE("NaN block", SK_ERROR_NOT_FINITE,
                   sk_limit_influences_in_metric(offsets_b, bones_b, out_b, &count_b, NULL, NULL, &influences,
                                                 m.coordinates, NULL, 0, blocks, b, max_influences, 0, NULL, NULL,
                                                 error));
    sk_limit_influences_in_metric(offsets_b, bones_b, out_b, &count_b, NULL, NULL, &influences, m.coordinates, NULL, 0,
                                  blocks, b, max_influences, 0, NULL, NULL, &named);
    CHECK_IN(named.message, strstr(named.message, "block (3, 2)") != NULL);
    EXPECT_FAILURE("null table", SK_ERROR_ARGUMENT,
                   sk_limit_influences_in_metric(offsets_b, bones_b, out_b, &count_b, NULL, NULL, &influences,
                                                 m.coordinates, NULL, 0, NULL, b, max_influences, 0, NULL, NULL,
                                                 error));
    EXPECT_FAILURE("too few bones in the table", SK_ERROR_INDEX,
                   sk_limit_influences_in_metric(offsets_b, bones_b, out_b, &count_b, NULL, NULL, &influences,
                                                 m.coordinates, NULL, 0, rg.expected_local, 1, max_influences, 0, NULL,
                                                 NULL, error));
    free(offsets_a), free(bones_a), free(offsets_b), free(bones_b), free(out_a), free(out_b), free(costs_a);
    free(costs_b), free(blocks), free(per_vertex_error);
    free_smooth_model(&m);
    free_rig(&rg);
}

/* ---------------------------------------------------------------------------------------------
 * 2b. Every removal of a set costed from one factorization equals the per-candidate solve
 * ------------------------------------------------------------------------------------------- */

typedef struct cost_case {
    const char *name;
    size_t bones, samples;
    int fixed;
    double max_angle;
    int32_t redundant;
    size_t least_singular; /* sets (of 60) whose P_I has a null space, at least */
} cost_case;

/* Over random sets of 2 to 12 influences: each candidate's cost from sk_influence_remover_costs against
 * sk_influence_remover_apply (the per-candidate dgelsy solve) and the brute-force KKT, the cheapest candidate the
 * same, and the one-factorization path really taken (fallbacks counted). */
static void test_costs_from_one_factorization(void)
{
    const cost_case cases[] = {
        {"varying translations (P_I definite)", 14, 40, 0, 1.2, -1, 0},
        {"fixed translations (B.3: P_I singular)", 14, 40, 1, 1.2, -1, 30},
        {"a bone moving with its parent (zero-cost removals)", 14, 40, 0, 1.0, 5, 25},
        {"small motions (ill-conditioned P_I)", 14, 40, 0, 0.02, -1, 0},
        {"fixed translations, small motions (singular and ill-conditioned)", 14, 40, 1, 0.02, -1, 30},
    };
    for (size_t which = 0; which < sizeof cases / sizeof *cases; ++which) {
        const cost_case *cc = &cases[which];
        rig rg = make_rig(cc->bones, cc->samples, cc->fixed, cc->max_angle, cc->redundant);
        sk_influence_remover *remover = NULL;
        sk_error create_error = empty_error();
        CHECK(sk_influence_remover_create(&remover, &rg.statistics, 12, &create_error) == SK_OK);
        double worst = 0.0, worst_brute = 0.0, worst_zero = 0.0;
        size_t candidates = 0, fallbacks = 0, singular = 0, same_choice = 0, sets = 0, zero_cost = 0, same_reversed = 0;
        for (int trial = 0; remover && trial < 60; ++trial) {
            size_t n = 2 + random_below(11);
            int32_t chosen[12];
            pick_distinct_bones(chosen, n, rg.bone_count);
            if (cc->redundant >= 0 && trial % 2 == 0) { /* the redundant bone and its parent, then distinct others */
                chosen[0] = cc->redundant, chosen[1] = rg.parents[cc->redundant];
                for (size_t have = 2; have < n;) {
                    const int32_t bone = (int32_t)random_below(rg.bone_count);
                    int taken = 0;
                    for (size_t j = 0; j < have; ++j)
                        taken |= chosen[j] == bone;
                    if (!taken)
                        chosen[have++] = bone;
                }
            }
            double coordinates_data[48], costs_data[12];
            random_coordinates(coordinates_data, n, trial % 3 == 0 ? 0.0 : 1.0);
            int32_t *bones = exact_copy_int32(chosen, n);
            double *coordinates = exact_copy_double(coordinates_data, 4 * n);
            double *costs = exact_copy_double(costs_data, n);
            sk_error error = empty_error();
            CHECK(sk_influence_remover_costs(remover, costs, &fallbacks, bones, coordinates, n, (size_t)trial,
                                             &error) == SK_OK);
            { /* the same set in reverse order: the kept split, the same bits in the given order */
                int32_t reversed_bones[12];
                double reversed_coordinates[48], reversed_costs[12];
                for (size_t k = 0; k < n; ++k) {
                    reversed_bones[k] = bones[n - 1 - k];
                    memcpy(reversed_coordinates + 4 * k, coordinates + 4 * (n - 1 - k), 4 * sizeof(double));
                }
                CHECK(sk_influence_remover_costs(remover, reversed_costs, &fallbacks, reversed_bones,
                                                 reversed_coordinates, n, (size_t)trial, &error) == SK_OK);
                for (size_t k = 0; k < n; ++k)
                    same_reversed += reversed_costs[n - 1 - k] == costs[k];
            }
            double p[48 * 48], largest = 0.0, diagonal = 0.0;
            form_p(p, &rg, bones, n);
            singular += null_dimension(p, 4 * n) > 0;
            for (size_t k = 0; k < 4 * n; ++k)
                diagonal = fmax(diagonal, p[k * 4 * n + k]);
            /* the cost of a unit move: a zero cost is zero to rounding of it */
            const double unit = sqrt(diagonal) * max_abs(coordinates, 4 * n);
            size_t cheapest = 0, cheapest_single = 0;
            double single_best = INFINITY;
            for (size_t k = 0; k < n; ++k)
                largest = fmax(largest, costs[k]);
            for (size_t k = 0; k < n; ++k) {
                double single = -1.0, brute = -1.0, brute_corrected[48];
                CHECK(sk_influence_remover_apply(remover, NULL, &single, bones, coordinates, n, k, (size_t)trial,
                                                 &error) == SK_OK);
                if (single > 1e-12 * unit) /* relative; a cost zero to rounding must be as small from both */
                    worst = fmax(worst, fabs(costs[k] - single) / single);
                else
                    worst_zero = fmax(worst_zero, costs[k] / unit);
                if (n <= 6) { /* the brute force squares: its zero costs are only zero to ~1e-8 */
                    brute_force_removal(brute_corrected, &brute, &rg, bones, coordinates, n, k);
                    worst_brute = fmax(worst_brute, fabs(costs[k] - brute) / fmax(brute, 1e-2 * unit));
                }
                zero_cost += single <= 1e-12 * unit;
                if (costs[k] < costs[cheapest])
                    cheapest = k;
                if (single < single_best)
                    single_best = single, cheapest_single = k;
                ++candidates;
            }
            /* a tie within rounding may pick either: the chosen one's cost is the least to rounding */
            same_choice += cheapest == cheapest_single || fabs(costs[cheapest] - single_best) <= 1e-9 * largest + 1e-12 * unit;
            ++sets;
            free(bones), free(coordinates), free(costs);
        }
        char context[256];
        snprintf(context, sizeof context,
                 "%s: worst %.2e against the per-candidate solve, %.2e against brute force, over %zu candidates of "
                 "%zu sets (%zu singular, %zu zero-cost, largest of those %.1e of a unit move's, %zu per-candidate "
                 "fallbacks)",
                 cc->name, worst, worst_brute, candidates, sets, singular, zero_cost, worst_zero, fallbacks);
        CHECK_IN(context, worst <= 1e-9);
        CHECK_IN(context, worst_zero <= 1e-13);
        CHECK_IN(context, worst_brute <= 1e-5);
        CHECK_IN(context, same_choice == sets);
        CHECK_IN(context, same_reversed == candidates);
        CHECK_IN(context, singular >= cc->least_singular && (cc->least_singular > 0 || singular == 0));
        CHECK_IN(context, cc->redundant < 0 || zero_cost >= 20);
        CHECK_IN(context, fallbacks * 20 <= candidates); /* the one-factorization path, not the fallback, is tested */
        printf("costs from one factorization, %s\n", context);
        sk_influence_remover_free(remover);
        free_rig(&rg);
    }
}

/* A kept split costs other coordinates of its set with the elimination it recorded: the same bits as a fresh
 * remover factoring that set anew, whether the split was just made, kept (costed again within 32 sets) or
 * evicted and made again (40 sets in a round, more than the remover keeps). */
static void test_kept_split_costs_new_coordinates(void)
{
    rig rg = make_rig(14, 40, 1, 1.2, -1);
    sk_influence_remover *kept = NULL;
    sk_error error = empty_error();
    CHECK(sk_influence_remover_create(&kept, &rg.statistics, 8, &error) == SK_OK);
    enum { SETS = 40 };
    int32_t sets[SETS][8];
    size_t sizes[SETS], compared = 0, same = 0, fallbacks = 0;
    for (size_t s = 0; s < SETS; ++s) {
        sizes[s] = 2 + random_below(7);
        pick_distinct_bones(sets[s], sizes[s], rg.bone_count);
    }
    for (int round = 0; kept && round < 3; ++round)
        for (size_t s = 0; s < SETS; ++s) {
            const size_t n = sizes[s];
            double coordinates[32], costs[8], fresh_costs[8];
            random_coordinates(coordinates, n, 1.0);
            sk_influence_remover *fresh = NULL;
            CHECK(sk_influence_remover_create(&fresh, &rg.statistics, 8, &error) == SK_OK);
            CHECK(sk_influence_remover_costs(kept, costs, &fallbacks, sets[s], coordinates, n, s, &error) == SK_OK);
            if (round == 1 && s > 0) { /* the set before, costed again while kept */
                double again[8], again_fresh[8], other[32];
                random_coordinates(other, sizes[s - 1], 1.0);
                sk_influence_remover *first = NULL;
                CHECK(sk_influence_remover_create(&first, &rg.statistics, 8, &error) == SK_OK);
                CHECK(sk_influence_remover_costs(kept, again, &fallbacks, sets[s - 1], other, sizes[s - 1], s, &error) ==
                      SK_OK);
                CHECK(first && sk_influence_remover_costs(first, again_fresh, NULL, sets[s - 1], other, sizes[s - 1], s,
                                                          &error) == SK_OK);
                for (size_t k = 0; k < sizes[s - 1]; ++k, ++compared)
                    same += again[k] == again_fresh[k];
                sk_influence_remover_free(first);
            }
            CHECK(fresh && sk_influence_remover_costs(fresh, fresh_costs, NULL, sets[s], coordinates, n, s, &error) ==
                  SK_OK);
            for (size_t k = 0; k < n; ++k, ++compared)
                same += costs[k] == fresh_costs[k];
            sk_influence_remover_free(fresh);
        }
    char context[160];
    snprintf(context, sizeof context, "kept splits: %zu of %zu costs the same bits as a fresh remover's, %zu fallbacks",
             same, compared, fallbacks);
    CHECK_IN(context, compared > 0 && same == compared);
    CHECK_IN(context, fallbacks * 20 <= compared);
    sk_influence_remover_free(kept);
    free_rig(&rg);
}

int main(void)
{
    test_program_name = "test_lod";
    test_removal_matches_brute_force();
    test_redundant_influence();
    test_costs_from_one_factorization();
    test_kept_split_costs_new_coordinates();
    test_limit_beats_limit_total();
    test_limit_consistency();
    test_limit_in_given_metric();
    test_bad_inputs();
    return finish_tests();
}
