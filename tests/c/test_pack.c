/*
 * Standalone tests of packing (csrc/skinkit.h, "Packing"): sk_pack, under the sanitizers. Overlaps and gaps
 * between the packed charts are measured by brute force over every pair of uv triangles.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>

#include "skinkit.h"
#include "test_support.h"

#define PI 3.14159265358979323846

/* Whether two uv triangles share interior points (separating axis test on their edges' normals). */
static int triangles_overlap(const double *a, const double *b)
{
    const double *shapes[2] = {a, b};
    for (int s = 0; s < 2; ++s)
        for (int k = 0; k < 3; ++k) {
            const double *p = shapes[s] + 2 * k, *q = shapes[s] + 2 * ((k + 1) % 3);
            const double normal[2] = {q[1] - p[1], p[0] - q[0]};
            double low[2] = {INFINITY, INFINITY}, high[2] = {-INFINITY, -INFINITY};
            for (int which = 0; which < 2; ++which)
                for (int i = 0; i < 3; ++i) {
                    const double x = normal[0] * shapes[which][2 * i] + normal[1] * shapes[which][2 * i + 1];
                    low[which] = fmin(low[which], x);
                    high[which] = fmax(high[which], x);
                }
            if (high[0] <= low[1] + 1e-12 || high[1] <= low[0] + 1e-12)
                return 0;
        }
    return 1;
}

/* The smallest distance between a vertex of one triangle and the other triangle's edges, by sampling. */
static double triangle_gap(const double *a, const double *b)
{
    double gap = INFINITY;
    const double *shapes[2] = {a, b};
    for (int s = 0; s < 2; ++s)
        for (int i = 0; i < 3; ++i)
            for (int k = 0; k < 3; ++k) {
                const double *x = shapes[s] + 2 * i, *p = shapes[1 - s] + 2 * k, *q = shapes[1 - s] + 2 * ((k + 1) % 3);
                const double dx = q[0] - p[0], dy = q[1] - p[1];
                const double along = fmin(fmax(((x[0] - p[0]) * dx + (x[1] - p[1]) * dy) / (dx * dx + dy * dy), 0), 1);
                gap = fmin(gap, hypot(x[0] - p[0] - along * dx, x[1] - p[1] - along * dy));
            }
    return gap;
}

static void test_packing(void)
{
    /* 40 squares of random sizes and positions, two triangles each, and a flattened bumpy patch in 4 charts. */
    const size_t squares = 40, n = 2 * squares;
    double *uv = allocate(6 * n, sizeof(double)), *packed = allocate(6 * n, sizeof(double));
    double *area = allocate(n, sizeof(double));
    int32_t *charts = allocate(n, sizeof(int32_t));
    for (size_t i = 0; i < squares; ++i) {
        const double side = random_uniform(0.2, 2.0), x = random_uniform(-5, 5), y = random_uniform(-5, 5);
        const double angle = random_uniform(0, PI), c = side * cos(angle), s = side * sin(angle);
        const double corners[4][2] = {{x, y}, {x + c, y + s}, {x + c - s, y + s + c}, {x - s, y + c}};
        const int order[6] = {0, 1, 2, 0, 2, 3};
        for (int k = 0; k < 6; ++k) {
            uv[12 * i + 2 * (size_t)k] = corners[order[k]][0];
            uv[12 * i + 2 * (size_t)k + 1] = corners[order[k]][1];
        }
        charts[2 * i] = charts[2 * i + 1] = (int32_t)i;
        area[2 * i] = area[2 * i + 1] = side * side / 2; /* the uv scale is the surface's */
    }
    const int sizes[2] = {256, 1024};
    for (int which = 0; which < 2; ++which) {
        sk_pack_options options = {sizes[which], 4.0};
        sk_pack_report report;
        EXPECT_SUCCESS("pack squares", sk_pack(packed, &report, uv, charts, area, n, &options, error));
        const double margin = options.margin / options.texture_size;
        CHECK(report.chart_count == squares);
        CHECK(report.packing_efficiency > 0.5 && report.packing_efficiency < 1.0);
        double lowest = INFINITY, highest = -INFINITY, covered = 0.0;
        for (size_t i = 0; i < 6 * n; ++i) {
            lowest = fmin(lowest, packed[i]);
            highest = fmax(highest, packed[i]);
        }
        CHECK(lowest >= margin - 1e-12 && highest <= 1 - margin + 1e-12);
        for (size_t t = 0; t < n; ++t) {
            const double *x = packed + 6 * t;
            covered += ((x[2] - x[0]) * (x[5] - x[1]) - (x[4] - x[0]) * (x[3] - x[1])) / 2;
            /* Every chart keeps its shape: scaled uniformly by the report's scale, turned, not mirrored. */
            const double *given = uv + 6 * t;
            CHECK(fabs(hypot(x[2] - x[0], x[3] - x[1]) - report.scale * hypot(given[2] - given[0], given[3] - given[1])) <
                  1e-9);
        }
        CHECK(fabs(covered - report.packing_efficiency) < 1e-12);
        int overlaps = 0;
        double gap = INFINITY;
        for (size_t a = 0; a < n; ++a)
            for (size_t b = a + 1; b < n; ++b)
                if (charts[a] != charts[b]) {
                    overlaps += triangles_overlap(packed + 6 * a, packed + 6 * b);
                    gap = fmin(gap, triangle_gap(packed + 6 * a, packed + 6 * b));
                }
        CHECK(overlaps == 0);
        CHECK(gap >= margin - 1e-12);
    }
    sk_pack_options options = {16, 2.0}; /* 40 charts of at least 3x3 texels (with margins) in 14x14 */
    sk_pack_report report;
    EXPECT_FAILURE("margin leaves no room", SK_ERROR_ARGUMENT,
                   sk_pack(packed, &report, uv, charts, area, n, &options, error));
    options.margin = 40.0;
    EXPECT_FAILURE("margin too large", SK_ERROR_ARGUMENT,
                   sk_pack(packed, &report, uv, charts, area, n, &options, error));
    options = (sk_pack_options){1024, 4.0};
    area[5] = 0.0;
    EXPECT_FAILURE("zero surface area", SK_ERROR_ARGUMENT,
                   sk_pack(packed, &report, uv, charts, area, n, &options, error));
    area[5] = 1.0;
    options.texture_size = SK_PACK_MAX_TEXTURE_SIZE + 1; /* 3e7 texels used to run for minutes */
    EXPECT_FAILURE("texture too large", SK_ERROR_ARGUMENT,
                   sk_pack(packed, &report, uv, charts, area, n, &options, error));
    /* An odd texture whose margin leaves one free texel in the middle: one chart fits, shrunk into it. */
    options = (sk_pack_options){15, 7.0};
    EXPECT_SUCCESS("one chart in the one free texel", sk_pack(packed, &report, uv, charts, area, 2, &options, error));
    for (size_t i = 0; i < 12; ++i)
        CHECK(packed[i] >= 7.0 / 15 - 1e-12 && packed[i] <= 8.0 / 15 + 1e-12);
    EXPECT_FAILURE("two charts with no room for a margin between them", SK_ERROR_ARGUMENT,
                   sk_pack(packed, &report, uv, charts, area, 4, &options, error));
    /* A texture above the grid's 1024 cells whose margin, rounded up to whole cells, leaves no cell at all. */
    options = (sk_pack_options){2048, 1023.5};
    EXPECT_FAILURE("margin rounded up to the whole grid", SK_ERROR_ARGUMENT,
                   sk_pack(packed, &report, uv, charts, area, 2, &options, error));
    options = (sk_pack_options){1024, 4.0};
    /* Found by the binding fuzzer: finite coordinates whose extent overflows (1e308 - -1e308) made a NaN width, a
     * huge skyline span and a write past the skyline. */
    const double saved[2] = {uv[0], uv[2]};
    uv[0] = 1e308, uv[2] = -1e308;
    EXPECT_FAILURE("uv extent overflowing", SK_ERROR_NOT_FINITE,
                   sk_pack(packed, &report, uv, charts, NULL, n, &options, error));
    uv[0] = saved[0], uv[2] = saved[1];
    charts[5] = -1;
    EXPECT_FAILURE("chart out of range", SK_ERROR_INDEX,
                   sk_pack(packed, &report, uv, charts, NULL, n, &options, error));
    free(uv);
    free(packed);
    free(area);
    free(charts);
}

/* Counts overlapping pairs of uv triangles of different charts and the smallest gap between them. */
static int overlaps_and_gap(const double *packed, const int32_t *charts, size_t n, double *gap)
{
    int overlaps = 0;
    *gap = INFINITY;
    for (size_t a = 0; a < n; ++a)
        for (size_t b = a + 1; b < n; ++b)
            if (charts[a] != charts[b]) {
                overlaps += triangles_overlap(packed + 6 * a, packed + 6 * b);
                *gap = fmin(*gap, triangle_gap(packed + 6 * a, packed + 6 * b));
            }
    return overlaps;
}

/*
 * Thin L-shaped charts (7 unit squares in a 4x4 box) cover 7/16 of their bounding rectangles: a packer of
 * rectangles cannot exceed 0.4375, one that packs outlines nests them. At 4096 texels the grid is coarser than the
 * texture (1024 cells of 4 texels): the margin, rounded up to whole cells, must still hold.
 */
static void test_outlines_nest(void)
{
    const size_t shapes = 24, squares_per_shape = 7, n = 2 * squares_per_shape * shapes;
    const int cells[7][2] = {{0, 0}, {1, 0}, {2, 0}, {3, 0}, {0, 1}, {0, 2}, {0, 3}};
    double *uv = allocate(6 * n, sizeof(double)), *packed = allocate(6 * n, sizeof(double));
    int32_t *charts = allocate(n, sizeof(int32_t));
    size_t t = 0;
    for (size_t shape = 0; shape < shapes; ++shape)
        for (size_t square = 0; square < squares_per_shape; ++square) {
            const double x = cells[square][0], y = cells[square][1];
            const double corners[4][2] = {{x, y}, {x + 1, y}, {x + 1, y + 1}, {x, y + 1}};
            const int order[2][3] = {{0, 1, 2}, {0, 2, 3}};
            for (int half = 0; half < 2; ++half, ++t) {
                for (int k = 0; k < 3; ++k) {
                    uv[6 * t + 2 * (size_t)k] = corners[order[half][k]][0];
                    uv[6 * t + 2 * (size_t)k + 1] = corners[order[half][k]][1];
                }
                charts[t] = (int32_t)shape;
            }
        }
    const int sizes[2] = {1024, 4096};
    for (int which = 0; which < 2; ++which) {
        sk_pack_options options = {sizes[which], 4.0};
        sk_pack_report report;
        EXPECT_SUCCESS("pack L shapes", sk_pack(packed, &report, uv, charts, NULL, n, &options, error));
        CHECK(report.chart_count == shapes);
        CHECK(report.packing_efficiency > 0.5); /* above what their bounding rectangles allow */
        double gap;
        CHECK(overlaps_and_gap(packed, charts, n, &gap) == 0);
        CHECK(gap >= options.margin / options.texture_size - 1e-12);
        double lowest = INFINITY, highest = -INFINITY;
        for (size_t i = 0; i < 6 * n; ++i) {
            lowest = fmin(lowest, packed[i]);
            highest = fmax(highest, packed[i]);
        }
        CHECK(lowest >= options.margin / options.texture_size - 1e-12);
        CHECK(highest <= 1 - options.margin / options.texture_size + 1e-12);
    }
    free(uv);
    free(packed);
    free(charts);
}

int main(void)
{
    test_program_name = "test_pack";
    test_packing();
    test_outlines_nest();
    return finish_tests();
}
