/*
 * The passes of section 5.3 for one disc chart: the free boundary (LSCM, or Tutte's embedding when LSCM flips),
 * the straight pinned boundary between corners, the unit-circle fallback, and the extra corners.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_flatten.h"

/* ---------------------------------------------------------------------------------------------
 * The passes
 * ------------------------------------------------------------------------------------------- */

/* Metric shortest-path distances from one vertex over the chart's edges (Dijkstra, binary heap). */
static void distances_from(double *distance, sk_vertex_distance *heap, const chart_mesh *m, int32_t source)
{
    for (size_t i = 0; i < m->vertex_count; ++i)
        distance[i] = INFINITY;
    size_t size = 0;
    distance[source] = 0.0;
    sk_heap_push(heap, &size, (sk_vertex_distance){0.0, source});
    while (size > 0) {
        const sk_vertex_distance top = sk_heap_pop(heap, &size);
        if (top.distance > distance[top.vertex])
            continue;
        for (int32_t s = m->ring_offsets[top.vertex]; s < m->ring_offsets[top.vertex + 1]; ++s) {
            const double through = top.distance + m->ring_length[s];
            if (through < distance[m->ring[s]]) {
                distance[m->ring[s]] = through;
                sk_heap_push(heap, &size, (sk_vertex_distance){through, m->ring[s]});
            }
        }
    }
}

static int32_t farthest_on_boundary(const chart_mesh *m, const double *distance)
{
    int32_t best = m->loop[0];
    for (size_t i = 0; i < m->boundary_count; ++i)
        if (distance[m->loop[i]] > distance[best])
            best = m->loop[i];
    return best;
}

/* Two boundary vertices far apart (two Dijkstra sweeps), and their distance. */
static int farthest_pair(int32_t pair[2], double *separation, const chart_mesh *m)
{
    double *distance = sk_allocate(m->vertex_count, sizeof *distance);
    sk_vertex_distance *heap = sk_allocate((size_t)m->ring_offsets[m->vertex_count] + 1, sizeof *heap);
    if (distance && heap) {
        distances_from(distance, heap, m, m->loop[0]);
        pair[0] = farthest_on_boundary(m, distance);
        distances_from(distance, heap, m, pair[0]);
        pair[1] = farthest_on_boundary(m, distance);
        *separation = distance[pair[1]];
    }
    free(distance);
    free(heap);
    return distance && heap;
}

/* Scales uv about the origin so that the chart's uv area equals its metric area ("metric units"). */
static void scale_to_metric_area(double *uv, const chart_mesh *m)
{
    double uv_area = 0.0;
    for (size_t t = 0; t < m->triangle_count; ++t) {
        const double *a = corner_uv(uv, m, t, 0), *b = corner_uv(uv, m, t, 1), *c = corner_uv(uv, m, t, 2);
        uv_area += cross2(b[0] - a[0], b[1] - a[1], c[0] - a[0], c[1] - a[1]) / 2;
    }
    if (!(uv_area > 0))
        return;
    const double scale = sqrt(sk_chart_metric_area(m) / uv_area);
    for (size_t i = 0; i < 2 * m->vertex_count; ++i)
        uv[i] *= scale;
}

typedef struct chart_scratch {
    double *free_uv;            /* pass 1 */
    double *uv;                 /* the pinned pass being tried */
    unsigned char *pinned, *movable, *is_corner; /* per local vertex */
    int32_t *loop_position;     /* per local vertex: its position in the boundary loop, or -1 */
    double *arc;                /* per loop position (and one more): arc length from loop[0] */
    int32_t *previous_corner;   /* per loop position: the loop position of the corner before (or at) it */
    int32_t *next_corner;       /* per loop position: the corner after (or at) it */
    unsigned char *wanted_side; /* per loop position of a corner: the side after it may get an extra corner */
    int32_t *rotated_loop;      /* the corner rule's scratch: the loop from another start, with its arc */
    double *rotated_arc;
} chart_scratch;

static void free_scratch(chart_scratch *s)
{
    SK_FREE_ALL(s->free_uv, s->uv, s->pinned, s->movable, s->is_corner, s->loop_position, s->arc, s->previous_corner,
                s->next_corner, s->wanted_side, s->rotated_loop, s->rotated_arc);
    memset(s, 0, sizeof *s);
}

static int allocate_scratch(chart_scratch *s, const chart_mesh *m)
{
    const size_t v = m->vertex_count, b = m->boundary_count;
    memset(s, 0, sizeof *s);
    s->free_uv = sk_allocate(2 * v, sizeof *s->free_uv);
    s->uv = sk_allocate(2 * v, sizeof *s->uv);
    s->pinned = sk_allocate(v, 1);
    s->movable = sk_allocate(v, 1);
    s->is_corner = sk_allocate(v, 1);
    s->loop_position = sk_allocate(v, sizeof *s->loop_position);
    s->arc = sk_allocate(b + 1, sizeof *s->arc);
    s->previous_corner = sk_allocate(b, sizeof *s->previous_corner);
    s->next_corner = sk_allocate(b, sizeof *s->next_corner);
    s->wanted_side = sk_allocate(b, 1);
    s->rotated_loop = sk_allocate(b + 1, sizeof *s->rotated_loop);
    s->rotated_arc = sk_allocate(b + 1, sizeof *s->rotated_arc);
    if (!s->free_uv || !s->uv || !s->pinned || !s->movable || !s->is_corner || !s->loop_position || !s->arc ||
        !s->previous_corner || !s->next_corner || !s->wanted_side || !s->rotated_loop || !s->rotated_arc) {
        free_scratch(s);
        return 0;
    }
    for (size_t i = 0; i < v; ++i)
        s->loop_position[i] = -1;
    s->arc[0] = 0.0;
    for (size_t i = 0; i < b; ++i) {
        s->loop_position[m->loop[i]] = (int32_t)i;
        s->arc[i + 1] = s->arc[i] + m->loop_length[i];
    }
    return 1;
}

/*
 * Tutte's embedding of the chart: the boundary on a circle whose circumference is the chart's metric
 * perimeter, spaced by arc length, and every interior vertex at the average of its neighbours.
 */
static int tutte_layout(double *uv, const chart_mesh *m, chart_scratch *s, pass_counts *counts)
{
    const size_t b = m->boundary_count;
    const double perimeter = s->arc[b], radius = perimeter / TWO_PI;
    memset(uv, 0, 2 * m->vertex_count * sizeof *uv);
    for (size_t i = 0; i < b; ++i) {
        const double angle = TWO_PI * s->arc[i] / perimeter;
        uv[2 * (size_t)m->loop[i]] = radius * cos(angle);
        uv[2 * (size_t)m->loop[i] + 1] = radius * sin(angle);
    }
    memcpy(s->pinned, m->on_boundary, m->vertex_count);
    return sk_solve_quadratic(uv, m, s->pinned, sk_assemble_tutte, &counts->solver_iterations);
}

/* LSCM with two pinned boundary vertices, far apart. */
static int two_pin_lscm(double *uv, const chart_mesh *m, chart_scratch *s, pass_counts *counts)
{
    int32_t pins[2];
    double separation = 0.0;
    if (!farthest_pair(pins, &separation, m))
        return 0;
    memset(uv, 0, 2 * m->vertex_count * sizeof *uv);
    memset(s->pinned, 0, m->vertex_count);
    s->pinned[pins[0]] = s->pinned[pins[1]] = 1;
    uv[2 * (size_t)pins[1]] = separation > 0 ? separation : 1.0;
    if (!sk_solve_quadratic(uv, m, s->pinned, sk_assemble_lscm, &counts->solver_iterations))
        return 0;
    return 1;
}

/*
 * Pass 1: a conformal layout, scaled to metric units. A chart of BOUNDARY_FIRST_MIN_VERTICES interior vertices or
 * more gets boundary first flattening, whose solves take nearly constant steps; a smaller one, or one where that
 * flipped a triangle, LSCM with two pins. LSCM can flip triangles where the metric is far from flat; the
 * optimisation cannot start from there (the stretch is infinite), so such a chart starts from Tutte's embedding
 * instead, which flips nothing, and the optimisation (optimise_free), which never flips a triangle either, frees
 * its boundary.
 */
static int free_boundary_pass(double *uv, const chart_mesh *m, chart_scratch *s, pass_counts *counts)
{
    int laid_out = 0;
    if (m->boundary_count >= 3 && m->vertex_count - m->boundary_count >= BOUNDARY_FIRST_MIN_VERTICES) {
        const int outcome = sk_boundary_first_layout(uv, m, &counts->solver_iterations);
        if (outcome < 0)
            return 0;
        laid_out = outcome > 0 && sk_count_invalid(m, uv) == 0;
        counts->boundary_first_charts += (size_t)laid_out;
    }
    if (!laid_out) {
        if (!two_pin_lscm(uv, m, s, counts))
            return 0;
        if (sk_count_invalid(m, uv) > 0) {
            if (!tutte_layout(uv, m, s, counts))
                return 0;
            ++counts->tutte_charts;
        }
    }
    scale_to_metric_area(uv, m);
    return 1;
}

/* The free layout's stretch optimisation, every vertex movable (when the options ask for it). */
static void optimise_free(double *uv, const chart_mesh *m, chart_scratch *s, const sk_flatten_options *options,
                          pass_counts *counts)
{
    if (options->optimise) {
        memset(s->movable, 1, m->vertex_count);
        sk_optimise_stretch(m, uv, s->movable, options->sweep_limit, counts);
    }
}


static int is_corner_at(const chart_scratch *s, const chart_mesh *m, size_t position)
{
    return s->is_corner[m->loop[position]];
}

/* Links every loop position to the corners before and after it (a corner is its own); needs one corner. */
static void link_corners(chart_scratch *s, const chart_mesh *m)
{
    const size_t b = m->boundary_count;
    size_t first = 0;
    while (!is_corner_at(s, m, first))
        ++first;
    int32_t last = (int32_t)first;
    for (size_t step = 0; step < b; ++step) {
        const size_t i = (first + step) % b;
        if (is_corner_at(s, m, i))
            last = (int32_t)i;
        s->previous_corner[i] = last;
    }
    last = (int32_t)first;
    for (size_t step = 0; step < b; ++step) {
        const size_t i = (first + b - step) % b;
        if (is_corner_at(s, m, i))
            last = (int32_t)i;
        s->next_corner[i] = last;
    }
}

/* The arc length going forward from loop position `from` to `to` (the whole perimeter when they are equal). */
static double arc_between(const chart_scratch *s, const chart_mesh *m, size_t from, size_t to)
{
    const double difference = s->arc[to] - s->arc[from];
    return difference > 0 ? difference : difference + s->arc[m->boundary_count];
}

/* Marks the chart's corners: the given ones on its boundary, completed to three by sk_chart_corners' rule. */
static void mark_corners(chart_scratch *s, const chart_mesh *m, const flatten_input *in)
{
    memset(s->is_corner, 0, m->vertex_count);
    for (size_t i = 0; i < m->boundary_count; ++i)
        if (in->corners[m->vertex[m->loop[i]]])
            s->is_corner[m->loop[i]] = 1;
    sk_complete_corners(s->is_corner, m->loop, s->arc, m->boundary_count, s->rotated_loop, s->rotated_arc);
    link_corners(s, m);
}

/* Puts the boundary's non-corner vertices on the segments between the corners already placed in uv, spaced by
 * the metric lengths of the boundary edges. */
static void straighten_sides(double *uv, const chart_scratch *s, const chart_mesh *m)
{
    for (size_t i = 0; i < m->boundary_count; ++i) {
        if (is_corner_at(s, m, i))
            continue;
        const size_t p = (size_t)s->previous_corner[i], q = (size_t)s->next_corner[i];
        const double fraction = arc_between(s, m, p, i) / arc_between(s, m, p, q);
        const double *a = uv + 2 * (size_t)m->loop[p], *c = uv + 2 * (size_t)m->loop[q];
        double *x = uv + 2 * (size_t)m->loop[i];
        x[0] = a[0] + fraction * (c[0] - a[0]);
        x[1] = a[1] + fraction * (c[1] - a[1]);
    }
}

/*
 * Pass 2 (circle = 0): corners at their pass-1 positions. Pass 3 (circle = 1): corners on a circle whose
 * circumference is the chart's metric perimeter, spaced by arc length, counterclockwise like the loop.
 * Either way every boundary vertex is pinned, the interior solved by LSCM and then optimised.
 */
static int pinned_pass(double *uv, const chart_mesh *m, chart_scratch *s, const sk_flatten_options *options,
                       int circle, pass_counts *counts)
{
    const size_t b = m->boundary_count;
    memcpy(uv, s->free_uv, 2 * m->vertex_count * sizeof *uv);
    if (circle) {
        const double perimeter = s->arc[b], radius = perimeter / (TWO_PI);
        for (size_t i = 0; i < b; ++i)
            if (is_corner_at(s, m, i)) {
                const double angle = TWO_PI * s->arc[i] / perimeter;
                uv[2 * (size_t)m->loop[i]] = radius * cos(angle);
                uv[2 * (size_t)m->loop[i] + 1] = radius * sin(angle);
            }
    }
    straighten_sides(uv, s, m);
    memcpy(s->pinned, m->on_boundary, m->vertex_count);
    if (!sk_solve_quadratic(uv, m, s->pinned, sk_assemble_lscm, &counts->solver_iterations))
        return 0;
    if (options->optimise) {
        for (size_t i = 0; i < m->vertex_count; ++i)
            s->movable[i] = !m->on_boundary[i];
        sk_optimise_stretch(m, uv, s->movable, options->sweep_limit, counts);
    }
    return 1;
}

/*
 * Adds the extra corner of section 5.3 (Fig 5.8): the boundary vertex whose summed distances to the corners on
 * either side exceed the distance between those corners the most. Distances are measured in the pass-1
 * layout, which is the chart's metric shape up to the little stretch LSCM leaves. When the last pinned layout
 * has flipped or degenerate triangles, only the sides holding their boundary vertices are considered.
 * Returns 0 when no boundary vertex is left to become a corner.
 */
static int add_extra_corner(chart_scratch *s, const chart_mesh *m, const double *failed_uv)
{
    const size_t b = m->boundary_count;
    int restricted = 0;
    memset(s->wanted_side, 0, b);
    for (size_t t = 0; failed_uv && t < m->triangle_count; ++t) {
        if (valid_double_area(corner_uv(failed_uv, m, t, 0), corner_uv(failed_uv, m, t, 1),
                              corner_uv(failed_uv, m, t, 2)) > 0)
            continue;
        for (int k = 0; k < 3; ++k) {
            const int32_t position = s->loop_position[m->corner[3 * t + (size_t)k]];
            if (position >= 0 && !is_corner_at(s, m, (size_t)position)) {
                s->wanted_side[s->previous_corner[position]] = 1;
                restricted = 1;
            }
        }
    }
    int32_t best = -1;
    double best_excess = -1.0;
    for (size_t i = 0; i < b; ++i) {
        if (is_corner_at(s, m, i) || (restricted && !s->wanted_side[s->previous_corner[i]]))
            continue;
        const double *x = s->free_uv + 2 * (size_t)m->loop[i];
        const double *p = s->free_uv + 2 * (size_t)m->loop[s->previous_corner[i]];
        const double *q = s->free_uv + 2 * (size_t)m->loop[s->next_corner[i]];
        const double excess = hypot(x[0] - p[0], x[1] - p[1]) + hypot(x[0] - q[0], x[1] - q[1]) -
                              hypot(p[0] - q[0], p[1] - q[1]);
        if (excess > best_excess) {
            best_excess = excess;
            best = (int32_t)i;
        }
    }
    if (best < 0)
        return 0;
    s->is_corner[m->loop[best]] = 1;
    link_corners(s, m);
    return 1;
}

/*
 * Flattens one disc chart into result (2 per local vertex) by the passes of section 5.3. Returns 0 when memory
 * ran out.
 */
int sk_flatten_chart(double *result, const chart_mesh *m, const flatten_input *in, pass_counts *counts)
{
    const sk_flatten_options *options = &in->options;
    chart_scratch s;
    if (!allocate_scratch(&s, m))
        return 0;
    int ok = free_boundary_pass(s.free_uv, m, &s, counts);
    /* Optimised also when straightening will replace it: the corners keep their pass-1 positions and the
     * stretch limit is relative to pass 1, and both are better for it (from LSCM's layout, straightening
     * raised the creature's stretch to 1.28 instead of 1.12). */
    if (ok)
        optimise_free(s.free_uv, m, &s, options, counts);
    const double free_stretch = ok ? sk_chart_stretch(m, s.free_uv) : INFINITY;
    /* A free layout with flipped triangles is not kept: the pinned passes are its fallback. */
    if (ok && (options->straight || !isfinite(free_stretch))) {
        mark_corners(&s, m, in);
        for (int extra = 0; ok; ++extra) {
            ok = pinned_pass(s.uv, m, &s, options, 0, counts);
            double stretch = ok ? sk_chart_stretch(m, s.uv) : INFINITY;
            int circle = 0;
            if (ok && !isfinite(stretch)) {
                ok = pinned_pass(s.uv, m, &s, options, 1, counts);
                stretch = ok ? sk_chart_stretch(m, s.uv) : INFINITY;
                circle = 1;
            }
            if (ok && isfinite(stretch) && !(stretch > options->stretch_limit * free_stretch)) {
                memcpy(result, s.uv, 2 * m->vertex_count * sizeof *result);
                ++*(circle ? &counts->circle_charts : &counts->straight_charts);
                free_scratch(&s);
                scale_to_metric_area(result, m);
                return 1;
            }
            if (!ok || extra == EXTRA_CORNER_LIMIT || !add_extra_corner(&s, m, isfinite(stretch) ? NULL : s.uv))
                break;
            ++counts->extra_corners;
        }
    }
    if (ok) { /* the free boundary: asked for, or every straightening failed */
        const int free_better = isfinite(free_stretch) || !options->straight ||
                                sk_count_invalid(m, s.free_uv) <= sk_count_invalid(m, s.uv);
        memcpy(result, free_better ? s.free_uv : s.uv, 2 * m->vertex_count * sizeof *result);
        ++counts->free_charts;
    }
    free_scratch(&s);
    if (ok) /* a pinned boundary sets its own scale: every result is brought to metric units */
        scale_to_metric_area(result, m);
    return ok;
}
