/* engine — the master–worker voxelization engine (Stolte–Kaufman, Figure 3).
 *
 * engine_create() maps one POSIX shared-memory segment and forks N worker
 * processes, each pinned to a CPU.  The segment holds a header, one slot per
 * worker (its 8-entry queue with two indices, the worker's and the master's,
 * C11 atomics with acquire/release ordering), the job input (the compiled
 * tape), the work stack and the octree.  The master (the caller's thread)
 * runs the scheduler: drain every busy worker's queue (octants onto the
 * stack, voxels into the octree), hand stack octants to idle workers, sleep
 * on a futex when there is nothing to do.  Workers sleep on their own futex
 * when idle.  The same workers then encode the VOD's bricks in parallel.
 *
 * Inside, the engine is a core and job kinds (shm/kinds.h): the worker
 * pool (pool.c: fork, pin, reap, re-fork), the scheduler of Figure 3
 * (sched.c: queues, work stack, sleeping, deaths), and one file per kind
 * (kind_implicit.c: this header's voxelization; kind_encode.c: its VOD
 * bricks) that the core runs through master.h's interface without knowing
 * which one it is.
 *
 * One job at a time per engine; the engine outlives many jobs (the daemon
 * keeps one for its whole life, `vox` makes one per command).  Use it from
 * one thread, the one that created it.
 *
 * Schedules.  ENGINE_SCHED_PAPER is Figure 3: an idle worker gets one octant,
 * tests its 8 children and sends back the kept ones (or, at the last level,
 * the voxels with their normals), one per queue entry.  ENGINE_SCHED_SUBTREE
 * (the default) does the same down to a split level, then hands out whole
 * subtrees, which the workers build in the shared octree arena themselves:
 * a subtree comes back as its root cell, which the master links into the
 * tree, so it sleeps most of the time.  Both give the serial algorithm's voxels bit for bit (subdiv.h says
 * why), whatever the number of workers.
 *
 * Robustness.  Whatever a worker wrote is checked before use (entries inside
 * the task's octant and the grid, counts bounded).  A worker that dies is
 * forked again; its octant is handed out again and the entries already
 * taken are skipped (the kernel is deterministic), so the job still
 * succeeds.  The count is per octant, not per job: a second death while
 * the same octant is being handled (the first worker's and the re-run's:
 * the octant kills its workers) fails the job (ENGINE_CRASHED), whereas
 * deaths on different octants of one job, however many, each only re-run
 * their octant.  A worker that dies while idle, or in the VOD phase (its
 * bricks are encoded by the caller instead), counts for nothing.  The
 * default segment is 2 GiB of address space, at most half of /dev/shm's
 * free space; tmpfs gives pages only as they are touched.
 *
 * Liveness.  Each worker advances a heartbeat in its slot every few
 * milliseconds of work.  A worker that holds a task and whose heartbeat
 * has not moved for the stall timeout (stopped, hung; waiting on a full
 * queue does not count) is killed with SIGKILL and replaced like one that
 * died, its task handed out again: a stall counts as a death, so a task
 * that stalls or kills its worker twice fails the job (ENGINE_CRASHED).
 * A cancelled or failed job never waits on a worker that does not answer:
 * one that has not let go of its task and is stopped (SIGSTOP), or has
 * shown no heartbeat for a second, is killed and replaced (any, after 5 s).
 *
 * Memory.  After every job, done, failed or cancelled, the pages of the
 * data area beyond keep_bytes (and beyond the octree an implicit job left
 * for the VOD phase) go back to tmpfs; engine_release() gives back the
 * octree too.  A kind estimates what its job will need as it grows, and
 * the job stops with ENGINE_LIMIT as soon as the estimate passes the
 * segment, instead of filling it first.
 */
#ifndef VOXD_ENGINE_H
#define VOXD_ENGINE_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include "err.h"
#include "grid.h"
#include "vod.h"

#define ENGINE_MAX_WORKERS 256

typedef struct engine engine;

/* The segment engine_create makes for shm_bytes 0 and n workers. */
size_t engine_shm_default(int workers);

typedef struct {
    int workers;          /* >= 1 */
    const int *cpus;      /* worker i is pinned to cpus[i % ncpus]; NULL: the
                             i-th (mod count) CPU of this process's affinity */
    int ncpus;
    size_t shm_bytes;     /* segment size; 0 = default (sparse, touched as used):
                             2 GiB, at most half of /dev/shm's free space */
    const char *shm_option; /* how the user raises shm_bytes ("--shm-size MIB"),
                               named in the failures of jobs that outgrow it;
                               NULL: none named */
    const char *shm_name; /* "/name" to keep (daemon); NULL = private, unlinked at once */
    size_t keep_bytes;    /* data pages kept between jobs; what a job touched
                             beyond them goes back to tmpfs when it ends;
                             0 = default (ENGINE_KEEP_BYTES) */
    double stall_timeout; /* seconds without a heartbeat before a busy worker
                             is killed and replaced; 0 = default
                             (ENGINE_STALL_TIMEOUT), < 0 = never */
} engine_opts;

#define ENGINE_KEEP_BYTES ((size_t)8 << 20) /* 8 MiB */
#define ENGINE_STALL_TIMEOUT 10.0           /* seconds */

typedef enum {
    ENGINE_SCHED_SUBTREE = 0, /* default: subtrees out, voxel batches back */
    ENGINE_SCHED_PAPER = 1,   /* the paper: one octant out, its kept children back */
} engine_schedule;

typedef struct {
    double fraction;      /* estimated, 0..1 */
    int level;            /* every octant of this level and above has been
                             tested: the grid's depth at the start, 0 at the end */
    uint64_t voxels;      /* stored so far */
    double seconds;
    /* Bytes of the segment's data area the job uses now, and what the kind
     * estimates it will need in all (0: no estimate yet).  The engine stops
     * the job with ENGINE_LIMIT when the estimate passes the data area. */
    uint64_t shm_used, shm_need;
} engine_progress;

/* Why a job failed: the engine's reason, for a caller to act on (the
 * daemon maps it to its error code) without decoding errno values. */
typedef enum {
    ENGINE_OK = 0,
    ENGINE_CANCELLED,   /* the job's cancel flag was set */
    ENGINE_BAD_JOB,     /* the job's description is invalid */
    ENGINE_LIMIT,       /* over a size: shared memory (octree, work stack,
                           bricks) or the VOD format's 4 GiB; the message
                           says what to change */
    ENGINE_CRASHED,     /* a task killed its worker twice */
    ENGINE_SINK,        /* the sink refused the bytes (code: its error) */
    ENGINE_FAULT,       /* the server's own: fork, memory, a worker that
                           broke the protocol or failed */
} engine_failure;

/* The engine's error is the project's (common/err.h): code the negative
 * errno returned with it (0 if none), kind its engine_failure (ENGINE_OK
 * if none), msg what happened and what to change ("" if none). */
typedef err_info engine_error;

/* "cancelled", "bad job", ...: for logs. */
const char *engine_failure_name(engine_failure f);

/* A kind of job: its master side's descriptor (master.h), one file each,
 * engine/kind_<name>.c, whose header declares its job, its call and its
 * figures.  The core below runs every kind alike. */
typedef struct engine_kind engine_kind;

/* What every job of the engine reports; a kind's own figures are its
 * own (an out-pointer in its job). */
typedef struct {
    uint64_t voxels;         /* (csg jobs: voxels with density >= S) */
    uint64_t octants;        /* boxes tested (the same for every schedule and
                                worker count; chain rebuilds not counted) */
    uint32_t cells;          /* octree cells used */
    double seconds;          /* wall time of the subdivision */
    double master_cpu;       /* master thread CPU seconds */
    double worker_cpu;       /* sum of the workers' CPU seconds for the job */
    uint32_t restarts;       /* workers that died and were forked again */
    uint32_t stalls;         /* ... of which were killed for making no
                                progress (no heartbeat for the stall timeout) */
    uint64_t duplicates;     /* voxels delivered more than once (0: a re-run
                                after a death skips what was delivered) */
    uint32_t offered;        /* tasks offered to a worker while it ran the
                                one before, not taken back (a kind with
                                engine_kind.prefetch) */
    uint32_t tasks;          /* tasks the job ran, where its kind counts
                                them (mesh: its tiles, iso: its brick
                                tasks), else 0 */
    engine_error err;        /* why engine_voxelize failed (kind ENGINE_OK,
                                msg "" if it did not) */
} engine_result;

/* Must be called from a thread that outlives the engine: the workers get
 * SIGKILL when the thread that forked them exits (PR_SET_PDEATHSIG). */
int engine_create(const engine_opts *o, engine **out, err_info *err);
/* Tells the workers to exit, unmaps and removes the segment while they
 * go, and reaps them (SIGKILL after 2 s). */
void engine_destroy(engine *e);
/* The end of a process that exits next, its output whole: the workers told
 * to exit, the segment's name removed, and nothing waited for.  The
 * workers let go of stdin, stdout and stderr and keep the segment mapped
 * until this thread is gone (PR_SET_PDEATHSIG), so the pages are freed by
 * the last of them after the process exits, not by it; the caller's own
 * mapping is unmapped on a thread of its own beside what it does next
 * (its exit finishes it); the init process (or a subreaper) reaps them.
 * engine_destroy's cost at the end of a large job (its pages freed, the
 * workers reaped) is then nobody's wait. */
void engine_abandon(engine *e);
/* engine_abandon, the caller's mapping left as it is: for a process that
 * hands its memory to afterexit_leave (common/afterexit.h), whose helper
 * tears it down after the exit; unmapping it here would only make the
 * exit wait for the unmapping thread (and the caller's page faults for
 * its lock). */
void engine_leave(engine *e);
int engine_workers(const engine *e);
/* Worker i's pid and the CPU it is pinned to (tests, status pages). */
int engine_worker_pid(const engine *e, int i);
int engine_worker_cpu(const engine *e, int i);

/* A worker as the master sees it now (status pages, logs). */
typedef enum {
    ENGINE_WORKER_IDLE = 0,
    ENGINE_WORKER_BUSY,      /* holds a task, its heartbeat moves */
    ENGINE_WORKER_STALLED,   /* holds a task, no heartbeat for over a second */
    ENGINE_WORKER_STARTING,  /* no process: being forked again */
} engine_worker_state;

typedef struct {
    int pid, cpu;
    engine_worker_state state;
    double quiet;            /* seconds since its heartbeat last moved (busy) */
    uint32_t replaced;       /* times this slot's worker died or was killed
                                and was forked again, since engine_create */
    uint32_t stalls;         /* ... of which for making no progress */
    uint32_t unanswered;     /* ... of which for not letting go of a cancelled
                                or failed job (stopped, or silent) */
    uint32_t ended;          /* tasks its process ended and the master took */
    /* The last one killed for making no progress: its pid, how long it had
     * been quiet and its process state then ('T' stopped, 'R' running...). */
    int stalled_pid;
    double stalled_quiet;
    char stalled_state;
} engine_worker_info;

/* 0, or -EINVAL for a bad index. */
int engine_worker_info_get(const engine *e, int i, engine_worker_info *out);

/* Between jobs: reap the workers that died since the last job (or since
 * the last call) and fork each again on its CPU.  Returns how many were
 * forked again (engine_worker_pid then gives the new pids), or -errno when
 * one could not be (its slot stays empty, and the next call or job tries
 * again), or -EBUSY from inside a job.  engine_voxelize does the same when
 * a job starts; a long-lived caller (the daemon) calls this while idle so
 * that a dead worker is replaced before the next job comes. */
int engine_check_workers(engine *e);

/* The caller is done with the last job's result: its pages (beyond
 * keep_bytes) go back to tmpfs now.  engine_pipeline_run calls it at the end of
 * every job. */
void engine_release(engine *e);
/* From now on the pages a job gives back at its end, and engine_release's,
 * go back at engine_tidy (or at the next job's start, or with the
 * segment): a caller that has an answer to give (voxd's reply, vox's file)
 * gives it first.  The bytes of every job are the same either way. */
void engine_lazy_release(engine *e);
/* The pages a lazy engine's last job left to give back, given back now. */
void engine_tidy(engine *e);

#endif
