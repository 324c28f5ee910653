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
#include "master.h"
#include "par.h"
#include "voxel.h"


typedef struct {
    const engine_mesh_job *job;
    engine_result *r;
    uint32_t ntiles;       /* tiles with triangles: tasks */
    uint32_t done;         /* tasks finished */
} mesh_job;

static uint64_t align64(uint64_t v) { return (v + 63) / 64 * 64; }

static mesh_block *block(engine *e)
{
    return shm_at(e->seg.base, e->h->job_off);
}

static int no_room(engine *e, const char *what)
{
    return sched_fail(e, ENGINE_LIMIT, -ENOMEM,
                      "%s does not fit in shared memory (%zu MiB); raise its size",
                      what, e->seg.bytes >> 20);
}

/* Where the mesh goes behind the block; the end of its triangles.  (The
 * tiles snap the vertices themselves: a lattice snapped here, serially,
 * into fresh pages of the segment cost the job more than it saved the
 * workers.) */
static uint64_t place_mesh(engine *e, const mesh *m, mesh_block *b)
{
    b->vertices_off = align64(e->h->data_off + sizeof *b);
    b->triangles_off = align64(b->vertices_off + (uint64_t)m->n_vertices * 12);
    return b->triangles_off + (uint64_t)m->n_triangles * 12;
}

/* The mesh's vertices and triangles into the segment, on a thread of
 * their own while the triangles are binned: the copy's time is the first
 * touch of the segment's pages, which the binning's arithmetic can run
 * beside. */
typedef struct {
    const mesh *m;
    void *vertices, *triangles;
} mesh_copy;

/* n bytes from src to fresh pages of the segment at to, the pages faulted
 * in by one call first (MADV_POPULATE_WRITE) rather than one fault each
 * as the copy goes; where the kernel has no such call, by the copy. */
static void copy_fresh(void *to, const void *src, size_t n)
{
#ifdef MADV_POPULATE_WRITE
    uintptr_t page = (uintptr_t)sysconf(_SC_PAGESIZE), a = (uintptr_t)to / page * page;
    if (n) madvise((void *)a, (uintptr_t)to + n - a, MADV_POPULATE_WRITE);
#endif
    if (n) memcpy(to, src, n);
}

static void *copy_mesh(void *ud)
{
    const mesh_copy *c = ud;
    copy_fresh(c->vertices, c->m->vertices, (size_t)c->m->n_vertices * 12);
    copy_fresh(c->triangles, c->m->triangles, (size_t)c->m->n_triangles * 12);
    return NULL;
}

/* Copy the bins behind the mesh (which copy_mesh put behind the block);
 * the volume's offset (the rest of the data area) in *vol_off. */
static int copy_bins(engine *e, const mesh *m, const mesh_bins *bins,
                     mesh_block *b, uint64_t *vol_off)
{
    uint64_t n = (uint64_t)bins->tiles[0] * bins->tiles[1];
    uint64_t end = e->h->data_off + e->h->data_bytes;
    b->start_off = align64(place_mesh(e, m, b));
    b->ids_off = align64(b->start_off + (n + 1) * sizeof(uint64_t));
    b->stats_off = align64(b->ids_off + bins->start[n] * sizeof(uint32_t));
    *vol_off = align64(b->stats_off + n * sizeof(mesh_tile_stats));
    if (*vol_off >= end) return no_room(e, "the mesh");
    copy_fresh(shm_at(e->seg.base, b->start_off), bins->start, (n + 1) * sizeof(uint64_t));
    copy_fresh(shm_at(e->seg.base, b->ids_off), bins->ids, bins->start[n] * sizeof(uint32_t));
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

/* One task per tile with triangles (every tile for a distance), the
 * lightest pushed first. */
static int push_tiles(engine *e, mesh_job *mj, const mesh_bins *bins)
{
    uint32_t n = bins->tiles[0] * bins->tiles[1], k = 0;
    /* a distance tile without triangles still writes its +w bricks */
    bool dist = mj->job->opts.channel == VOXEL_CH_DISTANCE;
    uint32_t *order = malloc((n ? n : 1) * sizeof *order);
    if (!order) return sched_fail(e, ENGINE_FAULT, -ENOMEM, "out of memory");
    for (uint32_t t = 0; t < n; t++)
        if ((bins->start[t + 1] > bins->start[t] || dist) && tile_wanted(mj->job, bins, t))
            order[k++] = t;
    qsort_r(order, k, sizeof *order, by_triangles, bins->start);
    int rc = 0;
    for (uint32_t i = 0; i < k && !rc; i++) {
        shm_task t = {.kind = SHM_KIND_MESH, .op = MESH_TILES};
        mesh_task_arg a = {order[i], 1};
        memcpy(t.arg, &a, sizeof a);
        rc = sched_push(e, &t);
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
                             mesh_vox_bits(o), MESH_VOLUME_BRICK);
    if (rc) return no_room(e, "the volume's tables");
    e->volume_bytes = bytes;
    return 0;
}

/* The low mip levels the tiles build: those whose bricks lie in one tile's
 * column (a level-l brick spans MESH_VOLUME_BRICK << l voxels), of the
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
    char msg[sizeof e->err.message];
    e->result = RESULT_NONE;
    sched_hold(e, 0); /* the last job's result: overwritten now */
    if (!j->mesh || !j->mesh->n_triangles || grid_check(&j->grid))
        return sched_fail(e, ENGINE_BAD_JOB, -EINVAL, "the mesh job is invalid");
    if (mesh_vox_check(&j->opts, msg, sizeof msg))
        return sched_fail(e, ENGINE_BAD_JOB, -EINVAL, "%s", msg);
    mesh_block *b = shm_at(e->seg.base, e->h->data_off);
    memset(b, 0, sizeof *b);
    if (place_mesh(e, j->mesh, b) > e->h->data_off + e->h->data_bytes)
        return no_room(e, "the mesh");
    mesh_copy copy = {j->mesh, shm_at(e->seg.base, b->vertices_off),
                      shm_at(e->seg.base, b->triangles_off)};
    par_task copying;
    par_start(&copying, copy_mesh, &copy);
    double t0 = clock_now();
    mesh_bins bins;
    int rc = mesh_bin(j->mesh, &j->grid, &j->opts, NULL, par_cpus(), &bins);
    mj->r->t_bin = clock_now() - t0;
    par_join(&copying);
    if (rc) return sched_fail(e, rc == -E2BIG ? ENGINE_LIMIT : ENGINE_FAULT, rc,
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
    return sched_fail(e, ENGINE_FAULT, -EPROTO,
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
    if (!error || e->err.failure) return;
    char what[64];
    mesh_describe(t, what, sizeof what);
    if (error == -ENOMEM)
        no_room(e, "the volume");
    else
        sched_fail(e, ENGINE_FAULT, error, "worker %d failed on %s: %s", i, what,
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
        p->shm_used = block(e)->volume_off - e->h->data_off + in.bytes_used;
    }
}

/* The tiles' counts, and the volume checked before the writer reads it. */
static int collect(engine *e, mesh_job *mj)
{
    const mesh_block *b = block(e);
    engine_result *r = mj->r;
    const mesh_tile_stats *st = shm_at(e->seg.base, b->stats_off);
    for (uint64_t t = 0; t < (uint64_t)b->tiles[0] * b->tiles[1]; t++) {
        r->voxels += st[t].voxels;
        r->disagreements += st[t].disagreements;
        r->disagree_bricks += st[t].disagree_bricks;
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
        return sched_fail(e, ENGINE_FAULT, -EPROTO,
                          "the workers left the volume inconsistent");
    /* the volume stays for the encode kind */
    sched_hold(e, b->volume_off - e->h->data_off + in.bytes_used);
    return 0;
}

static int mesh_finish(engine *e, void *job, int rc)
{
    mesh_job *mj = job;
    engine_result *r = mj->r;
    sched_job_totals(e, r);
    r->octants = 0;
    r->tiles = mj->ntiles;
    if (!rc) rc = collect(e, mj);
    r->seconds = clock_now() - e->t0;
    if (rc) return sched_job_failed(e, r, rc);
    e->result = RESULT_VOLUME;
    return 0;
}

const master_kind kind_mesh = {
    .name = "mesh",
    .id = SHM_KIND_MESH,
    .setup = mesh_setup,
    .take = mesh_take,
    .done = mesh_done,
    .rerun = mesh_rerun,
    .describe = mesh_describe,
    .progress = mesh_progress,
    .finish = mesh_finish,
};

int engine_mesh(engine *e, const engine_mesh_job *job, engine_result *r)
{
    double c0 = clock_thread_cpu();
    memset(r, 0, sizeof *r);
    mesh_job mj = {.job = job, .r = r};
    sched_watch w = {.progress = job->progress, .ud = job->ud, .cancel = job->cancel};
    e->volume = NULL;
    int rc = engine_run(e, &kind_mesh, &mj, &w);
    r->master_cpu = clock_thread_cpu() - c0;
    return rc;
}
