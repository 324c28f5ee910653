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

void par_run(unsigned n, void (*fn)(void *ud, unsigned k, unsigned n), void *ud)
{
    n = n < 1 ? 1 : n > PAR_MAX ? PAR_MAX : n;
    par_part part[PAR_MAX];
    pthread_t thread[PAR_MAX];
    int started[PAR_MAX] = {0};
    sigset_t all, old;
    sigfillset(&all);
    /* the new threads inherit the mask: signals stay the caller's */
    pthread_sigmask(SIG_BLOCK, &all, &old);
    for (unsigned k = 0; k < n; k++) {
        part[k] = (par_part){fn, ud, k, n};
        if (k) started[k] = pthread_create(&thread[k], NULL, part_run, &part[k]) == 0;
    }
    pthread_sigmask(SIG_SETMASK, &old, NULL);
    fn(ud, 0, n);
    for (unsigned k = 1; k < n; k++) {
        if (started[k]) pthread_join(thread[k], NULL);
        else fn(ud, k, n);
    }
}
