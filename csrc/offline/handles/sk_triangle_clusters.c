/*
 * Hierarchical triangle clustering for a handle rig's proxy bones (Feng 2010, section 2.3, after Wang et al.
 * 2007): every triangle starts as its own cluster and the touching pair whose union is carried worst by one rigid
 * motion per example is merged last. A cluster's error is its best rigid motion's vertex prediction error plus
 * edge_weight times its edge prediction error (each triangle edge rotated by the same rotation: orientation and
 * length both count), so the merge cost E(A u B) - E(A) - E(B) is the thesis' "vertex prediction errors ... but
 * also edge prediction errors". Both errors are sums over the cluster's triangle corners and edges, which merge by
 * adding: a cluster keeps the sums that fix its Kabsch fit per example and no pass over its triangles is needed.
 * The whole merge order (a dendrogram) is returned, so any cluster count is a cut of one run.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_internal.h"
#include "sk_math.h"

/* Per cluster: count, rest sum (3), rest spread (vertex + weighted edge squares), then per example: example sum
 * (3), example squares (vertex + weighted edge), cross matrix sum y x^T + w e' e^T (9). */
#define SK_CLUSTER_FIXED 5
#define SK_CLUSTER_PER_EXAMPLE 13
/* Merges between progress reports (and cancel checks). */
#define SK_CLUSTER_PROGRESS_EVERY 256

typedef struct merge_candidate {
    double cost;
    int32_t keep, gone;
    uint32_t keep_stamp, gone_stamp;
} merge_candidate;

typedef struct neighbour_list {
    int32_t *items;
    size_t size, capacity;
} neighbour_list;

typedef struct candidate_heap {
    merge_candidate *items;
    size_t size, capacity;
} candidate_heap;

typedef struct clustering {
    size_t cluster_count, example_count, stride;
    double *statistics; /* stride per cluster */
    double *own_error;  /* each live cluster's error */
    double *scratch;    /* one union's statistics */
    uint32_t *stamp;    /* bumped when a cluster changes: older candidates naming it are stale */
    unsigned char *alive;
    size_t *mark;       /* de-duplicates neighbour lists: the merge that last saw a cluster */
    neighbour_list *neighbours;
    candidate_heap heap;
} clustering;

static int cheaper(const void *a, const void *b)
{
    const merge_candidate *x = a, *y = b;
    if (x->cost != y->cost)
        return x->cost < y->cost;
    return x->keep != y->keep ? x->keep < y->keep : x->gone < y->gone; /* a total order: reproducible merges */
}

/* The rigid-fit error of a cluster's statistics, summed over the examples (never negative). */
static double cluster_error(const double *s, size_t example_count)
{
    const double n = s[0], *sx = s + 1;
    double total = 0;
    for (size_t e = 0; e < example_count; ++e) {
        const double *p = s + SK_CLUSTER_FIXED + e * SK_CLUSTER_PER_EXAMPLE, *sy = p, *cross = p + 4;
        double centred[9], singular[3];
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c)
                centred[3 * r + c] = cross[3 * r + c] - sy[r] * sx[c] / n;
        sk_svd3(singular, NULL, NULL, centred);
        const double sign = sk_determinant3(centred) < 0 ? -1.0 : 1.0;
        const double spread = s[4] - (sx[0] * sx[0] + sx[1] * sx[1] + sx[2] * sx[2]) / n + p[3] -
                              (sy[0] * sy[0] + sy[1] * sy[1] + sy[2] * sy[2]) / n;
        const double error = spread - 2 * (singular[0] + singular[1] + sign * singular[2]);
        total += error > 0 ? error : 0;
    }
    return total;
}

static double *statistics_of(const clustering *c, int32_t cluster)
{
    return c->statistics + (size_t)cluster * c->stride;
}

/* How much worse one rigid motion per example carries a u b than each its own. */
static double merge_cost(clustering *c, int32_t a, int32_t b)
{
    const double *x = statistics_of(c, a), *y = statistics_of(c, b);
    for (size_t i = 0; i < c->stride; ++i)
        c->scratch[i] = x[i] + y[i];
    return cluster_error(c->scratch, c->example_count) - c->own_error[a] - c->own_error[b];
}

static int push_candidate(clustering *c, int32_t a, int32_t b)
{
    merge_candidate candidate = {merge_cost(c, a, b), a < b ? a : b, a < b ? b : a, 0, 0};
    candidate.keep_stamp = c->stamp[candidate.keep];
    candidate.gone_stamp = c->stamp[candidate.gone];
    return SK_HEAP_PUSH(c->heap, candidate, cheaper);
}

static int add_neighbour(neighbour_list *list, int32_t other)
{
    return SK_PUSH(*list, other, 8);
}

/* Triangle statistics: corners and the three edges of each triangle, in every example. */
static void triangle_statistics(clustering *c, const int32_t *triangles, const double *rest, const double *frames,
                                size_t vertex_count, double edge_weight)
{
    for (size_t t = 0; t < c->cluster_count; ++t) {
        double *s = statistics_of(c, (int32_t)t);
        memset(s, 0, c->stride * sizeof *s);
        const int32_t *corner = triangles + 3 * t;
        s[0] = 3;
        for (int k = 0; k < 3; ++k) {
            const double *x = rest + 3 * (size_t)corner[k], *x_next = rest + 3 * (size_t)corner[(k + 1) % 3];
            for (int d = 0; d < 3; ++d) {
                s[1 + d] += x[d];
                s[4] += x[d] * x[d] + edge_weight * (x_next[d] - x[d]) * (x_next[d] - x[d]);
            }
            for (size_t e = 0; e < c->example_count; ++e) {
                const double *frame = frames + e * vertex_count * 3;
                const double *y = frame + 3 * (size_t)corner[k], *y_next = frame + 3 * (size_t)corner[(k + 1) % 3];
                double *p = s + SK_CLUSTER_FIXED + e * SK_CLUSTER_PER_EXAMPLE;
                for (int r = 0; r < 3; ++r) {
                    p[r] += y[r];
                    p[3] += y[r] * y[r] + edge_weight * (y_next[r] - y[r]) * (y_next[r] - y[r]);
                    for (int q = 0; q < 3; ++q)
                        p[4 + 3 * r + q] += y[r] * x[q] + edge_weight * (y_next[r] - y[r]) * (x_next[q] - x[q]);
                }
            }
        }
    }
}

typedef struct half_edge {
    int32_t low, high, triangle;
} half_edge;

static int half_edge_order(const void *a, const void *b)
{
    const half_edge *x = a, *y = b;
    if (x->low != y->low)
        return SK_ORDER(x->low, y->low);
    if (x->high != y->high)
        return SK_ORDER(x->high, y->high);
    return SK_ORDER(x->triangle, y->triangle);
}

/* Triangles sharing an edge are neighbours (every triangle on a non-manifold edge neighbours the next). */
static sk_status link_triangles(clustering *c, const int32_t *triangles, sk_error *error)
{
    const size_t t_count = c->cluster_count;
    half_edge *edges = sk_allocate(3 * t_count, sizeof *edges);
    if (!edges)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the edges of %zu triangles", t_count);
    for (size_t t = 0; t < t_count; ++t)
        for (int k = 0; k < 3; ++k) {
            const int32_t a = triangles[3 * t + k], b = triangles[3 * t + (k + 1) % 3];
            edges[3 * t + k] = (half_edge){a < b ? a : b, a < b ? b : a, (int32_t)t};
        }
    qsort(edges, 3 * t_count, sizeof *edges, half_edge_order);
    int ok = 1;
    for (size_t i = 1; i < 3 * t_count && ok; ++i) {
        const half_edge *x = edges + i - 1, *y = edges + i;
        if (x->low == y->low && x->high == y->high && x->triangle != y->triangle)
            ok = add_neighbour(&c->neighbours[x->triangle], y->triangle) &&
                 add_neighbour(&c->neighbours[y->triangle], x->triangle);
    }
    free(edges);
    return ok ? SK_OK : sk_fail(error, SK_ERROR_MEMORY, "out of memory for the triangle adjacency");
}

typedef struct centroid_key {
    double position;
    int32_t cluster;
} centroid_key;

static int centroid_order(const void *a, const void *b)
{
    const centroid_key *x = a, *y = b;
    return x->position != y->position ? SK_ORDER(x->position, y->position) : SK_ORDER(x->cluster, y->cluster);
}

/* Separate pieces of the mesh left as separate clusters: links each live cluster to the next in order of rest
 * centroid along the axis of widest spread, so the merging can go on to a single cluster (O(c log c)). */
static sk_status link_pieces(clustering *c, sk_error *error)
{
    centroid_key *keys = sk_allocate(c->cluster_count, sizeof *keys);
    if (!keys)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory linking the mesh's pieces");
    double low[3] = {INFINITY, INFINITY, INFINITY}, high[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t k = 0; k < c->cluster_count; ++k)
        if (c->alive[k])
            for (int d = 0; d < 3; ++d) {
                const double *s = statistics_of(c, (int32_t)k), x = s[1 + d] / s[0];
                low[d] = x < low[d] ? x : low[d];
                high[d] = x > high[d] ? x : high[d];
            }
    int axis = 0;
    for (int d = 1; d < 3; ++d)
        axis = high[d] - low[d] > high[axis] - low[axis] ? d : axis;
    size_t live = 0;
    for (size_t k = 0; k < c->cluster_count; ++k)
        if (c->alive[k]) {
            const double *s = statistics_of(c, (int32_t)k);
            keys[live++] = (centroid_key){s[1 + axis] / s[0], (int32_t)k};
        }
    qsort(keys, live, sizeof *keys, centroid_order);
    int ok = 1;
    for (size_t i = 1; i < live && ok; ++i) {
        const int32_t a = keys[i - 1].cluster, b = keys[i].cluster;
        ok = add_neighbour(&c->neighbours[a], b) && add_neighbour(&c->neighbours[b], a) && push_candidate(c, a, b);
    }
    free(keys);
    return ok ? SK_OK : sk_fail(error, SK_ERROR_MEMORY, "out of memory linking the mesh's pieces");
}

/* Merges gone into keep: sums, neighbour lists (each live neighbour once), and fresh candidates with each. */
static int merge(clustering *c, int32_t keep, int32_t gone, size_t merge_index)
{
    double *x = statistics_of(c, keep);
    const double *y = statistics_of(c, gone);
    for (size_t i = 0; i < c->stride; ++i)
        x[i] += y[i];
    c->own_error[keep] = cluster_error(x, c->example_count);
    c->alive[gone] = 0;
    ++c->stamp[keep];
    ++c->stamp[gone];
    neighbour_list merged = {0};
    c->mark[keep] = c->mark[gone] = merge_index;
    int ok = 1;
    for (int side = 0; side < 2 && ok; ++side) {
        const neighbour_list *list = &c->neighbours[side ? gone : keep];
        for (size_t i = 0; i < list->size && ok; ++i) {
            const int32_t other = list->items[i];
            if (!c->alive[other] || c->mark[other] == merge_index)
                continue;
            c->mark[other] = merge_index;
            ok = add_neighbour(&merged, other);
            if (ok && side == 1) /* a neighbour of gone only: it now touches keep */
                ok = add_neighbour(&c->neighbours[other], keep);
        }
    }
    free(c->neighbours[keep].items);
    free(c->neighbours[gone].items);
    c->neighbours[gone] = (neighbour_list){0};
    c->neighbours[keep] = merged;
    for (size_t i = 0; i < merged.size && ok; ++i)
        ok = push_candidate(c, keep, merged.items[i]);
    return ok;
}

static void clustering_free(clustering *c)
{
    if (c->neighbours)
        for (size_t k = 0; k < c->cluster_count; ++k)
            free(c->neighbours[k].items);
    SK_FREE_ALL(c->statistics, c->own_error, c->scratch, c->stamp, c->alive, c->mark, c->neighbours, c->heap.items);
}

static sk_status check_cluster_inputs(const int32_t *merges, const double *costs, const int32_t *triangles,
                                      size_t triangle_count, const double *rest, size_t vertex_count,
                                      const double *frames, size_t frame_count, double edge_weight, sk_error *error)
{
    if (!merges || !costs || !rest || !frames)
        return sk_fail(error, SK_ERROR_ARGUMENT, "triangle clustering arrays must not be null");
    if (triangle_count == 0 || triangle_count > INT32_MAX / 3)
        return sk_fail(error, SK_ERROR_ARGUMENT, "triangle count %zu: must be between 1 and %d", triangle_count,
                       INT32_MAX / 3);
    if (frame_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "no example frames: the clustering needs at least one");
    if (!(edge_weight >= 0 && isfinite(edge_weight)))
        return sk_fail(error, SK_ERROR_ARGUMENT, "edge weight %g: must be finite and >= 0", edge_weight);
    sk_status status = sk_validate_triangles(&(const sk_triangle_mesh){triangles, triangle_count, vertex_count}, error);
    if (status != SK_OK)
        return status;
    size_t values;
    if ((status = sk_array_size(&values, frame_count, vertex_count, 3, "example position", error)) != SK_OK)
        return status;
    size_t bad = sk_first_non_finite(rest, 3 * vertex_count);
    if (bad < 3 * vertex_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "rest vertex %zu: a NaN or infinity", bad / 3);
    bad = sk_first_non_finite(frames, values);
    if (bad < values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "example %zu, vertex %zu: a NaN or infinity",
                       bad / (3 * vertex_count), bad % (3 * vertex_count) / 3);
    return SK_OK;
}

sk_status sk_triangle_cluster_merges(int32_t *merges, double *costs, size_t merge_count, const int32_t *triangles,
                                     size_t triangle_count, const double *rest_positions, size_t vertex_count,
                                     const double *frames, size_t frame_count, double edge_weight,
                                     sk_progress_fn progress, void *progress_user, sk_error *error)
{
    sk_status status = check_cluster_inputs(merges, costs, triangles, triangle_count, rest_positions, vertex_count,
                                            frames, frame_count, edge_weight, error);
    if (status != SK_OK)
        return status;
    if (merge_count != triangle_count - 1)
        return sk_fail(error, SK_ERROR_ARGUMENT, "merge count %zu: %zu triangles make %zu merges", merge_count,
                       triangle_count, triangle_count - 1);
    clustering c = {.cluster_count = triangle_count, .example_count = frame_count};
    c.stride = SK_CLUSTER_FIXED + SK_CLUSTER_PER_EXAMPLE * frame_count;
    c.statistics = sk_allocate(triangle_count, c.stride * sizeof(double));
    c.own_error = sk_allocate(triangle_count, sizeof *c.own_error);
    c.scratch = sk_allocate(c.stride, sizeof *c.scratch);
    c.stamp = sk_allocate_zeroed(triangle_count, sizeof *c.stamp);
    c.alive = sk_allocate(triangle_count, sizeof *c.alive);
    c.mark = sk_allocate(triangle_count, sizeof *c.mark);
    c.neighbours = sk_allocate_zeroed(triangle_count, sizeof *c.neighbours);
    if (!c.statistics || !c.own_error || !c.scratch || !c.stamp || !c.alive || !c.mark || !c.neighbours) {
        clustering_free(&c);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the statistics of %zu triangles over %zu examples",
                       triangle_count, frame_count);
    }
    memset(c.alive, 1, triangle_count);
    for (size_t t = 0; t < triangle_count; ++t)
        c.mark[t] = SIZE_MAX;
    triangle_statistics(&c, triangles, rest_positions, frames, vertex_count, edge_weight);
    for (size_t t = 0; t < triangle_count; ++t)
        c.own_error[t] = cluster_error(statistics_of(&c, (int32_t)t), frame_count);
    status = link_triangles(&c, triangles, error);
    for (size_t t = 0; t < triangle_count && status == SK_OK; ++t)
        for (size_t i = 0; i < c.neighbours[t].size && status == SK_OK; ++i)
            if ((size_t)c.neighbours[t].items[i] > t && !push_candidate(&c, (int32_t)t, c.neighbours[t].items[i]))
                status = sk_fail(error, SK_ERROR_MEMORY, "out of memory for the merge queue");
    size_t merged = 0;
    while (status == SK_OK && merged + 1 < triangle_count) {
        if (c.heap.size == 0) {
            status = link_pieces(&c, error);
            continue;
        }
        merge_candidate top;
        SK_HEAP_POP(top, c.heap, cheaper);
        if (!c.alive[top.keep] || !c.alive[top.gone] || c.stamp[top.keep] != top.keep_stamp ||
            c.stamp[top.gone] != top.gone_stamp)
            continue; /* a stale candidate: one side has changed since it was costed */
        merges[2 * merged] = top.keep;
        merges[2 * merged + 1] = top.gone;
        costs[merged] = top.cost;
        if (!merge(&c, top.keep, top.gone, merged))
            status = sk_fail(error, SK_ERROR_MEMORY, "out of memory at merge %zu", merged);
        ++merged;
        if (status == SK_OK && progress && merged % SK_CLUSTER_PROGRESS_EVERY == 0 &&
            progress(progress_user, (double)merged / (double)(triangle_count - 1)))
            status = sk_fail(error, SK_ERROR_CANCELLED, "triangle clustering cancelled at merge %zu", merged);
    }
    clustering_free(&c);
    return status == SK_OK ? sk_succeed(error) : status;
}
