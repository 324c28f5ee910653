/* The boundary validator (proto_check.h) on requests: valid messages pass; each
 * rule refuses with its typed code and the message a person reads.  Messages are
 * built as structs (so out-of-range enums and NaNs are easy to inject), and some
 * also go through pack/unpack to show protobuf-c really delivers such values.
 * CSG jobs: test_proto_csg.c; replies: test_proto_reply.c. */
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

/* ---------------------------------------------------------------- valid */

Test(proto, valid_requests_pass)
{
    job j;
    job_init(&j);
    accepted(&j.req);
    /* Six-value domain, every option given. */
    double d6[6] = {-1, 1, -2, 2, -0.5, 0.5};
    j.im.domain = d6, j.im.n_domain = 6;
    j.sub.channel = VOXD__CHANNEL__CHANNEL_OCCUPANCY;
    j.sub.brick = 256, j.sub.comp = VOXD__COMPRESSION__COMPRESSION_NONE;
    j.sub.hash = VOXD__HASH__HASH_XX32, j.im.schedule = VOXD__SCHEDULE__SCHEDULE_PAPER;
    j.im.res = lim.max_res;
    accepted(&j.req);
    /* Source exactly at the limit. */
    char *big = malloc(lim.max_expr_bytes);
    memset(big, 'x', lim.max_expr_bytes);
    j.im.source.data = (uint8_t *)big, j.im.source.len = lim.max_expr_bytes;
    accepted(&j.req);
    free(big);

    Voxd__Request r = VOXD__REQUEST__INIT;
    Voxd__Hello h = VOXD__HELLO__INIT;
    h.version = PROTO_VERSION, h.client = "vox 0.1 \xc3\xa9t\xc3\xa9"; /* UTF-8 is fine */
    r.msg_case = VOXD__REQUEST__MSG_HELLO, r.hello = &h;
    accepted(&r);
    Voxd__Cancel c = VOXD__CANCEL__INIT;
    c.job_id = 1;
    r.msg_case = VOXD__REQUEST__MSG_CANCEL, r.cancel = &c;
    accepted(&r);
    Voxd__Status st = VOXD__STATUS__INIT;
    r.msg_case = VOXD__REQUEST__MSG_STATUS, r.status = &st;
    accepted(&r);
    Voxd__Ping p = VOXD__PING__INIT;
    r.msg_case = VOXD__REQUEST__MSG_PING, r.ping = &p;
    accepted(&r);
}

Test(proto, valid_request_survives_the_wire)
{
    job j;
    job_init(&j);
    uint8_t *buf;
    size_t len;
    cr_assert_eq(proto_frame_encode_request(&j.req, &buf, &len), 0);
    Voxd__Request *r = proto_frame_unpack_request(buf + 4, len - 4);
    cr_assert_not_null(r);
    accepted(r);
    voxd__request__free_unpacked(r, NULL);
    free(buf);
}

/* ---------------------------------------------------------------- request shape */

Test(proto, request_without_type)
{
    Voxd__Request r = VOXD__REQUEST__INIT;
    refused(&r, INVALID, "request of no type this server knows");
    refused(NULL, INVALID, "malformed request");
    r.msg_case = (Voxd__Request__MsgCase)42;
    refused(&r, INVALID, "request of unknown type 42");
    r.msg_case = VOXD__REQUEST__MSG_SUBMIT; /* case set, body missing */
    refused(&r, INVALID, "request of unknown type 2");
}

Test(proto, unknown_request_field_from_a_newer_client)
{
    /* Field 9, varint: a type this server does not know.  protobuf-c keeps it
     * as an unknown field and leaves the oneof unset. */
    static const uint8_t wire[] = {0x48, 0x01};
    Voxd__Request *r = proto_frame_unpack_request(wire, sizeof wire);
    cr_assert_not_null(r);
    refused(r, INVALID, "no type this server knows (protocol version 1)");
    voxd__request__free_unpacked(r, NULL);
}

Test(proto, hello_version_and_name)
{
    Voxd__Request r = VOXD__REQUEST__INIT;
    Voxd__Hello h = VOXD__HELLO__INIT;
    r.msg_case = VOXD__REQUEST__MSG_HELLO, r.hello = &h;
    refused(&r, INVALID, "protocol version 0 is not supported (this server speaks 1)");
    h.version = 2;
    refused(&r, INVALID, "protocol version 2 is not supported");
    h.version = 1;
    h.client = "bad\x1b[2Jname";
    refused(&r, INVALID, "client name contains control character 0x1b at offset 3");
    h.client = "caf\xe9"; /* Latin-1, not UTF-8 */
    refused(&r, INVALID, "client name is not valid UTF-8 at offset 3");
    h.client = "\xc0\xaf"; /* overlong '/' */
    refused(&r, INVALID, "not valid UTF-8 at offset 0");
    char name[200];
    memset(name, 'a', sizeof name - 1);
    name[sizeof name - 1] = '\0';
    h.client = name;
    refused(&r, INVALID, "client name is 199 bytes, limit 128");
}

Test(proto, cancel_needs_a_job_id)
{
    Voxd__Request r = VOXD__REQUEST__INIT;
    Voxd__Cancel c = VOXD__CANCEL__INIT;
    r.msg_case = VOXD__REQUEST__MSG_CANCEL, r.cancel = &c;
    refused(&r, INVALID, "cancel needs a job id");
}

Test(proto, submit_without_job)
{
    job j;
    job_init(&j);
    j.sub.job_case = VOXD__SUBMIT__JOB__NOT_SET;
    refused(&j.req, INVALID, "submit has no job (implicit, mesh or csg)");
    j.sub.job_case = (Voxd__Submit__JobCase)9;
    refused(&j.req, INVALID, "unknown job kind 9");
    j.sub.job_case = VOXD__SUBMIT__JOB_IMPLICIT, j.sub.implicit = NULL;
    refused(&j.req, INVALID, "submit job is missing");
}

/* ---------------------------------------------------------------- implicit */

Test(proto, res_missing_or_over_the_limit)
{
    job j;
    job_init(&j);
    j.im.res = 0;
    refused(&j.req, INVALID, "res is missing (give 1 to 4096)");
    j.im.res = 5000;
    refused(&j.req, LIMIT, "res 5000 is over this server's limit of 4096");
    lim.max_res = 8192;
    accepted(&j.req);
}

Test(proto, domain_needs_2_or_6_values)
{
    job j;
    job_init(&j);
    j.im.n_domain = 3;
    refused(&j.req, INVALID, "domain needs 2 or 6 values, got 3");
    j.im.n_domain = 0;
    refused(&j.req, INVALID, "domain needs 2 or 6 values, got 0");
}

Test(proto, domain_huge_repeated_field)
{
    job j;
    job_init(&j);
    size_t n = 100000;
    double *d = calloc(n, sizeof *d);
    j.im.domain = d, j.im.n_domain = n;
    refused(&j.req, INVALID, "domain needs 2 or 6 values, got 100000");
    free(d);
}

Test(proto, domain_low_below_high)
{
    job j;
    job_init(&j);
    j.dom[0] = 2, j.dom[1] = 2;
    refused(&j.req, INVALID, "domain: low 2 is not below high 2");
    double d6[6] = {0, 1, 0, 1, 3, -3};
    j.im.domain = d6, j.im.n_domain = 6;
    refused(&j.req, INVALID, "domain z: low 3 is not below high -3");
}

Test(proto, domain_not_finite)
{
    job j;
    job_init(&j);
    j.dom[1] = NAN;
    refused(&j.req, INVALID, "domain value 2 is not finite (nan)");
    j.dom[1] = 1, j.dom[0] = -INFINITY;
    refused(&j.req, INVALID, "domain value 1 is not finite (-inf)");
    j.dom[0] = -1.5e308, j.dom[1] = 1.5e308; /* finite ends, infinite width */
    refused(&j.req, INVALID, "domain is too wide");
}

Test(proto, non_finite_domain_through_the_wire)
{
    job j;
    job_init(&j);
    j.dom[0] = NAN;
    uint8_t *buf;
    size_t len;
    cr_assert_eq(proto_frame_encode_request(&j.req, &buf, &len), 0);
    Voxd__Request *r = proto_frame_unpack_request(buf + 4, len - 4);
    cr_assert_not_null(r);
    cr_assert(isnan(r->submit->implicit->domain[0]));
    refused(r, INVALID, "domain value 1 is not finite");
    voxd__request__free_unpacked(r, NULL);
    free(buf);
}

Test(proto, source_empty_too_long_or_with_nul)
{
    job j;
    job_init(&j);
    j.im.source.len = 0;
    refused(&j.req, INVALID, "expression is empty");
    char *big = malloc(70000);
    memset(big, 'x', 70000);
    j.im.source.data = (uint8_t *)big, j.im.source.len = 70000;
    refused(&j.req, LIMIT, "expression is 70000 bytes, limit 65536");
    free(big);
    job_init(&j);
    j.src[12] = '\0';
    refused(&j.req, INVALID, "source contains a NUL byte at offset 12");
}

Test(proto, source_name_bounded_one_line_no_nul)
{
    job j;
    job_init(&j);
    char name[JOB_META_NAME_MAX + 1];
    memset(name, 'n', sizeof name);
    j.im.source_name.data = (uint8_t *)name, j.im.source_name.len = JOB_META_NAME_MAX;
    accepted(&j.req);
    j.im.source_name.len = JOB_META_NAME_MAX + 1;
    refused(&j.req, LIMIT, "source_name is 513 bytes, limit 512");
    j.im.source_name.len = 8;
    name[3] = '\n';
    refused(&j.req, INVALID, "source_name contains a line break at offset 3");
    name[3] = '\0';
    refused(&j.req, INVALID, "source_name contains a NUL byte at offset 3");
}

Test(proto, nul_in_source_survives_the_wire_and_is_refused)
{
    job j;
    job_init(&j);
    j.src[0] = '\0'; /* a C string would look empty; bytes keep the length */
    uint8_t *buf;
    size_t len;
    cr_assert_eq(proto_frame_encode_request(&j.req, &buf, &len), 0);
    Voxd__Request *r = proto_frame_unpack_request(buf + 4, len - 4);
    cr_assert_eq(r->submit->implicit->source.len, strlen("x^2 + y^2 + z^2 - 1"));
    refused(r, INVALID, "source contains a NUL byte at offset 0");
    voxd__request__free_unpacked(r, NULL);
    free(buf);
}

Test(proto, unknown_enum_numbers)
{
    job j;
    job_init(&j);
    j.sub.channel = (Voxd__Channel)7;
    refused(&j.req, INVALID, "unknown channel 7");
    job_init(&j);
    j.sub.channel = (Voxd__Channel)-1;
    refused(&j.req, INVALID, "unknown channel -1");
    job_init(&j);
    j.sub.comp = (Voxd__Compression)4;
    refused(&j.req, INVALID, "unknown compression 4");
    job_init(&j);
    j.sub.hash = (Voxd__Hash)3;
    refused(&j.req, INVALID, "unknown hash 3");
    job_init(&j);
    j.im.schedule = (Voxd__Schedule)3;
    refused(&j.req, INVALID, "unknown schedule 3");
}

Test(proto, unknown_enum_number_through_the_wire)
{
    job j;
    job_init(&j);
    j.sub.channel = (Voxd__Channel)1000;
    uint8_t *buf;
    size_t len;
    cr_assert_eq(proto_frame_encode_request(&j.req, &buf, &len), 0);
    Voxd__Request *r = proto_frame_unpack_request(buf + 4, len - 4);
    cr_assert_not_null(r);
    cr_assert_eq((int)r->submit->channel, 1000, "protobuf-c keeps unknown enum numbers");
    refused(r, INVALID, "unknown channel 1000");
    voxd__request__free_unpacked(r, NULL);
    free(buf);
}

Test(proto, channel_not_available_for_implicit)
{
    job j;
    job_init(&j);
    j.sub.channel = VOXD__CHANNEL__CHANNEL_DENSITY;
    refused(&j.req, INVALID, "channel density is not available for implicit jobs");
    j.sub.channel = VOXD__CHANNEL__CHANNEL_SURFACE;
    accepted(&j.req);
}

/* Implicit.band: as Mesh.band, 1..32 (0 the default), for channel 4 only. */
Test(proto, implicit_distance_band)
{
    job j;
    job_init(&j);
    j.sub.channel = VOXD__CHANNEL__CHANNEL_DISTANCE;
    accepted(&j.req); /* the default band */
    j.im.band = 1;
    accepted(&j.req);
    j.im.band = 32;
    accepted(&j.req);
    j.im.band = 33;
    refused(&j.req, INVALID, "band 33 is not from 1 to 32 voxels (or 0: 3)");
    j.im.band = UINT32_MAX;
    refused(&j.req, INVALID, "band 4294967295 is not from 1 to 32 voxels");
    j.im.band = 4;
    j.sub.channel = VOXD__CHANNEL__CHANNEL_SURFACE;
    refused(&j.req, INVALID, "band 4 is for channel distance");
    j.sub.channel = VOXD__CHANNEL__CHANNEL_UNSPECIFIED; /* the default, surface */
    refused(&j.req, INVALID, "band 4 is for channel distance");
}

Test(proto, brick_power_of_two)
{
    job j;
    job_init(&j);
    const uint32_t bad_bricks[] = {1, 3, 12, 512, 0x80000000u};
    for (size_t i = 0; i < 5; i++) {
        j.sub.brick = bad_bricks[i];
        char want[80];
        snprintf(want, sizeof want, "brick %u is not a power of two from 2 to 256",
                 bad_bricks[i]);
        refused(&j.req, INVALID, want);
    }
    for (uint32_t b = 2; b <= 256; b *= 2) {
        j.sub.brick = b;
        accepted(&j.req);
    }
}

/* ---------------------------------------------------------------- mesh */

/* A valid mesh job, ready to be spoiled one field at a time. */
typedef struct {
    job j;
    Voxd__Mesh m;
    uint8_t data[32];
} mesh_job;

static void mesh_init(mesh_job *mj)
{
    static const Voxd__Mesh m0 = VOXD__MESH__INIT;
    job_init(&mj->j);
    mj->m = m0;
    memcpy(mj->data, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", 32);
    mj->m.data.data = mj->data, mj->m.data.len = 32;
    mj->m.res = 64;
    mj->m.pad = 1;
    mj->j.sub.job_case = VOXD__SUBMIT__JOB_MESH, mj->j.sub.mesh = &mj->m; /* a union */
}

Test(proto, valid_mesh_jobs_pass)
{
    mesh_job mj;
    mesh_init(&mj);
    accepted(&mj.j.req);
    /* Every option given, each enum at its last value; a binary file may
     * hold NULs. */
    mj.m.format = VOXD__MESH_FORMAT__MESH_FORMAT_GLTF;
    mj.m.mode = VOXD__MESH_MODE__MESH_MODE_INTERIOR;
    mj.m.repair = VOXD__MESH_REPAIR__MESH_REPAIR_WINDING;
    mj.m.supersample = 8;
    mj.data[3] = 0;
    mj.m.source_name.data = (uint8_t *)"bunny.off", mj.m.source_name.len = 9;
    mj.j.sub.channel = VOXD__CHANNEL__CHANNEL_DENSITY;
    accepted(&mj.j.req);
    mj.j.sub.channel = VOXD__CHANNEL__CHANNEL_SURFACE;
    mj.m.supersample = 2;
    accepted(&mj.j.req);
    /* A weld: at 0 (equal positions) and at both ends of its range. */
    mj.m.weld = 1;
    accepted(&mj.j.req);
    mj.m.weld_eps = 1e-30;
    accepted(&mj.j.req);
    mj.m.weld_eps = 1e30;
    accepted(&mj.j.req);
    mj.m.weld = 0, mj.m.weld_eps = 0;
    /* A domain instead of the bounding box (then no pad), 2 or 6 values. */
    double d6[6] = {-1, 1, -2, 2, -3, 3};
    mj.m.pad = 0, mj.m.domain = d6, mj.m.n_domain = 6;
    accepted(&mj.j.req);
    mj.m.n_domain = 2;
    accepted(&mj.j.req);
    /* The largest pad res leaves room for; data exactly at the limit. */
    mj.m.n_domain = 0, mj.m.res = 9, mj.m.pad = 4;
    accepted(&mj.j.req);
    lim.max_mesh_bytes = 32;
    accepted(&mj.j.req);
}

Test(proto, mesh_job_rules)
{
    mesh_job mj;
    mesh_init(&mj);
    mj.m.format = (Voxd__MeshFormat)6;
    refused(&mj.j.req, INVALID, "unknown mesh format 6");
    mesh_init(&mj);
    mj.m.mode = (Voxd__MeshMode)6;
    refused(&mj.j.req, INVALID, "unknown mesh mode 6");
    mesh_init(&mj);
    mj.m.repair = (Voxd__MeshRepair)4;
    refused(&mj.j.req, INVALID, "unknown mesh repair 4");
    mesh_init(&mj);
    mj.m.supersample = 1;
    refused(&mj.j.req, INVALID, "supersample 1 is not from 2 to 8");
    mj.m.supersample = 9;
    refused(&mj.j.req, INVALID, "supersample 9 is not from 2 to 8");
    mesh_init(&mj);
    mj.m.weld = 1;
    const double bad_weld[] = {-1e-3, 1e-31, 2e30, NAN, INFINITY};
    for (size_t i = 0; i < sizeof bad_weld / sizeof *bad_weld; i++) {
        mj.m.weld_eps = bad_weld[i];
        refused(&mj.j.req, INVALID, "is not 0 or from 1e-30 to 1e+30");
    }
    mj.m.weld = 0, mj.m.weld_eps = 1e-3;
    refused(&mj.j.req, INVALID, "weld_eps 0.001 without weld");
    mesh_init(&mj);
    mj.m.data.len = 0;
    refused(&mj.j.req, INVALID, "mesh data is empty");
    mesh_init(&mj);
    mj.m.res = 0;
    refused(&mj.j.req, INVALID, "res is missing");
    mj.m.res = lim.max_res + 1;
    refused(&mj.j.req, LIMIT, "res 4097 is over this server's limit of 4096");
    mesh_init(&mj);
    mj.m.n_domain = 4, mj.m.domain = mj.j.dom;
    refused(&mj.j.req, INVALID, "domain needs 2 or 6 values, got 4");
    mj.m.n_domain = 2, mj.m.pad = 1; /* a domain and a pad */
    refused(&mj.j.req, INVALID, "pad 1 is for a mesh fitted to its bounding box");
    mesh_init(&mj);
    mj.m.res = 8, mj.m.pad = 4;
    refused(&mj.j.req, INVALID, "pad 4 leaves no voxel for the mesh in res 8");
    mj.m.res = 1, mj.m.pad = UINT32_MAX; /* 2 pad overflows 32 bits */
    refused(&mj.j.req, INVALID, "pad 4294967295 leaves no voxel");
    mesh_init(&mj);
    mj.j.sub.channel = VOXD__CHANNEL__CHANNEL_DISTANCE;
    accepted(&mj.j.req); /* the default band */
    mj.m.band = 32;
    accepted(&mj.j.req);
    mj.m.band = 33;
    refused(&mj.j.req, INVALID, "band 33 is not from 1 to 32 voxels (or 0: 3)");
    mj.m.band = 2, mj.m.mode = VOXD__MESH_MODE__MESH_MODE_SURFACE;
    refused(&mj.j.req, INVALID, "channel distance takes its sign from the solid");
    mesh_init(&mj);
    mj.m.band = 2; /* a band without the distance channel */
    refused(&mj.j.req, INVALID, "band 2 is for channel distance");
    mesh_init(&mj);
    mj.m.source_name.data = (uint8_t *)"a\nb", mj.m.source_name.len = 3;
    refused(&mj.j.req, INVALID, "source_name contains a line break at offset 1");
    /* Over max_mesh_bytes inline: refused before the job exists. */
    mesh_init(&mj);
    lim.max_mesh_bytes = 31;
    refused(&mj.j.req, LIMIT, "mesh is 32 bytes, over this server's max_mesh_bytes of 31");
}

Test(proto, mesh_job_survives_the_wire)
{
    mesh_job mj;
    mesh_init(&mj);
    mj.m.mode = VOXD__MESH_MODE__MESH_MODE_SURFACE6;
    mj.m.repair = VOXD__MESH_REPAIR__MESH_REPAIR_VOTE;
    mj.m.supersample = 3;
    mj.m.weld = 1, mj.m.weld_eps = 2.5e-4;
    mj.m.source_name.data = (uint8_t *)"m.obj", mj.m.source_name.len = 5;
    uint8_t *buf;
    size_t n;
    cr_assert_eq(proto_frame_encode_request(&mj.j.req, &buf, &n), 0);
    Voxd__Request *r = proto_frame_unpack_request(buf + 4, n - 4);
    cr_assert_not_null(r);
    const Voxd__Mesh *m = r->submit->mesh;
    cr_assert_eq(r->submit->job_case, VOXD__SUBMIT__JOB_MESH);
    cr_expect(m->data.len == 32 && !memcmp(m->data.data, mj.data, 32));
    cr_expect_eq(m->mode, VOXD__MESH_MODE__MESH_MODE_SURFACE6);
    cr_expect_eq(m->repair, VOXD__MESH_REPAIR__MESH_REPAIR_VOTE);
    cr_expect(m->supersample == 3 && m->pad == 1 && m->res == 64 && m->n_domain == 0);
    cr_expect(m->weld && m->weld_eps == 2.5e-4);
    cr_expect(m->source_name.len == 5 && !memcmp(m->source_name.data, "m.obj", 5));
    accepted(r);
    voxd__request__free_unpacked(r, NULL);
    free(buf);
}

/* ---------------------------------------------------------------- chunked input */

Test(proto, submit_with_input_bytes)
{
    job j;
    job_init(&j);
    size_t len = j.im.source.len;
    j.sub.input_bytes = len;
    refused(&j.req, INVALID, "the expression comes either inline or as input_bytes, not both");
    j.im.source.len = 0, j.im.source.data = NULL;
    accepted(&j.req);
    j.sub.input_bytes = lim.max_expr_bytes;
    accepted(&j.req);
    j.sub.input_bytes = lim.max_expr_bytes + 1;
    refused(&j.req, LIMIT, "expression is 65537 bytes, limit 65536");
    /* The cap of every input, whatever its kind. */
    lim.max_expr_bytes = 16u << 20, lim.max_input_bytes = 1u << 20;
    j.sub.input_bytes = lim.max_input_bytes;
    accepted(&j.req);
    j.sub.input_bytes = lim.max_input_bytes + 1;
    refused(&j.req, LIMIT, "input is 1048577 bytes, over this server's max_input_bytes of 1048576");
    setup();
    /* Through the wire: the field is where the proto says. */
    j.sub.input_bytes = 1000;
    uint8_t *buf;
    size_t n;
    cr_assert_eq(proto_frame_encode_request(&j.req, &buf, &n), 0);
    Voxd__Request *r = proto_frame_unpack_request(buf + 4, n - 4);
    cr_assert_not_null(r);
    cr_assert_eq(r->submit->input_bytes, 1000);
    cr_assert_eq(r->submit->implicit->source.len, 0);
    accepted(r);
    voxd__request__free_unpacked(r, NULL);
    free(buf);
}

/* A mesh as the job's input: its size declared, within max_mesh_bytes
 * (and, as every input, max_input_bytes), no inline data beside it. */
Test(proto, mesh_as_input)
{
    mesh_job mj;
    mesh_init(&mj);
    mj.m.data.len = 0;
    mj.j.sub.input_bytes = lim.max_mesh_bytes;
    accepted(&mj.j.req);
    mj.j.sub.input_bytes = lim.max_mesh_bytes + 1;
    refused(&mj.j.req, LIMIT, "over this server's max_input_bytes"); /* the default: equal */
    lim.max_input_bytes = 4ull << 30;
    refused(&mj.j.req, LIMIT, "mesh is 67108865 bytes, over this server's max_mesh_bytes of 67108864");
    /* The expression's limit is not the mesh's. */
    mj.j.sub.input_bytes = lim.max_expr_bytes + 1;
    accepted(&mj.j.req);
    mj.m.data.len = 32;
    refused(&mj.j.req, INVALID, "the mesh comes either inline or as input_bytes, not both");
}

typedef struct {
    Voxd__Request req;
    Voxd__InputChunk in;
    uint8_t data[8];
} chunk_req;

static void chunk_init(chunk_req *c)
{
    c->req = (Voxd__Request)VOXD__REQUEST__INIT;
    c->in = (Voxd__InputChunk)VOXD__INPUT_CHUNK__INIT;
    memcpy(c->data, "x*x+y*y", 8);
    c->in.job_id = 3, c->in.offset = 0;
    c->in.data.data = c->data, c->in.data.len = 7;
    c->req.msg_case = VOXD__REQUEST__MSG_INPUT, c->req.input = &c->in;
}

Test(proto, input_chunk_rules)
{
    chunk_req c;
    chunk_init(&c);
    accepted(&c.req);
    c.in.job_id = 0;
    refused(&c.req, INVALID, "input chunk has no job id");
    chunk_init(&c);
    c.in.data.len = 0;
    refused(&c.req, INVALID, "input chunk at offset 0 is empty");
    chunk_init(&c);
    c.in.offset = lim.max_input_bytes - 7; /* ends exactly at the cap */
    accepted(&c.req);
    c.in.offset = lim.max_input_bytes - 6;
    refused(&c.req, LIMIT, "input chunk at offset 67108858 passes this server's max_input_bytes of 67108864");
    c.in.offset = UINT64_MAX - 2; /* offset + len overflows */
    refused(&c.req, LIMIT, "passes this server's max_input_bytes");
    /* A NUL is the job's to judge (an expression cannot hold one, a mesh can). */
    chunk_init(&c);
    c.data[2] = 0;
    accepted(&c.req);
    /* Through the wire. */
    uint8_t *buf;
    size_t n;
    c.in.offset = 12345;
    cr_assert_eq(proto_frame_encode_request(&c.req, &buf, &n), 0);
    Voxd__Request *r = proto_frame_unpack_request(buf + 4, n - 4);
    cr_assert_not_null(r);
    cr_assert_eq(r->msg_case, VOXD__REQUEST__MSG_INPUT);
    cr_assert(r->input->job_id == 3 && r->input->offset == 12345 && r->input->data.len == 7);
    accepted(r);
    voxd__request__free_unpacked(r, NULL);
    free(buf);
}
