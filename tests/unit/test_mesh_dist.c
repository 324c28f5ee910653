/* The distance channel of the mesh voxelizer (mesh_dist.c) against an
 * oracle written here: the distance from every voxel centre to every
 * triangle near it, by another method (the centre projected on the
 * triangle's plane, inside by its barycentric coordinates, else the
 * nearest of the three edges), in world units.  On closed shapes at 64^3
 * and 128^3: every voxel within the band within 1e-5 voxel of the oracle,
 * every voxel beyond it exactly the band's width, every sign the
 * occupancy solid's; the band's bricks and the rest as the volume holds
 * them (uniform bricks beyond the band, none empty inside the grid). */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "grid.h"
#include "mesh_shapes.h"
#include "mesh_vox.h"
#include "vod_volume.h"
#include "voxel.h"

static grid_spec cube_grid(uint32_t res)
{
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    grid_spec g;
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, res, &g, &err), 0, "%s", err.msg);
    return g;
}

static size_t nvox(const grid_spec *g)
{
    return (size_t)g->res[0] * g->res[1] * g->res[2];
}

static size_t vidx(const grid_spec *g, uint32_t x, uint32_t y, uint32_t z)
{
    return ((size_t)z * g->res[1] + y) * g->res[0] + x;
}

/* Every voxel of m for o, serially, as a dense array of the volume's
 * values; the volume's info in *in. */
static uint32_t *voxelize(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
                          vod_volume_info *in)
{
    size_t bytes = vod_volume_bytes(g->res, mesh_vox_bits(o), mesh_vox_sbrick(o), UINT32_MAX);
    void *arena = malloc(bytes);
    vod_volume *v;
    cr_assert_eq(vod_volume_init(&v, arena, bytes, g->res, mesh_vox_bits(o), mesh_vox_sbrick(o)), 0);
    mesh_tile_stats st = {0};
    cr_assert_eq(mesh_voxelize(m, g, o, v, &st), 0);
    uint32_t *d = malloc(nvox(g) * sizeof *d);
    for (uint32_t z = 0; z < g->res[2]; z++)
        for (uint32_t y = 0; y < g->res[1]; y++)
            for (uint32_t x = 0; x < g->res[0]; x++)
                d[vidx(g, x, y, z)] = vod_volume_get(v, x, y, z);
    if (in) vod_volume_get_info(v, in);
    free(arena);
    return d;
}

/* ---- the oracle ---- */

static double dot(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* Distance from p to the segment [a, b]. */
static double seg_dist(const double p[3], const double a[3], const double b[3])
{
    double ab[3], ap[3];
    for (int i = 0; i < 3; i++) ab[i] = b[i] - a[i], ap[i] = p[i] - a[i];
    double t = dot(ap, ab) / dot(ab, ab);
    if (!(t > 0)) t = 0;
    if (t > 1) t = 1;
    double q[3];
    for (int i = 0; i < 3; i++) q[i] = ap[i] - t * ab[i];
    return sqrt(dot(q, q));
}

/* Distance from p to triangle (a, b, c): the foot of the perpendicular on
 * its plane when its barycentric coordinates are all >= 0, else the
 * nearest edge. */
static double tri_dist(const double p[3], const double a[3], const double b[3],
                       const double c[3])
{
    double u[3], v[3], w[3], n[3];
    for (int i = 0; i < 3; i++) u[i] = b[i] - a[i], v[i] = c[i] - a[i], w[i] = p[i] - a[i];
    n[0] = u[1] * v[2] - u[2] * v[1];
    n[1] = u[2] * v[0] - u[0] * v[2];
    n[2] = u[0] * v[1] - u[1] * v[0];
    double nn = dot(n, n), h = dot(w, n) / nn, f[3];
    for (int i = 0; i < 3; i++) f[i] = w[i] - h * n[i]; /* the foot, from a */
    /* barycentric coordinates of the foot by the areas' signs */
    double uu = dot(u, u), uv = dot(u, v), vv = dot(v, v), fu = dot(f, u), fv = dot(f, v);
    double den = uu * vv - uv * uv, s = (vv * fu - uv * fv) / den, t = (uu * fv - uv * fu) / den;
    if (s >= 0 && t >= 0 && s + t <= 1) return fabs(h) * sqrt(nn);
    double d = seg_dist(p, a, b), e = seg_dist(p, b, c), g = seg_dist(p, c, a);
    return fmin(d, fmin(e, g));
}

/* The unsigned distance of every voxel centre within K voxels of some
 * triangle (the rest: +infinity), each triangle visiting the voxels of its
 * box grown by K (a voxel outside every grown box is further than K from
 * every triangle). */
static double *oracle(const mesh *m, const grid_spec *g, uint32_t K)
{
    double *d = malloc(nvox(g) * sizeof *d);
    for (size_t i = 0; i < nvox(g); i++) d[i] = INFINITY;
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        double P[3][3];
        int64_t lo[3], hi[3];
        for (int k = 0; k < 3; k++)
            for (int a = 0; a < 3; a++) P[k][a] = m->vertices[m->triangles[t][k]][a];
        for (int a = 0; a < 3; a++) {
            double l = fmin(P[0][a], fmin(P[1][a], P[2][a])), h = fmax(P[0][a], fmax(P[1][a], P[2][a]));
            lo[a] = (int64_t)floor((l - g->lo[a]) / g->vs - K) - 1;
            hi[a] = (int64_t)ceil((h - g->lo[a]) / g->vs + K) + 1;
            if (lo[a] < 0) lo[a] = 0;
            if (hi[a] > (int64_t)g->res[a] - 1) hi[a] = (int64_t)g->res[a] - 1;
        }
        for (int64_t z = lo[2]; z <= hi[2]; z++)
            for (int64_t y = lo[1]; y <= hi[1]; y++)
                for (int64_t x = lo[0]; x <= hi[0]; x++) {
                    double p[3] = {grid_coord(g, 0, (double)x + 0.5), grid_coord(g, 1, (double)y + 0.5),
                                   grid_coord(g, 2, (double)z + 0.5)};
                    double e = tri_dist(p, P[0], P[1], P[2]);
                    size_t i = vidx(g, (uint32_t)x, (uint32_t)y, (uint32_t)z);
                    if (e < d[i]) d[i] = e;
                }
    }
    return d;
}

static float as_float(uint32_t u)
{
    float f;
    memcpy(&f, &u, 4);
    return f;
}

/* Mesh m at res with band K: the distance against the oracle, the signs
 * against the occupancy solid. */
static void check_distance(const mesh *m, uint32_t res, uint32_t K, mesh_repair rep)
{
    grid_spec g = cube_grid(res);
    mesh_vox_opts od = {MESH_SOLID, rep, VOXEL_CH_DISTANCE, 0, K};
    mesh_vox_opts oo = {MESH_SOLID, rep, VOXEL_CH_OCCUPANCY, 0, 0};
    err_info err = {0};
    cr_assert_eq(mesh_vox_check(&od, &err), 0, "%s", err.msg);
    vod_volume_info in;
    uint32_t *dist = voxelize(m, &g, &od, &in), *occ = voxelize(m, &g, &oo, NULL);
    double *want = oracle(m, &g, K);
    float w = (float)(K * g.vs);
    cr_assert_eq(mesh_dist_width(&od, g.vs), w);
    size_t band = 0, beyond = 0, inside = 0;
    double worst = 0;
    for (size_t i = 0; i < nvox(&g); i++) {
        float v = as_float(dist[i]);
        bool in_solid = occ[i] != 0;
        inside += in_solid;
        cr_assert_eq(signbit(v) != 0, in_solid, "voxel %zu: %g, solid %d", i, (double)v,
                     in_solid);
        double o = want[i] / g.vs, got = fabs((double)v) / g.vs;
        if (o < K - 1e-6) { /* in the band: within 1e-5 voxel */
            band++;
            double e = fabs(got - o);
            if (e > worst) worst = e;
            cr_assert(e <= 1e-5, "voxel %zu: %.9f voxels, the oracle %.9f", i, got, o);
        } else if (o > K + 1e-6) { /* beyond: the band's width exactly */
            beyond++;
            cr_assert_eq(fabsf(v), w, "voxel %zu: %.9g, not the width %.9g", i, (double)v,
                         (double)w);
        }
    }
    cr_assert_gt(band, 1000, "a band: %zu voxels", band);
    cr_assert_gt(beyond, band, "space beyond the band: %zu voxels", beyond);
    cr_assert_gt(inside, 1000);
    /* memory for the band's bricks alone: the rest are uniform entries */
    uint64_t side = (res + in.sbrick - 1) / in.sbrick, bricks = side * side * side;
    cr_assert_lt(in.level0_bricks, bricks, "%u bricks with memory of %llu", in.level0_bricks,
                 (unsigned long long)bricks);
    cr_log_info("res %u band %u: %zu band voxels, worst %.3g voxel, %u of %llu bricks stored",
                res, K, band, worst, in.level0_bricks, (unsigned long long)bricks);
    free(dist), free(occ), free(want);
}

Test(mesh_dist, icosphere_against_the_oracle)
{
    shape s;
    shape_init(&s);
    double c[3] = {0.021, -0.013, 0.007};
    shape_icosphere(&s, c, 0.7, 3, false);
    const mesh *m = shape_finish(&s);
    check_distance(m, 64, 3, MESH_REPAIR_NONE);
    check_distance(m, 128, 3, MESH_REPAIR_NONE);
    check_distance(m, 64, 1, MESH_REPAIR_NONE);
    shape_free(&s);
}

Test(mesh_dist, torus_against_the_oracle)
{
    shape s;
    shape_init(&s);
    double c[3] = {0.021, -0.013, 0.007};
    shape_torus(&s, c, 0.55, 0.2, 40, 20);
    const mesh *m = shape_finish(&s);
    check_distance(m, 64, 3, MESH_REPAIR_NONE);
    check_distance(m, 128, 3, MESH_REPAIR_NONE);
    check_distance(m, 64, 5, MESH_REPAIR_WINDING);
    shape_free(&s);
}

Test(mesh_dist, box_against_the_oracle)
{
    shape s;
    shape_init(&s);
    double lo[3] = {-0.61, -0.37, -0.52}, hi[3] = {0.58, 0.49, 0.33};
    shape_box(&s, lo, hi);
    const mesh *m = shape_finish(&s);
    check_distance(m, 64, 3, MESH_REPAIR_NONE);
    check_distance(m, 128, 3, MESH_REPAIR_VOTE);
    shape_free(&s);
}

/* A grid that is not a whole number of tiles or bricks (res 72 on the
 * long axis, fewer on the others): the bricks at the grid's edge hold 0
 * past it and the distances inside. */
Test(mesh_dist, a_grid_of_partial_bricks)
{
    shape s;
    shape_init(&s);
    double c[3] = {0.1, 0, 0};
    shape_icosphere(&s, c, 0.5, 2, false);
    const mesh *m = shape_finish(&s);
    double lo[3] = {-0.8, -0.7, -0.6}, hi[3] = {1.0, 0.7, 0.6};
    grid_spec g;
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, 72, &g, &err), 0, "%s", err.msg);
    mesh_vox_opts od = {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_DISTANCE, 0, 0};
    mesh_vox_opts oo = {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_OCCUPANCY, 0, 0};
    uint32_t *dist = voxelize(m, &g, &od, NULL), *occ = voxelize(m, &g, &oo, NULL);
    double *want = oracle(m, &g, VOXEL_BAND_DEFAULT);
    for (size_t i = 0; i < nvox(&g); i++) {
        float v = as_float(dist[i]);
        cr_assert_eq(signbit(v) != 0, occ[i] != 0, "voxel %zu", i);
        double o = want[i] / g.vs, got = fabs((double)v) / g.vs;
        if (o < VOXEL_BAND_DEFAULT - 1e-6) cr_assert(fabs(got - o) <= 1e-5, "voxel %zu", i);
        else if (o > VOXEL_BAND_DEFAULT + 1e-6)
            cr_assert_eq(fabsf(v), (float)(VOXEL_BAND_DEFAULT * g.vs), "voxel %zu", i);
    }
    free(dist), free(occ), free(want);
    shape_free(&s);
}

Test(mesh_dist, options_are_checked)
{
    err_info err = {0};
    mesh_vox_opts ok = {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_DISTANCE, 0, 0};
    cr_assert_eq(mesh_vox_check(&ok, &err), 0);
    cr_assert_eq(mesh_vox_bits(&ok), VOD_VOLUME_F32);
    cr_assert_eq(mesh_vox_band(&ok), VOXEL_BAND_DEFAULT);
    ok.band = VOXEL_BAND_MAX;
    cr_assert_eq(mesh_vox_check(&ok, &err), 0);
    mesh_vox_opts bad[] = {
        {MESH_SURFACE, MESH_REPAIR_NONE, VOXEL_CH_DISTANCE, 0, 0},
        {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_DISTANCE, 0, VOXEL_BAND_MAX + 1},
        {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_OCCUPANCY, 0, 3},
    };
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        err.msg[0] = 0;
        cr_expect_eq(mesh_vox_check(&bad[i], &err), -EINVAL, "case %zu", i);
        cr_expect_neq(err.msg[0], 0);
    }
}
