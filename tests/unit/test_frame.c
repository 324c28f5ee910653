/* Framing: every message round-trips; a stream of frames decodes the same
 * whatever the read boundaries; bad lengths stop the decoder; memory grows
 * only with bytes received; truncation at EOF is seen; garbage unpacks to
 * NULL, and so does a message that would amplify into a huge heap. */
#include <criterion/criterion.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "frame.h"
#include "proto_check.h"

/* ---------------------------------------------------------------- samples */

#define N_REQ 7
#define N_REP 9

static uint8_t *enc_req(int i, size_t *len)
{
    Voxd__Request r = VOXD__REQUEST__INIT;
    Voxd__Hello h = VOXD__HELLO__INIT;
    Voxd__Submit s = VOXD__SUBMIT__INIT;
    Voxd__Implicit im = VOXD__IMPLICIT__INIT;
    Voxd__Mesh me = VOXD__MESH__INIT;
    Voxd__Csg cs = VOXD__CSG__INIT;
    Voxd__CsgNode n0 = VOXD__CSG_NODE__INIT, n1 = VOXD__CSG_NODE__INIT;
    Voxd__CsgNode *nodes[2] = {&n0, &n1};
    Voxd__Cancel c = VOXD__CANCEL__INIT;
    Voxd__Status st = VOXD__STATUS__INIT;
    Voxd__Ping p = VOXD__PING__INIT;
    static double dom[6] = {-1, 1, -2, 2, -3, 3};
    static double box[6] = {0, 1, 0, 1, 0, 1};
    static uint32_t kids[1] = {0};
    static const char src[] = "x^2 + y^2 + z^2 - 1";
    switch (i) {
    case 0:
        h.version = 1;
        h.client = "test";
        r.msg_case = VOXD__REQUEST__MSG_HELLO, r.hello = &h;
        break;
    case 1:
        im.source.data = (uint8_t *)src, im.source.len = strlen(src);
        im.n_domain = 6, im.domain = dom, im.res = 256;
        im.schedule = VOXD__SCHEDULE__SCHEDULE_PAPER;
        s.job_case = VOXD__SUBMIT__JOB_IMPLICIT, s.implicit = &im;
        s.channel = VOXD__CHANNEL__CHANNEL_OCCUPANCY, s.brick = 32;
        s.comp = VOXD__COMPRESSION__COMPRESSION_RUNL, s.hash = VOXD__HASH__HASH_XX32;
        r.msg_case = VOXD__REQUEST__MSG_SUBMIT, r.submit = &s;
        break;
    case 2:
        me.format = VOXD__MESH_FORMAT__MESH_FORMAT_OFF;
        me.data.data = (uint8_t *)"OFF\n0 0 0\n", me.data.len = 10;
        me.res = 64, me.pad = 1, me.repair = VOXD__MESH_REPAIR__MESH_REPAIR_VOTE;
        s.channel = VOXD__CHANNEL__CHANNEL_DENSITY;
        s.job_case = VOXD__SUBMIT__JOB_MESH, s.mesh = &me;
        r.msg_case = VOXD__REQUEST__MSG_SUBMIT, r.submit = &s;
        break;
    case 3:
        n0.op = VOXD__CSG_OP__CSG_PRIMITIVE, n0.primitive = VOXD__PRIMITIVE__PRIMITIVE_CONE;
        n0.n_size = 3, n0.size = box;
        n1.op = VOXD__CSG_OP__CSG_INVERSE, n1.n_children = 1, n1.children = kids;
        cs.n_nodes = 2, cs.nodes = nodes, cs.n_domain = 2, cs.domain = dom, cs.res = 32;
        s.job_case = VOXD__SUBMIT__JOB_CSG, s.csg = &cs;
        r.msg_case = VOXD__REQUEST__MSG_SUBMIT, r.submit = &s;
        break;
    case 4:
        c.job_id = 0x123456789abcull;
        r.msg_case = VOXD__REQUEST__MSG_CANCEL, r.cancel = &c;
        break;
    case 5: r.msg_case = VOXD__REQUEST__MSG_STATUS, r.status = &st; break;
    default:
        p.token = 0; /* an all-default body still makes a non-empty frame */
        r.msg_case = VOXD__REQUEST__MSG_PING, r.ping = &p;
        break;
    }
    uint8_t *buf;
    cr_assert_eq(proto_frame_encode_request(&r, &buf, len), 0, "request %d", i);
    return buf;
}

static uint8_t *enc_rep(int i, size_t *len)
{
    Voxd__Reply r = VOXD__REPLY__INIT;
    Voxd__HelloOk h = VOXD__HELLO_OK__INIT;
    Voxd__Limits l = VOXD__LIMITS__INIT;
    Voxd__Accepted a = VOXD__ACCEPTED__INIT;
    Voxd__Progress p = VOXD__PROGRESS__INIT;
    Voxd__ResultChunk c = VOXD__RESULT_CHUNK__INIT;
    Voxd__Summary s = VOXD__SUMMARY__INIT;
    Voxd__Error e = VOXD__ERROR__INIT;
    Voxd__StatusReply st = VOXD__STATUS_REPLY__INIT;
    Voxd__WorkerStatus w0 = VOXD__WORKER_STATUS__INIT, w1 = VOXD__WORKER_STATUS__INIT;
    Voxd__WorkerStatus *ws[2] = {&w0, &w1};
    Voxd__RunningJob rj = VOXD__RUNNING_JOB__INIT;
    Voxd__Pong po = VOXD__PONG__INIT;
    static uint8_t data[3000];
    switch (i) {
    case 0:
        l.max_frame = 1 << 20, l.chunk_size = 256 << 10, l.max_res = 4096;
        l.max_result_bytes = 4ull << 30;
        h.version = 1, h.server = "voxd test", h.limits = &l, h.workers = 4;
        r.msg_case = VOXD__REPLY__MSG_HELLO_OK, r.hello_ok = &h;
        break;
    case 1:
        a.job_id = 7, a.queue_position = 3;
        r.msg_case = VOXD__REPLY__MSG_ACCEPTED, r.accepted = &a;
        break;
    case 2:
        p.job_id = 7, p.fraction = 0.25, p.level = 5, p.voxels = 1000;
        r.msg_case = VOXD__REPLY__MSG_PROGRESS, r.progress = &p;
        break;
    case 3:
        for (size_t k = 0; k < sizeof data; k++) data[k] = (uint8_t)(k * 7);
        c.job_id = 7, c.offset = 65536, c.data.data = data, c.data.len = sizeof data;
        r.msg_case = VOXD__REPLY__MSG_CHUNK, r.chunk = &c;
        break;
    case 4:
        s.job_id = 7, s.voxels = 1234567, s.bricks = 99, s.file_bytes = 123456;
        s.crc32 = 0xdeadbeef, s.seconds_queued = 0.5, s.seconds_voxelize = 2;
        s.seconds_write = 0.25;
        r.msg_case = VOXD__REPLY__MSG_SUMMARY, r.summary = &s;
        break;
    case 5:
        e.job_id = 7, e.code = VOXD__ERROR_CODE__TIMEOUT, e.message = "too slow";
        r.msg_case = VOXD__REPLY__MSG_ERROR, r.error = &e;
        break;
    case 6:
        w0.pid = 100, w0.cpu = 0, w0.state = VOXD__WORKER_STATE__WORKER_STATE_BUSY;
        w1.pid = 101, w1.cpu = -1, w1.state = VOXD__WORKER_STATE__WORKER_STATE_IDLE;
        w1.jobs = 3, w1.voxels_per_second = 1e6;
        rj.job_id = 7, rj.uid = 1000, rj.fraction = 0.5, rj.seconds = 3;
        st.uptime = 10, st.n_workers = 2, st.workers = ws, st.queued = 2;
        st.running = &rj, st.clients = 3;
        r.msg_case = VOXD__REPLY__MSG_STATUS, r.status = &st;
        break;
    case 7:
        po.token = UINT64_MAX;
        r.msg_case = VOXD__REPLY__MSG_PONG, r.pong = &po;
        break;
    default:
        st.uptime = 1; /* idle daemon: no workers listed, nothing running */
        r.msg_case = VOXD__REPLY__MSG_STATUS, r.status = &st;
        break;
    }
    uint8_t *buf;
    cr_assert_eq(proto_frame_encode_reply(&r, &buf, len), 0, "reply %d", i);
    return buf;
}

static uint32_t be32(const uint8_t *p)
{
    return (uint32_t)p[0] << 24 | (uint32_t)p[1] << 16 | (uint32_t)p[2] << 8 | p[3];
}

/* Re-pack an unpacked message; must equal the original bytes. */
static void assert_repacks(const ProtobufCMessage *m, const uint8_t *orig, size_t len)
{
    size_t n = protobuf_c_message_get_packed_size(m);
    cr_assert_eq(n, len);
    uint8_t *b = malloc(n);
    protobuf_c_message_pack(m, b);
    cr_assert_eq(memcmp(b, orig, n), 0);
    free(b);
}

/* ---------------------------------------------------------------- round trips */

Test(frame, every_request_round_trips)
{
    for (int i = 0; i < N_REQ; i++) {
        size_t len;
        uint8_t *buf = enc_req(i, &len);
        cr_assert_gt(len, PROTO_FRAME_HEADER_BYTES);
        cr_assert_eq(be32(buf), len - PROTO_FRAME_HEADER_BYTES, "header of request %d", i);

        proto_frame_decoder d;
        proto_frame_decoder_init(&d, PROTO_FRAME_DEFAULT_MAX);
        const uint8_t *p = buf;
        size_t n = len;
        proto_frame_view f;
        cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), 1);
        cr_assert_eq(n, 0);
        cr_assert_eq(f.len, len - PROTO_FRAME_HEADER_BYTES);
        Voxd__Request *r = proto_frame_unpack_request(f.data, f.len);
        cr_assert_not_null(r, "request %d", i);
        assert_repacks(&r->base, f.data, f.len);
        voxd__request__free_unpacked(r, NULL);
        cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), 0);
        cr_assert_eq(proto_frame_decoder_finish(&d), 0);
        proto_frame_decoder_free(&d);
        free(buf);
    }
}

Test(frame, every_reply_round_trips)
{
    for (int i = 0; i < N_REP; i++) {
        size_t len;
        uint8_t *buf = enc_rep(i, &len);
        cr_assert_eq(be32(buf), len - PROTO_FRAME_HEADER_BYTES);
        Voxd__Reply *r = proto_frame_unpack_reply(buf + 4, len - 4);
        cr_assert_not_null(r, "reply %d", i);
        assert_repacks(&r->base, buf + 4, len - 4);
        if (i == 3) {
            cr_assert_eq(r->msg_case, VOXD__REPLY__MSG_CHUNK);
            cr_assert_eq(r->chunk->offset, 65536);
            cr_assert_eq(r->chunk->data.len, 3000);
            cr_assert_eq(r->chunk->data.data[2999], (uint8_t)(2999 * 7));
        }
        if (i == 6) {
            cr_assert_eq(r->status->n_workers, 2);
            cr_assert_eq(r->status->workers[1]->cpu, -1);
            cr_assert_eq(r->status->running->uid, 1000);
        }
        voxd__reply__free_unpacked(r, NULL);
        free(buf);
    }
}

Test(frame, fields_survive_the_trip)
{
    size_t len;
    uint8_t *buf = enc_req(1, &len);
    Voxd__Request *r = proto_frame_unpack_request(buf + 4, len - 4);
    cr_assert_not_null(r);
    cr_assert_eq(r->msg_case, VOXD__REQUEST__MSG_SUBMIT);
    Voxd__Implicit *im = r->submit->implicit;
    cr_assert_eq(r->submit->job_case, VOXD__SUBMIT__JOB_IMPLICIT);
    cr_assert_eq(im->source.len, strlen("x^2 + y^2 + z^2 - 1"));
    cr_assert_eq(memcmp(im->source.data, "x^2", 3), 0);
    cr_assert_eq(im->n_domain, 6);
    cr_assert_eq(im->domain[5], 3.0);
    cr_assert_eq(im->res, 256);
    cr_assert_eq(r->submit->brick, 32);
    cr_assert_eq(r->submit->hash, VOXD__HASH__HASH_XX32);
    voxd__request__free_unpacked(r, NULL);
    free(buf);
}

Test(frame, empty_message_cannot_be_framed)
{
    Voxd__Request r = VOXD__REQUEST__INIT;
    uint8_t *buf = NULL;
    size_t len = 0;
    cr_assert_eq(proto_frame_encode_request(&r, &buf, &len), -EINVAL);
    cr_assert_null(buf);
}

/* ---------------------------------------------------------------- splits */

typedef struct {
    uint8_t *data;
    size_t len;
    size_t ends[N_REQ + N_REP]; /* offset where each frame's message ends */
    int n;
} stream;

static void stream_make(stream *s)
{
    s->data = NULL, s->len = 0, s->n = 0;
    for (int i = 0; i < N_REQ + N_REP; i++) {
        size_t len;
        uint8_t *b = i < N_REQ ? enc_req(i, &len) : enc_rep(i - N_REQ, &len);
        s->data = realloc(s->data, s->len + len);
        memcpy(s->data + s->len, b, len);
        s->len += len;
        s->ends[s->n++] = s->len;
        free(b);
    }
}

/* Feed the stream in pieces given by cuts (sorted offsets) and check every
 * frame comes out once, whole, in order. */
static void feed_with_cuts(const stream *s, const size_t *cuts, int ncuts)
{
    proto_frame_decoder d;
    proto_frame_decoder_init(&d, PROTO_FRAME_DEFAULT_MAX);
    int got = 0;
    size_t start = 0;
    for (int c = 0; c <= ncuts; c++) {
        size_t end = c < ncuts ? cuts[c] : s->len;
        const uint8_t *p = s->data + start;
        size_t n = end - start;
        proto_frame_view f;
        int rc;
        while ((rc = proto_frame_decode(&d, &p, &n, &f)) == 1) {
            cr_assert_lt(got, s->n);
            size_t fend = s->ends[got];
            cr_assert_eq(memcmp(f.data, s->data + fend - f.len, f.len), 0,
                         "frame %d differs", got);
            cr_assert_eq(be32(s->data + fend - f.len - 4), f.len);
            got++;
        }
        cr_assert_eq(rc, 0);
        cr_assert_eq(n, 0, "input not consumed");
        start = end;
    }
    cr_assert_eq(got, s->n, "got %d frames of %d", got, s->n);
    cr_assert_eq(proto_frame_decoder_finish(&d), 0);
    proto_frame_decoder_free(&d);
}

Test(frame, split_at_every_byte_boundary)
{
    stream s;
    stream_make(&s);
    for (size_t k = 0; k <= s.len; k++) feed_with_cuts(&s, &k, 1);
    free(s.data);
}

Test(frame, byte_by_byte)
{
    stream s;
    stream_make(&s);
    size_t *cuts = malloc(s.len * sizeof *cuts);
    for (size_t k = 0; k < s.len; k++) cuts[k] = k + 1;
    feed_with_cuts(&s, cuts, (int)s.len - 1);
    free(cuts);
    free(s.data);
}

Test(frame, random_splits)
{
    stream s;
    stream_make(&s);
    srand(42);
    for (int t = 0; t < 200; t++) {
        size_t cuts[16];
        int n = rand() % 16;
        for (int i = 0; i < n; i++) cuts[i] = (size_t)rand() % (s.len + 1);
        for (int i = 1; i < n; i++) /* insertion sort */
            for (int j = i; j > 0 && cuts[j - 1] > cuts[j]; j--) {
                size_t x = cuts[j];
                cuts[j] = cuts[j - 1], cuts[j - 1] = x;
            }
        feed_with_cuts(&s, cuts, n);
    }
    free(s.data);
}

Test(frame, whole_frame_in_one_read_is_not_copied)
{
    size_t len;
    uint8_t *buf = enc_req(4, &len);
    proto_frame_decoder d;
    proto_frame_decoder_init(&d, PROTO_FRAME_DEFAULT_MAX);
    const uint8_t *p = buf;
    size_t n = len;
    proto_frame_view f;
    cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), 1);
    cr_assert_eq(f.data, buf + 4);
    cr_assert_eq(d.cap, 0);
    proto_frame_decoder_free(&d);
    free(buf);
}

/* ---------------------------------------------------------------- lengths */

static int feed_header(proto_frame_decoder *d, uint32_t n)
{
    uint8_t h[4] = {(uint8_t)(n >> 24), (uint8_t)(n >> 16), (uint8_t)(n >> 8), (uint8_t)n};
    const uint8_t *p = h;
    size_t len = 4;
    proto_frame_view f;
    return proto_frame_decode(d, &p, &len, &f);
}

Test(frame, length_zero_is_a_protocol_error_and_sticks)
{
    proto_frame_decoder d;
    proto_frame_decoder_init(&d, PROTO_FRAME_DEFAULT_MAX);
    cr_assert_eq(feed_header(&d, 0), -EPROTO);
    char msg[128];
    cr_assert_str_eq(proto_frame_decoder_strerror(&d, -EPROTO, msg, sizeof msg), "frame length 0");
    /* Refuses more input, consuming none. */
    uint8_t more[8] = {0, 0, 0, 1, 0x28, 0};
    const uint8_t *p = more;
    size_t n = sizeof more;
    proto_frame_view f;
    cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), -EPROTO);
    cr_assert_eq(n, sizeof more);
    cr_assert_eq(proto_frame_decoder_finish(&d), -EPROTO);
    proto_frame_decoder_free(&d);
}

Test(frame, length_max_is_accepted)
{
    const uint32_t max = 8192;
    proto_frame_decoder d;
    proto_frame_decoder_init(&d, max);
    uint8_t *buf = malloc(max + 4);
    buf[0] = 0, buf[1] = 0, buf[2] = max >> 8, buf[3] = max & 0xff;
    for (uint32_t i = 0; i < max; i++) buf[4 + i] = (uint8_t)i;
    /* In two reads, so the decoder must buffer it. */
    const uint8_t *p = buf;
    size_t n = 100;
    proto_frame_view f;
    cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), 0);
    n = max + 4 - 100;
    cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), 1);
    cr_assert_eq(f.len, max);
    cr_assert_eq(memcmp(f.data, buf + 4, max), 0);
    cr_assert_leq(d.cap, max);
    proto_frame_decoder_free(&d);
    free(buf);
}

Test(frame, length_over_max_is_refused)
{
    const uint32_t lens[] = {8193, 0xFFFFFFFFu, 0x80000000u};
    for (size_t i = 0; i < 3; i++) {
        proto_frame_decoder d;
        proto_frame_decoder_init(&d, 8192);
        cr_assert_eq(feed_header(&d, lens[i]), -EMSGSIZE);
        cr_assert_eq(d.cap, 0);
        char msg[128], want[128];
        snprintf(want, sizeof want, "frame length %u is over the limit of 8192", lens[i]);
        cr_assert_str_eq(proto_frame_decoder_strerror(&d, -EMSGSIZE, msg, sizeof msg), want);
        cr_assert_eq(feed_header(&d, 10), -EMSGSIZE);
        proto_frame_decoder_free(&d);
    }
}

Test(frame, max_is_clamped_and_can_change)
{
    proto_frame_decoder d;
    proto_frame_decoder_init(&d, 1);
    cr_assert_eq(d.max, PROTO_FRAME_MIN_MAX);
    proto_frame_decoder_set_max(&d, 0xFFFFFFFFu);
    cr_assert_eq(d.max, PROTO_FRAME_LIMIT_MAX);
    proto_frame_decoder_set_max(&d, 5000);
    cr_assert_eq(feed_header(&d, 5001), -EMSGSIZE);
    proto_frame_decoder_free(&d);
}

/* ---------------------------------------------------------------- memory */

Test(frame, header_alone_allocates_nothing)
{
    proto_frame_decoder d;
    proto_frame_decoder_init(&d, PROTO_FRAME_LIMIT_MAX);
    cr_assert_eq(feed_header(&d, PROTO_FRAME_LIMIT_MAX), 0);
    cr_assert_eq(d.cap, 0, "allocated %zu bytes for a header", d.cap);
    cr_assert_null(d.buf);
    cr_assert_eq(proto_frame_decoder_pending(&d), 4);

    /* A trickle of bytes keeps the buffer proportional to what arrived. */
    static uint8_t chunk[10000];
    size_t total = 0;
    for (int i = 0; i < 20; i++) {
        const uint8_t *p = chunk;
        size_t n = sizeof chunk;
        proto_frame_view f;
        cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), 0);
        total += sizeof chunk;
        cr_assert_leq(d.cap, 2 * total + PROTO_FRAME_INITIAL_ALLOC, "cap %zu after %zu bytes",
                      d.cap, total);
    }
    cr_assert_eq(proto_frame_decoder_pending(&d), total + 4);
    proto_frame_decoder_free(&d);
}

Test(frame, first_byte_allocates_only_a_little)
{
    proto_frame_decoder d;
    proto_frame_decoder_init(&d, PROTO_FRAME_DEFAULT_MAX);
    uint8_t b[5] = {0, 0x10, 0, 0, 0x42}; /* length 1 MiB, then one byte */
    const uint8_t *p = b;
    size_t n = 5;
    proto_frame_view f;
    cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), 0);
    cr_assert_eq(d.cap, PROTO_FRAME_INITIAL_ALLOC);
    proto_frame_decoder_free(&d);
}

Test(frame, large_buffer_is_dropped_after_its_frame)
{
    const uint32_t len = 200000;
    proto_frame_decoder d;
    proto_frame_decoder_init(&d, PROTO_FRAME_DEFAULT_MAX);
    uint8_t *buf = calloc(1, len + 4);
    buf[1] = len >> 16, buf[2] = (len >> 8) & 0xff, buf[3] = len & 0xff;
    const uint8_t *p = buf;
    size_t n = 10;
    proto_frame_view f;
    cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), 0);
    n = len + 4 - 10;
    cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), 1);
    cr_assert_eq(d.cap, len); /* exactly the frame, not more */
    cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), 0);
    cr_assert_eq(d.cap, 0, "an idle connection keeps %zu bytes", d.cap);
    proto_frame_decoder_free(&d);
    free(buf);
}

/* ---------------------------------------------------------------- EOF */

Test(frame, truncated_frame_at_eof_is_detected)
{
    size_t len;
    uint8_t *buf = enc_req(1, &len);
    for (size_t cut = 1; cut < len; cut++) {
        proto_frame_decoder d;
        proto_frame_decoder_init(&d, PROTO_FRAME_DEFAULT_MAX);
        const uint8_t *p = buf;
        size_t n = cut;
        proto_frame_view f;
        cr_assert_eq(proto_frame_decode(&d, &p, &n, &f), 0);
        cr_assert_eq(proto_frame_decoder_pending(&d), cut);
        cr_assert_eq(proto_frame_decoder_finish(&d), -EPIPE, "cut at %zu", cut);
        char msg[128];
        cr_assert(strstr(proto_frame_decoder_strerror(&d, -EPIPE, msg, sizeof msg), "truncated"));
        proto_frame_decoder_free(&d);
    }
    free(buf);
}

/* ---------------------------------------------------------------- unpack */

Test(frame, garbage_unpacks_to_null)
{
    static const uint8_t bad[][6] = {
        {0xff, 0xff, 0xff, 0xff, 0xff, 0xff}, /* varint key that never ends */
        {0x12, 0x05, 0x01},                   /* submit: length past the end */
        {0x0a, 0x02, 0x08},                   /* hello: truncated inside */
        {0x0f, 0x00},                         /* wire type 7 does not exist */
        {0x00, 0x00},                         /* field number 0 */
    };
    static const size_t lens[] = {6, 3, 3, 2, 2};
    for (size_t i = 0; i < 5; i++) {
        cr_assert_null(proto_frame_unpack_request(bad[i], lens[i]), "garbage %zu", i);
        cr_assert_null(proto_frame_unpack_reply(bad[i], lens[i]), "garbage %zu", i);
    }
    /* A valid request cut short. */
    size_t len;
    uint8_t *buf = enc_req(1, &len);
    cr_assert_null(proto_frame_unpack_request(buf + 4, len - 5));
    free(buf);
}

/* Bytes of a varint. */
static size_t put_varint(uint8_t *p, uint64_t v)
{
    size_t n = 0;
    do {
        p[n++] = (uint8_t)((v & 0x7f) | (v > 0x7f ? 0x80 : 0));
        v >>= 7;
    } while (v);
    return n;
}

/* Request{submit{csg{nodes: count copies of node}}}. */
static uint8_t *csg_nodes(size_t count, const uint8_t *node, size_t node_len, size_t *len)
{
    size_t each = 2 + node_len, inner = each * count;
    uint8_t hdr[32], l3[10], l2[10];
    size_t h = 0;
    /* Submit.csg (field 3) holds the nodes; Request.submit (field 2) the Submit. */
    size_t k3 = put_varint(l3, inner);
    size_t n2 = 1 + k3 + inner;
    size_t k2 = put_varint(l2, n2);
    hdr[h++] = 0x12, memcpy(hdr + h, l2, k2), h += k2;
    hdr[h++] = 0x1a, memcpy(hdr + h, l3, k3), h += k3;
    uint8_t *b = malloc(h + inner);
    memcpy(b, hdr, h);
    for (size_t i = 0; i < count; i++) {
        uint8_t *q = b + h + each * i;
        q[0] = 0x0a, q[1] = (uint8_t)node_len;
        if (node_len) memcpy(q + 2, node, node_len);
    }
    *len = h + inner;
    return b;
}

Test(frame, unpack_refuses_heap_amplification)
{
    /* The smallest meaningful node, {op: INVERSE, children: [0]}, 7 wire
     * bytes: the most nodes a server may allow (max_csg_nodes' maximum,
     * the evaluator's PROTO_CSG_MAX_NODES) must still unpack. */
    static const uint8_t inverse[] = {0x08, 0x14, 0x12, 0x01, 0x00};
    size_t len;
    uint8_t *b = csg_nodes(PROTO_CSG_MAX_NODES, inverse, sizeof inverse, &len);
    cr_assert_leq(len, PROTO_FRAME_DEFAULT_MAX);
    Voxd__Request *r = proto_frame_unpack_request(b, len);
    cr_assert_not_null(r, "a legitimate node count must unpack");
    cr_assert_eq(r->submit->csg->n_nodes, PROTO_CSG_MAX_NODES);
    cr_assert_eq(r->submit->csg->nodes[PROTO_CSG_MAX_NODES - 1]->op, VOXD__CSG_OP__CSG_INVERSE);
    voxd__request__free_unpacked(r, NULL);
    free(b);

    /* Empty nodes, 2 wire bytes for ~130 bytes of heap each: 800 KB that
     * would unpack to ~50 MB is refused. */
    b = csg_nodes(400000, NULL, 0, &len);
    cr_assert_leq(len, PROTO_FRAME_DEFAULT_MAX);
    cr_assert_null(proto_frame_unpack_request(b, len));
    r = voxd__request__unpack(NULL, len, b); /* well-formed: only the budget refuses it */
    cr_assert_not_null(r);
    voxd__request__free_unpacked(r, NULL);
    free(b);
}
