/* Marching cubes (iso.h): meshes of analytic shapes sampled into VOD files,
 * checked by iso_fixture.h's checker and by each vertex's distance to the
 * analytic surface; random volumes for the case table's consistency; normals;
 * mip levels and adaptive levels closed and near.  Workers, threads and
 * refusals: test_iso_parallel.c. */
#include <criterion/criterion.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "engine.h"
#include "expr.h"
#include "iso.h"
#include "mesh.h"
#include "vod.h"
#include "vod_volume.h"
#include "voxel.h"

#include "iso_fixture.h"

static void assert_near(const iso_mesh *m, const ramp *r, double tol, const char *what)
{
    double worst = 0;
    for (uint64_t i = 0; i < m->n_vertices; i++) {
        const float *p = m->pos + 3 * i;
        double d = fabs(r->dist(r->ud, p[0], p[1], p[2]));
        if (d > worst) worst = d;
    }
    cr_assert_leq(worst, tol, "%s: a vertex %g from the surface (allowed %g)", what, worst,
                  tol);
}

Test(iso, sphere_density_closed_near_and_its_volume)
{
    double R = 0.7;
    vol_spec s = cube_spec(48, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    iso_mesh m;
    polygonize(f, 127, 0, &m);
    assert_closed(&m, "sphere");
    assert_near(&m, &r, 0.5 * s.h, "sphere");
    /* every vertex within h/2 of the sphere: the volume within the shell */
    double v = check(&m).volume, exact = 4.0 / 3.0 * M_PI * R * R * R;
    double bound = 4.0 * M_PI * R * R * 0.5 * s.h;
    cr_assert_leq(fabs(v - exact), bound, "volume %g, exact %g, bound %g", v, exact, bound);
    iso_mesh_free(&m);
    vod_close(f);
}

Test(iso, torus_density_closed_near_and_its_volume)
{
    double rr[2] = {0.6, 0.25};
    vol_spec s = cube_spec(64, 16, -1, 1);
    ramp r = {torus_dist, rr, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    iso_mesh m;
    polygonize(f, 127, 0, &m);
    assert_closed(&m, "torus");
    assert_near(&m, &r, 0.5 * s.h, "torus");
    double v = check(&m).volume, exact = 2 * M_PI * M_PI * rr[0] * rr[1] * rr[1];
    double bound = 4 * M_PI * M_PI * rr[0] * rr[1] * 0.5 * s.h;
    cr_assert_leq(fabs(v - exact), bound, "volume %g, exact %g, bound %g", v, exact, bound);
    iso_mesh_free(&m);
    vod_close(f);
}

/* ---- Scene 1 of the paper, F / |grad F| as the distance ---- */

typedef struct {
    expr_vm *vm;
} scene;

static double scene_dist(const void *ud, double x, double y, double z)
{
    const scene *s = ud;
    double g[3];
    double f = expr_vm_grad(s->vm, 0, x, y, z, g);
    double len = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
    return len > 1e-9 ? f / len : (f > 0 ? 1e9 : -1e9);
}

static expr_tape *scene1_tape(void)
{
    FILE *fp = fopen("examples/scene1.vx", "rb");
    cr_assert_not_null(fp, "examples/scene1.vx (run from the repository root)");
    static char src[8192];
    size_t n = fread(src, 1, sizeof src - 1, fp);
    fclose(fp);
    expr_limits lim;
    expr_limits_default(&lim);
    expr_tape *t;
    expr_error e;
    cr_assert_eq(expr_compile(src, n, &lim, &t, &e), 0);
    return t;
}

Test(iso, scene1_density_closed_and_near)
{
    expr_tape *t = scene1_tape();
    scene sc;
    cr_assert_eq(expr_vm_new(t, 1, &sc.vm), 0);
    vol_spec s = cube_spec(96, 16, -1, 1);
    ramp r = {scene_dist, &sc, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    iso_mesh m;
    polygonize(f, 127, 0, &m);
    assert_closed(&m, "scene 1");
    /* F / |grad F| is a distance only to first order: where it says more
     * than h/2, F must change sign within h/2 along the gradient */
    for (uint64_t i = 0; i < m.n_vertices; i++) {
        const float *p = m.pos + 3 * i;
        double g[3], fv = expr_vm_grad(sc.vm, 0, p[0], p[1], p[2], g);
        double len = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
        if (len > 0 && fabs(fv) / len <= 0.5 * s.h) continue;
        double k = 0.5 * s.h / (len > 0 ? len : 1);
        double a = expr_vm_point(sc.vm, 0, p[0] - k * g[0], p[1] - k * g[1], p[2] - k * g[2]);
        double b = expr_vm_point(sc.vm, 0, p[0] + k * g[0], p[1] + k * g[1], p[2] + k * g[2]);
        cr_assert((a <= 0) != (b <= 0), "vertex %llu (%g %g %g) is not within h/2 of F = 0",
                  (unsigned long long)i, p[0], p[1], p[2]);
    }
    iso_mesh_free(&m);
    vod_close(f);
    expr_vm_free(sc.vm);
    expr_tape_free(t);
}

Test(iso, random_volumes_are_closed_whatever_the_cases)
{
    static const struct { uint32_t bits; int ch; uint32_t mode, iso; } kinds[] = {
        {1, VOXEL_CH_OCCUPANCY, 1, 127},
        {8, VOXEL_CH_DENSITY, 2, 127},
        {8, VOXEL_CH_DENSITY, 2, 40},
        {32, VOXEL_CH_SURFACE, 3, 127},
    };
    uint32_t seen[256] = {0};
    const iso_case *tab = iso_cases();
    for (size_t k = 0; k < sizeof kinds / sizeof *kinds; k++)
        for (int rep = 0; rep < 3; rep++) {
            vol_spec s = {{13 + rep, 9, 11 + 2 * rep}, 4, kinds[k].bits, kinds[k].ch,
                          0.1, {-0.5, 0.25, 1}};
            uint32_t mode = kinds[k].mode;
            vod_file *f = make_vod(&s, noise, &mode);
            for (int level = 0; level < 2; level++) {
                iso_mesh m;
                polygonize(f, kinds[k].iso, level, &m);
                char what[64];
                snprintf(what, sizeof what, "noise %zu.%d level %d", k, rep, level);
                assert_closed(&m, what);
                iso_mesh_free(&m);
            }
            vod_close(f);
        }
    /* every case's triangles use its crossing edges only */
    for (uint32_t cs = 1; cs < 255; cs++) {
        seen[cs] = tab[cs].ntri;
        for (uint32_t t = 0; t < tab[cs].ntri; t++)
            for (int i = 0; i < 3; i++) {
                uint32_t e = tab[cs].tri[t][i];
                if (e >= ISO_CENTRE_SLOT) continue;
                uint32_t c0 = iso_edge_corner(e), c1 = c0 | 1u << iso_edge_axis(e);
                cr_assert_neq(cs >> c0 & 1u, cs >> c1 & 1u, "case %u uses edge %u", cs, e);
            }
        cr_assert_gt(seen[cs], 0, "case %u has no triangle", cs);
    }
    cr_assert_eq(tab[0].ntri + tab[255].ntri, 0);
}

/* ---- normals ---- */

/* A solid ball of channel-3 voxels, each with the radial direction at its
 * centre as its normal (outwards, as the voxelizers store them). */
static uint32_t radial_surface(void *ud, double x, double y, double z)
{
    double R = *(const double *)ud;
    if (x * x + y * y + z * z >= R * R) return 0;
    const double n[3] = {x, y, z};
    return voxel_surface(n);
}

/* The worst angle (degrees) between a normal and the radial direction at
 * its vertex, over n vertices. */
static double worst_angle(const float *pos, const float *nrm, uint64_t n)
{
    double worst = 0;
    for (uint64_t i = 0; i < n; i++) {
        const float *p = pos + 3 * i, *q = nrm + 3 * i;
        double lp = sqrt((double)p[0] * p[0] + (double)p[1] * p[1] + (double)p[2] * p[2]);
        double lq = sqrt((double)q[0] * q[0] + (double)q[1] * q[1] + (double)q[2] * q[2]);
        double c = ((double)p[0] * q[0] + (double)p[1] * q[1] + (double)p[2] * q[2]) / (lp * lq);
        double a = lq > 0 ? acos(fmax(-1, fmin(1, c))) * 180 / M_PI : 180;
        if (a > worst) worst = a;
    }
    return worst;
}

/* The OBJ that vox mesh writes (iso_write) read back: its v and vn lines,
 * one normal per vertex. */
static double worst_angle_in_obj(const iso_mesh *m)
{
    FILE *f = tmpfile();
    cr_assert(f);
    cr_assert_eq(iso_write(fileno(f), m, ISO_FMT_OBJ, "normals", 2), 0);
    rewind(f);
    float *pos = malloc(m->n_vertices * 3 * sizeof *pos), *nrm = malloc(m->n_vertices * 3 * sizeof *nrm);
    uint64_t nv = 0, nn = 0;
    char line[256];
    while (fgets(line, sizeof line, f)) {
        float a, b, c;
        if (sscanf(line, "v %f %f %f", &a, &b, &c) == 3 && nv < m->n_vertices)
            pos[3 * nv] = a, pos[3 * nv + 1] = b, pos[3 * nv + 2] = c, nv++;
        else if (sscanf(line, "vn %f %f %f", &a, &b, &c) == 3 && nn < m->n_vertices)
            nrm[3 * nn] = a, nrm[3 * nn + 1] = b, nrm[3 * nn + 2] = c, nn++;
    }
    fclose(f);
    cr_assert_eq(nv, m->n_vertices, "the OBJ has %llu vertices of %llu", (unsigned long long)nv,
                 (unsigned long long)m->n_vertices);
    cr_assert_eq(nn, m->n_vertices, "the OBJ has %llu normals for %llu vertices",
                 (unsigned long long)nn, (unsigned long long)m->n_vertices);
    double w = worst_angle(pos, nrm, nv);
    free(pos);
    free(nrm);
    return w;
}

/* Every vertex normal, in the mesh and in the OBJ written from it, points
 * along the radius at the vertex.  Level 0: a vertex lies on an edge from
 * an occupied voxel's centre c, within a voxel h of it, and takes c's
 * normal (the empty end weighs 0), so it is off the radial direction at the
 * vertex by at most asin(h / |c|) = 3.9 degrees here (|c| > R - h), plus the
 * 12-bit packing's 0.1: the bound is 5.  Level 1: the blend of the two
 * ends' merged normals, each within the angle the 2h-voxel subtends: at
 * most about 2 asin(2h / (R - 2h)) = 15.8 degrees; the bound is 16.  A sign
 * lost in the blend or the normal turned inwards is off by far more. */
Test(iso, normals_point_along_the_radius)
{
    double R = 0.7;
    vol_spec s = {{48, 48, 48}, 8, 32, VOXEL_CH_SURFACE, 2.0 / 48, {-1, -1, -1}};
    vod_file *f = make_vod(&s, radial_surface, &R);
    static const double bound[2] = {5, 16};
    for (int level = 0; level < 2; level++) {
        iso_mesh m;
        polygonize(f, 127, level, &m);
        cr_assert(m.nrm, "level %d: no normals from channel 3", level);
        cr_assert_gt(m.n_vertices, 100);
        double w = worst_angle(m.pos, m.nrm, m.n_vertices), wf = worst_angle_in_obj(&m);
        fprintf(stderr, "NOTE: iso normals level %d: worst %.2f degrees off the radius (OBJ %.2f), "
                        "bound %.0f\n", level, w, wf, bound[level]);
        cr_assert_leq(w, bound[level], "level %d: a normal %.2f degrees off the radius", level, w);
        cr_assert_leq(wf, bound[level], "level %d: the OBJ's normal %.2f degrees off", level, wf);
        iso_mesh_free(&m);
    }
    vod_close(f);
}

/* ---- levels ---- */

Test(iso, every_mip_level_is_closed_and_coarser)
{
    double R = 0.8;
    vol_spec s = cube_spec(64, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    uint64_t last = UINT64_MAX;
    for (int l = 0; l < 3; l++) {
        iso_mesh m;
        polygonize(f, 127, l, &m);
        char what[32];
        snprintf(what, sizeof what, "level %d", l);
        assert_closed(&m, what);
        cr_assert_lt(m.n_triangles, last, "level %d has no fewer triangles", l);
        last = m.n_triangles;
        iso_mesh_free(&m);
    }
    vod_close(f);
}

Test(iso, adaptive_levels_have_no_boundary_at_any_radii)
{
    double R = 0.8;
    vol_spec s = cube_spec(64, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    iso_mesh full;
    polygonize(f, 127, 0, &full);
    static const double c[][3] = {{0, 0, 0}, {0.8, 0, 0}, {-0.5, 0.5, 0.6}, {2, 2, 2}};
    static const double radii[][3] = {{0.3, 0.6, 0.9}, {0.1, 0.2, 0.3}, {0.5, 1, 2},
                                      {0, 0.01, 0.02}};
    for (size_t i = 0; i < sizeof c / sizeof *c; i++)
        for (size_t j = 0; j < sizeof radii / sizeof *radii; j++)
            for (uint32_t n = 1; n <= 3; n++) {
                iso_mesh m;
                iso_request rq = {.iso = 127, .center = c[i], .radii = radii[j], .nradii = n};
                polygonize_rq(f, &rq, &m);
                char what[64];
                snprintf(what, sizeof what, "centre %zu, radii %zu x %u", i, j, n);
                assert_closed(&m, what);
                iso_mesh_free(&m);
            }
    /* far away, everything at the coarsest level: fewer triangles */
    iso_mesh m;
    double far[3] = {9, 9, 9}, rad[2] = {0.1, 0.2};
    iso_request rq = {.iso = 127, .center = far, .radii = rad, .nradii = 2};
    polygonize_rq(f, &rq, &m);
    cr_assert_lt(m.n_triangles, full.n_triangles / 4);
    iso_mesh_free(&m);
    iso_mesh_free(&full);
    vod_close(f);
}

/* The accuracy of coarse and adaptive levels of detail, on a sphere.
 * Mip level l: every vertex within a quarter of a level-l voxel (2^l h / 4)
 * of the analytic sphere, the enclosed volume within that shell's volume
 * of the exact one: a level whose voxels sat half a voxel off (the usual
 * slip, 2^(l-1) h) would be twice the bound away.  Adaptive levels: a vertex
 * within radii[0] of the centre lies in a block that touches the first
 * sphere, so at level 0 (less 2h: the wall that closes the level-0 region
 * lies within a voxel or so of its boundary): within h / 2 of the sphere as
 * at level 0.  Elsewhere the regions' walls lie inside the solid, so only
 * how far a vertex is outside the sphere is bounded (the coarsest level's
 * quarter voxel), and the volume, walls and all, within that shell. */
static double worst_dist(const iso_mesh *m, const ramp *r, const double *c, double within,
                         int outside_only)
{
    double worst = 0;
    for (uint64_t i = 0; i < m->n_vertices; i++) {
        const float *p = m->pos + 3 * i;
        if (c && hypot(hypot(p[0] - c[0], p[1] - c[1]), p[2] - c[2]) > within) continue;
        double d = r->dist(r->ud, p[0], p[1], p[2]);
        d = outside_only ? d : fabs(d);
        if (d > worst) worst = d;
    }
    return worst;
}

Test(iso, coarse_and_adaptive_levels_stay_near_the_surface)
{
    double R = 0.8;
    vol_spec s = cube_spec(64, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    double exact = 4.0 / 3.0 * M_PI * R * R * R;
    for (int l = 0; l < 3; l++) {
        iso_mesh m;
        polygonize(f, 127, l, &m);
        double tol = l ? 0.25 * ldexp(s.h, l) : 0.5 * s.h, w = worst_dist(&m, &r, NULL, 0, 0);
        double v = check(&m).volume, shell = 4.0 * M_PI * R * R * tol;
        fprintf(stderr, "NOTE: iso level %d: worst vertex %.3f h from the sphere (bound %.2f h), "
                        "volume off by %.4f (bound %.4f)\n", l, w / s.h, tol / s.h,
                fabs(v - exact), shell);
        cr_assert_leq(w, tol, "level %d: a vertex %g from the sphere (allowed %g)", l, w, tol);
        cr_assert_leq(fabs(v - exact), shell, "level %d: volume %g, exact %g", l, v, exact);
        iso_mesh_free(&m);
    }
    double c[3] = {0.8, 0, 0}, radii[2] = {0.3, 0.6};
    iso_params p;
    err_info err = {0};
    iso_request rq = {.iso = 127, .center = c, .radii = radii, .nradii = 2};
    cr_assert_eq(iso_params_make(f, &rq, &p, &err), 0, "%s", err.msg);
    iso_mesh m;
    polygonize_rq(f, &rq, &m);
    double fine = worst_dist(&m, &r, c, radii[0] - 2 * s.h, 0);
    double out = worst_dist(&m, &r, NULL, 0, 1), top = 0.25 * ldexp(s.h, (int)p.lod_top);
    double v = check(&m).volume, shell = 4.0 * M_PI * R * R * top;
    fprintf(stderr, "NOTE: iso adaptive (levels 0 to %u): worst vertex %.3f h near the centre "
                    "(bound 0.5 h), %.3f h outside (bound %.2f h), volume off by %.4f (bound %.4f)\n",
            p.lod_top, fine / s.h, out / s.h, top / s.h, fabs(v - exact), shell);
    cr_assert_leq(fine, 0.5 * s.h, "a vertex near the centre %g from the sphere", fine);
    cr_assert_leq(out, top, "a vertex %g outside the sphere (allowed %g)", out, top);
    cr_assert_leq(fabs(v - exact), shell, "adaptive: volume %g, exact %g", v, exact);
    iso_mesh_free(&m);
    vod_close(f);
}
