/* Helpers shared by the core's source files; not part of the public contract. */
#ifndef SK_INTERNAL_H
#define SK_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "skinkit.h"

/* MinGW-w64 builds define __USE_MINGW_ANSI_STDIO (C99 printf, %zu included), which is gnu_printf there. */
#if defined(__MINGW32__)
#define SK_PRINTF(a, b) __attribute__((format(gnu_printf, a, b)))
#elif defined(__GNUC__)
#define SK_PRINTF(a, b) __attribute__((format(printf, a, b)))
#else
#define SK_PRINTF(a, b)
#endif

/* A rarely taken path kept out of line, so that its caller's common path saves no registers for it. */
#if defined(__GNUC__)
#define SK_COLD __attribute__((noinline, cold))
#else
#define SK_COLD
#endif

/* -1, 0 or 1 as a is below, equal to or above b: one key of a qsort comparator. */
#define SK_ORDER(a, b) (((a) > (b)) - ((a) < (b)))

/* ---------------------------------------------------------------------------------------------
 * Errors (sk_error.c)
 * ------------------------------------------------------------------------------------------- */

/* Records status and a formatted message in *error (when not NULL) and returns status. */
sk_status sk_fail(sk_error *error, sk_status status, const char *format, ...) SK_PRINTF(3, 4);

/* Clears *error to SK_OK and returns SK_OK. */
sk_status sk_succeed(sk_error *error);

/* ---------------------------------------------------------------------------------------------
 * Sizes that cannot wrap, and allocation (sk_error.c)
 * ------------------------------------------------------------------------------------------- */

/* *out = a * b (a + b): 1 when it fits in size_t, else 0 with *out = SIZE_MAX. Saturating, so an allocation of
 * *out items fails instead of getting a wrapped-around small block. */
int sk_mul_size(size_t a, size_t b, size_t *out);
int sk_add_size(size_t a, size_t b, size_t *out);

/* *out = a * b * c, the element count of an array described by counts the caller gave: SK_ERROR_ARGUMENT
 * naming `what` when it does not fit in size_t (no such array can exist). */
sk_status sk_array_size(size_t *out, size_t a, size_t b, size_t c, const char *what, sk_error *error);

/* malloc / calloc of count items of `size` bytes; NULL when count * size overflows or memory runs out. A
 * count of 0 still gets a (one-byte) block, so NULL always means failure. */
void *sk_allocate(size_t count, size_t size);
void *sk_allocate_zeroed(size_t count, size_t size);

/*
 * Growable arrays: any struct with `items` (a pointer), `size` and `capacity`. SK_PUSH appends `item`,
 * doubling the capacity when full (starting at `minimum`), and evaluates to 1, or to 0 when memory ran out
 * (the array is then unchanged). sk_grow does the doubling; items_address is the address of the pointer.
 */
int sk_grow(void *items_address, size_t *capacity, size_t item_size, size_t minimum);
#define SK_PUSH(array, item, minimum)                                                                           \
    (((array).size < (array).capacity ||                                                                        \
      sk_grow(&(array).items, &(array).capacity, sizeof *(array).items, (minimum)))                             \
         ? ((array).items[(array).size++] = (item), 1)                                                          \
         : 0)

/* Frees every pointer given (NULL ones included): the arrays of a workspace, in one list rather than a free()
 * a line. sk_free_all frees count pointers. */
void sk_free_all(void *const *pointers, size_t count);
#define SK_FREE_ALL(...) sk_free_all((void *[]){__VA_ARGS__}, sizeof((void *[]){__VA_ARGS__}) / sizeof(void *))

/* ---------------------------------------------------------------------------------------------
 * Validation (sk_validate.c)
 * ------------------------------------------------------------------------------------------- */

/* Checks that each rest frame is finite, affine and well conditioned (see sk_validate_skeleton). */
sk_status sk_validate_rest_frames(const double *rest_frames, size_t bone_count, sk_error *error);

/* Index of the first NaN or infinity, or count when there is none. */
size_t sk_first_non_finite(const double *values, size_t count);
int sk_all_finite(const double *values, size_t count);
size_t sk_first_non_finite_f32(const float *values, size_t count);
int sk_all_finite_f32(const float *values, size_t count);

/* ---------------------------------------------------------------------------------------------
 * Binary min-heaps (sk_heap.c): one implementation over items of any type, for the priority queues of
 * segmentation (chart merges), level of detail (collapses) and Dijkstra's searches (lazy deletion)
 * ------------------------------------------------------------------------------------------- */

/* Strict order of two items: non-zero when *a comes before *b. */
typedef int (*sk_less_fn)(const void *a, const void *b);
#define SK_HEAP_MAX_ITEM 64 /* bytes: the largest item type a heap holds */

/* items[0 .. count - 2] is a heap and items[count - 1] was just appended: moves it to its place. */
void sk_heap_sift_up(void *items, size_t count, size_t item_size, sk_less_fn less);
/* Appends *item to the heap at *items_address (growing it like SK_PUSH, from `minimum` items) and sifts it up;
 * 0 when memory runs out (the heap is then unchanged). */
int sk_heap_insert(void *items_address, size_t *count, size_t *capacity, const void *item, size_t item_size,
                   size_t minimum, sk_less_fn less);
/* Copies the least item to *top and removes it from the heap of *count (>= 1) items. */
void sk_heap_pop_least(void *top, void *items, size_t *count, size_t item_size, sk_less_fn less);
/* The same on a growable array (items, size, capacity) as SK_PUSH takes: SK_HEAP_PUSH is 0 when memory runs out;
 * item must be an lvalue (a compound literal will do). */
#define SK_HEAP_PUSH(heap, item, less)                                                                          \
    ((void)sizeof(char[sizeof(item) <= SK_HEAP_MAX_ITEM ? 1 : -1]), /* a compile error if the item is too big */ \
     sk_heap_insert(&(heap).items, &(heap).size, &(heap).capacity, &(item), sizeof(item), 1024, (less)))
#define SK_HEAP_POP(top, heap, less) sk_heap_pop_least(&(top), (heap).items, &(heap).size, sizeof(top), (less))

typedef struct sk_vertex_distance {
    double distance;
    int32_t vertex;
} sk_vertex_distance;

/* Adds an entry to the heap of *size entries (the caller provides room for it). */
void sk_heap_push(sk_vertex_distance *heap, size_t *size, sk_vertex_distance item);
/* Removes and returns the entry of smallest distance; *size must be at least 1. */
sk_vertex_distance sk_heap_pop(sk_vertex_distance *heap, size_t *size);

/* ---------------------------------------------------------------------------------------------
 * Fork-join parallel loops (sk_parallel.c)
 *
 * Runs body(context, worker, begin, end) over [0, count) split into contiguous ranges, one per
 * worker; worker is in [0, workers) where workers = sk_worker_count(count, min_per_worker,
 * thread_count): no more than thread_count (0: the online processors) and at least min_per_worker
 * items each. Falls back to fewer threads (down to the calling thread) if threads cannot be started,
 * so it cannot fail.
 * ------------------------------------------------------------------------------------------- */

#define SK_MAX_WORKERS 64
/* Below this many items per worker, starting a thread costs more than it saves (measured: a 20k-vertex
 * evaluation was slower on two threads than on one; a per-vertex dense solve takes ~10 us). */
#define SK_EVALUATION_ITEMS_PER_WORKER 32768
#define SK_SOLVE_ITEMS_PER_WORKER 64
typedef void (*sk_range_body)(void *context, size_t worker, size_t begin, size_t end);
size_t sk_worker_count(size_t count, size_t min_per_worker, int thread_count);
void sk_parallel_for(size_t count, size_t min_per_worker, int thread_count, sk_range_body body, void *context);
/* Gives the processor to another ready thread, if any (a waiting loop's back-off). */
void sk_thread_yield(void);
/* Seconds on a monotonic clock, for stage timings in reports (sk_parallel.c: the platform layer). */
double sk_monotonic_seconds(void);

#endif
