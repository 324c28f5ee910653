/* alloc_fail — every allocation of a call failing in turn, for the suites
 * whose binary is linked with
 * -Wl,--wrap=malloc,--wrap=calloc,--wrap=realloc,--wrap=aligned_alloc,--wrap=free
 * (the Makefile names them): the allocations of the library's code (and
 * the test's) pass through the wrappers below.  Armed, they count the
 * allocations, fail the one whose turn it is, and keep the others in a
 * table until they are freed; alloc_fail_each runs a call with the first
 * failing, then the second, and so on until a run makes no more, and
 * wants each run to give its whole answer (the call checks that itself)
 * or -ENOMEM with "out of memory" in its message, and every block the run
 * allocated freed by its end.
 *
 * The table, not LeakSanitizer, says a run leaked: LSan scans the stacks
 * conservatively, and a pointer left in a dead frame that no later deeper
 * call overwrote keeps its block "reachable" (a leak put on vod_read's
 * make_refs error path on purpose went unreported; the table caught it).
 * Allocations inside other libraries (libc's strdup, libdeflate, json-c)
 * are not wrapped: not counted, not failed; nor are their frees, so a block
 * the library's code allocated must be freed through this binary's free
 * (protobuf-c's free_unpacked given an allocator that calls it).  The library's threads
 * allocate too: the count is atomic, the table under a lock, and with
 * several threads which allocation is the n-th may differ between runs;
 * each run's answer is checked whichever it was.  ALLOC_FAIL_VERBOSE in
 * the environment prints each call's count of allocations.
 *
 * Include it in one file of a binary (it defines the wrappers). */
#ifndef VOXD_TEST_ALLOC_FAIL_H
#define VOXD_TEST_ALLOC_FAIL_H

#include <criterion/criterion.h>
#include <errno.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"

void *__real_malloc(size_t size);
void *__real_calloc(size_t n, size_t size);
void *__real_realloc(void *p, size_t size);
void *__real_aligned_alloc(size_t align, size_t size);
void __real_free(void *p);
void *__wrap_malloc(size_t size);
void *__wrap_calloc(size_t n, size_t size);
void *__wrap_realloc(void *p, size_t size);
void *__wrap_aligned_alloc(size_t align, size_t size);
void __wrap_free(void *p);

/* Armed: allocations counted, and the one numbered fail_at (1-based)
 * fails.  Relaxed: the count only numbers the allocations; the test reads
 * it after the call has joined its threads. */
static atomic_bool af_armed;
static atomic_ulong af_made, af_fail_at;

/* The blocks allocated while armed and not freed yet (AF_LIVE_MAX bounds
 * them: past it the run fails, saying so). */
#define AF_LIVE_MAX 65536
static pthread_mutex_t af_lock = PTHREAD_MUTEX_INITIALIZER;
static void *af_live[AF_LIVE_MAX];
static size_t af_nlive;
static bool af_overflow;

/* The allocations of exactly af_watch bytes while armed: how many, and the
 * number (as af_made counts) of the last.  Relaxed, as af_made. */
static atomic_size_t af_watch;
static atomic_ulong af_watched, af_watched_last;

static int af_fail_now(size_t size)
{
    if (!atomic_load_explicit(&af_armed, memory_order_relaxed)) return 0;
    unsigned long n = atomic_fetch_add_explicit(&af_made, 1, memory_order_relaxed) + 1;
    if (size == atomic_load_explicit(&af_watch, memory_order_relaxed)) {
        atomic_fetch_add_explicit(&af_watched, 1, memory_order_relaxed);
        atomic_store_explicit(&af_watched_last, n, memory_order_relaxed);
    }
    return n == atomic_load_explicit(&af_fail_at, memory_order_relaxed);
}

/* p out of the table (the caller holds af_lock); whether it was there. */
static bool af_forget(void *p)
{
    for (size_t i = af_nlive; p && i-- > 0;)
        if (af_live[i] == p) {
            af_live[i] = af_live[--af_nlive];
            return true;
        }
    return false;
}

/* p into the table when armed (and was, realloc's old block, out of it). */
static void *af_track(void *p, void *was)
{
    pthread_mutex_lock(&af_lock);
    bool tracked = af_forget(was);
    if (p && (tracked || atomic_load_explicit(&af_armed, memory_order_relaxed))) {
        if (af_nlive < AF_LIVE_MAX) af_live[af_nlive++] = p;
        else af_overflow = true;
    }
    pthread_mutex_unlock(&af_lock);
    return p;
}

void *__wrap_malloc(size_t size)
{
    return af_fail_now(size) ? NULL : af_track(__real_malloc(size), NULL);
}

void *__wrap_calloc(size_t n, size_t size)
{
    return af_fail_now(n * size) ? NULL : af_track(__real_calloc(n, size), NULL);
}

void *__wrap_realloc(void *p, size_t size)
{
    if (af_fail_now(size)) return NULL; /* p stays p's */
    void *q = __real_realloc(p, size);
    return q ? af_track(q, p) : NULL;
}

void *__wrap_aligned_alloc(size_t align, size_t size)
{
    return af_fail_now(size) ? NULL : af_track(__real_aligned_alloc(align, size), NULL);
}

void __wrap_free(void *p)
{
    pthread_mutex_lock(&af_lock);
    af_forget(p);
    pthread_mutex_unlock(&af_lock);
    __real_free(p);
}

/* The test's own memory while armed (a fresh input for each run, a sink's
 * buffer), never failed nor counted; free it with free. */
static inline void *af_test_malloc(size_t size)
{
    return __real_malloc(size ? size : 1);
}

static inline void *af_test_realloc(void *p, size_t size)
{
    return __real_realloc(p, size ? size : 1);
}

static void af_arm(unsigned long at)
{
    atomic_store(&af_made, 0);
    atomic_store(&af_watched, 0);
    atomic_store(&af_watched_last, 0);
    atomic_store(&af_fail_at, at);
    atomic_store(&af_armed, true);
}

/* Disarms; whether the armed allocation was made (and failed).  Every
 * block allocated while armed must be free by then. */
static bool af_disarm(const char *what)
{
    atomic_store(&af_armed, false);
    pthread_mutex_lock(&af_lock);
    size_t left = af_nlive;
    bool overflow = af_overflow;
    af_nlive = 0;
    af_overflow = false;
    pthread_mutex_unlock(&af_lock);
    unsigned long at = atomic_load(&af_fail_at);
    cr_assert(!overflow, "%s: more than %d blocks allocated at once", what, AF_LIVE_MAX);
    cr_assert_eq(left, 0, "%s, allocation %lu failing: %zu blocks allocated during the run "
                 "were never freed", what, at, left);
    return atomic_load(&af_made) >= at;
}

/* One run of the call under test: its return code; on a failure its
 * message copied into msg (ERR_MSG_MAX bytes), or msg left "" where the
 * call returns a code alone; on success the run checks its answer itself
 * and frees what it got. */
typedef int (*alloc_fail_run)(void *ctx, char *msg);

/* run(ctx) with each allocation failing in turn, what naming it in the
 * failures; said: a failure must say "out of memory" (else the call has
 * no message, and its code alone is checked).  Returns the allocations of
 * a whole run (the last, which failed none). */
static inline unsigned long alloc_fail_runs(alloc_fail_run run, void *ctx, const char *what,
                                            bool said)
{
    for (unsigned long at = 1;; at++) {
        char msg[ERR_MSG_MAX] = "";
        af_arm(at);
        int rc = run(ctx, msg);
        bool failed_one = af_disarm(what);
        if (!failed_one) {
            cr_assert_eq(rc, 0, "%s, nothing failed: %d (%s)", what, rc, msg);
            if (getenv("ALLOC_FAIL_VERBOSE")) /* how far the runs reached */
                fprintf(stderr, "%s: %lu allocations\n", what, at - 1);
            return at - 1;
        }
        if (rc == 0) continue; /* it did without (run checked the answer) */
        cr_assert_eq(rc, -ENOMEM, "%s, allocation %lu failed: %d (%s)", what, at, rc, msg);
        cr_assert(!said || strstr(msg, "out of memory"), "%s, allocation %lu failed: \"%s\"",
                  what, at, msg);
    }
}

/* alloc_fail_runs of a call that says why it failed. */
static inline unsigned long alloc_fail_each(alloc_fail_run run, void *ctx, const char *what)
{
    return alloc_fail_runs(run, ctx, what, true);
}

#endif
