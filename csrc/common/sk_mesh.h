/* Triangle-mesh topology shared by unwrapping (and, later, simplification, baking, skeletons). */
#ifndef SK_MESH_H
#define SK_MESH_H

#include "sk_internal.h"

/*
 * Groups triangles by chart (a counting sort): chart c's triangles end up in members[offsets[c] ..
 * offsets[c + 1] - 1]. Chart ids must already be checked to lie in [0, triangle_count); offsets has
 * triangle_count + 2 entries, zeroed by the caller; members has triangle_count.
 */
void sk_group_by_chart(int32_t *offsets, int32_t *members, const int32_t *charts, size_t triangle_count);

#endif
