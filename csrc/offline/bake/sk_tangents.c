/*
 * MikkTSpace tangents (Mikkelsen 2008, the convention of Blender, Unreal, Unity and glTF), computed from the
 * description of the reference implementation. SPDX-License-Identifier: GPL-3.0-or-later
 *
 * 1. Corners are welded by value: two corners are one vertex when position, normal and uv have the same bits. A
 *    triangle with two corners at one position is degenerate and set aside.
 * 2. Each other triangle gets its uv-gradient direction dP/du (the sign of its uv area says whether the map
 *    preserves orientation), normalised. One with no uv area, or no extent along u or v in 3D, "groups with any":
 *    it contributes nothing and takes the orientation of the first group that reaches it.
 * 3. Neighbours are the triangles across each edge (in welded indices) running the other way, paired in edge order.
 * 4. Groups grow in triangle order: each unassigned corner of a triangle that does not group with any starts one
 *    at its welded vertex, which spreads depth
 *    first (across the corner's two edges, the next edge first) to the neighbours' corners of that vertex whose
 *    triangles have the group's orientation.
 * 5. A group's tangent is the normalised sum, over its triangles that group with no one, of the triangle's dP/du
 *    projected onto the vertex normal's plane and normalised, weighted by the corner's angle measured in that
 *    plane; its sign is +1 when the group preserves orientation. A corner no group reached keeps the default
 *    tangent (1, 0, 0) with sign -1, as do degenerate triangles' corners whose welded vertex no kept triangle
 *    has; the others take the tangent of the first corner of a kept triangle at the same welded vertex.
 * With the reference's 180-degree angular threshold no group splits further.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_bake_internal.h"
#include "sk_internal.h"
#include "sk_math.h"
#include "sk_mesh.h"

typedef struct directed_edge {
    int32_t low, high; /* welded vertices, low < high */
    int32_t corner;    /* the corner the edge leaves from (3 t + k, edge k -> k + 1) */
    int32_t forward;   /* 1 when the triangle runs low -> high */
} directed_edge;

/* A corner's (position, normal, uv) as 8 doubles. */
static void corner_values(double values[8], const sk_bake_surface *surface, size_t corner)
{
    memcpy(values, surface->positions + 3 * (size_t)surface->triangles[corner], 3 * sizeof(double));
    memcpy(values + 3, surface->normals + 3 * corner, 3 * sizeof(double));
    memcpy(values + 6, surface->uv + 2 * corner, 2 * sizeof(double));
}

/* A hash of the values' bits. Bits, not values: Blender's MikkTSpace hashes the floats' bits and so keeps a -0
 * corner apart from a +0 one (tests/blender/test_normal_maps.py holds the tangents to Blender's). */
static uint64_t values_hash(const double values[8])
{
    uint64_t hash = 0;
    for (int k = 0; k < 8; ++k) {
        uint64_t bits;
        memcpy(&bits, values + k, sizeof bits);
        hash = (hash ^ bits) * 0x9E3779B97F4A7C15ULL;
        hash ^= hash >> 29;
    }
    return hash;
}

/* Welded vertex of every corner: corners with the same bits of position, normal and uv are one vertex, numbered
 * in the order of their first corner (only which corners share a vertex matters downstream). An open-addressing
 * table of each vertex's first corner (table_size a power of two above the corner count, -1 free) replaces the
 * comparison sort of all the keys, half the tangents' cost on a 4k-triangle level. Returns the vertex count. */
static size_t weld_corners(int32_t *welded, int32_t *table, size_t table_size, const sk_bake_surface *surface,
                           size_t corner_count)
{
    for (size_t slot = 0; slot < table_size; ++slot)
        table[slot] = -1;
    size_t vertex_count = 0;
    for (size_t c = 0; c < corner_count; ++c) {
        double values[8], other[8];
        corner_values(values, surface, c);
        size_t slot = (size_t)values_hash(values) & (table_size - 1);
        for (;; slot = (slot + 1) & (table_size - 1)) {
            const int32_t first = table[slot];
            if (first < 0) {
                table[slot] = (int32_t)c;
                welded[c] = (int32_t)vertex_count++;
                break;
            }
            corner_values(other, surface, (size_t)first);
            if (memcmp(values, other, sizeof values) == 0) {
                welded[c] = welded[first];
                break;
            }
        }
    }
    return vertex_count;
}

/* Stable counting sort of the edges by one of their vertices (key_of_high: by high, else by low) into sorted;
 * counts has vertex_count + 1 entries. */
static void sort_edges_by_vertex(directed_edge *sorted, const directed_edge *edges, size_t edge_count,
                                 size_t *counts, size_t vertex_count, int key_of_high)
{
    memset(counts, 0, (vertex_count + 1) * sizeof *counts);
    for (size_t i = 0; i < edge_count; ++i)
        ++counts[(size_t)(key_of_high ? edges[i].high : edges[i].low) + 1];
    for (size_t v = 0; v < vertex_count; ++v)
        counts[v + 1] += counts[v];
    for (size_t i = 0; i < edge_count; ++i)
        sorted[counts[(size_t)(key_of_high ? edges[i].high : edges[i].low)]++] = edges[i];
}

/* |x| > FLT_MIN: the reference's test for a non-zero value. */
static int not_zero(double x) { return fabs(x) > 1.17549435e-38; }

/* Per triangle: the normalised uv-gradient direction (orientation-signed), whether it preserves orientation and
 * whether it groups with any (no uv area, or no 3D extent along u or v). */
static void triangle_directions(double *directions, unsigned char *preserving, unsigned char *with_any,
                                const sk_bake_surface *surface)
{
    for (size_t t = 0; t < surface->triangle_count; ++t) {
        const double *p0 = surface->positions + 3 * (size_t)surface->triangles[3 * t];
        const double *p1 = surface->positions + 3 * (size_t)surface->triangles[3 * t + 1];
        const double *p2 = surface->positions + 3 * (size_t)surface->triangles[3 * t + 2];
        const double *uv = surface->uv + 6 * t;
        const double t21x = uv[2] - uv[0], t21y = uv[3] - uv[1], t31x = uv[4] - uv[0], t31y = uv[5] - uv[1];
        const double signed_area = t21x * t31y - t21y * t31x;
        double direction[3], along_v[3];
        for (int k = 0; k < 3; ++k) {
            direction[k] = t31y * (p1[k] - p0[k]) - t21y * (p2[k] - p0[k]);
            along_v[k] = -t31x * (p1[k] - p0[k]) + t21x * (p2[k] - p0[k]);
        }
        preserving[t] = signed_area > 0;
        const double length2 = sk_dot3(direction, direction);
        with_any[t] = !(not_zero(signed_area) && not_zero(length2) && not_zero(sk_dot3(along_v, along_v)));
        const double scale = not_zero(signed_area) && not_zero(length2) ? (signed_area > 0 ? 1.0 : -1.0) / sqrt(length2)
                                                                       : 0.0;
        for (int k = 0; k < 3; ++k)
            directions[3 * t + k] = direction[k] * scale;
    }
}

static int same_point(const double *a, const double *b) { return a[0] == b[0] && a[1] == b[1] && a[2] == b[2]; }

static int32_t next_corner(int32_t c) { return c - c % 3 + (c % 3 + 1) % 3; }
static int32_t previous_corner(int32_t c) { return c - c % 3 + (c % 3 + 2) % 3; }

/* neighbours[c]: the kept triangle across edge c -> next(c) running the other way (-1 none), paired as the
 * reference does: edges in (low, high, corner) order, each unpaired one with the next unpaired opposite one. */
static sk_status find_neighbours(int32_t *neighbours, const int32_t *welded, size_t vertex_count,
                                 const unsigned char *degenerate, size_t corner_count, sk_error *error)
{
    directed_edge *edges = sk_allocate(corner_count, sizeof *edges), *by_high = sk_allocate(corner_count, sizeof *edges);
    size_t *counts = sk_allocate(vertex_count + 1, sizeof *counts);
    if (!edges || !by_high || !counts) {
        SK_FREE_ALL(edges, by_high, counts);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu tangent edges", corner_count);
    }
    size_t edge_count = 0;
    for (size_t c = 0; c < corner_count; ++c) {
        neighbours[c] = -1;
        if (degenerate[c / 3])
            continue;
        const int32_t a = welded[c], b = welded[next_corner((int32_t)c)];
        edges[edge_count++] = (directed_edge){a < b ? a : b, a < b ? b : a, (int32_t)c, a < b};
    }
    /* In (low, high, corner) order: made in corner order, then counting-sorted by high and (stably) by low. */
    sort_edges_by_vertex(by_high, edges, edge_count, counts, vertex_count, 1);
    sort_edges_by_vertex(edges, by_high, edge_count, counts, vertex_count, 0);
    for (size_t i = 0; i < edge_count; ++i) {
        if (neighbours[edges[i].corner] >= 0)
            continue;
        for (size_t j = i + 1; j < edge_count && edges[j].low == edges[i].low && edges[j].high == edges[i].high; ++j)
            if (edges[j].forward != edges[i].forward && neighbours[edges[j].corner] < 0) {
                neighbours[edges[i].corner] = edges[j].corner / 3;
                neighbours[edges[j].corner] = edges[i].corner / 3;
                break;
            }
    }
    SK_FREE_ALL(edges, by_high, counts);
    return SK_OK;
}

typedef struct group_state {
    int32_t *group_of;        /* per corner, -1 unassigned */
    int32_t *stack;           /* triangles still to visit, 2 corner_count + 2 */
    unsigned char *preserving; /* per triangle; a with-any triangle's may be adopted */
    const unsigned char *with_any;
    const int32_t *welded, *neighbours;
} group_state;

/* The reference's AssignRecur, depth first with an explicit stack: triangle t joins group g (welded vertex
 * vertex, orientation orient) at its corner of that vertex unless that corner has a group already or t runs the
 * other way; a with-any triangle none of whose corners has a group takes the group's orientation first. */
static void spread_group(group_state *state, int32_t g, int32_t vertex, unsigned char orient, size_t top)
{
    while (top > 0) {
        const int32_t t = state->stack[--top];
        int32_t corner = -1;
        for (int32_t k = 0; k < 3 && corner < 0; ++k)
            if (state->welded[3 * t + k] == vertex)
                corner = 3 * t + k;
        if (corner < 0 || state->group_of[corner] >= 0)
            continue;
        if (state->with_any[t] && state->group_of[3 * t] < 0 && state->group_of[3 * t + 1] < 0 &&
            state->group_of[3 * t + 2] < 0)
            state->preserving[t] = orient;
        if (state->preserving[t] != orient)
            continue;
        state->group_of[corner] = g;
        const int32_t right = state->neighbours[previous_corner(corner)], left = state->neighbours[corner];
        if (right >= 0)
            state->stack[top++] = right;
        if (left >= 0)
            state->stack[top++] = left; /* popped first: the reference recurses left, then right */
    }
}

/* Groups the corners of the kept triangles (the reference's Build4RuleGroups): only a triangle that does not
 * group with any starts a group, so a with-any triangle no group reaches keeps unassigned corners. orients[g] gets
 * each group's orientation. Returns the group count. */
static int32_t build_groups(group_state *state, unsigned char *orients, const unsigned char *degenerate,
                            size_t triangle_count)
{
    int32_t groups = 0;
    for (size_t t = 0; t < triangle_count; ++t) {
        if (degenerate[t] || state->with_any[t])
            continue;
        for (int32_t k = 0; k < 3; ++k) {
            const int32_t corner = 3 * (int32_t)t + k;
            if (state->group_of[corner] >= 0)
                continue;
            const int32_t g = groups++;
            orients[g] = state->preserving[t];
            state->group_of[corner] = g;
            size_t top = 0;
            const int32_t right = state->neighbours[previous_corner(corner)], left = state->neighbours[corner];
            if (right >= 0)
                state->stack[top++] = right;
            if (left >= 0)
                state->stack[top++] = left;
            spread_group(state, g, state->welded[corner], orients[g], top);
        }
    }
    return groups;
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

#define UV_BLOCK 12 /* two triangles' uv */

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
        /* Blocks wholly in 0-1 (so finite) are passed with one branch a block (& rather than &&: no branch a value);
         * from the first other block on, each value is tested to name what is wrong with it. */
        size_t i = 0;
        for (; i + UV_BLOCK <= 6 * surface->triangle_count; i += UV_BLOCK) {
            int outside = 0;
            for (int k = 0; k < UV_BLOCK; ++k)
                outside |= !((surface->uv[i + (size_t)k] >= 0) & (surface->uv[i + (size_t)k] <= 1));
            if (outside)
                break;
        }
        for (; i < 6 * surface->triangle_count; ++i) {
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
    size_t corner_count, stack_size;
    if ((status = sk_array_size(&corner_count, surface->triangle_count, 3, 1, "corner count", error)) != SK_OK)
        return status;
    if (corner_count > INT32_MAX / 2 - 1)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%zu corners exceed the int32 range", corner_count);
    stack_size = 2 * corner_count + 2;
    const size_t triangle_count = surface->triangle_count;
    size_t table_size = 1; /* the weld's table: a power of two, at least twice the corners (short probes) */
    while (table_size < 2 * corner_count)
        table_size *= 2;
    int32_t *table = sk_allocate(table_size, sizeof *table);
    int32_t *welded = sk_allocate(corner_count, sizeof *welded);
    int32_t *neighbours = sk_allocate(corner_count, sizeof(int32_t));
    int32_t *group_of = sk_allocate(corner_count, sizeof(int32_t)), *stack = sk_allocate(stack_size, sizeof(int32_t));
    int32_t *first_kept = sk_allocate(corner_count, sizeof(int32_t));
    double *directions = sk_allocate(triangle_count, 3 * sizeof *directions);
    double *sums = sk_allocate_zeroed(corner_count, 3 * sizeof *sums);
    unsigned char *flags = sk_allocate(triangle_count, 3), *orients = sk_allocate(corner_count, 1);
    if (!table || !welded || !neighbours || !group_of || !stack || !first_kept || !directions || !sums || !flags ||
        !orients) {
        SK_FREE_ALL(table, welded, neighbours, group_of, stack, first_kept, directions, sums, flags, orients);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the tangents of %zu corners", corner_count);
    }
    unsigned char *preserving = flags, *with_any = flags + triangle_count, *degenerate = flags + 2 * triangle_count;
    const size_t vertex_count = weld_corners(welded, table, table_size, surface, corner_count);
    for (size_t t = 0; t < triangle_count; ++t) {
        const double *p0 = surface->positions + 3 * (size_t)surface->triangles[3 * t];
        const double *p1 = surface->positions + 3 * (size_t)surface->triangles[3 * t + 1];
        const double *p2 = surface->positions + 3 * (size_t)surface->triangles[3 * t + 2];
        degenerate[t] = same_point(p0, p1) || same_point(p0, p2) || same_point(p1, p2);
    }
    triangle_directions(directions, preserving, with_any, surface);
    status = find_neighbours(neighbours, welded, vertex_count, degenerate, corner_count, error);
    if (status == SK_OK) {
        for (size_t c = 0; c < corner_count; ++c)
            group_of[c] = -1, first_kept[c] = -1;
        group_state state = {group_of, stack, preserving, with_any, welded, neighbours};
        build_groups(&state, orients, degenerate, triangle_count);
        for (size_t c = 0; c < corner_count; ++c) {
            if (degenerate[c / 3])
                continue;
            if (first_kept[welded[c]] < 0)
                first_kept[welded[c]] = (int32_t)c;
            if (with_any[c / 3] || group_of[c] < 0)
                continue;
            double projected[3];
            project_normalised(projected, directions + 3 * (c / 3), surface->normals + 3 * c);
            const double angle = corner_angle(surface, c);
            double *sum = sums + 3 * (size_t)group_of[c];
            for (int k = 0; k < 3; ++k)
                sum[k] += angle * projected[k];
        }
        for (size_t c = 0; c < corner_count; ++c) {
            const int32_t source = degenerate[c / 3] ? first_kept[welded[c]] : (int32_t)c;
            const int32_t group = source >= 0 ? group_of[source] : -1;
            const double *sum = group >= 0 ? sums + 3 * (size_t)group : NULL;
            const double length = sum ? sqrt(sk_dot3(sum, sum)) : 0;
            for (int k = 0; k < 3; ++k)
                tangents[4 * c + k] = length > 0 ? sum[k] / length : (k == 0 ? 1.0 : 0.0);
            tangents[4 * c + 3] = length > 0 && orients[group] ? 1.0 : -1.0;
        }
        status = sk_succeed(error);
    }
    SK_FREE_ALL(table, welded, neighbours, group_of, stack, first_kept, directions, sums, flags, orients);
    return status;
}
