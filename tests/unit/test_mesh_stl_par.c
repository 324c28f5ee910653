/* A large binary STL parsed and welded on several threads (mesh_stl_par.c).
 *
 * A random indexed mesh of 20,000 positions and 60,000 triangles (past the
 * 16,384 below which the serial path reads the file) is written here as
 * binary STL, every triangle its own three positions: a few positions
 * repeated under other indices, 0 beside -0 (they weld, and the first one
 * seen is kept), degenerate triangles before and after the weld.  Two
 * oracles: the serial path (parse_binary, then mesh_build_weld) and a weld
 * written here from the definition (the corners sorted by their bits, the
 * first of each position numbered in the file's order).  Every number of
 * threads must give both their mesh bit for bit, and the parallel path
 * must have run; a soup (no position twice) and a crowd (16 positions)
 * grow and skew the parts; a coordinate not finite and the limits give
 * the serial path's errors. */
#include <criterion/criterion.h>
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "mesh.h"
#include "mesh_load.h"
#include "mesh_shapes.h"
#include "unit_util.h"

#define NV 20000
#define NT 60000

static float vert[NV][3];
static uint32_t tri[NT][3];

static uint64_t rng = 0x2545f4914f6cdd1dull;
static uint32_t rnd(void) { return xorshift32(&rng); }

/* Positions of every magnitude and sign; position 2 is position 1's 0
 * with -0s, seen first; every 97th repeats an earlier one; triangle 100
 * repeats an index, triangle 200 two indices of one position (degenerate
 * once welded). */
static void make_mesh(void)
{
    for (int i = 0; i < NV; i++)
        for (int k = 0; k < 3; k++)
            vert[i][k] = ldexpf((float)((double)rnd() / 4294967296.0 - 0.5), (int)(rnd() % 13) - 6);
    vert[1][0] = vert[1][1] = vert[1][2] = 0.0f;
    vert[2][0] = -0.0f, vert[2][1] = 0.0f, vert[2][2] = -0.0f;
    for (int i = 97; i < NV; i += 97) memcpy(vert[i], vert[i / 2], sizeof vert[i]);
    for (int t = 0; t < NT; t++)
        do {
            for (int k = 0; k < 3; k++) tri[t][k] = rnd() % NV;
        } while (tri[t][0] == tri[t][1] || tri[t][1] == tri[t][2] || tri[t][0] == tri[t][2]);
    tri[0][0] = 2, tri[1][0] = 1; /* -0 seen before 0 */
    for (int t = 0; t < 2; t++) tri[t][1] = 3 + t, tri[t][2] = 5 + t;
    tri[100][1] = tri[100][0];
    tri[200][0] = 97, tri[200][1] = 48;
}

typedef struct {
    unsigned char *p;
    size_t n;
} file;

/* The triangles of pos (nt of them, corner by corner) as binary STL, its
 * header beginning with "solid" as many exporters' do, junk normals. */
static file stl_of(float (*pos)[3], uint32_t nt)
{
    file f = {calloc(1, 84 + 50 * (size_t)nt), 84 + 50 * (size_t)nt};
    cr_assert_not_null(f.p);
    memcpy(f.p, "solid written by test_mesh_stl_par", 35);
    memcpy(f.p + 80, &nt, 4); /* little-endian hosts only (x86, arm64) */
    for (uint32_t t = 0; t < nt; t++) {
        unsigned char *r = f.p + 84 + 50 * (size_t)t;
        float normal[3] = {(float)rnd(), -1.0f, NAN};
        memcpy(r, normal, 12);
        memcpy(r + 12, pos[3 * t], 36);
        r[48] = (unsigned char)t, r[49] = 0xff;
    }
    return f;
}

/* The corners of the indexed mesh, in the file's order. */
static float (*corners(void))[3]
{
    float (*c)[3] = malloc(sizeof(float[3]) * 3 * NT);
    cr_assert_not_null(c);
    for (int t = 0; t < NT; t++)
        for (int k = 0; k < 3; k++) memcpy(c[3 * t + k], vert[tri[t][k]], 12);
    return c;
}

static uint64_t par_runs(void) { return atomic_load(&mesh_stl_par_runs); }

/* mesh_parse's STL path with stl_threads set (mesh_load.c's parse_in). */
static int parse_with(const file *f, unsigned threads, const mesh_limits *lim, mesh *m, mesh_error *e)
{
    memset(e, 0, sizeof *e);
    memset(m, 0, sizeof *m);
    mbuild b = {.max_tri = lim && lim->max_triangles ? lim->max_triangles : MESH_MAX_TRIANGLES,
                .max_vert = lim && lim->max_vertices ? lim->max_vertices : MESH_MAX_VERTICES,
                .buf = (const char *)f->p, .err = e, .stl_threads = threads};
    int rc = mesh_parse_stl((const char *)f->p, f->n, &b);
    if (!rc) rc = mesh_build_finish(&b, MESH_FORMAT_STL, m);
    mesh_build_free(&b);
    return rc;
}

static void same_mesh(const mesh *a, const mesh *b, const char *what, unsigned threads)
{
    cr_assert_eq(a->n_vertices, b->n_vertices, "%s, %u threads: vertices", what, threads);
    cr_assert_eq(a->n_triangles, b->n_triangles, "%s, %u threads: triangles", what, threads);
    cr_assert_eq(a->n_degenerate, b->n_degenerate, "%s, %u threads: degenerate", what, threads);
    cr_assert(!memcmp(a->vertices, b->vertices, 12 * (size_t)a->n_vertices), "%s, %u threads: positions",
              what, threads);
    cr_assert(!memcmp(a->triangles, b->triangles, 12 * (size_t)a->n_triangles), "%s, %u threads: indices",
              what, threads);
    cr_assert(!memcmp(a->lo, b->lo, 12) && !memcmp(a->hi, b->hi, 12), "%s, %u threads: box", what, threads);
}

/* ---------------------------------------------- the weld by definition */

typedef struct {
    uint32_t key[3], c;
} keyed;

static int by_key_then_corner(const void *pa, const void *pb)
{
    const keyed *a = pa, *b = pb;
    int d = memcmp(a->key, b->key, sizeof a->key);
    return d ? d : (a->c > b->c) - (a->c < b->c);
}

/* The mesh of n corners c (n / 3 triangles): each position's first corner
 * found by sorting the corners by their bits (-0 as 0), the first corners
 * numbered in order, the degenerate triangles dropped. */
static void weld_by_definition(float (*c)[3], uint32_t n, mesh *m)
{
    keyed *k = malloc(n * sizeof *k);
    uint32_t *first = malloc(n * sizeof *first), *num = malloc(n * sizeof *num);
    cr_assert(k && first && num);
    for (uint32_t i = 0; i < n; i++) {
        for (int a = 0; a < 3; a++) {
            float x = c[i][a] == 0 ? 0.0f : c[i][a];
            memcpy(&k[i].key[a], &x, 4);
        }
        k[i].c = i;
    }
    qsort(k, n, sizeof *k, by_key_then_corner);
    for (uint32_t i = 0; i < n; i++)
        first[k[i].c] = i && !memcmp(k[i].key, k[i - 1].key, 12) ? first[k[i - 1].c] : k[i].c;
    *m = (mesh){.vertices = malloc(n * sizeof *m->vertices),
                .triangles = malloc(n / 3 * sizeof *m->triangles)};
    for (uint32_t i = 0; i < n; i++)
        if (first[i] == i) memcpy(m->vertices[num[i] = m->n_vertices++], c[i], 12);
    float lo[3] = {FLT_MAX, FLT_MAX, FLT_MAX}, hi[3] = {-FLT_MAX, -FLT_MAX, -FLT_MAX};
    for (uint32_t t = 0; t < n / 3; t++) {
        uint32_t w[3] = {num[first[3 * t]], num[first[3 * t + 1]], num[first[3 * t + 2]]};
        if (shape_degenerate(m->vertices, w)) {
            m->n_degenerate++;
            continue;
        }
        memcpy(m->triangles[m->n_triangles++], w, 12);
        for (int j = 0; j < 3; j++)
            for (int a = 0; a < 3; a++) {
                float x = m->vertices[w[j]][a];
                if (x < lo[a]) lo[a] = x;
                if (x > hi[a]) hi[a] = x;
            }
    }
    memcpy(m->lo, lo, 12), memcpy(m->hi, hi, 12);
    free(k), free(first), free(num);
}

/* ------------------------------------------------------------ the tests */

TestSuite(mesh_stl_par, .init = make_mesh);

/* The serial path's mesh, the definition's, and every number of threads'. */
static void check_file(const file *f, float (*c)[3], uint32_t n, const char *what)
{
    mesh want, serial, got;
    mesh_error e;
    weld_by_definition(c, n, &want);
    cr_assert_eq(parse_with(f, MESH_STL_SERIAL, NULL, &serial, &e), 0, "%s", e.msg);
    same_mesh(&serial, &want, what, 0);
    const unsigned threads[] = {1, 2, 3, 5, 8, 64};
    for (size_t i = 0; i < sizeof threads / sizeof *threads; i++) {
        uint64_t runs = par_runs();
        cr_assert_eq(parse_with(f, threads[i], NULL, &got, &e), 0, "%s", e.msg);
        cr_assert_eq(par_runs(), runs + 1, "%s, %u threads: the serial path ran", what, threads[i]);
        same_mesh(&got, &want, what, threads[i]);
        mesh_free(&got);
    }
    uint64_t runs = par_runs(); /* mesh_parse: one thread a CPU */
    cr_assert_eq(mesh_parse(f->p, f->n, MESH_FORMAT_AUTO, NULL, &got, &e), 0, "%s", e.msg);
    cr_assert_eq(par_runs(), runs + 1);
    same_mesh(&got, &want, what, 0);
    mesh_free(&got), mesh_free(&serial), mesh_free(&want);
}

Test(mesh_stl_par, every_number_of_threads_gives_the_serial_paths_mesh)
{
    float (*c)[3] = corners();
    file f = stl_of(c, NT);
    mesh m;
    mesh_error e;
    cr_assert_eq(parse_with(&f, 2, NULL, &m, &e), 0, "%s", e.msg);
    /* the oracle's own checks: welded, -0 first, triangles 100 and 200 dropped */
    cr_assert_lt(m.n_vertices, NV);
    cr_assert_geq(m.n_degenerate, 2, "%u", m.n_degenerate); /* 100, 200, and chance */
    cr_assert_eq(m.triangles[0][0], 0);
    cr_assert_eq(m.triangles[1][0], 0, "0 and -0 welded");
    cr_assert(signbit(m.vertices[0][0]) && !signbit(m.vertices[0][1]), "the first seen kept");
    mesh_free(&m);
    check_file(&f, c, 3 * NT, "the mesh");
    free(f.p), free(c);
}

/* No position twice: the parts' arrays and tables grow past their first
 * sizes.  16 positions: nearly every corner a repeat, the parts skewed. */
Test(mesh_stl_par, a_soup_and_a_crowd)
{
    float (*c)[3] = malloc(sizeof(float[3]) * 3 * NT);
    cr_assert_not_null(c);
    for (int i = 0; i < 3 * NT; i++)
        for (int a = 0; a < 3; a++) c[i][a] = (float)(int)(rnd() % 2000000) - 1e6f;
    file soup = stl_of(c, NT);
    check_file(&soup, c, 3 * NT, "soup");
    for (int i = 0; i < 3 * NT; i++) memcpy(c[i], vert[rnd() % 16], 12);
    file crowd = stl_of(c, NT);
    check_file(&crowd, c, 3 * NT, "crowd");
    free(soup.p), free(crowd.p), free(c);
}

/* A file the parallel path leaves: the serial path's error, or mesh. */
static void same_outcome(const file *f, const mesh_limits *lim, int want_rc, const char *want)
{
    mesh a, b;
    mesh_error ea, eb;
    uint64_t runs = par_runs();
    int ra = parse_with(f, MESH_STL_SERIAL, lim, &a, &ea), rb = parse_with(f, 2, lim, &b, &eb);
    cr_assert_eq(ra, want_rc, "%s", ea.msg);
    cr_assert_eq(rb, ra, "%s", eb.msg);
    cr_assert_eq(par_runs(), runs, "%s: the parallel path kept it", want);
    cr_assert_str_eq(eb.msg, ea.msg);
    cr_assert(strstr(ea.msg, want), "'%s' lacks '%s'", ea.msg, want);
    cr_assert_eq(eb.offset, ea.offset);
    if (ra == 0) same_mesh(&b, &a, "small", 2);
    else cr_assert_null(b.vertices);
    mesh_free(&a), mesh_free(&b);
}

Test(mesh_stl_par, what_it_leaves_gets_the_serial_paths_errors)
{
    float (*c)[3] = corners();
    file f = stl_of(c, NT);
    float nan = NAN, inf = INFINITY;
    memcpy(f.p + 84 + 50 * (size_t)(NT - 10) + 12 + 12 + 4, &nan, 4); /* a late corner's y */
    same_outcome(&f, NULL, -EINVAL, "not a finite number");
    memcpy(f.p + 84 + 50 * (size_t)(NT - 10) + 12 + 12 + 4, &inf, 4);
    same_outcome(&f, NULL, -EINVAL, "not a finite number");
    free(f.p);
    f = stl_of(c, NT);
    same_outcome(&f, &(mesh_limits){.max_vertices = 1000}, -E2BIG,
                 "distinct vertices: more than the limit of 1000");
    same_outcome(&f, &(mesh_limits){.max_triangles = NT - 1}, -E2BIG, "more than the limit");
    free(f.p);
    f = stl_of(c, 16383); /* below the parallel path's size */
    same_outcome(&f, NULL, 0, "");
    free(f.p), free(c);
}
