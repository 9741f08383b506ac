/*
 * The free boundary of a large chart by boundary first flattening (Sawhney and Crane 2017, "Boundary First
 * Flattening"), with the boundary keeping its metric lengths (scale factor 0 on the boundary). LSCM with two pins
 * (sk_flatten_passes.c) reaches a conformal map too, but its free boundary leaves CG a near-null space of every
 * near-holomorphic map, so its steps grow with the chart even with the multigrid (as vertices^0.46 on jittered height
 * fields; 480-500 steps on the 1M-vertex creature's 50k-60k charts). Here the same kind of map comes from solves the
 * multigrid does in nearly constant steps: one Poisson problem with the boundary pinned, then LSCM with the boundary
 * pinned where the first solve put it. (The Poisson problem is scalar; it runs on the same 2x2-block solver, its
 * second component's right side 0.)
 *
 * The steps: the angle defect K of every interior vertex and the geodesic curvature k of every boundary vertex
 * (pi minus its angle sum); the conformal factor u with L u = -K inside and u = 0 on the boundary (L the cotangent
 * Laplacian); the flattened boundary's curvature k + (L u) at each boundary vertex, which sums to 2 pi (discrete
 * Gauss-Bonnet); the boundary polygon by turning through those angles along the metric edge lengths, closed by the
 * least change of the lengths (weighted by 1 / length); and the interior by LSCM with that polygon pinned.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_flatten.h"

/* The cosine-side of corner k's angle: the dot product of its two edges, from the triangle's Gram matrix
 * (e1 = y_b - y_a, e2 = y_c - y_a). Twice the area is the cross product's length at every corner. */
static double corner_dot(const double gram[3], int k)
{
    if (k == 0)
        return gram[1];
    return k == 1 ? gram[0] - gram[1] : gram[2] - gram[1];
}

/* Each local vertex's angle sum, into `angles`. */
static void angle_sums(double *angles, const chart_mesh *m)
{
    memset(angles, 0, m->vertex_count * sizeof *angles);
    for (size_t t = 0; t < m->triangle_count; ++t)
        for (int k = 0; k < 3; ++k)
            angles[m->corner[3 * t + (size_t)k]] += atan2(2 * m->area[t], corner_dot(m->gram + 3 * t, k));
}

/*
 * The conformal factor u (in x[2i]; x[2i + 1] stays 0) with L u = -K at interior vertices and u = 0 on the
 * boundary, and (L u) at every vertex into lu. Returns 0 when memory ran out.
 */
static int conformal_factor(double *x, double *lu, const chart_mesh *m, const double *angles, size_t *iterations)
{
    linear_system system;
    if (!sk_prepare_system(&system, m, m->on_boundary, sk_assemble_dirichlet))
        return 0;
    double source_sq = 0.0;
    memset(x, 0, 2 * m->vertex_count * sizeof *x);
    for (size_t i = 0; i < m->vertex_count; ++i) {
        system.r[2 * i] = m->on_boundary[i] ? 0.0 : angles[i] - TWO_PI; /* -K */
        source_sq += system.r[2 * i] * system.r[2 * i];
    }
    *iterations += sk_solve_to_tolerance(x, &system, m, m->on_boundary, source_sq);
    for (size_t i = 0; i < m->vertex_count; ++i) {
        lu[i] = 0.0;
        for (int32_t s = m->ring_offsets[i]; s < m->ring_offsets[i + 1]; ++s)
            lu[i] += system.blocks[4 * (size_t)s] * x[2 * (size_t)m->ring[s]];
    }
    sk_free_system(&system);
    return 1;
}

/*
 * The boundary polygon into uv: edge i of the loop turned by the flattened curvature of loop[i] from edge i - 1,
 * its length the metric length closed by the least weighted change. Returns 0 when the polygon cannot be closed
 * (its directions all parallel) or closing it would make an edge non-positive.
 */
static int boundary_polygon(double *uv, double *direction, const chart_mesh *m, const double *angles,
                            const double *lu)
{
    const size_t b = m->boundary_count;
    double heading = 0.0, gap[2] = {0.0, 0.0}, moment[3] = {0.0, 0.0, 0.0}; /* sum l t, sum l t t' */
    for (size_t i = 0; i < b; ++i) {
        const int32_t vertex = m->loop[i];
        if (i > 0)
            heading += TWO_PI / 2 - angles[vertex] + lu[vertex];
        const double c = cos(heading), s = sin(heading), length = m->loop_length[i];
        direction[2 * i] = c;
        direction[2 * i + 1] = s;
        gap[0] += length * c;
        gap[1] += length * s;
        moment[0] += length * c * c;
        moment[1] += length * c * s;
        moment[2] += length * s * s;
    }
    const double determinant = moment[0] * moment[2] - moment[1] * moment[1];
    if (!(determinant > 1e-12 * (moment[0] + moment[2]) * (moment[0] + moment[2])))
        return 0;
    const double lambda[2] = {(moment[2] * gap[0] - moment[1] * gap[1]) / determinant,
                              (moment[0] * gap[1] - moment[1] * gap[0]) / determinant};
    double at[2] = {0.0, 0.0};
    for (size_t i = 0; i < b; ++i) {
        const double *t = direction + 2 * i, length = m->loop_length[i];
        const double closed = length * (1.0 - (t[0] * lambda[0] + t[1] * lambda[1]));
        if (!(closed > 0))
            return 0;
        uv[2 * (size_t)m->loop[i]] = at[0];
        uv[2 * (size_t)m->loop[i] + 1] = at[1];
        at[0] += closed * t[0];
        at[1] += closed * t[1];
    }
    return 1;
}

int sk_boundary_first_layout(double *uv, const chart_mesh *m, size_t *iterations)
{
    const size_t v = m->vertex_count;
    double *angles = sk_allocate(v, sizeof *angles), *lu = sk_allocate(v, sizeof *lu);
    double *direction = sk_allocate(2 * m->boundary_count, sizeof *direction);
    int outcome = angles && lu && direction ? 1 : -1;
    if (outcome > 0) {
        angle_sums(angles, m);
        outcome = conformal_factor(uv, lu, m, angles, iterations) ? 1 : -1;
    }
    if (outcome > 0) {
        memset(uv, 0, 2 * v * sizeof *uv);
        outcome = boundary_polygon(uv, direction, m, angles, lu);
    }
    if (outcome > 0)
        outcome = sk_solve_quadratic(uv, m, m->on_boundary, sk_assemble_lscm, iterations) ? 1 : -1;
    SK_FREE_ALL(angles, lu, direction);
    return outcome;
}
