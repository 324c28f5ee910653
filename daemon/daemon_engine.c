/* The engine thread: it creates the engine, runs the queued jobs one at a
 * time (every worker on each), writes each VOD into a memfd bounded by
 * max_result_bytes and hands the job back to the loop (d->done + async). */
#include <errno.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#include "clock.h"
#include "daemon.h"
#include "err.h"
#include "heap.h"
#include "log.h"
#include "pipeline.h"
#include "vod.h"

#define IDLE_CHECK_S 1 /* how often an idle engine thread looks for dead workers */

/* ---------------------------------------------------------------- helpers */

/* A line for the loop to log (the log is the loop's).  Under mu. */
__attribute__((format(printf, 3, 4))) static void elog(daemon_ctx *d, int level,
                                                       const char *fmt, ...)
{
    if (d->elog_n == DAEMON_ELOG_LINES) {
        d->elog_dropped++;
        return;
    }
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(d->elog[d->elog_n].text, sizeof d->elog[0].text, fmt, ap);
    va_end(ap);
    d->elog[d->elog_n++].level = level;
}

/* The result's memory file is closed: its bytes leave the budget. */
static void drop_result(daemon_job *j)
{
    if (j->fd < 0) return;
    close(j->fd);
    j->fd = -1;
    /* relaxed: see daemon_ctx.results_held */
    if (j->held_sum) atomic_fetch_sub_explicit(j->held_sum, j->size, memory_order_relaxed);
}

int daemon_memory_room(daemon_ctx *d, uint64_t max_memory, uint64_t shm, char *msg, size_t len)
{
    /* relaxed: see daemon_ctx.results_held */
    uint64_t held = atomic_load_explicit(&d->results_held, memory_order_relaxed);
    if (shm + held + CONFIG_RESULT_ROOM <= max_memory) return 0;
    snprintf(msg, len,
             "this server's memory budget (max_memory %llu MiB) is taken: %llu MiB of "
             "shared memory and %llu MiB of results waiting for their clients; try again "
             "later",
             (unsigned long long)(max_memory >> 20), (unsigned long long)(shm >> 20),
             (unsigned long long)(held >> 20));
    return VOXD__ERROR_CODE__BUSY;
}

void daemon_job_free(daemon_job *j)
{
    if (!j) return;
    if (j->map) munmap(j->map, j->size);
    drop_result(j);
    free(j->source);
    free(j->source_name);
    csg_tree_free(j->csg);
    free(j);
}

/* A worker replaced since the last snapshot: why, in the log. */
static void log_replaced(daemon_ctx *d, int i, const daemon_worker_snap *w,
                         const engine_worker_info *in)
{
    if (in->stalls != w->stalls)
        elog(d, LOG_LEVEL_WARN,
             "worker %d (pid %d, CPU %d) made no progress for %.1f s (process state %c); "
             "killed and forked again as pid %d, its task handed out again",
             i, in->stalled_pid, in->cpu, in->stalled_quiet, in->stalled_state, in->pid);
    else if (in->unanswered != w->unanswered)
        elog(d, LOG_LEVEL_WARN,
             "worker %d (pid %d, CPU %d) did not let go of a stopped job (stopped, or no "
             "progress); killed and forked again as pid %d",
             i, (int)w->pid, in->cpu, in->pid);
    else
        elog(d, LOG_LEVEL_WARN, "worker %d (pid %d) died; forked again as pid %d on CPU %d",
             i, (int)w->pid, in->pid, in->cpu);
}

/* The workers as the engine sees them now; a changed pid is a worker that
 * died, or stalled and was killed, and was forked again.  Engine thread,
 * under mu. */
static void snapshot(daemon_ctx *d, engine *e)
{
    int n = engine_workers(e);
    for (int i = 0; i < n; i++) {
        daemon_worker_snap *w = &d->workers[i];
        engine_worker_info in;
        if (engine_worker_info_get(e, i, &in)) continue;
        /* the counts move with the pid: a stall is counted when the worker
         * is killed, its pid changes once it is forked again */
        if (w->pid > 0 && in.pid > 0 && in.pid != w->pid) log_replaced(d, i, w, &in);
        if (in.pid > 0 && in.pid != w->pid) {
            w->pid = in.pid;
            w->replaced = in.replaced;
            w->stalls = in.stalls;
            w->unanswered = in.unanswered;
        }
        w->cpu = in.cpu;
        w->state = in.state;
    }
    d->nworkers = n;
}

static void wake_loop(daemon_ctx *d)
{
    uv_async_send(&d->wake);
}

/* ---------------------------------------------------------------- engine life */

static engine *engine_make(daemon_ctx *d)
{
    engine *e = NULL;
    err_info err = {0};
    engine_opts o = d->eopts;
    pthread_mutex_unlock(&d->mu);
    int rc = engine_create(&o, &e, &err);
    pthread_mutex_lock(&d->mu);
    if (rc) {
        snprintf(d->engine_err, sizeof d->engine_err, "%s",
                 err.msg[0] ? err.msg : strerror(-rc));
        d->engine_state = rc;
        return NULL;
    }
    engine_lazy_release(e); /* a job's pages go back after its reply (engine_main) */
    memset(d->workers, 0, sizeof d->workers);
    snapshot(d, e);
    d->engine_state = 1;
    return e;
}

/* Between jobs: a worker that died is reaped and forked again now, not
 * when the next job starts; snapshot() logs each one forked again. */
static void reap_idle(daemon_ctx *d, engine *e)
{
    pthread_mutex_unlock(&d->mu);
    int rc = engine_check_workers(e);
    pthread_mutex_lock(&d->mu);
    if (rc == 0) return;
    snapshot(d, e);
    if (rc < 0)
        elog(d, LOG_LEVEL_ERROR,
             "a worker died between jobs and cannot be forked again: %s; "
             "the next job tries again", strerror(-rc));
    wake_loop(d);
}

/* ---------------------------------------------------------------- one job */

typedef struct {
    daemon_ctx *d;
    daemon_job *j;
    engine *e;
} progress_ctx;

static void on_progress(void *ud, const engine_progress *p)
{
    progress_ctx *x = ud;
    pthread_mutex_lock(&x->d->mu);
    x->j->progress = *p;
    x->j->progress_seq++;
    snapshot(x->d, x->e);
    pthread_mutex_unlock(&x->d->mu);
    wake_loop(x->d);
}

/* The VOD goes into a memfd: bounded by the job's max_result_bytes and
 * the memory budget, stopped by its cancel flag. */
typedef struct {
    daemon_job *j;
    int over;      /* max_result_bytes was reached (not VOD's own 4 GiB limit) */
    /* the budget: results may hold max_memory - shm_size; 1 when this
     * result alone, 2 when it with the others held would pass it */
    uint64_t room;
    int budget;
} result_sink;

static int sink_write(void *ud, const void *buf, size_t n)
{
    result_sink *rs = ud;
    daemon_job *j = rs->j;
    /* relaxed: a flag, see engine_job.cancel */
    if (atomic_load_explicit(&j->cancel, memory_order_relaxed)) return -ECANCELED;
    if (n > j->max_result_bytes - j->size) {
        rs->over = 1;
        return -EFBIG;
    }
    /* relaxed: see daemon_ctx.results_held (it holds j->size too) */
    uint64_t held = atomic_load_explicit(j->held_sum, memory_order_relaxed);
    if (n > rs->room - j->size) rs->budget = 1;
    else if (held > rs->room || n > rs->room - held) rs->budget = 2;
    if (rs->budget) return -EFBIG;
    const uint8_t *p = buf;
    while (n) {
        ssize_t w = write(j->fd, p, n);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) return w < 0 ? -errno : -EIO;
        p += w;
        n -= (size_t)w;
        j->size += (uint64_t)w;
        /* relaxed: see daemon_ctx.results_held */
        atomic_fetch_add_explicit(j->held_sum, (uint64_t)w, memory_order_relaxed);
    }
    return 0;
}

void daemon_job_stopped(daemon_job *j)
{
    switch (j->cancel_code) {
    case VOXD__ERROR_CODE__TIMEOUT:
        daemon_job_error(j, j->cancel_code,
                         "the job ran past this server's job_timeout of %u s; ask for a lower "
                         "res or a simpler %s",
                         j->job_timeout, daemon_submit_input_name(j));
        break;
    case VOXD__ERROR_CODE__SHUTTING_DOWN:
        daemon_job_error(j, j->cancel_code, "the daemon is stopping");
        break;
    default: daemon_job_error(j, VOXD__ERROR_CODE__CANCELLED, "cancelled by a client"); break;
    }
}

/* The daemon's error code for the engine's reason. */
static int failure_code(const daemon_job *j, const result_sink *rs, engine_failure f)
{
    switch (f) {
    case ENGINE_CANCELLED: return j->cancel_code ? j->cancel_code : VOXD__ERROR_CODE__CANCELLED;
    case ENGINE_BAD_JOB: return VOXD__ERROR_CODE__INVALID_INPUT;
    case ENGINE_LIMIT: return VOXD__ERROR_CODE__LIMIT_EXCEEDED;
    case ENGINE_CRASHED: return VOXD__ERROR_CODE__WORKER_CRASHED;
    case ENGINE_SINK:
        return rs->over || rs->budget == 1 ? VOXD__ERROR_CODE__LIMIT_EXCEEDED
               : rs->budget             ? VOXD__ERROR_CODE__BUSY
                                        : VOXD__ERROR_CODE__INTERNAL;
    default: return VOXD__ERROR_CODE__INTERNAL;
    }
}

static int job_failed(daemon_job *j, const result_sink *rs, const engine_pipeline_report *r)
{
    const engine_error *err = &r->err;
    int code = failure_code(j, rs, err->kind);
    /* a cancel shows as the engine's, or as the sink's refusal */
    if (err->kind == ENGINE_CANCELLED || (err->kind == ENGINE_SINK && j->cancel_code))
        return daemon_job_stopped(j), -1;
    if (r->stage == ENGINE_PIPELINE_GRID) return daemon_job_error(j, code, "%s", err->msg);
    if (err->kind == ENGINE_CRASHED)
        return daemon_job_error(j, code, "this job kills its workers: %s; the daemon goes on",
                                err->msg);
    if (rs->over)
        return daemon_job_error(j, code,
                                "the result is over this server's max_result_bytes (%llu bytes); "
                                "ask for a lower res or a coarser output",
                                (unsigned long long)j->max_result_bytes);
    if (rs->budget == 1)
        return daemon_job_error(j, code,
                                "the result does not fit in this server's memory budget "
                                "(max_memory less shm_size: %llu MiB); ask for a lower res or "
                                "a coarser output",
                                (unsigned long long)(rs->room >> 20));
    if (rs->budget)
        return daemon_job_error(j, code,
                                "the result does not fit in this server's memory budget beside the "
                                "results waiting for their clients (%llu MiB for results in all); "
                                "try again later",
                                (unsigned long long)(rs->room >> 20));
    if (r->stage == ENGINE_PIPELINE_VOXELIZE)
        return daemon_job_error(j, code, "voxelization failed: %s", err->msg);
    return daemon_job_error(j, code, "cannot write the VOD: %s", err->msg);
}

/* The job through the pipeline into its memfd, its outcome in j. */
static void run_pipeline(engine *e, daemon_job *j, engine_pipeline_job *job, uint64_t room)
{
    vod_params_default(&job->vod);
    job->vod.channel = j->channel;
    job->vod.brick = j->brick;
    job->vod.comp = j->comp;
    job->vod.hash = j->hash;
    result_sink rs = {.j = j, .room = room};
    vod_sink sink = {sink_write, &rs};
    engine_pipeline_report r;
    if (engine_pipeline_run(e, job, &sink, &r) == 0) j->code = 0;
    else job_failed(j, &rs, &r);
    j->grid = r.grid;
    j->t_voxelize = r.t_voxelize;
    j->t_write = r.t_write;
    j->voxels = r.voxels;
    j->has_figures = r.stage != ENGINE_PIPELINE_GRID;
    j->fig = r.fig;
    j->st = r.st;
}

/* The MPI run's file into the job's memfd, through the sink's limits. */
static void copy_result(daemon_job *j, int in, uint64_t room)
{
    result_sink rs = {.j = j, .room = room};
    uint8_t buf[64 << 10];
    ssize_t n;
    int rc = 0;
    while (rc == 0 && (n = read(in, buf, sizeof buf)) != 0) {
        if (n < 0 && errno == EINTR) continue;
        rc = n < 0 ? -errno : sink_write(&rs, buf, (size_t)n);
    }
    if (rc == 0) {
        j->code = 0;
        return;
    }
    engine_pipeline_report r = {.stage = ENGINE_PIPELINE_WRITE};
    r.err.kind = ENGINE_SINK;
    snprintf(r.err.msg, sizeof r.err.msg, "%s", strerror(-rc));
    job_failed(j, &rs, &r);
}

/* The MPI run started: its line in the log now, not when it ends. */
static void mpi_started(void *ud, const char *line)
{
    progress_ctx *x = ud;
    pthread_mutex_lock(&x->d->mu);
    elog(x->d, LOG_LEVEL_INFO, "%s", line);
    pthread_mutex_unlock(&x->d->mu);
    wake_loop(x->d);
}

/* vox_mpi's progress, by subtrees done, as the job's progress. */
static void mpi_progress(void *ud, double fraction, uint64_t voxels)
{
    progress_ctx *x = ud;
    pthread_mutex_lock(&x->d->mu);
    x->j->progress.fraction = fraction;
    x->j->progress.voxels = voxels;
    x->j->progress.seconds = clock_now() - x->j->t_start;
    x->j->progress_seq++;
    pthread_mutex_unlock(&x->d->mu);
    wake_loop(x->d);
}

/* A job through mpirun ... vox_mpi (daemon_mpi.c): its grid from the
 * plan every job makes, its file copied into the memfd. */
static void run_mpi(daemon_ctx *d, const daemon_mpi *m, daemon_job *j, engine_pipeline_job *job,
                    uint64_t room)
{
    vod_params_default(&job->vod);
    job->vod.channel = j->channel;
    job->vod.brick = j->brick;
    job->vod.comp = j->comp;
    job->vod.hash = j->hash;
    engine_pipeline_report r = {0};
    vod_params v;
    char meta[JOB_META_MAX];
    if (engine_pipeline_plan(job, &r, &v, meta)) {
        daemon_job_error(j, VOXD__ERROR_CODE__INVALID_INPUT, "%s", r.err.msg);
        return;
    }
    j->grid = r.grid;
    int in = -1;
    progress_ctx px = {d, j, NULL};
    daemon_mpi_hooks h = {mpi_started, mpi_progress, &px};
    j->mpi_ranks = m->ranks;
    int rc = daemon_mpi_run(m, j, &in, &h);
    if (rc == -ECANCELED) daemon_job_stopped(j);
    pthread_mutex_lock(&d->mu);
    if (rc == 0)
        elog(d, LOG_LEVEL_INFO, "job %llu ran through MPI on %u rank%s in %.3f s",
             (unsigned long long)j->id, m->ranks, m->ranks == 1 ? "" : "s",
             j->t_voxelize + j->t_write);
    else if (j->code != VOXD__ERROR_CODE__CANCELLED && j->code != VOXD__ERROR_CODE__TIMEOUT &&
             j->code != VOXD__ERROR_CODE__SHUTTING_DOWN)
        elog(d, LOG_LEVEL_ERROR, "job %llu: %.200s", (unsigned long long)j->id, j->message);
    pthread_mutex_unlock(&d->mu);
    wake_loop(d);
    if (rc) return;
    copy_result(j, in, room);
    close(in);
}

static void run_job(daemon_ctx *d, engine *e, daemon_job *j, const daemon_mpi *mpi, uint64_t room)
{
    progress_ctx px = {d, j, e};
    engine_pipeline_job job = {
        .lo = {j->lo[0], j->lo[1], j->lo[2]}, .hi = {j->hi[0], j->hi[1], j->hi[2]},
        .res = j->res, .schedule = (engine_schedule)j->schedule, .band = j->band,
        .progress = on_progress, .ud = &px, .cancel = &j->cancel,
    };
    void *owned = NULL;
    int via_mpi = daemon_mpi_wants(mpi, j);
    if (daemon_submit_input(j, &job, &owned, via_mpi)) return;
    j->fd = memfd_create("voxd-result", MFD_CLOEXEC);
    if (j->fd < 0) {
        daemon_job_error(j, VOXD__ERROR_CODE__INTERNAL, "cannot hold the result: %s",
                         strerror(errno));
    } else if (via_mpi) {
        run_mpi(d, mpi, j, &job, room);
    } else {
        run_pipeline(e, j, &job, room);
    }
    daemon_submit_release(j, owned);
}

/* ---------------------------------------------------------------- the thread */

static void job_done(daemon_ctx *d, engine *e, daemon_job *j)
{
    /* A stop asked for wins over an outcome that raced it. */
    if (j->cancel_code && j->code == 0) daemon_job_stopped(j);
    if (j->code) drop_result(j);
    if (j->code == VOXD__ERROR_CODE__WORKER_CRASHED)
        elog(d, LOG_LEVEL_ERROR, "job %llu: %s", (unsigned long long)j->id, j->message);
    int n = j->mpi_ranks ? 0 : engine_workers(e); /* an MPI job was not theirs */
    for (int i = 0; i < n; i++) {
        d->workers[i].jobs++;
        if (j->code == 0 && j->t_voxelize > 0)
            d->workers[i].vps = (double)j->voxels / j->t_voxelize / n;
    }
    snapshot(d, e);
    d->running = NULL;
    j->state = DAEMON_DONE;
    j->next = NULL;
    if (d->done_tail) d->done_tail->next = j;
    else d->done = j;
    d->done_tail = j;
}

static void run_next(daemon_ctx *d, engine *e)
{
    daemon_job *j = d->queue;
    d->queue = j->next;
    if (!d->queue) d->queue_tail = NULL;
    d->nqueued--;
    j->next = NULL;
    j->state = DAEMON_RUNNING;
    j->t_start = clock_now();
    d->running = j;
    /* The budget, before anything is allocated: results delivered since
     * the job was admitted may have left room, or not. */
    uint64_t room = d->mem_max > d->mem_shm ? d->mem_max - d->mem_shm : 0;
    int full = daemon_memory_room(d, d->mem_max, d->mem_shm, j->message, sizeof j->message);
    daemon_mpi *m = malloc(sizeof *m); /* this job's MPI settings: a reload may change d's */
    if (m) *m = d->mpi;
    pthread_mutex_unlock(&d->mu);
    wake_loop(d);
    /* relaxed: a flag, see engine_job.cancel */
    if (atomic_load_explicit(&j->cancel, memory_order_relaxed)) daemon_job_stopped(j);
    else if (full) j->code = full;
    else if (!m) daemon_job_error(j, VOXD__ERROR_CODE__INTERNAL, "out of memory");
    else run_job(d, e, j, m, room);
    free(m);
    pthread_mutex_lock(&d->mu);
    job_done(d, e, j);
}

/* Between jobs: the loop asked for new workers (SIGHUP). */
static engine *reload(daemon_ctx *d, engine *e)
{
    d->reload = 0;
    pthread_mutex_unlock(&d->mu);
    engine_destroy(e);
    pthread_mutex_lock(&d->mu);
    e = engine_make(d);
    if (e) elog(d, LOG_LEVEL_INFO, "workers replaced: %d worker%s", engine_workers(e),
                engine_workers(e) == 1 ? "" : "s");
    else elog(d, LOG_LEVEL_ERROR, "cannot start new workers: %s", d->engine_err);
    return e;
}

/* Jobs while there is no engine (a reload failed): each gets INTERNAL, and
 * the next job tries to create the engine again. */
static void run_without_engine(daemon_ctx *d)
{
    daemon_job *j = d->queue;
    d->queue = j->next;
    if (!d->queue) d->queue_tail = NULL;
    d->nqueued--;
    daemon_job_error(j, VOXD__ERROR_CODE__INTERNAL, "the daemon has no workers: %s",
                     d->engine_err);
    j->state = DAEMON_DONE;
    j->next = NULL;
    if (d->done_tail) d->done_tail->next = j;
    else d->done = j;
    d->done_tail = j;
}

static void wait_work(daemon_ctx *d)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    ts.tv_sec += IDLE_CHECK_S;
    pthread_cond_timedwait(&d->cv, &d->mu, &ts);
}

/* The last job's pages given back once its outcome is out (the loop
 * streams the result meanwhile), not before. */
static void tidy(daemon_ctx *d, engine *e)
{
    pthread_mutex_unlock(&d->mu);
    engine_tidy(e);
    pthread_mutex_lock(&d->mu);
}

/* The heap a job left (kept while jobs run, voxd's main calls heap_keep:
 * the next job's arrays do not fault in again) given back once no job came
 * for a while. */
static void give_back(daemon_ctx *d, int *heap_kept)
{
    if (!*heap_kept) return;
    *heap_kept = 0;
    pthread_mutex_unlock(&d->mu);
    heap_give_back();
    pthread_mutex_lock(&d->mu);
}

static void *engine_main(void *arg)
{
    daemon_ctx *d = arg;
    pthread_mutex_lock(&d->mu);
    engine *e = engine_make(d);
    pthread_cond_broadcast(&d->started_cv);
    /* A failure at start ends the thread (daemon_engine_start reports it); a
     * failed reload later leaves e NULL and the next job tries again. */
    int started = e != NULL, heap_kept = 0;
    while (started && !d->quit) {
        if (d->reload) {
            e = reload(d, e);
        } else if (!d->queue) {
            wait_work(d);
            if (e && !d->queue && !d->quit && !d->reload) {
                reap_idle(d, e);
                give_back(d, &heap_kept);
            }
            continue;
        } else {
            if (!e) e = engine_make(d); /* a reload failed: try again */
            if (e) run_next(d, e);
            else run_without_engine(d);
            heap_kept = 1;
        }
        wake_loop(d);
        if (e) tidy(d, e);
    }
    pthread_mutex_unlock(&d->mu);
    engine_destroy(e);
    vod_encode_cleanup();
    return NULL;
}

int daemon_engine_start(daemon_ctx *d)
{
    /* The engine thread and the workers it forks take no signal: the loop's
     * uv_signal handlers get them all (a worker resets its own). */
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    int rc = pthread_create(&d->thread, NULL, engine_main, d);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (rc) return -rc;
    d->thread_started = 1;
    pthread_mutex_lock(&d->mu);
    while (d->engine_state == 0) pthread_cond_wait(&d->started_cv, &d->mu);
    rc = d->engine_state < 0 ? d->engine_state : 0;
    pthread_mutex_unlock(&d->mu);
    return rc;
}

void daemon_engine_stop(daemon_ctx *d)
{
    if (!d->thread_started) return;
    pthread_mutex_lock(&d->mu);
    d->quit = 1;
    if (d->running) {
        if (!d->running->cancel_code) d->running->cancel_code = VOXD__ERROR_CODE__SHUTTING_DOWN;
        atomic_store_explicit(&d->running->cancel, 1, memory_order_relaxed);
    }
    pthread_cond_signal(&d->cv);
    pthread_mutex_unlock(&d->mu);
    pthread_join(d->thread, NULL);
    d->thread_started = 0;
}

/* ---------------------------------------------------------------- loop side */

void daemon_queue_push(daemon_ctx *d, daemon_job *j)
{
    pthread_mutex_lock(&d->mu);
    j->state = DAEMON_QUEUED;
    j->next = NULL;
    if (d->queue_tail) d->queue_tail->next = j;
    else d->queue = j;
    d->queue_tail = j;
    d->nqueued++;
    pthread_cond_signal(&d->cv);
    pthread_mutex_unlock(&d->mu);
}

/* Under mu: take j out of the queue; 1 if it was there. */
static int unqueue(daemon_ctx *d, daemon_job *j)
{
    daemon_job **pp = &d->queue, *prev = NULL;
    while (*pp && *pp != j) prev = *pp, pp = &(*pp)->next;
    if (!*pp) return 0;
    *pp = j->next;
    if (d->queue_tail == j) d->queue_tail = prev;
    d->nqueued--;
    j->next = NULL;
    return 1;
}

int daemon_job_stop(daemon_ctx *d, daemon_job *j, int code)
{
    pthread_mutex_lock(&d->mu);
    int state = j->state, out = state == DAEMON_QUEUED && unqueue(d, j);
    if (state == DAEMON_RUNNING || state == DAEMON_DONE) {
        /* DONE: still on d->done; daemon_job_finished sees the code */
        if (!j->cancel_code) j->cancel_code = code;
        atomic_store_explicit(&j->cancel, 1, memory_order_relaxed);
    }
    pthread_mutex_unlock(&d->mu);
    return out;
}

int daemon_queue_admit(daemon_ctx *d, daemon_job *j, unsigned delivering, uint32_t *pos)
{
    const voxd_config *c = &d->cfg;
    pthread_mutex_lock(&d->mu);
    unsigned mine = delivering + (d->running && d->running->uid == j->uid);
    for (daemon_job *q = d->done; q; q = q->next) mine += q->uid == j->uid;
    for (daemon_job *q = d->queue; q; q = q->next) mine += q->uid == j->uid;
    int code = d->nqueued + d->nuploading >= c->max_queued_jobs ? VOXD__ERROR_CODE__BUSY
               : mine >= c->max_jobs_per_uid    ? VOXD__ERROR_CODE__LIMIT_EXCEEDED
                                                : 0;
    *pos = d->nqueued + (d->running != NULL);
    pthread_mutex_unlock(&d->mu);
    if (!code && j->state != DAEMON_UPLOADING) daemon_queue_push(d, j); /* else when its input is in */
    return code;
}

int daemon_busy(daemon_ctx *d)
{
    pthread_mutex_lock(&d->mu);
    int busy = d->queue || d->running || d->done;
    pthread_mutex_unlock(&d->mu);
    for (daemon_client *c = d->clients; c && !busy; c = c->next)
        busy = c->deliver != NULL;
    return busy;
}
