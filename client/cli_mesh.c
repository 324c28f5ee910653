/* vox mesh: a VOD file's surface as triangles (marching cubes, iso.h), one
 * mip level or adaptive levels round a point, run by the engine's workers
 * (or in this process with -w 0), written as PLY, OBJ or STL. */
#include <errno.h>
#include <pthread.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "afterexit.h"
#include "cli.h"
#include "clock.h"
#include "iso.h"
#include "kind_iso.h"
#include "outfile.h"
#include "par.h"
#include "syncbehind.h"
#include "thread_name.h"
#include "vod.h"

typedef struct {
    const char *in, *out, *cpus;
    iso_format fmt;
    uint32_t iso, level, workers, shm_mib;
    double center[3], radii[ISO_MAX_RADII];
    uint32_t nradii;
    int has_center, quiet;
} mesh_opts;

static const char usage_text[] =
    "usage: vox mesh FILE.vod -o OUT [--format ply|ply-ascii|obj|stl] [--level L]\n"
    "                [--iso V] [--lod-center X,Y,Z --lod-radii R0,R1,...] [-w N]\n"
    "  marching cubes over the file's bricks: a closed, oriented triangle mesh\n"
    "  -o OUT           the mesh; its extension (.ply, .obj, .stl) names the format\n"
    "                   unless --format does (ply: binary little-endian)\n"
    "  --level L        polygonize the mip level L bricks (default 0)\n"
    "  --iso V          a voxel is inside when its byte is above V, 0..254 (default\n"
    "                   127): channel 2's density, channel 3's occupancy, channel 1\n"
    "                   as 0/255\n"
    "  --lod-center X,Y,Z  adaptive levels of detail round this point (world units)\n"
    "  --lod-radii R0,R1,...  level i for the bricks a sphere of radius Ri touches,\n"
    "                   level n (the count of radii) beyond them; increasing, at most 8\n"
    "  -w, --workers N  worker processes, 0..256; 0 runs in this process\n"
    "                   (default: cores)\n"
    "  --cpus LIST      CPUs to pin the workers to\n"
    "  --shm-size MIB   the engine's shared memory (default 2048, at most half of\n"
    "                   /dev/shm's free space)\n"
    "  -q, --quiet      no summary\n";

static int parse_list(const char *s, double *v, uint32_t cap, uint32_t *n)
{
    *n = 0;
    while (*s) {
        char *end;
        if (*n == cap) return -1;
        v[(*n)++] = strtod(s, &end);
        if (end == s || (*end && *end != ',')) return -1;
        s = *end ? end + 1 : end;
        if (!*s && *end) return -1; /* a trailing comma */
    }
    return *n ? 0 : -1;
}

static int value_opt(const char *a)
{
    static const char *const v[] = {"-o", "--format", "--level", "--iso", "--lod-center",
                                    "--lod-radii", "-w", "--workers", "--cpus",
                                    "--shm-size"};
    for (size_t i = 0; i < sizeof v / sizeof *v; i++)
        if (!strcmp(a, v[i])) return 1;
    return 0;
}

/* "OPT VALUE: WHY" (WHY: a format of one unsigned number). */
static int bad_value(const char *opt, const char *v, const char *why, unsigned n)
{
    char w[80];
    snprintf(w, sizeof w, why, n);
    return cli_usage_error("mesh", "%s %.40s: %s", opt, v, w);
}

/* One option with its value; 0 or CLI_EXIT_USAGE. */
static int take(mesh_opts *o, const char *a, const char *v)
{
    uint32_t n;
    if (!strcmp(a, "-o")) o->out = v;
    else if (!strcmp(a, "--format")) {
        if (!(o->fmt = iso_format_of_name(v)))
            return bad_value(a, v, "not ply, ply-ascii, obj or stl", 0);
    } else if (!strcmp(a, "--level")) {
        if (cli_parse_uint(v, 0, ISO_MAX_LEVELS - 1, &o->level))
            return bad_value(a, v, "not a level 0..%u", ISO_MAX_LEVELS - 1);
    } else if (!strcmp(a, "--iso")) {
        if (cli_parse_uint(v, 0, 254, &o->iso)) return bad_value(a, v, "not a whole number 0..254", 0);
    } else if (!strcmp(a, "--lod-center")) {
        if (parse_list(v, o->center, 3, &n) || n != 3) return bad_value(a, v, "want X,Y,Z", 0);
        o->has_center = 1;
    } else if (!strcmp(a, "--lod-radii")) {
        if (parse_list(v, o->radii, ISO_MAX_RADII, &o->nradii))
            return bad_value(a, v, "want 1 to %u numbers R0,R1,...", ISO_MAX_RADII);
    } else if (!strcmp(a, "-w") || !strcmp(a, "--workers")) {
        if (cli_parse_uint(v, 0, ENGINE_MAX_WORKERS, &o->workers))
            return bad_value(a, v, "want 0..%u", ENGINE_MAX_WORKERS);
    } else if (!strcmp(a, "--cpus")) o->cpus = v;
    else if (!strcmp(a, "--shm-size")) {
        if (cli_parse_uint(v, 16, 1048576, &o->shm_mib)) return bad_value(a, v, "want 16..1048576 MiB", 0);
    }
    return 0;
}

static int check_opts(mesh_opts *o)
{
    if (!o->in) return cli_usage_error("mesh", "missing the input FILE.vod");
    if (!o->out) return cli_usage_error("mesh", "missing -o OUT (the file to write)");
    if (!o->fmt && !(o->fmt = iso_format_of_path(o->out)))
        return cli_usage_error("mesh", "%.40s: no format from its extension (.ply, .obj, "
                               ".stl); give --format", o->out);
    if (o->has_center != (o->nradii > 0))
        return cli_usage_error("mesh", "--lod-center and --lod-radii go together");
    if (o->nradii && o->level)
        return cli_usage_error("mesh", "--level and adaptive levels (--lod-radii) exclude "
                               "each other");
    return 0;
}

/* 0, CLI_EXIT_USAGE, or -1 for --help (printed). */
static int parse_opts(int argc, char **argv, mesh_opts *o)
{
    static const char *const names[] = {"-o", "--format", "--level", "--iso", "--lod-center",
                                        "--lod-radii", "-w", "--workers", "--cpus",
                                        "--shm-size", "-q", "--quiet", "--help", NULL};
    *o = (mesh_opts){.iso = 127, .workers = cli_cores(),
                     .shm_mib = 0 /* the engine's default */};
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            fputs(usage_text, stdout);
            return -1;
        }
        int takes = value_opt(a), rc;
        if (takes && !v) return cli_usage_error("mesh", "option '%s' needs a value", a);
        if (takes && (rc = take(o, a, v))) return rc;
        if (takes) {
            i++;
            continue;
        }
        if (!strcmp(a, "-q") || !strcmp(a, "--quiet")) o->quiet = 1;
        else if (a[0] == '-') return cli_unknown_option("mesh", a, names);
        else if (o->in) return cli_usage_error("mesh", "one input file only: '%.40s'", a);
        else o->in = a;
    }
    return check_opts(o);
}

static void *heap_alloc(void *ud, size_t bytes)
{
    void **keep = ud;
    return *keep = malloc(bytes);
}

/* The output file, opened before the job: with workers the mesh is
 * written while they weld it (streamed: engine_iso_job.laid_out), each
 * part as soon as it is final, by a thread of its own; else after it. */
typedef struct {
    const mesh_opts *o;
    outfile f;
    char comment[200];
    iso_mesh m;            /* the mesh's layout, as the engine gave it */
    engine_iso_weld weld;  /* its progress */
    pthread_t thread;
    int streaming, rc;     /* the thread runs; its iso_write's result */
    syncbehind sync;       /* the file's flushes while it is written */
} mesh_out;

static int ready_wait(void *ud, int tris, uint64_t hi)
{
    return engine_iso_wait(ud, tris, hi);
}

/* Formatted by as many threads as the job has workers: they wait while
 * the workers weld, and run once the weld's end leaves the CPUs to them. */
static void *write_run(void *ud)
{
    mesh_out *w = ud;
    thread_name("write");
    iso_ready ready = {ready_wait, &w->weld};
    w->rc = iso_write_ready(w->f.fd, &w->m, w->o->fmt, w->comment,
                            w->o->workers ? w->o->workers : 1, &ready);
    return NULL;
}

/* On the engine's thread before the weld: the writer started, every
 * signal blocked in it (they stay this thread's).  Without a thread the
 * mesh is written after the job (the engine's thread must not wait). */
static void laid_out(void *ud, const iso_mesh *m)
{
    mesh_out *w = ud;
    sigset_t all, old;
    w->m = *m;
    sigfillset(&all);
    pthread_sigmask(SIG_SETMASK, &all, &old);
    w->streaming = !pthread_create(&w->thread, NULL, write_run, w);
    pthread_sigmask(SIG_SETMASK, &old, NULL);
}

/* The mesh, by the engine's workers (e: the mesh lives in its shared
 * memory until it is abandoned) or (e NULL: -w 0) in this process; the
 * options are w's. */
static int polygonize(const vod_file *f, const iso_params *p, iso_mesh *m, engine_result *r,
                      engine *e, mesh_out *w)
{
    err_info err = {0};
    int rc;
    memset(r, 0, sizeof *r);
    if (e) {
        engine_lazy_release(e); /* nothing to give back before we exit */
        engine_iso_job job = {.file = f, .p = p, .cancel = &cli_interrupt, .ud = w,
                              .weld = &w->weld, .laid_out = laid_out};
        thread_name("engine");
        rc = engine_iso(e, &job, m, r);
        if (w->streaming) { /* the writer's waits end: all welded, or stop */
            if (rc) atomic_store_explicit(&w->weld.stop, 1, memory_order_relaxed);
            pthread_join(w->thread, NULL);
        }
        if (rc) err = r->err;
    } else {
        double c0 = clock_thread_cpu();
        void *mem = NULL;
        iso_input in;
        double t0 = clock_now();
        rc = iso_input_make(f, p, heap_alloc, &mem, &in);
        double t_in = clock_now() - t0;
        if (rc) err_set(&err, rc, "out of memory for the file's bricks");
        else rc = iso_run_serial(p, &in, m, &err);
        m->t_setup += t_in;
        iso_task *t;
        uint64_t n;
        if (!rc && !iso_tasks(p, &in, &t, &n)) free(t), r->tasks = (uint32_t)n;
        free(mem);
        r->master_cpu = clock_thread_cpu() - c0;
    }
    if (rc && !cli_interrupted())
        cli_error("%s: marching cubes failed: %s", w->o->in,
                  err.msg[0] ? err.msg : strerror(-rc));
    return rc;
}

static int open_out(const mesh_opts *o, mesh_out *w)
{
    *w = (mesh_out){.o = o};
    snprintf(w->comment, sizeof w->comment, "vox mesh, iso %u", o->iso);
    int rc = outfile_open(&w->f, o->out);
    if (rc) cli_error("cannot write %s: %s", o->out, strerror(-rc));
    else syncbehind_start(&w->sync, w->f.fd);
    return rc;
}

/* The mesh written (unless it was streamed) and the file put in place;
 * *old: the file it replaced, held open.  The engine (*e) is abandoned
 * once nothing reads the mesh in its segment: its mapping's page tables
 * are dropped while the commit's fsync waits, not at the exit. */
static int write_mesh(const mesh_opts *o, const iso_mesh *m, mesh_out *w, engine **e,
                      int *old)
{
    /* formatted by as many threads as the job had workers (idle now) */
    int rc = w->streaming ? w->rc : iso_write(w->f.fd, m, o->fmt, w->comment,
                                              o->workers ? o->workers : 1);
    engine_abandon(*e);
    *e = NULL;
    syncbehind_stop(&w->sync); /* the last bytes are the commit's fsync's */
    if (!rc && !cli_interrupted()) {
        thread_name("commit");
        *old = afterexit_hold(o->out); /* freed after our exit, not in the rename */
        rc = outfile_commit(&w->f, o->out);
    } else {
        outfile_abort(&w->f);
        if (cli_interrupted()) cli_end_interrupted(o->out);
    }
    if (rc) cli_error("cannot write %s: %s", o->out, strerror(-rc));
    return rc;
}

/* t: when the file was opened, the job started and ended, the mesh written. */
static void print_summary(const mesh_opts *o, const iso_params *p, const iso_mesh *m,
                          const engine_result *r, const double t[4])
{
    printf("%s: %llu triangles, %llu vertices from %s in %.3f s (%u brick task%s, "
           "%u worker%s), written in %.3f s\n", o->out, (unsigned long long)m->n_triangles,
           (unsigned long long)m->n_vertices, p->nradii ? "adaptive levels" : "one level",
           t[2] - t[1], r->tasks, cli_plural(r->tasks), o->workers,
           cli_plural(o->workers), t[3] - t[2]);
    printf("  file read and checked in %.3f s; bricks and tasks %.3f s, marching cubes "
           "%.3f s, weld %.3f s\n", t[1] - t[0], m->t_setup, m->t_tasks, m->t_weld);
    if (o->workers)
        printf("  CPU: master %.3f s, workers %.3f s\n", r->master_cpu, r->worker_cpu);
}

/* The file's bricks freed beside the mesh's write, not after it. */
static void *close_run(void *ud)
{
    thread_name("close");
    vod_close(ud);
    return NULL;
}

/* The input read and checked on a thread of its own while the caller's
 * starts the engine (the segment mapped, the workers forked: they must be
 * the forks of a thread that lives until the end). */
typedef struct {
    const mesh_opts *o;
    vod_file *f;
    int rc;
    err_info err;
} opening;

static void *open_run(void *ud)
{
    opening *op = ud;
    thread_name("read");
    /* the bricks inflated and hashed by as many threads as the job's
     * workers; those of the levels it polygonizes alone (adaptive: 0 to
     * the count of radii, iso_params_make's lod_top or more) */
    unsigned threads = op->o->workers ? op->o->workers : 1;
    const mesh_opts *o = op->o;
    uint32_t levels = o->nradii ? (2u << o->nradii) - 1 : 1u << o->level;
    op->rc = vod_open_levels(o->in, (int)threads, levels, &op->f, &op->err);
    return NULL;
}

/* The input and (with workers) the engine; an exit code on failure, the
 * input's error told first as when it was opened alone. */
static int open_both(const mesh_opts *o, vod_file **f, engine **e)
{
    opening op = {.o = o};
    par_task t;
    int rc = cli_start_engine_beside(&t, open_run, &op, o->workers, o->cpus, o->shm_mib, e);
    par_join(&t);
    if (op.rc) cli_error("%s: %s", o->in, op.err.msg);
    if (!op.rc && !rc) {
        *f = op.f;
        return 0;
    }
    engine_abandon(*e);
    *e = NULL;
    vod_close(op.f);
    return CLI_EXIT_FAILED;
}

static int run(const mesh_opts *o)
{
    vod_file *f;
    engine *e = NULL;
    double tr = clock_now();
    if (open_both(o, &f, &e)) return CLI_EXIT_FAILED;
    iso_params p;
    iso_request rq = {.iso = o->iso, .level = (int)o->level, .center = o->center,
                      .radii = o->radii, .nradii = o->nradii};
    err_info pe = {0};
    int rc = iso_params_make(f, &rq, &p, &pe);
    if (rc) {
        cli_error("%s: %s", o->in, pe.msg);
        engine_abandon(e);
        vod_close(f);
        return CLI_EXIT_USAGE;
    }
    iso_mesh m = {0};
    engine_result r;
    double t[4] = {tr, clock_now()};
    mesh_out w;
    if (open_out(o, &w)) {
        engine_abandon(e);
        vod_close(f);
        return CLI_EXIT_FAILED;
    }
    cli_catch_interrupts();
    rc = polygonize(f, &p, &m, &r, e, &w);
    t[2] = clock_now();
    par_task end;
    par_start(&end, close_run, f);
    if (rc || cli_interrupted()) {
        syncbehind_stop(&w.sync);
        outfile_abort(&w.f);
    }
    if (cli_interrupted()) {
        par_join(&end);
        cli_end_interrupted(o->out);
    }
    int old = -1;
    if (!rc) rc = write_mesh(o, &m, &w, &e, &old);
    t[3] = clock_now();
    par_join(&end);
    if (!rc && !o->quiet) print_summary(o, &p, &m, &r, t);
    iso_mesh_free(&m);
    /* The mesh was read from the segment until the write's end (where
     * write_mesh abandons the engine, e NULL since); the workers free it
     * after we exit, and nothing of the engine's end is waited for
     * (engine_abandon), nor the replaced file's blocks or our memory's
     * teardown (afterexit_leave, as vox voxelize ends). */
    engine_abandon(e);
    afterexit_leave(old); /* the process exits next */
    return rc ? CLI_EXIT_FAILED : CLI_EXIT_OK;
}

int cli_mesh(int argc, char **argv)
{
    mesh_opts o;
    int rc = parse_opts(argc, argv, &o);
    if (rc) return rc < 0 ? CLI_EXIT_OK : rc;
    return run(&o);
}
