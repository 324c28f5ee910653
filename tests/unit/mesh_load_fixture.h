/* mesh_load_fixture — the small meshes of the loaders' suites (test_mesh_load.c,
 * test_mesh_topo.c): a cube of quads, a tetrahedron, an octahedron, a hexagonal
 * prism of hexagons and quads, written in every format and variant, and loads
 * that must be refused. */
#ifndef VOXD_TEST_MESH_LOAD_FIXTURE_H
#define VOXD_TEST_MESH_LOAD_FIXTURE_H

#include <criterion/criterion.h>
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "mesh.h"
#include "mesh_load.h"

/* ------------------------------------------------------------ the models */

typedef struct {
    const char *name;
    int nv, nf;
    float v[16][3];
    int fn[16];     /* vertices of face i */
    int f[16][8];   /* counter-clockwise seen from outside */
    double volume;
} model;

static const model cube = {
    "cube", 8, 6,
    {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1},
     {-1, -1, 1}, {1, -1, 1}, {1, 1, 1}, {-1, 1, 1}},
    {4, 4, 4, 4, 4, 4},
    {{0, 3, 2, 1}, {4, 5, 6, 7}, {0, 1, 5, 4}, {2, 3, 7, 6}, {1, 2, 6, 5}, {0, 4, 7, 3}},
    8.0,
};

/* Coordinates that need correct rounding: 0.1 and 1/3 are not floats. */
static const model tetra = {
    "tetrahedron", 4, 4,
    {{0.1f, 0.2f, 0.3f}, {1.5f, 0.2f, 0.3f}, {0.1f, 1.7f, 0.3f}, {0.1f, 0.2f, 2.3333333f}},
    {3, 3, 3, 3},
    {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}},
    0, /* not checked */
};

static const model octa = {
    "octahedron", 6, 8,
    {{1e-3f, 0, 0}, {-1e-3f, 0, 0}, {0, 2.5e-3f, 0}, {0, -2.5e-3f, 0}, {0, 0, 3e5f}, {0, 0, -3e5f}},
    {3, 3, 3, 3, 3, 3, 3, 3},
    {{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4}, {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}},
    0,
};

static const model hexprism = {
    "hexagonal prism", 12, 8,
    {{1, 0, 0}, {0.5f, 0.866025404f, 0}, {-0.5f, 0.866025404f, 0}, {-1, 0, 0},
     {-0.5f, -0.866025404f, 0}, {0.5f, -0.866025404f, 0},
     {1, 0, 1}, {0.5f, 0.866025404f, 1}, {-0.5f, 0.866025404f, 1}, {-1, 0, 1},
     {-0.5f, -0.866025404f, 1}, {0.5f, -0.866025404f, 1}},
    {6, 6, 4, 4, 4, 4, 4, 4},
    {{5, 4, 3, 2, 1, 0}, {6, 7, 8, 9, 10, 11},
     {0, 1, 7, 6}, {1, 2, 8, 7}, {2, 3, 9, 8}, {3, 4, 10, 9}, {4, 5, 11, 10}, {5, 0, 6, 11}},
    0,
};

static const model *const models[] = {&cube, &tetra, &octa, &hexprism};

static inline int model_tris(const model *md)
{
    int n = 0;
    for (int i = 0; i < md->nf; i++) n += md->fn[i] - 2;
    return n;
}

/* Triangle t of the model's fan triangulation. */
static inline void model_tri(const model *md, int t, int out[3])
{
    for (int i = 0; i < md->nf; i++) {
        if (t < md->fn[i] - 2) {
            out[0] = md->f[i][0], out[1] = md->f[i][t + 1], out[2] = md->f[i][t + 2];
            return;
        }
        t -= md->fn[i] - 2;
    }
    cr_assert_fail("no triangle %d", t);
}

/* ------------------------------------------------------------ the writers */

typedef enum {
    OBJ_PLAIN, OBJ_FORMS, STL_ASCII, STL_BINARY, PLY_ASCII, PLY_LE, PLY_BE, OFF_PLAIN,
    OFF_INLINE, N_VARIANTS
} variant;

typedef struct {
    char *buf;
    size_t len;
    FILE *f;
} sink;

static inline void sink_open(sink *s)
{
    s->buf = NULL;
    s->len = 0;
    s->f = open_memstream(&s->buf, &s->len);
    cr_assert(s->f);
}

static inline void sink_close(sink *s) { cr_assert_eq(fclose(s->f), 0); }

static inline void put(sink *s, const void *p, size_t n) { fwrite(p, 1, n, s->f); }

static inline void put_uint(sink *s, uint64_t v, int size, int be)
{
    unsigned char b[8];
    for (int i = 0; i < size; i++) b[be ? size - 1 - i : i] = (unsigned char)(v >> (8 * i));
    put(s, b, (size_t)size);
}

static inline void put_f32(sink *s, float x, int be)
{
    uint32_t u;
    memcpy(&u, &x, 4);
    put_uint(s, u, 4, be);
}

static inline void put_f64(sink *s, double x, int be)
{
    uint64_t u;
    memcpy(&u, &x, 8);
    put_uint(s, u, 8, be);
}

static inline void write_obj(sink *s, const model *md, int forms)
{
    const char *nl = forms ? "\r\n" : "\n";
    fprintf(s->f, "# %s%smtllib x.mtl%so %s%s", md->name, nl, nl, md->name, nl);
    for (int i = 0; i < md->nv; i++) {
        if (forms && i == 1) fprintf(s->f, "vt 0.5 0.5%svn 0 0 1%s", nl, nl);
        if (forms && i == 2) fprintf(s->f, "v \\%s  %.9g %.9g %.9g 1.0%s", nl, md->v[i][0],
                                     md->v[i][1], md->v[i][2], nl); /* continued, with w */
        else fprintf(s->f, "v %.9g %.9g %.9g%s", md->v[i][0], md->v[i][1], md->v[i][2], nl);
    }
    fprintf(s->f, "g all%susemtl m%ss 1%s", nl, nl, nl);
    for (int i = 0; i < md->nf; i++) {
        fputs("f", s->f);
        for (int k = 0; k < md->fn[i]; k++) {
            int v = md->f[i][k];
            if (!forms) fprintf(s->f, " %d", v + 1);
            else if (k % 3 == 0) fprintf(s->f, "  %d/1/1", v - md->nv); /* negative: from the end */
            else if (k % 3 == 1) fprintf(s->f, "\t%d//1", v + 1);
            else fprintf(s->f, " %d/1", v - md->nv);
        }
        if (forms && i == 1) fputs(" # a comment", s->f);
        fputs(nl, s->f);
    }
    if (forms) fprintf(s->f, "l 1 2%s", nl);
}

static inline void write_stl(sink *s, const model *md, int binary)
{
    int nt = model_tris(md);
    if (binary) {
        /* a header that begins with "solid", as many writers make it */
        char head[80] = "solid but binary";
        put(s, head, 80);
        put_uint(s, (uint32_t)nt, 4, 0);
    } else {
        fprintf(s->f, "solid %s\n", md->name);
    }
    for (int t = 0; t < nt; t++) {
        int tri[3];
        model_tri(md, t, tri);
        if (binary) {
            for (int k = 0; k < 3; k++) put_f32(s, 0, 0);
            for (int v = 0; v < 3; v++)
                for (int k = 0; k < 3; k++) put_f32(s, md->v[tri[v]][k], 0);
            put_uint(s, 0x1234, 2, 0);
            continue;
        }
        fprintf(s->f, "  facet normal 0 0 %s\n    outer loop\n", t % 2 ? "1" : "-1e+00");
        for (int v = 0; v < 3; v++)
            fprintf(s->f, "      %s %.9g %.9g %.9g\n", t == 1 ? "VERTEX" : "vertex",
                    md->v[tri[v]][0], md->v[tri[v]][1], md->v[tri[v]][2]);
        fputs("    endloop\n  endfacet\n", s->f);
    }
    if (!binary) fprintf(s->f, "endsolid %s\n", md->name);
}

/* PLY with extra properties of every type in both elements, x as double,
 * and an extra element between the vertices and the faces. */
static inline void write_ply(sink *s, const model *md, int ascii, int be)
{
    fprintf(s->f,
            "ply\nformat %s 1.0\ncomment %s\nobj_info test\n"
            "element vertex %d\nproperty uchar red\nproperty double x\nproperty float32 y\n"
            "property list uchar float uv\nproperty float z\nproperty short flags\n"
            "element edge 2\nproperty int vertex1\nproperty uint vertex2\n"
            "property list ushort char junk\nproperty int8 tag\n"
            "element face %d\nproperty uchar intensity\n"
            "property list %s vertex_%s\nproperty ushort id\nend_header\n",
            ascii ? "ascii" : be ? "binary_big_endian" : "binary_little_endian", md->name,
            md->nv, md->nf, be ? "uint8 uint32" : "uchar int", be ? "index" : "indices");
    for (int i = 0; i < md->nv; i++) {
        if (ascii) {
            fprintf(s->f, "%d %.17g %.9g 2 0.25 0.75 %.9g -%d\n", i, (double)md->v[i][0],
                    md->v[i][1], md->v[i][2], i);
            continue;
        }
        put_uint(s, (uint64_t)i, 1, be);
        put_f64(s, md->v[i][0], be);
        put_f32(s, md->v[i][1], be);
        put_uint(s, 2, 1, be);
        put_f32(s, 0.25f, be);
        put_f32(s, 0.75f, be);
        put_f32(s, md->v[i][2], be);
        put_uint(s, (uint64_t)(uint16_t)-i, 2, be);
    }
    for (int i = 0; i < 2; i++) {
        if (ascii) {
            fprintf(s->f, "%d %d 3 -1 2 -3 %d\n", i, i + 1, -i);
            continue;
        }
        put_uint(s, (uint64_t)i, 4, be);
        put_uint(s, (uint64_t)i + 1, 4, be);
        put_uint(s, 3, 2, be);
        for (int k = 0; k < 3; k++) put_uint(s, (uint8_t)(k - 1), 1, be);
        put_uint(s, (uint8_t)-i, 1, be);
    }
    for (int i = 0; i < md->nf; i++) {
        if (ascii) {
            fprintf(s->f, "%d %d", 200 + i, md->fn[i]);
            for (int k = 0; k < md->fn[i]; k++) fprintf(s->f, " %d", md->f[i][k]);
            fprintf(s->f, " %d\n", 1000 + i);
            continue;
        }
        put_uint(s, (uint64_t)200 + i, 1, be);
        put_uint(s, (uint64_t)md->fn[i], 1, be);
        for (int k = 0; k < md->fn[i]; k++) put_uint(s, (uint64_t)md->f[i][k], 4, be);
        put_uint(s, (uint64_t)1000 + i, 2, be);
    }
}

static inline void write_off(sink *s, const model *md, int inline_counts)
{
    if (inline_counts) fprintf(s->f, "# %s\n\nCOFF %d %d %d # counts\n", md->name, md->nv, md->nf, 0);
    else fprintf(s->f, "OFF\n%d %d\n", md->nv, md->nf);
    for (int i = 0; i < md->nv; i++) {
        fprintf(s->f, "%.9g %.9g %.9g", md->v[i][0], md->v[i][1], md->v[i][2]);
        fputs(inline_counts ? " 255 0 0 255\n" : "\n", s->f);
        if (inline_counts && i == 0) fputs("# a comment line\n\n", s->f);
    }
    for (int i = 0; i < md->nf; i++) {
        fprintf(s->f, "%d", md->fn[i]);
        for (int k = 0; k < md->fn[i]; k++) fprintf(s->f, " %d", md->f[i][k]);
        fputs(inline_counts ? " 0.5 0.5 0.5\n" : "\n", s->f);
    }
}

static inline void write_variant(sink *s, const model *md, variant v)
{
    sink_open(s);
    switch (v) {
    case OBJ_PLAIN: write_obj(s, md, 0); break;
    case OBJ_FORMS: write_obj(s, md, 1); break;
    case STL_ASCII: write_stl(s, md, 0); break;
    case STL_BINARY: write_stl(s, md, 1); break;
    case PLY_ASCII: write_ply(s, md, 1, 0); break;
    case PLY_LE: write_ply(s, md, 0, 0); break;
    case PLY_BE: write_ply(s, md, 0, 1); break;
    case OFF_PLAIN: write_off(s, md, 0); break;
    case OFF_INLINE: write_off(s, md, 1); break;
    default: cr_assert_fail("variant %d", v);
    }
    sink_close(s);
}

/* ------------------------------------------------------------ the checks */

static inline int parse_text(const char *text, mesh_format f, mesh *m, mesh_error *e)
{
    return mesh_parse(text, strlen(text), f, NULL, m, e);
}

/* ------------------------------------------------------------ malformed */

/* text in format f fails with rc, a message holding want, at line `line`
 * (0: not checked). */
static inline void refuse(const char *text, mesh_format f, int rc, const char *want, uint64_t line)
{
    mesh m;
    mesh_error e;
    int got = parse_text(text, f, &m, &e);
    cr_assert_eq(got, rc, "got %d (%s) for:\n%s", got, e.msg, text);
    cr_assert_eq(e.code, rc, "code %d, returned %d: %s", e.code, rc, e.msg);
    cr_assert(strstr(e.msg, want), "message '%s' lacks '%s'", e.msg, want);
    if (line) cr_assert_eq(e.line, line, "line %llu, want %llu: %s", (unsigned long long)e.line,
                           (unsigned long long)line, e.msg);
    cr_assert_null(m.vertices);
    cr_assert_null(m.triangles);
    char buf[300];
    cr_assert(strstr(mesh_error_str(&e, buf, sizeof buf), e.msg));
}

#endif
