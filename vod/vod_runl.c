/* RUNL, the run-length coding of spec section 6: pairs {u8 count-1, voxel}
 * with the voxel in its raw width (whole raw bytes for 1-bit voxels). */
#include "vod.h"

#include <errno.h>
#include <string.h>

/* Bytes per RUNL unit. */
static size_t unit_bytes(uint32_t voxel_bits)
{
    return voxel_bits >= 8 ? voxel_bits / 8 : 1;
}

size_t vod_runl_bound(uint32_t voxel_bits, size_t raw)
{
    size_t w = unit_bytes(voxel_bits);
    return raw / w * (w + 1); /* every unit its own run */
}

size_t vod_runl_encode(uint32_t voxel_bits, const uint8_t *raw, size_t n,
                       uint8_t *out, size_t cap)
{
    size_t w = unit_bytes(voxel_bits), o = 0;
    for (size_t i = 0; i + w <= n;) {
        size_t run = 1;
        while (run < 256 && i + (run + 1) * w <= n &&
               memcmp(raw + i, raw + i + run * w, w) == 0)
            run++;
        if (cap - o < w + 1) return 0;
        out[o] = (uint8_t)(run - 1);
        memcpy(out + o + 1, raw + i, w);
        o += w + 1;
        i += run * w;
    }
    return o;
}

int vod_runl_decode(uint32_t voxel_bits, const uint8_t *in, size_t n,
                    uint8_t *raw, size_t raw_n)
{
    size_t w = unit_bytes(voxel_bits), i = 0, o = 0;
    while (o < raw_n) {
        if (n - i < w + 1) return -EBADMSG; /* input ends inside a pair */
        size_t run = (size_t)in[i] + 1;
        if (run > (raw_n - o) / w) return -EBADMSG; /* run passes raw_n */
        for (size_t r = 0; r < run; r++, o += w) memcpy(raw + o, in + i + 1, w);
        i += w + 1;
    }
    return i == n ? 0 : -EBADMSG; /* left-over bytes */
}
