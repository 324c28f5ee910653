/* par — one function run on several threads at once, the caller's among
 * them: for work that is one process's own (the master binning a mesh's
 * triangles while its workers wait), split by the callee into n parts;
 * and one function run beside the caller's thread until it joins it. */
#ifndef VOXD_PAR_H
#define VOXD_PAR_H

#include <pthread.h>

#define PAR_MAX 64 /* threads at most */

/* The CPUs this process may run on (its affinity mask), 1 to PAR_MAX. */
unsigned par_cpus(void);

/* fn(ud, k, n) for k = 0 .. n-1 (n clamped to 1 .. PAR_MAX), each on a
 * thread of its own (k = 0 on the caller's), every signal blocked in the
 * new ones; returns when all are done.  A part whose thread cannot be
 * made runs on the caller's after its own, so every part always runs. */
void par_run(unsigned n, void (*fn)(void *ud, unsigned k, unsigned n), void *ud);

/* fn(ud) on a thread of its own, every signal blocked there (they stay
 * the caller's, whose waits they are meant to interrupt), from
 * par_start until par_join; when no thread can be made, par_start runs
 * it at once on the caller's. */
typedef struct {
    pthread_t thread;
    int started;
} par_task;
void par_start(par_task *t, void *(*fn)(void *ud), void *ud);
void par_join(par_task *t);

#endif
