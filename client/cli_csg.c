/* vox csg: a volume CSG tree (.csg text, docs/csg.md) to a VOD file,
 * brick by brick on the embedded engine's workers (or in this process with
 * -w 0), through the pipeline the daemon runs too. */
#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "afterexit.h"
#include "cli.h"
#include "csg.h"
#include "engine.h"
#include "grid.h"
#include "outfile.h"
#include "pipeline.h"
#include "syncbehind.h"
#include "thread_name.h"
#include "vod.h"
#include "vod_volume.h"
#include "voxel.h"

static const char usage[] =
    "usage: vox csg FILE|- -o OUT.vod --res N [options]\n"
    "  evaluates a volume CSG tree (ICVG primitives, implicit leaves, the ICVG\n"
    "  algebra, erode/dilate; see docs/csg.md) brick by brick into a VOD file;\n"
    "  FILE - reads the tree from standard input\n"
    "  -o, --output OUT.vod   the file to write (required)\n"
    "  -r, --res N            voxels along the domain's longest axis, 1..4096 (required)\n"
    "  -c, --channel CH       density (8 bit, default), occupancy (density >= S),\n"
    "                         surface (density >= S, normals from its gradient) or\n"
    "                         distance (f32 signed distance in a band; implicit and mesh\n"
    "                         leaves, union, intersection, difference, inverse)\n"
    "      --band K           distance: the band's half width in voxels, 1..32 (default 3)\n"
    "  -d, --domain D         a,b (the cube [a,b]^3) or x0,x1,y0,y1,z0,z1 (default -1,1)\n"
    "  -Z, --compress C       the bricks' compression: zlib (default), runl or none\n"
    "  -w, --workers N        worker processes, 0 = serial in this process (default: cores);\n"
    "                         the same bytes whatever N\n"
    "  -q, --quiet            no summary line\n";

static int read_tree(const char *path, char **text, size_t *len)
{
    if (strcmp(path, "-")) return cli_read_file(path, CSG_MAX_SOURCE, text, len);
    size_t cap = CSG_MAX_SOURCE + 2, n = 0;
    char *buf = malloc(cap);
    if (!buf) return -ENOMEM;
    size_t got;
    while ((got = fread(buf + n, 1, cap - 1 - n, stdin)) > 0 && n + got < cap - 1) n += got;
    n += got;
    if (ferror(stdin) || n > CSG_MAX_SOURCE) {
        free(buf);
        return ferror(stdin) ? -EIO : -EFBIG;
    }
    buf[n] = 0;
    *text = buf;
    *len = n;
    return 0;
}

int cli_csg_parse(int argc, char **argv, cli_csg_opts *o)
{
    static const struct option longs[] = {
        {"output", 1, 0, 'o'}, {"res", 1, 0, 'r'}, {"channel", 1, 0, 'c'},
        {"domain", 1, 0, 'd'}, {"quiet", 0, 0, 'q'}, {"workers", 1, 0, 'w'}, {"compress", 1, 0, 'Z'}, {"band", 1, 0, 'N'},
        {"help", 0, 0, 'h'}, {0, 0, 0, 0}};
    *o = (cli_csg_opts){.channel = VOXEL_CH_DENSITY, .lo = {-1, -1, -1}, .hi = {1, 1, 1},
                    .comp = VOD_COMP_ZLIB,
                    .workers = cli_cores()};
    int c;
    optind = 1;
    while ((c = cli_getopt("csg", argc, argv, "o:r:c:d:w:Z:qh", longs)) != -1) {
        switch (c) {
        case 'o': o->out = optarg; break;
        case 'r':
            if (cli_parse_uint(optarg, 1, GRID_MAX_RES, &o->res)) {
                cli_error("bad --res '%.40s': want 1..%u", optarg, GRID_MAX_RES);
                return CLI_EXIT_USAGE;
            }
            break;
        case 'c':
            if (!strcmp(optarg, "density")) o->channel = VOXEL_CH_DENSITY;
            else if (!strcmp(optarg, "occupancy")) o->channel = VOXEL_CH_OCCUPANCY;
            else if (!strcmp(optarg, "surface")) o->channel = VOXEL_CH_SURFACE;
            else if (!strcmp(optarg, "distance")) o->channel = VOXEL_CH_DISTANCE;
            else {
                cli_error("bad --channel '%.40s': density, occupancy, surface or distance",
                          optarg);
                return CLI_EXIT_USAGE;
            }
            break;
        case 'd':
            if (cli_parse_domain(optarg, o->lo, o->hi)) {
                cli_error("bad --domain '%.40s'", optarg);
                return CLI_EXIT_USAGE;
            }
            break;
        case 'w':
            if (cli_parse_uint(optarg, 0, ENGINE_MAX_WORKERS, &o->workers)) {
                cli_error("bad --workers '%.40s': want 0..%d", optarg, ENGINE_MAX_WORKERS);
                return CLI_EXIT_USAGE;
            }
            o->workers_given = 1;
            break;
        case 'Z':
            if (!strcmp(optarg, "zlib")) o->comp = VOD_COMP_ZLIB;
            else if (!strcmp(optarg, "runl")) o->comp = VOD_COMP_RUNL;
            else if (!strcmp(optarg, "none")) o->comp = VOD_COMP_NONE;
            else {
                cli_error("bad --compress '%.40s': zlib, runl or none", optarg);
                return CLI_EXIT_USAGE;
            }
            break;
        case 'N':
            if (cli_parse_uint(optarg, 1, VOXEL_BAND_MAX, &o->band)) {
                cli_error("bad --band '%.40s': want 1..%u voxels", optarg, VOXEL_BAND_MAX);
                return CLI_EXIT_USAGE;
            }
            break;
        case 'q': o->quiet = 1; break;
        case 'h': fputs(usage, stdout); return -1;
        default: return CLI_EXIT_USAGE;
        }
    }
    if (optind == argc) return cli_usage_error("csg", "missing the tree: FILE.csg or -");
    if (optind + 1 != argc)
        return cli_usage_error("csg", "want one FILE.csg, not also '%.40s'", argv[optind + 1]);
    if (!o->out) return cli_usage_error("csg", "missing -o OUT.vod (the file to write)");
    if (!o->res)
        return cli_usage_error("csg", "missing --res N (voxels along the longest axis)");
    if (o->band && o->channel != VOXEL_CH_DISTANCE)
        return cli_usage_error("csg", "--band is for --channel distance");
    o->in = argv[optind];
    return 0;
}

/* The bytes of every mesh and vod leaf's file, named relative to the
 * .csg file's folder (the current one for standard input), into the tree
 * (it frees them).  0, or CLI_EXIT_USAGE after a message. */
static int read_leaves(const char *path, csg_tree *t)
{
    const char *slash = strcmp(path, "-") ? strrchr(path, '/') : NULL;
    int dir_len = slash ? (int)(slash - path + 1) : 0;
    for (uint32_t i = 0; i < t->n; i++) {
        const csg_node *n = &t->node[i];
        if (n->kind != CSG_MESH && n->kind != CSG_VOD) continue;
        const char *name = t->text + n->path_off;
        char full[4096];
        if (name[0] == '/') snprintf(full, sizeof full, "%s", name);
        else snprintf(full, sizeof full, "%.*s%s", dir_len, path, name);
        char *data;
        size_t len;
        int rc = cli_read_file(full, CSG_MAX_LEAF_FILE, &data, &len);
        if (!rc && !len) free(data), rc = -ENODATA;
        if (rc) {
            cli_error("%s: node '%s': %s: %s", strcmp(path, "-") ? path : "<stdin>", n->name,
                      full, rc == -EFBIG ? "too large" : rc == -ENODATA ? "empty file"
                                                       : strerror(-rc));
            return CLI_EXIT_USAGE;
        }
        t->data[i] = data;
        t->data_len[i] = len;
    }
    return 0;
}

int cli_csg_load(const char *path, csg_tree **t, uint64_t *text_bytes)
{
    char *text;
    size_t len;
    int rc = read_tree(path, &text, &len);
    if (rc) {
        cli_error("%s: %s", path, rc == -EFBIG ? "over 65536 bytes" : strerror(-rc));
        return CLI_EXIT_USAGE;
    }
    *text_bytes = len;
    csg_error err;
    rc = csg_parse(text, len, t, &err);
    if (rc) {
        const char *name = strcmp(path, "-") ? path : "<stdin>";
        cli_text_at at = {name, text, len, err.line, err.col};
        cli_error_at(&at, "%s%s%s%s", err.node[0] ? "node '" : "", err.node,
                     err.node[0] ? "': " : "", err.msg);
    }
    free(text);
    if (!rc && (rc = read_leaves(path, *t))) {
        csg_tree_free(*t);
        *t = NULL;
    }
    return rc ? CLI_EXIT_USAGE : 0;
}

/* The job's end as the user reads it: its error (rc, why) or its summary;
 * the exit status. */
static int report(const cli_csg_opts *o, const engine_pipeline_job *job,
                  const engine_pipeline_report *r, int rc, const char *why)
{
    if (rc) {
        cli_error("%s: %s", o->out, why);
        return r->err.kind == ENGINE_BAD_JOB ? CLI_EXIT_USAGE : CLI_EXIT_FAILED;
    }
    if (r->voxels == 0) cli_warn("%s has no voxel: nothing of the tree meets its box (see --domain)", o->out);
    if (o->quiet) return CLI_EXIT_OK;
    char bricks[160];
    engine_pipeline_describe(job, r, bricks, sizeof bricks);
    printf("%s: %llu voxels %s on a %ux%ux%u grid, %s, %llu bytes; evaluated in "
           "%.3f s, written in %.3f s\n", o->out, (unsigned long long)r->voxels,
           o->channel == VOXEL_CH_DISTANCE ? "inside (negative)" : "at or above S",
           r->grid.res[0], r->grid.res[1], r->grid.res[2], bricks,
           (unsigned long long)r->st.file_bytes, r->t_voxelize, r->t_write);
    return CLI_EXIT_OK;
}

/* The job through the pipeline (its workers, or this thread with -w 0),
 * into OUT under a temporary name renamed into place once complete. */
static int run(const cli_csg_opts *o, const char *text_name, uint64_t text_bytes,
               const csg_tree *t)
{
    engine_pipeline_job job = {.kind = &engine_kind_csg,
                        .csg = {.tree = t, .source_name = text_name,
                                .source_bytes = text_bytes},
                        .res = o->res, .band = o->band};
    memcpy(job.lo, o->lo, sizeof job.lo);
    memcpy(job.hi, o->hi, sizeof job.hi);
    vod_params_default(&job.vod);
    job.vod.channel = o->channel;
    job.vod.comp = o->comp;
    engine *e = NULL;
    if (o->workers && cli_start_engine(o->workers, NULL, 0, &e)) return CLI_EXIT_FAILED;
    outfile f;
    int rc = outfile_open(&f, o->out);
    if (rc) {
        engine_destroy(e);
        cli_error("%s: %s", o->out, strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    cli_catch_interrupts();
    job.cancel = &cli_interrupt;
    vod_sink sink = {outfile_write, &f};
    engine_pipeline_report r;
    if (e) engine_lazy_release(e); /* nothing to give back before we exit */
    syncbehind sync;
    syncbehind_start(&sync, f.fd); /* flushed as written, not all at the commit */
    rc = engine_pipeline_run(e, &job, &sink, &r);
    syncbehind_stop(&sync);
    engine_abandon(e); /* its end is not waited for: the file is */
    const char *why = rc ? r.err.msg : NULL;
    int old = -1;
    if (rc || cli_interrupted()) outfile_abort(&f);
    else {
        thread_name("commit");
        old = afterexit_hold(o->out); /* freed after our exit, not in the rename */
        if ((rc = outfile_commit(&f, o->out))) why = strerror(-rc);
    }
    if (cli_interrupted()) cli_end_interrupted(o->out);
    rc = report(o, &job, &r, rc, why);
    afterexit_leave(old); /* the process exits next */
    return rc;
}

int cli_csg(int argc, char **argv)
{
    cli_csg_opts o;
    int rc = cli_csg_parse(argc, argv, &o);
    if (rc) return rc < 0 ? CLI_EXIT_OK : rc;
    grid_spec g;
    err_info err = {0};
    if (grid_make(o.lo, o.hi, o.res, &g, &err)) {
        cli_error("%s", err.msg);
        return CLI_EXIT_USAGE;
    }
    csg_tree *t;
    uint64_t text_bytes = 0;
    if ((rc = cli_csg_load(o.in, &t, &text_bytes))) return rc;
    rc = run(&o, strcmp(o.in, "-") ? o.in : NULL, text_bytes, t);
    csg_tree_free(t);
    return rc;
}
