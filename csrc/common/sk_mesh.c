/* Triangle-mesh topology shared by unwrapping. */
#include "sk_mesh.h"

void sk_group_by_chart(int32_t *offsets, int32_t *members, const int32_t *charts, size_t triangle_count)
{
    for (size_t t = 0; t < triangle_count; ++t)
        ++offsets[charts[t] + 2];
    for (size_t c = 0; c <= triangle_count; ++c)
        offsets[c + 1] += offsets[c];
    for (size_t t = 0; t < triangle_count; ++t)
        members[offsets[charts[t] + 1]++] = (int32_t)t;
}
