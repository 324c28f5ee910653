/* The worker process: Figure 3's slave loop over the shared-memory slot,
 * the same for every kind of job; the kinds' kernels are in work_*.c. */
#include "worker.h"

#include <errno.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <time.h>
#include <unistd.h>

#include "clock.h"
#include "heap.h"
#include "work.h"

/* The worker side of every kind (worker/work_<name>.c, one row each
 * here): the task's kind is an index in the table. */
extern const worker_kind worker_implicit, worker_encode, worker_mesh, worker_csg, worker_iso;
static const worker_kind *const kinds[SHM_KINDS] = {
    [SHM_KIND_IMPLICIT] = &worker_implicit,
    [SHM_KIND_ENCODE] = &worker_encode,
    [SHM_KIND_MESH] = &worker_mesh,
    [SHM_KIND_CSG] = &worker_csg,
    [SHM_KIND_ISO] = &worker_iso,
};

static uint64_t cpu_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

/* A worker's heap is kept while it works (heap.h: the next tile's arrays
 * would fault in again) and given back once the worker has waited
 * WORKER_IDLE_S for a task (idle: between jobs, not between a job's
 * tasks). */
#define WORKER_IDLE_S 0.5

static void give_back(worker_ctx *w)
{
    if (!w->heap_kept) return;
    w->heap_kept = false;
    heap_give_back();
}

/* The task to run next: one the master gave (task_seq moved past
 * w->given, the last given one seen) or one it offered (`next`, taken by
 * the exchange: the master may take it back until then).  1 with the task
 * copied into *t and w->seq, w->lane, w->task_gen and w->skip set; 0 when
 * there is none. */
static int take_task(worker_ctx *w, shm_task *t)
{
    shm_slot *s = w->s;
    /* acquire: pairs with the master's release after it wrote the task
     * fields and the job input. */
    unsigned g = atomic_load_explicit(&s->task_seq, memory_order_acquire);
    if (g != w->given) {
        w->given = w->seq = g;
        *t = s->task;
        w->task_gen = s->task_gen;
        w->skip = s->task_skip;
    } else {
        /* acq_rel: acquires the master's release of next (next_task and
         * next_gen written before it); the exchange against the master's
         * own (engine_pool_take_back) decides who owns the task.  It is
         * offered only after run_seq said we copied our task: it is the
         * one after it. */
        if (!atomic_exchange_explicit(&s->next, 0, memory_order_acq_rel)) return 0;
        w->seq++;
        *t = s->next_task;
        w->task_gen = s->next_gen;
        w->skip = 0;
    }
    w->lane = &s->lane[w->seq & 1];
    /* release: the task is copied; pairs with the master's acquire in
     * offer() before it writes the next offer where this one was. */
    atomic_store_explicit(&s->run_seq, w->seq, memory_order_release);
    return 1;
}

/* The next task, into *t (its number in w->seq).  The master is rung
 * once: the task before ended (done_seq) and, when the next one was
 * there already, this one started (run_seq: the master may offer the one
 * after it). */
static void wait_task(worker_ctx *w, shm_task *t)
{
    shm_slot *s = w->s;
    int got = take_task(w, t);
    worker_ring_master(w);
    double idle0 = got ? 0 : clock_now();
    while (!got) {
        unsigned v = shm_sleep_begin(&s->wake, &s->sleeping);
        /* acquire: as in take_task; after the fence, the Dekker re-check
         * (relaxed for next: take_task's exchange acquires it) */
        if (atomic_load_explicit(&s->task_seq, memory_order_acquire) == w->given &&
            !atomic_load_explicit(&s->next, memory_order_relaxed))
            shm_futex_wait(&s->wake, v, WORKER_WAIT_NS);
        shm_sleep_end(&s->sleeping);
        worker_check_parent(w);
        got = take_task(w, t);
        if (!got && clock_now() - idle0 >= WORKER_IDLE_S) give_back(w);
    }
}

static void free_states(worker_ctx *w)
{
    for (int k = 0; k < SHM_KINDS; k++)
        if (kinds[k] && w->state[k]) kinds[k]->free(w->state[k]);
}

static _Noreturn void worker_exit(worker_ctx *w)
{
    free_states(w);
    _exit(0);
}

#define WORKER_LEAVE_BOUND_S 10 /* seconds: a sanitized worker's exit at most */

/* engine_abandon: the master's process exits next.  Whoever unmaps the
 * segment last frees its pages, and the user waits for the master, not for
 * us: so we keep it mapped until the master is gone (seen as a new parent
 * within 0.1 s), and let go of stdin, stdout and stderr first, so that a
 * reader of the command's output (a pipe) does not wait for us either.
 * The SIGKILL of PR_SET_PDEATHSIG is off here: we leave by _exit, so that
 * a tool watching the process (valgrind) sees its exit. */
static _Noreturn void worker_leave(worker_ctx *w)
{
    free_states(w);
    close(0), close(1), close(2);
    prctl(PR_SET_PDEATHSIG, 0);
    struct timespec tick = {0, 100000000};
    while (getppid() == w->h->master_pid) nanosleep(&tick, NULL);
#ifdef __SANITIZE_ADDRESS__
    /* A bound on the exit itself: under AddressSanitizer _exit runs
     * LeakSanitizer's check, which can wait forever on a lock that another
     * thread of the master held when it forked us (an orphaned worker was
     * once found asleep in libasan after a test had killed its master).
     * SIGALRM's default action (reset_signals) ends us then. */
    alarm(WORKER_LEAVE_BOUND_S);
#endif
    _exit(0);
}

/* The per-job counters the master sums (engine_sched_job_totals): reset on a job's
 * first task, whatever its kind. */
static void job_counters(worker_ctx *w)
{
    if (w->gen == w->task_gen) return;
    w->gen = w->task_gen;
    w->s->job_gen = w->task_gen;
    w->s->job_tested = 0;
    w->s->job_cpu_ns = 0;
    w->cpu0 = cpu_ns();
}

static int run_kind(worker_ctx *w, const shm_task *t)
{
    const worker_kind *k = t->kind < SHM_KINDS ? kinds[t->kind] : NULL;
    if (!k) return -EINVAL;
    if (w->begun[t->kind] != w->task_gen) {
        w->begun[t->kind] = 0;
        int rc = k->begin(w, &w->state[t->kind]);
        if (rc) return rc;
        w->begun[t->kind] = w->task_gen;
    }
    return k->run(w, w->state[t->kind], t);
}

static void run_task(worker_ctx *w, const shm_task *tp)
{
    shm_slot *s = w->s;
    shm_task t = *tp;
    if (t.kind == SHM_KIND_CORE && t.op == SHM_OP_EXIT) worker_exit(w);
    if (t.kind == SHM_KIND_CORE && t.op == SHM_OP_LEAVE) worker_leave(w);
    w->task_kind = t.kind;
    job_counters(w);
    worker_tick(w);
    int rc = run_kind(w, &t);
    w->heap_kept = true;
    worker_tick(w);
    s->job_cpu_ns = cpu_ns() - w->cpu0;
    s->error[w->seq & 1] = rc == -ECANCELED ? 0 : rc;
    /* release: publishes the task's last entries, counters and error
     * (and whatever its kind's block lets it write) to the master's
     * acquire load of done_seq. */
    atomic_store_explicit(&s->done_seq, w->seq, memory_order_release);
}

/* The master's handlers (an event loop's, say) mean nothing here; crash
 * signals keep theirs (sanitizer reports).  The master decides when a job
 * stops, so a terminal's ^C is ignored. */
static void reset_signals(void)
{
    static const int dfl[] = {SIGTERM, SIGHUP,  SIGUSR1, SIGUSR2,
                              SIGCHLD, SIGALRM, SIGWINCH};
    static const int ign[] = {SIGINT, SIGQUIT, SIGPIPE};
    for (size_t i = 0; i < sizeof dfl / sizeof dfl[0]; i++)
        signal(dfl[i], SIG_DFL);
    for (size_t i = 0; i < sizeof ign / sizeof ign[0]; i++)
        signal(ign[i], SIG_IGN);
    sigset_t none;
    sigemptyset(&none);
    sigprocmask(SIG_SETMASK, &none, NULL);
}

/* Every descriptor the master had open is inherited: clients' sockets,
 * the listening socket, result memfds, its log and its lock (vox: the
 * output file).  A worker needs none of them, and must not keep them: a
 * client's socket held by a worker does not close when the master closes
 * it, and a result's memory is not freed.  It keeps 0-2 (stderr carries
 * sanitizer reports); the segment is a mapping, its descriptor closed
 * after mmap (shm.c). */
static void close_inherited(void)
{
    if (close_range(3, ~0U, 0) == 0) return;
    /* a kernel before 5.9 (Debian 12 has 6.1): one by one */
    long max = sysconf(_SC_OPEN_MAX);
    if (max < 0 || max > 65536) max = 65536;
    for (long fd = 3; fd < max; fd++) close((int)fd);
}

_Noreturn void worker_main(uint8_t *base, uint32_t index)
{
    worker_ctx w;
    memset(&w, 0, sizeof w);
    w.base = base;
    w.h = shm_hdr(base);
    w.s = shm_slot_at(base, index);
    /* Die with the master (the thread that forked us, strictly), and make
     * sure it did not die before the request took effect. */
    prctl(PR_SET_PDEATHSIG, SIGKILL);
    worker_check_parent(&w);
    reset_signals();
    close_inherited();
    heap_keep();
    /* relaxed: a fresh worker starts from the slot as its predecessor (or
     * the master, at creation) left it; the fork orders everything. */
    w.given = w.seq = atomic_load_explicit(&w.s->done_seq, memory_order_relaxed);
    w.beats = atomic_load_explicit(&w.s->beat, memory_order_relaxed);
    for (;;) {
        shm_task t;
        wait_task(&w, &t);
        run_task(&w, &t);
    }
}
