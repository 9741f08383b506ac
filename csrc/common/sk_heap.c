/* Binary min-heaps over items of any type: the priority queues of segmentation, level of detail and the Dijkstra
 * searches of unwrapping share this one implementation. */
#include <string.h>

#include "sk_internal.h"

#define ITEM(items, index) ((unsigned char *)(items) + (index) * item_size)

void sk_heap_sift_up(void *items, size_t count, size_t item_size, sk_less_fn less)
{
    unsigned char item[SK_HEAP_MAX_ITEM];
    size_t child = count - 1;
    memcpy(item, ITEM(items, child), item_size);
    while (child > 0 && less(item, ITEM(items, (child - 1) / 2))) {
        memcpy(ITEM(items, child), ITEM(items, (child - 1) / 2), item_size);
        child = (child - 1) / 2;
    }
    memcpy(ITEM(items, child), item, item_size);
}

int sk_heap_insert(void *items_address, size_t *count, size_t *capacity, const void *item, size_t item_size,
                   size_t minimum, sk_less_fn less)
{
    if (*count == *capacity && !sk_grow(items_address, capacity, item_size, minimum))
        return 0;
    void *items = *(void **)items_address;
    memcpy(ITEM(items, (*count)++), item, item_size);
    sk_heap_sift_up(items, *count, item_size, less);
    return 1;
}

void sk_heap_pop_least(void *top, void *items, size_t *count, size_t item_size, sk_less_fn less)
{
    unsigned char last[SK_HEAP_MAX_ITEM];
    memcpy(top, ITEM(items, 0), item_size);
    memcpy(last, ITEM(items, --*count), item_size);
    size_t parent = 0;
    for (size_t child; (child = 2 * parent + 1) < *count; parent = child) {
        if (child + 1 < *count && less(ITEM(items, child + 1), ITEM(items, child)))
            ++child;
        if (!less(ITEM(items, child), last))
            break;
        memcpy(ITEM(items, parent), ITEM(items, child), item_size);
    }
    if (*count > 0)
        memcpy(ITEM(items, parent), last, item_size);
}

static int nearer(const void *a, const void *b)
{
    return ((const sk_vertex_distance *)a)->distance < ((const sk_vertex_distance *)b)->distance;
}

void sk_heap_push(sk_vertex_distance *heap, size_t *size, sk_vertex_distance item)
{
    heap[(*size)++] = item;
    sk_heap_sift_up(heap, *size, sizeof item, nearer);
}

sk_vertex_distance sk_heap_pop(sk_vertex_distance *heap, size_t *size)
{
    sk_vertex_distance top;
    sk_heap_pop_least(&top, heap, size, sizeof top, nearer);
    return top;
}
