/*
 * One progressive-mesh simplification step (Merry 2007, sections 6.2-6.3.1): half-edge collapses costed by
 * memoryless APS in the animation-space metric (or the rest pose), atlas-aware and topology-safe, and
 * influence collapses, in one priority queue. See skinkit.h's "Level of detail: one progressive-mesh
 * simplification step". SPDX-License-Identifier: GPL-3.0-or-later
 *
 * Candidates are per vertex: vertex u's edge candidate is its cheapest legal collapse u -> v over its
 * neighbours v (ties: the lowest v), its influence candidate the cheapest of its influences to remove. Both
 * depend only on u's one-ring (its faces, their corners' UVs and the coordinates of u and its neighbours), so
 * after a collapse u -> v exactly v and its new neighbours are re-costed, and after an influence collapse at a,
 * a and its neighbours (Fig 6.6). The queue is a binary heap with lazy deletion: an entry is live while its
 * stamp matches its candidate's; entries are ordered by (cost, id), edges (id u) before influences (id V + u).
 *
 * The APS overlay: inside one group of u's faces that share UVs (a wedge: one per chart u is in), the old
 * faces (u, a, b) and the new ones (v, a, b) triangulate the same polygon, the old interior edges are u-a and
 * the new ones v-b, so the overlay's cell corners are the polygon's vertices (no deviation), u itself (located
 * in a new face) and the crossings of old and new interior edges. At each, the deviation is a combination
 * sum_k c_k p_k of u's and its neighbours' coordinates with sum c_k = 0, so it is sum_{k != u} c_k (p_k - p_u).
 * Per vertex, P over the one-ring's bones is factored once, P_U = F^T F (pivoted Cholesky: P is only
 * semi-definite), and e_k = F (p_k - p_u) kept (the rest metric: e_k = x_k - x_u), so a corner's deviation is
 * |sum c_k e_k|, a norm of small numbers: a flat, linear neighbourhood costs 0 to rounding of its edge length,
 * not the square root of a rounding error of a quadratic form (measured: 1.9e-9 through a Gram matrix, 0 now).
 *
 * Full-edge collapses (sk_simplify_chain_tuned) keep this overlay: v stays where it is in parameter space and only
 * its coordinates move by delta, so each corner's deviation becomes g - beta F delta (beta: v's weight in the new
 * face there), v's other faces deviate linearly by at most |F delta| (at v), and the cost is a minimax over
 * F delta in the span of v's own columns of F, solved in solve_full.
 *
 * Lazy re-costing: an influence collapse at a moves only a's coordinates, by |F delta_a| in the metric, so a
 * neighbour w's candidates keep their legality and each corner's deviation moves by at most |c_a| |F delta_a|.
 * w's cost then falls by at most its largest corner coefficient times that (a full collapse's by no more below
 * its corners' bound |g| / (1 + |beta|)), so w is queued at that lower bound and re-costed only when the bound
 * reaches the top: the queue applies the same collapses in the same order as re-costing w at once (the same bits),
 * with about a third fewer costings on the horse.
 */
#include <lapacke.h>
#include <math.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sk_internal.h"
#include "sk_lod_internal.h"

#define MAX_STAR 256
#define MAX_LINK (MAX_STAR + 2)
/* A triangle is degenerate when twice its area is at most this times its longest edge squared. */
#define SLIVER 1e-8
/* A collapse may not make a rest-pose face thinner than THIN (twice its area over its longest edge squared: its
 * height over its longest side, 0.87 equilateral, 0.05 about a 3-degree needle or a 170-degree sliver) when the face
 * is also thinner than the one it replaces and turned from it by more than TURN_COS's angle (5 degrees). Thin faces
 * that turn dent the shading: Blender weights a vertex normal by its corners' angles, so a sliver's tilted normal
 * pulls at its obtuse corner. Thin faces in the plane cost nothing and stay allowed (the long strips along a
 * cylinder). Measured in BENCHMARKS.md, session 14. */
#define THIN 0.05
#define TURN_COS 0.99619469809174553 /* cos(5 degrees) */
#define PROGRESS_EVERY 256
/* A lazily re-costed candidate's lower bound is lowered by these margins (relative to it, and to its one-ring's
 * largest metric length): the rounding of the costs, the full collapse's quadratic form (sqrt(eps) relative) the
 * largest of it. */
#define FLOOR_RELATIVE 1e-4
#define FLOOR_ABSOLUTE 1e-8
/* The one-ring factor cache (by the ring's bone set) and the full collapse's basis cache (by that set and v's bones):
 * direct-mapped, for rings of up to CACHE_MAX_BONES bones and v of up to CACHE_MAX_V_BONES (d = 64: 32 KiB a factor,
 * 23 KiB a basis at most, 110 MiB in all). The horse's chain meets about 1,900 ring bone sets (7 bones on average):
 * 256 factor slots factored 7,670 times, 2,048 slots 1,869 times (about 12 MiB); and 2,197 bases: 512 slots made
 * 4,031 of them, 2,048 slots (about 7 MiB more) 2,787. */
#define FACTOR_SLOTS 2048
#define BASIS_SLOTS 2048
#define CACHE_MAX_BONES 16
#define CACHE_MAX_V_BONES 8
/* One-rings whose metric rows are kept (direct-mapped by vertex): all of the horse's, 20 MiB or so at most. */
#define ROW_SLOTS_MAX 16384
/* The most doubles kept for auto collapses' solved moves (V x 4 x the most influences a vertex has): 64 MiB. */
#define DELTA_KEPT_MAX ((size_t)8 << 20)
/* Per vertex, the corner coefficient bound of each of its first REACH_LINKS neighbours (the rest: the largest). */
#define REACH_LINKS 16
/* Per vertex of at most CHECKED_LINKS neighbours, check_target's outcome for each, kept from its last costing. */
#define CHECKED_LINKS 16

enum { F_BOUNDARY = 1, F_SEAM = 2, F_MATERIAL = 4, F_LOCKED = 8 };
enum { R_OK = 0, R_FLIP, R_CHART, R_SEAM, R_LINK, R_LOCKED };

typedef struct entry {
    double cost;
    int32_t id;
    uint32_t stamp;
} entry;

typedef struct heap {
    entry *items;
    size_t size, capacity;
} heap;

/* The queue's order, (cost, id): only one entry per id is live, so any heap pops the live ones in the same order. */
static int entry_less(const entry *x, const entry *y)
{
    return x->cost < y->cost || (x->cost == y->cost && x->id < y->id);
}

/* A binary min-heap of entries, typed (the generic sk_heap's copies and calls through a pointer were 6% of the
 * chain): 0 when memory runs out (the heap is then unchanged). */
static int heap_push(heap *h, entry item)
{
    if (h->size == h->capacity && !sk_grow(&h->items, &h->capacity, sizeof *h->items, 1024))
        return 0;
    size_t at = h->size++;
    while (at > 0 && entry_less(&item, &h->items[(at - 1) / 2])) {
        h->items[at] = h->items[(at - 1) / 2];
        at = (at - 1) / 2;
    }
    h->items[at] = item;
    return 1;
}

/* The least entry, removed (size >= 1). */
static entry heap_pop(heap *h)
{
    const entry top = h->items[0], last = h->items[--h->size];
    size_t parent = 0;
    for (size_t child; (child = 2 * parent + 1) < h->size; parent = child) {
        if (child + 1 < h->size && entry_less(&h->items[child + 1], &h->items[child]))
            ++child;
        if (!entry_less(&h->items[child], &last))
            break;
        h->items[parent] = h->items[child];
    }
    if (h->size > 0)
        h->items[parent] = last;
    return top;
}

/* u's one-ring, faces in ascending triangle order. */
typedef struct star {
    int32_t u;
    int n, nl, wedges;
    int32_t t[MAX_STAR];
    int k[MAX_STAR];             /* u's corner in t */
    int32_t a[MAX_STAR], b[MAX_STAR]; /* the other corners: (u, a, b) in the triangle's order */
    int ia[MAX_STAR], ib[MAX_STAR];   /* their link indices */
    int wedge[MAX_STAR];
    double c2[MAX_STAR][6];      /* 2D (u, a, b) per face: UVs or the projection */
    int32_t link[MAX_LINK];      /* neighbours, ascending */
    int flags[MAX_LINK], faces[MAX_LINK], face0[MAX_LINK], face1[MAX_LINK];
    int projected_ok;            /* without UVs: the projection is one-to-one */
    int gram_ready, rank;
    int faces_ready;             /* old_area and old_normal hold the faces' */
    double old_area[MAX_STAR];   /* twice (u, a, b)'s signed 2D area */
    double old_normal[MAX_STAR][3]; /* (x_a - x_u) x (x_b - x_u) in the rest pose */
    double *e;                   /* nl x rank: F (p_l - p_u), F^T F = P over the one-ring's bones */
    const double **wpos;         /* full stars: wedges x nl, link vertex l's 2D position in wedge w (or NULL) */
    const double *wu[MAX_STAR];  /* full stars: u's 2D position in each wedge */
} star;

/* One cell corner of a candidate's overlay: its deviation sum_k c[k] e_{index[k]} under the half-edge collapse and
 * the weight beta of v in the new face holding it (a full collapse moving v by delta deviates by beta F delta
 * less). */
typedef struct corner {
    int index[3];
    double c[3];
    double beta;
} corner;

/* A cached pivoted Cholesky factor of P over a bone set: what form_gram leaves in dense and pivots. */
typedef struct factor_slot {
    uint64_t hash;
    size_t n, d, rank;             /* n = 0: empty */
    int32_t bones[CACHE_MAX_BONES];
    double *factor;                /* d x d */
    lapack_int *pivots;            /* d */
    size_t capacity;               /* of factor (and pivots), in d */
} factor_slot;

/* A cached orthonormal basis of F's columns on v's coordinates (solve_full's Gram-Schmidt) for one bone set of the
 * ring (its factor) and v's bones in v's order. */
typedef struct basis_slot {
    uint64_t hash;
    size_t n, nv, kept;            /* n = 0: empty */
    int32_t bones[CACHE_MAX_BONES], v_bones[CACHE_MAX_V_BONES];
    int kept_column[4 * CACHE_MAX_V_BONES];
    double *values;                /* kept x kept (R, row-major) then kept x rank (Q's columns) */
    size_t capacity;
} basis_slot;

/* A one-ring's rows e_l = F (p_l - p_u) at its last form_gram: a row depends only on P's factor over the ring's bones
 * (the same bone set, the same bits) and on the coordinates of u and of link vertex l, so a later form_gram of u
 * over the same bones copies the rows of the link vertices whose coordinates (version) did not change. */
typedef struct row_slot {
    int32_t u;                     /* -1: empty */
    uint32_t u_version;
    size_t n, rank;
    uint64_t hash;
    int32_t bones[CACHE_MAX_BONES];
    int nl;
    int32_t *link;                 /* nl, with each one's version: allocated, so that an unused slot costs no pages */
    uint32_t *version;
    double *e;                     /* nl x rank */
    size_t capacity, link_capacity;
} row_slot;

typedef struct costing_batch costing_batch;
typedef struct costing_helper costing_helper;

typedef struct simplifier {
    size_t V, T, bone_count;
    int32_t *tri;
    unsigned char *alive, *in_use;
    double *uv;
    const int32_t *charts, *materials;
    const double *rest;
    int32_t *first, *next;
    const int32_t *offsets;
    int32_t *bones, *count, *merged;
    double *coords;
    int32_t *edge_target, *inf_slot;
    double *edge_cost, *inf_cost;
    uint32_t *stamp;
    uint32_t mark_stamp;
    uint32_t *mark;      /* V */
    uint32_t bone_stamp;
    uint32_t *bone_mark; /* bone_count */
    int32_t *bone_index; /* bone_count */
    heap queue;
    sk_influence_remover *remover;
    const sk_simplify_options *options;
    sk_simplify_report *report;
    size_t triangles, influences;
    star s, sv;          /* sv: scratch for the neighbour's star */
    double *dense, *q, *e; /* scratch for the metric */
    const double **wpos;   /* the wedge tables of s and sv */
    size_t dense_capacity, e_capacity, pivot_capacity;
    lapack_int *pivots;
    int *pivoted;          /* d: each original index's position in the pivoted order */
    unsigned char *lk; /* the locked sides, updated as edges merge */
    double corrected[4 * SK_LOD_MAX_VERTEX_INFLUENCES];
    /* Full-edge collapses (sk_simplify_chain_tuned) and the queue's influence weighting */
    int collapse;                 /* sk_lod_collapse */
    double edge_queue_scale;      /* edges are queued at cost / influence_cost_scale */
    int rank_per_influence;       /* and divided by the square root of the influences they remove */
    unsigned char *featured;      /* V: the vertex's star has a boundary, seam, material or locked edge */
    unsigned char *edge_full;     /* V: u's candidate is a full collapse */
    unsigned char *unsolved;      /* V (auto): u's queued key is its target's corner bound; the full solve is to come */
    size_t full_collapses;
    size_t gram_d;                /* the dimension of the factored P */
    const double *factor;         /* its pivoted factor: m->dense, or a factor cache slot's */
    const lapack_int *factor_pivots;
    corner *corners;
    size_t corner_count, corner_capacity;
    double *solve_work;
    size_t solve_capacity;
    double delta[4 * SK_LOD_MAX_VERTEX_INFLUENCES];
    /* Auto: solve_queued's move of a survivor, kept for apply_edge while u's entry is live (its inputs unchanged, a
     * new solve would give the same bits): V x delta_stride, with the stamp it was solved at (NULL: not kept) */
    double *queued_delta;
    uint32_t *delta_stamp;
    size_t delta_stride;          /* 4 x the most influences a vertex has */
    /* Lazy re-costing after influence collapses (see stale_after_move) */
    unsigned char *stale;         /* V: u's queued key is a lower bound, not its cost */
    double *edge_floor;           /* V: a lower bound of u's cost at its last costing, valid for any coordinates */
    double *edge_reach;           /* V: how much a unit move (in the metric) of any neighbour can lower it */
    double *edge_slack;           /* V: what the neighbours' moves since then may have lowered it by */
    double eval_floor, eval_reach; /* cost_target's: this target's lower bound; the largest coefficient met */
    double link_reach[MAX_LINK];  /* cost_edges': the largest coefficient met per link vertex */
    int32_t *reach_ids;           /* V x REACH_LINKS: u's first neighbours at its last costing (-1: none) */
    float *reach_values;          /* V x REACH_LINKS: their largest coefficient (rounded up) */
    unsigned char *checked;       /* V x CHECKED_LINKS: check_target's outcome per neighbour at u's last costing */
    factor_slot *factors;         /* FACTOR_SLOTS */
    basis_slot *bases;            /* BASIS_SLOTS */
    row_slot *rows;               /* row_slots */
    size_t row_slots;
    uint32_t *version;            /* V: bumped whenever the vertex's bones or coordinates change */
    size_t ring_bone_count;       /* the bones of the factored P (0: too many to cache), ascending */
    uint64_t ring_hash;
    int32_t ring_bones[CACHE_MAX_BONES];
    /* Costing on two threads (see that section) */
    costing_helper *helper;       /* the helper thread's, while a chain runs on two threads (NULL: one) */
    const costing_batch *batch;   /* the batch this thread is costing (NULL outside one), and its item */
    size_t batch_item;
} simplifier;

static uint64_t hash_bones(uint64_t hash, const int32_t *bones, size_t n)
{
    for (size_t k = 0; k < n; ++k) {
        hash ^= (uint64_t)(uint32_t)bones[k] + 0x9e3779b97f4a7c15ULL + (hash << 6) + (hash >> 2);
        hash *= 0xff51afd7ed558ccdULL;
    }
    return hash ^ (hash >> 29);
}

/* A cached factor of P over these bones, or NULL. */
static const factor_slot *cached_factor(const simplifier *m, const int32_t *bones, size_t n, uint64_t hash)
{
    const factor_slot *slot = &m->factors[hash % FACTOR_SLOTS];
    return slot->n == n && slot->hash == hash && !memcmp(slot->bones, bones, n * sizeof *bones) ? slot : NULL;
}

/* Keeps form_gram's factor (dense, pivots) of P over the ring's bones; out of memory, it is simply not kept. */
static void keep_factor(simplifier *m, size_t d, size_t rank)
{
    factor_slot *slot = &m->factors[m->ring_hash % FACTOR_SLOTS];
    if (d > slot->capacity) {
        double *factor = realloc(slot->factor, d * d * sizeof *factor);
        if (factor)
            slot->factor = factor;
        lapack_int *pivots = realloc(slot->pivots, d * sizeof *pivots);
        if (pivots)
            slot->pivots = pivots;
        slot->n = 0;
        if (!factor || !pivots)
            return;
        slot->capacity = d;
    }
    slot->hash = m->ring_hash, slot->n = m->ring_bone_count, slot->d = d, slot->rank = rank;
    memcpy(slot->bones, m->ring_bones, slot->n * sizeof *slot->bones);
    memcpy(slot->factor, m->dense, d * d * sizeof *slot->factor);
    memcpy(slot->pivots, m->pivots, d * sizeof *slot->pivots);
}

/* fmax and fmin as glibc's x86-64 ones compute them (maxsd / minsd: b on a tie, the other argument when one is a NaN),
 * inline: the calls cost 4% of the horse chain's instructions. */
static double max_of(double a, double b) { return a > b ? a : b == b ? b : a; }

static double min_of(double a, double b) { return a < b ? a : b == b ? b : a; }

static double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* a . b over n entries in four interleaved partial sums: one running sum is a chain of dependent additions, and the
 * full collapse's Gram-Schmidt spent half its time waiting on it. */
static double dot_n(const double *a, const double *b, size_t n)
{
    double sum[4] = {0.0, 0.0, 0.0, 0.0};
    size_t i = 0;
    for (; i + 4 <= n; i += 4)
        for (int lane = 0; lane < 4; ++lane)
            sum[lane] += a[i + (size_t)lane] * b[i + (size_t)lane];
    for (; i < n; ++i)
        sum[0] += a[i] * b[i];
    return (sum[0] + sum[1]) + (sum[2] + sum[3]);
}

/* residual -= along q, then dot_n(next, residual) (next NULL: dot_n(residual, residual)), in one pass: each entry is
 * updated before it is read, so the sums are dot_n's, term by term, on the updated residual. */
static double subtract_then_dot(double *residual, double along, const double *q, const double *next, size_t n)
{
    const double *b = next ? next : residual;
    double sum[4] = {0.0, 0.0, 0.0, 0.0};
    size_t i = 0;
    for (; i + 4 <= n; i += 4)
        for (int lane = 0; lane < 4; ++lane) {
            const size_t at = i + (size_t)lane;
            residual[at] -= along * q[at];
            sum[lane] += b[at] * residual[at];
        }
    for (; i < n; ++i) {
        residual[i] -= along * q[i];
        sum[0] += b[i] * residual[i];
    }
    return (sum[0] + sum[1]) + (sum[2] + sum[3]);
}

static void sub3(double *out, const double *a, const double *b)
{
    out[0] = a[0] - b[0], out[1] = a[1] - b[1], out[2] = a[2] - b[2];
}

static void cross3(double *out, const double *a, const double *b)
{
    out[0] = a[1] * b[2] - a[2] * b[1], out[1] = a[2] * b[0] - a[0] * b[2], out[2] = a[0] * b[1] - a[1] * b[0];
}

static double cross2(const double *a, const double *b) { return a[0] * b[1] - a[1] * b[0]; }

static uint32_t next_mark(uint32_t *stamp, uint32_t *marks, size_t n)
{
    if (++*stamp == 0) {
        memset(marks, 0, n * sizeof *marks);
        *stamp = 1;
    }
    return *stamp;
}

static int link_index(const star *s, int32_t x)
{
    int lo = 0, hi = s->nl - 1;
    while (lo <= hi) {
        const int mid = (lo + hi) / 2;
        if (s->link[mid] == x)
            return mid;
        if (s->link[mid] < x)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return -1;
}

/* A triangle's next corner, (k + 1) % 3 without the division. */
static const int NEXT_CORNER[3] = {1, 2, 0};

static const double *corner_uv(const simplifier *m, int32_t t, int corner) { return m->uv + 6 * (size_t)t + 2 * corner; }

/* Gathers u's live faces (pruning dead corners from its list, but inside a batch), ascending when full. Returns 0 when
 * u has more than MAX_STAR. */
static int gather_star(simplifier *m, star *s, int32_t u, int full)
{
    s->u = u, s->n = 0, s->nl = 0, s->gram_ready = 0, s->faces_ready = 0, s->projected_ok = 1;
    int32_t *link = &m->first[u];
    while (*link >= 0) {
        const int32_t slot = *link, t = slot / 3;
        if (!m->alive[t]) {
            if (m->batch) /* another thread may be walking the same list */
                link = &m->next[slot];
            else
                *link = m->next[slot];
            continue;
        }
        if (s->n == MAX_STAR)
            return 0;
        s->t[s->n] = t, s->k[s->n] = slot % 3, ++s->n;
        link = &m->next[slot];
    }
    for (int i = 1; full && i < s->n; ++i) /* ascending triangles: the order does not depend on the list's history
                                              (a partial star's users do not depend on its order) */
        for (int j = i; j > 0 && s->t[j - 1] > s->t[j]; --j) {
            int32_t tt = s->t[j]; s->t[j] = s->t[j - 1]; s->t[j - 1] = tt;
            int kk = s->k[j]; s->k[j] = s->k[j - 1]; s->k[j - 1] = kk;
        }
    for (int i = 0; i < s->n; ++i) {
        const int32_t *c = m->tri + 3 * (size_t)s->t[i];
        s->a[i] = c[NEXT_CORNER[s->k[i]]], s->b[i] = c[NEXT_CORNER[NEXT_CORNER[s->k[i]]]];
    }
    if (!full)
        return 1;
    /* The link, ascending and unique. */
    for (int i = 0; i < s->n; ++i)
        for (int e = 0; e < 2; ++e) {
            const int32_t x = e ? s->b[i] : s->a[i];
            int at = s->nl;
            while (at > 0 && s->link[at - 1] > x)
                --at;
            if (at > 0 && s->link[at - 1] == x)
                continue;
            memmove(s->link + at + 1, s->link + at, (size_t)(s->nl - at) * sizeof *s->link);
            s->link[at] = x, ++s->nl;
        }
    for (int l = 0; l < s->nl; ++l)
        s->flags[l] = 0, s->faces[l] = 0, s->face0[l] = s->face1[l] = -1;
    for (int i = 0; i < s->n; ++i) {
        s->ia[i] = link_index(s, s->a[i]), s->ib[i] = link_index(s, s->b[i]);
        for (int e = 0; e < 2; ++e) {
            const int l = e ? s->ib[i] : s->ia[i];
            if (s->faces[l]++ == 0)
                s->face0[l] = i;
            else
                s->face1[l] = i;
            /* the side of t joining u and this neighbour: u -> a is side k, b -> u side k + 2 */
            const int side = e ? (s->k[i] + 2) % 3 : s->k[i];
            if (m->lk && m->lk[3 * (size_t)s->t[i] + side])
                s->flags[l] |= F_LOCKED;
        }
    }
    for (int l = 0; l < s->nl; ++l) {
        if (s->faces[l] != 2) {
            s->flags[l] |= F_BOUNDARY;
            continue;
        }
        const int i0 = s->face0[l], i1 = s->face1[l];
        const int32_t t0 = s->t[i0], t1 = s->t[i1];
        if (m->materials && m->materials[t0] != m->materials[t1])
            s->flags[l] |= F_MATERIAL;
        if (m->charts && m->charts[t0] != m->charts[t1])
            s->flags[l] |= F_SEAM;
        if (m->uv) {
            const int32_t x = s->link[l];
            const int32_t *c0 = m->tri + 3 * (size_t)t0, *c1 = m->tri + 3 * (size_t)t1;
            for (int e = 0; e < 2; ++e) {
                const int32_t y = e ? x : s->u;
                int k0 = 0, k1 = 0;
                while (c0[k0] != y)
                    ++k0;
                while (c1[k1] != y)
                    ++k1;
                const double *p0 = corner_uv(m, t0, k0), *p1 = corner_uv(m, t1, k1);
                if (p0[0] != p1[0] || p0[1] != p1[1])
                    s->flags[l] |= F_SEAM;
            }
        }
    }
    /* Wedges: faces joined across edges that are neither seams nor the boundary (smallest face first). */
    int parent[MAX_STAR];
    for (int i = 0; i < s->n; ++i)
        parent[i] = i;
    for (int l = 0; l < s->nl; ++l)
        if (s->faces[l] == 2 && !(s->flags[l] & (F_SEAM | F_BOUNDARY))) {
            int r0 = s->face0[l], r1 = s->face1[l];
            while (parent[r0] != r0)
                r0 = parent[r0];
            while (parent[r1] != r1)
                r1 = parent[r1];
            if (r0 < r1)
                parent[r1] = r0;
            else if (r1 < r0)
                parent[r0] = r1;
        }
    s->wedges = 0;
    int wedge_of_root[MAX_STAR];
    for (int i = 0; i < s->n; ++i) {
        int r = i;
        while (parent[r] != r)
            r = parent[r];
        if (r == i)
            wedge_of_root[i] = s->wedges++;
        s->wedge[i] = wedge_of_root[r];
    }
    /* The wedge table: the first face (ascending) of each wedge holding each link vertex. */
    for (int x = 0; x < s->wedges * s->nl; ++x)
        s->wpos[x] = NULL;
    for (int i = s->n; i-- > 0;) {
        const int w = s->wedge[i];
        s->wpos[w * s->nl + s->ia[i]] = s->c2[i] + 2;
        s->wpos[w * s->nl + s->ib[i]] = s->c2[i] + 4;
        s->wu[w] = s->c2[i];
    }
    /* 2D coordinates: the corners' UVs, or the projection onto the plane of the area-weighted normal. */
    if (m->uv) {
        for (int i = 0; i < s->n; ++i) {
            const int32_t t = s->t[i];
            const int k = s->k[i];
            memcpy(s->c2[i], corner_uv(m, t, k), 2 * sizeof(double));
            memcpy(s->c2[i] + 2, corner_uv(m, t, (k + 1) % 3), 2 * sizeof(double));
            memcpy(s->c2[i] + 4, corner_uv(m, t, (k + 2) % 3), 2 * sizeof(double));
        }
    } else {
        const double *x = m->rest + 3 * (size_t)u;
        double normal[3] = {0, 0, 0};
        for (int i = 0; i < s->n; ++i) {
            double ea[3], eb[3], n[3];
            sub3(ea, m->rest + 3 * (size_t)s->a[i], x), sub3(eb, m->rest + 3 * (size_t)s->b[i], x);
            cross3(n, ea, eb);
            normal[0] += n[0], normal[1] += n[1], normal[2] += n[2];
        }
        const double length = sqrt(dot3(normal, normal));
        double e1[3], e2[3];
        if (!(length > 0.0)) {
            s->projected_ok = 0;
            return 1;
        }
        for (int c = 0; c < 3; ++c)
            normal[c] /= length;
        const double helper[3] = {fabs(normal[0]) < 0.6 ? 1.0 : 0.0, fabs(normal[0]) < 0.6 ? 0.0 : 1.0, 0.0};
        cross3(e1, normal, helper);
        const double l1 = sqrt(dot3(e1, e1));
        for (int c = 0; c < 3; ++c)
            e1[c] /= l1;
        cross3(e2, normal, e1);
        for (int i = 0; i < s->n; ++i) {
            const int32_t corners[3] = {u, s->a[i], s->b[i]};
            for (int c = 0; c < 3; ++c) {
                double d[3];
                sub3(d, m->rest + 3 * (size_t)corners[c], x);
                s->c2[i][2 * c] = dot3(d, e1), s->c2[i][2 * c + 1] = dot3(d, e2);
            }
            double ea[2] = {s->c2[i][2] - s->c2[i][0], s->c2[i][3] - s->c2[i][1]};
            double eb[2] = {s->c2[i][4] - s->c2[i][0], s->c2[i][5] - s->c2[i][1]};
            if (!(cross2(ea, eb) > 0.0))
                s->projected_ok = 0;
        }
    }
    return 1;
}

/* P over the ring's bones set[0..n) (ascending), factored into m->dense and m->pivots: P_U = F^T F by pivoted
 * Cholesky (P is only semi-definite); *rank rows of U hold F. u names the vertex in messages. */
static sk_status factor_ring(simplifier *m, const int32_t *set, size_t n, size_t *rank, size_t u, sk_error *error)
{
    const size_t d = 4 * n;
    double *p = m->dense;
    for (size_t a = 0; a < n; ++a)
        for (size_t b = a; b < n; ++b) {
            double block[16];
            sk_influence_remover_block(block, m->remover, set[a], set[b]);
            for (int r = 0; r < 4; ++r)
                for (int c = 0; c < 4; ++c) {
                    p[(4 * a + (size_t)r) * d + 4 * b + (size_t)c] = block[4 * r + c];
                    p[(4 * b + (size_t)c) * d + 4 * a + (size_t)r] = block[4 * r + c];
                }
        }
    return sk_factor_semidefinite(p, d, m->pivots, 1e-13, rank, "P over the one-ring of vertex", u, error);
}

/* The difference d_l = p_l - p_u in the ring's coordinates (d entries, by m->bone_index) into row. */
static void build_difference(const simplifier *m, const star *s, int l, double *row, size_t d)
{
    memset(row, 0, d * sizeof *row);
    for (int e = 0; e < 2; ++e) {
        const int32_t x = e ? s->u : s->link[l];
        const double sign = e ? -1.0 : 1.0;
        const size_t begin = (size_t)m->offsets[x];
        for (int32_t k = 0; k < m->count[x]; ++k) {
            const size_t at = 4 * (size_t)m->bone_index[m->bones[begin + (size_t)k]];
            for (int c = 0; c < 4; ++c)
                row[at + (size_t)c] += sign * m->coords[4 * (begin + (size_t)k) + (size_t)c];
        }
    }
}

/* e[0..n) += x column: restrict, so that the loop is vectorised without a check per call that e and column overlap
 * (its callers' never do). */
static void add_scaled(double *restrict e, const double *restrict column, double x, size_t n)
{
    for (size_t i = 0; i < n; ++i)
        e[i] += column[i] * x;
}

/* e = F d (r entries) for one difference row: column-major U, U(i, j) = factor[j * d + i] for j >= i; F = U Pi^T, so
 * (F x)_i = sum_{j >= i} U(i, j) x[piv(j)]. A difference p_l - p_u is non-zero only on the bones of l and u: column
 * by column of U (contiguous, no chain of dependent additions), skipping its zero entries, whose terms would add
 * nothing. */
static void metric_row(const simplifier *m, const double *row, double *e, size_t d, size_t r)
{
    memset(e, 0, r * sizeof *e);
    for (size_t j = 0; j < d; ++j) {
        const double x = row[m->factor_pivots[j] - 1];
        if (x != 0.0)
            add_scaled(e, m->factor + j * d, x, j < r ? j + 1 : r);
    }
}

static int row_slot_free(const simplifier *m, size_t slot);

/* u's kept rows, when they were formed over the same bones (m->ring_bones) and u's coordinates are unchanged. */
static const row_slot *kept_rows(const simplifier *m, int32_t u, size_t r)
{
    if (!m->rows || !m->ring_bone_count || !row_slot_free(m, (size_t)u % m->row_slots))
        return NULL;
    const row_slot *slot = &m->rows[(size_t)u % m->row_slots];
    return slot->u == u && slot->u_version == m->version[u] && slot->n == m->ring_bone_count &&
           slot->hash == m->ring_hash && slot->rank == r &&
           !memcmp(slot->bones, m->ring_bones, slot->n * sizeof *slot->bones) ? slot : NULL;
}

/* Row e = F (p_l - p_u) of u's one-ring from link vertex l's kept rows: when l's ring had the same bones (so the same
 * factor F) and u's coordinates and its own are those of then, l's row of u is F (p_u - p_l), and negating the
 * difference negates each rounded sum and product exactly, so -that row is e, bit for bit. 0 when not kept. */
static int mirrored_row(const simplifier *m, int32_t u, int32_t l, size_t r, double *e)
{
    const row_slot *slot = kept_rows(m, l, r);
    if (!slot)
        return 0;
    int lo = 0, hi = slot->nl - 1;
    while (lo <= hi) { /* u in l's link, ascending */
        const int mid = (lo + hi) / 2;
        if (slot->link[mid] < u)
            lo = mid + 1;
        else if (slot->link[mid] > u)
            hi = mid - 1;
        else {
            if (slot->version[mid] != m->version[u])
                return 0;
            const double *row = slot->e + (size_t)mid * r;
            for (size_t i = 0; i < r; ++i)
                e[i] = -row[i];
            return 1;
        }
    }
    return 0;
}

/* Keeps s's rows (s->e) in u's slot; out of memory, they are simply not kept. */
static void keep_rows(simplifier *m, const star *s)
{
    if (!m->rows || !m->ring_bone_count || !row_slot_free(m, (size_t)s->u % m->row_slots))
        return;
    row_slot *slot = &m->rows[(size_t)s->u % m->row_slots];
    const size_t need = (size_t)s->nl * (size_t)s->rank;
    slot->u = -1;
    if (need > slot->capacity) {
        double *e = realloc(slot->e, need * sizeof *e);
        if (!e)
            return;
        slot->e = e, slot->capacity = need;
    }
    if ((size_t)s->nl > slot->link_capacity) {
        int32_t *link = realloc(slot->link, (size_t)s->nl * sizeof *link);
        if (link)
            slot->link = link;
        uint32_t *version = realloc(slot->version, (size_t)s->nl * sizeof *version);
        if (version)
            slot->version = version;
        if (!link || !version)
            return;
        slot->link_capacity = (size_t)s->nl;
    }
    slot->u = s->u, slot->u_version = m->version[s->u], slot->n = m->ring_bone_count, slot->hash = m->ring_hash;
    slot->rank = (size_t)s->rank, slot->nl = s->nl;
    memcpy(slot->bones, m->ring_bones, slot->n * sizeof *slot->bones);
    memcpy(slot->link, s->link, (size_t)s->nl * sizeof *slot->link);
    for (int l = 0; l < s->nl; ++l)
        slot->version[l] = m->version[s->link[l]];
    memcpy(slot->e, s->e, need * sizeof *slot->e);
}

/* The Gram matrix of the differences (p_k - p_u) over u's link, under P or in the rest pose. */
static sk_status form_gram(simplifier *m, star *s, sk_error *error)
{
    const int nl = s->nl;
    const int32_t u = s->u;
    if (m->options->metric == SK_LOD_METRIC_REST) {
        if ((size_t)nl * 3 > m->e_capacity) {
            double *e = realloc(m->e, (size_t)nl * 3 * sizeof *e);
            if (!e)
                return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the metric of vertex %d's one-ring", (int)u);
            m->e = e, m->e_capacity = (size_t)nl * 3;
        }
        const double *x = m->rest + 3 * (size_t)u;
        for (int l = 0; l < nl; ++l)
            sub3(m->e + 3 * l, m->rest + 3 * (size_t)s->link[l], x);
        s->e = m->e, s->rank = 3, s->gram_ready = 1;
        return SK_OK;
    }
    /* The union of the bones, ascending. */
    const uint32_t stamp = next_mark(&m->bone_stamp, m->bone_mark, m->bone_count);
    size_t n = 0;
    int32_t *set = (int32_t *)m->q; /* reuse: at most (nl + 1) * 64 bones, sized below */
    for (int l = -1; l < nl; ++l) {
        const int32_t x = l < 0 ? u : s->link[l];
        const size_t begin = (size_t)m->offsets[x];
        for (int32_t k = 0; k < m->count[x]; ++k) {
            const int32_t bone = m->bones[begin + (size_t)k];
            if (m->bone_mark[bone] != stamp) {
                m->bone_mark[bone] = stamp;
                size_t at = n++;
                while (at > 0 && set[at - 1] > bone) {
                    set[at] = set[at - 1];
                    --at;
                }
                set[at] = bone;
            }
        }
    }
    for (size_t k = 0; k < n; ++k)
        m->bone_index[set[k]] = (int32_t)k;
    const size_t d = 4 * n;
    const size_t need = d * d + d; /* P (then its factor) and one difference row */
    if (d > m->pivot_capacity) {
        lapack_int *pivots = realloc(m->pivots, d * sizeof *pivots);
        if (pivots)
            m->pivots = pivots;
        int *pivoted = realloc(m->pivoted, d * sizeof *pivoted);
        if (pivoted)
            m->pivoted = pivoted;
        if (!pivots || !pivoted)
            return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the metric of vertex %d's one-ring", (int)u);
        m->pivot_capacity = d;
    }
    if (need > m->dense_capacity) {
        double *dense = realloc(m->dense, need * sizeof *dense);
        if (!dense)
            return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the metric of vertex %d's one-ring", (int)u);
        m->dense = dense, m->dense_capacity = need;
    }
    double *p = m->dense, *diff = p + d * d;
    /* P over the same bones gives the same factor, bit for bit: many one-rings share a bone set */
    m->ring_bone_count = n <= CACHE_MAX_BONES && m->factors ? n : 0;
    const factor_slot *cached = NULL;
    if (m->ring_bone_count) {
        memcpy(m->ring_bones, set, n * sizeof *set);
        m->ring_hash = hash_bones(0, set, n);
        cached = cached_factor(m, set, n, m->ring_hash);
    }
    size_t r = 0;
    m->factor = p, m->factor_pivots = m->pivots;
    if (cached) { /* read in place: only the next form_gram can replace the slot */
        m->factor = cached->factor, m->factor_pivots = cached->pivots;
        r = cached->rank;
    } else {
        const sk_status factored = factor_ring(m, set, n, &r, (size_t)u, error);
        if (factored != SK_OK)
            return factored;
        if (m->ring_bone_count)
            keep_factor(m, d, r);
    }
    if ((size_t)nl * r > m->e_capacity) {
        double *e = realloc(m->e, (size_t)nl * r * sizeof *e);
        if (!e)
            return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the metric of vertex %d's one-ring", (int)u);
        m->e = e, m->e_capacity = (size_t)nl * r;
    }
    for (size_t j = 0; j < d; ++j)
        m->pivoted[m->factor_pivots[j] - 1] = (int)j;
    const row_slot *kept = kept_rows(m, u, r);
    for (int l = 0, k = 0; l < nl; ++l) { /* both links ascending */
        double *e = m->e + (size_t)l * r;
        while (kept && k < kept->nl && kept->link[k] < s->link[l])
            ++k;
        if (kept && k < kept->nl && kept->link[k] == s->link[l] && kept->version[k] == m->version[s->link[l]]) {
            memcpy(e, kept->e + (size_t)k * r, r * sizeof *e);
            continue;
        }
        if (mirrored_row(m, u, s->link[l], r, e))
            continue;
        build_difference(m, s, l, diff, d);
        metric_row(m, diff, e, d, r);
    }
    s->e = m->e, s->rank = (int)r;
    keep_rows(m, s);
    s->gram_ready = 1;
    m->gram_d = d;
    return SK_OK;
}

/* |sum_k c_k e_{index_k}| over a corner's three terms: the deviation's norm, from the one-ring's differences mapped
 * by F. The three rows by pointer: indexed e[index[k] * rank + i] (int), GCC formed each address anew on every step
 * (depending on what surrounded it), about twice this loop's instructions. */
static double corner_cost(const star *s, const int *index, const double *c)
{
    const size_t rank = (size_t)s->rank;
    const double *e0 = s->e + (size_t)index[0] * rank, *e1 = s->e + (size_t)index[1] * rank;
    const double *e2 = s->e + (size_t)index[2] * rank;
    double sum = 0.0;
    for (size_t i = 0; i < rank; ++i) { /* no 0.0 + first: it changes only a zero's sign, which squaring drops */
        const double value = (c[0] * e0[i] + c[1] * e1[i]) + c[2] * e2[i];
        sum += value * value;
    }
    return sqrt(sum);
}

static int straight2(const double *from, const double *at, const double *to, double tolerance)
{
    const double d1[2] = {from[0] - at[0], from[1] - at[1]}, d2[2] = {to[0] - at[0], to[1] - at[1]};
    const double l1 = sqrt(d1[0] * d1[0] + d1[1] * d1[1]), l2 = sqrt(d2[0] * d2[0] + d2[1] * d2[1]);
    return d1[0] * d2[0] + d1[1] * d2[1] < 0.0 && fabs(cross2(d1, d2)) <= tolerance * l1 * l2;
}

static int straight3(const double *from, const double *at, const double *to, double tolerance)
{
    double d1[3], d2[3], c[3];
    sub3(d1, from, at), sub3(d2, to, at);
    cross3(c, d1, d2);
    return dot3(d1, d2) < 0.0 && sqrt(dot3(c, c)) <= tolerance * sqrt(dot3(d1, d1)) * sqrt(dot3(d2, d2));
}

/* The 2D position of link vertex l in wedge w, or NULL. */
static const double *wedge_position(const star *s, int w, int l) { return s->wpos[w * s->nl + l]; }

static const double *wedge_u(const star *s, int w) { return s->wu[w]; }

static int sliver2(const double *p0, const double *p1, const double *p2, double *area)
{
    const double e0[2] = {p1[0] - p0[0], p1[1] - p0[1]}, e1[2] = {p2[0] - p0[0], p2[1] - p0[1]};
    const double e2[2] = {p2[0] - p1[0], p2[1] - p1[1]};
    *area = cross2(e0, e1);
    double longest = max_of(e0[0] * e0[0] + e0[1] * e0[1], max_of(e1[0] * e1[0] + e1[1] * e1[1], e2[0] * e2[0] + e2[1] * e2[1]));
    return !(fabs(*area) > SLIVER * longest);
}

/* The link condition (u's and v's common neighbours are exactly the opposite corners of edge uv's faces) and no
 * duplicated face after u -> link[iv]: R_OK or R_LINK. */
static int link_condition(simplifier *m, const star *s, int iv)
{
    const int32_t v = s->link[iv];
    if (!gather_star(m, &m->sv, v, 0))
        return R_LINK;
    const star *sv = &m->sv;
    const uint32_t stamp = next_mark(&m->mark_stamp, m->mark, m->V);
    for (int l = 0; l < s->nl; ++l)
        m->mark[s->link[l]] = stamp;
    int common = 0;
    for (int i = 0; i < sv->n; ++i) /* v's neighbours that u has, each once: unmarked once counted */
        for (int e = 0; e < 2; ++e) {
            const int32_t x = e ? sv->b[i] : sv->a[i];
            if (m->mark[x] == stamp)
                ++common, m->mark[x] = stamp - 1;
        }
    if (common != s->faces[iv])
        return R_LINK;
    for (int i = 0; i < s->n; ++i) {
        if (s->ia[i] == iv || s->ib[i] == iv)
            continue;
        for (int j = 0; j < sv->n; ++j) {
            const int32_t x = sv->a[j], y = sv->b[j];
            if ((x == s->a[i] && y == s->b[i]) || (x == s->b[i] && y == s->a[i]))
                return R_LINK;
        }
    }
    return R_OK;
}

/* v = link[iv]'s 2D position in each wedge of u (target, s->wedges x 2): 0 when a wedge has no face of uv. */
static int wedge_targets(const star *s, int iv, double (*target)[2])
{
    for (int wedge = 0; wedge < s->wedges; ++wedge) {
        const double *pv = wedge_position(s, wedge, iv);
        if (!pv)
            return 0;
        target[wedge][0] = pv[0], target[wedge][1] = pv[1];
    }
    return 1;
}

/* The faces' 2D areas and rest normals before any collapse: check_target's flip test compares every target with them. */
static void old_faces(const simplifier *m, star *s)
{
    const double *xu = m->rest + 3 * (size_t)s->u;
    for (int i = 0; i < s->n; ++i) {
        sliver2(s->c2[i], s->c2[i] + 2, s->c2[i] + 4, &s->old_area[i]);
        double ea[3], eb[3];
        sub3(ea, m->rest + 3 * (size_t)s->a[i], xu), sub3(eb, m->rest + 3 * (size_t)s->b[i], xu);
        cross3(s->old_normal[i], ea, eb);
    }
    s->faces_ready = 1;
}

/* Records one overlay corner for a full collapse's solve: 0 when memory runs out. */
static int keep_corner(simplifier *m, const int *index, const double *c, double beta)
{
    if (m->corner_count == m->corner_capacity && !sk_grow(&m->corners, &m->corner_capacity, sizeof *m->corners, 256))
        return 0;
    corner *k = &m->corners[m->corner_count++];
    memcpy(k->index, index, sizeof k->index);
    memcpy(k->c, c, sizeof k->c);
    k->beta = beta;
    return 1;
}

/* A costed corner, for the lower bounds of lazy re-costing: moving v by F delta leaves it at least
 * deviation / (1 + |beta|) off, or v itself |F delta| off (|g| <= |g - beta F delta| + |beta| |F delta|). Inline: GCC
 * left it a call from cost_target (too large), 1.5M calls on the horse chain. */
static inline void note_corner(simplifier *m, double deviation, const int *index, const double *c, double beta)
{
    for (int k = 0; k < 3; ++k)
        m->link_reach[index[k]] = max_of(m->link_reach[index[k]], fabs(c[k]));
    m->eval_floor = max_of(m->eval_floor, deviation / (1.0 + fabs(beta)));
    m->eval_reach = max_of(m->eval_reach, max_of(fabs(c[0]), max_of(fabs(c[1]), fabs(c[2]))));
}

/* Whether the new face i (v, a, b; n_new its unnormalised normal, longest its longest edge squared) is thinner than
 * THIN, thinner than the face (u, a, b) it replaces and turned from it by more than TURN_COS's angle. */
static int thin_and_turned(const simplifier *m, const star *s, int i, const double *n_new, double longest)
{
    const double new_twice_area = sqrt(dot3(n_new, n_new));
    if (!(new_twice_area < THIN * longest))
        return 0;
    const double *xu = m->rest + 3 * (size_t)s->u, *xa = m->rest + 3 * (size_t)s->a[i],
                 *xb = m->rest + 3 * (size_t)s->b[i];
    double ea[3], eb[3], eab[3];
    sub3(ea, xa, xu), sub3(eb, xb, xu), sub3(eab, xb, xa);
    const double old_longest = max_of(dot3(ea, ea), max_of(dot3(eb, eb), dot3(eab, eab)));
    const double old_twice_area = sqrt(dot3(s->old_normal[i], s->old_normal[i]));
    return new_twice_area * old_longest < old_twice_area * longest &&
           dot3(s->old_normal[i], n_new) < TURN_COS * old_twice_area * new_twice_area;
}

/* Evaluate's checks of u -> link[iv] but the link condition (steps 1-3): the refusal reason or R_OK. target (s->wedges
 * x 2) receives v's position in each wedge. They read u's star only (its faces, their UVs or the projection, the rest
 * positions and the features), not the coordinates. */
static int check_target(const simplifier *m, star *s, int iv, double (*target)[2])
{
    const int32_t u = s->u, v = s->link[iv];
    const double tolerance = m->options->straightness;
    /* 1. Every wedge keeps a face of uv: u's corners land on v's in the same chart. */
    if (!wedge_targets(s, iv, target))
        return R_CHART;
    /* 2. The boundary, seams, material borders and locked edges. */
    int features = 0, iw = -1;
    for (int l = 0; l < s->nl; ++l)
        if (s->flags[l]) {
            ++features;
            if (l != iv)
                iw = l;
        }
    if (features > 0) {
        const int all = features == 2 && iw >= 0 ? s->flags[iv] | s->flags[iw] : s->flags[iv];
        const int reason = all & (F_SEAM | F_BOUNDARY) ? R_SEAM : R_LOCKED;
        if (features != 2 || !s->flags[iv] || s->flags[iv] != s->flags[iw])
            return reason;
        const int32_t w = s->link[iw];
        if ((all & (F_BOUNDARY | F_MATERIAL | F_LOCKED)) &&
            !straight3(m->rest + 3 * (size_t)v, m->rest + 3 * (size_t)u, m->rest + 3 * (size_t)w, tolerance))
            return reason;
        if (m->uv && (all & (F_SEAM | F_BOUNDARY)))
            for (int wedge = 0; wedge < s->wedges; ++wedge) {
                const double *pv = wedge_position(s, wedge, iv), *pw = wedge_position(s, wedge, iw);
                if (!pv || !pw)
                    return R_CHART;
                if (!straight2(pv, wedge_u(s, wedge), pw, tolerance))
                    return reason;
            }
    }
    if (!m->uv && !s->projected_ok)
        return R_FLIP;
    /* 3. No flipped or degenerate face, in UV (or the projection) and in the rest pose. */
    if (!s->faces_ready)
        old_faces(m, s);
    const double *xv = m->rest + 3 * (size_t)v;
    for (int i = 0; i < s->n; ++i) {
        if (s->ia[i] == iv || s->ib[i] == iv)
            continue;
        double new_area;
        if (sliver2(target[s->wedge[i]], s->c2[i] + 2, s->c2[i] + 4, &new_area) || !(s->old_area[i] * new_area > 0.0))
            return R_FLIP;
        const double *xa = m->rest + 3 * (size_t)s->a[i], *xb = m->rest + 3 * (size_t)s->b[i];
        double ea[3], eb[3], eab[3], n_new[3];
        sub3(ea, xa, xv), sub3(eb, xb, xv), sub3(eab, xb, xa);
        cross3(n_new, ea, eb);
        const double longest = max_of(dot3(ea, ea), max_of(dot3(eb, eb), dot3(eab, eab)));
        if (!(dot3(s->old_normal[i], n_new) > 0.0) || !(sqrt(dot3(n_new, n_new)) > SLIVER * longest))
            return R_FLIP;
        if (thin_and_turned(m, s, i, n_new, longest))
            return R_FLIP;
    }
    return R_OK;
}

/* Costs u -> link[iv] (*cost), which passed check_target (target: its wedge positions). The costing stops once it
 * reaches bound (*cost is then some value >= bound, not the cost): a candidate that cannot beat the best so far needs
 * no exact cost. collect: every corner also goes to m->corners, for a full collapse's solve (complete when the bound
 * is not reached). m->eval_floor receives the corners' lower bound of a full collapse onto v and m->eval_reach grows
 * to the largest coefficient met (note_corner). */
static void cost_target(simplifier *m, star *s, int iv, double bound, double *cost, double (*target)[2], int collect,
                        sk_status *status, sk_error *error)
{
    m->corner_count = 0;
    m->eval_floor = 0.0;
    const int32_t u = s->u;
    /* 4. The memoryless APS cost: the largest deviation over the overlay's cell corners. */
    if (!s->gram_ready) {
        *status = form_gram(m, s, error);
        if (*status != SK_OK)
            return;
    }
    double worst = 0.0;
    for (int wedge = 0; wedge < s->wedges; ++wedge) {
        const double *pu = wedge_u(s, wedge), *pv = target[wedge];
        /* u in the new faces: the face where it is most inside */
        double best = -INFINITY, beta[3] = {0, 0, 0};
        int index[5] = {iv, 0, 0, 0, 0};
        for (int i = 0; i < s->n; ++i) {
            if (s->wedge[i] != wedge || s->ia[i] == iv || s->ib[i] == iv)
                continue;
            const double *pa = s->c2[i] + 2, *pb = s->c2[i] + 4;
            const double ea[2] = {pa[0] - pv[0], pa[1] - pv[1]}, eb[2] = {pb[0] - pv[0], pb[1] - pv[1]};
            const double e[2] = {pu[0] - pv[0], pu[1] - pv[1]};
            const double area = cross2(ea, eb);
            if (area == 0.0)
                continue;
            const double ba = cross2(e, eb) / area, bb = cross2(ea, e) / area, b0 = 1.0 - ba - bb;
            const double least = min_of(b0, min_of(ba, bb));
            if (least > best) {
                best = least, beta[0] = b0, beta[1] = ba, beta[2] = bb;
                index[1] = s->ia[i], index[2] = s->ib[i];
            }
        }
        if (best > -INFINITY) {
            const double c[3] = {-beta[0], -beta[1], -beta[2]};
            const double deviation = corner_cost(s, index, c);
            worst = max_of(worst, deviation);
            note_corner(m, deviation, index, c, beta[0]);
            if (collect && !keep_corner(m, index, c, beta[0])) {
                *status = sk_fail(error, SK_ERROR_MEMORY, "out of memory for the overlay of vertex %d", (int)u);
                return;
            }
            if (worst >= bound)
                break;
        }
        /* crossings of old edges u-a and new edges v-b: the wedge's link vertices but v, ascending */
        int present[MAX_LINK], np = 0;
        double r[MAX_LINK][2], q[MAX_LINK][2], rr[MAX_LINK], qq[MAX_LINK];
        for (int l = 0; l < s->nl; ++l) {
            const double *pl = l == iv ? NULL : wedge_position(s, wedge, l);
            if (!pl)
                continue;
            r[np][0] = pl[0] - pu[0], r[np][1] = pl[1] - pu[1];
            q[np][0] = pl[0] - pv[0], q[np][1] = pl[1] - pv[1];
            rr[np] = r[np][0] * r[np][0] + r[np][1] * r[np][1];
            qq[np] = q[np][0] * q[np][0] + q[np][1] * q[np][1];
            present[np++] = l;
        }
        const double w0[2] = {pv[0] - pu[0], pv[1] - pu[1]};
        for (int a = 0; a < np && worst < bound; ++a) {
            const double wr = cross2(w0, r[a]);
            for (int b = 0; b < np; ++b) {
                if (b == a)
                    continue;
                const double denom = cross2(r[a], q[b]);
                if (!(fabs(denom) > 1e-14 * sqrt(rr[a] * qq[b])))
                    continue;
                const double sa = cross2(w0, q[b]) / denom, tb = wr / denom;
                if (!(sa > 1e-12 && sa < 1.0 - 1e-12 && tb > 1e-12 && tb < 1.0 - 1e-12))
                    continue;
                /* old (1 - sa) p_u + sa p_a, new (1 - tb) p_v + tb p_b */
                const int idx[3] = {present[a], iv, present[b]};
                const double c[3] = {sa, -(1.0 - tb), -tb};
                const double deviation = corner_cost(s, idx, c);
                worst = max_of(worst, deviation);
                note_corner(m, deviation, idx, c, 1.0 - tb);
                if (collect && !keep_corner(m, idx, c, 1.0 - tb)) {
                    *status = sk_fail(error, SK_ERROR_MEMORY, "out of memory for the overlay of vertex %d", (int)u);
                    return;
                }
                if (worst >= bound)
                    break;
            }
        }
        if (worst >= bound)
            break;
    }
    *cost = worst;
}

/* Costs u -> link[iv], legal when u was costed, its star unchanged since (a live entry's): cost_target's corners,
 * complete. */
static void cost_legal(simplifier *m, star *s, int iv, double *cost, double (*target)[2], int collect,
                       sk_status *status, sk_error *error)
{
    wedge_targets(s, iv, target);
    cost_target(m, s, iv, INFINITY, cost, target, collect, status, error);
}

/* Lawson's reweighting (the minimax of the corners' deviations as the limit of weighted least squares): the best
 * of at most 32 steps is kept (tests/core/test_lod_full_collapse.py: no search around it finds a lower cost). Its
 * gains shrink step by step: once LAWSON_PATIENCE steps in a row lower the best by under LAWSON_GAIN of it, the
 * rest would change the cost by less than the queue can tell apart. */
#define LAWSON_STEPS 32
#define LAWSON_PATIENCE 4
#define LAWSON_GAIN 1e-3
/* A column of F on v's coordinates whose part orthogonal to the columns before is below this fraction of the
 * largest column's norm is left out: a direction P barely sees would buy a tiny gain with a huge move. */
#define FULL_DROP 1e-3

/* F's column for pivoted-factor input index o (P's row), times scale, added to col (rank entries). */
static void add_f_column(double *col, const simplifier *m, size_t rank, size_t o, double scale)
{
    const size_t j = (size_t)m->pivoted[o], d = m->gram_d;
    for (size_t i = 0; i <= j && i < rank; ++i)
        col[i] += scale * m->factor[j * d + i];
}

/* A's column `column` (v's x, y, z per bone, then weight t minus the last bone's weight: the weights' sum stays)
 * into col. */
static void full_column(double *col, const simplifier *m, size_t rank, int32_t v, size_t column)
{
    const size_t n = (size_t)m->count[v], begin = (size_t)m->offsets[v];
    memset(col, 0, rank * sizeof *col);
    if (column < 3 * n) {
        const size_t at = 4 * (size_t)m->bone_index[m->bones[begin + column / 3]];
        add_f_column(col, m, rank, at + column % 3, 1.0);
        return;
    }
    const size_t t = column - 3 * n;
    add_f_column(col, m, rank, 4 * (size_t)m->bone_index[m->bones[begin + t]] + 3, 1.0);
    add_f_column(col, m, rank, 4 * (size_t)m->bone_index[m->bones[begin + n - 1]] + 3, -1.0);
}

/* The largest squared coefficient distance from v to a neighbour of u's link (bones matched by index). */
static double coordinate_spread(const simplifier *m, const star *s, int32_t v)
{
    const size_t vb = (size_t)m->offsets[v], vn = (size_t)m->count[v];
    double v2 = 0.0, spread = 0.0;
    for (size_t x = 0; x < 4 * vn; ++x)
        v2 += m->coords[4 * vb + x] * m->coords[4 * vb + x];
    for (int l = -1; l < s->nl; ++l) {
        const int32_t w = l < 0 ? s->u : s->link[l];
        if (w == v)
            continue;
        const size_t wb = (size_t)m->offsets[w], wn = (size_t)m->count[w];
        double w2 = 0.0, both = 0.0;
        for (size_t i = 0; i < wn; ++i) {
            const double *p = m->coords + 4 * (wb + i);
            w2 += p[0] * p[0] + p[1] * p[1] + p[2] * p[2] + p[3] * p[3];
            for (size_t j = 0; j < vn; ++j)
                if (m->bones[wb + i] == m->bones[vb + j]) {
                    const double *q = m->coords + 4 * (vb + j);
                    both += p[0] * q[0] + p[1] * q[1] + p[2] * q[2] + p[3] * q[3];
                }
        }
        spread = max_of(spread, v2 + w2 - 2.0 * both);
    }
    return spread;
}

/* Q (kept x r, an orthonormal basis of A's columns: F's columns on v's coordinates, by one pass of modified
 * Gram-Schmidt), R (rr, k x k: A's kept columns = Q R) and the kept columns' indices; columns (k x r) is scratch.
 * Returns kept. */
static size_t orthonormalize(const simplifier *m, int32_t v, size_t r, size_t k, double *q, double *rr,
                             double *columns, int *kept_column)
{
    double column_norm2[4 * SK_LOD_MAX_VERTEX_INFLUENCES];
    size_t kept = 0;
    double largest = 0.0;
    for (size_t column = 0; column < k; ++column) {
        full_column(columns + column * r, m, r, v, column);
        column_norm2[column] = dot_n(columns + column * r, columns + column * r, r);
        largest = max_of(largest, column_norm2[column]);
    }
    for (size_t column = 0; column < k; ++column) {
        if (!(column_norm2[column] > 0.0))
            continue;
        double *residual = columns + column * r;
        double along = kept ? dot_n(q, residual, r) : 0.0;
        for (size_t a = 0; a < kept; ++a) {
            rr[a * k + kept] = along;
            along = a + 1 < kept ? subtract_then_dot(residual, along, q + a * r, q + (a + 1) * r, r)
                                 : subtract_then_dot(residual, along, q + a * r, NULL, r);
        }
        double norm = kept ? along : dot_n(residual, residual, r);
        if (!(norm > FULL_DROP * FULL_DROP * largest))
            continue;
        norm = sqrt(norm);
        for (size_t i = 0; i < r; ++i)
            q[kept * r + i] = residual[i] / norm;
        rr[kept * k + kept] = norm;
        kept_column[kept++] = (int)column;
    }
    return kept;
}

/* orthonormalize's result, from the basis cache when the ring's bone set and v's bones were met before (the same
 * factor: the same bits), else computed and kept there. */
static size_t full_basis(simplifier *m, int32_t v, size_t r, size_t k, const double **basis, double *q, double *rr,
                         double *columns, int *kept_column)
{
    const size_t nv = (size_t)m->count[v];
    const int32_t *v_bones = m->bones + m->offsets[v];
    basis_slot *slot = NULL;
    uint64_t hash = 0;
    if (m->ring_bone_count && m->bases && nv <= CACHE_MAX_V_BONES) {
        hash = hash_bones(m->ring_hash, v_bones, nv);
        slot = &m->bases[hash % BASIS_SLOTS];
        if (slot->n == m->ring_bone_count && slot->hash == hash && slot->nv == nv &&
            !memcmp(slot->bones, m->ring_bones, slot->n * sizeof *slot->bones) &&
            !memcmp(slot->v_bones, v_bones, nv * sizeof *v_bones)) {
            const size_t kept = slot->kept;
            memcpy(kept_column, slot->kept_column, kept * sizeof *kept_column);
            for (size_t a = 0; a < kept; ++a)
                memcpy(rr + a * k + a, slot->values + a * kept + a, (kept - a) * sizeof *rr);
            *basis = slot->values + kept * kept; /* read in place: only the next miss can replace the slot */
            return kept;
        }
    }
    const size_t kept = orthonormalize(m, v, r, k, q, rr, columns, kept_column);
    *basis = q;
    if (!slot)
        return kept;
    const size_t need = kept * kept + kept * r;
    if (need > slot->capacity) {
        double *grown = realloc(slot->values, need * sizeof *grown);
        slot->n = 0;
        if (!grown)
            return kept; /* out of memory: simply not kept */
        slot->values = grown, slot->capacity = need;
    }
    slot->hash = hash, slot->n = m->ring_bone_count, slot->nv = nv, slot->kept = kept;
    memcpy(slot->bones, m->ring_bones, slot->n * sizeof *slot->bones);
    memcpy(slot->v_bones, v_bones, nv * sizeof *v_bones);
    memcpy(slot->kept_column, kept_column, kept * sizeof *kept_column);
    for (size_t a = 0; a < kept; ++a)
        memcpy(slot->values + a * kept + a, rr + a * k + a, (kept - a) * sizeof *rr);
    memcpy(slot->values + kept * kept, q, kept * r * sizeof *q);
    return kept;
}

/* The full collapse u -> link[iv] after cost_target(collect): v's coordinates move by delta (on v's bones, the
 * homogeneous weights' sum kept) to the minimiser of the largest deviation |g_c - beta_c F delta| over the
 * corners and v itself (g = 0, beta = 1). F delta = Q z (Q: an orthonormal basis of A's columns by one pass of
 * modified Gram-Schmidt, enough because a column left with under FULL_DROP of the largest norm is dropped), so a
 * corner's squared deviation is |g|^2 - 2 beta (Q^T g).z + beta^2 |z|^2. *cost
 * receives the least maximum met (the half-edge one, z = 0, included); delta (4 * count[v], may be NULL) the
 * move, R x = z solved on the columns kept. */
static sk_status solve_full(simplifier *m, const star *s, int iv, double *cost, double *delta, sk_error *error)
{
    const int32_t v = s->link[iv];
    const size_t r = (size_t)s->rank, n = (size_t)m->count[v];
    const size_t k = n > 1 ? 4 * n - 1 : 3, corners = m->corner_count + 1;
    const size_t need = 2 * r * k + k * k + corners * k + 3 * corners + 3 * k + r;
    if (need > m->solve_capacity) {
        double *grown = realloc(m->solve_work, need * sizeof *grown);
        if (!grown)
            return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the full collapse of vertex %d", (int)s->u);
        m->solve_work = grown, m->solve_capacity = need;
    }
    double *q = m->solve_work, *rr = q + r * k, *h = rr + k * k, *gg = h + corners * k, *w = gg + corners;
    double *beta = w + corners, *z = beta + corners, *best_z = z + k, *x = best_z + k, *col = x + k;
    double *columns = col + r; /* F's k columns on v's coordinates, formed once */
    int kept_column[4 * SK_LOD_MAX_VERTEX_INFLUENCES];
    const double *basis = NULL;
    const size_t kept = full_basis(m, v, r, k, &basis, q, rr, columns, kept_column);
    /* the corners: g = sum c e (rank entries, in col), h = Q^T g, gg = |g|^2; v itself last (g = 0, beta = 1) */
    double best = 0.0;
    for (size_t c = 0; c < corners; ++c) {
        double *hc = h + c * k;
        gg[c] = 0.0, w[c] = 1.0;
        memset(hc, 0, kept * sizeof *hc);
        if (c + 1 == corners) {
            beta[c] = 1.0;
            continue;
        }
        const corner *at = &m->corners[c];
        beta[c] = at->beta;
        for (size_t i = 0; i < r; ++i) { /* in a local: col's stores could alias at and s->e, which were re-read */
            double value = 0.0;
            for (int t = 0; t < 3; ++t)
                value += at->c[t] * s->e[(size_t)at->index[t] * r + i];
            col[i] = value;
            gg[c] += value * value;
        }
        for (size_t a = 0; a < kept; ++a)
            hc[a] = dot_n(basis + a * r, col, r);
        best = max_of(best, sqrt(gg[c]));
    }
    memset(best_z, 0, kept * sizeof *best_z);
    for (int step = 0, idle = 0; step < LAWSON_STEPS && idle < LAWSON_PATIENCE && kept > 0; ++step) {
        double weight = 0.0;
        memset(z, 0, kept * sizeof *z);
        for (size_t c = 0; c < corners; ++c) {
            /* w beta once (the products are the same, left to right): z's stores could alias w and beta, so the
             * compiler re-read and re-multiplied them for every a */
            const double wb = w[c] * beta[c];
            weight += wb * beta[c];
            add_scaled(z, h + c * k, wb, kept);
        }
        if (!(weight > 0.0))
            break;
        double zz = 0.0;
        for (size_t a = 0; a < kept; ++a)
            z[a] /= weight, zz += z[a] * z[a];
        double worst = 0.0, total = 0.0;
        for (size_t c = 0; c < corners; ++c) {
            const double hz = dot_n(h + c * k, z, kept);
            const double deviation = sqrt(max_of(0.0, gg[c] - 2.0 * beta[c] * hz + beta[c] * beta[c] * zz));
            worst = max_of(worst, deviation);
            w[c] *= deviation;
            total += w[c];
        }
        idle = worst < best * (1.0 - LAWSON_GAIN) ? 0 : idle + 1;
        if (worst < best) {
            best = worst;
            memcpy(best_z, z, kept * sizeof *z);
        }
        if (!(total > 0.0))
            break;
        for (size_t c = 0; c < corners; ++c)
            w[c] /= total;
    }
    for (size_t a = kept; a-- > 0;) {
        double value = best_z[a];
        for (size_t b = a + 1; b < kept; ++b)
            value -= rr[a * k + b] * x[b];
        x[a] = value / rr[a * k + a];
    }
    double move[4 * SK_LOD_MAX_VERTEX_INFLUENCES];
    memset(move, 0, 4 * n * sizeof *move);
    for (size_t a = 0; a < kept; ++a) {
        const size_t column = (size_t)kept_column[a];
        if (column < 3 * n) {
            move[4 * (column / 3) + column % 3] += x[a];
        } else {
            move[4 * (column - 3 * n) + 3] += x[a];
            move[4 * (n - 1) + 3] -= x[a];
        }
    }
    /* The trust region: v's coordinates move at most as far as its farthest neighbour's are from them (coefficient
     * space). A larger move fits the pose statistics in directions the poses barely show, and held-out poses
     * would see it (measured on the creature: 0.4 of the unit box); the collapse stays a half-edge one then. */
    double moved = 0.0;
    for (size_t e = 0; e < 4 * n; ++e)
        moved += move[e] * move[e];
    if (moved > coordinate_spread(m, s, v)) {
        best = 0.0;
        for (size_t c = 0; c < corners; ++c)
            best = max_of(best, sqrt(gg[c]));
        memset(move, 0, 4 * n * sizeof *move);
    }
    *cost = best;
    if (delta)
        memcpy(delta, move, 4 * n * sizeof *delta);
    return SK_OK;
}

static void count_refusal(simplifier *m, int reason)
{
    sk_simplify_report *r = m->report;
    if (reason == R_FLIP)
        ++r->refused_flip;
    else if (reason == R_CHART)
        ++r->refused_chart;
    else if (reason == R_SEAM)
        ++r->refused_seam;
    else if (reason == R_LINK)
        ++r->refused_link;
    else if (reason == R_LOCKED)
        ++r->refused_locked;
}

/* Whether u's star (gathered full) touches the boundary, a seam, a material border or a locked edge. */
static int star_featured(const star *s)
{
    for (int l = 0; l < s->nl; ++l)
        if (s->flags[l])
            return 1;
    return 0;
}

static unsigned char featured_as_costed(const simplifier *m, int32_t x);

/* Whether u -> link[l] may be a full collapse: an interior edge (neither end's star featured, v's as
 * of its last costing, which every change to its star triggers) in the animation metric. */
static int full_candidate(const simplifier *m, const star *s, int l)
{
    return m->collapse != SK_LOD_COLLAPSE_HALF && m->options->metric == SK_LOD_METRIC_ANIMATION &&
           !m->featured[s->u] && !featured_as_costed(m, s->link[l]);
}

/* Queues u's edge candidate at cost (or a lower bound of it), ranked as m's tuning says. */
static entry edge_entry(const simplifier *m, int32_t u, double cost)
{
    double rank = cost * m->edge_queue_scale;
    if (m->rank_per_influence && m->count[u] > 1) /* squared cost per influence removed: cost^2 / n */
        rank /= sqrt((double)m->count[u]);
    return (entry){rank, u, m->stamp[u]};
}

static sk_status queue_edge(simplifier *m, int32_t u, double cost, sk_error *error)
{
    if (!heap_push(&m->queue, edge_entry(m, u, cost)))
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the collapse queue");
    return SK_OK;
}

/* The largest metric length |e_l| of u's one-ring: the scale of its costs' rounding errors. */
static double ring_scale(const star *s)
{
    double largest = 0.0;
    for (int l = 0; l < s->nl; ++l)
        largest = max_of(largest, dot_n(s->e + (size_t)l * (size_t)s->rank, s->e + (size_t)l * (size_t)s->rank,
                                      (size_t)s->rank));
    return sqrt(largest);
}

/* Keeps the coefficient bound of u's first REACH_LINKS neighbours, rounded up to float. */
static void keep_reach(simplifier *m, const star *s)
{
    int32_t *ids = m->reach_ids + (size_t)s->u * REACH_LINKS;
    float *values = m->reach_values + (size_t)s->u * REACH_LINKS;
    for (int l = 0; l < REACH_LINKS; ++l) {
        ids[l] = l < s->nl ? s->link[l] : -1;
        float value = l < s->nl ? (float)m->link_reach[l] : 0.0f;
        if (l < s->nl && (double)value < m->link_reach[l])
            value = nextafterf(value, INFINITY);
        values[l] = value;
    }
}

/* How much a unit metric move of neighbour a can lower w's cost (as of w's last costing). */
static double reach_of(const simplifier *m, int32_t w, int32_t a)
{
    const int32_t *ids = m->reach_ids + (size_t)w * REACH_LINKS;
    for (int l = 0; l < REACH_LINKS && ids[l] >= 0; ++l)
        if (ids[l] == a)
            return (double)m->reach_values[(size_t)w * REACH_LINKS + (size_t)l];
    return m->edge_reach[w];
}

/* Re-costs u's edge candidate and queues it. ring (may be NULL) receives u's live neighbours, ascending, and
 * *ring_count their number (-1 when u is unused or its star too large to walk). star_kept: u's star is the one of its
 * last costing (only coordinates moved since), so each target's check_target outcome, which reads the star only, is
 * the one kept then. */
static sk_status cost_candidates(simplifier *m, int32_t u, int32_t *ring, int *ring_count, int star_kept,
                                 sk_error *error)
{
    ++m->stamp[u];
    const int32_t previous = m->edge_target[u];
    m->edge_target[u] = -1;
    m->stale[u] = 0, m->edge_slack[u] = 0.0, m->eval_reach = 0.0;
    if (m->unsolved)
        m->unsolved[u] = 0;
    if (ring_count)
        *ring_count = -1;
    if (!m->in_use[u])
        return SK_OK;
    star *s = &m->s;
    if (!gather_star(m, s, u, 1)) {
        ++m->report->refused_link;
        return SK_OK;
    }
    if (ring) {
        memcpy(ring, s->link, (size_t)s->nl * sizeof *ring);
        *ring_count = s->nl;
    }
    for (int l = 0; l < s->nl; ++l)
        m->link_reach[l] = 0.0;
    const unsigned char featured = (unsigned char)star_featured(s);
    if (m->featured && m->featured[u] != featured) /* inside a batch, set before it */
        m->featured[u] = featured;
    double target[MAX_STAR][2];
    double best = INFINITY;
    int32_t best_v = -1;
    int best_full = 0, best_l = -1;
    double floor = INFINITY; /* the least of the targets' lower bounds */
    double best_floor = 0.0;  /* the best target's corner bound of its full collapse */
    /* The last costing's target first: it is usually the best again (82% of the horse's re-costings), and its cost
     * as the bound stops the other targets' costing sooner. The choice is the one of an ascending scan, the least
     * (cost, link index) of the legal targets, so a target before the best stops only above its cost. */
    const int first = previous >= 0 ? link_index(s, previous) : -1;
    unsigned char *checked = s->nl <= CHECKED_LINKS ? m->checked + (size_t)u * CHECKED_LINKS : NULL;
    for (int step = first >= 0 ? -1 : 0; step < s->nl; ++step) {
        const int l = step < 0 ? first : step;
        if (step >= 0 && l == first)
            continue;
        double cost = 0.0;
        sk_status status = SK_OK;
        const int full = m->collapse == SK_LOD_COLLAPSE_FULL && full_candidate(m, s, l);
        const double bound = full ? INFINITY : l < best_l ? nextafter(best, INFINITY) : best;
        int reason = checked && star_kept ? checked[l] : check_target(m, s, l, target);
        if (checked && star_kept && reason == R_OK)
            wedge_targets(s, l, target);
        if (checked)
            checked[l] = (unsigned char)reason;
        if (reason == R_OK)
            cost_target(m, s, l, bound, &cost, target, full, &status, error);
        if (status != SK_OK)
            return status;
        /* 5. Last, being the dearest check (it walks v's star): only for a candidate that beats the bound. */
        if (reason == R_OK && cost < bound)
            reason = link_condition(m, s, l);
        if (reason != R_OK) {
            count_refusal(m, reason);
            continue;
        }
        /* a target that may be a full collapse could cost as little as its corners' bound; a half-edge one costs at
         * least the (maybe partial, when stopped at the bound) largest deviation met */
        floor = min_of(floor, full_candidate(m, s, l) ? m->eval_floor : cost);
        int chosen_full = 0;
        if (full) {
            double full_cost = 0.0;
            status = solve_full(m, s, l, &full_cost, NULL, error);
            if (status != SK_OK)
                return status;
            if (full_cost < cost)
                cost = full_cost, chosen_full = 1;
        }
        if (cost < best || (cost == best && l < best_l)) { /* ties keep the lowest v */
            best = cost, best_v = s->link[l], best_full = chosen_full, best_l = l, best_floor = m->eval_floor;
        }
    }
    if (best_v < 0)
        return SK_OK;
    m->edge_target[u] = best_v, m->edge_cost[u] = best;
    if (m->edge_full)
        m->edge_full[u] = (unsigned char)best_full;
    const double scale = ring_scale(s);
    m->edge_floor[u] = min_of(floor, best) * (1.0 - FLOOR_RELATIVE) - FLOOR_ABSOLUTE * scale;
    m->edge_reach[u] = m->eval_reach;
    keep_reach(m, s);
    if (m->collapse == SK_LOD_COLLAPSE_AUTO && full_candidate(m, s, best_l)) {
        /* the half-edge target's survivor is re-solved, but only once its corner bound reaches the top of the queue
         * (solve_queued): most costings are superseded before that */
        m->unsolved[u] = 1;
        return queue_edge(m, u, min_of(best_floor, best) * (1.0 - FLOOR_RELATIVE) - FLOOR_ABSOLUTE * scale, error);
    }
    return queue_edge(m, u, best, error);
}

static sk_status cost_edges(simplifier *m, int32_t u, int32_t *ring, int *ring_count, sk_error *error)
{
    return cost_candidates(m, u, ring, ring_count, 0, error);
}

/* Whether the queue's least live entry (its dead ones dropped) comes after item: item would be popped next. */
static void drop_dead_top(simplifier *m)
{
    while (m->queue.size > 0 && m->stamp[m->queue.items[0].id] != m->queue.items[0].stamp)
        heap_pop(&m->queue);
}

static int before_queue(simplifier *m, const entry *item)
{
    drop_dead_top(m);
    return m->queue.size == 0 || entry_less(item, &m->queue.items[0]);
}

/* The next live entry, when it is a stale edge entry, re-costed by the helper alone while this thread works on u's
 * collapse before it changes anything (solve_queued's solve, an influence collapse's correction): that work reads the
 * mesh and writes only u's entries and this thread's scratch, and the helper's costing reads neither (u's rows are
 * kept out of both threads' reach, as in a batch). The entry stays queued until end_speculation. */
typedef struct speculation {
    int32_t ids[2]; /* the helper's vertex, then u */
    uint_fast64_t posted;
} speculation;

static void speculate(simplifier *m, int32_t u, speculation *spec);
static sk_status end_speculation(simplifier *m, const speculation *spec, sk_error *error);

/* u's queued key was its half-edge target's corner bound: the target's survivor re-solved (what cost_edges would
 * have solved at once: u's one-ring and the target's features are as they were then), with its move in m->delta.
 * *next: u's cost is below every other entry, so m->s and target hold the collapse for collapse_edge at once;
 * otherwise u is queued at its cost. */
static sk_status solve_queued(simplifier *m, int32_t u, double (*target)[2], int *next, sk_error *error)
{
    star *s = &m->s;
    *next = 0;
    const int iv = gather_star(m, s, u, 1) ? link_index(s, m->edge_target[u]) : -1;
    if (iv < 0) /* a live entry's ring is the one it was costed on, so this cannot happen: costed again */
        return cost_edges(m, u, NULL, NULL, error);
    double cost = 0.0, full_cost = 0.0;
    sk_status status = SK_OK;
    speculation spec;
    speculate(m, u, &spec);
    cost_legal(m, s, iv, &cost, target, 1, &status, error);
    if (status == SK_OK)
        status = solve_full(m, s, iv, &full_cost, m->delta, error);
    const sk_status taken = end_speculation(m, &spec, error);
    if (status == SK_OK)
        status = taken;
    if (status != SK_OK)
        return status;
    m->unsolved[u] = 0;
    if (full_cost < m->edge_cost[u])
        m->edge_cost[u] = full_cost, m->edge_full[u] = 1;
    ++m->stamp[u];
    const entry item = edge_entry(m, u, m->edge_cost[u]);
    *next = before_queue(m, &item);
    if (*next)
        return SK_OK;
    if (m->queued_delta) {
        memcpy(m->queued_delta + (size_t)u * m->delta_stride, m->delta,
               4 * (size_t)m->count[m->edge_target[u]] * sizeof *m->delta);
        m->delta_stamp[u] = m->stamp[u];
    }
    if (!heap_push(&m->queue, item))
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the collapse queue");
    return SK_OK;
}

/* Re-costs vertex a's influence candidate and queues it. */
static sk_status cost_influences(simplifier *m, int32_t a, sk_error *error)
{
    const size_t id = m->V + (size_t)a;
    ++m->stamp[id];
    m->inf_slot[a] = -1;
    if (!m->options->simplify_influences || !m->in_use[a] || m->count[a] < 2)
        return SK_OK;
    const size_t begin = (size_t)m->offsets[a], n = (size_t)m->count[a];
    double best = INFINITY, costs[SK_LOD_MAX_VERTEX_INFLUENCES];
    const sk_status status = sk_influence_remover_costs(m->remover, costs, NULL, m->bones + begin,
                                                        m->coords + 4 * begin, n, (size_t)a, error);
    if (status != SK_OK)
        return status;
    for (size_t c = 0; c < n; ++c)
        if (costs[c] < best)
            best = costs[c], m->inf_slot[a] = (int32_t)c;
    m->inf_cost[a] = best;
    if (!heap_push(&m->queue, (entry){best, (int32_t)id, m->stamp[id]}))
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the collapse queue");
    return SK_OK;
}

/* ---------------------------------------------------------------------------------------------
 * Costing on two threads
 *
 * Costing u's edge candidate reads the mesh and writes only u's own entries (its target, cost, bounds, stamp) and the
 * costing thread's scratch and caches, whose contents never change a cost's bits. So the candidates costed while
 * nothing collapses (every vertex at the start; v's changed neighbours after an edge collapse; a run of stale entries
 * at the top of the queue) are shared out as a batch between the caller's thread and one helper thread, each with its
 * own scratch, caches, refusal counts and queue (the helper's entries join the caller's queue afterwards: the queue
 * pops live entries in (key, id) order, whatever order they were pushed in). Re-costing a stale entry before it
 * reaches the top changes only its key, from one lower bound of its cost to another (its cost), so the queue applies
 * the same collapses. Every level is the same bits on one thread or two.
 *
 * The one read that depends on the serial order: a full collapse needs both ends unfeatured, each as of its last
 * costing, so a batch of neighbours re-costed after an edge collapse keeps, for each member, its flag from before the
 * batch (featured_before) for the members after it. The helper waits for batches by spinning on a ticket (it yields
 * after a while); a batch it did not join in time is the caller's alone, so no batch ever waits for a thread that is
 * not running.
 * ------------------------------------------------------------------------------------------- */

/* Initial costing: vertices claimed this many at a time. */
#define START_CHUNK 32
/* The helper's spins on an unchanged ticket before it yields the processor. */
#define HELPER_SPINS 4096
/* thread_count 0 starts the helper for a model of at least this many influences (the arm's 5,250 ran 11% slower with
 * it, the creature's 24,387 17% faster: below, its start, caches and hand-offs cost more than it saves); 2 or more
 * start it for any size. */
#define HELPER_MIN_INFLUENCES 16384
/* Seconds the start waits for the helper thread to run. */
#define HELPER_START_WAIT 0.01

enum { TICKET_OPEN = 0, TICKET_JOINED = 1, TICKET_CLOSED = 2, TICKET_LEFT = 3 };

struct costing_batch {
    const int32_t *ids;                   /* the vertices to cost, or NULL: 0 .. count - 1 */
    size_t count, chunk;                  /* items are claimed chunk at a time */
    size_t members;                       /* ids' vertices whose rows are in use (count, or one more: see speculate) */
    int star_kept;
    const unsigned char *featured_before; /* per item, or NULL (see featured_as_costed) */
    atomic_size_t next;
    atomic_int failed;
    sk_status status;                     /* the first failure's */
    sk_error error;
};

struct costing_helper {
    simplifier worker;         /* the helper's simplifier: the caller's arrays, its own scratch, caches and queue */
    sk_simplify_report report; /* its refusal counts, added to the caller's after each batch it joined */
    costing_batch batch;
    atomic_uint_fast64_t ticket; /* batch generation << 2 | TICKET_*: posted OPEN, JOINED and LEFT by the helper, or
                                    CLOSED by the caller when the helper did not join */
    uint64_t generation;
    atomic_int started, finished;
};

/* The kept rows are shared, but inside a batch another member's thread may be rewriting a slot: this thread reads a
 * slot only when no other member's vertex maps to it, and writes its own item's on the same condition (in the start's
 * batch, where every vertex is a member, it reads none but its own and writes that when no other vertex shares it). */
static int row_slot_free(const simplifier *m, size_t slot)
{
    const costing_batch *b = m->batch;
    if (!b)
        return 1;
    const size_t own = m->batch_item;
    if (!b->ids)
        return slot == own && m->V <= m->row_slots;
    for (size_t i = 0; i < b->members; ++i)
        if (i != own && (size_t)b->ids[i] % m->row_slots == slot)
            return 0;
    return 1;
}

/* Vertex x's featured flag as the serial order would read it while this thread costs its batch item. */
static unsigned char featured_as_costed(const simplifier *m, int32_t x)
{
    const costing_batch *b = m->batch;
    if (b && b->featured_before)
        for (size_t i = m->batch_item + 1; i < b->count; ++i)
            if (b->ids[i] == x)
                return b->featured_before[i];
    return m->featured[x];
}

static void cost_items(simplifier *m, costing_batch *b)
{
    sk_error error = {0};
    for (;;) {
        const size_t begin = atomic_fetch_add(&b->next, b->chunk);
        if (begin >= b->count || atomic_load(&b->failed))
            return;
        const size_t end = begin + b->chunk < b->count ? begin + b->chunk : b->count;
        for (size_t i = begin; i < end; ++i) {
            m->batch_item = i;
            const int32_t u = b->ids ? b->ids[i] : (int32_t)i;
            const sk_status status = cost_candidates(m, u, NULL, NULL, b->star_kept, &error);
            if (status != SK_OK) {
                if (!atomic_exchange(&b->failed, 1))
                    b->status = status, b->error = error;
                return;
            }
        }
    }
}

/* The helper's queue entries into the caller's queue, its refusal counts into the caller's report. */
static sk_status take_helper_results(simplifier *m, costing_helper *h, sk_error *error)
{
    heap *queue = &h->worker.queue;
    for (size_t x = 0; x < queue->size; ++x)
        if (!heap_push(&m->queue, queue->items[x]))
            return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the collapse queue");
    queue->size = 0;
    sk_simplify_report *r = m->report, *hr = &h->report;
    r->refused_flip += hr->refused_flip, r->refused_chart += hr->refused_chart, r->refused_seam += hr->refused_seam;
    r->refused_link += hr->refused_link, r->refused_locked += hr->refused_locked;
    memset(hr, 0, sizeof *hr);
    return SK_OK;
}

/* Posts a batch for the helper: count items to claim (ids, or 0 .. count - 1), the first `members` of ids in use
 * (count, or one more: see speculate). Returns its ticket's generation bits; m costs inside it until close_batch. */
static uint_fast64_t post_batch(simplifier *m, const int32_t *ids, size_t count, size_t members, size_t chunk,
                                int star_kept, const unsigned char *featured_before)
{
    costing_helper *h = m->helper;
    costing_batch *b = &h->batch;
    b->ids = ids, b->count = count, b->members = members, b->chunk = chunk, b->star_kept = star_kept;
    b->featured_before = featured_before;
    atomic_store(&b->next, 0);
    atomic_store(&b->failed, 0);
    const uint_fast64_t posted = (uint_fast64_t)++h->generation << 2;
    atomic_store_explicit(&h->ticket, posted | TICKET_OPEN, memory_order_release);
    m->batch = b;
    return posted;
}

/* Ends the batch posted: the helper's results taken when it joined (waiting until it left), the first failure met. */
static sk_status close_batch(simplifier *m, uint_fast64_t posted, sk_error *error)
{
    costing_helper *h = m->helper;
    m->batch = NULL;
    uint_fast64_t open = posted | TICKET_OPEN;
    sk_status status = SK_OK;
    if (!atomic_compare_exchange_strong(&h->ticket, &open, posted | TICKET_CLOSED)) {
        while (atomic_load_explicit(&h->ticket, memory_order_acquire) != (posted | TICKET_LEFT))
            ;
        status = take_helper_results(m, h, error);
    }
    if (status == SK_OK && atomic_load(&h->batch.failed)) {
        *error = h->batch.error;
        return h->batch.status;
    }
    return status;
}

/* Costs the batch's vertices (ids, or 0 .. count - 1) with the helper when it runs; otherwise in order, as always. */
static sk_status cost_batch(simplifier *m, const int32_t *ids, size_t count, size_t chunk, int star_kept,
                            const unsigned char *featured_before, sk_error *error)
{
    costing_helper *h = m->helper;
    if (!h || count < 2 || !atomic_load_explicit(&h->started, memory_order_acquire)) {
        sk_status status = SK_OK;
        for (size_t i = 0; i < count && status == SK_OK; ++i)
            status = cost_candidates(m, ids ? ids[i] : (int32_t)i, NULL, NULL, star_kept, error);
        return status;
    }
    const uint_fast64_t posted = post_batch(m, ids, count, count, chunk, star_kept, featured_before);
    cost_items(m, &h->batch);
    return close_batch(m, posted, error);
}

static void helper_loop(costing_helper *h)
{
    atomic_store_explicit(&h->started, 1, memory_order_release);
    uint_fast64_t seen = 0;
    unsigned idle = 0;
    while (!atomic_load_explicit(&h->finished, memory_order_acquire)) {
        uint_fast64_t ticket = atomic_load_explicit(&h->ticket, memory_order_acquire);
        if ((ticket & 3) != TICKET_OPEN || ticket >> 2 == seen) {
            if (++idle == HELPER_SPINS)
                sk_thread_yield(), idle = 0;
            continue;
        }
        seen = ticket >> 2, idle = 0;
        if (!atomic_compare_exchange_strong(&h->ticket, &ticket, ticket | TICKET_JOINED))
            continue; /* the caller costed it alone */
        h->worker.batch = &h->batch;
        cost_items(&h->worker, &h->batch);
        h->worker.batch = NULL;
        atomic_store_explicit(&h->ticket, (ticket & ~(uint_fast64_t)3) | TICKET_LEFT, memory_order_release);
    }
}

/* The one-ring factor cache and the full collapses' basis cache, with their slots' buffers. */
static void free_factor_caches(simplifier *m)
{
    for (size_t x = 0; m->factors && x < FACTOR_SLOTS; ++x)
        free(m->factors[x].factor), free(m->factors[x].pivots);
    for (size_t x = 0; m->bases && x < BASIS_SLOTS; ++x)
        free(m->bases[x].values);
    free(m->factors), free(m->bases);
}

static void free_worker(simplifier *w)
{
    free(w->mark), free(w->bone_mark), free(w->bone_index), free(w->queue.items), free(w->dense), free(w->q);
    free((void *)w->wpos), free(w->e), free(w->pivots), free(w->pivoted), free(w->corners), free(w->solve_work);
    free_factor_caches(w);
}

/* The helper's simplifier: m's shared arrays and kept rows, scratch and factor and basis caches of its own (a slot
 * is rewritten on a miss, which a reader on the other thread would see half done). 0 when out of memory. */
static int make_worker(costing_helper *h, const simplifier *m)
{
    simplifier *w = &h->worker;
    *w = *m;
    memset(&h->report, 0, sizeof h->report);
    w->report = &h->report, w->helper = NULL, w->batch = NULL;
    w->queue = (heap){NULL, 0, 0};
    w->dense = w->e = NULL, w->pivots = NULL, w->pivoted = NULL, w->corners = NULL, w->solve_work = NULL;
    w->dense_capacity = w->e_capacity = w->pivot_capacity = w->corner_capacity = w->solve_capacity = 0;
    w->corner_count = 0;
    w->s.e = w->sv.e = NULL;
    w->mark_stamp = 0, w->bone_stamp = 0;
    w->mark = sk_allocate_zeroed(m->V, sizeof *w->mark);
    w->bone_mark = sk_allocate_zeroed(m->bone_count + 1, sizeof *w->bone_mark);
    w->bone_index = sk_allocate(m->bone_count + 1, sizeof *w->bone_index);
    w->q = sk_allocate((size_t)(MAX_LINK + 1) * SK_LOD_MAX_VERTEX_INFLUENCES, sizeof *w->q);
    w->wpos = sk_allocate(2 * (size_t)MAX_STAR * MAX_LINK, sizeof *w->wpos);
    w->s.wpos = w->wpos, w->sv.wpos = w->wpos ? w->wpos + (size_t)MAX_STAR * MAX_LINK : NULL;
    w->factors = m->factors ? calloc(FACTOR_SLOTS, sizeof *w->factors) : NULL;
    w->bases = m->bases ? calloc(BASIS_SLOTS, sizeof *w->bases) : NULL;
    if (!w->mark || !w->bone_mark || !w->bone_index || !w->q || !w->wpos || (m->factors && !w->factors) ||
        (m->bases && !w->bases)) {
        free_worker(w);
        return 0;
    }
    return 1;
}

/* The vertices whose one-rings an edge collapse changed (v, when first, then its neighbours, ascending), re-costed as
 * in that order. */
static sk_status cost_changed(simplifier *m, const int32_t *changed, int count, sk_error *error)
{
    costing_helper *h = m->helper; /* decided once: the flags set below are for a batch on two threads only */
    if (!h || count < 2 || !atomic_load_explicit(&h->started, memory_order_acquire))
        return cost_batch(m, changed, (size_t)count, 1, 0, NULL, error);
    unsigned char before[MAX_LINK + 1];
    for (int i = 0; i < count; ++i) { /* each member's flag from its new star, set before the batch (and pruned) */
        before[i] = m->featured ? m->featured[changed[i]] : 0;
        if (m->featured && m->in_use[changed[i]] && gather_star(m, &m->sv, changed[i], 1))
            m->featured[changed[i]] = (unsigned char)star_featured(&m->sv);
    }
    const uint_fast64_t posted = post_batch(m, changed, (size_t)count, (size_t)count, 1, 0,
                                            m->featured ? before : NULL);
    cost_items(m, &h->batch);
    return close_batch(m, posted, error);
}

/* The next live entry's vertex when it is a stale edge entry (stale first, as run_to_targets checks), else -1. */
static int32_t stale_at_top(simplifier *m)
{
    drop_dead_top(m);
    const int32_t next = m->queue.size > 0 ? m->queue.items[0].id : -1;
    return next >= 0 && (size_t)next < m->V && m->stale[next] ? next : -1;
}

/* Re-costs the stale edge entry just popped and, with a helper, the next live entry too when it is stale. */
static sk_status cost_stale(simplifier *m, int32_t u, sk_error *error)
{
    const int32_t next = m->helper ? stale_at_top(m) : -1;
    if (next < 0)
        return cost_candidates(m, u, NULL, NULL, 1, error);
    heap_pop(&m->queue);
    const int32_t pair[2] = {u, next};
    return cost_batch(m, pair, 2, 1, 1, NULL, error);
}

static void speculate(simplifier *m, int32_t u, speculation *spec)
{
    spec->posted = 0;
    costing_helper *h = m->helper;
    if (!h || !atomic_load_explicit(&h->started, memory_order_acquire))
        return;
    const int32_t next = stale_at_top(m);
    if (next < 0)
        return;
    spec->ids[0] = next, spec->ids[1] = u;
    spec->posted = post_batch(m, spec->ids, 1, 2, 1, 1, NULL);
    m->batch_item = 1;
}

/* Takes the helper's costing when it joined (its old entry is then dead); otherwise the entry stays as it was. */
static sk_status end_speculation(simplifier *m, const speculation *spec, sk_error *error)
{
    return spec->posted ? close_batch(m, spec->posted, error) : SK_OK;
}

/* |F delta|'s bound for vertex a's coordinates moving by delta (4 * count[a]): sqrt(delta^T P delta) over a's bones,
 * raised by the rounding of the quadratic form (P is semi-definite: its terms are at most trace(P) |delta|^2). */
static double move_length(const simplifier *m, int32_t a, const double *delta)
{
    const size_t begin = (size_t)m->offsets[a], n = (size_t)m->count[a];
    double form = 0.0, trace = 0.0, length2 = 0.0;
    for (size_t x = 0; x < 4 * n; ++x)
        length2 += delta[x] * delta[x];
    for (size_t j = 0; j < n; ++j)
        for (size_t k = 0; k < n; ++k) {
            double scratch[16];
            const double *block = sk_influence_remover_block_ref(scratch, m->remover, m->bones[begin + j],
                                                                 m->bones[begin + k]);
            for (int r = 0; r < 4; ++r)
                for (int c = 0; c < 4; ++c)
                    form += delta[4 * j + (size_t)r] * block[4 * r + c] * delta[4 * k + (size_t)c];
            if (j == k)
                trace += block[0] + block[5] + block[10] + block[15];
        }
    return sqrt(max_of(form, 0.0) + 1e-12 * trace * length2) * (1.0 + FLOOR_RELATIVE);
}

/* Vertex a's coordinates moved by at most `moved` in the metric: the one-ring of w (a neighbour, or a itself) changed
 * only there, so each of its corners' deviations moved by at most |c_a| moved, and its cost fell by at most
 * reach_of(w, a) moved
 * (its refusals depend on the topology and the UVs only, so they stand). Its candidate is queued at the lowered
 * lower bound and re-costed only when that reaches the top of the queue (run_to_targets) or its ring changes: the
 * queue pops the same collapses in the same order as re-costing it now would, for fewer costings. */
static sk_status stale_after_move(simplifier *m, int32_t w, int32_t a, double moved, sk_error *error)
{
    if (!m->in_use[w] || m->edge_target[w] < 0) /* no legal collapse: none appears by moving coordinates */
        return SK_OK;
    ++m->stamp[w];
    m->stale[w] = 1;
    /* w itself moving: every corner's coefficient of w sums to at most 1 in magnitude (minus a face's barycentric
     * weights, or sa - 1 at a crossing), so each deviation, and each corner bound, moves by at most its move */
    m->edge_slack[w] += (w == a ? 1.0 : reach_of(m, w, a)) * moved;
    return queue_edge(m, w, m->edge_floor[w] - m->edge_slack[w], error);
}

/* Collapses s->u onto s->link[iv] (a full collapse moving it by m->delta), target holding its UVs per wedge, and
 * re-costs what changed. */
static sk_status collapse_edge(simplifier *m, star *s, int iv, double (*target)[2], sk_error *error)
{
    const int32_t u = s->u, v = s->link[iv];
    const int full = m->edge_full && m->edge_full[u];
    sk_status status = SK_OK;
    int32_t u_ring[MAX_LINK]; /* u's neighbours, ascending: their one-rings change */
    const int u_nl = s->nl;
    memcpy(u_ring, s->link, (size_t)u_nl * sizeof *u_ring);
    if (m->lk) /* the killed faces' edges u-c and v-c merge: so do their locked sides */
        for (int i = 0; i < s->n; ++i) {
            if (s->ia[i] != iv && s->ib[i] != iv)
                continue;
            const int32_t f = s->t[i];
            const int k = s->k[i], lc = s->ia[i] == iv ? s->ib[i] : s->ia[i];
            const int32_t c = s->link[lc];
            const int side_uc = s->ia[i] == iv ? (k + 2) % 3 : k, side_vc = (k + 1) % 3;
            int32_t g2 = -1, g1 = -1;
            int side_g2 = 0, side_g1 = 0;
            const int j = s->face0[lc] == i ? s->face1[lc] : s->face0[lc];
            if (j >= 0)
                g2 = s->t[j], side_g2 = s->ia[j] == lc ? s->k[j] : (s->k[j] + 2) % 3;
            for (int32_t slot = m->first[v]; slot >= 0 && g1 < 0; slot = m->next[slot]) {
                const int32_t t = slot / 3;
                if (!m->alive[t] || t == f)
                    continue;
                const int32_t *tc = m->tri + 3 * (size_t)t;
                for (int e = 0; e < 3; ++e)
                    if ((tc[e] == v && tc[(e + 1) % 3] == c) || (tc[e] == c && tc[(e + 1) % 3] == v))
                        g1 = t, side_g1 = e;
            }
            unsigned char flag = m->lk[3 * (size_t)f + side_uc] | m->lk[3 * (size_t)f + side_vc];
            if (g2 >= 0)
                flag |= m->lk[3 * (size_t)g2 + side_g2];
            if (g1 >= 0)
                flag |= m->lk[3 * (size_t)g1 + side_g1];
            if (g2 >= 0)
                m->lk[3 * (size_t)g2 + side_g2] = flag;
            if (g1 >= 0)
                m->lk[3 * (size_t)g1 + side_g1] = flag;
        }
    int32_t opposite[2];
    int opposites = 0;
    for (int i = 0; i < s->n; ++i) {
        const int32_t t = s->t[i];
        if (s->ia[i] == iv || s->ib[i] == iv) {
            m->alive[t] = 0;
            --m->triangles;
            opposite[opposites++] = s->ia[i] == iv ? s->b[i] : s->a[i];
            continue;
        }
        m->tri[3 * (size_t)t + s->k[i]] = v;
        if (m->uv) {
            m->uv[6 * (size_t)t + 2 * s->k[i]] = target[s->wedge[i]][0];
            m->uv[6 * (size_t)t + 2 * s->k[i] + 1] = target[s->wedge[i]][1];
        }
    }
    /* u's corners join v's list */
    int32_t *tail = &m->first[v];
    while (*tail >= 0)
        tail = &m->next[*tail];
    *tail = m->first[u];
    m->first[u] = -1;
    m->in_use[u] = 0;
    m->merged[u] = v;
    m->influences -= (size_t)m->count[u];
    ++m->stamp[u], ++m->stamp[m->V + (size_t)u];
    m->edge_target[u] = -1, m->inf_slot[u] = -1, m->stale[u] = 0;
    m->report->epsilon = max_of(m->report->epsilon, m->edge_cost[u]);
    ++m->report->edge_collapses;
    if (full) { /* v moves: every one of its neighbours' one-rings changes, and its own influence costs */
        const size_t begin = (size_t)m->offsets[v];
        for (size_t x = 0; x < 4 * (size_t)m->count[v]; ++x)
            m->coords[4 * begin + x] += m->delta[x];
        ++m->version[v];
        ++m->full_collapses;
    }
    for (int o = 0; o < opposites; ++o) { /* cannot happen on a legal collapse; kept for safety */
        star *t = &m->sv;
        gather_star(m, t, opposite[o], 0);
        if (t->n == 0 && m->in_use[opposite[o]]) {
            m->in_use[opposite[o]] = 0;
            m->influences -= (size_t)m->count[opposite[o]];
        }
    }
    /* Re-costed: v and u's former neighbours, whose one-rings changed. v's other neighbours keep their one-rings
     * (so their costs), and their collapses onto v can only have become illegal (v gained neighbours and faces:
     * the link condition and the duplicate-face rule only tighten), so only those whose candidate is v need a
     * new one: the same candidates as re-costing every neighbour, at about half the work. A full collapse moves v's
     * coordinates as well, and that move alone changes the others' rings: they are re-costed lazily, as after an
     * influence collapse. */
    int32_t ring[MAX_LINK], changed[MAX_LINK + 1];
    int nl = -1, changes = 0;
    if (m->helper && gather_star(m, &m->sv, v, 1)) { /* v heads its neighbours' batch, its ring from this gather */
        nl = m->sv.nl;
        memcpy(ring, m->sv.link, (size_t)nl * sizeof *ring);
        changed[changes++] = v;
    } else
        status = cost_edges(m, v, ring, &nl, error);
    if (status == SK_OK && full)
        status = cost_influences(m, v, error);
    if (nl < 0) /* v's ring is too large to walk: u's former neighbours, at least */
        for (int l = 0; l < u_nl && status == SK_OK; ++l)
            status = u_ring[l] == v ? SK_OK : cost_edges(m, u_ring[l], NULL, NULL, error);
    const double moved = full ? move_length(m, v, m->delta) : 0.0;
    for (int l = 0, k = 0; l < nl && status == SK_OK; ++l) {
        const int32_t w = ring[l];
        while (k < u_nl && u_ring[k] < w)
            ++k;
        if ((k < u_nl && u_ring[k] == w) || m->edge_target[w] == v) /* neither reads the other's entries */
            changed[changes++] = w;
        else if (full)
            status = stale_after_move(m, w, v, moved, error);
    }
    return status == SK_OK ? cost_changed(m, changed, changes, error) : status;
}

/* Applies u's queued edge collapse, its star gathered and its target costed again. */
static sk_status apply_edge(simplifier *m, int32_t u, sk_error *error)
{
    const int32_t v = m->edge_target[u];
    star *s = &m->s;
    const int iv = gather_star(m, s, u, 1) ? link_index(s, v) : -1;
    if (iv < 0) /* as in solve_queued: a live entry's ring is the one it was costed on, so this cannot happen */
        return cost_edges(m, u, NULL, NULL, error);
    double target[MAX_STAR][2];
    double cost = 0.0;
    sk_status status = SK_OK;
    const int full = m->edge_full && m->edge_full[u];
    if (!full || (m->queued_delta && m->delta_stamp[u] == m->stamp[u])) { /* no solve to redo: v's UVs suffice */
        wedge_targets(s, iv, target);
        if (full)
            memcpy(m->delta, m->queued_delta + (size_t)u * m->delta_stride,
                   4 * (size_t)m->count[v] * sizeof *m->delta);
        return collapse_edge(m, s, iv, target, error);
    }
    cost_legal(m, s, iv, &cost, target, full, &status, error);
    if (status == SK_OK && full)
        status = solve_full(m, s, iv, &cost, m->delta, error);
    if (status != SK_OK)
        return status;
    return collapse_edge(m, s, iv, target, error);
}

static sk_status apply_influence(simplifier *m, int32_t a, sk_error *error)
{
    const size_t begin = (size_t)m->offsets[a], n = (size_t)m->count[a], c = (size_t)m->inf_slot[a];
    speculation spec;
    speculate(m, a, &spec);
    sk_status status = sk_influence_remover_apply(m->remover, m->corrected, NULL, m->bones + begin,
                                                  m->coords + 4 * begin, n, c, (size_t)a, error);
    const sk_status taken = end_speculation(m, &spec, error);
    if (status == SK_OK)
        status = taken;
    if (status != SK_OK)
        return status;
    double delta[4 * SK_LOD_MAX_VERTEX_INFLUENCES];
    for (size_t x = 0; x < 4 * n; ++x)
        delta[x] = m->corrected[x] - m->coords[4 * begin + x];
    const double moved = move_length(m, a, delta);
    for (size_t k = 0, t = 0; k < n; ++k) {
        if (k == c)
            continue;
        m->bones[begin + t] = m->bones[begin + k];
        memcpy(m->coords + 4 * (begin + t), m->corrected + 4 * k, 4 * sizeof(double));
        ++t;
    }
    --m->count[a];
    ++m->version[a];
    --m->influences;
    m->report->epsilon = max_of(m->report->epsilon, m->inf_cost[a]);
    ++m->report->influence_collapses;
    status = cost_influences(m, a, error);
    if (status != SK_OK)
        return status;
    /* only a's coordinates moved: a's own edge candidate and its neighbours' are re-costed lazily */
    if (!gather_star(m, &m->s, a, 0)) /* too large to walk: costed now (which counts the refusal) */
        return cost_edges(m, a, NULL, NULL, error);
    const star *s = &m->s;
    status = stale_after_move(m, a, a, moved, error);
    const uint32_t stamp = next_mark(&m->mark_stamp, m->mark, m->V);
    for (int i = 0; i < s->n && status == SK_OK; ++i) /* each neighbour once, in any order: the queue's is by key */
        for (int e = 0; e < 2 && status == SK_OK; ++e) {
            const int32_t w = e ? s->b[i] : s->a[i];
            if (m->mark[w] != stamp) {
                m->mark[w] = stamp;
                status = stale_after_move(m, w, a, moved, error);
            }
        }
    return status;
}

/* ---------------------------------------------------------------------------------------------
 * Checks and the driver
 * ------------------------------------------------------------------------------------------- */

static sk_status validate(const sk_triangle_mesh *mesh, const double *rest, const sk_influences *influences,
                          const double *coordinates, const sk_pose_statistics *statistics, const double *uv,
                          const sk_simplify_options *options, size_t *capacity, sk_error *error)
{
    if (!mesh || !mesh->triangles || !rest || !influences || !influences->offsets || !coordinates || !statistics ||
        !options)
        return sk_fail(error, SK_ERROR_ARGUMENT, "mesh, rest_positions, influences, coordinates, statistics and "
                                                 "options must not be null");
    if (mesh->triangle_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the mesh has no triangles");
    if (mesh->vertex_count != influences->vertex_count)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the mesh has %zu vertices but the influences %zu",
                       mesh->vertex_count, influences->vertex_count);
    if (mesh->vertex_count > INT32_MAX / 2 || mesh->triangle_count > INT32_MAX / 3)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the mesh is too large for int32 indices");
    if (options->metric != SK_LOD_METRIC_ANIMATION && options->metric != SK_LOD_METRIC_REST)
        return sk_fail(error, SK_ERROR_ARGUMENT, "metric %d is neither SK_LOD_METRIC_ANIMATION nor SK_LOD_METRIC_REST",
                       options->metric);
    if (!(options->straightness >= 0.0) || !isfinite(options->straightness))
        return sk_fail(error, SK_ERROR_ARGUMENT, "straightness %g must be finite and >= 0", options->straightness);
    sk_status status = sk_validate_surface(mesh, error);
    if (status == SK_OK)
        status = sk_validate_influences(influences, statistics->bone_count, error);
    if (status != SK_OK)
        return status;
    size_t bad = sk_first_non_finite(rest, 3 * mesh->vertex_count);
    if (bad < 3 * mesh->vertex_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "vertex %zu: its rest position has a NaN or infinity", bad / 3);
    bad = sk_first_non_finite(coordinates, 4 * influences->influence_count);
    if (bad < 4 * influences->influence_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "influence %zu: its coordinates have a NaN or infinity", bad / 4);
    if (uv) {
        bad = sk_first_non_finite(uv, 6 * mesh->triangle_count);
        if (bad < 6 * mesh->triangle_count)
            return sk_fail(error, SK_ERROR_NOT_FINITE, "triangle %zu: its UVs have a NaN or infinity", bad / 6);
    }
    *capacity = 1;
    for (size_t t = 0; t < mesh->triangle_count; ++t) {
        const int32_t *c = mesh->triangles + 3 * t;
        double e0[3], e1[3], e2[3], n[3];
        sub3(e0, rest + 3 * (size_t)c[1], rest + 3 * (size_t)c[0]);
        sub3(e1, rest + 3 * (size_t)c[2], rest + 3 * (size_t)c[0]);
        sub3(e2, rest + 3 * (size_t)c[2], rest + 3 * (size_t)c[1]);
        cross3(n, e0, e1);
        const double longest = max_of(dot3(e0, e0), max_of(dot3(e1, e1), dot3(e2, e2)));
        if (!(sqrt(dot3(n, n)) > 1e-14 * longest))
            return sk_fail(error, SK_ERROR_ARGUMENT, "triangle %zu (%d, %d, %d) is degenerate in the rest pose", t,
                           (int)c[0], (int)c[1], (int)c[2]);
        for (int k = 0; k < 3; ++k) {
            const size_t x = (size_t)c[k];
            const size_t begin = (size_t)influences->offsets[x], n_inf = (size_t)influences->offsets[x + 1] - begin;
            if (n_inf == 0)
                return sk_fail(error, SK_ERROR_ARGUMENT, "vertex %zu (of triangle %zu) has no influences", x, t);
            if (n_inf > SK_LOD_MAX_VERTEX_INFLUENCES)
                return sk_fail(error, SK_ERROR_ARGUMENT, "vertex %zu has %zu influences (at most %d)", x, n_inf,
                               SK_LOD_MAX_VERTEX_INFLUENCES);
            for (size_t i = 1; i < n_inf; ++i)
                for (size_t j = 0; j < i; ++j)
                    if (influences->bones[begin + i] == influences->bones[begin + j])
                        return sk_fail(error, SK_ERROR_ARGUMENT, "vertex %zu lists bone %d twice", x,
                                       (int)influences->bones[begin + i]);
            if (n_inf > *capacity)
                *capacity = n_inf;
        }
    }
    return SK_OK;
}

static void free_simplifier(simplifier *m)
{
    free(m->tri), free(m->alive), free(m->in_use), free(m->uv), free(m->first), free(m->next);
    free(m->bones), free(m->count), free(m->merged), free(m->coords), free(m->edge_target), free(m->inf_slot);
    free(m->edge_cost), free(m->inf_cost), free(m->stamp), free(m->mark), free(m->bone_mark), free(m->bone_index);
    free(m->queue.items), free(m->dense), free(m->q), free((void *)m->wpos), free(m->e), free(m->pivots), free(m->lk);
    free(m->pivoted);
    free(m->featured), free(m->edge_full), free(m->unsolved), free(m->corners), free(m->solve_work);
    free(m->stale), free(m->edge_floor), free(m->edge_reach), free(m->edge_slack), free(m->reach_ids);
    free(m->reach_values), free(m->checked), free(m->queued_delta), free(m->delta_stamp), free(m->version);
    for (size_t x = 0; m->rows && x < m->row_slots; ++x)
        free(m->rows[x].e), free(m->rows[x].link), free(m->rows[x].version);
    free(m->rows);
    free_factor_caches(m);
    sk_influence_remover_free(m->remover);
}

/* Checks the inputs and copies them into m's working arrays (cost_everything costs them). options must outlive m
 * (its targets may change between runs); report receives the refusals met while costing. tuning (may be NULL:
 * half-edge collapses, influence costs as they are). On failure m is freed. */
static sk_status start_simplifier(simplifier *m, const sk_triangle_mesh *mesh, const double *rest_positions,
                                  const sk_influences *influences, const double *coordinates,
                                  const sk_pose_statistics *statistics, const double *uv, const int32_t *charts,
                                  const int32_t *materials, const unsigned char *locked,
                                  const sk_simplify_options *options, const sk_simplify_tuning *tuning,
                                  sk_simplify_report *report, sk_error *error)
{
    memset(m, 0, sizeof *m);
    m->collapse = tuning ? tuning->collapse : SK_LOD_COLLAPSE_HALF;
    m->edge_queue_scale = tuning ? 1.0 / tuning->influence_cost_scale : 1.0;
    m->rank_per_influence = tuning ? tuning->rank_per_influence : 0;
    size_t capacity = 1;
    sk_status status = validate(mesh, rest_positions, influences, coordinates, statistics, uv, options, &capacity,
                                error);
    if (status != SK_OK)
        return status;
    const size_t V = mesh->vertex_count, T = mesh->triangle_count, IC = influences->influence_count;
    m->V = V, m->T = T, m->bone_count = statistics->bone_count;
    m->charts = charts, m->materials = materials, m->rest = rest_positions;
    m->offsets = influences->offsets, m->options = options, m->report = report;
    m->tri = sk_allocate(3 * T, sizeof *m->tri);
    m->alive = sk_allocate(T, 1);
    m->in_use = sk_allocate_zeroed(V, 1);
    m->uv = uv ? sk_allocate(6 * T, sizeof *m->uv) : NULL;
    m->first = sk_allocate(V, sizeof *m->first);
    m->next = sk_allocate(3 * T, sizeof *m->next);
    m->bones = sk_allocate(IC, sizeof *m->bones);
    m->coords = sk_allocate(4 * IC, sizeof *m->coords);
    m->count = sk_allocate(V, sizeof *m->count);
    m->merged = sk_allocate(V, sizeof *m->merged);
    m->edge_target = sk_allocate(V, sizeof *m->edge_target);
    m->inf_slot = sk_allocate(V, sizeof *m->inf_slot);
    m->edge_cost = sk_allocate(V, sizeof *m->edge_cost);
    m->inf_cost = sk_allocate(V, sizeof *m->inf_cost);
    m->stamp = sk_allocate_zeroed(2 * V, sizeof *m->stamp);
    m->mark = sk_allocate_zeroed(V, sizeof *m->mark);
    m->bone_mark = sk_allocate_zeroed(m->bone_count + 1, sizeof *m->bone_mark);
    m->bone_index = sk_allocate(m->bone_count + 1, sizeof *m->bone_index);
    m->q = sk_allocate((size_t)(MAX_LINK + 1) * SK_LOD_MAX_VERTEX_INFLUENCES, sizeof *m->q);
    m->wpos = sk_allocate(2 * (size_t)MAX_STAR * MAX_LINK, sizeof *m->wpos);
    m->s.wpos = m->wpos, m->sv.wpos = m->wpos ? m->wpos + (size_t)MAX_STAR * MAX_LINK : NULL;
    m->lk = locked ? sk_allocate(3 * T, 1) : NULL;
    const int full = m->collapse != SK_LOD_COLLAPSE_HALF;
    m->featured = full ? sk_allocate_zeroed(V, 1) : NULL;
    m->edge_full = full ? sk_allocate_zeroed(V, 1) : NULL;
    m->unsolved = m->collapse == SK_LOD_COLLAPSE_AUTO ? sk_allocate_zeroed(V, 1) : NULL;
    m->stale = sk_allocate_zeroed(V, 1);
    m->version = sk_allocate_zeroed(V, sizeof *m->version);
    m->edge_floor = sk_allocate(V, sizeof *m->edge_floor);
    m->edge_reach = sk_allocate(V, sizeof *m->edge_reach);
    m->edge_slack = sk_allocate(V, sizeof *m->edge_slack);
    m->reach_ids = sk_allocate(V * REACH_LINKS, sizeof *m->reach_ids);
    m->reach_values = sk_allocate(V * REACH_LINKS, sizeof *m->reach_values);
    m->checked = sk_allocate(V * CHECKED_LINKS, 1);
    if (m->collapse == SK_LOD_COLLAPSE_AUTO && options->metric == SK_LOD_METRIC_ANIMATION &&
        V <= DELTA_KEPT_MAX / (4 * capacity)) { /* else (or out of memory) apply_edge solves again */
        m->delta_stride = 4 * capacity;
        m->queued_delta = sk_allocate(V * m->delta_stride, sizeof *m->queued_delta);
        m->delta_stamp = m->queued_delta ? sk_allocate_zeroed(V, sizeof *m->delta_stamp) : NULL; /* live: >= 1 */
        if (!m->delta_stamp)
            free(m->queued_delta), m->queued_delta = NULL;
    }
    if (options->metric == SK_LOD_METRIC_ANIMATION) { /* without them, nothing is cached */
        m->row_slots = V < ROW_SLOTS_MAX ? V : ROW_SLOTS_MAX;
        m->rows = m->row_slots ? calloc(m->row_slots, sizeof *m->rows) : NULL;
        for (size_t x = 0; m->rows && x < m->row_slots; ++x)
            m->rows[x].u = -1;
        m->factors = calloc(FACTOR_SLOTS, sizeof *m->factors);
        m->bases = full ? calloc(BASIS_SLOTS, sizeof *m->bases) : NULL;
    }
    if ((full && (!m->featured || !m->edge_full)) || (m->collapse == SK_LOD_COLLAPSE_AUTO && !m->unsolved) || !m->tri || !m->alive || !m->in_use || (uv && !m->uv) || !m->first || !m->next || !m->bones || !m->coords ||
        !m->count || !m->merged || !m->edge_target || !m->inf_slot || !m->edge_cost || !m->inf_cost || !m->stamp ||
        !m->mark || !m->bone_mark || !m->bone_index || !m->q || !m->wpos || (locked && !m->lk) || !m->stale ||
        !m->edge_floor || !m->edge_reach || !m->edge_slack || !m->reach_ids || !m->reach_values || !m->checked || !m->version) {
        free_simplifier(m);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the simplification of %zu triangles", T);
    }
    status = sk_influence_remover_create(&m->remover, statistics, capacity, error);
    if (status != SK_OK) {
        free_simplifier(m);
        return status;
    }
    memcpy(m->tri, mesh->triangles, 3 * T * sizeof *m->tri);
    if (locked)
        memcpy(m->lk, locked, 3 * T);
    memset(m->alive, 1, T);
    if (uv)
        memcpy(m->uv, uv, 6 * T * sizeof *m->uv);
    memcpy(m->bones, influences->bones, IC * sizeof *m->bones);
    memcpy(m->coords, coordinates, 4 * IC * sizeof *m->coords);
    for (size_t x = 0; x < V; ++x) {
        m->first[x] = -1, m->merged[x] = -1, m->edge_target[x] = -1, m->inf_slot[x] = -1;
        m->count[x] = influences->offsets[x + 1] - influences->offsets[x];
    }
    for (size_t slot = 3 * T; slot-- > 0;) {
        const int32_t x = m->tri[slot];
        m->next[slot] = m->first[x];
        m->first[x] = (int32_t)slot;
        m->in_use[x] = 1;
    }
    m->triangles = T;
    for (size_t x = 0; x < V; ++x)
        if (m->in_use[x])
            m->influences += (size_t)m->count[x];
    for (size_t x = 0; full && x < V; ++x) /* a vertex's candidates need its neighbours' features */
        m->featured[x] = !m->in_use[x] || !gather_star(m, &m->s, (int32_t)x, 1) || star_featured(&m->s);
    return SK_OK;
}

/* Whether the helper thread runs, waiting for it a little: the start's batch is the largest. */
static int helper_running(const costing_helper *h)
{
    const double until = sk_monotonic_seconds() + HELPER_START_WAIT;
    while (!atomic_load_explicit(&h->started, memory_order_acquire))
        if (sk_monotonic_seconds() > until) /* it could not start: sk_parallel_for runs it after us */
            return 0;
    return 1;
}

static sk_status cost_all_influences(simplifier *m, sk_error *error)
{
    sk_status status = SK_OK;
    for (size_t x = 0; x < m->V && status == SK_OK; ++x)
        status = cost_influences(m, (int32_t)x, error);
    return status;
}

/* Costs every candidate once (the start of a run). With the helper, it starts on the edges while this thread costs
 * the influence candidates (they read and write none of the edges' entries), and this thread joins it after. */
static sk_status cost_everything(simplifier *m, sk_error *error)
{
    if (!m->helper || !helper_running(m->helper)) {
        const sk_status status = cost_batch(m, NULL, m->V, START_CHUNK, 0, NULL, error);
        return status == SK_OK ? cost_all_influences(m, error) : status;
    }
    const uint_fast64_t posted = post_batch(m, NULL, m->V, m->V, START_CHUNK, 0, NULL);
    const sk_status influences = cost_all_influences(m, error);
    if (influences == SK_OK) {
        cost_items(m, &m->helper->batch);
        return close_batch(m, posted, error);
    }
    sk_error ignored;
    close_batch(m, posted, &ignored); /* the first failure is the one reported */
    return influences;
}

static int targets_met(const simplifier *m)
{
    const sk_simplify_options *o = m->options;
    return (!o->target_triangles || m->triangles <= o->target_triangles) &&
           (!o->target_influences || m->influences <= o->target_influences);
}

/* How far one run is from its start (t0 triangles, i0 influences) to its targets, in [0, 1]. */
static double progress_fraction(const simplifier *m, size_t t0, size_t i0)
{
    double fraction = 0.0;
    const sk_simplify_options *o = m->options;
    if (o->target_triangles && t0 > o->target_triangles)
        fraction = max_of(fraction, (double)(t0 - m->triangles) / (double)(t0 - o->target_triangles));
    if (o->target_influences && i0 > o->target_influences)
        fraction = max_of(fraction, (double)(i0 - m->influences) / (double)(i0 - o->target_influences));
    return min_of(fraction, 1.0);
}

/* Where a run's progress lands in the caller's [0, 1]: begin + width * the run's own fraction. */
typedef struct progress_span {
    sk_progress_fn fn;
    void *user;
    double begin, width;
} progress_span;

/* Applies collapses, cheapest first, until m->options' targets are met (or none is left: report->exhausted).
 * The queue carries on from where the last run stopped: costs are memoryless, so a run to a lower target
 * continues exactly as one run from the input would. */
static sk_status run_to_targets(simplifier *m, const progress_span *progress, sk_error *error)
{
    const size_t t0 = m->triangles, i0 = m->influences;
    size_t pops = 0;
    sk_status status = SK_OK;
    while (status == SK_OK && !targets_met(m)) {
        entry top;
        int found = 0;
        while (m->queue.size > 0) {
            top = heap_pop(&m->queue);
            if (m->stamp[top.id] == top.stamp) {
                found = 1;
                break;
            }
        }
        if (!found) {
            m->report->exhausted = 1;
            break;
        }
        if ((size_t)top.id < m->V && m->stale[top.id]) { /* a lower bound on top: its cost, queued */
            status = cost_stale(m, top.id, error);
            continue;
        }
        if ((size_t)top.id < m->V && m->unsolved && m->unsolved[top.id]) {
            double target[MAX_STAR][2];
            int next = 0;
            status = solve_queued(m, top.id, target, &next, error);
            if (status != SK_OK || !next)
                continue;
            status = collapse_edge(m, &m->s, link_index(&m->s, m->edge_target[top.id]), target, error);
        } else if ((size_t)top.id < m->V)
            status = apply_edge(m, top.id, error);
        else
            status = apply_influence(m, (int32_t)((size_t)top.id - m->V), error);
        if (status == SK_OK && ++pops % PROGRESS_EVERY == 0 && progress->fn &&
            progress->fn(progress->user, progress->begin + progress->width * progress_fraction(m, t0, i0)))
            status = sk_fail(error, SK_ERROR_CANCELLED, "cancelled at %zu triangles and %zu influences", m->triangles,
                             m->influences);
    }
    return status;
}

/* The current mesh in sk_simplify's output layout, its CSR rows starting at entry `first` of bones_out and
 * coordinates_out (offsets_out[0] = first); report receives its counts. merged chains are shortened on the way
 * (each points at its current survivor). */
static void write_level(simplifier *m, int32_t *triangles_out, int32_t *triangle_origin, double *uv_out,
                        unsigned char *locked_out, int32_t *vertex_map, int32_t *offsets_out, int32_t *bones_out,
                        double *coordinates_out, size_t first, sk_simplify_report *report)
{
    size_t out = 0;
    for (size_t t = 0; t < m->T; ++t) {
        if (!m->alive[t])
            continue;
        memcpy(triangles_out + 3 * out, m->tri + 3 * t, 3 * sizeof *triangles_out);
        triangle_origin[out] = (int32_t)t;
        if (uv_out && m->uv)
            memcpy(uv_out + 6 * out, m->uv + 6 * t, 6 * sizeof *uv_out);
        if (locked_out) {
            if (m->lk)
                memcpy(locked_out + 3 * out, m->lk + 3 * t, 3);
            else
                memset(locked_out + 3 * out, 0, 3);
        }
        ++out;
    }
    size_t total = first, vertices = 0;
    offsets_out[0] = (int32_t)first;
    for (size_t x = 0; x < m->V; ++x) {
        int32_t y = (int32_t)x;
        while (m->merged[y] >= 0)
            y = m->merged[y];
        if (m->merged[x] >= 0)
            m->merged[x] = y;
        vertex_map[x] = y;
        if (m->merged[x] < 0) {
            const size_t begin = (size_t)m->offsets[x], n = (size_t)m->count[x];
            memcpy(bones_out + total, m->bones + begin, n * sizeof *bones_out);
            memcpy(coordinates_out + 4 * total, m->coords + 4 * begin, 4 * n * sizeof *coordinates_out);
            total += n;
            vertices += m->in_use[x];
        }
        offsets_out[x + 1] = (int32_t)total;
    }
    report->triangle_count = out;
    report->vertex_count = vertices;
    report->influence_count = m->influences;
}

sk_status sk_simplify(int32_t *triangles_out, int32_t *triangle_origin, double *uv_out, unsigned char *locked_out,
                      int32_t *vertex_map,
                      int32_t *offsets_out, int32_t *bones_out, double *coordinates_out, sk_simplify_report *report,
                      const sk_triangle_mesh *mesh, const double *rest_positions, const sk_influences *influences,
                      const double *coordinates, const sk_pose_statistics *statistics, const double *uv,
                      const int32_t *charts, const int32_t *materials, const unsigned char *locked,
                      const sk_simplify_options *options, sk_progress_fn progress, void *progress_user,
                      sk_error *error)
{
    if (!triangles_out || !triangle_origin || !vertex_map || !offsets_out || !bones_out || !coordinates_out ||
        !report)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the outputs (but uv_out) and report must not be null");
    if (uv_out && !uv) /* the simplified UVs are copied from the input's: without them there is nothing to copy */
        return sk_fail(error, SK_ERROR_ARGUMENT, "uv_out is given but uv is null: pass both or neither");
    if (options && options->target_triangles == 0 && options->target_influences == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "set target_triangles or target_influences (both are 0)");
    memset(report, 0, sizeof *report);
    simplifier sim;
    sk_status status = start_simplifier(&sim, mesh, rest_positions, influences, coordinates, statistics, uv, charts,
                                        materials, locked, options, NULL, report, error);
    if (status != SK_OK)
        return status;
    const progress_span span = {progress, progress_user, 0.0, 1.0};
    status = cost_everything(&sim, error);
    if (status == SK_OK)
        status = run_to_targets(&sim, &span, error);
    if (status == SK_OK) {
        write_level(&sim, triangles_out, triangle_origin, uv_out, locked_out, vertex_map, offsets_out, bones_out,
                    coordinates_out, 0, report);
        if (progress && progress(progress_user, 1.0))
            status = sk_fail(error, SK_ERROR_CANCELLED, "cancelled at the end");
        else
            status = sk_succeed(error);
    }
    free_simplifier(&sim);
    return status;
}

/* level_count >= 1 and no negative target. */
static sk_status chain_targets_valid(const sk_simplify_chain_options *options, sk_error *error)
{
    if (!options)
        return sk_fail(error, SK_ERROR_ARGUMENT, "options must not be null");
    if (options->level_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "level_count must be at least 1");
    for (size_t l = 0; l < options->level_count; ++l) {
        if (options->target_triangles && options->target_triangles[l] < 0)
            return sk_fail(error, SK_ERROR_ARGUMENT, "level %zu: target_triangles %d is negative", l,
                           (int)options->target_triangles[l]);
        if (options->target_influences && options->target_influences[l] < 0)
            return sk_fail(error, SK_ERROR_ARGUMENT, "level %zu: target_influences %d is negative", l,
                           (int)options->target_influences[l]);
    }
    return SK_OK;
}

/* sk_simplify_chain_tuned's body; tuning NULL: sk_simplify_chain's; level_full_collapses may be NULL. */
/* What a chain writes: sk_simplify_chain's outputs. */
typedef struct chain_outputs {
    int32_t *triangles_out, *triangle_origin;
    double *uv_out;
    unsigned char *locked_out;
    int32_t *vertex_map, *offsets_out, *bones_out;
    double *coordinates_out;
    int32_t *level_counts;
    double *level_epsilon;
    sk_simplify_chain_report *report;
    int32_t *level_full_collapses;
} chain_outputs;

/* Costs every candidate, then runs to each level's targets and writes it. */
static sk_status run_levels(simplifier *sim, sk_simplify_options *level, sk_simplify_report *running,
                            const chain_outputs *o, const sk_simplify_chain_options *options, sk_progress_fn progress,
                            void *progress_user, sk_error *error)
{
    const size_t V = sim->V, T = sim->T, L = options->level_count;
    sk_status status = cost_everything(sim, error);
    o->offsets_out[0] = 0;
    for (size_t l = 0; l < L && status == SK_OK; ++l) {
        level->target_triangles = options->target_triangles ? (size_t)options->target_triangles[l] : 0;
        level->target_influences = options->target_influences ? (size_t)options->target_influences[l] : 0;
        if (level->target_triangles == 0 && level->target_influences == 0) {
            if (sim->influences < 2) /* section 7.3's halving has nothing left to halve */
                break;
            level->target_influences = sim->influences / 2;
        }
        const size_t edges_before = running->edge_collapses, influences_before = running->influence_collapses;
        const size_t full_before = sim->full_collapses;
        const progress_span span = {progress, progress_user, (double)l / (double)L, 1.0 / (double)L};
        status = run_to_targets(sim, &span, error);
        if (status != SK_OK)
            break;
        sk_simplify_report counts;
        write_level(sim, o->triangles_out + 3 * T * l, o->triangle_origin + T * l,
                    o->uv_out ? o->uv_out + 6 * T * l : NULL, o->locked_out ? o->locked_out + 3 * T * l : NULL,
                    o->vertex_map + V * l, o->offsets_out + V * l, o->bones_out, o->coordinates_out,
                    (size_t)o->offsets_out[V * l], &counts);
        int32_t *row = o->level_counts + 5 * l;
        row[0] = (int32_t)counts.triangle_count, row[1] = (int32_t)counts.vertex_count;
        row[2] = (int32_t)counts.influence_count;
        row[3] = (int32_t)(running->edge_collapses - edges_before);
        row[4] = (int32_t)(running->influence_collapses - influences_before);
        o->level_epsilon[l] = running->epsilon;
        if (o->level_full_collapses)
            o->level_full_collapses[l] = (int32_t)(sim->full_collapses - full_before);
        o->report->level_count = l + 1;
        if (running->exhausted) {
            o->report->exhausted = 1;
            break;
        }
    }
    return status;
}

/* run_levels on the caller's thread (item 0) beside the helper's loop (item 1), on two threads when there are. */
typedef struct chain_region {
    simplifier *sim;
    sk_simplify_options *level;
    sk_simplify_report *running;
    const chain_outputs *outputs;
    const sk_simplify_chain_options *options;
    sk_progress_fn progress;
    void *progress_user;
    sk_error *error;
    sk_status status;
} chain_region;

static void chain_region_body(void *context, size_t worker, size_t begin, size_t end)
{
    (void)worker;
    chain_region *c = context;
    for (size_t item = begin; item < end; ++item)
        if (item == 0) {
            c->status = run_levels(c->sim, c->level, c->running, c->outputs, c->options, c->progress,
                                   c->progress_user, c->error);
            atomic_store_explicit(&c->sim->helper->finished, 1, memory_order_release);
        } else
            helper_loop(c->sim->helper); /* returns at once when run_levels is done (no second thread) */
}

static sk_status run_chain(const chain_outputs *o, const sk_triangle_mesh *mesh, const double *rest_positions,
                           const sk_influences *influences, const double *coordinates,
                           const sk_pose_statistics *statistics, const double *uv, const int32_t *charts,
                           const int32_t *materials, const unsigned char *locked,
                           const sk_simplify_chain_options *options, const sk_simplify_tuning *tuning,
                           sk_progress_fn progress, void *progress_user, sk_error *error)
{
    if (!o->triangles_out || !o->triangle_origin || !o->vertex_map || !o->offsets_out || !o->bones_out ||
        !o->coordinates_out || !o->level_counts || !o->level_epsilon || !o->report)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the outputs (but uv_out and locked_out) and report must not be null");
    if (o->uv_out && !uv)
        return sk_fail(error, SK_ERROR_ARGUMENT, "uv_out is given but uv is null: pass both or neither");
    sk_status status = chain_targets_valid(options, error);
    if (status != SK_OK)
        return status;
    memset(o->report, 0, sizeof *o->report);
    sk_simplify_options level = {0, 0, options->metric, options->simplify_influences, options->straightness};
    sk_simplify_report running;
    memset(&running, 0, sizeof running);
    simplifier sim;
    status = start_simplifier(&sim, mesh, rest_positions, influences, coordinates, statistics, uv, charts, materials,
                              locked, &level, tuning, &running, error);
    if (status != SK_OK)
        return status;
    if (influences->influence_count > (size_t)INT32_MAX / options->level_count) {
        free_simplifier(&sim);
        return sk_fail(error, SK_ERROR_ARGUMENT, "%zu levels of %zu influences overflow int32 offsets",
                       options->level_count, influences->influence_count);
    }
    const int threads = tuning ? tuning->thread_count : 1;
    costing_helper *helper = NULL;
    const int pays = threads >= 2 || influences->influence_count >= HELPER_MIN_INFLUENCES;
    if (pays && sk_worker_count(2, 1, threads) == 2) { /* out of memory: one thread */
        helper = calloc(1, sizeof *helper);
        if (helper && !make_worker(helper, &sim))
            free(helper), helper = NULL;
    }
    if (helper) {
        atomic_init(&helper->ticket, 0), atomic_init(&helper->started, 0), atomic_init(&helper->finished, 0);
        atomic_init(&helper->batch.next, 0), atomic_init(&helper->batch.failed, 0);
        sim.helper = helper;
        chain_region region = {&sim, &level, &running, o, options, progress, progress_user, error, SK_OK};
        sk_parallel_for(2, 1, threads, chain_region_body, &region);
        status = region.status;
        sim.helper = NULL;
        free_worker(&helper->worker);
        free(helper);
    } else
        status = run_levels(&sim, &level, &running, o, options, progress, progress_user, error);
    if (status == SK_OK) {
        sk_simplify_chain_report *report = o->report;
        report->edge_collapses = running.edge_collapses, report->influence_collapses = running.influence_collapses;
        report->refused_flip = running.refused_flip, report->refused_chart = running.refused_chart;
        report->refused_seam = running.refused_seam, report->refused_link = running.refused_link;
        report->refused_locked = running.refused_locked;
        if (progress && progress(progress_user, 1.0))
            status = sk_fail(error, SK_ERROR_CANCELLED, "cancelled at the end");
        else
            status = sk_succeed(error);
    }
    free_simplifier(&sim);
    return status;
}

sk_status sk_simplify_chain(int32_t *triangles_out, int32_t *triangle_origin, double *uv_out,
                            unsigned char *locked_out, int32_t *vertex_map, int32_t *offsets_out, int32_t *bones_out,
                            double *coordinates_out, int32_t *level_counts, double *level_epsilon,
                            sk_simplify_chain_report *report, const sk_triangle_mesh *mesh,
                            const double *rest_positions, const sk_influences *influences, const double *coordinates,
                            const sk_pose_statistics *statistics, const double *uv, const int32_t *charts,
                            const int32_t *materials, const unsigned char *locked,
                            const sk_simplify_chain_options *options, sk_progress_fn progress, void *progress_user,
                            sk_error *error)
{
    const chain_outputs outputs = {triangles_out, triangle_origin, uv_out, locked_out, vertex_map, offsets_out,
                                   bones_out, coordinates_out, level_counts, level_epsilon, report, NULL};
    return run_chain(&outputs, mesh, rest_positions, influences, coordinates, statistics, uv, charts, materials, locked,
                     options, NULL, progress, progress_user, error);
}

sk_status sk_simplify_chain_tuned(int32_t *triangles_out, int32_t *triangle_origin, double *uv_out,
                                  unsigned char *locked_out, int32_t *vertex_map, int32_t *offsets_out,
                                  int32_t *bones_out, double *coordinates_out, int32_t *level_counts,
                                  double *level_epsilon, sk_simplify_chain_report *report,
                                  int32_t *level_full_collapses, const sk_triangle_mesh *mesh,
                                  const double *rest_positions, const sk_influences *influences,
                                  const double *coordinates, const sk_pose_statistics *statistics, const double *uv,
                                  const int32_t *charts, const int32_t *materials, const unsigned char *locked,
                                  const sk_simplify_chain_options *options, const sk_simplify_tuning *tuning,
                                  sk_progress_fn progress, void *progress_user, sk_error *error)
{
    if (!tuning || !level_full_collapses)
        return sk_fail(error, SK_ERROR_ARGUMENT, "tuning and level_full_collapses must not be null");
    if (tuning->collapse != SK_LOD_COLLAPSE_HALF && tuning->collapse != SK_LOD_COLLAPSE_FULL &&
        tuning->collapse != SK_LOD_COLLAPSE_AUTO)
        return sk_fail(error, SK_ERROR_ARGUMENT, "collapse %d is not SK_LOD_COLLAPSE_HALF, _FULL or _AUTO",
                       tuning->collapse);
    if (tuning->rank_per_influence != 0 && tuning->rank_per_influence != 1)
        return sk_fail(error, SK_ERROR_ARGUMENT, "rank_per_influence %d is neither 0 nor 1", tuning->rank_per_influence);
    if (!(tuning->influence_cost_scale > 0.0) || !isfinite(tuning->influence_cost_scale))
        return sk_fail(error, SK_ERROR_ARGUMENT, "influence_cost_scale %g must be finite and > 0",
                       tuning->influence_cost_scale);
    if (tuning->thread_count < 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "thread_count %d must be >= 0", tuning->thread_count);
    const chain_outputs outputs = {triangles_out, triangle_origin, uv_out, locked_out, vertex_map, offsets_out,
                                   bones_out, coordinates_out, level_counts, level_epsilon, report,
                                   level_full_collapses};
    return run_chain(&outputs, mesh, rest_positions, influences, coordinates, statistics, uv, charts, materials, locked,
                     options, tuning, progress, progress_user, error);
}
