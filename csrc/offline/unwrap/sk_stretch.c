/*
 * Sander et al. 2001's L2 stretch: of metric and uv triangles, of a chart, its minimisation by global steps and
 * per-vertex Newton steps that never flip a triangle, and the public sk_triangle_stretch and sk_mesh_stretch.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_flatten.h"

/* ---------------------------------------------------------------------------------------------
 * Metric triangles and uv triangles
 * ------------------------------------------------------------------------------------------- */

sk_status sk_check_metric(const double *edge_lengths_sq, size_t triangle_count, sk_error *error)
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

/* ---------------------------------------------------------------------------------------------
 * Stretch of a chart and Sander's optimisation
 * ------------------------------------------------------------------------------------------- */

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

double sk_chart_metric_area(const chart_mesh *m)
{
    double total = 0.0;
    for (size_t t = 0; t < m->triangle_count; ++t)
        total += m->area[t];
    return total;
}

/* Sander's normalised L2 stretch of the chart (INFINITY when a triangle is flipped or degenerate). */
double sk_chart_stretch(const chart_mesh *m, const double *uv)
{
    const stretch_sums total = chart_sums(m, uv);
    return isfinite(total.weighted) ? sqrt(total.weighted * total.uv_area) / sk_chart_metric_area(m) : INFINITY;
}

int32_t sk_most_stretched(const chart_mesh *m, const double *uv)
{
    int32_t worst = 0;
    double largest = -1.0;
    for (size_t t = 0; t < m->triangle_count; ++t) {
        double twice_area;
        const double sum = singular_values_sq(m->gram + 3 * t, corner_uv(uv, m, t, 0), corner_uv(uv, m, t, 1),
                                              corner_uv(uv, m, t, 2), &twice_area);
        if (sum > largest) {
            largest = sum;
            worst = (int32_t)t;
        }
    }
    return worst;
}

/*
 * A uv triangle is invalid when it is flipped or degenerate in its own shape (valid_double_area), or when it has
 * collapsed relative to its chart: its share of the chart's uv area is below COLLAPSED_UV_SHARE times its share of
 * the chart's metric area (a scale factor under about 1e-4 against the chart's average: triangles laid onto each
 * other, or shrunk to nothing while the rest of the chart keeps its size). So the test does not depend on the
 * chart's size, only on how each triangle compares with it; a single triangle is always valid.
 */
static double chart_uv_area(const chart_mesh *m, const double *uv)
{
    double total = 0.0;
    for (size_t t = 0; t < m->triangle_count; ++t)
        total += fabs(cross2(corner_uv(uv, m, t, 1)[0] - corner_uv(uv, m, t, 0)[0],
                             corner_uv(uv, m, t, 1)[1] - corner_uv(uv, m, t, 0)[1],
                             corner_uv(uv, m, t, 2)[0] - corner_uv(uv, m, t, 0)[0],
                             corner_uv(uv, m, t, 2)[1] - corner_uv(uv, m, t, 0)[1]));
    return total;
}

static int triangle_invalid(const chart_mesh *m, const double *uv, size_t t, double uv_total, double metric_total)
{
    const double twice_area = valid_double_area(corner_uv(uv, m, t, 0), corner_uv(uv, m, t, 1), corner_uv(uv, m, t, 2));
    if (twice_area == 0.0)
        return 1;
    return m->triangle_count > 1 && !(twice_area / uv_total >= COLLAPSED_UV_SHARE * m->area[t] / metric_total);
}

int32_t sk_first_invalid(const chart_mesh *m, const double *uv)
{
    const double uv_total = chart_uv_area(m, uv), metric_total = sk_chart_metric_area(m);
    for (size_t t = 0; t < m->triangle_count; ++t)
        if (triangle_invalid(m, uv, t, uv_total, metric_total))
            return (int32_t)t;
    return -1;
}

size_t sk_count_invalid(const chart_mesh *m, const double *uv)
{
    const double uv_total = chart_uv_area(m, uv), metric_total = sk_chart_metric_area(m);
    size_t invalid = 0;
    for (size_t t = 0; t < m->triangle_count; ++t)
        invalid += (size_t)triangle_invalid(m, uv, t, uv_total, metric_total);
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
    sk_free_system(&g->system);
    free(g->fixed);
    free(g->direction);
    free(g->trial);
}

static int allocate_global(global_solver *g, const chart_mesh *m, const unsigned char *movable)
{
    const size_t v = m->vertex_count;
    if (!sk_allocate_system(&g->system, m))
        return 0;
    g->fixed = sk_allocate(v, 1);
    g->direction = sk_allocate(2 * v, sizeof *g->direction);
    g->trial = sk_allocate(2 * v, sizeof *g->trial);
    if (!g->fixed || !g->direction || !g->trial) {
        free_global(g);
        return 0;
    }
    size_t free_count = 0;
    for (size_t i = 0; i < v; ++i) {
        g->fixed[i] = !movable[i];
        free_count += movable[i] != 0;
    }
    sk_assemble_dirichlet(g->system.blocks, m);
    if (free_count >= AMG_MIN_FREE_VERTICES) {
        /* GLOBAL_CG_STEPS of SSOR carry a step only a few rings on a large chart; the multigrid carries it across.
         * With every vertex movable the Laplacian is singular (a translation costs nothing), which the multigrid's
         * coarsest factorisation cannot take: one vertex is held, which changes a step by a translation only. */
        if (free_count == v)
            g->fixed[0] = 1;
        g->system.amg = sk_build_amg(g->system.blocks, m, g->fixed); /* NULL (out of memory): SSOR still steps */
    }
    sk_invert_diagonal(&g->system, m, g->fixed);
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
    *iterations += sk_conjugate_gradients(g->direction, &g->system, m, g->fixed,
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
void sk_optimise_stretch(const chart_mesh *m, double *uv, const unsigned char *movable, int sweep_limit,
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
 * Stretch
 * ------------------------------------------------------------------------------------------- */

static sk_status check_stretch_arguments(const double *uv, const double *edge_lengths_sq, size_t triangle_count,
                                         sk_error *error)
{
    const size_t bad = sk_first_non_finite(uv, 6 * triangle_count);
    if (bad < 6 * triangle_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "triangle %zu has a uv coordinate that is not finite", bad / 6);
    return sk_check_metric(edge_lengths_sq, triangle_count, error);
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
