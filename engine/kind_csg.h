/* kind_csg — the CSG kind: a volume CSG tree (csg.h) evaluated brick by
 * brick on the engine's workers.  Its master side is kind_csg.c, its
 * worker side worker/work_csg.c.
 *
 * A pipeline job: the domain lo/hi as for an expression; the channel is the
 * density (vod.channel 2) or the occupancy (1: density >= S); the engine
 * evaluates the tree's bricks on its workers, the serial path in this
 * thread (csg_eval_volume), into the same volume layout, so the bytes are
 * the same. */
#ifndef VOXD_KIND_CSG_H
#define VOXD_KIND_CSG_H

#include <stdatomic.h>
#include <stdint.h>

#include "csg.h"
#include "engine.h"

/* Its master side, a pipeline job's kind (engine_pipeline_job.kind). */
extern const engine_kind engine_kind_csg;

/* Storage bricks evaluated, of which uniform (a table entry, no voxels
 * stored), operand subtrees decided from a uniform operand without
 * evaluating them, voxels the leaves sampled: a CSG job's figures, the
 * same in the pipeline's report (engine_pipeline_report.fig.csg). */
typedef struct {
    uint64_t bricks, uniform, skipped, voxel_evals;
} engine_csg_figures;

/* A volume CSG tree (csg.h) evaluated brick by brick into a brick-sparse
 * volume in shared memory (densities, occupancy or surface voxels): the
 * tree is copied into the segment, each worker evaluates runs of storage
 * bricks (csg_eval_store), and a worker that dies has its run evaluated
 * again (a brick is a pure function of the tree: the same bytes).  The
 * result stays for engine_write_vod, as a mesh job's.  Errors as
 * engine_mesh's. */
typedef struct {
    const csg_tree *tree;       /* parsed (and so checked) by the caller */
    grid_spec grid;
    int channel;                /* VOXEL_CH_DENSITY, _OCCUPANCY or _SURFACE (csg_eval_store) */
    void (*progress)(void *ud, const engine_progress *p);
    void *ud;
    const atomic_int *cancel;   /* as engine_job.cancel */
    /* NULL: every storage brick.  Else only the bricks inside this
     * octant's cube (vox_mpi's subtrees; its side a multiple of
     * CSG_VOLUME_BRICK), each as the whole grid's job makes it. */
    const grid_octant *root;
    engine_csg_figures *figures; /* optional: filled in when it returns */
} engine_csg_job;
int engine_csg(engine *e, const engine_csg_job *job, engine_result *r);

/* A pipeline job's input (engine_pipeline_job.csg). */
typedef struct {
    const csg_tree *tree;     /* parsed (and so checked) by the caller */
    const char *source_name;  /* its file's name, or NULL */
    uint64_t source_bytes;    /* its text's size, for the metadata */
} engine_csg_input;

#endif
