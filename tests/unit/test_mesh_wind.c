/* The repair by winding numbers (mesh_vox.h, MESH_REPAIR_WINDING) on
 * meshes with holes made here:
 *  - a tile ticks its heartbeat all along, in the winding numbers and in
 *    the supersampled density alike, and stops at once when a tick says so
 *    (the largest gap between two ticks is measured in the thread's CPU
 *    time, which a loaded machine does not stretch).
 */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "grid.h"
#include "mesh_shapes.h"
#include "mesh_vox.h"
#include "vod_volume.h"
#include "voxel.h"

/* ---- meshes, grids, volumes ---- */

static bool not_every_seventh(uint32_t i, void *ctx)
{
    (void)ctx;
    return i % 7 != 3;
}

/* An icosphere of radius 0.8 (20 * 4^level triangles) without every
 * seventh triangle. */
static const mesh *holed_sphere(shape *s, int level)
{
    double c[3] = {0.01, -0.02, 0.03};
    shape_init(s);
    shape_icosphere(s, c, 0.8, level, false);
    shape_remove(s, not_every_seventh, NULL);
    return shape_finish(s);
}

static grid_spec cube_grid(uint32_t res)
{
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    grid_spec g;
    char err[128];
    cr_assert_eq(grid_make(lo, hi, res, &g, err, sizeof err), 0, "%s", err);
    return g;
}

typedef struct {
    void *arena;
    vod_volume *v;
} tvol;

static tvol vol_make(const grid_spec *g, uint32_t bits)
{
    tvol r;
    size_t bytes = vod_volume_bytes(g->res, bits, MESH_VOLUME_BRICK, UINT32_MAX);
    cr_assert_gt(bytes, 0);
    r.arena = malloc(bytes);
    cr_assert_not_null(r.arena);
    cr_assert_eq(vod_volume_init(&r.v, r.arena, bytes, g->res, bits, MESH_VOLUME_BRICK), 0);
    return r;
}

/* ---- the heartbeat ---- */

typedef struct {
    double last, max_gap, first;
    unsigned ticks, stop_at; /* stop_at: the tick that says stop (0: none) */
} ticker;

static double cpu_now(void)
{
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static int tick(void *arg)
{
    ticker *k = arg;
    double n = cpu_now();
    if (k->ticks && n - k->last > k->max_gap) k->max_gap = n - k->last;
    if (!k->ticks) k->first = n;
    k->last = n;
    k->ticks++;
    return k->stop_at && k->ticks >= k->stop_at;
}

/* Tile (0, 0) of m on g with options o and the ticker k; its return code
 * and the thread's CPU seconds in *cpu. */
static int tile_with(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
                     const mesh_tile_env *env, double *cpu)
{
    mesh_bins b;
    cr_assert_eq(mesh_bin(m, g, o, NULL, 1, &b), 0);
    tvol v = vol_make(g, mesh_vox_bits(o));
    void *scratch = malloc(mesh_tile_scratch_bytes(g, o));
    cr_assert_not_null(scratch);
    mesh_tile_stats st = {0};
    double t0 = cpu_now();
    int rc = mesh_tile_run(m, NULL, b.ids + b.start[0], (size_t)(b.start[1] - b.start[0]), g, o,
                           0, 0, scratch, v.v, env, &st);
    *cpu = cpu_now() - t0;
    free(scratch);
    free(v.arena);
    mesh_bins_free(&b);
    return rc;
}

/* A tile of the winding numbers by the exact sum (seconds of work) and a
 * supersampled density tile: ticks never more than 20 ms of CPU apart
 * (about 1 ms is the plan), and a stop ends the tile within one tick. */
Test(mesh_wind, a_tile_ticks_all_along_and_stops_when_told, .timeout = 600)
{
    shape s;
    const mesh *m = holed_sphere(&s, 3);
    /* the same samples: 40^3 voxel centres, 20^3 voxels of 2^3 samples */
    grid_spec grids[] = {cube_grid(40), cube_grid(20)};
    mesh_vox_opts opts[] = {
        {MESH_SOLID, MESH_REPAIR_WINDING, VOXEL_CH_OCCUPANCY, 0},
        {MESH_SOLID, MESH_REPAIR_WINDING, VOXEL_CH_DENSITY, 2},
    };
    for (size_t i = 0; i < 2; i++) {
        const grid_spec g = grids[i];
        ticker k = {0};
        mesh_tile_env env = {.tick = tick, .arg = &k};
        double cpu;
        cr_assert_eq(tile_with(m, &g, &opts[i], &env, &cpu), 0);
        cr_log_info("options %zu: %.3f s of CPU, %u ticks, the longest gap %.4f s", i, cpu,
                    k.ticks, k.max_gap);
        cr_assert_geq(cpu, 0.2, "options %zu: a short tile (%.3f s)", i, cpu);
        cr_assert_geq(k.ticks, 10);
        cr_assert_leq(k.max_gap, 0.02, "options %zu: %.4f s without a tick", i, k.max_gap);
        cr_assert_leq(k.first, k.last);

        ticker stop = {.stop_at = k.ticks / 2};
        env.arg = &stop;
        cr_assert_eq(tile_with(m, &g, &opts[i], &env, &cpu), -ECANCELED, "options %zu", i);
        cr_assert_eq(stop.ticks, k.ticks / 2, "options %zu: ticks after the stop", i);
    }
    shape_free(&s);
}
