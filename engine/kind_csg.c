/* The csg kind's master side: a volume CSG tree (csg.h) evaluated brick by
 * brick into a brick-sparse volume in the segment.  Setup copies the
 * tree's nodes and text behind the block; then the file leaves' volumes
 * follow, one leaf after the other: a mesh leaf's by the workers, tile by
 * tile (its mesh parsed, placed and binned here, copied into the segment
 * as a mesh job's block, CSG_LEAF_TILES tasks building its volume with
 * mesh_tile_run, the same volume csg_leaf_build makes), a VOD leaf's here
 * (csg_leaf_build, on as many of this process's threads as it has
 * workers).  Once the last is in, the rest of the data area goes
 * to the result's volume, and the volume's storage bricks are pushed as runs of
 * consecutive bricks (x fastest), at most CSG_TASKS of them.  Workers send
 * no entries: a brick goes straight into the volume (uniform ones as a
 * table entry) and a run's counts into its entry of the stats array.  When
 * the last run is in, runs of brick columns follow, each building its
 * columns' low mip levels (what the writer's prepare() built here, on one
 * core, after the bricks).  A worker's death re-runs its run (the bricks
 * are a pure function of the tree: the same bytes again).  The volume is
 * checked before anyone reads it; the encode kind writes it. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "clock.h"
#include "csg.h"
#include "kind_csg.h"
#include "master.h"
#include "par.h"
#include "prefault.h"
#include "voxel.h"

_Static_assert(CSG_BLOCK_NODES == CSG_MAX_NODES, "a leaf offset per node");

/* Runs of bricks: enough for the workers to share the load and the
 * progress to move, few enough for the work stack (4096 + tasks). */
#define CSG_TASKS 2048u

typedef struct {
    const engine_csg_job *job;
    engine_result *r;
    engine_csg_figures fig; /* the job's own, for job->figures */
    uint32_t ntasks;       /* runs of bricks */
    uint32_t done;         /* runs finished */
    int mips_pushed;       /* the CSG_MIPS tasks are out */
    uint32_t per;          /* bricks a run */
    /* the file leaves, before the bricks: the next node to look at, the
     * mesh leaf whose tiles are out (-1: none) and its tasks */
    uint32_t next_leaf;
    int32_t leaf;
    uint32_t leaf_tasks, leaf_done;
    uint64_t off;          /* where the next leaf's data (then the volume) go */
} csg_job;

/* Mip columns a worker's share at least: enough to even out the load. */
#define CSG_MIP_COLUMNS_PER_WORKER 4u

/* The tree and the stats behind the block, the volume in the rest. */
static int copy_input(engine *e, const csg_tree *t, csg_block *b, uint64_t *vol_off)
{
    uint64_t end = e->h->data_off + e->h->data_bytes;
    b->n_nodes = t->n;
    b->node_bytes = sizeof(csg_node);
    b->nodes_off = engine_sched_align64(e->h->data_off + sizeof *b);
    b->text_off = engine_sched_align64(b->nodes_off + (uint64_t)t->n * sizeof(csg_node));
    b->text_len = t->text_len;
    b->stats_off = engine_sched_align64(b->text_off + t->text_len + 1);
    *vol_off = engine_sched_align64(b->stats_off + (uint64_t)b->ntasks * sizeof(csg_task_stats));
    if (*vol_off >= end) return engine_sched_no_room(e, "the tree");
    memcpy(shm_at(e->seg.base, b->nodes_off), t->node, t->n * sizeof(csg_node));
    char *text = shm_at(e->seg.base, b->text_off);
    if (t->text_len) memcpy(text, t->text, t->text_len);
    text[t->text_len] = 0;
    memset(shm_at(e->seg.base, b->stats_off), 0, b->ntasks * sizeof(csg_task_stats));
    return 0;
}

static int init_volume(engine *e, const grid_spec *g, int channel, uint64_t off)
{
    uint64_t bytes = e->h->data_off + e->h->data_bytes - off;
    int rc = vod_volume_init(&e->volume, shm_at(e->seg.base, off), bytes, g->res,
                             csg_channel_bits(channel), CSG_VOLUME_BRICK);
    if (rc) return engine_sched_no_room(e, "the volume's tables");
    e->volume_bytes = bytes;
    return 0;
}

/* The runs, the last pushed first: the stack hands out brick 0's first. */
static int push_runs(engine *e, const csg_block *b, uint32_t per)
{
    uint64_t n = (uint64_t)b->box_n[0] * b->box_n[1] * b->box_n[2];
    int rc = 0;
    for (uint32_t k = b->ntasks; k-- > 0 && !rc;) {
        uint64_t first = (uint64_t)k * per;
        csg_task_arg a = {(uint32_t)first, (uint32_t)(n - first < per ? n - first : per), k};
        shm_task t = {.kind = SHM_KIND_CSG, .op = CSG_BRICKS};
        memcpy(t.arg, &a, sizeof a);
        rc = engine_sched_push(e, &t);
    }
    return rc;
}

/* The bricks to evaluate: the whole volume, or those of the job's root
 * octant (its cube brick-aligned, or the whole grid's). */
static int set_box(const engine_csg_job *j, csg_block *b)
{
    const grid_octant *o = j->root;
    for (int a = 0; a < 3; a++) {
        b->box_lo[a] = 0;
        b->box_n[a] = b->nbricks[a];
    }
    if (!o) return 0;
    uint32_t side = 1u << o->level, at[3] = {o->x, o->y, o->z};
    if (o->level > j->grid.depth || (side % CSG_VOLUME_BRICK && o->level != j->grid.depth))
        return -EINVAL;
    for (int a = 0; a < 3; a++) {
        if (at[a] % side) return -EINVAL;
        uint32_t lo = at[a] / CSG_VOLUME_BRICK;
        uint32_t hi = (at[a] + side + CSG_VOLUME_BRICK - 1) / CSG_VOLUME_BRICK;
        b->box_lo[a] = lo < b->nbricks[a] ? lo : b->nbricks[a];
        b->box_n[a] = (hi < b->nbricks[a] ? hi : b->nbricks[a]) - b->box_lo[a];
    }
    return 0;
}

/* Level l's brick columns, x and y: g[0] * g[1] of them. */
static void mip_grid(const csg_block *b, uint32_t l, uint32_t g[2])
{
    uint32_t side = b->sbrick << l;
    for (int a = 0; a < 2; a++) g[a] = (b->grid.res[a] + side - 1) / side;
}

/* The mip levels the workers build, by columns, once the bricks are in:
 * the most whose columns still give every worker a few (the levels
 * above, a few bricks, are the writer's); 0 when even level 1 has too
 * few columns (a small volume: the writer builds them all). */
static uint32_t plan_mips(const engine *e, const csg_block *b)
{
    vod_volume_info in;
    vod_volume_get_info(e->volume, &in);
    uint32_t levels = 0, g[2];
    for (uint32_t l = 1; l <= (uint32_t)in.depth && l < 31; l++) {
        mip_grid(b, l, g);
        if ((uint64_t)g[0] * g[1] < (uint64_t)CSG_MIP_COLUMNS_PER_WORKER * (uint32_t)e->n) break;
        levels = l;
    }
    return levels;
}

/* The mip columns in runs, at most CSG_TASKS, the last pushed first. */
static int push_mips(engine *e, const csg_block *b)
{
    uint32_t g[2];
    mip_grid(b, b->mip_levels, g);
    uint64_t n = (uint64_t)g[0] * g[1];
    uint32_t per = (uint32_t)((n + CSG_TASKS - 1) / CSG_TASKS);
    uint32_t runs = (uint32_t)((n + per - 1) / per);
    int rc = 0;
    for (uint32_t k = runs; k-- > 0 && !rc;) {
        uint64_t first = (uint64_t)k * per;
        csg_task_arg a = {(uint32_t)first, (uint32_t)(n - first < per ? n - first : per), 0};
        shm_task t = {.kind = SHM_KIND_CSG, .op = CSG_MIPS};
        memcpy(t.arg, &a, sizeof a);
        rc = engine_sched_push(e, &t);
    }
    return rc;
}

/* ---- the file leaves, one after the other, before the bricks ---- */

/* The bricks: the rest of the data area to the result's volume, its runs
 * pushed. */
static int start_bricks(engine *e, csg_job *cj)
{
    csg_block *b = shm_at(e->seg.base, e->h->data_off);
    const engine_csg_job *j = cj->job;
    if (cj->off >= e->h->data_off + e->h->data_bytes) return engine_sched_no_room(e, "the volume");
    int rc = init_volume(e, &j->grid, j->channel, cj->off);
    if (rc) return rc;
    b->volume_off = cj->off;
    b->mip_levels = plan_mips(e, b);
    return push_runs(e, b, cj->per);
}

/* The mesh leaf's mesh, bins and tile stats into the segment at *off as
 * a mesh job's block (mesh_block), the leaf's volume in the rest; *off
 * moved to the volume. */
static int lay_out_mesh(engine *e, const mesh *m, const mesh_vox_opts *o, const grid_spec *g,
                        const mesh_bins *bins, uint64_t *off)
{
    csg_block *b = shm_at(e->seg.base, e->h->data_off);
    uint64_t n = (uint64_t)bins->tiles[0] * bins->tiles[1], end = e->h->data_off + e->h->data_bytes;
    uint64_t at = engine_sched_align64(*off), v = engine_sched_align64(at + sizeof(mesh_block));
    uint64_t t = engine_sched_align64(v + (uint64_t)m->n_vertices * 12);
    uint64_t st = engine_sched_align64(t + (uint64_t)m->n_triangles * 12);
    uint64_t ids = engine_sched_align64(st + (n + 1) * sizeof(uint64_t));
    uint64_t stats = engine_sched_align64(ids + bins->start[n] * sizeof(uint32_t));
    uint64_t vol = engine_sched_align64(stats + n * sizeof(mesh_tile_stats));
    if (vol >= end) return engine_sched_no_room(e, "a mesh leaf");
    mesh_block *mb = shm_at(e->seg.base, at);
    *mb = (mesh_block){.grid = *g, .opts = *o, .n_vertices = m->n_vertices,
                       .n_triangles = m->n_triangles, .vertices_off = v, .triangles_off = t,
                       .tiles = {bins->tiles[0], bins->tiles[1]}, .start_off = st,
                       .ids_off = ids, .stats_off = stats, .volume_off = vol};
    memcpy(mb->lo, m->lo, sizeof mb->lo);
    memcpy(mb->hi, m->hi, sizeof mb->hi);
    prefault_span c[] = {
        {shm_at(e->seg.base, v), m->vertices, (size_t)m->n_vertices * 12},
        {shm_at(e->seg.base, t), m->triangles, (size_t)m->n_triangles * 12},
        {shm_at(e->seg.base, st), bins->start, (n + 1) * sizeof(uint64_t)},
        {shm_at(e->seg.base, ids), bins->ids, bins->start[n] * sizeof(uint32_t)}};
    prefault_copy_par(c, 4, par_cpus()); /* a serial span of 15 ms on one thread */
    vod_volume *lv;
    if (vod_volume_init(&lv, shm_at(e->seg.base, vol), end - vol, g->res, mesh_vox_bits(o),
                        CSG_VOLUME_BRICK))
        return engine_sched_no_room(e, "a mesh leaf's tables");
    b->leaf_mesh_off = at;
    *off = vol;
    return 0;
}

/* The tiles of the mesh leaf in runs (every tile for a distance, whose
 * empty tiles write their +w bricks; else those with triangles), at most
 * CSG_TASKS, tile 0's first out; the count in cj->leaf_tasks. */
static int push_leaf_tiles(engine *e, csg_job *cj, const mesh_bins *bins, int dist)
{
    uint32_t n = bins->tiles[0] * bins->tiles[1], first = 0, last = 0;
    while (first < n && !dist && bins->start[first + 1] == bins->start[first]) first++;
    for (uint32_t k = 0; k < n; k++)
        if (dist || bins->start[k + 1] > bins->start[k]) last = k + 1;
    uint32_t span = last > first ? last - first : 0, per = (span + CSG_TASKS - 1) / CSG_TASKS;
    uint32_t runs = per ? (span + per - 1) / per : 0;
    int rc = 0;
    cj->leaf_tasks = runs;
    cj->leaf_done = 0;
    for (uint32_t k = runs; k-- > 0 && !rc;) {
        uint32_t a0 = first + k * per;
        csg_task_arg a = {a0, last - a0 < per ? last - a0 : per, (uint32_t)cj->leaf};
        shm_task t = {.kind = SHM_KIND_CSG, .op = CSG_LEAF_TILES};
        memcpy(t.arg, &a, sizeof a);
        rc = engine_sched_push(e, &t);
    }
    return rc;
}

/* Mesh leaf i: parsed, placed and binned here, laid out in the segment,
 * its tiles pushed (none: cj->leaf_tasks 0). */
static int start_mesh_leaf(engine *e, csg_job *cj, uint32_t i)
{
    csg_block *b = shm_at(e->seg.base, e->h->data_off);
    const engine_csg_job *j = cj->job;
    err_info le = {0};
    mesh m;
    mesh_vox_opts o;
    int rc = csg_leaf_mesh(j->tree, i, &m, &o, &le);
    if (rc) return engine_sched_fail(e, ENGINE_BAD_JOB, rc, "%s", le.msg);
    mesh_bins bins;
    rc = mesh_bin(&m, &j->grid, &o, NULL, par_cpus(), &bins);
    if (rc) {
        mesh_free(&m);
        return engine_sched_fail(e, rc == -E2BIG ? ENGINE_LIMIT : ENGINE_FAULT, rc,
                          "node '%s': binning the triangles to tiles: %s",
                          j->tree->node[i].name, strerror(-rc));
    }
    rc = lay_out_mesh(e, &m, &o, &j->grid, &bins, &cj->off);
    if (!rc) {
        b->leaf_off[i] = cj->off;
        cj->leaf = (int32_t)i;
        rc = push_leaf_tiles(e, cj, &bins, o.channel == VOXEL_CH_DISTANCE);
    }
    mesh_bins_free(&bins);
    mesh_free(&m);
    return rc;
}

/* The mesh leaf's tiles are all in: its volume checked, the next data
 * after it. */
static int end_mesh_leaf(engine *e, csg_job *cj)
{
    uint64_t end = e->h->data_off + e->h->data_bytes;
    vod_volume *lv = shm_at(e->seg.base, cj->off);
    vod_volume_info in;
    if (vod_volume_check(lv, end - cj->off))
        return engine_sched_fail(e, ENGINE_FAULT, -EPROTO, "the workers left a mesh leaf inconsistent");
    vod_volume_get_info(lv, &in);
    cj->off = engine_sched_align64(cj->off + in.bytes_used);
    cj->leaf = -1;
    return 0;
}

/* A VOD leaf's volume, here (csg_leaf_build), at cj->off. */
static int vod_leaf(engine *e, csg_job *cj, uint32_t i)
{
    csg_block *b = shm_at(e->seg.base, e->h->data_off);
    const engine_csg_job *j = cj->job;
    uint64_t end = e->h->data_off + e->h->data_bytes;
    err_info le = {0};
    vod_volume *lv;
    if (cj->off >= end || vod_volume_init(&lv, shm_at(e->seg.base, cj->off), end - cj->off,
                                          j->grid.res, 8, CSG_VOLUME_BRICK))
        return engine_sched_no_room(e, "the leaves' volumes");
    int rc = csg_leaf_build(j->tree, i, &j->grid, lv, (unsigned)e->n, &le); /* workers idle */
    vod_volume_info in;
    vod_volume_get_info(lv, &in);
    /* -ENOMEM is the segment's only when the volume's pool ran out; else
     * the heap's (the file's read, a thread's brick buffer) */
    if (rc == -ENOMEM && in.pool_full) return engine_sched_no_room(e, "the leaves' volumes");
    if (rc)
        return engine_sched_fail(e, rc == -ENOMEM ? ENGINE_LIMIT : ENGINE_BAD_JOB, rc, "%s",
                                 le.msg);
    b->leaf_off[i] = cj->off;
    cj->off = engine_sched_align64(cj->off + in.bytes_used);
    return 0;
}

/* What comes next: the next file leaf (a mesh leaf's tiles pushed: the
 * workers' turn), or, after the last, the bricks. */
static int next_phase(engine *e, csg_job *cj)
{
    const csg_tree *t = cj->job->tree;
    int rc = 0;
    while (!rc && cj->next_leaf < t->n) {
        uint32_t i = cj->next_leaf++;
        if (t->node[i].kind == CSG_VOD) rc = vod_leaf(e, cj, i);
        if (t->node[i].kind != CSG_MESH) continue;
        if (!(rc = start_mesh_leaf(e, cj, i)) && cj->leaf_tasks) return 0;
        if (!rc) rc = end_mesh_leaf(e, cj); /* no tile to build */
    }
    return rc ? rc : start_bricks(e, cj);
}

static int csg_setup(engine *e, void *job)
{
    csg_job *cj = job;
    const engine_csg_job *j = cj->job;
    e->result = RESULT_NONE;
    engine_sched_hold(e, 0); /* the last job's result: overwritten now */
    if (!j->tree || !j->tree->n || j->tree->n > CSG_MAX_NODES || grid_check(&j->grid) ||
        !csg_channel_bits(j->channel))
        return engine_sched_fail(e, ENGINE_BAD_JOB, -EINVAL, "the csg job is invalid");
    csg_block *b = shm_at(e->seg.base, e->h->data_off);
    memset(b, 0, sizeof *b);
    b->grid = j->grid;
    b->channel = (uint32_t)j->channel;
    b->sbrick = CSG_VOLUME_BRICK;
    for (int a = 0; a < 3; a++)
        b->nbricks[a] = (j->grid.res[a] + CSG_VOLUME_BRICK - 1) / CSG_VOLUME_BRICK;
    if (set_box(j, b)) return engine_sched_fail(e, ENGINE_BAD_JOB, -EINVAL, "the csg job is invalid");
    uint64_t n = (uint64_t)b->box_n[0] * b->box_n[1] * b->box_n[2];
    uint32_t per = n ? (uint32_t)((n + CSG_TASKS - 1) / CSG_TASKS) : 1;
    b->ntasks = cj->ntasks = (uint32_t)((n + per - 1) / per);
    e->h->job_off = e->h->data_off;
    e->h->job_bytes = sizeof *b;
    cj->per = per;
    cj->leaf = -1;
    int rc = copy_input(e, j->tree, b, &cj->off);
    return rc ? rc : next_phase(e, cj);
}

static int csg_take(engine *e, int i, const shm_entry *en)
{
    return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                      "worker %d sent an entry of type %u in a csg brick run", i, en->type);
}

static void csg_describe(const shm_task *t, char *buf, size_t len)
{
    csg_task_arg a = csg_task_bricks(t);
    if (t->op == CSG_LEAF_TILES)
        snprintf(buf, len, "csg mesh leaf %u tiles %u..%u", a.task, a.first,
                 a.first + a.count - 1);
    else
        snprintf(buf, len, "csg %s %u..%u", t->op == CSG_MIPS ? "mip columns" : "bricks",
                 a.first, a.first + a.count - 1);
}

static void csg_done(engine *e, int i, const shm_task *t, int error)
{
    csg_job *cj = e->job;
    const csg_block *b = engine_sched_block(e);
    if (t->op == CSG_BRICKS) cj->done++;
    /* the mesh leaf's last tile in: the next leaf, or the bricks */
    if (t->op == CSG_LEAF_TILES && ++cj->leaf_done == cj->leaf_tasks && !error &&
        !e->err.kind && !end_mesh_leaf(e, cj))
        next_phase(e, cj); /* a failure fails the job there */
    /* the last brick in: the workers build the low mip levels */
    if (!error && !e->err.kind && cj->done == cj->ntasks && !cj->mips_pushed &&
        b->mip_levels) {
        cj->mips_pushed = 1;
        push_mips(e, b); /* a full stack fails the job there */
    }
    if (!error || e->err.kind) return;
    char what[64];
    csg_describe(t, what, sizeof what);
    if (error == -ENOMEM && engine_volume_full(e))
        engine_sched_no_room(e, "the volume");
    else
        engine_sched_fail(e, ENGINE_FAULT, error, "worker %d failed on %s: %s", i, what,
                   strerror(-error));
}

static int csg_rerun(engine *e, int i, const shm_task *t)
{
    (void)e, (void)i, (void)t;
    return 1; /* a run writes the same bricks and counts again */
}

static void csg_progress(engine *e, engine_progress *p)
{
    const csg_job *cj = e->job;
    p->fraction = cj->ntasks ? (double)cj->done / cj->ntasks : 1.0;
    p->level = 0;
    const csg_block *b = engine_sched_block(e);
    if (e->volume && b->volume_off) { /* the pool grows as the workers write */
        vod_volume_info in;
        vod_volume_get_info(e->volume, &in);
        p->shm_used = b->volume_off - e->h->data_off + in.bytes_used;
    }
}

/* The runs' counts, and the volume checked before the writer reads it. */
static int collect(engine *e, csg_job *cj)
{
    const csg_block *b = engine_sched_block(e);
    engine_result *r = cj->r;
    const csg_task_stats *st = shm_at(e->seg.base, b->stats_off);
    for (uint32_t t = 0; t < b->ntasks; t++) {
        cj->fig.bricks += st[t].bricks;
        cj->fig.uniform += st[t].uniform_bricks;
        cj->fig.skipped += st[t].skipped;
        cj->fig.voxel_evals += st[t].voxel_evals;
        r->voxels += st[t].solid_voxels;
    }
    vod_volume_info in;
    int bad = vod_volume_check(e->volume, e->volume_bytes);
    if (!bad) {
        vod_volume_get_info(e->volume, &in);
        bad = memcmp(in.dims, cj->job->grid.res, sizeof in.dims) ||
              in.bits != csg_channel_bits(cj->job->channel);
    }
    if (!bad && cj->mips_pushed) /* every column's built */
        bad = vod_volume_mips_low(e->volume, (int)b->channel, (int)b->mip_levels);
    if (bad)
        return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                          "the workers left the volume inconsistent");
    /* the volume stays for the encode kind */
    engine_sched_hold(e, b->volume_off - e->h->data_off + in.bytes_used);
    return 0;
}

static int csg_finish(engine *e, void *job, int rc)
{
    csg_job *cj = job;
    engine_result *r = cj->r;
    engine_sched_job_totals(e, r);
    r->octants = 0;
    if (!rc) rc = collect(e, cj);
    r->seconds = clock_now() - e->t0;
    if (rc) return engine_sched_job_failed(e, r, rc);
    e->result = RESULT_VOLUME;
    return 0;
}

/* ---- the pipeline's side (master.h) ---- */

static int csg_domain(const engine_pipeline_job *job, double lo[3], double hi[3],
                      engine_pipeline_report *r)
{
    (void)lo, (void)hi; /* the job's own */
    if (!job->csg.tree || !job->csg.tree->n)
        return engine_pipeline_fail(r, ENGINE_BAD_JOB, -EINVAL, "the job has no csg tree");
    if (!csg_channel_bits(job->vod.channel))
        return engine_pipeline_fail(r, ENGINE_BAD_JOB, -EINVAL,
                             "a csg job writes the density, occupancy, surface or distance "
                             "channel");
    if (job->vod.channel != VOXEL_CH_DISTANCE) return 0;
    if (engine_pipeline_band(job) > VOXEL_BAND_MAX)
        return engine_pipeline_fail(r, ENGINE_BAD_JOB, -EINVAL, "a band of %u voxels: at most %u",
                             engine_pipeline_band(job), VOXEL_BAND_MAX);
    err_info why = {0};
    int rc = csg_dist_check(job->csg.tree, &why);
    if (rc)
        return engine_pipeline_fail(r, ENGINE_BAD_JOB, rc, "the distance channel: %s", why.msg);
    return 0;
}

static void csg_meta(const engine_pipeline_job *job, job_meta *m, char *pairs, size_t len)
{
    int n = snprintf(pairs, len, "csg_nodes=%u\n", job->csg.tree->n);
    /* the distance's band and units, as a mesh's or an expression's */
    if (job->vod.channel == VOXEL_CH_DISTANCE && n > 0 && (size_t)n < len)
        snprintf(pairs + n, len - (size_t)n, "distance_band=%u\ndistance_units=world\n",
                 engine_pipeline_band(job));
    m->generator = "vox csg";
    m->source = "";
    m->source_len = job->csg.source_bytes;
    m->source_name = job->csg.source_name;
    m->kind_pairs = pairs;
}

/* Channel 4: job's tree copied (the struct alone, its pointers shared:
 * free() it, not csg_tree_free) with the band in its distance leaves' k
 * (csg_tree_set_band), made the job's; *copy NULL for other channels. */
static int band_tree(engine_pipeline_job *job, csg_tree **copy, engine_pipeline_report *r)
{
    *copy = NULL;
    if (job->vod.channel != VOXEL_CH_DISTANCE) return 0;
    if (!(*copy = malloc(sizeof **copy)))
        return engine_pipeline_fail(r, ENGINE_LIMIT, -ENOMEM, "out of memory");
    **copy = *job->csg.tree;
    csg_tree_set_band(*copy, engine_pipeline_band(job));
    job->csg.tree = *copy;
    return 0;
}

/* The file leaves of a csg job in a sparse private mapping (*arena,
 * *abytes; none: MAP_FAILED), their volumes in leaves. */
static int serial_leaves(const engine_pipeline_job *job, engine_pipeline_report *r, void **arena,
                         size_t *abytes, vod_volume *leaves[CSG_MAX_NODES])
{
    *arena = MAP_FAILED;
    memset(leaves, 0, CSG_MAX_NODES * sizeof *leaves);
    const csg_tree *t = job->csg.tree;
    if (!csg_has_file_leaves(t)) return 0;
    *abytes = 0;
    for (uint32_t i = 0; i < t->n; i++)
        if (t->node[i].kind == CSG_MESH || t->node[i].kind == CSG_VOD) {
            size_t one = vod_volume_bytes(r->grid.res, csg_leaf_bits(&t->node[i]),
                                          CSG_VOLUME_BRICK, UINT64_MAX);
            *abytes = one && *abytes + one > *abytes ? *abytes + one : 0;
            if (!*abytes) break;
        }
    *arena = *abytes ? mmap(NULL, *abytes, PROT_READ | PROT_WRITE,
                        MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0)
                 : MAP_FAILED;
    if (*arena == MAP_FAILED)
        return engine_pipeline_fail(r, ENGINE_LIMIT, -ENOMEM, "cannot map the leaves' volumes");
    err_info le = {0};
    csg_arena a = {.base = *arena, .bytes = *abytes};
    int rc = csg_leaves_build(t, &r->grid, &a, leaves, &le);
    if (rc)
        return engine_pipeline_fail(r, rc == -ENOMEM || rc == -ENOSPC ? ENGINE_LIMIT : ENGINE_BAD_JOB,
                             rc, "%s", le.msg);
    return 0;
}

/* A csg job in this thread: every brick in turn (csg_eval_volume) into a
 * volume in a sparse private mapping, the engine's layout. */
static int csg_serial_run(engine_pipeline_job *job, const vod_params *v, vod_sink *sink,
                          engine_pipeline_report *r);

static int csg_serial(engine_pipeline_job *job, const vod_params *v, vod_sink *sink,
                      engine_pipeline_report *r)
{
    const csg_tree *own = job->csg.tree;
    csg_tree *copy;
    int rc = band_tree(job, &copy, r);
    if (!rc) rc = csg_serial_run(job, v, sink, r);
    job->csg.tree = own;
    free(copy);
    return rc;
}

static int csg_serial_run(engine_pipeline_job *job, const vod_params *v, vod_sink *sink,
                          engine_pipeline_report *r)
{
    r->stage = ENGINE_PIPELINE_VOXELIZE;
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
        return engine_pipeline_fail(r, ENGINE_LIMIT, -ENOMEM, "cannot map a volume of %ux%ux%u",
                             r->grid.res[0], r->grid.res[1], r->grid.res[2]);
    }
    vod_volume *vol;
    rc = vod_volume_init(&vol, arena, bytes, r->grid.res, bits, CSG_VOLUME_BRICK);
    csg_stats st = {0};
    if (!rc) rc = csg_eval_volume(job->csg.tree, &r->grid, (const vod_volume *const *)leaves,
                                  vol, v->channel, &st);
    r->t_voxelize = clock_now() - t0;
    r->fig.csg = (engine_csg_figures){st.bricks, st.uniform_bricks, st.skipped, st.voxel_evals};
    r->voxels = st.solid_voxels;
    if (rc) {
        engine_pipeline_fail(r, rc == -ENOMEM ? ENGINE_LIMIT : ENGINE_FAULT, rc,
                      "evaluating the tree: %s", strerror(-rc));
    } else {
        vod_source src = vod_volume_source(vol);
        rc = engine_pipeline_write_serial(NULL, &src, v, sink, r);
    }
    munmap(arena, bytes);
    if (larena != MAP_FAILED) munmap(larena, lbytes);
    return rc;
}

static int csg_voxelize(engine *e, engine_pipeline_job *job, const engine_sched_watch *w,
                        engine_result *er, engine_pipeline_report *r)
{
    const csg_tree *own = job->csg.tree;
    csg_tree *copy;
    int rc = band_tree(job, &copy, r);
    if (rc) return rc;
    engine_csg_job cj = {.tree = job->csg.tree, .grid = r->grid, .channel = job->vod.channel,
                         .progress = w->progress, .ud = w->ud, .cancel = w->cancel,
                         .figures = &r->fig.csg};
    rc = engine_csg(e, &cj, er);
    job->csg.tree = own;
    free(copy);
    return rc;
}

/* What vox says of a csg job that ran: its bricks. */
static void csg_summary(const engine_pipeline_job *job, const engine_pipeline_report *r,
                                char *buf, size_t len)
{
    (void)job;
    const engine_csg_figures *f = &r->fig.csg;
    snprintf(buf, len, "%llu bricks (%llu uniform, %llu operand subtrees skipped)",
             (unsigned long long)f->bricks, (unsigned long long)f->uniform,
             (unsigned long long)f->skipped);
}

const engine_kind engine_kind_csg = {
    .name = "csg",
    .id = SHM_KIND_CSG,
    .setup = csg_setup,
    .take = csg_take,
    .done = csg_done,
    .rerun = csg_rerun,
    .prefetch = 1, /* a run below the object takes less than a wake-up */
    .describe = csg_describe,
    .progress = csg_progress,
    .finish = csg_finish,
    .domain = csg_domain,
    .meta = csg_meta,
    .serial = csg_serial,
    .voxelize = csg_voxelize,
    .summary = csg_summary,
};

int engine_csg(engine *e, const engine_csg_job *job, engine_result *r)
{
    csg_job cj = {.job = job, .r = r};
    engine_sched_watch w = {.progress = job->progress, .ud = job->ud, .cancel = job->cancel};
    int rc = engine_sched_run_job(e, &engine_kind_csg, &cj, &w, r);
    if (job->figures) *job->figures = cj.fig;
    return rc;
}
