/* Geometry shared by the skeleton family's files (Vasilakis 2008, chapter 2): not part of the public contract. */
#ifndef SK_SKELETON_INTERNAL_H
#define SK_SKELETON_INTERNAL_H

#include <math.h>

#include "sk_internal.h"

/* A convex hull as triangles (9 coordinates each) and its facet planes (normal, offset: n.x + offset <= 0 inside). */
typedef struct sk_hull {
    double *corners;
    size_t triangle_count;
    double *planes;
    size_t plane_count;
} sk_hull;

/* The hull of `count` points (3 each) by Qhull. Returns 1 on success, 0 when the points are too few or flat (no
 * hull; *hull is then empty), -1 when memory ran out. */
int sk_hull_build(sk_hull *hull, const double *points, size_t count);
void sk_hull_free(sk_hull *hull);

/* The area-weighted centroid of the hull's surface (m_H, section 2.3.2) and its area. */
double sk_hull_centroid(double centroid[3], const sk_hull *hull);

/* Gottschalk's continuous covariance over the hull's triangles (section 3.2.3) about m_H. */
void sk_hull_covariance(double covariance[9], const sk_hull *hull, const double centroid[3]);

/*
 * The kernel of the half-spaces n.x <= d (4 per half-space: unit n, d) by half-space intersection: an interior point
 * (the guess, else a subgradient ascent of the least margin), the dual points' hull by Qhull, and the kernel
 * centroid, the area-weighted centroid of the hull of the kernel's vertices. Returns 1 when the kernel is non-empty
 * (centroid written), 0 when it is empty or unbounded, -1 when memory ran out. scale: the part's diagonal.
 */
int sk_kernel_centroid(double centroid[3], const double *halfspaces, size_t count, const double guess[3], double scale);

/* Eigenvectors of a symmetric 3x3 (LAPACKE), as rows of `axes`, by decreasing eigenvalue. 0 on LAPACK failure. */
int sk_principal_axes(double axes[9], double values[3], const double symmetric[9]);

static inline double sk_dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static inline void sk_cross3(double out[3], const double a[3], const double b[3])
{
    const double x = a[1] * b[2] - a[2] * b[1], y = a[2] * b[0] - a[0] * b[2], z = a[0] * b[1] - a[1] * b[0];
    out[0] = x;
    out[1] = y;
    out[2] = z;
}

static inline double sk_distance3(const double a[3], const double b[3])
{
    const double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return sqrt(sk_dot3(d, d));
}

#endif
