/* The two brick hashes of the VOD spec (section 2, hashAlgorithm). */
#include "vod.h"

#include <xxhash.h>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

/* Hsieh's get16bits, the portable (byte-wise, little-endian) form, so the
 * hash is the same on every host. */
static inline uint32_t get16(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8;
}

/* The tail bytes are `signed char` in the reference code: sign-extend, then
 * shift as u32 so that no negative number is ever shifted. */
static inline uint32_t tail8(const uint8_t *p)
{
    return (uint32_t)(int32_t)(signed char)*p;
}

/* SuperFastHash's loop step: one 4-byte word at p. */
static inline uint32_t sfhs_word(uint32_t hash, const uint8_t *p)
{
    hash += get16(p);
    uint32_t tmp = (get16(p + 2) << 11) ^ hash;
    hash = (hash << 16) ^ tmp;
    return hash + (hash >> 11);
}

/* SuperFastHash after its loop over whole words: the rem (0..3) tail bytes
 * at p, then the avalanche (vod_hash_sfhs4 finishes each lane with it). */
static uint32_t sfhs_finish(uint32_t hash, const uint8_t *p, size_t rem)
{
    switch (rem) {
    case 3:
        hash += get16(p);
        hash ^= hash << 16;
        hash ^= tail8(p + 2) << 18;
        hash += hash >> 11;
        break;
    case 2:
        hash += get16(p);
        hash ^= hash << 11;
        hash += hash >> 17;
        break;
    case 1:
        hash += tail8(p);
        hash ^= hash << 10;
        hash += hash >> 1;
        break;
    }
    hash ^= hash << 3;
    hash += hash >> 5;
    hash ^= hash << 4;
    hash += hash >> 17;
    hash ^= hash << 25;
    hash += hash >> 6;
    return hash;
}

/* P. Hsieh's SuperFastHash, step for step. */
uint32_t vod_hash_sfhs(const void *data, size_t len)
{
    const uint8_t *p = data;
    uint32_t hash = (uint32_t)len;
    if (len == 0 || p == NULL) return 0;
    for (size_t n = len >> 2; n > 0; n--, p += 4) hash = sfhs_word(hash, p);
    return sfhs_finish(hash, p, len & 3);
}

#ifdef __SSE2__
/* Words k..k+3 of the four buffers, as four vectors of one word each:
 * out[j] lane i = word k + j of buffer i. */
static inline void load_words4(const uint8_t *const d[4], size_t at, __m128i out[4])
{
    __m128i a = _mm_loadu_si128((const __m128i *)(d[0] + at));
    __m128i b = _mm_loadu_si128((const __m128i *)(d[1] + at));
    __m128i c = _mm_loadu_si128((const __m128i *)(d[2] + at));
    __m128i e = _mm_loadu_si128((const __m128i *)(d[3] + at));
    __m128i ab0 = _mm_unpacklo_epi32(a, b), ab1 = _mm_unpackhi_epi32(a, b);
    __m128i ce0 = _mm_unpacklo_epi32(c, e), ce1 = _mm_unpackhi_epi32(c, e);
    out[0] = _mm_unpacklo_epi64(ab0, ce0);
    out[1] = _mm_unpackhi_epi64(ab0, ce0);
    out[2] = _mm_unpacklo_epi64(ab1, ce1);
    out[3] = _mm_unpackhi_epi64(ab1, ce1);
}

/* SuperFastHash's loop step on four hashes at once (w: one little-endian
 * word of each buffer; get16(p) is its low half, get16(p + 2) its high). */
static inline __m128i sfhs_step4(__m128i hash, __m128i w)
{
    const __m128i lo16 = _mm_set1_epi32(0xffff);
    hash = _mm_add_epi32(hash, _mm_and_si128(w, lo16));
    __m128i tmp = _mm_xor_si128(_mm_slli_epi32(_mm_srli_epi32(w, 16), 11), hash);
    hash = _mm_xor_si128(_mm_slli_epi32(hash, 16), tmp);
    return _mm_add_epi32(hash, _mm_srli_epi32(hash, 11));
}

/* The loop over the whole words of four buffers of len bytes: one chain of
 * SuperFastHash is serial, four in the lanes of a vector cost about one. */
static void sfhs_words4(const uint8_t *const d[4], size_t len, uint32_t h[4])
{
    size_t words = len >> 2, k = 0;
    __m128i hash = _mm_set1_epi32((int)(uint32_t)len);
    for (; words - k >= 4; k += 4) {
        __m128i w[4];
        load_words4(d, 4 * k, w);
        for (int j = 0; j < 4; j++) hash = sfhs_step4(hash, w[j]);
    }
    _mm_storeu_si128((__m128i *)h, hash);
    for (int i = 0; i < 4; i++)
        for (size_t j = k; j < words; j++) h[i] = sfhs_word(h[i], d[i] + 4 * j);
}
#else
static void sfhs_words4(const uint8_t *const d[4], size_t len, uint32_t h[4])
{
    for (int i = 0; i < 4; i++) {
        h[i] = (uint32_t)len;
        for (size_t j = 0; j < len >> 2; j++) h[i] = sfhs_word(h[i], d[i] + 4 * j);
    }
}
#endif

void vod_hash_sfhs4(const void *const data[4], size_t len, uint32_t out[4])
{
    const uint8_t *d[4];
    for (int i = 0; i < 4; i++) d[i] = data[i];
    if (len == 0) {
        for (int i = 0; i < 4; i++) out[i] = 0;
        return;
    }
    sfhs_words4(d, len, out);
    for (int i = 0; i < 4; i++)
        out[i] = sfhs_finish(out[i], d[i] + (len & ~(size_t)3), len & 3);
}

uint32_t vod_hash_xx32(const void *data, size_t len)
{
    return XXH32(data, len, 0);
}

uint32_t vod_hash(uint32_t alg, const void *data, size_t len)
{
    return alg == VOD_HASH_XX32 ? vod_hash_xx32(data, len)
                                : vod_hash_sfhs(data, len);
}

const char *vod_fourcc_str(uint32_t v, char buf[5])
{
    for (int i = 0; i < 4; i++) {
        char c = (char)(v >> (8 * i));
        buf[i] = (c >= 32 && c < 127) ? c : '?';
    }
    buf[4] = '\0';
    return buf;
}
