/* Cutting a mesh open along seams: one new vertex per fan of triangles joined through non-seam edges. */
#include <stdlib.h>
#include <string.h>

#include "sk_charts.h"

/* The mesh edge joining each seam's two vertices, flagged; a pair that is not an edge is refused. */
static sk_status mark_seams(unsigned char *seam_edges, const topology *mesh, const int32_t *seams, size_t seam_count,
                            sk_error *error)
{
    for (size_t s = 0; s < seam_count; ++s) {
        const int32_t u = seams[2 * s], v = seams[2 * s + 1];
        if (u < 0 || v < 0 || (size_t)u >= mesh->flaps.vertex_count || (size_t)v >= mesh->flaps.vertex_count)
            return sk_fail(error, SK_ERROR_INDEX, "seam %zu: vertex (%d, %d) is outside [0, %zu)", s, (int)u, (int)v,
                           mesh->flaps.vertex_count);
        const int32_t e = sk_edge_between(&mesh->flaps, u, v);
        if (e >= 0)
            seam_edges[e] = 1;
        else
            return sk_fail(error, SK_ERROR_ARGUMENT, "seam %zu: vertices %d and %d are not joined by a mesh edge", s,
                           (int)u, (int)v);
    }
    return SK_OK;
}

/*
 * Splits each vertex into one copy per fan of its triangles joined through non-seam edges. seam_slots
 * (3 per triangle, may be NULL) flags the triangle edges that are seams.
 */
static sk_status cut_mesh(int32_t *cut_triangles, int32_t *source_vertex, size_t *cut_vertex_count,
                          unsigned char *seam_slots, const int32_t *triangles, const int32_t *seams, size_t vertex_count,
                          size_t triangle_count, size_t seam_count, sk_error *error)
{
    topology mesh;
    sk_status status = sk_build_topology(&mesh, triangles, vertex_count, triangle_count, NULL, 0, error);
    unsigned char *seam_edges = status == SK_OK ? sk_allocate_zeroed(mesh.flaps.edge_count, 1) : NULL;
    if (status == SK_OK && !seam_edges)
        status = sk_fail(error, SK_ERROR_MEMORY, "no memory to cut %zu triangles along seams", triangle_count);
    if (status == SK_OK)
        status = mark_seams(seam_edges, &mesh, seams, seam_count, error);
    /* the new vertices are the fans across non-seam edges, numbered in order of their first corner */
    const long fans = status == SK_OK ? sk_corner_fans(cut_triangles, &mesh.flaps, seam_edges) : 0;
    if (fans < 0)
        status = sk_fail(error, SK_ERROR_MEMORY, "no memory to cut %zu triangles along seams", triangle_count);
    if (status == SK_OK) {
        for (size_t slot = 0; slot < 3 * triangle_count; ++slot) {
            source_vertex[cut_triangles[slot]] = triangles[slot];
            if (seam_slots)
                seam_slots[slot] = seam_edges[mesh.flaps.triangle_edges[slot]];
        }
        *cut_vertex_count = (size_t)fans;
    }
    free(seam_edges);
    sk_free_topology(&mesh);
    return status;
}

sk_status sk_cut_along_seams(int32_t *cut_triangles, int32_t *source_vertex, size_t *cut_vertex_count,
                             const sk_triangle_mesh *mesh, const int32_t *seams, size_t seam_count, sk_error *error)
{
    if (!mesh)
        return sk_fail(error, SK_ERROR_ARGUMENT, "mesh must not be null");
    const int32_t *triangles = mesh->triangles;
    const size_t vertex_count = mesh->vertex_count, triangle_count = mesh->triangle_count;
    if (!cut_triangles || !source_vertex || !cut_vertex_count || (!seams && seam_count > 0))
        return sk_fail(error, SK_ERROR_ARGUMENT, "outputs and a non-empty seam list must not be null");
    const sk_status status = cut_mesh(cut_triangles, source_vertex, cut_vertex_count, NULL, triangles, seams,
                                      vertex_count, triangle_count, seam_count, error);
    return status == SK_OK ? sk_succeed(error) : status;
}

void sk_free_segment_mesh(segment_mesh *s)
{
    sk_free_topology(&s->mesh);
    SK_FREE_ALL(s->triangles, s->source_vertex, s->embedding, s->seam_slots, s->seam_edges);
}

sk_status sk_prepare_segment_mesh(segment_mesh *s, const double *embedding, size_t dimension,
                                      const int32_t *triangles, const int32_t *seams, size_t vertex_count,
                                      size_t triangle_count, size_t seam_count, sk_error *error)
{
    memset(s, 0, sizeof *s);
    if (seam_count == 0) {
        const sk_status status =
            sk_build_topology(&s->mesh, triangles, vertex_count, triangle_count, embedding, dimension, error);
        s->seam_edges = status == SK_OK ? sk_allocate_zeroed(s->mesh.flaps.edge_count + 1, 1) : NULL;
        if (status == SK_OK && !s->seam_edges)
            return sk_fail(error, SK_ERROR_MEMORY, "no memory for %zu seam flags", s->mesh.flaps.edge_count);
        return status;
    }
    if (triangle_count == 0 || triangle_count > INT32_MAX / 3)
        return sk_fail(error, SK_ERROR_ARGUMENT, "need between 1 and %d triangles", INT32_MAX / 3);
    s->triangles = sk_allocate(3 * triangle_count, sizeof(int32_t));
    s->source_vertex = sk_allocate(3 * triangle_count, sizeof(int32_t));
    s->seam_slots = sk_allocate(3 * triangle_count, 1);
    if (!s->triangles || !s->source_vertex || !s->seam_slots)
        return sk_fail(error, SK_ERROR_MEMORY, "no memory to cut %zu triangles along seams", triangle_count);
    size_t cut_vertex_count = 0;
    sk_status status = cut_mesh(s->triangles, s->source_vertex, &cut_vertex_count, s->seam_slots, triangles, seams,
                                vertex_count, triangle_count, seam_count, error);
    if (status != SK_OK)
        return status;
    s->embedding = sk_allocate(cut_vertex_count * dimension + 1, sizeof(double));
    if (!s->embedding)
        return sk_fail(error, SK_ERROR_MEMORY, "no memory for %zu cut vertices", cut_vertex_count);
    for (size_t v = 0; v < cut_vertex_count; ++v)
        memcpy(s->embedding + v * dimension, embedding + (size_t)s->source_vertex[v] * dimension,
               dimension * sizeof(double));
    status = sk_build_topology(&s->mesh, s->triangles, cut_vertex_count, triangle_count, s->embedding, dimension, error);
    s->seam_edges = status == SK_OK ? sk_allocate_zeroed(s->mesh.flaps.edge_count + 1, 1) : NULL;
    if (status == SK_OK && !s->seam_edges)
        return sk_fail(error, SK_ERROR_MEMORY, "no memory for %zu seam flags", s->mesh.flaps.edge_count);
    for (size_t slot = 0; status == SK_OK && slot < 3 * triangle_count; ++slot)
        s->seam_edges[s->mesh.flaps.triangle_edges[slot]] |= s->seam_slots[slot];
    return status;
}
