/* A large ASCII PLY file parsed on every CPU (mesh_ply.c's fast path).
 *
 * A random mesh of 60,000 vertices and 120,000 triangles (about 3 MB of
 * text, past the 1 MiB below which one thread parses) is written as ASCII
 * PLY in several spellings of its numbers (%.9g, %.8e, a leading '+',
 * "-0", CRLF line ends, trailing blanks, an extra vertex property and an
 * extra element with a list), and as binary little-endian PLY, an
 * independent oracle: every float printed with 9 significant digits reads
 * back to the same bits.  The fast path must give the binary file's mesh
 * bit for bit, and it must have run (mesh_ply_par_runs).  Layouts the fast
 * path does not take (an item over two lines, a blank line, a quad, the
 * vertex element after the faces) must give the one-thread parser's mesh,
 * and errors anywhere in the file the one-thread parser's message and line.
 */
#include <criterion/criterion.h>
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh.h"
#include "mesh_load.h"
#include "mesh_text_fixture.h"

#define NV 60000
#define NT 120000

static float vert[NV][3];
static uint32_t tri[NT][3];

static uint64_t rng = 0x9e3779b97f4a7c15ull;
static uint32_t rnd(void)
{
    rng = rng * 6364136223846793005ull + 1442695040888963407ull;
    return (uint32_t)(rng >> 33);
}

/* Positions of every magnitude and sign, a few degenerate triangles. */
static void make_mesh(void)
{
    for (int i = 0; i < NV; i++)
        for (int k = 0; k < 3; k++) {
            float x = (float)((double)rnd() / 2147483648.0 - 0.5);
            int e = (int)(rnd() % 13) - 6;
            vert[i][k] = ldexpf(x, e * 3);
        }
    vert[0][0] = vert[0][2] = 0.0f;
    vert[7][1] = -0.0f;
    for (int t = 0; t < NT; t++) /* three distinct corners, none vertex 0 */
        do {
            for (int k = 0; k < 3; k++) tri[t][k] = 1 + rnd() % (NV - 1);
        } while (tri[t][0] == tri[t][1] || tri[t][1] == tri[t][2] || tri[t][0] == tri[t][2]);
    tri[100][1] = tri[100][0]; /* degenerate: dropped by both parsers */
}

enum { PLAIN, EXP, CRLF_EXTRA, VERTS_LAST };

/* The ASCII file in one of the spellings. */
static text ascii_file(int style)
{
    text s = {0};
    const char *eol = style == CRLF_EXTRA ? " \r\n" : "\n";
    put(&s, "ply\nformat ascii 1.0\ncomment a test\n");
    if (style == CRLF_EXTRA) put(&s, "element material 2\nproperty list uchar float rgb\n");
    if (style != VERTS_LAST)
        put(&s, "element vertex %d\nproperty float x\nproperty float y\nproperty float z\n", NV);
    if (style == CRLF_EXTRA) put(&s, "property uchar confidence\n");
    put(&s, "element face %d\nproperty list uchar int vertex_indices\n", NT);
    if (style == VERTS_LAST)
        put(&s, "element vertex %d\nproperty float x\nproperty float y\nproperty float z\n", NV);
    put(&s, "end_header\n");
    if (style == CRLF_EXTRA) put(&s, "3 0.5 0.25 1%s0 %s", eol, eol);
    for (int pass = 0; pass < 2; pass++) {
        int verts = (pass == 0) == (style != VERTS_LAST);
        for (int i = 0; verts && i < NV; i++) {
            const float *v = vert[i];
            if (style == EXP) put(&s, "%.8e %+.8e %.8e", v[0], v[1], v[2]);
            else put(&s, "%.9g %.9g %.9g", v[0], v[1], v[2]);
            if (style == CRLF_EXTRA) put(&s, " %d", i % 256);
            put(&s, "%s", eol);
        }
        for (int t = 0; !verts && t < NT; t++)
            put(&s, "3 %u %u %u%s", tri[t][0], tri[t][1], tri[t][2], eol);
    }
    return s;
}

/* The same mesh as binary little-endian PLY. */
static text binary_file(void)
{
    return ply_binary(vert, NV, tri, NT);
}

static uint64_t par_runs(void) { return atomic_load(&mesh_ply_par_runs); }

static void parse(const text *s, mesh *m) { parse_text(s, MESH_FORMAT_AUTO, m); }

TestSuite(mesh_ply_par, .init = make_mesh);

/* The oracle for the binary file's mesh: the triangles but the degenerate
 * one, in order, and their box, taken here one by one. */
static void check_against_arrays(const mesh *m)
{
    cr_assert_eq(m->n_vertices, NV);
    cr_assert(!memcmp(m->vertices, vert, sizeof vert));
    cr_assert_eq(m->n_triangles, NT - 1);
    cr_assert_eq(m->n_degenerate, 1);
    cr_assert(!memcmp(m->triangles, tri, 100 * 12));
    cr_assert(!memcmp(m->triangles[100], tri[101], (NT - 101) * 12));
    float lo[3] = {FLT_MAX, FLT_MAX, FLT_MAX}, hi[3] = {-FLT_MAX, -FLT_MAX, -FLT_MAX};
    for (int t = 0; t < NT; t++)
        for (int k = 0; t != 100 && k < 3; k++)
            for (int a = 0; a < 3; a++) {
                float x = vert[tri[t][k]][a];
                if (x < lo[a]) lo[a] = x;
                if (x > hi[a]) hi[a] = x;
            }
    cr_assert(!memcmp(m->lo, lo, sizeof lo) && !memcmp(m->hi, hi, sizeof hi));
}

Test(mesh_ply_par, every_spelling_gives_the_binary_files_mesh_on_every_cpu)
{
    text bin = binary_file();
    mesh want, got;
    parse(&bin, &want);
    check_against_arrays(&want);
    for (int style = PLAIN; style <= CRLF_EXTRA; style++) {
        text s = ascii_file(style);
        cr_assert_gt(s.n, 1u << 20);
        uint64_t runs = par_runs();
        parse(&s, &got);
        cr_assert_eq(par_runs(), runs + 1, "style %d: not parsed on every CPU", style);
        same_mesh(&got, &want, "ascii");
        mesh_free(&got);
        free(s.p);
    }
    free(bin.p);
    mesh_free(&want);
}

/* A copy of s with `with` in place of the n bytes at at. */
static text edit(const text *s, size_t at, size_t n, const char *with)
{
    size_t w = strlen(with);
    text o = {malloc(s->n - n + w + 1), s->n - n + w, 0};
    cr_assert_not_null(o.p);
    memcpy(o.p, s->p, at);
    memcpy(o.p + at, with, w);
    memcpy(o.p + at + w, s->p + at + n, s->n - at - n);
    return o;
}

/* The byte offset where line `line` (1-based) of s starts. */
static size_t line_at(const text *s, uint64_t line)
{
    size_t at = 0;
    for (uint64_t l = 1; l < line; l++) {
        const char *nl = memchr(s->p + at, '\n', s->n - at);
        cr_assert_not_null(nl);
        at = (size_t)(nl - s->p) + 1;
    }
    return at;
}

/* Layouts the fast path leaves to one thread: the same mesh. */
Test(mesh_ply_par, other_layouts_give_the_same_mesh_on_one_thread)
{
    text s = ascii_file(PLAIN);
    mesh want, got;
    parse(&s, &want);
    size_t mid = line_at(&s, 11 + NV + NT / 2); /* a face in the middle (10 header lines) */
    const char *nl = memchr(s.p + mid, '\n', s.n - mid);
    size_t sp = (size_t)((const char *)memchr(s.p + mid, ' ', s.n - mid) - s.p);
    text split = edit(&s, sp, 1, "\n"); /* its count on a line of its own */
    text blank = edit(&s, mid, 0, "  \n");
    text trailing = edit(&s, s.n, 0, "\n \n\n");
    const text *same[] = {&split, &blank, &trailing};
    for (int i = 0; i < 3; i++) {
        uint64_t runs = par_runs();
        parse(same[i], &got);
        cr_assert_eq(par_runs(), runs + (i == 2), "layout %d", i);
        same_mesh(&got, &want, "layout");
        mesh_free(&got);
    }
    /* a quad in place of that face: two triangles by the fan */
    char quad[64];
    snprintf(quad, sizeof quad, "4 %u %u %u 0", tri[NT / 2][0], tri[NT / 2][1], tri[NT / 2][2]);
    text q = edit(&s, mid, (size_t)(nl - s.p) - mid, quad);
    parse(&q, &got);
    /* face 100 is degenerate: face NT / 2 is kept triangle NT / 2 - 1 */
    size_t k = NT / 2 - 1, rest = want.n_triangles - k - 1;
    cr_assert_eq(got.n_triangles, want.n_triangles + 1);
    cr_assert(!memcmp(got.triangles, want.triangles, 12 * k));
    uint32_t fan[2][3] = {{tri[NT / 2][0], tri[NT / 2][1], tri[NT / 2][2]},
                          {tri[NT / 2][0], tri[NT / 2][2], 0}};
    cr_assert(!memcmp(got.triangles[k], fan, sizeof fan));
    cr_assert(!memcmp(got.triangles[k + 2], want.triangles[k + 1], 12 * rest));
    mesh_free(&got);
    text last = ascii_file(VERTS_LAST);
    uint64_t runs = par_runs();
    parse(&last, &got);
    cr_assert_eq(par_runs(), runs + 1, "the faces first are parsed on every CPU too");
    same_mesh(&got, &want, "faces first");
    mesh_free(&got);
    free(split.p), free(blank.p), free(trailing.p), free(q.p), free(last.p), free(s.p);
    mesh_free(&want);
}

/* An error anywhere: the one-thread parser's message and line. */
static void refuse_at(const text *s, uint64_t line, const char *with, const char *want,
                      uint64_t want_line)
{
    size_t at = line_at(s, line);
    const char *nl = memchr(s->p + at, '\n', s->n - at);
    text o = edit(s, at, (size_t)(nl - s->p) - at, with);
    mesh m;
    mesh_error e;
    cr_assert_eq(mesh_parse(o.p, o.n, MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL, "%s", with);
    cr_assert(strstr(e.msg, want), "'%s' lacks '%s'", e.msg, want);
    cr_assert_eq(e.line, want_line, "%s: line %llu, want %llu", e.msg,
                 (unsigned long long)e.line, (unsigned long long)want_line);
    cr_assert_null(m.vertices);
    free(o.p);
}

Test(mesh_ply_par, errors_anywhere_are_the_one_thread_parsers)
{
    text s = ascii_file(PLAIN);
    const uint64_t v0 = 11, f0 = 11 + NV; /* the first vertex's and face's lines */
    refuse_at(&s, v0 + NV / 3, "0.5 x 0.25", "vertex 20000: a number expected, found 'x'",
              v0 + NV / 3);
    refuse_at(&s, v0 + NV - 1, "0.5 1e39 0.25", "not a finite number", v0 + NV - 1);
    refuse_at(&s, f0 + NT / 2, "3 1 2 60000", "out of range", f0 + NT / 2);
    refuse_at(&s, f0 + 5, "3 1 -2 5", "out of range", f0 + 5);
    refuse_at(&s, f0 + NT - 1, "2 1 2", "fewer than 3", f0 + NT - 1);
    refuse_at(&s, f0 + 99, "3 1 2 3\nzzz", "face 100: a list count expected, found 'zzz'",
              f0 + 100);
    text extra = edit(&s, s.n, 0, "junk\n");
    mesh m;
    mesh_error e;
    cr_assert_eq(mesh_parse(extra.p, extra.n, MESH_FORMAT_AUTO, NULL, &m, &e), -EINVAL);
    cr_assert(strstr(e.msg, "'junk' after the last element"), "%s", e.msg);
    cr_assert_eq(e.line, f0 + NT);
    free(extra.p);
    free(s.p);
}
