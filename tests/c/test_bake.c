/*
 * Standalone tests of the baking family (csrc/skinkit.h, "Baking normal maps and tangent maps"): MikkTSpace
 * tangents of a plane (straight and mirrored uv), a plane baked onto itself is flat, an analytic bump baked by
 * every mode, misses, overlapping and out-of-range uv, option checks, cancelling, and the same bits on any thread
 * count. Runs under ASan/UBSan.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "offline/bake/sk_bake_internal.h" /* the hierarchy of the ray-cast bake, checked against brute force */
#include "skinkit.h"
#include "test_support.h"

#define BUMP 0.03
#define PI 3.14159265358979323846

/* An n x n-quad grid on [0, 1]^2, z = bump * sin(2 pi x) sin(2 pi y) (or flat), uv = (x, y) (mirrored in u when
 * mirror), normals analytic per corner. */
typedef struct grid {
    size_t T, V;
    int32_t *triangles;
    double *positions, *normals, *uv;
    sk_bake_surface surface;
} grid;

static void bump_normal(double out[3], double x, double y, double bump)
{
    const double hx = bump * 2 * PI * cos(2 * PI * x) * sin(2 * PI * y);
    const double hy = bump * 2 * PI * sin(2 * PI * x) * cos(2 * PI * y);
    const double length = sqrt(hx * hx + hy * hy + 1);
    out[0] = -hx / length, out[1] = -hy / length, out[2] = 1 / length;
}

static grid make_grid(size_t n, double bump, int mirror)
{
    grid g = {2 * n * n, (n + 1) * (n + 1), NULL, NULL, NULL, NULL, {0}};
    g.triangles = allocate(3 * g.T, sizeof(int32_t));
    g.positions = allocate(3 * g.V, sizeof(double));
    g.normals = allocate(9 * g.T, sizeof(double));
    g.uv = allocate(6 * g.T, sizeof(double));
    for (size_t i = 0; i <= n; ++i)
        for (size_t j = 0; j <= n; ++j) {
            double *p = g.positions + 3 * (i * (n + 1) + j);
            p[0] = (double)j / (double)n, p[1] = (double)i / (double)n;
            p[2] = bump * sin(2 * PI * p[0]) * sin(2 * PI * p[1]);
        }
    size_t t = 0;
    for (size_t i = 0; i < n; ++i)
        for (size_t j = 0; j < n; ++j) {
            const int32_t a = (int32_t)(i * (n + 1) + j), b = a + 1, c = a + (int32_t)n + 2, d = a + (int32_t)n + 1;
            const int32_t quads[2][3] = {{a, b, c}, {a, c, d}};
            for (int q = 0; q < 2; ++q, ++t)
                for (int k = 0; k < 3; ++k) {
                    const double *p = g.positions + 3 * (size_t)quads[q][k];
                    g.triangles[3 * t + (size_t)k] = quads[q][k];
                    bump_normal(g.normals + 9 * t + 3 * (size_t)k, p[0], p[1], bump);
                    g.uv[6 * t + 2 * (size_t)k] = mirror ? 1 - p[0] : p[0];
                    g.uv[6 * t + 2 * (size_t)k + 1] = p[1];
                }
        }
    g.surface = (sk_bake_surface){g.triangles, g.positions, g.normals, g.uv, g.T, g.V};
    return g;
}

static void free_grid(grid *g) { free(g->triangles), free(g->positions), free(g->normals), free(g->uv); }

typedef struct bake_result {
    size_t size;
    float *image;
    unsigned char *coverage;
    double *exact, *frames;
    sk_bake_report report;
} bake_result;

static bake_result new_result(size_t size)
{
    bake_result r = {size, allocate(3 * size * size, sizeof(float)), allocate(size * size, 1),
                     allocate(3 * size * size, sizeof(double)), allocate(9 * size * size, sizeof(double)), {0}};
    return r;
}

static void free_result(bake_result *r) { free(r->image), free(r->coverage), free(r->exact), free(r->frames); }

static sk_status bake(bake_result *r, const grid *target, const double *tangents, const grid *source,
                      sk_bake_options options, sk_error *error)
{
    return sk_bake_normals(r->image, r->coverage, r->exact, r->frames, &r->report, &target->surface, tangents,
                           &source->surface, &options, NULL, NULL, error);
}

static void test_tangents(void)
{
    for (int mirror = 0; mirror < 2; ++mirror) {
        grid g = make_grid(3, 0, mirror);
        double *tangents = allocate(12 * g.T, sizeof(double));
        EXPECT_SUCCESS("plane tangents", sk_mikktspace_tangents(tangents, &g.surface, error));
        double worst = 0;
        for (size_t c = 0; c < 3 * g.T; ++c) {
            const double *t = tangents + 4 * c;
            worst = fmax(worst, fabs(t[0] - (mirror ? -1 : 1)) + fabs(t[1]) + fabs(t[2]));
            worst = fmax(worst, fabs(t[3] - (mirror ? -1 : 1)));
        }
        CHECK_IN(mirror ? "mirrored uv: tangent -x, sign -1" : "tangent +x, sign +1", worst < 1e-12);
        free(tangents);
        free_grid(&g);
    }
    /* A curved surface: every tangent is unit and orthogonal to its corner normal. */
    grid g = make_grid(8, BUMP * 5, 0);
    double *tangents = allocate(12 * g.T, sizeof(double));
    EXPECT_SUCCESS("bump tangents", sk_mikktspace_tangents(tangents, &g.surface, error));
    double worst = 0;
    for (size_t c = 0; c < 3 * g.T; ++c) {
        const double *t = tangents + 4 * c, *n = g.normals + 3 * c;
        worst = fmax(worst, fabs(t[0] * t[0] + t[1] * t[1] + t[2] * t[2] - 1));
        worst = fmax(worst, fabs(t[0] * n[0] + t[1] * n[1] + t[2] * n[2]));
    }
    CHECK_IN("unit tangents in the normal's plane", worst < 1e-12);
    free(tangents);
    free_grid(&g);
    /* MikkTSpace's degenerate rule: a triangle whose uvs are one point contributes nothing and, cut off from its
     * neighbours by the uvs it no longer shares, keeps the default (1, 0, 0) with sign -1 (Blender's port). */
    g = make_grid(3, 0, 0);
    tangents = allocate(12 * g.T, sizeof(double));
    for (int k = 1; k < 3; ++k)
        g.uv[2 * k] = g.uv[0], g.uv[2 * k + 1] = g.uv[1];
    EXPECT_SUCCESS("a triangle of no uv area", sk_mikktspace_tangents(tangents, &g.surface, error));
    worst = 0;
    for (size_t c = 0; c < 3 * g.T; ++c) {
        const double *t = tangents + 4 * c;
        worst = fmax(worst, fabs(t[0] - 1) + fabs(t[1]) + fabs(t[2]) + fabs(t[3] - (c < 3 ? -1 : 1)));
    }
    CHECK_IN("its corners (1, 0, 0, -1), the others +x with +1", worst < 1e-12);
    free(tangents);
    free_grid(&g);
}

static void test_self_and_bump(void)
{
    grid target = make_grid(4, 0, 0), source = make_grid(96, BUMP, 0);
    double *tangents = allocate(12 * target.T, sizeof(double));
    CHECK(sk_mikktspace_tangents(tangents, &target.surface, NULL) == SK_OK);
    const size_t size = 64;
    bake_result flat = new_result(size);
    EXPECT_SUCCESS("self bake", bake(&flat, &target, tangents, &target, (sk_bake_options){size, SK_BAKE_ATLAS, 2, 4, 0, 2},
                                     error));
    double worst = 0;
    for (size_t i = 0; i < size * size; ++i)
        worst = fmax(worst, fabs(flat.image[3 * i] - 0.5) + fabs(flat.image[3 * i + 1] - 0.5) +
                                fabs(flat.image[3 * i + 2] - 1));
    CHECK_IN("a plane baked onto itself is (0.5, 0.5, 1)", worst < 1.0 / 255);
    CHECK_IN("the whole square is filled", flat.report.filled == size * size && flat.report.missed == 0);
    static const char *const bump_checks[] = {"atlas: the analytic bump", "ray cast: the analytic bump",
                                              "guided: the analytic bump"};
    for (int mode = SK_BAKE_ATLAS; mode <= SK_BAKE_GUIDED; ++mode) {
        bake_result r = new_result(size);
        EXPECT_SUCCESS("bump bake", bake(&r, &target, tangents, &source, (sk_bake_options){size, mode, 2, 4, 0.1, 0}, error));
        double mean = 0, largest = 0;
        for (size_t row = 0; row < size; ++row)
            for (size_t column = 0; column < size; ++column) {
                const size_t i = row * size + column;
                double expected[3], decoded[3], length = 0;
                bump_normal(expected, (column + 0.5) / size, 1 - (row + 0.5) / size, BUMP);
                for (int k = 0; k < 3; ++k)
                    decoded[k] = 2.0 * r.image[3 * i + (size_t)k] - 1, length += decoded[k] * decoded[k];
                const double cosine = (decoded[0] * expected[0] + decoded[1] * expected[1] + decoded[2] * expected[2]) /
                                      sqrt(length);
                const double angle = acos(fmin(1, cosine)) * 180 / PI;
                mean += angle / (double)(size * size);
                largest = fmax(largest, angle);
            }
        CHECK_IN(bump_checks[mode], mean < 0.05 && largest < 0.2);
        free_result(&r);
    }
    /* Threads and bits: one thread and three give the same image. */
    bake_result one = new_result(size), three = new_result(size);
    CHECK(bake(&one, &target, tangents, &source, (sk_bake_options){size, SK_BAKE_RAY_CAST, 3, 2, 0.1, 1}, NULL) == SK_OK);
    CHECK(bake(&three, &target, tangents, &source, (sk_bake_options){size, SK_BAKE_RAY_CAST, 3, 2, 0.1, 3}, NULL) == SK_OK);
    CHECK_IN("the same bits on 1 and 3 threads", memcmp(one.image, three.image, 3 * size * size * sizeof(float)) == 0);
    free_result(&one), free_result(&three), free_result(&flat);
    free(tangents);
    free_grid(&target), free_grid(&source);
}

/* A target covering half the square (x in [0, 0.5]) at 32 texels: conservative coverage, then the margin. */
static void test_coverage_and_margin(void)
{
    grid target = make_grid(2, 0, 0);
    for (size_t i = 0; i < 6 * target.T; i += 2)
        target.uv[i] *= 0.5; /* squeeze uv into u <= 0.5 */
    double *tangents = allocate(12 * target.T, sizeof(double));
    CHECK(sk_mikktspace_tangents(tangents, &target.surface, NULL) == SK_OK);
    const size_t size = 33; /* u = 0.5 falls inside column 16 */
    bake_result r = new_result(size);
    EXPECT_SUCCESS("half square", bake(&r, &target, tangents, &target, (sk_bake_options){size, SK_BAKE_ATLAS, 1, 3, 0, 1},
                                       error));
    CHECK_IN("columns 0-16 filled (column 16 only conservatively)", r.report.filled == 17 * size);
    CHECK_IN("a margin of 3 columns", r.report.dilated == 3 * size);
    CHECK_IN("the rest empty", r.report.empty == (size - 20) * size);
    CHECK(r.coverage[16] == SK_TEXEL_FILLED && r.coverage[19] == SK_TEXEL_DILATED && r.coverage[20] == SK_TEXEL_EMPTY);
    free_result(&r);
    free(tangents);
    free_grid(&target);
}

static int cancel_at_once(void *user, double fraction)
{
    (void)fraction;
    ++*(int *)user;
    return 1;
}

/* Counts its calls and cancels on the second: a cancel midway through a bake of three batches of rows. */
static int cancel_on_second(void *user, double fraction)
{
    (void)fraction;
    return ++*(int *)user == 2;
}

/* Keeps the last fraction reported and never cancels. */
static int record_fraction(void *user, double fraction)
{
    *(double *)user = fraction;
    return 0;
}

static void test_failures(void)
{
    grid target = make_grid(2, 0, 0), far = make_grid(2, 0, 0);
    for (size_t v = 0; v < far.V; ++v)
        far.positions[3 * v + 2] = 5; /* out of any small cage */
    double *tangents = allocate(12 * target.T, sizeof(double));
    CHECK(sk_mikktspace_tangents(tangents, &target.surface, NULL) == SK_OK);
    const size_t size = 16;
    bake_result r = new_result(size);
    EXPECT_SUCCESS("a source out of reach", bake(&r, &target, tangents, &far,
                                                 (sk_bake_options){size, SK_BAKE_RAY_CAST, 2, 2, 0.5, 1}, error));
    CHECK_IN("every texel missed and flat", r.report.missed == size * size && r.report.filled == 0 &&
                                                 r.image[2] == 1.0f && r.coverage[0] == SK_TEXEL_MISSED);
    const sk_bake_options good = {size, SK_BAKE_ATLAS, 2, 2, 0, 1};
    sk_bake_options bad = good;
    bad.size = 0;
    EXPECT_FAILURE("size 0", SK_ERROR_ARGUMENT, bake(&r, &target, tangents, &target, bad, error));
    bad = good, bad.mode = 3;
    EXPECT_FAILURE("mode 3", SK_ERROR_ARGUMENT, bake(&r, &target, tangents, &target, bad, error));
    bad = good, bad.supersample = 9;
    EXPECT_FAILURE("supersample 9", SK_ERROR_ARGUMENT, bake(&r, &target, tangents, &target, bad, error));
    bad = good, bad.mode = SK_BAKE_RAY_CAST, bad.cage = 0;
    EXPECT_FAILURE("cage 0", SK_ERROR_ARGUMENT, bake(&r, &target, tangents, &target, bad, error));
    bad = good, bad.mode = SK_BAKE_GUIDED, bad.cage = 0;
    EXPECT_FAILURE("guided, cage 0", SK_ERROR_ARGUMENT, bake(&r, &target, tangents, &target, bad, error));
    target.uv[7] = 1.5;
    sk_error record;
    CHECK(bake(&r, &target, tangents, &target, good, &record) == SK_ERROR_ARGUMENT);
    CHECK_IN("uv outside 0-1 names the corner", strstr(record.message, "corner 3 (triangle 1)") != NULL);
    target.uv[7] = 0.5;
    /* Triangle 1 moved onto triangle 0 in uv: overlapping. */
    memcpy(target.uv + 6, target.uv, 6 * sizeof(double));
    CHECK(bake(&r, &target, tangents, &target, good, &record) == SK_ERROR_ARGUMENT);
    CHECK_IN("overlapping uvs are counted", strstr(record.message, "covered by more than one target triangle") != NULL);
    sk_bake_options one_sample = good;
    one_sample.supersample = 1; /* the texel centres' rasterised flags, not the per-sample search */
    CHECK(bake(&r, &target, tangents, &target, one_sample, &record) == SK_ERROR_ARGUMENT);
    CHECK_IN("overlapping uvs are counted at one sample", strstr(record.message, "covered by more than one") != NULL);
    free_grid(&target);
    target = make_grid(2, 0, 0);
    int calls = 0;
    sk_error cancelled;
    CHECK(sk_bake_normals(r.image, r.coverage, NULL, NULL, &r.report, &target.surface, tangents, &target.surface, &good,
                          cancel_at_once, &calls, &cancelled) == SK_ERROR_CANCELLED);
    CHECK_IN("cancelled on the first report", calls == 1 && cancelled.status == SK_ERROR_CANCELLED);
    tangents[5] = NAN;
    EXPECT_FAILURE("a NaN tangent", SK_ERROR_NOT_FINITE, bake(&r, &target, tangents, &target, good, error));
    target.triangles[4] = 99;
    EXPECT_FAILURE("an index out of range", SK_ERROR_INDEX, sk_mikktspace_tangents(tangents, &target.surface, error));
    free_result(&r);
    free(tangents);
    free_grid(&target), free_grid(&far);
}

/* A two-bone model on the bump grid: bone 1 (joint at x = 0.5) takes over across the middle. Posing bone 1, every
 * texel's normalize(G t1 x G t2) is the posed source face's normal. */
static void test_tangent_map(void)
{
    grid target = make_grid(2, 0, 0), source = make_grid(10, BUMP * 3, 0);
    const size_t V = source.V, size = 24, slots = 4;
    int32_t *offsets = allocate(V + 1, sizeof(int32_t)), *bones = allocate(2 * V, sizeof(int32_t));
    double *coordinates = allocate(8 * V, sizeof(double));
    for (size_t v = 0; v < V; ++v) {
        const double *p = source.positions + 3 * v, w = fmin(1, fmax(0, (p[0] - 0.3) / 0.4));
        offsets[v + 1] = (int32_t)(2 * v + 2);
        bones[2 * v] = 0, bones[2 * v + 1] = 1;
        double *root = coordinates + 8 * v, *child = root + 4;
        for (int k = 0; k < 3; ++k)
            root[k] = (1 - w) * p[k], child[k] = w * (p[k] - (k == 0 ? 0.5 : 0));
        root[3] = 1 - w, child[3] = w;
    }
    const sk_influences influences = {offsets, bones, V, 2 * V};
    int32_t *counts = allocate(size * size, sizeof(int32_t)), *texel_bones = allocate(size * size * slots, sizeof(int32_t));
    int32_t *triangles = allocate(size * size, sizeof(int32_t));
    double *tangents = allocate(8 * size * size * slots, sizeof(double));
    unsigned char *coverage = allocate(size * size, 1);
    EXPECT_SUCCESS("tangent map", sk_bake_tangent_map(counts, texel_bones, tangents, triangles, coverage, &target.surface,
                                                      &source.surface, &influences, coordinates, size, slots, 2, NULL, NULL,
                                                      error));
    double poses[32] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    const double angle = 0.7;
    const double child_pose[16] = {cos(angle), 0, sin(angle), 0.5, 0, 1, 0, 0.1, -sin(angle), 0, cos(angle), 0.2, 0, 0, 0, 1};
    memcpy(poses + 16, child_pose, sizeof child_pose);
    float *image = allocate(3 * size * size, sizeof(float));
    EXPECT_SUCCESS("posed normals", sk_tangent_map_normals(image, counts, texel_bones, tangents, poses, size * size, slots,
                                                           2, 1, error));
    double worst = 0;
    size_t filled = 0;
    for (size_t texel = 0; texel < size * size; ++texel) {
        if (coverage[texel] != SK_TEXEL_FILLED)
            continue;
        ++filled;
        double corner[3][3];
        for (int c = 0; c < 3; ++c) {
            const size_t vertex = (size_t)source.triangles[3 * (size_t)triangles[texel] + (size_t)c];
            for (int r = 0; r < 3; ++r) {
                corner[c][r] = 0;
                for (int32_t k = offsets[vertex]; k < offsets[vertex + 1]; ++k)
                    for (int d = 0; d < 4; ++d)
                        corner[c][r] += poses[16 * (size_t)bones[k] + 4 * (size_t)r + (size_t)d] * coordinates[4 * (size_t)k + (size_t)d];
            }
        }
        double e1[3], e2[3], n[3];
        for (int r = 0; r < 3; ++r)
            e1[r] = corner[1][r] - corner[0][r], e2[r] = corner[2][r] - corner[0][r];
        n[0] = e1[1] * e2[2] - e1[2] * e2[1], n[1] = e1[2] * e2[0] - e1[0] * e2[2], n[2] = e1[0] * e2[1] - e1[1] * e2[0];
        const double length = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for (int r = 0; r < 3; ++r)
            worst = fmax(worst, fabs(2.0 * image[3 * texel + (size_t)r] - 1 - n[r] / length));
    }
    CHECK_IN("every texel filled", filled == size * size);
    CHECK_IN("posed normals are the posed source faces'", worst < 1e-6);
    EXPECT_FAILURE("one slot is too few", SK_ERROR_ARGUMENT,
                   sk_bake_tangent_map(counts, texel_bones, tangents, triangles, coverage, &target.surface,
                                       &source.surface, &influences, coordinates, size, 1, 2, NULL, NULL, error));
    {   /* Cancelled midway: 80 rows are three batches; the second report cancels, naming the row it stopped at. */
        const size_t big = 80;
        int32_t *big_counts = allocate(big * big, sizeof(int32_t)), *big_bones = allocate(big * big * slots, sizeof(int32_t));
        int32_t *big_triangles = allocate(big * big, sizeof(int32_t));
        double *big_tangents = allocate(8 * big * big * slots, sizeof(double));
        unsigned char *big_coverage = allocate(big * big, 1);
        int calls = 0;
        sk_error cancelled;
        CHECK(sk_bake_tangent_map(big_counts, big_bones, big_tangents, big_triangles, big_coverage, &target.surface,
                                  &source.surface, &influences, coordinates, big, slots, 2, cancel_on_second, &calls,
                                  &cancelled) == SK_ERROR_CANCELLED);
        CHECK_IN("the tangent map cancelled on the second report", calls == 2 &&
                 strstr(cancelled.message, "cancelled at row 64 of 80") != NULL);
        double last_fraction = 0;
        EXPECT_SUCCESS("a tangent map reporting progress", sk_bake_tangent_map(
            big_counts, big_bones, big_tangents, big_triangles, big_coverage, &target.surface, &source.surface,
            &influences, coordinates, big, slots, 2, record_fraction, &last_fraction, error));
        CHECK_IN("progress reaches 1", last_fraction == 1.0);
        free(big_counts), free(big_bones), free(big_triangles), free(big_tangents), free(big_coverage);
    }
    /* The mip level: a block whose texels share one pair keeps it; an odd size or a wrong output size is refused. */
    const size_t half = size / 2;
    CHECK(sk_bake_tangent_map(counts, texel_bones, tangents, triangles, coverage, &target.surface, &source.surface,
                              &influences, coordinates, size, slots, 2, NULL, NULL, NULL) == SK_OK); /* the failed call wrote */
    int32_t *half_counts = allocate(half * half, sizeof(int32_t)), *half_bones = allocate(half * half * slots, sizeof(int32_t));
    double *half_tangents = allocate(8 * half * half * slots, sizeof(double));
    EXPECT_SUCCESS("downsample", sk_tangent_map_downsample(half_counts, half_bones, half_tangents, half, counts, texel_bones,
                                                           tangents, size, slots, NULL, 0, 2, error));
    double drift = 0;
    size_t uniform = 0;
    for (size_t row = 0; row < half; ++row)
        for (size_t column = 0; column < half; ++column) {
            const size_t child = 2 * row * size + 2 * column, out = row * half + column;
            const size_t others[3] = {child + 1, child + size, child + size + 1};
            int same = triangles[child] >= 0;
            for (int k = 0; k < 3; ++k)
                same &= triangles[others[k]] == triangles[child];
            if (!same)
                continue;
            ++uniform;
            CHECK(half_counts[out] == counts[child]);
            for (size_t k = 0; k < 8 * (size_t)counts[child]; ++k)
                drift = fmax(drift, fabs(half_tangents[8 * out * slots + k] - tangents[8 * child * slots + k]));
        }
    CHECK_IN("blocks within one source triangle keep their pair", uniform > 0 && drift < 1e-12);
    /* In the metric: P = I (two bones) is the Euclidean fit; a P that weighs bone 1 and the w component unevenly
     * still keeps a block's common pair (it lies in its own fitted plane), but moves mixed blocks. */
    double metric[2 * 2 * 16] = {0};
    for (size_t b = 0; b < 2; ++b)
        for (size_t r = 0; r < 4; ++r)
            metric[(b * 2 + b) * 16 + 5 * r] = 1;
    double *metric_tangents = allocate(8 * half * half * slots, sizeof(double));
    EXPECT_SUCCESS("downsample in P = I", sk_tangent_map_downsample(half_counts, half_bones, metric_tangents, half,
                                                                    counts, texel_bones, tangents, size, slots, metric,
                                                                    2, 2, error));
    double identity_drift = 0;
    for (size_t k = 0; k < 8 * half * half * slots; ++k)
        identity_drift = fmax(identity_drift, fabs(metric_tangents[k] - half_tangents[k]));
    CHECK_IN("P = I: the Euclidean fit", identity_drift < 1e-9);
    for (size_t r = 0; r < 4; ++r) {
        metric[(1 * 2 + 1) * 16 + 5 * r] = 9;
        metric[(0 * 2 + 1) * 16 + 5 * r] = metric[(1 * 2 + 0) * 16 + 5 * r] = 0.5;
    }
    EXPECT_SUCCESS("downsample in a metric", sk_tangent_map_downsample(half_counts, half_bones, metric_tangents, half,
                                                                       counts, texel_bones, tangents, size, slots,
                                                                       metric, 2, 2, error));
    double kept = 0, moved = 0;
    for (size_t row = 0; row < half; ++row)
        for (size_t column = 0; column < half; ++column) {
            const size_t child = 2 * row * size + 2 * column, out = row * half + column;
            const size_t others[3] = {child + 1, child + size, child + size + 1};
            int same = triangles[child] >= 0;
            for (int k = 0; k < 3; ++k)
                same &= triangles[others[k]] == triangles[child];
            for (size_t k = 0; k < 8 * (size_t)half_counts[out]; ++k) {
                const double change = fabs(metric_tangents[8 * out * slots + k] - half_tangents[8 * out * slots + k]);
                if (same)
                    kept = fmax(kept, fabs(metric_tangents[8 * out * slots + k] - tangents[8 * child * slots + k]));
                else
                    moved = fmax(moved, change);
            }
        }
    CHECK_IN("a metric keeps uniform blocks and moves mixed ones", kept < 1e-9 && moved > 1e-6);
    EXPECT_FAILURE("a bone outside the metric's skeleton", SK_ERROR_INDEX,
                   sk_tangent_map_downsample(half_counts, half_bones, metric_tangents, half, counts, texel_bones,
                                             tangents, size, slots, metric, 1, 1, error));
    free(metric_tangents);
    EXPECT_FAILURE("odd size", SK_ERROR_ARGUMENT, sk_tangent_map_downsample(half_counts, half_bones, half_tangents, half,
                                                                             counts, texel_bones, tangents, size - 1,
                                                                             slots, NULL, 0, 1, error));
    EXPECT_FAILURE("wrong output size", SK_ERROR_ARGUMENT,
                   sk_tangent_map_downsample(half_counts, half_bones, half_tangents, half - 1, counts, texel_bones,
                                             tangents, size, slots, NULL, 0, 1, error));
    free(half_counts), free(half_bones), free(half_tangents);
    texel_bones[1] = 7;
    counts[0] = 2;
    EXPECT_FAILURE("a bone out of range", SK_ERROR_INDEX,
                   sk_tangent_map_normals(image, counts, texel_bones, tangents, poses, size * size, slots, 2, 1, error));
    free(offsets), free(bones), free(coordinates), free(counts), free(texel_bones), free(triangles), free(tangents);
    free(coverage), free(image);
    free_grid(&target), free_grid(&source);
}

/* The cause of the horse's unbaked texels: a simplified level's corner normals tilted almost into the face (here
 * 84 degrees off it), so the ray along them runs beside a source 0.01 above the face and meets it only 0.1 away,
 * beyond the cage of 0.05. The source is within the cage all the same: every texel is baked, with its normal. */
static void test_grazing_normals(void)
{
    grid target = make_grid(2, 0, 0), source = make_grid(2, 0, 0);
    const double tilt = 0.1; /* the cosine between the corner normals and the face normal */
    for (size_t c = 0; c < 3 * target.T; ++c) {
        double *n = target.normals + 3 * c;
        n[0] = sqrt(1 - tilt * tilt), n[1] = 0, n[2] = tilt;
    }
    for (size_t v = 0; v < source.V; ++v)
        source.positions[3 * v + 2] = 0.01;
    double *tangents = allocate(12 * target.T, sizeof(double));
    CHECK(sk_mikktspace_tangents(tangents, &target.surface, NULL) == SK_OK);
    const size_t size = 16;
    bake_result r = new_result(size);
    EXPECT_SUCCESS("grazing normals", bake(&r, &target, tangents, &source,
                                           (sk_bake_options){size, SK_BAKE_RAY_CAST, 1, 0, 0.05, 1}, error));
    CHECK_IN("every texel baked", r.report.filled == size * size && r.report.missed == 0);
    double worst = 0;
    for (size_t texel = 0; texel < size * size; ++texel)
        worst = fmax(worst, fabs(r.exact[3 * texel + 2] - 1));
    CHECK_IN("the source's own normal (0, 0, 1) at every texel", worst < 1e-12);
    free_result(&r);
    free(tangents);
    free_grid(&target), free_grid(&source);
}

/* ---- the ray-cast bake's hierarchy against brute force ---------------------------------------------------------- */

/* The oracle: Moller-Trumbore as the hierarchy computes it (corner 0, the edges, the same operations in the same
 * order, the same 1e-9 barycentric tolerance), so a correct walk returns exactly its best hit. */
static int oracle_intersect(const sk_bake_surface *surface, size_t triangle, const double *origin,
                            const double *direction, double *t, double *w1, double *w2)
{
    const double *p0 = surface->positions + 3 * (size_t)surface->triangles[3 * triangle];
    const double *p1 = surface->positions + 3 * (size_t)surface->triangles[3 * triangle + 1];
    const double *p2 = surface->positions + 3 * (size_t)surface->triangles[3 * triangle + 2];
    double e1[3], e2[3], s[3], p[3], q[3];
    for (int k = 0; k < 3; ++k) {
        e1[k] = p1[k] - p0[k];
        e2[k] = p2[k] - p0[k];
        s[k] = origin[k] - p0[k];
    }
    sk_cross3(p, direction, e2);
    const double determinant = sk_dot3(e1, p);
    if (determinant == 0)
        return 0;
    const double inverse = 1.0 / determinant, u = sk_dot3(s, p) * inverse;
    if (u < -1e-9 || u > 1 + 1e-9)
        return 0;
    sk_cross3(q, s, e1);
    const double v = sk_dot3(direction, q) * inverse;
    if (v < -1e-9 || u + v > 1 + 1e-9)
        return 0;
    *t = sk_dot3(e2, q) * inverse;
    *w1 = u;
    *w2 = v;
    return 1;
}

/* The nearest hit within reach over every triangle (ties: the lowest index), or -1. */
static int32_t oracle_nearest_hit(const sk_bake_surface *surface, const double *origin, const double *direction,
                                  double reach, double *w1, double *w2)
{
    int32_t best = -1;
    for (size_t t = 0; t < surface->triangle_count; ++t) {
        double along, a, b;
        if (oracle_intersect(surface, t, origin, direction, &along, &a, &b) && fabs(along) <= reach &&
            (best < 0 || fabs(along) < reach)) {
            reach = fabs(along);
            best = (int32_t)t;
            *w1 = a;
            *w2 = b;
        }
    }
    return best;
}

/* The closest point within reach over every triangle (ties: the lowest index), or -1: each triangle's own closest
 * point from a one-triangle hierarchy (a root leaf: no walk to get wrong), its squared distance recomputed as the
 * hierarchy does. */
static int32_t oracle_closest_point(const sk_bake_surface *surface, const sk_bvh *single, const double *point,
                                    double reach, double *w1, double *w2)
{
    int32_t best = -1;
    double best2 = reach * reach;
    for (size_t t = 0; t < surface->triangle_count; ++t) {
        int32_t found;
        double a, b, distance2 = 0;
        if (!sk_bvh_closest_point(&single[t], point, INFINITY, -1, &found, &a, &b))
            continue;
        const double *p0 = surface->positions + 3 * (size_t)surface->triangles[3 * t];
        const double *p1 = surface->positions + 3 * (size_t)surface->triangles[3 * t + 1];
        const double *p2 = surface->positions + 3 * (size_t)surface->triangles[3 * t + 2];
        for (int k = 0; k < 3; ++k) {
            const double gap = p0[k] + a * (p1[k] - p0[k]) + b * (p2[k] - p0[k]) - point[k];
            distance2 += gap * gap;
        }
        if (distance2 < best2 || (distance2 == best2 && best < 0)) {
            best2 = distance2;
            best = (int32_t)t;
            *w1 = a;
            *w2 = b;
        }
    }
    return best;
}

/* A triangle soup in the unit cube: small random triangles, axis-aligned ones, degenerate ones (a point, a line),
 * twenty copies of one triangle (coinciding centres) and a run of triangles at exponentially growing distances
 * (the SAH peels one off per split, so the build must fall back to halving to keep the depth bounded). The queries
 * include axis-aligned segments (a direction component exactly 0) starting exactly on a box plane, where the slab
 * test meets 0 * inf, and segments passing a triangle's corner within the intersection's tolerance, outside the
 * triangle's own box: the hierarchy's boxes are padded for them. */
typedef struct soup {
    size_t T;
    int32_t triangles[3 * 400];
    double positions[9 * 400];
    double normals[9 * 400];
    sk_bake_surface surface;
} soup;

static void make_soup(soup *s)
{
    s->T = 0;
    for (size_t t = 0; t < 400; ++t) {
        double *p = s->positions + 9 * t, centre[3];
        for (int k = 0; k < 3; ++k)
            centre[k] = random_uniform(0, 1);
        for (int c = 0; c < 3; ++c)
            for (int k = 0; k < 3; ++k)
                p[3 * c + k] = centre[k] + random_uniform(-0.05, 0.05);
        if (t % 17 == 0) /* in a plane z = const, so a box is flat */
            p[2] = p[5] = p[8] = centre[2];
        if (t % 29 == 0) /* a point */
            for (int k = 0; k < 6; ++k)
                p[3 + k] = p[k % 3];
        if (t % 31 == 0) /* a line */
            for (int k = 0; k < 3; ++k)
                p[6 + k] = 2 * p[3 + k] - p[k];
        if (t >= 300 && t < 320) /* copies of one triangle */
            for (int k = 0; k < 9; ++k)
                p[k] = s->positions[9 * 300 + k];
        if (t >= 320 && t < 380) /* far out along x, each twice as far as the last */
            for (int c = 0; c < 3; ++c)
                p[3 * c] = 1 + ldexp(1, (int)(t - 320)) + 0.3 * c;
        for (int c = 0; c < 3; ++c)
            s->triangles[3 * t + (size_t)c] = (int32_t)(3 * t + (size_t)c);
        ++s->T;
    }
    for (size_t i = 0; i < 9 * s->T; ++i)
        s->normals[i] = i % 3 == 2;
    s->surface = (sk_bake_surface){s->triangles, s->positions, s->normals, NULL, s->T, 3 * s->T};
}

static void test_hierarchy(void)
{
    static soup s;
    make_soup(&s);
    sk_bvh bvh, *single = allocate(s.T, sizeof *single);
    sk_error error;
    CHECK_IN("the soup's hierarchy", sk_bvh_build(&bvh, &s.surface, &error) == SK_OK);
    sk_bake_surface one[400];
    for (size_t t = 0; t < s.T; ++t) {
        one[t] = (sk_bake_surface){s.triangles + 3 * t, s.positions, s.normals + 9 * t, NULL, 1, 3 * s.T};
        CHECK_IN("a one-triangle hierarchy", sk_bvh_build(&single[t], &one[t], &error) == SK_OK);
    }
    size_t wrong_hits = 0, wrong_points = 0, kernels_differ = 0, hits = 0, points = 0;
    for (int query = 0; query < 4000; ++query) {
        double origin[3], direction[3], length = 0;
        for (int k = 0; k < 3; ++k) {
            origin[k] = random_uniform(-0.1, 1.1);
            direction[k] = random_uniform(-1, 1);
        }
        if (query % 5 == 0) /* along an axis: two direction components exactly 0 */
            direction[(query / 5) % 3] = 1, direction[(query / 5 + 1) % 3] = 0, direction[(query / 5 + 2) % 3] = 0;
        if (query % 7 == 0) /* from a corner of a triangle: origins on box planes */
            for (int k = 0; k < 3; ++k)
                origin[k] = s.positions[9 * (size_t)(query % 300) + (size_t)k];
        if (query % 11 == 0) { /* along an axis from a point exactly on a plane of a node's box (a flat axis) */
            const sk_bvh_node *node = &bvh.nodes[(size_t)query % bvh.node_count];
            const int along = query % 3, on = (query + 1) % 3, other = (query + 2) % 3;
            for (int k = 0; k < 3; ++k)
                direction[k] = k == along;
            origin[along] = 0.5 * (node->low[along][0] + node->high[along][0]);
            origin[on] = query % 2 ? node->low[on][0] : node->high[on][0];
            origin[other] = 0.5 * (node->low[other][0] + node->high[other][0]);
        }
        if (query % 13 == 0) { /* down z just beyond a triangle's corner of largest x: inside the tolerance */
            const double *p = s.positions + 9 * (size_t)(query % 300);
            const int corner = p[0] > p[3] ? (p[0] > p[6] ? 0 : 2) : (p[3] > p[6] ? 1 : 2);
            origin[0] = p[3 * corner] + 1e-12;
            origin[1] = p[3 * corner + 1];
            origin[2] = p[3 * corner + 2] + 0.01;
            direction[0] = direction[1] = 0;
            direction[2] = -1;
        }
        for (int k = 0; k < 3; ++k)
            length += direction[k] * direction[k];
        for (int k = 0; k < 3; ++k)
            direction[k] /= sqrt(length);
        const double reach = query % 3 == 0 ? 0.02 : random_uniform(0.01, 0.5);
        const int32_t hint = query % 4 == 0 ? (int32_t)(query % 400) : -1;
        double w1 = 0, w2 = 0, e1 = 0, e2 = 0;
        int32_t hit = -1, expected = oracle_nearest_hit(&s.surface, origin, direction, reach, &e1, &e2);
        bvh.kernel = SK_BVH_SSE2 * sk_bvh_has_sse2();
        const int found = sk_bvh_nearest_hit(&bvh, origin, direction, reach, hint, &hit, &w1, &w2);
        hits += found;
        wrong_hits += found != (expected >= 0) || (found && (hit != expected || w1 != e1 || w2 != e2));
        int32_t scalar_hit = -1;
        double s1 = 0, s2 = 0;
        bvh.kernel = SK_BVH_SCALAR;
        const int scalar_found = sk_bvh_nearest_hit(&bvh, origin, direction, reach, hint, &scalar_hit, &s1, &s2);
        kernels_differ += scalar_found != found || (found && (scalar_hit != hit || s1 != w1 || s2 != w2));

        expected = oracle_closest_point(&s.surface, single, origin, reach, &e1, &e2);
        bvh.kernel = SK_BVH_SSE2 * sk_bvh_has_sse2();
        const int near = sk_bvh_closest_point(&bvh, origin, reach, -1, &hit, &w1, &w2);
        points += near;
        wrong_points += near != (expected >= 0) || (near && (hit != expected || w1 != e1 || w2 != e2));
        bvh.kernel = SK_BVH_SCALAR;
        const int scalar_near = sk_bvh_closest_point(&bvh, origin, reach, -1, &scalar_hit, &s1, &s2);
        kernels_differ += scalar_near != near || (near && (scalar_hit != hit || s1 != w1 || s2 != w2));
    }
    CHECK_IN("the hierarchy's nearest hits are brute force's", wrong_hits == 0);
    CHECK_IN("the hierarchy's closest points are brute force's", wrong_points == 0);
    CHECK_IN("the scalar and SSE2 walks agree bit for bit", kernels_differ == 0);
    CHECK_IN("the queries hit and miss both", hits > 400 && hits < 3600 && points > 400 && points < 3600);
    sk_bvh_free(&bvh);
    for (size_t t = 0; t < s.T; ++t)
        sk_bvh_free(&single[t]);
    free(single);
}

int main(void)
{
    test_program_name = "test_bake";
    test_tangents();
    test_self_and_bump();
    test_coverage_and_margin();
    test_failures();
    test_grazing_normals();
    test_hierarchy();
    test_tangent_map();
    return finish_tests();
}
