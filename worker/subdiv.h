/* subdiv — recursive octree subdivision with interval arithmetic (the kernel).
 *
 * The grid: voxel (X, Y, Z) is the box [lo + X*vs, lo + (X+1)*vs] per axis,
 * always computed by that one formula so that neighbouring boxes share their
 * bounds bit for bit and the union of the voxel boxes is the octant's box.
 * The octree spans 2^depth voxels per axis; only voxels with X < res[0],
 * Y < res[1], Z < res[2] exist (the rest is padding and never emitted).
 *
 * An octant is given by its low voxel corner and its level: it covers 2^level
 * voxels per axis; level 0 is one voxel, level `depth` the whole grid.
 * A box is kept when F's interval on it contains 0; a kept voxel is emitted
 * with the normalized gradient at its centre packed as a channel-3 value.
 */
#ifndef VOXD_SUBDIV_H
#define VOXD_SUBDIV_H

#include <stdint.h>

#include "expr.h"
#include "octree.h"

typedef struct {
    double lo[3];     /* domain low corner */
    double vs;        /* voxel size (cubic voxels) */
    uint32_t res[3];  /* voxels per axis, 1..4096 */
    int depth;        /* smallest d >= 1 with 2^d >= max(res) */
} subdiv_grid;

typedef struct {
    uint16_t x, y, z; /* low voxel corner */
    uint16_t level;   /* size 2^level voxels */
} subdiv_octant;

typedef struct {
    uint16_t x, y, z, pad;
    uint32_t value;   /* channel-3 voxel value (voxel.h) */
} subdiv_voxel;

/* Grid for res voxels along the longest axis of [lo, hi] (a box domain;
 * the other axes get ceil(extent / vs) voxels, at least 1).  -EINVAL with
 * a message for an empty or non-finite box or res outside 1..4096. */
int subdiv_grid_make(const double lo[3], const double hi[3], uint32_t res,
                     subdiv_grid *g, char *err, size_t errlen);

/* The world box of an octant (the one formula above). */
void subdiv_box(const subdiv_grid *g, subdiv_octant o, ival *x, ival *y,
                ival *z);

/* What the kernels produce.  A callback returning non-zero stops the
 * kernel, which returns that value. */
typedef struct {
    int (*voxel)(void *ud, const subdiv_voxel *v);
    int (*octant)(void *ud, const subdiv_octant *o);
    void *ud;
} subdiv_sink;

/* Paper schedule: test the 8 children of o (o.level >= 1) with the vm's
 * full tape; emit kept children as octants, or as voxels when o.level == 1. */
int subdiv_children(expr_vm *vm, const subdiv_grid *g, subdiv_octant o,
                    const subdiv_sink *s);

/* Subtree schedule: every voxel of o's subtree, depth first in child order
 * (so voxels arrive in octree preorder), pruning the tape on the way down.
 * o itself is assumed to have been kept by its parent's test. */
int subdiv_subtree(expr_vm *vm, const subdiv_grid *g, subdiv_octant o,
                   const subdiv_sink *s);

/* The serial algorithm (Figure 1 with an explicit stack): the whole grid
 * straight into the octree t (depth g->depth).  Returns 0, or -ENOMEM when
 * t's arena is full, or what a progress callback returned. */
int subdiv_serial(const expr_tape *tape, const subdiv_grid *g, octree *t);

#endif
