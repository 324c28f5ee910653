/* proto_check_int — what the two halves of proto_check share: proto_check.c
 * (the limits, the requests) and proto_check_reply.c (the replies). */
#ifndef VOXD_PROTO_CHECK_INT_H
#define VOXD_PROTO_CHECK_INT_H

#include <stddef.h>

#include "proto_check.h"

#define INVALID VOXD__ERROR_CODE__INVALID_INPUT
#define LIMIT VOXD__ERROR_CODE__LIMIT_EXCEEDED

/* e's code and message (e may be NULL); -E2BIG for LIMIT, else -EINVAL. */
__attribute__((format(printf, 3, 4)))
int proto_bad(proto_error *e, Voxd__ErrorCode code, const char *fmt, ...);
/* e cleared; 0. */
int proto_ok(proto_error *e);
/* Text for logs and terminals: at most max bytes, UTF-8, no control
 * characters (newline and tab allowed where multiline is set). */
int proto_check_text(const char *s, size_t max, int multiline, const char *what,
                     proto_error *e);

#endif
