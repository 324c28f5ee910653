/* vod — brick-octree VOD files (docs/vod-format.md), written and read.
 *
 * Writing happens in three phases so that the middle one can run in
 * parallel in the worker processes:
 *   1. master:  vod_layout(), vod_aggregate(), vod_collect()  — plan
 *   2. workers: vod_encode() for each collected brick node     — fill, hash, compress
 *   3. master:  vod_assemble()                                 — dedup, lay out, write
 * vod_write_octree() runs all three in-process.
 *
 * Reading (vod_read/vod_open) validates the whole file up front — every case of
 * section 8 of the spec is refused with a message naming what is wrong — so a
 * vod_file, once open, is trusted by every accessor.
 */
#ifndef VOXD_VOD_H
#define VOXD_VOD_H

#include <stddef.h>
#include <stdint.h>

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

/* What the writer is asked to produce. */
typedef struct {
    uint32_t volume[3];     /* volumeSize: the voxels asked for, each >= 1 */
    uint32_t brick;         /* 2^k, 1 <= k <= 8; default 16 */
    int channel;            /* VOXEL_CH_SURFACE (32 bit) or VOXEL_CH_OCCUPANCY (1 bit) */
    uint32_t comp;          /* VOD_COMP_* ; default ZLIB */
    uint32_t hash;          /* VOD_HASH_* ; default SFHS */
    int zlib_level;         /* 1..9, default 6 */
    float voxel_scale[3];   /* world size of a voxel */
    float origin[3];        /* world position of voxel (0,0,0)'s low corner */
    const char *metadata;   /* "key=value\n" lines, or NULL */
} vod_params;

void vod_params_default(vod_params *p);

/* The shape of the file for params p over an octree of octree_depth. */
typedef struct {
    uint32_t brick, brick_log2; /* brick size and k */
    uint32_t height;            /* treeHeight */
    uint32_t padded;            /* N = brick * 2^(height-1) */
    uint32_t voxel_bits;        /* 1 or 32 */
    size_t raw_bytes;           /* bytes of one raw brick */
    uint64_t nodes;             /* (8^height - 1) / 7 */
    int octree_depth;
} vod_layout;

/* Validate p against the spec and compute the layout.  -EINVAL with a
 * message in err for bad params (also when the volume is larger than the
 * octree's 2^octree_depth cube), -EFBIG when the octree table alone would
 * pass 4 GiB.  The padded side N is 2^octree_depth, smaller than it (an
 * octree deeper than the volume needs: the file's root is the cell that
 * covers [0, N)^3), or the brick itself when the brick is larger than the
 * whole octree (treeHeight 1). */
int vod_layout_make(const vod_params *p, int octree_depth, vod_layout *L,
                    char *err, size_t errlen);

/* One non-empty brick node of the complete tree. */
typedef struct {
    uint64_t preorder; /* index in the file's octree table */
    uint32_t level;    /* 0 = full-resolution leaf bricks */
    uint32_t bx, by, bz; /* brick coordinates within its level */
} vod_node;

/* Phase 1 precondition: the spec wants 0 outside volumeSize, so the tree must
 * hold no voxel there.  Checks it by walking only the cells that straddle
 * the volume's high faces.  0, or -EINVAL with the first such voxel in err. */
int vod_check_volume(const octree *t, const uint32_t volume[3], char *err,
                     size_t errlen);

/* Phase 1.  Fill t->agg (capacity t->used) with each cell's downsampled
 * value (spec section 3) so any level's brick can be read off the tree:
 * a level-l voxel (l >= 1) is agg of the cell of height l-1 covering it.
 * Channel 3: occupancy = mean of the 8 children's occupancy bytes, rounded
 * half up; normal = the normalized sum of the normals of the children whose
 * occupancy is > 0; a parent whose occupancy rounds to 0 is 0 (no voxel).
 * Channel 1: 1 iff any child is non-zero.  O(cells), recursive to depth. */
void vod_aggregate(octree *t, int channel);
/* Phase 1.  Write the non-empty brick nodes in preorder to out (up to cap);
 * returns how many there are (call with out = NULL to count).  A node is
 * non-empty iff its full-resolution region holds a voxel; such a node gets a
 * brick even if downsampling made all of it 0.  Visits only existing cells. */
size_t vod_collect(const octree *t, const vod_layout *L, vod_node *out,
                   size_t cap);

/* Phase 2: one brick. */
typedef struct {
    uint32_t hash;      /* hash of the raw brick */
    uint32_t size;      /* bytes written to out */
} vod_encoded;
/* Largest encoded size of one brick (bytes out must hold). */
size_t vod_encode_bound(const vod_layout *L, const vod_params *p);
/* Fill node n's raw brick from the tree (scratch holds L->raw_bytes), hash
 * it and compress it into out.  ZLIB reuses one deflate stream per thread
 * (see vod_encode_cleanup); the bytes depend only on the raw brick and p.
 * Returns 0, -ENOBUFS when cap is too small, -EINVAL for a node outside the
 * layout or a level >= 1 without t->agg. */
int vod_encode(const octree *t, const vod_layout *L, const vod_params *p,
               const vod_node *n, uint8_t *scratch, uint8_t *out, size_t cap,
               vod_encoded *rec);

/* Frees the calling thread's cached deflate stream (a thread that used
 * vod_encode should call it before it exits; a process need not). */
void vod_encode_cleanup(void);

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
} vod_stats;

/* Phase 3.  data[i] holds recs[i].size encoded bytes of nodes[i] (nodes in
 * preorder, as vod_collect gave them).  Duplicates (same hash, same bytes)
 * are stored once, IDs 1..n in order of first use.  -EINVAL for nodes not
 * strictly increasing in preorder or a size above vod_encode_bound, -EFBIG
 * when the file would pass 4 GiB, -ENOMEM, each with its message in err;
 * or the sink's error, with err left empty (the sink's owner knows why). */
int vod_assemble(const vod_layout *L, const vod_params *p, size_t n,
                 const vod_node *nodes, const vod_encoded *recs,
                 const uint8_t *const *data, vod_sink *sink, vod_stats *st,
                 char *err, size_t errlen);

/* All three phases in this process: the byte-for-byte reference for a
 * parallel writer.  Uses t->agg if set (capacity t->used), else allocates
 * and frees one (t->agg is NULL again on return). */
int vod_write_octree(octree *t, const vod_params *p, vod_sink *sink,
                     vod_stats *st, char *err, size_t errlen);
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
 * -EBADMSG with a message in err naming what is wrong, or -ENOMEM. */
int vod_read(const void *buf, size_t len, vod_file **out, char *err,
             size_t errlen);
int vod_open(const char *path, vod_file **out, char *err, size_t errlen);
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
/* Call fn for every non-zero voxel of level l inside vod_level_dims, brick
 * by brick in preorder, x fastest inside a brick; stops early and returns
 * fn's value if it returns non-zero; -EINVAL for a level out of range. */
int vod_foreach(const vod_file *f, int level,
                int (*fn)(void *ud, uint32_t x, uint32_t y, uint32_t z,
                          uint32_t v),
                void *ud);

/* ---- building blocks (exposed for tests and the parallel writer) ---- */

/* Hashes of the spec: SuperFastHash (0 for len 0, as the reference code)
 * and xxHash32 with seed 0; vod_hash picks by VOD_HASH_*. */
uint32_t vod_hash_sfhs(const void *data, size_t len);
uint32_t vod_hash_xx32(const void *data, size_t len);
uint32_t vod_hash(uint32_t alg, const void *data, size_t len);

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

#endif
