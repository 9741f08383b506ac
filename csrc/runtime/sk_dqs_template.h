/*
 * Dual-quaternion skinning kernel, written once and instantiated for double and float by
 * sk_dual_quaternion.c, which defines SK_REAL, SK_NAME(x) and SK_ALL_FINITE (as sk_evaluate_template.h) and
 * SK_FIRST_NON_FINITE (the index of the first NaN or infinity, for the messages).
 * Indices are range-checked as they are read; a vertex with a bad index is reported through first_bad.
 */

typedef struct SK_NAME(dqs_task) {
    SK_REAL *destination;
    const int32_t *offsets, *bones;
    const SK_REAL *vectors, *weights, *dual_quaternions;
    SK_REAL homogeneous;
    size_t influence_count, bone_count;
    size_t first_bad[SK_MAX_WORKERS];
} SK_NAME(dqs_task);

/* Blends a vertex's dual quaternions into b[8] (signs against the running sum); 0 when an index is bad. */
static int SK_NAME(blend_vertex)(SK_REAL b[8], const SK_NAME(dqs_task) *task, size_t vertex)
{
    const int32_t begin = task->offsets[vertex], end = task->offsets[vertex + 1];
    if (begin < 0 || end < begin || (size_t)end > task->influence_count)
        return 0;
    for (int c = 0; c < 8; ++c)
        b[c] = 0;
    for (int32_t k = begin; k < end; ++k) {
        if (task->bones[k] < 0 || (size_t)task->bones[k] >= task->bone_count)
            return 0;
        const SK_REAL *q = task->dual_quaternions + 8 * (size_t)task->bones[k];
        SK_REAL w = task->weights[k];
        if (b[0] * q[0] + b[1] * q[1] + b[2] * q[2] + b[3] * q[3] < 0)
            w = -w;
        for (int c = 0; c < 8; ++c)
            b[c] += w * q[c];
    }
    return 1;
}

/* Applies the normalised form of b to v (point when h != 0): R v + h t with t = 2 qe conj(q0) / |q0|^2. */
static void SK_NAME(apply_blend)(SK_REAL out[3], const SK_REAL b[8], const SK_REAL v[3], SK_REAL h)
{
    const SK_REAL norm2 = b[0] * b[0] + b[1] * b[1] + b[2] * b[2] + b[3] * b[3];
    if (!(norm2 > (SK_REAL)1e-30)) { /* the influences cancel: keep the rest vector */
        out[0] = v[0], out[1] = v[1], out[2] = v[2];
        return;
    }
    const SK_REAL w = b[0], x = b[1], y = b[2], z = b[3];
    const SK_REAL ew = b[4], ex = b[5], ey = b[6], ez = b[7];
    /* Rotation of the unnormalised quaternion, divided by its squared norm. */
    const SK_REAL s = 2 / norm2;
    const SK_REAL r00 = 1 - s * (y * y + z * z), r01 = s * (x * y - w * z), r02 = s * (x * z + w * y);
    const SK_REAL r10 = s * (x * y + w * z), r11 = 1 - s * (x * x + z * z), r12 = s * (y * z - w * x);
    const SK_REAL r20 = s * (x * z - w * y), r21 = s * (y * z + w * x), r22 = 1 - s * (x * x + y * y);
    /* t = 2 (w qe_v - ew q_v + q_v x qe_v) / |q0|^2: the vector part of 2 qe conj(q0). */
    const SK_REAL tx = s * (w * ex - ew * x + y * ez - z * ey);
    const SK_REAL ty = s * (w * ey - ew * y + z * ex - x * ez);
    const SK_REAL tz = s * (w * ez - ew * z + x * ey - y * ex);
    out[0] = r00 * v[0] + r01 * v[1] + r02 * v[2] + h * tx;
    out[1] = r10 * v[0] + r11 * v[1] + r12 * v[2] + h * ty;
    out[2] = r20 * v[0] + r21 * v[1] + r22 * v[2] + h * tz;
}

static void SK_NAME(dqs_range)(void *context, size_t worker, size_t begin, size_t end)
{
    SK_NAME(dqs_task) *task = context;
    for (size_t vertex = begin; vertex < end; ++vertex) {
        SK_REAL blend[8];
        SK_REAL *out = task->destination + 3 * vertex;
        const SK_REAL *v = task->vectors + 3 * vertex;
        if (!SK_NAME(blend_vertex)(blend, task, vertex)) {
            if (task->first_bad[worker] > vertex)
                task->first_bad[worker] = vertex;
            out[0] = v[0], out[1] = v[1], out[2] = v[2];
            continue;
        }
        SK_NAME(apply_blend)(out, blend, v, task->homogeneous);
    }
}

sk_status SK_NAME(sk_dqs_evaluate)(SK_REAL *destination, const sk_influences *influences, const SK_REAL *vectors,
                                   SK_REAL homogeneous, const SK_REAL *weights, const SK_REAL *dual_quaternions,
                                   size_t bone_count, int thread_count, sk_error *error)
{
    if (!destination || !influences || !dual_quaternions || !influences->offsets ||
        (influences->influence_count && (!weights || !influences->bones)) || (influences->vertex_count && !vectors))
        return sk_fail(error, SK_ERROR_ARGUMENT, "dual-quaternion skinning arrays must not be null");
    if (bone_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "dual-quaternion skinning needs at least one bone");
    size_t values;
    const sk_status sized = sk_array_size(&values, bone_count, 8, 1, "dual quaternion", error);
    if (sized != SK_OK)
        return sized;
    if (!SK_ALL_FINITE(dual_quaternions, values))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "bone %zu's dual quaternion has a NaN or infinity",
                       SK_FIRST_NON_FINITE(dual_quaternions, values) / 8);
    const size_t vertex_count = influences->vertex_count;
    if (influences->offsets[0] != 0 || influences->offsets[vertex_count] < 0 ||
        (size_t)influences->offsets[vertex_count] != influences->influence_count)
        return sk_validate_influences(influences, bone_count, error);
    SK_NAME(dqs_task) task = {.destination = destination, .offsets = influences->offsets, .bones = influences->bones,
                              .vectors = vectors, .weights = weights, .dual_quaternions = dual_quaternions,
                              .homogeneous = homogeneous, .influence_count = influences->influence_count,
                              .bone_count = bone_count};
    for (size_t w = 0; w < SK_MAX_WORKERS; ++w)
        task.first_bad[w] = SIZE_MAX;
    sk_parallel_for(vertex_count, SK_EVALUATION_ITEMS_PER_WORKER, thread_count, SK_NAME(dqs_range), &task);
    for (size_t w = 0; w < SK_MAX_WORKERS; ++w)
        if (task.first_bad[w] != SIZE_MAX)
            return sk_validate_influences(influences, bone_count, error);
    return sk_succeed(error);
}
