/* What the baking family's files share; not part of the public contract. */
#ifndef SK_BAKE_INTERNAL_H
#define SK_BAKE_INTERNAL_H

#include <string.h>

#include "skinkit.h"

static inline double sk_dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

static inline void sk_cross3(double *out, const double *a, const double *b)
{
    const double x = a[1] * b[2] - a[2] * b[1], y = a[2] * b[0] - a[0] * b[2], z = a[0] * b[1] - a[1] * b[0];
    out[0] = x;
    out[1] = y;
    out[2] = z;
}

/* Adds bone to the ascending set of *size bones unless it is there already (the set has room for one more). */
static inline void sk_insert_sorted_bone(int32_t *set, size_t *size, int32_t bone)
{
    size_t at = *size;
    for (size_t i = 0; i < *size; ++i) {
        if (set[i] == bone)
            return;
        if (set[i] > bone) {
            at = i;
            break;
        }
    }
    memmove(set + at + 1, set + at, (*size - at) * sizeof *set);
    set[at] = bone;
    ++*size;
}

/* Checks a bake surface's arrays (indices, finite values; uv present and in 0-1 when needs_uv), naming it. */
sk_status sk_check_bake_surface(const sk_bake_surface *surface, int needs_uv, const char *name, sk_error *error);

/* A bounding-volume hierarchy over a surface's triangles, for the nearest hit along a segment and the closest point:
 * a binary tree built by binned surface-area splits, collapsed into nodes of up to four children whose boxes are
 * stored one axis at a time, so that one node's four slab tests are a few SIMD operations. */
#define SK_BVH_WIDTH 4

typedef struct sk_bvh_node {
    double low[3][SK_BVH_WIDTH], high[3][SK_BVH_WIDTH]; /* per axis, the children's boxes */
    int32_t child[SK_BVH_WIDTH]; /* an inner child's node index, or a leaf child's first entry in order[] */
    int32_t count[SK_BVH_WIDTH]; /* a leaf child's triangles; 0 for an inner child */
    int32_t slots;               /* children in use: the first `slots` */
} sk_bvh_node;

/* Which box tests a query runs: the SSE2 ones (every x86-64; the default where compiled in) or the portable scalar
 * ones. Both make the same comparisons on the same values, so they visit the same nodes and give the same bits. */
typedef enum sk_bvh_kernel { SK_BVH_SCALAR = 0, SK_BVH_SSE2 = 1 } sk_bvh_kernel;

typedef struct sk_bvh {
    sk_bvh_node *nodes; /* nodes[0] is the root */
    int32_t *order;     /* per entry, its triangle (-1: none): each leaf has a block of SK_BVH_WIDTH entries */
    int32_t *entry_of;  /* the inverse of order: each triangle's entry */
    double *corners;    /* per block of entries: corner 0 and the edges to corners 1 and 2, one component at a time
                           (9 x SK_BVH_WIDTH doubles; zero for an entry without a triangle), so that a leaf's
                           intersection tests read one run of memory, SIMD lanes side by side */
    size_t node_count, entry_count;
    const sk_bake_surface *surface;
    sk_bvh_kernel kernel;
} sk_bvh;

/* Whether this build has the SSE2 box tests (an x86-64 compiler). */
int sk_bvh_has_sse2(void);

sk_status sk_bvh_build(sk_bvh *bvh, const sk_bake_surface *surface, sk_error *error);
void sk_bvh_free(sk_bvh *bvh);

/* The hit nearest to origin on the segment origin + t direction, |t| <= reach (among equals, the lowest triangle
 * index): 1 with its triangle and the barycentric weights of its corners 1 and 2, 0 when nothing is hit. hint (or
 * -1) is tried first: a neighbouring texel's hit shrinks the search at once without changing the answer. */
int sk_bvh_nearest_hit(const sk_bvh *bvh, const double *origin, const double *direction, double reach, int32_t hint,
                       int32_t *triangle, double *weight1, double *weight2);

/* The surface point closest to `point` within distance reach (among equals, the lowest triangle index): 1 with its
 * triangle and the barycentric weights of its corners 1 and 2, 0 when the surface is further away. hint (or -1) is
 * measured first, as in sk_bvh_nearest_hit: a neighbouring query's answer shrinks the search, not the answer. */
int sk_bvh_closest_point(const sk_bvh *bvh, const double *point, double reach, int32_t hint, int32_t *triangle,
                         double *weight1, double *weight2);

#endif
