/* Errors, finiteness checks and small affine-matrix helpers. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>

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

size_t sk_first_non_finite(const double *values, size_t count)
{
    for (size_t i = 0; i < count; ++i)
        if (!isfinite(values[i]))
            return i;
    return count;
}

int sk_all_finite(const double *values, size_t count)
{
    return sk_first_non_finite(values, count) == count;
}

int sk_all_finite_f32(const float *values, size_t count)
{
    for (size_t i = 0; i < count; ++i)
        if (!isfinite(values[i]))
            return 0;
    return 1;
}

int sk_affine_inverse(double destination[16], const double m[16])
{
    /* Cofactors of the 3x3 linear part; the translation follows as -A^-1 t. */
    const double c00 = m[5] * m[10] - m[6] * m[9];
    const double c01 = m[6] * m[8] - m[4] * m[10];
    const double c02 = m[4] * m[9] - m[5] * m[8];
    const double determinant = m[0] * c00 + m[1] * c01 + m[2] * c02;
    if (determinant == 0.0)
        return 0;
    const double s = 1.0 / determinant;
    double *d = destination;
    d[0] = c00 * s;
    d[1] = (m[2] * m[9] - m[1] * m[10]) * s;
    d[2] = (m[1] * m[6] - m[2] * m[5]) * s;
    d[4] = c01 * s;
    d[5] = (m[0] * m[10] - m[2] * m[8]) * s;
    d[6] = (m[2] * m[4] - m[0] * m[6]) * s;
    d[8] = c02 * s;
    d[9] = (m[1] * m[8] - m[0] * m[9]) * s;
    d[10] = (m[0] * m[5] - m[1] * m[4]) * s;
    for (int r = 0; r < 3; ++r)
        d[4 * r + 3] = -(d[4 * r] * m[3] + d[4 * r + 1] * m[7] + d[4 * r + 2] * m[11]);
    d[12] = d[13] = d[14] = 0.0;
    d[15] = 1.0;
    return 1;
}

void sk_group_by_chart(int32_t *offsets, int32_t *members, const int32_t *charts, size_t triangle_count)
{
    for (size_t t = 0; t < triangle_count; ++t)
        ++offsets[charts[t] + 2];
    for (size_t c = 0; c <= triangle_count; ++c)
        offsets[c + 1] += offsets[c];
    for (size_t t = 0; t < triangle_count; ++t)
        members[offsets[charts[t] + 1]++] = (int32_t)t;
}

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
