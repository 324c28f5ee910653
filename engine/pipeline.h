/* pipeline — one job from its description to a VOD sink and a report.
 *
 * The daemon, `vox voxelize` and the benchmarks all run a job through
 * engine_pipeline_run: the grid from the domain and resolution, the metadata,
 * the voxelization (on an engine's workers, or the serial algorithm in the
 * caller's thread), then the VOD written to the caller's sink.  So the
 * bytes are the same wherever a job runs, by construction.
 *
 * What a kind does is its master side's (engine/kind_<name>.c, one row in
 * engine/kinds.c's table): its checks and domain, its metadata, its run
 * without and with an engine, its figures (its own block of the report,
 * engine_pipeline_report.fig) and their words (engine_pipeline_describe).  A kind that
 * comes with its own description adds its member to engine_pipeline_job.
 *
 * CSG jobs: the domain lo/hi as for an expression; the channel is the
 * density (vod.channel 2) or the occupancy (1: density >= S); the engine
 * evaluates the tree's bricks on its workers, the serial path in this
 * thread (csg_eval_volume), into the same volume layout, so the bytes are
 * the same.
 *
 * Mesh jobs: with mesh.fit, res voxels span the longest side of the
 * mesh's bounding box grown by pad voxels on each side (so the mesh
 * itself spans res - 2 pad voxels); without it, the domain lo/hi as for an
 * expression.  Every mesh job's report has the mesh's topology; a repair
 * asked of a watertight mesh is not run (a closed mesh's parities along x,
 * y and z agree: the voxels are the plain solid's), so it costs nothing.
 */
#ifndef VOXD_PIPELINE_H
#define VOXD_PIPELINE_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include "csg.h"
#include "engine.h"
#include "job_meta.h"
#include "expr.h"
#include "grid.h"
#include "mesh_vox.h"
#include "vod.h"

typedef enum {
    ENGINE_PIPELINE_IMPLICIT = 1, /* F(x,y,z) = 0 */
    ENGINE_PIPELINE_MESH = 2,     /* a triangle mesh */
    ENGINE_PIPELINE_CSG = 3,      /* a volume CSG tree (csg.h) */
    ENGINE_PIPELINE_KINDS
} engine_pipeline_kind;

typedef struct {
    engine_pipeline_kind kind;
    struct {
        const expr_tape *tape;    /* compiled by the caller (its messages) */
        const char *source;       /* the expression's text, for the metadata */
        size_t source_len;
        const char *source_name;  /* its file's name, or NULL */
    } implicit;
    struct {
        const mesh *mesh;         /* loaded (and so checked) by the caller */
        mesh_vox_opts opts;
        uint32_t pad;             /* voxels around the bounding box (fit) */
        int fit;                  /* 1: the domain is the mesh's bounding box
                                     plus pad voxels, lo/hi are ignored */
        const char *source_name;  /* its file's name, or NULL */
        uint64_t source_bytes;    /* its file's size, for the metadata */
    } mesh;
    struct {
        const csg_tree *tree;     /* parsed (and so checked) by the caller */
        const char *source_name;  /* its file's name, or NULL */
        uint64_t source_bytes;    /* its text's size, for the metadata */
    } csg;
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

/* A mesh job's figures: its voxelization's (tiles and t_bin on an engine
 * only), and what the pipeline found of the mesh. */
typedef struct {
    engine_mesh_figures vox;
    uint32_t triangles;
    mesh_topo topo;               /* its edges (mesh_edges: no components, no volume) */
    double t_topology;            /* ... seconds finding them */
    int repair_skipped;           /* a repair asked of a watertight mesh: not
                                     needed (its three parities agree) */
} engine_pipeline_mesh_figures;

/* A kind's own figures, its member the one its kind fills. */
typedef union {
    engine_pipeline_mesh_figures mesh;
    engine_csg_figures csg;
} engine_pipeline_figures;

typedef struct {
    grid_spec grid;
    uint64_t voxels;
    uint64_t octants;             /* boxes tested (engine only) */
    uint32_t restarts;            /* workers forked again (engine only) */
    uint32_t stalls;              /* ... of which had stalled (engine only) */
    double t_voxelize, t_write;   /* wall seconds of the two stages */
    double t_job;                 /* wall seconds of engine_pipeline_run but the
                                     engine's release at its end (a mesh's
                                     topology, without a repair and on an
                                     engine, overlaps the voxelization:
                                     t_job, not the sum, is the job's time) */
    double master_cpu, worker_cpu;
    int workers;                  /* the engine's, 0: the serial algorithm */
    engine_pipeline_figures fig;         /* the job's kind's own (set from the
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

/* The kind's figures of job (r: engine_pipeline_run's) in words, for vox: a
 * mesh's as lines of their own, a csg tree's bricks as a clause; "" when
 * the kind has none. */
void engine_pipeline_describe(const engine_pipeline_job *job, const engine_pipeline_report *r, char *buf,
                       size_t len);

/* The job's distance band in voxels (VOXEL_BAND_DEFAULT when not given). */
uint32_t engine_pipeline_band(const engine_pipeline_job *job);

#endif
