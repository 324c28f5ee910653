/* The iso kind's master side: marching cubes over a VOD file's bricks by
 * every worker, in two phases.  Setup copies the raw bricks of the levels
 * the job reads into the data area behind the block (each shared brick
 * once), then the tasks (iso_tasks, in key order) and their result
 * records, and gives the rest of the data area to the arena; one ISO_BRICKS
 * task per worker starts phase 1, each worker claiming brick tasks from
 * the block's counter until none is left and packing each piece into the
 * arena.  When the last of them is done, the master runs every task whose
 * piece is not there (its worker died, failed, or the arena was full),
 * checks every piece and gives each its place in the mesh (iso_weld_bases),
 * lays the mesh's arrays out in the arena, and one ISO_WELD task per worker
 * starts phase 2: the workers weld pieces into those arrays (a caller that
 * asked is told the layout then, and may write the mesh while it is welded:
 * engine_iso_wait says which pieces are in).  At the end
 * the master welds what no worker did and checks every index: the mesh is
 * the serial run's, byte for byte, whoever ran which task, and stays in
 * the segment (a view) until the next job. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "clock.h"
#include "kind_iso.h"
#include "master.h"
#include "par.h"

typedef struct {
    const engine_iso_job *job;
    iso_mesh *out;
    engine_result *r;
    uint64_t at;           /* the data area's next free byte (setup) */
    int no_room;           /* shm_alloc refused: the data area is full */
    int bricks_left;       /* ISO_BRICKS tasks not done yet */
    int weld_ready;        /* prepare_weld ran */
    iso_piece *pc;         /* every piece's view, for the weld */
    iso_work *work;        /* the tasks run here */
    double t_setup, t_tasks_end; /* when setup and the tasks were done */
} iso_job;

/* iso_input_make's allocator: the data area, from ij->at on. */
static void *shm_alloc(void *ud, size_t bytes)
{
    engine *e = ud;
    iso_job *ij = e->job;
    uint64_t end = e->h->data_off + e->h->data_bytes, at = engine_sched_align64(ij->at);
    if (at > end || bytes > end - at) {
        ij->no_room = 1;
        return NULL;
    }
    ij->at = at + bytes;
    return shm_at(e->seg.base, at);
}

static int lay_out_tasks(engine *e, iso_block *b, const iso_input *in)
{
    iso_task *t;
    uint64_t n;
    if (iso_tasks(&b->p, in, &t, &n))
        return engine_sched_fail(e, ENGINE_FAULT, -ENOMEM, "out of memory for the tasks");
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
    return res ? 0 : engine_sched_no_room(e, "the tasks");
}

/* One task of op per live worker: each runs tasks (or welds pieces)
 * until none is left.  How many were pushed. */
static int push_all(engine *e, uint32_t op)
{
    shm_task t = {.kind = SHM_KIND_ISO, .op = op};
    int pushed = 0;
    for (int i = 0; i < e->n; i++)
        if (e->ms[i].pid > 0 && !engine_sched_push(e, &t)) pushed++;
    return pushed;
}

static int iso_setup(engine *e, void *job)
{
    iso_job *ij = job;
    e->result = RESULT_NONE;
    engine_sched_hold(e, 0);
    iso_block *b = shm_at(e->seg.base, e->h->data_off);
    memset(b, 0, sizeof *b);
    b->p = *ij->job->p;
    e->h->job_off = e->h->data_off;
    e->h->job_bytes = sizeof *b;
    ij->at = e->h->data_off + sizeof *b;
    iso_input in;
    /* the copy, the first touch of these pages, on every CPU the master
     * may run on: the workers wait for it */
    int rc = iso_input_make_threads(ij->job->file, &b->p, shm_alloc, e, par_cpus(), &in);
    if (rc && ij->no_room) return engine_sched_no_room(e, "the file's bricks");
    if (rc) return engine_sched_fail(e, ENGINE_FAULT, rc, "copying the file's bricks: %s",
                                     strerror(-rc));
    b->n_bricks = in.n;
    b->keys_off = (uint64_t)((const uint8_t *)in.keys - e->seg.base);
    b->offs_off = (uint64_t)((const uint8_t *)in.offs - e->seg.base);
    b->raw_off = (uint64_t)(in.raw - e->seg.base);
    b->raw_bytes = in.raw_bytes;
    if ((rc = lay_out_tasks(e, b, &in))) return rc;
    uint64_t end = e->h->data_off + e->h->data_bytes;
    b->arena_off = engine_sched_align64(ij->at);
    b->arena_cap = b->arena_off < end ? end - b->arena_off : 0;
    /* relaxed: published to the workers by the task_seq release */
    atomic_store_explicit(&b->next, 0, memory_order_relaxed);
    atomic_store_explicit(&b->bump, 0, memory_order_relaxed);
    ij->t_setup = clock_now();
    ij->bricks_left = push_all(e, ISO_BRICKS);
    return e->err.kind ? e->err.code : 0;
}

static int iso_take(engine *e, int i, const shm_entry *en)
{
    return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                      "worker %d sent an entry of type %u in marching cubes", i, en->type);
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
    iso_block *b = engine_sched_block(e);
    /* relaxed: an estimate, nothing is read through it */
    uint64_t next = atomic_load_explicit(&b->next, memory_order_relaxed);
    uint64_t weld = atomic_load_explicit(&b->weld_next, memory_order_relaxed);
    double n = b->n_tasks ? (double)b->n_tasks : 1;
    p->fraction = 0.8 * (double)(next < b->n_tasks ? next : b->n_tasks) / n +
                  0.2 * (double)(weld < b->n_tasks ? weld : b->n_tasks) / n;
    p->level = (int)b->p.level;
    p->shm_used = engine_sched_align64(b->arena_off) - e->h->data_off +
                  atomic_load_explicit(&b->bump, memory_order_relaxed);
}

/* n bytes of the arena past the pieces (the workers are idle: nothing
 * else takes from it now), or NULL when it is full. */
static void *arena_alloc(engine *e, uint64_t n)
{
    iso_block *b = engine_sched_block(e);
    /* relaxed: the workers are idle; the counter only hands out ranges */
    uint64_t at = atomic_fetch_add_explicit(&b->bump, (n + 63) & ~63ull, memory_order_relaxed);
    if (at > b->arena_cap || n > b->arena_cap - at) return NULL;
    return shm_at(e->seg.base, b->arena_off + at);
}

/* Task i run here (its worker died or failed, or its piece did not fit),
 * its piece packed into the arena for the weld. */
static int run_here(engine *e, iso_job *ij, uint64_t i)
{
    iso_block *b = engine_sched_block(e);
    iso_result *r = (iso_result *)shm_at(e->seg.base, b->results_off) + i;
    const iso_task *t = (const iso_task *)shm_at(e->seg.base, b->tasks_off) + i;
    iso_input in = {.n = b->n_bricks, .keys = shm_at(e->seg.base, b->keys_off),
                    .offs = shm_at(e->seg.base, b->offs_off),
                    .raw = shm_at(e->seg.base, b->raw_off), .raw_bytes = b->raw_bytes};
    iso_piece v;
    int rc = ij->work ? 0 : iso_work_new(&b->p, &ij->work);
    if (!rc) rc = iso_task_run(ij->work, &b->p, &in, t, &v);
    if (rc)
        return engine_sched_fail(e, ENGINE_FAULT, rc, "task %llu: %s", (unsigned long long)i,
                                 strerror(-rc));
    uint8_t *to = arena_alloc(e, iso_piece_bytes(&b->p, &v));
    if (!to) return engine_sched_no_room(e, "the mesh");
    iso_piece_pack(&b->p, &v, to);
    r->off = (uint64_t)(to - (uint8_t *)shm_at(e->seg.base, b->arena_off));
    r->nv = v.nv, r->nc = v.nc, r->nt = v.nt, r->ne = v.ne;
    /* release: the ISO_WELD tasks' task_seq release publishes it anyway */
    atomic_store_explicit(&r->done, 1, memory_order_release);
    return 0;
}

/* Task i's piece as the workers will see it: 0, or -1 when it is not
 * there (not done, or its record does not hold). */
static int view_of(engine *e, uint64_t i, iso_piece *pc)
{
    iso_block *b = engine_sched_block(e);
    iso_result *r = (iso_result *)shm_at(e->seg.base, b->results_off) + i;
    uint64_t key = iso_task_key(&b->p, (const iso_task *)shm_at(e->seg.base, b->tasks_off) + i);
    /* acquire: pairs with the worker's release store of done */
    int done = atomic_load_explicit(&r->done, memory_order_acquire);
    *pc = (iso_piece){.key = key, .nv = r->nv, .nc = r->nc, .nt = r->nt, .ne = r->ne};
    return done && r->off < b->arena_cap &&
                   !iso_piece_view(&b->p, shm_at(e->seg.base, b->arena_off + r->off),
                                   b->arena_cap - r->off, pc)
               ? 0
               : -1;
}

/* Task i's piece, run here first when it is not there. */
static int piece_of(engine *e, iso_job *ij, uint64_t i, iso_piece *pc)
{
    int rc = run_here(e, ij, i);
    if (rc) return rc;
    if (!view_of(e, i, pc)) return 0;
    return engine_sched_fail(e, ENGINE_FAULT, -EPROTO, "a piece of the mesh went missing");
}

/* Every piece's view, in parts on every CPU the master may run on (the
 * first read of the workers' pieces here, page by page): miss[i] set for
 * those not there. */
typedef struct {
    engine *e;
    iso_piece *pc;
    uint8_t *miss;
    uint64_t n;
} view_ctx;

static void view_part(void *ud, unsigned k, unsigned parts)
{
    view_ctx *c = ud;
    for (uint64_t i = c->n * k / parts; i < c->n * (k + 1) / parts; i++)
        c->miss[i] = view_of(c->e, i, &c->pc[i]) != 0;
}

static int views(engine *e, iso_job *ij, uint64_t n)
{
    view_ctx c = {e, ij->pc, calloc(n + 1, 1), n};
    if (!c.miss) return engine_sched_fail(e, ENGINE_FAULT, -ENOMEM, "out of memory");
    unsigned parts = par_cpus();
    if (parts > n / 256 + 1) parts = (unsigned)(n / 256 + 1);
    par_run(parts, view_part, &c);
    int rc = 0;
    for (uint64_t i = 0; i < n && !rc; i++) /* in task order, as before */
        if (c.miss[i]) rc = piece_of(e, ij, i, &ij->pc[i]);
    free(c.miss);
    return rc;
}

/* Between the phases: every piece there and checked, the bases and the
 * mesh's arrays laid out in the arena. */
static int prepare_weld(engine *e, iso_job *ij)
{
    iso_block *b = engine_sched_block(e);
    uint64_t n = b->n_tasks;
    ij->t_tasks_end = clock_now();
    ij->weld_ready = 1;
    if (!(ij->pc = calloc(n + 1, sizeof *ij->pc)))
        return engine_sched_fail(e, ENGINE_FAULT, -ENOMEM, "out of memory");
    int rc = views(e, ij, n);
    uint64_t *vb = rc ? NULL : arena_alloc(e, 8 * (n + 1));
    uint64_t *tb = vb ? arena_alloc(e, 8 * (n + 1)) : NULL;
    if (rc) return rc;
    if (!tb) return engine_sched_no_room(e, "the mesh");
    iso_weld wb = {.p = &b->p, .pc = ij->pc, .n = n, .vbase = vb, .tbase = tb};
    err_info why = {0};
    if ((rc = iso_weld_bases(&wb, par_cpus(), &why)))
        return engine_sched_fail(e, rc == -E2BIG ? ENGINE_LIMIT : ENGINE_FAULT, rc, "%s", why.msg);
    void *pos = arena_alloc(e, 12 * vb[n]), *tri = pos ? arena_alloc(e, 12 * tb[n]) : NULL;
    void *nrm = tri && b->p.normals ? arena_alloc(e, 12 * vb[n]) : NULL;
    if (!tri || (b->p.normals && !nrm)) return engine_sched_no_room(e, "the mesh");
    b->vbase_off = (uint64_t)((uint8_t *)vb - e->seg.base);
    b->tbase_off = (uint64_t)((uint8_t *)tb - e->seg.base);
    b->pos_off = (uint64_t)((uint8_t *)pos - e->seg.base);
    b->tri_off = (uint64_t)((uint8_t *)tri - e->seg.base);
    b->nrm_off = nrm ? (uint64_t)((uint8_t *)nrm - e->seg.base) : 0;
    /* relaxed: published by the ISO_WELD tasks' task_seq release */
    atomic_store_explicit(&b->weld_next, 0, memory_order_relaxed);
    return 0;
}

/* The mesh's layout told to the caller that asked (engine_iso_job's
 * laid_out), before the weld. */
static void announce(engine *e, const iso_job *ij)
{
    const engine_iso_job *j = ij->job;
    if (!j->laid_out || !j->weld) return;
    iso_block *b = engine_sched_block(e);
    uint64_t n = b->n_tasks, *vb = shm_at(e->seg.base, b->vbase_off);
    uint64_t *tb = shm_at(e->seg.base, b->tbase_off);
    engine_iso_weld *w = j->weld;
    w->results = shm_at(e->seg.base, b->results_off);
    w->vbase = vb, w->tbase = tb, w->n = n;
    atomic_init(&w->known, 0);
    atomic_init(&w->stop, 0);
    iso_mesh m = {.n_vertices = vb[n], .n_triangles = tb[n],
                  .pos = shm_at(e->seg.base, b->pos_off),
                  .nrm = b->nrm_off ? shm_at(e->seg.base, b->nrm_off) : NULL,
                  .tri = shm_at(e->seg.base, b->tri_off), .borrowed = 1};
    j->laid_out(j->ud, &m);
}

/* The last ISO_BRICKS task done starts the weld. */
static void iso_done(engine *e, int i, const shm_task *t, int error)
{
    iso_job *ij = e->job;
    (void)i, (void)error;
    if (t->op != ISO_BRICKS || --ij->bricks_left > 0 || e->err.kind) return;
    if (prepare_weld(e, ij)) return;
    push_all(e, ISO_WELD);
    announce(e, ij);
}

/* Every index the workers wrote checked against the vertex count, in
 * parts on every CPU the master may run on. */
typedef struct {
    const uint32_t *tri;
    uint64_t n, nv;          /* indices, vertices */
    int bad[PAR_MAX];
} index_check;

static void check_indices(void *ud, unsigned k, unsigned parts)
{
    index_check *c = ud;
    uint64_t lo = c->n * k / parts, hi = c->n * (k + 1) / parts;
    uint32_t most = 0;
    for (uint64_t i = lo; i < hi; i++) most = c->tri[i] > most ? c->tri[i] : most;
    c->bad[k] = lo < hi && most >= c->nv;
}

static int indices_ok(const uint32_t *tri, uint64_t n, uint64_t nv)
{
    index_check c = {tri, n, nv, {0}};
    unsigned parts = par_cpus();
    if (parts > n / 65536 + 1) parts = (unsigned)(n / 65536 + 1);
    par_run(parts, check_indices, &c);
    for (unsigned k = 0; k < parts; k++)
        if (c.bad[k]) return 0;
    return 1;
}

/* The pieces no worker welded, welded here; then every index checked
 * (the workers wrote them) and the mesh handed out as a view of the
 * segment, kept until the next job. */
static int weld_rest(engine *e, iso_job *ij)
{
    iso_block *b = engine_sched_block(e);
    uint64_t n = b->n_tasks;
    uint64_t *vb = shm_at(e->seg.base, b->vbase_off), *tb = shm_at(e->seg.base, b->tbase_off);
    iso_weld wd = {&b->p, ij->pc, n, vb, tb, shm_at(e->seg.base, b->pos_off),
                   b->nrm_off ? shm_at(e->seg.base, b->nrm_off) : NULL,
                   shm_at(e->seg.base, b->tri_off)};
    iso_result *res = shm_at(e->seg.base, b->results_off);
    err_info why = {0};
    for (uint64_t i = 0; i < n; i++) {
        /* acquire: pairs with the worker's release store of welded */
        if (atomic_load_explicit(&res[i].welded, memory_order_acquire)) continue;
        int rc = iso_weld_piece(&wd, i, &why);
        if (rc)
            return engine_sched_fail(e, ENGINE_FAULT, rc, "%s", why.msg[0] ? why.msg : strerror(-rc));
        /* release: pairs with engine_iso_wait's acquire (a writer streaming
         * the mesh) */
        atomic_store_explicit(&res[i].welded, 1, memory_order_release);
    }
    if (!indices_ok(wd.tri, 3 * tb[n], vb[n]))
        return engine_sched_fail(e, ENGINE_FAULT, -EPROTO, "the workers left the mesh inconsistent");
    *ij->out = (iso_mesh){.n_vertices = vb[n], .n_triangles = tb[n], .pos = wd.pos,
                          .nrm = wd.nrm, .tri = wd.tri, .borrowed = 1};
    /* the mesh stays until the next job */
    engine_sched_hold(e, b->arena_off - e->h->data_off +
                      atomic_load_explicit(&b->bump, memory_order_relaxed));
    return 0;
}

static int iso_finish(engine *e, void *job, int rc)
{
    iso_job *ij = job;
    engine_result *r = ij->r;
    engine_sched_job_totals(e, r);
    r->octants = 0;
    const iso_block *b = engine_sched_block(e);
    r->tasks = (uint32_t)b->n_tasks;
    if (!rc && !ij->weld_ready && !(rc = prepare_weld(e, ij))) /* no worker took a task */
        announce(e, ij);
    if (!rc) rc = weld_rest(e, ij);
    r->seconds = clock_now() - e->t0;
    if (!rc) {
        ij->out->t_setup = ij->t_setup - e->t0;
        ij->out->t_tasks = ij->t_tasks_end - ij->t_setup;
        ij->out->t_weld = clock_now() - ij->t_tasks_end;
    }
    iso_work_free(ij->work);
    free(ij->pc);
    return rc ? engine_sched_job_failed(e, r, rc) : 0;
}

static const engine_kind engine_kind_iso = {
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
    memset(out, 0, sizeof *out);
    iso_job ij = {.job = job, .out = out, .r = r};
    engine_sched_watch w = {.progress = job->progress, .ud = job->ud, .cancel = job->cancel};
    return engine_sched_run_job(e, &engine_kind_iso, &ij, &w, r);
}

int engine_iso_wait(engine_iso_weld *w, int tris, uint64_t hi)
{
    const uint64_t *base = tris ? w->tbase : w->vbase;
    const iso_result *res = w->results;
    /* acquire: pairs with the release below, so that the pieces another
     * wait saw welded are seen whole here too */
    uint64_t i = atomic_load_explicit(&w->known, memory_order_acquire), known = i;
    for (; i < w->n && base[i] < hi; i++)
        /* acquire: pairs with the welder's release store of welded */
        while (!atomic_load_explicit(&res[i].welded, memory_order_acquire)) {
            /* relaxed: a flag; the caller sets it once the job failed */
            if (atomic_load_explicit(&w->stop, memory_order_relaxed)) return -ECANCELED;
            nanosleep(&(struct timespec){.tv_nsec = 500000}, NULL);
        }
    /* release: pairs with the acquire above */
    while (i > known && !atomic_compare_exchange_weak_explicit(
                            &w->known, &known, i, memory_order_release, memory_order_acquire)) {
    }
    return 0;
}
