/* vod_volume — a brick-sparse volume of 8- or 32-bit voxels, the VOD brick
 * source of the job kinds that make dense data (mesh solids, volume CSG).
 *
 * The volume is cut into cubic storage bricks of S voxels per axis (its own
 * S, not the file's brick size).  A storage brick is empty (all 0, no
 * memory), uniform (every voxel one value, no memory) or allocated (S^3
 * voxels from a pool).  vod_volume_fill() marks the bricks a box covers
 * whole as uniform, so a solid's inside costs a table entry per brick.
 * A VOD_VOLUME_F32 volume stores an allocated brick packed: its voxels
 * equal to +-bg (the brick's largest magnitude: a distance's band width)
 * as a sign bit each, the others as they are, so a band brick costs its
 * band voxels, not S^3 (vod_volume_pack.c); readers see the same bits.
 *
 * Everything — header, brick tables, pool — lives in one arena addressed by
 * offsets, so the arena may sit in shared memory mapped at another address
 * in each process: a worker takes vod_volume_view() of the same bytes.
 *
 * As a source (vod.h) the volume gives channel 1 (1 where a voxel is
 * non-zero) and, from 8-bit voxels, channel 2 (density), from 32-bit
 * voxels, channel 3 (surface voxels with normals); a VOD_VOLUME_F32
 * volume gives channel 4 alone (floats, their bits as the voxels).  Its prepare() builds the
 * mip levels 1..depth for the channel, brick-sparse too, into the same pool
 * (the pool must have room: see vod_volume_bytes); writing a voxel after
 * that drops them, so the next prepare() builds them again.
 *
 * One writer at a time (but see vod_volume_put_brick); any number of
 * readers (region, fill, get) once the writers are done.
 */
#ifndef VOXD_VOD_VOLUME_H
#define VOXD_VOD_VOLUME_H

#include <stddef.h>
#include <stdint.h>

#include "vod.h"

#define VOD_VOLUME_MAX_SIDE 65536u /* 2^OCTREE_MAX_DEPTH */
#define VOD_VOLUME_MIN_BRICK 2u
#define VOD_VOLUME_MAX_BRICK 64u
/* bits of a volume of IEEE binary32 voxels (channel 4, signed distances):
 * 32 bits a voxel, any value a uniform brick (negative ones too), the mip
 * levels the mean of the floats. */
#define VOD_VOLUME_F32 0x120u

/* The arena, whose first bytes are the volume's header. */
typedef struct vod_volume vod_volume;

/* Bytes of arena for a volume of dims (each 1..VOD_VOLUME_MAX_SIDE) with
 * voxels of bits (8, 32 or VOD_VOLUME_F32) in storage bricks of side sbrick (a power of two
 * in VOD_VOLUME_MIN_BRICK..MAX_BRICK) that can allocate `bricks` level-0
 * bricks and, whatever their place, every mip brick above them (packed
 * ones at their largest, twice: a brick edited or put again larger moves).
 * A bound for a sparse mapping: a packed volume uses far less.  0 for bad
 * arguments or a size past SIZE_MAX. */
size_t vod_volume_bytes(const uint32_t dims[3], uint32_t bits, uint32_t sbrick,
                        uint64_t bricks);

/* An empty volume in arena (bytes long, 8-byte aligned; it need not be
 * cleared).  The pool gets what is left after the header and the tables.
 * 0 and the volume in *out, -EINVAL for bad arguments, -ENOSPC when the
 * tables alone do not fit. */
int vod_volume_init(vod_volume **out, void *arena, size_t bytes,
                    const uint32_t dims[3], uint32_t bits, uint32_t sbrick);
/* The volume another process built in arena (mapped anywhere), or NULL
 * when arena does not start with one. */
vod_volume *vod_volume_view(void *arena);

/* The voxel at (x, y, z) := value.  0, -EINVAL for a voxel outside dims or
 * a value wider than the voxels, -ENOMEM when the pool is full (the volume
 * is then unchanged). */
int vod_volume_set(vod_volume *v, uint32_t x, uint32_t y, uint32_t z,
                   uint32_t value);
/* Every voxel of the box [lo, hi) := value; bricks the box covers whole
 * (and that lie inside dims) become uniform without memory, unless value
 * does not fit 31 bits (in a VOD_VOLUME_F32 volume, past its 8 values that
 * do not).  Same errors as vod_volume_set (-EINVAL also for an
 * empty or inverted box); on -ENOMEM part of the box may be written. */
int vod_volume_fill(vod_volume *v, const uint32_t lo[3], const uint32_t hi[3],
                    uint32_t value);
/* Level-0 storage brick b (brick coordinates, each below
 * ceil(dims / sbrick)) := voxels, sbrick^3 values of the volume's width, x
 * fastest, 0 past dims.  A brick whose voxels are all one value becomes an
 * empty or uniform entry without memory.  Unlike every other writer, calls
 * for different bricks may run concurrently, in several threads or
 * processes (the pool's allocation is atomic); they must come before
 * prepare().  0, -EINVAL for a brick outside the grid, -ENOMEM when the
 * pool is full (the brick is then unchanged). */
int vod_volume_put_brick(vod_volume *v, const uint32_t b[3], const void *voxels);
/* Level-0 storage brick b := value in every voxel, without scanning a
 * buffer: an empty or uniform entry (or the brick's memory, when it has
 * some already or value does not fit 31 bits).  Concurrent like
 * vod_volume_put_brick; for bricks wholly inside dims (or value 0).  0,
 * -EINVAL for a brick outside the grid or a value wider than the voxels,
 * -ENOMEM when the pool is full. */
int vod_volume_put_uniform(vod_volume *v, const uint32_t b[3], uint32_t value);
/* Mip levels 1..levels of channel (one the volume gives) under the
 * level-`levels` brick columns [lo, hi) (x and y in that level's brick
 * coordinates, every z; hi clipped to the grid), built from level 0,
 * which must be final there.
 * Calls for different columns may run concurrently, in several threads or
 * processes, like vod_volume_put_brick (the mesh kind's workers build
 * their tile's after its bricks); a column built again uses its bricks'
 * memory again.  They count once vod_volume_mips_low() is called.  0,
 * -EINVAL for bad arguments, -ENOMEM when the pool is full. */
int vod_volume_mip_columns(vod_volume *v, int channel, int levels,
                           const uint32_t lo[2], const uint32_t hi[2]);
/* Levels 1..levels of channel are built (by vod_volume_mip_columns over
 * every column that holds a non-zero voxel; the others' entries are the
 * empty ones a new volume starts with): prepare() of that channel then
 * builds only the levels above.  Writing a voxel drops them (their bricks
 * stay taken); prepare() of another channel builds every level over them
 * (the pool must then have room for both).  0, or -EINVAL for bad
 * arguments or a volume already prepared. */
int vod_volume_mips_low(vod_volume *v, int channel, int levels);
/* The voxel at (x, y, z), 0 outside dims. */
uint32_t vod_volume_get(const vod_volume *v, uint32_t x, uint32_t y, uint32_t z);
/* 1 and *value when every voxel of the cube of n voxels per axis from lo
 * (which may reach outside dims: those voxels are 0) is known to hold one
 * value from the level-0 table alone (empty and uniform storage bricks),
 * else 0 (a brick with memory, even if its voxels agree). */
int vod_volume_box_uniform(const vod_volume *v, const int64_t lo[3], uint32_t n,
                           uint32_t *value);

/* What a volume holds, for tests and the job kinds' summaries. */
typedef struct {
    uint32_t dims[3], bits, sbrick; /* bits: 8, 32 or VOD_VOLUME_F32 */
    int depth;                 /* 2^depth >= every side, >= 1 */
    uint32_t pool_cap;         /* bricks the pool holds */
    uint32_t pool_used;        /* bricks allocated, mip bricks included */
    uint32_t level0_bricks;    /* allocated level-0 bricks */
    int mip_channel;           /* the channel the mip levels hold, 0: none */
    uint64_t bytes_used;       /* of the arena: past this nothing is used */
    int pool_full;             /* a writer found the pool full: its -ENOMEM
                                  was the volume's, not a heap's */
} vod_volume_info;
void vod_volume_get_info(const vod_volume *v, vod_volume_info *out);

/* 0 when v, in an arena of bytes, is a volume whose level 0 (and maybe
 * low mip levels, vod_volume_mip_columns) other processes wrote
 * (vod_volume_put_brick) that is safe to read: its header is what
 * vod_volume_init made for its dims, its pool inside the arena, every
 * table entry of every level inside the pool, not prepared and no mip
 * levels declared yet.  -EINVAL if not. */
int vod_volume_check(const vod_volume *v, size_t bytes);

/* v as a brick source (vod.h): ctx is v, valid in the process that made or
 * viewed it. */
vod_source vod_volume_source(vod_volume *v);

#endif
