/* A brick-sparse volume and its VOD brick source (vod_volume.h).
 *
 * Each level l (0 = the voxels, 1..depth = mip levels) has a table of one
 * u32 entry per storage brick, grid[l] bricks per axis, covering the
 * ceil(dims / 2^l) voxels of that level: 0 = empty, ENTRY_UNIFORM | v =
 * every voxel is v (v < 2^31), anything else = pool brick entry - 1.
 *
 * At a mip level an entry is 0 exactly when the brick's full-resolution
 * footprint holds no non-zero voxel (prepare() computes it from the voxels,
 * not from the downsampled values, which may round to 0), so the writer's
 * emptiness question is one table look-up there.  At level 0 a uniform
 * entry is never 0 (a box filled with 0 empties its bricks), but an
 * allocated brick may hold only zeros: it is scanned.
 */
#include "vod_volume.h"

#include <assert.h>
#include <errno.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include "vod_downsample.h"
#include "voxel.h"

#define VOL_MAGIC 0x4c4f5656u /* "VVOL" */
#define VOL_LEVELS (OCTREE_MAX_DEPTH + 1)
#define ENTRY_UNIFORM 0x80000000u
#define POOL_MAX (ENTRY_UNIFORM - 2u) /* entries 1..ENTRY_UNIFORM-1 */

struct vod_volume {
    uint32_t magic;
    uint32_t dims[3];
    uint32_t bits, sbrick, slog2;
    int depth;
    uint32_t grid[VOL_LEVELS][3];
    uint64_t table_off[VOL_LEVELS]; /* from the start of the arena */
    uint64_t pool_off, brick_bytes;
    uint32_t pool_cap;
    /* Bricks taken from the pool, and of those the level-0 ones.  Atomic
     * because vod_volume_put_brick() writers of different bricks run
     * concurrently (relaxed: a brick's bytes and table entry are published
     * to the readers by whatever ends the writers' phase, in the engine the
     * worker's done_seq release, which the master's acquire pairs with). */
    atomic_uint pool_used, pool_l0;
    /* 1 once a level-0 brick with memory may hold only zeros (a zero
     * written into one); while 0, such a brick is known to hold a voxel
     * without a scan.  Set by concurrent put_brick writers too (relaxed:
     * published like pool_used, by the end of the writers' phase). */
    atomic_uint zero_bricks;
    int mip_channel;
    uint32_t mip_base;  /* pool_used before the mip levels were built */
    /* Levels 1..low_levels of channel low_channel built by column
     * (vod_volume_mip_columns) and declared complete: prepare() of that
     * channel builds only the levels above.  Their bricks are mixed with
     * level 0's in the pool, so nothing gives them back. */
    int low_channel, low_levels;
};

static uint64_t align64(uint64_t v) { return (v + 63) & ~(uint64_t)63; }

static bool is_uniform(uint32_t e) { return (e & ENTRY_UNIFORM) != 0; }
static bool is_alloc(uint32_t e) { return e && !is_uniform(e); }

/* ---- layout ---- */

static int check_args(const uint32_t dims[3], uint32_t bits, uint32_t sbrick)
{
    for (int a = 0; a < 3; a++)
        if (dims[a] < 1 || dims[a] > VOD_VOLUME_MAX_SIDE) return -EINVAL;
    if (bits != 8 && bits != 32) return -EINVAL;
    if (sbrick < VOD_VOLUME_MIN_BRICK || sbrick > VOD_VOLUME_MAX_BRICK ||
        (sbrick & (sbrick - 1)))
        return -EINVAL;
    return 0;
}

/* Header fields from the arguments (checked): depth, grids, table offsets,
 * the pool's offset; returns the bytes before the pool. */
static uint64_t plan(struct vod_volume *h, const uint32_t dims[3], uint32_t bits,
                     uint32_t sbrick)
{
    memset(h, 0, sizeof *h);
    h->magic = VOL_MAGIC;
    memcpy(h->dims, dims, sizeof h->dims);
    h->bits = bits;
    h->sbrick = sbrick;
    while (1u << h->slog2 < sbrick) h->slog2++;
    uint32_t m = dims[0] > dims[1] ? dims[0] : dims[1];
    if (dims[2] > m) m = dims[2];
    h->depth = 1;
    while ((1u << h->depth) < m) h->depth++;
    uint64_t at = align64(sizeof *h);
    for (int l = 0; l <= h->depth; l++) {
        uint64_t g = 1;
        for (int a = 0; a < 3; a++) {
            uint32_t side = (uint32_t)(((uint64_t)dims[a] + (1u << l) - 1) >> l);
            h->grid[l][a] = (side + sbrick - 1) >> h->slog2;
            g *= h->grid[l][a];
        }
        h->table_off[l] = at;
        at = align64(at + 4 * g);
    }
    h->brick_bytes = (uint64_t)sbrick * sbrick * sbrick * bits / 8;
    h->pool_off = at;
    return at;
}

static uint64_t grid_bricks(const struct vod_volume *h, int l)
{
    return (uint64_t)h->grid[l][0] * h->grid[l][1] * h->grid[l][2];
}

size_t vod_volume_bytes(const uint32_t dims[3], uint32_t bits, uint32_t sbrick,
                        uint64_t bricks)
{
    if (check_args(dims, bits, sbrick)) return 0;
    struct vod_volume h;
    uint64_t head = plan(&h, dims, bits, sbrick);
    if (bricks > grid_bricks(&h, 0)) bricks = grid_bricks(&h, 0);
    /* a non-empty mip brick has a non-empty child: at most as many per
     * level as below, and never more than the level's grid */
    uint64_t pool = bricks;
    for (int l = 1; l <= h.depth; l++)
        pool += bricks < grid_bricks(&h, l) ? bricks : grid_bricks(&h, l);
    if (pool > POOL_MAX) pool = POOL_MAX;
    if (pool > (SIZE_MAX - head) / h.brick_bytes) return 0;
    return (size_t)(head + pool * h.brick_bytes);
}

int vod_volume_init(vod_volume **out, void *arena, size_t bytes,
                    const uint32_t dims[3], uint32_t bits, uint32_t sbrick)
{
    if (check_args(dims, bits, sbrick) || ((uintptr_t)arena & 7)) return -EINVAL;
    struct vod_volume h;
    uint64_t head = plan(&h, dims, bits, sbrick);
    if (head > bytes) return -ENOSPC;
    uint64_t cap = (bytes - head) / h.brick_bytes;
    h.pool_cap = (uint32_t)(cap > POOL_MAX ? POOL_MAX : cap);
    memset((uint8_t *)arena + sizeof h, 0, head - sizeof h);
    memcpy(arena, &h, sizeof h);
    *out = arena;
    return 0;
}

vod_volume *vod_volume_view(void *arena)
{
    vod_volume *v = arena;
    return v && v->magic == VOL_MAGIC ? v : NULL;
}

void vod_volume_get_info(const vod_volume *v, vod_volume_info *out)
{
    memcpy(out->dims, v->dims, sizeof out->dims);
    out->bits = v->bits;
    out->sbrick = v->sbrick;
    out->depth = v->depth;
    out->pool_cap = v->pool_cap;
    out->pool_used = atomic_load_explicit(&v->pool_used, memory_order_relaxed);
    out->level0_bricks = atomic_load_explicit(&v->pool_l0, memory_order_relaxed);
    out->mip_channel = v->mip_channel;
    out->bytes_used = v->pool_off + (uint64_t)out->pool_used * v->brick_bytes;
}

/* ---- bricks and voxels ---- */

static uint32_t *table(const vod_volume *v, int l)
{
    return (uint32_t *)((uint8_t *)v + v->table_off[l]);
}

int vod_volume_check(const vod_volume *v, size_t bytes)
{
    struct vod_volume h;
    if (bytes < sizeof h || v->magic != VOL_MAGIC ||
        check_args(v->dims, v->bits, v->sbrick))
        return -EINVAL;
    uint64_t head = plan(&h, v->dims, v->bits, v->sbrick);
    if (head > bytes || h.slog2 != v->slog2 || h.depth != v->depth ||
        memcmp(h.grid, v->grid, sizeof h.grid) ||
        memcmp(h.table_off, v->table_off, sizeof h.table_off) ||
        h.pool_off != v->pool_off || h.brick_bytes != v->brick_bytes)
        return -EINVAL;
    uint32_t used = atomic_load_explicit(&v->pool_used, memory_order_relaxed);
    uint32_t l0 = atomic_load_explicit(&v->pool_l0, memory_order_relaxed);
    if (v->pool_cap > (bytes - head) / h.brick_bytes || used > v->pool_cap ||
        l0 > used || v->mip_channel != 0)
        return -EINVAL;
    /* every level: the mip levels built by column are in the tables too */
    for (int l = 0; l <= v->depth; l++) {
        const uint32_t *t = table(v, l);
        for (uint64_t i = 0, n = grid_bricks(v, l); i < n; i++)
            if (is_alloc(t[i]) && t[i] > used) return -EINVAL;
    }
    return v->low_levels == 0 ? 0 : -EINVAL;
}

/* The entry of brick b of level l; 0 (empty) outside the grid. */
static uint32_t entry_at(const vod_volume *v, int l, const uint32_t b[3])
{
    const uint32_t *g = v->grid[l];
    if (b[0] >= g[0] || b[1] >= g[1] || b[2] >= g[2]) return 0;
    return table(v, l)[((uint64_t)b[2] * g[1] + b[1]) * g[0] + b[0]];
}

static uint8_t *brick_data(const vod_volume *v, uint32_t e)
{
    return (uint8_t *)v + v->pool_off + (uint64_t)(e - 1) * v->brick_bytes;
}

static size_t vox_index(const vod_volume *v, uint32_t x, uint32_t y, uint32_t z)
{
    return ((size_t)z * v->sbrick + y) * v->sbrick + x;
}

static uint32_t vox_get(const vod_volume *v, const uint8_t *d, size_t i)
{
    return v->bits == 8 ? d[i] : ((const uint32_t *)(const void *)d)[i];
}

static void vox_put(const vod_volume *v, uint8_t *d, size_t i, uint32_t val)
{
    if (v->bits == 8) d[i] = (uint8_t)val;
    else ((uint32_t *)(void *)d)[i] = val;
}

static void brick_set_all(const vod_volume *v, uint8_t *d, uint32_t val)
{
    if (v->bits == 8) {
        memset(d, (int)val, v->brick_bytes);
        return;
    }
    uint32_t *w = (uint32_t *)(void *)d;
    for (uint64_t i = 0; i < v->brick_bytes / 4; i++) w[i] = val;
}

/* A new pool brick holding val everywhere (fill), or anything (the caller
 * writes every voxel); its entry, or 0 when full. */
static uint32_t pool_take(vod_volume *v, uint32_t val, bool fill)
{
    uint32_t e = atomic_fetch_add_explicit(&v->pool_used, 1, memory_order_relaxed) + 1;
    if (e > v->pool_cap) {
        /* full: give the count back (every other taker fails too until
         * the count is below the cap again) */
        atomic_fetch_sub_explicit(&v->pool_used, 1, memory_order_relaxed);
        return 0;
    }
    if (fill) brick_set_all(v, brick_data(v, e), val);
    return e;
}

/* Writing voxels makes the mip levels stale: give their bricks back. */
static void drop_mips(vod_volume *v)
{
    /* The mip bricks were taken after every level-0 one: the pool goes
     * back to where it stood before them.  (Not to pool_l0: concurrent
     * writers, or one killed between taking a brick and counting it, may
     * leave level-0 bricks above that count.) */
    if (v->mip_channel)
        atomic_store_explicit(&v->pool_used, v->mip_base, memory_order_relaxed);
    v->mip_channel = 0;
}

/* A brick with memory may hold only zeros from now on. */
static void may_zero(vod_volume *v)
{
    atomic_store_explicit(&v->zero_bricks, 1, memory_order_relaxed);
}

/* The data of level-0 brick b, allocated (from empty or uniform) if need
 * be; whole: the caller writes every voxel (a new brick is not filled). */
static int level0_data(vod_volume *v, const uint32_t b[3], bool whole, uint8_t **out)
{
    const uint32_t *g = v->grid[0];
    uint32_t *e = &table(v, 0)[((uint64_t)b[2] * g[1] + b[1]) * g[0] + b[0]];
    if (!is_alloc(*e)) {
        uint32_t n = pool_take(v, *e & ~ENTRY_UNIFORM, !whole);
        if (!n) return -ENOMEM;
        atomic_fetch_add_explicit(&v->pool_l0, 1, memory_order_relaxed);
        *e = n;
    }
    *out = brick_data(v, *e);
    return 0;
}

static int check_value(const vod_volume *v, uint32_t value)
{
    return v->bits == 8 && value > 255 ? -EINVAL : 0;
}

/* Voxels are about to change: every mip level is stale. */
static void stale_mips(vod_volume *v)
{
    drop_mips(v);
    v->low_levels = 0;
}

int vod_volume_set(vod_volume *v, uint32_t x, uint32_t y, uint32_t z,
                   uint32_t value)
{
    if (x >= v->dims[0] || y >= v->dims[1] || z >= v->dims[2] ||
        check_value(v, value))
        return -EINVAL;
    stale_mips(v);
    uint32_t s = v->slog2, m = v->sbrick - 1, b[3] = {x >> s, y >> s, z >> s};
    uint32_t e = entry_at(v, 0, b);
    if (e == 0 ? value == 0 : is_uniform(e) && (e & ~ENTRY_UNIFORM) == value)
        return 0;
    if (value == 0) may_zero(v); /* into memory: e is allocated */
    uint8_t *d;
    int rc = level0_data(v, b, false, &d);
    if (rc == 0) vox_put(v, d, vox_index(v, x & m, y & m, z & m), value);
    return rc;
}

uint32_t vod_volume_get(const vod_volume *v, uint32_t x, uint32_t y, uint32_t z)
{
    if (x >= v->dims[0] || y >= v->dims[1] || z >= v->dims[2]) return 0;
    uint32_t s = v->slog2, m = v->sbrick - 1, b[3] = {x >> s, y >> s, z >> s};
    uint32_t e = entry_at(v, 0, b);
    if (!is_alloc(e)) return e & ~ENTRY_UNIFORM;
    return vox_get(v, brick_data(v, e), vox_index(v, x & m, y & m, z & m));
}

int vod_volume_box_uniform(const vod_volume *v, const int64_t lo[3], uint32_t n,
                           uint32_t *value)
{
    int64_t a0[3], a1[3]; /* the box clamped to dims, [a0, a1) */
    int outside = 0;
    for (int a = 0; a < 3; a++) {
        a0[a] = lo[a] < 0 ? 0 : lo[a];
        a1[a] = lo[a] + n > v->dims[a] ? v->dims[a] : lo[a] + n;
        outside |= lo[a] < 0 || lo[a] + n > v->dims[a];
        if (a0[a] >= a1[a]) return *value = 0, 1; /* wholly outside */
    }
    int64_t found = outside ? 0 : -1;
    uint32_t s = v->slog2, b[3];
    for (b[2] = (uint32_t)(a0[2] >> s); b[2] <= (uint32_t)((a1[2] - 1) >> s); b[2]++)
        for (b[1] = (uint32_t)(a0[1] >> s); b[1] <= (uint32_t)((a1[1] - 1) >> s); b[1]++)
            for (b[0] = (uint32_t)(a0[0] >> s); b[0] <= (uint32_t)((a1[0] - 1) >> s); b[0]++) {
                uint32_t e = entry_at(v, 0, b);
                if (is_alloc(e)) return 0;
                int64_t val = e & ~ENTRY_UNIFORM;
                if (found >= 0 && val != found) return 0;
                found = val;
            }
    *value = (uint32_t)found;
    return 1;
}

/* Brick b wholly inside the box: one entry, or the brick's data when it has
 * memory already (or the value cannot be a uniform entry). */
static int fill_whole(vod_volume *v, const uint32_t b[3], uint32_t value)
{
    const uint32_t *g = v->grid[0];
    uint32_t *e = &table(v, 0)[((uint64_t)b[2] * g[1] + b[1]) * g[0] + b[0]];
    if (!is_alloc(*e) && value < ENTRY_UNIFORM) {
        *e = value ? ENTRY_UNIFORM | value : 0;
        return 0;
    }
    if (value == 0) may_zero(v);
    uint8_t *d;
    int rc = level0_data(v, b, false, &d);
    if (rc == 0) brick_set_all(v, d, value);
    return rc;
}

/* The part [lo, hi) (brick-local) of brick b. */
static int fill_part(vod_volume *v, const uint32_t b[3], const uint32_t lo[3],
                     const uint32_t hi[3], uint32_t value)
{
    uint32_t e = entry_at(v, 0, b);
    if (e == 0 ? value == 0 : is_uniform(e) && (e & ~ENTRY_UNIFORM) == value)
        return 0;
    if (value == 0) may_zero(v);
    uint8_t *d;
    int rc = level0_data(v, b, false, &d);
    for (uint32_t z = lo[2]; z < hi[2] && !rc; z++)
        for (uint32_t y = lo[1]; y < hi[1]; y++)
            for (uint32_t x = lo[0]; x < hi[0]; x++)
                vox_put(v, d, vox_index(v, x, y, z), value);
    return rc;
}

int vod_volume_fill(vod_volume *v, const uint32_t lo[3], const uint32_t hi[3],
                    uint32_t value)
{
    for (int a = 0; a < 3; a++)
        if (lo[a] >= hi[a] || hi[a] > v->dims[a]) return -EINVAL;
    if (check_value(v, value)) return -EINVAL;
    stale_mips(v);
    uint32_t s = v->slog2, S = v->sbrick, b[3];
    for (b[2] = lo[2] >> s; b[2] <= (hi[2] - 1) >> s; b[2]++)
        for (b[1] = lo[1] >> s; b[1] <= (hi[1] - 1) >> s; b[1]++)
            for (b[0] = lo[0] >> s; b[0] <= (hi[0] - 1) >> s; b[0]++) {
                uint32_t l[3], h[3];
                bool whole = true;
                for (int a = 0; a < 3; a++) {
                    uint32_t o = b[a] << s;
                    l[a] = lo[a] > o ? lo[a] - o : 0;
                    h[a] = hi[a] - o < S ? hi[a] - o : S;
                    whole = whole && l[a] == 0 && h[a] == S;
                }
                int rc = whole ? fill_whole(v, b, value)
                               : fill_part(v, b, l, h, value);
                if (rc) return rc;
            }
    return 0;
}

/* The value every voxel of the S^3 brick d holds, or -1 when they differ
 * (or the one value cannot be a uniform entry). */
static int64_t brick_uniform_value(const vod_volume *v, const uint8_t *d)
{
    uint64_t n = (uint64_t)v->sbrick * v->sbrick * v->sbrick;
    uint32_t first = vox_get(v, d, 0);
    if (first >= ENTRY_UNIFORM) return -1;
    if (v->bits == 8) { /* 8 voxels a compare: S^3 is a multiple of 8 */
        uint64_t all = first * 0x0101010101010101ull, w;
        for (uint64_t i = 0; i < n; i += 8)
            if (memcpy(&w, d + i, 8), w != all) return -1;
    } else {
        const uint32_t *w = (const uint32_t *)(const void *)d;
        for (uint64_t i = 1; i < n; i++)
            if (w[i] != first) return -1;
    }
    return first;
}

int vod_volume_put_brick(vod_volume *v, const uint32_t b[3], const void *voxels)
{
    const uint32_t *g = v->grid[0];
    if (b[0] >= g[0] || b[1] >= g[1] || b[2] >= g[2]) return -EINVAL;
    assert(v->mip_channel == 0 && v->low_levels == 0 &&
           "put_brick runs before prepare() and vod_volume_mips_low()");
    uint32_t *e = &table(v, 0)[((uint64_t)b[2] * g[1] + b[1]) * g[0] + b[0]];
    int64_t u = brick_uniform_value(v, voxels);
    if (u >= 0 && !is_alloc(*e)) {
        *e = u ? ENTRY_UNIFORM | (uint32_t)u : 0;
        return 0;
    }
    if (u == 0) may_zero(v); /* zeros into the memory the brick has */
    uint8_t *d;
    int rc = level0_data(v, b, true, &d);
    if (rc == 0) memcpy(d, voxels, v->brick_bytes);
    return rc;
}

int vod_volume_put_uniform(vod_volume *v, const uint32_t b[3], uint32_t value)
{
    const uint32_t *g = v->grid[0];
    if (b[0] >= g[0] || b[1] >= g[1] || b[2] >= g[2] || check_value(v, value))
        return -EINVAL;
    assert(v->mip_channel == 0 && v->low_levels == 0 &&
           "put_uniform runs before prepare() and vod_volume_mips_low()");
    return fill_whole(v, b, value);
}

/* ---- mip levels ---- */

static uint64_t load64(const uint8_t *p)
{
    uint64_t w; /* byte k in bits 8k .. 8k + 7 */
    memcpy(&w, p, 8);
#if __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
    w = __builtin_bswap64(w);
#endif
    return w;
}

static uint32_t channels_of(const vod_volume *v)
{
    return 1u << VOXEL_CH_OCCUPANCY |
           (v->bits == 8 ? 1u << VOXEL_CH_DENSITY
                         : 1u << VOXEL_CH_SURFACE | 1u << VOXEL_CH_DISTANCE);
}

typedef struct {
    vod_volume *v;
    int l, ch;          /* building level l from level l-1 */
    uint32_t *out;      /* S^3 parent voxels */
    uint8_t *out8;      /* the same memory, as bytes: 8-bit volumes' */
    bool nonempty;      /* the parent's footprint holds a voxel */
} mip_ctx;

/* The octant of the parent from child brick d, any voxel width and
 * channel; returns the OR of the child's voxels. */
static uint32_t mip_octant_any(mip_ctx *m, const uint8_t *d, uint32_t ox,
                               uint32_t oy, uint32_t oz)
{
    const vod_volume *v = m->v;
    uint32_t half = v->sbrick / 2, c[8], any = 0;
    for (uint32_t z = 0; z < half; z++)
        for (uint32_t y = 0; y < half; y++)
            for (uint32_t x = 0; x < half; x++) {
                for (unsigned i = 0; i < 8; i++) {
                    c[i] = vox_get(v, d, vox_index(v, 2 * x + (i & 1u),
                                                   2 * y + (i >> 1 & 1u),
                                                   2 * z + (i >> 2 & 1u)));
                    any |= c[i];
                }
                m->out[vox_index(v, ox + x, oy + y, oz + z)] = vod_downsample(m->ch, c);
            }
    return any;
}

/* Channel 1 of 4 parent voxels from the 8 x-children of 4 rows (a..d, 8
 * bytes each): out[k] = 1 when a byte 2k or 2k+1 of any row is non-zero.
 * Returns the OR of the children. */
static uint64_t or_pairs4(const uint8_t *a, const uint8_t *b, const uint8_t *c,
                          const uint8_t *d, uint8_t *out)
{
    uint64_t w = load64(a) | load64(b) | load64(c) | load64(d);
    uint64_t p = w | w >> 8; /* byte 2k: the OR of children 2k and 2k + 1 */
    const uint64_t low7 = 0x7f7f7f7f7f7f7f7full;
    uint64_t t = ((((p & low7) + low7) | p) & 0x0080008000800080ull) >> 7;
    uint32_t q = (uint32_t)((t & 1u) | (t >> 8 & 0x100u) | (t >> 16 & 0x10000u) |
                            (t >> 24 & 0x1000000u));
    for (int k = 0; k < 4; k++) out[k] = (uint8_t)(q >> (8 * k));
    return w;
}

#ifdef __SSE2__
/* or_pairs4 for 8 parent voxels (16 bytes of each row), with SSE2;
 * returns whether any child is non-zero. */
static bool or_pairs8(const uint8_t *a, const uint8_t *b, const uint8_t *c,
                      const uint8_t *d, uint8_t *out)
{
    __m128i w = _mm_or_si128(
        _mm_or_si128(_mm_loadu_si128((const __m128i *)a), _mm_loadu_si128((const __m128i *)b)),
        _mm_or_si128(_mm_loadu_si128((const __m128i *)c), _mm_loadu_si128((const __m128i *)d)));
    /* each 16-bit lane: a pair of children, 0 or not */
    __m128i zero = _mm_setzero_si128(), empty = _mm_cmpeq_epi16(w, zero);
    __m128i one = _mm_andnot_si128(empty, _mm_set1_epi16(1));
    _mm_storel_epi64((__m128i *)out, _mm_packus_epi16(one, one));
    return _mm_movemask_epi8(empty) != 0xffff;
}
#endif

/* The same for 8-bit voxels and channels 1 and 2 (vod_downsample's rules
 * written out: any child non-zero, or the mean rounded half up), the mesh
 * and CSG volumes' common case, into the parent's bytes m->out8. */
static uint32_t mip_octant8(mip_ctx *m, const uint8_t *d, uint32_t ox,
                            uint32_t oy, uint32_t oz)
{
    const vod_volume *v = m->v;
    size_t S = v->sbrick, half = S / 2, SS = S * S;
    uint64_t any = 0;
    for (size_t z = 0; z < half; z++)
        for (size_t y = 0; y < half; y++) {
            const uint8_t *r0 = d + (2 * z * S + 2 * y) * S, *r1 = r0 + S;
            const uint8_t *r2 = r0 + SS, *r3 = r1 + SS;
            uint8_t *out = m->out8 + ((oz + z) * S + oy + y) * S + ox;
            size_t x = 0;
#ifdef __SSE2__
            if (m->ch == VOXEL_CH_OCCUPANCY)
                for (; x + 8 <= half; x += 8)
                    any |= or_pairs8(r0 + 2 * x, r1 + 2 * x, r2 + 2 * x, r3 + 2 * x, out + x);
#endif
            if (m->ch == VOXEL_CH_OCCUPANCY)
                for (; x + 4 <= half; x += 4) /* 8 children a word */
                    any |= or_pairs4(r0 + 2 * x, r1 + 2 * x, r2 + 2 * x, r3 + 2 * x,
                                     out + x);
            for (; x < half; x++) {
                size_t i = 2 * x;
                uint32_t ors = r0[i] | r0[i + 1] | r1[i] | r1[i + 1] | r2[i] |
                              r2[i + 1] | r3[i] | r3[i + 1];
                any |= ors;
                out[x] = (uint8_t)(m->ch == VOXEL_CH_DENSITY
                                       ? (r0[i] + r0[i + 1] + r1[i] + r1[i + 1] + r2[i] +
                                          r2[i + 1] + r3[i] + r3[i + 1] + 4u) / 8u
                                       : ors != 0);
            }
        }
    return any != 0;
}

/* The octant of the parent that child entry e (level l-1) covers, from
 * (ox, oy, oz) in the parent. */
static void mip_octant(mip_ctx *m, uint32_t e, uint32_t ox, uint32_t oy,
                       uint32_t oz)
{
    const vod_volume *v = m->v;
    uint32_t S = v->sbrick, half = S / 2, c[8];
    if (!is_alloc(e)) {
        for (int i = 0; i < 8; i++) c[i] = e & ~ENTRY_UNIFORM;
        uint32_t d = vod_downsample(m->ch, c);
        m->nonempty = m->nonempty || e != 0;
        for (uint32_t z = 0; z < half; z++)
            for (uint32_t y = 0; y < half; y++) {
                size_t at = vox_index(v, ox, oy + y, oz + z);
                if (v->bits == 8) memset(m->out8 + at, (int)d, half);
                else
                    for (uint32_t x = 0; x < half; x++) m->out[at + x] = d;
            }
        return;
    }
    const uint8_t *d = brick_data(v, e);
    /* 8-bit voxels give channels 1 and 2 only (channels_of) */
    uint32_t any = v->bits == 8 ? mip_octant8(m, d, ox, oy, oz)
                                : mip_octant_any(m, d, ox, oy, oz);
    /* a mip child with memory has a non-empty footprint by construction;
     * a level-0 one only if some voxel is non-zero */
    m->nonempty = m->nonempty || m->l > 1 || any;
}

/* The parent of 8 children that are all the same entry without memory
 * (all empty, or all uniform with one value), without visiting a voxel:
 * what the general path below gives for them.  false when they differ or
 * the parent's value cannot be a uniform entry. */
static bool mip_same_children(mip_ctx *m, const uint32_t p[3], uint32_t *entry)
{
    uint32_t e0 = 0;
    for (unsigned i = 0; i < 8; i++) {
        uint32_t c[3] = {2 * p[0] + (i & 1u), 2 * p[1] + (i >> 1 & 1u),
                         2 * p[2] + (i >> 2 & 1u)};
        uint32_t e = entry_at(m->v, m->l - 1, c);
        if (is_alloc(e) || (i && e != e0)) return false;
        e0 = e;
    }
    if (e0 == 0) {
        *entry = 0;
        return true;
    }
    uint32_t c[8];
    for (int i = 0; i < 8; i++) c[i] = e0 & ~ENTRY_UNIFORM;
    uint32_t d = vod_downsample(m->ch, c);
    if (d >= ENTRY_UNIFORM) return false;
    *entry = ENTRY_UNIFORM | d;
    return true;
}

/* Brick p of level m->l from its 8 children, into *entry (whose memory
 * is used again when it has some: a column built a second time). */
static int mip_brick(mip_ctx *m, const uint32_t p[3], uint32_t *entry)
{
    vod_volume *v = m->v;
    uint32_t half = v->sbrick / 2, old = *entry;
    if (mip_same_children(m, p, entry)) return 0;
    m->nonempty = false;
    for (unsigned i = 0; i < 8; i++) {
        uint32_t c[3] = {2 * p[0] + (i & 1u), 2 * p[1] + (i >> 1 & 1u),
                         2 * p[2] + (i >> 2 & 1u)};
        mip_octant(m, entry_at(v, m->l - 1, c), (i & 1u) * half,
                   (i >> 1 & 1u) * half, (i >> 2 & 1u) * half);
    }
    *entry = 0;
    if (!m->nonempty) return 0;
    uint64_t n = (uint64_t)v->sbrick * v->sbrick * v->sbrick, i;
    int64_t u = brick_uniform_value(v, v->bits == 8 ? m->out8 : (const uint8_t *)m->out);
    if (u >= 0) {
        *entry = ENTRY_UNIFORM | (uint32_t)u;
        return 0;
    }
    uint32_t e = is_alloc(old) ? old : pool_take(v, 0, false); /* written whole below */
    if (!e) return -ENOMEM;
    uint8_t *d = brick_data(v, e);
    if (v->bits == 8) memcpy(d, m->out8, n); /* the bytes are the voxels */
    else
        for (i = 0; i < n; i++) vox_put(v, d, (size_t)i, m->out[i]);
    *entry = e;
    return 0;
}

static int build_level(mip_ctx *m)
{
    vod_volume *v = m->v;
    const uint32_t *g = v->grid[m->l];
    uint32_t *t = table(v, m->l), p[3];
    uint64_t k = 0;
    for (p[2] = 0; p[2] < g[2]; p[2]++)
        for (p[1] = 0; p[1] < g[1]; p[1]++)
            for (p[0] = 0; p[0] < g[0]; p[0]++, k++) {
                int rc = mip_brick(m, p, &t[k]);
                if (rc) return rc;
            }
    return 0;
}

/* Levels 1..levels of the level-`levels` brick columns [lo, hi), every z. */
static int build_columns(mip_ctx *m, int levels, const uint32_t lo[2],
                         const uint32_t hi[2])
{
    vod_volume *v = m->v;
    int rc = 0;
    for (m->l = 1; m->l <= levels && !rc; m->l++) {
        const uint32_t *g = v->grid[m->l];
        uint32_t *t = table(v, m->l), p[3], k = (uint32_t)(levels - m->l);
        uint32_t x1 = hi[0] << k < g[0] ? hi[0] << k : g[0];
        uint32_t y1 = hi[1] << k < g[1] ? hi[1] << k : g[1];
        for (p[2] = 0; p[2] < g[2] && !rc; p[2]++)
            for (p[1] = lo[1] << k; p[1] < y1 && !rc; p[1]++)
                for (p[0] = lo[0] << k; p[0] < x1 && !rc; p[0]++)
                    rc = mip_brick(m, p, &t[((uint64_t)p[2] * g[1] + p[1]) * g[0] + p[0]]);
    }
    return rc;
}

static bool mip_args_ok(const vod_volume *v, int channel, int levels)
{
    return channel >= 0 && channel <= 31 && (channels_of(v) >> channel & 1u) &&
           levels >= 1 && levels <= v->depth;
}

int vod_volume_mip_columns(vod_volume *v, int channel, int levels,
                           const uint32_t lo[2], const uint32_t hi[2])
{
    if (!mip_args_ok(v, channel, levels)) return -EINVAL;
    for (int a = 0; a < 2; a++) /* hi is clipped to the grid */
        if (lo[a] >= hi[a] || lo[a] >= v->grid[levels][a]) return -EINVAL;
    assert(v->mip_channel == 0 && v->low_levels == 0 &&
           "mip_columns runs before prepare() and vod_volume_mips_low()");
    uint64_t n = (uint64_t)v->sbrick * v->sbrick * v->sbrick;
    mip_ctx m = {.v = v, .ch = channel, .out = malloc(n * sizeof *m.out)};
    if (!m.out) return -ENOMEM;
    m.out8 = (uint8_t *)m.out;
    int rc = build_columns(&m, levels, lo, hi);
    free(m.out);
    return rc;
}

int vod_volume_mips_low(vod_volume *v, int channel, int levels)
{
    if (!mip_args_ok(v, channel, levels) || v->mip_channel) return -EINVAL;
    v->low_channel = channel;
    v->low_levels = levels;
    return 0;
}

static int vol_prepare(vod_source *s, const vod_layout *L, int channel)
{
    (void)L; /* every level is built: the writer needs at most depth */
    vod_volume *v = s->ctx;
    if (channel < 0 || channel > 31 || !(channels_of(v) >> channel & 1u))
        return -EINVAL;
    if (v->mip_channel == channel) return 0;
    drop_mips(v);
    /* the levels built by column, when they are this channel's */
    int first = v->low_levels && v->low_channel == channel ? v->low_levels + 1 : 1;
    if (first == 1) v->low_levels = 0; /* another channel's: built over */
    v->mip_base = atomic_load_explicit(&v->pool_used, memory_order_relaxed);
    uint64_t n = (uint64_t)v->sbrick * v->sbrick * v->sbrick;
    mip_ctx m = {.v = v, .ch = channel, .out = malloc(n * sizeof *m.out)};
    m.out8 = (uint8_t *)m.out;
    int rc = m.out ? 0 : -ENOMEM;
    for (m.l = first; m.l <= v->depth && !rc; m.l++) {
        memset(table(v, m.l), 0, 4 * grid_bricks(v, m.l));
        rc = build_level(&m);
    }
    free(m.out);
    v->mip_channel = channel;
    if (rc) drop_mips(v); /* the levels built so far go back too */
    return rc;
}

/* ---- the source ---- */

/* The layout's channel (an unspecified one from its voxel width). */
static int channel_of(const vod_layout *L)
{
    if (L->channel) return L->channel;
    return L->voxel_bits == 1 ? VOXEL_CH_OCCUPANCY : L->voxel_bits == 8 ? VOXEL_CH_DENSITY
                                                                        : VOXEL_CH_SURFACE;
}

/* Some voxel of level-0 brick e in the box [lo, lo + side) is non-zero. */
static bool any_nonzero(const vod_volume *v, uint32_t e, const uint32_t lo[3],
                        uint32_t side)
{
    if (!is_alloc(e)) return e != 0;
    if (side == v->sbrick &&
        !atomic_load_explicit(&v->zero_bricks, memory_order_relaxed))
        return true; /* no zero was ever written into a brick's memory */
    const uint8_t *d = brick_data(v, e);
    for (uint32_t z = lo[2]; z < lo[2] + side; z++)
        for (uint32_t y = lo[1]; y < lo[1] + side; y++)
            for (uint32_t x = lo[0]; x < lo[0] + side; x++)
                if (vox_get(v, d, vox_index(v, x, y, z))) return true;
    return false;
}

/* Node n's full-resolution cube (2^k voxels per axis) holds a voxel.  A
 * cube of at least a storage brick is one brick of the level m where
 * bricks are that size; a smaller one lies in one level-0 brick. */
static bool footprint_nonempty(const vod_volume *v, const vod_layout *L,
                               const vod_node *n)
{
    uint32_t b[3] = {n->bx, n->by, n->bz}, zero[3] = {0, 0, 0};
    int k = (int)(L->brick_log2 + n->level), m = k - (int)v->slog2;
    if (m >= 0) {
        if (m > v->depth) { /* a brick larger than the whole volume */
            if (b[0] | b[1] | b[2]) return false;
            m = v->depth;
        }
        if (m >= 1 && !v->mip_channel) return true; /* not prepared: cannot tell */
        uint32_t e = entry_at(v, m, b);
        return m >= 1 ? e != 0 : any_nonzero(v, e, zero, v->sbrick);
    }
    uint32_t lo[3], sb[3], mask = v->sbrick - 1;
    for (int a = 0; a < 3; a++) {
        lo[a] = (b[a] << k) & mask;
        sb[a] = (b[a] << k) >> v->slog2;
    }
    return any_nonzero(v, entry_at(v, 0, sb), lo, 1u << k);
}

/* Every storage brick under node n's level-l brick is uniform with one
 * value (a brick past the grid is 0); in the channel's terms. */
static bool brick_uniform(const vod_volume *v, const vod_layout *L,
                          const vod_node *n, uint32_t *value)
{
    int l = (int)n->level, ch = channel_of(L);
    if (l > v->depth || (l >= 1 && v->mip_channel != ch)) return false;
    uint32_t B = L->brick, per = B >= v->sbrick ? B >> v->slog2 : 1, b0[3], b[3];
    b0[0] = (n->bx * B) >> v->slog2;
    b0[1] = (n->by * B) >> v->slog2;
    b0[2] = (n->bz * B) >> v->slog2;
    bool first = true;
    for (uint32_t z = 0; z < per; z++)
        for (uint32_t y = 0; y < per; y++)
            for (uint32_t x = 0; x < per; x++) {
                b[0] = b0[0] + x, b[1] = b0[1] + y, b[2] = b0[2] + z;
                uint32_t e = entry_at(v, l, b);
                if (is_alloc(e)) return false;
                uint32_t u = e & ~ENTRY_UNIFORM;
                if (l == 0 && ch == VOXEL_CH_OCCUPANCY) u = u != 0;
                if (!first && u != *value) return false;
                *value = u;
                first = false;
            }
    return true;
}

static int vol_region(const vod_source *s, const vod_layout *L, vod_node *n)
{
    const vod_volume *v = s->ctx;
    n->value = 0;
    n->ref = 0;
    if (!footprint_nonempty(v, L, n)) return VOD_REGION_EMPTY;
    return brick_uniform(v, L, n, &n->value) ? VOD_REGION_UNIFORM : VOD_REGION_MIXED;
}

/* Voxel i of a raw brick (spec section 5) := val. */
static inline void raw_put(uint8_t *raw, uint32_t bits, size_t i, uint32_t val)
{
    if (bits == 32) vod_put32(raw + 4 * i, val);
    else if (bits == 8) raw[i] = (uint8_t)val;
    else if (val) raw[i >> 3] |= (uint8_t)(1u << (i & 7));
}

/* Bit k set where byte k of s[0, 8) is non-zero, without a branch or a
 * loop: each byte's high bit is set when it is non-zero (its low 7 bits
 * plus 0x7f carry into it, or it was set), then the multiplication gathers
 * the 8 high bits (moved to bit 0 of their bytes) into the top byte. */
static inline uint8_t nonzero_bits8(const uint8_t *s)
{
    uint64_t w = load64(s);
    const uint64_t low7 = 0x7f7f7f7f7f7f7f7full, high = 0x8080808080808080ull;
    uint64_t t = (((w & low7) + low7) | w) & high;
    return (uint8_t)(((t >> 7) * 0x0102040810204080ull) >> 56);
}

/* n voxels of a row of 8-bit voxels (src; NULL: all u) as bits of a
 * channel-1 raw brick from bit r on: whole bytes at a time where they are
 * aligned (a row of a 16^3 brick is two). */
static void copy_row_bits8(uint8_t *raw, size_t r, const uint8_t *src, uint32_t u,
                           uint32_t n)
{
    uint32_t x = 0;
    for (; x < n && ((r + x) & 7); x++)
        if (src ? src[x] : u) raw[(r + x) >> 3] |= (uint8_t)(1u << ((r + x) & 7));
    for (; x + 8 <= n; x += 8)
        raw[(r + x) >> 3] |= src ? nonzero_bits8(src + x) : u ? 0xff : 0;
    for (; x < n; x++)
        if (src ? src[x] : u) raw[(r + x) >> 3] |= (uint8_t)(1u << ((r + x) & 7));
}

/* The box [a0, a1) of 8-bit voxels (storage brick data d, low corner o;
 * NULL: all u, not 0) as channel-1 bits of the raw brick of side B whose
 * low corner is lo, when every row starts and ends on a byte of it (the
 * usual case: bricks of 8 voxels or more): whole bytes, no bit offsets. */
static void copy_bytes_bits8(const vod_volume *v, uint32_t B, const uint8_t *d,
                             const uint32_t o[3], const uint32_t lo[3],
                             const uint32_t a0[3], const uint32_t a1[3], uint8_t *raw)
{
    uint32_t n8 = (a1[0] - a0[0]) / 8;
    size_t S = v->sbrick, row = B / 8; /* bytes from a row to the next, in raw */
    uint8_t *out0 = raw + (((size_t)(a0[2] - lo[2]) * B + (a0[1] - lo[1])) * B + (a0[0] - lo[0])) / 8;
    size_t s0 = vox_index(v, a0[0] - o[0], a0[1] - o[1], a0[2] - o[2]);
    /* rows and slices stepped, not recomputed: this is the writer's fill of
     * every mesh and CSG occupancy brick */
    for (uint32_t z = a0[2]; z < a1[2]; z++, out0 += row * B, s0 += S * S) {
        uint8_t *out = out0;
        size_t s = s0;
        for (uint32_t y = a0[1]; y < a1[1]; y++, out += row, s += S) {
            if (!d) {
                memset(out, 0xff, n8);
                continue;
            }
            const uint8_t *src = d + s;
            uint32_t k = 0;
#ifdef __SSE2__
            /* 16 voxels at once: a byte compare and its mask, bit i voxel i */
            for (; k + 2 <= n8; k += 2) {
                __m128i x = _mm_loadu_si128((const __m128i *)(src + 8 * k));
                unsigned m = ~(unsigned)_mm_movemask_epi8(_mm_cmpeq_epi8(x, _mm_setzero_si128()));
                out[k] |= (uint8_t)m;
                out[k + 1] |= (uint8_t)(m >> 8);
            }
#endif
            for (; k < n8; k++) out[k] |= nonzero_bits8(src + 8 * k);
        }
    }
}

/* The part of storage brick (entry e, low corner o, level-l voxels) that
 * lies in the raw brick whose low corner is lo. */
static void copy_part(const vod_volume *v, const vod_layout *L, uint32_t e,
                      const uint32_t o[3], const uint32_t lo[3], uint8_t *raw)
{
    uint32_t B = L->brick, S = v->sbrick, a0[3], a1[3];
    for (int a = 0; a < 3; a++) {
        a0[a] = o[a] > lo[a] ? o[a] : lo[a];
        a1[a] = o[a] + S < lo[a] + B ? o[a] + S : lo[a] + B;
    }
    const uint8_t *d = is_alloc(e) ? brick_data(v, e) : NULL;
    uint32_t u = e & ~ENTRY_UNIFORM;
    if (L->voxel_bits == 1 && v->bits == 8 && B % 8 == 0 && (a0[0] - lo[0]) % 8 == 0 &&
        (a1[0] - a0[0]) % 8 == 0) {
        copy_bytes_bits8(v, B, d, o, lo, a0, a1, raw);
        return;
    }
    for (uint32_t z = a0[2]; z < a1[2]; z++)
        for (uint32_t y = a0[1]; y < a1[1]; y++) {
            size_t r = ((size_t)(z - lo[2]) * B + (y - lo[1])) * B + (a0[0] - lo[0]);
            size_t s = vox_index(v, a0[0] - o[0], y - o[1], z - o[2]);
            uint32_t n = a1[0] - a0[0];
            if (L->voxel_bits == 1 && v->bits == 8)
                copy_row_bits8(raw, r, d ? d + s : NULL, u, n);
            else if (L->voxel_bits == 8 && v->bits == 8) /* a row at a time */
                d ? memcpy(raw + r, d + s, n) : memset(raw + r, (int)u, n);
            else
                for (uint32_t x = 0; x < n; x++)
                    raw_put(raw, L->voxel_bits, r + x, d ? vox_get(v, d, s + x) : u);
        }
}

static int vol_fill(const vod_source *s, const vod_layout *L, const vod_node *n,
                    uint8_t *raw)
{
    const vod_volume *v = s->ctx;
    int l = (int)n->level, ch = channel_of(L);
    if (!(channels_of(v) >> ch & 1u) || l > v->depth ||
        (l >= 1 && v->mip_channel != ch))
        return -EINVAL;
    uint32_t B = L->brick, lo[3] = {n->bx * B, n->by * B, n->bz * B}, b[3], o[3];
    const uint32_t *g = v->grid[l];
    uint32_t b1[3];
    for (int a = 0; a < 3; a++) {
        uint32_t last = (lo[a] + B - 1) >> v->slog2;
        b1[a] = last < g[a] ? last + 1 : g[a];
    }
    for (b[2] = lo[2] >> v->slog2; b[2] < b1[2]; b[2]++)
        for (b[1] = lo[1] >> v->slog2; b[1] < b1[1]; b[1]++)
            for (b[0] = lo[0] >> v->slog2; b[0] < b1[0]; b[0]++) {
                uint32_t e = entry_at(v, l, b);
                if (e == 0 || e == ENTRY_UNIFORM) continue; /* all 0 */
                for (int a = 0; a < 3; a++) o[a] = b[a] << v->slog2;
                copy_part(v, L, e, o, lo, raw);
            }
    return 0;
}

/* Some non-zero voxel of level-0 brick b (entry e) outside volume, in at. */
static bool brick_outside(const vod_volume *v, const uint32_t b[3], uint32_t e,
                          const uint32_t volume[3], uint32_t at[3])
{
    uint32_t S = v->sbrick, m = v->slog2;
    for (uint32_t z = 0; z < S; z++)
        for (uint32_t y = 0; y < S; y++)
            for (uint32_t x = 0; x < S; x++) {
                uint32_t p[3] = {(b[0] << m) + x, (b[1] << m) + y, (b[2] << m) + z};
                if (p[0] < volume[0] && p[1] < volume[1] && p[2] < volume[2])
                    continue;
                if (is_alloc(e) && !vox_get(v, brick_data(v, e), vox_index(v, x, y, z)))
                    continue;
                memcpy(at, p, sizeof p);
                return true;
            }
    return false;
}

/* Only level-0 bricks that reach past volume are scanned, voxel by voxel;
 * a row of bricks inside on y and z starts at the first that reaches x. */
static int vol_outside(const vod_source *s, const uint32_t volume[3],
                       uint32_t at[3])
{
    const vod_volume *v = s->ctx;
    const uint32_t *g = v->grid[0];
    uint32_t b[3], m = v->slog2;
    for (b[2] = 0; b[2] < g[2]; b[2]++)
        for (b[1] = 0; b[1] < g[1]; b[1]++) {
            bool in_yz = ((uint64_t)b[2] + 1) << m <= volume[2] &&
                         ((uint64_t)b[1] + 1) << m <= volume[1];
            for (b[0] = in_yz ? volume[0] >> m : 0; b[0] < g[0]; b[0]++) {
                uint32_t e = entry_at(v, 0, b);
                bool inside = in_yz && ((uint64_t)b[0] + 1) << m <= volume[0];
                if (e && !inside && brick_outside(v, b, e, volume, at)) return 1;
            }
        }
    return 0;
}

static const vod_source_ops volume_ops = {
    .name = "volume",
    .prepare = vol_prepare,
    .outside = vol_outside,
    .region = vol_region,
    .fill = vol_fill,
};

vod_source vod_volume_source(vod_volume *v)
{
    return (vod_source){
        .ops = &volume_ops,
        .ctx = v,
        .depth = v->depth,
        .channels = channels_of(v),
    };
}
