/* proto_fixture — what the validator's suites (test_proto*.c) share: the limits
 * every check runs against, a valid implicit job to break field by field, and
 * the assertions that a request is refused with its code and message, or
 * accepted. */
#ifndef VOXD_TEST_PROTO_FIXTURE_H
#define VOXD_TEST_PROTO_FIXTURE_H

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

static inline void setup(void)
{
    proto_limits_default(&lim);
}

/* A valid implicit job, ready to be spoiled one field at a time. */
typedef struct {
    Voxd__Request req;
    Voxd__Submit sub;
    Voxd__Implicit im;
    double dom[6];
    char src[64];
} job;

static inline void job_init(job *j)
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
static inline void refused(const Voxd__Request *r, Voxd__ErrorCode code, const char *want)
{
    proto_error e;
    int rc = proto_check_request(r, &lim, &e);
    cr_assert_eq(rc, code == LIMIT ? -E2BIG : -EINVAL, "rc %d for '%s'", rc, e.msg);
    cr_assert_eq(e.code, code, "code %s for '%s'", proto_error_code_name(e.code), e.msg);
    cr_assert(strstr(e.msg, want), "message '%s' lacks '%s'", e.msg, want);
}

static inline void accepted(const Voxd__Request *r)
{
    proto_error e;
    int rc = proto_check_request(r, &lim, &e);
    cr_assert_eq(rc, 0, "refused: %s", e.msg);
    cr_assert_eq(e.msg[0], '\0');
}

#endif
