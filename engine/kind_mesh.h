/* kind_mesh — the mesh kind: a triangle mesh voxelized tile by tile on
 * the engine's workers.  Its master side is kind_mesh.c, its worker side
 * worker/work_mesh.c.
 *
 * A pipeline job: with mesh.fit, res voxels span the longest side of the
 * mesh's bounding box grown by pad voxels on each side (so the mesh
 * itself spans res - 2 pad voxels); without it, the domain lo/hi as for an
 * expression.  Every mesh job's report has the mesh's topology; a repair
 * asked of a watertight mesh is not run (a closed mesh's parities along x,
 * y and z agree: the voxels are the plain solid's), so it costs nothing. */
#ifndef VOXD_KIND_MESH_H
#define VOXD_KIND_MESH_H

#include <stdatomic.h>
#include <stdint.h>

#include "engine.h"
#include "mesh_vox.h"

/* Its master side, a pipeline job's kind (engine_pipeline_job.kind). */
extern const engine_kind engine_kind_mesh;

/* What a mesh job counts besides engine_result. */
typedef struct {
    uint32_t tiles;          /* tiles with triangles, each one task */
    double t_bin;            /* seconds binning the triangles to tiles */
    uint64_t disagreements;  /* repair modes: mesh_tile_stats, summed */
    uint64_t disagree_bricks;
} engine_mesh_figures;

/* A triangle mesh voxelized tile by tile (mesh_vox.h) into a brick-sparse
 * volume in shared memory: the triangles and their bins are copied into
 * the segment, each worker runs whole tiles (the heaviest first) and
 * writes their bricks, and a worker that dies has its tile run again (the
 * tiles are deterministic: the same bricks are written again).  The
 * result stays in shared memory until the next job, for engine_write_vod.
 * Errors as engine_voxelize's (ENGINE_LIMIT: the volume or the mesh
 * outgrew shared memory). */
typedef struct {
    const mesh *mesh;
    grid_spec grid;
    mesh_vox_opts opts;
    /* The channel the VOD will be written in (0: not known): each tile
     * then builds the volume's low mip levels of that channel under its
     * own column (vod_volume_mip_columns), which the write's prepare()
     * would otherwise build in the master alone. */
    int mip_channel;
    void (*progress)(void *ud, const engine_progress *p);
    void *ud;
    const atomic_int *cancel;   /* as engine_job.cancel */
    /* NULL: every tile.  Else only the tiles tx in [tiles[0], tiles[2]),
     * ty in [tiles[1], tiles[3]) (vox_mpi's column groups): the volume
     * holds those columns alone, each as the whole grid's job makes it. */
    const uint32_t *tiles;
    engine_mesh_figures *figures; /* optional: filled in when it returns */
} engine_mesh_job;
int engine_mesh(engine *e, const engine_mesh_job *job, engine_result *r);

/* A pipeline job's input (engine_pipeline_job.mesh). */
typedef struct {
    const mesh *mesh;         /* loaded (and so checked) by the caller */
    mesh_vox_opts opts;
    uint32_t pad;             /* voxels around the bounding box (fit) */
    int fit;                  /* 1: the domain is the mesh's bounding box
                                 plus pad voxels, lo/hi are ignored */
    const char *source_name;  /* its file's name, or NULL */
    uint64_t source_bytes;    /* its file's size, for the metadata */
} engine_mesh_input;

/* A pipeline job's figures (engine_pipeline_report.fig.mesh): its
 * voxelization's (tiles and t_bin on an engine only), and what the
 * pipeline found of the mesh. */
typedef struct {
    engine_mesh_figures vox;
    uint32_t triangles;
    mesh_topo topo;           /* its edges (mesh_edges: no components, no volume) */
    double t_topology;        /* ... seconds finding them */
    int repair_skipped;       /* a repair asked of a watertight mesh: not
                                 needed (its three parities agree) */
} engine_mesh_report;

#endif
