/* A connection's output: replies framed onto libuv's write queue, and the
 * marks that bound it.  What a finished write means for the connection
 * (read again, stream more, close) is the connection's own business: its
 * `written` callback (daemon_client.c). */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "clock.h"
#include "daemon.h"
#include "log.h"

typedef struct {
    uv_write_t req;
    uint8_t *buf;
    size_t len;
} daemon_write;

size_t daemon_conn_queued(daemon_client *c)
{
    return uv_stream_get_write_queue_size((uv_stream_t *)&c->pipe);
}

/* Chunks are produced while fewer bytes than this wait in user space. */
size_t daemon_conn_pump_mark(const daemon_client *c)
{
    return c->d->cfg.chunk_size;
}

/* Reading stops while more than this waits: a client that sends requests
 * and never reads the replies cannot grow the queue without bound. */
size_t daemon_conn_read_mark(const daemon_client *c)
{
    return 2 * (size_t)c->d->cfg.max_frame + c->d->cfg.chunk_size;
}

/* Progress is dropped for a client whose replies pile up: only the
 * latest matters, and the stall timeout deals with the client. */
int daemon_client_backed_up(daemon_client *c)
{
    return c->closing || c->flush_close || daemon_conn_queued(c) >= daemon_conn_pump_mark(c);
}

static void on_write(uv_write_t *req, int status)
{
    daemon_write *w = (daemon_write *)req;
    daemon_client *c = req->data;
    free(w->buf);
    free(w);
    c->writes--;
    if (c->closing) return;
    if (status == 0) c->t_write = clock_now();
    c->written(c, status);
}

int daemon_client_send(daemon_client *c, const Voxd__Reply *r)
{
    if (c->closing) return -EPIPE;
    daemon_write *w = malloc(sizeof *w);
    int rc = w ? proto_frame_encode_reply(r, &w->buf, &w->len) : -ENOMEM;
    if (rc) {
        free(w);
        log_error("client pid %d: cannot encode a reply: %s", (int)c->pid, strerror(-rc));
        c->written(c, UV_EPIPE);
        return rc;
    }
    if (c->writes == 0) c->t_write = clock_now();
    uv_buf_t b = uv_buf_init((char *)w->buf, (unsigned)w->len);
    w->req.data = c;
    rc = uv_write(&w->req, (uv_stream_t *)&c->pipe, &b, 1, on_write);
    if (rc) {
        free(w->buf);
        free(w);
        c->written(c, rc);
        return -EPIPE;
    }
    c->writes++;
    return 0;
}
