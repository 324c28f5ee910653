/* The implicit kind's worker side: Figure 3's slave step on an octant
 * (the paper schedule) or a whole subtree (the subtree schedule), with
 * the subdivision kernel of subdiv.c over the job's tape. */
#include <errno.h>
#include <stdlib.h>

#include "subdiv.h"
#include "work.h"

typedef struct {
    worker_ctx *w;
    expr_vm *vm;
    grid_spec grid;
    subdiv_kernel k;
    shm_entry *cur;        /* the entry being filled, or NULL */
} implicit_state;

static void implicit_free(void *state)
{
    implicit_state *st = state;
    if (!st) return;
    if (st->vm) expr_vm_free(st->vm);
    free(st);
}

/* A vm over the job's tape (in the segment). */
static int implicit_begin(worker_ctx *w, void **state)
{
    implicit_state *st = *state;
    if (!st && !(st = *state = calloc(1, sizeof *st))) return -ENOMEM;
    if (st->vm) expr_vm_free(st->vm);
    st->vm = NULL;
    st->w = w;
    const implicit_block *b = shm_at(w->base, w->h->job_off);
    st->grid = b->grid;
    if (grid_check(&st->grid)) return -EINVAL;
    int rc = expr_vm_new(shm_at(w->base, b->tape_off), st->grid.depth, &st->vm);
    if (rc) return rc;
    subdiv_kernel_init(&st->k, st->vm, &st->grid);
    return 0;
}

static int sink_octant(void *ud, const grid_octant *o)
{
    implicit_state *st = ud;
    shm_entry *en = worker_entry_begin(st->w, IMPLICIT_OCTANTS);
    if (!en) return -ECANCELED;
    ((grid_octant *)en->payload)[0] = *o;
    en->count = 1;
    return worker_entry_end(st->w);
}

/* Paper schedule: one voxel per entry, as in Figure 3. */
static int sink_voxel_one(void *ud, const grid_voxel *v)
{
    implicit_state *st = ud;
    shm_entry *en = worker_entry_begin(st->w, IMPLICIT_VOXELS);
    if (!en) return -ECANCELED;
    ((grid_voxel *)en->payload)[0] = *v;
    en->count = 1;
    return worker_entry_end(st->w);
}

/* Subtree schedule: batches of IMPLICIT_BATCH voxels in preorder. */
static int sink_voxel_batch(void *ud, const grid_voxel *v)
{
    implicit_state *st = ud;
    if (!st->cur && !(st->cur = worker_entry_begin(st->w, IMPLICIT_VOXELS)))
        return -ECANCELED;
    ((grid_voxel *)st->cur->payload)[st->cur->count++] = *v;
    if (st->cur->count < IMPLICIT_BATCH) return 0;
    st->cur = NULL;
    return worker_entry_end_batched(st->w);
}

/* Every SUBDIV_POLL_TESTS box tests: the heartbeat, and the job's abort. */
static int sink_poll(void *ud)
{
    implicit_state *st = ud;
    worker_tick(st->w);
    return worker_aborted(st->w) ? -ECANCELED : 0;
}

static int implicit_run(worker_ctx *w, void *state, const shm_task *t)
{
    implicit_state *st = state;
    if (worker_aborted(w)) return -ECANCELED; /* handed out just before a cancel */
    subdiv_sink sink = {.octant = sink_octant, .poll = sink_poll, .ud = st};
    grid_octant o = implicit_octant(t);
    int rc;
    if (t->op == IMPLICIT_CHILDREN) {
        sink.voxel = sink_voxel_one;
        rc = subdiv_children(&st->k, o, &sink);
    } else if (t->op == IMPLICIT_SUBTREE) {
        sink.voxel = sink_voxel_batch;
        rc = subdiv_subtree(&st->k, o, &sink);
        if (rc == 0 && st->cur) {
            st->cur = NULL;
            rc = worker_entry_end(w);
        }
    } else {
        return -EINVAL;
    }
    st->cur = NULL;
    w->s->job_tested = st->k.tested;
    return rc;
}

const worker_kind worker_implicit = {
    .name = "implicit",
    .begin = implicit_begin,
    .run = implicit_run,
    .free = implicit_free,
};
