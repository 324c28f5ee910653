/* A large Wavefront OBJ parsed on every CPU (mesh_obj_par.c, mesh_obj.c's
 * fast path), and a large OFF (mesh_off_par.c, mesh_off.c's).
 *
 * A random mesh of 60,000 vertices and 120,000 triangles (about 4 MB of
 * text, past the 1 MiB below which one thread parses) is written as OBJ
 * in several spellings (%.9g and %.8e numbers, a w after the vertex, CRLF
 * line ends, comments, vt and vn statements, i/t/n and i//n face
 * vertices, relative indices with the faces among the vertices), and as
 * binary PLY, an independent oracle: every float printed with 9
 * significant digits reads back to the same bits.  The fast path must
 * give the binary file's mesh bit for bit, and it must have run
 * (mesh_obj_par_runs).  A polygon is fanned as one thread fans it; a line
 * continued by a backslash makes the fast path give up, the one-thread
 * parser's mesh the same; an error late in the file is the one-thread
 * parser's message at its line.  The same mesh as OFF (plain; CRLF with
 * colours after the vertices and faces and the counts on the keyword's
 * line) gives the binary file's mesh on every CPU; a comment line among
 * the records and a quad are read by one thread, to the same mesh and
 * the quad fanned; an index out of range in the last face is told at its
 * line. */
#include <criterion/criterion.h>
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

static uint64_t rng = 0x243f6a8885a308d3ull;
static uint32_t rnd(void)
{
    rng = rng * 6364136223846793005ull + 1442695040888963407ull;
    return (uint32_t)(rng >> 33);
}

/* Positions of every magnitude and sign; triangle t's corners all at or
 * below vertex t / 2 + 2, so that a face can follow the vertices it uses. */
static void make_mesh(void)
{
    for (int i = 0; i < NV; i++)
        for (int k = 0; k < 3; k++)
            vert[i][k] = ldexpf((float)((double)rnd() / 2147483648.0 - 0.5), (int)(rnd() % 13) * 3 - 18);
    for (int t = 0; t < NT; t++) {
        uint32_t top = (uint32_t)t / 2 + 3;
        do {
            for (int k = 0; k < 3; k++) tri[t][k] = rnd() % top;
        } while (tri[t][0] == tri[t][1] || tri[t][1] == tri[t][2] || tri[t][0] == tri[t][2]);
    }
}

enum { PLAIN, EXPONENTS, SLASHES, RELATIVE_CRLF };

/* Vertex i's statement in style. */
static void put_vertex(text *s, int style, int i)
{
    const float *v = vert[i];
    if (style == EXPONENTS) put(s, "v %.8e %.8e %.8e 1.0\n", (double)v[0], (double)v[1], (double)v[2]);
    else if (style == RELATIVE_CRLF) put(s, "v  %.9g\t%.9g %.9g \r\n", (double)v[0], (double)v[1], (double)v[2]);
    else put(s, "v %.9g %.9g %.9g\n", (double)v[0], (double)v[1], (double)v[2]);
}

/* Triangle t's statement in style, `so_far` vertices before it. */
static void put_face(text *s, int style, int t, int so_far)
{
    const uint32_t *c = tri[t];
    if (style == SLASHES)
        put(s, "f %u/%u/%u %u//%u %u/%u # t%d\n", c[0] + 1, t % 7 + 1, t % 5 + 1, c[1] + 1,
            t % 3 + 1, c[2] + 1, t % 11 + 1, t);
    else if (style == RELATIVE_CRLF)
        put(s, "f %d %d %d\r\n", (int)c[0] - so_far, (int)c[1] - so_far, (int)c[2] - so_far);
    else put(s, "f %u %u %u\n", c[0] + 1, c[1] + 1, c[2] + 1);
}

static text obj_file(int style)
{
    text s = {0};
    put(&s, "# a random mesh\nmtllib none.mtl\no thing\n");
    if (style == RELATIVE_CRLF) { /* each face after the vertices it reaches */
        int v = 0;
        for (int t = 0; t < NT; t++) {
            for (; v < NV && v < t / 2 + 3; v++) put_vertex(&s, style, v);
            put_face(&s, style, t, v);
        }
        for (; v < NV; v++) put_vertex(&s, style, v);
        return s;
    }
    for (int i = 0; i < NV; i++) put_vertex(&s, style, i);
    if (style == SLASHES) put(&s, "vt 0.5 0.5\nvn 0 0 1\ng part\nusemtl red\ns off\n");
    for (int t = 0; t < NT; t++) put_face(&s, style, t, NV);
    return s;
}

/* The oracle: the same mesh as binary little-endian PLY. */
static text binary_file(void)
{
    return ply_binary(vert, NV, tri, NT);
}

static uint64_t par_runs(void) { return atomic_load(&mesh_obj_par_runs); }

static void parse(const text *s, mesh *m) { parse_text(s, MESH_FORMAT_OBJ, m); }

TestSuite(mesh_obj_par, .init = make_mesh);

Test(mesh_obj_par, every_spelling_gives_the_binary_files_mesh_on_every_cpu)
{
    text bin = binary_file();
    mesh want, got;
    mesh_error e;
    cr_assert_eq(mesh_parse(bin.p, bin.n, MESH_FORMAT_AUTO, NULL, &want, &e), 0, "%s", e.msg);
    cr_assert_eq(want.n_vertices, NV);
    cr_assert_eq(want.n_triangles, NT);
    for (int style = PLAIN; style <= RELATIVE_CRLF; style++) {
        text s = obj_file(style);
        cr_assert_gt(s.n, 1u << 20);
        uint64_t runs = par_runs();
        parse(&s, &got);
        cr_assert_eq(par_runs(), runs + 1, "style %d: not parsed on every CPU", style);
        same_mesh(&got, &want, "obj");
        mesh_free(&got);
        free(s.p);
    }
    free(bin.p);
    mesh_free(&want);
}

/* s with its first face's line made a polygon of its three corners and
 * the last vertex (fanned: the triangle, then (a, c, last)), or continued by a
 * backslash onto a comment: the fast path's mesh or the one-thread
 * parser's, each what one thread makes of it. */
Test(mesh_obj_par, a_polygon_is_fanned_and_a_continued_line_read_by_one_thread)
{
    text plain = obj_file(PLAIN);
    char *f = strstr(plain.p, "\nf ") + 1, *nl = strchr(f, '\n');
    uint32_t a = tri[0][0] + 1, c = tri[0][2] + 1;
    for (int kind = 0; kind < 2; kind++) {
        char quad[16];
        snprintf(quad, sizeof quad, " %d\n", NV);
        const char *with = kind == 0 ? quad : " \\\n# joined\n";
        size_t head = (size_t)(nl - plain.p), tail = (size_t)(plain.p + plain.n - nl - 1);
        text s = {malloc(head + strlen(with) + tail), 0, 0};
        cr_assert_not_null(s.p);
        memcpy(s.p, plain.p, head);
        memcpy(s.p + head, with, strlen(with));
        memcpy(s.p + head + strlen(with), nl + 1, tail);
        s.n = head + strlen(with) + tail;
        uint64_t runs = par_runs();
        mesh got;
        parse(&s, &got);
        cr_assert_eq(par_runs(), runs + (kind == 0), "kind %d: the wrong path ran", kind);
        cr_assert_eq(got.n_vertices, NV);
        cr_assert_eq(got.n_triangles, NT + (kind == 0), "kind %d", kind);
        cr_assert(!memcmp(got.triangles[0], tri[0], 12));
        if (kind == 0)
            cr_assert(got.triangles[1][0] == a - 1 && got.triangles[1][1] == c - 1 &&
                      got.triangles[1][2] == NV - 1, "the fan's second triangle");
        cr_assert(!memcmp(got.triangles[1 + (kind == 0)], tri[1], 12 * (NT - 1)));
        mesh_free(&got);
        free(s.p);
    }
    free(plain.p);
}

/* A face in the last part that reaches past the vertices: refused with the
 * one-thread parser's message, at its line. */
Test(mesh_obj_par, an_error_late_in_the_file_is_told_at_its_line)
{
    text s = obj_file(PLAIN);
    put(&s, "f 1 2 %d\n", NV + 5);
    uint64_t lines = 0;
    for (size_t i = 0; i < s.n; i++) lines += s.p[i] == '\n';
    mesh m;
    mesh_error e;
    cr_assert_eq(mesh_parse(s.p, s.n, MESH_FORMAT_OBJ, NULL, &m, &e), -EINVAL);
    cr_assert_eq(e.line, lines, "line %llu, want %llu", (unsigned long long)e.line,
                 (unsigned long long)lines);
    char want[96];
    snprintf(want, sizeof want, "vertex index %d out of range (%d vertices so far)", NV + 5, NV);
    cr_assert(strstr(e.msg, want), "'%s' lacks '%s'", e.msg, want);
    free(s.p);
}

/* ---- OFF ---- */

static uint64_t off_runs(void) { return atomic_load(&mesh_off_par_runs); }

static text off_file(int crlf)
{
    text s = {0};
    const char *nl = crlf ? "\r\n" : "\n";
    if (crlf) put(&s, "OFF %d %d 0\r\n", NV, NT);
    else put(&s, "# a random mesh\nOFF\n%d %d 0\n", NV, NT);
    for (int i = 0; i < NV; i++)
        put(&s, crlf ? "%.9g %.9g %.9g 0.5 0.25 1%s" : "%.9g %.9g %.9g%s", (double)vert[i][0],
            (double)vert[i][1], (double)vert[i][2], nl);
    for (int t = 0; t < NT; t++)
        put(&s, crlf ? "3 %u %u %u 255 0 0%s" : "3  %u %u\t%u%s", tri[t][0], tri[t][1], tri[t][2], nl);
    return s;
}

static void parse_off(const text *s, mesh *m) { parse_text(s, MESH_FORMAT_OFF, m); }

Test(mesh_obj_par, an_off_file_gives_the_binary_files_mesh_on_every_cpu)
{
    text bin = binary_file();
    mesh want, got;
    mesh_error e;
    cr_assert_eq(mesh_parse(bin.p, bin.n, MESH_FORMAT_AUTO, NULL, &want, &e), 0, "%s", e.msg);
    for (int crlf = 0; crlf < 2; crlf++) {
        text s = off_file(crlf);
        cr_assert_gt(s.n, 1u << 20);
        uint64_t runs = off_runs();
        parse_off(&s, &got);
        cr_assert_eq(off_runs(), runs + 1, "crlf %d: not parsed on every CPU", crlf);
        same_mesh(&got, &want, "off");
        mesh_free(&got);
        free(s.p);
    }
    free(bin.p);
    mesh_free(&want);
}

/* s with the n bytes at `at` replaced by with. */
static text spliced(const text *s, size_t at, size_t n, const char *with)
{
    size_t w = strlen(with);
    text r = {malloc(s->n - n + w), s->n - n + w, 0};
    cr_assert_not_null(r.p);
    memcpy(r.p, s->p, at);
    memcpy(r.p + at, with, w);
    memcpy(r.p + at + w, s->p + at + n, s->n - at - n);
    return r;
}

Test(mesh_obj_par, an_off_layout_it_does_not_take_is_read_by_one_thread)
{
    text plain = off_file(0);
    mesh want, got;
    parse_off(&plain, &want);
    /* a comment line before the 30,000th vertex's line */
    char *mid = plain.p;
    for (int i = 0; i < 30003; i++) mid = strchr(mid, '\n') + 1;
    text c = spliced(&plain, (size_t)(mid - plain.p), 0, "# a comment\n");
    uint64_t runs = off_runs();
    parse_off(&c, &got);
    cr_assert_eq(off_runs(), runs, "a comment line: the fast path ran");
    same_mesh(&got, &want, "comment");
    mesh_free(&got);
    free(c.p);
    /* the last face a quad with the last vertex: fanned */
    char *last = plain.p + plain.n - 1;
    while (last[-1] != '\n') last--;
    char quad[96];
    snprintf(quad, sizeof quad, "4 %u %u %u %d\n", tri[NT - 1][0], tri[NT - 1][1], tri[NT - 1][2],
             NV - 1);
    text q = spliced(&plain, (size_t)(last - plain.p), (size_t)(plain.p + plain.n - last), quad);
    runs = off_runs();
    parse_off(&q, &got);
    cr_assert_eq(off_runs(), runs, "a quad: the fast path ran");
    cr_assert_eq(got.n_triangles, want.n_triangles + 1);
    cr_assert(!memcmp(got.triangles, want.triangles, 12 * (size_t)want.n_triangles));
    cr_assert(got.triangles[NT][0] == tri[NT - 1][0] && got.triangles[NT][2] == NV - 1);
    mesh_free(&got);
    free(q.p);
    /* the last face's index out of range: told at its line */
    snprintf(quad, sizeof quad, "3 0 1 %d\n", NV + 7);
    text bad = spliced(&plain, (size_t)(last - plain.p), (size_t)(plain.p + plain.n - last), quad);
    mesh_error e;
    cr_assert_eq(mesh_parse(bad.p, bad.n, MESH_FORMAT_OFF, NULL, &got, &e), -EINVAL);
    cr_assert_eq(e.line, 3 + (uint64_t)NV + NT, "line %llu", (unsigned long long)e.line);
    char want_msg[96];
    snprintf(want_msg, sizeof want_msg, "vertex index %d out of range (%d vertices)", NV + 7, NV);
    cr_assert(strstr(e.msg, want_msg), "'%s' lacks '%s'", e.msg, want_msg);
    free(bad.p);
    mesh_free(&want);
    free(plain.p);
}
