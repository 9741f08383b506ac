/*
 * Standalone tests of flattening and stretch (csrc/skinkit.h, "Flattening"): sk_flatten,
 * sk_triangle_stretch and sk_mesh_stretch, under the sanitizers (packing: test_pack.c).
 *
 * Meshes are built here from parametric surfaces. The references are independent of the core: developable
 * surfaces (plane, cylinder, cone) have an exact isometric flattening, so every uv edge must have its metric
 * length; overlaps are looked for by brute force over every pair of boundary edges or uv triangles.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "skinkit.h"
#include "test_support.h"

#define PI 3.14159265358979323846

typedef struct surface_mesh {
    size_t vertex_count, triangle_count;
    double *positions;  /* 3 per vertex */
    int32_t *triangles; /* 3 per triangle, counterclockwise seen from the side the parameters' normal points */
    unsigned char *corners;
} surface_mesh;

typedef void (*surface)(double point[3], double s, double t);

/* A (columns x rows) grid over [0, 1]^2 mapped by `f`, two triangles per cell, its four corners marked. */
static surface_mesh grid_mesh(surface f, size_t columns, size_t rows)
{
    surface_mesh m = {(columns + 1) * (rows + 1), 2 * columns * rows, NULL, NULL, NULL};
    m.positions = allocate(3 * m.vertex_count, sizeof(double));
    m.triangles = allocate(3 * m.triangle_count, sizeof(int32_t));
    m.corners = allocate(m.vertex_count, 1);
    for (size_t j = 0; j <= rows; ++j)
        for (size_t i = 0; i <= columns; ++i)
            f(m.positions + 3 * (j * (columns + 1) + i), (double)i / (double)columns, (double)j / (double)rows);
    size_t t = 0;
    for (size_t j = 0; j < rows; ++j)
        for (size_t i = 0; i < columns; ++i) {
            const int32_t a = (int32_t)(j * (columns + 1) + i), b = a + 1, c = a + (int32_t)columns + 1, d = c + 1;
            const int32_t cell[6] = {a, b, d, a, d, c};
            memcpy(m.triangles + 3 * t, cell, sizeof cell);
            t += 2;
        }
    m.corners[0] = m.corners[columns] = m.corners[rows * (columns + 1)] = m.corners[m.vertex_count - 1] = 1;
    return m;
}

static void free_surface(surface_mesh *m)
{
    free(m->positions);
    free(m->triangles);
    free(m->corners);
}

static double *edge_lengths(const surface_mesh *m, const double scale[3])
{
    double *lengths = allocate(3 * m->triangle_count, sizeof(double));
    for (size_t t = 0; t < m->triangle_count; ++t)
        for (int k = 0; k < 3; ++k) {
            const double *p = m->positions + 3 * (size_t)m->triangles[3 * t + (size_t)k];
            const double *q = m->positions + 3 * (size_t)m->triangles[3 * t + (size_t)(k + 1) % 3];
            double sum = 0.0;
            for (int axis = 0; axis < 3; ++axis)
                sum += pow(scale[axis] * (q[axis] - p[axis]), 2);
            lengths[3 * t + (size_t)k] = sum;
        }
    return lengths;
}

static const double unit_scale[3] = {1.0, 1.0, 1.0};

static void plane(double p[3], double s, double t)
{
    p[0] = 2.0 * pow(s, 1.5) + 0.5 * t; /* a parallelogram, unevenly spaced: not a regular grid */
    p[1] = 1.5 * t;
    p[2] = 0.0;
}

static void cylinder_patch(double p[3], double s, double t)
{
    p[0] = cos(1.5 * PI * s);
    p[1] = sin(1.5 * PI * s);
    p[2] = 2.0 * t;
}

static void cone_patch(double p[3], double s, double t)
{
    const double r = 0.5 + t, angle = PI * s, half_angle = 0.6;
    p[0] = r * sin(half_angle) * cos(angle);
    p[1] = r * sin(half_angle) * sin(angle);
    p[2] = r * cos(half_angle);
}

static void bumpy_patch(double p[3], double s, double t)
{
    p[0] = 2.0 * s;
    p[1] = 2.0 * t;
    p[2] = 0.4 * sin(3.0 * s) * cos(4.0 * t) + 0.3 * s * t;
}

/* Most of a hemisphere: the square mapped to the disc (elliptical grid mapping), lifted onto the sphere. */
static void hemisphere(double p[3], double s, double t)
{
    const double x = 2 * s - 1, y = 2 * t - 1;
    const double u = 0.97 * x * sqrt(1 - y * y / 2), v = 0.97 * y * sqrt(1 - x * x / 2);
    p[0] = u;
    p[1] = v;
    p[2] = sqrt(fmax(1 - u * u - v * v, 0.0));
}

/* A band around a wavy cone (z = 0.5 r sin 3 angle): developable, and its development turns through more than
 * a full circle, so the flattened boundary must cross itself. */
static void wavy_cone_band(double p[3], double s, double t)
{
    const double angle = 1.9 * PI * s, r = 1.0 + 0.4 * t;
    p[0] = r * cos(angle);
    p[1] = r * sin(angle);
    p[2] = 0.5 * r * sin(3 * angle);
}

static sk_flatten_options options_with(int straight, int optimise, int threads)
{
    return (sk_flatten_options){straight, optimise, 4.0, 50, threads};
}

typedef struct flattened {
    double *uv;
    int32_t *charts;
    sk_flatten_report report;
    sk_status status;
} flattened;

static flattened flatten_mesh(const surface_mesh *m, const double *lengths, const int32_t *charts,
                              sk_flatten_options options)
{
    flattened f = {allocate(6 * m->triangle_count, sizeof(double)), allocate(m->triangle_count, sizeof(int32_t)),
                   {0}, SK_OK};
    int32_t *one_chart = allocate(m->triangle_count, sizeof(int32_t));
    sk_error error = stale_error();
    f.status = sk_flatten(f.uv, f.charts, &f.report,
                          &(sk_triangle_mesh){m->triangles, m->triangle_count, m->vertex_count}, lengths,
                          charts ? charts : one_chart, m->corners, &options, &error);
    if (f.status != SK_OK)
        fprintf(stderr, "sk_flatten: %s\n", error.message);
    free(one_chart);
    return f;
}

static void free_flattened(flattened *f)
{
    free(f->uv);
    free(f->charts);
}

static double mesh_stretch(const double *uv, const double *lengths, size_t triangle_count)
{
    double stretch = NAN;
    sk_error error = stale_error();
    CHECK(sk_mesh_stretch(&stretch, uv, lengths, triangle_count, &error) == SK_OK);
    return stretch;
}

/* The largest relative difference between a uv edge's squared length and its metric one. */
static double isometry_error(const double *uv, const double *lengths, size_t triangle_count)
{
    double worst = 0.0;
    for (size_t t = 0; t < triangle_count; ++t)
        for (int k = 0; k < 3; ++k) {
            const double *p = uv + 6 * t + 2 * k, *q = uv + 6 * t + 2 * ((k + 1) % 3);
            const double uv_sq = pow(q[0] - p[0], 2) + pow(q[1] - p[1], 2);
            worst = fmax(worst, fabs(uv_sq - lengths[3 * t + (size_t)k]) / lengths[3 * t + (size_t)k]);
        }
    return worst;
}

static size_t invalid_triangles(const double *uv, const double *lengths, size_t triangle_count)
{
    double *stretch = allocate(triangle_count, sizeof(double));
    sk_error error = stale_error();
    CHECK(sk_triangle_stretch(stretch, uv, lengths, triangle_count, &error) == SK_OK);
    size_t invalid = 0;
    for (size_t t = 0; t < triangle_count; ++t)
        invalid += !isfinite(stretch[t]);
    free(stretch);
    return invalid;
}

/* ---------------------------------------------------------------------------------------------
 * Independent overlap checks, by brute force
 * ------------------------------------------------------------------------------------------- */

static double orient(const double *a, const double *b, const double *c)
{
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
}

static int proper_crossing(const double *a, const double *b, const double *c, const double *d)
{
    return orient(a, b, c) * orient(a, b, d) < 0 && orient(c, d, a) * orient(c, d, b) < 0;
}

/* Whether two boundary edges of one chart cross: boundary edges are those with no twin in the same chart. */
static int chart_boundary_crosses(const surface_mesh *m, const double *uv, const int32_t *charts, int32_t chart)
{
    size_t count = 0;
    size_t *edges = allocate(3 * m->triangle_count, sizeof(size_t)); /* 3 t + k */
    for (size_t t = 0; t < m->triangle_count; ++t) {
        if (charts[t] != chart)
            continue;
        for (int k = 0; k < 3; ++k) {
            const int32_t a = m->triangles[3 * t + (size_t)k], b = m->triangles[3 * t + (size_t)(k + 1) % 3];
            int twin = 0;
            for (size_t u = 0; u < m->triangle_count && !twin; ++u)
                for (int l = 0; l < 3 && charts[u] == chart; ++l)
                    twin |= m->triangles[3 * u + (size_t)l] == b && m->triangles[3 * u + (size_t)(l + 1) % 3] == a;
            if (!twin)
                edges[count++] = 3 * t + (size_t)k;
        }
    }
    int crosses = 0;
    for (size_t i = 0; i < count && !crosses; ++i)
        for (size_t j = i + 1; j < count && !crosses; ++j) {
            const size_t e = edges[i], f = edges[j];
            crosses = proper_crossing(uv + 2 * e, uv + 2 * (e - e % 3 + (e + 1) % 3), uv + 2 * f,
                                      uv + 2 * (f - f % 3 + (f + 1) % 3));
        }
    free(edges);
    return crosses;
}

/* ---------------------------------------------------------------------------------------------
 * Tests
 * ------------------------------------------------------------------------------------------- */

/* The mesh flattened in its own 3D metric with stretch optimisation; *lengths receives that metric. */
static flattened flatten_optimised(const surface_mesh *m, double **lengths, int straight)
{
    *lengths = edge_lengths(m, unit_scale);
    return flatten_mesh(m, *lengths, NULL, options_with(straight, 1, 0));
}

static void test_developable_surfaces(void)
{
    const surface surfaces[3] = {plane, cylinder_patch, cone_patch};
    const char *names[3] = {"plane", "cylinder patch", "cone patch"};
    for (int i = 0; i < 3; ++i)
        for (int straight = 0; straight < 2; ++straight) {
            surface_mesh m = grid_mesh(surfaces[i], 24, 16);
            double *lengths;
            flattened f = flatten_optimised(&m, &lengths, straight);
            char context[96];
            snprintf(context, sizeof context, "%s, straight %d", names[i], straight);
            CHECK_IN(context, f.status == SK_OK);
            CHECK_IN(context, f.report.chart_count == 1 && f.report.split_count == 0);
            /* The cone's development is an annulus sector, whose curved sides straightening must bend. */
            const double stretch = mesh_stretch(f.uv, lengths, m.triangle_count);
            if (!straight || i < 2) {
                CHECK_IN(context, fabs(stretch - 1.0) < 1e-6);
                CHECK_IN(context, isometry_error(f.uv, lengths, m.triangle_count) < 1e-6);
            } else {
                CHECK_IN(context, stretch > 1.0 + 1e-6 && stretch < 1.25);
            }
            CHECK_IN(context, f.report.invalid_triangles == 0);
            free_flattened(&f);
            free(lengths);
            free_surface(&m);
        }
}

static void test_curved_surfaces_have_valid_triangles(void)
{
    const surface surfaces[2] = {bumpy_patch, hemisphere};
    for (int i = 0; i < 2; ++i)
        for (int straight = 0; straight < 2; ++straight) {
            surface_mesh m = grid_mesh(surfaces[i], 20, 20);
            double *lengths;
            flattened f = flatten_optimised(&m, &lengths, straight);
            char context[64];
            snprintf(context, sizeof context, "surface %d, straight %d", i, straight);
            CHECK_IN(context, f.status == SK_OK);
            CHECK_IN(context, invalid_triangles(f.uv, lengths, m.triangle_count) == 0);
            CHECK_IN(context, f.report.invalid_triangles == 0);
            const double stretch = mesh_stretch(f.uv, lengths, m.triangle_count);
            CHECK_IN(context, stretch >= 1.0 && stretch < 1.5);
            /* Without the optimisation the stretch is LSCM's: the optimisation must not make it worse. */
            flattened plain = flatten_mesh(&m, lengths, NULL, options_with(straight, 0, 0));
            CHECK_IN(context, plain.status == SK_OK);
            CHECK_IN(context, stretch <= mesh_stretch(plain.uv, lengths, m.triangle_count) + 1e-12);
            free_flattened(&plain);
            free_flattened(&f);
            free(lengths);
            free_surface(&m);
        }
}

static void test_metric_scaling(void)
{
    surface_mesh m = grid_mesh(plane, 12, 12);
    const double stretched[3] = {2.0, 1.0, 1.0};
    double *lengths = edge_lengths(&m, stretched);
    flattened f = flatten_mesh(&m, lengths, NULL, options_with(0, 1, 0));
    CHECK(f.status == SK_OK);
    CHECK(isometry_error(f.uv, lengths, m.triangle_count) < 1e-6);
    /* The Euclidean layout of the same mesh is not an isometry of the stretched metric. */
    double *euclidean = edge_lengths(&m, unit_scale);
    flattened g = flatten_mesh(&m, euclidean, NULL, options_with(0, 1, 0));
    CHECK(isometry_error(g.uv, lengths, m.triangle_count) > 0.1);
    CHECK(mesh_stretch(g.uv, lengths, m.triangle_count) > 1.05);
    free_flattened(&f);
    free_flattened(&g);
    free(euclidean);
    free(lengths);
    free_surface(&m);
}

static void test_overlapping_chart_is_split(void)
{
    surface_mesh m = grid_mesh(wavy_cone_band, 60, 4);
    double *lengths = edge_lengths(&m, unit_scale);
    /* One chart laid out with its free boundary overlaps itself: its development turns through more than 2 pi. */
    for (int straight = 0; straight < 2; ++straight) {
        flattened f = flatten_mesh(&m, lengths, NULL, options_with(straight, 1, 0));
        CHECK(f.status == SK_OK);
        /* Straight sides between the four corners make a simple quadrilateral, which needs no split. */
        CHECK(straight || f.report.split_count >= 1);
        CHECK(f.report.chart_count == f.report.split_count + 1);
        int32_t largest = 0;
        for (size_t t = 0; t < m.triangle_count; ++t)
            largest = f.charts[t] > largest ? f.charts[t] : largest;
        CHECK((size_t)largest + 1 == f.report.chart_count);
        for (int32_t c = 0; c <= largest; ++c)
            CHECK(!chart_boundary_crosses(&m, f.uv, f.charts, c));
        CHECK(invalid_triangles(f.uv, lengths, m.triangle_count) == 0);
        free_flattened(&f);
    }
    free(lengths);
    free_surface(&m);
}

static void test_pieces_and_threads(void)
{
    /* Four charts (quadrants of the bumpy patch), one of them given as two separate pieces. */
    surface_mesh m = grid_mesh(bumpy_patch, 16, 16);
    double *lengths = edge_lengths(&m, unit_scale);
    int32_t *charts = allocate(m.triangle_count, sizeof(int32_t));
    for (size_t t = 0; t < m.triangle_count; ++t) {
        const size_t cell = t / 2, i = cell % 16, j = cell / 16;
        charts[t] = (int32_t)((i >= 8) + 2 * (j >= 8));
        if (charts[t] == 3 && i >= 12)
            charts[t] = 0; /* chart 0: the lower-left quadrant and a strip of the upper right */
    }
    flattened one = flatten_mesh(&m, lengths, charts, options_with(1, 1, 1));
    flattened two = flatten_mesh(&m, lengths, charts, options_with(1, 1, 2));
    CHECK(one.status == SK_OK && two.status == SK_OK);
    CHECK(one.report.chart_count == 5);
    CHECK(memcmp(one.uv, two.uv, 6 * m.triangle_count * sizeof(double)) == 0);
    CHECK(memcmp(one.charts, two.charts, m.triangle_count * sizeof(int32_t)) == 0);
    /* Result charts are numbered in the order of the given ones: chart 0's pieces first. */
    CHECK(one.charts[0] == 0 && one.charts[2 * (15 * 16 + 15)] == 1);
    CHECK(invalid_triangles(one.uv, lengths, m.triangle_count) == 0);
    free_flattened(&one);
    free_flattened(&two);
    free(charts);
    free(lengths);
    free_surface(&m);
}

static void test_stretch_definitions(void)
{
    /* A right triangle with legs 3 and 4, laid out isometrically, scaled, sheared and flipped. */
    const double lengths[3] = {9.0, 25.0, 16.0};
    const double isometric[6] = {0, 0, 3, 0, 0, 4};
    double uv[6], stretch[1], whole = 0.0;
    sk_error error = stale_error();
    CHECK(sk_triangle_stretch(stretch, isometric, lengths, 1, &error) == SK_OK && fabs(stretch[0] - 1.0) < 1e-15);
    for (int i = 0; i < 6; ++i)
        uv[i] = 2 * isometric[i];
    CHECK(sk_triangle_stretch(stretch, uv, lengths, 1, &error) == SK_OK && fabs(stretch[0] - 0.5) < 1e-15);
    CHECK(sk_mesh_stretch(&whole, uv, lengths, 1, &error) == SK_OK && fabs(whole - 1.0) < 1e-15);
    /* u scaled by 2: singular values 1/2 and 1 (before normalisation), so sqrt((1/4 + 1) / 2). */
    const double wide[6] = {0, 0, 6, 0, 0, 4};
    CHECK(sk_triangle_stretch(stretch, wide, lengths, 1, &error) == SK_OK &&
          fabs(stretch[0] - sqrt(1.25 / 2)) < 1e-15);
    CHECK(sk_mesh_stretch(&whole, wide, lengths, 1, &error) == SK_OK && fabs(whole - sqrt(1.25)) < 1e-14);
    const double flipped[6] = {0, 0, 0, 4, 3, 0};
    CHECK(sk_triangle_stretch(stretch, flipped, lengths, 1, &error) == SK_OK && isinf(stretch[0]));
    CHECK(sk_mesh_stretch(&whole, flipped, lengths, 1, &error) == SK_OK && isinf(whole));
    const double collapsed[6] = {0, 0, 1, 1, 2, 2};
    CHECK(sk_triangle_stretch(stretch, collapsed, lengths, 1, &error) == SK_OK && isinf(stretch[0]));
}

static void test_refusals(void)
{
    surface_mesh m = grid_mesh(plane, 4, 4);
    double *lengths = edge_lengths(&m, unit_scale);
    const size_t n = m.triangle_count;
    double *uv = allocate(6 * n, sizeof(double));
    int32_t *charts = allocate(n, sizeof(int32_t)), *out = allocate(n, sizeof(int32_t));
    sk_flatten_report report;
    sk_flatten_options options = options_with(1, 1, 0);
#define FLATTEN(tri, len, ch, v) sk_flatten(uv, out, &report, &(sk_triangle_mesh){(tri), n, (v)}, (len), (ch), m.corners, &options, error)
    EXPECT_FAILURE("chart id out of range", SK_ERROR_INDEX,
                   (charts[3] = (int32_t)n, FLATTEN(m.triangles, lengths, charts, m.vertex_count)));
    charts[3] = 0;
    EXPECT_FAILURE("vertex index out of range", SK_ERROR_INDEX,
                   FLATTEN(m.triangles, lengths, charts, m.vertex_count - 1));
    double *bad = exact_copy_double(lengths, 3 * n);
    bad[7] = NAN;
    EXPECT_FAILURE("NaN length", SK_ERROR_NOT_FINITE, FLATTEN(m.triangles, bad, charts, m.vertex_count));
    bad[7] = bad[6] + bad[8] + 4 * sqrt(bad[6] * bad[8]); /* longer than the other two sides together */
    EXPECT_FAILURE("not a triangle", SK_ERROR_ARGUMENT, FLATTEN(m.triangles, bad, charts, m.vertex_count));
    free(bad);
    options.stretch_limit = 0.5;
    EXPECT_FAILURE("stretch limit", SK_ERROR_ARGUMENT, FLATTEN(m.triangles, lengths, charts, m.vertex_count));
    options.stretch_limit = 4.0;
    /* A ring: the middle cells (one chart) removed from the other chart leave an annulus. */
    for (size_t t = 0; t < n; ++t) {
        const size_t cell = t / 2, i = cell % 4, j = cell / 4;
        charts[t] = i >= 1 && i <= 2 && j >= 1 && j <= 2;
    }
    EXPECT_FAILURE("annulus", SK_ERROR_ARGUMENT, FLATTEN(m.triangles, lengths, charts, m.vertex_count));
    memset(charts, 0, n * sizeof *charts);
    int32_t *flipped = exact_copy_int32(m.triangles, 3 * n);
    const int32_t swap = flipped[1];
    flipped[1] = flipped[2];
    flipped[2] = swap;
    EXPECT_FAILURE("inconsistent orientation", SK_ERROR_ARGUMENT, FLATTEN(flipped, lengths, charts, m.vertex_count));
    free(flipped);
    /* A closed tetrahedron, and a fin: three triangles on one edge. */
    const int32_t tetrahedron[12] = {0, 2, 1, 0, 1, 3, 1, 2, 3, 2, 0, 3};
    const int32_t fin[9] = {0, 1, 2, 1, 0, 3, 0, 1, 4};
    const double unit[12] = {2, 2, 2, 2, 2, 2, 2, 2, 2, 2, 2, 2};
    const int32_t zeros[4] = {0, 0, 0, 0};
    unsigned char few_corners[5] = {0};
    EXPECT_FAILURE("closed", SK_ERROR_ARGUMENT,
                   sk_flatten(uv, out, &report, &(sk_triangle_mesh){tetrahedron, 4, 4}, unit, zeros, few_corners,
                              &options, error));
    EXPECT_FAILURE("fin", SK_ERROR_ARGUMENT,
                   sk_flatten(uv, out, &report, &(sk_triangle_mesh){fin, 3, 5}, unit, zeros, few_corners, &options,
                              error));
    EXPECT_FAILURE("null", SK_ERROR_ARGUMENT,
                   sk_flatten(uv, out, NULL, &(sk_triangle_mesh){m.triangles, n, m.vertex_count}, lengths, charts,
                              m.corners, &options, error));
#undef FLATTEN
    free(uv);
    free(charts);
    free(out);
    free(lengths);
    free_surface(&m);
}

/* A deterministic uniform number in [-1, 1) (a linear congruential generator: the same mesh on every platform). */
static double jitter(uint64_t *state)
{
    *state = *state * 6364136223846793005u + 1442695040888963407u;
    return (double)(*state >> 11) / 4503599627370496.0 - 1.0;
}

/* The bumpy patch as a scan: vertices jittered by 0.3 of a cell, and every `fan_every`-th interior vertex moved to
 * within 1e-5 of a cell of its right-hand neighbour, whose triangles become needles (cotangents near 1e5). */
static surface_mesh scan_like_patch(size_t side, size_t fan_every)
{
    surface_mesh m = grid_mesh(bumpy_patch, side, side);
    const double cell = 2.0 / (double)side;
    uint64_t state = 7;
    for (size_t j = 1; j < side; ++j)
        for (size_t i = 1; i < side; ++i) {
            double *p = m.positions + 3 * (j * (side + 1) + i);
            p[0] += 0.3 * cell * jitter(&state);
            p[1] += 0.3 * cell * jitter(&state);
        }
    for (size_t j = 1; j < side; ++j)
        for (size_t i = 1; i + 1 < side; ++i)
            if ((j * (side + 1) + i) % fan_every == 0) {
                double *p = m.positions + 3 * (j * (side + 1) + i);
                const double *right = p + 3;
                for (int axis = 0; axis < 3; ++axis)
                    p[axis] = right[axis] + 1e-5 * cell * jitter(&state);
            }
    return m;
}

/*
 * Charts of 1000 free vertices or more are solved with the multigrid preconditioner (sk_amg.c). It must give
 * the same answer as SSOR (a developable chart's exact isometry), in steps that grow far more slowly with the size
 * than SSOR's, on needle triangles too (where SSOR needs tens of thousands), and the same bits on any thread count.
 */
static void test_multigrid_solves_large_charts(void)
{
    for (int straight = 0; straight < 2; ++straight) {
        surface_mesh m = grid_mesh(plane, 60, 40);
        double *lengths = edge_lengths(&m, unit_scale);
        flattened f = flatten_mesh(&m, lengths, NULL, options_with(straight, 0, 1));
        CHECK_IN(straight ? "plane, straight" : "plane, free", f.status == SK_OK);
        CHECK_IN(straight ? "plane, straight" : "plane, free", isometry_error(f.uv, lengths, m.triangle_count) < 1e-8);
        /* 2,301 interior vertices: the free pass is boundary first flattening, exact on a developable chart. */
        CHECK_IN(straight ? "plane, straight" : "plane, free", f.report.boundary_first_charts == 1);
        free_flattened(&f);
        free(lengths);
        free_surface(&m);
    }
    size_t steps[2] = {0, 0};
    for (int size = 0; size < 2; ++size) {
        surface_mesh m = grid_mesh(bumpy_patch, size ? 160 : 40, size ? 160 : 40);
        double *lengths = edge_lengths(&m, unit_scale);
        flattened f = flatten_mesh(&m, lengths, NULL, options_with(0, 0, 1));
        CHECK(f.status == SK_OK && f.report.invalid_triangles == 0);
        steps[size] = f.report.solver_iterations;
        free_flattened(&f);
        free(lengths);
        free_surface(&m);
    }
    /* 16 times the vertices: block SSOR alone took 180 and 1422 steps (7.9 times as many), the V-cycle on LSCM with
     * two pins 63 and 206 (its near-kernel is every discrete holomorphic map), boundary first flattening 29 and 33
     * (both its solves pin the boundary). */
    CHECK(steps[1] < 60 && 10 * steps[1] < 13 * steps[0]);

    surface_mesh m = scan_like_patch(64, 13);
    double *lengths = edge_lengths(&m, unit_scale);
    int32_t *charts = allocate(m.triangle_count, sizeof(int32_t));
    for (size_t t = 0; t < m.triangle_count; ++t) /* two charts of about 2100 vertices */
        charts[t] = (int32_t)(t / 2 % 64 >= 32);
    flattened one = flatten_mesh(&m, lengths, charts, options_with(1, 1, 1));
    flattened two = flatten_mesh(&m, lengths, charts, options_with(1, 1, 2));
    CHECK(one.status == SK_OK && two.status == SK_OK);
    CHECK(memcmp(one.uv, two.uv, 6 * m.triangle_count * sizeof(double)) == 0);
    CHECK(one.report.invalid_triangles == 0 && invalid_triangles(one.uv, lengths, m.triangle_count) == 0);
    CHECK(isfinite(mesh_stretch(one.uv, lengths, m.triangle_count)));
    flattened free_layout = flatten_mesh(&m, lengths, charts, options_with(0, 0, 1));
    CHECK(free_layout.status == SK_OK);
    CHECK(free_layout.report.solver_iterations < 1000); /* block SSOR alone: 17,636 steps; the V-cycle 201 */
    free_flattened(&free_layout);
    free_flattened(&one);
    free_flattened(&two);
    free(charts);
    free(lengths);
    free_surface(&m);
}

int main(void)
{
    test_program_name = "test_flatten";
    test_stretch_definitions();
    test_developable_surfaces();
    test_curved_surfaces_have_valid_triangles();
    test_metric_scaling();
    test_overlapping_chart_is_split();
    test_pieces_and_threads();
    test_multigrid_solves_large_charts();
    test_refusals();
    return finish_tests();
}
