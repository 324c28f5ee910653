/* libvox's own: the client's state and the calls its files share, none of
 * them exported (libvox.map exports vox_* alone; these are libvox_*).
 *
 * One non-blocking Unix stream socket, poll() with the client's silence
 * timeout, and the framing of proto/frame.h: libvox_socket.c sends and
 * reads, libvox_dispatch.c checks and records each reply, libvox_job.c
 * stores a job's result, libvox_submit.c and libvox_receive.c are the
 * calls of vox.h around a job, libvox.c the connection and the rest. */
#ifndef LIBVOX_INT_H
#define LIBVOX_INT_H

#include <stddef.h>
#include <stdint.h>

#include "frame.h"
#include "proto_check.h"
#include "vox.h"

#define READ_BUF (64u << 10)
#define IGNORE_SLOTS 16

enum { SINK_SPOOL, SINK_FD, SINK_BUF, SINK_NONE };

typedef struct vjob {
    struct vjob *next;
    uint64_t id;
    /* the result so far */
    uint64_t received;     /* bytes = the next chunk's offset */
    uint32_t crc;          /* zlib crc32 of every byte but the last tail_n */
    uint8_t tail[4];
    unsigned tail_n;
    int sink;              /* SINK_*; SINK_NONE: dropped, its end awaited */
    int fd;                /* SINK_SPOOL (-1 until the first chunk), SINK_FD */
    uint8_t *buf;          /* SINK_BUF */
    size_t cap;
    int local_err;         /* the sink failed: the job fails with this */
    /* timing: a job must end, whatever the daemon keeps saying */
    double t_accepted;     /* monotonic seconds */
    double t_data;         /* the last chunk's arrival */
    uint32_t queue_position;
    /* progress, terminal */
    double fraction;
    int level;
    uint64_t voxels;
    int progress_new;
    int cancel_sent;
    int discard;           /* nobody wants it: freed when it ends */
    int done;
    vox_error result;      /* code 0: the summary, checked */
    vox_summary sum;
} vjob;

/* The request a call waits for.  P_DRAIN: a ping behind an upload's last
 * chunk, so that what the daemon says about the chunks (an Error with no
 * job for each chunk sent after its job ended) comes in before the call
 * returns and cannot pass for the answer to a later request. */
enum { P_NONE, P_HELLO, P_SUBMIT, P_STATUS, P_PING, P_CANCEL, P_DRAIN };

struct vox_client {
    int fd;
    int timeout_ms;
    size_t inline_max;
    proto_frame_decoder dec;
    proto_limits lim;
    vox_server_info info;
    int ready;              /* HelloOk received */
    /* the connection's failure, sticky */
    int err;
    vox_error fail;
    /* an Error about no job and no request: why the daemon is about to close */
    int note_code;
    char note[PROTO_MAX_MESSAGE + 1];
    /* the request a call waits for */
    int pending, answered;
    vox_error ans;          /* code 0: success */
    uint64_t ans_job;
    uint32_t ans_qpos;
    vox_status_info ans_status;
    uint64_t ping_token, next_token;
    uint64_t last_pong;     /* pongs come back in order, each once */
    double t_any_data;      /* the last chunk of any job */
    uint64_t cancel_job;
    /* silence */
    double last_rx, ka_sent;
    vjob *jobs;
    /* jobs that ended (or were never ours) and were cancelled: a late
     * Error about them is the daemon's answer to the cancel, not news */
    uint64_t ignore[IGNORE_SLOTS];
    unsigned n_ignore;
    uint8_t *rbuf;
};

/* libvox_error.c; e may be NULL for both (a caller that wants no message) */
__attribute__((format(printf, 4, 5)))
void libvox_set_error(vox_error *e, int code, uint64_t job, const char *fmt, ...);
void libvox_copy_error(vox_error *dst, const vox_error *src);
/* Fail the connection (once: the first failure is the one reported). */
__attribute__((format(printf, 3, 4)))
int libvox_fail(vox_client *c, int code, const char *fmt, ...);

/* libvox_job.c */
double libvox_mono(void);
vjob *libvox_find_job(vox_client *c, uint64_t id);
void libvox_free_job(vjob *j);
void libvox_forget_job(vox_client *c, vjob *j);
void libvox_job_ended(vox_client *c, vjob *j);
int libvox_ignored(const vox_client *c, uint64_t id);
void libvox_add_ignored(vox_client *c, uint64_t id);
int libvox_write_all(int fd, const uint8_t *p, size_t n);
int libvox_on_chunk(vox_client *c, const Voxd__ResultChunk *m);
void libvox_on_summary(vjob *j, const Voxd__Summary *m);
int libvox_unspool(vjob *j, int sink, int fd);

/* libvox_dispatch.c */
int libvox_dispatch(vox_client *c, const uint8_t *data, size_t len);

/* libvox_socket.c */
int libvox_send_request(vox_client *c, const Voxd__Request *req);
int libvox_send_cancel(vox_client *c, uint64_t job_id);
void libvox_drop_job(vox_client *c, vjob *j);
int libvox_step(vox_client *c, int max_ms, int *interrupted);
int libvox_request(vox_client *c, int kind, const Voxd__Request *req, vox_error *err);
int libvox_ping(vox_client *c, int kind, vox_error *err);

#endif
