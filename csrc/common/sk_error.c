/* Status names, the error record, and overflow-checked size arithmetic. */
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sk_internal.h"

const char *sk_status_name(sk_status status)
{
    switch (status) {
    case SK_OK: return "ok";
    case SK_ERROR_ARGUMENT: return "invalid argument";
    case SK_ERROR_INDEX: return "index out of range";
    case SK_ERROR_NOT_FINITE: return "value not finite";
    case SK_ERROR_CYCLE: return "cyclic or disconnected skeleton";
    case SK_ERROR_SINGULAR: return "singular matrix";
    case SK_ERROR_MEMORY: return "out of memory";
    case SK_ERROR_LAPACK: return "LAPACK failure";
    case SK_ERROR_CANCELLED: return "cancelled";
    case SK_ERROR_RANK: return "underdetermined";
    }
    return "unknown status";
}

sk_status sk_fail(sk_error *error, sk_status status, const char *format, ...)
{
    if (error) {
        va_list arguments;
        va_start(arguments, format);
        error->status = status;
        vsnprintf(error->message, sizeof error->message, format, arguments);
        va_end(arguments);
    }
    return status;
}

sk_status sk_succeed(sk_error *error)
{
    if (error) {
        error->status = SK_OK;
        error->message[0] = '\0';
    }
    return SK_OK;
}

int sk_mul_size(size_t a, size_t b, size_t *out)
{
    if (b != 0 && a > SIZE_MAX / b) {
        *out = SIZE_MAX;
        return 0;
    }
    *out = a * b;
    return 1;
}

int sk_add_size(size_t a, size_t b, size_t *out)
{
    if (a > SIZE_MAX - b) {
        *out = SIZE_MAX;
        return 0;
    }
    *out = a + b;
    return 1;
}

sk_status sk_array_size(size_t *out, size_t a, size_t b, size_t c, const char *what, sk_error *error)
{
    size_t ab;
    if (!sk_mul_size(a, b, &ab) || !sk_mul_size(ab, c, out))
        return sk_fail(error, SK_ERROR_ARGUMENT, "the %s array (%zu x %zu x %zu values) does not fit in memory", what,
                       a, b, c);
    return SK_OK;
}

void *sk_allocate(size_t count, size_t size)
{
    size_t bytes;
    return sk_mul_size(count, size, &bytes) ? malloc(bytes ? bytes : 1) : NULL;
}

void *sk_allocate_zeroed(size_t count, size_t size)
{
    return calloc(count ? count : 1, size); /* calloc refuses a product that overflows */
}

void sk_free_all(void *const *pointers, size_t count)
{
    for (size_t k = 0; k < count; ++k)
        free(pointers[k]);
}

int sk_grow(void *items_address, size_t *capacity, size_t item_size, size_t minimum)
{
    size_t wanted, bytes;
    if (*capacity == 0)
        wanted = minimum;
    else if (!sk_mul_size(*capacity, 2, &wanted))
        return 0;
    if (!sk_mul_size(wanted, item_size, &bytes))
        return 0;
    /* The pointer is copied in and out as bytes: it may be any object pointer type (see SK_PUSH). */
    void *items;
    memcpy(&items, items_address, sizeof items);
    void *grown = realloc(items, bytes);
    if (!grown)
        return 0;
    memcpy(items_address, &grown, sizeof grown);
    *capacity = wanted;
    return 1;
}
