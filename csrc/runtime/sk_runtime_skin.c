/* Batched geomorphing skinning: validation of the pack and the instances (per call, O(instances + meshes)), then
 * one parallel loop over every instance's output vertices, so a crowd of small characters fills every thread. */
#include <math.h>

#include "sk_internal.h"
#include "sk_runtime_internal.h"

typedef struct skin_task {
    float *outputs[3];              /* positions, tangent_0, tangent_1 (NULL: not wanted) */
    const float *streams[3];        /* their (p, dp) data in the pack */
    const sk_runtime_pack *pack;
    const sk_runtime_instances *instances;
    sk_morph_kernel kernel;
    size_t first_bad[SK_MAX_WORKERS]; /* pack vertex */
    size_t bad_instance[SK_MAX_WORKERS];
} skin_task;

sk_status sk_runtime_kernel_supported(size_t *supported, int kernel, sk_error *error)
{
    if (!supported)
        return sk_fail(error, SK_ERROR_ARGUMENT, "supported must not be null");
    if (kernel < SK_RUNTIME_KERNEL_AUTO || kernel > SK_RUNTIME_KERNEL_AVX2)
        return sk_fail(error, SK_ERROR_ARGUMENT, "kernel %d is not a kernel (0 auto, 1 scalar, 2 SSE2, 3 AVX2)", kernel);
    *supported = sk_morph_kernel_for(kernel) != NULL;
    return sk_succeed(error);
}

/* The last instance whose output range starts at or before `output` (output_starts is non-decreasing). */
static size_t instance_at(const int32_t *output_starts, size_t instance_count, size_t output)
{
    size_t low = 0, high = instance_count; /* output_starts[low] <= output < output_starts[high] */
    while (high - low > 1) {
        const size_t middle = low + (high - low) / 2;
        if ((size_t)output_starts[middle] <= output)
            low = middle;
        else
            high = middle;
    }
    return low;
}

static void skin_range(void *context, size_t worker, size_t begin, size_t end)
{
    skin_task *task = context;
    const sk_runtime_instances *in = task->instances;
    const sk_runtime_pack *pack = task->pack;
    for (size_t i = instance_at(in->output_starts, in->instance_count, begin); begin < end; ++i) {
        const size_t first = (size_t)in->output_starts[i], last = (size_t)in->output_starts[i + 1];
        const size_t stop = last < end ? last : end;
        if (stop <= begin)
            continue; /* an instance of an empty mesh */
        const size_t mesh_start = (size_t)pack->mesh_starts[in->meshes[i]];
        sk_morph_range range = {.offsets = pack->influences.offsets, .bones = pack->influences.bones,
                                .matrices = in->matrices + 12 * in->bone_count * i,
                                .influence_count = pack->influences.influence_count, .bone_count = in->bone_count,
                                .begin = mesh_start + (begin - first), .end = mesh_start + (stop - first),
                                .fraction = in->fractions[i]};
        for (int s = 0; s < 3; ++s) {
            if (!task->outputs[s])
                continue;
            range.destination = task->outputs[s] + 3 * begin;
            range.morph = task->streams[s];
            range.morph_stride = s == 0 ? 8 : 16;
            const size_t bad = task->kernel(&range);
            if (bad < task->first_bad[worker]) {
                task->first_bad[worker] = bad;
                task->bad_instance[worker] = i;
            }
        }
        begin = stop;
    }
}

static sk_status check_pack(const sk_runtime_pack *pack, int want_tangents, sk_error *error)
{
    const sk_influences *inf = &pack->influences;
    if (!inf->offsets || (!inf->bones && inf->influence_count) || (!pack->positions && inf->influence_count) ||
        !pack->mesh_starts)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the pack's arrays must not be null");
    if (want_tangents && !pack->tangents && inf->influence_count)
        return sk_fail(error, SK_ERROR_ARGUMENT, "tangent outputs need the pack's tangents");
    if (inf->influence_count > INT32_MAX || inf->vertex_count > INT32_MAX)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the pack is too big for int32 offsets");
    if (inf->offsets[0] != 0 || inf->offsets[inf->vertex_count] != (int32_t)inf->influence_count)
        return sk_fail(error, SK_ERROR_INDEX, "the pack's offsets must run from 0 to influence_count %zu",
                       inf->influence_count);
    if (pack->mesh_starts[0] != 0 || pack->mesh_starts[pack->mesh_count] != (int32_t)inf->vertex_count)
        return sk_fail(error, SK_ERROR_INDEX, "mesh_starts must run from 0 to vertex_count %zu", inf->vertex_count);
    for (size_t m = 0; m < pack->mesh_count; ++m)
        if (pack->mesh_starts[m + 1] < pack->mesh_starts[m])
            return sk_fail(error, SK_ERROR_INDEX, "mesh %zu ends (%d) before it starts (%d)", m,
                           (int)pack->mesh_starts[m + 1], (int)pack->mesh_starts[m]);
    return SK_OK;
}

static sk_status check_instances(const sk_runtime_instances *in, const int32_t *mesh_starts, size_t mesh_count,
                                 size_t output_vertex_count, sk_error *error)
{
    if (!in->output_starts || (in->instance_count && (!in->meshes || !in->fractions || !in->matrices)))
        return sk_fail(error, SK_ERROR_ARGUMENT, "the instances' arrays must not be null");
    if (in->bone_count == 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "instances need at least one bone");
    size_t matrix_values;
    sk_status status = sk_array_size(&matrix_values, in->instance_count, in->bone_count, 12, "matrices", error);
    if (status != SK_OK)
        return status;
    if (in->output_starts[0] != 0)
        return sk_fail(error, SK_ERROR_INDEX, "output_starts[0] is %d, not 0", (int)in->output_starts[0]);
    for (size_t i = 0; i < in->instance_count; ++i) {
        const int32_t mesh = in->meshes[i];
        if (mesh < 0 || (size_t)mesh >= mesh_count)
            return sk_fail(error, SK_ERROR_INDEX, "instance %zu draws mesh %d of %zu", i, (int)mesh, mesh_count);
        const int64_t length = (int64_t)in->output_starts[i + 1] - in->output_starts[i];
        if (length != (int64_t)mesh_starts[mesh + 1] - mesh_starts[mesh])
            return sk_fail(error, SK_ERROR_INDEX, "instance %zu has %lld output vertices for mesh %d of %d", i,
                           (long long)length, (int)mesh, (int)(mesh_starts[mesh + 1] - mesh_starts[mesh]));
        if (!(in->fractions[i] >= 0.0f && in->fractions[i] <= 1.0f))
            return sk_fail(error, SK_ERROR_ARGUMENT, "instance %zu's fraction %g is not in [0, 1]", i,
                           (double)in->fractions[i]);
    }
    if ((size_t)in->output_starts[in->instance_count] != output_vertex_count)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the instances write %d vertices, the outputs hold %zu",
                       (int)in->output_starts[in->instance_count], output_vertex_count);
    if (!sk_all_finite_f32(in->matrices, matrix_values))
        return sk_fail(error, SK_ERROR_NOT_FINITE, "a bone matrix has a NaN or infinity");
    return SK_OK;
}

/* Names the first bad vertex the workers found (what: "an influence range or bone index", "a bone index"). */
static sk_status name_bad_vertex(const size_t *first_bad, const size_t *bad_instance, size_t workers,
                                 const char *what, size_t bone_count, sk_error *error)
{
    size_t bad = SIZE_MAX, instance = 0;
    for (size_t w = 0; w < workers; ++w)
        if (first_bad[w] < bad) {
            bad = first_bad[w];
            instance = bad_instance[w];
        }
    if (bad == SIZE_MAX)
        return sk_succeed(error);
    return sk_fail(error, SK_ERROR_INDEX, "pack vertex %zu (instance %zu) has %s out of range (%zu bones)", bad,
                   instance, what, bone_count);
}

/* The argument prologue both layouts share: the outputs, the pack and the instances given, tangent outputs in pairs,
 * and the kernel asked for found (kernel_found: the layout's own kernel table answered). */
static sk_status check_skin_call(const float *positions, const float *tangent_0, const float *tangent_1,
                                 const void *pack, const sk_runtime_instances *instances, int kernel_found,
                                 int kernel, sk_error *error)
{
    if (!positions || !pack || !instances)
        return sk_fail(error, SK_ERROR_ARGUMENT, "positions, pack and instances must not be null");
    if (!tangent_0 != !tangent_1)
        return sk_fail(error, SK_ERROR_ARGUMENT, "tangent_0 and tangent_1 must be both given or both null");
    if (!kernel_found)
        return sk_fail(error, SK_ERROR_ARGUMENT, "kernel %d is not available on this CPU or build", kernel);
    return SK_OK;
}

sk_status sk_runtime_skin(float *positions, float *tangent_0, float *tangent_1, size_t output_vertex_count,
                          const sk_runtime_pack *pack, const sk_runtime_instances *instances, int kernel,
                          int thread_count, sk_error *error)
{
    const sk_morph_kernel chosen = sk_morph_kernel_for(kernel);
    sk_status status = check_skin_call(positions, tangent_0, tangent_1, pack, instances, chosen != NULL, kernel, error);
    if (status == SK_OK)
        status = check_pack(pack, tangent_0 != NULL, error);
    if (status == SK_OK)
        status = check_instances(instances, pack->mesh_starts, pack->mesh_count, output_vertex_count, error);
    if (status != SK_OK)
        return status;
    skin_task task = {.outputs = {positions, tangent_0, tangent_1},
                      .streams = {pack->positions, pack->tangents, pack->tangents ? pack->tangents + 8 : NULL},
                      .pack = pack, .instances = instances, .kernel = chosen};
    for (size_t w = 0; w < SK_MAX_WORKERS; ++w)
        task.first_bad[w] = SIZE_MAX;
    sk_parallel_for(output_vertex_count, SK_EVALUATION_ITEMS_PER_WORKER, thread_count, skin_range, &task);
    return name_bad_vertex(task.first_bad, task.bad_instance,
                           sk_worker_count(output_vertex_count, SK_EVALUATION_ITEMS_PER_WORKER, thread_count),
                           "an influence range or bone index", instances->bone_count, error);
}

/* ---- The fixed-K layout ---------------------------------------------------------------------------------------- */

typedef struct fixed_task {
    float *outputs[3];              /* positions, tangent_0, tangent_1 (NULL: not wanted) */
    const float *streams[3];
    const sk_runtime_fixed_pack *pack;
    const sk_runtime_instances *instances;
    sk_fixed_kernel kernel;
    size_t first_bad[SK_MAX_WORKERS]; /* pack vertex */
    size_t bad_instance[SK_MAX_WORKERS];
} fixed_task;

static void fixed_range(void *context, size_t worker, size_t begin, size_t end)
{
    fixed_task *task = context;
    const sk_runtime_instances *in = task->instances;
    const sk_runtime_fixed_pack *pack = task->pack;
    for (size_t i = instance_at(in->output_starts, in->instance_count, begin); begin < end; ++i) {
        const size_t first = (size_t)in->output_starts[i], last = (size_t)in->output_starts[i + 1];
        const size_t stop = last < end ? last : end;
        if (stop <= begin)
            continue; /* an instance of an empty mesh */
        const size_t mesh_start = (size_t)pack->mesh_starts[in->meshes[i]];
        sk_fixed_range range = {.bones = pack->bones, .matrices = in->matrices + 12 * in->bone_count * i,
                                .bone_count = in->bone_count, .influences = pack->influences_per_vertex,
                                .begin = mesh_start + (begin - first), .end = mesh_start + (stop - first),
                                .fraction = in->fractions[i], .morphs = pack->floats_per_slot == 8};
        for (int s = 0; s < 3; ++s) {
            if (!task->outputs[s])
                continue;
            range.destination = task->outputs[s] + 3 * begin;
            range.data = task->streams[s];
            const size_t bad = task->kernel(&range);
            if (bad < task->first_bad[worker]) {
                task->first_bad[worker] = bad;
                task->bad_instance[worker] = i;
            }
        }
        begin = stop;
    }
}

static sk_status check_fixed_pack(const sk_runtime_fixed_pack *pack, int want_tangents, sk_error *error)
{
    if (!pack->mesh_starts)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the pack's mesh_starts must not be null");
    const size_t k = pack->influences_per_vertex;
    if (k < 2 || k > 64 || k % 2)
        return sk_fail(error, SK_ERROR_ARGUMENT, "influences_per_vertex %zu is not an even number in [2, 64]", k);
    if (pack->floats_per_slot != 4 && pack->floats_per_slot != 8)
        return sk_fail(error, SK_ERROR_ARGUMENT, "floats_per_slot is %zu, not 4 (p) or 8 (p and dp)",
                       pack->floats_per_slot);
    const size_t vertex_count = pack->vertex_count;
    if (pack->mesh_starts[0] != 0 || pack->mesh_starts[pack->mesh_count] < 0 ||
        (size_t)pack->mesh_starts[pack->mesh_count] != vertex_count)
        return sk_fail(error, SK_ERROR_INDEX, "mesh_starts must run from 0 to vertex_count %zu", vertex_count);
    for (size_t m = 0; m < pack->mesh_count; ++m)
        if (pack->mesh_starts[m + 1] < pack->mesh_starts[m])
            return sk_fail(error, SK_ERROR_INDEX, "mesh %zu ends (%d) before it starts (%d)", m,
                           (int)pack->mesh_starts[m + 1], (int)pack->mesh_starts[m]);
    size_t floats;
    sk_status status = sk_array_size(&floats, vertex_count, k, pack->floats_per_slot, "the pack's floats", error);
    if (status != SK_OK)
        return status;
    if (vertex_count && (!pack->bones || !pack->positions))
        return sk_fail(error, SK_ERROR_ARGUMENT, "the pack's bones and positions must not be null");
    if (!pack->tangent_0 != !pack->tangent_1)
        return sk_fail(error, SK_ERROR_ARGUMENT, "the pack's tangent_0 and tangent_1 must be both given or both null");
    if (want_tangents && vertex_count && !pack->tangent_0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "tangent outputs need the pack's tangents");
    return SK_OK;
}

static sk_status check_fractions_for(const sk_runtime_fixed_pack *pack, const sk_runtime_instances *in,
                                     sk_error *error)
{
    for (size_t i = 0; pack->floats_per_slot == 4 && i < in->instance_count; ++i)
        if (in->fractions[i] != 0.0f)
            return sk_fail(error, SK_ERROR_ARGUMENT, "instance %zu's fraction is %g, but the pack does not morph", i,
                           (double)in->fractions[i]);
    return SK_OK;
}

sk_status sk_runtime_skin_fixed(float *positions, float *tangent_0, float *tangent_1, size_t output_vertex_count,
                                const sk_runtime_fixed_pack *pack, const sk_runtime_instances *instances, int kernel,
                                int thread_count, sk_error *error)
{
    const sk_fixed_kernel chosen = sk_fixed_kernel_for(kernel);
    sk_status status = check_skin_call(positions, tangent_0, tangent_1, pack, instances, chosen != NULL, kernel, error);
    if (status == SK_OK)
        status = check_fixed_pack(pack, tangent_0 != NULL, error);
    if (status == SK_OK)
        status = check_instances(instances, pack->mesh_starts, pack->mesh_count, output_vertex_count, error);
    if (status == SK_OK)
        status = check_fractions_for(pack, instances, error);
    if (status != SK_OK)
        return status;
    fixed_task task = {.outputs = {positions, tangent_0, tangent_1},
                       .streams = {pack->positions, pack->tangent_0, pack->tangent_1},
                       .pack = pack, .instances = instances, .kernel = chosen};
    for (size_t w = 0; w < SK_MAX_WORKERS; ++w)
        task.first_bad[w] = SIZE_MAX;
    sk_parallel_for(output_vertex_count, SK_EVALUATION_ITEMS_PER_WORKER, thread_count, fixed_range, &task);
    return name_bad_vertex(task.first_bad, task.bad_instance,
                           sk_worker_count(output_vertex_count, SK_EVALUATION_ITEMS_PER_WORKER, thread_count),
                           "a bone index", instances->bone_count, error);
}
