/* mesh_surface — the voxels a triangle touches: Schwarz and Seidel's
 * triangle/box overlap ("Fast parallel surface and solid voxelization on
 * GPUs", 2010), a plane test and three 2D edge tests per voxel, in exact
 * integer arithmetic on the snapped triangle (mesh_vox_int.h).
 *
 * 26-separating (MESH_SURFACE): voxel boxes are closed, so a triangle that
 * only touches a box's face, edge or corner sets it.  The plane test asks
 * whether the plane meets the box (its two critical corners on either side
 * or on it); each projection on xy, yz and zx asks whether the projected
 * triangle meets the projected square (each edge's critical corner on the
 * inner side or on the edge).  With the plane test these are the 13 axes
 * of the separating axis theorem, so the result is exact.
 *
 * 6-separating (MESH_SURFACE6): the plane must meet the segment through the
 * voxel's centre along the normal's dominant axis, and each projection must
 * meet the diamond inscribed in the projected square.  A subset of the
 * 26-separating set, and thin: where two face-adjacent voxel centres lie on
 * either side of the surface, one of the two voxels is in it.
 *
 * An edge-on projection (normal component 0) is a segment: the edge tests
 * then ask whether its line meets the square, which the plane test already
 * implies unless the triangle is degenerate, a segment or a point. */
#include "mesh_vox_int.h"

#include <math.h>

typedef struct {
    int64_t ne[3][2]; /* edge normals in the projection, inner side > 0 */
    mesh_vox_i128 de[3];    /* test: ne . p + de >= 0, p the voxel's low corner */
    int64_t de64[3];  /* de, when it fits (a narrow triangle's: see below) */
} proj_test;

/* A triangle narrower than NARROW lattice units on every axis (the usual
 * one: 8 voxels) has edge normals below 2^19 in the projections and 2^39
 * in space.  With every coordinate below 2^40 (the clamp) and every voxel
 * corner tested within a voxel of its box (|p - P0| < 2^20), an edge
 * test's terms stay below 2^59 and 2^61 in all, the plane's below 2^59
 * each and 2^61 with the box's corner: 64-bit arithmetic gives the exact
 * 128-bit signs, several times faster. */
#define NARROW ((int64_t)1 << 19)

/* A projection: onto axes (a, c), dropping axis w; ns: the sign of the
 * normal's component w (>= 0: 1). */
typedef struct {
    int ns, a, c;
} proj_axes;

/* Projection ax of triangle P.  A narrow triangle's tests in 64 bits
 * (de64), any other's in 128 (de). */
static void proj_setup(const int64_t P[3][3], proj_axes ax, bool six, bool narrow, proj_test *pt)
{
    int ns = ax.ns, a = ax.a, c = ax.c;
    for (int i = 0; i < 3; i++) {
        const int64_t *p = P[i], *q = P[i == 2 ? 0 : i + 1];
        int64_t na = -ns * (q[c] - p[c]), nc = ns * (q[a] - p[a]);
        pt->ne[i][0] = na, pt->ne[i][1] = nc;
        int64_t m = na < 0 ? -na : na, mc = nc < 0 ? -nc : nc;
        /* six: the diamond's vertex furthest along ne; else the square's
         * corner furthest along ne */
        int64_t k0 = six ? MESH_VOX_H * (na + nc) : MESH_VOX_L * ((na > 0 ? na : 0) + (nc > 0 ? nc : 0));
        int64_t k1 = six ? MESH_VOX_H * (m > mc ? m : mc) : 0;
        if (narrow) {
            pt->de64[i] = -(na * p[a] + nc * p[c]) + k0 + k1;
        } else {
            mesh_vox_i128 d = -((mesh_vox_i128)na * p[a] + (mesh_vox_i128)nc * p[c]);
            pt->de[i] = d + k0 + k1;
        }
    }
}

static inline bool proj_pass(const proj_test *pt, int64_t pa, int64_t pc)
{
    for (int i = 0; i < 3; i++)
        if ((mesh_vox_i128)pt->ne[i][0] * pa + (mesh_vox_i128)pt->ne[i][1] * pc + pt->de[i] < 0)
            return false;
    return true;
}

static inline bool proj_pass64(const proj_test *pt, int64_t pa, int64_t pc)
{
    for (int i = 0; i < 3; i++)
        if (pt->ne[i][0] * pa + pt->ne[i][1] * pc + pt->de64[i] < 0) return false;
    return true;
}

/* Voxels X of the block whose closed boxes [X L, X L + L] meet [lo, hi]. */
static int voxel_range(const mesh_vox_block *b, int a, int64_t lo, int64_t hi,
                       int64_t *i0, int64_t *i1)
{
    int64_t s = mesh_vox_ceil_l(lo) - 1, e = mesh_vox_floor_l(hi);
    if (s < b->s0[a]) s = b->s0[a];
    if (e > b->s0[a] + b->n[a] - 1) e = b->s0[a] + b->n[a] - 1;
    *i0 = s, *i1 = e;
    return s <= e ? 0 : -1;
}

/* floor(q) for |q| < 2^62: a cast and a correction, floor() being a
 * library call without SSE4.1. */
static inline int64_t ifloor(double q)
{
    int64_t i = (int64_t)q;
    return i - (q < (double)i);
}

/* The triangle's plane as z over (x, y), in double: z at p0 plus the
 * gradient (gx, gy); spread: how far z moves within half a voxel of a
 * column's centre.  slanted: the plane is not vertical (n_z != 0). */
typedef struct {
    const int64_t *p0;
    double gx, gy, spread;
    bool slanted;
} z_plane;

/* The voxels [z0, z1] of the column at (px, py) that plane zp can reach,
 * from its z over the column in double (one voxel of margin covers the
 * rounding; the exact tests decide). */
static inline void z_range(const z_plane *zp, int64_t px, int64_t py, int64_t *z0, int64_t *z1)
{
    if (!zp->slanted) return;
    const int64_t *p0 = zp->p0;
    double gx = zp->gx, gy = zp->gy, spread = zp->spread;
    double zc = (double)p0[2] + gx * (double)(px + MESH_VOX_H - p0[0]) +
                gy * (double)(py + MESH_VOX_H - p0[1]);
    /* clamped to [z0 - 2, z1 + 2] first (the same voxels: past either end
     * the range is as empty or as whole), so the conversion is exact */
    double lo = (double)*z0 - 2, hi = (double)*z1 + 2;
    double qa = (zc - spread) / MESH_VOX_L, qc = (zc + spread) / MESH_VOX_L;
    qa = qa < lo ? lo : qa > hi ? hi : qa;
    qc = qc < lo ? lo : qc > hi ? hi : qc;
    int64_t a = ifloor(qa) - 1, c = ifloor(qc) + 1;
    if (a > *z0) *z0 = a;
    if (c < *z1) *z1 = c;
}

/* The voxels of block b that triangle P's bounding box covers, [i0, i1]
 * per axis, and whether the box is narrow (the 64-bit tests suffice);
 * nonzero when it covers none. */
static int tri_range(const int64_t P[3][3], const mesh_vox_block *b, int64_t i0[3], int64_t i1[3],
                     bool *narrow)
{
    int64_t lo[3], hi[3];
    for (int a = 0; a < 3; a++) {
        lo[a] = hi[a] = P[0][a];
        for (int i = 1; i < 3; i++) {
            if (P[i][a] < lo[a]) lo[a] = P[i][a];
            if (P[i][a] > hi[a]) hi[a] = P[i][a];
        }
        if (voxel_range(b, a, lo[a], hi[a], &i0[a], &i1[a])) return 1;
    }
    *narrow = hi[0] - lo[0] < NARROW && hi[1] - lo[1] < NARROW && hi[2] - lo[2] < NARROW;
    return 0;
}

/* The plane test's constants for normal n: the box's extremes lo_c, hi_c
 * (26-separating), the centre's offset half and the bound dom
 * (6-separating). */
static void plane_bounds(const mesh_vox_i128 n[3], mesh_vox_i128 *lo_c, mesh_vox_i128 *hi_c, mesh_vox_i128 *half,
                         mesh_vox_i128 *dom)
{
    *lo_c = *hi_c = *half = *dom = 0;
    for (int a = 0; a < 3; a++) {
        mesh_vox_i128 t = n[a] * MESH_VOX_L, m = n[a] < 0 ? -n[a] : n[a];
        if (t < 0) *lo_c += t;
        else *hi_c += t;
        *half += n[a] * MESH_VOX_H;
        if (m > *dom) *dom = m;
    }
    *dom *= MESH_VOX_H;
}

void mesh_vox_surface(const int64_t P[3][3], bool six, const mesh_vox_block *b, uint64_t *bits)
{
    int64_t i0[3], i1[3];
    bool narrow;
    if (tri_range(P, b, i0, i1, &narrow)) return;
    int64_t e1[3], e2[3];
    for (int a = 0; a < 3; a++) e1[a] = P[1][a] - P[0][a], e2[a] = P[2][a] - P[0][a];
    mesh_vox_i128 n[3] = {(mesh_vox_i128)e1[1] * e2[2] - (mesh_vox_i128)e1[2] * e2[1],
                    (mesh_vox_i128)e1[2] * e2[0] - (mesh_vox_i128)e1[0] * e2[2],
                    (mesh_vox_i128)e1[0] * e2[1] - (mesh_vox_i128)e1[1] * e2[0]};
    proj_test xy, yz, zx;
    proj_setup(P, (proj_axes){n[2] >= 0 ? 1 : -1, 0, 1}, six, narrow, &xy);
    proj_setup(P, (proj_axes){n[0] >= 0 ? 1 : -1, 1, 2}, six, narrow, &yz);
    proj_setup(P, (proj_axes){n[1] >= 0 ? 1 : -1, 2, 0}, six, narrow, &zx);
    /* plane: n . (p - P0) + lo_c <= 0 <= n . (p - P0) + hi_c over the box
     * (26), or |n . (centre - P0)| <= L/2 max |n_a| (6) */
    mesh_vox_i128 lo_c, hi_c, half, dom;
    plane_bounds(n, &lo_c, &hi_c, &half, &dom);
    /* the plane's z over a column, in double, narrows the z loop; the exact
     * tests decide (one voxel of margin covers the rounding) */
    z_plane zp = {.p0 = P[0], .slanted = n[2] != 0};
    if (zp.slanted) {
        double nzd = (double)n[2];
        zp.gx = -(double)n[0] / nzd, zp.gy = -(double)n[1] / nzd;
        zp.spread = (fabs(zp.gx) + fabs(zp.gy)) * MESH_VOX_H;
    }
    size_t n1 = (size_t)b->n[1], nw = b->nw;
    if (narrow) {
        int64_t n64[3] = {(int64_t)n[0], (int64_t)n[1], (int64_t)n[2]};
        int64_t lo64 = (int64_t)lo_c, hi64 = (int64_t)hi_c, half64 = (int64_t)half;
        int64_t dom64 = (int64_t)dom;
        for (int64_t Y = i0[1]; Y <= i1[1]; Y++)
            for (int64_t X = i0[0]; X <= i1[0]; X++) {
                int64_t px = X * MESH_VOX_L, py = Y * MESH_VOX_L;
                if (!proj_pass64(&xy, px, py)) continue;
                int64_t z0 = i0[2], z1 = i1[2];
                z_range(&zp, px, py, &z0, &z1);
                int64_t sxy = n64[0] * (px - P[0][0]) + n64[1] * (py - P[0][1]);
                size_t x = (size_t)(X - b->s0[0]), y = (size_t)(Y - b->s0[1]);
                for (int64_t Z = z0; Z <= z1; Z++) {
                    int64_t pz = Z * MESH_VOX_L, s = sxy + n64[2] * (pz - P[0][2]);
                    int64_t c = s + half64;
                    bool plane = six ? (c < 0 ? -c : c) <= dom64 : s + lo64 <= 0 && s + hi64 >= 0;
                    if (!plane || !proj_pass64(&yz, py, pz) || !proj_pass64(&zx, pz, px))
                        continue;
                    size_t z = (size_t)(Z - b->s0[2]);
                    bits[(z * n1 + y) * nw + x / 64] |= 1ull << (x & 63);
                }
            }
        return;
    }
    for (int64_t Y = i0[1]; Y <= i1[1]; Y++) {
        for (int64_t X = i0[0]; X <= i1[0]; X++) {
            int64_t px = X * MESH_VOX_L, py = Y * MESH_VOX_L;
            if (!proj_pass(&xy, px, py)) continue;
            int64_t z0 = i0[2], z1 = i1[2];
            z_range(&zp, px, py, &z0, &z1);
            mesh_vox_i128 sxy = n[0] * (px - P[0][0]) + n[1] * (py - P[0][1]);
            size_t x = (size_t)(X - b->s0[0]), y = (size_t)(Y - b->s0[1]);
            for (int64_t Z = z0; Z <= z1; Z++) {
                int64_t pz = Z * MESH_VOX_L;
                mesh_vox_i128 s = sxy + n[2] * (pz - P[0][2]);
                bool plane;
                if (six) {
                    mesh_vox_i128 c = s + half;
                    plane = (c < 0 ? -c : c) <= dom;
                } else {
                    plane = s + lo_c <= 0 && s + hi_c >= 0;
                }
                if (!plane || !proj_pass(&yz, py, pz) || !proj_pass(&zx, pz, px))
                    continue;
                size_t z = (size_t)(Z - b->s0[2]);
                bits[(z * n1 + y) * nw + x / 64] |= 1ull << (x & 63);
            }
        }
    }
}
