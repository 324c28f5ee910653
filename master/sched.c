/* The scheduler: Figure 3's master loop over the shared-memory slots, the
 * same for every kind of job.  The kind (master.h) says what a task's
 * entries mean; this file moves tasks and entries, sleeps, and replaces
 * workers that die. */
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/wait.h>

#include "clock.h"
#include "master.h"

#define MASTER_SLEEP_NS 20000000L /* 20 ms: cancel and progress stay live */
#define PROGRESS_EVERY 0.1        /* seconds between progress callbacks */
#define LIVENESS_EVERY 0.05       /* seconds between checks for dead workers */
#define TASK_DEATHS 2             /* deaths on one task that fail the job */

const char *engine_failure_name(engine_failure f)
{
    static const char *const names[] = {
        [ENGINE_OK] = "ok",          [ENGINE_CANCELLED] = "cancelled",
        [ENGINE_BAD_JOB] = "bad job", [ENGINE_LIMIT] = "over a limit",
        [ENGINE_CRASHED] = "crashed", [ENGINE_SINK] = "output failed",
        [ENGINE_FAULT] = "engine fault",
    };
    return (unsigned)f < sizeof names / sizeof names[0] ? names[f] : "?";
}

int sched_fail(engine *e, engine_failure f, int rc, const char *fmt, ...)
{
    if (e->err.failure) return e->err.code; /* the first is the one told */
    e->err.failure = f;
    e->err.code = rc;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(e->err.message, sizeof e->err.message, fmt, ap);
    va_end(ap);
    return rc;
}

engine_failure engine_vod_failure(int rc, int said)
{
    if (!said) return ENGINE_SINK;
    return rc == -EFBIG ? ENGINE_LIMIT : rc == -EINVAL ? ENGINE_BAD_JOB : ENGINE_FAULT;
}

int sched_push(engine *e, const shm_task *t)
{
    if (e->sp == e->cap)
        return sched_fail(e, ENGINE_LIMIT, -ENOMEM,
                          "the work stack overflowed (%u tasks)", e->cap);
    e->stack[e->sp++] = *t;
    return 0;
}

void sched_touched(engine *e, uint64_t end)
{
    if (end > e->touched) e->touched = end;
}

/* Hand task t to worker i, the entries before skip already taken. */
static void give(engine *e, int i, const shm_task *t, uint32_t skip)
{
    mslot *m = &e->ms[i];
    m->busy = 1;
    m->task = *t;
    m->consumed = skip;
    m->deaths = 0;
    e->nbusy++;
    pool_give(e, i, t, skip);
}

/* Worker i's task is over: finished and drained, or dropped. */
static void finish(engine *e, int i)
{
    mslot *m = &e->ms[i];
    m->busy = 0;
    e->nbusy--;
    e->kind->done(e, i, &m->task, pool_slot(e, i)->error);
}

static int take(engine *e, int i, const shm_entry *en)
{
    uint32_t kind = en->kind; /* read once: the worker's memory */
    if (kind != e->ms[i].task.kind)
        return sched_fail(e, ENGINE_FAULT, -EPROTO,
                          "worker %d sent an entry of kind %u in a task of "
                          "kind %u", i, kind, e->ms[i].task.kind);
    return e->kind->take(e, i, en);
}

/* Take every entry worker i published (or throw them away); returns how
 * much happened. */
static int drain(engine *e, int i, int discard)
{
    shm_slot *s = pool_slot(e, i);
    mslot *m = &e->ms[i];
    /* acquire: pairs with the worker's release of done_seq, so the prod
     * read next covers every entry of the finished task. */
    int done = atomic_load_explicit(&s->done_seq, memory_order_acquire) ==
               m->seq;
    unsigned n = queue_ready(&s->q), tail = queue_tail(&s->q);
    if (n > QUEUE_ENTRIES) {
        sched_fail(e, ENGINE_FAULT, -EPROTO,
                   "worker %d: its queue claims %u entries", i, n);
        discard = 1;
    }
    for (unsigned k = 0; k < n && !discard && !e->err.failure; k++)
        take(e, i, &s->ent[(tail + k) % QUEUE_ENTRIES]);
    if (n) {
        queue_consumed(&s->q, n);
        m->consumed += n;
        shm_wake_if_sleeping(&s->wake, &s->sleeping);
    }
    if (done) finish(e, i);
    return (int)n + done;
}

static int assign(engine *e)
{
    int did = 0;
    for (int i = 0; i < e->n && e->sp; i++) {
        if (e->ms[i].busy || e->ms[i].pid <= 0) continue;
        give(e, i, &e->stack[--e->sp], 0);
        did++;
    }
    return did;
}

static int anything_ready(engine *e)
{
    for (int i = 0; i < e->n; i++) {
        if (!e->ms[i].busy) continue;
        shm_slot *s = pool_slot(e, i);
        /* acquire: as in drain() */
        if (queue_ready(&s->q) ||
            atomic_load_explicit(&s->done_seq, memory_order_acquire) ==
                e->ms[i].seq)
            return 1;
    }
    return 0;
}

static void sleep_master(engine *e)
{
    shm_header *h = e->h;
    unsigned v = shm_sleep_begin(&h->doorbell, &h->master_sleeping);
    if (!anything_ready(e)) shm_futex_wait(&h->doorbell, v, MASTER_SLEEP_NS);
    shm_sleep_end(&h->master_sleeping);
}

/* Worker i is gone: keep what it published, then fork a new one that runs
 * its task again (when its kind wants it), skipping the entries taken. */
static void handle_death(engine *e, int i)
{
    mslot *m = &e->ms[i];
    shm_slot *s = pool_slot(e, i);
    m->pid = 0;
    e->restarts++;
    if (m->busy) drain(e, i, e->aborting);
    int rerun = m->busy && !e->aborting && e->kind->rerun(e, i, &m->task);
    /* The first death may be anybody's doing (a kill, the OOM killer): the
     * task is handed out again.  A second one on the same task says the
     * task kills its workers: the job fails. */
    if (rerun && ++m->deaths >= TASK_DEATHS) {
        char what[128];
        e->kind->describe(&m->task, what, sizeof what);
        sched_fail(e, ENGINE_CRASHED, -EIO,
                   "%s killed its worker twice (worker %d)", what, i);
        rerun = 0;
    }
    if (m->busy && !rerun) finish(e, i);
    /* No worker owns the slot now: its fields are the master's to reset,
     * and the fork orders these plain stores before the child's loads. */
    queue_reset(&s->q, atomic_load_explicit(&s->q.cons, memory_order_relaxed));
    atomic_store_explicit(&s->sleeping, 0, memory_order_relaxed);
    s->error = 0;
    s->task_skip = m->consumed;
    if (!rerun) atomic_store_explicit(&s->done_seq, m->seq, memory_order_relaxed);
    char err[200];
    int rc = pool_spawn(e, i, err, sizeof err);
    if (rc) {
        sched_fail(e, ENGINE_FAULT, rc, "%s", err);
        if (m->busy) finish(e, i);
    }
}

static void check_workers(engine *e, int force)
{
    double now = clock_now();
    if (!force && now - e->last_check < LIVENESS_EVERY) return;
    e->last_check = now;
    for (int i = 0; i < e->n; i++) {
        pid_t pid = e->ms[i].pid;
        if (pid <= 0) {
            if (force && !e->ms[i].busy) handle_death(e, i);
            continue;
        }
        pid_t r = waitpid(pid, NULL, WNOHANG);
        if (r == pid || (r < 0 && errno == ECHILD)) handle_death(e, i);
    }
}

int engine_check_workers(engine *e)
{
    if (e->kind) return -EBUSY; /* a job checks its own workers */
    uint32_t restarts = e->restarts;
    memset(&e->err, 0, sizeof e->err);
    check_workers(e, 1);
    int rc = e->err.failure ? e->err.code : (int)(e->restarts - restarts);
    /* Between jobs nothing else reads these: the next job starts afresh. */
    memset(&e->err, 0, sizeof e->err);
    e->restarts = restarts;
    return rc;
}

static void progress(engine *e, int force)
{
    if (!e->watch.progress || !e->kind->progress) return;
    double now = clock_now();
    if (!force && now - e->last_progress < PROGRESS_EVERY) return;
    e->last_progress = now;
    engine_progress p = {.seconds = now - e->t0};
    e->kind->progress(e, &p);
    e->watch.progress(e->watch.ud, &p);
}

static int cancelled(const engine *e)
{
    /* relaxed: see sched_watch.cancel */
    return e->watch.cancel &&
           atomic_load_explicit(e->watch.cancel, memory_order_relaxed);
}

/* Figure 3's master loop. */
static int run_loop(engine *e)
{
    for (;;) {
        int did = 0;
        for (int i = 0; i < e->n; i++)
            if (e->ms[i].busy) did += drain(e, i, 0);
        if (!e->err.failure) did += assign(e);
        if (e->err.failure) return e->err.code;
        if (e->nbusy == 0 && e->sp == 0) return 0;
        if (cancelled(e))
            return sched_fail(e, ENGINE_CANCELLED, -ECANCELED,
                              "the job was cancelled");
        progress(e, 0);
        if (!did) sleep_master(e);
        check_workers(e, 0);
    }
}

/* Tell the workers to drop the job and wait until all are idle. */
static void abort_job(engine *e)
{
    e->aborting = 1;
    /* relaxed: workers poll it; the fence in shm_wake_if_sleeping() pairs
     * with the one of a worker going to sleep. */
    atomic_store_explicit(&e->h->abort_gen, e->h->gen, memory_order_relaxed);
    for (int i = 0; i < e->n; i++)
        if (e->ms[i].busy)
            shm_wake_if_sleeping(&pool_slot(e, i)->wake,
                                 &pool_slot(e, i)->sleeping);
    while (e->nbusy) {
        int did = 0;
        for (int i = 0; i < e->n; i++)
            if (e->ms[i].busy) did += drain(e, i, 1);
        if (!did) sleep_master(e);
        check_workers(e, 0);
    }
    e->sp = 0;
    e->aborting = 0;
}

static void job_reset(engine *e, const master_kind *k, void *job,
                      const sched_watch *watch)
{
    e->kind = k;
    e->job = job;
    e->watch = watch ? *watch : (sched_watch){0};
    memset(&e->err, 0, sizeof e->err);
    e->restarts = 0;
    e->sp = 0;
    e->t0 = clock_now();
    e->last_progress = e->t0 - 1.0; /* the first call comes at once */
    /* A new generation: workers begin the job afresh (their kernels' state,
     * their counters), and an abort names this job only. */
    e->h->gen = e->h->gen + 1 ? e->h->gen + 1 : 1;
    e->h->job_kind = k->id;
}

int engine_run(engine *e, const master_kind *k, void *job,
               const sched_watch *watch)
{
    job_reset(e, k, job, watch);
    check_workers(e, 1); /* any that died since the last job */
    int rc = e->err.failure ? e->err.code : k->setup(e, job);
    if (!rc) rc = run_loop(e);
    if (e->nbusy) abort_job(e);
    if (!rc) progress(e, 1);
    rc = k->finish(e, job, rc);
    e->kind = NULL; /* the caller's job; nothing may use it after this */
    e->job = NULL;
    return rc;
}
