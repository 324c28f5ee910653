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
 * The root (level `depth`) is never tested; an octant whose low corner lies
 * outside res is never tested either (it holds no voxel).
 *
 * Tapes and reproducibility.  An octant at level L is always tested with
 * tape t = depth-1-L, and tape t+1 is always the one pruned (expr_vm_prune)
 * by the chain of its ancestors: the octant at level depth-1-s that contains
 * it, tested with tape s and pruned, for s = 0..t-1.  So whether a box is
 * kept, and a voxel's normal (taken with the tape its test used), depend on
 * the box alone, never on the order or the process that got there: the
 * serial algorithm, both engine schedules and any number of workers produce
 * the same voxels bit for bit.  A kernel remembers which chain its vm's tapes
 * were built for and rebuilds only the part that differs when it is handed
 * an octant elsewhere (a handful of evaluations, usually none or one).
 *
 * Batches.  The 8 children of an octant are tested in one pass over the
 * tape (expr_vm_ival8, a lane per child), and kept voxels get their
 * gradients up to 8 in one pass (expr_vm_grad8n): those of one level-1
 * octant, and in the subtree kernel those of consecutive level-1 octants
 * as long as tape depth-1 stays the same tape.  Each lane is computed
 * exactly as the one-box evaluators compute it, and the chain rebuild
 * evaluates its boxes with the same batched evaluator, so batching changes
 * nothing in what is kept, pruned or emitted, nor in the emission order.
 */
#ifndef VOXD_SUBDIV_H
#define VOXD_SUBDIV_H

#include <stddef.h>
#include <stdint.h>

#include "expr.h"
#include "grid.h"
#include "octree.h"

/* The world box of an octant (the one formula above). */
void subdiv_box(const grid_spec *g, grid_octant o, ival *x, ival *y,
                ival *z);

/* What the kernels produce.  A callback returning non-zero stops the
 * kernel, which returns that value.  poll (may be NULL) is called every
 * SUBDIV_POLL_TESTS box tests so a long subtree can be abandoned, and so
 * that the worker's heartbeat moves every few milliseconds even on a long
 * tape (512 tests of the 40-sine sphere of the tests: 4 ms). */
#define SUBDIV_POLL_TESTS 512u
typedef struct {
    int (*voxel)(void *ud, const grid_voxel *v);
    int (*octant)(void *ud, const grid_octant *o);
    int (*poll)(void *ud);
    void *ud;
} subdiv_sink;

/* A kernel: a vm over the job's tape plus the record of which ancestor
 * chain each of its pruned tapes was built for (see above). */
typedef struct {
    expr_vm *vm;
    const grid_spec *g;
    grid_octant chain[GRID_MAX_DEPTH]; /* chain[t]: built tape t+1 */
    int valid;          /* tapes 1..valid are built for chain[0..valid-1] */
    uint64_t tested;    /* boxes tested for the kernels' output */
    uint64_t rebuilt;   /* extra evaluations to rebuild chains */
    uint32_t poll_left;
} subdiv_kernel;

/* vm must have been made with max_depth >= g->depth; both must outlive k. */
void subdiv_kernel_init(subdiv_kernel *k, expr_vm *vm, const grid_spec *g);

/* Paper schedule: test the children of o (o.level >= 1, o kept by its own
 * test or the root) and emit the kept ones as octants, or as voxels when
 * o.level == 1, in child order. */
int subdiv_children(subdiv_kernel *k, grid_octant o, const subdiv_sink *s);

/* Subtree schedule: every voxel of o's subtree, depth first in child order
 * (so voxels arrive in octree preorder), pruning the tape on the way down.
 * o itself is assumed to have been kept by its parent's test (or to be the
 * root); o.level == 0 emits o as a voxel. */
int subdiv_subtree(subdiv_kernel *k, grid_octant o, const subdiv_sink *s);

/* The serial algorithm (Figure 1 with an explicit stack, the subtree kernel
 * on the root): the whole grid straight into the octree t (depth g->depth).
 * Returns 0, or -ENOMEM when t's arena is full or the vm cannot be made,
 * -EINVAL for a bad grid or a tree of another depth. */
int subdiv_serial(const expr_tape *tape, const grid_spec *g, octree *t);

#endif
