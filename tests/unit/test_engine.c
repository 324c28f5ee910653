/* The master–worker engine against the serial algorithm: the same voxels,
 * bit for bit, for every shape, schedule, split level and worker count;
 * cancel, worker deaths, small segments, VOD bytes, process and segment
 * hygiene, CPU pinning. */
#include <criterion/criterion.h>
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "engine.h"
#include "expr.h"
#include "kinds.h"
#include "octree.h"
#include "shm.h"
#include "subdiv.h"
#include "vod.h"
#include "voxel.h"

#define SPHERE "sqrt(x^2 + y^2 + z^2) - 0.8"
#define TORUS "sqrt((sqrt(x^2 + y^2) - 0.6)^2 + z^2) - 0.25"
#define SPHERES                                                               \
    "min(sqrt((x-0.3)^2+y^2+z^2)-0.35, sqrt((x+0.3)^2+y^2+z^2)-0.3,"          \
    " sqrt(x^2+(y-0.4)^2+z^2)-0.25, sqrt(x^2+(y+0.45)^2+(z-0.1)^2)-0.3,"       \
    " sqrt((x-0.5)^2+(y-0.5)^2+(z-0.5)^2)-0.2, sqrt(x^2+y^2+(z+0.6)^2)-0.3)"
#define SCENE2 "sin(4*theta)*sin(8*phi) - r"

static expr_tape *compile(const char *src)
{
    expr_tape *t = NULL;
    expr_error ee;
    cr_assert_eq(expr_compile(src, strlen(src), NULL, &t, &ee), 0, "%s", ee.msg);
    return t;
}

static grid_spec grid(uint32_t res)
{
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    grid_spec g;
    char err[200];
    cr_assert_eq(grid_make(lo, hi, res, &g, err, sizeof err), 0, "%s", err);
    return g;
}

typedef struct {
    octree t;
    octree_cell *arena;
    uint64_t tested;
} ref_tree;

static int ref_store(void *ud, const grid_voxel *v)
{
    return octree_store(ud, v->x, v->y, v->z, v->value);
}

/* The serial reference, through subdiv_serial, and its test count through
 * the same kernel (which must give the same voxels). */
static void reference(const expr_tape *tape, const grid_spec *g, ref_tree *r)
{
    uint32_t cap = 1u << 20;
    r->arena = malloc(octree_arena_bytes(cap));
    cr_assert(r->arena);
    octree_init(&r->t, r->arena, cap, g->depth);
    cr_assert_eq(subdiv_serial(tape, g, &r->t), 0);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(tape, g->depth, &vm), 0);
    subdiv_kernel k;
    subdiv_kernel_init(&k, vm, g);
    octree t2;
    octree_cell *a2 = malloc(octree_arena_bytes(cap));
    octree_init(&t2, a2, cap, g->depth);
    subdiv_sink s = {.voxel = ref_store, .ud = &t2};
    cr_assert_eq(subdiv_subtree(&k, grid_root(g), &s), 0);
    cr_assert_eq(t2.voxels, r->t.voxels);
    r->tested = k.tested;
    expr_vm_free(vm);
    free(a2);
}

static void assert_same(const octree *a, const octree *b, const char *what)
{
    octree_iter ia, ib;
    octree_iter_init(&ia, a);
    octree_iter_init(&ib, b);
    uint32_t x, y, z, v, x2, y2, z2, v2;
    uint64_t n = 0;
    for (;;) {
        bool ma = octree_iter_next(&ia, &x, &y, &z, &v);
        bool mb = octree_iter_next(&ib, &x2, &y2, &z2, &v2);
        cr_assert_eq(ma, mb, "%s: voxel counts differ after %llu", what,
                     (unsigned long long)n);
        if (!ma) break;
        cr_assert(x == x2 && y == y2 && z == z2 && v == v2,
                  "%s: voxel %llu: (%u %u %u %08x) vs (%u %u %u %08x)", what,
                  (unsigned long long)n, x, y, z, v, x2, y2, z2, v2);
        n++;
    }
    cr_assert(n > 0 && n == a->voxels && n == b->voxels, "%s", what);
}

static int pinned_cpu(pid_t pid);

static engine *make_engine(int workers, size_t shm_bytes)
{
    engine_opts o = {.workers = workers, .shm_bytes = shm_bytes};
    engine *e;
    char err[256] = "";
    cr_assert_eq(engine_create(&o, &e, err, sizeof err), 0, "%s", err);
    return e;
}

static void run(engine *e, const expr_tape *tape, const grid_spec *g,
                engine_schedule s, int split, engine_result *r)
{
    engine_job job = {.tape = tape, .grid = *g, .schedule = s, .split_level = split};
    int rc = engine_voxelize(e, &job, r);
    cr_assert_eq(rc, 0, "engine_voxelize: %d %s", rc, r->error);
}

/* Every worker count and schedule against the serial algorithm. */
static void identity(const char *src, uint32_t res, int max_workers)
{
    expr_tape *tape = compile(src);
    grid_spec g = grid(res);
    ref_tree ref;
    reference(tape, &g, &ref);
    for (int w = 1; w <= max_workers; w++) {
        engine *e = make_engine(w, 0);
        for (int s = 0; s < 2; s++) {
            engine_result r;
            run(e, tape, &g, (engine_schedule)s, 0, &r);
            char what[128];
            snprintf(what, sizeof what, "%s %u^3, %d workers, schedule %d", src, res, w, s);
            assert_same(&ref.t, engine_octree(e), what);
            cr_assert_eq(r.voxels, ref.t.voxels, "%s", what);
            cr_assert_eq(r.octants, ref.tested, "%s: tested %llu vs %llu", what,
                         (unsigned long long)r.octants, (unsigned long long)ref.tested);
            cr_assert_eq(r.cells, engine_octree(e)->used);
            cr_assert_eq(r.restarts, 0);
            cr_assert_eq(r.duplicates, 0);
            cr_assert(r.worker_cpu > 0 && r.master_cpu > 0 && r.seconds > 0);
        }
        engine_destroy(e);
    }
    free(ref.arena);
    expr_tape_free(tape);
}

Test(engine, sphere_identical_to_serial) { identity(SPHERE, 64, 3); }
Test(engine, torus_identical_to_serial) { identity(TORUS, 64, 3); }
Test(engine, min_of_spheres_identical_to_serial) { identity(SPHERES, 64, 3); }
Test(engine, scene2_identical_to_serial) { identity(SCENE2, 64, 3); }

Test(engine, scene2_128_and_split_levels)
{
    expr_tape *tape = compile(SCENE2);
    grid_spec g = grid(128);
    ref_tree ref;
    reference(tape, &g, &ref);
    engine *e = make_engine(2, 0);
    const int splits[] = {0, 1, 3, 7, 9};
    for (int i = 0; i < 5; i++) {
        engine_result r;
        run(e, tape, &g, ENGINE_SCHED_SUBTREE, splits[i], &r);
        assert_same(&ref.t, engine_octree(e), "split");
        cr_assert_eq(r.octants, ref.tested);
    }
    engine_result r;
    run(e, tape, &g, ENGINE_SCHED_PAPER, 0, &r);
    assert_same(&ref.t, engine_octree(e), "paper 128");
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}

/* Different grids and shapes one after the other on one engine, including a
 * non-power-of-two box domain. */
Test(engine, jobs_in_a_row_reuse_the_workers)
{
    engine *e = make_engine(2, 0);
    int pid0 = engine_worker_pid(e, 0);
    const char *src[] = {SPHERE, TORUS, SPHERES};
    const uint32_t res[] = {32, 100, 16};
    for (int k = 0; k < 3; k++) {
        expr_tape *tape = compile(src[k]);
        double lo[3] = {-1, -1, -0.4}, hi[3] = {1, 0.9, 0.4};
        grid_spec g;
        char err[200];
        cr_assert_eq(grid_make(lo, hi, res[k], &g, err, sizeof err), 0);
        ref_tree ref;
        reference(tape, &g, &ref);
        engine_result r;
        run(e, tape, &g, (engine_schedule)(k & 1), 0, &r);
        assert_same(&ref.t, engine_octree(e), src[k]);
        free(ref.arena);
        expr_tape_free(tape);
    }
    cr_assert_eq(engine_worker_pid(e, 0), pid0, "workers live across jobs");
    engine_destroy(e);
}

/* ---- the queue and the sleeping protocol, between two threads ---- */

#include <pthread.h>

#define QN 200000u

typedef struct {
    queue_idx q;
    uint32_t ent[QUEUE_ENTRIES];
    atomic_uint wake_p, wake_c; /* futex words: producer's, consumer's */
    atomic_int sleep_p, sleep_c;
    uint64_t sum;
    int order_ok;
} qtest;

/* Both sides wait without a timeout: a lost wakeup hangs the test, which
 * the timeout then fails. */
static void *producer(void *ud)
{
    qtest *t = ud;
    for (uint32_t i = 1; i <= QN; i++) {
        while (queue_space(&t->q) == 0) {
            unsigned v = shm_sleep_begin(&t->wake_p, &t->sleep_p);
            if (queue_space(&t->q) == 0) shm_futex_wait(&t->wake_p, v, 0);
            shm_sleep_end(&t->sleep_p);
        }
        t->ent[queue_head(&t->q)] = i;
        queue_publish(&t->q);
        shm_wake_if_sleeping(&t->wake_c, &t->sleep_c);
    }
    return NULL;
}

Test(engine, queue_and_futexes_lose_nothing, .timeout = 60)
{
    qtest *t = calloc(1, sizeof *t);
    t->order_ok = 1;
    pthread_t th;
    cr_assert_eq(pthread_create(&th, NULL, producer, t), 0);
    uint32_t expect = 1;
    while (expect <= QN) {
        unsigned n = queue_ready(&t->q);
        if (n == 0) {
            unsigned v = shm_sleep_begin(&t->wake_c, &t->sleep_c);
            if (queue_ready(&t->q) == 0) shm_futex_wait(&t->wake_c, v, 0);
            shm_sleep_end(&t->sleep_c);
            continue;
        }
        cr_assert_leq(n, QUEUE_ENTRIES);
        for (unsigned k = 0; k < n; k++) {
            uint32_t v = t->ent[(queue_tail(&t->q) + k) % QUEUE_ENTRIES];
            t->order_ok &= v == expect++;
            t->sum += v;
        }
        queue_consumed(&t->q, n);
        shm_wake_if_sleeping(&t->wake_p, &t->sleep_p);
    }
    pthread_join(th, NULL);
    cr_assert(t->order_ok);
    cr_assert_eq(t->sum, (uint64_t)QN * (QN + 1) / 2);
    free(t);
}

/* ---- progress and cancel ---- */

typedef struct {
    int calls;
    double last_fraction;
    int last_level;
    uint64_t last_voxels;
    int monotonic;
    atomic_int *cancel;
    engine *kill_in;      /* kill worker 0 of this engine at the first call */
    int killed;
} watch;

static void on_progress(void *ud, const engine_progress *p)
{
    watch *w = ud;
    if (p->fraction < w->last_fraction || p->fraction > 1.0) w->monotonic = 0;
    w->calls++;
    w->last_fraction = p->fraction;
    w->last_level = p->level;
    w->last_voxels = p->voxels;
    if (w->cancel) atomic_store(w->cancel, 1);
    if (w->kill_in && !w->killed) {
        cr_assert_eq(kill(engine_worker_pid(w->kill_in, 0), SIGKILL), 0);
        w->killed = 1;
    }
}

Test(engine, progress_ends_complete)
{
    expr_tape *tape = compile(SPHERE);
    grid_spec g = grid(64);
    engine *e = make_engine(2, 0);
    watch w = {.monotonic = 1};
    engine_job job = {.tape = tape, .grid = g, .progress = on_progress, .ud = &w};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), 0);
    cr_assert(w.calls >= 2 && w.monotonic);
    cr_assert_float_eq(w.last_fraction, 1.0, 1e-12);
    cr_assert_eq(w.last_level, 0);
    cr_assert_eq(w.last_voxels, r.voxels);
    engine_destroy(e);
    expr_tape_free(tape);
}

Test(engine, cancel_then_next_job_is_correct)
{
    expr_tape *tape = compile(SCENE2);
    grid_spec g = grid(128);
    ref_tree ref;
    reference(tape, &g, &ref);
    engine *e = make_engine(2, 0);
    for (int s = 0; s < 2; s++) {
        atomic_int cancel = 0;
        watch w = {.monotonic = 1, .cancel = &cancel};
        engine_job job = {.tape = tape, .grid = g, .schedule = (engine_schedule)s,
                          .progress = on_progress, .ud = &w, .cancel = &cancel};
        engine_result r;
        cr_assert_eq(engine_voxelize(e, &job, &r), -ECANCELED);
        cr_assert_eq(r.failure, ENGINE_CANCELLED);
        cr_assert(strstr(r.error, "cancel"), "%s", r.error);
        cr_assert_null(engine_octree(e));
        /* cancelled before it starts */
        cr_assert_eq(engine_voxelize(e, &job, &r), -ECANCELED);
        run(e, tape, &g, (engine_schedule)s, 0, &r);
        assert_same(&ref.t, engine_octree(e), "after cancel");
    }
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}

/* ---- worker deaths ---- */

/* Waits (60 s at most, for a loaded machine) until a killed child is dead:
 * a zombie, not yet reaped, so that the engine finds it dead. */
static int is_dead(pid_t pid) /* a zombie, or gone */
{
    char path[64], buf[256];
    snprintf(path, sizeof path, "/proc/%d/stat", (int)pid);
    FILE *f = fopen(path, "r");
    if (!f) return 1;
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = 0;
    const char *rp = strrchr(buf, ')');
    return rp && rp[1] == ' ' && rp[2] == 'Z';
}

static void wait_dead(pid_t pid)
{
    for (int k = 0; k < 6000; k++) {
        if (is_dead(pid)) return;
        usleep(10000);
    }
    cr_assert_fail("worker %d still alive 60 s after SIGKILL", (int)pid);
}

Test(engine, a_dead_worker_is_replaced_and_its_octant_redone)
{
    expr_tape *tape = compile(SPHERES);
    grid_spec g = grid(128);
    ref_tree ref;
    reference(tape, &g, &ref);
    engine *e = make_engine(2, 0);
    /* dead between jobs */
    int old = engine_worker_pid(e, 1);
    cr_assert_eq(kill(old, SIGKILL), 0);
    wait_dead(old);
    engine_result r;
    run(e, tape, &g, ENGINE_SCHED_SUBTREE, 0, &r);
    assert_same(&ref.t, engine_octree(e), "after an idle death");
    cr_assert_eq(r.restarts, 1);
    cr_assert_neq(engine_worker_pid(e, 1), old);
    /* dead during a job, in both schedules */
    for (int s = 0; s < 2; s++) {
        watch w = {.monotonic = 1, .kill_in = e};
        engine_job job = {.tape = tape, .grid = g, .schedule = (engine_schedule)s,
                          .progress = on_progress, .ud = &w};
        cr_assert_eq(engine_voxelize(e, &job, &r), 0, "%s", r.error);
        cr_assert(w.killed);
        cr_assert_geq(r.restarts, 1);
        assert_same(&ref.t, engine_octree(e), "after a death in a job");
        cr_assert_eq(r.voxels, ref.t.voxels);
    }
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}

static void check_inside_a_job(void *ud, const engine_progress *p)
{
    (void)p;
    cr_assert_eq(engine_check_workers(ud), -EBUSY);
}

/* Between jobs, engine_check_workers reaps a dead worker and forks it again
 * on its CPU at once; nothing to do is 0; inside a job it refuses. */
Test(engine, check_workers_between_jobs)
{
    expr_tape *tape = compile(SPHERES);
    grid_spec g = grid(64);
    ref_tree ref;
    reference(tape, &g, &ref);
    engine *e = make_engine(2, (size_t)64 << 20);
    cr_assert_eq(engine_check_workers(e), 0);
    int old = engine_worker_pid(e, 1), cpu = engine_worker_cpu(e, 1);
    cr_assert_eq(kill(old, SIGKILL), 0);
    int rc = 0;
    for (int k = 0; k < 6000 && rc == 0; k++) { /* 60 s at most: a loaded machine */
        rc = engine_check_workers(e);
        if (!rc) usleep(10000);
    }
    cr_assert_eq(rc, 1);
    int fresh = engine_worker_pid(e, 1);
    cr_assert(fresh > 0 && fresh != old);
    cr_assert_eq(kill(fresh, 0), 0, "the new worker lives");
    cr_assert_eq(pinned_cpu(fresh), cpu);
    errno = 0;
    cr_assert_eq(waitpid(old, NULL, WNOHANG), -1, "the dead one was reaped");
    cr_assert_eq(errno, ECHILD);
    cr_assert_eq(engine_check_workers(e), 0);
    engine_result r;
    engine_job job = {.tape = tape, .grid = g, .progress = check_inside_a_job, .ud = e};
    cr_assert_eq(engine_voxelize(e, &job, &r), 0, "%s", r.error);
    cr_assert_eq(r.restarts, 0, "nothing left to restart when the job started");
    assert_same(&ref.t, engine_octree(e), "after a worker forked again between jobs");
    cr_assert_eq(engine_worker_pid(e, 1), fresh);
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}

/* One worker, the whole grid as one subtree: stop the worker once its
 * queue is full, let the master take those entries, then kill it.  The new
 * worker redoes the subtree and must skip exactly what was taken. */
typedef struct {
    engine *e;
    int calls;
} stopper;

static void stop_then_kill(void *ud, const engine_progress *p)
{
    stopper *s = ud;
    (void)p;
    pid_t pid = engine_worker_pid(s->e, 0);
    if (s->calls == 0) {
        usleep(50000); /* the worker fills its 8 entries and waits */
        cr_assert_eq(kill(pid, SIGSTOP), 0);
    } else if (s->calls == 1) {
        cr_assert_eq(kill(pid, SIGKILL), 0);
    }
    s->calls++;
}

Test(engine, a_worker_killed_mid_subtree_resumes_without_duplicates)
{
    expr_tape *tape = compile(SPHERE);
    grid_spec g = grid(256);
    ref_tree ref;
    reference(tape, &g, &ref);
    engine *e = make_engine(1, 0);
    stopper st = {.e = e};
    engine_job job = {.tape = tape, .grid = g, .split_level = g.depth,
                      .progress = stop_then_kill, .ud = &st};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), 0, "%s", r.error);
    cr_assert_geq(st.calls, 2);
    cr_assert_eq(r.restarts, 1);
    cr_assert_eq(r.duplicates, 0);
    assert_same(&ref.t, engine_octree(e), "after a death mid-subtree");
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}

/* A slow job (a sphere with many wobbles: a long tape nothing prunes), so
 * that a task outlives the progress callbacks that kill its workers. */
static expr_tape *compile_slow(void)
{
    char src[4096];
    int n = snprintf(src, sizeof src, "sqrt(x^2+y^2+z^2)-0.8");
    for (int i = 1; i < 40; i++)
        n += snprintf(src + n, sizeof src - (size_t)n, "+0.001*sin(%d*x+%d*y+%d*z)", i,
                      i + 1, i + 2);
    return compile(src);
}

/* Kill worker 0 at some progress calls: `every` calls apart, each time a
 * worker forked since the last kill, until `kills`; then cancel, if asked. */
typedef struct {
    engine *e;
    int every, kills, calls, n;
    pid_t last;
    atomic_int *cancel;
} killer;

static void kill_worker0(void *ud, const engine_progress *p)
{
    killer *k = ud;
    (void)p;
    pid_t pid = engine_worker_pid(k->e, 0);
    if (k->n == k->kills) {
        if (k->cancel && pid > 0 && pid != k->last) atomic_store(k->cancel, 1);
    } else if (k->calls % k->every == 0 && pid > 0 && pid != k->last) {
        usleep(50000); /* well inside its task (the queue may fill: it waits) */
        cr_assert_eq(kill(pid, SIGKILL), 0);
        k->last = pid;
        k->n++;
    }
    k->calls++;
}

/* The octant itself is the suspect when the worker re-running it dies too:
 * the second death on one octant fails the job (ENGINE_CRASHED, the
 * octant named),
 * and the engine goes on with the next job. */
Test(engine, an_octant_that_kills_its_worker_twice_fails_the_job)
{
    expr_tape *slow = compile_slow(), *tape = compile(SPHERE);
    grid_spec gs = grid(128), g = grid(64);
    ref_tree ref;
    reference(tape, &g, &ref);
    engine *e = make_engine(1, 0);
    /* one task: the whole grid as one subtree, so both deaths are on it */
    killer k = {.e = e, .every = 1, .kills = 2};
    engine_job job = {.tape = slow, .grid = gs, .split_level = gs.depth,
                      .progress = kill_worker0, .ud = &k};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), -EIO, "%s", r.error);
    cr_assert_eq(r.failure, ENGINE_CRASHED);
    cr_assert_eq(k.n, 2);
    cr_assert_eq(r.restarts, 2);
    cr_assert(strstr(r.error, "octant (0,0,0) level 7 killed its worker twice"), "%s",
              r.error);
    cr_assert_null(engine_octree(e));
    run(e, tape, &g, ENGINE_SCHED_SUBTREE, 0, &r);
    cr_assert_eq(r.restarts, 0);
    assert_same(&ref.t, engine_octree(e), "the job after a failed one");
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
    expr_tape_free(slow);
}

/* Deaths on different octants of one job each re-run their octant only,
 * however many: four deaths of the one worker, 0.2 s apart on octants of
 * microseconds (the paper schedule), and the job is still running when it
 * is cancelled. */
Test(engine, deaths_on_different_octants_do_not_fail_the_job)
{
    expr_tape *slow = compile_slow();
    /* 256^3: the job outlasts its four kills (it is cancelled after them)
     * however slowly a loaded machine makes the progress calls come */
    grid_spec g = grid(256);
    engine *e = make_engine(1, 0);
    atomic_int cancel = 0;
    killer k = {.e = e, .every = 2, .kills = 4, .cancel = &cancel};
    engine_job job = {.tape = slow, .grid = g, .schedule = ENGINE_SCHED_PAPER,
                      .progress = kill_worker0, .ud = &k, .cancel = &cancel};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), -ECANCELED, "%s", r.error);
    cr_assert_eq(k.n, 4);
    cr_assert_eq(r.restarts, 4);
    engine_destroy(e);
    expr_tape_free(slow);
}

/* ---- liveness: stalled workers, cancels that never wait ---- */

static engine *make_engine_stall(int workers, double stall)
{
    engine_opts o = {.workers = workers, .stall_timeout = stall};
    engine *e;
    char err[256] = "";
    cr_assert_eq(engine_create(&o, &e, err, sizeof err), 0, "%s", err);
    return e;
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* SIGSTOP worker 0 at the progress calls: each worker forked since the
 * last stop, `stops` times; then cancel, if asked, once a worker forked
 * after the last stop runs (or at once, `cancel_now`). */
typedef struct {
    engine *e;
    int stops, n, cancel_now;
    pid_t last;
    atomic_int *cancel;
    double t_cancel;
} stopper2;

static void stop_worker0(void *ud, const engine_progress *p)
{
    stopper2 *k = ud;
    (void)p;
    pid_t pid = engine_worker_pid(k->e, 0);
    if (k->n < k->stops) {
        if (pid > 0 && pid != k->last) {
            usleep(50000); /* inside its task */
            cr_assert_eq(kill(pid, SIGSTOP), 0);
            k->last = pid;
            k->n++;
        }
    } else if (k->cancel && !k->t_cancel) {
        usleep(300000); /* the stopped worker is quiet for a while */
        k->t_cancel = now_s();
        atomic_store(k->cancel, 1);
    }
}

/* A worker stopped mid-task is found by its heartbeat, killed and forked
 * again; its task is run again and the job comes out identical, with no
 * voxel twice. */
Test(engine, a_stopped_worker_is_replaced_and_the_job_completes, .timeout = 120)
{
    expr_tape *tape = compile(SPHERES);
    grid_spec g = grid(128);
    ref_tree ref;
    reference(tape, &g, &ref);
    /* 5 s: long enough that a worker starved of CPU on a loaded machine
     * (ASan, 2 cores) is not taken for a stopped one */
    engine *e = make_engine_stall(2, 5.0);
    for (int s = 0; s < 2; s++) {
        stopper2 k = {.e = e, .stops = 1};
        engine_job job = {.tape = tape, .grid = g, .schedule = (engine_schedule)s,
                          .progress = stop_worker0, .ud = &k};
        engine_result r;
        double t0 = now_s();
        cr_assert_eq(engine_voxelize(e, &job, &r), 0, "%s", r.error);
        cr_assert_eq(k.n, 1);
        cr_assert_eq(r.stalls, 1);
        cr_assert_geq(r.restarts, 1);
        cr_assert_eq(r.duplicates, 0);
        cr_assert_lt(now_s() - t0, 60.0);
        assert_same(&ref.t, engine_octree(e), "after a stalled worker");
        engine_worker_info in;
        cr_assert_eq(engine_worker_info_get(e, 0, &in), 0);
        cr_assert_eq(in.stalls, (uint32_t)s + 1);
        cr_assert_eq(in.stalled_pid, k.last);
        cr_assert_eq(in.stalled_state, 'T');
        cr_assert_geq(in.stalled_quiet, 5.0);
        cr_assert_neq(in.pid, k.last);
        cr_assert_eq(in.state, ENGINE_WORKER_IDLE);
        errno = 0;
        cr_assert_eq(waitpid(k.last, NULL, WNOHANG), -1, "the stopped one was reaped");
    }
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}

/* A stall is a death of its task: a task that stalls its worker twice
 * fails the job, which names it. */
Test(engine, a_task_that_stalls_its_worker_twice_fails_the_job, .timeout = 120)
{
    expr_tape *slow = compile_slow();
    grid_spec g = grid(128);
    engine *e = make_engine_stall(1, 4.0); /* see the test above */
    stopper2 k = {.e = e, .stops = 2};
    engine_job job = {.tape = slow, .grid = g, .split_level = g.depth,
                      .progress = stop_worker0, .ud = &k};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), -EIO, "%s", r.error);
    cr_assert_eq(r.failure, ENGINE_CRASHED);
    cr_assert_eq(r.stalls, 2);
    cr_assert(strstr(r.error, "octant (0,0,0) level 7 stalled or killed its worker twice"),
              "%s", r.error);
    engine_destroy(e);
    expr_tape_free(slow);
}

/* Times a process's death (deathwatch.t_dead, 0 if not seen by stop). */
typedef struct {
    pid_t pid;
    double t0, t_dead;
    atomic_int stop; /* set by the test once destroy returned; read here */
} deathwatch;

static void *watch_death(void *ud)
{
    deathwatch *w = ud;
    for (;;) {
        if (is_dead(w->pid)) {
            w->t_dead = now_s();
            return NULL;
        }
        if (atomic_load(&w->stop)) {
            /* reaped just now? destroy waits for its workers */
            if (is_dead(w->pid)) w->t_dead = now_s();
            return NULL;
        }
        usleep(1000);
    }
}

/* A cancel while a worker is stopped (and stalls are never detected) is
 * answered at once: the worker that does not let go is killed, the next
 * job gets a fresh one. */
Test(engine, a_cancel_never_waits_on_a_stopped_worker, .timeout = 60)
{
    expr_tape *slow = compile_slow(), *tape = compile(SPHERE);
    grid_spec gs = grid(128), g = grid(64);
    ref_tree ref;
    reference(tape, &g, &ref);
    engine *e = make_engine_stall(2, -1);
    atomic_int cancel = 0;
    stopper2 k = {.e = e, .stops = 1, .cancel = &cancel};
    engine_job job = {.tape = slow, .grid = gs, .progress = stop_worker0, .ud = &k,
                      .cancel = &cancel};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), -ECANCELED, "%s", r.error);
    double waited = now_s() - k.t_cancel;
    cr_assert(k.t_cancel > 0);
    cr_assert_lt(waited, 5.0, "the cancel waited %.2f s", waited);
    cr_assert_eq(r.stalls, 0, "stall detection is off");
    engine_worker_info in;
    cr_assert_eq(engine_worker_info_get(e, 0, &in), 0);
    cr_assert_eq(in.unanswered, 1);
    cr_assert_neq(in.pid, k.last);
    run(e, tape, &g, ENGINE_SCHED_SUBTREE, 0, &r);
    assert_same(&ref.t, engine_octree(e), "the job after");
    /* and destroying an engine with a stopped idle worker does not wait
     * for it either: it dies before the 2 s engine_destroy gives a worker
     * that does not run (EXIT_WAIT_S).  Its death is timed by a thread
     * that watches it, apart from destroy's other work, which a loaded
     * machine makes slow. */
    deathwatch dw = {.pid = engine_worker_pid(e, 1)};
    cr_assert_eq(kill(dw.pid, SIGSTOP), 0);
    pthread_t th;
    dw.t0 = now_s();
    cr_assert_eq(pthread_create(&th, NULL, watch_death, &dw), 0);
    engine_destroy(e);
    atomic_store(&dw.stop, 1);
    pthread_join(th, NULL);
    cr_assert(dw.t_dead > 0, "the stopped worker outlived engine_destroy");
    cr_assert_lt(dw.t_dead - dw.t0, 1.9, "the stopped worker died after %.2f s",
                 dw.t_dead - dw.t0);
    free(ref.arena);
    expr_tape_free(tape);
    expr_tape_free(slow);
}

/* ---- errors ---- */

Test(engine, small_segments_give_clear_errors)
{
    engine_opts o = {.workers = 2, .shm_bytes = 1 << 20};
    engine *e;
    char err[256] = "";
    cr_assert_eq(engine_create(&o, &e, err, sizeof err), -ENOSPC);
    cr_assert(strstr(err, "too small"), "%s", err);
    /* big enough to start, too small for a 256^3 sphere's octree */
    e = make_engine(2, shm_min_bytes(2));
    expr_tape *tape = compile(SPHERE);
    grid_spec g = grid(256);
    engine_job job = {.tape = tape, .grid = g};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), -ENOMEM);
    cr_assert_eq(r.failure, ENGINE_LIMIT);
    cr_assert(strstr(r.error, "octree needs more than") &&
              strstr(r.error, "raise the shared memory size"), "%s", r.error);
    cr_assert_null(engine_octree(e));
    /* and a small job still runs on it */
    g = grid(32);
    ref_tree ref;
    reference(tape, &g, &ref);
    run(e, tape, &g, ENGINE_SCHED_SUBTREE, 0, &r);
    assert_same(&ref.t, engine_octree(e), "small job after ENOMEM");
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}

Test(engine, bad_arguments)
{
    engine_opts o = {.workers = 0};
    engine *e;
    char err[256] = "";
    cr_assert_eq(engine_create(&o, &e, err, sizeof err), -EINVAL);
    cr_assert(strstr(err, "workers"), "%s", err);
    int cpus[1] = {-3};
    engine_opts o2 = {.workers = 1, .cpus = cpus, .ncpus = 1};
    cr_assert_eq(engine_create(&o2, &e, err, sizeof err), -EINVAL);
    cr_assert(strstr(err, "CPU -3"), "%s", err);
    engine_opts o3 = {.workers = 1, .shm_name = "no-slash"};
    cr_assert_eq(engine_create(&o3, &e, err, sizeof err), -EINVAL);
    e = make_engine(1, 0);
    expr_tape *tape = compile(SPHERE);
    grid_spec g = grid(32);
    g.depth = 9;
    engine_job job = {.tape = tape, .grid = g};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), -EINVAL);
    cr_assert_eq(r.failure, ENGINE_BAD_JOB);
    cr_assert(strstr(r.error, "grid"), "%s", r.error);
    vod_params p;
    vod_params_default(&p);
    vod_sink sink = {NULL, NULL};
    engine_error ee;
    cr_assert_eq(engine_write_vod(e, &p, &sink, NULL, &ee), -EINVAL);
    cr_assert_eq(ee.failure, ENGINE_BAD_JOB);
    cr_assert(strstr(ee.message, "nothing to write"), "%s", ee.message);
    engine_destroy(e);
    expr_tape_free(tape);
}

/* ---- processes, segments, pinning ---- */

static int shm_entries_of(pid_t pid, const char *prefix)
{
    char want[64];
    snprintf(want, sizeof want, "%s%d.", prefix, (int)pid);
    DIR *d = opendir("/dev/shm");
    if (!d) return 0;
    int n = 0;
    struct dirent *de;
    while ((de = readdir(d)))
        n += strncmp(de->d_name, want, strlen(want)) == 0;
    closedir(d);
    return n;
}

Test(engine, create_destroy_leaves_nothing)
{
    pid_t pids[3 * 25];
    int np = 0;
    for (int k = 0; k < 25; k++) {
        engine *e = make_engine(3, (size_t)16 << 20);
        for (int i = 0; i < 3; i++) {
            pids[np] = engine_worker_pid(e, i);
            cr_assert_gt(pids[np], 0);
            cr_assert_eq(kill(pids[np], 0), 0, "worker alive");
            np++;
        }
        /* private segments are unlinked as soon as they are mapped */
        cr_assert_eq(shm_entries_of(getpid(), "voxd."), 0);
        engine_destroy(e);
    }
    for (int i = 0; i < np; i++) {
        errno = 0;
        cr_assert_eq(waitpid(pids[i], NULL, WNOHANG), -1, "worker %d not reaped", pids[i]);
        cr_assert_eq(errno, ECHILD);
    }
    /* a named segment exists while the engine lives, and is removed */
    char name[64], path[80];
    snprintf(name, sizeof name, "/voxd-test.%d.", (int)getpid());
    snprintf(path, sizeof path, "/dev/shm%s", name);
    engine_opts o = {.workers = 1, .shm_name = name, .shm_bytes = 16 << 20};
    engine *e, *e2;
    char err[256] = "";
    cr_assert_eq(engine_create(&o, &e, err, sizeof err), 0, "%s", err);
    cr_assert_eq(access(path, F_OK), 0);
    cr_assert_eq(engine_create(&o, &e2, err, sizeof err), -EEXIST);
    cr_assert(strstr(err, "exists") || strstr(err, "File exists"), "%s", err);
    engine_destroy(e);
    cr_assert_neq(access(path, F_OK), 0);
}

/* Descriptors of process pid above 2 (-1: it is gone). */
static int fds_above_stdio(pid_t pid)
{
    char path[64];
    snprintf(path, sizeof path, "/proc/%d/fd", (int)pid);
    DIR *d = opendir(path);
    if (!d) return -1;
    int n = 0;
    struct dirent *de;
    while ((de = readdir(d)))
        n += de->d_name[0] != '.' && atoi(de->d_name) > 2;
    closedir(d);
    return n;
}

/* A worker closes what it inherited right after the fork: give it a moment
 * (30 s at most, for a loaded machine). */
static void assert_only_stdio(pid_t pid, const char *what)
{
    int n = fds_above_stdio(pid);
    for (int k = 0; k < 3000 && n > 0; k++) {
        usleep(10000);
        n = fds_above_stdio(pid);
    }
    cr_assert_eq(n, 0, "%s: worker %d holds %d descriptor(s) above 2", what, (int)pid, n);
}

/* Workers keep none of the master's descriptors (a daemon's client sockets
 * and result memfds), whether forked at creation or again after a death:
 * the master's close of a pipe end is the last one. */
Test(engine, workers_hold_no_inherited_descriptors)
{
    int p[2];
    cr_assert_eq(pipe2(p, O_NONBLOCK), 0);
    int mfd = memfd_create("test-result", 0);
    cr_assert_geq(mfd, 0);
    engine *e = make_engine(2, (size_t)16 << 20);
    for (int i = 0; i < 2; i++) assert_only_stdio(engine_worker_pid(e, i), "at creation");
    pid_t old = engine_worker_pid(e, 1);
    cr_assert_eq(kill(old, SIGKILL), 0);
    wait_dead(old);
    expr_tape *tape = compile(SPHERE);
    grid_spec g = grid(32);
    engine_result r;
    run(e, tape, &g, ENGINE_SCHED_SUBTREE, 0, &r); /* forks worker 1 again */
    cr_assert_neq(engine_worker_pid(e, 1), old);
    assert_only_stdio(engine_worker_pid(e, 1), "forked again");
    close(p[1]);
    char c;
    cr_assert_eq(read(p[0], &c, 1), 0, "the pipe's write end is still open somewhere");
    close(p[0]);
    close(mfd);
    engine_destroy(e);
    expr_tape_free(tape);
}

static long long shm_blocks(const char *path)
{
    struct stat st;
    cr_assert_eq(stat(path, &st), 0);
    return (long long)st.st_blocks;
}

/* Pages a job touched go back to tmpfs when it ends, but for the octree
 * it leaves for its VOD; engine_release gives that back too. */
Test(engine, pages_beyond_keep_are_given_back)
{
    char name[64], path[80];
    snprintf(name, sizeof name, "/voxd-keep.%d.", (int)getpid());
    snprintf(path, sizeof path, "/dev/shm%s", name);
    engine_opts o = {.workers = 1, .shm_name = name, .keep_bytes = 4096};
    engine *e;
    char err[256] = "";
    cr_assert_eq(engine_create(&o, &e, err, sizeof err), 0, "%s", err);
    expr_tape *big = compile(SPHERES), *small = compile(SPHERE);
    grid_spec gb = grid(192), gs = grid(16);
    engine_result r;
    run(e, big, &gb, ENGINE_SCHED_SUBTREE, 0, &r);
    long long after_big = shm_blocks(path);
    run(e, small, &gs, ENGINE_SCHED_SUBTREE, 0, &r);
    long long after_small = shm_blocks(path);
    cr_assert_lt(after_small * 4, after_big, "%lld blocks, then %lld", after_big,
                 after_small);
    /* and the big job still comes out right on the released pages */
    ref_tree ref;
    reference(big, &gb, &ref);
    run(e, big, &gb, ENGINE_SCHED_SUBTREE, 0, &r);
    assert_same(&ref.t, engine_octree(e), "after release");
    /* the caller is done with the octree: only the fixed part and the
     * kept bytes stay */
    long long fixed = (long long)((shm_min_bytes(1) - SHM_MIN_DATA + 4096 + 4095) / 512);
    engine_release(e);
    cr_assert_null(engine_octree(e));
    cr_assert_leq(shm_blocks(path), fixed, "%lld blocks", shm_blocks(path));
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(big);
    expr_tape_free(small);
}

/* A job that cannot fit stops as soon as its estimated need passes the
 * segment (x*0: every voxel is on the surface), long before it fills it,
 * and what it touched goes back; the next job runs. */
Test(engine, a_job_too_big_stops_early_and_gives_its_pages_back, .timeout = 60)
{
    char name[64], path[80];
    snprintf(name, sizeof name, "/voxd-big.%d.", (int)getpid());
    snprintf(path, sizeof path, "/dev/shm%s", name);
    size_t bytes = (size_t)256 << 20;
    engine_opts o = {.workers = 2, .shm_name = name, .shm_bytes = bytes,
                     .keep_bytes = 4096};
    engine *e;
    char err[256] = "";
    cr_assert_eq(engine_create(&o, &e, err, sizeof err), 0, "%s", err);
    expr_tape *all = compile("x*0"), *tape = compile(SPHERE);
    grid_spec g = grid(2048), gs = grid(64);
    engine_job job = {.tape = all, .grid = g};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), -ENOMEM, "%s", r.error);
    cr_assert_eq(r.failure, ENGINE_LIMIT);
    cr_assert(strstr(r.error, "would need at least") && strstr(r.error, "256 MiB there are"),
              "%s", r.error);
    long long fixed = (long long)((shm_min_bytes(2) - SHM_MIN_DATA + 4096 + 4095) / 512);
    cr_assert_leq(shm_blocks(path), fixed, "%lld blocks", shm_blocks(path));
    ref_tree ref;
    reference(tape, &gs, &ref);
    run(e, tape, &gs, ENGINE_SCHED_SUBTREE, 0, &r);
    assert_same(&ref.t, engine_octree(e), "after a job too big");
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(all);
    expr_tape_free(tape);
}

static int pinned_cpu(pid_t pid)
{
    cpu_set_t set;
    cr_assert_eq(sched_getaffinity(pid, sizeof set, &set), 0);
    cr_assert_eq(CPU_COUNT(&set), 1, "worker %d not pinned", (int)pid);
    for (int c = 0; c < CPU_SETSIZE; c++)
        if (CPU_ISSET(c, &set)) return c;
    return -1;
}

Test(engine, workers_are_pinned)
{
    cpu_set_t mine;
    cr_assert_eq(sched_getaffinity(0, sizeof mine, &mine), 0);
    int allowed[CPU_SETSIZE], k = 0;
    for (int c = 0; c < CPU_SETSIZE; c++)
        if (CPU_ISSET(c, &mine)) allowed[k++] = c;
    engine *e = make_engine(3, (size_t)16 << 20);
    for (int i = 0; i < 3; i++) {
        cr_assert_eq(pinned_cpu(engine_worker_pid(e, i)), allowed[i % k]);
        cr_assert_eq(engine_worker_cpu(e, i), allowed[i % k]);
    }
    engine_destroy(e);
    int cpus[1] = {allowed[k - 1]};
    engine_opts o = {.workers = 2, .cpus = cpus, .ncpus = 1, .shm_bytes = 16 << 20};
    char err[256];
    cr_assert_eq(engine_create(&o, &e, err, sizeof err), 0, "%s", err);
    for (int i = 0; i < 2; i++)
        cr_assert_eq(pinned_cpu(engine_worker_pid(e, i)), allowed[k - 1]);
    engine_destroy(e);
}

/* ---- VOD ---- */

static void vod_same(engine *e, octree *ref, const grid_spec *g, uint32_t brick,
                     uint32_t comp, int channel)
{
    vod_params p;
    vod_params_default(&p);
    for (int a = 0; a < 3; a++) {
        p.volume[a] = g->res[a];
        p.voxel_scale[a] = (float)g->vs;
        p.origin[a] = (float)g->lo[a];
    }
    p.brick = brick;
    p.comp = comp;
    p.channel = channel;
    p.metadata = "generator=test_engine\n";
    vod_membuf a = {0}, b = {0};
    vod_sink sa = {vod_mem_write, &a}, sb = {vod_mem_write, &b};
    vod_stats st_a, st_b;
    char err[256] = "";
    cr_assert_eq(vod_write_octree(ref, &p, &sa, &st_a, err, sizeof err), 0, "%s", err);
    engine_error ee;
    cr_assert_eq(engine_write_vod(e, &p, &sb, &st_b, &ee), 0, "%s", ee.message);
    cr_assert_eq(a.n, b.n, "sizes %zu vs %zu", a.n, b.n);
    cr_assert_eq(memcmp(a.p, b.p, a.n), 0, "VOD bytes differ");
    cr_assert_eq(st_a.crc32, st_b.crc32);
    cr_assert_gt(st_b.bricks, 1);
    free(a.p);
    free(b.p);
}

Test(engine, vod_bytes_identical_to_serial_writer)
{
    expr_tape *tape = compile(SPHERES);
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 0.6};
    grid_spec g;
    char err[200];
    cr_assert_eq(grid_make(lo, hi, 120, &g, err, sizeof err), 0);
    ref_tree ref;
    reference(tape, &g, &ref);
    engine *e = make_engine(3, 0);
    engine_result r;
    run(e, tape, &g, ENGINE_SCHED_SUBTREE, 0, &r);
    vod_same(e, &ref.t, &g, 16, VOD_COMP_ZLIB, VOXEL_CH_SURFACE);
    vod_same(e, &ref.t, &g, 8, VOD_COMP_RUNL, VOXEL_CH_SURFACE);
    vod_same(e, &ref.t, &g, 4, VOD_COMP_NONE, VOXEL_CH_OCCUPANCY);
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}

/* The brick area overflows with zlib bricks: the master encodes what did
 * not fit with its own deflate stream, freed at the end of each write (and
 * made again for the next one), and the bytes are the serial writer's. */
Test(engine, vod_zlib_bricks_encoded_by_the_master)
{
    expr_tape *tape = compile(SCENE2);
    grid_spec g = grid(128);
    ref_tree ref;
    reference(tape, &g, &ref);
    char name[64];
    snprintf(name, sizeof name, "/voxd-zlib.%d.", (int)getpid());
    /* room for the tables and about half of the compressed bricks */
    engine_opts o = {.workers = 2, .shm_name = name,
                     .shm_bytes = shm_min_bytes(2) + (size_t)ref.t.used * 36 - (768u << 10)};
    engine *e;
    char err[256] = "";
    cr_assert_eq(engine_create(&o, &e, err, sizeof err), 0, "%s", err);
    engine_result r;
    run(e, tape, &g, ENGINE_SCHED_SUBTREE, 0, &r);
    for (int k = 0; k < 2; k++) vod_same(e, &ref.t, &g, 16, VOD_COMP_ZLIB, VOXEL_CH_SURFACE);
    int fd = shm_open(name, O_RDONLY, 0);
    cr_assert_geq(fd, 0);
    void *map = mmap(NULL, o.shm_bytes, PROT_READ, MAP_SHARED, fd, 0);
    close(fd);
    cr_assert_neq(map, MAP_FAILED);
    const shm_header *h = map;
    cr_assert_eq(h->job_kind, SHM_KIND_ENCODE);
    const encode_block *b = (const encode_block *)((const uint8_t *)map + h->job_off);
    cr_assert_gt(atomic_load(&b->bump), b->brick_cap,
                 "the workers' bricks all fitted: the master encoded none");
    munmap(map, o.shm_bytes);
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}

static int failing_write(void *ud, const void *buf, size_t n)
{
    (void)buf;
    (void)n;
    ++*(int *)ud;
    return -EFBIG;
}

/* A sink's own -EFBIG (a caller's result limit) is told as the sink's, not
 * as the format's 4 GiB limit. */
Test(engine, vod_sink_errors_are_the_sinks)
{
    expr_tape *tape = compile(SPHERE);
    grid_spec g = grid(64);
    engine *e = make_engine(2, (size_t)64 << 20);
    engine_result r;
    run(e, tape, &g, ENGINE_SCHED_SUBTREE, 0, &r);
    vod_params p;
    vod_params_default(&p);
    for (int a = 0; a < 3; a++) p.volume[a] = g.res[a];
    int calls = 0;
    vod_sink sink = {failing_write, &calls};
    engine_error ee;
    cr_assert_eq(engine_write_vod(e, &p, &sink, NULL, &ee), -EFBIG);
    cr_assert_eq(calls, 1);
    cr_assert_eq(ee.failure, ENGINE_SINK);
    cr_assert_eq(ee.code, -EFBIG);
    cr_assert_str_eq(ee.message, strerror(EFBIG));
    engine_destroy(e);
    expr_tape_free(tape);
}

/* The brick area overflows: the master encodes what did not fit, and the
 * bytes are still the serial writer's. */
Test(engine, vod_with_a_full_brick_area)
{
    expr_tape *tape = compile(SCENE2);
    grid_spec g = grid(128);
    ref_tree ref;
    reference(tape, &g, &ref);
    size_t need = (size_t)ref.t.used * 36 + 2 * 1024 * 1024;
    engine *e = make_engine(2, shm_min_bytes(2) + need - (1u << 20));
    engine_result r;
    run(e, tape, &g, ENGINE_SCHED_SUBTREE, 0, &r);
    vod_same(e, &ref.t, &g, 16, VOD_COMP_NONE, VOXEL_CH_SURFACE);
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}
