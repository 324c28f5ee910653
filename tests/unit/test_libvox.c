/* libvox against a fake daemon (libvox_fixture.h): hello and its refusal, a
 * job's chunks to a file and to a buffer with the CRC checked and the file
 * renamed into place, progress, interleaved jobs, every typed error with its
 * message, results that do not check, protocol violations (wrong offset,
 * oversized chunk, unknown job, bad frames).  After a failure no file is left at
 * the output path nor beside it.  Silence, timeouts, cancel, status and ping:
 * test_libvox_wait.c; inputs, meshes, sockets and a real daemon:
 * test_libvox_input.c. */
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

TestSuite(libvox, .init = make_dir, .fini = remove_dir, .timeout = 30);

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
    /* libvox 0.1's call (a wrapper of vox_receive_to_file) */
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
    cr_expect_eq(vox_receive_to_file(c, id, out_path("again.vod"), NULL, &e), -EINVAL);
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
    vox_receive_opts ro = {.progress = on_prog, .ud = &pl};
    cr_assert_eq(vox_receive_to_file(c, id, out_path("p.vod"), &ro, &e), 0, "%s", e.message);
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
    /* libvox 0.1's call (a wrapper of vox_receive_to_buffer) */
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
    cr_assert_eq(vox_receive_to_buffer(c, b, &buf, &len, NULL, &e), 0, "%s", e.message);
    uint8_t *wb = make_result(30001, 11, NULL), *wa = make_result(50000, 10, NULL);
    cr_expect_eq(len, 30001);
    cr_expect(memcmp(buf, wb, len) == 0);
    free(buf);
    vox_summary sum;
    vox_receive_opts ro = {.sum = &sum};
    cr_assert_eq(vox_receive_to_file(c, a, out_path("a.vod"), &ro, &e), 0, "%s", e.message);
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
    cr_expect_eq(vox_receive_to_buffer(c, id, &buf, &len, NULL, &e), VOX_EWORKER_CRASHED);
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
    cr_expect_eq(vox_receive_to_buffer(c, id, &buf, &len, NULL, NULL), -EBADMSG);
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
