/* libvox's jobs and their input: limits checked before anything is sent,
 * expressions and meshes over a frame sent in chunks, a job ended during its
 * upload, an unwritable output, a dropped job drained; no daemon at all, a Unix
 * socket path, and a real voxd's server info and grid. */
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

#include "libvox_fixture.h"

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

TestSuite(libvox, .init = make_dir, .fini = remove_dir, .timeout = 30);

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
    cr_expect_eq(vox_receive_to_buffer(c, id, &buf, &n, NULL, &e), 0, "%s", e.message);
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
    cr_expect_eq(vox_receive_to_file(c, id, out_path("out.vod"), NULL, &e), 0, "%s",
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
    cr_expect_eq(vox_receive_to_buffer(c, id, &buf, &n, NULL, &e), VOX_EINVALID_INPUT);
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
        cr_expect_eq(vox_receive_to_file(c, id, out_path("m.vod"), NULL, &e), 0, "%s",
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
    cr_expect_eq(vox_receive_to_file(c, id, out_path("m.vod"), NULL, &e), 0, "%s",
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
    cr_expect_eq(vox_receive_to_file(c, id, "/nonexistent/dir/x.vod", NULL, &e), -ENOENT);
    cr_expect(strstr(e.message, "cannot create /nonexistent/dir/x.vod"), "%s", e.message);
    /* The job was cancelled; what still comes of it is dropped, and the
     * connection goes on. */
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(vox_ping(c, NULL, &e), 0, "%s", e.message);
    cr_expect_eq(vox_receive_to_file(c, id, out_path("x.vod"), NULL, &e), -EINVAL);
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
    cr_expect_eq(vox_receive_to_file(c, a, "/nonexistent/dir/x.vod", NULL, &e), -ENOENT);
    uint8_t *buf;
    size_t len;
    cr_assert_eq(vox_receive_to_buffer(c, b, &buf, &len, NULL, &e), 0, "%s", e.message);
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
    cr_expect_eq(vox_receive_to_file(c, id, out_path("out.vod"), NULL, &e), 0, "%s",
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
    vox_receive_opts ro = {.sum = &sum};
    cr_assert_eq(vox_receive_to_file(c, id, out_path("g.vod"), &ro, &e), 0, "%s", e.message);
    double lo[3] = {-1, -0.3, -0.1}, hi[3] = {1, 0.3, 0.15};
    grid_spec g;
    err_info why = {0};
    cr_assert_eq(grid_make(lo, hi, 37, &g, &why), 0, "%s", why.msg);
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
