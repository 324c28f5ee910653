/* pipeline_kinds — the kinds a pipeline job may be, one row each: its
 * header (engine/kind_<name>.h, beside its master file), its input as a
 * member of engine_pipeline_job, its figures (if it has any) as a member
 * of the report's.  A job's kind is its engine_kind (engine_pipeline_job.kind):
 * nothing else numbers or names the kinds.
 */
#ifndef VOXD_PIPELINE_KINDS_H
#define VOXD_PIPELINE_KINDS_H

#include "kind_csg.h"
#include "kind_implicit.h"
#include "kind_mesh.h"

/* Each kind's input: engine_pipeline_job's anonymous union, the member
 * its kind reads (job.mesh.opts). */
#define ENGINE_PIPELINE_INPUTS      \
    engine_implicit_input implicit; \
    engine_mesh_input mesh;         \
    engine_csg_input csg;

/* Each kind's figures, the member its kind fills (engine_pipeline_report.fig). */
typedef union {
    engine_mesh_report mesh;
    engine_csg_figures csg;
} engine_pipeline_figures;

#endif
