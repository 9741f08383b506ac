/*
 * Refitting a level's coordinates to the full-detail surface: Hoppe et al. 1993's distance energy, measured in
 * animation space. The collapses place each survivor for its own one-ring; with the level's triangles and influence
 * sets fixed, the coordinates x_j that minimise
 *
 *   E(x) = sum_s w_s e_s^T P e_s,   e_s = sum_k b_sk x_{j_sk} - p_s
 *
 * (P = E[G^T G] from the pose statistics, so e^T P e is the expected squared distance over the poses) over samples
 * s of the full-detail surface (p_s its animation-space point, (j_sk, b_sk) the corners and barycentric weights of
 * its closest rest-pose point on the level, the correspondence the benchmarks measure by), plus the pull
 * lambda * m * sum_j (x_j - x0_j)^T P_jj (x_j - x0_j) towards the collapses' values (m: the mean sample mass of a
 * vertex; it holds the directions the samples hardly determine, which held-out poses would otherwise punish),
 * solve the normal equations
 *
 *   sum_l m_jl P[I_j, I_l] x_l + lambda m P_jj (x_j - x0_j) = P[I_j, :] z_j,
 *   m_jl = sum_s w_s b_sj b_sl,   z_j = sum_s w_s b_sj p_s.
 *
 * The sample mass is a mass matrix: well conditioned, so a few block-Jacobi-preconditioned CG steps from x0 reach
 * what a direct solve gives (measured on the horse, creature and cow chains: 3 steps within 0.1% of the exact
 * error). A vertex's diagonal block is its bone set's P[I, I] scaled by its mass, so vertices of one set share one
 * factorisation (see number_sets). A product sums each row's neighbours per bone first (t_b = sum_l m_jl x_lb) and
 * then applies P's blocks once per bone pair of the union, not once per neighbour. Rows are independent: threads
 * split them, and every reduction runs in one fixed order, so the result has the same bits on any thread count.
 * SPDX-License-Identifier: GPL-3.0-or-later
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../bake/sk_bake_internal.h"
#include "sk_lod_internal.h"

/* A vertex's diagonal block gets this fraction of its largest diagonal entry added (P may be singular: a bone no
 * pose moves), keeping the block solves finite without moving what the samples determine. */
#define DIAGONAL_RIDGE 1e-12
#define ROWS_PER_WORKER 256
/* Doubles of influence-set inverses kept for the whole solve (64 MiB: (4n)^2 a set); above, each CG step factors
 * the sets again, which needs no memory. */
#define FACTOR_BUDGET ((size_t)8 << 20)

typedef struct sample {
    int32_t triangle;  /* the level triangle holding the closest point, -1: none */
    double weight[3];  /* its barycentric weights */
    double mass;       /* w_s: the sample's share of the full-detail area */
} sample;

typedef struct refit {
    const sk_triangle_mesh *level, *mesh;
    const sk_influences *level_influences, *influences;
    const double *rest, *level_rest, *coordinates, *x0;
    sk_influence_remover *remover;
    sk_bake_surface surface; /* the level's, as the BVH sees it (it keeps a pointer) */
    sk_bvh bvh;
    size_t bone_count, unknowns;
    double pull; /* lambda * the mean vertex mass */
    sample *samples;
    int32_t *row_offsets, *row_vertices; /* each level vertex's neighbours and itself, ascending */
    double *row_mass;                    /* m_jl, parallel to row_vertices */
    int32_t *contribution_offsets, *contributions; /* per level vertex: 3 * sample + corner, ascending */
    double *ridge;         /* per level vertex: s_j eps_I, added to its diagonal block's diagonal */
    double *block;         /* per worker: one diagonal block, block_stride doubles */
    size_t block_stride;
    int32_t *set_of, *set_vertex; /* per vertex its bone set; per set its first vertex (see number_sets) */
    size_t set_count;
    double *set_eps;       /* per set: the ridge of its P[I, I] */
    double *scale;         /* per vertex: s_j, its diagonal block over its set's */
    double *inverses;      /* every set's (P[I, I] + eps I)^-1 when they fit FACTOR_BUDGET, else NULL */
    size_t *inverse_offsets;
    double *scratch;       /* per worker: 4 * bone_count accumulators */
    unsigned char *touched_mark; /* per worker: bone_count marks */
    int32_t *touched;      /* per worker: bone_count touched bones */
    double *source_weight; /* per worker, per full-detail vertex: its weight in the row being summed */
    int32_t *source_stamp, *source_list; /* per worker: the row (+1) that last met each vertex; the vertices met */
    int threads;
    size_t workers; /* the row passes' workers: each has its own scratch */
} refit;

static size_t vertex_influences(const sk_influences *influences, size_t v)
{
    return (size_t)(influences->offsets[v + 1] - influences->offsets[v]);
}

static const int32_t *vertex_bones(const refit *r, size_t j)
{
    return r->level_influences->bones + r->level_influences->offsets[j];
}

/* ---- checks --------------------------------------------------------------------------------------------------- */

static sk_status check_side(const sk_triangle_mesh *mesh, const double *rest, const sk_influences *influences,
                            const double *coordinates, size_t bone_count, const char *name, sk_error *error)
{
    if (!mesh || !mesh->triangles || !rest || !influences || !coordinates)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%s: triangles, rest positions, influences and coordinates must "
                       "not be null", name);
    if (influences->vertex_count != mesh->vertex_count)
        return sk_fail(error, SK_ERROR_ARGUMENT, "%s: the influences have %zu vertices but the mesh %zu", name,
                       influences->vertex_count, mesh->vertex_count);
    sk_status status = sk_validate_triangles(mesh, error);
    if (status == SK_OK)
        status = sk_validate_influences(influences, bone_count, error);
    if (status != SK_OK) { /* the same failure, named: the message is copied before it is written again */
        char reason[SK_MESSAGE_SIZE];
        snprintf(reason, sizeof reason, "%s", error ? error->message : "");
        return sk_fail(error, status, "%s: %s", name, reason);
    }
    size_t bad = sk_first_non_finite(rest, 3 * mesh->vertex_count);
    if (bad < 3 * mesh->vertex_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "%s: rest position of vertex %zu is not finite", name, bad / 3);
    bad = sk_first_non_finite(coordinates, 4 * influences->influence_count);
    if (bad < 4 * influences->influence_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "%s: coordinates of influence %zu are not finite", name, bad / 4);
    for (size_t v = 0; v < mesh->vertex_count; ++v) {
        const size_t n = vertex_influences(influences, v);
        if (n > SK_LOD_MAX_VERTEX_INFLUENCES)
            return sk_fail(error, SK_ERROR_ARGUMENT, "%s: vertex %zu has %zu influences (at most %d)", name, v, n,
                           SK_LOD_MAX_VERTEX_INFLUENCES);
        const int32_t *bones = influences->bones + influences->offsets[v];
        for (size_t a = 0; a < n; ++a)
            for (size_t b = a + 1; b < n; ++b)
                if (bones[a] == bones[b])
                    return sk_fail(error, SK_ERROR_ARGUMENT, "%s: vertex %zu has bone %d twice", name, v,
                                   (int)bones[a]);
    }
    return SK_OK;
}

static size_t largest_set(const sk_influences *influences)
{
    size_t most = 1;
    for (size_t v = 0; v < influences->vertex_count; ++v)
        if (vertex_influences(influences, v) > most)
            most = vertex_influences(influences, v);
    return most;
}

/* ---- the correspondence: every sample's closest rest-pose point on the level ----------------------------------- */

static double triangle_area(const double *rest, const int32_t *corner)
{
    const double *a = rest + 3 * (size_t)corner[0], *b = rest + 3 * (size_t)corner[1];
    const double *c = rest + 3 * (size_t)corner[2];
    const double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double n[3];
    sk_cross3(n, u, v);
    return 0.5 * sqrt(sk_dot3(n, n));
}

/* One sample per full-detail triangle, its centroid, at weight its area. The three-point rule (exact for quadratics)
 * took twice the time for the same error at every coarser level of the horse and cow chains (the level is always
 * much coarser than the mesh); only the first level gained (0.81 against 0.84 of the error before the refit). */
static void match_samples(void *context, size_t worker, size_t begin, size_t end)
{
    (void)worker;
    refit *r = context;
    int32_t hint = -1; /* the last sample's triangle: the next one is usually on it or beside it */
    for (size_t t = begin; t < end; ++t) {
        const int32_t *corner = r->mesh->triangles + 3 * t;
        sample *s = r->samples + t;
        double point[3];
        for (int axis = 0; axis < 3; ++axis)
            point[axis] = (r->rest[3 * (size_t)corner[0] + (size_t)axis] +
                           r->rest[3 * (size_t)corner[1] + (size_t)axis] +
                           r->rest[3 * (size_t)corner[2] + (size_t)axis]) / 3.0;
        double w1 = 0.0, w2 = 0.0;
        s->mass = triangle_area(r->rest, corner);
        if (!sk_bvh_closest_point(&r->bvh, point, INFINITY, hint, &s->triangle, &w1, &w2))
            s->triangle = -1, s->mass = 0.0;
        hint = s->triangle;
        s->weight[0] = 1.0 - w1 - w2, s->weight[1] = w1, s->weight[2] = w2;
    }
}

/* Each level vertex's samples (3 * sample + corner), in sample order: the rows' sums then run in one order. */
static int gather_contributions(refit *r)
{
    const size_t V = r->level->vertex_count, S = r->mesh->triangle_count;
    r->contribution_offsets = sk_allocate_zeroed(V + 1, sizeof *r->contribution_offsets);
    r->contributions = sk_allocate(3 * S, sizeof *r->contributions);
    int32_t *fill = sk_allocate(V, sizeof *fill);
    if (!r->contribution_offsets || !r->contributions || !fill) {
        free(fill);
        return 0;
    }
    for (size_t s = 0; s < S; ++s)
        for (int c = 0; r->samples[s].triangle >= 0 && c < 3; ++c)
            ++r->contribution_offsets[r->level->triangles[3 * (size_t)r->samples[s].triangle + (size_t)c] + 1];
    for (size_t v = 0; v < V; ++v)
        r->contribution_offsets[v + 1] += r->contribution_offsets[v];
    memcpy(fill, r->contribution_offsets, V * sizeof *fill);
    for (size_t s = 0; s < S; ++s)
        for (int c = 0; r->samples[s].triangle >= 0 && c < 3; ++c) {
            const int32_t v = r->level->triangles[3 * (size_t)r->samples[s].triangle + (size_t)c];
            r->contributions[fill[v]++] = (int32_t)(3 * s + (size_t)c);
        }
    free(fill);
    return 1;
}

/* ---- the sample mass, row by row over the level's one-rings ---------------------------------------------------- */

static int build_rows(refit *r)
{
    const size_t V = r->level->vertex_count, T = r->level->triangle_count;
    int32_t *degree = sk_allocate_zeroed(V + 1, sizeof *degree);
    if (!degree)
        return 0;
    for (size_t slot = 0; slot < 3 * T; ++slot)
        degree[r->level->triangles[slot] + 1] += 3; /* an upper bound: itself and two neighbours per triangle */
    for (size_t v = 0; v < V; ++v)
        degree[v + 1] += degree[v] + 1;
    int32_t *spare = sk_allocate((size_t)degree[V], sizeof *spare);
    size_t *sizes = sk_allocate_zeroed(V, sizeof *sizes);
    r->row_offsets = sk_allocate(V + 1, sizeof *r->row_offsets);
    int ok = spare && sizes && r->row_offsets;
    for (size_t v = 0; ok && v < V; ++v)
        sk_insert_sorted_bone(spare + degree[v], sizes + v, (int32_t)v); /* any ascending set */
    for (size_t t = 0; ok && t < T; ++t)
        for (int a = 0; a < 3; ++a)
            for (int b = 0; b < 3; ++b) {
                const int32_t u = r->level->triangles[3 * t + (size_t)a], w = r->level->triangles[3 * t + (size_t)b];
                sk_insert_sorted_bone(spare + degree[u], sizes + u, w);
            }
    if (ok) {
        r->row_offsets[0] = 0;
        for (size_t v = 0; v < V; ++v)
            r->row_offsets[v + 1] = r->row_offsets[v] + (int32_t)sizes[v];
        r->row_vertices = sk_allocate((size_t)r->row_offsets[V], sizeof *r->row_vertices);
        r->row_mass = sk_allocate_zeroed((size_t)r->row_offsets[V], sizeof *r->row_mass);
        ok = r->row_vertices && r->row_mass;
        for (size_t v = 0; ok && v < V; ++v)
            memcpy(r->row_vertices + r->row_offsets[v], spare + degree[v], sizes[v] * sizeof *spare);
    }
    SK_FREE_ALL(degree, spare, sizes);
    return ok;
}

static void sum_mass(void *context, size_t worker, size_t begin, size_t end)
{
    (void)worker;
    refit *r = context;
    for (size_t j = begin; j < end; ++j) {
        const int32_t *row = r->row_vertices + r->row_offsets[j];
        double *mass = r->row_mass + r->row_offsets[j];
        const size_t n = (size_t)(r->row_offsets[j + 1] - r->row_offsets[j]);
        for (int32_t k = r->contribution_offsets[j]; k < r->contribution_offsets[j + 1]; ++k) {
            const sample *s = r->samples + r->contributions[k] / 3;
            const double own = s->mass * s->weight[r->contributions[k] % 3];
            for (int c = 0; c < 3; ++c) {
                const int32_t l = r->level->triangles[3 * (size_t)s->triangle + (size_t)c];
                for (size_t i = 0; i < n; ++i)
                    if (row[i] == l) {
                        mass[i] += own * s->weight[c];
                        break;
                    }
            }
        }
    }
}

/* ---- products with P's blocks, one row at a time --------------------------------------------------------------- */

typedef struct bone_sums {
    double *sum;           /* 4 per bone */
    unsigned char *marked; /* per bone */
    int32_t *bones;        /* the bones touched, in the order first met */
    size_t count;
} bone_sums;

static bone_sums worker_sums(const refit *r, size_t worker)
{
    return (bone_sums){r->scratch + 4 * r->bone_count * worker, r->touched_mark + r->bone_count * worker,
                       r->touched + r->bone_count * worker, 0};
}

static void add_to_bone(bone_sums *t, int32_t bone, const double *value, double scale)
{
    if (!t->marked[bone]) {
        t->marked[bone] = 1;
        t->bones[t->count++] = bone;
        memset(t->sum + 4 * (size_t)bone, 0, 4 * sizeof *t->sum);
    }
    for (int c = 0; c < 4; ++c)
        t->sum[4 * (size_t)bone + (size_t)c] += scale * value[c];
}

/* out (4 per influence of level vertex j) = P[I_j, touched] t, then the marks are cleared. */
static void apply_blocks(const refit *r, bone_sums *t, size_t j, double *out)
{
    const int32_t *bones = vertex_bones(r, j);
    const size_t n = vertex_influences(r->level_influences, j);
    double scratch[16];
    for (size_t a = 0; a < n; ++a) {
        double y[4] = {0.0, 0.0, 0.0, 0.0};
        for (size_t k = 0; k < t->count; ++k) {
            const double *block = sk_influence_remover_block_ref(scratch, r->remover, bones[a], t->bones[k]);
            const double *x = t->sum + 4 * (size_t)t->bones[k];
            for (int row = 0; row < 4; ++row)
                y[row] += block[4 * row] * x[0] + block[4 * row + 1] * x[1] + block[4 * row + 2] * x[2] +
                          block[4 * row + 3] * x[3];
        }
        memcpy(out + 4 * a, y, sizeof y);
    }
    for (size_t k = 0; k < t->count; ++k)
        t->marked[t->bones[k]] = 0;
    t->count = 0;
}

/* t += sign * sum_l (m_jl + diagonal [l = j]) x_l, per bone: row j of the sample mass (plus `diagonal` on its own
 * vertex) applied to x. */
static void add_row(const refit *r, bone_sums *t, size_t j, const double *x, double sign, double diagonal)
{
    for (int32_t i = r->row_offsets[j]; i < r->row_offsets[j + 1]; ++i) {
        const size_t l = (size_t)r->row_vertices[i];
        const double scale = sign * (r->row_mass[i] + (l == j ? diagonal : 0.0));
        const int32_t *bones = vertex_bones(r, l);
        const double *values = x + 4 * (size_t)r->level_influences->offsets[l];
        for (size_t k = 0; k < vertex_influences(r->level_influences, l); ++k)
            add_to_bone(t, bones[k], values + 4 * k, scale);
    }
}

typedef struct product {
    refit *r;
    const double *x;
    double *y;
} product;

/* y = A x, A = sum_s w_s B_s^T P B_s + pull blockdiag(P_jj) + ridge. */
static void multiply_rows(void *context, size_t worker, size_t begin, size_t end)
{
    product *p = context;
    const refit *r = p->r;
    bone_sums t = worker_sums(r, worker);
    for (size_t j = begin; j < end; ++j) {
        add_row(r, &t, j, p->x, 1.0, r->pull);
        const size_t at = 4 * (size_t)r->level_influences->offsets[j];
        apply_blocks(r, &t, j, p->y + at);
        for (size_t k = 0; k < 4 * vertex_influences(r->level_influences, j); ++k)
            p->y[at + k] += r->ridge[j] * p->x[at + k];
    }
}

static void multiply(refit *r, const double *x, double *y)
{
    product p = {r, x, y};
    sk_parallel_for(r->level->vertex_count, ROWS_PER_WORKER, r->threads, multiply_rows, &p);
}

/* b_j = P[I_j, :] (z_j - sum_l m_jl x0_l): the right-hand side for the step from x0. z_j sums its samples' points
 * (each the mean of its triangle's three vertices): their weights are summed per full-detail vertex first, in the
 * order the vertices are met, so each vertex's influences are added once (a coarse level's vertex meets a vertex
 * through several samples: on the 134k chain 2-4x fewer additions). */
static void right_hand_rows(void *context, size_t worker, size_t begin, size_t end)
{
    product *p = context;
    const refit *r = p->r;
    bone_sums t = worker_sums(r, worker);
    const size_t V = r->mesh->vertex_count;
    double *weight = r->source_weight + V * worker;
    int32_t *stamp = r->source_stamp + V * worker, *met = r->source_list + V * worker;
    for (size_t j = begin; j < end; ++j) {
        size_t count = 0;
        for (int32_t k = r->contribution_offsets[j]; k < r->contribution_offsets[j + 1]; ++k) {
            const size_t s = (size_t)r->contributions[k] / 3;
            const sample *at = r->samples + s;
            const double own = at->mass * at->weight[r->contributions[k] % 3] / 3.0;
            const int32_t *corner = r->mesh->triangles + 3 * s; /* sample s is triangle s's centroid */
            for (int c = 0; c < 3; ++c) {
                const int32_t v = corner[c];
                if (stamp[v] != (int32_t)j + 1)
                    stamp[v] = (int32_t)j + 1, weight[v] = 0.0, met[count++] = v;
                weight[v] += own;
            }
        }
        for (size_t i = 0; i < count; ++i) {
            const size_t v = (size_t)met[i];
            const int32_t *bones = r->influences->bones + r->influences->offsets[v];
            const double *x = r->coordinates + 4 * (size_t)r->influences->offsets[v];
            for (size_t b = 0; b < vertex_influences(r->influences, v); ++b)
                add_to_bone(&t, bones[b], x + 4 * b, weight[v]);
        }
        add_row(r, &t, j, r->x0, -1.0, 0.0);
        apply_blocks(r, &t, j, p->y + 4 * (size_t)r->level_influences->offsets[j]);
    }
}

/* The mass on each row's own vertex (m_jj), where the diagonal block starts. */
static double own_mass(const refit *r, size_t j)
{
    for (int32_t i = r->row_offsets[j]; i < r->row_offsets[j + 1]; ++i)
        if ((size_t)r->row_vertices[i] == j)
            return r->row_mass[i];
    return 0.0;
}

/* P[I, I] + eps I for the bone set I (d x d, d = 4 n, eps = DIAGONAL_RIDGE times its largest diagonal entry, 1 when
 * that is 0) in `block`; returns eps. */
static double set_block(const refit *r, const int32_t *bones, size_t n, double *block)
{
    const size_t d = 4 * n;
    double scratch[16], largest = 0.0;
    for (size_t a = 0; a < n; ++a)
        for (size_t b = 0; b < n; ++b) {
            const double *p = sk_influence_remover_block_ref(scratch, r->remover, bones[a], bones[b]);
            for (size_t row = 0; row < 4; ++row)
                for (size_t col = 0; col < 4; ++col)
                    block[(4 * a + row) * d + 4 * b + col] = p[4 * row + col];
        }
    for (size_t k = 0; k < d; ++k)
        largest = fmax(largest, block[k * d + k]);
    const double eps = largest > 0.0 ? DIAGONAL_RIDGE * largest : 1.0;
    for (size_t k = 0; k < d; ++k)
        block[k * d + k] += eps;
    return eps;
}

/* Factors the set's P[I, I] + eps I into `block`, lower Cholesky, column-major (the block is symmetric: its rows
 * are its columns, no transposed copy; the _work call skips LAPACKE's NaN scan, the inputs were checked finite).
 * Returns 0 when it is not positive definite (eps makes that impossible; checked). */
static int factor_set(const refit *r, const int32_t *bones, size_t n, double *block, double *eps)
{
    *eps = set_block(r, bones, n, block);
    return n == 0 || LAPACKE_dpotrf_work(LAPACK_COL_MAJOR, 'L', (lapack_int)(4 * n), block, (lapack_int)(4 * n)) == 0;
}

/* x = (L L^T)^-1 x for a d x d lower factor L, column-major, x zero before entry `first`: two substitutions, too
 * small for a BLAS call. */
static void substitute(const double *factor, size_t d, size_t first, double *x)
{
    for (size_t k = first; k < d; ++k) { /* by columns: each reads one contiguous column of L */
        const double *column = factor + k * d;
        x[k] /= column[k];
        for (size_t i = k + 1; i < d; ++i)
            x[i] -= column[i] * x[k];
    }
    for (size_t i = d; i-- > 0;) { /* column i of L below the diagonal is contiguous: four sums break the chain */
        const double *column = factor + i * d;
        double sum[4] = {0.0, 0.0, 0.0, 0.0};
        size_t k = i + 1;
        for (; k + 4 <= d; k += 4)
            for (int lane = 0; lane < 4; ++lane)
                sum[lane] += column[k + (size_t)lane] * x[k + (size_t)lane];
        for (; k < d; ++k)
            sum[0] += column[k] * x[k];
        x[i] = (x[i] - ((sum[0] + sum[1]) + (sum[2] + sum[3]))) / column[i];
    }
}

/*
 * The diagonal blocks: vertex j's is s_j (P[I_j, I_j] + eps_I I) with s_j = m_jj + pull, so its factor is the
 * factor of its bone set's P[I, I] + eps_I I scaled by sqrt(s_j), and the vertices of one set share one
 * factorisation. Sets are told apart by their bones in order (a sequential pass, so the numbering is the same on
 * any thread count); their inverses are kept while they fit FACTOR_BUDGET doubles, else each preconditioner
 * application factors the set again.
 */
typedef struct set_table {
    int32_t *slots; /* open addressing: a set's first vertex, -1 empty */
    size_t mask;
} set_table;

static uint64_t hash_set(const int32_t *bones, size_t n)
{
    uint64_t hash = 1469598103934665603u ^ n;
    for (size_t k = 0; k < n; ++k)
        hash = (hash ^ (uint32_t)bones[k]) * 1099511628211u;
    return hash;
}

static int same_set(const refit *r, size_t a, size_t b)
{
    const size_t n = vertex_influences(r->level_influences, a);
    return n == vertex_influences(r->level_influences, b) &&
           memcmp(vertex_bones(r, a), vertex_bones(r, b), n * sizeof(int32_t)) == 0;
}

/* r->set_of[j]: the index of j's set among the distinct ones (r->set_count), each first met at r->set_vertex[id]. */
static int number_sets(refit *r)
{
    const size_t V = r->level->vertex_count;
    size_t capacity = 16;
    while (capacity < 2 * V)
        capacity *= 2;
    set_table table = {sk_allocate(capacity, sizeof(int32_t)), capacity - 1};
    int32_t *id_at = sk_allocate(capacity, sizeof(int32_t));
    r->set_of = sk_allocate(V, sizeof *r->set_of);
    r->set_vertex = sk_allocate(V, sizeof *r->set_vertex);
    const int ok = table.slots && id_at && r->set_of && r->set_vertex;
    for (size_t i = 0; ok && i < capacity; ++i)
        table.slots[i] = -1;
    for (size_t j = 0; ok && j < V; ++j) {
        size_t at = (size_t)hash_set(vertex_bones(r, j), vertex_influences(r->level_influences, j)) & table.mask;
        while (table.slots[at] >= 0 && !same_set(r, (size_t)table.slots[at], j))
            at = (at + 1) & table.mask;
        if (table.slots[at] < 0) {
            table.slots[at] = (int32_t)j;
            id_at[at] = (int32_t)r->set_count;
            r->set_vertex[r->set_count++] = (int32_t)j;
        }
        r->set_of[j] = id_at[at];
    }
    SK_FREE_ALL(table.slots, id_at);
    return ok;
}

static size_t set_size(const refit *r, size_t set)
{
    const size_t d = 4 * vertex_influences(r->level_influences, (size_t)r->set_vertex[set]);
    return d * d;
}

typedef struct preconditioning {
    refit *r;
    const double *residual;
    double *out;
    int failed; /* a block that is not positive definite */
} preconditioning;

/* The set's (P[I, I] + eps I)^-1, whole (both triangles), in `block`: a vertex's preconditioner is then one
 * product with contiguous columns instead of two substitutions, and there are far fewer sets than vertices (159 on
 * the 67k-vertex first level of the large chain). */
static int invert_set(const refit *r, const int32_t *bones, size_t n, double *factor, double *inverse, double *eps)
{
    const size_t d = 4 * n;
    if (!factor_set(r, bones, n, factor, eps))
        return 0;
    /* column by column from the factor (dpotri would run OpenBLAS's threaded BLAS 3 on these small blocks) */
    memset(inverse, 0, d * d * sizeof *inverse);
    for (size_t col = 0; col < d; ++col) {
        inverse[col * d + col] = 1.0;
        substitute(factor, d, col, inverse + col * d);
    }
    return 1;
}

static void keep_inverses(void *context, size_t worker, size_t begin, size_t end)
{
    preconditioning *c = context;
    const refit *r = c->r;
    for (size_t set = begin; set < end; ++set) {
        const size_t j = (size_t)r->set_vertex[set];
        if (!invert_set(r, vertex_bones(r, j), vertex_influences(r->level_influences, j),
                        r->block + worker * r->block_stride, r->inverses + r->inverse_offsets[set], r->set_eps + set))
            c->failed = 1;
    }
}

/* Each set's eps, and its inverse when they fit FACTOR_BUDGET; then every vertex's scale and ridge s_j eps_I. */
static int factor_sets(refit *r)
{
    size_t total = 0;
    for (size_t set = 0; set < r->set_count; ++set)
        total += set_size(r, set);
    r->set_eps = sk_allocate(r->set_count, sizeof *r->set_eps);
    r->scale = sk_allocate(r->level->vertex_count, sizeof *r->scale);
    if (!r->set_eps || !r->scale)
        return 0;
    if (total <= FACTOR_BUDGET) {
        r->inverse_offsets = sk_allocate(r->set_count, sizeof *r->inverse_offsets);
        r->inverses = sk_allocate(total, sizeof *r->inverses);
        if (!r->inverse_offsets || !r->inverses) { /* factoring at every step needs no more memory */
            SK_FREE_ALL(r->inverse_offsets, r->inverses);
            r->inverse_offsets = NULL, r->inverses = NULL;
        }
    }
    preconditioning c = {r, NULL, NULL, 0};
    if (r->inverses) {
        for (size_t set = 0, at = 0; set < r->set_count; at += set_size(r, set), ++set)
            r->inverse_offsets[set] = at;
        /* no more workers than the row passes have scratch for */
        sk_parallel_for(r->set_count, (r->set_count + r->workers - 1) / r->workers, r->threads, keep_inverses, &c);
    } else {
        for (size_t set = 0; set < r->set_count; ++set) {
            const size_t j = (size_t)r->set_vertex[set];
            r->set_eps[set] = set_block(r, vertex_bones(r, j), vertex_influences(r->level_influences, j), r->block);
        }
    }
    for (size_t j = 0; j < r->level->vertex_count; ++j) {
        const double s = own_mass(r, j) + r->pull;
        /* a vertex no sample reaches has a zero row: any positive scale preconditions it */
        r->scale[j] = s > 0.0 ? s : 1.0;
        r->ridge[j] = (s > 0.0 ? s : 1.0) * r->set_eps[r->set_of[j]];
    }
    return !c.failed;
}

/* out_j = D_j^-1 residual_j: the block-Jacobi preconditioner, from the kept set inverses or factored again. */
static void precondition_rows(void *context, size_t worker, size_t begin, size_t end)
{
    preconditioning *c = context;
    refit *r = c->r;
    double *block = r->block + worker * r->block_stride;
    for (size_t j = begin; j < end; ++j) {
        const size_t at = 4 * (size_t)r->level_influences->offsets[j];
        const size_t n = vertex_influences(r->level_influences, j), d = 4 * n;
        double *out = c->out + at;
        const double *residual = c->residual + at;
        if (r->inverses) {
            const double *inverse = r->inverses + r->inverse_offsets[r->set_of[j]];
            memset(out, 0, d * sizeof *out);
            for (size_t k = 0; k < d; ++k) {
                const double x = residual[k] / r->scale[j];
                for (size_t i = 0; i < d; ++i)
                    out[i] += inverse[k * d + i] * x;
            }
            continue;
        }
        double eps;
        if (!factor_set(r, vertex_bones(r, j), n, block, &eps)) {
            c->failed = 1;
            continue;
        }
        for (size_t k = 0; k < d; ++k)
            out[k] = residual[k] / r->scale[j];
        substitute(block, d, 0, out);
    }
}

static double dot(const double *a, const double *b, size_t n)
{
    double sum = 0.0;
    for (size_t i = 0; i < n; ++i)
        sum += a[i] * b[i];
    return sum;
}

/* Removes from each vertex's step the mean of its weight components (the fourth of each influence's four): the
 * weights of an animation-space vertex sum to one (a translated skeleton translates it), and the step keeps them so.
 * CG runs in that subspace: the right-hand side, the preconditioned residuals and the products are projected. */
static void project_weights(const refit *r, double *x)
{
    for (size_t j = 0; j < r->level->vertex_count; ++j) {
        const size_t n = vertex_influences(r->level_influences, j);
        double *row = x + 4 * (size_t)r->level_influences->offsets[j], mean = 0.0;
        for (size_t k = 0; k < n; ++k)
            mean += row[4 * k + 3];
        mean /= (double)(n ? n : 1);
        for (size_t k = 0; k < n; ++k)
            row[4 * k + 3] -= mean;
    }
}

static void precondition(refit *r, preconditioning *c)
{
    sk_parallel_for(r->level->vertex_count, ROWS_PER_WORKER, r->threads, precondition_rows, c);
    project_weights(r, c->out);
}

/* A few preconditioned CG steps on A delta = b from delta = 0, in the subspace of steps that keep every vertex's
 * weight sum (project_weights); x = x0 + delta. */
static sk_status solve(refit *r, double *x, const sk_lod_refit_options *options, sk_lod_refit_report *report,
                       sk_progress_fn progress, void *user, sk_error *error)
{
    const size_t n = r->unknowns;
    double *residual = sk_allocate(n, sizeof *residual), *z = sk_allocate(n, sizeof *z);
    double *direction = sk_allocate(n, sizeof *direction), *q = sk_allocate(n, sizeof *q);
    double *delta = sk_allocate_zeroed(n, sizeof *delta);
    sk_status status = SK_OK;
    if (!residual || !z || !direction || !q || !delta)
        status = sk_fail(error, SK_ERROR_MEMORY, "out of memory for the refit's %zu unknowns", n);
    if (status == SK_OK) {
        product rhs = {r, NULL, residual};
        sk_parallel_for(r->level->vertex_count, ROWS_PER_WORKER, r->threads, right_hand_rows, &rhs);
        project_weights(r, residual);
        preconditioning c = {r, residual, z, 0};
        precondition(r, &c);
        memcpy(direction, z, n * sizeof *z);
        double rz = dot(residual, z, n);
        const double start = rz;
        report->start_residual = sqrt(fmax(start, 0.0));
        for (size_t step = 0; step < options->max_steps && rz > options->tolerance * options->tolerance * start &&
                              !c.failed; ++step) {
            multiply(r, direction, q);
            project_weights(r, q);
            const double curvature = dot(direction, q, n);
            if (!(curvature > 0.0))
                break;
            const double alpha = rz / curvature;
            for (size_t i = 0; i < n; ++i)
                delta[i] += alpha * direction[i], residual[i] -= alpha * q[i];
            precondition(r, &c);
            const double next = dot(residual, z, n);
            for (size_t i = 0; i < n; ++i)
                direction[i] = z[i] + next / rz * direction[i];
            rz = next;
            report->steps = step + 1;
            if (progress && progress(user, 0.5 + 0.5 * (double)(step + 1) / (double)options->max_steps)) {
                status = sk_fail(error, SK_ERROR_CANCELLED, "refit cancelled after %zu steps", step + 1);
                break;
            }
        }
        if (c.failed && status == SK_OK)
            status = sk_fail(error, SK_ERROR_LAPACK, "a vertex's block of the refit is not positive definite");
        report->final_residual = sqrt(fmax(rz, 0.0));
    }
    if (status == SK_OK)
        for (size_t i = 0; i < n; ++i)
            x[i] = r->x0[i] + delta[i];
    SK_FREE_ALL(residual, z, direction, q, delta);
    return status;
}

static void free_refit(refit *r)
{
    sk_influence_remover_free(r->remover);
    sk_bvh_free(&r->bvh);
    SK_FREE_ALL(r->samples, r->row_offsets, r->row_vertices, r->row_mass, r->contribution_offsets, r->contributions,
                r->ridge, r->block, r->inverses, r->inverse_offsets, r->set_of, r->set_vertex, r->set_eps, r->scale,
                r->scratch, r->touched_mark, r->touched, r->source_weight, r->source_stamp, r->source_list);
}

/* The correspondence, the sample mass and the workers' scratch. */
static sk_status prepare(refit *r, const sk_lod_refit_options *options, sk_error *error)
{
    const size_t V = r->level->vertex_count, S = r->mesh->triangle_count;
    r->surface = (sk_bake_surface){r->level->triangles, r->level_rest, NULL, NULL, r->level->triangle_count, V};
    sk_status status = sk_bvh_build(&r->bvh, &r->surface, error);
    if (status != SK_OK)
        return status;
    const size_t workers = sk_worker_count(V, ROWS_PER_WORKER, options->thread_count);
    r->workers = workers;
    const size_t largest = 4 * largest_set(r->level_influences);
    r->block_stride = largest * largest;
    r->samples = sk_allocate(S, sizeof *r->samples);
    r->ridge = sk_allocate(V, sizeof *r->ridge);
    r->block = sk_allocate(workers * r->block_stride, sizeof *r->block);
    r->scratch = sk_allocate(workers * 4 * r->bone_count, sizeof *r->scratch);
    r->touched_mark = sk_allocate_zeroed(workers * r->bone_count, 1);
    r->touched = sk_allocate(workers * r->bone_count, sizeof *r->touched);
    r->source_weight = sk_allocate(workers * r->mesh->vertex_count, sizeof *r->source_weight);
    r->source_stamp = sk_allocate_zeroed(workers * r->mesh->vertex_count, sizeof *r->source_stamp);
    r->source_list = sk_allocate(workers * r->mesh->vertex_count, sizeof *r->source_list);
    if (!r->samples || !r->ridge || !r->block || !r->scratch || !r->touched_mark || !r->touched ||
        !r->source_weight || !r->source_stamp || !r->source_list)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the refit's %zu samples", S);
    sk_parallel_for(r->mesh->triangle_count, ROWS_PER_WORKER, options->thread_count, match_samples, r);
    if (!gather_contributions(r) || !build_rows(r))
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for the refit's sample mass (%zu vertices)", V);
    sk_parallel_for(V, ROWS_PER_WORKER, options->thread_count, sum_mass, r);
    double total = 0.0;
    for (size_t i = 0; i < (size_t)r->row_offsets[V]; ++i)
        total += r->row_mass[i];
    r->pull = options->pull * total / (double)(V ? V : 1);
    if (!number_sets(r))
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory numbering the refit's influence sets");
    if (!factor_sets(r))
        return sk_fail(error, SK_ERROR_LAPACK, "an influence set's block of the refit is not positive definite");
    return SK_OK;
}

static sk_status check_options(const sk_lod_refit_options *options, sk_error *error)
{
    if (!options)
        return sk_fail(error, SK_ERROR_ARGUMENT, "options must not be null");
    if (!(options->pull >= 0.0) || !isfinite(options->pull))
        return sk_fail(error, SK_ERROR_ARGUMENT, "pull %g must be finite and >= 0", options->pull);
    if (!(options->tolerance >= 0.0) || !(options->tolerance < 1.0))
        return sk_fail(error, SK_ERROR_ARGUMENT, "tolerance %g must lie in [0, 1)", options->tolerance);
    if (options->max_steps > 1000)
        return sk_fail(error, SK_ERROR_ARGUMENT, "max_steps %zu exceeds 1000", options->max_steps);
    return SK_OK;
}

sk_status sk_lod_refit(double *coordinates_out, sk_lod_refit_report *report, const sk_triangle_mesh *level,
                       const double *level_rest, const sk_influences *level_influences,
                       const double *level_coordinates, const sk_triangle_mesh *mesh, const double *rest_positions,
                       const sk_influences *influences, const double *coordinates,
                       const sk_pose_statistics *statistics, const sk_lod_refit_options *options,
                       sk_progress_fn progress, void *progress_user, sk_error *error)
{
    if (!coordinates_out || !report || !statistics)
        return sk_fail(error, SK_ERROR_ARGUMENT, "coordinates_out, report and statistics must not be null");
    memset(report, 0, sizeof *report);
    sk_status status = check_options(options, error);
    if (status == SK_OK)
        status = check_side(level, level_rest, level_influences, level_coordinates, statistics->bone_count, "level",
                            error);
    if (status == SK_OK)
        status = check_side(mesh, rest_positions, influences, coordinates, statistics->bone_count, "mesh", error);
    if (status == SK_OK && level->triangle_count == 0)
        status = sk_fail(error, SK_ERROR_ARGUMENT, "level: has no triangles to match the mesh on");
    if (status != SK_OK)
        return status;
    refit r;
    memset(&r, 0, sizeof r);
    r.level = level, r.mesh = mesh, r.level_influences = level_influences, r.influences = influences;
    r.rest = rest_positions, r.level_rest = level_rest, r.coordinates = coordinates, r.x0 = level_coordinates;
    r.bone_count = statistics->bone_count, r.unknowns = 4 * level_influences->influence_count;
    r.threads = options->thread_count;
    status = sk_influence_remover_create(&r.remover, statistics, largest_set(level_influences), error);
    if (status == SK_OK)
        status = prepare(&r, options, error);
    if (status == SK_OK && progress && progress(progress_user, 0.5))
        status = sk_fail(error, SK_ERROR_CANCELLED, "refit cancelled after matching the samples");
    if (status == SK_OK) {
        report->samples = mesh->triangle_count;
        for (size_t s = 0; s < report->samples; ++s)
            report->unmatched += r.samples[s].triangle < 0;
        report->influence_sets = r.set_count, report->kept_factors = r.inverses != NULL;
        status = solve(&r, coordinates_out, options, report, progress, progress_user, error);
    }
    free_refit(&r);
    return status == SK_OK ? sk_succeed(error) : status;
}
