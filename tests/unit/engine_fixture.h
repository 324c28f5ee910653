/* engine_fixture — what the engine suites (test_engine*.c) share: shapes
 * compiled, grids, the serial algorithm's tree and the comparison with it,
 * making and running an engine, progress watches, waiting for a process's death
 * and reading its CPU. */
#ifndef VOXD_TEST_ENGINE_FIXTURE_H
#define VOXD_TEST_ENGINE_FIXTURE_H

#include <criterion/criterion.h>
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <sched.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "engine.h"
#include "expr.h"
#include "kind_implicit.h"
#include "kinds.h"
#include "octree.h"
#include "shm.h"
#include "subdiv.h"
#include "vod.h"
#include "voxel.h"
/* ---- the queue and the sleeping protocol, between two threads ---- */

#include <pthread.h>

#define SPHERE "sqrt(x^2 + y^2 + z^2) - 0.8"

#define SPHERES                                                               \
    "min(sqrt((x-0.3)^2+y^2+z^2)-0.35, sqrt((x+0.3)^2+y^2+z^2)-0.3,"          \
    " sqrt(x^2+(y-0.4)^2+z^2)-0.25, sqrt(x^2+(y+0.45)^2+(z-0.1)^2)-0.3,"       \
    " sqrt((x-0.5)^2+(y-0.5)^2+(z-0.5)^2)-0.2, sqrt(x^2+y^2+(z+0.6)^2)-0.3)"

static inline expr_tape *compile(const char *src)
{
    expr_tape *t = NULL;
    expr_error ee;
    cr_assert_eq(expr_compile(src, strlen(src), NULL, &t, &ee), 0, "%s", ee.msg);
    return t;
}

static inline grid_spec grid(uint32_t res)
{
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    grid_spec g;
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, res, &g, &err), 0, "%s", err.msg);
    return g;
}

typedef struct {
    octree t;
    octree_cell *arena;
    uint64_t tested;
} ref_tree;

static inline int ref_store(void *ud, const grid_voxel *v)
{
    return octree_store(ud, v->x, v->y, v->z, v->value);
}

/* The serial reference, through subdiv_serial, and its test count through
 * the same kernel (which must give the same voxels). */
static inline void reference(const expr_tape *tape, const grid_spec *g, ref_tree *r)
{
    uint32_t cap = 1u << 20;
    r->arena = malloc(octree_arena_bytes(cap));
    cr_assert(r->arena);
    octree_init(&r->t, r->arena, cap, g->depth);
    cr_assert_eq(subdiv_serial(tape, g, &r->t), 0);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(tape, g->depth, &vm), 0);
    subdiv_kernel k;
    subdiv_kernel_init(&k, vm, g);
    octree t2;
    octree_cell *a2 = malloc(octree_arena_bytes(cap));
    octree_init(&t2, a2, cap, g->depth);
    subdiv_sink s = {.voxel = ref_store, .ud = &t2};
    cr_assert_eq(subdiv_subtree(&k, grid_root(g), &s), 0);
    cr_assert_eq(t2.voxels, r->t.voxels);
    r->tested = k.tested;
    expr_vm_free(vm);
    free(a2);
}

static inline void assert_same(const octree *a, const octree *b, const char *what)
{
    octree_iter ia, ib;
    octree_iter_init(&ia, a);
    octree_iter_init(&ib, b);
    uint32_t x, y, z, v, x2, y2, z2, v2;
    uint64_t n = 0;
    for (;;) {
        bool ma = octree_iter_next(&ia, &x, &y, &z, &v);
        bool mb = octree_iter_next(&ib, &x2, &y2, &z2, &v2);
        cr_assert_eq(ma, mb, "%s: voxel counts differ after %llu", what,
                     (unsigned long long)n);
        if (!ma) break;
        cr_assert(x == x2 && y == y2 && z == z2 && v == v2,
                  "%s: voxel %llu: (%u %u %u %08x) vs (%u %u %u %08x)", what,
                  (unsigned long long)n, x, y, z, v, x2, y2, z2, v2);
        n++;
    }
    cr_assert(n > 0 && n == a->voxels && n == b->voxels, "%s", what);
}

static inline engine *make_engine(int workers, size_t shm_bytes)
{
    engine_opts o = {.workers = workers, .shm_bytes = shm_bytes};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    return e;
}

static inline void run(engine *e, const expr_tape *tape, const grid_spec *g,
                       engine_schedule s, int split, engine_result *r)
{
    engine_job job = {.tape = tape, .grid = *g, .schedule = s, .split_level = split};
    int rc = engine_voxelize(e, &job, r);
    cr_assert_eq(rc, 0, "engine_voxelize: %d %s", rc, r->err.msg);
}

/* ---- progress and cancel ---- */

typedef struct {
    int calls;
    double last_fraction;
    int last_level;
    uint64_t last_voxels;
    int monotonic;
    atomic_int *cancel;
    engine *kill_in;      /* kill worker 0 of this engine at the first call */
    int killed;
} watch;

static inline void on_progress(void *ud, const engine_progress *p)
{
    watch *w = ud;
    if (p->fraction < w->last_fraction || p->fraction > 1.0) w->monotonic = 0;
    w->calls++;
    w->last_fraction = p->fraction;
    w->last_level = p->level;
    w->last_voxels = p->voxels;
    if (w->cancel) atomic_store(w->cancel, 1);
    if (w->kill_in && !w->killed) {
        cr_assert_eq(kill(engine_worker_pid(w->kill_in, 0), SIGKILL), 0);
        w->killed = 1;
    }
}

/* ---- worker deaths ---- */

/* Waits (60 s at most, for a loaded machine) until a killed child is dead:
 * a zombie, not yet reaped, so that the engine finds it dead. */
static inline int is_dead(pid_t pid) /* a zombie, or gone */
{
    char path[64], buf[256];
    snprintf(path, sizeof path, "/proc/%d/stat", (int)pid);
    FILE *f = fopen(path, "r");
    if (!f) return 1;
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = 0;
    const char *rp = strrchr(buf, ')');
    return rp && rp[1] == ' ' && rp[2] == 'Z';
}

static inline void wait_dead(pid_t pid)
{
    for (int k = 0; k < 6000; k++) {
        if (is_dead(pid)) return;
        usleep(10000);
    }
    cr_assert_fail("worker %d still alive 60 s after SIGKILL", (int)pid);
}

static inline int pinned_cpu(pid_t pid)
{
    cpu_set_t set;
    cr_assert_eq(sched_getaffinity(pid, sizeof set, &set), 0);
    cr_assert_eq(CPU_COUNT(&set), 1, "worker %d not pinned", (int)pid);
    for (int c = 0; c < CPU_SETSIZE; c++)
        if (CPU_ISSET(c, &set)) return c;
    return -1;
}

#endif
