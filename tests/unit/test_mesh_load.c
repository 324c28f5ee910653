/* The mesh loaders (mesh.h) and mesh_topology.
 *
 * Small meshes (a cube of quads, a tetrahedron, an octahedron, a hexagonal
 * prism of hexagons and quads) are written here in every format and
 * variant (OBJ with quads, negative indices and the v/vt/vn forms, CRLF
 * line ends and continuations; STL ascii and binary; PLY ascii and binary
 * little and big endian, with extra properties of every type and an extra
 * element; OFF with its counts on the keyword's line or their own) and
 * must load to the same triangles, the fan triangulation of the faces,
 * bit for bit (STL after welding).  Malformed files of each format must
 * fail with -EINVAL (or -E2BIG past a limit) and say where.  The float
 * parser is held against strtof, near the halfway points between floats
 * too.  Topology: a closed cube, one with a triangle removed or flipped,
 * a non-manifold fan, two components, and the signed volume. */
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

static int model_tris(const model *md)
{
    int n = 0;
    for (int i = 0; i < md->nf; i++) n += md->fn[i] - 2;
    return n;
}

/* Triangle t of the model's fan triangulation. */
static void model_tri(const model *md, int t, int out[3])
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

static const char *const variant_name[] = {
    "OBJ", "OBJ (negative indices, v/vt/vn, CRLF)", "STL ascii", "STL binary", "PLY ascii",
    "PLY binary LE", "PLY binary BE", "OFF", "OFF (counts inline, comments)"};
static const mesh_format variant_format[] = {
    MESH_FORMAT_OBJ, MESH_FORMAT_OBJ, MESH_FORMAT_STL, MESH_FORMAT_STL, MESH_FORMAT_PLY,
    MESH_FORMAT_PLY, MESH_FORMAT_PLY, MESH_FORMAT_OFF, MESH_FORMAT_OFF};

typedef struct {
    char *buf;
    size_t len;
    FILE *f;
} sink;

static void sink_open(sink *s)
{
    s->buf = NULL;
    s->len = 0;
    s->f = open_memstream(&s->buf, &s->len);
    cr_assert(s->f);
}

static void sink_close(sink *s) { cr_assert_eq(fclose(s->f), 0); }

static void put(sink *s, const void *p, size_t n) { fwrite(p, 1, n, s->f); }

static void put_uint(sink *s, uint64_t v, int size, int be)
{
    unsigned char b[8];
    for (int i = 0; i < size; i++) b[be ? size - 1 - i : i] = (unsigned char)(v >> (8 * i));
    put(s, b, (size_t)size);
}

static void put_f32(sink *s, float x, int be)
{
    uint32_t u;
    memcpy(&u, &x, 4);
    put_uint(s, u, 4, be);
}

static void put_f64(sink *s, double x, int be)
{
    uint64_t u;
    memcpy(&u, &x, 8);
    put_uint(s, u, 8, be);
}

static void write_obj(sink *s, const model *md, int forms)
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

static void write_stl(sink *s, const model *md, int binary)
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
static void write_ply(sink *s, const model *md, int ascii, int be)
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

static void write_off(sink *s, const model *md, int inline_counts)
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

static void write_variant(sink *s, const model *md, variant v)
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

static int parse_text(const char *text, mesh_format f, mesh *m, mesh_error *e)
{
    return mesh_parse(text, strlen(text), f, NULL, m, e);
}

/* m holds md's fan triangles, in order, with the same positions bit for
 * bit; and md's vertices in order, unless welded (STL: first use order). */
static void check_model(const mesh *m, const model *md, const char *what, int welded)
{
    int nt = model_tris(md);
    cr_assert_eq(m->n_triangles, (uint32_t)nt, "%s %s: %u triangles, want %d", what, md->name,
                 m->n_triangles, nt);
    cr_assert_eq(m->n_vertices, (uint32_t)md->nv, "%s %s: %u vertices", what, md->name,
                 m->n_vertices);
    cr_assert_eq(m->n_degenerate, 0);
    float lo[3] = {FLT_MAX, FLT_MAX, FLT_MAX}, hi[3] = {-FLT_MAX, -FLT_MAX, -FLT_MAX};
    for (int t = 0; t < nt; t++) {
        int tri[3];
        model_tri(md, t, tri);
        for (int k = 0; k < 3; k++) {
            uint32_t vi = m->triangles[t][k];
            cr_assert_lt(vi, m->n_vertices);
            if (!welded) cr_assert_eq(vi, (uint32_t)tri[k], "%s %s: triangle %d", what, md->name, t);
            cr_assert(!memcmp(m->vertices[vi], md->v[tri[k]], sizeof(float[3])),
                      "%s %s: triangle %d vertex %d: %.9g %.9g %.9g", what, md->name, t, k,
                      m->vertices[vi][0], m->vertices[vi][1], m->vertices[vi][2]);
            for (int j = 0; j < 3; j++) {
                lo[j] = fminf(lo[j], md->v[tri[k]][j]);
                hi[j] = fmaxf(hi[j], md->v[tri[k]][j]);
            }
        }
    }
    cr_assert(!memcmp(m->lo, lo, sizeof lo) && !memcmp(m->hi, hi, sizeof hi), "%s %s: bbox",
              what, md->name);
}

Test(mesh_load, every_model_in_every_variant_gives_the_same_triangles)
{
    for (size_t i = 0; i < sizeof models / sizeof *models; i++)
        for (int v = 0; v < N_VARIANTS; v++) {
            sink s;
            write_variant(&s, models[i], (variant)v);
            for (int forced = 0; forced < 2; forced++) {
                mesh m;
                mesh_error e;
                mesh_format f = forced ? variant_format[v] : MESH_FORMAT_AUTO;
                int rc = mesh_parse(s.buf, s.len, f, NULL, &m, &e);
                cr_assert_eq(rc, 0, "%s %s: %d %s (line %llu byte %llu)", variant_name[v],
                             models[i]->name, rc, e.msg, (unsigned long long)e.line,
                             (unsigned long long)e.offset);
                cr_assert_eq(m.format, variant_format[v], "%s: told %s", variant_name[v],
                             mesh_format_name(m.format));
                check_model(&m, models[i], variant_name[v], variant_format[v] == MESH_FORMAT_STL);
                mesh_free(&m);
                cr_assert_null(m.vertices);
            }
            free(s.buf);
        }
}

Test(mesh_load, mesh_load_maps_a_file)
{
    char path[] = "/tmp/test_mesh_load_XXXXXX";
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    sink s;
    write_variant(&s, &hexprism, PLY_BE);
    cr_assert_eq(write(fd, s.buf, s.len), (ssize_t)s.len);
    close(fd);
    mesh m;
    mesh_error e;
    cr_assert_eq(mesh_load(path, MESH_FORMAT_AUTO, NULL, &m, &e), 0, "%s", e.msg);
    check_model(&m, &hexprism, "mesh_load", 0);
    mesh_free(&m);
    /* empty, missing, a directory */
    cr_assert_eq(truncate(path, 0), 0);
    cr_assert_eq(mesh_load(path, MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "empty"), "%s", e.msg);
    unlink(path);
    cr_assert_eq(mesh_load(path, MESH_FORMAT_AUTO, NULL, &m, &e), -ENOENT);
    cr_assert(strstr(e.msg, "cannot open"), "%s", e.msg);
    cr_assert_eq(mesh_load("/tmp", MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL);
    cr_assert_null(m.vertices);
    free(s.buf);
}

Test(mesh_load, limits_give_e2big)
{
    for (int v = 0; v < N_VARIANTS; v++) {
        sink s;
        write_variant(&s, &cube, (variant)v);
        mesh m;
        mesh_error e;
        mesh_limits tri = {11, 0}, vert = {0, 7}, exact = {12, 8};
        cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_AUTO, &tri, &m, &e), -E2BIG,
                     "%s: %s", variant_name[v], e.msg);
        cr_assert(strstr(e.msg, "limit"), "%s", e.msg);
        cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_AUTO, &vert, &m, &e), -E2BIG,
                     "%s: %s", variant_name[v], e.msg);
        /* at the limits exactly: loads (STL's 36 raw positions weld to 8) */
        cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_AUTO, &exact, &m, &e), 0,
                     "%s: %s", variant_name[v], e.msg);
        mesh_free(&m);
        free(s.buf);
    }
}

Test(mesh_load, formats_are_told_by_contents)
{
    cr_assert_str_eq(mesh_format_name(MESH_FORMAT_OBJ), "OBJ");
    cr_assert_str_eq(mesh_format_name(MESH_FORMAT_STL), "STL");
    cr_assert_str_eq(mesh_format_name(MESH_FORMAT_PLY), "PLY");
    cr_assert_str_eq(mesh_format_name(MESH_FORMAT_OFF), "OFF");
    mesh m;
    mesh_error e;
    /* a text that is none of them */
    cr_assert_eq(parse_text("hello world\n", MESH_FORMAT_AUTO, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "known format"), "%s", e.msg);
    /* 4OFF is four-dimensional: not OFF */
    cr_assert_eq(parse_text("4OFF\n1 0 0\n", MESH_FORMAT_AUTO, &m, &e), -EINVAL);
    /* an ascii STL whose size happens to be 84 + 50 n would be binary; a
     * binary one whose header says "solid" is binary (the cube above) */
    sink s;
    write_variant(&s, &tetra, STL_BINARY);
    cr_assert_eq(memcmp(s.buf, "solid", 5), 0);
    cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_AUTO, NULL, &m, &e), 0, "%s", e.msg);
    mesh_free(&m);
    free(s.buf);
}

/* ------------------------------------------------------------ malformed */

/* text in format f fails with rc, a message holding want, at line `line`
 * (0: not checked). */
static void refuse(const char *text, mesh_format f, int rc, const char *want, uint64_t line)
{
    mesh m;
    mesh_error e;
    int got = parse_text(text, f, &m, &e);
    cr_assert_eq(got, rc, "got %d (%s) for:\n%s", got, e.msg, text);
    cr_assert(strstr(e.msg, want), "message '%s' lacks '%s'", e.msg, want);
    if (line) cr_assert_eq(e.line, line, "line %llu, want %llu: %s", (unsigned long long)e.line,
                           (unsigned long long)line, e.msg);
    cr_assert_null(m.vertices);
    cr_assert_null(m.triangles);
    char buf[300];
    cr_assert(strstr(mesh_error_str(&e, buf, sizeof buf), e.msg));
}

Test(mesh_load, empty_files)
{
    mesh m;
    mesh_error e;
    cr_assert_eq(mesh_parse("", 0, MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "empty"));
    refuse("# nothing\n", MESH_FORMAT_OBJ, -EINVAL, "no triangles", 0);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\n", MESH_FORMAT_AUTO, -EINVAL, "no triangles", 0);
    refuse("solid x\nendsolid x\n", MESH_FORMAT_AUTO, -EINVAL, "no triangles", 0);
    refuse("OFF\n0 0 0\n", MESH_FORMAT_AUTO, -EINVAL, "no triangles", 0);
    refuse("ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\n"
           "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n",
           MESH_FORMAT_AUTO, -EINVAL, "no triangles", 0);
}

Test(mesh_load, obj_errors)
{
    const mesh_format F = MESH_FORMAT_OBJ;
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", F, -EINVAL, "out of range", 4);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", F, -EINVAL, "out of range", 4);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n", F, -EINVAL, "out of range", 4);
    /* a vertex defined after the face that uses it */
    refuse("v 0 0 0\nv 1 0 0\nf 1 2 3\nv 0 1 0\n", F, -EINVAL, "out of range", 3);
    refuse("v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n", F, -EINVAL, "finite", 2);
    refuse("v 0 0 0\nv 1 0 inf\nv 0 1 0\nf 1 2 3\n", F, -EINVAL, "finite", 2);
    refuse("v 0 0 0\nv 1e39 0 0\nv 0 1 0\nf 1 2 3\n", F, -EINVAL, "finite", 2);
    refuse("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", F, -EINVAL, "not a number", 2);
    refuse("v 0 0 0\nv 1 0x 0\nv 0 1 0\nf 1 2 3\n", F, -EINVAL, "not a number", 2);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", F, -EINVAL, "at least 3", 4);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", F, -EINVAL, "not a vertex index", 4);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3/1/1/1\n", F, -EINVAL, "not a vertex", 4);
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n", F, -EINVAL,
           "not a vertex index", 4);
    /* truncated in the middle of a number: the last one is still read whole */
    refuse("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 ", F, -EINVAL, "at least 3", 4);
}

Test(mesh_load, stl_errors)
{
    const mesh_format F = MESH_FORMAT_STL;
    const char *facet = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
                        "vertex 0 1 0\nendloop\nendfacet\n";
    char buf[512];
    snprintf(buf, sizeof buf, "%s", facet);
    refuse(buf, F, -EINVAL, "'facet' or 'endsolid'", 0); /* no endsolid */
    snprintf(buf, sizeof buf, "%.*s", (int)(strstr(facet, "vertex 0 1") - facet), facet);
    refuse(buf, F, -EINVAL, "at least 3", 0); /* truncated in the loop */
    refuse("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 nan 0\n"
           "vertex 0 1 0\nendloop\nendfacet\nendsolid\n", F, -EINVAL, "finite", 5);
    refuse("solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
           "vertex 0 1 0\nendloop\nendfacet\nendsolid\nfoo\n", F, -EINVAL, "'solid'", 10);
    refuse("solid t\nfacet normal 0 0 1\nloop\n", F, -EINVAL, "'outer'", 3);

    /* binary: the size must be 84 + 50 n */
    sink s;
    write_variant(&s, &tetra, STL_BINARY);
    mesh m;
    mesh_error e;
    cr_assert_eq(mesh_parse(s.buf, s.len - 1, F, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "binary STL of 4 triangles must be 284 bytes"), "%s", e.msg);
    cr_assert_eq(mesh_parse(s.buf, s.len - 1, MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL);
    /* a count that lies */
    s.buf[80] = 5;
    cr_assert_eq(mesh_parse(s.buf, s.len, F, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "5 triangles must be 334 bytes"), "%s", e.msg);
    s.buf[80] = 4;
    /* NaN in the second triangle's first vertex: said by its byte offset */
    float nan = NAN;
    memcpy(s.buf + 84 + 50 + 12, &nan, 4);
    cr_assert_eq(mesh_parse(s.buf, s.len, F, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "finite"), "%s", e.msg);
    cr_assert_eq(e.offset, 84 + 50 + 12);
    cr_assert_eq(e.line, 0);
    /* too short for a header, and not "solid" */
    memcpy(s.buf, "xxxx", 4);
    cr_assert_eq(mesh_parse(s.buf, 50, F, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "84"), "%s", e.msg);
    free(s.buf);
}

static const char ply_head[] =
    "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";

Test(mesh_load, ply_errors)
{
    const mesh_format F = MESH_FORMAT_PLY;
    char buf[1024];
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n", ply_head);
    refuse(buf, F, -EINVAL, "out of range", 13);
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n", ply_head);
    refuse(buf, F, -EINVAL, "out of range", 13);
    snprintf(buf, sizeof buf, "%s0 0 0\n1 NaN 0\n0 1 0\n3 0 1 2\n", ply_head);
    refuse(buf, F, -EINVAL, "finite", 11);
    snprintf(buf, sizeof buf, "%s0.0 0.0 0.0\n1.0 0.0 0.0\n0.0 1.0 0.0\n2 0 1\n", ply_head);
    refuse(buf, F, -EINVAL, "fewer than 3", 13);
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n", ply_head); /* no face: too short */
    refuse(buf, F, -EINVAL, "need at least", 7);
    snprintf(buf, sizeof buf, "%s0.0 0.0 0.0\n1.0 0.0 0.0\n0.0 1.0 0.0\n3 0 1", ply_head);
    refuse(buf, F, -EINVAL, "a vertex index expected, found the end of the file", 13);
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 2\n", ply_head); /* extra */
    refuse(buf, F, -EINVAL, "after the last element", 14);
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n3 0 1 2", ply_head); /* no last newline */
    mesh m;
    mesh_error e;
    cr_assert_eq(parse_text(buf, F, &m, &e), 0, "%s", e.msg);
    mesh_free(&m);

    refuse("ply\nformat ascii 1.0\nelement vertex 3\nproperty float128 x\nend_header\n", F,
           -EINVAL, "unknown property type 'float128'", 4);
    refuse("ply\nformat ascii 1.0\nelement face 1\nproperty list float int vertex_indices\n"
           "end_header\n", F, -EINVAL, "integer type", 4);
    refuse("ply\nformat ascii 1.0\nelement face 1\nproperty list uchar double vertex_indices\n"
           "end_header\n", F, -EINVAL, "integer type", 4);
    refuse("ply\nformat binary_middle_endian 1.0\n", F, -EINVAL, "unknown format", 2);
    refuse("ply\nformat ascii 2.0\n", F, -EINVAL, "version", 2);
    refuse("ply\nelement vertex 3\n", F, -EINVAL, "no format line", 2);
    refuse("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n", F, -EINVAL,
           "no end_header", 0);
    refuse("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
           "end_header\n0 0\n", F, -EINVAL, "lacks x, y or z", 3);
    refuse("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
           "property float z\nend_header\n0 0 0\n", F, -EINVAL, "no face element", 0);
    refuse("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
           "property float z\nproperty float x\nend_header\n0 0 0\n", F, -EINVAL, "twice", 7);
    refuse("ply\nformat ascii 1.0\nelement vertex -1\n", F, -EINVAL, "not a whole number", 3);
    /* an unknown line hides no error: the elements are what their lines say */
    refuse("ply\nformat ascii 1.0\nelements vertex 3\nproperty float x\nend_header\n", F,
           -EINVAL, "a property before any element", 4);
    refuse("ply\nformat ascii 1.0\nelements vertex 3\nend_header\n", F, -EINVAL,
           "no vertex element", 0);
    refuse("ply\nfoo bar\nend_header\n", F, -EINVAL, "no format line", 3);
}

/* Blender 2.47 wrote its "Created by" line without "comment": skipped with
 * one warning line naming the first such line, the mesh as without it. */
Test(mesh_load, ply_unknown_header_lines_are_skipped_with_a_warning)
{
    char plain[1024], blender[1200], two[1300];
    const char *body = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    snprintf(plain, sizeof plain, "%s%s", ply_head, body);
    snprintf(blender, sizeof blender,
             "ply\nformat ascii 1.0\nCreated by Blender3D 247 - www.blender.org, source file: "
             "'x.blend'\n%s%s", ply_head + strlen("ply\nformat ascii 1.0\n"), body);
    snprintf(two, sizeof two, "ply\nformat ascii 1.0\nCreated by Blender\n%s", blender + 4);
    mesh a, b, c;
    mesh_error e;
    cr_assert_eq(parse_text(plain, MESH_FORMAT_AUTO, &a, &e), 0, "%s", e.msg);
    cr_assert_str_empty(a.warning);
    cr_assert_eq(parse_text(blender, MESH_FORMAT_AUTO, &b, &e), 0, "%s", e.msg);
    cr_assert(strstr(b.warning, "line 3: ") == b.warning, "%s", b.warning);
    cr_assert(strstr(b.warning, "'Created'"), "%s", b.warning);
    cr_assert_null(strstr(b.warning, "more"), "%s", b.warning);
    cr_assert_eq(b.n_triangles, a.n_triangles);
    cr_assert_eq(memcmp(b.vertices, a.vertices, sizeof *a.vertices * a.n_vertices), 0);
    cr_assert_eq(memcmp(b.triangles, a.triangles, sizeof *a.triangles * a.n_triangles), 0);
    /* "ply", "format", then two unknown lines, then "format" again */
    cr_assert_eq(parse_text(two, MESH_FORMAT_AUTO, &c, &e), -EINVAL);
    cr_assert(strstr(e.msg, "a second format line"), "%s", e.msg);
    snprintf(two, sizeof two, "ply\nformat ascii 1.0\nCreated by Blender\n%s",
             blender + strlen("ply\nformat ascii 1.0\n"));
    cr_assert_eq(parse_text(two, MESH_FORMAT_AUTO, &c, &e), 0, "%s", e.msg);
    cr_assert(strstr(c.warning, "line 3: ") == c.warning, "%s", c.warning);
    cr_assert(strstr(c.warning, "(and 1 more unknown header lines)"), "%s", c.warning);
    mesh_free(&a);
    mesh_free(&b);
    mesh_free(&c);
}

/* Counts that cannot be true fail before anything is allocated: with the
 * limits at their largest, a header claiming 2^31 faces (or vertices)
 * would ask for tens of GiB, which the sanitizer's allocator refuses with
 * a crash. */
Test(mesh_load, ply_counts_are_checked_against_the_bytes_first)
{
    const mesh_limits big = {UINT32_MAX, UINT32_MAX};
    const char *heads[] = {
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 2147483648\nproperty list uchar int vertex_indices\n"
        "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
        "ply\nformat binary_little_endian 1.0\nelement vertex 2147483648\nproperty float x\n"
        "property float y\nproperty float z\nelement face 1\n"
        "property list uchar int vertex_indices\nend_header\n0123456789abcdef",
        "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty float x\n"
        "property float y\nproperty float z\nelement face 1\n"
        "property list uchar int vertex_indices\nelement junk 18446744073709551615\n"
        "property uchar j\nend_header\n0123456789abcdef",
    };
    for (size_t i = 0; i < sizeof heads / sizeof *heads; i++) {
        mesh m;
        mesh_error e;
        cr_assert_eq(mesh_parse(heads[i], strlen(heads[i]), MESH_FORMAT_AUTO, &big, &m, &e),
                     -EINVAL, "%zu: %s", i, e.msg);
        cr_assert(strstr(e.msg, "need at least"), "%s", e.msg);
    }
    /* with the default limits too (-EINVAL: the file lies, before -E2BIG) */
    refuse(heads[0], MESH_FORMAT_AUTO, -EINVAL, "2147483648 of them need at least", 7);
    /* a true count past the limit: -E2BIG */
    char buf[1024];
    snprintf(buf, sizeof buf, "%s0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", ply_head);
    mesh m;
    mesh_error e;
    mesh_limits two = {0, 2};
    cr_assert_eq(mesh_parse(buf, strlen(buf), MESH_FORMAT_PLY, &two, &m, &e), -E2BIG);
    cr_assert_eq(e.line, 3, "%s", e.msg);
}

Test(mesh_load, ply_binary_errors)
{
    sink s;
    write_variant(&s, &tetra, PLY_LE);
    mesh m;
    mesh_error e;
    /* truncated, one byte short */
    cr_assert_eq(mesh_parse(s.buf, s.len - 1, MESH_FORMAT_PLY, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "truncated in face 3 of 4"), "%s", e.msg);
    cr_assert_gt(e.offset, 0);
    /* a byte too many */
    char *more = malloc(s.len + 1);
    memcpy(more, s.buf, s.len);
    more[s.len] = 0;
    cr_assert_eq(mesh_parse(more, s.len + 1, MESH_FORMAT_PLY, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "1 bytes after the last element"), "%s", e.msg);
    cr_assert_eq(e.offset, s.len);
    free(more);
    /* the last face's last index out of range */
    s.buf[s.len - 3 - 3] = 9; /* LE int, then a ushort id: its low byte */
    cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_PLY, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "vertex index 9 out of range"), "%s", e.msg);
    cr_assert_eq(e.offset, s.len - 2 - 4);
    free(s.buf);

    /* a negative list count (char) in the extra element */
    const char *h = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                    "property float y\nproperty float z\nelement e 1\nproperty list char int l\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
    sink b;
    sink_open(&b);
    put(&b, h, strlen(h));
    for (int i = 0; i < 9; i++) put_f32(&b, (float)(i % 4 == 0), 0);
    put_uint(&b, 0xff, 1, 0);
    put_uint(&b, 3, 1, 0);
    for (int i = 0; i < 3; i++) put_uint(&b, (uint64_t)i, 4, 0);
    sink_close(&b);
    cr_assert_eq(mesh_parse(b.buf, b.len, MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "a list of -1 items"), "%s", e.msg);
    cr_assert_eq(e.offset, strlen(h) + 36);
    free(b.buf);
}

Test(mesh_load, off_errors)
{
    const mesh_format F = MESH_FORMAT_OFF;
    refuse("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n", F, -EINVAL, "out of range", 6);
    refuse("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 nan\n3 0 1 2\n", F, -EINVAL, "finite", 5);
    refuse("OFF\n3 2 0\n0.0 0.0 0.0\n1.0 0.0 0.0\n0.0 1.0 0.0\n3 0 1 2\n", F, -EINVAL,
           "vertex count expected, found the end of the file", 0);
    refuse("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 1 2\n", F, -EINVAL,
           "after the last face", 7);
    refuse("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n", F, -EINVAL, "at least 3", 6);
    refuse("OFF\n3 1 0\n0.0 0.0 0.0\n1.0 0.0\n0.0 1.0 0.0\n3 0 1 2\n", F, -EINVAL,
           "coordinate expected", 4);
    refuse("OFF BINARY\n", F, -EINVAL, "binary OFF", 1);
    refuse("OFF\nthree 1 0\n", F, -EINVAL, "counts", 2);
    refuse("OFF\n3 1 x\n", F, -EINVAL, "edge count", 2);
    /* counts that cannot fit in what follows */
    refuse("OFF\n3 2147483648 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", F, -EINVAL, "cannot fit", 2);
    refuse("OFF\n4294967296 1\n", F, -EINVAL, "cannot fit", 2);
}

/* ------------------------------------------------------------ degenerate */

Test(mesh_load, degenerate_triangles_are_dropped_and_counted)
{
    /* a repeated index, three collinear points, two equal positions, and a
     * quad with a repeated corner (its fan gives one good triangle) */
    const char *obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nv 0 1 0\n"
                      "f 1 2 3\nf 1 1 2\nf 1 2 4\nf 1 3 5\nf 1 2 2 3\n";
    mesh m;
    mesh_error e;
    cr_assert_eq(parse_text(obj, MESH_FORMAT_AUTO, &m, &e), 0, "%s", e.msg);
    cr_assert_eq(m.n_triangles, 2);
    cr_assert_eq(m.n_degenerate, 4);
    cr_assert_eq(m.triangles[1][0], 0);
    cr_assert_eq(m.triangles[1][1], 1);
    cr_assert_eq(m.triangles[1][2], 2);
    /* the box of the kept triangles only: vertex 4 (x = 2) is not in one */
    cr_assert_eq(m.hi[0], 1.0f);
    mesh_free(&m);
    refuse("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 1 1\n", MESH_FORMAT_OBJ, -EINVAL,
           "all 2 are degenerate", 0);
}

Test(mesh_load, stl_welds_equal_positions_and_the_two_zeros)
{
    /* two triangles sharing an edge, one writing it with -0 */
    const char *stl = "solid w\n"
                      "facet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
                      "endloop\nendfacet\n"
                      "facet normal 0 0 1\nouter loop\nvertex 1 0 0\nvertex 1 1 0\nvertex -0 1 -0\n"
                      "endloop\nendfacet\nendsolid w\n";
    mesh m;
    mesh_error e;
    cr_assert_eq(parse_text(stl, MESH_FORMAT_AUTO, &m, &e), 0, "%s", e.msg);
    cr_assert_eq(m.n_vertices, 4);
    cr_assert_eq(m.triangles[1][0], m.triangles[0][1]);
    cr_assert_eq(m.triangles[1][2], m.triangles[0][2]);
    mesh_topo t;
    cr_assert_eq(mesh_topology(&m, &t), 0);
    cr_assert_eq(t.edges, 5);
    cr_assert_eq(t.open, 4);
    cr_assert_eq(t.components, 1);
    mesh_free(&m);
}

/* A grid of n x n squares (two triangles each) in binary STL: more
 * distinct positions than the welding table starts with, so it grows. */
Test(mesh_load, stl_welds_a_large_grid)
{
    const int n = 60;
    sink s;
    sink_open(&s);
    char head[80] = "grid";
    put(&s, head, 80);
    put_uint(&s, (uint64_t)(2 * n * n), 4, 0);
    for (int y = 0; y < n; y++)
        for (int x = 0; x < n; x++) {
            float c[4][3] = {{x * 0.1f, y * 0.1f, 0}, {(x + 1) * 0.1f, y * 0.1f, 0},
                             {(x + 1) * 0.1f, (y + 1) * 0.1f, 0}, {x * 0.1f, (y + 1) * 0.1f, 0}};
            const int tri[2][3] = {{0, 1, 2}, {0, 2, 3}};
            for (int t = 0; t < 2; t++) {
                for (int k = 0; k < 3; k++) put_f32(&s, 0, 0);
                for (int v = 0; v < 3; v++)
                    for (int k = 0; k < 3; k++) put_f32(&s, c[tri[t][v]][k], 0);
                put_uint(&s, 0, 2, 0);
            }
        }
    sink_close(&s);
    mesh m;
    mesh_error e;
    cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_AUTO, NULL, &m, &e), 0, "%s", e.msg);
    cr_assert_eq(m.n_vertices, (uint32_t)((n + 1) * (n + 1)));
    cr_assert_eq(m.n_triangles, (uint32_t)(2 * n * n));
    /* each triangle's corners are still its positions */
    for (uint32_t i = 0; i < m.n_triangles; i++) {
        int x = (int)(i / 2) % n, y = (int)(i / 2) / n;
        const float *p = m.vertices[m.triangles[i][i % 2 ? 2 : 1]];
        /* corner 1 of the first triangle is (x+1, y), corner 2 of the second (x, y+1) */
        float want[3] = {(x + (i % 2 == 0)) * 0.1f, (y + (int)(i % 2)) * 0.1f, 0};
        cr_assert(!memcmp(p, want, sizeof want), "triangle %u", i);
        cr_assert(!memcmp(m.vertices[m.triangles[i][0]], (float[3]){x * 0.1f, y * 0.1f, 0},
                          sizeof want), "triangle %u", i);
    }
    mesh_topo t;
    cr_assert_eq(mesh_topology(&m, &t), 0);
    cr_assert_eq(t.open, (uint64_t)(4 * n));
    cr_assert_eq(t.edges, (uint64_t)(2 * n * (n + 1) + n * n));
    cr_assert_eq(t.nonmanifold + t.inconsistent, 0);
    cr_assert_eq(t.components, 1);
    mesh_free(&m);
    free(s.buf);
}

/* ------------------------------------------------------------ numbers */

static void same_as_strtof(const char *tok)
{
    mtext t = {tok, tok + strlen(tok), tok};
    float got = 0;
    char *end;
    float want = strtof(tok, &end);
    int rc = mt_float(&t, &got);
    if (*end || end == tok) {
        cr_assert_eq(rc, -EINVAL, "'%s': %d", tok, rc);
        cr_assert_eq(t.p, tok);
    } else if (!isfinite(want)) {
        cr_assert_eq(rc, -ERANGE, "'%s': %d", tok, rc);
    } else {
        cr_assert_eq(rc, 0, "'%s': %d", tok, rc);
        cr_assert(!memcmp(&got, &want, 4), "'%s': %.9g, strtof %.9g", tok, got, want);
        cr_assert_eq(t.p, tok + strlen(tok));
    }
}

static uint64_t rng = 0x853c49e6748fea9bull;
static uint32_t rnd(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return (uint32_t)(rng >> 16);
}

Test(mesh_load, the_float_parser_rounds_as_strtof)
{
    const char *fixed[] = {
        "0", "-0", "+1", "1.", ".5", "-.5e-3", "1e10", "1E+10", "3.4028235e38", "3.4028236e38",
        "1.1754944e-38", "1e-45", "1e-50", "7e-46", "0.000000000000000000000000000001", "123456789012345678901234567890",
        "1.00000005960464477539062", "1.0000000596046447753906250000001", "16777217", "16777219",
        "9007199254740993", "0.1", "0.2", "0.3", "2.3333333", "nan", "-inf", "infinity", "0x1p3",
        "1e", "1e+", "-", ".", "", "1..2", "1.2.3", "--1", "1e5x", "1,5", "1e99999999999",
        "-1e-99999999999", "00000000000000000000000000000001.5",
        "0.100000000000000000000000000000000000000000000000000000000000000000001",
    };
    for (size_t i = 0; i < sizeof fixed / sizeof *fixed; i++) same_as_strtof(fixed[i]);
    char tok[96];
    for (int i = 0; i < 200000; i++) {
        uint32_t bits = rnd() ^ (rnd() << 16);
        float f;
        memcpy(&f, &bits, 4);
        if (!isfinite(f)) continue;
        static const char *const fmt[] = {"%.9g", "%.6g", "%.3g", "%.12g", "%.17g", "%.8e", "%f"};
        snprintf(tok, sizeof tok, fmt[i % 7], (double)f);
        if (strlen(tok) < sizeof tok - 1) same_as_strtof(tok);
        /* near a point halfway between f and the next float */
        float g = nextafterf(f, INFINITY);
        double mid = ((double)f + g) / 2;
        snprintf(tok, sizeof tok, i % 2 ? "%.17g" : "%.16e", i % 3 ? mid : nextafter(mid, 0));
        same_as_strtof(tok);
        /* short decimals with exponents, as files write them */
        snprintf(tok, sizeof tok, "%s%u.%ue%d", i % 5 ? "" : "-", rnd() % 100000, rnd() % 10000,
                 (int)(rnd() % 90) - 45);
        same_as_strtof(tok);
    }
}

/* ------------------------------------------------------------ topology */

static void load_model(const model *md, mesh *m)
{
    sink s;
    write_variant(&s, md, OBJ_PLAIN);
    mesh_error e;
    cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_AUTO, NULL, m, &e), 0, "%s", e.msg);
    free(s.buf);
}

Test(mesh_topology, closed_meshes_are_watertight)
{
    for (size_t i = 0; i < sizeof models / sizeof *models; i++) {
        mesh m;
        load_model(models[i], &m);
        mesh_topo t;
        cr_assert_eq(mesh_topology(&m, &t), 0);
        cr_assert(t.watertight, "%s", models[i]->name);
        cr_assert_eq(t.open + t.nonmanifold + t.inconsistent, 0);
        cr_assert_eq(t.components, 1);
        /* Euler: V - E + F = 2 for a sphere */
        cr_assert_eq((int64_t)m.n_vertices - (int64_t)t.edges + m.n_triangles, 2, "%s",
                     models[i]->name);
        cr_assert_gt(t.volume, 0, "%s faces outwards", models[i]->name);
        if (models[i]->volume)
            cr_assert_float_eq(t.volume, models[i]->volume, 1e-12, "%s", models[i]->name);
        mesh_free(&m);
    }
}

Test(mesh_topology, the_prism_volume)
{
    mesh m;
    load_model(&hexprism, &m);
    mesh_topo t;
    cr_assert_eq(mesh_topology(&m, &t), 0);
    double want = 6 * 0.5 * 1 * (double)0.866025404f; /* six triangles of the hexagon, height 1 */
    cr_assert_float_eq(t.volume, want, 1e-6);
    mesh_free(&m);
}

Test(mesh_topology, a_removed_triangle_opens_three_edges)
{
    mesh m;
    load_model(&cube, &m);
    m.n_triangles--;
    mesh_topo t;
    cr_assert_eq(mesh_topology(&m, &t), 0);
    cr_assert_eq(t.open, 3);
    cr_assert_eq(t.edges, 18);
    cr_assert_eq(t.nonmanifold + t.inconsistent, 0);
    cr_assert(!t.watertight);
    m.n_triangles++;
    mesh_free(&m);
}

/* Triangle i the other way round. */
static void flip(mesh *m, uint32_t i)
{
    uint32_t x = m->triangles[i][1];
    m->triangles[i][1] = m->triangles[i][2];
    m->triangles[i][2] = x;
}

Test(mesh_topology, a_flipped_triangle_is_inconsistent)
{
    mesh m;
    load_model(&cube, &m);
    flip(&m, 5);
    mesh_topo t;
    cr_assert_eq(mesh_topology(&m, &t), 0);
    cr_assert_eq(t.inconsistent, 3);
    cr_assert_eq(t.open + t.nonmanifold, 0);
    cr_assert(!t.watertight);
    /* all of them flipped: consistent again, the volume negative */
    for (uint32_t i = 0; i < m.n_triangles; i++)
        if (i != 5) flip(&m, i);
    cr_assert_eq(mesh_topology(&m, &t), 0);
    cr_assert(t.watertight);
    cr_assert_float_eq(t.volume, -8.0, 1e-12);
    mesh_free(&m);
}

Test(mesh_topology, a_fan_of_three_on_one_edge_is_non_manifold)
{
    const char *obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\n"
                      "f 1 2 3\nf 2 1 4\nf 1 2 5\n";
    mesh m;
    mesh_error e;
    cr_assert_eq(parse_text(obj, MESH_FORMAT_AUTO, &m, &e), 0, "%s", e.msg);
    mesh_topo t;
    cr_assert_eq(mesh_topology(&m, &t), 0);
    cr_assert_eq(t.nonmanifold, 1);
    cr_assert_eq(t.edges, 7);
    cr_assert_eq(t.open, 6);
    cr_assert_eq(t.components, 1);
    cr_assert(!t.watertight);
    mesh_free(&m);
}

Test(mesh_topology, components_and_their_volumes)
{
    /* the tetrahedron twice, the second shifted by 10 in x; then a lone
     * triangle touching neither */
    sink s;
    sink_open(&s);
    for (int c = 0; c < 2; c++) {
        for (int i = 0; i < tetra.nv; i++)
            fprintf(s.f, "v %.9g %.9g %.9g\n", tetra.v[i][0] + 10 * c, tetra.v[i][1], tetra.v[i][2]);
        for (int i = 0; i < tetra.nf; i++)
            fprintf(s.f, "f %d %d %d\n", tetra.f[i][0] + 1 + 4 * c, tetra.f[i][1] + 1 + 4 * c,
                    tetra.f[i][2] + 1 + 4 * c);
    }
    fflush(s.f);
    size_t two = s.len;
    fputs("v 5 5 5\nv 6 5 5\nv 5 6 5\nf 9 10 11\n", s.f);
    sink_close(&s);
    mesh m;
    mesh_error e;
    mesh_topo t;
    cr_assert_eq(mesh_parse(s.buf, two, MESH_FORMAT_AUTO, NULL, &m, &e), 0, "%s", e.msg);
    cr_assert_eq(mesh_topology(&m, &t), 0);
    cr_assert_eq(t.components, 2);
    cr_assert(t.watertight);
    double v1 = 1.4 * 1.5 * (2.3333333 - 0.3) / 6;
    cr_assert_float_eq(t.volume, 2 * v1, 1e-5);
    mesh_free(&m);
    cr_assert_eq(mesh_parse(s.buf, s.len, MESH_FORMAT_AUTO, NULL, &m, &e), 0, "%s", e.msg);
    cr_assert_eq(mesh_topology(&m, &t), 0);
    cr_assert_eq(t.components, 3);
    cr_assert_eq(t.open, 3);
    cr_assert_eq(t.edges, 15);
    cr_assert(!t.watertight);
    mesh_free(&m);
    free(s.buf);
}

/* mesh_edges (the jobs' topology) against a count written here: every
 * pair of edge uses compared, O(n^2), on random triangles over a few
 * vertices, so that edges are open, shared, shared the same way round and
 * shared by three, four and more (past the count a slot keeps), and one
 * vertex has a long bucket; and the same figures as mesh_topology gives. */
static void edges_by_pairs(const mesh *m, mesh_topo *t)
{
    memset(t, 0, sizeof *t);
    size_t n = (size_t)3 * m->n_triangles;
    uint32_t (*use)[3] = malloc(n * sizeof *use); /* lo, hi, forward */
    cr_assert(use);
    for (uint32_t i = 0; i < m->n_triangles; i++)
        for (int k = 0; k < 3; k++) {
            uint32_t a = m->triangles[i][k], b = m->triangles[i][(k + 1) % 3];
            uint32_t *u = use[3 * i + (uint32_t)k];
            u[0] = a < b ? a : b, u[1] = a < b ? b : a, u[2] = a < b;
        }
    for (size_t i = 0; i < n; i++) {
        size_t same = 0, fwd = 0, first = 1;
        for (size_t j = 0; j < n; j++) {
            if (use[j][0] != use[i][0] || use[j][1] != use[i][1]) continue;
            if (j < i) first = 0;
            same++;
            fwd += use[j][2];
        }
        if (!first) continue; /* the edge was counted at its first use */
        t->edges++;
        if (same == 1) t->open++;
        else if (same > 2) t->nonmanifold++;
        else if (fwd != 1) t->inconsistent++;
    }
    t->watertight = !t->open && !t->nonmanifold && !t->inconsistent;
    free(use);
}

Test(mesh_edges, the_same_counts_as_every_pair_of_uses)
{
    for (int round = 0; round < 40; round++) {
        uint32_t nv = 4 + rnd() % 40, nt = 1 + rnd() % 400;
        mesh m = {.n_vertices = nv, .n_triangles = nt};
        m.vertices = calloc(nv, sizeof *m.vertices);
        m.triangles = malloc(nt * sizeof *m.triangles);
        cr_assert(m.vertices && m.triangles);
        for (uint32_t i = 0; i < nt; i++) {
            do {
                for (int k = 0; k < 3; k++) /* vertex 0 in many: its bucket is long */
                    m.triangles[i][k] = rnd() % 3 == 0 ? 0 : rnd() % nv;
            } while (m.triangles[i][0] == m.triangles[i][1] ||
                     m.triangles[i][1] == m.triangles[i][2] ||
                     m.triangles[i][2] == m.triangles[i][0]);
        }
        mesh_topo want, got, full;
        edges_by_pairs(&m, &want);
        cr_assert_eq(mesh_edges(&m, &got), 0);
        cr_assert_eq(mesh_topology(&m, &full), 0);
        cr_assert_eq(got.edges, want.edges, "round %d", round);
        cr_assert_eq(got.open, want.open, "round %d", round);
        cr_assert_eq(got.nonmanifold, want.nonmanifold, "round %d", round);
        cr_assert_eq(got.inconsistent, want.inconsistent, "round %d", round);
        cr_assert_eq(got.watertight, want.watertight, "round %d", round);
        cr_assert_eq(got.components, 0);
        cr_assert_eq(got.volume, 0.0);
        cr_assert_eq(full.edges, want.edges);
        cr_assert_eq(full.open, want.open);
        cr_assert_eq(full.nonmanifold, want.nonmanifold);
        cr_assert_eq(full.inconsistent, want.inconsistent);
        mesh_free(&m);
    }
}

Test(mesh_edges, closed_flipped_and_opened_models)
{
    /* the same edge figures as mesh_topology (whose tests say what they are) */
    for (size_t i = 0; i < sizeof models / sizeof *models; i++)
        for (int change = 0; change < 3; change++) {
            mesh m;
            load_model(models[i], &m);
            if (change == 1) flip(&m, 1);
            if (change == 2) m.n_triangles--;
            mesh_topo got, want;
            cr_assert_eq(mesh_edges(&m, &got), 0);
            cr_assert_eq(mesh_topology(&m, &want), 0);
            cr_assert(got.edges == want.edges && got.open == want.open &&
                          got.nonmanifold == want.nonmanifold &&
                          got.inconsistent == want.inconsistent &&
                          got.watertight == want.watertight,
                      "%s, change %d", models[i]->name, change);
            cr_assert_eq(got.watertight, change == 0, "%s", models[i]->name);
            if (change == 2) m.n_triangles++;
            mesh_free(&m);
        }
}
