/* pipeline — one job from its description to a VOD sink and a report.
 *
 * The daemon, `vox voxelize` and the benchmarks all run a job through
 * engine_pipeline_run: the grid from the domain and resolution, the metadata,
 * the voxelization (on an engine's workers, or the serial algorithm in the
 * caller's thread), then the VOD written to the caller's sink.  So the
 * bytes are the same wherever a job runs, by construction.
 *
 * What a kind does is its master side's (engine/kind_<name>.c and its
 * header engine/kind_<name>.h, one row in pipeline_kinds.h): its
 * checks and domain, its metadata, its run without and with an engine,
 * its figures (its own block of the report, engine_pipeline_report.fig)
 * and their words (engine_pipeline_describe).  Its input is its own
 * member of engine_pipeline_job.
 */
#ifndef VOXD_PIPELINE_H
#define VOXD_PIPELINE_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include "engine.h"
#include "grid.h"
#include "job_meta.h"
#include "pipeline_kinds.h"
#include "vod.h"

typedef struct {
    /* What it is: &engine_kind_<name> (engine/kind_<name>.h), which reads
     * its own member of the union (pipeline_kinds.h). */
    const engine_kind *kind;
    union {
        ENGINE_PIPELINE_INPUTS
    };
    double lo[3], hi[3];          /* the domain */
    uint32_t res;                 /* voxels along its longest axis */
    engine_schedule schedule;
    uint32_t band;                /* channel 4: voxels each side, 0 the default */
    /* Channel, brick, compression, hash; the geometry and the metadata
     * are the job's and filled in here. */
    vod_params vod;
    /* Watching it (all optional; progress only with an engine): one
     * fraction over the voxelization and the VOD, 1 only once the VOD is
     * written. */
    void (*progress)(void *ud, const engine_progress *p);
    void *ud;
    const atomic_int *cancel;     /* see engine_job.cancel */
} engine_pipeline_job;

typedef enum { ENGINE_PIPELINE_GRID, ENGINE_PIPELINE_VOXELIZE, ENGINE_PIPELINE_WRITE } engine_pipeline_stage;

typedef struct {
    grid_spec grid;
    uint64_t voxels;
    uint64_t octants;             /* boxes tested (engine only) */
    uint32_t restarts;            /* workers forked again (engine only) */
    uint32_t stalls;              /* ... of which had stalled (engine only) */
    uint32_t offered;             /* tasks offered to a busy worker ahead (engine only) */
    double t_voxelize, t_write;   /* wall seconds of the two stages */
    double t_job;                 /* wall seconds of engine_pipeline_run but the
                                     engine's release at its end (a mesh's
                                     topology, without a repair and on an
                                     engine, overlaps the voxelization:
                                     t_job, not the sum, is the job's time) */
    double master_cpu, worker_cpu;
    int workers;                  /* the engine's, 0: the serial algorithm */
    engine_pipeline_figures fig;  /* the job's kind's own (set from the
                                     domain's checks on) */
    vod_stats st;
    engine_pipeline_stage stage;         /* the stage reached (that failed, if so) */
    engine_error err;             /* why it failed */
} engine_pipeline_report;

/* The job's grid (into r->grid) and the VOD parameters engine_pipeline_run
 * writes it with (v, its metadata in meta), without running it: what
 * vox_mpi's rank 0 needs to write the same file from bricks made
 * elsewhere.  0, or a negative errno with r->err saying why. */
int engine_pipeline_plan(const engine_pipeline_job *job, engine_pipeline_report *r, vod_params *v,
                  char meta[JOB_META_MAX]);

/* Run job; e NULL runs the serial algorithm in this thread.  Returns 0, or
 * a negative errno with r->err saying why and r->stage where. */
int engine_pipeline_run(engine *e, const engine_pipeline_job *job, vod_sink *sink,
                 engine_pipeline_report *r);

/* The kind's figures of job (r: engine_pipeline_run's) in words, for vox
 * (its kind's summary hook: lines of their own or a clause, as the kind
 * says); "" when the kind has none. */
void engine_pipeline_describe(const engine_pipeline_job *job, const engine_pipeline_report *r, char *buf,
                       size_t len);

/* The job's distance band in voxels (VOXEL_BAND_DEFAULT when not given). */
uint32_t engine_pipeline_band(const engine_pipeline_job *job);

#endif
