/* The core's services to a worker's kernels: the queue output of Figure 3
 * (one entry at a time, sleeping while the 8 entries are full). */
#include "work.h"

#include <errno.h>
#include <unistd.h>

#include "prefault.h"

void worker_check_parent(const worker_ctx *w)
{
    if (getppid() != w->h->master_pid) _exit(1);
}

void worker_ring_master(worker_ctx *w)
{
    shm_wake_if_sleeping(&w->h->doorbell, &w->h->master_sleeping);
}

int worker_aborted(const worker_ctx *w)
{
    /* relaxed: a flag checked between records; the master's fence and
     * wake (shm_wake_if_sleeping) reach a worker that sleeps. */
    return atomic_load_explicit(&w->h->abort_gen, memory_order_relaxed) ==
           w->task_gen;
}

/* size bytes from the shared counter; UINT64_MAX when they do not fit */
static uint64_t take_shared(atomic_ullong *bump, uint64_t cap, uint64_t size)
{
    /* relaxed: only the uniqueness of the ranges matters; the bytes are
     * published to the master by the done_seq release. */
    uint64_t off = atomic_fetch_add_explicit(bump, size, memory_order_relaxed);
    return off > cap || size > cap - off ? UINT64_MAX : off;
}

uint64_t worker_chunk_take(worker_ctx *w, worker_chunk *c, atomic_ullong *bump,
                           uint64_t area_off, uint64_t cap, uint64_t size)
{
    if (c->end - c->next < size && size <= WORKER_CHUNK) {
        /* relaxed: a hint; take_shared decides */
        uint64_t used = atomic_load_explicit(bump, memory_order_relaxed);
        uint64_t at = used <= cap && cap - used > (uint64_t)WORKER_CHUNK_SPARE * WORKER_CHUNK
                          ? take_shared(bump, cap, WORKER_CHUNK)
                          : UINT64_MAX;
        if (at != UINT64_MAX) {
            c->next = at, c->end = at + WORKER_CHUNK;
            prefault_write((uint8_t *)shm_at(w->base, area_off) + at, WORKER_CHUNK);
        }
    }
    if (c->end - c->next >= size) {
        c->next += size;
        return c->next - size;
    }
    return take_shared(bump, cap, size);
}

shm_entry *worker_entry_begin(worker_ctx *w, uint16_t type)
{
    shm_slot *s = w->s;
    queue_idx *q = &w->lane->q;
    worker_tick(w);
    while (queue_space(q) == 0) {
        if (worker_aborted(w)) return NULL;
        worker_ring_master(w); /* entries published without a ring */
        unsigned v = shm_sleep_begin(&s->wake, &s->sleeping);
        if (queue_space(q) == 0 && !worker_aborted(w))
            shm_futex_wait(&s->wake, v, WORKER_WAIT_NS);
        shm_sleep_end(&s->sleeping);
        worker_check_parent(w);
        worker_tick(w); /* waiting on the master is not a stall */
    }
    shm_entry *en = &w->lane->ent[queue_head(q)];
    en->kind = (uint16_t)w->task_kind;
    en->type = type;
    en->count = 0;
    return en;
}

/* A re-run after a death skips the entries the master already has: the
 * kernel's output is deterministic. */
int worker_entry_end(worker_ctx *w)
{
    if (w->skip) {
        w->skip--;
    } else {
        queue_publish(&w->lane->q);
        worker_ring_master(w);
    }
    return worker_aborted(w) ? -ECANCELED : 0;
}
