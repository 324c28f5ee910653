/* mesh_cpt — the regions of the closest-point transform (Mauch) of a
 * tile's triangles, for the distance channel (mesh_dist.c).
 *
 * A point's nearest point on the mesh lies in the interior of a face, of an
 * edge or at a vertex, and if it lies on feature f, then f holds the
 * nearest point of every triangle that contains f.  So the point lies in
 * f's region, the intersection over the triangles T containing f of the
 * points whose nearest point on T is on f:
 *   - a face: its prism, inside the lines of its three edges (within the
 *     plane) and nearer its plane than the band K;
 *   - an edge PQ: between the planes through P and Q normal to it, on the
 *     outer side of the edge within each of its triangles' planes (a wedge
 *     between the triangles' normals), within K of its line;
 *   - a vertex V: behind the plane through V normal to each of its edges
 *     (a cone about the vertex's normals), within K of V.
 * Each region is scanned and its voxels take the distance of the
 * triangles that contain its feature (Ericson's exact test, the same
 * arithmetic as before: the minimum is the same to the bit), so a band
 * voxel is visited about once per region it lies in — one or two — instead
 * of once per triangle whose grown box holds it (some twenty).  The
 * regions need the edges' and vertices' triangles: found per tile from the
 * vertex indices (a hash of each), in the tile's triangle order.  Any
 * triangle left out (not in the tile's list, or a duplicate vertex index)
 * only drops a half space: a larger region, still exact.
 *
 * Rounding: every half space and radius is grown by DIST_SLOP (1e-4
 * voxel).  A triangle whose computed distance can be the voxel's minimum
 * is within the rounding (~1e-13 voxel^2) of the true minimum; were the
 * voxel outside its nearest feature's region by more than the slop, a
 * neighbouring triangle would be nearer by about the slop squared (1e-8
 * voxel^2), so it is not outside, and is visited.  A degenerate or
 * needle-thin triangle (its normal not to be trusted) is a region of its
 * own: its whole box grown by K, as the scatter did.
 *
 * Everything is in the tile's triangle order: the same regions for any
 * number of workers. */
#include "mesh_dist_int.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "huge.h"

/* The lower bound's planes of d: for each edge P -> Q (ab, bc, ca,
 * counter-clockwise about n) the unit normal m = (Q - P) x n / |Q - P|, in
 * the plane and pointing away from the third vertex, and its offset c =
 * m . (P - a); a point's signed distance to the edge's line, within the
 * plane, is m . (p - a) - c.  A degenerate triangle (n = 0) gets m = 0 and
 * c = +inf. */
static void edge_planes(dtri *d)
{
    double o[3][3], e[3][3]; /* the edges' starts (from a) and vectors */
    for (int a = 0; a < 3; a++) {
        o[0][a] = 0, o[1][a] = d->ab[a], o[2][a] = d->ac[a];
        e[0][a] = d->ab[a], e[1][a] = d->ac[a] - d->ab[a], e[2][a] = -d->ac[a];
    }
    bool flat = d->n[0] == 0 && d->n[1] == 0 && d->n[2] == 0;
    for (int i = 0; i < 3; i++) {
        const double *u = e[i], *n = d->n;
        double m[3] = {u[1] * n[2] - u[2] * n[1], u[2] * n[0] - u[0] * n[2],
                       u[0] * n[1] - u[1] * n[0]};
        double len = sqrt(dot3(u, u));
        for (int a = 0; a < 3; a++) d->m[i][a] = flat || !(len > 0) ? 0 : m[a] / len;
        d->c[i] = flat || !(len > 0) ? INFINITY : dot3(d->m[i], o[i]);
    }
}

/* Vertex v of the mesh in voxel units. */
static void vpos(const mesh_vox_tile *t, uint32_t v, double p[3])
{
    for (int a = 0; a < 3; a++)
        p[a] = ((double)t->m->vertices[v][a] - t->g->lo[a]) / t->g->vs;
}

/* Triangle id of the mesh in voxel units, with the tile's voxels its box
 * grown by K reaches; false when it reaches none. */
static bool make_dtri(const mesh_vox_tile *t, uint32_t id, double K, dtri *d)
{
    double v[3][3];
    for (int i = 0; i < 3; i++) vpos(t, t->m->triangles[id][i], v[i]);
    int32_t org[3] = {(int32_t)t->x0, (int32_t)t->y0, 0};
    int32_t n[3] = {(int32_t)t->nx, (int32_t)t->ny, (int32_t)t->nz};
    for (int a = 0; a < 3; a++) {
        d->lo[a] = fmin(v[0][a], fmin(v[1][a], v[2][a]));
        d->hi[a] = fmax(v[0][a], fmax(v[1][a], v[2][a]));
        double lo = d->lo[a] - org[a], hi = d->hi[a] - org[a];
        /* centres X + 0.5 in [lo - K, hi + K] */
        d->i0[a] = iceil(lo - K - 0.5, 0, n[a] - 1);
        d->i1[a] = ifloor(hi + K - 0.5, 0, n[a] - 1);
        if (d->i0[a] > d->i1[a]) return false;
        d->a[a] = v[0][a];
        d->ab[a] = v[1][a] - v[0][a];
        d->ac[a] = v[2][a] - v[0][a];
    }
    double c[3] = {d->ab[1] * d->ac[2] - d->ab[2] * d->ac[1],
                   d->ab[2] * d->ac[0] - d->ab[0] * d->ac[2],
                   d->ab[0] * d->ac[1] - d->ab[1] * d->ac[0]};
    double len = sqrt(dot3(c, c));
    for (int a = 0; a < 3; a++) d->n[a] = len > 0 ? c[a] / len : 0;
    /* sin of its angle at a below 1e-9: its normal may be off by more
     * than the slop allows */
    d->deg = !(len > 1e-9 * sqrt(dot3(d->ab, d->ab) * dot3(d->ac, d->ac)));
    edge_planes(d);
    return true;
}

/* ---- the tile's vertices and edges ---- */

/* An open-addressing hash of keys (non-zero) to dense ids in first-seen
 * order. */
typedef struct {
    uint64_t *key;
    uint32_t *id, mask, n;
} dhash;

static int dhash_init(dhash *h, size_t want)
{
    size_t cap = 16;
    while (cap < 2 * want) cap *= 2;
    h->key = huge_calloc(cap, sizeof *h->key);
    h->id = huge_malloc(cap * sizeof *h->id);
    h->mask = (uint32_t)(cap - 1), h->n = 0;
    return h->key && h->id ? 0 : -ENOMEM;
}

static void dhash_free(dhash *h)
{
    free(h->key);
    free(h->id);
}

/* The id of key, a new one (h->n - 1) when first seen. */
static uint32_t dhash_get(dhash *h, uint64_t key)
{
    uint32_t i = (uint32_t)((key * 0x9E3779B97F4A7C15ull) >> 32) & h->mask;
    while (h->key[i] && h->key[i] != key) i = (i + 1) & h->mask;
    if (!h->key[i]) h->key[i] = key, h->id[i] = h->n++;
    return h->id[i];
}

/* The tile's vertices and edges: the vertex of corner k of triangle i is
 * cv[3i + k], its edge from corner k to k + 1 ce[3i + k]; the triangles of
 * vertex v are vl[vs[v] .. vs[v + 1]) and of edge e el[es[e] .. es[e + 1]),
 * as 4 * triangle + corner (or edge), in the tile's order; vertex v is the
 * mesh's vid[v], at pos[v] in voxel units (vpos once per vertex: the edges
 * and cones read each vertex many times). */
typedef struct {
    uint32_t nv, ne;
    uint32_t *cv, *ce, *vid, *vs, *vl, *es, *el;
    double (*pos)[3];
} dadj;

static void dadj_free(dadj *a)
{
    free(a->cv), free(a->ce), free(a->vid), free(a->vs), free(a->vl), free(a->es), free(a->el);
    free(a->pos);
}

/* The list of items (4 * triangle + k) by owner own[3i + k] (counted,
 * then filed): st[n + 1], ls[3 * ntri]. */
static void file_by(const uint32_t *own, uint32_t ntri, uint32_t n, uint32_t *st, uint32_t *ls)
{
    memset(st, 0, (n + 1) * sizeof *st);
    for (uint32_t i = 0; i < 3 * ntri; i++) st[own[i] + 1]++;
    for (uint32_t k = 0; k < n; k++) st[k + 1] += st[k];
    for (uint32_t i = 0; i < 3 * ntri; i++) ls[st[own[i]]++] = (i / 3) << 2 | (i % 3);
    for (uint32_t k = n; k > 0; k--) st[k] = st[k - 1];
    st[0] = 0;
}

static int dadj_make(const mesh_vox_tile *t, const uint32_t *tid, uint32_t ntri, dadj *a)
{
    memset(a, 0, sizeof *a);
    size_t n3 = (size_t)3 * ntri + 1;
    dhash hv = {0}, he = {0}; /* counts 0 where an init fails or is not made */
    int rc = dhash_init(&hv, n3);
    if (!rc) rc = dhash_init(&he, n3);
    a->cv = malloc(n3 * 4), a->ce = malloc(n3 * 4), a->vid = malloc(n3 * 4);
    a->vl = malloc(n3 * 4), a->el = malloc(n3 * 4);
    if (rc || !a->cv || !a->ce || !a->vid || !a->vl || !a->el) rc = -ENOMEM;
    for (uint32_t i = 0; !rc && i < ntri; i++)
        for (int k = 0; k < 3; k++) {
            uint32_t g = t->m->triangles[tid[i]][k], v = dhash_get(&hv, (uint64_t)g + 1);
            if (v == hv.n - 1) a->vid[v] = g;
            a->cv[3 * i + k] = v;
        }
    for (uint32_t i = 0; !rc && i < ntri; i++)
        for (int k = 0; k < 3; k++) {
            uint64_t p = a->cv[3 * i + k], q = a->cv[3 * i + (k + 1) % 3];
            a->ce[3 * i + k] = dhash_get(&he, (p < q ? p << 32 | q : q << 32 | p) + 1);
        }
    a->nv = hv.n, a->ne = he.n;
    dhash_free(&hv), dhash_free(&he);
    if (!rc) {
        a->vs = malloc(((size_t)a->nv + 1) * 4), a->es = malloc(((size_t)a->ne + 1) * 4);
        a->pos = malloc(((size_t)a->nv + 1) * sizeof *a->pos);
        if (!a->vs || !a->es || !a->pos) rc = -ENOMEM;
    }
    if (!rc) {
        for (uint32_t v = 0; v < a->nv; v++) vpos(t, a->vid[v], a->pos[v]);
        file_by(a->cv, ntri, a->nv, a->vs, a->vl);
        file_by(a->ce, ntri, a->ne, a->es, a->el);
    }
    return rc;
}

/* ---- the regions ---- */

static void add_hs(dcpt *d, const double a[3], double b)
{
    double *h = d->hs[d->nhs++];
    h[0] = a[0], h[1] = a[1], h[2] = a[2], h[3] = b;
}

/* The tile voxels of box [lo, hi] (voxel units) into f; false when none. */
static bool box_of(const mesh_vox_tile *t, const double lo[3], const double hi[3], dfeat *f)
{
    int32_t org[3] = {(int32_t)t->x0, (int32_t)t->y0, 0};
    int32_t n[3] = {(int32_t)t->nx, (int32_t)t->ny, (int32_t)t->nz};
    for (int a = 0; a < 3; a++) {
        f->i0[a] = iceil(lo[a] - DIST_SLOP - org[a] - 0.5, 0, n[a] - 1);
        f->i1[a] = ifloor(hi[a] + DIST_SLOP - org[a] - 0.5, 0, n[a] - 1);
        if (f->i0[a] > f->i1[a]) return false;
    }
    return true;
}

/* The box of the points p + s[j] (j < ns) for each p of base (nb): per
 * axis the least base plus the least s (and the greatest): a rounded sum
 * is monotonic in each term, so that is the least of the rounded sums to
 * the bit, in nb + ns steps, not nb * ns. */
static void box_pts(const double (*base)[3], int nb, const double (*s)[3], int ns,
                    double lo[3], double hi[3])
{
    for (int a = 0; a < 3; a++) {
        double bl = base[0][a], bh = bl, sl = s[0][a], sh = sl;
        for (int i = 1; i < nb; i++) {
            bl = base[i][a] < bl ? base[i][a] : bl;
            bh = base[i][a] > bh ? base[i][a] : bh;
        }
        for (int j = 1; j < ns; j++) {
            sl = s[j][a] < sl ? s[j][a] : sl;
            sh = s[j][a] > sh ? s[j][a] : sh;
        }
        lo[a] = bl + sl, hi[a] = bh + sh;
    }
}

/* A region to be: its box (voxel units), its triangles (items 4 *
 * triangle + k, n of them), its quad and its c and u (NULL: 0; dfeat). */
typedef struct {
    double lo[3], hi[3];
    const uint32_t *list;
    uint32_t n;
    int quad;
    const double *c, *u;
} dnew;

/* A new region of nw; false (nothing added) when its box holds no tile
 * voxel. */
static bool new_feat(dcpt *d, const mesh_vox_tile *t, const dnew *nw)
{
    dfeat *f = &d->f[d->nf];
    if (!box_of(t, nw->lo, nw->hi, f)) return false;
    f->h0 = d->nhs, f->nh = 0, f->t0 = d->ntl, f->nt = nw->n, f->quad = nw->quad, f->ax = 0;
    for (uint32_t i = 0; i < nw->n; i++) d->tl[d->ntl++] = nw->list[i] >> 2;
    for (int a = 0; a < 3; a++)
        f->c[a] = nw->c ? nw->c[a] : 0, f->u[a] = nw->u ? nw->u[a] : 0;
    d->nf++;
    return true;
}

/* Triangle i's face: its prism (degenerate: its grown box, no half space). */
static void face_feat(dcpt *d, const mesh_vox_tile *t, uint32_t i, double R)
{
    const dtri *r = &d->tri[i];
    uint32_t item = i << 2;
    dnew nw = {.list = &item, .n = 1, .quad = 0, .c = r->a};
    if (r->deg) {
        for (int a = 0; a < 3; a++) nw.lo[a] = r->lo[a] - R, nw.hi[a] = r->hi[a] + R;
        new_feat(d, t, &nw);
        return;
    }
    double v[3][3], s[2][3];
    for (int a = 0; a < 3; a++) {
        v[0][a] = r->a[a], v[1][a] = r->a[a] + r->ab[a], v[2][a] = r->a[a] + r->ac[a];
        s[0][a] = R * r->n[a], s[1][a] = -R * r->n[a];
    }
    box_pts((const double (*)[3])v, 3, (const double (*)[3])s, 2, nw.lo, nw.hi);
    if (!new_feat(d, t, &nw)) return;
    dfeat *f = &d->f[d->nf - 1];
    f->ax = axis_of(r->n, true); /* across the prism's slab */
    for (int k = 0; k < 3; k++) add_hs(d, r->m[k], dot3(r->m[k], r->a) + r->c[k] + DIST_SLOP);
    double nn[3] = {-r->n[0], -r->n[1], -r->n[2]}, h = dot3(r->n, r->a);
    add_hs(d, r->n, h + R);
    add_hs(d, nn, -h + R);
    f->nh = 5;
}

/* The box of edge PQ's wedge, radius R, from its two triangles' normals
 * when it opens less than a right angle (the sector lies in the
 * quadrilateral of its apex, its two rays and the tangents' meeting
 * point), else PQ's box grown by R, into e (whose list, n and u, the
 * edge's unit vector, it reads); returns the axis to scan it along: the
 * sector's bisector's, else the one most across the edge (u). */
static int edge_box(const dcpt *d, const double P[3], const double Q[3], double R, dnew *e)
{
    const uint32_t *L = e->list;
    uint32_t n = e->n;
    int ax = axis_of(e->u, false);
    const double base[2][3] = {{P[0], P[1], P[2]}, {Q[0], Q[1], Q[2]}};
    double s[4][3] = {{-R, -R, -R}, {R, R, R}};
    int ns = 2;
    const dtri *r1 = &d->tri[L[0] >> 2], *r2 = n == 2 ? &d->tri[L[1] >> 2] : NULL;
    if (r2 && !r1->deg && !r2->deg) {
        const double *m1 = r1->m[L[0] & 3], *m2 = r2->m[L[1] & 3];
        double g1[3], g2[3], s1 = dot3(m2, r1->n) >= 0 ? 1 : -1, s2 = dot3(m1, r2->n) >= 0 ? 1 : -1;
        for (int a = 0; a < 3; a++) g1[a] = s1 * r1->n[a], g2[a] = s2 * r2->n[a];
        double c = dot3(g1, g2);
        if (c > 0) {
            for (int a = 0; a < 3; a++) {
                s[0][a] = 0, s[1][a] = R * g1[a], s[2][a] = R * g2[a];
                s[3][a] = R * (g1[a] + g2[a]) / (1 + c);
            }
            ns = 4;
            ax = axis_of(s[3], true);
        }
    }
    box_pts(base, 2, (const double (*)[3])s, ns, e->lo, e->hi);
    return ax;
}

/* Edge e's wedge: the slab between P and Q, outside the edge in each of
 * its triangles' planes, within R of its line. */
static void edge_feat(dcpt *d, const mesh_vox_tile *t, const dadj *a, uint32_t e, double R)
{
    const uint32_t *L = a->el + a->es[e];
    uint32_t n = a->es[e + 1] - a->es[e], i = L[0] >> 2, k = L[0] & 3;
    const double *P = a->pos[a->cv[3 * i + k]], *Q = a->pos[a->cv[3 * i + (k + 1) % 3]];
    double u[3];
    for (int c = 0; c < 3; c++) u[c] = Q[c] - P[c];
    double len = sqrt(dot3(u, u));
    if (!(len > 0)) return; /* a point: its vertex's region */
    for (int c = 0; c < 3; c++) u[c] /= len;
    dnew nw = {.list = L, .n = n, .quad = 2, .c = P, .u = u};
    int ax = edge_box(d, P, Q, R, &nw);
    if (!new_feat(d, t, &nw)) return;
    dfeat *f = &d->f[d->nf - 1];
    f->ax = ax;
    double nu[3] = {-u[0], -u[1], -u[2]};
    add_hs(d, nu, -dot3(u, P) + DIST_SLOP);
    add_hs(d, u, dot3(u, Q) + DIST_SLOP);
    f->nh = 2;
    for (uint32_t j = 0; j < n && f->nh < DIST_MAXH; j++) {
        const dtri *r = &d->tri[L[j] >> 2];
        const double *m = r->m[L[j] & 3];
        if (r->deg) continue;
        double nm[3] = {-m[0], -m[1], -m[2]};
        add_hs(d, nm, -(dot3(m, r->a) + r->c[L[j] & 3]) + DIST_SLOP);
        f->nh++;
    }
}

/* Vertex v's cone: behind the plane through V normal to each of its edges,
 * within R of V. */
static void vert_feat(dcpt *d, const mesh_vox_tile *t, const dadj *a, uint32_t v, double R)
{
    const uint32_t *L = a->vl + a->vs[v];
    uint32_t n = a->vs[v + 1] - a->vs[v], seen[DIST_MAXH];
    const double *V = a->pos[v];
    double axis[3] = {0, 0, 0};
    dnew nw = {.list = L, .n = n, .quad = 1, .c = V};
    for (int c = 0; c < 3; c++) nw.lo[c] = V[c] - R, nw.hi[c] = V[c] + R;
    if (!new_feat(d, t, &nw)) return;
    dfeat *f = &d->f[d->nf - 1];
    for (uint32_t j = 0; j < n; j++)
        for (uint32_t s = 1; s < 3; s++) {
            uint32_t w = a->cv[3 * (L[j] >> 2) + ((L[j] & 3) + s) % 3], dup = w == v;
            for (uint32_t q = 0; q < f->nh && !dup; q++) dup = seen[q] == w;
            if (dup || f->nh == DIST_MAXH) continue;
            const double *W = a->pos[w];
            double u[3];
            for (int c = 0; c < 3; c++) u[c] = W[c] - V[c];
            double len = sqrt(dot3(u, u));
            if (!(len > 0)) continue;
            for (int c = 0; c < 3; c++) u[c] /= len;
            add_hs(d, u, dot3(u, V) + DIST_SLOP);
            seen[f->nh++] = w;
            for (int c = 0; c < 3; c++) axis[c] -= u[c];
        }
    f->ax = axis_of(axis, true); /* the cone's, about the opposite of its edges */
}

/* Each region into the slabs its box meets, in the regions' order (a
 * counting sort: counted, then filed). */
static int dcpt_bin(const mesh_vox_tile *t, dcpt *d)
{
    uint32_t ns = d->nslab = (t->nz + DIST_SLAB - 1) / DIST_SLAB;
    if (!(d->start = calloc((size_t)ns + 1, sizeof *d->start))) return -ENOMEM;
    for (int pass = 0; pass < 2; pass++) {
        for (uint32_t i = 0; i < d->nf; i++) {
            const dfeat *r = &d->f[i];
            for (uint32_t s = (uint32_t)r->i0[2] / DIST_SLAB; s <= (uint32_t)r->i1[2] / DIST_SLAB; s++)
                if (pass) d->list[d->start[s]++] = i;
                else d->start[s + 1]++;
        }
        if (pass) break;
        for (uint32_t s = 0; s < ns; s++) d->start[s + 1] += d->start[s];
        if (!(d->list = malloc((d->start[ns] ? d->start[ns] : 1) * sizeof *d->list)))
            return -ENOMEM;
    }
    /* filing left start[s] at the end of slab s, the start of s + 1 */
    for (uint32_t s = ns; s > 0; s--) d->start[s] = d->start[s - 1];
    d->start[0] = 0;
    return 0;
}

void mesh_cpt_free(dcpt *d)
{
    free(d->tri), free(d->f), free(d->hs), free(d->tl), free(d->start), free(d->list);
    memset(d, 0, sizeof *d);
}

int mesh_cpt_make(const mesh_vox_tile *t, uint32_t K, dcpt *d)
{
    memset(d, 0, sizeof *d);
    size_t n = t->n + 1;
    uint32_t *tid = malloc(n * sizeof *tid);
    d->tri = huge_malloc(n * sizeof *d->tri);
    if (!tid || !d->tri) {
        free(tid);
        return -ENOMEM;
    }
    for (size_t i = 0; i < t->n; i++)
        if (make_dtri(t, t->ids[i], K, &d->tri[d->ntri])) tid[d->ntri++] = t->ids[i];
    dadj a;
    int rc = dadj_make(t, tid, d->ntri, &a);
    free(tid);
    size_t nt = (size_t)d->ntri + 1;
    if (!rc) { /* sized by the edges and vertices dadj_make counted */
        d->f = huge_malloc((nt + a.ne + a.nv) * sizeof *d->f);
        d->hs = huge_malloc((5 * nt + 2 * (size_t)a.ne + 3 * nt + (size_t)DIST_MAXH * a.nv) *
                            sizeof *d->hs);
        d->tl = huge_malloc(7 * nt * sizeof *d->tl);
        if (!d->f || !d->hs || !d->tl) rc = -ENOMEM;
    }
    double R = K + DIST_SLOP;
    for (uint32_t i = 0; !rc && i < d->ntri; i++) face_feat(d, t, i, R);
    for (uint32_t e = 0; !rc && e < a.ne; e++) edge_feat(d, t, &a, e, R);
    for (uint32_t v = 0; !rc && v < a.nv; v++) vert_feat(d, t, &a, v, R);
    dadj_free(&a);
    return rc ? rc : dcpt_bin(t, d);
}
