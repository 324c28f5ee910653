/* The octree of voxels (octree.h) as a VOD brick source: the volume
 * precondition, the per-cell aggregates of the mip levels, which nodes are
 * empty, and a node's brick filled by walking the cells below it. */
#include <errno.h>
#include <stdbool.h>
#include <string.h>

#include "vod.h"
#include "vod_downsample.h"
#include "voxel.h"

/* ---- the volume precondition ---- */

/* Some voxel below cell c (height h, low corner o), which holds one. */
static void first_voxel(const octree *t, uint32_t c, int h, uint32_t o[3])
{
    for (;;) {
        unsigned i = 0;
        while (i < 7 && !t->cells[c].child[i]) i++;
        for (int a = 0; a < 3; a++) o[a] += ((i >> a) & 1u) << h;
        if (h == 0) return;
        c = octree_child(t, c, i);
        if (!c) return; /* a broken writer's index: no voxel below */
        h--;
    }
}

/* Only cells that straddle a high face are opened; a cell wholly inside the
 * volume is skipped, one wholly outside is an error if it holds anything. */
static int check_cell(const octree *t, const uint32_t *vol, uint32_t c, int h,
                      const uint32_t o[3], uint32_t bad[3])
{
    uint64_t side = 2ull << h;
    if (o[0] + side <= vol[0] && o[1] + side <= vol[1] && o[2] + side <= vol[2])
        return 0;
    for (unsigned i = 0; i < 8; i++) {
        uint32_t e = h > 0 ? octree_child(t, c, i) : t->cells[c].child[i], co[3];
        if (!e) continue;
        for (int a = 0; a < 3; a++) co[a] = o[a] + (((i >> a) & 1u) << h);
        bool out = co[0] >= vol[0] || co[1] >= vol[1] || co[2] >= vol[2];
        if (out) {
            if (h > 0) first_voxel(t, e, h - 1, co);
            memcpy(bad, co, sizeof co);
            return -EINVAL;
        }
        if (h > 0 && check_cell(t, vol, e, h - 1, co, bad)) return -EINVAL;
    }
    return 0;
}

static int octree_outside(const vod_source *s, const uint32_t volume[3],
                          uint32_t at[3])
{
    const octree *t = s->ctx;
    uint32_t o[3] = {0, 0, 0};
    if (t->used < 2) return 0;
    return check_cell(t, volume, 1, t->depth - 1, o, at) != 0;
}

/* ---- the mip levels: one aggregate per cell ---- */

static void agg_cell(octree *t, uint32_t c, int h, int channel)
{
    uint32_t v[8];
    for (int i = 0; i < 8; i++) {
        uint32_t e = h > 0 ? octree_child(t, c, i) : t->cells[c].child[i];
        if (h > 0 && e) agg_cell(t, e, h - 1, channel);
        v[i] = h == 0 ? e : e ? t->agg[e] : 0;
    }
    t->agg[c] = vod_downsample(channel, v);
}

void vod_aggregate(octree *t, int channel)
{
    if (!t->agg || t->used < 2) return;
    t->agg[0] = 0;
    vod_aggregate_subtree(t, 1, t->depth - 1, channel);
}

void vod_aggregate_subtree(octree *t, uint32_t c, int h, int channel)
{
    /* constant channels: the compiler specializes the recursion for each */
    if (channel == VOXEL_CH_SURFACE) agg_cell(t, c, h, VOXEL_CH_SURFACE);
    else agg_cell(t, c, h, VOXEL_CH_OCCUPANCY);
}

/* vod_aggregate_roots' walk: the cells of height h of tree t, n of them
 * so far, the first cap into out. */
typedef struct {
    const octree *t;
    int h;
    uint32_t *out;
    size_t cap, n;
} roots_walk;

/* The cells of height r->h below cell c (of height hc), in order. */
static void roots_below(roots_walk *r, uint32_t c, int hc)
{
    if (hc == r->h) {
        if (r->n < r->cap) r->out[r->n] = c;
        r->n++;
        return;
    }
    for (unsigned i = 0; i < 8; i++) {
        uint32_t e = octree_child(r->t, c, i);
        if (e) roots_below(r, e, hc - 1);
    }
}

size_t vod_aggregate_roots(const octree *t, int h, uint32_t *out, size_t cap)
{
    if (t->used < 2 || h < 0 || h > t->depth - 1) return 0;
    roots_walk r = {.t = t, .h = h, .out = out, .cap = out ? cap : 0};
    roots_below(&r, 1, t->depth - 1);
    return r.n;
}

/* Cells above height h, from their children's aggregates. */
static void agg_top(octree *t, uint32_t c, int hc, int h, int channel)
{
    if (hc == h) return;
    uint32_t v[8];
    for (int i = 0; i < 8; i++) {
        uint32_t e = octree_child(t, c, i);
        if (e) agg_top(t, e, hc - 1, h, channel);
        v[i] = e ? t->agg[e] : 0;
    }
    t->agg[c] = vod_downsample(channel, v);
}

void vod_aggregate_top(octree *t, int h, int channel)
{
    if (!t->agg || t->used < 2) return;
    t->agg[0] = 0;
    if (channel == VOXEL_CH_SURFACE) agg_top(t, 1, t->depth - 1, h, VOXEL_CH_SURFACE);
    else if (channel == VOXEL_CH_DENSITY) agg_top(t, 1, t->depth - 1, h, VOXEL_CH_DENSITY);
    else if (channel == VOXEL_CH_DISTANCE) agg_top(t, 1, t->depth - 1, h, VOXEL_CH_DISTANCE);
    else agg_top(t, 1, t->depth - 1, h, VOXEL_CH_OCCUPANCY);
}

static int octree_prepare(vod_source *s, const vod_layout *L, int channel)
{
    (void)L;
    octree *t = s->ctx;
    vod_aggregate(t, channel);
    return 0;
}

/* ---- nodes ---- */

/* The cell covering node (level, b) and its height; 0 if none.  A node's
 * region is a cell of height brick_log2 + level - 1, except a root brick
 * larger than the whole octree (treeHeight 1), which holds the root cell. */
static uint32_t node_cell(const octree *t, const vod_layout *L, uint32_t level,
                          const uint32_t b[3], int *h)
{
    int hc = (int)(L->brick_log2 + level) - 1;
    if (hc > t->depth - 1) {
        *h = t->depth - 1;
        return 1;
    }
    *h = hc;
    int s = (int)(L->brick_log2 + level);
    return octree_find(t, hc, b[0] << s, b[1] << s, b[2] << s);
}

/* node_cell, taken from the node's ref when region() left it there. */
static uint32_t node_cell_ref(const octree *t, const vod_layout *L,
                              const vod_node *n, const uint32_t b[3], int *h)
{
    if (!n->ref || n->ref >= t->used) return node_cell(t, L, n->level, b, h);
    int hc = (int)(L->brick_log2 + n->level) - 1;
    *h = hc > t->depth - 1 ? t->depth - 1 : hc;
    return n->ref;
}

static bool cell_empty(const octree *t, uint32_t c)
{
    if (!c) return true;
    for (int i = 0; i < 8; i++)
        if (t->cells[c].child[i]) return false;
    return true;
}

/* Cells exist only where voxels were stored (a cell is made on the way to
 * a voxel, a subtree's root linked only when it holds one, and nothing is
 * ever taken out), so a node is empty iff its cell is missing or (the root
 * of an empty tree) has no child: only the root's entries are read.  A
 * node's cell is a child of its parent's (ref), so the walk down the table
 * reads the cells of the nodes above the leaves, not the leaves' (7 in 8
 * of the nodes): each is a load, and a page's first touch, in a process
 * that did not write them (the master's plan; 5-7% of the sphere's and
 * union64's CPU).  A broken writer's childless cell would make a node of
 * zeros, which the readers take like any brick.  An octree never says
 * uniform: it does not know without walking the brick. */
static int octree_region(const vod_source *s, const vod_layout *L, vod_node *n)
{
    const octree *t = s->ctx;
    uint32_t c;
    if (n->ref && n->ref < t->used) {
        unsigned i = (n->bx & 1u) | (n->by & 1u) << 1 | (n->bz & 1u) << 2;
        c = octree_child(t, n->ref, i);
    } else {
        uint32_t b[3] = {n->bx, n->by, n->bz};
        int h;
        c = node_cell(t, L, n->level, b, &h);
    }
    n->ref = c;
    if (c && c != 1 && c != t->root) return VOD_REGION_MIXED;
    return cell_empty(t, c) ? VOD_REGION_EMPTY : VOD_REGION_MIXED;
}

/* ---- filling a brick ---- */

typedef struct {
    const octree *t;
    uint8_t *raw;
    uint32_t brick, bits, level;
} fill_ctx;

static inline void put_voxel(const fill_ctx *f, uint32_t x, uint32_t y,
                             uint32_t z, uint32_t v)
{
    size_t i = ((size_t)z * f->brick + y) * f->brick + x;
    if (f->bits == 32)
        vod_put32(f->raw + 4 * i, v);
    else if (f->bits == 8)
        f->raw[i] = (uint8_t)v;
    else if (v)
        f->raw[i >> 3] |= (uint8_t)(1u << (i & 7));
}

/* Cell c of height h has its low corner at level-l voxel (x, y, z) of the
 * brick.  Its children cover 2^(h-l) level-l voxels each: at h == l every
 * child is one voxel (a voxel value at level 0, the child's agg above). */
static void fill(const fill_ctx *f, uint32_t c, int h, uint32_t x, uint32_t y,
                 uint32_t z)
{
    const octree *t = f->t;
    if (h == 0 && f->level == 0) { /* voxel values */
        const uint32_t *v = t->cells[c].child;
        for (unsigned i = 0; i < 8; i++)
            if (v[i]) put_voxel(f, x + (i & 1u), y + ((i >> 1) & 1u), z + ((i >> 2) & 1u), v[i]);
        return;
    }
    uint32_t e[8]; /* cell indices, bounded (octree_child) */
    for (unsigned i = 0; i < 8; i++) e[i] = octree_child(t, c, i);
    if (h == (int)f->level) {
        for (unsigned i = 0; i < 8; i++) {
            uint32_t v = e[i] ? t->agg[e[i]] : 0;
            if (v) put_voxel(f, x + (i & 1u), y + ((i >> 1) & 1u),
                             z + ((i >> 2) & 1u), v);
        }
        return;
    }
    uint32_t half = 1u << (h - (int)f->level);
    /* the children's cells are scattered in the segment: ask for them all
     * before walking the first */
    for (unsigned i = 0; i < 8; i++)
        if (e[i]) __builtin_prefetch(&t->cells[e[i]]);
    for (unsigned i = 0; i < 8; i++)
        if (e[i])
            fill(f, e[i], h - 1, x + (i & 1u) * half, y + ((i >> 1) & 1u) * half,
                 z + ((i >> 2) & 1u) * half);
}

/* Voxel values are 32-bit surface voxels: channel 3 as they are, channel 1
 * as one bit (put_voxel sets it for any non-zero value, and the aggregates
 * of channel 1 are 0 or 1).  8 bits (channel 2) only above level 0, from
 * aggregates that are densities: vox_mpi's levels above a CSG or mesh
 * job's subtrees (mpi_top.c). */
static int octree_fill(const vod_source *s, const vod_layout *L,
                       const vod_node *n, uint8_t *raw)
{
    const octree *t = s->ctx;
    if (L->voxel_bits != 1 && L->voxel_bits != 8 && L->voxel_bits != 32) return -EINVAL;
    if (L->voxel_bits == 8 && n->level == 0) return -EINVAL; /* voxels are not densities */
    if (n->level > 0 && !t->agg) return -EINVAL;
    fill_ctx f = {t, raw, L->brick, L->voxel_bits, n->level};
    uint32_t b[3] = {n->bx, n->by, n->bz};
    int h;
    uint32_t c = node_cell_ref(t, L, n, b, &h);
    if (c) fill(&f, c, h, 0, 0, 0);
    return 0;
}

static const vod_source_ops octree_ops = {
    .name = "octree",
    .prepare = octree_prepare,
    .outside = octree_outside,
    .region = octree_region,
    .fill = octree_fill,
};

vod_source vod_octree_source(octree *t)
{
    return (vod_source){
        .ops = &octree_ops,
        .ctx = t,
        .depth = t->depth,
        .channels = 1u << VOXEL_CH_OCCUPANCY | 1u << VOXEL_CH_SURFACE,
    };
}
