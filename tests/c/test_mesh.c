/*
 * The shared mesh topology (csrc/common/sk_mesh.c): edge flaps, fans, components, loops, the chart-corner
 * rule, and the public surface check sk_validate_surface with the messages Python's unwrap used to word.
 */
#include <stdlib.h>
#include <string.h>

#include "sk_mesh.h"
#include "test_support.h"

/* A closed tetrahedron, consistently oriented (outward normals). */
static const int32_t tetrahedron[12] = {0, 2, 1, 0, 1, 3, 1, 2, 3, 2, 0, 3};

static void expect_message(const char *context, const int32_t *triangles, size_t triangle_count, size_t vertex_count,
                           const char *message)
{
    int32_t *copy = exact_copy_int32(triangles, 3 * triangle_count);
    const sk_triangle_mesh mesh = {copy, triangle_count, vertex_count};
    EXPECT_FAILURE(context, SK_ERROR_ARGUMENT, sk_validate_surface(&mesh, error));
    sk_error record = empty_error();
    sk_validate_surface(&mesh, &record);
    CHECK_IN(record.message, strcmp(record.message, message) == 0);
    free(copy);
}

static void test_validate_surface(void)
{
    const sk_triangle_mesh closed = {tetrahedron, 4, 4};
    EXPECT_SUCCESS("closed tetrahedron", sk_validate_surface(&closed, error));
    const sk_triangle_mesh open = {tetrahedron, 3, 4};
    EXPECT_SUCCESS("open tetrahedron", sk_validate_surface(&open, error));
    const sk_triangle_mesh empty = {NULL, 0, 0};
    EXPECT_SUCCESS("no triangles", sk_validate_surface(&empty, error));

    /* a fin on edge (0, 3) of the tetrahedron, and a lesser one on (1, 2): the edge shared by the most wins */
    const int32_t fins[27] = {0, 2, 1, 0, 1, 3, 1, 2, 3, 2, 0, 3, 3, 0, 4, 0, 3, 5, 2, 1, 6, 5, 4, 3, 4, 5, 0};
    expect_message("fins", fins, 7, 7,
                   "edge (0, 3) is shared by 4 faces [1, 3, 4, 5]: the mesh is not manifold there (separate or delete "
                   "the extra faces)");
    /* triangle 2 turned over: it runs along (1, 3) like triangle 1 does... and along (2, 1), (3, 2) too */
    const int32_t flipped[12] = {0, 2, 1, 0, 1, 3, 1, 3, 2, 2, 0, 3};
    expect_message("flipped", flipped, 4, 4,
                   "faces [1, 2] run the same way along edge (1, 3): their orientations disagree (recalculate the "
                   "normals so they point the same way)");
    /* two triangles that share only vertex 2 */
    const int32_t bowtie[6] = {0, 1, 2, 2, 3, 4};
    expect_message("bowtie", bowtie, 2, 5,
                   "vertex 2 joins separate fans of faces (a bowtie): the mesh is not manifold there (split the "
                   "vertex)");
    /* two closed tetrahedra touching at a vertex: no border, yet two fans */
    const int32_t cones[24] = {0, 2, 1, 0, 1, 3, 1, 2, 3, 2, 0, 3, 3, 5, 4, 3, 4, 6, 4, 5, 6, 5, 3, 6};
    expect_message("touching tetrahedra", cones, 8, 7,
                   "vertex 3 joins separate fans of faces (a bowtie): the mesh is not manifold there (split the "
                   "vertex)");
    const sk_triangle_mesh outside = {tetrahedron, 4, 3};
    EXPECT_FAILURE("index outside", SK_ERROR_INDEX, sk_validate_surface(&outside, error));
    EXPECT_FAILURE("null mesh", SK_ERROR_ARGUMENT, sk_validate_surface(NULL, error));
}

/* A 3 x 3 grid of vertices, 8 counterclockwise triangles (a disc with a border loop of 8). */
static const int32_t grid[24] = {0, 1, 4, 0, 4, 3, 1, 2, 5, 1, 5, 4, 3, 4, 7, 3, 7, 6, 4, 5, 8, 4, 8, 7};

static void test_edge_flaps(void)
{
    sk_edge_flaps flaps;
    CHECK(sk_edge_flaps_build(&flaps, grid, 8, 9, NULL) == SK_OK);
    CHECK(flaps.edge_count == 16);
    size_t border = 0;
    for (size_t e = 0; e < flaps.edge_count; ++e) {
        border += sk_is_border_edge(&flaps, (int32_t)e);
        CHECK(flaps.edge_vertices[2 * e] < flaps.edge_vertices[2 * e + 1]);
        for (int side = 0; side < 2; ++side) { /* the opposite corner is not on the edge */
            const int32_t t = flaps.edge_triangles[2 * e + side];
            if (t < 0)
                continue;
            const int32_t opposite = grid[3 * t + flaps.edge_corners[2 * e + side]];
            CHECK(opposite != flaps.edge_vertices[2 * e] && opposite != flaps.edge_vertices[2 * e + 1]);
        }
        CHECK(!sk_edge_runs_same_way(&flaps, (int32_t)e));
    }
    CHECK(border == 8);
    CHECK(sk_is_border_vertex(&flaps, 0) && !sk_is_border_vertex(&flaps, 4));
    CHECK(sk_edge_between(&flaps, 0, 4) >= 0 && sk_edge_between(&flaps, 0, 8) < 0);
    CHECK(flaps.vertex_edge_offsets[5] - flaps.vertex_edge_offsets[4] == 6); /* the centre's edges */

    int32_t offsets[9], vertices[8], edges[8];
    CHECK(sk_boundary_loops(offsets, vertices, edges, &flaps) == 1);
    const int32_t expected[8] = {0, 1, 2, 5, 8, 7, 6, 3}; /* counterclockwise from the lowest vertex */
    CHECK(offsets[1] == 8 && memcmp(vertices, expected, sizeof expected) == 0);

    int32_t fans[24], components[8];
    CHECK(sk_corner_fans(fans, &flaps, NULL) == 9); /* one fan per vertex */
    unsigned char cut[16] = {0};
    cut[sk_edge_between(&flaps, 1, 4)] = cut[sk_edge_between(&flaps, 4, 7)] = 1; /* slit the middle column */
    CHECK(sk_corner_fans(fans, &flaps, cut) == 12); /* the centre splits, and so do 1 and 7 on the border */
    cut[sk_edge_between(&flaps, 3, 4)] = cut[sk_edge_between(&flaps, 4, 5)] = 1;
    cut[sk_edge_between(&flaps, 0, 4)] = cut[sk_edge_between(&flaps, 4, 8)] = 1;
    CHECK(sk_triangle_components(components, &flaps, cut) == 6); /* only 1-5 and 3-7 still join triangles */
    CHECK(components[0] == 0 && components[1] == 1 && components[2] == 2 && components[3] == 2 &&
          components[7] == 5);
    sk_edge_flaps_free(&flaps);

    sk_edge_defect defect;
    const int32_t fin[9] = {0, 1, 2, 1, 0, 3, 0, 1, 4};
    CHECK(sk_edge_flaps_build(&flaps, fin, 3, 5, &defect) == SK_ERROR_ARGUMENT);
    CHECK(defect.vertices[0] == 0 && defect.vertices[1] == 1 && defect.triangle_count == 3);
    CHECK(defect.triangles[0] == 0 && defect.triangles[1] == 1 && defect.triangles[2] == 2);
}

static void test_complete_corners(void)
{
    int32_t loop[9], rotated[10];
    double along[10], rotated_along[10];
    for (int k = 0; k < 9; ++k)
        loop[k] = 10 + (k + 4) % 9; /* lowest vertex (10) at position 5 */
    for (int k = 0; k <= 9; ++k)
        along[k] = k;
    unsigned char corners[32] = {0};
    sk_complete_corners(corners, loop, along, 9, rotated, rotated_along);
    CHECK(corners[10] && corners[loop[8]] && corners[loop[2]]); /* positions 5, 8 and 2: thirds from the lowest */
    memset(corners, 0, sizeof corners);
    corners[loop[1]] = 1;
    sk_complete_corners(corners, loop, along, 9, rotated, rotated_along);
    CHECK(corners[loop[4]] && corners[loop[7]]);
    memset(corners, 0, sizeof corners);
    corners[loop[0]] = corners[loop[2]] = 1;
    sk_complete_corners(corners, loop, along, 9, rotated, rotated_along);
    CHECK(corners[loop[5]] || corners[loop[6]]); /* the middle of the longer arc, 2 .. 9 */
    int count = 0;
    for (int k = 0; k < 32; ++k)
        count += corners[k];
    CHECK(count == 3);
}

int main(void)
{
    test_program_name = "test_mesh";
    test_validate_surface();
    test_edge_flaps();
    test_complete_corners();
    return finish_tests();
}
