/*
 * Standalone tests of the progressive-mesh step sk_simplify (csrc/skinkit.h, level of detail): a flat chart down
 * to two triangles, redundant influences removed at zero cost, a chain of calls equal to one call, and each
 * refusal rule (flip, chart, seam, link, locked) on a mesh built to trigger it. Runs under ASan/UBSan.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "skinkit.h"
#include "test_support.h"

/* Two bones: the root and a child rotating about z by up to 0.5 rad (sampled), its joint at (0.5, 0, 0). */
typedef struct stats2 {
    double local[2 * 16], gram[2 * 16];
    int32_t parents[2];
    sk_pose_statistics statistics;
} stats2;

static void make_stats(stats2 *s)
{
    enum { SAMPLES = 16 };
    double local[SAMPLES * 2 * 16];
    memset(local, 0, sizeof local);
    for (int k = 0; k < SAMPLES; ++k) {
        double *root = local + 32 * k, *child = root + 16;
        for (int d = 0; d < 4; ++d)
            root[5 * d] = child[5 * d] = 1.0;
        const double a = 0.5 * sin(1.7 * k);
        child[0] = cos(a), child[1] = -sin(a), child[4] = sin(a), child[5] = cos(a), child[3] = 0.5;
    }
    s->parents[0] = -1, s->parents[1] = 0;
    sk_error error;
    CHECK(sk_joint_statistics(s->local, s->gram, local, s->parents, SAMPLES, 2, &error) == SK_OK);
    s->statistics = (sk_pose_statistics){s->local, s->gram, s->parents, 2};
}

/* An n x n grid on [0, 1]^2 with z = curvature * (x^2 + y^2); every vertex rigid on bone 0, plus (redundant)
 * a zero influence on bone 1. uv = (x, y), plus offset_uv for x > split (a second chart) when split < 1. */
typedef struct grid {
    size_t n, V, T, I;
    double *rest, *uv, *coords;
    int32_t *tri, *offsets, *bones, *charts;
} grid;

static grid make_grid(size_t n, double curvature, double split)
{
    grid g = {n, n * n, 2 * (n - 1) * (n - 1), 2 * n * n, NULL, NULL, NULL, NULL, NULL, NULL, NULL};
    g.rest = allocate(3 * g.V, sizeof(double));
    g.uv = allocate(6 * g.T, sizeof(double));
    g.coords = allocate(4 * g.I, sizeof(double));
    g.tri = allocate(3 * g.T, sizeof(int32_t));
    g.offsets = allocate(g.V + 1, sizeof(int32_t));
    g.bones = allocate(g.I, sizeof(int32_t));
    g.charts = allocate(g.T, sizeof(int32_t));
    for (size_t i = 0; i < n; ++i)
        for (size_t j = 0; j < n; ++j) {
            const size_t v = i * n + j;
            const double x = (double)j / (double)(n - 1), y = (double)i / (double)(n - 1);
            g.rest[3 * v] = x, g.rest[3 * v + 1] = y, g.rest[3 * v + 2] = curvature * (x * x + y * y);
            g.offsets[v] = (int32_t)(2 * v);
            g.bones[2 * v] = 0, g.bones[2 * v + 1] = 1;
            double *p = g.coords + 8 * v;
            p[0] = g.rest[3 * v], p[1] = g.rest[3 * v + 1], p[2] = g.rest[3 * v + 2], p[3] = 1.0;
            p[4] = p[5] = p[6] = p[7] = 0.0;
        }
    g.offsets[g.V] = (int32_t)g.I;
    size_t t = 0;
    for (size_t i = 0; i + 1 < n; ++i)
        for (size_t j = 0; j + 1 < n; ++j) {
            const int32_t a = (int32_t)(i * n + j), b = a + 1, c = a + (int32_t)n, d = c + 1;
            const int32_t quads[2][3] = {{a, b, d}, {a, d, c}};
            for (int q = 0; q < 2; ++q, ++t) {
                double cx = 0.0;
                for (int k = 0; k < 3; ++k)
                    cx += g.rest[3 * quads[q][k]] / 3.0;
                g.charts[t] = cx > split;
                for (int k = 0; k < 3; ++k) {
                    g.tri[3 * t + k] = quads[q][k];
                    g.uv[6 * t + 2 * k] = g.rest[3 * quads[q][k]] + (g.charts[t] ? 2.0 : 0.0);
                    g.uv[6 * t + 2 * k + 1] = g.rest[3 * quads[q][k] + 1];
                }
            }
        }
    return g;
}

static void free_grid(grid *g)
{
    free(g->rest), free(g->uv), free(g->coords), free(g->tri), free(g->offsets), free(g->bones), free(g->charts);
}

typedef struct result {
    int32_t *tri, *origin, *map, *offsets, *bones;
    double *uv, *coords;
    sk_simplify_report report;
    sk_status status;
} result;

static result run(const grid *g, const stats2 *s, const int32_t *tri, size_t T, const double *uv, const int32_t *charts,
                  const int32_t *offsets, const int32_t *bones, const double *coords, size_t I,
                  const unsigned char *locked, sk_simplify_options options)
{
    result r;
    r.tri = allocate(3 * T, sizeof(int32_t)), r.origin = allocate(T, sizeof(int32_t));
    r.map = allocate(g->V, sizeof(int32_t)), r.offsets = allocate(g->V + 1, sizeof(int32_t));
    r.bones = allocate(I ? I : 1, sizeof(int32_t)), r.uv = allocate(6 * T, sizeof(double));
    r.coords = allocate(4 * (I ? I : 1), sizeof(double));
    const sk_triangle_mesh mesh = {tri, T, g->V};
    const sk_influences inf = {offsets, bones, g->V, I};
    sk_error error;
    r.status = sk_simplify(r.tri, r.origin, uv ? r.uv : NULL, NULL, r.map, r.offsets, r.bones, r.coords, &r.report, &mesh,
                           g->rest, &inf, coords, &s->statistics, uv, charts, NULL, locked, &options, NULL, NULL,
                           &error);
    if (r.status != SK_OK)
        printf("sk_simplify: %s\n", error.message);
    return r;
}

static void free_result(result *r)
{
    free(r->tri), free(r->origin), free(r->map), free(r->offsets), free(r->bones), free(r->uv), free(r->coords);
}

static double uv_area(const double *uv)
{
    return (uv[2] - uv[0]) * (uv[5] - uv[1]) - (uv[4] - uv[0]) * (uv[3] - uv[1]);
}

static void test_flat_grid_to_two(void)
{
    stats2 s;
    make_stats(&s);
    grid g = make_grid(7, 0.0, 2.0);
    const sk_simplify_options options = {2, 0, SK_LOD_METRIC_ANIMATION, 0, 1e-6};
    result r = run(&g, &s, g.tri, g.T, g.uv, NULL, g.offsets, g.bones, g.coords, g.I, NULL, options);
    CHECK(r.status == SK_OK);
    CHECK(r.report.triangle_count == 2);
    CHECK(r.report.vertex_count == 4);
    CHECK(r.report.epsilon < 1e-12);
    for (size_t t = 0; t < r.report.triangle_count; ++t)
        CHECK(uv_area(r.uv + 6 * t) > 0.0);
    /* the four corners survive */
    const int32_t corners[4] = {0, 6, 42, 48};
    for (int c = 0; c < 4; ++c)
        CHECK(r.map[corners[c]] == corners[c]);
    CHECK(r.report.refused_seam > 0); /* the corners and the boundary off its line */
    const sk_triangle_mesh out = {r.tri, r.report.triangle_count, g.V};
    CHECK(sk_validate_surface(&out, NULL) == SK_OK);
    free_result(&r);
    free_grid(&g);
}

static void test_redundant_influences(void)
{
    stats2 s;
    make_stats(&s);
    grid g = make_grid(6, 0.4, 2.0);
    const sk_simplify_options options = {0, g.V, SK_LOD_METRIC_ANIMATION, 1, 1e-6};
    result r = run(&g, &s, g.tri, g.T, g.uv, NULL, g.offsets, g.bones, g.coords, g.I, NULL, options);
    CHECK(r.status == SK_OK);
    CHECK(r.report.influence_collapses == g.V);
    CHECK(r.report.edge_collapses == 0);
    CHECK(r.report.epsilon == 0.0);
    CHECK(r.report.influence_count == g.V);
    for (size_t v = 0; v < g.V; ++v)
        CHECK(r.offsets[v + 1] - r.offsets[v] == 1 && r.bones[r.offsets[v]] == 0);
    free_result(&r);
    free_grid(&g);
}

/* Two bones per vertex, the second's weight growing along x (0 at x = 0, 0.8 at x = 1) and its coordinates offset
 * by (-0.5, 0, 0): a grid whose deviation differs across it. */
static void blend_along_x(grid *g)
{
    for (size_t v = 0; v < g->V; ++v) {
        const double w = g->rest[3 * v] * 0.8;
        double *p = g->coords + 8 * v;
        for (int c = 0; c < 3; ++c)
            p[c] = (1 - w) * g->rest[3 * v + (size_t)c];
        p[3] = 1 - w;
        p[4] = w * (g->rest[3 * v] - 0.5), p[5] = w * g->rest[3 * v + 1], p[6] = w * g->rest[3 * v + 2], p[7] = w;
    }
}

/* Two calls (to 40 triangles, then to 12) against one call to 12, with influence collapses on. */
static void test_chain_equals_one_call(void)
{
    stats2 s;
    make_stats(&s);
    grid g = make_grid(9, 0.5, 0.5);
    /* a non-rigid model: bone 1's weight grows with x */
    blend_along_x(&g);
    const sk_simplify_options first = {40, 0, SK_LOD_METRIC_ANIMATION, 1, 1e-6};
    const sk_simplify_options second = {12, 0, SK_LOD_METRIC_ANIMATION, 1, 1e-6};
    result a = run(&g, &s, g.tri, g.T, g.uv, g.charts, g.offsets, g.bones, g.coords, g.I, NULL, first);
    CHECK(a.status == SK_OK);
    int32_t *charts_a = allocate(a.report.triangle_count, sizeof(int32_t));
    for (size_t t = 0; t < a.report.triangle_count; ++t)
        charts_a[t] = g.charts[a.origin[t]];
    const size_t ia = (size_t)a.offsets[g.V];
    result b = run(&g, &s, a.tri, a.report.triangle_count, a.uv, charts_a, a.offsets, a.bones, a.coords, ia, NULL,
                   second);
    result c = run(&g, &s, g.tri, g.T, g.uv, g.charts, g.offsets, g.bones, g.coords, g.I, NULL, second);
    CHECK(b.status == SK_OK && c.status == SK_OK);
    CHECK(b.report.triangle_count == c.report.triangle_count);
    CHECK(b.report.influence_count == c.report.influence_count);
    CHECK(a.report.edge_collapses + b.report.edge_collapses == c.report.edge_collapses);
    CHECK(a.report.influence_collapses + b.report.influence_collapses == c.report.influence_collapses);
    CHECK(fmax(a.report.epsilon, b.report.epsilon) == c.report.epsilon);
    int same = b.report.triangle_count == c.report.triangle_count;
    for (size_t t = 0; same && t < c.report.triangle_count; ++t) {
        same &= memcmp(b.tri + 3 * t, c.tri + 3 * t, 3 * sizeof(int32_t)) == 0;
        same &= a.origin[b.origin[t]] == c.origin[t];
        same &= memcmp(b.uv + 6 * t, c.uv + 6 * t, 6 * sizeof(double)) == 0;
    }
    CHECK(same);
    int maps = 1;
    for (size_t v = 0; v < g.V; ++v)
        maps &= b.map[a.map[v]] == c.map[v];
    CHECK(maps);
    CHECK(memcmp(b.offsets, c.offsets, (g.V + 1) * sizeof(int32_t)) == 0);
    CHECK(memcmp(b.coords, c.coords, 4 * (size_t)c.offsets[g.V] * sizeof(double)) == 0);
    /* the charts never merge: every triangle stays on its side of x = 0.5 in UV (chart 1 is offset by 2) */
    int kept = 1;
    for (size_t t = 0; t < c.report.triangle_count; ++t)
        for (int k = 0; k < 3; ++k)
            kept &= g.charts[c.origin[t]] ? c.uv[6 * t + 2 * k] >= 2.5 - 1e-12 : c.uv[6 * t + 2 * k] <= 0.5 + 1e-12;
    CHECK(kept);
    CHECK(c.report.refused_chart > 0);
    free(charts_a);
    free_result(&a), free_result(&b), free_result(&c);
    free_grid(&g);
}

static int cancel_at_once(void *user, double fraction)
{
    (void)fraction;
    ++*(int *)user;
    return 1;
}

/* sk_simplify_chain to 40 then 12 triangles: each level equals one sk_simplify from the input to its target; the
 * CSR's level rows follow one another; bad options and a cancel fail cleanly. */
static void test_simplify_chain(void)
{
    stats2 s;
    make_stats(&s);
    grid g = make_grid(9, 0.5, 0.5);
    blend_along_x(&g);
    enum { L = 2 };
    const size_t V = g.V, T = g.T, I = g.I;
    int32_t *tri = allocate(L * 3 * T, sizeof(int32_t)), *origin = allocate(L * T, sizeof(int32_t));
    int32_t *map = allocate(L * V, sizeof(int32_t)), *offsets = allocate(L * V + 1, sizeof(int32_t));
    int32_t *bones = allocate(L * I, sizeof(int32_t)), counts[5 * L];
    double *uv = allocate(L * 6 * T, sizeof(double)), *coords = allocate(L * 4 * I, sizeof(double)), epsilon[L];
    const int32_t targets[L] = {60, 36};
    sk_simplify_chain_options options = {L, targets, NULL, SK_LOD_METRIC_ANIMATION, 1, 1e-6};
    sk_simplify_chain_report report;
    const sk_triangle_mesh mesh = {g.tri, T, V};
    const sk_influences inf = {g.offsets, g.bones, V, I};
    sk_error error;
    CHECK(sk_simplify_chain(tri, origin, uv, NULL, map, offsets, bones, coords, counts, epsilon, &report, &mesh, g.rest,
                            &inf, g.coords, &s.statistics, g.uv, g.charts, NULL, NULL, &options, NULL, NULL,
                            &error) == SK_OK);
    CHECK(report.level_count == L && !report.exhausted);
    const sk_simplify_options singles[L] = {{60, 0, SK_LOD_METRIC_ANIMATION, 1, 1e-6},
                                            {36, 0, SK_LOD_METRIC_ANIMATION, 1, 1e-6}};
    size_t edges = 0;
    for (size_t l = 0; l < L; ++l) {
        result one = run(&g, &s, g.tri, T, g.uv, g.charts, g.offsets, g.bones, g.coords, I, NULL, singles[l]);
        CHECK(one.status == SK_OK);
        const size_t n = one.report.triangle_count;
        CHECK((size_t)counts[5 * l] == n && (size_t)counts[5 * l + 2] == one.report.influence_count);
        CHECK((size_t)counts[5 * l + 1] == one.report.vertex_count);
        CHECK(epsilon[l] == one.report.epsilon);
        CHECK(memcmp(tri + 3 * T * l, one.tri, 3 * n * sizeof(int32_t)) == 0);
        CHECK(memcmp(origin + T * l, one.origin, n * sizeof(int32_t)) == 0);
        CHECK(memcmp(uv + 6 * T * l, one.uv, 6 * n * sizeof(double)) == 0);
        CHECK(memcmp(map + V * l, one.map, V * sizeof(int32_t)) == 0);
        const int32_t *rows = offsets + V * l, shift = rows[0];
        int same = 1;
        for (size_t v = 0; v <= V; ++v)
            same &= rows[v] - shift == one.offsets[v];
        CHECK(same);
        CHECK(memcmp(bones + shift, one.bones, (size_t)one.offsets[V] * sizeof(int32_t)) == 0);
        CHECK(memcmp(coords + 4 * (size_t)shift, one.coords, 4 * (size_t)one.offsets[V] * sizeof(double)) == 0);
        edges += (size_t)counts[5 * l + 3];
        CHECK(edges == one.report.edge_collapses);
        free_result(&one);
    }
    CHECK(offsets[0] == 0 && report.edge_collapses == edges);
    /* bad options */
    options.level_count = 0;
    CHECK(sk_simplify_chain(tri, origin, uv, NULL, map, offsets, bones, coords, counts, epsilon, &report, &mesh, g.rest,
                            &inf, g.coords, &s.statistics, g.uv, g.charts, NULL, NULL, &options, NULL, NULL,
                            &error) == SK_ERROR_ARGUMENT);
    CHECK(strstr(error.message, "level_count") != NULL);
    const int32_t negative[L] = {60, -3};
    options.level_count = L, options.target_triangles = negative;
    CHECK(sk_simplify_chain(tri, origin, uv, NULL, map, offsets, bones, coords, counts, epsilon, &report, &mesh, g.rest,
                            &inf, g.coords, &s.statistics, g.uv, g.charts, NULL, NULL, &options, NULL, NULL,
                            &error) == SK_ERROR_ARGUMENT);
    CHECK(strstr(error.message, "level 1") != NULL);
    CHECK(sk_simplify_chain(tri, origin, uv, NULL, map, offsets, bones, coords, counts, epsilon, NULL, &mesh, g.rest,
                            &inf, g.coords, &s.statistics, g.uv, g.charts, NULL, NULL, &options, NULL, NULL,
                            &error) == SK_ERROR_ARGUMENT);
    /* no targets: each level halves the influences of the one before (a cancel first) */
    options.target_triangles = NULL;
    int calls = 0;
    CHECK(sk_simplify_chain(tri, origin, uv, NULL, map, offsets, bones, coords, counts, epsilon, &report, &mesh, g.rest,
                            &inf, g.coords, &s.statistics, g.uv, g.charts, NULL, NULL, &options, cancel_at_once,
                            &calls, &error) == SK_ERROR_CANCELLED);
    CHECK(calls == 1 && strstr(error.message, "cancel") != NULL);
    CHECK(sk_simplify_chain(tri, origin, uv, NULL, map, offsets, bones, coords, counts, epsilon, &report, &mesh, g.rest,
                            &inf, g.coords, &s.statistics, g.uv, g.charts, NULL, NULL, &options, NULL, NULL,
                            &error) == SK_OK);
    CHECK(report.level_count == L && counts[2] <= (int32_t)I / 2 && counts[7] <= counts[2] / 2 && counts[7] >= 1);
    free(tri), free(origin), free(map), free(offsets), free(bones), free(uv), free(coords);
    free_grid(&g);
}

/* A star of 8 faces whose link alternates radius 1 and 0.3: every collapse of its centre flips a face, and
 * the boundary is nowhere straight. */
static void test_flip(void)
{
    stats2 s;
    make_stats(&s);
    grid g = make_grid(4, 0.0, 2.0); /* only for the influences' storage (16 vertices) */
    free(g.rest), free(g.tri), free(g.uv);
    g.V = 11, g.T = 10;
    g.rest = allocate(33, sizeof(double));
    g.tri = allocate(30, sizeof(int32_t));
    memset(g.rest, 0, 33 * sizeof(double));
    for (int k = 0; k < 10; ++k) {
        const double deg = 3.14159265358979 / 180;
        const double r = k % 2 ? 0.2 : 1.0, a = (k / 2) * 72 * deg + (k % 2) * 40 * deg;
        g.rest[3 * (k + 1)] = r * cos(a), g.rest[3 * (k + 1) + 1] = r * sin(a);
        g.tri[3 * k] = 0, g.tri[3 * k + 1] = k + 1, g.tri[3 * k + 2] = (k + 1) % 10 + 1;
    }
    for (size_t v = 0; v < g.V; ++v)
        memcpy(g.coords + 8 * v, (double[4]){g.rest[3 * v], g.rest[3 * v + 1], 0.0, 1.0}, 4 * sizeof(double));
    g.uv = allocate(60, sizeof(double));
    for (int t = 0; t < 10; ++t)
        for (int k = 0; k < 3; ++k)
            g.uv[6 * t + 2 * k] = g.rest[3 * g.tri[3 * t + k]], g.uv[6 * t + 2 * k + 1] = g.rest[3 * g.tri[3 * t + k] + 1];
    const sk_simplify_options options = {1, 0, SK_LOD_METRIC_ANIMATION, 0, 1e-6};
    for (int with_uv = 0; with_uv < 2; ++with_uv) {
        result r = run(&g, &s, g.tri, g.T, with_uv ? g.uv : NULL, NULL, g.offsets, g.bones, g.coords, 2 * g.V, NULL,
                       options);
        CHECK(r.status == SK_OK);
        CHECK(r.report.exhausted == 1);
        CHECK(r.report.triangle_count == 10);
        CHECK(r.report.refused_flip == 10);
        free_result(&r);
    }
    free_grid(&g);
}

/* A closed octahedron: collapses go down to a tetrahedron, whose collapses the link rule refuses. */
static void test_link(void)
{
    stats2 s;
    make_stats(&s);
    grid g = make_grid(3, 0.0, 2.0);
    free(g.rest), free(g.tri);
    g.V = 6, g.T = 8;
    const double rest[18] = {1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1, 0, 0, -1};
    const int32_t tri[24] = {0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5};
    g.rest = allocate(18, sizeof(double));
    g.tri = allocate(24, sizeof(int32_t));
    memcpy(g.rest, rest, sizeof rest), memcpy(g.tri, tri, sizeof tri);
    for (size_t v = 0; v < g.V; ++v)
        memcpy(g.coords + 8 * v, (double[4]){rest[3 * v], rest[3 * v + 1], rest[3 * v + 2], 1.0}, 4 * sizeof(double));
    const sk_simplify_options options = {1, 0, SK_LOD_METRIC_REST, 0, 1e-6};
    result r = run(&g, &s, g.tri, g.T, NULL, NULL, g.offsets, g.bones, g.coords, 2 * g.V, NULL, options);
    CHECK(r.status == SK_OK);
    CHECK(r.report.exhausted == 1);
    CHECK(r.report.triangle_count >= 4);
    CHECK(r.report.refused_link > 0);
    const sk_triangle_mesh out = {r.tri, r.report.triangle_count, g.V};
    CHECK(sk_validate_surface(&out, NULL) == SK_OK);
    free_result(&r);
    free_grid(&g);
}

/* A locked polyline across a flat grid, bent at its middle vertex: the bend survives. */
static void test_locked(void)
{
    stats2 s;
    make_stats(&s);
    grid g = make_grid(7, 0.0, 2.0);
    /* the path (1,1) -> (2,2) -> (3,3) -> (3,4) -> (3,5) as vertex indices i * 7 + j, bent at (3,3) */
    const int32_t path[5] = {8, 16, 24, 25, 26};
    unsigned char *locked = allocate(3 * g.T, 1);
    memset(locked, 0, 3 * g.T);
    size_t flagged = 0;
    for (size_t t = 0; t < g.T; ++t)
        for (int k = 0; k < 3; ++k) {
            const int32_t a = g.tri[3 * t + k], b = g.tri[3 * t + (k + 1) % 3];
            for (int e = 0; e < 4; ++e)
                if ((a == path[e] && b == path[e + 1]) || (b == path[e] && a == path[e + 1]))
                    locked[3 * t + k] = 1, ++flagged;
        }
    const sk_simplify_options options = {2, 0, SK_LOD_METRIC_ANIMATION, 0, 1e-6};
    result r = run(&g, &s, g.tri, g.T, g.uv, NULL, g.offsets, g.bones, g.coords, g.I, locked, options);
    CHECK(r.status == SK_OK);
    CHECK(r.report.exhausted == 1);
    CHECK(r.report.refused_locked > 0);
    CHECK(r.map[24] == 24 && r.map[8] == 8 && r.map[26] == 26); /* the bend and the ends */
    free(locked);
    free_result(&r);
    free_grid(&g);
    (void)flagged;
}

static void test_bad_inputs(void)
{
    stats2 s;
    make_stats(&s);
    grid g = make_grid(3, 0.0, 2.0);
    int32_t tri_out[24], origin[8], map[9], offsets_out[10], bones_out[18];
    double coords_out[72];
    sk_simplify_report report;
    const sk_triangle_mesh mesh = {g.tri, g.T, g.V};
    const sk_influences inf = {g.offsets, g.bones, g.V, g.I};
    sk_simplify_options options = {0, 0, SK_LOD_METRIC_ANIMATION, 1, 1e-6};
    EXPECT_FAILURE("no target", SK_ERROR_ARGUMENT,
                   sk_simplify(tri_out, origin, NULL, NULL, map, offsets_out, bones_out, coords_out, &report, &mesh, g.rest,
                               &inf, g.coords, &s.statistics, NULL, NULL, NULL, NULL, &options, NULL, NULL, error));
    options.target_triangles = 2, options.metric = 7;
    EXPECT_FAILURE("bad metric", SK_ERROR_ARGUMENT,
                   sk_simplify(tri_out, origin, NULL, NULL, map, offsets_out, bones_out, coords_out, &report, &mesh, g.rest,
                               &inf, g.coords, &s.statistics, NULL, NULL, NULL, NULL, &options, NULL, NULL, error));
    options.metric = SK_LOD_METRIC_ANIMATION;
    int32_t flipped[24];
    memcpy(flipped, g.tri, sizeof flipped);
    flipped[1] = g.tri[2], flipped[2] = g.tri[1];
    const sk_triangle_mesh bad = {flipped, g.T, g.V};
    EXPECT_FAILURE("orientations disagree", SK_ERROR_ARGUMENT,
                   sk_simplify(tri_out, origin, NULL, NULL, map, offsets_out, bones_out, coords_out, &report, &bad, g.rest,
                               &inf, g.coords, &s.statistics, NULL, NULL, NULL, NULL, &options, NULL, NULL, error));
    int32_t empty_offsets[10];
    memcpy(empty_offsets, g.offsets, sizeof empty_offsets);
    for (int v = 1; v <= 9; ++v)
        empty_offsets[v] = v <= 4 ? 2 * v : 2 * v - 2; /* vertex 4 has none */
    const sk_influences hole = {empty_offsets, g.bones, g.V, g.I - 2};
    EXPECT_FAILURE("vertex without influences", SK_ERROR_ARGUMENT,
                   sk_simplify(tri_out, origin, NULL, NULL, map, offsets_out, bones_out, coords_out, &report, &mesh, g.rest,
                               &hole, g.coords, &s.statistics, NULL, NULL, NULL, NULL, &options, NULL, NULL, error));
    double squashed[27];
    memcpy(squashed, g.rest, sizeof squashed);
    for (int v = 0; v < 9; ++v)
        squashed[3 * v + 1] = 0.0;
    EXPECT_FAILURE("degenerate", SK_ERROR_ARGUMENT,
                   sk_simplify(tri_out, origin, NULL, NULL, map, offsets_out, bones_out, coords_out, &report, &mesh, squashed,
                               &inf, g.coords, &s.statistics, NULL, NULL, NULL, NULL, &options, NULL, NULL, error));
    const sk_influences wrong = {g.offsets, g.bones, g.V - 1, g.I};
    EXPECT_FAILURE("vertex counts", SK_ERROR_ARGUMENT,
                   sk_simplify(tri_out, origin, NULL, NULL, map, offsets_out, bones_out, coords_out, &report, &mesh, g.rest,
                               &wrong, g.coords, &s.statistics, NULL, NULL, NULL, NULL, &options, NULL, NULL, error));
    free_grid(&g);
}

/* One chain's outputs for `levels` levels of grid g (sk_simplify_chain's layout). */
typedef struct chain_buffers {
    int32_t *tri, *origin, *map, *offsets, *bones;
    double *uv, *coords;
} chain_buffers;

static chain_buffers chain_buffers_for(const grid *g, size_t levels)
{
    return (chain_buffers){allocate(levels * 3 * g->T, sizeof(int32_t)), allocate(levels * g->T, sizeof(int32_t)),
                           allocate(levels * g->V, sizeof(int32_t)), allocate(levels * g->V + 1, sizeof(int32_t)),
                           allocate(levels * g->I, sizeof(int32_t)), allocate(levels * 6 * g->T, sizeof(double)),
                           allocate(levels * 4 * g->I, sizeof(double))};
}

static void free_chain_buffers(chain_buffers *b)
{
    free(b->tri), free(b->origin), free(b->map), free(b->offsets), free(b->bones), free(b->uv), free(b->coords);
}

/* sk_simplify_chain_tuned on grid g (its UVs and charts) into o. */
static sk_status run_tuned(const grid *g, const stats2 *s, const sk_simplify_chain_options *options,
                           const sk_simplify_tuning *tuning, chain_buffers *o, int32_t *counts, double *epsilon,
                           sk_simplify_chain_report *report, int32_t *full, sk_error *error)
{
    const sk_triangle_mesh mesh = {g->tri, g->T, g->V};
    const sk_influences inf = {g->offsets, g->bones, g->V, g->I};
    return sk_simplify_chain_tuned(o->tri, o->origin, o->uv, NULL, o->map, o->offsets, o->bones, o->coords, counts,
                                   epsilon, report, full, &mesh, g->rest, &inf, g->coords, &s->statistics, g->uv,
                                   g->charts, NULL, NULL, options, tuning, NULL, NULL, error);
}

/* sk_simplify_chain_tuned: half-edge with scale 1 gives sk_simplify_chain's bits; full collapses on a bending,
 * curved grid lower the epsilon at a triangle budget, keep every vertex's weights summing to 1, flip no UV and
 * keep the surface manifold; bad tuning is refused by name. */
static void test_tuned_chain(void)
{
    stats2 s;
    make_stats(&s);
    grid g = make_grid(9, 0.5, 2.0);
    blend_along_x(&g);
    enum { L = 2 };
    const size_t V = g.V, T = g.T, I = g.I;
    int32_t counts[2][5 * L], full[2][L];
    double epsilon[2][L];
    chain_buffers out[2] = {chain_buffers_for(&g, L), chain_buffers_for(&g, L)};
    const int32_t targets[L] = {80, 40};
    const sk_simplify_chain_options options = {L, targets, NULL, SK_LOD_METRIC_ANIMATION, 0, 1e-6};
    sk_simplify_chain_report report[2];
    const sk_triangle_mesh mesh = {g.tri, T, V};
    const sk_influences inf = {g.offsets, g.bones, V, I};
    sk_error error;
    CHECK(sk_simplify_chain(out[0].tri, out[0].origin, out[0].uv, NULL, out[0].map, out[0].offsets, out[0].bones,
                            out[0].coords, counts[0], epsilon[0], &report[0], &mesh, g.rest, &inf, g.coords,
                            &s.statistics, g.uv, g.charts, NULL, NULL, &options, NULL, NULL, &error) == SK_OK);
    sk_simplify_tuning tuning = {SK_LOD_COLLAPSE_HALF, 1.0, 0, 1};
    CHECK(run_tuned(&g, &s, &options, &tuning, &out[1], counts[1], epsilon[1], &report[1], full[1], &error) ==
          SK_OK);
    CHECK(memcmp(counts[0], counts[1], sizeof counts[0]) == 0);
    CHECK(memcmp(epsilon[0], epsilon[1], sizeof epsilon[0]) == 0);
    CHECK(memcmp(out[0].tri, out[1].tri, L * 3 * T * sizeof(int32_t)) == 0);
    CHECK(memcmp(out[0].coords, out[1].coords, 4 * (size_t)out[0].offsets[L * V] * sizeof(double)) == 0);
    CHECK(full[1][0] == 0 && full[1][1] == 0);
    tuning.collapse = SK_LOD_COLLAPSE_FULL;
    CHECK(run_tuned(&g, &s, &options, &tuning, &out[1], counts[1], epsilon[1], &report[1], full[1], &error) ==
          SK_OK);
    CHECK(report[1].level_count == L && full[1][0] > 0);
    for (size_t l = 0; l < L; ++l) {
        CHECK(counts[1][5 * l] <= targets[l] && epsilon[1][l] < epsilon[0][l]);
        const size_t n = (size_t)counts[1][5 * l];
        int unflipped = 1;
        for (size_t t = 0; t < n; ++t)
            unflipped &= uv_area(out[1].uv + 6 * T * l + 6 * t) > 0.0;
        CHECK(unflipped);
        const sk_triangle_mesh level_mesh = {out[1].tri + 3 * T * l, n, V};
        CHECK(sk_validate_surface(&level_mesh, NULL) == SK_OK);
        const int32_t *rows = out[1].offsets + V * l;
        int affine = 1;
        for (size_t v = 0; v < V; ++v) {
            double sum = 0.0;
            for (int32_t k = rows[v]; k < rows[v + 1]; ++k)
                sum += out[1].coords[4 * (size_t)k + 3];
            affine &= rows[v] == rows[v + 1] || fabs(sum - 1.0) < 1e-12;
        }
        CHECK(affine);
    }
    tuning.collapse = 3;
    EXPECT_FAILURE("collapse", SK_ERROR_ARGUMENT,
                   run_tuned(&g, &s, &options, &tuning, &out[1], counts[1], epsilon[1], &report[1], full[1], error));
    tuning = (sk_simplify_tuning){SK_LOD_COLLAPSE_AUTO, 0.0, 0, 1};
    EXPECT_FAILURE("influence_cost_scale", SK_ERROR_ARGUMENT,
                   run_tuned(&g, &s, &options, &tuning, &out[1], counts[1], epsilon[1], &report[1], full[1], error));
    tuning = (sk_simplify_tuning){SK_LOD_COLLAPSE_AUTO, 1.0, 0, -1};
    EXPECT_FAILURE("thread_count", SK_ERROR_ARGUMENT,
                   run_tuned(&g, &s, &options, &tuning, &out[1], counts[1], epsilon[1], &report[1], full[1], error));
    free_chain_buffers(&out[0]), free_chain_buffers(&out[1]);
    free_grid(&g);
}

/* The candidates costed on two threads (thread_count 2 starts the helper at any size), full collapses and influence
 * collapses in the queue: every level the same bits as on one thread. */
static void test_two_threads(void)
{
    stats2 s;
    make_stats(&s);
    grid g = make_grid(50, 0.5, 2.0);
    blend_along_x(&g);
    enum { L = 4 };
    const size_t V = g.V, T = g.T;
    int32_t counts[2][5 * L], full[2][L];
    double epsilon[2][L];
    chain_buffers out[2] = {chain_buffers_for(&g, L), chain_buffers_for(&g, L)};
    const int32_t targets[L] = {4000, 2000, 1000, 500};
    const sk_simplify_chain_options options = {L, targets, NULL, SK_LOD_METRIC_ANIMATION, 1, 1e-6};
    sk_simplify_chain_report report[2];
    sk_error error;
    for (int k = 0; k < 2; ++k) {
        const sk_simplify_tuning tuning = {SK_LOD_COLLAPSE_AUTO, 1.0, 1, k + 1};
        CHECK(run_tuned(&g, &s, &options, &tuning, &out[k], counts[k], epsilon[k], &report[k], full[k], &error) ==
              SK_OK);
    }
    CHECK(report[0].level_count == L && report[1].level_count == L && full[0][0] > 0);
    CHECK(memcmp(counts[0], counts[1], sizeof counts[0]) == 0);
    CHECK(memcmp(epsilon[0], epsilon[1], sizeof epsilon[0]) == 0);
    CHECK(memcmp(full[0], full[1], sizeof full[0]) == 0);
    CHECK(memcmp(out[0].tri, out[1].tri, L * 3 * T * sizeof(int32_t)) == 0);
    CHECK(memcmp(out[0].map, out[1].map, L * V * sizeof(int32_t)) == 0);
    CHECK(memcmp(out[0].offsets, out[1].offsets, (L * V + 1) * sizeof(int32_t)) == 0);
    CHECK(memcmp(out[0].bones, out[1].bones, (size_t)out[0].offsets[L * V] * sizeof(int32_t)) == 0);
    CHECK(memcmp(out[0].coords, out[1].coords, 4 * (size_t)out[0].offsets[L * V] * sizeof(double)) == 0);
    free_chain_buffers(&out[0]), free_chain_buffers(&out[1]);
    free_grid(&g);
}

/* sk_lod_refit: a level equal to the mesh with the mesh's own coordinates stays where it is; perturbed, it moves
 * back (the grid's rigid model is on bone 0, so the perturbed rest positions must come back towards the rest); the
 * same bits on one and two threads; bad arguments are named. */
static void test_refit(void)
{
    stats2 s;
    make_stats(&s);
    grid g = make_grid(6, 0.3, 1.0);
    const sk_triangle_mesh mesh = {g.tri, g.T, g.V};
    const sk_influences inf = {g.offsets, g.bones, g.V, g.I};
    const sk_lod_refit_options options = {0.1, 50, 1e-12, 1};
    sk_lod_refit_report report;
    double *out = allocate(4 * g.I, sizeof(double)), *two = allocate(4 * g.I, sizeof(double));
    double *moved = allocate(4 * g.I, sizeof(double));
    EXPECT_SUCCESS("exact level", sk_lod_refit(out, &report, &mesh, g.rest, &inf, g.coords, &mesh, g.rest, &inf,
                                              g.coords, &s.statistics, &options, NULL, NULL, error));
    double largest = 0.0;
    for (size_t k = 0; k < 4 * g.I; ++k)
        largest = fmax(largest, fabs(out[k] - g.coords[k]));
    CHECK(largest < 1e-12);
    CHECK(report.samples == g.T && report.unmatched == 0);
    for (size_t k = 0; k < 4 * g.I; ++k)
        moved[k] = g.coords[k] + ((k % 8) < 3 ? 0.02 * sin(3.0 * (double)k) : 0.0); /* bone 0's position part */
    EXPECT_SUCCESS("perturbed", sk_lod_refit(out, &report, &mesh, g.rest, &inf, moved, &mesh, g.rest, &inf, g.coords,
                                            &s.statistics, &options, NULL, NULL, error));
    double before = 0.0, after = 0.0;
    for (size_t k = 0; k < 4 * g.I; ++k)
        before += (moved[k] - g.coords[k]) * (moved[k] - g.coords[k]),
        after += (out[k] - g.coords[k]) * (out[k] - g.coords[k]);
    CHECK(after < 0.5 * before);
    const sk_lod_refit_options two_threads = {0.1, 50, 1e-12, 2};
    EXPECT_SUCCESS("two threads", sk_lod_refit(two, &report, &mesh, g.rest, &inf, moved, &mesh, g.rest, &inf,
                                              g.coords, &s.statistics, &two_threads, NULL, NULL, error));
    CHECK(memcmp(out, two, 4 * g.I * sizeof(double)) == 0);
    const sk_lod_refit_options negative = {-1.0, 4, 1e-3, 1};
    EXPECT_FAILURE("negative pull", SK_ERROR_ARGUMENT,
                   sk_lod_refit(out, &report, &mesh, g.rest, &inf, moved, &mesh, g.rest, &inf, g.coords,
                                &s.statistics, &negative, NULL, NULL, error));
    g.tri[4] = (int32_t)g.V; /* out of range */
    EXPECT_FAILURE("bad level index", SK_ERROR_INDEX,
                   sk_lod_refit(out, &report, &mesh, g.rest, &inf, moved, &mesh, g.rest, &inf, g.coords,
                                &s.statistics, &options, NULL, NULL, error));
    free(out), free(two), free(moved);
    free_grid(&g);
}

int main(void)
{
    test_program_name = "test_lod_chain";
    test_flat_grid_to_two();
    test_redundant_influences();
    test_chain_equals_one_call();
    test_simplify_chain();
    test_tuned_chain();
    test_two_threads();
    test_flip();
    test_link();
    test_locked();
    test_bad_inputs();
    test_refit();
    return finish_tests();
}
