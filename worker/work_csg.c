/* The csg kind's worker side: runs of storage bricks of a volume CSG tree
 * (csg.h) evaluated into the job's volume, after the mesh leaves' volumes,
 * which runs of their tiles build first (mesh_tile_run, one leaf at a
 * time, its mesh and bins laid out by the master as a mesh job's block).  The tree, the stats array and
 * the volume are in the segment, laid out by the master (csg_block); the
 * worker rebuilds the tree around the nodes and text there and compiles
 * its implicit leaves once per job.  A brick is a pure function of tree,
 * grid and brick, and a task's counts go to its own stats entry, so a task
 * run again after a death writes the same bytes.  Once every brick is in,
 * runs of brick columns get their low mip levels built here too. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "mesh_vox.h"
#include "vod_volume.h"
#include "work.h"

typedef struct {
    csg_tree tree;         /* nodes copied from the segment, text pointing there */
    csg_eval *ev;
    uint8_t *buf;          /* one brick */
    size_t buf_bytes;
    void *scratch;         /* a mesh leaf's tile */
    size_t scratch_bytes;
} csg_state;

static void csg_state_free(void *state)
{
    csg_state *st = state;
    if (!st) return;
    csg_eval_free(st->ev);
    free(st->buf);
    free(st->scratch);
    free(st);
}

/* The job's tree (the last job's evaluator dropped; the new one at the first brick). */
static int csg_begin(worker_ctx *w, void **state)
{
    csg_state *st = *state;
    if (!st && !(st = *state = calloc(1, sizeof *st))) return -ENOMEM;
    csg_eval_free(st->ev);
    st->ev = NULL;
    const csg_block *b = shm_at(w->base, w->h->job_off);
    if (b->node_bytes != sizeof(csg_node) || !b->n_nodes || b->n_nodes > CSG_MAX_NODES)
        return -EINVAL;
    memcpy(st->tree.node, shm_at(w->base, b->nodes_off), b->n_nodes * sizeof(csg_node));
    st->tree.n = b->n_nodes;
    st->tree.text = shm_at(w->base, b->text_off);
    st->tree.text_len = b->text_len;
    size_t want = (size_t)b->sbrick * b->sbrick * b->sbrick * 4; /* up to 32-bit voxels */
    if (st->buf_bytes < want) {
        free(st->buf);
        st->buf_bytes = 0;
        if (!(st->buf = malloc(want))) return -ENOMEM;
        st->buf_bytes = want;
    }
    return 0;
}

/* The evaluator, at the job's first brick: the leaves' volumes are built
 * by then (the master pushes no brick before the last leaf is in). */
static int csg_evaluator(worker_ctx *w, csg_state *st, const csg_block *b)
{
    if (st->ev) return 0;
    const vod_volume *leaves[CSG_MAX_NODES] = {0};
    for (uint32_t i = 0; i < b->n_nodes; i++)
        if (b->leaf_off[i] && !(leaves[i] = vod_volume_view(shm_at(w->base, b->leaf_off[i]))))
            return -EINVAL;
    return csg_eval_new(&st->tree, &b->grid, b->sbrick, leaves, &st->ev);
}

/* The tiles' heartbeat (mesh_tile_env), as the mesh kind's. */
static int tile_tick(void *arg)
{
    worker_ctx *w = arg;
    worker_tick(w);
    return worker_aborted(w);
}

/* Tiles a.first .. a.first + a.count - 1 of mesh leaf a.task into its
 * volume: its mesh, bins and volume as the master laid them out. */
static int leaf_tiles(worker_ctx *w, csg_state *st, const csg_block *b, csg_task_arg a)
{
    if (a.task >= b->n_nodes || !b->leaf_mesh_off || b->leaf_off[a.task] == 0) return -EINVAL;
    const mesh_block *mb = shm_at(w->base, b->leaf_mesh_off);
    uint64_t n = (uint64_t)mb->tiles[0] * mb->tiles[1];
    if (a.first >= n || a.count > n - a.first || mb->volume_off != b->leaf_off[a.task])
        return -EINVAL;
    size_t want = mesh_tile_scratch_bytes(&mb->grid, &mb->opts);
    if (st->scratch_bytes < want) {
        free(st->scratch);
        st->scratch_bytes = 0;
        if (!(st->scratch = malloc(want))) return -ENOMEM;
        st->scratch_bytes = want;
    }
    mesh m = {.n_vertices = mb->n_vertices, .n_triangles = mb->n_triangles,
              .vertices = shm_at(w->base, mb->vertices_off),
              .triangles = shm_at(w->base, mb->triangles_off)};
    memcpy(m.lo, mb->lo, sizeof m.lo);
    memcpy(m.hi, mb->hi, sizeof m.hi);
    const uint64_t *start = shm_at(w->base, mb->start_off);
    const uint32_t *ids = shm_at(w->base, mb->ids_off);
    vod_volume *vol = vod_volume_view(shm_at(w->base, mb->volume_off));
    if (!vol) return -EINVAL;
    mesh_tile_env env = {.tick = tile_tick, .arg = w};
    const mesh_tiles j = {.m = &m, .g = &mb->grid, .o = &mb->opts, .vol = vol, .env = &env,
                          .scratch = st->scratch};
    for (uint64_t k = a.first; k < (uint64_t)a.first + a.count; k++) {
        if (worker_aborted(w)) return -ECANCELED;
        mesh_tile_stats s = {0};
        int rc = mesh_tile_run(&j, ids + start[k], start[k + 1] - start[k],
                               (uint32_t)(k % mb->tiles[0]), (uint32_t)(k / mb->tiles[0]), &s);
        if (rc) return rc;
        worker_tick(w);
    }
    return 0;
}

/* Columns a.first .. a.first + a.count - 1 of level mip_levels: their
 * mip levels 1..mip_levels, from the bricks every task has written. */
static int mips_run(worker_ctx *w, const csg_block *b, csg_task_arg a)
{
    vod_volume *vol = vod_volume_view(shm_at(w->base, b->volume_off));
    if (!vol || !b->mip_levels || b->mip_levels > 31) return -EINVAL;
    uint32_t side = b->sbrick << b->mip_levels, g[2];
    for (int i = 0; i < 2; i++) g[i] = (b->grid.res[i] + side - 1) / side;
    uint64_t n = (uint64_t)g[0] * g[1];
    if (a.first >= n || a.count > n - a.first) return -EINVAL;
    for (uint64_t k = a.first; k < (uint64_t)a.first + a.count; k++) {
        if (worker_aborted(w)) return -ECANCELED;
        uint32_t lo[2] = {(uint32_t)(k % g[0]), (uint32_t)(k / g[0])};
        uint32_t hi[2] = {lo[0] + 1, lo[1] + 1};
        int rc = vod_volume_mip_columns(vol, (int)b->channel, (int)b->mip_levels, lo, hi);
        if (rc) return rc;
        worker_tick(w);
    }
    return 0;
}

static int csg_run(worker_ctx *w, void *state, const shm_task *t)
{
    csg_state *st = state;
    const csg_block *b = shm_at(w->base, w->h->job_off);
    csg_task_arg a = csg_task_bricks(t);
    if (t->op == CSG_MIPS) return mips_run(w, b, a);
    if (t->op == CSG_LEAF_TILES) return leaf_tiles(w, st, b, a);
    int rc = csg_evaluator(w, st, b);
    if (rc) return rc;
    uint64_t n = (uint64_t)b->box_n[0] * b->box_n[1] * b->box_n[2];
    for (int i = 0; i < 3; i++)
        if (b->box_lo[i] > b->nbricks[i] || b->box_n[i] > b->nbricks[i] - b->box_lo[i])
            return -EINVAL;
    if (t->op != CSG_BRICKS || !st->ev || a.first >= n || a.count > n - a.first ||
        a.task >= b->ntasks)
        return -EINVAL;
    vod_volume *vol = vod_volume_view(shm_at(w->base, b->volume_off));
    if (!vol) return -EINVAL;
    csg_stats s0 = *csg_eval_stats(st->ev);
    for (uint64_t k = a.first; k < (uint64_t)a.first + a.count; k++) {
        if (worker_aborted(w)) return -ECANCELED;
        uint32_t bc[3] = {b->box_lo[0] + (uint32_t)(k % b->box_n[0]),
                          b->box_lo[1] + (uint32_t)(k / b->box_n[0] % b->box_n[1]),
                          b->box_lo[2] + (uint32_t)(k / b->box_n[0] / b->box_n[1])};
        if ((rc = csg_eval_store(st->ev, vol, bc, st->buf, (int)b->channel))) return rc;
        worker_tick(w);
    }
    const csg_stats *s1 = csg_eval_stats(st->ev);
    csg_task_stats *out = shm_at(w->base, b->stats_off);
    out[a.task] = (csg_task_stats){
        .bricks = s1->bricks - s0.bricks,
        .uniform_bricks = s1->uniform_bricks - s0.uniform_bricks,
        .skipped = s1->skipped - s0.skipped,
        .voxel_evals = s1->voxel_evals - s0.voxel_evals,
        .solid_voxels = s1->solid_voxels - s0.solid_voxels,
    };
    return 0;
}

const worker_kind worker_csg = {
    .name = "csg",
    .begin = csg_begin,
    .run = csg_run,
    .free = csg_state_free,
};
