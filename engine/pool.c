/* The engine's worker pool: CPUs, fork, pinning, giving a task to a slot,
 * reaping; the engine's creation and destruction. */
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdatomic.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "clock.h"
#include "err.h"
#include "master.h"
#include "par.h"
#include "thread_name.h"
#include "worker.h"

#define EXIT_WAIT_S 2.0 /* engine_destroy's patience with a worker that
                           does not run; one whose CPU time still grows
                           (a slow machine, valgrind) gets up to: */
#define EXIT_WAIT_MAX_S 60.0
#define QUIET_SHOWN_S 1.0 /* a busy worker this long without a heartbeat is
                             shown as stalled */

static int pick_cpus(engine *e, const engine_opts *o, err_info *err)
{
    if (o->cpus && o->ncpus > 0) {
        for (int i = 0; i < e->n; i++) {
            int c = o->cpus[i % o->ncpus];
            if (c < 0 || c >= CPU_SETSIZE)
                return err_set(err, -EINVAL, "CPU %d is out of range 0..%d", c,
                               CPU_SETSIZE - 1);
            e->ms[i].cpu = c;
        }
        return 0;
    }
    /* Automatic: the CPUs this process may run on, in order, from the one
     * it runs on now: worker i on the (s + i)-th.  The kernel starts a
     * process on an idle CPU, so jobs started side by side spread out:
     * from the first CPU every time, 16 one-worker vox started at once on
     * 16 cores pinned their 16 workers to CPU 0 and took 10 times longer
     * (docs/benchmarks.md). */
    cpu_set_t set;
    int list[CPU_SETSIZE], k = 0, s = 0, here = sched_getcpu();
    if (sched_getaffinity(0, sizeof set, &set) == 0)
        for (int c = 0; c < CPU_SETSIZE; c++)
            if (CPU_ISSET(c, &set)) {
                if (c == here) s = k;
                list[k++] = c;
            }
    if (k == 0) list[k++] = 0;
    for (int i = 0; i < e->n; i++) e->ms[i].cpu = list[(s + i) % k];
    return 0;
}

/* Whether the master may run on a CPU no worker is pinned to (-w 1 on two
 * cores): then it polls for results a while before it sleeps (sched.c). */
static int spare_cpu(const engine *e)
{
    cpu_set_t set;
    if (sched_getaffinity(0, sizeof set, &set) != 0) return 0;
    for (int i = 0; i < e->n; i++)
        if (e->ms[i].cpu >= 0 && e->ms[i].cpu < CPU_SETSIZE) CPU_CLR(e->ms[i].cpu, &set);
    return CPU_COUNT(&set) > 0;
}

int engine_pool_spawn(engine *e, int i, err_info *err)
{
    pid_t pid = fork();
    if (pid < 0) {
        int rc = -errno;
        return err_set(err, rc, "cannot fork worker %d: %s", i, strerror(-rc));
    }
    if (pid == 0) {
        thread_name("worker");
        worker_main(e->seg.base, (uint32_t)i);
    }
    e->ms[i].pid = pid;
    e->ms[i].ended = 0;
    engine_pool_slot(e, i)->pid = pid;
    engine_pool_slot(e, i)->cpu = e->ms[i].cpu;
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(e->ms[i].cpu, &set);
    if (sched_setaffinity(pid, sizeof set, &set) != 0) {
        int rc = -errno;
        kill(pid, SIGKILL);
        waitpid(pid, NULL, 0);
        e->ms[i].pid = 0;
        return err_set(err, rc, "cannot pin worker %d to CPU %d: %s", i, e->ms[i].cpu,
                       strerror(-rc));
    }
    return 0;
}

void engine_pool_give(engine *e, int i, const shm_task *t, uint32_t skip)
{
    shm_slot *s = engine_pool_slot(e, i);
    mslot *m = &e->ms[i];
    s->task = *t;
    s->task_gen = e->h->gen;
    s->task_skip = skip;
    m->cur = ++m->seq;
    /* release: publishes the task fields and the job's block to the
     * worker's acquire load of task_seq. */
    atomic_store_explicit(&s->task_seq, m->seq, memory_order_release);
    shm_wake_if_sleeping(&s->wake, &s->sleeping);
}

void engine_pool_offer(engine *e, int i, const shm_task *t)
{
    shm_slot *s = engine_pool_slot(e, i);
    mslot *m = &e->ms[i];
    m->next = *t;
    m->offered = 1;
    m->seq = m->cur + 1;
    s->next_task = *t;
    s->next_gen = e->h->gen;
    /* release: publishes next_task and next_gen (and the job's block) to
     * the worker's exchange (acq_rel) in take_task. */
    atomic_store_explicit(&s->next, 1, memory_order_release);
    shm_wake_if_sleeping(&s->wake, &s->sleeping);
}

int engine_pool_take_back(engine *e, int i)
{
    mslot *m = &e->ms[i];
    if (!m->offered) return 0;
    /* acq_rel: the exchange decides who owns the task, against the
     * worker's own exchange in take_task (the modification order of
     * `next` has one of the two read the 1). */
    if (!atomic_exchange_explicit(&engine_pool_slot(e, i)->next, 0, memory_order_acq_rel))
        return 0;
    m->offered = 0;
    m->seq = m->cur;
    return 1;
}

void engine_pool_kill(engine *e, int i)
{
    mslot *m = &e->ms[i];
    if (m->pid <= 0 || m->killed) return;
    kill(m->pid, SIGKILL);
    m->killed = 1;
}

/* /proc/PID/stat from its state on ("S ppid ..."), into buf; NULL when
 * it cannot be read. */
static const char *proc_stat(pid_t pid, char *buf, size_t len)
{
    char path[64];
    snprintf(path, sizeof path, "/proc/%d/stat", (int)pid);
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) return NULL;
    ssize_t n = read(fd, buf, len - 1);
    close(fd);
    if (n <= 0) return NULL;
    buf[n] = '\0';
    /* "pid (comm) S ...": comm may hold anything, so from the last ')' */
    char *p = strrchr(buf, ')');
    return p && p[1] == ' ' && p[2] ? p + 2 : NULL;
}

char engine_pool_proc_state(pid_t pid)
{
    char buf[512];
    const char *st = proc_stat(pid, buf, sizeof buf);
    return st ? st[0] : '?';
}

/* The process's user + system CPU time in clock ticks (fields 14 and 15
 * of /proc/PID/stat), 0 when it cannot be read. */
static unsigned long long proc_cpu_ticks(pid_t pid)
{
    char buf[512];
    const char *st = proc_stat(pid, buf, sizeof buf);
    unsigned long long ut = 0, stime = 0;
    /* from the state (field 3): skip fields 4..13, read 14 and 15 */
    if (!st || sscanf(st, "%*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %llu %llu",
                      &ut, &stime) != 2)
        return 0;
    return ut + stime;
}

/* A stopped worker (SIGSTOP, a debugger) would not take its exit task. */
static int stopped(pid_t pid)
{
    char st = engine_pool_proc_state(pid);
    return st == 'T' || st == 't';
}

/* The workers' exit: each has EXIT_WAIT_S to go, renewed while its CPU
 * time grows (it is on its way, only slowly: under valgrind, on a loaded
 * machine), up to EXIT_WAIT_MAX_S; then it is killed. */
static void reap_all(engine *e)
{
    double t0 = clock_now(), deadline = t0 + EXIT_WAIT_S;
    unsigned long long cpu[ENGINE_MAX_WORKERS] = {0};
    for (;;) {
        int left = 0, moved = 0;
        for (int i = 0; i < e->n; i++) {
            pid_t pid = e->ms[i].pid;
            if (pid <= 0) continue;
            pid_t r = waitpid(pid, NULL, WNOHANG);
            if (r == pid || (r < 0 && errno == ECHILD)) {
                e->ms[i].pid = 0;
                continue;
            }
            if (stopped(pid)) kill(pid, SIGKILL); /* it would never answer */
            left++;
        }
        if (!left) return;
        double now = clock_now();
        if (now > deadline) {
            for (int i = 0; i < e->n; i++) {
                if (e->ms[i].pid <= 0) continue;
                unsigned long long c = proc_cpu_ticks(e->ms[i].pid);
                moved |= c > cpu[i];
                cpu[i] = c;
            }
            if (!moved || now - t0 > EXIT_WAIT_MAX_S) break;
            deadline = now + EXIT_WAIT_S;
        }
        struct timespec ms = {0, 1000000};
        nanosleep(&ms, NULL);
    }
    for (int i = 0; i < e->n; i++) {
        if (e->ms[i].pid <= 0) continue;
        kill(e->ms[i].pid, SIGKILL);
        waitpid(e->ms[i].pid, NULL, 0);
        e->ms[i].pid = 0;
    }
}

/* Every live worker given op (exit or leave; a busy one killed). */
static void order(engine *e, uint32_t op)
{
    const shm_task task = {.kind = SHM_KIND_CORE, .op = op};
    for (int i = 0; i < e->n; i++) {
        if (e->ms[i].pid <= 0) continue;
        if (e->ms[i].busy) kill(e->ms[i].pid, SIGKILL);
        else engine_pool_give(e, i, &task, 0);
    }
}

static void order_exit(engine *e) { order(e, SHM_OP_EXIT); }

void engine_destroy(engine *e)
{
    if (!e) return;
    if (e->seg.base) {
        order_exit(e);
        /* The segment unmapped and unlinked while the workers exit, not
         * after: its pages go back to tmpfs when the last process lets go
         * of them, and each process's unmapping (its page tables) runs
         * beside the others' instead of after them. */
        shm_destroy(&e->seg);
        reap_all(e);
    }
    free(e);
}

/* engine_abandon's unmapping, beside the caller's last steps. */
typedef struct {
    void *base;
    size_t bytes;
    atomic_size_t next; /* the next piece to drop */
} unmapping;

#define UNMAP_PIECE ((size_t)32 << 20) /* a multiple of every page size here */

/* The mapping's page tables dropped piece by piece (the pages stay the
 * segment's), each thread taking the next: madvise takes the mapping's
 * lock to read, so the threads run at once, where munmap (or the exit's
 * teardown) would drop them all on one, under the lock held to write.
 * Pieces, not halves: what the master touched lies anywhere in it. */
static void unmap_part(void *ud, unsigned k, unsigned n)
{
    (void)k, (void)n;
    unmapping *u = ud;
    for (;;) {
        /* relaxed: a counter; the pieces are disjoint */
        size_t from = atomic_fetch_add_explicit(&u->next, UNMAP_PIECE, memory_order_relaxed);
        if (from >= u->bytes) return;
        size_t len = u->bytes - from < UNMAP_PIECE ? u->bytes - from : UNMAP_PIECE;
        madvise((char *)u->base + from, len, MADV_DONTNEED);
    }
}

static void *unmap_run(void *arg)
{
    unmapping *u = arg;
    unsigned cpus = par_cpus();
    if (cpus > 1) par_run(cpus, unmap_part, u);
    munmap(u->base, u->bytes);
    free(u);
    return NULL;
}

/* The caller's mapping unmapped on a detached thread (here when none can
 * be made), its page tables dropped in parts by every CPU (the master
 * touched hundreds of MB of it: 0.03-0.06 s of one thread in the exit of
 * vox mesh otherwise): only its page tables go, the workers still map the
 * pages. */
static void unmap_beside(shm_seg *s)
{
    unmapping *u = malloc(sizeof *u);
    pthread_t t;
    pthread_attr_t a;
    int started = 0;
    if (u && !pthread_attr_init(&a)) {
        u->base = s->base, u->bytes = s->bytes;
        atomic_init(&u->next, 0);
        pthread_attr_setdetachstate(&a, PTHREAD_CREATE_DETACHED);
        started = !pthread_create(&t, &a, unmap_run, u);
        pthread_attr_destroy(&a);
    }
    if (!started) {
        munmap(s->base, s->bytes);
        free(u);
    }
    s->base = NULL;
}

/* The workers told to leave, the segment's name removed; unmap: the
 * caller's mapping unmapped beside what it does next. */
static void leave(engine *e, int unmap)
{
    if (!e) return;
    if (e->seg.base) {
        order(e, SHM_OP_LEAVE);
        if (e->seg.named) shm_unlink(e->seg.name);
        e->seg.named = 0;
        if (unmap) unmap_beside(&e->seg);
    }
    free(e);
}

void engine_abandon(engine *e)
{
    leave(e, 1);
}

void engine_leave(engine *e)
{
    leave(e, 0);
}

int engine_create(const engine_opts *o, engine **out, err_info *err)
{
    *out = NULL;
    if (!o || o->workers < 1 || o->workers > ENGINE_MAX_WORKERS)
        return err_set(err, -EINVAL, "the number of workers must be 1..%d (got %d)",
                       ENGINE_MAX_WORKERS, o ? o->workers : 0);
    engine *e = calloc(1, sizeof *e);
    if (!e) return -ENOMEM;
    e->n = o->workers;
    e->keep = o->keep_bytes ? o->keep_bytes : ENGINE_KEEP_BYTES;
    e->stall_s = o->stall_timeout == 0 ? ENGINE_STALL_TIMEOUT : o->stall_timeout;
    e->shm_option = o->shm_option;
    int rc = pick_cpus(e, o, err);
    e->spare_cpu = !rc && spare_cpu(e);
    if (!rc)
        rc = shm_create(&e->seg, o->shm_name, o->shm_bytes, (uint32_t)e->n,
                        err);
    if (rc) {
        free(e);
        return rc;
    }
    e->h = shm_hdr(e->seg.base);
    e->stack = shm_at(e->seg.base, e->h->stack_off);
    e->cap = (uint32_t)e->h->stack_cap;
    for (int i = 0; i < e->n && !rc; i++) rc = engine_pool_spawn(e, i, err);
    if (rc) {
        engine_destroy(e);
        return rc;
    }
    *out = e;
    return 0;
}

int engine_workers(const engine *e) { return e->n; }

size_t engine_shm_default(int workers)
{
    return shm_default_bytes(workers > 0 ? (uint32_t)workers : 1);
}

int engine_worker_pid(const engine *e, int i)
{
    return i >= 0 && i < e->n ? (int)e->ms[i].pid : -1;
}

int engine_worker_cpu(const engine *e, int i)
{
    return i >= 0 && i < e->n ? e->ms[i].cpu : -1;
}

int engine_worker_info_get(const engine *e, int i, engine_worker_info *out)
{
    if (i < 0 || i >= e->n) return -EINVAL;
    const mslot *m = &e->ms[i];
    *out = (engine_worker_info){
        .pid = m->pid, .cpu = m->cpu, .state = ENGINE_WORKER_IDLE,
        .replaced = m->replaced, .stalls = m->stalls, .unanswered = m->unanswered,
        .ended = m->ended,
        .stalled_pid = m->stalled_pid, .stalled_quiet = m->stalled_quiet,
        .stalled_state = m->stalled_state ? m->stalled_state : '?',
    };
    if (m->pid <= 0 || m->killed) {
        out->state = ENGINE_WORKER_STARTING;
    } else if (e->kind && m->busy) {
        out->quiet = clock_now() - m->beat_t;
        out->state = out->quiet >= QUIET_SHOWN_S ? ENGINE_WORKER_STALLED : ENGINE_WORKER_BUSY;
    }
    return 0;
}

octree *engine_octree(engine *e) { return e->result == RESULT_OCTREE ? &e->tree : NULL; }
