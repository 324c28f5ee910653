/* What vox does with a file it has read, when memory runs out: every
 * allocation of vox render's drawing (a VOD file's occupancy and its
 * normals, a mesh flat and smooth), of vox mesh's marching cubes (the
 * input's bricks, the tasks, the weld; one level and the adaptive levels)
 * and of its writer (every format, one thread and three) fails in turn
 * (alloc_fail.h).  Each run gives the same picture, mesh or file as with
 * all its memory, or -ENOMEM, and frees every block it allocated. */
#include <criterion/criterion.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "alloc_fail.h"
#include "iso.h"
#include "iso_fixture.h"
#include "mesh_shapes.h"
#include "render.h"

/* A torus's occupancy (1 bit, channel 1) or its surface voxels with
 * normals (32 bits, channel 3). */
static uint32_t torus(void *ud, double x, double y, double z)
{
    int normals = *(const int *)ud;
    double q = sqrt(x * x + y * y) - 0.55, d = sqrt(q * q + z * z) - 0.25;
    if (!normals) return d < 0;
    if (fabs(d) > 0.05) return 0;
    double r = sqrt(x * x + y * y), n[3] = {q * x / r, q * y / r, z};
    double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    for (int a = 0; a < 3; a++) n[a] /= l;
    return voxel_surface(n);
}

static vod_file *torus_file(int normals)
{
    vol_spec s = {{40, 40, 24}, 8, normals ? 32 : 1, normals ? 3 : 1, 2.0 / 40, {-1, -1, -0.6}};
    return make_vod(&s, torus, &normals);
}

/* ---- vox render ---- */

typedef struct {
    const vod_file *f;
    const mesh *m;
    int smooth;
    render_opts o;
    render_image want;
} draw_case;

static int draw_once(void *ctx, char *msg)
{
    const draw_case *c = ctx;
    render_image img;
    err_info err = {0};
    int rc = c->f ? render_vod(c->f, 0, &c->o, &img, &err) : render_mesh(c->m, &c->o, c->smooth, &img);
    memcpy(msg, err.msg, sizeof err.msg);
    if (rc) return rc;
    size_t px = (size_t)img.width * img.height;
    cr_assert(img.width == c->want.width && img.height == c->want.height);
    cr_assert_eq(memcmp(img.rgb, c->want.rgb, 3 * px), 0, "another picture");
    cr_assert_eq(img.splats, c->want.splats);
    render_image_free(&img);
    return 0;
}

static void draws_or_fails_cleanly(draw_case *c, const char *what)
{
    render_opts_default(&c->o);
    c->o.width = 96, c->o.height = 80;
    err_info err = {0};
    int rc = c->f ? render_vod(c->f, 0, &c->o, &c->want, &err)
                  : render_mesh(c->m, &c->o, c->smooth, &c->want);
    cr_assert_eq(rc, 0, "%s: %s", what, err.msg);
    cr_assert_gt(c->want.splats, 0);
    cr_assert_geq(alloc_fail_runs(draw_once, c, what, false), 2, "%s", what);
    render_image_free(&c->want);
}

Test(client_alloc, vox_render_draws_or_fails_cleanly)
{
    for (int normals = 0; normals < 2; normals++) {
        vod_file *f = torus_file(normals);
        draw_case c = {.f = f};
        draws_or_fails_cleanly(&c, normals ? "render_vod, normals" : "render_vod, occupancy");
        vod_close(f);
    }
    shape s;
    shape_init(&s);
    shape_icosphere(&s, (const double[3]){0, 0, 0}, 0.8, 3, false);
    for (int smooth = 0; smooth < 2; smooth++) {
        draw_case c = {.m = shape_finish(&s), .smooth = smooth};
        draws_or_fails_cleanly(&c, smooth ? "render_mesh, smooth" : "render_mesh");
    }
    shape_free(&s);
}

/* ---- vox mesh ---- */

typedef struct {
    const vod_file *f;
    iso_params p;
    iso_mesh want;
} mc_case;

static void *test_heap(void *ud, size_t n)
{
    return *(void **)ud = malloc(n);
}

static int iso_once(void *ctx, char *msg)
{
    const mc_case *c = ctx;
    err_info err = {0};
    void *mem = NULL;
    iso_input in;
    int rc = iso_input_make(c->f, &c->p, test_heap, &mem, &in);
    iso_mesh m = {0};
    if (!rc) rc = iso_run_serial(&c->p, &in, &m, &err);
    memcpy(msg, err.msg, sizeof err.msg);
    free(mem);
    if (rc) return rc;
    cr_assert(m.n_vertices == c->want.n_vertices && m.n_triangles == c->want.n_triangles);
    cr_assert_eq(memcmp(m.pos, c->want.pos, 12 * m.n_vertices), 0);
    cr_assert_eq(memcmp(m.tri, c->want.tri, 12 * m.n_triangles), 0);
    iso_mesh_free(&m);
    return 0;
}

Test(client_alloc, vox_mesh_polygonizes_or_fails_cleanly)
{
    vod_file *f = torus_file(0);
    const double centre[3] = {0.5, 0, 0}, radii[2] = {0.3, 0.7};
    const iso_request rqs[] = {{.iso = 127, .level = 0},
                               {.iso = 127, .center = centre, .radii = radii, .nradii = 2}};
    const char *const names[] = {"iso, level 0", "iso, adaptive levels"};
    for (int k = 0; k < 2; k++) {
        mc_case c = {.f = f};
        err_info err = {0};
        cr_assert_eq(iso_params_make(f, &rqs[k], &c.p, &err), 0, "%s", err.msg);
        polygonize_rq(f, &rqs[k], &c.want);
        cr_assert_gt(c.want.n_triangles, 100);
        cr_assert_geq(alloc_fail_runs(iso_once, &c, names[k], false), 3, "%s", names[k]);
        iso_mesh_free(&c.want);
    }
    vod_close(f);
}

/* ---- vox mesh's writer ---- */

typedef struct {
    const iso_mesh *m;
    iso_format f;
    unsigned threads;
    char path[64];
    uint8_t *want;  /* the file with all its memory */
    size_t n;
} write_case;

/* The file at path, whole (the test's own memory: never failed). */
static uint8_t *slurp(const char *path, size_t *n)
{
    FILE *f = fopen(path, "rb");
    cr_assert(f);
    fseek(f, 0, SEEK_END);
    *n = (size_t)ftell(f);
    rewind(f);
    uint8_t *p = af_test_malloc(*n);
    cr_assert_eq(fread(p, 1, *n, f), *n);
    fclose(f);
    return p;
}

static int write_once(void *ctx, char *msg)
{
    (void)msg;
    write_case *c = ctx;
    int fd = open(c->path, O_WRONLY | O_CREAT | O_TRUNC, 0600);
    cr_assert_geq(fd, 0);
    int rc = iso_write(fd, c->m, c->f, "test_client_alloc", c->threads);
    close(fd);
    if (rc) return rc;
    size_t n;
    uint8_t *got = slurp(c->path, &n);
    cr_assert(n == c->n && !memcmp(got, c->want, n), "another file");
    free(got);
    return 0;
}

Test(client_alloc, vox_meshs_writer_writes_or_fails_cleanly)
{
    vod_file *f = torus_file(1); /* with normals: every format writes them or not */
    iso_mesh m;
    polygonize(f, 127, 0, &m);
    const iso_format fmts[] = {ISO_FMT_PLY, ISO_FMT_PLY_ASCII, ISO_FMT_OBJ, ISO_FMT_STL};
    const char *const names[] = {"PLY", "PLY ascii", "OBJ", "STL"};
    for (int k = 0; k < 4; k++)
        for (unsigned threads = 1; threads <= 3; threads += 2) {
            write_case c = {.m = &m, .f = fmts[k], .threads = threads};
            snprintf(c.path, sizeof c.path, "/tmp/test_client_alloc_%d.out", (int)getpid());
            int fd = open(c.path, O_WRONLY | O_CREAT | O_TRUNC, 0600);
            cr_assert_geq(fd, 0);
            cr_assert_eq(iso_write(fd, &m, fmts[k], "test_client_alloc", threads), 0);
            close(fd);
            c.want = slurp(c.path, &c.n);
            char what[48];
            snprintf(what, sizeof what, "iso_write, %s, %u threads", names[k], threads);
            alloc_fail_runs(write_once, &c, what, false);
            free(c.want);
            unlink(c.path);
        }
    iso_mesh_free(&m);
    vod_close(f);
}
