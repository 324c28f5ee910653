/* voxbench — the benchmarks behind `make bench`.
 *
 *   voxbench shapes  [-r RES]           standard shapes: serial and 1-worker times vs targets,
 *                                       the VOD write and the whole job (engine_pipeline_run)
 *   voxbench table1  [-r RES] [-n MAX]  the paper's Table 1 for Scenes 1-3, both schedules
 *   voxbench brute   [-r RES,...]       brute-force corner evaluation vs interval pruning
 *   voxbench vod     [-r RES] [-n MAX]  VOD write throughput, size, dedup, compression, read
 *   voxbench memory  [-r RES]           octree bytes per voxel, peak resident memory
 *   voxbench deflate [-r RES]           zlib, libdeflate and the one-pass encoder on the
 *                                       real bricks: time and size per level
 *
 * Every table is Markdown on stdout and starts with the machine's core count.
 * Each time is the median of REPEATS runs measured in this process. */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <libdeflate.h>
#include <zlib.h>

#include "bench_util.h"
#include "engine.h"
#include "expr.h"
#include "kind_encode.h"
#include "kind_implicit.h"
#include "octree.h"
#include "pipeline.h"
#include "subdiv.h"
#include "vod.h"
#include "voxel.h"

#define REPEATS 3

static void die(const char *what, const char *why)
{
    fprintf(stderr, "voxbench: %s: %s\n", what, why);
    exit(1);
}

/* ---- shapes ---- */

typedef struct {
    const char *name, *file;
    double target; /* seconds for one worker at 512^3, 0 = none */
    double lo, hi;
} shape;

static const shape shapes[] = {
    {"sphere", "examples/sphere.vx", 0.15, -1, 1},
    {"union64", "examples/union64.vx", 0.6, -1, 1},
    {"blend2", "examples/blend2.vx", 0.3, -1, 1},
    {"scene1", "examples/scene1.vx", 0, -1, 1},
    {"scene2", "examples/scene2.vx", 0, -1.05, 1.05},
    {"scene3", "examples/scene3.vx", 0, -1.05, 1.05},
};
#define NSHAPES (sizeof shapes / sizeof shapes[0])

static expr_tape *load_shape(const shape *s)
{
    FILE *f = fopen(s->file, "rb");
    if (!f) die(s->file, strerror(errno));
    static char buf[1 << 16];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = '\0';
    expr_tape *t;
    expr_error err;
    if (expr_compile(buf, n, NULL, &t, &err)) die(s->file, err.msg);
    return t;
}

static grid_spec shape_grid(const shape *s, uint32_t res)
{
    double lo[3] = {s->lo, s->lo, s->lo}, hi[3] = {s->hi, s->hi, s->hi};
    grid_spec g;
    err_info err = {0};
    if (grid_make(lo, hi, res, &g, &err)) die("grid", err.msg);
    return g;
}

static engine *make_engine(int workers)
{
    engine_opts o = {.workers = workers};
    engine *e;
    err_info err = {0};
    if (engine_create(&o, &e, &err)) die("engine", err.msg);
    return e;
}

typedef struct {
    double seconds, master_cpu, worker_cpu;
    uint64_t voxels;
} job_time;

/* Median wall time of REPEATS jobs (CPU figures from the median run). */
static job_time time_engine(engine *e, const expr_tape *t, const grid_spec *g,
                            engine_schedule sched)
{
    job_time runs[REPEATS];
    double secs[REPEATS];
    for (int i = 0; i < REPEATS; i++) {
        engine_job job = {.tape = t, .grid = *g, .schedule = sched};
        engine_result r;
        int rc = engine_voxelize(e, &job, &r);
        if (rc) die("engine_voxelize", strerror(-rc));
        runs[i] = (job_time){r.seconds, r.master_cpu, r.worker_cpu, r.voxels};
        secs[i] = r.seconds;
    }
    double m = median(secs, REPEATS);
    for (int i = 0; i < REPEATS; i++)
        if (runs[i].seconds == m) return runs[i];
    return runs[0];
}

typedef struct {
    void *arena;
    size_t bytes;
    octree t;
} serial_tree;

static void serial_alloc(serial_tree *s, int depth)
{
    uint32_t cells = 1u << 27;
    s->bytes = octree_arena_bytes(cells);
    s->arena = mmap(NULL, s->bytes, PROT_READ | PROT_WRITE,
                    MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (s->arena == MAP_FAILED) die("mmap", strerror(errno));
    octree_init(&s->t, s->arena, cells, depth);
}

static double time_serial(const expr_tape *t, const grid_spec *g, uint64_t *voxels)
{
    double secs[REPEATS];
    for (int i = 0; i < REPEATS; i++) {
        serial_tree s;
        serial_alloc(&s, g->depth);
        double t0 = now();
        if (subdiv_serial(t, g, &s.t)) die("subdiv_serial", "failed");
        secs[i] = now() - t0;
        *voxels = s.t.voxels;
        munmap(s.arena, s.bytes);
    }
    return median(secs, REPEATS);
}

static void header(const char *title, uint32_t res)
{
    printf("\n### %s (%u^3, %ld cores, median of %d runs)\n\n", title, res,
           sysconf(_SC_NPROCESSORS_ONLN), REPEATS);
}

static void header_range(const char *title, uint32_t lo, uint32_t hi)
{
    printf("\n### %s (%u^3 to %u^3, %ld cores, median of %d runs)\n\n", title, lo, hi,
           sysconf(_SC_NPROCESSORS_ONLN), REPEATS);
}

static int null_write(void *ud, const void *buf, size_t n)
{
    (void)buf;
    *(uint64_t *)ud += n;
    return 0;
}

/* The whole job as the daemon and vox run it (engine_pipeline_run: grid,
 * voxelization, VOD written to a sink that counts the bytes); the run of
 * median wall time. */
static engine_pipeline_report time_pipeline(engine *e, const shape *s, const expr_tape *t,
                                     uint32_t res, double *whole)
{
    engine_pipeline_job job = {
        .kind = &engine_kind_implicit,
        .implicit = {.tape = t, .source = "", .source_name = s->file},
        .lo = {s->lo, s->lo, s->lo}, .hi = {s->hi, s->hi, s->hi}, .res = res,
    };
    vod_params_default(&job.vod);
    engine_pipeline_report runs[REPEATS];
    double secs[REPEATS];
    for (int i = 0; i < REPEATS; i++) {
        uint64_t bytes = 0;
        vod_sink sink = {null_write, &bytes};
        double t0 = now();
        if (engine_pipeline_run(e, &job, &sink, &runs[i])) die("job", runs[i].err.msg);
        secs[i] = now() - t0;
    }
    *whole = median(secs, REPEATS);
    for (int i = 0; i < REPEATS; i++)
        if (secs[i] == *whole) return runs[i];
    return runs[0];
}

static void bench_shapes(uint32_t res)
{
    header("Standard shapes, one worker", res);
    printf("| shape | voxels | serial (s) | 1 worker (s) | target (s) | vs target | VOD write (s) | whole job (s) | VOD bytes |\n");
    printf("|---|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    engine *e = make_engine(1);
    for (size_t i = 0; i < NSHAPES; i++) {
        const shape *s = &shapes[i];
        expr_tape *t = load_shape(s);
        grid_spec g = shape_grid(s, res);
        uint64_t vox;
        double ser = time_serial(t, &g, &vox);
        job_time w = time_engine(e, t, &g, ENGINE_SCHED_SUBTREE);
        double whole;
        engine_pipeline_report r = time_pipeline(e, s, t, res, &whole);
        char tgt[32] = "-", ratio[32] = "-";
        if (s->target > 0 && res == 512) {
            snprintf(tgt, sizeof tgt, "%.2f", s->target);
            snprintf(ratio, sizeof ratio, "%.2fx", w.seconds / s->target);
        }
        printf("| %s | %llu | %.3f | %.3f | %s | %s | %.3f | %.3f | %llu |\n", s->name,
               (unsigned long long)w.voxels, ser, w.seconds, tgt, ratio, r.t_write, whole,
               (unsigned long long)r.st.file_bytes);
        if (vox != w.voxels) printf("\n**serial and engine disagree: %llu vs %llu voxels**\n",
                                    (unsigned long long)vox, (unsigned long long)w.voxels);
        expr_tape_free(t);
    }
    engine_destroy(e);
}

/* ---- Table 1 ---- */

static void table1_row(int n, job_time r[3][2], double t1[3][2], int sched)
{
    printf("| %d |", n);
    for (int s = 0; s < 3; s++) {
        double y = t1[s][sched] / (n * r[s][sched].seconds);
        if (n == 1) printf(" %.3f s | - |", r[s][sched].seconds);
        else printf(" %.3f s | %.0f%% |", r[s][sched].seconds, 100 * y);
    }
    printf("\n");
}

static void bench_table1(uint32_t res, int max_workers)
{
    const char *names[2] = {"subtree (default)", "paper"};
    expr_tape *tapes[3];
    grid_spec grids[3];
    for (int s = 0; s < 3; s++) {
        tapes[s] = load_shape(&shapes[3 + s]);
        grids[s] = shape_grid(&shapes[3 + s], res);
    }
    job_time (*all)[3][2] = calloc((size_t)max_workers + 1, sizeof *all);
    for (int n = 1; n <= max_workers; n++) {
        engine *e = make_engine(n);
        for (int s = 0; s < 3; s++)
            for (int k = 0; k < 2; k++)
                all[n][s][k] = time_engine(e, tapes[s], &grids[s], (engine_schedule)k);
        engine_destroy(e);
    }
    double t1[3][2];
    for (int s = 0; s < 3; s++)
        for (int k = 0; k < 2; k++) t1[s][k] = all[1][s][k].seconds;
    for (int k = 0; k < 2; k++) {
        header(k == 0 ? "Table 1, subtree schedule (default)" : "Table 1, paper schedule", res);
        printf("| workers | Scene 1 time | yield | Scene 2 time | yield | Scene 3 time | yield |\n");
        printf("|---:|---:|---:|---:|---:|---:|---:|\n");
        for (int n = 1; n <= max_workers; n++) table1_row(n, all[n], t1, k);
    }
    header("Table 1, voxels, rate and master CPU", res);
    printf("| schedule | workers | scene | voxels | Mvoxels/s | master CPU / workers' CPU |\n");
    printf("|---|---:|---|---:|---:|---:|\n");
    for (int k = 0; k < 2; k++)
        for (int n = 1; n <= max_workers; n++)
            for (int s = 0; s < 3; s++) {
                job_time *j = &all[n][s][k];
                printf("| %s | %d | %s | %llu | %.2f | %.1f%% |\n", names[k], n,
                       shapes[3 + s].name, (unsigned long long)j->voxels,
                       j->voxels / j->seconds / 1e6,
                       j->worker_cpu > 0 ? 100 * j->master_cpu / j->worker_cpu : 0.0);
            }
    free(all);
    for (int s = 0; s < 3; s++) expr_tape_free(tapes[s]);
}

/* ---- brute force ---- */

/* F at every voxel corner, (res+1)^3 point evaluations, on slices z in
 * [0, nz) of the corner lattice; returns seconds and the sign changes seen. */
static double brute_slices(const expr_tape *t, const grid_spec *g, uint32_t nz)
{
    expr_vm *vm;
    if (expr_vm_new(t, 1, &vm)) die("vm", "no memory");
    double t0 = now(), sink = 0;
    for (uint32_t k = 0; k < nz; k++) {
        double z = g->lo[2] + k * g->vs;
        for (uint32_t j = 0; j <= g->res[1]; j++) {
            double y = g->lo[1] + j * g->vs;
            for (uint32_t i = 0; i <= g->res[0]; i++)
                sink += expr_vm_point(vm, 0, g->lo[0] + i * g->vs, y, z) > 0;
        }
    }
    double s = now() - t0;
    expr_vm_free(vm);
    if (sink < 0) printf("impossible\n");
    return s;
}

static void bench_brute(const uint32_t *res, int nres)
{
    header_range("Brute force (F at every voxel corner) vs interval subdivision, serial",
                 res[0], res[nres - 1]);
    printf("| shape | res | corners | brute force (s) | how | subdivision (s) | speed-up |\n");
    printf("|---|---:|---:|---:|---|---:|---:|\n");
    const int which[] = {0, 3};
    for (int w = 0; w < 2; w++) {
        const shape *s = &shapes[which[w]];
        expr_tape *t = load_shape(s);
        for (int r = 0; r < nres; r++) {
            grid_spec g = shape_grid(s, res[r]);
            uint32_t nz = g.res[2] + 1, measured = nz;
            /* Big grids: time a spread of slices and scale by the count. */
            if ((uint64_t)nz * nz * nz > 200000000ull) measured = 32;
            double b = brute_slices(t, &g, measured) * nz / measured;
            uint64_t vox;
            double sub = time_serial(t, &g, &vox);
            char how[64];
            if (measured == nz) snprintf(how, sizeof how, "measured");
            else snprintf(how, sizeof how, "%u of %u slices, scaled", measured, nz);
            printf("| %s | %u | %llu | %.2f | %s | %.3f | %.0fx |\n", s->name, res[r],
                   (unsigned long long)nz * nz * nz, b, how, sub, b / sub);
        }
        expr_tape_free(t);
    }
}

/* ---- VOD ---- */

static int count_voxel(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    (void)x, (void)y, (void)z, (void)v;
    ++*(uint64_t *)ud;
    return 0;
}

static double time_vod_read(const char *path, uint64_t *voxels)
{
    double t0 = now();
    vod_file *f;
    err_info err;
    if (vod_open(path, &f, &err)) die(path, err.msg);
    *voxels = 0;
    vod_foreach(f, 0, count_voxel, voxels);
    vod_close(f);
    return now() - t0;
}

/* The same volume as a flat RAW file (4 bytes a voxel): write, then time a
 * read that touches every voxel. */
static double time_raw_read(const octree *t, uint32_t n, const char *path, uint64_t *bytes)
{
    size_t total = (size_t)n * n * n * 4;
    uint32_t *vol = calloc((size_t)n * n * n, 4);
    if (!vol) die("raw", "no memory");
    octree_iter it;
    octree_iter_init(&it, t);
    uint32_t x, y, z, v;
    while (octree_iter_next(&it, &x, &y, &z, &v))
        if (x < n && y < n && z < n) vol[((size_t)z * n + y) * n + x] = v;
    int fd = open(path, O_CREAT | O_TRUNC | O_WRONLY, 0600);
    if (fd < 0 || write(fd, vol, total) != (ssize_t)total) die(path, "cannot write");
    close(fd);
    memset(vol, 0, total);
    double t0 = now();
    fd = open(path, O_RDONLY);
    size_t got = 0;
    while (got < total) {
        ssize_t r = read(fd, (char *)vol + got, total - got);
        if (r <= 0) die(path, "cannot read");
        got += (size_t)r;
    }
    close(fd);
    uint64_t nz = 0;
    for (size_t i = 0; i < (size_t)n * n * n; i++) nz += vol[i] != 0;
    double s = now() - t0;
    free(vol);
    unlink(path);
    *bytes = total;
    return s + (nz == 0 ? 0 : 0);
}

static void bench_vod(uint32_t res, int max_workers)
{
    header("VOD files (zlib level 6, SFHS, 16^3 bricks, channel 3)", res);
    printf("| shape | workers | write (s) | raw MB/s | file bytes | unique bricks | dedup | compression | read+validate (s) | RAW bytes | RAW read (s) |\n");
    printf("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    const int which[] = {0, 1, 3, 5}; /* union64: 64 equal spheres, duplicate bricks */
    for (int w = 0; w < 4; w++) {
        const shape *s = &shapes[which[w]];
        expr_tape *t = load_shape(s);
        grid_spec g = shape_grid(s, res);
        for (int n = 1; n <= max_workers; n = n == 1 ? max_workers : n + 1) {
            engine *e = make_engine(n);
            time_engine(e, t, &g, ENGINE_SCHED_SUBTREE);
            vod_params p;
            vod_params_default(&p);
            for (int a = 0; a < 3; a++) p.volume[a] = g.res[a], p.voxel_scale[a] = (float)g.vs;
            char path[] = "/tmp/voxbench-XXXXXX";
            int fd = mkstemp(path);
            vod_sink sink = {vod_fd_write, (void *)(intptr_t)fd};
            vod_stats st;
            engine_error err;
            double t0 = now();
            if (engine_write_vod(e, &p, &sink, &st, &err)) die("write", err.msg);
            double wt = now() - t0;
            close(fd);
            uint64_t vox, raw_bytes;
            double rt = time_vod_read(path, &vox);
            double raw = time_raw_read(engine_octree(e), g.res[0], path, &raw_bytes);
            printf("| %s | %d | %.3f | %.0f | %llu | %llu | %.2fx | %.1fx | %.3f | %llu | %.3f |\n",
                   s->name, n, wt, st.raw_bytes / wt / 1e6, (unsigned long long)st.file_bytes,
                   (unsigned long long)st.bricks, (double)st.nonempty_nodes / (double)st.bricks,
                   (double)st.brick_raw_bytes / (double)st.brick_data_bytes, rt,
                   (unsigned long long)raw_bytes, raw);
            unlink(path);
            engine_destroy(e);
            if (max_workers == 1) break;
        }
        expr_tape_free(t);
    }
}

/* ---- memory ---- */

/* One shape, serial, in this (forked) process: its row of the table. */
static void memory_row(const shape *s, uint32_t res)
{
    expr_tape *t = load_shape(s);
    grid_spec g = shape_grid(s, res);
    serial_tree st;
    serial_alloc(&st, g.depth);
    if (subdiv_serial(t, &g, &st.t)) die("subdiv_serial", "failed");
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    printf("| %s | %llu | %u | %.2f | %.1f |\n", s->name, (unsigned long long)st.t.voxels,
           st.t.used, (double)octree_arena_bytes(st.t.used) / (double)st.t.voxels,
           ru.ru_maxrss / 1024.0);
    munmap(st.arena, st.bytes);
    expr_tape_free(t);
}

/* Each shape in a process of its own, so that each peak is its own job's. */
static void bench_memory(uint32_t res)
{
    printf("\n### Memory (%u^3, %ld cores, one run each)\n\n", res, sysconf(_SC_NPROCESSORS_ONLN));
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    double base = ru.ru_maxrss / 1024.0;
    printf("| shape | voxels | octree cells | octree bytes/voxel | peak RSS (MiB) |\n");
    printf("|---|---:|---:|---:|---:|\n");
    for (size_t i = 0; i < NSHAPES; i++) {
        fflush(stdout);
        pid_t pid = fork();
        if (pid < 0) die("fork", strerror(errno));
        if (pid == 0) {
            memory_row(&shapes[i], res);
            fflush(stdout);
            _exit(0);
        }
        int st;
        if (waitpid(pid, &st, 0) < 0 || !WIFEXITED(st) || WEXITSTATUS(st))
            die("memory", "a measuring process failed");
    }
    printf("\n(peak RSS of a process that ran only that job with the serial engine, "
           "%.1f MiB of it the program before the job)\n", base);
}

/* ---- deflate: the brick compressors on the real bricks ---- */

/* The distinct raw bricks of one file (what the writer compresses: a
 * duplicate is found by its hash before compression), end to end. */
typedef struct {
    uint8_t *raw;
    size_t n, brick_bytes;
    uint32_t brick, voxel_bits;
} brick_set;

/* Index of a brick equal to scratch among the kept ones, or -1;
 * slots: open addressing on the hash, each the brick's index + 1. */
static long find_brick(const brick_set *b, const uint32_t *slot, size_t cap,
                       uint32_t h, const uint8_t *scratch, size_t *at)
{
    size_t j = h & (cap - 1);
    for (; slot[j]; j = (j + 1) & (cap - 1))
        if (!memcmp(b->raw + (slot[j] - 1) * b->brick_bytes, scratch, b->brick_bytes))
            return (long)slot[j] - 1;
    *at = j;
    return -1;
}

static void collect_bricks(const shape *s, uint32_t res, brick_set *b)
{
    expr_tape *t = load_shape(s);
    grid_spec g = shape_grid(s, res);
    serial_tree st;
    serial_alloc(&st, g.depth);
    if (subdiv_serial(t, &g, &st.t)) die("subdiv_serial", "failed");
    vod_params p;
    vod_params_default(&p);
    for (int a = 0; a < 3; a++) p.volume[a] = g.res[a];
    vod_layout L;
    err_info err = {0};
    if (vod_layout_make(&p, g.depth, &L, &err)) die("layout", err.msg);
    st.t.agg = malloc((size_t)st.t.used * sizeof *st.t.agg);
    vod_source src = vod_octree_source(&st.t);
    if (!st.t.agg || vod_prepare(&src, &L, p.channel, &err)) die("prepare", err.msg);
    size_t n = vod_collect(&src, &L, NULL, 0), cap = 16;
    while (cap < 2 * n) cap *= 2;
    vod_node *nodes = malloc((n + 1) * sizeof *nodes);
    uint32_t *slot = calloc(cap, sizeof *slot);
    uint8_t *scratch = malloc(L.raw_bytes);
    b->brick_bytes = L.raw_bytes;
    b->brick = L.brick;
    b->voxel_bits = L.voxel_bits;
    b->raw = malloc((n + 1) * L.raw_bytes);
    b->n = 0;
    if (!nodes || !slot || !scratch || !b->raw) die("deflate", "no memory");
    vod_collect(&src, &L, nodes, n);
    for (size_t i = 0; i < n; i++) {
        memset(scratch, 0, L.raw_bytes);
        if (nodes[i].uniform) die("deflate", "an octree gave a uniform node");
        if (src.ops->fill(&src, &L, &nodes[i], scratch)) die("fill", "failed");
        size_t at;
        uint32_t h = vod_hash_sfhs(scratch, L.raw_bytes);
        if (find_brick(b, slot, cap, h, scratch, &at) >= 0) continue;
        memcpy(b->raw + b->n * L.raw_bytes, scratch, L.raw_bytes);
        slot[at] = (uint32_t)++b->n;
    }
    free(nodes);
    free(slot);
    free(scratch);
    free(st.t.agg);
    munmap(st.arena, st.bytes);
    expr_tape_free(t);
}

/* One pass over the bricks, a zlib stream each, as the writer makes them
 * (one stream reset between bricks, the smallest window holding a brick);
 * returns the bytes. */
static uint64_t zlib_pass(const brick_set *b, int level, uint8_t *out, size_t cap)
{
    int wbits = 9;
    while (wbits < 15 && ((size_t)1 << wbits) < b->brick_bytes) wbits++;
    z_stream z;
    memset(&z, 0, sizeof z);
    if (deflateInit2(&z, level, Z_DEFLATED, wbits, 8, Z_DEFAULT_STRATEGY) != Z_OK)
        die("zlib", "deflateInit2");
    uint64_t total = 0;
    for (size_t i = 0; i < b->n; i++) {
        deflateReset(&z);
        z.next_in = b->raw + i * b->brick_bytes;
        z.avail_in = (uInt)b->brick_bytes;
        z.next_out = out;
        z.avail_out = (uInt)cap;
        if (deflate(&z, Z_FINISH) != Z_STREAM_END) die("zlib", "deflate");
        total += z.total_out;
    }
    deflateEnd(&z);
    return total;
}

/* A file's distinct bricks, every level: the bricks of a mesh or CSG job,
 * say.  The reader gives a brick that nodes share the same pointer. */
typedef struct {
    const uint8_t **p;
    size_t n, cap;
} brick_ptrs;

static int add_file_brick(void *ud, const uint32_t at[3], const uint8_t *raw)
{
    (void)at;
    brick_ptrs *f = ud;
    if (f->n == f->cap) {
        f->cap = f->cap ? 2 * f->cap : 1024;
        if (!(f->p = realloc(f->p, f->cap * sizeof *f->p))) die("deflate", "no memory");
    }
    f->p[f->n++] = raw;
    return 0;
}

static int cmp_ptr(const void *a, const void *b)
{
    uintptr_t x = (uintptr_t) * (const uint8_t *const *)a;
    uintptr_t y = (uintptr_t) * (const uint8_t *const *)b;
    return (x > y) - (x < y);
}

static void file_bricks_read(const char *path, brick_set *b)
{
    vod_file *vf;
    err_info err;
    if (vod_open(path, &vf, &err)) die(path, err.msg);
    const vod_info *in = vod_get_info(vf);
    *b = (brick_set){.brick = in->brick, .voxel_bits = in->voxel_bits,
                     .brick_bytes = (size_t)in->brick * in->brick * in->brick *
                                    in->voxel_bits / 8};
    brick_ptrs f = {0};
    for (uint32_t l = 0; l < in->height; l++) vod_foreach_brick(vf, (int)l, add_file_brick, &f);
    qsort(f.p, f.n, sizeof *f.p, cmp_ptr);
    if (!(b->raw = malloc(f.n * b->brick_bytes + 1))) die("deflate", "no memory");
    for (size_t i = 0; i < f.n; i++)
        if (i == 0 || f.p[i] != f.p[i - 1])
            memcpy(b->raw + b->n++ * b->brick_bytes, f.p[i], b->brick_bytes);
    free(f.p);
    vod_close(vf);
}

static uint64_t sparse_pass(const brick_set *b, uint8_t *out, size_t cap)
{
    vod_sparse *z;
    if (vod_sparse_new(b->brick, b->voxel_bits, &z)) die("sparse", "no encoder");
    uint64_t total = 0;
    for (size_t i = 0; i < b->n; i++) {
        size_t k = vod_sparse_compress(z, b->raw + i * b->brick_bytes, b->brick_bytes,
                                       out, cap);
        if (!k) die("sparse", "output too small");
        total += k;
    }
    vod_sparse_free(z);
    return total;
}

static uint64_t libdeflate_pass(const brick_set *b, int level, uint8_t *out, size_t cap)
{
    struct libdeflate_compressor *c = libdeflate_alloc_compressor(level);
    if (!c) die("libdeflate", "no compressor");
    uint64_t total = 0;
    for (size_t i = 0; i < b->n; i++) {
        size_t k = libdeflate_zlib_compress(c, b->raw + i * b->brick_bytes,
                                            b->brick_bytes, out, cap);
        if (!k) die("libdeflate", "output too small");
        total += k;
    }
    libdeflate_free_compressor(c);
    return total;
}

/* Median time of REPEATS passes. */
static double time_pass(const brick_set *b, int lib, int level, uint64_t *bytes)
{
    size_t cap = 2 * b->brick_bytes + 1024;
    uint8_t *out = malloc(cap);
    if (!out) die("deflate", "no memory");
    double secs[REPEATS];
    for (int i = 0; i < REPEATS; i++) {
        double t0 = now();
        *bytes = lib == 2 ? sparse_pass(b, out, cap)
                 : lib   ? libdeflate_pass(b, level, out, cap)
                         : zlib_pass(b, level, out, cap);
        secs[i] = now() - t0;
    }
    free(out);
    return median(secs, REPEATS);
}

/* The table's rows for one set of bricks. */
static void deflate_rows(const char *name, const brick_set *b)
{
    static const struct { int lib, level; } runs[] = {
        {0, 1}, {0, 6}, {0, 9}, {1, 1}, {1, 6}, {1, 9}, {1, 12}, {2, 0}};
    double mb = (double)(b->n * b->brick_bytes) / 1e6;
    uint64_t ref = 0;
    for (size_t r = 0; r < sizeof runs / sizeof runs[0]; r++) {
        uint64_t bytes;
        double t = time_pass(b, runs[r].lib, runs[r].level, &bytes);
        if (!runs[r].lib && runs[r].level == 6) ref = bytes;
        char vs[32] = "-";
        if (ref) snprintf(vs, sizeof vs, "%+.1f%%", 100.0 * ((double)bytes / (double)ref - 1));
        char level[16];
        if (runs[r].lib == 2) snprintf(level, sizeof level, "1-%d", VOD_SPARSE_LEVEL);
        else snprintf(level, sizeof level, "%d", runs[r].level);
        printf("| %s | %u^3 x %u bit | %zu | %.1f | %s | %s | %.4f | %.0f | %.2f | %llu | %s |\n",
               name, b->brick, b->voxel_bits, b->n, mb,
               runs[r].lib == 2 ? "voxd one-pass" : runs[r].lib ? "libdeflate" : "zlib",
               level, t, mb / t, t / (double)b->n * 1e6, (unsigned long long)bytes, vs);
    }
}

/* The distinct bricks of the sphere, union64 and Scene 1 (channel 3) at
 * res, or, when files are named, those of each file. */
static void bench_deflate(uint32_t res, char **files, int nfiles)
{
    header("Brick compression: zlib, libdeflate and the writer's one-pass encoder "
           "(the distinct bricks of each file, one core)", res);
    printf("| bricks of | brick | bricks | raw MB | encoder | level | time (s) | raw MB/s | us a brick | bytes | vs zlib 6 |\n");
    printf("|---|---|---:|---:|---|---:|---:|---:|---:|---:|---:|\n");
    const int which[] = {0, 1, 3}; /* sphere, union64, scene1 */
    for (int w = 0; w < 3 && !nfiles; w++) {
        brick_set b;
        collect_bricks(&shapes[which[w]], res, &b);
        deflate_rows(shapes[which[w]].name, &b);
        free(b.raw);
    }
    for (int i = 0; i < nfiles; i++) {
        brick_set b;
        file_bricks_read(files[i], &b);
        const char *base = strrchr(files[i], '/');
        deflate_rows(base ? base + 1 : files[i], &b);
        free(b.raw);
    }
}

static int parse_res_list(const char *s, uint32_t *out, int cap)
{
    int n = 0;
    while (*s && n < cap) {
        char *end;
        unsigned long v = strtoul(s, &end, 10);
        if (end == s || v < 1 || v > 4096) return -1;
        out[n++] = (uint32_t)v;
        s = *end == ',' ? end + 1 : end;
    }
    return n;
}

int main(int argc, char **argv)
{
    if (argc < 2) {
        fprintf(stderr, "usage: voxbench shapes|table1|brute|vod|memory|deflate [-r RES[,RES..]] [-n MAXWORKERS] [FILE.vod...]\n"
                        "  (files: deflate only, their bricks instead of the shapes')\n");
        return 2;
    }
    uint32_t res[8] = {512};
    int nres = 1;
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    int maxw = cores > 0 ? (int)cores : 1;
    char *files[16];
    int nfiles = 0;
    for (int i = 2; i < argc; i++) {
        if (argv[i][0] != '-') {
            if (nfiles == 16) die(argv[i], "at most 16 files");
            files[nfiles++] = argv[i];
            continue;
        }
        if (i + 1 == argc) die(argv[i], "wants a value");
        if (!strcmp(argv[i], "-r") && (nres = parse_res_list(argv[i + 1], res, 8)) < 1)
            die("-r", "want RES[,RES...] in 1..4096");
        if (!strcmp(argv[i], "-n")) maxw = atoi(argv[i + 1]);
        i++;
    }
    if (nfiles && strcmp(argv[1], "deflate")) die(files[0], "files are for deflate only");
    if (maxw < 1 || maxw > ENGINE_MAX_WORKERS) die("-n", "out of range");
    const char *cmd = argv[1];
    if (!strcmp(cmd, "shapes")) bench_shapes(res[0]);
    else if (!strcmp(cmd, "table1")) bench_table1(res[0], maxw);
    else if (!strcmp(cmd, "brute")) bench_brute(res, nres);
    else if (!strcmp(cmd, "vod")) bench_vod(res[0], maxw);
    else if (!strcmp(cmd, "memory")) bench_memory(res[0]);
    else if (!strcmp(cmd, "deflate")) bench_deflate(res[0], files, nfiles);
    else die(cmd, "unknown benchmark");
    return 0;
}
