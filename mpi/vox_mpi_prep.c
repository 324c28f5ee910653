/* vox_mpi: rank 0's preparation: its own options, vox voxelize's or vox
 * csg's, the job's input loaded, its plan, and the cut into subtrees. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>

#include "par.h"
#include "vox_mpi.h"
#include "voxel.h"

static void usage(FILE *f)
{
    fprintf(f,
"usage: mpirun [mpirun options] vox_mpi voxelize (-e EXPR | -f FILE) -o OUT [options]\n"
"       mpirun [mpirun options] vox_mpi voxelize --mesh FILE -o OUT [options]\n"
"       mpirun [mpirun options] vox_mpi csg FILE -o OUT -r N [vox csg's options]\n"
"\n"
"vox voxelize's and vox csg's jobs over the ranks of an MPI job: rank 0 cuts\n"
"the grid into subtrees (an implicit job's by its interval tests, a CSG job's\n"
"into cubes of whole bricks, a mesh job's into columns through z, each sent\n"
"with the triangles it needs) and hands them out on request, every rank (rank 0\n"
"too) runs the engine on them with -w workers of its own, and rank 0 writes\n"
"OUT, the same bytes vox voxelize -w W (vox csg -w W) writes for the job.\n"
"Only rank 0 reads files: the other hosts need the vox_mpi binary alone.\n"
"\n"
"voxelize takes vox voxelize's options (vox voxelize --help), --mesh's too\n"
"(--mode, --repair, --supersample, --pad, --bbox, --weld, --channel, --band);\n"
"csg takes vox csg's (vox csg --help: -o, -r, -c, -d, -w, -Z, --band, -q), its\n"
"FILE a file.\n"
"\n"
"  -e, --expr EXPR       the implicit function F(x,y,z)\n"
"  -f, --file FILE       ... from a .vx file (its #@ directives apply)\n"
"  -o, --output FILE     the VOD file, written by rank 0 under a temporary\n"
"                        name and renamed when complete\n"
"  -r, --res N           voxels along the longest axis (default 256)\n"
"  -d, --domain A,B | X0,X1,Y0,Y1,Z0,Z1\n"
"                        the domain (default [-1,1]^3)\n"
"  -w, --workers N       worker processes per rank (default: the CPUs the\n"
"                        rank may run on; 0: the serial algorithm per rank)\n"
"      --cpus LIST       CPUs to pin each rank's workers to\n"
"      --shm-size MiB    each rank's shared-memory segment (default 2048)\n"
"      --schedule subtree|paper, --channel, --brick, --compress,\n"
"      --compress-level, --hash\n"
"                        as vox voxelize (vox voxelize --help)\n"
"      --subtrees N      subtrees (mesh: columns) per rank to aim for (default %d)\n"
"      --stats           rank 0's end by stage, and a line per rank: host,\n"
"                        subtrees, bricks and bytes sent\n"
"      --progress        the progress line, by subtrees done\n"
"      --source-name NAME  the source's name in the file's metadata (voxd's;\n"
"                        \"\" for none)\n"
"  -q, --quiet           no summary\n"
"\n"
"Under mpirun: --mca btl self,tcp for ranks on several hosts over TCP,\n"
"--oversubscribe for more ranks than cores; as root, --allow-run-as-root\n"
"(docs/mpi.md).\n", SUBTREES_PER_RANK);
}

/* --mesh-format NAME: 0, or -1 when NAME is no format's. */
static int parse_mesh_format(const char *s, mesh_format *f)
{
    static const mesh_format all[] = {MESH_FORMAT_OBJ, MESH_FORMAT_STL, MESH_FORMAT_PLY,
                                      MESH_FORMAT_OFF, MESH_FORMAT_GLTF};
    for (size_t i = 0; i < sizeof all / sizeof *all; i++)
        if (!strcasecmp(s, mesh_format_name(all[i]))) return *f = all[i], 0;
    return -1;
}

/* vox csg's job given the options voxd passes and vox csg has not:
 * 1 when argv[i] (and its value, then *i moves on) was one, 0 when not,
 * -1 after a message. */
static int csg_option(prep *p, int argc, char **argv, int *i)
{
    const char *a = argv[*i], *v = *i + 1 < argc ? argv[*i + 1] : NULL;
    uint32_t u;
    if (!strcmp(a, "--packed")) return p->packed = 1;
    if (!strcmp(a, "--progress")) return p->csg_progress = 1;
    if (strcmp(a, "--brick") && strcmp(a, "--hash") && strcmp(a, "--source-bytes")) return 0;
    ++*i;
    if (!strcmp(a, "--brick") && v && !cli_parse_uint(v, 2, 256, &u) && !(u & (u - 1)))
        return p->csg_brick = u, 1;
    if (!strcmp(a, "--hash") && v && (!strcmp(v, "sfhs") || !strcmp(v, "xx32")))
        return p->csg_hash = !strcmp(v, "sfhs") ? VOD_HASH_SFHS : VOD_HASH_XX32, 1;
    if (!strcmp(a, "--source-bytes") && v && !cli_parse_uint(v, 0, UINT32_MAX, &u))
        return p->source_bytes = u, 1;
    mpi_msg("bad %s '%.40s'", a, v ? v : "");
    return -1;
}

/* One of vox_mpi's own options at argv[*i] taken (1), none (0), or -1
 * after a message. */
static int own_option(prep *p, int argc, char **argv, int *i)
{
    const char *a = argv[*i];
    if (!strcmp(a, "--stats")) return p->stats = 1;
    if (!strcmp(a, "--subtrees")) {
        if (++*i >= argc || cli_parse_uint(argv[*i], 1, 4096, &p->per_rank)) {
            mpi_msg("bad --subtrees: want a whole number from 1 to 4096");
            return -1;
        }
        return 1;
    }
    if (!strcmp(a, "--source-name") || !strcmp(a, "--mesh-format")) {
        if (++*i >= argc) {
            mpi_msg("%s wants a value", a);
            return -1;
        }
        if (a[2] == 's') return p->source_name = argv[*i], 1;
        if (!parse_mesh_format(argv[*i], &p->mesh_format)) return 1;
        mpi_msg("bad --mesh-format '%.40s': want obj, stl, ply, off or gltf", argv[*i]);
        return -1;
    }
    return argc > 1 && !strcmp(argv[1], "csg") ? csg_option(p, argc, argv, i) : 0;
}

/* Take vox_mpi's own options out of argv (the rest is vox voxelize's or
 * vox csg's). */
static int own_options(prep *p, int *argc, char **argv)
{
    int k = 0;
    for (int i = 0; i < *argc; i++) {
        if (!strcmp(argv[i], "-h") || !strcmp(argv[i], "--help")) {
            usage(stdout);
            return CLI_EXIT_OK;
        }
        int rc = i ? own_option(p, *argc, argv, &i) : 0;
        if (rc < 0) return CLI_EXIT_USAGE;
        if (!rc) argv[k++] = argv[i];
    }
    *argc = k;
    return -1;
}

/* The source's name in the file's metadata: --source-name's, else the
 * file's. */
static const char *source_name(const prep *p, const char *file)
{
    return !p->source_name ? file : p->source_name[0] ? p->source_name : NULL;
}

/* The tree the ranks run: packed for the broadcast (one of at most 2
 * GiB); its distance leaves' k the band (csg_tree_set_band, as the
 * pipeline's csg kind sets it). */
static int pack_tree(prep *p, const char *name)
{
    if (p->o.vod.channel == VOXEL_CH_DISTANCE)
        csg_tree_set_band(p->tree, p->o.mesh_opts.band ? p->o.mesh_opts.band : VOXEL_BAND_DEFAULT);
    p->kind = MPI_KIND_CSG; /* mpi_prep_free frees the packed tree */
    int rc = csg_tree_pack(p->tree, &p->input, &p->input_bytes);
    if (rc) {
        mpi_msg("%s: %s", name, strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    if (p->input_bytes > INT32_MAX) { /* one broadcast */
        mpi_msg("%s: the tree and its files' bytes pass 2 GiB; vox_mpi broadcasts them at once",
                name);
        return CLI_EXIT_USAGE;
    }
    return -1;
}

/* An expression's distance runs as vox voxelize runs it: a CSG tree of one
 * implicit leaf, the expression's text (kind_implicit's distance_tree), cut
 * and run as a CSG job's; rank 0's plan stays the implicit job's (its
 * metadata). */
static int implicit_distance_tree(prep *p)
{
    csg_tree *t = calloc(1, sizeof *t);
    if (!t || !(t->text = malloc(p->src.len + 1))) {
        free(t);
        mpi_msg("out of memory");
        return CLI_EXIT_FAILED;
    }
    memcpy(t->text, p->src.text, p->src.len);
    t->text[p->src.len] = '\0';
    t->text_len = p->src.len;
    t->n = 1;
    csg_node *n = &t->node[0];
    n->kind = CSG_IMPLICIT;
    n->a = n->b = -1;
    n->expr_len = (uint32_t)p->src.len;
    snprintf(n->name, sizeof n->name, "implicit");
    p->tree = t;
    return pack_tree(p, p->src.name);
}

static int prepare_implicit(prep *p, engine_pipeline_job *pj)
{
    int rc = cli_job_source(&p->o, &p->src, &p->tape);
    if (rc) return rc;
    pj->kind = &engine_kind_implicit;
    pj->implicit.tape = p->tape;
    pj->implicit.source = p->src.text;
    pj->implicit.source_len = p->src.len;
    pj->implicit.source_name = source_name(p, p->src.path);
    if (p->o.vod.channel == VOXEL_CH_DISTANCE) return implicit_distance_tree(p);
    p->kind = MPI_KIND_IMPLICIT;
    p->input = (uint8_t *)p->tape;
    p->input_bytes = expr_tape_bytes(p->tape);
    return -1;
}

static int prepare_mesh(prep *p, engine_pipeline_job *pj)
{
    mesh_error merr;
    if (mesh_load(p->o.mesh, p->mesh_format, NULL, &p->mesh, &merr)) {
        char m[sizeof merr.msg + 64];
        mpi_msg("%s: %s", p->o.mesh, mesh_error_str(&merr, m, sizeof m));
        return CLI_EXIT_USAGE;
    }
    if (p->mesh.warning[0]) mpi_msg("warning: %s: %s", p->o.mesh, p->mesh.warning);
    if (p->o.weld >= 0 && mesh_weld(&p->mesh, p->o.weld, NULL)) {
        mpi_msg("%s: no triangle is left once welded at %g (or no memory)", p->o.mesh, p->o.weld);
        mesh_free(&p->mesh);
        return CLI_EXIT_USAGE;
    }
    p->mesh_loaded = 1;
    p->kind = MPI_KIND_MESH;
    struct stat sb;
    pj->kind = &engine_kind_mesh;
    pj->mesh.mesh = &p->mesh;
    pj->mesh.opts = p->o.mesh_opts;
    pj->mesh.pad = p->o.pad;
    pj->mesh.fit = !p->o.has_domain;
    pj->mesh.source_name = source_name(p, p->o.mesh);
    pj->mesh.source_bytes = stat(p->o.mesh, &sb) == 0 ? (uint64_t)sb.st_size : 0;
    return -1;
}

/* A tree packed as csg_pack.h packs it (voxd's job file): 0, or the
 * exit code after a message. */
static int load_packed(const char *path, csg_tree **out)
{
    char *buf;
    size_t len;
    int rc = cli_read_file(path, INT32_MAX, &buf, &len); /* one broadcast */
    if (!rc) {
        rc = csg_tree_unpack((const uint8_t *)buf, len, out);
        free(buf);
    }
    if (rc) mpi_msg("%s: %s", path, rc == -EPROTO ? "not a packed CSG tree" : strerror(-rc));
    return rc ? CLI_EXIT_USAGE : 0;
}

/* vox csg's options into the job's (the rest of vox_mpi reads those). */
static int prepare_csg(prep *p, int argc, char **argv, engine_pipeline_job *pj)
{
    cli_csg_opts co;
    int rc = cli_csg_parse(argc, argv, &co);
    if (rc) return rc < 0 ? CLI_EXIT_OK : rc;
    if (!strcmp(co.in, "-")) {
        mpi_msg("vox_mpi csg reads its tree from a file, not standard input");
        return CLI_EXIT_USAGE;
    }
    uint64_t text_bytes = p->source_bytes;
    if ((rc = p->packed ? load_packed(co.in, &p->tree) : cli_csg_load(co.in, &p->tree, &text_bytes)))
        return rc;
    p->o.vod.channel = co.channel;
    p->o.mesh_opts.band = co.band;
    if ((rc = pack_tree(p, co.in)) >= 0) return rc;
    p->o.out = co.out;
    p->o.quiet = co.quiet;
    p->o.res = co.res;
    if (co.workers_given) p->o.workers = co.workers;
    p->o.shm_mib = 0; /* vox csg's: the engine's default */
    vod_params_default(&p->o.vod);
    p->o.vod.channel = co.channel;
    p->o.vod.comp = co.comp;
    if (p->csg_brick) p->o.vod.brick = p->csg_brick;
    if (p->csg_hash) p->o.vod.hash = p->csg_hash;
    p->o.progress = p->csg_progress;
    memcpy(p->o.lo, co.lo, sizeof co.lo);
    memcpy(p->o.hi, co.hi, sizeof co.hi);
    pj->kind = &engine_kind_csg;
    pj->csg.tree = p->tree;
    pj->csg.source_name = source_name(p, co.in);
    pj->csg.source_bytes = text_bytes;
    return -1;
}

/* The options of vox voxelize or vox csg, the job's input loaded. */
static int prepare_kind(prep *p, int argc, char **argv, engine_pipeline_job *pj)
{
    cli_job_defaults(&p->o);
    p->o.workers = WORKERS_AUTO;
    if (argc >= 2 && !strcmp(argv[1], "csg")) return prepare_csg(p, argc - 1, argv + 1, pj);
    if (argc < 2 || strcmp(argv[1], "voxelize")) {
        usage(stderr);
        return CLI_EXIT_USAGE;
    }
    int rc = cli_job_parse(CLI_CMD_VOXELIZE, argc - 1, argv + 1, &p->o);
    if (rc) return rc;
    if (p->o.mode == CLI_MODE_DAEMON) {
        mpi_msg("--daemon: vox_mpi runs its jobs itself, never on a voxd");
        return CLI_EXIT_USAGE;
    }
    if (p->o.res > GRID_MAX_RES) {
        mpi_msg("bad --res '%s': want a whole number from 1 to %u", p->o.res_arg, GRID_MAX_RES);
        return CLI_EXIT_USAGE;
    }
    return p->o.mesh ? prepare_mesh(p, pj) : prepare_implicit(p, pj);
}

/* A mesh job's topology (the repair dropped when the mesh is watertight,
 * as engine_pipeline_run drops it) and its triangles binned to the tiles. */
static int prepare_bins(prep *p)
{
    p->run_opts = p->o.mesh_opts;
    int rc = mesh_topology(&p->mesh, &p->topo);
    if (!rc && p->topo.watertight) p->run_opts.repair = MESH_REPAIR_NONE;
    if (!rc && p->run_opts.repair != MESH_REPAIR_WINDING)
        rc = mesh_bin(&p->mesh, &p->plan.grid, &p->run_opts, NULL, par_cpus(), &p->bins);
    if (rc) mpi_msg("%s: the mesh's edges and tiles: %s", p->o.mesh, strerror(-rc));
    return rc;
}

/* A mesh job's columns without a triangle are left out: they hold no
 * voxel, and a rank gets no empty mesh. */
static void drop_empty_columns(prep *p)
{
    size_t k = 0;
    for (size_t i = 0; i < p->cut.n; i++) {
        uint32_t t[4];
        mpi_column_tiles(&p->plan.grid, p->cut.oct[i], t);
        int any = 0;
        for (uint32_t ty = t[1]; ty < t[3] && !any; ty++)
            for (uint32_t tx = t[0]; tx < t[2] && !any; tx++) {
                uint64_t c = (uint64_t)ty * p->bins.tiles[0] + tx;
                any = p->bins.start[c + 1] > p->bins.start[c];
            }
        if (any) p->cut.oct[k++] = p->cut.oct[i];
    }
    p->cut.n = k;
}

/* The cut: an implicit job's by the kernel's interval tests; a CSG job's
 * octants of whole storage bricks; a mesh job's columns of whole tiles. */
static int make_cut(prep *p)
{
    size_t target = (size_t)p->per_rank * p->ctx->nranks;
    if (p->kind == MPI_KIND_IMPLICIT)
        return mpi_cut_make(p->tape, &p->plan.grid, &p->L, target, &p->cut);
    if (p->kind == MPI_KIND_CSG)
        return mpi_cut_grid(&p->plan.grid, &p->L, target, 4 /* CSG_VOLUME_BRICK */, 0,
                            &p->cut);
    int rc = mpi_cut_grid(&p->plan.grid, &p->L, target, 6 /* MESH_TILE */, 1, &p->cut);
    /* a distance's columns without triangles still hold the band's width */
    if (!rc && p->bins.start && p->o.vod.channel != VOXEL_CH_DISTANCE) drop_empty_columns(p);
    return rc;
}

/* -1 when the job is ready to run; else the exit code of every rank. */
int mpi_prepare(prep *p, int argc, char **argv)
{
    p->per_rank = SUBTREES_PER_RANK;
    p->fd = -1;
    int rc = own_options(p, &argc, argv);
    if (rc >= 0) return rc;
    engine_pipeline_job pj = {0};
    if ((rc = prepare_kind(p, argc, argv, &pj)) >= 0) return rc;
    memcpy(pj.lo, p->o.lo, sizeof pj.lo);
    memcpy(pj.hi, p->o.hi, sizeof pj.hi);
    pj.res = p->o.res;
    pj.schedule = p->o.schedule;
    pj.band = p->o.mesh_opts.band;
    pj.vod = p->o.vod;
    err_info err = {0};
    if (engine_pipeline_plan(&pj, &p->plan, &p->v, p->meta) ||
        vod_layout_make(&p->v, p->plan.grid.depth, &p->L, &err)) {
        mpi_msg("%s", p->plan.err.msg[0] ? p->plan.err.msg : err.msg);
        return CLI_EXIT_USAGE;
    }
    if (p->kind == MPI_KIND_MESH && prepare_bins(p)) return CLI_EXIT_FAILED;
    if ((rc = make_cut(p))) {
        mpi_msg("cutting the job into subtrees: %s", strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    /* unnamed until complete (outfile.h): no kill, not even mpirun's
     * SIGKILL, leaves a partial file */
    if ((rc = outfile_open(&p->ctx->out_file, p->o.out))) {
        mpi_msg("cannot create %s: %s", p->o.out, strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    p->fd = p->ctx->out_file.fd;
    return -1;
}

wire_job mpi_job_of(const prep *p)
{
    wire_job j = {.status = -1, .schedule = p->o.schedule, .kind = p->kind,
                  .workers = p->o.workers, .shm_mib = p->o.shm_mib, .grid = p->plan.grid,
                  .vod = p->v, .mesh_opts = p->run_opts, .node_level = p->cut.node_level,
                  .input_bytes = p->input_bytes};
    j.vod.metadata = NULL;
    if (p->o.cpus) snprintf(j.cpus, sizeof j.cpus, "%s", p->o.cpus);
    return j;
}

/* A rank's part of job j whose input (the tape, the tree) is at input. */
mpi_subtree_job mpi_subtree_job_of(const wire_job *j, const void *input, const csg_tree *tree)
{
    return (mpi_subtree_job){.kind = (mpi_kind)j->kind,
                             .tape = j->kind == MPI_KIND_IMPLICIT ? input : NULL,
                             .tree = tree, .mesh_opts = j->mesh_opts, .grid = j->grid,
                             .vod = j->vod, .node_level = j->node_level,
                             .schedule = j->schedule};
}

void mpi_prep_free(prep *p)
{
    mpi_cut_free(&p->cut);
    expr_tape_free(p->tape);
    source_free(&p->src);
    if (p->mesh_loaded) mesh_free(&p->mesh);
    mesh_bins_free(&p->bins);
    csg_tree_free(p->tree);
    if (p->kind == MPI_KIND_CSG) free(p->input);
}
