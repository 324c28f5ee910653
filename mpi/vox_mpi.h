/* vox_mpi's own: the messages between ranks, the context every rank
 * shares, and the calls its files share (vox_mpi.c: main and each rank's
 * run; vox_mpi_msg.c: messages on stderr and between ranks;
 * vox_mpi_slave.c: a rank working on subtrees; vox_mpi_serve.c: rank 0
 * handing them out and writing the file; vox_mpi_prep.c: rank 0's options,
 * plan and cut).  Only these files call MPI. */
#ifndef VOX_MPI_H
#define VOX_MPI_H

#include <mpi.h>
#include <stdint.h>
#include <stdio.h>

#include "cli.h"
#include "csg.h"
#include "engine.h"
#include "mesh.h"
#include "mpi_part.h"
#include "outfile.h"
#include "pipeline.h"
#include "progress.h"
#include "source.h"
#include "vod.h"

enum { TAG_REQ = 1, TAG_NODES, TAG_BRICKS, TAG_FAIL, /* up, to rank 0 */
       TAG_TASK = 11, TAG_WANT };                   /* down, from rank 0 */

#define SUBTREES_PER_RANK 8
#define HOST_MAX 64
#define WORKERS_AUTO UINT32_MAX /* -w not given: each rank decides */

/* The job as broadcast; status >= 0: every rank exits with it.  Behind
 * it, input_bytes of the job's input: an implicit job's tape, a CSG job's
 * tree (csg_tree_pack); a mesh job's triangles go with its tasks. */
typedef struct {
    int32_t status, schedule;
    int32_t kind, pad;   /* mpi_kind */
    uint32_t workers, shm_mib;
    grid_spec grid;
    vod_params vod;      /* metadata NULL */
    mesh_vox_opts mesh_opts;
    uint32_t node_level, pad2;
    uint64_t input_bytes;
    char cpus[128];
} wire_job;

/* A task: an octant, or a mesh job's column followed by its triangles
 * (mpi_mesh_part). */
typedef struct {
    int32_t index;       /* -1: no subtree left */
    grid_octant o;
} wire_task;

typedef struct {
    uint64_t voxels;
    uint32_t n, ntops, npairs, pad; /* then n mpi_rec, ntops mpi_topref, npairs mpi_pair */
} wire_nodes;

/* What a rank did, gathered by rank 0 at the end. */
typedef struct {
    uint32_t workers, pad;       /* this rank's */
    uint64_t bytes, messages;    /* sent to rank 0 */
    uint64_t subtrees, nodes, bricks, brick_bytes;
    double busy;                 /* seconds voxelizing and encoding */
} rank_stats;

/* What every rank knows of the MPI job, set once in main (the
 * communicators, its rank and host); rank 0's unfinished file too. */
typedef struct {
    MPI_Comm up, down;     /* to rank 0; from rank 0 (see vox_mpi.c) */
    int me, nranks;
    int local_rank, local_size; /* among the ranks on this host */
    char host[HOST_MAX];   /* this rank's; rank 0 has all in all_hosts */
    char (*all_hosts)[HOST_MAX];
    outfile out_file;      /* rank 0's unfinished file: the signals remove
                              it when it has a name (outfile.h) */
} mpi_ctx;

/* A rank working on subtrees (rank 0's own thread is one). */
typedef struct {
    const mpi_ctx *ctx;
    mpi_subtree_job sj;
    rank_stats st;
    int rc;
} slave;

/* Rank 0's own slave: its state and its job, for its thread. */
typedef struct {
    slave s;
    wire_job j;
} own_slave;

typedef struct {
    int task;            /* the subtree it holds, -1 none */
    mpi_rec *want;       /* the records asked for, waiting for BRICKS */
    size_t nwant;
} rank_state;

/* Rank 0's side: the subtrees handed out, the bricks booked. */
typedef struct {
    mpi_ctx *ctx;
    const mpi_cut *cut;
    const grid_spec *grid;
    mpi_kind kind;
    const mesh *mesh;        /* a mesh job's: its triangles go out with the tasks */
    const mesh_bins *bins;   /* ... binned to the tiles; NULL: every triangle
                                goes with every task (the winding number's repair) */
    mpi_book book;
    mpi_rec *nodes;      /* every node of the file, in arrival order */
    size_t n, cap;
    int spill;           /* the distinct bricks' bytes, an unlinked file */
    uint64_t spill_bytes;
    mpi_top *top;
    rank_state *rs;
    size_t next, done;
    uint64_t voxels, sent_bytes;
    progress pr;
} master;

/* Rank 0's preparation: options, source, plan, cut. */
typedef struct {
    mpi_ctx *ctx;
    cli_job_opts o;
    int stats;
    uint32_t per_rank;
    /* --source-name: the name the file's metadata gives the source (voxd
     * runs a client's job from a private copy); "" none */
    const char *source_name;
    /* voxd's: the job's mesh format (AUTO: from the contents); a csg
     * FILE packed as csg_pack.h packs it, the tree text's size for the
     * metadata, and the options vox csg has not: --brick, --hash,
     * --progress (0 when not given) */
    mesh_format mesh_format;
    int packed, csg_progress;
    uint64_t source_bytes;
    uint32_t csg_brick, csg_hash;
    mpi_kind kind;
    source src;
    expr_tape *tape;       /* implicit */
    mesh mesh;             /* mesh (mesh_loaded) */
    int mesh_loaded;
    mesh_vox_opts run_opts; /* ... the repair as run: none when watertight */
    mesh_topo topo;
    mesh_bins bins;        /* ... the triangles of each tile (none: winding) */
    csg_tree *tree;        /* csg */
    uint8_t *input;        /* what follows the job: the tape, the packed tree */
    size_t input_bytes;
    vod_params v;
    char meta[JOB_META_MAX];
    vod_layout L;
    engine_pipeline_report plan;
    mpi_cut cut;
    int fd;
} prep;

/* vox_mpi_msg.c */
void mpi_msg(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
void mpi_wait_msg(MPI_Comm c, int src, int tag, MPI_Status *st);
void *mpi_recv_msg(const mpi_ctx *ctx, MPI_Comm c, MPI_Status *st, int *n);

/* vox_mpi_slave.c */
void mpi_send_up(slave *s, const void *buf, size_t n, int tag);
int mpi_slave_run(slave *s, const wire_job *j);
void *mpi_slave_thread(void *ud);

/* vox_mpi_serve.c */
void mpi_catch_signals(mpi_ctx *ctx);
void mpi_fail_master(master *m, const char *what, int rc);
void mpi_serve(master *m);
int mpi_spill_open(const char *path);
void mpi_finish_file(prep *p, master *m, rank_stats *all, double t0);

/* vox_mpi_prep.c */
int mpi_prepare(prep *p, int argc, char **argv);
wire_job mpi_job_of(const prep *p);
mpi_subtree_job mpi_subtree_job_of(const wire_job *j, const void *input, const csg_tree *tree);
void mpi_prep_free(prep *p);

#endif
