/* The master's side of every kind of job a pipeline runs: engine_pipeline_job's
 * kind is an index here, as a task's kind is in worker/worker.c's table.
 * Each kind is one engine_kind (master.h) in its own file,
 * engine/kind_<name>.c; the engine runs the encode and iso kinds, which
 * are no pipeline job, by their engine_<kind> call alone. */
#include "master.h"

const engine_kind *const engine_pipeline_kinds[ENGINE_PIPELINE_KINDS] = {
    [ENGINE_PIPELINE_IMPLICIT] = &engine_kind_implicit,
    [ENGINE_PIPELINE_MESH] = &engine_kind_mesh,
    [ENGINE_PIPELINE_CSG] = &engine_kind_csg,
};
