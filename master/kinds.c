/* The master's side of every kind of job a pipeline runs: pipeline_job's
 * kind is an index here, as a task's kind is in worker/worker.c's table.
 * Each kind is one master_kind (master.h) in its own file,
 * master/kind_<name>.c; the engine runs the encode and iso kinds, which
 * are no pipeline job, by their engine_<kind> call alone. */
#include "master.h"

const master_kind *const pipeline_kinds[PIPELINE_KINDS] = {
    [PIPELINE_IMPLICIT] = &kind_implicit,
    [PIPELINE_MESH] = &kind_mesh,
    [PIPELINE_CSG] = &kind_csg,
};
