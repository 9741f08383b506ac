/*
 * Flattening charts to the plane (Merry 2007, section 5.3): LSCM (Levy et al. 2002) in the metric given by
 * each triangle's squared edge lengths (a large chart's free boundary by boundary first flattening, Sawhney and
 * Crane 2017, whose solves the multigrid does in steps that do not grow with the chart), the passes of section
 * 5.3 (free boundary, straight pinned boundary, unit-circle fallback, extra corners), Sander et al. 2001's L2
 * stretch minimised by global steps and per-vertex Newton steps that never flip a triangle, and the splits that
 * leave no chart overlapping itself and no triangle flipped. This file runs them over the charts; the parts are in
 * sk_chart_mesh.c, sk_lscm.c, sk_boundary_first.c, sk_amg.c, sk_stretch.c, sk_flatten_passes.c and sk_overlap.c.
 *
 * Charts are independent: workers take them largest first from a shared counter, so one big chart does not
 * leave the other workers idle. Nothing depends on the order in which charts are done, so the result does
 * not depend on the thread count.
 */
#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "sk_flatten.h"

/* ---------------------------------------------------------------------------------------------
 * Charts in parallel; a chart's pieces (components, overlap splits) one after another
 * ------------------------------------------------------------------------------------------- */

typedef struct piece {
    int32_t *triangles; /* mesh triangles, owned */
    size_t count;
    int from_split;     /* made by an overlap split, not given */
} piece;

typedef struct piece_stack {
    piece *items;
    size_t size, capacity;
} piece_stack;

static int push_piece(piece_stack *stack, piece item)
{
    return SK_PUSH(*stack, item, 8);
}

/* Pushes one piece per label (labels in [0, label_count)) made of the parent's triangles with that label. */
static int push_labelled(piece_stack *stack, const piece *parent, const int32_t *labels, size_t label_count,
                         int from_split)
{
    for (size_t label = label_count; label-- > 0;) {
        size_t count = 0;
        for (size_t t = 0; t < parent->count; ++t)
            count += labels[t] == (int32_t)label;
        piece item = {sk_allocate(count, sizeof(int32_t)), 0, from_split};
        if (!item.triangles)
            return 0;
        for (size_t t = 0; t < parent->count; ++t)
            if (labels[t] == (int32_t)label)
                item.triangles[item.count++] = parent->triangles[t];
        if (!push_piece(stack, item)) {
            free(item.triangles);
            return 0;
        }
    }
    return 1;
}

typedef struct worker_state {
    pass_counts counts;
    size_t splits, flip_splits, stretch_splits, invalid_triangles, overlapping_charts;
    sk_status status;
    size_t failed_chart;
    sk_error error;
} worker_state;

typedef struct flatten_job {
    const flatten_input *in;
    const int32_t *chart_offsets, *chart_triangles; /* the mesh triangles of each given chart, CSR */
    const int32_t *order;                           /* charts, largest first */
    size_t chart_count;
    double *uv;                                     /* destination, 6 per triangle */
    int32_t *piece_of_triangle;                     /* the piece number within its given chart */
    int32_t *piece_count;                           /* per given chart */
    atomic_size_t next;
    atomic_int failed;
    worker_state workers[SK_MAX_WORKERS];
} flatten_job;

/* Writes a finished piece: its uv per triangle corner and its number within the given chart. */
static void write_piece(flatten_job *job, const chart_mesh *m, const double *uv, int32_t number)
{
    for (size_t t = 0; t < m->triangle_count; ++t) {
        const size_t triangle = (size_t)m->triangles[t];
        for (int k = 0; k < 3; ++k) {
            const double *x = corner_uv(uv, m, t, k);
            job->uv[6 * triangle + 2 * (size_t)k] = x[0];
            job->uv[6 * triangle + 2 * (size_t)k + 1] = x[1];
        }
        job->piece_of_triangle[triangle] = number;
    }
}

/* Whether a free-boundary layout (optimised) of a large chart still stretches more than STRETCH_SPLIT_LIMIT. */
static int too_stretched(const sk_flatten_options *options, const chart_mesh *m, const double *uv)
{
    return !options->straight && options->optimise && m->triangle_count >= STRETCH_SPLIT_MIN_TRIANGLES &&
           sk_chart_stretch(m, uv) > STRETCH_SPLIT_LIMIT;
}

/*
 * Flattens a built piece; splits it (pushing the halves) when its boundary crosses itself, when it is too stretched
 * to lie flat whole (too_stretched), or when every pass still left a flipped, degenerate or collapsed triangle (the
 * guarantee behind the passes: the halves are flattened again, down to single triangles, which LSCM lays out as
 * they are in the metric).
 */
static sk_status finish_piece(flatten_job *job, worker_state *w, piece_stack *stack, const piece *item,
                              const chart_mesh *m, int32_t *pieces_done)
{
    double *uv = sk_allocate(2 * m->vertex_count, sizeof *uv);
    int32_t *labels = sk_allocate(m->triangle_count, sizeof *labels);
    int32_t *queue = sk_allocate(m->triangle_count, sizeof *queue);
    sk_status status = SK_ERROR_MEMORY;
    size_t crossing[2];
    if (uv && labels && queue && sk_flatten_chart(uv, m, job->in, &w->counts)) {
        const int crossed = sk_find_boundary_crossing(crossing, m, uv);
        if (crossed < 0) {
            status = SK_ERROR_MEMORY;
        } else if (crossed && sk_split_labels(labels, queue, m, crossing)) {
            status = push_labelled(stack, item, labels, 2, 1) ? SK_OK : SK_ERROR_MEMORY;
            ++w->splits;
        } else if (too_stretched(&job->in->options, m, uv)) {
            sk_split_around(labels, queue, m, sk_most_stretched(m, uv));
            status = push_labelled(stack, item, labels, 2, 1) ? SK_OK : SK_ERROR_MEMORY;
            ++w->stretch_splits;
        } else if (m->triangle_count > 1 && sk_first_invalid(m, uv) >= 0) {
            sk_split_around(labels, queue, m, sk_first_invalid(m, uv));
            status = push_labelled(stack, item, labels, 2, 1) ? SK_OK : SK_ERROR_MEMORY;
            ++w->flip_splits;
        } else {
            w->overlapping_charts += crossed;
            w->invalid_triangles += sk_count_invalid(m, uv);
            write_piece(job, m, uv, (*pieces_done)++);
            status = SK_OK;
        }
    }
    free(uv);
    free(labels);
    free(queue);
    return status;
}

static sk_status flatten_given_chart(flatten_job *job, worker_state *w, size_t chart)
{
    const size_t begin = (size_t)job->chart_offsets[chart], count = (size_t)job->chart_offsets[chart + 1] - begin;
    piece_stack stack = {NULL, 0, 0};
    int32_t pieces_done = 0;
    sk_status status = SK_OK;
    if (count > 0) {
        piece first = {sk_allocate(count, sizeof(int32_t)), count, 0};
        if (!first.triangles || !push_piece(&stack, first)) {
            free(first.triangles);
            status = SK_ERROR_MEMORY;
        } else {
            memcpy(first.triangles, job->chart_triangles + begin, count * sizeof(int32_t));
        }
    }
    while (status == SK_OK && stack.size > 0) {
        piece item = stack.items[--stack.size];
        int32_t *labels = sk_allocate(item.count, sizeof *labels);
        size_t components = 0;
        chart_mesh m;
        const build_outcome built = labels ? sk_build_chart_mesh(&m, job->in, item.triangles, item.count, chart, labels,
                                                              &components, &w->error)
                                           : OUT_OF_MEMORY;
        if (built == BUILT) {
            status = finish_piece(job, w, &stack, &item, &m, &pieces_done);
            sk_free_chart_mesh(&m);
        } else if (built == DISCONNECTED) {
            status = push_labelled(&stack, &item, labels, components, item.from_split) ? SK_OK : SK_ERROR_MEMORY;
        } else if (built == NOT_DISC && item.from_split) {
            /* A split of a disc can leave a piece with a hole (a half that surrounds the other); split again. */
            status = push_labelled(&stack, &item, labels, components, 1) ? SK_OK : SK_ERROR_MEMORY;
            ++w->splits;
        } else if (built == NOT_DISC) {
            status = SK_ERROR_ARGUMENT;
        } else if (built == REFUSED) {
            if (item.from_split) /* the thesis's argument says this cannot happen; say so if it does */
                sk_fail(&w->error, SK_ERROR_ARGUMENT,
                        "chart %zu: splitting its self-overlapping layout made a piece that is not a disc (%s)", chart,
                        w->error.message);
            status = SK_ERROR_ARGUMENT;
        } else {
            status = SK_ERROR_MEMORY;
        }
        free(labels);
        free(item.triangles);
    }
    while (stack.size > 0)
        free(stack.items[--stack.size].triangles);
    free(stack.items);
    job->piece_count[chart] = pieces_done;
    if (status == SK_ERROR_MEMORY)
        sk_fail(&w->error, status, "chart %zu: out of memory while flattening %zu triangles", chart, count);
    return status;
}

static void flatten_worker(void *context, size_t worker, size_t begin, size_t end)
{
    (void)begin;
    (void)end;
    flatten_job *job = context;
    worker_state *w = &job->workers[worker];
    for (;;) {
        const size_t index = atomic_fetch_add(&job->next, 1);
        if (index >= job->chart_count || atomic_load(&job->failed))
            return;
        const size_t chart = (size_t)job->order[index];
        const sk_status status = flatten_given_chart(job, w, chart);
        if (status != SK_OK) {
            w->status = status;
            w->failed_chart = chart;
            atomic_store(&job->failed, 1);
            return;
        }
    }
}

typedef struct sized_chart {
    int32_t size, chart;
} sized_chart;

static int larger_first(const void *a, const void *b)
{
    const sized_chart *x = a, *y = b;
    return x->size != y->size ? SK_ORDER(y->size, x->size) : SK_ORDER(x->chart, y->chart);
}

static sk_status check_flatten_arguments(const flatten_input *in, const int32_t *charts, sk_error *error)
{
    const sk_flatten_options *o = &in->options;
    if (!(isfinite(o->stretch_limit) && o->stretch_limit >= 1.0))
        return sk_fail(error, SK_ERROR_ARGUMENT, "stretch_limit must be a finite number >= 1 (got %g)",
                       o->stretch_limit);
    if (o->sweep_limit < 0)
        return sk_fail(error, SK_ERROR_ARGUMENT, "sweep_limit must not be negative (got %d)", o->sweep_limit);
    const sk_triangle_mesh mesh = {in->triangles, in->triangle_count, in->vertex_count};
    sk_status status = sk_validate_triangles(&mesh, error);
    if (status != SK_OK)
        return status;
    for (size_t t = 0; t < in->triangle_count; ++t)
        if (charts[t] < 0 || (size_t)charts[t] >= in->triangle_count)
            return sk_fail(error, SK_ERROR_INDEX, "triangle %zu has chart %d, outside [0, %zu)", t, charts[t],
                           in->triangle_count);
    return sk_check_metric(in->edge_lengths_sq, in->triangle_count, error);
}

/* Sums the workers' counts into the report and picks the failure of the lowest-numbered chart. */
static sk_status gather(sk_flatten_report *report, const flatten_job *job, size_t workers, sk_error *error)
{
    const worker_state *failed = NULL;
    for (size_t w = 0; w < workers; ++w) {
        const worker_state *s = &job->workers[w];
        report->straight_charts += s->counts.straight_charts;
        report->circle_charts += s->counts.circle_charts;
        report->free_charts += s->counts.free_charts;
        report->extra_corners += s->counts.extra_corners;
        report->tutte_charts += s->counts.tutte_charts;
        report->boundary_first_charts += s->counts.boundary_first_charts;
        report->solver_iterations += s->counts.solver_iterations;
        report->optimisation_sweeps += s->counts.sweeps;
        report->split_count += s->splits;
        report->flip_splits += s->flip_splits;
        report->stretch_splits += s->stretch_splits;
        report->invalid_triangles += s->invalid_triangles;
        report->overlapping_charts += s->overlapping_charts;
        if (s->status != SK_OK && (!failed || s->failed_chart < failed->failed_chart))
            failed = s;
    }
    if (failed)
        return sk_fail(error, failed->status, "%s", failed->error.message);
    return SK_OK;
}

sk_status sk_flatten(double *uv, int32_t *charts_out, sk_flatten_report *report, const sk_triangle_mesh *mesh,
                     const double *edge_lengths_sq, const int32_t *charts, const unsigned char *corners,
                     const sk_flatten_options *options, sk_error *error)
{
    if (!uv || !charts_out || !report || !mesh || !mesh->triangles || !edge_lengths_sq || !charts || !corners ||
        !options)
        return sk_fail(error, SK_ERROR_ARGUMENT, "sk_flatten: a null pointer");
    const int32_t *triangles = mesh->triangles;
    const size_t vertex_count = mesh->vertex_count, triangle_count = mesh->triangle_count;
    if (triangle_count == 0 || triangle_count > INT32_MAX / 3)
        return sk_fail(error, SK_ERROR_ARGUMENT, "triangle_count must be in [1, %d] (got %zu)", INT32_MAX / 3,
                       triangle_count);
    const flatten_input in = {triangles, edge_lengths_sq, corners, triangle_count, vertex_count, *options};
    sk_status status = check_flatten_arguments(&in, charts, error);
    if (status != SK_OK)
        return status;
    memset(report, 0, sizeof *report);
    int32_t *offsets = sk_allocate_zeroed(triangle_count + 2, sizeof *offsets);
    int32_t *members = sk_allocate(triangle_count, sizeof *members);
    int32_t *order = sk_allocate(triangle_count, sizeof *order);
    int32_t *piece_count = sk_allocate_zeroed(triangle_count, sizeof *piece_count);
    sized_chart *sized = sk_allocate(triangle_count, sizeof *sized);
    flatten_job *job = sk_allocate_zeroed(1, sizeof *job);
    if (!offsets || !members || !order || !piece_count || !sized || !job) {
        status = sk_fail(error, SK_ERROR_MEMORY, "sk_flatten: out of memory for %zu triangles", triangle_count);
        goto done;
    }
    sk_group_by_chart(offsets, members, charts, triangle_count);
    for (size_t c = 0; c < triangle_count; ++c)
        sized[c] = (sized_chart){offsets[c + 1] - offsets[c], (int32_t)c};
    qsort(sized, triangle_count, sizeof *sized, larger_first);
    for (size_t c = 0; c < triangle_count; ++c)
        order[c] = sized[c].chart;
    job->in = &in;
    job->chart_offsets = offsets;
    job->chart_triangles = members;
    job->order = order;
    job->chart_count = triangle_count;
    job->uv = uv;
    job->piece_of_triangle = charts_out;
    job->piece_count = piece_count;
    atomic_init(&job->next, 0);
    atomic_init(&job->failed, 0);
    const size_t workers = sk_worker_count(triangle_count, 1, options->thread_count);
    sk_parallel_for(triangle_count, 1, options->thread_count, flatten_worker, job);
    status = gather(report, job, workers, error);
    if (status == SK_OK) {
        /* Number the result's charts: the given charts in order, each followed by its pieces. */
        int32_t *first_number = order; /* reused: the order is no longer needed */
        int32_t total = 0;
        for (size_t c = 0; c < triangle_count; ++c) {
            first_number[c] = total;
            total += piece_count[c];
        }
        for (size_t t = 0; t < triangle_count; ++t)
            charts_out[t] += first_number[charts[t]];
        report->chart_count = (size_t)total;
        status = sk_succeed(error);
    }
done:
    free(offsets);
    free(members);
    free(order);
    free(piece_count);
    free(sized);
    free(job);
    return status;
}
