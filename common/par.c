/* par: see par.h. */
#include "par.h"

#include <pthread.h>
#include <sched.h>
#include <signal.h>

unsigned par_cpus(void)
{
    cpu_set_t set;
    if (sched_getaffinity(0, sizeof set, &set) != 0) return 1;
    int n = CPU_COUNT(&set);
    return n < 1 ? 1 : n > PAR_MAX ? PAR_MAX : (unsigned)n;
}

typedef struct {
    void (*fn)(void *ud, unsigned k, unsigned n);
    void *ud;
    unsigned k, n;
} par_part;

static void *part_run(void *arg)
{
    par_part *p = arg;
    p->fn(p->ud, p->k, p->n);
    return NULL;
}

/* pthread_create with every signal blocked in the new thread (it
 * inherits the mask); 1 when it started. */
static int start_blocked(pthread_t *t, void *(*fn)(void *), void *ud)
{
    sigset_t all, old;
    sigfillset(&all);
    pthread_sigmask(SIG_BLOCK, &all, &old);
    int started = pthread_create(t, NULL, fn, ud) == 0;
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    return started;
}

void par_start(par_task *t, void *(*fn)(void *ud), void *ud)
{
    t->started = start_blocked(&t->thread, fn, ud);
    if (!t->started) fn(ud);
}

void par_join(par_task *t)
{
    if (t->started) pthread_join(t->thread, NULL);
    t->started = 0;
}

void par_run(unsigned n, void (*fn)(void *ud, unsigned k, unsigned n), void *ud)
{
    n = n < 1 ? 1 : n > PAR_MAX ? PAR_MAX : n;
    par_part part[PAR_MAX];
    pthread_t thread[PAR_MAX];
    int started[PAR_MAX] = {0};
    for (unsigned k = 0; k < n; k++) {
        part[k] = (par_part){fn, ud, k, n};
        if (k) started[k] = start_blocked(&thread[k], part_run, &part[k]);
    }
    fn(ud, 0, n);
    for (unsigned k = 1; k < n; k++) {
        if (started[k]) pthread_join(thread[k], NULL);
        else fn(ud, k, n);
    }
}
