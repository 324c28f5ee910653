/* iso_fixture — what the marching cubes suites (test_iso*.c) share: volumes
 * sampled into VOD files, polygonizing them, the mesh checker (edge-use counts
 * and directions, each vertex's link one cycle, no two vertices at one place,
 * the enclosed volume by the divergence theorem), analytic distances and seeded
 * noise. */
#ifndef VOXD_TEST_ISO_FIXTURE_H
#define VOXD_TEST_ISO_FIXTURE_H

#include <criterion/criterion.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "engine.h"
#include "expr.h"
#include "iso.h"
#include "mesh.h"
#include "vod.h"
#include "vod_volume.h"
#include "voxel.h"

/* ---- VOD files from functions ---- */

typedef uint32_t (*voxel_fn)(void *ud, double x, double y, double z);

typedef struct {
    uint32_t dims[3], brick, bits;
    int channel;
    double h, origin[3];
} vol_spec;

/* The file of fn sampled at the voxel centres (world coordinates). */
static inline vod_file *make_vod(const vol_spec *s, voxel_fn fn, void *ud)
{
    uint32_t vbits = s->bits == 32 ? 32 : 8;
    size_t bytes = vod_volume_bytes(s->dims, vbits, 16, UINT32_MAX);
    void *arena = malloc(bytes);
    vod_volume *v;
    cr_assert_eq(vod_volume_init(&v, arena, bytes, s->dims, vbits, 16), 0);
    for (uint32_t z = 0; z < s->dims[2]; z++)
        for (uint32_t y = 0; y < s->dims[1]; y++)
            for (uint32_t x = 0; x < s->dims[0]; x++) {
                uint32_t val = fn(ud, s->origin[0] + (x + 0.5) * s->h,
                                  s->origin[1] + (y + 0.5) * s->h,
                                  s->origin[2] + (z + 0.5) * s->h);
                if (val) cr_assert_eq(vod_volume_set(v, x, y, z, val), 0);
            }
    vod_params p;
    vod_params_default(&p);
    p.channel = s->channel;
    p.brick = s->brick;
    for (int a = 0; a < 3; a++) {
        p.volume[a] = s->dims[a];
        p.voxel_scale[a] = (float)s->h;
        p.origin[a] = (float)s->origin[a];
    }
    vod_source src = vod_volume_source(v);
    vod_membuf mb = {0};
    vod_sink sink = {vod_mem_write, &mb};
    err_info err = {0};
    cr_assert_eq(vod_write(&src, &p, &sink, NULL, &err), 0, "%s", err.msg);
    vod_file *f;
    cr_assert_eq(vod_read(mb.p, mb.n, &f, &err), 0, "%s", err.msg);
    free(mb.p);
    free(arena);
    return f;
}

static inline void *heap(void *ud, size_t n)
{
    return *(void **)ud = malloc(n);
}

/* The mesh of request rq, in this thread. */
static inline void polygonize_rq(const vod_file *f, const iso_request *rq, iso_mesh *m)
{
    iso_params p;
    err_info err = {0};
    cr_assert_eq(iso_params_make(f, rq, &p, &err), 0, "%s", err.msg);
    void *mem = NULL;
    iso_input in;
    cr_assert_eq(iso_input_make(f, &p, heap, &mem, &in), 0);
    cr_assert_eq(iso_run_serial(&p, &in, m, &err), 0, "%s", err.msg);
    free(mem);
}

/* The mesh of one level at iso. */
static inline void polygonize(const vod_file *f, uint32_t iso, int level, iso_mesh *m)
{
    iso_request rq = {.iso = iso, .level = level};
    polygonize_rq(f, &rq, m);
}

/* ---- the checker ---- */

typedef struct {
    uint64_t open, nonmanifold, inconsistent, degenerate, bad_links, same_place;
    double volume;
} topo;

typedef struct {
    uint64_t key;
    int dir;
} dedge;

static inline int by_key(const void *a, const void *b)
{
    uint64_t x = ((const dedge *)a)->key, y = ((const dedge *)b)->key;
    return (x > y) - (x < y);
}

static inline void check_edges(const iso_mesh *m, topo *t)
{
    size_t n = 3 * m->n_triangles;
    dedge *e = malloc((n ? n : 1) * sizeof *e);
    for (uint64_t i = 0; i < m->n_triangles; i++)
        for (int k = 0; k < 3; k++) {
            uint32_t a = m->tri[3 * i + k], b = m->tri[3 * i + (k + 1) % 3];
            uint64_t lo = a < b ? a : b, hi = a < b ? b : a;
            e[3 * i + k] = (dedge){lo << 32 | hi, a < b ? 1 : -1};
            if (a == b) t->degenerate++;
        }
    qsort(e, n, sizeof *e, by_key);
    for (size_t i = 0; i < n;) {
        size_t j = i;
        int sum = 0;
        while (j < n && e[j].key == e[i].key) sum += e[j++].dir;
        if (j - i == 1) t->open++;
        else if (j - i > 2) t->nonmanifold++;
        else if (sum != 0) t->inconsistent++;
        i = j;
    }
    free(e);
}

/* Each vertex's link (the edges opposite it in its triangles) must be one
 * cycle: its triangles form a single disk round it. */
typedef struct {
    uint32_t v, from, to;
} link_edge;

static inline int by_vertex(const void *a, const void *b)
{
    const link_edge *x = a, *y = b;
    if (x->v != y->v) return x->v < y->v ? -1 : 1;
    return (x->from > y->from) - (x->from < y->from);
}

static inline int one_cycle(const link_edge *l, size_t n)
{
    uint32_t at = l[0].to;
    for (size_t step = 1; step < n; step++) {
        size_t lo = 0, hi = n; /* l sorted by from */
        while (lo < hi) {
            size_t mid = (lo + hi) / 2;
            if (l[mid].from < at) lo = mid + 1;
            else hi = mid;
        }
        if (lo == n || l[lo].from != at) return 0;
        at = l[lo].to;
        if (at == l[0].from) return step == n - 1;
    }
    return at == l[0].from;
}

static inline void check_links(const iso_mesh *m, topo *t)
{
    size_t n = 3 * m->n_triangles;
    link_edge *l = malloc((n ? n : 1) * sizeof *l);
    for (uint64_t i = 0; i < m->n_triangles; i++)
        for (int k = 0; k < 3; k++)
            l[3 * i + k] = (link_edge){m->tri[3 * i + k], m->tri[3 * i + (k + 1) % 3],
                                       m->tri[3 * i + (k + 2) % 3]};
    qsort(l, n, sizeof *l, by_vertex);
    for (size_t i = 0; i < n;) {
        size_t j = i;
        while (j < n && l[j].v == l[i].v) j++;
        if (!one_cycle(l + i, j - i)) t->bad_links++;
        i = j;
    }
    free(l);
}

static inline int by_pos(const void *a, const void *b)
{
    return memcmp(a, b, 12);
}

static inline void check_places(const iso_mesh *m, topo *t)
{
    float *p = malloc(12 * (m->n_vertices ? m->n_vertices : 1));
    memcpy(p, m->pos, 12 * m->n_vertices);
    qsort(p, m->n_vertices, 12, by_pos);
    for (uint64_t i = 1; i < m->n_vertices; i++)
        if (!memcmp(p + 3 * i, p + 3 * (i - 1), 12)) t->same_place++;
    free(p);
}

static inline topo check(const iso_mesh *m)
{
    topo t = {0};
    check_edges(m, &t);
    check_links(m, &t);
    check_places(m, &t);
    for (uint64_t i = 0; i < m->n_triangles; i++) {
        const float *a = m->pos + 3 * m->tri[3 * i], *b = m->pos + 3 * m->tri[3 * i + 1],
                    *c = m->pos + 3 * m->tri[3 * i + 2];
        t.volume += (a[0] * ((double)b[1] * c[2] - (double)b[2] * c[1]) -
                     a[1] * ((double)b[0] * c[2] - (double)b[2] * c[0]) +
                     a[2] * ((double)b[0] * c[1] - (double)b[1] * c[0])) / 6.0;
    }
    return t;
}

static inline void assert_closed(const iso_mesh *m, const char *what)
{
    topo t = check(m);
    cr_assert_gt(m->n_triangles, 0, "%s: no triangles", what);
    cr_assert(!t.open && !t.nonmanifold && !t.inconsistent && !t.degenerate,
              "%s: %llu open, %llu non-manifold, %llu inconsistent edges, %llu "
              "degenerate triangles", what, (unsigned long long)t.open,
              (unsigned long long)t.nonmanifold, (unsigned long long)t.inconsistent,
              (unsigned long long)t.degenerate);
    cr_assert(!t.bad_links, "%s: %llu vertices whose triangles are not one disk", what,
              (unsigned long long)t.bad_links);
    cr_assert(!t.same_place, "%s: %llu vertices at another's place", what,
              (unsigned long long)t.same_place);
    cr_assert_gt(t.volume, 0, "%s: not oriented outwards (volume %g)", what, t.volume);
}

/* ---- shapes: signed distances as density ramps ---- */

typedef struct {
    double (*dist)(const void *, double, double, double); /* < 0 inside */
    const void *ud;
    double h;
} ramp;

/* Density 127.5 on the surface, 64 per voxel inwards, clamped. */
static inline uint32_t ramp_value(void *ud, double x, double y, double z)
{
    const ramp *r = ud;
    double v = 127.5 - 64.0 * r->dist(r->ud, x, y, z) / r->h;
    return v <= 0 ? 0 : v >= 255 ? 255 : (uint32_t)lround(v);
}

static inline double sphere_dist(const void *ud, double x, double y, double z)
{
    return sqrt(x * x + y * y + z * z) - *(const double *)ud;
}

static inline double torus_dist(const void *ud, double x, double y, double z)
{
    const double *rr = ud;
    double q = sqrt(x * x + y * y) - rr[0];
    return sqrt(q * q + z * z) - rr[1];
}

static inline vol_spec cube_spec(uint32_t n, uint32_t brick, double lo, double hi)
{
    vol_spec s = {{n, n, n}, brick, 8, VOXEL_CH_DENSITY, (hi - lo) / n, {lo, lo, lo}};
    return s;
}

/* ---- the table: random volumes hit every case and every face pairing ---- */

static uint64_t rng = 0x2545f4914f6cdd1dull;

static inline uint32_t rnd(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return (uint32_t)(rng >> 16);
}

static inline uint32_t noise(void *ud, double x, double y, double z)
{
    (void)x, (void)y, (void)z;
    uint32_t mode = *(uint32_t *)ud, v = rnd();
    return mode == 1 ? (v & 1u) : mode == 2 ? (v % 256) : (v & 1u ? VOXEL_FULL : 0);
}

#endif
