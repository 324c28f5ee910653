/* The engine when workers die or stall: a dead worker is replaced and its octant
 * redone, workers checked between jobs, a worker killed mid-subtree resumes
 * without duplicates, an octant that kills its worker twice fails the job and
 * deaths on different octants do not, a stopped worker is replaced, a task that
 * stalls its worker twice fails the job, and a cancel never waits on a stopped
 * worker; a worker killed with its next task offered loses none. */
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
        cr_assert_eq(engine_voxelize(e, &job, &r), 0, "%s", r.err.msg);
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
    cr_assert_eq(engine_voxelize(e, &job, &r), 0, "%s", r.err.msg);
    cr_assert_eq(r.restarts, 0, "nothing left to restart when the job started");
    assert_same(&ref.t, engine_octree(e), "after a worker forked again between jobs");
    cr_assert_eq(engine_worker_pid(e, 1), fresh);
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}

/* One worker, the whole grid as one subtree: stop the worker half way
 * through building it in the arena, then kill it.  Its blocks are wasted;
 * the new worker builds the subtree again in blocks of its own, and the
 * master links that one only. */
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
        usleep(20000); /* the worker is building the subtree */
        cr_assert_eq(kill(pid, SIGSTOP), 0);
    } else if (s->calls == 1) {
        cr_assert_eq(kill(pid, SIGKILL), 0);
    }
    s->calls++;
}

Test(engine, a_worker_killed_mid_subtree_resumes_without_duplicates)
{
    expr_tape *tape = compile(SPHERE);
    /* 512^3: the release build's worker builds it in some 0.15 s, so the
     * stop 20 ms into it lands inside (at 256^3 the worker had ended first) */
    grid_spec g = grid(512);
    ref_tree ref;
    reference(tape, &g, &ref);
    engine *e = make_engine(1, 0);
    stopper st = {.e = e};
    engine_job job = {.tape = tape, .grid = g, .split_level = g.depth,
                      .progress = stop_then_kill, .ud = &st};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), 0, "%s", r.err.msg);
    cr_assert_geq(st.calls, 2);
    cr_assert_eq(r.restarts, 1);
    cr_assert_eq(r.duplicates, 0);
    cr_assert_eq(r.cells, ref.t.used, "the dead worker's cells are not the tree's");
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
 * worker forked since the last kill (`fresh`: once it has also ended a task,
 * so that no task is killed twice however slowly a loaded machine runs the
 * new worker's first one), until `kills`; then cancel, if asked. */
typedef struct {
    engine *e;
    int every, kills, calls, n, fresh;
    pid_t last;
    atomic_int *cancel;
} killer;

/* Worker 0 has ended a task since it was forked. */
static int ended_one(engine *e)
{
    engine_worker_info in;
    cr_assert_eq(engine_worker_info_get(e, 0, &in), 0);
    return in.ended > 0;
}

static void kill_worker0(void *ud, const engine_progress *p)
{
    killer *k = ud;
    (void)p;
    pid_t pid = engine_worker_pid(k->e, 0);
    if (k->n == k->kills) {
        if (k->cancel && pid > 0 && pid != k->last) atomic_store(k->cancel, 1);
    } else if (k->calls % k->every == 0 && pid > 0 && pid != k->last &&
               (!k->fresh || ended_one(k->e))) {
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
    cr_assert_eq(engine_voxelize(e, &job, &r), -EIO, "%s", r.err.msg);
    cr_assert_eq(r.err.kind, ENGINE_CRASHED);
    cr_assert_eq(k.n, 2);
    cr_assert_eq(r.restarts, 2);
    cr_assert(strstr(r.err.msg, "octant (0,0,0) level 7 killed its worker twice"), "%s",
              r.err.msg);
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
    killer k = {.e = e, .every = 2, .kills = 4, .fresh = 1, .cancel = &cancel};
    engine_job job = {.tape = slow, .grid = g, .schedule = ENGINE_SCHED_PAPER,
                      .progress = kill_worker0, .ud = &k, .cancel = &cancel};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), -ECANCELED, "%s", r.err.msg);
    cr_assert_eq(k.n, 4);
    cr_assert_eq(r.restarts, 4);
    engine_destroy(e);
    expr_tape_free(slow);
}

/* The implicit kind offers a busy worker its next task (engine_kind.prefetch):
 * one worker, so that while the stack holds two tasks or more it nearly
 * always has one offered.  A worker killed with its next task offered (not
 * started: back onto the stack) or taken (started: run again, its entries
 * skipped) loses no subtree and doubles none. */
Test(engine, a_worker_killed_with_its_next_task_offered_loses_none)
{
    expr_tape *tape = compile(SPHERES);
    /* 512^3: the job outlasts its first kill (50 ms after a task ended)
     * however slowly a loaded machine runs it; at 256^3 a kill sometimes
     * landed after the last task, and the job saw no death */
    grid_spec g = grid(512);
    ref_tree ref;
    reference(tape, &g, &ref);
    engine *e = make_engine(1, 0);
    killer k = {.e = e, .every = 1, .kills = 3, .fresh = 1};
    engine_job job = {.tape = tape, .grid = g, .split_level = 2,
                      .progress = kill_worker0, .ud = &k};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &job, &r), 0, "%s", r.err.msg);
    cr_assert_geq(k.n, 1, "no worker was killed inside the job");
    /* every death the job saw was handled; a kill that lands after the
     * last task ended (the killer sleeps 50 ms first) is the next job's */
    cr_assert_geq(r.restarts, 1, "no death was seen inside the job");
    cr_assert_leq(r.restarts, (uint32_t)k.n);
    cr_assert_eq(r.duplicates, 0);
    cr_assert_eq(r.voxels, ref.t.voxels);
    cr_assert_gt(r.offered, 0, "no task was offered ahead");
    assert_same(&ref.t, engine_octree(e), "after deaths with tasks offered");
    engine_destroy(e);
    free(ref.arena);
    expr_tape_free(tape);
}

/* ---- liveness: stalled workers, cancels that never wait ---- */

static engine *make_engine_stall(int workers, double stall)
{
    engine_opts o = {.workers = workers, .stall_timeout = stall};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
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
        cr_assert_eq(engine_voxelize(e, &job, &r), 0, "%s", r.err.msg);
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
    cr_assert_eq(engine_voxelize(e, &job, &r), -EIO, "%s", r.err.msg);
    cr_assert_eq(r.err.kind, ENGINE_CRASHED);
    cr_assert_eq(r.stalls, 2);
    cr_assert(strstr(r.err.msg, "octant (0,0,0) level 7 stalled or killed its worker twice"),
              "%s", r.err.msg);
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
    cr_assert_eq(engine_voxelize(e, &job, &r), -ECANCELED, "%s", r.err.msg);
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
