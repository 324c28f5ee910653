/* mesh_shapes — closed triangle meshes built in memory (mesh.h) for the
 * tests and the mesh voxelizer's timing harness: a box, an icosphere of
 * level L, a torus, a sphere inside a hollow sphere, a non-convex "C" prism,
 * and triangles taken away (holes).  Triangles are counter-clockwise seen
 * from outside; vertices are shared by index, so every mesh is closed.
 *
 * Every coordinate is rounded to a multiple of 2^-20 (SHAPE_QUANTUM): on a
 * grid whose low corner is such a multiple and whose voxel size is 2^-k
 * with k >= 4, the voxelizer's lattice (2^-16 voxel) holds these vertices
 * exactly, so an oracle in double sees the very mesh that is voxelized.
 *
 * Append shapes to one mesh (shape_init, then shape_*), shape_finish() for
 * the bounding box, shape_free() at the end. */
#ifndef VOXD_TEST_MESH_SHAPES_H
#define VOXD_TEST_MESH_SHAPES_H

#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "mesh.h"

#define SHAPE_QUANTUM (1.0 / 1048576.0) /* 2^-20 */

typedef struct {
    mesh m;
    uint32_t cap_v, cap_t;
} shape;

static inline void shape_init(shape *s)
{
    memset(s, 0, sizeof *s);
}

static inline void shape_free(shape *s)
{
    free(s->m.vertices);
    free(s->m.triangles);
    memset(s, 0, sizeof *s);
}

static inline float shape_q(double x)
{
    return (float)(nearbyint(x / SHAPE_QUANTUM) * SHAPE_QUANTUM);
}

static inline uint32_t shape_vertex(shape *s, double x, double y, double z)
{
    if (s->m.n_vertices == s->cap_v) {
        s->cap_v = s->cap_v ? 2 * s->cap_v : 64;
        s->m.vertices = realloc(s->m.vertices, s->cap_v * sizeof *s->m.vertices);
        if (!s->m.vertices) abort();
    }
    float *v = s->m.vertices[s->m.n_vertices];
    v[0] = shape_q(x), v[1] = shape_q(y), v[2] = shape_q(z);
    return s->m.n_vertices++;
}

static inline void shape_tri(shape *s, uint32_t a, uint32_t b, uint32_t c)
{
    if (s->m.n_triangles == s->cap_t) {
        s->cap_t = s->cap_t ? 2 * s->cap_t : 64;
        s->m.triangles = realloc(s->m.triangles, s->cap_t * sizeof *s->m.triangles);
        if (!s->m.triangles) abort();
    }
    uint32_t *t = s->m.triangles[s->m.n_triangles++];
    t[0] = a, t[1] = b, t[2] = c;
}

static inline void shape_quad(shape *s, uint32_t a, uint32_t b, uint32_t c, uint32_t d)
{
    shape_tri(s, a, b, c);
    shape_tri(s, a, c, d);
}

/* The bounding box of the triangles' vertices. */
static inline const mesh *shape_finish(shape *s)
{
    mesh *m = &s->m;
    for (int a = 0; a < 3; a++) m->lo[a] = INFINITY, m->hi[a] = -INFINITY;
    for (uint32_t t = 0; t < m->n_triangles; t++)
        for (int i = 0; i < 3; i++)
            for (int a = 0; a < 3; a++) {
                float v = m->vertices[m->triangles[t][i]][a];
                if (v < m->lo[a]) m->lo[a] = v;
                if (v > m->hi[a]) m->hi[a] = v;
            }
    return m;
}

/* Vertices from `first` on := R v + t (rounded again). */
static inline void shape_transform(shape *s, uint32_t first, const double R[3][3],
                                   const double t[3])
{
    for (uint32_t i = first; i < s->m.n_vertices; i++) {
        float *v = s->m.vertices[i];
        double p[3] = {v[0], v[1], v[2]}, q[3];
        for (int a = 0; a < 3; a++) q[a] = R[a][0] * p[0] + R[a][1] * p[1] + R[a][2] * p[2] + t[a];
        for (int a = 0; a < 3; a++) v[a] = shape_q(q[a]);
    }
}

/* Rotation by angle about the unit axis k (Rodrigues). */
static inline void shape_rotation(const double k[3], double angle, double R[3][3])
{
    double c = cos(angle), s = sin(angle), C = 1 - c;
    R[0][0] = c + k[0] * k[0] * C, R[0][1] = k[0] * k[1] * C - k[2] * s, R[0][2] = k[0] * k[2] * C + k[1] * s;
    R[1][0] = k[1] * k[0] * C + k[2] * s, R[1][1] = c + k[1] * k[1] * C, R[1][2] = k[1] * k[2] * C - k[0] * s;
    R[2][0] = k[2] * k[0] * C - k[1] * s, R[2][1] = k[2] * k[1] * C + k[0] * s, R[2][2] = c + k[2] * k[2] * C;
}

static inline void shape_box(shape *s, const double lo[3], const double hi[3])
{
    uint32_t v[8];
    for (int i = 0; i < 8; i++)
        v[i] = shape_vertex(s, i & 1 ? hi[0] : lo[0], i & 2 ? hi[1] : lo[1],
                            i & 4 ? hi[2] : lo[2]);
    shape_quad(s, v[0], v[2], v[3], v[1]); /* z = lo, normal -z */
    shape_quad(s, v[4], v[5], v[7], v[6]); /* z = hi */
    shape_quad(s, v[0], v[1], v[5], v[4]); /* y = lo */
    shape_quad(s, v[2], v[6], v[7], v[3]); /* y = hi */
    shape_quad(s, v[0], v[4], v[6], v[2]); /* x = lo */
    shape_quad(s, v[1], v[3], v[7], v[5]); /* x = hi */
}

/* The midpoint vertex of edge (a, b), made once (a small hash table of
 * edges; the unit-sphere points in pos). */
typedef struct {
    uint64_t *keys;
    uint32_t *vals;
    size_t cap;
} shape_edges;

static inline uint32_t shape_midpoint(shape *s, shape_edges *e, double (*pos)[3],
                                      uint32_t base, uint32_t a, uint32_t b)
{
    uint64_t key = a < b ? (uint64_t)a << 32 | b : (uint64_t)b << 32 | a;
    size_t h = (size_t)((key * 0x9e3779b97f4a7c15ull) >> 20) % e->cap;
    while (e->keys[h] != UINT64_MAX) {
        if (e->keys[h] == key) return e->vals[h];
        h = (h + 1) % e->cap;
    }
    uint32_t n = s->m.n_vertices - base;
    double p[3], l = 0;
    for (int i = 0; i < 3; i++) p[i] = pos[a][i] + pos[b][i], l += p[i] * p[i];
    l = sqrt(l);
    for (int i = 0; i < 3; i++) pos[n][i] = p[i] / l;
    e->keys[h] = key;
    e->vals[h] = n;
    shape_vertex(s, 0, 0, 0); /* placed by shape_icosphere */
    return n;
}

/* An icosahedron subdivided level times (20 * 4^level triangles), its
 * vertices on the sphere (centre c, radius r); inward: facing the centre
 * (the inner wall of a hollow). */
static inline void shape_icosphere(shape *s, const double c[3], double r, int level,
                                   bool inward)
{
    uint64_t nt = 20ull << (2 * level), nv = nt / 2 + 2;
    double (*pos)[3] = malloc(nv * sizeof *pos);
    uint32_t (*tri)[3] = malloc(nt * sizeof *tri), (*nxt)[3] = malloc(nt * sizeof *nxt);
    shape_edges e = {malloc(2 * nt * sizeof(uint64_t)), malloc(2 * nt * sizeof(uint32_t)), 2 * nt};
    if (!pos || !tri || !nxt || !e.keys || !e.vals) abort();
    uint32_t base = s->m.n_vertices;
    double t = (1 + sqrt(5.0)) / 2;
    const double ico[12][3] = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                               {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                               {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
    static const uint32_t faces[20][3] = {
        {0, 11, 5}, {0, 5, 1}, {0, 1, 7}, {0, 7, 10}, {0, 10, 11},
        {1, 5, 9}, {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
        {3, 9, 4}, {3, 4, 2}, {3, 2, 6}, {3, 6, 8}, {3, 8, 9},
        {4, 9, 5}, {2, 4, 11}, {6, 2, 10}, {8, 6, 7}, {9, 8, 1}};
    for (int i = 0; i < 12; i++) {
        double l = sqrt(ico[i][0] * ico[i][0] + ico[i][1] * ico[i][1] + ico[i][2] * ico[i][2]);
        for (int a = 0; a < 3; a++) pos[i][a] = ico[i][a] / l;
        shape_vertex(s, 0, 0, 0);
    }
    memcpy(tri, faces, sizeof faces);
    uint64_t n = 20;
    for (int l = 0; l < level; l++) {
        for (size_t i = 0; i < e.cap; i++) e.keys[i] = UINT64_MAX;
        for (uint64_t i = 0; i < n; i++) {
            uint32_t a = tri[i][0], b = tri[i][1], d = tri[i][2];
            uint32_t ab = shape_midpoint(s, &e, pos, base, a, b);
            uint32_t bd = shape_midpoint(s, &e, pos, base, b, d);
            uint32_t da = shape_midpoint(s, &e, pos, base, d, a);
            uint32_t q[4][3] = {{a, ab, da}, {b, bd, ab}, {d, da, bd}, {ab, bd, da}};
            memcpy(nxt[4 * i], q, sizeof q);
        }
        n *= 4;
        uint32_t (*sw)[3] = tri;
        tri = nxt, nxt = sw;
    }
    for (uint32_t i = 0; i < s->m.n_vertices - base; i++) {
        float *v = s->m.vertices[base + i];
        for (int a = 0; a < 3; a++) v[a] = shape_q(c[a] + r * pos[i][a]);
    }
    for (uint64_t i = 0; i < n; i++)
        shape_tri(s, base + tri[i][0], base + tri[i][inward ? 2 : 1],
                  base + tri[i][inward ? 1 : 2]);
    free(pos), free(tri), free(nxt), free(e.keys), free(e.vals);
}

/* A torus about the z axis through c: tube radius r at distance R. */
static inline void shape_torus(shape *s, const double c[3], double R, double r,
                               int nu, int nv)
{
    uint32_t base = s->m.n_vertices;
    for (int i = 0; i < nu; i++)
        for (int j = 0; j < nv; j++) {
            double u = 2 * M_PI * i / nu, v = 2 * M_PI * j / nv;
            shape_vertex(s, c[0] + (R + r * cos(v)) * cos(u), c[1] + (R + r * cos(v)) * sin(u),
                         c[2] + r * sin(v));
        }
    for (int i = 0; i < nu; i++)
        for (int j = 0; j < nv; j++) {
            uint32_t a = base + (uint32_t)(i * nv + j), b = base + (uint32_t)(((i + 1) % nu) * nv + j),
                     d = base + (uint32_t)(i * nv + (j + 1) % nv),
                     e = base + (uint32_t)(((i + 1) % nu) * nv + (j + 1) % nv);
            shape_quad(s, a, b, e, d);
        }
}

/* A sphere of radius r_core inside a hollow sphere (radii r_in < r_out). */
static inline void shape_nested(shape *s, const double c[3], double r_out, double r_in,
                                double r_core, int level)
{
    shape_icosphere(s, c, r_out, level, false);
    shape_icosphere(s, c, r_in, level, true);
    shape_icosphere(s, c, r_core, level, false);
}

/* A "C" prism: the letter in the xy plane, cells of side unit from lo (3 x
 * 3 cells, open towards +x between y = 1 and 2), depth along z. */
static inline void shape_c(shape *s, const double lo[3], double unit, double depth)
{
    static const int X[3] = {0, 1, 3};
    uint32_t v[2][3][4]; /* [cap][x index][y] */
    for (int k = 0; k < 2; k++)
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 4; j++)
                v[k][i][j] = shape_vertex(s, lo[0] + X[i] * unit, lo[1] + j * unit,
                                          lo[2] + k * depth);
    /* the cap's cells (x index i..i+1, y j..j+1) */
    static const int cells[5][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 0}, {1, 2}};
    for (int c = 0; c < 5; c++) {
        int i = cells[c][0], j = cells[c][1];
        shape_quad(s, v[0][i][j], v[0][i][j + 1], v[0][i + 1][j + 1], v[0][i + 1][j]);
        shape_quad(s, v[1][i][j], v[1][i + 1][j], v[1][i + 1][j + 1], v[1][i][j + 1]);
    }
    /* the boundary, counter-clockwise seen from +z */
    static const int loop[12][2] = {{0, 0}, {1, 0}, {2, 0}, {2, 1}, {1, 1}, {1, 2},
                                    {2, 2}, {2, 3}, {1, 3}, {0, 3}, {0, 2}, {0, 1}};
    for (int e = 0; e < 12; e++) {
        const int *a = loop[e], *b = loop[(e + 1) % 12];
        shape_quad(s, v[0][a[0]][a[1]], v[0][b[0]][b[1]], v[1][b[0]][b[1]], v[1][a[0]][a[1]]);
    }
}

/* Takes away the triangles i with keep(i) false (holes). */
static inline void shape_remove(shape *s, bool (*keep)(uint32_t i, void *ctx), void *ctx)
{
    uint32_t n = 0;
    for (uint32_t i = 0; i < s->m.n_triangles; i++)
        if (keep(i, ctx)) memmove(s->m.triangles[n++], s->m.triangles[i], sizeof *s->m.triangles);
    s->m.n_triangles = n;
}

/* An icosphere (level 3, radius 0.7, a little off the origin) with every
 * seventh triangle taken away: open, so that a repair has work (caps to
 * build, parities that disagree). */
static inline bool shape_not_every_seventh(uint32_t i, void *ctx)
{
    (void)ctx;
    return i % 7 != 3;
}

static inline const mesh *shape_holed_sphere(shape *s)
{
    shape_init(s);
    shape_icosphere(s, (const double[3]){0.05, -0.1, 0.02}, 0.7, 3, false);
    shape_remove(s, shape_not_every_seventh, NULL);
    return shape_finish(s);
}

/* Triangle t of positions v is degenerate by its definition in mesh.h: two
 * equal indices, or the edges' cross product (in double) exactly zero. */
static inline int shape_degenerate(float (*v)[3], const uint32_t t[3])
{
    if (t[0] == t[1] || t[1] == t[2] || t[0] == t[2]) return 1;
    const float *a = v[t[0]], *b = v[t[1]], *c = v[t[2]];
    double u[3], w[3];
    for (int k = 0; k < 3; k++) u[k] = (double)b[k] - a[k], w[k] = (double)c[k] - a[k];
    return u[1] * w[2] - u[2] * w[1] == 0 && u[2] * w[0] - u[0] * w[2] == 0 &&
           u[0] * w[1] - u[1] * w[0] == 0;
}

/* The signed volume the triangles enclose (divergence theorem). */
static inline double shape_volume(const mesh *m)
{
    double v = 0;
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        const float *a = m->vertices[m->triangles[t][0]], *b = m->vertices[m->triangles[t][1]],
                    *c = m->vertices[m->triangles[t][2]];
        v += (double)a[0] * ((double)b[1] * c[2] - (double)b[2] * c[1]) -
             (double)a[1] * ((double)b[0] * c[2] - (double)b[2] * c[0]) +
             (double)a[2] * ((double)b[0] * c[1] - (double)b[1] * c[0]);
    }
    return v / 6;
}

#endif
