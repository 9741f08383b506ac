/*
 * Packing charts into the unit square (Merry 2007, section 5.4, after Sander et al. 2001): each chart brought
 * to a common texel density, turned to its smallest bounding rectangle (rotating calipers on its convex hull)
 * with the long side vertical, the rectangles dropped tallest first onto a skyline in rows that run
 * alternately left-to-right and right-to-left, and the largest common scale that fits found by bisection.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_mesh.h"

#define SCALE_BISECTIONS 60

typedef struct chart_box {
    int32_t chart;
    double density;         /* the chart's scale to its surface area */
    double cosine, sine;    /* the rotation (x' = c x + s y, y' = -s x + c y) to its smallest rectangle */
    double low[2], size[2]; /* that rectangle after rotation: corner and (width, height), height >= width */
    double place[2];        /* its packed corner (before the margin offset), in the unit square */
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

static int taller_first(const void *a, const void *b)
{
    const chart_box *x = a, *y = b;
    return x->size[1] != y->size[1] ? SK_ORDER(y->size[1], x->size[1]) : SK_ORDER(x->chart, y->chart);
}

/*
 * Places the boxes (tallest first) at `scale`, each grown by `margin` (the square's side is side): rows run
 * alternately left-to-right and right-to-left and each box drops onto the skyline, kept per column of
 * skyline_size columns (the texels). Boxes span whole columns, so a box lands on the highest column it covers
 * and cannot overlap an earlier one. Returns 0 when a box does not fit.
 */
static int place_boxes(chart_box *boxes, size_t count, double scale, double margin, double side, double *skyline,
                       size_t skyline_size)
{
    const double column = side / (double)skyline_size;
    memset(skyline, 0, skyline_size * sizeof *skyline);
    int rightward = 1;
    size_t cursor = 0; /* the column the row has reached */
    for (size_t i = 0; i < count; ++i) {
        const double width = scale * boxes[i].size[0] + margin, height = scale * boxes[i].size[1] + margin;
        const double columns = ceil(width / column * (1 - 1e-12));
        if (!(columns <= (double)skyline_size)) /* NaN too: it would become a huge span */
            return 0;
        const size_t span = columns < 1 ? 1 : (size_t)columns;
        if (rightward && cursor + span > skyline_size) {
            rightward = 0;
            cursor = skyline_size;
        } else if (!rightward && cursor < span) {
            rightward = 1;
            cursor = 0;
        }
        const size_t first = rightward ? cursor : cursor - span;
        double y = 0.0;
        for (size_t c = first; c < first + span; ++c)
            y = fmax(y, skyline[c]);
        if (y + height > side)
            return 0;
        for (size_t c = first; c < first + span; ++c)
            skyline[c] = y + height;
        boxes[i].place[0] = (double)first * column;
        boxes[i].place[1] = y;
        cursor = rightward ? first + span : first;
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

/* Finds the largest scale at which the boxes fit (bisection) and leaves them placed at it. */
static sk_status fit_boxes(double *scale, chart_box *boxes, size_t count, const sk_pack_options *options,
                           sk_error *error)
{
    const double margin = options->margin / options->texture_size, side = 1.0 - margin;
    double *skyline = sk_allocate((size_t)options->texture_size, sizeof *skyline);
    if (!skyline)
        return sk_fail(error, SK_ERROR_MEMORY, "sk_pack: out of memory for the skyline");
    double total = 0.0;
    for (size_t i = 0; i < count; ++i)
        total += boxes[i].size[0] * boxes[i].size[1];
    double low = 0.0, high = 1.0 / sqrt(total); /* above high the boxes' area alone exceeds the square */
    sk_status status = SK_OK;
    if (!place_boxes(boxes, count, 0.0, margin, side, skyline, (size_t)options->texture_size)) {
        status = sk_fail(error, SK_ERROR_ARGUMENT,
                         "%zu charts do not fit a %d-texel texture with %g texels of margin, however small",
                         count, options->texture_size, options->margin);
    } else {
        for (int step = 0; step < SCALE_BISECTIONS; ++step) {
            const double middle = (low + high) / 2;
            *(place_boxes(boxes, count, middle, margin, side, skyline, (size_t)options->texture_size) ? &low
                                                                                                       : &high) = middle;
        }
        place_boxes(boxes, count, low, margin, side, skyline, (size_t)options->texture_size);
        *scale = low;
    }
    free(skyline);
    return status;
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
    qsort(boxes, count, sizeof *boxes, taller_first);
    double scale = 0.0;
    status = fit_boxes(&scale, boxes, count, options, error);
    if (status != SK_OK)
        goto done;
    /* Each box sits margin/2 inside its grown cell, and the cells margin/2 inside the square. */
    const double margin = options->margin / options->texture_size;
    for (size_t i = 0; i < count; ++i)
        box_of_chart[boxes[i].chart] = (int32_t)i;
    double covered = 0.0;
    for (size_t t = 0; t < triangle_count; ++t) {
        const chart_box *box = &boxes[box_of_chart[charts[t]]];
        for (int k = 0; k < 3; ++k) {
            const double x = box->density * uv[6 * t + 2 * (size_t)k], y = box->density * uv[6 * t + 2 * (size_t)k + 1];
            const double turned[2] = {box->cosine * x + box->sine * y, -box->sine * x + box->cosine * y};
            for (int axis = 0; axis < 2; ++axis)
                destination[6 * t + 2 * (size_t)k + (size_t)axis] =
                    margin + box->place[axis] + scale * (turned[axis] - box->low[axis]);
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
