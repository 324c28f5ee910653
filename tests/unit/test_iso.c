/* Marching cubes (iso.h): meshes of analytic shapes sampled into VOD files
 * checked by a checker written here (edge-use counts and directions, each
 * vertex's link one cycle, no two vertices at one place, the enclosed
 * volume by the divergence theorem, each vertex's distance to the analytic
 * surface); random volumes for the case table's consistency; 1 and 2
 * workers against the serial run, byte for byte; mip levels and adaptive
 * levels closed; bad parameters refused; the input, the checks and the
 * writers on several threads against one, and the files read back. */
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

/* ---- VOD files from functions ---- */

typedef uint32_t (*voxel_fn)(void *ud, double x, double y, double z);

typedef struct {
    uint32_t dims[3], brick, bits;
    int channel;
    double h, origin[3];
} vol_spec;

/* The file of fn sampled at the voxel centres (world coordinates). */
static vod_file *make_vod(const vol_spec *s, voxel_fn fn, void *ud)
{
    uint32_t vbits = s->bits == 32 ? 32 : 8;
    size_t bytes = vod_volume_bytes(s->dims, vbits, 16, UINT32_MAX);
    void *arena = malloc(bytes);
    vod_volume *v;
    cr_assert_eq(vod_volume_init(&v, arena, bytes, s->dims, vbits, 16), 0);
    for (uint32_t z = 0; z < s->dims[2]; z++)
        for (uint32_t y = 0; y < s->dims[1]; y++)
            for (uint32_t x = 0; x < s->dims[0]; x++) {
                uint32_t val = fn(ud, s->origin[0] + (x + 0.5) * s->h,
                                  s->origin[1] + (y + 0.5) * s->h,
                                  s->origin[2] + (z + 0.5) * s->h);
                if (val) cr_assert_eq(vod_volume_set(v, x, y, z, val), 0);
            }
    vod_params p;
    vod_params_default(&p);
    p.channel = s->channel;
    p.brick = s->brick;
    for (int a = 0; a < 3; a++) {
        p.volume[a] = s->dims[a];
        p.voxel_scale[a] = (float)s->h;
        p.origin[a] = (float)s->origin[a];
    }
    vod_source src = vod_volume_source(v);
    vod_membuf mb = {0};
    vod_sink sink = {vod_mem_write, &mb};
    char err[256] = "";
    cr_assert_eq(vod_write(&src, &p, &sink, NULL, err, sizeof err), 0, "%s", err);
    vod_file *f;
    cr_assert_eq(vod_read(mb.p, mb.n, &f, err, sizeof err), 0, "%s", err);
    free(mb.p);
    free(arena);
    return f;
}

static void *heap(void *ud, size_t n)
{
    return *(void **)ud = malloc(n);
}

static void polygonize(const vod_file *f, uint32_t iso, int level, const double *c,
                       const double *radii, uint32_t nr, iso_mesh *m)
{
    iso_params p;
    char err[256] = "";
    cr_assert_eq(iso_params_make(f, iso, level, c, radii, nr, &p, err, sizeof err), 0,
                 "%s", err);
    void *mem = NULL;
    iso_input in;
    cr_assert_eq(iso_input_make(f, &p, heap, &mem, &in), 0);
    cr_assert_eq(iso_run_serial(&p, &in, m, err, sizeof err), 0, "%s", err);
    free(mem);
}

/* ---- the checker ---- */

typedef struct {
    uint64_t open, nonmanifold, inconsistent, degenerate, bad_links, same_place;
    double volume;
} topo;

typedef struct {
    uint64_t key;
    int dir;
} dedge;

static int by_key(const void *a, const void *b)
{
    uint64_t x = ((const dedge *)a)->key, y = ((const dedge *)b)->key;
    return (x > y) - (x < y);
}

static void check_edges(const iso_mesh *m, topo *t)
{
    size_t n = 3 * m->n_triangles;
    dedge *e = malloc((n ? n : 1) * sizeof *e);
    for (uint64_t i = 0; i < m->n_triangles; i++)
        for (int k = 0; k < 3; k++) {
            uint32_t a = m->tri[3 * i + k], b = m->tri[3 * i + (k + 1) % 3];
            uint64_t lo = a < b ? a : b, hi = a < b ? b : a;
            e[3 * i + k] = (dedge){lo << 32 | hi, a < b ? 1 : -1};
            if (a == b) t->degenerate++;
        }
    qsort(e, n, sizeof *e, by_key);
    for (size_t i = 0; i < n;) {
        size_t j = i;
        int sum = 0;
        while (j < n && e[j].key == e[i].key) sum += e[j++].dir;
        if (j - i == 1) t->open++;
        else if (j - i > 2) t->nonmanifold++;
        else if (sum != 0) t->inconsistent++;
        i = j;
    }
    free(e);
}

/* Each vertex's link (the edges opposite it in its triangles) must be one
 * cycle: its triangles form a single disk round it. */
typedef struct {
    uint32_t v, from, to;
} link_edge;

static int by_vertex(const void *a, const void *b)
{
    const link_edge *x = a, *y = b;
    if (x->v != y->v) return x->v < y->v ? -1 : 1;
    return (x->from > y->from) - (x->from < y->from);
}

static int one_cycle(const link_edge *l, size_t n)
{
    uint32_t at = l[0].to;
    for (size_t step = 1; step < n; step++) {
        size_t lo = 0, hi = n; /* l sorted by from */
        while (lo < hi) {
            size_t mid = (lo + hi) / 2;
            if (l[mid].from < at) lo = mid + 1;
            else hi = mid;
        }
        if (lo == n || l[lo].from != at) return 0;
        at = l[lo].to;
        if (at == l[0].from) return step == n - 1;
    }
    return at == l[0].from;
}

static void check_links(const iso_mesh *m, topo *t)
{
    size_t n = 3 * m->n_triangles;
    link_edge *l = malloc((n ? n : 1) * sizeof *l);
    for (uint64_t i = 0; i < m->n_triangles; i++)
        for (int k = 0; k < 3; k++)
            l[3 * i + k] = (link_edge){m->tri[3 * i + k], m->tri[3 * i + (k + 1) % 3],
                                       m->tri[3 * i + (k + 2) % 3]};
    qsort(l, n, sizeof *l, by_vertex);
    for (size_t i = 0; i < n;) {
        size_t j = i;
        while (j < n && l[j].v == l[i].v) j++;
        if (!one_cycle(l + i, j - i)) t->bad_links++;
        i = j;
    }
    free(l);
}

static int by_pos(const void *a, const void *b)
{
    return memcmp(a, b, 12);
}

static void check_places(const iso_mesh *m, topo *t)
{
    float *p = malloc(12 * (m->n_vertices ? m->n_vertices : 1));
    memcpy(p, m->pos, 12 * m->n_vertices);
    qsort(p, m->n_vertices, 12, by_pos);
    for (uint64_t i = 1; i < m->n_vertices; i++)
        if (!memcmp(p + 3 * i, p + 3 * (i - 1), 12)) t->same_place++;
    free(p);
}

static topo check(const iso_mesh *m)
{
    topo t = {0};
    check_edges(m, &t);
    check_links(m, &t);
    check_places(m, &t);
    for (uint64_t i = 0; i < m->n_triangles; i++) {
        const float *a = m->pos + 3 * m->tri[3 * i], *b = m->pos + 3 * m->tri[3 * i + 1],
                    *c = m->pos + 3 * m->tri[3 * i + 2];
        t.volume += (a[0] * ((double)b[1] * c[2] - (double)b[2] * c[1]) -
                     a[1] * ((double)b[0] * c[2] - (double)b[2] * c[0]) +
                     a[2] * ((double)b[0] * c[1] - (double)b[1] * c[0])) / 6.0;
    }
    return t;
}

static void assert_closed(const iso_mesh *m, const char *what)
{
    topo t = check(m);
    cr_assert_gt(m->n_triangles, 0, "%s: no triangles", what);
    cr_assert(!t.open && !t.nonmanifold && !t.inconsistent && !t.degenerate,
              "%s: %llu open, %llu non-manifold, %llu inconsistent edges, %llu "
              "degenerate triangles", what, (unsigned long long)t.open,
              (unsigned long long)t.nonmanifold, (unsigned long long)t.inconsistent,
              (unsigned long long)t.degenerate);
    cr_assert(!t.bad_links, "%s: %llu vertices whose triangles are not one disk", what,
              (unsigned long long)t.bad_links);
    cr_assert(!t.same_place, "%s: %llu vertices at another's place", what,
              (unsigned long long)t.same_place);
    cr_assert_gt(t.volume, 0, "%s: not oriented outwards (volume %g)", what, t.volume);
}

/* ---- shapes: signed distances as density ramps ---- */

typedef struct {
    double (*dist)(const void *, double, double, double); /* < 0 inside */
    const void *ud;
    double h;
} ramp;

/* Density 127.5 on the surface, 64 per voxel inwards, clamped. */
static uint32_t ramp_value(void *ud, double x, double y, double z)
{
    const ramp *r = ud;
    double v = 127.5 - 64.0 * r->dist(r->ud, x, y, z) / r->h;
    return v <= 0 ? 0 : v >= 255 ? 255 : (uint32_t)lround(v);
}

static double sphere_dist(const void *ud, double x, double y, double z)
{
    return sqrt(x * x + y * y + z * z) - *(const double *)ud;
}

static double torus_dist(const void *ud, double x, double y, double z)
{
    const double *rr = ud;
    double q = sqrt(x * x + y * y) - rr[0];
    return sqrt(q * q + z * z) - rr[1];
}

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

static vol_spec cube_spec(uint32_t n, uint32_t brick, double lo, double hi)
{
    vol_spec s = {{n, n, n}, brick, 8, VOXEL_CH_DENSITY, (hi - lo) / n, {lo, lo, lo}};
    return s;
}

Test(iso, sphere_density_closed_near_and_its_volume)
{
    double R = 0.7;
    vol_spec s = cube_spec(48, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    iso_mesh m;
    polygonize(f, 127, 0, NULL, NULL, 0, &m);
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
    polygonize(f, 127, 0, NULL, NULL, 0, &m);
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
    polygonize(f, 127, 0, NULL, NULL, 0, &m);
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

/* ---- the table: random volumes hit every case and every face pairing ---- */

static uint64_t rng = 0x2545f4914f6cdd1dull;
static uint32_t rnd(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return (uint32_t)(rng >> 16);
}

static uint32_t noise(void *ud, double x, double y, double z)
{
    (void)x, (void)y, (void)z;
    uint32_t mode = *(uint32_t *)ud, v = rnd();
    return mode == 1 ? (v & 1u) : mode == 2 ? (v % 256) : (v & 1u ? VOXEL_FULL : 0);
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
                polygonize(f, kinds[k].iso, level, NULL, NULL, 0, &m);
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
        polygonize(f, 127, level, NULL, NULL, 0, &m);
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
        polygonize(f, 127, l, NULL, NULL, 0, &m);
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
    polygonize(f, 127, 0, NULL, NULL, 0, &full);
    static const double c[][3] = {{0, 0, 0}, {0.8, 0, 0}, {-0.5, 0.5, 0.6}, {2, 2, 2}};
    static const double radii[][3] = {{0.3, 0.6, 0.9}, {0.1, 0.2, 0.3}, {0.5, 1, 2},
                                      {0, 0.01, 0.02}};
    for (size_t i = 0; i < sizeof c / sizeof *c; i++)
        for (size_t j = 0; j < sizeof radii / sizeof *radii; j++)
            for (uint32_t n = 1; n <= 3; n++) {
                iso_mesh m;
                polygonize(f, 127, 0, c[i], radii[j], n, &m);
                char what[64];
                snprintf(what, sizeof what, "centre %zu, radii %zu x %u", i, j, n);
                assert_closed(&m, what);
                iso_mesh_free(&m);
            }
    /* far away, everything at the coarsest level: fewer triangles */
    iso_mesh m;
    double far[3] = {9, 9, 9}, rad[2] = {0.1, 0.2};
    polygonize(f, 127, 0, far, rad, 2, &m);
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
        polygonize(f, 127, l, NULL, NULL, 0, &m);
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
    char err[256];
    cr_assert_eq(iso_params_make(f, 127, 0, c, radii, 2, &p, err, sizeof err), 0, "%s", err);
    iso_mesh m;
    polygonize(f, 127, 0, c, radii, 2, &m);
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

/* ---- the engine ---- */

static int same_mesh(const iso_mesh *a, const iso_mesh *b)
{
    return a->n_vertices == b->n_vertices && a->n_triangles == b->n_triangles &&
           !memcmp(a->pos, b->pos, 12 * a->n_vertices) &&
           !memcmp(a->tri, b->tri, 12 * a->n_triangles) && !a->nrm == !b->nrm &&
           (!a->nrm || !memcmp(a->nrm, b->nrm, 12 * a->n_vertices));
}

Test(iso, the_workers_give_the_serial_mesh_byte_for_byte)
{
    double rr[2] = {0.6, 0.25};
    vol_spec s = cube_spec(80, 8, -1, 1);
    ramp r = {torus_dist, rr, s.h};
    vod_file *files[2] = {make_vod(&s, ramp_value, &r), NULL};
    uint32_t mode = 3;
    vol_spec s3 = {{21, 17, 19}, 4, 32, VOXEL_CH_SURFACE, 0.1, {0, 0, 0}};
    files[1] = make_vod(&s3, noise, &mode);
    for (int w = 1; w <= 2; w++) {
        engine_opts o = {.workers = w, .shm_bytes = (size_t)256 << 20};
        engine *e;
        char err[256] = "";
        cr_assert_eq(engine_create(&o, &e, err, sizeof err), 0, "%s", err);
        for (int k = 0; k < 2; k++)
            for (int level = 0; level < 2; level++) {
                iso_params p;
                cr_assert_eq(iso_params_make(files[k], 127, level, NULL, NULL, 0, &p, err,
                                             sizeof err), 0, "%s", err);
                iso_mesh ref, m;
                polygonize(files[k], 127, level, NULL, NULL, 0, &ref);
                engine_iso_job job = {.file = files[k], .p = &p};
                engine_result res;
                cr_assert_eq(engine_iso(e, &job, &m, &res), 0, "%s", res.error);
                cr_assert(same_mesh(&ref, &m), "file %d level %d, %d workers: another mesh",
                          k, level, w);
                cr_assert_eq(!m.nrm, k == 0, "normals only from channel 3");
                iso_mesh_free(&ref);
                iso_mesh_free(&m);
            }
        engine_destroy(e);
    }
    vod_close(files[0]);
    vod_close(files[1]);
}

/* ---- refusals ---- */

Test(iso, bad_parameters_are_refused)
{
    double R = 0.5;
    vol_spec s = cube_spec(16, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    iso_params p;
    char err[256];
    double c[3] = {0, 0, 0}, dec[2] = {1, 0.5}, nan_r[1] = {NAN};
    cr_assert_eq(iso_params_make(f, 255, 0, NULL, NULL, 0, &p, err, sizeof err), -EINVAL);
    cr_assert_eq(iso_params_make(f, 127, 2, NULL, NULL, 0, &p, err, sizeof err), -EINVAL);
    cr_assert(strstr(err, "levels 0..1"), "%s", err);
    cr_assert_eq(iso_params_make(f, 127, 0, c, dec, 2, &p, err, sizeof err), -EINVAL);
    cr_assert(strstr(err, "increasing"), "%s", err);
    cr_assert_eq(iso_params_make(f, 127, 0, c, nan_r, 1, &p, err, sizeof err), -EINVAL);
    vod_close(f);
}

Test(iso, a_piece_that_refers_to_nobody_is_refused)
{
    double R = 0.5;
    vol_spec s = cube_spec(16, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    iso_params p;
    char err[256] = "";
    cr_assert_eq(iso_params_make(f, 127, 0, NULL, NULL, 0, &p, err, sizeof err), 0);
    void *mem = NULL;
    iso_input in;
    cr_assert_eq(iso_input_make(f, &p, heap, &mem, &in), 0);
    iso_task *t;
    uint64_t n;
    cr_assert_eq(iso_tasks(&p, &in, &t, &n), 0);
    cr_assert_gt(n, 1);
    iso_work *w;
    cr_assert_eq(iso_work_new(&p, &w), 0);
    iso_piece pc;
    cr_assert_eq(iso_task_run(w, &p, &in, &t[0], &pc), 0);
    cr_assert_gt(pc.ne, 0);
    /* the first task alone: its references to the others find nobody */
    iso_mesh m;
    cr_assert_eq(iso_merge(&p, &pc, 1, &m, err, sizeof err), -EPROTO);
    cr_assert(strstr(err, "refers to a vertex no piece has"), "%s", err);
    /* a piece that owns every vertex it uses, alone, then with a
     * reference past its vertices */
    uint64_t i = 0;
    for (; i < n; i++) {
        cr_assert_eq(iso_task_run(w, &p, &in, &t[i], &pc), 0);
        if (!pc.ne && pc.nt) break;
    }
    cr_assert_lt(i, n, "no task owns all its vertices");
    cr_assert_eq(iso_merge(&p, &pc, 1, &m, err, sizeof err), 0, "%s", err);
    cr_assert_eq(m.n_triangles, pc.nt);
    iso_mesh_free(&m);
    uint32_t *tri = (uint32_t *)pc.tri;
    tri[0] = pc.nv + 5;
    cr_assert_eq(iso_merge(&p, &pc, 1, &m, err, sizeof err), -EPROTO);
    cr_assert(strstr(err, "refers to no vertex"), "%s", err);
    iso_work_free(w);
    free(t);
    free(mem);
    vod_close(f);
}

/* A worker stopped before the job: it holds its task without a heartbeat,
 * is killed after the stall timeout and replaced; the tasks it never ran
 * are run by the other worker or the master, and the mesh is the same. */
Test(iso, a_stalled_worker_costs_nothing_but_time)
{
    double R = 0.7;
    vol_spec s = cube_spec(64, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    engine_opts o = {.workers = 2, .shm_bytes = (size_t)256 << 20, .stall_timeout = 0.2};
    engine *e;
    char err[256] = "";
    cr_assert_eq(engine_create(&o, &e, err, sizeof err), 0, "%s", err);
    iso_params p;
    cr_assert_eq(iso_params_make(f, 127, 0, NULL, NULL, 0, &p, err, sizeof err), 0);
    iso_mesh ref, m;
    polygonize(f, 127, 0, NULL, NULL, 0, &ref);
    cr_assert_eq(kill(engine_worker_pid(e, 0), SIGSTOP), 0);
    engine_iso_job job = {.file = f, .p = &p};
    engine_result res;
    cr_assert_eq(engine_iso(e, &job, &m, &res), 0, "%s", res.error);
    cr_assert_geq(res.stalls, 1, "the stopped worker was not replaced");
    cr_assert(same_mesh(&ref, &m), "another mesh after a stall");
    iso_mesh_free(&m);
    /* and the engine goes on: the next job on the replaced worker */
    cr_assert_eq(engine_iso(e, &job, &m, &res), 0, "%s", res.error);
    cr_assert(same_mesh(&ref, &m));
    iso_mesh_free(&m);
    iso_mesh_free(&ref);
    engine_destroy(e);
    vod_close(f);
}

/* Shared memory too small for the pieces: a limit, said. */
Test(iso, too_small_a_segment_is_a_limit)
{
    double R = 0.7;
    vol_spec s = cube_spec(128, 16, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    engine_opts o = {.workers = 1, .shm_bytes = (size_t)3 << 20};
    engine *e;
    char err[256] = "";
    cr_assert_eq(engine_create(&o, &e, err, sizeof err), 0, "%s", err);
    iso_params p;
    cr_assert_eq(iso_params_make(f, 127, 0, NULL, NULL, 0, &p, err, sizeof err), 0);
    engine_iso_job job = {.file = f, .p = &p};
    engine_result res;
    iso_mesh m;
    cr_assert_lt(engine_iso(e, &job, &m, &res), 0);
    cr_assert_eq(res.failure, ENGINE_LIMIT, "%s", res.error);
    cr_assert(strstr(res.error, "does not fit in shared memory"), "%s", res.error);
    engine_destroy(e);
    vod_close(f);
}

/* vod_foreach_brick (what the input is made from): every non-empty brick
 * of a level once, the pointer vod_brick gives for its coordinates. */
typedef struct {
    const vod_file *f;
    int level;
    uint64_t n, wrong;
} walk_check;

static int count_brick(void *ud, const uint32_t b[3], const uint8_t *raw)
{
    walk_check *w = ud;
    w->n++;
    if (vod_brick(w->f, w->level, b) != raw) w->wrong++;
    return 0;
}

Test(iso, vod_foreach_brick_walks_every_brick_once)
{
    uint32_t mode = 2;
    vol_spec s = {{37, 21, 29}, 4, 8, VOXEL_CH_DENSITY, 0.1, {0, 0, 0}};
    vod_file *f = make_vod(&s, noise, &mode);
    for (int l = 0; l < (int)vod_get_info(f)->height; l++) {
        walk_check w = {f, l, 0, 0};
        cr_assert_eq(vod_foreach_brick(f, l, count_brick, &w), 0);
        uint32_t side = vod_level_size(f, l) / 4, b[3];
        uint64_t expect = 0;
        for (b[2] = 0; b[2] < side; b[2]++)
            for (b[1] = 0; b[1] < side; b[1]++)
                for (b[0] = 0; b[0] < side; b[0]++) expect += vod_brick(f, l, b) != NULL;
        cr_assert_eq(w.n, expect, "level %d: %llu bricks walked, %llu there", l,
                     (unsigned long long)w.n, (unsigned long long)expect);
        cr_assert_eq(w.wrong, 0, "level %d", l);
    }
    cr_assert_eq(vod_foreach_brick(f, 99, count_brick, NULL), -EINVAL);
    vod_close(f);
}

/* The bricks' states drop the tasks wholly inside a solid or wholly
 * outside: fewer tasks, the same mesh, byte for byte. */
Test(iso, a_solid_interior_costs_no_task)
{
    double R = 0.85;
    vol_spec s = cube_spec(96, 8, -1, 1);
    ramp r = {sphere_dist, &R, s.h};
    vod_file *f = make_vod(&s, ramp_value, &r);
    iso_params p;
    char err[256] = "";
    cr_assert_eq(iso_params_make(f, 127, 0, NULL, NULL, 0, &p, err, sizeof err), 0, "%s", err);
    void *mem = NULL;
    iso_input in;
    cr_assert_eq(iso_input_make(f, &p, heap, &mem, &in), 0);
    iso_input blind = in;
    blind.state = NULL;
    iso_task *t;
    uint64_t n_state, n_blind;
    cr_assert_eq(iso_tasks(&p, &in, &t, &n_state), 0);
    free(t);
    cr_assert_eq(iso_tasks(&p, &blind, &t, &n_blind), 0);
    free(t);
    cr_assert_lt(n_state, n_blind, "%llu tasks with the states, %llu without",
                 (unsigned long long)n_state, (unsigned long long)n_blind);
    iso_mesh a, b;
    cr_assert_eq(iso_run_serial(&p, &in, &a, err, sizeof err), 0, "%s", err);
    cr_assert_eq(iso_run_serial(&p, &blind, &b, err, sizeof err), 0, "%s", err);
    cr_assert(same_mesh(&a, &b), "the states changed the mesh");
    assert_closed(&a, "sphere, interior skipped");
    iso_mesh_free(&a);
    iso_mesh_free(&b);
    free(mem);
    vod_close(f);
}

/* ---- several threads against one ---- */

/* A mesh of nv random vertices (and normals) and nt triangles of three
 * distinct random indices: several of the writer's chunks of each. */
static iso_mesh random_mesh(uint64_t nv, uint64_t nt, int normals, unsigned seed)
{
    iso_mesh m = {.n_vertices = nv, .n_triangles = nt, .pos = malloc(12 * nv),
                  .nrm = normals ? malloc(12 * nv) : NULL, .tri = malloc(12 * nt)};
    srand(seed);
    for (uint64_t i = 0; i < 3 * nv; i++) {
        m.pos[i] = (float)rand() / (float)RAND_MAX * 2.0f - 1.0f;
        if (normals) m.nrm[i] = (float)rand() / (float)RAND_MAX - 0.5f;
    }
    for (uint64_t i = 0; i < nt; i++) {
        uint32_t a = (uint32_t)(rand() % (int)nv), b, c;
        do b = (uint32_t)(rand() % (int)nv); while (b == a);
        do c = (uint32_t)(rand() % (int)nv); while (c == a || c == b);
        m.tri[3 * i] = a, m.tri[3 * i + 1] = b, m.tri[3 * i + 2] = c;
    }
    return m;
}

/* m written in format f by `threads` threads after `skip` bytes already in
 * the file: the file's bytes past them, *len long. */
static uint8_t *written(const iso_mesh *m, iso_format f, unsigned threads, size_t skip,
                        size_t *len)
{
    char path[] = "/tmp/test_iso_writeXXXXXX";
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    unlink(path);
    uint8_t pad[64] = {0};
    cr_assert_eq(write(fd, pad, skip), (ssize_t)skip);
    cr_assert_eq(iso_write(fd, m, f, "a comment", threads), 0);
    off_t end = lseek(fd, 0, SEEK_CUR);
    cr_assert_eq(end, lseek(fd, 0, SEEK_END), "the fd stands at the file's end");
    *len = (size_t)end - skip;
    uint8_t *buf = malloc(*len ? *len : 1);
    cr_assert_eq(pread(fd, buf, *len, (off_t)skip), (ssize_t)*len);
    close(fd);
    return buf;
}

Test(iso, the_writers_on_several_threads_write_one_threads_bytes)
{
    static const iso_format fmt[] = {ISO_FMT_PLY, ISO_FMT_PLY_ASCII, ISO_FMT_OBJ, ISO_FMT_STL};
    for (int normals = 0; normals < 2; normals++) {
        iso_mesh m = random_mesh(20011, 30013, normals, 7u + (unsigned)normals);
        for (size_t k = 0; k < sizeof fmt / sizeof *fmt; k++) {
            size_t n1, nn;
            uint8_t *one = written(&m, fmt[k], 1, 0, &n1);
            for (unsigned threads = 2; threads <= 5; threads += 3) {
                uint8_t *many = written(&m, fmt[k], threads, 17, &nn);
                cr_assert(n1 == nn && !memcmp(one, many, n1),
                          "format %d, normals %d: %u threads differ from one", (int)fmt[k],
                          normals, threads);
                free(many);
            }
            /* read back by the loaders (an independent parser): every
             * vertex and triangle as written (STL has no shared vertices) */
            mesh back;
            mesh_error me;
            if (fmt[k] != ISO_FMT_STL) {
                cr_assert_eq(mesh_parse(one, n1, MESH_FORMAT_AUTO, NULL, &back, &me), 0, "%s",
                             me.msg);
                cr_assert_eq(back.n_vertices, m.n_vertices);
                cr_assert_eq(back.n_triangles, m.n_triangles);
                cr_assert(!memcmp(back.vertices, m.pos, 12 * m.n_vertices));
                cr_assert(!memcmp(back.triangles, m.tri, 12 * m.n_triangles));
                mesh_free(&back);
            } else
                cr_assert_eq(n1, 84 + 50 * m.n_triangles);
            free(one);
        }
        iso_mesh_free(&m);
    }
}

/* Waves of density: surface in nearly every brick, few bricks alike. */
static uint32_t waves(void *ud, double x, double y, double z)
{
    (void)ud;
    return (uint32_t)lround(127.5 + 127 * sin(7 * x) * sin(6 * y + 0.3) * sin(5 * z + 0.7));
}

/* An fd in append mode (pwrite would append) and a pipe (no offsets):
 * written in order by one thread, the same bytes. */
Test(iso, the_writers_on_an_appending_fd_or_a_pipe_write_in_order)
{
    iso_mesh m = random_mesh(20011, 30013, 1, 3);
    size_t n1;
    uint8_t *one = written(&m, ISO_FMT_OBJ, 1, 0, &n1);
    char path[] = "/tmp/test_iso_appendXXXXXX";
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    close(fd);
    fd = open(path, O_WRONLY | O_APPEND);
    unlink(path);
    cr_assert_eq(iso_write(fd, &m, ISO_FMT_OBJ, "a comment", 4), 0);
    cr_assert_eq(lseek(fd, 0, SEEK_END), (off_t)n1);
    uint8_t *back = malloc(n1);
    char fdpath[64];
    snprintf(fdpath, sizeof fdpath, "/proc/self/fd/%d", fd);
    int rd = open(fdpath, O_RDONLY);
    cr_assert_geq(rd, 0);
    cr_assert_eq(pread(rd, back, n1, 0), (ssize_t)n1);
    cr_assert(!memcmp(one, back, n1), "appending: other bytes");
    close(rd);
    close(fd);
    /* a pipe: a small mesh, whose file fits the pipe's buffer */
    iso_mesh small = random_mesh(50, 60, 0, 5);
    size_t ns;
    uint8_t *want = written(&small, ISO_FMT_PLY, 1, 0, &ns);
    cr_assert_lt(ns, 60000);
    int pp[2];
    cr_assert_eq(pipe(pp), 0);
    cr_assert_eq(iso_write(pp[1], &small, ISO_FMT_PLY, "a comment", 4), 0);
    close(pp[1]);
    cr_assert_eq(read(pp[0], back, ns + 1), (ssize_t)ns);
    cr_assert(!memcmp(want, back, ns), "a pipe: other bytes");
    close(pp[0]);
    free(want), free(back), free(one);
    iso_mesh_free(&small);
    iso_mesh_free(&m);
}

Test(iso, the_input_and_the_checks_on_several_threads_are_one_threads)
{
    vol_spec s = cube_spec(128, 8, -1, 1);
    vod_file *f = make_vod(&s, waves, NULL);
    iso_params p;
    char err[256] = "", err3[256] = "";
    cr_assert_eq(iso_params_make(f, 127, 0, NULL, NULL, 0, &p, err, sizeof err), 0);
    void *mem1 = NULL, *mem3 = NULL;
    iso_input a, b;
    cr_assert_eq(iso_input_make_threads(f, &p, heap, &mem1, 1, &a), 0);
    cr_assert_eq(iso_input_make_threads(f, &p, heap, &mem3, 3, &b), 0);
    cr_assert(a.n == b.n && a.raw_bytes == b.raw_bytes && a.raw_bytes >= 2u << 20,
              "want several parts of the copy: %zu bytes", (size_t)a.raw_bytes);
    cr_assert(!memcmp(a.keys, b.keys, 8 * a.n) && !memcmp(a.offs, b.offs, 8 * a.n) &&
              !memcmp(a.state, b.state, a.n) && !memcmp(a.raw, b.raw, a.raw_bytes));
    /* every piece, then one broken at the back: the same error either way */
    iso_task *t;
    uint64_t n;
    cr_assert_eq(iso_tasks(&p, &a, &t, &n), 0);
    cr_assert_gt(n, 3 * 256, "want several parts of the check");
    iso_work *w;
    cr_assert_eq(iso_work_new(&p, &w), 0);
    iso_piece *pc = calloc(n, sizeof *pc);
    uint8_t **own = calloc(n, sizeof *own);
    for (uint64_t i = 0; i < n; i++) {
        iso_piece v;
        cr_assert_eq(iso_task_run(w, &p, &a, &t[i], &v), 0);
        size_t bytes = iso_piece_bytes(&p, &v);
        own[i] = malloc(bytes ? bytes : 1);
        iso_piece_pack(&p, &v, own[i]);
        iso_piece_view(&p, own[i], bytes, v.key, v.nv, v.nc, v.nt, v.ne, &pc[i]);
    }
    uint64_t *vb1 = malloc(8 * (n + 1)), *tb1 = malloc(8 * (n + 1));
    uint64_t *vb3 = malloc(8 * (n + 1)), *tb3 = malloc(8 * (n + 1));
    cr_assert_eq(iso_weld_bases(&p, pc, n, vb1, tb1, 1, err, sizeof err), 0, "%s", err);
    cr_assert_eq(iso_weld_bases(&p, pc, n, vb3, tb3, 3, err, sizeof err), 0, "%s", err);
    cr_assert(!memcmp(vb1, vb3, 8 * (n + 1)) && !memcmp(tb1, tb3, 8 * (n + 1)));
    uint64_t late = n - 2, early = n / 2; /* in the last part, then in the middle one */
    while (!pc[late].nt) late--;
    while (!pc[early].nt) early++;
    ((uint32_t *)pc[late].tri)[0] = pc[late].nv + 1;
    cr_assert_eq(iso_weld_bases(&p, pc, n, vb1, tb1, 1, err, sizeof err), -EPROTO);
    cr_assert_eq(iso_weld_bases(&p, pc, n, vb3, tb3, 3, err3, sizeof err3), -EPROTO);
    cr_assert_str_eq(err, err3);
    ((uint32_t *)pc[early].tri)[0] = pc[early].nv + 1;
    cr_assert_eq(iso_weld_bases(&p, pc, n, vb3, tb3, 3, err3, sizeof err3), -EPROTO);
    char want[64];
    snprintf(want, sizeof want, "piece %llu: ", (unsigned long long)early);
    cr_assert(!strncmp(err3, want, strlen(want)), "the first bad piece: %s", err3);
    for (uint64_t i = 0; i < n; i++) free(own[i]);
    free(own), free(pc), free(vb1), free(tb1), free(vb3), free(tb3), free(t);
    iso_work_free(w);
    free(mem1), free(mem3);
    vod_close(f);
}
