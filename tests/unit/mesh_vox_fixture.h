/* mesh_vox_fixture — what the mesh voxelizer's suites (test_mesh_vox*.c) share:
 * grids, a dense volume voxelized, small vector helpers, and the surface oracle
 * (the separating axis theorem on every voxel box) that the solid's checks run
 * too. */
#ifndef VOXD_TEST_MESH_VOX_FIXTURE_H
#define VOXD_TEST_MESH_VOX_FIXTURE_H

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

/* ---- grids, volumes, dense copies ---- */

/* The cube [-1, 1]^3 at res voxels a side (voxel size 2 / res, a power of
 * two for the res used here). */
static inline grid_spec cube_grid(uint32_t res)
{
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    grid_spec g;
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, res, &g, &err), 0, "%s", err.msg);
    cr_assert_eq(g.res[0], res);
    return g;
}

typedef struct {
    void *arena;
    vod_volume *v;
} tvol;

static inline tvol vol_make(const grid_spec *g, uint32_t bits, uint32_t sbrick)
{
    tvol r;
    size_t bytes = vod_volume_bytes(g->res, bits, sbrick, UINT32_MAX);
    cr_assert_gt(bytes, 0);
    r.arena = malloc(bytes);
    cr_assert_not_null(r.arena);
    cr_assert_eq(vod_volume_init(&r.v, r.arena, bytes, g->res, bits, sbrick), 0);
    return r;
}

static inline size_t nvox(const grid_spec *g)
{
    return (size_t)g->res[0] * g->res[1] * g->res[2];
}

static inline size_t vidx(const grid_spec *g, uint32_t x, uint32_t y, uint32_t z)
{
    return ((size_t)z * g->res[1] + y) * g->res[0] + x;
}

/* Every voxel of mesh m for options o, serially, as a dense array. */
static inline uint32_t *voxelize(const mesh *m, const grid_spec *g, const mesh_vox_opts *o,
                                 uint32_t sbrick, mesh_tile_stats *st)
{
    tvol v = vol_make(g, mesh_vox_bits(o), sbrick);
    mesh_tile_stats s = {0};
    cr_assert_eq(mesh_voxelize(m, g, o, v.v, &s), 0);
    uint32_t *d = malloc(nvox(g) * sizeof *d);
    cr_assert_not_null(d);
    for (uint32_t z = 0; z < g->res[2]; z++)
        for (uint32_t y = 0; y < g->res[1]; y++)
            for (uint32_t x = 0; x < g->res[0]; x++)
                d[vidx(g, x, y, z)] = vod_volume_get(v.v, x, y, z);
    free(v.arena);
    if (st) *st = s;
    return d;
}

static inline uint32_t *voxelize_mode(const mesh *m, const grid_spec *g, mesh_mode mode,
                                      mesh_repair rep, mesh_tile_stats *st)
{
    mesh_vox_opts o = {mode, rep, VOXEL_CH_OCCUPANCY, 0, 0};
    return voxelize(m, g, &o, 16, st);
}

static inline double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static inline void cross3(const double a[3], const double b[3], double r[3])
{
    r[0] = a[1] * b[2] - a[2] * b[1];
    r[1] = a[2] * b[0] - a[0] * b[2];
    r[2] = a[0] * b[1] - a[1] * b[0];
}

static inline void vert(const mesh *m, uint32_t t, int i, double p[3])
{
    const float *v = m->vertices[m->triangles[t][i]];
    p[0] = v[0], p[1] = v[1], p[2] = v[2];
}

/* ---- surface ---- */

/* Separating axis test of triangle tr against the closed box [b0, b1]. */
static inline bool sat_touch(const mesh *m, uint32_t tr, const double b0[3], const double b1[3])
{
    double c[3], h[3], v[3][3], e[3][3], n[3];
    for (int a = 0; a < 3; a++) c[a] = (b0[a] + b1[a]) / 2, h[a] = (b1[a] - b0[a]) / 2;
    for (int i = 0; i < 3; i++) {
        vert(m, tr, i, v[i]);
        for (int a = 0; a < 3; a++) v[i][a] -= c[a];
    }
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++) e[i][a] = v[(i + 1) % 3][a] - v[i][a];
    double axes[13][3];
    int na = 0;
    for (int a = 0; a < 3; a++) {
        double u[3] = {0, 0, 0};
        u[a] = 1;
        memcpy(axes[na++], u, sizeof u);
        for (int i = 0; i < 3; i++) cross3(u, e[i], axes[na++]);
    }
    cross3(e[0], e[1], n);
    memcpy(axes[na++], n, sizeof n);
    for (int k = 0; k < na; k++) {
        const double *L = axes[k];
        double p0 = dot3(v[0], L), p1 = dot3(v[1], L), p2 = dot3(v[2], L);
        double lo = fmin(p0, fmin(p1, p2)), hi = fmax(p0, fmax(p1, p2));
        double r = h[0] * fabs(L[0]) + h[1] * fabs(L[1]) + h[2] * fabs(L[2]);
        if (lo > r || hi < -r) return false;
    }
    return true;
}

/* The voxels the triangles touch, by the separating axis test. */
static inline uint8_t *sat_surface(const mesh *m, const grid_spec *g)
{
    uint8_t *d = calloc(nvox(g), 1);
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        int i0[3], i1[3];
        for (int a = 0; a < 3; a++) {
            double lo = INFINITY, hi = -INFINITY;
            for (int i = 0; i < 3; i++) {
                double p[3];
                vert(m, t, i, p);
                lo = fmin(lo, p[a]), hi = fmax(hi, p[a]);
            }
            i0[a] = (int)floor((lo - g->lo[a]) / g->vs) - 1;
            i1[a] = (int)floor((hi - g->lo[a]) / g->vs) + 1;
            if (i0[a] < 0) i0[a] = 0;
            if (i1[a] > (int)g->res[a] - 1) i1[a] = (int)g->res[a] - 1;
        }
        for (int z = i0[2]; z <= i1[2]; z++)
            for (int y = i0[1]; y <= i1[1]; y++)
                for (int x = i0[0]; x <= i1[0]; x++) {
                    double b0[3] = {grid_coord(g, 0, x), grid_coord(g, 1, y), grid_coord(g, 2, z)};
                    double b1[3] = {grid_coord(g, 0, x + 1), grid_coord(g, 1, y + 1),
                                    grid_coord(g, 2, z + 1)};
                    if (sat_touch(m, t, b0, b1)) d[vidx(g, (uint32_t)x, (uint32_t)y, (uint32_t)z)] = 1;
                }
    }
    return d;
}

static inline void check_surface_modes(const mesh *m, uint32_t res)
{
    grid_spec g = cube_grid(res);
    uint8_t *want = sat_surface(m, &g);
    uint32_t *s26 = voxelize_mode(m, &g, MESH_SURFACE, MESH_REPAIR_NONE, NULL);
    uint32_t *s6 = voxelize_mode(m, &g, MESH_SURFACE6, MESH_REPAIR_NONE, NULL);
    uint32_t *sol = voxelize_mode(m, &g, MESH_SOLID, MESH_REPAIR_NONE, NULL);
    uint32_t *con = voxelize_mode(m, &g, MESH_CONSERVATIVE, MESH_REPAIR_NONE, NULL);
    uint32_t *in = voxelize_mode(m, &g, MESH_INTERIOR, MESH_REPAIR_NONE, NULL);
    size_t wrong = 0, not_sub = 0, sets = 0, n26 = 0, n6 = 0, gaps = 0;
    for (size_t i = 0; i < nvox(&g); i++) {
        bool a = s26[i] != 0, b = s6[i] != 0, so = sol[i] != 0;
        if (a != (want[i] != 0) && wrong++ < 5) cr_log_error("voxel %zu: %d, SAT %d", i, a, want[i]);
        not_sub += b && !a;
        sets += (con[i] != 0) != (so || a);
        sets += (in[i] != 0) != (so && !a);
        n26 += a, n6 += b;
    }
    /* 6-separating: of two face-adjacent voxels whose centres lie on either
     * side, one is in surface6 */
    for (uint32_t z = 0; z < res; z++)
        for (uint32_t y = 0; y < res; y++)
            for (uint32_t x = 0; x < res; x++) {
                size_t i = vidx(&g, x, y, z);
                size_t nb[3] = {x + 1 < res ? vidx(&g, x + 1, y, z) : i,
                                y + 1 < res ? vidx(&g, x, y + 1, z) : i,
                                z + 1 < res ? vidx(&g, x, y, z + 1) : i};
                for (int k = 0; k < 3; k++)
                    gaps += (sol[i] != 0) != (sol[nb[k]] != 0) && !s6[i] && !s6[nb[k]];
            }
    cr_expect_eq(wrong, 0, "%zu voxels differ from the SAT", wrong);
    cr_expect_eq(not_sub, 0, "%zu surface6 voxels outside surface", not_sub);
    cr_expect_eq(sets, 0, "conservative / interior differ from the set operations");
    cr_expect_eq(gaps, 0, "%zu face-adjacent in/out pairs without a surface6 voxel", gaps);
    cr_expect_gt(n6, 0);
    cr_expect_lt(n6, n26, "surface6 (%zu) is thinner than surface (%zu)", n6, n26);
    free(want), free(s26), free(s6), free(sol), free(con), free(in);
}

#endif
