/* The boundary validator on what a server says (proto_check_reply): hello_ok and
 * its limits against the table, the job replies' ids, progress, chunks,
 * summaries and their grid, errors and status; the error may be NULL. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "expr.h"
#include "frame.h"
#include "job_meta.h"
#include "proto_check.h"

#include "proto_fixture.h"

TestSuite(proto, .init = setup);

/* ---------------------------------------------------------------- replies */

typedef struct {
    Voxd__Reply r;
    union {
        Voxd__HelloOk hello_ok;
        Voxd__Accepted accepted;
        Voxd__Progress progress;
        Voxd__ResultChunk chunk;
        Voxd__Summary summary;
        Voxd__Error error;
        Voxd__StatusReply status;
        Voxd__Pong pong;
    } m;
    Voxd__Limits limits;
    Voxd__Grid grid;
    uint32_t grid_res[3];
    double grid_origin[3];
    Voxd__WorkerStatus w[2];
    Voxd__WorkerStatus *wp[2];
    Voxd__RunningJob running;
    uint8_t data[16];
} reply;

static void reply_init(reply *x, Voxd__Reply__MsgCase which)
{
    memset(x, 0, sizeof *x);
    x->r = (Voxd__Reply)VOXD__REPLY__INIT;
    x->r.msg_case = which;
    switch (which) {
    case VOXD__REPLY__MSG_HELLO_OK:
        x->m.hello_ok = (Voxd__HelloOk)VOXD__HELLO_OK__INIT;
        x->limits = (Voxd__Limits)VOXD__LIMITS__INIT;
        proto_limits_to_hello(&lim, &x->limits);
        x->m.hello_ok.version = 1, x->m.hello_ok.server = "voxd 0.1";
        x->m.hello_ok.limits = &x->limits, x->m.hello_ok.workers = 8;
        x->r.hello_ok = &x->m.hello_ok;
        break;
    case VOXD__REPLY__MSG_ACCEPTED:
        x->m.accepted = (Voxd__Accepted)VOXD__ACCEPTED__INIT;
        x->m.accepted.job_id = 1;
        x->r.accepted = &x->m.accepted;
        break;
    case VOXD__REPLY__MSG_PROGRESS:
        x->m.progress = (Voxd__Progress)VOXD__PROGRESS__INIT;
        x->m.progress.job_id = 1, x->m.progress.fraction = 1, x->m.progress.level = 12;
        x->r.progress = &x->m.progress;
        break;
    case VOXD__REPLY__MSG_CHUNK:
        x->m.chunk = (Voxd__ResultChunk)VOXD__RESULT_CHUNK__INIT;
        x->m.chunk.job_id = 1, x->m.chunk.offset = 0;
        x->m.chunk.data.data = x->data, x->m.chunk.data.len = sizeof x->data;
        x->r.chunk = &x->m.chunk;
        break;
    case VOXD__REPLY__MSG_SUMMARY:
        x->m.summary = (Voxd__Summary)VOXD__SUMMARY__INIT;
        x->m.summary.job_id = 1, x->m.summary.file_bytes = 64;
        /* res 100 on [-1,1] x [-0.5,0.5] x [-0.25,0.25] */
        x->grid = (Voxd__Grid)VOXD__GRID__INIT;
        x->grid_res[0] = 100, x->grid_res[1] = 50, x->grid_res[2] = 25;
        x->grid_origin[0] = -1, x->grid_origin[1] = -0.5, x->grid_origin[2] = -0.25;
        x->grid.res = x->grid_res, x->grid.n_res = 3, x->grid.depth = 7;
        x->grid.voxel_size = 0.02, x->grid.origin = x->grid_origin, x->grid.n_origin = 3;
        x->m.summary.grid = &x->grid;
        x->r.summary = &x->m.summary;
        break;
    case VOXD__REPLY__MSG_ERROR:
        x->m.error = (Voxd__Error)VOXD__ERROR__INIT;
        x->m.error.code = VOXD__ERROR_CODE__BUSY;
        x->m.error.message = "queue full (64 jobs)\n\ttry later";
        x->r.error = &x->m.error;
        break;
    case VOXD__REPLY__MSG_STATUS:
        x->m.status = (Voxd__StatusReply)VOXD__STATUS_REPLY__INIT;
        for (int i = 0; i < 2; i++) {
            x->w[i] = (Voxd__WorkerStatus)VOXD__WORKER_STATUS__INIT;
            x->w[i].pid = 100 + (uint32_t)i, x->w[i].cpu = i - 1;
            x->w[i].state = VOXD__WORKER_STATE__WORKER_STATE_IDLE;
            x->wp[i] = &x->w[i];
        }
        x->running = (Voxd__RunningJob)VOXD__RUNNING_JOB__INIT;
        x->running.job_id = 3, x->running.fraction = 0.5;
        x->m.status.workers = x->wp, x->m.status.n_workers = 2;
        x->m.status.running = &x->running;
        x->r.status = &x->m.status;
        break;
    default:
        x->m.pong = (Voxd__Pong)VOXD__PONG__INIT;
        x->r.pong = &x->m.pong;
        break;
    }
}

static void reply_refused(const reply *x, Voxd__ErrorCode code, const char *want)
{
    proto_error e;
    int rc = proto_check_reply(&x->r, &lim, &e);
    cr_assert_eq(rc, code == LIMIT ? -E2BIG : -EINVAL, "rc %d for '%s'", rc, e.msg);
    cr_assert_eq(e.code, code, "code %s for '%s'", proto_error_code_name(e.code), e.msg);
    cr_assert(strstr(e.msg, want), "message '%s' lacks '%s'", e.msg, want);
}

static void reply_ok(const reply *x)
{
    proto_error e;
    cr_assert_eq(proto_check_reply(&x->r, &lim, &e), 0, "refused: %s", e.msg);
}

Test(proto, valid_replies_pass)
{
    for (int c = VOXD__REPLY__MSG_HELLO_OK; c <= VOXD__REPLY__MSG_PONG; c++) {
        reply x;
        reply_init(&x, (Voxd__Reply__MsgCase)c);
        reply_ok(&x);
    }
}

Test(proto, reply_shape)
{
    reply x;
    reply_init(&x, VOXD__REPLY__MSG__NOT_SET);
    x.r.pong = NULL;
    reply_refused(&x, INVALID, "reply of no type this client knows");
    x.r.msg_case = (Voxd__Reply__MsgCase)77;
    reply_refused(&x, INVALID, "reply of unknown type 77");
    proto_error e;
    cr_assert_eq(proto_check_reply(NULL, &lim, &e), -EINVAL);
}

Test(proto, hello_ok_rules)
{
    reply x;
    reply_init(&x, VOXD__REPLY__MSG_HELLO_OK);
    x.m.hello_ok.version = 2;
    reply_refused(&x, INVALID, "server speaks protocol version 2, this client 1");
    reply_init(&x, VOXD__REPLY__MSG_HELLO_OK);
    x.m.hello_ok.limits = NULL;
    reply_refused(&x, INVALID, "hello_ok has no limits");
    reply_init(&x, VOXD__REPLY__MSG_HELLO_OK);
    x.limits.max_frame = 100;
    reply_refused(&x, INVALID, "server max_frame 100 is outside 4096 to 67108864");
    reply_init(&x, VOXD__REPLY__MSG_HELLO_OK);
    x.limits.chunk_size = 1 << 20;
    reply_refused(&x, INVALID, "server chunk_size 1048576 does not fit its max_frame 1048576");
    reply_init(&x, VOXD__REPLY__MSG_HELLO_OK);
    x.limits.max_res = 0;
    reply_refused(&x, INVALID, "server max_res 0 is outside 1 to 65536");
    /* Every limit within the range a daemon's config takes (the table's). */
    for (size_t i = 0; i < proto_n_limits; i++) {
        const proto_limit_info *row = &proto_limit_table[i];
        char want[128];
        reply_init(&x, VOXD__REPLY__MSG_HELLO_OK);
        proto_limits l = lim;
        uint64_t bad = row->max + 1;
        memcpy((char *)&l + row->off, &bad, row->size); /* little-endian: the low bytes */
        if (row->size == 4 && row->max == UINT32_MAX) continue; /* no value past it */
        proto_limits_to_hello(&l, &x.limits);
        snprintf(want, sizeof want, "server %s %llu is outside", row->name,
                 (unsigned long long)(row->size == 4 ? (uint32_t)bad : bad));
        reply_refused(&x, INVALID, want);
        if (row->min == 0) continue;
        reply_init(&x, VOXD__REPLY__MSG_HELLO_OK);
        l = lim;
        uint64_t zero = 0;
        memcpy((char *)&l + row->off, &zero, row->size);
        proto_limits_to_hello(&l, &x.limits);
        snprintf(want, sizeof want, "server %s 0 is outside %llu to", row->name,
                 (unsigned long long)row->min);
        reply_refused(&x, INVALID, want);
    }
    reply_init(&x, VOXD__REPLY__MSG_HELLO_OK);
    x.m.hello_ok.workers = 1000;
    reply_refused(&x, INVALID, "server reports 1000 workers, limit 256");
    reply_init(&x, VOXD__REPLY__MSG_HELLO_OK);
    x.m.hello_ok.server = "voxd\n";
    reply_refused(&x, INVALID, "server name contains control character 0x0a at offset 4");

    /* A client takes its limits from a good HelloOk. */
    reply_init(&x, VOXD__REPLY__MSG_HELLO_OK);
    x.limits.chunk_size = 4096;
    proto_limits l;
    proto_limits_from_hello(&x.limits, &l);
    cr_assert_eq(l.chunk_size, 4096);
    cr_assert_eq(l.max_result_bytes, 1ull << 32);
    cr_assert_eq(l.max_csg_nodes, 256);
    cr_assert_eq(l.max_input_bytes, 64u << 20);
}

/* ---------------------------------------------------------------- the table of limits */

/* The table VOX_LIMITS and the protocol's Limits message have the same
 * fields, by name, each as wide as the other; every field survives the
 * wire both ways; the table's ranges are those of the modules behind. */
Test(proto, limits_table_is_the_limits_message)
{
    const ProtobufCMessageDescriptor *d = &voxd__limits__descriptor;
    cr_assert_eq(d->n_fields, proto_n_limits, "Limits has %u fields, the table %zu rows",
                 d->n_fields, proto_n_limits);
    for (unsigned f = 0; f < d->n_fields; f++) {
        const ProtobufCFieldDescriptor *fd = &d->fields[f];
        size_t i = 0;
        while (i < proto_n_limits && strcmp(proto_limit_table[i].name, fd->name)) i++;
        cr_assert_lt(i, proto_n_limits, "Limits.%s has no row in VOX_LIMITS", fd->name);
        size_t want = fd->type == PROTOBUF_C_TYPE_UINT64 ? 8 : fd->type == PROTOBUF_C_TYPE_UINT32 ? 4 : 0;
        cr_assert_eq(proto_limit_table[i].size, want, "Limits.%s is %zu bytes wide in the table",
                     fd->name, proto_limit_table[i].size);
        cr_assert_eq(fd->label, PROTOBUF_C_LABEL_NONE, "Limits.%s is not a plain scalar", fd->name);
    }
    for (size_t i = 0; i < proto_n_limits; i++) {
        const proto_limit_info *row = &proto_limit_table[i];
        cr_assert_not_null(protobuf_c_message_descriptor_get_field_by_name(d, row->name),
                           "row %s is not a field of Limits", row->name);
        cr_assert(row->min <= row->def && row->def <= row->max, "%s", row->name);
        cr_assert(row->doc[0] && (!strcmp(row->unit, "BYTES") || !strcmp(row->unit, "COUNT") ||
                                  !strcmp(row->unit, "SECONDS")), "%s", row->name);
    }
    /* Distinct values in every field, through HelloOk's Limits and back. */
    proto_limits a, b;
    memset(&b, 0, sizeof b);
    for (size_t i = 0; i < proto_n_limits; i++) {
        uint64_t v = proto_limit_table[i].min + i + 1;
        memcpy((char *)&a + proto_limit_table[i].off, &v, proto_limit_table[i].size);
    }
    Voxd__Limits l = VOXD__LIMITS__INIT;
    proto_limits_to_hello(&a, &l);
    uint8_t buf[256];
    size_t n = voxd__limits__pack(&l, buf);
    Voxd__Limits *u = voxd__limits__unpack(NULL, n, buf);
    cr_assert_not_null(u);
    proto_limits_from_hello(u, &b);
    voxd__limits__free_unpacked(u, NULL);
    for (size_t i = 0; i < proto_n_limits; i++)
        cr_expect_eq(proto_limit_get(&a, i), proto_limit_get(&b, i), "%s",
                     proto_limit_table[i].name);
    /* The bounds the frame decoder and the expression parser hold. */
    for (size_t i = 0; i < proto_n_limits; i++) {
        const proto_limit_info *row = &proto_limit_table[i];
        if (!strcmp(row->name, "max_frame"))
            cr_expect(row->min == PROTO_FRAME_MIN_MAX && row->max == PROTO_FRAME_LIMIT_MAX &&
                      row->def == PROTO_FRAME_DEFAULT_MAX);
        if (!strcmp(row->name, "max_expr_depth")) cr_expect_eq(row->max, EXPR_MAX_DEPTH_CAP);
        if (!strcmp(row->name, "chunk_size")) cr_expect_leq(row->max, PROTO_FRAME_LIMIT_MAX);
    }
}

Test(proto, limits_defaults_are_the_tables)
{
    proto_limits d;
    memset(&d, 0xa5, sizeof d);
    proto_limits_default(&d);
    for (size_t i = 0; i < proto_n_limits; i++)
        cr_expect_eq(proto_limit_get(&d, i), proto_limit_table[i].def, "%s",
                     proto_limit_table[i].name);
    cr_expect_eq(d.max_csg_nodes, 256);
    cr_expect_eq(d.max_csg_depth, 64);
    cr_expect_eq(d.max_csg_leaf_bytes, 64u << 20);
    cr_expect_eq(d.max_input_bytes, 64u << 20);
}

Test(proto, job_replies_need_a_job_id)
{
    const Voxd__Reply__MsgCase cases[] = {VOXD__REPLY__MSG_ACCEPTED,
                                          VOXD__REPLY__MSG_PROGRESS,
                                          VOXD__REPLY__MSG_CHUNK, VOXD__REPLY__MSG_SUMMARY};
    const char *names[] = {"accepted has no job id", "progress has no job id",
                           "chunk has no job id", "summary has no job id"};
    for (int i = 0; i < 4; i++) {
        reply x;
        reply_init(&x, cases[i]);
        switch (cases[i]) {
        case VOXD__REPLY__MSG_ACCEPTED: x.m.accepted.job_id = 0; break;
        case VOXD__REPLY__MSG_PROGRESS: x.m.progress.job_id = 0; break;
        case VOXD__REPLY__MSG_CHUNK: x.m.chunk.job_id = 0; break;
        default: x.m.summary.job_id = 0; break;
        }
        reply_refused(&x, INVALID, names[i]);
    }
    /* An error about no job in particular is fine. */
    reply x;
    reply_init(&x, VOXD__REPLY__MSG_ERROR);
    x.m.error.job_id = 0;
    reply_ok(&x);
}

Test(proto, progress_rules)
{
    reply x;
    reply_init(&x, VOXD__REPLY__MSG_PROGRESS);
    x.m.progress.fraction = 1.01;
    reply_refused(&x, INVALID, "fraction 1.01 is not in [0, 1]");
    x.m.progress.fraction = NAN;
    reply_refused(&x, INVALID, "fraction nan is not in [0, 1]");
    x.m.progress.fraction = 0, x.m.progress.level = 65;
    reply_refused(&x, INVALID, "progress level 65 is over 64");
}

Test(proto, chunk_bounds)
{
    reply x;
    reply_init(&x, VOXD__REPLY__MSG_CHUNK);
    x.m.chunk.data.len = 0;
    reply_refused(&x, INVALID, "chunk at offset 0 is empty");
    lim.chunk_size = 8;
    x.m.chunk.data.len = 16;
    reply_refused(&x, INVALID, "chunk of 16 bytes is over chunk_size 8");
    setup();
    x.m.chunk.offset = lim.max_result_bytes - 16; /* ends exactly at the limit */
    reply_ok(&x);
    x.m.chunk.offset = lim.max_result_bytes - 15;
    reply_refused(&x, LIMIT, "passes max_result_bytes 4294967296");
    x.m.chunk.offset = UINT64_MAX - 4; /* offset + len overflows */
    reply_refused(&x, LIMIT, "passes max_result_bytes");
}

Test(proto, summary_rules)
{
    reply x;
    reply_init(&x, VOXD__REPLY__MSG_SUMMARY);
    x.m.summary.file_bytes = 0;
    reply_refused(&x, INVALID, "summary file_bytes 0 is outside 1 to 4294967296");
    x.m.summary.file_bytes = lim.max_result_bytes + 1;
    reply_refused(&x, INVALID, "summary file_bytes 4294967297");
    x.m.summary.file_bytes = 100;
    x.m.summary.seconds_voxelize = -1;
    reply_refused(&x, INVALID, "seconds_voxelize -1 is not a finite number of seconds");
    x.m.summary.seconds_voxelize = 0, x.m.summary.seconds_write = INFINITY;
    reply_refused(&x, INVALID, "seconds_write inf");
}

/* The grid a summary carries is one grid_make could have made. */
Test(proto, summary_grid_rules)
{
    reply x;
    reply_init(&x, VOXD__REPLY__MSG_SUMMARY);
    reply_ok(&x);
    x.m.summary.grid = NULL;
    reply_refused(&x, INVALID, "summary has no grid");
    reply_init(&x, VOXD__REPLY__MSG_SUMMARY);
    x.grid.n_res = 2;
    reply_refused(&x, INVALID, "summary grid has 2 res and 3 origin values, not 3");
    reply_init(&x, VOXD__REPLY__MSG_SUMMARY);
    x.grid.n_origin = 4;
    reply_refused(&x, INVALID, "3 res and 4 origin values");
    reply_init(&x, VOXD__REPLY__MSG_SUMMARY);
    x.grid_res[1] = 0;
    reply_refused(&x, INVALID, "summary grid res 0 is outside 1 to 4096");
    x.grid_res[1] = 4097;
    reply_refused(&x, INVALID, "summary grid res 4097 is outside 1 to 4096");
    reply_init(&x, VOXD__REPLY__MSG_SUMMARY);
    x.grid.depth = 8;
    reply_refused(&x, INVALID, "summary grid depth 8, where res 100 needs 7");
    x.grid.depth = 7, x.grid_res[0] = 128, x.grid_res[2] = 1;
    reply_ok(&x);
    x.grid_res[0] = 129;
    reply_refused(&x, INVALID, "where res 129 needs 8");
    x.grid_res[0] = x.grid_res[1] = x.grid_res[2] = 1, x.grid.depth = 1;
    reply_ok(&x); /* depth is at least 1 */
    reply_init(&x, VOXD__REPLY__MSG_SUMMARY);
    x.grid.voxel_size = 0;
    reply_refused(&x, INVALID, "voxel_size 0 is not finite and > 0");
    x.grid.voxel_size = NAN;
    reply_refused(&x, INVALID, "voxel_size nan");
    reply_init(&x, VOXD__REPLY__MSG_SUMMARY);
    x.grid_origin[2] = INFINITY;
    reply_refused(&x, INVALID, "summary grid origin inf is not finite");
}

Test(proto, error_rules)
{
    reply x;
    reply_init(&x, VOXD__REPLY__MSG_ERROR);
    x.m.error.code = VOXD__ERROR_CODE__ERROR_CODE_UNSPECIFIED;
    reply_refused(&x, INVALID, "unknown error code 0");
    x.m.error.code = (Voxd__ErrorCode)9;
    reply_refused(&x, INVALID, "unknown error code 9");
    x.m.error.code = VOXD__ERROR_CODE__INTERNAL;
    x.m.error.message = "bell\a";
    reply_refused(&x, INVALID, "error message contains control character 0x07 at offset 4");
    char big[1100];
    memset(big, 'e', sizeof big - 1);
    big[sizeof big - 1] = '\0';
    x.m.error.message = big;
    reply_refused(&x, INVALID, "error message is 1099 bytes, limit 1024");
    cr_assert_str_eq(proto_error_code_name(VOXD__ERROR_CODE__WORKER_CRASHED), "WORKER_CRASHED");
    cr_assert_str_eq(proto_error_code_name(1234), "UNKNOWN");
}

Test(proto, status_rules)
{
    reply x;
    reply_init(&x, VOXD__REPLY__MSG_STATUS);
    x.w[1].state = (Voxd__WorkerState)5;
    reply_refused(&x, INVALID, "worker 1 has unknown state 5");
    reply_init(&x, VOXD__REPLY__MSG_STATUS);
    x.w[1].state = VOXD__WORKER_STATE__WORKER_STATE_STALLED;
    x.w[1].replaced = 2;
    x.w[1].stalls = 3;
    reply_refused(&x, INVALID, "worker 1 has 3 stalls but 2 replacements");
    reply_init(&x, VOXD__REPLY__MSG_STATUS);
    x.w[0].pid = 0;
    reply_refused(&x, INVALID, "worker 0 has pid 0");
    reply_init(&x, VOXD__REPLY__MSG_STATUS);
    x.w[0].cpu = -2;
    reply_refused(&x, INVALID, "worker 0 has cpu -2");
    reply_init(&x, VOXD__REPLY__MSG_STATUS);
    x.w[1].voxels_per_second = NAN;
    reply_refused(&x, INVALID, "worker 1 has voxels_per_second nan");
    reply_init(&x, VOXD__REPLY__MSG_STATUS);
    x.m.status.uptime = -INFINITY;
    reply_refused(&x, INVALID, "uptime -inf");
    reply_init(&x, VOXD__REPLY__MSG_STATUS);
    x.running.job_id = 0;
    reply_refused(&x, INVALID, "running job has no job id");
    reply_init(&x, VOXD__REPLY__MSG_STATUS);
    x.running.fraction = 2;
    reply_refused(&x, INVALID, "fraction 2 is not in [0, 1]");

    reply_init(&x, VOXD__REPLY__MSG_STATUS);
    size_t n = 5000;
    Voxd__WorkerStatus **many = calloc(n, sizeof *many);
    for (size_t i = 0; i < n; i++) many[i] = &x.w[0];
    x.m.status.workers = many, x.m.status.n_workers = n;
    reply_refused(&x, INVALID, "status lists 5000 workers, limit 256");
    free(many);
}

/* StatusReply.jobs: each job's id, kind, state, fraction and seconds
 * checked, and at most PROTO_MAX_STATUS_JOBS of them. */
Test(proto, status_jobs)
{
    reply x;
    Voxd__JobStatus js[2], *jp[2] = {&js[0], &js[1]};
    for (int i = 0; i < 2; i++) {
        js[i] = (Voxd__JobStatus)VOXD__JOB_STATUS__INIT;
        js[i].job_id = 3 + (uint64_t)i, js[i].uid = 1000, js[i].res = 64;
        js[i].kind = i ? VOXD__JOB_KIND__JOB_KIND_CSG : VOXD__JOB_KIND__JOB_KIND_IMPLICIT;
        js[i].state = i ? VOXD__JOB_STATE__JOB_STATE_QUEUED : VOXD__JOB_STATE__JOB_STATE_RUNNING;
        js[i].fraction = i ? 0 : 0.5, js[i].seconds = 1.5;
    }
    reply_init(&x, VOXD__REPLY__MSG_STATUS);
    x.m.status.jobs = jp, x.m.status.n_jobs = 2;
    reply_ok(&x);
    js[1].kind = (Voxd__JobKind)4;
    reply_refused(&x, INVALID, "job 4 has unknown kind 4");
    js[1].kind = VOXD__JOB_KIND__JOB_KIND_UNSPECIFIED;
    reply_refused(&x, INVALID, "job 4 has unknown kind 0");
    js[1].kind = VOXD__JOB_KIND__JOB_KIND_MESH;
    js[1].state = (Voxd__JobState)3;
    reply_refused(&x, INVALID, "job 4 has unknown state 3");
    js[1].state = VOXD__JOB_STATE__JOB_STATE_QUEUED;
    js[0].job_id = 0;
    reply_refused(&x, INVALID, "status job has no job id");
    js[0].job_id = 3;
    js[0].fraction = -0.5;
    reply_refused(&x, INVALID, "fraction -0.5 is not in [0, 1]");
    js[0].fraction = 0.5;
    js[1].seconds = NAN;
    reply_refused(&x, INVALID, "job seconds nan");
    js[1].seconds = 0;
    reply_ok(&x);

    size_t n = PROTO_MAX_STATUS_JOBS + 1;
    Voxd__JobStatus **many = calloc(n, sizeof *many);
    for (size_t i = 0; i < n; i++) many[i] = &js[1];
    x.m.status.jobs = many, x.m.status.n_jobs = n;
    reply_refused(&x, INVALID, "status lists 1025 jobs, limit 1024");
    free(many);
}

Test(proto, err_may_be_null)
{
    job j;
    job_init(&j);
    cr_assert_eq(proto_check_request(&j.req, &lim, NULL), 0);
    j.im.res = 0;
    cr_assert_eq(proto_check_request(&j.req, &lim, NULL), -EINVAL);
}
