/* mesh_dist — the distance channel of a tile (channel 4): the signed
 * distance from each voxel's centre to the mesh, in world units, negative
 * inside, in a narrow band of K voxels on each side of the surface; beyond
 * it the band's width K * vs with the voxel's sign.
 *
 * The unsigned distance is exact (to the rounding of double arithmetic):
 * the smallest distance from the centre to the closest point of any
 * triangle (Ericson's closest point on a triangle, by Voronoi regions of
 * its vertices and edges, the plane's distance inside its face), found by
 * a closest-point transform (mesh_cpt.c): each face's, edge's and vertex's
 * region is scanned row by row and its voxels take the distance of the
 * triangles that hold the feature.  The tile is done in slabs of DIST_SLAB
 * voxels in z: the squared distances of a slab's bricks that some region's
 * box meets start at K^2, every region of the slab is scanned once (not
 * once per brick its box crosses: a region of the dragon at 1024^3 crosses
 * several 8^3 bricks, and its slices' and rows' spans are the scan's cost),
 * then the slab's bricks are made in order.  A brick that no region's box
 * meets lies beyond the band whole: a uniform brick of +w or -w from the
 * solid's bits, no voxel visited.
 *
 * The sign is the solid's (t->occ: the parity at the voxel centres, or its
 * repair), so the distance's sign and the occupancy agree voxel for voxel.
 * Coordinates are voxel units, (v - lo) / vs, the centre of voxel X at
 * X + 0.5; the result is scaled by vs once, at the end.  Everything is a
 * function of the tile's data alone, in a fixed order: the same bytes for
 * any number of workers. */
#include "mesh_dist_int.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "voxel.h"

float mesh_dist_width(const mesh_vox_opts *o, double vs)
{
    return (float)(mesh_vox_band(o) * vs);
}

/* |p - (a + s d)|^2 for the closest s in [0, 1] (d may be 0). */
static double seg_d2(const double ap[3], const double d[3])
{
    double dd = dot3(d, d), s = dd > 0 ? dot3(ap, d) / dd : 0;
    s = s < 0 ? 0 : s > 1 ? 1 : s;
    double q[3] = {ap[0] - s * d[0], ap[1] - s * d[1], ap[2] - s * d[2]};
    return dot3(q, q);
}

/* The squared distance from p to triangle t (Ericson, Real-Time Collision
 * Detection 5.1.5: the Voronoi regions of the vertices, then the edges,
 * then the face). */
static inline __attribute__((always_inline)) double tri_d2(const dtri *t, const double p[3])
{
    double ap[3] = {p[0] - t->a[0], p[1] - t->a[1], p[2] - t->a[2]};
    double d1 = dot3(t->ab, ap), d2 = dot3(t->ac, ap);
    if (d1 <= 0 && d2 <= 0) return dot3(ap, ap);
    double bp[3] = {ap[0] - t->ab[0], ap[1] - t->ab[1], ap[2] - t->ab[2]};
    double d3 = dot3(t->ab, bp), d4 = dot3(t->ac, bp);
    if (d3 >= 0 && d4 <= d3) return dot3(bp, bp);
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) return seg_d2(ap, t->ab);
    double cp[3] = {ap[0] - t->ac[0], ap[1] - t->ac[1], ap[2] - t->ac[2]};
    double d5 = dot3(t->ab, cp), d6 = dot3(t->ac, cp);
    if (d6 >= 0 && d5 <= d6) return dot3(cp, cp);
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) return seg_d2(ap, t->ac);
    double va = d3 * d6 - d5 * d4;
    double bc[3] = {t->ac[0] - t->ab[0], t->ac[1] - t->ab[1], t->ac[2] - t->ab[2]};
    if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) return seg_d2(bp, bc);
    if (t->n[0] == 0 && t->n[1] == 0 && t->n[2] == 0) /* degenerate: its edges */
        return fmin(seg_d2(ap, t->ab), fmin(seg_d2(ap, t->ac), seg_d2(bp, bc)));
    double h = dot3(ap, t->n); /* inside the face: the plane's distance */
    return h * h;
}

static uint32_t fbits(float f)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    return u;
}

/* The larger and smaller of two numbers (fmax and fmin are calls) */
#define MAXD(a, b) ((a) > (b) ? (a) : (b))
#define MIND(a, b) ((a) < (b) ? (a) : (b))

/* What a region's rows and slices are scanned with: its regions, the
 * region, the two axes across its rows (u, v) and its radius squared. */
typedef struct {
    const dcpt *d;
    const dfeat *f;
    int u, v;
    double R2;
} dscan;

/* The span along f->ax (voxel centres, absolute) of the row at pu, pv on
 * the two other axes u, v inside region f: s[0 .. 1] narrowed by its
 * half spaces and its ball or cylinder; false when nothing is left. */
static bool row_span(const dscan *sc, double pu, double pv, double s[2])
{
    const dfeat *f = sc->f;
    int ax = f->ax, u = sc->u, v = sc->v;
    double lo = s[0], hi = s[1];
    for (uint32_t j = 0; j < f->nh; j++) {
        const double *h = sc->d->hs[f->h0 + j];
        double c = h[3] - h[u] * pu - h[v] * pv;
        if (h[ax] > 0) {
            double q = c / h[ax];
            hi = q < hi ? q : hi;
        } else if (h[ax] < 0) {
            double q = c / h[ax];
            lo = q > lo ? q : lo;
        } else if (c < 0) {
            return false;
        }
        if (!(lo <= hi)) return false;
    }
    double qu = pu - f->c[u], qv = pv - f->c[v], r;
    if (f->quad == 1) { /* within R of c: a ball */
        double e = sc->R2 - qu * qu - qv * qv;
        if (e < 0) return false;
        r = sqrt(e);
        lo = MAXD(lo, f->c[ax] - r), hi = MIND(hi, f->c[ax] + r);
    } else if (f->quad == 2) { /* within R of the line c + s u: A q^2 + B q + C < 0 */
        double w = qu * f->u[u] + qv * f->u[v], A = 1 - f->u[ax] * f->u[ax];
        double B = -2 * f->u[ax] * w, C = qu * qu + qv * qv - w * w - sc->R2;
        if (A > 1e-6) { /* else the line runs along the row: its slab bounds it */
            double disc = B * B - 4 * A * C;
            if (disc < 0) return false;
            r = sqrt(disc);
            lo = MAXD(lo, f->c[ax] + (-B - r) / (2 * A));
            hi = MIND(hi, f->c[ax] + (-B + r) / (2 * A));
        } else if (C > 0) {
            return false;
        }
    }
    s[0] = lo, s[1] = hi;
    return lo <= hi;
}

/* The slices of a region (scanned across axis v), each the polygon of the
 * rows (axis u) whose span along ax can be non-empty: the half spaces
 * a_u q_u + a_s q_s <= c - a_v q_v of the region (q = p - f->c) and the
 * span [s0, s1] two more, with q_s eliminated (Fourier-Motzkin: each upper
 * bound of q_s against each lower one), made once a region and slab; what
 * is left, al q_u <= b0 - bv q_v, in three runs: the upper bounds of q_u
 * (al > 0), the lower ones, and those without q_u (al = 0), inv = 1 / al.
 * Most vertices' cones are empty, and their slices say so without a row
 * visited (for the edges' wedges it pays less, for the faces' prisms not
 * at all: most of their rows are). */
#define DIST_MAXP ((DIST_MAXH + 2) * (DIST_MAXH + 2) / 4 + DIST_MAXH + 2)
typedef struct {
    uint32_t nhi, nlo, nzero; /* uppers at [0, nhi), lowers at [DIST_MAXP - nlo, DIST_MAXP) */
    double inv[DIST_MAXP], b0[DIST_MAXP], bv[DIST_MAXP];
    double zb0[DIST_MAXP], zbv[DIST_MAXP];
} dslices;

/* A margin far above the rounding of the slices' sums (~1e-14 voxel), far
 * below the slop: the slices only narrow the rows that row_span decides,
 * so they may take more, never less. */
#define SLICE_MARGIN 1e-7

/* Half space al q_u <= b0 - bv q_v into its run of ds. */
static void slices_add(dslices *ds, double al, double b0, double bv)
{
    if (al == 0) {
        ds->zb0[ds->nzero] = b0, ds->zbv[ds->nzero++] = bv;
        return;
    }
    uint32_t i = al > 0 ? ds->nhi++ : DIST_MAXP - ++ds->nlo;
    ds->inv[i] = 1 / al, ds->b0[i] = b0, ds->bv[i] = bv;
}

static void slices_make(const dscan *sc, double s0, double s1, dslices *ds)
{
    const dfeat *f = sc->f;
    int ax = f->ax, u = sc->u, v = sc->v;
    uint32_t n = f->nh;
    double au[DIST_MAXH + 2], as[DIST_MAXH + 2], c[DIST_MAXH + 2], cv[DIST_MAXH + 2];
    for (uint32_t j = 0; j < n; j++) {
        const double *h = sc->d->hs[f->h0 + j];
        au[j] = h[u], as[j] = h[ax], cv[j] = h[v];
        c[j] = h[3] - dot3(h, f->c);
    }
    au[n] = 0, as[n] = 1, c[n] = s1 - f->c[ax], cv[n] = 0;
    au[n + 1] = 0, as[n + 1] = -1, c[n + 1] = f->c[ax] - s0, cv[n + 1] = 0;
    ds->nhi = ds->nlo = ds->nzero = 0;
    for (uint32_t j = 0; j < n + 2; j++) {
        if (as[j] == 0) slices_add(ds, au[j], c[j], cv[j]);
        if (!(as[j] > 0)) continue;
        for (uint32_t k = 0; k < n + 2; k++)
            if (as[k] < 0)
                slices_add(ds, au[j] * -as[k] + au[k] * as[j], c[j] * -as[k] + c[k] * as[j],
                           cv[j] * -as[k] + cv[k] * as[j]);
    }
}

/* The rows of the slice at pv (axis v) that can hold voxels of the region:
 * uu[0 .. 1] on axis u narrowed to its polygon in ds and, for a vertex,
 * the ball's disc; false when the slice holds none. */
static bool slice_span(const dscan *sc, const dslices *ds, double pv, double uu[2])
{
    const dfeat *f = sc->f;
    int u = sc->u, v = sc->v;
    double qv = pv - f->c[v], lo = uu[0] - f->c[u], hi = uu[1] - f->c[u];
    for (uint32_t i = 0; i < ds->nzero; i++)
        if (ds->zb0[i] - ds->zbv[i] * qv < -SLICE_MARGIN) return false;
    for (uint32_t i = 0; i < ds->nhi; i++) hi = MIND(hi, (ds->b0[i] - ds->bv[i] * qv) * ds->inv[i]);
    for (uint32_t i = DIST_MAXP - ds->nlo; i < DIST_MAXP; i++)
        lo = MAXD(lo, (ds->b0[i] - ds->bv[i] * qv) * ds->inv[i]);
    if (f->quad == 1) {
        double r2 = sc->R2 - qv * qv;
        if (r2 < 0) return false;
        double r = sqrt(r2);
        lo = MAXD(lo, -r), hi = MIND(hi, r);
    }
    uu[0] = lo + f->c[u] - SLICE_MARGIN, uu[1] = hi + f->c[u] + SLICE_MARGIN;
    return uu[0] <= uu[1];
}

/* A slab of the tile: DIST_SLAB voxels in z from z0 (h of them), whose
 * squared distances (voxel units) d2 holds, x fastest, rows of MESH_TILE,
 * planes of MESH_TILE^2; reach[k]: some region's box meets the slab's
 * brick k (bx fastest, nb[0] x nb[1] x nb[2] of them). */
typedef struct {
    int32_t z0, h;
    uint32_t nb[3];
    double *d2;
    uint8_t *reach;
} dslab;

/* Slab brick (bx, by, bz)'s flag in reach (bz from the slab's first). */
static uint8_t *reach_at(const dslab *sl, uint32_t bx, uint32_t by, uint32_t bz)
{
    return &sl->reach[((size_t)bz * sl->nb[1] + by) * sl->nb[0] + bx];
}

#define SLAB_ROW ((size_t)MESH_TILE)
#define SLAB_PLANE ((size_t)MESH_TILE * MESH_TILE)

/* A row of a region: its triangles tl[0 .. nt), the centre of its voxel 0
 * along the row's axis o and its voxels a .. b. */
typedef struct {
    const dcpt *d;
    const uint32_t *tl;
    uint32_t nt;
    double o;
    int32_t a, b;
} drow;

/* Row r's voxels along axis ax (p the centre's other two coordinates), e
 * voxel a's squared distance and st the step to the next, lowered to the
 * distance of r's triangles.  Inlined with ax a constant, p stays in
 * registers (an indexed store into p and its reload as a vector stalled
 * the store's forwarding); the same arithmetic to the bit. */
static inline __attribute__((always_inline)) void row_d2(const drow *r, const double pin[3],
                                                         int ax, double *e, size_t st)
{
    for (int32_t k = r->a; k <= r->b; k++, e += st) {
        double p[3] = {pin[0], pin[1], pin[2]}, m = *e;
        p[ax] = r->o + k;
        for (uint32_t q = 0; q < r->nt; q++) {
            double x = tri_d2(&r->d->tri[r->tl[q]], p);
            m = x < m ? x : m;
        }
        *e = m;
    }
}

/* The voxels of region f in slab sl's rows along f->ax lowered to the
 * distance of f's triangles: each voxel of the region is visited once,
 * whatever bricks its box crosses. */
static void feat_d2(const mesh_vox_tile *t, const dcpt *d, const dfeat *f, double R2,
                    const dslab *sl)
{
    dscan sc = {.d = d, .f = f, .u = (f->ax + 1) % 3, .v = (f->ax + 2) % 3, .R2 = R2};
    int ax = f->ax, u = sc.u, v = sc.v;
    int32_t lo[3] = {f->i0[0], f->i0[1], MAXD(f->i0[2], sl->z0)};
    int32_t hi[3] = {f->i1[0], f->i1[1], MIND(f->i1[2], sl->z0 + sl->h - 1)};
    /* the centre of tile voxel i along axis a: org[a] + i (exact: halves) */
    double org[3] = {(double)t->x0 + 0.5, (double)t->y0 + 0.5, 0.5};
    size_t step[3] = {1, SLAB_ROW, SLAB_PLANE};
    double *base = sl->d2 - (size_t)sl->z0 * SLAB_PLANE;
    const uint32_t *tl = d->tl + f->t0;
    dslices ds;
    /* a face's rows all meet its prism: no slice test for them */
    if (f->quad) slices_make(&sc, org[ax] + lo[ax], org[ax] + hi[ax], &ds);
    for (int32_t j = lo[v]; j <= hi[v]; j++) {
        double uu[2] = {org[u] + lo[u], org[u] + hi[u]};
        if (f->quad && !slice_span(&sc, &ds, org[v] + j, uu)) continue;
        int32_t i0 = iceil(uu[0] - org[u], lo[u], hi[u]), i1 = ifloor(uu[1] - org[u], lo[u], hi[u]);
        for (int32_t i = i0; i <= i1; i++) {
            double p[3], s[2] = {org[ax] + lo[ax], org[ax] + hi[ax]};
            p[u] = org[u] + i, p[v] = org[v] + j;
            if (!row_span(&sc, p[u], p[v], s)) continue;
            int32_t a = iceil(s[0] - org[ax], lo[ax], hi[ax]), b = ifloor(s[1] - org[ax], lo[ax], hi[ax]);
            if (a > b) continue; /* (row would point past the slab) */
            double *row = base + (size_t)i * step[u] + (size_t)j * step[v] + (size_t)a * step[ax];
            drow r = {.d = d, .tl = tl, .nt = f->nt, .o = org[ax], .a = a, .b = b};
            if (ax == 0) row_d2(&r, p, 0, row, step[0]);
            else if (ax == 1) row_d2(&r, p, 1, row, step[1]);
            else row_d2(&r, p, 2, row, step[2]);
        }
    }
}

/* Slab sl's bricks that the boxes of its regions (list[l0 .. l1)) meet,
 * their voxels set to K^2 (nothing nearer); the others untouched. */
static void slab_reach(const mesh_vox_tile *t, const dcpt *d, uint64_t l0, uint64_t l1,
                       uint32_t K, dslab *sl)
{
    uint32_t S = t->S, sh = (uint32_t)__builtin_ctz(S); /* S a power of 2 */
    int32_t zlo = sl->z0, zhi = sl->z0 + sl->h - 1;
    size_t nx = sl->nb[0], nxy = nx * sl->nb[1];
    uint8_t *reach = sl->reach;
    memset(reach, 0, nxy * sl->nb[2]);
    /* the bounds in locals: the flags' stores (bytes) may alias anything */
    for (uint64_t j = l0; j < l1; j++) {
        const dfeat *f = &d->f[d->list[j]];
        uint32_t z0 = (uint32_t)(MAXD(f->i0[2], zlo) - zlo) >> sh,
                 z1 = (uint32_t)(MIND(f->i1[2], zhi) - zlo) >> sh;
        uint32_t y0 = (uint32_t)f->i0[1] >> sh, y1 = (uint32_t)f->i1[1] >> sh;
        uint32_t x0 = (uint32_t)f->i0[0] >> sh, x1 = (uint32_t)f->i1[0] >> sh;
        for (uint32_t bz = z0; bz <= z1; bz++)
            for (uint32_t by = y0; by <= y1; by++)
                for (uint32_t bx = x0; bx <= x1; bx++) reach[bz * nxy + by * nx + bx] = 1;
    }
    double KK = (double)K * K;
    for (uint32_t bz = 0; bz < sl->nb[2]; bz++)
        for (uint32_t by = 0; by < sl->nb[1]; by++)
            for (uint32_t bx = 0; bx < sl->nb[0]; bx++) {
                if (!*reach_at(sl, bx, by, bz)) continue;
                for (uint32_t z = bz * S; z < (bz + 1) * S; z++)
                    for (uint32_t y = by * S; y < (by + 1) * S; y++) {
                        double *r = sl->d2 + z * SLAB_PLANE + y * SLAB_ROW + bx * S;
                        for (uint32_t x = 0; x < S; x++) r[x] = KK;
                    }
            }
}

/* 0 none, 2 every voxel, 1 some of brick (bx, by, bz)'s voxels inside. */
static int brick_sign(const mesh_vox_tile *t, const uint32_t bk[3])
{
    uint32_t S = t->S;
    uint64_t full = S == 64 ? ~0ull : ((1ull << S) - 1) << (bk[0] * S), any = 0, all = full;
    for (uint32_t z = bk[2] * S; z < (bk[2] + 1) * S && z < t->nz; z++)
        for (uint32_t y = bk[1] * S; y < (bk[1] + 1) * S && y < t->ny; y++) {
            uint64_t w = t->occ[(size_t)z * t->ny + y] & full;
            any |= w;
            all &= w;
        }
    return !any ? 0 : all == full ? 2 : 1;
}

/* What a tile's bricks are made with: the tile, its regions, its buffers,
 * the band K and its width w in world units. */
typedef struct {
    mesh_vox_tile *t;
    const dcpt *d;
    const mesh_vox_bufs *b;
    uint32_t K;
    float w;
} dtile;

/* Row (Y, Z) of a brick, its S voxels from tile voxel X0 on (xyz), into
 * out: 0 past the grid, as the volume wants; the signed distance within
 * the band; beyond it +-w, the same bits as sqrt(K^2) * vs (all of them
 * when no region reached the brick: its d2 was not set). */
static void brick_row(const dtile *dt, const dslab *sl, bool reached, const uint32_t xyz[3],
                      float *out)
{
    mesh_vox_tile *t = dt->t;
    uint32_t S = t->S, X0 = xyz[0], Y = xyz[1], Z = xyz[2], n = 0, band = 0;
    if (Y < t->ny && Z < t->nz) n = t->nx - X0 < S ? t->nx - X0 : S;
    uint64_t occ = n ? t->occ[(size_t)Z * t->ny + Y] >> X0 : 0;
    const double *e = n ? sl->d2 + (Z - (uint32_t)sl->z0) * SLAB_PLANE + Y * SLAB_ROW + X0 : NULL;
    double vs = t->g->vs, KK = (double)dt->K * dt->K;
    for (uint32_t x = 0; x < n; x++) {
        bool in = occ >> x & 1u;
        if (reached && e[x] < KK) {
            double dist = sqrt(e[x]);
            band++;
            out[x] = (float)((in ? -dist : dist) * vs);
        } else {
            out[x] = in ? -dt->w : dt->w;
        }
    }
    for (uint32_t x = n; x < S; x++) out[x] = 0.0f;
    t->st->voxels += band;
}

/* Brick bk (tile bricks; its squared distances in slab sl): a uniform +w
 * or -w when no region reaches it and the solid agrees over it (inside the
 * grid whole), else every voxel. */
static int dist_brick(const dtile *dt, const dslab *sl, const uint32_t bk[3])
{
    mesh_vox_tile *t = dt->t;
    uint32_t S = t->S, zb = bk[2] - (uint32_t)sl->z0 / S;
    bool whole = (bk[0] + 1) * S <= t->nx && (bk[1] + 1) * S <= t->ny && (bk[2] + 1) * S <= t->nz;
    bool reached = *reach_at(sl, bk[0], bk[1], zb);
    uint32_t at[3] = {t->x0 / S + bk[0], t->y0 / S + bk[1], bk[2]};
    if (!reached && whole) {
        int sg = brick_sign(t, bk);
        if (sg != 1) return vod_volume_put_uniform(t->vol, at, fbits(sg ? -dt->w : dt->w));
    }
    float *out = (float *)(void *)dt->b->brick;
    for (uint32_t z = 0; z < S; z++)
        for (uint32_t y = 0; y < S; y++)
            brick_row(dt, sl, reached, (const uint32_t[3]){bk[0] * S, bk[1] * S + y, bk[2] * S + z},
                      out + ((size_t)z * S + y) * S);
    return vod_volume_put_brick(t->vol, at, out);
}

/* Slab s of the tile: its bricks reached, its regions scanned once each,
 * then its bricks in order (bx fastest). */
static int dist_slab(const dtile *dt, uint32_t s, dslab *sl)
{
    mesh_vox_tile *t = dt->t;
    const dcpt *d = dt->d;
    uint32_t S = t->S;
    sl->z0 = (int32_t)(s * DIST_SLAB);
    sl->h = (int32_t)(t->nz - s * DIST_SLAB < DIST_SLAB ? t->nz - s * DIST_SLAB : DIST_SLAB);
    sl->nb[0] = (t->nx + S - 1) / S, sl->nb[1] = (t->ny + S - 1) / S;
    sl->nb[2] = ((uint32_t)sl->h + S - 1) / S;
    slab_reach(t, d, d->start[s], d->start[s + 1], dt->K, sl);
    double R = dt->K + DIST_SLOP;
    for (uint64_t j = d->start[s]; j < d->start[s + 1]; j++) {
        const dfeat *f = &d->f[d->list[j]];
        feat_d2(t, d, f, R * R, sl);
        if (mesh_vox_beat(&t->pulse, 8 * f->nt + 8)) return -ECANCELED;
    }
    int rc = 0;
    uint32_t bz0 = (uint32_t)sl->z0 / S;
    for (uint32_t bz = bz0; bz < bz0 + sl->nb[2] && !rc; bz++)
        for (uint32_t by = 0; by < sl->nb[1] && !rc; by++)
            for (uint32_t bx = 0; bx < sl->nb[0] && !rc; bx++)
                rc = dist_brick(dt, sl, (const uint32_t[3]){bx, by, bz});
    return rc;
}

int mesh_vox_dist_run(mesh_vox_tile *t, const mesh_vox_plan *p, const mesh_vox_bufs *b)
{
    dcpt d;
    int rc = mesh_cpt_make(t, p->band, &d);
    dtile dt = {.t = t, .d = &d, .b = b, .K = p->band, .w = mesh_dist_width(t->o, t->g->vs)};
    size_t nb = (size_t)(MESH_TILE / t->S) * (MESH_TILE / t->S) * (DIST_SLAB / t->S);
    dslab sl = {.d2 = b->d2, .reach = rc ? NULL : malloc(nb)};
    if (!rc && !sl.reach) rc = -ENOMEM;
    for (uint32_t s = 0; s < d.nslab && !rc; s++) rc = dist_slab(&dt, s, &sl);
    free(sl.reach);
    mesh_cpt_free(&d);
    return rc;
}
