/* One subtree on a rank: voxelized on the engine (or serially), its bricks
 * encoded, handed to the caller with their content keys and the top brick
 * rank 0 needs for the levels above (mpi_part.h). */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "mpi_part.h"
#include "subdiv.h"

#define SERIAL_CELLS (1u << 27) /* address space, touched as used */

typedef struct {
    const mpi_subtree_job *j;
    mpi_deliver deliver;
    void *ud;
    uint64_t voxels;
} sub_ctx;

/* The non-zero voxels of node n's brick (the subtree's top brick). */
static int top_pairs(const vod_layout *L, const vod_source *src, const vod_node *n,
                     mpi_pair **out, size_t *np)
{
    size_t voxels = (size_t)L->brick * L->brick * L->brick;
    uint8_t *raw = calloc(1, L->raw_bytes);
    mpi_pair *p = malloc(voxels * sizeof *p);
    int rc = raw && p ? 0 : -ENOMEM;
    if (!rc && n->uniform)
        for (size_t i = 0; i < voxels && n->value; i++) p[(*np)++] = (mpi_pair){(uint32_t)i, n->value};
    else if (!rc)
        rc = src->ops->fill(src, L, n, raw);
    for (size_t i = 0; !rc && !n->uniform && i < voxels; i++) {
        uint32_t v = L->voxel_bits == 32 ? vod_get32(raw + 4 * i)
                                         : (uint32_t)(raw[i >> 3] >> (i & 7) & 1u);
        if (v) p[(*np)++] = (mpi_pair){(uint32_t)i, v};
    }
    free(raw);
    if (rc) free(p);
    else *out = p;
    return rc;
}

/* The subtree's nodes (level <= node_level: the others are the path above
 * it, rank 0's), keyed, with its top brick's voxels, to the caller. */
static int hand_over(void *ud, const vod_layout *L, const vod_source *src, size_t n,
                     const vod_node *nodes, const vod_encoded *recs,
                     const uint8_t *const *data)
{
    sub_ctx *c = ud;
    uint32_t top = c->j->node_level;
    mpi_rec *r = malloc((n ? n : 1) * sizeof *r);
    const uint8_t **d = malloc((n ? n : 1) * sizeof *d);
    mpi_pair *pairs = NULL;
    size_t k = 0, np = 0;
    int rc = r && d ? 0 : -ENOMEM;
    for (size_t i = 0; !rc && i < n; i++) {
        if (nodes[i].level > top) continue;
        if (nodes[i].level == top && top < L->height - 1)
            rc = top_pairs(L, src, &nodes[i], &pairs, &np);
        r[k] = (mpi_rec){.preorder = nodes[i].preorder, .level = nodes[i].level,
                         .hash = recs[i].hash, .size = recs[i].size};
        mpi_key(data[i], recs[i].size, r[k].key);
        d[k++] = data[i];
    }
    mpi_bricks b = {.n = k, .recs = r, .data = d, .npairs = np, .pairs = pairs,
                    .voxels = c->voxels};
    if (!rc) rc = c->deliver(c->ud, &b);
    free(pairs);
    free(r);
    free(d);
    return rc;
}

static int on_engine(const mpi_subtree_job *j, grid_octant o, sub_ctx *c, char *err,
                     size_t errlen)
{
    engine_job ej = {.tape = j->tape, .grid = j->grid, .root = &o, .schedule = j->schedule};
    engine_result er;
    int rc = engine_voxelize(j->e, &ej, &er);
    c->voxels = er.voxels;
    if (rc) {
        snprintf(err, errlen, "voxelizing octant (%u,%u,%u) level %u: %s", o.x, o.y, o.z,
                 o.level, er.error);
        engine_release(j->e);
        return rc;
    }
    engine_error ee;
    rc = engine_encode_bricks(j->e, &j->vod, hand_over, c, NULL, &ee);
    if (rc) snprintf(err, errlen, "encoding the bricks of octant (%u,%u,%u) level %u: %s",
                     o.x, o.y, o.z, o.level, ee.message);
    engine_release(j->e);
    return rc;
}

static int store_voxel(void *ud, const grid_voxel *v)
{
    return octree_store(ud, v->x, v->y, v->z, v->value);
}

/* The subtree's nodes encoded here, each distinct brick once (its
 * duplicates point at it). */
static int encode_serial(const mpi_subtree_job *j, octree *t, sub_ctx *c, char *err,
                         size_t errlen)
{
    vod_layout L;
    int rc = vod_layout_make(&j->vod, t->depth, &L, err, errlen);
    if (rc) return rc;
    vod_source src = vod_octree_source(t);
    t->agg = malloc((size_t)t->used * sizeof *t->agg);
    if (!t->agg) return -ENOMEM;
    if ((rc = vod_prepare(&src, &L, j->vod.channel, err, errlen))) return rc;
    size_t n = vod_collect(&src, &L, NULL, 0);
    vod_node *nodes = malloc((n ? n : 1) * sizeof *nodes);
    vod_encoded *recs = calloc(n ? n : 1, sizeof *recs);
    const uint8_t **data = calloc(n ? n : 1, sizeof *data);
    uint8_t **own = calloc(n ? n : 1, sizeof *own);
    vod_encoder *enc = NULL;
    rc = nodes && recs && data && own ? vod_encoder_new(&L, &j->vod, &enc) : -ENOMEM;
    if (!rc) vod_collect(&src, &L, nodes, n);
    size_t bound = vod_encode_bound(&L, &j->vod);
    for (size_t i = 0; !rc && i < n; i++) {
        if (nodes[i].level > j->node_level) continue; /* rank 0's */
        uint64_t same;
        if (!(own[i] = malloc(bound))) rc = -ENOMEM;
        if (!rc) rc = vod_encoder_put(enc, &src, &nodes[i], i, own[i], bound, &recs[i], &same);
        if (!rc && same != i) {
            free(own[i]);
            own[i] = NULL;
        }
        if (!rc) data[i] = same == i ? own[i] : data[same];
    }
    if (rc) snprintf(err, errlen, "encoding a subtree's bricks: %s", strerror(-rc));
    /* the nodes above the subtree: no bytes, and hand_over skips them */
    for (size_t i = 0; !rc && i < n; i++)
        if (!data[i]) data[i] = (const uint8_t *)"";
    if (!rc) rc = hand_over(c, &L, &src, n, nodes, recs, data);
    vod_encoder_free(enc);
    for (size_t i = 0; own && i < n; i++) free(own[i]);
    free(own);
    free(data);
    free(recs);
    free(nodes);
    free(t->agg);
    t->agg = NULL;
    return rc;
}

static int on_serial(const mpi_subtree_job *j, grid_octant o, sub_ctx *c, char *err,
                     size_t errlen)
{
    size_t bytes = octree_arena_bytes(SERIAL_CELLS);
    void *arena = mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                       MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (arena == MAP_FAILED) {
        snprintf(err, errlen, "cannot map the octree: %s", strerror(errno));
        return -ENOMEM;
    }
    octree t;
    octree_init(&t, arena, SERIAL_CELLS, j->grid.depth);
    expr_vm *vm;
    int rc = expr_vm_new(j->tape, j->grid.depth, &vm);
    if (!rc) {
        subdiv_kernel k;
        subdiv_kernel_init(&k, vm, &j->grid);
        subdiv_sink sink = {.voxel = store_voxel, .ud = &t};
        rc = subdiv_subtree(&k, o, &sink);
        expr_vm_free(vm);
    }
    if (rc) snprintf(err, errlen, "voxelizing octant (%u,%u,%u) level %u: %s", o.x, o.y,
                     o.z, o.level, rc == -ENOMEM ? "the octree outgrew its arena"
                                                 : strerror(-rc));
    c->voxels = t.voxels;
    if (!rc) rc = encode_serial(j, &t, c, err, errlen);
    munmap(arena, bytes);
    return rc;
}

int mpi_subtree_run(const mpi_subtree_job *j, grid_octant o, mpi_deliver deliver,
                    void *ud, char *err, size_t errlen)
{
    sub_ctx c = {.j = j, .deliver = deliver, .ud = ud};
    err[0] = '\0';
    return j->e ? on_engine(j, o, &c, err, errlen) : on_serial(j, o, &c, err, errlen);
}
