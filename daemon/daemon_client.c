/* Connections: accept (SO_PEERCRED against allow_uids, then max_clients
 * and max_clients_per_uid), read
 * and decode frames (the one boundary check), answer requests, take jobs'
 * inputs in InputChunks, stream results under a bounded write queue, and
 * time out clients that stall. */
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>

#include "clock.h"
#include "daemon.h"
#include "err.h"
#include "log.h"
#include "pipeline.h"
#include "proto_check.h"
#include "vod.h"
#include "voxel.h"

typedef struct {
    uv_write_t req;
    uint8_t *buf;
    size_t len;
} daemon_write;

static void start_reading(daemon_client *c);

static double client_timeout(const daemon_client *c)
{
    return c->d->cfg.client_timeout; /* --client-timeout applied (daemon_load_config) */
}

/* ---------------------------------------------------------------- closing */

static void on_closed(uv_handle_t *h)
{
    daemon_client *c = (daemon_client *)h;
    proto_frame_decoder_free(&c->dec);
    free(c);
}

void daemon_client_unlink_job(daemon_client *c, daemon_job *j)
{
    for (daemon_job **pp = &c->jobs; *pp; pp = &(*pp)->cnext)
        if (*pp == j) {
            *pp = j->cnext;
            break;
        }
    j->cnext = NULL;
    j->client = NULL;
}

static void unlink_delivery(daemon_client *c, daemon_job *j)
{
    daemon_job *prev = NULL;
    for (daemon_job *q = c->deliver; q; prev = q, q = q->next)
        if (q == j) {
            if (prev) prev->next = j->next;
            else c->deliver = j->next;
            if (c->deliver_tail == j) c->deliver_tail = prev;
            j->next = NULL;
            return;
        }
}

/* The client is gone: its uploading and queued jobs are freed now, a
 * running one is cancelled and freed when the engine gives it back. */
static void drop_jobs(daemon_client *c)
{
    daemon_ctx *d = c->d;
    while (c->jobs) {
        daemon_job *j = c->jobs;
        daemon_client_unlink_job(c, j);
        if (j->state == DAEMON_UPLOADING) {
            d->nuploading--;
            log_info("job %llu: dropped, its client left during its upload (%zu of %llu bytes)",
                     (unsigned long long)j->id, j->source_len,
                     (unsigned long long)j->input_total);
            daemon_job_free(j);
        } else if (j->state == DAEMON_DELIVERING) {
            daemon_job_free(j);
        } else if (daemon_job_stop(d, j, VOXD__ERROR_CODE__CANCELLED)) {
            log_info("job %llu: cancelled, its client left", (unsigned long long)j->id);
            daemon_job_free(j);
        } else {
            log_info("job %llu: stopping, its client left", (unsigned long long)j->id);
        }
    }
    c->deliver = c->deliver_tail = NULL;
}

void daemon_client_close(daemon_client *c)
{
    if (c->closing) return;
    daemon_ctx *d = c->d;
    c->closing = 1;
    drop_jobs(c);
    if (c->prev) c->prev->next = c->next;
    else d->clients = c->next;
    if (c->next) c->next->prev = c->prev;
    d->nclients--;
    d->nadmitted -= c->admitted != 0;
    /* A worker closes what it inherits as it starts (worker.c), but one
     * being forked this instant may hold a copy for a moment: shutdown()
     * ends the connection for the peer whoever holds one; close alone
     * would not. */
    uv_os_fd_t fd;
    if (uv_fileno((uv_handle_t *)&c->pipe, &fd) == 0) shutdown(fd, SHUT_RDWR);
    uv_close((uv_handle_t *)&c->pipe, on_closed);
}

void daemon_client_close_after_flush(daemon_client *c)
{
    if (c->closing) return;
    c->flush_close = 1;
    if (c->reading) uv_read_stop((uv_stream_t *)&c->pipe);
    c->reading = 0;
    if (c->writes == 0) daemon_client_close(c);
}

/* A write finished (status 0) or failed (negative): the connection layer's
 * callback (daemon_conn.c). */
static void on_written(daemon_client *c, int status)
{
    if (status < 0) {
        log_debug("client pid %d: write failed: %s", (int)c->pid, uv_strerror(status));
        daemon_client_close(c);
        return;
    }
    if (c->flush_close) {
        if (c->writes == 0) daemon_client_close(c);
        return;
    }
    if (!c->reading && daemon_conn_queued(c) <= daemon_conn_read_mark(c)) start_reading(c);
    daemon_client_pump(c);
}

/* ---------------------------------------------------------------- results */

void daemon_job_fail(daemon_ctx *d, daemon_job *j, int code, const char *msg)
{
    (void)d;
    daemon_client *c = j->client;
    log_info("job %llu: %s: %s", (unsigned long long)j->id, proto_error_code_name(code), msg);
    /* Out of the client's list first: a failed send closes the client,
     * which frees the jobs still listed. */
    if (c) daemon_client_unlink_job(c, j);
    if (c) daemon_client_error(c, j->id, code, "%s", msg);
    daemon_job_free(j);
}

void daemon_job_finished(daemon_ctx *d, daemon_job *j)
{
    daemon_client *c = j->client;
    if (!c) {
        daemon_job_free(j);
        return;
    }
    if (j->cancel_code && j->code == 0) daemon_job_stopped(j);
    if (j->code) {
        daemon_job_fail(d, j, j->code, j->message);
        return;
    }
    void *map = mmap(NULL, j->size, PROT_READ, MAP_SHARED, j->fd, 0);
    if (map == MAP_FAILED) {
        daemon_job_fail(d, j, VOXD__ERROR_CODE__INTERNAL, "cannot read the result back");
        return;
    }
    j->map = map;
    log_info("job %llu: %llu voxels, %llu bytes in %.3f s", (unsigned long long)j->id,
             (unsigned long long)j->voxels, (unsigned long long)j->size,
             j->t_voxelize + j->t_write);
    j->state = DAEMON_DELIVERING;
    j->next = NULL;
    if (c->deliver_tail) c->deliver_tail->next = j;
    else c->deliver = j;
    c->deliver_tail = j;
    daemon_client_pump(c);
}

/* Stream the finished results: one chunk at a time while the write queue
 * is short, then the summary. */
void daemon_client_pump(daemon_client *c)
{
    while (!c->closing && c->deliver && daemon_conn_queued(c) < daemon_conn_pump_mark(c)) {
        daemon_job *j = c->deliver;
        if (j->sent < j->size) {
            uint64_t n = j->size - j->sent;
            if (n > c->d->cfg.chunk_size) n = c->d->cfg.chunk_size;
            if (daemon_send_chunk(c, j, j->map + j->sent, (size_t)n)) return;
            j->sent += n;
            continue;
        }
        if (daemon_send_summary(c, j)) return;
        unlink_delivery(c, j);
        daemon_client_unlink_job(c, j);
        daemon_job_free(j);
    }
}

/* ---------------------------------------------------------------- requests */

static int on_hello(daemon_client *c, const Voxd__Hello *h)
{
    if (c->hello)
        return daemon_client_error(c, 0, VOXD__ERROR_CODE__INVALID_INPUT,
                               "hello was already received on this connection");
    c->hello = 1;
    log_debug("client pid %d uid %u: hello from \"%s\"", (int)c->pid, (unsigned)c->uid,
              h->client ? h->client : "");
    return daemon_send_hello_ok(c);
}

/* Jobs of uid on the loop's lists: results waiting to be streamed and
 * inputs being uploaded hold memory as a running job does, so they count
 * against max_jobs_per_uid. */
static unsigned loop_jobs_of(daemon_ctx *d, uid_t uid)
{
    unsigned n = 0;
    for (daemon_client *o = d->clients; o; o = o->next) {
        if (o->uid != uid) continue;
        for (daemon_job *j = o->deliver; j; j = j->next) n++;
        for (daemon_job *j = o->jobs; j; j = j->cnext) n += j->state == DAEMON_UPLOADING;
    }
    return n;
}

static int on_submit(daemon_client *c, const Voxd__Submit *s)
{
    daemon_ctx *d = c->d;
    if (d->stopping)
        return daemon_client_error(c, 0, VOXD__ERROR_CODE__SHUTTING_DOWN,
                               "the daemon is stopping and takes no new jobs");
    csg_tree *tree = NULL;
    char msg[300];
    int rc = daemon_submit_build(&d->cfg, s, &tree, msg, sizeof msg);
    if (rc)
        return daemon_client_error(c, 0,
                               rc == -E2BIG    ? VOXD__ERROR_CODE__LIMIT_EXCEEDED
                               : rc == -EINVAL ? VOXD__ERROR_CODE__INVALID_INPUT
                                               : VOXD__ERROR_CODE__INTERNAL,
                               "%s", msg);
    daemon_job *j = daemon_submit_job(c, s);
    if (!j) {
        csg_tree_free(tree);
        return daemon_client_error(c, 0, VOXD__ERROR_CODE__INTERNAL, "out of memory");
    }
    j->csg = tree;
    j->id = d->next_job_id + 1;
    char why[300];
    if (daemon_memory_room(d, config_max_memory(&d->cfg), d->mem_shm, why, sizeof why)) {
        daemon_job_free(j);
        return daemon_client_error(c, 0, VOXD__ERROR_CODE__BUSY, "%s", why);
    }
    uint32_t pos;
    int code = daemon_queue_admit(d, j, loop_jobs_of(d, c->uid), &pos);
    if (code == VOXD__ERROR_CODE__BUSY) {
        daemon_job_free(j);
        return daemon_client_error(c, 0, code,
                               "the job queue is full (max_queued_jobs %u); try again later",
                               d->cfg.max_queued_jobs);
    }
    if (code) {
        daemon_job_free(j);
        return daemon_client_error(c, 0, code,
                               "uid %u already has %u jobs queued, running or being "
                               "delivered (max_jobs_per_uid); wait for one to finish",
                               (unsigned)c->uid, d->cfg.max_jobs_per_uid);
    }
    /* Queued: the engine thread may have it already, but nothing about it
     * reaches the client before this Accepted (only the loop writes). */
    d->next_job_id++;
    j->client = c;
    j->cnext = c->jobs;
    c->jobs = j;
    if (j->state == DAEMON_UPLOADING) {
        d->nuploading++;
        log_info("job %llu: accepted from uid %u, res %u, waiting for %llu bytes of %s",
                 (unsigned long long)j->id, (unsigned)c->uid, j->res,
                 (unsigned long long)j->input_total, daemon_submit_input_name(j));
    } else {
        log_info("job %llu: accepted from uid %u, res %u, %zu bytes of %s",
                 (unsigned long long)j->id, (unsigned)c->uid, j->res, j->source_len,
                 daemon_submit_input_name(j));
    }
    return daemon_send_accepted(c, j->id, pos);
}

/* ---------------------------------------------------------------- inputs */

/* An upload that went wrong: the job's terminal error, its buffer freed. */
__attribute__((format(printf, 4, 5)))
static int upload_fail(daemon_client *c, daemon_job *j, int code, const char *fmt, ...)
{
    char msg[512];
    va_list ap;
    va_start(ap, fmt);
    err_vfmt(msg, sizeof msg, 0, fmt, ap);
    va_end(ap);
    c->d->nuploading--;
    daemon_job_fail(c->d, j, code, msg);
    return 0;
}

/* A failed send closes c and frees its jobs: the loops over c->jobs below
 * stop then. */
void daemon_client_fail_uploads(daemon_client *c, int code, const char *msg)
{
    for (daemon_job *j = c->jobs, *next; j && !c->closing; j = next) {
        next = j->cnext;
        if (j->state == DAEMON_UPLOADING) upload_fail(c, j, code, "%s", msg);
    }
}

/* Append to the job's input, growing the buffer by doubling up to the
 * declared size (and its NUL). */
static int input_append(daemon_job *j, const uint8_t *p, size_t n)
{
    size_t need = j->source_len + n + 1;
    if (need > j->input_cap) {
        size_t cap = j->input_cap * 2;
        if (cap < need) cap = need;
        if (cap > j->input_total + 1) cap = (size_t)j->input_total + 1;
        char *b = realloc(j->source, cap);
        if (!b) return -ENOMEM;
        j->source = b;
        j->input_cap = cap;
    }
    memcpy(j->source + j->source_len, p, n);
    j->source_len += n;
    j->source[j->source_len] = '\0';
    return 0;
}

static daemon_job *upload_of(daemon_client *c, uint64_t id)
{
    for (daemon_job *j = c->jobs; j; j = j->cnext)
        if (j->id == id && j->state == DAEMON_UPLOADING) return j;
    return NULL;
}

/* A piece of a job's input: in order, within the declared size, bytes its
 * kind may hold (an expression no NUL; a mesh file any byte).  The last
 * one queues the job (admitted at its Submit, where it was counted as
 * queued). */
static int on_input(daemon_client *c, const Voxd__InputChunk *m)
{
    unsigned long long id = (unsigned long long)m->job_id;
    daemon_job *j = upload_of(c, m->job_id);
    if (!j)
        return daemon_client_error(c, 0, VOXD__ERROR_CODE__INVALID_INPUT,
                               "no job %llu of this connection is waiting for input", id);
    const uint8_t *data = m->data.data;
    size_t n = m->data.len;
    if (m->offset != j->source_len)
        return upload_fail(c, j, VOXD__ERROR_CODE__INVALID_INPUT,
                           "input chunk at offset %llu where %zu was due (chunks come in order)",
                           (unsigned long long)m->offset, j->source_len);
    if (n > j->input_total - j->source_len)
        return upload_fail(c, j, VOXD__ERROR_CODE__INVALID_INPUT,
                           "input chunk of %zu bytes at offset %llu passes the %llu bytes the "
                           "job declared (input_bytes)",
                           n, (unsigned long long)m->offset,
                           (unsigned long long)j->input_total);
    const uint8_t *nul = daemon_submit_is_text(j) ? memchr(data, 0, n) : NULL;
    if (nul)
        return upload_fail(c, j, VOXD__ERROR_CODE__INVALID_INPUT,
                           "expression source contains a NUL byte at offset %llu",
                           (unsigned long long)(m->offset + (uint64_t)(nul - data)));
    if (input_append(j, data, n))
        return upload_fail(c, j, VOXD__ERROR_CODE__INTERNAL, "out of memory for the job's input");
    j->t_input = clock_now();
    if (j->source_len < j->input_total) return 0;
    c->d->nuploading--;
    j->t_submit = clock_now(); /* Summary.seconds_queued: from here */
    log_info("job %llu: input complete (%zu bytes); queued", id, j->source_len);
    daemon_queue_push(c->d, j);
    return 0;
}

/* A job of this connection, or of another connection of the same uid
 * (`vox cancel ID` runs in a process of its own); root may cancel any. */
static daemon_job *find_job(daemon_client *c, uint64_t id)
{
    for (daemon_client *o = c->d->clients; o; o = o->next) {
        if (o != c && c->uid != 0 && o->uid != c->uid) continue;
        for (daemon_job *j = o->jobs; j; j = j->cnext)
            if (j->id == id) return j;
    }
    return NULL;
}

/* The job's terminal Error CANCELLED goes to the connection that submitted
 * it: now for a queued or delivering job, when the engine has stopped for
 * a running one. */
static int on_cancel(daemon_client *c, uint64_t id)
{
    daemon_job *j = find_job(c, id);
    if (!j)
        return daemon_client_error(c, 0, VOXD__ERROR_CODE__INVALID_INPUT,
                               "no job %llu of this uid is uploading, queued, running or being delivered",
                               (unsigned long long)id);
    log_info("job %llu: cancel asked by client pid %d", (unsigned long long)id, (int)c->pid);
    if (j->state == DAEMON_UPLOADING) {
        upload_fail(j->client, j, VOXD__ERROR_CODE__CANCELLED, "cancelled by a client");
    } else if (j->state == DAEMON_DELIVERING) {
        unlink_delivery(j->client, j);
        daemon_job_fail(c->d, j, VOXD__ERROR_CODE__CANCELLED, "cancelled by a client");
    } else if (daemon_job_stop(c->d, j, VOXD__ERROR_CODE__CANCELLED)) {
        daemon_job_fail(c->d, j, VOXD__ERROR_CODE__CANCELLED, "cancelled by a client");
    }
    return 0;
}

static void dispatch(daemon_client *c, const Voxd__Request *r)
{
    if (!c->hello && r->msg_case != VOXD__REQUEST__MSG_HELLO) {
        daemon_client_error(c, 0, VOXD__ERROR_CODE__INVALID_INPUT,
                        "the first message must be hello (protocol version %u)",
                        PROTO_VERSION);
        daemon_client_close_after_flush(c);
        return;
    }
    switch (r->msg_case) {
    case VOXD__REQUEST__MSG_HELLO: on_hello(c, r->hello); break;
    case VOXD__REQUEST__MSG_SUBMIT: on_submit(c, r->submit); break;
    case VOXD__REQUEST__MSG_CANCEL: on_cancel(c, r->cancel->job_id); break;
    case VOXD__REQUEST__MSG_STATUS: daemon_send_status(c); break;
    case VOXD__REQUEST__MSG_PING: daemon_send_pong(c, r->ping->token); break;
    case VOXD__REQUEST__MSG_INPUT: on_input(c, r->input); break;
    default: break; /* proto_check_request refused it */
    }
}

static void on_frame(daemon_client *c, const uint8_t *data, size_t len)
{
    Voxd__Request *r = proto_frame_unpack_request(data, len);
    if (!r && errno == ENOMEM) { /* the server's failure, not the client's */
        log_msg(LOG_LEVEL_ERROR, "client pid %d: out of memory unpacking a request of %zu "
                "bytes; closing", (int)c->pid, len);
        daemon_client_error(c, 0, VOXD__ERROR_CODE__INTERNAL,
                            "the server ran out of memory reading a request of %zu bytes", len);
        daemon_client_close_after_flush(c);
        return;
    }
    if (!r) {
        log_limited(&c->d->loglim[DAEMON_LOG_BAD_FRAME], LOG_LEVEL_INFO,
                    "client pid %d: garbage frame of %zu bytes; closing", (int)c->pid, len);
        daemon_client_error(c, 0, VOXD__ERROR_CODE__INVALID_INPUT,
                        "malformed request: not a voxd protocol message");
        daemon_client_close_after_flush(c);
        return;
    }
    proto_limits lim;
    proto_error pe;
    config_proto_limits(&c->d->cfg, &lim);
    if (proto_check_request(r, &lim, &pe) == 0) {
        dispatch(c, r);
    } else {
        log_limited(&c->d->loglim[DAEMON_LOG_BAD_REQUEST], LOG_LEVEL_DEBUG,
                    "client pid %d: refused request: %s", (int)c->pid, pe.msg);
        daemon_client_error(c, 0, pe.code, "%s", pe.msg);
        /* A bad hello ends the conversation; a bad job only the job. */
        if (!c->hello) daemon_client_close_after_flush(c);
    }
    voxd__request__free_unpacked(r, NULL);
}

/* ---------------------------------------------------------------- reading */

static void on_alloc(uv_handle_t *h, size_t hint, uv_buf_t *buf)
{
    (void)hint;
    daemon_client *c = (daemon_client *)h;
    /* One buffer for every client: a read is consumed before the next. */
    *buf = uv_buf_init((char *)c->d->readbuf, sizeof c->d->readbuf);
}

static void on_bytes(daemon_client *c, const uint8_t *p, size_t n)
{
    proto_frame_view f;
    int rc = 0;
    while (!c->closing && !c->flush_close && (rc = proto_frame_decode(&c->dec, &p, &n, &f)) == 1)
        on_frame(c, f.data, f.len);
    if (rc < 0 && !c->closing) {
        char why[128];
        proto_frame_decoder_strerror(&c->dec, rc, why, sizeof why);
        log_limited(&c->d->loglim[DAEMON_LOG_BAD_FRAME], LOG_LEVEL_INFO,
                    "client pid %d: %s; closing", (int)c->pid, why);
        daemon_client_error(c, 0, VOXD__ERROR_CODE__INVALID_INPUT,
                        "%s (max_frame %u); closing the connection", why, c->d->cfg.max_frame);
        daemon_client_close_after_flush(c);
        return;
    }
    if (proto_frame_decoder_pending(&c->dec) == 0) c->t_frame = 0;
    else if (c->t_frame == 0) c->t_frame = clock_now();
}

static void on_read(uv_stream_t *s, ssize_t nread, const uv_buf_t *buf)
{
    daemon_client *c = (daemon_client *)s;
    if (c->closing) return;
    if (nread > 0) {
        on_bytes(c, (const uint8_t *)buf->base, (size_t)nread);
        if (!c->closing && c->reading && daemon_conn_queued(c) > daemon_conn_read_mark(c)) {
            uv_read_stop(s); /* on_write starts it again */
            c->reading = 0;
        }
        return;
    }
    if (nread == 0) return;
    if (proto_frame_decoder_finish(&c->dec) == -EPIPE)
        log_limited(&c->d->loglim[DAEMON_LOG_CUT], LOG_LEVEL_INFO,
                    "client pid %d: connection ended inside a frame", (int)c->pid);
    else if (nread != UV_EOF)
        log_debug("client pid %d: read failed: %s", (int)c->pid, uv_strerror((int)nread));
    daemon_client_close(c);
}

static void start_reading(daemon_client *c)
{
    if (uv_read_start((uv_stream_t *)&c->pipe, on_alloc, on_read) == 0) c->reading = 1;
}

/* ---------------------------------------------------------------- accepting */

static int peer_uid(daemon_client *c)
{
    struct ucred cred;
    socklen_t len = sizeof cred;
    uv_os_fd_t fd;
    if (uv_fileno((uv_handle_t *)&c->pipe, &fd) ||
        getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cred, &len) != 0)
        return -errno;
    c->uid = cred.uid;
    c->pid = cred.pid;
    return 0;
}

/* Refuse with a typed error, then close once it is written. */
__attribute__((format(printf, 3, 4)))
static void refuse(daemon_client *c, int code, const char *fmt, ...)
{
    char why[256];
    va_list ap;
    va_start(ap, fmt);
    err_vfmt(why, sizeof why, 0, fmt, ap);
    va_end(ap);
    daemon_client_error(c, 0, code, "%s", why);
    daemon_client_close_after_flush(c);
}

/* Admitted connections of uid. */
static unsigned clients_of(const daemon_ctx *d, uid_t uid)
{
    unsigned n = 0;
    for (const daemon_client *o = d->clients; o; o = o->next) n += o->admitted && o->uid == uid;
    return n;
}

/* Who may connect, and how many: allow_uids, then room at all, then the
 * uid's share.  A refused connection is not counted against either
 * limit while its error is written, so a flood of refused connections
 * takes no slot from anyone.  Each refusal kind is logged through its
 * own rate limit.  1 when admitted. */
static int admit(daemon_ctx *d, daemon_client *c)
{
    unsigned mine, share = config_clients_per_uid(&d->cfg);
    if (!config_uid_allowed(&d->cfg, c->uid)) {
        log_limited(&d->loglim[DAEMON_LOG_NOT_ALLOWED], LOG_LEVEL_WARN,
                    "refused a connection from uid %u (pid %d): not in allow_uids",
                    (unsigned)c->uid, (int)c->pid);
        refuse(c, VOXD__ERROR_CODE__LIMIT_EXCEEDED,
               "this uid may not use this server (allow_uids in its config)");
        return 0;
    }
    if (d->nadmitted >= d->cfg.max_clients) {
        log_limited(&d->loglim[DAEMON_LOG_FULL], LOG_LEVEL_WARN,
                    "refused a connection from uid %u: %u clients (max_clients)",
                    (unsigned)c->uid, d->nadmitted);
        refuse(c, VOXD__ERROR_CODE__BUSY, "too many connections (max_clients); try again later");
        return 0;
    }
    if ((mine = clients_of(d, c->uid)) >= share) {
        log_limited(&d->loglim[DAEMON_LOG_PER_UID], LOG_LEVEL_WARN,
                    "refused a connection from uid %u (pid %d): it has %u connections "
                    "(max_clients_per_uid)",
                    (unsigned)c->uid, (int)c->pid, mine);
        refuse(c, VOXD__ERROR_CODE__LIMIT_EXCEEDED,
               "uid %u already has %u connections to this server (max_clients_per_uid %u); "
               "close one first",
               (unsigned)c->uid, mine, share);
        return 0;
    }
    c->admitted = 1;
    d->nadmitted++;
    return 1;
}

static void reject_pending(daemon_ctx *d);

static void on_reject_closed(uv_handle_t *h)
{
    daemon_ctx *d = h->data;
    d->reject_busy = 0;
    if (d->reject_waiting) { /* one came while this one closed */
        d->reject_waiting = 0;
        reject_pending(d);
    }
}

/* The pending connection (if any) accepted into the spare pipe and closed:
 * with no memory for a client, the connection is refused this way, for
 * libuv stops reading the listener until its pending one is accepted (a
 * daemon out of memory once would otherwise accept nobody ever after). */
static void reject_pending(daemon_ctx *d)
{
    if (!d->listening) return;
    if (d->reject_busy) {
        d->reject_waiting = 1;
        return;
    }
    if (uv_pipe_init(d->loop, &d->reject, 0)) return;
    d->reject.data = d;
    d->reject_busy = 1;
    if (uv_accept((uv_stream_t *)&d->listener, (uv_stream_t *)&d->reject) == 0)
        log_limited(&d->loglim[DAEMON_LOG_ACCEPT], LOG_LEVEL_WARN,
                    "out of memory for a new client; its connection closed");
    uv_close((uv_handle_t *)&d->reject, on_reject_closed);
}

void daemon_on_connection(uv_stream_t *server, int status)
{
    daemon_ctx *d = server->data;
    if (status < 0) {
        log_limited(&d->loglim[DAEMON_LOG_ACCEPT], LOG_LEVEL_WARN, "accept: %s",
                    uv_strerror(status));
        return;
    }
    daemon_client *c = calloc(1, sizeof *c);
    if (!c) {
        reject_pending(d);
        return;
    }
    c->d = d;
    c->written = on_written;
    if (uv_pipe_init(d->loop, &c->pipe, 0) || uv_accept(server, (uv_stream_t *)&c->pipe)) {
        uv_close((uv_handle_t *)&c->pipe, (uv_close_cb)free);
        return;
    }
    proto_frame_decoder_init(&c->dec, d->cfg.max_frame);
    c->t_connect = clock_now();
    c->next = d->clients;
    if (d->clients) d->clients->prev = c;
    d->clients = c;
    d->nclients++;
    if (peer_uid(c)) {
        daemon_client_close(c);
    } else if (admit(d, c)) {
        log_debug("client pid %d uid %u connected", (int)c->pid, (unsigned)c->uid);
        start_reading(c);
    }
}

/* ---------------------------------------------------------------- timeouts */

/* An upload that stopped holds its buffer: it ends as a stalled frame
 * would, after the client timeout. */
static void tick_uploads(daemon_client *c, double now, double t)
{
    for (daemon_job *j = c->jobs, *next; j && !c->closing; j = next) {
        next = j->cnext;
        if (j->state == DAEMON_UPLOADING && now - j->t_input > t)
            upload_fail(c, j, VOXD__ERROR_CODE__TIMEOUT,
                        "the job's input stopped: no chunk for %.0f s (client_timeout); "
                        "%zu of %llu bytes came",
                        t, j->source_len, (unsigned long long)j->input_total);
    }
}

void daemon_client_tick(daemon_client *c, double now)
{
    double t = client_timeout(c);
    if (c->closing) return;
    tick_uploads(c, now, t);
    if (c->closing) return;
    if (c->writes && now - c->t_write > t) {
        log_limited(&c->d->loglim[DAEMON_LOG_STALLED], LOG_LEVEL_INFO,
                    "client pid %d: has not read its replies for %.0f s; dropping it",
                    (int)c->pid, t);
        daemon_client_close(c);
        return;
    }
    if (c->flush_close) return;
    const char *what = !c->hello && now - c->t_connect > t ? "no hello"
                       : c->t_frame && now - c->t_frame > t ? "a frame did not complete"
                                                             : NULL;
    if (!what) return;
    log_limited(&c->d->loglim[DAEMON_LOG_STALLED], LOG_LEVEL_INFO,
                "client pid %d: %s within %.0f s; closing", (int)c->pid, what, t);
    daemon_client_error(c, 0, VOXD__ERROR_CODE__INVALID_INPUT,
                    "%s within %.0f s; closing the connection", what, t);
    daemon_client_close_after_flush(c);
}

/* ---------------------------------------------------------------- engine news */

static void flush_elog(daemon_ctx *d)
{
    for (unsigned i = 0; i < d->elog_n; i++)
        log_msg(d->elog[i].level, "%s", d->elog[i].text);
    if (d->elog_dropped)
        log_warn("%u engine log line%s dropped", d->elog_dropped,
                 d->elog_dropped == 1 ? "" : "s");
    d->elog_n = 0;
    d->elog_dropped = 0;
}

/* The engine thread said something: log lines, progress, finished jobs. */
void daemon_on_wake(uv_async_t *a)
{
    daemon_ctx *d = a->data;
    pthread_mutex_lock(&d->mu);
    flush_elog(d);
    daemon_job *done = d->done;
    d->done = d->done_tail = NULL;
    daemon_job *r = d->running;
    engine_progress p;
    int send = r && r->client && r->progress_seq != r->progress_sent;
    if (send) {
        p = r->progress;
        r->progress_sent = r->progress_seq;
    }
    pthread_mutex_unlock(&d->mu);
    if (send && !daemon_client_backed_up(r->client)) daemon_send_progress(r->client, r, &p);
    while (done) {
        daemon_job *j = done;
        done = j->next;
        j->next = NULL;
        daemon_job_finished(d, j);
    }
}
