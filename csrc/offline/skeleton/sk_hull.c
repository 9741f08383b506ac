/*
 * Convex hulls, kernels and hull moments for skeleton extraction (Vasilakis 2008, sections 2.3.1-2.3.2, 3.2.3):
 * Qhull (reentrant libqhull_r) builds the hulls; the kernel is a half-space intersection done the way qhalf does it
 * (dual points about an interior point, their hull, each dual facet a kernel vertex).
 */
#include <lapacke.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <libqhull_r/libqhull_r.h>

#include "sk_skeleton_internal.h"

void sk_hull_free(sk_hull *hull)
{
    SK_FREE_ALL(hull->corners, hull->planes);
    memset(hull, 0, sizeof *hull);
}

/* Qhull writes its diagnostics (a flat input, a precision problem) to a file: a scratch one, never the user's
 * console; stderr only when no scratch file can be made. */
static FILE *open_diagnostics(int *owned)
{
    FILE *file = tmpfile();
    *owned = file != NULL;
    return file ? file : stderr;
}

/* Copies the triangulated facets of the hull Qhull holds into *hull. 0 when memory ran out. */
static int collect_facets(sk_hull *hull, qhT *qh)
{
    facetT *facet;
    size_t count = 0;
    FORALLfacets
        ++count;
    hull->corners = sk_allocate(count * 9, sizeof(double));
    hull->planes = sk_allocate(count * 4, sizeof(double));
    if (!hull->corners || !hull->planes)
        return 0;
    FORALLfacets {
        vertexT *vertex, **vertexp;
        size_t corner = 0;
        double *triangle = hull->corners + 9 * hull->triangle_count;
        FOREACHvertex_(facet->vertices) {
            if (corner < 3)
                memcpy(triangle + 3 * corner, vertex->point, 3 * sizeof(double));
            ++corner;
        }
        double *plane = hull->planes + 4 * hull->plane_count++;
        memcpy(plane, facet->normal, 3 * sizeof(double));
        plane[3] = facet->offset;
        if (corner == 3) /* "Qt" triangulates, so every facet is a triangle; a safeguard all the same */
            ++hull->triangle_count;
    }
    return 1;
}

int sk_hull_build(sk_hull *hull, const double *points, size_t count)
{
    memset(hull, 0, sizeof *hull);
    if (count < 4 || count > (size_t)INT32_MAX / 3)
        return 0;
    coordT *copy = sk_allocate(count * 3, sizeof(coordT)); /* Qhull takes a non-const array */
    qhT *qh = sk_allocate_zeroed(1, sizeof(qhT));
    if (!copy || !qh) {
        SK_FREE_ALL(copy, qh);
        return -1;
    }
    memcpy(copy, points, count * 3 * sizeof(double));
    int owned = 0;
    FILE *diagnostics = open_diagnostics(&owned);
    qh_zero(qh, diagnostics);
    char command[] = "qhull Qt Pp";
    int result = 0;
    if (qh_new_qhull(qh, 3, (int)count, copy, False, command, NULL, diagnostics) == 0)
        result = collect_facets(hull, qh) ? 1 : -1;
    int long_blocks = 0, long_bytes = 0;
    qh_freeqhull(qh, !qh_ALL);
    qh_memfreeshort(qh, &long_blocks, &long_bytes);
    if (owned)
        fclose(diagnostics);
    SK_FREE_ALL(copy, qh);
    if (result != 1)
        sk_hull_free(hull);
    return result;
}

static double triangle_area(const double *t, double centre[3])
{
    const double u[3] = {t[3] - t[0], t[4] - t[1], t[5] - t[2]}, v[3] = {t[6] - t[0], t[7] - t[1], t[8] - t[2]};
    double n[3];
    sk_cross3(n, u, v);
    for (int c = 0; c < 3; ++c)
        centre[c] = (t[c] + t[3 + c] + t[6 + c]) / 3.0;
    return 0.5 * sqrt(sk_dot3(n, n));
}

double sk_hull_centroid(double centroid[3], const sk_hull *hull)
{
    double total = 0.0, sum[3] = {0, 0, 0};
    for (size_t t = 0; t < hull->triangle_count; ++t) {
        double centre[3];
        const double area = triangle_area(hull->corners + 9 * t, centre);
        total += area;
        for (int c = 0; c < 3; ++c)
            sum[c] += area * centre[c];
    }
    for (int c = 0; c < 3; ++c)
        centroid[c] = total > 0.0 ? sum[c] / total : 0.0;
    return total;
}

void sk_hull_covariance(double covariance[9], const sk_hull *hull, const double centroid[3])
{
    double total = 0.0, sum[9] = {0};
    for (size_t t = 0; t < hull->triangle_count; ++t) {
        const double *p = hull->corners + 9 * t;
        double m[3];
        const double area = triangle_area(p, m);
        total += area;
        for (int i = 0; i < 3; ++i)
            for (int j = 0; j < 3; ++j)
                sum[3 * i + j] += area * (9.0 * m[i] * m[j] + p[i] * p[j] + p[3 + i] * p[3 + j] + p[6 + i] * p[6 + j]);
    }
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            covariance[3 * i + j] = total > 0.0 ? sum[3 * i + j] / (12.0 * total) - centroid[i] * centroid[j] : 0.0;
}

int sk_principal_axes(double axes[9], double values[3], const double symmetric[9])
{
    double a[9], w[3];
    memcpy(a, symmetric, sizeof a);
    if (LAPACKE_dsyev(LAPACK_ROW_MAJOR, 'V', 'U', 3, a, 3, w) != 0)
        return 0;
    for (int k = 0; k < 3; ++k) { /* dsyev sorts ascending and stores eigenvectors as columns */
        values[k] = w[2 - k];
        for (int c = 0; c < 3; ++c)
            axes[3 * k + c] = a[3 * c + (2 - k)];
    }
    return 1;
}

/* The least slack d - n.x over the half-spaces, and the one that attains it. */
static double least_margin(const double *halfspaces, size_t count, const double x[3], size_t *tightest)
{
    double least = INFINITY;
    for (size_t i = 0; i < count; ++i) {
        const double *h = halfspaces + 4 * i;
        const double margin = h[3] - sk_dot3(h, x);
        if (margin < least) {
            least = margin;
            *tightest = i;
        }
    }
    return least;
}

/* A point strictly inside every half-space, started from the guess: a subgradient ascent of the least margin (the
 * Chebyshev centre problem), stopped once the margin is a thousandth of the scale. The margin it reached. */
static double interior_point(double x[3], const double *halfspaces, size_t count, const double guess[3], double scale)
{
    enum { ITERATIONS = 400 };
    double current[3] = {guess[0], guess[1], guess[2]};
    size_t tightest = 0;
    double best = least_margin(halfspaces, count, current, &tightest);
    memcpy(x, current, sizeof current);
    for (int k = 0; k < ITERATIONS && best < 1e-3 * scale; ++k) {
        least_margin(halfspaces, count, current, &tightest);
        const double step = 0.05 * scale / sqrt(1.0 + k);
        for (int c = 0; c < 3; ++c)
            current[c] -= step * halfspaces[4 * tightest + (size_t)c];
        const double margin = least_margin(halfspaces, count, current, &tightest);
        if (margin > best) {
            best = margin;
            memcpy(x, current, sizeof current);
        }
    }
    return best;
}

int sk_kernel_centroid(double centroid[3], const double *halfspaces, size_t count, const double guess[3], double scale)
{
    double inside[3];
    if (count < 4 || !(scale > 0.0) || interior_point(inside, halfspaces, count, guess, scale) <= 1e-9 * scale)
        return 0;
    double *dual = sk_allocate(count * 3, sizeof(double));
    if (!dual)
        return -1;
    for (size_t i = 0; i < count; ++i) { /* n.(x - inside) <= d - n.inside, scaled to 1 */
        const double *h = halfspaces + 4 * i;
        const double slack = h[3] - sk_dot3(h, inside);
        for (int c = 0; c < 3; ++c)
            dual[3 * i + (size_t)c] = h[c] / slack;
    }
    sk_hull dual_hull, kernel_hull;
    int result = sk_hull_build(&dual_hull, dual, count);
    free(dual);
    if (result != 1)
        return result;
    /* Each facet a.y + o = 0 of the dual hull (o < 0: the origin inside) is the kernel vertex inside + a / -o; an
     * offset near 0 means the origin is on the dual hull's border: the kernel is unbounded. */
    double *vertices = sk_allocate(dual_hull.plane_count * 3, sizeof(double));
    if (!vertices) {
        sk_hull_free(&dual_hull);
        return -1;
    }
    for (size_t f = 0; f < dual_hull.plane_count && result == 1; ++f) {
        const double *plane = dual_hull.planes + 4 * f;
        if (!(plane[3] < -1e-12 / scale))
            result = 0;
        for (int c = 0; c < 3; ++c)
            vertices[3 * f + (size_t)c] = inside[c] + plane[c] / -plane[3];
    }
    if (result == 1)
        result = sk_hull_build(&kernel_hull, vertices, dual_hull.plane_count);
    if (result == 1) {
        sk_hull_centroid(centroid, &kernel_hull);
        sk_hull_free(&kernel_hull);
    }
    free(vertices);
    sk_hull_free(&dual_hull);
    return result;
}
