/* shm — the engine's shared-memory segment: layout and creation.
 *
 *   header | slot 0 .. slot N-1 | work stack | data
 *
 * Offsets from the segment's base, never pointers (a process may map the
 * segment anywhere).  This file is the core's contract, the same for every
 * kind of job: slots with their task and two 8-entry queues, the work stack of
 * tasks, the job's generation.  The data area belongs to the job's kind:
 * shm/kinds.h says what each kind keeps there.
 *
 * Who writes what: the master writes the header and, in each slot, the
 * task fields and the queue's consumer index; a worker writes only its own
 * slot's worker fields, its queue entries and producer index, and what its
 * kind's block says it may (the encode kind: the records and bricks it
 * claimed through the block's shared counters; the implicit kind: the
 * octree cells of the blocks it claimed).  The master treats what a worker wrote as untrusted.
 *
 * Sleeping: every futex word here is 32 bits and used without
 * FUTEX_PRIVATE_FLAG (the segment is shared between processes).  A side
 * that sleeps sets its `sleeping` flag, issues a seq_cst fence, reads the
 * futex word, re-checks its condition and only then waits on the value it
 * read; the side that changes the condition stores it, issues a seq_cst
 * fence and, if the flag is set, bumps the word and wakes.  The two fences
 * (Dekker) guarantee that either the sleeper sees the new condition or the
 * waker sees the flag: no lost wakeup, and no syscall when nobody sleeps.
 */
#ifndef VOXD_SHM_H
#define VOXD_SHM_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <sys/types.h>

#include "err.h"
#include "queue.h"

#define SHM_MAGIC 0x44584f56u /* "VOXD" */
#define SHM_VERSION 4u
#define SHM_DEFAULT_BYTES ((size_t)2 << 30)   /* 2 GiB, sparse */
#define SHM_MIN_DATA ((size_t)1 << 20)        /* data area at least 1 MiB */

_Static_assert(ATOMIC_INT_LOCK_FREE == 2, "lock-free int atomics needed");
_Static_assert(ATOMIC_LLONG_LOCK_FREE == 2, "lock-free 64-bit atomics needed");

/* What the master hands a worker: a task of a job kind (shm/kinds.h).
 * The core's own kind, SHM_KIND_CORE, has one operation: exit. */
typedef struct {
    uint32_t kind;        /* shm_kind */
    uint32_t op;          /* the kind's operation */
    uint8_t arg[16];      /* the kind's argument (implicit: an octant) */
} shm_task;

/* SHM_TASK_ARG(name, T) defines `static inline T name(const shm_task *t)`,
 * task t's argument read as a T (each kind's argument type, shm/kinds.h),
 * and checks at compile time that a T fits in arg. */
#define SHM_TASK_ARG(name, T)                                                  \
    _Static_assert(sizeof(T) <= sizeof ((shm_task *)0)->arg, #T " fits a task"); \
    static inline T name(const shm_task *t)                                    \
    {                                                                          \
        T a;                                                                   \
        memcpy(&a, t->arg, sizeof a);                                          \
        return a;                                                              \
    }

#define SHM_OP_EXIT 1u    /* SHM_KIND_CORE: leave the loop */
#define SHM_OP_LEAVE 2u   /* SHM_KIND_CORE: let go of stdio, keep the segment
                             until the master is gone, exit (engine_abandon) */

/* What a worker hands back: one queue entry of its task's kind, `count`
 * records of the kind's record `type` in the payload.  The master checks
 * kind, type and count before it reads a record. */
#define SHM_PAYLOAD_BYTES 8192u
typedef struct {
    uint16_t kind;        /* the kind of the task that wrote it */
    uint16_t type;        /* the kind's record type */
    uint32_t count;       /* records in the payload */
    _Alignas(16) uint8_t payload[SHM_PAYLOAD_BYTES];
} shm_entry;

/* Derived state of a slot (shm_slot_state()). */
enum shm_slot_state { SHM_IDLE = 0, SHM_BUSY = 1, SHM_DONE = 2 };

/* One task's queue: the 8-entry queue of Figure 3 and its entries. */
typedef struct {
    queue_idx q;          /* prod: worker; cons: master */
    shm_entry ent[QUEUE_ENTRIES];
} shm_lane;

typedef struct {
    /* ---- written by the master ---- */
    /* Bumped (release) after the task fields below are written; the worker
     * loads it with acquire.  A worker is busy while done_seq is behind
     * the last task it was given or offered: every task, given or
     * offered, has the sequence number after the one before it on this
     * slot, and the worker runs and ends them in that order. */
    _Alignas(64) atomic_uint task_seq;
    /* The futex word the worker sleeps on (idle, or queue full).  Bumped by
     * the master when it sees `sleeping` set (Dekker, see above). */
    atomic_uint wake;
    uint32_t task_gen;    /* job generation the task belongs to */
    uint32_t task_skip;   /* entries of this task already consumed (a
                             re-run after a worker died skips them) */
    shm_task task;        /* the task assigned: handed out again if the
                             worker dies */
    int32_t pid;          /* the worker's pid */
    int32_t cpu;          /* the CPU it is pinned to */
    /* A second task offered while the worker runs its current one (a kind
     * with engine_kind.prefetch), so that the worker starts it without
     * waiting for the master.  Offered only once the worker has copied
     * its current task (run_seq), so the offered one is always that
     * task's sequence number + 1: next_task and next_gen written, then
     * `next` stored to 1 (release).  Whoever exchanges `next` for 0 and
     * reads 1 owns the task (acq_rel on both sides): the worker when its
     * task ends, or the master taking it back for an idle worker. */
    shm_task next_task;
    uint32_t next_gen;
    _Alignas(64) atomic_uint next;

    /* ---- written by the worker ---- */
    /* Stored (release) when the task is finished, after its last entry is
     * published and the counters below are written; the master loads it
     * with acquire. */
    _Alignas(64) atomic_uint done_seq;
    /* 1 while the worker is about to wait or waits on `wake`.  seq_cst (the
     * Dekker pair with the master's fence after it changes task_seq, the
     * queue's cons or the header's abort_gen). */
    atomic_int sleeping;
    /* The sequence number of the task the worker runs, stored (release)
     * once it has copied the task (given or offered); the master's acquire
     * load pairs with it before it offers the next one. */
    atomic_uint run_seq;
    /* Negative errno of task seq at error[seq & 1], 0 if none (published
     * by the done_seq release). */
    int32_t error[2];
    uint32_t job_gen;     /* job the counters below are for */
    uint64_t job_tested;  /* boxes tested in this job */
    uint64_t job_cpu_ns;  /* CPU time spent on this job's tasks */
    /* The heartbeat: advanced by the worker every few milliseconds of a
     * task's work (worker_tick), so the master can tell a worker that makes
     * no progress (stopped, hung) from a busy one.  relaxed on both sides:
     * the master only compares successive values; nothing is published
     * with it. */
    atomic_uint beat;

    /* Task seq writes its entries in lane[seq & 1] only; the master drains
     * that lane for it, and gives or offers task seq + 2 only after it has
     * drained and ended task seq: a lane is never shared by two live tasks
     * (docs/design.md, "The next task offered"). */
    shm_lane lane[2];
} shm_slot;

typedef struct {
    uint32_t magic, version;
    int32_t master_pid;
    uint32_t workers;
    uint64_t bytes;
    uint64_t slots_off, slot_bytes;
    uint64_t stack_off, stack_cap;   /* work stack: stack_cap tasks */
    uint64_t data_off, data_bytes;

    /* The job, written by the master before a job's first task (the
     * task_seq release publishes it): its kind's block in the data area
     * (shm/kinds.h), where the kind keeps its input and shared state. */
    uint32_t gen;                    /* current job generation (master) */
    uint32_t job_kind;               /* shm_kind */
    uint64_t job_off, job_bytes;

    /* == gen when the master abandons the job.  Workers load it relaxed
     * between octants; the master's fence + wake makes sleepers see it. */
    _Alignas(64) atomic_uint abort_gen;

    /* The master's futex word, bumped by workers that see master_sleeping
     * set after they published something (Dekker, see above). */
    _Alignas(64) atomic_uint doorbell;
    atomic_int master_sleeping;      /* seq_cst, the Dekker flag */
} shm_header;

typedef struct {
    uint8_t *base;
    size_t bytes;
    int fd;
    int named;          /* unlink at destroy */
    char name[64];
} shm_seg;

/* Bytes the fixed part needs for n workers, plus the minimum data area. */
size_t shm_min_bytes(uint32_t workers);
/* The default segment for n workers: 2 GiB, but at most half of /dev/shm's
 * free space (at least the fixed part's need, where that fits). */
size_t shm_default_bytes(uint32_t workers);
/* Create (O_EXCL, 0600), size and map the segment and write its header.
 * name NULL: a private unique name, unlinked right after mapping.
 * bytes 0: shm_default_bytes.  Returns
 * 0 or a negative errno with a message in err. */
int shm_create(shm_seg *s, const char *name, size_t bytes, uint32_t workers,
               err_info *err);
void shm_destroy(shm_seg *s);

static inline shm_header *shm_hdr(uint8_t *base)
{
    return (shm_header *)base;
}
static inline shm_slot *shm_slot_at(uint8_t *base, uint32_t i)
{
    shm_header *h = shm_hdr(base);
    return (shm_slot *)(base + h->slots_off + (uint64_t)i * h->slot_bytes);
}
static inline void *shm_at(uint8_t *base, uint64_t off)
{
    return base + off;
}

/* For observers (status pages): idle, busy (task running), or done (task
 * finished, queue not drained yet).  A snapshot, not a synchronization. */
static inline int shm_slot_state(shm_slot *s)
{
    /* acquire: pairs with the releases of task_seq and done_seq; run_seq
     * is ahead of task_seq when the worker runs an offered task */
    unsigned t = atomic_load_explicit(&s->task_seq, memory_order_acquire);
    unsigned r = atomic_load_explicit(&s->run_seq, memory_order_acquire);
    unsigned d = atomic_load_explicit(&s->done_seq, memory_order_acquire);
    if ((int)(r - t) > 0) t = r;
    /* relaxed: a snapshot; an offered task (next) is work to come */
    if ((int)(t - d) > 0 || atomic_load_explicit(&s->next, memory_order_relaxed)) return SHM_BUSY;
    return queue_ready(&s->lane[0].q) || queue_ready(&s->lane[1].q) ? SHM_DONE : SHM_IDLE;
}

/* Futex wrappers (non-private: shared between processes).  wait returns
 * when *w != val, on a wake, a signal, or after timeout_ns (0 = none). */
void shm_futex_wait(atomic_uint *w, unsigned val, long timeout_ns);
void shm_futex_wake(atomic_uint *w, int n);
/* The waker's half of the Dekker pair: after changing the condition. */
void shm_wake_if_sleeping(atomic_uint *w, atomic_int *sleeping);

/* The sleeper's half: set the flag, fence, and return the value of w to
 * wait on; the caller then re-checks its condition and, if still unmet,
 * calls shm_futex_wait(w, value, ...); then shm_sleep_end(). */
static inline unsigned shm_sleep_begin(atomic_uint *w, atomic_int *sleeping)
{
    /* relaxed store + seq_cst fence: the Dekker pair of the fence in
     * shm_wake_if_sleeping(). */
    atomic_store_explicit(sleeping, 1, memory_order_relaxed);
    atomic_thread_fence(memory_order_seq_cst);
    /* acquire: pairs with the waker's fetch_add, so a bumped value comes
     * with the condition it announced. */
    return atomic_load_explicit(w, memory_order_acquire);
}
static inline void shm_sleep_end(atomic_int *sleeping)
{
    /* relaxed: a stale 1 only costs the other side one spare wake. */
    atomic_store_explicit(sleeping, 0, memory_order_relaxed);
}

#endif
