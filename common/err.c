/* err — see err.h. */
#include "err.h"

#include <stdio.h>

int err_vfmt(char *buf, size_t len, int code, const char *fmt, va_list ap)
{
    if (buf && len) vsnprintf(buf, len, fmt, ap);
    return code;
}

int err_fmt(char *buf, size_t len, int code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    err_vfmt(buf, len, code, fmt, ap);
    va_end(ap);
    return code;
}

int err_vset(err_info *e, int code, const char *fmt, va_list ap)
{
    if (!e) return code;
    e->code = code;
    return err_vfmt(e->msg, sizeof e->msg, code, fmt, ap);
}

int err_set(err_info *e, int code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    err_vset(e, code, fmt, ap);
    va_end(ap);
    return code;
}

void err_clear(err_info *e)
{
    if (!e) return;
    e->code = 0;
    e->msg[0] = '\0';
}
