/* A fork-join parallel for over index ranges with no persistent pool (no global state), and a monotonic clock.
 * The only platform-specific code in the core: POSIX threads everywhere but Windows, Win32 threads there (MinGW-w64
 * builds need no winpthreads DLL beside the extension). */
#ifdef _WIN32
#define WIN32_LEAN_AND_MEAN
#include <windows.h>
#else
#define _POSIX_C_SOURCE 200809L /* sysconf, clock_gettime */
#include <pthread.h>
#include <sched.h>
#include <time.h>
#include <unistd.h>
#endif

#include "sk_internal.h"


typedef struct worker_task {
    sk_range_body body;
    void *context;
    size_t worker, begin, end;
} worker_task;

static void run_task(const worker_task *task) { task->body(task->context, task->worker, task->begin, task->end); }

#ifdef _WIN32
typedef HANDLE sk_thread;

static DWORD WINAPI thread_entry(LPVOID argument)
{
    run_task(argument);
    return 0;
}

static int start_thread(sk_thread *thread, worker_task *task)
{
    *thread = CreateThread(NULL, 0, thread_entry, task, 0, NULL);
    return *thread != NULL;
}

static void join_thread(sk_thread thread)
{
    WaitForSingleObject(thread, INFINITE);
    CloseHandle(thread);
}

void sk_thread_yield(void) { SwitchToThread(); }

static long online_processors(void)
{
    SYSTEM_INFO info;
    GetSystemInfo(&info);
    return (long)info.dwNumberOfProcessors;
}

double sk_monotonic_seconds(void)
{
    LARGE_INTEGER count, frequency;
    QueryPerformanceCounter(&count);
    QueryPerformanceFrequency(&frequency);
    return (double)count.QuadPart / (double)frequency.QuadPart;
}
#else
typedef pthread_t sk_thread;

static void *thread_entry(void *argument)
{
    run_task(argument);
    return NULL;
}

static int start_thread(sk_thread *thread, worker_task *task) { return pthread_create(thread, NULL, thread_entry, task) == 0; }

static void join_thread(sk_thread thread) { pthread_join(thread, NULL); }

static long online_processors(void) { return sysconf(_SC_NPROCESSORS_ONLN); }

void sk_thread_yield(void) { sched_yield(); }

double sk_monotonic_seconds(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}
#endif

size_t sk_worker_count(size_t count, size_t min_per_worker, int thread_count)
{
    long wanted = thread_count;
    if (thread_count <= 0)
        wanted = online_processors();
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
    sk_thread threads[SK_MAX_WORKERS];
    int started[SK_MAX_WORKERS] = {0};
    for (size_t w = 0; w < workers; ++w) {
        tasks[w] = (worker_task){body, context, w, count * w / workers, count * (w + 1) / workers};
    }
    for (size_t w = 1; w < workers; ++w)
        started[w] = start_thread(&threads[w], &tasks[w]);
    run_task(&tasks[0]);
    for (size_t w = 1; w < workers; ++w) {
        if (started[w])
            join_thread(threads[w]);
        else
            run_task(&tasks[w]); /* the thread could not start: do its share here */
    }
}
