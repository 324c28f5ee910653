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
#include "mesh_vox_int.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "voxel.h"

float mesh_dist_width(const mesh_vox_opts *o, double vs)
{
    return (float)(mesh_vox_band(o) * vs);
}

/* A triangle in voxel units: vertex a, edges ab and ac, its unit normal
 * (0 when degenerate), and the voxel centres its box grown by the band
 * reaches, [i0, i1] per axis (relative to the tile). */
typedef struct {
    double a[3], ab[3], ac[3], n[3];
    double m[3][3], c[3]; /* the edges' outward normals in its plane, their offsets */
    double inv_nx;        /* 1 / n[0] (0 when n[0] is) */
    double lo[3], hi[3];  /* its box */
    int32_t i0[3], i1[3];
} dtri;

static double dot3(const double *u, const double *v)
{
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
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

/* ceil(q) and floor(q) as integers, clamped to [lo, hi + 1] and [lo - 1,
 * hi] (an empty range stays empty). */
static int32_t iceil(double q, int32_t lo, int32_t hi)
{
    if (!(q > lo)) return lo;
    if (q > hi) return hi + 1;
    int32_t i = (int32_t)q;
    return i + (q > (double)i);
}
static int32_t ifloor(double q, int32_t lo, int32_t hi)
{
    if (!(q < hi)) return hi;
    if (q < lo) return lo - 1;
    int32_t i = (int32_t)q;
    return i - (q < (double)i);
}

/* The lower bound's planes of d (brick_d2): for each edge P -> Q (ab, bc,
 * ca, counter-clockwise about n) the unit normal m = (Q - P) x n / |Q - P|,
 * in the plane and pointing away from the third vertex, and its offset c =
 * m . (P - a); a point's signed distance to the edge's line, within the
 * plane, is m . (p - a) - c.  A degenerate triangle (n = 0) gets m = 0 and
 * c = +inf: no bound from its plane or edges. */
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
    d->inv_nx = d->n[0] != 0 ? 1 / d->n[0] : 0;
}

/* Triangle id of the mesh in voxel units relative to the tile, with the
 * tile's voxels its grown box reaches; false when it reaches none. */
static bool make_dtri(const mesh_vox_tile *t, uint32_t id, double K, dtri *d)
{
    const mesh *m = t->m;
    double v[3][3];
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++)
            v[i][a] = ((double)m->vertices[m->triangles[id][i]][a] - t->g->lo[a]) / t->g->vs;
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
    edge_planes(d);
    return true;
}

/* The tile's triangles and, per storage brick of the tile (bx fastest,
 * then by, then bz), the indices of those whose grown box meets it:
 * list[start[k] .. start[k + 1]). */
typedef struct {
    dtri *tri;
    uint32_t ntri;
    uint32_t nb[3];  /* bricks of the tile per axis */
    uint64_t *start;
    uint32_t *list;
} dbins;

static void dbins_free(dbins *d)
{
    free(d->tri);
    free(d->start);
    free(d->list);
}

static uint64_t brick_index(const dbins *d, uint32_t bx, uint32_t by, uint32_t bz)
{
    return ((uint64_t)bz * d->nb[1] + by) * d->nb[0] + bx;
}

/* Each triangle into the bricks its grown box meets, in the tile's
 * triangle order (a counting sort: counted, then filed). */
static int dbins_make(const mesh_vox_tile *t, uint32_t K, dbins *d)
{
    uint32_t S = t->S;
    memset(d, 0, sizeof *d);
    d->nb[0] = (t->nx + S - 1) / S, d->nb[1] = (t->ny + S - 1) / S;
    d->nb[2] = (t->nz + S - 1) / S;
    uint64_t nbr = (uint64_t)d->nb[0] * d->nb[1] * d->nb[2];
    d->tri = malloc((t->n ? t->n : 1) * sizeof *d->tri);
    d->start = calloc(nbr + 1, sizeof *d->start);
    if (!d->tri || !d->start) return -ENOMEM;
    for (size_t i = 0; i < t->n; i++)
        if (make_dtri(t, t->ids[i], K, &d->tri[d->ntri])) d->ntri++;
    for (int pass = 0; pass < 2; pass++) {
        for (uint32_t i = 0; i < d->ntri; i++) {
            const dtri *r = &d->tri[i];
            for (uint32_t bz = (uint32_t)r->i0[2] / S; bz <= (uint32_t)r->i1[2] / S; bz++)
                for (uint32_t by = (uint32_t)r->i0[1] / S; by <= (uint32_t)r->i1[1] / S; by++)
                    for (uint32_t bx = (uint32_t)r->i0[0] / S; bx <= (uint32_t)r->i1[0] / S;
                         bx++) {
                        uint64_t k = brick_index(d, bx, by, bz);
                        if (pass) d->list[d->start[k]++] = i;
                        else d->start[k + 1]++;
                    }
        }
        if (pass) break;
        for (uint64_t k = 0; k < nbr; k++) d->start[k + 1] += d->start[k];
        if (!(d->list = malloc((d->start[nbr] ? d->start[nbr] : 1) * sizeof *d->list)))
            return -ENOMEM;
    }
    /* filing left start[k] at the end of brick k, the start of k + 1 */
    for (uint64_t k = nbr; k > 0; k--) d->start[k] = d->start[k - 1];
    d->start[0] = 0;
    return 0;
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

/* The squared distance from c to [lo, hi] along one axis. */
static inline double gap2(double c, double lo, double hi)
{
    double g = c < lo ? lo - c : c > hi ? c - hi : 0;
    return g * g;
}

/* A triangle's lower bound along a row of voxels: at x (voxel units from
 * the triangle's vertex a), the height above its plane h = h0 + n_x x and
 * the distances to its edges' lines e_i = e0[i] + m_i,x x.  The distance to the
 * triangle is at least that to its plane and, within the plane, that to
 * the half plane of any edge (the triangle lies in all three), so
 *     d^2 >= h^2 + max(0, e_0, e_1, e_2)^2,
 * exact inside the face's and the edges' prisms, where the closest point of
 * most voxels lies; Ericson's test runs only where the bound is below the
 * voxel's best so far.  The bound is computed near a (small numbers, an
 * error far below SLACK): a triangle it skips is farther than the best by
 * more than both rounding errors, so the minimum is the one every triangle
 * would give, bit for bit. */
#define SLACK 1e-9

/* The x (voxel units from r's vertex a) of a row at py, pz where r's plane
 * is nearer than K: [*x0, *x1] shrunk to |h0 + n_x x| < K (and a little,
 * for the rounding), with h0 the height at x = 0 in *h0. */
static inline void slab(const dtri *r, double py, double pz, double K, double *h0,
                        double *x0, double *x1)
{
    double B = K + 1e-6;
    *h0 = r->n[1] * (py - r->a[1]) + r->n[2] * (pz - r->a[2]);
    if (r->n[0] == 0) {
        if (!(fabs(*h0) < B)) *x1 = -INFINITY;
        return;
    }
    double q0 = (-B - *h0) * r->inv_nx, q1 = (B - *h0) * r->inv_nx;
    if (q0 > q1) {
        double q = q0;
        q0 = q1, q1 = q;
    }
    *x0 = q0 > *x0 ? q0 : *x0;
    *x1 = q1 < *x1 ? q1 : *x1;
}

/* Row y, z of the brick's squared distances (row[x] for the tile's x in
 * [lo, hi]) lowered by triangle r: Ericson's test only where the bound is
 * below the voxel's best. */
static void row_d2(const mesh_vox_tile *t, const dtri *r, double py, double pz, int32_t lo,
                   int32_t hi, double K, double *row)
{
    double ax = r->a[0] - t->x0 - 0.5, x0 = lo - ax, x1 = hi - ax, h0; /* x = X - ax */
    slab(r, py, pz, K, &h0, &x0, &x1);
    int32_t a = iceil(x0 + ax, lo, hi), b = ifloor(x1 + ax, lo, hi);
    if (a > b) return;
    double e0[3], y = py - r->a[1], z = pz - r->a[2], p[3] = {0, py, pz};
    for (int i = 0; i < 3; i++) e0[i] = r->m[i][1] * y + r->m[i][2] * z - r->c[i];
    for (int32_t x = a; x <= b; x++) {
        double u = x - ax, h = h0 + r->n[0] * u, e = 0;
        for (int i = 0; i < 3; i++) {
            double ei = e0[i] + r->m[i][0] * u;
            e = ei > e ? ei : e;
        }
        if (h * h + e * e > row[x] + SLACK) continue;
        p[0] = (double)(t->x0 + (uint32_t)x) + 0.5;
        double d2 = tri_d2(r, p);
        if (d2 < row[x]) row[x] = d2;
    }
}

/* The voxels' squared distances (voxel units) in brick (bx, by, bz), from
 * its triangles, starting from K^2 (nothing nearer).  The distance to a
 * triangle's box is a lower bound of the distance to it: a row whose
 * (y, z) lies K or more from the box is skipped; in the others the slab
 * |h| < K cuts the row and the bound of row_d2 skips most voxels. */
static void brick_d2(mesh_vox_tile *t, const dbins *d, uint32_t bx, uint32_t by, uint32_t bz,
                     uint32_t K, double *d2)
{
    uint32_t S = t->S;
    size_t n = (size_t)S * S * S;
    for (size_t i = 0; i < n; i++) d2[i] = (double)K * K;
    uint64_t k = brick_index(d, bx, by, bz);
    int32_t o[3] = {(int32_t)(bx * S), (int32_t)(by * S), (int32_t)(bz * S)};
    double KK = (double)K * K;
    for (uint64_t j = d->start[k]; j < d->start[k + 1]; j++) {
        const dtri *r = &d->tri[d->list[j]];
        int32_t lo[3], hi[3];
        for (int a = 0; a < 3; a++) {
            lo[a] = r->i0[a] > o[a] ? r->i0[a] : o[a];
            hi[a] = r->i1[a] < o[a] + (int32_t)S - 1 ? r->i1[a] : o[a] + (int32_t)S - 1;
        }
        for (int32_t z = lo[2]; z <= hi[2]; z++) {
            double pz = z + 0.5, gz = gap2(pz, r->lo[2], r->hi[2]);
            for (int32_t y = lo[1]; y <= hi[1]; y++) {
                double py = (double)(t->y0 + (uint32_t)y) + 0.5;
                if (gz + gap2(py, r->lo[1], r->hi[1]) >= KK) continue;
                double *row = d2 + ((size_t)(z - o[2]) * S + (size_t)(y - o[1])) * S - o[0];
                row_d2(t, r, py, pz, lo[0], hi[0], K, row);
            }
        }
        if (mesh_vox_beat(&t->pulse, (uint32_t)(hi[0] - lo[0] + 1) * (uint32_t)(hi[1] - lo[1] + 1) *
                                   (uint32_t)(hi[2] - lo[2] + 1) / 4 + 1))
            return;
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
static int dist_brick(mesh_vox_tile *t, const dbins *d, const mesh_vox_bufs *b, uint32_t K, float w,
                      uint32_t bx, uint32_t by, uint32_t bz)
{
    uint32_t S = t->S;
    uint64_t k = brick_index(d, bx, by, bz);
    bool whole = (bx + 1) * S <= t->nx && (by + 1) * S <= t->ny && (bz + 1) * S <= t->nz;
    uint32_t at[3] = {t->x0 / S + bx, t->y0 / S + by, bz};
    if (d->start[k] == d->start[k + 1] && whole) {
        int sg = brick_sign(t, bx, by, bz);
        if (sg != 1) return vod_volume_put_uniform(t->vol, at, fbits(sg ? -w : w));
    }
    brick_d2(t, d, bx, by, bz, K, b->d2);
    if (t->pulse.stop) return -ECANCELED;
    float *out = (float *)(void *)b->brick;
    double vs = t->g->vs;
    for (uint32_t z = 0; z < S; z++)
        for (uint32_t y = 0; y < S; y++)
            for (uint32_t x = 0; x < S; x++) {
                size_t i = ((size_t)z * S + y) * S + x;
                uint32_t X = bx * S + x, Y = by * S + y, Z = bz * S + z;
                if (X >= t->nx || Y >= t->ny || Z >= t->nz) {
                    out[i] = 0.0f; /* past the grid: 0, as the volume wants */
                    continue;
                }
                double e = b->d2[i], dist = sqrt(e);
                t->st->voxels += e < (double)K * K;
                out[i] = (float)((inside(t, X, Y, Z) ? -dist : dist) * vs);
            }
    return vod_volume_put_brick(t->vol, at, out);
}

int mesh_vox_dist_run(mesh_vox_tile *t, const mesh_vox_plan *p, const mesh_vox_bufs *b)
{
    dbins d;
    int rc = dbins_make(t, p->band, &d);
    float w = mesh_dist_width(t->o, t->g->vs);
    for (uint32_t bz = 0; bz < d.nb[2] && !rc; bz++)
        for (uint32_t by = 0; by < d.nb[1] && !rc; by++)
            for (uint32_t bx = 0; bx < d.nb[0] && !rc; bx++)
                rc = dist_brick(t, &d, b, p->band, w, bx, by, bz);
    dbins_free(&d);
    return rc;
}
