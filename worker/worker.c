/* The worker process: Figure 3's slave over the shared-memory slot. */
#include "worker.h"

#include <errno.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <time.h>
#include <unistd.h>

#include "shm.h"
#include "subdiv.h"
#include "vod.h"

#define WORKER_TIMEOUT_NS 1000000000L /* re-check the parent once a second */
#define ENCODE_CHUNK 8u               /* brick nodes claimed at a time */

typedef struct {
    uint8_t *base;
    shm_header *h;
    shm_slot *s;
    /* the job the vm is for */
    uint32_t gen;
    grid_spec grid;
    expr_vm *vm;
    subdiv_kernel k;
    uint64_t cpu0;
    /* the running task */
    uint32_t task_gen;
    uint32_t skip;
    shm_entry *cur;
    /* VOD phase scratch */
    uint8_t *scratch, *out;
    size_t scratch_bytes, out_bytes;
} worker;

static uint64_t cpu_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

static void check_parent(const worker *w)
{
    if (getppid() != w->h->master_pid) _exit(1);
}

static int aborted(const worker *w)
{
    /* relaxed: a flag checked between octants; the master's fence and
     * wake (shm_wake_if_sleeping) reach a worker that sleeps. */
    return atomic_load_explicit(&w->h->abort_gen, memory_order_relaxed) ==
           w->task_gen;
}

/* Wait for the next task (task_seq != last); returns its sequence number. */
static unsigned wait_task(worker *w, unsigned last)
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
        if (t == last) shm_futex_wait(&s->wake, v, WORKER_TIMEOUT_NS);
        shm_sleep_end(&s->sleeping);
        check_parent(w);
    }
}

static void ring_master(worker *w)
{
    shm_wake_if_sleeping(&w->h->doorbell, &w->h->master_sleeping);
}

/* ---- queue output ---- */

/* The element to fill next, waiting while the queue is full. */
static int entry_begin(worker *w, uint32_t kind)
{
    shm_slot *s = w->s;
    while (queue_space(&s->q) == 0) {
        if (aborted(w)) return -ECANCELED;
        unsigned v = shm_sleep_begin(&s->wake, &s->sleeping);
        if (queue_space(&s->q) == 0 && !aborted(w))
            shm_futex_wait(&s->wake, v, WORKER_TIMEOUT_NS);
        shm_sleep_end(&s->sleeping);
        check_parent(w);
    }
    w->cur = &s->ent[queue_head(&s->q)];
    w->cur->kind = kind;
    w->cur->count = 0;
    return 0;
}

/* Publish the element being filled (a re-run after a death skips the
 * entries the master already has: the kernel's output is deterministic). */
static int entry_end(worker *w)
{
    w->cur = NULL;
    if (w->skip) {
        w->skip--;
    } else {
        queue_publish(&w->s->q);
        ring_master(w);
    }
    return aborted(w) ? -ECANCELED : 0;
}

static int sink_octant(void *ud, const grid_octant *o)
{
    worker *w = ud;
    int rc = entry_begin(w, SHM_ENT_OCTANT);
    if (rc) return rc;
    w->cur->octant = *o;
    return entry_end(w);
}

/* Paper schedule: one voxel per entry, as in Figure 3. */
static int sink_voxel_one(void *ud, const grid_voxel *v)
{
    worker *w = ud;
    int rc = entry_begin(w, SHM_ENT_VOXELS);
    if (rc) return rc;
    w->cur->vox[0] = *v;
    w->cur->count = 1;
    return entry_end(w);
}

/* Subtree schedule: batches of SHM_BATCH voxels in preorder. */
static int sink_voxel_batch(void *ud, const grid_voxel *v)
{
    worker *w = ud;
    if (!w->cur) {
        int rc = entry_begin(w, SHM_ENT_VOXELS);
        if (rc) return rc;
    }
    w->cur->vox[w->cur->count++] = *v;
    return w->cur->count == SHM_BATCH ? entry_end(w) : 0;
}

static int sink_poll(void *ud)
{
    return aborted(ud) ? -ECANCELED : 0;
}

/* ---- tasks ---- */

/* First task of a job: a vm over the job's tape (in the segment). */
static int job_begin(worker *w)
{
    shm_header *h = w->h;
    if (w->vm) expr_vm_free(w->vm);
    w->vm = NULL;
    w->gen = 0;
    w->grid = h->grid;
    w->s->job_gen = w->s->task_gen;
    w->s->job_tested = 0;
    w->s->job_cpu_ns = 0;
    w->cpu0 = cpu_ns();
    if (grid_check(&w->grid)) return -EINVAL;
    const expr_tape *tape = shm_at(w->base, h->tape_off);
    int rc = expr_vm_new(tape, w->grid.depth, &w->vm);
    if (rc) return rc;
    subdiv_kernel_init(&w->k, w->vm, &w->grid);
    w->gen = w->s->task_gen;
    return 0;
}

static int run_subdiv(worker *w, uint32_t kind)
{
    shm_slot *s = w->s;
    if (aborted(w)) return -ECANCELED; /* handed out just before a cancel */
    if (w->gen != s->task_gen) {
        int rc = job_begin(w);
        if (rc) return rc;
    }
    subdiv_sink sink = {.octant = sink_octant, .poll = sink_poll, .ud = w};
    int rc;
    if (kind == SHM_TASK_CHILDREN) {
        sink.voxel = sink_voxel_one;
        rc = subdiv_children(&w->k, s->task, &sink);
    } else {
        sink.voxel = sink_voxel_batch;
        rc = subdiv_subtree(&w->k, s->task, &sink);
        if (rc == 0 && w->cur) rc = entry_end(w);
    }
    w->cur = NULL;
    s->job_tested = w->k.tested;
    s->job_cpu_ns = cpu_ns() - w->cpu0;
    return rc;
}

static int grow(uint8_t **p, size_t *have, size_t want)
{
    if (*have >= want) return 0;
    uint8_t *n = realloc(*p, want);
    if (!n) return -ENOMEM;
    *p = n;
    *have = want;
    return 0;
}

static void vod_fail(shm_vod *v, int rc)
{
    int zero = 0;
    /* relaxed: the master reads it after acquiring done_seq */
    atomic_compare_exchange_strong_explicit(&v->error, &zero, rc,
                                            memory_order_relaxed,
                                            memory_order_relaxed);
}

/* Encode node i into the shared brick area. */
static int encode_one(worker *w, const octree *t, uint64_t i)
{
    shm_vod *v = &w->h->vod;
    const vod_node *nodes = shm_at(w->base, v->nodes_off);
    vod_encoded *recs = shm_at(w->base, v->recs_off);
    uint64_t *offs = shm_at(w->base, v->offs_off);
    vod_encoded rec;
    int rc = vod_encode(t, &v->L, &v->p, &nodes[i], w->scratch, w->out,
                        w->out_bytes, &rec);
    if (rc) return rc;
    /* relaxed: only the uniqueness of the ranges matters; the bytes are
     * published to the master by the done_seq release. */
    uint64_t off = atomic_fetch_add_explicit(&v->bump, rec.size,
                                             memory_order_relaxed);
    /* Full: leave the node unrecorded, the master encodes it itself. */
    if (off > v->brick_cap || rec.size > v->brick_cap - off) return 0;
    memcpy((uint8_t *)shm_at(w->base, v->brick_off) + off, w->out, rec.size);
    recs[i] = rec;
    offs[i] = off;
    return 0;
}

static int run_encode(worker *w)
{
    shm_vod *v = &w->h->vod;
    int rc = grow(&w->scratch, &w->scratch_bytes, v->L.raw_bytes);
    if (!rc) rc = grow(&w->out, &w->out_bytes, vod_encode_bound(&v->L, &v->p));
    if (rc) {
        vod_fail(v, rc);
        return rc;
    }
    octree t;
    octree_view(&t, shm_at(w->base, v->cells_off), v->cells_used, v->depth);
    t.agg = shm_at(w->base, v->agg_off);
    for (;;) {
        /* relaxed: a counter that hands out disjoint chunks */
        uint64_t i0 = atomic_fetch_add_explicit(&v->next, ENCODE_CHUNK,
                                                memory_order_relaxed);
        if (i0 >= v->n) return 0;
        uint64_t end = i0 + ENCODE_CHUNK < v->n ? i0 + ENCODE_CHUNK : v->n;
        for (uint64_t i = i0; i < end; i++) {
            /* relaxed: stop early once anybody failed */
            if (atomic_load_explicit(&v->error, memory_order_relaxed)) return 0;
            if ((rc = encode_one(w, &t, i))) {
                vod_fail(v, rc);
                return rc;
            }
        }
    }
}

static _Noreturn void worker_exit(worker *w)
{
    if (w->vm) expr_vm_free(w->vm);
    free(w->scratch);
    free(w->out);
    _exit(0);
}

static void run_task(worker *w, unsigned seq)
{
    shm_slot *s = w->s;
    uint32_t kind = s->task_kind;
    w->task_gen = s->task_gen;
    w->skip = s->task_skip;
    int rc;
    switch (kind) {
    case SHM_TASK_CHILDREN:
    case SHM_TASK_SUBTREE: rc = run_subdiv(w, kind); break;
    case SHM_TASK_ENCODE: rc = run_encode(w); break;
    case SHM_TASK_EXIT: worker_exit(w);
    default: rc = -EINVAL; break;
    }
    s->error = rc == -ECANCELED ? 0 : rc;
    /* release: publishes the task's last entries, counters and error
     * (and, for encoding, its records and bricks) to the master's acquire
     * load of done_seq. */
    atomic_store_explicit(&s->done_seq, seq, memory_order_release);
    ring_master(w);
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
    worker w;
    memset(&w, 0, sizeof w);
    w.base = base;
    w.h = shm_hdr(base);
    w.s = shm_slot_at(base, index);
    /* Die with the master (the thread that forked us, strictly), and make
     * sure it did not die before the request took effect. */
    prctl(PR_SET_PDEATHSIG, SIGKILL);
    check_parent(&w);
    reset_signals();
    close_inherited();
    /* relaxed: a fresh worker starts from the slot as its predecessor (or
     * the master, at creation) left it; the fork orders everything. */
    unsigned last = atomic_load_explicit(&w.s->done_seq, memory_order_relaxed);
    for (;;) {
        unsigned seq = wait_task(&w, last);
        run_task(&w, seq);
        last = seq;
    }
}
