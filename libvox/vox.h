/* vox.h — libvox, the client library of the voxd daemon.
 *
 * One connection to a daemon is a vox_client: vox_connect() opens the Unix
 * socket and says hello; then submit jobs, receive their results (a VOD
 * file, written whole or not at all, or a buffer), cancel jobs, ask for the
 * daemon's status, ping it.  Every call blocks until it is done, fails, or
 * the daemon has been silent for the client's timeout.  A client is used
 * from one thread at a time.
 *
 * Errors.  Every function that can fail returns 0 or a negative code:
 *   - a negative errno for what happened on this side or on the socket:
 *       -ENOENT / -ECONNREFUSED  no daemon listening at the path
 *       -ETIMEDOUT   the daemon said nothing for the timeout (it is pinged
 *                    after half of it, so a daemon that is alive but busy
 *                    with other jobs never times out); or, for one job, its
 *                    result stopped for the timeout, or it did not end
 *                    within the daemon's own job_timeout (per job ahead of
 *                    it, plus a timeout each): the job is then cancelled
 *                    and the connection goes on
 *       -ECONNRESET  the daemon closed the connection
 *       -EPROTO      the daemon broke the protocol (a reply that does not
 *                    validate, a chunk at the wrong offset or for a job this
 *                    client does not have, progress after the result began,
 *                    a reply nobody asked for, ...); the connection is unusable
 *       -EBADMSG     a result whose length or CRC-32 does not check
 *       -EINVAL, -ENOMEM, I/O errors of the output file, ...
 *   - a VOX_E* code for a typed error of the daemon (the job's terminal
 *     error, or a refused request), with the daemon's message.
 * Functions taking a vox_error fill it on failure (it may be NULL): the
 * code, the job it concerns and a message for a person, which for a daemon
 * error is the daemon's own ("res 5000 is over this server's limit of 4096").
 * Once the connection has failed (timeout, closed, protocol), every later
 * call fails with the same error: close the client.
 */
#ifndef VOX_H
#define VOX_H

#include <stddef.h>
#include <stdint.h>

#include "vox_limits.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Typed errors of the daemon: -(VOX_ESERVER_BASE + the protocol's ErrorCode). */
#define VOX_ESERVER_BASE 1000
#define VOX_EINVALID_INPUT (-1001)  /* the job is malformed or unsupported */
#define VOX_ELIMIT_EXCEEDED (-1002) /* over one of the daemon's limits */
#define VOX_EBUSY (-1003)           /* queue full, too many jobs or clients */
#define VOX_ECANCELLED (-1004)      /* the job was cancelled */
#define VOX_EWORKER_CRASHED (-1005) /* a worker died during the job */
#define VOX_ETIMEOUT (-1006)        /* the job ran past the daemon's job_timeout */
#define VOX_ESHUTTING_DOWN (-1007)  /* the daemon is stopping */
#define VOX_EINTERNAL (-1008)       /* a bug or a resource failure in the daemon */
#define VOX_IS_SERVER_ERROR(rc) ((rc) <= VOX_EINVALID_INPUT && (rc) >= VOX_EINTERNAL)

/* The daemon's default socket; vox uses $VOXD_SOCKET first. */
#define VOX_DEFAULT_SOCKET "/run/voxd/voxd.sock"
#define VOX_DEFAULT_TIMEOUT_MS 30000
/* A job's input (an implicit job's expression, a mesh job's file) larger
 * than this is sent after the job's Submit in InputChunks rather than
 * inside it. */
#define VOX_DEFAULT_INLINE_MAX 65536

/* A short description: "no such file or directory", "over a limit of the daemon". */
const char *vox_strerror(int code);
/* The name of a daemon error ("LIMIT_EXCEEDED"), NULL for any other code. */
const char *vox_error_name(int code);

typedef struct {
    int code;           /* the failing call's return value */
    uint64_t job_id;    /* the job it concerns, 0 if none */
    char message[1100]; /* the daemon's message (up to 1024 bytes), or ours */
} vox_error;

/* ---------------------------------------------------------------- connecting */

typedef struct vox_client vox_client;

typedef struct {
    int timeout_ms;          /* give up after this much silence; 0 = VOX_DEFAULT_TIMEOUT_MS */
    const char *client_name; /* for the daemon's log; NULL = "libvox" */
    size_t inline_max;       /* an input over this many bytes goes in InputChunks (so does one
                                whose request would not fit the daemon's max_frame);
                                0 = VOX_DEFAULT_INLINE_MAX */
} vox_options;

/* Connect to the daemon at socket_path and say hello.  opts may be NULL.
 * -ENOENT / -ECONNREFUSED when no daemon listens there, a VOX_E* code when
 * it refuses this client (VOX_EBUSY: too many clients; VOX_ELIMIT_EXCEEDED:
 * a uid not allowed, or one at its max_clients_per_uid), -ETIMEDOUT when it
 * does not answer.  On success *out is a client to close with vox_close. */
int vox_connect(const char *socket_path, const vox_options *opts, vox_client **out,
                vox_error *err);
/* The same over a stream socket already connected to a daemon; fd becomes
 * the client's (closed by vox_close, or here on failure). */
int vox_connect_fd(int fd, const vox_options *opts, vox_client **out, vox_error *err);
/* Close the connection; the daemon cancels the jobs still running for it.
 * Results not received are dropped.  NULL is allowed. */
void vox_close(vox_client *c);
/* Change the silence timeout (ms > 0). */
void vox_set_timeout(vox_client *c, int ms);

typedef struct {
    char name[130];            /* "voxd 0.1" */
    uint32_t version;          /* protocol version: 1 */
    uint32_t workers;
    /* The daemon's limits, one field per row of VOX_LIMITS (vox_limits.h):
     * max_frame, max_expr_bytes, max_expr_depth, max_res, max_queued_jobs,
     * max_jobs_per_uid, job_timeout, max_result_bytes, chunk_size,
     * max_csg_nodes, max_input_bytes, max_mesh_bytes, max_triangles. */
#define VOX_SERVER_LIMIT(name, type, def, min, max, unit, doc) type name;
    VOX_LIMITS(VOX_SERVER_LIMIT)
#undef VOX_SERVER_LIMIT
} vox_server_info;

/* What the daemon said about itself in its hello. */
void vox_server(const vox_client *c, vox_server_info *out);

/* ---------------------------------------------------------------- jobs */

/* Enum values are the protocol's; 0 everywhere means the daemon's default. */
/* DEFAULT: SURFACE for an implicit job, OCCUPANCY for a mesh job, DENSITY
 * for a CSG job; DENSITY is for mesh and CSG jobs, DISTANCE for every kind
 * (its band: vox_implicit.band, vox_mesh.supersample, vox_csg.band). */
enum {
    VOX_CHANNEL_DEFAULT = 0,
    VOX_CHANNEL_OCCUPANCY = 1,
    VOX_CHANNEL_DENSITY = 2,
    VOX_CHANNEL_SURFACE = 3,
    VOX_CHANNEL_DISTANCE = 4, /* the f32 signed distance in a narrow band */
};
enum { VOX_COMP_DEFAULT = 0, VOX_COMP_NONE = 1, VOX_COMP_ZLIB = 2, VOX_COMP_RUNL = 3 };
enum { VOX_HASH_DEFAULT = 0, VOX_HASH_SFHS = 1, VOX_HASH_XX32 = 2 };
enum { VOX_SCHEDULE_DEFAULT = 0, VOX_SCHEDULE_SUBTREE = 1, VOX_SCHEDULE_PAPER = 2 };

/* The kinds of job (the protocol's Submit.job numbers). */
enum {
    VOX_JOB_IMPLICIT = 1, /* vox_job.implicit */
    VOX_JOB_MESH = 2,     /* vox_job.mesh */
    VOX_JOB_CSG = 3,      /* vox_job.csg */
};

/* F(x,y,z) = 0 over a box: the job of `vox voxelize`. */
typedef struct {
    const char *source;   /* the expression (expr/expr.h syntax) */
    size_t source_len;    /* its bytes; 0 = strlen(source) */
    const char *source_name; /* the file it came from, for the VOD's metadata
                                (at most 512 bytes, one line); may be NULL */
    double domain[6];     /* x0, x1, y0, y1, z0, z1, each low < high */
    uint32_t res;         /* voxels along the longest axis */
    int schedule;         /* VOX_SCHEDULE_* */
    uint32_t band;        /* VOX_CHANNEL_DISTANCE: the band's half width in
                             voxels, 1..32; 0 = 3 (last: vox_job's union keeps
                             its size, vox_mesh the largest) */
} vox_implicit;

/* A mesh job's file format, mode and repair (mesh/mesh_vox.h says what each
 * does); 0 everywhere is the default. */
enum {
    VOX_MESH_FORMAT_AUTO = 0, /* told from the contents */
    VOX_MESH_FORMAT_OBJ = 1,
    VOX_MESH_FORMAT_STL = 2,
    VOX_MESH_FORMAT_PLY = 3,
    VOX_MESH_FORMAT_OFF = 4,
    VOX_MESH_FORMAT_GLTF = 5, /* a .glb, or a .gltf with its buffers embedded */
};
enum {
    VOX_MESH_MODE_DEFAULT = 0, /* SOLID */
    VOX_MESH_MODE_SOLID = 1,   /* voxel centres inside the mesh */
    VOX_MESH_MODE_SURFACE = 2, /* voxels a triangle touches (26-separating) */
    VOX_MESH_MODE_SURFACE6 = 3, /* the thinner 6-separating surface */
    VOX_MESH_MODE_CONSERVATIVE = 4, /* solid plus surface */
    VOX_MESH_MODE_INTERIOR = 5, /* solid minus surface */
};
enum {
    VOX_MESH_REPAIR_DEFAULT = 0, /* NONE */
    VOX_MESH_REPAIR_NONE = 1,    /* the parity along z */
    VOX_MESH_REPAIR_VOTE = 2,    /* the majority of the parities along x, y, z */
    VOX_MESH_REPAIR_WINDING = 3, /* the winding number where they disagree */
};

/* A triangle mesh file (OBJ, STL, PLY, OFF) voxelized on a grid: the job
 * of `vox voxelize --mesh`, which gives the same file.  The daemon parses
 * the bytes itself when the job runs; a file it cannot read is the job's
 * VOX_EINVALID_INPUT (with the line or byte), too many triangles its
 * VOX_ELIMIT_EXCEEDED. */
typedef struct {
    const void *data;     /* the file's bytes, as they are */
    size_t len;           /* 1..the daemon's max_mesh_bytes */
    int format;           /* VOX_MESH_FORMAT_* */
    const char *source_name; /* the file's name, for the VOD's metadata
                                (at most 512 bytes, one line); may be NULL */
    int mode;             /* VOX_MESH_MODE_* */
    int repair;           /* VOX_MESH_REPAIR_* */
    uint32_t supersample; /* VOX_CHANNEL_DENSITY: samples per voxel and axis,
                             2..8; 0 = 2.  VOX_CHANNEL_DISTANCE: the band's
                             half width in voxels, 1..32; 0 = 3 (one field
                             for both keeps vox_job's layout) */
    int fit;              /* 1: the grid fits the mesh's bounding box grown by
                             pad voxels each side (domain unused); 0: domain */
    uint32_t pad;         /* fit: empty voxels around the box (vox's default: 1) */
    double domain[6];     /* !fit: x0, x1, y0, y1, z0, z1, each low < high */
    uint32_t res;         /* voxels along the longest axis; 2 pad < res */
    int weld;             /* 1: merge the vertices within weld_eps first */
    double weld_eps;      /* 0 (equal positions) or 1e-30..1e30, the mesh's units */
} vox_mesh;

/* Volume CSG (docs/csg.md): the protocol's CsgOp, Primitive and Axis
 * numbers (proto/voxd.proto). */
enum {
    VOX_CSG_PRIMITIVE = 1, VOX_CSG_IMPLICIT = 2, VOX_CSG_MESH = 3, VOX_CSG_VOD = 4,
    VOX_CSG_UNION = 10, VOX_CSG_INTERSECTION = 11, VOX_CSG_DIFFERENCE = 12,
    VOX_CSG_TRIM = 13, VOX_CSG_CAP = 14, VOX_CSG_ADD = 15, VOX_CSG_MODULATE = 16,
    VOX_CSG_DIVIDE = 17, VOX_CSG_DIFFERENCE_A = 18, VOX_CSG_DIFFERENCE_B = 19,
    VOX_CSG_INVERSE = 20, VOX_CSG_DIVIDE_A = 21, VOX_CSG_SCALAR_ADD = 22,
    VOX_CSG_SCALAR_MUL = 23, VOX_CSG_ERODE = 24, VOX_CSG_DILATE = 25,
};
enum { VOX_PRIMITIVE_CUBOID = 1, VOX_PRIMITIVE_ELLIPSOID = 2, VOX_PRIMITIVE_CYLINDER = 3,
       VOX_PRIMITIVE_CONE = 4 };
enum { VOX_AXIS_DEFAULT = 0 /* z */, VOX_AXIS_X = 1, VOX_AXIS_Y = 2, VOX_AXIS_Z = 3 };

/* One node of a CSG tree; the fields its op does not take stay 0. */
typedef struct {
    int op;                 /* VOX_CSG_* */
    uint32_t children[2];   /* indices of earlier nodes */
    uint32_t n_children;    /* 2 binary, 1 unary, 0 leaves */
    int primitive;          /* VOX_PRIMITIVE_*: center, size (full, > 0) and rotate
                               (radians about x, then y, then z), world units */
    double center[3], size[3], rotate[3];
    int axis;               /* VOX_AXIS_*: a cylinder's or cone's */
    const char *source;     /* VOX_CSG_IMPLICIT: F(x,y,z), inside where F < 0 */
    size_t source_len;      /* its bytes; 0 = strlen(source) */
    int has_domain;         /* VOX_CSG_IMPLICIT: L outside [domain[0], domain[1]]^3 */
    double domain[2];
    double scalar;          /* divide's S_L, scale_add's and scale_mul's scalar */
    uint32_t k;             /* erode, dilate: voxels, 1..16 */
    const char *name;       /* for the daemon's messages; may be NULL */
    const void *data;       /* VOX_CSG_MESH, VOX_CSG_VOD: the file's bytes, as they are */
    size_t data_len;
    int has_fit;            /* VOX_CSG_MESH: the bounding box's centre moved to fit[], */
    double fit[3];          /* its longest side made scale; else coordinates times scale */
    double scale;           /* 0 = 1 */
} vox_csg_node;

/* A CSG tree on a grid: the job of `vox csg`, which gives the same file;
 * channel DENSITY (the default), OCCUPANCY, SURFACE or DISTANCE.
 * The tree travels whole in the job's Submit (a flat node list, the last
 * node the result), the mesh and VOD leaves' files in their nodes, or,
 * when large, after it as the job's input in InputChunks; the daemon checks it and compiles its expressions when
 * the job is submitted, refusing a bad one with VOX_EINVALID_INPUT (or
 * VOX_ELIMIT_EXCEEDED: max_csg_nodes, max_csg_depth, max_expr_bytes). */
typedef struct {
    const vox_csg_node *nodes;
    size_t n_nodes;         /* 1..the daemon's max_csg_nodes */
    const char *source_name; /* the .csg file's name, for the VOD's metadata; may be NULL */
    uint64_t source_bytes;  /* the .csg text's size, for the same */
    double domain[6];       /* x0, x1, y0, y1, z0, z1, each low < high */
    uint32_t res;           /* voxels along the longest axis */
    uint32_t band;          /* VOX_CHANNEL_DISTANCE: the band's half width in
                               voxels, 1..32; 0 = 3 */
} vox_csg;

/* A job of any kind: `kind` says which member of the union holds it; the
 * VOD options are common to every kind. */
typedef struct {
    int kind;             /* VOX_JOB_* */
    union {
        vox_implicit implicit; /* VOX_JOB_IMPLICIT */
        vox_mesh mesh;         /* VOX_JOB_MESH */
        vox_csg csg;           /* VOX_JOB_CSG */
    };
    int channel;          /* VOX_CHANNEL_* */
    uint32_t brick;       /* brick side, a power of two 2..256; 0 = 16 */
    int comp;             /* VOX_COMP_* */
    int hash;             /* VOX_HASH_* */
} vox_job;

/* Send a job.  On acceptance *job_id (never 0) names it and *queue_position
 * (may be NULL) is the number of jobs before it (0: running now).  An input
 * (the expression, the mesh file) larger than the client's inline_max, or
 * than fits the daemon's max_frame, follows the job in InputChunks; the
 * call returns once it is all sent (a job that the daemon ends during its
 * upload, say for a NUL byte in the expression, is still accepted:
 * vox_receive_* gives its error).  A refusal is a VOX_E* code with the
 * daemon's reason (VOX_EBUSY, VOX_ELIMIT_EXCEEDED, VOX_EINVALID_INPUT,
 * VOX_ESHUTTING_DOWN).  An input over the daemon's max_expr_bytes (an
 * expression), max_mesh_bytes (a mesh) or max_input_bytes is refused here
 * with VOX_ELIMIT_EXCEEDED, unsent, and so is a CSG tree whose Submit
 * would not fit the daemon's max_frame (a tree is never chunked). */
int vox_submit_job(vox_client *c, const vox_job *job, uint64_t *job_id,
                   uint32_t *queue_position, vox_error *err);

/* The implicit job of earlier versions, options and all: vox_submit sends it
 * through vox_submit_job. */
typedef struct {
    const char *source;   /* the expression (expr/expr.h syntax) */
    size_t source_len;    /* its bytes; 0 = strlen(source) */
    const char *source_name; /* the file it came from, for the VOD's metadata
                                (at most 512 bytes, one line); may be NULL */
    double domain[6];     /* x0, x1, y0, y1, z0, z1, each low < high */
    uint32_t res;         /* voxels along the longest axis */
    int channel;          /* VOX_CHANNEL_* */
    uint32_t brick;       /* brick side, a power of two 2..256; 0 = 16 */
    int comp;             /* VOX_COMP_* */
    int hash;             /* VOX_HASH_* */
    int schedule;         /* VOX_SCHEDULE_* */
} vox_implicit_job;

int vox_submit(vox_client *c, const vox_implicit_job *job, uint64_t *job_id,
               uint32_t *queue_position, vox_error *err);

/* Progress of a job being received: the estimated fraction done (0..1), the
 * deepest octree level finished and the voxels found so far.  Also called,
 * with the last values (all 0 before the first progress), when a signal
 * interrupts the wait, so that a flag set by a signal handler can be acted
 * on.  Return non-zero to cancel the job: the call then still waits for the
 * job's end, which is VOX_ECANCELLED unless it had already finished. */
typedef int (*vox_progress_cb)(void *ud, double fraction, int level, uint64_t voxels);

typedef struct {
    uint64_t job_id;
    uint64_t voxels;
    uint64_t bricks;          /* unique bricks stored */
    uint64_t file_bytes;
    uint32_t crc32;           /* the VOD trailer's fileCRC32, checked */
    double seconds_queued, seconds_voxelize, seconds_write;
    /* The grid the daemon voxelized on: voxel (X, Y, Z) is the cube
     * origin + [X, X+1] * voxel_size on x (likewise y, z), X < grid[0]. */
    uint32_t grid[3];         /* voxels along x, y, z */
    uint32_t depth;           /* octree levels: the smallest d >= 1, 2^d >= max(grid) */
    double voxel_size;        /* edge of the cubic voxels */
    double origin[3];         /* the grid's low corner (the domain's) */
    /* A mesh job's (has_mesh set): what it found in the mesh and did. */
    int has_mesh;
    struct {
        uint32_t triangles;   /* after the degenerate ones were dropped */
        uint64_t open_edges, nonmanifold_edges;
        int watertight;       /* no open, non-manifold or inconsistent edge */
        uint32_t tiles;       /* tiles with triangles */
        int repair_skipped;   /* a repair asked of a watertight mesh: not run */
        uint64_t disagreements, disagree_bricks; /* repair: where the parities differ */
    } mesh;
    /* The job ran through mpirun ... vox_mpi on this many ranks (the daemon's
     * mpi_hostfile, docs/mpi.md); 0: on the daemon's own workers. */
    uint32_t mpi_ranks;
} vox_summary;

/* How a receive call watches its job and what it hands back besides the
 * file; every field optional (a zeroed struct, or NULL: none).  A field
 * added here is an interface change (libvox's soname, docs/libvox.md). */
typedef struct {
    vox_progress_cb progress; /* sees the job's progress; may cancel it */
    void *ud;                 /* progress's first argument */
    vox_summary *sum;         /* gets the summary when the job succeeded */
} vox_receive_opts;

/* Wait for a job's end and write its VOD to path.  The file is written under
 * a temporary name beside path and renamed into place only when the job
 * succeeded and the result checks: as many bytes as the summary says, their
 * CRC-32 (zlib's, over every byte but the last 4) equal to the summary's and
 * to the file's own last 4 bytes (little-endian).  Otherwise nothing is left
 * at path or beside it.  o (may be NULL): see vox_receive_opts.  The job is
 * forgotten on return, whatever the outcome.  Results of other jobs of this
 * client that arrive meanwhile are kept (in an unlinked temporary file)
 * until they are received. */
int vox_receive_to_file(vox_client *c, uint64_t job_id, const char *path,
                        const vox_receive_opts *o, vox_error *err);
/* The same into a malloc'ed buffer (*buf, *len; free() it), checked the
 * same way; nothing is returned on failure. */
int vox_receive_to_buffer(vox_client *c, uint64_t job_id, uint8_t **buf, size_t *len,
                          const vox_receive_opts *o, vox_error *err);
/* The calls above as libvox 0.1 first had them, kept (thin wrappers) so that
 * programs built against them run and build unchanged: cb, ud and sum are
 * vox_receive_opts' progress, ud and sum.  Their seven and eight arguments
 * are that public ABI's (libvox.map), not to be folded into a struct. */
int vox_receive_file(vox_client *c, uint64_t job_id, const char *path, vox_progress_cb cb,
                     void *ud, vox_summary *sum, vox_error *err);
int vox_receive_buffer(vox_client *c, uint64_t job_id, uint8_t **buf, size_t *len,
                       vox_progress_cb cb, void *ud, vox_summary *sum, vox_error *err);

/* Ask the daemon to cancel a job, then wait for its answer to a ping sent
 * behind the cancel, so a refusal ("no such job") comes back here as a
 * VOX_E* code.  The job may be one of this connection's, which then ends
 * with VOX_ECANCELLED (seen by vox_receive_*), or one another connection
 * submitted, if the daemon allows it. */
int vox_cancel(vox_client *c, uint64_t job_id, vox_error *err);

/* ---------------------------------------------------------------- daemon */

enum {
    VOX_WORKER_UNKNOWN = 0,
    VOX_WORKER_IDLE = 1,
    VOX_WORKER_BUSY = 2,
    VOX_WORKER_STARTING = 3, /* being forked, again after a death */
    VOX_WORKER_STALLED = 4,  /* holds a task, no progress for over a second */
};

typedef struct {
    uint32_t pid;
    int cpu;                  /* pinned to, -1 = not pinned */
    int state;                /* VOX_WORKER_* */
    uint64_t jobs;            /* jobs it took part in */
    double voxels_per_second; /* over its last job */
    uint32_t replaced;        /* times its worker died or was killed and forked again */
    uint32_t stalls;          /* ... of which for making no progress */
} vox_worker_status;

enum {
    VOX_JOB_QUEUED = 1,
    VOX_JOB_RUNNING = 2,
};

/* A job of the daemon's (any uid's), running or queued. */
typedef struct {
    uint64_t id;
    uint32_t uid;
    int kind;        /* VOX_JOB_IMPLICIT, _MESH, _CSG */
    uint32_t res;    /* voxels along the longest axis */
    int state;       /* VOX_JOB_QUEUED or VOX_JOB_RUNNING */
    double fraction; /* done, 0 while queued */
    double seconds;  /* since it was queued, or since it started */
} vox_job_status;

typedef struct {
    double uptime;              /* seconds */
    size_t n_workers;
    vox_worker_status *workers; /* n_workers entries */
    uint32_t queued;            /* jobs waiting */
    uint32_t clients;           /* connections */
    int has_running;            /* a job is running: */
    uint64_t running_job_id;
    uint32_t running_uid;
    double running_fraction, running_seconds;
    /* The running job, then the queued ones in the order they will run
     * (at most 1024; queued counts them all).  A voxd before this field
     * sends none: n_jobs 0 with queued or has_running set. */
    size_t n_jobs;
    vox_job_status *jobs;
} vox_status_info;

/* The daemon's state.  Free with vox_status_free. */
int vox_status(vox_client *c, vox_status_info *out, vox_error *err);
void vox_status_free(vox_status_info *s);

/* A round trip; *rtt_seconds (may be NULL) is how long it took. */
int vox_ping(vox_client *c, double *rtt_seconds, vox_error *err);

#ifdef __cplusplus
}
#endif

#endif
