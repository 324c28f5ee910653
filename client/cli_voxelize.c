/* vox voxelize: an implicit surface to a VOD file, on the voxd daemon when one
 * answers, else with the embedded engine. */
#include <errno.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>

#include "cli.h"
#include "engine.h"
#include "job_meta.h"
#include "outfile.h"
#include "progress.h"
#include "source.h"
#include "subdiv.h"
#include "vod.h"
#include "voxel.h"

typedef cli_job_opts voxelize_opts;

/* The options both commands take, in both usages. */

static double now_seconds(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* The file is written under a temporary name beside OUT and renamed into
 * place only when complete, so a failed job never leaves a partial file. */
typedef struct {
    char tmp[4096];
    int fd;
} out_file;

static int out_open(out_file *f, const char *path)
{
    f->fd = outfile_create(path, f->tmp, sizeof f->tmp);
    return f->fd < 0 ? f->fd : 0;
}

static int out_commit(out_file *f, const char *path, int ok)
{
    int rc = 0;
    if (ok && fsync(f->fd) != 0) rc = -errno;
    if (close(f->fd) != 0 && rc == 0) rc = -errno;
    if (ok && rc == 0 && rename(f->tmp, path) != 0) rc = -errno;
    if (!ok || rc) unlink(f->tmp);
    return rc;
}

static void set_vod_geometry(vod_params *v, const grid_spec *g)
{
    for (int a = 0; a < 3; a++) {
        v->volume[a] = g->res[a];
        v->voxel_scale[a] = (float)g->vs;
        v->origin[a] = (float)g->lo[a];
    }
}

typedef struct {
    octree tree;
    void *arena;
    size_t arena_bytes;
} serial_tree;

/* The serial algorithm's octree lives in a sparse private mapping that is
 * touched only as cells are handed out. */
static int serial_voxelize(const expr_tape *tape, const grid_spec *g,
                           serial_tree *s)
{
    uint32_t cells = 1u << 27; /* 4 GiB of address space, not of memory */
    s->arena_bytes = octree_arena_bytes(cells);
    s->arena = mmap(NULL, s->arena_bytes, PROT_READ | PROT_WRITE,
                    MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (s->arena == MAP_FAILED) return -errno;
    octree_init(&s->tree, s->arena, cells, g->depth);
    return subdiv_serial(tape, g, &s->tree);
}

static void on_progress(void *ud, const engine_progress *p)
{
    progress_update((progress *)ud, p->fraction, p->level, p->voxels);
}

typedef struct {
    uint64_t voxels;
    double t_voxelize, t_write, master_cpu, worker_cpu;
    vod_stats st;
} run_result;

static int run_engine(const voxelize_opts *o, const expr_tape *tape,
                      const grid_spec *g, vod_params *vp, out_file *f,
                      progress *pr, run_result *res)
{
    int cpus[ENGINE_MAX_WORKERS], ncpus = 0;
    if (o->cpus && (ncpus = cli_parse_cpus(o->cpus, cpus, ENGINE_MAX_WORKERS)) <= 0) {
        cli_error("bad --cpus '%s': want a list like 0,1 or 0-3", o->cpus);
        return -EINVAL;
    }
    engine_opts eo = {.workers = (int)o->workers, .cpus = ncpus ? cpus : NULL,
                      .ncpus = ncpus, .shm_bytes = (size_t)o->shm_mib << 20};
    char err[256] = "";
    engine *e;
    int rc = engine_create(&eo, &e, err, sizeof err);
    if (rc) {
        cli_error("cannot start the engine: %s", err[0] ? err : strerror(-rc));
        return rc;
    }
    engine_job job = {.tape = tape, .grid = *g, .schedule = o->schedule,
                      .progress = on_progress, .ud = pr};
    engine_result er;
    rc = engine_voxelize(e, &job, &er);
    progress_done(pr);
    if (rc) {
        cli_error("voxelization failed: %s", strerror(-rc));
    } else {
        res->voxels = er.voxels;
        res->t_voxelize = er.seconds;
        res->master_cpu = er.master_cpu;
        res->worker_cpu = er.worker_cpu;
        double t0 = now_seconds();
        vod_sink sink = {vod_fd_write, (void *)(intptr_t)f->fd};
        rc = engine_write_vod(e, vp, &sink, &res->st, err, sizeof err);
        res->t_write = now_seconds() - t0;
        if (rc) cli_error("cannot write %s: %s", o->out, err[0] ? err : strerror(-rc));
    }
    engine_destroy(e);
    return rc;
}

static int run_serial(const voxelize_opts *o, const expr_tape *tape,
                      const grid_spec *g, vod_params *vp, out_file *f,
                      run_result *res)
{
    serial_tree s;
    double t0 = now_seconds();
    int rc = serial_voxelize(tape, g, &s);
    res->t_voxelize = now_seconds() - t0;
    if (rc == -ENOMEM) cli_error("the octree outgrew its 4 GiB arena");
    else if (rc) cli_error("voxelization failed: %s", strerror(-rc));
    if (rc == 0) {
        res->voxels = s.tree.voxels;
        char err[256] = "";
        vod_sink sink = {vod_fd_write, (void *)(intptr_t)f->fd};
        t0 = now_seconds();
        rc = vod_write_octree(&s.tree, vp, &sink, &res->st, err, sizeof err);
        res->t_write = now_seconds() - t0;
        if (rc) cli_error("cannot write %s: %s", o->out, err[0] ? err : strerror(-rc));
    }
    if (s.arena != MAP_FAILED) munmap(s.arena, s.arena_bytes);
    return rc;
}

static void print_summary(const voxelize_opts *o, const grid_spec *g,
                          const run_result *r)
{
    printf("%s: %llu voxels on a %ux%ux%u grid in %.3f s (%.2f Mvoxels/s), "
           "VOD written in %.3f s\n",
           o->out, (unsigned long long)r->voxels, g->res[0], g->res[1], g->res[2],
           r->t_voxelize, r->t_voxelize > 0 ? r->voxels / r->t_voxelize / 1e6 : 0.0,
           r->t_write);
    printf("  %llu bytes, %llu bricks (%llu non-empty nodes), CRC %08x\n",
           (unsigned long long)r->st.file_bytes, (unsigned long long)r->st.bricks,
           (unsigned long long)r->st.nonempty_nodes, r->st.crc32);
    if (o->workers > 0)
        printf("  CPU: master %.3f s, workers %.3f s\n", r->master_cpu, r->worker_cpu);
}

static int voxelize(voxelize_opts *o, const source *src, const expr_tape *tape)
{
    grid_spec g;
    char err[256];
    if (grid_make(o->lo, o->hi, o->res, &g, err, sizeof err)) {
        cli_error("%s", err);
        return 2;
    }
    char meta[JOB_META_MAX];
    job_meta m = {
        .source = src->text, .source_len = src->len, .source_name = src->path,
        .res = o->res, .grid = {g.res[0], g.res[1], g.res[2]},
        .lo = {o->lo[0], o->lo[1], o->lo[2]}, .hi = {o->hi[0], o->hi[1], o->hi[2]},
    };
    job_meta_format(meta, sizeof meta, &m);
    o->vod.metadata = meta;
    set_vod_geometry(&o->vod, &g);
    out_file f;
    int rc = out_open(&f, o->out);
    if (rc) {
        cli_error("cannot create %s: %s", o->out, strerror(-rc));
        return 1;
    }
    progress pr;
    progress_init(&pr, o->progress);
    run_result res = {0};
    rc = o->workers ? run_engine(o, tape, &g, &o->vod, &f, &pr, &res)
                    : run_serial(o, tape, &g, &o->vod, &f, &res);
    int rc2 = out_commit(&f, o->out, rc == 0);
    if (rc == 0 && rc2) cli_error("cannot write %s: %s", o->out, strerror(-rc2));
    if (rc || rc2) return 1;
    if (!o->quiet) print_summary(o, &g, &res);
    return 0;
}

/* The daemon, when one answers (or must): an exit code, or -1 to run the
 * job here. */
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

int cli_voxelize(int argc, char **argv, const char *sock)
{
    voxelize_opts o;
    cli_job_defaults(&o);
    int rc = cli_job_parse(CLI_CMD_VOXELIZE, argc, argv, &o);
    if (rc) return rc;
    if (o.mode == CLI_MODE_AUTO && o.engine_opts) o.mode = CLI_MODE_EMBEDDED;
    source src;
    expr_tape *tape;
    if ((rc = cli_job_source(&o, &src, &tape))) return rc;
    rc = -1;
    if (o.mode != CLI_MODE_EMBEDDED) rc = try_daemon(&o, &src, sock);
    if (rc < 0) {
        if (o.res > GRID_MAX_RES) {
            cli_error("bad --res '%s': want a whole number from 1 to %u", o.res_arg,
                      GRID_MAX_RES);
            rc = CLI_EXIT_USAGE;
        } else {
            rc = voxelize(&o, &src, tape);
        }
    }
    expr_tape_free(tape);
    source_free(&src);
    return rc;
}
