/* The boundary validator: valid messages pass; each rule refuses with its
 * typed code and the message a person reads.  Messages are built as structs
 * (so out-of-range enums and NaNs are easy to inject), and some also go
 * through pack/unpack to show protobuf-c really delivers such values. */
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

#define INVALID VOXD__ERROR_CODE__INVALID_INPUT
#define LIMIT VOXD__ERROR_CODE__LIMIT_EXCEEDED

static proto_limits lim;

static void setup(void)
{
    proto_limits_default(&lim);
}

TestSuite(proto, .init = setup);

/* A valid implicit job, ready to be spoiled one field at a time. */
typedef struct {
    Voxd__Request req;
    Voxd__Submit sub;
    Voxd__Implicit im;
    double dom[6];
    char src[64];
} job;

static void job_init(job *j)
{
    static const Voxd__Request r0 = VOXD__REQUEST__INIT;
    static const Voxd__Submit s0 = VOXD__SUBMIT__INIT;
    static const Voxd__Implicit i0 = VOXD__IMPLICIT__INIT;
    j->req = r0, j->sub = s0, j->im = i0;
    snprintf(j->src, sizeof j->src, "x^2 + y^2 + z^2 - 1");
    j->im.source.data = (uint8_t *)j->src;
    j->im.source.len = strlen(j->src);
    j->dom[0] = -1.5, j->dom[1] = 1.5;
    j->im.domain = j->dom, j->im.n_domain = 2;
    j->im.res = 64;
    j->sub.job_case = VOXD__SUBMIT__JOB_IMPLICIT, j->sub.implicit = &j->im;
    j->req.msg_case = VOXD__REQUEST__MSG_SUBMIT, j->req.submit = &j->sub;
}

/* Check r is refused with code and a message containing want. */
static void refused(const Voxd__Request *r, Voxd__ErrorCode code, const char *want)
{
    proto_error e;
    int rc = proto_check_request(r, &lim, &e);
    cr_assert_eq(rc, code == LIMIT ? -E2BIG : -EINVAL, "rc %d for '%s'", rc, e.msg);
    cr_assert_eq(e.code, code, "code %s for '%s'", proto_error_code_name(e.code), e.msg);
    cr_assert(strstr(e.msg, want), "message '%s' lacks '%s'", e.msg, want);
}

static void accepted(const Voxd__Request *r)
{
    proto_error e;
    int rc = proto_check_request(r, &lim, &e);
    cr_assert_eq(rc, 0, "refused: %s", e.msg);
    cr_assert_eq(e.msg[0], '\0');
}

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
    cr_assert_eq(frame_encode_request(&j.req, &buf, &len), 0);
    Voxd__Request *r = frame_unpack_request(buf + 4, len - 4);
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
    Voxd__Request *r = frame_unpack_request(wire, sizeof wire);
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
    cr_assert_eq(frame_encode_request(&j.req, &buf, &len), 0);
    Voxd__Request *r = frame_unpack_request(buf + 4, len - 4);
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
    cr_assert_eq(frame_encode_request(&j.req, &buf, &len), 0);
    Voxd__Request *r = frame_unpack_request(buf + 4, len - 4);
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
    cr_assert_eq(frame_encode_request(&j.req, &buf, &len), 0);
    Voxd__Request *r = frame_unpack_request(buf + 4, len - 4);
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
    j.sub.channel = VOXD__CHANNEL__CHANNEL_DISTANCE;
    refused(&j.req, INVALID, "channel distance is not available");
    j.sub.channel = VOXD__CHANNEL__CHANNEL_SURFACE;
    accepted(&j.req);
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
    cr_assert_eq(frame_encode_request(&mj.j.req, &buf, &n), 0);
    Voxd__Request *r = frame_unpack_request(buf + 4, n - 4);
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

/* ---------------------------------------------------------------- CSG */

typedef struct {
    Voxd__Csg csg;
    Voxd__CsgNode node[4];
    Voxd__CsgNode *ptr[4];
    uint32_t kids[4][2];
    double center[3], size[3], rot[3];
    double dom[2];
} csg;

/* cuboid "base", ellipsoid "egg", difference(0, 1), inverse(2): valid. */
static void csg_init(csg *c, job *j)
{
    static const Voxd__Csg c0 = VOXD__CSG__INIT;
    static const Voxd__CsgNode n0 = VOXD__CSG_NODE__INIT;
    c->csg = c0;
    for (int i = 0; i < 4; i++) c->node[i] = n0, c->ptr[i] = &c->node[i];
    for (int a = 0; a < 3; a++) c->center[a] = 0.1 * a, c->size[a] = 1, c->rot[a] = 0.5;
    for (int i = 0; i < 2; i++) {
        c->node[i].op = VOXD__CSG_OP__CSG_PRIMITIVE;
        c->node[i].primitive = i ? VOXD__PRIMITIVE__PRIMITIVE_ELLIPSOID
                                 : VOXD__PRIMITIVE__PRIMITIVE_CUBOID;
        c->node[i].center = c->center, c->node[i].n_center = 3;
        c->node[i].size = c->size, c->node[i].n_size = 3;
    }
    c->node[0].rotate = c->rot, c->node[0].n_rotate = 3;
    c->node[0].name.data = (uint8_t *)"base", c->node[0].name.len = 4;
    c->node[1].name.data = (uint8_t *)"egg", c->node[1].name.len = 3;
    c->node[2].op = VOXD__CSG_OP__CSG_DIFFERENCE;
    c->kids[2][0] = 0, c->kids[2][1] = 1;
    c->node[2].children = c->kids[2], c->node[2].n_children = 2;
    c->node[3].op = VOXD__CSG_OP__CSG_INVERSE;
    c->kids[3][0] = 2;
    c->node[3].children = c->kids[3], c->node[3].n_children = 1;
    c->csg.nodes = c->ptr, c->csg.n_nodes = 4;
    c->dom[0] = -1, c->dom[1] = 2;
    c->csg.domain = c->dom, c->csg.n_domain = 2;
    c->csg.res = 128;
    job_init(j);
    j->sub.job_case = VOXD__SUBMIT__JOB_CSG, j->sub.csg = &c->csg;
    j->sub.channel = VOXD__CHANNEL__CHANNEL_UNSPECIFIED;
}

Test(proto, csg_a_valid_tree_passes)
{
    csg c;
    job j;
    csg_init(&c, &j);
    accepted(&j.req);
    j.sub.channel = VOXD__CHANNEL__CHANNEL_OCCUPANCY;
    accepted(&j.req);
    j.sub.channel = VOXD__CHANNEL__CHANNEL_DENSITY;
    accepted(&j.req);
    j.sub.channel = VOXD__CHANNEL__CHANNEL_SURFACE;
    accepted(&j.req);
    j.sub.channel = VOXD__CHANNEL__CHANNEL_DISTANCE; /* the pipeline decides the tree */
    accepted(&j.req);
    csg_init(&c, &j);
    j.sub.input_bytes = 10;
    refused(&j.req, INVALID, "the CSG leaves' data_bytes add up to 0, the job declares 10 "
                             "bytes of input");
}

Test(proto, csg_child_must_be_earlier)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.kids[3][0] = 3; /* itself */
    refused(&j.req, INVALID, "CSG node 3 refers to node 3, which is not earlier");
    c.kids[3][0] = 5;
    refused(&j.req, INVALID, "CSG node 3 refers to node 5, which is not earlier");
    c.kids[3][0] = 0xFFFFFFFFu;
    refused(&j.req, INVALID, "refers to node 4294967295");
}

Test(proto, csg_arity_ops_and_counts)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.node[2].n_children = 1;
    refused(&j.req, INVALID, "CSG node 2 (difference) needs 2 children, got 1");
    csg_init(&c, &j);
    c.node[0].n_children = 1, c.node[0].children = c.kids[2];
    refused(&j.req, INVALID, "CSG node 0 ('base') (primitive) needs 0 children, got 1");
    csg_init(&c, &j);
    c.node[1].op = VOXD__CSG_OP__CSG_OP_UNSPECIFIED;
    refused(&j.req, INVALID, "CSG node 1 ('egg') has no op");
    c.node[1].op = (Voxd__CsgOp)5; /* a hole in the numbering */
    refused(&j.req, INVALID, "CSG node 1 ('egg') has unknown op 5");
    c.node[1].op = (Voxd__CsgOp)99;
    refused(&j.req, INVALID, "CSG node 1 ('egg') has unknown op 99");
    csg_init(&c, &j);
    c.csg.n_nodes = 0;
    refused(&j.req, INVALID, "CSG job has no nodes");
    c.csg.n_nodes = 4, lim.max_csg_nodes = 3;
    refused(&j.req, LIMIT, "CSG job has 4 nodes, over this server's max_csg_nodes of 3");
}

Test(proto, csg_huge_node_list)
{
    csg c;
    job j;
    csg_init(&c, &j);
    size_t n = 200000;
    Voxd__CsgNode **many = calloc(n, sizeof *many);
    for (size_t i = 0; i < n; i++) many[i] = &c.node[0];
    c.csg.nodes = many, c.csg.n_nodes = n;
    refused(&j.req, LIMIT, "CSG job has 200000 nodes, over this server's max_csg_nodes of 256");
    free(many);
}

/* A chain of inverses: its depth against max_csg_depth; dilations along
 * it against the evaluator's margin. */
Test(proto, csg_depth_and_margin)
{
    csg c;
    job j;
    csg_init(&c, &j);
    lim.max_csg_depth = 3; /* egg or base, difference, inverse: 3 */
    accepted(&j.req);
    lim.max_csg_depth = 2;
    refused(&j.req, LIMIT, "CSG node 3: the tree is deeper than this server's max_csg_depth of 2");

    setup();
    enum { N = 10 };
    Voxd__CsgNode nodes[N], *ptrs[N];
    uint32_t kids[N];
    for (int i = 0; i < N; i++) {
        nodes[i] = (Voxd__CsgNode)VOXD__CSG_NODE__INIT;
        ptrs[i] = &nodes[i];
        if (i == 0) {
            nodes[0] = c.node[0];
            continue;
        }
        kids[i] = (uint32_t)i - 1;
        nodes[i].op = VOXD__CSG_OP__CSG_DILATE;
        nodes[i].children = &kids[i], nodes[i].n_children = 1;
        nodes[i].k = 8;
    }
    c.csg.nodes = ptrs, c.csg.n_nodes = N;
    refused(&j.req, INVALID, "CSG node 9: erosions and dilations along one path pass 64 voxels");
    c.csg.n_nodes = 9; /* 8 x 8 = 64 */
    accepted(&j.req);
}

Test(proto, csg_names)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.node[0].name.data = (uint8_t *)"1st", c.node[0].name.len = 3;
    refused(&j.req, INVALID, "CSG node 0's name has a byte 0x31 at offset 0");
    c.node[0].name.data = (uint8_t *)"a\nb", c.node[0].name.len = 3;
    refused(&j.req, INVALID, "CSG node 0's name has a byte 0x0a at offset 1");
    c.node[0].name.data = (uint8_t *)"abcdefghijabcdefghijabcdefghijab", c.node[0].name.len = 32;
    refused(&j.req, INVALID, "CSG node 0's name is 32 bytes, limit 31");
}

Test(proto, csg_primitives)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.node[1].primitive = (Voxd__Primitive)9;
    refused(&j.req, INVALID, "CSG node 1 ('egg') has unknown primitive 9");
    csg_init(&c, &j);
    c.node[0].n_size = 2;
    refused(&j.req, INVALID, "CSG node 0 ('base') needs 3 values for its size, got 2");
    csg_init(&c, &j);
    c.node[0].n_size = 0;
    refused(&j.req, INVALID, "needs 3 values for its size, got 0");
    csg_init(&c, &j);
    c.size[1] = 0;
    refused(&j.req, INVALID, "CSG node 0 ('base')'s size must be positive, value 2 is 0");
    csg_init(&c, &j);
    c.center[2] = INFINITY;
    refused(&j.req, INVALID, "CSG node 0 ('base')'s center value 3 is inf");
    csg_init(&c, &j);
    c.rot[0] = 1e300;
    refused(&j.req, INVALID, "'s rotation value 1 is 1e+300, not a finite number");
    csg_init(&c, &j);
    c.node[1].n_center = 0, c.node[1].n_rotate = 0; /* both may be left out */
    accepted(&j.req);
    c.node[1].axis = VOXD__AXIS__AXIS_X;
    refused(&j.req, INVALID, "CSG node 1 ('egg'): only a cylinder or a cone has an axis");
    c.node[1].primitive = VOXD__PRIMITIVE__PRIMITIVE_CONE;
    accepted(&j.req);
    c.node[1].axis = (Voxd__Axis)7;
    refused(&j.req, INVALID, "CSG node 1 ('egg') has unknown axis 7");
}

Test(proto, csg_implicit_mesh_and_vod_leaves)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.node[1] = (Voxd__CsgNode)VOXD__CSG_NODE__INIT;
    c.node[1].op = VOXD__CSG_OP__CSG_IMPLICIT;
    refused(&j.req, INVALID, "CSG node 1's expression is empty");
    c.node[1].source.data = (uint8_t *)"x\0y", c.node[1].source.len = 3;
    refused(&j.req, INVALID, "CSG node 1's expression source contains a NUL byte at offset 1");
    c.node[1].source.len = 1;
    accepted(&j.req);
    c.node[1].domain = c.dom, c.node[1].n_domain = 2;
    accepted(&j.req);
    c.node[1].n_domain = 6;
    refused(&j.req, INVALID, "CSG node 1's domain needs 2 values (or none), got 6");
    c.node[1].n_domain = 2, c.dom[1] = -3;
    refused(&j.req, INVALID, "CSG node 1's domain: low -1 is not below high -3");
    c.dom[1] = 2;
    lim.max_expr_bytes = 0;
    refused(&j.req, LIMIT, "CSG node 1's expression is 1 bytes, limit 0");

    setup();
    c.node[1] = (Voxd__CsgNode)VOXD__CSG_NODE__INIT;
    c.node[1].op = VOXD__CSG_OP__CSG_MESH;
    refused(&j.req, INVALID, "CSG node 1: a mesh leaf needs its file's data");
    c.node[1].op = VOXD__CSG_OP__CSG_VOD;
    refused(&j.req, INVALID, "CSG node 1: a vod leaf needs its file's data");
    c.node[1].data.data = (uint8_t *)"0123456789", c.node[1].data.len = 10;
    accepted(&j.req);
    c.node[1].scale = 2;
    refused(&j.req, INVALID, "CSG node 1 (vod) does not take a mesh's fit or scale");
    c.node[1].op = VOXD__CSG_OP__CSG_MESH;
    accepted(&j.req);
    c.node[1].scale = -1;
    refused(&j.req, INVALID, "CSG node 1's scale is -1: 0 (none) or a positive number");
    c.node[1].scale = 0;
    c.node[1].fit = c.center, c.node[1].n_fit = 2;
    refused(&j.req, INVALID, "CSG node 1 needs 3 values for its fit, got 2");
    c.node[1].n_fit = 3;
    accepted(&j.req);
    lim.max_csg_leaf_bytes = 9;
    refused(&j.req, LIMIT, "the CSG job's leaves are 10 bytes, over this server's "
                           "max_csg_leaf_bytes of 9");
    setup();
    c.node[2].data.data = (uint8_t *)"x", c.node[2].data.len = 1;
    refused(&j.req, INVALID, "CSG node 2 (difference) does not take a file's data");
    c.node[2].data.len = 0, c.node[2].data_bytes = 1;
    refused(&j.req, INVALID, "CSG node 2 (difference) does not take a file's data");
    c.node[2].data_bytes = 0;

    /* The leaves' files as the job's input: sizes in the nodes, adding up. */
    c.node[1].fit = NULL, c.node[1].n_fit = 0;
    c.node[1].data.len = 0, c.node[1].data_bytes = 1000;
    refused(&j.req, INVALID, "CSG node 1 has data_bytes but the job declares no input_bytes");
    j.sub.input_bytes = 999;
    refused(&j.req, INVALID, "data_bytes add up to 1000, the job declares 999 bytes of input");
    j.sub.input_bytes = 1000;
    accepted(&j.req);
    c.node[1].data.len = 10;
    refused(&j.req, INVALID, "CSG node 1: its file comes inline or as input (data_bytes), not both");
    c.node[1].data.len = 0;
    lim.max_csg_leaf_bytes = 999;
    refused(&j.req, LIMIT, "CSG node 1's file is 1000 bytes, over this server's max_csg_leaf_bytes of 999");
}

Test(proto, csg_stray_fields_and_numbers)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.node[2].source.data = (uint8_t *)"x", c.node[2].source.len = 1;
    refused(&j.req, INVALID, "CSG node 2 (difference) does not take an expression or its domain");
    csg_init(&c, &j);
    c.node[3].n_size = 3, c.node[3].size = c.size;
    refused(&j.req, INVALID, "CSG node 3 (inverse) does not take a primitive's fields");
    csg_init(&c, &j);
    c.node[0].scalar = NAN;
    refused(&j.req, INVALID, "CSG node 0 ('base') (primitive) does not take a scalar");
    csg_init(&c, &j);
    c.node[3].k = 2;
    refused(&j.req, INVALID, "CSG node 3 (inverse) does not take k");

    csg_init(&c, &j);
    c.node[2].op = VOXD__CSG_OP__CSG_DIVIDE;
    refused(&j.req, INVALID, "CSG node 2 (divide) needs a scalar S_L in (0, 1], got 0");
    c.node[2].scalar = 1.5;
    refused(&j.req, INVALID, "got 1.5");
    c.node[2].scalar = NAN;
    refused(&j.req, INVALID, "got nan");
    c.node[2].scalar = 0.5;
    accepted(&j.req);

    csg_init(&c, &j);
    c.node[3].op = VOXD__CSG_OP__CSG_SCALAR_MUL;
    c.node[3].scalar = INFINITY;
    refused(&j.req, INVALID, "CSG node 3 needs a finite scalar, got inf");
    c.node[3].scalar = -3;
    accepted(&j.req);
    c.node[3].scalar = 0;
    c.node[3].op = VOXD__CSG_OP__CSG_ERODE;
    refused(&j.req, INVALID, "CSG node 3 needs k of 1..16 voxels, got 0");
    c.node[3].k = 17;
    refused(&j.req, INVALID, "got 17");
    c.node[3].k = 16;
    accepted(&j.req);
}

Test(proto, csg_domain_res_and_name)
{
    csg c;
    job j;
    csg_init(&c, &j);
    c.csg.n_domain = 0;
    refused(&j.req, INVALID, "domain needs 2 or 6 values, got 0");
    csg_init(&c, &j);
    c.csg.res = 100000;
    refused(&j.req, LIMIT, "res 100000 is over this server's limit of 4096");
    csg_init(&c, &j);
    c.csg.source_name.data = (uint8_t *)"a\nb", c.csg.source_name.len = 3;
    refused(&j.req, INVALID, "source_name contains a line break at offset 1");
}

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
            cr_expect(row->min == FRAME_MIN_MAX && row->max == FRAME_LIMIT_MAX &&
                      row->def == FRAME_DEFAULT_MAX);
        if (!strcmp(row->name, "max_expr_depth")) cr_expect_eq(row->max, EXPR_MAX_DEPTH_CAP);
        if (!strcmp(row->name, "chunk_size")) cr_expect_leq(row->max, FRAME_LIMIT_MAX);
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
    cr_assert_eq(frame_encode_request(&j.req, &buf, &n), 0);
    Voxd__Request *r = frame_unpack_request(buf + 4, n - 4);
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
    cr_assert_eq(frame_encode_request(&c.req, &buf, &n), 0);
    Voxd__Request *r = frame_unpack_request(buf + 4, n - 4);
    cr_assert_not_null(r);
    cr_assert_eq(r->msg_case, VOXD__REQUEST__MSG_INPUT);
    cr_assert(r->input->job_id == 3 && r->input->offset == 12345 && r->input->data.len == 7);
    accepted(r);
    voxd__request__free_unpacked(r, NULL);
    free(buf);
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
