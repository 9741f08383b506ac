/*
 * Skeletons from segmented meshes (Vasilakis 2008, chapter 3): openings between parts, the parts' hierarchy,
 * kernel centroids and principal directions (sk_hull.c), the refinements of section 3.3 and the three methods of
 * section 3.2. The digest's corrections are applied: Algorithm 2's split loop runs k = i..j-1 and returns G[1,N],
 * the refinements take the closest (not the farthest) direction, weights multiply the angle, Algorithm 4 turns the
 * child (not the parent).
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_mesh.h"
#include "sk_skeleton_internal.h"

typedef struct opening_record {
    int32_t a, b, vertex; /* parts a < b */
} opening_record;

typedef struct opening {
    int32_t a, b;
    double centroid[3], normal[3]; /* the best-fit plane's normal */
    double joint[3];               /* where the child across it turns: the centroid, or its junction's (below) */
} opening;

typedef struct part_geometry {
    double kernel_centroid[3], axes[9], box[6];
    int32_t flags;
} part_geometry;

/* Everything one extraction builds; freed by free_workspace. */
typedef struct workspace {
    const double *positions;
    const int32_t *triangles, *triangle_parts;
    size_t triangle_count, vertex_count, part_count, opening_count;
    sk_edge_flaps flaps;
    opening *openings;
    int32_t *opening_vertex_offsets, *opening_vertices; /* CSR: the vertices of each opening */
    int32_t *part_opening_offsets, *part_openings; /* CSR: the openings of each part */
    int32_t *part_triangle_offsets, *part_triangles;
    int32_t *order;      /* parts in breadth-first order from the root */
    int32_t *parents;    /* the hierarchy used */
    int32_t *child_opening; /* per part: its opening with its parent (-1 for the root) */
    part_geometry *parts;
    double orientation;  /* +1 when the triangles face outward, -1 when inward */
} workspace;

static double now_seconds(void) { return sk_monotonic_seconds(); }

static void free_workspace(workspace *w)
{
    sk_edge_flaps_free(&w->flaps);
    SK_FREE_ALL(w->openings, w->opening_vertex_offsets, w->opening_vertices, w->part_opening_offsets,
                w->part_openings, w->part_triangle_offsets, w->part_triangles, w->order, w->parents, w->child_opening,
                w->parts);
}

/* ---------------------------------------------------------------------------------------------
 * Input checks
 * ------------------------------------------------------------------------------------------- */

static sk_status check_options(const sk_skeleton_options *options, sk_error *error)
{
    if (!options)
        return sk_fail(error, SK_ERROR_ARGUMENT, "options is NULL");
    if (options->method < SK_SKELETON_OPENING || options->method > SK_SKELETON_PRINCIPAL_AXIS)
        return sk_fail(error, SK_ERROR_ARGUMENT, "method %d is not 0 (opening), 1 (centroid) or 2 (principal axis)",
                       options->method);
    if (!(options->max_angle_degrees > 0.0) || !(options->max_angle_degrees <= 180.0))
        return sk_fail(error, SK_ERROR_ARGUMENT, "max_angle_degrees %g is not in (0, 180]", options->max_angle_degrees);
    if (!(options->closeness >= 0.0) || !(options->closeness < 1.0))
        return sk_fail(error, SK_ERROR_ARGUMENT, "closeness %g is not in [0, 1)", options->closeness);
    return SK_OK;
}

static sk_status check_parts(const int32_t *triangle_parts, size_t triangle_count, size_t part_count, sk_error *error)
{
    if (part_count == 0 || part_count > triangle_count)
        return sk_fail(error, SK_ERROR_ARGUMENT, "part_count %zu is not in [1, triangle_count = %zu]", part_count,
                       triangle_count);
    for (size_t t = 0; t < triangle_count; ++t)
        if (triangle_parts[t] < 0 || (size_t)triangle_parts[t] >= part_count)
            return sk_fail(error, SK_ERROR_INDEX, "triangle_parts[%zu] = %d is not in [0, %zu)", t, triangle_parts[t],
                           part_count);
    return SK_OK;
}

/* A given hierarchy: one root (-1), parents in range, no cycle. */
static sk_status check_parents(const int32_t *parents, size_t part_count, sk_error *error)
{
    size_t roots = 0;
    for (size_t p = 0; p < part_count; ++p) {
        if (parents[p] == -1) {
            ++roots;
            continue;
        }
        if (parents[p] < 0 || (size_t)parents[p] >= part_count || (size_t)parents[p] == p)
            return sk_fail(error, SK_ERROR_INDEX, "parents[%zu] = %d is not -1 or another part in [0, %zu)", p,
                           parents[p], part_count);
        size_t steps = 0;
        for (int32_t q = parents[p]; q != -1; q = parents[q])
            if (++steps > part_count || q < 0 || (size_t)q >= part_count)
                return sk_fail(error, SK_ERROR_CYCLE, "the parents of part %zu form a cycle", p);
    }
    if (roots != 1)
        return sk_fail(error, SK_ERROR_ARGUMENT, "parents has %zu roots (-1 entries); a tree has one", roots);
    return SK_OK;
}

/* ---------------------------------------------------------------------------------------------
 * Openings and the hierarchy
 * ------------------------------------------------------------------------------------------- */

static int compare_records(const void *x, const void *y)
{
    const opening_record *a = x, *b = y;
    const int key = SK_ORDER(a->a, b->a);
    if (key)
        return key;
    return SK_ORDER(a->b, b->b) ? SK_ORDER(a->b, b->b) : SK_ORDER(a->vertex, b->vertex);
}

/* The opening's centroid and best-fit plane (the normal: the covariance's least eigenvector). */
static void fit_opening(opening *o, const opening_record *records, size_t count, const double *positions)
{
    double mean[3] = {0, 0, 0}, covariance[9] = {0};
    for (size_t k = 0; k < count; ++k)
        for (int c = 0; c < 3; ++c)
            mean[c] += positions[3 * (size_t)records[k].vertex + (size_t)c] / (double)count;
    for (size_t k = 0; k < count; ++k) {
        const double *p = positions + 3 * (size_t)records[k].vertex;
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                covariance[3 * i + j] += (p[i] - mean[i]) * (p[j] - mean[j]);
    }
    double axes[9], values[3];
    memcpy(o->centroid, mean, sizeof mean);
    if (sk_principal_axes(axes, values, covariance))
        memcpy(o->normal, axes + 6, 3 * sizeof(double));
    else
        o->normal[0] = 1.0, o->normal[1] = o->normal[2] = 0.0;
}

/* Openings: the vertices of every edge between triangles of two parts, per part pair. */
static sk_status find_openings(workspace *w, sk_error *error)
{
    struct {
        opening_record *items;
        size_t size, capacity;
    } records = {0};
    for (size_t e = 0; e < w->flaps.edge_count; ++e) {
        const int32_t t0 = w->flaps.edge_triangles[2 * e], t1 = w->flaps.edge_triangles[2 * e + 1];
        if (t1 < 0 || w->triangle_parts[t0] == w->triangle_parts[t1])
            continue;
        const int32_t a = w->triangle_parts[t0], b = w->triangle_parts[t1];
        for (int end = 0; end < 2; ++end) {
            opening_record r = {a < b ? a : b, a < b ? b : a, w->flaps.edge_vertices[2 * e + (size_t)end]};
            if (!SK_PUSH(records, r, 256)) {
                free(records.items);
                return sk_fail(error, SK_ERROR_MEMORY, "out of memory listing the openings");
            }
        }
    }
    if (records.size)
        qsort(records.items, records.size, sizeof *records.items, compare_records);
    size_t unique = 0, pairs = 0;
    for (size_t k = 0; k < records.size; ++k)
        if (k == 0 || compare_records(records.items + k, records.items + unique - 1) != 0) {
            if (unique == 0 || records.items[k].a != records.items[unique - 1].a ||
                records.items[k].b != records.items[unique - 1].b)
                ++pairs;
            records.items[unique++] = records.items[k];
        }
    w->openings = sk_allocate(pairs, sizeof *w->openings);
    w->opening_vertex_offsets = sk_allocate(pairs + 1, sizeof(int32_t));
    w->opening_vertices = sk_allocate(unique ? unique : 1, sizeof(int32_t));
    if (!w->openings || !w->opening_vertex_offsets || !w->opening_vertices) {
        free(records.items);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu openings", pairs);
    }
    for (size_t k = 0; k < unique; ++k)
        w->opening_vertices[k] = records.items[k].vertex;
    w->opening_vertex_offsets[0] = 0;
    for (size_t begin = 0, end; begin < unique; begin = end) {
        for (end = begin + 1; end < unique && records.items[end].a == records.items[begin].a &&
                              records.items[end].b == records.items[begin].b;
             ++end)
            ;
        opening *o = w->openings + w->opening_count++;
        o->a = records.items[begin].a;
        o->b = records.items[begin].b;
        fit_opening(o, records.items + begin, end - begin, w->positions);
        memcpy(o->joint, o->centroid, sizeof o->joint);
        w->opening_vertex_offsets[w->opening_count] = (int32_t)end;
    }
    free(records.items);
    return SK_OK;
}

/* Groups the openings and the triangles by part (CSR). */
static sk_status index_parts(workspace *w, sk_error *error)
{
    const size_t parts = w->part_count;
    w->part_opening_offsets = sk_allocate_zeroed(parts + 2, sizeof(int32_t));
    w->part_openings = sk_allocate(2 * w->opening_count, sizeof(int32_t));
    w->part_triangle_offsets = sk_allocate_zeroed(w->triangle_count + 2, sizeof(int32_t)); /* as sk_group_by_chart needs */
    w->part_triangles = sk_allocate(w->triangle_count, sizeof(int32_t));
    if (!w->part_opening_offsets || !w->part_openings || !w->part_triangle_offsets || !w->part_triangles)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory indexing %zu parts", parts);
    for (size_t o = 0; o < w->opening_count; ++o) {
        ++w->part_opening_offsets[w->openings[o].a + 2];
        ++w->part_opening_offsets[w->openings[o].b + 2];
    }
    for (size_t p = 0; p < parts; ++p)
        w->part_opening_offsets[p + 2] += w->part_opening_offsets[p + 1];
    for (size_t o = 0; o < w->opening_count; ++o) {
        w->part_openings[w->part_opening_offsets[w->openings[o].a + 1]++] = (int32_t)o;
        w->part_openings[w->part_opening_offsets[w->openings[o].b + 1]++] = (int32_t)o;
    }
    sk_group_by_chart(w->part_triangle_offsets, w->part_triangles, w->triangle_parts, w->triangle_count);
    for (size_t p = 0; p < parts; ++p) {
        if (w->part_triangle_offsets[p] == w->part_triangle_offsets[p + 1])
            return sk_fail(error, SK_ERROR_ARGUMENT, "part %zu has no triangle (part ids must be 0..part_count-1)", p);
        const int32_t openings = w->part_opening_offsets[p + 1] - w->part_opening_offsets[p];
        if (openings == 0 && parts > 1)
            return sk_fail(error, SK_ERROR_ARGUMENT,
                           "part %zu has no opening: it shares no edge with another part (weld its seam)", p);
        if (openings > SK_SKELETON_MAX_OPENINGS)
            return sk_fail(error, SK_ERROR_ARGUMENT, "part %zu has %d openings; at most %d are supported", p,
                           openings, SK_SKELETON_MAX_OPENINGS);
    }
    return SK_OK;
}

static int32_t other_part(const opening *o, int32_t part)
{
    return o->a == part ? o->b : o->a;
}

/* The part with the most openings (ties: most triangles, then lowest id). */
static int32_t choose_root(const workspace *w)
{
    int32_t best = 0;
    for (size_t p = 1; p < w->part_count; ++p) {
        const int32_t openings = w->part_opening_offsets[p + 1] - w->part_opening_offsets[p],
                      best_openings = w->part_opening_offsets[best + 1] - w->part_opening_offsets[best],
                      triangles = w->part_triangle_offsets[p + 1] - w->part_triangle_offsets[p],
                      best_triangles = w->part_triangle_offsets[best + 1] - w->part_triangle_offsets[best];
        if (openings > best_openings || (openings == best_openings && triangles > best_triangles))
            best = (int32_t)p;
    }
    return best;
}

/* The breadth-first order of the hierarchy (given, or grown over the openings), with each part's opening to its
 * parent. */
static sk_status build_hierarchy(workspace *w, const int32_t *given, sk_error *error)
{
    const size_t parts = w->part_count;
    w->order = sk_allocate(parts, sizeof(int32_t));
    w->parents = sk_allocate(parts, sizeof(int32_t));
    w->child_opening = sk_allocate(parts, sizeof(int32_t));
    if (!w->order || !w->parents || !w->child_opening)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the hierarchy of %zu parts", parts);
    for (size_t p = 0; p < parts; ++p)
        w->parents[p] = w->child_opening[p] = -2; /* -2: not reached yet */
    int32_t root = choose_root(w);
    if (given)
        for (size_t p = 0; p < parts; ++p)
            if (given[p] == -1)
                root = (int32_t)p;
    size_t reached = 0;
    w->order[reached++] = root;
    w->parents[root] = w->child_opening[root] = -1;
    for (size_t head = 0; head < reached; ++head) {
        const int32_t part = w->order[head];
        for (int32_t k = w->part_opening_offsets[part]; k < w->part_opening_offsets[part + 1]; ++k) {
            const int32_t o = w->part_openings[k], next = other_part(w->openings + o, part);
            if (w->parents[next] != -2 || (given && given[next] != part))
                continue;
            w->parents[next] = part;
            w->child_opening[next] = o;
            w->order[reached++] = next;
        }
    }
    for (size_t p = 0; p < parts; ++p)
        if (w->parents[p] == -2)
            return given ? sk_fail(error, SK_ERROR_ARGUMENT, "part %zu shares no opening with its parent %d", p,
                                   given[p])
                         : sk_fail(error, SK_ERROR_ARGUMENT,
                                   "parts do not connect into one tree: part %zu is not reached from the root %d", p,
                                   root);
    return SK_OK;
}

/* The opening between parts a and b, or -1. */
static int32_t opening_between(const workspace *w, int32_t a, int32_t b)
{
    for (int32_t k = w->part_opening_offsets[a]; k < w->part_opening_offsets[a + 1]; ++k)
        if (other_part(w->openings + w->part_openings[k], a) == b)
            return w->part_openings[k];
    return -1;
}

static int32_t opening_size(const workspace *w, int32_t o)
{
    return w->opening_vertex_offsets[o + 1] - w->opening_vertex_offsets[o];
}

/*
 * Joints shared by more than two parts (the cow's hips: four parts meet at one point). When children of one part
 * also touch each other, each child's opening with the parent is only one side of the junction, and its centroid
 * lies off the point where they all turn (10% of the diagonal on the cow). Siblings whose opening with each other
 * has at least half as many vertices as the smaller of their openings with the parent (a few touching vertices
 * elsewhere are contact, not a junction), joined transitively, and their parent form a junction; its point is the
 * mean of the centroids of all openings among them (each interface counts once, however long: the union of their
 * vertices leans toward the longest), and each of those children's joints goes there.
 */
static sk_status place_junctions(workspace *w, sk_error *error)
{
    int32_t *children = sk_allocate(w->part_count, sizeof(int32_t)), *group = sk_allocate(w->part_count,
                                                                                          sizeof(int32_t));
    if (!children || !group) {
        SK_FREE_ALL(children, group);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the junctions");
    }
    for (size_t p = 0; p < w->part_count; ++p) {
        size_t count = 0;
        for (size_t c = 0; c < w->part_count; ++c)
            if (w->parents[c] == (int32_t)p)
                children[count++] = (int32_t)c;
        for (size_t i = 0; i < count; ++i)
            group[i] = (int32_t)i;
        for (size_t i = 0; i < count; ++i)
            for (size_t k = i + 1; k < count; ++k) {
                const int32_t between = opening_between(w, children[i], children[k]);
                const int32_t smaller = (int32_t)fmin(opening_size(w, w->child_opening[children[i]]),
                                                      opening_size(w, w->child_opening[children[k]]));
                if (between >= 0 && 2 * opening_size(w, between) >= smaller)
                    sk_join_classes(group, (int32_t)i, (int32_t)k);
            }
        for (size_t i = 0; i < count; ++i) {
            const int32_t root = sk_find_root(group, (int32_t)i);
            if (root != (int32_t)i)
                continue; /* each junction once, from its first child */
            size_t members = 0;
            for (size_t k = 0; k < count; ++k)
                members += sk_find_root(group, (int32_t)k) == root;
            if (members < 2)
                continue;
            double sum[3] = {0.0, 0.0, 0.0};
            size_t openings = 0;
            for (size_t o = 0; o < w->opening_count; ++o) {
                const opening *op = w->openings + o;
                int inside = (op->a == (int32_t)p) + (op->b == (int32_t)p);
                for (size_t k = 0; k < count; ++k)
                    if (sk_find_root(group, (int32_t)k) == root)
                        inside += (op->a == children[k]) + (op->b == children[k]);
                if (inside < 2)
                    continue;
                for (int c = 0; c < 3; ++c)
                    sum[c] += op->centroid[c];
                ++openings;
            }
            for (size_t k = 0; k < count; ++k)
                if (sk_find_root(group, (int32_t)k) == root)
                    for (int c = 0; c < 3; ++c)
                        w->openings[w->child_opening[children[k]]].joint[c] = sum[c] / (double)openings;
        }
    }
    SK_FREE_ALL(children, group);
    return SK_OK;
}

/* ---------------------------------------------------------------------------------------------
 * Per-part geometry: hull, kernel centroid, principal directions
 * ------------------------------------------------------------------------------------------- */

/* +1 when the mesh's signed volume about its vertex mean is positive (triangles face out), else -1. */
static double mesh_orientation(const workspace *w)
{
    double mean[3] = {0, 0, 0}, volume = 0.0;
    for (size_t v = 0; v < w->vertex_count; ++v)
        for (int c = 0; c < 3; ++c)
            mean[c] += w->positions[3 * v + (size_t)c] / (double)w->vertex_count;
    for (size_t t = 0; t < w->triangle_count; ++t) {
        double a[3], b[3], c[3], n[3];
        for (int k = 0; k < 3; ++k) {
            a[k] = w->positions[3 * (size_t)w->triangles[3 * t] + (size_t)k] - mean[k];
            b[k] = w->positions[3 * (size_t)w->triangles[3 * t + 1] + (size_t)k] - mean[k];
            c[k] = w->positions[3 * (size_t)w->triangles[3 * t + 2] + (size_t)k] - mean[k];
        }
        sk_cross3(n, b, c);
        volume += sk_dot3(a, n);
    }
    return volume >= 0.0 ? 1.0 : -1.0;
}

/* The distinct vertices of a part's triangles (stamp: vertex_count entries, all -1, left so). */
static size_t part_points(double *points, int32_t *stamp, const workspace *w, int32_t part)
{
    size_t count = 0;
    for (int32_t k = w->part_triangle_offsets[part]; k < w->part_triangle_offsets[part + 1]; ++k)
        for (int c = 0; c < 3; ++c) {
            const int32_t v = w->triangles[3 * (size_t)w->part_triangles[k] + (size_t)c];
            if (stamp[v] == part)
                continue;
            stamp[v] = part;
            memcpy(points + 3 * count++, w->positions + 3 * (size_t)v, 3 * sizeof(double));
        }
    for (int32_t k = w->part_triangle_offsets[part]; k < w->part_triangle_offsets[part + 1]; ++k)
        for (int c = 0; c < 3; ++c)
            stamp[w->triangles[3 * (size_t)w->part_triangles[k] + (size_t)c]] = -1;
    return count;
}

static double points_diagonal(const double *points, size_t count)
{
    double low[3] = {INFINITY, INFINITY, INFINITY}, high[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t k = 0; k < count; ++k)
        for (int c = 0; c < 3; ++c) {
            low[c] = fmin(low[c], points[3 * k + (size_t)c]);
            high[c] = fmax(high[c], points[3 * k + (size_t)c]);
        }
    return sk_distance3(low, high);
}

/* The half-spaces of a part's kernel: each triangle's inner side and each opening's plane, facing away from the
 * part's vertex mean. Returns their number. */
static size_t kernel_halfspaces(double *halfspaces, const workspace *w, int32_t part, const double mean[3])
{
    size_t count = 0;
    for (int32_t k = w->part_triangle_offsets[part]; k < w->part_triangle_offsets[part + 1]; ++k) {
        const int32_t *t = w->triangles + 3 * (size_t)w->part_triangles[k];
        const double *a = w->positions + 3 * (size_t)t[0], *b = w->positions + 3 * (size_t)t[1],
                     *c = w->positions + 3 * (size_t)t[2];
        const double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double *h = halfspaces + 4 * count, length;
        sk_cross3(h, u, v);
        length = sqrt(sk_dot3(h, h));
        if (!(length > 0.0))
            continue; /* a degenerate triangle bounds nothing */
        for (int i = 0; i < 3; ++i)
            h[i] *= w->orientation / length;
        h[3] = sk_dot3(h, a);
        ++count;
    }
    for (int32_t k = w->part_opening_offsets[part]; k < w->part_opening_offsets[part + 1]; ++k) {
        const opening *o = w->openings + w->part_openings[k];
        double *h = halfspaces + 4 * count++;
        const double toward_mean[3] = {mean[0] - o->centroid[0], mean[1] - o->centroid[1], mean[2] - o->centroid[2]};
        const double sign = sk_dot3(o->normal, toward_mean) > 0.0 ? -1.0 : 1.0;
        for (int i = 0; i < 3; ++i)
            h[i] = sign * o->normal[i];
        h[3] = sk_dot3(h, o->centroid);
    }
    return count;
}

/* The covariance of the points themselves about their mean: the degenerate part's directions. */
static void point_covariance(double covariance[9], double mean[3], const double *points, size_t count)
{
    memset(covariance, 0, 9 * sizeof(double));
    mean[0] = mean[1] = mean[2] = 0.0;
    for (size_t k = 0; k < count; ++k)
        for (int c = 0; c < 3; ++c)
            mean[c] += points[3 * k + (size_t)c] / (double)count;
    for (size_t k = 0; k < count; ++k)
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                covariance[3 * i + j] += (points[3 * k + (size_t)i] - mean[i]) * (points[3 * k + (size_t)j] - mean[j]);
}

/* Makes the frame right-handed by flipping its last row when needed. */
static void make_right_handed(double axes[9])
{
    double cross[3];
    sk_cross3(cross, axes, axes + 3);
    if (sk_dot3(cross, axes + 6) < 0.0)
        for (int c = 0; c < 3; ++c)
            axes[6 + c] = -axes[6 + c];
}

static sk_status measure_part(workspace *w, int32_t part, double *points, double *halfspaces, int32_t *stamp,
                              double *hull_seconds, double *kernel_seconds, sk_error *error)
{
    part_geometry *g = w->parts + part;
    const size_t count = part_points(points, stamp, w, part);
    double started = now_seconds(), covariance[9], values[3], centroid[3];
    sk_hull hull;
    const int built = sk_hull_build(&hull, points, count);
    if (built < 0)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the convex hull of part %d", part);
    double mean[3];
    point_covariance(covariance, mean, points, count);
    if (built == 1 && sk_hull_centroid(centroid, &hull) > 0.0) {
        sk_hull_covariance(covariance, &hull, centroid);
    } else {
        memcpy(centroid, mean, sizeof mean);
        g->flags |= SK_SKELETON_DEGENERATE;
    }
    sk_hull_free(&hull);
    if (!sk_principal_axes(g->axes, values, covariance))
        return sk_fail(error, SK_ERROR_LAPACK, "the principal directions of part %d did not converge", part);
    make_right_handed(g->axes);
    *hull_seconds += now_seconds() - started;
    started = now_seconds();
    memcpy(g->kernel_centroid, centroid, sizeof centroid);
    if (!(g->flags & SK_SKELETON_DEGENERATE)) {
        const size_t spaces = kernel_halfspaces(halfspaces, w, part, mean);
        const int kernel = sk_kernel_centroid(g->kernel_centroid, halfspaces, spaces, centroid,
                                              points_diagonal(points, count));
        if (kernel < 0)
            return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the kernel of part %d", part);
        if (kernel == 1)
            g->flags |= SK_SKELETON_STAR_SHAPED;
        else
            memcpy(g->kernel_centroid, centroid, sizeof centroid); /* not star-shaped: the hull centroid */
    }
    *kernel_seconds += now_seconds() - started;
    return SK_OK;
}

/* ---------------------------------------------------------------------------------------------
 * Refinements (section 3.3)
 * ------------------------------------------------------------------------------------------- */

/* v rotated about the unit axis by angle (Rodrigues). */
static void rotate_vector(double v[3], const double axis[3], double angle)
{
    double cross[3];
    const double c = cos(angle), s = sin(angle), along = sk_dot3(axis, v) * (1.0 - c);
    sk_cross3(cross, axis, v);
    for (int k = 0; k < 3; ++k)
        v[k] = v[k] * c + cross[k] * s + axis[k] * along;
}

static void rotate_frame(double axes[9], const double axis[3], double angle)
{
    for (int r = 0; r < 3; ++r)
        rotate_vector(axes + 3 * r, axis, angle);
}

/* The angle between a direction (either sign) and a vector, and the sign that makes them agree. */
static double direction_angle(const double direction[3], const double v[3], double *sign)
{
    const double length = sqrt(sk_dot3(v, v) * sk_dot3(direction, direction));
    const double cosine = length > 0.0 ? sk_dot3(direction, v) / length : 1.0;
    *sign = cosine < 0.0 ? -1.0 : 1.0;
    return acos(fmin(1.0, fabs(cosine)));
}

/* Turns the frame so that row k (signed) moves toward v by `angle`. */
static void turn_toward(double axes[9], int k, const double v[3], double sign, double angle)
{
    const double from[3] = {sign * axes[3 * k], sign * axes[3 * k + 1], sign * axes[3 * k + 2]};
    double axis[3];
    sk_cross3(axis, from, v);
    const double length = sqrt(sk_dot3(axis, axis));
    if (length > 1e-300 && angle > 0.0) {
        for (int c = 0; c < 3; ++c)
            axis[c] /= length;
        rotate_frame(axes, axis, angle);
    }
}

/* Algorithm 3's align: the closest direction turns toward v by weight times its angle, unless that exceeds
 * max_angle. */
static void align_local(double axes[9], const double v[3], double weight, double max_angle)
{
    int closest = 0;
    double best = INFINITY, best_sign = 1.0;
    for (int k = 0; k < 3; ++k) {
        double sign;
        const double angle = direction_angle(axes + 3 * k, v, &sign);
        if (angle < best)
            best = angle, closest = k, best_sign = sign;
    }
    if (!(sk_dot3(v, v) > 0.0) || best * weight > max_angle)
        return;
    turn_toward(axes, closest, v, best_sign, best * weight);
}

/* The feature vector of an opening: its centroid from the part's KC. */
static void feature_vector(double v[3], const workspace *w, const part_geometry *g, int32_t opening_index)
{
    const opening *o = w->openings + opening_index;
    for (int c = 0; c < 3; ++c)
        v[c] = o->centroid[c] - g->kernel_centroid[c];
}

/* The thesis makes each vector's closest direction the principal one in turn, so the last opening visited wins
 * and the answer depends on the openings' order. Order-free reading: once every vector has turned the frame, the
 * principal direction is the one along which the openings reach farthest from KC (the largest weighted second
 * moment sum of weight * (d . v)^2). On a part whose covariance is nearly isotropic (the cow's trunk is as tall as
 * it is wide and long) this picks the axis its openings lie along rather than whichever vector came last. */
static int aligned_direction(const workspace *w, int32_t part)
{
    const part_geometry *g = w->parts + part;
    const int32_t first = w->part_opening_offsets[part], last = w->part_opening_offsets[part + 1];
    const double n = (double)(last - first);
    const int root = w->parents[part] == -1;
    double score[3] = {0.0, 0.0, 0.0};
    for (int32_t k = first; k < last; ++k) {
        double v[3];
        feature_vector(v, w, g, w->part_openings[k]);
        const double weight = root ? 1.0 / n : (w->part_openings[k] == w->child_opening[part] ? 2.0 : 1.0) / (n + 1.0);
        for (int d = 0; d < 3; ++d) {
            const double along = sk_dot3(g->axes + 3 * d, v);
            score[d] += weight * along * along;
        }
    }
    int best = 0;
    for (int d = 1; d < 3; ++d)
        if (score[d] > score[best])
            best = d;
    return best;
}

/* Puts the principal direction first (a right-handed frame). */
static void principal_first(double axes[9], int principal)
{
    if (principal == 0)
        return;
    double row[3];
    memcpy(row, axes, sizeof row);
    memcpy(axes, axes + 3 * principal, sizeof row);
    memcpy(axes + 3 * principal, row, sizeof row);
    make_right_handed(axes);
}

static void refine_local(workspace *w, int32_t part, double max_angle)
{
    part_geometry *g = w->parts + part;
    const int32_t first = w->part_opening_offsets[part], last = w->part_opening_offsets[part + 1];
    const double n = (double)(last - first);
    const int root = w->parents[part] == -1;
    double v[3];
    if (!root) { /* the opening to the parent first, with twice the weight */
        feature_vector(v, w, g, w->child_opening[part]);
        align_local(g->axes, v, 2.0 / (n + 1.0), max_angle);
    }
    for (int32_t k = first; k < last; ++k) {
        if (w->part_openings[k] == w->child_opening[part])
            continue;
        feature_vector(v, w, g, w->part_openings[k]);
        align_local(g->axes, v, root ? 1.0 / n : 1.0 / (n + 1.0), max_angle);
    }
    principal_first(g->axes, aligned_direction(w, part));
}

/* Algorithm 4 for one child: its principal axis onto the parent's closest direction, then the closest remaining
 * pair of directions about it. */
static void refine_parent(part_geometry *child, const part_geometry *parent, double max_angle)
{
    int closest = 0;
    double best = INFINITY, best_sign = 1.0;
    for (int k = 0; k < 3; ++k) {
        double sign;
        const double angle = direction_angle(parent->axes + 3 * k, child->axes, &sign);
        if (angle < best)
            best = angle, closest = k, best_sign = sign;
    }
    if (best > max_angle)
        return;
    const double target[3] = {best_sign * parent->axes[3 * closest], best_sign * parent->axes[3 * closest + 1],
                              best_sign * parent->axes[3 * closest + 2]};
    turn_toward(child->axes, 0, target, 1.0, best);
    int pair_child = 1, pair_parent = -1;
    double pair_best = INFINITY, pair_sign = 1.0;
    for (int i = 1; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
            double sign;
            const double angle = j == closest ? INFINITY : direction_angle(parent->axes + 3 * j, child->axes + 3 * i, &sign);
            if (angle < pair_best)
                pair_best = angle, pair_child = i, pair_parent = j, pair_sign = sign;
        }
    if (pair_parent < 0)
        return;
    const double *from = child->axes + 3 * pair_child;
    const double to[3] = {pair_sign * parent->axes[3 * pair_parent], pair_sign * parent->axes[3 * pair_parent + 1],
                          pair_sign * parent->axes[3 * pair_parent + 2]};
    double cross[3], axis[3];
    memcpy(axis, child->axes, sizeof axis);
    sk_cross3(cross, from, to);
    rotate_frame(child->axes, axis, atan2(sk_dot3(axis, cross), sk_dot3(from, to)));
}

/* The oriented box along the (final) directions: half-length (m1 + m2) / 2 about the recentred middle. */
static void fit_box(part_geometry *g, const double *points, size_t count)
{
    double low[3] = {INFINITY, INFINITY, INFINITY}, high[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t k = 0; k < count; ++k)
        for (int r = 0; r < 3; ++r) {
            const double along = sk_dot3(g->axes + 3 * r, points + 3 * k);
            low[r] = fmin(low[r], along);
            high[r] = fmax(high[r], along);
        }
    for (int c = 0; c < 3; ++c)
        g->box[c] = 0.0;
    for (int r = 0; r < 3; ++r) {
        g->box[3 + r] = 0.5 * (high[r] - low[r]);
        for (int c = 0; c < 3; ++c)
            g->box[c] += 0.5 * (high[r] + low[r]) * g->axes[3 * r + c];
    }
}

/* ---------------------------------------------------------------------------------------------
 * The methods (section 3.2)
 * ------------------------------------------------------------------------------------------- */

typedef struct joints {
    double *positions;
    int32_t *parents, *parts, *kinds;
    size_t count, capacity;
} joints;

static int32_t add_joint(joints *j, const double position[3], int32_t parent, int32_t part, int kind)
{
    if (j->count >= j->capacity)
        return -1; /* cannot happen within SK_SKELETON_JOINTS_PER_PART per part; a guard all the same */
    memcpy(j->positions + 3 * j->count, position, 3 * sizeof(double));
    j->parents[j->count] = parent;
    j->parts[j->count] = part;
    j->kinds[j->count] = kind;
    return (int32_t)j->count++;
}

/* The openings of a part to its children, in the part's opening order. */
static size_t child_openings(int32_t *out, const workspace *w, int32_t part)
{
    size_t count = 0;
    for (int32_t k = w->part_opening_offsets[part]; k < w->part_opening_offsets[part + 1]; ++k) {
        const int32_t o = w->part_openings[k], other = other_part(w->openings + o, part);
        if (w->parents[other] == part && w->child_opening[other] == o)
            out[count++] = other;
    }
    return count;
}

static void mean_vertex(double mean[3], const workspace *w, int32_t part, int32_t *stamp, double *points)
{
    const size_t count = part_points(points, stamp, w, part);
    double covariance[9];
    point_covariance(covariance, mean, points, count);
}

/* Opening and Centroid methods: one hub per part (its root point or KC) joined to its children's ocs. */
static int hub_methods(joints *j, int32_t *part_joints, const workspace *w, int centroid, int32_t *children,
                       int32_t *stamp, double *points)
{
    for (size_t k = 0; k < w->part_count; ++k) {
        const int32_t part = w->order[k];
        int32_t hub;
        if (w->parents[part] == -1) {
            double root[3];
            if (centroid)
                memcpy(root, w->parts[part].kernel_centroid, sizeof root);
            else
                mean_vertex(root, w, part, stamp, points);
            hub = part_joints[part] = add_joint(j, root, -1, part, SK_JOINT_ROOT_POINT);
        } else {
            hub = part_joints[part];
            if (centroid)
                hub = add_joint(j, w->parts[part].kernel_centroid, hub, part, SK_JOINT_KERNEL_CENTROID);
        }
        const size_t count = child_openings(children, w, part);
        for (size_t c = 0; c < count; ++c)
            part_joints[children[c]] = add_joint(j, w->openings[w->child_opening[children[c]]].joint, hub,
                                                 children[c], SK_JOINT_OPENING);
        if (hub < 0)
            return 0;
    }
    return 1;
}

/* One opening centroid on a part's principal axis: the part across it (-1: the parent) and its projection. */
typedef struct axis_opening {
    double along, distance_to_axis, farthest; /* clamped parameter, d_min, max distance to the other ocs */
    const double *centroid;
    int32_t child; /* the child part across it, or -1 for the parent */
} axis_opening;

static int compare_along(const void *x, const void *y)
{
    const axis_opening *a = x, *b = y;
    return SK_ORDER(a->along, b->along) ? SK_ORDER(a->along, b->along) : SK_ORDER(a->child, b->child);
}

/* The line through KC along the principal axis, clipped to the part's points' hull planes (or their extent). */
static void axis_extent(double *t0, double *t1, const part_geometry *g, const double *points, size_t count)
{
    sk_hull hull;
    *t0 = INFINITY;
    *t1 = -INFINITY;
    for (size_t k = 0; k < count; ++k) {
        const double d[3] = {points[3 * k] - g->kernel_centroid[0], points[3 * k + 1] - g->kernel_centroid[1],
                             points[3 * k + 2] - g->kernel_centroid[2]};
        *t0 = fmin(*t0, sk_dot3(d, g->axes));
        *t1 = fmax(*t1, sk_dot3(d, g->axes));
    }
    if (sk_hull_build(&hull, points, count) != 1)
        return;
    for (size_t f = 0; f < hull.plane_count; ++f) { /* n.(KC + t a) + o <= 0 */
        const double *plane = hull.planes + 4 * f, slope = sk_dot3(plane, g->axes);
        const double limit = -(sk_dot3(plane, g->kernel_centroid) + plane[3]);
        if (slope > 1e-12)
            *t1 = fmin(*t1, limit / slope);
        else if (slope < -1e-12)
            *t0 = fmax(*t0, limit / slope);
    }
    sk_hull_free(&hull);
    *t0 = fmin(*t0, 0.0);
    *t1 = fmax(*t1, 0.0);
}

static void point_on_axis(double out[3], const part_geometry *g, double t)
{
    for (int c = 0; c < 3; ++c)
        out[c] = g->kernel_centroid[c] + t * g->axes[c];
}

/* Eq. 3.2: oc k's normalised variation against a link point at parameter `link`. */
static double variation(const axis_opening *k, const part_geometry *g, double link)
{
    double p[3];
    point_on_axis(p, g, link);
    const double range = k->farthest - k->distance_to_axis;
    return range > 1e-12 ? (sk_distance3(k->centroid, p) - k->distance_to_axis) / range : 0.0;
}

/* Algorithm 2: the interval programme over the sorted ocs. split[i n + j]: -1 for one group, else the last oc of
 * the left side. sum_v: the summed variations of the cell's chosen groups. */
static void group_openings(int32_t *split, double *score, double *sum_v, const axis_opening *ocs, size_t n,
                           const part_geometry *g)
{
    const double span = ocs[n - 1].along - ocs[0].along;
    for (size_t i = 0; i < n; ++i) {
        split[i * n + i] = -1;
        score[i * n + i] = sum_v[i * n + i] = 0.0;
    }
    for (size_t length = 2; length <= n; ++length)
        for (size_t i = 0; i + length <= n; ++i) {
            const size_t j = i + length - 1;
            double link = 0.0, merged = 0.0;
            for (size_t k = i; k <= j; ++k)
                link += ocs[k].along / (double)length; /* eq. 3.1 */
            for (size_t k = i; k <= j; ++k)
                merged += variation(ocs + k, g, link);
            const double reach = span > 1e-12 ? (ocs[j].along - ocs[i].along) / span : 0.0;
            double best = 0.5 * (merged / (double)length + reach); /* eq. 3.3 */
            split[i * n + j] = -1;
            sum_v[i * n + j] = merged;
            for (size_t k = i; k < j; ++k) { /* the corrected bounds: k = i .. j - 1 */
                const double gap = span > 1e-12 ? (ocs[k + 1].along - ocs[k].along) / span : 0.0; /* eq. 3.5 */
                const double separated = (sum_v[i * n + k] / (double)(k - i + 1) +
                                          sum_v[(k + 1) * n + j] / (double)(j - k) + (1.0 - gap)) / 3.0; /* eq. 3.4 */
                if (separated < best) {
                    best = separated;
                    split[i * n + j] = (int32_t)k;
                    sum_v[i * n + j] = sum_v[i * n + k] + sum_v[(k + 1) * n + j];
                }
            }
            score[i * n + j] = best;
        }
}

/* The groups of cell (i, j), left to right: group_of[k] for each oc, the count returned. */
static size_t read_groups(int32_t *group_of, const int32_t *split, size_t n, size_t i, size_t j, size_t next)
{
    const int32_t k = split[i * n + j];
    if (k < 0) {
        for (size_t m = i; m <= j; ++m)
            group_of[m] = (int32_t)next;
        return next + 1;
    }
    next = read_groups(group_of, split, n, i, (size_t)k, next);
    return read_groups(group_of, split, n, (size_t)k + 1, j, next);
}

typedef struct axis_scratch {
    axis_opening *ocs;
    int32_t *split, *group_of, *link_joints;
    double *score, *sum_v, *link_along;
} axis_scratch;

/* The Principal Axis method for one part: ocs projected and grouped, the link points, the axis ends the connecting
 * rule asks for, and the joints of the part's children's ocs. */
static int principal_axis_part(joints *j, int32_t *part_joints, const workspace *w, int32_t part, double closeness,
                               axis_scratch *s, int32_t *children, int32_t *stamp, double *points)
{
    const part_geometry *g = w->parts + part;
    const size_t point_count = part_points(points, stamp, w, part);
    double t0, t1;
    axis_extent(&t0, &t1, g, points, point_count);
    const size_t child_count = child_openings(children, w, part);
    const int root = w->parents[part] == -1;
    size_t n = 0;
    if (!root)
        s->ocs[n++] = (axis_opening){0, 0, 0, w->openings[w->child_opening[part]].joint, -1};
    for (size_t c = 0; c < child_count; ++c)
        s->ocs[n++] = (axis_opening){0, 0, 0, w->openings[w->child_opening[children[c]]].joint, children[c]};
    for (size_t k = 0; k < n; ++k) {
        const double d[3] = {s->ocs[k].centroid[0] - g->kernel_centroid[0], s->ocs[k].centroid[1] - g->kernel_centroid[1],
                             s->ocs[k].centroid[2] - g->kernel_centroid[2]};
        double p[3];
        s->ocs[k].along = fmin(t1, fmax(t0, sk_dot3(d, g->axes))); /* outside the segment: its closest end */
        point_on_axis(p, g, s->ocs[k].along);
        s->ocs[k].distance_to_axis = sk_distance3(s->ocs[k].centroid, p);
    }
    for (size_t k = 0; k < n; ++k)
        for (size_t m = 0; m < n; ++m)
            s->ocs[k].farthest = fmax(s->ocs[k].farthest, sk_distance3(s->ocs[k].centroid, s->ocs[m].centroid));
    size_t groups = 0;
    if (n > 0) {
        qsort(s->ocs, n, sizeof *s->ocs, compare_along);
        group_openings(s->split, s->score, s->sum_v, s->ocs, n, g);
        groups = read_groups(s->group_of, s->split, n, 0, n - 1, 0);
        for (size_t q = 0; q < groups; ++q)
            s->link_along[q] = 0.0;
        for (size_t q = 0, k = 0; q < groups; ++q) {
            size_t members = 0;
            for (; k < n && (size_t)s->group_of[k] == q; ++k, ++members)
                s->link_along[q] += s->ocs[k].along;
            s->link_along[q] /= (double)members;
        }
    } else { /* a lone part: KC is its only link point */
        s->link_along[groups++] = 0.0;
    }
    /* The entry: the parent's oc's group, or the root's middle group. */
    size_t entry = groups / 2;
    for (size_t k = 0; k < n; ++k)
        if (s->ocs[k].child < 0)
            entry = (size_t)s->group_of[k];
    double p[3];
    point_on_axis(p, g, s->link_along[entry]);
    s->link_joints[entry] = add_joint(j, p, root ? -1 : part_joints[part], part, root ? SK_JOINT_ROOT_POINT
                                                                                       : SK_JOINT_LINK_POINT);
    if (root)
        part_joints[part] = s->link_joints[entry];
    for (size_t q = entry + 1; q < groups; ++q) {
        point_on_axis(p, g, s->link_along[q]);
        s->link_joints[q] = add_joint(j, p, s->link_joints[q - 1], part, SK_JOINT_LINK_POINT);
    }
    for (size_t q = entry; q-- > 0;) {
        point_on_axis(p, g, s->link_along[q]);
        s->link_joints[q] = add_joint(j, p, s->link_joints[q + 1], part, SK_JOINT_LINK_POINT);
    }
    const double near = closeness * (t1 - t0);
    if (s->link_along[0] - t0 > near && s->link_along[0] - t0 > 0.0) {
        point_on_axis(p, g, t0);
        add_joint(j, p, s->link_joints[0], part, SK_JOINT_AXIS_END);
    }
    if (t1 - s->link_along[groups - 1] > near && t1 - s->link_along[groups - 1] > 0.0) {
        point_on_axis(p, g, t1);
        add_joint(j, p, s->link_joints[groups - 1], part, SK_JOINT_AXIS_END);
    }
    for (size_t k = 0; k < n; ++k)
        if (s->ocs[k].child >= 0)
            part_joints[s->ocs[k].child] = add_joint(j, s->ocs[k].centroid, s->link_joints[s->group_of[k]],
                                                     s->ocs[k].child, SK_JOINT_OPENING);
    return j->count <= j->capacity && s->link_joints[entry] >= 0;
}

static sk_status principal_axis_method(joints *j, int32_t *part_joints, const workspace *w, double closeness,
                                       int32_t *children, int32_t *stamp, double *points, sk_error *error)
{
    size_t most = 1;
    for (size_t p = 0; p < w->part_count; ++p)
        if ((size_t)(w->part_opening_offsets[p + 1] - w->part_opening_offsets[p]) > most)
            most = (size_t)(w->part_opening_offsets[p + 1] - w->part_opening_offsets[p]);
    axis_scratch s = {sk_allocate(most, sizeof(axis_opening)), sk_allocate(most * most, sizeof(int32_t)),
                      sk_allocate(most, sizeof(int32_t)),      sk_allocate(most, sizeof(int32_t)),
                      sk_allocate(most * most, sizeof(double)), sk_allocate(most * most, sizeof(double)),
                      sk_allocate(most, sizeof(double))};
    sk_status status = SK_OK;
    if (!s.ocs || !s.split || !s.group_of || !s.link_joints || !s.score || !s.sum_v || !s.link_along)
        status = sk_fail(error, SK_ERROR_MEMORY, "out of memory grouping %zu openings", most);
    for (size_t k = 0; k < w->part_count && status == SK_OK; ++k)
        if (!principal_axis_part(j, part_joints, w, w->order[k], closeness, &s, children, stamp, points))
            status = sk_fail(error, SK_ERROR_ARGUMENT, "part %d: more joints than the capacity", w->order[k]);
    SK_FREE_ALL(s.ocs, s.split, s.group_of, s.link_joints, s.score, s.sum_v, s.link_along);
    return status;
}

/* ---------------------------------------------------------------------------------------------
 * The entry point
 * ------------------------------------------------------------------------------------------- */

static sk_status check_arguments(const sk_triangle_mesh *mesh, const double *positions, const int32_t *triangle_parts,
                                 size_t part_count, const int32_t *parents, const sk_skeleton_options *options,
                                 sk_error *error)
{
    if (!mesh || !positions || !triangle_parts)
        return sk_fail(error, SK_ERROR_ARGUMENT, "mesh, positions and triangle_parts must not be NULL");
    sk_status status = check_options(options, error);
    if (status == SK_OK)
        status = sk_validate_triangles(mesh, error);
    if (status == SK_OK && mesh->triangle_count == 0)
        status = sk_fail(error, SK_ERROR_ARGUMENT, "the mesh has no triangle");
    size_t values;
    if (status == SK_OK)
        status = sk_array_size(&values, mesh->vertex_count, 3, 1, "positions", error);
    if (status == SK_OK && !sk_all_finite(positions, values)) {
        const size_t bad = sk_first_non_finite(positions, values);
        status = sk_fail(error, SK_ERROR_NOT_FINITE, "positions of vertex %zu are not finite", bad / 3);
    }
    if (status == SK_OK && mesh->triangle_count > (size_t)INT32_MAX / 3)
        status = sk_fail(error, SK_ERROR_ARGUMENT, "%zu triangles are too many", mesh->triangle_count);
    if (status == SK_OK)
        status = check_parts(triangle_parts, mesh->triangle_count, part_count, error);
    if (status == SK_OK && parents)
        status = check_parents(parents, part_count, error);
    return status;
}

sk_status sk_extract_skeleton(double *joint_positions, int32_t *joint_parents, int32_t *joint_parts,
                              int32_t *joint_kinds, int32_t *part_parents, int32_t *part_joints,
                              double *kernel_centroids, double *principal_axes, double *boxes, int32_t *part_flags,
                              sk_skeleton_report *report, const sk_triangle_mesh *mesh, const double *positions,
                              const int32_t *triangle_parts, size_t part_count, const int32_t *parents,
                              const sk_skeleton_options *options, sk_error *error)
{
    if (!joint_positions || !joint_parents || !joint_parts || !joint_kinds || !part_parents || !part_joints ||
        !kernel_centroids || !principal_axes || !boxes || !part_flags || !report)
        return sk_fail(error, SK_ERROR_ARGUMENT, "an output array or the report is NULL");
    sk_status status = check_arguments(mesh, positions, triangle_parts, part_count, parents, options, error);
    if (status != SK_OK)
        return status;
    memset(report, 0, sizeof *report);
    workspace w = {.positions = positions, .triangles = mesh->triangles, .triangle_parts = triangle_parts,
                   .triangle_count = mesh->triangle_count, .vertex_count = mesh->vertex_count, .part_count = part_count};
    double started = now_seconds();
    sk_edge_defect defect;
    status = sk_edge_flaps_build(&w.flaps, mesh->triangles, mesh->triangle_count, mesh->vertex_count, &defect);
    if (status != SK_OK)
        return status == SK_ERROR_MEMORY
                   ? sk_fail(error, status, "out of memory building the mesh's edges")
                   : sk_fail(error, status, "edge (%d, %d) is shared by %zu triangles: a part is not manifold",
                             defect.vertices[0], defect.vertices[1], defect.triangle_count);
    status = find_openings(&w, error);
    if (status == SK_OK)
        status = index_parts(&w, error);
    if (status == SK_OK)
        status = build_hierarchy(&w, parents, error);
    report->opening_seconds = now_seconds() - started;
    double *points = NULL, *halfspaces = NULL;
    int32_t *stamp = NULL, *children = NULL;
    if (status == SK_OK) {
        w.parts = sk_allocate_zeroed(part_count, sizeof *w.parts);
        points = sk_allocate(3 * mesh->vertex_count, sizeof(double));
        halfspaces = sk_allocate(4 * (mesh->triangle_count + 2 * w.opening_count), sizeof(double));
        stamp = sk_allocate(mesh->vertex_count, sizeof(int32_t));
        children = sk_allocate(part_count, sizeof(int32_t));
        if (!w.parts || !points || !halfspaces || !stamp || !children)
            status = sk_fail(error, SK_ERROR_MEMORY, "out of memory for the parts' geometry");
        else
            for (size_t v = 0; v < mesh->vertex_count; ++v)
                stamp[v] = -1;
        if (status == SK_OK)
            status = place_junctions(&w, error);
    }
    if (status == SK_OK) {
        w.orientation = mesh_orientation(&w);
        for (size_t p = 0; p < part_count && status == SK_OK; ++p)
            status = measure_part(&w, (int32_t)p, points, halfspaces, stamp, &report->hull_seconds,
                                  &report->kernel_seconds, error);
    }
    if (status == SK_OK) {
        started = now_seconds();
        const double max_angle = options->max_angle_degrees * 3.14159265358979323846 / 180.0;
        for (size_t k = 0; k < part_count; ++k) {
            const int32_t part = w.order[k];
            if (options->refine_local)
                refine_local(&w, part, max_angle);
            if (options->refine_parent && w.parents[part] >= 0)
                refine_parent(w.parts + part, w.parts + w.parents[part], max_angle);
            fit_box(w.parts + part, points, part_points(points, stamp, &w, part));
        }
        joints j = {joint_positions, joint_parents, joint_parts, joint_kinds, 0,
                    SK_SKELETON_JOINTS_PER_PART * part_count};
        if (options->method == SK_SKELETON_PRINCIPAL_AXIS)
            status = principal_axis_method(&j, part_joints, &w, options->closeness, children, stamp, points, error);
        else if (!hub_methods(&j, part_joints, &w, options->method == SK_SKELETON_CENTROID, children, stamp, points))
            status = sk_fail(error, SK_ERROR_ARGUMENT, "more joints than the capacity");
        report->joint_count = j.count;
        report->method_seconds = now_seconds() - started;
    }
    if (status == SK_OK) {
        report->opening_count = w.opening_count;
        for (size_t p = 0; p < part_count; ++p) {
            const part_geometry *g = w.parts + p;
            part_parents[p] = w.parents[p];
            memcpy(kernel_centroids + 3 * p, g->kernel_centroid, 3 * sizeof(double));
            memcpy(principal_axes + 9 * p, g->axes, 9 * sizeof(double));
            memcpy(boxes + 6 * p, g->box, 6 * sizeof(double));
            part_flags[p] = g->flags;
            report->star_shaped_count += (g->flags & SK_SKELETON_STAR_SHAPED) != 0;
            report->degenerate_count += (g->flags & SK_SKELETON_DEGENERATE) != 0;
        }
    }
    SK_FREE_ALL(points, halfspaces, stamp, children);
    free_workspace(&w);
    return status == SK_OK ? sk_succeed(error) : status;
}
