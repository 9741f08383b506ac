/*
 * Tangent-space normal maps (Merry 2007, section 7.5): for every texel a target triangle covers, the source
 * surface's normal expressed in the target's interpolated MikkTSpace frame, encoded 0.5 n + 0.5.
 * SPDX-License-Identifier: GPL-3.0-or-later
 *
 * Coverage is conservative: a texel belongs to every uv triangle its square overlaps (so bilinear filtering
 * along a chart's border never reads an unbaked texel). Each texel averages its s x s samples that fall inside a
 * triangle; a touched texel with no sample inside is evaluated at the point of the nearest triangle closest to
 * its centre. The source normal comes from the same uv point on the source (the shared atlas of a LOD chain),
 * or from the nearest hit of a segment along the target's interpolated normal, within the cage distance each
 * way, or (guided) from that hit where its normal agrees with the same uv point's. A margin of dilation passes
 * then copies the average of filled neighbours outwards so that mip-maps do not bleed the background into the
 * charts.
 *
 * Work runs over batches of texel rows (each row is independent, so any thread count gives the same bits);
 * progress is reported between batches on the calling thread.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_bake_internal.h"
#include "sk_internal.h"

#define TILE_TEXELS 8
#define BATCH_ROWS 32
#define MAX_SUPERSAMPLE 8
#define MAX_MARGIN 127 /* passes are marked in a byte (2 pass + 1) */
#define MIN_UV_AREA 1e-14
/* A point strictly inside two triangles by this much (in barycentric weight) is an overlap, not a shared edge. */
#define OVERLAP_WEIGHT 1e-6
/* The atlas lookup snaps a uv point to a source triangle at most this many texels away. */
#define SNAP_TEXELS 1.5

/* ---------------------------------------------------------------------------------------------
 * Uv bins: a grid of cells over the unit square, each listing the triangles whose uv box (grown by `grow`)
 * meets it (CSR)
 * ------------------------------------------------------------------------------------------- */

typedef struct uv_bins {
    size_t cells;   /* per side */
    double scale;   /* cells per unit of uv */
    int flip_v;     /* rows count down from v = 1 (texel rows) rather than up from v = 0 */
    size_t *offsets;
    int32_t *triangles;
} uv_bins;

/* The least and the largest of three finite values (libm's fmin and fmax were calls in the profile). */
static double smallest3(double a, double b, double c)
{
    const double ab = a < b ? a : b;
    return ab < c ? ab : c;
}

static double largest3(double a, double b, double c)
{
    const double ab = a > b ? a : b;
    return ab > c ? ab : c;
}

/* The cell holding a cell coordinate, clamped to the grid: the same as flooring it and clamping, with the cast made
 * only inside [0, cells - 1] (cheaper than floor, and a cell range is found per triangle and per snap). The casts go
 * through long (a grid has at most MAX_BIN_CELLS a side: the same values), one instruction each where size_t's
 * unsigned conversions are several. */
static size_t clamped_cell(double coordinate, size_t cells)
{
    return coordinate <= 0 ? 0 : (coordinate >= (double)(long)(cells - 1) ? cells - 1 : (size_t)(long)coordinate);
}

/* The cells a uv triangle's box (grown by `grow`) meets: columns range[0]-range[1], rows range[2]-range[3] (rows
 * counting down from v = 1 when flip_v, so the box's top is the first row). */
static void cell_range(size_t range[4], const uv_bins *bins, const double *uv, double grow)
{
    const double scale = bins->scale;
    const double low_u = smallest3(uv[0], uv[2], uv[4]) - grow, high_u = largest3(uv[0], uv[2], uv[4]) + grow;
    const double low_v = smallest3(uv[1], uv[3], uv[5]) - grow, high_v = largest3(uv[1], uv[3], uv[5]) + grow;
    range[0] = clamped_cell(low_u * scale, bins->cells);
    range[1] = clamped_cell(high_u * scale, bins->cells);
    range[2] = clamped_cell((bins->flip_v ? 1 - high_v : low_v) * scale, bins->cells);
    range[3] = clamped_cell((bins->flip_v ? 1 - low_v : high_v) * scale, bins->cells);
}

static double uv_area2(const double *uv)
{
    return (uv[2] - uv[0]) * (uv[5] - uv[1]) - (uv[3] - uv[1]) * (uv[4] - uv[0]);
}

/* A uv triangle's barycentric map, precomputed once per triangle: the weights of corners 1 and 2 at (u, v) are
 * w1 = (u - u0) a1u + (v - v0) a1v and w2 = (u - u0) a2u + (v - v0) a2v (the per-texel tests were the bake's largest
 * cost while each recomputed its area and divided). area2 is the doubled signed area; a triangle with
 * |area2| < MIN_UV_AREA is skipped by every test. */
typedef struct uv_frame {
    double u0, v0, a1u, a1v, a2u, a2v, area2;
} uv_frame;

/* A uv triangle's box. Kept apart from its frame, and only for the target: the source's containment tests, most of
 * the bake's random reads, then touch 56 bytes a triangle instead of 88 (the source's frames were the largest
 * buffer after the image: 1.5 MB of the horse's 8 MB a bake), and its snap forms the box from the uv. */
typedef struct uv_box {
    double low[2], high[2];
} uv_box;

static uv_box triangle_box(const double *c)
{
    return (uv_box){{smallest3(c[0], c[2], c[4]), smallest3(c[1], c[3], c[5])},
                    {largest3(c[0], c[2], c[4]), largest3(c[1], c[3], c[5])}};
}

/* The frames of the triangles, and where boxes is not NULL their boxes. */
static sk_status build_uv_frames(uv_frame **frames, uv_box **boxes, const double *uv, size_t triangle_count,
                                 sk_error *error)
{
    *frames = sk_allocate(triangle_count ? triangle_count : 1, sizeof(uv_frame));
    if (boxes)
        *boxes = sk_allocate(triangle_count ? triangle_count : 1, sizeof(uv_box));
    if (!*frames || (boxes && !*boxes))
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu uv triangles", triangle_count);
    for (size_t t = 0; t < triangle_count; ++t) {
        const double *c = uv + 6 * t, area2 = uv_area2(c), inverse = fabs(area2) < MIN_UV_AREA ? 0 : 1.0 / area2;
        (*frames)[t] = (uv_frame){c[0], c[1], (c[5] - c[1]) * inverse, -(c[4] - c[0]) * inverse,
                                  -(c[3] - c[1]) * inverse, (c[2] - c[0]) * inverse, area2};
        if (boxes)
            (*boxes)[t] = triangle_box(c);
    }
    return SK_OK;
}

/* A triangle's cell range in a bin grid (x first, x last, y first, y last): the grid has at most MAX_BIN_CELLS a
 * side, so 16 bits each (a quarter of size_t's: the ranges of a large source were pages of memory faulted in per
 * bake). */
#define MAX_BIN_CELLS 65536
typedef struct cell_span {
    uint16_t range[4];
} cell_span;

/* Bins list only the triangles with a usable uv area (|area2| >= MIN_UV_AREA, read from their frames, which hold
 * it: recomputing it here showed in the instruction counts): every search skipped the others, and now need not test
 * each candidate's area. */
static sk_status build_bins(uv_bins *bins, const double *uv, const uv_frame *frames, size_t triangle_count,
                            size_t cells, double scale, int flip_v, double grow, sk_error *error)
{
    size_t cell_count;
    sk_status status = sk_array_size(&cell_count, cells, cells, 1, "uv cells", error);
    if (status != SK_OK)
        return status;
    if (cells > MAX_BIN_CELLS)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%zu uv cells a side exceed %d", cells, MAX_BIN_CELLS);
    *bins = (uv_bins){cells, scale, flip_v, sk_allocate_zeroed(cell_count + 1, sizeof(size_t)), NULL};
    /* Each triangle's cell range, found once for both passes (an empty range, first > last, for a skipped one). */
    cell_span *ranges = sk_allocate(triangle_count ? triangle_count : 1, sizeof(cell_span));
    if (!bins->offsets || !ranges) {
        free(ranges);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu uv cells", cell_count);
    }
    /* The entries' total, checked once: no partial sum of the cells' counts can then wrap. */
    size_t entries = 0;
    for (size_t t = 0; t < triangle_count; ++t) {
        size_t range[4], cells_met;
        if (fabs(frames[t].area2) < MIN_UV_AREA) {
            ranges[t] = (cell_span){{1, 0, 1, 0}};
            continue;
        }
        cell_range(range, bins, uv + 6 * t, grow);
        for (int k = 0; k < 4; ++k)
            ranges[t].range[k] = (uint16_t)range[k];
        if (!sk_mul_size(range[1] - range[0] + 1, range[3] - range[2] + 1, &cells_met) ||
            !sk_add_size(entries, cells_met, &entries)) {
            free(ranges);
            return sk_fail(error, SK_ERROR_MEMORY, "too many uv cell entries");
        }
    }
    /* Each cell's count, then the cells' starts, then the fill (which advances each start to its cell's end). */
    for (size_t t = 0; t < triangle_count; ++t) {
        const cell_span span = ranges[t];
        for (size_t y = span.range[2]; y <= span.range[3]; ++y) {
            size_t *counts = bins->offsets + y * cells + 1;
            for (size_t x = span.range[0]; x <= span.range[1]; ++x)
                ++counts[x];
        }
    }
    for (size_t c = 0; c < cell_count; ++c)
        bins->offsets[c + 1] += bins->offsets[c];
    bins->triangles = sk_allocate(entries, sizeof(int32_t));
    if (!bins->triangles) {
        free(ranges);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu uv cell entries", entries);
    }
    for (size_t t = 0; t < triangle_count; ++t) {
        const cell_span span = ranges[t];
        for (size_t y = span.range[2]; y <= span.range[3]; ++y) {
            size_t *next = bins->offsets + y * cells;
            for (size_t x = span.range[0]; x <= span.range[1]; ++x)
                bins->triangles[next[x]++] = (int32_t)t;
        }
    }
    memmove(bins->offsets + 1, bins->offsets, cell_count * sizeof(size_t));
    bins->offsets[0] = 0;
    free(ranges);
    return SK_OK;
}

static void free_bins(uv_bins *bins) { SK_FREE_ALL(bins->offsets, bins->triangles); }

/* ---------------------------------------------------------------------------------------------
 * Uv triangle geometry
 * ------------------------------------------------------------------------------------------- */

/* Barycentric weights of point p in the uv triangle (area2 its doubled signed area, non-zero). */
static void barycentric(double weights[3], const double *uv, double area2, double u, double v)
{
    const double inverse = 1.0 / area2; /* one division, not two: this runs per texel and candidate */
    weights[1] = ((u - uv[0]) * (uv[5] - uv[1]) - (v - uv[1]) * (uv[4] - uv[0])) * inverse;
    weights[2] = ((uv[2] - uv[0]) * (v - uv[1]) - (uv[3] - uv[1]) * (u - uv[0])) * inverse;
    weights[0] = 1 - weights[1] - weights[2];
}

/* Whether (u, v) lies in the triangle (weights all >= 0), filling its weights. */
static int frame_contains(double weights[3], const uv_frame *frame, double u, double v)
{
    const double du = u - frame->u0, dv = v - frame->v0;
    weights[1] = du * frame->a1u + dv * frame->a1v;
    weights[2] = du * frame->a2u + dv * frame->a2v;
    weights[0] = 1 - weights[1] - weights[2];
    return weights[0] >= 0 && weights[1] >= 0 && weights[2] >= 0;
}

/* Squared uv distance from the point to the uv box (0 inside it). */
static double box_distance2(const uv_box *box, const double point[2])
{
    double distance2 = 0;
    for (int k = 0; k < 2; ++k) {
        const double below = box->low[k] - point[k], above = point[k] - box->high[k];
        const double gap = below > 0 ? below : (above > 0 ? above : 0);
        distance2 += gap * gap;
    }
    return distance2;
}

/* Squared uv distance from (u, v) to the triangle, with the weights of its closest point. */
static double closest_point(double weights[3], const double *uv, double area2, double u, double v)
{
    barycentric(weights, uv, area2, u, v);
    if (weights[0] >= 0 && weights[1] >= 0 && weights[2] >= 0)
        return 0;
    double best = INFINITY;
    for (int k = 0; k < 3; ++k) {
        const int next = (k + 1) % 3;
        const double ax = uv[2 * k], ay = uv[2 * k + 1], dx = uv[2 * next] - ax, dy = uv[2 * next + 1] - ay;
        const double length2 = dx * dx + dy * dy;
        double s = length2 > 0 ? ((u - ax) * dx + (v - ay) * dy) / length2 : 0;
        s = s < 0 ? 0 : (s > 1 ? 1 : s);
        const double ex = ax + s * dx - u, ey = ay + s * dy - v, distance2 = ex * ex + ey * ey;
        if (distance2 < best) {
            best = distance2;
            weights[k] = 1 - s;
            weights[next] = s;
            weights[3 - k - next] = 0;
        }
    }
    return best;
}

/* The separating-axis test of a uv triangle's edges against squares, prepared once per triangle: each edge's start
 * and direction, and which corner of a square lies furthest inside it (the edge function is linear: its largest
 * value over the square is at that corner). */
typedef struct edge_test {
    double orientation, ax[3], ay[3], dx[3], dy[3];
    unsigned char high_u[3], high_v[3];
} edge_test;

static void prepare_edge_test(edge_test *test, const double *uv, double area2)
{
    test->orientation = area2 > 0 ? 1 : -1;
    for (int k = 0; k < 3; ++k) {
        const int next = (k + 1) % 3;
        test->ax[k] = uv[2 * k];
        test->ay[k] = uv[2 * k + 1];
        test->dx[k] = uv[2 * next] - test->ax[k];
        test->dy[k] = uv[2 * next + 1] - test->ay[k];
        test->high_u[k] = (test->orientation * -test->dy[k]) > 0;
        test->high_v[k] = (test->orientation * test->dx[k]) > 0;
    }
}

/* Whether the square [u0, u1] x [v0, v1] reaches inside every edge. */
static int edges_admit_square(const edge_test *test, double u0, double v0, double u1, double v1)
{
    for (int k = 0; k < 3; ++k) {
        const double u = test->high_u[k] ? u1 : u0, v = test->high_v[k] ? v1 : v0;
        if (test->orientation * (test->dx[k] * (v - test->ay[k]) - test->dy[k] * (u - test->ax[k])) < 0)
            return 0;
    }
    return 1;
}

/* Whether the uv triangle overlaps the square [u0, u1] x [v0, v1] (separating axes: the box's and the edges'). */
static int overlaps_square(const double *uv, double area2, const uv_box *box, double u0, double v0, double u1,
                           double v1)
{
    if (box->high[0] < u0 || box->low[0] > u1 || box->high[1] < v0 || box->low[1] > v1)
        return 0;
    edge_test test;
    prepare_edge_test(&test, uv, area2);
    return edges_admit_square(&test, u0, v0, u1, v1);
}

/* ---------------------------------------------------------------------------------------------
 * The bake
 * ------------------------------------------------------------------------------------------- */

/* The texels around a target triangle's uv box, one more each way and clamped to the image (rows counting down
 * from v = 1): columns column0-column1, rows row0-row1 (row0 > row1 for a triangle without a usable uv area). */
typedef struct triangle_span {
    uint32_t column0, column1, row0, row1;
} triangle_span;

typedef struct bake_context {
    float *image;
    unsigned char *coverage;
    double *exact, *frames;
    const sk_bake_surface *target, *source;
    const double *tangents;
    const sk_bake_options *options;
    uv_bins target_bins, source_bins;
    uv_frame *target_frames, *source_frames; /* source_frames: atlas bakes and tangent maps only */
    uv_box *target_boxes;
    /* The texel centres of the batch of rows from row_begin, rasterised before the batch (rasterise_centres): per
     * texel the first target triangle containing its centre (-1: none), and the flags below, so that the
     * centre queries do not search the tile's triangles. A batch's rows, not the image's: 80 kB at 512 that stay in
     * the cache between their writing and their reading, where the image's 1.3 MB were faulted in, written and then
     * read back from memory. */
    int32_t *centre_triangles;
    unsigned char *centre_flags;
    triangle_span *spans; /* per target triangle, the texels rasterise_centres visits */
    /* Per batch of rows, the target triangles whose spans meet it, ascending (CSR: batch b's are
     * batch_triangles[batch_offsets[b]] to batch_triangles[batch_offsets[b + 1] - 1]): each batch then visits its
     * own triangles rather than testing every triangle's span (16 passes over the whole list at 512). */
    size_t *batch_offsets;
    int32_t *batch_triangles;
    sk_bvh bvh;
    size_t row_begin;
    double texel_size; /* 1 / options->size */
    double guide_cosine; /* cos SK_BAKE_GUIDE_DEGREES */
    size_t overlaps[SK_MAX_WORKERS];
    size_t first_overlap[SK_MAX_WORKERS]; /* texel index, or SIZE_MAX */
} bake_context;

static void interpolate(double out[3], const double *corners, const double weights[3])
{
    for (int k = 0; k < 3; ++k)
        out[k] = weights[0] * corners[k] + weights[1] * corners[3 + k] + weights[2] * corners[6 + k];
}

static int normalise(double v[3])
{
    const double length = sqrt(sk_dot3(v, v));
    if (!(length > 0))
        return 0;
    for (int k = 0; k < 3; ++k)
        v[k] /= length;
    return 1;
}

/* The range of bins->triangles listing the cell of a uv point (bins counting rows up from v = 0); casts through long
 * as clamped_cell's. */
static void point_cell(size_t *begin, size_t *end, const uv_bins *bins, const double point[2])
{
    const size_t cells = bins->cells;
    const double side = (double)(long)cells;
    const size_t x = point[0] >= 1 ? cells - 1 : (point[0] <= 0 ? 0 : (size_t)(long)(point[0] * side));
    const size_t y = point[1] >= 1 ? cells - 1 : (point[1] <= 0 ? 0 : (size_t)(long)(point[1] * side));
    *begin = bins->offsets[y * cells + x];
    *end = bins->offsets[y * cells + x + 1];
}

/* The snap's best so far: the squared uv distance (the snap's square to begin with), the triangle (-1: none yet) and
 * the weights of its closest point. */
typedef struct snap_best {
    double distance2, weights[3];
    int32_t triangle;
} snap_best;

/* Measures the triangles of cell (x, y) against the best (the least distance, the lowest index among equals). A
 * triangle whose uv box is further than the best so far cannot be closer (most of the cells' triangles: the exact
 * distance is the dearest test of the snap); the best itself is not measured again. */
static void snap_in_cell(snap_best *best, const bake_context *context, const double point[2], size_t x, size_t y)
{
    const uv_bins *bins = &context->source_bins;
    const uv_frame *frames = context->source_frames;
    for (size_t i = bins->offsets[y * bins->cells + x]; i < bins->offsets[y * bins->cells + x + 1]; ++i) {
        const int32_t t = bins->triangles[i];
        const double *uv = context->source->uv + 6 * (size_t)t;
        const uv_box box = triangle_box(uv);
        if (t == best->triangle || box_distance2(&box, point) > best->distance2)
            continue;
        double candidate[3];
        const double distance2 = closest_point(candidate, uv, frames[t].area2, point[0], point[1]);
        if (distance2 < best->distance2 || (distance2 == best->distance2 && (best->triangle < 0 || t < best->triangle))) {
            best->distance2 = distance2;
            best->triangle = t;
            memcpy(best->weights, candidate, sizeof candidate);
        }
    }
}

/* A lower bound of the squared uv distance from the point to cell (x, y) of the source bins (rows up from v = 0):
 * the cell's sides moved out by CELL_SLACK (rounding in the grid's cell of a value cannot then put a point outside
 * them), the grid's edge cells open outwards (they hold what the clamp puts there). */
#define CELL_SLACK 1e-9
static double cell_distance2(const uv_bins *bins, const double point[2], size_t x, size_t y)
{
    const size_t cell[2] = {x, y};
    double distance2 = 0;
    for (int k = 0; k < 2; ++k) {
        const double low = cell[k] == 0 ? -INFINITY : (double)(long)cell[k] / bins->scale - CELL_SLACK;
        const double high = cell[k] + 1 == bins->cells ? INFINITY : (double)(long)(cell[k] + 1) / bins->scale + CELL_SLACK;
        const double gap = point[k] < low ? low - point[k] : (point[k] > high ? point[k] - high : 0);
        distance2 += gap * gap;
    }
    return distance2;
}

/* The source triangle closest to a uv point that none contains, within the snap, with its weights there (-1: none
 * that near): over the cells the snap's square meets, the point's own first (the nearest is mostly there), then the
 * others not already further than the best, each whole (a triangle in several cells may be measured again: the
 * same distance, so the same answer). Kept out of source_at_point, whose common path then saves no registers for
 * it. */
SK_COLD static int32_t snap_to_source(double hit_weights[3], const bake_context *context, const double point[2])
{
    const double snap = SNAP_TEXELS / (double)context->options->size;
    const uv_bins *bins = &context->source_bins;
    snap_best best = {snap * snap, {0, 0, 0}, -1};
    size_t range[4], own[4];
    const double square[6] = {point[0] - snap, point[1] - snap, point[0] + snap, point[1] + snap,
                              point[0] + snap, point[1] + snap};
    const double spot[6] = {point[0], point[1], point[0], point[1], point[0], point[1]};
    cell_range(range, bins, square, 0);
    cell_range(own, bins, spot, 0);
    snap_in_cell(&best, context, point, own[0], own[2]);
    for (size_t y = range[2]; y <= range[3]; ++y)
        for (size_t x = range[0]; x <= range[1]; ++x)
            if ((x != own[0] || y != own[2]) && cell_distance2(bins, point, x, y) <= best.distance2)
                snap_in_cell(&best, context, point, x, y);
    if (best.triangle >= 0)
        memcpy(hit_weights, best.weights, sizeof best.weights);
    return best.triangle;
}

/* source_at_point past the hint: the first source triangle containing the point in cell order, else the closest
 * within the snap (-1: none). */
static int32_t source_in_cell(double hit_weights[3], const bake_context *context, const double point[2],
                              int32_t *hint)
{
    const uv_frame *frames = context->source_frames;
    size_t begin, end;
    point_cell(&begin, &end, &context->source_bins, point);
    for (size_t i = begin; i < end; ++i) {
        const int32_t t = context->source_bins.triangles[i];
        if (frame_contains(hit_weights, &frames[t], point[0], point[1]))
            return *hint = t;
    }
    return snap_to_source(hit_weights, context, point);
}

/* The source triangle at a uv point and its weights there (-1 when none is within the snap): the row's last source
 * triangle when it contains the point (neighbouring texels mostly share one; this test is inlined into the row loop,
 * where a call per texel showed in the profile), else source_in_cell's. frames: the source's (the row loop's copy,
 * read once a row: see texel_out). */
static inline int32_t source_at_point(double hit_weights[3], const bake_context *context, const uv_frame *frames,
                                      const double point[2], int32_t *hint)
{
    if (*hint >= 0 && frame_contains(hit_weights, &frames[*hint], point[0], point[1]))
        return *hint;
    return source_in_cell(hit_weights, context, point, hint);
}

/* source_at_point at the uv of the target point (triangle, weights). */
static int32_t source_at_uv(double hit_weights[3], const bake_context *context, int32_t triangle,
                            const double weights[3], int32_t *hint)
{
    double point[2] = {0, 0};
    for (int c = 0; c < 3; ++c)
        for (int k = 0; k < 2; ++k)
            point[k] += weights[c] * context->target->uv[6 * (size_t)triangle + 2 * (size_t)c + (size_t)k];
    return source_at_point(hit_weights, context, context->source_frames, point, hint);
}

/* The source triangle (-1: none) and its weights where the segment along the target's interpolated normal through
 * the target point first meets it within +-cage. */
static int32_t source_on_ray(double hit_weights[3], const bake_context *context, int32_t triangle,
                             const double weights[3], int32_t *hint)
{
    const sk_bake_surface *target = context->target;
    double origin[3], direction[3];
    int32_t hit = -1;
    for (int k = 0; k < 3; ++k) {
        origin[k] = 0;
        for (int c = 0; c < 3; ++c)
            origin[k] += weights[c] *
                         target->positions[3 * (size_t)target->triangles[3 * (size_t)triangle + (size_t)c] + (size_t)k];
    }
    interpolate(direction, target->normals + 9 * (size_t)triangle, weights);
    if (!normalise(direction))
        return -1;
    /* Where the interpolated normal grazes the surface (a simplified level's slivers tilt their vertex normals
     * almost into the face), its ray runs beside a source that lies well within the cage and misses it: the
     * closest source point within the cage stands in. */
    if (sk_bvh_nearest_hit(&context->bvh, origin, direction, context->options->cage, *hint, &hit, &hit_weights[1],
                           &hit_weights[2]) ||
        sk_bvh_closest_point(&context->bvh, origin, context->options->cage, -1, &hit, &hit_weights[1],
                             &hit_weights[2])) {
        hit_weights[0] = 1 - hit_weights[1] - hit_weights[2];
        *hint = hit;
    }
    return hit;
}

/* The source's normal at a source triangle's weights, normalised; 0 when there is none. */
static int source_normal_at(double normal[3], const bake_context *context, int32_t hit, const double hit_weights[3])
{
    if (hit < 0)
        return 0;
    interpolate(normal, context->source->normals + 9 * (size_t)hit, hit_weights);
    return normalise(normal);
}

/* The source's interpolated normal at the target point, or 0 when the source does not reach it. Guided: the ray's
 * where it agrees with the same uv point's (the ray finds the point a view along the normal sees, the atlas which
 * part of the surface it must be), else the same uv point's. */
static int source_normal(double normal[3], const bake_context *context, int32_t triangle, const double weights[3],
                         int32_t *hint)
{
    double hit_weights[3];
    const int mode = context->options->mode;
    if (mode == SK_BAKE_ATLAS)
        return source_normal_at(normal, context, source_at_uv(hit_weights, context, triangle, weights, hint),
                                hit_weights);
    if (mode == SK_BAKE_RAY_CAST)
        return source_normal_at(normal, context, source_on_ray(hit_weights, context, triangle, weights, hint),
                                hit_weights);
    double on_ray[3];
    const int atlas_found = source_normal_at(normal, context,
                                             source_at_uv(hit_weights, context, triangle, weights, hint), hit_weights);
    if (!source_normal_at(on_ray, context, source_on_ray(hit_weights, context, triangle, weights, hint), hit_weights))
        return atlas_found;
    if (atlas_found && sk_dot3(on_ray, normal) < context->guide_cosine)
        return 1;
    memcpy(normal, on_ray, sizeof on_ray);
    return 1;
}

/* The target's frame (T, B, N) from its interpolated tangent, normal and bitangent sign, left unnormalised as the
 * Normal Map node decodes (Cycles' svm_node_normal_map, and MikkTSpace's own rule: "the interpolated vectors, not
 * normalised", so that the baker is the exact inverse of the shader): B = sign N x T. A zero normal becomes +z, and
 * a tangent missing or parallel to the normal any unit vector orthogonal to it (the map stays decodable). */
static void make_frame(double frame[9], const double tangent[3], const double normal[3], double sign)
{
    double *t = frame, *b = frame + 3, *n = frame + 6;
    memcpy(t, tangent, 3 * sizeof(double));
    memcpy(n, normal, 3 * sizeof(double));
    double nn = sk_dot3(n, n);
    if (!(nn > 0)) {
        n[0] = n[1] = 0;
        n[2] = nn = 1;
    }
    sk_cross3(b, n, t);
    if (!(sk_dot3(b, b) > 2e-9 * sk_dot3(t, t) * nn)) {
        const double axis[3] = {fabs(n[0]) < 0.9 * sqrt(nn) ? 1 : 0, fabs(n[0]) < 0.9 * sqrt(nn) ? 0 : 1, 0};
        const double along = sk_dot3(axis, n) / nn;
        for (int k = 0; k < 3; ++k)
            t[k] = axis[k] - along * n[k];
        normalise(t);
        sk_cross3(b, n, t);
    }
    if (sign < 0)
        for (int k = 0; k < 3; ++k)
            b[k] = -b[k];
}

/* The target's frame at the point of triangle with these weights. */
static void target_frame(double frame[9], const bake_context *context, int32_t triangle, const double weights[3])
{
    double tangent[3] = {0, 0, 0}, normal[3], sign = 0;
    interpolate(normal, context->target->normals + 9 * (size_t)triangle, weights);
    for (int c = 0; c < 3; ++c) {
        const double *corner = context->tangents + 12 * (size_t)triangle + 4 * (size_t)c;
        for (int k = 0; k < 3; ++k)
            tangent[k] += weights[c] * corner[k];
        sign += weights[c] * corner[3];
    }
    make_frame(frame, tangent, normal, sign);
}

/* The object-space direction n in the frame: x with [T B N] x parallel to n, normalised (0 when n is zero). B is
 * orthogonal to T and N, so with the Gram entries of T and N the inverse is closed-form: x is proportional to
 * ((N.N)(T.n) - (T.N)(N.n), B.n, (T.T)(N.n) - (T.N)(T.n)), each over |N x T|^2 = |B|^2 > 0, which the
 * normalisation drops; n need not be unit either. */
static int encode_in_frame(double out[3], const double frame[9], const double n[3])
{
    const double *t = frame, *b = frame + 3, *normal = frame + 6;
    const double tt = sk_dot3(t, t), nn = sk_dot3(normal, normal), tn = sk_dot3(t, normal);
    const double t_dot = sk_dot3(t, n), n_dot = sk_dot3(normal, n);
    out[0] = nn * t_dot - tn * n_dot;
    out[1] = sk_dot3(b, n);
    out[2] = tt * n_dot - tn * t_dot;
    return normalise(out);
}

/* make_frame and encode_in_frame in one, for the row path's attributes (tangent, normal, sign): the Gram entries
 * are formed once and the frame is written only when it is kept; a zero normal or a tangent along it takes the
 * general path. */
static inline int encode_at(double out[3], double frame[9], const double attributes[7], const double n[3],
                            int keep_frame)
{
    const double *t = attributes, *normal = attributes + 3, sign = attributes[6] < 0 ? -1 : 1;
    double c[3];
    sk_cross3(c, normal, t);
    const double tt = sk_dot3(t, t), nn = sk_dot3(normal, normal), cc = sk_dot3(c, c);
    if (!(nn > 0) || !(cc > 2e-9 * tt * nn)) {
        make_frame(frame, t, normal, attributes[6]);
        return encode_in_frame(out, frame, n);
    }
    const double tn = sk_dot3(t, normal), t_dot = sk_dot3(t, n), n_dot = sk_dot3(normal, n);
    out[0] = nn * t_dot - tn * n_dot;
    out[1] = sign * sk_dot3(c, n);
    out[2] = tt * n_dot - tn * t_dot;
    if (keep_frame)
        for (int k = 0; k < 3; ++k) {
            frame[k] = t[k];
            frame[3 + k] = sign * c[k];
            frame[6 + k] = normal[k];
        }
    const double length2 = sk_dot3(out, out);
    if (!(length2 > 0))
        return 0;
    const double inverse = 1.0 / sqrt(length2);
    for (int k = 0; k < 3; ++k)
        out[k] *= inverse;
    return 1;
}

/* The source normal in the target's tangent frame at the point (see encode_in_frame). */
static int tangent_space_normal(double out[3], double object[3], double frame[9], const bake_context *context,
                                int32_t triangle, const double weights[3], int32_t *hint)
{
    if (!source_normal(object, context, triangle, weights, hint))
        return 0;
    target_frame(frame, context, triangle, weights);
    return encode_in_frame(out, frame, object);
}

/* A point of the texel (dx, dy in 0-1 from its top left corner) in uv, by one multiplication by the texel's size
 * (the same bits as dividing by a power-of-two image side; a division per texel showed in the CPU time). */
static void texel_uv(double *u, double *v, const bake_context *context, size_t column, size_t row, double dx, double dy)
{
    *u = ((double)(long)column + dx) * context->texel_size; /* through long: see clamped_cell */
    *v = 1 - ((double)(long)row + dy) * context->texel_size;
}

/* The first candidate triangle (of the texel's tile) containing the uv point, with its weights, or -1; *strictly
 * counts the candidates containing it by more than OVERLAP_WEIGHT. */
static int32_t containing_triangle(double weights[3], size_t *strictly, const bake_context *context, size_t first,
                                   size_t last, double u, double v)
{
    int32_t found = -1;
    double candidate[3];
    for (size_t e = first; e < last; ++e) {
        const int32_t t = context->target_bins.triangles[e];
        const uv_frame *frame = &context->target_frames[t];
        if (!frame_contains(candidate, frame, u, v))
            continue;
        *strictly += candidate[0] > OVERLAP_WEIGHT && candidate[1] > OVERLAP_WEIGHT && candidate[2] > OVERLAP_WEIGHT;
        if (found < 0) {
            found = t;
            memcpy(weights, candidate, sizeof candidate);
        }
    }
    return found;
}

/* The triangle touching the texel square whose closest point to the centre is nearest, with that point's weights
 * (the first among equals), or -1. */
static int32_t nearest_touching(double weights[3], const bake_context *context, size_t first, size_t last,
                                size_t column, size_t row)
{
    double centre_u, centre_v, u0, v0, u1, v1, best = INFINITY, candidate[3];
    int32_t nearest = -1;
    texel_uv(&centre_u, &centre_v, context, column, row, 0.5, 0.5);
    texel_uv(&u0, &v1, context, column, row, 0, 0);
    texel_uv(&u1, &v0, context, column, row, 1, 1);
    for (size_t e = first; e < last; ++e) {
        const int32_t t = context->target_bins.triangles[e];
        const double *uv = context->target->uv + 6 * (size_t)t, area2 = context->target_frames[t].area2;
        if (!overlaps_square(uv, area2, &context->target_boxes[t], u0, v0, u1, v1))
            continue;
        const double distance2 = closest_point(candidate, uv, area2, centre_u, centre_v);
        if (distance2 < best) {
            best = distance2;
            nearest = t;
            memcpy(weights, candidate, sizeof candidate);
        }
    }
    return nearest;
}

enum {
    CENTRE_TOUCHED = 1,        /* some target triangle overlaps the texel's square */
    CENTRE_STRICTLY_ONE = 2,   /* one triangle contains the centre by more than OVERLAP_WEIGHT */
    CENTRE_STRICTLY_MORE = 4   /* more than one does: overlapping uvs */
};
_Static_assert(CENTRE_STRICTLY_MORE == 2 * CENTRE_STRICTLY_ONE, "rasterise_row counts strict containments by a sum");

/* The u range of the uv triangle within the strip low_v <= v <= high_v: 0 when it misses the strip. */
static int strip_span(double *low_u, double *high_u, const double *uv, double low_v, double high_v)
{
    *low_u = INFINITY;
    *high_u = -INFINITY;
    for (int k = 0; k < 3; ++k) {
        const double *a = uv + 2 * k, *b = uv + 2 * ((k + 1) % 3);
        double t0 = 0, t1 = 1;
        const double dv = b[1] - a[1];
        if (dv != 0) {
            double enter = (low_v - a[1]) / dv, leave = (high_v - a[1]) / dv;
            if (enter > leave) {
                const double swap = enter;
                enter = leave;
                leave = swap;
            }
            t0 = enter > 0 ? enter : 0;
            t1 = leave < 1 ? leave : 1;
        } else if (a[1] < low_v || a[1] > high_v) {
            continue;
        }
        if (t0 > t1)
            continue;
        const double ua = a[0] + t0 * (b[0] - a[0]), ub = a[0] + t1 * (b[0] - a[0]);
        *low_u = smallest3(*low_u, ua, ub);
        *high_u = largest3(*high_u, ua, ub);
    }
    return *low_u <= *high_u;
}

/* floor(x) for a texel coordinate (a uv value in 0-1, validated, times the image side: far inside long's range),
 * by truncation through long: floor is a libm call without SSE4.1, and this runs four times a rasterised row. */
static double texel_floor(double x)
{
    const double truncated = (double)(long)x;
    return truncated > x ? truncated - 1 : truncated;
}

/* A texel's place in the batch's centre maps. */
static size_t centre_index(const bake_context *context, size_t column, size_t row)
{
    return (row - context->row_begin) * context->options->size + column;
}

/* Row `row` of rasterise_centres for triangle t, columns first to last: frame_contains and overlaps_square written
 * out with the row's terms formed once (the same operations on the same values, so the same bits). */
static void rasterise_row(bake_context *context, int32_t t, const uv_frame *frame, const uv_box *box,
                          const edge_test *edges, size_t row, size_t first, size_t last)
{
    const double step = context->texel_size;
    int32_t *triangles = context->centre_triangles + centre_index(context, 0, row);
    unsigned char *flags = context->centre_flags + centre_index(context, 0, row);
    /* texel_uv's centre row and the square's top and bottom */
    const double v = 1 - ((double)row + 0.5) * step, top = 1 - (double)row * step, bottom = 1 - ((double)row + 1) * step;
    const double dv = v - frame->v0, dv1 = dv * frame->a1v, dv2 = dv * frame->a2v;
    const int rows_meet_box = !(box->high[1] < bottom || box->low[1] > top);
    /* The column as a double, stepped by 1 (exact: the same value as converting it, which cost several
     * instructions a texel for an unsigned type). */
    double x = (double)(long)first;
    for (size_t column = first; column <= last; ++column, x += 1) {
        const double du = (x + 0.5) * step - frame->u0;
        const double w1 = du * frame->a1u + dv1, w2 = du * frame->a2u + dv2, w0 = 1 - w1 - w2;
        if (w0 >= 0 && w1 >= 0 && w2 >= 0) {
            if (triangles[column] < 0)
                triangles[column] = t;
            unsigned char state = flags[column]; /* one load and one store of the flags */
            /* ONE the first time, MORE (= 2 ONE) after: a sum without a branch (8 instructions a texel were 1% of
             * the horse's bake) */
            if (w0 > OVERLAP_WEIGHT && w1 > OVERLAP_WEIGHT && w2 > OVERLAP_WEIGHT)
                state |= (unsigned char)(CENTRE_STRICTLY_ONE + (state & CENTRE_STRICTLY_ONE));
            flags[column] = state | CENTRE_TOUCHED;
            continue;
        }
        if (flags[column] & CENTRE_TOUCHED || !rows_meet_box)
            continue;
        const double left = x * step, right = (x + 1) * step;
        if (!(box->high[0] < left || box->low[0] > right) && edges_admit_square(edges, left, bottom, right, top))
            flags[column] |= CENTRE_TOUCHED;
    }
}

/* Each target triangle's span (see triangle_span), found once for all the batches. */
static void find_spans(bake_context *context)
{
    const size_t size = context->options->size;
    const double scale = (double)size;
    for (size_t t = 0; t < context->target->triangle_count; ++t) {
        const uv_box *box = &context->target_boxes[t];
        if (fabs(context->target_frames[t].area2) < MIN_UV_AREA) {
            context->spans[t] = (triangle_span){0, 0, 1, 0};
            continue;
        }
        const double first_column = texel_floor(box->low[0] * scale) - 1;
        const double last_column = texel_floor(box->high[0] * scale) + 1;
        const double first_row = texel_floor((1 - box->high[1]) * scale) - 1;
        const double last_row = texel_floor((1 - box->low[1]) * scale) + 1;
        context->spans[t] = (triangle_span){first_column < 0 ? 0 : (uint32_t)first_column,
                                            last_column > scale - 1 ? (uint32_t)(size - 1) : (uint32_t)last_column,
                                            first_row < 0 ? 0 : (uint32_t)first_row,
                                            last_row > scale - 1 ? (uint32_t)(size - 1) : (uint32_t)last_row};
    }
}

/* The batches' lists of triangles (see bake_context) from the spans: each batch's count, the starts, then the fill
 * in triangle order (advancing each start to its batch's end, then moved back). */
static sk_status list_batch_triangles(bake_context *context, sk_error *error)
{
    const size_t batches = (context->options->size + BATCH_ROWS - 1) / BATCH_ROWS;
    const size_t triangle_count = context->target->triangle_count;
    context->batch_offsets = sk_allocate_zeroed(batches + 1, sizeof(size_t));
    if (!context->batch_offsets)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu row batches", batches);
    size_t entries = 0;
    for (size_t t = 0; t < triangle_count; ++t) {
        const triangle_span span = context->spans[t];
        if (span.row0 > span.row1)
            continue;
        for (size_t b = span.row0 / BATCH_ROWS; b <= span.row1 / BATCH_ROWS; ++b)
            ++context->batch_offsets[b + 1];
        if (!sk_add_size(entries, span.row1 / BATCH_ROWS - span.row0 / BATCH_ROWS + 1, &entries))
            return sk_fail(error, SK_ERROR_MEMORY, "too many batch entries");
    }
    for (size_t b = 0; b < batches; ++b)
        context->batch_offsets[b + 1] += context->batch_offsets[b];
    context->batch_triangles = sk_allocate(entries ? entries : 1, sizeof(int32_t));
    if (!context->batch_triangles)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu batch entries", entries);
    for (size_t t = 0; t < triangle_count; ++t) {
        const triangle_span span = context->spans[t];
        for (size_t b = span.row0 / BATCH_ROWS; span.row0 <= span.row1 && b <= span.row1 / BATCH_ROWS; ++b)
            context->batch_triangles[context->batch_offsets[b]++] = (int32_t)t;
    }
    memmove(context->batch_offsets + 1, context->batch_offsets, batches * sizeof(size_t));
    context->batch_offsets[0] = 0;
    return SK_OK;
}

/* The texel centres of rows begin to end - 1 (the batch from context->row_begin) in every target triangle, in
 * triangle order (the order of the tiles' lists, so that the first containing triangle is the one
 * containing_triangle finds), and which texels a triangle touches (the test nearest_touching makes): one pass over
 * each triangle's box instead of a search per texel. Each texel sees its triangles in the same order whichever
 * batch holds it, so batches give the bits of one pass over the image. */
static void rasterise_centres(bake_context *context, size_t begin, size_t end)
{
    const size_t size = context->options->size;
    const double scale = (double)size;
    memset(context->centre_triangles, 0xff, (end - begin) * size * sizeof(int32_t)); /* all -1 */
    memset(context->centre_flags, 0, (end - begin) * size);
    const size_t batch = begin / BATCH_ROWS;
    for (size_t e = context->batch_offsets[batch]; e < context->batch_offsets[batch + 1]; ++e) {
        const size_t t = (size_t)context->batch_triangles[e];
        const triangle_span span = context->spans[t];
        const size_t row0 = span.row0 < begin ? begin : span.row0, row1 = span.row1 + 1 > end ? end - 1 : span.row1;
        const uv_frame *frame = &context->target_frames[t];
        const double *uv = context->target->uv + 6 * t;
        edge_test edges;
        prepare_edge_test(&edges, uv, frame->area2);
        for (size_t row = row0; row <= row1; ++row) {
            /* Only the columns the triangle meets within the row's strip (and one more each way) can touch it: a
             * sliver's box holds many texels it does not come near. */
            double low_u, high_u;
            if (!strip_span(&low_u, &high_u, uv, 1 - (double)(row + 1) / scale, 1 - (double)row / scale))
                continue;
            const double span0 = texel_floor(low_u * scale) - 1, span1 = texel_floor(high_u * scale) + 1;
            const size_t first = span0 < (double)span.column0 ? span.column0 : (size_t)span0;
            const size_t last = span1 > (double)span.column1 ? span.column1 : (size_t)span1;
            rasterise_row(context, (int32_t)t, frame, &context->target_boxes[t], &edges, row, first, last);
        }
    }
}

/* The first target triangle containing the texel's centre with its weights there, or -1; *strictly as
 * containing_triangle counts it. */
static int32_t centre_triangle(double weights[3], size_t *strictly, const bake_context *context, size_t column,
                               size_t row)
{
    const size_t at = centre_index(context, column, row);
    const int32_t t = context->centre_triangles[at];
    const unsigned char flags = context->centre_flags[at];
    *strictly += flags & CENTRE_STRICTLY_MORE ? 2 : (flags & CENTRE_STRICTLY_ONE ? 1 : 0);
    if (t >= 0) {
        double u, v;
        texel_uv(&u, &v, context, column, row, 0.5, 0.5);
        frame_contains(weights, &context->target_frames[t], u, v);
    }
    return t;
}

/* The centre's triangle, else the nearest one touching the texel (only where one touches it), else -1. */
static int32_t centre_or_nearest(double weights[3], const bake_context *context, size_t first, size_t last,
                                 size_t column, size_t row)
{
    size_t ignored = 0;
    const int32_t t = centre_triangle(weights, &ignored, context, column, row);
    if (t >= 0 || !(context->centre_flags[centre_index(context, column, row)] & CENTRE_TOUCHED))
        return t;
    return nearest_touching(weights, context, first, last, column, row);
}

/* Writes a texel: its encoded tangent-space normal (NULL: flat, (0, 0, 1)), its coverage state, and where asked for,
 * the exact object-space normal and the frame (both zero when object is NULL: the texel was not baked). */
static void store_diagnostics(bake_context *context, size_t texel, const double *object, const double *frame)
{
    if (context->exact)
        for (int k = 0; k < 3; ++k)
            context->exact[3 * texel + (size_t)k] = object ? object[k] : 0.0;
    if (context->frames)
        for (int k = 0; k < 9; ++k)
            context->frames[9 * texel + (size_t)k] = object ? frame[k] : 0.0;
}

/* Where store_texel writes, read from the context once a row: a byte store (the coverage) may alias anything, so
 * the context's fields were loaded again after every texel's (3.1M instructions of the horse's 512 bake). */
typedef struct texel_out {
    float *image;
    unsigned char *coverage;
    int diagnostics; /* exact or frames are asked for */
} texel_out;

static texel_out texel_out_of(const bake_context *context)
{
    return (texel_out){context->image, context->coverage, context->exact || context->frames};
}

/* Inlined into the row loop, a flat texel's encoding written as the constants it rounds to (0.5 0 + 0.5, 0.5 1 + 0.5:
 * exact in float) and the diagnostics kept apart: the store was 30 instructions a texel. */
static inline void store_texel(bake_context *context, texel_out out, size_t texel, unsigned char state,
                               const double *value, const double *object, const double *frame)
{
    float *pixel = out.image + 3 * texel;
    if (value) {
        for (int k = 0; k < 3; ++k)
            pixel[k] = (float)(0.5 * value[k] + 0.5);
    } else {
        pixel[0] = pixel[1] = 0.5f;
        pixel[2] = 1.0f;
    }
    out.coverage[texel] = state;
    if (out.diagnostics)
        store_diagnostics(context, texel, object, frame);
}

static void bake_texel(bake_context *context, size_t worker, size_t column, size_t row, int32_t *hint)
{
    const size_t size = context->options->size, texel = row * size + column, s = context->options->supersample;
    const size_t tiles = context->target_bins.cells;
    const size_t cell = (row / TILE_TEXELS) * tiles + column / TILE_TEXELS;
    const size_t first = context->target_bins.offsets[cell], last = context->target_bins.offsets[cell + 1];
    double sum[3] = {0, 0, 0}, value[3], object[3], frame[9], weights[3];
    double centre_value[3], centre_object[3], centre_frame[9];
    size_t hits = 0, misses = 0, inside = 0, overlap = 0;
    int centre_found = 0, centre_done = 0;
    for (size_t j = 0; j < s; ++j)
        for (size_t i = 0; i < s; ++i) {
            double u, v;
            size_t strictly = 0;
            texel_uv(&u, &v, context, column, row, ((double)i + 0.5) / (double)s, ((double)j + 0.5) / (double)s);
            const int32_t found = s == 1 ? centre_triangle(weights, &strictly, context, column, row)
                                         : containing_triangle(weights, &strictly, context, first, last, u, v);
            overlap |= strictly > 1;
            if (found < 0)
                continue;
            ++inside;
            const int ok = tangent_space_normal(value, object, frame, context, found, weights, hint);
            hits += ok;
            misses += !ok;
            for (int k = 0; ok && k < 3; ++k)
                sum[k] += value[k];
            if (2 * i + 1 == s && 2 * j + 1 == s) { /* odd s: this sample is the centre */
                centre_done = 1;
                centre_found = ok;
                memcpy(centre_value, value, sizeof value);
                memcpy(centre_object, object, sizeof object);
                memcpy(centre_frame, frame, sizeof frame);
            }
        }
    /* The point nearest the centre, on the triangle containing it or else the nearest one touching the texel:
     * the whole value of a touched texel without inside samples, and where the exact normal is measured. */
    int32_t nearest = -1;
    if (!centre_done) {
        nearest = centre_or_nearest(weights, context, first, last, column, row);
        centre_found = nearest >= 0 &&
                       tangent_space_normal(centre_value, centre_object, centre_frame, context, nearest, weights, hint);
    }
    if (inside == 0 && nearest >= 0) {
        hits = centre_found;
        misses = !centre_found;
        if (centre_found)
            memcpy(sum, centre_value, sizeof sum);
    }
    const int filled = hits > 0 && normalise(sum);
    store_texel(context, texel_out_of(context), texel, filled ? SK_TEXEL_FILLED : (misses > 0 ? SK_TEXEL_MISSED : SK_TEXEL_EMPTY),
                filled ? sum : NULL, centre_found ? centre_object : NULL, centre_frame);
    if (overlap && context->overlaps[worker]++ == 0)
        context->first_overlap[worker] = texel;
}

/* What a one-sample atlas bake interpolates over a target triangle: tangent (3), normal (3), bitangent sign (1)
 * and uv (2), in this order. */
#define ROW_ATTRIBUTES 9

/* The attributes of triangle t at the weights (linear in them, so weight steps give attribute steps). */
static void row_attributes(double out[ROW_ATTRIBUTES], const bake_context *context, int32_t t,
                           const double weights[3])
{
    const double *tangents = context->tangents + 12 * (size_t)t, *normals = context->target->normals + 9 * (size_t)t;
    const double *uv = context->target->uv + 6 * (size_t)t;
    for (int k = 0; k < ROW_ATTRIBUTES; ++k)
        out[k] = 0;
    for (int c = 0; c < 3; ++c) {
        const double w = weights[c];
        for (int k = 0; k < 3; ++k) {
            out[k] += w * tangents[4 * c + k];
            out[3 + k] += w * normals[3 * c + k];
        }
        out[6] += w * tangents[4 * c + 3];
        out[7] += w * uv[2 * c];
        out[8] += w * uv[2 * c + 1];
    }
}

/* A one-sample atlas bake of one row. Along a run of texels whose centres lie in one target triangle, the
 * barycentric weights, and with them the unnormalised tangent, normal, sign and uv point, are affine in the column:
 * they are interpolated at the run's first texel and then step by a constant per texel. Texels only touched by a
 * triangle take the general path (the nearest triangle point); empty ones are written flat at once. */
static void bake_row_one_sample(bake_context *context, size_t worker, size_t row)
{
    const size_t size = context->options->size;
    const double step = context->texel_size;
    double at[ROW_ATTRIBUTES], delta[ROW_ATTRIBUTES];
    int32_t hint = -1, current = -1;
    const int32_t *centre_triangles = context->centre_triangles + centre_index(context, 0, row);
    const unsigned char *centre_flags = context->centre_flags + centre_index(context, 0, row);
    /* what the loop reads of the context, read once (see texel_out) */
    const texel_out out = texel_out_of(context);
    const uv_frame *source_frames = context->source_frames;
    const double *source_normals = context->source->normals;
    const int keep_frame = context->frames != NULL, keep_exact = context->exact != NULL;
    for (size_t column = 0; column < size; ++column) {
        const size_t texel = row * size + column;
        const int32_t t = centre_triangles[column];
        if (t < 0) {
            current = -1;
            if (centre_flags[column] & CENTRE_TOUCHED)
                bake_texel(context, worker, column, row, &hint);
            else
                store_texel(context, out, texel, SK_TEXEL_EMPTY, NULL, NULL, NULL);
            continue;
        }
        if (centre_flags[column] & CENTRE_STRICTLY_MORE && context->overlaps[worker]++ == 0)
            context->first_overlap[worker] = texel;
        if (t != current) {
            const uv_frame *frame = &context->target_frames[t];
            const double steps[3] = {-(frame->a1u + frame->a2u) * step, frame->a1u * step, frame->a2u * step};
            double weights[3], u, v;
            texel_uv(&u, &v, context, column, row, 0.5, 0.5);
            frame_contains(weights, frame, u, v);
            row_attributes(at, context, t, weights);
            row_attributes(delta, context, t, steps);
            current = t;
        } else {
            for (int k = 0; k < ROW_ATTRIBUTES; ++k)
                at[k] += delta[k];
        }
        double frame[9], object[3], value[3], source_weights[3];
        const int32_t hit = source_at_point(source_weights, context, source_frames, at + 7, &hint);
        int ok = 0;
        if (hit >= 0) {
            interpolate(object, source_normals + 9 * (size_t)hit, source_weights);
            ok = encode_at(value, frame, at, object, keep_frame) && (!keep_exact || normalise(object));
        } else {
            make_frame(frame, at, at + 3, at[6]);
        }
        store_texel(context, out, texel, ok ? SK_TEXEL_FILLED : SK_TEXEL_MISSED, ok ? value : NULL,
                    ok ? object : NULL, frame);
    }
}

static void bake_rows(void *argument, size_t worker, size_t begin, size_t end)
{
    bake_context *context = argument;
    const int one_sample_atlas = context->options->mode == SK_BAKE_ATLAS && context->options->supersample == 1;
    for (size_t row = context->row_begin + begin; row < context->row_begin + end; ++row) {
        if (one_sample_atlas) {
            bake_row_one_sample(context, worker, row);
            continue;
        }
        int32_t hint = -1; /* the row's last source triangle: rows are independent, so threads do not matter */
        for (size_t column = 0; column < context->options->size; ++column)
            bake_texel(context, worker, column, row, &hint);
    }
}

/* The margin, one ring of texels per pass: an empty texel next to baked ones (8-neighbours, baked before this pass)
 * takes their normalised average. Only the frontier is visited: the texels queued by the previous pass.
 * mark[t]: 2 p when t was dilated in pass p, 2 p + 1 when it is queued for pass p (so margin <= 127). The frontier
 * keeps each texel's row and column, so that finding its neighbours takes no division (two a texel showed in the
 * profile). */
typedef struct frontier_texel {
    uint32_t row, column;
} frontier_texel;

typedef struct texel_list {
    frontier_texel *items;
    size_t size, capacity;
} texel_list;

static int dilated_in(const unsigned char *mark, size_t texel, size_t pass)
{
    return mark[texel] == 2 * pass;
}

/* The 8-neighbours' row and column offsets in row-major order (the order the average sums them in). */
static const int NEIGHBOUR_ROWS[8] = {-1, -1, -1, 0, 0, 1, 1, 1}, NEIGHBOUR_COLUMNS[8] = {-1, 0, 1, -1, 1, -1, 0, 1};

/* The margin's image: its side and the 8-neighbours' texel offsets, which a texel inside the border takes as they
 * are (clipping each neighbour to the image was half the margin's instructions). */
typedef struct margin_grid {
    size_t size;
    long offsets[8];
} margin_grid;

static margin_grid make_margin_grid(size_t size)
{
    margin_grid grid = {size, {0}};
    for (int i = 0; i < 8; ++i)
        grid.offsets[i] = NEIGHBOUR_ROWS[i] * (long)size + NEIGHBOUR_COLUMNS[i];
    return grid;
}

static int inside_border(const margin_grid *grid, frontier_texel at)
{
    return at.row > 0 && at.column > 0 && at.row + 1 < grid->size && at.column + 1 < grid->size;
}

/* Neighbour i of the texel when it lies inside the image: 1 with its texel index. Texels inside the border take
 * the grid's offsets instead, in loops of eight with no test per neighbour (the test was a third of the margin's
 * instructions). */
static int neighbour(size_t *other, const margin_grid *grid, frontier_texel at, int i)
{
    const long row = (long)at.row + NEIGHBOUR_ROWS[i], column = (long)at.column + NEIGHBOUR_COLUMNS[i];
    if (row < 0 || column < 0 || row >= (long)grid->size || column >= (long)grid->size)
        return 0;
    *other = (size_t)row * grid->size + (size_t)column;
    return 1;
}

_Static_assert(SK_TEXEL_EMPTY == 0, "next_to_baked ors the neighbours' states");

/* Whether an empty texel has a baked 8-neighbour: the first pass's frontier. Inside the image's border, the or of
 * the eight states (most texels: no offsets to clip). */
static int next_to_baked(const unsigned char *coverage, size_t size, size_t row, size_t column)
{
    const size_t texel = row * size + column;
    if (row > 0 && column > 0 && row + 1 < size && column + 1 < size) {
        const unsigned char *above = coverage + texel - size, *here = coverage + texel, *below = coverage + texel + size;
        return (above[-1] | above[0] | above[1] | here[-1] | here[1] | below[-1] | below[0] | below[1]) != 0;
    }
    const margin_grid grid = make_margin_grid(size);
    for (int i = 0; i < 8; ++i) {
        size_t other;
        if (neighbour(&other, &grid, (frontier_texel){(uint32_t)row, (uint32_t)column}, i) &&
            coverage[other] != SK_TEXEL_EMPTY)
            return 1;
    }
    return 0;
}

/* What one frontier texel's pass learns from its 8-neighbours, in one read of each: the sum of the decoded normals
 * that count (baked, or dilated before this pass) and the empty neighbours the next pass takes (not queued for this
 * pass or the next already). Dilating and then queueing read every neighbour twice. */
typedef struct margin_visit {
    double sum[3];
    size_t neighbours, empties;
    int empty[8]; /* the neighbours (0-7) to queue */
    unsigned char dilated_now, queued_now, queued_next;
} margin_visit;

static inline void visit_neighbour(margin_visit *visit, const float *image, const unsigned char *coverage,
                                   const unsigned char *mark, size_t other, int i)
{
    const unsigned char state = coverage[other], marked = mark[other];
    if (state != SK_TEXEL_EMPTY) {
        if (marked == visit->dilated_now)
            return;
        for (int k = 0; k < 3; ++k)
            visit->sum[k] += 2.0 * image[3 * other + (size_t)k] - 1.0;
        ++visit->neighbours;
    } else if (marked != visit->queued_now && marked != visit->queued_next) {
        visit->empty[visit->empties++] = i;
    }
}

/* Dilates a frontier texel in pass `pass` and, where next is not NULL, queues its empty neighbours for the next
 * pass: 1 when dilated, 0 when not (no neighbour counts, or their sum is zero), -1 when memory ran out. A texel of
 * this pass's frontier is not queued here even when it then fails: dilate queues those after the pass. */
static int dilate_texel(texel_list *next, float *image, unsigned char *coverage, unsigned char *mark,
                        const margin_grid *grid, frontier_texel at, size_t pass)
{
    margin_visit visit; /* field by field: an initialiser would also zero empty[], 14 instructions a texel */
    visit.sum[0] = visit.sum[1] = visit.sum[2] = 0;
    visit.neighbours = visit.empties = 0;
    visit.dilated_now = (unsigned char)(2 * pass);
    visit.queued_now = (unsigned char)(2 * pass + 1);
    visit.queued_next = (unsigned char)(2 * pass + 3);
    const size_t texel = (size_t)at.row * grid->size + at.column;
    if (inside_border(grid, at)) {
        for (int i = 0; i < 8; ++i)
            visit_neighbour(&visit, image, coverage, mark, (size_t)((long)texel + grid->offsets[i]), i);
    } else {
        for (int i = 0; i < 8; ++i) {
            size_t other;
            if (neighbour(&other, grid, at, i))
                visit_neighbour(&visit, image, coverage, mark, other, i);
        }
    }
    if (visit.neighbours == 0 || !normalise(visit.sum))
        return 0;
    for (int k = 0; k < 3; ++k)
        image[3 * texel + (size_t)k] = (float)(0.5 * visit.sum[k] + 0.5);
    coverage[texel] = SK_TEXEL_DILATED;
    mark[texel] = visit.dilated_now;
    for (size_t e = 0; next && e < visit.empties; ++e) {
        const int i = visit.empty[e];
        const frontier_texel queued = {(uint32_t)((long)at.row + NEIGHBOUR_ROWS[i]),
                                       (uint32_t)((long)at.column + NEIGHBOUR_COLUMNS[i])};
        mark[(size_t)queued.row * grid->size + queued.column] = visit.queued_next;
        if (!SK_PUSH(*next, queued, 256))
            return -1;
    }
    return 1;
}

/* A texel of pass's frontier that was not dilated joins the next pass when a neighbour was dilated in this one (as
 * any empty neighbour of a dilated texel does); 0 when memory ran out. */
static int requeue_failed(texel_list *next, unsigned char *mark, const margin_grid *grid, frontier_texel at,
                          size_t pass)
{
    const size_t texel = (size_t)at.row * grid->size + at.column;
    if (mark[texel] != 2 * pass + 1)
        return 1; /* dilated */
    for (int i = 0; i < 8; ++i) {
        size_t other;
        if (neighbour(&other, grid, at, i) && dilated_in(mark, other, pass)) {
            mark[texel] = (unsigned char)(2 * pass + 3);
            return SK_PUSH(*next, at, 256);
        }
    }
    return 1;
}

/* Puts the texel on the first pass's frontier; 0 when memory ran out. */
static int start_frontier(texel_list *frontier, unsigned char *mark, size_t size, size_t row, size_t column)
{
    mark[row * size + column] = 2 * 1 + 1;
    return SK_PUSH(*frontier, ((frontier_texel){(uint32_t)row, (uint32_t)column}), 256);
}

/* The texels of a border row (or column 0 and size - 1 of another) that start the frontier; 0: out of memory. */
static int start_frontier_at(texel_list *frontier, unsigned char *mark, const unsigned char *coverage, size_t size,
                             size_t row, size_t column)
{
    return coverage[row * size + column] != SK_TEXEL_EMPTY || !next_to_baked(coverage, size, row, column) ||
           start_frontier(frontier, mark, size, row, column);
}

/* The first frontier, in texel order: each empty texel next to a baked one, visited once (the order within a
 * pass does not change what it writes: a pass reads only texels baked or dilated before it). A row inside the
 * border is tested whole: near[c], the or of the texel's eight neighbours' states masked by its own emptiness, is a
 * loop without branches the compiler vectorises, and the row is then skipped eight bytes at a time where none starts
 * (a test and a call per texel were 3M instructions of the horse's 512 bake). 0 when memory ran out. */
static int first_frontier(texel_list *frontier, unsigned char *mark, const unsigned char *coverage, size_t size,
                          unsigned char *near)
{
    for (size_t row = 0; row < size; ++row) {
        if (row == 0 || row + 1 == size) {
            for (size_t column = 0; column < size; ++column)
                if (!start_frontier_at(frontier, mark, coverage, size, row, column))
                    return 0;
            continue;
        }
        const unsigned char *above = coverage + (row - 1) * size, *here = above + size, *below = here + size;
        near[0] = near[size - 1] = 0; /* the border columns: start_frontier_at */
        for (size_t c = 1; c + 1 < size; ++c)
            near[c] = (unsigned char)((above[c - 1] | above[c] | above[c + 1] | here[c - 1] | here[c + 1] |
                                       below[c - 1] | below[c] | below[c + 1]) &
                                      -(here[c] == SK_TEXEL_EMPTY));
        if (!start_frontier_at(frontier, mark, coverage, size, row, 0))
            return 0;
        for (size_t c = 0; c < size; c += 8) {
            const size_t n = size - c < 8 ? size - c : 8;
            uint64_t word = 1; /* a short last block is scanned */
            if (n == 8)
                memcpy(&word, near + c, 8); /* one load */
            for (size_t k = 0; word && k < n; ++k)
                if (near[c + k] && !start_frontier(frontier, mark, size, row, c + k))
                    return 0;
        }
        if (!start_frontier_at(frontier, mark, coverage, size, row, size - 1))
            return 0;
    }
    return 1;
}

static sk_status dilate(size_t *dilated, float *image, unsigned char *coverage, size_t size, size_t margin,
                        unsigned char *mark, sk_error *error)
{
    texel_list frontier = {0}, next = {0};
    const margin_grid grid = make_margin_grid(size);
    unsigned char *near = margin > 0 ? sk_allocate(size, 1) : NULL;
    int ok = margin == 0 || (near && first_frontier(&frontier, mark, coverage, size, near));
    *dilated = 0;
    for (size_t pass = 1; ok && pass <= margin && frontier.size > 0; ++pass) {
        next.size = 0;
        size_t failed = 0;
        for (size_t i = 0; ok && i < frontier.size; ++i) {
            const int result = dilate_texel(pass < margin ? &next : NULL, image, coverage, mark, &grid,
                                            frontier.items[i], pass);
            ok = result >= 0;
            *dilated += result > 0;
            failed += result == 0;
        }
        for (size_t i = 0; ok && failed > 0 && pass < margin && i < frontier.size; ++i)
            ok = requeue_failed(&next, mark, &grid, frontier.items[i], pass);
        const texel_list swap = frontier;
        frontier = next;
        next = swap;
    }
    SK_FREE_ALL(frontier.items, next.items, near);
    return ok ? SK_OK : sk_fail(error, SK_ERROR_MEMORY, "out of memory for the margin's frontier");
}

_Static_assert(SK_TEXEL_EMPTY == 0 && SK_TEXEL_FILLED == 1 && SK_TEXEL_MISSED == 2 && SK_TEXEL_DILATED == 3,
               "count_states reads a state as two bits");

/* How many texels hold each coverage state, eight a word: a state is two bits of its byte (low, high), so a byte is
 * filled where low & ~high, and so on; the 0/1 bytes of a word are summed by one multiplication (at most 8 each).
 * The per-texel compare-and-add was 6 instructions a texel. */
static void count_states(size_t counts[4], const unsigned char *coverage, size_t texel_count)
{
    const uint64_t ones = 0x0101010101010101ULL;
    counts[0] = counts[1] = counts[2] = counts[3] = 0;
    size_t i = 0;
    for (; i + 8 <= texel_count; i += 8) {
        uint64_t word;
        memcpy(&word, coverage + i, 8);
        const uint64_t low = word & ones, high = (word >> 1) & ones;
        counts[SK_TEXEL_FILLED] += (size_t)(((low & ~high) * ones) >> 56);
        counts[SK_TEXEL_MISSED] += (size_t)(((high & ~low) * ones) >> 56);
        counts[SK_TEXEL_DILATED] += (size_t)(((low & high) * ones) >> 56);
    }
    for (; i < texel_count; ++i)
        ++counts[coverage[i] & 3];
    counts[SK_TEXEL_EMPTY] = texel_count - counts[SK_TEXEL_FILLED] - counts[SK_TEXEL_MISSED] - counts[SK_TEXEL_DILATED];
}

static sk_status check_options(const sk_bake_options *options, sk_error *error)
{
    if (!options)
        return sk_fail(error, SK_ERROR_ARGUMENT, "options is NULL");
    if (options->size < 1 || options->size > SK_BAKE_MAX_SIZE)
        return sk_fail(error, SK_ERROR_ARGUMENT, "size %zu is outside 1-%d", options->size, SK_BAKE_MAX_SIZE);
    if (options->mode != SK_BAKE_ATLAS && options->mode != SK_BAKE_RAY_CAST && options->mode != SK_BAKE_GUIDED)
        return sk_fail(error, SK_ERROR_ARGUMENT, "mode %d is not atlas (0), ray cast (1) or guided (2)",
                       options->mode);
    if (options->supersample < 1 || options->supersample > MAX_SUPERSAMPLE)
        return sk_fail(error, SK_ERROR_ARGUMENT, "supersample %zu is outside 1-%d", options->supersample,
                       MAX_SUPERSAMPLE);
    if (options->margin > MAX_MARGIN)
        return sk_fail(error, SK_ERROR_ARGUMENT, "margin %zu exceeds %d texels", options->margin, MAX_MARGIN);
    if (options->mode != SK_BAKE_ATLAS && !(options->cage > 0 && isfinite(options->cage)))
        return sk_fail(error, SK_ERROR_ARGUMENT, "cage distance %g must be positive and finite", options->cage);
    return SK_OK;
}

static sk_status prepare(bake_context *context, sk_error *error)
{
    const sk_bake_options *options = context->options;
    const size_t tiles = (options->size + TILE_TEXELS - 1) / TILE_TEXELS;
    context->texel_size = 1.0 / (double)options->size;
    const size_t target_count = context->target->triangle_count, batch_texels = BATCH_ROWS * options->size;
    sk_status status = build_uv_frames(&context->target_frames, &context->target_boxes, context->target->uv,
                                       target_count, error);
    if (status == SK_OK)
        status = build_bins(&context->target_bins, context->target->uv, context->target_frames, target_count, tiles,
                            (double)options->size / TILE_TEXELS, 1, 1.0 / (double)options->size, error);
    if (status != SK_OK)
        return status;
    context->spans = sk_allocate(target_count ? target_count : 1, sizeof(triangle_span));
    context->centre_triangles = sk_allocate(batch_texels, sizeof(int32_t));
    context->centre_flags = sk_allocate(batch_texels, 1);
    if (!context->spans || !context->centre_triangles || !context->centre_flags)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the centres of %zu x %zu texels", options->size,
                       (size_t)BATCH_ROWS);
    find_spans(context);
    if ((status = list_batch_triangles(context, error)) != SK_OK)
        return status;
    if (options->mode != SK_BAKE_ATLAS && (status = sk_bvh_build(&context->bvh, context->source, error)) != SK_OK)
        return status;
    if (options->mode == SK_BAKE_RAY_CAST)
        return SK_OK;
    status = build_uv_frames(&context->source_frames, NULL, context->source->uv, context->source->triangle_count,
                             error);
    if (status != SK_OK)
        return status;
    /* sqrt(2 T) cells a side: the containing triangle is the common case, the snap looks through the cells around
     * the point. sqrt(8 T) had fewer candidates a cell, but its entries cost more to build than they saved (creature's
     * coarsest level: 6.5M instructions more at 512, 2.9M at 1024; sqrt(T / 2) held 10-23 a cell, grown by the
     * snap). */
    size_t cells = (size_t)ceil(sqrt(2.0 * (double)context->source->triangle_count));
    cells = cells < 1 ? 1 : (cells > 2048 ? 2048 : cells);
    return build_bins(&context->source_bins, context->source->uv, context->source_frames,
                      context->source->triangle_count, cells, (double)cells, 0, 0, error);
}

/* Frees what prepare made, once: each bake calls it when its rows are done. */
static void release(bake_context *context)
{
    free_bins(&context->target_bins);
    free_bins(&context->source_bins);
    SK_FREE_ALL(context->target_frames, context->source_frames, context->target_boxes, context->spans,
                context->batch_offsets, context->batch_triangles, context->centre_triangles, context->centre_flags);
    sk_bvh_free(&context->bvh);
}

/* The batch of rows from row: rasterised on the calling thread, then baked by `work` on the threads. */
static void run_batch(bake_context *context, size_t row, size_t rows, void (*work)(void *, size_t, size_t, size_t),
                      void *argument)
{
    context->row_begin = row;
    rasterise_centres(context, row, row + rows);
    sk_parallel_for(rows, 1, context->options->thread_count, work, argument);
}

static sk_status run_rows(bake_context *context, sk_progress_fn progress, void *progress_user, sk_error *error)
{
    const size_t size = context->options->size;
    for (size_t row = 0; row < size; row += BATCH_ROWS) {
        const size_t rows = size - row < BATCH_ROWS ? size - row : BATCH_ROWS;
        run_batch(context, row, rows, bake_rows, context);
        if (progress && progress(progress_user, 0.95 * (double)(row + rows) / (double)size))
            return sk_fail(error, SK_ERROR_CANCELLED, "the bake was cancelled at row %zu of %zu", row + rows, size);
    }
    size_t overlaps = 0, first = SIZE_MAX;
    for (size_t w = 0; w < SK_MAX_WORKERS; ++w) {
        overlaps += context->overlaps[w];
        if (context->overlaps[w] && context->first_overlap[w] < first)
            first = context->first_overlap[w];
    }
    if (overlaps > 0)
        return sk_fail(error, SK_ERROR_ARGUMENT,
                       "%zu texels are covered by more than one target triangle (overlapping uvs), the first at column "
                       "%zu, row %zu: give every triangle its own part of the atlas", overlaps, first % size, first / size);
    return SK_OK;
}

sk_status sk_bake_normals(float *image, unsigned char *coverage, double *exact, double *frames, sk_bake_report *report,
                          const sk_bake_surface *target, const double *tangents, const sk_bake_surface *source,
                          const sk_bake_options *options, sk_progress_fn progress, void *progress_user, sk_error *error)
{
    sk_status status = check_options(options, error);
    if (status != SK_OK)
        return status;
    if (!image || !coverage || !report || !tangents)
        return sk_fail(error, SK_ERROR_ARGUMENT, "image, coverage, report and tangents are required");
    if ((status = sk_check_bake_surface(target, 1, "target", error)) != SK_OK ||
        (status = sk_check_bake_surface(source, options->mode != SK_BAKE_RAY_CAST, "source", error)) != SK_OK)
        return status;
    size_t bad = sk_first_non_finite(tangents, 12 * target->triangle_count);
    if (bad < 12 * target->triangle_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "tangent of corner %zu is not finite", bad / 4);
    size_t texel_count;
    if ((status = sk_array_size(&texel_count, options->size, options->size, 1, "texel count", error)) != SK_OK)
        return status;
    bake_context context = {.image = image, .coverage = coverage, .exact = exact, .frames = frames, .target = target,
                            .source = source, .tangents = tangents, .options = options,
                            .guide_cosine = cos(SK_BAKE_GUIDE_DEGREES * 3.14159265358979323846 / 180.0)};
    status = prepare(&context, error);
    if (status == SK_OK)
        status = run_rows(&context, progress, progress_user, error);
    /* The rows' buffers go before the margin's marks come: the marks then reuse their memory. */
    release(&context);
    unsigned char *marks = NULL;
    if (status == SK_OK) {
        *report = (sk_bake_report){0};
        marks = sk_allocate_zeroed(texel_count, 1);
        status = marks ? dilate(&report->dilated, image, coverage, options->size, options->margin, marks, error)
                       : sk_fail(error, SK_ERROR_MEMORY, "out of memory for the margin's marks of %zu texels",
                                 texel_count);
    }
    if (status == SK_OK) {
        size_t counts[4];
        count_states(counts, coverage, texel_count);
        report->filled = counts[SK_TEXEL_FILLED];
        report->missed = counts[SK_TEXEL_MISSED];
        report->empty = counts[SK_TEXEL_EMPTY];
        if (progress && progress(progress_user, 1.0))
            status = sk_fail(error, SK_ERROR_CANCELLED, "the bake was cancelled after dilation");
        else
            status = sk_succeed(error);
    }
    free(marks);
    return status;
}

/* ---------------------------------------------------------------------------------------------
 * Tangent maps (section 7.5): per texel the animation-space tangents dp/du and dp/dv of the source's model at the
 * texel centre's uv point, on the union of the source triangle's bones
 * ------------------------------------------------------------------------------------------- */

#define MAX_CORNER_INFLUENCES 64 /* per source vertex */

typedef struct tangent_context {
    bake_context bake;
    int32_t *counts, *bones, *source_triangles;
    double *tangents;
    const sk_influences *influences;
    const double *coordinates;
    size_t max_influences;
    size_t overfull[SK_MAX_WORKERS], first_overfull[SK_MAX_WORKERS], needed[SK_MAX_WORKERS];
} tangent_context;

/* The coordinates of `bone` at source vertex `vertex` (zero when the vertex has no such influence). */
static void vertex_coordinates(double out[4], const tangent_context *context, int32_t vertex, int32_t bone)
{
    const sk_influences *influences = context->influences;
    out[0] = out[1] = out[2] = out[3] = 0;
    for (int32_t k = influences->offsets[vertex]; k < influences->offsets[vertex + 1]; ++k)
        if (influences->bones[k] == bone)
            for (int d = 0; d < 4; ++d)
                out[d] += context->coordinates[4 * (size_t)k + (size_t)d];
}

/* Writes the texel's bones and tangent pairs (oriented so that t1 x t2 follows the source face), or leaves it
 * empty (count 0) with the coverage saying why. */
static void tangent_texel(tangent_context *context, size_t worker, size_t column, size_t row, int32_t *hint)
{
    bake_context *bake = &context->bake;
    const size_t size = bake->options->size, texel = row * size + column, capacity = context->max_influences;
    const size_t tiles = bake->target_bins.cells, cell = (row / TILE_TEXELS) * tiles + column / TILE_TEXELS;
    const size_t first = bake->target_bins.offsets[cell], last = bake->target_bins.offsets[cell + 1];
    double weights[3], source_weights[3];
    context->counts[texel] = 0;
    context->source_triangles[texel] = -1;
    memset(context->bones + texel * capacity, 0, capacity * sizeof(int32_t));
    memset(context->tangents + 8 * texel * capacity, 0, 8 * capacity * sizeof(double));
    const int32_t triangle = centre_or_nearest(weights, bake, first, last, column, row);
    bake->coverage[texel] = triangle < 0 ? SK_TEXEL_EMPTY : SK_TEXEL_MISSED;
    const int32_t source = triangle < 0 ? -1 : source_at_uv(source_weights, bake, triangle, weights, hint);
    if (source < 0)
        return;
    const double *uv = bake->source->uv + 6 * (size_t)source;
    const double e1u = uv[2] - uv[0], e1v = uv[3] - uv[1], e2u = uv[4] - uv[0], e2v = uv[5] - uv[1];
    const double determinant = e1u * e2v - e1v * e2u;
    if (fabs(determinant) < MIN_UV_AREA)
        return;
    int32_t corners[3], set[3 * MAX_CORNER_INFLUENCES];
    size_t set_size = 0;
    for (int c = 0; c < 3; ++c) {
        corners[c] = bake->source->triangles[3 * (size_t)source + (size_t)c];
        const int32_t begin = context->influences->offsets[corners[c]], end = context->influences->offsets[corners[c] + 1];
        for (int32_t k = begin; k < end; ++k)
            sk_insert_sorted_bone(set, &set_size, context->influences->bones[k]);
    }
    if (set_size > capacity) {
        if (context->overfull[worker]++ == 0)
            context->first_overfull[worker] = texel;
        context->needed[worker] = set_size > context->needed[worker] ? set_size : context->needed[worker];
        return;
    }
    /* p(u, v) is linear over the triangle: dp/du and dp/dv from the two uv edges (Cramer). */
    const double orientation = determinant > 0 ? 1 : -1;
    for (size_t b = 0; b < set_size; ++b) {
        double p0[4], p1[4], p2[4];
        vertex_coordinates(p0, context, corners[0], set[b]);
        vertex_coordinates(p1, context, corners[1], set[b]);
        vertex_coordinates(p2, context, corners[2], set[b]);
        double *pair = context->tangents + 8 * (texel * capacity + b);
        for (int d = 0; d < 4; ++d) {
            const double d1 = p1[d] - p0[d], d2 = p2[d] - p0[d];
            pair[d] = (e2v * d1 - e1v * d2) / determinant;
            pair[4 + d] = orientation * (e1u * d2 - e2u * d1) / determinant;
        }
        context->bones[texel * capacity + b] = set[b];
    }
    context->counts[texel] = (int32_t)set_size;
    context->source_triangles[texel] = source;
    bake->coverage[texel] = SK_TEXEL_FILLED;
}

static void tangent_rows(void *argument, size_t worker, size_t begin, size_t end)
{
    tangent_context *context = argument;
    for (size_t row = context->bake.row_begin + begin; row < context->bake.row_begin + end; ++row) {
        int32_t hint = -1;
        for (size_t column = 0; column < context->bake.options->size; ++column)
            tangent_texel(context, worker, column, row, &hint);
    }
}

sk_status sk_bake_tangent_map(int32_t *counts, int32_t *bones, double *tangents, int32_t *source_triangles,
                              unsigned char *coverage, const sk_bake_surface *target, const sk_bake_surface *source,
                              const sk_influences *influences, const double *coordinates, size_t size,
                              size_t max_influences, int thread_count, sk_progress_fn progress, void *progress_user,
                              sk_error *error)
{
    const sk_bake_options options = {size, SK_BAKE_ATLAS, 1, 0, 0, thread_count};
    sk_status status = check_options(&options, error);
    if (status != SK_OK)
        return status;
    if (!counts || !bones || !tangents || !source_triangles || !coverage || !influences || !coordinates)
        return sk_fail(error, SK_ERROR_ARGUMENT, "an output or the model is NULL");
    if (max_influences < 1)
        return sk_fail(error, SK_ERROR_ARGUMENT, "max_influences must be at least 1");
    if ((status = sk_check_bake_surface(target, 1, "target", error)) != SK_OK ||
        (status = sk_check_bake_surface(source, 1, "source", error)) != SK_OK)
        return status;
    if (influences->vertex_count != source->vertex_count)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the model has %zu vertices, the source %zu", influences->vertex_count,
                       source->vertex_count);
    if ((status = sk_validate_influences(influences, SIZE_MAX, error)) != SK_OK)
        return status;
    for (size_t vertex = 0; vertex < influences->vertex_count; ++vertex)
        if (influences->offsets[vertex + 1] - influences->offsets[vertex] > MAX_CORNER_INFLUENCES)
            return sk_fail(error, SK_ERROR_ARGUMENT, "vertex %zu has %d influences, more than %d", vertex,
                           influences->offsets[vertex + 1] - influences->offsets[vertex], MAX_CORNER_INFLUENCES);
    size_t bad = sk_first_non_finite(coordinates, 4 * influences->influence_count);
    if (bad < 4 * influences->influence_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "coordinate %zu of influence %zu is not finite", bad % 4, bad / 4);
    tangent_context context = {.bake = {.coverage = coverage, .target = target, .source = source, .options = &options},
                               .counts = counts, .bones = bones, .source_triangles = source_triangles,
                               .tangents = tangents, .influences = influences, .coordinates = coordinates,
                               .max_influences = max_influences};
    status = prepare(&context.bake, error);
    for (size_t row = 0; status == SK_OK && row < size; row += BATCH_ROWS) {
        const size_t rows = size - row < BATCH_ROWS ? size - row : BATCH_ROWS;
        run_batch(&context.bake, row, rows, tangent_rows, &context);
        if (progress && progress(progress_user, (double)(row + rows) / (double)size))
            status = sk_fail(error, SK_ERROR_CANCELLED, "the tangent-map bake was cancelled at row %zu of %zu",
                             row + rows, size);
    }
    size_t overfull = 0, first = SIZE_MAX, needed = 0;
    for (size_t w = 0; w < SK_MAX_WORKERS; ++w) {
        overfull += context.overfull[w];
        needed = context.needed[w] > needed ? context.needed[w] : needed;
        if (context.overfull[w] && context.first_overfull[w] < first)
            first = context.first_overfull[w];
    }
    if (status == SK_OK && overfull > 0)
        status = sk_fail(error, SK_ERROR_ARGUMENT,
                         "%zu texels need more than max_influences = %zu bones (up to %zu), the first at column %zu, "
                         "row %zu", overfull, max_influences, needed, first % size, first / size);
    else if (status == SK_OK)
        status = sk_succeed(error);
    release(&context.bake);
    return status;
}
