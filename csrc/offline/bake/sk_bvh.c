/*
 * A bounding-volume hierarchy over triangles (median split on the longest axis of the centroids' box, leaves of
 * at most LEAF_SIZE), the nearest hit along a segment and the closest surface point within a distance, for the
 * ray-cast bake. SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <float.h>
#include <math.h>
#include <stdlib.h>

#include "sk_bake_internal.h"
#include "sk_internal.h"

#define LEAF_SIZE 4
#define MAX_DEPTH 64

typedef struct keyed_triangle {
    double key;
    int32_t triangle;
} keyed_triangle;

static int compare_keyed(const void *a, const void *b)
{
    const keyed_triangle *x = a, *y = b;
    const int order = SK_ORDER(x->key, y->key);
    return order ? order : SK_ORDER(x->triangle, y->triangle);
}

static const double *corner_position(const sk_bake_surface *surface, int32_t triangle, int corner)
{
    return surface->positions + 3 * (size_t)surface->triangles[3 * (size_t)triangle + (size_t)corner];
}

static void node_bounds(sk_bvh_node *node, const sk_bvh *bvh, size_t begin, size_t end)
{
    for (int k = 0; k < 3; ++k) {
        node->low[k] = DBL_MAX;
        node->high[k] = -DBL_MAX;
    }
    for (size_t i = begin; i < end; ++i)
        for (int c = 0; c < 3; ++c) {
            const double *p = corner_position(bvh->surface, bvh->order[i], c);
            for (int k = 0; k < 3; ++k) {
                node->low[k] = fmin(node->low[k], p[k]);
                node->high[k] = fmax(node->high[k], p[k]);
            }
        }
}

/* Splits the triangles of node `index` (order[begin, end)) until leaves are small; nodes[] has room for
 * 2 * triangle_count nodes, keyed[] is scratch of triangle_count. */
static void split(sk_bvh *bvh, keyed_triangle *keyed, size_t index, size_t begin, size_t end, int depth)
{
    sk_bvh_node *node = &bvh->nodes[index];
    node_bounds(node, bvh, begin, end);
    if (end - begin <= LEAF_SIZE || depth >= MAX_DEPTH) {
        node->first = (int32_t)begin;
        node->count = (int32_t)(end - begin);
        return;
    }
    int axis = 0;
    for (int k = 1; k < 3; ++k)
        if (node->high[k] - node->low[k] > node->high[axis] - node->low[axis])
            axis = k;
    for (size_t i = begin; i < end; ++i) {
        const int32_t t = bvh->order[i];
        keyed[i] = (keyed_triangle){corner_position(bvh->surface, t, 0)[axis] + corner_position(bvh->surface, t, 1)[axis] +
                                        corner_position(bvh->surface, t, 2)[axis],
                                    t};
    }
    qsort(keyed + begin, end - begin, sizeof *keyed, compare_keyed);
    for (size_t i = begin; i < end; ++i)
        bvh->order[i] = keyed[i].triangle;
    const size_t middle = begin + (end - begin) / 2;
    const size_t left = bvh->node_count;
    bvh->node_count += 2;
    node->first = (int32_t)left;
    node->count = 0;
    split(bvh, keyed, left, begin, middle, depth + 1);
    split(bvh, keyed, left + 1, middle, end, depth + 1);
}

sk_status sk_bvh_build(sk_bvh *bvh, const sk_bake_surface *surface, sk_error *error)
{
    const size_t count = surface->triangle_count;
    *bvh = (sk_bvh){sk_allocate(count, 2 * sizeof(sk_bvh_node)), sk_allocate(count, sizeof(int32_t)),
                    sk_allocate(count, sizeof(int32_t)), sk_allocate(count, 9 * sizeof(double)), 1, surface};
    keyed_triangle *keyed = sk_allocate(count, sizeof *keyed);
    if (!bvh->nodes || !bvh->order || !bvh->entry_of || !bvh->corners || !keyed || count > INT32_MAX / 2) {
        free(keyed);
        sk_bvh_free(bvh);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the hierarchy of %zu source triangles", count);
    }
    for (size_t t = 0; t < count; ++t)
        bvh->order[t] = (int32_t)t;
    split(bvh, keyed, 0, 0, count, 0);
    free(keyed);
    for (size_t i = 0; i < count; ++i) {
        const double *p0 = corner_position(surface, bvh->order[i], 0), *p1 = corner_position(surface, bvh->order[i], 1),
                     *p2 = corner_position(surface, bvh->order[i], 2);
        double *entry = bvh->corners + 9 * i;
        bvh->entry_of[bvh->order[i]] = (int32_t)i;
        for (int k = 0; k < 3; ++k) {
            entry[k] = p0[k];
            entry[3 + k] = p1[k] - p0[k];
            entry[6 + k] = p2[k] - p0[k];
        }
    }
    return SK_OK;
}

void sk_bvh_free(sk_bvh *bvh)
{
    SK_FREE_ALL(bvh->nodes, bvh->order, bvh->entry_of, bvh->corners);
    bvh->nodes = NULL;
    bvh->order = NULL;
    bvh->entry_of = NULL;
    bvh->corners = NULL;
}

/* The smallest |t| at which the segment's parameter interval [-reach, reach] meets the box (slabs; inverse =
 * 1 / direction, infinite along an axis the direction does not move on), or -1 when it misses. Plain comparisons
 * rather than fmin/fmax, which are library calls without -ffast-math and dominated the traversal. */
static double segment_meets_box(const sk_bvh_node *node, const double *origin, const double *inverse, double reach)
{
    double enter = -reach, leave = reach;
    for (int k = 0; k < 3; ++k) {
        if (isinf(inverse[k])) {
            if (origin[k] < node->low[k] || origin[k] > node->high[k])
                return -1;
            continue;
        }
        double a = (node->low[k] - origin[k]) * inverse[k], b = (node->high[k] - origin[k]) * inverse[k];
        if (a > b) {
            const double swap = a;
            a = b;
            b = swap;
        }
        enter = a > enter ? a : enter;
        leave = b < leave ? b : leave;
        if (enter > leave)
            return -1;
    }
    return enter > 0 ? enter : (leave < 0 ? -leave : 0);
}

/* Moller-Trumbore on both sides of the triangle at entry `entry` of order[] (its corner 0 and edges); 1 with t and
 * the weights of corners 1 and 2 on a hit. */
static int intersect(const sk_bvh *bvh, size_t entry, const double *origin, const double *direction, double *t,
                     double *w1, double *w2)
{
    const double *p0 = bvh->corners + 9 * entry, *e1 = p0 + 3, *e2 = p0 + 6;
    double s[3], p[3], q[3];
    for (int k = 0; k < 3; ++k)
        s[k] = origin[k] - p0[k];
    sk_cross3(p, direction, e2);
    const double determinant = sk_dot3(e1, p);
    if (determinant == 0)
        return 0;
    const double inverse = 1.0 / determinant, tolerance = 1e-9;
    const double u = sk_dot3(s, p) * inverse;
    if (u < -tolerance || u > 1 + tolerance)
        return 0;
    sk_cross3(q, s, e1);
    const double v = sk_dot3(direction, q) * inverse;
    if (v < -tolerance || u + v > 1 + tolerance)
        return 0;
    *t = sk_dot3(e2, q) * inverse;
    *w1 = u;
    *w2 = v;
    return 1;
}

/* Whether a hit at |t| = distance on `candidate` beats the best so far: nearer, or as near and a lower index (so
 * the answer does not depend on the order triangles are tried in). */
static int better(double distance, int32_t candidate, double reach, int found, int32_t best)
{
    return distance < reach || (distance == reach && (!found || candidate < best));
}

int sk_bvh_nearest_hit(const sk_bvh *bvh, const double *origin, const double *direction, double reach, int32_t hint,
                       int32_t *triangle, double *weight1, double *weight2)
{
    int32_t stack[2 * MAX_DEPTH + 2];
    size_t top = 0;
    int found = 0;
    double t, w1, w2;
    if (hint >= 0 && (size_t)hint < bvh->surface->triangle_count &&
        intersect(bvh, (size_t)bvh->entry_of[hint], origin, direction, &t, &w1, &w2) && fabs(t) <= reach) {
        reach = fabs(t);
        *triangle = hint;
        *weight1 = w1;
        *weight2 = w2;
        found = 1;
    }
    const double inverse[3] = {direction[0] != 0 ? 1 / direction[0] : INFINITY,
                               direction[1] != 0 ? 1 / direction[1] : INFINITY,
                               direction[2] != 0 ? 1 / direction[2] : INFINITY};
    stack[top++] = 0;
    while (top > 0) {
        const sk_bvh_node *node = &bvh->nodes[stack[--top]];
        if (segment_meets_box(node, origin, inverse, reach) < 0)
            continue;
        if (node->count == 0) {
            stack[top++] = node->first;
            stack[top++] = node->first + 1;
            continue;
        }
        for (int32_t i = node->first; i < node->first + node->count; ++i) {
            if (intersect(bvh, (size_t)i, origin, direction, &t, &w1, &w2) &&
                better(fabs(t), bvh->order[i], reach, found, *triangle)) {
                reach = fabs(t);
                *triangle = bvh->order[i];
                *weight1 = w1;
                *weight2 = w2;
                found = 1;
            }
        }
    }
    return found;
}

/* Squared distance from the point to the node's box (0 inside). */
static double box_distance2(const sk_bvh_node *node, const double *point)
{
    double sum = 0;
    for (int k = 0; k < 3; ++k) {
        const double below = node->low[k] - point[k], above = point[k] - node->high[k];
        const double gap = below > 0 ? below : (above > 0 ? above : 0);
        sum += gap * gap;
    }
    return sum;
}

/* The point of the triangle closest to `point` as the weights of corners 1 and 2 (Ericson, Real-Time Collision
 * Detection 5.1.5: the Voronoi region of a corner, an edge or the face), and its squared distance. */
static double closest_on_triangle(const sk_bake_surface *surface, int32_t triangle, const double *point, double *w1,
                                  double *w2)
{
    const double *a = corner_position(surface, triangle, 0), *b = corner_position(surface, triangle, 1),
                 *c = corner_position(surface, triangle, 2);
    double ab[3], ac[3], ap[3], bp[3], cp[3];
    for (int k = 0; k < 3; ++k) {
        ab[k] = b[k] - a[k];
        ac[k] = c[k] - a[k];
        ap[k] = point[k] - a[k];
        bp[k] = point[k] - b[k];
        cp[k] = point[k] - c[k];
    }
    const double d1 = sk_dot3(ab, ap), d2 = sk_dot3(ac, ap), d3 = sk_dot3(ab, bp), d4 = sk_dot3(ac, bp);
    const double d5 = sk_dot3(ab, cp), d6 = sk_dot3(ac, cp);
    const double va = d3 * d6 - d5 * d4, vb = d5 * d2 - d1 * d6, vc = d1 * d4 - d3 * d2;
    double v, w;
    if (d1 <= 0 && d2 <= 0) {
        v = 0, w = 0;
    } else if (d3 >= 0 && d4 <= d3) {
        v = 1, w = 0;
    } else if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        v = d1 / (d1 - d3), w = 0;
    } else if (d6 >= 0 && d5 <= d6) {
        v = 0, w = 1;
    } else if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        v = 0, w = d2 / (d2 - d6);
    } else if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6)), v = 1 - w;
    } else {
        const double denominator = va + vb + vc;
        if (!(fabs(denominator) > 0)) { /* a degenerate triangle: its first corner stands for it */
            v = 0, w = 0;
        } else {
            v = vb / denominator, w = vc / denominator;
        }
    }
    double distance2 = 0;
    for (int k = 0; k < 3; ++k) {
        const double gap = a[k] + v * ab[k] + w * ac[k] - point[k];
        distance2 += gap * gap;
    }
    *w1 = v;
    *w2 = w;
    return distance2;
}

int sk_bvh_closest_point(const sk_bvh *bvh, const double *point, double reach, int32_t *triangle, double *weight1,
                         double *weight2)
{
    int32_t stack[2 * MAX_DEPTH + 2];
    size_t top = 0;
    int found = 0;
    double best = reach * reach, w1, w2;
    stack[top++] = 0;
    while (top > 0) {
        const sk_bvh_node *node = &bvh->nodes[stack[--top]];
        if (box_distance2(node, point) > best)
            continue;
        if (node->count == 0) {
            stack[top++] = node->first;
            stack[top++] = node->first + 1;
            continue;
        }
        for (int32_t i = node->first; i < node->first + node->count; ++i) {
            const double distance2 = closest_on_triangle(bvh->surface, bvh->order[i], point, &w1, &w2);
            if (distance2 < best || (distance2 == best && (!found || bvh->order[i] < *triangle))) {
                best = distance2;
                *triangle = bvh->order[i];
                *weight1 = w1;
                *weight2 = w2;
                found = 1;
            }
        }
    }
    return found;
}
