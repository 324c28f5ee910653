/* One subtree on a rank: voxelized on the engine (or serially), its bricks
 * encoded, handed to the caller with their content keys and the top brick
 * rank 0 needs for the levels above (mpi_part.h). */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "err.h"
#include "kind_csg.h"
#include "kind_encode.h"
#include "kind_implicit.h"
#include "kind_mesh.h"
#include "mpi_part.h"
#include "subdiv.h"

#define SERIAL_CELLS (1u << 27) /* address space, touched as used */

typedef struct {
    const mpi_subtree_job *j;
    mpi_deliver deliver;
    void *ud;
    uint64_t voxels;
} sub_ctx;

/* The non-zero voxels of node n's brick (a subtree's top brick), added
 * to *out (*np of them so far). */
static int top_pairs(const vod_layout *L, const vod_source *src, const vod_node *n,
                     mpi_pair **out, size_t *np)
{
    size_t voxels = (size_t)L->brick * L->brick * L->brick;
    uint8_t *raw = calloc(1, L->raw_bytes);
    mpi_pair *p = realloc(*out, (*np + voxels) * sizeof *p);
    if (p) *out = p;
    int rc = raw && p ? 0 : -ENOMEM;
    if (!rc && n->uniform)
        for (size_t i = 0; i < voxels && n->value; i++) p[(*np)++] = (mpi_pair){(uint32_t)i, n->value};
    else if (!rc)
        rc = src->ops->fill(src, L, n, raw);
    for (size_t i = 0; !rc && !n->uniform && i < voxels; i++) {
        uint32_t v = L->voxel_bits == 32  ? vod_get32(raw + 4 * i)
                     : L->voxel_bits == 8 ? raw[i]
                                          : (uint32_t)(raw[i >> 3] >> (i & 7) & 1u);
        if (v) p[(*np)++] = (mpi_pair){(uint32_t)i, v};
    }
    free(raw);
    return rc;
}

/* The octant of the subtree whose top brick is node n (of level top). */
static grid_octant top_octant(const vod_layout *L, int depth, const vod_node *n, uint32_t top)
{
    if (top >= L->height - 1) return (grid_octant){0, 0, 0, (uint16_t)depth};
    uint32_t s = top + L->brick_log2;
    return (grid_octant){(uint16_t)(n->bx << s), (uint16_t)(n->by << s),
                         (uint16_t)(n->bz << s), (uint16_t)s};
}

/* The task's nodes (level <= node_level: the others are the paths above
 * its subtrees, rank 0's), keyed, with each subtree's top brick and its
 * voxels, to the caller.  An engine_deliver (kind_encode.h). */
static int hand_over(void *ud, const engine_bricks *eb)
{
    sub_ctx *c = ud;
    const vod_layout *L = eb->L;
    const vod_node *nodes = eb->nodes;
    const vod_encoded *recs = eb->recs;
    const uint8_t *const *data = eb->data;
    size_t n = eb->n;
    uint32_t top = c->j->node_level;
    mpi_rec *r = malloc((n ? n : 1) * sizeof *r);
    const uint8_t **d = malloc((n ? n : 1) * sizeof *d);
    mpi_topref *tops = malloc((n ? n : 1) * sizeof *tops);
    mpi_pair *pairs = NULL;
    size_t k = 0, nt = 0, np = 0;
    int rc = r && d && tops ? 0 : -ENOMEM;
    for (size_t i = 0; !rc && i < n; i++) {
        if (nodes[i].level > top) continue;
        if (nodes[i].level == top) {
            size_t before = np;
            if (top < L->height - 1) rc = top_pairs(L, eb->src, &nodes[i], &pairs, &np);
            tops[nt++] = (mpi_topref){top_octant(L, c->j->grid.depth, &nodes[i], top),
                                      (uint32_t)(np - before)};
        }
        r[k] = (mpi_rec){.preorder = nodes[i].preorder, .level = nodes[i].level,
                         .hash = recs[i].hash, .size = recs[i].size};
        mpi_key(data[i], recs[i].size, r[k].key);
        d[k++] = data[i];
    }
    mpi_bricks b = {.n = k, .recs = r, .data = d, .ntops = nt, .tops = tops, .npairs = np,
                    .pairs = pairs, .voxels = c->voxels};
    if (!rc) rc = c->deliver(c->ud, &b);
    free(pairs);
    free(tops);
    free(r);
    free(d);
    return rc;
}

void mpi_column_tiles(const grid_spec *g, grid_octant o, uint32_t tiles[4])
{
    uint32_t side = 1u << o.level, at[2] = {o.x, o.y};
    for (int a = 0; a < 2; a++) {
        uint32_t n = (g->res[a] + MESH_TILE - 1) / MESH_TILE;
        uint32_t hi = (at[a] + side + MESH_TILE - 1) / MESH_TILE;
        tiles[a] = at[a] / MESH_TILE;
        tiles[2 + a] = hi < n ? hi : n;
    }
}

/* The storage bricks of octant o (csg_bricks' lo, hi). */
static void octant_bricks(grid_octant o, uint32_t lo[3], uint32_t hi[3])
{
    uint32_t side = 1u << o.level, at[3] = {o.x, o.y, o.z};
    for (int a = 0; a < 3; a++) {
        lo[a] = at[a] / CSG_VOLUME_BRICK;
        hi[a] = (at[a] + side + CSG_VOLUME_BRICK - 1) / CSG_VOLUME_BRICK;
    }
}

/* The task's voxels on the engine: its octant's (implicit), its column's
 * tiles (mesh), its octant's storage bricks (csg). */
static int engine_task(const mpi_subtree_job *j, grid_octant o, engine_result *er)
{
    if (j->kind == MPI_KIND_MESH) {
        uint32_t tiles[4];
        mpi_column_tiles(&j->grid, o, tiles);
        engine_mesh_job mj = {.mesh = j->mesh, .grid = j->grid, .opts = j->mesh_opts,
                              .mip_channel = j->vod.channel, .tiles = tiles};
        return engine_mesh(j->e, &mj, er);
    }
    if (j->kind == MPI_KIND_CSG) {
        engine_csg_job cj = {.tree = j->tree, .grid = j->grid, .channel = j->vod.channel,
                             .root = &o};
        return engine_csg(j->e, &cj, er);
    }
    engine_job ej = {.tape = j->tape, .grid = j->grid, .root = &o, .schedule = j->schedule};
    return engine_voxelize(j->e, &ej, er);
}

static const char *task_noun(const mpi_subtree_job *j)
{
    return j->kind == MPI_KIND_MESH ? "column" : "octant";
}

static int on_engine(const mpi_subtree_job *j, grid_octant o, sub_ctx *c, err_info *err)
{
    engine_result er;
    int rc = engine_task(j, o, &er);
    c->voxels = er.voxels;
    if (rc) {
        err_set(err, rc, "voxelizing %s (%u,%u,%u) level %u: %s", task_noun(j), o.x,
                 o.y, o.z, o.level, er.err.msg);
        engine_release(j->e);
        return rc;
    }
    engine_error ee;
    rc = engine_encode_bricks(j->e, &j->vod, hand_over, c, NULL, &ee);
    if (rc) err_set(err, rc, "encoding the bricks of %s (%u,%u,%u) level %u: %s",
                     task_noun(j), o.x, o.y, o.z, o.level, ee.msg);
    engine_release(j->e);
    return rc;
}

static int store_voxel(void *ud, const grid_voxel *v)
{
    return octree_store(ud, v->x, v->y, v->z, v->value);
}

/* The task's nodes encoded here from src (prepared), each distinct brick
 * once (its duplicates point at it). */
static int encode_serial(const mpi_subtree_job *j, vod_source *src, const vod_layout *L,
                         sub_ctx *c, err_info *err)
{
    size_t n = vod_collect(src, L, NULL, 0);
    vod_node *nodes = malloc((n ? n : 1) * sizeof *nodes);
    vod_encoded *recs = calloc(n ? n : 1, sizeof *recs);
    const uint8_t **data = calloc(n ? n : 1, sizeof *data);
    uint8_t **own = calloc(n ? n : 1, sizeof *own);
    vod_encoder *enc = NULL;
    int rc = nodes && recs && data && own ? vod_encoder_new(L, &j->vod, &enc) : -ENOMEM;
    if (!rc) vod_collect(src, L, nodes, n);
    size_t bound = vod_encode_bound(L, &j->vod);
    for (size_t i = 0; !rc && i < n; i++) {
        if (nodes[i].level > j->node_level) continue; /* rank 0's */
        uint64_t same;
        if (!(own[i] = malloc(bound))) rc = -ENOMEM;
        vod_brick_out o = {own[i], bound, &recs[i]};
        if (!rc) rc = vod_encoder_put(enc, src, &nodes[i], i, &o, &same);
        if (!rc && same != i) {
            free(own[i]);
            own[i] = NULL;
        }
        if (!rc) data[i] = same == i ? own[i] : data[same];
    }
    if (rc) err_set(err, rc, "encoding a subtree's bricks: %s", strerror(-rc));
    /* the nodes above the subtree: no bytes, and hand_over skips them */
    for (size_t i = 0; !rc && i < n; i++)
        if (!data[i]) data[i] = (const uint8_t *)"";
    engine_bricks eb = {.L = L, .src = src, .n = n, .nodes = nodes, .recs = recs,
                        .data = data};
    if (!rc) rc = hand_over(c, &eb);
    vod_encoder_free(enc);
    for (size_t i = 0; own && i < n; i++) free(own[i]);
    free(own);
    free(data);
    free(recs);
    free(nodes);
    return rc;
}

/* The layout, the source prepared (its mip levels), then encode_serial. */
static int prepare_encode(const mpi_subtree_job *j, vod_source *src, sub_ctx *c, err_info *err)
{
    vod_layout L;
    int rc = vod_layout_make(&j->vod, j->grid.depth, &L, err);
    if (!rc) rc = vod_prepare(src, &L, j->vod.channel, err);
    return rc ? rc : encode_serial(j, src, &L, c, err);
}

static int octree_serial(const mpi_subtree_job *j, grid_octant o, sub_ctx *c, err_info *err)
{
    size_t bytes = octree_arena_bytes(SERIAL_CELLS);
    void *arena = mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                       MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (arena == MAP_FAILED) {
        return err_set(err, -ENOMEM, "cannot map the octree: %s", strerror(errno));
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
    if (rc) err_set(err, rc, "voxelizing octant (%u,%u,%u) level %u: %s", o.x, o.y,
                     o.z, o.level, rc == -ENOMEM ? "the octree outgrew its arena"
                                                 : strerror(-rc));
    c->voxels = t.voxels;
    vod_source src = vod_octree_source(&t);
    if (!rc && !(t.agg = malloc((size_t)t.used * sizeof *t.agg))) rc = -ENOMEM;
    if (!rc) rc = prepare_encode(j, &src, c, err);
    free(t.agg);
    munmap(arena, bytes);
    return rc;
}

/* A sparse private mapping of `bytes` (touched as used), MAP_FAILED if none. */
static void *sparse_map(size_t bytes)
{
    return bytes ? mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                        MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0)
                 : MAP_FAILED;
}

/* A csg job's file leaves built in *arena (MAP_FAILED: none), as the
 * serial pipeline builds them. */
static int csg_leaves(const mpi_subtree_job *j, void **arena, size_t *bytes,
                      vod_volume *leaves[CSG_MAX_NODES], err_info *err)
{
    *arena = MAP_FAILED;
    memset(leaves, 0, CSG_MAX_NODES * sizeof *leaves);
    if (!csg_has_file_leaves(j->tree)) return 0;
    *bytes = 0; /* a mesh leaf of a distance is f32 (csg_leaf_bits) */
    for (uint32_t i = 0; i < j->tree->n; i++)
        if (j->tree->node[i].kind == CSG_MESH || j->tree->node[i].kind == CSG_VOD)
            *bytes += vod_volume_bytes(j->grid.res, csg_leaf_bits(&j->tree->node[i]),
                                       CSG_VOLUME_BRICK, UINT64_MAX);
    if ((*arena = sparse_map(*bytes)) == MAP_FAILED) {
        return err_set(err, -ENOMEM, "cannot map the leaves' volumes");
    }
    csg_arena a = {.base = *arena, .bytes = *bytes};
    return csg_leaves_build(j->tree, &j->grid, &a, leaves, err);
}

void mpi_leaves_free(mpi_leaves *l)
{
    if (l->arena != MAP_FAILED) munmap(l->arena, l->bytes);
    *l = (mpi_leaves)MPI_LEAVES_INIT;
}

/* A csg task's bricks into vol, in this thread, over the job's leaves
 * (j->leaves: built by the first task; else for this task alone). */
static int csg_serial(const mpi_subtree_job *j, grid_octant o, vod_volume *vol, sub_ctx *c,
                      err_info *err)
{
    mpi_leaves own = MPI_LEAVES_INIT, *l = j->leaves ? j->leaves : &own;
    int rc = 0;
    if (!l->built) {
        mpi_leaves_free(l); /* what a failed build left */
        rc = csg_leaves(j, &l->arena, &l->bytes, l->v, err);
        l->built = !rc;
    }
    csg_bricks part = {.vol = vol, .channel = j->vod.channel};
    octant_bricks(o, part.lo, part.hi);
    csg_stats st = {0};
    if (!rc) {
        rc = csg_eval_bricks(j->tree, &j->grid, (const vod_volume *const *)l->v, &part, &st);
        if (rc) err_set(err, rc, "evaluating the tree: %s", strerror(-rc));
    }
    c->voxels = st.solid_voxels;
    mpi_leaves_free(&own);
    return rc;
}

/* A mesh or csg task in this thread: its voxels into a volume of the
 * whole grid (a sparse mapping: only the task's bricks are touched), then
 * its nodes encoded. */
static int volume_serial(const mpi_subtree_job *j, grid_octant o, sub_ctx *c, err_info *err)
{
    int is_mesh = j->kind == MPI_KIND_MESH;
    uint32_t bits = is_mesh ? mesh_vox_bits(&j->mesh_opts) : csg_channel_bits(j->vod.channel);
    /* a distance's volume in 8^3 bricks (MESH_DIST_BRICK), as on one machine:
     * the same file, less memory beyond the band */
    uint32_t sbrick = is_mesh ? mesh_vox_sbrick(&j->mesh_opts) : CSG_VOLUME_BRICK;
    size_t bytes = vod_volume_bytes(j->grid.res, bits, sbrick, UINT64_MAX);
    void *arena = sparse_map(bytes);
    if (arena == MAP_FAILED) {
        return err_set(err, -ENOMEM, "cannot map a volume of %ux%ux%u", j->grid.res[0],
                       j->grid.res[1], j->grid.res[2]);
    }
    vod_volume *vol;
    int rc = vod_volume_init(&vol, arena, bytes, j->grid.res, bits, sbrick);
    if (!rc && is_mesh) {
        uint32_t tiles[4];
        mpi_column_tiles(&j->grid, o, tiles);
        mesh_tile_stats st = {0};
        rc = mesh_voxelize_tiles(j->mesh, &j->grid, &j->mesh_opts, tiles, vol, &st);
        c->voxels = st.voxels;
        if (rc) err_set(err, rc, "voxelizing the mesh: %s", strerror(-rc));
    } else if (!rc) {
        rc = csg_serial(j, o, vol, c, err);
    }
    vod_source src = vod_volume_source(vol);
    if (!rc) rc = prepare_encode(j, &src, c, err);
    munmap(arena, bytes);
    return rc;
}

int mpi_subtree_run(const mpi_subtree_job *j, grid_octant o, mpi_deliver deliver,
                    void *ud, err_info *err)
{
    sub_ctx c = {.j = j, .deliver = deliver, .ud = ud};
    err_info scratch;
    if (!err) err = &scratch;
    *err = (err_info){0};
    /* a distance's column without a triangle: the band's width alone, its
     * uniform bricks made here (the engine's mesh kind takes no empty
     * mesh), the same bytes */
    int empty = j->kind == MPI_KIND_MESH && j->mesh->n_triangles == 0;
    if (j->e && !empty) return on_engine(j, o, &c, err);
    return j->kind == MPI_KIND_MESH || j->kind == MPI_KIND_CSG
               ? volume_serial(j, o, &c, err)
               : octree_serial(j, o, &c, err);
}
