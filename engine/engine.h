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

#include "csg.h"
#include "err.h"
#include "expr.h"
#include "grid.h"
#include "iso.h"
#include "mesh_vox.h"
#include "octree.h"
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

typedef struct {
    const expr_tape *tape;
    grid_spec grid;
    engine_schedule schedule;
    /* Called by the master now and then (at most ~10 times a second). */
    void (*progress)(void *ud, const engine_progress *p);
    void *ud;
    /* Set to non-zero by anyone to stop the job: engine_voxelize returns
     * -ECANCELED.  Read with relaxed loads; nothing pairs with it. */
    const atomic_int *cancel;
    /* Subtree schedule: octants of this level and below go out whole (a
     * subtree of 2^split_level voxels per axis); 0 = automatic (depth-3,
     * within 1..6: many more tasks than workers). */
    int split_level;
    /* NULL: the whole grid.  Else only this octant's subtree, the octant
     * taken as kept by its parent's test (vox_mpi hands a rank the octants
     * its rank 0 kept); the voxels are those the whole grid's job gives
     * inside it, and the automatic split level is taken from its level. */
    const grid_octant *root;
} engine_job;

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

/* A kind's own figures: its member of engine_result.fig (the other
 * kinds' members share the bytes; the implicit kind has none of its own). */
typedef struct {
    uint32_t tiles;          /* tiles with triangles, each one task */
    double t_bin;            /* seconds binning the triangles to tiles */
    uint64_t disagreements;  /* repair modes: mesh_tile_stats, summed */
    uint64_t disagree_bricks;
} engine_mesh_figures;

/* Storage bricks evaluated, of which uniform (a table entry, no voxels
 * stored), operand subtrees decided from a uniform operand without
 * evaluating them, voxels the leaves sampled. */
typedef struct {
    uint64_t bricks, uniform, skipped, voxel_evals;
} engine_csg_figures;

typedef struct {
    uint32_t tasks;          /* brick tasks (iso_tasks) */
} engine_iso_figures;

typedef union {
    engine_mesh_figures mesh;
    engine_csg_figures csg;
    engine_iso_figures iso;
} engine_figures;

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
    engine_figures fig;      /* the job's kind's own figures */
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

/* Voxelize job; the octree stays in shared memory until the next job.
 * Returns 0, or a negative errno with r->err saying why (its kind):
 * ENGINE_CANCELLED, ENGINE_BAD_JOB, ENGINE_LIMIT (octree or work stack
 * full: the message says what to raise), ENGINE_CRASHED (an octant killed
 * its worker twice: the message names it), ENGINE_FAULT; the engine is then
 * ready for the next job.  A worker that dies during a job is forked again
 * and its octant handed out again (its output is deterministic, so the
 * entries already taken are skipped); see Robustness above. */
int engine_voxelize(engine *e, const engine_job *job, engine_result *r);
/* A triangle mesh voxelized tile by tile (mesh_vox.h) into a brick-sparse
 * volume in shared memory: the triangles and their bins are copied into
 * the segment, each worker runs whole tiles (the heaviest first) and
 * writes their bricks, and a worker that dies has its tile run again (the
 * tiles are deterministic: the same bricks are written again).  The
 * result stays in shared memory until the next job, for engine_write_vod.
 * Errors as engine_voxelize's (ENGINE_LIMIT: the volume or the mesh
 * outgrew shared memory). */
typedef struct {
    const mesh *mesh;
    grid_spec grid;
    mesh_vox_opts opts;
    /* The channel the VOD will be written in (0: not known): each tile
     * then builds the volume's low mip levels of that channel under its
     * own column (vod_volume_mip_columns), which the write's prepare()
     * would otherwise build in the master alone. */
    int mip_channel;
    void (*progress)(void *ud, const engine_progress *p);
    void *ud;
    const atomic_int *cancel;   /* as engine_job.cancel */
    /* NULL: every tile.  Else only the tiles tx in [tiles[0], tiles[2]),
     * ty in [tiles[1], tiles[3]) (vox_mpi's column groups): the volume
     * holds those columns alone, each as the whole grid's job makes it. */
    const uint32_t *tiles;
} engine_mesh_job;
int engine_mesh(engine *e, const engine_mesh_job *job, engine_result *r);
/* A volume CSG tree (csg.h) evaluated brick by brick into a brick-sparse
 * volume in shared memory (densities, occupancy or surface voxels): the
 * tree is copied into the segment, each worker evaluates runs of storage
 * bricks (csg_eval_store), and a worker that dies has its run evaluated
 * again (a brick is a pure function of the tree: the same bytes).  The
 * result stays for engine_write_vod, as a mesh job's.  Errors as
 * engine_mesh's. */
typedef struct {
    const csg_tree *tree;       /* parsed (and so checked) by the caller */
    grid_spec grid;
    int channel;                /* VOXEL_CH_DENSITY, _OCCUPANCY or _SURFACE (csg_eval_store) */
    void (*progress)(void *ud, const engine_progress *p);
    void *ud;
    const atomic_int *cancel;   /* as engine_job.cancel */
    /* NULL: every storage brick.  Else only the bricks inside this
     * octant's cube (vox_mpi's subtrees; its side a multiple of
     * CSG_VOLUME_BRICK), each as the whole grid's job makes it. */
    const grid_octant *root;
} engine_csg_job;
int engine_csg(engine *e, const engine_csg_job *job, engine_result *r);

/* Marching cubes over an open VOD file (iso.h) by the workers: the raw
 * bricks of the levels p reads are copied into the segment, each worker
 * claims brick tasks until none is left and packs each task's piece into
 * shared memory; a task a worker did not finish (it died, or the pieces
 * outgrew the segment) is run by the caller's thread, and the pieces are
 * welded here in task order, so *out is iso_run_serial's mesh, byte for
 * byte.  Free it with iso_mesh_free.  Errors as engine_voxelize's
 * (ENGINE_LIMIT: the bricks did not fit, or more than 2^32 vertices). */
typedef struct engine_iso_weld engine_iso_weld;
typedef struct {
    const vod_file *file;
    const iso_params *p;        /* iso_params_make's, for file */
    void (*progress)(void *ud, const engine_progress *p);
    void *ud;
    const atomic_int *cancel;   /* as engine_job.cancel */
    /* Optional: once the mesh's size and place in shared memory are
     * known, before it is welded, *weld is filled in and laid_out(ud, m)
     * called on the caller's thread: m (its counts, its arrays, still
     * being written) is final part by part as engine_iso_wait says, so a
     * writer may stream it while it is welded (vox mesh).  On success all
     * of it is final when engine_iso returns; on failure the caller sets
     * weld->stop before it lets go of the engine. */
    engine_iso_weld *weld;
    void (*laid_out)(void *ud, const iso_mesh *m);
} engine_iso_job;
int engine_iso(engine *e, const engine_iso_job *job, iso_mesh *out, engine_result *r);

/* The weld's progress, the caller's (engine_iso_job.weld); views of the
 * segment, valid until the engine's next job. */
struct engine_iso_weld {
    const void *results;        /* the pieces' results (their welded flags) */
    const uint64_t *vbase, *tbase; /* piece i's first vertex and triangle */
    uint64_t n;                 /* pieces */
    /* Pieces below it are known welded: raised by the waits.  Relaxed:
     * each wait reads the flags themselves with acquire. */
    atomic_uint_fast64_t known;
    atomic_int stop;            /* set by the caller: the waits give up */
};
/* Until the vertices (tris 0) or triangles (tris 1) below hi are welded:
 * 0, or -ECANCELED once w->stop is set. */
int engine_iso_wait(engine_iso_weld *w, int tris, uint64_t hi);

/* The last job's octree (a view into shared memory), NULL when the last
 * job failed, was not an implicit one, or there was none, or after
 * engine_release. */
octree *engine_octree(engine *e);
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
/* Write the last job's octree or volume as VOD, bricks encoded by the workers into
 * shared memory (what does not fit, or what a dying worker left undone, is
 * encoded by the caller's thread, which frees its encoder before
 * returning); the bytes are vod_write_octree()'s.  Returns 0, or a
 * negative errno with err saying why: ENGINE_LIMIT when the file would
 * pass the format's 4 GiB or shared memory is too small (the message names
 * what to change), ENGINE_SINK with the sink's own error as the code,
 * ENGINE_BAD_JOB (no octree, bad parameters), ENGINE_FAULT. */
int engine_write_vod(engine *e, const vod_params *p, vod_sink *sink,
                     vod_stats *st, engine_error *err);
/* The bricks engine_write_vod would write, without the file: the last
 * job's non-empty brick nodes in preorder, each node's record and encoded
 * bytes (a duplicate's data points at its first's), handed to deliver
 * with the source they came from (its mip levels made: fill() works at
 * every level) while they are still in shared memory.  vox_mpi's ranks
 * send their subtrees' bricks this way.  deliver returns 0 or a negative
 * errno (then ENGINE_SINK).  Errors as engine_write_vod's. */
typedef int (*engine_deliver)(void *ud, const vod_layout *L, const vod_source *src,
                              size_t n, const vod_node *nodes,
                              const vod_encoded *recs, const uint8_t *const *data);
int engine_encode_bricks(engine *e, const vod_params *p, engine_deliver deliver,
                         void *ud, vod_stats *st, engine_error *err);

#endif
