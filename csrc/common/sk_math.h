/*
 * Small dense linear algebra the core shares, with no LAPACK: what the runtime needs must link without it.
 * Matrices are row-major like the public API (4x4 affine frames, 3x3 linear parts).
 */
#ifndef SK_MATH_H
#define SK_MATH_H

#include <string.h>

/* destination = a b for 4x4 matrices; destination may be a or b (the product is formed aside first). */
static inline void sk_multiply4(double destination[16], const double a[16], const double b[16])
{
    double product[16];
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c)
            product[4 * r + c] =
                a[4 * r] * b[c] + a[4 * r + 1] * b[4 + c] + a[4 * r + 2] * b[8 + c] + a[4 * r + 3] * b[12 + c];
    memcpy(destination, product, sizeof product);
}

/* Inverts an affine 4x4 matrix; returns 0 when its linear part is exactly singular. */
int sk_affine_inverse(double destination[16], const double matrix[16]);

double sk_determinant3(const double m[9]);

/* The largest eigenvalue of a symmetric 3x3 matrix (trigonometric solution of the characteristic cubic). */
double sk_largest_symmetric_eigenvalue3(const double m[9]);

/*
 * Singular value decomposition a = U diag(singular) V^T of a 3x3 matrix by one-sided Jacobi (Hestenes): plane
 * rotations orthogonalise a's columns, whose norms are then the singular values, descending. Its absolute error
 * is a few ulps of the largest singular value, as LAPACK's dgesvd (forming a^T a instead would square the
 * condition number and lose the small ones below 1e-8 relative). u and v may be NULL; with u, a column whose
 * singular value is zero is completed to an orthonormal basis.
 */
void sk_svd3(double singular[3], double u[9], double v[9], const double a[9]);

/*
 * The rotation nearest to m (the orthogonal factor U V^T of its polar decomposition); when that is a reflection
 * (a rank-deficient or near-planar m) the direction of the smallest singular value is flipped (Merry 2007,
 * section 4.1.4: "negate the smallest eigenvalue of S").
 */
void sk_nearest_rotation3(double rotation[9], const double m[9]);

/* The 4x4 row-major rigid motion x -> rotation x + translation. */
static inline void sk_rigid_matrix(double destination[16], const double rotation[9], const double translation[3])
{
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c)
            destination[4 * r + c] = rotation[3 * r + c];
        destination[4 * r + 3] = translation[r];
    }
    destination[12] = destination[13] = destination[14] = 0.0;
    destination[15] = 1.0;
}

#endif
