/* Sync behind a file's writers: see syncbehind.h. */
#include "syncbehind.h"

#include <errno.h>
#include <signal.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "thread_name.h"

/* Until stop, or PERIOD_MS from now: 1 when stopped. */
static int wait_period(syncbehind *s)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    ts.tv_nsec += SYNCBEHIND_PERIOD_MS * 1000000L;
    if (ts.tv_nsec >= 1000000000L) ts.tv_sec++, ts.tv_nsec -= 1000000000L;
    pthread_mutex_lock(&s->mu);
    while (!s->stop && pthread_cond_timedwait(&s->cv, &s->mu, &ts) != ETIMEDOUT) {
    }
    int stop = s->stop;
    pthread_mutex_unlock(&s->mu);
    return stop;
}

static void *sync_run(void *ud)
{
    syncbehind *s = ud;
    thread_name("sync");
    long long synced = 0;
    while (!wait_period(s)) {
        struct stat st;
        if (fstat(s->fd, &st)) break;
        if (st.st_size - synced < SYNCBEHIND_BYTES) continue;
        /* a hint only: its error, if any, is the commit's fsync's to tell */
        if (fdatasync(s->fd)) break;
        synced = st.st_size; /* at least these bytes are on the disk */
        atomic_fetch_add_explicit(&s->flushes, 1, memory_order_relaxed);
    }
    return NULL;
}

void syncbehind_start(syncbehind *s, int fd)
{
    s->fd = fd;
    s->stop = 0;
    s->started = 0;
    atomic_init(&s->flushes, 0);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&s->cv, &ca);
    pthread_condattr_destroy(&ca);
    pthread_mutex_init(&s->mu, NULL);
    /* every signal blocked in it: they stay the caller's (its interrupts) */
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    s->started = !pthread_create(&s->thread, NULL, sync_run, s);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    if (!s->started) {
        pthread_cond_destroy(&s->cv);
        pthread_mutex_destroy(&s->mu);
    }
}

void syncbehind_stop(syncbehind *s)
{
    if (!s->started) return;
    pthread_mutex_lock(&s->mu);
    s->stop = 1;
    pthread_cond_signal(&s->cv);
    pthread_mutex_unlock(&s->mu);
    pthread_join(s->thread, NULL);
    pthread_cond_destroy(&s->cv);
    pthread_mutex_destroy(&s->mu);
    s->started = 0;
}
