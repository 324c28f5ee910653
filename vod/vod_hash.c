/* The two brick hashes of the VOD spec (section 2, hashAlgorithm). */
#include "vod.h"

#include <xxhash.h>

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

/* P. Hsieh's SuperFastHash, step for step. */
uint32_t vod_hash_sfhs(const void *data, size_t len)
{
    const uint8_t *p = data;
    uint32_t hash = (uint32_t)len, tmp;
    if (len == 0 || p == NULL) return 0;
    size_t rem = len & 3;
    for (size_t n = len >> 2; n > 0; n--, p += 4) {
        hash += get16(p);
        tmp = (get16(p + 2) << 11) ^ hash;
        hash = (hash << 16) ^ tmp;
        hash += hash >> 11;
    }
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
    /* Force "avalanching" of the final 127 bits. */
    hash ^= hash << 3;
    hash += hash >> 5;
    hash ^= hash << 4;
    hash += hash >> 17;
    hash ^= hash << 25;
    hash += hash >> 6;
    return hash;
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
