/*
 * The animation-space metrics (Merry 2007, chapter 3): per-joint pose statistics, blocks of the
 * expectation matrix P by the common-ancestor recursion, mean distances (L2,2) and max-distance bounds
 * (L2,inf) by sphere propagation.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "sk_internal.h"
#include "sk_math.h"

/* destination += a^T b */
static void add_transposed_product4(double *destination, const double *a, const double *b)
{
    for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c)
            destination[4 * r + c] += a[r] * b[c] + a[4 + r] * b[4 + c] + a[8 + r] * b[8 + c] + a[12 + r] * b[12 + c];
}

static void identity4(double *m)
{
    memset(m, 0, 16 * sizeof *m);
    m[0] = m[5] = m[10] = m[15] = 1.0;
}

static size_t depth_of(const int32_t *parents, size_t bone)
{
    size_t depth = 0;
    while (bone != 0) {
        bone = (size_t)parents[bone];
        ++depth;
    }
    return depth;
}

/* Bones ordered parents first (by depth), so a forward pass can follow the hierarchy. */
static sk_status parents_first_order(size_t *order, const int32_t *parents, size_t bone_count, sk_error *error)
{
    size_t *depth = sk_allocate(bone_count, sizeof *depth);
    if (!depth)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory");
    size_t count = 0, deepest = 0;
    for (size_t bone = 0; bone < bone_count; ++bone) {
        depth[bone] = depth_of(parents, bone);
        deepest = depth[bone] > deepest ? depth[bone] : deepest;
    }
    for (size_t level = 0; level <= deepest; ++level)
        for (size_t bone = 0; bone < bone_count; ++bone)
            if (depth[bone] == level)
                order[count++] = bone;
    free(depth);
    return SK_OK;
}

/* destination += a^T x a for 4x4 matrices */
static void add_congruence4(double *destination, const double *a, const double *x)
{
    double xa[16];
    sk_multiply4(xa, x, a);
    add_transposed_product4(destination, a, xa);
}

sk_status sk_joint_statistics(double *expected_local, double *expected_gram, const double *local,
                              const int32_t *parents, size_t sample_count, size_t bone_count, sk_error *error)
{
    if (!expected_local || !expected_gram || !local || sample_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "joint statistics need at least one sample");
    sk_status status = sk_validate_skeleton(parents, NULL, bone_count, error);
    if (status != SK_OK)
        return status;
    size_t values;
    if ((status = sk_array_size(&values, sample_count, bone_count, 16, "sampled joint", error)) != SK_OK)
        return status;
    const size_t bad = sk_first_non_finite(local, values);
    if (bad < values)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "sample %zu, bone %zu: the joint matrix has a NaN or infinity",
                       bad / 16 / bone_count, bad / 16 % bone_count);
    size_t *order = sk_allocate(bone_count, sizeof *order);
    if (!order)
        return sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu bones", bone_count);
    status = parents_first_order(order, parents, bone_count, error);
    /*
     * The independent-joints model throughout: E[G_j^T G_j] = E[L_j^T E[G_p^T G_p] L_j], averaging over each
     * joint's own samples with its parent's expectation already formed. Averaging G_j^T G_j over whole
     * sampled poses instead would not match the cross blocks of the recursion, and the mixed P can be
     * indefinite (a moving vector would get a "mean distance" of 0).
     */
    for (size_t i = 0; status == SK_OK && i < bone_count; ++i) {
        const size_t bone = order[i];
        double *mean = expected_local + 16 * bone, *gram = expected_gram + 16 * bone;
        if (bone == 0) {
            identity4(mean);
            identity4(gram);
            continue;
        }
        memset(mean, 0, 16 * sizeof *mean);
        memset(gram, 0, 16 * sizeof *gram);
        const double *parent_gram = expected_gram + 16 * (size_t)parents[bone];
        for (size_t sample = 0; sample < sample_count; ++sample) {
            const double *joint = local + 16 * (bone_count * sample + bone);
            for (int e = 0; e < 16; ++e)
                mean[e] += joint[e];
            add_congruence4(gram, joint, parent_gram);
        }
        for (int e = 0; e < 16; ++e) {
            mean[e] /= (double)sample_count;
            gram[e] /= (double)sample_count;
        }
    }
    free(order);
    return status == SK_OK ? sk_succeed(error) : status;
}

/* prod E[L] along the path from `ancestor` (exclusive) down to `bone` (inclusive), parent first. */
static void path_product(double *product, const double *expected_local, const int32_t *parents, size_t ancestor,
                         size_t bone)
{
    identity4(product);
    for (size_t node = bone; node != ancestor; node = (size_t)parents[node])
        sk_multiply4(product, expected_local + 16 * node, product);
}

static size_t lowest_common_ancestor(const int32_t *parents, size_t j, size_t k)
{
    size_t depth_j = depth_of(parents, j), depth_k = depth_of(parents, k);
    for (; depth_j > depth_k; --depth_j)
        j = (size_t)parents[j];
    for (; depth_k > depth_j; --depth_k)
        k = (size_t)parents[k];
    while (j != k) {
        j = (size_t)parents[j];
        k = (size_t)parents[k];
    }
    return j;
}

/* The block without argument checks (the callers have made them). */
static void expectation_block(double *block, const double *expected_local, const double *expected_gram,
                              const int32_t *parents, size_t j, size_t k)
{
    const size_t ancestor = lowest_common_ancestor(parents, j, k);
    double to_j[16], to_k[16], right[16];
    path_product(to_j, expected_local, parents, ancestor, j);
    path_product(to_k, expected_local, parents, ancestor, k);
    sk_multiply4(right, expected_gram + 16 * ancestor, to_k);
    memset(block, 0, 16 * sizeof *block);
    add_transposed_product4(block, to_j, right);
}

static sk_status check_statistics(const double *expected_local, const double *expected_gram, const int32_t *parents,
                                  size_t bone_count, sk_error *error)
{
    if (!expected_local || !expected_gram)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the joint statistics must not be null");
    sk_status status = sk_validate_skeleton(parents, NULL, bone_count, error);
    if (status == SK_OK && (!sk_all_finite(expected_local, 16 * bone_count) ||
                            !sk_all_finite(expected_gram, 16 * bone_count)))
        status = sk_fail(error, SK_ERROR_NOT_FINITE, "the joint statistics have a NaN or infinity");
    return status;
}

sk_status sk_expectation_block(double *block, const double *expected_local, const double *expected_gram,
                               const int32_t *parents, size_t bone_count, size_t j, size_t k, sk_error *error)
{
    if (!block)
        return sk_fail(error, SK_ERROR_ARGUMENT, "block must not be null");
    if (j >= bone_count || k >= bone_count)
        return sk_fail(error, SK_ERROR_INDEX, "block (%zu, %zu) is outside %zu bones", j, k, bone_count);
    const sk_status status = check_statistics(expected_local, expected_gram, parents, bone_count, error);
    if (status != SK_OK)
        return status;
    expectation_block(block, expected_local, expected_gram, parents, j, k);
    return sk_succeed(error);
}

sk_status sk_expectation_blocks(double *blocks, const double *expected_local, const double *expected_gram,
                                const int32_t *parents, size_t bone_count, sk_error *error)
{
    if (!blocks)
        return sk_fail(error, SK_ERROR_ARGUMENT, "blocks must not be null");
    const sk_status status = check_statistics(expected_local, expected_gram, parents, bone_count, error);
    if (status != SK_OK)
        return status;
    for (size_t j = 0; j < bone_count; ++j)
        for (size_t k = j; k < bone_count; ++k) {
            double *block = blocks + 16 * (j * bone_count + k), *mirror = blocks + 16 * (k * bone_count + j);
            expectation_block(block, expected_local, expected_gram, parents, j, k);
            for (int r = 0; r < 4 && k != j; ++r) /* P_kj = P_jk^T (a diagonal block is its own) */
                for (int c = 0; c < 4; ++c)
                    mirror[4 * c + r] = block[4 * r + c];
        }
    return sk_succeed(error);
}

sk_status sk_linear_norms(double *destination, const double *matrices, size_t matrix_count, sk_error *error)
{
    if (!destination || (!matrices && matrix_count))
        return sk_fail(error, SK_ERROR_ARGUMENT, "destination and matrices must not be null");
    const size_t bad = sk_first_non_finite(matrices, 16 * matrix_count);
    if (bad < 16 * matrix_count)
        return sk_fail(error, SK_ERROR_NOT_FINITE, "matrix %zu has a NaN or infinity", bad / 16);
    for (size_t i = 0; i < matrix_count; ++i) {
        const double *m = matrices + 16 * i;
        double gram[9]; /* A^T A of the linear part */
        for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c)
                gram[3 * r + c] = m[r] * m[c] + m[4 + r] * m[4 + c] + m[8 + r] * m[8 + c];
        destination[i] = sqrt(fmax(sk_largest_symmetric_eigenvalue3(gram), 0.0));
    }
    return sk_succeed(error);
}

static sk_status check_vectors(const sk_influences *influences, const double *vectors, size_t bone_count,
                               sk_error *error)
{
    if (!influences || (!vectors && influences->influence_count > 0))
        return sk_fail(error, SK_ERROR_ARGUMENT, "vectors must not be null");
    const size_t influence_count = influences->influence_count;
    sk_status status = sk_validate_influences(influences, bone_count, error);
    const size_t bad = status == SK_OK ? sk_first_non_finite(vectors, 4 * influence_count) : 0;
    if (status == SK_OK && bad < 4 * influence_count)
        status = sk_fail(error, SK_ERROR_NOT_FINITE, "influence %zu of the vectors has a NaN or infinity", bad / 4);
    return status;
}

typedef struct distance_task {
    const int32_t *offsets, *bones;
    const double *vectors, *blocks;
    size_t bone_count;
    double *destination;
} distance_task;

static void mean_distance_range(void *context, size_t worker, size_t begin, size_t end)
{
    (void)worker;
    const distance_task *task = context;
    for (size_t i = begin; i < end; ++i) {
        double sum = 0.0;
        for (int32_t a = task->offsets[i]; a < task->offsets[i + 1]; ++a)
            for (int32_t b = task->offsets[i]; b < task->offsets[i + 1]; ++b) {
                const double *block =
                    task->blocks + 16 * ((size_t)task->bones[a] * task->bone_count + (size_t)task->bones[b]);
                const double *s = task->vectors + 4 * (size_t)a, *t = task->vectors + 4 * (size_t)b;
                for (int r = 0; r < 4; ++r)
                    sum += s[r] * (block[4 * r] * t[0] + block[4 * r + 1] * t[1] + block[4 * r + 2] * t[2] +
                                   block[4 * r + 3] * t[3]);
            }
        task->destination[i] = sqrt(sum > 0.0 ? sum : 0.0); /* P is semi-definite: rounding may dip below 0 */
    }
}

sk_status sk_mean_distances(double *destination, const sk_influences *influences, const double *vectors,
                            const double *expected_local, const double *expected_gram, const int32_t *parents,
                            size_t bone_count, double *block_cache, unsigned char *cached, int thread_count,
                            sk_error *error)
{
    if (!destination || !block_cache || !cached)
        return sk_fail(error, SK_ERROR_ARGUMENT, "destination and the block cache must not be null");
    size_t cache_size;
    sk_status status = sk_array_size(&cache_size, bone_count, bone_count, 16, "block cache", error);
    if (status == SK_OK)
        status = check_statistics(expected_local, expected_gram, parents, bone_count, error);
    if (status == SK_OK)
        status = check_vectors(influences, vectors, bone_count, error);
    if (status != SK_OK)
        return status;
    const int32_t *offsets = influences->offsets, *bones = influences->bones;
    const size_t vector_count = influences->vertex_count;
    /* Form the blocks these vectors need first (serially, so the cache is never written concurrently). */
    for (size_t i = 0; i < vector_count; ++i)
        for (int32_t a = offsets[i]; a < offsets[i + 1]; ++a)
            for (int32_t b = offsets[i]; b < offsets[i + 1]; ++b) {
                const size_t pair = (size_t)bones[a] * bone_count + (size_t)bones[b];
                if (!cached[pair]) {
                    expectation_block(block_cache + 16 * pair, expected_local, expected_gram, parents,
                                      (size_t)bones[a], (size_t)bones[b]);
                    cached[pair] = 1;
                }
            }
    distance_task task = {offsets, bones, vectors, block_cache, bone_count, destination};
    sk_parallel_for(vector_count, SK_SOLVE_ITEMS_PER_WORKER * 64, thread_count, mean_distance_range, &task);
    return sk_succeed(error);
}

typedef struct bound_task {
    const int32_t *offsets, *bones, *parents;
    const double *vectors, *linear_bound, *centre, *radius;
    const size_t *deepest_first; /* every bone, children before parents */
    size_t bone_count;
    double *destination;
    double *volumes;         /* per worker: 5 per bone, the sphere S_w(v, r) as (w, v, r) */
    size_t *touched;         /* per worker: the bones a vector reaches */
    unsigned char *marked;   /* per worker: a flag per bone, all zero between vectors */
} bound_task;

/* Pushes the volume S_w(v, r) of `bone` through its joint into its parent (eq. 3.27-3.28). */
static void propagate(double *volume, const bound_task *task, size_t bone)
{
    double *own = volume + 5 * bone, *parent = volume + 5 * (size_t)task->parents[bone];
    const double w = own[0], s = task->linear_bound[bone], *c = task->centre + 3 * bone;
    const double length = sqrt(own[1] * own[1] + own[2] * own[2] + own[3] * own[3]);
    parent[0] += w;
    for (int axis = 0; axis < 3; ++axis)
        parent[1 + axis] += w * c[axis];
    parent[4] += s * length + s * own[4] + fabs(w) * task->radius[bone];
}

static void max_distance_range(void *context, size_t worker, size_t begin, size_t end)
{
    const bound_task *task = context;
    const size_t b = task->bone_count;
    double *volume = task->volumes + worker * 5 * b;
    size_t *touched = task->touched + worker * b;
    unsigned char *marked = task->marked + worker * b;
    for (size_t i = begin; i < end; ++i) {
        /* The root's volume holds the result: start it empty even for a vector without influences. */
        size_t count = 1;
        marked[0] = 1;
        touched[0] = 0;
        memset(volume, 0, 5 * sizeof *volume);
        for (int32_t a = task->offsets[i]; a < task->offsets[i + 1]; ++a)
            for (size_t bone = (size_t)task->bones[a]; !marked[bone]; bone = (size_t)task->parents[bone]) {
                marked[bone] = 1; /* the walk stops at the first bone already reached (at the latest the root) */
                touched[count++] = bone;
                memset(volume + 5 * bone, 0, 5 * sizeof *volume);
            }
        for (int32_t a = task->offsets[i]; a < task->offsets[i + 1]; ++a)
            for (int c = 0; c < 4; ++c)
                volume[5 * (size_t)task->bones[a] + (c == 3 ? 0 : 1 + (size_t)c)] += task->vectors[4 * (size_t)a + (size_t)c];
        /* Children before parents, so each volume is complete before it moves up; one pass over the
         * precomputed order costs O(bones), where sorting the reached bones cost O(reached^2). */
        for (size_t x = 0; x < b; ++x) {
            const size_t bone = task->deepest_first[x];
            if (bone != 0 && marked[bone])
                propagate(volume, task, bone);
        }
        const double *root = volume;
        task->destination[i] = sqrt(root[1] * root[1] + root[2] * root[2] + root[3] * root[3]) + root[4];
        for (size_t x = 0; x < count; ++x)
            marked[touched[x]] = 0;
    }
}

sk_status sk_max_distances(double *destination, const sk_influences *influences, const double *vectors,
                           const int32_t *parents, const double *linear_bound, const double *translation_centre,
                           const double *translation_radius, size_t bone_count, int thread_count, sk_error *error)
{
    if (!destination || !linear_bound || !translation_centre || !translation_radius)
        return sk_fail(error, SK_ERROR_ARGUMENT, "destination and the joint bounds must not be null");
    sk_status status = sk_validate_skeleton(parents, NULL, bone_count, error);
    if (status == SK_OK)
        status = check_vectors(influences, vectors, bone_count, error);
    if (status != SK_OK)
        return status;
    const size_t vector_count = influences->vertex_count;
    for (size_t bone = 0; bone < bone_count; ++bone)
        if (!(linear_bound[bone] >= 0.0) || !(translation_radius[bone] >= 0.0) || !isfinite(linear_bound[bone]) ||
            !isfinite(translation_radius[bone]) || !sk_all_finite(translation_centre + 3 * bone, 3))
            return sk_fail(error, SK_ERROR_ARGUMENT, "bone %zu: its bounds must be finite and >= 0", bone);
    const size_t workers = sk_worker_count(vector_count, SK_SOLVE_ITEMS_PER_WORKER * 64, thread_count);
    size_t *order = sk_allocate(bone_count, sizeof *order);
    size_t scratch; /* per-bone entries for every worker; saturates, so the allocations fail on overflow */
    sk_mul_size(workers, bone_count, &scratch);
    bound_task task = {influences->offsets, influences->bones, parents, vectors, linear_bound, translation_centre,
                       translation_radius, order, bone_count, destination, sk_allocate(scratch, 5 * sizeof(double)),
                       sk_allocate(scratch, sizeof(size_t)), sk_allocate_zeroed(scratch, 1)};
    if (order && task.volumes && task.touched && task.marked &&
        parents_first_order(order, parents, bone_count, error) == SK_OK) {
        for (size_t x = 0; x < bone_count / 2; ++x) { /* reverse: deepest first */
            const size_t swap = order[x];
            order[x] = order[bone_count - 1 - x];
            order[bone_count - 1 - x] = swap;
        }
        sk_parallel_for(vector_count, SK_SOLVE_ITEMS_PER_WORKER * 64, thread_count, max_distance_range, &task);
        status = sk_succeed(error);
    } else {
        status = sk_fail(error, SK_ERROR_MEMORY, "out of memory for %zu bones", bone_count);
    }
    free(order), free(task.volumes), free(task.touched), free(task.marked);
    return status;
}
