/* mpi_part — what vox_mpi does that is not talking MPI: the job cut into
 * subtrees, one subtree voxelized and its bricks encoded on a rank, rank
 * 0's book of the bricks it holds, and the levels above the subtrees.
 *
 * The seam.  A VOD file is a complete brick octree over the grid's octree
 * (docs/vod-format.md): the brick node of level l covers a cube of
 * brick * 2^l voxels, and its brick depends on the voxels of that cube
 * alone.  Rank 0 cuts the grid at octree level s (cubes of 2^s voxels,
 * s > log2(brick)), keeping the octants the subdivision's own interval
 * tests keep; a subtree's VOD nodes are then those of level s - log2(brick)
 * and below inside its cube, and a rank makes them exactly as one process
 * would: the same boxes tested, the same voxels, the same mip levels, the
 * same bytes per brick.  The nodes above (the "top") mix subtrees; rank 0
 * makes them from each subtree's brick of level s - log2(brick), which the
 * rank sends beside its records (the non-zero voxels only): a level-l voxel
 * is made from the 8 level-(l-1) voxels below it (spec section 3), so the
 * top needs nothing else.  Rank 0 then has every node's encoded brick in
 * preorder and vod_assemble writes the same file as vox voxelize.
 */
#ifndef VOXD_MPI_PART_H
#define VOXD_MPI_PART_H

#include <stddef.h>
#include <stdint.h>
#include <sys/mman.h>

#include "csg.h"
#include "csg_pack.h"
#include "engine.h"
#include "err.h"
#include "expr.h"
#include "grid.h"
#include "mesh.h"
#include "mesh_vox.h"
#include "vod.h"

/* ---- the cut ---- */

typedef struct {
    grid_octant *oct;   /* the kept octants of level `level`, in preorder */
    size_t n;
    int level;          /* s: the subtrees' octree level */
    uint32_t node_level; /* their VOD node level (the top is above it) */
    uint64_t tested;    /* boxes rank 0 tested to find them */
} mpi_cut;

/* The subtrees' VOD node level for cut level s of a grid of depth `depth`:
 * s - log2(brick), or the root's level when s is the whole grid. */
uint32_t mpi_node_level(const vod_layout *L, int depth, int s);
/* Subdivide the grid from its root with the subdivision kernel's interval
 * tests (the boxes and tapes every job tests) until there are at least
 * `target` kept octants or the next level would be a brick or smaller
 * (subtrees stay above the brick: levels log2(brick) + 1 and up).  0 or
 * -ENOMEM / the vm's error. */
int mpi_cut_make(const expr_tape *tape, const grid_spec *g, const vod_layout *L,
                 size_t target, mpi_cut *out);
void mpi_cut_free(mpi_cut *c);
/* The cut of a mesh or CSG job, which has no interval test: level s the
 * lowest at or above min_level (and above the brick) that still gives at
 * least `target` tasks (the grid's whole depth when none does), and every
 * octant of level s that meets the grid, in preorder; with columns, one
 * octant per xy column of level s (z 0: the column through the whole grid
 * in z), in x fastest order.  0 or -ENOMEM. */
int mpi_cut_grid(const grid_spec *g, const vod_layout *L, size_t target, int min_level,
                 int columns, mpi_cut *out);

/* ---- a subtree on a rank ---- */

/* One brick node as it goes on the wire (48 bytes): where it is in the
 * file, its record and a 128-bit content hash of its encoded bytes, by
 * which rank 0 knows whether it holds those bytes already. */
typedef struct {
    uint64_t preorder;
    uint32_t level;
    uint32_t hash;      /* the file's hash of the raw brick (vod_encoded) */
    uint32_t size;      /* encoded bytes */
    uint32_t pad;
    uint64_t key[2];    /* XXH3-128 of the encoded bytes */
} mpi_rec;

/* A non-zero voxel of a subtree's top brick: its index in the brick's
 * raw layout (x fastest) and its value (0/1 for channel 1). */
typedef struct {
    uint32_t idx, value;
} mpi_pair;

/* A subtree's top brick (its node of level node_level): the subtree's
 * octant and how many of the task's pairs, in order, are its voxels. */
typedef struct {
    grid_octant o;
    uint32_t npairs;
} mpi_topref;

/* What a task gave: its nodes (level <= node_level, preorder), their
 * encoded bytes (valid only during the call), its subtrees' top bricks
 * (one per subtree that gave nodes: one for an octant, any number for a
 * mesh job's column) and their voxels, one top after the other. */
typedef struct {
    size_t n;
    const mpi_rec *recs;
    const uint8_t *const *data;
    size_t ntops;
    const mpi_topref *tops;
    size_t npairs;
    const mpi_pair *pairs;
    uint64_t voxels;    /* the task's */
} mpi_bricks;

/* Called once per subtree with its bricks; 0 or a negative errno. */
typedef int (*mpi_deliver)(void *ud, const mpi_bricks *b);

typedef enum { MPI_KIND_IMPLICIT = 1, MPI_KIND_MESH, MPI_KIND_CSG } mpi_kind;

/* A CSG job's file leaves over the whole grid, for a rank that runs its
 * tasks serially: built by its first task, kept for the others (each
 * task built them whole again: a mesh leaf voxelized once per octant). */
typedef struct {
    int built;
    void *arena; /* MAP_FAILED: none */
    size_t bytes;
    vod_volume *v[CSG_MAX_NODES];
} mpi_leaves;
#define MPI_LEAVES_INIT {.arena = MAP_FAILED}
void mpi_leaves_free(mpi_leaves *l);

typedef struct {
    mpi_kind kind;           /* 0: implicit */
    const expr_tape *tape;   /* implicit */
    const mesh *mesh;        /* mesh: the triangles the task's tiles need */
    mesh_vox_opts mesh_opts; /* ... the repair as run (none when watertight) */
    const csg_tree *tree;    /* csg, its file leaves' bytes with it */
    grid_spec grid;
    vod_params vod;      /* metadata unused */
    uint32_t node_level;
    engine *e;           /* NULL: the serial algorithm in this thread */
    engine_schedule schedule;
    mpi_leaves *leaves;  /* csg without e: kept across tasks (NULL: built per task) */
} mpi_subtree_job;

/* The tiles of a mesh job's column o (mesh_vox.h's tx0, ty0, tx1, ty1). */
void mpi_column_tiles(const grid_spec *g, grid_octant o, uint32_t tiles[4]);

/* Run task o of the job and encode its bricks, on the engine or serially,
 * then call deliver: an implicit job's octant (kept by its parent's
 * test), a CSG job's octant (its storage bricks alone), a mesh job's
 * column (o.x, o.y at o.level: its tiles alone, through the grid in z).
 * 0, or a negative errno with the reason in err. */
int mpi_subtree_run(const mpi_subtree_job *j, grid_octant o, mpi_deliver deliver,
                    void *ud, err_info *err);

/* ---- what mesh jobs send (mpi_wire.c; a CSG tree goes as csg_pack.h packs it) ---- */

/* The triangles the tiles need (bins: m's, for the job's grid and
 * options), with their vertices, as one buffer (malloc'd): the triangles
 * in m's order, so that a tile sees the same ones in the same order;
 * tiles NULL: every triangle (the winding number's repair reads them
 * all).  0 or -ENOMEM. */
int mpi_mesh_part(const mesh *m, const mesh_bins *bins, const uint32_t tiles[4],
                  uint8_t **out, size_t *len);
/* A mesh over such a buffer (4-byte aligned, kept while the mesh is
 * used), its indices checked and its bounding box found: 0 or -EPROTO. */
int mpi_mesh_view(const uint8_t *buf, size_t len, mesh *out);

/* ---- rank 0's book of bricks ---- */

/* Every distinct brick rank 0 has been told of, by content: held (its
 * bytes at an offset in the spill file) or asked for (pending). */
typedef struct {
    uint64_t key[2];
    uint32_t hash, size;
    uint64_t off;       /* in the spill, once held */
    int state;          /* 0 free slot, 1 asked for, 2 held */
} mpi_book_entry;

typedef struct {
    mpi_book_entry *slot;
    size_t cap, used;
} mpi_book;

void mpi_book_init(mpi_book *b);
void mpi_book_free(mpi_book *b);
/* The entry of r's content, made (state 1, asked for) when new: *fresh is
 * then 1 and the caller asks the rank for its bytes.  NULL: no memory.
 * The pointer is valid until the next call. */
mpi_book_entry *mpi_book_get(mpi_book *b, const mpi_rec *r, int *fresh);

/* The XXH3-128 key of encoded bytes. */
void mpi_key(const uint8_t *data, size_t n, uint64_t key[2]);

/* ---- the top ---- */

/* The nodes above the subtrees, made from their top bricks.  Add each
 * subtree's pairs, then mpi_top_encode calls put for every non-empty node
 * above node_level with its record and encoded bytes (valid during the
 * call), in preorder. */
typedef struct mpi_top mpi_top;
int mpi_top_new(const vod_layout *L, int depth, uint32_t node_level, mpi_top **out);
void mpi_top_free(mpi_top *t);
int mpi_top_add(mpi_top *t, grid_octant o, const mpi_pair *pairs, size_t n);
int mpi_top_encode(mpi_top *t, const vod_params *p,
                   int (*put)(void *ud, const vod_node *n, const vod_encoded *rec,
                              const uint8_t *data),
                   void *ud);

#endif
