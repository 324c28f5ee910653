/* daemon — voxd's server: a libuv loop for clients, signals and timers, and
 * one engine thread that runs the jobs (the nginx model: the master
 * supervises, the forked workers compute).
 *
 *   loop thread (libuv)                       engine thread (pthread)
 *     listener, clients, frame decoders          creates the engine (it must
 *     signals: TERM/INT QUIT HUP USR1            outlive it: PR_SET_PDEATHSIG
 *     housekeeping timer: timeouts               is per thread), pops jobs,
 *     job queue (push), cancels  --- mu/cv -->   compiles, voxelizes, writes
 *     results to the clients     <-- async ---   the VOD into a memfd
 *
 * Everything a client sends goes through proto_frame_decode and
 * proto_check_request once, in daemon_client.c; past that it is trusted.
 *
 * Threads.  d->mu guards what both threads touch: the queue, the running
 * job, the done list, each job's progress, the worker snapshot, the
 * engine thread's log lines and its flags.  A job is owned by the loop
 * while it is nowhere or delivering, by the queue while queued (the loop
 * may take it out), and by the engine thread while running (the loop may
 * only set its cancel code and flag).  Only the loop logs: the engine
 * thread posts lines (d->elog) that the loop writes.
 */
#ifndef VOXD_DAEMON_H
#define VOXD_DAEMON_H

#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <sys/types.h>
#include <uv.h>

#include "config.h"
#include "engine.h"
#include "exit_status.h"
#include "frame.h"
#include "grid.h"
#include "log.h"
#include "mesh_vox.h"
#include "pipeline.h"
#include "voxd.pb-c.h"

#define DAEMON_SERVER_NAME "voxd 0.1"
#define DAEMON_TICK_MS 100                /* housekeeping period */
#define DAEMON_READ_BUF (64u << 10)       /* one read's buffer, shared by all clients */
#define DAEMON_ELOG_LINES 32              /* engine thread log lines awaiting the loop */
#define DAEMON_STOP_GRACE_MS 2000         /* fast stop: how long clients get to read their errors */

typedef struct daemon_ctx daemon_ctx;
typedef struct daemon_client daemon_client;
typedef struct daemon_job daemon_job;

/* Settings from the command line that the config file does not hold. */
typedef struct {
    const char *config_path;   /* NULL: /etc/voxd/voxd.conf if it exists */
    const char *socket;        /* --socket: absolute, overrides the file's */
    int workers;               /* --workers: overrides the file's; 0 = not given */
    unsigned client_timeout;   /* --client-timeout: overrides the file's; 0 = not given */
    int stall_timeout;         /* --worker-stall-timeout: overrides the file's; -1 = not given */
    int ready_fd;              /* --daemon: write 1 byte here once serving; -1 none */
} daemon_options;

/* UPLOADING: accepted, its input coming in InputChunks; on the client's
 * list only (loop only) until the last byte, then queued. */
enum daemon_job_state { DAEMON_QUEUED, DAEMON_RUNNING, DAEMON_DONE, DAEMON_DELIVERING, DAEMON_UPLOADING };

/* How the daemon is stopping: a graceful stop lets the jobs finish. */
enum daemon_stop { DAEMON_STOP_NONE, DAEMON_STOP_GRACEFUL, DAEMON_STOP_FAST };

struct daemon_job {
    uint64_t id;
    uid_t uid;
    daemon_client *client;         /* NULL once the client is gone (loop only) */
    daemon_job *next;              /* queue / done list (under mu) */
    daemon_job *cnext;             /* the client's jobs (loop only) */
    enum daemon_job_state state;   /* under mu */

    /* the request, copied and checked */
    const engine_kind *kind;   /* one of daemon_submit.c's table's */
    /* The job's input: the expression, or the mesh file's bytes (freed
     * once parsed); NUL-terminated; inline, or the input as it arrives. */
    char *source;
    size_t source_len;         /* bytes of it (received so far while uploading) */
    /* an input sent as InputChunks (loop only) */
    uint64_t input_total;      /* bytes the Submit declared, 0 = inline */
    size_t input_cap;          /* bytes allocated at source */
    double t_input;            /* monotonic seconds of the Accepted or the last chunk */
    char *source_name;         /* its file's name, NUL-terminated, or NULL */
    double lo[3], hi[3];
    uint32_t res;
    int schedule;              /* engine_schedule */
    int channel;               /* VOXEL_CH_* */
    uint32_t band;             /* channel 4, any kind: voxels each side, 0 the default */
    uint32_t brick, comp, hash;
    /* a mesh job's options (mesh_opts.channel = channel) */
    mesh_format mesh_format;
    mesh_vox_opts mesh_opts;
    int weld;               /* Mesh.weld: mesh_weld(weld_eps) once parsed */
    double weld_eps;
    uint32_t pad;
    int fit;                   /* no domain: the mesh's bounding box and pad */
    /* a CSG job's tree, built and checked at submit (daemon_csg.c), and
     * its text's size for the metadata (its source is empty) */
    csg_tree *csg;
    uint64_t csg_source_bytes;
    /* limits at submit time (a HUP does not change a job's) */
    uint32_t max_expr_bytes, max_expr_depth, job_timeout, max_triangles;
    uint64_t max_result_bytes;

    /* The daemon's results_held, in which this job's result counts (size
     * bytes, while fd holds it). */
    atomic_ullong *held_sum;

    /* stopping it: the loop sets cancel_code under mu, then cancel */
    atomic_int cancel;
    int cancel_code;           /* Voxd__ErrorCode, 0 = none asked */

    double t_submit, t_start;  /* monotonic seconds */
    engine_progress progress;  /* under mu */
    unsigned progress_seq, progress_sent;

    /* the outcome (engine thread, then the loop) */
    int code;                  /* 0 = success, else Voxd__ErrorCode */
    char message[512];
    int fd;                    /* memfd holding the VOD, -1 none */
    uint8_t *map;              /* the memfd mapped for delivery, NULL none */
    uint64_t size, sent;       /* bytes of the VOD, bytes sent as chunks */
    uint64_t voxels;
    int has_figures;           /* the job passed its checks: fig below */
    engine_pipeline_figures fig;      /* its kind's own figures (engine_pipeline_report.fig) */
    vod_stats st;
    double t_voxelize, t_write;
    grid_spec grid;            /* the job's grid, for its Summary (set when it succeeded) */
    uint32_t mpi_ranks;        /* it ran through MPI on this many ranks; 0 = the engine */
};

struct daemon_client {
    uv_pipe_t pipe;            /* first: handle->data is not needed */
    daemon_ctx *d;
    daemon_client *prev, *next;    /* d->clients */
    proto_frame_decoder dec;
    uid_t uid;
    pid_t pid;
    int hello;                 /* Hello received */
    int admitted;              /* counted in nadmitted: not refused at accept */
    int closing;               /* uv_close called */
    int flush_close;           /* close once the write queue is empty */
    int reading;               /* uv_read_start in effect */
    unsigned writes;           /* uv_write requests in flight */
    double t_connect;          /* monotonic seconds */
    double t_frame;            /* when the partial frame began, 0 = none */
    double t_write;            /* last write progress while writes pend */
    daemon_job *jobs;              /* its jobs in every state (cnext) */
    daemon_job *deliver, *deliver_tail; /* finished jobs to stream, in order (next) */
    /* A write finished (0) or failed (a negative libuv error): set by
     * daemon_client.c, called by daemon_conn.c. */
    void (*written)(daemon_client *c, int status);
};

/* Kinds of repeated per-connection messages, each rate-limited on its own
 * (log_limit): a flood of one kind writes a few lines and a count. */
enum daemon_log_kind {
    DAEMON_LOG_ACCEPT,      /* accept(2) failed (out of descriptors) */
    DAEMON_LOG_NOT_ALLOWED, /* refused: uid not in allow_uids */
    DAEMON_LOG_PER_UID,     /* refused: max_clients_per_uid */
    DAEMON_LOG_FULL,        /* refused: max_clients */
    DAEMON_LOG_BAD_FRAME,   /* garbage or a bad frame length: closed */
    DAEMON_LOG_BAD_REQUEST, /* a request the checker refused (debug) */
    DAEMON_LOG_STALLED,     /* a client timed out */
    DAEMON_LOG_CUT,         /* a connection ended inside a frame */
    DAEMON_LOG_KINDS
};

typedef struct {
    pid_t pid;
    int cpu;
    uint64_t jobs;
    double vps;
    engine_worker_state state;
    uint32_t replaced, stalls, unanswered; /* engine_worker_info's */
} daemon_worker_snap;

/* The MPI settings (config's mpi_*), the engine thread's copy. */
typedef struct {
    char hostfile[PATH_MAX];   /* "" = no job runs through MPI */
    uint32_t min_res, ranks, workers;
    char mpirun[PATH_MAX];     /* "" = mpirun on the PATH */
    char args[512];
    char vox_mpi[PATH_MAX];    /* "" = beside voxd */
} daemon_mpi;

struct daemon_ctx {
    uv_loop_t *loop;
    voxd_config cfg;           /* loop's copy: limits of new requests */
    daemon_options opt;
    char shm_name[64];
    double t_start;

    uv_pipe_t listener;
    int listening;
    /* A connection accepted only to be closed, when no memory was left for
     * its client: libuv reads no further connection until the pending one
     * is accepted.  busy while it closes; waiting: another came meanwhile
     * (daemon_client.c). */
    uv_pipe_t reject;
    int reject_busy, reject_waiting;
    uv_signal_t sig_term, sig_int, sig_quit, sig_hup, sig_usr1;
    uv_timer_t tick, stop_timer;
    uv_async_t wake;
    uv_check_t turn;           /* after every turn of the loop: time to exit? */
    enum daemon_stop stopping;     /* DAEMON_STOP_NONE until a signal */
    int exiting;               /* handles are being closed */
    cli_exit exit_code;        /* daemon_run's: CLI_EXIT_OK, or CLI_EXIT_FAILED at a failed start */

    daemon_client *clients;
    unsigned nclients;         /* connections, the ones being refused included */
    unsigned nadmitted;        /* connections admitted: what max_clients bounds */
    log_limit loglim[DAEMON_LOG_KINDS];
    unsigned nuploading;       /* jobs waiting for their input (loop only) */
    /* Bytes of the results held in memory files: the running job's as it
     * is written, and the finished ones' until they are delivered or
     * dropped.  relaxed: a sum read for the max_memory budget; nothing is
     * published through it. */
    atomic_ullong results_held;
    uint64_t next_job_id;
    uint8_t readbuf[DAEMON_READ_BUF];

    /* ---- shared with the engine thread, under mu ---- */
    pthread_mutex_t mu;
    pthread_cond_t cv;         /* engine thread: work, reload or quit */
    pthread_cond_t started_cv; /* loop: the engine was created (or not) */
    pthread_t thread;
    int thread_started;
    daemon_job *queue, *queue_tail;
    unsigned nqueued;
    daemon_job *running;
    daemon_job *done, *done_tail;
    int quit, reload;
    int engine_state;          /* 0 starting, 1 ready, -errno failed */
    char engine_err[256];
    engine_opts eopts;         /* the next engine's (reload copies in) */
    daemon_mpi mpi;                /* the next job's (reload copies in) */
    uint64_t mem_max, mem_shm; /* max_memory (resolved) and shm_size, for the
                                  engine thread's budget checks */
    int cpus[CONFIG_MAX_CPUS];
    int nworkers;
    daemon_worker_snap workers[ENGINE_MAX_WORKERS];
    struct { int level; char text[300]; } elog[DAEMON_ELOG_LINES];
    unsigned elog_n, elog_dropped;
};

/* voxd.c: the whole server, from a loaded config to the end.  The caller
 * has opened the log, holds the lock and removed stale files.  Returns the
 * process exit code. */
int daemon_run(const voxd_config *cfg, const daemon_options *opt, const char *shm_name);

/* daemon.c */
/* The configuration the options name: the file (or the defaults when no
 * file was named and /etc/voxd/voxd.conf does not exist), then the
 * command line's overrides (--socket, --workers, --client-timeout).
 * 0 or -errno with a message in err. */
int daemon_load_config(const daemon_options *o, voxd_config *c, err_info *err);
void daemon_engine_opts(daemon_ctx *d, const voxd_config *c); /* under mu */

/* daemon_engine.c */
int daemon_engine_start(daemon_ctx *d);
void daemon_engine_stop(daemon_ctx *d);
void daemon_job_free(daemon_job *j);
/* daemon_csg.c: a checked Csg message's tree, its expressions compiled
 * under the limits given; 0, or a negative errno with msg saying why
 * (-EINVAL a bad expression, -E2BIG one over a limit). */
int daemon_csg_tree(const Voxd__Csg *c, uint32_t max_expr_bytes, uint32_t max_expr_depth,
                csg_tree **out, char *msg, size_t len);
/* The job's input (len bytes) cut into the leaves that were sent as input
 * (data_bytes: a length and no data yet), in node order.  0, -EINVAL when
 * the lengths do not add up to len, -ENOMEM. */
int daemon_csg_input(csg_tree *t, const char *input, size_t len);
/* Set j's terminal error from its cancel_code (a person's words for it). */
void daemon_job_stopped(daemon_job *j);
/* Push a checked job onto the queue; the caller counted the limits. */
void daemon_queue_push(daemon_ctx *d, daemon_job *j);
/* Admit j if the queue and j's uid have room (its jobs uploading, queued,
 * running, or finished and not yet delivered: `delivering` of them, the
 * uploading and the delivering, are on the loop's lists; the queue's room
 * counts the uploading jobs as queued): 0 (queued, or left uploading when
 * j is DAEMON_UPLOADING; *pos = jobs ahead of it), or
 * VOXD__ERROR_CODE__BUSY / __LIMIT_EXCEEDED. */
int daemon_queue_admit(daemon_ctx *d, daemon_job *j, unsigned delivering, uint32_t *pos);
/* Stop a job wherever it is: queued ones are taken out and get their
 * terminal error now (1 is returned), a running one is told to stop with
 * code and gets it when the engine returns (0). */
int daemon_job_stop(daemon_ctx *d, daemon_job *j, int code);
int daemon_busy(daemon_ctx *d); /* jobs queued, running or delivering */
/* The memory budget (max_memory): room for one more job's result beside
 * the segment (shm bytes) and the results held?  0, or
 * VOXD__ERROR_CODE__BUSY with why in msg. */
int daemon_memory_room(daemon_ctx *d, uint64_t max_memory, uint64_t shm, char *msg,
                   size_t len);

/* daemon_mpi.c: jobs through mpirun ... vox_mpi (engine thread) */
int daemon_mpi_wants(const daemon_mpi *m, const daemon_job *j);
/* What an MPI run tells the engine thread while it runs. */
typedef struct {
    void (*started)(void *ud, const char *line);          /* mpirun runs: a log line */
    void (*progress)(void *ud, double fraction, uint64_t voxels); /* subtrees done */
    void *ud;
} daemon_mpi_hooks;
/* Run j through MPI: 0 with *result an open descriptor of its VOD file
 * (unlinked) and j's voxels, st and times from vox_mpi's summary;
 * -ECANCELED when j's cancel flag stopped it (the caller sets why); or -1
 * with j's error set. */
int daemon_mpi_run(const daemon_mpi *m, daemon_job *j, int *result, const daemon_mpi_hooks *h);

/* daemon_conn.c: a connection's output */
/* Frame r onto c's write queue; 0, or -errno after c->written(c, error). */
int daemon_client_send(daemon_client *c, const Voxd__Reply *r);
size_t daemon_conn_queued(daemon_client *c);          /* bytes waiting in user space */
size_t daemon_conn_pump_mark(const daemon_client *c); /* results stream below this */
size_t daemon_conn_read_mark(const daemon_client *c); /* requests are read below this */
int daemon_client_backed_up(daemon_client *c);        /* progress replies are dropped */

/* daemon_client.c */
/* The engine thread said something (d->wake): log lines, progress,
 * finished jobs. */
void daemon_on_wake(uv_async_t *a);
void daemon_on_connection(uv_stream_t *server, int status);
void daemon_client_close(daemon_client *c);
void daemon_client_close_after_flush(daemon_client *c);
void daemon_client_tick(daemon_client *c, double now);
int daemon_client_error(daemon_client *c, uint64_t job_id, int code, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
void daemon_client_pump(daemon_client *c);
/* The job's terminal error to its client (if any), the job out of the
 * client's list and freed. */
void daemon_job_fail(daemon_ctx *d, daemon_job *j, int code, const char *msg);
/* A finished job from the engine: its terminal error, or on to delivery. */
void daemon_job_finished(daemon_ctx *d, daemon_job *j);
void daemon_client_unlink_job(daemon_client *c, daemon_job *j);
/* End every job of c still uploading its input with code (a stop). */
void daemon_client_fail_uploads(daemon_client *c, int code, const char *msg);

/* daemon_submit.c: a Submit made into a job (the one place in the daemon
 * that tells the kinds apart, but for daemon_mpi.c) */
/* Set j's terminal error (code a Voxd__ErrorCode, the message formatted);
 * returns -1. */
int daemon_job_error(daemon_job *j, int code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
/* What is built and checked before s's job is queued (a CSG tree into
 * *out): 0 (nothing for the other kinds), or -E2BIG, -EINVAL or another
 * -errno with msg set. */
int daemon_submit_build(const voxd_config *cfg, const Voxd__Submit *s, csg_tree **out, char *msg,
                        size_t len);
/* A new job of c's from s (not queued), or NULL when out of memory. */
daemon_job *daemon_submit_job(daemon_client *c, const Voxd__Submit *s);
/* What the job's input is, for messages. */
const char *daemon_submit_input_name(const daemon_job *j);
int daemon_submit_is_text(const daemon_job *j); /* its input is text: no NUL byte in it */
/* The kind's part of the pipeline job, as vox voxelize fills it (so the
 * bytes are the same): the expression compiled, the mesh parsed, the CSG
 * tree's leaves cut in, a bad input refused here with its typed error even
 * when the job then runs through MPI (mpi: the mesh's bytes kept for
 * vox_mpi).  What it made is in *owned, for daemon_submit_release.  0, or
 * -1 with the job's error (and nothing to release). */
int daemon_submit_input(daemon_job *j, engine_pipeline_job *job, void **owned, int mpi);
void daemon_submit_release(const daemon_job *j, void *owned);
/* The job's kind in a StatusReply. */
Voxd__JobKind daemon_submit_status_kind(const daemon_job *j);
/* The kind's figures into m (when it has any and the job got that far);
 * on the loop thread, which sends m before it calls this again. */
void daemon_submit_summary(const daemon_job *j, Voxd__Summary *m);

/* daemon_reply.c */
int daemon_send_hello_ok(daemon_client *c);
int daemon_send_accepted(daemon_client *c, uint64_t id, uint32_t pos);
int daemon_send_progress(daemon_client *c, const daemon_job *j, const engine_progress *p);
int daemon_send_chunk(daemon_client *c, const daemon_job *j, const uint8_t *data, size_t n);
int daemon_send_summary(daemon_client *c, const daemon_job *j);
int daemon_send_status(daemon_client *c);
int daemon_send_pong(daemon_client *c, uint64_t token);
/* Text for an Error message: printable ASCII, newline and tab; the rest '?'. */
void daemon_clean_text(char *s);

#endif
