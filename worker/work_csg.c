/* The csg kind's worker side: runs of storage bricks of a volume CSG tree
 * (csg.h) evaluated into the job's volume.  The tree, the stats array and
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
#include "vod_volume.h"
#include "work.h"

typedef struct {
    csg_tree tree;         /* nodes copied from the segment, text pointing there */
    csg_eval *ev;
    uint8_t *buf;          /* one brick */
    size_t buf_bytes;
} csg_state;

static void csg_state_free(void *state)
{
    csg_state *st = state;
    if (!st) return;
    csg_eval_free(st->ev);
    free(st->buf);
    free(st);
}

/* The job's tree and evaluator (the last job's dropped). */
static int csg_begin(work_ctx *w, void **state)
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
    const vod_volume *leaves[CSG_MAX_NODES] = {0};
    for (uint32_t i = 0; i < b->n_nodes; i++)
        if (b->leaf_off[i] && !(leaves[i] = vod_volume_view(shm_at(w->base, b->leaf_off[i]))))
            return -EINVAL;
    return csg_eval_new(&st->tree, &b->grid, b->sbrick, leaves, &st->ev);
}

/* Columns a.first .. a.first + a.count - 1 of level mip_levels: their
 * mip levels 1..mip_levels, from the bricks every task has written. */
static int mips_run(work_ctx *w, const csg_block *b, csg_task_arg a)
{
    vod_volume *vol = vod_volume_view(shm_at(w->base, b->volume_off));
    if (!vol || !b->mip_levels || b->mip_levels > 31) return -EINVAL;
    uint32_t side = b->sbrick << b->mip_levels, g[2];
    for (int i = 0; i < 2; i++) g[i] = (b->grid.res[i] + side - 1) / side;
    uint64_t n = (uint64_t)g[0] * g[1];
    if (a.first >= n || a.count > n - a.first) return -EINVAL;
    for (uint64_t k = a.first; k < (uint64_t)a.first + a.count; k++) {
        if (work_aborted(w)) return -ECANCELED;
        uint32_t lo[2] = {(uint32_t)(k % g[0]), (uint32_t)(k / g[0])};
        uint32_t hi[2] = {lo[0] + 1, lo[1] + 1};
        int rc = vod_volume_mip_columns(vol, (int)b->channel, (int)b->mip_levels, lo, hi);
        if (rc) return rc;
        work_tick(w);
    }
    return 0;
}

static int csg_run(work_ctx *w, void *state, const shm_task *t)
{
    csg_state *st = state;
    const csg_block *b = shm_at(w->base, w->h->job_off);
    csg_task_arg a = csg_task_bricks(t);
    if (t->op == CSG_MIPS) return mips_run(w, b, a);
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
        if (work_aborted(w)) return -ECANCELED;
        uint32_t bc[3] = {b->box_lo[0] + (uint32_t)(k % b->box_n[0]),
                          b->box_lo[1] + (uint32_t)(k / b->box_n[0] % b->box_n[1]),
                          b->box_lo[2] + (uint32_t)(k / b->box_n[0] / b->box_n[1])};
        int rc = csg_eval_store(st->ev, vol, bc, st->buf, (int)b->channel);
        if (rc) return rc;
        work_tick(w);
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

const work_kind work_csg = {
    .name = "csg",
    .begin = csg_begin,
    .run = csg_run,
    .free = csg_state_free,
};
