/*
 * A bounding-volume hierarchy over triangles for the ray-cast bake: the nearest hit along a segment and the
 * closest surface point within a distance. SPDX-License-Identifier: GPL-3.0-or-later
 *
 * Built as a binary tree by binned surface-area-heuristic splits (O(n log n), no sorting), then collapsed into
 * nodes of up to four children whose boxes are stored one axis at a time, so that a node's four box tests are a
 * handful of SSE2 operations (or the same comparisons in scalar code elsewhere). Both queries run one walk over the
 * tree with their own box measure and leaf test.
 *
 * Every triangle's box is padded a little beyond its corners, so a hit the intersection test accepts just outside
 * the triangle (its barycentric tolerance) still lies in its leaf's box: the answer is the best over all
 * triangles (nearest, then lowest index), whatever the tree's shape.
 */
#include <float.h>
#include <math.h>
#include <stdlib.h>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "sk_bake_internal.h"
#include "sk_internal.h"

#define LEAF_SIZE 4
#define BINS 16
/* Past this depth a node is halved by count (no reordering): the depth stays bounded on any input. */
#define SAH_DEPTH 40
#define MAX_DEPTH (SAH_DEPTH + 32)
/* Each 4-wide level leaves at most three siblings on the stack. */
#define STACK_SIZE (3 * MAX_DEPTH + SK_BVH_WIDTH)
/* A triangle's box grows by this fraction of its largest extent and of its largest coordinate: far more than the
 * intersection test's 1e-9 barycentric tolerance and the slab test's rounding. */
#define PAD_EXTENT 1e-7
#define PAD_MAGNITUDE 1e-13
#define INTERSECT_TOLERANCE 1e-9

/* ---------------------------------------------------------------------------------------------
 * The binary build
 * ------------------------------------------------------------------------------------------- */

typedef struct box {
    double low[3], high[3];
} box;

typedef struct binary_node {
    box bounds;
    int32_t first; /* a leaf's first entry in order[], or an inner node's left child (right = first + 1) */
    int32_t count; /* triangles in a leaf; 0 for an inner node */
} binary_node;

typedef struct builder {
    const box *boxes;      /* per triangle, padded */
    const double *centres; /* per triangle, its box's centre */
    int32_t *order;     /* the triangles, reordered into the leaves' ranges */
    binary_node *nodes; /* room for 2 * triangle_count */
    size_t node_count;
} builder;

static const double *corner_position(const sk_bake_surface *surface, int32_t triangle, int corner)
{
    return surface->positions + 3 * (size_t)surface->triangles[3 * (size_t)triangle + (size_t)corner];
}

static box empty_box(void) { return (box){{DBL_MAX, DBL_MAX, DBL_MAX}, {-DBL_MAX, -DBL_MAX, -DBL_MAX}}; }

static void grow_box(box *into, const box *by)
{
    for (int k = 0; k < 3; ++k) {
        into->low[k] = by->low[k] < into->low[k] ? by->low[k] : into->low[k];
        into->high[k] = by->high[k] > into->high[k] ? by->high[k] : into->high[k];
    }
}

/* Half the box's surface area (0 for an empty box). */
static double half_area(const box *b)
{
    const double x = b->high[0] - b->low[0], y = b->high[1] - b->low[1], z = b->high[2] - b->low[2];
    return x < 0 ? 0 : x * y + y * z + z * x;
}

static box padded_triangle_box(const sk_bake_surface *surface, int32_t triangle)
{
    box b = empty_box();
    double extent = 0, magnitude = 0;
    for (int c = 0; c < 3; ++c) {
        const double *p = corner_position(surface, triangle, c);
        grow_box(&b, &(box){{p[0], p[1], p[2]}, {p[0], p[1], p[2]}});
        for (int k = 0; k < 3; ++k)
            magnitude = fabs(p[k]) > magnitude ? fabs(p[k]) : magnitude;
    }
    for (int k = 0; k < 3; ++k)
        extent = b.high[k] - b.low[k] > extent ? b.high[k] - b.low[k] : extent;
    const double pad = PAD_EXTENT * extent + PAD_MAGNITUDE * magnitude;
    for (int k = 0; k < 3; ++k) {
        b.low[k] -= pad;
        b.high[k] += pad;
    }
    return b;
}

static int bin_of(double centre, double low, double scale)
{
    const int bin = (int)((centre - low) * scale);
    return bin < 0 ? 0 : (bin >= BINS ? BINS - 1 : bin);
}

typedef struct bin {
    box bounds, centres; /* the triangles' boxes, and their centres */
    size_t count;
} bin;

static bin empty_bin(void) { return (bin){empty_box(), empty_box(), 0}; }

static void merge_bin(bin *into, const bin *by)
{
    grow_box(&into->bounds, &by->bounds);
    grow_box(&into->centres, &by->centres);
    into->count += by->count;
}

/* The two sides of order[begin, end) (its boxes and centres) when it is halved by count, without reordering: for
 * coinciding centres and past SAH_DEPTH. */
static size_t halve(const builder *b, size_t begin, size_t end, bin sides[2])
{
    const size_t middle = begin + (end - begin) / 2;
    sides[0] = sides[1] = empty_bin();
    for (size_t i = begin; i < end; ++i) {
        const int32_t t = b->order[i];
        const double *c = b->centres + 3 * (size_t)t;
        bin *side = &sides[i >= middle];
        grow_box(&side->bounds, &b->boxes[t]);
        grow_box(&side->centres, &(box){{c[0], c[1], c[2]}, {c[0], c[1], c[2]}});
        ++side->count;
    }
    return middle;
}

/* The binned SAH split of order[begin, end) along the longest axis of its centres' box: reorders the range into its
 * two sides, fills their boxes and returns where the right one begins (halve() when the centres coincide). Only
 * splits that leave triangles on both sides are considered; ties go to the lower bin. */
static size_t sah_split(const builder *b, size_t begin, size_t end, const box *centres, bin sides[2])
{
    int axis = 0;
    for (int k = 1; k < 3; ++k)
        if (centres->high[k] - centres->low[k] > centres->high[axis] - centres->low[axis])
            axis = k;
    const double low = centres->low[axis], extent = centres->high[axis] - low, scale = BINS / extent;
    if (!(extent > 0) || !isfinite(scale)) /* coinciding centres, or so nearly that the scale overflows */
        return halve(b, begin, end, sides);
    bin bins[BINS];
    for (int i = 0; i < BINS; ++i)
        bins[i] = empty_bin();
    for (size_t i = begin; i < end; ++i) {
        const int32_t t = b->order[i];
        const double *c = b->centres + 3 * (size_t)t;
        bin *into = &bins[bin_of(c[axis], low, scale)];
        grow_box(&into->bounds, &b->boxes[t]);
        grow_box(&into->centres, &(box){{c[0], c[1], c[2]}, {c[0], c[1], c[2]}});
        ++into->count;
    }
    bin right[BINS]; /* right[i]: bins i + 1 .. BINS - 1 together */
    right[BINS - 2] = bins[BINS - 1];
    for (int i = BINS - 3; i >= 0; --i) {
        right[i] = right[i + 1];
        merge_bin(&right[i], &bins[i + 1]);
    }
    bin left = empty_bin();
    double best = INFINITY;
    int split_bin = -1;
    for (int i = 0; i < BINS - 1; ++i) {
        merge_bin(&left, &bins[i]);
        if (left.count == 0 || right[i].count == 0)
            continue;
        const double cost = half_area(&left.bounds) * (double)left.count + half_area(&right[i].bounds) * (double)right[i].count;
        if (cost < best) {
            best = cost;
            split_bin = i;
            sides[0] = left;
            sides[1] = right[i];
        }
    }
    size_t i = begin, j = end; /* split_bin >= 0: the extent is positive, so the first and last bins are used */
    while (i < j) {
        if (bin_of(b->centres[3 * (size_t)b->order[i] + (size_t)axis], low, scale) <= split_bin) {
            ++i;
        } else {
            const int32_t swap = b->order[i];
            b->order[i] = b->order[--j];
            b->order[j] = swap;
        }
    }
    return i;
}

/* Builds node `index` over order[begin, end) (its triangles' boxes and centres in `all`) and its subtree. */
static void split(builder *b, size_t index, size_t begin, size_t end, const bin *all, int depth)
{
    b->nodes[index].bounds = all->bounds;
    if (end - begin <= LEAF_SIZE) {
        b->nodes[index].first = (int32_t)begin;
        b->nodes[index].count = (int32_t)(end - begin);
        return;
    }
    bin sides[2];
    const size_t middle = depth < SAH_DEPTH ? sah_split(b, begin, end, &all->centres, sides) : halve(b, begin, end, sides);
    const size_t left = b->node_count;
    b->node_count += 2;
    b->nodes[index].first = (int32_t)left;
    b->nodes[index].count = 0;
    split(b, left, begin, middle, &sides[0], depth + 1);
    split(b, left + 1, middle, end, &sides[1], depth + 1);
}

/* ---------------------------------------------------------------------------------------------
 * Collapsing the binary tree into 4-wide nodes
 * ------------------------------------------------------------------------------------------- */

/* Gives binary leaf `leaf` the next block of SK_BVH_WIDTH entries: its triangles (the rest -1, with zero corners)
 * and their corners, one component at a time (SIMD reads two or four triangles' x of corner 0 at once). Returns the
 * block's first entry. */
static int32_t place_leaf(sk_bvh *bvh, const int32_t *build_order, const binary_node *leaf)
{
    const size_t first = bvh->entry_count;
    bvh->entry_count += SK_BVH_WIDTH;
    double *block = bvh->corners + 9 * first;
    for (size_t lane = 0; lane < SK_BVH_WIDTH; ++lane) {
        const int32_t t = lane < (size_t)leaf->count ? build_order[(size_t)leaf->first + lane] : -1;
        bvh->order[first + lane] = t;
        if (t < 0)
            continue;
        bvh->entry_of[t] = (int32_t)(first + lane);
        const double *p0 = corner_position(bvh->surface, t, 0), *p1 = corner_position(bvh->surface, t, 1),
                     *p2 = corner_position(bvh->surface, t, 2);
        for (size_t k = 0; k < 3; ++k) {
            block[SK_BVH_WIDTH * k + lane] = p0[k];
            block[SK_BVH_WIDTH * (3 + k) + lane] = p1[k] - p0[k];
            block[SK_BVH_WIDTH * (6 + k) + lane] = p2[k] - p0[k];
        }
    }
    return (int32_t)first;
}

/* Writes the 4-wide node for binary inner node `index` (and its subtree) and returns its index: its children are
 * the binary node's, each inner one with the largest box replaced by its own two children until there are four. */
static int32_t collapse(sk_bvh *bvh, const binary_node *binary, const int32_t *build_order, size_t index)
{
    size_t slot_nodes[SK_BVH_WIDTH] = {(size_t)binary[index].first, (size_t)binary[index].first + 1};
    int slots = 2;
    while (slots < SK_BVH_WIDTH) {
        int widest = -1;
        for (int s = 0; s < slots; ++s)
            if (binary[slot_nodes[s]].count == 0 &&
                (widest < 0 || half_area(&binary[slot_nodes[s]].bounds) > half_area(&binary[slot_nodes[widest]].bounds)))
                widest = s;
        if (widest < 0)
            break;
        const size_t opened = slot_nodes[widest];
        slot_nodes[widest] = (size_t)binary[opened].first;
        slot_nodes[slots++] = (size_t)binary[opened].first + 1;
    }
    const int32_t me = (int32_t)bvh->node_count++;
    bvh->nodes[me] = (sk_bvh_node){.slots = slots};
    for (int s = 0; s < slots; ++s) {
        const binary_node *child = &binary[slot_nodes[s]];
        const int32_t placed =
            child->count ? place_leaf(bvh, build_order, child) : collapse(bvh, binary, build_order, slot_nodes[s]);
        sk_bvh_node *node = &bvh->nodes[me];
        for (int k = 0; k < 3; ++k) {
            node->low[k][s] = child->bounds.low[k];
            node->high[k][s] = child->bounds.high[k];
        }
        node->child[s] = placed;
        node->count[s] = child->count;
    }
    return me;
}

int sk_bvh_has_sse2(void)
{
#if defined(__SSE2__)
    return 1;
#else
    return 0;
#endif
}

/* The binary tree over every triangle, with build_order[] its leaves' triangles, or NULL when memory ran out;
 * *node_count its nodes. */
static binary_node *build_binary(const sk_bake_surface *surface, int32_t *build_order, size_t *node_count)
{
    const size_t count = surface->triangle_count;
    box *boxes = sk_allocate(count, sizeof *boxes);
    double *centres = sk_allocate(count, 3 * sizeof *centres);
    binary_node *nodes = sk_allocate(count ? 2 * count : 1, sizeof *nodes);
    if (!boxes || !centres || !nodes) {
        SK_FREE_ALL(boxes, centres, nodes);
        return NULL;
    }
    for (size_t t = 0; t < count; ++t) {
        build_order[t] = (int32_t)t;
        boxes[t] = padded_triangle_box(surface, (int32_t)t);
        for (int k = 0; k < 3; ++k)
            centres[3 * t + (size_t)k] = 0.5 * (boxes[t].low[k] + boxes[t].high[k]);
    }
    builder b = {boxes, centres, build_order, nodes, 1};
    bin all[2];
    halve(&b, 0, count, all);
    merge_bin(&all[0], &all[1]);
    split(&b, 0, 0, count, &all[0], 0);
    SK_FREE_ALL(boxes, centres);
    *node_count = b.node_count;
    return nodes;
}

sk_status sk_bvh_build(sk_bvh *bvh, const sk_bake_surface *surface, sk_error *error)
{
    const size_t count = surface->triangle_count;
    *bvh = (sk_bvh){.surface = surface, .kernel = sk_bvh_has_sse2() ? SK_BVH_SSE2 : SK_BVH_SCALAR};
    int32_t *build_order = sk_allocate(count, sizeof *build_order);
    size_t binary_count = 0;
    binary_node *binary = count > INT32_MAX / (2 * SK_BVH_WIDTH) || !build_order
                              ? NULL
                              : build_binary(surface, build_order, &binary_count);
    const size_t leaves = (binary_count + 1) / 2; /* a full binary tree */
    if (binary) {
        bvh->nodes = sk_allocate(count ? count : 1, sizeof(sk_bvh_node));
        bvh->order = sk_allocate(leaves, SK_BVH_WIDTH * sizeof(int32_t));
        bvh->entry_of = sk_allocate(count, sizeof(int32_t));
        bvh->corners = sk_allocate_zeroed(leaves, SK_BVH_WIDTH * 9 * sizeof(double));
    }
    if (!binary || !bvh->nodes || !bvh->order || !bvh->entry_of || !bvh->corners) {
        SK_FREE_ALL(build_order, binary);
        sk_bvh_free(bvh);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the hierarchy of %zu source triangles", count);
    }
    if (binary[0].count > 0 || count == 0) { /* one leaf: a root with one slot (none without triangles) */
        bvh->nodes[0] = (sk_bvh_node){.slots = count > 0};
        bvh->node_count = 1;
        if (count > 0) {
            bvh->nodes[0].child[0] = place_leaf(bvh, build_order, &binary[0]);
            bvh->nodes[0].count[0] = binary[0].count;
            for (int k = 0; k < 3; ++k) {
                bvh->nodes[0].low[k][0] = binary[0].bounds.low[k];
                bvh->nodes[0].high[k][0] = binary[0].bounds.high[k];
            }
        }
    } else {
        collapse(bvh, binary, build_order, 0);
    }
    SK_FREE_ALL(build_order, binary);
    return SK_OK;
}

void sk_bvh_free(sk_bvh *bvh)
{
    SK_FREE_ALL(bvh->nodes, bvh->order, bvh->entry_of, bvh->corners);
    bvh->nodes = NULL;
    bvh->order = NULL;
    bvh->entry_of = NULL;
    bvh->corners = NULL;
}

/* ---------------------------------------------------------------------------------------------
 * The walk: each query measures a node's children (a bit per child it meets, and how far each is) and tests a
 * leaf's triangles; a child further than the query's current bound is skipped, also when popped later.
 * ------------------------------------------------------------------------------------------- */

typedef struct query {
    double point[3];      /* the segment's origin, or the point */
    double direction[3];  /* the segment's direction */
    double inverse[3];    /* 1 / direction, for the slab tests (infinite where the direction is 0) */
    int near[3], far[3];  /* per axis, the offset in a node's planes (low, then high) of the entering and leaving
                             planes: low[k] and high[k] when the direction grows along k, else the other way */
    double bound;         /* the segment's reach, or the squared distance to the closest point so far */
    sk_bvh_kernel kernel;
    int found;
    int32_t triangle;
    double w1, w2;
} query;

typedef struct pending {
    int32_t node;
    double distance;
} pending;

typedef unsigned (*measure_fn)(const sk_bvh_node *node, const query *q, double distance[SK_BVH_WIDTH]);
typedef void (*leaf_fn)(const sk_bvh *bvh, int32_t first, int32_t count, query *q);

/* Inlined into each query once per kernel, so that its measure and leaf test are direct calls (inlined too). The
 * caller's stack has STACK_SIZE entries: a frame of its own would keep the walk from being inlined. */
static inline void walk(const sk_bvh *bvh, query *q, pending *stack, measure_fn measure, leaf_fn test_leaf)
{
    size_t top = 0;
    pending next = {0, 0}; /* the root */
    for (;;) {
        const sk_bvh_node *node = &bvh->nodes[next.node];
        double distance[SK_BVH_WIDTH];
        unsigned met = measure(node, q, distance) & ((1u << node->slots) - 1);
        next.node = -1;
        for (int s = 0; met; ++s, met >>= 1) {
            if (!(met & 1))
                continue;
            if (node->count[s] > 0) {
                if (distance[s] <= q->bound)
                    test_leaf(bvh, node->child[s], node->count[s], q);
            } else if (next.node < 0) { /* the first inner child is walked next, without a trip through the stack */
                next = (pending){node->child[s], distance[s]};
            } else {
                stack[top++] = (pending){node->child[s], distance[s]};
            }
        }
        if (next.node >= 0 && next.distance <= q->bound)
            continue;
        do {
            if (top == 0)
                return;
            --top;
        } while (stack[top].distance > q->bound);
        next = stack[top];
    }
}

/* ---------------------------------------------------------------------------------------------
 * The nearest hit along a segment
 * ------------------------------------------------------------------------------------------- */

/* Per child: whether the segment's parameter interval [-reach, reach] meets its box (slabs), and the smallest |t|
 * where it does. The direction's signs pick each axis' entering and leaving planes once per query (near[k], far[k]:
 * offsets of low[k] or high[k] in the node), so a slab costs no min/max of its two planes. Where the direction does
 * not move along an axis its inverse is infinite: a plane on the origin's side gives -inf or +inf (no constraint, or
 * a miss) and a plane through the origin 0 * inf = NaN, which the comparisons ignore (the origin is in the slab).
 * Plain comparisons rather than fmin/fmax, which are library calls without -ffast-math. */
static unsigned segment_measure_scalar(const sk_bvh_node *node, const query *q, double distance[SK_BVH_WIDTH])
{
    const double *planes = &node->low[0][0];
    unsigned met = 0;
    for (int s = 0; s < SK_BVH_WIDTH; ++s) {
        double enter = -q->bound, leave = q->bound;
        for (int k = 0; k < 3; ++k) {
            const double near = (planes[q->near[k] + s] - q->point[k]) * q->inverse[k];
            const double far = (planes[q->far[k] + s] - q->point[k]) * q->inverse[k];
            enter = near > enter ? near : enter;
            leave = far < leave ? far : leave;
        }
        const double behind = -leave > 0 ? -leave : 0;
        distance[s] = enter > behind ? enter : behind;
        met |= (unsigned)(enter <= leave) << s;
    }
    return met;
}

#if defined(__SSE2__)
/* The same comparisons as segment_measure_scalar, two children per register: MAXPD and MINPD return their second
 * operand when either is NaN, as the scalar ?: do. */
static unsigned segment_measure_sse2(const sk_bvh_node *node, const query *q, double distance[SK_BVH_WIDTH])
{
    const double *planes = &node->low[0][0];
    unsigned met = 0;
    for (int h = 0; h < SK_BVH_WIDTH; h += 2) {
        __m128d enter = _mm_set1_pd(-q->bound), leave = _mm_set1_pd(q->bound);
        for (int k = 0; k < 3; ++k) {
            const __m128d origin = _mm_set1_pd(q->point[k]), inverse = _mm_set1_pd(q->inverse[k]);
            const __m128d near = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(planes + q->near[k] + h), origin), inverse);
            const __m128d far = _mm_mul_pd(_mm_sub_pd(_mm_loadu_pd(planes + q->far[k] + h), origin), inverse);
            enter = _mm_max_pd(near, enter);
            leave = _mm_min_pd(far, leave);
        }
        const __m128d behind = _mm_max_pd(_mm_sub_pd(_mm_setzero_pd(), leave), _mm_setzero_pd());
        _mm_storeu_pd(&distance[h], _mm_max_pd(enter, behind));
        met |= (unsigned)_mm_movemask_pd(_mm_cmple_pd(enter, leave)) << h;
    }
    return met;
}
#endif

/* Moller-Trumbore on both sides of the triangle with corner 0 and edges c (9 doubles); 1 with t and the weights of
 * corners 1 and 2 on a hit. */
static int intersect(const double c[9], const double *origin, const double *direction, double *t, double *w1,
                     double *w2)
{
    const double *p0 = c, *e1 = c + 3, *e2 = c + 6;
    double s[3], p[3], q[3];
    for (int k = 0; k < 3; ++k)
        s[k] = origin[k] - p0[k];
    sk_cross3(p, direction, e2);
    const double determinant = sk_dot3(e1, p);
    if (determinant == 0)
        return 0;
    const double inverse = 1.0 / determinant;
    const double u = sk_dot3(s, p) * inverse;
    if (u < -INTERSECT_TOLERANCE || u > 1 + INTERSECT_TOLERANCE)
        return 0;
    sk_cross3(q, s, e1);
    const double v = sk_dot3(direction, q) * inverse;
    if (v < -INTERSECT_TOLERANCE || u + v > 1 + INTERSECT_TOLERANCE)
        return 0;
    *t = sk_dot3(e2, q) * inverse;
    *w1 = u;
    *w2 = v;
    return 1;
}

/* Keeps a hit of `candidate` at t when it beats the best so far: nearer, or as near and a lower index (so the
 * answer does not depend on the order triangles are tried in). */
static void offer_hit(query *q, int32_t candidate, double t, double w1, double w2)
{
    const double distance = fabs(t);
    if (distance < q->bound || (distance == q->bound && (!q->found || candidate < q->triangle))) {
        q->bound = distance;
        q->triangle = candidate;
        q->w1 = w1;
        q->w2 = w2;
        q->found = 1;
    }
}

/* Intersects the triangle at `entry` (its corners gathered from its block's lane) and offers the hit. */
static void offer_entry(const sk_bvh *bvh, query *q, size_t entry)
{
    const size_t lane = entry % SK_BVH_WIDTH;
    const double *block = bvh->corners + 9 * (entry - lane);
    double corners[9], t, w1, w2;
    for (size_t i = 0; i < 9; ++i)
        corners[i] = block[SK_BVH_WIDTH * i + lane];
    if (intersect(corners, q->point, q->direction, &t, &w1, &w2))
        offer_hit(q, bvh->order[entry], t, w1, w2);
}

static void segment_leaf_scalar(const sk_bvh *bvh, int32_t first, int32_t count, query *q)
{
    for (int32_t i = first; i < first + count; ++i)
        offer_entry(bvh, q, (size_t)i);
}

#if defined(__SSE2__)
/* intersect() on two triangles at once, lane by lane the same operations in the same order (so the same bits), each
 * rejection test negated so that a NaN passes it as in the scalar code; the hits are offered in entry order. */
static void segment_leaf_sse2(const sk_bvh *bvh, int32_t first, int32_t count, query *q)
{
    const double *block = bvh->corners + 9 * (size_t)first;
    const __m128d d0 = _mm_set1_pd(q->direction[0]), d1 = _mm_set1_pd(q->direction[1]),
                  d2 = _mm_set1_pd(q->direction[2]);
    const __m128d low = _mm_set1_pd(-INTERSECT_TOLERANCE), high = _mm_set1_pd(1 + INTERSECT_TOLERANCE);
    for (int h = 0; h < count; h += 2) {
        __m128d c[9];
        for (int i = 0; i < 9; ++i)
            c[i] = _mm_loadu_pd(block + SK_BVH_WIDTH * i + h);
        const __m128d s0 = _mm_sub_pd(_mm_set1_pd(q->point[0]), c[0]), s1 = _mm_sub_pd(_mm_set1_pd(q->point[1]), c[1]),
                      s2 = _mm_sub_pd(_mm_set1_pd(q->point[2]), c[2]);
        const __m128d p0 = _mm_sub_pd(_mm_mul_pd(d1, c[8]), _mm_mul_pd(d2, c[7])),
                      p1 = _mm_sub_pd(_mm_mul_pd(d2, c[6]), _mm_mul_pd(d0, c[8])),
                      p2 = _mm_sub_pd(_mm_mul_pd(d0, c[7]), _mm_mul_pd(d1, c[6]));
        const __m128d determinant =
            _mm_add_pd(_mm_add_pd(_mm_mul_pd(c[3], p0), _mm_mul_pd(c[4], p1)), _mm_mul_pd(c[5], p2));
        const __m128d inverse = _mm_div_pd(_mm_set1_pd(1.0), determinant);
        const __m128d u =
            _mm_mul_pd(_mm_add_pd(_mm_add_pd(_mm_mul_pd(s0, p0), _mm_mul_pd(s1, p1)), _mm_mul_pd(s2, p2)), inverse);
        const __m128d q0 = _mm_sub_pd(_mm_mul_pd(s1, c[5]), _mm_mul_pd(s2, c[4])),
                      q1 = _mm_sub_pd(_mm_mul_pd(s2, c[3]), _mm_mul_pd(s0, c[5])),
                      q2 = _mm_sub_pd(_mm_mul_pd(s0, c[4]), _mm_mul_pd(s1, c[3]));
        const __m128d v =
            _mm_mul_pd(_mm_add_pd(_mm_add_pd(_mm_mul_pd(d0, q0), _mm_mul_pd(d1, q1)), _mm_mul_pd(d2, q2)), inverse);
        const __m128d t =
            _mm_mul_pd(_mm_add_pd(_mm_add_pd(_mm_mul_pd(c[6], q0), _mm_mul_pd(c[7], q1)), _mm_mul_pd(c[8], q2)), inverse);
        __m128d accepted = _mm_cmpneq_pd(determinant, _mm_setzero_pd());
        accepted = _mm_and_pd(accepted, _mm_and_pd(_mm_cmpnlt_pd(u, low), _mm_cmpngt_pd(u, high)));
        accepted = _mm_and_pd(accepted, _mm_and_pd(_mm_cmpnlt_pd(v, low), _mm_cmpngt_pd(_mm_add_pd(u, v), high)));
        unsigned hits = (unsigned)_mm_movemask_pd(accepted) & (count - h >= 2 ? 3u : 1u);
        if (!hits)
            continue;
        double ts[2], us[2], vs[2];
        _mm_storeu_pd(ts, t);
        _mm_storeu_pd(us, u);
        _mm_storeu_pd(vs, v);
        for (int lane = 0; lane < 2; ++lane)
            if (hits & (1u << lane))
                offer_hit(q, bvh->order[(size_t)first + (size_t)(h + lane)], ts[lane], us[lane], vs[lane]);
    }
}
#endif

static query segment_query(const sk_bvh *bvh, const double *origin, const double *direction, double reach)
{
    query q = {.bound = reach, .kernel = bvh->kernel};
    for (int k = 0; k < 3; ++k) {
        q.point[k] = origin[k];
        q.direction[k] = direction[k];
        q.inverse[k] = direction[k] != 0 ? 1 / direction[k] : INFINITY;
        const int low = SK_BVH_WIDTH * k, high = SK_BVH_WIDTH * (3 + k);
        q.near[k] = q.inverse[k] > 0 ? low : high;
        q.far[k] = q.inverse[k] > 0 ? high : low;
    }
    return q;
}

int sk_bvh_nearest_hit(const sk_bvh *bvh, const double *origin, const double *direction, double reach, int32_t hint,
                       int32_t *triangle, double *weight1, double *weight2)
{
    query q = segment_query(bvh, origin, direction, reach);
    if (hint >= 0 && (size_t)hint < bvh->surface->triangle_count)
        offer_entry(bvh, &q, (size_t)bvh->entry_of[hint]);
    pending stack[STACK_SIZE];
#if defined(__SSE2__)
    if (q.kernel == SK_BVH_SSE2)
        walk(bvh, &q, stack, segment_measure_sse2, segment_leaf_sse2);
    else
#endif
        walk(bvh, &q, stack, segment_measure_scalar, segment_leaf_scalar);
    if (q.found) {
        *triangle = q.triangle;
        *weight1 = q.w1;
        *weight2 = q.w2;
    }
    return q.found;
}

/* ---------------------------------------------------------------------------------------------
 * The closest point
 * ------------------------------------------------------------------------------------------- */

/* Per child: the squared distance from the point to its box (0 inside), and whether it is within the bound. */
static unsigned point_measure_scalar(const sk_bvh_node *node, const query *q, double distance[SK_BVH_WIDTH])
{
    unsigned met = 0;
    for (int s = 0; s < SK_BVH_WIDTH; ++s) {
        double sum = 0;
        for (int k = 0; k < 3; ++k) {
            const double below = node->low[k][s] - q->point[k], above = q->point[k] - node->high[k][s];
            const double outside = below > above ? below : above, gap = outside > 0 ? outside : 0;
            sum += gap * gap;
        }
        distance[s] = sum;
        met |= (unsigned)(sum <= q->bound) << s;
    }
    return met;
}

#if defined(__SSE2__)
static unsigned point_measure_sse2(const sk_bvh_node *node, const query *q, double distance[SK_BVH_WIDTH])
{
    unsigned met = 0;
    const __m128d bound = _mm_set1_pd(q->bound);
    for (int h = 0; h < 2; ++h) {
        __m128d sum = _mm_setzero_pd();
        for (int k = 0; k < 3; ++k) {
            const __m128d point = _mm_set1_pd(q->point[k]);
            const __m128d below = _mm_sub_pd(_mm_loadu_pd(&node->low[k][2 * h]), point);
            const __m128d above = _mm_sub_pd(point, _mm_loadu_pd(&node->high[k][2 * h]));
            const __m128d gap = _mm_max_pd(_mm_max_pd(above, below), _mm_setzero_pd());
            sum = _mm_add_pd(sum, _mm_mul_pd(gap, gap));
        }
        _mm_storeu_pd(&distance[2 * h], sum);
        met |= (unsigned)_mm_movemask_pd(_mm_cmple_pd(sum, bound)) << (2 * h);
    }
    return met;
}
#endif

/* The point of the triangle closest to `point` as the weights of corners 1 and 2 (Ericson, Real-Time Collision
 * Detection 5.1.5: the Voronoi region of a corner, an edge or the face), and its squared distance. */
static double closest_on_triangle(const sk_bake_surface *surface, int32_t triangle, const double *point, double *w1,
                                  double *w2)
{
    const double *a = corner_position(surface, triangle, 0), *b = corner_position(surface, triangle, 1),
                 *c = corner_position(surface, triangle, 2);
    double ab[3], ac[3], ap[3], bp[3], cp[3];
    for (int k = 0; k < 3; ++k) {
        ab[k] = b[k] - a[k];
        ac[k] = c[k] - a[k];
        ap[k] = point[k] - a[k];
        bp[k] = point[k] - b[k];
        cp[k] = point[k] - c[k];
    }
    const double d1 = sk_dot3(ab, ap), d2 = sk_dot3(ac, ap), d3 = sk_dot3(ab, bp), d4 = sk_dot3(ac, bp);
    const double d5 = sk_dot3(ab, cp), d6 = sk_dot3(ac, cp);
    const double va = d3 * d6 - d5 * d4, vb = d5 * d2 - d1 * d6, vc = d1 * d4 - d3 * d2;
    double v, w;
    if (d1 <= 0 && d2 <= 0) {
        v = 0, w = 0;
    } else if (d3 >= 0 && d4 <= d3) {
        v = 1, w = 0;
    } else if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        v = d1 / (d1 - d3), w = 0;
    } else if (d6 >= 0 && d5 <= d6) {
        v = 0, w = 1;
    } else if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        v = 0, w = d2 / (d2 - d6);
    } else if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6)), v = 1 - w;
    } else {
        const double denominator = va + vb + vc;
        if (!(fabs(denominator) > 0)) { /* a degenerate triangle: its first corner stands for it */
            v = 0, w = 0;
        } else {
            v = vb / denominator, w = vc / denominator;
        }
    }
    double distance2 = 0;
    for (int k = 0; k < 3; ++k) {
        const double gap = a[k] + v * ab[k] + w * ac[k] - point[k];
        distance2 += gap * gap;
    }
    *w1 = v;
    *w2 = w;
    return distance2;
}

static void point_leaf(const sk_bvh *bvh, int32_t first, int32_t count, query *q)
{
    for (int32_t i = first; i < first + count; ++i) {
        const int32_t candidate = bvh->order[i];
        double w1, w2;
        const double distance2 = closest_on_triangle(bvh->surface, candidate, q->point, &w1, &w2);
        if (distance2 < q->bound || (distance2 == q->bound && (!q->found || candidate < q->triangle))) {
            q->bound = distance2;
            q->triangle = candidate;
            q->w1 = w1;
            q->w2 = w2;
            q->found = 1;
        }
    }
}

int sk_bvh_closest_point(const sk_bvh *bvh, const double *point, double reach, int32_t hint, int32_t *triangle,
                         double *weight1, double *weight2)
{
    query q = {.point = {point[0], point[1], point[2]}, .bound = reach * reach, .kernel = bvh->kernel};
    if (hint >= 0 && (size_t)hint < bvh->surface->triangle_count) /* the walk then prunes by its distance at once */
        point_leaf(bvh, bvh->entry_of[hint], 1, &q);
    pending stack[STACK_SIZE];
#if defined(__SSE2__)
    if (q.kernel == SK_BVH_SSE2)
        walk(bvh, &q, stack, point_measure_sse2, point_leaf);
    else
#endif
        walk(bvh, &q, stack, point_measure_scalar, point_leaf);
    if (q.found) {
        *triangle = q.triangle;
        *weight1 = q.w1;
        *weight2 = q.w2;
    }
    return q.found;
}
