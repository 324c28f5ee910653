/* The mesh voxelizer's surface modes against the separating axis theorem (13
 * axes) on every voxel box (surface6 inside surface and 6-separating;
 * conservative and interior as set operations), a surface touching a voxel face;
 * holes: vote and winding number against the closed mesh; tiles in any order,
 * one twice: the same volume as mesh_voxelize; the bins: each triangle once in
 * ascending order, the same on any number of threads, the plain solid's bins
 * holding the triangles that flip a column. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "grid.h"
#include "mesh_shapes.h"
#include "mesh_vox.h"
#include "mesh_vox_int.h"
#include "vod_volume.h"
#include "voxel.h"

#include "mesh_vox_fixture.h"

Test(mesh_vox, surface_modes_match_the_separating_axis_test)
{
    shape s;
    shape_init(&s);
    double c[3] = {0.021, -0.013, 0.007};
    shape_icosphere(&s, c, 0.7, 3, false);
    check_surface_modes(shape_finish(&s), 64);
    shape_free(&s);

    shape_init(&s);
    shape_torus(&s, c, 0.55, 0.2, 40, 20);
    check_surface_modes(shape_finish(&s), 64);
    shape_free(&s);

    shape_init(&s);
    double lo[3] = {-0.77, -0.71, -0.43};
    double k[3] = {0.6, 0, 0.8}, R[3][3], t[3] = {0, 0, 0};
    shape_c(&s, lo, 0.47, 0.91);
    shape_rotation(k, 0.3, R);
    shape_transform(&s, 0, R, t);
    check_surface_modes(shape_finish(&s), 64);
    shape_free(&s);
}

Test(mesh_vox, surface_touching_a_voxel_face_sets_both_voxels)
{
    /* a box whose faces lie on voxel boundaries: closed boxes, so both
     * layers beside each face are touched; the SAT is exact here */
    grid_spec g = cube_grid(32);
    double lo[3] = {grid_coord(&g, 0, 4), grid_coord(&g, 1, 6), grid_coord(&g, 2, 8)};
    double hi[3] = {grid_coord(&g, 0, 20), grid_coord(&g, 1, 17), grid_coord(&g, 2, 25)};
    shape s;
    shape_init(&s);
    shape_box(&s, lo, hi);
    const mesh *m = shape_finish(&s);
    uint8_t *want = sat_surface(m, &g);
    uint32_t *got = voxelize_mode(m, &g, MESH_SURFACE, MESH_REPAIR_NONE, NULL);
    size_t wrong = 0, n = 0;
    for (size_t i = 0; i < nvox(&g); i++) {
        wrong += (got[i] != 0) != (want[i] != 0);
        n += got[i] != 0;
    }
    cr_expect_eq(wrong, 0);
    /* the shell of boxes [3, 21) x [5, 18) x [7, 26) less [5, 19) x [7, 16) x [9, 24) */
    cr_expect_eq(n, (size_t)18 * 13 * 19 - (size_t)14 * 9 * 15);
    free(want), free(got);
    shape_free(&s);
}

/* ---- holes ---- */

typedef struct {
    double c[3], r;  /* triangles with a vertex in this ball go */
    const mesh *m;
} hole;

static bool keep_outside_hole(uint32_t t, void *ctx)
{
    const hole *h = ctx;
    for (int i = 0; i < 3; i++) {
        double p[3], d = 0;
        vert(h->m, t, i, p);
        for (int a = 0; a < 3; a++) d += (p[a] - h->c[a]) * (p[a] - h->c[a]);
        if (d < h->r * h->r) return false;
    }
    return true;
}

Test(mesh_vox, repair_fills_holes)
{
    grid_spec g = cube_grid(64);
    double c[3] = {0.017, -0.023, 0.011};
    shape s;
    shape_init(&s);
    shape_icosphere(&s, c, 0.7, 3, false);
    const mesh *m = shape_finish(&s);
    mesh_tile_stats st;
    uint32_t *closed = voxelize_mode(m, &g, MESH_SOLID, MESH_REPAIR_NONE, NULL);
    size_t n_closed = 0;
    for (size_t i = 0; i < nvox(&g); i++) n_closed += closed[i] != 0;
    for (int rep = 1; rep < 3; rep++) { /* a closed mesh: nothing to repair */
        uint32_t *d = voxelize_mode(m, &g, MESH_SOLID, (mesh_repair)rep, &st);
        cr_expect_eq(st.disagreements, 0);
        cr_expect_eq(st.disagree_bricks, 0);
        cr_expect_eq(memcmp(d, closed, nvox(&g) * 4), 0);
        free(d);
    }
    /* holes at the top and on the side */
    size_t before = s.m.n_triangles;
    hole h1 = {{c[0], c[1] + 0.1, c[2] + 0.7}, 0.2, m}, h2 = {{c[0] + 0.7, c[1], c[2]}, 0.15, m};
    shape_remove(&s, keep_outside_hole, &h1);
    shape_remove(&s, keep_outside_hole, &h2);
    cr_assert_lt(s.m.n_triangles, before);
    size_t n_plain = 0;
    uint32_t *plain = voxelize_mode(m, &g, MESH_SOLID, MESH_REPAIR_NONE, NULL);
    for (size_t i = 0; i < nvox(&g); i++) n_plain += plain[i] != 0;
    free(plain);
    cr_expect_gt(fabs((double)n_plain - (double)n_closed), 0.01 * n_closed,
                 "the holes spoil the plain parity (%zu vs %zu)", n_plain, n_closed);
    for (int rep = 1; rep < 3; rep++) {
        uint32_t *d = voxelize_mode(m, &g, MESH_SOLID, (mesh_repair)rep, &st);
        size_t n = 0;
        for (size_t i = 0; i < nvox(&g); i++) n += d[i] != 0;
        cr_expect_gt(st.disagreements, 0);
        cr_expect_gt(st.disagree_bricks, 0);
        cr_expect_leq(st.disagree_bricks, 64 * 64 * 64 / (16 * 16 * 16));
        cr_expect(fabs((double)n - (double)n_closed) <= 0.01 * n_closed,
                  "repair %d: %zu voxels, closed %zu", rep, n, n_closed);
        free(d);
    }
    free(closed);
    shape_free(&s);
}

/* ---- tiles ---- */

/* A grid whose sides are not multiples of the tile. */
static grid_spec odd_grid(void)
{
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 0.6, -0.5};
    grid_spec g;
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, 160, &g, &err), 0, "%s", err.msg);
    cr_assert(g.res[0] == 160 && g.res[1] == 128 && g.res[2] == 40);
    return g;
}

static void check_tiles(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
                        uint32_t sbrick)
{
    uint32_t bits = mesh_vox_bits(o);
    tvol ref = vol_make(g, bits, sbrick), got = vol_make(g, bits, sbrick);
    mesh_tile_stats s_ref = {0}, s_got = {0}, s_once = {0};
    cr_assert_eq(mesh_voxelize(m, g, o, ref.v, &s_ref), 0);
    mesh_bins b;
    mesh_lattice *lat = malloc(m->n_vertices * sizeof *lat);
    cr_assert_eq(mesh_bin(m, g, o, lat, 1, &b), 0);
    uint32_t nt = b.tiles[0] * b.tiles[1];
    cr_assert_eq(b.tiles[0], (g->res[0] + 63) / 64);
    uint32_t *order = malloc((nt + 1) * sizeof *order);
    for (uint32_t i = 0; i < nt; i++) order[i] = (i * 5 + 3) % nt; /* 5 is prime to nt = 6 */
    order[nt] = order[nt / 2];                                     /* one tile twice */
    void *scratch = malloc(mesh_tile_scratch_bytes(g, o));
    for (uint32_t i = 0; i <= nt; i++) {
        uint32_t t = order[i];
        mesh_tile_stats *st = i < nt ? &s_got : &s_once;
        /* half of them snap the vertices themselves */
        mesh_tiles j = {.m = m, .lattice = i % 2 ? NULL : lat, .g = g, .o = o, .vol = got.v,
                        .scratch = scratch};
        cr_assert_eq(mesh_tile_run(&j, b.ids + b.start[t], b.start[t + 1] - b.start[t],
                                   t % b.tiles[0], t / b.tiles[0], st), 0);
    }
    size_t diff = 0;
    for (uint32_t z = 0; z < g->res[2]; z++)
        for (uint32_t y = 0; y < g->res[1]; y++)
            for (uint32_t x = 0; x < g->res[0]; x++)
                diff += vod_volume_get(ref.v, x, y, z) != vod_volume_get(got.v, x, y, z);
    cr_expect_eq(diff, 0, "%zu voxels differ with the tiles scrambled", diff);
    cr_expect_eq(s_got.voxels, s_ref.voxels);
    cr_expect_eq(s_got.disagreements, s_ref.disagreements);
    cr_expect_gt(s_ref.voxels, 0);
    vod_volume_info ia, ib;
    vod_volume_get_info(ref.v, &ia);
    vod_volume_get_info(got.v, &ib);
    cr_expect_eq(ia.level0_bricks, ib.level0_bricks, "the tile run twice allocates nothing new");
    free(order), free(scratch), free(ref.arena), free(got.arena), free(lat);
    mesh_bins_free(&b);
}

Test(mesh_vox, tiles_in_any_order_give_the_same_volume)
{
    grid_spec g = odd_grid();
    shape s;
    shape_init(&s);
    double c[3] = {0.1, -0.2, -0.75}, k[3] = {0.2, 0.5, -0.55};
    shape_torus(&s, c, 0.62, 0.2, 32, 16);
    shape_icosphere(&s, k, 0.3, 2, false); /* partly outside the grid */
    size_t before = s.m.n_triangles;
    shape_remove(&s, keep_outside_hole, &(hole){{0.92, -0.2, -0.75}, 0.06, &s.m});
    cr_assert_lt(s.m.n_triangles, before, "a hole in the torus");
    const mesh *m = shape_finish(&s);
    mesh_vox_opts all[] = {
        {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_SOLID, MESH_REPAIR_VOTE, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_CONSERVATIVE, MESH_REPAIR_WINDING, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_SURFACE6, MESH_REPAIR_NONE, VOXEL_CH_SURFACE, 2, 0},
        {MESH_SOLID, MESH_REPAIR_VOTE, VOXEL_CH_DENSITY, 3, 0},
    };
    const uint32_t sb[] = {16, 8, 32, 16, 64};
    for (size_t i = 0; i < sizeof all / sizeof *all; i++) check_tiles(m, &g, &all[i], sb[i]);
    shape_free(&s);
}

Test(mesh_vox, bins_list_each_triangle_once_in_ascending_order)
{
    grid_spec g = odd_grid();
    shape s;
    shape_init(&s);
    double c[3] = {0.1, -0.2, -0.35};
    shape_icosphere(&s, c, 0.6, 3, false);
    const mesh *m = shape_finish(&s);
    for (int rep = 0; rep < 2; rep++) {
        mesh_vox_opts o = {MESH_SOLID, rep ? MESH_REPAIR_VOTE : MESH_REPAIR_NONE,
                           VOXEL_CH_OCCUPANCY, 0, 0};
        mesh_bins b;
        cr_assert_eq(mesh_bin(m, &g, &o, NULL, 1, &b), 0);
        cr_assert_eq(b.tiles[0], 3);
        cr_assert_eq(b.tiles[1], 2);
        uint64_t total = 0;
        for (uint32_t t = 0; t < 6; t++) {
            for (uint64_t i = b.start[t] + 1; i < b.start[t + 1]; i++)
                cr_assert_lt(b.ids[i - 1], b.ids[i]);
            total += b.start[t + 1] - b.start[t];
        }
        /* every triangle somewhere; repair lists more (the rows to the right) */
        cr_expect_geq(total, m->n_triangles);
        if (rep) cr_expect_gt(total, 2 * (uint64_t)m->n_triangles);
        mesh_bins_free(&b);
    }
    shape_free(&s);
}

/* Binning on several threads gives the bins one thread gives, in every
 * mode (the plain solid's codes, the others' spans, the repair's rows),
 * with triangles that hold no centre and triangles over several tiles. */
Test(mesh_vox, bins_are_the_same_on_any_number_of_threads)
{
    grid_spec g = odd_grid();
    shape s;
    shape_init(&s);
    double c[3] = {0.1, -0.2, -0.35};
    shape_icosphere(&s, c, 0.6, 6, false); /* 81920 triangles: up to 2 parts */
    double k[3] = {0.3, 0.1, -0.5};
    shape_icosphere(&s, k, 0.4, 6, false); /* 163840 in all: up to 5 */
    const mesh *m = shape_finish(&s);
    cr_assert_geq(m->n_triangles, 5 * MESH_BIN_PART_MIN);
    mesh_vox_opts all[] = {
        {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_SOLID, MESH_REPAIR_VOTE, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_SURFACE, MESH_REPAIR_NONE, VOXEL_CH_SURFACE, 0, 0},
        {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_DENSITY, 2, 0},
    };
    for (size_t i = 0; i < sizeof all / sizeof *all; i++) {
        mesh_bins one;
        cr_assert_eq(mesh_bin(m, &g, &all[i], NULL, 1, &one), 0);
        uint32_t nt = one.tiles[0] * one.tiles[1];
        cr_assert_gt(one.start[nt], 0);
        for (unsigned threads = 2; threads <= 5; threads++) {
            mesh_bins b;
            cr_assert_eq(mesh_bin(m, &g, &all[i], NULL, threads, &b), 0);
            cr_assert_eq(memcmp(b.tiles, one.tiles, sizeof b.tiles), 0);
            cr_assert_eq(memcmp(b.start, one.start, (nt + 1) * sizeof *b.start), 0,
                         "mode %zu, %u threads: the starts", i, threads);
            cr_assert_eq(memcmp(b.ids, one.ids, one.start[nt] * sizeof *b.ids), 0,
                         "mode %zu, %u threads: the ids", i, threads);
            mesh_bins_free(&b);
        }
        mesh_bins_free(&one);
    }
    shape_free(&s);
}

/* The plain solid's bins are exact: a triangle rasterized alone into a
 * tile's columns (every crossing flips the one slice of a block far above
 * the mesh) and flipping a bit there is in the tile's bin, and a triangle
 * in the bin has a centre of the tile in the box of its snapped vertices;
 * a fine mesh has triangles that hold no centre and are in no bin.  The
 * lattice mesh_bin fills is the tiles' own snapping. */
Test(mesh_vox, plain_solid_bins_hold_the_triangles_that_flip_a_column)
{
    grid_spec g = odd_grid();
    shape s;
    shape_init(&s);
    double c[3] = {0.1, -0.2, -0.35};
    shape_icosphere(&s, c, 0.6, 6, false); /* 81920 triangles, most smaller than a voxel */
    const mesh *m = shape_finish(&s);
    mesh_vox_opts o = {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_OCCUPANCY, 0, 0};
    mesh_bins b;
    mesh_lattice *lat = malloc(m->n_vertices * sizeof *lat);
    cr_assert_eq(mesh_bin(m, &g, &o, lat, 1, &b), 0);
    uint32_t ntiles = b.tiles[0] * b.tiles[1];
    bool *in_bin = calloc((size_t)ntiles * m->n_triangles, 1);
    for (uint32_t t = 0; t < ntiles; t++)
        for (uint64_t i = b.start[t]; i < b.start[t + 1]; i++)
            in_bin[(size_t)t * m->n_triangles + b.ids[i]] = true;
    mesh_vox_frame f;
    mesh_vox_frame_init(&f, m, &g, 1);
    uint64_t words[64], flipping = 0, listed = 0, none = 0;
    for (uint32_t id = 0; id < m->n_triangles; id++) {
        int64_t P[3][3];
        mesh_vox_triangle(&f, id, P);
        for (int k = 0; k < 3; k++)
            cr_assert_eq(memcmp(P[k], lat[m->triangles[id][k]], sizeof P[k]), 0);
        bool any = false;
        for (uint32_t t = 0; t < ntiles; t++) {
            uint32_t x0 = t % b.tiles[0] * 64, y0 = t / b.tiles[0] * 64;
            mesh_vox_block blk = {{x0, y0, 1 << 20}, {(int32_t)(g.res[0] - x0 < 64 ? g.res[0] - x0 : 64),
                                                (int32_t)(g.res[1] - y0 < 64 ? g.res[1] - y0 : 64), 1},
                            1};
            memset(words, 0, sizeof words);
            mesh_vox_target tg = {&blk, words, NULL, true, NULL};
            mesh_vox_raster(P, 2, &tg);
            bool flips = false;
            for (int i = 0; i < blk.n[1]; i++) flips |= words[i] != 0;
            bool listed_here = in_bin[(size_t)t * m->n_triangles + id];
            cr_assert(!flips || listed_here, "triangle %u flips tile %u but is not in its bin", id, t);
            if (listed_here) /* the box of its snapped vertices holds a centre of the tile */
                for (int a = 0; a < 2; a++) {
                    int64_t lo = P[0][a], hi = P[0][a];
                    for (int k = 1; k < 3; k++)
                        lo = P[k][a] < lo ? P[k][a] : lo, hi = P[k][a] > hi ? P[k][a] : hi;
                    int64_t first = (a ? y0 : x0), last = first + blk.n[a] - 1;
                    while (first <= last && first * MESH_VOX_L + MESH_VOX_H < lo) first++;
                    while (last >= first && last * MESH_VOX_L + MESH_VOX_H > hi) last--;
                    cr_assert_leq(first, last, "triangle %u in tile %u holds no centre of it", id, t);
                }
            flipping += flips;
            listed += listed_here;
            any |= listed_here;
        }
        none += !any;
    }
    cr_expect_gt(flipping, 0);
    cr_expect_gt(none, m->n_triangles / 10, "%lu of %u triangles hold no centre",
                 (unsigned long)none, m->n_triangles);
    cr_expect_geq(listed, flipping);
    free(lat), free(in_bin);
    mesh_bins_free(&b);
    shape_free(&s);
}
