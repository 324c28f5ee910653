/* libvox against a fake daemon: a thread on the other end of a socketpair
 * (or of a temporary Unix socket) that speaks frames from a script.  Every
 * client-side path: hello and its refusal, a job's chunks to a file and to a
 * buffer with the CRC checked and the file renamed into place, progress,
 * every typed error with its message, results that do not check, protocol
 * violations (wrong offset, oversized chunk, unknown job, bad frames, replies
 * nobody asked for), a daemon that closes mid-result or goes silent, the
 * keepalive that tells a busy daemon from a hung one, interleaved jobs,
 * cancellation, status, ping, and no daemon at all.  After a failure no
 * file is left at the output path nor beside it. */
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
    frame_decoder dec;
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

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void srv_bad(srv *s, const char *what)
{
    if (!s->bad[0]) snprintf(s->bad, sizeof s->bad, "%s", what);
}

static void srv_write(srv *s, const void *buf, size_t len)
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

static void srv_send(srv *s, Voxd__Reply *r)
{
    uint8_t *buf;
    size_t len;
    if (frame_encode_reply(r, &buf, &len)) {
        srv_bad(s, "cannot encode a reply");
        return;
    }
    srv_write(s, buf, len);
    free(buf);
}

static void send_pong(srv *s, uint64_t token)
{
    Voxd__Pong m = VOXD__PONG__INIT;
    m.token = token;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_PONG, r.pong = &m;
    srv_send(s, &r);
}

/* The next request (pings answered or swallowed per s->pong), NULL at EOF
 * or after 5 s of nothing. */
static Voxd__Request *srv_read(srv *s)
{
    for (;;) {
        frame_view f;
        int rc = frame_decode(&s->dec, &s->p, &s->n, &f);
        if (rc == 1) {
            Voxd__Request *r = frame_unpack_request(f.data, f.len);
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
static Voxd__Request *srv_read_any(srv *s)
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
static Voxd__Request *srv_expect(srv *s, Voxd__Request__MsgCase kind)
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

static void srv_expect_free(srv *s, Voxd__Request__MsgCase kind)
{
    Voxd__Request *r = srv_expect(s, kind);
    if (r) voxd__request__free_unpacked(r, NULL);
}

/* Wait for the client to close (answering pings), at most 5 s. */
static void srv_drain(srv *s)
{
    Voxd__Request *r;
    while ((r = srv_read(s))) voxd__request__free_unpacked(r, NULL);
}

/* The table's defaults, but for what the test asks. */
static void send_hello_ok(srv *s)
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

static void srv_hello(srv *s)
{
    Voxd__Request *r = srv_expect(s, VOXD__REQUEST__MSG_HELLO);
    if (!r) return;
    if (r->hello->version != 1) srv_bad(s, "hello version is not 1");
    voxd__request__free_unpacked(r, NULL);
    send_hello_ok(s);
}

static void send_accepted(srv *s, uint64_t id, uint32_t qpos)
{
    Voxd__Accepted m = VOXD__ACCEPTED__INIT;
    m.job_id = id, m.queue_position = qpos;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_ACCEPTED, r.accepted = &m;
    srv_send(s, &r);
}

static void send_progress(srv *s, uint64_t id, double f, uint32_t level, uint64_t voxels)
{
    Voxd__Progress m = VOXD__PROGRESS__INIT;
    m.job_id = id, m.fraction = f, m.level = level, m.voxels = voxels;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_PROGRESS, r.progress = &m;
    srv_send(s, &r);
}

static void send_chunk(srv *s, uint64_t id, uint64_t off, const uint8_t *data, size_t n)
{
    Voxd__ResultChunk m = VOXD__RESULT_CHUNK__INIT;
    m.job_id = id, m.offset = off, m.data.data = (uint8_t *)data, m.data.len = n;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_CHUNK, r.chunk = &m;
    srv_send(s, &r);
}

static void send_summary(srv *s, uint64_t id, uint64_t bytes, uint32_t crc)
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

static void send_error(srv *s, uint64_t id, int code, const char *msg)
{
    Voxd__Error m = VOXD__ERROR__INIT;
    m.job_id = id, m.code = (Voxd__ErrorCode)code, m.message = (char *)msg;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_ERROR, r.error = &m;
    srv_send(s, &r);
}

/* A stand-in for a VOD file: n bytes whose last 4 are the little-endian
 * CRC-32 of the others (all the client checks). */
static uint8_t *make_result(size_t n, uint32_t seed, uint32_t *crc)
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
static void send_result(srv *s, uint64_t id, const uint8_t *b, size_t n, size_t chunk)
{
    for (size_t off = 0; off < n; off += chunk)
        send_chunk(s, id, off, b + off, n - off < chunk ? n - off : chunk);
}

/* Read the Submit and accept it as job `id`. */
static Voxd__Request *srv_accept_job(srv *s, uint64_t id, uint32_t qpos)
{
    Voxd__Request *r = srv_expect(s, VOXD__REQUEST__MSG_SUBMIT);
    if (r) send_accepted(s, id, qpos);
    return r;
}

static void *srv_main(void *arg)
{
    srv *s = arg;
    if (s->listen_fd >= 0) {
        s->fd = accept(s->listen_fd, NULL, NULL);
        if (s->fd < 0) {
            srv_bad(s, "accept failed");
            return NULL;
        }
    }
    frame_decoder_init(&s->dec, FRAME_DEFAULT_MAX);
    s->fn(s);
    frame_decoder_free(&s->dec);
    close(s->fd);
    return NULL;
}

static srv *srv_new(srv_fn fn, void *arg)
{
    srv *s = calloc(1, sizeof *s);
    s->fn = fn;
    s->arg = arg;
    s->pong = 1;
    s->listen_fd = -1;
    return s;
}

/* A fake daemon on a socketpair; *client_fd is the client's end. */
static void srv_start(srv *s, int *client_fd)
{
    int sv[2];
    cr_assert_eq(socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sv), 0);
    s->fd = sv[1];
    *client_fd = sv[0];
    cr_assert_eq(pthread_create(&s->th, NULL, srv_main, s), 0);
}

static void srv_finish(srv *s)
{
    pthread_join(s->th, NULL);
    cr_expect_str_empty(s->bad, "fake daemon: %s", s->bad);
    free(s);
}

/* Connect a client with these options to a fake daemon running fn. */
static vox_client *start_opts(srv *s, const vox_options *o)
{
    int fd;
    srv_start(s, &fd);
    vox_client *c = NULL;
    vox_error e;
    int rc = vox_connect_fd(fd, o, &c, &e);
    cr_assert_eq(rc, 0, "connect: %d %s", rc, e.message);
    return c;
}

/* Connect a client with a short timeout to a fake daemon running fn. */
static vox_client *start(srv *s, int timeout_ms)
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

static void make_dir(void)
{
    snprintf(dir, sizeof dir, "/tmp/test_libvox.XXXXXX");
    cr_assert_not_null(mkdtemp(dir));
}

static int dir_entries(void)
{
    DIR *d = opendir(dir);
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)))
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..")) n++;
    closedir(d);
    return n;
}

static void remove_dir(void)
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

static char *out_path(const char *name)
{
    static char p[256];
    snprintf(p, sizeof p, "%s/%s", dir, name);
    return p;
}

static uint8_t *slurp(const char *path, size_t *n)
{
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    fseek(f, 0, SEEK_END);
    long len = ftell(f);
    fseek(f, 0, SEEK_SET);
    uint8_t *b = malloc((size_t)len + 1);
    *n = fread(b, 1, (size_t)len, f);
    fclose(f);
    return b;
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

static int on_prog(void *ud, double f, int level, uint64_t voxels)
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
static uint64_t submit(vox_client *c, uint64_t want)
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
static void expect_fail(vox_client *c, uint64_t id, int want, const char *msg_part)
{
    vox_error e;
    vox_summary sum;
    int rc = vox_receive_file(c, id, out_path("out.vod"), NULL, NULL, &sum, &e);
    cr_expect_eq(rc, want, "receive: %d (%s), want %d", rc, e.message, want);
    cr_expect_eq(e.code, rc);
    if (msg_part)
        cr_expect(strstr(e.message, msg_part), "message '%s' lacks '%s'", e.message, msg_part);
    cr_expect_eq(dir_entries(), 0, "a file was left in %s", dir);
}

TestSuite(libvox, .init = make_dir, .fini = remove_dir, .timeout = 30);

/* ---------------------------------------------------------------- hello */

static void s_idle(srv *s)
{
    srv_hello(s);
    srv_drain(s);
}

Test(libvox, hello_gives_server_and_limits)
{
    srv *s = srv_new(s_idle, NULL);
    s->hello_chunk = 2000;
    vox_client *c = start(s, 5000);
    vox_server_info i;
    vox_server(c, &i);
    cr_expect_str_eq(i.name, "fake voxd");
    cr_expect_eq(i.version, 1);
    cr_expect_eq(i.workers, 3);
    cr_expect_eq(i.chunk_size, 2000);
    cr_expect_eq(i.max_res, 4096);
    cr_expect_eq(i.job_timeout, 600);
    cr_expect_eq(i.max_csg_nodes, 256);
    cr_expect_eq(i.max_input_bytes, 64u << 20);
    vox_close(c);
    srv_finish(s);
}

static void s_refuse_hello(srv *s)
{
    srv_expect_free(s, VOXD__REQUEST__MSG_HELLO);
    send_error(s, 0, VOXD__ERROR_CODE__BUSY, "too many clients (limit 128)");
}

Test(libvox, hello_refused_is_typed)
{
    srv *s = srv_new(s_refuse_hello, NULL);
    int fd;
    srv_start(s, &fd);
    vox_client *c = (vox_client *)1;
    vox_error e;
    int rc = vox_connect_fd(fd, NULL, &c, &e);
    cr_expect_eq(rc, VOX_EBUSY);
    cr_expect_null(c);
    cr_expect(strstr(e.message, "too many clients (limit 128)"), "%s", e.message);
    srv_finish(s);
}

static void s_bad_hello(srv *s)
{
    srv_expect_free(s, VOXD__REQUEST__MSG_HELLO);
    Voxd__Limits l = VOXD__LIMITS__INIT; /* all zero: invalid */
    Voxd__HelloOk h = VOXD__HELLO_OK__INIT;
    h.version = 1, h.limits = &l;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_HELLO_OK, r.hello_ok = &h;
    srv_send(s, &r);
    srv_drain(s);
}

Test(libvox, invalid_hello_is_a_protocol_error)
{
    srv *s = srv_new(s_bad_hello, NULL);
    int fd;
    srv_start(s, &fd);
    vox_client *c;
    vox_error e;
    cr_expect_eq(vox_connect_fd(fd, NULL, &c, &e), -EPROTO);
    cr_expect(strstr(e.message, "max_frame"), "%s", e.message);
    srv_finish(s);
}

static void s_silent_hello(srv *s)
{
    s->pong = 0;
    srv_drain(s);
}

Test(libvox, silent_daemon_at_hello_times_out)
{
    srv *s = srv_new(s_silent_hello, NULL);
    int fd;
    srv_start(s, &fd);
    vox_client *c;
    vox_error e;
    vox_options o = {.timeout_ms = 200};
    double t0 = now_s();
    cr_expect_eq(vox_connect_fd(fd, &o, &c, &e), -ETIMEDOUT);
    double t = now_s() - t0;
    cr_expect(t >= 0.15 && t < 10, "timed out after %.3f s", t);
    srv_finish(s);
}

/* ---------------------------------------------------------------- happy path */

#define RESULT_BYTES 100003
static int s_happy_saw_cancel;

static void s_happy(srv *s)
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

Test(libvox, happy_path_to_file)
{
    srv *s = srv_new(s_happy, NULL);
    vox_client *c = start(s, 5000);
    uint64_t id = 0;
    uint32_t q = 0;
    vox_error e;
    cr_assert_eq(vox_submit(c, &sphere, &id, &q, &e), 0, "%s", e.message);
    cr_expect_eq(id, 7);
    cr_expect_eq(q, 2);
    prog_log pl = {0};
    vox_summary sum;
    int rc = vox_receive_file(c, id, out_path("out.vod"), on_prog, &pl, &sum, &e);
    cr_assert_eq(rc, 0, "%s", e.message);
    uint32_t crc;
    uint8_t *want = make_result(RESULT_BYTES, 1, &crc);
    size_t n;
    uint8_t *got = slurp(out_path("out.vod"), &n);
    cr_assert_not_null(got);
    cr_expect_eq(n, RESULT_BYTES);
    cr_expect(memcmp(got, want, n) == 0, "file differs from what was sent");
    cr_expect_eq(dir_entries(), 1, "a temporary file was left");
    struct stat st;
    cr_expect_eq(stat(out_path("out.vod"), &st), 0);
    mode_t um = umask(0);
    umask(um);
    cr_expect_eq(st.st_mode & 0777, 0666 & ~um, "mode %o", st.st_mode & 0777);
    cr_expect_eq(sum.job_id, 7);
    cr_expect_eq(sum.crc32, crc);
    cr_expect_eq(sum.file_bytes, RESULT_BYTES);
    cr_expect_eq(sum.voxels, 1234);
    cr_expect_eq(sum.bricks, 56);
    cr_expect_float_eq(sum.seconds_voxelize, 1.5, 1e-12);
    /* The grid, as the daemon said. */
    cr_expect(sum.grid[0] == 64 && sum.grid[1] == 40 && sum.grid[2] == 9, "grid %ux%ux%u",
              sum.grid[0], sum.grid[1], sum.grid[2]);
    cr_expect_eq(sum.depth, 6);
    cr_expect_float_eq(sum.voxel_size, 0.03125, 1e-15);
    cr_expect(sum.origin[0] == -1 && sum.origin[1] == -0.625 && sum.origin[2] == -0.140625);
    /* Progress: each report seen once, in order (all may arrive in one
     * read, so the callback may see only the latest of a batch). */
    cr_expect(pl.calls >= 1 && pl.calls <= 3, "%d progress calls", pl.calls);
    cr_expect_float_eq(pl.fraction[pl.calls - 1], 0.75, 1e-12);
    cr_expect_eq(pl.level[pl.calls - 1], 4);
    cr_expect_eq(pl.voxels[pl.calls - 1], 300);
    for (int i = 1; i < pl.calls && i < 16; i++)
        cr_expect(pl.fraction[i] > pl.fraction[i - 1]);
    free(got);
    free(want);
    /* The job is forgotten: receiving it again is an error, not a hang. */
    cr_expect_eq(vox_receive_file(c, id, out_path("again.vod"), NULL, NULL, NULL, &e), -EINVAL);
    vox_close(c);
    srv_finish(s);
}

/* Progress sent one at a time, each after the client's callback saw the
 * one before (the callback's log is shared with this thread), so the
 * client sees every one.  Sent as soon as the job is accepted: the first
 * arrives before the receiving call. */
static void s_progress_steps(srv *s)
{
    prog_log *pl = s->arg;
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 3, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    for (int i = 1; i <= 5; i++) {
        send_progress(s, 3, i / 10.0, 10 - i, (uint64_t)i * 1000);
        __atomic_store_n(&pl->sent, i, __ATOMIC_RELEASE); /* pairs with the test's load */
        for (int t = 0; t < 30000 && __atomic_load_n(&pl->calls, __ATOMIC_ACQUIRE) < i; t++)
            usleep(1000);
    }
    uint32_t crc;
    uint8_t *b = make_result(64, 2, &crc);
    send_result(s, 3, b, 64, 64);
    send_summary(s, 3, 64, crc);
    free(b);
    srv_drain(s);
}

Test(libvox, progress_callbacks_in_order)
{
    prog_log pl = {0};
    srv *s = srv_new(s_progress_steps, &pl);
    vox_client *c = start(s, 5000);
    uint64_t id = submit(c, 3);
    /* the first progress is waiting when the receiving call starts (30 s
     * at most: a loaded machine) */
    for (int t = 0; t < 30000 && __atomic_load_n(&pl.sent, __ATOMIC_ACQUIRE) < 1; t++)
        usleep(1000);
    cr_assert_geq(__atomic_load_n(&pl.sent, __ATOMIC_ACQUIRE), 1, "no progress sent");
    vox_error e;
    cr_assert_eq(vox_receive_file(c, id, out_path("p.vod"), on_prog, &pl, NULL, &e), 0, "%s",
                 e.message);
    cr_expect_eq(pl.calls, 5);
    for (int i = 0; i < 5; i++) {
        cr_expect_float_eq(pl.fraction[i], (i + 1) / 10.0, 1e-12);
        cr_expect_eq(pl.level[i], 9 - i);
        cr_expect_eq(pl.voxels[i], (uint64_t)(i + 1) * 1000);
    }
    vox_close(c);
    srv_finish(s);
}

Test(libvox, happy_path_to_buffer)
{
    srv *s = srv_new(s_happy, NULL);
    vox_client *c = start(s, 5000);
    uint64_t id = submit(c, 7);
    uint8_t *buf;
    size_t len;
    vox_summary sum;
    vox_error e;
    cr_assert_eq(vox_receive_buffer(c, id, &buf, &len, NULL, NULL, &sum, &e), 0, "%s",
                 e.message);
    uint8_t *want = make_result(RESULT_BYTES, 1, NULL);
    cr_expect_eq(len, RESULT_BYTES);
    cr_expect(memcmp(buf, want, len) == 0);
    cr_expect_eq(sum.file_bytes, RESULT_BYTES);
    free(buf);
    free(want);
    vox_close(c);
    srv_finish(s);
}

/* Two jobs whose chunks interleave; received in the other order.  The
 * first job's result waits in the spool while the second is received. */
static void s_two_jobs(srv *s)
{
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 10, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    r = srv_accept_job(s, 11, 1);
    if (r) voxd__request__free_unpacked(r, NULL);
    uint32_t ca, cb;
    uint8_t *a = make_result(50000, 10, &ca), *b = make_result(30001, 11, &cb);
    for (int i = 0; i < 5; i++) {
        send_progress(s, 10, i / 10.0, 3, (uint64_t)i);
        send_progress(s, 11, i / 10.0, 3, (uint64_t)i);
    }
    for (size_t off = 0; off < 50000; off += 5000) {
        send_chunk(s, 10, off, a + off, 5000);
        if (off < 30001) send_chunk(s, 11, off, b + off, 30001 - off < 5000 ? 30001 - off : 5000);
    }
    send_summary(s, 11, 30001, cb);
    send_summary(s, 10, 50000, ca);
    free(a);
    free(b);
    srv_drain(s);
}

Test(libvox, interleaved_jobs)
{
    srv *s = srv_new(s_two_jobs, NULL);
    vox_client *c = start(s, 5000);
    uint64_t a = submit(c, 10), b = submit(c, 11);
    vox_error e;
    uint8_t *buf;
    size_t len;
    cr_assert_eq(vox_receive_buffer(c, b, &buf, &len, NULL, NULL, NULL, &e), 0, "%s", e.message);
    uint8_t *wb = make_result(30001, 11, NULL), *wa = make_result(50000, 10, NULL);
    cr_expect_eq(len, 30001);
    cr_expect(memcmp(buf, wb, len) == 0);
    free(buf);
    vox_summary sum;
    cr_assert_eq(vox_receive_file(c, a, out_path("a.vod"), NULL, NULL, &sum, &e), 0, "%s",
                 e.message);
    size_t n;
    uint8_t *got = slurp(out_path("a.vod"), &n);
    cr_expect_eq(n, 50000);
    cr_expect(memcmp(got, wa, n) == 0);
    cr_expect_eq(sum.job_id, 10);
    free(got);
    free(wa);
    free(wb);
    vox_close(c);
    srv_finish(s);
}

/* ---------------------------------------------------------------- typed errors */

static const struct {
    int code, vox;
    const char *name, *msg;
} codes[] = {
    {1, VOX_EINVALID_INPUT, "INVALID_INPUT", "<source>:1:9: expected ')'"},
    {2, VOX_ELIMIT_EXCEEDED, "LIMIT_EXCEEDED", "res 5000 is over this server's limit of 4096"},
    {3, VOX_EBUSY, "BUSY", "queue full (64 jobs)"},
    {4, VOX_ECANCELLED, "CANCELLED", "cancelled by the client"},
    {5, VOX_EWORKER_CRASHED, "WORKER_CRASHED", "worker 2 (pid 4242) died: SIGSEGV"},
    {6, VOX_ETIMEOUT, "TIMEOUT", "job ran past job_timeout (600 s)"},
    {7, VOX_ESHUTTING_DOWN, "SHUTTING_DOWN", "voxd is stopping"},
    {8, VOX_EINTERNAL, "INTERNAL", "out of shared memory"},
};

static void s_job_error(srv *s)
{
    int k = *(int *)s->arg;
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 40 + (uint64_t)k, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    uint8_t part[100] = {1, 2, 3};
    send_chunk(s, 40 + (uint64_t)k, 0, part, sizeof part); /* a partial result first */
    send_error(s, 40 + (uint64_t)k, codes[k].code, codes[k].msg);
    srv_drain(s);
}

Test(libvox, every_typed_job_error_reaches_the_caller)
{
    for (int k = 0; k < 8; k++) {
        srv *s = srv_new(s_job_error, &k);
        vox_client *c = start(s, 5000);
        uint64_t id = submit(c, 40 + (uint64_t)k);
        expect_fail(c, id, codes[k].vox, codes[k].msg);
        cr_expect_str_eq(vox_error_name(codes[k].vox), codes[k].name);
        cr_expect(VOX_IS_SERVER_ERROR(codes[k].vox));
        /* The same through the buffer interface: nothing returned. */
        vox_close(c);
        srv_finish(s);
    }
    cr_expect_null(vox_error_name(-ENOENT));
    cr_expect_null(vox_error_name(0));
    cr_expect(!VOX_IS_SERVER_ERROR(-EPROTO));
    cr_expect_str_eq(vox_strerror(-ENOENT), strerror(ENOENT));
    cr_expect_str_eq(vox_strerror(VOX_ELIMIT_EXCEEDED), "over a limit of the daemon");
}

static void s_job_error_buf(srv *s)
{
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 5, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    uint8_t part[10] = {0};
    send_chunk(s, 5, 0, part, sizeof part);
    send_error(s, 5, VOXD__ERROR_CODE__WORKER_CRASHED, "worker 0 died");
    srv_drain(s);
}

Test(libvox, typed_error_to_buffer_returns_nothing)
{
    srv *s = srv_new(s_job_error_buf, NULL);
    vox_client *c = start(s, 5000);
    uint64_t id = submit(c, 5);
    uint8_t *buf = (uint8_t *)1;
    size_t len = 7;
    vox_error e;
    cr_expect_eq(vox_receive_buffer(c, id, &buf, &len, NULL, NULL, NULL, &e), VOX_EWORKER_CRASHED);
    cr_expect_null(buf);
    cr_expect_eq(len, 0);
    cr_expect_str_eq(e.message, "worker 0 died");
    cr_expect_eq(e.job_id, 5);
    vox_close(c);
    srv_finish(s);
}

static void s_refuse_submit(srv *s)
{
    int k = *(int *)s->arg;
    srv_hello(s);
    srv_expect_free(s, VOXD__REQUEST__MSG_SUBMIT);
    send_error(s, 0, codes[k].code, codes[k].msg);
    /* The connection goes on: a second job is accepted. */
    Voxd__Request *r = srv_accept_job(s, 2, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    srv_drain(s);
}

Test(libvox, refused_submit_is_typed_and_the_connection_goes_on)
{
    int ks[] = {0, 1, 2, 6};
    for (size_t i = 0; i < 4; i++) {
        int k = ks[i];
        srv *s = srv_new(s_refuse_submit, &k);
        vox_client *c = start(s, 5000);
        uint64_t id = 0;
        vox_error e;
        cr_expect_eq(vox_submit(c, &sphere, &id, NULL, &e), codes[k].vox);
        cr_expect_str_eq(e.message, codes[k].msg);
        cr_expect_eq(id, 0);
        cr_expect_eq(vox_submit(c, &sphere, &id, NULL, &e), 0);
        cr_expect_eq(id, 2);
        vox_close(c);
        srv_finish(s);
    }
}

/* ---------------------------------------------------------------- results that do not check */

enum { BAD_CRC, BAD_OWN_CRC, BAD_LENGTH_SHORT, BAD_LENGTH_LONG, BAD_TINY };

static void s_bad_result(srv *s)
{
    int k = *(int *)s->arg;
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 9, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    uint32_t crc;
    uint8_t *b = make_result(5000, 9, &crc);
    switch (k) {
    case BAD_CRC:
        send_result(s, 9, b, 5000, 1024);
        send_summary(s, 9, 5000, crc ^ 1);
        break;
    case BAD_OWN_CRC: /* summary agrees with the bytes, the file's trailer does not */
        b[4999] ^= 0x80;
        send_result(s, 9, b, 5000, 1024);
        send_summary(s, 9, 5000, crc);
        break;
    case BAD_LENGTH_SHORT:
        send_result(s, 9, b, 5000, 1024);
        send_summary(s, 9, 5001, crc);
        break;
    case BAD_LENGTH_LONG:
        send_result(s, 9, b, 5000, 1024);
        send_summary(s, 9, 4999, crc);
        break;
    case BAD_TINY:
        send_chunk(s, 9, 0, b, 3);
        send_summary(s, 9, 3, 0);
        break;
    }
    free(b);
    srv_drain(s);
}

Test(libvox, result_that_does_not_check_leaves_no_file)
{
    const char *want[] = {"CRC-32", "CRC-32", "summary says 5001", "summary says 4999", "CRC-32"};
    for (int k = BAD_CRC; k <= BAD_TINY; k++) {
        srv *s = srv_new(s_bad_result, &k);
        vox_client *c = start(s, 5000);
        uint64_t id = submit(c, 9);
        expect_fail(c, id, -EBADMSG, want[k]);
        vox_close(c);
        srv_finish(s);
    }
}

Test(libvox, crc_mismatch_to_buffer_returns_nothing)
{
    int k = BAD_CRC;
    srv *s = srv_new(s_bad_result, &k);
    vox_client *c = start(s, 5000);
    uint64_t id = submit(c, 9);
    uint8_t *buf;
    size_t len;
    cr_expect_eq(vox_receive_buffer(c, id, &buf, &len, NULL, NULL, NULL, NULL), -EBADMSG);
    cr_expect_null(buf);
    vox_close(c);
    srv_finish(s);
}

/* ---------------------------------------------------------------- protocol violations */

enum {
    V_GAP, V_OVERLAP, V_UNKNOWN_JOB, V_OVER_CHUNK, V_OVER_RESULT, V_OVER_FRAME, V_ZERO_FRAME,
    V_GARBAGE, V_NAN_PROGRESS, V_AFTER_END, V_SECOND_END, V_UNSOLICITED_ACCEPT, V_EMPTY_CHUNK,
    V_BAD_CODE, V_PROGRESS_AFTER_CHUNK, V_PONG_NEVER_ASKED, V_COUNT
};

static void s_violation(srv *s)
{
    int k = *(int *)s->arg;
    s->hello_chunk = 4096;
    s->max_result = 100000;
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 1, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    uint32_t crc;
    uint8_t *b = make_result(200000, 1, &crc);
    send_chunk(s, 1, 0, b, 1000);
    switch (k) {
    case V_GAP: send_chunk(s, 1, 1001, b + 1001, 10); break;
    case V_OVERLAP: send_chunk(s, 1, 999, b + 999, 10); break;
    case V_UNKNOWN_JOB: send_chunk(s, 2, 0, b, 10); break;
    case V_OVER_CHUNK: send_chunk(s, 1, 1000, b + 1000, 4097); break;
    case V_OVER_RESULT:
        for (uint64_t off = 1000; off < 100000; off += 4000) send_chunk(s, 1, off, b + off, 4000);
        send_chunk(s, 1, 101000, b, 10);
        break;
    case V_OVER_FRAME: {
        uint8_t hdr[4] = {0x01, 0x00, 0x00, 0x01}; /* 16 MiB + 1 */
        srv_write(s, hdr, 4);
        break;
    }
    case V_ZERO_FRAME: {
        uint8_t hdr[4] = {0, 0, 0, 0};
        srv_write(s, hdr, 4);
        break;
    }
    case V_GARBAGE: {
        uint8_t g[12] = {0, 0, 0, 8, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff};
        srv_write(s, g, sizeof g);
        break;
    }
    case V_NAN_PROGRESS: send_progress(s, 1, NAN, 3, 1); break;
    case V_AFTER_END:
        send_error(s, 1, VOXD__ERROR_CODE__INTERNAL, "oops");
        send_chunk(s, 1, 1000, b + 1000, 10);
        break;
    case V_SECOND_END:
        send_error(s, 1, VOXD__ERROR_CODE__INTERNAL, "oops");
        send_error(s, 1, VOXD__ERROR_CODE__INTERNAL, "oops again");
        break;
    case V_UNSOLICITED_ACCEPT: send_accepted(s, 5, 0); break;
    case V_EMPTY_CHUNK: send_chunk(s, 1, 1000, b, 0); break;
    case V_BAD_CODE: send_error(s, 1, 99, "what"); break;
    case V_PROGRESS_AFTER_CHUNK: send_progress(s, 1, 0.5, 3, 1); break;
    case V_PONG_NEVER_ASKED: send_pong(s, 1000); break;
    }
    free(b);
    srv_drain(s);
}

Test(libvox, protocol_violations_fail_the_job_and_leave_no_file)
{
    for (int k = 0; k < V_COUNT; k++) {
        srv *s = srv_new(s_violation, &k);
        vox_client *c = start(s, 5000);
        uint64_t id = submit(c, 1);
        int want = -EPROTO;
        /* After its first end a job's own late messages are not seen by
         * the receiving call (the job ended first): the next call is. */
        if (k == V_AFTER_END || k == V_SECOND_END) want = VOX_EINTERNAL;
        cr_log_info("violation %d", k);
        expect_fail(c, id, want, NULL);
        if (want != -EPROTO) {
            vox_error e;
            cr_expect_eq(vox_ping(c, NULL, &e), -EPROTO, "violation %d: ping after", k);
        }
        /* The connection is done for: every later call says why. */
        vox_error e;
        cr_expect_eq(vox_ping(c, NULL, &e), -EPROTO, "violation %d", k);
        cr_expect_eq(e.code, -EPROTO);
        cr_expect(strlen(e.message) > 0);
        vox_close(c);
        srv_finish(s);
    }
}

/* ---------------------------------------------------------------- closed, silent */

static void s_close_mid_result(srv *s)
{
    int mid_frame = *(int *)s->arg;
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 4, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    uint8_t *b = make_result(20000, 4, NULL);
    send_result(s, 4, b, 12000, 4000);
    if (mid_frame) {
        uint8_t hdr[6] = {0, 0, 0x10, 0, 0x22, 0x01};
        srv_write(s, hdr, sizeof hdr);
    }
    free(b);
    /* returns: srv_main closes the socket */
}

Test(libvox, daemon_closes_mid_result)
{
    for (int mid = 0; mid < 2; mid++) {
        srv *s = srv_new(s_close_mid_result, &mid);
        vox_client *c = start(s, 5000);
        uint64_t id = submit(c, 4);
        expect_fail(c, id, -ECONNRESET, mid ? "middle of a reply" : "closed the connection");
        vox_close(c);
        srv_finish(s);
    }
}

static void s_shutdown_note(srv *s)
{
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 4, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    send_error(s, 0, VOXD__ERROR_CODE__SHUTTING_DOWN, "voxd got SIGTERM");
}

Test(libvox, connection_error_before_close_is_the_reason)
{
    srv *s = srv_new(s_shutdown_note, NULL);
    vox_client *c = start(s, 5000);
    uint64_t id = submit(c, 4);
    expect_fail(c, id, VOX_ESHUTTING_DOWN, "voxd got SIGTERM");
    vox_close(c);
    srv_finish(s);
}

static void s_silent_job(srv *s)
{
    srv_hello(s);
    s->pong = 0;
    Voxd__Request *r = srv_accept_job(s, 8, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    uint8_t b[100] = {0};
    send_chunk(s, 8, 0, b, 100);
    srv_drain(s); /* swallows pings, until the client gives up and closes */
}

Test(libvox, silent_daemon_mid_result_times_out)
{
    srv *s = srv_new(s_silent_job, NULL);
    vox_client *c = start(s, 300);
    uint64_t id = submit(c, 8);
    double t0 = now_s();
    expect_fail(c, id, -ETIMEDOUT, "stalled");
    double t = now_s() - t0;
    cr_expect(t >= 0.25 && t < 10, "gave up after %.3f s", t);
    vox_close(c);
    srv_finish(s);
}

static void s_silent_before_result(srv *s)
{
    srv_hello(s);
    s->pong = 0;
    Voxd__Request *r = srv_accept_job(s, 8, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    srv_drain(s); /* swallows pings, until the client gives up and closes */
}

Test(libvox, silent_daemon_times_out)
{
    srv *s = srv_new(s_silent_before_result, NULL);
    vox_client *c = start(s, 300);
    uint64_t id = submit(c, 8);
    double t0 = now_s();
    expect_fail(c, id, -ETIMEDOUT, "said nothing");
    double t = now_s() - t0;
    cr_expect(t >= 0.25 && t < 10, "gave up after %.3f s", t);
    cr_expect(s->pings_seen >= 1, "no keepalive ping was sent");
    /* The connection is dead: every later call says so at once. */
    vox_error e;
    cr_expect_eq(vox_ping(c, NULL, &e), -ETIMEDOUT);
    vox_close(c);
    srv_finish(s);
}

/* Alive (pongs) but the job never ends, or its result stops halfway: the
 * job times out by the daemon's own job_timeout, or by the silence of its
 * result, is cancelled, and the connection goes on. */
static int s_saw_cancel;

static void s_alive_job_stuck(srv *s)
{
    int stall = *(int *)s->arg;
    s->job_timeout = 1;
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 9, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    if (stall) {
        uint8_t b[100] = {0};
        send_chunk(s, 9, 0, b, sizeof b);
    }
    while ((r = srv_read(s))) { /* answers pings */
        if (r->msg_case == VOXD__REQUEST__MSG_CANCEL && r->cancel->job_id == 9) {
            __atomic_store_n(&s_saw_cancel, 1, __ATOMIC_RELEASE);
            send_error(s, 9, VOXD__ERROR_CODE__CANCELLED, "cancelled");
        }
        voxd__request__free_unpacked(r, NULL);
    }
}

/* A job the daemon keeps alive (it answers pings) but never ends (stall 0)
 * or whose result stops (stall 1): the client gives up within [tmin, tmax)
 * seconds with msg, cancels the job, and the connection still works. */
static void expect_late_job(int stall, int timeout_ms, const char *msg, double tmin,
                            double tmax)
{
    srv *s = srv_new(s_alive_job_stuck, &stall);
    vox_client *c = start(s, timeout_ms);
    uint64_t id = submit(c, 9);
    double t0 = now_s();
    expect_fail(c, id, -ETIMEDOUT, msg);
    double t = now_s() - t0;
    cr_expect(t >= tmin && t < tmax, "gave up after %.3f s", t);
    vox_error e;
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "%s", e.message);
    vox_close(c);
    srv_finish(s);
    cr_expect(s_saw_cancel, "the late job was not cancelled");
}

Test(libvox, job_past_the_daemons_job_timeout)
{
    /* (0 ahead + 1) * (job_timeout 1 s + 0.2 s) + 0.2 s */
    expect_late_job(0, 200, "did not finish in 1.4 s (the daemon's job_timeout is 1 s", 1.3, 10);
}

Test(libvox, result_stalled_while_pongs_come)
{
    expect_late_job(1, 300, "stalled", 0.25, 10);
}

static void s_pong_twice(srv *s)
{
    srv_hello(s);
    s->pong = 0;
    Voxd__Request *r;
    uint64_t last = 0;
    while ((r = srv_read_any(s))) {
        if (r->msg_case == VOXD__REQUEST__MSG_PING) {
            if (last) send_pong(s, last); /* the previous one again */
            send_pong(s, r->ping->token);
            last = r->ping->token;
        }
        voxd__request__free_unpacked(r, NULL);
    }
}

Test(libvox, replayed_pong_is_a_protocol_error)
{
    srv *s = srv_new(s_pong_twice, NULL);
    vox_client *c = start(s, 5000);
    vox_error e;
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(vox_ping(c, NULL, &e), -EPROTO);
    cr_expect(strstr(e.message, "it had answered"), "%s", e.message);
    vox_close(c);
    srv_finish(s);
}

/* Busy with other jobs for ten timeouts, but answering pings: no timeout. */
static void s_slow_but_alive(srv *s)
{
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 6, 5);
    if (r) voxd__request__free_unpacked(r, NULL);
    double until = now_s() + 5.0;
    while (now_s() < until) {
        /* answer whatever pings come, for 5 s: five times the client's
         * timeout, which is long enough that a loaded machine does not
         * delay a pong past it */
        struct pollfd p = {s->fd, POLLIN, 0};
        if (poll(&p, 1, 20) == 1) {
            ssize_t n = read(s->fd, s->in, sizeof s->in);
            if (n <= 0) return;
            const uint8_t *q = s->in;
            size_t left = (size_t)n;
            frame_view f;
            while (frame_decode(&s->dec, &q, &left, &f) == 1) {
                Voxd__Request *x = frame_unpack_request(f.data, f.len);
                if (x && x->msg_case == VOXD__REQUEST__MSG_PING) {
                    s->pings_seen++;
                    send_pong(s, x->ping->token);
                }
                if (x) voxd__request__free_unpacked(x, NULL);
            }
        }
    }
    uint32_t crc;
    uint8_t *b = make_result(1000, 6, &crc);
    send_result(s, 6, b, 1000, 1000);
    send_summary(s, 6, 1000, crc);
    free(b);
    srv_drain(s);
}

Test(libvox, keepalive_tells_busy_from_hung)
{
    srv *s = srv_new(s_slow_but_alive, NULL);
    vox_client *c = start(s, 1000);
    uint64_t id = submit(c, 6);
    vox_error e;
    cr_expect_eq(vox_receive_file(c, id, out_path("slow.vod"), NULL, NULL, NULL, &e), 0, "%s",
                 e.message);
    cr_expect(s->pings_seen >= 3, "%d pings", s->pings_seen);
    vox_close(c);
    srv_finish(s);
}

/* ---------------------------------------------------------------- cancel */

static void s_cancel_from_callback(srv *s)
{
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 12, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    send_progress(s, 12, 0.1, 5, 10);
    r = srv_expect(s, VOXD__REQUEST__MSG_CANCEL);
    if (r) {
        if (r->cancel->job_id != 12) srv_bad(s, "cancel names the wrong job");
        voxd__request__free_unpacked(r, NULL);
    }
    send_error(s, 12, VOXD__ERROR_CODE__CANCELLED, "cancelled by the client");
    srv_drain(s);
}

Test(libvox, progress_callback_cancels)
{
    srv *s = srv_new(s_cancel_from_callback, NULL);
    vox_client *c = start(s, 5000);
    uint64_t id = submit(c, 12);
    prog_log pl = {.cancel_at = 1};
    vox_error e;
    cr_expect_eq(vox_receive_file(c, id, out_path("c.vod"), on_prog, &pl, NULL, &e),
                 VOX_ECANCELLED);
    cr_expect_str_eq(e.message, "cancelled by the client");
    cr_expect_eq(dir_entries(), 0);
    vox_close(c);
    srv_finish(s);
}

static void s_cancel_own(srv *s)
{
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 20, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    r = srv_expect(s, VOXD__REQUEST__MSG_CANCEL);
    if (r) voxd__request__free_unpacked(r, NULL);
    send_error(s, 20, VOXD__ERROR_CODE__CANCELLED, "cancelled");
    /* A daemon may also answer the cancel itself once the job has ended:
     * no news to the client, whose cancel succeeded. */
    send_error(s, 20, VOXD__ERROR_CODE__INVALID_INPUT, "job 20 has ended");
    srv_drain(s); /* answers the ping behind the cancel */
}

Test(libvox, cancel_own_job)
{
    srv *s = srv_new(s_cancel_own, NULL);
    vox_client *c = start(s, 5000);
    uint64_t id = submit(c, 20);
    vox_error e;
    cr_expect_eq(vox_cancel(c, id, &e), 0, "%s", e.message);
    cr_expect_eq(vox_receive_file(c, id, out_path("c.vod"), NULL, NULL, NULL, &e),
                 VOX_ECANCELLED);
    cr_expect_eq(dir_entries(), 0);
    vox_close(c);
    srv_finish(s);
}

static void s_cancel_other(srv *s)
{
    srv_hello(s);
    /* 76: allowed (nothing but the pong); 77: refused naming the job;
     * 78: refused as an error about no job */
    Voxd__Request *r = srv_expect(s, VOXD__REQUEST__MSG_CANCEL);
    if (r) voxd__request__free_unpacked(r, NULL);
    r = srv_expect(s, VOXD__REQUEST__MSG_CANCEL);
    if (r) {
        send_error(s, r->cancel->job_id, VOXD__ERROR_CODE__INVALID_INPUT, "no job 77 of uid 1000");
        voxd__request__free_unpacked(r, NULL);
    }
    r = srv_expect(s, VOXD__REQUEST__MSG_CANCEL);
    if (r) {
        send_error(s, 0, VOXD__ERROR_CODE__INVALID_INPUT, "no such job");
        voxd__request__free_unpacked(r, NULL);
    }
    srv_drain(s);
}

Test(libvox, cancel_another_connections_job)
{
    srv *s = srv_new(s_cancel_other, NULL);
    vox_client *c = start(s, 5000);
    vox_error e;
    cr_expect_eq(vox_cancel(c, 76, &e), 0, "%s", e.message);
    cr_expect_eq(vox_cancel(c, 77, &e), VOX_EINVALID_INPUT);
    cr_expect_str_eq(e.message, "no job 77 of uid 1000");
    cr_expect_eq(e.job_id, 77);
    cr_expect_eq(vox_cancel(c, 78, &e), VOX_EINVALID_INPUT);
    cr_expect_str_eq(e.message, "no such job");
    cr_expect_eq(e.job_id, 78);
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(vox_cancel(c, 0, &e), -EINVAL);
    vox_close(c);
    srv_finish(s);
}

/* ---------------------------------------------------------------- status, ping */

static void s_status(srv *s)
{
    srv_hello(s);
    srv_expect_free(s, VOXD__REQUEST__MSG_STATUS);
    Voxd__WorkerStatus w0 = VOXD__WORKER_STATUS__INIT, w1 = VOXD__WORKER_STATUS__INIT;
    w0.pid = 100, w0.cpu = 0, w0.state = VOXD__WORKER_STATE__WORKER_STATE_BUSY, w0.jobs = 3;
    w0.voxels_per_second = 1.5e6;
    w1.pid = 101, w1.cpu = -1, w1.state = VOXD__WORKER_STATE__WORKER_STATE_STALLED;
    w1.replaced = 3, w1.stalls = 1;
    Voxd__WorkerStatus *ws[2] = {&w0, &w1};
    Voxd__RunningJob run = VOXD__RUNNING_JOB__INIT;
    run.job_id = 9, run.uid = 1000, run.fraction = 0.5, run.seconds = 2.5;
    Voxd__StatusReply st = VOXD__STATUS_REPLY__INIT;
    st.uptime = 3600, st.n_workers = 2, st.workers = ws, st.queued = 4, st.running = &run;
    st.clients = 2;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_STATUS, r.status = &st;
    srv_send(s, &r);
    /* Second status: idle, no workers listed. */
    srv_expect_free(s, VOXD__REQUEST__MSG_STATUS);
    st.running = NULL, st.n_workers = 0, st.workers = NULL;
    srv_send(s, &r);
    srv_drain(s);
}

Test(libvox, status)
{
    srv *s = srv_new(s_status, NULL);
    vox_client *c = start(s, 5000);
    vox_status_info st;
    vox_error e;
    cr_assert_eq(vox_status(c, &st, &e), 0, "%s", e.message);
    cr_expect_float_eq(st.uptime, 3600, 1e-9);
    cr_assert_eq(st.n_workers, 2);
    cr_expect_eq(st.workers[0].pid, 100);
    cr_expect_eq(st.workers[0].cpu, 0);
    cr_expect_eq(st.workers[0].state, VOX_WORKER_BUSY);
    cr_expect_eq(st.workers[0].jobs, 3);
    cr_expect_float_eq(st.workers[0].voxels_per_second, 1.5e6, 1e-6);
    cr_expect_eq(st.workers[1].cpu, -1);
    cr_expect_eq(st.workers[1].state, VOX_WORKER_STALLED);
    cr_expect_eq(st.workers[1].replaced, 3);
    cr_expect_eq(st.workers[1].stalls, 1);
    cr_expect_eq(st.workers[0].replaced, 0);
    cr_expect_eq(st.queued, 4);
    cr_expect_eq(st.clients, 2);
    cr_expect(st.has_running);
    cr_expect_eq(st.running_job_id, 9);
    cr_expect_eq(st.running_uid, 1000);
    cr_expect_float_eq(st.running_fraction, 0.5, 1e-12);
    vox_status_free(&st);
    cr_assert_eq(vox_status(c, &st, &e), 0, "%s", e.message);
    cr_expect(!st.has_running);
    cr_expect_eq(st.n_workers, 0);
    vox_status_free(&st);
    vox_close(c);
    srv_finish(s);
}

static void s_unsolicited_status(srv *s)
{
    srv_hello(s);
    Voxd__StatusReply st = VOXD__STATUS_REPLY__INIT;
    Voxd__Reply r = VOXD__REPLY__INIT;
    r.msg_case = VOXD__REPLY__MSG_STATUS, r.status = &st;
    srv_send(s, &r);
    srv_drain(s);
}

Test(libvox, unsolicited_reply_is_a_protocol_error)
{
    srv *s = srv_new(s_unsolicited_status, NULL);
    vox_client *c = start(s, 5000);
    vox_error e;
    cr_expect_eq(vox_ping(c, NULL, &e), -EPROTO);
    cr_expect(strstr(e.message, "nobody asked"), "%s", e.message);
    vox_close(c);
    srv_finish(s);
}

static void s_pong_wrong(srv *s)
{
    srv_hello(s);
    s->pong = 0;
    Voxd__Request *r = srv_read(s); /* nothing: the ping is swallowed */
    (void)r;
    srv_drain(s);
}

static void s_ping(srv *s)
{
    srv_hello(s);
    srv_drain(s);
}

Test(libvox, ping)
{
    srv *s = srv_new(s_ping, NULL);
    vox_client *c = start(s, 5000);
    vox_error e;
    double rtt = -1;
    for (int i = 0; i < 3; i++) {
        cr_expect_eq(vox_ping(c, &rtt, &e), 0, "%s", e.message);
        cr_expect(rtt >= 0 && rtt < 5);
    }
    vox_close(c);
    srv_finish(s);
}

Test(libvox, unanswered_ping_times_out_and_sticks)
{
    srv *s = srv_new(s_pong_wrong, NULL);
    vox_client *c = start(s, 200);
    vox_error e;
    cr_expect_eq(vox_ping(c, NULL, &e), -ETIMEDOUT);
    cr_expect_eq(vox_status(c, &(vox_status_info){0}, &e), -ETIMEDOUT);
    uint64_t id;
    cr_expect_eq(vox_submit(c, &sphere, &id, NULL, &e), -ETIMEDOUT);
    vox_close(c);
    srv_finish(s);
}

/* ---------------------------------------------------------------- limits */

static void s_small_limits(srv *s)
{
    s->hello_max_frame = 4096;
    s->hello_chunk = 4000;
    s->hello_max_expr = 6000;
    s->hello_max_input = 5000;
    srv_hello(s);
    srv_drain(s); /* the oversized submits never arrive; a ping does */
}

/* What the daemon would refuse for its size is refused here, unsent: an
 * expression over max_expr_bytes, or one that must go as input (over a
 * frame) and is over max_input_bytes. */
Test(libvox, input_over_the_limits_is_refused_unsent)
{
    srv *s = srv_new(s_small_limits, NULL);
    vox_client *c = start(s, 5000);
    char *big = malloc(7001);
    memset(big, 'x', 7000);
    big[7000] = '\0';
    vox_implicit_job j = sphere;
    j.source = big;
    uint64_t id;
    vox_error e;
    cr_expect_eq(vox_submit(c, &j, &id, NULL, &e), VOX_ELIMIT_EXCEEDED);
    cr_expect(strstr(e.message, "expression is 7000 bytes, over this server's max_expr_bytes of 6000"),
              "%s", e.message);
    j.source_len = 5500;
    cr_expect_eq(vox_submit(c, &j, &id, NULL, &e), VOX_ELIMIT_EXCEEDED);
    cr_expect(strstr(e.message, "5500 bytes, over this server's max_input_bytes of 5000"), "%s",
              e.message);
    /* A CSG tree never goes in chunks: one whose Submit passes max_frame
     * is refused unsent. */
    vox_csg_node leaf = {.op = VOX_CSG_IMPLICIT, .source = big, .source_len = 4500};
    vox_job cj = {.kind = VOX_JOB_CSG,
                  .csg = {.nodes = &leaf, .n_nodes = 1, .domain = {-1, 1, -1, 1, -1, 1},
                          .res = 16}};
    cr_expect_eq(vox_submit_job(c, &cj, &id, NULL, &e), VOX_ELIMIT_EXCEEDED);
    cr_expect(strstr(e.message, "over this server's max_frame of 4096"), "%s", e.message);
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "%s", e.message);
    free(big);
    vox_close(c);
    srv_finish(s);
}

Test(libvox, incomplete_jobs_are_refused_unsent)
{
    srv *s = srv_new(s_idle, NULL);
    vox_client *c = start(s, 5000);
    uint64_t id = 0;
    vox_error e;
    vox_job j = {.kind = VOX_JOB_CSG};
    cr_expect_eq(vox_submit_job(c, &j, &id, NULL, &e), -EINVAL);
    cr_expect(strstr(e.message, "the CSG job has no nodes"), "%s", e.message);
    j.kind = VOX_JOB_MESH; /* no data */
    cr_expect_eq(vox_submit_job(c, &j, &id, NULL, &e), -EINVAL);
    cr_expect(strstr(e.message, "no mesh data"), "%s", e.message);
    j.mesh.data = "v 0 0 0\n"; /* and no length */
    cr_expect_eq(vox_submit_job(c, &j, &id, NULL, &e), -EINVAL);
    j.kind = 0;
    cr_expect_eq(vox_submit_job(c, &j, &id, NULL, &e), -EINVAL);
    j = (vox_job){.kind = VOX_JOB_IMPLICIT}; /* no source */
    cr_expect_eq(vox_submit_job(c, &j, &id, NULL, &e), -EINVAL);
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "%s", e.message);
    vox_close(c);
    srv_finish(s);
}

/* ---------------------------------------------------------------- chunked input */

#define LONG_EXPR 10007
typedef struct {
    const char *want;   /* the input expected */
    size_t n;
    size_t max_piece;   /* no chunk longer */
    int chunks;         /* chunks seen */
    int fail_after;     /* > 0: end the job after this many chunks */
    int stray;          /* chunks that came after the job ended */
    uint32_t max_expr;  /* the daemon's max_expr_bytes; 0: default */
} upload_log;

/* Read the upload of job id: Submit with input_bytes and no inline source,
 * then the chunks in order (each checked), then the drain's ping.  With
 * fail_after, the job's terminal error after that many chunks, and for
 * every chunk after it what voxd says: no such job. */
static void srv_upload(srv *s, uint64_t id, upload_log *u)
{
    Voxd__Request *r = srv_accept_job(s, id, 0);
    if (!r) return;
    const Voxd__Submit *sub = r->submit;
    size_t inline_len = sub->job_case == VOXD__SUBMIT__JOB_MESH ? sub->mesh->data.len
                                                                : sub->implicit->source.len;
    if (sub->input_bytes != u->n || inline_len) srv_bad(s, "submit does not declare its input");
    voxd__request__free_unpacked(r, NULL);
    uint8_t *got = malloc(u->n);
    size_t have = 0;
    while ((r = srv_read_any(s))) {
        if (r->msg_case == VOXD__REQUEST__MSG_PING) {
            send_pong(s, r->ping->token); /* the drain: the upload is over */
            voxd__request__free_unpacked(r, NULL);
            break;
        }
        if (r->msg_case != VOXD__REQUEST__MSG_INPUT || r->input->job_id != id) {
            srv_bad(s, "a request other than the job's input chunk");
        } else if (u->fail_after && u->chunks >= u->fail_after) {
            u->stray++;
            send_error(s, 0, VOXD__ERROR_CODE__INVALID_INPUT, "no job of this connection is waiting for input");
        } else {
            const Voxd__InputChunk *in = r->input;
            if (in->offset != have || in->data.len > u->max_piece || in->data.len > u->n - have)
                srv_bad(s, "an input chunk out of order or too long");
            else memcpy(got + have, in->data.data, in->data.len), have += in->data.len;
            if (++u->chunks == u->fail_after)
                send_error(s, id, VOXD__ERROR_CODE__INVALID_INPUT, "NUL byte in chunk 2");
        }
        voxd__request__free_unpacked(r, NULL);
    }
    if (!u->fail_after && (have != u->n || memcmp(got, u->want, u->n)))
        srv_bad(s, "the input assembled differs from the job's");
    free(got);
}

static void s_upload(srv *s)
{
    upload_log *u = s->arg;
    s->hello_max_frame = 4096;
    s->hello_chunk = 1024;
    s->hello_max_expr = u->max_expr;
    srv_hello(s);
    srv_upload(s, 9, u);
    if (u->fail_after) {
        srv_drain(s);
        return;
    }
    uint32_t crc;
    uint8_t *b = make_result(5000, 9, &crc);
    send_result(s, 9, b, 5000, 1000);
    send_summary(s, 9, 5000, crc);
    free(b);
    srv_drain(s);
}

static char *long_expr(size_t n)
{
    char *e = malloc(n + 1);
    for (size_t i = 0; i < n; i++) e[i] = (char)('a' + i % 26);
    e[n] = '\0';
    return e;
}

/* An expression over the daemon's max_frame goes as InputChunks of its
 * chunk_size, in order, after the Accepted; the job then runs as any. */
Test(libvox, input_over_a_frame_goes_in_chunks)
{
    char *expr = long_expr(LONG_EXPR);
    upload_log u = {.want = expr, .n = LONG_EXPR, .max_piece = 1024};
    srv *s = srv_new(s_upload, &u);
    vox_client *c = start(s, 5000);
    vox_job j = {.kind = VOX_JOB_IMPLICIT,
                 .implicit = {.source = expr, .domain = {-1, 1, -1, 1, -1, 1}, .res = 64}};
    uint64_t id = 0;
    vox_error e;
    cr_assert_eq(vox_submit_job(c, &j, &id, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(id, 9);
    uint8_t *buf;
    size_t n;
    cr_expect_eq(vox_receive_buffer(c, id, &buf, &n, NULL, NULL, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(n, 5000);
    free(buf);
    vox_close(c);
    srv_finish(s);
    cr_expect_eq(u.chunks, (LONG_EXPR + 1023) / 1024);
    free(expr);
}

/* inline_max sends even a short expression as input; vox_submit goes
 * through the same path. */
Test(libvox, inline_max_option)
{
    upload_log u = {.want = sphere.source, .n = strlen(sphere.source), .max_piece = 1024};
    srv *s = srv_new(s_upload, &u);
    vox_options o = {.timeout_ms = 5000, .inline_max = 8};
    vox_client *c = start_opts(s, &o);
    uint64_t id = 0;
    vox_error e;
    cr_assert_eq(vox_submit(c, &sphere, &id, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(vox_receive_file(c, id, out_path("out.vod"), NULL, NULL, NULL, &e), 0, "%s",
                 e.message);
    vox_close(c);
    srv_finish(s);
    cr_expect_eq(u.chunks, 1);
}

/* The daemon ends the job during its upload: the client stops sending
 * (the input, 4 MB, is far more than the socket holds), the daemon's "no
 * such job" for the chunks already sent are drained before the call
 * returns (they are no answer to the next request), and the job's error
 * comes from receive. */
#define HUGE_EXPR (4u << 20)
Test(libvox, job_ended_during_its_upload)
{
    char *expr = long_expr(HUGE_EXPR);
    upload_log u = {.want = expr, .n = HUGE_EXPR, .max_piece = 1024, .fail_after = 2,
                    .max_expr = 16u << 20};
    srv *s = srv_new(s_upload, &u);
    vox_client *c = start(s, 5000);
    vox_job j = {.kind = VOX_JOB_IMPLICIT,
                 .implicit = {.source = expr, .domain = {-1, 1, -1, 1, -1, 1}, .res = 64}};
    uint64_t id = 0;
    vox_error e;
    cr_assert_eq(vox_submit_job(c, &j, &id, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "a stray error answered the ping: %s", e.message);
    uint8_t *buf = NULL;
    size_t n;
    cr_expect_eq(vox_receive_buffer(c, id, &buf, &n, NULL, NULL, NULL, &e), VOX_EINVALID_INPUT);
    cr_expect(strstr(e.message, "NUL byte in chunk 2"), "%s", e.message);
    cr_expect_null(buf);
    vox_close(c);
    srv_finish(s);
    cr_expect_lt(u.chunks + u.stray, (HUGE_EXPR + 1023) / 1024, "the client sent all %d chunks",
                 u.chunks + u.stray);
    free(expr);
}

/* ---------------------------------------------------------------- mesh jobs */

/* A small binary "file": every byte value, NULs included (the daemon, not
 * libvox, parses it). */
static uint8_t *mesh_bytes(size_t n)
{
    uint8_t *b = malloc(n);
    for (size_t i = 0; i < n; i++) b[i] = (uint8_t)(i * 7);
    return b;
}

static const vox_mesh bunny = {
    .format = VOX_MESH_FORMAT_AUTO, .source_name = "models/bunny.stl",
    .mode = VOX_MESH_MODE_CONSERVATIVE, .repair = VOX_MESH_REPAIR_WINDING,
    .supersample = 4, .fit = 1, .pad = 3, .domain = {-1, 1, -2, 2, -3, 3}, .res = 100,
};

/* Two mesh jobs inline: the Submit carries the file's bytes and every
 * option as the protocol says (the fitted one its pad and no domain, the
 * other its domain and no pad). */
static void s_mesh_inline(srv *s)
{
    const uint8_t *want = s->arg;
    srv_hello(s);
    for (uint64_t id = 40; id < 42; id++) {
        Voxd__Request *r = srv_accept_job(s, id, 0);
        if (!r) return;
        const Voxd__Submit *sub = r->submit;
        const Voxd__Mesh *m = sub->job_case == VOXD__SUBMIT__JOB_MESH ? sub->mesh : NULL;
        int fit = id == 40;
        if (!m || sub->input_bytes || m->data.len != 300 || memcmp(m->data.data, want, 300))
            srv_bad(s, "the mesh is not inline as it was given");
        else if (m->format != VOXD__MESH_FORMAT__MESH_FORMAT_UNSPECIFIED ||
                 m->mode != VOXD__MESH_MODE__MESH_MODE_CONSERVATIVE ||
                 m->repair != VOXD__MESH_REPAIR__MESH_REPAIR_WINDING || m->supersample != 4 ||
                 m->res != 100 || sub->channel != VOXD__CHANNEL__CHANNEL_DENSITY)
            srv_bad(s, "the mesh's options are not the job's");
        else if (m->source_name.len != 16 || memcmp(m->source_name.data, "models/bunny.stl", 16))
            srv_bad(s, "the mesh's source_name is not the job's");
        else if (fit ? m->pad != 3 || m->n_domain : m->pad || m->n_domain != 6 || m->domain[3] != 2)
            srv_bad(s, "the fitted job has a domain, or the other a pad");
        voxd__request__free_unpacked(r, NULL);
        uint32_t crc;
        uint8_t *b = make_result(2000, (uint32_t)id, &crc);
        send_result(s, id, b, 2000, 1000);
        send_summary(s, id, 2000, crc);
        free(b);
    }
    srv_drain(s);
}

Test(libvox, mesh_job_inline_with_its_options)
{
    uint8_t *data = mesh_bytes(300);
    srv *s = srv_new(s_mesh_inline, data);
    vox_client *c = start(s, 5000);
    vox_job j = {.kind = VOX_JOB_MESH, .mesh = bunny, .channel = VOX_CHANNEL_DENSITY};
    j.mesh.data = data, j.mesh.len = 300;
    vox_error e;
    for (uint64_t want = 40; want < 42; want++) {
        uint64_t id = 0;
        cr_assert_eq(vox_submit_job(c, &j, &id, NULL, &e), 0, "%s", e.message);
        cr_expect_eq(id, want);
        cr_expect_eq(vox_receive_file(c, id, out_path("m.vod"), NULL, NULL, NULL, &e), 0, "%s",
                     e.message);
        j.mesh.fit = 0; /* the second: its domain, its pad not sent */
    }
    vox_close(c);
    srv_finish(s);
    free(data);
}

/* A mesh file over the daemon's max_frame goes as InputChunks, bytes as
 * they are (NULs too). */
Test(libvox, mesh_over_a_frame_goes_in_chunks)
{
    uint8_t *data = mesh_bytes(9000);
    upload_log u = {.want = (const char *)data, .n = 9000, .max_piece = 1024};
    srv *s = srv_new(s_upload, &u);
    vox_client *c = start(s, 5000);
    vox_job j = {.kind = VOX_JOB_MESH, .mesh = bunny};
    j.mesh.data = data, j.mesh.len = 9000;
    uint64_t id = 0;
    vox_error e;
    cr_assert_eq(vox_submit_job(c, &j, &id, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(id, 9);
    cr_expect_eq(vox_receive_file(c, id, out_path("m.vod"), NULL, NULL, NULL, &e), 0, "%s",
                 e.message);
    vox_close(c);
    srv_finish(s);
    cr_expect_eq(u.chunks, (9000 + 1023) / 1024);
    free(data);
}

static void s_small_mesh_limit(srv *s)
{
    s->hello_max_mesh = 8192;
    s->hello_max_frame = 4096;
    s->hello_chunk = 4000;
    s->hello_max_input = 6000;
    srv_hello(s);
    srv_drain(s); /* the oversized submits never arrive; a ping does */
}

/* A mesh over max_mesh_bytes, or one that must go as input and is over
 * max_input_bytes, is refused here, unsent. */
Test(libvox, mesh_over_the_limits_is_refused_unsent)
{
    srv *s = srv_new(s_small_mesh_limit, NULL);
    vox_client *c = start(s, 5000);
    uint8_t *data = mesh_bytes(9000);
    vox_job j = {.kind = VOX_JOB_MESH, .mesh = bunny};
    j.mesh.data = data, j.mesh.len = 9000;
    uint64_t id;
    vox_error e;
    cr_expect_eq(vox_submit_job(c, &j, &id, NULL, &e), VOX_ELIMIT_EXCEEDED);
    cr_expect(strstr(e.message, "mesh is 9000 bytes, over this server's max_mesh_bytes of 8192"),
              "%s", e.message);
    j.mesh.len = 7000;
    cr_expect_eq(vox_submit_job(c, &j, &id, NULL, &e), VOX_ELIMIT_EXCEEDED);
    cr_expect(strstr(e.message, "7000 bytes, over this server's max_input_bytes of 6000"), "%s",
              e.message);
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "%s", e.message);
    vox_close(c);
    srv_finish(s);
    free(data);
}

Test(libvox, unwritable_output_fails_at_once)
{
    srv *s = srv_new(s_happy, NULL);
    vox_client *c = start(s, 5000);
    uint64_t id = submit(c, 7);
    vox_error e;
    cr_expect_eq(vox_receive_file(c, id, "/nonexistent/dir/x.vod", NULL, NULL, NULL, &e), -ENOENT);
    cr_expect(strstr(e.message, "cannot create /nonexistent/dir/x.vod"), "%s", e.message);
    /* The job was cancelled; what still comes of it is dropped, and the
     * connection goes on. */
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(vox_receive_file(c, id, out_path("x.vod"), NULL, NULL, NULL, &e), -EINVAL);
    vox_close(c);
    srv_finish(s);
    cr_expect(s_happy_saw_cancel, "the job was not cancelled");
}

/* A job dropped while its result streams: the rest is discarded, checked,
 * and the job freed at its end; the next job is received whole. */
static void s_drop_then_next(srv *s)
{
    srv_hello(s);
    Voxd__Request *r = srv_accept_job(s, 30, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    r = srv_accept_job(s, 31, 0);
    if (r) voxd__request__free_unpacked(r, NULL);
    uint32_t crc;
    uint8_t *b = make_result(9000, 30, &crc);
    send_result(s, 30, b, 4000, 1000);
    r = srv_expect(s, VOXD__REQUEST__MSG_CANCEL); /* the drop */
    if (r) voxd__request__free_unpacked(r, NULL);
    for (size_t off = 4000; off < 9000; off += 1000) send_chunk(s, 30, off, b + off, 1000);
    send_summary(s, 30, 9000, crc); /* it finished before the cancel */
    send_error(s, 30, VOXD__ERROR_CODE__INVALID_INPUT, "no job 30"); /* the cancel's answer */
    free(b);
    b = make_result(5000, 31, &crc);
    send_result(s, 31, b, 5000, 999);
    send_summary(s, 31, 5000, crc);
    free(b);
    srv_drain(s);
}

Test(libvox, dropped_job_is_drained)
{
    srv *s = srv_new(s_drop_then_next, NULL);
    vox_client *c = start(s, 5000);
    uint64_t a = submit(c, 30), b = submit(c, 31);
    vox_error e;
    cr_expect_eq(vox_receive_file(c, a, "/nonexistent/dir/x.vod", NULL, NULL, NULL, &e), -ENOENT);
    uint8_t *buf;
    size_t len;
    cr_assert_eq(vox_receive_buffer(c, b, &buf, &len, NULL, NULL, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(len, 5000);
    free(buf);
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "%s", e.message);
    vox_close(c);
    srv_finish(s);
}

/* ---------------------------------------------------------------- the socket */

static void set_sun_path(struct sockaddr_un *sa, const char *path)
{
    cr_assert_lt(strlen(path), sizeof sa->sun_path);
    memcpy(sa->sun_path, path, strlen(path) + 1);
}

Test(libvox, no_daemon)
{
    vox_client *c = (vox_client *)1;
    vox_error e;
    cr_expect_eq(vox_connect(out_path("none.sock"), NULL, &c, &e), -ENOENT);
    cr_expect_null(c);
    cr_expect(strstr(e.message, "none.sock"), "%s", e.message);
    /* A socket file nobody listens on (a daemon that died). */
    int fd = socket(AF_UNIX, SOCK_STREAM, 0);
    struct sockaddr_un sa = {.sun_family = AF_UNIX};
    set_sun_path(&sa, out_path("dead.sock"));
    cr_assert_eq(bind(fd, (struct sockaddr *)&sa, sizeof sa), 0);
    close(fd);
    cr_expect_eq(vox_connect(out_path("dead.sock"), NULL, &c, &e), -ECONNREFUSED);
    cr_expect(strstr(e.message, "connection refused"), "%s", e.message);
    char longp[200];
    memset(longp, 'a', sizeof longp - 1);
    longp[sizeof longp - 1] = '\0';
    cr_expect_eq(vox_connect(longp, NULL, &c, &e), -ENAMETOOLONG);
}

Test(libvox, over_a_unix_socket_path)
{
    srv *s = srv_new(s_happy, NULL);
    int lfd = socket(AF_UNIX, SOCK_STREAM, 0);
    struct sockaddr_un sa = {.sun_family = AF_UNIX};
    set_sun_path(&sa, out_path("voxd.sock"));
    cr_assert_eq(bind(lfd, (struct sockaddr *)&sa, sizeof sa), 0);
    cr_assert_eq(listen(lfd, 4), 0);
    s->listen_fd = lfd;
    cr_assert_eq(pthread_create(&s->th, NULL, srv_main, s), 0);
    vox_client *c;
    vox_error e;
    cr_assert_eq(vox_connect(out_path("voxd.sock"), NULL, &c, &e), 0, "%s", e.message);
    uint64_t id = submit(c, 7);
    cr_expect_eq(vox_receive_file(c, id, out_path("out.vod"), NULL, NULL, NULL, &e), 0, "%s",
                 e.message);
    vox_close(c);
    srv_finish(s);
    close(lfd);
    unlink(out_path("voxd.sock"));
}

/* ---------------------------------------------------------------- a real daemon */

/* Each limit's test value: its default moved by one, within its range. */
#define TEST_VALUE(def, max) ((def) < (max) ? (def) + 1 : (def) - 1)

/* The voxd built beside this test: build/V/voxd for build/V/tests/test_libvox. */
static void voxd_path(char *buf, size_t len)
{
    char exe[4096];
    ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
    cr_assert_gt(n, 0);
    exe[n] = '\0';
    for (int up = 0; up < 2; up++) *strrchr(exe, '/') = '\0';
    snprintf(buf, len, "%s/voxd", exe);
    cr_assert_eq(access(buf, X_OK), 0, "no voxd at %s (make builds it)", buf);
}

/* voxd on sock with conf, dying with this test; its pid. */
static pid_t start_voxd(const char *conf, const char *sock)
{
    char voxd[4096 + 8];
    voxd_path(voxd, sizeof voxd);
    pid_t pid = fork();
    cr_assert_geq(pid, 0);
    if (pid == 0) {
        prctl(PR_SET_PDEATHSIG, SIGTERM); /* TERM: it removes its socket and segment */
        int null = open("/dev/null", O_WRONLY);
        dup2(null, 1);
        execl(voxd, "voxd", "--config", conf, "--socket", sock, "--workers", "1", (char *)NULL);
        _exit(127);
    }
    return pid;
}

static vox_client *connect_when_up(const char *sock, const vox_options *o)
{
    vox_client *c = NULL;
    vox_error e = {0};
    for (int i = 0; i < 300; i++) {
        if (vox_connect(sock, o, &c, &e) == 0) return c;
        usleep(100000);
    }
    cr_assert_fail("no voxd answering on %s: %s", sock, e.message);
    return NULL;
}

/* Every limit of the table reaches vox_server_info from a real daemon's
 * config, max_csg_nodes and max_input_bytes included; and a job sent in
 * chunks comes back with the daemon's grid, the one grid_make
 * gives. */
Test(libvox, server_info_and_grid_from_a_real_daemon, .timeout = 120)
{
    char conf[256];
    snprintf(conf, sizeof conf, "%s", out_path("voxd.conf"));
    FILE *f = fopen(conf, "w");
    cr_assert_not_null(f);
    fputs("shm_size 64M\n", f);
#define CONF_LINE(name, type, def, min, max, unit, doc) \
    fprintf(f, "%s %llu\n", #name, (unsigned long long)TEST_VALUE(def, max));
    VOX_LIMITS(CONF_LINE)
#undef CONF_LINE
    fclose(f);
    char sock[256];
    snprintf(sock, sizeof sock, "%s", out_path("voxd.sock"));
    pid_t pid = start_voxd(conf, sock);

    vox_options o = {.timeout_ms = 30000, .inline_max = 4}; /* every input in chunks */
    vox_client *c = connect_when_up(sock, &o);
    vox_server_info i;
    vox_server(c, &i);
#define EXPECT_LIMIT(name, type, def, min, max, unit, doc)                                  \
    cr_expect_eq((uint64_t)i.name, (uint64_t)TEST_VALUE(def, max), "%s %llu", #name, \
                 (unsigned long long)i.name);
    VOX_LIMITS(EXPECT_LIMIT)
#undef EXPECT_LIMIT
    cr_expect_eq(i.max_csg_nodes, 255);
    cr_expect_eq(i.max_input_bytes, (64u << 20) + 1);

    vox_job j = {.kind = VOX_JOB_IMPLICIT,
                 .implicit = {.source = sphere.source, .domain = {-1, 1, -0.3, 0.3, -0.1, 0.15},
                              .res = 37}};
    uint64_t id;
    vox_error e;
    cr_assert_eq(vox_submit_job(c, &j, &id, NULL, &e), 0, "%s", e.message);
    vox_summary sum;
    cr_assert_eq(vox_receive_file(c, id, out_path("g.vod"), NULL, NULL, &sum, &e), 0, "%s",
                 e.message);
    double lo[3] = {-1, -0.3, -0.1}, hi[3] = {1, 0.3, 0.15};
    grid_spec g;
    char why[256];
    cr_assert_eq(grid_make(lo, hi, 37, &g, why, sizeof why), 0, "%s", why);
    for (int a = 0; a < 3; a++) {
        cr_expect_eq(sum.grid[a], g.res[a], "axis %d: %u, want %u", a, sum.grid[a], g.res[a]);
        cr_expect(sum.origin[a] == g.lo[a], "axis %d origin %g, want %g", a, sum.origin[a],
                  g.lo[a]);
    }
    cr_expect_eq(sum.depth, (uint32_t)g.depth);
    cr_expect(sum.voxel_size == g.vs, "voxel_size %g, want %g", sum.voxel_size, g.vs);
    cr_expect_gt(sum.voxels, 0);
    vox_close(c);
    kill(pid, SIGTERM);
    int st;
    cr_expect_eq(waitpid(pid, &st, 0), pid);
    cr_expect(WIFEXITED(st) && WEXITSTATUS(st) == 0, "voxd ended with status %#x", st);
}
