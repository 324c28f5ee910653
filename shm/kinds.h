/* kinds — the kinds of job the engine runs, and what each keeps in the
 * shared segment's data area.
 *
 * A kind is a pair: its master side (engine/kind_<name>.c: set the job up
 * here, seed the work stack, take what the workers return, progress,
 * what a worker's death means, the result) and its worker side
 * (worker/work_<name>.c: begin a job, run one task).  The core (the pool,
 * the scheduler of Figure 3, the queues, the futexes, re-forking) serves
 * every kind alike.  This header is their contract: the kind's number,
 * its operations and record types, and its block in the data area, which
 * the master writes before the job's first task (published by the
 * task_seq release) and the workers read.
 *
 * Adding a kind: a number and a block here, one master file
 * (engine/kind_<name>.c and its header), one worker file
 * (worker/work_<name>.c), one row in each side's table
 * (engine/pipeline_kinds.h for a pipeline job's kind, worker/worker.c);
 * docs/design.md, "Adding a kind of job", lists every file.
 */
#ifndef VOXD_KINDS_H
#define VOXD_KINDS_H

#include <errno.h>
#include <stdatomic.h>
#include <stdint.h>
#include <string.h>

#include "grid.h"
#include "iso.h"
#include "mesh_vox.h"
#include "shm.h"
#include "vod.h"

enum shm_kind {
    SHM_KIND_CORE = 0,     /* the pool's own tasks (SHM_OP_EXIT) */
    SHM_KIND_IMPLICIT = 1, /* F(x,y,z) = 0 by interval subdivision */
    SHM_KIND_ENCODE = 2,   /* the VOD's bricks of the last job, in parallel */
    SHM_KIND_MESH = 3,     /* a triangle mesh, tile by tile, into a volume */
    SHM_KIND_CSG = 4,      /* a volume CSG tree, brick by brick, into a volume */
    SHM_KIND_ISO = 5,      /* marching cubes over a VOD file's bricks */
    SHM_KINDS
};

/* ---- implicit: Stolte–Kaufman subdivision of an expression ---- */

enum implicit_op {
    IMPLICIT_CHILDREN = 1, /* test the octant's children, return the kept */
    IMPLICIT_SUBTREE = 2,  /* build the octant's subtree in the arena */
};
enum implicit_record {
    IMPLICIT_OCTANTS = 1,  /* grid_octant: kept child octants */
    IMPLICIT_VOXELS = 2,   /* grid_voxel: a voxel (the paper schedule) */
    IMPLICIT_BUILT = 3,    /* implicit_subtree: a subtree built, one per task */
};

/* What IMPLICIT_SUBTREE returns once the octant's subtree is built (and
 * nothing when it holds no voxel): the root cell of its `cells` cells, a
 * cell of height o.level-1 in the arena, and its voxels.  Its cells all
 * lie below `end` (the worker's next cell: a worker's blocks come in the
 * arena's order).  The master links the root into the tree (octree_link);
 * it never reads the cells below. */
typedef struct {
    grid_octant o;         /* the task's octant */
    uint32_t root, cells, end;
    uint64_t voxels;
} implicit_subtree;

/* The octree's arena is shared: the master and every worker building a
 * subtree take blocks of OCTREE_BLOCK_CELLS cells from one counter.  Block
 * b is cells [1 + b*B, 1 + (b+1)*B) of the arena (cut at tree_cells);
 * block 0 is the master's from the start (the root, cell 1), the counter
 * starts at 1.  owners (u16 per block at owners_off) says who claimed a
 * block: 1 + a worker's index, or IMPLICIT_MASTER. */
#define IMPLICIT_MASTER 0xffffu

typedef struct {
    grid_spec grid;
    uint64_t tape_off, tape_bytes;   /* the compiled expression */
    uint64_t tree_off, owners_off;   /* the arena's cells, the blocks' owners */
    uint32_t tree_cells, blocks;     /* the arena's cells, blocks in it */
    /* The next block to hand out: fetch_add by whoever needs one (relaxed:
     * only the blocks' uniqueness matters; the cells written in a block
     * reach the master with the worker's queue entry, release/acquire, and
     * the final count is read after every worker's done_seq acquire). */
    _Alignas(64) atomic_uint next_block;
} implicit_block;

static inline _Atomic uint16_t *implicit_owners(uint8_t *base, const implicit_block *b)
{
    return (_Atomic uint16_t *)(base + b->owners_off);
}

/* Claim the next block of the arena for `who`: its cells [*first, *end).
 * 0, or -ENOMEM once every block is handed out. */
static inline int implicit_claim(uint8_t *base, implicit_block *b, uint16_t who,
                                 uint32_t *first, uint32_t *end)
{
    unsigned n = atomic_fetch_add_explicit(&b->next_block, 1, memory_order_relaxed);
    if (n >= b->blocks) return -ENOMEM;
    /* relaxed: the claimer's own mark, published to the master with the
     * subtree's entry (the queue's release/acquire); a read of another's
     * block sees 0 or that claimer's number, never the reader's. */
    atomic_store_explicit(&implicit_owners(base, b)[n], who, memory_order_relaxed);
    *first = 1 + n * OCTREE_BLOCK_CELLS;
    *end = b->tree_cells - *first > OCTREE_BLOCK_CELLS ? *first + OCTREE_BLOCK_CELLS
                                                       : b->tree_cells;
    return 0;
}

/* The task argument of both operations: the octant. */
SHM_TASK_ARG(implicit_octant, grid_octant)

/* ---- encode: the VOD bricks of the last job's octree or volume ---- */

enum encode_source {
    ENCODE_OCTREE = 1,     /* the implicit kind's octree (cells_off ...) */
    ENCODE_VOLUME = 2,     /* a vod_volume at volume_off (the mesh kind's) */
};

enum encode_op {
    ENCODE_BRICKS = 1,     /* encode brick nodes until none is left */
    ENCODE_AGGREGATE = 2,  /* the mip levels of subtrees until none is left */
};

typedef struct {
    vod_layout L;
    vod_params p;          /* metadata is NULL here: encoding does not use it */
    uint32_t source;       /* enum encode_source */
    uint64_t volume_off;   /* ENCODE_VOLUME: the volume, prepared by the master */
    uint32_t cells_used;
    int32_t depth;
    uint64_t cells_off, agg_off, nodes_off, recs_off, offs_off;
    uint64_t n;            /* brick nodes */
    uint64_t brick_off, brick_cap;
    /* The aggregate's first phase: the subtrees of the cells of height
     * root_height (u32 cell each at roots_off), each one's byte at
     * roots_done_off set to 1 by the worker that finished it (published
     * by its done_seq release); the master does the rest. */
    uint64_t roots_off, roots_done_off, nroots;
    int32_t root_height;
    /* Next node index to encode: workers fetch_add chunks (relaxed: the
     * node array was published by the task_seq release). */
    _Alignas(64) atomic_ullong next;
    /* Next subtree to aggregate, the same way. */
    _Alignas(64) atomic_ullong agg_next;
    /* Bump allocator in the brick area: workers fetch_add their encoded
     * size (relaxed: the bytes and record are published by done_seq). */
    _Alignas(64) atomic_ullong bump;
    /* First error a worker met (negative errno), 0 if none; relaxed,
     * read by the master after every done_seq acquire. */
    atomic_int error;
    /* Nanoseconds the workers spent filling, hashing and compressing
     * (vod_times), each adding its own at the end of its task (relaxed:
     * read by the master after every done_seq acquire). */
    atomic_ullong ns_fill, ns_hash, ns_compress;
} encode_block;

/* ---- mesh: a triangle mesh voxelized tile by tile (mesh_vox.h) ---- */

enum mesh_op {
    MESH_TILES = 1,        /* voxelize tiles first .. first + count - 1 */
};

/* The task's argument: a run of tiles (numbered as mesh_bins numbers them). */
typedef struct {
    uint32_t first, count;
} mesh_task_arg;

typedef struct {
    grid_spec grid;
    mesh_vox_opts opts;
    uint32_t n_vertices, n_triangles;
    uint64_t vertices_off, triangles_off;   /* float[3], uint32_t[3] */
    float lo[3], hi[3];                     /* the mesh's bounding box */
    uint32_t tiles[2];
    uint64_t start_off, ids_off;            /* mesh_bins' arrays */
    uint64_t stats_off;                     /* mesh_tile_stats per tile */
    uint64_t volume_off;                    /* the vod_volume's arena */
    /* After its bricks each tile builds mip levels 1..mip_levels of
     * channel mip_channel under its column (0: none); the master declares
     * them built once every tile is done. */
    int32_t mip_channel;
    uint32_t mip_levels;
} mesh_block;

SHM_TASK_ARG(mesh_task_tiles, mesh_task_arg)

/* ---- csg: a volume CSG tree (csg.h) evaluated brick by brick ---- */

enum csg_op {
    CSG_BRICKS = 1,        /* bricks first .. first + count - 1 of the box (x fastest) */
    CSG_MIPS = 2,          /* mip columns first .. first + count - 1 (x fastest) */
    CSG_LEAF_TILES = 3,    /* tiles first .. first + count - 1 of mesh leaf `task` */
};

/* The task's argument: a run of storage bricks, numbered x fastest over
 * the block's box of bricks; its counts go to stats[task].  For CSG_MIPS
 * a run of the volume's level-mip_levels brick columns, numbered x
 * fastest (task unused); for CSG_LEAF_TILES a run of the mesh leaf's
 * tiles (mesh_bins' numbers), task its node. */
typedef struct {
    uint32_t first, count, task;
} csg_task_arg;

/* What one task's bricks came to (csg_stats of its bricks); the task's own
 * entry, so a task run again after a death writes the same. */
typedef struct {
    uint64_t bricks, uniform_bricks, skipped, voxel_evals, solid_voxels;
} csg_task_stats;

#define CSG_BLOCK_NODES 256u

/* The tree is csg.h's csg_tree: its n nodes (csg_node, an array at
 * nodes_off) and its text pool (text_len bytes at text_off), copied by the
 * master; the workers rebuild a csg_tree around them. */
typedef struct {
    grid_spec grid;
    uint32_t channel;                       /* the VOD channel (csg_eval_store) */
    uint32_t sbrick, nbricks[3];            /* the volume's storage bricks */
    /* the bricks evaluated: box_n[a] from box_lo[a] on each axis (the
     * whole volume, or vox_mpi's subtree); tasks number them x fastest */
    uint32_t box_lo[3], box_n[3];
    uint32_t n_nodes, node_bytes;           /* node_bytes: sizeof(csg_node) */
    uint64_t nodes_off, text_off, text_len;
    uint32_t ntasks;
    uint64_t stats_off;                     /* csg_task_stats per task */
    /* The mesh and vod leaves' volumes (8 bits, the job's grid), built by
     * the master before the first task: node i's at leaf_off[i], 0 for
     * the other nodes (CSG_BLOCK_NODES = csg.h's CSG_MAX_NODES). */
    uint64_t leaf_off[CSG_BLOCK_NODES];
    uint64_t volume_off;                    /* the vod_volume's arena */
    /* Once every brick is in, the CSG_MIPS tasks build mip levels
     * 1..mip_levels of the VOD's channel (`channel`) by columns
     * (vod_volume_mip_columns); 0: none, the writer builds them all. */
    uint32_t mip_levels;
    /* The mesh leaf whose volume the CSG_LEAF_TILES tasks build (one
     * leaf at a time, before the bricks): its mesh, bins and volume
     * (leaf_off[node]) as a mesh job's block (mesh_block) at leaf_mesh_off. */
    uint64_t leaf_mesh_off;
} csg_block;

SHM_TASK_ARG(csg_task_bricks, csg_task_arg)

/* ---- iso: marching cubes, brick by brick (iso.h) ---- */

enum iso_op {
    ISO_BRICKS = 1,        /* polygonize tasks until none is left */
    ISO_WELD = 2,          /* weld pieces into the mesh until none is left */
};

/* One task's piece in the arena: its counts (iso_piece_view lays the
 * bytes out), written by the worker that ran it before `done`. */
typedef struct {
    uint64_t off;          /* from the arena's start */
    uint32_t nv, nc, nt, ne;
    /* 1 once the piece is complete: stored with release after the piece
     * and the fields above, loaded with acquire by the master (a worker
     * that died half way leaves it 0, and the master runs the task). */
    atomic_uint done;
    /* 1 once the piece is welded into the mesh's arrays: release by the
     * worker that welded it, acquire by the master, which welds the
     * others itself. */
    atomic_uint welded;
} iso_result;

typedef struct {
    iso_params p;
    /* the input (iso_input): n brick keys and offsets, the raw bricks */
    uint64_t n_bricks, keys_off, offs_off, raw_off, raw_bytes;
    uint64_t n_tasks, tasks_off;   /* iso_task[n_tasks], in key order */
    uint64_t results_off;          /* iso_result[n_tasks] */
    uint64_t arena_off, arena_cap; /* the pieces' bytes */
    /* The weld (written by the master between the phases, published by
     * the ISO_WELD tasks' task_seq release): each piece's first vertex
     * and triangle (u64[n_tasks + 1] each), the mesh's arrays. */
    uint64_t vbase_off, tbase_off;
    uint64_t pos_off, nrm_off, tri_off; /* nrm_off 0: no normals */
    /* Next task to run: workers fetch_add (relaxed: the tasks were
     * published by the task_seq release). */
    _Alignas(64) atomic_ullong next;
    /* Bump allocator in the arena: workers fetch_add a piece's size
     * (relaxed: only the ranges' uniqueness matters; the bytes are
     * published by the result's done release). */
    _Alignas(64) atomic_ullong bump;
    /* Next piece to weld: workers fetch_add (relaxed: the weld's arrays
     * were published by the ISO_WELD task_seq release). */
    _Alignas(64) atomic_ullong weld_next;
} iso_block;

#endif
