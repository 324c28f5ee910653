/* The iso kind's worker side, two phases.  ISO_BRICKS: marching cubes on
 * the tasks it claims from the block's counter, each task's piece packed
 * into the shared arena and its result marked done.  ISO_WELD: the pieces
 * it claims welded into the mesh's arrays (the master checked them and
 * laid the arrays out in between).  What a worker does not finish (a
 * piece that does not fit, a failure, a death) is left unmarked: the
 * master does it. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "prefault.h"
#include "work.h"

typedef struct {
    iso_work *w;
    uint32_t brick, normals; /* what w was made for */
    worker_chunk arena;      /* this worker's chunk of the job's arena */
} iso_state;

static void iso_state_free(void *state)
{
    iso_state *st = state;
    if (!st) return;
    iso_work_free(st->w);
    free(st);
}

/* The scratch for this job's bricks, kept while the brick size and the
 * channel stay the same. */
static int iso_begin(worker_ctx *w, void **state)
{
    iso_state *st = *state;
    if (!st && !(st = *state = calloc(1, sizeof *st))) return -ENOMEM;
    const iso_block *b = shm_at(w->base, w->h->job_off);
    st->arena = (worker_chunk){0, 0}; /* a new job's arena */
    if (st->w && st->brick == b->p.brick && st->normals == b->p.normals) return 0;
    iso_work_free(st->w);
    st->w = NULL;
    int rc = iso_work_new(&b->p, &st->w);
    st->brick = b->p.brick;
    st->normals = b->p.normals;
    return rc;
}

static iso_input block_input(const worker_ctx *w, const iso_block *b)
{
    return (iso_input){
        .n = b->n_bricks,
        .keys = shm_at(w->base, b->keys_off),
        .offs = shm_at(w->base, b->offs_off),
        .raw = shm_at(w->base, b->raw_off),
        .raw_bytes = b->raw_bytes,
    };
}

/* Task i's piece into the arena, if it fits. */
static void store(worker_ctx *w, iso_state *st, iso_block *b, uint64_t i, const iso_piece *pc)
{
    iso_result *r = (iso_result *)shm_at(w->base, b->results_off) + i;
    uint64_t bytes = iso_piece_bytes(&b->p, pc);
    uint64_t off = worker_chunk_take(w, &st->arena, &b->bump, b->arena_off, b->arena_cap,
                                     (bytes + 7) & ~7ull);
    if (off == UINT64_MAX) return;
    iso_piece_pack(&b->p, pc, shm_at(w->base, b->arena_off + off));
    r->off = off;
    r->nv = pc->nv;
    r->nc = pc->nc;
    r->nt = pc->nt;
    r->ne = pc->ne;
    /* release: pairs with the master's acquire load of done */
    atomic_store_explicit(&r->done, 1, memory_order_release);
}

/* Every piece's view (the master checked them before the weld). */
static iso_piece *views(const worker_ctx *w, const iso_block *b)
{
    iso_piece *pc = calloc(b->n_tasks + 1, sizeof *pc);
    const iso_result *res = shm_at(w->base, b->results_off);
    const iso_task *t = shm_at(w->base, b->tasks_off);
    for (uint64_t i = 0; pc && i < b->n_tasks; i++) {
        const iso_result *r = &res[i];
        pc[i] = (iso_piece){.key = iso_task_key(&b->p, &t[i]), .nv = r->nv, .nc = r->nc,
                            .nt = r->nt, .ne = r->ne};
        if (r->off > b->arena_cap ||
            iso_piece_view(&b->p, shm_at(w->base, b->arena_off + r->off),
                           b->arena_cap - r->off, &pc[i])) {
            free(pc);
            return NULL;
        }
    }
    return pc;
}

/* The output arrays of pieces [i0, i1) mapped by one call each: their
 * ranges are contiguous, and a worker welds a run of pieces at a time so
 * that the pages it writes are its own. */
static void prefault_pieces(const iso_weld *wd, uint64_t i0, uint64_t i1)
{
    uint64_t v0 = wd->vbase[i0], v1 = wd->vbase[i1], t0 = wd->tbase[i0], t1 = wd->tbase[i1];
    prefault_write(wd->pos + 3 * v0, 12 * (v1 - v0));
    if (wd->nrm) prefault_write(wd->nrm + 3 * v0, 12 * (v1 - v0));
    prefault_write(wd->tri + 3 * t0, 12 * (t1 - t0));
}

#define WELD_RUN 64u /* pieces claimed at a time */

static int weld_run(worker_ctx *w, iso_block *b)
{
    iso_piece *pc = views(w, b);
    if (!pc) return -ENOMEM;
    iso_result *res = shm_at(w->base, b->results_off);
    iso_weld wd = {&b->p, pc, b->n_tasks, shm_at(w->base, b->vbase_off),
                   shm_at(w->base, b->tbase_off), shm_at(w->base, b->pos_off),
                   b->nrm_off ? shm_at(w->base, b->nrm_off) : NULL,
                   shm_at(w->base, b->tri_off)};
    int rc = 0;
    while (!rc) {
        /* relaxed: a counter that hands out disjoint runs of pieces */
        uint64_t i0 = atomic_fetch_add_explicit(&b->weld_next, WELD_RUN, memory_order_relaxed);
        if (i0 >= b->n_tasks) break;
        uint64_t i1 = b->n_tasks - i0 < WELD_RUN ? b->n_tasks : i0 + WELD_RUN;
        prefault_pieces(&wd, i0, i1);
        for (uint64_t i = i0; i < i1 && !rc; i++) {
            if (worker_aborted(w)) rc = -ECANCELED;
            if (rc) break;
            worker_tick(w);
            /* release: pairs with the master's acquire load of welded */
            if (!iso_weld_piece(&wd, i, NULL)) /* the master says what failed */
                atomic_store_explicit(&res[i].welded, 1, memory_order_release);
        }
    }
    free(pc);
    return rc;
}

static int iso_run(worker_ctx *w, void *state, const shm_task *t)
{
    iso_state *st = state;
    iso_block *b = shm_at(w->base, w->h->job_off);
    if (t->op == ISO_WELD) return weld_run(w, b);
    if (t->op != ISO_BRICKS) return -EINVAL;
    iso_input in = block_input(w, b);
    const iso_task *tasks = shm_at(w->base, b->tasks_off);
    for (;;) {
        if (worker_aborted(w)) return -ECANCELED;
        /* relaxed: a counter that hands out disjoint tasks */
        uint64_t i = atomic_fetch_add_explicit(&b->next, 1, memory_order_relaxed);
        if (i >= b->n_tasks) return 0;
        worker_tick(w);
        iso_piece pc;
        if (iso_task_run(st->w, &b->p, &in, &tasks[i], &pc) == 0) store(w, st, b, i, &pc);
    }
}

const worker_kind worker_iso = {
    .name = "iso",
    .begin = iso_begin,
    .run = iso_run,
    .free = iso_state_free,
};
