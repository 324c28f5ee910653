/* The VOD nodes above the subtrees, on rank 0 (mpi_part.h): an octree of
 * the grid's depth whose cells of height node_level - 1 carry, as their
 * aggregates, the subtrees' top-brick voxels (a level-l voxel is the
 * aggregate of the cell of height l - 1 that covers it); the aggregates
 * above are made from those by the rule every writer uses
 * (vod_aggregate_top), and the nodes above node_level are encoded from
 * it.  Each subtree's cells reach down to level 0 at one voxel per cell
 * (a placeholder, never read: only nodes above node_level are encoded),
 * and every subtree that gave bricks has its cell even when its top brick
 * is all 0 (a sparse surface voxel's mean occupancy rounds to 0 high up):
 * the nodes that cover it are not empty. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "mpi_part.h"
#include "voxel.h"

typedef struct {
    grid_octant o;
    size_t first, n; /* its pairs */
} top_sub;

struct mpi_top {
    vod_layout L;
    int depth;
    uint32_t node_level;
    top_sub *subs;
    size_t nsubs, subs_cap;
    mpi_pair *pairs;
    size_t npairs, pairs_cap;
};

int mpi_top_new(const vod_layout *L, int depth, uint32_t node_level, mpi_top **out)
{
    mpi_top *t = calloc(1, sizeof *t);
    if (!t) return -ENOMEM;
    t->L = *L;
    t->depth = depth;
    t->node_level = node_level;
    *out = t;
    return 0;
}

void mpi_top_free(mpi_top *t)
{
    if (!t) return;
    free(t->subs);
    free(t->pairs);
    free(t);
}

static int reserve(void **v, size_t *cap, size_t need, size_t size)
{
    if (need <= *cap) return 0;
    size_t c = *cap ? *cap : 256;
    while (c < need) c *= 2;
    void *p = realloc(*v, c * size);
    if (!p) return -ENOMEM;
    *v = p;
    *cap = c;
    return 0;
}

int mpi_top_add(mpi_top *t, grid_octant o, const mpi_pair *pairs, size_t n)
{
    if (reserve((void **)&t->subs, &t->subs_cap, t->nsubs + 1, sizeof *t->subs) ||
        reserve((void **)&t->pairs, &t->pairs_cap, t->npairs + n, sizeof *t->pairs))
        return -ENOMEM;
    size_t voxels = (size_t)t->L.brick * t->L.brick * t->L.brick;
    for (size_t i = 0; i < n; i++)
        if (pairs[i].idx >= voxels) return -EINVAL;
    t->subs[t->nsubs++] = (top_sub){o, t->npairs, n};
    if (n) memcpy(t->pairs + t->npairs, pairs, n * sizeof *pairs);
    t->npairs += n;
    return 0;
}

/* Level-0 corner of pair p of subtree s. */
static void pair_corner(const mpi_top *t, const top_sub *s, mpi_pair p, uint32_t c[3])
{
    uint32_t b = t->L.brick, l = t->node_level;
    c[0] = s->o.x + ((p.idx % b) << l);
    c[1] = s->o.y + ((p.idx / b % b) << l);
    c[2] = s->o.z + ((p.idx / b / b) << l);
}

/* The tree: every subtree's corner and every pair's cell, their
 * aggregates, and those above. */
static int build(mpi_top *t, octree *tree, int channel)
{
    int g = (int)t->node_level - 1;
    for (size_t i = 0; i < t->nsubs; i++) {
        const top_sub *s = &t->subs[i];
        if (octree_store(tree, s->o.x, s->o.y, s->o.z, 1)) return -ENOMEM;
        for (size_t k = 0; k < s->n; k++) {
            uint32_t c[3];
            pair_corner(t, s, t->pairs[s->first + k], c);
            if (octree_store(tree, c[0], c[1], c[2], 1)) return -ENOMEM;
        }
    }
    tree->agg = calloc(tree->used, sizeof *tree->agg);
    if (!tree->agg) return -ENOMEM;
    for (size_t i = 0; i < t->nsubs; i++) {
        const top_sub *s = &t->subs[i];
        for (size_t k = 0; k < s->n; k++) {
            uint32_t c[3];
            pair_corner(t, s, t->pairs[s->first + k], c);
            tree->agg[octree_find(tree, g, c[0], c[1], c[2])] = t->pairs[s->first + k].value;
        }
    }
    vod_aggregate_top(tree, g, channel);
    return 0;
}

typedef int (*top_put)(void *ud, const vod_node *n, const vod_encoded *rec,
                       const uint8_t *data);

/* The tree as a source whose walk stops at the subtrees' top nodes: the
 * cells below them are placeholders (one per top-brick voxel, down to
 * level 0) and their nodes are the ranks', so vod_collect need not list
 * them (most of the top's time when it did).  The nodes above keep their
 * preorder numbers (vod_collect counts them from the layout) and their
 * bricks (fill reads the cells, not the walk). */
typedef struct {
    vod_source tree;
    uint32_t node_level;
} top_source;

static int top_region(const vod_source *s, const vod_layout *L, vod_node *n)
{
    const top_source *t = s->ctx;
    if (n->level <= t->node_level) return VOD_REGION_EMPTY;
    return t->tree.ops->region(&t->tree, L, n);
}

static int top_fill(const vod_source *s, const vod_layout *L, const vod_node *n,
                    uint8_t *raw)
{
    const top_source *t = s->ctx;
    return t->tree.ops->fill(&t->tree, L, n, raw);
}

static const vod_source_ops top_ops = {.name = "the top of the tree", .region = top_region,
                                       .fill = top_fill};

/* Every node above node_level, encoded, to put in preorder. */
static int encode_nodes(mpi_top *t, octree *tree, const vod_params *p, top_put put,
                        void *ud)
{
    top_source ts = {.tree = vod_octree_source(tree), .node_level = t->node_level};
    /* a mesh or CSG job's densities and distances: the aggregates are
     * theirs (build) */
    ts.tree.channels |= 1u << VOXEL_CH_DENSITY | 1u << VOXEL_CH_DISTANCE;
    vod_source src = ts.tree;
    src.ops = &top_ops;
    src.ctx = &ts;
    size_t n = vod_collect(&src, &t->L, NULL, 0);
    vod_node *nodes = malloc((n ? n : 1) * sizeof *nodes);
    uint8_t **own = calloc(n ? n : 1, sizeof *own);
    vod_encoder *enc = NULL;
    int rc = nodes && own ? vod_encoder_new(&t->L, p, &enc) : -ENOMEM;
    if (!rc) vod_collect(&src, &t->L, nodes, n);
    size_t bound = vod_encode_bound(&t->L, p);
    for (size_t i = 0; !rc && i < n; i++) {
        if (nodes[i].level <= t->node_level) continue;
        vod_encoded rec;
        uint64_t same;
        if (!(own[i] = malloc(bound))) rc = -ENOMEM;
        vod_brick_out o = {own[i], bound, &rec};
        if (!rc) rc = vod_encoder_put(enc, &src, &nodes[i], i, &o, &same);
        if (!rc) rc = put(ud, &nodes[i], &rec, own[same]);
    }
    vod_encoder_free(enc);
    for (size_t i = 0; own && i < n; i++) free(own[i]);
    free(own);
    free(nodes);
    return rc;
}

int mpi_top_encode(mpi_top *t, const vod_params *p, top_put put, void *ud)
{
    if (t->node_level >= t->L.height - 1 || t->node_level < 1) return 0; /* no top */
    size_t cap = (t->nsubs + t->npairs) * (size_t)t->depth + 2;
    if (cap > UINT32_MAX) return -E2BIG;
    size_t bytes = octree_arena_bytes((uint32_t)cap);
    void *arena = mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                       MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (arena == MAP_FAILED) return -ENOMEM;
    octree tree;
    octree_init(&tree, arena, (uint32_t)cap, t->depth);
    int rc = build(t, &tree, p->channel);
    if (!rc) rc = encode_nodes(t, &tree, p, put, ud);
    free(tree.agg);
    munmap(arena, bytes);
    return rc;
}
