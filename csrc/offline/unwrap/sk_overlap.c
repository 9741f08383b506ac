/* Overlap check: boundary self-intersections on a uniform grid, and the two-source split of section 5.3. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_flatten.h"

/* ---------------------------------------------------------------------------------------------
 * Overlap check: boundary self-intersections on a uniform grid, and the two-source split
 * ------------------------------------------------------------------------------------------- */

static double orient(const double a[2], const double b[2], const double c[2])
{
    return cross2(b[0] - a[0], b[1] - a[1], c[0] - a[0], c[1] - a[1]);
}

static int within_box(const double a[2], const double b[2], const double p[2])
{
    return p[0] >= fmin(a[0], b[0]) && p[0] <= fmax(a[0], b[0]) && p[1] >= fmin(a[1], b[1]) &&
           p[1] <= fmax(a[1], b[1]);
}

/* Whether segments ab and cd cross or touch. */
static int segments_meet(const double a[2], const double b[2], const double c[2], const double d[2])
{
    const double o1 = orient(a, b, c), o2 = orient(a, b, d), o3 = orient(c, d, a), o4 = orient(c, d, b);
    if (((o1 > 0 && o2 < 0) || (o1 < 0 && o2 > 0)) && ((o3 > 0 && o4 < 0) || (o3 < 0 && o4 > 0)))
        return 1;
    return (o1 == 0 && within_box(a, b, c)) || (o2 == 0 && within_box(a, b, d)) ||
           (o3 == 0 && within_box(c, d, a)) || (o4 == 0 && within_box(c, d, b));
}

typedef struct segment_grid {
    double origin[2], cell;
    size_t columns, rows;
    int32_t *offsets, *segments; /* per cell, CSR */
} segment_grid;

static void segment_cells(size_t range[4], const segment_grid *g, const double *a, const double *b)
{
    const double low[2] = {fmin(a[0], b[0]), fmin(a[1], b[1])}, high[2] = {fmax(a[0], b[0]), fmax(a[1], b[1])};
    const size_t limit[2] = {g->columns - 1, g->rows - 1};
    for (int axis = 0; axis < 2; ++axis) {
        const double first = floor((low[axis] - g->origin[axis]) / g->cell);
        const double last = floor((high[axis] - g->origin[axis]) / g->cell);
        range[2 * axis] = first <= 0 ? 0 : first >= (double)limit[axis] ? limit[axis] : (size_t)first;
        range[2 * axis + 1] = last <= 0 ? 0 : last >= (double)limit[axis] ? limit[axis] : (size_t)last;
    }
}

/*
 * Finds two non-adjacent boundary edges of the layout that cross or touch; returns 0 when there are none and
 * -1 when memory ran out. The edges go into a uniform grid of about one cell per edge (cells about one edge
 * long, at most four per edge), so only edges sharing a cell are compared.
 */
int sk_find_boundary_crossing(size_t crossing[2], const chart_mesh *m, const double *uv)
{
    const size_t b = m->boundary_count;
    if (b < 4)
        return 0;
    crossing[0] = 0; /* the answer when the whole boundary sits at one point */
    crossing[1] = 2;
    segment_grid g = {{INFINITY, INFINITY}, 0.0, 0, 0, NULL, NULL};
    double high[2] = {-INFINITY, -INFINITY}, total_length = 0.0;
    for (size_t i = 0; i < b; ++i) {
        const double *p = uv + 2 * (size_t)m->loop[i], *q = uv + 2 * (size_t)m->loop[(i + 1) % b];
        for (int axis = 0; axis < 2; ++axis) {
            g.origin[axis] = fmin(g.origin[axis], p[axis]);
            high[axis] = fmax(high[axis], p[axis]);
        }
        total_length += hypot(q[0] - p[0], q[1] - p[1]);
    }
    const double width = high[0] - g.origin[0], height = high[1] - g.origin[1];
    g.cell = fmax(total_length / (double)b, sqrt(width * height / (4.0 * (double)b)));
    if (!(g.cell > 0))
        return 1; /* every boundary vertex at one point: certainly overlapping */
    g.columns = (size_t)(width / g.cell) + 1;
    g.rows = (size_t)(height / g.cell) + 1;
    const size_t cells = g.columns * g.rows;
    g.offsets = sk_allocate_zeroed(cells + 1, sizeof *g.offsets);
    int found = 0;
    if (!g.offsets)
        return -1;
    size_t range[4];
    for (int fill = 0; fill < 2; ++fill) {
        for (size_t i = 0; i < b; ++i) {
            segment_cells(range, &g, uv + 2 * (size_t)m->loop[i], uv + 2 * (size_t)m->loop[(i + 1) % b]);
            for (size_t y = range[2]; y <= range[3]; ++y)
                for (size_t x = range[0]; x <= range[1]; ++x) {
                    const size_t cell = y * g.columns + x;
                    if (fill)
                        g.segments[g.offsets[cell]++] = (int32_t)i;
                    else
                        ++g.offsets[cell + 1];
                }
        }
        if (!fill) {
            for (size_t c = 0; c < cells; ++c)
                g.offsets[c + 1] += g.offsets[c];
            g.segments = sk_allocate((size_t)g.offsets[cells] + 1, sizeof *g.segments);
            if (!g.segments) {
                free(g.offsets);
                return -1;
            }
        } else { /* the fill advanced each cell's start to its end: shift back */
            for (size_t c = cells; c > 0; --c)
                g.offsets[c] = g.offsets[c - 1];
            g.offsets[0] = 0;
        }
    }
    for (size_t c = 0; c < cells && !found; ++c)
        for (int32_t x = g.offsets[c]; x < g.offsets[c + 1] && !found; ++x)
            for (int32_t y = x + 1; y < g.offsets[c + 1] && !found; ++y) {
                const size_t i = (size_t)g.segments[x], j = (size_t)g.segments[y];
                if ((i + 1) % b == j || (j + 1) % b == i)
                    continue;
                if (segments_meet(uv + 2 * (size_t)m->loop[i], uv + 2 * (size_t)m->loop[(i + 1) % b],
                                  uv + 2 * (size_t)m->loop[j], uv + 2 * (size_t)m->loop[(j + 1) % b])) {
                    crossing[0] = i < j ? i : j;
                    crossing[1] = i < j ? j : i;
                    found = 1;
                }
            }
    free(g.offsets);
    free(g.segments);
    return found;
}

/*
 * The split of section 5.3: a two-source breadth-first search over faces from the triangles of the two
 * crossing boundary edges; each face joins the source it is fewer edge crossings from (ties to the first).
 * Returns 0 when both edges belong to one triangle (nothing to split).
 */
int sk_split_labels(int32_t *labels, int32_t *queue, const chart_mesh *m, const size_t crossing[2])
{
    const int32_t first = m->loop_triangle[crossing[0]], second = m->loop_triangle[crossing[1]];
    if (first == second)
        return 0;
    sk_two_source_labels(labels, queue, m, first, second);
    return 1;
}
