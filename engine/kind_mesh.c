/* The mesh kind's master side: a triangle mesh voxelized tile by tile
 * (mesh_vox.h) into a brick-sparse volume in the segment.  Setup bins the
 * triangles to the tiles (here, once), copies the vertices, triangles and
 * bins into the data area behind the block, gives the rest of the data
 * area to the volume, and pushes one task per tile that has triangles
 * (a tile without any stays empty), lightest first so that the work
 * stack hands out the heaviest first.  Workers send no entries: a tile's
 * bricks go straight into the volume and its counts into its entry of
 * the stats array.  The volume is checked before anyone reads it. */
#include <errno.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "clock.h"
#include "kind_mesh.h"
#include "master.h"
#include "par.h"
#include "prefault.h"
#include "voxel.h"


typedef struct {
    const engine_mesh_job *job;
    engine_result *r;
    engine_mesh_figures fig; /* the job's own, for job->figures */
    uint32_t ntiles;       /* tiles with triangles: tasks */
    uint32_t done;         /* tasks finished */
} mesh_job;

/* Where the mesh goes behind the block; the end of its triangles.  (The
 * tiles snap the vertices themselves: a lattice snapped here, serially,
 * into fresh pages of the segment cost the job more than it saved the
 * workers.) */
static uint64_t place_mesh(engine *e, const mesh *m, mesh_block *b)
{
    b->vertices_off = engine_sched_align64(e->h->data_off + sizeof *b);
    b->triangles_off = engine_sched_align64(b->vertices_off + (uint64_t)m->n_vertices * 12);
    return b->triangles_off + (uint64_t)m->n_triangles * 12;
}

/* The mesh's vertices and triangles into the segment while the triangles
 * are binned, on as many threads as the binning's (the copy's time is the
 * first touch of the segment's pages): on one thread beside the binning,
 * the copy outlasted it on 16 cores and ran alone. */
static void *copy_mesh(void *spans)
{
    prefault_copy_par(spans, 2, par_cpus());
    return NULL;
}

/* Copy the bins behind the mesh (which copy_mesh put behind the block);
 * the volume's offset (the rest of the data area) in *vol_off. */
static int copy_bins(engine *e, const mesh *m, const mesh_bins *bins,
                     mesh_block *b, uint64_t *vol_off)
{
    uint64_t n = (uint64_t)bins->tiles[0] * bins->tiles[1];
    uint64_t end = e->h->data_off + e->h->data_bytes;
    b->start_off = engine_sched_align64(place_mesh(e, m, b));
    b->ids_off = engine_sched_align64(b->start_off + (n + 1) * sizeof(uint64_t));
    b->stats_off = engine_sched_align64(b->ids_off + bins->start[n] * sizeof(uint32_t));
    *vol_off = engine_sched_align64(b->stats_off + n * sizeof(mesh_tile_stats));
    if (*vol_off >= end) return engine_sched_no_room(e, "the mesh");
    prefault_span copies[] = {
        {shm_at(e->seg.base, b->start_off), bins->start, (n + 1) * sizeof(uint64_t)},
        {shm_at(e->seg.base, b->ids_off), bins->ids, bins->start[n] * sizeof(uint32_t)}};
    prefault_copy_par(copies, 2, par_cpus());
    memset(shm_at(e->seg.base, b->stats_off), 0, n * sizeof(mesh_tile_stats));
    return 0;
}

static int by_triangles(const void *pa, const void *pb, void *ud)
{
    const uint64_t *start = ud;
    uint32_t a = *(const uint32_t *)pa, b = *(const uint32_t *)pb;
    uint64_t na = start[a + 1] - start[a], nb = start[b + 1] - start[b];
    return na != nb ? (na < nb ? -1 : 1) : (a < b ? -1 : a > b);
}

/* 1 when tile t is one the job runs (engine_mesh_job.tiles). */
static int tile_wanted(const engine_mesh_job *j, const mesh_bins *bins, uint32_t t)
{
    if (!j->tiles) return 1;
    uint32_t tx = t % bins->tiles[0], ty = t / bins->tiles[0];
    return tx >= j->tiles[0] && tx < j->tiles[2] && ty >= j->tiles[1] && ty < j->tiles[3];
}

/* One task per tile with triangles (every tile where mesh_vox_every_tile),
 * the lightest pushed first. */
static int push_tiles(engine *e, mesh_job *mj, const mesh_bins *bins)
{
    uint32_t n = bins->tiles[0] * bins->tiles[1], k = 0;
    /* a distance tile without triangles still writes its +w bricks, and a
     * capped winding tile may hold inside samples */
    bool every = mesh_vox_every_tile(&mj->job->grid, &mj->job->opts);
    uint32_t *order = malloc((n ? n : 1) * sizeof *order);
    if (!order) return engine_sched_fail(e, ENGINE_FAULT, -ENOMEM, "out of memory");
    for (uint32_t t = 0; t < n; t++)
        if ((bins->start[t + 1] > bins->start[t] || every) && tile_wanted(mj->job, bins, t))
            order[k++] = t;
    qsort_r(order, k, sizeof *order, by_triangles, bins->start);
    int rc = 0;
    for (uint32_t i = 0; i < k && !rc; i++) {
        shm_task t = {.kind = SHM_KIND_MESH, .op = MESH_TILES};
        mesh_task_arg a = {order[i], 1};
        memcpy(t.arg, &a, sizeof a);
        rc = engine_sched_push(e, &t);
    }
    mj->ntiles = k;
    free(order);
    return rc;
}

static int init_volume(engine *e, const mesh_vox_opts *o, const grid_spec *g,
                       uint64_t off)
{
    uint64_t bytes = e->h->data_off + e->h->data_bytes - off;
    int rc = vod_volume_init(&e->volume, shm_at(e->seg.base, off), bytes, g->res,
                             mesh_vox_bits(o), mesh_vox_sbrick(o));
    if (rc) return engine_sched_no_room(e, "the volume's tables");
    e->volume_bytes = bytes;
    return 0;
}

/* The low mip levels the tiles build: those whose bricks lie in one tile's
 * column (a level-l brick spans sbrick << l voxels), of the
 * VOD's channel when the volume gives it (else none: the writer says
 * what is wrong with the channel). */
static void plan_mips(engine *e, int channel, mesh_block *b)
{
    vod_volume_info in;
    vod_volume_get_info(e->volume, &in);
    vod_source src = vod_volume_source(e->volume);
    b->mip_channel = 0;
    b->mip_levels = 0;
    if (channel < 1 || channel > 31 || !(src.channels >> channel & 1u)) return;
    while ((int)b->mip_levels < in.depth &&
           (in.sbrick << (b->mip_levels + 1)) <= MESH_TILE)
        b->mip_levels++;
    if (b->mip_levels) b->mip_channel = channel;
}

static int mesh_setup(engine *e, void *job)
{
    mesh_job *mj = job;
    const engine_mesh_job *j = mj->job;
    err_info msg = {0};
    e->result = RESULT_NONE;
    engine_sched_hold(e, 0); /* the last job's result: overwritten now */
    if (!j->mesh || !j->mesh->n_triangles || grid_check(&j->grid))
        return engine_sched_fail(e, ENGINE_BAD_JOB, -EINVAL, "the mesh job is invalid");
    if (mesh_vox_check(&j->opts, &msg))
        return engine_sched_fail(e, ENGINE_BAD_JOB, -EINVAL, "%s", msg.msg);
    mesh_block *b = shm_at(e->seg.base, e->h->data_off);
    memset(b, 0, sizeof *b);
    if (place_mesh(e, j->mesh, b) > e->h->data_off + e->h->data_bytes)
        return engine_sched_no_room(e, "the mesh");
    prefault_span copy[] = {
        {shm_at(e->seg.base, b->vertices_off), j->mesh->vertices, (size_t)j->mesh->n_vertices * 12},
        {shm_at(e->seg.base, b->triangles_off), j->mesh->triangles,
         (size_t)j->mesh->n_triangles * 12}};
    par_task copying;
    par_start(&copying, copy_mesh, copy);
    double t0 = clock_now();
    mesh_bins bins;
    int rc = mesh_bin(j->mesh, &j->grid, &j->opts, NULL, par_cpus(), &bins);
    mj->fig.t_bin = clock_now() - t0;
    par_join(&copying);
    if (rc) return engine_sched_fail(e, rc == -E2BIG ? ENGINE_LIMIT : ENGINE_FAULT, rc,
                              "binning the triangles to tiles: %s", strerror(-rc));
    b->grid = j->grid;
    b->opts = j->opts;
    b->n_vertices = j->mesh->n_vertices;
    b->n_triangles = j->mesh->n_triangles;
    memcpy(b->lo, j->mesh->lo, sizeof b->lo);
    memcpy(b->hi, j->mesh->hi, sizeof b->hi);
    memcpy(b->tiles, bins.tiles, sizeof b->tiles);
    e->h->job_off = e->h->data_off;
    e->h->job_bytes = sizeof *b;
    uint64_t vol_off;
    rc = copy_bins(e, j->mesh, &bins, b, &vol_off);
    if (!rc) rc = init_volume(e, &j->opts, &j->grid, vol_off);
    if (!rc) {
        b->volume_off = vol_off;
        plan_mips(e, j->mip_channel, b);
        rc = push_tiles(e, mj, &bins);
    }
    mesh_bins_free(&bins);
    return rc;
}

static int mesh_take(engine *e, int i, const shm_entry *en)
{
    return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                      "worker %d sent an entry of type %u in a mesh tile", i,
                      en->type);
}

static void mesh_describe(const shm_task *t, char *buf, size_t len)
{
    mesh_task_arg a = mesh_task_tiles(t);
    snprintf(buf, len, "mesh tile %u", a.first);
}

static void mesh_done(engine *e, int i, const shm_task *t, int error)
{
    mesh_job *mj = e->job;
    mj->done++;
    if (!error || e->err.kind) return;
    char what[64];
    mesh_describe(t, what, sizeof what);
    if (error == -ENOMEM && engine_volume_full(e))
        engine_sched_no_room(e, "the volume");
    else
        engine_sched_fail(e, ENGINE_FAULT, error, "worker %d failed on %s: %s", i, what,
                   strerror(-error));
}

static int mesh_rerun(engine *e, int i, const shm_task *t)
{
    (void)e, (void)i, (void)t;
    return 1; /* a tile writes the same bricks again */
}

static void mesh_progress(engine *e, engine_progress *p)
{
    const mesh_job *mj = e->job;
    p->fraction = mj->ntiles ? (double)mj->done / mj->ntiles : 1.0;
    p->level = 0;
    if (e->volume) { /* the pool grows as the workers write */
        vod_volume_info in;
        vod_volume_get_info(e->volume, &in);
        const mesh_block *b = engine_sched_block(e);
        p->shm_used = b->volume_off - e->h->data_off + in.bytes_used;
    }
}

/* The tiles' counts, and the volume checked before the writer reads it. */
static int collect(engine *e, mesh_job *mj)
{
    const mesh_block *b = engine_sched_block(e);
    engine_result *r = mj->r;
    const mesh_tile_stats *st = shm_at(e->seg.base, b->stats_off);
    for (uint64_t t = 0; t < (uint64_t)b->tiles[0] * b->tiles[1]; t++) {
        r->voxels += st[t].voxels;
        mj->fig.disagreements += st[t].disagreements;
        mj->fig.disagree_bricks += st[t].disagree_bricks;
    }
    vod_volume_info in;
    int bad = vod_volume_check(e->volume, e->volume_bytes);
    if (!bad) {
        vod_volume_get_info(e->volume, &in);
        bad = memcmp(in.dims, mj->job->grid.res, sizeof in.dims) ||
              in.bits != mesh_vox_bits(&mj->job->opts);
    }
    if (!bad && b->mip_levels) /* every tile built its column's */
        bad = vod_volume_mips_low(e->volume, b->mip_channel, (int)b->mip_levels);
    if (bad)
        return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                          "the workers left the volume inconsistent");
    /* the volume stays for the encode kind */
    engine_sched_hold(e, b->volume_off - e->h->data_off + in.bytes_used);
    return 0;
}

static int mesh_finish(engine *e, void *job, int rc)
{
    mesh_job *mj = job;
    engine_result *r = mj->r;
    engine_sched_job_totals(e, r);
    r->octants = 0;
    r->tasks = mj->fig.tiles = mj->ntiles;
    if (!rc) rc = collect(e, mj);
    r->seconds = clock_now() - e->t0;
    if (rc) return engine_sched_job_failed(e, r, rc);
    e->result = RESULT_VOLUME;
    return 0;
}

/* ---- the pipeline's side (master.h) ---- */

/* A mesh job's domain: its bounding box grown by pad voxels each side,
 * the voxel size such that res voxels span the longest side of that. */
static int mesh_fit(const engine_pipeline_job *job, double lo[3], double hi[3],
                    engine_pipeline_report *r)
{
    const mesh *m = job->mesh.mesh;
    double ext = 0;
    for (int a = 0; a < 3; a++)
        if ((double)m->hi[a] - m->lo[a] > ext) ext = (double)m->hi[a] - m->lo[a];
    if (!(ext > 0))
        return engine_pipeline_fail(r, ENGINE_BAD_JOB, -EINVAL, "the mesh has an empty bounding box");
    if ((uint64_t)job->mesh.pad * 2 >= job->res)
        return engine_pipeline_fail(r, ENGINE_BAD_JOB, -EINVAL,
                             "a padding of %u voxels leaves no room in %u voxels",
                             job->mesh.pad, job->res);
    double vs = ext / (double)(job->res - 2 * job->mesh.pad);
    for (int a = 0; a < 3; a++) {
        lo[a] = m->lo[a] - job->mesh.pad * vs;
        hi[a] = m->hi[a] + job->mesh.pad * vs;
    }
    return 0;
}

/* The job's checks, and its domain when it fits the mesh. */
static int mesh_domain(const engine_pipeline_job *job, double lo[3], double hi[3],
                       engine_pipeline_report *r)
{
    if (!job->mesh.mesh || !job->mesh.mesh->n_triangles)
        return engine_pipeline_fail(r, ENGINE_BAD_JOB, -EINVAL, "the job has no expression or mesh");
    err_info err = {0};
    if (mesh_vox_check(&job->mesh.opts, &err))
        return engine_pipeline_fail(r, ENGINE_BAD_JOB, -EINVAL, "%s", err.msg);
    r->fig.mesh.triangles = job->mesh.mesh->n_triangles;
    return job->mesh.fit ? mesh_fit(job, lo, hi, r) : 0;
}

static void mesh_meta(const engine_pipeline_job *job, job_meta *m, char *pairs, size_t len)
{
    static const char *const modes[] = {"solid", "surface", "surface6",
                                        "conservative", "interior"};
    static const char *const repairs[] = {"none", "vote", "winding"};
    int n = snprintf(pairs, len, "mesh_triangles=%u\nmesh_mode=%s\nmesh_repair=%s\n",
                     job->mesh.mesh->n_triangles, modes[job->mesh.opts.mode],
                     repairs[job->mesh.opts.repair]);
    /* the distance's band (voxels) and units: what readers of a level set
     * (the .vdb's background) need */
    if (job->mesh.opts.channel == VOXEL_CH_DISTANCE && n > 0 && (size_t)n < len)
        snprintf(pairs + n, len - (size_t)n, "distance_band=%u\ndistance_units=world\n",
                 mesh_vox_band(&job->mesh.opts));
    m->source = "";
    m->source_len = job->mesh.source_bytes;
    m->source_name = job->mesh.source_name;
    m->kind_pairs = pairs;
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

/* mesh_edges' failure rc, as the job's (before any voxel). */
static int topo_error(engine_pipeline_report *r, int rc)
{
    r->stage = ENGINE_PIPELINE_GRID;
    return engine_pipeline_fail(r, rc == -E2BIG ? ENGINE_LIMIT : ENGINE_FAULT, rc,
                         "the mesh's edges: %s", strerror(-rc));
}

/* Wait for t and put its result in r: 0, or the error mesh_check gives. */
static int topo_join(topo_job *t, engine_pipeline_report *r)
{
    par_join(&t->task);
    r->fig.mesh.topo = t->topo;
    r->fig.mesh.t_topology = t->seconds;
    return t->rc ? topo_error(r, t->rc) : 0;
}

/* A mesh job's topology into r; the repair dropped from *run when the
 * mesh is watertight. */
static int mesh_check(engine_pipeline_job *run, engine_pipeline_report *r)
{
    double t0 = clock_now();
    int rc = mesh_edges(run->mesh.mesh, &r->fig.mesh.topo);
    r->fig.mesh.t_topology = clock_now() - t0;
    if (rc) return topo_error(r, rc);
    if (r->fig.mesh.topo.watertight && run->mesh.opts.repair != MESH_REPAIR_NONE) {
        run->mesh.opts.repair = MESH_REPAIR_NONE;
        r->fig.mesh.repair_skipped = 1;
    }
    return 0;
}

/* A mesh job in this thread: every tile in turn (mesh_voxelize) into a
 * volume in a sparse private mapping, touched only as bricks are made. */
static int run_serial_mesh(const engine_pipeline_job *job, const vod_params *v,
                           vod_sink *sink, engine_pipeline_report *r)
{
    const mesh_vox_opts *o = &job->mesh.opts;
    r->stage = ENGINE_PIPELINE_VOXELIZE;
    size_t bytes = vod_volume_bytes(r->grid.res, mesh_vox_bits(o), mesh_vox_sbrick(o),
                                    UINT64_MAX);
    void *arena = bytes ? mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                               MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0)
                        : MAP_FAILED;
    if (arena == MAP_FAILED)
        return engine_pipeline_fail(r, ENGINE_LIMIT, -ENOMEM, "cannot map a volume of %ux%ux%u",
                             r->grid.res[0], r->grid.res[1], r->grid.res[2]);
    vod_volume *vol;
    int rc = vod_volume_init(&vol, arena, bytes, r->grid.res, mesh_vox_bits(o),
                             mesh_vox_sbrick(o));
    mesh_tile_stats st = {0};
    double t0 = clock_now();
    if (!rc) rc = mesh_voxelize(job->mesh.mesh, &r->grid, o, vol, &st);
    r->t_voxelize = clock_now() - t0;
    r->voxels = st.voxels;
    r->fig.mesh.vox.disagreements = st.disagreements;
    r->fig.mesh.vox.disagree_bricks = st.disagree_bricks;
    if (rc) {
        engine_pipeline_fail(r, rc == -ENOMEM ? ENGINE_LIMIT : ENGINE_FAULT, rc,
                      "voxelizing the mesh: %s", strerror(-rc));
    } else {
        vod_source src = vod_volume_source(vol);
        rc = engine_pipeline_write_serial(NULL, &src, v, sink, r);
    }
    munmap(arena, bytes);
    return rc;
}

static int mesh_serial(engine_pipeline_job *run, const vod_params *v, vod_sink *sink,
                       engine_pipeline_report *r)
{
    int rc = mesh_check(run, r);
    return rc ? rc : run_serial_mesh(run, v, sink, r);
}

/* Without a repair the topology decides nothing before the write: on an
 * engine it is found while the triangles are voxelized. */
static int mesh_voxelize_stage(engine *e, engine_pipeline_job *run, const engine_sched_watch *w,
                               engine_result *er, engine_pipeline_report *r)
{
    topo_job topo = {.m = run->mesh.mesh};
    bool overlap = run->mesh.opts.repair == MESH_REPAIR_NONE;
    if (overlap) par_start(&topo.task, topo_run, &topo);
    else {
        int rc = mesh_check(run, r);
        if (rc) return rc;
    }
    engine_mesh_job mj = {.mesh = run->mesh.mesh, .grid = r->grid, .opts = run->mesh.opts,
                          .mip_channel = run->vod.channel, .progress = w->progress,
                          .ud = w->ud, .cancel = w->cancel, .figures = &r->fig.mesh.vox};
    int rc = engine_mesh(e, &mj, er);
    int trc = overlap ? topo_join(&topo, r) : 0;
    return trc ? trc : rc;
}

/* What vox says of a mesh job that ran. */
static void mesh_summary(const engine_pipeline_job *job, const engine_pipeline_report *r,
                                 char *buf, size_t len)
{
    const engine_mesh_report *f = &r->fig.mesh;
    FILE *out = fmemopen(buf, len, "w");
    if (!out) return;
    fprintf(out, "  mesh: %u triangles, %llu open and %llu non-manifold edges: %s (%.3f s)",
            f->triangles, (unsigned long long)f->topo.open,
            (unsigned long long)f->topo.nonmanifold,
            f->topo.watertight ? "watertight" : "not watertight", f->t_topology);
    if (r->workers > 0)
        fprintf(out, "; %u tile%s with triangles, binned in %.3f s", f->vox.tiles,
                f->vox.tiles == 1 ? "" : "s", f->vox.t_bin);
    fprintf(out, "; job %.3f s\n", r->t_job);
    if (f->repair_skipped)
        fprintf(out, "  repair: not needed, the mesh is watertight (its parities agree)\n");
    else if (job->mesh.opts.repair != MESH_REPAIR_NONE)
        fprintf(out, "  repair: %llu voxels where the parities along x, y, z disagree, in %llu "
                "storage bricks\n", (unsigned long long)f->vox.disagreements,
                (unsigned long long)f->vox.disagree_bricks);
    fclose(out);
}

const engine_kind engine_kind_mesh = {
    .name = "mesh",
    .id = SHM_KIND_MESH,
    .setup = mesh_setup,
    .take = mesh_take,
    .done = mesh_done,
    .rerun = mesh_rerun,
    .describe = mesh_describe,
    .progress = mesh_progress,
    .finish = mesh_finish,
    .domain = mesh_domain,
    .meta = mesh_meta,
    .serial = mesh_serial,
    .voxelize = mesh_voxelize_stage,
    .summary = mesh_summary,
};

int engine_mesh(engine *e, const engine_mesh_job *job, engine_result *r)
{
    mesh_job mj = {.job = job, .r = r};
    engine_sched_watch w = {.progress = job->progress, .ud = job->ud, .cancel = job->cancel};
    int rc = engine_sched_run_job(e, &engine_kind_mesh, &mj, &w, r);
    if (job->figures) *job->figures = mj.fig;
    return rc;
}
