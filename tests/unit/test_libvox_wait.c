/* libvox against a fake daemon that closes mid-result or goes silent: the
 * keepalive that tells a busy daemon from a hung one, the job timeout, replies
 * nobody asked for, cancellation (from a callback, of its own job, of another
 * connection's), status and ping. */
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

TestSuite(libvox, .init = make_dir, .fini = remove_dir, .timeout = 30);

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
            proto_frame_view f;
            while (proto_frame_decode(&s->dec, &q, &left, &f) == 1) {
                Voxd__Request *x = proto_frame_unpack_request(f.data, f.len);
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
    cr_expect_eq(vox_receive_to_file(c, id, out_path("slow.vod"), NULL, &e), 0, "%s",
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
    vox_receive_opts ro = {.progress = on_prog, .ud = &pl};
    cr_expect_eq(vox_receive_to_file(c, id, out_path("c.vod"), &ro, &e), VOX_ECANCELLED);
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
    cr_expect_eq(vox_receive_to_file(c, id, out_path("c.vod"), NULL, &e),
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
