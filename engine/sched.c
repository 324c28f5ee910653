/* The scheduler: Figure 3's master loop over the shared-memory slots, the
 * same for every kind of job.  The kind (master.h) says what a task's
 * entries mean; this file moves tasks and entries, sleeps, replaces
 * workers that die or stall, stops a job whose estimated memory passes the
 * segment, and gives the job's pages back when it ends. */
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/wait.h>
#include <unistd.h>

#include "clock.h"
#include "master.h"

#define MASTER_SLEEP_NS 20000000L /* 20 ms: cancel and progress stay live */
#define PROGRESS_EVERY 0.1        /* seconds between progress callbacks */
#define LIVENESS_EVERY 0.05       /* seconds between checks for dead workers */
#define TASK_DEATHS 2             /* deaths on one task that fail the job */
#define LOOKED_AWAY_S 1.0         /* a gap between checks this long (a long
                                     setup, a starved master) restarts every
                                     worker's quiet time */
/* An abandoned job's busy workers: one whose process is stopped is killed
 * once it has been quiet ABORT_STOPPED_S, one without a heartbeat for
 * ABORT_QUIET_S, any after ABORT_WAIT_S.  A live worker lets go at its next
 * heartbeat (the kernels check the abort where they tick), so the last two
 * are generous: a worker under valgrind ticks seconds apart. */
#define ABORT_STOPPED_S 0.1
#define ABORT_QUIET_S 1.0
#define ABORT_WAIT_S 5.0

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

int engine_sched_fail(engine *e, engine_failure f, int rc, const char *fmt, ...)
{
    if (e->err.kind) return e->err.code; /* the first is the one told */
    e->err.kind = f;
    va_list ap;
    va_start(ap, fmt);
    err_vset(&e->err, rc, fmt, ap);
    va_end(ap);
    /* every limit of the segment says "shared memory": name the way to
     * raise it, the caller's (--shm-size, voxd.conf's shm_size) */
    size_t n = strlen(e->err.msg);
    if (f == ENGINE_LIMIT && e->shm_option && strstr(e->err.msg, "shared memory"))
        snprintf(e->err.msg + n, sizeof e->err.msg - n, " (%s)", e->shm_option);
    return rc;
}

int engine_sched_no_room(engine *e, const char *what)
{
    return engine_sched_fail(e, ENGINE_LIMIT, -ENOMEM,
                      "%s does not fit in shared memory (%zu MiB); raise its size",
                      what, e->seg.bytes >> 20);
}

bool engine_volume_full(const engine *e)
{
    if (!e->volume) return false;
    vod_volume_info in;
    vod_volume_get_info(e->volume, &in);
    return in.pool_full != 0;
}

int engine_sched_run_job(engine *e, const engine_kind *k, void *job, const engine_sched_watch *watch,
                  engine_result *r)
{
    double c0 = clock_thread_cpu();
    memset(r, 0, sizeof *r);
    e->volume = NULL; /* a volume kind's progress reads it once its setup made it */
    int rc = engine_run(e, k, job, watch);
    r->master_cpu = clock_thread_cpu() - c0;
    return rc;
}

engine_failure engine_vod_failure(int rc, int said)
{
    if (!said) return ENGINE_SINK;
    return rc == -EFBIG ? ENGINE_LIMIT : rc == -EINVAL ? ENGINE_BAD_JOB : ENGINE_FAULT;
}

int engine_sched_push(engine *e, const shm_task *t)
{
    if (e->sp == e->cap)
        return engine_sched_fail(e, ENGINE_LIMIT, -ENOMEM,
                          "the work stack overflowed (%u tasks)", e->cap);
    e->stack[e->sp++] = *t;
    return 0;
}

void engine_sched_hold(engine *e, uint64_t bytes)
{
    e->hold = bytes;
}

/* The segment's pages from `from` (page-aligned) to its end back to tmpfs,
 * which frees them for every process that maps them; the range's
 * untouched pages cost nothing (2 GiB of them: 0.2 ms). */
static void give_back(engine *e, uint64_t from)
{
    madvise(e->seg.base + from, e->seg.bytes - from, MADV_REMOVE);
}

void engine_sched_release(engine *e)
{
    uint64_t page = (uint64_t)sysconf(_SC_PAGESIZE);
    uint64_t keep = e->keep > e->hold ? e->keep : e->hold;
    uint64_t from = (e->h->data_off + keep + page - 1) / page * page;
    if (from >= e->seg.bytes) return;
    /* Lazy: nothing reads or writes past `from` until the next job, whose
     * start gives the pages back first (engine_tidy), so the next job sees
     * what it would have seen; the caller answers before paying for it. */
    if (e->lazy) {
        if (!e->due || from < e->due) e->due = from;
        return;
    }
    give_back(e, from);
}

void engine_lazy_release(engine *e) { e->lazy = 1; }

void engine_tidy(engine *e)
{
    if (e->kind || !e->due) return;
    uint64_t from = e->due;
    e->due = 0;
    give_back(e, from);
}

void engine_sched_job_totals(engine *e, engine_result *r)
{
    uint64_t tested = 0, cpu = 0;
    for (int i = 0; i < e->n; i++) {
        shm_slot *s = engine_pool_slot(e, i);
        if (s->job_gen != e->h->gen) continue;
        tested += s->job_tested;
        cpu += s->job_cpu_ns;
    }
    r->octants = tested;
    r->worker_cpu = (double)cpu * 1e-9;
    r->restarts = e->restarts;
    r->stalls = e->stalls;
    r->offered = e->offered;
}

int engine_sched_job_failed(engine *e, engine_result *r, int rc)
{
    r->err = e->err;
    return rc;
}

void engine_release(engine *e)
{
    if (e->kind) return; /* inside a job: its finish holds what it needs */
    e->result = RESULT_NONE;
    e->hold = 0;
    engine_sched_release(e);
}


/* Hand task t to worker i, the entries before skip already taken. */
static void give(engine *e, int i, const shm_task *t, uint32_t skip)
{
    mslot *m = &e->ms[i];
    m->busy = 1;
    m->task = *t;
    m->consumed = skip;
    m->deaths = 0;
    m->task_stalls = 0;
    /* relaxed: see shm_slot.beat */
    m->beat = atomic_load_explicit(&engine_pool_slot(e, i)->beat, memory_order_relaxed);
    m->beat_t = clock_now();
    e->nbusy++;
    engine_pool_give(e, i, t, skip);
}

/* Worker i's offered task is its current one now (the one before is
 * finished and drained): the worker has taken it, or will. */
static void promote(engine *e, int i)
{
    mslot *m = &e->ms[i];
    m->busy = 1;
    m->task = m->next;
    m->cur = m->seq;
    m->offered = 0;
    m->consumed = 0;
    m->deaths = 0;
    m->task_stalls = 0;
    e->nbusy++;
    e->offered++;
}

/* Worker i's task is over: finished and drained, or dropped.  Its lane
 * is free from here: the next task given or offered writes in it. */
static void finish(engine *e, int i)
{
    mslot *m = &e->ms[i];
    m->busy = 0;
    e->nbusy--;
    e->kind->done(e, i, &m->task, engine_pool_slot(e, i)->error[m->cur & 1]);
    if (m->offered) promote(e, i);
}

static int take(engine *e, int i, const shm_entry *en)
{
    uint32_t kind = en->kind; /* read once: the worker's memory */
    if (kind != e->ms[i].task.kind)
        return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                          "worker %d sent an entry of kind %u in a task of "
                          "kind %u", i, kind, e->ms[i].task.kind);
    return e->kind->take(e, i, en);
}

/* Whether worker i has ended its current task: done_seq at cur, or past
 * it when the worker ended the offered task too. */
static int task_ended(engine *e, int i)
{
    /* acquire: pairs with the worker's release of done_seq, so the prod
     * read after it covers every entry of the ended task. */
    unsigned d = atomic_load_explicit(&engine_pool_slot(e, i)->done_seq, memory_order_acquire);
    return (int)(d - e->ms[i].cur) >= 0;
}

/* Take every entry worker i's current task published (or throw them
 * away); returns how much happened.  Its lane holds its entries only:
 * the worker may run on into the next task, which writes the other. */
static int drain(engine *e, int i, int discard)
{
    shm_slot *s = engine_pool_slot(e, i);
    mslot *m = &e->ms[i];
    shm_lane *l = &s->lane[m->cur & 1];
    int done = task_ended(e, i); /* before the prod read next */
    unsigned n = queue_ready(&l->q), tail = queue_tail(&l->q);
    if (n > QUEUE_ENTRIES) {
        engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                   "worker %d: its queue claims %u entries", i, n);
        discard = 1;
    }
    for (unsigned k = 0; k < n && !discard && !e->err.kind; k++)
        take(e, i, &l->ent[(tail + k) % QUEUE_ENTRIES]);
    if (n) {
        queue_consumed(&l->q, n);
        m->consumed += n;
        shm_wake_if_sleeping(&s->wake, &s->sleeping);
    }
    if (done) {
        m->ended++;
        finish(e, i);
    }
    return (int)n + done;
}

/* A task for an idle worker when the stack is empty: one offered to a
 * busy worker, taken back before it started it. */
static int take_back(engine *e, shm_task *t)
{
    for (int j = 0; j < e->n; j++) {
        if (!engine_pool_take_back(e, j)) continue;
        *t = e->ms[j].next;
        return 1;
    }
    return 0;
}

/* Whether busy worker i can be offered its next task: the kind's
 * prefetch, the stack holding more than one task a worker, none offered
 * yet, and the worker has copied its current task (run_seq): the offered
 * one is then the one after it, and the worker is done reading the offer
 * place.  The offered task's lane is the task before's, finished and
 * drained (else the current one would not be current). */
static int can_offer(engine *e, int i)
{
    mslot *m = &e->ms[i];
    if (!e->kind->prefetch || e->aborting || e->sp <= (uint32_t)e->n) return 0;
    if (!m->busy || m->offered || m->pid <= 0 || m->killed) return 0;
    /* acquire: pairs with the worker's release once it copied its task */
    return atomic_load_explicit(&engine_pool_slot(e, i)->run_seq, memory_order_acquire) == m->cur;
}

static int offer(engine *e)
{
    int did = 0;
    for (int i = 0; i < e->n; i++) {
        if (!can_offer(e, i)) continue;
        engine_pool_offer(e, i, &e->stack[--e->sp]);
        did++;
    }
    return did;
}

static int assign(engine *e)
{
    int did = 0;
    for (int i = 0; i < e->n; i++) {
        if (e->ms[i].busy || e->ms[i].pid <= 0) continue;
        shm_task t;
        if (e->sp) t = e->stack[--e->sp];
        else if (!take_back(e, &t)) break;
        if (e->sp < (uint32_t)e->n && e->kind->tail) e->kind->tail(e, &t);
        give(e, i, &t, 0);
        did++;
    }
    return did + offer(e);
}

static int anything_ready(engine *e)
{
    for (int i = 0; i < e->n; i++) {
        if (!e->ms[i].busy) continue;
        shm_slot *s = engine_pool_slot(e, i);
        if (queue_ready(&s->lane[e->ms[i].cur & 1].q) || task_ended(e, i) || can_offer(e, i))
            return 1;
    }
    return 0;
}

/* How long the master polls for results before it sleeps, when it has a
 * CPU of its own.  Each sleep costs a worker a futex wake (a system call,
 * and on a virtual machine the wake of an idle CPU) at its next ring: with
 * one worker on two cores the sphere at 512^3 rang about a thousand times
 * and its engine took 13% longer than the serial algorithm's.  A master
 * that is awake when the ring comes costs the worker a load of the
 * sleeping flag.  Without a spare CPU the master would poll on the
 * workers' time, so it sleeps at once. */
#define MASTER_POLL_S 200e-6

static void sleep_master(engine *e)
{
    shm_header *h = e->h;
    if (e->spare_cpu) {
        double until = clock_now() + MASTER_POLL_S;
        while (clock_now() < until)
            if (anything_ready(e)) return;
    }
    unsigned v = shm_sleep_begin(&h->doorbell, &h->master_sleeping);
    if (!anything_ready(e)) shm_futex_wait(&h->doorbell, v, MASTER_SLEEP_NS);
    shm_sleep_end(&h->master_sleeping);
}

/* Worker i is gone: keep what it published, then fork a new one that runs
 * its task again (when its kind wants it), skipping the entries taken. */
static void handle_death(engine *e, int i)
{
    mslot *m = &e->ms[i];
    shm_slot *s = engine_pool_slot(e, i);
    m->pid = 0;
    m->killed = 0;
    m->replaced++;
    e->restarts++;
    /* Its task, and the offered one when it had ended the first and begun
     * it (finish() made it current): the dead write nothing more. */
    while (m->busy && drain(e, i, e->aborting)) {}
    /* Offered still: the task before never ended, so this one never began
     * (the worker takes it only after its done_seq): back to the stack. */
    if (engine_pool_take_back(e, i)) engine_sched_push(e, &m->next);
    int rerun = m->busy && !e->aborting && e->kind->rerun(e, i, &m->task);
    /* The first death may be anybody's doing (a kill, the OOM killer, a
     * SIGSTOP that made it stall): the task is handed out again.  A second
     * one on the same task says the task kills (or hangs) its workers: the
     * job fails. */
    if (rerun && ++m->deaths >= TASK_DEATHS) {
        char what[128];
        e->kind->describe(&m->task, what, sizeof what);
        engine_sched_fail(e, ENGINE_CRASHED, -EIO, "%s %s its worker twice (worker %d)", what,
                   m->task_stalls ? "stalled or killed" : "killed", i);
        rerun = 0;
    }
    if (m->busy && !rerun) finish(e, i);
    /* No worker owns the slot now: its fields are the master's to reset,
     * and the fork orders these plain stores before the child's loads. */
    for (int k = 0; k < 2; k++) {
        queue_idx *q = &s->lane[k].q;
        queue_reset(q, atomic_load_explicit(&q->cons, memory_order_relaxed));
    }
    atomic_store_explicit(&s->sleeping, 0, memory_order_relaxed);
    atomic_store_explicit(&s->next, 0, memory_order_relaxed); /* one made current */
    memset(s->error, 0, sizeof s->error);
    /* the current task again as given (it may have been offered) */
    s->task = m->task;
    s->task_gen = e->h->gen;
    s->task_skip = m->consumed;
    atomic_store_explicit(&s->task_seq, m->cur, memory_order_relaxed);
    atomic_store_explicit(&s->done_seq, rerun ? m->cur - 1 : m->cur, memory_order_relaxed);
    /* not the current task's: no offer until the new worker copied it */
    atomic_store_explicit(&s->run_seq, m->cur - 1, memory_order_relaxed);
    err_info err = {0};
    int rc = engine_pool_spawn(e, i, &err);
    if (rc) {
        engine_sched_fail(e, ENGINE_FAULT, rc, "%s", err.msg);
        if (m->busy) finish(e, i);
    } else if (rerun) {
        /* The task's new worker is quiet from its fork, not from its
         * predecessor's last heartbeat: after a stall that one is a whole
         * stall timeout old, and the new worker would be killed at the next
         * check unless it ticked first (a loaded machine: the task failed) */
        m->beat_t = clock_now();
    }
}

/* Worker i's heartbeat: its quiet time starts again when it moved, when
 * its queue is full (it waits on us, not we on it) or when asked. */
static void watch_beat(engine *e, int i, double now, int reset)
{
    mslot *m = &e->ms[i];
    shm_slot *s = engine_pool_slot(e, i);
    /* relaxed: see shm_slot.beat */
    unsigned b = atomic_load_explicit(&s->beat, memory_order_relaxed);
    if (reset || b != m->beat || queue_ready(&s->lane[m->cur & 1].q) >= QUEUE_ENTRIES ||
        queue_ready(&s->lane[(m->cur + 1) & 1].q) >= QUEUE_ENTRIES) {
        m->beat = b;
        m->beat_t = now;
    }
}

/* Worker i made no progress for the stall timeout: killed, and replaced
 * as after a crash once it is reaped (a death of its task). */
static void stalled(engine *e, int i, double now)
{
    mslot *m = &e->ms[i];
    m->stalled_pid = m->pid;
    m->stalled_quiet = now - m->beat_t;
    m->stalled_state = engine_pool_proc_state(m->pid);
    m->stalls++;
    m->task_stalls++;
    e->stalls++;
    engine_pool_kill(e, i);
}

/* Reap the dead (and replace them); in a job, watch the busy ones'
 * heartbeats and kill those that stall. */
static void check_workers(engine *e, int force)
{
    double now = clock_now();
    if (!force && now - e->last_check < LIVENESS_EVERY) return;
    int reset = now - e->last_check > LOOKED_AWAY_S;
    e->last_check = now;
    for (int i = 0; i < e->n; i++) {
        mslot *m = &e->ms[i];
        pid_t pid = m->pid;
        if (pid <= 0) {
            if (force && !m->busy) handle_death(e, i);
            continue;
        }
        pid_t r = waitpid(pid, NULL, WNOHANG);
        if (r == pid || (r < 0 && errno == ECHILD)) {
            handle_death(e, i);
            continue;
        }
        if (!m->busy || m->killed) continue;
        watch_beat(e, i, now, reset);
        if (e->stall_s > 0 && now - m->beat_t >= e->stall_s) stalled(e, i, now);
    }
}

int engine_check_workers(engine *e)
{
    if (e->kind) return -EBUSY; /* a job checks its own workers */
    uint32_t restarts = e->restarts;
    memset(&e->err, 0, sizeof e->err);
    check_workers(e, 1);
    int rc = e->err.kind ? e->err.code : (int)(e->restarts - restarts);
    /* Between jobs nothing else reads these: the next job starts afresh. */
    memset(&e->err, 0, sizeof e->err);
    e->restarts = restarts;
    return rc;
}

/* The kind's estimate of the job's need passed the data area: stop now,
 * not once the segment is full. */
static void too_big(engine *e, const engine_progress *p)
{
    engine_sched_fail(e, ENGINE_LIMIT, -ENOMEM,
               "the job would need at least %llu MiB of shared memory (at %.2f%% done, "
               "%llu MiB in use), over the %zu MiB there are; raise "
               "the shared memory size or ask for less",
               (unsigned long long)(p->shm_need >> 20), p->fraction * 100.0,
               (unsigned long long)(p->shm_used >> 20), e->seg.bytes >> 20);
}

/* The kind's progress, every PROGRESS_EVERY (force: now, the job done):
 * its estimate checked, then the watcher told. */
static void progress(engine *e, int force)
{
    if (!e->kind->progress) return;
    double now = clock_now();
    if (!force && now - e->last_progress < PROGRESS_EVERY) return;
    e->last_progress = now;
    engine_progress p = {.seconds = now - e->t0};
    e->kind->progress(e, &p);
    if (!force && p.shm_need > e->h->data_bytes) too_big(e, &p);
    if (e->watch.progress) e->watch.progress(e->watch.ud, &p);
}

static int cancelled(const engine *e)
{
    /* relaxed: see engine_sched_watch.cancel */
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
        if (!e->err.kind) did += assign(e);
        if (e->err.kind) return e->err.code;
        if (e->nbusy == 0 && e->sp == 0) return 0;
        if (cancelled(e))
            return engine_sched_fail(e, ENGINE_CANCELLED, -ECANCELED,
                              "the job was cancelled");
        progress(e, 0);
        if (!did) sleep_master(e);
        check_workers(e, 0);
    }
}

/* A worker that does not let go of an abandoned job (stopped, hung) is
 * killed: a cancel never waits on it. */
static void kill_unanswered(engine *e, double t0)
{
    double now = clock_now();
    for (int i = 0; i < e->n; i++) {
        mslot *m = &e->ms[i];
        if (!m->busy || m->pid <= 0 || m->killed) continue;
        double quiet = now - m->beat_t;
        int kill_it = now - t0 >= ABORT_WAIT_S || quiet >= ABORT_QUIET_S;
        if (!kill_it && quiet >= ABORT_STOPPED_S) {
            char st = engine_pool_proc_state(m->pid);
            kill_it = st == 'T' || st == 't';
        }
        if (!kill_it) continue;
        m->unanswered++;
        engine_pool_kill(e, i);
    }
}

/* Tell the workers to drop the job and wait until all are idle (see
 * kill_unanswered for how long at most). */
static void abort_job(engine *e)
{
    double t0 = clock_now();
    e->aborting = 1;
    /* relaxed: workers poll it; the fence in shm_wake_if_sleeping() pairs
     * with the one of a worker going to sleep. */
    atomic_store_explicit(&e->h->abort_gen, e->h->gen, memory_order_relaxed);
    for (int i = 0; i < e->n; i++) {
        engine_pool_take_back(e, i); /* not started: dropped */
        if (e->ms[i].busy)
            shm_wake_if_sleeping(&engine_pool_slot(e, i)->wake,
                                 &engine_pool_slot(e, i)->sleeping);
    }
    while (e->nbusy) {
        int did = 0;
        for (int i = 0; i < e->n; i++)
            if (e->ms[i].busy) did += drain(e, i, 1);
        if (!did) sleep_master(e);
        check_workers(e, 0);
        kill_unanswered(e, t0);
    }
    e->sp = 0;
    e->aborting = 0;
}

static void job_reset(engine *e, const engine_kind *k, void *job,
                      const engine_sched_watch *watch)
{
    e->kind = k;
    e->job = job;
    e->watch = watch ? *watch : (engine_sched_watch){0};
    memset(&e->err, 0, sizeof e->err);
    e->restarts = 0;
    e->stalls = 0;
    e->offered = 0;
    e->sp = 0;
    e->t0 = clock_now();
    e->last_progress = e->t0 - 1.0; /* the first call comes at once */
    /* A new generation: workers begin the job afresh (their kernels' state,
     * their counters), and an abort names this job only. */
    e->h->gen = e->h->gen + 1 ? e->h->gen + 1 : 1;
    e->h->job_kind = k->id;
}

int engine_run(engine *e, const engine_kind *k, void *job,
               const engine_sched_watch *watch)
{
    engine_tidy(e); /* the last job's pages, where the caller left them */
    job_reset(e, k, job, watch);
    check_workers(e, 1); /* any that died since the last job */
    int rc = e->err.kind ? e->err.code : k->setup(e, job);
    if (!rc) rc = run_loop(e);
    if (e->nbusy) abort_job(e);
    if (!rc) progress(e, 1);
    rc = k->finish(e, job, rc);
    engine_sched_release(e); /* done, failed or cancelled: the pages go back */
    e->kind = NULL; /* the caller's job; nothing may use it after this */
    e->job = NULL;
    return rc;
}
