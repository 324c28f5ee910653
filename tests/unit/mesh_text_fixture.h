/* mesh_text_fixture — what the parallel text loaders' suites share
 * (test_mesh_ply_par, test_mesh_obj_par): a growing text, the oracle of a
 * mesh written as binary little-endian PLY, and a mesh compared bit for
 * bit. */
#ifndef VOXD_TEST_MESH_TEXT_FIXTURE_H
#define VOXD_TEST_MESH_TEXT_FIXTURE_H

#include <criterion/criterion.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh.h"

typedef struct {
    char *p;
    size_t n, cap;
} text;

static void put(text *s, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void put(text *s, const char *fmt, ...)
{
    va_list ap;
    for (;;) {
        va_start(ap, fmt);
        int n = vsnprintf(s->p + s->n, s->cap - s->n, fmt, ap);
        va_end(ap);
        cr_assert_geq(n, 0);
        if (s->n + (size_t)n < s->cap) {
            s->n += (size_t)n;
            return;
        }
        s->cap = s->cap * 2 + (size_t)n + 4096;
        s->p = realloc(s->p, s->cap);
        cr_assert_not_null(s->p);
    }
}

/* Vertices v[0 .. nv) and triangles t[0 .. nt) as binary little-endian
 * PLY (little-endian hosts only: x86, arm64). */
static inline text ply_binary(const float (*v)[3], int nv, const uint32_t (*t)[3], int nt)
{
    text s = {0};
    put(&s, "ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\n"
            "property float y\nproperty float z\nelement face %d\n"
            "property list uchar int vertex_indices\nend_header\n", nv, nt);
    s.p = realloc(s.p, s.n + (size_t)nv * 12 + (size_t)nt * 13);
    cr_assert_not_null(s.p);
    memcpy(s.p + s.n, v, (size_t)nv * 12);
    s.n += (size_t)nv * 12;
    for (int i = 0; i < nt; i++) {
        s.p[s.n++] = 3;
        memcpy(s.p + s.n, t[i], 12);
        s.n += 12;
    }
    return s;
}

/* s parsed as format f into m; the test fails on an error, saying it. */
static inline void parse_text(const text *s, mesh_format f, mesh *m)
{
    mesh_error e;
    int rc = mesh_parse(s->p, s->n, f, NULL, m, &e);
    cr_assert_eq(rc, 0, "%s (line %llu)", e.msg, (unsigned long long)e.line);
}

static inline void same_mesh(const mesh *a, const mesh *b, const char *what)
{
    cr_assert_eq(a->n_vertices, b->n_vertices, "%s: vertices", what);
    cr_assert_eq(a->n_triangles, b->n_triangles, "%s: triangles", what);
    cr_assert_eq(a->n_degenerate, b->n_degenerate, "%s: degenerate", what);
    cr_assert(!memcmp(a->vertices, b->vertices, 12 * (size_t)a->n_vertices), "%s: positions", what);
    cr_assert(!memcmp(a->triangles, b->triangles, 12 * (size_t)a->n_triangles), "%s: indices",
              what);
    cr_assert(!memcmp(a->lo, b->lo, 12) && !memcmp(a->hi, b->hi, 12), "%s: box", what);
}

#endif
