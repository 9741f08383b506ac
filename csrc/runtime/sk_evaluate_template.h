/*
 * Evaluation kernels, written once and instantiated for double and float by sk_skinning.c, which
 * defines SK_REAL (the scalar type), SK_NAME(x) (appends the precision suffix) and SK_ALL_FINITE.
 *
 * The kernels range-check every CSR offset and bone index as they read it (a fused check costs a
 * predictable branch, a separate validation pass would cost a second sweep over memory); a vertex
 * with a bad index is skipped and reported through first_bad[worker], and the caller then names it.
 */

typedef struct SK_NAME(evaluation) {
    SK_REAL *destination;
    const sk_influences *influences;
    const int32_t *offsets, *bones;
    const SK_REAL *coordinates; /* animation space: 4 per influence */
    const SK_REAL *vectors;     /* linear blend: 3 per vertex */
    const SK_REAL *weights;     /* linear blend: 1 per influence */
    SK_REAL homogeneous;
    const SK_REAL *matrices;    /* bone_count row-major 4x4 */
    size_t influence_count, bone_count;
    size_t first_bad[SK_MAX_WORKERS];
} SK_NAME(evaluation);

static int SK_NAME(influence_range_ok)(const SK_NAME(evaluation) *task, size_t vertex)
{
    const int32_t begin = task->offsets[vertex], end = task->offsets[vertex + 1];
    if (begin < 0 || end < begin || (size_t)end > task->influence_count)
        return 0;
    for (int32_t k = begin; k < end; ++k)
        if (task->bones[k] < 0 || (size_t)task->bones[k] >= task->bone_count)
            return 0;
    return 1;
}

static void SK_NAME(note_bad_vertex)(SK_NAME(evaluation) *task, size_t worker, size_t vertex)
{
    if (task->first_bad[worker] > vertex)
        task->first_bad[worker] = vertex;
}

static void SK_NAME(animation_space_range)(void *context, size_t worker, size_t begin, size_t end)
{
    SK_NAME(evaluation) *task = context;
    for (size_t vertex = begin; vertex < end; ++vertex) {
        SK_REAL x = 0, y = 0, z = 0;
        if (!SK_NAME(influence_range_ok)(task, vertex)) {
            SK_NAME(note_bad_vertex)(task, worker, vertex);
        } else {
            for (int32_t k = task->offsets[vertex]; k < task->offsets[vertex + 1]; ++k) {
                const SK_REAL *m = task->matrices + 16 * (size_t)task->bones[k];
                const SK_REAL *p = task->coordinates + 4 * (size_t)k;
                x += m[0] * p[0] + m[1] * p[1] + m[2] * p[2] + m[3] * p[3];
                y += m[4] * p[0] + m[5] * p[1] + m[6] * p[2] + m[7] * p[3];
                z += m[8] * p[0] + m[9] * p[1] + m[10] * p[2] + m[11] * p[3];
            }
        }
        task->destination[3 * vertex] = x;
        task->destination[3 * vertex + 1] = y;
        task->destination[3 * vertex + 2] = z;
    }
}

static void SK_NAME(linear_blend_range)(void *context, size_t worker, size_t begin, size_t end)
{
    SK_NAME(evaluation) *task = context;
    const SK_REAL h = task->homogeneous;
    for (size_t vertex = begin; vertex < end; ++vertex) {
        SK_REAL x = 0, y = 0, z = 0;
        const SK_REAL *v = task->vectors + 3 * vertex;
        if (!SK_NAME(influence_range_ok)(task, vertex)) {
            SK_NAME(note_bad_vertex)(task, worker, vertex);
        } else {
            for (int32_t k = task->offsets[vertex]; k < task->offsets[vertex + 1]; ++k) {
                const SK_REAL *m = task->matrices + 16 * (size_t)task->bones[k];
                const SK_REAL w = task->weights[k];
                x += w * (m[0] * v[0] + m[1] * v[1] + m[2] * v[2] + m[3] * h);
                y += w * (m[4] * v[0] + m[5] * v[1] + m[6] * v[2] + m[7] * h);
                z += w * (m[8] * v[0] + m[9] * v[1] + m[10] * v[2] + m[11] * h);
            }
        }
        task->destination[3 * vertex] = x;
        task->destination[3 * vertex + 1] = y;
        task->destination[3 * vertex + 2] = z;
    }
}

static sk_status SK_NAME(run)(SK_NAME(evaluation) *task, sk_range_body body, int thread_count, sk_error *error)
{
    if (!task->influences)
        return sk_fail(error, SK_ERROR_ARGUMENT, "evaluation arrays must not be null");
    const size_t vertex_count = task->influences->vertex_count;
    task->offsets = task->influences->offsets;
    task->bones = task->influences->bones;
    task->influence_count = task->influences->influence_count;
    if (!task->destination || !task->offsets || !task->matrices || (!task->bones && task->influence_count))
        return sk_fail(error, SK_ERROR_ARGUMENT, "evaluation arrays must not be null");
    if (task->bone_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "evaluation needs at least one bone");
    size_t matrix_values;
    const sk_status sized = sk_array_size(&matrix_values, task->bone_count, 16, 1, "pose", error);
    if (sized != SK_OK)
        return sized;
    if (!SK_ALL_FINITE(task->matrices, matrix_values))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "a pose matrix has a NaN or infinity");
    /* The kernels check each vertex's own range; the two ends of the CSR pattern are checked here,
     * once, so that evaluation rejects exactly what sk_validate_influences rejects. */
    if (task->offsets[0] != 0 || task->offsets[vertex_count] < 0 ||
        (size_t)task->offsets[vertex_count] != task->influence_count)
        return sk_validate_influences(task->influences, task->bone_count, error);
    for (size_t w = 0; w < sizeof task->first_bad / sizeof task->first_bad[0]; ++w)
        task->first_bad[w] = SIZE_MAX;
    sk_parallel_for(vertex_count, SK_EVALUATION_ITEMS_PER_WORKER, thread_count, body, task);
    for (size_t w = 0; w < sk_worker_count(vertex_count, SK_EVALUATION_ITEMS_PER_WORKER, thread_count); ++w)
        if (task->first_bad[w] != SIZE_MAX)
            return sk_validate_influences(task->influences, task->bone_count, error);
    return sk_succeed(error);
}

sk_status SK_NAME(sk_animation_space_evaluate)(SK_REAL *destination, const sk_influences *influences,
                                               const SK_REAL *coordinates, const SK_REAL *poses, size_t bone_count,
                                               int thread_count, sk_error *error)
{
    if (!coordinates && influences && influences->influence_count)
        return sk_fail(error, SK_ERROR_ARGUMENT, "coordinates must not be null");
    SK_NAME(evaluation) task = {.destination = destination, .influences = influences, .coordinates = coordinates,
                                .matrices = poses, .bone_count = bone_count};
    return SK_NAME(run)(&task, SK_NAME(animation_space_range), thread_count, error);
}

sk_status SK_NAME(sk_lbs_evaluate)(SK_REAL *destination, const sk_influences *influences, const SK_REAL *vectors,
                                   SK_REAL homogeneous, const SK_REAL *weights, const SK_REAL *skinning_matrices,
                                   size_t bone_count, int thread_count, sk_error *error)
{
    if (influences && ((!weights && influences->influence_count) || (!vectors && influences->vertex_count)))
        return sk_fail(error, SK_ERROR_ARGUMENT, "weights and vectors must not be null");
    SK_NAME(evaluation) task = {.destination = destination, .influences = influences, .vectors = vectors,
                                .weights = weights, .homogeneous = homogeneous, .matrices = skinning_matrices,
                                .bone_count = bone_count};
    return SK_NAME(run)(&task, SK_NAME(linear_blend_range), thread_count, error);
}
