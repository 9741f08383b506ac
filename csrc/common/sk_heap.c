/* The binary min-heap of (distance, vertex) entries that the Dijkstra searches of unwrapping share. */
#include "sk_internal.h"

void sk_heap_push(sk_vertex_distance *heap, size_t *size, sk_vertex_distance item)
{
    size_t child = (*size)++;
    while (child > 0 && heap[(child - 1) / 2].distance > item.distance) {
        heap[child] = heap[(child - 1) / 2];
        child = (child - 1) / 2;
    }
    heap[child] = item;
}

sk_vertex_distance sk_heap_pop(sk_vertex_distance *heap, size_t *size)
{
    const sk_vertex_distance top = heap[0], last = heap[--*size];
    size_t parent = 0;
    for (size_t child; (child = 2 * parent + 1) < *size; parent = child) {
        if (child + 1 < *size && heap[child + 1].distance < heap[child].distance)
            ++child;
        if (!(heap[child].distance < last.distance))
            break;
        heap[parent] = heap[child];
    }
    if (*size > 0)
        heap[parent] = last;
    return top;
}
