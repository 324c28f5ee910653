/* The mesh voxelizer (mesh_vox.h) against oracles written here:
 * - solid: a ray from every voxel centre in the generic direction (1, 0.37,
 *   0.21), its crossings counted by Möller–Trumbore in double (another
 *   algorithm, another direction), at 64^3 and 128^3;
 * - the top-left rule: a box whose faces, edges and corners lie exactly on
 *   voxel centres: every column crossed 0 or 2 times, the inside exactly the
 *   half-open box of centres, the three parities equal;
 * - density: the sum against the mesh's volume; normals of a sphere; options.
 * The surface modes, holes, tiles and bins: test_mesh_vox_surface.c.  The shapes
 * (mesh_shapes.h) have vertices on the voxelizer's lattice, so the oracles see
 * the very mesh that is voxelized. */
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

static void centre(const grid_spec *g, uint32_t x, uint32_t y, uint32_t z, double c[3])
{
    c[0] = grid_coord(g, 0, x + 0.5);
    c[1] = grid_coord(g, 1, y + 0.5);
    c[2] = grid_coord(g, 2, z + 0.5);
}

/* ---- the ray oracle: crossings along a generic direction ---- */

typedef struct {
    const mesh *m;
    double d[3], e1[3], e2[3];  /* direction and a basis across it */
    double lo[2], cell;         /* 2D grid of the projections */
    int G;
    uint32_t *start, *list;     /* triangles per cell */
} ray_oracle;

static void cell_range(const ray_oracle *o, const double s[2], int c[2])
{
    for (int a = 0; a < 2; a++) {
        int i = (int)floor((s[a] - o->lo[a]) / o->cell);
        c[a] = i < 0 ? 0 : i >= o->G ? o->G - 1 : i;
    }
}

static void oracle_init(ray_oracle *o, const mesh *m)
{
    double d[3] = {1, 0.37, 0.21}, l = sqrt(dot3(d, d)), up[3] = {0, 0, 1};
    for (int a = 0; a < 3; a++) o->d[a] = d[a] / l;
    cross3(o->d, up, o->e1);
    l = sqrt(dot3(o->e1, o->e1));
    for (int a = 0; a < 3; a++) o->e1[a] /= l;
    cross3(o->d, o->e1, o->e2);
    o->m = m;
    o->G = 96;
    double lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (uint32_t t = 0; t < m->n_triangles; t++)
        for (int i = 0; i < 3; i++) {
            double p[3];
            vert(m, t, i, p);
            double s[2] = {dot3(p, o->e1), dot3(p, o->e2)};
            for (int a = 0; a < 2; a++) lo[a] = fmin(lo[a], s[a]), hi[a] = fmax(hi[a], s[a]);
        }
    o->lo[0] = lo[0], o->lo[1] = lo[1];
    o->cell = fmax(hi[0] - lo[0], hi[1] - lo[1]) / o->G * 1.0001;
    o->start = calloc((size_t)o->G * o->G + 1, sizeof *o->start);
    for (int pass = 0; pass < 2; pass++) {
        if (pass == 1) {
            for (int i = 0; i < o->G * o->G; i++) o->start[i + 1] += o->start[i];
            o->list = malloc((o->start[o->G * o->G] + 1) * sizeof *o->list);
        }
        uint32_t *cur = pass ? calloc((size_t)o->G * o->G, sizeof *cur) : NULL;
        for (uint32_t t = 0; t < m->n_triangles; t++) {
            double a[2] = {INFINITY, INFINITY}, b[2] = {-INFINITY, -INFINITY};
            for (int i = 0; i < 3; i++) {
                double p[3];
                vert(m, t, i, p);
                double s[2] = {dot3(p, o->e1), dot3(p, o->e2)};
                for (int k = 0; k < 2; k++) a[k] = fmin(a[k], s[k]), b[k] = fmax(b[k], s[k]);
            }
            int c0[2], c1[2];
            cell_range(o, a, c0);
            cell_range(o, b, c1);
            for (int j = c0[1]; j <= c1[1]; j++)
                for (int i = c0[0]; i <= c1[0]; i++) {
                    int c = j * o->G + i;
                    if (pass) o->list[o->start[c] + cur[c]++] = t;
                    else o->start[c + 1]++;
                }
        }
        free(cur);
    }
}

static void oracle_free(ray_oracle *o)
{
    free(o->start);
    free(o->list);
}

/* Möller–Trumbore: the ray c + t d crosses triangle tr at some t > 0. */
static bool mesh_text_hit(const ray_oracle *o, uint32_t tr, const double c[3])
{
    double v0[3], v1[3], v2[3], e1[3], e2[3], p[3], s[3], q[3];
    vert(o->m, tr, 0, v0);
    vert(o->m, tr, 1, v1);
    vert(o->m, tr, 2, v2);
    for (int a = 0; a < 3; a++) e1[a] = v1[a] - v0[a], e2[a] = v2[a] - v0[a], s[a] = c[a] - v0[a];
    cross3(o->d, e2, p);
    double det = dot3(e1, p);
    if (det == 0) return false;
    double u = dot3(s, p) / det;
    if (u < 0 || u > 1) return false;
    cross3(s, e1, q);
    double v = dot3(o->d, q) / det;
    if (v < 0 || u + v > 1) return false;
    return dot3(e2, q) / det > 0;
}

static bool oracle_inside(const ray_oracle *o, const double c[3])
{
    double s[2] = {dot3(c, o->e1), dot3(c, o->e2)};
    int k[2];
    cell_range(o, s, k);
    int cell = k[1] * o->G + k[0], n = 0;
    for (uint32_t i = o->start[cell]; i < o->start[cell + 1]; i++) n += mesh_text_hit(o, o->list[i], c);
    return n & 1;
}

/* The solid of m at res against the ray oracle, voxel for voxel; its count
 * (for a mesh inside the grid) against the mesh's volume within the voxels
 * the surface touches. */
static void check_solid(const mesh *m, uint32_t res)
{
    grid_spec g = cube_grid(res);
    uint32_t *d = voxelize_mode(m, &g, MESH_SOLID, MESH_REPAIR_NONE, NULL);
    uint32_t *s = voxelize_mode(m, &g, MESH_SURFACE, MESH_REPAIR_NONE, NULL);
    ray_oracle o;
    oracle_init(&o, m);
    size_t wrong = 0, inside = 0, touched = 0;
    for (uint32_t z = 0; z < res; z++)
        for (uint32_t y = 0; y < res; y++)
            for (uint32_t x = 0; x < res; x++) {
                double c[3];
                centre(&g, x, y, z, c);
                uint32_t v = d[vidx(&g, x, y, z)];
                cr_assert(v == 0 || v == VOXEL_FULL);
                bool want = oracle_inside(&o, c);
                if ((v != 0) != want && wrong++ < 5)
                    cr_log_error("voxel %u %u %u: %d, oracle %d", x, y, z, v != 0, want);
                inside += v != 0;
                touched += s[vidx(&g, x, y, z)] != 0;
            }
    cr_expect_eq(wrong, 0, "%zu voxels differ from the ray oracle at %u^3", wrong, res);
    bool in_grid = true; /* the volume bound holds for a mesh inside the grid */
    for (int a = 0; a < 3; a++)
        in_grid = in_grid && m->lo[a] >= g.lo[a] && m->hi[a] <= grid_coord(&g, a, res);
    double vol = shape_volume(m) / (g.vs * g.vs * g.vs);
    cr_expect(!in_grid || fabs((double)inside - vol) <= (double)touched,
              "%zu voxels inside, volume %.1f voxels, %zu touched", inside, vol, touched);
    cr_expect_gt(inside, 0);
    oracle_free(&o);
    free(d);
    free(s);
}

/* ---- solid ---- */

Test(mesh_vox, icospheres_match_the_ray_oracle)
{
    for (int level = 1; level <= 4; level++) {
        shape s;
        shape_init(&s);
        double c[3] = {0.0123 * level, -0.031, 0.017 * level};
        shape_icosphere(&s, c, 0.55 + 0.07 * level, level, false);
        const mesh *m = shape_finish(&s);
        cr_assert_gt(shape_volume(m), 0, "the icosphere faces outwards");
        check_solid(m, level == 3 ? 128 : 64);
        shape_free(&s);
    }
}

Test(mesh_vox, boxes_match_the_ray_oracle)
{
    shape s;
    shape_init(&s);
    double lo[3] = {-0.61, -0.33, -0.71}, hi[3] = {0.52, 0.47, 0.13};
    shape_box(&s, lo, hi);
    cr_assert_gt(shape_volume(shape_finish(&s)), 0);
    check_solid(shape_finish(&s), 64);
    /* a box turned about a generic axis: every face on a slant */
    shape_free(&s);
    shape_init(&s);
    double l2[3] = {-0.5, -0.35, -0.4}, h2[3] = {0.45, 0.3, 0.5};
    double k[3] = {0.48, 0.6, 0.64}, R[3][3], t[3] = {0.01, -0.02, 0.03};
    shape_box(&s, l2, h2);
    shape_rotation(k, 0.7, R);
    shape_transform(&s, 0, R, t);
    check_solid(shape_finish(&s), 64);
    shape_free(&s);
}

Test(mesh_vox, torus_nested_spheres_and_c_match_the_ray_oracle)
{
    shape s;
    shape_init(&s);
    double c[3] = {0.013, -0.021, 0.008};
    shape_torus(&s, c, 0.6, 0.23, 48, 24);
    cr_assert_gt(shape_volume(shape_finish(&s)), 0);
    check_solid(shape_finish(&s), 64);
    shape_free(&s);

    shape_init(&s);
    shape_nested(&s, c, 0.85, 0.6, 0.35, 3);
    check_solid(shape_finish(&s), 64);
    shape_free(&s);

    shape_init(&s);
    double lo[3] = {-0.77, -0.71, -0.43};
    shape_c(&s, lo, 0.47, 0.91);
    cr_assert_gt(shape_volume(shape_finish(&s)), 0);
    check_solid(shape_finish(&s), 64);
    /* the C turned, so its concave faces are slanted too */
    double k[3] = {0, 0.6, 0.8}, R[3][3], t[3] = {0.05, 0.02, 0};
    shape_rotation(k, 0.4, R);
    shape_transform(&s, 0, R, t);
    check_solid(shape_finish(&s), 128);
    shape_free(&s);
}

/* Triangles far wider than the grid take the 128-bit paths: a box of
 * +-10^4 (300,000 voxels) turned so that its corner cuts the grid; and a box
 * of +-10^6, past the clamp of 2^40 lattice units (2^19 world units here),
 * whose top face z = 0.1 the clamp leaves where it is. */
Test(mesh_vox, huge_triangles_match_the_oracles)
{
    shape s;
    shape_init(&s);
    double lo[3] = {-1e4, -1e4, -1e4}, hi[3] = {0.13, 0.21, 0.17};
    double k[3] = {0.48, 0.6, 0.64}, R[3][3], t[3] = {0, 0, 0};
    shape_box(&s, lo, hi);
    shape_rotation(k, 0.3, R);
    shape_transform(&s, 0, R, t);
    check_solid(shape_finish(&s), 64);
    check_surface_modes(shape_finish(&s), 64);
    shape_free(&s);

    shape_init(&s);
    double lo2[3] = {-1e6, -1e6, -1e6}, hi2[3] = {1e6, 1e6, 0.1};
    shape_box(&s, lo2, hi2);
    grid_spec g = cube_grid(64);
    uint32_t *d = voxelize_mode(shape_finish(&s), &g, MESH_SOLID, MESH_REPAIR_VOTE, NULL);
    size_t wrong = 0;
    for (uint32_t z = 0; z < 64; z++)
        for (uint32_t y = 0; y < 64; y++)
            for (uint32_t x = 0; x < 64; x++) {
                double c[3];
                centre(&g, x, y, z, c);
                wrong += (d[vidx(&g, x, y, z)] != 0) != (c[2] < 0.1);
            }
    cr_expect_eq(wrong, 0);
    free(d);
    shape_free(&s);
}

/* A box whose faces lie on voxel centres: lo + (i + 0.5) vs, so its
 * vertices and the diagonals of its faces go through centres too. */
static const mesh *centre_box(shape *s, const grid_spec *g, const uint32_t a[3],
                              const uint32_t b[3])
{
    double lo[3], hi[3];
    for (int k = 0; k < 3; k++) {
        lo[k] = grid_coord(g, k, a[k] + 0.5);
        hi[k] = grid_coord(g, k, b[k] + 0.5);
    }
    shape_init(s);
    shape_box(s, lo, hi);
    return shape_finish(s);
}

Test(mesh_vox, box_on_voxel_centres_follows_the_top_left_rule)
{
    grid_spec g = cube_grid(64);
    const uint32_t a[3] = {5, 9, 3}, b[3] = {41, 45, 30}; /* square xy: diagonals on centres */
    shape s;
    const mesh *m = centre_box(&s, &g, a, b);
    /* each column is crossed 0 or 2 times, 2 exactly over [a, b) x [a, b) */
    mesh_vox_frame f;
    mesh_vox_frame_init(&f, m, &g, 1);
    mesh_vox_block blk = {{0, 0, -4}, {64, 64, 72}, 1};
    uint64_t *bits = malloc(mesh_vox_block_words(&blk) * 8);
    uint8_t *count = calloc(64 * 64, 1);
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        memset(bits, 0, mesh_vox_block_words(&blk) * 8);
        mesh_vox_target tg = {&blk, bits, NULL, true, NULL};
        int64_t P[3][3];
        mesh_vox_triangle(&f, t, P);
        mesh_vox_raster(P, 2, &tg);
        for (int z = 0; z < 72; z++)
            for (int y = 0; y < 64; y++)
                for (int x = 0; x < 64; x++)
                    count[y * 64 + x] += bits[z * 64 + y] >> x & 1;
    }
    for (uint32_t y = 0; y < 64; y++)
        for (uint32_t x = 0; x < 64; x++) {
            bool in = x >= a[0] && x < b[0] && y >= a[1] && y < b[1];
            cr_expect_eq(count[y * 64 + x], in ? 2 : 0, "column %u %u crossed %u times", x, y,
                         count[y * 64 + x]);
        }
    /* the solid is exactly the half-open box of centres, with or without
     * repair (whose three parities agree everywhere) */
    for (int rep = 0; rep < 3; rep++) {
        mesh_tile_stats st;
        uint32_t *d = voxelize_mode(m, &g, MESH_SOLID, (mesh_repair)rep, &st);
        size_t n = 0, wrong = 0;
        for (uint32_t z = 0; z < 64; z++)
            for (uint32_t y = 0; y < 64; y++)
                for (uint32_t x = 0; x < 64; x++) {
                    bool in = x >= a[0] && x < b[0] && y >= a[1] && y < b[1] && z >= a[2] && z < b[2];
                    wrong += (d[vidx(&g, x, y, z)] != 0) != in;
                    n += d[vidx(&g, x, y, z)] != 0;
                }
        cr_expect_eq(wrong, 0, "repair %d: %zu voxels off the box", rep, wrong);
        cr_expect_eq(n, (size_t)(b[0] - a[0]) * (b[1] - a[1]) * (b[2] - a[2]));
        cr_expect_eq(st.disagreements, 0);
        cr_expect_eq(st.voxels, n);
        free(d);
    }
    free(bits);
    free(count);
    shape_free(&s);
}

/* An octahedron |x - C| + |y - C| + |z - C| <= r voxels around centre C:
 * its slanted faces go through many centres.  The rule for a sample on
 * the mesh is that of the sample moved by (eps^2, eps^3, eps): with
 * d = the offset from C, sum |d| + eps s_z + ... with s_a = sign(d_a) (+1
 * for 0), so a centre on a face is inside exactly when d_z < 0.  The same
 * for the parities along x, y and z: no disagreement, any repair. */
Test(mesh_vox, octahedron_on_voxel_centres_breaks_ties_alike_in_all_directions)
{
    grid_spec g = cube_grid(64);
    const int C[3] = {30, 33, 31}, r = 17;
    shape s;
    shape_init(&s);
    uint32_t v[3][2];
    for (int a = 0; a < 3; a++)
        for (int k = 0; k < 2; k++) {
            double p[3];
            for (int b = 0; b < 3; b++)
                p[b] = grid_coord(&g, b, C[b] + 0.5 + (b == a ? (k ? r : -r) : 0));
            v[a][k] = shape_vertex(&s, p[0], p[1], p[2]);
        }
    for (int o = 0; o < 8; o++) {
        int sx = o & 1, sy = o >> 1 & 1, sz = o >> 2 & 1;
        if ((sx + sy + sz) % 2 == 0) shape_tri(&s, v[0][sx], v[2][sz], v[1][sy]); /* an odd number of minus */
        else shape_tri(&s, v[0][sx], v[1][sy], v[2][sz]);
    }
    const mesh *m = shape_finish(&s);
    cr_assert_gt(shape_volume(m), 0);
    size_t on_face = 0;
    for (int rep = 0; rep < 3; rep++) {
        mesh_tile_stats st;
        uint32_t *d = voxelize_mode(m, &g, MESH_SOLID, (mesh_repair)rep, &st);
        size_t wrong = 0;
        on_face = 0;
        for (int z = 0; z < 64; z++)
            for (int y = 0; y < 64; y++)
                for (int x = 0; x < 64; x++) {
                    int l1 = abs(x - C[0]) + abs(y - C[1]) + abs(z - C[2]);
                    bool in = l1 < r || (l1 == r && z < C[2]);
                    on_face += l1 == r;
                    wrong += (d[vidx(&g, (uint32_t)x, (uint32_t)y, (uint32_t)z)] != 0) != in;
                }
        cr_expect_eq(wrong, 0, "repair %d: %zu voxels off", rep, wrong);
        cr_expect_eq(st.disagreements, 0, "repair %d: %llu disagreements", rep,
                     (unsigned long long)st.disagreements);
        free(d);
    }
    cr_expect_gt(on_face, 1000);
    shape_free(&s);
}

/* ---- density and normals ---- */

Test(mesh_vox, density_sums_to_the_volume)
{
    grid_spec g = cube_grid(64);
    double c[3] = {0.011, 0.007, -0.013};
    shape s;
    shape_init(&s);
    shape_icosphere(&s, c, 0.85, 4, false);
    const mesh *m = shape_finish(&s);
    double vol = shape_volume(m) / (g.vs * g.vs * g.vs);
    for (uint32_t K = 2; K <= 4; K += 2) {
        mesh_vox_opts o = {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_DENSITY, K, 0};
        mesh_tile_stats st;
        uint32_t *d = voxelize(m, &g, &o, 32, &st);
        double sum = 0;
        size_t partial = 0, nonzero = 0;
        for (size_t i = 0; i < nvox(&g); i++) {
            sum += d[i];
            partial += d[i] != 0 && d[i] != 255;
            nonzero += d[i] != 0;
        }
        /* the rounding to 8 bits moves each partly covered voxel by up to
         * 1/510; the samples' own errors, up to a voxel's samples on the
         * surface each, mostly cancel over a sphere (here |err| < 2 voxels) */
        double err = fabs(sum / 255 - vol);
        cr_expect(err < 0.01 * partial, "K %u: sum %.1f voxels, volume %.1f, %zu partial", K,
                  sum / 255, vol, partial);
        cr_expect_gt(partial, 1000);
        cr_expect_eq(st.voxels, nonzero);
        free(d);
    }
    shape_free(&s);
}

Test(mesh_vox, density_of_half_coverage_is_the_surface_threshold)
{
    /* a box over x in [0, 2.5) voxels (in the grid's frame): the voxel
     * x = 2 is half covered: 127, the ICVG S; x < 2 full, x > 2 empty */
    grid_spec g = cube_grid(16);
    double lo[3] = {grid_coord(&g, 0, 0.0), grid_coord(&g, 1, 0), grid_coord(&g, 2, 0)};
    double hi[3] = {grid_coord(&g, 0, 2.5), grid_coord(&g, 1, 16), grid_coord(&g, 2, 16)};
    lo[0] -= 1, lo[1] -= 1, lo[2] -= 1, hi[1] += 1, hi[2] += 1; /* past the grid */
    shape s;
    shape_init(&s);
    shape_box(&s, lo, hi);
    for (uint32_t K = 2; K <= 8; K += 2) {
        mesh_vox_opts o = {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_DENSITY, K, 0};
        uint32_t *d = voxelize(shape_finish(&s), &g, &o, 8, NULL);
        for (uint32_t z = 0; z < 16; z += 5)
            for (uint32_t y = 0; y < 16; y += 3) {
                cr_expect_eq(d[vidx(&g, 1, y, z)], 255);
                cr_expect_eq(d[vidx(&g, 2, y, z)], 127, "K %u: %u", K, d[vidx(&g, 2, y, z)]);
                cr_expect_eq(d[vidx(&g, 3, y, z)], 0);
            }
        free(d);
    }
    shape_free(&s);
}

Test(mesh_vox, sphere_normals_point_outwards)
{
    grid_spec g = cube_grid(64);
    double c[3] = {0.013, -0.009, 0.004};
    shape s;
    shape_init(&s);
    shape_icosphere(&s, c, 0.8, 4, false);
    const mesh *m = shape_finish(&s);
    uint32_t *occ = voxelize_mode(m, &g, MESH_SURFACE, MESH_REPAIR_NONE, NULL);
    /* the default supersample (2) and 4: mean and worst angle to the radius
     * (the icosphere's facets themselves lean by up to ~2 degrees) */
    const uint32_t K[2] = {0, 4};
    const double mean_max[2] = {3, 2}, worst_max[2] = {15, 8};
    for (int k = 0; k < 2; k++) {
        mesh_vox_opts o = {MESH_SURFACE, MESH_REPAIR_NONE, VOXEL_CH_SURFACE, K[k], 0};
        uint32_t *d = voxelize(m, &g, &o, 16, NULL);
        size_t n = 0;
        double worst = 0, sum = 0;
        for (uint32_t z = 0; z < 64; z++)
            for (uint32_t y = 0; y < 64; y++)
                for (uint32_t x = 0; x < 64; x++) {
                    uint32_t v = d[vidx(&g, x, y, z)];
                    cr_assert_eq(v != 0, occ[vidx(&g, x, y, z)] != 0, "the mode's occupancy");
                    if (!v) continue;
                    cr_assert_eq(voxel_occupancy(v), VOXEL_FULL);
                    double nrm[3], p[3], r[3], l = 0;
                    voxel_unpack_normal(v, nrm);
                    centre(&g, x, y, z, p);
                    for (int a = 0; a < 3; a++) r[a] = p[a] - c[a], l += r[a] * r[a];
                    double ang = acos(fmin(1, dot3(nrm, r) / sqrt(l))) * 180 / M_PI;
                    worst = fmax(worst, ang);
                    sum += ang;
                    n++;
                }
        cr_assert_gt(n, 10000);
        cr_expect_lt(sum / n, mean_max[k], "K %u: mean angle %.2f degrees", K[k], sum / n);
        cr_expect_lt(worst, worst_max[k], "K %u: worst angle %.2f degrees", K[k], worst);
        free(d);
    }
    free(occ);
    shape_free(&s);
}

/* ---- the interface's edges ---- */

Test(mesh_vox, options_are_checked)
{
    err_info err = {0};
    mesh_vox_opts ok = {MESH_SURFACE, MESH_REPAIR_VOTE, VOXEL_CH_SURFACE, 0, 0};
    cr_expect_eq(mesh_vox_check(&ok, &err), 0);
    cr_expect_eq(mesh_vox_bits(&ok), 32);
    ok.channel = VOXEL_CH_OCCUPANCY;
    cr_expect_eq(mesh_vox_bits(&ok), 8);
    mesh_vox_opts bad[] = {
        {(mesh_mode)9, MESH_REPAIR_NONE, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_SOLID, (mesh_repair)7, VOXEL_CH_OCCUPANCY, 0, 0},
        {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_DENSITY, 1, 0},
        {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_DENSITY, 9, 0},
        {MESH_SURFACE, MESH_REPAIR_NONE, VOXEL_CH_DENSITY, 2, 0},
    };
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
        err.msg[0] = 0;
        cr_expect_eq(mesh_vox_check(&bad[i], &err), -EINVAL, "case %zu", i);
        cr_expect_neq(err.msg[0], 0);
    }
}

Test(mesh_vox, tile_run_refuses_a_volume_that_does_not_fit)
{
    grid_spec g = cube_grid(64);
    shape s;
    shape_init(&s);
    double c[3] = {0, 0, 0};
    shape_icosphere(&s, c, 0.5, 1, false);
    const mesh *m = shape_finish(&s);
    mesh_vox_opts o = {MESH_SOLID, MESH_REPAIR_NONE, VOXEL_CH_OCCUPANCY, 0, 0};
    void *scratch = malloc(mesh_tile_scratch_bytes(&g, &o));
    uint32_t ids[1] = {0};
    mesh_tile_stats st = {0};
    tvol v32 = vol_make(&g, 32, 16); /* the wrong width */
    mesh_tiles j = {.m = m, .g = &g, .o = &o, .vol = v32.v, .scratch = scratch};
    cr_expect_eq(mesh_tile_run(&j, ids, 1, 0, 0, &st), -EINVAL);
    tvol v8 = vol_make(&g, 8, 16);
    j.vol = v8.v;
    cr_expect_eq(mesh_tile_run(&j, ids, 1, 1, 0, &st), -EINVAL,
                 "tile x 1 of a 64-wide grid");
    /* a pool without room for a brick: -ENOMEM */
    size_t bytes = vod_volume_bytes(g.res, 8, 16, 0);
    void *arena = malloc(bytes);
    vod_volume *small;
    cr_assert_eq(vod_volume_init(&small, arena, bytes, g.res, 8, 16), 0);
    cr_expect_eq(mesh_voxelize(m, &g, &o, small, &st), -ENOMEM);
    free(arena), free(scratch), free(v32.arena), free(v8.arena);
    shape_free(&s);
}
