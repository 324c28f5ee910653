/* vox csg: a volume CSG tree (.csg text, docs/csg.md) to a VOD file, in
 * this process, brick by brick (serial for now). */
#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "cli.h"
#include "csg.h"
#include "grid.h"
#include "outfile.h"
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
    "  -c, --channel CH       density (8 bit, default) or occupancy (density >= S);\n"
    "                         surface is not supported by csg yet\n"
    "  -d, --domain D         a,b (the cube [a,b]^3) or x0,x1,y0,y1,z0,z1 (default -1,1)\n"
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

typedef struct {
    const char *in, *out;
    uint32_t res;
    int channel, quiet;
    double lo[3], hi[3];
} csg_opts;

static int parse_opts(int argc, char **argv, csg_opts *o)
{
    static const struct option longs[] = {
        {"output", 1, 0, 'o'}, {"res", 1, 0, 'r'}, {"channel", 1, 0, 'c'},
        {"domain", 1, 0, 'd'}, {"quiet", 0, 0, 'q'}, {"help", 0, 0, 'h'}, {0, 0, 0, 0}};
    *o = (csg_opts){.channel = VOXEL_CH_DENSITY, .lo = {-1, -1, -1}, .hi = {1, 1, 1}};
    int c;
    optind = 1;
    while ((c = getopt_long(argc, argv, "o:r:c:d:qh", longs, NULL)) != -1) {
        switch (c) {
        case 'o': o->out = optarg; break;
        case 'r':
            if (cli_parse_uint(optarg, 1, GRID_MAX_RES, &o->res)) {
                cli_error("bad --res '%s': want 1..%u", optarg, GRID_MAX_RES);
                return CLI_EXIT_USAGE;
            }
            break;
        case 'c':
            if (!strcmp(optarg, "density")) o->channel = VOXEL_CH_DENSITY;
            else if (!strcmp(optarg, "occupancy")) o->channel = VOXEL_CH_OCCUPANCY;
            else {
                cli_error("bad --channel '%s': density or occupancy%s", optarg,
                          strcmp(optarg, "surface") ? "" : " (surface is not supported by csg yet)");
                return CLI_EXIT_USAGE;
            }
            break;
        case 'd':
            if (cli_parse_domain(optarg, o->lo, o->hi)) {
                cli_error("bad --domain '%s'", optarg);
                return CLI_EXIT_USAGE;
            }
            break;
        case 'q': o->quiet = 1; break;
        case 'h': fputs(usage, stdout); return -1;
        default: fputs(usage, stderr); return CLI_EXIT_USAGE;
        }
    }
    if (optind + 1 != argc || !o->out || !o->res) {
        fputs(usage, stderr);
        return CLI_EXIT_USAGE;
    }
    o->in = argv[optind];
    return 0;
}

static int load_tree(const csg_opts *o, csg_tree **t)
{
    char *text;
    size_t len;
    int rc = read_tree(o->in, &text, &len);
    if (rc) {
        cli_error("%s: %s", o->in, rc == -EFBIG ? "over 65536 bytes" : strerror(-rc));
        return CLI_EXIT_USAGE;
    }
    csg_error err;
    rc = csg_parse(text, len, t, &err);
    if (rc) {
        const char *name = strcmp(o->in, "-") ? o->in : "<stdin>";
        if (err.line) fprintf(stderr, "%s:%d:%d: ", name, err.line, err.col);
        else fprintf(stderr, "%s: ", name);
        if (err.node[0]) fprintf(stderr, "node '%s': ", err.node);
        fprintf(stderr, "%s\n", err.msg);
        char ex[EXPR_EXCERPT_MAX];
        if (err.line && !expr_excerpt(text, len, err.line, err.col, ex, sizeof ex))
            fputs(ex, stderr);
    }
    free(text);
    return rc ? CLI_EXIT_USAGE : 0;
}

/* Evaluate into a sparse private volume and write it. */
static int run(const csg_opts *o, const csg_tree *t, const grid_spec *g)
{
    size_t bytes = vod_volume_bytes(g->res, 8, 16, UINT64_MAX);
    void *arena = bytes ? mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                               MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0)
                        : MAP_FAILED;
    if (arena == MAP_FAILED) {
        cli_error("cannot map a volume of %ux%ux%u", g->res[0], g->res[1], g->res[2]);
        return CLI_EXIT_FAILED;
    }
    vod_volume *vol;
    csg_stats st = {0};
    int rc = vod_volume_init(&vol, arena, bytes, g->res, 8, 16);
    if (!rc) rc = csg_eval_volume(t, g, vol, o->channel == VOXEL_CH_OCCUPANCY, &st);
    char err[256] = "";
    vod_stats vst = {0};
    char tmp[4096];
    int fd = rc ? -1 : outfile_create(o->out, tmp, sizeof tmp);
    if (!rc && fd < 0) rc = fd, snprintf(err, sizeof err, "%s: %s", o->out, strerror(-fd));
    if (!rc) {
        vod_params p;
        vod_params_default(&p);
        p.channel = o->channel;
        for (int a = 0; a < 3; a++) {
            p.volume[a] = g->res[a];
            p.voxel_scale[a] = (float)g->vs;
            p.origin[a] = (float)g->lo[a];
        }
        vod_source src = vod_volume_source(vol);
        vod_sink sink = {vod_fd_write, (void *)(intptr_t)fd};
        rc = vod_write(&src, &p, &sink, &vst, err, sizeof err);
        if (!rc && fsync(fd)) rc = -errno;
        if (close(fd) && !rc) rc = -errno;
        if (!rc && rename(tmp, o->out)) rc = -errno;
        if (rc) unlink(tmp);
    }
    munmap(arena, bytes);
    if (rc) {
        cli_error("%s", err[0] ? err : strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    if (!o->quiet)
        printf("%s: %ux%ux%u, %llu bricks (%llu uniform, %llu operand subtrees skipped), "
               "%llu bytes\n", o->out, g->res[0], g->res[1], g->res[2],
               (unsigned long long)st.bricks, (unsigned long long)st.uniform_bricks,
               (unsigned long long)st.skipped, (unsigned long long)vst.file_bytes);
    return CLI_EXIT_OK;
}

int cli_csg(int argc, char **argv)
{
    csg_opts o;
    int rc = parse_opts(argc, argv, &o);
    if (rc) return rc < 0 ? CLI_EXIT_OK : rc;
    grid_spec g;
    char err[200];
    if (grid_make(o.lo, o.hi, o.res, &g, err, sizeof err)) {
        cli_error("%s", err);
        return CLI_EXIT_USAGE;
    }
    csg_tree *t;
    if ((rc = load_tree(&o, &t))) return rc;
    rc = run(&o, t, &g);
    csg_tree_free(t);
    return rc;
}
