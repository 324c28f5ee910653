/* mesh_dist — the distance channel of a tile (channel 4): the signed
 * distance from each voxel's centre to the mesh, in world units, negative
 * inside, in a narrow band of K voxels on each side of the surface; beyond
 * it the band's width K * vs with the voxel's sign.
 *
 * The unsigned distance is exact (to the rounding of double arithmetic):
 * the smallest distance from the centre to the closest point of any
 * triangle (Ericson's closest point on a triangle, by Voronoi regions of
 * its vertices and edges, the plane's distance inside its face).  The
 * tile's triangles (mesh_bin gives every triangle within the band of its
 * columns) are binned to the tile's storage bricks by their boxes grown by
 * the band; a brick's triangles each lower the squared distances of the
 * voxels of their grown box (a scatter, as OpenVDB's meshToVolume does), so
 * the work is the band's, not the volume's.  Along each row of the box a
 * cheap lower bound (the height above the triangle's plane and the
 * distance to its edges' lines, row_d2) skips the voxels the triangle
 * cannot bring nearer than their best so far: Ericson's test runs on about
 * one voxel in four of the box, with the same minimum to the bit.
 * A brick that no triangle reaches lies beyond the band whole: a uniform
 * brick of +w or -w from the solid's bits, no voxel visited.
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
static double tri_d2(const dtri *t, const double p[3])
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

/* The solid's bit of tile voxel (x, y, z). */
static bool inside(const mesh_vox_tile *t, uint32_t x, uint32_t y, uint32_t z)
{
    return t->occ[(size_t)z * t->ny + y] >> x & 1u;
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

/* The span along f->ax (voxel centres, absolute) of the row at pu, pv on
 * the two other axes u, v inside region f: [*s0, *s1] narrowed by its
 * half spaces and its ball or cylinder; false when nothing is left. */
static bool row_span(const dcpt *d, const dfeat *f, int u, int v, double pu, double pv,
                     double R2, double *s0, double *s1)
{
    int ax = f->ax;
    double lo = *s0, hi = *s1;
    for (uint32_t j = 0; j < f->nh; j++) {
        const double *h = d->hs[f->h0 + j];
        double s = h[3] - h[u] * pu - h[v] * pv;
        if (h[ax] > 0) {
            double q = s / h[ax];
            hi = q < hi ? q : hi;
        } else if (h[ax] < 0) {
            double q = s / h[ax];
            lo = q > lo ? q : lo;
        } else if (s < 0) {
            return false;
        }
        if (!(lo <= hi)) return false;
    }
    double qu = pu - f->c[u], qv = pv - f->c[v], r;
    if (f->quad == 1) { /* within R of c: a ball */
        double s = R2 - qu * qu - qv * qv;
        if (s < 0) return false;
        r = sqrt(s);
        lo = MAXD(lo, f->c[ax] - r), hi = MIND(hi, f->c[ax] + r);
    } else if (f->quad == 2) { /* within R of the line c + s u: A q^2 + B q + C < 0 */
        double w = qu * f->u[u] + qv * f->u[v], A = 1 - f->u[ax] * f->u[ax];
        double B = -2 * f->u[ax] * w, C = qu * qu + qv * qv - w * w - R2;
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
    *s0 = lo, *s1 = hi;
    return lo <= hi;
}

/* The rows of region f in the slice at pv (axis v) whose span along ax can
 * be non-empty: [*u0, *u1] on axis u narrowed to the projection of the
 * slice's polygon, its half spaces a_u q_u + a_s q_s <= c (q = p - f->c,
 * the span [s0, s1] two more) with q_s eliminated (Fourier-Motzkin: each
 * upper bound of q_s against each lower one), and the ball's disc; false
 * when the slice holds none.  Most vertices' cones are empty, and their
 * slices say so without a row visited (for the edges' wedges it pays
 * less, for the faces' prisms not at all: most of their rows are). */
static bool slice_span(const dcpt *d, const dfeat *f, int u, int v, double pv, double s0,
                       double s1, double R2, double *u0, double *u1)
{
    int ax = f->ax;
    uint32_t n = f->nh;
    double au[DIST_MAXH + 2], as[DIST_MAXH + 2], c[DIST_MAXH + 2];
    double qv = pv - f->c[v], lo = *u0 - f->c[u], hi = *u1 - f->c[u];
    for (uint32_t j = 0; j < n; j++) {
        const double *h = d->hs[f->h0 + j];
        au[j] = h[u], as[j] = h[ax];
        c[j] = h[3] - dot3(h, f->c) - h[v] * qv;
    }
    au[n] = 0, as[n] = 1, c[n] = s1 - f->c[ax];
    au[n + 1] = 0, as[n + 1] = -1, c[n + 1] = f->c[ax] - s0;
    for (uint32_t j = 0; j < n + 2; j++) {
        double al = au[j], be = c[j]; /* al q_u <= be */
        if (as[j] != 0) {
            if (as[j] < 0) continue;
            for (uint32_t k = 0; k < n + 2; k++) {
                if (!(as[k] < 0)) continue;
                al = au[j] * -as[k] + au[k] * as[j], be = c[j] * -as[k] + c[k] * as[j];
                if (al > 0) hi = MIND(hi, be / al);
                else if (al < 0) lo = MAXD(lo, be / al);
                else if (be < 0) return false;
            }
            if (!(lo <= hi)) return false;
            continue;
        }
        if (al > 0) hi = MIND(hi, be / al);
        else if (al < 0) lo = MAXD(lo, be / al);
        else if (be < 0) return false;
    }
    if (f->quad == 1) {
        double r2 = R2 - qv * qv;
        if (r2 < 0) return false;
        double r = sqrt(r2);
        lo = MAXD(lo, -r), hi = MIND(hi, r);
    }
    /* a margin far above the rounding of these sums, far below the slop */
    *u0 = lo + f->c[u] - 1e-7, *u1 = hi + f->c[u] + 1e-7;
    return *u0 <= *u1;
}

/* Region f's voxels in brick o (its first tile voxel) lowered to the
 * distance of f's triangles: d2 the brick's squared distances (x fastest),
 * the region scanned in rows along f->ax. */
static void feat_d2(const mesh_vox_tile *t, const dcpt *d, const dfeat *f, const int32_t o[3],
                    double R2, double *d2)
{
    uint32_t S = t->S;
    int ax = f->ax, u = (ax + 1) % 3, v = (ax + 2) % 3;
    int32_t lo[3], hi[3];
    for (int a = 0; a < 3; a++) {
        lo[a] = f->i0[a] > o[a] ? f->i0[a] : o[a];
        hi[a] = f->i1[a] < o[a] + (int32_t)S - 1 ? f->i1[a] : o[a] + (int32_t)S - 1;
    }
    /* the centre of tile voxel i along axis a: org[a] + i (exact: halves) */
    double org[3] = {(double)t->x0 + 0.5, (double)t->y0 + 0.5, 0.5};
    size_t step[3] = {1, S, (size_t)S * S};
    const uint32_t *tl = d->tl + f->t0;
    for (int32_t j = lo[v]; j <= hi[v]; j++) {
        double u0 = org[u] + lo[u], u1 = org[u] + hi[u];
        /* a face's rows all meet its prism: no slice test for them */
        if (f->quad && !slice_span(d, f, u, v, org[v] + j, org[ax] + lo[ax], org[ax] + hi[ax],
                                   R2, &u0, &u1))
            continue;
        int32_t i0 = iceil(u0 - org[u], lo[u], hi[u]), i1 = ifloor(u1 - org[u], lo[u], hi[u]);
        for (int32_t i = i0; i <= i1; i++) {
            double p[3], s0 = org[ax] + lo[ax], s1 = org[ax] + hi[ax];
            p[u] = org[u] + i, p[v] = org[v] + j;
            if (!row_span(d, f, u, v, p[u], p[v], R2, &s0, &s1)) continue;
            int32_t a = iceil(s0 - org[ax], lo[ax], hi[ax]), b = ifloor(s1 - org[ax], lo[ax], hi[ax]);
            double *row = d2 + (size_t)(i - o[u]) * step[u] + (size_t)(j - o[v]) * step[v];
            for (int32_t k = a; k <= b; k++) {
                double *e = row + (size_t)(k - o[ax]) * step[ax];
                p[ax] = org[ax] + k;
                for (uint32_t q = 0; q < f->nt; q++) {
                    double x = tri_d2(&d->tri[tl[q]], p);
                    *e = x < *e ? x : *e;
                }
            }
        }
    }
}

/* The voxels' squared distances (voxel units) in brick (bx, by, bz), from
 * the regions that reach it, starting from K^2 (nothing nearer). */
static void brick_d2(mesh_vox_tile *t, const dcpt *d, uint64_t k, uint32_t bx, uint32_t by,
                     uint32_t bz, uint32_t K, double *d2)
{
    uint32_t S = t->S;
    size_t n = (size_t)S * S * S;
    for (size_t i = 0; i < n; i++) d2[i] = (double)K * K;
    int32_t o[3] = {(int32_t)(bx * S), (int32_t)(by * S), (int32_t)(bz * S)};
    double R = K + DIST_SLOP;
    for (uint64_t j = d->start[k]; j < d->start[k + 1]; j++) {
        const dfeat *f = &d->f[d->list[j]];
        feat_d2(t, d, f, o, R * R, d2);
        if (mesh_vox_beat(&t->pulse, 8 * f->nt + 8)) return;
    }
}

/* 0 none, 2 every voxel, 1 some of brick (bx, by, bz)'s voxels inside. */
static int brick_sign(const mesh_vox_tile *t, uint32_t bx, uint32_t by, uint32_t bz)
{
    uint32_t S = t->S;
    uint64_t full = S == 64 ? ~0ull : ((1ull << S) - 1) << (bx * S), any = 0, all = full;
    for (uint32_t z = bz * S; z < (bz + 1) * S && z < t->nz; z++)
        for (uint32_t y = by * S; y < (by + 1) * S && y < t->ny; y++) {
            uint64_t w = t->occ[(size_t)z * t->ny + y] & full;
            any |= w;
            all &= w;
        }
    return !any ? 0 : all == full ? 2 : 1;
}

/* Brick (bx, by, bz): a uniform +w or -w when no triangle reaches it and
 * the solid agrees over it (inside the grid whole), else every voxel. */
static int dist_brick(mesh_vox_tile *t, const dcpt *d, const mesh_vox_bufs *b, uint32_t K, float w,
                      uint32_t bx, uint32_t by, uint32_t bz)
{
    uint32_t S = t->S;
    uint64_t k = ((uint64_t)bz * d->nb[1] + by) * d->nb[0] + bx;
    bool whole = (bx + 1) * S <= t->nx && (by + 1) * S <= t->ny && (bz + 1) * S <= t->nz;
    uint32_t at[3] = {t->x0 / S + bx, t->y0 / S + by, bz};
    if (d->start[k] == d->start[k + 1] && whole) {
        int sg = brick_sign(t, bx, by, bz);
        if (sg != 1) return vod_volume_put_uniform(t->vol, at, fbits(sg ? -w : w));
    }
    brick_d2(t, d, k, bx, by, bz, K, b->d2);
    if (t->pulse.stop) return -ECANCELED;
    float *out = (float *)(void *)b->brick;
    double vs = t->g->vs, KK = (double)K * K;
    for (uint32_t z = 0; z < S; z++)
        for (uint32_t y = 0; y < S; y++)
            for (uint32_t x = 0; x < S; x++) {
                size_t i = ((size_t)z * S + y) * S + x;
                uint32_t X = bx * S + x, Y = by * S + y, Z = bz * S + z;
                if (X >= t->nx || Y >= t->ny || Z >= t->nz) {
                    out[i] = 0.0f; /* past the grid: 0, as the volume wants */
                    continue;
                }
                double e = b->d2[i];
                if (!(e < KK)) { /* beyond the band: +-w, the same bits as sqrt(K^2) * vs */
                    out[i] = inside(t, X, Y, Z) ? -w : w;
                    continue;
                }
                double dist = sqrt(e);
                t->st->voxels++;
                out[i] = (float)((inside(t, X, Y, Z) ? -dist : dist) * vs);
            }
    return vod_volume_put_brick(t->vol, at, out);
}

int mesh_vox_dist_run(mesh_vox_tile *t, const mesh_vox_plan *p, const mesh_vox_bufs *b)
{
    dcpt d;
    int rc = mesh_cpt_make(t, p->band, &d);
    float w = mesh_dist_width(t->o, t->g->vs);
    for (uint32_t bz = 0; bz < d.nb[2] && !rc; bz++)
        for (uint32_t by = 0; by < d.nb[1] && !rc; by++)
            for (uint32_t bx = 0; bx < d.nb[0] && !rc; bx++)
                rc = dist_brick(t, &d, b, p->band, w, bx, by, bz);
    mesh_cpt_free(&d);
    return rc;
}
