/*
 * Triangle-mesh topology, built once by one function and shared by every algorithm that walks a mesh
 * (segmentation, cutting, corners, straightening, flattening; later simplification, baking and skeleton
 * extraction), in the manner of libigl's edge_flaps / is_edge_manifold / boundary_loop.
 *
 * Corners are numbered by slot: corner k of triangle t is slot 3 t + k, and edge k of a triangle joins its
 * corners k and (k + 1) % 3. Every function here expects triangles already checked by sk_validate_triangles
 * (indices in range, no repeated vertex) and fewer than 2^31 / 3 of them.
 */
#ifndef SK_MESH_H
#define SK_MESH_H

#include "sk_internal.h"

/* The undirected edges of a triangle list, each with the (at most two) triangles beside it, and the
 * vertex-to-edge and vertex-to-triangle adjacency. */
typedef struct sk_edge_flaps {
    const int32_t *triangles; /* 3 per triangle (not owned) */
    size_t vertex_count, triangle_count, edge_count;
    int32_t *triangle_edges;  /* 3 per triangle: the edge of each side */
    int32_t *edge_vertices;   /* 2 per edge, smaller first; edges are numbered in order of these pairs */
    int32_t *edge_triangles;  /* 2 per edge, in slot order; the second is -1 on the border */
    int32_t *edge_corners;    /* 2 per edge: the corner (0-2) of each triangle opposite the edge, or -1 */
    int32_t *vertex_edge_offsets, *vertex_edges;         /* CSR, vertex_count + 1 offsets: edges, ascending */
    int32_t *vertex_triangle_offsets, *vertex_triangles; /* CSR: the triangles at each vertex, ascending */
} sk_edge_flaps;

/* Up to this many of the triangles on a non-manifold edge are named in a defect. */
#define SK_DEFECT_TRIANGLES 16

/* An edge that more than two triangles share: the one shared by the most (the first such edge in edge order
 * among equals), with its first triangles in slot order. */
typedef struct sk_edge_defect {
    int32_t vertices[2]; /* smaller first */
    size_t triangle_count;
    int32_t triangles[SK_DEFECT_TRIANGLES];
} sk_edge_defect;

/*
 * Builds the edge flaps of `triangle_count` triangles on `vertex_count` vertices. SK_ERROR_ARGUMENT when an
 * edge has more than two triangles (*defect, when not NULL, names it; the caller words the message),
 * SK_ERROR_MEMORY when memory runs out; no message either way. On failure nothing needs freeing. With
 * vertex_count 0 only the edges are built (no vertex adjacency): enough for fans, components and orientation,
 * and it costs nothing per vertex of a large mesh when the triangles are a small part of it.
 */
sk_status sk_edge_flaps_build(sk_edge_flaps *flaps, const int32_t *triangles, size_t triangle_count,
                              size_t vertex_count, sk_edge_defect *defect);
void sk_edge_flaps_free(sk_edge_flaps *flaps);

/* The triangle across edge e from triangle t (-1 on the border). */
static inline int32_t sk_edge_other_triangle(const sk_edge_flaps *flaps, int32_t e, int32_t t)
{
    return flaps->edge_triangles[2 * e] == t ? flaps->edge_triangles[2 * e + 1] : flaps->edge_triangles[2 * e];
}

/* The end of edge e that is not v. */
static inline int32_t sk_edge_other_vertex(const sk_edge_flaps *flaps, int32_t e, int32_t v)
{
    return flaps->edge_vertices[2 * e] == v ? flaps->edge_vertices[2 * e + 1] : flaps->edge_vertices[2 * e];
}

static inline int sk_is_border_edge(const sk_edge_flaps *flaps, int32_t e)
{
    return flaps->edge_triangles[2 * e + 1] < 0;
}

/* The slot (3 t + k) of the side of triangle t that is edge e (e must be one of its edges). */
static inline int32_t sk_edge_slot(const sk_edge_flaps *flaps, int32_t e, int32_t t)
{
    const int32_t *sides = flaps->triangle_edges + 3 * t;
    return 3 * t + (sides[0] == e ? 0 : sides[1] == e ? 1 : 2);
}

/* The edge joining u and v, or -1. */
int32_t sk_edge_between(const sk_edge_flaps *flaps, int32_t u, int32_t v);

/* Whether vertex v has a border edge. */
int sk_is_border_vertex(const sk_edge_flaps *flaps, int32_t v);

/* Whether the two triangles of interior edge e run along it the same way (their orientations disagree). */
int sk_edge_runs_same_way(const sk_edge_flaps *flaps, int32_t e);

/*
 * Fans: the corners at one vertex joined across interior edges that are not cut (cut_edges: one flag per
 * edge, may be NULL). fan_of_corner (3 per triangle) receives each corner's fan, numbered in order of the fan's
 * first corner slot; a vertex with two fans is pinched (a bowtie), or cut. Returns the number of fans, or -1
 * when memory ran out.
 */
long sk_corner_fans(int32_t *fan_of_corner, const sk_edge_flaps *flaps, const unsigned char *cut_edges);

/* Connected components of triangles across interior edges that are not cut (cut_edges may be NULL), numbered
 * in order of their first triangle. Returns their number, or -1 when memory ran out. */
long sk_triangle_components(int32_t *component, const sk_edge_flaps *flaps, const unsigned char *cut_edges);

/* Union-find over items 0..n-1 (start from parent[i] = i): the root of item's class, halving the path on the way. */
int32_t sk_find_root(int32_t *parent, int32_t item);
/* Joins the classes of a and b under the smaller root, so that a class's root is its smallest member. */
void sk_join_classes(int32_t *parent, int32_t a, int32_t b);

/*
 * Walks a closed chain of edges: from start_vertex along first_edge, at each vertex on along the first other
 * edge (in vertex_edges order) that on_chain accepts, until back at start_vertex or stuck. loop_vertices[k]
 * and loop_edges[k] (the edge leaving loop_vertices[k]; either may be NULL) receive the chain; returns its
 * length (at most vertex_count). The chain is a loop where every vertex has exactly two accepted edges.
 */
typedef int (*sk_edge_filter)(const void *context, int32_t edge);
size_t sk_trace_loop(int32_t *loop_vertices, int32_t *loop_edges, const sk_edge_flaps *flaps, sk_edge_filter on_chain,
                     const void *context, int32_t start_vertex, int32_t first_edge);

/*
 * The border loops (chains of edges with one triangle), each in its triangles' direction (the interior on the
 * left of counterclockwise triangles), starting at its lowest vertex, loops in order of that vertex: loop l
 * is loop_vertices[loop_offsets[l] .. loop_offsets[l + 1] - 1] and loop_edges alike. Needs consistently
 * oriented triangles and one fan per vertex; arrays: border edges (+ 1 for the offsets). Returns the number of
 * loops, or -1 when memory ran out.
 */
long sk_boundary_loops(int32_t *loop_offsets, int32_t *loop_vertices, int32_t *loop_edges, const sk_edge_flaps *flaps);

/*
 * Chart corners (Merry 2007, Fig 5.6), the one rule segmentation and flattening share: adds corners to a loop
 * of n vertices (loop, with along[k] the length from loop[0] to loop[k] and along[n] the loop's) until it has
 * three. With none: its lowest-numbered vertex and those nearest a third and two thirds of the way round;
 * with one: the two at a third and two thirds from it; with two: the vertex nearest the middle of the longer
 * arc between them. corners is indexed by vertex; a loop of three vertices or fewer gets all of them.
 * Evenly spaced corners make the straightened boundary nearest an equilateral triangle. rotated and
 * rotated_along: scratch of n + 1 entries.
 */
void sk_complete_corners(unsigned char *corners, const int32_t *loop, const double *along, size_t n, int32_t *rotated,
                         double *rotated_along);

/*
 * Groups triangles by chart (a counting sort): chart c's triangles end up in members[offsets[c] ..
 * offsets[c + 1] - 1]. Chart ids must already be checked to lie in [0, triangle_count); offsets has
 * triangle_count + 2 entries, zeroed by the caller; members has triangle_count.
 */
void sk_group_by_chart(int32_t *offsets, int32_t *members, const int32_t *charts, size_t triangle_count);

#endif
