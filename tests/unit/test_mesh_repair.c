/* The repair by winding numbers (--repair winding, MESH_REPAIR_WINDING)
 * against an oracle written here from its definition (mesh_vox.h,
 * docs/meshes.md): a voxel is inside by its parity where the parities of
 * rays along x, y and z agree, and where they disagree, when the
 * generalized winding number w at its centre has |w| >= 1/2.  Both are
 * computed here: the parities by counting, column by column, the triangles
 * whose projection holds the column's point and which cross it below the
 * voxel's centre (rays from the low side, as the lattice's prefix sums
 * run); w by summing over the triangles the solid angle of Van Oosterom and
 * Strackee, tan(Omega/2) = a.(b x c) / (|a||b||c| + (a.b)|c| + (b.c)|a| +
 * (c.a)|b|), over 4 pi.
 *
 * The meshes are open (holes cut in a sphere and a torus, the sphere facing
 * inwards, a soup of a sphere's triangles with every seventh missing).
 * Every voxel must be what the oracle says, through the public entry
 * (mesh_voxelize) with its tree and with the exact sum (mesh_wind_exact),
 * but those where the oracle meets a tie (a column's point within 1e-9 of a
 * projected edge, a crossing within 1e-9 of a centre, |w| within 1e-9 of
 * 1/2: the vertices lie on the voxelizer's lattice, so both see one mesh
 * and ties are rare).  The disagreements counted here are the
 * voxelizer's, and many of them have |w| between 1/4 and 3/4, some on each
 * side of 1/2: a threshold of 1/4 or 3/4, a sum of the wrong scale, or w
 * taken with its sign (the inward sphere's w is near -1 inside) fails.
 *
 * Only mesh_vox.h's API is used: the fast sum's internals change apart.
 */
#include <criterion/criterion.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "grid.h"
#include "mesh_shapes.h"
#include "mesh_vox.h"
#include "vod_volume.h"
#include "voxel.h"

#define RES 64u

static grid_spec cube_grid(void)
{
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    grid_spec g;
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, RES, &g, &err), 0, "%s", err.msg);
    return g;
}

/* ---- the oracle ---- */

#define TIE 1e-9

static double dot(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* The solid angle of triangle (a, b, c) seen from the origin. */
static double solid_angle(const double a[3], const double b[3], const double c[3])
{
    double bxc[3] = {b[1] * c[2] - b[2] * c[1], b[2] * c[0] - b[0] * c[2],
                     b[0] * c[1] - b[1] * c[0]};
    double la = sqrt(dot(a, a)), lb = sqrt(dot(b, b)), lc = sqrt(dot(c, c));
    double den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb;
    return 2 * atan2(dot(a, bxc), den);
}

/* The winding number of m at point p: the solid angles over 4 pi. */
static double winding(const mesh *m, const double p[3])
{
    double sum = 0;
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        double r[3][3];
        for (int i = 0; i < 3; i++)
            for (int a = 0; a < 3; a++)
                r[i][a] = (double)m->vertices[m->triangles[t][i]][a] - p[a];
        sum += solid_angle(r[0], r[1], r[2]);
    }
    return sum / (4 * M_PI);
}

static double centre(const grid_spec *g, int a, uint32_t i)
{
    return g->lo[a] + (i + 0.5) * g->vs;
}

#define MAX_CROSS 64

/* The distance from (u, v) to the segment (x0, y0)-(x1, y1). */
static double seg_dist(double x0, double y0, double x1, double y1, double u, double v)
{
    double dx = x1 - x0, dy = y1 - y0, l2 = dx * dx + dy * dy;
    double s = l2 > 0 ? ((u - x0) * dx + (v - y0) * dy) / l2 : 0;
    s = s < 0 ? 0 : s > 1 ? 1 : s;
    return hypot(u - x0 - s * dx, v - y0 - s * dy);
}

/* The crossings along axis a of the column through (u, v) on the other two
 * axes (b = a + 1, c = a + 2, mod 3): their a coordinates in *x (n of
 * them); -1 when the point lies within TIE of a projected edge. */
static int column(const mesh *m, int a, double u, double v, double *x)
{
    int b = (a + 1) % 3, c = (a + 2) % 3, n = 0;
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        double P[3][3], e[3];
        for (int i = 0; i < 3; i++)
            for (int k = 0; k < 3; k++) P[i][k] = m->vertices[m->triangles[t][i]][k];
        for (int i = 0; i < 3; i++) {
            const double *p = P[i], *q = P[(i + 1) % 3];
            e[i] = (q[b] - p[b]) * (v - p[c]) - (q[c] - p[c]) * (u - p[b]);
        }
        double area = e[0] + e[1] + e[2];
        if (fabs(area) < 1e-30) continue; /* seen edge on */
        bool pos = e[0] > 0 && e[1] > 0 && e[2] > 0, neg = e[0] < 0 && e[1] < 0 && e[2] < 0;
        for (int i = 0; i < 3; i++)
            if (seg_dist(P[i][b], P[i][c], P[(i + 1) % 3][b], P[(i + 1) % 3][c], u, v) <= TIE)
                return -1;
        if (!pos && !neg) continue;
        /* e[i] is opposite vertex (i + 2) % 3: its barycentric weight */
        x[n++] = (e[1] * P[0][a] + e[2] * P[1][a] + e[0] * P[2][a]) / area;
        cr_assert_lt(n, MAX_CROSS);
    }
    return n;
}

/* The parity of every voxel along axis a (bit a of par[i]), x fastest;
 * tie[i] set where a column or a crossing meets a tie. */
static void parities(const mesh *m, const grid_spec *g, int a, uint8_t *par, uint8_t *tie)
{
    int b = (a + 1) % 3, c = (a + 2) % 3;
    double x[MAX_CROSS];
    for (uint32_t j = 0; j < g->res[b]; j++)
        for (uint32_t k = 0; k < g->res[c]; k++) {
            int n = column(m, a, centre(g, b, j), centre(g, c, k), x);
            for (uint32_t i = 0; i < g->res[a]; i++) {
                uint32_t at[3];
                at[a] = i, at[b] = j, at[c] = k;
                size_t idx = ((size_t)at[2] * g->res[1] + at[1]) * g->res[0] + at[0];
                int below = 0;
                double ci = centre(g, a, i);
                for (int q = 0; q < n; q++) {
                    below += x[q] < ci;
                    if (fabs(x[q] - ci) <= TIE) tie[idx] = 1;
                }
                if (n < 0) tie[idx] = 1;
                par[idx] |= (uint8_t)((below & 1) << a);
            }
        }
}

typedef struct {
    uint8_t *inside, *tie, *dis; /* per voxel */
    double *w;                   /* per voxel where dis, else 0 */
} oracle_t;

static oracle_t oracle(const mesh *m, const grid_spec *g)
{
    size_t n = (size_t)g->res[0] * g->res[1] * g->res[2];
    oracle_t o = {calloc(n, 1), calloc(n, 1), calloc(n, 1), calloc(n, sizeof(double))};
    uint8_t *par = calloc(n, 1);
    cr_assert(o.inside && o.tie && o.dis && o.w && par);
    for (int a = 0; a < 3; a++) parities(m, g, a, par, o.tie);
    size_t i = 0;
    for (uint32_t z = 0; z < g->res[2]; z++)
        for (uint32_t y = 0; y < g->res[1]; y++)
            for (uint32_t x = 0; x < g->res[0]; x++, i++) {
                if (par[i] == 0 || par[i] == 7) {
                    o.inside[i] = par[i] == 7;
                    continue;
                }
                double p[3] = {centre(g, 0, x), centre(g, 1, y), centre(g, 2, z)};
                o.dis[i] = 1;
                o.w[i] = winding(m, p);
                o.inside[i] = fabs(o.w[i]) >= 0.5;
                if (fabs(fabs(o.w[i]) - 0.5) <= TIE) o.tie[i] = 1;
            }
    free(par);
    return o;
}

static void oracle_free(oracle_t *o)
{
    free(o->inside), free(o->tie), free(o->dis), free(o->w);
}

/* ---- the voxelizer ---- */

/* The occupancy of every voxel (x fastest), serially through mesh_voxelize. */
static uint8_t *voxelize(const mesh *m, const grid_spec *g, mesh_repair rep,
                         mesh_tile_stats *st)
{
    mesh_vox_opts o = {.mode = MESH_SOLID, .repair = rep, .channel = VOXEL_CH_OCCUPANCY};
    size_t bytes = vod_volume_bytes(g->res, 8, MESH_VOLUME_BRICK, UINT32_MAX);
    void *arena = malloc(bytes);
    vod_volume *v;
    cr_assert_not_null(arena);
    cr_assert_eq(vod_volume_init(&v, arena, bytes, g->res, 8, MESH_VOLUME_BRICK), 0);
    memset(st, 0, sizeof *st);
    cr_assert_eq(mesh_voxelize(m, g, &o, v, st), 0);
    size_t n = (size_t)g->res[0] * g->res[1] * g->res[2], i = 0;
    uint8_t *d = malloc(n);
    cr_assert_not_null(d);
    for (uint32_t z = 0; z < g->res[2]; z++)
        for (uint32_t y = 0; y < g->res[1]; y++)
            for (uint32_t x = 0; x < g->res[0]; x++) d[i++] = vod_volume_get(v, x, y, z) != 0;
    free(arena);
    return d;
}

/* ---- the comparison ---- */

typedef struct {
    size_t dis;            /* voxels whose parities disagree (the oracle's count) */
    size_t ties;           /* voxels not compared */
    size_t mid_in, mid_out; /* disagreeing, |w| in [1/2, 3/4) and in [1/4, 1/2) */
    size_t neg;            /* disagreeing, w <= -1/2 */
} tally;

static tally compare(const mesh *m, const char *what)
{
    grid_spec g = cube_grid();
    size_t n = (size_t)g.res[0] * g.res[1] * g.res[2];
    oracle_t o = oracle(m, &g);
    tally t = {0};
    for (size_t i = 0; i < n; i++) {
        t.ties += o.tie[i];
        if (!o.dis[i] || o.tie[i]) continue;
        double a = fabs(o.w[i]);
        t.dis++;
        t.mid_in += a >= 0.5 && a < 0.75;
        t.mid_out += a >= 0.25 && a < 0.5;
        t.neg += o.w[i] <= -0.5;
    }
    for (int exact = 0; exact < 2; exact++) {
        const char *how = exact ? "exact sum" : "tree";
        mesh_tile_stats st;
        mesh_wind_exact = exact;
        uint8_t *d = voxelize(m, &g, MESH_REPAIR_WINDING, &st);
        mesh_wind_exact = 0;
        size_t differ = 0;
        for (size_t i = 0; i < n; i++) {
            if (o.tie[i] || d[i] == o.inside[i]) continue;
            if (differ++ < 5)
                cr_log_error("%s (%s): voxel (%zu, %zu, %zu): %s, the oracle %s (%s, w = %.6f)",
                             what, how, i % RES, i / RES % RES, i / RES / RES,
                             d[i] ? "inside" : "outside", o.inside[i] ? "inside" : "outside",
                             o.dis[i] ? "parities disagree" : "parities agree", o.w[i]);
        }
        cr_expect_eq(differ, 0, "%s (%s): %zu voxels against the oracle", what, how, differ);
        /* the voxelizer found the disagreements the oracle found (up to ties) */
        cr_expect_leq((double)llabs((long long)st.disagreements - (long long)t.dis), (double)t.ties,
                      "%s (%s): %llu disagreements, the oracle %zu", what, how,
                      (unsigned long long)st.disagreements, t.dis);
        free(d);
    }
    cr_log_info("%s: %zu disagreements, %zu with |w| in [1/2, 3/4), %zu in [1/4, 1/2), "
                "%zu with w <= -1/2; %zu ties", what, t.dis, t.mid_in, t.mid_out, t.neg, t.ties);
    cr_expect_leq(t.ties, n / 1000, "%s: %zu ties", what, t.ties);
    oracle_free(&o);
    return t;
}

/* ---- the meshes ---- */

typedef struct {
    double at[3], r;
    const mesh *m;
} hole;

/* Keeps triangle i unless its centroid lies within h->r of h->at. */
static bool outside_hole(uint32_t i, void *ctx)
{
    const hole *h = ctx;
    double d2 = 0;
    for (int a = 0; a < 3; a++) {
        double c = 0;
        for (int k = 0; k < 3; k++) c += h->m->vertices[h->m->triangles[i][k]][a];
        d2 += (c / 3 - h->at[a]) * (c / 3 - h->at[a]);
    }
    return d2 > h->r * h->r;
}

static bool not_every_seventh(uint32_t i, void *ctx)
{
    (void)ctx;
    return i % 7 != 3;
}

static void cut(shape *s, double x, double y, double z, double r)
{
    hole h = {{x, y, z}, r, &s->m};
    uint32_t before = s->m.n_triangles;
    shape_remove(s, outside_hole, &h);
    cr_assert_lt(s->m.n_triangles, before, "the hole at (%g, %g, %g) cut nothing", x, y, z);
}

/* A threshold of 1/4 or 3/4 (or a sum scaled by 4/5) would change some of
 * the voxels the winding number decided. */
static void expect_seen(const tally *t, const char *what)
{
    cr_expect_gt(t->dis, 50, "%s: %zu disagreements", what, t->dis);
    cr_expect_gt(t->mid_in, 5, "%s: %zu with |w| in [1/2, 3/4)", what, t->mid_in);
    cr_expect_gt(t->mid_out, 5, "%s: %zu with |w| in [1/4, 1/2)", what, t->mid_out);
}

static void holed_sphere(bool inward, const char *what)
{
    double c[3] = {0.017, -0.023, 0.011};
    shape s;
    shape_init(&s);
    shape_icosphere(&s, c, 0.7, 3, inward);
    shape_finish(&s);
    cut(&s, c[0], c[1] + 0.1, c[2] + 0.7, 0.3);
    cut(&s, c[0] + 0.7, c[1], c[2], 0.25);
    tally t = compare(shape_finish(&s), what);
    expect_seen(&t, what);
    if (inward) cr_expect_gt(t.neg, 10, "%s: %zu voxels with w <= -1/2", what, t.neg);
    shape_free(&s);
}

Test(mesh_repair, a_sphere_with_two_holes, .timeout = 600)
{
    holed_sphere(false, "sphere with two holes");
}

/* Facing inwards, w is near -1 inside: the repair takes |w|. */
Test(mesh_repair, a_sphere_facing_inwards_with_two_holes, .timeout = 600)
{
    holed_sphere(true, "inward sphere with two holes");
}

Test(mesh_repair, a_torus_with_a_hole, .timeout = 600)
{
    double c[3] = {0.013, 0.021, -0.017};
    shape s;
    shape_init(&s);
    shape_torus(&s, c, 0.6, 0.25, 48, 24);
    shape_finish(&s);
    cut(&s, c[0] + 0.85, c[1], c[2], 0.2);
    cut(&s, c[0], c[1] - 0.6, c[2] + 0.25, 0.15);
    tally t = compare(shape_finish(&s), "torus with two holes");
    expect_seen(&t, "torus with two holes");
    shape_free(&s);
}

/* A soup: every seventh triangle of a sphere missing, holes all over. */
Test(mesh_repair, a_soup, .timeout = 600)
{
    double c[3] = {0.01, -0.02, 0.03};
    shape s;
    shape_init(&s);
    shape_icosphere(&s, c, 0.8, 2, false);
    shape_remove(&s, not_every_seventh, NULL);
    tally t = compare(shape_finish(&s), "soup");
    expect_seen(&t, "soup");
    shape_free(&s);
}
