/* Direct visualization (section 6 and Figure 6 of Stolte & Kaufman): voxels
 * drawn as shaded, z-buffered splats.  See render.h. */
#include "render.h"

#include <errno.h>
#include <math.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "outfile.h"
#include "voxel.h"

#define DEG (M_PI / 180.0)
/* The light: from the camera, offset this much up and to the left. */
#define LIGHT_UP 0.35
#define LIGHT_LEFT 0.35

struct render_ctx {
    render_opts o;
    render_image img;
    double light[3];      /* unit, world, toward the light */
    double half_w, half_h; /* world half extents of a voxel along right/up */
};

void render_opts_default(render_opts *o)
{
    /* the defaults render.h gives; the fields left out are 0 */
    *o = (render_opts){.width = 1024, .height = 1024, .azimuth = 30.0, .elevation = 20.0,
                       .fov = 35.0, .ambient = 0.2, .color = 0xffffff};
}

int render_opts_check(const render_opts *o)
{
    if (o->width < 1 || o->width > RENDER_MAX_SIZE || o->height < 1 ||
        o->height > RENDER_MAX_SIZE)
        return -EINVAL;
    if (!isfinite(o->azimuth) || !(o->elevation >= -90.0) ||
        !(o->elevation <= 90.0))
        return -EINVAL;
    if (o->perspective && !(o->fov > 0.0 && o->fov < 170.0)) return -EINVAL;
    if (!(o->ambient >= 0.0 && o->ambient <= 1.0)) return -EINVAL;
    if ((o->background | o->color) > 0xffffffu) return -EINVAL;
    return 0;
}

/* ---- vectors ---- */

static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void sub3(const double a[3], const double b[3], double out[3])
{
    for (int k = 0; k < 3; k++) out[k] = a[k] - b[k];
}

static int normalize3(double v[3])
{
    double l = sqrt(dot3(v, v));
    if (!(l > 0.0) || !isfinite(l)) return -1;
    for (int k = 0; k < 3; k++) v[k] /= l;
    return 0;
}

/* ---- camera ---- */

int render_project(const render_camera *c, const double p[3], double *px,
                   double *py, double *depth)
{
    double d[3];
    if (!c->perspective) {
        sub3(p, c->centre, d);
        *px = c->cx + dot3(d, c->right) * c->scale;
        *py = c->cy - dot3(d, c->up) * c->scale;
        *depth = dot3(d, c->forward) + c->ref;
        return 0;
    }
    sub3(p, c->eye, d);
    double z = dot3(d, c->forward);
    *depth = z;
    if (!(z > 0.0)) return -ERANGE;
    *px = c->cx + c->focal * dot3(d, c->right) / z;
    *py = c->cy - c->focal * dot3(d, c->up) / z;
    return 0;
}

/* Orbit basis: forward points from the camera to the centre; right is
 * horizontal (so it stays defined looking straight down or up). */
static void camera_basis(const render_opts *o, render_camera *c)
{
    double az = o->azimuth * DEG, el = o->elevation * DEG;
    c->forward[0] = -cos(el) * cos(az);
    c->forward[1] = -cos(el) * sin(az);
    c->forward[2] = -sin(el);
    c->right[0] = -sin(az);
    c->right[1] = cos(az);
    c->right[2] = 0.0;
    /* up = right x forward */
    c->up[0] = c->right[1] * c->forward[2] - c->right[2] * c->forward[1];
    c->up[1] = c->right[2] * c->forward[0] - c->right[0] * c->forward[2];
    c->up[2] = c->right[0] * c->forward[1] - c->right[1] * c->forward[0];
}

static void box_corner(const double lo[3], const double hi[3], int i,
                       double out[3])
{
    out[0] = i & 1 ? hi[0] : lo[0];
    out[1] = i & 2 ? hi[1] : lo[1];
    out[2] = i & 4 ? hi[2] : lo[2];
}

/* Orthographic: the scale that fits the projected corners (and at least one
 * voxel) inside the frame less its margins. */
static void fit_ortho(render_ctx *ctx, const double lo[3], const double hi[3])
{
    render_camera *c = &ctx->img.cam;
    double amax = ctx->half_w, bmax = ctx->half_h, r2 = 0.0;
    for (int i = 0; i < 8; i++) {
        double p[3], d[3];
        box_corner(lo, hi, i, p);
        sub3(p, c->centre, d);
        amax = fmax(amax, fabs(dot3(d, c->right)));
        bmax = fmax(bmax, fabs(dot3(d, c->up)));
        r2 = fmax(r2, dot3(d, d));
    }
    double fill = 1.0 - 2.0 * RENDER_MARGIN;
    c->scale = fmin(0.5 * ctx->o.width * fill / amax,
                    0.5 * ctx->o.height * fill / bmax);
    /* The camera plane sits outside the box, so depths are positive. */
    c->ref = sqrt(r2) + ctx->half_w + ctx->half_h;
}

/* Perspective: the nearest camera distance at which every corner, grown by
 * half a voxel, projects inside the frame less its margins. */
static void fit_perspective(render_ctx *ctx, const double lo[3],
                            const double hi[3])
{
    render_camera *c = &ctx->img.cam;
    double fill = 1.0 - 2.0 * RENDER_MARGIN;
    double ty = tan(0.5 * ctx->o.fov * DEG);
    double tx = ty * ctx->o.width / ctx->o.height;
    double dist = 0.0;
    for (int i = 0; i < 8; i++) {
        double p[3], d[3];
        box_corner(lo, hi, i, p);
        sub3(p, c->centre, d);
        double a = fabs(dot3(d, c->right)) + ctx->half_w;
        double b = fabs(dot3(d, c->up)) + ctx->half_h;
        double need = fmax(a / (tx * fill), b / (ty * fill)) -
                      dot3(d, c->forward);
        dist = fmax(dist, need);
    }
    c->focal = 0.5 * ctx->o.height / ty;
    for (int k = 0; k < 3; k++) c->eye[k] = c->centre[k] - dist * c->forward[k];
}

static void setup_light(render_ctx *ctx)
{
    const render_camera *c = &ctx->img.cam;
    for (int k = 0; k < 3; k++)
        ctx->light[k] =
            -c->forward[k] + LIGHT_UP * c->up[k] - LIGHT_LEFT * c->right[k];
    normalize3(ctx->light);
}

/* ---- image ---- */

static int image_alloc(render_image *img, int w, int h, uint32_t bg)
{
    size_t n = (size_t)w * (size_t)h;
    img->width = w;
    img->height = h;
    img->rgb = malloc(n * 3);
    img->depth = malloc(n * sizeof(float));
    if (!img->rgb || !img->depth) {
        render_image_free(img);
        return -ENOMEM;
    }
    for (size_t i = 0; i < n; i++) {
        img->rgb[3 * i] = (uint8_t)(bg >> 16);
        img->rgb[3 * i + 1] = (uint8_t)(bg >> 8);
        img->rgb[3 * i + 2] = (uint8_t)bg;
        img->depth[i] = INFINITY;
    }
    img->splats = 0;
    return 0;
}

void render_image_free(render_image *img)
{
    free(img->rgb);
    free(img->depth);
    img->rgb = NULL;
    img->depth = NULL;
}

static int box_valid(const double lo[3], const double hi[3],
                     const double voxel[3])
{
    for (int k = 0; k < 3; k++)
        if (!isfinite(lo[k]) || !isfinite(hi[k]) || !(lo[k] <= hi[k]) ||
            !isfinite(voxel[k]) || !(voxel[k] > 0.0))
            return 0;
    return 1;
}

int render_begin(render_ctx **out, const render_opts *o, const double lo[3],
                 const double hi[3], const double voxel[3])
{
    *out = NULL;
    if (render_opts_check(o) < 0 || !box_valid(lo, hi, voxel)) return -EINVAL;
    render_ctx *ctx = calloc(1, sizeof(*ctx));
    if (!ctx) return -ENOMEM;
    ctx->o = *o;
    int rc = image_alloc(&ctx->img, o->width, o->height, o->background);
    if (rc < 0) {
        free(ctx);
        return rc;
    }
    render_camera *c = &ctx->img.cam;
    c->perspective = o->perspective != 0;
    camera_basis(o, c);
    for (int k = 0; k < 3; k++) c->centre[k] = 0.5 * (lo[k] + hi[k]);
    c->cx = 0.5 * o->width;
    c->cy = 0.5 * o->height;
    /* Half the bounding rectangle of one projected voxel box. */
    for (int k = 0; k < 3; k++) {
        ctx->half_w += 0.5 * fabs(c->right[k]) * voxel[k];
        ctx->half_h += 0.5 * fabs(c->up[k]) * voxel[k];
    }
    if (c->perspective)
        fit_perspective(ctx, lo, hi);
    else
        fit_ortho(ctx, lo, hi);
    setup_light(ctx);
    *out = ctx;
    return 0;
}

/* ---- splats ---- */

static uint32_t shade(const render_ctx *ctx, const double p[3],
                      const double n[3])
{
    double m[3], v[3], lit = 1.0;
    if (n) {
        memcpy(m, n, sizeof(m));
        if (normalize3(m) == 0) {
            /* Toward the viewer: flip a normal that faces away. */
            if (ctx->img.cam.perspective)
                sub3(ctx->img.cam.eye, p, v);
            else
                for (int k = 0; k < 3; k++) v[k] = -ctx->img.cam.forward[k];
            if (dot3(m, v) < 0.0)
                for (int k = 0; k < 3; k++) m[k] = -m[k];
            lit = fmax(0.0, dot3(m, ctx->light));
        }
    }
    double i = ctx->o.ambient + (1.0 - ctx->o.ambient) * lit;
    uint32_t rgb = 0;
    for (int s = 16; s >= 0; s -= 8) {
        double ch = floor(((ctx->o.color >> s) & 0xffu) * i + 0.5);
        rgb |= (uint32_t)fmin(255.0, fmax(0.0, ch)) << s;
    }
    return rgb;
}

/* Pixels whose centres lie in [lo, hi), clipped to [0, size); at least the
 * pixel holding the centre.  0 when nothing is left. */
static int span(double centre, double half, int size, int *a, int *b)
{
    double lo = ceil(centre - half - 0.5), hi = ceil(centre + half - 0.5);
    if (hi <= lo) {
        lo = floor(centre);
        hi = lo + 1.0;
    }
    lo = fmax(lo, 0.0);
    hi = fmin(hi, (double)size);
    if (!(lo < hi)) return 0;
    *a = (int)lo;
    *b = (int)hi;
    return 1;
}

/* A splat's rectangle in the image: its centre and half its sides. */
typedef struct {
    double x, y, hw, hh;
} splat_rect;

static void draw(render_ctx *ctx, const splat_rect *r, float depth, uint32_t rgb)
{
    render_image *img = &ctx->img;
    int i0, i1, j0, j1;
    if (!span(r->x, r->hw, img->width, &i0, &i1) ||
        !span(r->y, r->hh, img->height, &j0, &j1))
        return;
    for (int j = j0; j < j1; j++) {
        size_t row = (size_t)j * (size_t)img->width;
        for (int i = i0; i < i1; i++) {
            float *zb = &img->depth[row + (size_t)i];
            uint8_t *c = &img->rgb[3 * (row + (size_t)i)];
            uint32_t old = (uint32_t)c[0] << 16 | (uint32_t)c[1] << 8 | c[2];
            /* Ties go to the brighter colour: order-independent. */
            if (depth < *zb || (depth == *zb && rgb > old)) {
                *zb = depth;
                c[0] = (uint8_t)(rgb >> 16);
                c[1] = (uint8_t)(rgb >> 8);
                c[2] = (uint8_t)rgb;
            }
        }
    }
}

void render_splat(render_ctx *ctx, const double p[3], const double n[3])
{
    const render_camera *c = &ctx->img.cam;
    double px, py, depth;
    if (render_project(c, p, &px, &py, &depth) < 0) return;
    if (!isfinite(px) || !isfinite(py) || !isfinite(depth)) return;
    double k = c->perspective ? c->focal / depth : c->scale;
    ctx->img.splats++;
    splat_rect r = {px, py, ctx->half_w * k, ctx->half_h * k};
    draw(ctx, &r, (float)depth, shade(ctx, p, n));
}

/* The triangle's edge function at (x, y): twice the signed area of (a, b,
 * (x, y)), positive on the left of a->b in image coordinates. */
static double edge(const double a[3], const double b[3], double x, double y)
{
    return (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]);
}

/* A triangle being drawn: its vertices in the image (x, y, depth), in the
 * world and their normals, and twice its signed area in the image. */
typedef struct {
    const double (*s)[3], (*p)[3], (*n)[3];
    double area;
} render_tri;

/* The pixels of row j, columns [i0, i1), whose centres lie in the triangle,
 * z-buffered as draw() does. */
static void tri_row(render_ctx *ctx, const render_tri *t, int j, int i0, int i1)
{
    render_image *img = &ctx->img;
    const double(*s)[3] = t->s, (*p)[3] = t->p, (*n)[3] = t->n;
    double area = t->area;
    double y = j + 0.5;
    for (int i = i0; i < i1; i++) {
        double x = i + 0.5, w[3];
        w[0] = edge(s[1], s[2], x, y) / area;
        w[1] = edge(s[2], s[0], x, y) / area;
        w[2] = 1.0 - w[0] - w[1];
        if (w[0] < 0.0 || w[1] < 0.0 || w[2] < 0.0) continue;
        /* depth: linear in the image for orthographic, 1/depth for perspective */
        double d = ctx->img.cam.perspective
                       ? 1.0 / (w[0] / s[0][2] + w[1] / s[1][2] + w[2] / s[2][2])
                       : w[0] * s[0][2] + w[1] * s[1][2] + w[2] * s[2][2];
        size_t at = (size_t)j * (size_t)img->width + (size_t)i;
        if (!((float)d <= img->depth[at])) continue;
        double q[3], m[3];
        for (int k = 0; k < 3; k++) {
            q[k] = w[0] * p[0][k] + w[1] * p[1][k] + w[2] * p[2][k];
            m[k] = w[0] * n[0][k] + w[1] * n[1][k] + w[2] * n[2][k];
        }
        uint32_t rgb = shade(ctx, q, m);
        uint8_t *c = &img->rgb[3 * at];
        uint32_t old = (uint32_t)c[0] << 16 | (uint32_t)c[1] << 8 | c[2];
        /* Ties go to the brighter colour, as for splats: a shared edge's
         * pixels do not depend on the order of the triangles. */
        if ((float)d < img->depth[at] || rgb > old) {
            img->depth[at] = (float)d;
            c[0] = (uint8_t)(rgb >> 16);
            c[1] = (uint8_t)(rgb >> 8);
            c[2] = (uint8_t)rgb;
        }
    }
}

void render_triangle(render_ctx *ctx, const double p[3][3], const double n[3][3])
{
    double s[3][3], lo[2] = {INFINITY, INFINITY}, hi[2] = {-INFINITY, -INFINITY};
    for (int v = 0; v < 3; v++) {
        if (render_project(&ctx->img.cam, p[v], &s[v][0], &s[v][1], &s[v][2]) < 0) return;
        for (int k = 0; k < 3; k++)
            if (!isfinite(s[v][k])) return;
        for (int k = 0; k < 2; k++) {
            lo[k] = fmin(lo[k], s[v][k]);
            hi[k] = fmax(hi[k], s[v][k]);
        }
    }
    double area = edge(s[0], s[1], s[2][0], s[2][1]);
    if (area == 0.0) return; /* edge-on: no pixel centre is inside */
    /* pixel centres i + 0.5 in [lo, hi], clipped to the image */
    int i0 = (int)fmax(0.0, ceil(lo[0] - 0.5)), i1 = (int)fmin(ctx->img.width, floor(hi[0] - 0.5) + 1);
    int j0 = (int)fmax(0.0, ceil(lo[1] - 0.5)), j1 = (int)fmin(ctx->img.height, floor(hi[1] - 0.5) + 1);
    ctx->img.splats++;
    render_tri t = {s, p, n, area};
    for (int j = j0; j < j1; j++) tri_row(ctx, &t, j, i0, i1);
}

void render_finish(render_ctx *ctx, render_image *out)
{
    *out = ctx->img;
    free(ctx);
}

void render_abort(render_ctx *ctx)
{
    if (!ctx) return;
    render_image_free(&ctx->img);
    free(ctx);
}

/* ---- octree source (Figure 6) ---- */

/* Voxel index box [lo, hi) of the voxels present; 0 if none. */
static int octree_bounds(const octree *t, uint32_t lo[3], uint32_t hi[3])
{
    octree_iter it;
    uint32_t p[3], v;
    int any = 0;
    octree_iter_init(&it, t);
    while (octree_iter_next(&it, &p[0], &p[1], &p[2], &v)) {
        for (int k = 0; k < 3; k++) {
            if (!any || p[k] < lo[k]) lo[k] = p[k];
            if (!any || p[k] + 1 > hi[k]) hi[k] = p[k] + 1;
        }
        any = 1;
    }
    return any;
}

/* The world box to frame: the voxels' box, or the volume's. */
static void world_box(const double origin[3], const double voxel[3],
                      const uint32_t ilo[3], const uint32_t ihi[3],
                      double lo[3], double hi[3])
{
    for (int k = 0; k < 3; k++) {
        lo[k] = origin[k] + ilo[k] * voxel[k];
        hi[k] = origin[k] + ihi[k] * voxel[k];
    }
}

int render_octree(const octree *t, const double origin[3],
                  const double voxel[3], const uint32_t res[3],
                  const render_opts *o, render_image *out)
{
    uint32_t ilo[3] = {0, 0, 0}, ihi[3], side = 1u << t->depth;
    double lo[3], hi[3], p[3], n[3];
    for (int k = 0; k < 3; k++) ihi[k] = res ? res[k] : side;
    if (!o->fit_volume) octree_bounds(t, ilo, ihi);
    world_box(origin, voxel, ilo, ihi, lo, hi);
    render_ctx *ctx;
    int rc = render_begin(&ctx, o, lo, hi, voxel);
    if (rc < 0) return rc;
    octree_iter it;
    uint32_t x, y, z, v;
    octree_iter_init(&it, t);
    while (octree_iter_next(&it, &x, &y, &z, &v)) {
        p[0] = origin[0] + (x + 0.5) * voxel[0];
        p[1] = origin[1] + (y + 0.5) * voxel[1];
        p[2] = origin[2] + (z + 0.5) * voxel[2];
        voxel_unpack_normal(v, n);
        render_splat(ctx, p, n);
    }
    render_finish(ctx, out);
    return 0;
}

/* ---- VOD source ---- */

enum vod_mode { MODE_NORMALS, MODE_OCCUPANCY, MODE_DISTANCE };

typedef struct {
    render_ctx *ctx;
    const vod_file *f;
    int level;
    enum vod_mode mode;
    uint32_t lim;          /* voxels per axis at the level */
    double origin[3], voxel[3];
    uint32_t lo[3], hi[3]; /* bounds pass: index box [lo, hi) */
    int any;
} vod_walk;

/* Channel 4: the voxel's distance, and whether it is within a voxel of
 * the zero level (the voxels drawn). */
static float as_float(uint32_t v)
{
    float f;
    memcpy(&f, &v, sizeof f);
    return f;
}

static int near_zero(const vod_walk *w, uint32_t v)
{
    return fabs(as_float(v)) < w->voxel[0];
}

static int bounds_cb(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    vod_walk *w = ud;
    uint32_t p[3] = {x, y, z};
    if (w->mode == MODE_DISTANCE && !near_zero(w, v)) return 0;
    for (int k = 0; k < 3; k++) {
        if (!w->any || p[k] < w->lo[k]) w->lo[k] = p[k];
        if (!w->any || p[k] + 1 > w->hi[k]) w->hi[k] = p[k] + 1;
    }
    w->any = 1;
    return 0;
}

static int occupied(const vod_walk *w, int64_t x, int64_t y, int64_t z)
{
    if (x < 0 || y < 0 || z < 0 || x >= w->lim || y >= w->lim || z >= w->lim)
        return 0;
    return vod_voxel(w->f, w->level, (uint32_t)x, (uint32_t)y, (uint32_t)z) != 0;
}

/* 1 when the six face neighbours are all occupied: the voxel is hidden. */
static int enclosed(const vod_walk *w, uint32_t x, uint32_t y, uint32_t z)
{
    return occupied(w, x - 1ll, y, z) && occupied(w, x + 1ll, y, z) &&
           occupied(w, x, y - 1ll, z) && occupied(w, x, y + 1ll, z) &&
           occupied(w, x, y, z - 1ll) && occupied(w, x, y, z + 1ll);
}

/* The negated occupancy gradient over the 26 neighbours, each weighted by
 * 1/|d|^2, taken to world space (a gradient scales by 1/voxel size). */
static void occupancy_normal(const vod_walk *w, uint32_t x, uint32_t y,
                             uint32_t z, double n[3])
{
    n[0] = n[1] = n[2] = 0.0;
    for (int dz = -1; dz <= 1; dz++)
        for (int dy = -1; dy <= 1; dy++)
            for (int dx = -1; dx <= 1; dx++) {
                int d2 = dx * dx + dy * dy + dz * dz;
                if (!d2 || !occupied(w, (int64_t)x + dx, (int64_t)y + dy,
                                     (int64_t)z + dz))
                    continue;
                n[0] -= dx / (double)d2;
                n[1] -= dy / (double)d2;
                n[2] -= dz / (double)d2;
            }
    for (int k = 0; k < 3; k++) n[k] /= w->voxel[k];
}

/* The distance at (x, y, z) of the level, clamped into the volume. */
static double dist_at(const vod_walk *w, int64_t x, int64_t y, int64_t z)
{
    int64_t c[3] = {x, y, z};
    for (int k = 0; k < 3; k++) c[k] = c[k] < 0 ? 0 : c[k] >= w->lim ? w->lim - 1 : c[k];
    return as_float(vod_voxel(w->f, w->level, (uint32_t)c[0], (uint32_t)c[1], (uint32_t)c[2]));
}

/* Channel 4: a voxel within a voxel of the zero level splats at its centre
 * moved by -d along the distance's gradient (central differences, world
 * units), the gradient its normal: the zero level drawn, not the shell. */
static int splat_distance(vod_walk *w, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    if (!near_zero(w, v)) return 0;
    double d = as_float(v), n[3], p[3], len = 0;
    int64_t X = x, Y = y, Z = z;
    n[0] = (dist_at(w, X + 1, Y, Z) - dist_at(w, X - 1, Y, Z)) / w->voxel[0];
    n[1] = (dist_at(w, X, Y + 1, Z) - dist_at(w, X, Y - 1, Z)) / w->voxel[1];
    n[2] = (dist_at(w, X, Y, Z + 1) - dist_at(w, X, Y, Z - 1)) / w->voxel[2];
    for (int k = 0; k < 3; k++) len += n[k] * n[k];
    len = sqrt(len);
    uint32_t c[3] = {x, y, z};
    for (int k = 0; k < 3; k++)
        p[k] = w->origin[k] + (c[k] + 0.5) * w->voxel[k] - (len > 0 ? d * n[k] / len : 0);
    render_splat(w->ctx, p, n);
    return 0;
}

static int splat_cb(void *ud, uint32_t x, uint32_t y, uint32_t z, uint32_t v)
{
    vod_walk *w = ud;
    double p[3], n[3];
    if (w->mode == MODE_DISTANCE) return splat_distance(w, x, y, z, v);
    if (w->mode == MODE_NORMALS) {
        if (!voxel_occupancy(v)) return 0;
        voxel_unpack_normal(v, n);
    } else {
        if (enclosed(w, x, y, z)) return 0;
        occupancy_normal(w, x, y, z, n);
    }
    p[0] = w->origin[0] + (x + 0.5) * w->voxel[0];
    p[1] = w->origin[1] + (y + 0.5) * w->voxel[1];
    p[2] = w->origin[2] + (z + 0.5) * w->voxel[2];
    render_splat(w->ctx, p, n);
    return 0;
}

/* How to shade the file's voxels, or -ENOTSUP. */
static int vod_mode_of(const vod_info *in, enum vod_mode *mode, err_info *e)
{
    uint32_t ch = in->channel, bits = in->voxel_bits;
    int is_float = (in->flags & VOD_FLAG_FLOAT) != 0;
    if ((ch == VOXEL_CH_SURFACE || ch == VOXEL_CH_UNSPECIFIED) && bits == 32 &&
        !is_float) {
        *mode = MODE_NORMALS;
        return 0;
    }
    if ((ch == VOXEL_CH_OCCUPANCY || ch == VOXEL_CH_UNSPECIFIED) && bits == 1) {
        *mode = MODE_OCCUPANCY;
        return 0;
    }
    if (ch == VOXEL_CH_DISTANCE && bits == 32) {
        *mode = MODE_DISTANCE;
        return 0;
    }
    return err_set(e, -ENOTSUP,
                   "render: channel %u with %u-bit%s voxels is not supported "
                   "(only 1-bit occupancy, 32-bit surface voxels and f32 distances)",
                   ch, bits, is_float ? " float" : "");
}

static int vod_walk_init(vod_walk *w, const vod_file *f, int level, err_info *e)
{
    const vod_info *in = vod_get_info(f);
    memset(w, 0, sizeof(*w));
    if (level < 0 || (uint32_t)level >= in->height)
        return err_set(e, -EINVAL, "render: level %d outside 0..%u", level, in->height - 1);
    int rc = vod_mode_of(in, &w->mode, e);
    if (rc < 0) return rc;
    w->f = f;
    w->level = level;
    w->lim = vod_level_size(f, level);
    for (int k = 0; k < 3; k++) {
        w->origin[k] = in->origin[k];
        w->voxel[k] = ldexp(in->voxel_scale[k], level);
    }
    return 0;
}

/* The world box to frame at w's level: the voxels' box, else the volume. */
static void vod_box(vod_walk *w, const render_opts *o, double lo[3],
                    double hi[3])
{
    const vod_info *in = vod_get_info(w->f);
    if (!o->fit_volume) vod_foreach(w->f, w->level, bounds_cb, w);
    for (int k = 0; k < 3; k++) {
        if (w->any) {
            lo[k] = w->origin[k] + w->lo[k] * w->voxel[k];
            hi[k] = w->origin[k] + w->hi[k] * w->voxel[k];
        } else {
            lo[k] = w->origin[k];
            hi[k] = w->origin[k] + (double)in->volume[k] * in->voxel_scale[k];
        }
    }
}

int render_vod(const vod_file *f, int level, const render_opts *o, render_image *out,
               err_info *e)
{
    vod_walk w;
    double lo[3], hi[3];
    int rc = vod_walk_init(&w, f, level, e);
    if (rc < 0) return rc;
    if (render_opts_check(o) < 0)
        return err_set(e, -EINVAL, "render: bad options (size 1..%d, elevation "
                       "-90..90, fov 0..170, ambient 0..1)", RENDER_MAX_SIZE);
    vod_box(&w, o, lo, hi);
    rc = render_begin(&w.ctx, o, lo, hi, w.voxel);
    if (rc < 0) return err_set(e, rc, "render: %s", strerror(-rc));
    rc = vod_foreach(f, level, splat_cb, &w);
    if (rc) { /* splat_cb never stops the walk: the reader failed */
        render_abort(w.ctx);
        return err_set(e, rc < 0 ? rc : -EIO, "render: reading level %d: %s", level,
                       strerror(rc < 0 ? -rc : EIO));
    }
    render_finish(w.ctx, out);
    return 0;
}

/* ---- PNG ---- */

int render_write_png(const render_image *img, const char *path)
{
    png_image pi;
    memset(&pi, 0, sizeof(pi));
    pi.version = PNG_IMAGE_VERSION;
    pi.width = (png_uint_32)img->width;
    pi.height = (png_uint_32)img->height;
    pi.format = PNG_FORMAT_RGB;
    png_int_32 stride = 3 * img->width;
    /* made in memory, then written as every vox output is (outfile): the
     * write's errors are the file system's own, the file whole or absent */
    png_alloc_size_t size = 0;
    uint8_t *png = NULL;
    int ok = png_image_write_get_memory_size(pi, size, 0, img->rgb, stride, NULL) &&
             (png = malloc(size)) &&
             png_image_write_to_memory(&pi, png, &size, 0, img->rgb, stride, NULL);
    png_image_free(&pi);
    int rc = ok ? outfile_put(path, png, size) : -ENOMEM;
    free(png);
    return rc;
}
