/* Helpers shared by the core's source files; not part of the public contract. */
#ifndef SK_INTERNAL_H
#define SK_INTERNAL_H

#include "skinkit.h"

#if defined(__GNUC__)
#define SK_PRINTF(a, b) __attribute__((format(printf, a, b)))
#else
#define SK_PRINTF(a, b)
#endif

/* Records status and a formatted message in *error (when not NULL) and returns status. */
sk_status sk_fail(sk_error *error, sk_status status, const char *format, ...) SK_PRINTF(3, 4);

/* Clears *error to SK_OK and returns SK_OK. */
sk_status sk_succeed(sk_error *error);

/* Checks that each rest frame is finite, affine and well conditioned (see sk_validate_skeleton). */
sk_status sk_validate_rest_frames(const double *rest_frames, size_t bone_count, sk_error *error);

int sk_all_finite(const double *values, size_t count);

/* A (distance, vertex) entry of the binary min-heap Dijkstra's searches use (with lazy deletion). */
typedef struct sk_vertex_distance {
    double distance;
    int32_t vertex;
} sk_vertex_distance;

/* Adds an entry to the heap of *size entries (the caller provides room for it). */
void sk_heap_push(sk_vertex_distance *heap, size_t *size, sk_vertex_distance item);
/* Removes and returns the entry of smallest distance; *size must be at least 1. */
sk_vertex_distance sk_heap_pop(sk_vertex_distance *heap, size_t *size);

/*
 * Groups triangles by chart (a counting sort): chart c's triangles end up in members[offsets[c] ..
 * offsets[c + 1] - 1]. Chart ids must already be checked to lie in [0, triangle_count); offsets has
 * triangle_count + 2 entries, zeroed by the caller; members has triangle_count.
 */
void sk_group_by_chart(int32_t *offsets, int32_t *members, const int32_t *charts, size_t triangle_count);
/* Index of the first NaN or infinity, or count when there is none. */
size_t sk_first_non_finite(const double *values, size_t count);
int sk_all_finite_f32(const float *values, size_t count);

/* Inverts an affine 4x4 row-major matrix; returns 0 when its linear part is exactly singular. */
int sk_affine_inverse(double destination[16], const double matrix[16]);

/*
 * Runs body(context, worker, begin, end) over [0, count) split into contiguous ranges, one per
 * worker; worker is in [0, workers) where workers = sk_worker_count(count, min_per_worker,
 * thread_count): no more than thread_count (0: the online processors) and at least min_per_worker
 * items each. Falls back to fewer threads (down to the calling thread) if threads cannot be started,
 * so it cannot fail.
 */
#define SK_MAX_WORKERS 64
/* Below this many items per worker, starting a thread costs more than it saves (measured: a 20k-vertex
 * evaluation was slower on two threads than on one; a per-vertex dense solve takes ~10 us). */
#define SK_EVALUATION_ITEMS_PER_WORKER 32768
#define SK_SOLVE_ITEMS_PER_WORKER 64
typedef void (*sk_range_body)(void *context, size_t worker, size_t begin, size_t end);
size_t sk_worker_count(size_t count, size_t min_per_worker, int thread_count);
void sk_parallel_for(size_t count, size_t min_per_worker, int thread_count, sk_range_body body, void *context);

#endif
