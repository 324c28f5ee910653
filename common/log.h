/* log — the daemon's log: one line per message, to a file or stderr.
 *
 *   2025-01-31T12:00:00.123Z voxd[4242] info: listening on /run/voxd/voxd.sock
 *
 * Each line goes out with one write(2) on an O_APPEND descriptor, so lines of
 * the master and of forked workers do not interleave.  Control characters in
 * a message (a client's text may end up there) are written as '?', so one
 * message is one line.  Lines are cut at LOG_MAX_LINE bytes.
 *
 * log_reopen() reopens the file after logrotate moved it; the daemon calls it
 * from its loop when SIGUSR1 arrived (never from the signal handler).
 * Not thread-safe: the daemon's loop is one thread.
 */
#ifndef VOXD_LOG_H
#define VOXD_LOG_H

#include <stdarg.h>

/* Not LOG_ERR / LOG_INFO...: those are <syslog.h> macros. */
enum log_level {
    LOG_LEVEL_ERROR = 0,
    LOG_LEVEL_WARN = 1,
    LOG_LEVEL_INFO = 2,
    LOG_LEVEL_DEBUG = 3,
};

#define LOG_MAX_LINE 2048

/* Log to path (appended, created 0640), or to stderr when path is NULL or
 * "".  ident names the process in each line ("voxd", "voxd-worker").
 * Returns 0 or a negative errno (the previous destination stays). */
int log_open(const char *path, const char *ident, int level);
/* Reopen the same path (0 when logging to stderr); on failure the old
 * descriptor stays in use and a negative errno is returned. */
int log_reopen(void);
void log_close(void);
void log_set_level(int level);
int log_get_level(void);

/* "error", "warn", "info", "debug" <-> level; -1 for an unknown name. */
int log_level_parse(const char *name);
const char *log_level_name(int level);

__attribute__((format(printf, 2, 0)))
void log_vmsg(int level, const char *fmt, va_list ap);
__attribute__((format(printf, 2, 3)))
void log_msg(int level, const char *fmt, ...);
__attribute__((format(printf, 1, 2))) void log_error(const char *fmt, ...);
__attribute__((format(printf, 1, 2))) void log_warn(const char *fmt, ...);
__attribute__((format(printf, 1, 2))) void log_info(const char *fmt, ...);
__attribute__((format(printf, 1, 2))) void log_debug(const char *fmt, ...);

#endif
