/*
 * Standalone tests of the animation-space max distances (csrc/skinkit.h, "The animation-space
 * metrics"): sk_max_distances bounds |G s| over every pose within the joint bounds and is attained by
 * worst cases, and sk_mean_distances / sk_max_distances refuse bad input (the expectations:
 * test_metrics.c).
 *
 * Meant to run under AddressSanitizer and UndefinedBehaviorSanitizer: the arrays handed to the core
 * are exactly sized heap blocks, so a function that read past its counts (or past a bad index before
 * rejecting it) would be stopped by the sanitizer, not just by a failed CHECK.
 *
 * References are computed with plain loops (here and in metrics_cases.c): forward kinematics by
 * walking each bone up to the root, explicit poses within the joint bounds, and worst-case poses built
 * by hand that attain the max-distance bound.
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
 * Random joints within bounds, and rotations
 * ------------------------------------------------------------------------------------------- */

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

/* ---------------------------------------------------------------------------------------------
 * 1. sk_max_distances: a bound over every pose within the joint bounds, attained by worst cases
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
 * 2. Errors of sk_mean_distances and sk_max_distances
 * ------------------------------------------------------------------------------------------- */

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

int main(void)
{
    test_program_name = "test_metric_bounds";
    test_max_distance_bounds_every_pose();
    test_max_distance_weight_only_worst_case();
    test_max_distance_chain_worst_case();
    test_max_distance_of_empty_vectors();
    test_max_distance_thread_counts();
    test_distance_errors();
    return finish_tests();
}
