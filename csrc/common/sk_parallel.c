/* A fork-join parallel for over index ranges, with pthreads and no persistent pool (no global state). */
#define _POSIX_C_SOURCE 200809L /* sysconf */
#include <pthread.h>
#include <unistd.h>

#include "sk_internal.h"


typedef struct worker_task {
    sk_range_body body;
    void *context;
    size_t worker, begin, end;
} worker_task;

static void *run_task(void *argument)
{
    const worker_task *task = argument;
    task->body(task->context, task->worker, task->begin, task->end);
    return NULL;
}

size_t sk_worker_count(size_t count, size_t min_per_worker, int thread_count)
{
    long wanted = thread_count;
    if (thread_count <= 0)
        wanted = sysconf(_SC_NPROCESSORS_ONLN);
    if (wanted < 1)
        wanted = 1;
    if (wanted > SK_MAX_WORKERS)
        wanted = SK_MAX_WORKERS;
    size_t by_size = min_per_worker > 0 ? count / min_per_worker : count;
    if (by_size < 1)
        by_size = 1;
    return (size_t)wanted < by_size ? (size_t)wanted : by_size;
}

void sk_parallel_for(size_t count, size_t min_per_worker, int thread_count, sk_range_body body, void *context)
{
    const size_t workers = sk_worker_count(count, min_per_worker, thread_count);
    worker_task tasks[SK_MAX_WORKERS];
    pthread_t threads[SK_MAX_WORKERS];
    int started[SK_MAX_WORKERS] = {0};
    for (size_t w = 0; w < workers; ++w) {
        tasks[w] = (worker_task){body, context, w, count * w / workers, count * (w + 1) / workers};
    }
    for (size_t w = 1; w < workers; ++w)
        started[w] = pthread_create(&threads[w], NULL, run_task, &tasks[w]) == 0;
    run_task(&tasks[0]);
    for (size_t w = 1; w < workers; ++w) {
        if (started[w])
            pthread_join(threads[w], NULL);
        else
            run_task(&tasks[w]); /* the thread could not start: do its share here */
    }
}
