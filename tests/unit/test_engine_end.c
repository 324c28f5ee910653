/* The end of a job that nobody should wait for: a lazy engine gives its
 * pages back at engine_tidy or at the next job's start, never before its
 * caller has answered, with the same bytes; engine_abandon leaves no
 * segment name behind, its workers let go of stdio at once, keep the
 * segment until the master is gone and then go, reaped by a subreaper. */
#include <criterion/criterion.h>
#include <dirent.h>
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "engine.h"
#include "expr.h"
#include "kind_encode.h"
#include "kind_implicit.h"
#include "shm.h"
#include "vod.h"

#define SPHERES                                                               \
    "min(sqrt((x-0.3)^2+y^2+z^2)-0.35, sqrt((x+0.3)^2+y^2+z^2)-0.3,"          \
    " sqrt(x^2+(y-0.4)^2+z^2)-0.25, sqrt(x^2+(y+0.45)^2+(z-0.1)^2)-0.3,"       \
    " sqrt((x-0.5)^2+(y-0.5)^2+(z-0.5)^2)-0.2, sqrt(x^2+y^2+(z+0.6)^2)-0.3)"

static expr_tape *compile(const char *src)
{
    expr_tape *t = NULL;
    expr_error ee;
    cr_assert_eq(expr_compile(src, strlen(src), NULL, &t, &ee), 0, "%s", ee.msg);
    return t;
}

static grid_spec grid(uint32_t res)
{
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    grid_spec g;
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, res, &g, &err), 0, "%s", err.msg);
    return g;
}

static engine *named_engine(const char *name, int workers)
{
    engine_opts o = {.workers = workers, .shm_name = name, .keep_bytes = 4096};
    engine *e;
    err_info err = {0};
    cr_assert_eq(engine_create(&o, &e, &err), 0, "%s", err.msg);
    return e;
}

static long long shm_blocks(const char *path)
{
    struct stat st;
    cr_assert_eq(stat(path, &st), 0);
    return (long long)st.st_blocks;
}

/* The job voxelized and written as VOD into *out. */
static void job(engine *e, const expr_tape *tape, const grid_spec *g, vod_membuf *out)
{
    engine_job j = {.tape = tape, .grid = *g};
    engine_result r;
    cr_assert_eq(engine_voxelize(e, &j, &r), 0, "%s", r.err.msg);
    vod_params p;
    vod_params_default(&p);
    for (int a = 0; a < 3; a++) {
        p.volume[a] = g->res[a];
        p.voxel_scale[a] = (float)g->vs;
        p.origin[a] = (float)g->lo[a];
    }
    p.metadata = "generator=test_engine_end\n";
    *out = (vod_membuf){0};
    vod_sink s = {vod_mem_write, out};
    vod_stats st;
    engine_error ee;
    cr_assert_eq(engine_write_vod(e, &p, &s, &st, &ee), 0, "%s", ee.msg);
}

static void same(const vod_membuf *a, const vod_membuf *b, const char *what)
{
    cr_assert_eq(a->n, b->n, "%s: sizes %zu vs %zu", what, a->n, b->n);
    cr_assert_eq(memcmp(a->p, b->p, a->n), 0, "%s: the bytes differ", what);
}

/* A lazy engine keeps the job's pages past its end and engine_release
 * (the caller answers first); the next job's start gives them back before
 * it writes anything, so back-to-back jobs give an eager engine's bytes;
 * engine_tidy gives everything back but the fixed part. */
Test(engine_end, lazy_release_waits_for_tidy_and_changes_no_byte, .timeout = 120)
{
    char lazy_name[64], eager_name[64], path[80];
    snprintf(lazy_name, sizeof lazy_name, "/voxd-lazy.%d.", (int)getpid());
    snprintf(eager_name, sizeof eager_name, "/voxd-eager.%d.", (int)getpid());
    snprintf(path, sizeof path, "/dev/shm%s", lazy_name);
    expr_tape *tape = compile(SPHERES);
    grid_spec g = grid(192);
    engine *eager = named_engine(eager_name, 2), *lazy = named_engine(lazy_name, 2);
    engine_lazy_release(lazy);
    vod_membuf ref, a, b;
    job(eager, tape, &g, &ref);
    job(lazy, tape, &g, &a);
    engine_release(lazy);
    long long fixed = (long long)((shm_min_bytes(2) - SHM_MIN_DATA + 4096 + 4095) / 512);
    long long kept = shm_blocks(path);
    cr_assert_gt(kept, 4 * fixed, "the pages went back before engine_tidy: %lld blocks",
                 kept);
    job(lazy, tape, &g, &b); /* starts on the last job's pages: given back first */
    same(&ref, &a, "lazy, first job");
    same(&ref, &b, "lazy, after a deferred release");
    engine_release(lazy);
    engine_tidy(lazy);
    cr_assert_leq(shm_blocks(path), fixed, "%lld blocks after engine_tidy", shm_blocks(path));
    engine_tidy(lazy); /* nothing due: nothing happens */
    cr_assert_null(engine_octree(lazy));
    engine_destroy(lazy);
    engine_destroy(eager);
    free(ref.p);
    free(a.p);
    free(b.p);
    expr_tape_free(tape);
}

/* How many of fds 0-2 process pid holds (-1: it is gone). */
static int stdio_held(pid_t pid)
{
    int n = 0;
    for (int fd = 0; fd < 3; fd++) {
        char p[64];
        snprintf(p, sizeof p, "/proc/%d/fd/%d", (int)pid, fd);
        n += access(p, F_OK) == 0;
    }
    char d[64];
    snprintf(d, sizeof d, "/proc/%d/fd", (int)pid);
    DIR *dir = opendir(d);
    if (!dir) return -1;
    closedir(dir);
    return n;
}

/* Reaped within 30 s (the subreaper's child once its master is gone). */
static int reaped(pid_t pid)
{
    for (int k = 0; k < 3000; k++) {
        pid_t r = waitpid(pid, NULL, WNOHANG);
        if (r == pid) return 1;
        usleep(10000);
    }
    return 0;
}

/* The master's process: a job, the engine abandoned, its workers' pids to
 * fd w, then it waits for a byte on fd go and exits. */
static _Noreturn void abandoning_master(const char *name, int w, int go)
{
    engine *e = named_engine(name, 2);
    expr_tape *tape = compile(SPHERES);
    grid_spec g = grid(96);
    vod_membuf out;
    job(e, tape, &g, &out);
    pid_t pids[2] = {engine_worker_pid(e, 0), engine_worker_pid(e, 1)};
    engine_abandon(e);
    if (write(w, pids, sizeof pids) != (ssize_t)sizeof pids) _exit(2);
    char c;
    if (read(go, &c, 1) != 1) _exit(3);
    _exit(0);
}

Test(engine_end, abandon_leaves_nothing_and_is_waited_for_by_nobody, .timeout = 120)
{
    cr_assert_eq(prctl(PR_SET_CHILD_SUBREAPER, 1), 0);
    char name[64], path[80];
    snprintf(name, sizeof name, "/voxd-abandon.%d.", (int)getpid());
    snprintf(path, sizeof path, "/dev/shm%s", name);
    int pw[2], pg[2];
    cr_assert_eq(pipe(pw), 0);
    cr_assert_eq(pipe(pg), 0);
    pid_t master = fork();
    cr_assert_geq(master, 0);
    if (master == 0) abandoning_master(name, pw[1], pg[0]);
    pid_t pids[2];
    cr_assert_eq(read(pw[0], pids, sizeof pids), (ssize_t)sizeof pids);
    cr_assert_neq(access(path, F_OK), 0, "the segment's name outlives engine_abandon");
    for (int i = 0; i < 2; i++) {
        int held = stdio_held(pids[i]);
        for (int k = 0; k < 3000 && held > 0; k++) {
            usleep(10000);
            held = stdio_held(pids[i]);
        }
        cr_assert_eq(held, 0, "worker %d: %d of stdin, stdout, stderr held (-1: gone)",
                     (int)pids[i], held);
    }
    cr_assert_eq(write(pg[1], "x", 1), 1);
    int st;
    cr_assert_eq(waitpid(master, &st, 0), master);
    cr_assert(WIFEXITED(st) && WEXITSTATUS(st) == 0, "the master's status %d", st);
    for (int i = 0; i < 2; i++)
        cr_assert(reaped(pids[i]), "worker %d outlived its master", (int)pids[i]);
    close(pw[0]), close(pw[1]), close(pg[0]), close(pg[1]);
}
