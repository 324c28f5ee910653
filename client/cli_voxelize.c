/* vox voxelize: an implicit surface or a triangle mesh to a VOD file, on the
 * voxd daemon when one answers, else with the embedded engine. */
#include <errno.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "afterexit.h"
#include "cli.h"
#include "engine.h"
#include "mesh.h"
#include "outfile.h"
#include "par.h"
#include "pipeline.h"
#include "progress.h"
#include "source.h"
#include "syncbehind.h"
#include "thread_name.h"
#include "vod.h"
#include "voxel.h"

typedef cli_job_opts voxelize_opts;

/* The options both commands take, in both usages. */

/* The file is made by outfile (unnamed until complete, then linked into
 * place), so a failed or interrupted job never leaves a partial file. */

/* The sink's writes, stopped by an interrupt: the VOD writer fails with
 * -ECANCELED and the file is dropped. */
static int write_or_stop(void *ud, const void *p, size_t n)
{
    if (cli_interrupted()) return -ECANCELED;
    return outfile_write(ud, p, n);
}

static void on_progress(void *ud, const engine_progress *p)
{
    progress_update((progress *)ud, p->fraction, p->level, p->voxels);
}

static void print_summary(const voxelize_opts *o, const engine_pipeline_report *r)
{
    const grid_spec *g = &r->grid;
    printf("%s: %llu voxels on a %ux%ux%u grid in %.3f s (%.2f Mvoxels/s), "
           "VOD written in %.3f s\n",
           o->out, (unsigned long long)r->voxels, g->res[0], g->res[1], g->res[2],
           r->t_voxelize, r->t_voxelize > 0 ? r->voxels / r->t_voxelize / 1e6 : 0.0,
           r->t_write);
    printf("  %llu bytes, %llu brick%s (%llu non-empty node%s), CRC %08x\n",
           (unsigned long long)r->st.file_bytes, (unsigned long long)r->st.bricks,
           cli_plural(r->st.bricks), (unsigned long long)r->st.nonempty_nodes,
           cli_plural(r->st.nonempty_nodes), r->st.crc32);
    if (o->workers > 0)
        printf("  CPU: master %.3f s, workers %.3f s\n", r->master_cpu, r->worker_cpu);
    const vod_times *t = &r->st.t;
    printf("  VOD stages: fill %.3f s, hash %.3f s, compress %.3f s, assemble %.3f s, "
           "write %.3f s (%s)\n", t->fill, t->hash, t->compress, t->assemble, t->write,
           o->workers > 0 ? "seconds in each, summed over the processes" : "seconds in each");
}

/* The job on the embedded engine (or the serial algorithm, -w 0): e, when
 * the caller started it, else one started here. */
static int run_job(const voxelize_opts *o, const engine_pipeline_job *job, outfile *f,
                   engine_pipeline_report *r, engine *e)
{
    int rc = o->workers && !e ? cli_start_engine(o->workers, o->cpus, o->shm_mib, &e) : 0;
    if (rc) return rc;
    if (e) engine_lazy_release(e); /* nothing to give back before we exit */
    vod_sink sink = {write_or_stop, f};
    rc = engine_pipeline_run(e, job, &sink, r);
    /* its end is not waited for, the file is; its mapping goes with our
     * memory, after the exit (afterexit_leave in voxelize) */
    engine_leave(e);
    if (rc == 0 || cli_interrupted()) return rc;
    if (r->stage == ENGINE_PIPELINE_WRITE)
        cli_error("cannot write %s: %s", o->out, r->err.msg);
    else
        cli_error("voxelization failed: %s", r->err.msg);
    return rc;
}

/* e: the engine the caller started (NULL: started here); it is the job's
 * from here on, whatever happens. */
static int voxelize(voxelize_opts *o, engine_pipeline_job *job, engine *e)
{
    job->lo[0] = o->lo[0], job->lo[1] = o->lo[1], job->lo[2] = o->lo[2];
    job->hi[0] = o->hi[0], job->hi[1] = o->hi[1], job->hi[2] = o->hi[2];
    job->res = o->res;
    job->schedule = o->schedule;
    job->vod = o->vod;
    grid_spec g;
    err_info err = {0};
    if (job->kind == &engine_kind_implicit &&
        grid_make(o->lo, o->hi, o->res, &g, &err)) {
        cli_error("%s", err.msg);
        engine_abandon(e);
        return CLI_EXIT_USAGE;
    }
    cli_catch_interrupts();
    job->cancel = &cli_interrupt;
    outfile f;
    int rc = outfile_open(&f, o->out);
    if (rc) {
        cli_error("cannot create %s: %s", o->out, strerror(-rc));
        engine_abandon(e);
        return CLI_EXIT_FAILED;
    }
    progress pr;
    progress_init(&pr, o->progress);
    job->progress = on_progress;
    job->ud = &pr;
    engine_pipeline_report r;
    syncbehind sync;
    syncbehind_start(&sync, f.fd); /* flushed as written, not all at the commit */
    rc = run_job(o, job, &f, &r, e);
    syncbehind_stop(&sync);
    progress_done(&pr);
    if (rc || cli_interrupted()) {
        outfile_abort(&f);
        if (cli_interrupted()) cli_end_interrupted(o->out);
        return CLI_EXIT_FAILED;
    }
    thread_name("commit");
    int old = afterexit_hold(o->out); /* freed after our exit, not in the rename */
    if ((rc = outfile_commit(&f, o->out))) {
        cli_error("cannot write %s: %s", o->out, strerror(-rc));
        afterexit_leave(old);
        return CLI_EXIT_FAILED;
    }
    if (r.voxels == 0) cli_warn("%s has no voxel: nothing of the job meets its box (see --domain)", o->out);
    if (!o->quiet) {
        print_summary(o, &r);
        char kind[512];
        engine_pipeline_describe(job, &r, kind, sizeof kind);
        fputs(kind, stdout);
    }
    afterexit_leave(old); /* the process exits next */
    return CLI_EXIT_OK;
}

static int voxelize_expr(voxelize_opts *o, const source *src, const expr_tape *tape)
{
    engine_pipeline_job job = {
        .kind = &engine_kind_implicit,
        .implicit = {.tape = tape, .source = src->text, .source_len = src->len,
                     .source_name = src->path},
        .band = o->mesh_opts.band,
    };
    return voxelize(o, &job, NULL);
}

/* The mesh loaded on a thread of its own while the caller's starts the
 * engine (the segment mapped, the workers forked): neither waits for the
 * other, and the load's errors are told as before. */
typedef struct {
    const voxelize_opts *o;
    mesh m;
    int rc;
} mesh_loading;

static void *load_run(void *ud)
{
    mesh_loading *l = ud;
    thread_name("load");
    l->rc = cli_mesh_load(l->o->mesh, MESH_FORMAT_AUTO, l->o->weld, &l->m, NULL);
    return NULL;
}

/* A mesh job on the embedded engine: loaded and checked here (its errors
 * with the file's line or byte).  (The daemon gets the file as it is and
 * parses it itself.) */
static int voxelize_mesh(voxelize_opts *o)
{
    mesh_loading l = {.o = o};
    par_task loading;
    engine *e = NULL;
    int rc = cli_start_engine_beside(&loading, load_run, &l, o->workers, o->cpus, o->shm_mib, &e);
    par_join(&loading);
    if (l.rc || rc) { /* the load's error first, as when it ran alone */
        engine_abandon(e);
        if (!l.rc) mesh_free(&l.m);
        return l.rc ? l.rc : CLI_EXIT_FAILED;
    }
    mesh m = l.m;
    struct stat sb;
    engine_pipeline_job job = {
        .kind = &engine_kind_mesh,
        .mesh = {.mesh = &m, .opts = o->mesh_opts, .pad = o->pad,
                 .fit = !o->has_domain, .source_name = o->mesh,
                 .source_bytes = stat(o->mesh, &sb) == 0 ? (uint64_t)sb.st_size : 0},
    };
    rc = voxelize(o, &job, e);
    mesh_free(&m);
    return rc;
}

/* The daemon, when one answers (or must): an exit code, or -1 to run the
 * job here.  src: the expression, NULL for a mesh job. */
static int try_daemon(const voxelize_opts *o, const source *src, const char *sock)
{
    vox_client *c;
    vox_error err;
    /* A daemon that answers at all answers a hello at once. */
    int rc = cli_connect(sock, o->mode == CLI_MODE_DAEMON ? 30000 : 5000, &c, &err);
    if (rc) {
        if (o->mode == CLI_MODE_DAEMON) return cli_no_daemon(sock, rc, &err);
        if (rc != -ENOENT && rc != -ECONNREFUSED && !o->quiet)
            cli_error("%s; using the embedded engine", err.message);
        return -1;
    }
    int refused = 0;
    rc = cli_daemon_job(c, o, src, o->mode == CLI_MODE_AUTO, &refused);
    vox_close(c);
    if (o->mode == CLI_MODE_AUTO &&
        (refused == VOX_EBUSY || refused == VOX_ESHUTTING_DOWN)) {
        if (!o->quiet)
            cli_error("voxd on %s is %s; using the embedded engine", sock,
                      refused == VOX_EBUSY ? "busy" : "shutting down");
        return -1;
    }
    return rc;
}

/* The embedded engine's limit (the daemon has its own, max_res). */
static int bad_res(const voxelize_opts *o)
{
    cli_error("bad --res '%s': want a whole number from 1 to %u", o->res_arg, GRID_MAX_RES);
    return CLI_EXIT_USAGE;
}

int cli_voxelize(int argc, char **argv, const char *sock)
{
    voxelize_opts o;
    cli_job_defaults(&o);
    int rc = cli_job_parse(CLI_CMD_VOXELIZE, argc, argv, &o);
    if (rc) return rc;
    if (o.mode == CLI_MODE_AUTO && o.engine_opts) o.mode = CLI_MODE_EMBEDDED;
    if (o.mesh) {
        rc = o.mode != CLI_MODE_EMBEDDED ? try_daemon(&o, NULL, sock) : -1;
        if (rc >= 0) return rc;
        return o.res > GRID_MAX_RES ? bad_res(&o) : voxelize_mesh(&o);
    }
    source src;
    expr_tape *tape;
    if ((rc = cli_job_source(&o, &src, &tape))) return rc;
    rc = o.mode != CLI_MODE_EMBEDDED ? try_daemon(&o, &src, sock) : -1;
    if (rc < 0) rc = o.res > GRID_MAX_RES ? bad_res(&o) : voxelize_expr(&o, &src, tape);
    expr_tape_free(tape);
    source_free(&src);
    return rc;
}
