/* The iso kind's master side: marching cubes over a VOD file's bricks by
 * every worker.  Setup copies the raw bricks of the levels the job reads
 * into the data area behind the block (each shared brick once), then the
 * tasks (iso_tasks, in key order) and their result records, and gives the
 * rest of the data area to the pieces; one task per worker starts them,
 * each worker then claims tasks from the block's counter until none is
 * left.  At the end every task whose piece is not done (its worker died,
 * failed, or the arena was full) is run here, and the pieces are welded
 * (iso_merge, which checks each one) in task order: the mesh is the
 * serial run's, byte for byte, whoever ran which task. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clock.h"
#include "master.h"

typedef struct {
    const engine_iso_job *job;
    iso_mesh *out;
    engine_result *r;
    uint64_t at;           /* the data area's next free byte (setup) */
    double t_setup;        /* when setup was done */
} iso_job;

static uint64_t align64(uint64_t v) { return (v + 63) / 64 * 64; }

static iso_block *block(engine *e)
{
    return shm_at(e->seg.base, e->h->job_off);
}

static int no_room(engine *e, const char *what)
{
    return sched_fail(e, ENGINE_LIMIT, -ENOMEM,
                      "%s does not fit in shared memory (%zu MiB); raise its size",
                      what, e->seg.bytes >> 20);
}

/* iso_input_make's allocator: the data area, from ij->at on. */
static void *shm_alloc(void *ud, size_t bytes)
{
    engine *e = ud;
    iso_job *ij = e->job;
    uint64_t end = e->h->data_off + e->h->data_bytes, at = align64(ij->at);
    if (at > end || bytes > end - at) return NULL;
    ij->at = at + bytes;
    return shm_at(e->seg.base, at);
}

static int lay_out_tasks(engine *e, iso_block *b, const iso_input *in)
{
    iso_task *t;
    uint64_t n;
    if (iso_tasks(&b->p, in, &t, &n))
        return sched_fail(e, ENGINE_FAULT, -ENOMEM, "out of memory for the tasks");
    iso_task *st = shm_alloc(e, n * sizeof *t);
    iso_result *res = st ? shm_alloc(e, n * sizeof *res) : NULL;
    if (res) {
        memcpy(st, t, n * sizeof *t);
        memset(res, 0, n * sizeof *res);
        b->n_tasks = n;
        b->tasks_off = (uint64_t)((uint8_t *)st - e->seg.base);
        b->results_off = (uint64_t)((uint8_t *)res - e->seg.base);
    }
    free(t);
    return res ? 0 : no_room(e, "the tasks");
}

/* One task per live worker: each runs tasks until none is left. */
static int push_all(engine *e)
{
    shm_task t = {.kind = SHM_KIND_ISO, .op = ISO_BRICKS};
    int rc = 0;
    for (int i = 0; i < e->n && !rc; i++)
        if (e->ms[i].pid > 0) rc = sched_push(e, &t);
    return rc;
}

static int iso_setup(engine *e, void *job)
{
    iso_job *ij = job;
    e->result = RESULT_NONE;
    sched_hold(e, 0);
    iso_block *b = shm_at(e->seg.base, e->h->data_off);
    memset(b, 0, sizeof *b);
    b->p = *ij->job->p;
    e->h->job_off = e->h->data_off;
    e->h->job_bytes = sizeof *b;
    ij->at = e->h->data_off + sizeof *b;
    iso_input in;
    int rc = iso_input_make(ij->job->file, &b->p, shm_alloc, e, &in);
    if (rc) return no_room(e, "the file's bricks");
    b->n_bricks = in.n;
    b->keys_off = (uint64_t)((const uint8_t *)in.keys - e->seg.base);
    b->offs_off = (uint64_t)((const uint8_t *)in.offs - e->seg.base);
    b->raw_off = (uint64_t)(in.raw - e->seg.base);
    b->raw_bytes = in.raw_bytes;
    if ((rc = lay_out_tasks(e, b, &in))) return rc;
    uint64_t end = e->h->data_off + e->h->data_bytes;
    b->arena_off = align64(ij->at);
    b->arena_cap = b->arena_off < end ? end - b->arena_off : 0;
    /* relaxed: published to the workers by the task_seq release */
    atomic_store_explicit(&b->next, 0, memory_order_relaxed);
    atomic_store_explicit(&b->bump, 0, memory_order_relaxed);
    ij->t_setup = clock_now();
    return push_all(e);
}

static int iso_take(engine *e, int i, const shm_entry *en)
{
    return sched_fail(e, ENGINE_FAULT, -EPROTO,
                      "worker %d sent an entry of type %u in marching cubes", i, en->type);
}

/* A worker's failure or death leaves its tasks undone: iso_finish runs them. */
static void iso_done(engine *e, int i, const shm_task *t, int error)
{
    (void)e, (void)i, (void)t, (void)error;
}

static int iso_rerun(engine *e, int i, const shm_task *t)
{
    (void)e, (void)i, (void)t;
    return 0;
}

static void iso_describe(const shm_task *t, char *buf, size_t len)
{
    (void)t;
    snprintf(buf, len, "marching cubes");
}

static void iso_progress(engine *e, engine_progress *p)
{
    iso_block *b = block(e);
    /* relaxed: an estimate, nothing is read through it */
    uint64_t next = atomic_load_explicit(&b->next, memory_order_relaxed);
    p->fraction = b->n_tasks ? (double)(next < b->n_tasks ? next : b->n_tasks) / b->n_tasks : 1;
    p->level = (int)b->p.level;
    p->shm_used = align64(b->arena_off) - e->h->data_off +
                  atomic_load_explicit(&b->bump, memory_order_relaxed);
}

/* Task i's piece: the worker's when it is done and fits the arena, else
 * run here into own[i]. */
static int piece_of(engine *e, iso_work **w, uint64_t i, iso_piece *pc, uint8_t **own)
{
    iso_block *b = block(e);
    iso_result *r = (iso_result *)shm_at(e->seg.base, b->results_off) + i;
    const iso_task *t = (const iso_task *)shm_at(e->seg.base, b->tasks_off) + i;
    uint64_t key = iso_task_key(&b->p, t);
    /* acquire: pairs with the worker's release store of done */
    if (atomic_load_explicit(&r->done, memory_order_acquire) && r->off < b->arena_cap &&
        !iso_piece_view(&b->p, shm_at(e->seg.base, b->arena_off + r->off),
                        b->arena_cap - r->off, key, r->nv, r->nc, r->nt, r->ne, pc))
        return 0;
    int rc = *w ? 0 : iso_work_new(&b->p, w);
    iso_input in = {b->n_bricks, shm_at(e->seg.base, b->keys_off),
                    shm_at(e->seg.base, b->offs_off), shm_at(e->seg.base, b->raw_off),
                    b->raw_bytes};
    iso_piece v;
    if (!rc) rc = iso_task_run(*w, &b->p, &in, t, &v);
    size_t bytes = rc ? 0 : iso_piece_bytes(&b->p, &v);
    if (!rc && !(*own = malloc(bytes ? bytes : 1))) rc = -ENOMEM;
    if (rc) return rc;
    iso_piece_pack(&b->p, &v, *own);
    return iso_piece_view(&b->p, *own, bytes, key, v.nv, v.nc, v.nt, v.ne, pc);
}

static int gather_and_merge(engine *e, iso_job *ij)
{
    iso_block *b = block(e);
    uint64_t n = b->n_tasks;
    iso_piece *pc = calloc(n + 1, sizeof *pc);
    uint8_t **own = calloc(n + 1, sizeof *own);
    iso_work *w = NULL;
    int rc = pc && own ? 0 : -ENOMEM;
    for (uint64_t i = 0; i < n && !rc; i++) rc = piece_of(e, &w, i, &pc[i], &own[i]);
    iso_work_free(w);
    char msg[sizeof e->err.message] = "";
    if (rc) sched_fail(e, ENGINE_FAULT, rc, "marching cubes: %s", strerror(-rc));
    else if ((rc = iso_merge(&b->p, pc, n, ij->out, msg, sizeof msg)))
        sched_fail(e, rc == -E2BIG ? ENGINE_LIMIT : ENGINE_FAULT, rc, "%s", msg);
    for (uint64_t i = 0; own && i < n; i++) free(own[i]);
    free(own);
    free(pc);
    return rc;
}

static int iso_finish(engine *e, void *job, int rc)
{
    iso_job *ij = job;
    engine_result *r = ij->r;
    sched_job_totals(e, r);
    r->octants = 0;
    r->tiles = (uint32_t)block(e)->n_tasks;
    double t = clock_now();
    if (!rc) rc = gather_and_merge(e, ij);
    r->seconds = clock_now() - e->t0;
    ij->out->t_setup = ij->t_setup - e->t0;
    ij->out->t_tasks = t - ij->t_setup;
    ij->out->t_weld = clock_now() - t;
    return rc ? sched_job_failed(e, r, rc) : 0;
}

const master_kind kind_iso = {
    .name = "iso",
    .id = SHM_KIND_ISO,
    .setup = iso_setup,
    .take = iso_take,
    .done = iso_done,
    .rerun = iso_rerun,
    .describe = iso_describe,
    .progress = iso_progress,
    .finish = iso_finish,
};

int engine_iso(engine *e, const engine_iso_job *job, iso_mesh *out, engine_result *r)
{
    double c0 = clock_thread_cpu();
    memset(r, 0, sizeof *r);
    memset(out, 0, sizeof *out);
    iso_job ij = {.job = job, .out = out, .r = r};
    sched_watch w = {.progress = job->progress, .ud = job->ud, .cancel = job->cancel};
    int rc = engine_run(e, &kind_iso, &ij, &w);
    r->master_cpu = clock_thread_cpu() - c0;
    return rc;
}
