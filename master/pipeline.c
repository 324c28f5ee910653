/* One job from its description to a VOD sink: see pipeline.h. */
#include "pipeline.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

#include "clock.h"
#include "job_meta.h"
#include "master.h"
#include "par.h"
#include "subdiv.h"
#include "voxel.h"

#define SERIAL_CELLS (1u << 27) /* 4 GiB of address space, not of memory */

__attribute__((format(printf, 4, 5))) static int fail(pipeline_report *r,
                                                      engine_failure f, int rc,
                                                      const char *fmt, ...)
{
    r->err.failure = f;
    r->err.code = rc;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(r->err.message, sizeof r->err.message, fmt, ap);
    va_end(ap);
    return rc;
}

uint32_t pipeline_band(const pipeline_job *job)
{
    return job->band ? job->band : VOXEL_BAND_DEFAULT;
}

/* The job's VOD parameters: its geometry and metadata on the caller's
 * choice of channel, brick, compression and hash. */
static void vod_setup(vod_params *v, const pipeline_job *job, const double lo[3],
                      const double hi[3], const grid_spec *g, char meta[JOB_META_MAX])
{
    job_meta m = {
        .source = job->implicit.source, .source_len = job->implicit.source_len,
        .source_name = job->implicit.source_name, .res = job->res,
        .grid = {g->res[0], g->res[1], g->res[2]},
        .lo = {lo[0], lo[1], lo[2]},
        .hi = {hi[0], hi[1], hi[2]},
    };
    char pairs[160];
    if (job->kind == PIPELINE_MESH) {
        static const char *const modes[] = {"solid", "surface", "surface6",
                                            "conservative", "interior"};
        static const char *const repairs[] = {"none", "vote", "winding"};
        snprintf(pairs, sizeof pairs, "mesh_triangles=%u\nmesh_mode=%s\nmesh_repair=%s\n",
                 job->mesh.mesh->n_triangles, modes[job->mesh.opts.mode],
                 repairs[job->mesh.opts.repair]);
        m.source = "";
        m.source_len = job->mesh.source_bytes;
        m.source_name = job->mesh.source_name;
        m.kind_pairs = pairs;
    } else if (job->kind == PIPELINE_CSG) {
        snprintf(pairs, sizeof pairs, "csg_nodes=%u\n", job->csg.tree->n);
        m.generator = "vox csg";
        m.source = "";
        m.source_len = job->csg.source_bytes;
        m.source_name = job->csg.source_name;
        m.kind_pairs = pairs;
    }
    job_meta_format(meta, JOB_META_MAX, &m);
    if (job->vod.channel == VOXEL_CH_DISTANCE) {
        size_t n = strlen(meta);
        snprintf(meta + n, JOB_META_MAX - n, "distance_band=%u\ndistance_units=world\n",
                 pipeline_band(job));
    }
    *v = job->vod;
    v->metadata = meta;
    for (int a = 0; a < 3; a++) {
        v->volume[a] = g->res[a];
        v->voxel_scale[a] = (float)g->vs;
        v->origin[a] = (float)g->lo[a];
    }
}

/* The job's progress as one fraction: the voxelization's to
 * VOXELIZE_SHARE, the VOD's to just under 1; 1 only once the file is
 * written (pipeline_run says it then), never while a stage still runs. */
#define VOXELIZE_SHARE 0.6
#define WRITE_END 0.99

typedef struct {
    const pipeline_job *job;
    pipeline_stage stage;
    uint64_t voxels;   /* the voxelization's, shown while writing */
} staged;

static void on_stage_progress(void *ud, const engine_progress *p)
{
    staged *s = ud;
    engine_progress q = *p;
    if (s->stage == PIPELINE_VOXELIZE) {
        q.fraction = VOXELIZE_SHARE * p->fraction;
    } else {
        q.fraction = VOXELIZE_SHARE + (WRITE_END - VOXELIZE_SHARE) * p->fraction;
        q.level = 0;
        q.voxels = s->voxels;
    }
    s->job->progress(s->job->ud, &q);
}

/* The voxelization stage of job on the engine's workers, its progress
 * through prog and ud. */
static int engine_stage(engine *e, const pipeline_job *job, const grid_spec *g,
                        void (*prog)(void *, const engine_progress *), void *ud,
                        engine_result *er)
{
    if (job->kind == PIPELINE_MESH) {
        engine_mesh_job mj = {.mesh = job->mesh.mesh, .grid = *g,
                              .opts = job->mesh.opts,
                              .mip_channel = job->vod.channel, .progress = prog,
                              .ud = ud, .cancel = job->cancel};
        return engine_mesh(e, &mj, er);
    }
    if (job->kind == PIPELINE_CSG) {
        engine_csg_job cj = {.tree = job->csg.tree, .grid = *g,
                             .channel = job->vod.channel,
                             .progress = prog, .ud = ud, .cancel = job->cancel};
        return engine_csg(e, &cj, er);
    }
    engine_job ej = {.tape = job->implicit.tape, .grid = *g,
                     .schedule = job->schedule, .progress = prog,
                     .ud = ud, .cancel = job->cancel};
    return engine_voxelize(e, &ej, er);
}

/* A mesh's topology found in a thread of its own while the engine bins
 * the triangles and the workers run the tiles: the master is idle then. */
typedef struct {
    const mesh *m;
    par_task task;
    int rc;
    mesh_topo topo;
    double seconds;
} topo_job;

static void *topo_run(void *arg)
{
    topo_job *t = arg;
    double t0 = clock_now();
    t->rc = mesh_edges(t->m, &t->topo);
    t->seconds = clock_now() - t0;
    return NULL;
}

static int topo_error(pipeline_report *r, int rc);

/* Wait for t and put its result in r: 0, or the error mesh_check gives. */
static int topo_join(topo_job *t, pipeline_report *r)
{
    par_join(&t->task);
    r->topo = t->topo;
    r->t_topology = t->seconds;
    return t->rc ? topo_error(r, t->rc) : 0;
}

/* The voxelization on e, then (t not NULL) the topology joined, then the
 * VOD written. */
static int run_engine(engine *e, const pipeline_job *job, const vod_params *v,
                      vod_sink *sink, topo_job *t, pipeline_report *r)
{
    staged sp = {.job = job, .stage = PIPELINE_VOXELIZE};
    void (*prog)(void *, const engine_progress *) = job->progress ? on_stage_progress : NULL;
    engine_result er;
    r->stage = PIPELINE_VOXELIZE;
    int rc = engine_stage(e, job, &r->grid, prog, &sp, &er);
    int trc = t ? topo_join(t, r) : 0;
    r->voxels = er.voxels;
    r->tiles = er.tiles;
    r->t_bin = er.t_bin;
    r->disagreements = er.disagreements;
    r->disagree_bricks = er.disagree_bricks;
    r->octants = er.octants;
    r->csg_bricks = er.csg_bricks;
    r->csg_uniform = er.csg_uniform;
    r->csg_skipped = er.csg_skipped;
    r->csg_voxel_evals = er.csg_voxel_evals;
    r->restarts = er.restarts;
    r->stalls = er.stalls;
    r->t_voxelize = er.seconds;
    r->master_cpu = er.master_cpu;
    r->worker_cpu = er.worker_cpu;
    if (trc) return trc;
    if (rc) return fail(r, er.failure, rc, "%s", er.error);
    r->stage = PIPELINE_WRITE;
    sp.stage = PIPELINE_WRITE;
    sp.voxels = er.voxels;
    double t0 = clock_now();
    rc = engine_write_vod_watched(e, v, sink, &r->st, &r->err, prog, &sp, job->cancel);
    r->t_write = clock_now() - t0;
    if (!rc && job->progress) {
        engine_progress done = {.fraction = 1.0, .voxels = er.voxels,
                                .seconds = r->t_voxelize + r->t_write};
        job->progress(job->ud, &done);
    }
    return rc;
}

/* The sink as the serial writer sees it: what the caller's sink said is
 * the sink's failure, whatever message the writer puts around it. */
typedef struct {
    vod_sink *inner;
    int rc;
} watched_sink;

static int watched_write(void *ud, const void *buf, size_t n)
{
    watched_sink *w = ud;
    int rc = w->inner->write(w->inner->ud, buf, n);
    if (rc) w->rc = rc;
    return rc;
}

/* The write stage in this thread, from the octree t or else source s. */
static int write_serial(octree *t, vod_source *s, const vod_params *v,
                        vod_sink *sink, pipeline_report *r)
{
    r->stage = PIPELINE_WRITE;
    watched_sink w = {sink, 0};
    vod_sink ws = {watched_write, &w};
    char err[sizeof r->err.message] = "";
    double t0 = clock_now();
    int rc = t ? vod_write_octree(t, v, &ws, &r->st, err, sizeof err)
               : vod_write(s, v, &ws, &r->st, err, sizeof err);
    r->t_write = clock_now() - t0;
    if (rc && w.rc == rc) return fail(r, ENGINE_SINK, rc, "%s", strerror(-rc));
    if (rc) return fail(r, engine_vod_failure(rc, 1), rc, "%s", err);
    return 0;
}

/* A mesh job in this thread: every tile in turn (mesh_voxelize) into a
 * volume in a sparse private mapping, touched only as bricks are made. */
static int run_serial_mesh(const pipeline_job *job, const vod_params *v,
                           vod_sink *sink, pipeline_report *r)
{
    const mesh_vox_opts *o = &job->mesh.opts;
    r->stage = PIPELINE_VOXELIZE;
    size_t bytes = vod_volume_bytes(r->grid.res, mesh_vox_bits(o), MESH_VOLUME_BRICK,
                                    UINT64_MAX);
    void *arena = bytes ? mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                               MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0)
                        : MAP_FAILED;
    if (arena == MAP_FAILED)
        return fail(r, ENGINE_LIMIT, -ENOMEM, "cannot map a volume of %ux%ux%u",
                    r->grid.res[0], r->grid.res[1], r->grid.res[2]);
    vod_volume *vol;
    int rc = vod_volume_init(&vol, arena, bytes, r->grid.res, mesh_vox_bits(o),
                             MESH_VOLUME_BRICK);
    mesh_tile_stats st = {0};
    double t0 = clock_now();
    if (!rc) rc = mesh_voxelize(job->mesh.mesh, &r->grid, o, vol, &st);
    r->t_voxelize = clock_now() - t0;
    r->voxels = st.voxels;
    r->disagreements = st.disagreements;
    r->disagree_bricks = st.disagree_bricks;
    if (rc) {
        fail(r, rc == -ENOMEM ? ENGINE_LIMIT : ENGINE_FAULT, rc,
             "voxelizing the mesh: %s", strerror(-rc));
    } else {
        vod_source src = vod_volume_source(vol);
        rc = write_serial(NULL, &src, v, sink, r);
    }
    munmap(arena, bytes);
    return rc;
}

/* A csg job in this thread: every brick in turn (csg_eval_volume) into a
 * volume in a sparse private mapping, the engine's layout. */
/* The file leaves of a csg job in a sparse private mapping (*arena,
 * *abytes; none: MAP_FAILED), their volumes in leaves. */
static int serial_leaves(const pipeline_job *job, pipeline_report *r, void **arena,
                         size_t *abytes, vod_volume *leaves[CSG_MAX_NODES])
{
    *arena = MAP_FAILED;
    memset(leaves, 0, CSG_MAX_NODES * sizeof *leaves);
    const csg_tree *t = job->csg.tree;
    if (!csg_has_file_leaves(t)) return 0;
    size_t one = vod_volume_bytes(r->grid.res, 8, CSG_VOLUME_BRICK, UINT64_MAX), n = 0;
    for (uint32_t i = 0; i < t->n; i++)
        n += t->node[i].kind == CSG_MESH || t->node[i].kind == CSG_VOD;
    *abytes = one * n;
    *arena = one ? mmap(NULL, *abytes, PROT_READ | PROT_WRITE,
                        MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0)
                 : MAP_FAILED;
    if (*arena == MAP_FAILED)
        return fail(r, ENGINE_LIMIT, -ENOMEM, "cannot map the leaves' volumes");
    char msg[sizeof r->err.message];
    size_t used;
    int rc = csg_leaves_build(t, &r->grid, *arena, *abytes, leaves, &used, msg, sizeof msg);
    if (rc)
        return fail(r, rc == -ENOMEM || rc == -ENOSPC ? ENGINE_LIMIT : ENGINE_BAD_JOB, rc, "%s",
                    msg);
    return 0;
}

static int run_serial_csg(const pipeline_job *job, const vod_params *v,
                          vod_sink *sink, pipeline_report *r)
{
    r->stage = PIPELINE_VOXELIZE;
    void *larena;
    size_t lbytes = 0;
    vod_volume *leaves[CSG_MAX_NODES];
    double t0 = clock_now();
    int rc = serial_leaves(job, r, &larena, &lbytes, leaves);
    if (rc) {
        if (larena != MAP_FAILED) munmap(larena, lbytes);
        return rc;
    }
    uint32_t bits = csg_channel_bits(v->channel);
    size_t bytes = vod_volume_bytes(r->grid.res, bits, CSG_VOLUME_BRICK, UINT64_MAX);
    void *arena = bytes ? mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                               MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0)
                        : MAP_FAILED;
    if (arena == MAP_FAILED) {
        if (larena != MAP_FAILED) munmap(larena, lbytes);
        return fail(r, ENGINE_LIMIT, -ENOMEM, "cannot map a volume of %ux%ux%u",
                    r->grid.res[0], r->grid.res[1], r->grid.res[2]);
    }
    vod_volume *vol;
    rc = vod_volume_init(&vol, arena, bytes, r->grid.res, bits, CSG_VOLUME_BRICK);
    csg_stats st = {0};
    if (!rc) rc = csg_eval_volume(job->csg.tree, &r->grid, (const vod_volume *const *)leaves,
                                  vol, v->channel, &st);
    r->t_voxelize = clock_now() - t0;
    r->csg_bricks = st.bricks;
    r->csg_uniform = st.uniform_bricks;
    r->csg_skipped = st.skipped;
    r->csg_voxel_evals = st.voxel_evals;
    r->voxels = st.solid_voxels;
    if (rc) {
        fail(r, rc == -ENOMEM ? ENGINE_LIMIT : ENGINE_FAULT, rc,
             "evaluating the tree: %s", strerror(-rc));
    } else {
        vod_source src = vod_volume_source(vol);
        rc = write_serial(NULL, &src, v, sink, r);
    }
    munmap(arena, bytes);
    if (larena != MAP_FAILED) munmap(larena, lbytes);
    return rc;
}

/* The serial algorithm: its octree in a sparse private mapping, touched
 * only as cells are handed out. */
static int run_serial(const pipeline_job *job, const vod_params *v,
                      vod_sink *sink, pipeline_report *r)
{
    if (job->kind == PIPELINE_MESH) return run_serial_mesh(job, v, sink, r);
    if (job->kind == PIPELINE_CSG) return run_serial_csg(job, v, sink, r);
    size_t bytes = octree_arena_bytes(SERIAL_CELLS);
    void *arena = mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                       MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    r->stage = PIPELINE_VOXELIZE;
    if (arena == MAP_FAILED)
        return fail(r, ENGINE_FAULT, -errno, "cannot map the octree: %s",
                    strerror(errno));
    octree t;
    octree_init(&t, arena, SERIAL_CELLS, r->grid.depth);
    double t0 = clock_now();
    int rc = subdiv_serial(job->implicit.tape, &r->grid, &t);
    r->t_voxelize = clock_now() - t0;
    r->voxels = t.voxels;
    if (rc == -ENOMEM)
        fail(r, ENGINE_LIMIT, rc, "the octree outgrew its 4 GiB arena");
    else if (rc)
        fail(r, ENGINE_FAULT, rc, "%s", strerror(-rc));
    if (!rc) rc = write_serial(&t, NULL, v, sink, r);
    munmap(arena, bytes);
    return rc;
}

/* A mesh job's domain: its bounding box grown by pad voxels each side,
 * the voxel size such that res voxels span the longest side of that. */
static int mesh_fit(const pipeline_job *job, double lo[3], double hi[3],
                    pipeline_report *r)
{
    const mesh *m = job->mesh.mesh;
    double ext = 0;
    for (int a = 0; a < 3; a++)
        if ((double)m->hi[a] - m->lo[a] > ext) ext = (double)m->hi[a] - m->lo[a];
    if (!(ext > 0))
        return fail(r, ENGINE_BAD_JOB, -EINVAL, "the mesh has an empty bounding box");
    if ((uint64_t)job->mesh.pad * 2 >= job->res)
        return fail(r, ENGINE_BAD_JOB, -EINVAL,
                    "a padding of %u voxels leaves no room in %u voxels",
                    job->mesh.pad, job->res);
    double vs = ext / (double)(job->res - 2 * job->mesh.pad);
    for (int a = 0; a < 3; a++) {
        lo[a] = m->lo[a] - job->mesh.pad * vs;
        hi[a] = m->hi[a] + job->mesh.pad * vs;
    }
    return 0;
}

/* The job's kind-specific checks and its domain. */
static int job_domain(const pipeline_job *job, double lo[3], double hi[3],
                      pipeline_report *r)
{
    memcpy(lo, job->lo, 3 * sizeof *lo);
    memcpy(hi, job->hi, 3 * sizeof *hi);
    if (pipeline_band(job) > CSG_DIST_MAX_BAND)
        return fail(r, ENGINE_BAD_JOB, -EINVAL, "a band of %u voxels: at most %u",
                    job->band, CSG_DIST_MAX_BAND);
    if (job->kind == PIPELINE_IMPLICIT && job->vod.channel == VOXEL_CH_DISTANCE &&
        !job->implicit.source)
        return fail(r, ENGINE_BAD_JOB, -EINVAL, "the distance job has no expression text");
    if (job->kind == PIPELINE_IMPLICIT)
        return job->implicit.tape ? 0
                                  : fail(r, ENGINE_BAD_JOB, -EINVAL,
                                         "the job has no expression");
    if (job->kind == PIPELINE_CSG) {
        if (!job->csg.tree || !job->csg.tree->n)
            return fail(r, ENGINE_BAD_JOB, -EINVAL, "the job has no csg tree");
        if (!csg_channel_bits(job->vod.channel))
            return fail(r, ENGINE_BAD_JOB, -EINVAL,
                        "a csg job writes the density, occupancy or surface channel");
        const csg_node *root = &job->csg.tree->node[job->csg.tree->n - 1];
        if (job->vod.channel == VOXEL_CH_DISTANCE &&
            (root->kind != CSG_IMPLICIT || root->has_domain))
            return fail(r, ENGINE_BAD_JOB, -ENOTSUP,
                        "the distance channel of a csg tree is not built yet (only of "
                        "an implicit surface)");
        return 0;
    }
    if (job->kind != PIPELINE_MESH || !job->mesh.mesh || !job->mesh.mesh->n_triangles)
        return fail(r, ENGINE_BAD_JOB, -EINVAL, "the job has no expression or mesh");
    char err[sizeof r->err.message];
    if (mesh_vox_check(&job->mesh.opts, err, sizeof err))
        return fail(r, ENGINE_BAD_JOB, -EINVAL, "%s", err);
    return job->mesh.fit ? mesh_fit(job, lo, hi, r) : 0;
}

/* mesh_edges' failure rc, as the job's (before any voxel). */
static int topo_error(pipeline_report *r, int rc)
{
    r->stage = PIPELINE_GRID;
    return fail(r, rc == -E2BIG ? ENGINE_LIMIT : ENGINE_FAULT, rc,
                "the mesh's edges: %s", strerror(-rc));
}

/* A mesh job's topology into r; the repair dropped from *run when the
 * mesh is watertight. */
static int mesh_check(pipeline_job *run, pipeline_report *r)
{
    double t0 = clock_now();
    int rc = mesh_edges(run->mesh.mesh, &r->topo);
    r->t_topology = clock_now() - t0;
    if (rc) return topo_error(r, rc);
    if (r->topo.watertight && run->mesh.opts.repair != MESH_REPAIR_NONE) {
        run->mesh.opts.repair = MESH_REPAIR_NONE;
        r->repair_skipped = 1;
    }
    return 0;
}

int pipeline_plan(const pipeline_job *job, pipeline_report *r, vod_params *v,
                  char meta[JOB_META_MAX])
{
    memset(r, 0, sizeof *r);
    r->stage = PIPELINE_GRID;
    double lo[3], hi[3];
    int rc = job_domain(job, lo, hi, r);
    if (rc) return rc;
    char err[sizeof r->err.message];
    rc = grid_make(lo, hi, job->res, &r->grid, err, sizeof err);
    if (rc) return fail(r, ENGINE_BAD_JOB, rc, "%s", err);
    vod_setup(v, job, lo, hi, &r->grid, meta); /* the repair asked for */
    return 0;
}

/* An implicit job's distance runs as the csg kind's: a tree of one
 * implicit leaf (the job's text), its k the band; csg_dist does the rest. */
static int distance_tree(const pipeline_job *job, csg_tree **out)
{
    csg_tree *t = calloc(1, sizeof *t);
    char *text = malloc(job->implicit.source_len + 1);
    if (!t || !text) {
        free(t);
        free(text);
        return -ENOMEM;
    }
    memcpy(text, job->implicit.source, job->implicit.source_len);
    text[job->implicit.source_len] = 0;
    t->n = 1;
    t->text = text;
    t->text_len = job->implicit.source_len;
    csg_node *n = &t->node[0];
    n->kind = CSG_IMPLICIT;
    n->a = n->b = -1;
    n->expr_len = (uint32_t)job->implicit.source_len;
    n->k = pipeline_band(job);
    snprintf(n->name, sizeof n->name, "implicit");
    *out = t;
    return 0;
}

/* pipeline_run from t0 on; r->t_job set before the engine's release. */
static int pipeline_stages(engine *e, const pipeline_job *job, vod_sink *sink,
                           double t0, pipeline_report *r)
{
    char meta[JOB_META_MAX];
    vod_params v;
    int rc = pipeline_plan(job, r, &v, meta);
    if (rc) return rc;
    pipeline_job run = *job;
    csg_tree *dist_tree = NULL;
    if (job->kind == PIPELINE_IMPLICIT && job->vod.channel == VOXEL_CH_DISTANCE) {
        if ((rc = distance_tree(job, &dist_tree)))
            return fail(r, ENGINE_FAULT, rc, "%s", strerror(-rc));
        run.kind = PIPELINE_CSG;
        run.csg.tree = dist_tree;
    }
    /* Without a repair the topology decides nothing before the write: on
     * an engine it is found while the triangles are voxelized. */
    topo_job topo = {.m = job->mesh.mesh};
    bool overlap = e && job->kind == PIPELINE_MESH &&
                   job->mesh.opts.repair == MESH_REPAIR_NONE;
    if (overlap) par_start(&topo.task, topo_run, &topo);
    else if (job->kind == PIPELINE_MESH && (rc = mesh_check(&run, r))) return rc;
    if (!e) {
        rc = run_serial(&run, &v, sink, r);
    } else {
        rc = run_engine(e, &run, &v, sink, overlap ? &topo : NULL, r);
        r->t_job = clock_now() - t0; /* the release below is the engine's */
        engine_release(e); /* the job's pages go back, its result's too */
    }
    csg_tree_free(dist_tree);
    return rc;
}

int pipeline_run(engine *e, const pipeline_job *job, vod_sink *sink,
                 pipeline_report *r)
{
    double t0 = clock_now();
    int rc = pipeline_stages(e, job, sink, t0, r);
    if (!r->t_job) r->t_job = clock_now() - t0;
    return rc;
}
