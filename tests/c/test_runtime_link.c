/*
 * The runtime on its own: this program is linked from csrc/common and csrc/runtime only, without LAPACK or
 * BLAS (see the Makefile), so it builds only while evaluation needs nothing from the offline tools. It then
 * checks that what it links works: a skeleton validated (the LAPACK-free 3x3 SVD), a linear-blend model
 * converted to animation space and both evaluated against the reference formulas.
 */
#include <stdlib.h>

#include "test_support.h"

int main(void)
{
    test_program_name = "test_runtime_link";
    test_mesh mesh = make_random_mesh(200, 6);
    int32_t parents[6] = {-1, 0, 1, 1, 0, 4};
    EXPECT_SUCCESS("skeleton", sk_validate_skeleton(parents, mesh.rest_frames, mesh.bone_count, error));

    double *poses = allocate(16 * mesh.bone_count, sizeof *poses);
    double *linear_blend = allocate(3 * mesh.vertex_count, sizeof *linear_blend);
    double *projected = allocate(3 * mesh.vertex_count, sizeof *projected);
    double *reference = allocate(3 * mesh.vertex_count, sizeof *reference);
    random_frames(poses, mesh.bone_count);
    reference_linear_blend(reference, &mesh, mesh.rest_positions, 1.0, poses);

    double *skinning = skinning_matrices_of("skinning matrices", &mesh, poses);
    EXPECT_SUCCESS("linear blend", sk_lbs_evaluate_f64(linear_blend,
                                                       &mesh.influences,
                                                       mesh.rest_positions, 1.0, mesh.weights, skinning,
                                                       mesh.bone_count, 1, error));
    CHECK(close_to(linear_blend, reference, 3 * mesh.vertex_count, 1e-12));
    double *coordinates = converted_coordinates("conversion", &mesh, mesh.rest_positions, 1.0);
    EXPECT_SUCCESS("animation space", sk_animation_space_evaluate_f64(projected,
                                                                      &mesh.influences,
                                                                      coordinates, poses, mesh.bone_count, 1, error));
    CHECK(close_to(projected, reference, 3 * mesh.vertex_count, 1e-12));

    free(poses);
    free(skinning);
    free(coordinates);
    free(linear_blend);
    free(projected);
    free(reference);
    free_mesh(&mesh);
    return finish_tests();
}
