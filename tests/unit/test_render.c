/* Direct visualization: framing and coverage of a sphere, shading, the
 * z-buffer, rotation, perspective, hole-free splats, PNG output. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <png.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "octree.h"
#include "render.h"
#include "vod.h"
#include "voxel.h"

#define CAP 65536u
#define SHELL_R 28.0
#define SHELL_HALF 0.87 /* half thickness: every voxel the sphere crosses */

static octree_cell arena[CAP];
static const double ORIGIN0[3] = {0, 0, 0}, UNIT[3] = {1, 1, 1};
static const double CENTRE[3] = {32, 32, 32};

/* A spherical shell of voxels with radial normals in a 64^3 octree. */
static void make_shell(octree *t, const double c[3], double r)
{
    octree_init(t, arena, CAP, 6);
    for (uint32_t z = 0; z < 64; z++)
        for (uint32_t y = 0; y < 64; y++)
            for (uint32_t x = 0; x < 64; x++) {
                double n[3] = {x + 0.5 - c[0], y + 0.5 - c[1], z + 0.5 - c[2]};
                double d = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
                if (fabs(d - r) <= SHELL_HALF)
                    cr_assert_eq(octree_store(t, x, y, z, voxel_surface(n)), 0);
            }
}

static render_opts opts(int w, int h, double az, double el)
{
    render_opts o;
    render_opts_default(&o);
    o.width = w;
    o.height = h;
    o.azimuth = az;
    o.elevation = el;
    return o;
}

static const uint8_t *px(const render_image *img, int i, int j)
{
    return &img->rgb[3 * ((size_t)j * img->width + i)];
}

static int lit(const render_image *img, int i, int j)
{
    const uint8_t *p = px(img, i, j);
    return p[0] | p[1] | p[2]; /* background is black */
}

/* Count of covered pixels, their centroid and bounding box. */
typedef struct {
    long n;
    double mx, my;
    int i0, i1, j0, j1;
} cover;

static cover coverage(const render_image *img)
{
    cover c = {0, 0, 0, img->width, -1, img->height, -1};
    for (int j = 0; j < img->height; j++)
        for (int i = 0; i < img->width; i++) {
            if (!lit(img, i, j)) continue;
            c.n++;
            c.mx += i + 0.5;
            c.my += j + 0.5;
            c.i0 = i < c.i0 ? i : c.i0;
            c.i1 = i > c.i1 ? i : c.i1;
            c.j0 = j < c.j0 ? j : c.j0;
            c.j1 = j > c.j1 ? j : c.j1;
        }
    if (c.n) {
        c.mx /= c.n;
        c.my /= c.n;
    }
    return c;
}

static int grey(const render_image *img, int i, int j) { return px(img, i, j)[1]; }

Test(render, orthographic_sphere_is_a_centred_disc_of_the_right_area)
{
    static octree t;
    make_shell(&t, CENTRE, SHELL_R);
    const double views[][2] = {{30, 20}, {0, 0}, {45, 45}, {200, -30}, {90, 90}};
    for (size_t v = 0; v < sizeof(views) / sizeof(views[0]); v++) {
        render_opts o = opts(512, 384, views[v][0], views[v][1]);
        render_image img;
        cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), 0);
        cover c = coverage(&img);
        /* Outer radius of the shell: the farthest voxel centres plus half
         * a voxel. */
        double r_px = (SHELL_R + SHELL_HALF + 0.5) * img.cam.scale;
        double want = M_PI * r_px * r_px;
        cr_assert(fabs(c.n - want) < 0.05 * want,
                  "view %zu: %ld pixels, disc of radius %.1f has %.0f", v, c.n,
                  r_px, want);
        cr_assert(fabs(c.mx - 256) < 1.0 && fabs(c.my - 192) < 1.0,
                  "view %zu: centroid %.2f %.2f", v, c.mx, c.my);
        /* Framed with a margin, not cut by the edges. */
        cr_assert(c.i0 > 0 && c.j0 > 0 && c.i1 < 511 && c.j1 < 383);
        cr_assert_eq(img.splats, t.voxels);
        render_image_free(&img);
    }
}

Test(render, centre_is_brighter_than_the_rim_and_ambient_one_is_flat)
{
    static octree t;
    make_shell(&t, CENTRE, SHELL_R);
    render_opts o = opts(400, 400, 30, 20);
    render_image img;
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), 0);
    double r_px = SHELL_R * img.cam.scale;
    int centre = grey(&img, 200, 200), darkest = 255;
    for (int k = 0; k < 8; k++) {
        int i = (int)(200 + 0.9 * r_px * cos(k * M_PI / 4));
        int j = (int)(200 + 0.9 * r_px * sin(k * M_PI / 4));
        cr_assert(lit(&img, i, j));
        cr_assert_gt(centre, grey(&img, i, j), "direction %d", k);
        darkest = grey(&img, i, j) < darkest ? grey(&img, i, j) : darkest;
    }
    cr_assert_gt(centre, 200);
    cr_assert_lt(darkest, centre * 0.6, "diffuse term barely varies");
    cr_assert_geq(darkest, (int)(0.2 * 255), "ambient floor");
    /* The light sits up and to the left of the camera: so does the
     * highlight. */
    int best = 0;
    double hx = 0, hy = 0, hn = 0;
    for (int j = 0; j < 400; j++)
        for (int i = 0; i < 400; i++) best = grey(&img, i, j) > best ? grey(&img, i, j) : best;
    for (int j = 0; j < 400; j++)
        for (int i = 0; i < 400; i++)
            if (grey(&img, i, j) == best) hx += i, hy += j, hn++;
    cr_assert(hx / hn < 200 - 0.2 * r_px && hy / hn < 200 - 0.2 * r_px,
              "highlight at %g %g", hx / hn, hy / hn);
    render_image_free(&img);

    o.ambient = 1.0;
    o.color = 0x3080c0;
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), 0);
    long n = 0;
    for (int j = 0; j < 400; j++)
        for (int i = 0; i < 400; i++) {
            if (!lit(&img, i, j)) continue;
            const uint8_t *p = px(&img, i, j);
            cr_assert(p[0] == 0x30 && p[1] == 0x80 && p[2] == 0xc0);
            n++;
        }
    cr_assert_gt(n, 10000);
    render_image_free(&img);
}

/* Splat a shell of voxel centres around c with radius r (normals radial,
 * or `fixed` when not NULL). */
static void splat_sphere(render_ctx *ctx, const double c[3], double r,
                         const double *fixed)
{
    int lo[3], hi[3];
    for (int k = 0; k < 3; k++) {
        lo[k] = (int)floor(c[k] - r - 2);
        hi[k] = (int)ceil(c[k] + r + 2);
    }
    for (int z = lo[2]; z <= hi[2]; z++)
        for (int y = lo[1]; y <= hi[1]; y++)
            for (int x = lo[0]; x <= hi[0]; x++) {
                double p[3] = {x + 0.5, y + 0.5, z + 0.5};
                double n[3] = {p[0] - c[0], p[1] - c[1], p[2] - c[2]};
                double d = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
                if (fabs(d - r) <= SHELL_HALF) render_splat(ctx, p, fixed ? fixed : n);
            }
}

static const double BOX_LO[3] = {0, 0, 0}, BOX_HI[3] = {64, 64, 64};

/* Far sphere lit (normals toward the camera), near one only ambient (a
 * normal across the view, away from the light). */
static void two_spheres(int near_first, render_image *img)
{
    render_opts o = opts(256, 256, 0, 0); /* looking down -x */
    o.ambient = 0.2;
    render_ctx *ctx;
    cr_assert_eq(render_begin(&ctx, &o, BOX_LO, BOX_HI, UNIT), 0);
    const double far_c[3] = {18, 32, 32}, near_c[3] = {46, 32, 32};
    const double across[3] = {0, 1, 0}; /* the camera's right */
    const double toward[3] = {1, 0, 0};
    for (int pass = 0; pass < 2; pass++) {
        if (pass == near_first)
            splat_sphere(ctx, far_c, 14, toward);
        else
            splat_sphere(ctx, near_c, 8, across);
    }
    render_finish(ctx, img);
}

Test(render, z_buffer_keeps_the_nearer_object_in_any_order)
{
    render_image a, b;
    two_spheres(0, &a);
    two_spheres(1, &b);
    size_t n = (size_t)a.width * a.height;
    cr_assert_eq(memcmp(a.rgb, b.rgb, 3 * n), 0, "order changed the image");
    cr_assert_eq(memcmp(a.depth, b.depth, 4 * n), 0);
    /* Image centre: the near sphere (ambient only), in front of the far. */
    double pc[3] = {46 + 8, 32, 32}, qx, qy, dnear, dfar;
    render_project(&a.cam, pc, &qx, &qy, &dnear);
    pc[0] = 18 + 14;
    render_project(&a.cam, pc, &qx, &qy, &dfar);
    cr_assert_eq(grey(&a, 128, 128), 51);
    cr_assert(fabs(a.depth[128 * 256 + 128] - dnear) < 1.0);
    cr_assert(dnear < dfar - 10);
    /* Outside the near disc, inside the far one: the far sphere. */
    int i = (int)(128 + 11 * a.cam.scale);
    cr_assert_gt(grey(&a, i, 128), 200);
    /* Depth there: the front of the shell's outer surface. */
    double r_out = 14 + SHELL_HALF, behind = 14 - sqrt(r_out * r_out - 11 * 11);
    cr_assert(fabs(a.depth[128 * 256 + i] - (dfar + behind)) < 1.0, "%g %g",
              a.depth[128 * 256 + i], dfar + behind);
    cr_assert(isinf(a.depth[0]) && !lit(&a, 0, 0));
    render_image_free(&a);
    render_image_free(&b);
}

/* A solid bar along x: 48 x 8 x 8 voxels. */
static void make_bar(octree *t)
{
    const double up[3] = {0, 0, 1};
    octree_init(t, arena, CAP, 6);
    for (uint32_t z = 28; z < 36; z++)
        for (uint32_t y = 28; y < 36; y++)
            for (uint32_t x = 8; x < 56; x++)
                cr_assert_eq(octree_store(t, x, y, z, voxel_surface(up)), 0);
}

Test(render, rotation_changes_the_silhouette)
{
    static octree t;
    make_bar(&t);
    render_image img[2];
    cover c[2];
    for (int v = 0; v < 2; v++) {
        render_opts o = opts(256, 256, v * 90, 0);
        o.fit_volume = 1;
        cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img[v]), 0);
        c[v] = coverage(&img[v]);
    }
    double w0 = c[0].i1 - c[0].i0 + 1, h0 = c[0].j1 - c[0].j0 + 1;
    double w1 = c[1].i1 - c[1].i0 + 1, h1 = c[1].j1 - c[1].j0 + 1;
    cr_assert(fabs(w0 / h0 - 1) < 0.1, "end-on: %gx%g", w0, h0);
    cr_assert(fabs(w1 / h1 - 6) < 0.6, "side-on: %gx%g", w1, h1);
    cr_assert(fabs((double)c[1].n / c[0].n - 6) < 0.6, "areas %ld %ld", c[0].n,
              c[1].n);
    /* Same framing (the volume box), same vertical extent. */
    cr_assert(fabs(h0 - h1) <= 2);
    /* Framing the bar itself fills the frame end-on. */
    render_opts o = opts(256, 256, 0, 0);
    render_image tight;
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &tight), 0);
    cover ct = coverage(&tight);
    cr_assert(ct.i1 - ct.i0 + 1 > 0.85 * 256 && ct.i1 - ct.i0 + 1 < 0.95 * 256);
    for (int v = 0; v < 2; v++) render_image_free(&img[v]);
    render_image_free(&tight);
}

Test(render, perspective_sphere_is_round_and_near_things_look_bigger)
{
    static octree t;
    make_shell(&t, CENTRE, SHELL_R);
    render_opts o = opts(400, 300, 30, 20);
    o.perspective = 1;
    render_image img;
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), 0);
    cover c = coverage(&img);
    double w = c.i1 - c.i0 + 1, h = c.j1 - c.j0 + 1;
    cr_assert(fabs(w / h - 1) < 0.04, "%g x %g", w, h);
    double want = M_PI * w * h / 4;
    cr_assert(fabs(c.n - want) < 0.05 * want, "%ld vs %g", c.n, want);
    cr_assert(fabs(c.mx - 200) < 1.5 && fabs(c.my - 150) < 1.5);
    cr_assert(c.i0 > 0 && c.j0 > 0 && c.i1 < 399 && c.j1 < 299);
    render_image_free(&img);

    /* Two equal spheres, one nearer the camera (looking down -x; the near
     * one is on the left).  Equal in orthographic, not in perspective. */
    long half[2][2] = {{0, 0}, {0, 0}};
    for (int persp = 0; persp < 2; persp++) {
        o = opts(256, 128, 0, 0);
        o.perspective = persp;
        render_ctx *ctx;
        cr_assert_eq(render_begin(&ctx, &o, BOX_LO, BOX_HI, UNIT), 0);
        const double a[3] = {48, 16, 32}, b[3] = {16, 48, 32};
        splat_sphere(ctx, a, 10, NULL);
        splat_sphere(ctx, b, 10, NULL);
        render_finish(ctx, &img);
        for (int j = 0; j < 128; j++)
            for (int i = 0; i < 256; i++)
                half[persp][i >= 128] += lit(&img, i, j) != 0;
        render_image_free(&img);
    }
    cr_assert(labs(half[0][0] - half[0][1]) < 0.02 * half[0][0]);
    cr_assert(half[1][0] > 1.3 * half[1][1], "near %ld far %ld", half[1][0],
              half[1][1]);
}

/* Pixels inside the projection of a planar parallelogram (shrunk by one
 * voxel) must all be covered. */
static void assert_no_holes(const render_image *img, const double p0[3],
                            const double e1[3], const double e2[3])
{
    double q[3][2], d;
    const double *e[2] = {e1, e2};
    render_project(&img->cam, p0, &q[0][0], &q[0][1], &d);
    for (int k = 0; k < 2; k++) {
        double p[3] = {p0[0] + e[k][0], p0[1] + e[k][1], p0[2] + e[k][2]};
        render_project(&img->cam, p, &q[k + 1][0], &q[k + 1][1], &d);
    }
    double a[2] = {q[1][0] - q[0][0], q[1][1] - q[0][1]};
    double b[2] = {q[2][0] - q[0][0], q[2][1] - q[0][1]};
    double det = a[0] * b[1] - a[1] * b[0];
    long inside = 0;
    for (int j = 0; j < img->height; j++)
        for (int i = 0; i < img->width; i++) {
            double x = i + 0.5 - q[0][0], y = j + 0.5 - q[0][1];
            double s = (x * b[1] - y * b[0]) / det, t = (a[0] * y - a[1] * x) / det;
            if (s < 0.05 || s > 0.95 || t < 0.05 || t > 0.95) continue;
            inside++;
            cr_assert(lit(img, i, j), "hole at %d %d", i, j);
        }
    cr_assert_gt(inside, 1000);
}

Test(render, slanted_and_diagonal_planes_have_no_holes)
{
    static octree t;
    render_image img;
    /* A z = 32 layer, seen obliquely. */
    octree_init(&t, arena, CAP, 6);
    const double up[3] = {0, 0, 1};
    for (uint32_t y = 0; y < 64; y++)
        for (uint32_t x = 0; x < 64; x++)
            cr_assert_eq(octree_store(&t, x, y, 32, voxel_surface(up)), 0);
    render_opts o = opts(300, 300, 37, 25);
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), 0);
    const double p0[3] = {0.5, 0.5, 32.5}, ex[3] = {63, 0, 0}, ey[3] = {0, 63, 0};
    assert_no_holes(&img, p0, ex, ey);
    render_image_free(&img);
    /* A one-voxel staircase x + y = 63, the thinnest (26-connected) plane,
     * seen along its normal: plain voxel-sized squares would leave gaps. */
    octree_init(&t, arena, CAP, 6);
    const double diag[3] = {1, 1, 0};
    for (uint32_t z = 0; z < 64; z++)
        for (uint32_t x = 0; x < 64; x++)
            cr_assert_eq(octree_store(&t, x, 63 - x, z, voxel_surface(diag)), 0);
    for (int persp = 0; persp < 2; persp++) {
        o = opts(300, 300, 45, 0);
        o.perspective = persp;
        cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), 0);
        const double q0[3] = {0.5, 63.5, 0.5}, ed[3] = {63, -63, 0},
                     ez[3] = {0, 0, 63};
        assert_no_holes(&img, q0, ed, ez);
        render_image_free(&img);
    }
}

Test(render, output_is_deterministic_and_perspective_differs)
{
    static octree t;
    make_shell(&t, CENTRE, 20);
    render_opts o = opts(200, 200, 123, -17);
    render_image a, b, p;
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &a), 0);
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &b), 0);
    cr_assert_eq(memcmp(a.rgb, b.rgb, 3 * 200 * 200), 0);
    cr_assert_eq(memcmp(a.depth, b.depth, 4 * 200 * 200), 0);
    o.perspective = 1;
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &p), 0);
    cr_assert_neq(memcmp(a.rgb, p.rgb, 3 * 200 * 200), 0);
    render_image_free(&a);
    render_image_free(&b);
    render_image_free(&p);
}

Test(render, bad_options_are_einval_and_an_empty_tree_is_background)
{
    static octree t;
    octree_init(&t, arena, CAP, 4);
    render_image img;
    render_opts o = opts(8193, 10, 0, 0);
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), -EINVAL);
    o = opts(10, 0, 0, 0);
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), -EINVAL);
    o = opts(10, 10, 0, 91);
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), -EINVAL);
    o = opts(10, 10, 0, 0);
    o.perspective = 1;
    o.fov = 0;
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), -EINVAL);
    o = opts(10, 10, 0, 0);
    o.ambient = 1.5;
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), -EINVAL);
    render_ctx *ctx;
    o = opts(10, 10, 0, 0);
    const double bad_lo[3] = {1, 0, 0}, zero[3] = {1, 0, 1};
    cr_assert_eq(render_begin(&ctx, &o, bad_lo, ORIGIN0, UNIT), -EINVAL);
    cr_assert_eq(render_begin(&ctx, &o, ORIGIN0, UNIT, zero), -EINVAL);
    cr_assert_null(ctx);

    o = opts(16, 8, 0, 0);
    o.background = 0x102030;
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), 0);
    cr_assert_eq(img.splats, 0);
    for (int k = 0; k < 16 * 8; k++) {
        cr_assert(img.rgb[3 * k] == 0x10 && img.rgb[3 * k + 1] == 0x20 &&
                  img.rgb[3 * k + 2] == 0x30);
        cr_assert(isinf(img.depth[k]));
    }
    render_image_free(&img);
}

Test(render, png_reads_back_with_libpng)
{
    static octree t;
    make_shell(&t, CENTRE, 20);
    render_opts o = opts(96, 61, 10, 30); /* odd sizes: rows and stride */
    o.color = 0xff8020;
    render_image img;
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), 0);
    char dir[] = "/tmp/test_render.XXXXXX", path[64];
    cr_assert_not_null(mkdtemp(dir));
    snprintf(path, sizeof(path), "%s/a.png", dir);
    cr_assert_eq(render_write_png(&img, path), 0);

    png_image pi;
    memset(&pi, 0, sizeof(pi));
    pi.version = PNG_IMAGE_VERSION;
    cr_assert(png_image_begin_read_from_file(&pi, path), "%s", pi.message);
    cr_assert_eq(pi.width, 96);
    cr_assert_eq(pi.height, 61);
    pi.format = PNG_FORMAT_RGB;
    uint8_t *buf = malloc(PNG_IMAGE_SIZE(pi));
    cr_assert(png_image_finish_read(&pi, NULL, buf, 0, NULL), "%s", pi.message);
    cr_assert_eq(memcmp(buf, img.rgb, 96 * 61 * 3), 0);
    free(buf);
    unlink(path);

    snprintf(path, sizeof(path), "%s/no/such/dir.png", dir);
    cr_assert_eq(render_write_png(&img, path), -ENOENT);
    rmdir(dir);
    render_image_free(&img);
}

Test(render, normals_facing_away_are_flipped_two_sided)
{
    static octree out_t, in_t;
    static octree_cell arena2[CAP];
    make_shell(&out_t, CENTRE, 20);
    /* The same shell with every normal negated (seen from inside). */
    octree_init(&in_t, arena2, CAP, 6);
    octree_iter it;
    uint32_t x, y, z, v;
    octree_iter_init(&it, &out_t);
    while (octree_iter_next(&it, &x, &y, &z, &v)) {
        double n[3];
        voxel_unpack_normal(v, n);
        for (int k = 0; k < 3; k++) n[k] = -n[k];
        cr_assert_eq(octree_store(&in_t, x, y, z, voxel_surface(n)), 0);
    }
    for (int persp = 0; persp < 2; persp++) {
        render_opts o = opts(160, 160, 250, 35);
        o.perspective = persp;
        render_image a, b;
        cr_assert_eq(render_octree(&out_t, ORIGIN0, UNIT, NULL, &o, &a), 0);
        cr_assert_eq(render_octree(&in_t, ORIGIN0, UNIT, NULL, &o, &b), 0);
        long differ = 0;
        for (int k = 0; k < 160 * 160 * 3; k++)
            differ += abs(a.rgb[k] - b.rgb[k]) > 2; /* normal quantization */
        cr_assert_lt(differ, 20, "%ld channels differ", differ);
        cr_assert_gt(grey(&b, 80, 80), 200, "inward normals shade dark");
        render_image_free(&a);
        render_image_free(&b);
    }
}

Test(render, equal_depth_ties_go_to_the_brighter_splat)
{
    render_opts o = opts(32, 32, 0, 0);
    const double p[3] = {32, 32, 32}, lit_n[3] = {1, 0, 0}, dark_n[3] = {0, 1, 0};
    uint8_t got[2];
    for (int order = 0; order < 2; order++) {
        render_ctx *ctx;
        render_image img;
        cr_assert_eq(render_begin(&ctx, &o, BOX_LO, BOX_HI, UNIT), 0);
        render_splat(ctx, p, order ? lit_n : dark_n);
        render_splat(ctx, p, order ? dark_n : lit_n);
        render_finish(ctx, &img);
        cr_assert_eq(img.splats, 2);
        got[order] = (uint8_t)grey(&img, 16, 16);
        render_image_free(&img);
    }
    cr_assert_eq(got[0], got[1]);
    cr_assert_gt(got[0], 200);
}

/* ---- VOD input ---- */

/* t written as a 64^3 VOD of the given channel, read back; scale and
 * origin as given, or unit voxels at the origin when NULL. */
static vod_file *to_vod_placed(octree *t, int channel, const float *scale,
                               const float *origin)
{
    vod_params p;
    vod_params_default(&p);
    p.volume[0] = p.volume[1] = p.volume[2] = 64;
    p.channel = channel;
    for (int k = 0; k < 3 && scale; k++) {
        p.voxel_scale[k] = scale[k];
        p.origin[k] = origin[k];
    }
    vod_membuf m = {0};
    vod_sink sink = {vod_mem_write, &m};
    vod_stats st;
    err_info err = {0};
    cr_assert_eq(vod_write_octree(t, &p, &sink, &st, &err), 0, "%s", err.msg);
    vod_file *f;
    cr_assert_eq(vod_read(m.p, m.n, &f, &err), 0, "%s", err.msg);
    free(m.p);
    return f;
}

static vod_file *to_vod(octree *t, int channel)
{
    return to_vod_placed(t, channel, NULL, NULL);
}

Test(render, vod_level_zero_matches_the_octree_and_level_one_is_coarser)
{
    static octree t;
    make_shell(&t, CENTRE, SHELL_R);
    vod_file *f = to_vod(&t, VOXEL_CH_SURFACE);
    render_opts o = opts(300, 300, 30, 20);
    render_image direct, l0, l1;
    err_info re = {0};
    cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &direct), 0);
    cr_assert_eq(render_vod(f, 0, &o, &l0, &re), 0, "%s", re.msg);
    cr_assert_eq(render_vod(f, 1, &o, &l1, &re), 0, "%s", re.msg);
    /* Same voxels, other order: the z-buffer makes the bytes equal. */
    cr_assert_eq(l0.splats, t.voxels);
    cr_assert_eq(memcmp(direct.rgb, l0.rgb, 300 * 300 * 3), 0);
    cover c0 = coverage(&l0), c1 = coverage(&l1);
    cr_assert(fabs((double)c1.n / c0.n - 1) < 0.10, "%ld vs %ld", c1.n, c0.n);
    cr_assert_lt(l1.splats * 3, l0.splats, "%llu vs %llu splats",
                 (unsigned long long)l1.splats, (unsigned long long)l0.splats);
    cr_assert(fabs(c1.mx - c0.mx) < 3 && fabs(c1.my - c0.my) < 3);
    /* Level 1 is shaded from the merged normals: still bright in the middle. */
    cr_assert_gt(grey(&l1, 150, 150), 200);
    render_image_free(&direct);
    render_image_free(&l0);
    render_image_free(&l1);

    cr_assert_eq(render_vod(f, 3, &o, &l0, &re), -EINVAL);
    cr_assert(strstr(re.msg, "level"), "%s", re.msg);
    o.width = 0;
    cr_assert_eq(render_vod(f, 0, &o, &l0, &re), -EINVAL);
    vod_close(f);
}

Test(render, occupancy_vod_is_shaded_from_neighbour_gradients)
{
    static octree t;
    octree_init(&t, arena, CAP, 6);
    const double up[3] = {0, 0, 1}; /* ignored by a 1-bit file */
    for (uint32_t z = 0; z < 64; z++)
        for (uint32_t y = 0; y < 64; y++)
            for (uint32_t x = 0; x < 64; x++) {
                double d[3] = {x + 0.5 - 32, y + 0.5 - 32, z + 0.5 - 32};
                if (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= 24.0 * 24.0)
                    cr_assert_eq(octree_store(&t, x, y, z, voxel_surface(up)), 0);
            }
    vod_file *f = to_vod(&t, VOXEL_CH_OCCUPANCY);
    render_opts o = opts(300, 300, 30, 20);
    render_image img;
    err_info re = {0};
    cr_assert_eq(render_vod(f, 0, &o, &img, &re), 0, "%s", re.msg);
    /* Hidden inner voxels are skipped. */
    cr_assert_lt(img.splats * 4, t.voxels);
    cover c = coverage(&img);
    double r_px = 24.5 * img.cam.scale;
    cr_assert(fabs(c.n - M_PI * r_px * r_px) < 0.05 * M_PI * r_px * r_px);
    int centre = grey(&img, 150, 150), darkest = 255;
    for (int k = 0; k < 8; k++) {
        int i = (int)(150 + 0.9 * r_px * cos(k * M_PI / 4));
        int j = (int)(150 + 0.9 * r_px * sin(k * M_PI / 4));
        cr_assert_gt(centre, grey(&img, i, j), "direction %d", k);
        darkest = grey(&img, i, j) < darkest ? grey(&img, i, j) : darkest;
    }
    cr_assert_lt(darkest, centre * 0.6);
    render_image_free(&img);
    /* Level 1 of the ball: coarser, same disc. */
    cr_assert_eq(render_vod(f, 1, &o, &img, &re), 0, "%s", re.msg);
    cover c1 = coverage(&img);
    /* OR-downsampling dilates by up to one coarse voxel. */
    cr_assert(fabs((double)c1.n / c.n - 1) < 0.15, "%ld vs %ld", c1.n, c.n);
    cr_assert_gt(grey(&img, 150, 150), darkest);
    render_image_free(&img);
    vod_close(f);
}

Test(render, vod_voxel_scale_and_origin_place_the_splats)
{
    static octree t;
    make_shell(&t, CENTRE, 20);
    const float scale[3] = {2, 1, 0.5f}, origin[3] = {-5, 3, 7};
    vod_file *f = to_vod_placed(&t, VOXEL_CH_SURFACE, scale, origin);
    err_info re = {0};
    for (int view = 0; view < 2; view++) {
        /* Looking down -y: x across, z up; then down -x: y across. */
        render_opts o = opts(240, 240, view ? 0 : 90, 0);
        o.fit_volume = 1;
        render_image img;
        cr_assert_eq(render_vod(f, 0, &o, &img, &re), 0, "%s", re.msg);
        cover c = coverage(&img);
        double w = c.i1 - c.i0 + 1, h = c.j1 - c.j0 + 1;
        double want = view ? 1.0 / 0.5 : 2.0 / 0.5;
        cr_assert(fabs(w / h / want - 1) < 0.06, "view %d: %g x %g", view, w, h);
        /* The ellipsoid's centre, in world units, is the image centre. */
        double centre[3], qx, qy, d;
        for (int k = 0; k < 3; k++) centre[k] = origin[k] + 32.0 * scale[k];
        cr_assert_eq(render_project(&img.cam, centre, &qx, &qy, &d), 0);
        cr_assert(fabs(qx - c.mx) < 1 && fabs(qy - c.my) < 1);
        cr_assert(fabs(qx - 120) < 1e-9 && fabs(qy - 120) < 1e-9);
        render_image_free(&img);
    }
    vod_close(f);
}

/* The camera against one written here from docs/cli.md: azimuth about +z
 * from +x, elevation above the xy-plane, the camera looking at the volume's
 * centre, +z up on the picture and the view not mirrored (right = forward x
 * up).  A 3^3 blob off the centre must appear, seen from each view, off the
 * picture's centre in the direction (d . right, -d . up) the test computes
 * (rows grow downwards), within 2 degrees (the volume box framed,
 * fit_volume, so that the picture's centre is the volume's). */
static void camera_axes(double az, double el, double right[3], double up[3])
{
    double a = az * M_PI / 180, e = el * M_PI / 180;
    double f[3] = {-cos(e) * cos(a), -cos(e) * sin(a), -sin(e)}; /* forward */
    double r[3] = {f[1], -f[0], 0}; /* f x (0, 0, 1) */
    double lr = hypot(r[0], r[1]);
    for (int k = 0; k < 3; k++) right[k] = r[k] / lr;
    up[0] = right[1] * f[2] - right[2] * f[1];
    up[1] = right[2] * f[0] - right[0] * f[2];
    up[2] = right[0] * f[1] - right[1] * f[0];
}

Test(render, the_camera_options_place_a_point_where_the_test_computes)
{
    static octree t;
    octree_init(&t, arena, CAP, 6);
    const double d[3] = {12, -7, 9}; /* the blob's centre off the volume's (32, 32, 32) */
    const double n[3] = {0, 0, 1};
    for (int z = -1; z <= 1; z++)
        for (int y = -1; y <= 1; y++)
            for (int x = -1; x <= 1; x++)
                cr_assert_eq(octree_store(&t, (uint32_t)(31 + d[0] + x), (uint32_t)(31 + d[1] + y),
                                          (uint32_t)(31 + d[2] + z), voxel_surface(n)), 0);
    /* voxel 31 + k spans 31 + k .. 32 + k: its centre is 32 + k - 0.5; the
     * blob's centre is that of voxel 31 + d, at 32 + d - 0.5 */
    const double views[][2] = {{0, 0}, {90, 0}, {30, 20}, {200, -30}, {45, 60}, {-120, 10}};
    for (size_t v = 0; v < sizeof views / sizeof *views; v++) {
        render_opts o = opts(301, 301, views[v][0], views[v][1]);
        o.fit_volume = 1;
        render_image img;
        cr_assert_eq(render_octree(&t, ORIGIN0, UNIT, NULL, &o, &img), 0);
        cover c = coverage(&img);
        cr_assert_gt(c.n, 0, "view %zu: the blob is not in the picture", v);
        double right[3], up[3], p[3];
        camera_axes(views[v][0], views[v][1], right, up);
        for (int k = 0; k < 3; k++) p[k] = d[k] - 0.5;
        double wx = p[0] * right[0] + p[1] * right[1] + p[2] * right[2];
        double wy = -(p[0] * up[0] + p[1] * up[1] + p[2] * up[2]);
        double gx = c.mx - 150.5, gy = c.my - 150.5;
        double angle = fabs(atan2(wx * gy - wy * gx, wx * gx + wy * gy)) * 180 / M_PI;
        cr_assert_leq(angle, 2.0,
                      "view %zu (azimuth %g, elevation %g): the blob at (%.1f, %.1f) px off the "
                      "centre, the camera puts it at (%.1f, %.1f) x scale: %.1f degrees apart",
                      v, views[v][0], views[v][1], gx, gy, wx, wy, angle);
        cr_assert_gt(hypot(gx, gy), 10, "view %zu: the blob sits at the centre", v);
        render_image_free(&img);
    }
}
