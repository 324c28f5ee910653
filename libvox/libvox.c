/* libvox — the voxd client library.  See vox.h.
 *
 * One non-blocking Unix stream socket, poll() with the client's silence
 * timeout, and the framing of proto/frame.h.  Every reply is unpacked with a
 * bounded budget and validated by proto_check_reply() before anything here
 * looks at it; what depends on the conversation (a reply nobody asked for, a
 * chunk at the wrong offset or for a job this client does not have) is
 * checked in dispatch() and ends the connection as -EPROTO.
 *
 * dispatch() only updates state: the answer to the one request a blocked
 * call waits for, and each job's result (chunks go to the job's sink: the
 * output file or buffer of the job being received, else a spool file), its
 * CRC, its latest progress and its terminal.  Callbacks run in the receiving
 * loop, never inside dispatch(), so a callback cannot re-enter it.
 */
#include "vox.h"

#include <errno.h>
#include <fcntl.h>
#include <stdatomic.h>
#include <limits.h>
#include <math.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>
#include <zlib.h>

#include "frame.h"
#include "outfile.h"
#include "proto_check.h"

#define READ_BUF (64u << 10)
#define IGNORE_SLOTS 16

/* ---------------------------------------------------------------- errors */

static const char *const server_names[] = {
    "INVALID_INPUT", "LIMIT_EXCEEDED", "BUSY",          "CANCELLED",
    "WORKER_CRASHED", "TIMEOUT",       "SHUTTING_DOWN", "INTERNAL",
};
static const char *const server_texts[] = {
    "the daemon refused the job as invalid",
    "over a limit of the daemon",
    "the daemon is busy",
    "the job was cancelled",
    "a worker of the daemon died during the job",
    "the job ran past the daemon's time limit",
    "the daemon is shutting down",
    "internal error in the daemon",
};

const char *vox_error_name(int code)
{
    if (!VOX_IS_SERVER_ERROR(code)) return NULL;
    return server_names[-code - VOX_ESERVER_BASE - 1];
}

const char *vox_strerror(int code)
{
    if (code == 0) return "success";
    if (VOX_IS_SERVER_ERROR(code)) return server_texts[-code - VOX_ESERVER_BASE - 1];
    switch (code) {
    case -ETIMEDOUT: return "the daemon did not answer in time";
    case -ECONNRESET: return "the daemon closed the connection";
    case -EPROTO: return "the daemon broke the protocol";
    case -EBADMSG: return "the result does not check (length or CRC-32)";
    }
    if (code < 0 && code > -4096) return strerror(-code);
    return "unknown error";
}

/* ---------------------------------------------------------------- state */

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
    frame_decoder dec;
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

static double mono(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

__attribute__((format(printf, 4, 5)))
static void set_error(vox_error *e, int code, uint64_t job, const char *fmt, ...)
{
    e->code = code;
    e->job_id = job;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(e->message, sizeof e->message, fmt, ap);
    va_end(ap);
}

static void copy_error(vox_error *dst, const vox_error *src)
{
    if (dst) *dst = *src;
}

/* Fail the connection (once: the first failure is the one reported). */
__attribute__((format(printf, 3, 4)))
static int fail(vox_client *c, int code, const char *fmt, ...)
{
    if (c->err) return c->err;
    c->err = code;
    c->fail.code = code;
    c->fail.job_id = 0;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(c->fail.message, sizeof c->fail.message, fmt, ap);
    va_end(ap);
    return code;
}

/* The daemon closed the connection: say why if it said so first. */
static int fail_closed(vox_client *c, const char *how)
{
    if (c->note_code) {
        int code = -(VOX_ESERVER_BASE + c->note_code);
        return fail(c, code, "%s", c->note);
    }
    return fail(c, -ECONNRESET, "voxd closed the connection%s", how);
}

static vjob *find_job(vox_client *c, uint64_t id)
{
    for (vjob *j = c->jobs; j; j = j->next)
        if (j->id == id) return j;
    return NULL;
}

static void free_job(vjob *j)
{
    if (j->sink == SINK_SPOOL && j->fd >= 0) close(j->fd);
    free(j->buf);
    free(j);
}

static void forget_job(vox_client *c, vjob *j)
{
    for (vjob **p = &c->jobs; *p; p = &(*p)->next)
        if (*p == j) {
            *p = j->next;
            break;
        }
    free_job(j);
}

/* A job's end has been dispatched. */
static void job_ended(vox_client *c, vjob *j)
{
    if (j->discard) forget_job(c, j);
}

static int ignored(const vox_client *c, uint64_t id)
{
    unsigned n = c->n_ignore < IGNORE_SLOTS ? c->n_ignore : IGNORE_SLOTS;
    for (unsigned i = 0; i < n; i++)
        if (c->ignore[i] == id) return 1;
    return 0;
}

static void add_ignored(vox_client *c, uint64_t id)
{
    if (!ignored(c, id)) c->ignore[c->n_ignore++ % IGNORE_SLOTS] = id;
}

/* ---------------------------------------------------------------- results */

static int write_all(int fd, const uint8_t *p, size_t n)
{
    while (n) {
        ssize_t w = write(fd, p, n);
        if (w < 0) {
            if (errno == EINTR) continue;
            return -errno;
        }
        p += w;
        n -= (size_t)w;
    }
    return 0;
}

/* An unlinked temporary file for results nobody is receiving yet. */
static int spool_open(void)
{
    const char *dir = getenv("TMPDIR");
    if (!dir || !*dir) dir = "/tmp";
    int fd = open(dir, O_TMPFILE | O_RDWR | O_CLOEXEC, 0600);
    if (fd >= 0) return fd;
    char path[PATH_MAX];
    if (snprintf(path, sizeof path, "%s/libvox.XXXXXX", dir) >= (int)sizeof path)
        return -ENAMETOOLONG;
    fd = mkostemp(path, O_CLOEXEC);
    if (fd < 0) return -errno;
    unlink(path);
    return fd;
}

static int buf_append(vjob *j, const uint8_t *p, size_t n)
{
    size_t need = (size_t)j->received + n;
    if (need > j->cap) {
        size_t cap = j->cap ? j->cap : 65536;
        while (cap < need) cap = cap > SIZE_MAX / 2 ? need : cap * 2;
        uint8_t *b = realloc(j->buf, cap);
        if (!b) return -ENOMEM;
        j->buf = b;
        j->cap = cap;
    }
    memcpy(j->buf + j->received, p, n);
    return 0;
}

static int sink_write(vjob *j, const uint8_t *p, size_t n)
{
    switch (j->sink) {
    case SINK_NONE: return 0;
    case SINK_BUF: return buf_append(j, p, n);
    case SINK_SPOOL:
        if (j->fd < 0 && (j->fd = spool_open()) < 0) {
            int rc = j->fd;
            j->fd = -1;
            return rc;
        }
        return write_all(j->fd, p, n);
    default: return write_all(j->fd, p, n);
    }
}

/* The CRC of everything but the last 4 bytes seen so far, which wait in
 * tail until more bytes come or the summary checks them. */
static void crc_feed(vjob *j, const uint8_t *p, size_t n)
{
    if (n >= 4) {
        if (j->tail_n) j->crc = (uint32_t)crc32(j->crc, j->tail, j->tail_n);
        j->crc = (uint32_t)crc32(j->crc, p, (uInt)(n - 4));
        memcpy(j->tail, p + n - 4, 4);
        j->tail_n = 4;
        return;
    }
    uint8_t t[8];
    size_t total = j->tail_n + n;
    memcpy(t, j->tail, j->tail_n);
    memcpy(t + j->tail_n, p, n);
    if (total > 4) {
        j->crc = (uint32_t)crc32(j->crc, t, (uInt)(total - 4));
        memcpy(j->tail, t + total - 4, 4);
        j->tail_n = 4;
    } else {
        memcpy(j->tail, t, total);
        j->tail_n = (unsigned)total;
    }
}

static int on_chunk(vox_client *c, const Voxd__ResultChunk *m)
{
    vjob *j = find_job(c, m->job_id);
    if (!j)
        return fail(c, -EPROTO, "voxd sent a result chunk for job %llu, which is not a job of this connection",
                    (unsigned long long)m->job_id);
    if (j->done)
        return fail(c, -EPROTO, "voxd sent a result chunk for job %llu after its end",
                    (unsigned long long)m->job_id);
    if (m->offset != j->received)
        return fail(c, -EPROTO, "voxd sent job %llu's chunk at offset %llu where %llu was due",
                    (unsigned long long)m->job_id, (unsigned long long)m->offset,
                    (unsigned long long)j->received);
    /* proto_check_reply bounded offset + len by max_result_bytes. */
    if (!j->local_err) {
        int rc = sink_write(j, m->data.data, m->data.len);
        if (rc) {
            j->local_err = rc;
            set_error(&j->result, rc, j->id, "cannot store job %llu's result: %s",
                      (unsigned long long)j->id, strerror(-rc));
        }
    }
    crc_feed(j, m->data.data, m->data.len);
    j->received += m->data.len;
    j->t_data = c->t_any_data = mono();
    return 0;
}

static void on_summary(vjob *j, const Voxd__Summary *m)
{
    j->done = 1;
    if (j->local_err) return;
    unsigned long long id = (unsigned long long)j->id;
    if (m->file_bytes != j->received) {
        set_error(&j->result, -EBADMSG, j->id,
                  "job %llu's result is %llu bytes, the daemon's summary says %llu", id,
                  (unsigned long long)j->received, (unsigned long long)m->file_bytes);
        return;
    }
    uint32_t own = (uint32_t)j->tail[0] | (uint32_t)j->tail[1] << 8 |
                   (uint32_t)j->tail[2] << 16 | (uint32_t)j->tail[3] << 24;
    if (j->tail_n < 4 || j->crc != m->crc32 || own != m->crc32) {
        set_error(&j->result, -EBADMSG, j->id,
                  "job %llu's result fails its CRC-32 check: computed %08x, the file says %08x, "
                  "the daemon's summary %08x",
                  id, j->crc, own, m->crc32);
        return;
    }
    j->result.code = 0;
    j->sum = (vox_summary){
        .job_id = j->id, .voxels = m->voxels, .bricks = m->bricks,
        .file_bytes = m->file_bytes, .crc32 = m->crc32,
        .seconds_queued = m->seconds_queued, .seconds_voxelize = m->seconds_voxelize,
        .seconds_write = m->seconds_write, .mpi_ranks = m->mpi_ranks};
    /* proto_check_reply made sure of 3 values each and a consistent grid. */
    const Voxd__Grid *g = m->grid;
    for (int a = 0; a < 3; a++) {
        j->sum.grid[a] = g->res[a];
        j->sum.origin[a] = g->origin[a];
    }
    j->sum.depth = g->depth;
    j->sum.voxel_size = g->voxel_size;
    const Voxd__MeshReport *mr = m->mesh;
    if (mr) {
        j->sum.has_mesh = 1;
        j->sum.mesh.triangles = mr->triangles;
        j->sum.mesh.open_edges = mr->open_edges;
        j->sum.mesh.nonmanifold_edges = mr->nonmanifold_edges;
        j->sum.mesh.watertight = mr->watertight;
        j->sum.mesh.tiles = mr->tiles;
        j->sum.mesh.repair_skipped = mr->repair_skipped;
        j->sum.mesh.disagreements = mr->disagreements;
        j->sum.mesh.disagree_bricks = mr->disagree_bricks;
    }
}

/* ---------------------------------------------------------------- dispatch */

static void answer(vox_client *c, int code, uint64_t job, const char *msg)
{
    c->answered = 1;
    c->ans.code = code;
    c->ans.job_id = job;
    snprintf(c->ans.message, sizeof c->ans.message, "%s", msg ? msg : "");
}

static int on_error(vox_client *c, const Voxd__Error *m)
{
    int code = -(VOX_ESERVER_BASE + (int)m->code);
    const char *msg = m->message && *m->message ? m->message : vox_strerror(code);
    vjob *j = m->job_id ? find_job(c, m->job_id) : NULL;
    if (j && !j->done) {
        j->done = 1;
        if (!j->local_err) set_error(&j->result, code, j->id, "%s", msg);
        job_ended(c, j);
        return 0;
    }
    /* A job of ours that has ended: a late answer to a cancel of it is no
     * news; anything else is a second end. */
    if (j) {
        if (ignored(c, m->job_id)) return 0;
        return fail(c, -EPROTO, "voxd sent a second end for job %llu",
                    (unsigned long long)m->job_id);
    }
    /* What the daemon says about a cancel this client waits on. */
    if (c->pending == P_CANCEL && !c->answered &&
        (m->job_id == 0 || m->job_id == c->cancel_job)) {
        answer(c, code, m->job_id, msg);
        return 0;
    }
    if (m->job_id && ignored(c, m->job_id)) return 0;
    /* A refused request; only a Submit's refusal may name a job id (the
     * one the job would have had).  While draining an upload, an Error
     * with no job is about a chunk sent after its job ended: no news. */
    if (c->pending == P_DRAIN && m->job_id == 0) return 0;
    if (c->pending != P_NONE && !c->answered &&
        (m->job_id == 0 || c->pending == P_SUBMIT)) {
        answer(c, code, m->job_id, msg);
        return 0;
    }
    if (m->job_id)
        return fail(c, -EPROTO, "voxd sent an error for job %llu, which is not a job of this connection: %s",
                    (unsigned long long)m->job_id, msg);
    /* About the connection: kept to say why, should the daemon close it. */
    c->note_code = (int)m->code;
    snprintf(c->note, sizeof c->note, "%s", msg);
    return 0;
}

static int on_hello_ok(vox_client *c, const Voxd__HelloOk *m)
{
    if (c->ready || c->pending != P_HELLO)
        return fail(c, -EPROTO, "voxd sent a second hello");
    const Voxd__Limits *l = m->limits;
    proto_limits_from_hello(l, &c->lim);
    frame_decoder_set_max(&c->dec, l->max_frame);
    vox_server_info *i = &c->info;
    snprintf(i->name, sizeof i->name, "%s", m->server ? m->server : "");
    i->version = m->version;
    i->workers = m->workers;
#define INFO_LIMIT(name, type, def, min, max, unit, doc) i->name = l->name;
    VOX_LIMITS(INFO_LIMIT)
#undef INFO_LIMIT
    c->ready = 1;
    answer(c, 0, 0, NULL);
    return 0;
}

static int on_accepted(vox_client *c, const Voxd__Accepted *m)
{
    if (c->pending != P_SUBMIT || c->answered)
        return fail(c, -EPROTO, "voxd accepted job %llu, which was never submitted",
                    (unsigned long long)m->job_id);
    if (find_job(c, m->job_id))
        return fail(c, -EPROTO, "voxd accepted job %llu a second time",
                    (unsigned long long)m->job_id);
    vjob *j = calloc(1, sizeof *j);
    if (!j) return fail(c, -ENOMEM, "out of memory");
    j->id = m->job_id;
    j->fd = -1;
    j->sink = SINK_SPOOL;
    j->t_accepted = mono();
    j->queue_position = m->queue_position;
    j->next = c->jobs;
    c->jobs = j;
    c->ans_job = m->job_id;
    c->ans_qpos = m->queue_position;
    answer(c, 0, m->job_id, NULL);
    return 0;
}

static int on_progress(vox_client *c, const Voxd__Progress *m)
{
    vjob *j = find_job(c, m->job_id);
    if (!j || j->done)
        return fail(c, -EPROTO, "voxd sent progress for job %llu, which %s",
                    (unsigned long long)m->job_id,
                    j ? "has ended" : "is not a job of this connection");
    if (j->received)
        return fail(c, -EPROTO, "voxd sent progress for job %llu after its result began",
                    (unsigned long long)m->job_id);
    j->fraction = m->fraction;
    j->level = (int)m->level;
    j->voxels = m->voxels;
    j->progress_new = 1;
    return 0;
}

static int on_status(vox_client *c, const Voxd__StatusReply *m)
{
    if (c->pending != P_STATUS || c->answered)
        return fail(c, -EPROTO, "voxd sent a status nobody asked for");
    vox_status_info *s = &c->ans_status;
    memset(s, 0, sizeof *s);
    s->uptime = m->uptime;
    s->queued = m->queued;
    s->clients = m->clients;
    if (m->n_workers) {
        s->workers = calloc(m->n_workers, sizeof *s->workers);
        if (!s->workers) return fail(c, -ENOMEM, "out of memory");
        s->n_workers = m->n_workers;
        for (size_t i = 0; i < m->n_workers; i++) {
            const Voxd__WorkerStatus *w = m->workers[i];
            s->workers[i] = (vox_worker_status){w->pid, w->cpu, (int)w->state, w->jobs,
                                                w->voxels_per_second, w->replaced,
                                                w->stalls};
        }
    }
    if (m->n_jobs && !(s->jobs = calloc(m->n_jobs, sizeof *s->jobs)))
        return fail(c, -ENOMEM, "out of memory");
    s->n_jobs = m->n_jobs;
    for (size_t i = 0; i < m->n_jobs; i++) {
        const Voxd__JobStatus *j = m->jobs[i];
        s->jobs[i] = (vox_job_status){j->job_id, j->uid, (int)j->kind, j->res,
                                      (int)j->state, j->fraction, j->seconds};
    }
    if (m->running) {
        s->has_running = 1;
        s->running_job_id = m->running->job_id;
        s->running_uid = m->running->uid;
        s->running_fraction = m->running->fraction;
        s->running_seconds = m->running->seconds;
    }
    answer(c, 0, 0, NULL);
    return 0;
}

static int on_pong(vox_client *c, const Voxd__Pong *m)
{
    if (m->token <= c->last_pong || m->token >= c->next_token)
        return fail(c, -EPROTO, "voxd answered a ping that %s (token %llu)",
                    m->token >= c->next_token ? "was never sent" : "it had answered",
                    (unsigned long long)m->token);
    c->last_pong = m->token;
    if ((c->pending == P_PING || c->pending == P_CANCEL || c->pending == P_DRAIN) &&
        !c->answered && m->token == c->ping_token)
        answer(c, 0, 0, NULL);
    return 0;
}

static int dispatch(vox_client *c, const uint8_t *data, size_t len)
{
    Voxd__Reply *r = frame_unpack_reply(data, len);
    if (!r) return fail(c, -EPROTO, "voxd sent a reply that does not unpack (%zu bytes)", len);
    proto_error pe;
    int rc = proto_check_reply(r, &c->lim, &pe);
    if (rc) {
        rc = fail(c, -EPROTO, "voxd sent an invalid reply: %s", pe.msg);
    } else if (!c->ready && r->msg_case != VOXD__REPLY__MSG_HELLO_OK &&
               r->msg_case != VOXD__REPLY__MSG_ERROR) {
        rc = fail(c, -EPROTO, "voxd sent a reply of type %d before its hello", (int)r->msg_case);
    } else {
        switch (r->msg_case) {
        case VOXD__REPLY__MSG_HELLO_OK: rc = on_hello_ok(c, r->hello_ok); break;
        case VOXD__REPLY__MSG_ACCEPTED: rc = on_accepted(c, r->accepted); break;
        case VOXD__REPLY__MSG_PROGRESS: rc = on_progress(c, r->progress); break;
        case VOXD__REPLY__MSG_CHUNK: rc = on_chunk(c, r->chunk); break;
        case VOXD__REPLY__MSG_SUMMARY: {
            vjob *j = find_job(c, r->summary->job_id);
            if (!j || j->done)
                rc = fail(c, -EPROTO, "voxd sent a summary for job %llu, which %s",
                          (unsigned long long)r->summary->job_id,
                          j ? "has ended" : "is not a job of this connection");
            else {
                on_summary(j, r->summary);
                job_ended(c, j);
            }
            break;
        }
        case VOXD__REPLY__MSG_ERROR: rc = on_error(c, r->error); break;
        case VOXD__REPLY__MSG_STATUS: rc = on_status(c, r->status); break;
        case VOXD__REPLY__MSG_PONG: rc = on_pong(c, r->pong); break;
        default: rc = fail(c, -EPROTO, "voxd sent a reply of unknown type"); break;
        }
    }
    voxd__reply__free_unpacked(r, NULL);
    return rc;
}

/* ---------------------------------------------------------------- socket */

/* Read what is there and dispatch every complete frame.  0, or the
 * connection's failure. */
static int read_some(vox_client *c)
{
    ssize_t n = read(c->fd, c->rbuf, READ_BUF);
    if (n < 0) {
        if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) return 0;
        if (errno == ECONNRESET) return fail_closed(c, "");
        return fail(c, -errno, "reading from voxd: %s", strerror(errno));
    }
    if (n == 0) {
        int rc = frame_decoder_finish(&c->dec);
        return fail_closed(c, rc ? " in the middle of a reply" : "");
    }
    c->last_rx = mono();
    const uint8_t *p = c->rbuf;
    size_t left = (size_t)n;
    frame_view f;
    int rc;
    while ((rc = frame_decode(&c->dec, &p, &left, &f)) == 1)
        if ((rc = dispatch(c, f.data, f.len))) return rc;
    if (rc < 0) {
        char why[160];
        return fail(c, -EPROTO, "voxd sent a bad frame: %s",
                    frame_decoder_strerror(&c->dec, rc, why, sizeof why));
    }
    return 0;
}

static int timeout_left_ms(const vox_client *c, double since, double now)
{
    double left = c->timeout_ms / 1000.0 - (now - since);
    if (left <= 0) return 0;
    return (int)ceil(left * 1000.0);
}

/* Send a whole frame, reading (and dispatching) whatever comes meanwhile. */
static int send_frame(vox_client *c, const uint8_t *buf, size_t len)
{
    if (c->err) return c->err;
    size_t off = 0;
    double moved = mono();
    while (off < len) {
        ssize_t n = send(c->fd, buf + off, len - off, MSG_NOSIGNAL);
        if (n > 0) {
            off += (size_t)n;
            moved = mono();
            continue;
        }
        if (n < 0 && errno == EINTR) continue;
        if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) {
            int e = errno;
            if (e == EPIPE || e == ECONNRESET) {
                /* Read what the daemon said before it closed. */
                while (!c->err && read_some(c) == 0) {
                    struct pollfd q = {c->fd, POLLIN, 0};
                    if (poll(&q, 1, 0) <= 0) break;
                }
                return fail_closed(c, "");
            }
            return fail(c, -e, "writing to voxd: %s", strerror(e));
        }
        struct pollfd p = {c->fd, POLLOUT | POLLIN, 0};
        int ms = timeout_left_ms(c, moved, mono());
        if (ms == 0)
            return fail(c, -ETIMEDOUT, "voxd took nothing from the socket for %.1f s",
                        c->timeout_ms / 1000.0);
        int r = poll(&p, 1, ms);
        if (r < 0 && errno != EINTR) return fail(c, -errno, "poll: %s", strerror(errno));
        if (r > 0 && (p.revents & (POLLIN | POLLHUP | POLLERR))) {
            int rc = read_some(c);
            if (rc) return rc;
        }
    }
    return 0;
}

static int send_request(vox_client *c, const Voxd__Request *req)
{
    uint8_t *buf;
    size_t len;
    int rc = frame_encode_request(req, &buf, &len);
    if (rc) return rc;
    rc = send_frame(c, buf, len);
    free(buf);
    return rc;
}

static int send_ping(vox_client *c, uint64_t token)
{
    Voxd__Ping ping = VOXD__PING__INIT;
    ping.token = token;
    Voxd__Request req = VOXD__REQUEST__INIT;
    req.msg_case = VOXD__REQUEST__MSG_PING;
    req.ping = &ping;
    return send_request(c, &req);
}

static int send_cancel(vox_client *c, uint64_t job_id)
{
    Voxd__Cancel cancel = VOXD__CANCEL__INIT;
    cancel.job_id = job_id;
    Voxd__Request req = VOXD__REQUEST__INIT;
    req.msg_case = VOXD__REQUEST__MSG_CANCEL;
    req.cancel = &cancel;
    return send_request(c, &req);
}

/* Nobody will receive the job: cancel it, drop what comes of it until its
 * end, then free it (its replies must still check, and a cancel's late
 * answer is no news).  j may be freed on return. */
static void drop_job(vox_client *c, vjob *j)
{
    if (j->done) {
        forget_job(c, j);
        return;
    }
    if (j->sink == SINK_SPOOL && j->fd >= 0) close(j->fd);
    free(j->buf);
    j->buf = NULL;
    j->fd = -1;
    j->sink = SINK_NONE;
    j->discard = 1;
    add_ignored(c, j->id);
    if (!j->cancel_sent) {
        j->cancel_sent = 1;
        send_cancel(c, j->id); /* may end and free j; a failure is the connection's */
    }
}

/* Wait for input once (or for the timeout, or a signal) and dispatch it.
 * After half the timeout of silence a ping goes out: a daemon that is busy
 * with other jobs answers it, a hung one does not.  *interrupted is set when
 * a signal cut the wait short.  0, or the connection's failure. */
static int step(vox_client *c, int max_ms, int *interrupted)
{
    if (c->err) return c->err;
    double now = mono(), half = c->timeout_ms / 2000.0;
    double idle = now - c->last_rx;
    if (idle >= c->timeout_ms / 1000.0)
        return fail(c, -ETIMEDOUT, "voxd said nothing for %.1f s", c->timeout_ms / 1000.0);
    int ka_due = c->ready && c->ka_sent <= c->last_rx;
    if (ka_due && idle >= half) {
        int rc = send_ping(c, c->next_token++);
        if (rc) return rc;
        c->ka_sent = now;
        ka_due = 0;
    }
    int ms = timeout_left_ms(c, c->last_rx, now);
    if (ka_due) {
        int to_ka = (int)ceil((half - idle) * 1000.0);
        if (to_ka < ms) ms = to_ka < 1 ? 1 : to_ka;
    }
    if (max_ms >= 0 && max_ms < ms) ms = max_ms;
    struct pollfd p = {c->fd, POLLIN, 0};
    int r = poll(&p, 1, ms);
    if (r < 0) {
        if (errno == EINTR) {
            if (interrupted) *interrupted = 1;
            return 0;
        }
        return fail(c, -errno, "poll: %s", strerror(errno));
    }
    if (r == 0) return 0;
    return read_some(c);
}

/* Send a request and wait for its answer. */
static int request(vox_client *c, int kind, const Voxd__Request *req, vox_error *err)
{
    if (c->err) {
        copy_error(err, &c->fail);
        return c->err;
    }
    c->pending = kind;
    c->answered = 0;
    memset(&c->ans, 0, sizeof c->ans);
    int rc = send_request(c, req);
    if (rc && !c->err) {
        set_error(&c->ans, rc, 0, "cannot send the request: %s", vox_strerror(rc));
        c->pending = P_NONE;
        copy_error(err, &c->ans);
        return rc;
    }
    while (!rc && !c->answered) rc = step(c, -1, NULL);
    c->pending = P_NONE;
    if (!c->answered) {
        copy_error(err, &c->fail);
        return c->err;
    }
    if (c->ans.code) copy_error(err, &c->ans);
    return c->ans.code;
}

/* ---------------------------------------------------------------- connect */

int vox_connect_fd(int fd, const vox_options *opts, vox_client **out, vox_error *err)
{
    vox_error tmp;
    if (!err) err = &tmp;
    *out = NULL;
    int fl = fcntl(fd, F_GETFL);
    if (fl < 0 || fcntl(fd, F_SETFL, fl | O_NONBLOCK) < 0) {
        int rc = -errno;
        close(fd);
        set_error(err, rc, 0, "%s", strerror(-rc));
        return rc;
    }
    vox_client *c = calloc(1, sizeof *c);
    uint8_t *rbuf = malloc(READ_BUF);
    if (!c || !rbuf) {
        free(c);
        free(rbuf);
        close(fd);
        set_error(err, -ENOMEM, 0, "out of memory");
        return -ENOMEM;
    }
    c->fd = fd;
    c->rbuf = rbuf;
    c->timeout_ms = opts && opts->timeout_ms > 0 ? opts->timeout_ms : VOX_DEFAULT_TIMEOUT_MS;
    c->inline_max = opts && opts->inline_max ? opts->inline_max : VOX_DEFAULT_INLINE_MAX;
    c->next_token = 1;
    proto_limits_default(&c->lim);
    frame_decoder_init(&c->dec, FRAME_DEFAULT_MAX);
    c->last_rx = mono();

    Voxd__Hello hello = VOXD__HELLO__INIT;
    hello.version = PROTO_VERSION;
    hello.client = (char *)(opts && opts->client_name ? opts->client_name : "libvox");
    Voxd__Request req = VOXD__REQUEST__INIT;
    req.msg_case = VOXD__REQUEST__MSG_HELLO;
    req.hello = &hello;
    int rc = request(c, P_HELLO, &req, err);
    if (rc) {
        if (VOX_IS_SERVER_ERROR(rc)) {
            char msg[sizeof err->message];
            snprintf(msg, sizeof msg, "%s", err->message);
            set_error(err, rc, 0, "voxd refused this client: %s", msg);
        }
        vox_close(c);
        return rc;
    }
    *out = c;
    return 0;
}

int vox_connect(const char *socket_path, const vox_options *opts, vox_client **out,
                vox_error *err)
{
    vox_error tmp;
    if (!err) err = &tmp;
    *out = NULL;
    struct sockaddr_un sa = {.sun_family = AF_UNIX};
    if (!socket_path || strlen(socket_path) >= sizeof sa.sun_path) {
        set_error(err, -ENAMETOOLONG, 0, "socket path %s is too long (at most %zu bytes)",
                  socket_path ? socket_path : "(null)", sizeof sa.sun_path - 1);
        return -ENAMETOOLONG;
    }
    strcpy(sa.sun_path, socket_path);
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) {
        int rc = -errno;
        set_error(err, rc, 0, "socket: %s", strerror(-rc));
        return rc;
    }
    if (connect(fd, (struct sockaddr *)&sa, sizeof sa) != 0) {
        int rc = -errno;
        close(fd);
        set_error(err, rc, 0, "no voxd answering on %s (%s)", socket_path,
                  rc == -ECONNREFUSED ? "connection refused" : strerror(-rc));
        return rc;
    }
    return vox_connect_fd(fd, opts, out, err);
}

void vox_close(vox_client *c)
{
    if (!c) return;
    while (c->jobs) {
        vjob *j = c->jobs;
        c->jobs = j->next;
        free_job(j);
    }
    close(c->fd);
    frame_decoder_free(&c->dec);
    free(c->rbuf);
    free(c);
}

void vox_set_timeout(vox_client *c, int ms)
{
    if (ms > 0) c->timeout_ms = ms;
}

void vox_server(const vox_client *c, vox_server_info *out)
{
    *out = c->info;
}

/* ---------------------------------------------------------------- requests */

/* A ping, and every reply up to its pong: see P_DRAIN. */
static int drain(vox_client *c, vox_error *err)
{
    c->ping_token = c->next_token++;
    Voxd__Ping ping = VOXD__PING__INIT;
    ping.token = c->ping_token;
    Voxd__Request req = VOXD__REQUEST__INIT;
    req.msg_case = VOXD__REQUEST__MSG_PING;
    req.ping = &ping;
    return request(c, P_DRAIN, &req, err);
}

/* Send job id's input in InputChunks, in order; stop early when the daemon
 * ends the job.  0, or the connection's failure. */
static int upload(vox_client *c, uint64_t id, const uint8_t *data, size_t n, vox_error *err)
{
    size_t piece = c->info.chunk_size; /* within a frame: proto_check_reply */
    /* What comes meanwhile is no answer to anything; an Error with no job
     * is about a chunk (see P_DRAIN). */
    c->pending = P_DRAIN;
    c->answered = 1;
    for (size_t off = 0; off < n;) {
        vjob *j = find_job(c, id);
        if (!j || j->done) break;
        size_t k = n - off < piece ? n - off : piece;
        Voxd__InputChunk in = VOXD__INPUT_CHUNK__INIT;
        in.job_id = id;
        in.offset = off;
        in.data.data = (uint8_t *)data + off;
        in.data.len = k;
        Voxd__Request req = VOXD__REQUEST__INIT;
        req.msg_case = VOXD__REQUEST__MSG_INPUT;
        req.input = &in;
        int rc = send_request(c, &req);
        if (rc) {
            c->pending = P_NONE;
            copy_error(err, &c->fail);
            return rc;
        }
        off += k;
    }
    c->pending = P_NONE;
    int rc = drain(c, err);
    vjob *j = find_job(c, id);
    if (j) j->t_accepted = mono(); /* its time to finish counts from here */
    return rc;
}

/* A Submit and the messages it points into (the caller's, on its stack). */
typedef struct {
    Voxd__Implicit im;
    Voxd__Mesh mesh;
    Voxd__Submit sub;
    Voxd__Request req;
} submit_msg;

/* The job's input, the expression or the mesh file: 0, or -EINVAL /
 * -ENOTSUP with err set. */
static int job_input(const vox_job *job, const uint8_t **data, size_t *len, vox_error *err)
{
    int k = job ? job->kind : 0;
    if (k == VOX_JOB_IMPLICIT && job->implicit.source) {
        *data = (const uint8_t *)job->implicit.source;
        *len = job->implicit.source_len ? job->implicit.source_len
                                        : strlen(job->implicit.source);
        return 0;
    }
    if (k == VOX_JOB_MESH && job->mesh.data && job->mesh.len) {
        *data = job->mesh.data;
        *len = job->mesh.len;
        return 0;
    }
    int rc = -EINVAL;
    set_error(err, rc, 0, "%s",
              k == VOX_JOB_IMPLICIT   ? "the job has no expression"
              : k == VOX_JOB_MESH     ? "the job has no mesh data"
                                      : "the job is of no known kind");
    return rc;
}

/* A file's name for the metadata, if any. */
static ProtobufCBinaryData name_bytes(const char *name)
{
    ProtobufCBinaryData b = {name ? strlen(name) : 0, (uint8_t *)name};
    return b;
}

/* The kind's message: its input inline, or left out (chunked: sent by
 * upload after the Accepted). */
static void implicit_request(const vox_job *job, const uint8_t *data, size_t len,
                             int chunked, submit_msg *m)
{
    const vox_implicit *ij = &job->implicit;
    if (!chunked) m->im.source.data = (uint8_t *)data, m->im.source.len = len;
    m->im.source_name = name_bytes(ij->source_name);
    m->im.domain = (double *)ij->domain;
    m->im.n_domain = 6;
    m->im.res = ij->res;
    m->im.schedule = (Voxd__Schedule)ij->schedule;
    m->sub.job_case = VOXD__SUBMIT__JOB_IMPLICIT;
    m->sub.implicit = &m->im;
}

static void mesh_request(const vox_job *job, const uint8_t *data, size_t len, int chunked,
                         submit_msg *m)
{
    const vox_mesh *mj = &job->mesh;
    if (!chunked) m->mesh.data.data = (uint8_t *)data, m->mesh.data.len = len;
    m->mesh.format = (Voxd__MeshFormat)mj->format;
    m->mesh.mode = (Voxd__MeshMode)mj->mode;
    m->mesh.repair = (Voxd__MeshRepair)mj->repair;
    /* one field of vox_mesh, two of the protocol's */
    if (job->channel == VOX_CHANNEL_DISTANCE) m->mesh.band = mj->supersample;
    else m->mesh.supersample = mj->supersample;
    m->mesh.weld = mj->weld != 0;
    m->mesh.weld_eps = mj->weld_eps;
    m->mesh.source_name = name_bytes(mj->source_name);
    if (mj->fit) {
        m->mesh.pad = mj->pad;
    } else {
        m->mesh.domain = (double *)mj->domain;
        m->mesh.n_domain = 6;
    }
    m->mesh.res = mj->res;
    m->sub.job_case = VOXD__SUBMIT__JOB_MESH;
    m->sub.mesh = &m->mesh;
}

/* The Submit of job, its input inline or declared as input_bytes. */
static void submit_request(const vox_job *job, const uint8_t *data, size_t len, int chunked,
                           submit_msg *m)
{
    *m = (submit_msg){VOXD__IMPLICIT__INIT, VOXD__MESH__INIT, VOXD__SUBMIT__INIT,
                      VOXD__REQUEST__INIT};
    if (job->kind == VOX_JOB_MESH) mesh_request(job, data, len, chunked, m);
    else if (job->kind == VOX_JOB_IMPLICIT) implicit_request(job, data, len, chunked, m);
    if (chunked) m->sub.input_bytes = len;
    m->sub.channel = (Voxd__Channel)job->channel;
    m->sub.brick = job->brick;
    m->sub.comp = (Voxd__Compression)job->comp;
    m->sub.hash = (Voxd__Hash)job->hash;
    m->req.msg_case = VOXD__REQUEST__MSG_SUBMIT;
    m->req.submit = &m->sub;
}

/* What the daemon would refuse for its size, refused here unsent. */
static int check_input_size(const vox_client *c, int kind, size_t len, int chunked,
                            vox_error *err)
{
    if (kind == VOX_JOB_IMPLICIT && len > c->lim.max_expr_bytes) {
        set_error(err, VOX_ELIMIT_EXCEEDED, 0,
                  "expression is %zu bytes, over this server's max_expr_bytes of %u", len,
                  c->lim.max_expr_bytes);
        return VOX_ELIMIT_EXCEEDED;
    }
    if (kind == VOX_JOB_MESH && len > c->lim.max_mesh_bytes) {
        set_error(err, VOX_ELIMIT_EXCEEDED, 0,
                  "mesh is %zu bytes, over this server's max_mesh_bytes of %llu", len,
                  (unsigned long long)c->lim.max_mesh_bytes);
        return VOX_ELIMIT_EXCEEDED;
    }
    if (chunked && len > c->lim.max_input_bytes) {
        set_error(err, VOX_ELIMIT_EXCEEDED, 0,
                  "the job's input is %zu bytes, over this server's max_input_bytes of %llu",
                  len, (unsigned long long)c->lim.max_input_bytes);
        return VOX_ELIMIT_EXCEEDED;
    }
    return 0;
}

/* A CSG job's Submit: its nodes in arrays of the caller's (nodes, ptrs),
 * pointing into job. */
static void csg_request(const vox_job *job, int chunked, Voxd__CsgNode *nodes,
                        Voxd__CsgNode **ptrs, submit_msg *m, Voxd__Csg *cm)
{
    const vox_csg *cj = &job->csg;
    for (size_t i = 0; i < cj->n_nodes; i++) {
        const vox_csg_node *v = &cj->nodes[i];
        Voxd__CsgNode *n = &nodes[i];
        voxd__csg_node__init(n);
        n->op = (Voxd__CsgOp)v->op;
        n->children = (uint32_t *)v->children;
        n->n_children = v->n_children > 2 ? 2 : v->n_children;
        if (v->op == VOX_CSG_PRIMITIVE) {
            n->primitive = (Voxd__Primitive)v->primitive;
            n->center = (double *)v->center, n->n_center = 3;
            n->size = (double *)v->size, n->n_size = 3;
            n->rotate = (double *)v->rotate, n->n_rotate = 3;
            n->axis = (Voxd__Axis)v->axis;
        }
        if (v->source) {
            n->source.data = (uint8_t *)v->source;
            n->source.len = v->source_len ? v->source_len : strlen(v->source);
        }
        if (v->has_domain) n->domain = (double *)v->domain, n->n_domain = 2;
        n->scalar = v->scalar;
        n->k = v->k;
        n->name = name_bytes(v->name);
        if (v->data && chunked) n->data_bytes = v->data_len;
        else if (v->data) n->data.data = (uint8_t *)v->data, n->data.len = v->data_len;
        if (v->has_fit) n->fit = (double *)v->fit, n->n_fit = 3;
        n->scale = v->scale;
        ptrs[i] = n;
    }
    voxd__csg__init(cm);
    cm->nodes = ptrs;
    cm->n_nodes = cj->n_nodes;
    cm->domain = (double *)cj->domain;
    cm->n_domain = 6;
    cm->res = cj->res;
    cm->source_name = name_bytes(cj->source_name);
    cm->source_bytes = cj->source_bytes;
    m->sub.job_case = VOXD__SUBMIT__JOB_CSG;
    m->sub.csg = cm;
}

/* The mesh and VOD leaves' files one after the other, in node order (the
 * job's input when they go in InputChunks); *len their size. */
static uint8_t *csg_leaves_input(const vox_csg *cj, size_t *len)
{
    size_t n = 0;
    for (size_t i = 0; i < cj->n_nodes; i++)
        if (cj->nodes[i].data) n += cj->nodes[i].data_len;
    uint8_t *buf = malloc(n ? n : 1);
    if (!buf) return NULL;
    size_t off = 0;
    for (size_t i = 0; i < cj->n_nodes; i++)
        if (cj->nodes[i].data) {
            memcpy(buf + off, cj->nodes[i].data, cj->nodes[i].data_len);
            off += cj->nodes[i].data_len;
        }
    *len = n;
    return buf;
}

/* A CSG job: its tree in the Submit, which must fit a frame; the leaves'
 * files inline when they fit too and are small (inline_max), else after
 * the Accepted as the job's input. */
static int submit_csg(vox_client *c, const vox_job *job, uint64_t *job_id,
                      uint32_t *queue_position, vox_error *err)
{
    size_t n = job->csg.n_nodes;
    if (!n || !job->csg.nodes) {
        set_error(err, -EINVAL, 0, "the CSG job has no nodes");
        return -EINVAL;
    }
    size_t in_len = 0;
    uint8_t *input = csg_leaves_input(&job->csg, &in_len);
    Voxd__CsgNode *nodes = calloc(n, sizeof *nodes);
    Voxd__CsgNode **ptrs = calloc(n, sizeof *ptrs);
    int rc = 0;
    if (!nodes || !ptrs || !input) {
        set_error(err, -ENOMEM, 0, "out of memory");
        rc = -ENOMEM;
    }
    submit_msg m;
    Voxd__Csg cm;
    int chunked = 0;
    if (!rc) {
        submit_request(job, NULL, 0, 0, &m);
        csg_request(job, 0, nodes, ptrs, &m, &cm);
        chunked = in_len && (in_len > c->inline_max ||
                             protobuf_c_message_get_packed_size(&m.req.base) > c->lim.max_frame);
        if (chunked) {
            submit_request(job, NULL, 0, 0, &m);
            csg_request(job, 1, nodes, ptrs, &m, &cm);
            m.sub.input_bytes = in_len;
        }
        if (chunked && in_len > c->lim.max_input_bytes) {
            set_error(err, VOX_ELIMIT_EXCEEDED, 0,
                      "the CSG leaves are %zu bytes, over this server's max_input_bytes of %llu",
                      in_len, (unsigned long long)c->lim.max_input_bytes);
            rc = VOX_ELIMIT_EXCEEDED;
        }
        size_t bytes = protobuf_c_message_get_packed_size(&m.req.base);
        if (!rc && bytes > c->lim.max_frame) {
            set_error(err, VOX_ELIMIT_EXCEEDED, 0,
                      "the CSG tree's request is %zu bytes, over this server's max_frame "
                      "of %u", bytes, c->lim.max_frame);
            rc = VOX_ELIMIT_EXCEEDED;
        }
    }
    if (!rc) rc = request(c, P_SUBMIT, &m.req, err);
    free(nodes);
    free(ptrs);
    uint64_t id = rc ? 0 : c->ans_job;
    uint32_t qpos = rc ? 0 : c->ans_qpos;
    if (!rc && chunked) rc = upload(c, id, input, in_len, err);
    free(input);
    if (rc) return rc;
    *job_id = id;
    if (queue_position) *queue_position = qpos;
    return 0;
}

int vox_submit_job(vox_client *c, const vox_job *job, uint64_t *job_id,
                   uint32_t *queue_position, vox_error *err)
{
    vox_error tmp;
    if (!err) err = &tmp;
    if (job && job->kind == VOX_JOB_CSG) return submit_csg(c, job, job_id, queue_position, err);
    const uint8_t *data;
    size_t len;
    int rc = job_input(job, &data, &len, err);
    if (rc) return rc;
    submit_msg m;
    submit_request(job, data, len, 0, &m);
    /* Inline when small and it fits a frame; else in InputChunks. */
    int chunked = len > c->inline_max ||
                  protobuf_c_message_get_packed_size(&m.req.base) > c->lim.max_frame;
    if ((rc = check_input_size(c, job->kind, len, chunked, err))) return rc;
    if (chunked) submit_request(job, data, len, 1, &m);
    if ((rc = request(c, P_SUBMIT, &m.req, err))) return rc;
    uint64_t id = c->ans_job;
    uint32_t qpos = c->ans_qpos;
    if (chunked && (rc = upload(c, id, data, len, err))) return rc;
    *job_id = id;
    if (queue_position) *queue_position = qpos;
    return 0;
}

int vox_submit(vox_client *c, const vox_implicit_job *job, uint64_t *job_id,
               uint32_t *queue_position, vox_error *err)
{
    if (!job) return vox_submit_job(c, NULL, job_id, queue_position, err);
    vox_job j = {
        .kind = VOX_JOB_IMPLICIT,
        .implicit = {.source = job->source, .source_len = job->source_len,
                     .source_name = job->source_name, .res = job->res,
                     .schedule = job->schedule},
        .channel = job->channel, .brick = job->brick, .comp = job->comp, .hash = job->hash};
    memcpy(j.implicit.domain, job->domain, sizeof j.implicit.domain);
    return vox_submit_job(c, &j, job_id, queue_position, err);
}

int vox_cancel(vox_client *c, uint64_t job_id, vox_error *err)
{
    vox_error tmp;
    if (!err) err = &tmp;
    if (job_id == 0) {
        set_error(err, -EINVAL, 0, "job id 0 names no job");
        return -EINVAL;
    }
    if (c->err) {
        copy_error(err, &c->fail);
        return c->err;
    }
    vjob *j = find_job(c, job_id);
    if (j && j->done) return 0; /* nothing left to cancel */
    if (j) j->cancel_sent = 1;
    /* Should the job end before the cancel reaches the daemon, its answer
     * to the cancel is no news. */
    add_ignored(c, job_id);
    int rc = send_cancel(c, job_id);
    if (rc) {
        copy_error(err, &c->fail);
        return rc;
    }
    /* A ping behind the cancel: whatever the daemon says about the cancel
     * comes before the pong. */
    c->ping_token = c->next_token++;
    c->cancel_job = job_id;
    Voxd__Ping ping = VOXD__PING__INIT;
    ping.token = c->ping_token;
    Voxd__Request req = VOXD__REQUEST__INIT;
    req.msg_case = VOXD__REQUEST__MSG_PING;
    req.ping = &ping;
    rc = request(c, P_CANCEL, &req, err);
    if (rc && err->job_id == 0) err->job_id = job_id;
    return rc;
}

int vox_status(vox_client *c, vox_status_info *out, vox_error *err)
{
    memset(out, 0, sizeof *out);
    Voxd__Status st = VOXD__STATUS__INIT;
    Voxd__Request req = VOXD__REQUEST__INIT;
    req.msg_case = VOXD__REQUEST__MSG_STATUS;
    req.status = &st;
    memset(&c->ans_status, 0, sizeof c->ans_status);
    int rc = request(c, P_STATUS, &req, err);
    if (rc) {
        vox_status_free(&c->ans_status);
        return rc;
    }
    *out = c->ans_status;
    memset(&c->ans_status, 0, sizeof c->ans_status);
    return 0;
}

void vox_status_free(vox_status_info *s)
{
    if (!s) return;
    free(s->workers);
    s->workers = NULL;
    s->n_workers = 0;
    free(s->jobs);
    s->jobs = NULL;
    s->n_jobs = 0;
}

int vox_ping(vox_client *c, double *rtt_seconds, vox_error *err)
{
    c->ping_token = c->next_token++;
    Voxd__Ping ping = VOXD__PING__INIT;
    ping.token = c->ping_token;
    Voxd__Request req = VOXD__REQUEST__INIT;
    req.msg_case = VOXD__REQUEST__MSG_PING;
    req.ping = &ping;
    double t0 = mono();
    int rc = request(c, P_PING, &req, err);
    if (rc == 0 && rtt_seconds) *rtt_seconds = mono() - t0;
    return rc;
}

/* ---------------------------------------------------------------- receiving */

/* Move what the spool holds to the job's new sink. */
static int unspool(vjob *j, int sink, int fd)
{
    int spool = j->fd;
    j->sink = sink;
    j->fd = fd;
    if (spool < 0) return 0;
    int rc = 0;
    if (j->local_err) goto out;
    if (sink == SINK_BUF) {
        size_t n = (size_t)j->received;
        j->buf = malloc(n ? n : 1);
        if (!j->buf) {
            rc = -ENOMEM;
            goto out;
        }
        j->cap = n;
    }
    uint8_t block[65536];
    off_t off = 0;
    while ((uint64_t)off < j->received) {
        size_t want = sizeof block;
        if (j->received - (uint64_t)off < want) want = (size_t)(j->received - (uint64_t)off);
        ssize_t r = pread(spool, block, want, off);
        if (r < 0 && errno == EINTR) continue;
        if (r <= 0) {
            rc = r < 0 ? -errno : -EIO;
            break;
        }
        if (sink == SINK_BUF) memcpy(j->buf + off, block, (size_t)r);
        else if ((rc = write_all(fd, block, (size_t)r))) break;
        off += r;
    }
out:
    close(spool);
    if (rc) {
        j->local_err = rc;
        set_error(&j->result, rc, j->id, "cannot store job %llu's result: %s",
                  (unsigned long long)j->id, strerror(-rc));
    }
    return rc;
}

/* How long a job may take from its acceptance to its first result byte: the
 * daemon's job_timeout for it and each job that was ahead of it, plus a
 * silence timeout each for starting and stopping.  0: no limit (a daemon
 * without job_timeout). */
static double job_deadline(const vox_client *c, const vjob *j)
{
    if (!c->info.job_timeout) return 0;
    double ahead = j->queue_position;
    double cap = c->info.max_queued_jobs ? c->info.max_queued_jobs : 1;
    if (ahead > cap) ahead = cap;
    double t = c->timeout_ms / 1000.0;
    return (ahead + 1) * (c->info.job_timeout + t) + t;
}

/* 0 while the job may still end in time, with *ms how long the next wait
 * may be (-1: no limit); else -ETIMEDOUT with the job's result set. */
static int job_late(vox_client *c, vjob *j, int *ms)
{
    double now = mono(), t = c->timeout_ms / 1000.0, left;
    unsigned long long id = (unsigned long long)j->id;
    if (j->received) {
        /* Streaming: only result bytes count, not pongs. */
        left = j->t_data + t - now;
        if (left <= 0) {
            set_error(&j->result, -ETIMEDOUT, j->id,
                      "job %llu's result stalled: no data for %.1f s", id, t);
            return -ETIMEDOUT;
        }
    } else {
        double d = job_deadline(c, j);
        if (d == 0) {
            *ms = -1;
            return 0;
        }
        left = j->t_accepted + d - now;
        /* Results of this connection's earlier jobs streaming in may
         * hold this one's back. */
        double busy = c->t_any_data + t - now;
        if (busy > left) left = busy;
        if (left <= 0) {
            set_error(&j->result, -ETIMEDOUT, j->id,
                      "job %llu did not finish in %.1f s (the daemon's job_timeout is %u s, "
                      "%u job%s ahead of it)",
                      id, d, c->info.job_timeout, j->queue_position,
                      j->queue_position == 1 ? " was" : "s were");
            return -ETIMEDOUT;
        }
    }
    *ms = left > 86400 ? 86400000 : (int)ceil(left * 1000.0);
    return 0;
}

/* Wait for a job's end, showing its progress; the job's result code.  The
 * job may not have ended (it took too long): the caller drops it. */
static int wait_job(vox_client *c, vjob *j, vox_progress_cb cb, void *ud)
{
    while (!j->done) {
        int intr = 0, ms;
        if (job_late(c, j, &ms)) return j->result.code;
        /* Progress that came before this call is shown first. */
        int rc = j->progress_new ? 0 : step(c, ms, &intr);
        if (rc) {
            if (j->done) break; /* its end came before the failure */
            j->done = 1;
            if (!j->local_err) j->result = c->fail, j->result.job_id = j->id;
            break;
        }
        if (!cb) j->progress_new = 0;
        if (cb && (j->progress_new || intr)) {
            j->progress_new = 0;
            if (cb(ud, j->fraction, j->level, j->voxels) && !j->cancel_sent && !j->done) {
                j->cancel_sent = 1;
                add_ignored(c, j->id);
                send_cancel(c, j->id); /* a failure shows in the next step */
            }
        }
    }
    if (cb && j->progress_new && !j->result.code) {
        j->progress_new = 0;
        cb(ud, j->fraction, j->level, j->voxels);
    }
    return j->result.code;
}

static vjob *receivable(vox_client *c, uint64_t job_id, vox_error *err)
{
    vjob *j = find_job(c, job_id);
    if (!j) set_error(err, -EINVAL, job_id, "job %llu is not a job of this connection",
                      (unsigned long long)job_id);
    return j;
}

int vox_receive_file(vox_client *c, uint64_t job_id, const char *path, vox_progress_cb cb,
                     void *ud, vox_summary *sum, vox_error *err)
{
    vox_error tmp_err;
    if (!err) err = &tmp_err;
    vjob *j = receivable(c, job_id, err);
    if (!j) return -EINVAL;
    outfile f;
    int rc = outfile_open(&f, path);
    if (rc) {
        set_error(err, rc, job_id, "cannot create %s: %s", path, strerror(-rc));
        drop_job(c, j);
        return rc;
    }
    unspool(j, SINK_FD, f.fd);
    rc = wait_job(c, j, cb, ud);
    if (rc) outfile_abort(&f);
    else rc = outfile_commit(&f, path);
    if (rc) {
        /* the file's own failure (a full disk) names the file */
        if (j->result.code && !j->local_err) copy_error(err, &j->result);
        else set_error(err, rc, job_id, "cannot write %s: %s", path, strerror(-rc));
    } else if (sum) {
        *sum = j->sum;
    }
    drop_job(c, j);
    return rc;
}

int vox_receive_buffer(vox_client *c, uint64_t job_id, uint8_t **buf, size_t *len,
                       vox_progress_cb cb, void *ud, vox_summary *sum, vox_error *err)
{
    vox_error tmp_err;
    if (!err) err = &tmp_err;
    *buf = NULL;
    *len = 0;
    vjob *j = receivable(c, job_id, err);
    if (!j) return -EINVAL;
    unspool(j, SINK_BUF, -1);
    int rc = wait_job(c, j, cb, ud);
    if (rc) {
        copy_error(err, &j->result);
    } else {
        *buf = j->buf;
        *len = (size_t)j->received;
        j->buf = NULL;
        if (sum) *sum = j->sum;
    }
    drop_job(c, j);
    return rc;
}
