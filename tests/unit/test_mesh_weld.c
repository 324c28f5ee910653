/* mesh_weld against a brute-force weld written here from its definition:
 * for each vertex in order, the first earlier kept vertex within eps
 * (dx^2 + dy^2 + dz^2 <= eps^2 in double), else it is kept; O(n^2).
 *
 * The meshes are made here: an icosphere turned into a soup (every
 * triangle its own three vertices) with each copy moved by up to a
 * jitter, which the weld must close again; random clusters of points much
 * denser than eps, where the greedy order decides everything; a lattice
 * whose neighbours lie exactly eps apart; coordinates far past 2^40 cells
 * and near zero; eps = 0 with -0 and 0.  Every case must give the brute
 * force's vertices, bit for bit, and its triangles (less the degenerate
 * ones, by their definition in mesh.h).  The exact weld of many vertices,
 * on every CPU, against a sorted oracle, also with a part's table refused
 * (malloc wrapped for this binary: it falls back to one thread). */
#include <criterion/criterion.h>
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh.h"
#include "mesh_load.h"
#include "mesh_shapes.h"
#include "par.h"
#include "proto_check.h"

/* ---------------------------------------------------------- the oracle */

static void brute_map(float (*v)[3], uint32_t n, double eps, uint32_t *map)
{
    uint32_t *kept = malloc(n * sizeof *kept + 1), nk = 0;
    for (uint32_t i = 0; i < n; i++) {
        map[i] = i;
        for (uint32_t j = 0; j < nk; j++) {
            const float *a = v[kept[j]], *b = v[i];
            double dx = (double)a[0] - b[0], dy = (double)a[1] - b[1], dz = (double)a[2] - b[2];
            if (dx * dx + dy * dy + dz * dz <= eps * eps) {
                map[i] = kept[j];
                break;
            }
        }
        if (map[i] == i) kept[nk++] = i;
    }
    free(kept);
}

/* A copy of m (mesh_weld replaces its arrays). */
static mesh copy_of(const mesh *m)
{
    mesh c = *m;
    c.vertices = malloc(m->n_vertices * sizeof *c.vertices + 1);
    c.triangles = malloc(m->n_triangles * sizeof *c.triangles + 1);
    memcpy(c.vertices, m->vertices, m->n_vertices * sizeof *c.vertices);
    memcpy(c.triangles, m->triangles, m->n_triangles * sizeof *c.triangles);
    return c;
}

/* mesh_weld(m, eps) gives the mesh of the oracle's map (map[i]: the kept
 * vertex i goes to); returns the vertices kept. */
static uint32_t check_map(const mesh *m, double eps, const uint32_t *map, const char *what)
{
    uint32_t n = m->n_vertices;
    uint32_t *renum = malloc(n * sizeof *renum + 1), nk = 0;
    for (uint32_t i = 0; i < n; i++)
        if (map[i] == i) renum[i] = nk++;
    mesh w = copy_of(m);
    uint32_t merged = 0;
    int rc = mesh_weld(&w, eps, &merged);
    cr_assert_eq(rc, 0, "%s: mesh_weld %d", what, rc);
    cr_assert_eq(w.n_vertices, nk, "%s: %u vertices, brute force %u", what, w.n_vertices, nk);
    cr_assert_eq(merged, n - nk, "%s", what);
    for (uint32_t i = 0; i < n; i++)
        if (map[i] == i)
            cr_assert_eq(memcmp(w.vertices[renum[i]], m->vertices[i], sizeof *w.vertices), 0,
                         "%s: vertex %u", what, i);
    uint32_t kept = 0;
    float lo[3] = {FLT_MAX, FLT_MAX, FLT_MAX}, hi[3] = {-FLT_MAX, -FLT_MAX, -FLT_MAX};
    for (uint32_t i = 0; i < m->n_triangles; i++) {
        uint32_t t[3];
        for (int k = 0; k < 3; k++) t[k] = map[m->triangles[i][k]];
        if (shape_degenerate(m->vertices, t)) continue;
        cr_assert_lt(kept, w.n_triangles, "%s", what);
        for (int k = 0; k < 3; k++) {
            cr_assert_eq(w.triangles[kept][k], renum[t[k]], "%s: triangle %u", what, i);
            for (int a = 0; a < 3; a++) { /* the first of equal values (-0, +0) */
                float x = m->vertices[t[k]][a];
                lo[a] = x < lo[a] ? x : lo[a];
                hi[a] = x > hi[a] ? x : hi[a];
            }
        }
        kept++;
    }
    /* the box of the triangles left, to the bit */
    cr_assert(!memcmp(w.lo, lo, sizeof lo) && !memcmp(w.hi, hi, sizeof hi), "%s: box", what);
    cr_assert_eq(kept, w.n_triangles, "%s: %u triangles, brute force %u", what, w.n_triangles,
                 kept);
    cr_assert_eq(w.n_degenerate, m->n_degenerate + (m->n_triangles - kept), "%s", what);
    mesh_free(&w);
    free(renum);
    return nk;
}

/* mesh_weld(m, eps) gives the brute force's mesh; returns the vertices kept. */
static uint32_t check_weld(const mesh *m, double eps, const char *what)
{
    uint32_t *map = malloc(m->n_vertices * sizeof *map + 1);
    brute_map(m->vertices, m->n_vertices, eps, map);
    uint32_t nk = check_map(m, eps, map, what);
    free(map);
    return nk;
}

/* ---------------------------------------------------------- the meshes */

static double urand(uint64_t *s)
{
    *s = *s * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(*s >> 11) / 9007199254740992.0;
}

/* Every triangle of m with its own three vertices, each coordinate moved
 * by up to jitter. */
static void soup_of(const mesh *m, double jitter, uint64_t seed, shape *out)
{
    shape_init(out);
    for (uint32_t i = 0; i < m->n_triangles; i++) {
        uint32_t c[3];
        for (int k = 0; k < 3; k++) {
            const float *p = m->vertices[m->triangles[i][k]];
            c[k] = shape_vertex(out, 0, 0, 0);
            for (int a = 0; a < 3; a++)
                out->m.vertices[c[k]][a] = (float)(p[a] + jitter * (2 * urand(&seed) - 1));
        }
        shape_tri(out, c[0], c[1], c[2]);
    }
    shape_finish(out);
}

Test(mesh_weld, a_jittered_soup_closes_again)
{
    shape ico, soup;
    shape_init(&ico);
    shape_icosphere(&ico, (double[3]){0.25, -0.5, 1}, 1, 3, false); /* 1280 triangles */
    const mesh *m = shape_finish(&ico);
    soup_of(m, 1e-4, 7, &soup);
    mesh_topo t;
    cr_assert_eq(mesh_topology(&soup.m, &t), 0);
    cr_assert_eq(t.open, 3 * 1280ull, "the soup: every edge open");
    /* copies of one vertex lie within 2e-4 sqrt(3); distinct ones ~0.1 apart */
    cr_assert_eq(check_weld(&soup.m, 1e-3, "soup"), m->n_vertices);
    mesh w = copy_of(&soup.m);
    cr_assert_eq(mesh_weld(&w, 1e-3, NULL), 0);
    cr_assert_eq(mesh_topology(&w, &t), 0);
    cr_assert(t.watertight, "welded soup: %llu open", (unsigned long long)t.open);
    cr_assert_eq(t.edges, 3 * 1280ull / 2);
    mesh_free(&w);
    /* a weld smaller than the jitter leaves it open, and still agrees */
    check_weld(&soup.m, 1e-6, "soup, eps below the jitter");
    shape_free(&soup);
    shape_free(&ico);
    /* exact copies, a zero coordinate written -0 in every other copy: eps
     * = 0 merges them all */
    shape_init(&ico);
    shape_icosphere(&ico, (double[3]){0, 0, 0}, 1, 2, false);
    m = shape_finish(&ico);
    soup_of(m, 0, 1, &soup);
    int zeros = 0;
    for (uint32_t i = 1; i < soup.m.n_vertices; i += 2)
        for (int a = 0; a < 3; a++)
            if (soup.m.vertices[i][a] == 0) soup.m.vertices[i][a] = -0.0f, zeros++;
    cr_assert_gt(zeros, 10);
    cr_assert_eq(check_weld(&soup.m, 0, "exact soup"), m->n_vertices);
    shape_free(&soup);
    shape_free(&ico);
}

/* n random points in a box of side `side` around c, random triangles over them. */
static void cloud(shape *s, uint32_t n, uint32_t nt, const double c[3], double side, uint64_t seed)
{
    shape_init(s);
    for (uint32_t i = 0; i < n; i++) {
        uint32_t v = shape_vertex(s, 0, 0, 0);
        for (int a = 0; a < 3; a++)
            s->m.vertices[v][a] = (float)(c[a] + side * (urand(&seed) - 0.5));
    }
    for (uint32_t i = 0; i < nt; i++)
        shape_tri(s, (uint32_t)(urand(&seed) * n), (uint32_t)(urand(&seed) * n),
                  (uint32_t)(urand(&seed) * n));
    shape_finish(s);
}

Test(mesh_weld, dense_clusters_follow_the_greedy_order)
{
    static const struct {
        double c[3], side, eps;
    } cases[] = {
        {{0, 0, 0}, 1, 0.05},        /* many candidates a vertex */
        {{0, 0, 0}, 1, 0.2},
        {{-3, 7, 0.5}, 0.01, 3e-4},
        {{1e7, -1e7, 3e6}, 64, 2},   /* float spacing 1 there: cells past 2^20 */
        {{2e30, 0, 0}, 1e25, 1e-3},  /* cells far past 2^40: equal coordinates only */
        {{0, 0, 0}, 1e-28, 1e-30},   /* the smallest eps, on tiny coordinates */
    };
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        shape s;
        cloud(&s, 3000, 3000, cases[i].c, cases[i].side, 11 + i);
        char what[64];
        snprintf(what, sizeof what, "cloud %zu", i);
        uint32_t nk = check_weld(&s.m, cases[i].eps, what);
        if (i < 3) cr_assert(nk < 3000 && nk > 10, "%s: %u kept", what, nk);
        shape_free(&s);
    }
}

/* Neighbours exactly eps apart (a power of two: exact) merge; points on
 * the cells' borders. */
Test(mesh_weld, a_lattice_eps_apart)
{
    shape s;
    shape_init(&s);
    for (int z = -4; z < 4; z++)
        for (int y = -4; y < 4; y++)
            for (int x = -4; x < 4; x++) shape_vertex(&s, x / 8.0, y / 8.0, z / 8.0);
    uint64_t seed = 3;
    for (int i = 0; i < 600; i++)
        shape_tri(&s, (uint32_t)(urand(&seed) * 512), (uint32_t)(urand(&seed) * 512),
                  (uint32_t)(urand(&seed) * 512));
    shape_finish(&s);
    cr_assert_lt(check_weld(&s.m, 0.125, "lattice at eps"), 512);
    cr_assert_eq(check_weld(&s.m, 0.124, "lattice below eps"), 512);
    check_weld(&s.m, 0.125 * sqrt(3.0), "lattice at the diagonal");
    shape_free(&s);
}

Test(mesh_weld, bad_eps_and_a_weld_that_leaves_nothing)
{
    shape s;
    shape_init(&s);
    shape_icosphere(&s, (double[3]){0, 0, 0}, 1, 1, false);
    shape_finish(&s);
    /* the protocol's range is mesh_weld's (clang takes no double in a
     * _Static_assert) */
    cr_assert(PROTO_MIN_WELD == MESH_WELD_MIN && PROTO_MAX_WELD == MESH_WELD_MAX);
    mesh w = copy_of(&s.m);
    const double bad[] = {-1, NAN, INFINITY, 1e-31, 2e30, -0.5e-30};
    for (size_t i = 0; i < sizeof bad / sizeof *bad; i++)
        cr_assert_eq(mesh_weld(&w, bad[i], NULL), -EINVAL, "eps %g", bad[i]);
    /* every vertex into one: every triangle degenerate */
    cr_assert_eq(mesh_weld(&w, 10, NULL), -EINVAL);
    cr_assert_eq(w.n_vertices, s.m.n_vertices, "the mesh unchanged");
    cr_assert_eq(memcmp(w.vertices, s.m.vertices, w.n_vertices * sizeof *w.vertices), 0);
    /* a closed mesh with no duplicate: nothing merged, the same mesh */
    uint32_t merged = 1;
    cr_assert_eq(mesh_weld(&w, 1e-3, &merged), 0);
    cr_assert_eq(merged, 0);
    cr_assert_eq(w.n_triangles, s.m.n_triangles);
    cr_assert_eq(memcmp(w.triangles, s.m.triangles, w.n_triangles * sizeof *w.triangles), 0);
    for (int a = 0; a < 3; a++) cr_assert(w.lo[a] == s.m.lo[a] && w.hi[a] == s.m.hi[a]);
    mesh_free(&w);
    shape_free(&s);
}

/* ---------------------------------------------- eps = 0 on every CPU */

/* The exact weld's oracle for many vertices: the vertices sorted by their
 * position (-0 as 0), then by index; each goes to the first of its run. */
static const float (*sort_v)[3];

static int by_position(const void *a, const void *b)
{
    uint32_t i = *(const uint32_t *)a, j = *(const uint32_t *)b;
    for (int k = 0; k < 3; k++) {
        double x = sort_v[i][k] + 0.0, y = sort_v[j][k] + 0.0;
        if (x != y) return x < y ? -1 : 1;
    }
    return (i > j) - (i < j);
}

static void sorted_map(float (*v)[3], uint32_t n, uint32_t *map)
{
    uint32_t *ord = malloc(n * sizeof *ord + 1);
    for (uint32_t i = 0; i < n; i++) ord[i] = i;
    sort_v = (const float (*)[3])v;
    qsort(ord, n, sizeof *ord, by_position);
    for (uint32_t r = 0; r < n; r++) {
        bool same = r > 0;
        for (int k = 0; k < 3 && same; k++) same = v[ord[r]][k] + 0.0 == v[ord[r - 1]][k] + 0.0;
        map[ord[r]] = same ? map[ord[r - 1]] : ord[r];
    }
    free(ord);
}

/* malloc through this wrapper (this binary alone is linked with
 * -Wl,--wrap=malloc: the Makefile says so): the first allocation of
 * fail_size bytes, when armed, fails; every other passes on. */
void *__real_malloc(size_t size);
void *__wrap_malloc(size_t size);
static _Atomic size_t fail_size;
static _Atomic int failures;

void *__wrap_malloc(size_t size)
{
    size_t want = size;
    if (size && atomic_compare_exchange_strong(&fail_size, &want, 0)) {
        failures++;
        return NULL;
    }
    return __real_malloc(size);
}

/* 200,000 vertices drawn from 40,000 positions (a zero coordinate written
 * -0 in some copies), above the size the weld runs on every CPU from:
 * the map is the sorted oracle's, and the parallel path ran; or, with a
 * part's table refused (fail_part), the weld on one thread gives it. */
static void exact_weld_many(bool fail_part)
{
    enum { N = 200000, DISTINCT = 40000, TRIS = 150000 };
    float (*pos)[3] = malloc(DISTINCT * sizeof *pos);
    uint64_t seed = 5;
    for (uint32_t i = 0; i < DISTINCT; i++)
        for (int a = 0; a < 3; a++)
            pos[i][a] = urand(&seed) < 0.1 ? 0.0f : (float)(urand(&seed) * 8 - 4);
    shape s;
    shape_init(&s);
    for (uint32_t i = 0; i < N; i++) {
        uint32_t v = shape_vertex(&s, 0, 0, 0), from = (uint32_t)(urand(&seed) * DISTINCT);
        for (int a = 0; a < 3; a++) {
            float x = pos[from][a];
            s.m.vertices[v][a] = x == 0 && urand(&seed) < 0.5 ? -0.0f : x;
        }
    }
    for (uint32_t i = 0; i < TRIS; i++)
        shape_tri(&s, (uint32_t)(urand(&seed) * N), (uint32_t)(urand(&seed) * N),
                  (uint32_t)(urand(&seed) * N));
    shape_finish(&s);
    uint32_t *map = malloc(N * sizeof *map);
    sorted_map(s.m.vertices, N, map);
    uint64_t runs = atomic_load(&mesh_weld_par_runs);
    if (fail_part) {
        /* a part's table as mesh_weld.c sizes it: a power of two of 8-byte
         * slots, at least twice the part's share of the vertices */
        unsigned parts = par_cpus() < 8 ? par_cpus() : 8;
        size_t slots = 16;
        while (slots < 2 * ((size_t)N / parts + 1)) slots *= 2;
        failures = 0;
        fail_size = slots * 8;
    }
    uint32_t nk = check_map(&s.m, 0, map, fail_part ? "exact, a part refused" : "exact, many");
    cr_assert(nk > DISTINCT / 2 && nk <= DISTINCT, "%u kept", nk);
    if (fail_part) {
        cr_assert_eq(failures, 1, "the part's table refused once");
        cr_assert_eq(atomic_load(&mesh_weld_par_runs), runs, "not counted as welded on every CPU");
    } else {
        cr_assert_eq(atomic_load(&mesh_weld_par_runs), runs + 1, "not welded on every CPU");
    }
    free(map);
    free(pos);
    shape_free(&s);
}

Test(mesh_weld, an_exact_weld_on_every_cpu_is_the_oracles)
{
    exact_weld_many(false);
}

Test(mesh_weld, a_part_without_its_table_leaves_the_weld_to_one_thread)
{
    cr_assert_geq(par_cpus(), 2, "the weld runs on every CPU only where there are two");
    exact_weld_many(true);
}
