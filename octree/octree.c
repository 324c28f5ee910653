/* The Stolte–Kaufman octree: Figure 2 (insertion from the last written cell)
 * and Figure 6 (iteration with an explicit stack), over an index arena. */
#include "octree.h"

#include <assert.h>
#include <errno.h>
#include <string.h>

/* Room for n more cells (n <= OCTREE_BLOCK_CELLS) in the block being taken
 * from: with one writer the arena's end is the limit; with a grab a new
 * block is taken when the current one lacks them (its tail is left
 * unused).  0 or -ENOMEM. */
static int room(octree *t, uint32_t n)
{
    if (t->block_end - t->next >= n) return 0;
    if (!t->grab) return n <= t->capacity - t->next ? 0 : -ENOMEM;
    uint32_t first, end;
    if (t->grab(t->grab_ud, &first, &end)) return -ENOMEM;
    if (first == 0 || first >= end || end > t->capacity) return -ENOMEM;
    t->next = first;
    t->block_end = end;
    if (end > t->used) t->used = end;
    return end - first >= n ? 0 : -ENOMEM;
}

/* Hand out the next cell; the caller made room.  One writer clears a
 * whole block when a new one starts (Figure 2's alloc_block); a writer of
 * a shared arena clears cell by cell, so that the pages of its last
 * block's tail, which no one uses, are never touched (a small job's
 * writers would each hold a block's pages otherwise). */
static uint32_t alloc_cell(octree *t)
{
    if (t->grab) {
        assert(t->next < t->block_end);
        memset(&t->cells[t->next], 0, sizeof t->cells[0]);
    } else if (t->next == t->block_end) {
        assert(t->next < t->capacity);
        uint32_t end = t->next + OCTREE_BLOCK_CELLS;
        if (end > t->capacity || end < t->next) end = t->capacity;
        memset(&t->cells[t->next], 0, octree_arena_bytes(end - t->next));
        t->block_end = end;
    }
    t->taken++;
    uint32_t c = t->next++;
    if (!t->grab) t->used = t->next;
    return c;
}

void octree_init(octree *t, octree_cell *arena, uint32_t capacity, int depth)
{
    assert(capacity >= 2 && depth >= 1 && depth <= OCTREE_MAX_DEPTH);
    memset(t, 0, sizeof *t);
    t->cells = arena;
    t->capacity = capacity;
    t->depth = depth;
    t->used = 1; /* cell 0 means "empty" and is never handed out */
    t->next = t->block_end = 1;
    t->root = alloc_cell(t);
    memset(&t->cells[0], 0, sizeof t->cells[0]);
    t->path[0] = t->root;
    t->path_len = 1;
}

void octree_view(octree *t, octree_cell *arena, uint32_t used, int depth)
{
    memset(t, 0, sizeof *t);
    t->cells = arena;
    t->capacity = used;
    t->used = used;
    t->next = t->block_end = used;
    t->root = used > 1 ? 1 : 0;
    t->depth = depth;
}

void octree_share(octree *t, octree_grab grab, void *ud)
{
    t->grab = grab;
    t->grab_ud = ud;
    t->used = t->block_end;
}

void octree_writer(octree *t, octree_cell *arena, uint32_t capacity,
                   octree_grab grab, void *ud)
{
    memset(t, 0, sizeof *t);
    t->cells = arena;
    t->capacity = capacity;
    t->depth = 1;
    t->grab = grab;
    t->grab_ud = ud;
}

void octree_subtree(octree *t, int depth)
{
    assert(depth >= 1 && depth <= OCTREE_MAX_DEPTH);
    t->depth = depth;
    t->root = 0;
    t->voxels = 0;
    t->taken = 0;
    t->path_len = 0;
    memset(t->last, 0, sizeof t->last);
}

static inline unsigned child_index(uint32_t x, uint32_t y, uint32_t z, int h)
{
    return ((x >> h) & 1u) | ((y >> h) & 1u) << 1 | ((z >> h) & 1u) << 2;
}

/* Cells a store below the path's end at height h would have to create. */
static uint32_t cells_missing(const octree *t, uint32_t x, uint32_t y,
                              uint32_t z, int h)
{
    uint32_t cell = t->path[t->path_len - 1];
    for (; h > 0; h--) {
        cell = t->cells[cell].child[child_index(x, y, z, h)];
        if (cell == 0) return (uint32_t)h;
    }
    return 0;
}

int octree_store(octree *t, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    assert(v != 0 && (x | y | z) >> t->depth == 0);
    /* The common case in preorder: a sibling of the last voxel, in the
     * leaf cell the path already ends at (what the general code below does
     * when it neither climbs nor descends). */
    if (t->path_len == t->depth &&
        (((x ^ t->last[0]) | (y ^ t->last[1]) | (z ^ t->last[2])) >> 1) == 0) {
        uint32_t *leaf = &t->cells[t->path[t->depth - 1]].child[child_index(x, y, z, 0)];
        t->voxels += (*leaf == 0);
        *leaf = v;
        t->last[0] = x;
        t->last[1] = y;
        t->last[2] = z;
        return 0;
    }
    /* A subtree's first voxel: its root cell first (octree_subtree; the
     * path then starts at the root, as after octree_init). */
    if (t->path_len == 0) {
        if (room(t, (uint32_t)t->depth)) return -ENOMEM;
        t->root = alloc_cell(t);
        t->path[0] = t->root;
        t->path_len = 1;
    }
    /* Ascend to the common parent: mask2 keeps the coordinate bits that name
     * the current cell; pop while the new voxel differs in any of them. */
    int h = t->depth - t->path_len; /* height of the deepest cell on the path */
    uint32_t mask2 = ~0u << (h + 1);
    while (((x ^ t->last[0]) | (y ^ t->last[1]) | (z ^ t->last[2])) & mask2) {
        t->path_len--;
        h++;
        mask2 <<= 1;
    }
    if (t->block_end - t->next < (uint32_t)h) {
        uint32_t missing = cells_missing(t, x, y, z, h);
        if (missing && room(t, missing)) return -ENOMEM;
    }
    /* Descend, creating the cells that do not exist yet. */
    uint32_t cell = t->path[t->path_len - 1];
    for (; h > 0; h--) {
        uint32_t *slot = &t->cells[cell].child[child_index(x, y, z, h)];
        if (*slot == 0) *slot = alloc_cell(t);
        cell = *slot;
        t->path[t->path_len++] = cell;
    }
    uint32_t *leaf = &t->cells[cell].child[child_index(x, y, z, 0)];
    t->voxels += (*leaf == 0);
    *leaf = v;
    t->last[0] = x;
    t->last[1] = y;
    t->last[2] = z;
    return 0;
}

uint32_t octree_find(const octree *t, int h, uint32_t x, uint32_t y,
                     uint32_t z)
{
    assert(h >= 0 && h < t->depth);
    uint32_t cell = t->root < t->used ? t->root : 0;
    for (int l = t->depth - 1; l > h && cell; l--)
        cell = octree_child(t, cell, child_index(x, y, z, l));
    return cell;
}

int octree_link(octree *t, const uint32_t at[3], int h, uint32_t cell, uint64_t voxels)
{
    uint32_t x = at[0], y = at[1], z = at[2];
    assert(cell && h >= 0 && h < t->depth && (x | y | z) >> t->depth == 0);
    octree_cell *root = &t->cells[t->root];
    if (h == t->depth - 1) { /* the whole tree */
        for (int i = 0; i < 8; i++)
            if (root->child[i]) return -EEXIST;
        *root = t->cells[cell];
        t->voxels += voxels;
        return 0;
    }
    /* The cells of heights depth-2 .. h+1 on the way, some missing. */
    uint32_t c = t->root, missing = 0;
    for (int l = t->depth - 1; l > h + 1 && !missing; l--) {
        uint32_t e = t->cells[c].child[child_index(x, y, z, l)];
        if (e >= t->capacity) return -EEXIST; /* not a cell this tree made */
        if (!e) missing = (uint32_t)(l - 1 - h);
        c = e;
    }
    if (missing && room(t, missing)) return -ENOMEM;
    c = t->root;
    for (int l = t->depth - 1; l > h + 1; l--) {
        uint32_t *slot = &t->cells[c].child[child_index(x, y, z, l)];
        if (*slot == 0) *slot = alloc_cell(t);
        c = *slot;
    }
    uint32_t *slot = &t->cells[c].child[child_index(x, y, z, h + 1)];
    if (*slot) return -EEXIST;
    *slot = cell;
    t->voxels += voxels;
    return 0;
}

uint32_t octree_get(const octree *t, uint32_t x, uint32_t y, uint32_t z)
{
    if ((x | y | z) >> t->depth) return 0;
    uint32_t cell = octree_find(t, 0, x, y, z);
    return cell ? t->cells[cell].child[child_index(x, y, z, 0)] : 0;
}

void octree_iter_init(octree_iter *it, const octree *t)
{
    memset(it, 0, sizeof *it);
    it->t = t;
    it->cell[0] = t->root;
    it->top = t->root && t->root < t->used ? 0 : -1;
}

/* Figure 6: X, Y, Z hold the coordinate bits of the path to the current
 * cell; descending shifts a child's bit in, ascending shifts it out. */
bool octree_iter_next(octree_iter *it, uint32_t *x, uint32_t *y, uint32_t *z,
                      uint32_t *v)
{
    const octree_cell *cells = it->t->cells;
    const int leaf_top = it->t->depth - 1;
    while (it->top >= 0) {
        unsigned i = it->next[it->top];
        if (i > 7) { /* this cell is done: ascend one level */
            it->top--;
            it->x >>= 1;
            it->y >>= 1;
            it->z >>= 1;
            continue;
        }
        it->next[it->top] = (uint8_t)(i + 1);
        uint32_t e = it->top == leaf_top ? cells[it->cell[it->top]].child[i]
                                         : octree_child(it->t, it->cell[it->top], i);
        if (e == 0) continue;
        uint32_t cx = it->x << 1 | (i & 1u), cy = it->y << 1 | ((i >> 1) & 1u),
                 cz = it->z << 1 | ((i >> 2) & 1u);
        if (it->top == leaf_top) {
            *x = cx;
            *y = cy;
            *z = cz;
            *v = e;
            return true;
        }
        it->top++;
        it->cell[it->top] = e;
        it->next[it->top] = 0;
        it->x = cx;
        it->y = cy;
        it->z = cz;
    }
    return false;
}
