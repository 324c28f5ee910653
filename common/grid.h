/* grid — the voxel grid of a job, and the one formula for its bounds.
 *
 * Voxel (X, Y, Z) is the box [lo + X*vs, lo + (X+1)*vs] per axis, always
 * computed by that one formula so that neighbouring boxes share their bounds
 * bit for bit and the union of the voxel boxes is the octant's box.  The
 * octree spans 2^depth voxels per axis; only voxels with X < res[0],
 * Y < res[1], Z < res[2] exist (the rest is padding and never emitted).
 *
 * An octant is given by its low voxel corner and its level: it covers
 * 2^level voxels per axis; level 0 is one voxel, level `depth` the whole grid.
 * The master, the workers, the VOD writer and the clients share this
 * arithmetic; it depends on nothing else.
 */
#ifndef VOXD_GRID_H
#define VOXD_GRID_H

#include <stddef.h>
#include <stdint.h>

#include "err.h"

#define GRID_MAX_RES 4096u
#define GRID_MAX_DEPTH 12 /* 2^12 = GRID_MAX_RES */

typedef struct {
    double lo[3];     /* domain low corner */
    double vs;        /* voxel size (cubic voxels) */
    uint32_t res[3];  /* voxels per axis, 1..4096 */
    int depth;        /* smallest d >= 1 with 2^d >= max(res) */
} grid_spec;

typedef struct {
    uint16_t x, y, z; /* low voxel corner */
    uint16_t level;   /* size 2^level voxels */
} grid_octant;

typedef struct {
    uint16_t x, y, z, pad;
    uint32_t value;   /* channel-3 voxel value (voxel.h) */
} grid_voxel;

/* Grid for res voxels along the longest axis of [lo, hi] (a box domain;
 * the other axes get ceil(extent / vs) voxels, at least 1).  The grid covers
 * the domain: lo + res[a]*vs >= hi[a].  -EINVAL with a message for an empty
 * or non-finite box or res outside 1..4096. */
int grid_make(const double lo[3], const double hi[3], uint32_t res,
                     grid_spec *g, err_info *err);
/* 0 when g is a grid grid_make could have made (res, depth, finite
 * lo and vs > 0), else -EINVAL: for grids that come from elsewhere. */
int grid_check(const grid_spec *g);

/* World coordinate lo[a] + X*vs: the one formula for every bound (X may be
 * fractional for centres: X + 0.5). */
static inline double grid_coord(const grid_spec *g, int a, double X)
{
    return g->lo[a] + X * g->vs;
}

/* The grid's root octant (level depth at the origin). */
static inline grid_octant grid_root(const grid_spec *g)
{
    return (grid_octant){0, 0, 0, (uint16_t)g->depth};
}

#endif
