/*
 * Tests of skeleton extraction (sk_skeleton.c, sk_hull.c) under the sanitizers: a chain of capped cylinders, one
 * part per cylinder, has known openings, kernel centroids, hierarchy and axis; bad input fails naming the part.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "test_support.h"

enum { PARTS = 3, RINGS_PER_PART = 4, SIDES = 12, RINGS = PARTS * RINGS_PER_PART + 1 };
enum { VERTICES = RINGS * SIDES + 2, TRIANGLES = (RINGS - 1) * SIDES * 2 + 2 * SIDES };
static const double LENGTH = 2.0, RADIUS = 0.5;

typedef struct chain {
    double positions[VERTICES * 3];
    int32_t triangles[TRIANGLES * 3], parts[TRIANGLES];
} chain;

static int32_t ring_vertex(int ring, int side)
{
    return (int32_t)(ring * SIDES + side % SIDES);
}

static void add_triangle(chain *c, size_t *t, int32_t a, int32_t b, int32_t d, int32_t part)
{
    c->triangles[3 * *t] = a;
    c->triangles[3 * *t + 1] = b;
    c->triangles[3 * *t + 2] = d;
    c->parts[(*t)++] = part;
}

/* Cylinders along x, part k spanning [k LENGTH, (k + 1) LENGTH], sharing rings at the openings, capped. */
static void make_chain(chain *c)
{
    for (int r = 0; r < RINGS; ++r)
        for (int s = 0; s < SIDES; ++s) {
            const double angle = 2.0 * 3.14159265358979323846 * s / SIDES;
            double *p = c->positions + 3 * (size_t)ring_vertex(r, s);
            p[0] = LENGTH * r / RINGS_PER_PART;
            p[1] = RADIUS * cos(angle);
            p[2] = RADIUS * sin(angle);
        }
    const int32_t first_cap = RINGS * SIDES, last_cap = first_cap + 1;
    memset(c->positions + 3 * first_cap, 0, 6 * sizeof(double));
    c->positions[3 * last_cap] = LENGTH * PARTS;
    size_t t = 0;
    for (int r = 0; r + 1 < RINGS; ++r)
        for (int s = 0; s < SIDES; ++s) {
            const int32_t a = ring_vertex(r, s), b = ring_vertex(r, s + 1), u = ring_vertex(r + 1, s),
                          d = ring_vertex(r + 1, s + 1), part = r / RINGS_PER_PART;
            add_triangle(c, &t, a, b, d, part);
            add_triangle(c, &t, a, d, u, part);
        }
    for (int s = 0; s < SIDES; ++s) {
        add_triangle(c, &t, first_cap, ring_vertex(0, s + 1), ring_vertex(0, s), 0);
        add_triangle(c, &t, last_cap, ring_vertex(RINGS - 1, s), ring_vertex(RINGS - 1, s + 1), PARTS - 1);
    }
}

typedef struct skeleton {
    double joints[15 * PARTS], centroids[3 * PARTS], axes[9 * PARTS], boxes[6 * PARTS];
    int32_t parents[5 * PARTS], joint_parts[5 * PARTS], kinds[5 * PARTS], part_parents[PARTS], part_joints[PARTS],
        flags[PARTS];
    sk_skeleton_report report;
} skeleton;

static sk_status extract(skeleton *s, const chain *c, const int32_t *parts, const int32_t *given, int method,
                         sk_error *error)
{
    const sk_triangle_mesh mesh = {c->triangles, TRIANGLES, VERTICES};
    const sk_skeleton_options options = {method, 1, 0, 20.0, 0.25};
    return sk_extract_skeleton(s->joints, s->parents, s->joint_parts, s->kinds, s->part_parents, s->part_joints,
                               s->centroids, s->axes, s->boxes, s->flags, &s->report, &mesh, c->positions, parts,
                               PARTS, given, &options, error);
}

static int near3(const double *p, double x, double y, double z, double tolerance)
{
    return fabs(p[0] - x) < tolerance && fabs(p[1] - y) < tolerance && fabs(p[2] - z) < tolerance;
}

static void test_centroid_method_finds_openings_and_kernels(void)
{
    static chain c;
    static skeleton s;
    make_chain(&c);
    EXPECT_SUCCESS("centroid", extract(&s, &c, c.parts, NULL, SK_SKELETON_CENTROID, error));
    CHECK(s.report.opening_count == PARTS - 1);
    CHECK(s.report.star_shaped_count == PARTS); /* a cylinder is convex */
    CHECK(s.part_parents[1] == -1 && s.part_parents[0] == 1 && s.part_parents[2] == 1); /* the most openings */
    for (int p = 0; p < PARTS; ++p) {
        /* The kernel of a capped cylinder is the cylinder: its centroid is the middle (the hull's surface
         * centroid of a polygonal cylinder, on the axis). */
        CHECK_IN("kernel centroid", near3(s.centroids + 3 * p, LENGTH * (p + 0.5), 0, 0, 0.05 * LENGTH));
        CHECK_IN("principal axis along x", fabs(s.axes[9 * p]) > 0.999);
        CHECK_IN("box half-length", fabs(s.boxes[6 * p + 3] - LENGTH / 2) < 1e-9);
    }
    CHECK(s.report.joint_count == 2 * PARTS - 1);
    size_t openings = 0;
    for (size_t j = 0; j < s.report.joint_count; ++j) {
        CHECK(s.parents[j] < (int32_t)j); /* parents come first */
        if (s.kinds[j] == SK_JOINT_OPENING) {
            ++openings;
            const double x = s.joint_parts[j] == 0 ? LENGTH : 2 * LENGTH;
            CHECK_IN("opening centroid", near3(s.joints + 3 * j, x, 0, 0, 1e-9));
        }
    }
    CHECK(openings == PARTS - 1);
}

static void test_principal_axis_method_reaches_the_ends(void)
{
    static chain c;
    static skeleton s;
    make_chain(&c);
    EXPECT_SUCCESS("principal axis", extract(&s, &c, c.parts, NULL, SK_SKELETON_PRINCIPAL_AXIS, error));
    int reached_start = 0, reached_end = 0;
    for (size_t j = 0; j < s.report.joint_count; ++j) {
        reached_start |= near3(s.joints + 3 * j, 0, 0, 0, 1e-6);
        reached_end |= near3(s.joints + 3 * j, PARTS * LENGTH, 0, 0, 1e-6);
        CHECK_IN("on the axis", fabs(s.joints[3 * j + 1]) < 1e-6 && fabs(s.joints[3 * j + 2]) < 1e-6);
    }
    CHECK(reached_start && reached_end);
    /* The root part's root point is its single link point: both ocs project to its two ends and group apart or
     * together, either way on the axis between the openings. */
    const double *root = s.joints + 3 * s.part_joints[1];
    CHECK(root[0] >= LENGTH - 1e-6 && root[0] <= 2 * LENGTH + 1e-6);
}

static void test_given_hierarchy_is_kept(void)
{
    static chain c;
    static skeleton s;
    make_chain(&c);
    const int32_t given[PARTS] = {-1, 0, 1};
    EXPECT_SUCCESS("given", extract(&s, &c, c.parts, given, SK_SKELETON_OPENING, error));
    CHECK(memcmp(s.part_parents, given, sizeof given) == 0);
    CHECK(s.report.joint_count == PARTS);
    const int32_t unrelated[PARTS] = {-1, 0, 0}; /* parts 0 and 2 share no opening */
    EXPECT_FAILURE("no shared opening", SK_ERROR_ARGUMENT, extract(&s, &c, c.parts, unrelated, 0, error));
    const int32_t cycle[PARTS] = {-1, 2, 1};
    EXPECT_FAILURE("cycle", SK_ERROR_CYCLE, extract(&s, &c, c.parts, cycle, 0, error));
}

static void test_bad_parts_are_refused(void)
{
    static chain c;
    static skeleton s;
    make_chain(&c);
    static int32_t parts[TRIANGLES];
    memcpy(parts, c.parts, sizeof parts);
    parts[5] = PARTS;
    EXPECT_FAILURE("part out of range", SK_ERROR_INDEX, extract(&s, &c, parts, NULL, 0, error));
    for (size_t t = 0; t < TRIANGLES; ++t)
        parts[t] = c.parts[t] == 2 ? 1 : c.parts[t]; /* part 2 unused */
    EXPECT_FAILURE("unused part", SK_ERROR_ARGUMENT, extract(&s, &c, parts, NULL, 0, error));
    /* Part 1 cut loose from part 0: its first ring re-made from new vertices would need more vertices; a cheaper
     * disconnection is a NaN. */
    c.positions[7] = NAN;
    EXPECT_FAILURE("not finite", SK_ERROR_NOT_FINITE, extract(&s, &c, c.parts, NULL, 0, error));
}

static void test_part_without_opening_is_named(void)
{
    /* Two separate tetrahedra: parts 0 and 1 share no edge. */
    const double positions[24] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 5, 0, 0, 6, 0, 0, 5, 1, 0, 5, 0, 1};
    const int32_t triangles[24] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3, 4, 6, 5, 4, 5, 7, 4, 7, 6, 5, 6, 7};
    const int32_t parts[8] = {0, 0, 0, 0, 1, 1, 1, 1};
    const sk_triangle_mesh mesh = {triangles, 8, 8};
    const sk_skeleton_options options = {SK_SKELETON_CENTROID, 0, 0, 20.0, 0.25};
    double joints[30], centroids[6], axes[18], boxes[12];
    int32_t parents[10], joint_parts[10], kinds[10], part_parents[2], part_joints[2], flags[2];
    sk_skeleton_report report;
    EXPECT_FAILURE("no opening", SK_ERROR_ARGUMENT,
                   sk_extract_skeleton(joints, parents, joint_parts, kinds, part_parents, part_joints, centroids, axes,
                                       boxes, flags, &report, &mesh, positions, parts, 2, NULL, &options, error));
    sk_error record;
    sk_extract_skeleton(joints, parents, joint_parts, kinds, part_parents, part_joints, centroids, axes, boxes, flags,
                        &report, &mesh, positions, parts, 2, NULL, &options, &record);
    CHECK(strstr(record.message, "part 0 has no opening") != NULL);
    /* One tetrahedron alone is a one-part skeleton, star-shaped, its KC its centroid's neighbourhood. */
    const sk_triangle_mesh one = {triangles, 4, 4};
    EXPECT_SUCCESS("one part", sk_extract_skeleton(joints, parents, joint_parts, kinds, part_parents, part_joints,
                                                   centroids, axes, boxes, flags, &report, &one, positions, parts, 1,
                                                   NULL, &options, error));
    CHECK(report.joint_count == 1 && parents[0] == -1 && (flags[0] & SK_SKELETON_STAR_SHAPED));
    /* A tetrahedron's kernel is itself: KC is its surface centroid (three faces of area 1/2, one of sqrt(3)/2). */
    const double surface = (1.0 + sqrt(3.0) / 2.0) / (3.0 * (1.5 + sqrt(3.0) / 2.0));
    CHECK(near3(centroids, surface, surface, surface, 1e-6));
}

static void test_options_are_checked(void)
{
    static chain c;
    static skeleton s;
    make_chain(&c);
    const sk_triangle_mesh mesh = {c.triangles, TRIANGLES, VERTICES};
    const sk_skeleton_options bad_method = {3, 0, 0, 20.0, 0.25}, bad_angle = {0, 0, 0, 0.0, 0.25},
                              bad_closeness = {0, 0, 0, 20.0, 1.0};
    const sk_skeleton_options *all[3] = {&bad_method, &bad_angle, &bad_closeness};
    for (int k = 0; k < 3; ++k)
        EXPECT_FAILURE("options", SK_ERROR_ARGUMENT,
                       sk_extract_skeleton(s.joints, s.parents, s.joint_parts, s.kinds, s.part_parents, s.part_joints,
                                           s.centroids, s.axes, s.boxes, s.flags, &s.report, &mesh, c.positions,
                                           c.parts, PARTS, NULL, all[k], error));
}


/* Three parts in a row along x (0 the root): part 1 turns about (1, 0, 0), part 2 about (2, 0, 0). */
static void test_forward_kinematics_turns_about_the_joint(void)
{
    const double joints[9] = {0, 0, 0, 1, 0, 0, 2, 0, 0}, axes[9] = {0, 0, 1, -1, 0, 0, -1, 0, 0};
    const int32_t parents[3] = {-1, 0, 1}, cyclic[3] = {2, -1, 0}, root_in_the_middle[3] = {1, -1, 1};
    double angles[9] = {0}, world[48];
    angles[3] = 90.0; /* part 1 a quarter turn about X of its frame (z along its parent axis) */
    EXPECT_SUCCESS("fk", sk_forward_kinematics(world, joints, axes, angles, parents, NULL, 3, error));
    const double *w = world + 16;
    CHECK(fabs(w[3] + w[0] * 1.0 - 1.0) < 1e-12 && fabs(w[7] + w[4]) < 1e-12); /* the joint is fixed */
    const double tip[3] = {w[0] * 2 + w[3], w[4] * 2 + w[7], w[8] * 2 + w[11]}; /* (2, 0, 0) moved */
    CHECK(fabs(tip[0] - 1.0) < 1e-12 && fabs(fabs(tip[1]) + fabs(tip[2]) - 1.0) < 1e-12);
    /* The child follows: part 2's joint moves with part 1. */
    CHECK(fabs(world[32 + 3] + world[32] * 2 - tip[0]) < 1e-12);
    CHECK(fabs(world[0] - 1.0) < 1e-12 && fabs(world[3]) < 1e-12);
    EXPECT_FAILURE("two roots", SK_ERROR_ARGUMENT,
                   sk_forward_kinematics(world, joints, axes, angles, (const int32_t[3]){-1, -1, 1}, NULL, 3, error));
    EXPECT_FAILURE("cycle", SK_ERROR_CYCLE, sk_forward_kinematics(world, joints, axes, angles, cyclic, NULL, 3, error));
    EXPECT_SUCCESS("a parent after its child",
                   sk_forward_kinematics(world, joints, axes, angles, root_in_the_middle, NULL, 3, error));
    /* The root (part 1) turns about its own joint, which stays; part 0 (its child, unturned) moves with it. */
    CHECK(fabs(world[16 + 3] + world[16 + 0] - 1.0) < 1e-12 && fabs(world[16 + 7] + world[16 + 4]) < 1e-12);
    CHECK(fabs(world[5] - world[16 + 5]) < 1e-12 && fabs(world[6] - world[16 + 6]) < 1e-12);
    angles[4] = NAN;
    EXPECT_FAILURE("nan", SK_ERROR_NOT_FINITE, sk_forward_kinematics(world, joints, axes, angles, parents, NULL, 3, error));
}

static void test_collisions_skip_parents_and_find_overlaps(void)
{
    /* Unit boxes: 0 at the origin, 1 (child of 0) touching it, 2 (child of 1) moved onto 0. */
    const double boxes[18] = {0, 0, 0, 1, 1, 1, 1.5, 0, 0, 1, 1, 1, 3, 0, 0, 1, 1, 1};
    double axes[27] = {0}, world[48] = {0};
    for (int p = 0; p < 3; ++p)
        for (int k = 0; k < 3; ++k) {
            axes[9 * p + 4 * k] = 1.0;
            world[16 * p + 5 * k] = 1.0;
        }
    for (int p = 0; p < 3; ++p)
        world[16 * p + 15] = 1.0;
    const int32_t parents[3] = {-1, 0, 1};
    int32_t pairs[6];
    size_t count = 9;
    EXPECT_SUCCESS("apart", sk_detect_collisions(pairs, &count, world, boxes, axes, parents, 3, 3, error));
    CHECK(count == 0);
    world[16 * 2 + 3] = -2.5; /* part 2 onto part 0 */
    EXPECT_SUCCESS("overlap", sk_detect_collisions(pairs, &count, world, boxes, axes, parents, 3, 3, error));
    CHECK(count == 1 && pairs[0] == 0 && pairs[1] == 2);
    EXPECT_FAILURE("capacity", SK_ERROR_ARGUMENT, sk_detect_collisions(pairs, &count, world, boxes, axes, parents, 3,
                                                                       0, error));
    /* Turned 45 degrees about z, a box near a corner of another separates only on a cross-product axis. */
    const double c = sqrt(0.5);
    world[16 * 2 + 0] = c, world[16 * 2 + 1] = -c, world[16 * 2 + 4] = c, world[16 * 2 + 5] = c;
    world[16 * 2 + 3] = -3.0 + 2.0 + sqrt(2.0) + 0.01;
    EXPECT_SUCCESS("corner", sk_detect_collisions(pairs, &count, world, boxes, axes, parents, 3, 3, error));
    CHECK(count == 0);
}

/* A chain 0-1-2-3 and a branch 4 under 0: identity frames, unit boxes along x at 0, 1.5, 3, 4.5 and 4 at 1.5 above. */
static void chain_with_branch(double world[80], double boxes[30], double axes[45])
{
    memset(world, 0, 80 * sizeof *world);
    memset(axes, 0, 45 * sizeof *axes);
    for (int p = 0; p < 5; ++p) {
        for (int k = 0; k < 4; ++k)
            world[16 * p + 5 * k] = 1.0;
        for (int k = 0; k < 3; ++k) {
            axes[9 * p + 4 * k] = 1.0;
            boxes[6 * p + 3 + k] = 0.6;
        }
        boxes[6 * p] = p < 4 ? 1.5 * p : 0.0;
        boxes[6 * p + 1] = p < 4 ? 0.0 : 1.5;
        boxes[6 * p + 2] = 0.0;
    }
}

static void test_collision_candidates_and_ordered_tests(void)
{
    const int32_t parents[5] = {-1, 0, 1, 2, 0};
    int32_t pairs[20];
    size_t count = 0;
    EXPECT_SUCCESS("all", sk_collision_candidates(pairs, &count, parents, 5, -1, 10, error));
    CHECK(count == 6); /* 10 pairs less the 4 parent-child ones */
    EXPECT_SUCCESS("joint 2", sk_collision_candidates(pairs, &count, parents, 5, 2, 10, error));
    /* Moving part 2 carries {2, 3}; across: (0,2) (0,3) (1,3) (2,4) (3,4) but (1,2) is parent-child. */
    const int32_t expected[10] = {0, 2, 0, 3, 1, 3, 2, 4, 3, 4};
    CHECK(count == 5 && memcmp(pairs, expected, sizeof expected) == 0);
    EXPECT_SUCCESS("root moves", sk_collision_candidates(pairs, &count, parents, 5, 0, 10, error));
    CHECK(count == 0); /* everything turns together */
    EXPECT_FAILURE("moved part", SK_ERROR_INDEX, sk_collision_candidates(pairs, &count, parents, 5, 5, 10, error));
    EXPECT_FAILURE("capacity", SK_ERROR_ARGUMENT, sk_collision_candidates(pairs, &count, parents, 5, -1, 2, error));

    double world[80], boxes[30], axes[45];
    chain_with_branch(world, boxes, axes);
    int32_t all[20], found[20], tested[10];
    double weights[10];
    size_t all_count = 0;
    EXPECT_SUCCESS("candidates", sk_collision_candidates(all, &all_count, parents, 5, -1, 10, error));
    sk_collision_report report;
    EXPECT_SUCCESS("apart", sk_detect_collisions_among(found, tested, weights, &report, world, boxes, axes, all,
                                                       all_count, 5, 0, 10, error));
    CHECK(report.pair_count == 0);
    /* Part 3 folded back over part 1 and part 2 pushed onto part 4: two collisions, the nearer one tested first. */
    world[16 * 3 + 3] = -3.0;
    world[16 * 2 + 3] = -2.5, world[16 * 2 + 7] = 1.4;
    EXPECT_SUCCESS("two", sk_detect_collisions_among(found, tested, weights, &report, world, boxes, axes, all,
                                                     all_count, 5, 0, 10, error));
    CHECK(report.pair_count == 2 && report.box_tests == report.sphere_hits);
    for (size_t t = 1; t < report.sphere_hits; ++t)
        CHECK(weights[tested[t - 1]] <= weights[tested[t]]);
    size_t plain = 0;
    int32_t plain_pairs[20];
    EXPECT_SUCCESS("all pairs", sk_detect_collisions(plain_pairs, &plain, world, boxes, axes, parents, 5, 10, error));
    CHECK(plain == report.pair_count);
    EXPECT_SUCCESS("first", sk_detect_collisions_among(found, tested, weights, &report, world, boxes, axes, all,
                                                       all_count, 5, 1, 10, error));
    CHECK(report.pair_count == 1 && report.box_tests <= report.sphere_hits);
    const int32_t bad[2] = {1, 1};
    EXPECT_FAILURE("pair", SK_ERROR_INDEX, sk_detect_collisions_among(found, tested, weights, &report, world, boxes,
                                                                      axes, bad, 1, 5, 0, 10, error));
}

static void test_seam_points_follow_arcs(void)
{
    /* Part 1 turned a quarter turn about z at the joint (1, 0, 0); part 0 fixed. */
    double world[32] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, -1, 0, 1, 1, 0, 0, -1, 0, 0, 1, 0, 0, 0, 0, 1};
    const double joints[6] = {0, 0, 0, 1, 0, 0}, rest[3] = {1, 0.5, 0};
    const int32_t sources[3] = {0, 0, 0}, parts_a[3] = {0, 0, 1}, parts_b[3] = {-1, 1, -1};
    const double blend[3] = {0.0, 0.5, 0.0};
    double positions[9];
    EXPECT_SUCCESS("seams", sk_evaluate_seams(positions, rest, world, joints, sources, parts_a, parts_b, blend, 3, 1, 2,
                                              error));
    CHECK(fabs(positions[0] - 1.0) < 1e-12 && fabs(positions[1] - 0.5) < 1e-12); /* rigid on part 0 */
    CHECK(fabs(positions[6] - 0.5) < 1e-12 && fabs(positions[7]) < 1e-12);       /* rigid on part 1 */
    const double dx = positions[3] - 1.0, dy = positions[4]; /* half way: 45 degrees round the joint */
    CHECK(fabs(sqrt(dx * dx + dy * dy) - 0.5) < 1e-12 && fabs(dx + sqrt(0.125)) < 1e-12);
    const double bad_blend[3] = {0.0, 1.5, 0.0};
    EXPECT_FAILURE("blend", SK_ERROR_ARGUMENT, sk_evaluate_seams(positions, rest, world, joints, sources, parts_a,
                                                                 parts_b, bad_blend, 3, 1, 2, error));
    const int32_t bad_source[3] = {0, 1, 0};
    EXPECT_FAILURE("source", SK_ERROR_INDEX, sk_evaluate_seams(positions, rest, world, joints, bad_source, parts_a,
                                                               parts_b, blend, 3, 1, 2, error));
}

/* ---- Algorithm 5 per frame (sk_seam_fill.c) on the chain with its vertices unsplit: part 0 fixed, parts 1 and 2
 * pushed 0.6 along -x into it, so rings 3, 4 and 5 sink all round and the kept surface falls in two pieces. */

enum { SEAM_POINTS = VERTICES, CAPACITY = VERTICES + TRIANGLES };

typedef struct seam_case {
    int32_t sources[VERTICES], parts_a[VERTICES], parts_b[VERTICES], twins[3 * TRIANGLES];
    double blend[VERTICES], joints[3 * PARTS], boxes[15 * PARTS], planes[6];
    int32_t ring_offsets[VERTICES + 1], ring[6 * TRIANGLES], seam_parts[2], start_offsets[3], starts[2 * SIDES];
    double positions[3 * CAPACITY], normals[3 * CAPACITY], seconds[4];
    int32_t triangles[6 * CAPACITY], counts[6];
} seam_case;

static void make_seam_case(seam_case *k, const chain *c)
{
    memset(k, 0, sizeof *k);
    for (int32_t v = 0; v < VERTICES; ++v) {
        const int ring = v < RINGS * SIDES ? v / SIDES : (v == RINGS * SIDES ? 0 : RINGS - 1);
        k->sources[v] = v;
        k->parts_a[v] = ring / RINGS_PER_PART < PARTS ? ring / RINGS_PER_PART : PARTS - 1;
        k->parts_b[v] = -1;
    }
    for (int p = 0; p < PARTS; ++p) {
        double *box = k->boxes + 15 * p;
        box[0] = LENGTH * (p + 0.5);
        box[3] = box[7] = box[11] = 1.0; /* axes: the identity's rows */
        box[12] = LENGTH / 2;
        box[13] = box[14] = RADIUS * 1.2;
        k->joints[3 * p] = LENGTH * p;
    }
    for (size_t e = 0; e < 3 * TRIANGLES; ++e) { /* twins by brute force: the edge running back */
        const int32_t u = c->triangles[e], v = c->triangles[3 * (e / 3) + (e % 3 + 1) % 3];
        k->twins[e] = -1;
        for (size_t f = 0; f < 3 * TRIANGLES; ++f)
            if (c->triangles[f] == v && c->triangles[3 * (f / 3) + (f % 3 + 1) % 3] == u)
                k->twins[e] = (int32_t)f;
    }
    int32_t degree[VERTICES] = {0};
    for (size_t e = 0; e < 3 * TRIANGLES; ++e)
        ++degree[c->triangles[e]];
    for (int32_t v = 0; v < VERTICES; ++v)
        k->ring_offsets[v + 1] = k->ring_offsets[v] + 2 * degree[v];
    int32_t filled[VERTICES] = {0};
    for (size_t e = 0; e < 3 * TRIANGLES; ++e) { /* both neighbours along each corner's edges (duplicates are fine) */
        const int32_t u = c->triangles[e], v = c->triangles[3 * (e / 3) + (e % 3 + 1) % 3],
                      w = c->triangles[3 * (e / 3) + (e % 3 + 2) % 3];
        k->ring[k->ring_offsets[u] + filled[u]++] = v;
        k->ring[k->ring_offsets[u] + filled[u]++] = w;
    }
    k->seam_parts[0] = 0;
    k->seam_parts[1] = 1;
    k->start_offsets[1] = SIDES;
    k->start_offsets[2] = 2 * SIDES;
    for (int s = 0; s < SIDES; ++s) {
        k->starts[s] = ring_vertex(RINGS_PER_PART - 1, s); /* part 0's ring next to the opening */
        k->starts[SIDES + s] = ring_vertex(RINGS_PER_PART, s);
    }
    k->planes[0] = LENGTH;
    k->planes[3] = 1.0; /* the opening plane x = LENGTH, normal into part 1 */
}

static sk_status reconstruct(seam_case *k, const chain *c, const double *world, size_t capacity,
                             sk_progress_fn progress, sk_error *error)
{
    const sk_seam_topology topology = {c->positions, VERTICES, k->joints, PARTS, k->sources, k->parts_a,
                                       k->parts_b, k->blend, SEAM_POINTS, c->triangles, k->twins, TRIANGLES,
                                       NULL, 0, NULL, 0, 0};
    const sk_seam_removal removal = {k->ring_offsets, k->ring, k->boxes, k->seam_parts, k->start_offsets,
                                     k->starts, k->planes, 1};
    return sk_reconstruct_seams(k->positions, k->triangles, k->normals, k->counts, k->seconds, &topology, &removal,
                                world, 1, capacity, 2 * capacity, 1, 0, progress, NULL, error);
}

/* Every directed edge once and its reverse present, and V - E + F = 2 over the used vertices. */
static int closed_sphere(const int32_t *triangles, size_t triangle_count, size_t vertex_count)
{
    for (size_t e = 0; e < 3 * triangle_count; ++e) {
        const int32_t u = triangles[e], v = triangles[3 * (e / 3) + (e % 3 + 1) % 3];
        int same = 0, reverse = 0;
        for (size_t f = 0; f < 3 * triangle_count; ++f) {
            const int32_t a = triangles[f], b = triangles[3 * (f / 3) + (f % 3 + 1) % 3];
            same += a == u && b == v;
            reverse += a == v && b == u;
        }
        if (same != 1 || reverse != 1)
            return 0;
    }
    return 2 * vertex_count == triangle_count + 4;
}

static int cancel_at_once(void *user, double fraction)
{
    (void)user;
    (void)fraction;
    return 1;
}

static void test_sunk_rings_are_removed_and_the_pieces_bridged(void)
{
    static chain c;
    static seam_case k;
    make_chain(&c);
    make_seam_case(&k, &c);
    double world[16 * PARTS];
    for (int p = 0; p < PARTS; ++p) {
        memset(world + 16 * p, 0, 16 * sizeof(double));
        world[16 * p] = world[16 * p + 5] = world[16 * p + 10] = world[16 * p + 15] = 1.0;
    }
    EXPECT_SUCCESS("at rest", reconstruct(&k, &c, world, CAPACITY, NULL, error));
    CHECK(k.counts[0] == VERTICES && k.counts[1] == TRIANGLES && k.counts[2] == 0 && k.counts[5] == 0);
    CHECK(memcmp(k.triangles, c.triangles, sizeof c.triangles) == 0);
    world[16 * 1 + 3] = world[16 * 2 + 3] = -0.6;
    EXPECT_SUCCESS("pushed in", reconstruct(&k, &c, world, CAPACITY, NULL, error));
    CHECK(k.counts[2] == 3 * SIDES); /* rings 3, 4 and 5 */
    CHECK(k.counts[5] == 0);         /* bridged, not fallen back */
    CHECK(k.counts[0] == VERTICES - 3 * SIDES && k.counts[3] == 0);
    CHECK(closed_sphere(k.triangles, (size_t)k.counts[1], (size_t)k.counts[0]));
    for (int32_t v = 0; v < k.counts[0]; ++v)
        CHECK(fabs(sqrt(k.normals[3 * v] * k.normals[3 * v] + k.normals[3 * v + 1] * k.normals[3 * v + 1] +
                        k.normals[3 * v + 2] * k.normals[3 * v + 2]) - 1.0) < 1e-9);
    EXPECT_FAILURE("capacity", SK_ERROR_ARGUMENT, reconstruct(&k, &c, world, VERTICES / 2, NULL, error));
    EXPECT_FAILURE("cancel", SK_ERROR_CANCELLED, reconstruct(&k, &c, world, CAPACITY, cancel_at_once, error));
    k.twins[7] = 3 * TRIANGLES;
    EXPECT_FAILURE("twins", SK_ERROR_INDEX, reconstruct(&k, &c, world, CAPACITY, NULL, error));
    k.twins[7] = -1;
    k.starts[3] = VERTICES;
    EXPECT_FAILURE("starts", SK_ERROR_INDEX, reconstruct(&k, &c, world, CAPACITY, NULL, error));
}

static void test_conic_arc_lies_on_its_conic(void)
{
    /* C = (0, 0), D = (3, 1), tangents toward X = (1, 2.5): barycentrics on (C, X, D) satisfy b1^2 = 4 w^2 b0 b2. */
    const double start[3] = {0, 0, 0}, end[3] = {3, 1, 0}, start_tangent[3] = {1, 2.5, 0}, end_tangent[3] = {-2, 1.5, 0};
    const double through[3] = {1.3, 1.2, 0};
    double points[3 * 7], weight;
    EXPECT_SUCCESS("conic", sk_conic_arc(points, &weight, 7, start, start_tangent, end, end_tangent, through, error));
    for (int k = 0; k < 7; ++k) {
        const double *p = points + 3 * k;
        /* p = b0 C + b1 X + b2 D with C at the origin: solve [X D] (b1, b2) = p */
        const double determinant = 1.0 * 1.0 - 3.0 * 2.5;
        const double b1 = (p[0] * 1.0 - 3.0 * p[1]) / determinant, b2 = (1.0 * p[1] - 2.5 * p[0]) / determinant;
        const double b0 = 1.0 - b1 - b2;
        CHECK(fabs(b1 * b1 - 4.0 * weight * weight * b0 * b2) < 1e-9 && fabs(p[2]) < 1e-12);
    }
    const double behind[3] = {-1, 1, 0};
    EXPECT_FAILURE("no conic", SK_ERROR_ARGUMENT,
                   sk_conic_arc(points, &weight, 7, start, start_tangent, end, end_tangent, behind, error));
    EXPECT_FAILURE("no plane", SK_ERROR_ARGUMENT,
                   sk_conic_arc(points, &weight, 7, start, start_tangent, start, end_tangent, through, error));
}

int main(void)
{
    test_program_name = "test_skeleton";
    test_centroid_method_finds_openings_and_kernels();
    test_principal_axis_method_reaches_the_ends();
    test_given_hierarchy_is_kept();
    test_bad_parts_are_refused();
    test_part_without_opening_is_named();
    test_options_are_checked();
    test_forward_kinematics_turns_about_the_joint();
    test_collisions_skip_parents_and_find_overlaps();
    test_collision_candidates_and_ordered_tests();
    test_seam_points_follow_arcs();
    test_sunk_rings_are_removed_and_the_pieces_bridged();
    test_conic_arc_lies_on_its_conic();
    return finish_tests();
}
