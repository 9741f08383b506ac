/*
 * Packing charts into the unit square (Merry 2007, section 5.4), by their outlines rather than their bounding
 * rectangles: each chart brought to a common texel density (its uv area made its surface area), turned to its
 * smallest bounding rectangle (rotating calipers on its convex hull), rasterized conservatively onto a grid of
 * texels and grown by the margin; larger charts first, each goes to the quarter turn and place whose top is
 * lowest (then bottom-left) where its grown footprint covers no cell of an earlier chart, so small charts fill the
 * holes and concavities that larger ones leave (the raster approach of xatlas and of Levy et al. 2002's Tetris
 * packing, without their growing atlas). The largest common scale that fits is found by bisection.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_mesh.h"

/* The scale search (search_scale): the share of the square's scale below which a useful packing rarely falls (an
 * efficiency of 0.3), bisections on the coarse grid, then on the fine grid within FINE_BRACKET above the coarse
 * result: the efficiency is then within 0.1% of the best the bisection can reach. */
#define LIKELY_SCALE 0.55
#define COARSE_BISECTIONS 10
#define FINE_BISECTIONS 7
#define FINE_BRACKET 0.08

typedef struct chart_box {
    int32_t chart;
    double density;         /* the chart's scale to its surface area */
    double cosine, sine;    /* the rotation (x' = c x + s y, y' = -s x + c y) to its smallest rectangle */
    double low[2], size[2]; /* that rectangle after rotation: corner and (width, height), height >= width */
    double area;            /* its uv area at that density */
    int32_t raster[2];      /* its raster's width and height in cells, at the packed scale */
    int32_t cell[2];        /* the grid cell of its footprint's lower left corner */
    int quarter_turns;      /* counterclockwise, after the rectangle's orientation */
} chart_box;

typedef struct point {
    double x, y;
} point;

static int compare_points(const void *a, const void *b)
{
    const point *p = a, *q = b;
    return p->x != q->x ? SK_ORDER(p->x, q->x) : SK_ORDER(p->y, q->y);
}

static double turn(point o, point a, point b)
{
    return (a.x - o.x) * (b.y - o.y) - (a.y - o.y) * (b.x - o.x);
}

/* Andrew's monotone chain: the convex hull of points (sorted in place), counterclockwise, into hull. */
static size_t convex_hull(point *hull, point *points, size_t count)
{
    qsort(points, count, sizeof *points, compare_points);
    size_t size = 0;
    for (size_t i = 0; i < count; ++i) {
        while (size >= 2 && turn(hull[size - 2], hull[size - 1], points[i]) <= 0)
            --size;
        hull[size++] = points[i];
    }
    for (size_t i = count - 1, lower = size + 1; i-- > 0;) {
        while (size >= lower && turn(hull[size - 2], hull[size - 1], points[i]) <= 0)
            --size;
        hull[size++] = points[i];
    }
    return size > 1 ? size - 1 : size; /* the last point repeats the first */
}

static double along(point p, double c, double s)
{
    return c * p.x + s * p.y;
}

/* Advances index i around the hull while the next point projects further along (c, s). */
static size_t advance(const point *hull, size_t count, size_t i, double c, double s)
{
    for (size_t step = 0; step < count && along(hull[(i + 1) % count], c, s) > along(hull[i], c, s); ++step)
        i = (i + 1) % count;
    return i;
}

static size_t extreme(const point *hull, size_t count, double c, double s)
{
    size_t best = 0;
    for (size_t i = 1; i < count; ++i)
        if (along(hull[i], c, s) > along(hull[best], c, s))
            best = i;
    return best;
}

/*
 * The smallest-area bounding rectangle has a side on a hull edge (Freeman and Shapira 1975); rotating calipers
 * visit every edge with three pointers (farthest along the edge, against it, and away from it) that only move
 * forward, so the whole search is linear in the hull's size.
 */
static void smallest_rectangle(chart_box *box, const point *hull, size_t count)
{
    double best_area = INFINITY;
    size_t ahead = 0, behind = 0, away = 0;
    for (size_t i = 0; i < count; ++i) {
        const point a = hull[i], b = hull[(i + 1) % count];
        const double length = hypot(b.x - a.x, b.y - a.y);
        if (!(length > 0))
            continue;
        const double c = (b.x - a.x) / length, s = (b.y - a.y) / length;
        if (best_area == INFINITY) { /* the first edge: start each pointer at its extreme point */
            ahead = extreme(hull, count, c, s);
            behind = extreme(hull, count, -c, -s);
            away = extreme(hull, count, -s, c);
        }
        ahead = advance(hull, count, ahead, c, s);
        behind = advance(hull, count, behind, -c, -s);
        away = advance(hull, count, away, -s, c);
        const double width = along(hull[ahead], c, s) - along(hull[behind], c, s);
        const double height = along(hull[away], -s, c) - along(a, -s, c);
        if (width * height < best_area) {
            best_area = width * height;
            box->cosine = c;
            box->sine = s;
            box->low[0] = along(hull[behind], c, s);
            box->low[1] = along(a, -s, c);
            box->size[0] = width;
            box->size[1] = height;
        }
    }
    if (box->size[0] > box->size[1]) { /* a quarter turn more puts the long side vertical */
        const double c = box->cosine, s = box->sine, low_x = box->low[0], width = box->size[0];
        box->cosine = s; /* x'' = -y', y'' = x' */
        box->sine = -c;
        box->low[0] = -(box->low[1] + box->size[1]);
        box->low[1] = low_x;
        box->size[0] = box->size[1];
        box->size[1] = width;
    }
}

/* Charts go on a grid of cells (the texture's texels, at most MAX_GRID_CELLS a side: the grid's cells are then
 * a few texels, and the margin is rounded up to whole cells, so it is never less than asked). */
#define MAX_GRID_CELLS 1024
#define QUARTER_TURNS 4
/* Below this many cells a side the coarse grid of the scale search is too coarse to bracket the scale. */
#define MIN_COARSE_GRID 128

typedef struct span {
    int32_t start, length; /* cells [start, start + length) of a row */
} span;

/* One chart's footprint (its cells grown by the margin) in each of the four quarter turns: row r of turn k has the
 * spans spans[k][row_start[k][r] .. row_start[k][r + 1]). */
typedef struct footprint {
    int32_t width[QUARTER_TURNS], height[QUARTER_TURNS];
    int32_t *row_start[QUARTER_TURNS];
    span *spans[QUARTER_TURNS];
} footprint;

typedef struct packer {
    int32_t grid;            /* cells along a side of the square */
    int32_t dilation;        /* the margin, in whole cells (rounded up) */
    unsigned char *occupied; /* grid * grid: cells covered by a placed chart (not its margin) */
    int32_t *free_run;       /* grid * grid: free cells from (x, y) rightward along row y; minus the occupied ones
                                when (x, y) is occupied */
    unsigned char *cells;    /* grid * grid: the chart being placed, rasterized */
    unsigned char *grown;    /* grid * grid: its rows grown by the margin */
    unsigned char *grown_cells; /* grid * grid: its rows and columns grown by the margin (unturned footprint) */
    int32_t *prefix;         /* grid + 1: running counts for the dilation */
    footprint turns;
} packer;

static int larger_first(const void *a, const void *b)
{
    const chart_box *x = a, *y = b;
    const double area_x = x->area, area_y = y->area;
    return area_x != area_y ? SK_ORDER(area_y, area_x) : SK_ORDER(x->chart, y->chart);
}

/* The cell of the unturned footprint (width x height) that cell (x, y) of its turn k shows. */
static void source_cell(int32_t *source_x, int32_t *source_y, int turn, int32_t x, int32_t y, int32_t width,
                        int32_t height)
{
    switch (turn) {
    case 0: *source_x = x; *source_y = y; break;
    case 1: *source_x = y; *source_y = height - 1 - x; break;
    case 2: *source_x = width - 1 - x; *source_y = height - 1 - y; break;
    default: *source_x = width - 1 - y; *source_y = x; break;
    }
}

/* Where point (x, y) of the unturned footprint (width x height cells) lands in turn k (counterclockwise). */
static void turn_point(double *turned, int turn, double x, double y, double width, double height)
{
    const double results[QUARTER_TURNS][2] = {{x, y}, {height - y, x}, {width - x, height - y}, {y, width - x}};
    turned[0] = results[turn][0];
    turned[1] = results[turn][1];
}

/* The chart's point in cells, relative to the lower corner of its turned rectangle, at `scale`. */
static void chart_point(double *cell, const chart_box *box, const double *x, double cells_per_unit)
{
    const double u = box->density * x[0], v = box->density * x[1];
    cell[0] = cells_per_unit * (box->cosine * u + box->sine * v - box->low[0]);
    cell[1] = cells_per_unit * (-box->sine * u + box->cosine * v - box->low[1]);
}

/* Marks every cell of the width x height raster that a triangle touches (conservatively: the triangle's x range
 * within each row's strip, widened by a hair so that a point on a cell border counts for both cells). */
static void rasterize_triangle(unsigned char *cells, int32_t width, int32_t height, double corners[3][2])
{
    const double hair = 1e-9;
    double low_y = INFINITY, high_y = -INFINITY;
    for (int k = 0; k < 3; ++k) {
        low_y = fmin(low_y, corners[k][1]);
        high_y = fmax(high_y, corners[k][1]);
    }
    const int32_t first_row = (int32_t)fmax(0, floor(low_y - hair));
    const int32_t last_row = (int32_t)fmin(height - 1, floor(high_y + hair));
    for (int32_t row = first_row; row <= last_row; ++row) {
        const double bottom = row - hair, top = row + 1 + hair;
        double low_x = INFINITY, high_x = -INFINITY;
        for (int k = 0; k < 3; ++k) {
            const double *p = corners[k], *q = corners[(k + 1) % 3];
            if (p[1] >= bottom && p[1] <= top) {
                low_x = fmin(low_x, p[0]);
                high_x = fmax(high_x, p[0]);
            }
            const double lines[2] = {bottom, top};
            for (int l = 0; l < 2; ++l)
                if ((p[1] - lines[l]) * (q[1] - lines[l]) < 0) {
                    const double x = p[0] + (q[0] - p[0]) * (lines[l] - p[1]) / (q[1] - p[1]);
                    low_x = fmin(low_x, x);
                    high_x = fmax(high_x, x);
                }
        }
        if (!(low_x <= high_x))
            continue;
        const int32_t first = (int32_t)fmax(0, floor(low_x - hair)), last = (int32_t)fmin(width - 1, floor(high_x + hair));
        for (int32_t x = first; x <= last; ++x)
            cells[(size_t)row * (size_t)width + (size_t)x] = 1;
    }
}

/* out[i] = whether any of in[i - 2 * radius .. i] is set (in has length - 2 * radius entries, at stride). */
static void grow_line(unsigned char *out, size_t out_stride, const unsigned char *in, size_t in_stride,
                      int32_t length, int32_t radius, int32_t *prefix)
{
    const int32_t in_length = length - 2 * radius;
    prefix[0] = 0;
    for (int32_t i = 0; i < in_length; ++i)
        prefix[i + 1] = prefix[i] + (in[(size_t)i * in_stride] != 0);
    for (int32_t i = 0; i < length; ++i) {
        const int32_t from = i - 2 * radius < 0 ? 0 : i - 2 * radius, to = i + 1 > in_length ? in_length : i + 1;
        out[(size_t)i * out_stride] = to > from && prefix[to] - prefix[from] > 0;
    }
}

/* The chart's footprint in its four quarter turns, from its raster (width x height) grown by the dilation. */
static void make_footprint(packer *p, int32_t width, int32_t height)
{
    const int32_t d = p->dilation, grown_width = width + 2 * d, grown_height = height + 2 * d;
    for (int32_t y = 0; y < height; ++y)
        grow_line(p->grown + (size_t)y * (size_t)grown_width, 1, p->cells + (size_t)y * (size_t)width, 1, grown_width,
                  d, p->prefix);
    for (int32_t x = 0; x < grown_width; ++x)
        grow_line(p->grown_cells + x, (size_t)grown_width, p->grown + x, (size_t)grown_width, grown_height, d,
                  p->prefix);
    for (int turn = 0; turn < QUARTER_TURNS; ++turn) {
        const int32_t w = turn % 2 ? grown_height : grown_width, h = turn % 2 ? grown_width : grown_height;
        footprint *f = &p->turns;
        f->width[turn] = w;
        f->height[turn] = h;
        size_t count = 0;
        for (int32_t y = 0; y < h; ++y) {
            f->row_start[turn][y] = (int32_t)count;
            for (int32_t x = 0; x < w; ++x) {
                int32_t sx, sy;
                source_cell(&sx, &sy, turn, x, y, grown_width, grown_height);
                if (!p->grown_cells[(size_t)sy * (size_t)grown_width + (size_t)sx])
                    continue;
                if (x > 0 && count > (size_t)f->row_start[turn][y] && f->spans[turn][count - 1].start +
                                                                        f->spans[turn][count - 1].length == x)
                    ++f->spans[turn][count - 1].length;
                else
                    f->spans[turn][count++] = (span){x, 1};
            }
        }
        f->row_start[turn][h] = (int32_t)count;
    }
}

/*
 * The lowest place (then the leftmost) for turn k of the footprint whose top is below *best_top; 0 if none. A place
 * is tried row by row of the footprint, starting with the row that blocked the last try; a blocked span skips the
 * places that would still cover the occupied cells it ran into.
 */
static int find_place(int32_t *place, int32_t *best_top, const packer *p, int turn)
{
    const footprint *f = &p->turns;
    const int32_t w = f->width[turn], h = f->height[turn], grid = p->grid;
    int32_t hint = 0;
    for (int32_t y = 0; y + h <= grid && y + h < *best_top; ++y) {
        int32_t x = 0;
        while (x + w <= grid) {
            int blocked = 0;
            for (int32_t n = 0; n < h && !blocked; ++n) {
                const int32_t row = (hint + n) % h;
                const int32_t *free_run = p->free_run + (size_t)(y + row) * (size_t)grid + (size_t)x;
                for (int32_t s = f->row_start[turn][row]; s < f->row_start[turn][row + 1]; ++s) {
                    const span piece = f->spans[turn][s];
                    const int32_t free = free_run[piece.start];
                    if (free < piece.length) {
                        x += free > 0 ? free + 1 : -free;
                        hint = row;
                        blocked = 1;
                        break;
                    }
                }
            }
            if (!blocked) {
                place[0] = x;
                place[1] = y;
                *best_top = y + h;
                return 1;
            }
        }
    }
    return 0;
}

/* Marks the chart's own cells (turned and placed; not its margin) occupied and updates the free runs of their rows. */
static void occupy(packer *p, const chart_box *box, int32_t width, int32_t height)
{
    const unsigned char *cells = p->cells;
    const int32_t d = p->dilation, grown_width = width + 2 * d, grown_height = height + 2 * d, grid = p->grid;
    for (int32_t y = 0; y < height; ++y)
        for (int32_t x = 0; x < width; ++x) {
            if (!cells[(size_t)y * (size_t)width + (size_t)x])
                continue;
            double turned[2];
            turn_point(turned, box->quarter_turns, x + d + 0.5, y + d + 0.5, grown_width, grown_height);
            const size_t column = (size_t)(box->cell[0] + (int32_t)turned[0]), row = (size_t)(box->cell[1] + (int32_t)turned[1]);
            p->occupied[row * (size_t)grid + column] = 1;
        }
    const int32_t rows = box->quarter_turns % 2 ? grown_width : grown_height;
    for (int32_t y = box->cell[1]; y < box->cell[1] + rows; ++y) {
        int32_t run = 0;
        for (int32_t x = grid; x-- > 0;) {
            if (p->occupied[(size_t)y * (size_t)grid + (size_t)x])
                run = run < 0 ? run - 1 : -1;
            else
                run = run > 0 ? run + 1 : 1;
            p->free_run[(size_t)y * (size_t)grid + (size_t)x] = run;
        }
    }
}

/* Rasterizes box's chart at cells_per_unit into p->cells; 0 when it, grown by the margin, is wider or taller than
 * the grid. */
static int rasterize_chart(int32_t *width, int32_t *height, packer *p, const chart_box *box, const double *uv,
                           const int32_t *members, size_t begin, size_t end, double cells_per_unit)
{
    const double limit = p->grid - 2 * p->dilation;
    const double w = ceil(cells_per_unit * box->size[0] * (1 - 1e-12));
    const double h = ceil(cells_per_unit * box->size[1] * (1 - 1e-12));
    if (!(fmax(w, 1) <= limit && fmax(h, 1) <= limit)) /* NaN too: the comparison fails */
        return 0;
    *width = w < 1 ? 1 : (int32_t)w;
    *height = h < 1 ? 1 : (int32_t)h;
    memset(p->cells, 0, (size_t)*width * (size_t)*height);
    for (size_t i = begin; i < end; ++i) {
        double corners[3][2];
        for (int k = 0; k < 3; ++k)
            chart_point(corners[k], box, uv + 6 * (size_t)members[i] + 2 * k, cells_per_unit);
        rasterize_triangle(p->cells, *width, *height, corners);
    }
    return 1;
}

/*
 * Places the charts (larger first) at `scale`: each at the turn and place whose top is lowest, bottom-left
 * first, where its footprint covers no cell of an earlier chart. Returns 0 when a chart finds no place.
 */
static int place_charts(packer *p, chart_box *boxes, size_t count, double scale, const double *uv,
                        const int32_t *offsets, const int32_t *members)
{
    const size_t grid = (size_t)p->grid;
    memset(p->occupied, 0, grid * grid);
    for (size_t y = 0; y < grid; ++y)
        for (size_t x = 0; x < grid; ++x)
            p->free_run[y * grid + x] = (int32_t)(grid - x);
    const double cells_per_unit = scale * (double)grid;
    for (size_t i = 0; i < count; ++i) {
        chart_box *box = &boxes[i];
        int32_t width, height;
        if (!rasterize_chart(&width, &height, p, box, uv, members, (size_t)offsets[box->chart],
                             (size_t)offsets[box->chart + 1], cells_per_unit))
            return 0;
        make_footprint(p, width, height);
        int32_t best_top = p->grid + 1, place[2];
        box->quarter_turns = -1;
        for (int turn = 0; turn < QUARTER_TURNS; ++turn)
            if (find_place(place, &best_top, p, turn)) {
                box->quarter_turns = turn;
                box->cell[0] = place[0];
                box->cell[1] = place[1];
            }
        if (box->quarter_turns < 0)
            return 0;
        box->raster[0] = width;
        box->raster[1] = height;
        occupy(p, box, width, height);
    }
    return 1;
}
static sk_status check_pack_arguments(const double *uv, const int32_t *charts, const double *surface_area,
                                      size_t triangle_count, const sk_pack_options *options, sk_error *error)
{
    if (options->texture_size < 1 || options->texture_size > SK_PACK_MAX_TEXTURE_SIZE)
        return sk_fail(error, SK_ERROR_ARGUMENT, "texture_size must be in [1, %d] texels (got %d)",
                       SK_PACK_MAX_TEXTURE_SIZE, options->texture_size);
    if (!(isfinite(options->margin) && options->margin >= 0 && 2 * options->margin < options->texture_size))
        return sk_fail(error, SK_ERROR_ARGUMENT, "margin must be in [0, texture_size / 2) texels (got %g for %d)",
                       options->margin, options->texture_size);
    const size_t bad = sk_first_non_finite(uv, 6 * triangle_count);
    if (bad < 6 * triangle_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "triangle %zu has a uv coordinate that is not finite", bad / 6);
    for (size_t t = 0; t < triangle_count; ++t) {
        if (charts[t] < 0 || (size_t)charts[t] >= triangle_count)
            return sk_fail(error, SK_ERROR_INDEX, "triangle %zu has chart %d, outside [0, %zu)", t, charts[t],
                           triangle_count);
        if (surface_area && !(isfinite(surface_area[t]) && surface_area[t] > 0))
            return sk_fail(error, SK_ERROR_ARGUMENT, "triangle %zu has surface area %g (must be positive)", t,
                           surface_area[t]);
    }
    return SK_OK;
}

static double signed_area(const double *corners)
{
    return ((corners[2] - corners[0]) * (corners[5] - corners[1]) - (corners[4] - corners[0]) * (corners[3] - corners[1])) / 2;
}

static sk_status overflowing_chart(size_t chart, sk_error *error)
{
    return sk_fail(error, SK_ERROR_NOT_FINITE, "chart %zu: its uv extent overflows double precision (coordinates "
                   "near 1e308); flatten it again or rescale its uvs", chart);
}

/* Density, hull and smallest rectangle of each chart; members: the triangles of chart c at offsets[c]... */
static sk_status measure_charts(chart_box *boxes, size_t *box_count, const double *uv, const double *surface_area,
                                const int32_t *offsets, const int32_t *members, size_t triangle_count, sk_error *error)
{
    point *points = sk_allocate(3 * triangle_count, sizeof *points);
    point *hull = sk_allocate(6 * triangle_count + 1, sizeof *hull);
    if (!points || !hull) {
        free(points);
        free(hull);
        return sk_fail(error, SK_ERROR_MEMORY, "sk_pack: out of memory for %zu triangles", triangle_count);
    }
    sk_status status = SK_OK;
    *box_count = 0;
    for (size_t c = 0; c < triangle_count && status == SK_OK; ++c) {
        const size_t begin = (size_t)offsets[c], end = (size_t)offsets[c + 1];
        if (begin == end)
            continue;
        double uv_area = 0.0, area = 0.0;
        for (size_t i = begin; i < end; ++i) {
            const size_t t = (size_t)members[i];
            uv_area += signed_area(uv + 6 * t);
            area += surface_area ? surface_area[t] : 0.0;
        }
        if (!isfinite(uv_area)) {
            status = overflowing_chart(c, error);
            break;
        }
        if (!(uv_area > 0)) {
            status = sk_fail(error, SK_ERROR_ARGUMENT, "chart %zu has no positive uv area (%g): it cannot be packed",
                             c, uv_area);
            break;
        }
        chart_box *box = &boxes[(*box_count)++];
        memset(box, 0, sizeof *box);
        box->chart = (int32_t)c;
        box->density = surface_area ? sqrt(area / uv_area) : 1.0;
        box->area = box->density * box->density * uv_area;
        size_t count = 0;
        for (size_t i = begin; i < end; ++i)
            for (int k = 0; k < 3; ++k) {
                const double *x = uv + 6 * (size_t)members[i] + 2 * k;
                points[count++] = (point){box->density * x[0], box->density * x[1]};
            }
        smallest_rectangle(box, hull, convex_hull(hull, points, count));
        if (!(isfinite(box->density) && isfinite(box->size[0] * box->size[1])))
            status = overflowing_chart(c, error);
    }
    free(points);
    free(hull);
    return status;
}

/* The packer's buffers for a grid of `grid` cells a side; 0 when memory is short. */
static int open_packer(packer *p, int32_t grid, int32_t dilation)
{
    memset(p, 0, sizeof *p);
    p->grid = grid;
    p->dilation = dilation;
    const size_t cells = (size_t)grid * (size_t)grid;
    p->occupied = sk_allocate(cells, 1);
    p->free_run = sk_allocate(cells, sizeof *p->free_run);
    p->cells = sk_allocate(cells, 1);
    p->grown = sk_allocate(cells, 1);
    p->grown_cells = sk_allocate(cells, 1);
    p->prefix = sk_allocate((size_t)grid + 1, sizeof *p->prefix);
    int ok = p->occupied && p->free_run && p->cells && p->grown && p->grown_cells && p->prefix;
    for (int turn = 0; turn < QUARTER_TURNS; ++turn) {
        p->turns.row_start[turn] = sk_allocate((size_t)grid + 1, sizeof *p->turns.row_start[turn]);
        /* at most a span and a gap after it: (width + 1) / 2 a row */
        p->turns.spans[turn] = sk_allocate((size_t)grid * ((size_t)grid + 1) / 2 + 1, sizeof *p->turns.spans[turn]);
        ok = ok && p->turns.row_start[turn] && p->turns.spans[turn];
    }
    return ok;
}

/* The margin in whole cells of a grid of `grid` cells a side (rounded up: never less than asked). */
static int32_t margin_cells(const sk_pack_options *options, int32_t grid)
{
    return (int32_t)ceil(options->margin * grid / options->texture_size);
}

static void close_packer(packer *p)
{
    free(p->occupied);
    free(p->free_run);
    free(p->cells);
    free(p->grown);
    free(p->grown_cells);
    free(p->prefix);
    for (int turn = 0; turn < QUARTER_TURNS; ++turn) {
        free(p->turns.row_start[turn]);
        free(p->turns.spans[turn]);
    }
}

/* What a search for the scale needs: the charts and where the best placement found so far is kept. */
typedef struct scale_search {
    chart_box *boxes, *best; /* boxes: placed by each try; best: the placement at best_scale */
    size_t count;
    double best_scale;
    const double *uv;
    const int32_t *offsets, *members;
} scale_search;

/* Tries `steps` scales by bisection of (low, high) on p's grid, low assumed to fit; every fitting one on the
 * finest grid (keep) is kept in search->best when larger. Returns the largest fitting scale tried, or low. */
static double bisect_scale(scale_search *search, packer *p, double low, double high, int steps, int keep)
{
    for (int step = 0; step < steps; ++step) {
        const double middle = (low + high) / 2;
        if (place_charts(p, search->boxes, search->count, middle, search->uv, search->offsets, search->members)) {
            low = middle;
            if (keep && middle > search->best_scale) {
                search->best_scale = middle;
                memcpy(search->best, search->boxes, search->count * sizeof *search->boxes);
            }
        } else {
            high = middle;
        }
    }
    return low;
}

static int try_scale(scale_search *search, packer *p, double scale)
{
    if (!place_charts(p, search->boxes, search->count, scale, search->uv, search->offsets, search->members))
        return 0;
    if (scale >= search->best_scale) {
        search->best_scale = scale;
        memcpy(search->best, search->boxes, search->count * sizeof *search->boxes);
    }
    return 1;
}

/*
 * The largest scale at which the charts fit, with search->best placed at it: a coarse bisection on a grid of a
 * quarter of the cells a side (a sixteenth of the work a try) brackets it, a few fine tries refine it. Above 1 / sqrt(total area) the
 * charts' area alone would exceed the square.
 */
static void search_scale(scale_search *search, packer *fine, packer *coarse, double total_area)
{
    const double high = 1.0 / sqrt(total_area);
    double guess = 0.0;
    if (coarse) {
        guess = place_charts(coarse, search->boxes, search->count, LIKELY_SCALE * high, search->uv, search->offsets,
                             search->members)
                    ? bisect_scale(search, coarse, LIKELY_SCALE * high, high, COARSE_BISECTIONS, 0)
                    : bisect_scale(search, coarse, 0.0, LIKELY_SCALE * high, COARSE_BISECTIONS, 0);
    }
    if (guess > 0 && try_scale(search, fine, guess))
        bisect_scale(search, fine, guess, fmin(high, guess * (1 + FINE_BRACKET)), FINE_BISECTIONS, 1);
    else
        bisect_scale(search, fine, 0.0, guess > 0 ? guess : high, COARSE_BISECTIONS + FINE_BISECTIONS, 1);
}

sk_status sk_pack(double *destination, sk_pack_report *report, const double *uv, const int32_t *charts,
                  const double *surface_area, size_t triangle_count, const sk_pack_options *options, sk_error *error)
{
    if (!destination || !report || !uv || !charts || !options)
        return sk_fail(error, SK_ERROR_ARGUMENT, "sk_pack: a null pointer");
    if (triangle_count == 0 || triangle_count > INT32_MAX / 3)
        return sk_fail(error, SK_ERROR_ARGUMENT, "triangle_count must be in [1, %d] (got %zu)", INT32_MAX / 3,
                       triangle_count);
    sk_status status = check_pack_arguments(uv, charts, surface_area, triangle_count, options, error);
    if (status != SK_OK)
        return status;
    int32_t *offsets = sk_allocate_zeroed(triangle_count + 2, sizeof *offsets);
    int32_t *members = sk_allocate(triangle_count, sizeof *members);
    chart_box *boxes = sk_allocate(triangle_count, sizeof *boxes);
    int32_t *box_of_chart = sk_allocate(triangle_count, sizeof *box_of_chart);
    size_t count = 0;
    if (!offsets || !members || !boxes || !box_of_chart) {
        status = sk_fail(error, SK_ERROR_MEMORY, "sk_pack: out of memory for %zu triangles", triangle_count);
        goto done;
    }
    sk_group_by_chart(offsets, members, charts, triangle_count);
    status = measure_charts(boxes, &count, uv, surface_area, offsets, members, triangle_count, error);
    if (status != SK_OK)
        goto done;
    qsort(boxes, count, sizeof *boxes, larger_first);
    double total_area = 0.0;
    for (size_t i = 0; i < count; ++i)
        total_area += boxes[i].area;
    const int32_t grid = options->texture_size < MAX_GRID_CELLS ? options->texture_size : MAX_GRID_CELLS;
    const int32_t coarse_grid = grid / 4;
    packer fine = {0}, coarse = {0}; /* zeroed: closing one that never opened frees nothing */
    const int have_coarse = coarse_grid >= MIN_COARSE_GRID;
    const int opened = open_packer(&fine, grid, margin_cells(options, grid)) &&
                       (!have_coarse || open_packer(&coarse, coarse_grid, margin_cells(options, coarse_grid)));
    chart_box *best = sk_allocate(count, sizeof *best);
    scale_search search = {boxes, best, count, 0.0, uv, offsets, members};
    if (!opened || !best) {
        status = sk_fail(error, SK_ERROR_MEMORY, "sk_pack: out of memory for a %d-cell grid", grid);
    } else if (!try_scale(&search, &fine, 0.0)) {
        status = sk_fail(error, SK_ERROR_ARGUMENT,
                         "%zu charts do not fit a %d-texel texture with %g texels of margin, however small",
                         count, options->texture_size, options->margin);
    } else {
        search_scale(&search, &fine, have_coarse ? &coarse : NULL, total_area);
        memcpy(boxes, best, count * sizeof *boxes);
    }
    const int32_t d = fine.dilation;
    const double scale = search.best_scale;
    close_packer(&fine);
    close_packer(&coarse);
    free(best);
    if (status != SK_OK)
        goto done;
    for (size_t i = 0; i < count; ++i)
        box_of_chart[boxes[i].chart] = (int32_t)i;
    double covered = 0.0;
    for (size_t t = 0; t < triangle_count; ++t) {
        const chart_box *box = &boxes[box_of_chart[charts[t]]];
        for (int k = 0; k < 3; ++k) {
            double cell[2], turned[2];
            chart_point(cell, box, uv + 6 * t + 2 * (size_t)k, scale * grid);
            turn_point(turned, box->quarter_turns, cell[0] + d, cell[1] + d, box->raster[0] + 2 * d,
                       box->raster[1] + 2 * d);
            for (int axis = 0; axis < 2; ++axis)
                destination[6 * t + 2 * (size_t)k + (size_t)axis] = (box->cell[axis] + turned[axis]) / grid;
        }
        covered += fabs(signed_area(destination + 6 * t));
    }
    report->chart_count = count;
    report->scale = scale;
    report->packing_efficiency = covered;
    status = sk_succeed(error);
done:
    free(offsets);
    free(members);
    free(boxes);
    free(box_of_chart);
    return status;
}
