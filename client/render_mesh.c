/* render_mesh (render.h): a triangle mesh drawn by render_triangle, so a
 * volume and its polygonization can be shown side by side alike. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>

#include "render.h"

/* The normal of triangle t, its length twice the triangle's area. */
static void face_normal(const mesh *m, uint32_t t, double out[3])
{
    const uint32_t *v = m->triangles[t];
    double a[3], b[3];
    for (int k = 0; k < 3; k++) {
        a[k] = (double)m->vertices[v[1]][k] - m->vertices[v[0]][k];
        b[k] = (double)m->vertices[v[2]][k] - m->vertices[v[0]][k];
    }
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

/* Per vertex, the sum of its triangles' normals (area-weighted); NULL when
 * out of memory. */
static double (*vertex_normals(const mesh *m))[3]
{
    double (*vn)[3] = calloc(m->n_vertices ? m->n_vertices : 1, sizeof *vn);
    if (!vn) return NULL;
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        double f[3];
        face_normal(m, t, f);
        for (int c = 0; c < 3; c++)
            for (int k = 0; k < 3; k++) vn[m->triangles[t][c]][k] += f[k];
    }
    return vn;
}

int render_mesh(const mesh *m, const render_opts *o, int smooth, render_image *out)
{
    double lo[3], hi[3], ext = 0.0;
    for (int k = 0; k < 3; k++) {
        lo[k] = m->lo[k];
        hi[k] = m->hi[k];
        ext = fmax(ext, hi[k] - lo[k]);
    }
    /* render_begin's "voxel" only widens the frame's fit: a thousandth */
    double px = ext > 0.0 ? ext / 1000.0 : 1e-6, pix[3] = {px, px, px};
    render_ctx *ctx;
    int rc = render_begin(&ctx, o, lo, hi, pix);
    if (rc < 0) return rc;
    double (*vn)[3] = smooth ? vertex_normals(m) : NULL;
    if (smooth && !vn) {
        render_abort(ctx);
        return -ENOMEM;
    }
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        double p[3][3], n[3][3], f[3];
        if (!smooth) face_normal(m, t, f);
        for (int c = 0; c < 3; c++)
            for (int k = 0; k < 3; k++) {
                p[c][k] = m->vertices[m->triangles[t][c]][k];
                n[c][k] = smooth ? vn[m->triangles[t][c]][k] : f[k];
            }
        render_triangle(ctx, p, n);
    }
    free(vn);
    render_finish(ctx, out);
    return 0;
}
