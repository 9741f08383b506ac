/* Chart corners (Merry 2007, Fig 5.6): where charts meet, completed to three per chart by the shared rule. */
#include <stdlib.h>

#include "sk_charts.h"

/* ---------------------------------------------------------------------------------------------
 * Corners
 * ------------------------------------------------------------------------------------------- */

typedef struct chart_side {
    const topology *mesh;
    const int32_t *charts;
    int32_t chart;
} chart_side;

static int on_side_boundary(const void *context, int32_t e)
{
    const chart_side *side = context;
    return on_chart_boundary(side->mesh, side->charts, e, side->chart);
}

/*
 * The boundary loop of disc chart c: its n vertices in order, along[k] = the length from loop[0] to loop[k]
 * and along[n] = the whole loop's (edge counts when the lengths are missing or all zero). edges: scratch for
 * the loop's edges.
 */
static size_t boundary_loop(const topology *mesh, const int32_t *charts, int32_t c, const int32_t *list, size_t count,
                            int32_t *loop, int32_t *edges, double *along)
{
    int32_t first = -1;
    for (size_t i = 0; i < count && first < 0; ++i)
        for (int k = 0; k < 3 && first < 0; ++k)
            if (on_chart_boundary(mesh, charts, mesh->flaps.triangle_edges[3 * list[i] + k], c))
                first = mesh->flaps.triangle_edges[3 * list[i] + k];
    const chart_side side = {mesh, charts, c};
    const size_t n = sk_trace_loop(loop, edges, &mesh->flaps, on_side_boundary, &side,
                                   mesh->flaps.edge_vertices[2 * first], first);
    along[0] = 0.0;
    for (size_t k = 0; k < n; ++k)
        along[k + 1] = along[k] + (mesh->edge_lengths ? mesh->edge_lengths[edges[k]] : 1.0);
    if (!(along[n] > 0.0))
        for (size_t k = 0; k <= n; ++k)
            along[k] = (double)k;
    return n;
}

/* Where three charts meet, or two on the mesh border. */
static int natural_corner(const topology *mesh, const int32_t *charts, int32_t v)
{
    int32_t seen[2] = {-1, -1};
    int distinct = 0;
    for (int32_t k = mesh->flaps.vertex_triangle_offsets[v]; k < mesh->flaps.vertex_triangle_offsets[v + 1]; ++k) {
        const int32_t c = charts[mesh->flaps.vertex_triangles[k]];
        if (c == seen[0] || c == seen[1])
            continue;
        if (++distinct == 3)
            return 1;
        seen[distinct - 1] = c;
    }
    return distinct == 2 && sk_is_border_vertex(&mesh->flaps, v);
}

sk_status sk_compute_corners(unsigned char *corners, const topology *mesh, const int32_t *charts,
                                 const chart_members *members, sk_error *error)
{
    const size_t V = mesh->flaps.vertex_count;
    int32_t *loop = sk_allocate(2 * (V + 1), sizeof *loop), *edges = sk_allocate(V + 1, sizeof *edges);
    double *along = sk_allocate(2 * (V + 1), sizeof *along);
    if (!loop || !edges || !along) {
        free(loop);
        free(edges);
        free(along);
        return sk_fail(error, SK_ERROR_MEMORY, "no memory for the boundary loops of %zu vertices", V);
    }
    for (size_t v = 0; v < V; ++v)
        corners[v] = (unsigned char)natural_corner(mesh, charts, (int32_t)v);
    for (size_t c = 0; c < members->chart_count; ++c) {
        if (!members->lists[c].size)
            continue;
        const size_t n =
            boundary_loop(mesh, charts, (int32_t)c, members->lists[c].items, members->lists[c].size, loop, edges, along);
        sk_complete_corners(corners, loop, along, n, loop + V + 1, along + V + 1);
    }
    free(loop);
    free(edges);
    free(along);
    return SK_OK;
}

sk_status sk_chart_corners(unsigned char *corners, const sk_triangle_mesh *mesh, const int32_t *charts,
                           const double *embedding, size_t dimension, sk_error *error)
{
    if (!mesh)
        return sk_fail(error, SK_ERROR_ARGUMENT, "mesh must not be null");
    const int32_t *triangles = mesh->triangles;
    const size_t vertex_count = mesh->vertex_count, triangle_count = mesh->triangle_count;
    if (!corners)
        return sk_fail(error, SK_ERROR_ARGUMENT, "corners must not be null");
    size_t values = 0;
    if (embedding && sk_array_size(&values, vertex_count, dimension, 1, "embedding", error) != SK_OK)
        return SK_ERROR_ARGUMENT;
    if (embedding && (dimension < 1 || sk_first_non_finite(embedding, values) < values))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "the embedding needs a dimension and finite values");
    topology topo;
    chart_members members = {0};
    disc_scratch scratch = {0};
    sk_status status = sk_build_topology(&topo, triangles, vertex_count, triangle_count, embedding, dimension, error);
    if (status == SK_OK)
        status = sk_collect_members(&members, charts, triangle_count, error);
    if (status == SK_OK && !sk_make_disc_scratch(&scratch, &topo))
        status = sk_fail(error, SK_ERROR_MEMORY, "no memory to check the charts");
    if (status == SK_OK)
        status = sk_check_discs(&topo, charts, &members, &scratch, error);
    if (status == SK_OK)
        status = sk_compute_corners(corners, &topo, charts, &members, error);
    sk_free_disc_scratch(&scratch);
    sk_free_members(&members);
    sk_free_topology(&topo);
    return status == SK_OK ? sk_succeed(error) : status;
}
