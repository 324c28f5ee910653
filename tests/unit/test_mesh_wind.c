/* The repair by winding numbers (mesh_vox.h, MESH_REPAIR_WINDING) on
 * meshes with holes made here:
 *  - a tile ticks its heartbeat all along, in the winding numbers and in
 *    the supersampled density alike, and stops at once when a tick says so
 *    (the largest gap between two ticks is measured in the thread's CPU
 *    time, which a loaded machine does not stretch);
 *  - the answers of the caps' direct path and of their tree (mesh_wcap.c,
 *    mesh_wcap_tree_only) against the exact sum's (mesh_wind_exact,
 *    the code before the tree: the oracle) on every voxel of spheres and
 *    tori with holes cut and of a soup of loose triangles, in the solid
 *    and the density: at least 99.99% equal, every voxel where the exact
 *    |w| is within 0.001 of 1/2 equal (the tree hands those to the exact
 *    sum), and the solid within 2% of the closed mesh's;
 *  - the bounds themselves: a cell's (mesh_vox_wind_cell), the far field
 *    handed down from a cell to a point of it (mesh_vox_wind_down), the
 *    caps' expansion (mesh_vox_wcap_expand);
 *  - the same bytes from 0, 1 and 2 workers (test_mesh_engine's jobs
 *    hold the serial tiles against the engine's).
 */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "grid.h"
#include "mesh_shapes.h"
#include "mesh_vox.h"
#include "mesh_vox_int.h"
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
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, res, &g, &err), 0, "%s", err.msg);
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
    mesh_tiles j = {.m = m, .g = g, .o = o, .vol = v.v, .env = env, .scratch = scratch};
    int rc = mesh_tile_run(&j, b.ids + b.start[0], (size_t)(b.start[1] - b.start[0]), 0, 0, &st);
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
        {MESH_SOLID, MESH_REPAIR_WINDING, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_SOLID, MESH_REPAIR_WINDING, VOXEL_CH_DENSITY, 2, 0},
    };
    for (size_t i = 0; i < 2; i++) {
        const grid_spec g = grids[i];
        ticker k = {0};
        mesh_tile_env env = {.tick = tick, .arg = &k};
        double cpu;
        cr_assert_eq(tile_with(m, &g, &opts[i], &env, &cpu), 0);
        cr_log_info("options %zu: %.3f s of CPU, %u ticks, the longest gap %.4f s", i, cpu,
                    k.ticks, k.max_gap);
        cr_assert_geq(cpu, 0.05, "options %zu: a short tile (%.3f s)", i, cpu);
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

/* ---- the tree against the exact sum ---- */

/* Every voxel of m on g for options o, serially (mesh_voxelize), as bytes
 * (the occupancy or the density). */
static uint8_t *dense(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
                      mesh_tile_stats *st)
{
    tvol v = vol_make(g, 8);
    memset(st, 0, sizeof *st);
    cr_assert_eq(mesh_voxelize(m, g, o, v.v, st), 0);
    size_t n = (size_t)g->res[0] * g->res[1] * g->res[2];
    uint8_t *d = malloc(n);
    cr_assert_not_null(d);
    for (uint32_t z = 0; z < g->res[2]; z++)
        for (uint32_t y = 0; y < g->res[1]; y++)
            for (uint32_t x = 0; x < g->res[0]; x++) {
                d[((size_t)z * g->res[1] + y) * g->res[0] + x] =
                    (uint8_t)vod_volume_get(v.v, x, y, z);
            }
    free(v.arena);
    return d;
}

/* The exact |w| at voxel centre (x, y, z) (mesh_solid.c's sum). */
static double exact_w(const mesh *m, const grid_spec *g, uint32_t x, uint32_t y, uint32_t z)
{
    mesh_vox_frame f;
    mesh_vox_frame_init(&f, m, g, 1);
    double q[1][3] = {{x + 0.5, y + 0.5, z + 0.5}}, w;
    mesh_vox_winding_many(&f, (const double (*)[3])q, 1, &w);
    return fabs(w);
}

/* The tree's voxels against the exact sum's, every voxel: the share that
 * differs, and none where the exact |w| is near 1/2; returns the voxels
 * inside (occupancy) for the closed-mesh comparison. */
static size_t last_diff; /* hold_against_exact's voxels that differed */
static size_t last_half; /* ... and the voxels whose exact |w| lies within 0.1 of 1/2 */

static size_t hold_against_exact(const mesh *m, const grid_spec *g, int channel,
                                 const char *what)
{
    mesh_vox_opts o = {MESH_SOLID, MESH_REPAIR_WINDING, channel, 2, 0};
    mesh_tile_stats sf, sx;
    mesh_wcap_tree_only = 1;
    uint8_t *tree = dense(m, g, &o, &sf);
    mesh_wcap_tree_only = 0;
    uint8_t *fast = dense(m, g, &o, &sf);
    mesh_wind_exact = 1;
    uint8_t *ref = dense(m, g, &o, &sx);
    mesh_wind_exact = 0;
    cr_assert_gt(sx.disagreements, 0, "%s: nothing to repair", what);
    cr_assert_eq(sf.disagreements, sx.disagreements);
    size_t n = (size_t)g->res[0] * g->res[1] * g->res[2], diff = 0, near = 0, inside = 0;
    last_half = 0;
    for (size_t i = 0; i < n; i++) {
        inside += fast[i] != 0;
        uint32_t vx = (uint32_t)(i % g->res[0]), vy = (uint32_t)(i / g->res[0] % g->res[1]),
                 vz = (uint32_t)(i / g->res[0] / g->res[1]);
        if (channel == VOXEL_CH_OCCUPANCY && n <= 32768)
            last_half += fabs(exact_w(m, g, vx, vy, vz) - 0.5) < 0.1;
        /* the direct path's answer and the caps' tree's, each held */
        for (int k = 0; k < 2; k++) {
            if ((k ? tree : fast)[i] == ref[i]) continue;
            diff++;
            if (channel == VOXEL_CH_OCCUPANCY)
                near += fabs(exact_w(m, g, vx, vy, vz) - 0.5) < 0.001;
        }
    }
    cr_log_info("%s: %zu of %zu voxels differ (the direct path's and the tree's), "
                "%llu disagreements", what, diff, n, (unsigned long long)sx.disagreements);
    cr_expect_leq(diff * 10000, 2 * sx.disagreements, "%s: %zu voxels differ", what, diff);
    cr_expect_eq(near, 0, "%s: %zu voxels near |w| = 1/2 differ", what, near);
    last_diff = diff;
    free(tree);
    free(fast);
    free(ref);
    return inside;
}

static bool every_fifth_and_more(uint32_t i, void *ctx)
{
    (void)ctx;
    return i % 5 != 2 && i % 97 != 11;
}

Test(mesh_wind, spheres_and_tori_with_holes_against_the_exact_sum, .timeout = 900)
{
    grid_spec g = cube_grid(48);
    shape s;
    double c[3] = {0.02, -0.01, 0.03};
    shape_init(&s);
    shape_icosphere(&s, c, 0.85, 3, false);
    const mesh *m = shape_finish(&s);
    mesh_vox_opts plain = {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_OCCUPANCY, 0, 0};
    mesh_tile_stats st;
    uint8_t *closed = dense(m, &g, &plain, &st);
    size_t n = (size_t)g.res[0] * g.res[1] * g.res[2], nclosed = 0;
    for (size_t i = 0; i < n; i++) nclosed += closed[i] != 0;
    free(closed);
    shape_remove(&s, every_fifth_and_more, NULL);
    m = shape_finish(&s);
    size_t in = hold_against_exact(m, &g, VOXEL_CH_OCCUPANCY, "sphere");
    cr_expect_leq(fabs((double)in - (double)nclosed), 0.02 * (double)nclosed,
                  "sphere: %zu voxels inside, closed %zu", in, nclosed);
    grid_spec g24 = cube_grid(24);
    hold_against_exact(m, &g24, VOXEL_CH_DENSITY, "sphere, density");
    shape_free(&s);

    shape_init(&s);
    shape_torus(&s, c, 0.6, 0.25, 48, 24);
    shape_remove(&s, not_every_seventh, NULL);
    m = shape_finish(&s);
    hold_against_exact(m, &g, VOXEL_CH_OCCUPANCY, "torus");
    shape_free(&s);
}

/* A soup: loose triangles (no vertex shared) of a sphere, every other one
 * turned the wrong way, some missing. */
Test(mesh_wind, a_soup_against_the_exact_sum, .timeout = 900)
{
    shape src, s;
    double c[3] = {0, 0.02, -0.01};
    shape_init(&src);
    shape_icosphere(&src, c, 0.8, 3, false);
    const mesh *a = shape_finish(&src);
    shape_init(&s);
    for (uint32_t t = 0; t < a->n_triangles; t++) {
        if (t % 11 == 4) continue;
        uint32_t v[3];
        for (int i = 0; i < 3; i++) {
            const float *p = a->vertices[a->triangles[t][i]];
            v[i] = shape_vertex(&s, p[0], p[1], p[2]);
        }
        if (t % 2) shape_tri(&s, v[0], v[2], v[1]);
        else shape_tri(&s, v[0], v[1], v[2]);
    }
    const mesh *m = shape_finish(&s);
    grid_spec g40 = cube_grid(40);
    hold_against_exact(m, &g40, VOXEL_CH_OCCUPANCY, "soup");
    shape_free(&s);
    shape_free(&src);
}

/* Large holes: large caps, whose solid angle varies across the cells, so
 * that the cells' bound and the samples' threshold decide voxels where
 * the exact |w| lies near 1/2: a sphere without its top and a box without
 * its lid, each voxel equal to the exact sum's (a mutation of the
 * threshold 1/2 or of the bound in mesh_wcap.c changes some of them). */
static bool below_cut(uint32_t i, void *ctx)
{
    const shape *s = ctx;
    double z = 0;
    for (int k = 0; k < 3; k++) z += s->m.vertices[s->m.triangles[i][k]][2];
    return z / 3 < 0.3;
}

Test(mesh_wind, large_holes_against_the_exact_sum_voxel_for_voxel, .timeout = 900)
{
    grid_spec g = cube_grid(32);
    shape s;
    double c[3] = {0.03, 0.01, -0.02};
    shape_init(&s);
    shape_icosphere(&s, c, 0.8, 3, false);
    shape_remove(&s, below_cut, &s);
    const mesh *m = shape_finish(&s);
    hold_against_exact(m, &g, VOXEL_CH_OCCUPANCY, "sphere without its top");
    cr_expect_eq(last_diff, 0, "%zu voxels differ", last_diff);
    cr_expect_geq(last_half, 200, "only %zu voxels near |w| = 1/2: nothing to test", last_half);
    shape_free(&s);

    /* a box (outward, counter-clockwise) without its top face, turned a
     * little so that no face lies on the samples */
    static const uint32_t faces[10][3] = {{0, 2, 3}, {0, 3, 1}, {0, 1, 5}, {0, 5, 4}, {2, 6, 7},
                                          {2, 7, 3}, {0, 4, 6}, {0, 6, 2}, {1, 3, 7}, {1, 7, 5}};
    double R[3][3], axis[3] = {0.3, -0.2, 1};
    shape_init(&s);
    for (int v = 0; v < 8; v++)
        shape_vertex(&s, v & 1 ? 0.66 : -0.71, v & 2 ? 0.69 : -0.62, v & 4 ? 0.58 : -0.73);
    for (int f = 0; f < 10; f++) shape_tri(&s, faces[f][0], faces[f][1], faces[f][2]);
    double len = sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
    for (int a = 0; a < 3; a++) axis[a] /= len;
    shape_rotation(axis, 0.2, R);
    shape_transform(&s, 0, R, c);
    m = shape_finish(&s);
    hold_against_exact(m, &g, VOXEL_CH_OCCUPANCY, "box without its lid");
    cr_expect_eq(last_diff, 0, "%zu voxels differ", last_diff);
    cr_expect_geq(last_half, 200, "only %zu voxels near |w| = 1/2: nothing to test", last_half);
    shape_free(&s);
}

/* ---- the cell bound itself ---- */

/* w of triangle v at p (Van Oosterom and Strackee), here as the oracle. */
static double tri_w(const double v[3][3], const double p[3])
{
    double a[3], b[3], c[3];
    for (int i = 0; i < 3; i++) a[i] = v[0][i] - p[i], b[i] = v[1][i] - p[i], c[i] = v[2][i] - p[i];
    double la = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    double lb = sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
    double lc = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    double det = a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) +
                 a[2] * (b[0] * c[1] - b[1] * c[0]);
    double den = la * lb * lc + (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) * lc +
                 (b[0] * c[0] + b[1] * c[1] + b[2] * c[2]) * la +
                 (c[0] * a[0] + c[1] * a[1] + c[2] * a[2]) * lb;
    return atan2(det, den) / (2 * M_PI);
}

/* The bound tests' shape: a wavy fan of FAN triangles about (0.3, -0.2,
 * 0.1), a cap as mesh_wcap.c makes. */
enum { FAN = 48 };

static void wavy_fan(double tri[FAN][3][3])
{
    for (int k = 0; k < FAN; k++) {
        double a0 = 2 * M_PI * k / FAN, a1 = 2 * M_PI * (k + 1) / FAN;
        double r0 = 6 + sin(3 * a0), r1 = 6 + sin(3 * a1);
        double p0[3] = {r0 * cos(a0), r0 * sin(a0), 0.7 * sin(2 * a0)};
        double p1[3] = {r1 * cos(a1), r1 * sin(a1), 0.7 * sin(2 * a1)};
        for (int i = 0; i < 3; i++) tri[k][0][i] = p1[i], tri[k][1][i] = p0[i];
        tri[k][2][0] = 0.3, tri[k][2][1] = -0.2, tri[k][2][2] = 0.1;
    }
}

/* mesh_vox_cell_box counts a cell's bits as mesh_vox_cell_count does and
 * shrinks the cell to their bounding box, against a sample-by-sample scan:
 * sparse random bits (a few a cell, on rows and slices in any order, so a
 * box taken from the last row seen would be wrong) and cells of every
 * shape within a word's row, empty ones included. */
Test(mesh_wind, a_cell_shrinks_to_the_box_of_its_samples)
{
    mesh_vox_block b = {{-70, 5, 1000}, {128, 40, 36}, 2};
    size_t nw = mesh_vox_block_words(&b);
    uint64_t *bits = calloc(nw, sizeof *bits);
    cr_assert(bits);
    uint64_t seed = 12345;
    for (int k = 0; k < 600; k++) {
        seed = seed * 6364136223846793005ull + 1442695040888963407ull;
        uint32_t x = (uint32_t)(seed >> 33) % 128, y = (uint32_t)(seed >> 20) % 40,
                 z = (uint32_t)(seed >> 45) % 36;
        bits[mesh_vox_word(&b, x, y, z)] |= 1ull << (x & 63);
    }
    int boxes = 0, empty = 0;
    for (int k = 0; k < 4000; k++) {
        uint32_t lo[3], hi[3], blo[3] = {0}, bhi[3] = {0};
        seed = seed * 6364136223846793005ull + 1442695040888963407ull;
        uint32_t w = (uint32_t)(seed >> 60) & 1, x0 = (uint32_t)(seed >> 8) % 64;
        lo[0] = 64 * w + x0, hi[0] = lo[0] + 1 + (uint32_t)(seed >> 16) % (64 - x0);
        lo[1] = (uint32_t)(seed >> 24) % 40, hi[1] = lo[1] + 1 + (uint32_t)(seed >> 32) % (40 - lo[1]);
        lo[2] = (uint32_t)(seed >> 40) % 36, hi[2] = lo[2] + 1 + (uint32_t)(seed >> 48) % (36 - lo[2]);
        uint64_t n = 0;
        uint32_t elo[3] = {UINT32_MAX, UINT32_MAX, UINT32_MAX}, ehi[3] = {0, 0, 0};
        for (uint32_t z = lo[2]; z < hi[2]; z++)
            for (uint32_t y = lo[1]; y < hi[1]; y++)
                for (uint32_t x = lo[0]; x < hi[0]; x++) {
                    if (!(bits[mesh_vox_word(&b, x, y, z)] >> (x & 63) & 1)) continue;
                    uint32_t p[3] = {x, y, z};
                    n++;
                    for (int a = 0; a < 3; a++) {
                        elo[a] = p[a] < elo[a] ? p[a] : elo[a];
                        ehi[a] = p[a] + 1 > ehi[a] ? p[a] + 1 : ehi[a];
                    }
                }
        cr_assert_eq(mesh_vox_cell_box(&b, bits, lo, hi, blo, bhi), n);
        cr_assert_eq(mesh_vox_cell_count(&b, bits, lo, hi), n);
        if (!n) {
            empty++;
            continue;
        }
        boxes++;
        for (int a = 0; a < 3; a++)
            cr_assert(blo[a] == elo[a] && bhi[a] == ehi[a], "cell %d axis %d: [%u, %u) not [%u, %u)",
                      k, a, blo[a], bhi[a], elo[a], ehi[a]);
    }
    cr_assert(boxes > 500 && empty > 100, "%d boxes, %d empty cells", boxes, empty);
    free(bits);
}

/* mesh_vox_wind_cell's value at a cell's centre and its bound hold at every
 * point tried within the cell's ball (the expansion's remainder and the
 * variation over the ball: without the latter they would not), with and
 * without a near list (mesh_vox_wind_near adds the near triangles exactly); the
 * test shape is a wavy fan of 48 triangles, a cap as mesh_wcap.c makes. */
Test(mesh_wind, the_cell_bound_holds_within_the_ball)
{
    enum { N = FAN };
    double tri[N][3][3];
    wavy_fan(tri);
    mesh_vox_wtree *t;
    cr_assert_eq(mesh_vox_wtree_make(NULL, NULL, (const double (*)[3][3])tri, N, NULL, &t), 0);
    size_t checked = 0, with_near = 0;
    double worst = 0; /* the largest |w(p) - w(b)| seen: the variation is real */
    for (double rho = 0.8; rho < 4; rho *= 2)
        for (int z = -12; z <= 12; z += 3)
            for (int y = -12; y <= 12; y += 3)
                for (int x = -12; x <= 12; x += 3)
                    for (int use_near = 0; use_near < 2; use_near++) {
                        mesh_vox_wball q = {{x + 0.25, y - 0.35, z + 0.45}, rho, 2e-3, 10};
                        const double *b = q.b;
                        double v, e;
                        mesh_vox_near nr;
                        if (!mesh_vox_wind_cell(t, &q, use_near ? &nr : NULL, &v, &e, NULL)) continue;
                        with_near += use_near && nr.n;
                        for (int d = 0; d < 27; d++) {
                            double p[3] = {b[0] + rho * (d % 3 - 1) / sqrt(3),
                                           b[1] + rho * (d / 3 % 3 - 1) / sqrt(3),
                                           b[2] + rho * (d / 9 - 1) / sqrt(3)};
                            double w = 0, u = v;
                            for (int k = 0; k < N; k++) w += tri_w(tri[k], p);
                            if (use_near && nr.n) {
                                bool close = false;
                                u += mesh_vox_wind_near(t, &nr, p, 1e-3, &close);
                            }
                            cr_assert_leq(fabs(w - u), e, "b (%g %g %g) rho %g: |%g - %g| > %g",
                                          b[0], b[1], b[2], rho, w, u, e);
                            if (!use_near && fabs(w - v) > worst) worst = fabs(w - v);
                            checked++;
                        }
                    }
    cr_log_info("%zu points checked, %zu cells with near triangles, largest variation %.4f",
                checked, with_near, worst);
    cr_assert_gt(checked, 20000);
    cr_assert_gt(with_near, 100);
    cr_assert_gt(worst, 0.01);
    mesh_vox_wtree_free(t);
}

/* The caps' expansion about a cell's centre (mesh_wcap.c's direct path:
 * the exact value, the gradient by Biot and Savart over the boundary, the
 * remainder's bound per boundary segment) holds at every point tried
 * within the cell's ball, on the same wavy fan; and the gradient matters:
 * without it the bound fails at many of the points (so that a wrong sign
 * or a wrong gradient would fail here). */
Test(mesh_wind, the_caps_expansion_holds_within_the_ball)
{
    enum { N = FAN };
    double tri[N][3][3];
    wavy_fan(tri);
    size_t checked = 0, cells = 0, refused = 0, needs_grad = 0;
    for (double rho = 0.8; rho < 7; rho *= 2)
        for (int z = -12; z <= 12; z += 2)
            for (int y = -12; y <= 12; y += 3)
                for (int x = -12; x <= 12; x += 3) {
                    double b[3] = {x + 0.25, y - 0.35, z + 0.45};
                    mesh_vox_cexp e;
                    if (!mesh_vox_wcap_expand((const double (*)[3][3])tri, NULL, N, b, rho, &e)) {
                        refused++;
                        continue;
                    }
                    cells++;
                    for (int d = 0; d < 27; d++) {
                        double q[3] = {rho * (d % 3 - 1) / sqrt(3), rho * (d / 3 % 3 - 1) / sqrt(3),
                                       rho * (d / 9 - 1) / sqrt(3)};
                        double p[3] = {b[0] + q[0], b[1] + q[1], b[2] + q[2]}, w = 0;
                        for (int k = 0; k < N; k++) w += tri_w(tri[k], p);
                        double u = e.v + e.g[0] * q[0] + e.g[1] * q[1] + e.g[2] * q[2];
                        cr_assert_leq(fabs(w - u), e.e, "b (%g %g %g) rho %g: |%g - %g| > %g",
                                      b[0], b[1], b[2], rho, w, u, e.e);
                        needs_grad += fabs(w - e.v) > e.e;
                        checked++;
                    }
                }
    cr_log_info("%zu points in %zu cells checked (%zu cells refused), %zu need the gradient",
                checked, cells, refused, needs_grad);
    cr_assert_gt(checked, 50000);
    cr_assert_gt(refused, 100); /* the cells the fan crosses */
    cr_assert_gt(needs_grad, checked / 10);
}

/* mesh_vox_wind_down (mesh_wcap.c's descent): a cell's far field, handed
 * down to a point of its ball (a query of rho 0 from the cell's list),
 * plus the triangles left near, holds the exact sum within the bound at
 * every point tried, on the same wavy fan; the cells hand nodes and
 * triangles down, and take others whole. */
Test(mesh_wind, the_far_field_handed_down_holds_within_the_ball)
{
    enum { N = FAN, CAP = 256 };
    double tri[N][3][3];
    wavy_fan(tri);
    mesh_vox_wtree *t;
    cr_assert_eq(mesh_vox_wtree_make(NULL, NULL, (const double (*)[3][3])tri, N, NULL, &t), 0);
    static uint32_t room[2][3][CAP];
    uint32_t root = 0;
    mesh_vox_wlist top = {.n_node = 1, .node = &root}, l[2];
    for (int i = 0; i < 2; i++)
        l[i] = (mesh_vox_wlist){.cap = CAP, .node = room[i][0], .tri = room[i][1], .leaf = room[i][2]};
    size_t checked = 0, handed = 0, taken = 0;
    double worst = 0;
    for (double rho = 0.8; rho < 7; rho *= 2)
        for (int z = -12; z <= 12; z += 3)
            for (int y = -12; y <= 12; y += 3)
                for (int x = -12; x <= 12; x += 3) {
                    mesh_vox_wball q = {{x + 0.25, y - 0.35, z + 0.45}, rho, 2e-3, 10};
                    const double *b = q.b;
                    if (!mesh_vox_wind_down(t, &top, &q, &l[0], NULL)) continue;
                    handed += l[0].n_node + l[0].n_tri > 0;
                    taken += l[0].e4 > 0;
                    for (int d = 0; d < 27; d++) {
                        double p[3] = {b[0] + rho * (d % 3 - 1) / sqrt(3),
                                       b[1] + rho * (d / 3 % 3 - 1) / sqrt(3),
                                       b[2] + rho * (d / 9 - 1) / sqrt(3)};
                        mesh_vox_wball qp = {{p[0], p[1], p[2]}, 0, 1e-4, 10};
                        cr_assert(mesh_vox_wind_down(t, &l[0], &qp, &l[1], NULL));
                        cr_assert_eq(l[1].n_node, 0);
                        bool close = false;
                        double w = 0, u = l[1].w4 / (4 * M_PI) +
                                          mesh_vox_wind_tris(t, &(mesh_vox_tris){l[1].tri, l[1].leaf, l[1].n_tri},
                                                             p, 1e-3, &close);
                        /* and the tree's vertices kept as floats (from
                         * their leaf's centre): within 1e-6 here, but
                         * at points close to a triangle (mesh_wcap.c
                         * leaves those to the mesh's tree) */
                        if (close) continue;
                        double e = l[1].e4 / (4 * M_PI) + 1e-6;
                        for (int k = 0; k < N; k++) w += tri_w(tri[k], p);
                        worst = fabs(w - u) > worst ? fabs(w - u) : worst;
                        cr_assert_leq(fabs(w - u), e, "b (%g %g %g) rho %g: |%g - %g| > %g", b[0],
                                      b[1], b[2], rho, w, u, e);
                        checked++;
                    }
                }
    cr_log_info("%zu points checked; %zu cells handed some down, %zu took some whole; "
                "largest difference %.3g", checked, handed, taken, worst);
    cr_assert_gt(checked, 20000);
    cr_assert_gt(handed, 100);
    cr_assert_gt(taken, 100);
    mesh_vox_wtree_free(t);
}

/* ---- samples on a cap: the mesh's exact sum decides ---- */

/* Voxel units (cube_grid(32): 1/16 a voxel, low corner -1) to world. */
static double vw(double u)
{
    return -1 + u / 16;
}

/* The tent: four triangles from an apex below to a skew quadrilateral
 * hole v0 v1 v2 v3 (voxel units) whose vertices average to o = (16, 16,
 * 16.5), so that mesh_wcap.c's cap, the fan (b, a, o) of each boundary
 * edge a -> b, holds the triangle v1 v0 o in the plane z = 16.5 of
 * voxel centres, and its spokes o v0 (x = y) and o v1 (x + y = 32) run
 * through voxel centres; no centre lies on the tent itself (its planes
 * miss every centre).  Then a small closed icosphere far from it, so
 * that the triangles are many and the caps' exact sum is tried before
 * the mesh's tree (mesh_wcap.c's EXACT_WORK). */
static const double TENT[5][3] = {{8, 8, 16.5}, {24, 8, 16.5}, {24, 24, 20.5}, {8, 24, 12.5},
                                  {16, 16, 6.5}};

static const mesh *tent_and_ball(shape *s)
{
    shape_init(s);
    uint32_t v[5];
    for (int i = 0; i < 5; i++) v[i] = shape_vertex(s, vw(TENT[i][0]), vw(TENT[i][1]), vw(TENT[i][2]));
    for (int i = 0; i < 4; i++) shape_tri(s, v[i], v[(i + 1) % 4], v[4]);
    double c[3] = {vw(4.2), vw(4.1), vw(27.9)};
    shape_icosphere(s, c, 3.0 / 16, 3, false);
    return shape_finish(s);
}

/* The distance from p to triangle t (all voxel units): brute force over
 * the plane's foot and the three edges. */
static double tri_dist(const double t[3][3], const double p[3])
{
    double e1[3], e2[3], n[3], d[3], best = INFINITY;
    for (int a = 0; a < 3; a++) e1[a] = t[1][a] - t[0][a], e2[a] = t[2][a] - t[0][a], d[a] = p[a] - t[0][a];
    n[0] = e1[1] * e2[2] - e1[2] * e2[1], n[1] = e1[2] * e2[0] - e1[0] * e2[2],
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    double nn = n[0] * n[0] + n[1] * n[1] + n[2] * n[2], h = (d[0] * n[0] + d[1] * n[1] + d[2] * n[2]) / nn;
    double f[3] = {p[0] - h * n[0], p[1] - h * n[1], p[2] - h * n[2]}; /* the foot */
    bool in = true;
    for (int i = 0; i < 3; i++) { /* the foot on the inner side of every edge */
        const double *a = t[i], *b = t[(i + 1) % 3];
        double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, w[3] = {f[0] - a[0], f[1] - a[1], f[2] - a[2]};
        double x[3] = {u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0]};
        in = in && x[0] * n[0] + x[1] * n[1] + x[2] * n[2] >= 0;
    }
    if (in) return fabs(h) * sqrt(nn);
    for (int i = 0; i < 3; i++) {
        const double *a = t[i], *b = t[(i + 1) % 3];
        double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, uu = 0, s = 0, q = 0;
        for (int k = 0; k < 3; k++) uu += u[k] * u[k], s += (p[k] - a[k]) * u[k];
        s = s < 0 ? 0 : s > uu ? 1 : s / uu;
        for (int k = 0; k < 3; k++) q += (p[k] - a[k] - s * u[k]) * (p[k] - a[k] - s * u[k]);
        best = sqrt(q) < best ? sqrt(q) : best;
    }
    return best;
}

/* The winding number of every triangle of m at p (voxel units of
 * cube_grid(32)), summed here: the oracle. */
static double brute_w(const mesh *m, const double p[3])
{
    double w = 0;
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        double v[3][3];
        for (int i = 0; i < 3; i++)
            for (int a = 0; a < 3; a++) v[i][a] = ((double)m->vertices[m->triangles[t][i]][a] + 1) * 16;
        w += tri_w(v, p);
    }
    return w;
}

/* dense() through the caps' tree (tree 1) or the direct path (0), with
 * *spared the samples sent on to the mesh's exact sum meanwhile. */
static uint8_t *dense_counted(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
                              int tree, uint64_t *spared)
{
    mesh_tile_stats st;
    mesh_wcap_tree_only = tree;
    uint64_t before = atomic_load(&mesh_wcap_to_exact);
    uint8_t *d = dense(m, g, o, &st);
    *spared = atomic_load(&mesh_wcap_to_exact) - before;
    mesh_wcap_tree_only = 0;
    return d;
}

/* The cap's triangle of edge a -> b: (b, a, o), as mesh_wcap.c makes it. */
static bool on_tent_cap(const double p[3])
{
    const double o[3] = {16, 16, 16.5};
    for (int i = 0; i < 4; i++) {
        double t[3][3];
        memcpy(t[0], TENT[(i + 1) % 4], sizeof t[0]);
        memcpy(t[1], TENT[i], sizeof t[1]);
        memcpy(t[2], o, sizeof t[2]);
        if (tri_dist(t, p) <= 1e-12) return true;
    }
    return false;
}

/* Samples lying on a cap triangle (inside it and on its spokes) leave
 * the caps' exact sum, whose angle there has no sign, for the mesh's
 * exact sum: each such voxel is inside exactly when the generalized
 * winding number summed here over every triangle (tri_w, the oracle) has
 * |w| >= 1/2; the direct path and the caps' tree alike, and the fallback
 * counted (mesh_wcap_to_exact) at least once a sample. */
Test(mesh_wind, samples_on_a_cap_go_to_the_mesh_exact_sum, .timeout = 600)
{
    shape s;
    const mesh *m = tent_and_ball(&s);
    grid_spec g = cube_grid(32);
    mesh_vox_opts o = {MESH_SOLID, MESH_REPAIR_WINDING, VOXEL_CH_OCCUPANCY, 0, 0};
    for (int tree = 0; tree < 2; tree++) {
        uint64_t spared;
        uint8_t *d = dense_counted(m, &g, &o, tree, &spared);
        size_t on = 0, wrong = 0, inside = 0;
        for (uint32_t z = 0; z < 32; z++)
            for (uint32_t y = 0; y < 32; y++)
                for (uint32_t x = 0; x < 32; x++) {
                    double p[3] = {x + 0.5, y + 0.5, z + 0.5};
                    if (!on_tent_cap(p)) continue;
                    double w = brute_w(m, p);
                    cr_assert_gt(fabs(fabs(w) - 0.5), 1e-6, "(%u %u %u): |w| %.12f", x, y, z, w);
                    bool want = fabs(w) >= 0.5, got = d[((size_t)z * 32 + y) * 32 + x] != 0;
                    if (got != want)
                        cr_log_error("tree %d: (%u %u %u) w %.6f, voxel %d", tree, x, y, z, w, got);
                    on++, wrong += got != want, inside += want;
                }
        cr_log_info("tree %d: %zu samples on the cap (%zu inside), %zu wrong; %llu to the exact sum",
                    tree, on, inside, wrong, (unsigned long long)spared);
        cr_expect_eq(wrong, 0, "tree %d: %zu of %zu samples on the cap wrong", tree, wrong, on);
        cr_expect_geq(on, 60, "tree %d: only %zu samples on the cap", tree, on);
        cr_expect_gt(inside, 0, "tree %d: none inside", tree);
        cr_expect_lt(inside, on, "tree %d: all inside", tree);
        cr_expect_geq(spared, on, "tree %d: %llu samples to the exact sum for %zu on the cap", tree,
                      (unsigned long long)spared, on);
        free(d);
    }
    shape_free(&s);
}

/* Three faces of a box about the voxel centre p = (16.5, 16.5, 16.5),
 * x = lo, x = hi and y = hi (an extra vertex on the x = lo face's edge
 * takes the caps' fan point off p): by symmetry each face subtends a
 * sixth of the sphere from p, so |w(p)| = 1/2 on the voxelizer's lattice.
 * Then corners move by less than the lattice's step: UP and DOWN, corner
 * (hi, hi, hi) by a quarter step along z (the raster and the caps see the
 * same mesh both times, |w| = 1/2 exactly there; the mesh as given |w| =
 * 1/2 +- 2e-8); APART, three corners so that the lattice's mesh has |w| =
 * 1/2 + 8.5e-8 and the given one 1/2 - 2e-8 (the caps' angles, from
 * the lattice's vertices as the raster's sides want, err by more than
 * 1e-9).  The small icosphere makes the triangles many (mesh_wcap.c's
 * EXACT_WORK). */
enum { UP, DOWN, APART }; /* three_faces' moves */

static const mesh *three_faces(shape *s, int move)
{
    shape_init(s);
    uint32_t v[8];
    for (int i = 0; i < 8; i++)
        v[i] = shape_vertex(s, vw(i & 1 ? 24.75 : 8.25), vw(i & 2 ? 24.75 : 8.25), vw(i & 4 ? 24.75 : 8.25));
    uint32_t e = shape_vertex(s, vw(8.25), vw(8.25), vw(12.75)); /* on edge v0 v4 */
    shape_tri(s, v[6], v[2], v[0]); /* x = lo: the polygon v0 e v4 v6 v2, fanned from v6 */
    shape_tri(s, v[6], v[0], e);
    shape_tri(s, v[6], e, v[4]);
    shape_quad(s, v[1], v[3], v[7], v[5]); /* x = hi */
    shape_quad(s, v[2], v[6], v[7], v[3]); /* y = hi */
    const double step = 1.0 / 1048576; /* the lattice's, world units (2^-16 voxel) */
    if (move == APART) { /* the lattice's mesh has |w| > 1/2, the given one < 1/2 */
        s->m.vertices[v[7]][2] = (float)(vw(24.75) + 0.625 * step); /* snapped: + 1 step */
        s->m.vertices[v[3]][2] = (float)(vw(8.25) + 0.4375 * step); /* snapped: no move */
        s->m.vertices[v[5]][0] = (float)(vw(24.75) + 0.4375 * step);
    } else {
        s->m.vertices[v[7]][2] = (float)(vw(24.75) + (move == UP ? 0.25 : -0.25) * step);
    }
    double c[3] = {vw(4.2), vw(4.1), vw(27.9)};
    shape_icosphere(s, c, 3.0 / 16, 3, false);
    return shape_finish(s);
}

/* A sample whose |N - w_C| by the caps' exact sum lies near 1/2 goes to
 * the mesh's exact sum: at p of three_faces, each move, the voxel is what
 * the oracle says, and the answers of UP and DOWN differ (the caps, on
 * the lattice, see |w| = 1/2 both times: a decision from them would be
 * wrong once; APART's from them would be wrong); in the caps' tree and
 * their direct path (which decides p from the given vertices). */
Test(mesh_wind, a_sample_near_one_half_goes_to_the_mesh_exact_sum, .timeout = 600)
{
    static const char *name[] = {"up", "down", "apart"};
    grid_spec g = cube_grid(32);
    mesh_vox_opts o = {MESH_SOLID, MESH_REPAIR_WINDING, VOXEL_CH_OCCUPANCY, 0, 0};
    const double p[3] = {16.5, 16.5, 16.5};
    bool want[3];
    for (int k = UP; k <= APART; k++) {
        shape s;
        const mesh *m = three_faces(&s, k);
        double w = brute_w(m, p);
        cr_log_info("%s: |w(p)| - 1/2 = %.3g", name[k], fabs(w) - 0.5);
        cr_assert_gt(fabs(fabs(w) - 0.5), 1e-12, "%s: the oracle undecided: |w| %.17g", name[k], w);
        cr_assert_lt(fabs(fabs(w) - 0.5), 1e-7, "%s: |w| %.17g: not near 1/2", name[k], w);
        want[k] = fabs(w) >= 0.5;
        for (int tree = 0; tree < 2; tree++) {
            uint64_t spared;
            uint8_t *d = dense_counted(m, &g, &o, tree, &spared);
            bool got = d[(16 * 32 + 16) * 32 + 16] != 0;
            cr_expect_eq(got, want[k], "%s, tree %d: voxel %d, |w| %.17g", name[k], tree, got, w);
            cr_expect(!tree || spared >= 1, "%s: nothing to the exact sum", name[k]);
            free(d);
        }
        shape_free(&s);
    }
    cr_expect_neq(want[UP], want[DOWN], "the oracle's answers: the move does not matter");
    cr_expect(!want[APART], "apart: the oracle inside");
}
