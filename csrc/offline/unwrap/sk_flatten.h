/*
 * What the files of flattening share (internal to csrc/offline/unwrap): the metric and uv triangles, a chart as a
 * mesh of its own, the sparse solver, the stretch and its optimisation, the passes and the overlap split.
 * sk_flatten.c runs them over the charts in parallel.
 */
#ifndef SK_FLATTEN_H
#define SK_FLATTEN_H

#include <math.h>

#include "sk_mesh.h"

/* A uv triangle is degenerate when twice its area is below this fraction of its longest edge squared. */
#define DEGENERATE_UV_RATIO 1e-12
/* A uv triangle whose share of its chart's uv area is below this times its share of the metric area has collapsed
 * (see sk_count_invalid): an area scale 1e-8 of the chart's average, a length scale 1e-4. */
#define COLLAPSED_UV_SHARE 1e-8
/* A metric triangle must have g11 g22 - g12^2 above this fraction of g11 g22 (sine squared of its angle). */
#define DEGENERATE_METRIC_RATIO 1e-14
#define CG_RELATIVE_TOLERANCE 1e-12
/* The relaxation factor of the CG preconditioner's SSOR sweeps (sk_lscm.c), in (0, 2): 1.6 took 17% fewer steps
 * than 1.0 (Gauss-Seidel) on the creature's charts. */
#define SSOR_OMEGA 1.6
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
 * Metric triangles and uv triangles (sk_stretch.c)
 * ------------------------------------------------------------------------------------------- */

/* The Gram matrix of e1 = y_b - y_a, e2 = y_c - y_a from the squared lengths of ab, bc, ca (polarisation). */
static inline void gram_from_lengths(double gram[3], const double lengths_sq[3])
{
    gram[0] = lengths_sq[0];
    gram[1] = (lengths_sq[0] + lengths_sq[2] - lengths_sq[1]) / 2;
    gram[2] = lengths_sq[2];
}

static inline double gram_area(const double gram[3])
{
    const double determinant = gram[0] * gram[2] - gram[1] * gram[1];
    return determinant > 0 ? sqrt(determinant) / 2 : 0.0;
}

static inline double cross2(double ax, double ay, double bx, double by)
{
    return ax * by - ay * bx;
}

/* Twice the signed area of uv triangle (a, b, c), or 0 when it is flipped or degenerate. */
static inline double valid_double_area(const double a[2], const double b[2], const double c[2])
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
static inline double singular_values_sq(const double gram[3], const double a[2], const double b[2], const double c[2],
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

sk_status sk_check_metric(const double *edge_lengths_sq, size_t triangle_count, sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * A chart as a mesh of its own (sk_chart_mesh.c)
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

typedef enum build_outcome { BUILT, DISCONNECTED, NOT_DISC, REFUSED, OUT_OF_MEMORY } build_outcome;

typedef struct flatten_input {
    const int32_t *triangles;
    const double *edge_lengths_sq;
    const unsigned char *corners;
    size_t triangle_count, vertex_count;
    sk_flatten_options options;
} flatten_input;

/* The position of vertex j in vertex i's ring, or -1. */
static inline int32_t ring_slot(const chart_mesh *m, int32_t i, int32_t j)
{
    for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s)
        if (m->ring[s] == j)
            return s;
    return -1;
}

void sk_free_chart_mesh(chart_mesh *m);

/*
 * Builds the chart's own mesh from `count` mesh triangles: the corners of each mesh vertex that are joined
 * round a fan become one local vertex (a vertex where the chart touches itself becomes two), and non-manifold
 * and inconsistently oriented edges are refused. DISCONNECTED leaves component labels (one per triangle) in
 * `labels`; NOT_DISC (closed, or more than one boundary loop) leaves the reason in *error and a split of the
 * piece in two in `labels` (*component_count = 2); REFUSED leaves the reason in *error.
 */
build_outcome sk_build_chart_mesh(chart_mesh *m, const flatten_input *in, const int32_t *triangles, size_t count,
                                      size_t chart, int32_t *labels, size_t *component_count, sk_error *error);

/* Labels each triangle 0 or 1 by the source it is fewer steps from across interior edges (ties to the first). */
void sk_two_source_labels(int32_t *labels, int32_t *queue, const chart_mesh *m, int32_t first, int32_t second);

/*
 * Splits a connected piece of two or more triangles in two: the triangles nearer to `seed` than to the
 * triangle farthest from it (breadth-first over faces), and the rest.
 */
void sk_split_around(int32_t *labels, int32_t *queue, const chart_mesh *m, int32_t seed);

/* ---------------------------------------------------------------------------------------------
 * LSCM and Tutte: assembly and preconditioned conjugate gradients (sk_lscm.c)
 * ------------------------------------------------------------------------------------------- */

static inline double dot(const double *a, const double *b, size_t count)
{
    double sum = 0.0;
    for (size_t i = 0; i < count; ++i)
        sum += a[i] * b[i];
    return sum;
}

typedef void (*assembler)(double *blocks, const chart_mesh *m);

/* The storage of a conjugate-gradient solve over a chart: the matrix's blocks, the inverse diagonal blocks
 * and the four vectors. */
typedef struct amg_hierarchy amg_hierarchy;
typedef struct linear_system {
    double *blocks, *inverse, *r, *z, *p, *q;
    amg_hierarchy *amg; /* the multigrid preconditioner when the chart is big enough for one, else NULL (SSOR) */
} linear_system;

/* Free vertices from which a solve builds the multigrid preconditioner (sk_amg.c) instead of SSOR alone: below
 * it SSOR's steps are few and the hierarchy's setup costs more than it saves. */
#define AMG_MIN_FREE_VERTICES 1000

/*
 * The smoothed-aggregation multigrid hierarchy of the chart's blocks over its free vertices (sk_amg.c); NULL
 * when memory ran out.
 */
amg_hierarchy *sk_build_amg(const double *blocks, const chart_mesh *m, const unsigned char *pinned);
/* z = M^-1 r (2 per chart vertex, pinned entries of z set to 0): one symmetric V-cycle (h holds its vectors). */
void sk_apply_amg(double *z, amg_hierarchy *h, const chart_mesh *m, const double *r);
void sk_free_amg(amg_hierarchy *h);

/*
 * Adds each triangle's LSCM term |sum_k W_k U_k|^2 / (2 area) (W_k = z_{k+2} - z_{k+1} in the local frame,
 * U_k = u_k + i v_k) to the normal matrix, stored as one 2x2 block (u, v rows and columns) per ring entry.
 */
void sk_assemble_lscm(double *blocks, const chart_mesh *m);

/* The Dirichlet energy of u and v, the same for both (the cotangent Laplacian in each block's diagonal, 0 off it):
 * LSCM's term without its area part. */
void sk_assemble_dirichlet(double *blocks, const chart_mesh *m);

/*
 * Tutte's barycentric embedding (uniform weights): each vertex's block row says it sits at the average of
 * its neighbours. With the boundary pinned on a convex polygon no triangle flips (Tutte 1963).
 */
void sk_assemble_tutte(double *blocks, const chart_mesh *m);

void sk_free_system(linear_system *system);

int sk_allocate_system(linear_system *system, const chart_mesh *m);

/* The inverse of each free vertex's diagonal block, which the preconditioner's sweeps apply. */
void sk_invert_diagonal(linear_system *system, const chart_mesh *m, const unsigned char *pinned);

/* Preconditioned CG from x, whose residual is in system->r, until |r|^2 <= tolerance_sq or `limit` steps;
 * returns the steps. */
size_t sk_conjugate_gradients(double *x, linear_system *system, const chart_mesh *m, const unsigned char *pinned,
                                  double tolerance_sq, size_t limit);

/*
 * Allocates a system over the chart, assembles it and prepares its preconditioner: the inverse diagonal blocks, and
 * the multigrid hierarchy when AMG_MIN_FREE_VERTICES or more vertices are free. Returns 0 when memory ran out.
 */
int sk_prepare_system(linear_system *system, const chart_mesh *m, const unsigned char *pinned, assembler assemble);

/* CG from x (its residual in system->r) until |r| is CG_RELATIVE_TOLERANCE of the right side's norm (rhs_sq its
 * square), or 4 steps a vertex; returns the steps. */
size_t sk_solve_to_tolerance(double *x, linear_system *system, const chart_mesh *m, const unsigned char *pinned,
                             double rhs_sq);

/*
 * Minimises the quadratic energy `assemble` builds (LSCM's, or Tutte's) over the free vertices of uv (2 per
 * local vertex; pinned entries are the pins, free entries the starting guess). Returns 0 when memory ran
 * out; *iterations counts CG steps.
 */
int sk_solve_quadratic(double *uv, const chart_mesh *m, const unsigned char *pinned, assembler assemble,
                           size_t *iterations);

/* ---------------------------------------------------------------------------------------------
 * Boundary first flattening (sk_boundary_first.c)
 * ------------------------------------------------------------------------------------------- */

/* Interior vertices from which the free pass flattens a chart by boundary first flattening instead of LSCM with
 * two pins: where the multigrid takes over from SSOR (AMG_MIN_FREE_VERTICES) and LSCM's steps start to grow; smaller
 * charts, which SSOR solves in few steps, keep the thesis' LSCM (BENCHMARKS.md, session 15). */
#define BOUNDARY_FIRST_MIN_VERTICES 1000

/*
 * A conformal layout of the chart (2 per local vertex) whose boundary keeps its metric lengths. Returns 1, 0 when
 * the boundary polygon could not be closed (uv is then undefined; LSCM with two pins is the fallback) or -1 when
 * memory ran out. *iterations counts CG steps.
 */
int sk_boundary_first_layout(double *uv, const chart_mesh *m, size_t *iterations);

/* ---------------------------------------------------------------------------------------------
 * Stretch of a chart and its optimisation (sk_stretch.c)
 * ------------------------------------------------------------------------------------------- */

static inline const double *corner_uv(const double *uv, const chart_mesh *m, size_t t, int k)
{
    return uv + 2 * (size_t)m->corner[3 * t + (size_t)k];
}

typedef struct pass_counts {
    size_t straight_charts, circle_charts, free_charts, extra_corners, tutte_charts, boundary_first_charts;
    size_t solver_iterations, sweeps;
} pass_counts;

double sk_chart_metric_area(const chart_mesh *m);

/* Sander's normalised L2 stretch of the chart (INFINITY when a triangle is flipped or degenerate). */
double sk_chart_stretch(const chart_mesh *m, const double *uv);

/* The triangle of the layout with the largest sigma1^2 + sigma2^2 (the most stretched, at any common scale). */
int32_t sk_most_stretched(const chart_mesh *m, const double *uv);

/* A free-boundary chart of STRETCH_SPLIT_MIN_TRIANGLES or more whose optimised layout still stretches more than
 * STRETCH_SPLIT_LIMIT is split in two, like one whose layout overlaps itself, and each half flattened again. Such a
 * chart is too curved to lie flat whole: LSCM with two pins used to fold it (and the overlap split cut it), boundary
 * first flattening lays it out whole at a stretch of 1.2 and more (BENCHMARKS.md, session 15). The benchmark
 * characters' worst chart stretches 1.072; halves stay above about 1000 triangles, so a rough mesh is not cut to
 * crumbs. */
#define STRETCH_SPLIT_LIMIT 1.1
#define STRETCH_SPLIT_MIN_TRIANGLES 2000

size_t sk_count_invalid(const chart_mesh *m, const double *uv);
/* The first flipped, degenerate or collapsed triangle of the chart's layout, or -1. */
int32_t sk_first_invalid(const chart_mesh *m, const double *uv);

/*
 * Minimises the chart's normalised L2 stretch (Sander et al. 2001, eq. 5.6-5.8) by Newton steps on one
 * movable vertex at a time, in a fixed order, until a sweep improves the stretch by less than
 * STRETCH_RELATIVE_IMPROVEMENT or after sweep_limit sweeps. No step flips a triangle; a layout that already
 * has a flipped or degenerate triangle is left alone (its stretch is infinite: no move can be compared).
 */
void sk_optimise_stretch(const chart_mesh *m, double *uv, const unsigned char *movable, int sweep_limit,
                             pass_counts *counts);

/* ---------------------------------------------------------------------------------------------
 * The passes (sk_flatten_passes.c) and the overlap split (sk_overlap.c)
 * ------------------------------------------------------------------------------------------- */

/*
 * Flattens one disc chart into result (2 per local vertex) by the passes of section 5.3. Returns 0 when memory
 * ran out.
 */
int sk_flatten_chart(double *result, const chart_mesh *m, const flatten_input *in, pass_counts *counts);

/*
 * Finds two non-adjacent boundary edges of the layout that cross or touch; returns 0 when there are none and
 * -1 when memory ran out. The edges go into a uniform grid of about one cell per edge (cells about one edge
 * long, at most four per edge), so only edges sharing a cell are compared.
 */
int sk_find_boundary_crossing(size_t crossing[2], const chart_mesh *m, const double *uv);

/*
 * The split of section 5.3: a two-source breadth-first search over faces from the triangles of the two
 * crossing boundary edges; each face joins the source it is fewer edge crossings from (ties to the first).
 * Returns 0 when both edges belong to one triangle (nothing to split).
 */
int sk_split_labels(int32_t *labels, int32_t *queue, const chart_mesh *m, const size_t crossing[2]);

#endif
