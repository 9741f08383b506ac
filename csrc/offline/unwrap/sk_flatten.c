/*
 * Flattening charts to the plane (Merry 2007, section 5.3): LSCM (Levy et al. 2002) in the metric given by
 * each triangle's squared edge lengths, the passes of section 5.3 (free boundary, straight pinned boundary,
 * unit-circle fallback, extra corners), Sander et al. 2001's L2 stretch minimised by global steps and per-vertex
 * Newton steps that never flip a triangle, and the splits that leave no chart overlapping itself and no
 * triangle flipped.
 *
 * Linear solver: preconditioned conjugate gradients over a block-CSR matrix (one 2x2 block per pair of
 * neighbouring vertices, block-Jacobi preconditioner). Once two or more vertices are pinned, LSCM's normal
 * equations are symmetric positive definite, which is what CG needs; no sparse Cholesky library is among
 * the project's dependencies (LAPACK is dense only and a dense factorisation of a 17k-triangle chart would
 * take gigabytes), while CG needs O(nnz) memory and only matrix-vector products, so it scales with the chart.
 *
 * Charts are independent: workers take them largest first from a shared counter, so one big chart does not
 * leave the other workers idle. Nothing depends on the order in which charts are done, so the result does
 * not depend on the thread count.
 */
#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "sk_mesh.h"

/* A uv triangle is degenerate when twice its area is below this fraction of its longest edge squared. */
#define DEGENERATE_UV_RATIO 1e-12
/* A metric triangle must have g11 g22 - g12^2 above this fraction of g11 g22 (sine squared of its angle). */
#define DEGENERATE_METRIC_RATIO 1e-14
#define CG_RELATIVE_TOLERANCE 1e-12
/* The global steps of the stretch optimisation only need a direction: a loose solve. */
#define GLOBAL_CG_TOLERANCE 1e-2
#define GLOBAL_CG_STEPS 20
/* Newton steps of the stretch optimisation: sufficient decrease, halvings before a vertex is left alone. */
#define ARMIJO_FRACTION 1e-4
#define BACKTRACKING_STEPS 30
#define STRETCH_RELATIVE_IMPROVEMENT 1e-6
/* Each extra corner costs a pair of solves; past this many, straightening is given up for the chart. */
#define EXTRA_CORNER_LIMIT 24
#define TWO_PI 6.28318530717958647692

/* ---------------------------------------------------------------------------------------------
 * Metric triangles and uv triangles
 * ------------------------------------------------------------------------------------------- */

/* The Gram matrix of e1 = y_b - y_a, e2 = y_c - y_a from the squared lengths of ab, bc, ca (polarisation). */
static void gram_from_lengths(double gram[3], const double lengths_sq[3])
{
    gram[0] = lengths_sq[0];
    gram[1] = (lengths_sq[0] + lengths_sq[2] - lengths_sq[1]) / 2;
    gram[2] = lengths_sq[2];
}

static double gram_area(const double gram[3])
{
    const double determinant = gram[0] * gram[2] - gram[1] * gram[1];
    return determinant > 0 ? sqrt(determinant) / 2 : 0.0;
}

static sk_status check_metric(const double *edge_lengths_sq, size_t triangle_count, sk_error *error)
{
    for (size_t t = 0; t < triangle_count; ++t) {
        const double *lengths = edge_lengths_sq + 3 * t;
        if (!sk_all_finite(lengths, 3))
            return sk_fail(error, SK_ERROR_NOT_FINITE, "triangle %zu has a squared edge length that is not finite", t);
        double gram[3];
        gram_from_lengths(gram, lengths);
        const double determinant = gram[0] * gram[2] - gram[1] * gram[1];
        if (!(lengths[0] > 0 && lengths[1] > 0 && lengths[2] > 0) ||
            !(determinant > DEGENERATE_METRIC_RATIO * gram[0] * gram[2]))
            return sk_fail(error, SK_ERROR_ARGUMENT,
                           "triangle %zu has a non-positive metric area (squared edge lengths %g, %g, %g: degenerate "
                           "or not a triangle)", t, lengths[0], lengths[1], lengths[2]);
    }
    return SK_OK;
}

static double cross2(double ax, double ay, double bx, double by)
{
    return ax * by - ay * bx;
}

/* Twice the signed area of uv triangle (a, b, c), or 0 when it is flipped or degenerate. */
static double valid_double_area(const double a[2], const double b[2], const double c[2])
{
    const double twice_area = cross2(b[0] - a[0], b[1] - a[1], c[0] - a[0], c[1] - a[1]);
    double longest = 0.0;
    const double *points[3] = {a, b, c};
    for (int k = 0; k < 3; ++k) {
        const double *p = points[k], *q = points[(k + 1) % 3];
        const double length_sq = (q[0] - p[0]) * (q[0] - p[0]) + (q[1] - p[1]) * (q[1] - p[1]);
        longest = length_sq > longest ? length_sq : longest;
    }
    return twice_area > DEGENERATE_UV_RATIO * longest ? twice_area : 0.0;
}

/*
 * sigma1^2 + sigma2^2 of the map from uv to the metric (eq. 5.6-5.8): J = (e1 e2) M, with M the rows of S for
 * the second and third vertex (the first row is minus their sum, so it drops out against edge vectors), and
 * tr(J^T J) = tr(M^T Gram M). Returns INFINITY for a flipped or degenerate uv triangle; *twice_uv_area
 * receives twice the uv area (0 when invalid).
 */
static double singular_values_sq(const double gram[3], const double a[2], const double b[2], const double c[2],
                                 double *twice_uv_area)
{
    const double d = valid_double_area(a, b, c);
    *twice_uv_area = d;
    if (d == 0.0)
        return INFINITY;
    const double b_s = (c[1] - a[1]) / d, b_t = (a[0] - c[0]) / d; /* coefficients of y_b */
    const double c_s = (a[1] - b[1]) / d, c_t = (b[0] - a[0]) / d; /* coefficients of y_c */
    return gram[0] * (b_s * b_s + b_t * b_t) + 2 * gram[1] * (b_s * c_s + b_t * c_t) +
           gram[2] * (c_s * c_s + c_t * c_t);
}

/* ---------------------------------------------------------------------------------------------
 * A chart as a mesh of its own: local vertices, adjacency, the boundary loop
 * ------------------------------------------------------------------------------------------- */

typedef struct chart_mesh {
    size_t triangle_count, vertex_count, boundary_count;
    const int32_t *triangles;  /* the mesh triangle of each local triangle (not owned) */
    int32_t *corner;           /* 3 per triangle: the local vertex at each corner */
    int32_t *vertex;           /* the mesh vertex of each local vertex */
    double *gram;              /* 3 per triangle: g11, g12, g22 */
    double *area;              /* metric area per triangle */
    int32_t *across;           /* 3 per triangle: the triangle across edge k (corner k to k+1), or -1 */
    int32_t *incident_offsets; /* per local vertex: its triangles, CSR */
    int32_t *incident;
    int32_t *ring_offsets;     /* per local vertex: its neighbours and itself, sorted, CSR */
    int32_t *ring;
    double *ring_length;       /* metric length of the edge to each ring entry (0 for the vertex itself) */
    int32_t *loop;             /* the boundary loop, counterclockwise (interior on the left) */
    int32_t *loop_triangle;    /* the triangle of boundary edge loop[i] -> loop[i + 1] */
    double *loop_length;       /* the metric length of that edge */
    unsigned char *on_boundary;
} chart_mesh;

static void free_chart_mesh(chart_mesh *m)
{
    free(m->corner);
    free(m->vertex);
    free(m->gram);
    free(m->area);
    free(m->across);
    free(m->incident_offsets);
    free(m->incident);
    free(m->ring_offsets);
    free(m->ring);
    free(m->ring_length);
    free(m->loop);
    free(m->loop_triangle);
    free(m->loop_length);
    free(m->on_boundary);
    memset(m, 0, sizeof *m);
}

typedef enum build_outcome { BUILT, DISCONNECTED, NOT_DISC, REFUSED, OUT_OF_MEMORY } build_outcome;

typedef struct flatten_input {
    const int32_t *triangles;
    const double *edge_lengths_sq;
    const unsigned char *corners;
    size_t triangle_count, vertex_count;
    sk_flatten_options options;
} flatten_input;

/* Labels each triangle 0 or 1 by the source it is fewer steps from across interior edges (ties to the first). */
static void two_source_labels(int32_t *labels, int32_t *queue, const chart_mesh *m, int32_t first, int32_t second)
{
    for (size_t t = 0; t < m->triangle_count; ++t)
        labels[t] = -1;
    size_t head = 0, tail = 0;
    labels[first] = 0;
    labels[second] = 1;
    queue[tail++] = first;
    queue[tail++] = second;
    while (head < tail) {
        const size_t t = (size_t)queue[head++];
        for (int k = 0; k < 3; ++k) {
            const int32_t next = m->across[3 * t + (size_t)k];
            if (next >= 0 && labels[next] < 0) {
                labels[next] = labels[t];
                queue[tail++] = next;
            }
        }
    }
}

/*
 * Splits a connected piece of two or more triangles in two: the triangles nearer to `seed` than to the
 * triangle farthest from it (breadth-first over faces), and the rest.
 */
static void split_around(int32_t *labels, int32_t *queue, const chart_mesh *m, int32_t seed)
{
    for (size_t t = 0; t < m->triangle_count; ++t)
        labels[t] = -1;
    size_t head = 0, tail = 0;
    labels[seed] = 0;
    queue[tail++] = seed;
    while (head < tail) {
        const size_t t = (size_t)queue[head++];
        for (int k = 0; k < 3; ++k) {
            const int32_t next = m->across[3 * t + (size_t)k];
            if (next >= 0 && labels[next] < 0) {
                labels[next] = 0;
                queue[tail++] = next;
            }
        }
    }
    two_source_labels(labels, queue, m, seed, queue[tail - 1]);
}

/* The position of vertex j in vertex i's ring, or -1. */
static int32_t ring_slot(const chart_mesh *m, int32_t i, int32_t j)
{
    for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s)
        if (m->ring[s] == j)
            return s;
    return -1;
}

/* The metric length of edge e of the local mesh, from its last triangle's squared lengths (the triangles on
 * either side may disagree a little when the metric is given per triangle). */
static double local_edge_length(const chart_mesh *m, const sk_edge_flaps *local, const flatten_input *in, int32_t e)
{
    const int32_t t = local->edge_triangles[2 * e + (sk_is_border_edge(local, e) ? 0 : 1)];
    const int32_t side = sk_edge_slot(local, e, t) % 3;
    return sqrt(in->edge_lengths_sq[3 * (size_t)m->triangles[t] + (size_t)side]);
}

/*
 * Adjacency over the local vertices: across[], the triangles at each vertex (incident), and each vertex's ring
 * (its neighbours and itself, ascending, with the metric length to each). The local edges are numbered by their
 * vertex pairs, so a vertex's edges list its lower neighbours ascending, then its higher ones.
 */
static int build_adjacency(chart_mesh *m, sk_edge_flaps *local, const flatten_input *in)
{
    const size_t n = m->triangle_count, v = m->vertex_count;
    m->across = sk_allocate(3 * n, sizeof *m->across);
    m->ring_offsets = sk_allocate(v + 1, sizeof *m->ring_offsets);
    m->ring = sk_allocate(2 * local->edge_count + v, sizeof *m->ring);
    m->ring_length = sk_allocate_zeroed(2 * local->edge_count + v, sizeof *m->ring_length);
    if (!m->across || !m->ring_offsets || !m->ring || !m->ring_length)
        return 0;
    for (size_t slot = 0; slot < 3 * n; ++slot)
        m->across[slot] = sk_edge_other_triangle(local, local->triangle_edges[slot], (int32_t)(slot / 3));
    size_t size = 0;
    for (size_t i = 0; i < v; ++i) {
        m->ring_offsets[i] = (int32_t)size;
        int self_placed = 0;
        for (int32_t k = local->vertex_edge_offsets[i]; k < local->vertex_edge_offsets[i + 1]; ++k) {
            const int32_t e = local->vertex_edges[k], j = sk_edge_other_vertex(local, e, (int32_t)i);
            if (!self_placed && j > (int32_t)i) {
                m->ring[size++] = (int32_t)i;
                self_placed = 1;
            }
            m->ring_length[size] = local_edge_length(m, local, in, e);
            m->ring[size++] = j;
        }
        if (!self_placed)
            m->ring[size++] = (int32_t)i;
    }
    m->ring_offsets[v] = (int32_t)size;
    /* the triangles at each vertex, taken over from the flaps */
    m->incident_offsets = local->vertex_triangle_offsets;
    m->incident = local->vertex_triangles;
    local->vertex_triangle_offsets = local->vertex_triangles = NULL;
    return 1;
}

/* The first border loop as the chart's boundary (with its triangles and metric lengths); *loops: how many. */
static int trace_boundary(chart_mesh *m, const sk_edge_flaps *local, const flatten_input *in, long *loops)
{
    size_t border = 0;
    for (size_t e = 0; e < local->edge_count; ++e)
        border += sk_is_border_edge(local, (int32_t)e);
    int32_t *offsets = sk_allocate(border + 1, sizeof *offsets), *edges = sk_allocate(border, sizeof *edges);
    m->loop = sk_allocate(border, sizeof *m->loop);
    m->loop_triangle = sk_allocate(border, sizeof *m->loop_triangle);
    m->loop_length = sk_allocate(border, sizeof *m->loop_length);
    m->on_boundary = sk_allocate_zeroed(m->vertex_count, 1);
    int ok = offsets && edges && m->loop && m->loop_triangle && m->loop_length && m->on_boundary;
    *loops = ok ? sk_boundary_loops(offsets, m->loop, edges, local) : -1;
    ok = *loops >= 0;
    if (ok) {
        m->boundary_count = *loops > 0 ? (size_t)offsets[1] : 0;
        for (size_t i = 0; i < (size_t)offsets[*loops]; ++i)
            m->on_boundary[m->loop[i]] = 1;
        for (size_t i = 0; i < m->boundary_count; ++i) {
            m->loop_triangle[i] = local->edge_triangles[2 * edges[i]];
            m->loop_length[i] = local_edge_length(m, local, in, edges[i]);
        }
    }
    free(offsets);
    free(edges);
    return ok;
}

/*
 * Builds the chart's own mesh from `count` mesh triangles: the corners of each mesh vertex that are joined
 * round a fan become one local vertex (a vertex where the chart touches itself becomes two), and non-manifold
 * and inconsistently oriented edges are refused. DISCONNECTED leaves component labels (one per triangle) in
 * `labels`; NOT_DISC (closed, or more than one boundary loop) leaves the reason in *error and a split of the
 * piece in two in `labels` (*component_count = 2); REFUSED leaves the reason in *error.
 */
static build_outcome build_chart_mesh(chart_mesh *m, const flatten_input *in, const int32_t *triangles, size_t count,
                                      size_t chart, int32_t *labels, size_t *component_count, sk_error *error)
{
    memset(m, 0, sizeof *m);
    m->triangles = triangles;
    m->triangle_count = count;
    m->gram = sk_allocate(3 * count, sizeof *m->gram);
    m->area = sk_allocate(count, sizeof *m->area);
    m->corner = sk_allocate(3 * count, sizeof *m->corner);
    int32_t *mesh_corners = sk_allocate(3 * count, sizeof *mesh_corners), *queue = sk_allocate(count, sizeof *queue);
    sk_edge_flaps edges = {0}, local = {0};
    build_outcome outcome = OUT_OF_MEMORY;
    if (!m->gram || !m->area || !m->corner || !mesh_corners || !queue)
        goto done;
    for (size_t t = 0; t < count; ++t) {
        gram_from_lengths(m->gram + 3 * t, in->edge_lengths_sq + 3 * (size_t)triangles[t]);
        m->area[t] = gram_area(m->gram + 3 * t);
        for (int k = 0; k < 3; ++k)
            mesh_corners[3 * t + (size_t)k] = in->triangles[3 * (size_t)triangles[t] + (size_t)k];
    }
    sk_edge_defect defect;
    const sk_status built = sk_edge_flaps_build(&edges, mesh_corners, count, 0, &defect); /* edges alone */
    if (built == SK_ERROR_ARGUMENT) {
        sk_fail(error, SK_ERROR_ARGUMENT, "chart %zu is not a disc: edge (%d, %d) is shared by %zu of its triangles",
                chart, defect.vertices[0], defect.vertices[1], defect.triangle_count);
        outcome = REFUSED;
    }
    if (built != SK_OK)
        goto done;
    for (size_t e = 0; e < edges.edge_count; ++e)
        if (sk_edge_runs_same_way(&edges, (int32_t)e)) {
            sk_fail(error, SK_ERROR_ARGUMENT,
                    "chart %zu: triangles %d and %d have opposite orientations across edge (%d, %d)", chart,
                    m->triangles[edges.edge_triangles[2 * e]], m->triangles[edges.edge_triangles[2 * e + 1]],
                    edges.edge_vertices[2 * e], edges.edge_vertices[2 * e + 1]);
            outcome = REFUSED;
            goto done;
        }
    const long components = sk_triangle_components(labels, &edges, NULL);
    const long fans = components < 0 ? -1 : sk_corner_fans(m->corner, &edges, NULL);
    if (fans < 0)
        goto done;
    *component_count = (size_t)components;
    if (components > 1) {
        outcome = DISCONNECTED;
        goto done;
    }
    m->vertex_count = (size_t)fans;
    m->vertex = sk_allocate(m->vertex_count, sizeof *m->vertex);
    if (!m->vertex)
        goto done;
    for (size_t c = 0; c < 3 * count; ++c)
        m->vertex[m->corner[c]] = mesh_corners[c];
    long loops = 0;
    if (sk_edge_flaps_build(&local, m->corner, count, m->vertex_count, NULL) != SK_OK ||
        !build_adjacency(m, &local, in) || !trace_boundary(m, &local, in, &loops))
        goto done;
    const long euler = (long)m->vertex_count - (long)local.edge_count + (long)count;
    if (loops == 0) {
        sk_fail(error, SK_ERROR_ARGUMENT, "chart %zu is closed (it has no boundary): cut it into discs", chart);
        outcome = NOT_DISC;
    } else if (loops != 1 || euler != 1) {
        sk_fail(error, SK_ERROR_ARGUMENT,
                "chart %zu is not a disc: %ld boundary loops and Euler characteristic %ld (a disc has 1 and 1)",
                chart, loops, euler);
        outcome = NOT_DISC;
    } else {
        outcome = BUILT;
    }
    if (outcome == NOT_DISC) {
        split_around(labels, queue, m, 0);
        *component_count = 2;
    }
done:
    sk_edge_flaps_free(&edges);
    sk_edge_flaps_free(&local);
    free(mesh_corners);
    free(queue);
    if (outcome != BUILT)
        free_chart_mesh(m);
    return outcome;
}

/* ---------------------------------------------------------------------------------------------
 * LSCM: assembly and preconditioned conjugate gradients
 * ------------------------------------------------------------------------------------------- */

/* The triangle's isometric local frame (digest 3.2): x1 = 0, x2 = (sqrt g11, 0), x3 above the x axis. */
static void local_frame(double x[3][2], const double gram[3])
{
    const double first = sqrt(gram[0]);
    x[0][0] = x[0][1] = 0.0;
    x[1][0] = first;
    x[1][1] = 0.0;
    x[2][0] = gram[1] / first;
    x[2][1] = sqrt(fmax(gram[2] - gram[1] * gram[1] / gram[0], 0.0));
}

/*
 * Adds each triangle's LSCM term |sum_k W_k U_k|^2 / (2 area) (W_k = z_{k+2} - z_{k+1} in the local frame,
 * U_k = u_k + i v_k) to the normal matrix, stored as one 2x2 block (u, v rows and columns) per ring entry.
 */
static void assemble_lscm(double *blocks, const chart_mesh *m)
{
    memset(blocks, 0, 4 * (size_t)m->ring_offsets[m->vertex_count] * sizeof *blocks);
    for (size_t t = 0; t < m->triangle_count; ++t) {
        double x[3][2];
        local_frame(x, m->gram + 3 * t);
        double w_re[3], w_im[3];
        for (int k = 0; k < 3; ++k) {
            w_re[k] = x[(k + 2) % 3][0] - x[(k + 1) % 3][0];
            w_im[k] = x[(k + 2) % 3][1] - x[(k + 1) % 3][1];
        }
        const double weight = 1.0 / (4.0 * m->area[t]); /* 1 / (2 * twice the area) */
        for (int k = 0; k < 3; ++k) {
            const int32_t row = m->corner[3 * t + (size_t)k];
            for (int l = 0; l < 3; ++l) {
                double *block = blocks + 4 * (size_t)ring_slot(m, row, m->corner[3 * t + (size_t)l]);
                /* Columns of the residual rows: u_k -> (a_k, b_k), v_k -> (-b_k, a_k). */
                const double same = w_re[k] * w_re[l] + w_im[k] * w_im[l];
                const double mixed = w_im[k] * w_re[l] - w_re[k] * w_im[l];
                block[0] += weight * same;
                block[1] += weight * mixed;
                block[2] -= weight * mixed;
                block[3] += weight * same;
            }
        }
    }
}

/* y = A x over the free vertices (pinned rows give 0, pinned columns are skipped). */
static void free_product(double *y, const double *blocks, const chart_mesh *m, const unsigned char *pinned,
                         const double *x)
{
    for (size_t i = 0; i < m->vertex_count; ++i) {
        double u = 0.0, v = 0.0;
        if (!pinned[i])
            for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s) {
                const size_t j = (size_t)m->ring[s];
                if (pinned[j])
                    continue;
                const double *b = blocks + 4 * (size_t)s;
                u += b[0] * x[2 * j] + b[1] * x[2 * j + 1];
                v += b[2] * x[2 * j] + b[3] * x[2 * j + 1];
            }
        y[2 * i] = u;
        y[2 * i + 1] = v;
    }
}

static double dot(const double *a, const double *b, size_t count)
{
    double sum = 0.0;
    for (size_t i = 0; i < count; ++i)
        sum += a[i] * b[i];
    return sum;
}

/* z = (block diagonal)^-1 r on the free vertices. */
static void precondition(double *z, const double *inverse, const double *r, size_t vertex_count)
{
    for (size_t i = 0; i < vertex_count; ++i) {
        const double *d = inverse + 4 * i;
        z[2 * i] = d[0] * r[2 * i] + d[1] * r[2 * i + 1];
        z[2 * i + 1] = d[2] * r[2 * i] + d[3] * r[2 * i + 1];
    }
}

/*
 * Tutte's barycentric embedding (uniform weights): each vertex's block row says it sits at the average of
 * its neighbours. With the boundary pinned on a convex polygon no triangle flips (Tutte 1963).
 */
static void assemble_tutte(double *blocks, const chart_mesh *m)
{
    for (size_t i = 0; i < m->vertex_count; ++i) {
        const double neighbours = (double)(m->ring_offsets[i + 1] - m->ring_offsets[i] - 1);
        for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s) {
            const double weight = (size_t)m->ring[s] == i ? neighbours : -1.0;
            double *block = blocks + 4 * (size_t)s;
            block[0] = block[3] = weight;
            block[1] = block[2] = 0.0;
        }
    }
}

typedef void (*assembler)(double *blocks, const chart_mesh *m);

/* The storage of a conjugate-gradient solve over a chart: the matrix's blocks, the inverse diagonal blocks
 * and the four vectors. */
typedef struct linear_system {
    double *blocks, *inverse, *r, *z, *p, *q;
} linear_system;

static void free_system(linear_system *system)
{
    free(system->blocks);
    free(system->inverse);
    free(system->r);
    free(system->z);
    free(system->p);
    free(system->q);
}

static int allocate_system(linear_system *system, const chart_mesh *m)
{
    const size_t v = m->vertex_count, n = 2 * v, slots = (size_t)m->ring_offsets[v];
    system->blocks = sk_allocate(4 * slots, sizeof *system->blocks);
    system->inverse = sk_allocate_zeroed(4 * v, sizeof *system->inverse);
    system->r = sk_allocate_zeroed(n, sizeof *system->r);
    system->z = sk_allocate(n, sizeof *system->z);
    system->p = sk_allocate(n, sizeof *system->p);
    system->q = sk_allocate(n, sizeof *system->q);
    if (system->blocks && system->inverse && system->r && system->z && system->p && system->q)
        return 1;
    free_system(system);
    return 0;
}

/* The block-Jacobi preconditioner: the inverse of each free vertex's diagonal block. */
static void invert_diagonal(linear_system *system, const chart_mesh *m, const unsigned char *pinned)
{
    for (size_t i = 0; i < m->vertex_count; ++i) {
        if (pinned[i])
            continue;
        const double *d = system->blocks + 4 * (size_t)ring_slot(m, (int32_t)i, (int32_t)i);
        const double determinant = d[0] * d[3] - d[1] * d[2];
        if (determinant > 0) {
            system->inverse[4 * i] = d[3] / determinant;
            system->inverse[4 * i + 1] = -d[1] / determinant;
            system->inverse[4 * i + 2] = -d[2] / determinant;
            system->inverse[4 * i + 3] = d[0] / determinant;
        }
    }
}

/* Preconditioned CG from x, whose residual is in system->r, until |r|^2 <= tolerance_sq or `limit` steps;
 * returns the steps. */
static size_t conjugate_gradients(double *x, linear_system *system, const chart_mesh *m, const unsigned char *pinned,
                                  double tolerance_sq, size_t limit)
{
    const size_t v = m->vertex_count, n = 2 * v;
    double *r = system->r, *z = system->z, *p = system->p, *q = system->q;
    precondition(z, system->inverse, r, v);
    memcpy(p, z, n * sizeof *p);
    double rz = dot(r, z, n);
    size_t step = 0;
    while (step < limit && dot(r, r, n) > tolerance_sq) {
        free_product(q, system->blocks, m, pinned, p);
        const double curvature = dot(p, q, n);
        if (!(curvature > 0))
            break;
        const double alpha = rz / curvature;
        for (size_t i = 0; i < n; ++i) {
            x[i] += alpha * p[i];
            r[i] -= alpha * q[i];
        }
        precondition(z, system->inverse, r, v);
        const double rz_next = dot(r, z, n);
        const double beta = rz_next / rz;
        rz = rz_next;
        for (size_t i = 0; i < n; ++i)
            p[i] = z[i] + beta * p[i];
        ++step;
    }
    return step;
}

/*
 * Minimises the quadratic energy `assemble` builds (LSCM's, or Tutte's) over the free vertices of uv (2 per
 * local vertex; pinned entries are the pins, free entries the starting guess). Returns 0 when memory ran
 * out; *iterations counts CG steps.
 */
static int solve_quadratic(double *uv, const chart_mesh *m, const unsigned char *pinned, assembler assemble,
                           size_t *iterations)
{
    linear_system system;
    if (!allocate_system(&system, m))
        return 0;
    assemble(system.blocks, m);
    invert_diagonal(&system, m, pinned);
    /* r = b - A x with b = -(pinned columns) x_pinned: both together are -(all columns) x on free rows. */
    double rhs_sq = 0.0;
    for (size_t i = 0; i < m->vertex_count; ++i) {
        double ru = 0.0, rv = 0.0, bu = 0.0, bv = 0.0;
        if (!pinned[i])
            for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s) {
                const size_t j = (size_t)m->ring[s];
                const double *b = system.blocks + 4 * (size_t)s;
                const double pu = b[0] * uv[2 * j] + b[1] * uv[2 * j + 1];
                const double pv = b[2] * uv[2 * j] + b[3] * uv[2 * j + 1];
                ru -= pu;
                rv -= pv;
                if (pinned[j]) {
                    bu -= pu;
                    bv -= pv;
                }
            }
        system.r[2 * i] = ru;
        system.r[2 * i + 1] = rv;
        rhs_sq += bu * bu + bv * bv;
    }
    *iterations += conjugate_gradients(uv, &system, m, pinned, CG_RELATIVE_TOLERANCE * CG_RELATIVE_TOLERANCE * rhs_sq,
                                       4 * m->vertex_count + 200);
    free_system(&system);
    return 1;
}

/* ---------------------------------------------------------------------------------------------
 * Stretch of a chart and Sander's optimisation
 * ------------------------------------------------------------------------------------------- */

static const double *corner_uv(const double *uv, const chart_mesh *m, size_t t, int k)
{
    return uv + 2 * (size_t)m->corner[3 * t + (size_t)k];
}

/*
 * The two sums Sander's normalised stretch needs: S = sum of area * (sigma1^2 + sigma2^2) / 2 and P = sum of
 * the uv areas; the normalised L2 stretch is sqrt(S P) / (metric area). S is infinite when a triangle is
 * flipped or degenerate.
 */
typedef struct stretch_sums {
    double weighted, uv_area;
} stretch_sums;

static stretch_sums triangle_sums(const chart_mesh *m, const double *uv, size_t t)
{
    double twice_area;
    const double sum = singular_values_sq(m->gram + 3 * t, corner_uv(uv, m, t, 0), corner_uv(uv, m, t, 1),
                                          corner_uv(uv, m, t, 2), &twice_area);
    return (stretch_sums){m->area[t] * sum / 2, twice_area / 2};
}

static stretch_sums chart_sums(const chart_mesh *m, const double *uv)
{
    stretch_sums total = {0.0, 0.0};
    for (size_t t = 0; t < m->triangle_count; ++t) {
        const stretch_sums s = triangle_sums(m, uv, t);
        total.weighted += s.weighted;
        total.uv_area += s.uv_area;
    }
    return total;
}

static double chart_metric_area(const chart_mesh *m)
{
    double total = 0.0;
    for (size_t t = 0; t < m->triangle_count; ++t)
        total += m->area[t];
    return total;
}

/* Sander's normalised L2 stretch of the chart (INFINITY when a triangle is flipped or degenerate). */
static double chart_stretch(const chart_mesh *m, const double *uv)
{
    const stretch_sums total = chart_sums(m, uv);
    return isfinite(total.weighted) ? sqrt(total.weighted * total.uv_area) / chart_metric_area(m) : INFINITY;
}

static size_t count_invalid(const chart_mesh *m, const double *uv)
{
    size_t invalid = 0;
    for (size_t t = 0; t < m->triangle_count; ++t)
        invalid += valid_double_area(corner_uv(uv, m, t, 0), corner_uv(uv, m, t, 1), corner_uv(uv, m, t, 2)) == 0.0;
    return invalid;
}

static stretch_sums incident_sums(const chart_mesh *m, const double *uv, size_t vertex)
{
    stretch_sums sums = {0.0, 0.0};
    for (int32_t s = m->incident_offsets[vertex]; s < m->incident_offsets[vertex + 1]; ++s) {
        const stretch_sums t = triangle_sums(m, uv, (size_t)m->incident[s]);
        sums.weighted += t.weighted;
        sums.uv_area += t.uv_area;
    }
    return sums;
}

static int corner_of(const chart_mesh *m, size_t triangle, size_t vertex)
{
    int k = 0;
    while (m->corner[3 * triangle + (size_t)k] != (int32_t)vertex)
        ++k;
    return k;
}

/*
 * The largest step t along the unit `direction` that keeps every triangle around the vertex unflipped: twice
 * a triangle's area is linear in t (slope direction x (b - c) for the vertex followed by b, c), so the bound
 * is exact. It is also limited to the longest incident uv edge, which bounds it where moving forward never
 * flips anything.
 */
static double largest_vertex_step(const chart_mesh *m, const double *uv, size_t vertex, const double direction[2])
{
    const double *x = uv + 2 * vertex;
    double reach = 0.0, largest = INFINITY;
    for (int32_t s = m->incident_offsets[vertex]; s < m->incident_offsets[vertex + 1]; ++s) {
        const size_t t = (size_t)m->incident[s];
        const int k = corner_of(m, t, vertex);
        const double *b = corner_uv(uv, m, t, (k + 1) % 3), *c = corner_uv(uv, m, t, (k + 2) % 3);
        const double twice_area = cross2(b[0] - x[0], b[1] - x[1], c[0] - x[0], c[1] - x[1]);
        const double slope = cross2(direction[0], direction[1], b[0] - c[0], b[1] - c[1]);
        if (slope < 0)
            largest = fmin(largest, twice_area / -slope);
        reach = fmax(reach, hypot(b[0] - x[0], b[1] - x[1]));
    }
    return fmin(largest, reach);
}

/*
 * The vertex's share of the chart sums with exact derivatives in its position. Per incident triangle (the
 * vertex x followed by p, q counterclockwise), with u1 = p - x, u2 = q - x, d = u1 x u2 (twice the uv area)
 * and the Gram matrix of the metric edges in the same order, sigma1^2 + sigma2^2 = tr(G (U^T U)^-1) = N / d^2
 * with N = g22 |u1|^2 - 2 g12 u1.u2 + g11 |u2|^2: N is quadratic and d linear in x, so the gradient and the
 * Hessian are closed forms. Hessians are stored as (xx, xy, yy).
 */
typedef struct vertex_terms {
    stretch_sums sums;
    double weighted_gradient[2], weighted_hessian[3];
    double area_gradient[2];
} vertex_terms;

static void add_triangle_terms(vertex_terms *terms, const chart_mesh *m, const double *uv, size_t t, size_t vertex)
{
    const int k = corner_of(m, t, vertex);
    const double *gram = m->gram + 3 * t;
    const double lengths_sq[3] = {gram[0], gram[0] + gram[2] - 2 * gram[1], gram[2]};
    const double g11 = lengths_sq[k], g22 = lengths_sq[(k + 2) % 3], opposite = lengths_sq[(k + 1) % 3];
    const double g12 = (g11 + g22 - opposite) / 2;
    const double *x = uv + 2 * vertex, *p = corner_uv(uv, m, t, (k + 1) % 3), *q = corner_uv(uv, m, t, (k + 2) % 3);
    if (valid_double_area(x, p, q) == 0.0) {
        terms->sums.weighted = INFINITY;
        return;
    }
    const double u1[2] = {p[0] - x[0], p[1] - x[1]}, u2[2] = {q[0] - x[0], q[1] - x[1]};
    const double d = cross2(u1[0], u1[1], u2[0], u2[1]), inverse = 1.0 / d;
    const double n = g22 * (u1[0] * u1[0] + u1[1] * u1[1]) - 2 * g12 * (u1[0] * u2[0] + u1[1] * u2[1]) +
                     g11 * (u2[0] * u2[0] + u2[1] * u2[1]);
    double n_gradient[2], d_gradient[2] = {p[1] - q[1], q[0] - p[0]};
    for (int axis = 0; axis < 2; ++axis)
        n_gradient[axis] = 2 * (g12 * (u1[axis] + u2[axis]) - g22 * u1[axis] - g11 * u2[axis]);
    const double weight = m->area[t] / 2, i2 = inverse * inverse, i3 = i2 * inverse, i4 = i2 * i2;
    terms->sums.weighted += weight * n * i2;
    terms->sums.uv_area += d / 2;
    for (int axis = 0; axis < 2; ++axis) {
        terms->weighted_gradient[axis] += weight * (n_gradient[axis] * i2 - 2 * n * d_gradient[axis] * i3);
        terms->area_gradient[axis] += d_gradient[axis] / 2;
    }
    const int rows[3] = {0, 0, 1}, columns[3] = {0, 1, 1};
    for (int e = 0; e < 3; ++e) {
        const int r = rows[e], c = columns[e];
        const double quadratic = r == c ? 2 * opposite * i2 : 0.0;
        terms->weighted_hessian[e] +=
            weight * (quadratic - 2 * (n_gradient[r] * d_gradient[c] + d_gradient[r] * n_gradient[c]) * i3 +
                      6 * n * d_gradient[r] * d_gradient[c] * i4);
    }
}

/* Solves H step = -gradient for a 2x2 symmetric H, its smallest eigenvalue raised to a fraction of the
 * largest so the step always descends (the local energy is not convex everywhere). Returns 0 without a
 * positive curvature to use. */
static int descent_step(double step[2], const double hessian[3], const double gradient[2])
{
    const double mean = (hessian[0] + hessian[2]) / 2;
    const double radius = hypot((hessian[0] - hessian[2]) / 2, hessian[1]);
    const double largest = mean + radius, smallest = mean - radius;
    if (!(largest > 0) || !isfinite(largest))
        return 0;
    const double shift = smallest < 1e-3 * largest ? 1e-3 * largest - smallest : 0.0;
    const double a = hessian[0] + shift, b = hessian[1], c = hessian[2] + shift, determinant = a * c - b * b;
    step[0] = -(c * gradient[0] - b * gradient[1]) / determinant;
    step[1] = -(a * gradient[1] - b * gradient[0]) / determinant;
    return isfinite(step[0]) && isfinite(step[1]);
}

/* The chart's S * P (its normalised stretch squared times its metric area squared) with the vertex at
 * start + t direction, the other triangles' sums given; the vertex's own sums are kept for the caller. */
typedef struct line_search {
    const chart_mesh *m;
    double *uv;
    size_t vertex;
    double start[2], direction[2];
    stretch_sums others, local;
} line_search;

static double objective_at(line_search *search, double t)
{
    double *x = search->uv + 2 * search->vertex;
    x[0] = search->start[0] + t * search->direction[0];
    x[1] = search->start[1] + t * search->direction[1];
    search->local = incident_sums(search->m, search->uv, search->vertex);
    return (search->others.weighted + search->local.weighted) * (search->others.uv_area + search->local.uv_area);
}

/*
 * One Newton step of the chart's S * P in one vertex's position, with backtracking (Armijo) inside the
 * interval where no incident triangle flips. The product, not S alone, is what the normalised stretch
 * measures: moving a boundary vertex changes the chart's uv area too. Returns the chart sums after the move.
 */
static stretch_sums newton_move(const chart_mesh *m, double *uv, size_t vertex, stretch_sums total)
{
    vertex_terms local = {{0.0, 0.0}, {0.0, 0.0}, {0.0, 0.0, 0.0}, {0.0, 0.0}};
    for (int32_t s = m->incident_offsets[vertex]; s < m->incident_offsets[vertex + 1]; ++s)
        add_triangle_terms(&local, m, uv, (size_t)m->incident[s], vertex);
    if (!isfinite(local.sums.weighted))
        return total;
    const double weighted = total.weighted, area = total.uv_area;
    const double *sg = local.weighted_gradient, *ag = local.area_gradient, *sh = local.weighted_hessian;
    const double gradient[2] = {sg[0] * area + weighted * ag[0], sg[1] * area + weighted * ag[1]};
    const double hessian[3] = {sh[0] * area + 2 * sg[0] * ag[0], sh[1] * area + sg[0] * ag[1] + sg[1] * ag[0],
                               sh[2] * area + 2 * sg[1] * ag[1]};
    double step[2];
    if (!descent_step(step, hessian, gradient))
        return total;
    const double length = hypot(step[0], step[1]);
    if (!(length > 0))
        return total;
    line_search search = {m, uv, vertex, {uv[2 * vertex], uv[2 * vertex + 1]}, {step[0] / length, step[1] / length},
                          {weighted - local.sums.weighted, area - local.sums.uv_area}, local.sums};
    const double slope = gradient[0] * search.direction[0] + gradient[1] * search.direction[1];
    const double current = weighted * area;
    double t = fmin(length, 0.9 * largest_vertex_step(m, uv, vertex, search.direction));
    for (int halving = 0; halving < BACKTRACKING_STEPS && t > 0; ++halving, t /= 2)
        if (objective_at(&search, t) <= current + ARMIJO_FRACTION * t * slope)
            return (stretch_sums){search.others.weighted + search.local.weighted,
                                  search.others.uv_area + search.local.uv_area};
    uv[2 * vertex] = search.start[0];
    uv[2 * vertex + 1] = search.start[1];
    return total;
}

typedef struct pass_counts {
    size_t straight_charts, circle_charts, free_charts, extra_corners, tutte_charts, solver_iterations, sweeps;
} pass_counts;

/*
 * Global steps for the low frequencies that single-vertex moves are slow to remove: the gradient of S * P
 * over the movable vertices, preconditioned by the metric's Dirichlet Laplacian (the quadratic proxy of
 * Kovalsky et al. 2016, the energy's Hessian up to scale near an isometry), then a backtracking line search
 * inside the largest step that flips no triangle.
 */
typedef struct global_solver {
    linear_system system;  /* the Dirichlet blocks and the CG storage */
    unsigned char *fixed;  /* the vertices that are not movable */
    double *direction, *trial;
    double step;           /* the last accepted step, where the next line search starts */
} global_solver;

static void free_global(global_solver *g)
{
    free_system(&g->system);
    free(g->fixed);
    free(g->direction);
    free(g->trial);
}

static int allocate_global(global_solver *g, const chart_mesh *m, const unsigned char *movable)
{
    const size_t v = m->vertex_count;
    if (!allocate_system(&g->system, m))
        return 0;
    g->fixed = sk_allocate(v, 1);
    g->direction = sk_allocate(2 * v, sizeof *g->direction);
    g->trial = sk_allocate(2 * v, sizeof *g->trial);
    if (!g->fixed || !g->direction || !g->trial) {
        free_global(g);
        return 0;
    }
    for (size_t i = 0; i < v; ++i)
        g->fixed[i] = !movable[i];
    assemble_lscm(g->system.blocks, m);
    /* LSCM's blocks are the Dirichlet energy's (u and v alike) minus the area's (coupling u and v). */
    for (size_t s = 0; s < (size_t)m->ring_offsets[v]; ++s)
        g->system.blocks[4 * s + 1] = g->system.blocks[4 * s + 2] = 0.0;
    invert_diagonal(&g->system, m, g->fixed);
    g->step = 1.0;
    return 1;
}

/* The largest t at which uv + t direction still has every triangle counterclockwise (INFINITY: never
 * flips): twice a triangle's area is a quadratic a + b t + c t^2 with a > 0. */
static double largest_unflipped_step(const chart_mesh *m, const double *uv, const double *direction)
{
    double largest = INFINITY;
    for (size_t t = 0; t < m->triangle_count; ++t) {
        const double *x0 = corner_uv(uv, m, t, 0), *x1 = corner_uv(uv, m, t, 1), *x2 = corner_uv(uv, m, t, 2);
        const double *d0 = corner_uv(direction, m, t, 0), *d1 = corner_uv(direction, m, t, 1);
        const double *d2 = corner_uv(direction, m, t, 2);
        const double e1[2] = {x1[0] - x0[0], x1[1] - x0[1]}, e2[2] = {x2[0] - x0[0], x2[1] - x0[1]};
        const double f1[2] = {d1[0] - d0[0], d1[1] - d0[1]}, f2[2] = {d2[0] - d0[0], d2[1] - d0[1]};
        const double a = cross2(e1[0], e1[1], e2[0], e2[1]);
        const double b = cross2(e1[0], e1[1], f2[0], f2[1]) + cross2(f1[0], f1[1], e2[0], e2[1]);
        const double c = cross2(f1[0], f1[1], f2[0], f2[1]);
        double root = INFINITY;
        if (fabs(c) <= 1e-12 * fabs(b)) {
            if (b < 0)
                root = -a / b;
        } else {
            const double discriminant = b * b - 4 * a * c;
            if (discriminant >= 0) {
                /* The roots' product is a / c: a stable pair without cancellation. */
                const double q = -(b + copysign(sqrt(discriminant), b)) / 2;
                const double r1 = q / c, r2 = a / q;
                root = fmin(r1 > 0 ? r1 : INFINITY, r2 > 0 ? r2 : INFINITY);
            }
        }
        largest = fmin(largest, root);
    }
    return largest;
}

/* One global step; returns the chart sums after it (unchanged when no step lowers S * P). */
static stretch_sums global_step(global_solver *g, const chart_mesh *m, double *uv, stretch_sums total,
                                size_t *iterations)
{
    const size_t v = m->vertex_count;
    double *gradient = g->trial; /* until the line search needs it */
    double rhs_sq = 0.0;
    for (size_t i = 0; i < v; ++i) {
        gradient[2 * i] = gradient[2 * i + 1] = 0.0;
        if (!g->fixed[i]) {
            vertex_terms local = {{0.0, 0.0}, {0.0, 0.0}, {0.0, 0.0, 0.0}, {0.0, 0.0}};
            for (int32_t s = m->incident_offsets[i]; s < m->incident_offsets[i + 1]; ++s)
                add_triangle_terms(&local, m, uv, (size_t)m->incident[s], i);
            if (!isfinite(local.sums.weighted))
                return total;
            for (int axis = 0; axis < 2; ++axis)
                gradient[2 * i + (size_t)axis] = local.weighted_gradient[axis] * total.uv_area +
                                                 total.weighted * local.area_gradient[axis];
        }
        /* The proxy of S * P's Hessian is P times the Laplacian: the step solves L d = -gradient / P. */
        g->system.r[2 * i] = -gradient[2 * i] / total.uv_area;
        g->system.r[2 * i + 1] = -gradient[2 * i + 1] / total.uv_area;
        rhs_sq += g->system.r[2 * i] * g->system.r[2 * i] + g->system.r[2 * i + 1] * g->system.r[2 * i + 1];
    }
    memset(g->direction, 0, 2 * v * sizeof *g->direction);
    *iterations += conjugate_gradients(g->direction, &g->system, m, g->fixed,
                                       GLOBAL_CG_TOLERANCE * GLOBAL_CG_TOLERANCE * rhs_sq, GLOBAL_CG_STEPS);
    const double slope = dot(gradient, g->direction, 2 * v);
    if (!(slope < 0))
        return total;
    const double current = total.weighted * total.uv_area;
    double t = fmin(2 * g->step, 0.8 * largest_unflipped_step(m, uv, g->direction));
    for (int halving = 0; halving < BACKTRACKING_STEPS && t > 0; ++halving, t /= 2) {
        for (size_t i = 0; i < 2 * v; ++i)
            g->trial[i] = uv[i] + t * g->direction[i];
        const stretch_sums after = chart_sums(m, g->trial);
        if (after.weighted * after.uv_area <= current + ARMIJO_FRACTION * t * slope) {
            memcpy(uv, g->trial, 2 * v * sizeof *uv);
            g->step = t;
            return after;
        }
    }
    g->step = t;
    return total;
}

/*
 * Minimises the chart's normalised L2 stretch (Sander et al. 2001, eq. 5.6-5.8) by Newton steps on one
 * movable vertex at a time, in a fixed order, until a sweep improves the stretch by less than
 * STRETCH_RELATIVE_IMPROVEMENT or after sweep_limit sweeps. No step flips a triangle; a layout that already
 * has a flipped or degenerate triangle is left alone (its stretch is infinite: no move can be compared).
 */
static void optimise_stretch(const chart_mesh *m, double *uv, const unsigned char *movable, int sweep_limit,
                             pass_counts *counts)
{
    stretch_sums total = chart_sums(m, uv);
    if (!isfinite(total.weighted))
        return;
    global_solver global;
    const int global_steps = allocate_global(&global, m, movable); /* without memory for them: sweeps only */
    for (int sweep = 0; sweep < sweep_limit; ++sweep) {
        const double before = total.weighted * total.uv_area;
        if (global_steps)
            total = global_step(&global, m, uv, total, &counts->solver_iterations);
        for (size_t i = 0; i < m->vertex_count; ++i)
            if (movable[i])
                total = newton_move(m, uv, i, total);
        ++counts->sweeps;
        total = chart_sums(m, uv); /* from scratch: the running sums drift by rounding over many moves */
        if (sqrt(total.weighted * total.uv_area / before) > 1 - STRETCH_RELATIVE_IMPROVEMENT)
            break;
    }
    if (global_steps)
        free_global(&global);
}

/* ---------------------------------------------------------------------------------------------
 * The passes
 * ------------------------------------------------------------------------------------------- */

/* Metric shortest-path distances from one vertex over the chart's edges (Dijkstra, binary heap). */
static void distances_from(double *distance, sk_vertex_distance *heap, const chart_mesh *m, int32_t source)
{
    for (size_t i = 0; i < m->vertex_count; ++i)
        distance[i] = INFINITY;
    size_t size = 0;
    distance[source] = 0.0;
    sk_heap_push(heap, &size, (sk_vertex_distance){0.0, source});
    while (size > 0) {
        const sk_vertex_distance top = sk_heap_pop(heap, &size);
        if (top.distance > distance[top.vertex])
            continue;
        for (int32_t s = m->ring_offsets[top.vertex]; s < m->ring_offsets[top.vertex + 1]; ++s) {
            const double through = top.distance + m->ring_length[s];
            if (through < distance[m->ring[s]]) {
                distance[m->ring[s]] = through;
                sk_heap_push(heap, &size, (sk_vertex_distance){through, m->ring[s]});
            }
        }
    }
}

static int32_t farthest_on_boundary(const chart_mesh *m, const double *distance)
{
    int32_t best = m->loop[0];
    for (size_t i = 0; i < m->boundary_count; ++i)
        if (distance[m->loop[i]] > distance[best])
            best = m->loop[i];
    return best;
}

/* Two boundary vertices far apart (two Dijkstra sweeps), and their distance. */
static int farthest_pair(int32_t pair[2], double *separation, const chart_mesh *m)
{
    double *distance = sk_allocate(m->vertex_count, sizeof *distance);
    sk_vertex_distance *heap = sk_allocate((size_t)m->ring_offsets[m->vertex_count] + 1, sizeof *heap);
    if (distance && heap) {
        distances_from(distance, heap, m, m->loop[0]);
        pair[0] = farthest_on_boundary(m, distance);
        distances_from(distance, heap, m, pair[0]);
        pair[1] = farthest_on_boundary(m, distance);
        *separation = distance[pair[1]];
    }
    free(distance);
    free(heap);
    return distance && heap;
}

/* Scales uv about the origin so that the chart's uv area equals its metric area ("metric units"). */
static void scale_to_metric_area(double *uv, const chart_mesh *m)
{
    double uv_area = 0.0;
    for (size_t t = 0; t < m->triangle_count; ++t) {
        const double *a = corner_uv(uv, m, t, 0), *b = corner_uv(uv, m, t, 1), *c = corner_uv(uv, m, t, 2);
        uv_area += cross2(b[0] - a[0], b[1] - a[1], c[0] - a[0], c[1] - a[1]) / 2;
    }
    if (!(uv_area > 0))
        return;
    const double scale = sqrt(chart_metric_area(m) / uv_area);
    for (size_t i = 0; i < 2 * m->vertex_count; ++i)
        uv[i] *= scale;
}

typedef struct chart_scratch {
    double *free_uv;            /* pass 1 */
    double *uv;                 /* the pinned pass being tried */
    unsigned char *pinned, *movable, *is_corner; /* per local vertex */
    int32_t *loop_position;     /* per local vertex: its position in the boundary loop, or -1 */
    double *arc;                /* per loop position (and one more): arc length from loop[0] */
    int32_t *previous_corner;   /* per loop position: the loop position of the corner before (or at) it */
    int32_t *next_corner;       /* per loop position: the corner after (or at) it */
    unsigned char *wanted_side; /* per loop position of a corner: the side after it may get an extra corner */
    int32_t *rotated_loop;      /* the corner rule's scratch: the loop from another start, with its arc */
    double *rotated_arc;
} chart_scratch;

static void free_scratch(chart_scratch *s)
{
    free(s->free_uv);
    free(s->uv);
    free(s->pinned);
    free(s->movable);
    free(s->is_corner);
    free(s->loop_position);
    free(s->arc);
    free(s->previous_corner);
    free(s->next_corner);
    free(s->wanted_side);
    free(s->rotated_loop);
    free(s->rotated_arc);
    memset(s, 0, sizeof *s);
}

static int allocate_scratch(chart_scratch *s, const chart_mesh *m)
{
    const size_t v = m->vertex_count, b = m->boundary_count;
    memset(s, 0, sizeof *s);
    s->free_uv = sk_allocate(2 * v, sizeof *s->free_uv);
    s->uv = sk_allocate(2 * v, sizeof *s->uv);
    s->pinned = sk_allocate(v, 1);
    s->movable = sk_allocate(v, 1);
    s->is_corner = sk_allocate(v, 1);
    s->loop_position = sk_allocate(v, sizeof *s->loop_position);
    s->arc = sk_allocate(b + 1, sizeof *s->arc);
    s->previous_corner = sk_allocate(b, sizeof *s->previous_corner);
    s->next_corner = sk_allocate(b, sizeof *s->next_corner);
    s->wanted_side = sk_allocate(b, 1);
    s->rotated_loop = sk_allocate(b + 1, sizeof *s->rotated_loop);
    s->rotated_arc = sk_allocate(b + 1, sizeof *s->rotated_arc);
    if (!s->free_uv || !s->uv || !s->pinned || !s->movable || !s->is_corner || !s->loop_position || !s->arc ||
        !s->previous_corner || !s->next_corner || !s->wanted_side || !s->rotated_loop || !s->rotated_arc) {
        free_scratch(s);
        return 0;
    }
    for (size_t i = 0; i < v; ++i)
        s->loop_position[i] = -1;
    s->arc[0] = 0.0;
    for (size_t i = 0; i < b; ++i) {
        s->loop_position[m->loop[i]] = (int32_t)i;
        s->arc[i + 1] = s->arc[i] + m->loop_length[i];
    }
    return 1;
}

/*
 * Tutte's embedding of the chart: the boundary on a circle whose circumference is the chart's metric
 * perimeter, spaced by arc length, and every interior vertex at the average of its neighbours.
 */
static int tutte_layout(double *uv, const chart_mesh *m, chart_scratch *s, pass_counts *counts)
{
    const size_t b = m->boundary_count;
    const double perimeter = s->arc[b], radius = perimeter / TWO_PI;
    memset(uv, 0, 2 * m->vertex_count * sizeof *uv);
    for (size_t i = 0; i < b; ++i) {
        const double angle = TWO_PI * s->arc[i] / perimeter;
        uv[2 * (size_t)m->loop[i]] = radius * cos(angle);
        uv[2 * (size_t)m->loop[i] + 1] = radius * sin(angle);
    }
    memcpy(s->pinned, m->on_boundary, m->vertex_count);
    return solve_quadratic(uv, m, s->pinned, assemble_tutte, &counts->solver_iterations);
}

/*
 * Pass 1: LSCM with two pinned boundary vertices, far apart; then scaled to metric units. LSCM can flip
 * triangles where the metric is far from flat; the optimisation cannot start from there (the stretch is
 * infinite), so such a chart starts from Tutte's embedding instead, which flips nothing, and the optimisation
 * (optimise_free), which never flips a triangle either, frees its boundary.
 */
static int free_boundary_pass(double *uv, const chart_mesh *m, chart_scratch *s, pass_counts *counts)
{
    int32_t pins[2];
    double separation = 0.0;
    if (!farthest_pair(pins, &separation, m))
        return 0;
    memset(uv, 0, 2 * m->vertex_count * sizeof *uv);
    memset(s->pinned, 0, m->vertex_count);
    s->pinned[pins[0]] = s->pinned[pins[1]] = 1;
    uv[2 * (size_t)pins[1]] = separation > 0 ? separation : 1.0;
    if (!solve_quadratic(uv, m, s->pinned, assemble_lscm, &counts->solver_iterations))
        return 0;
    if (count_invalid(m, uv) > 0) {
        if (!tutte_layout(uv, m, s, counts))
            return 0;
        ++counts->tutte_charts;
    }
    scale_to_metric_area(uv, m);
    return 1;
}

/* The free layout's stretch optimisation, every vertex movable (when the options ask for it). */
static void optimise_free(double *uv, const chart_mesh *m, chart_scratch *s, const sk_flatten_options *options,
                          pass_counts *counts)
{
    if (options->optimise) {
        memset(s->movable, 1, m->vertex_count);
        optimise_stretch(m, uv, s->movable, options->sweep_limit, counts);
    }
}


static int is_corner_at(const chart_scratch *s, const chart_mesh *m, size_t position)
{
    return s->is_corner[m->loop[position]];
}

/* Links every loop position to the corners before and after it (a corner is its own); needs one corner. */
static void link_corners(chart_scratch *s, const chart_mesh *m)
{
    const size_t b = m->boundary_count;
    size_t first = 0;
    while (!is_corner_at(s, m, first))
        ++first;
    int32_t last = (int32_t)first;
    for (size_t step = 0; step < b; ++step) {
        const size_t i = (first + step) % b;
        if (is_corner_at(s, m, i))
            last = (int32_t)i;
        s->previous_corner[i] = last;
    }
    last = (int32_t)first;
    for (size_t step = 0; step < b; ++step) {
        const size_t i = (first + b - step) % b;
        if (is_corner_at(s, m, i))
            last = (int32_t)i;
        s->next_corner[i] = last;
    }
}

/* The arc length going forward from loop position `from` to `to` (the whole perimeter when they are equal). */
static double arc_between(const chart_scratch *s, const chart_mesh *m, size_t from, size_t to)
{
    const double difference = s->arc[to] - s->arc[from];
    return difference > 0 ? difference : difference + s->arc[m->boundary_count];
}

/* Marks the chart's corners: the given ones on its boundary, completed to three by sk_chart_corners' rule. */
static void mark_corners(chart_scratch *s, const chart_mesh *m, const flatten_input *in)
{
    memset(s->is_corner, 0, m->vertex_count);
    for (size_t i = 0; i < m->boundary_count; ++i)
        if (in->corners[m->vertex[m->loop[i]]])
            s->is_corner[m->loop[i]] = 1;
    sk_complete_corners(s->is_corner, m->loop, s->arc, m->boundary_count, s->rotated_loop, s->rotated_arc);
    link_corners(s, m);
}

/* Puts the boundary's non-corner vertices on the segments between the corners already placed in uv, spaced by
 * the metric lengths of the boundary edges. */
static void straighten_sides(double *uv, const chart_scratch *s, const chart_mesh *m)
{
    for (size_t i = 0; i < m->boundary_count; ++i) {
        if (is_corner_at(s, m, i))
            continue;
        const size_t p = (size_t)s->previous_corner[i], q = (size_t)s->next_corner[i];
        const double fraction = arc_between(s, m, p, i) / arc_between(s, m, p, q);
        const double *a = uv + 2 * (size_t)m->loop[p], *c = uv + 2 * (size_t)m->loop[q];
        double *x = uv + 2 * (size_t)m->loop[i];
        x[0] = a[0] + fraction * (c[0] - a[0]);
        x[1] = a[1] + fraction * (c[1] - a[1]);
    }
}

/*
 * Pass 2 (circle = 0): corners at their pass-1 positions. Pass 3 (circle = 1): corners on a circle whose
 * circumference is the chart's metric perimeter, spaced by arc length, counterclockwise like the loop.
 * Either way every boundary vertex is pinned, the interior solved by LSCM and then optimised.
 */
static int pinned_pass(double *uv, const chart_mesh *m, chart_scratch *s, const sk_flatten_options *options,
                       int circle, pass_counts *counts)
{
    const size_t b = m->boundary_count;
    memcpy(uv, s->free_uv, 2 * m->vertex_count * sizeof *uv);
    if (circle) {
        const double perimeter = s->arc[b], radius = perimeter / (TWO_PI);
        for (size_t i = 0; i < b; ++i)
            if (is_corner_at(s, m, i)) {
                const double angle = TWO_PI * s->arc[i] / perimeter;
                uv[2 * (size_t)m->loop[i]] = radius * cos(angle);
                uv[2 * (size_t)m->loop[i] + 1] = radius * sin(angle);
            }
    }
    straighten_sides(uv, s, m);
    memcpy(s->pinned, m->on_boundary, m->vertex_count);
    if (!solve_quadratic(uv, m, s->pinned, assemble_lscm, &counts->solver_iterations))
        return 0;
    if (options->optimise) {
        for (size_t i = 0; i < m->vertex_count; ++i)
            s->movable[i] = !m->on_boundary[i];
        optimise_stretch(m, uv, s->movable, options->sweep_limit, counts);
    }
    return 1;
}

/*
 * Adds the extra corner of section 5.3 (Fig 5.8): the boundary vertex whose summed distances to the corners on
 * either side exceed the distance between those corners the most. Distances are measured in the pass-1
 * layout, which is the chart's metric shape up to the little stretch LSCM leaves. When the last pinned layout
 * has flipped or degenerate triangles, only the sides holding their boundary vertices are considered.
 * Returns 0 when no boundary vertex is left to become a corner.
 */
static int add_extra_corner(chart_scratch *s, const chart_mesh *m, const double *failed_uv)
{
    const size_t b = m->boundary_count;
    int restricted = 0;
    memset(s->wanted_side, 0, b);
    for (size_t t = 0; failed_uv && t < m->triangle_count; ++t) {
        if (valid_double_area(corner_uv(failed_uv, m, t, 0), corner_uv(failed_uv, m, t, 1),
                              corner_uv(failed_uv, m, t, 2)) > 0)
            continue;
        for (int k = 0; k < 3; ++k) {
            const int32_t position = s->loop_position[m->corner[3 * t + (size_t)k]];
            if (position >= 0 && !is_corner_at(s, m, (size_t)position)) {
                s->wanted_side[s->previous_corner[position]] = 1;
                restricted = 1;
            }
        }
    }
    int32_t best = -1;
    double best_excess = -1.0;
    for (size_t i = 0; i < b; ++i) {
        if (is_corner_at(s, m, i) || (restricted && !s->wanted_side[s->previous_corner[i]]))
            continue;
        const double *x = s->free_uv + 2 * (size_t)m->loop[i];
        const double *p = s->free_uv + 2 * (size_t)m->loop[s->previous_corner[i]];
        const double *q = s->free_uv + 2 * (size_t)m->loop[s->next_corner[i]];
        const double excess = hypot(x[0] - p[0], x[1] - p[1]) + hypot(x[0] - q[0], x[1] - q[1]) -
                              hypot(p[0] - q[0], p[1] - q[1]);
        if (excess > best_excess) {
            best_excess = excess;
            best = (int32_t)i;
        }
    }
    if (best < 0)
        return 0;
    s->is_corner[m->loop[best]] = 1;
    link_corners(s, m);
    return 1;
}

/*
 * Flattens one disc chart into result (2 per local vertex) by the passes of section 5.3. Returns 0 when memory
 * ran out.
 */
static int flatten_chart(double *result, const chart_mesh *m, const flatten_input *in, pass_counts *counts)
{
    const sk_flatten_options *options = &in->options;
    chart_scratch s;
    if (!allocate_scratch(&s, m))
        return 0;
    int ok = free_boundary_pass(s.free_uv, m, &s, counts);
    /* Optimised also when straightening will replace it: the corners keep their pass-1 positions and the
     * stretch limit is relative to pass 1, and both are better for it (from LSCM's layout, straightening
     * raised the creature's stretch to 1.28 instead of 1.12). */
    if (ok)
        optimise_free(s.free_uv, m, &s, options, counts);
    const double free_stretch = ok ? chart_stretch(m, s.free_uv) : INFINITY;
    /* A free layout with flipped triangles is not kept: the pinned passes are its fallback. */
    if (ok && (options->straight || !isfinite(free_stretch))) {
        mark_corners(&s, m, in);
        for (int extra = 0; ok; ++extra) {
            ok = pinned_pass(s.uv, m, &s, options, 0, counts);
            double stretch = ok ? chart_stretch(m, s.uv) : INFINITY;
            int circle = 0;
            if (ok && !isfinite(stretch)) {
                ok = pinned_pass(s.uv, m, &s, options, 1, counts);
                stretch = ok ? chart_stretch(m, s.uv) : INFINITY;
                circle = 1;
            }
            if (ok && isfinite(stretch) && !(stretch > options->stretch_limit * free_stretch)) {
                memcpy(result, s.uv, 2 * m->vertex_count * sizeof *result);
                ++*(circle ? &counts->circle_charts : &counts->straight_charts);
                free_scratch(&s);
                scale_to_metric_area(result, m);
                return 1;
            }
            if (!ok || extra == EXTRA_CORNER_LIMIT || !add_extra_corner(&s, m, isfinite(stretch) ? NULL : s.uv))
                break;
            ++counts->extra_corners;
        }
    }
    if (ok) { /* the free boundary: asked for, or every straightening failed */
        const int free_better = isfinite(free_stretch) || !options->straight ||
                                count_invalid(m, s.free_uv) <= count_invalid(m, s.uv);
        memcpy(result, free_better ? s.free_uv : s.uv, 2 * m->vertex_count * sizeof *result);
        ++counts->free_charts;
    }
    free_scratch(&s);
    if (ok) /* a pinned boundary sets its own scale: every result is brought to metric units */
        scale_to_metric_area(result, m);
    return ok;
}

/* ---------------------------------------------------------------------------------------------
 * Overlap check: boundary self-intersections on a uniform grid, and the two-source split
 * ------------------------------------------------------------------------------------------- */

static double orient(const double a[2], const double b[2], const double c[2])
{
    return cross2(b[0] - a[0], b[1] - a[1], c[0] - a[0], c[1] - a[1]);
}

static int within_box(const double a[2], const double b[2], const double p[2])
{
    return p[0] >= fmin(a[0], b[0]) && p[0] <= fmax(a[0], b[0]) && p[1] >= fmin(a[1], b[1]) &&
           p[1] <= fmax(a[1], b[1]);
}

/* Whether segments ab and cd cross or touch. */
static int segments_meet(const double a[2], const double b[2], const double c[2], const double d[2])
{
    const double o1 = orient(a, b, c), o2 = orient(a, b, d), o3 = orient(c, d, a), o4 = orient(c, d, b);
    if (((o1 > 0 && o2 < 0) || (o1 < 0 && o2 > 0)) && ((o3 > 0 && o4 < 0) || (o3 < 0 && o4 > 0)))
        return 1;
    return (o1 == 0 && within_box(a, b, c)) || (o2 == 0 && within_box(a, b, d)) ||
           (o3 == 0 && within_box(c, d, a)) || (o4 == 0 && within_box(c, d, b));
}

typedef struct segment_grid {
    double origin[2], cell;
    size_t columns, rows;
    int32_t *offsets, *segments; /* per cell, CSR */
} segment_grid;

static void segment_cells(size_t range[4], const segment_grid *g, const double *a, const double *b)
{
    const double low[2] = {fmin(a[0], b[0]), fmin(a[1], b[1])}, high[2] = {fmax(a[0], b[0]), fmax(a[1], b[1])};
    const size_t limit[2] = {g->columns - 1, g->rows - 1};
    for (int axis = 0; axis < 2; ++axis) {
        const double first = floor((low[axis] - g->origin[axis]) / g->cell);
        const double last = floor((high[axis] - g->origin[axis]) / g->cell);
        range[2 * axis] = first <= 0 ? 0 : first >= (double)limit[axis] ? limit[axis] : (size_t)first;
        range[2 * axis + 1] = last <= 0 ? 0 : last >= (double)limit[axis] ? limit[axis] : (size_t)last;
    }
}

/*
 * Finds two non-adjacent boundary edges of the layout that cross or touch; returns 0 when there are none and
 * -1 when memory ran out. The edges go into a uniform grid of about one cell per edge (cells about one edge
 * long, at most four per edge), so only edges sharing a cell are compared.
 */
static int find_boundary_crossing(size_t crossing[2], const chart_mesh *m, const double *uv)
{
    const size_t b = m->boundary_count;
    if (b < 4)
        return 0;
    crossing[0] = 0; /* the answer when the whole boundary sits at one point */
    crossing[1] = 2;
    segment_grid g = {{INFINITY, INFINITY}, 0.0, 0, 0, NULL, NULL};
    double high[2] = {-INFINITY, -INFINITY}, total_length = 0.0;
    for (size_t i = 0; i < b; ++i) {
        const double *p = uv + 2 * (size_t)m->loop[i], *q = uv + 2 * (size_t)m->loop[(i + 1) % b];
        for (int axis = 0; axis < 2; ++axis) {
            g.origin[axis] = fmin(g.origin[axis], p[axis]);
            high[axis] = fmax(high[axis], p[axis]);
        }
        total_length += hypot(q[0] - p[0], q[1] - p[1]);
    }
    const double width = high[0] - g.origin[0], height = high[1] - g.origin[1];
    g.cell = fmax(total_length / (double)b, sqrt(width * height / (4.0 * (double)b)));
    if (!(g.cell > 0))
        return 1; /* every boundary vertex at one point: certainly overlapping */
    g.columns = (size_t)(width / g.cell) + 1;
    g.rows = (size_t)(height / g.cell) + 1;
    const size_t cells = g.columns * g.rows;
    g.offsets = sk_allocate_zeroed(cells + 1, sizeof *g.offsets);
    int found = 0;
    if (!g.offsets)
        return -1;
    size_t range[4];
    for (int fill = 0; fill < 2; ++fill) {
        for (size_t i = 0; i < b; ++i) {
            segment_cells(range, &g, uv + 2 * (size_t)m->loop[i], uv + 2 * (size_t)m->loop[(i + 1) % b]);
            for (size_t y = range[2]; y <= range[3]; ++y)
                for (size_t x = range[0]; x <= range[1]; ++x) {
                    const size_t cell = y * g.columns + x;
                    if (fill)
                        g.segments[g.offsets[cell]++] = (int32_t)i;
                    else
                        ++g.offsets[cell + 1];
                }
        }
        if (!fill) {
            for (size_t c = 0; c < cells; ++c)
                g.offsets[c + 1] += g.offsets[c];
            g.segments = sk_allocate((size_t)g.offsets[cells] + 1, sizeof *g.segments);
            if (!g.segments) {
                free(g.offsets);
                return -1;
            }
        } else { /* the fill advanced each cell's start to its end: shift back */
            for (size_t c = cells; c > 0; --c)
                g.offsets[c] = g.offsets[c - 1];
            g.offsets[0] = 0;
        }
    }
    for (size_t c = 0; c < cells && !found; ++c)
        for (int32_t x = g.offsets[c]; x < g.offsets[c + 1] && !found; ++x)
            for (int32_t y = x + 1; y < g.offsets[c + 1] && !found; ++y) {
                const size_t i = (size_t)g.segments[x], j = (size_t)g.segments[y];
                if ((i + 1) % b == j || (j + 1) % b == i)
                    continue;
                if (segments_meet(uv + 2 * (size_t)m->loop[i], uv + 2 * (size_t)m->loop[(i + 1) % b],
                                  uv + 2 * (size_t)m->loop[j], uv + 2 * (size_t)m->loop[(j + 1) % b])) {
                    crossing[0] = i < j ? i : j;
                    crossing[1] = i < j ? j : i;
                    found = 1;
                }
            }
    free(g.offsets);
    free(g.segments);
    return found;
}

/*
 * The split of section 5.3: a two-source breadth-first search over faces from the triangles of the two
 * crossing boundary edges; each face joins the source it is fewer edge crossings from (ties to the first).
 * Returns 0 when both edges belong to one triangle (nothing to split).
 */
static int split_labels(int32_t *labels, int32_t *queue, const chart_mesh *m, const size_t crossing[2])
{
    const int32_t first = m->loop_triangle[crossing[0]], second = m->loop_triangle[crossing[1]];
    if (first == second)
        return 0;
    two_source_labels(labels, queue, m, first, second);
    return 1;
}

/* ---------------------------------------------------------------------------------------------
 * Charts in parallel; a chart's pieces (components, overlap splits) one after another
 * ------------------------------------------------------------------------------------------- */

typedef struct piece {
    int32_t *triangles; /* mesh triangles, owned */
    size_t count;
    int from_split;     /* made by an overlap split, not given */
} piece;

typedef struct piece_stack {
    piece *items;
    size_t size, capacity;
} piece_stack;

static int push_piece(piece_stack *stack, piece item)
{
    return SK_PUSH(*stack, item, 8);
}

/* Pushes one piece per label (labels in [0, label_count)) made of the parent's triangles with that label. */
static int push_labelled(piece_stack *stack, const piece *parent, const int32_t *labels, size_t label_count,
                         int from_split)
{
    for (size_t label = label_count; label-- > 0;) {
        size_t count = 0;
        for (size_t t = 0; t < parent->count; ++t)
            count += labels[t] == (int32_t)label;
        piece item = {sk_allocate(count, sizeof(int32_t)), 0, from_split};
        if (!item.triangles)
            return 0;
        for (size_t t = 0; t < parent->count; ++t)
            if (labels[t] == (int32_t)label)
                item.triangles[item.count++] = parent->triangles[t];
        if (!push_piece(stack, item)) {
            free(item.triangles);
            return 0;
        }
    }
    return 1;
}

typedef struct worker_state {
    pass_counts counts;
    size_t splits, flip_splits, invalid_triangles, overlapping_charts;
    sk_status status;
    size_t failed_chart;
    sk_error error;
} worker_state;

typedef struct flatten_job {
    const flatten_input *in;
    const int32_t *chart_offsets, *chart_triangles; /* the mesh triangles of each given chart, CSR */
    const int32_t *order;                           /* charts, largest first */
    size_t chart_count;
    double *uv;                                     /* destination, 6 per triangle */
    int32_t *piece_of_triangle;                     /* the piece number within its given chart */
    int32_t *piece_count;                           /* per given chart */
    atomic_size_t next;
    atomic_int failed;
    worker_state workers[SK_MAX_WORKERS];
} flatten_job;

/* Writes a finished piece: its uv per triangle corner and its number within the given chart. */
static void write_piece(flatten_job *job, const chart_mesh *m, const double *uv, int32_t number)
{
    for (size_t t = 0; t < m->triangle_count; ++t) {
        const size_t triangle = (size_t)m->triangles[t];
        for (int k = 0; k < 3; ++k) {
            const double *x = corner_uv(uv, m, t, k);
            job->uv[6 * triangle + 2 * (size_t)k] = x[0];
            job->uv[6 * triangle + 2 * (size_t)k + 1] = x[1];
        }
        job->piece_of_triangle[triangle] = number;
    }
}

/* The first flipped or degenerate triangle of the layout, or -1. */
static int32_t first_invalid(const chart_mesh *m, const double *uv)
{
    for (size_t t = 0; t < m->triangle_count; ++t)
        if (valid_double_area(corner_uv(uv, m, t, 0), corner_uv(uv, m, t, 1), corner_uv(uv, m, t, 2)) == 0.0)
            return (int32_t)t;
    return -1;
}

/*
 * Flattens a built piece; splits it (pushing the halves) when its boundary crosses itself, or when every pass
 * still left a flipped or degenerate triangle (the guarantee behind the passes: the halves are flattened
 * again, down to single triangles, which LSCM lays out as they are in the metric).
 */
static sk_status finish_piece(flatten_job *job, worker_state *w, piece_stack *stack, const piece *item,
                              const chart_mesh *m, int32_t *pieces_done)
{
    double *uv = sk_allocate(2 * m->vertex_count, sizeof *uv);
    int32_t *labels = sk_allocate(m->triangle_count, sizeof *labels);
    int32_t *queue = sk_allocate(m->triangle_count, sizeof *queue);
    sk_status status = SK_ERROR_MEMORY;
    size_t crossing[2];
    if (uv && labels && queue && flatten_chart(uv, m, job->in, &w->counts)) {
        const int crossed = find_boundary_crossing(crossing, m, uv);
        if (crossed < 0) {
            status = SK_ERROR_MEMORY;
        } else if (crossed && split_labels(labels, queue, m, crossing)) {
            status = push_labelled(stack, item, labels, 2, 1) ? SK_OK : SK_ERROR_MEMORY;
            ++w->splits;
        } else if (m->triangle_count > 1 && first_invalid(m, uv) >= 0) {
            split_around(labels, queue, m, first_invalid(m, uv));
            status = push_labelled(stack, item, labels, 2, 1) ? SK_OK : SK_ERROR_MEMORY;
            ++w->flip_splits;
        } else {
            w->overlapping_charts += crossed;
            w->invalid_triangles += count_invalid(m, uv);
            write_piece(job, m, uv, (*pieces_done)++);
            status = SK_OK;
        }
    }
    free(uv);
    free(labels);
    free(queue);
    return status;
}

static sk_status flatten_given_chart(flatten_job *job, worker_state *w, size_t chart)
{
    const size_t begin = (size_t)job->chart_offsets[chart], count = (size_t)job->chart_offsets[chart + 1] - begin;
    piece_stack stack = {NULL, 0, 0};
    int32_t pieces_done = 0;
    sk_status status = SK_OK;
    if (count > 0) {
        piece first = {sk_allocate(count, sizeof(int32_t)), count, 0};
        if (!first.triangles || !push_piece(&stack, first)) {
            free(first.triangles);
            status = SK_ERROR_MEMORY;
        } else {
            memcpy(first.triangles, job->chart_triangles + begin, count * sizeof(int32_t));
        }
    }
    while (status == SK_OK && stack.size > 0) {
        piece item = stack.items[--stack.size];
        int32_t *labels = sk_allocate(item.count, sizeof *labels);
        size_t components = 0;
        chart_mesh m;
        const build_outcome built = labels ? build_chart_mesh(&m, job->in, item.triangles, item.count, chart, labels,
                                                              &components, &w->error)
                                           : OUT_OF_MEMORY;
        if (built == BUILT) {
            status = finish_piece(job, w, &stack, &item, &m, &pieces_done);
            free_chart_mesh(&m);
        } else if (built == DISCONNECTED) {
            status = push_labelled(&stack, &item, labels, components, item.from_split) ? SK_OK : SK_ERROR_MEMORY;
        } else if (built == NOT_DISC && item.from_split) {
            /* A split of a disc can leave a piece with a hole (a half that surrounds the other); split again. */
            status = push_labelled(&stack, &item, labels, components, 1) ? SK_OK : SK_ERROR_MEMORY;
            ++w->splits;
        } else if (built == NOT_DISC) {
            status = SK_ERROR_ARGUMENT;
        } else if (built == REFUSED) {
            if (item.from_split) /* the thesis's argument says this cannot happen; say so if it does */
                sk_fail(&w->error, SK_ERROR_ARGUMENT,
                        "chart %zu: splitting its self-overlapping layout made a piece that is not a disc (%s)", chart,
                        w->error.message);
            status = SK_ERROR_ARGUMENT;
        } else {
            status = SK_ERROR_MEMORY;
        }
        free(labels);
        free(item.triangles);
    }
    while (stack.size > 0)
        free(stack.items[--stack.size].triangles);
    free(stack.items);
    job->piece_count[chart] = pieces_done;
    if (status == SK_ERROR_MEMORY)
        sk_fail(&w->error, status, "chart %zu: out of memory while flattening %zu triangles", chart, count);
    return status;
}

static void flatten_worker(void *context, size_t worker, size_t begin, size_t end)
{
    (void)begin;
    (void)end;
    flatten_job *job = context;
    worker_state *w = &job->workers[worker];
    for (;;) {
        const size_t index = atomic_fetch_add(&job->next, 1);
        if (index >= job->chart_count || atomic_load(&job->failed))
            return;
        const size_t chart = (size_t)job->order[index];
        const sk_status status = flatten_given_chart(job, w, chart);
        if (status != SK_OK) {
            w->status = status;
            w->failed_chart = chart;
            atomic_store(&job->failed, 1);
            return;
        }
    }
}

typedef struct sized_chart {
    int32_t size, chart;
} sized_chart;

static int larger_first(const void *a, const void *b)
{
    const sized_chart *x = a, *y = b;
    if (x->size != y->size)
        return x->size > y->size ? -1 : 1;
    return (x->chart > y->chart) - (x->chart < y->chart);
}

static sk_status check_flatten_arguments(const flatten_input *in, const int32_t *charts, sk_error *error)
{
    const sk_flatten_options *o = &in->options;
    if (!(isfinite(o->stretch_limit) && o->stretch_limit >= 1.0))
        return sk_fail(error, SK_ERROR_ARGUMENT, "stretch_limit must be a finite number >= 1 (got %g)",
                       o->stretch_limit);
    if (o->sweep_limit < 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "sweep_limit must not be negative (got %d)", o->sweep_limit);
    const sk_triangle_mesh mesh = {in->triangles, in->triangle_count, in->vertex_count};
    sk_status status = sk_validate_triangles(&mesh, error);
    if (status != SK_OK)
        return status;
    for (size_t t = 0; t < in->triangle_count; ++t)
        if (charts[t] < 0 || (size_t)charts[t] >= in->triangle_count)
            return sk_fail(error, SK_ERROR_INDEX, "triangle %zu has chart %d, outside [0, %zu)", t, charts[t],
                           in->triangle_count);
    return check_metric(in->edge_lengths_sq, in->triangle_count, error);
}

/* Sums the workers' counts into the report and picks the failure of the lowest-numbered chart. */
static sk_status gather(sk_flatten_report *report, const flatten_job *job, size_t workers, sk_error *error)
{
    const worker_state *failed = NULL;
    for (size_t w = 0; w < workers; ++w) {
        const worker_state *s = &job->workers[w];
        report->straight_charts += s->counts.straight_charts;
        report->circle_charts += s->counts.circle_charts;
        report->free_charts += s->counts.free_charts;
        report->extra_corners += s->counts.extra_corners;
        report->tutte_charts += s->counts.tutte_charts;
        report->solver_iterations += s->counts.solver_iterations;
        report->optimisation_sweeps += s->counts.sweeps;
        report->split_count += s->splits;
        report->flip_splits += s->flip_splits;
        report->invalid_triangles += s->invalid_triangles;
        report->overlapping_charts += s->overlapping_charts;
        if (s->status != SK_OK && (!failed || s->failed_chart < failed->failed_chart))
            failed = s;
    }
    if (failed)
        return sk_fail(error, failed->status, "%s", failed->error.message);
    return SK_OK;
}

sk_status sk_flatten(double *uv, int32_t *charts_out, sk_flatten_report *report, const sk_triangle_mesh *mesh,
                     const double *edge_lengths_sq, const int32_t *charts, const unsigned char *corners,
                     const sk_flatten_options *options, sk_error *error)
{
    if (!uv || !charts_out || !report || !mesh || !mesh->triangles || !edge_lengths_sq || !charts || !corners ||
        !options)
        return sk_fail(error, SK_ERROR_ARGUMENT, "sk_flatten: a null pointer");
    const int32_t *triangles = mesh->triangles;
    const size_t vertex_count = mesh->vertex_count, triangle_count = mesh->triangle_count;
    if (triangle_count == 0 || triangle_count > INT32_MAX / 3)
        return sk_fail(error, SK_ERROR_ARGUMENT, "triangle_count must be in [1, %d] (got %zu)", INT32_MAX / 3,
                       triangle_count);
    const flatten_input in = {triangles, edge_lengths_sq, corners, triangle_count, vertex_count, *options};
    sk_status status = check_flatten_arguments(&in, charts, error);
    if (status != SK_OK)
        return status;
    memset(report, 0, sizeof *report);
    int32_t *offsets = sk_allocate_zeroed(triangle_count + 2, sizeof *offsets);
    int32_t *members = sk_allocate(triangle_count, sizeof *members);
    int32_t *order = sk_allocate(triangle_count, sizeof *order);
    int32_t *piece_count = sk_allocate_zeroed(triangle_count, sizeof *piece_count);
    sized_chart *sized = sk_allocate(triangle_count, sizeof *sized);
    flatten_job *job = sk_allocate_zeroed(1, sizeof *job);
    if (!offsets || !members || !order || !piece_count || !sized || !job) {
        status = sk_fail(error, SK_ERROR_MEMORY, "sk_flatten: out of memory for %zu triangles", triangle_count);
        goto done;
    }
    sk_group_by_chart(offsets, members, charts, triangle_count);
    for (size_t c = 0; c < triangle_count; ++c)
        sized[c] = (sized_chart){offsets[c + 1] - offsets[c], (int32_t)c};
    qsort(sized, triangle_count, sizeof *sized, larger_first);
    for (size_t c = 0; c < triangle_count; ++c)
        order[c] = sized[c].chart;
    job->in = &in;
    job->chart_offsets = offsets;
    job->chart_triangles = members;
    job->order = order;
    job->chart_count = triangle_count;
    job->uv = uv;
    job->piece_of_triangle = charts_out;
    job->piece_count = piece_count;
    atomic_init(&job->next, 0);
    atomic_init(&job->failed, 0);
    const size_t workers = sk_worker_count(triangle_count, 1, options->thread_count);
    sk_parallel_for(triangle_count, 1, options->thread_count, flatten_worker, job);
    status = gather(report, job, workers, error);
    if (status == SK_OK) {
        /* Number the result's charts: the given charts in order, each followed by its pieces. */
        int32_t *first_number = order; /* reused: the order is no longer needed */
        int32_t total = 0;
        for (size_t c = 0; c < triangle_count; ++c) {
            first_number[c] = total;
            total += piece_count[c];
        }
        for (size_t t = 0; t < triangle_count; ++t)
            charts_out[t] += first_number[charts[t]];
        report->chart_count = (size_t)total;
        status = sk_succeed(error);
    }
done:
    free(offsets);
    free(members);
    free(order);
    free(piece_count);
    free(sized);
    free(job);
    return status;
}

/* ---------------------------------------------------------------------------------------------
 * Stretch
 * ------------------------------------------------------------------------------------------- */

static sk_status check_stretch_arguments(const double *uv, const double *edge_lengths_sq, size_t triangle_count,
                                         sk_error *error)
{
    const size_t bad = sk_first_non_finite(uv, 6 * triangle_count);
    if (bad < 6 * triangle_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "triangle %zu has a uv coordinate that is not finite", bad / 6);
    return check_metric(edge_lengths_sq, triangle_count, error);
}

/* sigma1^2 + sigma2^2 of triangle t (INFINITY when flipped or degenerate), its metric area and uv area. */
static double triangle_terms(const double *uv, const double *edge_lengths_sq, size_t t, double *area,
                             double *uv_area)
{
    double gram[3], twice_uv_area;
    gram_from_lengths(gram, edge_lengths_sq + 3 * t);
    *area = gram_area(gram);
    const double *x = uv + 6 * t;
    const double sum = singular_values_sq(gram, x, x + 2, x + 4, &twice_uv_area);
    *uv_area = twice_uv_area / 2;
    return sum;
}

sk_status sk_triangle_stretch(double *destination, const double *uv, const double *edge_lengths_sq,
                              size_t triangle_count, sk_error *error)
{
    if (!destination || !uv || !edge_lengths_sq)
        return sk_fail(error, SK_ERROR_ARGUMENT, "sk_triangle_stretch: a null pointer");
    const sk_status status = check_stretch_arguments(uv, edge_lengths_sq, triangle_count, error);
    if (status != SK_OK)
        return status;
    for (size_t t = 0; t < triangle_count; ++t) {
        double area, uv_area;
        destination[t] = sqrt(triangle_terms(uv, edge_lengths_sq, t, &area, &uv_area) / 2);
    }
    return sk_succeed(error);
}

sk_status sk_mesh_stretch(double *stretch, const double *uv, const double *edge_lengths_sq, size_t triangle_count,
                          sk_error *error)
{
    if (!stretch || !uv || !edge_lengths_sq)
        return sk_fail(error, SK_ERROR_ARGUMENT, "sk_mesh_stretch: a null pointer");
    if (triangle_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "sk_mesh_stretch: no triangles");
    const sk_status status = check_stretch_arguments(uv, edge_lengths_sq, triangle_count, error);
    if (status != SK_OK)
        return status;
    double weighted = 0.0, total_area = 0.0, total_uv_area = 0.0;
    for (size_t t = 0; t < triangle_count; ++t) {
        double area, uv_area;
        const double singular_sum = triangle_terms(uv, edge_lengths_sq, t, &area, &uv_area);
        weighted += area * singular_sum / 2;
        total_area += area;
        total_uv_area += uv_area;
    }
    *stretch = isfinite(weighted) ? sqrt(weighted * total_uv_area) / total_area : INFINITY;
    return sk_succeed(error);
}
