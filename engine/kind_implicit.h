/* kind_implicit — the implicit kind: F(x,y,z) = 0 by Stolte–Kaufman
 * subdivision on the engine's workers (Figure 3; engine.h's Schedules),
 * into an octree in shared memory.  Its master side is kind_implicit.c,
 * its worker side worker/work_implicit.c. */
#ifndef VOXD_KIND_IMPLICIT_H
#define VOXD_KIND_IMPLICIT_H

#include <stdatomic.h>

#include "engine.h"
#include "expr.h"
#include "octree.h"

/* Its master side, a pipeline job's kind (engine_pipeline_job.kind). */
extern const engine_kind engine_kind_implicit;

typedef struct {
    const expr_tape *tape;
    grid_spec grid;
    engine_schedule schedule;
    /* Called by the master now and then (at most ~10 times a second). */
    void (*progress)(void *ud, const engine_progress *p);
    void *ud;
    /* Set to non-zero by anyone to stop the job: engine_voxelize returns
     * -ECANCELED.  Read with relaxed loads; nothing pairs with it. */
    const atomic_int *cancel;
    /* Subtree schedule: octants of this level and below go out whole (a
     * subtree of 2^split_level voxels per axis); 0 = automatic (depth-3,
     * within 1..6: many more tasks than workers). */
    int split_level;
    /* NULL: the whole grid.  Else only this octant's subtree, the octant
     * taken as kept by its parent's test (vox_mpi hands a rank the octants
     * its rank 0 kept); the voxels are those the whole grid's job gives
     * inside it, and the automatic split level is taken from its level. */
    const grid_octant *root;
} engine_job;

/* Voxelize job; the octree stays in shared memory until the next job.
 * Returns 0, or a negative errno with r->err saying why (its kind):
 * ENGINE_CANCELLED, ENGINE_BAD_JOB, ENGINE_LIMIT (octree or work stack
 * full: the message says what to raise), ENGINE_CRASHED (an octant killed
 * its worker twice: the message names it), ENGINE_FAULT; the engine is then
 * ready for the next job.  A worker that dies during a job is forked again
 * and its octant handed out again (its output is deterministic, so the
 * entries already taken are skipped); see Robustness above. */
int engine_voxelize(engine *e, const engine_job *job, engine_result *r);
/* The last job's octree (a view into shared memory), NULL when the last
 * job failed, was not an implicit one, or there was none, or after
 * engine_release. */
octree *engine_octree(engine *e);

/* A pipeline job's input (engine_pipeline_job.implicit). */
typedef struct {
    const expr_tape *tape;    /* compiled by the caller (its messages) */
    const char *source;       /* the expression's text, for the metadata */
    size_t source_len;
    const char *source_name;  /* its file's name, or NULL */
} engine_implicit_input;

#endif
