/* Edge straightening (Merry 2007, section 5.2.3): chart boundaries replaced by shortest paths between corners. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_charts.h"

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
    sk_free_members(&s->members);
    sk_free_disc_scratch(&s->discs);
    SK_FREE_ALL(s->border, s->path_of_edge, s->path_of_vertex, s->path_offsets, s->path_vertices, s->distance,
                s->previous_edge, s->heap, s->new_path, s->saved, s->union_list);
    sk_free_marks(&s->old_path);
    sk_free_marks(&s->new_path_edges);
    sk_free_marks(&s->side);
    sk_free_marks(&s->reached);
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
        sk_disc_problem(s->mesh, s->charts, left, s->members.lists[left].items, s->members.lists[left].size, &s->discs, &where) ||
        sk_disc_problem(s->mesh, s->charts, right, s->members.lists[right].items, s->members.lists[right].size, &s->discs,
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
        sk_triangle_bivector(bivector, &triangle_area, s->embedding, s->dimension, s->mesh->flaps.triangles + 3 * t);
        area += triangle_area;
        for (size_t k = 0; k < components; ++k)
            sum[k] += bivector[k];
        for (int k = 0; k < 3; ++k) {
            const int32_t e = s->mesh->flaps.triangle_edges[3 * t + k];
            if (chart_across(s->mesh, s->charts, e, t) != c)
                perimeter += s->mesh->edge_lengths[e];
        }
    }
    return sk_combined_metric(area, perimeter, sk_max_projected_area(&s->spectral, sum), s->rho);
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
        !s->new_path || !s->saved || !s->union_list || !sk_make_marks(&s->old_path, V) ||
        !sk_make_marks(&s->new_path_edges, E) || !sk_make_marks(&s->side, T) || !sk_make_marks(&s->reached, V))
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
    const sk_status sized = sk_check_embedding(embedding, dimension, vertex_count, error);
    if (sized != SK_OK)
        return sized;
    topology topo;
    straightener s;
    memset(&s, 0, sizeof s);
    sk_status status = sk_build_topology(&topo, triangles, vertex_count, triangle_count, embedding, dimension, error);
    if (status == SK_OK)
        status = sk_collect_members(&s.members, charts, triangle_count, error);
    if (status == SK_OK && !sk_make_disc_scratch(&s.discs, &topo))
        status = sk_fail(error, SK_ERROR_MEMORY, "no memory to check the charts");
    if (status == SK_OK)
        status = sk_check_discs(&topo, charts, &s.members, &s.discs, error);
    if (status == SK_OK)
        status = sk_compute_corners(corners, &topo, charts, &s.members, error);
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
    sk_free_topology(&topo);
    return status == SK_OK ? sk_succeed(error) : status;
}
