/* The mesh kind's worker side: whole tiles of a triangle mesh voxelized
 * into the job's volume (mesh_vox.h).  The mesh, the bins and the volume
 * are in the segment, laid out by the master (mesh_block); a tile writes
 * only the bricks of its own column, and its counts into its own entry of
 * the stats array, so a tile run again after a death writes the same. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "huge.h"
#include "mesh_vox.h"
#include "vod_volume.h"
#include "work.h"

typedef struct {
    void *scratch;
    size_t scratch_bytes;
    mesh_wtree *wt; /* this job's winding-number tree, or NULL */
} mesh_state;

static void mesh_state_free(void *state)
{
    mesh_state *st = state;
    if (!st) return;
    free(st->scratch);
    mesh_wtree_free(st->wt);
    free(st);
}

/* The mesh in the segment, as the block describes it. */
static mesh block_mesh(const worker_ctx *w, const mesh_block *b)
{
    mesh m = {
        .n_vertices = b->n_vertices, .n_triangles = b->n_triangles,
        .vertices = shm_at(w->base, b->vertices_off),
        .triangles = shm_at(w->base, b->triangles_off),
    };
    memcpy(m.lo, b->lo, sizeof m.lo);
    memcpy(m.hi, b->hi, sizeof m.hi);
    return m;
}

/* The tile's scratch, kept across jobs and grown when a job needs more;
 * for the repair by winding numbers the job's tree, built by every worker
 * at its first tile of the job (the same tree: it depends on the mesh and
 * the grid alone). */
static int mesh_begin(worker_ctx *w, void **state)
{
    mesh_state *st = *state;
    if (!st && !(st = *state = calloc(1, sizeof *st))) return -ENOMEM;
    const mesh_block *b = shm_at(w->base, w->h->job_off);
    mesh_wtree_free(st->wt);
    st->wt = NULL;
    if (mesh_vox_lends_tree(&b->opts)) {
        mesh m = block_mesh(w, b);
        int rc = mesh_wtree_build(&m, &b->grid, &st->wt);
        worker_tick(w);
        if (rc) return rc;
    }
    size_t want = mesh_tile_scratch_bytes(&b->grid, &b->opts);
    if (st->scratch_bytes >= want) return 0;
    free(st->scratch);
    st->scratch_bytes = 0;
    /* huge pages: the columns' and the distance's slab are written whole (huge.h) */
    if (!(st->scratch = huge_malloc(want ? want : 1))) return -ENOMEM;
    st->scratch_bytes = want;
    return 0;
}

/* Tile (tx, ty)'s low mip levels (mesh_block.mip_levels), built right
 * after its bricks, while they are in this worker's cache: the level-l
 * bricks whose footprint is the tile's column. */
static int tile_mips(vod_volume *vol, const mesh_block *b, uint32_t tx, uint32_t ty)
{
    if (!b->mip_levels) return 0;
    vod_volume_info in;
    vod_volume_get_info(vol, &in);
    uint32_t per = MESH_TILE / (in.sbrick << b->mip_levels); /* >= 1: the master's plan */
    if (!per) return -EINVAL;
    uint32_t lo[2] = {tx * per, ty * per}, hi[2] = {lo[0] + per, lo[1] + per};
    return vod_volume_mip_columns(vol, b->mip_channel, (int)b->mip_levels, lo, hi);
}

/* The tiles' heartbeat (mesh_tile_env): a winding-number or density tile
 * can run for seconds; the abort is checked where the beat is given. */
static int tile_tick(void *arg)
{
    worker_ctx *w = arg;
    worker_tick(w);
    return worker_aborted(w);
}

static int mesh_run(worker_ctx *w, void *state, const shm_task *t)
{
    mesh_state *st = state;
    const mesh_block *b = shm_at(w->base, w->h->job_off);
    mesh_task_arg a = mesh_task_tiles(t);
    uint64_t ntiles = (uint64_t)b->tiles[0] * b->tiles[1];
    if (t->op != MESH_TILES || a.first >= ntiles || a.count > ntiles - a.first)
        return -EINVAL;
    mesh m = block_mesh(w, b);
    const uint64_t *start = shm_at(w->base, b->start_off);
    const uint32_t *ids = shm_at(w->base, b->ids_off);
    mesh_tile_stats *stats = shm_at(w->base, b->stats_off);
    vod_volume *vol = vod_volume_view(shm_at(w->base, b->volume_off));
    if (!vol) return -EINVAL;
    mesh_tile_env env = {.wtree = st->wt, .tick = tile_tick, .arg = w};
    mesh_tiles j = {.m = &m, .g = &b->grid, .o = &b->opts, .vol = vol, .env = &env,
                    .scratch = st->scratch};
    for (uint32_t k = a.first; k < a.first + a.count; k++) {
        if (worker_aborted(w)) return -ECANCELED;
        mesh_tile_stats s = {0};
        int rc = mesh_tile_run(&j, ids + start[k], start[k + 1] - start[k], k % b->tiles[0],
                               k / b->tiles[0], &s);
        if (!rc) rc = tile_mips(vol, b, k % b->tiles[0], k / b->tiles[0]);
        if (rc) return rc;
        stats[k] = s;
        worker_tick(w);
    }
    return 0;
}

const worker_kind worker_mesh = {
    .name = "mesh",
    .begin = mesh_begin,
    .run = mesh_run,
    .free = mesh_state_free,
};
