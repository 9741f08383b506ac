/* CPU algorithm 1 (Merry 2007, section 7.4): loop over vertices, then over their influences,
 * v += G_j (p_j + f dp_j), with p and dp interleaved so one influence is one 32-byte read. A scalar version, an
 * SSE2 one (the x86-64 baseline) and an AVX2+FMA one compiled for that target alone (a target attribute), picked
 * at run time by CPU detection so the library still runs on any x86-64. The same three for the fixed-K layout
 * (sk_runtime_fixed_pack: 16-bit bones, no offsets, (p, p, dp, dp) per pair of slots), four vertices per step. */
#include <string.h>

#include "sk_runtime_internal.h"
#include "skinkit.h"

#ifdef SK_RUNTIME_X86
#include <immintrin.h>
#endif

/* 1 when the vertex's influence range is inside the pattern. Bone indices are checked in the kernels' loops, as they
 * are read (a predictable branch, no second pass over memory). */
static int range_ok(const sk_morph_range *r, size_t vertex)
{
    const int32_t begin = r->offsets[vertex], end = r->offsets[vertex + 1];
    return begin >= 0 && end >= begin && (size_t)end <= r->influence_count;
}

static int bone_ok(const sk_morph_range *r, int32_t bone)
{
    return (uint32_t)bone < r->bone_count; /* a negative index wraps to a huge one */
}

static size_t note_bad(size_t first_bad, size_t vertex, float *out)
{
    out[0] = out[1] = out[2] = 0.0f;
    return first_bad < vertex ? first_bad : vertex;
}

size_t sk_morph_scalar(const sk_morph_range *r)
{
    size_t first_bad = SIZE_MAX;
    const float f = r->fraction;
    for (size_t vertex = r->begin; vertex < r->end; ++vertex) {
        float *out = r->destination + 3 * (vertex - r->begin);
        if (!range_ok(r, vertex)) {
            first_bad = note_bad(first_bad, vertex, out);
            continue;
        }
        float x = 0.0f, y = 0.0f, z = 0.0f;
        int32_t k = r->offsets[vertex];
        for (; k < r->offsets[vertex + 1] && bone_ok(r, r->bones[k]); ++k) {
            const float *m = r->matrices + 12 * (size_t)r->bones[k];
            const float *c = r->morph + r->morph_stride * (size_t)k;
            const float q0 = c[0] + f * c[4], q1 = c[1] + f * c[5], q2 = c[2] + f * c[6], q3 = c[3] + f * c[7];
            x += m[0] * q0 + m[1] * q1 + m[2] * q2 + m[3] * q3;
            y += m[4] * q0 + m[5] * q1 + m[6] * q2 + m[7] * q3;
            z += m[8] * q0 + m[9] * q1 + m[10] * q2 + m[11] * q3;
        }
        if (k < r->offsets[vertex + 1]) {
            first_bad = note_bad(first_bad, vertex, out);
            continue;
        }
        out[0] = x;
        out[1] = y;
        out[2] = z;
    }
    return first_bad;
}

/* ---- The fixed-K layout (sk_runtime_fixed_pack): no offsets, 16-bit bones, four vertices per SIMD step ---- */

/* 1 when every bone index of `count` vertices from `first` is in range: one branch for a block of vertices, the
 * check itself branch-free. */
static inline int fixed_bones_ok(const sk_fixed_range *r, size_t slots, size_t first, size_t count)
{
    const uint16_t *bones = r->bones + slots * first;
    unsigned bad = 0;
    for (size_t k = 0; k < slots * count; ++k)
        bad |= bones[k] >= r->bone_count;
    return !bad;
}

/* Vertex `vertex`'s slot k: its p; its dp 8 floats further on when the pack morphs. */
static const float *fixed_slot(const sk_fixed_range *r, size_t vertex, size_t k)
{
    const size_t pair_floats = r->morphs ? 16 : 8;
    return r->data + pair_floats * (r->influences / 2 * vertex + k / 2) + 4 * (k % 2);
}

size_t sk_fixed_scalar(const sk_fixed_range *r)
{
    size_t first_bad = SIZE_MAX;
    for (size_t vertex = r->begin; vertex < r->end; ++vertex) {
        float *out = r->destination + 3 * (vertex - r->begin);
        if (!fixed_bones_ok(r, r->influences, vertex, 1)) {
            first_bad = note_bad(first_bad, vertex, out);
            continue;
        }
        float x = 0.0f, y = 0.0f, z = 0.0f;
        for (size_t k = 0; k < r->influences; ++k) {
            const float *m = r->matrices + 12 * (size_t)r->bones[r->influences * vertex + k];
            const float *c = fixed_slot(r, vertex, k);
            float q[4];
            for (int i = 0; i < 4; ++i)
                q[i] = r->morphs ? c[i] + r->fraction * c[8 + i] : c[i];
            x += m[0] * q[0] + m[1] * q[1] + m[2] * q[2] + m[3] * q[3];
            y += m[4] * q[0] + m[5] * q[1] + m[6] * q[2] + m[7] * q[3];
            z += m[8] * q[0] + m[9] * q[1] + m[10] * q[2] + m[11] * q[3];
        }
        out[0] = x;
        out[1] = y;
        out[2] = z;
    }
    return first_bad;
}

#ifdef SK_RUNTIME_X86

/* (sum of a's lanes, sum of b's, sum of c's): the three rows' dot products, by one 4x4 transpose. Stores three
 * floats only: the fourth would land on the next vertex, which may belong to another thread. */
static void store_row_sums(float *out, __m128 a, __m128 b, __m128 c)
{
    __m128 d = _mm_setzero_ps();
    _MM_TRANSPOSE4_PS(a, b, c, d);
    float sums[4];
    _mm_storeu_ps(sums, _mm_add_ps(_mm_add_ps(a, b), _mm_add_ps(c, d)));
    memcpy(out, sums, 3 * sizeof *out);
}

size_t sk_morph_sse2(const sk_morph_range *r)
{
    size_t first_bad = SIZE_MAX;
    const __m128 f = _mm_set1_ps(r->fraction);
    for (size_t vertex = r->begin; vertex < r->end; ++vertex) {
        float *out = r->destination + 3 * (vertex - r->begin);
        if (!range_ok(r, vertex)) {
            first_bad = note_bad(first_bad, vertex, out);
            continue;
        }
        __m128 x = _mm_setzero_ps(), y = _mm_setzero_ps(), z = _mm_setzero_ps();
        int32_t k = r->offsets[vertex];
        for (; k < r->offsets[vertex + 1] && bone_ok(r, r->bones[k]); ++k) {
            const float *m = r->matrices + 12 * (size_t)r->bones[k];
            const float *c = r->morph + r->morph_stride * (size_t)k;
            const __m128 q = _mm_add_ps(_mm_loadu_ps(c), _mm_mul_ps(f, _mm_loadu_ps(c + 4)));
            x = _mm_add_ps(x, _mm_mul_ps(_mm_loadu_ps(m), q));
            y = _mm_add_ps(y, _mm_mul_ps(_mm_loadu_ps(m + 4), q));
            z = _mm_add_ps(z, _mm_mul_ps(_mm_loadu_ps(m + 8), q));
        }
        if (k < r->offsets[vertex + 1]) {
            first_bad = note_bad(first_bad, vertex, out);
            continue;
        }
        store_row_sums(out, x, y, z);
    }
    return first_bad;
}

/* Two influences per step in 256-bit lanes: (p_k | p_k+1) and (dp_k | dp_k+1) from two 32-byte reads, the two
 * bones' rows side by side; an odd last influence in 128 bits. */
__attribute__((target("avx2,fma"))) static __m128 fold(__m256 v)
{
    return _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps(v, 1));
}

__attribute__((target("avx2,fma"))) size_t sk_morph_avx2(const sk_morph_range *r)
{
    size_t first_bad = SIZE_MAX;
    const __m256 f = _mm256_set1_ps(r->fraction);
    const size_t stride = r->morph_stride;
    for (size_t vertex = r->begin; vertex < r->end; ++vertex) {
        float *out = r->destination + 3 * (vertex - r->begin);
        if (!range_ok(r, vertex)) {
            first_bad = note_bad(first_bad, vertex, out);
            continue;
        }
        __m256 x = _mm256_setzero_ps(), y = _mm256_setzero_ps(), z = _mm256_setzero_ps();
        int32_t k = r->offsets[vertex];
        const int32_t end = r->offsets[vertex + 1];
        for (; k + 1 < end && bone_ok(r, r->bones[k]) && bone_ok(r, r->bones[k + 1]); k += 2) {
            const float *a = r->matrices + 12 * (size_t)r->bones[k];
            const float *b = r->matrices + 12 * (size_t)r->bones[k + 1];
            const __m256 first = _mm256_loadu_ps(r->morph + stride * (size_t)k);
            const __m256 second = _mm256_loadu_ps(r->morph + stride * (size_t)(k + 1));
            const __m256 p = _mm256_permute2f128_ps(first, second, 0x20);
            const __m256 dp = _mm256_permute2f128_ps(first, second, 0x31);
            const __m256 q = _mm256_fmadd_ps(f, dp, p);
            x = _mm256_fmadd_ps(_mm256_set_m128(_mm_loadu_ps(b), _mm_loadu_ps(a)), q, x);
            y = _mm256_fmadd_ps(_mm256_set_m128(_mm_loadu_ps(b + 4), _mm_loadu_ps(a + 4)), q, y);
            z = _mm256_fmadd_ps(_mm256_set_m128(_mm_loadu_ps(b + 8), _mm_loadu_ps(a + 8)), q, z);
        }
        __m128 x4 = fold(x), y4 = fold(y), z4 = fold(z);
        if (k + 1 < end || (k < end && !bone_ok(r, r->bones[k]))) {
            first_bad = note_bad(first_bad, vertex, out);
            continue;
        }
        if (k < end) {
            const float *m = r->matrices + 12 * (size_t)r->bones[k];
            const float *c = r->morph + stride * (size_t)k;
            const __m128 q = _mm_fmadd_ps(_mm256_castps256_ps128(f), _mm_loadu_ps(c + 4), _mm_loadu_ps(c));
            x4 = _mm_fmadd_ps(_mm_loadu_ps(m), q, x4);
            y4 = _mm_fmadd_ps(_mm_loadu_ps(m + 4), q, y4);
            z4 = _mm_fmadd_ps(_mm_loadu_ps(m + 8), q, z4);
        }
        store_row_sums(out, x4, y4, z4);
    }
    return first_bad;
}

/* Inlined into each kernel twice, with morphs a constant, so the layout test leaves the inner loop. */
#define SK_FIXED_INLINE static inline __attribute__((always_inline))

/* Four consecutive vertices' (x, y, z, -) packed into twelve floats (five shuffles) and written by three 16-byte
 * streaming stores to a 16-byte aligned out: the outputs are not read back, so they skip the cache and its
 * read-for-ownership (measured: 15-25% more vertices per second on one core at 1M vertices). */
SK_FIXED_INLINE void stream_four(float *out, __m128 v0, __m128 v1, __m128 v2, __m128 v3)
{
    const __m128 z0x1 = _mm_shuffle_ps(v0, v1, _MM_SHUFFLE(0, 0, 2, 2));
    const __m128 z2x3 = _mm_shuffle_ps(v2, v3, _MM_SHUFFLE(0, 0, 2, 2));
    _mm_stream_ps(out, _mm_shuffle_ps(v0, z0x1, _MM_SHUFFLE(3, 0, 1, 0)));
    _mm_stream_ps(out + 4, _mm_shuffle_ps(v1, v2, _MM_SHUFFLE(1, 0, 2, 1)));
    _mm_stream_ps(out + 8, _mm_shuffle_ps(z2x3, v3, _MM_SHUFFLE(2, 1, 2, 0)));
}

/* A block of four starts where the output is 16-byte aligned (the address advances 12 bytes a vertex, so single
 * vertices reach it within three) and all four are in the range. */
static int block_starts(const sk_fixed_range *r, size_t vertex, const float *out)
{
    return vertex + 4 <= r->end && ((uintptr_t)out & 15) == 0;
}

/* One vertex's (x, y, z): stores three floats only, the fourth lane being the next vertex's. */
SK_FIXED_INLINE void store_one(float *out, __m128 v)
{
    _mm_storel_pi((__m64 *)out, v);
    _mm_store_ss(out + 2, _mm_movehl_ps(v, v));
}

/* (x, y, z, 0): the sums of the three row accumulators' lanes, one vector per vertex so that four vertices' results
 * stay in four registers. */
SK_FIXED_INLINE __m128 sse2_fixed_vertex(const sk_fixed_range *r, size_t vertex, __m128 f, int morphs, size_t slots)
{
    const size_t pair_floats = morphs ? 16 : 8;
    const uint16_t *bones = r->bones + slots * vertex;
    const float *pair = r->data + pair_floats / 2 * slots * vertex;
    __m128 x = _mm_setzero_ps(), y = _mm_setzero_ps(), z = _mm_setzero_ps(), w = _mm_setzero_ps();
    for (size_t k = 0; k < slots; ++k) {
        const float *m = r->matrices + 12 * (size_t)bones[k];
        const float *c = pair + pair_floats * (k / 2) + 4 * (k % 2);
        const __m128 q = morphs ? _mm_add_ps(_mm_loadu_ps(c), _mm_mul_ps(f, _mm_loadu_ps(c + 8))) : _mm_loadu_ps(c);
        x = _mm_add_ps(x, _mm_mul_ps(_mm_loadu_ps(m), q));
        y = _mm_add_ps(y, _mm_mul_ps(_mm_loadu_ps(m + 4), q));
        z = _mm_add_ps(z, _mm_mul_ps(_mm_loadu_ps(m + 8), q));
    }
    _MM_TRANSPOSE4_PS(x, y, z, w);
    return _mm_add_ps(_mm_add_ps(x, y), _mm_add_ps(z, w));
}

SK_FIXED_INLINE size_t sse2_fixed(const sk_fixed_range *r, int morphs, size_t slots)
{
    size_t first_bad = SIZE_MAX;
    const __m128 f = _mm_set1_ps(r->fraction);
    for (size_t vertex = r->begin; vertex < r->end;) {
        float *out = r->destination + 3 * (vertex - r->begin);
        if (block_starts(r, vertex, out) && fixed_bones_ok(r, slots, vertex, 4)) {
            const __m128 v0 = sse2_fixed_vertex(r, vertex, f, morphs, slots);
            const __m128 v1 = sse2_fixed_vertex(r, vertex + 1, f, morphs, slots);
            const __m128 v2 = sse2_fixed_vertex(r, vertex + 2, f, morphs, slots);
            stream_four(out, v0, v1, v2, sse2_fixed_vertex(r, vertex + 3, f, morphs, slots));
            vertex += 4;
            continue;
        }
        if (fixed_bones_ok(r, slots, vertex, 1))
            store_one(out, sse2_fixed_vertex(r, vertex, f, morphs, slots));
        else
            first_bad = note_bad(first_bad, vertex, out);
        ++vertex;
    }
    _mm_sfence(); /* the streamed outputs visible to whichever thread reads them next */
    return first_bad;
}

/* K = 4 (what engines draw) and K = 2 get loops the compiler unrolls; other K the general loop. */
size_t sk_fixed_sse2(const sk_fixed_range *r)
{
    switch (r->influences) {
    case 2:
        return r->morphs ? sse2_fixed(r, 1, 2) : sse2_fixed(r, 0, 2);
    case 4:
        return r->morphs ? sse2_fixed(r, 1, 4) : sse2_fixed(r, 0, 4);
    default:
        return r->morphs ? sse2_fixed(r, 1, r->influences) : sse2_fixed(r, 0, r->influences);
    }
}

/* A pair of slots per step: (p_2j | p_2j+1) is one 256-bit read, and with dp_2j | dp_2j+1 right after it q is one
 * FMA, no permute; the two bones' rows side by side. The rows are reduced by horizontal adds before the two
 * halves are folded: (x, y, z, z). */
__attribute__((target("avx2,fma"))) SK_FIXED_INLINE __m128 avx2_fixed_vertex(const sk_fixed_range *r, size_t vertex,
                                                                           __m256 f, int morphs, size_t slots)
{
    const size_t pair_floats = morphs ? 16 : 8;
    const uint16_t *bones = r->bones + slots * vertex;
    const float *c = r->data + pair_floats / 2 * slots * vertex;
    __m256 x = _mm256_setzero_ps(), y = _mm256_setzero_ps(), z = _mm256_setzero_ps();
    for (size_t k = 0; k < slots; k += 2, c += pair_floats) {
        const float *a = r->matrices + 12 * (size_t)bones[k];
        const float *b = r->matrices + 12 * (size_t)bones[k + 1];
        const __m256 q = morphs ? _mm256_fmadd_ps(f, _mm256_loadu_ps(c + 8), _mm256_loadu_ps(c)) : _mm256_loadu_ps(c);
        x = _mm256_fmadd_ps(_mm256_set_m128(_mm_loadu_ps(b), _mm_loadu_ps(a)), q, x);
        y = _mm256_fmadd_ps(_mm256_set_m128(_mm_loadu_ps(b + 4), _mm_loadu_ps(a + 4)), q, y);
        z = _mm256_fmadd_ps(_mm256_set_m128(_mm_loadu_ps(b + 8), _mm_loadu_ps(a + 8)), q, z);
    }
    return fold(_mm256_hadd_ps(_mm256_hadd_ps(x, y), _mm256_hadd_ps(z, z)));
}

__attribute__((target("avx2,fma"))) SK_FIXED_INLINE size_t avx2_fixed(const sk_fixed_range *r, int morphs, size_t slots)
{
    size_t first_bad = SIZE_MAX;
    const __m256 f = _mm256_set1_ps(r->fraction);
    for (size_t vertex = r->begin; vertex < r->end;) {
        float *out = r->destination + 3 * (vertex - r->begin);
        if (block_starts(r, vertex, out) && fixed_bones_ok(r, slots, vertex, 4)) {
            const __m128 v0 = avx2_fixed_vertex(r, vertex, f, morphs, slots);
            const __m128 v1 = avx2_fixed_vertex(r, vertex + 1, f, morphs, slots);
            const __m128 v2 = avx2_fixed_vertex(r, vertex + 2, f, morphs, slots);
            stream_four(out, v0, v1, v2, avx2_fixed_vertex(r, vertex + 3, f, morphs, slots));
            vertex += 4;
            continue;
        }
        if (fixed_bones_ok(r, slots, vertex, 1))
            store_one(out, avx2_fixed_vertex(r, vertex, f, morphs, slots));
        else
            first_bad = note_bad(first_bad, vertex, out);
        ++vertex;
    }
    _mm_sfence(); /* the streamed outputs visible to whichever thread reads them next */
    return first_bad;
}

__attribute__((target("avx2,fma"))) size_t sk_fixed_avx2(const sk_fixed_range *r)
{
    switch (r->influences) {
    case 2:
        return r->morphs ? avx2_fixed(r, 1, 2) : avx2_fixed(r, 0, 2);
    case 4:
        return r->morphs ? avx2_fixed(r, 1, 4) : avx2_fixed(r, 0, 4);
    default:
        return r->morphs ? avx2_fixed(r, 1, r->influences) : avx2_fixed(r, 0, r->influences);
    }
}

static int avx2_available(void)
{
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}

sk_morph_kernel sk_morph_kernel_for(int kernel)
{
    switch (kernel) {
    case SK_RUNTIME_KERNEL_AUTO:
        return avx2_available() ? sk_morph_avx2 : sk_morph_sse2;
    case SK_RUNTIME_KERNEL_SCALAR:
        return sk_morph_scalar;
    case SK_RUNTIME_KERNEL_SSE2:
        return sk_morph_sse2;
    case SK_RUNTIME_KERNEL_AVX2:
        return avx2_available() ? sk_morph_avx2 : NULL;
    default:
        return NULL;
    }
}

sk_fixed_kernel sk_fixed_kernel_for(int kernel)
{
    switch (kernel) {
    case SK_RUNTIME_KERNEL_AUTO:
        return avx2_available() ? sk_fixed_avx2 : sk_fixed_sse2;
    case SK_RUNTIME_KERNEL_SCALAR:
        return sk_fixed_scalar;
    case SK_RUNTIME_KERNEL_SSE2:
        return sk_fixed_sse2;
    case SK_RUNTIME_KERNEL_AVX2:
        return avx2_available() ? sk_fixed_avx2 : NULL;
    default:
        return NULL;
    }
}

#else

sk_morph_kernel sk_morph_kernel_for(int kernel)
{
    return kernel == SK_RUNTIME_KERNEL_AUTO || kernel == SK_RUNTIME_KERNEL_SCALAR ? sk_morph_scalar : NULL;
}

sk_fixed_kernel sk_fixed_kernel_for(int kernel)
{
    return kernel == SK_RUNTIME_KERNEL_AUTO || kernel == SK_RUNTIME_KERNEL_SCALAR ? sk_fixed_scalar : NULL;
}

#endif
