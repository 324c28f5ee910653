/* mesh_dist_int — what mesh_dist.c (the distance's bricks) and mesh_cpt.c
 * (the closest-point transform's regions) share; not an interface. */
#ifndef VOXD_MESH_DIST_INT_H
#define VOXD_MESH_DIST_INT_H

#include <stdbool.h>
#include <stdint.h>

#include "mesh_vox_int.h"

/* Every region is grown by this much (voxels) in each of its half spaces
 * and its radius: the margin of the rounding (see mesh_cpt.c). */
#define DIST_SLOP 1e-4
/* At most this many half spaces a region (more would only shrink it). */
#define DIST_MAXH 16
/* A tile's distance is made in slabs of this many voxels in z (a multiple
 * of any storage brick; the slab's squared distances are MESH_TILE^2 x
 * DIST_SLAB doubles, mesh_vox_bufs.d2): each region is scanned once per
 * slab it meets, whatever bricks it crosses. */
#define DIST_SLAB MESH_TILE

/* A triangle in voxel units: vertex a, edges ab and ac, its unit normal
 * (0 when degenerate), and the voxel centres its box grown by the band
 * reaches, [i0, i1] per axis (relative to the tile).  deg: too thin for
 * its normal to be trusted (its regions are its whole grown box). */
typedef struct {
    double a[3], ab[3], ac[3], n[3];
    double m[3][3], c[3]; /* the edges' outward normals in its plane, their offsets */
    double lo[3], hi[3];  /* its box */
    int32_t i0[3], i1[3];
    bool deg;
} dtri;

/* A region of the closest-point transform: the voxels of box [i0, i1]
 * (tile voxels) inside the half spaces a . p <= b of hs[h0 .. h0 + nh)
 * and, quad 1, within r of point c, quad 2, within r of the line c + s u
 * (quad 0: c a point of the region, the origin of its slices' arithmetic);
 * each such voxel takes the distance of the triangles tl[t0 .. t0 + nt).
 * It is scanned in rows along axis ax: the one its region is longest
 * along, so that the rows are few. */
typedef struct {
    int32_t i0[3], i1[3];
    uint32_t h0, nh, t0, nt;
    int quad, ax;
    double c[3], u[3];
} dfeat;

/* A tile's triangles and regions, and per slab of the tile (DIST_SLAB
 * voxels in z) the regions whose box meets it: list[start[s] ..
 * start[s + 1]). */
typedef struct {
    dtri *tri;
    uint32_t ntri;
    dfeat *f;
    uint32_t nf;
    double (*hs)[4];
    uint32_t nhs;
    uint32_t *tl;
    uint32_t ntl;
    uint32_t nslab;
    uint64_t *start;
    uint32_t *list;
} dcpt;

/* The regions of the tile's triangles t->ids (dtri already made, in
 * d->tri), binned to its slabs.  0 or -ENOMEM (d freed by mesh_cpt_free in
 * any case). */
int mesh_cpt_make(const mesh_vox_tile *t, uint32_t K, dcpt *d);
void mesh_cpt_free(dcpt *d);

/* The axis of v's largest (ax 1) or smallest (ax 0) component. */
static inline int axis_of(const double v[3], bool largest)
{
    double a = v[0] < 0 ? -v[0] : v[0], b = v[1] < 0 ? -v[1] : v[1], c = v[2] < 0 ? -v[2] : v[2];
    if (largest) return a >= b && a >= c ? 0 : b >= c ? 1 : 2;
    return a <= b && a <= c ? 0 : b <= c ? 1 : 2;
}

static inline double dot3(const double *u, const double *v)
{
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
}

/* ceil(q) and floor(q) as integers, clamped to [lo, hi + 1] and [lo - 1,
 * hi] (an empty range stays empty). */
static inline int32_t iceil(double q, int32_t lo, int32_t hi)
{
    if (!(q > lo)) return lo;
    if (q > hi) return hi + 1;
    int32_t i = (int32_t)q;
    return i + (q > (double)i);
}
static inline int32_t ifloor(double q, int32_t lo, int32_t hi)
{
    if (!(q < hi)) return hi;
    if (q < lo) return lo - 1;
    int32_t i = (int32_t)q;
    return i - (q < (double)i);
}

#endif
