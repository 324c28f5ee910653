/* The master–worker engine against the serial algorithm: the same voxels, bit
 * for bit, for every shape, schedule, split level and worker count; the queue,
 * progress, cancel, small segments, bad arguments, VOD bytes, process and
 * segment hygiene, pages given back, CPU pinning.  Workers that die or stall:
 * test_engine_death.c. */
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
#include "kind_encode.h"
#include "kind_implicit.h"
#include "kinds.h"
#include "octree.h"
#include "shm.h"
#include "subdiv.h"
#include "vod.h"
#include "voxel.h"
/* ---- the queue and the sleeping protocol, between two threads ---- */

#include <pthread.h>

#include "engine_fixture.h"

#define TORUS "sqrt((sqrt(x^2 + y^2) - 0.6)^2 + z^2) - 0.25"

#define SCENE2 "sin(4*theta)*sin(8*phi) - r"

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
            cr_assert_eq(r.cells, ref.t.used, "%s: %u cells vs %u", what, r.cells, ref.t.used);
            cr_assert_geq(engine_octree(e)->used, r.cells);
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

/* At 256^3 the subtrees are of level 5, above the tail's level: the last
 * ones go out as their children (engine_kind.tail), the same tree. */
Test(engine, torus_256_with_a_split_tail_identical_to_serial, .timeout = 120)
{
    identity(TORUS, 256, 2);
}

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

/* The implicit kind offers a busy worker its next task (engine_kind.prefetch),
 * which the worker takes from its slot's second place and writes in its second
 * queue: with many small tasks (subtrees of level 3) some go that way, one
 * worker or two, and the tree is still the serial one. */
Test(engine, tasks_offered_ahead_give_the_same_tree)
{
    expr_tape *tape = compile(SCENE2);
    grid_spec g = grid(128);
    ref_tree ref;
    reference(tape, &g, &ref);
    for (int w = 1; w <= 2; w++) {
        engine *e = make_engine(w, 0);
        for (int k = 0; k < 3; k++) {
            engine_result r;
            run(e, tape, &g, ENGINE_SCHED_SUBTREE, 3, &r);
            assert_same(&ref.t, engine_octree(e), "offered ahead");
            cr_assert_eq(r.octants, ref.tested);
            cr_assert_eq(r.duplicates, 0);
            cr_assert_gt(r.offered, 0, "%d workers: no task was offered ahead", w);
        }
        engine_destroy(e);
    }
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
        err_info err = {0};
        cr_assert_eq(grid_make(lo, hi, res[k], &g, &err), 0);
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
        cr_assert_eq(r.err.kind, ENGINE_CANCELLED);
        cr_assert(strstr(r.err.msg, "cancel"), "%s", r.err.msg);
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

/* ---- errors ---- */

Test(engine, small_segments_give_clear_errors)
{
    engine_opts o = {.workers = 2, .shm_bytes = 1 << 20};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), -ENOSPC);
    cr_assert(strstr(err.msg, "too small"), "%s", err.msg);
    /* big enough to start, too small for a 256^3 sphere's octree */
    e = make_engine(2, shm_min_bytes(2));
    expr_tape *tape = compile(SPHERE);
    grid_spec g = grid(256);
    engine_job job = {.tape = tape, .grid = g};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), -ENOMEM);
    cr_assert_eq(r.err.kind, ENGINE_LIMIT);
    /* which stops it first depends on the timing: the octree running out
     * of cells, or the progress check's estimate passing the segment (a
     * loaded machine lets the estimate run first) */
    cr_assert((strstr(r.err.msg, "octree needs more than") ||
               strstr(r.err.msg, "the job would need at least")) &&
              strstr(r.err.msg, "raise the shared memory size"), "%s", r.err.msg);
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
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), -EINVAL);
    cr_assert(strstr(err.msg, "workers"), "%s", err.msg);
    int cpus[1] = {-3};
    engine_opts o2 = {.workers = 1, .cpus = cpus, .ncpus = 1};
    cr_assert_eq(engine_create(&o2, &e, &err), -EINVAL);
    cr_assert(strstr(err.msg, "CPU -3"), "%s", err.msg);
    engine_opts o3 = {.workers = 1, .shm_name = "no-slash"};
    cr_assert_eq(engine_create(&o3, &e, &err), -EINVAL);
    e = make_engine(1, 0);
    expr_tape *tape = compile(SPHERE);
    grid_spec g = grid(32);
    g.depth = 9;
    engine_job job = {.tape = tape, .grid = g};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), -EINVAL);
    cr_assert_eq(r.err.kind, ENGINE_BAD_JOB);
    cr_assert(strstr(r.err.msg, "grid"), "%s", r.err.msg);
    vod_params p;
    vod_params_default(&p);
    vod_sink sink = {NULL, NULL};
    engine_error ee;
    cr_assert_eq(engine_write_vod(e, &p, &sink, NULL, &ee), -EINVAL);
    cr_assert_eq(ee.kind, ENGINE_BAD_JOB);
    cr_assert(strstr(ee.msg, "nothing to write"), "%s", ee.msg);
    engine_destroy(e);
    expr_tape_free(tape);
}

/* ---- processes, segments, pinning ---- */

/* A test's named segment, "/voxd-WHAT.PID.".  A failed assertion leaves the
 * test before engine_destroy: its .fini unlinks the segment whatever became
 * of the test (ENOENT, the engine's own unlink, ignored). */
static char segment[64];

static const char *named_segment(const char *what)
{
    snprintf(segment, sizeof segment, "/voxd-%s.%d.", what, (int)getpid());
    return segment;
}

static void unlink_named_segment(void)
{
    if (segment[0]) shm_unlink(segment);
}

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

Test(engine, create_destroy_leaves_nothing, .fini = unlink_named_segment)
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
    const char *name = named_segment("test");
    char path[80];
    snprintf(path, sizeof path, "/dev/shm%s", name);
    engine_opts o = {.workers = 1, .shm_name = name, .shm_bytes = 16 << 20};
    engine *e, *e2;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    cr_assert_eq(access(path, F_OK), 0);
    cr_assert_eq(engine_create(&o, &e2, &err), -EEXIST);
    cr_assert(strstr(err.msg, "exists") || strstr(err.msg, "File exists"), "%s", err.msg);
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
Test(engine, pages_beyond_keep_are_given_back, .fini = unlink_named_segment)
{
    const char *name = named_segment("keep");
    char path[80];
    snprintf(path, sizeof path, "/dev/shm%s", name);
    engine_opts o = {.workers = 1, .shm_name = name, .keep_bytes = 4096};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
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
Test(engine, a_job_too_big_stops_early_and_gives_its_pages_back, .timeout = 60,
     .fini = unlink_named_segment)
{
    const char *name = named_segment("big");
    char path[80];
    snprintf(path, sizeof path, "/dev/shm%s", name);
    size_t bytes = (size_t)256 << 20;
    engine_opts o = {.workers = 2, .shm_name = name, .shm_bytes = bytes,
                     .keep_bytes = 4096};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    expr_tape *all = compile("x*0"), *tape = compile(SPHERE);
    grid_spec g = grid(2048), gs = grid(64);
    engine_job job = {.tape = all, .grid = g};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), -ENOMEM, "%s", r.err.msg);
    cr_assert_eq(r.err.kind, ENGINE_LIMIT);
    cr_assert(strstr(r.err.msg, "would need at least") && strstr(r.err.msg, "256 MiB there are"),
              "%s", r.err.msg);
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

Test(engine, workers_are_pinned)
{
    cpu_set_t mine;
    cr_assert_eq(sched_getaffinity(0, sizeof mine, &mine), 0);
    int allowed[CPU_SETSIZE], k = 0;
    for (int c = 0; c < CPU_SETSIZE; c++)
        if (CPU_ISSET(c, &mine)) allowed[k++] = c;
    /* Automatic: the allowed CPUs in order, from one of them (the one the
     * master ran on: where the kernel put it), each once before any twice. */
    engine *e = make_engine(k + 1, (size_t)16 << 20);
    int s = -1;
    for (int j = 0; j < k; j++)
        if (allowed[j] == engine_worker_cpu(e, 0)) s = j;
    cr_assert(s >= 0, "worker 0 on CPU %d, not one the process may use", engine_worker_cpu(e, 0));
    for (int i = 0; i < k + 1; i++) {
        cr_assert_eq(pinned_cpu(engine_worker_pid(e, i)), allowed[(s + i) % k]);
        cr_assert_eq(engine_worker_cpu(e, i), allowed[(s + i) % k]);
    }
    engine_destroy(e);
    /* From the CPU the master runs on: the process bound to the last one
     * alone, every worker there. */
    cpu_set_t last;
    CPU_ZERO(&last);
    CPU_SET(allowed[k - 1], &last);
    cr_assert_eq(sched_setaffinity(0, sizeof last, &last), 0);
    e = make_engine(2, (size_t)16 << 20);
    cr_assert_eq(sched_setaffinity(0, sizeof mine, &mine), 0);
    for (int i = 0; i < 2; i++) cr_assert_eq(pinned_cpu(engine_worker_pid(e, i)), allowed[k - 1]);
    engine_destroy(e);
    int cpus[1] = {allowed[k - 1]};
    engine_opts o = {.workers = 2, .cpus = cpus, .ncpus = 1, .shm_bytes = 16 << 20};
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
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
    err_info err = {0};
    cr_assert_eq(vod_write_octree(ref, &p, &sa, &st_a, &err), 0, "%s", err.msg);
    engine_error ee;
    cr_assert_eq(engine_write_vod(e, &p, &sb, &st_b, &ee), 0, "%s", ee.msg);
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
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, 120, &g, &err), 0);
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
Test(engine, vod_zlib_bricks_encoded_by_the_master, .fini = unlink_named_segment)
{
    expr_tape *tape = compile(SCENE2);
    grid_spec g = grid(128);
    ref_tree ref;
    reference(tape, &g, &ref);
    const char *name = named_segment("zlib");
    /* room for the tables and part of the compressed bricks (about 0.5 MB
     * here), the arena's unused block tails too (the master's and each
     * worker's last: their cells and aggregates).  The workers' tails
     * depend on which subtrees each one ran, so the bricks' room varies by
     * up to two blocks (0.3 MB) from run to run: it is cut so far that the
     * largest still holds less than the bricks. */
    size_t tails = (size_t)3 * OCTREE_BLOCK_CELLS * 36;
    engine_opts o = {.workers = 2, .shm_name = name,
                     .shm_bytes = shm_min_bytes(2) + (size_t)ref.t.used * 36 + tails - (896u << 10)};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
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
                 "the workers' bricks all fitted: the master encoded none (%u of %u)",
                 (unsigned)atomic_load(&b->bump), (unsigned)b->brick_cap);
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
    cr_assert_eq(ee.kind, ENGINE_SINK);
    cr_assert_eq(ee.code, -EFBIG);
    cr_assert_str_eq(ee.msg, strerror(EFBIG));
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
