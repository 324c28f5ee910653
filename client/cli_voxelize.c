/* vox voxelize: an implicit surface to a VOD file, on the voxd daemon when one
 * answers, else with the embedded engine; and the job options vox submit
 * shares. */
#include <errno.h>
#include <getopt.h>
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
#define JOB_OPTIONS \
    "  -e, --expr EXPR        the function F(x,y,z); the surface is F = 0\n" \
    "  -f, --file FILE        read F from a file (\"#@ domain ...\" lines give defaults)\n" \
    "  -o, --output OUT       the VOD file to write (written whole, then renamed into place)\n" \
    "  -d, --domain A,B | X0,X1,Y0,Y1,Z0,Z1\n" \
    "                         the box to voxelize (default -1,1)\n"
#define OUTPUT_OPTIONS \
    "      --schedule subtree|paper\n" \
    "                         hand out subtrees (default) or single octants (the paper)\n" \
    "      --channel surface|occupancy\n" \
    "                         32-bit voxels with normals (default) or 1 bit\n" \
    "      --brick N          brick size, a power of two 2..256 (default 16)\n" \
    "      --compress zlib|runl|none   (default zlib)\n" \
    "      --hash sfhs|xx32   brick hash (default sfhs)\n"
#define SHOW_OPTIONS \
    "      --progress         show progress even when stderr is not a terminal\n" \
    "  -q, --quiet            no summary\n"

static const char usage_voxelize[] =
    "usage: vox [--socket PATH] voxelize (--expr EXPR | --file FILE.vx) -o OUT.vod [options]\n"
    JOB_OPTIONS
    "  -r, --res N            voxels along the longest axis, 1..4096 (default 256)\n"
    "  -w, --workers N        worker processes, 0 = serial in-process (default: cores)\n"
    "      --cpus LIST        CPUs to pin workers to, e.g. 0,1 or 0-3 (default: automatic)\n"
    OUTPUT_OPTIONS
    "      --shm-size MIB     shared memory for the engine (default 2048)\n"
    SHOW_OPTIONS
    "      --embedded         run the embedded engine even when voxd answers\n"
    "      --daemon           run the job on voxd; exit 3 when none answers\n"
    "\n"
    "The job runs on the voxd daemon when one answers on the socket (see vox --help),\n"
    "else on the engine embedded in vox; a daemon that is busy or stopping also leaves\n"
    "the job to the embedded engine.\n"
    "-w, --cpus and --shm-size belong to the embedded engine and select it.  The file\n"
    "is the same either way.  Exit status: 0 done, 1 the job failed, 2 bad usage or a\n"
    "bad expression, 3 --daemon and no voxd answering.\n";

static const char usage_submit[] =
    "usage: vox [--socket PATH] submit (--expr EXPR | --file FILE.vx) -o OUT.vod [options]\n"
    JOB_OPTIONS
    "  -r, --res N            voxels along the longest axis, 1..the daemon's max_res\n"
    "                         (default 256)\n"
    OUTPUT_OPTIONS
    SHOW_OPTIONS
    "\n"
    "Runs the job on the voxd daemon at the socket (see vox --help) and writes the\n"
    "result it streams back, checked (length and CRC-32) before it is renamed into\n"
    "place.  On a terminal the job's id is shown; an interrupt (Ctrl-C) cancels the\n"
    "job.  Exit status: 0 done, 1 the job failed or was refused (with the daemon's\n"
    "reason), 2 bad usage or a bad expression, 3 no voxd answering on the socket.\n";

void cli_job_usage(int cmd, FILE *f)
{
    fputs(cmd == CLI_CMD_SUBMIT ? usage_submit : usage_voxelize, f);
}

void cli_job_defaults(cli_job_opts *o)
{
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    memset(o, 0, sizeof *o);
    o->res = 256;
    o->workers = cores > 0 ? (uint32_t)cores : 1;
    o->shm_mib = 2048;
    o->schedule = ENGINE_SCHED_SUBTREE;
    o->mode = CLI_MODE_AUTO;
    vod_params_default(&o->vod);
    o->vod.channel = VOXEL_CH_SURFACE;
    for (int a = 0; a < 3; a++) o->lo[a] = -1, o->hi[a] = 1;
}

static int parse_choice(const char *s, const char *const names[],
                        const uint32_t values[], uint32_t *out)
{
    for (int i = 0; names[i]; i++)
        if (strcmp(s, names[i]) == 0) {
            *out = values[i];
            return 0;
        }
    return -1;
}

static int parse_vod_option(int c, const char *arg, vod_params *v)
{
    static const char *const ch_names[] = {"surface", "occupancy", NULL};
    static const uint32_t ch_values[] = {VOXEL_CH_SURFACE, VOXEL_CH_OCCUPANCY};
    static const char *const comp_names[] = {"zlib", "runl", "none", NULL};
    static const uint32_t comp_values[] = {VOD_COMP_ZLIB, VOD_COMP_RUNL, VOD_COMP_NONE};
    static const char *const hash_names[] = {"sfhs", "xx32", NULL};
    static const uint32_t hash_values[] = {VOD_HASH_SFHS, VOD_HASH_XX32};
    uint32_t u;
    switch (c) {
    case 'C':
        if (parse_choice(arg, ch_names, ch_values, &u)) return -1;
        v->channel = (int)u;
        return 0;
    case 'B':
        if (cli_parse_uint(arg, 2, 256, &u) || (u & (u - 1))) return -1;
        v->brick = u;
        return 0;
    case 'Z': return parse_choice(arg, comp_names, comp_values, &v->comp);
    case 'H': return parse_choice(arg, hash_names, hash_values, &v->hash);
    }
    return -1;
}

int cli_job_parse(int cmd, int argc, char **argv, cli_job_opts *o)
{
    /* The embedded engine's options and the mode switches are voxelize's. */
    static const struct option longs_voxelize[] = {
        {"expr", 1, 0, 'e'}, {"file", 1, 0, 'f'}, {"output", 1, 0, 'o'},
        {"domain", 1, 0, 'd'}, {"res", 1, 0, 'r'}, {"workers", 1, 0, 'w'},
        {"cpus", 1, 0, 'P'}, {"schedule", 1, 0, 'S'}, {"channel", 1, 0, 'C'},
        {"brick", 1, 0, 'B'}, {"compress", 1, 0, 'Z'}, {"hash", 1, 0, 'H'},
        {"shm-size", 1, 0, 'M'}, {"progress", 0, 0, 'p'}, {"quiet", 0, 0, 'q'},
        {"embedded", 0, 0, 'E'}, {"daemon", 0, 0, 'D'},
        {"help", 0, 0, 'h'}, {0, 0, 0, 0}};
    static const struct option longs_submit[] = {
        {"expr", 1, 0, 'e'}, {"file", 1, 0, 'f'}, {"output", 1, 0, 'o'},
        {"domain", 1, 0, 'd'}, {"res", 1, 0, 'r'},
        {"schedule", 1, 0, 'S'}, {"channel", 1, 0, 'C'},
        {"brick", 1, 0, 'B'}, {"compress", 1, 0, 'Z'}, {"hash", 1, 0, 'H'},
        {"progress", 0, 0, 'p'}, {"quiet", 0, 0, 'q'},
        {"help", 0, 0, 'h'}, {0, 0, 0, 0}};
    int submit = cmd == CLI_CMD_SUBMIT;
    const char *name = submit ? "submit" : "voxelize";
    int c;
    optind = 1;
    while ((c = getopt_long(argc, argv, submit ? "e:f:o:d:r:qh" : "e:f:o:d:r:w:qh",
                            submit ? longs_submit : longs_voxelize, NULL)) != -1) {
        switch (c) {
        case 'e': o->expr = optarg; break;
        case 'f': o->file = optarg; break;
        case 'o': o->out = optarg; break;
        case 'd':
            if (cli_parse_domain(optarg, o->lo, o->hi)) {
                cli_error("bad --domain '%s': want A,B or X0,X1,Y0,Y1,Z0,Z1 with each low < high", optarg);
                return CLI_EXIT_USAGE;
            }
            o->has_domain = 1;
            break;
        case 'r':
            /* The embedded engine's limit is checked when it runs: the
             * daemon has its own (max_res). */
            if (cli_parse_uint(optarg, 1, UINT32_MAX, &o->res)) {
                if (submit)
                    cli_error("bad --res '%s': want a whole number from 1 (to the daemon's max_res)", optarg);
                else
                    cli_error("bad --res '%s': want a whole number from 1 to %u", optarg, SUBDIV_MAX_RES);
                return CLI_EXIT_USAGE;
            }
            o->res_arg = optarg;
            break;
        case 'w':
            if (cli_parse_uint(optarg, 0, ENGINE_MAX_WORKERS, &o->workers)) {
                cli_error("bad --workers '%s': want 0..%d", optarg, ENGINE_MAX_WORKERS);
                return CLI_EXIT_USAGE;
            }
            o->engine_opts = 1;
            break;
        case 'P': o->cpus = optarg; o->engine_opts = 1; break;
        case 'S':
            if (strcmp(optarg, "subtree") && strcmp(optarg, "paper")) {
                cli_error("bad --schedule '%s': want subtree or paper", optarg);
                return CLI_EXIT_USAGE;
            }
            o->schedule = optarg[0] == 'p' ? ENGINE_SCHED_PAPER : ENGINE_SCHED_SUBTREE;
            break;
        case 'M':
            if (cli_parse_uint(optarg, 16, 1u << 20, &o->shm_mib)) {
                cli_error("bad --shm-size '%s': want MiB from 16 to 1048576", optarg);
                return CLI_EXIT_USAGE;
            }
            o->engine_opts = 1;
            break;
        case 'p': o->progress = 1; break;
        case 'q': o->quiet = 1; break;
        case 'E': case 'D': {
            cli_mode m = c == 'E' ? CLI_MODE_EMBEDDED : CLI_MODE_DAEMON;
            if (o->mode != CLI_MODE_AUTO && o->mode != m) {
                cli_error("give at most one of --embedded and --daemon");
                return CLI_EXIT_USAGE;
            }
            o->mode = m;
            break;
        }
        case 'h': cli_job_usage(cmd, stdout); exit(0);
        case 'C': case 'B': case 'Z': case 'H':
            if (parse_vod_option(c, optarg, &o->vod)) {
                cli_error("bad value '%s' for --%s (see vox %s --help)", optarg,
                          c == 'C' ? "channel" : c == 'B' ? "brick" : c == 'Z' ? "compress" : "hash",
                          name);
                return CLI_EXIT_USAGE;
            }
            break;
        default: cli_job_usage(cmd, stderr); return CLI_EXIT_USAGE;
        }
    }
    if (optind < argc) {
        cli_error("unexpected argument '%s'", argv[optind]);
        return CLI_EXIT_USAGE;
    }
    if (!o->expr == !o->file) {
        cli_error("give exactly one of --expr and --file");
        return CLI_EXIT_USAGE;
    }
    if (!o->out) {
        cli_error("missing -o OUT.vod");
        return CLI_EXIT_USAGE;
    }
    if (o->mode == CLI_MODE_DAEMON && o->engine_opts) {
        cli_error("-w, --cpus and --shm-size are the embedded engine's: not with --daemon");
        return CLI_EXIT_USAGE;
    }
    return 0;
}

int cli_job_source(cli_job_opts *o, source *src, expr_tape **tape)
{
    if (source_load(src, o->file, o->expr)) return CLI_EXIT_USAGE;
    if (!o->has_domain && src->has_domain)
        memcpy(o->lo, src->lo, sizeof o->lo), memcpy(o->hi, src->hi, sizeof o->hi);
    /* Compiled here also when the daemon runs the job: a bad expression
     * gets the same file:line:col message and caret either way. */
    expr_tape *t;
    if (source_compile(src, NULL, &t)) {
        source_free(src);
        return CLI_EXIT_USAGE;
    }
    if (tape) *tape = t;
    else expr_tape_free(t);
    return 0;
}

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

static void set_vod_geometry(vod_params *v, const subdiv_grid *g)
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
static int serial_voxelize(const expr_tape *tape, const subdiv_grid *g,
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
                      const subdiv_grid *g, vod_params *vp, out_file *f,
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
                      const subdiv_grid *g, vod_params *vp, out_file *f,
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

static void print_summary(const voxelize_opts *o, const subdiv_grid *g,
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
    subdiv_grid g;
    char err[256];
    if (subdiv_grid_make(o->lo, o->hi, o->res, &g, err, sizeof err)) {
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
        if (o.res > SUBDIV_MAX_RES) {
            cli_error("bad --res '%s': want a whole number from 1 to %u", o.res_arg,
                      SUBDIV_MAX_RES);
            rc = CLI_EXIT_USAGE;
        } else {
            rc = voxelize(&o, &src, tape);
        }
    }
    expr_tape_free(tape);
    source_free(&src);
    return rc;
}
