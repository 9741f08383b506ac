/*
 * What segmentation, cutting, corners and straightening share (internal to csrc/offline/unwrap): the mesh with
 * metric edge lengths, generation-stamped marks, the chart metric of eq. 5.4, per-chart triangle lists with
 * the disc check, and the mesh cut along seams that segmentation runs on.
 *
 * Every metric quantity comes from a per-vertex embedding y_i in R^d (the rest pose, or animation space
 * projected on its principal directions): lengths are |y_u - y_v| and a triangle's plane is the
 * bivector (y_b - y_a) ^ (y_c - y_a) / 2, stored as its d(d-1)/2 components (i < j). A chart's maximum
 * projected area is the spectral norm of the antisymmetric matrix of its summed bivector (appendix A.1).
 */
#ifndef SK_CHARTS_H
#define SK_CHARTS_H

#include <lapacke.h>
#include <string.h>

#include "sk_mesh.h"

#define MAX_COMPONENTS (SK_SEGMENT_MAX_DIMENSION * (SK_SEGMENT_MAX_DIMENSION - 1) / 2)

/* ---------------------------------------------------------------------------------------------
 * The mesh: the shared edge flaps (common/sk_mesh.h) and metric edge lengths (sk_charts.c)
 * ------------------------------------------------------------------------------------------- */

/* The mesh's edge flaps, with each edge's metric length in the embedding (when there is one). */
typedef struct topology {
    sk_edge_flaps flaps;
    double *edge_lengths;
} topology;

void sk_free_topology(topology *mesh);

/* Validates the triangles and builds the topology; a non-manifold edge is refused by name. */
sk_status sk_build_topology(topology *mesh, const int32_t *triangles, size_t vertex_count, size_t triangle_count,
                                const double *embedding, size_t dimension, sk_error *error);

/* Refuses an embedding whose size overflows, or with a NaN or infinity (naming the vertex). */
sk_status sk_check_embedding(const double *embedding, size_t dimension, size_t vertex_count, sk_error *error);

static inline int32_t chart_across(const topology *mesh, const int32_t *charts, int32_t e, int32_t t)
{
    const int32_t other = sk_edge_other_triangle(&mesh->flaps, e, t);
    return other < 0 ? -1 : charts[other];
}

/* Whether edge e lies on chart c's boundary: exactly one of its sides is in c (the border counts as outside). */
static inline int on_chart_boundary(const topology *mesh, const int32_t *charts, int32_t e, int32_t c)
{
    const int32_t t0 = mesh->flaps.edge_triangles[2 * e], t1 = mesh->flaps.edge_triangles[2 * e + 1];
    return (charts[t0] == c) != (t1 >= 0 && charts[t1] == c);
}

/* ---------------------------------------------------------------------------------------------
 * Scratch: per-vertex and per-triangle marks that are "cleared" by bumping a generation counter
 * ------------------------------------------------------------------------------------------- */

typedef struct marks {
    uint32_t generation;
    uint32_t *stamp;
    int32_t *value; /* 3 integers per item, meaningful while stamp == generation */
} marks;

int sk_make_marks(marks *m, size_t count);

void sk_free_marks(marks *m);

static inline void next_generation(marks *m, size_t count)
{
    if (++m->generation == 0) { /* wrapped: old stamps could collide with new generations */
        memset(m->stamp, 0, (count + 1) * sizeof *m->stamp);
        m->generation = 1;
    }
}

/* Marks item i for this generation (zeroing its values); returns 1 when it was not marked yet. */
static inline int mark(marks *m, int32_t i)
{
    if (m->stamp[i] == m->generation)
        return 0;
    m->stamp[i] = m->generation;
    m->value[3 * i] = m->value[3 * i + 1] = m->value[3 * i + 2] = 0;
    return 1;
}

static inline int marked(const marks *m, int32_t i)
{
    return m->stamp[i] == m->generation;
}

/* ---------------------------------------------------------------------------------------------
 * Chart metric (eq. 5.4): area, summed bivector, perimeter
 * ------------------------------------------------------------------------------------------- */

typedef struct chart_shape {
    double area, perimeter;
    double bivector[MAX_COMPONENTS];
} chart_shape;

/* LAPACK workspace for the largest singular value of a chart's antisymmetric bivector matrix. */
typedef struct spectral_workspace {
    size_t dimension;
    double matrix[SK_SEGMENT_MAX_DIMENSION * SK_SEGMENT_MAX_DIMENSION];
    double eigenvectors[SK_SEGMENT_MAX_DIMENSION * SK_SEGMENT_MAX_DIMENSION];
    double work[26 * SK_SEGMENT_MAX_DIMENSION];
    lapack_int iwork[10 * SK_SEGMENT_MAX_DIMENSION];
    lapack_int support[2 * SK_SEGMENT_MAX_DIMENSION];
    lapack_int failure; /* the first non-zero LAPACK info, reported by the caller */
} spectral_workspace;

void sk_triangle_bivector(double *bivector, double *area, const double *embedding, size_t dimension,
                              const int32_t *triangle);

/*
 * Maximum projected area = the spectral norm of the antisymmetric matrix M of the bivector. Its singular
 * values come in equal pairs, so in 2-4 dimensions there are closed forms (|B|; for d = 4 the pair's
 * squares are the roots of s^2 - |B|^2 s + Pf(M)^2). Beyond that we take the largest eigenvalue of
 * M^T M with LAPACK dsyevr rather than power iteration: the top eigenvalue is always double and the
 * next pair is close to it exactly for the tube-like charts the metric must recognise, where power
 * iteration would converge slowly and stop early with an underestimate.
 */
double sk_max_projected_area(spectral_workspace *w, const double *bivector);

/* E_combined * area (the chart's term in eq. 5.5's numerator); zero for a chart of zero area. */
double sk_weighted_metric(double area, double perimeter, double projected, double rho);

double sk_combined_metric(double area, double perimeter, double projected, double rho);

/* ---------------------------------------------------------------------------------------------
 * Charts given per triangle: member lists and the disc check
 * ------------------------------------------------------------------------------------------- */

typedef struct triangle_list {
    int32_t *items;
    size_t size, capacity;
} triangle_list;

typedef struct chart_members {
    size_t chart_count;   /* ids are in [0, chart_count) */
    triangle_list *lists; /* per chart */
} chart_members;

static inline int add_member(chart_members *members, int32_t c, int32_t t)
{
    return SK_PUSH(members->lists[c], t, 4);
}

void sk_free_members(chart_members *members);

/* Checks the chart ids' range and lists each chart's triangles. */
sk_status sk_collect_members(chart_members *members, const int32_t *charts, size_t triangle_count, sk_error *error);

typedef struct disc_scratch {
    marks vertices;  /* value: triangles, interior edge sides, boundary edges at the vertex */
    marks triangles; /* visited by the connectivity search */
    int32_t *queue;  /* triangle_count */
} disc_scratch;

int sk_make_disc_scratch(disc_scratch *scratch, const topology *mesh);

void sk_free_disc_scratch(disc_scratch *scratch);

/*
 * NULL when chart c (its `count` triangles in `list`) is a topological disc, else the reason. A disc is
 * connected, has Euler characteristic V - E + F = 1 and a boundary, and each vertex has one fan of chart
 * triangles (boundary vertices exactly two boundary edges): this rules out charts touching themselves at
 * a vertex, annuli, spheres and the projective plane.
 */
const char *sk_disc_problem(const topology *mesh, const int32_t *charts, int32_t c, const int32_t *list,
                                size_t count, disc_scratch *s, int32_t *where);

sk_status sk_check_discs(const topology *mesh, const int32_t *charts, const chart_members *members,
                             disc_scratch *scratch, sk_error *error);

/* E_mesh (eq. 5.5) of charts given per triangle (ids 0..count-1): per chart its area, summed bivector and
 * perimeter (edges whose other side is another chart or nothing). Returns -1 when memory ran out. */
double sk_charts_mesh_metric(const topology *mesh, const int32_t *charts, size_t count, const double *embedding,
                                 size_t dimension, double rho);

/* Chart corners (sk_corners.c): where charts meet, completed by sk_complete_corners' rule. */
sk_status sk_compute_corners(unsigned char *corners, const topology *mesh, const int32_t *charts,
                                 const chart_members *members, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * The mesh cut along seams (sk_cut.c)
 * ------------------------------------------------------------------------------------------- */

/* The mesh segmentation runs on: cut along the seams (seams then flagged per cut edge), or as given. */
typedef struct segment_mesh {
    topology mesh;
    int32_t *triangles, *source_vertex;
    double *embedding;
    unsigned char *seam_slots, *seam_edges;
} segment_mesh;
void sk_free_segment_mesh(segment_mesh *s);

sk_status sk_prepare_segment_mesh(segment_mesh *s, const double *embedding, size_t dimension,
                                      const int32_t *triangles, const int32_t *seams, size_t vertex_count,
                                      size_t triangle_count, size_t seam_count, sk_error *error);

#endif
