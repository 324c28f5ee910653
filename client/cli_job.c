/* The options of a voxelization job, shared by vox voxelize and vox submit:
 * their usage texts, defaults and parsing, and loading the job's source. */
#include <errno.h>
#include <getopt.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "cli.h"
#include "source.h"
#include "vod.h"
#include "voxel.h"

#define JOB_OPTIONS \
    "  -e, --expr EXPR        the function F(x,y,z); the surface is F = 0\n" \
    "  -f, --file FILE        read F from a file (\"#@ domain ...\" lines give defaults)\n" \
    "  -o, --output OUT       the VOD file to write (written whole, then renamed into place)\n" \
    "  -d, --domain A,B | X0,X1,Y0,Y1,Z0,Z1\n" \
    "                         the box to voxelize (default -1,1)\n"
#define OUTPUT_OPTIONS \
    "      --schedule subtree|paper\n" \
    "                         hand out subtrees (default) or single octants (the paper)\n" \
    "      --channel surface|occupancy|density|distance\n" \
    "                         32-bit voxels with normals (the default for F), 1 bit (the\n" \
    "                         default for a mesh), 8-bit density (meshes only) or the\n" \
    "                         f32 signed distance in a band (meshes and expressions)\n" \
    "      --brick N          brick size, a power of two 2..256 (default 16)\n" \
    "      --compress zlib|runl|none   (default zlib)\n" \
    "      --hash sfhs|xx32   brick hash (default sfhs)\n"
#define SHOW_OPTIONS \
    "      --progress         show progress even when stderr is not a terminal\n" \
    "  -q, --quiet            no summary\n"

#define MESH_OPTIONS \
    "      --mesh FILE        a triangle mesh (OBJ, STL, PLY, OFF, glTF: told from the\n" \
    "                         contents) instead of F; --res voxels span its bounding box\n" \
    "                         and --pad\n" \
    "      --mode solid|surface|surface6|conservative|interior   (default solid)\n" \
    "      --repair none|vote|winding\n" \
    "                         meshes with holes: majority of the x, y, z parities, or the\n" \
    "                         winding number where they disagree (default none)\n" \
    "      --supersample K    density: KxKxK samples per voxel, 2..8 (default 2)\n" \
    "      --band K           distance (any job): exact within K voxels of the surface,\n" \
    "                         1..32 (default 3); beyond, K voxels with the voxel's sign\n" \
    CLI_WELD_HELP \
    "      --pad N            empty voxels around the mesh's bounding box (default 1)\n" \
    "      --bbox X0,X1,Y0,Y1,Z0,Z1\n" \
    "                         the box to voxelize instead of the mesh's bounding box\n"

static const char usage_voxelize[] =
    "usage: vox [--socket PATH] voxelize (--expr EXPR | --file FILE.vx | --mesh FILE)\n"
    "           -o OUT.vod [options]\n"
    JOB_OPTIONS
    MESH_OPTIONS
    "  -r, --res N            voxels along the longest axis, 1..4096 (default 256)\n"
    "  -w, --workers N        worker processes, 0 = serial in-process (default: cores)\n"
    "      --cpus LIST        CPUs to pin workers to, e.g. 0,1 or 0-3 (default: automatic)\n"
    OUTPUT_OPTIONS
    "      --compress-level N zlib level 1..12 (default 6): 1..6 voxd's one-pass encoder\n"
    "                         (bricks up to 64^3; libdeflate's for larger), 7..12 libdeflate's\n"
    "      --shm-size MIB     shared memory for the engine (default 2048, at most half\n"
    "                         of /dev/shm's free space)\n"
    SHOW_OPTIONS
    "      --embedded         run the embedded engine even when voxd answers\n"
    "      --daemon           run the job on voxd; exit 3 when none answers\n"
    "\n"
    "The job runs on the voxd daemon when one answers on the socket (see vox --help),\n"
    "else on the engine embedded in vox; a daemon that is busy or stopping also leaves\n"
    "the job to the embedded engine.\n"
    "-w, --cpus, --shm-size and --compress-level belong to the embedded engine and\n"
    "select it (voxd writes at level 6).  The file is the same either way.  Exit\n"
    "status: 0 done, 1 the job failed, 2 bad usage, a bad expression or mesh file, 3 --daemon\n"
    "and no voxd answering.\n";

static const char usage_submit[] =
    "usage: vox [--socket PATH] submit (--expr EXPR | --file FILE.vx | --mesh FILE |\n"
    "           --csg FILE.csg)\n"
    "           -o OUT.vod [options]\n"
    JOB_OPTIONS
    MESH_OPTIONS
    "  -r, --res N            voxels along the longest axis, 1..the daemon's max_res\n"
    "                         (default 256)\n"
    OUTPUT_OPTIONS
    "      --compress-level N 6 only: voxd writes zlib at level 6, as vox voxelize does\n"
    "                         by default (the protocol carries no level)\n"
    SHOW_OPTIONS
    "\n"
    "Runs the job on the voxd daemon at the socket (see vox --help) and writes the\n"
    "result it streams back, checked (length and CRC-32) before it is renamed into\n"
    "place.  --csg sends a volume CSG tree (docs/csg.md), checked here and by the\n"
    "daemon, as vox csg evaluates it (the same bytes; channel density by default,\n"
    "occupancy, surface or distance with --band; --domain as for an expression).\n"
    "A mesh file goes as it is (inline, or in chunks when large): the daemon\n"
    "reads it and says what is wrong with it.  The job's id is said on stderr (for\n"
    "vox cancel); an interrupt (Ctrl-C) cancels the job.  Exit status: 0 done, 1 the\n"
    "job failed or was refused (with the daemon's reason), 2 bad usage, a bad\n"
    "expression or a mesh file the daemon cannot read, 3 no voxd answering.\n";

void cli_job_usage(int cmd, FILE *f)
{
    fputs(cmd == CLI_CMD_SUBMIT ? usage_submit : usage_voxelize, f);
}

void cli_job_defaults(cli_job_opts *o)
{
    memset(o, 0, sizeof *o);
    o->res = 256;
    o->workers = cli_cores();
    o->shm_mib = 0; /* the engine's default: 2048, at most half of /dev/shm's free space */
    o->schedule = ENGINE_SCHED_SUBTREE;
    o->mode = CLI_MODE_AUTO;
    vod_params_default(&o->vod);
    o->vod.channel = VOXEL_CH_SURFACE;
    o->pad = 1;
    o->weld = -1;
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
    static const char *const ch_names[] = {"surface", "occupancy", "density", "distance",
                                           NULL};
    static const uint32_t ch_values[] = {VOXEL_CH_SURFACE, VOXEL_CH_OCCUPANCY,
                                         VOXEL_CH_DENSITY, VOXEL_CH_DISTANCE};
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

/* --mode, --repair, --supersample, --band, --pad, --bbox, --weld: 0, or -1
 * after a message. */
static int parse_mesh_option(int c, const char *arg, cli_job_opts *o)
{
    static const char *const modes[] = {"solid", "surface", "surface6",
                                        "conservative", "interior", NULL};
    static const uint32_t mode_values[] = {MESH_SOLID, MESH_SURFACE, MESH_SURFACE6,
                                           MESH_CONSERVATIVE, MESH_INTERIOR};
    static const char *const repairs[] = {"none", "vote", "winding", NULL};
    static const uint32_t repair_values[] = {MESH_REPAIR_NONE, MESH_REPAIR_VOTE,
                                             MESH_REPAIR_WINDING};
    uint32_t u;
    if (c == 'N') { /* the band: any job's distance, not a mesh's option alone */
        if (!cli_parse_uint(arg, 1, VOXEL_BAND_MAX, &o->mesh_opts.band)) return 0;
        cli_error("bad --band '%.40s': want 1..%u voxels", arg, VOXEL_BAND_MAX);
        return -1;
    }
    o->mesh_opts_given = 1;
    switch (c) {
    case 'O':
        if (!parse_choice(arg, modes, mode_values, &u)) return o->mesh_opts.mode = u, 0;
        cli_error("bad --mode '%.40s': want solid, surface, surface6, conservative or interior", arg);
        return -1;
    case 'R':
        if (!parse_choice(arg, repairs, repair_values, &u)) return o->mesh_opts.repair = u, 0;
        cli_error("bad --repair '%.40s': want none, vote or winding", arg);
        return -1;
    case 'K':
        if (!cli_parse_uint(arg, 2, 8, &o->mesh_opts.supersample)) return 0;
        cli_error("bad --supersample '%.40s': want 2..8", arg);
        return -1;
    case 'A':
        if (!cli_parse_uint(arg, 0, GRID_MAX_RES / 2, &o->pad)) return 0;
        cli_error("bad --pad '%.40s': want 0..%u voxels", arg, GRID_MAX_RES / 2);
        return -1;
    case 'W': return cli_parse_weld(arg, &o->weld);
    case 'X':
        if (!cli_parse_domain(arg, o->lo, o->hi) && strchr(arg, ',') != strrchr(arg, ','))
            return o->has_domain = 1, 0;
        cli_error("bad --bbox '%.40s': want X0,X1,Y0,Y1,Z0,Z1 with each low < high", arg);
        return -1;
    }
    return -1;
}

/* vox submit given one of voxelize's engine options or mode switches. */
static int engine_option(int c)
{
    if (c == 'E' || c == 'D')
        return cli_usage_error("submit", "--%s is vox voxelize's: vox submit always runs "
                               "the job on voxd", c == 'E' ? "embedded" : "daemon");
    return cli_usage_error("submit", "%s belongs to the daemon (its config file's "
                           "workers, cpus, shm_size); vox voxelize --embedded takes it",
                           c == 'w' ? "-w/--workers" : c == 'P' ? "--cpus" : "--shm-size");
}

/* What was given together that cannot be: 0 or CLI_EXIT_USAGE. */
static int check_job_kind(const char *name, cli_job_opts *o)
{
    int kinds = !!o->expr + !!o->file + !!o->mesh + !!o->csg;
    if (kinds != 1)
        return cli_usage_error(name, "%s of --expr, --file, --mesh%s",
                               kinds ? "give only one" : "missing the job: give one",
                               strcmp(name, "submit") ? "" : ", --csg");
    if (o->csg) { /* the densities, or the occupancy */
        if (o->mesh_opts_given) {
            cli_error("--mode, --repair, --supersample, --pad, --bbox and --weld are for --mesh jobs");
            return CLI_EXIT_USAGE;
        }
        if (!o->channel_given) o->vod.channel = VOXEL_CH_DENSITY;
        if (o->mesh_opts.band && o->vod.channel != VOXEL_CH_DISTANCE) {
            cli_error("--band is for --channel distance");
            return CLI_EXIT_USAGE;
        }
        return 0;
    }
    if (!o->mesh && o->mesh_opts_given) {
        cli_error("--mode, --repair, --supersample, --pad, --bbox and --weld are for --mesh jobs");
        return CLI_EXIT_USAGE;
    }
    if (!o->mesh && o->vod.channel == VOXEL_CH_DENSITY) {
        cli_error("--channel density is for --mesh jobs (an expression gives surface, "
                  "occupancy or distance)");
        return CLI_EXIT_USAGE;
    }
    if (o->mesh_opts.band && o->vod.channel != VOXEL_CH_DISTANCE) {
        cli_error("--band is for --channel distance");
        return CLI_EXIT_USAGE;
    }
    if (o->vod.channel == VOXEL_CH_DISTANCE && o->mesh_opts.mode != MESH_SOLID) {
        cli_error("--channel distance takes its sign from the solid: mode solid only");
        return CLI_EXIT_USAGE;
    }
    if (o->mesh && !o->channel_given) o->vod.channel = VOXEL_CH_OCCUPANCY;
    o->mesh_opts.channel = o->vod.channel;
    return 0;
}

/* --compress-level: 1..VOD_ZLIB_LEVEL_MAX for vox voxelize; submit takes
 * only the level voxd writes at, there being no level in the protocol. */
static int parse_level(int submit, const char *arg, vod_params *v)
{
    uint32_t u;
    vod_params d;
    vod_params_default(&d);
    if (cli_parse_uint(arg, 1, VOD_ZLIB_LEVEL_MAX, &u)) {
        cli_error("bad --compress-level '%.40s': want 1..%d", arg, VOD_ZLIB_LEVEL_MAX);
        return -1;
    }
    if (submit && (int)u != d.zlib_level) {
        cli_error("bad --compress-level %u: voxd writes at level %d (the protocol carries "
                  "no level); use vox voxelize --embedded --compress-level %u",
                  u, d.zlib_level, u);
        return -1;
    }
    v->zlib_level = (int)u;
    return 0;
}

/* The embedded engine's options and the mode switches are voxelize's. */
static const struct option longs_voxelize[] = {
    {"expr", 1, 0, 'e'}, {"file", 1, 0, 'f'}, {"output", 1, 0, 'o'},
    {"domain", 1, 0, 'd'}, {"res", 1, 0, 'r'}, {"workers", 1, 0, 'w'},
    {"cpus", 1, 0, 'P'}, {"schedule", 1, 0, 'S'}, {"channel", 1, 0, 'C'},
    {"brick", 1, 0, 'B'}, {"compress", 1, 0, 'Z'}, {"hash", 1, 0, 'H'},
    {"shm-size", 1, 0, 'M'}, {"progress", 0, 0, 'p'}, {"quiet", 0, 0, 'q'},
    {"embedded", 0, 0, 'E'}, {"daemon", 0, 0, 'D'}, {"compress-level", 1, 0, 'L'},
    {"mesh", 1, 0, 'm'}, {"mode", 1, 0, 'O'}, {"repair", 1, 0, 'R'},
    {"supersample", 1, 0, 'K'}, {"band", 1, 0, 'N'}, {"pad", 1, 0, 'A'}, {"bbox", 1, 0, 'X'},
    {"weld", 1, 0, 'W'},
    {"help", 0, 0, 'h'}, {0, 0, 0, 0}};
static const struct option longs_submit[] = {
    {"expr", 1, 0, 'e'}, {"file", 1, 0, 'f'}, {"output", 1, 0, 'o'},
    {"domain", 1, 0, 'd'}, {"res", 1, 0, 'r'},
    {"schedule", 1, 0, 'S'}, {"channel", 1, 0, 'C'},
    {"brick", 1, 0, 'B'}, {"compress", 1, 0, 'Z'}, {"hash", 1, 0, 'H'},
    {"progress", 0, 0, 'p'}, {"quiet", 0, 0, 'q'}, {"compress-level", 1, 0, 'L'},
    {"mesh", 1, 0, 'm'}, {"mode", 1, 0, 'O'}, {"repair", 1, 0, 'R'},
    {"supersample", 1, 0, 'K'}, {"band", 1, 0, 'N'}, {"pad", 1, 0, 'A'}, {"bbox", 1, 0, 'X'},
    {"weld", 1, 0, 'W'},
    {"csg", 1, 0, 'G'}, {"help", 0, 0, 'h'},
    /* voxelize's, each refused with why (engine_option) */
    {"workers", 1, 0, 'w'}, {"cpus", 1, 0, 'P'}, {"shm-size", 1, 0, 'M'},
    {"embedded", 0, 0, 'E'}, {"daemon", 0, 0, 'D'}, {0, 0, 0, 0}};

/* The options with a checked value: the domain, the resolution and the
 * engine's numbers.  0, or CLI_EXIT_USAGE (said). */
static int parse_value_option(int submit, int c, const char *arg, cli_job_opts *o)
{
    switch (c) {
    case 'd':
        if (cli_parse_domain(arg, o->lo, o->hi)) {
            cli_error("bad --domain '%.40s': want A,B or X0,X1,Y0,Y1,Z0,Z1 with each low < high", arg);
            return CLI_EXIT_USAGE;
        }
        o->has_domain = 1;
        break;
    case 'r':
        /* The embedded engine's limit is checked when it runs: the
         * daemon has its own (max_res). */
        if (cli_parse_uint(arg, 1, UINT32_MAX, &o->res)) {
            if (submit)
                cli_error("bad --res '%.40s': want a whole number from 1 (to the daemon's max_res)", arg);
            else
                cli_error("bad --res '%.40s': want a whole number from 1 to %u", arg, GRID_MAX_RES);
            return CLI_EXIT_USAGE;
        }
        o->res_arg = arg;
        break;
    case 'w':
        if (cli_parse_uint(arg, 0, ENGINE_MAX_WORKERS, &o->workers)) {
            cli_error("bad --workers '%.40s': want 0..%d", arg, ENGINE_MAX_WORKERS);
            return CLI_EXIT_USAGE;
        }
        o->engine_opts = 1;
        break;
    case 'S':
        if (strcmp(arg, "subtree") && strcmp(arg, "paper")) {
            cli_error("bad --schedule '%.40s': want subtree or paper", arg);
            return CLI_EXIT_USAGE;
        }
        o->schedule = arg[0] == 'p' ? ENGINE_SCHED_PAPER : ENGINE_SCHED_SUBTREE;
        break;
    case 'M':
        if (cli_parse_uint(arg, 16, 1u << 20, &o->shm_mib)) {
            cli_error("bad --shm-size '%.40s': want MiB from 16 to 1048576", arg);
            return CLI_EXIT_USAGE;
        }
        o->engine_opts = 1;
        break;
    }
    return 0;
}

/* One option c (with its argument arg) of voxelize or submit (name) into o.
 * 0, or CLI_EXIT_USAGE (said). */
static int parse_option(int cmd, const char *name, int c, const char *arg, cli_job_opts *o)
{
    int submit = cmd == CLI_CMD_SUBMIT;
    switch (c) {
    case 'e': o->expr = arg; break;
    case 'f': o->file = arg; break;
    case 'o': o->out = arg; break;
    case 'd': case 'r': case 'w': case 'S': case 'M':
        return parse_value_option(submit, c, arg, o);
    case 'P': o->cpus = arg; o->engine_opts = 1; break;
    case 'L':
        if (parse_level(submit, arg, &o->vod)) return CLI_EXIT_USAGE;
        o->engine_opts |= !submit;
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
    case 'h': cli_job_usage(cmd, stdout); exit(CLI_EXIT_OK);
    case 'm': o->mesh = arg; break;
    case 'G': o->csg = arg; break;
    case 'O': case 'R': case 'K': case 'N': case 'A': case 'X': case 'W':
        if (parse_mesh_option(c, arg, o)) return CLI_EXIT_USAGE;
        break;
    case 'C': case 'B': case 'Z': case 'H':
        o->channel_given |= c == 'C';
        if (parse_vod_option(c, arg, &o->vod)) {
            cli_error("bad value '%.40s' for --%s (see vox %s --help)", arg,
                      c == 'C' ? "channel" : c == 'B' ? "brick" : c == 'Z' ? "compress" : "hash",
                      name);
            return CLI_EXIT_USAGE;
        }
        break;
    default: return CLI_EXIT_USAGE;
    }
    return 0;
}

/* What the options must hold together once read. */
static int check_options(const char *name, int argc, char **argv, cli_job_opts *o)
{
    if (optind < argc)
        return cli_usage_error(name, "unexpected argument '%.40s'", argv[optind]);
    if (check_job_kind(name, o)) return CLI_EXIT_USAGE;
    if (!o->out) return cli_usage_error(name, "missing -o OUT.vod (the file to write)");
    if (o->mode == CLI_MODE_DAEMON && o->engine_opts) {
        cli_error("-w, --cpus, --shm-size and --compress-level are the embedded engine's: "
                  "not with --daemon");
        return CLI_EXIT_USAGE;
    }
    return 0;
}

int cli_job_parse(int cmd, int argc, char **argv, cli_job_opts *o)
{
    int submit = cmd == CLI_CMD_SUBMIT;
    const char *name = submit ? "submit" : "voxelize";
    int c;
    optind = 1;
    while ((c = cli_getopt(name, argc, argv, submit ? "e:f:o:d:r:w:qh" : "e:f:o:d:r:w:qh",
                           submit ? longs_submit : longs_voxelize)) != -1) {
        if (submit && strchr("wPMED", c)) return engine_option(c);
        int rc = parse_option(cmd, name, c, optarg, o);
        if (rc) return rc;
    }
    return check_options(name, argc, argv, o);
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
