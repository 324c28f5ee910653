/* libvox_fixture — the fake daemon of the libvox suites (test_libvox*.c): a
 * thread on the other end of a socketpair (or of a temporary Unix socket) that
 * speaks frames from a script, the replies it sends, a temporary output folder,
 * and the jobs the tests submit. */
#ifndef VOXD_TEST_LIBVOX_FIXTURE_H
#define VOXD_TEST_LIBVOX_FIXTURE_H

#include <criterion/criterion.h>
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include <zlib.h>

#include "frame.h"
#include "proto_check.h"
#include "grid.h"
#include "vox.h"

/* ---------------------------------------------------------------- fake daemon */

typedef struct srv srv;

typedef void (*srv_fn)(srv *s);

struct srv {
    int fd;
    int pong;              /* answer pings (keepalives) by itself */
    int hello_max_frame;   /* 0: default */
    int hello_chunk;       /* 0: default */
    uint64_t max_result;   /* 0: default */
    uint32_t hello_max_expr;  /* 0: default */
    uint64_t hello_max_input; /* 0: default */
    uint64_t hello_max_mesh;  /* 0: default */
    int job_timeout;       /* 0: 600; -1: none */
    proto_frame_decoder dec;
    uint8_t in[65536];
    const uint8_t *p;
    size_t n;
    uint8_t *frame;        /* the last frame read (copied) */
    char bad[256];         /* what went wrong on this side */
    srv_fn fn;
    void *arg;
    pthread_t th;
    int listen_fd;         /* accept first when >= 0 */
    int pings_seen;
    int raw;               /* srv_read returns pings too */
};

static inline double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static inline void srv_bad(srv *s, const char *what)
{
    if (!s->bad[0]) snprintf(s->bad, sizeof s->bad, "%s", what);
}

static inline void srv_write(srv *s, const void *buf, size_t len)
{
    const uint8_t *p = buf;
    while (len) {
        ssize_t w = send(s->fd, p, len, MSG_NOSIGNAL);
        if (w < 0) {
            if (errno == EINTR) continue;
            return; /* the client went away: its test says what it saw */
        }
        p += w;
        len -= (size_t)w;
    }
}

static inline void srv_send(srv *s, Voxd__Reply *r)
{
    uint8_t *buf;
    size_t len;
    if (proto_frame_encode_reply(r, &buf, &len)) {
        srv_bad(s, "cannot encode a reply");
        return;
    }
    srv_write(s, buf, len);
    free(buf);
}

static inline void send_pong(srv *s, uint64_t token)
{
    Voxd__Pong m = VOXD__PONG__INIT;
    m.token = token;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_PONG, r.pong = &m;
    srv_send(s, &r);
}

/* The next request (pings answered or swallowed per s->pong), NULL at EOF
 * or after 5 s of nothing. */
static inline Voxd__Request *srv_read(srv *s)
{
    for (;;) {
        proto_frame_view f;
        int rc = proto_frame_decode(&s->dec, &s->p, &s->n, &f);
        if (rc == 1) {
            Voxd__Request *r = proto_frame_unpack_request(f.data, f.len);
            if (!r) {
                srv_bad(s, "a request that does not unpack");
                return NULL;
            }
            proto_limits lim;
            proto_limits_default(&lim);
            lim.max_res = 1u << 20;
            if (s->hello_max_expr) lim.max_expr_bytes = s->hello_max_expr;
            if (proto_check_request(r, &lim, NULL)) srv_bad(s, "a request that does not check");
            if (r->msg_case == VOXD__REQUEST__MSG_PING && !s->raw) {
                s->pings_seen++;
                if (s->pong) send_pong(s, r->ping->token);
                voxd__request__free_unpacked(r, NULL);
                continue;
            }
            return r;
        }
        if (rc < 0) {
            srv_bad(s, "a bad frame");
            return NULL;
        }
        struct pollfd p = {s->fd, POLLIN, 0};
        if (poll(&p, 1, 5000) <= 0) return NULL;
        ssize_t n = read(s->fd, s->in, sizeof s->in);
        if (n <= 0) return NULL;
        s->p = s->in;
        s->n = (size_t)n;
    }
}

/* The next request, pings included. */
static inline Voxd__Request *srv_read_any(srv *s)
{
    int pong = s->pong;
    s->pong = 0;
    s->raw = 1;
    Voxd__Request *r = srv_read(s);
    s->raw = 0;
    s->pong = pong;
    return r;
}

/* The next request, which must be of this kind. */
static inline Voxd__Request *srv_expect(srv *s, Voxd__Request__MsgCase kind)
{
    Voxd__Request *r = srv_read(s);
    if (!r) {
        srv_bad(s, "no request where one was due");
        return NULL;
    }
    if (r->msg_case != kind) {
        char b[64];
        snprintf(b, sizeof b, "request %d where %d was due", (int)r->msg_case, (int)kind);
        srv_bad(s, b);
        voxd__request__free_unpacked(r, NULL);
        return NULL;
    }
    return r;
}

static inline void srv_expect_free(srv *s, Voxd__Request__MsgCase kind)
{
    Voxd__Request *r = srv_expect(s, kind);
    if (r) voxd__request__free_unpacked(r, NULL);
}

/* Wait for the client to close (answering pings), at most 5 s. */
static inline void srv_drain(srv *s)
{
    Voxd__Request *r;
    while ((r = srv_read(s))) voxd__request__free_unpacked(r, NULL);
}

/* The table's defaults, but for what the test asks. */
static inline void send_hello_ok(srv *s)
{
    proto_limits lim;
    proto_limits_default(&lim);
    if (s->hello_max_frame) lim.max_frame = (uint32_t)s->hello_max_frame;
    if (s->job_timeout) lim.job_timeout = s->job_timeout < 0 ? 0 : (uint32_t)s->job_timeout;
    if (s->max_result) lim.max_result_bytes = s->max_result;
    if (s->hello_chunk) lim.chunk_size = (uint32_t)s->hello_chunk;
    if (s->hello_max_expr) lim.max_expr_bytes = s->hello_max_expr;
    if (s->hello_max_input) lim.max_input_bytes = s->hello_max_input;
    if (s->hello_max_mesh) lim.max_mesh_bytes = s->hello_max_mesh;
    Voxd__Limits l = VOXD__LIMITS__INIT;
    proto_limits_to_hello(&lim, &l);
    Voxd__HelloOk h = VOXD__HELLO_OK__INIT;
    h.version = 1;
    h.server = "fake voxd";
    h.limits = &l;
    h.workers = 3;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_HELLO_OK, r.hello_ok = &h;
    srv_send(s, &r);
}

static inline void srv_hello(srv *s)
{
    Voxd__Request *r = srv_expect(s, VOXD__REQUEST__MSG_HELLO);
    if (!r) return;
    if (r->hello->version != 1) srv_bad(s, "hello version is not 1");
    voxd__request__free_unpacked(r, NULL);
    send_hello_ok(s);
}

static inline void send_accepted(srv *s, uint64_t id, uint32_t qpos)
{
    Voxd__Accepted m = VOXD__ACCEPTED__INIT;
    m.job_id = id, m.queue_position = qpos;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_ACCEPTED, r.accepted = &m;
    srv_send(s, &r);
}

static inline void send_progress(srv *s, uint64_t id, double f, uint32_t level, uint64_t voxels)
{
    Voxd__Progress m = VOXD__PROGRESS__INIT;
    m.job_id = id, m.fraction = f, m.level = level, m.voxels = voxels;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_PROGRESS, r.progress = &m;
    srv_send(s, &r);
}

static inline void send_chunk(srv *s, uint64_t id, uint64_t off, const uint8_t *data, size_t n)
{
    Voxd__ResultChunk m = VOXD__RESULT_CHUNK__INIT;
    m.job_id = id, m.offset = off, m.data.data = (uint8_t *)data, m.data.len = n;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_CHUNK, r.chunk = &m;
    srv_send(s, &r);
}

static inline void send_summary(srv *s, uint64_t id, uint64_t bytes, uint32_t crc)
{
    uint32_t res[3] = {64, 40, 9};
    double origin[3] = {-1, -0.625, -0.140625};
    Voxd__Grid g = VOXD__GRID__INIT;
    g.res = res, g.n_res = 3, g.depth = 6, g.voxel_size = 0.03125;
    g.origin = origin, g.n_origin = 3;
    Voxd__Summary m = VOXD__SUMMARY__INIT;
    m.grid = &g;
    m.job_id = id, m.voxels = 1234, m.bricks = 56, m.file_bytes = bytes, m.crc32 = crc;
    m.seconds_queued = 0.5, m.seconds_voxelize = 1.5, m.seconds_write = 0.25;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_SUMMARY, r.summary = &m;
    srv_send(s, &r);
}

static inline void send_error(srv *s, uint64_t id, int code, const char *msg)
{
    Voxd__Error m = VOXD__ERROR__INIT;
    m.job_id = id, m.code = (Voxd__ErrorCode)code, m.message = (char *)msg;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_ERROR, r.error = &m;
    srv_send(s, &r);
}

/* A stand-in for a VOD file: n bytes whose last 4 are the little-endian
 * CRC-32 of the others (all the client checks). */
static inline uint8_t *make_result(size_t n, uint32_t seed, uint32_t *crc)
{
    uint8_t *b = malloc(n);
    uint32_t x = seed * 2654435761u + 1;
    for (size_t i = 0; i < n - 4; i++) {
        x = x * 1103515245u + 12345u;
        b[i] = (uint8_t)(x >> 16);
    }
    uint32_t c = (uint32_t)crc32(0, b, (uInt)(n - 4));
    b[n - 4] = (uint8_t)c, b[n - 3] = (uint8_t)(c >> 8);
    b[n - 2] = (uint8_t)(c >> 16), b[n - 1] = (uint8_t)(c >> 24);
    if (crc) *crc = c;
    return b;
}

/* Send a whole result as chunks of `chunk` bytes. */
static inline void send_result(srv *s, uint64_t id, const uint8_t *b, size_t n, size_t chunk)
{
    for (size_t off = 0; off < n; off += chunk)
        send_chunk(s, id, off, b + off, n - off < chunk ? n - off : chunk);
}

/* Read the Submit and accept it as job `id`. */
static inline Voxd__Request *srv_accept_job(srv *s, uint64_t id, uint32_t qpos)
{
    Voxd__Request *r = srv_expect(s, VOXD__REQUEST__MSG_SUBMIT);
    if (r) send_accepted(s, id, qpos);
    return r;
}

static inline void *srv_main(void *arg)
{
    srv *s = arg;
    if (s->listen_fd >= 0) {
        s->fd = accept(s->listen_fd, NULL, NULL);
        if (s->fd < 0) {
            srv_bad(s, "accept failed");
            return NULL;
        }
    }
    proto_frame_decoder_init(&s->dec, PROTO_FRAME_DEFAULT_MAX);
    s->fn(s);
    proto_frame_decoder_free(&s->dec);
    close(s->fd);
    return NULL;
}

static inline srv *srv_new(srv_fn fn, void *arg)
{
    srv *s = calloc(1, sizeof *s);
    s->fn = fn;
    s->arg = arg;
    s->pong = 1;
    s->listen_fd = -1;
    return s;
}

/* A fake daemon on a socketpair; *client_fd is the client's end. */
static inline void srv_start(srv *s, int *client_fd)
{
    int sv[2];
    cr_assert_eq(socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sv), 0);
    s->fd = sv[1];
    *client_fd = sv[0];
    cr_assert_eq(pthread_create(&s->th, NULL, srv_main, s), 0);
}

static inline void srv_finish(srv *s)
{
    pthread_join(s->th, NULL);
    cr_expect_str_empty(s->bad, "fake daemon: %s", s->bad);
    free(s);
}

/* Connect a client with a short timeout to a fake daemon running fn. */
static inline vox_client *start(srv *s, int timeout_ms)
{
    int fd;
    srv_start(s, &fd);
    vox_options o = {.timeout_ms = timeout_ms, .client_name = "test"};
    vox_client *c = NULL;
    vox_error e;
    int rc = vox_connect_fd(fd, &o, &c, &e);
    cr_assert_eq(rc, 0, "connect: %d %s", rc, e.message);
    return c;
}

/* ---------------------------------------------------------------- helpers */

static char dir[64];

static inline void make_dir(void)
{
    snprintf(dir, sizeof dir, "/tmp/test_libvox.XXXXXX");
    cr_assert_not_null(mkdtemp(dir));
}

static inline int dir_entries(void)
{
    DIR *d = opendir(dir);
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)))
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..")) n++;
    closedir(d);
    return n;
}

static inline void remove_dir(void)
{
    DIR *d = opendir(dir);
    struct dirent *e;
    char p[512];
    while ((e = readdir(d)))
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..")) {
            snprintf(p, sizeof p, "%s/%s", dir, e->d_name);
            unlink(p);
        }
    closedir(d);
    rmdir(dir);
}

static inline char *out_path(const char *name)
{
    static char p[256];
    snprintf(p, sizeof p, "%s/%s", dir, name);
    return p;
}

static const vox_implicit_job sphere = {
    .source = "sqrt(x^2+y^2+z^2) - 0.8",
    .domain = {-1, 1, -1, 1, -1, 1},
    .res = 64,
};

typedef struct {
    int calls;
    double fraction[16];
    int level[16];
    uint64_t voxels[16];
    int cancel_at; /* return 1 at this call (1-based), 0: never */
    int sent;      /* progress frames the fake daemon has sent (atomic) */
} prog_log;

static inline int on_prog(void *ud, double f, int level, uint64_t voxels)
{
    prog_log *p = ud;
    int n = __atomic_load_n(&p->calls, __ATOMIC_ACQUIRE);
    if (n < 16) {
        p->fraction[n] = f;
        p->level[n] = level;
        p->voxels[n] = voxels;
    }
    __atomic_store_n(&p->calls, n + 1, __ATOMIC_RELEASE);
    return p->cancel_at && n + 1 >= p->cancel_at;
}

/* Submit the sphere, expect acceptance as job `id`. */
static inline uint64_t submit(vox_client *c, uint64_t want)
{
    uint64_t id = 0;
    uint32_t q = 99;
    vox_error e;
    int rc = vox_submit(c, &sphere, &id, &q, &e);
    cr_assert_eq(rc, 0, "submit: %d %s", rc, e.message);
    cr_assert_eq(id, want);
    return id;
}

/* Receive job id into OUT and expect failure rc with no file left. */
static inline void expect_fail(vox_client *c, uint64_t id, int want, const char *msg_part)
{
    vox_error e;
    vox_summary sum;
    int rc = vox_receive_to_file(c, id, out_path("out.vod"), &(vox_receive_opts){.sum = &sum}, &e);
    cr_expect_eq(rc, want, "receive: %d (%s), want %d", rc, e.message, want);
    cr_expect_eq(e.code, rc);
    if (msg_part)
        cr_expect(strstr(e.message, msg_part), "message '%s' lacks '%s'", e.message, msg_part);
    cr_expect_eq(dir_entries(), 0, "a file was left in %s", dir);
}

/* ---------------------------------------------------------------- hello */

static inline void s_idle(srv *s)
{
    srv_hello(s);
    srv_drain(s);
}

/* ---------------------------------------------------------------- happy path */

#define RESULT_BYTES 100003

static int s_happy_saw_cancel;

static inline void s_happy(srv *s)
{
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 7, 2);
    if (r) {
        Voxd__Implicit *im = r->submit->implicit;
        if (!im || im->source.len != strlen(sphere.source) ||
            memcmp(im->source.data, sphere.source, im->source.len))
            srv_bad(s, "submit source differs");
        if (!im || im->n_domain != 6 || im->domain[0] != -1 || im->domain[5] != 1 ||
            im->res != 64)
            srv_bad(s, "submit domain or res differs");
        if (r->submit->channel || r->submit->brick || r->submit->comp || r->submit->hash)
            srv_bad(s, "submit output options are not the defaults");
        voxd__request__free_unpacked(r, NULL);
    }
    uint32_t crc;
    uint8_t *b = make_result(RESULT_BYTES, 1, &crc);
    send_progress(s, 7, 0.25, 6, 100);
    send_progress(s, 7, 0.5, 5, 200);
    send_progress(s, 7, 0.75, 4, 300);
    send_result(s, 7, b, 30000, 10000);
    for (size_t off = 30000; off < RESULT_BYTES; off += 7001)
        send_chunk(s, 7, off, b + off, RESULT_BYTES - off < 7001 ? RESULT_BYTES - off : 7001);
    send_summary(s, 7, RESULT_BYTES, crc);
    free(b);
    while ((r = srv_read(s))) {
        if (r->msg_case == VOXD__REQUEST__MSG_CANCEL && r->cancel->job_id == 7)
            __atomic_store_n(&s_happy_saw_cancel, 1, __ATOMIC_RELEASE);
        voxd__request__free_unpacked(r, NULL);
    }
}

#endif
