/* master — the engine's inside: the state the pool, the scheduler and the
 * kinds share, and the interface a kind's master side implements.
 *
 * A job runs as engine_run(e, kind, job, watch): the core resets its state,
 * replaces dead workers, calls kind->setup (write the kind's block in the
 * data area, push the first tasks), then runs Figure 3's loop: drain every
 * busy worker's queue through kind->take, hand stack tasks to idle
 * workers, sleep on the doorbell, replace workers that died (their task is
 * handed out again if kind->rerun says so, skipping the entries taken; a
 * second death on one task fails the job), kill and replace busy workers
 * whose heartbeat stands still for the stall timeout (a death too).  When
 * the stack is empty and no worker is busy, or on a failure or a cancel
 * (the workers are then told to drop the job and waited for, but not one
 * that does not answer: it is killed), kind->finish produces the
 * result, and the data area's pages beyond what the job leaves behind
 * (engine_sched_hold) go back to tmpfs.
 */
#ifndef VOXD_MASTER_H
#define VOXD_MASTER_H

#include <stdatomic.h>
#include <stdbool.h>
#include <sys/types.h>
#include <time.h>

#include "engine.h"
#include "kinds.h"
#include "octree.h"
#include "pipeline.h"
#include "shm.h"
#include "vod_volume.h"

typedef struct {
    pid_t pid;          /* 0: no worker */
    int cpu;
    unsigned seq;       /* the last task's sequence number, given or offered */
    unsigned cur;       /* the current task's (seq, or seq - 1 when one is
                           offered) */
    int busy;           /* a task given and not finished and drained */
    shm_task task;      /* the current task */
    int offered;        /* the next task offered (seq), not taken back */
    shm_task next;      /* ... that one */
    uint32_t consumed;  /* entries of the current task taken */
    uint32_t ended;     /* tasks the worker's process ended (drained) */
    int deaths;         /* workers that died (or stalled) on the current task */
    int task_stalls;    /* ... of which stalled */
    /* liveness */
    unsigned beat;      /* the slot's heartbeat as last seen */
    double beat_t;      /* when it last moved, or the watch was reset */
    int killed;         /* SIGKILL sent, not reaped yet */
    uint32_t replaced;  /* re-forks of this slot since engine_create */
    uint32_t stalls;    /* ... for making no progress */
    uint32_t unanswered; /* ... for not letting go of an abandoned job */
    int stalled_pid;    /* the last worker killed for it, */
    double stalled_quiet; /* how long it had been quiet, */
    char stalled_state; /* its process state then (/proc: 'T' stopped) */
} mslot;

/* What the caller of a job watches it with (all optional). */
typedef struct {
    void (*progress)(void *ud, const engine_progress *p);
    void *ud;
    /* Set to non-zero by anyone to stop the job.  Read with relaxed loads;
     * nothing pairs with it. */
    const atomic_int *cancel;
} engine_sched_watch;

/* engine_write_vod, watched by w: progress (fraction = the bricks handed
 * out so far) and a cancel flag (ENGINE_CANCELLED); w may be NULL. */
int engine_write_vod_watched(engine *e, const vod_params *p, vod_sink *sink,
                             vod_stats *st, engine_error *err, const engine_sched_watch *w);

struct engine {
    shm_seg seg;
    shm_header *h;
    int n;
    int spare_cpu;      /* the master may run on a CPU no worker is pinned to */
    mslot ms[ENGINE_MAX_WORKERS];
    shm_task *stack;    /* the work stack, in the segment */
    uint32_t sp, cap;
    /* the running job */
    const engine_kind *kind;
    void *job;          /* the kind's */
    engine_sched_watch watch;
    int aborting;
    int nbusy;
    engine_error err;   /* the job's first failure */
    uint32_t restarts, stalls, offered;
    double t0, last_progress, last_check;
    double stall_s;     /* the stall timeout; <= 0: never */
    const char *shm_option; /* engine_opts.shm_option */
    /* the segment's pages */
    uint64_t keep;      /* bytes of the data area kept between jobs */
    uint64_t hold;      /* bytes of the data area the last job left for the
                           next (the implicit kind's octree, the mesh kind's
                           volume), 0 none */
    int lazy;           /* engine_lazy_release: releases wait for engine_tidy */
    uint64_t due;       /* lazy: the segment's pages from here on are to go
                           back (engine_tidy, the next job's start); 0 none */
    /* the last job's result, for engine_octree and the encoder: the
     * implicit kind's octree or the mesh kind's volume */
    enum { RESULT_NONE, RESULT_OCTREE, RESULT_VOLUME } result;
    octree tree;
    int tree_top;       /* every cell of tree at this height or above lies
                           in the master's blocks (the workers' subtrees
                           are below it); -1 unknown */
    vod_volume *volume;
    uint64_t volume_bytes;  /* its arena */
};

struct engine_kind {
    const char *name;
    uint32_t id;        /* shm_kind: the workers' side of the same kind */
    /* Set the job up in the segment and push its first tasks; 0, or
     * engine_sched_fail's return. */
    int (*setup)(engine *e, void *job);
    /* Check and take one entry worker i published (untrusted); 0, or
     * engine_sched_fail's return. */
    int (*take)(engine *e, int i, const shm_entry *en);
    /* Worker i's task is over (finished and drained, or dropped after a
     * death); error: the worker's negative errno, 0 if none. */
    void (*done)(engine *e, int i, const shm_task *t, int error);
    /* Worker i died holding task t: 1 to hand t out again, 0 to drop it. */
    int (*rerun)(engine *e, int i, const shm_task *t);
    /* Optional (NULL: none).  Task t, just taken from the stack, is about
     * to be handed out while fewer tasks than workers are left there (the
     * job's end): the kind may make it a finer one whose parts come back
     * as tasks, so that the workers end together instead of one of them
     * finishing a large last task alone. */
    void (*tail)(engine *e, shm_task *t);
    /* Non-zero: while the stack holds more tasks than there are workers,
     * a busy worker is offered its next task (engine_pool_offer), which it
     * starts as soon as its current one ends, without waiting for the
     * master; an idle worker takes one back when the stack is empty.  The
     * kind's done() then sees a worker's tasks in turn, as always. */
    int prefetch;
    /* Name task t for a message ("octant (1,2,3) level 4"). */
    void (*describe)(const shm_task *t, char *buf, size_t len);
    /* Fill the progress report (NULL: the kind reports none), with
     * shm_used and shm_need when the kind can tell: the core stops the job
     * when shm_need passes the data area.  Called every 0.1 s whether or
     * not the caller watches. */
    void (*progress)(engine *e, engine_progress *p);
    /* The job is over with rc (0 or a failure): produce the result. */
    int (*finish)(engine *e, void *job, int rc);
    /* The pipeline's side (pipeline.c runs every job through these; NULL
     * for a kind that is no pipeline job: encode, iso).  The job's checks
     * and its domain (lo, hi: the job's, which a kind whose domain is its
     * input's replaces); 0, or engine_pipeline_fail's return. */
    int (*domain)(const engine_pipeline_job *job, double lo[3], double hi[3], engine_pipeline_report *r);
    /* Its source and pairs in the VOD's metadata (m's source fields, its
     * "key=value\n" pairs written in pairs and named by m->kind_pairs). */
    void (*meta)(const engine_pipeline_job *job, job_meta *m, char *pairs, size_t len);
    /* The job without an engine (vox -w 0), into r->grid, then the VOD
     * written (engine_pipeline_write_serial).  run: the caller's copy of the job,
     * the kind's to change (a mesh's repair that is not needed). */
    int (*serial)(engine_pipeline_job *run, const vod_params *v, vod_sink *sink,
                  engine_pipeline_report *r);
    /* The voxelization on e's workers (engine_<kind>), watched by w; the
     * kind's figures from er into r->fig.  The core copies the common
     * ones and writes the VOD.  0, or a negative errno (r->err set when
     * the kind said why, else er's). */
    int (*voxelize)(engine *e, engine_pipeline_job *run, const engine_sched_watch *w, engine_result *er,
                    engine_pipeline_report *r);
    /* The job run as another kind's (NULL: never): run rewritten in
     * place, what it needs kept in *owned (csg_tree_free'd after the job).
     * 0, or a negative errno. */
    int (*rewrite)(engine_pipeline_job *run, csg_tree **owned);
    /* Its figures in words, for vox (engine_pipeline_describe); NULL: none. */
    void (*summary)(const engine_pipeline_job *job, const engine_pipeline_report *r, char *buf,
                     size_t len);
};

/* ---- pipeline.c: for the kinds' pipeline side ---- */

/* r->err set (failure f, code rc, the message); returns rc. */
int engine_pipeline_fail(engine_pipeline_report *r, engine_failure f, int rc, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
/* The serial write stage, in this thread, from the octree t or else the
 * source s (r->stage, r->t_write, r->st; r->err on a failure). */
int engine_pipeline_write_serial(octree *t, vod_source *s, const vod_params *v, vod_sink *sink,
                          engine_pipeline_report *r);

/* ---- pool.c: the workers' lives ---- */

/* Fork worker i on its CPU; 0 or -errno with a message in err. */
int engine_pool_spawn(engine *e, int i, err_info *err);
/* Write task t into worker i's slot and wake it (the slot's mechanics;
 * the scheduler's books are the caller's). */
void engine_pool_give(engine *e, int i, const shm_task *t, uint32_t skip);
/* Offer busy worker i task t as its next (the slot's `next`), numbered
 * after its current one; it takes it when the current one ends. */
void engine_pool_offer(engine *e, int i, const shm_task *t);
/* Take worker i's offered task back: 1 when it is ours again (in
 * ms[i].next), 0 when the worker has taken it (or none was offered). */
int engine_pool_take_back(engine *e, int i);
/* SIGKILL worker i (a stall, or no answer to an abort); the scheduler
 * reaps and replaces it as after a crash. */
void engine_pool_kill(engine *e, int i);
/* A process's state letter from /proc/PID/stat ('R', 'S', 'T' stopped...),
 * '?' when it cannot be read. */
char engine_pool_proc_state(pid_t pid);

static inline shm_slot *engine_pool_slot(engine *e, int i)
{
    return shm_slot_at(e->seg.base, (uint32_t)i);
}

/* ---- sched.c: Figure 3's loop, for any kind ---- */

/* Run a job of kind k; returns kind->finish's result. */
int engine_run(engine *e, const engine_kind *k, void *job,
               const engine_sched_watch *watch);
/* engine_run for a kind whose result is an engine_result: r zeroed
 * first, the master thread's CPU time into it (the wrappers engine_mesh,
 * engine_csg, ... are this with their kind's job). */
int engine_sched_run_job(engine *e, const engine_kind *k, void *job, const engine_sched_watch *watch,
                  engine_result *r);
/* Record the job's failure (the first one is the one told) and return rc. */
int engine_sched_fail(engine *e, engine_failure f, int rc, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
/* The failure of a VOD writer's rc: its own when it said something
 * (said), else the sink's. */
engine_failure engine_vod_failure(int rc, int said);
/* engine_sched_fail's ENGINE_LIMIT for what ("the volume") that the data area
 * cannot hold. */
int engine_sched_no_room(engine *e, const char *what);
/* Whether a worker found the job's volume (e->volume) full: a task's
 * -ENOMEM is then the data area's (engine_sched_no_room), else the
 * worker's own heap's. */
bool engine_volume_full(const engine *e);
/* Push task t onto the work stack; 0 or engine_sched_fail (stack full). */
int engine_sched_push(engine *e, const shm_task *t);
/* The job leaves the data area's first `bytes` for the next job (the
 * implicit kind's octree for the encode kind); 0 leaves nothing.  The core
 * gives every page past them (and past keep_bytes) back to tmpfs when a
 * job ends. */
void engine_sched_hold(engine *e, uint64_t bytes);
/* Give back the data area's pages past max(keep_bytes, hold). */
void engine_sched_release(engine *e);
/* The running job's block (shm/kinds.h's <kind>_block) in the data area. */
static inline void *engine_sched_block(engine *e)
{
    return shm_at(e->seg.base, e->h->job_off);
}

/* Offsets in the data area are kept 64-byte aligned (a cache line). */
static inline uint64_t engine_sched_align64(uint64_t v)
{
    return (v + 63) / 64 * 64;
}

/* The job's totals from the workers' slots (boxes tested, CPU) and the
 * core's books (restarts, stalls), into r. */
void engine_sched_job_totals(engine *e, engine_result *r);
/* The job's failure (the first told) into r; returns rc. */
int engine_sched_job_failed(engine *e, engine_result *r, int rc);

#endif
