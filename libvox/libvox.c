/* libvox — the voxd client library.  See vox.h.
 *
 * One non-blocking Unix stream socket, poll() with the client's silence
 * timeout, and the framing of proto/frame.h.  Every reply is unpacked with a
 * bounded budget and validated by proto_check_reply() before anything here
 * looks at it; what depends on the conversation (a reply nobody asked for, a
 * chunk at the wrong offset or for a job this client does not have) is
 * checked in libvox_dispatch() and ends the connection as -EPROTO.
 *
 * libvox_dispatch() only updates state: the answer to the one request a blocked
 * call waits for, and each job's result (chunks go to the job's sink: the
 * output file or buffer of the job being received, else a spool file), its
 * CRC, its latest progress and its terminal.  Callbacks run in the receiving
 * loop, never inside libvox_dispatch(), so a callback cannot re-enter it.
 *
 * This file: connecting, closing, and the small requests (cancel, status,
 * ping); libvox_int.h says which file holds the rest.
 */
#include "vox.h"

#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include "libvox_int.h"

int vox_connect_fd(int fd, const vox_options *opts, vox_client **out, vox_error *err)
{
    vox_error tmp;
    if (!err) err = &tmp;
    *out = NULL;
    int fl = fcntl(fd, F_GETFL);
    if (fl < 0 || fcntl(fd, F_SETFL, fl | O_NONBLOCK) < 0) {
        int rc = -errno;
        close(fd);
        libvox_set_error(err, rc, 0, "%s", strerror(-rc));
        return rc;
    }
    vox_client *c = calloc(1, sizeof *c);
    uint8_t *rbuf = malloc(READ_BUF);
    if (!c || !rbuf) {
        free(c);
        free(rbuf);
        close(fd);
        libvox_set_error(err, -ENOMEM, 0, "out of memory");
        return -ENOMEM;
    }
    c->fd = fd;
    c->rbuf = rbuf;
    c->timeout_ms = opts && opts->timeout_ms > 0 ? opts->timeout_ms : VOX_DEFAULT_TIMEOUT_MS;
    c->inline_max = opts && opts->inline_max ? opts->inline_max : VOX_DEFAULT_INLINE_MAX;
    c->next_token = 1;
    proto_limits_default(&c->lim);
    proto_frame_decoder_init(&c->dec, PROTO_FRAME_DEFAULT_MAX);
    c->last_rx = libvox_mono();

    Voxd__Hello hello = VOXD__HELLO__INIT;
    hello.version = PROTO_VERSION;
    hello.client = (char *)(opts && opts->client_name ? opts->client_name : "libvox");
    Voxd__Request req = VOXD__REQUEST__INIT;
    req.msg_case = VOXD__REQUEST__MSG_HELLO;
    req.hello = &hello;
    int rc = libvox_request(c, P_HELLO, &req, err);
    if (rc) {
        if (VOX_IS_SERVER_ERROR(rc)) {
            char msg[sizeof err->message];
            snprintf(msg, sizeof msg, "%s", err->message);
            libvox_set_error(err, rc, 0, "voxd refused this client: %s", msg);
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
        libvox_set_error(err, -ENAMETOOLONG, 0, "socket path %s is too long (at most %zu bytes)",
                  socket_path ? socket_path : "(null)", sizeof sa.sun_path - 1);
        return -ENAMETOOLONG;
    }
    strcpy(sa.sun_path, socket_path);
    int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
    if (fd < 0) {
        int rc = -errno;
        libvox_set_error(err, rc, 0, "socket: %s", strerror(-rc));
        return rc;
    }
    if (connect(fd, (struct sockaddr *)&sa, sizeof sa) != 0) {
        int rc = -errno;
        close(fd);
        libvox_set_error(err, rc, 0, "no voxd answering on %s (%s)", socket_path,
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
        libvox_free_job(j);
    }
    close(c->fd);
    proto_frame_decoder_free(&c->dec);
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

int vox_cancel(vox_client *c, uint64_t job_id, vox_error *err)
{
    vox_error tmp;
    if (!err) err = &tmp;
    if (job_id == 0) {
        libvox_set_error(err, -EINVAL, 0, "job id 0 names no job");
        return -EINVAL;
    }
    if (c->err) {
        libvox_copy_error(err, &c->fail);
        return c->err;
    }
    vjob *j = libvox_find_job(c, job_id);
    if (j && j->done) return 0; /* nothing left to cancel */
    if (j) j->cancel_sent = 1;
    /* Should the job end before the cancel reaches the daemon, its answer
     * to the cancel is no news. */
    libvox_add_ignored(c, job_id);
    int rc = libvox_send_cancel(c, job_id);
    if (rc) {
        libvox_copy_error(err, &c->fail);
        return rc;
    }
    /* A ping behind the cancel: whatever the daemon says about the cancel
     * comes before the pong. */
    c->cancel_job = job_id;
    rc = libvox_ping(c, P_CANCEL, err);
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
    int rc = libvox_request(c, P_STATUS, &req, err);
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
    double t0 = libvox_mono();
    int rc = libvox_ping(c, P_PING, err);
    if (rc == 0 && rtt_seconds) *rtt_seconds = libvox_mono() - t0;
    return rc;
}
