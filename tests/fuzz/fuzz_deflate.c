/* Fuzz the one-pass deflate encoder (vod_deflate.c) by round trip: the
 * input builds a brick (byte 0 picks its size, 2..16 per side, and its
 * voxel size, 1, 8 or 32 bits; then records of 6 bytes: a 4-byte word's
 * index and its value, and every 7th record copies a run of earlier
 * words, so that matches and long runs of zeros both occur), the encoder
 * compresses it and zlib must inflate the stream to the same bytes.  Invariants (abort on violation):
 *   - the stream inflates with zlib to exactly the brick;
 *   - one byte less of room than the stream took gives 0, never a
 *     truncated stream. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#include "vod.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static uint32_t get32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* The brick the input describes, into raw (n voxels). */
static void build(const uint8_t *data, size_t size, uint32_t *raw, size_t n)
{
    memset(raw, 0, n * 4);
    for (size_t i = 0, rec = 0; i + 6 <= size; i += 6, rec++) {
        size_t at = ((size_t)data[i] | (size_t)data[i + 1] << 8) % n;
        uint32_t v = get32(data + i + 2);
        if (rec % 7 == 6) { /* a run copied from earlier voxels */
            size_t from = v % n, len = (v >> 16) % 64 + 1;
            for (size_t k = 0; k < len && at + k < n; k++) raw[at + k] = raw[(from + k) % n];
        } else {
            raw[at] = v;
        }
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1) return 0;
    static const uint32_t voxel_bits[3] = {1, 8, 32};
    uint32_t brick = 2u << (data[0] % 4); /* 2, 4, 8, 16 */
    uint32_t bits = voxel_bits[(data[0] >> 2) % 3];
    size_t bytes = (size_t)brick * brick * brick * bits / 8, cap = 2 * bytes + 64;
    size_t n = (bytes + 3) / 4; /* words; raw has room for the last one */
    uint32_t *raw = malloc(n * 4), *back = malloc(n * 4);
    uint8_t *out = malloc(cap);
    vod_sparse *z = NULL;
    if (!raw || !back || !out || vod_sparse_new(brick, bits, &z)) abort();
    build(data + 1, size - 1, raw, n);
    size_t k = vod_sparse_compress(z, (const uint8_t *)raw, bytes, out, cap);
    if (k == 0) abort(); /* 2n + 64 always holds a brick */
    uLongf got = bytes;
    if (uncompress((Bytef *)back, &got, out, k) != Z_OK || got != bytes ||
        memcmp(back, raw, bytes) != 0)
        abort();
    if (vod_sparse_compress(z, (const uint8_t *)raw, bytes, out, k - 1) != 0) abort();
    vod_sparse_free(z);
    free(raw);
    free(back);
    free(out);
    return 0;
}
