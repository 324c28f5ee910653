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

/* Wait for the next task (task_seq != last); returns its sequence number. */
static unsigned wait_task(worker_ctx *w, unsigned last)
{
    shm_slot *s = w->s;
    for (;;) {
        /* acquire: pairs with the master's release after it wrote the task
         * fields and the job input. */
        unsigned t = atomic_load_explicit(&s->task_seq, memory_order_acquire);
        if (t != last) return t;
        unsigned v = shm_sleep_begin(&s->wake, &s->sleeping);
        /* acquire: as above; after the fence, the Dekker re-check */
        t = atomic_load_explicit(&s->task_seq, memory_order_acquire);
        if (t == last) shm_futex_wait(&s->wake, v, WORKER_WAIT_NS);
        shm_sleep_end(&s->sleeping);
        worker_check_parent(w);
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

static void run_task(worker_ctx *w, unsigned seq)
{
    shm_slot *s = w->s;
    shm_task t = s->task;
    if (t.kind == SHM_KIND_CORE && t.op == SHM_OP_EXIT) worker_exit(w);
    if (t.kind == SHM_KIND_CORE && t.op == SHM_OP_LEAVE) worker_leave(w);
    w->task_gen = s->task_gen;
    w->skip = s->task_skip;
    job_counters(w);
    worker_tick(w);
    int rc = run_kind(w, &t);
    worker_tick(w);
    s->job_cpu_ns = cpu_ns() - w->cpu0;
    s->error = rc == -ECANCELED ? 0 : rc;
    /* release: publishes the task's last entries, counters and error
     * (and whatever its kind's block lets it write) to the master's
     * acquire load of done_seq. */
    atomic_store_explicit(&s->done_seq, seq, memory_order_release);
    worker_ring_master(w);
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
    /* relaxed: a fresh worker starts from the slot as its predecessor (or
     * the master, at creation) left it; the fork orders everything. */
    unsigned last = atomic_load_explicit(&w.s->done_seq, memory_order_relaxed);
    w.beats = atomic_load_explicit(&w.s->beat, memory_order_relaxed);
    for (;;) {
        unsigned seq = wait_task(&w, last);
        run_task(&w, seq);
        last = seq;
    }
}
