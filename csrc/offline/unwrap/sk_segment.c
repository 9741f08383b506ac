/*
 * Segmentation into disc charts (Merry 2007, section 5.2): greedy chart merging with the combined
 * area-ratio and compactness metric (Garland et al. 2001, Sander et al. 2001).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_charts.h"

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

static int cheaper(const void *a, const void *b)
{
    return ((const merge_candidate *)a)->cost < ((const merge_candidate *)b)->cost;
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
    const double after = sk_weighted_metric(area, perimeter, sk_max_projected_area(&m->spectral, merged), m->rho);
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
            !SK_HEAP_PUSH(m->heap, candidate, cheaper))
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
    return sk_weighted_metric(m->area[c], m->perimeter[c], sk_max_projected_area(&m->spectral, m->bivector + c * m->components),
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
    SK_FREE_ALL(m->boundary, m->chart_of, m->next_triangle, m->last_triangle, m->triangle_count, m->area,
                m->perimeter, m->bivector, m->term, m->version, m->alive, m->heap.items);
    sk_free_marks(&m->vertex_marks);
    sk_free_marks(&m->seen_vertices);
    sk_free_marks(&m->chart_marks);
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
             sk_make_marks(&m->vertex_marks, m->mesh->flaps.vertex_count) &&
             sk_make_marks(&m->seen_vertices, m->mesh->flaps.vertex_count) && sk_make_marks(&m->chart_marks, T);
    for (size_t t = 0; ok && t < T; ++t) {
        m->chart_of[t] = (int32_t)t;
        m->next_triangle[t] = -1;
        m->last_triangle[t] = (int32_t)t;
        m->triangle_count[t] = 1;
        m->alive[t] = 1;
        sk_triangle_bivector(m->bivector + t * m->components, &m->area[t], m->embedding, m->dimension,
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
            ok = SK_HEAP_PUSH(m->heap, candidate, cheaper);
    }
    return ok;
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
        merge_candidate next;
        SK_HEAP_POP(next, m->heap, cheaper);
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
    const sk_status sized = sk_check_embedding(embedding, dimension, vertex_count, error);
    if (sized != SK_OK)
        return sized;
    return SK_OK;
}

/*
 * Seams-only mode's fast path: 1 when every piece between the seams is a disc (charts and report then
 * filled), 0 when some piece needs merging, -1 when memory ran out.
 */
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
    const long pieces = sk_make_disc_scratch(&discs, mesh) ? sk_triangle_components(charts, &mesh->flaps, cut->seam_edges)
                                                        : -1;
    if (pieces >= 0) {
        const size_t count = (size_t)pieces; /* the pieces between the seams, numbered as charts are */
        if (sk_collect_members(&members, charts, T, NULL) == SK_OK) {
            result = 1;
            for (size_t c = 0; c < count && result == 1; ++c) {
                int32_t where;
                if (sk_disc_problem(mesh, charts, (int32_t)c, members.lists[c].items, members.lists[c].size, &discs, &where))
                    result = 0;
            }
            const double metric = result == 1 ? sk_charts_mesh_metric(mesh, charts, count, embedding, dimension, rho) : 0;
            if (metric < 0.0)
                result = -1;
            if (result == 1 && report) {
                report->chart_count = count;
                report->mesh_metric = metric;
                report->component_count = count;
            }
        }
    }
    sk_free_members(&members);
    sk_free_disc_scratch(&discs);
    return result;
}

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
    status = sk_prepare_segment_mesh(&cut, embedding, dimension, triangles, seams, vertex_count, triangle_count,
                                  seam_count, error);
    if (status == SK_OK && options->mode == SK_SEGMENT_SEAMS) {
        /* the artist's pieces are usually discs already: then no merging (and no merge queue) is needed */
        const int fast = seam_pieces_are_discs(charts, report, &cut, cut.embedding ? cut.embedding : embedding,
                                               dimension, options->rho);
        if (fast != 0) {
            sk_free_segment_mesh(&cut);
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
    sk_free_segment_mesh(&cut);
    return status == SK_OK ? sk_succeed(error) : status;
}
