/* render_mesh and render_triangle (client/render.h): triangles cover the
 * pixels their projection covers, flat and smooth shading differ as they
 * should, the z-buffer keeps the nearer surface, and the bytes do not depend
 * on the order of the triangles. */
#include <criterion/criterion.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "render.h"

static render_opts opts(int size, double az, double el)
{
    render_opts o;
    render_opts_default(&o);
    o.width = o.height = size;
    o.azimuth = az;
    o.elevation = el;
    return o;
}

static int lit(const render_image *img, int i)
{
    const uint8_t *p = img->rgb + 3 * (size_t)i;
    return p[0] | p[1] | p[2];
}

static int count_lit(const render_image *img)
{
    int n = 0;
    for (int i = 0; i < img->width * img->height; i++) n += lit(img, i) != 0;
    return n;
}

/* Distinct non-background greys. */
static int shades(const render_image *img)
{
    int seen[256] = {0}, n = 0;
    for (int i = 0; i < img->width * img->height; i++)
        if (lit(img, i) && !seen[img->rgb[3 * i + 1]]++) n++;
    return n;
}

typedef struct {
    float v[64][3];
    uint32_t t[64][3];
    mesh m;
} small_mesh;

static void finish(small_mesh *s, uint32_t nv, uint32_t nt)
{
    s->m = (mesh){.n_vertices = nv, .n_triangles = nt, .vertices = s->v, .triangles = s->t};
    for (int k = 0; k < 3; k++) {
        s->m.lo[k] = INFINITY;
        s->m.hi[k] = -INFINITY;
        for (uint32_t i = 0; i < nv; i++) {
            s->m.lo[k] = fminf(s->m.lo[k], s->v[i][k]);
            s->m.hi[k] = fmaxf(s->m.hi[k], s->v[i][k]);
        }
    }
}

/* The square [-1,1]^2 of the plane x = X, two triangles facing +x. */
static void square(small_mesh *s, float x, float half)
{
    float c[4][2] = {{-half, -half}, {half, -half}, {half, half}, {-half, half}};
    for (int i = 0; i < 4; i++) {
        s->v[i][0] = x;
        s->v[i][1] = c[i][0];
        s->v[i][2] = c[i][1];
    }
    uint32_t t[2][3] = {{0, 1, 2}, {0, 2, 3}};
    memcpy(s->t, t, sizeof t);
    finish(s, 4, 2);
}

Test(render_mesh, a_square_seen_face_on_fills_the_frame_less_its_margins)
{
    /* azimuth 0, elevation 0: the camera looks down -x; the square's side
     * is the framed box's, 90% of the image */
    static small_mesh s;
    square(&s, 0.0f, 1.0f);
    render_opts o = opts(100, 0, 0);
    render_image img;
    cr_assert_eq(render_mesh(&s.m, &o, 0, &img), 0);
    int n = count_lit(&img);
    cr_assert(abs(n - 90 * 90) <= 2 * 90 + 1, "%d pixels lit, want 8100", n);
    cr_assert_eq(img.splats, 2);
    cr_assert_eq(shades(&img), 1, "a flat plane is one shade");
    cr_assert(!lit(&img, 0) && !lit(&img, 100 * 100 - 1), "corners are background");
    render_image_free(&img);
}

/* A roof: two triangles bent along the z axis at 90 degrees. */
static void roof(small_mesh *s)
{
    float v[4][3] = {{0, 0, -1}, {0, 0, 1}, {1, -1, 0}, {1, 1, 0}};
    memcpy(s->v, v, sizeof v);
    uint32_t t[2][3] = {{0, 1, 2}, {1, 0, 3}};
    memcpy(s->t, t, sizeof t);
    finish(s, 4, 2);
}

Test(render_mesh, flat_gives_one_shade_a_triangle_and_smooth_a_gradient)
{
    static small_mesh s;
    roof(&s);
    render_opts o = opts(128, 10, 10);
    render_image flat, smooth;
    cr_assert_eq(render_mesh(&s.m, &o, 0, &flat), 0);
    cr_assert_eq(render_mesh(&s.m, &o, 1, &smooth), 0);
    cr_assert_eq(shades(&flat), 2, "flat: %d shades", shades(&flat));
    cr_assert(shades(&smooth) > 10, "smooth: %d shades", shades(&smooth));
    cr_assert_eq(count_lit(&flat), count_lit(&smooth), "the same pixels are covered");
    render_image_free(&flat);
    render_image_free(&smooth);
}

Test(render_mesh, the_nearer_square_hides_the_farther_in_either_order)
{
    static small_mesh s;
    square(&s, 0.0f, 1.0f);
    /* a smaller square in front (camera on +x), tilted so it shades apart */
    float v[4][3] = {{0.5f, -0.5f, -0.5f}, {0.6f, 0.5f, -0.5f}, {0.6f, 0.5f, 0.5f},
                     {0.5f, -0.5f, 0.5f}};
    memcpy(s.v + 4, v, sizeof v);
    uint32_t t[2][3] = {{4, 5, 6}, {4, 6, 7}};
    memcpy(s.t + 2, t, sizeof t);
    finish(&s, 8, 4);
    render_opts o = opts(101, 0, 0);
    render_image a, b;
    cr_assert_eq(render_mesh(&s.m, &o, 0, &a), 0);
    /* the same triangles in reverse order */
    static small_mesh r;
    r = s;
    for (int i = 0; i < 4; i++) memcpy(r.t[i], s.t[3 - i], sizeof r.t[i]);
    r.m.vertices = r.v;
    r.m.triangles = r.t;
    cr_assert_eq(render_mesh(&r.m, &o, 0, &b), 0);
    cr_assert_eq(memcmp(a.rgb, b.rgb, (size_t)101 * 101 * 3), 0, "order changed the image");
    size_t centre = 50 * 101 + 50, edge = 50 * 101 + 8;
    cr_assert(a.depth[centre] < a.depth[edge], "the centre is the nearer square");
    cr_assert_neq(a.rgb[3 * centre + 1], a.rgb[3 * edge + 1], "the front square shades apart");
    render_image_free(&a);
    render_image_free(&b);
}

/* A UV sphere of radius 1, n around, n / 2 from pole to pole. */
static void uv_sphere(mesh *m, int n)
{
    int rows = n / 2 + 1;
    m->n_vertices = (uint32_t)(rows * n);
    m->n_triangles = (uint32_t)(2 * n * (rows - 1));
    m->vertices = calloc(m->n_vertices, sizeof *m->vertices);
    m->triangles = calloc(m->n_triangles, sizeof *m->triangles);
    cr_assert(m->vertices && m->triangles);
    for (int j = 0; j < rows; j++)
        for (int i = 0; i < n; i++) {
            double th = M_PI * j / (rows - 1), ph = 2 * M_PI * i / n;
            float *p = m->vertices[j * n + i];
            p[0] = (float)(sin(th) * cos(ph));
            p[1] = (float)(sin(th) * sin(ph));
            p[2] = (float)cos(th);
        }
    uint32_t k = 0;
    for (int j = 0; j + 1 < rows; j++)
        for (int i = 0; i < n; i++) {
            uint32_t a = j * n + i, b = j * n + (i + 1) % n, c = a + n, d = b + n;
            uint32_t t1[3] = {a, c, b}, t2[3] = {b, c, d};
            memcpy(m->triangles[k++], t1, sizeof t1);
            memcpy(m->triangles[k++], t2, sizeof t2);
        }
    for (int a = 0; a < 3; a++) m->lo[a] = -1, m->hi[a] = 1;
}

Test(render_mesh, a_smooth_sphere_is_a_round_disc_bright_in_the_middle)
{
    mesh m;
    uv_sphere(&m, 64);
    render_opts o = opts(128, 30, 20);
    render_image img;
    cr_assert_eq(render_mesh(&m, &o, 1, &img), 0);
    /* the sphere's outline is a circle of radius 0.9 * 64 / sqrt(3)..: the
     * framed box is the cube, so compare with the disc the fit gives */
    int n = count_lit(&img);
    cr_assert(n > 3000 && n < 128 * 128 * 0.8, "%d pixels", n);
    int centre = img.rgb[3 * (64 * 128 + 64) + 1];
    int rim = 0;
    for (int i = 0; i < 128; i++) /* the leftmost lit pixel of the middle row */
        if (lit(&img, 64 * 128 + i)) {
            rim = img.rgb[3 * (64 * 128 + i) + 1];
            break;
        }
    cr_assert(centre > rim + 40, "centre %d, rim %d", centre, rim);
    render_image_free(&img);
    free(m.vertices);
    free(m.triangles);
}
