/* bench_engine — the engine's timings: serial vs 1..N workers, both
 * schedules, master CPU vs workers' CPU.
 *
 *   bench_engine [-r res] [-w max_workers] [-n repeats] [-s split] [expr]
 *
 * Prints one line per configuration: best wall time of n runs (the
 * subdivision with normals and the octree), voxels, octants tested, master
 * and worker CPU seconds of that run. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#include "engine.h"
#include "expr.h"
#include "octree.h"
#include "subdiv.h"

static double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static void die(const char *what, const char *why)
{
    fprintf(stderr, "bench_engine: %s: %s\n", what, why);
    exit(1);
}

static double serial(const expr_tape *t, const subdiv_grid *g, int n,
                     uint64_t *voxels)
{
    uint32_t cap = 1u << 26;
    size_t bytes = octree_arena_bytes(cap);
    octree_cell *arena = mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                              MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (arena == MAP_FAILED) die("mmap", strerror(errno));
    double best = 1e30;
    for (int i = 0; i < n; i++) {
        octree tr;
        octree_init(&tr, arena, cap, g->depth);
        double t0 = now();
        if (subdiv_serial(t, g, &tr)) die("subdiv_serial", "failed");
        double dt = now() - t0;
        if (dt < best) best = dt;
        *voxels = tr.voxels;
    }
    munmap(arena, bytes);
    return best;
}

static void engine_runs(const expr_tape *t, const subdiv_grid *g, int workers,
                        engine_schedule s, int split, int n)
{
    engine_opts o = {.workers = workers};
    engine *e;
    char err[256];
    if (engine_create(&o, &e, err, sizeof err)) die("engine_create", err);
    engine_result best = {.seconds = 1e30};
    for (int i = 0; i < n; i++) {
        engine_job job = {.tape = t, .grid = *g, .schedule = s, .split_level = split};
        engine_result r;
        if (engine_voxelize(e, &job, &r)) die("engine_voxelize", r.error);
        if (r.seconds < best.seconds) best = r;
    }
    printf("%-8s %2d workers  %8.4f s  %9llu voxels  %10llu tested  master %.4f s  "
           "workers %.4f s  (master/workers %.1f%%)\n",
           s == ENGINE_SCHED_PAPER ? "paper" : "subtree", workers, best.seconds,
           (unsigned long long)best.voxels, (unsigned long long)best.octants,
           best.master_cpu, best.worker_cpu,
           100.0 * best.master_cpu / (best.worker_cpu > 0 ? best.worker_cpu : 1));
    engine_destroy(e);
}

int main(int argc, char **argv)
{
    uint32_t res = 512;
    int maxw = 2, n = 5, split = 0, opt, paper = 1;
    while ((opt = getopt(argc, argv, "r:w:n:s:P")) != -1) {
        switch (opt) {
        case 'r': res = (uint32_t)atoi(optarg); break;
        case 'w': maxw = atoi(optarg); break;
        case 'n': n = atoi(optarg); break;
        case 's': split = atoi(optarg); break;
        case 'P': paper = 0; break;
        default: die("usage", "[-r res] [-w workers] [-n repeats] [-s split] [-P] [expr]");
        }
    }
    const char *src = optind < argc ? argv[optind] : "sqrt(x^2+y^2+z^2)-0.8";
    expr_tape *t;
    expr_error ee;
    if (expr_compile(src, strlen(src), NULL, &t, &ee)) die("expr", ee.msg);
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    subdiv_grid g;
    char err[256];
    if (subdiv_grid_make(lo, hi, res, &g, err, sizeof err)) die("grid", err);
    uint64_t voxels = 0;
    double ts = serial(t, &g, n, &voxels);
    printf("%s at %u^3\nserial              %8.4f s  %9llu voxels\n", src, res, ts,
           (unsigned long long)voxels);
    for (int w = 1; w <= maxw; w++)
        engine_runs(t, &g, w, ENGINE_SCHED_SUBTREE, split, n);
    for (int w = 1; paper && w <= maxw; w++)
        engine_runs(t, &g, w, ENGINE_SCHED_PAPER, 0, n > 2 ? 2 : n);
    expr_tape_free(t);
    return 0;
}
