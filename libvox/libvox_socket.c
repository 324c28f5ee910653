/* The socket: sending frames, reading and dispatching what comes, the
 * silence timeout and its keep-alive pings, a request and its answer. */
#include "vox.h"

#include <errno.h>
#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>

#include "libvox_int.h"

/* The daemon closed the connection: say why if it said so first. */
static int fail_closed(vox_client *c, const char *how)
{
    if (c->note_code) {
        int code = -(VOX_ESERVER_BASE + c->note_code);
        return libvox_fail(c, code, "%s", c->note);
    }
    return libvox_fail(c, -ECONNRESET, "voxd closed the connection%s", how);
}

/* Read what is there and dispatch every complete frame.  0, or the
 * connection's failure. */
static int read_some(vox_client *c)
{
    ssize_t n = read(c->fd, c->rbuf, READ_BUF);
    if (n < 0) {
        if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) return 0;
        if (errno == ECONNRESET) return fail_closed(c, "");
        return libvox_fail(c, -errno, "reading from voxd: %s", strerror(errno));
    }
    if (n == 0) {
        int rc = proto_frame_decoder_finish(&c->dec);
        return fail_closed(c, rc ? " in the middle of a reply" : "");
    }
    c->last_rx = libvox_mono();
    const uint8_t *p = c->rbuf;
    size_t left = (size_t)n;
    proto_frame_view f;
    int rc;
    while ((rc = proto_frame_decode(&c->dec, &p, &left, &f)) == 1)
        if ((rc = libvox_dispatch(c, f.data, f.len))) return rc;
    if (rc < 0) {
        char why[160];
        return libvox_fail(c, -EPROTO, "voxd sent a bad frame: %s",
                    proto_frame_decoder_strerror(&c->dec, rc, why, sizeof why));
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
    double moved = libvox_mono();
    while (off < len) {
        ssize_t n = send(c->fd, buf + off, len - off, MSG_NOSIGNAL);
        if (n > 0) {
            off += (size_t)n;
            moved = libvox_mono();
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
            return libvox_fail(c, -e, "writing to voxd: %s", strerror(e));
        }
        struct pollfd p = {c->fd, POLLOUT | POLLIN, 0};
        int ms = timeout_left_ms(c, moved, libvox_mono());
        if (ms == 0)
            return libvox_fail(c, -ETIMEDOUT, "voxd took nothing from the socket for %.1f s",
                        c->timeout_ms / 1000.0);
        int r = poll(&p, 1, ms);
        if (r < 0 && errno != EINTR) return libvox_fail(c, -errno, "poll: %s", strerror(errno));
        if (r > 0 && (p.revents & (POLLIN | POLLHUP | POLLERR))) {
            int rc = read_some(c);
            if (rc) return rc;
        }
    }
    return 0;
}

int libvox_send_request(vox_client *c, const Voxd__Request *req)
{
    uint8_t *buf;
    size_t len;
    int rc = proto_frame_encode_request(req, &buf, &len);
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
    return libvox_send_request(c, &req);
}

int libvox_send_cancel(vox_client *c, uint64_t job_id)
{
    Voxd__Cancel cancel = VOXD__CANCEL__INIT;
    cancel.job_id = job_id;
    Voxd__Request req = VOXD__REQUEST__INIT;
    req.msg_case = VOXD__REQUEST__MSG_CANCEL;
    req.cancel = &cancel;
    return libvox_send_request(c, &req);
}

/* Nobody will receive the job: cancel it, drop what comes of it until its
 * end, then free it (its replies must still check, and a cancel's late
 * answer is no news).  j may be freed on return. */
void libvox_drop_job(vox_client *c, vjob *j)
{
    if (j->done) {
        libvox_forget_job(c, j);
        return;
    }
    if (j->sink == SINK_SPOOL && j->fd >= 0) close(j->fd);
    free(j->buf);
    j->buf = NULL;
    j->fd = -1;
    j->sink = SINK_NONE;
    j->discard = 1;
    libvox_add_ignored(c, j->id);
    if (!j->cancel_sent) {
        j->cancel_sent = 1;
        libvox_send_cancel(c, j->id); /* may end and free j; a failure is the connection's */
    }
}

/* Wait for input once (or for the timeout, or a signal) and dispatch it.
 * After half the timeout of silence a ping goes out: a daemon that is busy
 * with other jobs answers it, a hung one does not.  *interrupted is set when
 * a signal cut the wait short.  0, or the connection's failure. */
int libvox_step(vox_client *c, int max_ms, int *interrupted)
{
    if (c->err) return c->err;
    double now = libvox_mono(), half = c->timeout_ms / 2000.0;
    double idle = now - c->last_rx;
    if (idle >= c->timeout_ms / 1000.0)
        return libvox_fail(c, -ETIMEDOUT, "voxd said nothing for %.1f s", c->timeout_ms / 1000.0);
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
        return libvox_fail(c, -errno, "poll: %s", strerror(errno));
    }
    if (r == 0) return 0;
    return read_some(c);
}

/* Send a request and wait for its answer. */
int libvox_request(vox_client *c, int kind, const Voxd__Request *req, vox_error *err)
{
    if (c->err) {
        libvox_copy_error(err, &c->fail);
        return c->err;
    }
    c->pending = kind;
    c->answered = 0;
    memset(&c->ans, 0, sizeof c->ans);
    int rc = libvox_send_request(c, req);
    if (rc && !c->err) {
        libvox_set_error(&c->ans, rc, 0, "cannot send the request: %s", vox_strerror(rc));
        c->pending = P_NONE;
        libvox_copy_error(err, &c->ans);
        return rc;
    }
    while (!rc && !c->answered) rc = libvox_step(c, -1, NULL);
    c->pending = P_NONE;
    if (!c->answered) {
        libvox_copy_error(err, &c->fail);
        return c->err;
    }
    if (c->ans.code) libvox_copy_error(err, &c->ans);
    return c->ans.code;
}

/* A ping as the request a call waits for: P_PING, or P_CANCEL and P_DRAIN,
 * where what the daemon says about a cancel or an upload comes before the
 * pong. */
int libvox_ping(vox_client *c, int kind, vox_error *err)
{
    c->ping_token = c->next_token++;
    Voxd__Ping ping = VOXD__PING__INIT;
    ping.token = c->ping_token;
    Voxd__Request req = VOXD__REQUEST__INIT;
    req.msg_case = VOXD__REQUEST__MSG_PING;
    req.ping = &ping;
    return libvox_request(c, kind, &req, err);
}
