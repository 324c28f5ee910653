/* vod — brick-octree VOD files (docs/vod-format.md), written and read.
 *
 * The writer reads its voxels from a brick source (vod_source, below): the
 * octree of voxels the implicit-surface engine builds, or a brick-sparse
 * volume (vod_volume.h) for the kinds that make dense data.  Writing happens
 * in three phases so that the middle one can run in parallel in the worker
 * processes:
 *   1. master:  vod_layout_make(), vod_check_source(), vod_prepare(),
 *               vod_collect()                                  — plan
 *   2. workers: vod_encoder_put() for each collected brick node — fill, hash,
 *               look up, compress (a duplicate is found before compression)
 *   3. master:  vod_assemble()                                 — dedup, lay out, write
 * vod_write() runs all three in-process; vod_write_octree() wraps an octree.
 *
 * Reading (vod_read/vod_open) validates the whole file up front — every case of
 * section 8 of the spec is refused with a message naming what is wrong — so a
 * vod_file, once open, is trusted by every accessor.
 */
#ifndef VOXD_VOD_H
#define VOXD_VOD_H

#include <stddef.h>
#include <stdint.h>

#include "err.h"
#include "octree.h"

#define VOD_FOURCC(a, b, c, d)                                                \
    ((uint32_t)(a) | (uint32_t)(b) << 8 | (uint32_t)(c) << 16 |               \
     (uint32_t)(d) << 24)
#define VOD_HASH_SFHS VOD_FOURCC('S', 'F', 'H', 'S')
#define VOD_HASH_XX32 VOD_FOURCC('X', 'X', '3', '2')
#define VOD_COMP_NONE VOD_FOURCC('N', 'O', 'N', 'E')
#define VOD_COMP_ZLIB VOD_FOURCC('Z', 'L', 'I', 'B')
#define VOD_COMP_RUNL VOD_FOURCC('R', 'U', 'N', 'L')

#define VOD_FLAG_COMPRESSED (1u << 0)
#define VOD_FLAG_PADDED (1u << 1)
#define VOD_FLAG_FLOAT (1u << 2)
#define VOD_FLAG_TRAILER (1u << 16)

#define VOD_HEADER_BYTES 64u
#define VOD_DEFAULT_BRICK 16u
#define VOD_MAX_METADATA 65536u
#define VOD_ZLIB_LEVEL_MAX 12 /* libdeflate's levels: 1..9 as zlib's, 10..12 slower */
#define VOD_SPARSE_LEVEL 6    /* up to it, bricks go to vod_sparse_compress */

/* What the writer is asked to produce. */
typedef struct {
    uint32_t volume[3];     /* volumeSize: the voxels asked for, each >= 1 */
    uint32_t brick;         /* 2^k, 1 <= k <= 8; default 16 */
    int channel;            /* VOXEL_CH_OCCUPANCY (1 bit), VOXEL_CH_DENSITY (8 bit),
                               VOXEL_CH_SURFACE (32 bit) or VOXEL_CH_DISTANCE (f32);
                               the source must give it */
    uint32_t comp;          /* VOD_COMP_* ; default ZLIB */
    uint32_t hash;          /* VOD_HASH_* ; default SFHS */
    int zlib_level;         /* ZLIB: 1..VOD_ZLIB_LEVEL_MAX, default 6 */
    float voxel_scale[3];   /* world size of a voxel */
    float origin[3];        /* world position of voxel (0,0,0)'s low corner */
    const char *metadata;   /* "key=value\n" lines, or NULL */
} vod_params;

void vod_params_default(vod_params *p);

/* The shape of the file for params p over a source of 2^octree_depth
 * voxels per axis (vod_source.depth). */
typedef struct {
    uint32_t brick, brick_log2; /* brick size and k */
    uint32_t height;            /* treeHeight */
    uint32_t padded;            /* N = brick * 2^(height-1) */
    uint32_t voxel_bits;        /* 1, 8 or 32 */
    int channel;                /* the params' (voxel.h) */
    size_t raw_bytes;           /* bytes of one raw brick */
    uint64_t nodes;             /* (8^height - 1) / 7 */
    int octree_depth;
} vod_layout;

/* Validate p against the spec and compute the layout.  -EINVAL with a
 * message in err for bad params (also when the volume is larger than the
 * source's 2^octree_depth cube), -EFBIG when the octree table alone would
 * pass 4 GiB.  The padded side N is 2^octree_depth, smaller than it (an
 * octree deeper than the volume needs: the file's root is the cell that
 * covers [0, N)^3), or the brick itself when the brick is larger than the
 * whole octree (treeHeight 1). */
int vod_layout_make(const vod_params *p, int octree_depth, vod_layout *L,
                    err_info *err);

/* One non-empty brick node of the complete tree. */
typedef struct {
    uint64_t preorder; /* index in the file's octree table */
    uint32_t level;    /* 0 = full-resolution leaf bricks */
    uint32_t bx, by, bz; /* brick coordinates within its level */
    uint32_t uniform;  /* 1: the source said every voxel of the brick is value */
    uint32_t value;    /* (in the channel's terms: 0/1 for channel 1) */
    uint32_t ref;      /* the source's own note on the node (the octree: its cell) */
} vod_node;

/* ---- brick sources ----
 *
 * What the writer reads voxels from.  A source holds voxel values over a
 * cube of 2^depth voxels per axis (x, y, z from 0); a voxel it does not hold
 * is 0, and 0 means "no voxel".  Level 0 is full resolution; a level-l voxel
 * is made from the 8 level-(l-1) voxels below it as spec section 3 says for
 * the channel: 1 bit: OR; 8 bit: the mean rounded half up; channel 3: the
 * mean occupancy rounded half up with the normalized sum of the occupied
 * children's normals, 0 where the occupancy rounds to 0.  At level 0,
 * channel 1 is 1 where the value is non-zero.
 *
 * The writer's brick node (level l, brick b) of a file with bricks of B
 * voxels covers the full-resolution cube [b * B * 2^l, (b+1) * B * 2^l) per
 * axis; its brick holds the level-l voxels [b * B, (b+1) * B).  That cube
 * may reach past the source's (the padded side of the file is rounded up to
 * B * 2^(treeHeight-1)): the voxels there are 0.
 *
 * What each callback must guarantee:
 *  - prepare(s, L, channel): called once per file in the master, after
 *    vod_check_source() and before any region() or fill(); builds what
 *    levels >= 1 need for this channel (the octree's aggregates, the
 *    volume's mip levels) in memory that the processes calling fill() can
 *    reach.  Returns 0 or a negative errno (-ENOMEM: no room).  Nothing may
 *    change the voxels between prepare() and the last fill().
 *  - outside(s, volume, at): 1 with the coordinates of some non-zero voxel
 *    at x >= volume[0] or y >= volume[1] or z >= volume[2] in at, else 0.
 *    (The spec wants the padding 0; the writer refuses such a source.)
 *  - region(s, L, n): n's level and brick are set, n->ref is its parent's
 *    ref (0 for the root).  Returns VOD_REGION_EMPTY when n's
 *    full-resolution cube holds no non-zero voxel — exactly then: the node
 *    gets brickID 0 and its subtree is not visited; VOD_REGION_UNIFORM with
 *    n->value when every voxel of n's level-l brick is that value (in the
 *    channel's terms: 0/1 for channel 1) — the writer then makes the brick
 *    itself, no fill(); VOD_REGION_MIXED otherwise (or when the source
 *    cannot tell cheaply).  A non-empty node whose brick downsampling made
 *    all 0 is not EMPTY: it still gets a brick.  region() may set n->ref to
 *    what it wants back in fill() and in the children's region() (the
 *    octree keeps the node's cell there, so no look-up starts from the
 *    root); it sets n->value and n->ref only.
 *  - fill(s, L, n, raw): write the level-l brick of node n (as region()
 *    left it, or with ref 0) into raw (L->raw_bytes, zeroed by the caller)
 *    in spec section 5's layout at L->voxel_bits: 1-bit voxels packed, 8
 *    and 32-bit ones little-endian; it may leave 0 voxels unwritten.
 *    Read-only on the source and a function of the source and n alone, so
 *    any process, in any order, gives the same bytes.  Returns 0, or
 *    -EINVAL for a layout it cannot give.
 *
 * region() and fill() run in the worker processes too: ops must point to
 * static tables of the program (the same address after fork) and ctx to a
 * view the process made of data in the shared segment (octree_view,
 * vod_volume_view), never to the master's private memory. */
enum { VOD_REGION_EMPTY, VOD_REGION_MIXED, VOD_REGION_UNIFORM };

typedef struct vod_source vod_source;
typedef struct {
    const char *name; /* what it is, for messages ("octree") */
    int (*prepare)(vod_source *s, const vod_layout *L, int channel);
    int (*outside)(const vod_source *s, const uint32_t volume[3], uint32_t at[3]);
    int (*region)(const vod_source *s, const vod_layout *L, vod_node *n);
    int (*fill)(const vod_source *s, const vod_layout *L, const vod_node *n,
                uint8_t *raw);
} vod_source_ops;

struct vod_source {
    const vod_source_ops *ops;
    void *ctx;         /* the source's data (an octree, a vod_volume) */
    int depth;         /* 2^depth voxels per axis hold every voxel, 1..16 */
    uint32_t channels; /* bit c set: channel c can be written */
};

/* The octree t as a source (channels 1 and 3).  Its prepare() runs
 * vod_aggregate() (a no-op without t->agg: then only level 0 can be
 * filled). */
vod_source vod_octree_source(octree *t);

/* Phase 1 precondition: p->channel is one the source gives, and the spec
 * wants 0 outside volumeSize, so the source must hold no voxel there.  0,
 * or -EINVAL with what is wrong (the first such voxel) in err. */
int vod_check_source(const vod_source *s, const vod_params *p, err_info *err);

/* Phase 1: s->ops->prepare for p's channel; 0, or its error with a message. */
int vod_prepare(vod_source *s, const vod_layout *L, int channel, err_info *err);

/* Phase 1 for an octree (what its prepare() runs).  Fill t->agg (capacity
 * t->used) with each cell's downsampled value (spec section 3) so any
 * level's brick can be read off the tree: a level-l voxel (l >= 1) is agg of
 * the cell of height l-1 covering it.  O(cells), recursive to depth. */
void vod_aggregate(octree *t, int channel);
/* vod_aggregate in parts, for processes that share the work: the cells of
 * height h in preorder (into out, up to cap; returns how many there are,
 * out NULL to count), the aggregates of one of them and its subtree (any
 * process, subtrees in any order: each writes its own cells' agg only),
 * then those of the cells above height h from their children's.  The
 * result is vod_aggregate's. */
size_t vod_aggregate_roots(const octree *t, int h, uint32_t *out, size_t cap);
void vod_aggregate_subtree(octree *t, uint32_t c, int h, int channel);
/* (vod_aggregate_top also takes channel 2, densities, and channel 4, the
 * floats' bits (their mean, vod_down_float): vox_mpi's levels above a mesh
 * or CSG job's subtrees, whose cells carry those values.) */
void vod_aggregate_top(octree *t, int h, int channel);
/* Phase 1.  Write the non-empty brick nodes in preorder to out (up to cap);
 * returns how many there are (call with out = NULL to count).  Asks the
 * source's region() about the root and the 8 children of each non-empty
 * node, and records in each node whether its brick is uniform. */
size_t vod_collect(const vod_source *s, const vod_layout *L, vod_node *out,
                   size_t cap);

/* Phase 2: one brick. */
typedef struct {
    uint32_t hash;      /* hash of the raw brick */
    uint32_t size;      /* bytes written to out */
} vod_encoded;
/* Largest encoded size of one brick (bytes out must hold). */
size_t vod_encode_bound(const vod_layout *L, const vod_params *p);
/* Where one brick's encoding goes: its bytes into out (cap bytes), its
 * record into *rec. */
typedef struct {
    uint8_t *out;
    size_t cap;
    vod_encoded *rec;
} vod_brick_out;
/* Fill node n's raw brick from the source (scratch holds L->raw_bytes), hash
 * it and compress it into o->out (its record in *o->rec), without looking
 * for duplicates (the encoder below does).  It uses an encoder kept per thread (see
 * vod_encode_cleanup); the bytes depend only on the raw brick and p, and
 * are what vod_encoder_put gives.  A uniform node's brick is made here.
 * Returns 0, -ENOBUFS when o->cap is too small, -EINVAL for a node outside
 * the layout, -ENOMEM, or the source's error (an octree without t->agg
 * cannot fill levels >= 1). */
int vod_encode(const vod_source *s, const vod_layout *L, const vod_params *p,
               const vod_node *n, uint8_t *scratch, const vod_brick_out *o);

/* Frees the calling thread's vod_encode encoder (a thread that used
 * vod_encode should call it before it exits; a process need not). */
void vod_encode_cleanup(void);

/* Seconds spent in each stage of writing one file, on CLOCK_MONOTONIC.
 * fill: the source's prepare (the mip levels), vod_collect's walk and
 * filling each brick; hash: hashing each brick and looking up an earlier
 * equal one; compress; assemble: vod_assemble less its sink writes (dedup,
 * the layout, the CRC); write: the sink's writes.  Where bricks are encoded
 * in several processes, fill, hash and compress are their sum over the
 * processes (so they may pass the wall time of the write). */
typedef struct {
    double fill, hash, compress, assemble, write;
} vod_times;
void vod_times_add(vod_times *to, const vod_times *t);

/* An encoder of one file's bricks, for one thread: its scratch, its
 * compressor, and the bricks it has compressed so far, by hash (a node,
 * a record and a tag each, about 64 bytes; no raw brick is kept). */
typedef struct vod_encoder vod_encoder;
/* 0, -EINVAL for a level out of range, or -ENOMEM. */
int vod_encoder_new(const vod_layout *L, const vod_params *p, vod_encoder **out);
void vod_encoder_free(vod_encoder *e);
/* Node n's brick: filled, hashed, and if this encoder compressed an equal
 * brick before (the same hash, then the same raw bytes: the earlier node is
 * filled again and compared), *same is the tag given with that brick and
 * *o->rec its record, and nothing is written to o->out; else the brick is
 * compressed into o->out (o->cap bytes) and *same = tag.  The caller stores
 * the bytes of the first and points its duplicates at them, so the file is
 * the same as if each had been compressed.  Returns vod_encode's errors. */
int vod_encoder_put(vod_encoder *e, const vod_source *s, const vod_node *n,
                    uint64_t tag, const vod_brick_out *o, uint64_t *same);
/* A batch for vod_encoder_put_batch: nodes n[0..count-1], count at most
 * VOD_ENCODE_BATCH, with tags tag[i]; brick i compressed into out[i] (cap
 * bytes each), its record into rec[i], the tag of the brick it equals
 * into same[i]. */
#define VOD_ENCODE_BATCH 4
typedef struct {
    const vod_node *n;
    const uint64_t *tag;
    size_t count;
    uint8_t *const *out;
    size_t cap;
    vod_encoded *rec;
    uint64_t *same;
} vod_brick_batch;
/* vod_encoder_put for each node of b: the records of b->count calls of
 * vod_encoder_put in order (a brick equal to an earlier one of the batch
 * is its duplicate), but the new bricks' file hashes computed together
 * (SFHS is a serial chain: vod_hash_sfhs4 runs four at the cost of about
 * one).  -EINVAL for a larger count, else vod_encoder_put's errors (the
 * records before the failing brick may be unset). */
int vod_encoder_put_batch(vod_encoder *e, const vod_source *s, const vod_brick_batch *b);
/* Its fill, hash and compress seconds so far (the others 0). */
void vod_encoder_times(const vod_encoder *e, vod_times *t);

/* Where the file goes: write must write all n bytes or fail (negative errno). */
typedef struct {
    int (*write)(void *ud, const void *buf, size_t n);
    void *ud;
} vod_sink;

typedef struct {
    uint64_t file_bytes;
    uint64_t raw_bytes;       /* volume size uncompressed: padded^3 * bits / 8 */
    uint64_t nodes, nonempty_nodes;
    uint64_t bricks;          /* unique bricks stored */
    uint64_t brick_raw_bytes; /* raw bytes of the unique bricks */
    uint64_t brick_data_bytes; /* stored (compressed) bytes of the unique bricks */
    uint32_t crc32;           /* the trailer's fileCRC32 */
    vod_times t;              /* vod_assemble sets assemble and write; the
                                 writers add the phases before it */
} vod_stats;

/* Phase 3.  data[i] holds recs[i].size encoded bytes of nodes[i] (nodes in
 * preorder, as vod_collect gave them).  Duplicates (same hash, same bytes)
 * are stored once, IDs 1..n in order of first use.  -EINVAL for nodes not
 * strictly increasing in preorder or a size above vod_encode_bound, -EFBIG
 * when the file would pass 4 GiB, -ENOMEM, each with its message in err;
 * or the sink's error, with err left clear (code 0, message "": the sink's
 * owner knows why). */
typedef struct {
    const vod_layout *L;
    const vod_params *p;
    size_t n;                   /* bricks: nodes, recs and data have n each */
    const vod_node *nodes;
    const vod_encoded *recs;
    const uint8_t *const *data;
    vod_sink *sink;
    vod_stats *st;              /* NULL: no figures */
    err_info *err;              /* NULL: no message */
} vod_assembly;
int vod_assemble(const vod_assembly *a);

/* All three phases in this process: the byte-for-byte reference for a
 * parallel writer.  0, or a negative errno with its message in err (err
 * NULL: none). */
int vod_write(vod_source *s, const vod_params *p, vod_sink *sink,
              vod_stats *st, err_info *err);
/* vod_write of an octree.  Uses t->agg if set (capacity t->used), else
 * allocates and frees one (t->agg is NULL again on return). */
int vod_write_octree(octree *t, const vod_params *p, vod_sink *sink,
                     vod_stats *st, err_info *err);
/* A sink writing to a file descriptor. */
int vod_fd_write(void *fd_as_ptr, const void *buf, size_t n);
/* A sink into memory: ud is a vod_membuf, zeroed at first, that grows as
 * needed (-ENOMEM when it cannot); free(p) when done. */
typedef struct {
    uint8_t *p;
    size_t n, cap;
} vod_membuf;
int vod_mem_write(void *membuf, const void *buf, size_t n);

/* ---- reading ---- */

typedef struct vod_file vod_file;

typedef struct {
    uint32_t version;
    uint32_t volume[3];
    uint32_t brick;
    float voxel_scale[3];
    uint32_t height, voxel_bits, hash, comp, flags;
    uint64_t nodes;
    uint32_t bricks;
    int has_trailer;
    float origin[3];
    uint32_t channel;
    const char *metadata; /* NUL-terminated copy, "" if none */
    uint32_t crc32;
    uint64_t file_bytes;
    uint64_t brick_data_bytes; /* sum of dataSize */
} vod_info;

/* Parse and fully validate a file image (copied).  Returns 0, or -EINVAL /
 * -EBADMSG with a message in err naming what is wrong, or -ENOMEM (err may
 * be NULL: no message; its code and msg are cleared first). */
int vod_read(const void *buf, size_t len, vod_file **out, err_info *err);
int vod_open(const char *path, vod_file **out, err_info *err);
/* vod_read and vod_open with up to `threads` threads (this one included)
 * inflating and hashing the bricks, for callers that have the cores: the
 * same checks, result and, for a damaged file, the same error and message
 * (the first bad brick record in file order) as with one. */
int vod_read_threads(const void *buf, size_t len, int threads, vod_file **out,
                     err_info *err);
int vod_open_threads(const char *path, int threads, vod_file **out, err_info *err);
/* vod_open_threads keeping the bricks of some levels only (bit l of levels:
 * level l; bits past the file's levels ignored), for the readers of one
 * level (vox mesh, export, render): the header, the octree, the brick
 * table, every record's extents and the trailer's CRC are checked as
 * vod_open checks them, but only the bricks that nodes of those levels
 * hold are inflated and hashed (the mip levels above level 0 are about a
 * seventh more), so a damaged brick that only other levels hold is not
 * found (vod_open and vod_scan find it).  Other levels read as if absent:
 * vod_voxel 0, vod_brick NULL, the walks -EINVAL. */
#define VOD_LEVELS_ALL UINT32_MAX
int vod_open_levels(const char *path, int threads, uint32_t levels, vod_file **out,
                    err_info *err);
/* vod_open_levels of a file image in memory (copied), as vod_read_threads. */
int vod_read_levels(const void *buf, size_t len, int threads, uint32_t levels, vod_file **out,
                    err_info *err);
/* vod_open_threads without keeping the bricks: the same checks, result and
 * messages; each brick, once inflated and checked, is handed to fn for
 * every node that holds it (its level and brick coordinates, the file's
 * info but its metadata) on one of the scan's threads (thread 0 ..
 * threads - 1), then dropped, so the memory is the file's mapping and
 * tables and one brick a thread, not its raw volume (vox info); a brick
 * that many nodes share is kept (keep_bytes of them at most) until the
 * file has checked, and its nodes dealt to every thread.  fn runs on several
 * threads at once, in no set order, and may have run for a file that is
 * then refused: keep what it finds per thread, and use it only when this
 * returns 0.  *out has the file's info; its voxels are not there
 * (vod_voxel reads 0, vod_brick NULL, the walks return -EINVAL). */
typedef void (*vod_scan_fn)(void *ud, unsigned thread, const vod_info *in, int level,
                            const uint32_t b[3], const uint8_t *raw);
#define VOD_SCAN_KEEP ((uint64_t)64 << 20) /* vod_scan_opts.keep_bytes, by default */
typedef struct {
    int threads;         /* 1 or more */
    uint64_t keep_bytes; /* the shared bricks kept, at most (0: none) */
    vod_scan_fn fn;
    void *ud;
} vod_scan_opts;
int vod_scan(const char *path, const vod_scan_opts *o, vod_file **out, err_info *err);
void vod_close(vod_file *f);
const vod_info *vod_get_info(const vod_file *f);

/* Voxels per axis of the padded cube at level l: N >> l (0 for a level
 * outside 0..treeHeight-1).  vod_voxel accepts coordinates below it. */
uint32_t vod_level_size(const vod_file *f, int level);
/* The volume at level l: ceil(volumeSize[a] / 2^l) per axis, the extent
 * vod_foreach visits.  Returns -EINVAL for a level out of range. */
int vod_level_dims(const vod_file *f, int level, uint32_t dims[3]);
/* The voxel value at level l (0 = full resolution): 1-bit voxels read 0/1,
 * 8/16/32-bit voxels their unsigned value; 0 outside the padded cube. */
uint32_t vod_voxel(const vod_file *f, int level, uint32_t x, uint32_t y,
                   uint32_t z);
/* The raw brick (section 5's layout at vod_get_info's voxel_bits) of the
 * level-l node at brick coordinates b (each below vod_level_size / brick),
 * or NULL when that node is empty (all its voxels 0) or b is outside the
 * tree: for readers that copy whole bricks (vox export). */
const uint8_t *vod_brick(const vod_file *f, int level, const uint32_t b[3]);
/* Call fn for every non-zero voxel of level l inside vod_level_dims, brick
 * by brick in preorder, x fastest inside a brick; stops early and returns
 * fn's value if it returns non-zero; -EINVAL for a level out of range. */
int vod_foreach(const vod_file *f, int level,
                int (*fn)(void *ud, uint32_t x, uint32_t y, uint32_t z,
                          uint32_t v),
                void *ud);

/* The non-zero voxels of one raw brick, at level l and brick coordinates b
 * of a file of info in, inside vod_level_dims, to fn as vod_foreach gives
 * them; stops early with fn's non-zero value; -EINVAL for a level out of
 * range.  For vod_scan's fn. */
int vod_brick_foreach(const vod_info *in, int level, const uint32_t b[3], const uint8_t *raw,
                      int (*fn)(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v),
                      void *ud);

/* Call fn for every non-empty brick of level l, in preorder, with its
 * brick coordinates within the level and its raw bytes (section 5's
 * layout; bricks the file shares give the same pointer); stops early and
 * returns fn's value if it returns non-zero; -EINVAL for a level out of
 * range.  For readers that take whole bricks (vox mesh). */
int vod_foreach_brick(const vod_file *f, int level,
                      int (*fn)(void *ud, const uint32_t b[3], const uint8_t *raw),
                      void *ud);

/* ---- building blocks (exposed for tests and the parallel writer) ---- */


/* Hashes of the spec: SuperFastHash (0 for len 0, as the reference code)
 * and xxHash32 with seed 0; vod_hash picks by VOD_HASH_*. */
uint32_t vod_hash_sfhs(const void *data, size_t len);
uint32_t vod_hash_xx32(const void *data, size_t len);
/* vod_hash_sfhs of four buffers of len bytes each, into out[0..3]: the
 * hash is one serial chain, so four are computed in the lanes of a vector
 * (about the time of one; SSE2, else one after another). */
void vod_hash_sfhs4(const void *const data[4], size_t len, uint32_t out[4]);
uint32_t vod_hash(uint32_t alg, const void *data, size_t len);
/* A FourCC as text for messages ("ZLIB"; '?' for unprintable bytes). */
const char *vod_fourcc_str(uint32_t v, char buf[5]);

/* RUNL (spec section 6) over raw bricks of voxel_bits 1, 8, 16 or 32:
 * pairs {u8 count-1, voxel}, voxels of 1 bit taken as whole raw bytes. */
size_t vod_runl_bound(uint32_t voxel_bits, size_t raw);
/* Encode raw bytes; returns the encoded size, or 0 if cap is too small. */
size_t vod_runl_encode(uint32_t voxel_bits, const uint8_t *raw, size_t n,
                       uint8_t *out, size_t cap);
/* Decode exactly raw_n bytes from exactly n bytes of in: 0, or -EBADMSG
 * when a run passes raw_n, the input ends inside a pair or before raw_n
 * bytes, or bytes are left over. */
int vod_runl_decode(uint32_t voxel_bits, const uint8_t *in, size_t n,
                    uint8_t *raw, size_t raw_n);

/* A zlib stream for a raw brick in one pass (vod_deflate.c says how): the
 * encoder's compressor at levels 1..VOD_SPARSE_LEVEL.  A vod_sparse holds
 * the scratch for bricks of one size and voxel size (brick^3 voxels, brick
 * 2..VOD_SPARSE_MAX_BRICK, voxel_bits 1, 8 or 32): 0, -EINVAL or
 * -ENOMEM. */
#define VOD_SPARSE_MAX_BRICK 64u
typedef struct vod_sparse vod_sparse;
int vod_sparse_new(uint32_t brick, uint32_t voxel_bits, vod_sparse **out);
void vod_sparse_free(vod_sparse *z);
/* Compress the brick^3 voxels of raw (n bytes, at most the size given to
 * vod_sparse_new, whole voxels) into out; returns the size, or 0 when cap
 * is too small or n too large. */
size_t vod_sparse_compress(vod_sparse *z, const uint8_t *raw, size_t n, uint8_t *out,
                           size_t cap);

static inline uint32_t vod_get32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 |
           (uint32_t)p[3] << 24;
}
static inline void vod_put32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
}

/* Voxel i (x fastest) of a raw brick of bits-bit voxels (section 5's
 * layout): what vod_voxel reads, for a reader that holds the brick
 * (vod_brick). */
static inline uint32_t vod_raw_voxel(const uint8_t *raw, uint32_t bits, size_t i)
{
    switch (bits) {
    case 1: return raw[i >> 3] >> (i & 7) & 1u;
    case 8: return raw[i];
    case 16: return (uint32_t)raw[2 * i] | (uint32_t)raw[2 * i + 1] << 8;
    default: return vod_get32(raw + 4 * i);
    }
}

#endif
