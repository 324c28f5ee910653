/* The implicit kind's worker side: Figure 3's slave step on an octant
 * (the paper schedule) or a whole subtree (the subtree schedule), with
 * the subdivision kernel of subdiv.c over the job's tape.  A subtree's
 * voxels go straight into its own cells in the job's arena (Figure 2's
 * insertion, blocks claimed from the block's counter); the master gets
 * its root cell and links it. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "prefault.h"
#include "subdiv.h"
#include "work.h"

typedef struct {
    worker_ctx *w;
    expr_vm *vm;
    grid_spec grid;
    subdiv_kernel k;
    grid_octant at;        /* the subtree's octant */
    implicit_block *b;
    uint16_t who;          /* 1 + this worker's slot: the blocks' owner */
    octree t;              /* the subtree being built; its block carries
                              over to the next subtree of the job */
} implicit_state;

static void implicit_free(void *state)
{
    implicit_state *st = state;
    if (!st) return;
    if (st->vm) expr_vm_free(st->vm);
    free(st);
}

/* A block of the arena for this worker (octree_grab), its pages mapped
 * by one call rather than a fault each as its cells are taken (the
 * sphere at 2048^3: 34,000 of its 81,000 faults; design.md, Page faults). */
static int grab(void *ud, uint32_t *first, uint32_t *end)
{
    implicit_state *st = ud;
    int rc = implicit_claim(st->w->base, st->b, st->who, first, end);
    if (!rc) prefault_write(&st->t.cells[*first], (size_t)(*end - *first) * sizeof st->t.cells[0]);
    return rc;
}

/* A vm over the job's tape (in the segment), a writer of its arena. */
static int implicit_begin(worker_ctx *w, void **state)
{
    implicit_state *st = *state;
    if (!st && !(st = *state = calloc(1, sizeof *st))) return -ENOMEM;
    if (st->vm) expr_vm_free(st->vm);
    st->vm = NULL;
    st->w = w;
    implicit_block *b = shm_at(w->base, w->h->job_off);
    st->b = b;
    st->who = (uint16_t)(1 + ((uint8_t *)w->s - w->base - w->h->slots_off) / w->h->slot_bytes);
    octree_writer(&st->t, shm_at(w->base, b->tree_off), b->tree_cells, grab, st);
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

/* Subtree schedule: into the subtree's cells, in its own coordinates
 * (the subtree's octant at the origin). */
static int sink_voxel_store(void *ud, const grid_voxel *v)
{
    implicit_state *st = ud;
    const grid_octant *o = &st->at;
    return octree_store(&st->t, v->x - o->x, v->y - o->y, v->z - o->z, v->value);
}

/* The subtree of o, built; its root to the master (nothing if empty). */
static int build_subtree(implicit_state *st, grid_octant o, subdiv_sink *sink)
{
    sink->voxel = sink_voxel_store;
    st->at = o;
    octree_subtree(&st->t, o.level);
    int rc = subdiv_subtree(&st->k, o, sink);
    if (rc || !st->t.root) return rc;
    shm_entry *en = worker_entry_begin(st->w, IMPLICIT_BUILT);
    if (!en) return -ECANCELED;
    implicit_subtree s = {.o = o, .root = st->t.root, .cells = st->t.taken,
                          .end = st->t.next, .voxels = st->t.voxels};
    memcpy(en->payload, &s, sizeof s);
    en->count = 1;
    return worker_entry_end(st->w);
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
    } else if (t->op == IMPLICIT_SUBTREE && o.level >= 1 && o.level <= st->grid.depth) {
        rc = build_subtree(st, o, &sink);
    } else {
        return -EINVAL;
    }
    w->s->job_tested = st->k.tested;
    return rc;
}

const worker_kind worker_implicit = {
    .name = "implicit",
    .begin = implicit_begin,
    .run = implicit_run,
    .free = implicit_free,
};
