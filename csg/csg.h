/* csg — volume constructive solid geometry on 8-bit densities (ICVG).
 *
 * A tree is a flat list of nodes in which every child has a smaller index
 * than its parent (so the list is its own bottom-up order, and the wire
 * form later needs no nesting); the last node is the result.  Leaves are
 * the ICVG primitives (virtual volume sampling functions with the layers
 * L = 0 < S = 127 < H = 255) and implicit expressions; the inner nodes are
 * the ICVG algebra, erosion and dilation.  docs/csg.md gives every formula.
 *
 * Evaluation is brick by brick: csg_eval_brick() computes one cubic brick
 * of the grid from (tree, grid, brick) alone, so bricks may be computed in
 * any order, by any process, and give the same bytes.
 */
#ifndef VOXD_CSG_H
#define VOXD_CSG_H

#include <stddef.h>
#include <stdint.h>

#include "csg_limits.h"
#include "err.h"
#include "expr.h"
#include "grid.h"
#include "mesh_vox.h"
#include "vod_volume.h"

#define CSG_L 0u
#define CSG_S 127u
#define CSG_H 255u

/* CSG_MAX_NODES, CSG_MAX_MORPH, CSG_MAX_MARGIN, CSG_NAME_MAX: csg_limits.h */
#define CSG_MAX_DEPTH 64u        /* longest path from the result to a leaf */
#define CSG_MAX_SOURCE 65536u    /* bytes of a .csg text */
#define CSG_MAX_LEAF_FILE ((size_t)4 << 30) /* bytes of a mesh or vod leaf's file */
#define CSG_VOLUME_BRICK 16u     /* storage brick of the result's vod_volume */
#define CSG_IMPLICIT_RAMP 1.0    /* voxels from S to L (or H) of an implicit leaf */

typedef enum {
    /* leaves */
    CSG_CUBOID, CSG_ELLIPSOID, CSG_CYLINDER, CSG_CONE, CSG_IMPLICIT,
    CSG_MESH, CSG_VOD,   /* a file's bytes made a volume on the job's grid (csg_leaf_build) */
    /* binary (a, b) */
    CSG_UNION, CSG_INTERSECTION, CSG_TRIM, CSG_CAP, CSG_DIFFERENCE_A,
    CSG_DIFFERENCE_B, CSG_DIFFERENCE, CSG_ADD, CSG_MODULATE, CSG_DIVIDE_A,
    CSG_DIVIDE, /* param: S_L in (0, 1] */
    /* unary (a) */
    CSG_INVERSE, CSG_SCALAR_ADD, CSG_SCALAR_MUL, /* param: the scalar */
    CSG_ERODE, CSG_DILATE,                        /* k: box half-width */
    CSG_KIND_COUNT
} csg_kind;

typedef struct {
    csg_kind kind;
    char name[CSG_NAME_MAX];
    int32_t a, b;          /* children (indices below this node), -1: none */
    double param;          /* divide's S_L, a scalar */
    uint32_t k;            /* erode / dilate; a distance leaf's band (csg_tree_set_band) */
    /* primitives: centre, full size along the local axes (x, y, z), rotation (radians, applied
     * about x, then y, then z) */
    double center[3], size[3], rot[3];
    double m[3][3];        /* world -> local rotation, from rot */
    int axis;              /* cylinder, cone: the local axis along which
                              size[axis] is the height (default 2: z) */
    /* implicit: the expression (offset into the tree's text pool) and an
     * optional cubic domain outside which the leaf is L */
    uint32_t expr_off, expr_len;
    int has_domain;
    double dom_lo, dom_hi;
    /* mesh, vod: the file's name as written (offset into the text pool);
     * mesh: with has_fit, its bounding box's centre moved to fit[] and its
     * longest side made `scale` world units; without, its coordinates
     * multiplied by scale (1 when not given) */
    uint32_t path_off, path_len;
    int has_fit;
    double fit[3], scale;
} csg_node;

/* 1 for a leaf kind (no children). */
static inline int csg_is_leaf(csg_kind k) { return k <= CSG_VOD; }

typedef struct {
    uint32_t n;
    csg_node node[CSG_MAX_NODES];
    char *text;            /* the implicit leaves' sources and the file leaves'
                              names, NUL-separated */
    size_t text_len;
    /* mesh and vod leaves: the file's bytes (malloc'd, the tree's: freed
     * by csg_tree_free), set by whoever reads the files (vox) or receives
     * them (the daemon); NULL for other nodes */
    void *data[CSG_MAX_NODES];
    size_t data_len[CSG_MAX_NODES];
} csg_tree;

/* The project's error (common/err.h: code the errno returned, msg what
 * is wrong) and where: the place in the text and the definition's name. */
typedef struct {
    ERR_INFO_EMBED(info);
    int line, col;         /* 1-based; 0 when none */
    char node[CSG_NAME_MAX];
} csg_error;

/* Parse a .csg text (docs/csg.md).  0 and *out (free with csg_tree_free),
 * -EINVAL with err filled for a bad text, -E2BIG for a limit, -ENOMEM. */
int csg_parse(const char *src, size_t len, csg_tree **out, csg_error *err);
void csg_tree_free(csg_tree *t);
/* The kind's name as the text writes it ("union", "cuboid"...). */
const char *csg_kind_name(csg_kind k);

/* The operator op on densities a, b (b ignored by unary ones), exactly as
 * docs/csg.md defines it; param and k as in the node. */
uint8_t csg_apply(csg_kind op, uint8_t a, uint8_t b, double param);
/* The primitive n sampled at the world point p, with voxels of size vs. */
uint8_t csg_prim_sample(const csg_node *n, const double p[3], double vs);
/* The node's rotation matrix from its angles (the parser calls it). */
void csg_node_rotation(csg_node *n);

/* ---- file leaves (csg_leaf.c) ---- */

/* The 8-bit volume of a mesh or vod leaf on grid g, from the node's file
 * bytes, into vol (g->res, csg_leaf_bits(node) bits, empty): a mesh through
 * the mesh voxelizer's density channel (solid, 4^3 samples a voxel: the
 * fraction inside, so its surface lands on S), placed by fit and scale, or
 * with a band (k > 0: channel 4) its signed distance (f32, mesh_dist); a VOD file's
 * level 0 at each voxel centre of g (nearest: the file voxel whose box holds
 * the centre; L outside the file), occupancy 1 as H, density as it is,
 * surface voxels as H where occupied (by up to `threads` threads of the
 * caller: the engine's master gives its workers' count, the serial
 * pipeline 1).  Done once per job, before any brick.
 * 0, or a negative errno with err (not NULL) saying why (-EINVAL a file
 * that does not load, -ENOMEM the volume's pool is full). */
int csg_leaf_build(const csg_tree *t, uint32_t i, const grid_spec *g, vod_volume *vol,
                   unsigned threads, err_info *err);
/* Mesh leaf i's mesh parsed from its bytes and placed (fit, scale) into
 * *m (mesh_free it), and the options csg_leaf_build voxelizes it with into
 * *o: what the engine's workers build the leaf's volume from, tile by tile
 * (mesh_tile_run), the same volume.  0, or a negative errno with err. */
int csg_leaf_mesh(const csg_tree *t, uint32_t i, mesh *m, mesh_vox_opts *o, err_info *err);
/* The memory the file leaves' volumes are built in, one after the other. */
typedef struct {
    void *base;   /* 8-byte aligned */
    size_t bytes; /* its length */
    size_t used;  /* set by csg_leaves_build: the bytes the volumes take */
} csg_arena;
/* Every file leaf of t built in turn (csg_leaf_build, one thread) into arena a:
 * leaves[i] for each (NULL for the other nodes), a->used the bytes they
 * take.  0, or the first leaf's error in err (-ENOSPC, -ENOMEM: the arena
 * is too small). */
int csg_leaves_build(const csg_tree *t, const grid_spec *g, csg_arena *a,
                     vod_volume *leaves[CSG_MAX_NODES], err_info *err);
/* 1 when t has a mesh or vod leaf. */
int csg_has_file_leaves(const csg_tree *t);

/* An evaluator: scratch buffers and the implicit leaves' compiled tapes.
 * One per thread. */
typedef struct csg_eval csg_eval;
typedef struct {
    uint64_t bricks, uniform_bricks;  /* results */
    uint64_t skipped;     /* operand subtrees decided without evaluation */
    uint64_t voxel_evals; /* voxels a leaf sampled */
    uint64_t solid_voxels; /* stored voxels (inside the grid) with density >= S */
} csg_stats;

/* leaves: for each mesh or vod node i, leaves[i] is its volume
 * (csg_leaf_build, 8 bits, dims g->res); NULL when the tree has none. */
int csg_eval_new(const csg_tree *t, const grid_spec *g, uint32_t side,
                 const vod_volume *const *leaves, csg_eval **out);
void csg_eval_free(csg_eval *e);
/* Brick b (brick coordinates: voxels b*side .. b*side+side-1 per axis) of
 * the result into out (side^3 bytes, x fastest), or *uniform = 1 and
 * *value when every voxel has one value (out then untouched).  Voxels past
 * the grid are computed too (the caller masks them).  0 or -ENOMEM. */
int csg_eval_brick(csg_eval *e, const uint32_t b[3], uint8_t *out, int *uniform,
                   uint8_t *value);
const csg_stats *csg_eval_stats(const csg_eval *e);
/* Brick b of the result stored into vol (storage brick side as the
 * evaluator's, csg_channel_bits(channel) bits) for the VOD channel
 * (voxel.h): DENSITY the densities; OCCUPANCY 1 where >= S, else 0;
 * SURFACE an occupied voxel (voxel_surface) where >= S, its normal minus
 * the density's central-difference gradient (the tree is evaluated over
 * the brick grown by one voxel).  A uniform brick is a table entry, voxels
 * past the grid are 0.  buf: side^3 voxels of scratch.  Bricks may be
 * stored concurrently (vod_volume_put_brick).  0 or a negative errno
 * (-ENOMEM: the volume's pool is full). */
int csg_eval_store(csg_eval *e, vod_volume *vol, const uint32_t b[3], void *buf, int channel);
/* The voxel bits of a channel's volume: 8 (density, occupancy), 32
 * (surface), 0 for a channel CSG does not write. */
uint32_t csg_channel_bits(int channel);

/* Every brick of vol (its storage brick side) in turn, for the channel as
 * csg_eval_store.  0 or a negative errno. */
int csg_eval_volume(const csg_tree *t, const grid_spec *g, const vod_volume *const *leaves,
                    vod_volume *vol, int channel, csg_stats *st);
/* Some bricks of a volume, for a channel: those b with lo[a] <= b[a] <
 * hi[a] (storage brick coordinates; a hi past the volume's end stops at
 * its end). */
typedef struct {
    vod_volume *vol;
    int channel;
    uint32_t lo[3], hi[3];
} csg_bricks;
/* The bricks of part p alone, as csg_eval_volume stores them: vox_mpi's
 * subtrees. */
int csg_eval_bricks(const csg_tree *t, const grid_spec *g, const vod_volume *const *leaves,
                    const csg_bricks *p, csg_stats *st);

/* ---- a tree's signed distance, channel 4 (csg_deval.c) ---- */

/* 0 when the tree's result (the nodes it reaches) has a signed distance:
 * implicit leaves without a domain and mesh leaves, combined by union
 * (min), intersection (max), difference (max(a, -b)) and inverse (-a);
 * else -ENOTSUP with err naming the first node that has none.  The tree
 * has a node (checked where it came in). */
int csg_dist_check(const csg_tree *t, err_info *err);
/* Every implicit and mesh leaf's k := band (voxels each side, 0: the
 * default): what the distance channel's evaluation and csg_leaf_build
 * read (a mesh leaf with k > 0 is built as its distance, f32). */
void csg_tree_set_band(csg_tree *t, uint32_t band);
/* The voxel bits of node i's leaf volume (csg_leaf_build): VOD_VOLUME_F32
 * for a mesh leaf with a band (k > 0), else 8. */
uint32_t csg_leaf_bits(const csg_node *n);

/* ---- the signed distance of an implicit surface (csg_dist.c) ---- */

/* The band's width in voxels, at most; values are within CSG_DIST_EPS
 * voxel above the length of a segment from the centre to the foot point
 * (docs/expressions.md). */
#define CSG_DIST_MAX_BAND 64u
#define CSG_DIST_EPS 1e-4

typedef struct csg_dist csg_dist;
typedef struct {
    uint64_t band_voxels;   /* voxels whose value was computed */
    uint64_t projected;     /* ... by the certified foot point */
    uint64_t marched;       /* ... by the march along 27 directions */
} csg_dist_stats;

/* The distance to t's F = 0 on grid g in a band of `band` voxels each side
 * (1..CSG_DIST_MAX_BAND).  One per thread.  0, -EINVAL, -ENOMEM. */
int csg_dist_new(const expr_tape *t, const grid_spec *g, uint32_t band, csg_dist **out);
void csg_dist_free(csg_dist *d);
/* The cube of n^3 voxels (n a power of two) from voxel lo into out (f32,
 * x fastest): the signed distance in world units, negative inside (F < 0),
 * within the band; beyond it +-W (W = band * vs, as a float); 0 past the
 * grid.  0 or -EINVAL. */
int csg_dist_brick(csg_dist *d, const uint32_t lo[3], uint32_t n, float *out);
/* The value of one voxel centre c (world) in the band: its sign F's,
 * decided by intervals (0 where they leave it open), its magnitude a
 * certified upper bound of the distance to F = 0, at most W. */
float csg_dist_voxel(csg_dist *d, const double c[3]);
const csg_dist_stats *csg_dist_get_stats(const csg_dist *d);

#endif
