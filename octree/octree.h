/* octree — the Stolte–Kaufman pointer octree, addressed by cell index.
 *
 * A cell is 8 u32 entries in child order (child i: x += i&1, y += (i>>1)&1,
 * z += (i>>2)&1).  In a cell of height h > 0 an entry is the index of a child
 * cell (0 = empty region); in a cell of height 0 an entry is a voxel value
 * (voxel.h; 0 = no voxel).  A cell of height h covers 2^(h+1) voxels per
 * axis; the root (cell 1) has height depth-1, so the octree spans 2^depth
 * voxels per axis, depth >= 1.  Cell 0 is never used, so index 0 can mean
 * "empty".
 *
 * Indices, not pointers: the arena may live in shared memory mapped anywhere,
 * and a process that only reads the tree (a worker encoding bricks) makes its
 * own octree view of the same arena with octree_view().
 *
 * Cells are taken from the arena in blocks of OCTREE_BLOCK_CELLS (Figure 2's
 * alloc_block), so a writer touches memory in large, sequential steps.  A
 * tree with one writer takes them in order; several writers in one arena
 * (the engine's workers, each building whole subtrees) take them from a
 * shared counter through a grab callback (octree_share, octree_writer), and
 * one of them links the finished subtrees' root cells into the tree
 * (octree_link).  Nothing depends on where a cell lies in the arena: every
 * reader walks the tree from its root, and reads an index at or past `used`
 * (which only a broken writer leaves) as empty (octree_child).
 */
#ifndef VOXD_OCTREE_H
#define VOXD_OCTREE_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#define OCTREE_MAX_DEPTH 16
#define OCTREE_BLOCK_CELLS 4096u

typedef struct {
    uint32_t child[8];
} octree_cell;

/* A new block of cells [*first, *end) for the caller alone (1 <= first <
 * end <= the arena's capacity); 0, or -ENOMEM when the arena is all handed
 * out.  The octree clears each cell as it hands it out. */
typedef int (*octree_grab)(void *ud, uint32_t *first, uint32_t *end);

typedef struct {
    octree_cell *cells; /* arena: cells[0] unused; a whole tree's root is cells[1] */
    uint32_t *agg;      /* optional per-cell aggregate (vod_aggregate), or NULL */
    uint32_t capacity;  /* cells in the arena */
    /* Every cell index in the tree is below it: with one writer the cells
     * handed out so far, cell 0 included; with blocks from grab the end of
     * the last block taken (the owner of the shared arena sets the end of
     * every writer's blocks once they are done). */
    uint32_t used;
    uint32_t root;      /* the root cell: 1, or a subtree's (0 while empty) */
    int depth;          /* 2^depth voxels per axis */
    uint64_t voxels;    /* voxels stored */
    uint32_t taken;     /* cells this tree (or subtree) was handed */
    /* Figure 2's insertion state: the path from the root to the last cell
     * written, and the last voxel's coordinates. */
    uint32_t path[OCTREE_MAX_DEPTH];
    int path_len;
    uint32_t last[3];
    uint32_t next, block_end; /* the block cells are taken from: [next, block_end) */
    octree_grab grab;   /* NULL: blocks in the arena's order */
    void *grab_ud;
} octree;

/* Bytes of arena needed for `cells` cells. */
static inline size_t octree_arena_bytes(uint32_t cells)
{
    return (size_t)cells * sizeof(octree_cell);
}

/* Start an empty tree of the given depth in arena (capacity cells, >= 2).
 * The arena need not be cleared: blocks are cleared as they are handed out. */
void octree_init(octree *t, octree_cell *arena, uint32_t capacity, int depth);
/* A read-only view of a tree another process built (used cells known). */
void octree_view(octree *t, octree_cell *arena, uint32_t used, int depth);

/* From now on t's blocks come from grab (after octree_init: the rest of
 * its current block is still used first), so that other writers can take
 * blocks of the same arena. */
void octree_share(octree *t, octree_grab grab, void *ud);
/* A writer of subtrees in a shared arena, with no cell yet: call
 * octree_subtree before each subtree. */
void octree_writer(octree *t, octree_cell *arena, uint32_t capacity,
                   octree_grab grab, void *ud);
/* Start a new subtree of the given depth (2^depth voxels per axis, its own
 * coordinates) in t: root, voxels and taken start again from 0, and the
 * root cell is taken at the first store; the block being taken from
 * carries over.  Then octree_store as into any tree. */
void octree_subtree(octree *t, int depth);
/* Make `cell`, the root of a subtree of height h holding `voxels` voxels
 * (built by another writer of the arena), the cell of height h that covers
 * voxel at = (x, y, z), creating the cells above it that are missing; h ==
 * depth-1 (the whole tree) copies its entries into the root.  Returns 0,
 * -EEXIST when that region holds something already, or -ENOMEM (the tree
 * unchanged). */
int octree_link(octree *t, const uint32_t at[3], int h, uint32_t cell, uint64_t voxels);

/* Entry i of cell c of height > 0 (a cell index), for readers: an index at
 * or past t->used, which only a broken writer of a shared arena can leave,
 * reads as empty, so that no walk leaves the arena (nor the aggregates,
 * used entries).  A walk is bounded by the height besides, so no index can
 * make it loop. */
static inline uint32_t octree_child(const octree *t, uint32_t c, unsigned i)
{
    uint32_t e = t->cells[c].child[i];
    return e < t->used ? e : 0;
}

/* Figure 2: store voxel value v (!= 0) at (x, y, z), climbing from the last
 * cell written to the common parent with the two masks, then descending and
 * creating cells.  Storing to an occupied voxel overwrites it.  Returns 0,
 * or -ENOMEM when the arena is full (the tree is then unchanged). */
int octree_store(octree *t, uint32_t x, uint32_t y, uint32_t z, uint32_t v);

/* The voxel value at (x, y, z), 0 if none. */
uint32_t octree_get(const octree *t, uint32_t x, uint32_t y, uint32_t z);

/* The index of the cell of height h that covers voxel (x, y, z), 0 if that
 * region is empty. */
uint32_t octree_find(const octree *t, int h, uint32_t x, uint32_t y,
                     uint32_t z);

/* Figure 6: iteration over every voxel in preorder (child order), with an
 * explicit stack.  Usage:
 *   octree_iter it; octree_iter_init(&it, t);
 *   while (octree_iter_next(&it, &x, &y, &z, &v)) ...            */
typedef struct {
    const octree *t;
    uint32_t cell[OCTREE_MAX_DEPTH];
    uint8_t next[OCTREE_MAX_DEPTH];
    int top;
    uint32_t x, y, z;
} octree_iter;
void octree_iter_init(octree_iter *it, const octree *t);
bool octree_iter_next(octree_iter *it, uint32_t *x, uint32_t *y, uint32_t *z,
                      uint32_t *v);

#endif
