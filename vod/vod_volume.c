/* A brick-sparse volume and its VOD brick source (vod_volume.h).
 *
 * Each level l (0 = the voxels, 1..depth = mip levels) has a table of one
 * u32 entry per storage brick, grid[l] bricks per axis, covering the
 * ceil(dims / 2^l) voxels of that level: 0 = empty, ENTRY_UNIFORM | v =
 * every voxel is v (v < 2^31), WIDE_BASE + i = every voxel is wide[i] (a
 * float volume's values of 2^31 and more: negative distances), anything
 * else = pool brick entry - 1.
 *
 * At a mip level an entry is 0 exactly when the brick's full-resolution
 * footprint holds no non-zero voxel (prepare() computes it from the voxels,
 * not from the downsampled values, which may round to 0), so the writer's
 * emptiness question is one table look-up there.  At level 0 a uniform
 * entry is never 0 (a box filled with 0 empties its bricks), but an
 * allocated brick may hold only zeros: it is scanned.
 */
#include "vod_volume_int.h"

#include <assert.h>
#include <errno.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include "clock.h"
#include "par.h"
#include "vod_downsample.h"
#include "voxel.h"
#include "zero.h"

/* The entry of value u without memory (0 for 0), or 0 when u cannot be
 * one (the top bit set in an integer volume, or no wide slot left). */
uint32_t vod_vol_uentry(struct vod_volume *v, uint32_t u)
{
    if (u < ENTRY_UNIFORM) return u ? ENTRY_UNIFORM | u : 0;
    if (!v->f32) return 0;
    uint32_t n = atomic_load_explicit(&v->wide_n, memory_order_relaxed);
    for (uint32_t i = 0; i < n && i < WIDE_MAX; i++)
        if (v->wide[i] == u) return WIDE_BASE + i;
    uint32_t i = atomic_fetch_add_explicit(&v->wide_n, 1, memory_order_relaxed);
    if (i >= WIDE_MAX) {
        atomic_fetch_sub_explicit(&v->wide_n, 1, memory_order_relaxed);
        return 0;
    }
    v->wide[i] = u;
    return WIDE_BASE + i;
}

/* ---- layout ---- */

static int check_args(const uint32_t dims[3], uint32_t bits, uint32_t sbrick)
{
    for (int a = 0; a < 3; a++)
        if (dims[a] < 1 || dims[a] > VOD_VOLUME_MAX_SIDE) return -EINVAL;
    if (bits != 8 && bits != 32 && bits != VOD_VOLUME_F32) return -EINVAL;
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
    h->f32 = bits == VOD_VOLUME_F32;
    h->bits = h->f32 ? 32 : bits;
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
    h->brick_bytes = (uint64_t)sbrick * sbrick * sbrick * h->bits / 8;
    h->packed = h->f32;
    h->unit = h->packed ? PACK_UNIT : h->brick_bytes;
    h->pool_off = at;
    return at;
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
    /* in units: a packed brick at its largest, every voxel stored, twice
     * (a record that an edit or a larger put moves leaves its old units) */
    uint64_t per = h.packed ? 2 * vod_pack_max_units(sbrick) : 1;
    pool = pool > POOL_MAX / per ? POOL_MAX : pool * per;
    if (pool > (SIZE_MAX - head) / h.unit) return 0;
    return (size_t)(head + pool * h.unit);
}

int vod_volume_init(vod_volume **out, void *arena, size_t bytes,
                    const uint32_t dims[3], uint32_t bits, uint32_t sbrick)
{
    if (check_args(dims, bits, sbrick) || ((uintptr_t)arena & 7)) return -EINVAL;
    struct vod_volume h;
    uint64_t head = plan(&h, dims, bits, sbrick);
    if (head > bytes) return -ENOSPC;
    uint64_t cap = (bytes - head) / h.unit;
    h.pool_cap = (uint32_t)(cap > POOL_MAX ? POOL_MAX : cap);
    /* another than any volume made before at this address (the writers'
     * chunks, vod_volume_pool.c): the clock's nanoseconds */
    h.pool_epoch = (uint64_t)(clock_now() * 1e9);
    /* the tables: in the engine's segment, their pages are touched first
     * by the workers that store bricks, not here (zero.h) */
    zero_range((uint8_t *)arena + sizeof h, head - sizeof h);
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
    out->bits = v->f32 ? VOD_VOLUME_F32 : v->bits;
    out->sbrick = v->sbrick;
    out->depth = v->depth;
    out->pool_cap = v->pool_cap;
    out->pool_used = atomic_load_explicit(&v->pool_used, memory_order_relaxed);
    out->level0_bricks = atomic_load_explicit(&v->pool_l0, memory_order_relaxed);
    out->mip_channel = v->mip_channel;
    out->bytes_used = v->pool_off + (uint64_t)out->pool_used * v->unit;
    out->pool_full = (int)atomic_load_explicit(&v->pool_full, memory_order_relaxed);
}

/* ---- bricks and voxels ---- */

/* The pool's units in use from which vod_volume_check reads the tables
 * and records on every CPU. */
#define CHECK_PAR_UNITS 16384u
#define CHECK_CHUNK 4096u /* entries of a level a part takes at a time */

/* The tables' entries checked by part k of n: chunk j of each level is
 * part j % n's; any bad entry sets bad (relaxed: read after par_run's
 * join). */
typedef struct {
    const vod_volume *v;
    uint32_t used;
    atomic_int bad;
} entry_check;

static bool entry_bad(const vod_volume *v, uint32_t e, uint32_t used)
{
    if (is_alloc(e)) return e > used || (v->packed && vod_pack_check(v, e, used));
    return e >= WIDE_BASE && e < ENTRY_UNIFORM &&
           e - WIDE_BASE >= atomic_load_explicit(&v->wide_n, memory_order_relaxed);
}

static void check_part(void *ud, unsigned k, unsigned n)
{
    entry_check *c = ud;
    const vod_volume *v = c->v;
    for (int l = 0; l <= v->depth; l++) {
        const uint32_t *t = table(v, l);
        uint64_t end = grid_bricks(v, l);
        for (uint64_t i0 = (uint64_t)k * CHECK_CHUNK; i0 < end; i0 += (uint64_t)n * CHECK_CHUNK) {
            /* relaxed: another part's find only ends this one early */
            if (atomic_load_explicit(&c->bad, memory_order_relaxed)) return;
            uint64_t i1 = end - i0 < CHECK_CHUNK ? end : i0 + CHECK_CHUNK;
            for (uint64_t i = i0; i < i1; i++)
                if (entry_bad(v, t[i], c->used)) {
                    /* relaxed: read after par_run's join */
                    atomic_store_explicit(&c->bad, 1, memory_order_relaxed);
                    return;
                }
        }
    }
}

int vod_volume_check(const vod_volume *v, size_t bytes)
{
    struct vod_volume h;
    if (bytes < sizeof h || v->magic != VOL_MAGIC ||
        check_args(v->dims, v->bits, v->sbrick) || v->f32 > 1)
        return -EINVAL;
    uint64_t head = plan(&h, v->dims, v->f32 ? VOD_VOLUME_F32 : v->bits, v->sbrick);
    if (head > bytes || h.slog2 != v->slog2 || h.depth != v->depth ||
        memcmp(h.grid, v->grid, sizeof h.grid) ||
        memcmp(h.table_off, v->table_off, sizeof h.table_off) ||
        h.pool_off != v->pool_off || h.brick_bytes != v->brick_bytes ||
        h.packed != v->packed || h.unit != v->unit)
        return -EINVAL;
    uint32_t used = atomic_load_explicit(&v->pool_used, memory_order_relaxed);
    uint32_t l0 = atomic_load_explicit(&v->pool_l0, memory_order_relaxed);
    if (v->pool_cap > (bytes - head) / h.unit || used > v->pool_cap ||
        l0 > used || v->mip_channel != 0 ||
        atomic_load_explicit(&v->wide_n, memory_order_relaxed) > WIDE_MAX)
        return -EINVAL;
    if (v->low_levels) return -EINVAL;
    /* every level: the mip levels built by column are in the tables too;
     * on every CPU when the pool is large (a packed record's head is
     * read here first in this process: the dragon's distance at 1024^3,
     * 100,000 records, 0.2 s of one thread, nearly all of it that first
     * load), on this thread when there are few (a thread costs more) */
    entry_check c = {.v = v, .used = used};
    atomic_init(&c.bad, 0);
    unsigned cpus = used >= CHECK_PAR_UNITS ? par_cpus() : 1;
    if (cpus > 1) par_run(cpus, check_part, &c);
    else check_part(&c, 0, 1);
    /* relaxed: par_run's join orders the parts' stores before it */
    return atomic_load_explicit(&c.bad, memory_order_relaxed) ? -EINVAL : 0;
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
 * writes every voxel); its entry, or 0 when full.  Not for packed
 * volumes, whose records vod_pack_store makes. */
uint32_t vod_vol_pool_take(vod_volume *v, uint32_t val, bool fill)
{
    uint32_t e = vod_vol_pool_units(v, 1);
    if (e && fill) brick_set_all(v, brick_data(v, e), val);
    return e;
}

/* Writing voxels makes the mip levels stale: give their bricks back. */
void vod_vol_drop_mips(vod_volume *v)
{
    /* The mip bricks were taken after every level-0 one: the pool goes
     * back to where it stood before them.  (Not to pool_l0: concurrent
     * writers, or one killed between taking a brick and counting it, may
     * leave level-0 bricks above that count.) */
    if (v->mip_channel) {
        atomic_store_explicit(&v->pool_used, v->mip_base, memory_order_relaxed);
        v->pool_epoch++; /* the chunks above mip_base are no one's now */
    }
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
        uint32_t n = vod_vol_pool_take(v, uval(v, *e), !whole);
        if (!n) return -ENOMEM;
        atomic_fetch_add_explicit(&v->pool_l0, 1, memory_order_relaxed);
        *e = n;
    }
    *out = brick_data(v, *e);
    return 0;
}

/* A packed volume's level-0 brick b, edited through a copy: voxels of the
 * brick-local box [lo, hi) := value, or (vox given) every voxel := vox.
 * The record is made again, in its own units when they suffice. */
static int packed_edit(vod_volume *v, const uint32_t b[3], const uint32_t lo[3],
                       const uint32_t hi[3], uint32_t value, const uint32_t *vox)
{
    const uint32_t *g = v->grid[0];
    uint32_t *e = &table(v, 0)[((uint64_t)b[2] * g[1] + b[1]) * g[0] + b[0]];
    size_t N = (size_t)v->sbrick * v->sbrick * v->sbrick;
    uint32_t *buf = NULL;
    if (!vox) {
        if (!(buf = malloc(N * sizeof *buf))) return -ENOMEM;
        if (is_alloc(*e)) vod_pack_range(v, brick_data(v, *e), 0, N, buf);
        else
            for (size_t i = 0; i < N; i++) buf[i] = uval(v, *e);
        for (uint32_t z = lo[2]; z < hi[2]; z++)
            for (uint32_t y = lo[1]; y < hi[1]; y++)
                for (uint32_t x = lo[0]; x < hi[0]; x++) buf[vox_index(v, x, y, z)] = value;
        vox = buf;
    }
    uint32_t n = vod_pack_store(v, *e, vox, buf != NULL);
    free(buf);
    if (!n) return -ENOMEM;
    if (!is_alloc(*e)) atomic_fetch_add_explicit(&v->pool_l0, 1, memory_order_relaxed);
    *e = n;
    return 0;
}

static int check_value(const vod_volume *v, uint32_t value)
{
    return v->bits == 8 && value > 255 ? -EINVAL : 0;
}

/* Voxels are about to change: every mip level is stale. */
static void stale_mips(vod_volume *v)
{
    vod_vol_drop_mips(v);
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
    if (e == 0 ? value == 0 : is_uniform(e) && uval(v, e) == value)
        return 0;
    if (value == 0) may_zero(v); /* into memory: e is allocated */
    if (v->packed) {
        uint32_t l[3] = {x & m, y & m, z & m}, h[3] = {l[0] + 1, l[1] + 1, l[2] + 1};
        return packed_edit(v, b, l, h, value, NULL);
    }
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
    if (!is_alloc(e)) return uval(v, e);
    return brick_voxel(v, e, vox_index(v, x & m, y & m, z & m));
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
                int64_t val = uval(v, e);
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
    uint32_t u = is_alloc(*e) || !value ? 0 : vod_vol_uentry(v, value);
    if (!is_alloc(*e) && (u || !value)) {
        *e = u;
        return 0;
    }
    if (value == 0) may_zero(v);
    if (v->packed) {
        uint32_t l[3] = {0, 0, 0}, h[3] = {v->sbrick, v->sbrick, v->sbrick};
        return packed_edit(v, b, l, h, value, NULL);
    }
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
    if (e == 0 ? value == 0 : is_uniform(e) && uval(v, e) == value)
        return 0;
    if (value == 0) may_zero(v);
    if (v->packed) return packed_edit(v, b, lo, hi, value, NULL);
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
int64_t vod_vol_uniform_value(const vod_volume *v, const uint8_t *d)
{
    uint64_t n = (uint64_t)v->sbrick * v->sbrick * v->sbrick;
    uint32_t first = vox_get(v, d, 0);
    if (first >= ENTRY_UNIFORM && !v->f32) return -1;
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
    int64_t u = vod_vol_uniform_value(v, voxels);
    uint32_t ue = u > 0 && !is_alloc(*e) ? vod_vol_uentry(v, (uint32_t)u) : 0;
    if (!is_alloc(*e) && (u == 0 || ue)) {
        *e = ue;
        return 0;
    }
    if (u == 0) may_zero(v); /* zeros into the memory the brick has */
    if (v->packed) return packed_edit(v, b, NULL, NULL, 0, voxels);
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
