/*
 * Influence simplification (Merry 2007, section 6.3, eq. 6.1 and appendix A.2) and Limit Influences
 * (section 6.4). SPDX-License-Identifier: GPL-3.0-or-later
 *
 * Removing the influence at position c of an influence set I (n bones, sorted) from coordinates q:
 * the correction s (4n) has s_c = -q_c, the free part y = s on the m = n - 1 kept bones, and one
 * constraint left, e^T y = w_c (e picks the kept bones' weights, w_c = q_c's weight), so that the
 * weights of s sum to 0. Parametrise y = Y0 q_c + N z with the minimum-norm particular solution
 * Y0 q_c = (w_c / m) e and N (4m x (4m - 1)) an orthonormal basis of e's complement: the kept bones'
 * x, y, z axes and a Helmert basis of their weights orthogonal to (1, ..., 1). Then y0 is orthogonal
 * to N z, so ||s||^2 = |q_c|^2 + ||y0||^2 + ||z||^2 and the least Euclidean correction is the
 * minimum-norm z.
 *
 * The objective is not formed as a quadratic (normal equations square the condition number, and a
 * near-zero cost would come out as the square root of a rounding error, ~1e-8): P_I = F^T F with F from
 * a pivoted Cholesky factorisation of P_I (dpstrf), and s^T P_I s = ||F s||^2 = ||G z + H q_c||^2 with
 * G = F [N; 0] and H = F [Y0; -I]. The minimum-norm least-squares z = -G^+ H q_c comes from a complete
 * orthogonal factorisation of G (dgelsy: QR with column pivoting, then RZ), so the correction and the
 * cost are linear in q_c:
 *   y = L q_c with L = Y0 - N G^+ H (4m x 4),   cost = ||W q_c|| with W = H - G G^+ H (the residual map).
 * (L, W) depend only on (I, c): they are what the per-thread cache of the last 128 preprocessings keeps
 * (first in, first out). A preprocessing is a deterministic function of (I, c), so the cache only saves
 * work: results are the same bits whatever the thread count or the order of the vertices.
 *
 * Thresholds (relative, so independent of the model's scale):
 *   - P_I's factorisation stops once every remaining pivot is at or below PIVOT_THRESHOLD = 1e-12 times
 *     P_I's largest diagonal entry; the dropped remainder is PSD with norm at most its trace, 4n * 1e-12
 *     of that entry. P_I is exactly singular for fixed joint translations (appendix B.3) and wherever two
 *     bones move together; rounding (the products along the skeleton, the sample averages, the
 *     factorisation) leaves those pivots at about (depth + 4n) eps, ~1e-14 relative for a 20-deep
 *     skeleton and 16 influences, so 1e-12 keeps a margin of 100. What is dropped moves the skinned
 *     vertex, in RMS over the poses, by at most ~1e-6 of the stiffest direction's motion per unit
 *     coefficient.
 *   - the reduced system's rank: dgelsy's RCOND = SINGULAR_THRESHOLD = 1e-6, the largest leading block of
 *     the pivoted QR of G whose estimated condition stays below 1e6; in eigenvalue terms the same 1e-12
 *     relative threshold on the reduced PSD system G^T G = N^T P_I N (restricted to the constraint).
 *     Directions below it are ties: they get no component, which is the least-Euclidean tie-break.
 */
#include <lapacke.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "sk_internal.h"
#include "sk_lod_internal.h"

#define PIVOT_THRESHOLD 1e-12
#define SINGULAR_THRESHOLD 1e-6
/* The thesis keeps the last 128 (influence set, bone) preprocessings. */
#define CACHE_ENTRIES 128
/* The simplifier's remover keeps more, as many as REMOVER_CACHE_BYTES hold (at least CACHE_ENTRIES): its chain
 * removes the same bone from the same set again and again (the horse's: 4,096 entries, 8.3 MiB, make 2,492
 * preprocessings where 128 made 6,822). */
#define REMOVER_CACHE_ENTRIES 4096
#define REMOVER_CACHE_BYTES (16u << 20)
/* Up to this many bones, every block of P is formed once (bone_count^2 * 128 bytes: 8 MiB at 256);
 * above it, each vertex forms its own blocks with sk_expectation_block, so a large rig costs no memory. */
#define BLOCK_TABLE_MAX_BONES 256
/* Vertices per batch between progress reports. */
#define BATCH_VERTICES 2048

/* ---------------------------------------------------------------------------------------------
 * P blocks
 * ------------------------------------------------------------------------------------------- */

typedef struct block_source {
    const sk_pose_statistics *statistics; /* NULL when the caller gave the blocks */
    size_t bone_count;
    const double *table; /* bone_count^2 blocks, or NULL: formed on demand from the statistics */
    double *owned;       /* the table when formed here (freed with the source) */
} block_source;

/* The statistics were validated, so sk_expectation_block cannot fail here. */
static void get_block(double block[16], const block_source *source, int32_t j, int32_t k)
{
    const sk_pose_statistics *st = source->statistics;
    if (source->table) {
        memcpy(block, source->table + 16 * ((size_t)j * source->bone_count + (size_t)k), 16 * sizeof *block);
        return;
    }
    if (sk_expectation_block(block, st->expected_local, st->expected_gram, st->parents, st->bone_count, (size_t)j,
                             (size_t)k, NULL) != SK_OK)
        for (int e = 0; e < 16; ++e)
            block[e] = NAN; /* unreachable; refused as a non-finite P_I below */
}

static sk_status validate_statistics(const sk_pose_statistics *statistics, sk_error *error)
{
    if (!statistics || !statistics->expected_local || !statistics->expected_gram)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the pose statistics must not be null");
    if (statistics->bone_count > INT32_MAX)
        return sk_fail(error, SK_ERROR_ARGUMENT, "bone_count %zu exceeds the int32 bone indices",
                       statistics->bone_count);
    const sk_status status = sk_validate_skeleton(statistics->parents, NULL, statistics->bone_count, error);
    if (status != SK_OK)
        return status;
    for (size_t bone = 0; bone < statistics->bone_count; ++bone)
        if (!sk_all_finite(statistics->expected_local + 16 * bone, 16) ||
            !sk_all_finite(statistics->expected_gram + 16 * bone, 16))
            return sk_fail(error, SK_ERROR_NOT_FINITE, "bone %zu: its pose statistics have a NaN or infinity", bone);
    return SK_OK;
}

static sk_status make_block_source(block_source *source, const sk_pose_statistics *statistics, sk_error *error)
{
    const size_t b = statistics->bone_count;
    *source = (block_source){statistics, b, NULL, NULL};
    if (b > BLOCK_TABLE_MAX_BONES)
        return SK_OK;
    source->owned = malloc(b * b * 16 * sizeof(double));
    if (!source->owned)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the P blocks of %zu bones", b);
    source->table = source->owned;
    return sk_expectation_blocks(source->owned, statistics->expected_local, statistics->expected_gram,
                                 statistics->parents, b, error);
}

/* ---------------------------------------------------------------------------------------------
 * Per-thread workspace and cache
 * ------------------------------------------------------------------------------------------- */

typedef struct cache_entry {
    uint64_t hash;
    size_t count;  /* n, the influence set's size; 0 for an empty slot */
    int32_t removed; /* the bone removed */
    int32_t *bones;  /* n, sorted */
    double *l;       /* 4(n - 1) x 4 */
    double *w;       /* rows x 4 */
    size_t rows;
} cache_entry;

/* A hash index over a cache's slots: per bucket the first slot whose key hashes there, per slot the next one (-1:
 * none). A lookup walks one bucket's few slots: scanning all of them cost the horse's chain 1.5% of its instructions
 * (4,096 preprocessings, 512 splits). */
typedef struct slot_index {
    int32_t *head;  /* buckets: a power of two, at least the slots */
    int32_t *chain; /* slots */
    size_t mask;
} slot_index;

/* 0 when memory runs out (the index is then empty and may be freed). */
static int index_init(slot_index *index, size_t slots)
{
    size_t buckets = 1;
    while (buckets < slots) /* slots <= REMOVER_CACHE_ENTRIES: no overflow */
        buckets *= 2;
    index->mask = buckets - 1;
    index->head = malloc(buckets * sizeof *index->head);
    index->chain = malloc(slots * sizeof *index->chain);
    if (!index->head || !index->chain)
        return 0;
    memset(index->head, 0xff, buckets * sizeof *index->head); /* every int32 -1 */
    memset(index->chain, 0xff, slots * sizeof *index->chain);
    return 1;
}

/* Frees and empties the index (safe to call again, as a failed init's clean-up and a later free may both do). */
static void index_free(slot_index *index)
{
    free(index->head), free(index->chain);
    index->head = index->chain = NULL;
}

static int32_t *index_bucket(const slot_index *index, uint64_t hash)
{
    return &index->head[(size_t)(hash ^ (hash >> 32)) & index->mask];
}

static void index_insert(slot_index *index, size_t slot, uint64_t hash)
{
    int32_t *bucket = index_bucket(index, hash);
    index->chain[slot] = *bucket;
    *bucket = (int32_t)slot;
}

/* Unlinks slot, filed under hash. */
static void index_remove(slot_index *index, size_t slot, uint64_t hash)
{
    int32_t *link = index_bucket(index, hash);
    while (*link >= 0 && (size_t)*link != slot)
        link = &index->chain[*link];
    if (*link >= 0)
        *link = index->chain[slot];
}

typedef struct workspace {
    size_t capacity; /* influences per set */
    size_t f_rows;   /* rows of f in use */
    double *p, *z, *f, *f0, *g, *h, *u, *x, *best_l, *difference;
    lapack_int *isuppz;
    cache_entry *entries;
    slot_index index; /* of entries, by their hash */
    size_t entry_count;
    size_t next; /* the slot the next preprocessing replaces (first in, first out) */
    /* the vertex being simplified */
    int32_t *set, *original_index;
    double *q, *q0, *tq; /* tq: tangent_count x 4 capacity */
    void *block;         /* every array above lives in this one allocation */
} workspace;

static void free_workspace(workspace *ws)
{
    if (ws)
        free(ws->block), free(ws->entries), index_free(&ws->index);
}

static sk_status init_workspace(workspace *ws, size_t capacity, size_t tangent_count, size_t entry_count,
                                sk_error *error)
{
    memset(ws, 0, sizeof *ws);
    ws->capacity = capacity;
    const size_t d = 4 * capacity;
    /* d <= 4 * SK_LOD_MAX_VERTEX_INFLUENCES, so only the tangent term can overflow. */
    size_t tangent_doubles;
    if (!sk_mul_size(tangent_count, d, &tangent_doubles))
        return sk_fail(error, SK_ERROR_ARGUMENT, "tangent_count %zu is too large", tangent_count);
    const size_t doubles_fixed = 6 * d * d + 1 * d + 3 * 4 * d + 2 * d + entry_count * (d * 4 + d * 4);
    if (tangent_doubles > SIZE_MAX / sizeof(double) / 2 - doubles_fixed)
        return sk_fail(error, SK_ERROR_ARGUMENT, "tangent_count %zu is too large", tangent_count);
    const size_t doubles = doubles_fixed + tangent_doubles;
    const size_t ints = 2 * capacity + entry_count * capacity;
    const size_t lapack_ints = 2 * d;
    const size_t bytes = doubles * sizeof(double) + lapack_ints * sizeof(lapack_int) + ints * sizeof(int32_t);
    char *block = malloc(bytes);
    ws->entries = calloc(entry_count, sizeof *ws->entries);
    if (!block || !ws->entries || !index_init(&ws->index, entry_count)) {
        free(block), free(ws->entries), ws->entries = NULL, index_free(&ws->index);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the workspace of %zu influences", capacity);
    }
    ws->entry_count = entry_count;
    ws->block = block;
    double *next = (double *)block;
#define TAKE(name, size) (ws->name = next, next += (size))
    TAKE(p, d * d);
    TAKE(z, d * d);
    TAKE(f, d * d);
    TAKE(f0, d * d);
    TAKE(g, d * d);
    TAKE(u, d * d);
    TAKE(difference, d);
    TAKE(h, 4 * d);
    TAKE(x, 4 * d);
    TAKE(best_l, 4 * d);
    TAKE(q, d);
    TAKE(q0, d);
    TAKE(tq, tangent_doubles);
#undef TAKE
    for (size_t e = 0; e < entry_count; ++e) {
        ws->entries[e].l = next;
        next += 4 * d;
        ws->entries[e].w = next;
        next += 4 * d;
    }
    lapack_int *isuppz = (lapack_int *)(void *)((double *)block + doubles);
    ws->isuppz = isuppz;
    int32_t *ints_next = (int32_t *)(void *)(isuppz + lapack_ints);
    ws->set = ints_next;
    ws->original_index = ints_next + capacity;
    for (size_t e = 0; e < entry_count; ++e)
        ws->entries[e].bones = ints_next + 2 * capacity + e * capacity;
    return SK_OK;
}

static uint64_t key_hash(const int32_t *set, size_t n, int32_t removed)
{
    uint64_t hash = 1469598103934665603ULL ^ (uint64_t)(uint32_t)removed;
    for (size_t k = 0; k < n; ++k) {
        hash ^= (uint64_t)(uint32_t)set[k];
        hash *= 1099511628211ULL;
    }
    return hash ^ (uint64_t)n * 0x9E3779B97F4A7C15ULL;
}

static cache_entry *cache_lookup(workspace *ws, const int32_t *set, size_t n, int32_t removed, uint64_t hash)
{
    for (int32_t e = *index_bucket(&ws->index, hash); e >= 0; e = ws->index.chain[e]) {
        cache_entry *entry = &ws->entries[e];
        if (entry->hash == hash && entry->count == n && entry->removed == removed &&
            memcmp(entry->bones, set, n * sizeof *set) == 0)
            return entry;
    }
    return NULL;
}

/* ---------------------------------------------------------------------------------------------
 * The solver
 * ------------------------------------------------------------------------------------------- */

/* F (ws->f_rows x 4n, row-major) with F^T F = P_I up to a remainder dropped below PIVOT_THRESHOLD. */
static sk_status factor_set(workspace *ws, const block_source *source, const int32_t *set, size_t n,
                            size_t vertex, sk_error *error)
{
    const size_t d = 4 * n;
    double *p = ws->p;
    for (size_t a = 0; a < n; ++a)
        for (size_t b = a; b < n; ++b) {
            double block[16];
            get_block(block, source, set[a], set[b]);
            for (int r = 0; r < 4; ++r)
                for (int c = 0; c < 4; ++c) {
                    p[(4 * a + (size_t)r) * d + 4 * b + (size_t)c] = block[4 * r + c];
                    p[(4 * b + (size_t)c) * d + 4 * a + (size_t)r] = block[4 * r + c];
                }
        }
    if (!sk_all_finite(p, d * d))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "vertex %zu: a block of P over its bones is not finite", vertex);
    size_t rows = 0;
    const sk_status status = sk_factor_semidefinite(p, d, ws->isuppz, PIVOT_THRESHOLD, &rows, "P over the bones of vertex",
                                                    vertex, error);
    if (status != SK_OK)
        return status;
    for (size_t i = 0; i < rows; ++i) /* F = U Pi^T: row i holds U(i, j) at column piv(j) */
        for (size_t j = 0; j < d; ++j)
            ws->f[i * d + (size_t)ws->isuppz[j] - 1] = j >= i ? p[j * d + i] : 0.0;
    ws->f_rows = rows;
    return SK_OK;
}

sk_status sk_factor_semidefinite(double *p, size_t d, lapack_int *pivots, double relative_threshold, size_t *rank,
                                 const char *what, size_t element, sk_error *error)
{
    double largest = 0.0;
    for (size_t k = 0; k < d; ++k)
        largest = fmax(largest, p[k * d + k]);
    lapack_int factored = 0;
    if (largest > 0.0) {
        const lapack_int info = LAPACKE_dpstrf(LAPACK_COL_MAJOR, 'U', (lapack_int)d, p, (lapack_int)d, pivots,
                                               &factored, relative_threshold * largest);
        if (info < 0)
            return sk_fail(error, SK_ERROR_LAPACK, "%s %zu: dpstrf failed (info %d)", what, element, (int)info);
    }
    *rank = (size_t)factored;
    return SK_OK;
}

/* Helmert basis of the weights orthogonal to (1, ..., 1): vector h (1 <= h < m), component t. */
static double helmert(size_t h, size_t t)
{
    if (t > h)
        return 0.0;
    const double scale = 1.0 / sqrt((double)h * (double)(h + 1));
    return t < h ? scale : -(double)h * scale;
}

/* Fills entry (L, W) for removing position c of the set whose factor ws->f holds. */
static sk_status prepare_removal(workspace *ws, cache_entry *entry, size_t n, size_t c, size_t vertex, sk_error *error)
{
    const size_t d = 4 * n, m = n - 1, cols = 4 * m - 1, r = ws->f_rows, ldb = r > cols ? r : cols;
    const double *f = ws->f;
    double *g = ws->g, *h = ws->h, *g_copy = ws->u, *b = ws->z; /* column-major: g (r x cols), h and b (x 4) */
    for (size_t row = 0; row < r; ++row) {
        const double *fr = f + row * d;
        double weight_mean = 0.0;
        for (size_t t = 0; t < m; ++t) {
            const size_t pos = t + (t >= c);
            for (size_t a = 0; a < 3; ++a)
                g[(3 * t + a) * r + row] = fr[4 * pos + a];
            weight_mean += fr[4 * pos + 3];
        }
        double prefix = fr[4 * (c == 0) + 3]; /* the weights of kept bones 0 .. hv - 1 */
        for (size_t hv = 1; hv < m; ++hv) {
            const double weight = fr[4 * (hv + (hv >= c)) + 3];
            g[(3 * m + hv - 1) * r + row] = (prefix - (double)hv * weight) / sqrt((double)hv * (double)(hv + 1));
            prefix += weight;
        }
        for (size_t a = 0; a < 3; ++a)
            h[a * r + row] = -fr[4 * c + a];
        h[3 * r + row] = -fr[4 * c + 3] + weight_mean / (double)m;
    }
    /* X = G^+ H, the minimum-norm least-squares solution by a complete orthogonal factorisation (dgelsy:
     * QR with column pivoting, rank where R11's estimated condition reaches 1 / SINGULAR_THRESHOLD). */
    double *x = ws->x;
    memset(x, 0, cols * 4 * sizeof *x);
    memcpy(g_copy, g, r * cols * sizeof *g);
    if (r > 0) {
        memset(b, 0, 4 * ldb * sizeof *b);
        for (size_t a = 0; a < 4; ++a)
            memcpy(b + a * ldb, h + a * r, r * sizeof *b);
        lapack_int rank = 0;
        memset(ws->isuppz, 0, cols * sizeof *ws->isuppz); /* jpvt: every column free */
        const lapack_int info = LAPACKE_dgelsy(LAPACK_COL_MAJOR, (lapack_int)r, (lapack_int)cols, 4, g, (lapack_int)r,
                                               b, (lapack_int)ldb, ws->isuppz, SINGULAR_THRESHOLD, &rank);
        if (info != 0)
            return sk_fail(error, SK_ERROR_LAPACK, "vertex %zu: dgelsy of the reduced system failed (info %d)",
                           vertex, (int)info);
        for (size_t col = 0; col < cols; ++col)
            for (size_t a = 0; a < 4; ++a)
                x[4 * col + a] = b[a * ldb + col];
    }
    /* W = H - G X, the residual map (row-major, r x 4): the cost is |W q_c|. */
    for (size_t row = 0; row < r; ++row)
        for (size_t a = 0; a < 4; ++a) {
            double sum = h[a * r + row];
            for (size_t col = 0; col < cols; ++col)
                sum -= g_copy[col * r + row] * x[4 * col + a];
            entry->w[4 * row + a] = sum;
        }
    entry->rows = r;
    /* L = Y0 - N X */
    double *lm = entry->l;
    for (size_t t = 0; t < m; ++t) {
        for (size_t a = 0; a < 3; ++a)
            for (int k = 0; k < 4; ++k)
                lm[4 * (4 * t + a) + (size_t)k] = -x[4 * (3 * t + a) + (size_t)k];
        for (int k = 0; k < 4; ++k) {
            double sum = k == 3 ? 1.0 / (double)m : 0.0;
            for (size_t hv = t > 0 ? t : 1; hv < m; ++hv)
                sum -= helmert(hv, t) * x[4 * (3 * m + hv - 1) + (size_t)k];
            lm[4 * (4 * t + 3) + (size_t)k] = sum;
        }
    }
    return SK_OK;
}

static double apply_norm(const double *w, size_t rows, const double *v)
{
    double sum = 0.0;
    for (size_t row = 0; row < rows; ++row) {
        const double value = w[4 * row] * v[0] + w[4 * row + 1] * v[1] + w[4 * row + 2] * v[2] + w[4 * row + 3] * v[3];
        sum += value * value;
    }
    return sqrt(sum);
}

/* The cached (or freshly prepared) entry for removing position c of the set (its factor formed on demand). */
static sk_status removal_entry(cache_entry **result, workspace *ws, const block_source *source, const int32_t *set,
                               size_t n, size_t c, int *factored, size_t vertex, sk_error *error)
{
    const uint64_t hash = key_hash(set, n, set[c]);
    cache_entry *entry = cache_lookup(ws, set, n, set[c], hash);
    if (!entry) {
        sk_status status = SK_OK;
        if (!*factored) {
            status = factor_set(ws, source, set, n, vertex, error);
            *factored = status == SK_OK;
        }
        const size_t slot = ws->next;
        entry = &ws->entries[slot];
        ws->next = (ws->next + 1) % ws->entry_count;
        if (entry->count)
            index_remove(&ws->index, slot, entry->hash);
        entry->count = 0; /* invalid until prepared */
        if (status == SK_OK)
            status = prepare_removal(ws, entry, n, c, vertex, error);
        if (status != SK_OK)
            return status;
        entry->hash = hash;
        entry->count = n;
        entry->removed = set[c];
        memcpy(entry->bones, set, n * sizeof *set);
        index_insert(&ws->index, slot, hash);
    }
    *result = entry;
    return SK_OK;
}

/* v_kept += L p for the 4-vectors of the set but position c; then drops position c. */
static void apply_removal(double *v, const double *l, size_t n, size_t c)
{
    const double p[4] = {v[4 * c], v[4 * c + 1], v[4 * c + 2], v[4 * c + 3]};
    memmove(v + 4 * c, v + 4 * c + 4, 4 * (n - 1 - c) * sizeof *v);
    for (size_t row = 0; row < 4 * (n - 1); ++row)
        v[row] += l[4 * row] * p[0] + l[4 * row + 1] * p[1] + l[4 * row + 2] * p[2] + l[4 * row + 3] * p[3];
}

/* Sorts the vertex's influences by bone (insertion sort: n <= 64) into ws->set / original_index. */
static void load_sorted(workspace *ws, const int32_t *bones, size_t n)
{
    for (size_t k = 0; k < n; ++k) {
        size_t at = k;
        while (at > 0 && ws->set[at - 1] > bones[k]) {
            ws->set[at] = ws->set[at - 1];
            ws->original_index[at] = ws->original_index[at - 1];
            --at;
        }
        ws->set[at] = bones[k];
        ws->original_index[at] = (int32_t)k;
    }
}

static void gather(double *destination, const double *coordinates, const int32_t *original_index, size_t n)
{
    for (size_t k = 0; k < n; ++k)
        memcpy(destination + 4 * k, coordinates + 4 * (size_t)original_index[k], 4 * sizeof *destination);
}

/* Index of a repeated bone in a sorted set, or n. */
static size_t repeated_bone(const int32_t *set, size_t n)
{
    for (size_t k = 1; k < n; ++k)
        if (set[k] == set[k - 1])
            return k;
    return n;
}

/* ---------------------------------------------------------------------------------------------
 * One removal
 * ------------------------------------------------------------------------------------------- */

sk_status sk_remove_influence(double *corrected, double *cost, const int32_t *bones, const double *coordinates,
                              size_t count, size_t removed, const sk_pose_statistics *statistics, sk_error *error)
{
    if (!corrected || !bones || !coordinates)
        return sk_fail(error, SK_ERROR_ARGUMENT, "corrected, bones and coordinates must not be null");
    if (count < 2 || count > SK_LOD_MAX_VERTEX_INFLUENCES)
        return sk_fail(error, SK_ERROR_ARGUMENT, "removing an influence needs 2 to %d influences, not %zu",
                       SK_LOD_MAX_VERTEX_INFLUENCES, count);
    if (removed >= count)
        return sk_fail(error, SK_ERROR_INDEX, "removed influence %zu is outside [0, %zu)", removed, count);
    sk_status status = validate_statistics(statistics, error);
    if (status != SK_OK)
        return status;
    for (size_t k = 0; k < count; ++k)
        if (bones[k] < 0 || (size_t)bones[k] >= statistics->bone_count)
            return sk_fail(error, SK_ERROR_INDEX, "influence %zu: bone index %d is outside [0, %zu)", k,
                           (int)bones[k], statistics->bone_count);
    const size_t bad = sk_first_non_finite(coordinates, 4 * count);
    if (bad < 4 * count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "influence %zu (bone %d): its coordinates have a NaN or infinity",
                       bad / 4, (int)bones[bad / 4]);
    workspace ws;
    status = init_workspace(&ws, count, 0, CACHE_ENTRIES, error);
    if (status != SK_OK)
        return status;
    load_sorted(&ws, bones, count);
    const size_t repeated = repeated_bone(ws.set, count);
    block_source source = {statistics, statistics->bone_count, NULL, NULL}; /* one set: blocks on demand */
    if (repeated < count)
        status = sk_fail(error, SK_ERROR_ARGUMENT, "bone %d is listed twice", (int)ws.set[repeated]);
    size_t c = 0;
    while (ws.original_index[c] != (int32_t)removed)
        ++c;
    int factored = 0;
    cache_entry *entry = NULL;
    if (status == SK_OK)
        status = removal_entry(&entry, &ws, &source, ws.set, count, c, &factored, 0, error);
    if (status == SK_OK) {
        gather(ws.q, coordinates, ws.original_index, count);
        if (cost)
            *cost = apply_norm(entry->w, entry->rows, ws.q + 4 * c);
        apply_removal(ws.q, entry->l, count, c);
        /* Back to the given order, the removed influence's slot zeroed (the layout of the input). */
        memset(corrected + 4 * removed, 0, 4 * sizeof *corrected);
        for (size_t k = 0, t = 0; k < count; ++k) {
            if (k == c)
                continue;
            memcpy(corrected + 4 * (size_t)ws.original_index[k], ws.q + 4 * t, 4 * sizeof *corrected);
            ++t;
        }
        status = sk_succeed(error);
    }
    free_workspace(&ws);
    return status;
}

/* ---------------------------------------------------------------------------------------------
 * Limit Influences
 * ------------------------------------------------------------------------------------------- */

/* A remover over the caller's block source (it takes ownership of source.owned, NULL when borrowed). */
static sk_status remover_create(sk_influence_remover **remover, block_source source, size_t capacity,
                                size_t entry_count, sk_error *error);

/* Candidates whose one-split cost is within this (relative to the cheapest, plus this times the dearest, for
 * zero-cost ties) of the cheapest are re-costed by the per-candidate solve, which picks among them as it always
 * did: the first of least cost. The two solvers agree to rounding, so this keeps the choice of the per-candidate
 * solve and costs it one preprocessing per step (the winner's, needed for its correction anyway) instead of n. */
#define NEAR_TIE 1e-6

typedef struct limit_task {
    const sk_influences *influences;
    const double *coordinates, *tangents;
    size_t tangent_count, max_influences;
    block_source source;
    int32_t *out_bones;   /* written at the input's offsets, compacted afterwards */
    int32_t *out_counts;  /* per vertex (limited_offsets + 1) */
    double *out_coordinates, *out_tangents, *costs;
    workspace *workspaces;
    sk_influence_remover **removers; /* per worker: every candidate's cost from one split of P's factor */
    size_t batch_begin;
    /* per worker: the first failure */
    sk_status *statuses;
    sk_error *errors;
} limit_task;

/* The position of the set's cheapest removal, its preprocessing's L copied into ws->best_l. */
static sk_status cheapest_removal(size_t *best, limit_task *task, workspace *ws, sk_influence_remover *remover,
                                  size_t n, int factored, size_t vertex, sk_error *error)
{
    double fast[SK_LOD_MAX_VERTEX_INFLUENCES];
    sk_status status = sk_influence_remover_costs(remover, fast, NULL, ws->set, ws->q, n, vertex, error);
    if (status != SK_OK)
        return status;
    double lowest = fast[0], highest = fast[0];
    for (size_t c = 1; c < n; ++c)
        lowest = fmin(lowest, fast[c]), highest = fmax(highest, fast[c]);
    const double band = lowest * (1.0 + NEAR_TIE) + NEAR_TIE * highest; /* NaN: every candidate is re-costed */
    double best_cost = INFINITY;
    int found = 0;
    for (size_t c = 0; c < n; ++c) {
        if (fast[c] > band)
            continue;
        cache_entry *entry = NULL;
        status = removal_entry(&entry, ws, &task->source, ws->set, n, c, &factored, vertex, error);
        if (status != SK_OK)
            return status;
        const double cost = apply_norm(entry->w, entry->rows, ws->q + 4 * c);
        if (cost < best_cost || !found) {
            best_cost = cost, *best = c, found = 1;
            /* Copied: a later candidate's preprocessing may take this cache slot. */
            memcpy(ws->best_l, entry->l, 16 * (n - 1) * sizeof(double));
        }
    }
    return SK_OK;
}

static sk_status limit_vertex(limit_task *task, workspace *ws, sk_influence_remover *remover, size_t vertex,
                              sk_error *error)
{
    const sk_influences *in = task->influences;
    const size_t begin = (size_t)in->offsets[vertex], n0 = (size_t)in->offsets[vertex + 1] - begin;
    const size_t stride = in->influence_count * 4, tangents = task->tangent_count;
    const double *coordinates = task->coordinates + 4 * begin;
    if (n0 <= task->max_influences) {
        memcpy(task->out_bones + begin, in->bones + begin, n0 * sizeof(int32_t));
        memcpy(task->out_coordinates + 4 * begin, coordinates, 4 * n0 * sizeof(double));
        for (size_t t = 0; t < tangents; ++t)
            memcpy(task->out_tangents + t * stride + 4 * begin, task->tangents + t * stride + 4 * begin,
                   4 * n0 * sizeof(double));
        task->out_counts[vertex] = (int32_t)n0;
        if (task->costs)
            task->costs[vertex] = 0.0;
        return SK_OK;
    }
    const size_t d0 = 4 * ws->capacity;
    load_sorted(ws, in->bones + begin, n0);
    gather(ws->q, coordinates, ws->original_index, n0);
    memcpy(ws->q0, ws->q, 4 * n0 * sizeof(double));
    for (size_t t = 0; t < tangents; ++t)
        gather(ws->tq + t * d0, task->tangents + t * stride + 4 * begin, ws->original_index, n0);
    /* The original set, kept for the total correction's norm. */
    int32_t original_set[SK_LOD_MAX_VERTEX_INFLUENCES];
    memcpy(original_set, ws->set, n0 * sizeof(int32_t));
    int32_t *set = ws->set, *index = ws->original_index;
    /* The original set's factor serves the first removal and the total correction's norm. */
    sk_status status = factor_set(ws, &task->source, set, n0, vertex, error);
    if (status != SK_OK)
        return status;
    const size_t rows0 = ws->f_rows;
    memcpy(ws->f0, ws->f, rows0 * 4 * n0 * sizeof(double));
    for (size_t n = n0; n > task->max_influences; --n) {
        size_t best = 0;
        status = cheapest_removal(&best, task, ws, remover, n, n == n0, vertex, error);
        if (status != SK_OK)
            return status;
        apply_removal(ws->q, ws->best_l, n, best);
        for (size_t t = 0; t < tangents; ++t)
            apply_removal(ws->tq + t * d0, ws->best_l, n, best);
        memmove(set + best, set + best + 1, (n - 1 - best) * sizeof *set);
        memmove(index + best, index + best + 1, (n - 1 - best) * sizeof *index);
    }
    const size_t kept = task->max_influences;
    if (task->costs) {
        /* ||new - original||_{2,2} over the original set (removed influences: -original). */
        for (size_t k = 0, t = 0; k < n0; ++k) {
            const int keep = t < kept && original_set[k] == set[t];
            for (int a = 0; a < 4; ++a)
                ws->difference[4 * k + (size_t)a] = (keep ? ws->q[4 * t + (size_t)a] : 0.0) - ws->q0[4 * k + (size_t)a];
            t += (size_t)keep;
        }
        const size_t d = 4 * n0;
        double sum = 0.0;
        for (size_t row = 0; row < rows0; ++row) {
            double value = 0.0;
            for (size_t col = 0; col < d; ++col)
                value += ws->f0[row * d + col] * ws->difference[col];
            sum += value * value;
        }
        task->costs[vertex] = sqrt(sum);
    }
    /* Out in the given order: the kept influences sorted by their original index. */
    for (size_t slot = 0; slot < kept; ++slot) {
        size_t pick = slot;
        for (size_t k = slot + 1; k < kept; ++k)
            if (index[k] < index[pick])
                pick = k;
        const size_t at = begin + slot;
        task->out_bones[at] = set[pick];
        memcpy(task->out_coordinates + 4 * at, ws->q + 4 * pick, 4 * sizeof(double));
        for (size_t t = 0; t < tangents; ++t)
            memcpy(task->out_tangents + t * stride + 4 * at, ws->tq + t * d0 + 4 * pick, 4 * sizeof(double));
        if (pick != slot) { /* selection sort: swap pick into slot */
            int32_t b = set[slot], i = index[slot];
            set[slot] = set[pick], index[slot] = index[pick];
            set[pick] = b, index[pick] = i;
            double swap[4];
            memcpy(swap, ws->q + 4 * slot, sizeof swap);
            memcpy(ws->q + 4 * slot, ws->q + 4 * pick, sizeof swap);
            memcpy(ws->q + 4 * pick, swap, sizeof swap);
            for (size_t t = 0; t < tangents; ++t) {
                double *v = ws->tq + t * d0;
                memcpy(swap, v + 4 * slot, sizeof swap);
                memcpy(v + 4 * slot, v + 4 * pick, sizeof swap);
                memcpy(v + 4 * pick, swap, sizeof swap);
            }
        }
    }
    task->out_counts[vertex] = (int32_t)kept;
    return SK_OK;
}

static void limit_range(void *context, size_t worker, size_t begin, size_t end)
{
    limit_task *task = context;
    for (size_t i = begin; i < end && task->statuses[worker] == SK_OK; ++i)
        task->statuses[worker] = limit_vertex(task, &task->workspaces[worker], task->removers[worker],
                                              task->batch_begin + i, &task->errors[worker]);
}

static sk_status validate_limit(int32_t *limited_offsets, int32_t *limited_bones, double *limited_coordinates,
                                size_t *limited_count, double *limited_tangents, const sk_influences *influences,
                                const double *coordinates, const double *tangents, size_t tangent_count,
                                size_t bone_count, size_t max_influences, size_t *capacity, sk_error *error)
{
    if (!limited_offsets || !limited_bones || !limited_coordinates || !limited_count || !influences)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the outputs and the influences must not be null");
    if (max_influences < 1)
        return sk_fail(error, SK_ERROR_ARGUMENT, "max_influences must be at least 1");
    const size_t vertices = influences->vertex_count, count = influences->influence_count;
    if (vertices >= INT32_MAX || count > INT32_MAX)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%zu vertices and %zu influences exceed the int32 offsets",
                       vertices, count);
    if (!coordinates && count > 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "coordinates must not be null");
    if (tangent_count > SK_LOD_MAX_TANGENT_SETS)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%zu tangent sets: at most %d are carried along", tangent_count,
                       SK_LOD_MAX_TANGENT_SETS);
    if (tangent_count > 0 && (!tangents || !limited_tangents))
        return sk_fail(error, SK_ERROR_ARGUMENT, "%zu tangent sets need tangents and limited_tangents", tangent_count);
    size_t tangent_bytes;
    sk_status status = sk_array_size(&tangent_bytes, tangent_count, 4 * count, sizeof(double), "tangents", error);
    if (status == SK_OK)
        status = sk_validate_influences(influences, bone_count, error);
    if (status != SK_OK)
        return status;
    *capacity = 1;
    for (size_t v = 0; v < vertices; ++v) {
        const size_t begin = (size_t)influences->offsets[v], n = (size_t)influences->offsets[v + 1] - begin;
        for (size_t set = 0; set <= tangent_count; ++set) {
            const double *values = (set == 0 ? coordinates : tangents + (set - 1) * 4 * count) + 4 * begin;
            const size_t bad = sk_first_non_finite(values, 4 * n);
            if (bad < 4 * n) {
                if (set == 0)
                    return sk_fail(error, SK_ERROR_NOT_FINITE, "vertex %zu: the coordinates of bone %d are not finite",
                                   v, (int)influences->bones[begin + bad / 4]);
                return sk_fail(error, SK_ERROR_NOT_FINITE, "vertex %zu: tangent set %zu, bone %d, is not finite", v,
                               set - 1, (int)influences->bones[begin + bad / 4]);
            }
        }
        if (n <= max_influences)
            continue;
        if (n > SK_LOD_MAX_VERTEX_INFLUENCES)
            return sk_fail(error, SK_ERROR_ARGUMENT, "vertex %zu has %zu influences, more than the %d supported", v, n,
                           SK_LOD_MAX_VERTEX_INFLUENCES);
        for (size_t a = 0; a < n; ++a)
            for (size_t b = a + 1; b < n; ++b)
                if (influences->bones[begin + a] == influences->bones[begin + b])
                    return sk_fail(error, SK_ERROR_ARGUMENT, "vertex %zu: bone %d is listed twice", v,
                                   (int)influences->bones[begin + a]);
        *capacity = n > *capacity ? n : *capacity;
    }
    return SK_OK;
}

/* Limit Influences in the metric of `source` (statistics to form the blocks from, or the caller's table). */
static sk_status limit_in_metric(int32_t *limited_offsets, int32_t *limited_bones, double *limited_coordinates,
                                 size_t *limited_count, double *costs, double *limited_tangents,
                                 const sk_influences *influences, const double *coordinates, const double *tangents,
                                 size_t tangent_count, block_source metric, size_t max_influences, int thread_count,
                                 sk_progress_fn progress, void *progress_user, sk_error *error)
{
    size_t capacity = 1;
    sk_status status = validate_limit(limited_offsets, limited_bones, limited_coordinates, limited_count,
                                      limited_tangents, influences, coordinates, tangents, tangent_count,
                                      metric.bone_count, max_influences, &capacity, error);
    if (status != SK_OK)
        return status;
    const size_t vertices = influences->vertex_count, count = influences->influence_count;
    const size_t first_batch = vertices < BATCH_VERTICES ? vertices : BATCH_VERTICES;
    const size_t workers = sk_worker_count(first_batch, SK_SOLVE_ITEMS_PER_WORKER, thread_count);
    limit_task task = {influences, coordinates, tangents, tangent_count, max_influences, metric,
                       limited_bones, limited_offsets + 1, limited_coordinates, limited_tangents, costs,
                       calloc(workers, sizeof(workspace)), calloc(workers, sizeof(sk_influence_remover *)), 0,
                       calloc(workers, sizeof(sk_status)), calloc(workers, sizeof(sk_error))};
    size_t initialised = 0;
    if (!task.workspaces || !task.removers || !task.statuses || !task.errors)
        status = sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu workers", workers);
    if (status == SK_OK && metric.statistics)
        status = make_block_source(&task.source, metric.statistics, error);
    block_source borrowed = task.source;
    borrowed.owned = NULL; /* the task's, freed with it */
    for (; status == SK_OK && initialised < workers; ++initialised) {
        status = init_workspace(&task.workspaces[initialised], capacity, tangent_count, CACHE_ENTRIES, error);
        if (status == SK_OK)
            status = remover_create(&task.removers[initialised], borrowed, capacity, CACHE_ENTRIES, error);
    }
    for (size_t batch = 0; status == SK_OK && batch < vertices; batch += BATCH_VERTICES) {
        const size_t size = vertices - batch < BATCH_VERTICES ? vertices - batch : BATCH_VERTICES;
        task.batch_begin = batch;
        sk_parallel_for(size, SK_SOLVE_ITEMS_PER_WORKER, thread_count, limit_range, &task);
        for (size_t w = 0; w < workers && status == SK_OK; ++w)
            if (task.statuses[w] != SK_OK) {
                status = task.statuses[w];
                if (error)
                    *error = task.errors[w];
            }
        if (status == SK_OK && progress && progress(progress_user, (double)(batch + size) / (double)vertices))
            status = sk_fail(error, SK_ERROR_CANCELLED, "cancelled after %zu of %zu vertices", batch + size, vertices);
    }
    if (status == SK_OK) {
        /* Compact: each vertex's result sits at its input offset; the new offsets are never larger. */
        const size_t stride = 4 * count;
        limited_offsets[0] = 0;
        for (size_t v = 0; v < vertices; ++v) {
            const size_t from = (size_t)influences->offsets[v], to = (size_t)limited_offsets[v];
            const size_t n = (size_t)limited_offsets[v + 1];
            if (from != to) {
                memmove(limited_bones + to, limited_bones + from, n * sizeof *limited_bones);
                memmove(limited_coordinates + 4 * to, limited_coordinates + 4 * from, 4 * n * sizeof(double));
                for (size_t t = 0; t < tangent_count; ++t)
                    memmove(limited_tangents + t * stride + 4 * to, limited_tangents + t * stride + 4 * from,
                            4 * n * sizeof(double));
            }
            limited_offsets[v + 1] = (int32_t)(to + n);
        }
        *limited_count = (size_t)limited_offsets[vertices];
        status = sk_succeed(error);
    }
    for (size_t w = 0; w < initialised; ++w) {
        free_workspace(&task.workspaces[w]);
        sk_influence_remover_free(task.removers[w]);
    }
    free(task.workspaces), free(task.removers), free(task.statuses), free(task.errors), free(task.source.owned);
    return status;
}

sk_status sk_limit_influences(int32_t *limited_offsets, int32_t *limited_bones, double *limited_coordinates,
                              size_t *limited_count, double *costs, double *limited_tangents,
                              const sk_influences *influences, const double *coordinates, const double *tangents,
                              size_t tangent_count, const sk_pose_statistics *statistics, size_t max_influences,
                              int thread_count, sk_progress_fn progress, void *progress_user, sk_error *error)
{
    const sk_status status = validate_statistics(statistics, error);
    if (status != SK_OK)
        return status;
    return limit_in_metric(limited_offsets, limited_bones, limited_coordinates, limited_count, costs, limited_tangents,
                           influences, coordinates, tangents, tangent_count,
                           (block_source){statistics, statistics->bone_count, NULL, NULL}, max_influences, thread_count,
                           progress, progress_user, error);
}

/* The caller's P blocks: finite and symmetric (P_jk = P_kj^T to 1e-9 of the largest entry), else the message names
 * the first offending block. Semi-definiteness is not checked: pivoted Cholesky stops at the first non-positive
 * pivot, so an indefinite table only loses its non-positive part. */
static sk_status validate_metric_blocks(const double *blocks, size_t bone_count, sk_error *error)
{
    if (!blocks)
        return sk_fail(error, SK_ERROR_ARGUMENT, "metric_blocks must not be null");
    if (bone_count < 1 || bone_count > INT32_MAX)
        return sk_fail(error, SK_ERROR_ARGUMENT, "bone_count %zu must be in [1, INT32_MAX]", bone_count);
    size_t entries;
    sk_status status = sk_array_size(&entries, bone_count, bone_count, 16, "metric_blocks", error);
    if (status != SK_OK)
        return status;
    const size_t bad = sk_first_non_finite(blocks, entries);
    if (bad < entries)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "metric block (%zu, %zu) has a NaN or infinity",
                       bad / 16 / bone_count, bad / 16 % bone_count);
    double largest = 0.0;
    for (size_t e = 0; e < entries; ++e)
        largest = fmax(largest, fabs(blocks[e]));
    for (size_t j = 0; j < bone_count; ++j)
        for (size_t k = j; k < bone_count; ++k)
            for (int r = 0; r < 4; ++r)
                for (int c = 0; c < 4; ++c)
                    if (fabs(blocks[16 * (j * bone_count + k) + 4 * r + c] -
                             blocks[16 * (k * bone_count + j) + 4 * c + r]) > 1e-9 * largest)
                        return sk_fail(error, SK_ERROR_ARGUMENT,
                                       "metric block (%zu, %zu) is not the transpose of block (%zu, %zu)", j, k, k, j);
    return SK_OK;
}

sk_status sk_limit_influences_in_metric(int32_t *limited_offsets, int32_t *limited_bones, double *limited_coordinates,
                                        size_t *limited_count, double *costs, double *limited_tangents,
                                        const sk_influences *influences, const double *coordinates,
                                        const double *tangents, size_t tangent_count, const double *metric_blocks,
                                        size_t bone_count, size_t max_influences, int thread_count,
                                        sk_progress_fn progress, void *progress_user, sk_error *error)
{
    const sk_status status = validate_metric_blocks(metric_blocks, bone_count, error);
    if (status != SK_OK)
        return status;
    return limit_in_metric(limited_offsets, limited_bones, limited_coordinates, limited_count, costs, limited_tangents,
                           influences, coordinates, tangents, tangent_count,
                           (block_source){NULL, bone_count, metric_blocks, NULL}, max_influences, thread_count,
                           progress, progress_user, error);
}

/* ---------------------------------------------------------------------------------------------
 * The persistent remover of sk_lod_internal.h (the progressive simplifier's influence collapses)
 * ------------------------------------------------------------------------------------------- */

/* One candidate's five-row elimination (candidate_program) as it acts on the right-hand sides: the row operations
 * x[row] -= coefficient x[pivot] in order, then cost^2 = sum (x[sum_row] / sum_norm)^2. Its pivots and coefficients
 * depend on the set alone, so a kept split costs new coordinates with these few operations, the same bits as the
 * whole elimination. */
#define PROGRAM_STEPS 20 /* 2 passes for each of the 10 pairs of the 5 rows */
typedef struct removal_program {
    int fast; /* 0: the per-candidate solve decides */
    int steps, sums;
    unsigned char row[PROGRAM_STEPS], pivot[PROGRAM_STEPS], sum_row[5];
    double coefficient[PROGRAM_STEPS], sum_norm[5];
} removal_program;

/* One set's split for sk_influence_remover_costs (d = 4 * count, row-major): m (d x rank) with F m = I, z
 * (d x (d - rank)) an orthonormal basis of F's null space, right after m (the two fill d x d), weight_row their
 * weight rows' sums; fast 0 when the factor asks for the per-candidate solve. */
typedef struct split_entry {
    uint64_t hash;
    size_t count; /* 0: an empty slot */
    size_t rank;
    int fast;
    int32_t *set; /* sorted */
    double *m, *z, *weight_row;
    removal_program *programs; /* count, one per sorted position */
} split_entry;

/* Splits kept (first in, first out) like the preprocessings: many vertices share small sets. At most this many
 * bytes of them, and at most SPLIT_ENTRIES (the horse's 5-level chain, 8 influences a vertex, meets 1,388 sets:
 * 512 entries made 2,904 splits, 1,536 entries, 16 MiB, make 1,388). */
#define SPLIT_ENTRIES 1536
#define SPLIT_CACHE_BYTES (16u << 20)

struct sk_influence_remover {
    block_source source;
    workspace ws;
    size_t capacity;
    /* The sorted bone set whose factor ws.f holds (factored_count 0: none yet). The simplifier costs every removal
     * of a vertex's set in a row, so one factorization serves them all. */
    int32_t factored_set[SK_LOD_MAX_VERTEX_INFLUENCES];
    size_t factored_count;
    /* sk_influence_remover_costs' splits and the triangular inverse they are made with */
    split_entry splits[SPLIT_ENTRIES];
    slot_index split_index; /* of splits, by their hash */
    size_t split_entries, split_next;
    double *inverse;
    void *split_block;
};

/* The buffers of sk_influence_remover_costs: as many split entries of the largest set as SPLIT_CACHE_BYTES hold
 * (1 to SPLIT_ENTRIES). */
static sk_status init_cost_buffers(sk_influence_remover *r, sk_error *error)
{
    const size_t d = 4 * r->capacity; /* <= 256: no overflow below */
    const size_t entry_doubles = d * d + d + 1, entry_programs = r->capacity * sizeof(removal_program);
    const size_t entry_bytes = entry_doubles * sizeof(double) + entry_programs + r->capacity * 4;
    size_t entries = SPLIT_CACHE_BYTES / entry_bytes;
    entries = entries < 1 ? 1 : entries > SPLIT_ENTRIES ? SPLIT_ENTRIES : entries;
    r->inverse = malloc(d * d * sizeof(double));
    r->split_block = malloc(entries * entry_bytes);
    if (!r->inverse || !r->split_block || !index_init(&r->split_index, entries))
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the costing buffers of %zu influences", r->capacity);
    double *next = r->split_block;
    removal_program *programs = (removal_program *)(void *)(next + entries * entry_doubles);
    int32_t *sets = (int32_t *)(void *)(programs + entries * r->capacity);
    for (size_t e = 0; e < entries; ++e) {
        split_entry *entry = &r->splits[e];
        entry->count = 0;
        entry->m = next, entry->z = next, entry->weight_row = next + d * d; /* z: placed once the rank is known */
        next += entry_doubles;
        entry->programs = programs + e * r->capacity;
        entry->set = sets + e * r->capacity;
    }
    r->split_entries = entries;
    return SK_OK;
}

sk_status sk_influence_remover_create(sk_influence_remover **remover, const sk_pose_statistics *statistics,
                                      size_t capacity, sk_error *error)
{
    *remover = NULL;
    if (capacity < 1 || capacity > SK_LOD_MAX_VERTEX_INFLUENCES)
        return sk_fail(error, SK_ERROR_ARGUMENT, "a vertex has more than %d influences", SK_LOD_MAX_VERTEX_INFLUENCES);
    sk_status status = validate_statistics(statistics, error);
    if (status != SK_OK)
        return status;
    block_source source;
    status = make_block_source(&source, statistics, error);
    if (status != SK_OK) {
        free(source.owned);
        return status;
    }
    /* capacity <= SK_LOD_MAX_VERTEX_INFLUENCES: no overflow */
    const size_t entry_bytes = 8 * 4 * capacity * sizeof(double) + capacity * sizeof(int32_t) + sizeof(cache_entry);
    const size_t most = REMOVER_CACHE_BYTES / entry_bytes;
    const size_t entries = most < CACHE_ENTRIES ? CACHE_ENTRIES : most > REMOVER_CACHE_ENTRIES ? REMOVER_CACHE_ENTRIES
                                                                                                : most;
    return remover_create(remover, source, capacity, entries, error);
}

static sk_status remover_create(sk_influence_remover **remover, block_source source, size_t capacity,
                                size_t entry_count, sk_error *error)
{
    *remover = NULL;
    sk_influence_remover *r = calloc(1, sizeof *r);
    if (!r) {
        free(source.owned);
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the influence remover");
    }
    r->capacity = capacity;
    r->source = source;
    sk_status status = init_workspace(&r->ws, capacity, 0, entry_count, error);
    if (status == SK_OK)
        status = init_cost_buffers(r, error);
    if (status != SK_OK) {
        sk_influence_remover_free(r);
        return status;
    }
    *remover = r;
    return SK_OK;
}

void sk_influence_remover_free(sk_influence_remover *remover)
{
    if (!remover)
        return;
    free_workspace(&remover->ws);
    free(remover->source.owned);
    free(remover->inverse), free(remover->split_block), index_free(&remover->split_index);
    free(remover);
}

sk_status sk_influence_remover_apply(sk_influence_remover *remover, double *corrected, double *cost,
                                     const int32_t *bones, const double *coordinates, size_t count, size_t removed,
                                     size_t vertex, sk_error *error)
{
    workspace *ws = &remover->ws;
    load_sorted(ws, bones, count);
    size_t c = 0;
    while (ws->original_index[c] != (int32_t)removed)
        ++c;
    int factored = remover->factored_count == count &&
                   memcmp(remover->factored_set, ws->set, count * sizeof *ws->set) == 0;
    cache_entry *entry = NULL;
    const sk_status status = removal_entry(&entry, ws, &remover->source, ws->set, count, c, &factored, vertex, error);
    if (status != SK_OK) {
        remover->factored_count = 0; /* a failed factorization may have left ws->f half-written */
        return status;
    }
    if (factored) { /* ws->f holds this set's factor (made now or before) */
        memcpy(remover->factored_set, ws->set, count * sizeof *ws->set);
        remover->factored_count = count;
    }
    gather(ws->q, coordinates, ws->original_index, count);
    if (cost)
        *cost = apply_norm(entry->w, entry->rows, ws->q + 4 * c);
    if (!corrected)
        return SK_OK;
    apply_removal(ws->q, entry->l, count, c);
    memset(corrected + 4 * removed, 0, 4 * sizeof *corrected);
    for (size_t k = 0, t = 0; k < count; ++k) {
        if (k == c)
            continue;
        memcpy(corrected + 4 * (size_t)ws->original_index[k], ws->q + 4 * t, 4 * sizeof *corrected);
        ++t;
    }
    return SK_OK;
}

void sk_influence_remover_block(double block[16], const sk_influence_remover *remover, int32_t j, int32_t k)
{
    get_block(block, &remover->source, j, k);
}

const double *sk_influence_remover_block_ref(double scratch[16], const sk_influence_remover *remover, int32_t j,
                                             int32_t k)
{
    const block_source *source = &remover->source;
    if (source->table)
        return source->table + 16 * ((size_t)j * source->bone_count + (size_t)k);
    get_block(scratch, source, j, k);
    return scratch;
}

/* ---------------------------------------------------------------------------------------------
 * Every removal of one set from one factorization (sk_influence_remover_costs)
 *
 * The removal of position c is min ||F s||^2 under the five constraints C_c s = d_c: s_c = -q_c (4 rows) and
 * e_w^T s = 0 (the weights of s sum to zero; e_w picks every weight). F comes from pivoted Cholesky,
 * F = [U11 U12] Pi^T (rank x 4n) with U11 upper triangular and well scaled (its pivots above PIVOT_THRESHOLD).
 * With M = Pi [U11^-1; 0] (so F M = I) and Z an orthonormal basis of F's null space (Pi [-U11^-1 U12; I],
 * orthonormalised), every s is s = M u + Z y with F s = u: u costs, y (the zero-weight directions of A.2.3, the
 * matrix weight's null space of A.2.4) is free. So the cost is min ||u|| subject to (C_c M) u + (C_c Z) y = d_c,
 * five rows of precomputed matrices: four are M's and Z's rows of position c, the fifth (their weight rows'
 * sums) is the same for every c. Row operations keep the system's solutions: eliminating y (pivoted
 * Gram-Schmidt on the Z parts, the same operations applied to whole rows) leaves the rows whose Z part vanished,
 * constraints on u alone; orthogonalising their M parts gives cost^2 = sum (d_i / |m_i|)^2, the minimum-norm u.
 * One split (a triangular inverse) serves all n candidates, against one dgelsy of a rank x (4n - 5) system per
 * candidate, and the last SPLIT_ENTRIES splits are kept, as the preprocessings are. It solves the same problem as
 * prepare_removal, so it gives the same cost up to rounding where both solvers see the same rank; where a
 * decision is near a threshold (a weakly coupled null direction, a nearly dependent constraint, a factor whose
 * pivots spread widely) the candidate, or the whole set, falls back to the per-candidate solve, so the
 * thresholds of the file's header keep deciding the result there.
 * ------------------------------------------------------------------------------------------- */

/* A null direction coupling the constraints by less than this (unit-norm direction) is not free; above
 * FREE_SURE it is; in between the per-candidate solve decides. */
#define FREE_ZERO 1e-8
#define FREE_SURE 1e-4
/* U11's diagonal spread beyond this ratio (its pivots beyond its square): the per-candidate solve decides. */
#define RANGE_SPREAD 1e-5
/* A constraint row losing all but this fraction of its norm to the others: nearly dependent, fall back. */
#define ROW_DEPENDENT 1e-9

/* The split of the set whose pivoted Cholesky factor ws->p (column-major U) and ws->isuppz (pivots) hold, of
 * rank r, into entry. 0 when U11's pivots spread too widely. */
static int split_factor(split_entry *entry, const sk_influence_remover *remover, size_t count, size_t r)
{
    const size_t d = 4 * count, nulls = d - r;
    const double *u = remover->ws.p; /* U(i, j) = u[j * d + i], j >= i */
    const lapack_int *pivots = remover->ws.isuppz;
    entry->z = entry->m + d * r;
    double *t = remover->inverse, *m = entry->m, *z = entry->z; /* t: U11^-1, row-major r x r */
    if (!(fabs(u[(r - 1) * d + r - 1]) > RANGE_SPREAD * fabs(u[0])))
        return 0;
    for (size_t j = 0; j < r; ++j) { /* column j of U11^-1 by back substitution */
        t[j * r + j] = 1.0 / u[j * d + j];
        for (size_t i = j; i-- > 0;) {
            double sum = 0.0;
            for (size_t k = i + 1; k <= j; ++k)
                sum += u[k * d + i] * t[k * r + j];
            t[i * r + j] = -sum / u[i * d + i];
        }
        for (size_t i = j + 1; i < r; ++i)
            t[i * r + j] = 0.0;
    }
    memset(m, 0, d * r * sizeof *m);
    for (size_t j = 0; j < r; ++j) /* M = Pi [U11^-1; 0]: pivoted row j is the set's coordinate pivots[j] - 1 */
        memcpy(m + ((size_t)pivots[j] - 1) * r, t + j * r, r * sizeof *m);
    memset(z, 0, d * nulls * sizeof *z);
    for (size_t k = 0; k < nulls; ++k) { /* column k: Pi [-U11^-1 U(:, r + k); e_k] */
        for (size_t j = 0; j < r; ++j) {
            double sum = 0.0;
            for (size_t i = j; i < r; ++i)
                sum += t[j * r + i] * u[(r + k) * d + i];
            z[((size_t)pivots[j] - 1) * nulls + k] = -sum;
        }
        z[((size_t)pivots[r + k] - 1) * nulls + k] = 1.0;
    }
    for (size_t k = 0; k < nulls; ++k) /* orthonormal columns (Gram-Schmidt twice): unit-scaled couplings */
        for (int pass = 0; pass < 2; ++pass) {
            for (size_t l = 0; l < k; ++l) {
                double projection = 0.0;
                for (size_t i = 0; i < d; ++i)
                    projection += z[i * nulls + k] * z[i * nulls + l];
                for (size_t i = 0; i < d; ++i)
                    z[i * nulls + k] -= projection * z[i * nulls + l];
            }
            double norm = 0.0;
            for (size_t i = 0; i < d; ++i)
                norm += z[i * nulls + k] * z[i * nulls + k];
            norm = sqrt(norm);
            for (size_t i = 0; i < d; ++i)
                z[i * nulls + k] /= norm;
        }
    /* The fifth constraint row (the weights' sum), the same for every candidate, right-hand side 0. */
    double *weight_row = entry->weight_row;
    memset(weight_row, 0, (d + 1) * sizeof *weight_row);
    for (size_t p = 0; p < count; ++p) {
        for (size_t j = 0; j < r; ++j)
            weight_row[j] += m[(4 * p + 3) * r + j];
        for (size_t k = 0; k < nulls; ++k)
            weight_row[r + k] += z[(4 * p + 3) * nulls + k];
    }
    return 1;
}

static double dot(const double *a, const double *b, size_t n)
{
    double sum = 0.0;
    for (size_t i = 0; i < n; ++i)
        sum += a[i] * b[i];
    return sum;
}

/* rows[j] -= (part_j . part_p / part_p . part_p) rows[p] over [0, part + part_width) (the columns still read),
 * twice (re-orthogonalisation), the coefficients kept in program. */
static void eliminate(removal_program *program, double (*rows)[4 * SK_LOD_MAX_VERTEX_INFLUENCES], int j, int p,
                      size_t part, size_t part_width)
{
    double *row_j = rows[j];
    const double *row_p = rows[p];
    const double scale = dot(row_p + part, row_p + part, part_width);
    for (int pass = 0; pass < 2; ++pass) {
        const double coefficient = dot(row_j + part, row_p + part, part_width) / scale;
        for (size_t i = 0; i < part + part_width; ++i)
            row_j[i] -= coefficient * row_p[i];
        program->row[program->steps] = (unsigned char)j, program->pivot[program->steps] = (unsigned char)p;
        program->coefficient[program->steps++] = coefficient;
    }
}

/* The elimination of sorted position c's five rows [B | Z] (their right-hand sides apart) into program; fast = 0
 * when the per-candidate solve must decide. */
static void candidate_program(removal_program *program, const split_entry *split, size_t c)
{
    const size_t d = 4 * split->count, rank = split->rank, nulls = d - rank;
    double rows[5][4 * SK_LOD_MAX_VERTEX_INFLUENCES];
    program->fast = 0, program->steps = program->sums = 0;
    for (size_t a = 0; a < 4; ++a) {
        memcpy(rows[a], split->m + (4 * c + a) * rank, rank * sizeof(double));
        for (size_t k = 0; k < nulls; ++k)
            rows[a][rank + k] = split->z[(4 * c + a) * nulls + k];
    }
    memcpy(rows[4], split->weight_row, d * sizeof(double));
    int done[5] = {0};
    for (int step = 0; step < 5; ++step) { /* eliminate the free y */
        int pivot = -1;
        double best = 0.0;
        for (int i = 0; i < 5; ++i) {
            const double norm = done[i] ? 0.0 : sqrt(dot(rows[i] + rank, rows[i] + rank, nulls));
            if (!done[i] && (pivot < 0 || norm > best))
                pivot = i, best = norm;
        }
        if (pivot < 0 || best <= FREE_ZERO)
            break;
        if (best < FREE_SURE)
            return;
        done[pivot] = 1;
        for (int i = 0; i < 5; ++i)
            if (!done[i])
                eliminate(program, rows, i, pivot, rank, nulls);
    }
    double start[5];
    for (int i = 0; i < 5; ++i) {
        start[i] = sqrt(dot(rows[i], rows[i], rank));
        if (!done[i] && !(start[i] > 0.0))
            return; /* a constraint nothing can meet: only rounding makes one */
    }
    for (int step = 0; step < 5; ++step) { /* the rows left constrain u: orthogonalise them */
        int pivot = -1;
        double best = 0.0, kept = 0.0; /* kept: the fraction of its norm the pivot row keeps */
        for (int i = 0; i < 5; ++i) {
            if (done[i])
                continue;
            const double norm = sqrt(dot(rows[i], rows[i], rank));
            if (pivot < 0 || norm / start[i] > kept)
                pivot = i, best = norm, kept = norm / start[i];
        }
        if (pivot < 0)
            break;
        if (!(kept > ROW_DEPENDENT))
            return;
        done[pivot] = 1;
        program->sum_row[program->sums] = (unsigned char)pivot, program->sum_norm[program->sums++] = best;
        for (int i = 0; i < 5; ++i)
            if (!done[i])
                eliminate(program, rows, i, pivot, 0, rank);
    }
    program->fast = 1;
}

/* The cost of removing a position whose sorted coordinates are q_c (4): program on the right-hand sides
 * (-q_c, and 0 for the weights' sum). A pivot row is final once it is a pivot, so its term is summed after the
 * row operations, in the pivots' order. */
static double program_cost(const removal_program *program, const double *q_c)
{
    double x[5] = {-q_c[0], -q_c[1], -q_c[2], -q_c[3], 0.0};
    for (int k = 0; k < program->steps; ++k)
        x[program->row[k]] -= program->coefficient[k] * x[program->pivot[k]];
    double sum = 0.0;
    for (int k = 0; k < program->sums; ++k)
        sum += (x[program->sum_row[k]] / program->sum_norm[k]) * (x[program->sum_row[k]] / program->sum_norm[k]);
    return sqrt(sum);
}

/* The split of the sorted set in ws->set: kept, or made now (factoring P over the set) in the oldest slot. */
static sk_status split_of_set(const split_entry **result, sk_influence_remover *remover, size_t count, size_t vertex,
                              sk_error *error)
{
    workspace *ws = &remover->ws;
    const uint64_t hash = key_hash(ws->set, count, -1);
    for (int32_t e = *index_bucket(&remover->split_index, hash); e >= 0; e = remover->split_index.chain[e]) {
        const split_entry *entry = &remover->splits[e];
        if (entry->count == count && entry->hash == hash && memcmp(entry->set, ws->set, count * sizeof *ws->set) == 0) {
            *result = entry;
            return SK_OK;
        }
    }
    const size_t slot = remover->split_next;
    split_entry *entry = &remover->splits[slot];
    remover->split_next = (remover->split_next + 1) % remover->split_entries;
    if (entry->count)
        index_remove(&remover->split_index, slot, entry->hash);
    entry->count = remover->factored_count = 0; /* invalid until made */
    const sk_status status = factor_set(ws, &remover->source, ws->set, count, vertex, error);
    if (status != SK_OK)
        return status;
    memcpy(remover->factored_set, ws->set, count * sizeof *ws->set);
    remover->factored_count = count;
    entry->rank = ws->f_rows;
    entry->fast = ws->f_rows == 0 || split_factor(entry, remover, count, ws->f_rows);
    memcpy(entry->set, ws->set, count * sizeof *ws->set);
    entry->hash = hash;
    entry->count = count;
    index_insert(&remover->split_index, slot, hash);
    for (size_t c = 0; entry->fast && entry->rank > 0 && c < count; ++c)
        candidate_program(&entry->programs[c], entry, c);
    *result = entry;
    return SK_OK;
}

sk_status sk_influence_remover_costs(sk_influence_remover *remover, double *costs, size_t *fallbacks,
                                     const int32_t *bones, const double *coordinates, size_t count, size_t vertex,
                                     sk_error *error)
{
    workspace *ws = &remover->ws;
    load_sorted(ws, bones, count);
    const split_entry *split = NULL;
    sk_status status = split_of_set(&split, remover, count, vertex, error);
    if (status != SK_OK)
        return status;
    gather(ws->q, coordinates, ws->original_index, count);
    /* The sorted order, kept: the fallback reloads ws->set and ws->original_index (the same values). */
    int32_t original_index[SK_LOD_MAX_VERTEX_INFLUENCES];
    memcpy(original_index, ws->original_index, count * sizeof *original_index);
    for (size_t c = 0; c < count; ++c) {
        const size_t slot = (size_t)original_index[c];
        double cost = 0.0;
        if (split->rank == 0) { /* P = 0 over these bones: every removal is free */
            costs[slot] = 0.0;
            continue;
        }
        if (split->fast && split->programs[c].fast) {
            costs[slot] = program_cost(&split->programs[c], ws->q + 4 * c);
            continue;
        }
        if (fallbacks)
            ++*fallbacks;
        status = sk_influence_remover_apply(remover, NULL, &cost, bones, coordinates, count, slot, vertex, error);
        if (status != SK_OK)
            return status;
        costs[slot] = cost;
    }
    return SK_OK;
}
