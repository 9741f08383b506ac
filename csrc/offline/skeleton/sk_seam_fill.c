/*
 * Seam reconstruction per frame (Vasilakis 2008, section 4.4, Algorithm 5) on the fixed seam topology that
 * skinkit.skeleton.seams prepares: add (the rigid points and the QLERP arcs of sk_evaluate_seams, optionally the
 * conic middle-point arcs), remove (points sinking into the other part of a seam, by region growing), triangulate
 * (an advancing-front fill of every hole the removal opens, in place of the thesis' Tight Cocone) and normals.
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <stdlib.h>
#include <string.h>

#include "sk_mesh.h"
#include "sk_skeleton_internal.h"
#include "skinkit.h"

/* A piece of kept triangles cut off from the rest with at most this many triangles is an island (removed). */
#define ISLAND_CAP 64
/* Rounds of pinched-vertex and island removal before a frame falls back to the fixed topology. */
#define FILL_ROUNDS 8
/* The most hole borders a frame bridges between cut-off pieces (more: the frame falls back). */
#define MAX_BRIDGED_LOOPS 256
/* Samples along a conic from which its points are placed at equal arc lengths. */
#define CONIC_SAMPLES 128
/* The most arc points of one column (skinkit.skeleton.seams.MAX_STEPS). */
#define MAX_COLUMN_STEPS 256

/* ---- small geometry ---------------------------------------------------------------------------------------- */

static void transform_point(double out[3], const double *m, const double p[3])
{
    double result[3];
    for (int r = 0; r < 3; ++r)
        result[r] = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
    memcpy(out, result, sizeof result);
}

static double corner_angle(const double *previous, const double *vertex, const double *following)
{
    const double u[3] = {previous[0] - vertex[0], previous[1] - vertex[1], previous[2] - vertex[2]};
    const double v[3] = {following[0] - vertex[0], following[1] - vertex[1], following[2] - vertex[2]};
    double c[3];
    sk_cross3(c, u, v);
    return atan2(sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), u[0] * v[0] + u[1] * v[1] + u[2] * v[2]);
}

/* ---- the conic of Fudos and Hoffmann (section 2.1.3), in 2D ------------------------------------------------- */

static double side_of(const double s[2], const double r[2], const double on[2])
{
    return (s[1] - on[1]) * r[0] - (s[0] - on[0]) * r[1];
}

/* The rational quadratic Bezier from c (tangent v) to d (tangent u, both pointing at the tangents' crossing x)
 * through p: control w x with weight w. 1 when the conic exists (p on d's side of c's tangent, on c's side of d's,
 * w > -1, the tangents not parallel), else 0. The thesis prints M2 = D_y u_y - D_x u_x; it is D_x u_y - D_y u_x. */
static int conic_control(double control[2], double *weight, const double c[2], const double v[2], const double d[2],
                         const double u[2], const double p[2])
{
    const double at_c = side_of(d, v, c) * side_of(p, v, c), at_d = side_of(c, u, d) * side_of(p, u, d);
    const double turn = v[0] * u[1] - v[1] * u[0];
    if (!(at_c > 0.0) || !(at_d > 0.0) || fabs(turn) < 1e-12 * sqrt((v[0] * v[0] + v[1] * v[1]) *
                                                                  (u[0] * u[0] + u[1] * u[1])))
        return 0;
    const double m1 = c[0] * v[1] - c[1] * v[0], m2 = d[0] * u[1] - d[1] * u[0];
    const double area = 0.5 * ((d[0] - c[0]) * (p[1] - c[1]) - (d[1] - c[1]) * (p[0] - c[0]));
    const double root = sqrt(at_c * at_d);
    const double w = area * turn / root;
    if (!(w > -1.0) || !isfinite(w))
        return 0;
    control[0] = area * (v[0] * m2 - u[0] * m1) / root; /* w times the tangents' crossing */
    control[1] = area * (v[1] * m2 - u[1] * m1) / root;
    *weight = w;
    return 1;
}

static void conic_at(double out[2], double t, const double c[2], const double control[2], double w,
                     const double d[2])
{
    const double a = (1.0 - t) * (1.0 - t), b = 2.0 * t * (1.0 - t), e = t * t;
    const double denominator = a + b * w + e;
    out[0] = (a * c[0] + b * control[0] + e * d[0]) / denominator;
    out[1] = (a * c[1] + b * control[1] + e * d[1]) / denominator;
}

/* count points strictly between c and d at equal arc lengths along the conic (fractions[k] = (k + 1) / (count + 1)
 * of its length, also written when fractions is not NULL). */
static void conic_sample(double *points, double *fractions, size_t count, const double c[2], const double control[2],
                         double w, const double d[2])
{
    double lengths[CONIC_SAMPLES + 1], previous[2] = {c[0], c[1]};
    lengths[0] = 0.0;
    for (int k = 1; k <= CONIC_SAMPLES; ++k) {
        double here[2];
        conic_at(here, (double)k / CONIC_SAMPLES, c, control, w, d);
        lengths[k] = lengths[k - 1] + hypot(here[0] - previous[0], here[1] - previous[1]);
        previous[0] = here[0];
        previous[1] = here[1];
    }
    int segment = 0;
    for (size_t k = 0; k < count; ++k) {
        const double fraction = (double)(k + 1) / (double)(count + 1), target = fraction * lengths[CONIC_SAMPLES];
        while (segment < CONIC_SAMPLES - 1 && lengths[segment + 1] < target)
            ++segment;
        const double span = lengths[segment + 1] - lengths[segment];
        const double local = span > 0.0 ? (target - lengths[segment]) / span : 0.0;
        conic_at(points + 2 * k, ((double)segment + local) / CONIC_SAMPLES, c, control, w, d);
        if (fractions)
            fractions[k] = fraction;
    }
}

/* A plane basis (origin o, unit e1, e2) and 2D coordinates in it. */
typedef struct plane2 {
    double origin[3], e1[3], e2[3];
} plane2;

static int plane_from(plane2 *plane, const double origin[3], const double first[3], const double second[3])
{
    double n1 = sqrt(sk_dot3(first, first));
    if (!(n1 > 0.0))
        return 0;
    for (int i = 0; i < 3; ++i)
        plane->e1[i] = first[i] / n1;
    const double along = sk_dot3(second, plane->e1);
    double rest[3] = {second[0] - along * plane->e1[0], second[1] - along * plane->e1[1],
                      second[2] - along * plane->e1[2]};
    const double n2 = sqrt(sk_dot3(rest, rest));
    if (!(n2 > 1e-9 * sqrt(sk_dot3(second, second))))
        return 0;
    for (int i = 0; i < 3; ++i) {
        plane->e2[i] = rest[i] / n2;
        plane->origin[i] = origin[i];
    }
    return 1;
}

static void to_plane(double out[2], const plane2 *plane, const double p[3])
{
    const double d[3] = {p[0] - plane->origin[0], p[1] - plane->origin[1], p[2] - plane->origin[2]};
    out[0] = sk_dot3(d, plane->e1);
    out[1] = sk_dot3(d, plane->e2);
}

static void direction_to_plane(double out[2], const plane2 *plane, const double v[3])
{
    out[0] = sk_dot3(v, plane->e1);
    out[1] = sk_dot3(v, plane->e2);
}

static void from_plane(double out[3], const plane2 *plane, const double p[2], double offset, const double normal[3])
{
    for (int i = 0; i < 3; ++i)
        out[i] = plane->origin[i] + p[0] * plane->e1[i] + p[1] * plane->e2[i] + offset * normal[i];
}

sk_status sk_conic_arc(double *points, double *weight, size_t point_count, const double *start,
                       const double *start_tangent, const double *end, const double *end_tangent,
                       const double *through, sk_error *error)
{
    if (!points || !weight || !start || !start_tangent || !end || !end_tangent || !through)
        return sk_fail(error, SK_ERROR_ARGUMENT, "an array is NULL");
    if (!sk_all_finite(start, 3) || !sk_all_finite(start_tangent, 3) || !sk_all_finite(end, 3) ||
        !sk_all_finite(end_tangent, 3) || !sk_all_finite(through, 3))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "an end, tangent or the through point is not finite");
    const double chord[3] = {end[0] - start[0], end[1] - start[1], end[2] - start[2]};
    plane2 plane;
    if (!plane_from(&plane, start, chord, start_tangent) &&
        !plane_from(&plane, start, chord, end_tangent))
        return sk_fail(error, SK_ERROR_ARGUMENT, "start and end coincide, or both tangents run along the chord: "
                                                 "no plane for the conic");
    double c[2], d[2], v[2], u[2], p[2], control[2], w;
    to_plane(c, &plane, start);
    to_plane(d, &plane, end);
    to_plane(p, &plane, through);
    direction_to_plane(v, &plane, start_tangent);
    direction_to_plane(u, &plane, end_tangent);
    if (!conic_control(control, &w, c, v, d, u, p))
        return sk_fail(error, SK_ERROR_ARGUMENT, "no conic from start to end through the point with these "
                                                 "tangents (the point is not between the tangent lines, or they "
                                                 "are parallel)");
    double *flat = sk_allocate(point_count ? point_count : 1, 2 * sizeof(double));
    if (!flat)
        return sk_fail(error, SK_ERROR_MEMORY, "no memory for %zu conic points", point_count);
    conic_sample(flat, NULL, point_count, c, control, w, d);
    const double zero[3] = {0.0, 0.0, 0.0};
    for (size_t k = 0; k < point_count; ++k)
        from_plane(points + 3 * k, &plane, flat + 2 * k, 0.0, zero);
    free(flat);
    *weight = w;
    return sk_succeed(error);
}

/* ---- validation ------------------------------------------------------------------------------------------- */

static sk_status check_indices(const int32_t *values, size_t count, int32_t low, size_t high, const char *what,
                               sk_error *error)
{
    for (size_t k = 0; k < count; ++k)
        if (values[k] < low || (values[k] >= 0 && (size_t)values[k] >= high))
            return sk_fail(error, SK_ERROR_INDEX, "%s[%zu] = %d is not in [%d, %zu)", what, k, values[k], low, high);
    return SK_OK;
}

static sk_status check_offsets(const int32_t *offsets, size_t count, const char *what, sk_error *error)
{
    if (offsets[0] != 0)
        return sk_fail(error, SK_ERROR_INDEX, "%s[0] = %d is not 0", what, offsets[0]);
    for (size_t k = 0; k < count; ++k)
        if (offsets[k + 1] < offsets[k])
            return sk_fail(error, SK_ERROR_INDEX, "%s[%zu] = %d is below %s[%zu] = %d", what, k + 1, offsets[k + 1],
                           what, k, offsets[k]);
    return SK_OK;
}

static sk_status check_inputs(const sk_seam_topology *s, const sk_seam_removal *r, const double *world,
                              size_t frame_count, sk_error *error)
{
    if (!s->rest_positions || !s->joints || !s->sources || !s->parts_a || !s->parts_b || !s->blend ||
        !s->triangles || !s->twins || (s->cap_member_count && !s->cap_members) ||
        (s->column_count && !s->columns) || !r->ring_offsets || !r->boxes ||
        (r->seam_count && (!r->seam_parts || !r->planes)) || !r->start_offsets || !world)
        return sk_fail(error, SK_ERROR_ARGUMENT, "an array is NULL");
    if (!s->part_count || !s->point_count || !s->triangle_count || !frame_count)
        return sk_fail(error, SK_ERROR_ARGUMENT, "no parts, points, triangles or frames");
    if (s->point_count > INT32_MAX / 2 || s->triangle_count > INT32_MAX / 12)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%zu points, %zu triangles: too many for 32-bit indices",
                       s->point_count, s->triangle_count);
    sk_status status;
    if ((status = check_indices(s->triangles, 3 * s->triangle_count, 0, s->point_count, "triangles", error)) ||
        (status = check_indices(s->twins, 3 * s->triangle_count, -1, 3 * s->triangle_count, "twins", error)) ||
        (status = check_offsets(r->ring_offsets, s->point_count, "ring_offsets", error)))
        return status;
    if ((r->ring_offsets[s->point_count] && !r->ring) ||
        (r->start_offsets[2 * r->seam_count] && !r->starts))
        return sk_fail(error, SK_ERROR_ARGUMENT, "ring or starts is NULL");
    if ((status = check_indices(r->ring, (size_t)r->ring_offsets[s->point_count], 0, s->point_count, "ring",
                                error)) ||
        (status = check_indices(r->seam_parts, 2 * r->seam_count, 0, s->part_count, "seam_parts", error)) ||
        (status = check_offsets(r->start_offsets, 2 * r->seam_count, "start_offsets", error)) ||
        (status = check_indices(r->starts, (size_t)r->start_offsets[2 * r->seam_count], 0, s->point_count,
                                "starts", error)))
        return status;
    if (s->column_count && (s->column_width < 3 || s->column_width > MAX_COLUMN_STEPS + 2))
        return sk_fail(error, SK_ERROR_ARGUMENT, "column_width %zu: columns hold their two ends and 1 to %d arc points",
                       s->column_width, MAX_COLUMN_STEPS);
    if ((status = check_indices(s->columns, s->column_count * s->column_width, 0, s->point_count, "columns",
                                error)))
        return status;
    for (size_t k = 0; k < s->cap_member_count; ++k)
        if (s->cap_members[2 * k] < 0 || (size_t)s->cap_members[2 * k] >= s->point_count ||
            s->cap_members[2 * k + 1] < 0 || (size_t)s->cap_members[2 * k + 1] >= s->point_count)
            return sk_fail(error, SK_ERROR_INDEX, "cap_members row %zu = (%d, %d): not (centre, ring point)", k,
                           s->cap_members[2 * k], s->cap_members[2 * k + 1]);
    for (size_t k = 0; k < s->column_count; ++k) {
        const int32_t *row = s->columns + k * s->column_width;
        for (size_t i = 1; i + 1 < s->column_width; ++i)
            if (s->parts_b[row[i]] < 0)
                return sk_fail(error, SK_ERROR_ARGUMENT, "column %zu: point %d is not an arc point (parts_b -1)", k,
                               row[i]);
    }
    if (!sk_all_finite(r->boxes, 15 * s->part_count) || !sk_all_finite(r->planes, 6 * r->seam_count))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "a box or an opening plane is not finite");
    size_t world_size;
    if (!sk_mul_size(16 * s->part_count, frame_count, &world_size) || !sk_all_finite(world, world_size))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "world is not finite");
    return SK_OK;
}

/* ---- per-call scratch ---------------------------------------------------------------------------------------- */

typedef struct fill_item {
    double angle;
    int32_t corner, stamp;
} fill_item;

static int fill_item_less(const void *a, const void *b)
{
    const fill_item *x = a, *y = b;
    if (x->angle != y->angle)
        return x->angle < y->angle;
    if (x->corner != y->corner)
        return x->corner < y->corner;
    return x->stamp < y->stamp;
}

/* An open-addressing set of undirected edges (key u * 2^32 + v, u < v; 0 is never a key since u < v). */
typedef struct edge_set {
    uint64_t *keys;
    size_t mask, count;
} edge_set;

static uint64_t edge_key(int32_t a, int32_t b)
{
    const uint64_t low = (uint64_t)(a < b ? a : b), high = (uint64_t)(a < b ? b : a);
    return (low << 32) | high;
}

static size_t edge_slot(const edge_set *set, uint64_t key)
{
    size_t slot = (size_t)((key * 0x9E3779B97F4A7C15ull) >> 17) & set->mask;
    while (set->keys[slot] && set->keys[slot] != key)
        slot = (slot + 1) & set->mask;
    return slot;
}

static int edge_set_has(const edge_set *set, uint64_t key)
{
    return set->keys[edge_slot(set, key)] == key;
}

static void edge_set_add(edge_set *set, uint64_t key)
{
    const size_t slot = edge_slot(set, key);
    if (!set->keys[slot]) {
        set->keys[slot] = key;
        ++set->count;
    }
}

typedef struct scratch {
    size_t points, triangles, half_edges; /* capacities */
    double *positions;                    /* the frame's points then its fill centres */
    double *cap_sums;                     /* 4 per point: a cap centre's ring sum and count */
    unsigned char *removed, *keep, *on_border, *island_seen, *island_big;
    int32_t *visited_stamp, *queue, *open_edges, *out_count, *out_start, *out_items, *out_left, *first_order;
    int32_t *stack_position, *walk, *stack, *loop_offsets, *loop_vertices;
    int32_t *candidates, *piece_stamp, *piece, *compact;
    int32_t *before, *after, *version, *alive, *refused, *order;
    int32_t *component, *vertex_component, *partner; /* bridging: triangle classes, per point, per loop */
    fill_item *heap;
    size_t heap_capacity;
    int32_t visit, flood; /* the last stamps written into visited_stamp and piece_stamp (kept across frames) */
    edge_set edges;
} scratch;

static void scratch_free(scratch *w)
{
    void *pointers[] = {w->positions, w->cap_sums, w->removed, w->keep, w->on_border, w->island_seen, w->island_big,
                        w->visited_stamp, w->queue, w->open_edges, w->out_count, w->out_start, w->out_items,
                        w->out_left, w->first_order, w->stack_position, w->walk, w->stack, w->loop_offsets,
                        w->loop_vertices, w->candidates, w->piece_stamp, w->piece, w->compact, w->before, w->after,
                        w->version, w->alive, w->refused, w->order, w->heap, w->edges.keys, w->component,
                        w->vertex_component, w->partner};
    sk_free_all(pointers, sizeof pointers / sizeof pointers[0]);
    memset(w, 0, sizeof *w);
}

static int scratch_make(scratch *w, size_t points, size_t triangles)
{
    memset(w, 0, sizeof *w);
    w->points = points + triangles; /* the points and at most one fill centre per removed triangle */
    w->triangles = 4 * triangles;   /* kept ones plus at most three fill triangles per removed one */
    w->half_edges = 3 * triangles;
    size_t edge_slots = 1;
    while (edge_slots < 8 * w->half_edges + 16) /* twice the candidates' directed edges */
        edge_slots <<= 1;
    w->edges.mask = edge_slots - 1; /* the most slots; fill_holes uses as many as it needs */
    const size_t p = w->points, h = w->half_edges + 1;
    w->positions = sk_allocate(p, 3 * sizeof(double));
    w->cap_sums = sk_allocate(points, 4 * sizeof(double));
    w->removed = sk_allocate(p, 1);
    w->keep = sk_allocate(triangles, 1);
    w->on_border = sk_allocate_zeroed(p, 1);
    w->island_seen = sk_allocate(triangles, 1);
    w->island_big = sk_allocate(triangles, 1);
    w->visited_stamp = sk_allocate_zeroed(p, sizeof(int32_t));
    w->queue = sk_allocate(p, sizeof(int32_t));
    w->open_edges = sk_allocate(h, sizeof(int32_t));
    w->out_count = sk_allocate_zeroed(p, sizeof(int32_t));
    w->out_start = sk_allocate(p, sizeof(int32_t));
    w->out_items = sk_allocate(h, sizeof(int32_t));
    w->out_left = sk_allocate_zeroed(p, sizeof(int32_t));
    w->first_order = sk_allocate(h, sizeof(int32_t));
    w->stack_position = sk_allocate(p, sizeof(int32_t));
    w->walk = sk_allocate(h, sizeof(int32_t));
    w->stack = sk_allocate(h, sizeof(int32_t));
    w->loop_offsets = sk_allocate(h + 1, sizeof(int32_t));
    w->loop_vertices = sk_allocate(h, sizeof(int32_t));
    w->candidates = sk_allocate(w->triangles, 3 * sizeof(int32_t));
    w->piece_stamp = sk_allocate_zeroed(triangles, sizeof(int32_t));
    w->piece = sk_allocate(triangles, sizeof(int32_t));
    w->compact = sk_allocate(p, sizeof(int32_t));
    w->before = sk_allocate(h, sizeof(int32_t));
    w->after = sk_allocate(h, sizeof(int32_t));
    w->version = sk_allocate(h, sizeof(int32_t));
    w->alive = sk_allocate(h, sizeof(int32_t));
    w->refused = sk_allocate(h, sizeof(int32_t));
    w->order = sk_allocate(h, sizeof(int32_t));
    w->edges.keys = sk_allocate_zeroed(edge_slots, sizeof(uint64_t));
    w->component = sk_allocate(triangles, sizeof(int32_t));
    w->vertex_component = sk_allocate(p, sizeof(int32_t));
    w->partner = sk_allocate(h + 1, sizeof(int32_t));
    if (!w->positions || !w->cap_sums || !w->removed || !w->keep || !w->on_border || !w->island_seen ||
        !w->island_big ||
        !w->visited_stamp || !w->queue || !w->open_edges || !w->out_count || !w->out_start || !w->out_items ||
        !w->out_left || !w->first_order || !w->stack_position || !w->walk || !w->stack || !w->loop_offsets ||
        !w->loop_vertices || !w->candidates || !w->piece_stamp || !w->piece || !w->compact || !w->before ||
        !w->after || !w->version || !w->alive || !w->refused || !w->order || !w->edges.keys || !w->component ||
        !w->vertex_component || !w->partner) {
        scratch_free(w);
        return 0;
    }
    for (size_t k = 0; k < p; ++k)
        w->stack_position[k] = -1;
    return 1;
}

/* A fresh stamp for a visited-marks array (stamps differ from every mark left in it; it is cleared on wrap). */
static int32_t next_stamp(int32_t *counter, int32_t *marks, size_t count)
{
    if (*counter == INT32_MAX) {
        memset(marks, 0, count * sizeof(int32_t));
        *counter = 0;
    }
    return ++*counter;
}

/* ---- add: rigid points, arcs, conic middle points, cap centres ------------------------------------------- */

/* The conic arc of one column (section 4.4.2, S2): in the plane PL through the deeper part's posed joint and both
 * parts' posed centres, from the column's end on part a (tangent along a's axis toward the joint) to its end on
 * part b (along b's axis toward the joint), through V_m = (I_P + InB) / 2 with InB the ends' midpoint and I_P the
 * tangents' crossing; the offsets off the plane are blended along the arc. 0 (the QLERP arc kept) when PL or the
 * conic is degenerate. */
static int conic_column(double *positions, const int32_t *row, size_t steps, const sk_seam_topology *s,
                        const sk_seam_removal *r, const double *world)
{
    const int32_t a = s->parts_a[row[1]], b = s->parts_b[row[1]];
    double joint[3], centre_a[3], centre_b[3];
    transform_point(joint, world + 16 * (size_t)b, s->joints + 3 * (size_t)b);
    transform_point(centre_a, world + 16 * (size_t)a, r->boxes + 15 * (size_t)a);
    transform_point(centre_b, world + 16 * (size_t)b, r->boxes + 15 * (size_t)b);
    const double axis_a[3] = {joint[0] - centre_a[0], joint[1] - centre_a[1], joint[2] - centre_a[2]};
    const double axis_b[3] = {joint[0] - centre_b[0], joint[1] - centre_b[1], joint[2] - centre_b[2]};
    plane2 plane;
    if (!plane_from(&plane, joint, axis_a, axis_b))
        return 0; /* the parts in line: no bend to round */
    double normal[3];
    sk_cross3(normal, plane.e1, plane.e2);
    const double *start = positions + 3 * (size_t)row[0], *end = positions + 3 * (size_t)row[steps + 1];
    if (sk_distance3(start, end) <= 1e-9 * (sqrt(sk_dot3(axis_a, axis_a)) + sqrt(sk_dot3(axis_b, axis_b))))
        return 0; /* the column has not opened */
    double c[2], d[2], v[2], u[2], crossing[2], middle[2], control[2], w;
    to_plane(c, &plane, start);
    to_plane(d, &plane, end);
    direction_to_plane(v, &plane, axis_a);
    direction_to_plane(u, &plane, axis_b);
    const double turn = v[0] * u[1] - v[1] * u[0];
    if (fabs(turn) < 1e-12)
        return 0;
    const double along = ((d[0] - c[0]) * u[1] - (d[1] - c[1]) * u[0]) / turn; /* c + along v is on d's line */
    crossing[0] = c[0] + along * v[0];
    crossing[1] = c[1] + along * v[1];
    middle[0] = 0.5 * (crossing[0] + 0.5 * (c[0] + d[0])); /* V_m = (I_P + InB) / 2 */
    middle[1] = 0.5 * (crossing[1] + 0.5 * (c[1] + d[1]));
    const double tangent_v[2] = {crossing[0] - c[0], crossing[1] - c[1]}, tangent_u[2] = {crossing[0] - d[0],
                                                                                         crossing[1] - d[1]};
    if (!(along > 0.0) || !(tangent_u[0] * u[0] + tangent_u[1] * u[1] > 0.0) ||
        !conic_control(control, &w, c, tangent_v, d, tangent_u, middle))
        return 0;
    double flat[2 * MAX_COLUMN_STEPS], fractions[MAX_COLUMN_STEPS];
    conic_sample(flat, fractions, steps, c, control, w, d);
    const double offset_c = sk_dot3((const double[3]){start[0] - joint[0], start[1] - joint[1], start[2] - joint[2]},
                                    normal);
    const double offset_d = sk_dot3((const double[3]){end[0] - joint[0], end[1] - joint[1], end[2] - joint[2]},
                                    normal);
    for (size_t k = 0; k < steps; ++k)
        from_plane(positions + 3 * (size_t)row[k + 1], &plane, flat + 2 * k,
                   (1.0 - fractions[k]) * offset_c + fractions[k] * offset_d, normal);
    return 1;
}

static sk_status add_points(double *positions, double *cap_sums, size_t *conic_columns, const sk_seam_topology *s,
                            const sk_seam_removal *r, const double *world, int conic_arcs, sk_error *error)
{
    sk_status status = sk_evaluate_seams(positions, s->rest_positions, world, s->joints, s->sources, s->parts_a,
                                         s->parts_b, s->blend, s->point_count, s->vertex_count, s->part_count, error);
    if (status)
        return status;
    *conic_columns = 0;
    if (conic_arcs)
        for (size_t k = 0; k < s->column_count; ++k)
            *conic_columns += (size_t)conic_column(positions, s->columns + k * s->column_width, s->column_width - 2, s,
                                                   r, world);
    for (size_t k = 0; k < s->cap_member_count; ++k)
        memset(cap_sums + 4 * (size_t)s->cap_members[2 * k], 0, 4 * sizeof(double));
    for (size_t k = 0; k < s->cap_member_count; ++k) {
        double *sum = cap_sums + 4 * (size_t)s->cap_members[2 * k];
        const double *p = positions + 3 * (size_t)s->cap_members[2 * k + 1];
        sum[0] += p[0];
        sum[1] += p[1];
        sum[2] += p[2];
        sum[3] += 1.0;
    }
    for (size_t k = 0; k < s->cap_member_count; ++k) {
        const double *sum = cap_sums + 4 * (size_t)s->cap_members[2 * k];
        for (int i = 0; i < 3; ++i)
            positions[3 * (size_t)s->cap_members[2 * k] + i] = sum[i] / sum[3];
    }
    return SK_OK;
}

/* ---- remove: sinking points (section 4.4.1) ------------------------------------------------------------------ */

/* Whether point p (rest position q) lies in part's posed box and crossed its posed opening plane (on the plane's
 * positive side now, not at rest: curved openings leave rest points on both sides of their best-fit plane). */
static int sinks_into(const double p[3], const double q[3], const double *world, const sk_seam_removal *r,
                      size_t part, const double centre[3], const double normal[3], double sign)
{
    const double *m = world + 16 * part;
    const double d[3] = {p[0] - m[3], p[1] - m[7], p[2] - m[11]};
    double rest[3];
    for (int j = 0; j < 3; ++j)
        rest[j] = d[0] * m[j] + d[1] * m[4 + j] + d[2] * m[8 + j]; /* R^T (p - t) */
    const double *box_centre = r->boxes + 15 * part, *axes = box_centre + 3, *halves = box_centre + 12;
    for (int k = 0; k < 3; ++k) {
        const double local = (rest[0] - box_centre[0]) * axes[3 * k] + (rest[1] - box_centre[1]) * axes[3 * k + 1] +
                             (rest[2] - box_centre[2]) * axes[3 * k + 2];
        if (!(fabs(local) <= halves[k]))
            return 0;
    }
    const double now = sign * ((rest[0] - centre[0]) * normal[0] + (rest[1] - centre[1]) * normal[1] +
                               (rest[2] - centre[2]) * normal[2]);
    const double before = sign * ((q[0] - centre[0]) * normal[0] + (q[1] - centre[1]) * normal[1] +
                                  (q[2] - centre[2]) * normal[2]);
    return now > 0.0 && before <= 0.0;
}

/* Region growing from each seam's opening copies into the other part (a visited set; the thesis' listing has
 * none), on the same-part 1-rings. Returns how many points were removed. */
static size_t remove_sinking(scratch *w, const double *positions, const sk_seam_topology *s,
                             const sk_seam_removal *r, const double *world)
{
    size_t removed = 0;
    for (size_t seam = 0; seam < r->seam_count; ++seam)
        for (int side = 0; side < 2; ++side) {
            const size_t other = (size_t)r->seam_parts[2 * seam + (side ? 0 : 1)];
            const double sign = side ? -1.0 : 1.0;
            const int32_t stamp = next_stamp(&w->visit, w->visited_stamp, w->points);
            size_t head = 0, tail = 0;
            for (int32_t k = r->start_offsets[2 * seam + side]; k < r->start_offsets[2 * seam + side + 1]; ++k) {
                const int32_t v = r->starts[k];
                if (w->visited_stamp[v] != stamp) {
                    w->visited_stamp[v] = stamp;
                    w->queue[tail++] = v;
                }
            }
            while (head < tail) {
                const int32_t v = w->queue[head++];
                if (!sinks_into(positions + 3 * (size_t)v, s->rest_positions + 3 * (size_t)s->sources[v], world, r,
                                other, r->planes + 6 * seam, r->planes + 6 * seam + 3, sign))
                    continue;
                if (!w->removed[v]) {
                    w->removed[v] = 1;
                    ++removed;
                }
                for (int32_t k = r->ring_offsets[v]; k < r->ring_offsets[v + 1]; ++k) {
                    const int32_t n = r->ring[k];
                    if (w->visited_stamp[n] != stamp) {
                        w->visited_stamp[n] = stamp;
                        w->queue[tail++] = n;
                    }
                }
            }
        }
    return removed;
}

/* ---- triangulate: the holes' borders and their advancing-front fill ---------------------------------------- */

static int32_t next_corner(int32_t half_edge)
{
    return 3 * (half_edge / 3) + (half_edge % 3 + 1) % 3;
}

/* The kept triangles' half-edges whose twin's triangle is removed, ascending. */
static size_t open_half_edges(scratch *w, const sk_seam_topology *s)
{
    size_t count = 0;
    for (size_t e = 0; e < 3 * s->triangle_count; ++e) {
        const int32_t twin = s->twins[e];
        if (w->keep[e / 3] && twin >= 0 && !w->keep[twin / 3])
            w->open_edges[count++] = (int32_t)e;
    }
    return count;
}

/* Border vertices with two or more outgoing open half-edges (two gaps in their fan) are marked removed. */
static size_t remove_pinched(scratch *w, const sk_seam_topology *s, size_t open_count)
{
    size_t pinched = 0;
    for (size_t k = 0; k < open_count; ++k)
        ++w->out_count[s->triangles[w->open_edges[k]]];
    for (size_t k = 0; k < open_count; ++k) {
        const int32_t v = s->triangles[w->open_edges[k]];
        if (w->out_count[v] > 1 && !w->removed[v]) {
            w->removed[v] = 1;
            ++pinched;
        }
    }
    for (size_t k = 0; k < open_count; ++k)
        w->out_count[s->triangles[w->open_edges[k]]] = 0;
    return pinched;
}

/* Splits a closed walk where it passes a vertex twice, appending each simple loop of >= 3 vertices. */
static void simple_loops(scratch *w, size_t walk_length, size_t *loop_count, size_t *vertex_count)
{
    size_t depth = 0;
    for (size_t k = 0; k < walk_length; ++k) {
        const int32_t vertex = w->walk[k];
        const int32_t start = w->stack_position[vertex];
        if (start >= 0) {
            if (depth - (size_t)start >= 3) {
                memcpy(w->loop_vertices + *vertex_count, w->stack + start, (depth - (size_t)start) * sizeof(int32_t));
                *vertex_count += depth - (size_t)start;
                w->loop_offsets[++*loop_count] = (int32_t)*vertex_count;
            }
            for (size_t gone = (size_t)start + 1; gone < depth; ++gone)
                w->stack_position[w->stack[gone]] = -1;
            depth = (size_t)start + 1;
        } else {
            w->stack_position[vertex] = (int32_t)depth;
            w->stack[depth++] = vertex;
        }
    }
    if (depth >= 3) {
        memcpy(w->loop_vertices + *vertex_count, w->stack, depth * sizeof(int32_t));
        *vertex_count += depth;
        w->loop_offsets[++*loop_count] = (int32_t)*vertex_count;
    }
    for (size_t k = 0; k < depth; ++k)
        w->stack_position[w->stack[k]] = -1;
}

/* The holes' borders walked into closed loops in the kept triangles' direction, each split into simple loops.
 * The walk order follows the open half-edges' order (a vertex's last outgoing edge taken first). */
static size_t border_loops(scratch *w, const sk_seam_topology *s, size_t open_count)
{
    size_t distinct = 0;
    for (size_t k = 0; k < open_count; ++k) {
        const int32_t u = s->triangles[w->open_edges[k]];
        if (!w->out_count[u]++)
            w->first_order[distinct++] = u;
    }
    int32_t running = 0;
    for (size_t k = 0; k < distinct; ++k) {
        const int32_t u = w->first_order[k];
        w->out_start[u] = running;
        running += w->out_count[u];
        w->out_left[u] = 0;
    }
    for (size_t k = 0; k < open_count; ++k) {
        const int32_t u = s->triangles[w->open_edges[k]];
        w->out_items[w->out_start[u] + w->out_left[u]++] = s->triangles[next_corner(w->open_edges[k])];
    }
    size_t loop_count = 0, vertex_count = 0, cursor = 0;
    w->loop_offsets[0] = 0;
    for (;;) {
        while (cursor < distinct && !w->out_left[w->first_order[cursor]])
            ++cursor;
        if (cursor == distinct)
            break;
        int32_t u = w->first_order[cursor];
        size_t length = 0;
        w->walk[length++] = u;
        for (;;) {
            const int32_t v = w->out_items[w->out_start[u] + --w->out_left[u]];
            if (v == w->walk[0])
                break;
            w->walk[length++] = v;
            u = v;
            if (!w->out_left[u])
                break;
        }
        simple_loops(w, length, &loop_count, &vertex_count);
    }
    for (size_t k = 0; k < distinct; ++k)
        w->out_count[w->first_order[k]] = 0;
    return loop_count;
}

static int push_corner(scratch *w, size_t *heap_count, const double *positions, const int32_t *loop, int32_t k)
{
    const fill_item item = {corner_angle(positions + 3 * (size_t)loop[w->before[k]], positions + 3 * (size_t)loop[k],
                                         positions + 3 * (size_t)loop[w->after[k]]),
                            k, w->version[k]};
    return sk_heap_insert(&w->heap, heap_count, &w->heap_capacity, &item, sizeof item, 64, fill_item_less);
}

static void append_triangle(int32_t *triangles, size_t *count, int32_t a, int32_t b, int32_t c)
{
    triangles[3 * *count] = a;
    triangles[3 * *count + 1] = b;
    triangles[3 * *count + 2] = c;
    ++*count;
}

/* Closes one hole whose border runs loop[0] -> loop[1] -> ... : an advancing front clipping the corner of
 * smallest angle first, refusing a diagonal that is already an edge (it would make the mesh non-manifold); what
 * cannot be clipped is fanned to a new point at its mean (*points grows by one). 0 when memory ran out. */
static int fill_loop(scratch *w, edge_set *edges, size_t *triangle_count, size_t *points, const int32_t *loop,
                     size_t n)
{
    size_t heap_count = 0, remaining = n, refused = 0;
    for (size_t k = 0; k < n; ++k) {
        w->before[k] = (int32_t)((k + n - 1) % n);
        w->after[k] = (int32_t)((k + 1) % n);
        w->alive[k] = 1;
        w->version[k] = 0;
    }
    for (size_t k = 0; k < n; ++k)
        if (!push_corner(w, &heap_count, w->positions, loop, (int32_t)k))
            return 0;
    while (remaining > 3 && heap_count) {
        fill_item top;
        sk_heap_pop_least(&top, w->heap, &heap_count, sizeof top, fill_item_less);
        const int32_t k = top.corner;
        if (!w->alive[k] || top.stamp != w->version[k])
            continue;
        const int32_t b = loop[w->before[k]], a = loop[w->after[k]];
        const uint64_t diagonal = edge_key(a, b);
        if (edge_set_has(edges, diagonal)) {
            w->refused[refused++] = k; /* may become clippable once a neighbour goes */
            continue;
        }
        append_triangle(w->candidates, triangle_count, a, loop[k], b); /* the fill runs against the border */
        edge_set_add(edges, diagonal);
        w->alive[k] = 0;
        --remaining;
        w->after[w->before[k]] = w->after[k];
        w->before[w->after[k]] = w->before[k];
        const int32_t neighbours[2] = {w->before[k], w->after[k]};
        for (int i = 0; i < 2; ++i) {
            ++w->version[neighbours[i]];
            if (!push_corner(w, &heap_count, w->positions, loop, neighbours[i]))
                return 0;
        }
        for (size_t i = 0; i < refused; ++i)
            if (w->alive[w->refused[i]]) {
                ++w->version[w->refused[i]];
                if (!push_corner(w, &heap_count, w->positions, loop, w->refused[i]))
                    return 0;
            }
        refused = 0;
    }
    size_t start = 0;
    while (!w->alive[start])
        ++start;
    size_t m = 0;
    int32_t k = (int32_t)start;
    do {
        w->order[m++] = loop[k];
        k = w->after[k];
    } while (k != (int32_t)start);
    if (m == 3) { /* its sides are border edges or diagonals used once so far */
        append_triangle(w->candidates, triangle_count, w->order[2], w->order[1], w->order[0]);
        return 1;
    }
    const int32_t centre = (int32_t)*points;
    double *mean = w->positions + 3 * *points;
    mean[0] = mean[1] = mean[2] = 0.0;
    for (size_t i = 0; i < m; ++i) {
        append_triangle(w->candidates, triangle_count, w->order[(i + 1) % m], w->order[i], centre);
        for (int j = 0; j < 3; ++j)
            mean[j] += w->positions[3 * (size_t)w->order[i] + j];
    }
    for (int j = 0; j < 3; ++j)
        mean[j] /= (double)m;
    ++*points;
    return 1;
}

/* A strip of triangles joining hole border a (n points) to hole border b (m points) of another piece: a zipper
 * from a[0] and b's nearest point, a forward and b backward (each border edge then runs against its kept
 * triangle), taking the shorter diagonal at each step. */
static void bridge_loops(scratch *w, size_t *triangle_count, const int32_t *a, size_t n, const int32_t *b, size_t m)
{
    const double *p = w->positions;
    size_t start = 0;
    for (size_t j = 1; j < m; ++j)
        if (sk_distance3(p + 3 * (size_t)a[0], p + 3 * (size_t)b[j]) <
            sk_distance3(p + 3 * (size_t)a[0], p + 3 * (size_t)b[start]))
            start = j;
    /* The front (i, j) must not come back to a pair it passed (mod n, m): never all of b's steps at one i (the
     * first step is along a; b's last step is not taken at the i of its first) nor all of a's at one j. */
    size_t i = 0, j = 0, first_b = SIZE_MAX; /* steps taken along a and along b */
    while (i < n || j < m) {
        const int32_t here_a = a[i % n], here_b = b[(start + m - j % m) % m];
        const int32_t next_a = a[(i + 1) % n], next_b = b[(start + 2 * m - j % m - 1) % m];
        int step_a;
        if (i == n || (i == n - 1 && j == 0))
            step_a = 0;
        else if (i == 0 || j == m || (j == m - 1 && i == first_b))
            step_a = 1;
        else
            step_a = sk_distance3(p + 3 * (size_t)next_a, p + 3 * (size_t)here_b) <=
                     sk_distance3(p + 3 * (size_t)here_a, p + 3 * (size_t)next_b);
        if (step_a) {
            append_triangle(w->candidates, triangle_count, next_a, here_a, here_b);
            ++i;
        } else {
            if (first_b == SIZE_MAX)
                first_b = i;
            append_triangle(w->candidates, triangle_count, here_a, here_b, next_b);
            ++j;
        }
    }
}

/* The kept triangles then the fill of every hole (into w->candidates); *points grows by the fill centres. With
 * partners (per loop: -1 capped, else the loop it is bridged to; the lower of a pair lays the strip), bridged
 * loops are joined instead of capped. */
static int fill_holes(scratch *w, size_t *triangle_count, size_t *points, const sk_seam_topology *s,
                      size_t loop_count, const int32_t *partners)
{
    *triangle_count = 0;
    for (size_t t = 0; t < s->triangle_count; ++t)
        if (w->keep[t])
            append_triangle(w->candidates, triangle_count, s->triangles[3 * t], s->triangles[3 * t + 1],
                            s->triangles[3 * t + 2]);
    if (!loop_count)
        return 1;
    const size_t border_count = (size_t)w->loop_offsets[loop_count];
    for (size_t k = 0; k < border_count; ++k)
        w->on_border[w->loop_vertices[k]] = 1;
    size_t needed = border_count;
    for (size_t t = 0; t < *triangle_count; ++t)
        for (int i = 0; i < 3; ++i)
            needed += w->on_border[w->candidates[3 * t + i]];
    size_t slots = 16;
    while (slots < 2 * needed && slots <= w->edges.mask)
        slots <<= 1;
    edge_set edges = {w->edges.keys, slots - 1, 0};
    memset(edges.keys, 0, slots * sizeof(uint64_t));
    for (size_t t = 0; t < *triangle_count; ++t) {
        const int32_t *corner = w->candidates + 3 * t;
        for (int i = 0; i < 3; ++i)
            if (w->on_border[corner[i]] && w->on_border[corner[(i + 1) % 3]])
                edge_set_add(&edges, edge_key(corner[i], corner[(i + 1) % 3]));
    }
    for (size_t k = 0; k < border_count; ++k)
        w->on_border[w->loop_vertices[k]] = 0;
    for (size_t loop = 0; loop < loop_count; ++loop) {
        const size_t first = (size_t)w->loop_offsets[loop], n = (size_t)w->loop_offsets[loop + 1] - first;
        const int32_t other = partners ? partners[loop] : -1;
        if (other < 0) {
            if (!fill_loop(w, &edges, triangle_count, points, w->loop_vertices + first, n))
                return 0;
        } else if ((size_t)other > loop) {
            const size_t second = (size_t)w->loop_offsets[other], m = (size_t)w->loop_offsets[other + 1] - second;
            bridge_loops(w, triangle_count, w->loop_vertices + first, n, w->loop_vertices + second, m);
        }
    }
    return 1;
}

typedef struct loop_pair {
    double distance;
    int32_t first, second;
} loop_pair;

static int loop_pair_order(const void *a, const void *b)
{
    const loop_pair *x = a, *y = b;
    if (x->distance != y->distance)
        return x->distance < y->distance ? -1 : 1;
    return x->first != y->first ? (x->first < y->first ? -1 : 1) : (x->second > y->second) - (x->second < y->second);
}

/* When a sunk band runs all round an opening, the kept surface falls into pieces that the caps close one by one.
 * The thesis joins the two sides' end points (section 4.4.2, S2); here the pieces are joined by strips between
 * their hole borders, nearest borders first, one bridge per pair of pieces that are not yet joined (Kruskal over
 * the pieces). Writes w->partner; 0 when there is nothing to bridge, too much, or memory ran out. */
static int plan_bridges(scratch *w, const sk_seam_topology *s, size_t loop_count)
{
    if (loop_count < 2 || loop_count > MAX_BRIDGED_LOOPS)
        return 0;
    int32_t *parent = w->component;
    for (size_t t = 0; t < s->triangle_count; ++t)
        parent[t] = (int32_t)t;
    for (size_t e = 0; e < 3 * s->triangle_count; ++e) {
        const int32_t twin = s->twins[e];
        if (w->keep[e / 3] && twin >= 0 && w->keep[twin / 3])
            sk_join_classes(parent, (int32_t)(e / 3), twin / 3);
    }
    for (size_t t = 0; t < s->triangle_count; ++t)
        if (w->keep[t])
            for (int i = 0; i < 3; ++i)
                w->vertex_component[s->triangles[3 * t + i]] = sk_find_root(parent, (int32_t)t);
    double centres[3 * MAX_BRIDGED_LOOPS];
    int32_t piece[MAX_BRIDGED_LOOPS];
    for (size_t loop = 0; loop < loop_count; ++loop) {
        const size_t first = (size_t)w->loop_offsets[loop], n = (size_t)w->loop_offsets[loop + 1] - first;
        double *centre = centres + 3 * loop;
        centre[0] = centre[1] = centre[2] = 0.0;
        for (size_t k = 0; k < n; ++k)
            for (int i = 0; i < 3; ++i)
                centre[i] += w->positions[3 * (size_t)w->loop_vertices[first + k] + i] / (double)n;
        piece[loop] = w->vertex_component[w->loop_vertices[first]];
        w->partner[loop] = -1;
    }
    const size_t pair_capacity = loop_count * (loop_count - 1) / 2;
    loop_pair *pairs = sk_allocate(pair_capacity, sizeof(loop_pair));
    if (!pairs)
        return 0;
    size_t pair_count = 0;
    for (size_t a = 0; a < loop_count; ++a)
        for (size_t b = a + 1; b < loop_count; ++b)
            if (piece[a] != piece[b])
                pairs[pair_count++] = (loop_pair){sk_distance3(centres + 3 * a, centres + 3 * b), (int32_t)a,
                                                  (int32_t)b};
    qsort(pairs, pair_count, sizeof(loop_pair), loop_pair_order);
    size_t bridges = 0;
    for (size_t k = 0; k < pair_count; ++k) {
        const int32_t a = pairs[k].first, b = pairs[k].second;
        if (w->partner[a] >= 0 || w->partner[b] >= 0 ||
            sk_find_root(parent, piece[a]) == sk_find_root(parent, piece[b]))
            continue;
        sk_join_classes(parent, piece[a], piece[b]);
        w->partner[a] = b;
        w->partner[b] = a;
        ++bridges;
    }
    free(pairs);
    return bridges > 0;
}

/* Small kept pieces cut off inside a sunk region: from each hole border a flood over kept triangles that stops past
 * ISLAND_CAP triangles; a flood that runs out first is an island, its vertices marked removed. Returns how many
 * vertices were newly marked. */
static size_t remove_islands(scratch *w, const sk_seam_topology *s, size_t open_count)
{
    memset(w->island_seen, 0, s->triangle_count);
    memset(w->island_big, 0, s->triangle_count);
    size_t marked = 0;
    for (size_t k = 0; k < open_count; ++k) {
        const int32_t first = w->open_edges[k] / 3;
        if (w->island_seen[first])
            continue;
        const int32_t stamp = next_stamp(&w->flood, w->piece_stamp, s->triangle_count);
        size_t piece = 0, queue = 0;
        int joined = 0;
        w->piece_stamp[first] = stamp;
        w->piece[piece++] = first;
        w->queue[queue++] = first;
        while (queue && piece <= ISLAND_CAP && !joined) {
            const int32_t t = w->queue[--queue];
            for (int i = 0; i < 3; ++i) {
                const int32_t twin = s->twins[3 * t + i];
                if (twin >= 0 && w->keep[twin / 3] && w->piece_stamp[twin / 3] != stamp) {
                    joined |= w->island_big[twin / 3];
                    w->piece_stamp[twin / 3] = stamp;
                    w->piece[piece++] = twin / 3;
                    w->queue[queue++] = twin / 3;
                }
            }
        }
        const int big = joined || queue;
        for (size_t i = 0; i < piece; ++i) {
            w->island_seen[w->piece[i]] = 1;
            if (big)
                w->island_big[w->piece[i]] = 1;
        }
        if (big)
            continue;
        for (size_t i = 0; i < piece; ++i)
            for (int j = 0; j < 3; ++j) {
                const int32_t v = s->triangles[3 * (size_t)w->piece[i] + j];
                if (!w->removed[v]) {
                    w->removed[v] = 1;
                    ++marked;
                }
            }
    }
    return marked;
}

/* ---- one frame ------------------------------------------------------------------------------------------------ */

typedef struct frame_result {
    size_t position_count, triangle_count, removed, fill_points, conic_columns;
    int fallback;
    double seconds[4]; /* add, remove, triangulate, normals */
} frame_result;

static void area_normals(double *normals, const double *positions, size_t position_count, const int32_t *triangles,
                         size_t triangle_count)
{
    memset(normals, 0, 3 * position_count * sizeof(double));
    for (size_t t = 0; t < triangle_count; ++t) {
        const double *a = positions + 3 * (size_t)triangles[3 * t], *b = positions + 3 * (size_t)triangles[3 * t + 1],
                     *c = positions + 3 * (size_t)triangles[3 * t + 2];
        const double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double face[3];
        sk_cross3(face, u, v);
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                normals[3 * (size_t)triangles[3 * t + i] + j] += face[j];
    }
    for (size_t k = 0; k < position_count; ++k) {
        double *n = normals + 3 * k;
        const double length = sqrt(sk_dot3(n, n));
        for (int j = 0; j < 3; ++j)
            n[j] = length > 0.0 ? n[j] / length : 0.0;
    }
}

/* Whether the candidate triangles on `points` points are one closed sphere: every directed edge once and its
 * reverse too (closed, edge-manifold, consistently oriented), and Euler's V - E + F = 2 with E = 3F / 2 (V the
 * points used, marked in w->compact). */
static int is_sphere(scratch *w, size_t points, size_t triangle_count)
{
    memset(w->compact, 0, points * sizeof(int32_t));
    for (size_t k = 0; k < 3 * triangle_count; ++k)
        w->compact[w->candidates[k]] = 1;
    size_t used = 0;
    for (size_t k = 0; k < points; ++k)
        used += (size_t)w->compact[k];
    if (2 * used != triangle_count + 4)
        return 0;
    size_t slots = 16;
    while (slots < 6 * triangle_count && slots <= w->edges.mask)
        slots <<= 1;
    edge_set directed = {w->edges.keys, slots - 1, 0};
    memset(directed.keys, 0, slots * sizeof(uint64_t));
    for (size_t t = 0; t < triangle_count; ++t)
        for (int i = 0; i < 3; ++i) {
            const uint64_t key =
                ((uint64_t)w->candidates[3 * t + i] << 32) | (uint64_t)w->candidates[3 * t + (i + 1) % 3];
            const size_t slot = edge_slot(&directed, key);
            if (directed.keys[slot] == key)
                return 0; /* an edge run the same way twice */
            directed.keys[slot] = key;
        }
    for (size_t t = 0; t < triangle_count; ++t)
        for (int i = 0; i < 3; ++i) {
            const uint64_t reverse = ((uint64_t)w->candidates[3 * t + (i + 1) % 3] << 32) |
                                     (uint64_t)w->candidates[3 * t + i];
            if (!edge_set_has(&directed, reverse))
                return 0; /* a border edge */
        }
    return 1;
}

/* Steps 2-3 of Algorithm 5 on w->positions: removal rounds until the filled surface is one closed sphere
 * (V - E + F = 2 with E = 3F / 2), else *fallback. The accepted triangles are left in w->candidates. */
static sk_status remove_and_fill(scratch *w, frame_result *result, const sk_seam_topology *s,
                                 const sk_seam_removal *r, const double *world, int remove, sk_error *error)
{
    const double started = sk_monotonic_seconds();
    memset(w->removed, 0, s->point_count);
    result->removed = remove ? remove_sinking(w, w->positions, s, r, world) : 0;
    const double removed_at = sk_monotonic_seconds();
    result->seconds[1] = removed_at - started;
    result->fallback = 1;
    size_t triangle_count = 0, points = s->point_count;
    for (int round = 0; round < FILL_ROUNDS; ++round) {
        for (size_t t = 0; t < s->triangle_count; ++t) {
            const int32_t *corner = s->triangles + 3 * t;
            w->keep[t] = !(w->removed[corner[0]] || w->removed[corner[1]] || w->removed[corner[2]]);
        }
        const size_t open_count = open_half_edges(w, s);
        const size_t pinched = remove_pinched(w, s, open_count);
        if (pinched) {
            result->removed += pinched;
            continue;
        }
        const size_t loop_count = border_loops(w, s, open_count);
        points = s->point_count;
        if (!fill_holes(w, &triangle_count, &points, s, loop_count, NULL))
            return sk_fail(error, SK_ERROR_MEMORY, "no memory for the hole fill");
        if (is_sphere(w, points, triangle_count)) {
            result->fallback = 0;
            break;
        }
        points = s->point_count;
        if (plan_bridges(w, s, loop_count)) { /* pieces first: a small real piece is no island */
            if (!fill_holes(w, &triangle_count, &points, s, loop_count, w->partner))
                return sk_fail(error, SK_ERROR_MEMORY, "no memory for the hole fill");
            if (is_sphere(w, points, triangle_count)) {
                result->fallback = 0;
                break;
            }
        }
        const size_t islands = remove_islands(w, s, open_count);
        if (!islands)
            break;
        result->removed += islands;
    }
    if (result->fallback) {
        memcpy(w->candidates, s->triangles, 3 * s->triangle_count * sizeof(int32_t));
        triangle_count = s->triangle_count;
        points = s->point_count;
        result->removed = 0;
        for (size_t k = 0; k < points; ++k)
            w->compact[k] = 1;
    }
    result->fill_points = points - s->point_count;
    result->triangle_count = triangle_count;
    result->position_count = points; /* before compaction */
    result->seconds[2] = sk_monotonic_seconds() - removed_at;
    return SK_OK;
}

static sk_status reconstruct_frame(frame_result *result, double *positions_out, int32_t *triangles_out,
                                   double *normals_out, scratch *w, const sk_seam_topology *s,
                                   const sk_seam_removal *r, const double *world, size_t position_capacity,
                                   size_t triangle_capacity, int remove, int conic_arcs, size_t frame,
                                   sk_error *error)
{
    const double started = sk_monotonic_seconds();
    sk_status status = add_points(w->positions, w->cap_sums, &result->conic_columns, s, r, world, conic_arcs, error);
    if (status)
        return status;
    result->seconds[0] = sk_monotonic_seconds() - started;
    if ((status = remove_and_fill(w, result, s, r, world, remove, error)))
        return status;
    const double normals_at = sk_monotonic_seconds();
    size_t kept = 0;
    for (size_t k = 0; k < result->position_count; ++k)
        w->compact[k] = w->compact[k] ? (int32_t)kept++ : -1;
    if (kept > position_capacity || result->triangle_count > triangle_capacity)
        return sk_fail(error, SK_ERROR_ARGUMENT,
                       "frame %zu has %zu points and %zu triangles: over position_capacity %zu or triangle_capacity "
                       "%zu", frame, kept, result->triangle_count, position_capacity, triangle_capacity);
    for (size_t k = 0; k < result->position_count; ++k)
        if (w->compact[k] >= 0)
            memcpy(positions_out + 3 * (size_t)w->compact[k], w->positions + 3 * k, 3 * sizeof(double));
    for (size_t k = 0; k < 3 * result->triangle_count; ++k)
        triangles_out[k] = w->compact[w->candidates[k]];
    result->position_count = kept;
    area_normals(normals_out, positions_out, kept, triangles_out, result->triangle_count);
    result->seconds[3] = sk_monotonic_seconds() - normals_at;
    return SK_OK;
}

sk_status sk_reconstruct_seams(double *positions, int32_t *triangles, double *normals, int32_t *frame_counts,
                               double *frame_seconds, const sk_seam_topology *topology,
                               const sk_seam_removal *removal, const double *world, size_t frame_count,
                               size_t position_capacity, size_t triangle_capacity, int remove_sinking,
                               int conic_arcs, sk_progress_fn progress, void *progress_user, sk_error *error)
{
    if (!positions || !triangles || !normals || !frame_counts || !frame_seconds || !topology || !removal)
        return sk_fail(error, SK_ERROR_ARGUMENT, "an array is NULL");
    sk_status status = check_inputs(topology, removal, world, frame_count, error);
    if (status)
        return status;
    size_t position_floats, triangle_ints;
    if (!sk_mul_size(3 * frame_count, position_capacity, &position_floats) ||
        !sk_mul_size(3 * frame_count, triangle_capacity, &triangle_ints))
        return sk_fail(error, SK_ERROR_ARGUMENT, "frame_count * capacity overflows");
    scratch w;
    if (!scratch_make(&w, topology->point_count, topology->triangle_count))
        return sk_fail(error, SK_ERROR_MEMORY, "no memory for the seam reconstruction of %zu points",
                       topology->point_count);
    for (size_t f = 0; f < frame_count && status == SK_OK; ++f) {
        frame_result result = {0};
        status = reconstruct_frame(&result, positions + 3 * position_capacity * f,
                                   triangles + 3 * triangle_capacity * f, normals + 3 * position_capacity * f, &w,
                                   topology, removal, world + 16 * topology->part_count * f, position_capacity,
                                   triangle_capacity, remove_sinking, conic_arcs, f, error);
        if (status)
            break;
        int32_t *counts = frame_counts + 6 * f;
        counts[0] = (int32_t)result.position_count;
        counts[1] = (int32_t)result.triangle_count;
        counts[2] = (int32_t)result.removed;
        counts[3] = (int32_t)result.fill_points;
        counts[4] = (int32_t)result.conic_columns;
        counts[5] = result.fallback;
        memcpy(frame_seconds + 4 * f, result.seconds, sizeof result.seconds);
        if (progress && progress(progress_user, (double)(f + 1) / (double)frame_count))
            status = sk_fail(error, SK_ERROR_CANCELLED, "cancelled after frame %zu of %zu", f + 1, frame_count);
    }
    scratch_free(&w);
    return status == SK_OK ? sk_succeed(error) : status;
}
