/* work — what a worker's kernels see: the worker's context, the interface
 * each job kind implements on the worker side, and the core's services
 * for handing results back (the slot's 8-entry queue).
 *
 * The core (worker.c) waits for a task, finds its kind in the table, calls
 * the kind's begin() on the kind's first task of a job generation, then
 * run(); it publishes done_seq when run() returns.  A kernel hands results
 * back with worker_entry_begin() / worker_entry_end(): the entry is the queue
 * element the master reads once published; on a re-run after a death the
 * core skips the entries the master already took (kernels are
 * deterministic), so a kernel never needs to know.
 *
 * Liveness: a kernel calls worker_tick() every few milliseconds of work (the
 * implicit kind at each poll of its subdivision, the encode kind at every
 * brick and every subtree of the mip levels).  The master kills a worker
 * whose heartbeat stands still for the stall timeout while it holds a task
 * (engine_opts.stall_timeout) and hands its task out again as after a
 * crash.  The core ticks as a task starts and ends and at every entry, so
 * a kernel whose entries come often enough needs nothing more.
 */
#ifndef VOXD_WORK_H
#define VOXD_WORK_H

#include <stdint.h>

#include "kinds.h"
#include "shm.h"

#define WORKER_WAIT_NS 1000000000L /* waits re-check the parent once a second */

typedef struct worker_ctx {
    uint8_t *base;           /* the segment */
    shm_header *h;
    shm_slot *s;             /* this worker's slot */
    uint32_t task_gen;       /* the running task's job generation */
    unsigned given;          /* the last task_seq seen (a task given) */
    unsigned seq;            /* the running (or last) task's sequence number */
    shm_lane *lane;          /* its queue: s->lane[seq & 1] */
    uint32_t task_kind;      /* the running task's kind */
    uint32_t skip;           /* entries of the task still to skip */
    uint32_t gen;            /* job generation the counters are for */
    uint64_t cpu0;           /* CPU time at the job's first task */
    unsigned beats;          /* the heartbeat's value (worker_tick) */
    bool heap_kept;          /* freed memory kept since the last trim (worker_main) */
    uint32_t begun[SHM_KINDS]; /* job generation each kind was begun for */
    void *state[SHM_KINDS];    /* each kind's state, across jobs */
} worker_ctx;

typedef struct {
    const char *name;
    /* First task of a job of this kind: read the kind's block, set up
     * *state (kept across jobs; NULL at first).  0 or a negative errno. */
    int (*begin)(worker_ctx *w, void **state);
    /* Run task t.  0, -ECANCELED when the job was abandoned, or a
     * negative errno (the master fails the job with it). */
    int (*run)(worker_ctx *w, void *state, const shm_task *t);
    /* The worker exits: free *state. */
    void (*free)(void *state);
} worker_kind;

/* The heartbeat: "still working".  A store and an add, cheap enough for
 * every few hundred microseconds of work; too seldom (seconds apart) and
 * the master takes the worker for stalled. */
static inline void worker_tick(worker_ctx *w)
{
    /* relaxed: see shm_slot.beat (only this worker writes it) */
    atomic_store_explicit(&w->s->beat, ++w->beats, memory_order_relaxed);
}

/* Exit at once when the master is gone (checked after every wait). */
void worker_check_parent(const worker_ctx *w);
/* Ring the master's doorbell (after publishing something). */
void worker_ring_master(worker_ctx *w);
/* The job was abandoned (the master's abort_gen). */
int worker_aborted(const worker_ctx *w);
/* A worker's share of a bump allocator of the segment (the encoder's brick
 * area, the iso kind's arena): the counter is taken WORKER_CHUNK bytes at
 * a time while more than WORKER_CHUNK_SPARE chunks are left, the chunk's
 * pages mapped by one call (prefault.h), so that two workers never write
 * the same page and no page is faulted one store at a time; the rest of a
 * worker's last chunk stays unused, and near the area's end sizes are
 * taken one at a time.  Kept per job (zeroed when the job begins). */
#define WORKER_CHUNK (1u << 20)
#define WORKER_CHUNK_SPARE 64u
typedef struct {
    uint64_t next, end;
} worker_chunk;
/* size bytes of the area at area_off (cap bytes, counter *bump): their
 * offset in it, or UINT64_MAX when they do not fit. */
uint64_t worker_chunk_take(worker_ctx *w, worker_chunk *c, atomic_ullong *bump,
                           uint64_t area_off, uint64_t cap, uint64_t size);

/* The queue element to fill next, as an entry of `type` with count 0,
 * waiting while the queue is full; NULL when the job was abandoned. */
shm_entry *worker_entry_begin(worker_ctx *w, uint16_t type);
/* Publish the entry being filled; -ECANCELED when the job was abandoned
 * meanwhile, else 0. */
int worker_entry_end(worker_ctx *w);

#endif
