/* Internals of the brick-sparse volume shared by its two files:
 * vod_volume.c (the store: layout, voxels, fills, bricks) and
 * vod_volume_src.c (its mip levels and its VOD source).  The source
 * side calls the store side, never the other way round. */
#ifndef VOD_VOLUME_INT_H
#define VOD_VOLUME_INT_H

#include "vod_volume.h"

#include <stdatomic.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "octree.h"

#define VOL_MAGIC 0x4c4f5656u /* "VVOL" */
#define VOL_LEVELS (OCTREE_MAX_DEPTH + 1)
#define ENTRY_UNIFORM 0x80000000u
/* A float volume's uniform values with the top bit set (-w, the inside
 * of a distance field beyond its band) have entries WIDE_BASE + i, their
 * values in the header, added as the writers meet them. */
#define WIDE_MAX 8u
#define WIDE_BASE (ENTRY_UNIFORM - WIDE_MAX)
#define POOL_MAX (WIDE_BASE - 2u) /* entries 1..WIDE_BASE-1 */

struct vod_volume {
    uint32_t magic;
    uint32_t dims[3];
    uint32_t bits, sbrick, slog2;
    uint32_t f32; /* 1: IEEE binary32 voxels, channel 4 (VOD_VOLUME_F32) */
    /* 1: the pool's bricks are packed records (vod_volume_pack.c), as a
     * float volume's are: a distance's band bricks hold few voxels that
     * are not +-w, the band's width */
    uint32_t packed;
    int depth;
    uint32_t grid[VOL_LEVELS][3];
    uint64_t table_off[VOL_LEVELS]; /* from the start of the arena */
    uint64_t pool_off, brick_bytes;
    /* Bytes of a pool unit: a brick (brick_bytes), or PACK_UNIT when
     * packed (a record takes as many units as it needs).  pool_cap,
     * pool_used and mip_base count units; an entry is its first unit + 1. */
    uint64_t unit;
    uint32_t pool_cap;
    /* Bricks taken from the pool, and of those the level-0 ones.  Atomic
     * because vod_volume_put_brick() writers of different bricks run
     * concurrently (relaxed: a brick's bytes and table entry are published
     * to the readers by whatever ends the writers' phase, in the engine the
     * worker's done_seq release, which the master's acquire pairs with). */
    atomic_uint pool_used, pool_l0;
    /* Which pool the writers' chunks are of (vod_volume_pool.c): set when
     * the volume is made, moved when pool_used goes back (the mip levels
     * dropped), between the writers' phases. */
    uint64_t pool_epoch;
    /* 1 once a level-0 brick with memory may hold only zeros (a zero
     * written into one); while 0, such a brick is known to hold a voxel
     * without a scan.  Set by concurrent put_brick writers too (relaxed:
     * published like pool_used, by the end of the writers' phase). */
    atomic_uint zero_bricks;
    /* 1 once a writer found the pool full: its -ENOMEM is the volume's,
     * not a heap's (relaxed: read after the writers' phase, like pool_used) */
    atomic_uint pool_full;
    int mip_channel;
    uint32_t mip_base;  /* pool_used before the mip levels were built */
    /* Levels 1..low_levels of channel low_channel built by column
     * (vod_volume_mip_columns) and declared complete: prepare() of that
     * channel builds only the levels above.  Their bricks are mixed with
     * level 0's in the pool, so nothing gives them back. */
    int low_channel, low_levels;
    /* The wide uniform values (WIDE_BASE).  A writer that needs a new one
     * takes a slot (relaxed: slots are published to readers like the
     * bricks, by the end of the writers' phase) and writes its value; two
     * writers may take a slot each for one value, which costs a slot. */
    atomic_uint wide_n;
    uint32_t wide[WIDE_MAX];
};

static inline uint64_t align64(uint64_t v) { return (v + 63) & ~(uint64_t)63; }

static inline bool is_uniform(uint32_t e) { return e >= WIDE_BASE; }

static inline bool is_alloc(uint32_t e) { return e && !is_uniform(e); }

/* The value of an entry without memory. */
static inline uint32_t uval(const struct vod_volume *v, uint32_t e)
{
    return e >= ENTRY_UNIFORM ? e & ~ENTRY_UNIFORM : e >= WIDE_BASE ? v->wide[e - WIDE_BASE] : 0;
}

static inline uint64_t grid_bricks(const struct vod_volume *h, int l)
{
    return (uint64_t)h->grid[l][0] * h->grid[l][1] * h->grid[l][2];
}

static inline uint32_t *table(const vod_volume *v, int l)
{
    return (uint32_t *)((uint8_t *)v + v->table_off[l]);
}

/* The entry of brick b of level l; 0 (empty) outside the grid. */
static inline uint32_t entry_at(const vod_volume *v, int l, const uint32_t b[3])
{
    const uint32_t *g = v->grid[l];
    if (b[0] >= g[0] || b[1] >= g[1] || b[2] >= g[2]) return 0;
    return table(v, l)[((uint64_t)b[2] * g[1] + b[1]) * g[0] + b[0]];
}

static inline uint8_t *brick_data(const vod_volume *v, uint32_t e)
{
    return (uint8_t *)v + v->pool_off + (uint64_t)(e - 1) * v->unit;
}

static inline size_t vox_index(const vod_volume *v, uint32_t x, uint32_t y, uint32_t z)
{
    return ((size_t)z * v->sbrick + y) * v->sbrick + x;
}

static inline uint32_t vox_get(const vod_volume *v, const uint8_t *d, size_t i)
{
    return v->bits == 8 ? d[i] : ((const uint32_t *)(const void *)d)[i];
}

static inline void vox_put(const vod_volume *v, uint8_t *d, size_t i, uint32_t val)
{
    if (v->bits == 8) d[i] = (uint8_t)val;
    else ((uint32_t *)(void *)d)[i] = val;
}

/* ---- packed bricks (vod_volume_pack.c) ----
 * A packed record: a head (pack_head), then two bit masks of S^3 bits
 * (64-bit words, voxel i in bit i % 64 of word i / 64): `lit`, the voxels
 * stored as they are, and `neg`, the sign of the others, then the n
 * literal values in voxel order.  A voxel that is not literal holds
 * bg | neg << 31: bg is the largest |value| of the brick (the band's
 * width w in a distance brick, where every voxel beyond the band is +-w). */
#define PACK_UNIT 16u
typedef struct {
    uint32_t n;   /* literal voxels */
    uint32_t cap; /* units the record owns (>= its size: reused when rebuilt) */
    uint32_t bg;  /* the non-literal voxels' magnitude (sign bit clear) */
    uint32_t pad;
} pack_head;

/* Units of the largest record (every voxel literal). */
uint64_t vod_pack_max_units(uint32_t sbrick);
/* The S^3 voxels vox (the volume's u32s) as a record: in old's units when
 * old is allocated and they suffice, else in new ones (old's are then lost
 * until the volume is made again: a brick put twice, a column built twice).
 * edit: a brick written voxel by voxel (set, fill) gets the units of the
 * largest record at once, so that its edits never move it.  Its entry, or
 * 0 when the pool is full.  Concurrent for different bricks. */
uint32_t vod_pack_store(vod_volume *v, uint32_t old, const uint32_t *vox, bool edit);
/* Voxels i0 .. i0 + n - 1 of record d (voxel order) into out. */
void vod_pack_range(const vod_volume *v, const uint8_t *d, size_t i0, size_t n, uint32_t *out);
/* Voxel i of record d. */
uint32_t vod_pack_voxel(const vod_volume *v, const uint8_t *d, size_t i);
/* Some voxel of record d is non-zero. */
bool vod_pack_any(const vod_volume *v, const uint8_t *d);
/* 0 when entry e's record lies in the first `used` units and agrees
 * with itself (its count and its mask), else -EINVAL. */
int vod_pack_check(const vod_volume *v, uint32_t e, uint32_t used);
/* Voxel i of allocated entry e, packed or not. */
static inline uint32_t brick_voxel(const vod_volume *v, uint32_t e, size_t i)
{
    return v->packed ? vod_pack_voxel(v, brick_data(v, e), i) : vox_get(v, brick_data(v, e), i);
}

/* `units` consecutive pool units; the entry of the first, or 0 when full
 * (vod_volume_pool.c: a thread takes them from its chunk).  Concurrent. */
uint32_t vod_vol_pool_units(vod_volume *v, uint64_t units);

/* The entry of value u without memory (0 for 0), or 0 when u cannot be
 * one (the top bit set in an integer volume, or no wide slot left). */
uint32_t vod_vol_uentry(struct vod_volume *v, uint32_t u);

/* A new pool brick holding val everywhere (fill), or anything (the caller
 * writes every voxel); its entry, or 0 when full. */
uint32_t vod_vol_pool_take(vod_volume *v, uint32_t val, bool fill);

/* Writing voxels makes the mip levels stale: give their bricks back. */
void vod_vol_drop_mips(vod_volume *v);

/* The value every voxel of the S^3 brick d holds, or -1 when they differ
 * (or the one value cannot be a uniform entry). */
int64_t vod_vol_uniform_value(const vod_volume *v, const uint8_t *d);

#endif
