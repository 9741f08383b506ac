/*
 * The problems the fitting tests (test_fit.c, test_fit_errors.c) are built on, independent of the
 * core: random example poses, a generated animation-space model with its exact examples, the terms
 * of the fits' objectives, and plain-loop references (own Gaussian elimination of the KKT systems).
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "fit_cases.h"
#include "test_support.h"

/* ---------------------------------------------------------------------------------------------
 * Small dense linear algebra, independent of the core (which uses LAPACK)
 * ------------------------------------------------------------------------------------------- */

/* Solves a x = b in place (x returned in b) by Gaussian elimination with partial pivoting; a (n x n,
 * row-major) is destroyed. Returns 0 when a pivot is exactly zero. */
int solve_gauss(double *a, double *b, size_t n)
{
    for (size_t column = 0; column < n; ++column) {
        size_t pivot = column;
        for (size_t r = column + 1; r < n; ++r)
            if (fabs(a[r * n + column]) > fabs(a[pivot * n + column]))
                pivot = r;
        if (a[pivot * n + column] == 0.0)
            return 0;
        if (pivot != column) {
            for (size_t c = 0; c < n; ++c) {
                const double t = a[column * n + c];
                a[column * n + c] = a[pivot * n + c];
                a[pivot * n + c] = t;
            }
            const double t = b[column];
            b[column] = b[pivot];
            b[pivot] = t;
        }
        for (size_t r = column + 1; r < n; ++r) {
            const double factor = a[r * n + column] / a[column * n + column];
            if (factor == 0.0)
                continue;
            for (size_t c = column; c < n; ++c)
                a[r * n + c] -= factor * a[column * n + c];
            b[r] -= factor * b[column];
        }
    }
    for (size_t i = n; i-- > 0;) {
        double sum = b[i];
        for (size_t j = i + 1; j < n; ++j)
            sum -= a[i * n + j] * b[j];
        b[i] = sum / a[i * n + i];
    }
    return 1;
}

/* ---------------------------------------------------------------------------------------------
 * An animation-space model generated in the test, and its examples
 * ------------------------------------------------------------------------------------------- */

/* A general affine frame: rotation * diag(scales) * rotation, then a translation. */
static void random_affine(double frame[16])
{
    double first[16], second[16], rotation[9], scales[3] = {1, 1, 1}, translation[3] = {0, 0, 0};
    random_rotation(rotation);
    for (int i = 0; i < 3; ++i) {
        scales[i] = random_uniform(0.5, 2.0);
        translation[i] = random_uniform(-2.0, 2.0);
    }
    make_frame(first, rotation, scales, translation);
    random_rotation(rotation);
    const double unit[3] = {1, 1, 1}, none[3] = {0, 0, 0};
    make_frame(second, rotation, unit, none);
    multiply(frame, first, second);
}

/* example_count poses of bone_count bones: bone 0 is the identity root, the others random affine. */
double *random_example_poses(size_t example_count, size_t bone_count)
{
    double *poses = allocate(16 * example_count * bone_count, sizeof *poses);
    for (size_t e = 0; e < example_count; ++e) {
        set_identity(poses + 16 * e * bone_count);
        for (size_t bone = 1; bone < bone_count; ++bone)
            random_affine(poses + 16 * (e * bone_count + bone));
    }
    return poses;
}

static const double *pose_at(const fit_model *m, size_t example, int32_t bone)
{
    return m->poses + 16 * (example * m->bone_count + (size_t)bone);
}

/* out[(e V + i) 3 ..] = top three rows of sum_k G^e_{bones[k]} p_k, straight from eq. 3.1. */
static void model_positions(double *out, const fit_model *m, const double *coordinates)
{
    for (size_t e = 0; e < m->example_count; ++e)
        for (size_t vertex = 0; vertex < m->vertex_count; ++vertex) {
            double sum[3] = {0, 0, 0};
            for (int32_t k = m->offsets[vertex]; k < m->offsets[vertex + 1]; ++k) {
                const double *g = pose_at(m, e, m->bones[k]), *p = coordinates + 4 * k;
                for (int r = 0; r < 3; ++r)
                    sum[r] += g[4 * r] * p[0] + g[4 * r + 1] * p[1] + g[4 * r + 2] * p[2] + g[4 * r + 3] * p[3];
            }
            memcpy(out + 3 * (e * m->vertex_count + vertex), sum, sizeof sum);
        }
}

/*
 * A random model: vertex i has 1 .. max_influences distinct bones out of bone_count (bone 0 included
 * only when allow_root), random p_j with weights summing to 1 (some negative, as animation space
 * allows), random affine poses, and the exact examples those produce.
 */
fit_model make_fit_model(size_t vertex_count, size_t bone_count, size_t example_count, size_t max_influences,
                         int allow_root)
{
    fit_model m = {.vertex_count = vertex_count, .bone_count = bone_count, .example_count = example_count};
    const size_t first = allow_root ? 0 : 1;
    int32_t *offsets = allocate(vertex_count + 1, sizeof *offsets);
    int32_t *bones = allocate(vertex_count * max_influences, sizeof *bones);
    size_t k = 0;
    for (size_t vertex = 0; vertex < vertex_count; ++vertex) {
        const size_t count = 1 + random_below(max_influences);
        pick_distinct_bones(bones + k, count, bone_count - first);
        for (size_t i = 0; i < count; ++i)
            bones[k + i] += (int32_t)first;
        k += count;
        offsets[vertex + 1] = (int32_t)k;
    }
    m.influence_count = k;
    m.offsets = exact_copy_int32(offsets, vertex_count + 1);
    m.bones = exact_copy_int32(bones, k);
    free(offsets), free(bones);
    m.coordinates = allocate(4 * k, sizeof *m.coordinates);
    for (size_t vertex = 0; vertex < vertex_count; ++vertex) {
        double weight_sum = 0.0;
        for (int32_t j = m.offsets[vertex]; j < m.offsets[vertex + 1]; ++j) {
            double *p = m.coordinates + 4 * j;
            for (int c = 0; c < 3; ++c)
                p[c] = random_uniform(-1.0, 1.0);
            p[3] = j + 1 < m.offsets[vertex + 1] ? random_uniform(-0.5, 1.0) : 1.0 - weight_sum;
            weight_sum += p[3];
        }
    }
    m.poses = random_example_poses(example_count, bone_count);
    m.examples = allocate(3 * example_count * vertex_count, sizeof *m.examples);
    model_positions(m.examples, &m, m.coordinates);
    m.influences = (sk_influences){m.offsets, m.bones, vertex_count, k};
    m.example_set = (sk_examples){m.poses, m.examples, example_count, bone_count};
    return m;
}

void free_fit_model(fit_model *m)
{
    free(m->offsets), free(m->bones), free(m->coordinates), free(m->poses), free(m->examples);
}

void add_noise(double *values, size_t count, double amplitude)
{
    for (size_t i = 0; i < count; ++i)
        values[i] += random_uniform(-amplitude, amplitude);
}

/* sum_i sum_e |G^e p_i - v_i^e|^2 */
double data_term(const fit_model *m, const double *coordinates)
{
    const size_t count = 3 * m->example_count * m->vertex_count;
    double *positions = allocate(count, sizeof *positions), sum = 0.0;
    model_positions(positions, m, coordinates);
    for (size_t i = 0; i < count; ++i)
        sum += (positions[i] - m->examples[i]) * (positions[i] - m->examples[i]);
    free(positions);
    return sum;
}

/* The influence slot of `bone` in vertex's set, or -1. */
static int32_t slot_of_bone(const fit_model *m, size_t vertex, int32_t bone)
{
    for (int32_t k = m->offsets[vertex]; k < m->offsets[vertex + 1]; ++k)
        if (m->bones[k] == bone)
            return k;
    return -1;
}

/* sum_edges w_k |p_a - p_b|^2, with p a vector over all bones (zero where a bone has no influence). */
double edge_term(const fit_model *m, const double *coordinates, const int32_t *edges, const double *weights,
                 size_t edge_count)
{
    double sum = 0.0;
    for (size_t e = 0; e < edge_count; ++e) {
        const size_t a = (size_t)edges[2 * e], b = (size_t)edges[2 * e + 1];
        for (int32_t bone = 0; bone < (int32_t)m->bone_count; ++bone) {
            const int32_t ka = slot_of_bone(m, a, bone), kb = slot_of_bone(m, b, bone);
            for (int c = 0; c < 4; ++c) {
                const double d = (ka >= 0 ? coordinates[4 * ka + c] : 0.0) - (kb >= 0 ? coordinates[4 * kb + c] : 0.0);
                sum += weights[e] * d * d;
            }
        }
    }
    return sum;
}

double worst_weight_sum_error(const fit_model *m, const double *coordinates)
{
    double worst = 0.0;
    for (size_t vertex = 0; vertex < m->vertex_count; ++vertex) {
        double sum = 0.0;
        for (int32_t k = m->offsets[vertex]; k < m->offsets[vertex + 1]; ++k)
            sum += coordinates[4 * k + 3];
        worst = fmax(worst, fabs(sum - 1.0));
    }
    return worst;
}

/*
 * Adds vertex's normal equations (data term only) in the full 4-per-influence unknowns to the dense
 * system `normal` (n x n) and `rhs` at unknown `base`: D^T D and D^T v, D the 3E x 4n_i matrix of
 * the top three rows of the poses.
 */
static void add_vertex_normal_equations(double *normal, double *rhs, size_t n, size_t base, const fit_model *m,
                                        size_t vertex)
{
    const int32_t begin = m->offsets[vertex], end = m->offsets[vertex + 1];
    for (size_t e = 0; e < m->example_count; ++e)
        for (int r = 0; r < 3; ++r) {
            const double target = m->examples[3 * (e * m->vertex_count + vertex) + (size_t)r];
            for (int32_t i = begin; i < end; ++i)
                for (int ci = 0; ci < 4; ++ci) {
                    const double di = pose_at(m, e, m->bones[i])[4 * r + ci];
                    const size_t row = base + 4 * (size_t)(i - begin) + (size_t)ci;
                    rhs[row] += di * target;
                    for (int32_t j = begin; j < end; ++j)
                        for (int cj = 0; cj < 4; ++cj)
                            normal[row * n + base + 4 * (size_t)(j - begin) + (size_t)cj] +=
                                di * pose_at(m, e, m->bones[j])[4 * r + cj];
                }
        }
}

/*
 * Reference for the per-vertex fit with vertex regularisation (eq. 4.3): for each vertex, the KKT
 * system of  min sum_e |G^e p - v^e|^2 + lambda |p|^2  subject to  sum of p's weights = 1,
 * solved by Gaussian elimination. Returns 0 if a system is singular.
 */
int reference_per_vertex(double *coordinates, const fit_model *m, double lambda)
{
    for (size_t vertex = 0; vertex < m->vertex_count; ++vertex) {
        const size_t count = (size_t)(m->offsets[vertex + 1] - m->offsets[vertex]), n = 4 * count + 1;
        double *kkt = allocate(n * n, sizeof *kkt), *rhs = allocate(n, sizeof *rhs);
        add_vertex_normal_equations(kkt, rhs, n, 0, m, vertex);
        for (size_t s = 0; s < count; ++s) {
            for (int c = 0; c < 4; ++c)
                kkt[(4 * s + (size_t)c) * n + 4 * s + (size_t)c] += lambda;
            kkt[(4 * s + 3) * n + n - 1] = kkt[(n - 1) * n + 4 * s + 3] = 1.0;
        }
        rhs[n - 1] = 1.0;
        const int ok = solve_gauss(kkt, rhs, n);
        memcpy(coordinates + 4 * m->offsets[vertex], rhs, 4 * count * sizeof *rhs);
        free(kkt), free(rhs);
        if (!ok)
            return 0;
    }
    return 1;
}

/*
 * Reference for the global fit (eq. 4.4): the KKT system of data + edge terms over all vertices at
 * once, subject to each vertex's weights summing to 1, solved densely by Gaussian elimination.
 */
int reference_global(double *coordinates, const fit_model *m, const int32_t *edges, const double *weights,
                     size_t edge_count)
{
    const size_t K = m->influence_count, V = m->vertex_count, n = 4 * K + V;
    double *kkt = allocate(n * n, sizeof *kkt), *rhs = allocate(n, sizeof *rhs);
    for (size_t vertex = 0; vertex < V; ++vertex) {
        add_vertex_normal_equations(kkt, rhs, n, 4 * (size_t)m->offsets[vertex], m, vertex);
        for (int32_t k = m->offsets[vertex]; k < m->offsets[vertex + 1]; ++k)
            kkt[(4 * (size_t)k + 3) * n + 4 * K + vertex] = kkt[(4 * K + vertex) * n + 4 * (size_t)k + 3] = 1.0;
        rhs[4 * K + vertex] = 1.0;
    }
    for (size_t e = 0; e < edge_count; ++e) {
        const size_t a = (size_t)edges[2 * e], b = (size_t)edges[2 * e + 1];
        for (int32_t bone = 0; bone < (int32_t)m->bone_count; ++bone) {
            const int32_t ka = slot_of_bone(m, a, bone), kb = slot_of_bone(m, b, bone);
            for (size_t c = 0; c < 4; ++c) { /* w |pa - pb|^2: +w on the diagonals, -w between them */
                if (ka >= 0)
                    kkt[(4 * (size_t)ka + c) * n + 4 * (size_t)ka + c] += weights[e];
                if (kb >= 0)
                    kkt[(4 * (size_t)kb + c) * n + 4 * (size_t)kb + c] += weights[e];
                if (ka >= 0 && kb >= 0) {
                    kkt[(4 * (size_t)ka + c) * n + 4 * (size_t)kb + c] -= weights[e];
                    kkt[(4 * (size_t)kb + c) * n + 4 * (size_t)ka + c] -= weights[e];
                }
            }
        }
    }
    const int ok = solve_gauss(kkt, rhs, n);
    memcpy(coordinates, rhs, 4 * K * sizeof *rhs);
    free(kkt), free(rhs);
    return ok;
}

