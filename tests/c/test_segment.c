/*
 * Standalone tests of the segmentation (csrc/skinkit.h, "Segmentation"): sk_segment, sk_chart_corners and
 * sk_straighten_charts, under AddressSanitizer and UndefinedBehaviorSanitizer.
 *
 * Meshes are built here (grid, closed box, capped cylinder); chart topology is checked by an independent
 * brute-force count (V - E + F per chart, one simple boundary loop, edge-connected), not by the core's
 * own disc check.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "skinkit.h"
#include "test_support.h"

typedef struct mesh {
    size_t vertex_count, triangle_count;
    double *positions; /* 3 per vertex */
    int32_t *triangles;
} mesh;

static void free_test_mesh(mesh *m)
{
    free(m->positions);
    free(m->triangles);
}

static void add_quad(int32_t *triangles, size_t *t, int32_t a, int32_t b, int32_t c, int32_t d)
{
    const int32_t quad[6] = {a, b, c, a, c, d};
    memcpy(triangles + 3 * *t, quad, sizeof quad);
    *t += 2;
}

/* An n x m grid of unit squares in the z = 0 plane, each split in two triangles. */
static mesh make_grid(size_t n, size_t m)
{
    mesh g = {(n + 1) * (m + 1), 2 * n * m, NULL, NULL};
    g.positions = allocate(3 * g.vertex_count, sizeof(double));
    g.triangles = allocate(3 * g.triangle_count, sizeof(int32_t));
    for (size_t j = 0; j <= m; ++j)
        for (size_t i = 0; i <= n; ++i) {
            g.positions[3 * (j * (n + 1) + i)] = (double)i;
            g.positions[3 * (j * (n + 1) + i) + 1] = (double)j;
        }
    size_t t = 0;
    for (size_t j = 0; j < m; ++j)
        for (size_t i = 0; i < n; ++i) {
            const int32_t a = (int32_t)(j * (n + 1) + i);
            add_quad(g.triangles, &t, a, a + 1, a + 1 + (int32_t)(n + 1), a + (int32_t)(n + 1));
        }
    return g;
}

/*
 * A cylinder of `around` x `rings` quads (radius 1, height 2), with its two caps as triangle fans about a
 * centre vertex when capped. Vertex (ring r, step k) is r * around + k; the centres come last.
 */
static mesh make_cylinder(size_t around, size_t rings, int capped)
{
    mesh c = {around * (rings + 1) + (capped ? 2 : 0), 2 * around * rings + (capped ? 2 * around : 0), NULL, NULL};
    c.positions = allocate(3 * c.vertex_count, sizeof(double));
    c.triangles = allocate(3 * c.triangle_count, sizeof(int32_t));
    for (size_t r = 0; r <= rings; ++r)
        for (size_t k = 0; k < around; ++k) {
            const double angle = 2.0 * 3.14159265358979 * (double)k / (double)around;
            double *p = c.positions + 3 * (r * around + k);
            p[0] = cos(angle);
            p[1] = sin(angle);
            p[2] = 2.0 * (double)r / (double)rings;
        }
    size_t t = 0;
    for (size_t r = 0; r < rings; ++r)
        for (size_t k = 0; k < around; ++k) {
            const int32_t a = (int32_t)(r * around + k), b = (int32_t)(r * around + (k + 1) % around);
            add_quad(c.triangles, &t, a, b, b + (int32_t)around, a + (int32_t)around);
        }
    if (capped) {
        const int32_t bottom = (int32_t)(around * (rings + 1)), top = bottom + 1;
        c.positions[3 * (size_t)top + 2] = 2.0;
        for (size_t k = 0; k < around; ++k) {
            const int32_t a = (int32_t)k, b = (int32_t)((k + 1) % around);
            const int32_t fan_bottom[3] = {bottom, b, a};
            const int32_t fan_top[3] = {top, a + (int32_t)(rings * around), b + (int32_t)(rings * around)};
            memcpy(c.triangles + 3 * t++, fan_bottom, sizeof fan_bottom);
            memcpy(c.triangles + 3 * t++, fan_top, sizeof fan_top);
        }
    }
    return c;
}

/* A closed box: the six faces of an n x n x n cube of unit squares. */
static mesh make_box(size_t n)
{
    const size_t side = (n + 1) * (n + 1);
    mesh b = {6 * side, 12 * n * n, NULL, NULL};
    b.positions = allocate(3 * b.vertex_count, sizeof(double));
    b.triangles = allocate(3 * b.triangle_count, sizeof(int32_t));
    size_t t = 0;
    /* Six faces with their own vertices, welded afterwards by position. */
    for (int face = 0; face < 6; ++face) {
        const int axis = face / 2, high = face % 2;
        for (size_t j = 0; j <= n; ++j)
            for (size_t i = 0; i <= n; ++i) {
                double *p = b.positions + 3 * (face * side + j * (n + 1) + i);
                p[axis] = high ? (double)n : 0.0;
                p[(axis + 1) % 3] = (double)i;
                p[(axis + 2) % 3] = (double)j;
            }
        for (size_t j = 0; j < n; ++j)
            for (size_t i = 0; i < n; ++i) {
                const int32_t a = (int32_t)(face * side + j * (n + 1) + i), s = (int32_t)(n + 1);
                if (high)
                    add_quad(b.triangles, &t, a, a + 1, a + 1 + s, a + s);
                else
                    add_quad(b.triangles, &t, a, a + s, a + 1 + s, a + 1);
            }
    }
    for (size_t k = 0; k < 3 * b.triangle_count; ++k)
        for (int32_t v = 0; v < b.triangles[k]; ++v)
            if (!memcmp(b.positions + 3 * v, b.positions + 3 * (size_t)b.triangles[k], 3 * sizeof(double))) {
                b.triangles[k] = v;
                break;
            }
    return b;
}

/* ---------------------------------------------------------------------------------------------
 * Independent topology checks (brute force: the test meshes are small)
 * ------------------------------------------------------------------------------------------- */

static int same_edge(const int32_t *tri_a, int ka, const int32_t *tri_b, int kb)
{
    const int32_t a0 = tri_a[ka], a1 = tri_a[(ka + 1) % 3], b0 = tri_b[kb], b1 = tri_b[(kb + 1) % 3];
    return (a0 == b0 && a1 == b1) || (a0 == b1 && a1 == b0);
}

/* The triangle sharing edge k of triangle t, or -1. */
static long neighbour(const mesh *m, size_t t, int k)
{
    for (size_t o = 0; o < m->triangle_count; ++o)
        for (int j = 0; o != t && j < 3; ++j)
            if (same_edge(m->triangles + 3 * t, k, m->triangles + 3 * o, j))
                return (long)o;
    return -1;
}

/* Whether chart c is a disc: V - E + F = 1, a boundary where each vertex has two boundary edges, connected. */
static int chart_is_disc(const mesh *m, const int32_t *charts, int32_t c)
{
    long faces = 0, edge_sides = 0, boundary = 0;
    long *boundary_at = calloc(m->vertex_count, sizeof(long));
    unsigned char *used = calloc(m->vertex_count, 1), *reached = calloc(m->triangle_count, 1);
    size_t first = m->triangle_count;
    for (size_t t = 0; t < m->triangle_count; ++t) {
        if (charts[t] != c)
            continue;
        first = first < t ? first : t;
        ++faces;
        for (int k = 0; k < 3; ++k) {
            used[m->triangles[3 * t + k]] = 1;
            const long o = neighbour(m, t, k);
            if (o >= 0 && charts[o] == c) {
                ++edge_sides;
            } else {
                ++boundary;
                ++boundary_at[m->triangles[3 * t + k]];
                ++boundary_at[m->triangles[3 * t + (k + 1) % 3]];
            }
        }
    }
    long vertices = 0;
    int loop_ok = boundary > 0;
    for (size_t v = 0; v < m->vertex_count; ++v) {
        vertices += used[v];
        loop_ok &= boundary_at[v] == 0 || boundary_at[v] == 2;
    }
    size_t count = 0;
    if (first < m->triangle_count) { /* flood fill through the chart */
        reached[first] = 1;
        for (int changed = 1; changed;) {
            changed = 0;
            for (size_t t = 0; t < m->triangle_count; ++t)
                for (int k = 0; reached[t] && k < 3; ++k) {
                    const long o = neighbour(m, t, k);
                    if (o >= 0 && charts[o] == c && !reached[o])
                        reached[o] = changed = 1;
                }
        }
        for (size_t t = 0; t < m->triangle_count; ++t)
            count += reached[t];
    }
    free(boundary_at);
    free(used);
    free(reached);
    return faces > 0 && vertices - (boundary + edge_sides / 2) + faces == 1 && loop_ok && (long)count == faces;
}

static size_t chart_count_of(const int32_t *charts, size_t triangle_count)
{
    int32_t largest = -1;
    for (size_t t = 0; t < triangle_count; ++t)
        largest = charts[t] > largest ? charts[t] : largest;
    return (size_t)(largest + 1);
}

static int all_discs(const mesh *m, const int32_t *charts)
{
    const size_t count = chart_count_of(charts, m->triangle_count);
    for (size_t c = 0; c < count; ++c)
        if (!chart_is_disc(m, charts, (int32_t)c))
            return 0;
    return 1;
}

/* Every seam edge has its two triangles in different charts. */
static int seams_respected(const mesh *m, const int32_t *charts, const int32_t *seams, size_t seam_count)
{
    for (size_t s = 0; s < seam_count; ++s)
        for (size_t t = 0; t < m->triangle_count; ++t)
            for (int k = 0; k < 3; ++k) {
                const int32_t a = m->triangles[3 * t + k], b = m->triangles[3 * t + (k + 1) % 3];
                const long o = neighbour(m, t, k);
                if (((a == seams[2 * s] && b == seams[2 * s + 1]) || (b == seams[2 * s] && a == seams[2 * s + 1])) &&
                    o >= 0 && charts[o] == charts[t])
                    return 0;
            }
    return 1;
}

/* The mesh opened along the seams (sk_cut_along_seams): charts of a seamed mesh are discs of this one. */
static mesh cut_open(const mesh *m, const int32_t *seams, size_t seam_count)
{
    mesh cut = {0, m->triangle_count, NULL, allocate(3 * m->triangle_count, sizeof(int32_t))};
    int32_t *source = allocate(3 * m->triangle_count, sizeof(int32_t));
    EXPECT_SUCCESS("cut", sk_cut_along_seams(cut.triangles, source, &cut.vertex_count,
                                             &(sk_triangle_mesh){m->triangles, m->triangle_count, m->vertex_count},
                                             seams, seam_count, error));
    cut.positions = allocate(3 * cut.vertex_count + 1, sizeof(double));
    for (size_t v = 0; v < cut.vertex_count; ++v)
        memcpy(cut.positions + 3 * v, m->positions + 3 * (size_t)source[v], 3 * sizeof(double));
    free(source);
    return cut;
}

static sk_segment_options greedy(size_t chart_count, double threshold)
{
    return (sk_segment_options){SK_SEGMENT_GREEDY, chart_count, threshold, 0.2};
}

/* The positions with extra zero columns: the metric is the same, only the plane-fit code path changes. */
static double *padded(const mesh *m, size_t dimension)
{
    double *embedding = allocate(m->vertex_count * dimension, sizeof(double));
    for (size_t v = 0; v < m->vertex_count; ++v)
        for (size_t k = 0; k < 3; ++k)
            embedding[v * dimension + (k + dimension - 3) % dimension] = m->positions[3 * v + k];
    return embedding;
}

/* ---------------------------------------------------------------------------------------------
 * Tests
 * ------------------------------------------------------------------------------------------- */

static void test_closed_box_needs_two_discs(void)
{
    mesh box = make_box(3);
    int32_t *charts = allocate(box.triangle_count, sizeof(int32_t));
    sk_segment_report report;
    const sk_segment_options options = greedy(1, 0.0);
    EXPECT_SUCCESS("box", sk_segment(charts, &report,
                                     &(sk_triangle_mesh){box.triangles, box.triangle_count, box.vertex_count},
                                     box.positions, 3, NULL, 0, &options, error));
    CHECK_IN("a closed surface is never one disc", report.chart_count >= 2);
    CHECK(report.chart_count == chart_count_of(charts, box.triangle_count));
    CHECK_IN("box charts are discs", all_discs(&box, charts));
    const sk_segment_options six = greedy(6, 0.0);
    EXPECT_SUCCESS("box to 6", sk_segment(charts, &report,
                                          &(sk_triangle_mesh){box.triangles, box.triangle_count, box.vertex_count},
                                          box.positions, 3, NULL, 0, &six, error));
    CHECK_IN("target count reached", report.chart_count == 6);
    CHECK_IN("box charts are discs", all_discs(&box, charts));
    /* Six flat faces are the best six charts: each chart is one face (all its triangles share a normal). */
    int planar = 1;
    for (size_t t = 0; t < box.triangle_count; ++t)
        for (size_t o = 0; o < box.triangle_count; ++o)
            if (charts[t] == charts[o] && t / (2 * 9) != o / (2 * 9))
                planar = 0;
    CHECK_IN("six charts of a box are its faces", planar);
    /* Thresholds: E_mesh never ends above one unless merges lowered it there, and a lower one stops sooner. */
    const sk_segment_options loose = greedy(0, 1.8), tight = greedy(0, 1.5);
    sk_segment_report loose_report, tight_report;
    EXPECT_SUCCESS("threshold 1.8", sk_segment(charts, &loose_report,
                                               &(sk_triangle_mesh){box.triangles, box.triangle_count, box.vertex_count},
                                               box.positions, 3, NULL, 0, &loose, error));
    CHECK(loose_report.mesh_metric <= 1.8 && all_discs(&box, charts));
    EXPECT_SUCCESS("threshold 1.5", sk_segment(charts, &tight_report,
                                               &(sk_triangle_mesh){box.triangles, box.triangle_count, box.vertex_count},
                                               box.positions, 3, NULL, 0, &tight, error));
    CHECK(tight_report.mesh_metric <= 1.5 && all_discs(&box, charts));
    CHECK_IN("a lower threshold stops earlier", tight_report.chart_count > loose_report.chart_count);
    free(charts);
    free_test_mesh(&box);
}

static void test_grid_target_and_threshold(void)
{
    mesh grid = make_grid(8, 6);
    int32_t *charts = allocate(grid.triangle_count, sizeof(int32_t));
    sk_segment_report report;
    const sk_segment_options one = greedy(1, 0.0);
    EXPECT_SUCCESS("grid to 1", sk_segment(charts, &report,
                                           &(sk_triangle_mesh){grid.triangles, grid.triangle_count, grid.vertex_count},
                                           grid.positions, 3, NULL, 0, &one, error));
    CHECK_IN("a plane becomes one chart", report.chart_count == 1 && chart_count_of(charts, grid.triangle_count) == 1);
    /* One flat rectangle 8 x 6: E = (48 + 0.2 * 28^2 / 4 pi) / 48. */
    CHECK(fabs(report.mesh_metric - (48.0 + 0.2 * 28.0 * 28.0 / (4.0 * 3.14159265358979)) / 48.0) < 1e-9);
    const sk_segment_options four = greedy(4, 0.0);
    EXPECT_SUCCESS("grid to 4", sk_segment(charts, &report,
                                           &(sk_triangle_mesh){grid.triangles, grid.triangle_count, grid.vertex_count},
                                           grid.positions, 3, NULL, 0, &four, error));
    CHECK(report.chart_count == 4 && chart_count_of(charts, grid.triangle_count) == 4);
    CHECK(all_discs(&grid, charts));
    CHECK(all_discs(&grid, charts));
    free(charts);
    free_test_mesh(&grid);
}

/* Seams along one line of the tube and round both cap rims: the tube (cut open), and two caps. */
static void test_capped_cylinder_seams(void)
{
    const size_t around = 12, rings = 4;
    mesh cylinder = make_cylinder(around, rings, 1);
    const size_t seam_count = rings + 2 * around;
    int32_t *seams = allocate(2 * seam_count, sizeof(int32_t));
    size_t s = 0;
    for (size_t r = 0; r < rings; ++r, ++s) {
        seams[2 * s] = (int32_t)(r * around);
        seams[2 * s + 1] = (int32_t)((r + 1) * around);
    }
    for (size_t k = 0; k < around; ++k)
        for (size_t ring = 0; ring <= rings; ring += rings, ++s) {
            seams[2 * s] = (int32_t)(ring * around + k);
            seams[2 * s + 1] = (int32_t)(ring * around + (k + 1) % around);
        }
    int32_t *charts = allocate(cylinder.triangle_count, sizeof(int32_t));
    sk_segment_report report;
    const sk_segment_options seams_only = {SK_SEGMENT_SEAMS, 0, 0.0, 0.2};
    int32_t *exact_seams = exact_copy_int32(seams, 2 * seam_count);
    EXPECT_SUCCESS("seams mode", sk_segment(charts, &report,
                                            &(sk_triangle_mesh){cylinder.triangles, cylinder.triangle_count, cylinder.vertex_count},
                                            cylinder.positions, 3, exact_seams, seam_count, &seams_only, error));
    CHECK_IN("tube and two caps", report.chart_count == 3 && report.component_count == 3);
    const size_t tube = 2 * around * rings;
    int expected = 1;
    for (size_t t = 0; t < cylinder.triangle_count; ++t) {
        const int32_t piece = t < tube ? charts[0] : charts[tube + (t - tube) % 2];
        expected &= charts[t] == piece;
    }
    CHECK_IN("the charts are the pieces between seams", expected && charts[tube] != charts[tube + 1] &&
                                                            charts[0] != charts[tube] && charts[0] != charts[tube + 1]);
    mesh opened = cut_open(&cylinder, seams, seam_count);
    /* Rims split in two (tube and cap), the seam line once more: its ends three ways. */
    CHECK_IN("the seams are opened", opened.vertex_count == cylinder.vertex_count + 2 * around + rings + 1);
    CHECK(all_discs(&opened, charts));
    CHECK_IN("the tube is not a disc before the cut", !all_discs(&cylinder, charts));
    /* Without the line seam the tube is an annulus: seams mode cuts it into discs. */
    mesh rims_only = cut_open(&cylinder, seams + 2 * rings, seam_count - rings);
    EXPECT_SUCCESS("seams mode, uncut tube",
                   sk_segment(charts, &report,
                              &(sk_triangle_mesh){cylinder.triangles, cylinder.triangle_count, cylinder.vertex_count},
                              cylinder.positions, 3, exact_seams + 2 * rings, seam_count - rings, &seams_only, error));
    CHECK(report.component_count == 3 && report.chart_count > 3);
    CHECK(all_discs(&rims_only, charts));
    CHECK(seams_respected(&cylinder, charts, seams + 2 * rings, seam_count - rings));
    /* Greedy merging never crosses a seam either. */
    const sk_segment_options five = greedy(5, 0.0);
    EXPECT_SUCCESS("greedy with seams", sk_segment(charts, &report,
                                                   &(sk_triangle_mesh){cylinder.triangles, cylinder.triangle_count, cylinder.vertex_count},
                                                   cylinder.positions, 3, exact_seams, seam_count, &five, error));
    CHECK(report.chart_count == 5 && seams_respected(&cylinder, charts, seams, seam_count));
    CHECK(all_discs(&opened, charts));
    free_test_mesh(&rims_only);
    free_test_mesh(&opened);
    free(exact_seams);
    free(seams);
    free(charts);
    free_test_mesh(&cylinder);
}

/* Padding the 3D embedding with zero coordinates changes nothing: checks the 4D and LAPACK plane fits. */
static void test_higher_dimensions_agree(void)
{
    mesh cylinder = make_cylinder(10, 5, 1);
    for (size_t k = 0; k < 3 * cylinder.vertex_count; ++k) /* no ties between merge costs */
        cylinder.positions[k] += random_uniform(-0.05, 0.05);
    int32_t *reference = allocate(cylinder.triangle_count, sizeof(int32_t));
    int32_t *charts = allocate(cylinder.triangle_count, sizeof(int32_t));
    const sk_segment_options options = greedy(4, 0.0);
    sk_segment_report reference_report, report;
    EXPECT_SUCCESS("3D", sk_segment(reference, &reference_report,
                                    &(sk_triangle_mesh){cylinder.triangles, cylinder.triangle_count, cylinder.vertex_count},
                                    cylinder.positions, 3, NULL, 0, &options, error));
    const size_t dimensions[3] = {4, 6, 8};
    for (int k = 0; k < 3; ++k) {
        double *embedding = padded(&cylinder, dimensions[k]);
        char context[32];
        snprintf(context, sizeof context, "%zu dimensions", dimensions[k]);
        EXPECT_SUCCESS(context, sk_segment(charts, &report,
                                           &(sk_triangle_mesh){cylinder.triangles, cylinder.triangle_count, cylinder.vertex_count},
                                           embedding, dimensions[k], NULL, 0, &options, error));
        CHECK_IN(context, !memcmp(charts, reference, cylinder.triangle_count * sizeof(int32_t)));
        CHECK_IN(context, fabs(report.mesh_metric - reference_report.mesh_metric) < 1e-9);
        free(embedding);
    }
    free(charts);
    free(reference);
    free_test_mesh(&cylinder);
}

static void test_degenerate_triangles(void)
{
    mesh grid = make_grid(4, 4);
    for (size_t v = 0; v < grid.vertex_count; ++v) /* squash a column of quads to zero width */
        if (grid.positions[3 * v] >= 2.0)
            grid.positions[3 * v] -= 1.0;
    int32_t *charts = allocate(grid.triangle_count, sizeof(int32_t));
    sk_segment_report report;
    const sk_segment_options two = greedy(2, 0.0);
    EXPECT_SUCCESS("zero-area triangles", sk_segment(charts, &report,
                                                     &(sk_triangle_mesh){grid.triangles, grid.triangle_count, grid.vertex_count},
                                                     grid.positions, 3, NULL, 0, &two, error));
    CHECK(report.chart_count <= 2 && isfinite(report.mesh_metric) && all_discs(&grid, charts));
    free(charts);
    free_test_mesh(&grid);
}

static size_t corners_on_chart(const mesh *m, const int32_t *charts, const unsigned char *corners, int32_t c)
{
    unsigned char *counted = calloc(m->vertex_count, 1);
    size_t count = 0;
    for (size_t t = 0; t < m->triangle_count; ++t)
        for (int k = 0; charts[t] == c && k < 3; ++k) {
            const int32_t v = m->triangles[3 * t + k];
            if (corners[v] && !counted[v]) {
                counted[v] = 1;
                ++count;
            }
        }
    free(counted);
    return count;
}

static void test_corners(void)
{
    mesh grid = make_grid(6, 6);
    int32_t *charts = allocate(grid.triangle_count, sizeof(int32_t));
    unsigned char *corners = allocate(grid.vertex_count, 1);
    EXPECT_SUCCESS("one chart", sk_chart_corners(corners,
                                                 &(sk_triangle_mesh){grid.triangles, grid.triangle_count, grid.vertex_count},
                                                 charts, grid.positions, 3, error));
    size_t count = 0;
    for (size_t v = 0; v < grid.vertex_count; ++v)
        count += corners[v];
    CHECK_IN("a lone chart gets three corners", count == 3);
    CHECK_IN("starting from its lowest vertex", corners[0]);
    /* Left and right halves: the two ends of the middle line are corners (two charts on the border). */
    for (size_t t = 0; t < grid.triangle_count; ++t)
        charts[t] = (t / 2) % 6 < 3 ? 0 : 1;
    EXPECT_SUCCESS("two halves", sk_chart_corners(corners,
                                                  &(sk_triangle_mesh){grid.triangles, grid.triangle_count, grid.vertex_count},
                                                  charts, NULL, 0, error));
    CHECK(corners[3] && corners[6 * 7 + 3]);
    CHECK(corners_on_chart(&grid, charts, corners, 0) >= 3 && corners_on_chart(&grid, charts, corners, 1) >= 3);
    count = 0;
    for (size_t v = 0; v < grid.vertex_count; ++v)
        count += corners[v];
    CHECK_IN("two natural corners and one added per chart", count == 4);
    free(corners);
    free(charts);
    free_test_mesh(&grid);
}

/* A staircase boundary between two halves of a grid is straightened to the grid's middle line. */
static void test_straightening(void)
{
    const size_t n = 8;
    mesh grid = make_grid(n, n);
    int32_t *charts = allocate(grid.triangle_count, sizeof(int32_t));
    for (size_t t = 0; t < grid.triangle_count; ++t) {
        const size_t i = (t / 2) % n, j = (t / 2) / n;
        charts[t] = i < n / 2 + (j % 2) ? 0 : 1; /* the boundary zigzags between x = 4 and x = 5 */
    }
    unsigned char *corners = allocate(grid.vertex_count, 1), *before = allocate(grid.vertex_count, 1);
    sk_straighten_report report;
    EXPECT_SUCCESS("corners", sk_chart_corners(before,
                                               &(sk_triangle_mesh){grid.triangles, grid.triangle_count, grid.vertex_count},
                                               charts, grid.positions, 3, error));
    EXPECT_SUCCESS("straighten", sk_straighten_charts(charts, corners, &report,
                                                      &(sk_triangle_mesh){grid.triangles, grid.triangle_count, grid.vertex_count},
                                                      grid.positions, 3, &(sk_straighten_options){1.2, 0.2}, error));
    CHECK(!memcmp(corners, before, grid.vertex_count));
    CHECK(report.paths == report.shortest + report.constrained + report.kept && report.shortest >= 1);
    CHECK(all_discs(&grid, charts));
    CHECK(corners_on_chart(&grid, charts, corners, 0) >= 3 && corners_on_chart(&grid, charts, corners, 1) >= 3);
    /* The corners are (4, 0) and (4 or 5, 8); the shortest route is straight up, so every triangle of chart 0
     * lies left of x = 5 and the boundary has no more zigzag. */
    size_t left = 0;
    for (size_t t = 0; t < grid.triangle_count; ++t)
        left += charts[t] == 0;
    int straight = 1;
    for (size_t t = 0; t < grid.triangle_count; ++t) {
        double x = 0.0;
        for (int k = 0; k < 3; ++k)
            x += grid.positions[3 * (size_t)grid.triangles[3 * t + k]] / 3.0;
        straight &= (charts[t] == 0) == (x < 4.0) || (x > 4.0 && x < 5.0);
    }
    CHECK_IN("the boundary runs straight between its corners", straight);
    CHECK(left > 0 && left < grid.triangle_count);
    free(before);
    free(corners);
    free(charts);
    free_test_mesh(&grid);
}

static void test_bad_input(void)
{
    mesh grid = make_grid(2, 2);
    int32_t *charts = allocate(grid.triangle_count + 1, sizeof(int32_t));
    unsigned char *corners = allocate(grid.vertex_count, 1);
    const sk_segment_options options = greedy(1, 0.0);
    /* A third triangle on edge (0, 4): non-manifold. */
    int32_t fin[3 * 9];
    memcpy(fin, grid.triangles, 3 * 8 * sizeof(int32_t));
    fin[24] = 0, fin[25] = 4, fin[26] = 2;
    int32_t *bad = exact_copy_int32(fin, 27);
    EXPECT_FAILURE("non-manifold edge", SK_ERROR_ARGUMENT,
                   sk_segment(charts, NULL, &(sk_triangle_mesh){bad, 9, grid.vertex_count}, grid.positions, 3, NULL,
                              0, &options, error));
    sk_error record = empty_error();
    sk_segment(charts, NULL, &(sk_triangle_mesh){bad, 9, grid.vertex_count}, grid.positions, 3, NULL, 0, &options,
               &record);
    CHECK_IN(record.message, strstr(record.message, "edge (0, 4)") != NULL);
    EXPECT_FAILURE("non-manifold corners", SK_ERROR_ARGUMENT,
                   sk_chart_corners(corners, &(sk_triangle_mesh){bad, 9, grid.vertex_count}, charts, NULL, 0, error));
    bad[26] = 9; /* out of range */
    EXPECT_FAILURE("vertex index", SK_ERROR_INDEX,
                   sk_segment(charts, NULL, &(sk_triangle_mesh){bad, 9, grid.vertex_count}, grid.positions, 3, NULL,
                              0, &options, error));
    bad[26] = 0; /* repeats a vertex */
    EXPECT_FAILURE("repeated vertex", SK_ERROR_ARGUMENT,
                   sk_segment(charts, NULL, &(sk_triangle_mesh){bad, 9, grid.vertex_count}, grid.positions, 3, NULL,
                              0, &options, error));
    free(bad);
    const int32_t not_edge[2] = {0, 8}, outside[2] = {0, 9};
    EXPECT_FAILURE("seam not an edge", SK_ERROR_ARGUMENT,
                   sk_segment(charts, NULL, &(sk_triangle_mesh){grid.triangles, 8, grid.vertex_count}, grid.positions,
                              3, not_edge, 1, &options, error));
    EXPECT_FAILURE("seam vertex", SK_ERROR_INDEX,
                   sk_segment(charts, NULL, &(sk_triangle_mesh){grid.triangles, 8, grid.vertex_count}, grid.positions,
                              3, outside, 1, &options, error));
    EXPECT_FAILURE("dimension", SK_ERROR_ARGUMENT,
                   sk_segment(charts, NULL, &(sk_triangle_mesh){grid.triangles, 8, 1}, grid.positions, 9, NULL, 0,
                              &options, error));
    const sk_segment_options negative = {SK_SEGMENT_GREEDY, 0, 0.0, -1.0}, unknown = {(sk_segment_mode)7, 0, 0.0, 0.2};
    EXPECT_FAILURE("rho", SK_ERROR_ARGUMENT,
                   sk_segment(charts, NULL, &(sk_triangle_mesh){grid.triangles, 8, grid.vertex_count}, grid.positions,
                              3, NULL, 0, &negative, error));
    EXPECT_FAILURE("mode", SK_ERROR_ARGUMENT,
                   sk_segment(charts, NULL, &(sk_triangle_mesh){grid.triangles, 8, grid.vertex_count}, grid.positions,
                              3, NULL, 0, &unknown, error));
    EXPECT_FAILURE("no triangles", SK_ERROR_ARGUMENT,
                   sk_segment(charts, NULL, &(sk_triangle_mesh){grid.triangles, 0, grid.vertex_count}, grid.positions,
                              3, NULL, 0, &options, error));
    double *nan_positions = exact_copy_double(grid.positions, 3 * grid.vertex_count);
    nan_positions[7] = NAN;
    EXPECT_FAILURE("NaN", SK_ERROR_NOT_FINITE,
                   sk_segment(charts, NULL, &(sk_triangle_mesh){grid.triangles, 8, grid.vertex_count}, nan_positions,
                              3, NULL, 0, &options, error));
    free(nan_positions);
    /* Charts: out of range, or not discs (two triangles meeting only at vertex 4). */
    for (size_t t = 0; t < 8; ++t)
        charts[t] = 0;
    charts[3] = 8;
    EXPECT_FAILURE("chart range", SK_ERROR_INDEX,
                   sk_chart_corners(corners, &(sk_triangle_mesh){grid.triangles, 8, grid.vertex_count}, charts, NULL,
                                    0, error));
    for (size_t t = 0; t < 8; ++t)
        charts[t] = t == 0 || t == 7 ? 1 : 2;
    EXPECT_FAILURE("chart touching itself", SK_ERROR_ARGUMENT,
                   sk_chart_corners(corners, &(sk_triangle_mesh){grid.triangles, 8, grid.vertex_count}, charts, NULL,
                                    0, error));
    EXPECT_FAILURE("straighten non-disc", SK_ERROR_ARGUMENT,
                   sk_straighten_charts(charts, corners, NULL,
                                        &(sk_triangle_mesh){grid.triangles, 8, grid.vertex_count}, grid.positions, 3,
                                        &(sk_straighten_options){1.2, 0.2}, error));
    for (size_t t = 0; t < 8; ++t)
        charts[t] = 0;
    EXPECT_FAILURE("ratio below 1", SK_ERROR_ARGUMENT,
                   sk_straighten_charts(charts, corners, NULL,
                                        &(sk_triangle_mesh){grid.triangles, 8, grid.vertex_count}, grid.positions, 3,
                                        &(sk_straighten_options){0.5, 0.2}, error));
    mesh box = make_box(1);
    int32_t *box_charts = allocate(box.triangle_count, sizeof(int32_t));
    unsigned char *box_corners = allocate(box.vertex_count, 1);
    EXPECT_FAILURE("a closed surface is not a chart", SK_ERROR_ARGUMENT,
                   sk_chart_corners(box_corners,
                                    &(sk_triangle_mesh){box.triangles, box.triangle_count, box.vertex_count},
                                    box_charts, NULL, 0, error));
    free(box_corners);
    free(box_charts);
    free_test_mesh(&box);
    free(corners);
    free(charts);
    free_test_mesh(&grid);
}

/* Random triangle soups and random chart labels: every call returns a status, the sanitizers see no fault. */
static void test_malformed_input_is_safe(void)
{
    const size_t vertex_count = 12, triangle_count = 20;
    for (int round = 0; round < 200; ++round) {
        int32_t *triangles = allocate(3 * triangle_count, sizeof(int32_t));
        for (size_t k = 0; k < 3 * triangle_count; ++k)
            triangles[k] = (int32_t)random_below(vertex_count + 1) - (random_below(20) == 0);
        int32_t *exact = exact_copy_int32(triangles, 3 * triangle_count);
        double *positions = allocate(3 * vertex_count, sizeof(double));
        for (size_t k = 0; k < 3 * vertex_count; ++k)
            positions[k] = random_uniform(-1.0, 1.0);
        double *exact_positions = exact_copy_double(positions, 3 * vertex_count);
        int32_t *charts = allocate(triangle_count, sizeof(int32_t));
        unsigned char *corners = allocate(vertex_count, 1);
        const sk_segment_options options = greedy(1 + random_below(4), 0.0);
        sk_error record;
        const sk_status status = sk_segment(charts, NULL, &(sk_triangle_mesh){exact, triangle_count, vertex_count},
                                            exact_positions, 3, NULL, 0, &options, &record);
        CHECK(status == SK_OK || status == SK_ERROR_ARGUMENT || status == SK_ERROR_INDEX);
        for (size_t t = 0; t < triangle_count; ++t)
            charts[t] = status == SK_OK && random_below(2) ? charts[t] : (int32_t)random_below(triangle_count + 1);
        const sk_status corner_status = sk_chart_corners(corners,
                                                         &(sk_triangle_mesh){exact, triangle_count, vertex_count},
                                                         charts, exact_positions, 3, &record);
        const sk_status straighten_status = sk_straighten_charts(charts, corners, NULL,
                                                                 &(sk_triangle_mesh){exact, triangle_count, vertex_count},
                                                                 exact_positions, 3,
                                                                 &(sk_straighten_options){1.2, 0.2}, &record);
        CHECK(corner_status != SK_ERROR_MEMORY && straighten_status != SK_ERROR_MEMORY);
        free(corners);
        free(charts);
        free(exact_positions);
        free(positions);
        free(exact);
        free(triangles);
    }
}

int main(void)
{
    test_program_name = "test_segment";
    test_closed_box_needs_two_discs();
    test_grid_target_and_threshold();
    test_capped_cylinder_seams();
    test_higher_dimensions_agree();
    test_degenerate_triangles();
    test_corners();
    test_straightening();
    test_bad_input();
    test_malformed_input_is_safe();
    return finish_tests();
}
