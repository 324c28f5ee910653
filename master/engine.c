/* The master side of the engine: workers' lives, Figure 3's scheduler over
 * the shared-memory slots, and the parallel VOD brick phase. */
#include "engine.h"

#include <errno.h>
#include <limits.h>
#include <sched.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "shm.h"
#include "worker.h"

#define MASTER_SLEEP_NS 20000000L /* 20 ms: cancel and progress stay live */
#define PROGRESS_EVERY 0.1        /* seconds between progress callbacks */
#define LIVENESS_EVERY 0.05       /* seconds between checks for dead workers */
#define OCTANT_DEATHS 2           /* deaths on one octant that fail the job */
#define EXIT_WAIT_S 2.0           /* engine_destroy's patience */
#define KEEP_BYTES ((size_t)64 << 20) /* default engine_opts.keep_bytes */

typedef struct {
    pid_t pid;          /* 0: no worker */
    int cpu;
    unsigned seq;       /* the last task_seq given */
    int busy;           /* a task given and not finished and drained */
    uint32_t kind;
    grid_octant task;
    uint32_t consumed;  /* entries of the current task taken */
    uint32_t kept;      /* octants the current task sent back */
    int deaths;         /* workers that died on the current task */
} mslot;

struct engine {
    shm_seg seg;
    shm_header *h;
    int n;
    mslot ms[ENGINE_MAX_WORKERS];
    octree tree;
    int have_tree;
    grid_octant *stack; /* the work stack, in the segment */
    uint32_t sp, cap;
    /* the running job */
    const engine_job *job;
    int split;
    int aborting;
    int nbusy;
    uint64_t done_vol, total_vol;
    uint32_t pending[GRID_MAX_DEPTH + 1]; /* octants pushed, unfinished */
    int error;
    char msg[256];
    uint32_t restarts;
    uint64_t stored;    /* voxels taken from the queues */
    uint64_t touched;   /* end of the data pages the last job touched */
    uint64_t keep;      /* bytes of the data area kept between jobs */
    double t0, last_progress, last_check;
};

static double now_s(clockid_t c)
{
    struct timespec ts;
    clock_gettime(c, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

__attribute__((format(printf, 3, 4))) static int fail(engine *e, int rc,
                                                      const char *fmt, ...)
{
    if (e->error) return e->error; /* the first error is the one told */
    e->error = rc;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(e->msg, sizeof e->msg, fmt, ap);
    va_end(ap);
    return rc;
}

static inline shm_slot *slot(engine *e, int i)
{
    return shm_slot_at(e->seg.base, (uint32_t)i);
}

/* ---- workers' lives ---- */

static int pick_cpus(engine *e, const engine_opts *o, char *err,
                     size_t errlen)
{
    if (o->cpus && o->ncpus > 0) {
        for (int i = 0; i < e->n; i++) {
            int c = o->cpus[i % o->ncpus];
            if (c < 0 || c >= CPU_SETSIZE) {
                snprintf(err, errlen, "CPU %d is out of range 0..%d", c,
                         CPU_SETSIZE - 1);
                return -EINVAL;
            }
            e->ms[i].cpu = c;
        }
        return 0;
    }
    /* Automatic: worker i on the i-th CPU this process may run on. */
    cpu_set_t set;
    int list[CPU_SETSIZE], k = 0;
    if (sched_getaffinity(0, sizeof set, &set) == 0)
        for (int c = 0; c < CPU_SETSIZE; c++)
            if (CPU_ISSET(c, &set)) list[k++] = c;
    if (k == 0) list[k++] = 0;
    for (int i = 0; i < e->n; i++) e->ms[i].cpu = list[i % k];
    return 0;
}

static int spawn(engine *e, int i, char *err, size_t errlen)
{
    pid_t pid = fork();
    if (pid < 0) {
        int rc = -errno;
        snprintf(err, errlen, "cannot fork worker %d: %s", i, strerror(-rc));
        return rc;
    }
    if (pid == 0) worker_main(e->seg.base, (uint32_t)i);
    e->ms[i].pid = pid;
    slot(e, i)->pid = pid;
    slot(e, i)->cpu = e->ms[i].cpu;
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(e->ms[i].cpu, &set);
    if (sched_setaffinity(pid, sizeof set, &set) != 0) {
        int rc = -errno;
        kill(pid, SIGKILL);
        waitpid(pid, NULL, 0);
        e->ms[i].pid = 0;
        snprintf(err, errlen, "cannot pin worker %d to CPU %d: %s", i,
                 e->ms[i].cpu, strerror(-rc));
        return rc;
    }
    return 0;
}

/* Hand task kind on octant o to worker i. */
static void give(engine *e, int i, grid_octant o, uint32_t kind,
                 uint32_t skip)
{
    shm_slot *s = slot(e, i);
    mslot *m = &e->ms[i];
    s->task_kind = kind;
    s->task_gen = e->h->gen;
    s->task_skip = skip;
    s->task = o;
    m->busy = 1;
    m->kind = kind;
    m->task = o;
    m->consumed = skip;
    m->kept = 0;
    m->deaths = 0;
    m->seq++;
    e->nbusy++;
    /* release: publishes the task fields and the job input to the worker's
     * acquire load of task_seq. */
    atomic_store_explicit(&s->task_seq, m->seq, memory_order_release);
    shm_wake_if_sleeping(&s->wake, &s->sleeping);
}

static void reap_all(engine *e)
{
    double deadline = now_s(CLOCK_MONOTONIC) + EXIT_WAIT_S;
    for (;;) {
        int left = 0;
        for (int i = 0; i < e->n; i++) {
            pid_t pid = e->ms[i].pid;
            if (pid <= 0) continue;
            pid_t r = waitpid(pid, NULL, WNOHANG);
            if (r == pid || (r < 0 && errno == ECHILD)) e->ms[i].pid = 0;
            else left++;
        }
        if (!left) return;
        if (now_s(CLOCK_MONOTONIC) > deadline) break;
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

void engine_destroy(engine *e)
{
    if (!e) return;
    if (e->seg.base) {
        for (int i = 0; i < e->n; i++) {
            if (e->ms[i].pid <= 0) continue;
            if (e->ms[i].busy) kill(e->ms[i].pid, SIGKILL);
            else give(e, i, (grid_octant){0, 0, 0, 0}, SHM_TASK_EXIT, 0);
        }
        reap_all(e);
        shm_destroy(&e->seg);
    }
    free(e);
}

int engine_create(const engine_opts *o, engine **out, char *err,
                  size_t errlen)
{
    *out = NULL;
    if (!o || o->workers < 1 || o->workers > ENGINE_MAX_WORKERS) {
        snprintf(err, errlen, "the number of workers must be 1..%d (got %d)",
                 ENGINE_MAX_WORKERS, o ? o->workers : 0);
        return -EINVAL;
    }
    engine *e = calloc(1, sizeof *e);
    if (!e) return -ENOMEM;
    e->n = o->workers;
    e->keep = o->keep_bytes ? o->keep_bytes : KEEP_BYTES;
    int rc = pick_cpus(e, o, err, errlen);
    if (!rc)
        rc = shm_create(&e->seg, o->shm_name, o->shm_bytes, (uint32_t)e->n,
                        err, errlen);
    if (rc) {
        free(e);
        return rc;
    }
    e->h = shm_hdr(e->seg.base);
    e->stack = shm_at(e->seg.base, e->h->stack_off);
    e->cap = (uint32_t)e->h->stack_cap;
    for (int i = 0; i < e->n && !rc; i++) rc = spawn(e, i, err, errlen);
    if (rc) {
        engine_destroy(e);
        return rc;
    }
    *out = e;
    return 0;
}

int engine_workers(const engine *e) { return e->n; }

int engine_worker_pid(const engine *e, int i)
{
    return i >= 0 && i < e->n ? (int)e->ms[i].pid : -1;
}

int engine_worker_cpu(const engine *e, int i)
{
    return i >= 0 && i < e->n ? e->ms[i].cpu : -1;
}

octree *engine_octree(engine *e) { return e->have_tree ? &e->tree : NULL; }

/* ---- the scheduler ---- */

static uint64_t volume(int level) { return 1ull << (3 * level); }

static int push(engine *e, grid_octant o)
{
    if (e->sp == e->cap)
        return fail(e, -ENOMEM, "the work stack overflowed (%u octants)",
                    e->cap);
    e->stack[e->sp++] = o;
    e->pending[o.level]++;
    return 0;
}

static int outside_res(const engine *e, unsigned x, unsigned y, unsigned z)
{
    const uint32_t *res = e->h->grid.res;
    return x >= res[0] || y >= res[1] || z >= res[2];
}

/* Is (x, y, z) inside octant o? */
static int inside(grid_octant o, unsigned x, unsigned y, unsigned z)
{
    unsigned n = 1u << o.level;
    return x - o.x < n && y - o.y < n && z - o.z < n;
}

static int take_octant(engine *e, int i, grid_octant o)
{
    const mslot *m = &e->ms[i];
    if (m->kind != SHM_TASK_CHILDREN || o.level + 1 != m->task.level ||
        !inside(m->task, o.x, o.y, o.z) || (o.x | o.y | o.z) & ((1u << o.level) - 1) ||
        outside_res(e, o.x, o.y, o.z))
        return fail(e, -EPROTO,
                    "worker %d sent octant (%u,%u,%u) level %u, not a child "
                    "of its task",
                    i, o.x, o.y, o.z, o.level);
    e->ms[i].kept++;
    return push(e, o);
}

static int take_voxels(engine *e, int i, const shm_entry *en)
{
    const mslot *m = &e->ms[i];
    uint32_t n = en->count; /* read once: the worker's memory */
    if (n == 0 || n > SHM_BATCH ||
        (m->kind == SHM_TASK_CHILDREN && (n != 1 || m->task.level != 1)))
        return fail(e, -EPROTO, "worker %d sent a batch of %u voxels", i, n);
    for (uint32_t j = 0; j < n; j++) {
        grid_voxel v = en->vox[j];
        if (!inside(m->task, v.x, v.y, v.z) || outside_res(e, v.x, v.y, v.z) ||
            v.value == 0)
            return fail(e, -EPROTO, "worker %d sent voxel (%u,%u,%u) outside "
                        "its task", i, v.x, v.y, v.z);
        e->stored++;
        if (octree_store(&e->tree, v.x, v.y, v.z, v.value))
            return fail(e, -ENOMEM,
                        "the octree needs more than %u cells; raise the "
                        "shared memory size (now %zu MiB)",
                        e->tree.capacity, e->seg.bytes >> 20);
    }
    return 0;
}

static int take(engine *e, int i, const shm_entry *en)
{
    uint32_t kind = en->kind;
    if (kind == SHM_ENT_OCTANT) return take_octant(e, i, en->octant);
    if (kind == SHM_ENT_VOXELS) return take_voxels(e, i, en);
    return fail(e, -EPROTO, "worker %d sent an entry of kind %u", i, kind);
}

/* Worker i finished its subdivision task and its queue is drained. */
static void finish(engine *e, int i)
{
    mslot *m = &e->ms[i];
    shm_slot *s = slot(e, i);
    m->busy = 0;
    e->nbusy--;
    if (s->error)
        fail(e, s->error, "worker %d failed: %s", i, strerror(-s->error));
    if (m->kind == SHM_TASK_ENCODE) return;
    int l = m->task.level;
    e->pending[l]--;
    if (m->kind == SHM_TASK_SUBTREE || l == 1)
        e->done_vol += volume(l);
    else
        e->done_vol += volume(l) - (uint64_t)m->kept * volume(l - 1);
}

/* Take every entry worker i published (or throw them away); returns how
 * much happened. */
static int drain(engine *e, int i, int discard)
{
    shm_slot *s = slot(e, i);
    mslot *m = &e->ms[i];
    /* acquire: pairs with the worker's release of done_seq, so the prod
     * read next covers every entry of the finished task. */
    int done = atomic_load_explicit(&s->done_seq, memory_order_acquire) ==
               m->seq;
    unsigned n = queue_ready(&s->q), tail = queue_tail(&s->q);
    if (n > QUEUE_ENTRIES) {
        fail(e, -EPROTO, "worker %d: its queue claims %u entries", i, n);
        discard = 1;
    }
    for (unsigned k = 0; k < n && !discard && !e->error; k++)
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
        grid_octant o = e->stack[--e->sp];
        uint32_t kind = e->job->schedule == ENGINE_SCHED_PAPER ||
                                o.level > e->split
                            ? SHM_TASK_CHILDREN
                            : SHM_TASK_SUBTREE;
        give(e, i, o, kind, 0);
        did++;
    }
    return did;
}

static int anything_ready(engine *e)
{
    for (int i = 0; i < e->n; i++) {
        if (!e->ms[i].busy) continue;
        shm_slot *s = slot(e, i);
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
 * its task again, skipping the entries already taken. */
static void handle_death(engine *e, int i)
{
    mslot *m = &e->ms[i];
    shm_slot *s = slot(e, i);
    m->pid = 0;
    e->restarts++;
    if (m->busy) drain(e, i, e->aborting);
    int rerun = m->busy && !e->aborting && m->kind != SHM_TASK_ENCODE;
    /* The first death may be anybody's doing (a kill, the OOM killer):
     * the octant is handed out again.  A second one on the same octant
     * says the octant kills its workers: the job fails. */
    if (rerun && ++m->deaths >= OCTANT_DEATHS) {
        fail(e, -EIO, "octant (%u,%u,%u) level %u killed its worker twice "
             "(worker %d)", m->task.x, m->task.y, m->task.z, m->task.level, i);
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
    int rc = spawn(e, i, err, sizeof err);
    if (rc) {
        fail(e, rc, "%s", err);
        if (m->busy) finish(e, i);
    }
}

static void check_workers(engine *e, int force)
{
    double now = now_s(CLOCK_MONOTONIC);
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
    if (e->job) return -EBUSY; /* a job checks its own workers */
    uint32_t restarts = e->restarts;
    e->error = 0;
    e->msg[0] = '\0';
    check_workers(e, 1);
    int rc = e->error ? e->error : (int)(e->restarts - restarts);
    /* Between jobs nothing else reads these: the next job starts afresh. */
    e->error = 0;
    e->restarts = restarts;
    return rc;
}

static int top_pending(const engine *e)
{
    for (int l = GRID_MAX_DEPTH; l > 0; l--)
        if (e->pending[l]) return l;
    return 0;
}

static void progress(engine *e, int force)
{
    const engine_job *job = e->job;
    if (!job->progress) return;
    double now = now_s(CLOCK_MONOTONIC);
    if (!force && now - e->last_progress < PROGRESS_EVERY) return;
    e->last_progress = now;
    double f = (double)e->done_vol / (double)e->total_vol;
    engine_progress p = {.fraction = f > 1.0 ? 1.0 : f,
                         .level = top_pending(e),
                         .voxels = e->tree.voxels,
                         .seconds = now - e->t0};
    job->progress(job->ud, &p);
}

static int cancelled(const engine *e)
{
    /* relaxed: see engine_job.cancel */
    return e->job->cancel &&
           atomic_load_explicit(e->job->cancel, memory_order_relaxed);
}

/* Figure 3's master loop. */
static int run_job(engine *e)
{
    for (;;) {
        int did = 0;
        for (int i = 0; i < e->n; i++)
            if (e->ms[i].busy) did += drain(e, i, 0);
        if (!e->error) did += assign(e);
        if (e->error) return e->error;
        if (e->nbusy == 0 && e->sp == 0) return 0;
        if (cancelled(e)) return fail(e, -ECANCELED, "the job was cancelled");
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
            shm_wake_if_sleeping(&slot(e, i)->wake, &slot(e, i)->sleeping);
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

/* A daemon's engine lives long: give back to tmpfs what the last big job
 * touched beyond the first keep bytes of the data area (kept warm for the
 * usual jobs).  The caller is about to overwrite all of it anyway. */
static void release_pages(engine *e)
{
    uint64_t keep = (e->h->data_off + e->keep + 4095) / 4096 * 4096;
    if (e->touched <= keep) return;
    madvise(e->seg.base + keep, e->touched - keep, MADV_REMOVE);
    e->touched = keep;
}

static void note_touched(engine *e, uint64_t end)
{
    if (end > e->touched) e->touched = end;
}

static int job_setup(engine *e, const engine_job *job)
{
    if (!job->tape) return fail(e, -EINVAL, "the job has no tape");
    if (grid_check(&job->grid))
        return fail(e, -EINVAL, "the job's grid is invalid");
    shm_header *h = e->h;
    size_t tb = expr_tape_bytes(job->tape);
    uint64_t end = h->data_off + h->data_bytes;
    uint64_t tree_off = (h->data_off + tb + 63) / 64 * 64;
    if (tree_off + 2 * sizeof(octree_cell) > end)
        return fail(e, -ENOMEM,
                    "the expression (%zu bytes compiled) leaves no room for "
                    "the octree; raise the shared memory size",
                    tb);
    uint64_t cap = (end - tree_off) / sizeof(octree_cell);
    release_pages(e);
    memcpy(shm_at(e->seg.base, h->data_off), job->tape, tb);
    h->gen = h->gen + 1 ? h->gen + 1 : 1;
    h->grid = job->grid;
    h->tape_off = h->data_off;
    h->tape_bytes = tb;
    h->tree_off = tree_off;
    h->tree_cap = cap > UINT32_MAX ? UINT32_MAX : (uint32_t)cap;
    int depth = job->grid.depth;
    octree_init(&e->tree, shm_at(e->seg.base, tree_off), h->tree_cap, depth);
    e->total_vol = volume(depth);
    e->split = job->split_level > 0 ? job->split_level
               : depth - 3 < 1      ? 1
               : depth - 3 > 6      ? 6
                                    : depth - 3;
    return push(e, grid_root(&job->grid));
}

static void job_reset(engine *e, const engine_job *job)
{
    e->job = job;
    e->error = 0;
    e->msg[0] = '\0';
    e->restarts = 0;
    e->stored = 0;
    e->have_tree = 0;
    e->sp = 0;
    e->done_vol = 0;
    memset(e->pending, 0, sizeof e->pending);
    e->t0 = now_s(CLOCK_MONOTONIC);
    e->last_progress = e->t0 - 1.0; /* the first call comes at once */
}

static void job_stats(engine *e, engine_result *r)
{
    uint64_t tested = 0, cpu = 0;
    for (int i = 0; i < e->n; i++) {
        shm_slot *s = slot(e, i);
        if (s->job_gen != e->h->gen) continue;
        tested += s->job_tested;
        cpu += s->job_cpu_ns;
    }
    r->octants = tested;
    r->worker_cpu = (double)cpu * 1e-9;
    r->restarts = e->restarts;
}

int engine_voxelize(engine *e, const engine_job *job, engine_result *r)
{
    double c0 = now_s(CLOCK_THREAD_CPUTIME_ID);
    memset(r, 0, sizeof *r);
    job_reset(e, job);
    check_workers(e, 1); /* any that died since the last job */
    int rc = e->error ? e->error : job_setup(e, job);
    if (!rc) rc = run_job(e);
    if (e->nbusy) abort_job(e);
    job_stats(e, r);
    if (e->tree.cells) /* octree_store clears whole blocks ahead */
        note_touched(e, e->h->tree_off +
                            (uint64_t)e->tree.block_end * sizeof(octree_cell));
    r->seconds = now_s(CLOCK_MONOTONIC) - e->t0;
    if (rc) {
        snprintf(r->error, sizeof r->error, "%s", e->msg);
    } else {
        e->have_tree = 1;
        r->voxels = e->tree.voxels;
        r->cells = e->tree.used;
        r->duplicates = e->stored - e->tree.voxels;
        progress(e, 1);
    }
    e->job = NULL; /* the caller's; nothing may use it after the return */
    r->master_cpu = now_s(CLOCK_THREAD_CPUTIME_ID) - c0;
    return rc;
}

/* ---- the VOD phase ---- */

static uint64_t align64(uint64_t v) { return (v + 63) / 64 * 64; }

/* Lay the VOD phase out behind the used cells; 0 or -ENOSPC. */
static int vod_plan(engine *e, const vod_params *p, const vod_layout *L,
                    char *err, size_t errlen)
{
    shm_header *h = e->h;
    shm_vod *v = &h->vod;
    uint64_t end = h->data_off + h->data_bytes;
    uint64_t agg = align64(h->tree_off + (uint64_t)e->tree.used *
                                             sizeof(octree_cell));
    uint64_t nodes = align64(agg + (uint64_t)e->tree.used * sizeof(uint32_t));
    if (nodes > end) goto full;
    e->tree.agg = shm_at(e->seg.base, agg);
    vod_aggregate(&e->tree, p->channel);
    uint64_t n = vod_collect(&e->tree, L, NULL, 0);
    v->recs_off = align64(nodes + n * sizeof(vod_node));
    v->offs_off = align64(v->recs_off + n * sizeof(vod_encoded));
    v->brick_off = align64(v->offs_off + n * sizeof(uint64_t));
    if (v->brick_off > end) goto full;
    vod_collect(&e->tree, L, shm_at(e->seg.base, nodes), n);
    memset(shm_at(e->seg.base, v->offs_off), 0xff, n * sizeof(uint64_t));
    v->L = *L;
    v->p = *p;
    v->p.metadata = NULL;
    v->cells_used = e->tree.used;
    v->depth = e->tree.depth;
    v->cells_off = h->tree_off;
    v->agg_off = agg;
    v->nodes_off = nodes;
    v->n = n;
    v->brick_cap = end - v->brick_off;
    /* relaxed: published to the workers by the task_seq release */
    atomic_store_explicit(&v->next, 0, memory_order_relaxed);
    atomic_store_explicit(&v->bump, 0, memory_order_relaxed);
    atomic_store_explicit(&v->error, 0, memory_order_relaxed);
    return 0;
full:
    snprintf(err, errlen,
             "no room left in shared memory for the VOD bricks; raise its "
             "size (now %zu MiB)",
             e->seg.bytes >> 20);
    return -ENOSPC;
}

/* Every worker encodes bricks until none is left. */
static void vod_encode_all(engine *e)
{
    e->error = 0;
    for (int i = 0; i < e->n; i++)
        if (e->ms[i].pid > 0)
            give(e, i, (grid_octant){0, 0, 0, 0}, SHM_TASK_ENCODE, 0);
    while (e->nbusy) {
        int did = 0;
        for (int i = 0; i < e->n; i++)
            if (e->ms[i].busy) did += drain(e, i, 1);
        if (!did) sleep_master(e);
        check_workers(e, 0);
    }
}

/* The records come from other processes: a missing (a worker died) or
 * malformed one is encoded again here, into memory of our own. */
static int vod_gather(engine *e, const vod_params *p, const uint8_t **data,
                      uint8_t **own)
{
    shm_vod *v = &e->h->vod;
    const vod_node *nodes = shm_at(e->seg.base, v->nodes_off);
    vod_encoded *recs = shm_at(e->seg.base, v->recs_off);
    const uint64_t *offs = shm_at(e->seg.base, v->offs_off);
    const uint8_t *bricks = shm_at(e->seg.base, v->brick_off);
    size_t bound = vod_encode_bound(&v->L, p);
    uint8_t *scratch = NULL;
    int rc = 0;
    for (uint64_t i = 0; i < v->n && !rc; i++) {
        uint64_t off = offs[i];
        uint32_t size = recs[i].size;
        if (off < v->brick_cap && size <= bound && size <= v->brick_cap - off) {
            data[i] = bricks + off;
            continue;
        }
        if (!scratch && !(scratch = malloc(v->L.raw_bytes))) rc = -ENOMEM;
        if (!rc && !(own[i] = malloc(bound))) rc = -ENOMEM;
        if (!rc)
            rc = vod_encode(&e->tree, &v->L, p, &nodes[i], scratch, own[i],
                            bound, &recs[i]);
        data[i] = own[i];
    }
    /* This thread encoded bricks: its cached deflate stream is this job's,
     * freed now as vod_write_octree frees its own (a daemon's engine thread
     * lives long, and an engine's caller need not know about the cache). */
    if (scratch) vod_encode_cleanup();
    free(scratch);
    return rc;
}

int engine_write_vod(engine *e, const vod_params *p, vod_sink *sink,
                     vod_stats *st, char *err, size_t errlen)
{
    if (!e->have_tree) {
        snprintf(err, errlen, "no octree to write: the last job failed or "
                              "there was none");
        return -EINVAL;
    }
    vod_layout L;
    int rc = vod_layout_make(p, e->tree.depth, &L, err, errlen);
    if (!rc) rc = vod_check_volume(&e->tree, p->volume, err, errlen);
    if (!rc) rc = vod_plan(e, p, &L, err, errlen);
    if (rc) return rc;
    /* A worker's failure leaves its bricks unrecorded: vod_gather() encodes
     * them here, so errors need no other handling. */
    vod_encode_all(e);
    shm_vod *v = &e->h->vod;
    /* relaxed: read after every worker's done_seq acquire */
    uint64_t used = atomic_load_explicit(&v->bump, memory_order_relaxed);
    note_touched(e, v->brick_off + (used < v->brick_cap ? used : v->brick_cap));
    const uint8_t **data = calloc(v->n ? v->n : 1, sizeof *data);
    uint8_t **own = calloc(v->n ? v->n : 1, sizeof *own);
    rc = data && own ? vod_gather(e, p, data, own) : -ENOMEM;
    if (rc)
        snprintf(err, errlen, "%s", strerror(-rc));
    else
        rc = vod_assemble(&v->L, p, v->n, shm_at(e->seg.base, v->nodes_off),
                          shm_at(e->seg.base, v->recs_off), data, sink, st, err, errlen);
    /* vod_assemble says its own failures; a sink's is told as its code */
    if (rc && !err[0]) snprintf(err, errlen, "%s", strerror(-rc));
    for (uint64_t i = 0; own && i < v->n; i++) free(own[i]);
    free(own);
    free(data);
    return rc;
}
