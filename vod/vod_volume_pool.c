/* vod_volume_pool — the pool's units for the writers of a volume's bricks
 * (vod_volume.c's bricks, vod_volume_pack.c's records).
 *
 * Writers in several processes (the engine's workers) take units from one
 * counter, pool_used.  Taken a record at a time, two writers' records lie
 * side by side on the pages, and every process takes a page fault at its
 * first store to each page it writes: the dragon's distance at 1024^3 took
 * some 34,000 of them, each costing microseconds on a virtual machine.  So
 * a thread takes POOL_CHUNK_BYTES at a time while the pool has more than
 * POOL_CHUNK_SPARE chunks left, gives its records out of that chunk, and
 * maps the chunk's pages in one call (prefault_write) as it takes it.  The
 * rest of a thread's last chunk stays unused (pool_used counts the units
 * taken, not the records'); near the end of the pool units are taken one
 * record at a time, so a pool that held its records before still does
 * (vod_volume_bytes sizes it).  A chunk is of one volume: the thread keeps
 * its volume and the pool's epoch beside it, and a new volume made at the
 * same address, or the pool given back (vod_vol_drop_mips), has another.
 * A process forked from a thread with a chunk (the engine's master forks
 * a worker's replacement mid-job) would inherit it and give out its units
 * a second time: the child forgets it (pthread_atfork). */
#include "vod_volume_int.h"

#include <pthread.h>

#include "prefault.h"

#define POOL_CHUNK_BYTES (1u << 20)
#define POOL_CHUNK_SPARE 64u

/* This thread's chunk: units [next, end) of volume v's pool at epoch. */
static _Thread_local struct {
    const vod_volume *v;
    uint64_t epoch;
    uint32_t next, end;
} mine;

/* In a forked child: the forking thread's chunk is its parent's. */
static void forget_chunk(void)
{
    mine.v = NULL;
}

static void watch_forks(void)
{
    (void)pthread_atfork(NULL, NULL, forget_chunk);
}

/* `units` units from the shared counter; the first's index (entry - 1),
 * or UINT32_MAX when they do not fit. */
static uint32_t take_shared(vod_volume *v, uint64_t units)
{
    if (units > v->pool_cap) return UINT32_MAX;
    uint32_t u = (uint32_t)units;
    /* relaxed: see pool_used's declaration (the bytes are published by
     * the end of the writers' phase) */
    uint32_t at = atomic_fetch_add_explicit(&v->pool_used, u, memory_order_relaxed);
    if (at > v->pool_cap - u) {
        /* full: give the count back (every other taker fails too until
         * the count is below the cap again) */
        atomic_fetch_sub_explicit(&v->pool_used, u, memory_order_relaxed);
        return UINT32_MAX;
    }
    return at;
}

/* A new chunk for this thread, when the pool has room to spare. */
static void take_chunk(vod_volume *v)
{
    uint64_t chunk = POOL_CHUNK_BYTES / v->unit;
    /* relaxed: a hint; take_shared decides */
    uint32_t used = atomic_load_explicit(&v->pool_used, memory_order_relaxed);
    if (chunk < 2 || used > v->pool_cap || v->pool_cap - used < POOL_CHUNK_SPARE * chunk) return;
    uint32_t at = take_shared(v, chunk);
    if (at == UINT32_MAX) return;
    mine.v = v, mine.epoch = v->pool_epoch;
    mine.next = at, mine.end = at + (uint32_t)chunk;
    prefault_write(brick_data(v, at + 1), chunk * v->unit);
}

uint32_t vod_vol_pool_units(vod_volume *v, uint64_t units)
{
    if (mine.v != v || mine.epoch != v->pool_epoch) mine.v = NULL;
    if (mine.v && mine.end - mine.next < units) mine.v = NULL; /* its rest unused */
    if (!mine.v) {
        static pthread_once_t once = PTHREAD_ONCE_INIT;
        pthread_once(&once, watch_forks);
        take_chunk(v);
    }
    if (mine.v && mine.end - mine.next >= units) {
        uint32_t at = mine.next;
        mine.next += (uint32_t)units;
        return at + 1;
    }
    uint32_t at = take_shared(v, units);
    if (at == UINT32_MAX) atomic_store_explicit(&v->pool_full, 1, memory_order_relaxed);
    return at == UINT32_MAX ? 0 : at + 1;
}
