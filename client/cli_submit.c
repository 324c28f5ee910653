/* vox submit / status / cancel / ping: the voxd daemon through libvox; and
 * the daemon half of vox voxelize. */
#include <errno.h>
#include <fcntl.h>
#include <libgen.h>
#include <getopt.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "cli.h"
#include "csg.h"
#include "progress.h"
#include "voxel.h"

#define CONNECT_TIMEOUT_MS 10000 /* a daemon that answers at all says hello at once */
#define TIMEOUT_MS 30000         /* silence (pinged after half) before giving up */

/* ---------------------------------------------------------------- connecting */

int cli_connect(const char *sock, int timeout_ms, vox_client **c, vox_error *err)
{
    vox_options opts = {.timeout_ms = timeout_ms, .client_name = "vox"};
    int rc = vox_connect(sock, &opts, c, err);
    if (rc == 0) vox_set_timeout(*c, TIMEOUT_MS);
    return rc;
}

static int no_daemon(const char *sock, int rc, const vox_error *err, const char *instead)
{
    if (rc == -ENOENT || rc == -ECONNREFUSED)
        cli_error("no voxd answering on %s (%s); start one with `voxd --config ...` or %s",
                  sock, rc == -ENOENT ? "no such socket" : "connection refused", instead);
    else
        cli_error("cannot use voxd on %s: %s", sock, err->message);
    return CLI_EXIT_NO_DAEMON;
}

int cli_no_daemon(const char *sock, int rc, const vox_error *err)
{
    return no_daemon(sock, rc, err, "leave out --daemon");
}

static int connect_or_say(const char *sock, vox_client **c)
{
    vox_error err;
    int rc = cli_connect(sock, CONNECT_TIMEOUT_MS, c, &err);
    return rc ? no_daemon(sock, rc, &err, "use vox voxelize") : 0;
}

/* "LIMIT_EXCEEDED: res 5000 is over ..." for a daemon's error, else ours. */
static void print_failure(const char *what, int rc, const vox_error *err)
{
    if (VOX_IS_SERVER_ERROR(rc))
        cli_error("%s: %s: %s", what, vox_error_name(rc), err->message);
    else
        cli_error("%s: %s", what, err->message[0] ? err->message : vox_strerror(rc));
}

/* ---------------------------------------------------------------- a job */

static int on_job_progress(void *ud, double fraction, int level, uint64_t voxels)
{
    progress_update(ud, fraction, level, voxels);
    return cli_interrupted() != 0;
}

static int vox_channel(int ch)
{
    return ch == VOXEL_CH_OCCUPANCY ? VOX_CHANNEL_OCCUPANCY
           : ch == VOXEL_CH_DENSITY ? VOX_CHANNEL_DENSITY
           : ch == VOXEL_CH_DISTANCE ? VOX_CHANNEL_DISTANCE
                                    : VOX_CHANNEL_SURFACE;
}

static int vox_comp(uint32_t comp)
{
    return comp == VOD_COMP_NONE ? VOX_COMP_NONE
           : comp == VOD_COMP_RUNL ? VOX_COMP_RUNL
                                   : VOX_COMP_ZLIB;
}

/* The grid is the daemon's, from its summary. */
static void print_summary(const cli_job_opts *o, const vox_summary *s)
{
    if (s->voxels == 0) cli_warn("%s has no voxel: nothing of the job meets its box (see --domain)", o->out);
    if (o->quiet) return;
    double t = s->seconds_voxelize;
    printf("%s: %llu voxels on a %ux%ux%u grid", o->out, (unsigned long long)s->voxels,
           s->grid[0], s->grid[1], s->grid[2]);
    printf(" in %.3f s (%.2f Mvoxels/s), VOD written in %.3f s\n", t,
           t > 0 ? s->voxels / t / 1e6 : 0.0, s->seconds_write);
    printf("  %llu bytes, %llu brick%s, CRC %08x\n", (unsigned long long)s->file_bytes,
           (unsigned long long)s->bricks, cli_plural(s->bricks), s->crc32);
    printf("  voxd job %llu, %.3f s in the queue", (unsigned long long)s->job_id,
           s->seconds_queued);
    if (s->mpi_ranks) printf(", through MPI on %u rank%s", s->mpi_ranks, cli_plural(s->mpi_ranks));
    printf("\n");
    if (!s->has_mesh) return;
    printf("  mesh: %u triangles, %llu open and %llu non-manifold edges: %s; %u tiles "
           "with triangles\n", s->mesh.triangles, (unsigned long long)s->mesh.open_edges,
           (unsigned long long)s->mesh.nonmanifold_edges,
           s->mesh.watertight ? "watertight" : "not watertight", s->mesh.tiles);
    if (s->mesh.repair_skipped)
        printf("  repair: not needed, the mesh is watertight (its parities agree)\n");
    else if (o->mesh_opts.repair != MESH_REPAIR_NONE)
        printf("  repair: %llu voxels where the parities along x, y, z disagree, in %llu "
               "storage bricks\n", (unsigned long long)s->mesh.disagreements,
               (unsigned long long)s->mesh.disagree_bricks);
}

static int submit_and_receive(vox_client *c, const vox_job *job,
                              const cli_job_opts *o, int quiet_refusal, int *refused)
{
    uint64_t id;
    uint32_t qpos;
    vox_error err;
    int rc = vox_submit_job(c, job, &id, &qpos, &err);
    if (rc) {
        if (VOX_IS_SERVER_ERROR(rc) && refused) *refused = rc;
        if (!(quiet_refusal && (rc == VOX_EBUSY || rc == VOX_ESHUTTING_DOWN)))
            print_failure("job failed", rc, &err);
        return CLI_EXIT_FAILED;
    }

    /* Always said, on a terminal or not: the id is what vox cancel takes. */
    if (qpos) cli_note("voxd job %" PRIu64 ", %u ahead of it in the queue", id, qpos);
    else cli_note("voxd job %" PRIu64, id);
    progress pr;
    progress_init(&pr, o->progress);
    if (cli_interrupted()) vox_cancel(c, id, &err); /* its outcome shows below */
    vox_summary sum;
    vox_receive_opts ro = {.progress = on_job_progress, .ud = &pr, .sum = &sum};
    rc = vox_receive_to_file(c, id, o->out, &ro, &err);
    progress_done(&pr);

    if (rc) {
        char what[64];
        if (rc == VOX_ECANCELLED && cli_interrupted())
            snprintf(what, sizeof what, "job %" PRIu64 " cancelled (interrupted)", id);
        else
            snprintf(what, sizeof what, "job %" PRIu64 " failed", id);
        if (rc == VOX_ECANCELLED && cli_interrupted()) cli_error("%s", what);
        else print_failure(what, rc, &err);
        /* A mesh file the daemon cannot read: as when vox reads it itself. */
        return rc == VOX_EINVALID_INPUT && (o->mesh || o->csg) ? CLI_EXIT_USAGE
                                                                : CLI_EXIT_FAILED;
    }
    print_summary(o, &sum);
    return CLI_EXIT_OK;
}

/* A .gltf whose buffers name files: the daemon reads no file, so the JSON
 * goes with them embedded as data: URIs (mesh_gltf_embed), in a mapping of
 * its own in place of the file's.  0, or CLI_EXIT_USAGE after a message. */
static int embed_gltf(const char *path, void **data, size_t *len)
{
    char *dup = strdup(path), *out;
    size_t n;
    mesh_error err;
    int rc = dup ? mesh_gltf_embed(*data, *len, dirname(dup), &out, &n, &err) : -ENOMEM;
    free(dup);
    if (rc || !out) {
        char msg[300];
        if (rc) cli_error("%s: %s", path, rc == -ENOMEM && !err.msg[0] ? strerror(ENOMEM)
                                                                      : mesh_error_str(&err, msg, sizeof msg));
        if (rc) munmap(*data, *len);
        return rc ? CLI_EXIT_USAGE : 0;
    }
    void *p = mmap(NULL, n, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    munmap(*data, *len);
    if (p == MAP_FAILED) {
        free(out);
        cli_error("%s: %s", path, strerror(errno));
        return CLI_EXIT_USAGE;
    }
    memcpy(p, out, n);
    free(out);
    *data = p;
    *len = n;
    return 0;
}

/* The mesh file's bytes as they are, mapped (the daemon parses them, as
 * vox voxelize --embedded does the file): 0, or CLI_EXIT_USAGE after a
 * message in the loader's words. */
static int map_mesh(const char *path, void **data, size_t *len)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    struct stat st;
    if (fd < 0 || fstat(fd, &st) != 0) {
        cli_error("%s: cannot open: %s", path, strerror(errno));
        if (fd >= 0) close(fd);
        return CLI_EXIT_USAGE;
    }
    const char *bad = !S_ISREG(st.st_mode) ? "not a regular file"
                      : st.st_size == 0    ? "empty file"
                                           : NULL;
    void *p = bad ? MAP_FAILED : mmap(NULL, (size_t)st.st_size, PROT_READ, MAP_PRIVATE, fd, 0);
    if (!bad && p == MAP_FAILED) bad = strerror(errno);
    close(fd);
    if (bad) {
        cli_error("%s: %s", path, bad);
        return CLI_EXIT_USAGE;
    }
    *data = p;
    *len = (size_t)st.st_size;
    return embed_gltf(path, data, len);
}

/* libvox's mesh enums are the protocol's: mesh_vox.h's plus one. */
_Static_assert(VOX_MESH_MODE_SOLID == MESH_SOLID + 1 && VOX_MESH_MODE_SURFACE == MESH_SURFACE + 1 &&
                   VOX_MESH_MODE_SURFACE6 == MESH_SURFACE6 + 1 &&
                   VOX_MESH_MODE_CONSERVATIVE == MESH_CONSERVATIVE + 1 &&
                   VOX_MESH_MODE_INTERIOR == MESH_INTERIOR + 1,
               "VOX_MESH_MODE_* numbers");
_Static_assert(VOX_MESH_REPAIR_NONE == MESH_REPAIR_NONE + 1 &&
                   VOX_MESH_REPAIR_VOTE == MESH_REPAIR_VOTE + 1 &&
                   VOX_MESH_REPAIR_WINDING == MESH_REPAIR_WINDING + 1,
               "VOX_MESH_REPAIR_* numbers");

/* The mesh job of o, on the file's bytes. */
static void mesh_job(const cli_job_opts *o, const void *data, size_t len, vox_job *job)
{
    job->kind = VOX_JOB_MESH;
    job->mesh = (vox_mesh){
        .data = data, .len = len, .format = VOX_MESH_FORMAT_AUTO, .source_name = o->mesh,
        .mode = (int)o->mesh_opts.mode + 1,     /* the protocol's numbers */
        .repair = (int)o->mesh_opts.repair + 1,
        /* vox_mesh's one field for the density's samples and the band */
        .supersample = o->mesh_opts.channel == VOXEL_CH_DISTANCE ? o->mesh_opts.band
                                                                 : o->mesh_opts.supersample,
        .weld = o->weld >= 0,
        .weld_eps = o->weld >= 0 ? o->weld : 0,
        .fit = !o->has_domain, .pad = o->pad,
        .domain = {o->lo[0], o->hi[0], o->lo[1], o->hi[1], o->lo[2], o->hi[2]},
        .res = o->res,
    };
}

/* A CSG tree as libvox's nodes: the values the daemon rebuilds the same
 * tree from (the rotation in radians, as the parser made it). */
static int csg_wire_kind(csg_kind k)
{
    static const int ops[CSG_KIND_COUNT] = {
        [CSG_CUBOID] = VOX_CSG_PRIMITIVE, [CSG_ELLIPSOID] = VOX_CSG_PRIMITIVE,
        [CSG_CYLINDER] = VOX_CSG_PRIMITIVE, [CSG_CONE] = VOX_CSG_PRIMITIVE,
        [CSG_IMPLICIT] = VOX_CSG_IMPLICIT, [CSG_MESH] = VOX_CSG_MESH, [CSG_VOD] = VOX_CSG_VOD,
        [CSG_UNION] = VOX_CSG_UNION,
        [CSG_INTERSECTION] = VOX_CSG_INTERSECTION, [CSG_TRIM] = VOX_CSG_TRIM,
        [CSG_CAP] = VOX_CSG_CAP, [CSG_DIFFERENCE_A] = VOX_CSG_DIFFERENCE_A,
        [CSG_DIFFERENCE_B] = VOX_CSG_DIFFERENCE_B, [CSG_DIFFERENCE] = VOX_CSG_DIFFERENCE,
        [CSG_ADD] = VOX_CSG_ADD, [CSG_MODULATE] = VOX_CSG_MODULATE,
        [CSG_DIVIDE_A] = VOX_CSG_DIVIDE_A, [CSG_DIVIDE] = VOX_CSG_DIVIDE,
        [CSG_INVERSE] = VOX_CSG_INVERSE, [CSG_SCALAR_ADD] = VOX_CSG_SCALAR_ADD,
        [CSG_SCALAR_MUL] = VOX_CSG_SCALAR_MUL, [CSG_ERODE] = VOX_CSG_ERODE,
        [CSG_DILATE] = VOX_CSG_DILATE,
    };
    return ops[k];
}

static void csg_wire_node(const csg_tree *t, const csg_node *n, vox_csg_node *v)
{
    static const int prims[] = {[CSG_CUBOID] = VOX_PRIMITIVE_CUBOID,
                                [CSG_ELLIPSOID] = VOX_PRIMITIVE_ELLIPSOID,
                                [CSG_CYLINDER] = VOX_PRIMITIVE_CYLINDER,
                                [CSG_CONE] = VOX_PRIMITIVE_CONE};
    *v = (vox_csg_node){.op = csg_wire_kind(n->kind), .name = n->name};
    if (n->a >= 0) v->children[v->n_children++] = (uint32_t)n->a;
    if (n->b >= 0) v->children[v->n_children++] = (uint32_t)n->b;
    if (n->kind <= CSG_CONE) {
        v->primitive = prims[n->kind];
        memcpy(v->center, n->center, sizeof v->center);
        memcpy(v->size, n->size, sizeof v->size);
        memcpy(v->rotate, n->rot, sizeof v->rotate);
        if (n->kind == CSG_CYLINDER || n->kind == CSG_CONE) v->axis = n->axis + 1;
    } else if (n->kind == CSG_IMPLICIT) {
        v->source = t->text + n->expr_off;
        v->source_len = n->expr_len;
        v->has_domain = n->has_domain;
        v->domain[0] = n->dom_lo, v->domain[1] = n->dom_hi;
    } else if (n->kind == CSG_DIVIDE || n->kind == CSG_SCALAR_ADD || n->kind == CSG_SCALAR_MUL) {
        v->scalar = n->param;
    } else if (n->kind == CSG_ERODE || n->kind == CSG_DILATE) {
        v->k = n->k;
    } else if (n->kind == CSG_MESH || n->kind == CSG_VOD) {
        v->data = t->data[n - t->node];
        v->data_len = t->data_len[n - t->node];
        if (n->kind == CSG_MESH) {
            v->has_fit = n->has_fit;
            memcpy(v->fit, n->fit, sizeof v->fit);
            v->scale = n->scale;
        }
    }
}

/* The CSG job of o: the tree parsed here (its errors with line and column),
 * then sent as nodes (*nodes, freed by the caller with the tree *t). */
static int csg_job(const cli_job_opts *o, vox_job *job, csg_tree **t, vox_csg_node **nodes)
{
    uint64_t bytes;
    int rc = cli_csg_load(o->csg, t, &bytes);
    if (rc) return rc;
    if (!(*nodes = calloc((*t)->n, sizeof **nodes))) {
        cli_error("out of memory");
        return CLI_EXIT_FAILED;
    }
    for (uint32_t i = 0; i < (*t)->n; i++) csg_wire_node(*t, &(*t)->node[i], &(*nodes)[i]);
    job->kind = VOX_JOB_CSG;
    job->csg = (vox_csg){
        .nodes = *nodes, .n_nodes = (*t)->n,
        .source_name = strcmp(o->csg, "-") ? o->csg : NULL, .source_bytes = bytes,
        .domain = {o->lo[0], o->hi[0], o->lo[1], o->hi[1], o->lo[2], o->hi[2]},
        .res = o->res, .band = o->mesh_opts.band,
    };
    return 0;
}

/* The job of o: the expression in src, or the mesh file o->mesh (mapped
 * into *map, *map_len; the caller unmaps it).  0, or an exit code. */
static int daemon_job(const cli_job_opts *o, const source *src, vox_job *job, void **map,
                      size_t *map_len)
{
    *job = (vox_job){
        .channel = vox_channel(o->vod.channel),
        .brick = o->vod.brick,
        .comp = vox_comp(o->vod.comp),
        .hash = o->vod.hash == VOD_HASH_XX32 ? VOX_HASH_XX32 : VOX_HASH_SFHS,
    };
    if (o->csg) return 0; /* csg_job's */
    if (o->mesh) {
        int rc = map_mesh(o->mesh, map, map_len);
        if (rc == 0) mesh_job(o, *map, *map_len, job);
        return rc;
    }
    if (src->len == 0) {
        cli_error("%s: the expression is empty", src->name);
        return CLI_EXIT_USAGE;
    }
    job->kind = VOX_JOB_IMPLICIT;
    job->implicit = (vox_implicit){
        .source = src->text,
        .source_len = src->len,
        .source_name = src->path,
        .domain = {o->lo[0], o->hi[0], o->lo[1], o->hi[1], o->lo[2], o->hi[2]},
        .res = o->res,
        .schedule = o->schedule == ENGINE_SCHED_PAPER ? VOX_SCHEDULE_PAPER
                                                      : VOX_SCHEDULE_SUBTREE,
        .band = o->mesh_opts.band,
    };
    return 0;
}

int cli_daemon_job(vox_client *c, const cli_job_opts *o, const source *src,
                   int quiet_refusal, int *refused)
{
    if (refused) *refused = 0;
    vox_job job;
    void *map = NULL;
    size_t map_len = 0;
    csg_tree *tree = NULL;
    vox_csg_node *nodes = NULL;
    int rc = daemon_job(o, src, &job, &map, &map_len);
    if (rc == 0 && o->csg) rc = csg_job(o, &job, &tree, &nodes);
    if (rc) {
        csg_tree_free(tree);
        free(nodes);
        return rc;
    }
    /* An interrupt cancels the job on the daemon, then vox ends as the
     * job does (without SA_RESTART: it cuts the wait short).  The handler
     * is in place before the job exists, so no interrupt is lost between
     * the daemon's accepting it and our waiting for it; and it stays until
     * vox exits, as the embedded path's does: a signal once the file is in
     * place changes nothing (exit 0, the file whole), where the default
     * action put back here would end vox by the signal over a whole file.
     * The flag is vox's one flag, so that an embedded run after a daemon's
     * refusal sees an interrupt that came during the refusal. */
    cli_catch_interrupts();
    rc = submit_and_receive(c, &job, o, quiet_refusal, refused);
    if (map) munmap(map, map_len);
    csg_tree_free(tree);
    free(nodes);
    return rc;
}

int cli_submit(int argc, char **argv, const char *sock)
{
    cli_job_opts o;
    cli_job_defaults(&o);
    int rc = cli_job_parse(CLI_CMD_SUBMIT, argc, argv, &o);
    if (rc) return rc;
    /* A mesh goes as it is: the daemon parses it; a CSG tree is parsed
     * here (csg_job), then checked again by the daemon. */
    source src = {0};
    if (!o.mesh && !o.csg && (rc = cli_job_source(&o, &src, NULL))) return rc;
    vox_client *c;
    rc = connect_or_say(sock, &c);
    if (rc == 0) {
        rc = cli_daemon_job(c, &o, o.mesh || o.csg ? NULL : &src, 0, NULL);
        vox_close(c);
    }
    source_free(&src);
    return rc;
}

/* ---------------------------------------------------------------- status, cancel, ping */

/* Only --help: 0 to go on, else the exit code. */
static int no_options(const char *cmd, int argc, char **argv, const char *usage)
{
    static const struct option longs[] = {{"help", 0, 0, 'h'}, {0, 0, 0, 0}};
    int c;
    optind = 1;
    while ((c = cli_getopt(cmd, argc, argv, "h", longs)) != -1) {
        if (c == 'h') {
            fputs(usage, stdout);
            exit(CLI_EXIT_OK);
        }
        return CLI_EXIT_USAGE;
    }
    return -1;
}

/* A command without options or arguments (status, ping): its usage
 * errors, else connected.  0 with *c, or the exit status. */
/* A command of no arguments: connected to sock, ask prints what the daemon
 * says, or returns a VOX_E* code with err set (then said as cmd's failure). */
typedef int (*plain_ask)(vox_client *c, const char *sock, vox_error *err);
static int plain_command(const char *cmd, int argc, char **argv, const char *usage,
                         const char *sock, plain_ask ask)
{
    int rc = no_options(cmd, argc, argv, usage);
    if (rc >= 0) return rc;
    if (optind < argc) return cli_usage_error(cmd, "unexpected argument '%.40s'", argv[optind]);
    vox_client *c;
    if ((rc = connect_or_say(sock, &c))) return rc;
    vox_error err;
    rc = ask(c, sock, &err);
    if (rc) print_failure(cmd, rc, &err);
    vox_close(c);
    return rc ? CLI_EXIT_FAILED : CLI_EXIT_OK;
}

static void format_duration(double s, char *buf, size_t cap)
{
    unsigned long long t = (unsigned long long)s;
    if (s < 60) snprintf(buf, cap, "%.1f s", s);
    else if (t < 3600) snprintf(buf, cap, "%llu min %02llu s", t / 60, t % 60);
    else if (t < 86400) snprintf(buf, cap, "%llu h %02llu min", t / 3600, t / 60 % 60);
    else snprintf(buf, cap, "%llu d %02llu h", t / 86400, t / 3600 % 24);
}

static const char *state_name(int s)
{
    switch (s) {
    case VOX_WORKER_IDLE: return "idle";
    case VOX_WORKER_BUSY: return "busy";
    case VOX_WORKER_STARTING: return "starting";
    case VOX_WORKER_STALLED: return "stalled";
    default: return "unknown";
    }
}

/* Every job, running and queued: what vox cancel needs to find one. */
static void print_jobs(const vox_status_info *st)
{
    static const char *const kinds[] = {"?", "implicit", "mesh", "csg"};
    printf("jobs: %zu\n", st->n_jobs);
    if (st->n_jobs)
        printf("  %8s %6s %-8s %5s %-7s %6s %10s\n", "ID", "UID", "KIND", "RES", "STATE", "DONE",
               "FOR");
    for (size_t i = 0; i < st->n_jobs; i++) {
        const vox_job_status *j = &st->jobs[i];
        char t[64];
        format_duration(j->seconds, t, sizeof t);
        printf("  %8llu %6u %-8s %5u %-7s %5.1f%% %10s\n", (unsigned long long)j->id, j->uid,
               kinds[j->kind >= 1 && j->kind <= 3 ? j->kind : 0], j->res,
               j->state == VOX_JOB_RUNNING ? "running" : "queued", j->fraction * 100.0, t);
    }
}

static const char usage_status[] =
    "usage: vox [--socket PATH] status\n"
    "The daemon's state: uptime and clients, the queue, the running job, every job\n"
    "(running and queued: id, uid, kind, resolution, state, progress, time), and each\n"
    "worker's pid, CPU, state (idle, busy, stalled, starting), jobs, voxels per\n"
    "second over its last job, and how often it was replaced (died, or killed for\n"
    "making no progress: STALLS).\n"
    "Exit status: 0, 1 the request failed, 3 no voxd answering on the socket.\n";

static int show_status(vox_client *c, const char *sock, vox_error *err)
{
    vox_status_info st;
    int rc = vox_status(c, &st, err);
    if (rc) return rc;
    vox_server_info info;
    vox_server(c, &info);
    char up[64];
    format_duration(st.uptime, up, sizeof up);
    printf("%s on %s: up %s, %u client%s\n", info.name, sock, up, st.clients,
           st.clients == 1 ? "" : "s");
    printf("queue: %u job%s waiting (limit %u)\n", st.queued, st.queued == 1 ? "" : "s",
           info.max_queued_jobs);
    if (st.has_running) {
        char t[64];
        format_duration(st.running_seconds, t, sizeof t);
        printf("running: job %llu of uid %u, %.1f%% done, for %s\n",
               (unsigned long long)st.running_job_id, st.running_uid,
               st.running_fraction * 100.0, t);
    } else {
        printf("running: nothing\n");
    }
    print_jobs(&st);
    printf("workers: %zu\n", st.n_workers);
    if (st.n_workers)
        printf("  %8s %4s %-9s %6s %14s %8s %6s\n", "PID", "CPU", "STATE", "JOBS", "VOXELS/S",
               "REPLACED", "STALLS");
    for (size_t i = 0; i < st.n_workers; i++) {
        const vox_worker_status *w = &st.workers[i];
        char cpu[16];
        if (w->cpu < 0) snprintf(cpu, sizeof cpu, "-");
        else snprintf(cpu, sizeof cpu, "%d", w->cpu);
        printf("  %8u %4s %-9s %6llu %14.0f %8u %6u\n", w->pid, cpu, state_name(w->state),
               (unsigned long long)w->jobs, w->voxels_per_second, w->replaced, w->stalls);
    }
    vox_status_free(&st);
    return 0;
}

int cli_status(int argc, char **argv, const char *sock)
{
    return plain_command("status", argc, argv, usage_status, sock, show_status);
}

static const char usage_cancel[] =
    "usage: vox [--socket PATH] cancel JOB_ID\n"
    "Asks voxd to cancel a job (its id is said by vox submit and listed by\n"
    "vox status); the job ends with CANCELLED for the client that submitted it.\n"
    "The daemon decides whose jobs a connection may cancel and says why it refuses.\n"
    "Exit status: 0 the daemon took the cancel, 1 it refused (with its reason), 2 bad\n"
    "usage, 3 no voxd answering on the socket.\n";

int cli_cancel(int argc, char **argv, const char *sock)
{
    int rc = no_options("cancel", argc, argv, usage_cancel);
    if (rc >= 0) return rc;
    if (argc - optind != 1)
        return cli_usage_error("cancel", "%s", argc - optind ? "want one JOB_ID"
                                                             : "missing JOB_ID (vox status lists them)");
    const char *arg = argv[optind];
    char *end;
    errno = 0;
    unsigned long long id = strtoull(arg, &end, 10);
    if (arg[0] < '0' || arg[0] > '9' || *end || errno || id == 0)
        return cli_usage_error("cancel", "bad JOB_ID '%.40s': want a job number (from 1)", arg);
    vox_client *c;
    if ((rc = connect_or_say(sock, &c))) return rc;
    vox_error err;
    rc = vox_cancel(c, id, &err);
    vox_close(c);
    if (rc == 0 || rc == VOX_ECANCELLED) {
        printf("job %llu: cancel taken by voxd\n", id);
        return CLI_EXIT_OK;
    }
    char what[64];
    snprintf(what, sizeof what, "cannot cancel job %llu", id);
    print_failure(what, rc, &err);
    return CLI_EXIT_FAILED;
}

static const char usage_ping[] =
    "usage: vox [--socket PATH] ping\n"
    "Says hello to voxd and times one round trip; prints the daemon's name, protocol\n"
    "version and workers.  Exit status: 0 it answered, 1 it failed to, 3 no voxd\n"
    "answering on the socket.\n";

static int show_ping(vox_client *c, const char *sock, vox_error *err)
{
    double rtt;
    int rc = vox_ping(c, &rtt, err);
    if (rc) return rc;
    vox_server_info info;
    vox_server(c, &info);
    printf("%s on %s: protocol %u, %u worker%s, round trip %.3f ms\n", info.name, sock,
           info.version, info.workers, info.workers == 1 ? "" : "s", rtt * 1e3);
    return 0;
}

int cli_ping(int argc, char **argv, const char *sock)
{
    return plain_command("ping", argc, argv, usage_ping, sock, show_ping);
}
