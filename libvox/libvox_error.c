/* libvox's errors: the texts of vox_strerror and the setters of a
 * vox_error (a job's, a call's, the connection's sticky failure). */
#include "vox.h"

#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "err.h"
#include "libvox_int.h"

static const char *const server_names[] = {
    "INVALID_INPUT", "LIMIT_EXCEEDED", "BUSY",          "CANCELLED",
    "WORKER_CRASHED", "TIMEOUT",       "SHUTTING_DOWN", "INTERNAL",
};
static const char *const server_texts[] = {
    "the daemon refused the job as invalid",
    "over a limit of the daemon",
    "the daemon is busy",
    "the job was cancelled",
    "a worker of the daemon died during the job",
    "the job ran past the daemon's time limit",
    "the daemon is shutting down",
    "internal error in the daemon",
};

const char *vox_error_name(int code)
{
    if (!VOX_IS_SERVER_ERROR(code)) return NULL;
    return server_names[-code - VOX_ESERVER_BASE - 1];
}

const char *vox_strerror(int code)
{
    if (code == 0) return "success";
    if (VOX_IS_SERVER_ERROR(code)) return server_texts[-code - VOX_ESERVER_BASE - 1];
    switch (code) {
    case -ETIMEDOUT: return "the daemon did not answer in time";
    case -ECONNRESET: return "the daemon closed the connection";
    case -EPROTO: return "the daemon broke the protocol";
    case -EBADMSG: return "the result does not check (length or CRC-32)";
    }
    if (code < 0 && code > -4096) return strerror(-code);
    return "unknown error";
}

__attribute__((format(printf, 4, 5)))
void libvox_set_error(vox_error *e, int code, uint64_t job, const char *fmt, ...)
{
    if (!e) return; /* the caller passed no vox_error: it wants no message */
    e->code = code;
    e->job_id = job;
    va_list ap;
    va_start(ap, fmt);
    err_vfmt(e->message, sizeof e->message, code, fmt, ap);
    va_end(ap);
}

void libvox_copy_error(vox_error *dst, const vox_error *src)
{
    if (dst) *dst = *src;
}

/* Fail the connection (once: the first failure is the one reported). */
__attribute__((format(printf, 3, 4)))
int libvox_fail(vox_client *c, int code, const char *fmt, ...)
{
    if (c->err) return c->err;
    c->err = code;
    c->fail.code = code;
    c->fail.job_id = 0;
    va_list ap;
    va_start(ap, fmt);
    err_vfmt(c->fail.message, sizeof c->fail.message, code, fmt, ap);
    va_end(ap);
    return code;
}
