/*
 * The runtime (csrc/runtime/sk_runtime_*.c): batched geomorphing skinning by every kernel against a double
 * precision reference of v = sum_k G_k (p_k + f dp_k), culling against random frusta (no visible sphere is ever
 * culled), level selection (the interpolated epsilon never exceeds the allowed error), UV morphing, and the
 * refusals of bad input. Linked without LAPACK, like test_runtime_link.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "test_support.h"

typedef struct test_pack {
    test_mesh mesh;                 /* the CSR pattern over every mesh's vertices */
    float *positions, *tangents;    /* 8 and 16 per influence */
    int32_t *mesh_starts;           /* 4: three meshes */
    sk_runtime_pack pack;
} test_pack;

static void random_floats(float *values, size_t count, double low, double high)
{
    for (size_t i = 0; i < count; ++i)
        values[i] = (float)random_uniform(low, high);
}

/* Three meshes of vertex_count / 3 vertices (the last takes the rest) in one pack. */
static test_pack make_pack(size_t vertex_count, size_t bone_count)
{
    test_pack t = {.mesh = make_random_mesh(vertex_count, bone_count)};
    t.positions = allocate(8 * t.mesh.influence_count, sizeof(float));
    t.tangents = allocate(16 * t.mesh.influence_count, sizeof(float));
    random_floats(t.positions, 8 * t.mesh.influence_count, -1.0, 1.0);
    random_floats(t.tangents, 16 * t.mesh.influence_count, -1.0, 1.0);
    t.mesh_starts = allocate(4, sizeof(int32_t));
    t.mesh_starts[1] = (int32_t)(vertex_count / 3);
    t.mesh_starts[2] = (int32_t)(2 * vertex_count / 3);
    t.mesh_starts[3] = (int32_t)vertex_count;
    t.pack = (sk_runtime_pack){t.mesh.influences, t.positions, t.tangents, t.mesh_starts, 3};
    return t;
}

static void free_pack(test_pack *t)
{
    free(t->positions);
    free(t->tangents);
    free(t->mesh_starts);
    free_mesh(&t->mesh);
}

typedef struct test_crowd {
    int32_t *meshes, *output_starts;
    float *fractions, *matrices;
    size_t output_vertex_count;
    sk_runtime_instances instances;
} test_crowd;

static test_crowd make_crowd(const test_pack *t, size_t instance_count)
{
    const size_t bones = t->mesh.bone_count;
    test_crowd c = {.meshes = allocate(instance_count, sizeof(int32_t)),
                    .output_starts = allocate(instance_count + 1, sizeof(int32_t)),
                    .fractions = allocate(instance_count, sizeof(float)),
                    .matrices = allocate(12 * bones * instance_count, sizeof(float))};
    random_floats(c.matrices, 12 * bones * instance_count, -2.0, 2.0);
    for (size_t i = 0; i < instance_count; ++i) {
        c.meshes[i] = (int32_t)(i % 3);
        c.fractions[i] = i == 0 ? 0.0f : i == 1 ? 1.0f : (float)random_uniform(0.0, 1.0);
        c.output_starts[i + 1] = c.output_starts[i] + t->mesh_starts[c.meshes[i] + 1] - t->mesh_starts[c.meshes[i]];
    }
    c.output_vertex_count = (size_t)c.output_starts[instance_count];
    c.instances = (sk_runtime_instances){c.meshes, c.fractions, c.matrices, c.output_starts, instance_count, bones};
    return c;
}

static void free_crowd(test_crowd *c)
{
    free(c->meshes);
    free(c->output_starts);
    free(c->fractions);
    free(c->matrices);
}

/* The definition, in double precision: stream s of instance i, vertex v (pack numbering). */
static void reference_vertex(double out[3], const test_pack *t, const test_crowd *c, size_t i, size_t v, int stream)
{
    const float *data = stream == 0 ? t->positions : t->tangents + 8 * (stream - 1);
    const size_t stride = stream == 0 ? 8 : 16;
    const double f = c->fractions[i];
    out[0] = out[1] = out[2] = 0.0;
    for (int32_t k = t->mesh.offsets[v]; k < t->mesh.offsets[v + 1]; ++k) {
        const float *m = c->matrices + 12 * (c->instances.bone_count * i + (size_t)t->mesh.bones[k]);
        const float *p = data + stride * (size_t)k;
        for (int r = 0; r < 3; ++r)
            for (int col = 0; col < 4; ++col)
                out[r] += (double)m[4 * r + col] * ((double)p[col] + f * (double)p[4 + col]);
    }
}

static double worst_difference(const test_pack *t, const test_crowd *c, float *const outputs[3])
{
    double worst = 0.0;
    for (size_t i = 0; i < c->instances.instance_count; ++i)
        for (int32_t o = c->output_starts[i]; o < c->output_starts[i + 1]; ++o) {
            const size_t v = (size_t)(t->mesh_starts[c->meshes[i]] + (o - c->output_starts[i]));
            for (int s = 0; s < 3; ++s) {
                double expected[3];
                reference_vertex(expected, t, c, i, v, s);
                for (int r = 0; r < 3; ++r) {
                    const double d = fabs(outputs[s][3 * o + r] - expected[r]) / (1.0 + fabs(expected[r]));
                    worst = d > worst ? d : worst;
                }
            }
        }
    return worst;
}

static void test_kernels_agree_with_the_definition(void)
{
    test_pack t = make_pack(3000, 12);
    test_crowd c = make_crowd(&t, 7);
    float *outputs[3];
    for (int s = 0; s < 3; ++s)
        outputs[s] = allocate(3 * c.output_vertex_count, sizeof(float));
    for (int kernel = SK_RUNTIME_KERNEL_AUTO; kernel <= SK_RUNTIME_KERNEL_AVX2; ++kernel) {
        size_t supported = 7;
        EXPECT_SUCCESS("kernel supported", sk_runtime_kernel_supported(&supported, kernel, error));
        CHECK(supported == 0 || supported == 1);
        CHECK(kernel > SK_RUNTIME_KERNEL_SSE2 || supported == 1); /* the x86-64 baseline is always there */
        if (!supported) {
            EXPECT_FAILURE("an unsupported kernel", SK_ERROR_ARGUMENT,
                           sk_runtime_skin(outputs[0], outputs[1], outputs[2], c.output_vertex_count, &t.pack,
                                           &c.instances, kernel, 1, error));
            continue;
        }
        for (int threads = 1; threads <= 3; threads += 2) {
            for (int s = 0; s < 3; ++s)
                memset(outputs[s], 0xff, 3 * c.output_vertex_count * sizeof(float)); /* NaNs unless written */
            EXPECT_SUCCESS("skin", sk_runtime_skin(outputs[0], outputs[1], outputs[2], c.output_vertex_count, &t.pack,
                                                   &c.instances, kernel, threads, error));
            CHECK_IN(kernel == 1 ? "scalar" : kernel == 2 ? "sse2" : kernel == 3 ? "avx2" : "auto",
                     worst_difference(&t, &c, outputs) < 1e-5);
        }
    }
    /* positions only: the tangent outputs may be left out, the pack's tangents then too */
    sk_runtime_pack no_tangents = t.pack;
    no_tangents.tangents = NULL;
    EXPECT_SUCCESS("positions only", sk_runtime_skin(outputs[0], NULL, NULL, c.output_vertex_count, &no_tangents,
                                                     &c.instances, 0, 1, error));
    EXPECT_FAILURE("tangents without pack tangents", SK_ERROR_ARGUMENT,
                   sk_runtime_skin(outputs[0], outputs[1], outputs[2], c.output_vertex_count, &no_tangents,
                                   &c.instances, 0, 1, error));
    EXPECT_FAILURE("one tangent output", SK_ERROR_ARGUMENT,
                   sk_runtime_skin(outputs[0], outputs[1], NULL, c.output_vertex_count, &t.pack, &c.instances, 0, 1,
                                   error));
    for (int s = 0; s < 3; ++s)
        free(outputs[s]);
    free_crowd(&c);
    free_pack(&t);
}

/* Enough vertices for several workers, with instances whose ranges straddle the workers' boundaries. */
static void test_threads_split_instances(void)
{
    test_pack t = make_pack(60000, 5);
    test_crowd c = make_crowd(&t, 5);
    float *serial = allocate(3 * c.output_vertex_count, sizeof(float));
    float *threaded = allocate(3 * c.output_vertex_count, sizeof(float));
    EXPECT_SUCCESS("serial", sk_runtime_skin(serial, NULL, NULL, c.output_vertex_count, &t.pack, &c.instances,
                                             SK_RUNTIME_KERNEL_SSE2, 1, error));
    EXPECT_SUCCESS("threaded", sk_runtime_skin(threaded, NULL, NULL, c.output_vertex_count, &t.pack, &c.instances,
                                               SK_RUNTIME_KERNEL_SSE2, 4, error));
    CHECK(memcmp(serial, threaded, 3 * c.output_vertex_count * sizeof(float)) == 0);
    free(serial);
    free(threaded);
    free_crowd(&c);
    free_pack(&t);
}

static void test_skin_refusals(void)
{
    test_pack t = make_pack(300, 4);
    test_crowd c = make_crowd(&t, 3);
    float *out = allocate(3 * c.output_vertex_count, sizeof(float));
    const size_t n = c.output_vertex_count;
    EXPECT_FAILURE("unknown kernel", SK_ERROR_ARGUMENT,
                   sk_runtime_skin(out, NULL, NULL, n, &t.pack, &c.instances, 9, 1, error));
    EXPECT_FAILURE("wrong output size", SK_ERROR_ARGUMENT,
                   sk_runtime_skin(out, NULL, NULL, n - 1, &t.pack, &c.instances, 0, 1, error));
    c.meshes[1] = 3;
    EXPECT_FAILURE("mesh out of range", SK_ERROR_INDEX,
                   sk_runtime_skin(out, NULL, NULL, n, &t.pack, &c.instances, 0, 1, error));
    c.meshes[1] = 1;
    c.fractions[2] = 1.5f;
    EXPECT_FAILURE("fraction above 1", SK_ERROR_ARGUMENT,
                   sk_runtime_skin(out, NULL, NULL, n, &t.pack, &c.instances, 0, 1, error));
    c.fractions[2] = 0.5f;
    c.matrices[5] = NAN;
    EXPECT_FAILURE("NaN matrix", SK_ERROR_NOT_FINITE,
                   sk_runtime_skin(out, NULL, NULL, n, &t.pack, &c.instances, 0, 1, error));
    c.matrices[5] = 0.0f;
    /* a bad bone at every position of some vertex's influences: first, in a pair, at an odd tail; too big or negative */
    for (int kernel = SK_RUNTIME_KERNEL_SCALAR; kernel <= SK_RUNTIME_KERNEL_AVX2; ++kernel) {
        size_t supported = 0;
        EXPECT_SUCCESS("kernel supported", sk_runtime_kernel_supported(&supported, kernel, error));
        for (size_t k = 0; supported && k < 12; ++k) {
            const int32_t saved = t.mesh.bones[k];
            t.mesh.bones[k] = k % 2 ? -1 : 4; /* bone_count is 4 */
            sk_error record = empty_error();
            CHECK(sk_runtime_skin(out, NULL, NULL, n, &t.pack, &c.instances, kernel, 1, &record) == SK_ERROR_INDEX);
            CHECK(strstr(record.message, "pack vertex") != NULL);
            t.mesh.bones[k] = saved;
        }
    }
    t.mesh_starts[1] = t.mesh_starts[2] + 1;
    EXPECT_FAILURE("mesh ranges decreasing", SK_ERROR_INDEX,
                   sk_runtime_skin(out, NULL, NULL, n, &t.pack, &c.instances, 0, 1, error));
    free(out);
    free_crowd(&c);
    free_pack(&t);
}

/* ---- the fixed-K layout ------------------------------------------------------------------------------------- */

typedef struct test_fixed {
    uint16_t *bones;
    float *streams[3]; /* positions, tangent_0, tangent_1 in the fixed layout */
    sk_runtime_fixed_pack pack;
} test_fixed;

/* The CSR pack's data in the fixed layout: K = the most influences of a vertex, rounded up to even; padding is
 * bone 0 with zero coordinates. Without dp (floats_per_slot 4) the pack keeps only p. */
static test_fixed make_fixed(const test_pack *t, size_t floats_per_slot)
{
    const size_t vertices = t->mesh.vertex_count;
    size_t slots = 2;
    for (size_t v = 0; v < vertices; ++v) {
        const size_t count = (size_t)(t->mesh.offsets[v + 1] - t->mesh.offsets[v]);
        slots = count + count % 2 > slots ? count + count % 2 : slots;
    }
    test_fixed f = {.bones = allocate(vertices * slots, sizeof(uint16_t))};
    for (int s = 0; s < 3; ++s)
        f.streams[s] = allocate(vertices * slots * floats_per_slot, sizeof(float));
    for (size_t v = 0; v < vertices; ++v)
        for (int32_t k = t->mesh.offsets[v]; k < t->mesh.offsets[v + 1]; ++k) {
            const size_t slot = (size_t)(k - t->mesh.offsets[v]);
            f.bones[v * slots + slot] = (uint16_t)t->mesh.bones[k];
            const size_t start = v * slots * floats_per_slot + slot / 2 * 2 * floats_per_slot + 4 * (slot % 2);
            for (int s = 0; s < 3; ++s) {
                const float *csr = s == 0 ? t->positions + 8 * (size_t)k : t->tangents + 16 * (size_t)k + 8 * (s - 1);
                memcpy(f.streams[s] + start, csr, 4 * sizeof(float));
                if (floats_per_slot == 8)
                    memcpy(f.streams[s] + start + 8, csr + 4, 4 * sizeof(float));
            }
        }
    f.pack = (sk_runtime_fixed_pack){f.bones, f.streams[0], f.streams[1], f.streams[2], t->mesh_starts, 3, vertices,
                                     slots, floats_per_slot};
    return f;
}

static void free_fixed(test_fixed *f)
{
    free(f->bones);
    for (int s = 0; s < 3; ++s)
        free(f->streams[s]);
}

/* Both layouts, every kernel, one and three threads, against the double-precision definition; the pack without
 * dp against the definition at fraction 0. Meshes of 1000 and 1001 vertices leave partial blocks of four; the
 * outputs start one float past an allocation's (16-byte aligned) start, so the streamed blocks of four begin after
 * single vertices. */
static void test_fixed_layout_agrees_with_the_definition(void)
{
    test_pack t = make_pack(3001, 12);
    test_crowd c = make_crowd(&t, 7);
    float *buffers[3], *outputs[3];
    for (int s = 0; s < 3; ++s) {
        buffers[s] = allocate(3 * c.output_vertex_count + 1, sizeof(float));
        outputs[s] = buffers[s] + 1;
    }
    for (size_t floats = 4; floats <= 8; floats += 4) {
        test_fixed f = make_fixed(&t, floats);
        CHECK(f.pack.influences_per_vertex >= 4); /* the random mesh has vertices with 3 or more influences */
        for (size_t i = 0; floats == 4 && i < c.instances.instance_count; ++i)
            c.fractions[i] = 0.0f;
        for (int kernel = SK_RUNTIME_KERNEL_AUTO; kernel <= SK_RUNTIME_KERNEL_AVX2; ++kernel) {
            size_t supported = 0;
            EXPECT_SUCCESS("kernel supported", sk_runtime_kernel_supported(&supported, kernel, error));
            for (int threads = 1; supported && threads <= 3; threads += 2) {
                for (int s = 0; s < 3; ++s)
                    memset(outputs[s], 0xff, 3 * c.output_vertex_count * sizeof(float)); /* NaNs unless written */
                EXPECT_SUCCESS("skin fixed", sk_runtime_skin_fixed(outputs[0], outputs[1], outputs[2],
                                                                   c.output_vertex_count, &f.pack, &c.instances,
                                                                   kernel, threads, error));
                CHECK_IN(floats == 8 ? "fixed, morphing" : "fixed, p only", worst_difference(&t, &c, outputs) < 1e-5);
            }
        }
        free_fixed(&f);
    }
    for (int s = 0; s < 3; ++s)
        free(buffers[s]);
    free_crowd(&c);
    free_pack(&t);
}

static void test_fixed_refusals(void)
{
    test_pack t = make_pack(302, 4); /* meshes of 100, 101 and 101 vertices */
    test_crowd c = make_crowd(&t, 3);
    test_fixed f = make_fixed(&t, 8);
    float *out = allocate(3 * c.output_vertex_count, sizeof(float));
    const size_t n = c.output_vertex_count;
    sk_runtime_fixed_pack bad = f.pack;
    bad.influences_per_vertex = 3;
    EXPECT_FAILURE("odd K", SK_ERROR_ARGUMENT,
                   sk_runtime_skin_fixed(out, NULL, NULL, n, &bad, &c.instances, 0, 1, error));
    bad = f.pack;
    bad.floats_per_slot = 6;
    EXPECT_FAILURE("floats per slot", SK_ERROR_ARGUMENT,
                   sk_runtime_skin_fixed(out, NULL, NULL, n, &bad, &c.instances, 0, 1, error));
    bad = f.pack;
    bad.vertex_count += 1;
    EXPECT_FAILURE("vertex count", SK_ERROR_INDEX,
                   sk_runtime_skin_fixed(out, NULL, NULL, n, &bad, &c.instances, 0, 1, error));
    bad = f.pack;
    bad.tangent_1 = NULL;
    EXPECT_FAILURE("one pack tangent", SK_ERROR_ARGUMENT,
                   sk_runtime_skin_fixed(out, NULL, NULL, n, &bad, &c.instances, 0, 1, error));
    bad = f.pack;
    bad.floats_per_slot = 4; /* reads half the floats: fine for size, but the fractions must be 0 */
    c.fractions[0] = 0.0f;
    c.fractions[1] = 0.0f;
    c.fractions[2] = 0.25f;
    EXPECT_FAILURE("a fraction without dp", SK_ERROR_ARGUMENT,
                   sk_runtime_skin_fixed(out, NULL, NULL, n, &bad, &c.instances, 0, 1, error));
    /* a bad bone in every slot of the first block's vertices and of a tail vertex, for every kernel */
    const size_t slots = f.pack.influences_per_vertex;
    const size_t tail = (size_t)t.mesh_starts[3] - 1; /* mesh 2 has 101 vertices: its last is in no block of 4 */
    for (int kernel = SK_RUNTIME_KERNEL_SCALAR; kernel <= SK_RUNTIME_KERNEL_AVX2; ++kernel) {
        size_t supported = 0;
        EXPECT_SUCCESS("kernel supported", sk_runtime_kernel_supported(&supported, kernel, error));
        for (size_t k = 0; supported && k < 4 * slots + slots; ++k) {
            uint16_t *bone = k < 4 * slots ? f.bones + k : f.bones + tail * slots + (k - 4 * slots);
            const uint16_t saved = *bone;
            *bone = 4; /* bone_count is 4 */
            sk_error record = empty_error();
            CHECK(sk_runtime_skin_fixed(out, NULL, NULL, n, &f.pack, &c.instances, kernel, 1, &record) ==
                  SK_ERROR_INDEX);
            CHECK(strstr(record.message, "pack vertex") != NULL);
            *bone = saved;
        }
    }
    EXPECT_SUCCESS("restored", sk_runtime_skin_fixed(out, NULL, NULL, n, &f.pack, &c.instances, 0, 1, error));
    free(out);
    free_fixed(&f);
    free_crowd(&c);
    free_pack(&t);
}

/* ---- culling and level selection ---------------------------------------------------------------------------- */

/* A random perspective view: row-major projection * view, camera at eye looking along forward. */
static void random_view(float view_projection[16], double eye[3], double forward[3], double *fov)
{
    double rotation[9];
    random_rotation(rotation);
    for (int c = 0; c < 3; ++c) {
        eye[c] = random_uniform(-5.0, 5.0);
        forward[c] = -rotation[6 + c]; /* the camera looks down its -z */
    }
    *fov = random_uniform(0.3, 2.0);
    const double aspect = random_uniform(0.5, 2.0), near = random_uniform(0.05, 1.0), far = near + random_uniform(5, 50);
    const double fx = 1.0 / tan(*fov / 2), fy = fx * aspect;
    double view[16] = {0}, projection[16] = {0}, product[16];
    for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c)
            view[4 * r + c] = rotation[3 * r + c];
        view[4 * r + 3] = -(rotation[3 * r] * eye[0] + rotation[3 * r + 1] * eye[1] + rotation[3 * r + 2] * eye[2]);
    }
    view[15] = 1.0;
    projection[0] = fx;
    projection[5] = fy;
    projection[10] = -(far + near) / (far - near);
    projection[11] = -2.0 * far * near / (far - near);
    projection[14] = -1.0;
    multiply(product, projection, view);
    for (int i = 0; i < 16; ++i)
        view_projection[i] = (float)product[i];
}

static int point_in_clip(const float m[16], const double p[3])
{
    double clip[4];
    for (int r = 0; r < 4; ++r)
        clip[r] = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
    return clip[3] > 0 && fabs(clip[0]) <= clip[3] && fabs(clip[1]) <= clip[3] && fabs(clip[2]) <= clip[3];
}

static void test_culling_never_culls_a_visible_sphere(void)
{
    int culled_some = 0, kept_some = 0, wrongly_culled = 0;
    for (int trial = 0; trial < 200; ++trial) {
        float view_projection[16], planes[24], spheres[4 * 50];
        uint8_t visible[50];
        double eye[3], forward[3], fov;
        random_view(view_projection, eye, forward, &fov);
        EXPECT_SUCCESS("planes", sk_runtime_frustum_planes(planes, view_projection, error));
        for (int s = 0; s < 50; ++s) {
            for (int c = 0; c < 3; ++c)
                spheres[4 * s + c] = (float)(eye[c] + random_uniform(-30.0, 30.0));
            spheres[4 * s + 3] = (float)random_uniform(0.0, 4.0);
        }
        EXPECT_SUCCESS("cull", sk_runtime_cull(visible, spheres, 50, planes, 6, error));
        for (int s = 0; s < 50; ++s) {
            /* sample the sphere's surface and centre: any sample inside the clip volume makes it visible */
            int seen = 0;
            for (int sample = 0; sample < 200 && !seen; ++sample) {
                double d[3] = {random_uniform(-1, 1), random_uniform(-1, 1), random_uniform(-1, 1)};
                const double scale = sample == 0 ? 0.0 : spheres[4 * s + 3] / (euclidean_norm(d, 3) + 1e-12);
                double p[3];
                for (int c = 0; c < 3; ++c)
                    p[c] = spheres[4 * s + c] + scale * d[c];
                seen = point_in_clip(view_projection, p);
            }
            wrongly_culled += seen && !visible[s];
            culled_some |= !visible[s];
            kept_some |= visible[s];
        }
    }
    CHECK(wrongly_culled == 0);
    CHECK(culled_some && kept_some); /* the frusta did cut through the spheres */
}

static void test_culling_refusals(void)
{
    float planes[24], degenerate[16] = {0}, spheres[4] = {0, 0, 0, -1};
    uint8_t visible[1];
    EXPECT_FAILURE("degenerate matrix", SK_ERROR_ARGUMENT, sk_runtime_frustum_planes(planes, degenerate, error));
    degenerate[3] = INFINITY;
    EXPECT_FAILURE("infinite matrix", SK_ERROR_NOT_FINITE, sk_runtime_frustum_planes(planes, degenerate, error));
    for (int i = 0; i < 24; ++i)
        planes[i] = 0.0f;
    EXPECT_FAILURE("negative radius", SK_ERROR_ARGUMENT, sk_runtime_cull(visible, spheres, 1, planes, 6, error));
    spheres[3] = NAN;
    EXPECT_FAILURE("NaN radius", SK_ERROR_NOT_FINITE, sk_runtime_cull(visible, spheres, 1, planes, 6, error));
}

static void test_selected_level_stays_within_the_allowed_error(void)
{
    enum { instances = 400, level_count = 5 };
    float spheres[4 * instances], epsilons[level_count * instances], levels[instances];
    const float eye[3] = {0.0f, 0.0f, 0.0f}, forward[3] = {0.0f, 0.0f, -1.0f};
    const sk_runtime_camera camera = {eye, forward, 1.0f, 1920.0f};
    const float tolerance = 2.0f;
    for (size_t i = 0; i < instances; ++i) {
        spheres[4 * i] = (float)random_uniform(-10, 10);
        spheres[4 * i + 1] = (float)random_uniform(-10, 10);
        spheres[4 * i + 2] = (float)random_uniform(-400, 5);
        spheres[4 * i + 3] = (float)random_uniform(0, 3);
        float *eps = epsilons + level_count * i;
        eps[0] = 0.0f;
        for (size_t k = 1; k < level_count; ++k)
            eps[k] = eps[k - 1] + (float)random_uniform(0.0, 0.3);
        if (i % 7 == 0)
            eps[level_count - 1] = INFINITY; /* a chain of fewer levels */
    }
    EXPECT_SUCCESS("select", sk_runtime_select_levels(levels, spheres, epsilons, instances, level_count, &camera,
                                                      tolerance, error));
    int interpolated = 0, violations = 0, not_coarsest = 0;
    for (size_t i = 0; i < instances; ++i) {
        const float *s = spheres + 4 * i, *eps = epsilons + level_count * i;
        const double depth = fmax(-(double)s[2] - (double)s[3], 0.0);
        const double allowed = 2.0 * tolerance * depth * sin(0.5) / 1920.0;
        const size_t k = (size_t)floor(levels[i]);
        const double fraction = levels[i] - (double)k;
        CHECK(levels[i] >= 0.0f && k < level_count);
        const double at_level = fraction > 0 ? eps[k] + fraction * ((double)eps[k + 1] - eps[k]) : eps[k];
        violations += at_level > allowed;
        interpolated += fraction > 0;
        /* not needlessly fine: a finer level only when the next is beyond the allowed error */
        not_coarsest += fraction == 0 && k + 1 < level_count && isfinite(eps[k + 1]) && eps[k + 1] <= allowed;
    }
    CHECK(violations == 0);
    CHECK(not_coarsest == 0);
    CHECK(interpolated > 0);
    float inside[4] = {0.0f, 0.0f, 0.0f, 1.0f}, level;
    EXPECT_SUCCESS("inside", sk_runtime_select_levels(&level, inside, epsilons, 1, level_count, &camera, 2.0f, error));
    CHECK(level == 0.0f); /* the camera inside the sphere: full detail */
    const float backwards[3] = {0.0f, 0.0f, -2.0f};
    const sk_runtime_camera bad = {eye, backwards, 1.0f, 1920.0f};
    EXPECT_FAILURE("forward not unit", SK_ERROR_ARGUMENT,
                   sk_runtime_select_levels(&level, inside, epsilons, 1, level_count, &bad, 2.0f, error));
    float decreasing[3] = {0.0f, 1.0f, 0.5f};
    EXPECT_FAILURE("epsilons decrease", SK_ERROR_ARGUMENT,
                   sk_runtime_select_levels(&level, inside, decreasing, 1, 3, &camera, 2.0f, error));
}

static void test_morph_uv(void)
{
    const float morph[8] = {0.25f, 0.5f, 0.5f, -0.5f, 1.0f, 0.0f, 0.0f, 0.0f};
    float uv[4];
    EXPECT_SUCCESS("uv", sk_runtime_morph_uv(uv, morph, 2, 0.5f, error));
    CHECK(uv[0] == 0.5f && uv[1] == 0.25f && uv[2] == 1.0f && uv[3] == 0.0f);
    EXPECT_FAILURE("fraction", SK_ERROR_ARGUMENT, sk_runtime_morph_uv(uv, morph, 2, -0.1f, error));
}

int main(void)
{
    test_program_name = "test_runtime";
    test_kernels_agree_with_the_definition();
    test_threads_split_instances();
    test_skin_refusals();
    test_fixed_layout_agrees_with_the_definition();
    test_fixed_refusals();
    test_culling_never_culls_a_visible_sphere();
    test_culling_refusals();
    test_selected_level_stays_within_the_allowed_error();
    test_morph_uv();
    return finish_tests();
}
