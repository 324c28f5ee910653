/* The parsers of what a client sends when memory runs out: every
 * allocation of expr_compile, csg_parse and mesh_parse (each text format,
 * and the binary ones on one thread and on several) fails in turn
 * (alloc_fail.h).  Each run gives the whole answer or -ENOMEM with "out of
 * memory" in its message and nothing handed back, and frees every block
 * it allocated. */
#include <criterion/criterion.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc_fail.h"
#include "csg.h"
#include "expr.h"
#include "mesh.h"
#include "mesh_shapes.h"

/* ---- expressions ---- */

static const char blend[] = "m = 44;\n"
                            "a = sqrt((x+0.3)^2 + y^2 + z^2) - 0.5;\n"
                            "b = sqrt((x-0.3)^2 + y^2 + z^2) - 0.5;\n"
                            "-log(exp(-m*a) + exp(-m*b)) / m + min(a, b) * 0 + "
                            "max(abs(x) - 1, abs(y) - 1, abs(z) - 1) * 0";

static int compile_once(void *ctx, char *msg)
{
    size_t *want = ctx;
    expr_tape *t = (expr_tape *)1;
    expr_error err = {0};
    int rc = expr_compile(blend, strlen(blend), NULL, &t, &err);
    memcpy(msg, err.msg, sizeof err.msg);
    if (rc) return rc;
    cr_assert_eq(expr_tape_bytes(t), *want, "a tape of %zu bytes, want %zu",
                 expr_tape_bytes(t), *want);
    expr_tape_free(t);
    return 0;
}

Test(parse_alloc, an_expression_compiles_or_fails_cleanly)
{
    expr_tape *t;
    expr_error err = {0};
    cr_assert_eq(expr_compile(blend, strlen(blend), NULL, &t, &err), 0, "%s", err.msg);
    size_t want = expr_tape_bytes(t);
    expr_tape_free(t);
    cr_assert_geq(alloc_fail_each(compile_once, &want, "expr_compile"), 5);
}

/* ---- CSG trees ---- */

static const char tree[] =
    "block = cuboid center 0,0,-0.1 size 1.6,1.0,0.6\n"
    "boss  = cylinder center 0,0,0.3 radius 0.35 height 0.4 axis z\n"
    "bore  = cylinder center 0,0,0 radius 0.18 height 2 axis z\n"
    "ball  = implicit \"sqrt(x^2 + y^2 + z^2) - 0.4\"\n"
    "blob  = implicit \"x^2 + 2*y^2 + 3*z^2 - 0.2\" domain -1,1\n"
    "part  = difference(difference(union(union(block, boss), blob), bore), ball)\n"
    "result part\n";

static int csg_once(void *ctx, char *msg)
{
    const csg_tree *want = ctx;
    csg_tree *t = (csg_tree *)1;
    csg_error err = {0};
    int rc = csg_parse(tree, strlen(tree), &t, &err);
    memcpy(msg, err.msg, sizeof err.msg);
    if (rc) {
        cr_assert_null(t, "a failed parse handed back a tree");
        return rc;
    }
    cr_assert_eq(t->n, want->n);
    cr_assert_eq(t->text_len, want->text_len);
    cr_assert_eq(memcmp(t->text, want->text, t->text_len), 0);
    csg_tree_free(t);
    return 0;
}

Test(parse_alloc, a_csg_tree_parses_or_fails_cleanly)
{
    csg_tree *want;
    csg_error err = {0};
    cr_assert_eq(csg_parse(tree, strlen(tree), &want, &err), 0, "%s", err.msg);
    cr_assert_geq(alloc_fail_each(csg_once, want, "csg_parse"), 2);
    csg_tree_free(want);
}

/* ---- meshes ---- */

/* A closed mesh's bytes in one format. */
typedef struct {
    char *p;
    size_t n, cap;
} text;

static void add(text *t, const void *p, size_t n)
{
    if (t->n + n > t->cap) {
        t->cap = (t->n + n) * 2;
        t->p = realloc(t->p, t->cap);
        cr_assert(t->p);
    }
    memcpy(t->p + t->n, p, n);
    t->n += n;
}

static void addf(text *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void addf(text *t, const char *fmt, ...)
{
    char line[256];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    cr_assert(n > 0 && (size_t)n < sizeof line);
    add(t, line, (size_t)n);
}

typedef enum { OBJ, OFF, PLY_ASCII, PLY_BINARY, STL_ASCII, STL_BINARY } form;
static const char *const form_name[] = {"OBJ", "OFF", "PLY ascii", "PLY binary", "STL ascii",
                                        "STL binary"};

static void put_f32le(text *t, float x)
{
    add(t, &x, 4); /* x86-64 and the other targets here are little endian */
}

static void put_u32le(text *t, uint32_t x)
{
    add(t, &x, 4);
}

static void write_stl(text *t, const mesh *m, bool binary)
{
    if (!binary) addf(t, "solid s\n");
    else {
        char head[80] = "binary";
        add(t, head, sizeof head);
        put_u32le(t, m->n_triangles);
    }
    for (uint32_t i = 0; i < m->n_triangles; i++) {
        if (!binary) addf(t, "facet normal 0 0 0\nouter loop\n");
        else for (int k = 0; k < 3; k++) put_f32le(t, 0);
        for (int k = 0; k < 3; k++) {
            const float *v = m->vertices[m->triangles[i][k]];
            if (!binary) addf(t, "vertex %.9g %.9g %.9g\n", v[0], v[1], v[2]);
            else for (int a = 0; a < 3; a++) put_f32le(t, v[a]);
        }
        if (!binary) addf(t, "endloop\nendfacet\n");
        else add(t, "\0\0", 2);
    }
    if (!binary) addf(t, "endsolid s\n");
}

static void write_ply(text *t, const mesh *m, bool binary)
{
    addf(t, "ply\nformat %s 1.0\nelement vertex %u\nproperty float x\nproperty float y\n"
         "property float z\nelement face %u\nproperty list uchar int vertex_indices\n"
         "end_header\n", binary ? "binary_little_endian" : "ascii", m->n_vertices,
         m->n_triangles);
    for (uint32_t i = 0; i < m->n_vertices; i++) {
        const float *v = m->vertices[i];
        if (!binary) addf(t, "%.9g %.9g %.9g\n", v[0], v[1], v[2]);
        else for (int a = 0; a < 3; a++) put_f32le(t, v[a]);
    }
    for (uint32_t i = 0; i < m->n_triangles; i++) {
        const uint32_t *c = m->triangles[i];
        if (!binary) addf(t, "3 %u %u %u\n", c[0], c[1], c[2]);
        else {
            add(t, "\3", 1);
            for (int k = 0; k < 3; k++) put_u32le(t, c[k]);
        }
    }
}

static text write_mesh(const mesh *m, form f)
{
    text t = {0};
    if (f == STL_ASCII || f == STL_BINARY) write_stl(&t, m, f == STL_BINARY);
    else if (f == PLY_ASCII || f == PLY_BINARY) write_ply(&t, m, f == PLY_BINARY);
    else {
        if (f == OFF) addf(&t, "OFF\n%u %u 0\n", m->n_vertices, m->n_triangles);
        for (uint32_t i = 0; i < m->n_vertices; i++)
            addf(&t, f == OBJ ? "v %.9g %.9g %.9g\n" : "%.9g %.9g %.9g\n", m->vertices[i][0],
                 m->vertices[i][1], m->vertices[i][2]);
        for (uint32_t i = 0; i < m->n_triangles; i++) {
            const uint32_t *c = m->triangles[i];
            if (f == OBJ) addf(&t, "f %u %u %u\n", c[0] + 1, c[1] + 1, c[2] + 1);
            else addf(&t, "3 %u %u %u\n", c[0], c[1], c[2]);
        }
    }
    return t;
}

typedef struct {
    text in;
    const char *what;
    mesh want;
} mesh_case;

static int mesh_once(void *ctx, char *msg)
{
    const mesh_case *c = ctx;
    mesh m;
    mesh_error err = {0};
    int rc = mesh_parse(c->in.p, c->in.n, MESH_FORMAT_AUTO, NULL, &m, &err);
    memcpy(msg, err.msg, sizeof err.msg);
    if (rc) return rc;
    cr_assert(m.n_vertices == c->want.n_vertices && m.n_triangles == c->want.n_triangles,
              "%s: %u vertices, %u triangles; want %u, %u", c->what, m.n_vertices,
              m.n_triangles, c->want.n_vertices, c->want.n_triangles);
    cr_assert_eq(memcmp(m.triangles, c->want.triangles, m.n_triangles * sizeof *m.triangles), 0,
                 "%s: other triangles", c->what);
    cr_assert_eq(memcmp(m.vertices, c->want.vertices, m.n_vertices * sizeof *m.vertices), 0,
                 "%s: other vertices", c->what);
    mesh_free(&m);
    return 0;
}

/* The icosphere of `level` in each form, parsed with each allocation
 * failing in turn. */
static void meshes_parse_or_fail_cleanly(int level)
{
    shape s;
    shape_init(&s);
    shape_icosphere(&s, (const double[3]){0.1, -0.2, 0.3}, 0.8, level, false);
    const mesh *ico = shape_finish(&s);
    for (form f = OBJ; f <= STL_BINARY; f++) {
        mesh_case c = {write_mesh(ico, f), form_name[f], {0}};
        mesh_error err = {0};
        cr_assert_eq(mesh_parse(c.in.p, c.in.n, MESH_FORMAT_AUTO, NULL, &c.want, &err), 0,
                     "%s: %s", c.what, err.msg);
        cr_assert_eq(c.want.n_triangles, ico->n_triangles, "%s", c.what);
        cr_assert_geq(alloc_fail_each(mesh_once, &c, c.what), 2, "%s", c.what);
        mesh_free(&c.want);
        free(c.in.p);
    }
    shape_free(&s);
}

Test(parse_alloc, a_small_mesh_parses_or_fails_cleanly_in_every_format)
{
    meshes_parse_or_fail_cleanly(2); /* 320 triangles: one thread */
}

/* 81920 triangles: the loaders' parallel paths, on every CPU (a binary
 * STL of 16384 triangles and up, a PLY over 1 MiB, the last step's checks
 * and boxes of 65536 triangles and up). */
Test(parse_alloc, a_larger_mesh_parses_or_fails_cleanly_in_every_format, .timeout = 600)
{
    meshes_parse_or_fail_cleanly(6);
}
