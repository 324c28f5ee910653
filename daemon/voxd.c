/* voxd — the voxelization daemon: options, configuration, the lock that
 * tells a live daemon from a crashed one's leftovers, --daemon with its
 * pidfile; then daemon.c serves until a signal says stop. */
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "config.h"
#include "daemon.h"
#include "heap.h"
#include "log.h"
#include "suggest.h"

#include "version.h"

#define LOCK_PATIENCE_MS 2000 /* workers of a crashed daemon die within ms */

static const char usage[] =
    "usage: voxd [options]\n"
    "Voxelization daemon: serves jobs from vox and libvox on a Unix socket.\n"
    "\n"
    "  -c, --config FILE        configuration file (default " CONFIG_DEFAULT_PATH
    " if it\n"
    "                           exists, else the built-in defaults)\n"
    "  -s, --socket PATH        socket to listen on (overrides the file's socket)\n"
    "  -w, --workers N          worker processes, 1..256 (overrides the file's workers)\n"
    "      --client-timeout S   seconds a client may take to send hello, to finish\n"
    "                           a started frame, or to read a pending reply, 1..86400\n"
    "                           (overrides the file's client_timeout, default 30)\n"
    "      --worker-stall-timeout S  seconds a busy worker may go without progress\n"
    "                           before it is killed and replaced, 0..3600, 0 = never\n"
    "                           (overrides the file's worker_stall_timeout, default 10)\n"
    "  -d, --daemon             detach from the terminal once serving; write pidfile\n"
    "      --check-config FILE  load FILE, print the effective settings, exit 0 (valid)\n"
    "                           or 1 (FILE:LINE: why)\n"
    "  -h, --help               this text\n"
    "  -V, --version            the version and the git commit it was built from\n"
    "\n"
    "Signals: TERM/INT stop now (running jobs end with SHUTTING_DOWN); QUIT stops\n"
    "accepting and exits when the running and queued jobs are done; HUP rereads the\n"
    "configuration and replaces the workers between jobs; USR1 reopens the log.\n"
    "A second voxd on the same socket refuses to start; a crashed one's socket and\n"
    "shared memory are removed at start (under the lock file SOCKET.lock).\n";

typedef struct {
    daemon_options o;
    int daemonize;
    const char *check;
    char socket[CONFIG_SOCKET_MAX];
} voxd_args;

/* An argument in a message: at most 40 bytes of it, then "...". */
#define ARG(s) (strlen(s) > 40 ? 40 : (int)strlen(s)), (s), (strlen(s) > 40 ? "..." : "")

static int parse_uint(const char *s, unsigned lo, unsigned hi, unsigned *out)
{
    char *end;
    errno = 0;
    unsigned long v = strtoul(s, &end, 10);
    if (errno || end == s || *end || s[0] == '-' || v < lo || v > hi) return -1;
    *out = (unsigned)v;
    return 0;
}

/* --socket relative to the current directory becomes absolute (the daemon
 * may change directory, and the socket file is removed on exit). */
static int set_socket(voxd_args *a, const char *path)
{
    char cwd[4096] = "";
    if (path[0] != '/' && !getcwd(cwd, sizeof cwd)) return -1;
    int n = snprintf(a->socket, sizeof a->socket, "%s%s%s", cwd, cwd[0] ? "/" : "", path);
    if (n < 0 || (size_t)n >= sizeof a->socket) return -1;
    a->o.socket = a->socket;
    return 0;
}

/* "voxd: message; see 'voxd --help'": CLI_EXIT_USAGE. */
__attribute__((format(printf, 1, 2))) static int usage_error(const char *fmt, ...)
{
    char msg[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    fprintf(stderr, "voxd: %s; see 'voxd --help'\n", msg);
    return CLI_EXIT_USAGE;
}

/* getopt's '?' or ':' (it printed nothing: opterr is 0), in one line. */
static int option_error(int c, char **argv, const struct option *longs)
{
    const char *arg = argv[optind - 1];
    int n = (int)strcspn(arg, "=");
    if (c == ':') {
        if (!strncmp(arg, "--", 2)) return usage_error("option '%.*s' needs a value", n, arg);
        return usage_error("option '-%c' needs a value", optopt);
    }
    if (strncmp(arg, "--", 2) || (optopt && !strchr(arg, '=')))
        return usage_error("unknown option '-%c'", optopt);
    if (optopt) return usage_error("option '%.*s' takes no value", n, arg);
    const char *names[32];
    char store[32][32];
    int k = 0;
    for (; longs[k].name && k < 31; k++) {
        snprintf(store[k], sizeof store[k], "--%s", longs[k].name);
        names[k] = store[k];
    }
    names[k] = NULL;
    const char *near = suggest_nearest(arg, (size_t)n, names);
    if (n > 40) n = 40;
    if (near) return usage_error("unknown option '%.*s' (did you mean '%s'?)", n, arg, near);
    return usage_error("unknown option '%.*s'", n, arg);
}

static int parse_args(int argc, char **argv, voxd_args *a)
{
    static const struct option longs[] = {
        {"config", 1, 0, 'c'}, {"socket", 1, 0, 's'}, {"workers", 1, 0, 'w'},
        {"client-timeout", 1, 0, 'T'}, {"worker-stall-timeout", 1, 0, 'S'},
        {"daemon", 0, 0, 'd'},
        {"check-config", 1, 0, 'C'}, {"help", 0, 0, 'h'}, {"version", 0, 0, 'V'},
        {0, 0, 0, 0}};
    unsigned u;
    int c;
    opterr = 0;
    while ((c = getopt_long(argc, argv, ":c:s:w:dhV", longs, NULL)) != -1) {
        switch (c) {
        case 'c': a->o.config_path = optarg; break;
        case 's':
            if (set_socket(a, optarg)) {
                fprintf(stderr, "voxd: socket path '%.*s%s' is too long (under %d bytes)\n",
                        ARG(optarg), CONFIG_SOCKET_MAX);
                return CLI_EXIT_USAGE;
            }
            break;
        case 'w':
            if (parse_uint(optarg, 1, CONFIG_MAX_WORKERS, &u)) {
                fprintf(stderr, "voxd: bad --workers '%.*s%s': want 1..%d\n", ARG(optarg),
                        CONFIG_MAX_WORKERS);
                return CLI_EXIT_USAGE;
            }
            a->o.workers = (int)u;
            break;
        case 'T':
            if (parse_uint(optarg, 1, 86400, &u)) {
                fprintf(stderr, "voxd: bad --client-timeout '%.*s%s': want seconds 1..86400\n",
                        ARG(optarg));
                return CLI_EXIT_USAGE;
            }
            a->o.client_timeout = u;
            break;
        case 'S':
            if (parse_uint(optarg, 0, 3600, &u)) {
                fprintf(stderr,
                        "voxd: bad --worker-stall-timeout '%.*s%s': want seconds 0..3600\n",
                        ARG(optarg));
                return CLI_EXIT_USAGE;
            }
            a->o.stall_timeout = (int)u;
            break;
        case 'd': a->daemonize = 1; break;
        case 'C': a->check = optarg; break;
        case 'h': fputs(usage, stdout); exit(CLI_EXIT_OK);
        case 'V':
            printf("voxd %s (commit %s, protocol 1)\n", VOX_VERSION, VOX_COMMIT);
            exit(CLI_EXIT_OK);
        default: return option_error(c, argv, longs);
        }
    }
    if (optind < argc) return usage_error("unexpected argument '%.*s%s'", ARG(argv[optind]));
    return 0;
}

static int check_config(const char *path)
{
    voxd_config c;
    err_info err = {0};
    if (config_load(path, &c, &err)) {
        fprintf(stderr, "voxd: %s\n", err.msg);
        return CLI_EXIT_FAILED;
    }
    config_print(stdout, &c);
    return CLI_EXIT_OK;
}

/* ---------------------------------------------------------------- the lock */

/* flock on SOCKET.lock, held for the daemon's life: held by someone else
 * means a live daemon.  A worker closes its inherited copy as it starts,
 * but a crashed daemon's worker caught between its fork and that may hold
 * it for a few milliseconds more (it dies with its master), hence the
 * patience. */
static int take_lock(const char *socket, int *fd)
{
    char path[CONFIG_SOCKET_MAX + 8];
    snprintf(path, sizeof path, "%s.lock", socket);
    *fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0600);
    if (*fd < 0) {
        fprintf(stderr, "voxd: cannot open %s: %s\n", path, strerror(errno));
        return -1;
    }
    for (int waited = 0;; waited += 50) {
        if (flock(*fd, LOCK_EX | LOCK_NB) == 0) return 0;
        if (errno != EWOULDBLOCK || waited >= LOCK_PATIENCE_MS) break;
        struct timespec ts = {0, 50 * 1000000L};
        nanosleep(&ts, NULL);
    }
    fprintf(stderr, "voxd: another voxd is running on %s (it holds %s); not starting\n",
            socket, path);
    close(*fd);
    *fd = -1;
    return -1;
}

/* The segment's name follows from the socket path: one daemon per socket,
 * and the lock that guards the socket guards the segment too. */
static void shm_name_for(const char *socket, char *name, size_t n)
{
    uint64_t h = 1469598103934665603ull; /* FNV-1a */
    for (const unsigned char *p = (const unsigned char *)socket; *p; p++)
        h = (h ^ *p) * 1099511628211ull;
    snprintf(name, n, "/voxd-%016llx", (unsigned long long)h);
}

/* Under the lock: whatever is at the socket path and the segment's name
 * was left by a daemon that died. */
static int remove_stale(const char *socket, const char *shm)
{
    struct stat st;
    if (lstat(socket, &st) == 0) {
        if (!S_ISSOCK(st.st_mode)) {
            fprintf(stderr, "voxd: %s exists and is not a socket; not touching it\n", socket);
            return -1;
        }
        if (unlink(socket) != 0) {
            fprintf(stderr, "voxd: cannot remove the stale socket %s: %s\n", socket,
                    strerror(errno));
            return -1;
        }
        log_warn("removed the stale socket %s (a voxd that did not stop cleanly)", socket);
    }
    if (shm_unlink(shm) == 0)
        log_warn("removed the stale shared memory %s", shm);
    return 0;
}

/* ---------------------------------------------------------------- --daemon */

/* Fork; the parent waits until the child serves (a byte on the pipe) or
 * fails (the pipe closes: the child said why on stderr) and exits so. */
static int detach(int *ready_fd)
{
    int p[2];
    if (pipe2(p, O_CLOEXEC) != 0) return -errno;
    pid_t pid = fork();
    if (pid < 0) return -errno;
    if (pid > 0) {
        close(p[1]);
        char b = 0;
        ssize_t r;
        do r = read(p[0], &b, 1);
        while (r < 0 && errno == EINTR);
        _exit(r == 1 && b == '1' ? CLI_EXIT_OK : CLI_EXIT_FAILED);
    }
    close(p[0]);
    setsid();
    *ready_fd = p[1];
    return 0;
}

static int write_pidfile(const char *path)
{
    if (!path[0]) return 0;
    int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) {
        fprintf(stderr, "voxd: cannot write the pidfile %s: %s\n", path, strerror(errno));
        return -1;
    }
    char buf[32];
    int n = snprintf(buf, sizeof buf, "%ld\n", (long)getpid());
    ssize_t w = write(fd, buf, (size_t)n);
    close(fd);
    return w == n ? 0 : -1;
}

/* ---------------------------------------------------------------- main */

static int serve(const voxd_config *cfg, voxd_args *a)
{
    int lock = -1, rc = CLI_EXIT_FAILED;
    char shm[64];
    shm_name_for(cfg->socket, shm, sizeof shm);
    if (take_lock(cfg->socket, &lock) || remove_stale(cfg->socket, shm) ||
        write_pidfile(cfg->pidfile))
        goto out;
    rc = daemon_run(cfg, &a->o, shm);
    unlink(cfg->socket);
    shm_unlink(shm); /* the engine removed it; a failed start may not have */
    if (cfg->pidfile[0]) unlink(cfg->pidfile);
out:
    if (lock >= 0) close(lock);
    return rc;
}

int main(int argc, char **argv)
{
    heap_keep(); /* before any thread: the engine thread gives it back when idle */
    voxd_args a = {.o = {.ready_fd = -1, .stall_timeout = -1}};
    int rc = parse_args(argc, argv, &a);
    if (rc) return rc;
    if (a.check) return check_config(a.check);
    voxd_config cfg;
    err_info err = {0};
    if (daemon_load_config(&a.o, &cfg, &err)) {
        fprintf(stderr, "voxd: %s\n", err.msg);
        return CLI_EXIT_FAILED;
    }
    /* A client that goes away mid-write is an EPIPE, not a signal. */
    signal(SIGPIPE, SIG_IGN);
    log_set_detached(a.daemonize);
    if ((rc = log_open(cfg.log_file, "voxd", cfg.log_level))) {
        fprintf(stderr, "voxd: cannot open the log %s: %s\n", cfg.log_file, strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    if (a.daemonize && (rc = detach(&a.o.ready_fd))) {
        fprintf(stderr, "voxd: cannot detach: %s\n", strerror(-rc));
        return CLI_EXIT_FAILED;
    }
    if (a.daemonize && chdir("/") != 0) return CLI_EXIT_FAILED;
    rc = serve(&cfg, &a);
    log_close();
    return rc;
}
