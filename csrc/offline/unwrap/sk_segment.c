/*
 * Segmentation into disc charts (Merry 2007, section 5.2): greedy chart merging with the combined
 * area-ratio and compactness metric, chart corners, and edge straightening.
 *
 * Every metric quantity comes from a per-vertex embedding y_i in R^d (the rest pose, or animation space
 * projected on its principal directions): lengths are |y_u - y_v| and a triangle's plane is the
 * bivector (y_b - y_a) ^ (y_c - y_a) / 2, stored as its d(d-1)/2 components (i < j). A chart's maximum
 * projected area is the spectral norm of the antisymmetric matrix of its summed bivector (appendix A.1).
 */
#include <lapacke.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_mesh.h"

#define SK_PI 3.14159265358979323846
#define MAX_COMPONENTS (SK_SEGMENT_MAX_DIMENSION * (SK_SEGMENT_MAX_DIMENSION - 1) / 2)
/* A chart whose projected area vanishes (folded flat onto itself) gets this finite area ratio, so that
 * sums of chart costs never meet inf - inf and such charts still merge last. */
#define MAX_AREA_RATIO 1e12

/* ---------------------------------------------------------------------------------------------
 * Mesh topology: the shared edge flaps (common/sk_mesh.h) and metric edge lengths
 * ------------------------------------------------------------------------------------------- */

/* The mesh's edge flaps, with each edge's metric length in the embedding (when there is one). */
typedef struct topology {
    sk_edge_flaps flaps;
    double *edge_lengths;
} topology;

static void free_topology(topology *mesh)
{
    sk_edge_flaps_free(&mesh->flaps);
    free(mesh->edge_lengths);
    mesh->edge_lengths = NULL;
}

static double distance(const double *embedding, size_t dimension, int32_t u, int32_t v)
{
    double sum = 0.0;
    for (size_t k = 0; k < dimension; ++k) {
        const double difference = embedding[(size_t)u * dimension + k] - embedding[(size_t)v * dimension + k];
        sum += difference * difference;
    }
    return sqrt(sum);
}

/* Validates the triangles and builds the topology; a non-manifold edge is refused by name. */
static sk_status build_topology(topology *mesh, const int32_t *triangles, size_t vertex_count, size_t triangle_count,
                                const double *embedding, size_t dimension, sk_error *error)
{
    memset(mesh, 0, sizeof *mesh);
    if (triangle_count == 0 || triangle_count > INT32_MAX / 3 || vertex_count > INT32_MAX)
        return sk_fail(error, SK_ERROR_ARGUMENT, "need between 1 and %d triangles and fewer than 2^31 vertices",
                       INT32_MAX / 3);
    const sk_triangle_mesh given = {triangles, triangle_count, vertex_count};
    sk_status status = sk_validate_triangles(&given, error);
    if (status != SK_OK)
        return status;
    sk_edge_defect defect;
    status = sk_edge_flaps_build(&mesh->flaps, triangles, triangle_count, vertex_count, &defect);
    if (status == SK_ERROR_ARGUMENT)
        return sk_fail(error, SK_ERROR_ARGUMENT,
                       "edge (%d, %d) is shared by %zu triangles (%d, %d, %d...): the mesh is not manifold",
                       defect.vertices[0], defect.vertices[1], defect.triangle_count, defect.triangles[0],
                       defect.triangles[1], defect.triangles[2]);
    if (status != SK_OK)
        return sk_fail(error, SK_ERROR_MEMORY, "no memory for the mesh edges of %zu triangles", triangle_count);
    if (embedding) {
        const size_t E = mesh->flaps.edge_count;
        mesh->edge_lengths = sk_allocate(E, sizeof(double));
        if (!mesh->edge_lengths)
            return sk_fail(error, SK_ERROR_MEMORY, "no memory for %zu edge lengths", E);
        for (size_t e = 0; e < E; ++e)
            mesh->edge_lengths[e] =
                distance(embedding, dimension, mesh->flaps.edge_vertices[2 * e], mesh->flaps.edge_vertices[2 * e + 1]);
    }
    return SK_OK;
}

/* Refuses an embedding whose size overflows, or with a NaN or infinity (naming the vertex). */
static sk_status check_embedding(const double *embedding, size_t dimension, size_t vertex_count, sk_error *error)
{
    size_t values;
    const sk_status status = sk_array_size(&values, vertex_count, dimension, 1, "embedding", error);
    if (status != SK_OK)
        return status;
    const size_t bad = sk_first_non_finite(embedding, values);
    if (bad < values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "embedding of vertex %zu has a NaN or infinity", bad / dimension);
    return SK_OK;
}

static int32_t chart_across(const topology *mesh, const int32_t *charts, int32_t e, int32_t t)
{
    const int32_t other = sk_edge_other_triangle(&mesh->flaps, e, t);
    return other < 0 ? -1 : charts[other];
}

/* Whether edge e lies on chart c's boundary: exactly one of its sides is in c (the border counts as outside). */
static int on_chart_boundary(const topology *mesh, const int32_t *charts, int32_t e, int32_t c)
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

static int make_marks(marks *m, size_t count)
{
    m->generation = 0;
    m->stamp = sk_allocate_zeroed(count + 1, sizeof *m->stamp);
    m->value = sk_allocate_zeroed(3 * (count + 1), sizeof *m->value);
    return m->stamp && m->value;
}

static void free_marks(marks *m)
{
    free(m->stamp);
    free(m->value);
}

static void next_generation(marks *m, size_t count)
{
    if (++m->generation == 0) { /* wrapped: old stamps could collide with new generations */
        memset(m->stamp, 0, (count + 1) * sizeof *m->stamp);
        m->generation = 1;
    }
}

/* Marks item i for this generation (zeroing its values); returns 1 when it was not marked yet. */
static int mark(marks *m, int32_t i)
{
    if (m->stamp[i] == m->generation)
        return 0;
    m->stamp[i] = m->generation;
    m->value[3 * i] = m->value[3 * i + 1] = m->value[3 * i + 2] = 0;
    return 1;
}

static int marked(const marks *m, int32_t i)
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

static void triangle_bivector(double *bivector, double *area, const double *embedding, size_t dimension,
                              const int32_t *triangle)
{
    const double *a = embedding + (size_t)triangle[0] * dimension, *b = embedding + (size_t)triangle[1] * dimension,
                 *c = embedding + (size_t)triangle[2] * dimension;
    double sum = 0.0;
    size_t k = 0;
    for (size_t i = 0; i < dimension; ++i)
        for (size_t j = i + 1; j < dimension; ++j, ++k) {
            const double u_i = b[i] - a[i], u_j = b[j] - a[j], v_i = c[i] - a[i], v_j = c[j] - a[j];
            bivector[k] = 0.5 * (u_i * v_j - u_j * v_i);
            sum += bivector[k] * bivector[k];
        }
    *area = sqrt(sum);
}

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

/*
 * Maximum projected area = the spectral norm of the antisymmetric matrix M of the bivector. Its singular
 * values come in equal pairs, so in 2-4 dimensions there are closed forms (|B|; for d = 4 the pair's
 * squares are the roots of s^2 - |B|^2 s + Pf(M)^2). Beyond that we take the largest eigenvalue of
 * M^T M with LAPACK dsyevr rather than power iteration: the top eigenvalue is always double and the
 * next pair is close to it exactly for the tube-like charts the metric must recognise, where power
 * iteration would converge slowly and stop early with an underestimate.
 */
static double max_projected_area(spectral_workspace *w, const double *bivector)
{
    const size_t d = w->dimension;
    double squared = 0.0;
    for (size_t k = 0; k < d * (d - 1) / 2; ++k)
        squared += bivector[k] * bivector[k];
    if (d <= 3)
        return sqrt(squared);
    if (d == 4) {
        const double pfaffian = bivector[0] * bivector[5] - bivector[1] * bivector[4] + bivector[2] * bivector[3];
        const double discriminant = fmax(squared * squared - 4.0 * pfaffian * pfaffian, 0.0);
        return sqrt(0.5 * (squared + sqrt(discriminant)));
    }
    double m[SK_SEGMENT_MAX_DIMENSION * SK_SEGMENT_MAX_DIMENSION] = {0};
    for (size_t i = 0, k = 0; i < d; ++i)
        for (size_t j = i + 1; j < d; ++j, ++k) {
            m[i * d + j] = bivector[k];
            m[j * d + i] = -bivector[k];
        }
    for (size_t i = 0; i < d; ++i)
        for (size_t j = 0; j < d; ++j) {
            double sum = 0.0;
            for (size_t k = 0; k < d; ++k)
                sum += m[k * d + i] * m[k * d + j];
            w->matrix[j * d + i] = sum;
        }
    lapack_int found = 0;
    double eigenvalue[SK_SEGMENT_MAX_DIMENSION];
    const lapack_int n = (lapack_int)d;
    /* Column-major _work variant: M^T M is symmetric, and the plain driver would allocate on every call. */
    const lapack_int info = LAPACKE_dsyevr_work(LAPACK_COL_MAJOR, 'N', 'I', 'U', n, w->matrix, n, 0.0, 0.0, n, n,
                                                0.0, &found, eigenvalue, w->eigenvectors, n, w->support, w->work,
                                                26 * n, w->iwork, 10 * n);
    if (info != 0 || found != 1) {
        if (!w->failure)
            w->failure = info != 0 ? info : -1;
        return sqrt(squared); /* an upper bound; the caller reports the failure */
    }
    return sqrt(fmax(eigenvalue[0], 0.0));
}

/* E_combined * area (the chart's term in eq. 5.5's numerator); zero for a chart of zero area. */
static double weighted_metric(double area, double perimeter, double projected, double rho)
{
    if (!(area > 0.0))
        return 0.0;
    const double compactness = rho * perimeter * perimeter / (4.0 * SK_PI);
    return (area + compactness) * area / fmax(projected, area / MAX_AREA_RATIO);
}

static double combined_metric(double area, double perimeter, double projected, double rho)
{
    return area > 0.0 ? weighted_metric(area, perimeter, projected, rho) / area : 0.0;
}

/* ---------------------------------------------------------------------------------------------
 * Greedy merging (section 5.2.2; Garland et al. 2001, Sander et al. 2001)
 * ------------------------------------------------------------------------------------------- */

typedef struct edge_list {
    int32_t *items;
    size_t size, capacity, stale; /* stale: entries that are no longer on the chart's boundary */
} edge_list;

static int append_edge(edge_list *list, int32_t e)
{
    return SK_PUSH(*list, e, 4);
}

typedef struct merge_candidate {
    double cost;          /* change of sum E_i A_i if the two charts merge */
    double shared_length; /* metric length of the boundary they share */
    int32_t a, b;
    uint32_t version_a, version_b;
} merge_candidate;

typedef struct candidate_heap {
    merge_candidate *items;
    size_t size, capacity;
} candidate_heap;

static int heap_push(candidate_heap *heap, merge_candidate item)
{
    if (!SK_PUSH(*heap, item, 1024))
        return 0;
    size_t child = heap->size - 1; /* sift the new last entry up */
    while (child > 0 && heap->items[(child - 1) / 2].cost > item.cost) {
        heap->items[child] = heap->items[(child - 1) / 2];
        child = (child - 1) / 2;
    }
    heap->items[child] = item;
    return 1;
}

static merge_candidate heap_pop(candidate_heap *heap)
{
    const merge_candidate top = heap->items[0], last = heap->items[--heap->size];
    size_t parent = 0;
    for (;;) {
        size_t child = 2 * parent + 1;
        if (child >= heap->size)
            break;
        if (child + 1 < heap->size && heap->items[child + 1].cost < heap->items[child].cost)
            ++child;
        if (!(heap->items[child].cost < last.cost))
            break;
        heap->items[parent] = heap->items[child];
        parent = child;
    }
    if (heap->size > 0)
        heap->items[parent] = last;
    return top;
}

typedef struct merger {
    const topology *mesh;
    const double *embedding;
    size_t dimension, components;
    double rho;
    const unsigned char *seam_edges; /* per edge: a user seam, never merged across */
    int32_t *chart_of;               /* per triangle */
    int32_t *next_triangle, *last_triangle; /* per-chart triangle lists (chart id = its first triangle) */
    int32_t *triangle_count;
    double *area, *perimeter, *bivector, *term; /* term: E_i A_i */
    edge_list *boundary;
    uint32_t *version;
    unsigned char *alive;
    marks vertex_marks, seen_vertices, chart_marks;
    candidate_heap heap;
    spectral_workspace spectral;
    double metric_sum; /* sum over charts of E_i A_i */
    size_t chart_count;
} merger;

static int32_t side_chart(const merger *m, int32_t e, int32_t c)
{
    const int32_t t0 = m->mesh->flaps.edge_triangles[2 * e], t1 = m->mesh->flaps.edge_triangles[2 * e + 1];
    const int32_t c0 = m->chart_of[t0], c1 = t1 < 0 ? -1 : m->chart_of[t1];
    return c0 == c ? c1 : c0;
}

static int touches_chart(const merger *m, int32_t v, int32_t c)
{
    const topology *mesh = m->mesh;
    for (int32_t k = mesh->flaps.vertex_triangle_offsets[v]; k < mesh->flaps.vertex_triangle_offsets[v + 1]; ++k)
        if (m->chart_of[mesh->flaps.vertex_triangles[k]] == c)
            return 1;
    return 0;
}

/*
 * The shared boundary of charts s and l must be one simple path (no seam on it), and the charts must
 * have no other vertex in common: then gluing two discs along an arc gives a disc (Euler characteristic
 * 1 + 1 - 1). Two arcs would make an annulus, a closed loop a sphere, and an extra common vertex a
 * pinch. Scans only s's boundary, so callers pass the chart with the shorter boundary list as s.
 */
static int shared_boundary_is_arc(merger *m, int32_t s, int32_t l, double *shared_length)
{
    const edge_list *list = &m->boundary[s];
    marks *path = &m->vertex_marks; /* value[0]: shared edges at the vertex, value[1..2]: those edges */
    next_generation(path, m->mesh->flaps.vertex_count);
    size_t shared = 0;
    int32_t end = -1;
    *shared_length = 0.0;
    for (size_t k = 0; k < list->size; ++k) {
        const int32_t e = list->items[k];
        if (!on_chart_boundary(m->mesh, m->chart_of, e, s) || side_chart(m, e, s) != l)
            continue;
        if (m->seam_edges[e])
            return 0;
        ++shared;
        *shared_length += m->mesh->edge_lengths[e];
        for (int side = 0; side < 2; ++side) {
            const int32_t v = m->mesh->flaps.edge_vertices[2 * e + side];
            mark(path, v);
            int32_t *degree = &path->value[3 * v];
            if (*degree == 2)
                return 0; /* the shared edges branch */
            path->value[3 * v + 1 + (*degree)++] = e;
        }
    }
    if (shared == 0)
        return 0;
    for (size_t k = 0; k < list->size && end < 0; ++k) {
        const int32_t e = list->items[k];
        for (int side = 0; side < 2 && end < 0; ++side) {
            const int32_t v = m->mesh->flaps.edge_vertices[2 * e + side];
            if (marked(path, v) && path->value[3 * v] == 1)
                end = v;
        }
    }
    if (end < 0)
        return 0; /* a closed loop */
    size_t walked = 0;
    for (int32_t v = end, e = path->value[3 * end + 1];;) {
        ++walked;
        v = sk_edge_other_vertex(&m->mesh->flaps, e, v);
        if (path->value[3 * v] == 1)
            break;
        e = path->value[3 * v + 1] == e ? path->value[3 * v + 2] : path->value[3 * v + 1];
    }
    if (walked != shared)
        return 0; /* more than one arc */
    marks *seen = &m->seen_vertices;
    next_generation(seen, m->mesh->flaps.vertex_count);
    size_t common = 0;
    for (size_t k = 0; k < list->size; ++k) {
        const int32_t e = list->items[k];
        if (!on_chart_boundary(m->mesh, m->chart_of, e, s))
            continue;
        for (int side = 0; side < 2; ++side) {
            const int32_t v = m->mesh->flaps.edge_vertices[2 * e + side];
            if (mark(seen, v) && (marked(path, v) || touches_chart(m, v, l)) && ++common > shared + 1)
                return 0;
        }
    }
    return 1;
}

static int evaluate_merge(merger *m, int32_t a, int32_t b, merge_candidate *candidate)
{
    const int a_shorter = m->boundary[a].size - m->boundary[a].stale <= m->boundary[b].size - m->boundary[b].stale;
    double shared_length;
    if (!shared_boundary_is_arc(m, a_shorter ? a : b, a_shorter ? b : a, &shared_length))
        return 0;
    double merged[MAX_COMPONENTS];
    for (size_t k = 0; k < m->components; ++k)
        merged[k] = m->bivector[a * m->components + k] + m->bivector[b * m->components + k];
    const double area = m->area[a] + m->area[b];
    const double perimeter = fmax(m->perimeter[a] + m->perimeter[b] - 2.0 * shared_length, 0.0);
    const double after = weighted_metric(area, perimeter, max_projected_area(&m->spectral, merged), m->rho);
    candidate->cost = after - m->term[a] - m->term[b];
    candidate->shared_length = shared_length;
    candidate->a = a;
    candidate->b = b;
    candidate->version_a = m->version[a];
    candidate->version_b = m->version[b];
    return 1;
}

static int push_merges_of(merger *m, int32_t c)
{
    marks *neighbours = &m->chart_marks;
    next_generation(neighbours, m->mesh->flaps.triangle_count);
    const edge_list *list = &m->boundary[c];
    for (size_t k = 0; k < list->size; ++k) {
        const int32_t e = list->items[k];
        if (!on_chart_boundary(m->mesh, m->chart_of, e, c))
            continue;
        const int32_t other = side_chart(m, e, c);
        merge_candidate candidate;
        if (other >= 0 && mark(neighbours, other) && evaluate_merge(m, c, other, &candidate) &&
            !heap_push(&m->heap, candidate))
            return 0;
    }
    return 1;
}

static void compact_boundary(merger *m, int32_t c)
{
    edge_list *list = &m->boundary[c];
    size_t kept = 0;
    for (size_t k = 0; k < list->size; ++k)
        if (on_chart_boundary(m->mesh, m->chart_of, list->items[k], c))
            list->items[kept++] = list->items[k];
    list->size = kept;
    list->stale = 0;
}

static double chart_term(merger *m, int32_t c)
{
    return weighted_metric(m->area[c], m->perimeter[c], max_projected_area(&m->spectral, m->bivector + c * m->components),
                           m->rho);
}

/* Moves gone's boundary edges that do not face keep into keep's list; those facing keep become interior. */
static int take_boundary(merger *m, int32_t keep, int32_t gone)
{
    edge_list *kept = &m->boundary[keep], *removed = &m->boundary[gone];
    for (size_t k = 0; k < removed->size; ++k) {
        const int32_t e = removed->items[k];
        if (!on_chart_boundary(m->mesh, m->chart_of, e, gone))
            continue;
        if (side_chart(m, e, gone) == keep)
            ++kept->stale; /* its entry in keep's list is no longer on the boundary */
        else if (!append_edge(kept, e))
            return 0;
    }
    free(removed->items);
    memset(removed, 0, sizeof *removed);
    return 1;
}

/* Merges the chart with fewer triangles into the other (so each triangle is relabelled O(log T) times). */
static int apply_merge(merger *m, const merge_candidate *candidate)
{
    const int a_larger = m->triangle_count[candidate->a] >= m->triangle_count[candidate->b];
    const int32_t keep = a_larger ? candidate->a : candidate->b, gone = a_larger ? candidate->b : candidate->a;
    if (!take_boundary(m, keep, gone))
        return 0;
    for (int32_t t = gone; t >= 0; t = m->next_triangle[t])
        m->chart_of[t] = keep;
    m->next_triangle[m->last_triangle[keep]] = gone;
    m->last_triangle[keep] = m->last_triangle[gone];
    m->triangle_count[keep] += m->triangle_count[gone];
    m->area[keep] += m->area[gone];
    m->perimeter[keep] = fmax(m->perimeter[keep] + m->perimeter[gone] - 2.0 * candidate->shared_length, 0.0);
    for (size_t k = 0; k < m->components; ++k)
        m->bivector[keep * m->components + k] += m->bivector[gone * m->components + k];
    if (2 * m->boundary[keep].stale > m->boundary[keep].size)
        compact_boundary(m, keep);
    const double before = m->term[keep] + m->term[gone];
    m->term[keep] = chart_term(m, keep);
    m->term[gone] = 0.0;
    m->metric_sum += m->term[keep] - before;
    m->alive[gone] = 0;
    ++m->version[keep];
    ++m->version[gone];
    --m->chart_count;
    return push_merges_of(m, keep);
}

static void free_merger(merger *m)
{
    if (m->boundary)
        for (size_t c = 0; c < m->mesh->flaps.triangle_count; ++c)
            free(m->boundary[c].items);
    free(m->boundary);
    free(m->chart_of);
    free(m->next_triangle);
    free(m->last_triangle);
    free(m->triangle_count);
    free(m->area);
    free(m->perimeter);
    free(m->bivector);
    free(m->term);
    free(m->version);
    free(m->alive);
    free_marks(&m->vertex_marks);
    free_marks(&m->seen_vertices);
    free_marks(&m->chart_marks);
    free(m->heap.items);
}

/* One chart per triangle, and every legal merge of two triangles in the queue. */
static int start_merger(merger *m)
{
    const size_t T = m->mesh->flaps.triangle_count, K = m->components ? m->components : 1;
    m->boundary = sk_allocate_zeroed(T, sizeof *m->boundary);
    m->chart_of = sk_allocate(T, sizeof(int32_t));
    m->next_triangle = sk_allocate(T, sizeof(int32_t));
    m->last_triangle = sk_allocate(T, sizeof(int32_t));
    m->triangle_count = sk_allocate(T, sizeof(int32_t));
    m->area = sk_allocate(T, sizeof(double));
    m->perimeter = sk_allocate(T, sizeof(double));
    m->bivector = sk_allocate(T * K, sizeof(double));
    m->term = sk_allocate(T, sizeof(double));
    m->version = sk_allocate_zeroed(T, sizeof(uint32_t));
    m->alive = sk_allocate(T, 1);
    int ok = m->boundary && m->chart_of && m->next_triangle && m->last_triangle && m->triangle_count && m->area &&
             m->perimeter && m->bivector && m->term && m->version && m->alive &&
             make_marks(&m->vertex_marks, m->mesh->flaps.vertex_count) &&
             make_marks(&m->seen_vertices, m->mesh->flaps.vertex_count) && make_marks(&m->chart_marks, T);
    for (size_t t = 0; ok && t < T; ++t) {
        m->chart_of[t] = (int32_t)t;
        m->next_triangle[t] = -1;
        m->last_triangle[t] = (int32_t)t;
        m->triangle_count[t] = 1;
        m->alive[t] = 1;
        triangle_bivector(m->bivector + t * m->components, &m->area[t], m->embedding, m->dimension,
                          m->mesh->flaps.triangles + 3 * t);
        m->perimeter[t] = 0.0;
        for (int k = 0; k < 3 && ok; ++k) {
            const int32_t e = m->mesh->flaps.triangle_edges[3 * t + k];
            m->perimeter[t] += m->mesh->edge_lengths[e];
            ok = append_edge(&m->boundary[t], e);
        }
    }
    m->chart_count = T;
    m->metric_sum = 0.0;
    for (size_t t = 0; ok && t < T; ++t) {
        m->term[t] = chart_term(m, (int32_t)t);
        m->metric_sum += m->term[t];
    }
    for (size_t e = 0; ok && e < m->mesh->flaps.edge_count; ++e) {
        const int32_t t0 = m->mesh->flaps.edge_triangles[2 * e], t1 = m->mesh->flaps.edge_triangles[2 * e + 1];
        merge_candidate candidate;
        if (t1 >= 0 && t0 != t1 && evaluate_merge(m, t0, t1, &candidate))
            ok = heap_push(&m->heap, candidate);
    }
    return ok;
}

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

/* Numbers the charts 0, 1, ... in order of their first triangle. */
static size_t renumber(int32_t *charts, const int32_t *labels, size_t triangle_count, int32_t *scratch)
{
    for (size_t t = 0; t < triangle_count; ++t)
        scratch[t] = -1;
    int32_t next = 0;
    for (size_t t = 0; t < triangle_count; ++t) {
        if (scratch[labels[t]] < 0)
            scratch[labels[t]] = next++;
        charts[t] = scratch[labels[t]];
    }
    return (size_t)next;
}

static int keep_merging(const merger *m, const merge_candidate *next, const sk_segment_options *options,
                        double total_area)
{
    if (options->mode == SK_SEGMENT_SEAMS)
        return 1;
    if (options->chart_count > 0 && m->chart_count <= options->chart_count)
        return 0;
    if (options->threshold > 0.0) /* a merge that lowers E_mesh is always taken */
        return next->cost <= 0.0 || !(total_area > 0.0) ||
               (m->metric_sum + next->cost) / total_area <= options->threshold;
    return options->chart_count > 0 || next->cost <= 0.0;
}

static sk_status run_merges(merger *m, const sk_segment_options *options, sk_error *error)
{
    double total_area = 0.0;
    for (size_t t = 0; t < m->mesh->flaps.triangle_count; ++t)
        total_area += m->area[t];
    while (m->heap.size > 0) {
        const merge_candidate next = heap_pop(&m->heap);
        if (!m->alive[next.a] || !m->alive[next.b] || m->version[next.a] != next.version_a ||
            m->version[next.b] != next.version_b)
            continue; /* one of the charts has changed since this candidate was costed */
        if (!keep_merging(m, &next, options, total_area))
            break;
        if (!apply_merge(m, &next))
            return sk_fail(error, SK_ERROR_MEMORY, "no memory for the merge queue (%zu charts left)", m->chart_count);
    }
    if (m->spectral.failure)
        return sk_fail(error, SK_ERROR_LAPACK, "dsyevr failed on a chart's plane fit (info %d)",
                       (int)m->spectral.failure);
    return SK_OK;
}

static sk_status check_segment_arguments(const double *embedding, size_t dimension, size_t vertex_count,
                                         const int32_t *seams, size_t seam_count, const sk_segment_options *options,
                                         sk_error *error)
{
    if (!options || !embedding || (!seams && seam_count > 0))
        return sk_fail(error, SK_ERROR_ARGUMENT, "embedding, options and a non-empty seam list must not be null");
    if (dimension < 2 || dimension > SK_SEGMENT_MAX_DIMENSION)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the embedding has %zu dimensions, expected 2 to %d", dimension,
                       SK_SEGMENT_MAX_DIMENSION);
    if (options->mode != SK_SEGMENT_GREEDY && options->mode != SK_SEGMENT_SEAMS)
        return sk_fail(error, SK_ERROR_ARGUMENT, "unknown segmentation mode %d", (int)options->mode);
    if (!(options->rho >= 0.0) || !isfinite(options->rho) || !(options->threshold >= 0.0) ||
        !isfinite(options->threshold))
        return sk_fail(error, SK_ERROR_ARGUMENT, "rho (%g) and threshold (%g) must be finite and not negative",
                       options->rho, options->threshold);
    const sk_status sized = check_embedding(embedding, dimension, vertex_count, error);
    if (sized != SK_OK)
        return sized;
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
    sk_status status = build_topology(&mesh, triangles, vertex_count, triangle_count, NULL, 0, error);
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
    free_topology(&mesh);
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

/* The mesh segmentation runs on: cut along the seams (seams then flagged per cut edge), or as given. */
typedef struct segment_mesh {
    topology mesh;
    int32_t *triangles, *source_vertex;
    double *embedding;
    unsigned char *seam_slots, *seam_edges;
} segment_mesh;

static void free_segment_mesh(segment_mesh *s)
{
    free_topology(&s->mesh);
    free(s->triangles);
    free(s->source_vertex);
    free(s->embedding);
    free(s->seam_slots);
    free(s->seam_edges);
}

static sk_status prepare_segment_mesh(segment_mesh *s, const double *embedding, size_t dimension,
                                      const int32_t *triangles, const int32_t *seams, size_t vertex_count,
                                      size_t triangle_count, size_t seam_count, sk_error *error)
{
    memset(s, 0, sizeof *s);
    if (seam_count == 0) {
        const sk_status status =
            build_topology(&s->mesh, triangles, vertex_count, triangle_count, embedding, dimension, error);
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
    status = build_topology(&s->mesh, s->triangles, cut_vertex_count, triangle_count, s->embedding, dimension, error);
    s->seam_edges = status == SK_OK ? sk_allocate_zeroed(s->mesh.flaps.edge_count + 1, 1) : NULL;
    if (status == SK_OK && !s->seam_edges)
        return sk_fail(error, SK_ERROR_MEMORY, "no memory for %zu seam flags", s->mesh.flaps.edge_count);
    for (size_t slot = 0; status == SK_OK && slot < 3 * triangle_count; ++slot)
        s->seam_edges[s->mesh.flaps.triangle_edges[slot]] |= s->seam_slots[slot];
    return status;
}

/* Seams-only mode's fast path, defined with the disc check below: 1 when every piece between the seams is a disc
 * (charts and report then filled), 0 when some piece needs merging, -1 when memory ran out. */
static int seam_pieces_are_discs(int32_t *charts, sk_segment_report *report, const segment_mesh *cut,
                                 const double *embedding, size_t dimension, double rho);

sk_status sk_segment(int32_t *charts, sk_segment_report *report, const sk_triangle_mesh *mesh,
                     const double *embedding, size_t dimension, const int32_t *seams, size_t seam_count,
                     const sk_segment_options *options, sk_error *error)
{
    if (!mesh)
        return sk_fail(error, SK_ERROR_ARGUMENT, "mesh must not be null");
    const int32_t *triangles = mesh->triangles;
    const size_t vertex_count = mesh->vertex_count, triangle_count = mesh->triangle_count;
    if (!charts)
        return sk_fail(error, SK_ERROR_ARGUMENT, "charts must not be null");
    sk_status status = check_segment_arguments(embedding, dimension, vertex_count, seams, seam_count, options, error);
    if (status != SK_OK)
        return status;
    segment_mesh cut;
    status = prepare_segment_mesh(&cut, embedding, dimension, triangles, seams, vertex_count, triangle_count,
                                  seam_count, error);
    if (status == SK_OK && options->mode == SK_SEGMENT_SEAMS) {
        /* the artist's pieces are usually discs already: then no merging (and no merge queue) is needed */
        const int fast = seam_pieces_are_discs(charts, report, &cut, cut.embedding ? cut.embedding : embedding,
                                               dimension, options->rho);
        if (fast != 0) {
            free_segment_mesh(&cut);
            return fast > 0 ? sk_succeed(error) : sk_fail(error, SK_ERROR_MEMORY, "no memory for the seam pieces");
        }
    }
    merger m;
    memset(&m, 0, sizeof m);
    m.mesh = &cut.mesh;
    if (status == SK_OK) {
        m.embedding = cut.embedding ? cut.embedding : embedding;
        m.dimension = dimension;
        m.components = dimension * (dimension - 1) / 2;
        m.rho = options->rho;
        m.seam_edges = cut.seam_edges;
        m.spectral.dimension = dimension;
        if (!start_merger(&m))
            status = sk_fail(error, SK_ERROR_MEMORY, "no memory for %zu charts", triangle_count);
    }
    if (status == SK_OK)
        status = run_merges(&m, options, error);
    if (status == SK_OK) {
        const size_t count = renumber(charts, m.chart_of, triangle_count, m.next_triangle);
        /* the artist's pieces: components across non-seam edges (m.last_triangle is free by now) */
        const long components = sk_triangle_components(m.last_triangle, &cut.mesh.flaps, cut.seam_edges);
        if (components < 0)
            status = sk_fail(error, SK_ERROR_MEMORY, "no memory to count the seam pieces");
        double total_area = 0.0;
        for (size_t t = 0; t < triangle_count; ++t)
            total_area += m.area[t] * (m.alive[t] != 0);
        if (report && status == SK_OK) {
            report->chart_count = count;
            report->mesh_metric = total_area > 0.0 ? m.metric_sum / total_area : 0.0;
            report->component_count = (size_t)components;
        }
    }
    free_merger(&m);
    free_segment_mesh(&cut);
    return status == SK_OK ? sk_succeed(error) : status;
}

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

static void free_members(chart_members *members)
{
    for (size_t c = 0; members->lists && c < members->chart_count; ++c)
        free(members->lists[c].items);
    free(members->lists);
    memset(members, 0, sizeof *members);
}

static int add_member(chart_members *members, int32_t c, int32_t t)
{
    return SK_PUSH(members->lists[c], t, 4);
}

/* Checks the chart ids' range and lists each chart's triangles. */
static sk_status collect_members(chart_members *members, const int32_t *charts, size_t triangle_count, sk_error *error)
{
    memset(members, 0, sizeof *members);
    if (!charts)
        return sk_fail(error, SK_ERROR_ARGUMENT, "charts must not be null");
    size_t count = 0;
    for (size_t t = 0; t < triangle_count; ++t) {
        if (charts[t] < 0 || (size_t)charts[t] >= triangle_count)
            return sk_fail(error, SK_ERROR_INDEX, "triangle %zu: chart %d is outside [0, %zu)", t, (int)charts[t],
                           triangle_count);
        if ((size_t)charts[t] + 1 > count)
            count = (size_t)charts[t] + 1;
    }
    members->chart_count = count;
    members->lists = sk_allocate_zeroed(count, sizeof *members->lists);
    int ok = members->lists != NULL;
    for (size_t t = 0; ok && t < triangle_count; ++t)
        ok = add_member(members, charts[t], (int32_t)t);
    return ok ? SK_OK : sk_fail(error, SK_ERROR_MEMORY, "no memory for the triangle lists of %zu charts", count);
}

typedef struct disc_scratch {
    marks vertices;  /* value: triangles, interior edge sides, boundary edges at the vertex */
    marks triangles; /* visited by the connectivity search */
    int32_t *queue;  /* triangle_count */
} disc_scratch;

static int make_disc_scratch(disc_scratch *scratch, const topology *mesh)
{
    scratch->queue = sk_allocate(mesh->flaps.triangle_count + 1, sizeof(int32_t));
    return make_marks(&scratch->vertices, mesh->flaps.vertex_count) &&
           make_marks(&scratch->triangles, mesh->flaps.triangle_count) && scratch->queue;
}

static void free_disc_scratch(disc_scratch *scratch)
{
    free_marks(&scratch->vertices);
    free_marks(&scratch->triangles);
    free(scratch->queue);
}

static size_t reachable_triangles(const topology *mesh, const int32_t *charts, const int32_t *list, disc_scratch *s)
{
    next_generation(&s->triangles, mesh->flaps.triangle_count);
    size_t head = 0, tail = 0;
    mark(&s->triangles, list[0]);
    s->queue[tail++] = list[0];
    while (head < tail) {
        const int32_t t = s->queue[head++];
        for (int k = 0; k < 3; ++k) {
            const int32_t o = sk_edge_other_triangle(&mesh->flaps, mesh->flaps.triangle_edges[3 * t + k], t);
            if (o >= 0 && charts[o] == charts[t] && mark(&s->triangles, o))
                s->queue[tail++] = o;
        }
    }
    return tail;
}

/*
 * NULL when chart c (its `count` triangles in `list`) is a topological disc, else the reason. A disc is
 * connected, has Euler characteristic V - E + F = 1 and a boundary, and each vertex has one fan of chart
 * triangles (boundary vertices exactly two boundary edges): this rules out charts touching themselves at
 * a vertex, annuli, spheres and the projective plane.
 */
static const char *disc_problem(const topology *mesh, const int32_t *charts, int32_t c, const int32_t *list,
                                size_t count, disc_scratch *s, int32_t *where)
{
    marks *v = &s->vertices;
    next_generation(v, mesh->flaps.vertex_count);
    long vertices = 0, boundary = 0, interior_sides = 0;
    for (size_t i = 0; i < count; ++i)
        for (int k = 0; k < 3; ++k) {
            const int32_t x = mesh->flaps.triangles[3 * list[i] + k];
            vertices += mark(v, x);
            ++v->value[3 * x];
        }
    for (size_t i = 0; i < count; ++i)
        for (int k = 0; k < 3; ++k) {
            const int32_t e = mesh->flaps.triangle_edges[3 * list[i] + k];
            const int32_t o = sk_edge_other_triangle(&mesh->flaps, e, list[i]);
            const int slot = o >= 0 && charts[o] == c ? 1 : 2;
            interior_sides += slot == 1;
            boundary += slot == 2;
            ++v->value[3 * mesh->flaps.edge_vertices[2 * e] + slot];
            ++v->value[3 * mesh->flaps.edge_vertices[2 * e + 1] + slot];
        }
    *where = list[0];
    if (boundary == 0)
        return "it is a closed surface";
    if (vertices - (boundary + interior_sides / 2) + (long)count != 1)
        return "its Euler characteristic is not 1";
    for (size_t i = 0; i < count; ++i)
        for (int k = 0; k < 3; ++k) {
            const int32_t x = mesh->flaps.triangles[3 * list[i] + k];
            const int32_t fans = v->value[3 * x] - v->value[3 * x + 1] / 2, edges = v->value[3 * x + 2];
            if (!(edges == 0 ? fans == 0 : edges == 2 && fans == 1)) {
                *where = x;
                return "it touches itself at a vertex";
            }
        }
    if (reachable_triangles(mesh, charts, list, s) != count)
        return "it is not connected";
    return NULL;
}

static sk_status check_discs(const topology *mesh, const int32_t *charts, const chart_members *members,
                             disc_scratch *scratch, sk_error *error)
{
    for (size_t c = 0; c < members->chart_count; ++c) {
        int32_t where;
        const char *problem = members->lists[c].size ? disc_problem(mesh, charts, (int32_t)c, members->lists[c].items,
                                                               members->lists[c].size, scratch, &where)
                                               : NULL;
        if (problem)
            return sk_fail(error, SK_ERROR_ARGUMENT, "chart %zu is not a disc: %s (near %s %d)", c, problem,
                           strstr(problem, "vertex") ? "vertex" : "triangle", (int)where);
    }
    return SK_OK;
}

/* E_mesh (eq. 5.5) of charts given per triangle (ids 0..count-1): per chart its area, summed bivector and
 * perimeter (edges whose other side is another chart or nothing). Returns -1 when memory ran out. */
static double charts_mesh_metric(const topology *mesh, const int32_t *charts, size_t count, const double *embedding,
                                 size_t dimension, double rho)
{
    const size_t components = dimension * (dimension - 1) / 2;
    chart_shape *shapes = sk_allocate_zeroed(count, sizeof *shapes);
    if (!shapes)
        return -1.0;
    for (size_t t = 0; t < mesh->flaps.triangle_count; ++t) {
        chart_shape *shape = &shapes[charts[t]];
        double bivector[MAX_COMPONENTS], area;
        triangle_bivector(bivector, &area, embedding, dimension, mesh->flaps.triangles + 3 * t);
        shape->area += area;
        for (size_t k = 0; k < components; ++k)
            shape->bivector[k] += bivector[k];
        for (int k = 0; k < 3; ++k) {
            const int32_t e = mesh->flaps.triangle_edges[3 * t + k], o = sk_edge_other_triangle(&mesh->flaps, e, (int32_t)t);
            if (o < 0 || charts[o] != charts[t])
                shape->perimeter += mesh->edge_lengths[e];
        }
    }
    spectral_workspace spectral;
    memset(&spectral, 0, sizeof spectral);
    spectral.dimension = dimension;
    double sum = 0.0, total_area = 0.0;
    for (size_t c = 0; c < count; ++c) {
        sum += weighted_metric(shapes[c].area, shapes[c].perimeter, max_projected_area(&spectral, shapes[c].bivector),
                               rho);
        total_area += shapes[c].area;
    }
    free(shapes);
    return total_area > 0.0 ? sum / total_area : 0.0;
}

static int seam_pieces_are_discs(int32_t *charts, sk_segment_report *report, const segment_mesh *cut,
                                 const double *embedding, size_t dimension, double rho)
{
    const topology *mesh = &cut->mesh;
    const size_t T = mesh->flaps.triangle_count;
    chart_members members;
    memset(&members, 0, sizeof members);
    disc_scratch discs;
    memset(&discs, 0, sizeof discs);
    int result = -1;
    const long pieces = make_disc_scratch(&discs, mesh) ? sk_triangle_components(charts, &mesh->flaps, cut->seam_edges)
                                                        : -1;
    if (pieces >= 0) {
        const size_t count = (size_t)pieces; /* the pieces between the seams, numbered as charts are */
        if (collect_members(&members, charts, T, NULL) == SK_OK) {
            result = 1;
            for (size_t c = 0; c < count && result == 1; ++c) {
                int32_t where;
                if (disc_problem(mesh, charts, (int32_t)c, members.lists[c].items, members.lists[c].size, &discs, &where))
                    result = 0;
            }
            const double metric = result == 1 ? charts_mesh_metric(mesh, charts, count, embedding, dimension, rho) : 0;
            if (metric < 0.0)
                result = -1;
            if (result == 1 && report) {
                report->chart_count = count;
                report->mesh_metric = metric;
                report->component_count = count;
            }
        }
    }
    free_members(&members);
    free_disc_scratch(&discs);
    return result;
}

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

static sk_status compute_corners(unsigned char *corners, const topology *mesh, const int32_t *charts,
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
    sk_status status = build_topology(&topo, triangles, vertex_count, triangle_count, embedding, dimension, error);
    if (status == SK_OK)
        status = collect_members(&members, charts, triangle_count, error);
    if (status == SK_OK && !make_disc_scratch(&scratch, &topo))
        status = sk_fail(error, SK_ERROR_MEMORY, "no memory to check the charts");
    if (status == SK_OK)
        status = check_discs(&topo, charts, &members, &scratch, error);
    if (status == SK_OK)
        status = compute_corners(corners, &topo, charts, &members, error);
    free_disc_scratch(&scratch);
    free_members(&members);
    free_topology(&topo);
    return status == SK_OK ? sk_succeed(error) : status;
}

/* ---------------------------------------------------------------------------------------------
 * Edge straightening (section 5.2.3)
 * ------------------------------------------------------------------------------------------- */


typedef struct straightener {
    const topology *mesh;
    int32_t *charts;
    const unsigned char *corners;
    const double *embedding;
    size_t dimension;
    double rho, ratio;
    chart_members members;
    disc_scratch discs;
    unsigned char *border;          /* per vertex: on the mesh border */
    int32_t *path_of_edge;          /* per edge: the boundary path it is on, or -1 */
    int32_t *path_of_vertex;        /* per vertex: the path it is inside of (not an end), or -1 */
    int32_t *path_offsets, *path_vertices; /* CSR of the paths' vertices as found */
    size_t path_count;
    marks old_path, new_path_edges, side, reached;
    double *distance;               /* per vertex, valid while `reached` marks it */
    int32_t *previous_edge;         /* per vertex on the search tree */
    sk_vertex_distance *heap;       /* Dijkstra's queue (lazy deletion), up to 2 * edges + 1 entries */
    int32_t *new_path, *saved, *union_list; /* edges of the candidate path; labels to restore; L and R's triangles */
    spectral_workspace spectral;
} straightener;

static void free_straightener(straightener *s)
{
    free_members(&s->members);
    free_disc_scratch(&s->discs);
    free(s->border);
    free(s->path_of_edge);
    free(s->path_of_vertex);
    free(s->path_offsets);
    free(s->path_vertices);
    free_marks(&s->old_path);
    free_marks(&s->new_path_edges);
    free_marks(&s->side);
    free_marks(&s->reached);
    free(s->distance);
    free(s->previous_edge);
    free(s->heap);
    free(s->new_path);
    free(s->saved);
    free(s->union_list);
}

static int32_t next_path_edge(const straightener *s, int32_t v, int32_t previous, int32_t left, int32_t right)
{
    const topology *mesh = s->mesh;
    for (int32_t k = mesh->flaps.vertex_edge_offsets[v]; k < mesh->flaps.vertex_edge_offsets[v + 1]; ++k) {
        const int32_t e = mesh->flaps.vertex_edges[k], t1 = mesh->flaps.edge_triangles[2 * e + 1];
        if (e == previous || t1 < 0)
            continue;
        const int32_t a = s->charts[mesh->flaps.edge_triangles[2 * e]], b = s->charts[t1];
        if ((a == left && b == right) || (a == right && b == left))
            return e;
    }
    return -1;
}

/* Walks from v away along e until a corner; writes the vertices passed (after v) and returns their count. */
static size_t walk_to_corner(const straightener *s, int32_t v, int32_t e, int32_t left, int32_t right, int32_t *out)
{
    size_t n = 0;
    const int32_t start = v;
    while (n < s->mesh->flaps.vertex_count) {
        v = sk_edge_other_vertex(&s->mesh->flaps, e, v);
        out[n++] = v;
        if (s->corners[v] || v == start)
            break;
        e = next_path_edge(s, v, e, left, right);
        if (e < 0)
            break;
    }
    return n;
}

/* Splits every boundary between two charts into paths from corner to corner. */
static int find_paths(straightener *s)
{
    const topology *mesh = s->mesh;
    const size_t V = mesh->flaps.vertex_count;
    int32_t *backward = sk_allocate(V + 1, sizeof *backward), *forward = sk_allocate(V + 1, sizeof *forward);
    s->path_offsets = sk_allocate(mesh->flaps.edge_count + 2, sizeof(int32_t));
    s->path_vertices = sk_allocate(2 * mesh->flaps.edge_count + 1, sizeof(int32_t));
    const int ok = backward && forward && s->path_offsets && s->path_vertices;
    size_t used = 0;
    s->path_count = 0;
    for (size_t e = 0; ok && e < mesh->flaps.edge_count; ++e) {
        const int32_t t1 = mesh->flaps.edge_triangles[2 * e + 1];
        if (t1 < 0 || s->path_of_edge[e] >= 0 || s->charts[mesh->flaps.edge_triangles[2 * e]] == s->charts[t1])
            continue;
        const int32_t left = s->charts[mesh->flaps.edge_triangles[2 * e]], right = s->charts[t1];
        /* The path through e = (u, v): back from v past u to a corner, then on from u past v to a corner
         * (or round to u again on a loop without corners). */
        const int32_t u = mesh->flaps.edge_vertices[2 * e], v = mesh->flaps.edge_vertices[2 * e + 1];
        const size_t ahead = walk_to_corner(s, u, (int32_t)e, left, right, forward);
        const int closed = forward[ahead - 1] == u;
        const size_t back = closed ? 1 : walk_to_corner(s, v, (int32_t)e, left, right, backward);
        if (closed)
            backward[0] = u;
        const int32_t p = (int32_t)s->path_count++;
        s->path_offsets[p] = (int32_t)used;
        for (size_t k = back; k-- > 0;)
            s->path_vertices[used++] = backward[k];
        for (size_t k = 0; k < ahead; ++k)
            s->path_vertices[used++] = forward[k];
        for (int32_t k = s->path_offsets[p]; k + 1 < (int32_t)used; ++k) {
            const int32_t edge = sk_edge_between(&mesh->flaps, s->path_vertices[k], s->path_vertices[k + 1]);
            if (edge >= 0)
                s->path_of_edge[edge] = p;
            if (k > s->path_offsets[p])
                s->path_of_vertex[s->path_vertices[k]] = p;
        }
    }
    if (ok)
        s->path_offsets[s->path_count] = (int32_t)used;
    free(backward);
    free(forward);
    return ok;
}

static int in_pair(const straightener *s, int32_t t, int32_t left, int32_t right)
{
    return t >= 0 && (s->charts[t] == left || s->charts[t] == right);
}

/* Whether the new boundary of path p may pass through v: inside the two charts, or on p itself. */
static int vertex_allowed(const straightener *s, int32_t v, int32_t p, int32_t left, int32_t right, int constrained)
{
    if (s->corners[v] || s->border[v] || (s->path_of_vertex[v] >= 0 && s->path_of_vertex[v] != p))
        return 0;
    if (constrained && !marked(&s->old_path, v))
        return 0;
    const topology *mesh = s->mesh;
    for (int32_t k = mesh->flaps.vertex_triangle_offsets[v]; k < mesh->flaps.vertex_triangle_offsets[v + 1]; ++k)
        if (!in_pair(s, mesh->flaps.vertex_triangles[k], left, right))
            return 0;
    return 1;
}

/* An edge inside one of the two charts, or on p: never on another boundary. */
static int edge_allowed(const straightener *s, int32_t e, int32_t p, int32_t left, int32_t right)
{
    const int32_t t0 = s->mesh->flaps.edge_triangles[2 * e], t1 = s->mesh->flaps.edge_triangles[2 * e + 1];
    return in_pair(s, t0, left, right) && in_pair(s, t1, left, right) &&
           (s->charts[t0] == s->charts[t1] || s->path_of_edge[e] == p);
}

/* Dijkstra from `from` to `to`; the path's edges go to s->new_path. Returns their count (0: unreachable). */
static size_t shortest_path(straightener *s, int32_t p, int32_t from, int32_t to, int32_t left, int32_t right,
                            int constrained)
{
    const topology *mesh = s->mesh;
    marks *reached = &s->reached;
    next_generation(reached, mesh->flaps.vertex_count);
    size_t size = 0;
    mark(reached, from);
    s->distance[from] = 0.0;
    s->previous_edge[from] = -1;
    sk_heap_push(s->heap, &size, (sk_vertex_distance){0.0, from});
    while (size > 0) {
        const sk_vertex_distance top = sk_heap_pop(s->heap, &size);
        const int32_t v = top.vertex;
        if (top.distance > s->distance[v] || reached->value[3 * v] /* settled */)
            continue;
        reached->value[3 * v] = 1;
        if (v == to)
            break;
        for (int32_t k = mesh->flaps.vertex_edge_offsets[v]; k < mesh->flaps.vertex_edge_offsets[v + 1]; ++k) {
            const int32_t e = mesh->flaps.vertex_edges[k], w = sk_edge_other_vertex(&mesh->flaps, e, v);
            const double candidate = top.distance + mesh->edge_lengths[e];
            if ((marked(reached, w) && (reached->value[3 * w] || s->distance[w] <= candidate)) ||
                !edge_allowed(s, e, p, left, right) || (w != to && !vertex_allowed(s, w, p, left, right, constrained)))
                continue;
            mark(reached, w);
            s->distance[w] = candidate;
            s->previous_edge[w] = e;
            sk_heap_push(s->heap, &size, (sk_vertex_distance){candidate, w});
        }
    }
    if (!marked(reached, to) || !reached->value[3 * to])
        return 0;
    size_t count = 0;
    for (int32_t v = to; v != from; v = sk_edge_other_vertex(&mesh->flaps, s->previous_edge[v], v))
        s->new_path[count++] = s->previous_edge[v];
    return count;
}

static int rebuild_members(straightener *s, int32_t left, int32_t right, size_t count)
{
    s->members.lists[left].size = s->members.lists[right].size = 0;
    for (size_t i = 0; i < count; ++i)
        if (!add_member(&s->members, s->charts[s->union_list[i]], s->union_list[i]))
            return 0;
    return 1;
}

static int label_side(marks *side, int32_t t, int32_t label)
{
    if (mark(side, t)) {
        side->value[3 * t] = label;
        return 1;
    }
    return side->value[3 * t] == label ? 0 : -1;
}

/*
 * Labels the two charts' triangles by flood fill from the rest of each chart's boundary, never crossing
 * the new path or another boundary. 1 when every triangle is reached from exactly one side.
 */
static int flood_sides(straightener *s, int32_t p, int32_t left, int32_t right, size_t count)
{
    const topology *mesh = s->mesh;
    marks *side = &s->side;
    next_generation(side, mesh->flaps.triangle_count);
    int32_t *queue = s->discs.queue;
    size_t head = 0, tail = 0;
    for (size_t i = 0; i < count; ++i) {
        const int32_t t = s->union_list[i], c = s->charts[t];
        for (int k = 0; k < 3; ++k) {
            const int32_t e = mesh->flaps.triangle_edges[3 * t + k];
            if (!on_chart_boundary(mesh, s->charts, e, c) || s->path_of_edge[e] == p)
                continue;
            const int labelled = label_side(side, t, c == left ? 1 : 2);
            if (labelled < 0)
                return 0;
            if (labelled)
                queue[tail++] = t;
        }
    }
    while (head < tail) {
        const int32_t t = queue[head++];
        for (int k = 0; k < 3; ++k) {
            const int32_t e = mesh->flaps.triangle_edges[3 * t + k], o = sk_edge_other_triangle(&mesh->flaps, e, t);
            if (!in_pair(s, o, left, right) || marked(&s->new_path_edges, e) ||
                (s->charts[o] != s->charts[t] && s->path_of_edge[e] != p))
                continue;
            const int labelled = label_side(side, o, side->value[3 * t]);
            if (labelled < 0)
                return 0;
            if (labelled)
                queue[tail++] = o;
        }
    }
    return tail == count;
}

static void restore_labels(straightener *s, int32_t left, int32_t right, size_t count)
{
    for (size_t i = 0; i < count; ++i)
        s->charts[s->union_list[i]] = s->saved[i];
    rebuild_members(s, left, right, count); /* cannot fail: the lists only shrink back */
}

/* Moves the boundary between left and right onto the path in s->new_path; 1 when both stay discs. */
static int move_boundary(straightener *s, int32_t p, int32_t left, int32_t right, size_t path_edges, int *failed)
{
    const size_t count = s->members.lists[left].size + s->members.lists[right].size;
    memcpy(s->union_list, s->members.lists[left].items, s->members.lists[left].size * sizeof(int32_t));
    memcpy(s->union_list + s->members.lists[left].size, s->members.lists[right].items,
           s->members.lists[right].size * sizeof(int32_t));
    next_generation(&s->new_path_edges, s->mesh->flaps.edge_count);
    for (size_t k = 0; k < path_edges; ++k)
        mark(&s->new_path_edges, s->new_path[k]);
    if (!flood_sides(s, p, left, right, count))
        return 0;
    for (size_t i = 0; i < count; ++i) {
        const int32_t t = s->union_list[i];
        s->saved[i] = s->charts[t];
        s->charts[t] = s->side.value[3 * t] == 1 ? left : right;
    }
    if (!rebuild_members(s, left, right, count)) {
        *failed = 1;
        return 0;
    }
    int32_t where;
    if (!s->members.lists[left].size || !s->members.lists[right].size ||
        disc_problem(s->mesh, s->charts, left, s->members.lists[left].items, s->members.lists[left].size, &s->discs, &where) ||
        disc_problem(s->mesh, s->charts, right, s->members.lists[right].items, s->members.lists[right].size, &s->discs,
                     &where)) {
        restore_labels(s, left, right, count);
        return 0;
    }
    return 1;
}

static double chart_metric(straightener *s, int32_t c)
{
    const size_t components = s->dimension * (s->dimension - 1) / 2;
    double sum[MAX_COMPONENTS] = {0}, bivector[MAX_COMPONENTS], area = 0.0, perimeter = 0.0;
    for (size_t i = 0; i < s->members.lists[c].size; ++i) {
        const int32_t t = s->members.lists[c].items[i];
        double triangle_area;
        triangle_bivector(bivector, &triangle_area, s->embedding, s->dimension, s->mesh->flaps.triangles + 3 * t);
        area += triangle_area;
        for (size_t k = 0; k < components; ++k)
            sum[k] += bivector[k];
        for (int k = 0; k < 3; ++k) {
            const int32_t e = s->mesh->flaps.triangle_edges[3 * t + k];
            if (chart_across(s->mesh, s->charts, e, t) != c)
                perimeter += s->mesh->edge_lengths[e];
        }
    }
    return combined_metric(area, perimeter, max_projected_area(&s->spectral, sum), s->rho);
}

/* Records path p's new route in the per-edge and per-vertex path maps. */
static void commit_path(straightener *s, int32_t p, int32_t to, size_t path_edges)
{
    const int32_t *old = s->path_vertices + s->path_offsets[p];
    const size_t old_count = (size_t)(s->path_offsets[p + 1] - s->path_offsets[p]);
    for (size_t k = 0; k + 1 < old_count; ++k) {
        const int32_t e = sk_edge_between(&s->mesh->flaps, old[k], old[k + 1]);
        if (e >= 0)
            s->path_of_edge[e] = -1;
        if (k > 0)
            s->path_of_vertex[old[k]] = -1;
    }
    int32_t v = to;
    for (size_t k = 0; k < path_edges; ++k) {
        s->path_of_edge[s->new_path[k]] = p;
        if (k > 0)
            s->path_of_vertex[v] = p;
        v = sk_edge_other_vertex(&s->mesh->flaps, s->new_path[k], v);
    }
}

static int same_as_old(const straightener *s, int32_t p, size_t path_edges)
{
    if (path_edges + 1 != (size_t)(s->path_offsets[p + 1] - s->path_offsets[p]))
        return 0;
    for (size_t k = 0; k < path_edges; ++k)
        if (s->path_of_edge[s->new_path[k]] != p)
            return 0;
    return 1;
}

typedef enum path_outcome { PATH_KEPT, PATH_SHORTEST, PATH_CONSTRAINED, PATH_NO_MEMORY } path_outcome;

static path_outcome straighten_path(straightener *s, int32_t p)
{
    const int32_t *old = s->path_vertices + s->path_offsets[p];
    const size_t old_count = (size_t)(s->path_offsets[p + 1] - s->path_offsets[p]);
    const int32_t from = old[0], to = old[old_count - 1];
    const int32_t first_edge = old_count >= 2 ? sk_edge_between(&s->mesh->flaps, old[0], old[1]) : -1;
    if (from == to || first_edge < 0)
        return PATH_KEPT;
    const int32_t left = s->charts[s->mesh->flaps.edge_triangles[2 * first_edge]];
    const int32_t right = s->charts[s->mesh->flaps.edge_triangles[2 * first_edge + 1]];
    const double left_before = chart_metric(s, left), right_before = chart_metric(s, right);
    next_generation(&s->old_path, s->mesh->flaps.vertex_count);
    for (size_t k = 0; k < old_count; ++k)
        mark(&s->old_path, old[k]);
    int failed = 0;
    size_t edges = shortest_path(s, p, from, to, left, right, 0);
    if (edges && !same_as_old(s, p, edges) && move_boundary(s, p, left, right, edges, &failed)) {
        if (chart_metric(s, left) <= s->ratio * left_before && chart_metric(s, right) <= s->ratio * right_before) {
            commit_path(s, p, to, edges);
            return PATH_SHORTEST;
        }
        restore_labels(s, left, right, s->members.lists[left].size + s->members.lists[right].size);
    }
    edges = failed ? 0 : shortest_path(s, p, from, to, left, right, 1);
    if (edges && !same_as_old(s, p, edges) && move_boundary(s, p, left, right, edges, &failed)) {
        commit_path(s, p, to, edges);
        return PATH_CONSTRAINED;
    }
    return failed ? PATH_NO_MEMORY : PATH_KEPT;
}

static int start_straightener(straightener *s)
{
    const topology *mesh = s->mesh;
    const size_t V = mesh->flaps.vertex_count, T = mesh->flaps.triangle_count, E = mesh->flaps.edge_count;
    s->border = sk_allocate(V + 1, 1);
    s->path_of_edge = sk_allocate(E + 1, sizeof(int32_t));
    s->path_of_vertex = sk_allocate(V + 1, sizeof(int32_t));
    s->distance = sk_allocate(V + 1, sizeof(double));
    s->previous_edge = sk_allocate(V + 1, sizeof(int32_t));
    s->heap = sk_allocate(2 * E + 2, sizeof(sk_vertex_distance));
    s->new_path = sk_allocate(V + 1, sizeof(int32_t));
    s->saved = sk_allocate(T + 1, sizeof(int32_t));
    s->union_list = sk_allocate(T + 1, sizeof(int32_t));
    if (!s->border || !s->path_of_edge || !s->path_of_vertex || !s->distance || !s->previous_edge || !s->heap ||
        !s->new_path || !s->saved || !s->union_list || !make_marks(&s->old_path, V) ||
        !make_marks(&s->new_path_edges, E) || !make_marks(&s->side, T) || !make_marks(&s->reached, V))
        return 0;
    for (size_t v = 0; v < V; ++v) {
        s->border[v] = (unsigned char)sk_is_border_vertex(&mesh->flaps, (int32_t)v);
        s->path_of_vertex[v] = -1;
    }
    for (size_t e = 0; e < E; ++e)
        s->path_of_edge[e] = -1;
    return find_paths(s);
}

static sk_status run_straightening(straightener *s, sk_straighten_report *report, sk_error *error)
{
    sk_straighten_report counts = {s->path_count, 0, 0, 0};
    for (size_t p = 0; p < s->path_count; ++p) {
        const path_outcome outcome = straighten_path(s, (int32_t)p);
        if (outcome == PATH_NO_MEMORY)
            return sk_fail(error, SK_ERROR_MEMORY, "no memory to straighten boundary path %zu", p);
        counts.shortest += outcome == PATH_SHORTEST;
        counts.constrained += outcome == PATH_CONSTRAINED;
        counts.kept += outcome == PATH_KEPT;
    }
    if (s->spectral.failure)
        return sk_fail(error, SK_ERROR_LAPACK, "dsyevr failed on a chart's plane fit (info %d)",
                       (int)s->spectral.failure);
    if (report)
        *report = counts;
    return SK_OK;
}

sk_status sk_straighten_charts(int32_t *charts, unsigned char *corners, sk_straighten_report *report,
                               const sk_triangle_mesh *mesh, const double *embedding, size_t dimension,
                               const sk_straighten_options *options, sk_error *error)
{
    if (!options)
        return sk_fail(error, SK_ERROR_ARGUMENT, "options must not be null");
    const double ratio = options->ratio, rho = options->rho;
    if (!mesh)
        return sk_fail(error, SK_ERROR_ARGUMENT, "mesh must not be null");
    const int32_t *triangles = mesh->triangles;
    const size_t vertex_count = mesh->vertex_count, triangle_count = mesh->triangle_count;
    if (!corners || !embedding)
        return sk_fail(error, SK_ERROR_ARGUMENT, "corners and embedding must not be null");
    if (!(ratio >= 1.0) || !isfinite(ratio) || !(rho >= 0.0) || !isfinite(rho))
        return sk_fail(error, SK_ERROR_ARGUMENT, "ratio (%g) must be at least 1 and rho (%g) not negative", ratio,
                       rho);
    if (dimension < 2 || dimension > SK_SEGMENT_MAX_DIMENSION)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the embedding has %zu dimensions, expected 2 to %d", dimension,
                       SK_SEGMENT_MAX_DIMENSION);
    const sk_status sized = check_embedding(embedding, dimension, vertex_count, error);
    if (sized != SK_OK)
        return sized;
    topology topo;
    straightener s;
    memset(&s, 0, sizeof s);
    sk_status status = build_topology(&topo, triangles, vertex_count, triangle_count, embedding, dimension, error);
    if (status == SK_OK)
        status = collect_members(&s.members, charts, triangle_count, error);
    if (status == SK_OK && !make_disc_scratch(&s.discs, &topo))
        status = sk_fail(error, SK_ERROR_MEMORY, "no memory to check the charts");
    if (status == SK_OK)
        status = check_discs(&topo, charts, &s.members, &s.discs, error);
    if (status == SK_OK)
        status = compute_corners(corners, &topo, charts, &s.members, error);
    if (status == SK_OK) {
        s.mesh = &topo;
        s.charts = charts;
        s.corners = corners;
        s.embedding = embedding;
        s.dimension = dimension;
        s.rho = rho;
        s.ratio = ratio;
        s.spectral.dimension = dimension;
        if (!start_straightener(&s))
            status = sk_fail(error, SK_ERROR_MEMORY, "no memory to straighten %zu triangles", triangle_count);
    }
    if (status == SK_OK)
        status = run_straightening(&s, report, error);
    free_straightener(&s);
    free_topology(&topo);
    return status == SK_OK ? sk_succeed(error) : status;
}
