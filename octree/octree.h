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
 * alloc_block), so a writer touches memory in large, sequential steps.
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

typedef struct {
    octree_cell *cells; /* arena: cells[0] unused, cells[1] the root */
    uint32_t *agg;      /* optional per-cell aggregate (vod_aggregate), or NULL */
    uint32_t capacity;  /* cells in the arena */
    uint32_t used;      /* cells handed out so far, cell 0 included */
    int depth;          /* 2^depth voxels per axis */
    uint64_t voxels;    /* voxels stored */
    /* Figure 2's insertion state: the path from the root to the last cell
     * written, and the last voxel's coordinates. */
    uint32_t path[OCTREE_MAX_DEPTH];
    int path_len;
    uint32_t last[3];
    uint32_t block_end; /* end of the block cells are being taken from */
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
