/* mesh_wcap — the winding number of an open mesh as an integer count and
 * the solid angles of small caps: the repair's fast path (K = 1 blocks).
 *
 * The triangles' boundary chain B (each edge a -> b counted +1 per
 * triangle that runs a -> b and -1 per triangle that runs b -> a; on a
 * closed mesh every edge cancels) is closed, so every connected piece of
 * it bounds a cap: the fan of its edges to one point o (the mean of its
 * vertices, on the lattice), edge a -> b giving the triangle (b, a, o).
 * The mesh S with its caps C is closed (its boundary B - B = 0), so its
 * winding number is the signed count of the crossings of any ray from p,
 *     w_S(p) + w_C(p) = N(p),
 * N counted along -z by the same exact raster as the parity (mesh_vox_target's
 * counters, the caps rasterized beside the tile's triangles: S and C share
 * the snapped vertices, so the raster sees one closed surface).  Hence
 *     |w_S(p)| >= 1/2  <=>  |N(p) - w_C(p)| >= 1/2,
 * and where w_C stays within (k - 1/2, k + 1/2) over a cell of samples,
 * every sample of the cell is inside exactly when N != k: one query of
 * the caps' tree (mesh_vox_wind_cell, rigorous bound) decides a whole cell,
 * wherever the mesh's own surface lies.  Near a cap the query leaves the
 * cap triangles within reach out (its near list) and each sample adds
 * their exact angles to the rest's value and bound; a cell still
 * undecided is split in eight, down to single samples.  The caps are
 * small where the holes are (the dragon's are a triangle each).  Samples
 * within 1e-6 of 1/2 past the bound, or too near a cap triangle for the
 * sign of its angle to be trusted against the raster's side, go to
 * mesh_vox_wind_block (the tree, then the exact sum near 1/2): the answer stays
 * the exact sum's where it matters.
 *
 * Where the caps are few (at most DIRECT_MAX triangles: a few large
 * holes) the tree is left aside: every cell takes every cap triangle,
 * w_C's exact value at its centre, its gradient by Biot and Savart over
 * the boundary, and Taylor's remainder bounded per boundary segment
 * (mesh_vox_wcap_expand), which a large cap's area does not feed; the cell is
 * decided whole, or sample by sample from the linear expansion, and the
 * samples left go to its eight halves.
 *
 * The angles use the mesh's vertices as given and the raster their
 * snapped copies (within 2^-17 voxel): the two agree but for points that
 * close to a triangle, where the raster's tie rule decides (as the parity
 * does).
 */
#include "mesh_vox_int.h"

#include <errno.h>
#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

int mesh_wind_exact;
int mesh_wcap_tree_only;
_Atomic uint64_t mesh_wcap_to_exact;

/* Built lazily, by the first tile that needs each part, so that the build
 * ticks that tile's heartbeat (a worker builds its own at its first tile
 * of a job: seconds of wall time for a large mesh on a loaded machine). */
struct mesh_wtree {
    mesh m;                   /* the job's mesh (its arrays outlive the tiles) */
    grid_spec g;
    int tris_rc, caps_rc;     /* 1: not built yet; else the build's return */
    mesh_vox_wtree *tris;           /* the mesh's triangles (mesh_wind.c) */
    mesh_vox_wtree *caps;           /* the caps' triangles, or NULL: none */
    int64_t (*cap_lat)[3][3]; /* the caps on the K = 1 lattice */
    double (*cap_vt)[3][3];   /* the caps in voxel units when at most
                                 DIRECT_MAX (mesh_vox_wcap_block's direct path),
                                 else NULL: the tree's */
    double (*cap_ball)[4];    /* ... and a ball about each (centre, radius) */
    uint32_t n_caps;
};

#define DIRECT_MAX 1024u /* cap triangles at most for the direct path */

/* ---- the boundary chain and its caps ---- */

typedef struct {
    uint64_t key; /* lo << 32 | hi, lo < hi: an edge's vertices */
    int32_t s;    /* +1: the triangle runs lo -> hi, -1: hi -> lo */
} dedge;

static int u32_cmp(const void *x, const void *y)
{
    uint32_t a = *(const uint32_t *)x, b = *(const uint32_t *)y;
    return (a > b) - (a < b);
}

/* h[0, n) ascending (insertion: a vertex has a few edges; qsort past 32). */
static void sort_bucket(uint32_t *h, size_t n)
{
    if (n > 32) {
        qsort(h, n, sizeof *h, u32_cmp);
        return;
    }
    for (size_t i = 1; i < n; i++) {
        uint32_t x = h[i];
        size_t j = i;
        for (; j > 0 && h[j - 1] > x; j--) h[j] = h[j - 1];
        h[j] = x;
    }
}

/* Bucket lo's edges h[0, n) (hi << 1, 1: the triangle runs hi -> lo),
 * sorted, summed per edge into e (room grown as needed).  -ENOMEM. */
static int bucket_edges(uint32_t lo, uint32_t *h, size_t n, dedge **e, size_t *ne, size_t *cap)
{
    sort_bucket(h, n);
    for (size_t i = 0; i < n;) {
        int64_t c = 0;
        size_t j = i;
        for (; j < n && h[j] >> 1 == h[i] >> 1; j++) c += h[j] & 1 ? -1 : 1;
        if (c && *ne == *cap) {
            size_t grown = *cap ? 2 * *cap : 1024;
            dedge *g = realloc(*e, grown * sizeof *g);
            if (!g) return -ENOMEM;
            *e = g, *cap = grown;
        }
        if (c) (*e)[(*ne)++] = (dedge){(uint64_t)lo << 32 | (h[i] >> 1), (int32_t)c};
        i = j;
    }
    return 0;
}

/* The chain's edges with their multiplicities, a -> b for c > 0, into
 * (*out)[0, *nb) sorted by key: the triangles' edges counted into one
 * bucket a lower vertex (4 bytes an edge, where a sort of whole edges
 * took 32: the scatter's misses are most of the time), each bucket then
 * sorted and summed; -ENOMEM, -E2BIG past 2^31 vertices (hi << 1 | 1
 * must fit 32 bits; the repair then takes the mesh's tree). */
static int boundary(const mesh *m, dedge **out, size_t *nb)
{
    size_t n = 3 * (size_t)m->n_triangles, cap = 0;
    *out = NULL, *nb = 0;
    if (m->n_vertices > UINT32_MAX / 2) return -E2BIG;
    size_t *at = calloc((size_t)m->n_vertices + 1, sizeof *at);
    uint32_t *h = malloc(n * sizeof *h);
    int rc = at && h ? 0 : -ENOMEM;
    for (int pass = 0; !rc && pass < 2; pass++) {
        for (uint32_t t = 0; t < m->n_triangles; t++)
            for (int i = 0; i < 3; i++) {
                uint32_t a = m->triangles[t][i], b = m->triangles[t][(i + 1) % 3];
                if (a == b) continue;
                uint32_t lo = a < b ? a : b, hi = a < b ? b : a;
                if (pass) h[at[lo]++] = hi << 1 | (a > b);
                else at[lo + 1]++;
            }
        for (uint32_t v = 0; !pass && v < m->n_vertices; v++) at[v + 1] += at[v];
    }
    for (uint32_t v = 0; !rc && v < m->n_vertices; v++) { /* at[v]: now bucket v's end */
        size_t first = v ? at[v - 1] : 0;
        rc = bucket_edges(v, h + first, at[v] - first, out, nb, &cap);
    }
    free(at), free(h);
    if (rc) free(*out), *out = NULL, *nb = 0;
    return rc;
}

static uint32_t find(uint32_t *up, uint32_t v)
{
    while (up[v] != v) v = up[v] = up[up[v]];
    return v;
}

static void vox_of(const mesh *m, const grid_spec *g, uint32_t v, double p[3])
{
    for (int a = 0; a < 3; a++) p[a] = ((double)m->vertices[v][a] - g->lo[a]) / g->vs;
}

/* The fan points: per piece of the chain (union-find over its vertices)
 * the mean of its edges' ends, snapped to the lattice.  The chain's
 * vertices are numbered densely in the order its edges first name them,
 * so that the arrays hold them alone (arrays over every vertex of the mesh
 * made most of the caps' build: their pages); the pieces, and each one's
 * sum in its order, are those of the vertices themselves. */
typedef struct {
    uint32_t *num;   /* a vertex's number + 1; 0: not on the chain */
    uint32_t *up;    /* the union-find over the numbers */
    int64_t (*o)[3]; /* o[root]: the fan point of the root's piece, lattice units */
} fans;

static uint32_t edge_end(const dedge *e, int h)
{
    return h ? (uint32_t)e->key : (uint32_t)(e->key >> 32);
}

static uint32_t fan_root(const fans *f, uint32_t v)
{
    return find(f->up, f->num[v] - 1);
}

static void fans_free(fans *f)
{
    free(f->num), free(f->up), free(f->o);
}

static int fan_points(const mesh *m, const grid_spec *g, const dedge *e, size_t nb, fans *f)
{
    size_t nv = 0;
    f->num = calloc(m->n_vertices, sizeof *f->num);
    f->up = malloc(2 * nb * sizeof *f->up);
    f->o = malloc(2 * nb * sizeof *f->o);
    double(*sum)[4] = calloc(2 * nb, sizeof *sum);
    if (!f->num || !f->up || !f->o || !sum) {
        fans_free(f), free(sum);
        return -ENOMEM;
    }
    for (size_t i = 0; i < nb; i++)
        for (int h = 0; h < 2; h++) {
            uint32_t v = edge_end(&e[i], h);
            if (!f->num[v]) f->up[nv] = (uint32_t)nv, f->num[v] = (uint32_t)++nv;
        }
    for (size_t i = 0; i < nb; i++) {
        uint32_t a = fan_root(f, edge_end(&e[i], 0)), b = fan_root(f, edge_end(&e[i], 1));
        if (a != b) f->up[a > b ? a : b] = a < b ? a : b; /* the smaller number is the root */
    }
    for (size_t i = 0; i < nb; i++)
        for (int h = 0; h < 2; h++) {
            uint32_t v = edge_end(&e[i], h), r = fan_root(f, v);
            double p[3];
            vox_of(m, g, v, p);
            for (int a = 0; a < 3; a++) sum[r][a] += p[a];
            sum[r][3] += 1;
        }
    for (size_t k = 0; k < nv; k++)
        if (sum[k][3] > 0)
            for (int a = 0; a < 3; a++) f->o[k][a] = mesh_vox_snap(sum[k][a] / sum[k][3] * (double)MESH_VOX_L);
    free(sum);
    return 0;
}

/* The n caps vt into t for the direct path, with their balls. */
static int keep_caps(mesh_wtree *t, double (*vt)[3][3], size_t n)
{
    t->cap_vt = vt;
    t->cap_ball = malloc(n * sizeof *t->cap_ball);
    if (!t->cap_ball) return -ENOMEM;
    for (size_t k = 0; k < n; k++) {
        double *o = t->cap_ball[k], r2 = 0;
        for (int a = 0; a < 3; a++) o[a] = (vt[k][0][a] + vt[k][1][a] + vt[k][2][a]) / 3;
        for (int i = 0; i < 3; i++) {
            double s = 0;
            for (int a = 0; a < 3; a++) s += (vt[k][i][a] - o[a]) * (vt[k][i][a] - o[a]);
            r2 = s > r2 ? s : r2;
        }
        o[3] = sqrt(r2) * (1 + 1e-9) + 1e-9;
    }
    return 0;
}

/* The caps of t's mesh: the fans of the chain e[0, nb), as voxel-unit
 * triangles (the tree's) and lattice ones (the raster's). */
static int make_caps(mesh_wtree *t, const mesh *m, const grid_spec *g, const dedge *e, size_t nb,
                     mesh_vox_pulse *pulse)
{
    fans f = {NULL, NULL, NULL};
    size_t n = 0;
    for (size_t i = 0; i < nb; i++) n += (size_t)abs(e[i].s);
    if (!n) return 0;
    if (n > UINT32_MAX) return -ENOMEM;
    int rc = fan_points(m, g, e, nb, &f);
    if (rc) return rc;
    double(*vt)[3][3] = malloc(n * sizeof *vt);
    t->cap_lat = malloc(n * sizeof *t->cap_lat);
    double scale = (double)1u * (double)MESH_VOX_L / g->vs; /* mesh_vox_frame_init's, K = 1 */
    for (size_t i = 0, k = 0; vt && t->cap_lat && i < nb; i++) {
        uint32_t lo = (uint32_t)(e[i].key >> 32), hi = (uint32_t)e[i].key;
        uint32_t v[2] = {e[i].s > 0 ? hi : lo, e[i].s > 0 ? lo : hi}; /* (b, a) of a -> b */
        const int64_t *c = f.o[fan_root(&f, lo)];
        for (int r = 0; r < abs(e[i].s); r++, k++) {
            for (int j = 0; j < 2; j++) {
                vox_of(m, g, v[j], vt[k][j]);
                for (int a = 0; a < 3; a++) /* mesh_vox_vertex's snap: the mesh's lattice */
                    t->cap_lat[k][j][a] =
                        mesh_vox_snap(((double)m->vertices[v[j]][a] - g->lo[a]) * scale);
            }
            for (int a = 0; a < 3; a++) {
                t->cap_lat[k][2][a] = c[a];
                vt[k][2][a] = (double)c[a] / (double)MESH_VOX_L; /* exact */
            }
        }
    }
    rc = vt && t->cap_lat
             ? mesh_vox_wtree_make(NULL, g, (const double (*)[3][3])vt, (uint32_t)n, pulse, &t->caps)
             : -ENOMEM;
    t->n_caps = rc ? 0 : (uint32_t)n;
    if (!rc && n <= DIRECT_MAX) rc = keep_caps(t, vt, n), vt = NULL;
    free(vt), fans_free(&f);
    return rc;
}

int mesh_wtree_build(const mesh *m, const grid_spec *g, mesh_wtree **out)
{
    *out = NULL;
    if (!m->n_triangles) return -EINVAL;
    mesh_wtree *t = calloc(1, sizeof *t);
    if (!t) return -ENOMEM;
    t->m = *m;
    t->g = *g;
    t->tris_rc = t->caps_rc = 1;
    *out = t;
    return 0;
}

/* The parts of t a tile needs, built on first use (t is the caller's
 * alone: one tile at a time reads it).  0 or -ENOMEM. */
static int need_tris(const mesh_wtree *ct, mesh_vox_pulse *pulse)
{
    mesh_wtree *t = (mesh_wtree *)ct; /* const for the tiles: built once, then read */
    if (t->tris_rc == 1) t->tris_rc = mesh_vox_wtree_make(&t->m, &t->g, NULL, 0, pulse, &t->tris);
    return t->tris_rc;
}

static int need_caps(const mesh_wtree *ct, mesh_vox_pulse *pulse)
{
    mesh_wtree *t = (mesh_wtree *)ct;
    if (t->caps_rc != 1) return t->caps_rc;
    dedge *e = NULL;
    size_t nb = 0;
    int rc = boundary(&t->m, &e, &nb);
    mesh_vox_beat(pulse, (uint32_t)(t->m.n_triangles / 4));
    if (!rc) rc = make_caps(t, &t->m, &t->g, e, nb, pulse);
    free(e);
    return t->caps_rc = rc;
}

int mesh_vox_wcap_ready(const mesh_vox_frame *f)
{
    return need_caps(f->caps, f->pulse);
}

/* Whether cap P can cross a ray along axis r of block b: its box across r
 * meets the block's rays, and it starts before the block's end along r
 * (the rays run from -infinity; the raster drops what it does not cross). */
static bool cap_meets(const int64_t P[3][3], int r, const mesh_vox_block *b)
{
    for (int a = 0; a < 3; a++) {
        int64_t lo = (int64_t)b->s0[a] * MESH_VOX_L, hi = (int64_t)(b->s0[a] + b->n[a]) * MESH_VOX_L;
        bool below = P[0][a] < lo && P[1][a] < lo && P[2][a] < lo;
        bool above = P[0][a] > hi && P[1][a] > hi && P[2][a] > hi;
        if (above || (a != r && below)) return false;
    }
    return true;
}

void mesh_vox_wcap_parities(const mesh_vox_frame *f, const mesh_vox_block *b, uint64_t *cz,
                            uint64_t *cx, uint64_t *kx, uint64_t *cy, uint64_t *ky)
{
    const mesh_wtree *t = f->caps;
    memset(cz, 0, mesh_vox_block_words(b) * 8);
    mesh_vox_target tz = {b, cz, NULL, true, NULL}, tx = {b, cx, kx, false, NULL},
                    ty = {b, cy, ky, false, NULL};
    const mesh_vox_target *to[3] = {&tx, &ty, &tz};
    for (uint32_t i = 0; i < t->n_caps; i++) {
        if (mesh_vox_beat(f->pulse, 1)) return;
        for (int r = 0; r < 3; r++)
            if (cap_meets(t->cap_lat[i], r, b)) mesh_vox_raster(t->cap_lat[i], r, to[r]);
    }
    mesh_vox_prefix_z(b, cz, NULL, true);
    mesh_vox_prefix_x(b, cx, kx);
    mesh_vox_prefix_y(b, cy, ky);
}

void mesh_wtree_free(mesh_wtree *t)
{
    if (!t) return;
    mesh_vox_wtree_free(t->tris);
    mesh_vox_wtree_free(t->caps);
    free(t->cap_lat);
    free(t->cap_vt);
    free(t->cap_ball);
    free(t);
}

/* ---- a block's samples ---- */

#define TOP 64u      /* the largest cell tried, samples a side (a word's row; 32:
                        9% more node visits on the holed dragon at 1024^3) */
#define CELL_MIN 4u  /* samples to decide that make a cell worth a query */
#define NEAR_WORK 64u /* near triangles times the cell's samples, at most, for
                         a cell to be tried sample by sample (512: 1.7 times the
                         near angles for 4% fewer nodes and triangles walked) */
#define TOL_SAMPLE 1e-4 /* a node's error at most, a sample's query */
#define TOL_CELL 4e-3   /* ... a cell's (2e-3: 6% more of the descent's work on
                           the holed dragon at 1024^3, 8e-3 as much, 1.6e-2 more) */
#define TOL_MAG 0.02    /* a node's share of a bound of |w_C| over a cell */
#define NEAR 1e-3    /* voxels: nearer a cap triangle, mesh_vox_wind_block decides */
#define MARGIN 1e-6  /* past the bound, nearer 1/2: mesh_vox_wind_block decides */
#define TOL_FINE 1e-6    /* ... a sample's second query */
#define DEPTH 8         /* down_cell's depths (64 samples a side: 7), and fresh()'s */
#define LIST_CAP 4096u  /* nodes, and triangles, handed down at most */

typedef struct {
    const mesh_vox_frame *f;
    const mesh_vox_block *b;
    uint64_t *todo; /* the samples still to decide */
    uint64_t *bits, *spare;
    const uint16_t *count;
    const mesh_vox_wtree *caps;
    mesh_vox_wlist *lists; /* one a depth of down_cell, or NULL */
    bool any_spare;
} cblock;

/* Every sample of the cell to decide: inside when its count is not k. */
static void cell_by_count(cblock *c, const uint32_t lo[3], const uint32_t hi[3], uint16_t k)
{
    mesh_vox_decide d = {c->b, c->todo, c->bits, c->todo, c->count};
    mesh_vox_cell_decide(&d, lo, hi, k);
}

/* Sample bit x of word i (at p) where w_C lies within e of v: decided
 * (and no longer to do) when |N - w_C| keeps off 1/2. */
static void decide(cblock *c, size_t i, unsigned x, double v, double e)
{
    uint64_t bit = 1ull << x;
    double a = fabs((double)(int16_t)c->count[i * 64 + x] - v);
    if (fabs(a - 0.5) <= e + MARGIN) return;
    c->bits[i] = a > 0.5 ? c->bits[i] | bit : c->bits[i] & ~bit;
    c->todo[i] &= ~bit;
}

/* The samples of the cell one by one from a cell query: w_C = v (within
 * e) plus the near triangles' exact angles. */
static void cell_by_near(cblock *c, const uint32_t lo[3], const uint32_t hi[3], const mesh_vox_tris *s,
                         double v, double e)
{
    uint64_t mask = mesh_vox_xmask(lo, hi);
    uint32_t work = 0;
    for (uint32_t z = lo[2]; z < hi[2]; z++)
        for (uint32_t y = lo[1]; y < hi[1]; y++) {
            size_t i = mesh_vox_word(c->b, lo[0], y, z);
            for (uint64_t r = c->todo[i] & mask; r; r &= r - 1) {
                unsigned x = (unsigned)__builtin_ctzll(r);
                double p[3] = {(double)(c->b->s0[0] + (int64_t)(lo[0] / 64 * 64 + x)) + 0.5,
                               (double)(c->b->s0[1] + (int64_t)y) + 0.5,
                               (double)(c->b->s0[2] + (int64_t)z) + 0.5};
                bool close = false;
                double u = v + mesh_vox_wind_tris(c->caps, s, p, NEAR, &close);
                if (!close) decide(c, i, x, u, e);
                work += s->n;
            }
        }
    mesh_vox_beat(c->f->pulse, work);
}

/* The samples of the cell still to do to mesh_vox_wind_block. */
static void cell_spare(cblock *c, const uint32_t lo[3], const uint32_t hi[3])
{
    uint64_t mask = mesh_vox_xmask(lo, hi);
    for (uint32_t z = lo[2]; z < hi[2]; z++)
        for (uint32_t y = lo[1]; y < hi[1]; y++) {
            size_t i = mesh_vox_word(c->b, lo[0], y, z);
            uint64_t d = c->todo[i] & mask;
            if (!d) continue;
            c->spare[i] |= d;
            c->todo[i] &= ~d;
            c->any_spare = true;
        }
}

/* The eight halves of cell [lo, hi) (those with samples) to fn. */
static void split(cblock *c, const uint32_t lo[3], const uint32_t hi[3],
                  void (*fn)(cblock *, const uint32_t *, const uint32_t *))
{
    for (int q = 0; q < 8; q++) {
        uint32_t clo[3], chi[3];
        if (mesh_vox_half(lo, hi, q, clo, chi)) fn(c, clo, chi);
    }
}

/* The cell decided by its counts when w_C = v within e keeps off every
 * half integer. */
static bool try_count(cblock *c, const uint32_t lo[3], const uint32_t hi[3], double v, double e)
{
    double k = floor(v + 0.5);
    if (!(v - e > k - 0.5 && v + e < k + 0.5)) return false;
    cell_by_count(c, lo, hi, (uint16_t)(int64_t)k);
    return true;
}

/* Cell [lo, hi): a query of the caps' tree decides it whole (w_C off
 * every half integer) or sample by sample (near triangles exact), else
 * its eight halves. */
static void cell(cblock *c, const uint32_t *lo, const uint32_t *hi)
{
    uint64_t n = mesh_vox_cell_count(c->b, c->todo, lo, hi);
    if (!n || (c->f->pulse && c->f->pulse->stop)) return;
    uint32_t ext[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    if (!c->caps) { /* closed: w_C = 0 */
        cell_by_count(c, lo, hi, 0);
        mesh_vox_beat(c->f->pulse, (uint32_t)(n / 8 + 1));
        return;
    }
    bool one = ext[0] == 1 && ext[1] == 1 && ext[2] == 1;
    double b[3], r2 = 0, v, e;
    uint32_t work = (uint32_t)(n / 8);
    for (int a = 0; a < 3; a++) {
        b[a] = (double)c->b->s0[a] + 0.5 * ((double)lo[a] + hi[a]);
        r2 += 0.25 * (double)(ext[a] - 1) * (ext[a] - 1);
    }
    double mag;
    mesh_vox_wball q = {{b[0], b[1], b[2]}, sqrt(r2) * (1 + 1e-9), TOL_MAG, 0.45};
    if (!one && mesh_vox_wind_mag(c->caps, &q, &mag, &work)) {
        mesh_vox_beat(c->f->pulse, work);
        cell_by_count(c, lo, hi, 0); /* |w_C| < 1/2 all over */
        return;
    }
    mesh_vox_near nr;
    q.tol = one ? TOL_SAMPLE : TOL_CELL, q.emax = 0.5;
    bool ok = mesh_vox_wind_cell(c->caps, &q, &nr, &v, &e, &work);
    mesh_vox_beat(c->f->pulse, work);
    if (ok && !nr.n && try_count(c, lo, hi, v, e)) return;
    if (ok && (n < CELL_MIN || nr.n * ext[0] * ext[1] * ext[2] <= 4 * NEAR_WORK))
        cell_by_near(c, lo, hi, &(mesh_vox_tris){nr.tri, nr.leaf, nr.n}, v, e);
    if (one) {
        cell_spare(c, lo, hi);
        return;
    }
    split(c, lo, hi, cell);
}

/* Sample lo by a query of the caps' tree from its root, every node taken
 * within tol. */
static void fresh(cblock *c, const uint32_t lo[3], double tol)
{
    uint32_t hi[3] = {lo[0] + 1, lo[1] + 1, lo[2] + 1}, root = 0, work = 0;
    mesh_vox_wball q = {.rho = 0, .tol = tol, .emax = 0.5};
    for (int a = 0; a < 3; a++) q.b[a] = (double)(c->b->s0[a] + (int64_t)lo[a]) + 0.5;
    mesh_vox_wlist top = {.n_node = 1, .node = &root}, *out = &c->lists[DEPTH - 1];
    bool ok = mesh_vox_wind_down(c->caps, &top, &q, out, &work);
    mesh_vox_beat(c->f->pulse, work);
    if (ok)
        cell_by_near(c, lo, hi, &(mesh_vox_tris){out->tri, out->leaf, out->n_tri}, out->w4 / (4 * M_PI),
                     out->e4 / (4 * M_PI) + 1e-9);
}

/* Cell [cl, ch), shrunk to the box of its samples to do, from its
 * parent's far field in (the caps' tree's root for a top cell): the nodes
 * and triangles far enough taken, the rest handed to its halves; decided
 * whole when nothing is left near and w_C keeps off every half integer,
 * else sample by sample when few triangles are left near; a single sample
 * still to do goes to fresh queries, then to mesh_vox_wind_block (a list
 * too long: the cell to cell()). */
static void down_cell(cblock *c, const uint32_t *cl, const uint32_t *ch, const mesh_vox_wlist *in,
                      int depth)
{
    uint32_t lo[3], hi[3]; /* the cell [cl, ch) shrunk to its samples to do */
    uint64_t n = mesh_vox_cell_box(c->b, c->todo, cl, ch, lo, hi);
    if (!n || (c->f->pulse && c->f->pulse->stop)) return;
    uint32_t ext[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]}, work = (uint32_t)(n / 8);
    bool one = ext[0] == 1 && ext[1] == 1 && ext[2] == 1;
    mesh_vox_wball q = {.tol = one ? TOL_SAMPLE : TOL_CELL, .emax = 0.5};
    double r2 = 0;
    for (int a = 0; a < 3; a++) {
        q.b[a] = (double)c->b->s0[a] + 0.5 * ((double)lo[a] + hi[a]);
        r2 += 0.25 * (double)(ext[a] - 1) * (ext[a] - 1);
    }
    q.rho = sqrt(r2) * (1 + 1e-9);
    mesh_vox_wlist *out = &c->lists[depth];
    bool ok = depth < DEPTH - 1 && mesh_vox_wind_down(c->caps, in, &q, out, &work);
    mesh_vox_beat(c->f->pulse, work);
    if (!ok) {
        cell(c, lo, hi);
        return;
    }
    double v = out->w4 / (4 * M_PI), e = out->e4 / (4 * M_PI) + 1e-9; /* and the sums' rounding */
    if (!out->n_node && !out->n_tri && try_count(c, lo, hi, v, e)) return;
    if (!out->n_node && (one || n < CELL_MIN || out->n_tri * ext[0] * ext[1] * ext[2] <= 4 * NEAR_WORK))
        cell_by_near(c, lo, hi, &(mesh_vox_tris){out->tri, out->leaf, out->n_tri}, v, e);
    for (int k = 0; one && k < 2; k++) /* a fresh query, then a finer one */
        if (mesh_vox_cell_count(c->b, c->todo, lo, hi)) fresh(c, lo, k ? TOL_FINE : TOL_SAMPLE);
    if (one) {
        cell_spare(c, lo, hi);
        return;
    }
    for (int h = 0; h < 8; h++) {
        uint32_t clo[3], chi[3];
        if (mesh_vox_half(lo, hi, h, clo, chi)) down_cell(c, clo, chi, out, depth + 1);
    }
}

/* ---- the direct path: few cap triangles, all of them at every cell ---- */

/* The gradient of the solid angle of a surface bounded by the segment
 * a -> b (relative to the point) gains (a x b)(|a| + |b|) / (|a| |b|
 * (|a| |b| + a.b)): Biot and Savart's law of a straight wire. */
static void seg_grad(const double a[3], const double b[3], double g[3])
{
    double la = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    double lb = sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
    double s = (la + lb) / (la * lb * (la * lb + a[0] * b[0] + a[1] * b[1] + a[2] * b[2]));
    g[0] += (a[1] * b[2] - a[2] * b[1]) * s;
    g[1] += (a[2] * b[0] - a[0] * b[2]) * s;
    g[2] += (a[0] * b[1] - a[1] * b[0]) * s;
}

/* The distance from the origin to the segment a -> b; its length in *len. */
static double seg_dist(const double a[3], const double b[3], double *len)
{
    double d[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    double dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    double s = dd > 0 ? -(a[0] * d[0] + a[1] * d[1] + a[2] * d[2]) / dd : 0;
    s = s < 0 ? 0 : s > 1 ? 1 : s;
    double q[3] = {a[0] + s * d[0], a[1] + s * d[1], a[2] + s * d[2]};
    *len = sqrt(dd);
    return sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
}


/* The caps' value at b (every triangle's exact angle) and gradient (the
 * boundary's segments, edges 0 -> 1 of the cap triangles: the spokes to
 * the fan points cancel); off the caps w_C is smooth and its second
 * derivative along a unit u is the boundary's integral of
 * dl x D_u((x - p) / |x - p|^3) / (4 pi), at most 2 l / (4 pi d^3) a
 * segment (l its length, d its distance), so Taylor's remainder over the
 * cell is at most the sum of rho^2 l / (4 pi (d - rho)^3) over the
 * segments, d from b.  False where a cap triangle comes within rho + NEAR
 * of b (a cell the caps may cross). */
bool mesh_vox_wcap_expand(const double (*tri)[3][3], const double (*ball)[4], uint32_t n,
                    const double b[3], double rho, mesh_vox_cexp *x)
{
    double h = 0, g[3] = {0, 0, 0}, e = 0, reach = rho + NEAR;
    for (uint32_t k = 0; k < n; k++) {
        const double(*T)[3] = tri[k];
        double r[3][3], l, c2 = 0;
        if (ball) /* its ball says far: no need of the triangle's distance */
            for (int a = 0; a < 3; a++) c2 += (ball[k][a] - b[a]) * (ball[k][a] - b[a]);
        if ((!ball || c2 <= (ball[k][3] + reach) * (ball[k][3] + reach)) &&
            !(mesh_vox_tri_dist(T, b) * (1 - 1e-9) > reach))
            return false;
        for (int i = 0; i < 3; i++)
            for (int a = 0; a < 3; a++) r[i][a] = T[i][a] - b[a];
        double f = seg_dist(r[0], r[1], &l) * (1 - 1e-9) - rho; /* > NEAR: the cap's edge */
        e += l / (f * f * f);
        h += mesh_vox_half_solid_angle(r[0], r[1], r[2]);
        seg_grad(r[0], r[1], g);
    }
    x->v = h / (2 * M_PI);
    for (int a = 0; a < 3; a++) x->g[a] = g[a] / (4 * M_PI);
    x->e = rho * rho * e / (4 * M_PI) + 1e-9; /* and the sums' rounding */
    return true;
}

/* The cell's samples one by one from the expansion x about b. */
static void cell_by_lin(cblock *c, const uint32_t lo[3], const uint32_t hi[3], const double b[3],
                        const mesh_vox_cexp *x)
{
    uint64_t mask = mesh_vox_xmask(lo, hi);
    for (uint32_t z = lo[2]; z < hi[2]; z++)
        for (uint32_t y = lo[1]; y < hi[1]; y++) {
            size_t i = mesh_vox_word(c->b, lo[0], y, z);
            double dz = (double)(c->b->s0[2] + (int64_t)z) + 0.5 - b[2];
            double dy = (double)(c->b->s0[1] + (int64_t)y) + 0.5 - b[1];
            double u0 = x->v + x->g[1] * dy + x->g[2] * dz;
            for (uint64_t r = c->todo[i] & mask; r; r &= r - 1) {
                unsigned xb = (unsigned)__builtin_ctzll(r);
                double dx = (double)(c->b->s0[0] + (int64_t)(lo[0] / 64 * 64 + xb)) + 0.5 - b[0];
                decide(c, i, xb, u0 + x->g[0] * dx, x->e);
            }
        }
}

/* Cell [lo, hi) by the caps' expansion about its centre: whole when it
 * keeps off every half integer, else sample by sample, the samples left
 * to its eight halves; a sample too near a cap to mesh_vox_wind_block. */
static void direct_cell(cblock *c, const uint32_t *lo, const uint32_t *hi)
{
    uint64_t n = mesh_vox_cell_count(c->b, c->todo, lo, hi);
    if (!n || (c->f->pulse && c->f->pulse->stop)) return;
    double b[3], r2 = 0;
    for (int a = 0; a < 3; a++) {
        b[a] = (double)c->b->s0[a] + 0.5 * ((double)lo[a] + hi[a]);
        r2 += 0.25 * (double)(hi[a] - lo[a] - 1) * (hi[a] - lo[a] - 1);
    }
    double rho = sqrt(r2) * (1 + 1e-9);
    const mesh_wtree *t = c->f->wt;
    mesh_vox_cexp x;
    bool ok = mesh_vox_wcap_expand((const double (*)[3][3])t->cap_vt,
                             (const double (*)[4])t->cap_ball, t->n_caps, b, rho, &x);
    mesh_vox_beat(c->f->pulse, c->f->wt->n_caps);
    if (ok) {
        double gn = sqrt(x.g[0] * x.g[0] + x.g[1] * x.g[1] + x.g[2] * x.g[2]);
        if (try_count(c, lo, hi, x.v, gn * rho * (1 + 1e-9) + x.e)) return;
        cell_by_lin(c, lo, hi, b, &x);
    }
    if (r2 == 0) cell_spare(c, lo, hi);
    else split(c, lo, hi, direct_cell);
}

typedef uint16_t u16x8 __attribute__((vector_size(16))); /* eight counts an add */

/* The caps into the counters (those whose x, y box meets the block's),
 * then the prefix sum along z: count = N. */
static void count_caps(const mesh_vox_frame *f, const mesh_wtree *t, const mesh_vox_block *b,
                       uint16_t *count)
{
    mesh_vox_target tc = {b, NULL, NULL, true, count};
    for (uint32_t i = 0; i < t->n_caps; i++) {
        if (mesh_vox_beat(f->pulse, 1)) return;
        if (cap_meets(t->cap_lat[i], 2, b)) mesh_vox_raster(t->cap_lat[i], 2, &tc);
    }
    size_t slice = (size_t)b->n[1] * b->nw * 64;
    for (int32_t z = 1; z < b->n[2]; z++) {
        uint16_t *s = count + (size_t)z * slice, *p = s - slice;
        for (size_t i = 0; i < slice; i += 8) { /* slice: a multiple of 64 */
            u16x8 a, c;
            memcpy(&a, s + i, sizeof a);
            memcpy(&c, p + i, sizeof c);
            a += c; /* modulo 2^16, as the counts are */
            memcpy(s + i, &a, sizeof a);
        }
        mesh_vox_beat(f->pulse, (uint32_t)(slice / 256));
    }
}

/* The samples of word w set in bits r as points (voxel units, K = 1)
 * into q, their bits into idx: how many. */
static unsigned word_points(const mesh_vox_block *b, size_t w, uint64_t r, double q[64][3], unsigned idx[64])
{
    size_t row = w / b->nw, z = row / (size_t)b->n[1], y = row % (size_t)b->n[1];
    unsigned n = 0;
    for (; r; r &= r - 1) {
        unsigned i = (unsigned)__builtin_ctzll(r);
        q[n][0] = (double)(b->s0[0] + (int64_t)((w % b->nw) * 64 + i)) + 0.5;
        q[n][1] = (double)(b->s0[1] + (int64_t)y) + 0.5;
        q[n][2] = (double)(b->s0[2] + (int64_t)z) + 0.5;
        idx[n++] = i;
    }
    return n;
}

/* The samples set in dis by the exact sum, a word at a time (when a
 * tree cannot be had: no memory for it; and the few samples the caps'
 * exact sum leaves). */
static void exact_words(const mesh_vox_frame *f, const mesh_vox_block *b, const uint64_t *dis, uint64_t *bits)
{
    for (size_t w = 0; w < mesh_vox_block_words(b); w++) {
        double q[64][3], wn[64];
        unsigned idx[64], n = dis[w] ? word_points(b, w, dis[w], q, idx) : 0;
        if (!n) continue;
        mesh_vox_winding_many(f, (const double (*)[3])q, n, wn);
        for (unsigned k = 0; k < n; k++)
            bits[w] = fabs(wn[k]) >= 0.5 ? bits[w] | 1ull << idx[k] : bits[w] & ~(1ull << idx[k]);
    }
}

/* The old path: the mesh's tree, sample by sample near 1/2. */
static void by_tree(const mesh_vox_frame *f, const mesh_vox_block *b, const uint64_t *dis, uint64_t *bits)
{
    if (need_tris(f->wt, f->pulse)) exact_words(f, b, dis, bits);
    else mesh_vox_wind_block(f, f->wt->tris, b, dis, bits);
}

/* Half cap triangle P's solid angle at q (voxel units) from its lattice
 * vertices, the raster's own (their differences from q are exact), so
 * that the angle's sign is the raster's side of the cap; *on set where q
 * lies on the closed triangle: in its plane within the rounding of the
 * triple product, and inside it or on an edge or a vertex (there Van
 * Oosterom and Strackee's denominator is negative, or zero: on an edge
 * or a vertex atan2 meets 0 / 0 and rounding, and the angle is not even
 * near +-pi), where the raster's tie rule decides the side. */
static double cap_half_angle(const int64_t P[3][3], const double q[3], bool *on)
{
    double r[3][3], det, den, l;
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++) r[i][a] = (double)P[i][a] / (double)MESH_VOX_L - q[a];
    double h = mesh_vox_half_solid_angle_parts(r[0], r[1], r[2], &det, &den, &l);
    if (fabs(det) <= 1e-12 * l && den <= 1e-9 * l) *on = true; /* in the plane, not outside */
    return h;
}

#define EXACT_MARGIN 1e-6 /* |N - w_C| nearer 1/2 after the caps' exact sum: the mesh's
                             (the angles' lattice vertices move w by 1e-7 and more from
                             the mesh's own: MARGIN's reason; 1e-9 let a sample of
                             |w| = 1/2 - 2e-8 in as 1/2 + 8e-8) */
#define EXACT_WORK 4u     /* a block's spare samples times its caps at most this many
                             times the mesh's triangles: the caps' exact sum, else the tree */

/* The spare samples of word w by the caps' exact winding number,
 * |N - w_C| against 1/2 (w_S = N - w_C exactly where the raster and the
 * angles see the same caps); those on a cap or within EXACT_MARGIN of 1/2
 * stay in spare. */
static void caps_exact(const cblock *c, size_t w)
{
    const mesh_wtree *t = c->f->wt;
    double q[64][3], h[64] = {0};
    unsigned idx[64], n = word_points(c->b, w, c->spare[w], q, idx);
    bool on[64] = {false};
    for (uint32_t i = 0; i < t->n_caps; i++) {
        if (mesh_vox_beat(c->f->pulse, n)) return; /* the tile is abandoned */
        for (unsigned k = 0; k < n; k++) h[k] += cap_half_angle(t->cap_lat[i], q[k], &on[k]);
    }
    for (unsigned k = 0; k < n; k++) {
        double a = fabs((double)(int16_t)c->count[w * 64 + idx[k]] - h[k] / (2 * M_PI));
        if (on[k] || fabs(a - 0.5) <= EXACT_MARGIN) {
            atomic_fetch_add_explicit(&mesh_wcap_to_exact, 1, memory_order_relaxed);
            continue; /* left in spare: exact_words decides it */
        }
        uint64_t bit = 1ull << idx[k];
        c->bits[w] = a > 0.5 ? c->bits[w] | bit : c->bits[w] & ~bit;
        c->spare[w] &= ~bit;
    }
}

/* The samples the caps' walk left (in spare): by the caps' exact sum
 * where they are few, the rest by the mesh's exact sum (no tree to
 * build); many: the mesh's tree. */
static void spare_block(const cblock *c)
{
    size_t nw = mesh_vox_block_words(c->b);
    uint64_t n = 0;
    for (size_t w = 0; w < nw; w++) n += (uint64_t)__builtin_popcountll(c->spare[w]);
    if (n * c->f->wt->n_caps > (uint64_t)EXACT_WORK * c->f->m->n_triangles) {
        by_tree(c->f, c->b, c->spare, c->bits);
        return;
    }
    for (size_t w = 0; w < nw; w++)
        if (c->spare[w]) caps_exact(c, w);
    exact_words(c->f, c->b, c->spare, c->bits);
}

void mesh_vox_wcap_block(const mesh_vox_frame *f, const mesh_vox_block *b, uint64_t *dis, uint64_t *bits,
                   uint16_t *count, uint64_t *spare)
{
    const mesh_wtree *t = f->wt;
    size_t nwords = mesh_vox_block_words(b), i = 0;
    while (i < nwords && !dis[i]) i++;
    if (i == nwords) return;
    if (!count || need_caps(t, f->pulse)) {
        by_tree(f, b, dis, bits);
        return;
    }
    count_caps(f, t, b, count);
    memset(spare, 0, nwords * 8);
    cblock c = {.f = f, .b = b, .todo = dis, .bits = bits, .spare = spare, .count = count,
                .caps = t->caps};
    bool direct = t->cap_vt && !mesh_wcap_tree_only;
    uint32_t root = 0, *room = direct || !t->caps ? NULL : malloc(DEPTH * 3 * LIST_CAP * sizeof *room);
    mesh_vox_wlist lists[DEPTH], top = {.n_node = 1, .node = &root};
    for (int d = 0; room && d < DEPTH; d++)
        lists[d] = (mesh_vox_wlist){.cap = LIST_CAP, .node = room + 3 * d * LIST_CAP,
                                    .tri = room + (3 * d + 1) * LIST_CAP,
                                    .leaf = room + (3 * d + 2) * LIST_CAP};
    c.lists = room ? lists : NULL;
    uint32_t lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    while (mesh_vox_top_next(b, TOP, lo, hi)) {
        if (direct) direct_cell(&c, lo, hi);
        else if (c.lists) down_cell(&c, lo, hi, &top, 0);
        else cell(&c, lo, hi);
    }
    free(room);
    if (c.any_spare) spare_block(&c);
}
