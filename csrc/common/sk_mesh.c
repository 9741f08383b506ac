/* Triangle-mesh topology: edge flaps, fans, components, loops, chart corners, and sk_validate_surface. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sk_mesh.h"

/* ---------------------------------------------------------------------------------------------
 * Edge flaps
 * ------------------------------------------------------------------------------------------- */

typedef struct half_edge {
    uint64_t key; /* (smaller vertex << 32) | larger vertex */
    int32_t slot; /* 3 * triangle + side */
} half_edge;

static int compare_half_edges(const void *a, const void *b)
{
    const half_edge *x = a, *y = b;
    return x->key != y->key ? SK_ORDER(x->key, y->key) : SK_ORDER(x->slot, y->slot);
}

void sk_edge_flaps_free(sk_edge_flaps *flaps)
{
    SK_FREE_ALL(flaps->triangle_edges, flaps->edge_vertices, flaps->edge_triangles, flaps->edge_corners,
                flaps->vertex_edge_offsets, flaps->vertex_edges, flaps->vertex_triangle_offsets,
                flaps->vertex_triangles);
    memset(flaps, 0, sizeof *flaps);
}

/* Fills a CSR (offsets: count + 1) listing values[k] under owners[k], in k order. 0 when memory ran out. */
static int fill_csr(int32_t *offsets, int32_t *items, const int32_t *owners, size_t pairs, size_t count,
                    int32_t value_divisor)
{
    int32_t *cursor = sk_allocate(count + 1, sizeof *cursor);
    if (!cursor)
        return 0;
    memset(offsets, 0, (count + 1) * sizeof *offsets);
    for (size_t k = 0; k < pairs; ++k)
        ++offsets[owners[k] + 1];
    for (size_t i = 0; i < count; ++i)
        offsets[i + 1] += offsets[i];
    memcpy(cursor, offsets, (count + 1) * sizeof *cursor);
    for (size_t k = 0; k < pairs; ++k)
        items[cursor[owners[k]]++] = (int32_t)k / value_divisor;
    free(cursor);
    return 1;
}

/* Numbers the edges from the sorted half-edges; fails on the edge shared by the most triangles. */
static sk_status group_edges(sk_edge_flaps *flaps, const half_edge *halves, sk_edge_defect *defect)
{
    const size_t half_count = 3 * flaps->triangle_count;
    size_t edge = 0, worst = 2, worst_first = 0;
    for (size_t first = 0, last; first < half_count; first = last) {
        for (last = first + 1; last < half_count && halves[last].key == halves[first].key; ++last) {
        }
        if (last - first > worst) {
            worst = last - first;
            worst_first = first;
        }
        flaps->edge_vertices[2 * edge] = (int32_t)(halves[first].key >> 32);
        flaps->edge_vertices[2 * edge + 1] = (int32_t)(halves[first].key & 0xffffffffu);
        for (int side = 0; side < 2; ++side) {
            const int32_t slot = first + (size_t)side < last && side < 2 ? halves[first + (size_t)side].slot : -1;
            flaps->edge_triangles[2 * edge + (size_t)side] = slot < 0 ? -1 : slot / 3;
            flaps->edge_corners[2 * edge + (size_t)side] = slot < 0 ? -1 : (slot % 3 + 2) % 3;
        }
        for (size_t k = first; k < last; ++k)
            flaps->triangle_edges[halves[k].slot] = (int32_t)edge;
        ++edge;
    }
    flaps->edge_count = edge;
    if (worst == 2)
        return SK_OK;
    if (defect) {
        defect->vertices[0] = (int32_t)(halves[worst_first].key >> 32);
        defect->vertices[1] = (int32_t)(halves[worst_first].key & 0xffffffffu);
        defect->triangle_count = worst;
        for (size_t k = 0; k < worst && k < SK_DEFECT_TRIANGLES; ++k)
            defect->triangles[k] = halves[worst_first + k].slot / 3;
    }
    return SK_ERROR_ARGUMENT;
}

sk_status sk_edge_flaps_build(sk_edge_flaps *flaps, const int32_t *triangles, size_t triangle_count,
                              size_t vertex_count, sk_edge_defect *defect)
{
    memset(flaps, 0, sizeof *flaps);
    flaps->triangles = triangles;
    flaps->triangle_count = triangle_count;
    flaps->vertex_count = vertex_count;
    const size_t slots = 3 * triangle_count; /* the callers keep triangle_count below 2^31 / 3 */
    half_edge *halves = sk_allocate(slots, sizeof *halves);
    flaps->triangle_edges = sk_allocate(slots, sizeof(int32_t));
    /* at most one edge per slot */
    flaps->edge_vertices = sk_allocate(2 * slots, sizeof(int32_t));
    flaps->edge_triangles = sk_allocate(2 * slots, sizeof(int32_t));
    flaps->edge_corners = sk_allocate(2 * slots, sizeof(int32_t));
    sk_status status = SK_ERROR_MEMORY;
    if (halves && flaps->triangle_edges && flaps->edge_vertices && flaps->edge_triangles && flaps->edge_corners) {
        for (size_t slot = 0; slot < slots; ++slot) {
            const uint32_t a = (uint32_t)triangles[slot], b = (uint32_t)triangles[slot - slot % 3 + (slot + 1) % 3];
            halves[slot].key = a < b ? ((uint64_t)a << 32) | b : ((uint64_t)b << 32) | a;
            halves[slot].slot = (int32_t)slot;
        }
        qsort(halves, slots, sizeof *halves, compare_half_edges);
        status = group_edges(flaps, halves, defect);
    }
    free(halves);
    if (status == SK_OK && vertex_count > 0) {
        const size_t E = flaps->edge_count;
        flaps->vertex_edge_offsets = sk_allocate(vertex_count + 1, sizeof(int32_t));
        flaps->vertex_edges = sk_allocate(2 * E, sizeof(int32_t));
        flaps->vertex_triangle_offsets = sk_allocate(vertex_count + 1, sizeof(int32_t));
        flaps->vertex_triangles = sk_allocate(slots, sizeof(int32_t));
        if (!flaps->vertex_edge_offsets || !flaps->vertex_edges || !flaps->vertex_triangle_offsets ||
            !flaps->vertex_triangles ||
            !fill_csr(flaps->vertex_edge_offsets, flaps->vertex_edges, flaps->edge_vertices, 2 * E, vertex_count, 2) ||
            !fill_csr(flaps->vertex_triangle_offsets, flaps->vertex_triangles, triangles, slots, vertex_count, 3))
            status = SK_ERROR_MEMORY;
    }
    if (status != SK_OK)
        sk_edge_flaps_free(flaps);
    return status;
}

int32_t sk_edge_between(const sk_edge_flaps *flaps, int32_t u, int32_t v)
{
    for (int32_t k = flaps->vertex_edge_offsets[u]; k < flaps->vertex_edge_offsets[u + 1]; ++k)
        if (sk_edge_other_vertex(flaps, flaps->vertex_edges[k], u) == v)
            return flaps->vertex_edges[k];
    return -1;
}

int sk_is_border_vertex(const sk_edge_flaps *flaps, int32_t v)
{
    for (int32_t k = flaps->vertex_edge_offsets[v]; k < flaps->vertex_edge_offsets[v + 1]; ++k)
        if (sk_is_border_edge(flaps, flaps->vertex_edges[k]))
            return 1;
    return 0;
}

/* The vertex a triangle's side starts from, going round the triangle. */
static int32_t side_start(const sk_edge_flaps *flaps, int32_t e, int side)
{
    const int32_t t = flaps->edge_triangles[2 * e + side];
    return flaps->triangles[3 * t + (flaps->edge_corners[2 * e + side] + 1) % 3];
}

int sk_edge_runs_same_way(const sk_edge_flaps *flaps, int32_t e)
{
    return !sk_is_border_edge(flaps, e) && side_start(flaps, e, 0) == side_start(flaps, e, 1);
}

/* ---------------------------------------------------------------------------------------------
 * Fans and components (union-find: a class's root is its smallest member)
 * ------------------------------------------------------------------------------------------- */

int32_t sk_find_root(int32_t *parent, int32_t x)
{
    while (parent[x] != x) {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    return x;
}

void sk_join_classes(int32_t *parent, int32_t a, int32_t b)
{
    a = sk_find_root(parent, a);
    b = sk_find_root(parent, b);
    if (a != b)
        parent[a > b ? a : b] = a < b ? a : b;
}

/* Numbers the classes of parent (count items) in order of their smallest member, into number. */
static long number_classes(int32_t *number, int32_t *parent, size_t count)
{
    long classes = 0;
    for (size_t i = 0; i < count; ++i) {
        const int32_t root = sk_find_root(parent, (int32_t)i);
        /* the root is the smallest member, so it is numbered before any other member is reached */
        number[i] = root == (int32_t)i ? (int32_t)classes++ : number[root];
    }
    return classes;
}

long sk_corner_fans(int32_t *fan_of_corner, const sk_edge_flaps *flaps, const unsigned char *cut_edges)
{
    const size_t slots = 3 * flaps->triangle_count;
    int32_t *parent = sk_allocate(slots, sizeof *parent);
    if (!parent)
        return -1;
    for (size_t slot = 0; slot < slots; ++slot)
        parent[slot] = (int32_t)slot;
    for (size_t e = 0; e < flaps->edge_count; ++e) {
        if (sk_is_border_edge(flaps, (int32_t)e) || (cut_edges && cut_edges[e]))
            continue;
        const int32_t t0 = flaps->edge_triangles[2 * e], t1 = flaps->edge_triangles[2 * e + 1];
        for (int end = 0; end < 2; ++end) { /* each end of the edge: its corner in t0 and in t1 */
            const int32_t v = flaps->edge_vertices[2 * e + (size_t)end];
            const int32_t *a = flaps->triangles + 3 * t0, *b = flaps->triangles + 3 * t1;
            sk_join_classes(parent, 3 * t0 + (a[0] == v ? 0 : a[1] == v ? 1 : 2),
                            3 * t1 + (b[0] == v ? 0 : b[1] == v ? 1 : 2));
        }
    }
    const long fans = number_classes(fan_of_corner, parent, slots);
    free(parent);
    return fans;
}

long sk_triangle_components(int32_t *component, const sk_edge_flaps *flaps, const unsigned char *cut_edges)
{
    int32_t *parent = sk_allocate(flaps->triangle_count, sizeof *parent);
    if (!parent)
        return -1;
    for (size_t t = 0; t < flaps->triangle_count; ++t)
        parent[t] = (int32_t)t;
    for (size_t e = 0; e < flaps->edge_count; ++e)
        if (!sk_is_border_edge(flaps, (int32_t)e) && !(cut_edges && cut_edges[e]))
            sk_join_classes(parent, flaps->edge_triangles[2 * e], flaps->edge_triangles[2 * e + 1]);
    const long components = number_classes(component, parent, flaps->triangle_count);
    free(parent);
    return components;
}

/* ---------------------------------------------------------------------------------------------
 * Loops
 * ------------------------------------------------------------------------------------------- */

size_t sk_trace_loop(int32_t *loop_vertices, int32_t *loop_edges, const sk_edge_flaps *flaps, sk_edge_filter on_chain,
                     const void *context, int32_t start_vertex, int32_t first_edge)
{
    size_t n = 0;
    for (int32_t v = start_vertex, e = first_edge; n < flaps->vertex_count && e >= 0;) {
        if (loop_vertices)
            loop_vertices[n] = v;
        if (loop_edges)
            loop_edges[n] = e;
        ++n;
        v = sk_edge_other_vertex(flaps, e, v);
        if (v == start_vertex)
            break;
        const int32_t arrived = e;
        e = -1;
        for (int32_t k = flaps->vertex_edge_offsets[v]; k < flaps->vertex_edge_offsets[v + 1] && e < 0; ++k)
            if (flaps->vertex_edges[k] != arrived && on_chain(context, flaps->vertex_edges[k]))
                e = flaps->vertex_edges[k];
    }
    return n;
}

static int border_filter(const void *context, int32_t edge)
{
    return sk_is_border_edge(context, edge);
}

long sk_boundary_loops(int32_t *loop_offsets, int32_t *loop_vertices, int32_t *loop_edges, const sk_edge_flaps *flaps)
{
    unsigned char *visited = sk_allocate_zeroed(flaps->vertex_count, 1);
    if (!visited)
        return -1;
    long loops = 0;
    size_t used = 0;
    loop_offsets[0] = 0;
    for (size_t v = 0; v < flaps->vertex_count; ++v) {
        if (visited[v])
            continue;
        /* the border edge leaving v in its triangle's direction: its side starts at v */
        int32_t leaving = -1;
        for (int32_t k = flaps->vertex_edge_offsets[v]; k < flaps->vertex_edge_offsets[v + 1] && leaving < 0; ++k) {
            const int32_t e = flaps->vertex_edges[k];
            if (sk_is_border_edge(flaps, e) && side_start(flaps, e, 0) == (int32_t)v)
                leaving = e;
        }
        if (leaving < 0)
            continue;
        const size_t n = sk_trace_loop(loop_vertices + used, loop_edges + used, flaps, border_filter, flaps,
                                       (int32_t)v, leaving);
        for (size_t k = 0; k < n; ++k)
            visited[loop_vertices[used + k]] = 1;
        used += n;
        loop_offsets[++loops] = (int32_t)used;
    }
    free(visited);
    return loops;
}

/* ---------------------------------------------------------------------------------------------
 * Chart corners (Fig 5.6)
 * ------------------------------------------------------------------------------------------- */

/* The loop position in [from, to) whose length along the loop is nearest `target`. */
static size_t nearest_position(const double *along, size_t from, size_t to, double target)
{
    size_t best = from;
    for (size_t k = from; k < to; ++k)
        if (fabs(along[k] - target) < fabs(along[best] - target))
            best = k;
    return best;
}

/* The loop started at position `origin`: rotated[k] = loop[origin + k], lengths measured from it. */
static void rotate_loop(int32_t *rotated, double *rotated_along, const int32_t *loop, const double *along, size_t n,
                        size_t origin)
{
    for (size_t k = 0; k < n; ++k) {
        const size_t from = (origin + k) % n;
        rotated[k] = loop[from];
        rotated_along[k] = from >= origin ? along[from] - along[origin] : along[n] - along[origin] + along[from];
    }
    rotated_along[n] = along[n];
}

void sk_complete_corners(unsigned char *corners, const int32_t *loop, const double *along, size_t n, int32_t *rotated,
                         double *rotated_along)
{
    if (n <= 3) {
        for (size_t k = 0; k < n; ++k)
            corners[loop[k]] = 1;
        return;
    }
    size_t found[2] = {0, 0}, count = 0, lowest = 0;
    for (size_t k = 0; k < n; ++k) {
        if (corners[loop[k]] && count < 2)
            found[count] = k;
        count += corners[loop[k]] != 0;
        if (loop[k] < loop[lowest])
            lowest = k;
    }
    if (count >= 3)
        return;
    if (count == 2) { /* the vertex nearest the middle of the longer arc that has a vertex inside */
        const size_t i = found[0], j = found[1];
        const double inner = along[j] - along[i], outer = along[n] - inner;
        const int inner_has_vertex = j - i >= 2, outer_has_vertex = n - (j - i) >= 2;
        if (inner_has_vertex && (inner >= outer || !outer_has_vertex)) {
            corners[loop[nearest_position(along, i + 1, j, along[i] + inner / 2)]] = 1;
        } else {
            rotate_loop(rotated, rotated_along, loop, along, n, j);
            corners[rotated[nearest_position(rotated_along, 1, n - (j - i), outer / 2)]] = 1;
        }
        return;
    }
    rotate_loop(rotated, rotated_along, loop, along, n, count == 1 ? found[0] : lowest);
    const double total = rotated_along[n];
    const size_t third = nearest_position(rotated_along, 1, n - 1, total / 3);
    corners[rotated[0]] = 1;
    corners[rotated[third]] = 1;
    corners[rotated[nearest_position(rotated_along, third + 1, n, 2 * total / 3)]] = 1;
}

void sk_group_by_chart(int32_t *offsets, int32_t *members, const int32_t *charts, size_t triangle_count)
{
    for (size_t t = 0; t < triangle_count; ++t)
        ++offsets[charts[t] + 2];
    for (size_t c = 0; c <= triangle_count; ++c)
        offsets[c + 1] += offsets[c];
    for (size_t t = 0; t < triangle_count; ++t)
        members[offsets[charts[t] + 1]++] = (int32_t)t;
}

/* ---------------------------------------------------------------------------------------------
 * The public surface check
 * ------------------------------------------------------------------------------------------- */

/* Appends ", t" for each triangle to the message buffer (the message is cut at SK_MESSAGE_SIZE anyway). */
static void list_triangles(char *text, size_t size, const int32_t *triangles, size_t count)
{
    size_t used = 0;
    for (size_t k = 0; k < count && used < size; ++k) {
        const int written = snprintf(text + used, size - used, "%s%d", k ? ", " : "", (int)triangles[k]);
        if (written < 0)
            break;
        used += (size_t)written;
    }
}

/* The first orientation conflict as a directed-edge scan finds it: the conflicting edge whose later slot is
 * smallest (the first slot that repeats a directed edge already seen), or -1. */
static int32_t first_orientation_conflict(const sk_edge_flaps *flaps)
{
    int32_t best = -1, best_slot = INT32_MAX;
    for (size_t e = 0; e < flaps->edge_count; ++e) {
        if (!sk_edge_runs_same_way(flaps, (int32_t)e))
            continue;
        const int32_t later = sk_edge_slot(flaps, (int32_t)e, flaps->edge_triangles[2 * e + 1]);
        if (later < best_slot) {
            best_slot = later;
            best = (int32_t)e;
        }
    }
    return best;
}

sk_status sk_validate_surface(const sk_triangle_mesh *mesh, sk_error *error)
{
    if (!mesh)
        return sk_fail(error, SK_ERROR_ARGUMENT, "mesh must not be null");
    if (mesh->triangle_count > INT32_MAX / 3 || mesh->vertex_count > INT32_MAX)
        return sk_fail(error, SK_ERROR_ARGUMENT, "a surface takes at most %d triangles and 2^31 vertices",
                       INT32_MAX / 3);
    sk_status status = sk_validate_triangles(mesh, error);
    if (status != SK_OK)
        return status;
    sk_edge_flaps flaps;
    sk_edge_defect defect;
    status = sk_edge_flaps_build(&flaps, mesh->triangles, mesh->triangle_count, mesh->vertex_count, &defect);
    if (status == SK_ERROR_ARGUMENT) {
        char faces[SK_MESSAGE_SIZE];
        list_triangles(faces, sizeof faces, defect.triangles,
                       defect.triangle_count < SK_DEFECT_TRIANGLES ? defect.triangle_count : SK_DEFECT_TRIANGLES);
        return sk_fail(error, SK_ERROR_ARGUMENT,
                       "edge (%d, %d) is shared by %zu faces [%s]: the mesh is not manifold there (separate or delete "
                       "the extra faces)",
                       (int)defect.vertices[0], (int)defect.vertices[1], defect.triangle_count, faces);
    }
    if (status != SK_OK)
        return sk_fail(error, status, "no memory for the edges of %zu triangles", mesh->triangle_count);
    const int32_t conflict = first_orientation_conflict(&flaps);
    int32_t *fans = conflict < 0 ? sk_allocate(3 * mesh->triangle_count, sizeof *fans) : NULL;
    int32_t pinched = -1;
    if (conflict >= 0) {
        const int32_t t0 = flaps.edge_triangles[2 * conflict], t1 = flaps.edge_triangles[2 * conflict + 1];
        const int32_t from = side_start(&flaps, conflict, 0);
        status = sk_fail(error, SK_ERROR_ARGUMENT,
                         "faces [%d, %d] run the same way along edge (%d, %d): their orientations disagree "
                         "(recalculate the normals so they point the same way)",
                         (int)t0, (int)t1, (int)from, (int)sk_edge_other_vertex(&flaps, conflict, from));
    } else if (!fans || sk_corner_fans(fans, &flaps, NULL) < 0) {
        status = sk_fail(error, SK_ERROR_MEMORY, "no memory for the fans of %zu triangles", mesh->triangle_count);
    } else {
        /* a vertex whose corners fall in two fans: fans are numbered in corner order, so a corner whose fan is
         * not the first fan seen at its vertex names a pinched vertex */
        int32_t *first_fan = sk_allocate(mesh->vertex_count, sizeof *first_fan);
        if (!first_fan) {
            status = sk_fail(error, SK_ERROR_MEMORY, "no memory for %zu vertices", mesh->vertex_count);
        } else {
            for (size_t v = 0; v < mesh->vertex_count; ++v)
                first_fan[v] = -1;
            for (size_t slot = 0; slot < 3 * mesh->triangle_count; ++slot) {
                const int32_t v = mesh->triangles[slot];
                if (first_fan[v] < 0)
                    first_fan[v] = fans[slot];
                else if (first_fan[v] != fans[slot] && (pinched < 0 || v < pinched))
                    pinched = v;
            }
            free(first_fan);
        }
    }
    free(fans);
    sk_edge_flaps_free(&flaps);
    if (status == SK_OK && pinched >= 0)
        status = sk_fail(error, SK_ERROR_ARGUMENT,
                         "vertex %d joins separate fans of faces (a bowtie): the mesh is not manifold there (split the "
                         "vertex)",
                         (int)pinched);
    return status == SK_OK ? sk_succeed(error) : status;
}
