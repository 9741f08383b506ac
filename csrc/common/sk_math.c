/* Small dense linear algebra without LAPACK: the affine inverse, 3x3 eigenvalues, SVD and polar factor. */
#include <float.h>
#include <math.h>

#include "sk_math.h"

int sk_affine_inverse(double destination[16], const double m[16])
{
    /* Cofactors of the 3x3 linear part; the translation follows as -A^-1 t. */
    const double c00 = m[5] * m[10] - m[6] * m[9];
    const double c01 = m[6] * m[8] - m[4] * m[10];
    const double c02 = m[4] * m[9] - m[5] * m[8];
    const double determinant = m[0] * c00 + m[1] * c01 + m[2] * c02;
    if (determinant == 0.0)
        return 0;
    const double s = 1.0 / determinant;
    double *d = destination;
    d[0] = c00 * s;
    d[1] = (m[2] * m[9] - m[1] * m[10]) * s;
    d[2] = (m[1] * m[6] - m[2] * m[5]) * s;
    d[4] = c01 * s;
    d[5] = (m[0] * m[10] - m[2] * m[8]) * s;
    d[6] = (m[2] * m[4] - m[0] * m[6]) * s;
    d[8] = c02 * s;
    d[9] = (m[1] * m[8] - m[0] * m[9]) * s;
    d[10] = (m[0] * m[5] - m[1] * m[4]) * s;
    for (int r = 0; r < 3; ++r)
        d[4 * r + 3] = -(d[4 * r] * m[3] + d[4 * r + 1] * m[7] + d[4 * r + 2] * m[11]);
    d[12] = d[13] = d[14] = 0.0;
    d[15] = 1.0;
    return 1;
}

double sk_determinant3(const double m[9])
{
    return m[0] * (m[4] * m[8] - m[5] * m[7]) - m[1] * (m[3] * m[8] - m[5] * m[6]) +
           m[2] * (m[3] * m[7] - m[4] * m[6]);
}

double sk_largest_symmetric_eigenvalue3(const double m[9])
{
    const double off = m[1] * m[1] + m[2] * m[2] + m[5] * m[5];
    const double trace = m[0] + m[4] + m[8];
    if (off == 0.0)
        return fmax(m[0], fmax(m[4], m[8]));
    const double q = trace / 3.0;
    const double a = m[0] - q, d = m[4] - q, f = m[8] - q;
    const double p = sqrt((a * a + d * d + f * f + 2.0 * off) / 6.0);
    /* B = (M - q I) / p; r = det(B) / 2, clamped into [-1, 1] against rounding. */
    const double b0 = a / p, b4 = d / p, b8 = f / p, b1 = m[1] / p, b2 = m[2] / p, b5 = m[5] / p;
    double r = (b0 * (b4 * b8 - b5 * b5) - b1 * (b1 * b8 - b5 * b2) + b2 * (b1 * b5 - b4 * b2)) / 2.0;
    r = r < -1.0 ? -1.0 : (r > 1.0 ? 1.0 : r);
    return q + 2.0 * p * cos(acos(r) / 3.0);
}

/* Sweeps of the one-sided Jacobi: 3x3 converges quadratically, in 4-6 sweeps to rounding. */
#define JACOBI_SWEEPS 30

static double column_dot(const double *m, int p, int q)
{
    return m[p] * m[q] + m[3 + p] * m[3 + q] + m[6 + p] * m[6 + q];
}

static void rotate_columns(double *m, int p, int q, double c, double s)
{
    for (int r = 0; r < 3; ++r) {
        const double x = m[3 * r + p], y = m[3 * r + q];
        m[3 * r + p] = c * x - s * y;
        m[3 * r + q] = s * x + c * y;
    }
}

static void swap_columns(double *m, int p, int q)
{
    for (int r = 0; r < 3; ++r) {
        const double t = m[3 * r + p];
        m[3 * r + p] = m[3 * r + q];
        m[3 * r + q] = t;
    }
}

/* Column k of u becomes a unit vector orthogonal to columns i and j (which are orthonormal or zero). */
static void complete_column(double *u, int k, int i, int j)
{
    double x[3] = {u[i + 3] * u[j + 6] - u[i + 6] * u[j + 3], u[i + 6] * u[j] - u[i] * u[j + 6],
                   u[i] * u[j + 3] - u[i + 3] * u[j]};
    double length = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
    if (!(length > 0.5)) { /* column j is zero too: any unit vector orthogonal to column i */
        const int axis = fabs(u[i]) < 0.6 ? 0 : 1; /* an axis not along column i (or any, when it is zero) */
        double e[3] = {0, 0, 0};
        e[axis] = 1.0;
        const double along = e[0] * u[i] + e[1] * u[i + 3] + e[2] * u[i + 6];
        for (int r = 0; r < 3; ++r)
            x[r] = e[r] - along * u[i + 3 * r];
        length = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
    }
    for (int r = 0; r < 3; ++r)
        u[3 * r + k] = x[r] / length;
}

void sk_svd3(double singular[3], double u[9], double v[9], const double a[9])
{
    double b[9], w[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    memcpy(b, a, sizeof b);
    for (int sweep = 0; sweep < JACOBI_SWEEPS; ++sweep) {
        int rotated = 0;
        for (int p = 0; p < 2; ++p)
            for (int q = p + 1; q < 3; ++q) {
                const double alpha = column_dot(b, p, p), beta = column_dot(b, q, q), gamma = column_dot(b, p, q);
                if (!(fabs(gamma) > DBL_EPSILON * sqrt(alpha * beta)))
                    continue;
                /* The rotation that makes columns p and q orthogonal (the smaller of the two angles). */
                const double zeta = (beta - alpha) / (2.0 * gamma);
                const double t = (zeta >= 0 ? 1.0 : -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
                const double c = 1.0 / sqrt(1.0 + t * t), s = c * t;
                rotate_columns(b, p, q, c, s);
                rotate_columns(w, p, q, c, s);
                rotated = 1;
            }
        if (!rotated)
            break;
    }
    for (int k = 0; k < 3; ++k)
        singular[k] = sqrt(column_dot(b, k, k));
    for (int i = 0; i < 2; ++i) /* descending, columns of b and w along */
        for (int k = 2; k > i; --k)
            if (singular[k] > singular[k - 1]) {
                const double t = singular[k];
                singular[k] = singular[k - 1];
                singular[k - 1] = t;
                swap_columns(b, k, k - 1);
                swap_columns(w, k, k - 1);
            }
    if (v)
        memcpy(v, w, sizeof w);
    if (!u)
        return;
    for (int k = 0; k < 3; ++k)
        for (int r = 0; r < 3; ++r)
            u[3 * r + k] = singular[k] > 0 ? b[3 * r + k] / singular[k] : 0.0;
    /* Zero singular values (the last ones, being sorted) leave zero columns: complete the basis. */
    if (!(singular[0] > 0))
        u[0] = 1.0, u[3] = u[6] = 0.0;
    if (!(singular[1] > 0))
        complete_column(u, 1, 0, 2);
    if (!(singular[2] > 0))
        complete_column(u, 2, 0, 1);
}

void sk_nearest_rotation3(double rotation[9], const double m[9])
{
    double singular[3], u[9], v[9];
    sk_svd3(singular, u, v, m);
    if (sk_determinant3(u) * sk_determinant3(v) < 0)
        for (int r = 0; r < 3; ++r)
            u[3 * r + 2] = -u[3 * r + 2]; /* column 2 has the smallest singular value */
    for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
            rotation[3 * r + c] = u[3 * r] * v[3 * c] + u[3 * r + 1] * v[3 * c + 1] + u[3 * r + 2] * v[3 * c + 2];
}
