/* Gathering a box's voxels from the bricks that hold them (export.h). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "export.h"
#include "voxel.h"

/* The 8 bytes (0 or 1) of 8 one-bit voxels, bit i to byte i: one load per
 * 8 voxels where a row of a brick is whole bytes.  A constant table (the
 * gathering threads share it). */
#define BIT(v, i) ((uint64_t)((v) >> (i) & 1u) << (8 * (i)))
#define E8(v) (BIT(v, 0) | BIT(v, 1) | BIT(v, 2) | BIT(v, 3) | BIT(v, 4) | BIT(v, 5) | \
               BIT(v, 6) | BIT(v, 7))
#define T4(v) E8(v), E8((v) + 1), E8((v) + 2), E8((v) + 3)
#define T16(v) T4(v), T4((v) + 4), T4((v) + 8), T4((v) + 12)
#define T64(v) T16(v), T16((v) + 16), T16((v) + 32), T16((v) + 48)
static const uint64_t bits8[256] = {T64(0u), T64(64u), T64(128u), T64(192u)};

static uint8_t voxel_u8(const vod_info *in, const uint8_t *raw, size_t i)
{
    if (in->channel == VOXEL_CH_DISTANCE) return raw[4 * i + 3] >> 7; /* the f32's sign */
    switch (in->voxel_bits) {
    case 1: return raw[i >> 3] >> (i & 7) & 1u;
    case 8: return raw[i];
    default: return raw[4 * i]; /* channel 3: bits 0-7, the occupancy */
    }
}

/* One row of a brick, voxels [src, src + n) of raw, into out. */
static void row(const vod_info *in, const uint8_t *raw, size_t src, uint32_t n, uint8_t *out)
{
    if (in->voxel_bits == 8) {
        memcpy(out, raw + src, n);
        return;
    }
    uint32_t x = 0;
    if (in->voxel_bits == 1 && src % 8 == 0) /* whole bytes: 8 voxels a load */
        for (; x + 8 <= n; x += 8) memcpy(out + x, &bits8[raw[(src + x) >> 3]], 8);
    for (; x < n; x++) out[x] = voxel_u8(in, raw, src + x);
}

/* What one brick's part of a box goes to: the box and its output. */
typedef struct {
    const export_box *b;
    const uint32_t *lo;
    uint32_t B, w, h;     /* the brick's side; the box's width and height */
    void *out;
    int comps;            /* export_gather_normals' */
} gather;

/* Every brick of the box lo..hi that the file holds (an empty one holds
 * 0s, which out starts with), its part of the box s..e to fn. */
static void each_brick(gather *g, const uint32_t hi[3],
                       void (*fn)(const gather *g, const uint8_t *raw, const uint32_t s[3],
                                  const uint32_t e[3]))
{
    const uint32_t *lo = g->lo, B = g->B;
    uint32_t bk[3];
    for (bk[2] = lo[2] / B; bk[2] * B < hi[2]; bk[2]++)
        for (bk[1] = lo[1] / B; bk[1] * B < hi[1]; bk[1]++)
            for (bk[0] = lo[0] / B; bk[0] * B < hi[0]; bk[0]++) {
                const uint8_t *raw = vod_brick(g->b->f, g->b->level, bk);
                if (!raw) continue;
                uint32_t s[3], e[3];
                for (int a = 0; a < 3; a++) {
                    s[a] = bk[a] * B > lo[a] ? bk[a] * B : lo[a];
                    e[a] = (bk[a] + 1) * B < hi[a] ? (bk[a] + 1) * B : hi[a];
                }
                fn(g, raw, s, e);
            }
}

static void gather_values(const gather *g, const uint8_t *raw, const uint32_t s[3],
                          const uint32_t e[3])
{
    const uint32_t *lo = g->lo, B = g->B;
    for (uint32_t z = s[2]; z < e[2]; z++)
        for (uint32_t y = s[1]; y < e[1]; y++) {
            size_t src = ((size_t)(z % B) * B + y % B) * B + s[0] % B;
            size_t dst = ((size_t)(z - lo[2]) * g->h + (y - lo[1])) * g->w + s[0] - lo[0];
            row(g->b->in, raw, src, e[0] - s[0], (uint8_t *)g->out + dst);
        }
}

void export_gather(const export_box *b, const uint32_t lo[3], const uint32_t hi[3],
                   uint8_t *out)
{
    gather g = {b, lo, b->in->brick, hi[0] - lo[0], hi[1] - lo[1], out, 0};
    memset(out, 0, (size_t)g.w * g.h * (hi[2] - lo[2]));
    each_brick(&g, hi, gather_values);
}

static void gather_normals(const gather *g, const uint8_t *raw, const uint32_t s[3],
                           const uint32_t e[3])
{
    const uint32_t *lo = g->lo, B = g->B;
    for (uint32_t z = s[2]; z < e[2]; z++)
        for (uint32_t y = s[1]; y < e[1]; y++)
            for (uint32_t x = s[0]; x < e[0]; x++) {
                size_t i = ((size_t)(z % B) * B + y % B) * B + x % B;
                size_t o = ((size_t)(z - lo[2]) * g->h + (y - lo[1])) * g->w + x - lo[0];
                uint32_t v;
                memcpy(&v, raw + 4 * i, 4); /* little-endian bricks */
                if (g->b->distance) { /* channel 4: the float itself */
                    memcpy((float *)g->out + o, &v, 4);
                    continue;
                }
                if (!voxel_occupancy(v)) continue;
                double n[3];
                voxel_unpack_normal(v, n);
                float *p = (float *)g->out + o * g->comps;
                if (g->comps == 4) *p++ = (float)voxel_occupancy(v);
                for (int a = 0; a < 3; a++) p[a] = (float)n[a];
            }
}

void export_gather_normals(const export_box *b, const uint32_t lo[3], const uint32_t hi[3],
                           float *out, int comps)
{
    gather g = {b, lo, b->in->brick, hi[0] - lo[0], hi[1] - lo[1], out, comps};
    memset(out, 0, (size_t)g.w * g.h * (hi[2] - lo[2]) * comps * sizeof(float));
    each_brick(&g, hi, gather_normals);
}

double export_band_width(const vod_info *in, unsigned *band)
{
    const char *m = in->metadata ? strstr(in->metadata, "distance_band=") : NULL;
    unsigned k = VOXEL_BAND_DEFAULT;
    if (m && (m == in->metadata || m[-1] == '\n')) {
        char *end;
        unsigned long v = strtoul(m + 14, &end, 10);
        if (end != m + 14 && v >= 1 && v <= 4096) k = (unsigned)v;
    }
    if (band) *band = k;
    return (double)(float)(k * (double)in->voxel_scale[0]);
}
