/* The runtime's vertex transformation kernels (sk_runtime_kernels.c), shared with its batch driver
 * (sk_runtime_skin.c); not part of the public contract. */
#ifndef SK_RUNTIME_INTERNAL_H
#define SK_RUNTIME_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

/* One stream (positions or one tangent) of a contiguous vertex range of one mesh, for one instance. */
typedef struct sk_morph_range {
    float *destination;          /* 3 per vertex of the range, from its first vertex */
    const float *morph;          /* 8 per influence (p, dp), indexed by the pack's influence numbers */
    const int32_t *offsets;      /* the pack's CSR offsets */
    const int32_t *bones;
    const float *matrices;       /* bone_count * 12 */
    size_t influence_count, bone_count;
    size_t begin, end;           /* pack vertices */
    size_t morph_stride;         /* floats between consecutive influences' (p, dp): 8 positions, 16 tangents */
    float fraction;
} sk_morph_range;

/* Transforms the range; returns the first vertex (pack numbering) whose offsets or bone indices are out of range
 * (its output is zero), or SIZE_MAX when there is none. */
typedef size_t (*sk_morph_kernel)(const sk_morph_range *range);

size_t sk_morph_scalar(const sk_morph_range *range);
#if defined(__x86_64__) || defined(_M_X64)
#define SK_RUNTIME_X86 1
size_t sk_morph_sse2(const sk_morph_range *range);
size_t sk_morph_avx2(const sk_morph_range *range);
#endif

/* The kernel for an sk_runtime_kernel value (AUTO resolved by CPU detection), or NULL when it cannot run here. */
sk_morph_kernel sk_morph_kernel_for(int kernel);

/* One stream of a contiguous vertex range of a fixed-K pack (sk_runtime_fixed_pack), for one instance. */
typedef struct sk_fixed_range {
    float *destination;       /* 3 per vertex of the range, from its first vertex */
    const float *data;        /* the stream's floats for the whole pack: K 8 (morphing) or K 4 per vertex */
    const uint16_t *bones;    /* K per pack vertex */
    const float *matrices;    /* bone_count * 12 */
    size_t bone_count, influences;
    size_t begin, end;        /* pack vertices */
    float fraction;
    int morphs;
} sk_fixed_range;

/* As sk_morph_kernel: returns the first vertex with a bone index out of range (its output zero) or SIZE_MAX. */
typedef size_t (*sk_fixed_kernel)(const sk_fixed_range *range);

size_t sk_fixed_scalar(const sk_fixed_range *range);
#ifdef SK_RUNTIME_X86
size_t sk_fixed_sse2(const sk_fixed_range *range);
size_t sk_fixed_avx2(const sk_fixed_range *range);
#endif
sk_fixed_kernel sk_fixed_kernel_for(int kernel);

#endif
