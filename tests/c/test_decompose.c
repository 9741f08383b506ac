/*
 * Tests of the sequence-skinning core (sk_decompose.c) under the sanitizers: rigid poses, bone ranking, core motions
 * and rest joints recover known answers; bad input fails with the right status, never out of bounds.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "test_support.h"

enum { BONES = 4, PER_BONE = 12, VERTICES = (BONES - 1) * PER_BONE, FRAMES = 5 };

/* Random rigid motions (bone 0 the identity) and rest points, each point on one bone (1..), and the frames. */
typedef struct rigid_scene {
    double rest[VERTICES * 3], frames[FRAMES * VERTICES * 3], motions[FRAMES * BONES * 16];
    int32_t offsets[VERTICES + 1], bones[VERTICES];
    double coordinates[VERTICES * 4];
} rigid_scene;

static void make_rigid_scene(rigid_scene *s)
{
    for (size_t f = 0; f < FRAMES; ++f) {
        set_identity(s->motions + 16 * f * BONES);
        for (size_t b = 1; b < BONES; ++b)
            random_frame(s->motions + 16 * (f * BONES + b), 1.0, 1.0, 2.0);
    }
    for (size_t i = 0; i < VERTICES; ++i) {
        s->offsets[i] = (int32_t)i;
        s->bones[i] = (int32_t)(1 + i / PER_BONE);
        for (int c = 0; c < 3; ++c)
            s->rest[3 * i + (size_t)c] = s->coordinates[4 * i + (size_t)c] = random_uniform(-1, 1);
        s->coordinates[4 * i + 3] = 1.0;
        for (size_t f = 0; f < FRAMES; ++f)
            transform(s->frames + 3 * (f * VERTICES + i), s->motions + 16 * (f * BONES + (size_t)s->bones[i]),
                      s->rest + 3 * i, 1.0);
    }
    s->offsets[VERTICES] = VERTICES;
}

static void test_rigid_poses_are_recovered(void)
{
    rigid_scene *s = allocate(1, sizeof *s);
    make_rigid_scene(s);
    double *poses = allocate(FRAMES * BONES * 16, sizeof *poses);
    for (size_t k = 0; k < FRAMES * BONES; ++k)
        set_identity(poses + 16 * k);
    double frame_errors[FRAMES];
    EXPECT_SUCCESS("from the identity", sk_solve_rigid_poses(poses, frame_errors,
                                                             &(sk_influences){s->offsets, s->bones, VERTICES, VERTICES},
                                                             s->coordinates, s->frames, FRAMES, BONES, 0, 2, error));
    CHECK(frame_errors[1] > 1e-3);
    EXPECT_SUCCESS("solve", sk_solve_rigid_poses(poses, frame_errors,
                                                 &(sk_influences){s->offsets, s->bones, VERTICES, VERTICES},
                                                 s->coordinates, s->frames, FRAMES, BONES, 1, 2, error));
    CHECK(max_abs_difference(poses, s->motions, FRAMES * BONES * 16) < 1e-9);
    CHECK(max_abs(frame_errors, FRAMES) < 1e-18);
    EXPECT_SUCCESS("zero sweeps keep the start", sk_solve_rigid_poses(poses, NULL,
                                                                      &(sk_influences){s->offsets, s->bones, VERTICES, VERTICES},
                                                                      s->coordinates, s->frames, FRAMES, BONES, 0, 1,
                                                                      error));
    CHECK(max_abs_difference(poses, s->motions, FRAMES * BONES * 16) < 1e-9);
    int32_t bad_bones[VERTICES];
    memcpy(bad_bones, s->bones, sizeof bad_bones);
    bad_bones[3] = BONES;
    EXPECT_FAILURE("bone out of range", SK_ERROR_INDEX,
                   sk_solve_rigid_poses(poses, NULL, &(sk_influences){s->offsets, bad_bones, VERTICES, VERTICES},
                                        s->coordinates, s->frames, FRAMES, BONES, 1, 1, error));
    s->frames[7] = NAN;
    EXPECT_FAILURE("NaN target", SK_ERROR_NOT_FINITE,
                   sk_solve_rigid_poses(poses, NULL, &(sk_influences){s->offsets, s->bones, VERTICES, VERTICES},
                                        s->coordinates, s->frames, FRAMES, BONES, 1, 1, error));
    free(poses);
    free(s);
}

/* Each vertex lists the static root (with zero coordinates) before its own bone, and the bones alternate along
 * the vertices, so a bone's influences are not in the order they are stored in: the solve must pair each one's
 * coordinates with its own vertex to recover the motions in one sweep from the identity. */
static void test_rigid_poses_follow_interleaved_influences(void)
{
    rigid_scene *s = allocate(1, sizeof *s);
    make_rigid_scene(s);
    int32_t offsets[VERTICES + 1], bones[2 * VERTICES];
    double coordinates[2 * VERTICES * 4] = {0}, *frames = allocate(FRAMES * VERTICES * 3, sizeof *frames);
    for (size_t i = 0; i < VERTICES; ++i) {
        offsets[i] = (int32_t)(2 * i);
        bones[2 * i] = 0;
        bones[2 * i + 1] = (int32_t)(1 + i % (BONES - 1));
        memcpy(coordinates + 8 * i + 4, s->coordinates + 4 * i, 4 * sizeof *coordinates);
        for (size_t f = 0; f < FRAMES; ++f)
            transform(frames + 3 * (f * VERTICES + i), s->motions + 16 * (f * BONES + (size_t)bones[2 * i + 1]),
                      s->rest + 3 * i, 1.0);
    }
    offsets[VERTICES] = 2 * VERTICES;
    double *poses = allocate(FRAMES * BONES * 16, sizeof *poses), frame_errors[FRAMES];
    for (size_t k = 0; k < FRAMES * BONES; ++k)
        set_identity(poses + 16 * k);
    EXPECT_SUCCESS("solve", sk_solve_rigid_poses(poses, frame_errors,
                                                 &(sk_influences){offsets, bones, VERTICES, 2 * VERTICES},
                                                 coordinates, frames, FRAMES, BONES, 1, 2, error));
    CHECK(max_abs_difference(poses, s->motions, FRAMES * BONES * 16) < 1e-9);
    CHECK(max_abs(frame_errors, FRAMES) < 1e-18);
    free(poses);
    free(frames);
    free(s);
}

static void test_bones_are_ranked_by_rigid_error(void)
{
    rigid_scene *s = allocate(1, sizeof *s);
    make_rigid_scene(s);
    int32_t best[VERTICES * 2];
    double errors[VERTICES * 2];
    EXPECT_SUCCESS("rank", sk_rank_bones(best, errors, s->rest, s->frames, s->motions, NULL, VERTICES, FRAMES, BONES,
                                         2, 2, error));
    int ranked = 1;
    for (size_t i = 0; i < VERTICES; ++i)
        ranked &= best[2 * i] == s->bones[i] && errors[2 * i] < 1e-18 && errors[2 * i + 1] >= errors[2 * i];
    CHECK(ranked);
    unsigned char allowed[VERTICES * BONES];
    memset(allowed, 0, sizeof allowed);
    for (size_t i = 0; i < VERTICES; ++i)
        allowed[i * BONES + 2] = 1; /* only bone 2 */
    EXPECT_SUCCESS("rank restricted", sk_rank_bones(best, errors, s->rest, s->frames, s->motions, allowed, VERTICES,
                                                    FRAMES, BONES, 2, 1, error));
    int restricted = 1;
    for (size_t i = 0; i < VERTICES; ++i)
        restricted &= best[2 * i] == 2 && best[2 * i + 1] == -1 && isinf(errors[2 * i + 1]);
    CHECK(restricted);
    EXPECT_FAILURE("no candidates", SK_ERROR_ARGUMENT,
                   sk_rank_bones(best, errors, s->rest, s->frames, s->motions, NULL, VERTICES, FRAMES, BONES, 0, 1,
                                 error));
    free(s);
}

static void test_core_motions_and_rest_joints(void)
{
    rigid_scene *s = allocate(1, sizeof *s);
    make_rigid_scene(s);
    /* core sets by bone: bone 0 none, bone b its PER_BONE points */
    int32_t core_offsets[BONES + 1] = {0, 0, PER_BONE, 2 * PER_BONE, 3 * PER_BONE}, cores[VERTICES];
    for (size_t i = 0; i < VERTICES; ++i)
        cores[i] = (int32_t)i;
    double *motions = allocate(FRAMES * BONES * 16, sizeof *motions);
    EXPECT_SUCCESS("core motions", sk_fit_core_motions(motions, core_offsets, cores, s->rest, s->frames, VERTICES,
                                                       VERTICES, FRAMES, BONES, error));
    CHECK(max_abs_difference(motions, s->motions, FRAMES * BONES * 16) < 1e-9);

    /* three points (a plane): the minimum-norm affine fit's polar factor is still a rotation, not a reflection */
    int32_t planar[3] = {0, 1, 2}, planar_offsets[3] = {0, 0, 3};
    EXPECT_SUCCESS("three points are enough", sk_fit_core_motions(motions, planar_offsets, planar, s->rest, s->frames,
                                                                  VERTICES, 3, FRAMES, 2, error));
    const double *r = motions + 16;
    const double det = r[0] * (r[5] * r[10] - r[6] * r[9]) - r[1] * (r[4] * r[10] - r[6] * r[8]) +
                       r[2] * (r[4] * r[9] - r[5] * r[8]);
    CHECK(fabs(det - 1.0) < 1e-9);
    int32_t two[2] = {0, 1}, two_offsets[3] = {0, 0, 2};
    EXPECT_FAILURE("two core vertices", SK_ERROR_RANK,
                   sk_fit_core_motions(motions, two_offsets, two, s->rest, s->frames, VERTICES, 2, FRAMES, 2, error));
    double line[VERTICES * 3];
    memcpy(line, s->rest, sizeof line);
    for (int k = 0; k < 4; ++k)
        for (int c = 0; c < 3; ++c)
            line[3 * k + c] = (double)k * (c + 1); /* points 0..3 on a line */
    int32_t on_line[4] = {0, 1, 2, 3}, line_offsets[3] = {0, 0, 4};
    EXPECT_FAILURE("collinear core", SK_ERROR_RANK,
                   sk_fit_core_motions(motions, line_offsets, on_line, line, s->frames, VERTICES, 4, FRAMES, 2, error));
    int32_t outside[3] = {0, 1, VERTICES};
    EXPECT_FAILURE("core vertex out of range", SK_ERROR_INDEX,
                   sk_fit_core_motions(motions, planar_offsets, outside, s->rest, s->frames, VERTICES, 3, FRAMES, 2,
                                       error));

    /* a ball joint at h: the child's motion is the parent's times a rotation about h, so eq. 4.6 finds h */
    const double hinge[3] = {0.3, -0.2, 0.5};
    double joint_motions[FRAMES * 2 * 16];
    for (size_t f = 0; f < FRAMES; ++f) {
        double rotation[9], about[16], to[16], from[16], tmp[16];
        random_rotation(rotation);
        make_frame(about, rotation, (double[3]){1, 1, 1}, (double[3]){0, 0, 0});
        set_identity(to);
        set_identity(from);
        for (int c = 0; c < 3; ++c) {
            to[4 * c + 3] = hinge[c];
            from[4 * c + 3] = -hinge[c];
        }
        set_identity(joint_motions + 32 * f);
        multiply(tmp, about, from);
        multiply(joint_motions + 32 * f + 16, to, tmp);
    }
    const int32_t parents[2] = {-1, 0};
    double joints[6], approximate[6] = {0, 0, 0, 1, 1, 1};
    EXPECT_SUCCESS("rest joints", sk_fit_rest_joints(joints, joint_motions, parents, approximate, FRAMES, 2, 1e-3,
                                                     error));
    CHECK(fabs(joints[3] - hinge[0]) < 1e-5 && fabs(joints[4] - hinge[1]) < 1e-5 && fabs(joints[5] - hinge[2]) < 1e-5);
    const int32_t cycle[2] = {1, 0};
    EXPECT_FAILURE("not a tree", SK_ERROR_CYCLE,
                   sk_fit_rest_joints(joints, joint_motions, cycle, approximate, FRAMES, 2, 1e-3, error));
    EXPECT_FAILURE("negative lambda", SK_ERROR_ARGUMENT,
                   sk_fit_rest_joints(joints, joint_motions, parents, approximate, FRAMES, 2, -1.0, error));
    free(motions);
    free(s);
}

int main(void)
{
    test_program_name = "test_decompose";
    test_rigid_poses_are_recovered();
    test_rigid_poses_follow_interleaved_influences();
    test_bones_are_ranked_by_rigid_error();
    test_core_motions_and_rest_joints();
    return finish_tests();
}
