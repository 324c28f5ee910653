/* log — the daemon's log: one line per message, to a file, stderr, or (a
 * detached daemon without a file) syslog(3) with facility daemon.
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
/* On (voxd --daemon): no path means syslog, not the terminal left behind;
 * before log_open, and kept by the reopens of a reload. */
void log_set_detached(int on);
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

/* A rate limit for one kind of repeated message, so that a flood (2,000
 * refused connections, a client sending garbage in a loop) writes a few
 * lines, not one per event.  A token bucket: LOG_LIMIT_BURST lines may go
 * out at once, then one more each 1/LOG_LIMIT_PER_S seconds; the lines it
 * holds back are counted, and the next line it lets through is preceded by
 * one summary, at the level of the most severe line held back:
 *
 *   ... voxd[4242] warn: 1995 similar messages suppressed (refused connections: max_clients)
 *
 * log_limit_flush writes that summary when no line comes to carry it (the
 * daemon calls it from its housekeeping timer), when a token allows.  A
 * line below the log level is neither written nor counted.  One log_limit
 * per kind, LOG_LIMIT_INIT("what it counts"); not thread-safe (the loop's). */
#define LOG_LIMIT_BURST 5
#define LOG_LIMIT_PER_S 1.0

typedef struct {
    const char *what;         /* the kind, in its summary */
    double tokens;            /* lines that may go out now (at most LOG_LIMIT_BURST) */
    double t;                 /* monotonic seconds of the last refill; 0 = never */
    unsigned long suppressed; /* lines held back since the last summary */
    int level;                /* the most severe of them */
} log_limit;

#define LOG_LIMIT_INIT(what_) \
    {.what = (what_), .tokens = LOG_LIMIT_BURST, .level = LOG_LEVEL_DEBUG}

/* The bucket alone, at monotonic time now: 1 when a line of this level may
 * go out (its token taken), 0 when it is held back (counted). */
int log_limit_take(log_limit *l, double now, int level);
/* A line through the limit l. */
__attribute__((format(printf, 3, 4)))
void log_limited(log_limit *l, int level, const char *fmt, ...);
/* The summary of the lines held back, if any and if a token allows. */
void log_limit_flush(log_limit *l, double now);

#endif
