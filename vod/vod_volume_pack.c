/* Packed bricks of a float volume (the layout in vod_volume_int.h).
 *
 * A distance field's band brick holds the exact distance in the voxels
 * near the surface and +-w (the band's width) in the others: at 1024^3 the
 * dragon's 16^3 band bricks hold 579 band voxels of 4096 on average.  A
 * record keeps the band voxels as they are and the others as one sign bit
 * each, so the volume's memory follows the band's voxels, not its bricks'.
 * The record is lossless for any values (bg is only a choice of which
 * voxels cost a bit instead of 32), so every reader sees the voxels the
 * writer gave, bit for bit.
 */
#include "bits.h"
#include "vod_volume_int.h"

#include <errno.h>
#include <stdatomic.h>
#include <string.h>

#define SIGN 0x80000000u

static size_t vox_n(uint32_t sbrick)
{
    return (size_t)sbrick * sbrick * sbrick;
}

static size_t mask_words(uint32_t sbrick)
{
    return (vox_n(sbrick) + 63) / 64;
}

/* Bytes of a record of n literals. */
static uint64_t record_bytes(uint32_t sbrick, uint64_t n)
{
    return sizeof(pack_head) + 16 * (uint64_t)mask_words(sbrick) + 4 * n;
}

static uint64_t units_of(uint64_t bytes)
{
    return (bytes + PACK_UNIT - 1) / PACK_UNIT;
}

uint64_t vod_pack_max_units(uint32_t sbrick)
{
    return units_of(record_bytes(sbrick, vox_n(sbrick)));
}

/* The record's parts (its head, masks and values are 4- and 8-byte
 * aligned: records start on a unit, the pool on 64 bytes). */
static const pack_head *head_of(const uint8_t *d)
{
    return (const pack_head *)(const void *)d;
}
static const uint64_t *lit_of(const uint8_t *d)
{
    return (const uint64_t *)(const void *)(d + sizeof(pack_head));
}
static const uint64_t *neg_of(const vod_volume *v, const uint8_t *d)
{
    return lit_of(d) + mask_words(v->sbrick);
}
static const uint32_t *vals_of(const vod_volume *v, const uint8_t *d)
{
    return (const uint32_t *)(const void *)(neg_of(v, d) + mask_words(v->sbrick));
}

uint32_t vod_pack_store(vod_volume *v, uint32_t old, const uint32_t *vox, bool edit)
{
    size_t N = vox_n(v->sbrick), W = mask_words(v->sbrick);
    uint32_t bg = 0, n = 0;
    for (size_t i = 0; i < N; i++) {
        uint32_t a = vox[i] & ~SIGN;
        bg = a > bg ? a : bg;
    }
    for (size_t i = 0; i < N; i++) n += (vox[i] & ~SIGN) != bg;
    uint64_t units = units_of(record_bytes(v->sbrick, n));
    if (edit) units = vod_pack_max_units(v->sbrick);
    uint32_t e = old, cap;
    if (is_alloc(old) && head_of(brick_data(v, old))->cap >= units) {
        cap = head_of(brick_data(v, old))->cap;
    } else {
        if (!(e = vod_vol_pool_units(v, units))) return 0;
        cap = (uint32_t)units;
    }
    uint8_t *d = brick_data(v, e);
    pack_head h = {.n = n, .cap = cap, .bg = bg};
    memcpy(d, &h, sizeof h);
    uint64_t *lit = (uint64_t *)(void *)(d + sizeof h), *neg = lit + W;
    uint32_t *out = (uint32_t *)(void *)(neg + W);
    memset(lit, 0, 16 * W);
    for (size_t i = 0, k = 0; i < N; i++) {
        uint64_t bit = 1ull << (i & 63);
        if ((vox[i] & ~SIGN) != bg) {
            lit[i >> 6] |= bit;
            out[k++] = vox[i];
        } else if (vox[i] & SIGN) {
            neg[i >> 6] |= bit;
        }
    }
    return e;
}

/* Literals before voxel i. */
static size_t rank(const uint64_t *lit, size_t i)
{
    size_t r = 0;
    for (size_t w = 0; w < i >> 6; w++) r += bits_popcount64(lit[w]);
    if (i & 63) r += bits_popcount64(lit[i >> 6] & ((1ull << (i & 63)) - 1));
    return r;
}

void vod_pack_range(const vod_volume *v, const uint8_t *d, size_t i0, size_t n, uint32_t *out)
{
    const uint64_t *lit = lit_of(d), *neg = neg_of(v, d);
    const uint32_t *vals = vals_of(v, d);
    uint32_t bg = head_of(d)->bg;
    size_t k = rank(lit, i0);
    /* a word's part at a time: every voxel bg with its sign, then the
     * literals over them (no branch on a voxel) */
    for (size_t i = i0, m; i < i0 + n; i += m, out += m) {
        size_t b = i & 63;
        m = 64 - b < i0 + n - i ? 64 - b : i0 + n - i;
        uint64_t l = lit[i >> 6] >> b, s = neg[i >> 6] >> b;
        if (m < 64) l &= (1ull << m) - 1;
        for (size_t j = 0; j < m; j++) out[j] = bg | (uint32_t)(s >> j & 1) * SIGN;
        for (; l; l &= l - 1) out[__builtin_ctzll(l)] = vals[k++];
    }
}

uint32_t vod_pack_voxel(const vod_volume *v, const uint8_t *d, size_t i)
{
    uint32_t u;
    vod_pack_range(v, d, i, 1, &u);
    return u;
}

bool vod_pack_any(const vod_volume *v, const uint8_t *d)
{
    const uint64_t *lit = lit_of(d), *neg = neg_of(v, d);
    const uint32_t *vals = vals_of(v, d);
    const pack_head *h = head_of(d);
    for (uint32_t k = 0; k < h->n; k++)
        if (vals[k]) return true;
    if (h->n == vox_n(v->sbrick)) return false; /* every voxel a literal */
    if (h->bg) return true;
    for (size_t w = 0; w < mask_words(v->sbrick); w++)
        if (neg[w] & ~lit[w]) return true; /* -0.0: bits 0x80000000 */
    return false;
}

int vod_pack_check(const vod_volume *v, uint32_t e, uint32_t used)
{
    if (!is_alloc(e) || e > used) return -EINVAL;
    const uint8_t *d = brick_data(v, e);
    const pack_head *h = head_of(d);
    size_t N = vox_n(v->sbrick), W = mask_words(v->sbrick), pop = 0;
    if (h->cap < 1 || h->cap > used - (e - 1) || h->n > N ||
        units_of(record_bytes(v->sbrick, h->n)) > h->cap || (h->bg & SIGN))
        return -EINVAL;
    const uint64_t *lit = lit_of(d);
    for (size_t w = 0; w < W; w++) pop += bits_popcount64(lit[w]);
    /* no mask bits past the S^3 voxels (S^3 >= 8: a whole word, or 8 bits) */
    if (N % 64 && (lit[W - 1] >> (N % 64) || neg_of(v, d)[W - 1] >> (N % 64))) return -EINVAL;
    return pop == h->n ? 0 : -EINVAL;
}
