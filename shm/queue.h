/* queue — the 8-entry single-producer single-consumer queue of Figure 3.
 *
 * Only the two indices live here; the entries are an array of QUEUE_ENTRIES
 * elements next to them (their type is the user's).  Both indices count
 * entries since the queue was reset and wrap modulo 2^32; entry i lives in
 * element i % QUEUE_ENTRIES.
 *   - prod: entries published; written by the producer only (a worker).
 *   - cons: entries consumed;  written by the consumer only (the master).
 * The producer fills element prod % 8, then publishes it by storing prod+1
 * with release order; the consumer loads prod with acquire order, so the
 * entry's bytes are visible before it reads them.  Symmetrically the
 * consumer stores cons with release after it is done reading an entry, and
 * the producer loads cons with acquire before reusing that element.  No lock
 * is shared; the atomics are lock-free and address-free, so this works
 * between processes in shared memory.  Sleeping when empty or full is the
 * user's business (futexes in the engine).
 */
#ifndef VOXD_QUEUE_H
#define VOXD_QUEUE_H

#include <stdatomic.h>
#include <stdint.h>

#define QUEUE_ENTRIES 8u

typedef struct {
    /* On separate cache lines: each is written by one side only. */
    _Alignas(64) atomic_uint prod;
    _Alignas(64) atomic_uint cons;
} queue_idx;

/* Both sides must be quiescent (no job running). */
static inline void queue_reset(queue_idx *q, unsigned at)
{
    /* relaxed: the caller publishes the reset through its own release
     * (the engine's task sequence number). */
    atomic_store_explicit(&q->prod, at, memory_order_relaxed);
    atomic_store_explicit(&q->cons, at, memory_order_relaxed);
}

/* ---- producer side ---- */

/* Free elements (0..8).  acquire pairs with the consumer's release in
 * queue_consumed(): the element it finished reading may be overwritten. */
static inline unsigned queue_space(queue_idx *q)
{
    unsigned p = atomic_load_explicit(&q->prod, memory_order_relaxed);
    unsigned c = atomic_load_explicit(&q->cons, memory_order_acquire);
    return QUEUE_ENTRIES - (p - c);
}

/* Element index the producer fills next (valid when queue_space() > 0). */
static inline unsigned queue_head(queue_idx *q)
{
    /* relaxed: prod is only written by this (the producing) side */
    return atomic_load_explicit(&q->prod, memory_order_relaxed) %
           QUEUE_ENTRIES;
}

/* Publish the filled element.  release pairs with the consumer's acquire in
 * queue_ready(). */
static inline void queue_publish(queue_idx *q)
{
    unsigned p = atomic_load_explicit(&q->prod, memory_order_relaxed);
    atomic_store_explicit(&q->prod, p + 1, memory_order_release);
}

/* ---- consumer side ---- */

/* Published entries not consumed yet.  acquire pairs with queue_publish()'s
 * release.  The count comes from the other process: the caller checks that
 * it is <= QUEUE_ENTRIES before trusting it. */
static inline unsigned queue_ready(queue_idx *q)
{
    unsigned p = atomic_load_explicit(&q->prod, memory_order_acquire);
    unsigned c = atomic_load_explicit(&q->cons, memory_order_relaxed);
    return p - c;
}

/* Element index of the oldest unconsumed entry. */
static inline unsigned queue_tail(queue_idx *q)
{
    /* relaxed: cons is only written by this (the consuming) side */
    return atomic_load_explicit(&q->cons, memory_order_relaxed) %
           QUEUE_ENTRIES;
}

/* Release n entries back to the producer.  release pairs with the acquire
 * in queue_space(). */
static inline void queue_consumed(queue_idx *q, unsigned n)
{
    unsigned c = atomic_load_explicit(&q->cons, memory_order_relaxed);
    atomic_store_explicit(&q->cons, c + n, memory_order_release);
}

#endif
