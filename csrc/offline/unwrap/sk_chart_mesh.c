/* A chart (or a piece of one) as a mesh of its own: local vertices, adjacency and the boundary loop. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_flatten.h"

/* ---------------------------------------------------------------------------------------------
 * A chart as a mesh of its own: local vertices, adjacency, the boundary loop
 * ------------------------------------------------------------------------------------------- */

void sk_free_chart_mesh(chart_mesh *m)
{
    SK_FREE_ALL(m->corner, m->vertex, m->gram, m->area, m->across, m->incident_offsets, m->incident, m->ring_offsets,
                m->ring, m->ring_length, m->loop, m->loop_triangle, m->loop_length, m->on_boundary);
    memset(m, 0, sizeof *m);
}

/*
 * Breadth-first over faces across interior edges from the sources: each triangle gets the label of the source it
 * is fewest steps from (ties to the earlier source), and the queue ends with the farthest triangle. Returns the
 * queue's length.
 */
static size_t label_by_nearest_source(int32_t *labels, int32_t *queue, const chart_mesh *m, const int32_t *sources,
                                      int32_t source_count)
{
    for (size_t t = 0; t < m->triangle_count; ++t)
        labels[t] = -1;
    size_t head = 0, tail = 0;
    for (int32_t k = 0; k < source_count; ++k) {
        labels[sources[k]] = k;
        queue[tail++] = sources[k];
    }
    while (head < tail) {
        const size_t t = (size_t)queue[head++];
        for (int k = 0; k < 3; ++k) {
            const int32_t next = m->across[3 * t + (size_t)k];
            if (next >= 0 && labels[next] < 0) {
                labels[next] = labels[t];
                queue[tail++] = next;
            }
        }
    }
    return tail;
}

/* Labels each triangle 0 or 1 by the source it is fewer steps from across interior edges (ties to the first). */
void sk_two_source_labels(int32_t *labels, int32_t *queue, const chart_mesh *m, int32_t first, int32_t second)
{
    const int32_t sources[2] = {first, second};
    label_by_nearest_source(labels, queue, m, sources, 2);
}

/*
 * Splits a connected piece of two or more triangles in two: the triangles nearer to `seed` than to the
 * triangle farthest from it (breadth-first over faces), and the rest.
 */
void sk_split_around(int32_t *labels, int32_t *queue, const chart_mesh *m, int32_t seed)
{
    const size_t tail = label_by_nearest_source(labels, queue, m, &seed, 1);
    sk_two_source_labels(labels, queue, m, seed, queue[tail - 1]);
}

/* The metric length of edge e of the local mesh, from its last triangle's squared lengths (the triangles on
 * either side may disagree a little when the metric is given per triangle). */
static double local_edge_length(const chart_mesh *m, const sk_edge_flaps *local, const flatten_input *in, int32_t e)
{
    const int32_t t = local->edge_triangles[2 * e + (sk_is_border_edge(local, e) ? 0 : 1)];
    const int32_t side = sk_edge_slot(local, e, t) % 3;
    return sqrt(in->edge_lengths_sq[3 * (size_t)m->triangles[t] + (size_t)side]);
}

/*
 * Adjacency over the local vertices: across[], the triangles at each vertex (incident), and each vertex's ring
 * (its neighbours and itself, ascending, with the metric length to each). The local edges are numbered by their
 * vertex pairs, so a vertex's edges list its lower neighbours ascending, then its higher ones.
 */
static int build_adjacency(chart_mesh *m, sk_edge_flaps *local, const flatten_input *in)
{
    const size_t n = m->triangle_count, v = m->vertex_count;
    m->across = sk_allocate(3 * n, sizeof *m->across);
    m->ring_offsets = sk_allocate(v + 1, sizeof *m->ring_offsets);
    m->ring = sk_allocate(2 * local->edge_count + v, sizeof *m->ring);
    m->ring_length = sk_allocate_zeroed(2 * local->edge_count + v, sizeof *m->ring_length);
    if (!m->across || !m->ring_offsets || !m->ring || !m->ring_length)
        return 0;
    for (size_t slot = 0; slot < 3 * n; ++slot)
        m->across[slot] = sk_edge_other_triangle(local, local->triangle_edges[slot], (int32_t)(slot / 3));
    size_t size = 0;
    for (size_t i = 0; i < v; ++i) {
        m->ring_offsets[i] = (int32_t)size;
        int self_placed = 0;
        for (int32_t k = local->vertex_edge_offsets[i]; k < local->vertex_edge_offsets[i + 1]; ++k) {
            const int32_t e = local->vertex_edges[k], j = sk_edge_other_vertex(local, e, (int32_t)i);
            if (!self_placed && j > (int32_t)i) {
                m->ring[size++] = (int32_t)i;
                self_placed = 1;
            }
            m->ring_length[size] = local_edge_length(m, local, in, e);
            m->ring[size++] = j;
        }
        if (!self_placed)
            m->ring[size++] = (int32_t)i;
    }
    m->ring_offsets[v] = (int32_t)size;
    /* the triangles at each vertex, taken over from the flaps */
    m->incident_offsets = local->vertex_triangle_offsets;
    m->incident = local->vertex_triangles;
    local->vertex_triangle_offsets = local->vertex_triangles = NULL;
    return 1;
}

/* The first border loop as the chart's boundary (with its triangles and metric lengths); *loops: how many. */
static int trace_boundary(chart_mesh *m, const sk_edge_flaps *local, const flatten_input *in, long *loops)
{
    size_t border = 0;
    for (size_t e = 0; e < local->edge_count; ++e)
        border += sk_is_border_edge(local, (int32_t)e);
    int32_t *offsets = sk_allocate(border + 1, sizeof *offsets), *edges = sk_allocate(border, sizeof *edges);
    m->loop = sk_allocate(border, sizeof *m->loop);
    m->loop_triangle = sk_allocate(border, sizeof *m->loop_triangle);
    m->loop_length = sk_allocate(border, sizeof *m->loop_length);
    m->on_boundary = sk_allocate_zeroed(m->vertex_count, 1);
    int ok = offsets && edges && m->loop && m->loop_triangle && m->loop_length && m->on_boundary;
    *loops = ok ? sk_boundary_loops(offsets, m->loop, edges, local) : -1;
    ok = *loops >= 0;
    if (ok) {
        m->boundary_count = *loops > 0 ? (size_t)offsets[1] : 0;
        for (size_t i = 0; i < (size_t)offsets[*loops]; ++i)
            m->on_boundary[m->loop[i]] = 1;
        for (size_t i = 0; i < m->boundary_count; ++i) {
            m->loop_triangle[i] = local->edge_triangles[2 * edges[i]];
            m->loop_length[i] = local_edge_length(m, local, in, edges[i]);
        }
    }
    free(offsets);
    free(edges);
    return ok;
}

/*
 * Builds the chart's own mesh from `count` mesh triangles: the corners of each mesh vertex that are joined
 * round a fan become one local vertex (a vertex where the chart touches itself becomes two), and non-manifold
 * and inconsistently oriented edges are refused. DISCONNECTED leaves component labels (one per triangle) in
 * `labels`; NOT_DISC (closed, or more than one boundary loop) leaves the reason in *error and a split of the
 * piece in two in `labels` (*component_count = 2); REFUSED leaves the reason in *error.
 */
build_outcome sk_build_chart_mesh(chart_mesh *m, const flatten_input *in, const int32_t *triangles, size_t count,
                                      size_t chart, int32_t *labels, size_t *component_count, sk_error *error)
{
    memset(m, 0, sizeof *m);
    m->triangles = triangles;
    m->triangle_count = count;
    m->gram = sk_allocate(3 * count, sizeof *m->gram);
    m->area = sk_allocate(count, sizeof *m->area);
    m->corner = sk_allocate(3 * count, sizeof *m->corner);
    int32_t *mesh_corners = sk_allocate(3 * count, sizeof *mesh_corners), *queue = sk_allocate(count, sizeof *queue);
    sk_edge_flaps edges = {0}, local = {0};
    build_outcome outcome = OUT_OF_MEMORY;
    if (!m->gram || !m->area || !m->corner || !mesh_corners || !queue)
        goto done;
    for (size_t t = 0; t < count; ++t) {
        gram_from_lengths(m->gram + 3 * t, in->edge_lengths_sq + 3 * (size_t)triangles[t]);
        m->area[t] = gram_area(m->gram + 3 * t);
        for (int k = 0; k < 3; ++k)
            mesh_corners[3 * t + (size_t)k] = in->triangles[3 * (size_t)triangles[t] + (size_t)k];
    }
    sk_edge_defect defect;
    const sk_status built = sk_edge_flaps_build(&edges, mesh_corners, count, 0, &defect); /* edges alone */
    if (built == SK_ERROR_ARGUMENT) {
        sk_fail(error, SK_ERROR_ARGUMENT, "chart %zu is not a disc: edge (%d, %d) is shared by %zu of its triangles",
                chart, defect.vertices[0], defect.vertices[1], defect.triangle_count);
        outcome = REFUSED;
    }
    if (built != SK_OK)
        goto done;
    for (size_t e = 0; e < edges.edge_count; ++e)
        if (sk_edge_runs_same_way(&edges, (int32_t)e)) {
            sk_fail(error, SK_ERROR_ARGUMENT,
                    "chart %zu: triangles %d and %d have opposite orientations across edge (%d, %d)", chart,
                    m->triangles[edges.edge_triangles[2 * e]], m->triangles[edges.edge_triangles[2 * e + 1]],
                    edges.edge_vertices[2 * e], edges.edge_vertices[2 * e + 1]);
            outcome = REFUSED;
            goto done;
        }
    const long components = sk_triangle_components(labels, &edges, NULL);
    const long fans = components < 0 ? -1 : sk_corner_fans(m->corner, &edges, NULL);
    if (fans < 0)
        goto done;
    *component_count = (size_t)components;
    if (components > 1) {
        outcome = DISCONNECTED;
        goto done;
    }
    m->vertex_count = (size_t)fans;
    m->vertex = sk_allocate(m->vertex_count, sizeof *m->vertex);
    if (!m->vertex)
        goto done;
    for (size_t c = 0; c < 3 * count; ++c)
        m->vertex[m->corner[c]] = mesh_corners[c];
    long loops = 0;
    if (sk_edge_flaps_build(&local, m->corner, count, m->vertex_count, NULL) != SK_OK ||
        !build_adjacency(m, &local, in) || !trace_boundary(m, &local, in, &loops))
        goto done;
    const long euler = (long)m->vertex_count - (long)local.edge_count + (long)count;
    if (loops == 0) {
        sk_fail(error, SK_ERROR_ARGUMENT, "chart %zu is closed (it has no boundary): cut it into discs", chart);
        outcome = NOT_DISC;
    } else if (loops != 1 || euler != 1) {
        sk_fail(error, SK_ERROR_ARGUMENT,
                "chart %zu is not a disc: %ld boundary loops and Euler characteristic %ld (a disc has 1 and 1)",
                chart, loops, euler);
        outcome = NOT_DISC;
    } else {
        outcome = BUILT;
    }
    if (outcome == NOT_DISC) {
        sk_split_around(labels, queue, m, 0);
        *component_count = 2;
    }
done:
    sk_edge_flaps_free(&edges);
    sk_edge_flaps_free(&local);
    free(mesh_corners);
    free(queue);
    if (outcome != BUILT)
        sk_free_chart_mesh(m);
    return outcome;
}
