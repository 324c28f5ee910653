/* A CSG tree's signed distance (channel 4, csg_deval.c) against closed
 * forms.  Two balls, their union, intersection and difference: the true
 * signed distance of each solid is written here from its boundary (two
 * sphere pieces and the crease circle where they meet), the membership by
 * a dense brute force over every voxel centre.  On every voxel:
 *   - the sign is the membership (never wrong);
 *   - the magnitude is never above the true distance (min/max of
 *     distances is 1-Lipschitz with the solid's sign: a lower bound), but
 *     for the leaves' documented tolerance;
 *   - where docs/csg.md says the combination is exact (the operator's
 *     rule, decided here from the balls' own distances) the value is the
 *     true distance clamped to +-W, within that tolerance;
 * and the inexact region is real: somewhere in it the value is below the
 * distance by more than a tenth of a voxel.  Then a mesh leaf (a box as an
 * OFF file) with an implicit ball: signs, and the union's exact outside. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "csg_fixture.h"
#include "voxel.h"

typedef enum { OP_UNION, OP_INTERSECTION, OP_DIFFERENCE } op_kind;

typedef struct {
    double c[2][3], r[2];
} balls;

static const balls B = {{{-0.25, 0.0, 0.0}, {0.22, 0.05, -0.03}}, {0.5, 0.43}};

static double dist3(const double a[3], const double b[3])
{
    return sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                (a[2] - b[2]) * (a[2] - b[2]));
}

/* The distance from p to the crease circle where the two spheres meet. */
static double circle_dist(const double p[3])
{
    double d = dist3(B.c[0], B.c[1]), n[3], m[3], q[3];
    double h = (d * d + B.r[0] * B.r[0] - B.r[1] * B.r[1]) / (2 * d);
    double rho = sqrt(B.r[0] * B.r[0] - h * h);
    for (int a = 0; a < 3; a++) {
        n[a] = (B.c[1][a] - B.c[0][a]) / d;
        m[a] = B.c[0][a] + h * n[a];
        q[a] = p[a] - m[a];
    }
    double t = q[0] * n[0] + q[1] * n[1] + q[2] * n[2], rad2 = 0;
    for (int a = 0; a < 3; a++) rad2 += (q[a] - t * n[a]) * (q[a] - t * n[a]);
    double e = sqrt(rad2) - rho;
    return sqrt(t * t + e * e);
}

/* The distance from p to the part of sphere i inside (in = 1) or outside
 * (in = 0) the other ball: the radial one when p's foot point on the
 * sphere lies in that part, else the distance to the crease circle (the
 * distance to a sphere's points grows with their angle from the foot, so
 * over a cap without the foot it is least on the cap's rim). */
static double piece_dist(const double p[3], int i, int in)
{
    double l = dist3(p, B.c[i]), f[3];
    if (l == 0) return B.r[i];
    for (int a = 0; a < 3; a++) f[a] = B.c[i][a] + B.r[i] * (p[a] - B.c[i][a]) / l;
    int foot_in = dist3(f, B.c[1 - i]) < B.r[1 - i];
    return foot_in == in ? fabs(l - B.r[i]) : circle_dist(p);
}

static int inside_ball(const double p[3], int i) { return dist3(p, B.c[i]) < B.r[i]; }

/* The solid's membership, by brute force on the balls. */
static int member(op_kind op, const double p[3])
{
    int a = inside_ball(p, 0), b = inside_ball(p, 1);
    return op == OP_UNION ? a || b : op == OP_INTERSECTION ? a && b : a && !b;
}

/* The true signed distance to the solid's boundary. */
static double true_sdf(op_kind op, const double p[3])
{
    double d = op == OP_UNION          ? fmin(piece_dist(p, 0, 0), piece_dist(p, 1, 0))
               : op == OP_INTERSECTION ? fmin(piece_dist(p, 0, 1), piece_dist(p, 1, 1))
                                       : fmin(piece_dist(p, 0, 0), piece_dist(p, 1, 1));
    return member(op, p) ? -d : d;
}

/* docs/csg.md's rule: 1 where min/max of the operands' exact distances
 * a, b is the solid's distance clamped to +-w. */
static int rule_exact(op_kind op, double a, double b, double w)
{
    if (op == OP_UNION) { /* the dual of the intersection */
        a = -a;
        b = -b;
    } else if (op == OP_DIFFERENCE) {
        b = -b;
    }
    double u = fmax(a, b), o = fmin(a, b); /* max: the intersection */
    if (u <= 0 || u >= w) return 1;        /* inside both, or beyond the band */
    return o < 0 && -o > u;                /* outside one only, nearer than the other's depth */
}

static double sphere_sdf(const double p[3], int i) { return dist3(p, B.c[i]) - B.r[i]; }

typedef struct {
    uint64_t voxels, exact, bound_gap; /* bound_gap: inexact by over 0.1 voxel */
} tally;

static vod_volume *eval_tree(csg_tree *t, const grid_spec *g, uint32_t band,
                             vod_volume *const *leaves, void **arena)
{
    csg_tree_set_band(t, band);
    size_t bytes = vod_volume_bytes(g->res, VOD_VOLUME_F32, CSG_VOLUME_BRICK, UINT64_MAX);
    cr_assert(bytes);
    *arena = malloc(bytes);
    vod_volume *vol;
    cr_assert_eq(vod_volume_init(&vol, *arena, bytes, g->res, VOD_VOLUME_F32, CSG_VOLUME_BRICK),
                 0);
    csg_stats st;
    cr_assert_eq(csg_eval_volume(t, g, (const vod_volume *const *)leaves, vol, VOXEL_CH_DISTANCE,
                                 &st), 0);
    return vol;
}

static float voxel_f(const vod_volume *v, uint32_t x, uint32_t y, uint32_t z)
{
    uint32_t bits = vod_volume_get(v, x, y, z);
    float f;
    memcpy(&f, &bits, sizeof f);
    return f;
}

static void check_balls(op_kind op, const char *opname, uint32_t res, uint32_t band)
{
    char src[512];
    snprintf(src, sizeof src,
             "a = implicit \"sqrt((x+0.25)^2 + y^2 + z^2) - 0.5\"\n"
             "b = implicit \"sqrt((x-0.22)^2 + (y-0.05)^2 + (z+0.03)^2) - 0.43\"\n"
             "r = %s(a, b)\nresult r\n", opname);
    csg_tree *t = parse(src);
    grid_spec g = grid(res);
    void *arena;
    vod_volume *vol = eval_tree(t, &g, band, NULL, &arena);
    double vs = g.vs, w = (float)(band * vs);
    double tol = (CSG_DIST_EPS + 1e-4) * vs + 1e-6;
    tally n = {0};
    for (uint32_t z = 0; z < res; z++)
        for (uint32_t y = 0; y < res; y++)
            for (uint32_t x = 0; x < res; x++) {
                double p[3] = {grid_coord(&g, 0, x + 0.5), grid_coord(&g, 1, y + 0.5),
                               grid_coord(&g, 2, z + 0.5)};
                double v = voxel_f(vol, x, y, z), d = true_sdf(op, p);
                double dc = fmax(-w, fmin(w, d));
                n.voxels++;
                cr_assert_eq(v < 0, member(op, p), "%s (%u,%u,%u): value %g, member %d", opname,
                             x, y, z, v, member(op, p));
                cr_assert(v != 0, "%s (%u,%u,%u): 0 off the surface", opname, x, y, z);
                cr_assert(fabs(v) <= fabs(dc) + tol, "%s (%u,%u,%u): |%.9g| above the distance %.9g",
                          opname, x, y, z, v, d);
                if (rule_exact(op, sphere_sdf(p, 0), sphere_sdf(p, 1), w)) {
                    n.exact++;
                    cr_assert(fabs(v - dc) <= tol, "%s (%u,%u,%u): %.9g, exact %.9g", opname, x,
                              y, z, v, dc);
                } else if (fabs(dc) - fabs(v) > 0.1 * vs) {
                    n.bound_gap++;
                }
            }
    /* both regions are there: most voxels exact, some only bounded */
    cr_assert_gt(n.exact, n.voxels / 2, "%s: %llu exact of %llu", opname,
                 (unsigned long long)n.exact, (unsigned long long)n.voxels);
    cr_assert_gt(n.bound_gap, 0, "%s: the inexact region is never below the distance", opname);
    free(arena);
    csg_tree_free(t);
}

Test(csg_distance, union_of_two_balls) { check_balls(OP_UNION, "union", 64, 3); }
Test(csg_distance, intersection_of_two_balls) { check_balls(OP_INTERSECTION, "intersection", 64, 3); }
Test(csg_distance, difference_of_two_balls) { check_balls(OP_DIFFERENCE, "difference", 64, 3); }
Test(csg_distance, wide_band) { check_balls(OP_UNION, "union", 48, 8); }
Test(csg_distance, difference_wide_band) { check_balls(OP_DIFFERENCE, "difference", 40, 12); }

/* ---- a mesh leaf: a box as an OFF file (mesh_dist's exact distance) ---- */

static const double BOX_LO[3] = {-0.61, -0.37, -0.29}, BOX_HI[3] = {0.13, 0.41, 0.33};

static char *box_off(size_t *len)
{
    char *s = malloc(2048);
    int n = snprintf(s, 2048, "OFF\n8 12 0\n");
    for (int v = 0; v < 8; v++)
        n += snprintf(s + n, 2048 - (size_t)n, "%.17g %.17g %.17g\n", v & 1 ? BOX_HI[0] : BOX_LO[0],
                      v & 2 ? BOX_HI[1] : BOX_LO[1], v & 4 ? BOX_HI[2] : BOX_LO[2]);
    /* two triangles a face, outward */
    static const int f[12][3] = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                                 {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
    for (int i = 0; i < 12; i++)
        n += snprintf(s + n, 2048 - (size_t)n, "3 %d %d %d\n", f[i][0], f[i][1], f[i][2]);
    *len = (size_t)n;
    return s;
}

static double box_sdf(const double p[3])
{
    double q[3], out = 0, in = -INFINITY;
    for (int a = 0; a < 3; a++) {
        double c = (BOX_LO[a] + BOX_HI[a]) / 2, h = (BOX_HI[a] - BOX_LO[a]) / 2;
        q[a] = fabs(p[a] - c) - h;
        out += q[a] > 0 ? q[a] * q[a] : 0;
        in = fmax(in, q[a]);
    }
    return in > 0 ? sqrt(out) : in;
}

static void check_mesh(op_kind op, const char *opname)
{
    char src[512];
    snprintf(src, sizeof src,
             "box = mesh \"box.off\"\n"
             "a = implicit \"sqrt((x-0.22)^2 + (y-0.05)^2 + (z+0.03)^2) - 0.43\"\n"
             "r = %s(box, a)\nresult r\n", opname);
    csg_tree *t = parse(src);
    t->data[0] = box_off(&t->data_len[0]);
    const uint32_t res = 64, band = 3;
    grid_spec g = grid(res);
    csg_tree_set_band(t, band);
    cr_assert_eq(csg_leaf_bits(&t->node[0]), VOD_VOLUME_F32);
    size_t lbytes = vod_volume_bytes(g.res, VOD_VOLUME_F32, CSG_VOLUME_BRICK, UINT64_MAX);
    void *larena = malloc(lbytes), *arena;
    csg_arena la = {.base = larena, .bytes = lbytes};
    vod_volume *leaves[CSG_MAX_NODES];
    err_info err = {0};
    cr_assert_eq(csg_leaves_build(t, &g, &la, leaves, &err), 0, "%s", err.msg);
    cr_assert(la.used > 0 && la.used <= lbytes, "%zu of %zu bytes", la.used, lbytes);
    vod_volume *vol = eval_tree(t, &g, band, leaves, &arena);
    double vs = g.vs, w = (float)(band * vs), tol = (CSG_DIST_EPS + 1e-4) * vs + 1e-6;
    uint64_t outside = 0;
    for (uint32_t z = 0; z < res; z++)
        for (uint32_t y = 0; y < res; y++)
            for (uint32_t x = 0; x < res; x++) {
                double p[3] = {grid_coord(&g, 0, x + 0.5), grid_coord(&g, 1, y + 0.5),
                               grid_coord(&g, 2, z + 0.5)};
                double v = voxel_f(vol, x, y, z), db = box_sdf(p), da = sphere_sdf(p, 1);
                int in = op == OP_UNION ? db < 0 || da < 0 : db < 0 && da >= 0;
                cr_assert_eq(v < 0, in, "%s (%u,%u,%u): value %g", opname, x, y, z, v);
                if (op == OP_UNION && db > 0 && da > 0) { /* outside both: exact */
                    outside++;
                    double dc = fmin(w, fmin(db, da));
                    cr_assert(fabs(v - dc) <= tol, "%s (%u,%u,%u): %.9g, exact %.9g", opname,
                              x, y, z, v, dc);
                }
            }
    if (op == OP_UNION) cr_assert_gt(outside, 1000);
    free(arena);
    free(larena);
    csg_tree_free(t);
}

Test(csg_distance, mesh_box_union_ball) { check_mesh(OP_UNION, "union"); }
Test(csg_distance, mesh_box_minus_ball) { check_mesh(OP_DIFFERENCE, "difference"); }

/* What has no distance is refused, naming the node; the rest passes. */
Test(csg_distance, check_refuses)
{
    static const struct {
        const char *src, *node;
    } no[] = {
        {"a = cuboid size 1,1,1\nresult a\n", "'a' (cuboid)"},
        {"a = implicit \"x\" domain -1,1\nresult a\n", "'a' (implicit)"},
        {"a = implicit \"x\"\nb = implicit \"y\"\nc = add(a, b)\nresult c\n", "'c' (add)"},
        {"a = implicit \"x\"\nb = dilate(a, 2)\nresult b\n", "'b' (dilate)"},
        {"a = implicit \"x\"\ne = ellipsoid radius 0.5\nc = union(a, e)\nresult c\n",
         "'e' (ellipsoid)"},
    };
    err_info err = {0};
    for (size_t i = 0; i < sizeof no / sizeof no[0]; i++) {
        csg_tree *t = parse(no[i].src);
        cr_assert_eq(csg_dist_check(t, &err), -ENOTSUP, "%s", no[i].src);
        cr_assert_eq(err.code, -ENOTSUP, "%s", no[i].src);
        cr_assert(strstr(err.msg, no[i].node), "%s: %s", no[i].node, err.msg);
        csg_tree_free(t);
    }
    /* an unreferenced primitive is not evaluated: no refusal */
    csg_tree *t = parse("e = cuboid size 1,1,1\na = implicit \"x\"\nb = implicit \"y\"\n"
                        "c = inverse(difference(a, b))\nresult c\n");
    cr_assert_eq(csg_dist_check(t, &err), 0, "%s", err.msg);
    csg_tree_free(t);
}
