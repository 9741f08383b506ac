/*
 * MikkTSpace tangents (Mikkelsen 2008, the convention of Blender, Unreal, Unity and glTF), computed from the
 * description of the reference implementation. SPDX-License-Identifier: GPL-3.0-or-later
 *
 * 1. Corners are welded by value: two corners are one vertex when position, normal and uv are all equal.
 * 2. Each triangle gets its uv-gradient direction dP/du (the sign of its uv area says whether the map preserves
 *    orientation), normalised.
 * 3. A corner's group is the set of corners of its welded vertex reachable through triangles that share an
 *    edge (in welded indices) and have the same orientation; seams and mirrored islands therefore split groups.
 * 4. A group's tangent is the normalised sum, over its corners, of the triangle's dP/du projected onto the
 *    corner's normal plane and normalised, weighted by the corner's angle measured in that plane; its sign is
 *    +1 when the triangles preserve orientation, else -1.
 * With the reference's 180-degree angular threshold no group splits further, so this is the whole rule for
 * triangles with non-zero uv area (degenerate uv triangles get their own, unaveraged, direction).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_bake_internal.h"
#include "sk_internal.h"
#include "sk_math.h"
#include "sk_mesh.h"

typedef struct corner_key {
    double values[8]; /* position, normal, uv */
    int32_t corner;
} corner_key;

static int compare_keys(const void *a, const void *b)
{
    const corner_key *x = a, *y = b;
    for (int k = 0; k < 8; ++k) {
        const int order = SK_ORDER(x->values[k], y->values[k]);
        if (order)
            return order;
    }
    return SK_ORDER(x->corner, y->corner);
}

typedef struct directed_edge {
    int32_t low, high; /* welded vertices, low < high */
    int32_t corner;    /* the corner the edge leaves from (3 t + k, edge k -> k + 1) */
    int32_t forward;   /* 1 when the triangle runs low -> high */
} directed_edge;

static int compare_edges(const void *a, const void *b)
{
    const directed_edge *x = a, *y = b;
    int order = SK_ORDER(x->low, y->low);
    if (!order)
        order = SK_ORDER(x->high, y->high);
    if (!order)
        order = SK_ORDER(x->corner, y->corner);
    return order;
}

/* Welded vertex of every corner: the rank of its (position, normal, uv) among the distinct values. */
static void weld_corners(int32_t *welded, corner_key *keys, const sk_bake_surface *surface, size_t corner_count)
{
    for (size_t c = 0; c < corner_count; ++c) {
        const double *position = surface->positions + 3 * (size_t)surface->triangles[c];
        memcpy(keys[c].values, position, 3 * sizeof(double));
        memcpy(keys[c].values + 3, surface->normals + 3 * c, 3 * sizeof(double));
        memcpy(keys[c].values + 6, surface->uv + 2 * c, 2 * sizeof(double));
        keys[c].corner = (int32_t)c;
    }
    qsort(keys, corner_count, sizeof *keys, compare_keys);
    int32_t vertex = -1;
    for (size_t c = 0; c < corner_count; ++c) {
        if (c == 0 || memcmp(keys[c].values, keys[c - 1].values, sizeof keys[c].values) != 0)
            ++vertex;
        welded[keys[c].corner] = vertex;
    }
}

/* Per triangle: the normalised uv-gradient direction (orientation-signed) and whether it preserves orientation. */
static void triangle_directions(double *directions, unsigned char *preserving, const sk_bake_surface *surface)
{
    for (size_t t = 0; t < surface->triangle_count; ++t) {
        const double *p0 = surface->positions + 3 * (size_t)surface->triangles[3 * t];
        const double *p1 = surface->positions + 3 * (size_t)surface->triangles[3 * t + 1];
        const double *p2 = surface->positions + 3 * (size_t)surface->triangles[3 * t + 2];
        const double *uv = surface->uv + 6 * t;
        const double t21x = uv[2] - uv[0], t21y = uv[3] - uv[1], t31x = uv[4] - uv[0], t31y = uv[5] - uv[1];
        const double signed_area = t21x * t31y - t21y * t31x;
        double direction[3];
        for (int k = 0; k < 3; ++k)
            direction[k] = t31y * (p1[k] - p0[k]) - t21y * (p2[k] - p0[k]);
        preserving[t] = signed_area > 0;
        const double length = sqrt(sk_dot3(direction, direction));
        const double scale = signed_area != 0 && length > 0 ? (signed_area > 0 ? 1.0 : -1.0) / length : 1.0;
        for (int k = 0; k < 3; ++k)
            directions[3 * t + k] = direction[k] * scale;
    }
}

/* Joins each corner with the corners of the same welded vertex in the same-orientation triangles across its
 * two edges. */
static sk_status join_groups(int32_t *parent, const int32_t *welded, const unsigned char *preserving,
                             size_t corner_count, sk_error *error)
{
    directed_edge *edges = sk_allocate(corner_count, sizeof *edges);
    if (!edges)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu tangent edges", corner_count);
    for (size_t c = 0; c < corner_count; ++c) {
        const size_t next = c - c % 3 + (c % 3 + 1) % 3;
        const int32_t a = welded[c], b = welded[next];
        edges[c] = (directed_edge){a < b ? a : b, a < b ? b : a, (int32_t)c, a < b};
        parent[c] = (int32_t)c;
    }
    qsort(edges, corner_count, sizeof *edges, compare_edges);
    for (size_t begin = 0, end; begin < corner_count; begin = end) {
        for (end = begin + 1; end < corner_count && edges[end].low == edges[begin].low &&
                              edges[end].high == edges[begin].high; ++end) {
        }
        /* The first opposite-running pair on this edge is the neighbourhood (the reference's first match). */
        for (size_t i = begin; i < end; ++i) {
            size_t j = i + 1;
            while (j < end && edges[j].forward == edges[i].forward)
                ++j;
            if (j == end)
                continue;
            const int32_t ci = edges[i].corner, cj = edges[j].corner;
            if (ci / 3 == cj / 3 || preserving[ci / 3] != preserving[cj / 3])
                break;
            const int32_t ci_next = ci - ci % 3 + (ci % 3 + 1) % 3, cj_next = cj - cj % 3 + (cj % 3 + 1) % 3;
            /* Edge ci -> ci_next runs the other way in the neighbour: cj -> cj_next with cj at ci_next. */
            sk_join_classes(parent, ci, cj_next);
            sk_join_classes(parent, ci_next, cj);
            break;
        }
    }
    free(edges);
    return SK_OK;
}

static void project_normalised(double *out, const double *vector, const double *normal)
{
    const double along = sk_dot3(normal, vector);
    for (int k = 0; k < 3; ++k)
        out[k] = vector[k] - along * normal[k];
    const double length = sqrt(sk_dot3(out, out));
    if (length > 0)
        for (int k = 0; k < 3; ++k)
            out[k] /= length;
}

/* The corner's angle in its normal's plane. */
static double corner_angle(const sk_bake_surface *surface, size_t corner)
{
    const size_t base = corner - corner % 3;
    const double *normal = surface->normals + 3 * corner;
    const double *here = surface->positions + 3 * (size_t)surface->triangles[corner];
    const double *next = surface->positions + 3 * (size_t)surface->triangles[base + (corner % 3 + 1) % 3];
    const double *previous = surface->positions + 3 * (size_t)surface->triangles[base + (corner % 3 + 2) % 3];
    double to_previous[3], to_next[3], a[3], b[3];
    for (int k = 0; k < 3; ++k) {
        to_previous[k] = previous[k] - here[k];
        to_next[k] = next[k] - here[k];
    }
    project_normalised(a, to_previous, normal);
    project_normalised(b, to_next, normal);
    double cosine = sk_dot3(a, b);
    cosine = cosine > 1 ? 1 : (cosine < -1 ? -1 : cosine);
    return acos(cosine);
}

sk_status sk_check_bake_surface(const sk_bake_surface *surface, int needs_uv, const char *name, sk_error *error)
{
    if (!surface || !surface->triangles || !surface->positions || !surface->normals)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%s: triangles, positions and normals are required", name);
    if (surface->triangle_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%s has no triangles", name);
    if (needs_uv && !surface->uv)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%s has no uv coordinates (unwrap it first)", name);
    const sk_status status = sk_validate_triangles(
        &(sk_triangle_mesh){surface->triangles, surface->triangle_count, surface->vertex_count}, error);
    if (status != SK_OK)
        return status;
    size_t bad = sk_first_non_finite(surface->positions, 3 * surface->vertex_count);
    if (bad < 3 * surface->vertex_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "%s: position of vertex %zu is not finite", name, bad / 3);
    bad = sk_first_non_finite(surface->normals, 9 * surface->triangle_count);
    if (bad < 9 * surface->triangle_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "%s: normal of corner %zu is not finite", name, bad / 3);
    if (needs_uv) {
        for (size_t i = 0; i < 6 * surface->triangle_count; ++i) {
            const double value = surface->uv[i];
            if (!isfinite(value))
                return sk_fail(error, SK_ERROR_NOT_FINITE, "%s: uv of corner %zu is not finite", name, i / 2);
            if (value < 0 || value > 1)
                return sk_fail(error, SK_ERROR_ARGUMENT,
                               "%s: uv of corner %zu (triangle %zu) is %g, outside 0-1 (pack the atlas into the unit "
                               "square)", name, i / 2, i / 6, value);
        }
    }
    return SK_OK;
}

sk_status sk_mikktspace_tangents(double *tangents, const sk_bake_surface *surface, sk_error *error)
{
    if (!tangents)
        return sk_fail(error, SK_ERROR_ARGUMENT, "tangents is NULL");
    sk_status status = sk_check_bake_surface(surface, 1, "mesh", error);
    if (status != SK_OK)
        return status;
    size_t corner_count;
    if ((status = sk_array_size(&corner_count, surface->triangle_count, 3, 1, "corner count", error)) != SK_OK)
        return status;
    if (corner_count > INT32_MAX)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%zu corners exceed the int32 range", corner_count);
    corner_key *keys = sk_allocate(corner_count, sizeof *keys);
    int32_t *welded = sk_allocate(corner_count, sizeof *welded);
    int32_t *parent = sk_allocate(corner_count, sizeof *parent);
    double *directions = sk_allocate(surface->triangle_count, 3 * sizeof *directions);
    double *sums = sk_allocate_zeroed(corner_count, 3 * sizeof *sums);
    unsigned char *preserving = sk_allocate(surface->triangle_count, 1);
    if (!keys || !welded || !parent || !directions || !sums || !preserving) {
        SK_FREE_ALL(keys, welded, parent, directions, sums, preserving);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the tangents of %zu corners", corner_count);
    }
    weld_corners(welded, keys, surface, corner_count);
    triangle_directions(directions, preserving, surface);
    status = join_groups(parent, welded, preserving, corner_count, error);
    if (status == SK_OK) {
        for (size_t c = 0; c < corner_count; ++c) {
            double projected[3];
            project_normalised(projected, directions + 3 * (c / 3), surface->normals + 3 * c);
            const double angle = corner_angle(surface, c);
            double *sum = sums + 3 * (size_t)sk_find_root(parent, (int32_t)c);
            for (int k = 0; k < 3; ++k)
                sum[k] += angle * projected[k];
        }
        for (size_t c = 0; c < corner_count; ++c) {
            const double *sum = sums + 3 * (size_t)sk_find_root(parent, (int32_t)c);
            const double length = sqrt(sk_dot3(sum, sum));
            for (int k = 0; k < 3; ++k)
                tangents[4 * c + k] = length > 0 ? sum[k] / length : 0.0;
            tangents[4 * c + 3] = preserving[c / 3] ? 1.0 : -1.0;
        }
        status = sk_succeed(error);
    }
    SK_FREE_ALL(keys, welded, parent, directions, sums, preserving);
    return status;
}
