/* log — the daemon's log.  See log.h. */
#include "log.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <syslog.h>
#include <time.h>
#include <unistd.h>

#include "clock.h"
static struct {
    int fd;              /* 2, or our descriptor of path */
    int own;             /* fd is ours to close */
    int level;
    char path[PATH_MAX]; /* "" = stderr, or syslog when detached */
    char ident[32];
    int detached;        /* no path means syslog (log_set_detached) */
    int syslog;          /* lines go to syslog(3) */
} L = {2, 0, LOG_LEVEL_INFO, "", "voxd", 0, 0};

static const char *const level_names[] = {"error", "warn", "info", "debug"};

int log_level_parse(const char *name)
{
    for (int i = 0; i <= LOG_LEVEL_DEBUG; i++)
        if (strcmp(name, level_names[i]) == 0) return i;
    return -1;
}

const char *log_level_name(int level)
{
    return level >= 0 && level <= LOG_LEVEL_DEBUG ? level_names[level] : "?";
}

void log_set_level(int level)
{
    if (level < LOG_LEVEL_ERROR) level = LOG_LEVEL_ERROR;
    if (level > LOG_LEVEL_DEBUG) level = LOG_LEVEL_DEBUG;
    L.level = level;
}

int log_get_level(void)
{
    return L.level;
}

static int open_path(const char *path)
{
    int fd = open(path, O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC, 0640);
    return fd < 0 ? -errno : fd;
}

void log_set_detached(int on)
{
    L.detached = on;
}

int log_open(const char *path, const char *ident, int level)
{
    int fd = 2, own = path && *path;
    if (own) {
        if (strlen(path) >= sizeof L.path) return -ENAMETOOLONG;
        if ((fd = open_path(path)) < 0) return fd;
    }
    log_close();
    L.fd = fd;
    L.own = own;
    snprintf(L.path, sizeof L.path, "%s", own ? path : "");
    snprintf(L.ident, sizeof L.ident, "%s", ident ? ident : "voxd");
    log_set_level(level);
    /* openlog keeps the pointer: L.ident lives as long as the process */
    if ((L.syslog = !own && L.detached)) openlog(L.ident, LOG_PID | LOG_NDELAY, LOG_DAEMON);
    return 0;
}

int log_reopen(void)
{
    if (!L.path[0]) return 0;
    int fd = open_path(L.path);
    if (fd < 0) return fd;
    /* dup2 swaps the file under the same number, so a forked child that
     * inherited L.fd keeps a valid descriptor too. */
    int rc = dup2(fd, L.fd) < 0 ? -errno : 0;
    close(fd);
    return rc;
}

void log_close(void)
{
    if (L.syslog) closelog();
    L.syslog = 0;
    if (L.own) close(L.fd);
    L.fd = 2;
    L.own = 0;
    L.path[0] = '\0';
}

/* "2025-01-31T12:00:00.123Z voxd[4242] info: " into buf. */
static int prefix(char *buf, size_t len, int level)
{
    struct timespec ts;
    struct tm tm;
    clock_gettime(CLOCK_REALTIME, &ts);
    gmtime_r(&ts.tv_sec, &tm);
    char when[32];
    strftime(when, sizeof when, "%Y-%m-%dT%H:%M:%S", &tm);
    return snprintf(buf, len, "%s.%03ldZ %s[%ld] %s: ", when, ts.tv_nsec / 1000000,
                    L.ident, (long)getpid(), log_level_name(level));
}

/* syslog's priority of a level */
static int priority(int level)
{
    static const int p[] = {LOG_ERR, LOG_WARNING, LOG_INFO, LOG_DEBUG};
    return p[level < 0 ? 0 : level > LOG_LEVEL_DEBUG ? LOG_LEVEL_DEBUG : level];
}

void log_vmsg(int level, const char *fmt, va_list ap)
{
    if (level > L.level) return;
    if (L.syslog) { /* syslog stamps the time, the ident and the pid itself */
        char msg[LOG_MAX_LINE];
        vsnprintf(msg, sizeof msg, fmt, ap);
        for (char *c = msg; *c; c++)
            if ((unsigned char)*c < 0x20 || *c == 0x7f) *c = '?';
        syslog(priority(level), "%s: %s", log_level_name(level), msg);
        return;
    }
    char line[LOG_MAX_LINE];
    int n = prefix(line, sizeof line - 1, level);
    if (n < 0 || (size_t)n >= sizeof line - 1) return;
    int m = vsnprintf(line + n, sizeof line - 1 - (size_t)n, fmt, ap);
    if (m < 0) return;
    size_t end = (size_t)n + (size_t)m;
    if (end > sizeof line - 2) end = sizeof line - 2; /* cut, keep room for '\n' */
    for (size_t i = (size_t)n; i < end; i++)
        if ((unsigned char)line[i] < 0x20 || line[i] == 0x7f) line[i] = '?';
    line[end++] = '\n';
    ssize_t w;
    do w = write(L.fd, line, end);
    while (w < 0 && errno == EINTR);
}

void log_msg(int level, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    log_vmsg(level, fmt, ap);
    va_end(ap);
}

#define LOG_FN(name, level)                                                   \
    void name(const char *fmt, ...)                                           \
    {                                                                         \
        va_list ap;                                                           \
        va_start(ap, fmt);                                                    \
        log_vmsg(level, fmt, ap);                                             \
        va_end(ap);                                                           \
    }
LOG_FN(log_error, LOG_LEVEL_ERROR)
LOG_FN(log_warn, LOG_LEVEL_WARN)
LOG_FN(log_info, LOG_LEVEL_INFO)
LOG_FN(log_debug, LOG_LEVEL_DEBUG)

/* ---------------------------------------------------------------- rate limits */

/* Tokens come back at LOG_LIMIT_PER_S, up to the burst. */
static void refill(log_limit *l, double now)
{
    if (l->t > 0 && now > l->t) l->tokens += (now - l->t) * LOG_LIMIT_PER_S;
    if (l->tokens > LOG_LIMIT_BURST) l->tokens = LOG_LIMIT_BURST;
    if (now > l->t) l->t = now;
}

int log_limit_take(log_limit *l, double now, int level)
{
    refill(l, now);
    if (l->tokens >= 1) {
        l->tokens -= 1;
        return 1;
    }
    if (level < l->level) l->level = level;
    l->suppressed++;
    return 0;
}

static void summary(log_limit *l)
{
    log_msg(l->level, "%lu similar message%s suppressed (%s)", l->suppressed,
            l->suppressed == 1 ? "" : "s", l->what);
    l->suppressed = 0;
    l->level = LOG_LEVEL_DEBUG;
}

void log_limited(log_limit *l, int level, const char *fmt, ...)
{
    if (level > L.level || !log_limit_take(l, clock_now(), level)) return;
    if (l->suppressed) summary(l);
    va_list ap;
    va_start(ap, fmt);
    log_vmsg(level, fmt, ap);
    va_end(ap);
}

void log_limit_flush(log_limit *l, double now)
{
    if (!l->suppressed) return;
    refill(l, now);
    if (l->tokens < 1) return;
    l->tokens -= 1;
    summary(l);
}
