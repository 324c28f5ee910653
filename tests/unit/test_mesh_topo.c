/* Degenerate triangles dropped and counted, STL's welding (equal positions, the
 * two zeros, a large grid), the float parser against strtof (near the halfway
 * points between floats too), and mesh_topology: a closed cube, one with a
 * triangle removed or flipped, a non-manifold fan, two components, the signed
 * volume, and the edge counts against every pair of uses. */
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

#include "mesh_load_fixture.h"

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
    int rc = mesh_text_float(&t, &got);
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
