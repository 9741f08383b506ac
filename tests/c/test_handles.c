/* Training a handle rig (csrc/offline/handles): kernel CCA with the fused regression, the Poisson solver, the
 * hierarchical triangle clustering. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "test_support.h"

#define EXAMPLES 12

/* Targets linear in the inputs are rebuilt exactly by the linear kernel (the ridge is tiny), a constant target
 * group is predicted as its constant, and the correlations are 1 as far as the inputs' rank goes, 0 beyond. */
static void kernel_cca_reproduces_linear_targets(void)
{
    double inputs[EXAMPLES * 2], targets[EXAMPLES * 2 * 3], kernel[EXAMPLES * EXAMPLES];
    const double a[2][3] = {{1, -2, 0.5}, {0.3, 1, 2}}, b[3] = {0.1, 0.2, -0.3};
    for (int i = 0; i < EXAMPLES; ++i) {
        inputs[2 * i] = random_uniform(-1, 1), inputs[2 * i + 1] = random_uniform(-1, 1);
        for (int c = 0; c < 3; ++c) {
            targets[(i * 2 + 0) * 3 + c] = b[c] + inputs[2 * i] * a[0][c] + inputs[2 * i + 1] * a[1][c];
            targets[(i * 2 + 1) * 3 + c] = 7 + c; /* group 1: never changes */
        }
    }
    EXPECT_SUCCESS("kernel", sk_kernel_values(kernel, inputs, inputs, EXAMPLES, EXAMPLES, 2, SK_KERNEL_LINEAR, 0, 1,
                                              error));
    double mapping[2 * 3 * EXAMPLES], offset[2 * 3], correlations[2 * 3];
    EXPECT_SUCCESS("kcca", sk_kernel_cca(mapping, offset, correlations, kernel, targets, EXAMPLES, 2, 3, 3, 1e-9, 2,
                                         error));
    double worst = 0;
    for (int i = 0; i < EXAMPLES; ++i)
        for (int g = 0; g < 2; ++g)
            for (int c = 0; c < 3; ++c) {
                double d = offset[g * 3 + c];
                for (int j = 0; j < EXAMPLES; ++j)
                    d += mapping[(g * 3 + c) * EXAMPLES + j] * kernel[i * EXAMPLES + j];
                worst = fmax(worst, fabs(d - targets[(i * 2 + g) * 3 + c]));
            }
    CHECK_IN("training targets rebuilt", worst < 1e-6);
    CHECK(fabs(correlations[0] - 1) < 1e-6 && fabs(correlations[1] - 1) < 1e-6 && correlations[2] < 1e-6);
    CHECK(correlations[3] == 0 && max_abs(mapping + 3 * EXAMPLES, 3 * EXAMPLES) == 0 && offset[4] == 8);
    /* A new input: the linear map extends exactly. */
    const double x[2] = {0.25, -0.5};
    double xi[EXAMPLES];
    EXPECT_SUCCESS("kernel", sk_kernel_values(xi, x, inputs, 1, EXAMPLES, 2, SK_KERNEL_LINEAR, 0, 1, error));
    double d = offset[1];
    for (int j = 0; j < EXAMPLES; ++j)
        d += mapping[EXAMPLES + j] * xi[j];
    CHECK_IN("held-out input", fabs(d - (b[1] + x[0] * a[0][1] + x[1] * a[1][1])) < 1e-6);
    /* Bad input. */
    EXPECT_FAILURE("no ridge", SK_ERROR_ARGUMENT, sk_kernel_cca(mapping, offset, correlations, kernel, targets,
                                                                EXAMPLES, 2, 3, 3, 0, 1, error));
    EXPECT_FAILURE("too many pairs", SK_ERROR_ARGUMENT, sk_kernel_cca(mapping, offset, correlations, kernel, targets,
                                                                      EXAMPLES, 2, 3, 4, 1e-3, 1, error));
    EXPECT_FAILURE("one example", SK_ERROR_ARGUMENT, sk_kernel_cca(mapping, offset, correlations, kernel, targets,
                                                                   1, 2, 3, 3, 1e-3, 1, error));
    targets[7] = NAN;
    EXPECT_FAILURE("NaN target", SK_ERROR_NOT_FINITE, sk_kernel_cca(mapping, offset, correlations, kernel, targets,
                                                                    EXAMPLES, 2, 3, 3, 1e-3, 1, error));
}

/* Three rigid pieces (one bone each, bone 3 unused) of 4 vertices, edges inside the pieces and across them; the
 * examples move every piece rigidly with the same motion per piece as the ground truth, the pieces joined so
 * that cross edges follow the first piece's rotation exactly (all pieces share the rotation, with different
 * translations that the cross edges see). With the true rotations and handle positions the solve restores the
 * example exactly. */
#define PIECES 3
#define VERTICES (4 * PIECES)
static void poisson_restores_the_pose(void)
{
    double rest[VERTICES * 3], weights[VERTICES];
    int32_t offsets[VERTICES + 1], bones[VERTICES];
    for (int v = 0; v < VERTICES; ++v) {
        offsets[v] = v, bones[v] = v / 4, weights[v] = 1;
        for (int c = 0; c < 3; ++c)
            rest[3 * v + c] = random_uniform(-1, 1) + (c == 0 ? 3 * (v / 4) : 0);
    }
    offsets[VERTICES] = VERTICES;
    int32_t edges[64];
    size_t edge_count = 0;
    for (int p = 0; p < PIECES; ++p)
        for (int i = 0; i < 4; ++i)
            for (int j = i + 1; j < 4; ++j)
                edges[2 * edge_count] = 4 * p + i, edges[2 * edge_count++ + 1] = 4 * p + j;
    const size_t inner_edges = edge_count;
    edges[2 * edge_count] = 3, edges[2 * edge_count++ + 1] = 4; /* pieces 0-1 and 1-2 touch */
    edges[2 * edge_count] = 7, edges[2 * edge_count++ + 1] = 8;
    enum { EXAMPLE_COUNT = 4, BONES = PIECES + 1 };
    double rotations[EXAMPLE_COUNT * BONES * 9], positions[EXAMPLE_COUNT * VERTICES * 3];
    for (int e = 0; e < EXAMPLE_COUNT; ++e) {
        double r[9], frame[16];
        random_rotation(r);
        const double ones[3] = {1, 1, 1}, t[3] = {random_uniform(-1, 1), random_uniform(-1, 1), 0};
        make_frame(frame, r, ones, t);
        for (int b = 0; b < BONES; ++b)
            memcpy(rotations + (e * BONES + b) * 9, r, sizeof r);
        for (int v = 0; v < VERTICES; ++v)
            transform(positions + (e * VERTICES + v) * 3, frame, rest + 3 * v, 1);
    }
    const int32_t handles[2] = {1, 9};
    double y[BONES * BONES * 3], z[BONES * 2], edge_error = -1;
    const sk_influences influences = {offsets, bones, VERTICES, VERTICES};
    EXPECT_SUCCESS("solver", sk_handle_translation_solver(y, z, &edge_error, &influences, rest, weights, edges,
                                                          edge_count, rotations, positions, EXAMPLE_COUNT, BONES,
                                                          handles, 2, 10, 2, error));
    CHECK_IN("the examples' edges are rigid", edge_error < 1e-6);
    /* A new rigid pose, the rotation known: t_b = sum_a R_a y_ba + sum_l z_bl c_l must put every vertex back. */
    double r[9], frame[16];
    random_rotation(r);
    const double ones[3] = {1, 1, 1}, t[3] = {0.5, -2, 1};
    make_frame(frame, r, ones, t);
    double c[6];
    transform(c, frame, rest + 3 * handles[0], 1);
    transform(c + 3, frame, rest + 3 * handles[1], 1);
    double worst = 0;
    for (int v = 0; v < VERTICES; ++v) {
        const int b = v / 4;
        double translation[3] = {0, 0, 0}, expected[3];
        for (int a = 0; a < BONES; ++a)
            for (int row = 0; row < 3; ++row)
                for (int k = 0; k < 3; ++k)
                    translation[row] += r[3 * row + k] * y[(b * BONES + a) * 3 + k];
        for (int l = 0; l < 2; ++l)
            for (int row = 0; row < 3; ++row)
                translation[row] += z[b * 2 + l] * c[3 * l + row];
        transform(expected, frame, rest + 3 * v, 1);
        for (int row = 0; row < 3; ++row) {
            const double got = r[3 * row] * rest[3 * v] + r[3 * row + 1] * rest[3 * v + 1] +
                               r[3 * row + 2] * rest[3 * v + 2] + translation[row];
            worst = fmax(worst, fabs(got - expected[row]));
        }
    }
    CHECK_IN("translations restore the pose", worst < 1e-9);
    /* Without the cross edges piece 1 holds no handle: refused, naming the bone. */
    sk_error record = empty_error();
    CHECK(sk_handle_translation_solver(y, z, &edge_error, &influences, rest, weights, edges, inner_edges, rotations,
                                       positions, EXAMPLE_COUNT, BONES, handles, 2, 10, 1, &record) ==
          SK_ERROR_SINGULAR);
    CHECK(strstr(record.message, "bone 1") != NULL);
    EXPECT_FAILURE("beta 0", SK_ERROR_ARGUMENT, sk_handle_translation_solver(y, z, &edge_error, &influences, rest,
                                                                             weights, edges, edge_count, rotations,
                                                                             positions, EXAMPLE_COUNT, BONES,
                                                                             handles, 2, 0, 1, error));
    const int32_t outside[2] = {1, VERTICES};
    EXPECT_FAILURE("handle out of range", SK_ERROR_INDEX,
                   sk_handle_translation_solver(y, z, &edge_error, &influences, rest, weights, edges, edge_count,
                                                rotations, positions, EXAMPLE_COUNT, BONES, outside, 2, 1, 1, error));
    positions[5] = NAN;
    EXPECT_FAILURE("NaN example", SK_ERROR_NOT_FINITE,
                   sk_handle_translation_solver(y, z, &edge_error, &influences, rest, weights, edges, edge_count,
                                                rotations, positions, EXAMPLE_COUNT, BONES, handles, 2, 1, 1, error));
}

/* Two vertices move in opposite directions, the others stay: the one component is theirs, and its two extremes,
 * the farther first, are the suggestion. */
static void suggestion_finds_the_moving_vertices(void)
{
    enum { FRAMES = 6, COUNT = 10 };
    double frames[FRAMES * COUNT * 3];
    for (int e = 0; e < FRAMES; ++e)
        for (int v = 0; v < COUNT; ++v)
            for (int c = 0; c < 3; ++c) {
                double position = v + 0.1 * c;
                if (c == 0 && v == 2)
                    position += 2.0 * e;
                if (c == 0 && v == 7)
                    position -= 1.0 * e;
                frames[(e * COUNT + v) * 3 + c] = position;
            }
    int32_t chosen[3];
    EXPECT_SUCCESS("suggest", sk_suggest_handles(chosen, frames, FRAMES, COUNT, 2, error));
    CHECK(chosen[0] == 2 && chosen[1] == 7);
    EXPECT_SUCCESS("suggest three", sk_suggest_handles(chosen, frames, FRAMES, COUNT, 3, error));
    CHECK(chosen[0] != chosen[2] && chosen[1] != chosen[2]);
    EXPECT_FAILURE("too few frames", SK_ERROR_ARGUMENT, sk_suggest_handles(chosen, frames, 2, COUNT, 3, error));
    EXPECT_FAILURE("too many handles", SK_ERROR_ARGUMENT, sk_suggest_handles(chosen, frames, FRAMES, COUNT, 11, error));
    double still[FRAMES * COUNT * 3];
    for (int i = 0; i < FRAMES * COUNT * 3; ++i)
        still[i] = frames[i % (COUNT * 3)];
    EXPECT_FAILURE("still frames", SK_ERROR_ARGUMENT, sk_suggest_handles(chosen, still, FRAMES, COUNT, 2, error));
    frames[40] = NAN;
    EXPECT_FAILURE("NaN", SK_ERROR_NOT_FINITE, sk_suggest_handles(chosen, frames, FRAMES, COUNT, 2, error));
}

/* A strip of three rigid parts (columns 0-3, 4-7, 8-11), each moved by its own rotation about z and translation per
 * example, the strips between them stretched: cut at three clusters, the triangles inside each part are one cluster
 * and the parts are three; merges inside a part cost nothing (rounding), the last one (two parts) a lot. */
static void triangle_clustering_finds_planted_parts(void)
{
    enum { COLS = 12, ROWS = 4, PARTS = 3, FRAMES = 5, VERTICES_ = COLS * ROWS,
           TRIANGLES_ = 2 * (COLS - 1) * (ROWS - 1) };
    double rest[VERTICES_ * 3], frames[FRAMES * VERTICES_ * 3];
    int32_t triangles[TRIANGLES_ * 3], triangle_part[TRIANGLES_];
    for (int c = 0; c < COLS; ++c)
        for (int r = 0; r < ROWS; ++r) {
            double *x = rest + 3 * (c * ROWS + r);
            x[0] = c, x[1] = r, x[2] = random_uniform(-0.3, 0.3);
        }
    size_t t = 0;
    for (int c = 0; c + 1 < COLS; ++c)
        for (int r = 0; r + 1 < ROWS; ++r) {
            const int32_t a = c * ROWS + r, b = a + ROWS, part = c / 4 == (c + 1) / 4 ? c / 4 : -1;
            const int32_t quad[2][3] = {{a, b, b + 1}, {a, b + 1, a + 1}};
            for (int k = 0; k < 2; ++k, ++t) {
                memcpy(triangles + 3 * t, quad[k], sizeof quad[k]);
                triangle_part[t] = part;
            }
        }
    for (int e = 0; e < FRAMES; ++e) {
        double angle[PARTS], shift[PARTS][3];
        for (int p = 0; p < PARTS; ++p) {
            angle[p] = random_uniform(-1.2, 1.2);
            for (int d = 0; d < 3; ++d)
                shift[p][d] = random_uniform(-2, 2);
        }
        for (int v = 0; v < VERTICES_; ++v) {
            const int p = v / ROWS / 4;
            const double *x = rest + 3 * v;
            double *y = frames + 3 * ((size_t)e * VERTICES_ + v);
            y[0] = cos(angle[p]) * x[0] - sin(angle[p]) * x[1] + shift[p][0];
            y[1] = sin(angle[p]) * x[0] + cos(angle[p]) * x[1] + shift[p][1];
            y[2] = x[2] + shift[p][2];
        }
    }
    int32_t merges[2 * (TRIANGLES_ - 1)], root[TRIANGLES_];
    double costs[TRIANGLES_ - 1];
    EXPECT_SUCCESS("cluster", sk_triangle_cluster_merges(merges, costs, TRIANGLES_ - 1, triangles, TRIANGLES_, rest,
                                                         VERTICES_, frames, FRAMES, 1.0, NULL, NULL, error));
    for (int i = 0; i < TRIANGLES_; ++i)
        root[i] = i;
    for (int m = 0; m < TRIANGLES_ - PARTS; ++m)
        root[merges[2 * m + 1]] = merges[2 * m];
    for (int pass = 0; pass < TRIANGLES_; ++pass)
        for (int i = 0; i < TRIANGLES_; ++i)
            root[i] = root[root[i]];
    int32_t part_root[PARTS] = {-1, -1, -1};
    int pure = 1;
    for (int i = 0; i < TRIANGLES_; ++i) {
        const int p = triangle_part[i];
        if (p < 0)
            continue;
        if (part_root[p] < 0)
            part_root[p] = root[i];
        pure &= part_root[p] == root[i];
    }
    CHECK_IN("each part is one cluster", pure);
    CHECK_IN("the parts are three clusters", part_root[0] != part_root[1] && part_root[1] != part_root[2] &&
                                                 part_root[0] != part_root[2]);
    const int inside = 2 * (ROWS - 1) * (3 * PARTS) - PARTS; /* merges that join triangles within the parts */
    double worst_inside = 0;
    for (int m = 0; m < inside; ++m)
        worst_inside = fmax(worst_inside, fabs(costs[m]));
    CHECK_IN("merges inside a rigid part cost nothing", worst_inside < 1e-9);
    CHECK_IN("merging two parts costs a lot", costs[TRIANGLES_ - 2] > 1.0);
    EXPECT_FAILURE("merge count", SK_ERROR_ARGUMENT,
                   sk_triangle_cluster_merges(merges, costs, TRIANGLES_, triangles, TRIANGLES_, rest, VERTICES_,
                                              frames, FRAMES, 1.0, NULL, NULL, error));
    EXPECT_FAILURE("negative edge weight", SK_ERROR_ARGUMENT,
                   sk_triangle_cluster_merges(merges, costs, TRIANGLES_ - 1, triangles, TRIANGLES_, rest, VERTICES_,
                                              frames, FRAMES, -1.0, NULL, NULL, error));
    const int32_t kept_corner = triangles[7];
    triangles[7] = VERTICES_;
    EXPECT_FAILURE("vertex out of range", SK_ERROR_INDEX,
                   sk_triangle_cluster_merges(merges, costs, TRIANGLES_ - 1, triangles, TRIANGLES_, rest, VERTICES_,
                                              frames, FRAMES, 1.0, NULL, NULL, error));
    triangles[7] = kept_corner;
    frames[100] = NAN;
    EXPECT_FAILURE("NaN example", SK_ERROR_NOT_FINITE,
                   sk_triangle_cluster_merges(merges, costs, TRIANGLES_ - 1, triangles, TRIANGLES_, rest, VERTICES_,
                                              frames, FRAMES, 1.0, NULL, NULL, error));
}

/* Two triangles far apart touch nothing: they are still merged (linked by centroid), so every cut exists. */
static void triangle_clustering_links_separate_pieces(void)
{
    const double rest[18] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 5, 0, 0, 6, 0, 0, 5, 1, 0};
    const int32_t triangles[6] = {0, 1, 2, 3, 4, 5};
    int32_t merges[2];
    double costs[1];
    EXPECT_SUCCESS("pieces", sk_triangle_cluster_merges(merges, costs, 1, triangles, 2, rest, 6, rest, 1, 1.0, NULL,
                                                        NULL, error));
    CHECK(merges[0] == 0 && merges[1] == 1 && fabs(costs[0]) < 1e-9);
}

int main(void)
{
    test_program_name = "test_handles";
    kernel_cca_reproduces_linear_targets();
    poisson_restores_the_pose();
    suggestion_finds_the_moving_vertices();
    triangle_clustering_finds_planted_parts();
    triangle_clustering_links_separate_pieces();
    return finish_tests();
}
