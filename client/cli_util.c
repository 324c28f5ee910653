/* Parsers and helpers shared by the vox subcommands. */
#include "cli.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "par.h"
#include "prefault.h"
#include "thread_name.h"

int cli_parse_domain(const char *s, double lo[3], double hi[3])
{
    double v[6];
    int n = 0;
    const char *p = s;
    while (n < 6) {
        char *end;
        errno = 0;
        v[n] = strtod(p, &end);
        if (end == p || errno || !isfinite(v[n])) return -1;
        n++;
        if (*end == '\0') break;
        if (*end != ',') return -1;
        p = end + 1;
    }
    if (n == 2)
        for (int a = 0; a < 3; a++) lo[a] = v[0], hi[a] = v[1];
    else if (n == 6)
        for (int a = 0; a < 3; a++) lo[a] = v[2 * a], hi[a] = v[2 * a + 1];
    else
        return -1;
    for (int a = 0; a < 3; a++)
        if (!(lo[a] < hi[a])) return -1;
    return 0;
}

int cli_parse_uint(const char *s, uint32_t min, uint32_t max, uint32_t *out)
{
    char *end;
    errno = 0;
    if (*s < '0' || *s > '9') return -1;
    unsigned long v = strtoul(s, &end, 10);
    if (errno || *end || v < min || v > max) return -1;
    *out = (uint32_t)v;
    return 0;
}

int cli_parse_cpus(const char *s, int *cpus, int cap)
{
    int n = 0;
    const char *p = s;
    for (;;) {
        char *end;
        long a = strtol(p, &end, 10), b;
        if (end == p || a < 0 || a > 4095) return -1;
        b = a;
        if (*end == '-') {
            p = end + 1;
            b = strtol(p, &end, 10);
            if (end == p || b < a || b > 4095) return -1;
        }
        for (long c = a; c <= b; c++) {
            if (n == cap) return -1;
            cpus[n++] = (int)c;
        }
        if (*end == '\0') return n;
        if (*end != ',') return -1;
        p = end + 1;
    }
}

/* A file's bytes read into buf in parts, each on a thread of its own
 * (pread at its offset): the copy's time is mostly the first touch of the
 * buffer's pages, which the threads share. */
typedef struct {
    int fd;
    char *buf;
    size_t n;
    /* The first error (0: none).  Relaxed: read after par_run joins. */
    atomic_int err;
} file_read;

static void read_part(void *ud, unsigned k, unsigned parts)
{
    file_read *r = ud;
    size_t lo = r->n * k / parts, hi = r->n * (k + 1) / parts;
    prefault_write(r->buf + lo, hi - lo);
    while (lo < hi) {
        ssize_t got = pread(r->fd, r->buf + lo, hi - lo, (off_t)lo);
        if (got < 0 && errno == EINTR) continue;
        if (got <= 0) { /* an error, or the file cut short meanwhile */
            atomic_store_explicit(&r->err, got < 0 ? errno : EIO, memory_order_relaxed);
            return;
        }
        lo += (size_t)got;
    }
}

int cli_read_file(const char *path, size_t max, char **out, size_t *len)
{
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0) return -errno;
    struct stat st;
    if (fstat(fd, &st) != 0 || (size_t)st.st_size > max) {
        close(fd);
        return -EFBIG;
    }
    /* on every CPU for a large file, its pages made present first (one
     * call, not a fault a page): by one thread, the dragon's 33 MB PLY as
     * a CSG leaf took 18-23 ms before the job could start, now 2-7 (huge
     * pages, tried, sometimes stalled 20 ms on their allocation) */
    file_read r = {.fd = fd, .n = (size_t)st.st_size, .buf = malloc((size_t)st.st_size + 1)};
    atomic_init(&r.err, 0);
    if (!r.buf) {
        close(fd);
        return -ENOMEM;
    }
    unsigned parts = (unsigned)(r.n / ((size_t)4 << 20)) + 1, cpus = par_cpus();
    par_run(parts < cpus ? parts : cpus, read_part, &r);
    close(fd);
    int err = atomic_load_explicit(&r.err, memory_order_relaxed);
    if (err) {
        free(r.buf);
        return -err;
    }
    r.buf[r.n] = '\0';
    *out = r.buf;
    *len = r.n;
    return 0;
}

uint32_t cli_cores(void)
{
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    return n > 0 ? (uint32_t)n : 1;
}

int cli_start_engine(uint32_t workers, const char *cpus, uint32_t shm_mib, engine **e)
{
    int cpu[ENGINE_MAX_WORKERS], ncpus = 0;
    if (cpus && (ncpus = cli_parse_cpus(cpus, cpu, ENGINE_MAX_WORKERS)) <= 0) {
        cli_error("bad --cpus '%.40s': want a list like 0,1 or 0-3", cpus);
        return -EINVAL;
    }
    engine_opts eo = {.workers = (int)workers, .cpus = ncpus ? cpu : NULL,
                      .ncpus = ncpus, .shm_bytes = (size_t)shm_mib << 20,
                      .shm_option = "--shm-size"};
    err_info err = {0};
    thread_name("start");
    int rc = engine_create(&eo, e, &err);
    if (rc == -ENOSPC) cli_error("cannot start the engine: %s (--shm-size MIB sets it)", err.msg);
    else if (rc) cli_error("cannot start the engine: %s", err.msg[0] ? err.msg : strerror(-rc));
    return rc;
}

/* AddressSanitizer (cli.h says why it matters here): GCC says so by
 * __SANITIZE_ADDRESS__, clang by __has_feature (which GCC 12 lacks, so
 * the test is nested). */
#if defined(__SANITIZE_ADDRESS__)
#define CLI_FORK_UNSAFE_MALLOC 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define CLI_FORK_UNSAFE_MALLOC 1
#endif
#endif

int cli_start_engine_beside(par_task *t, void *(*fn)(void *ud), void *ud, uint32_t workers,
                            const char *cpus, uint32_t shm_mib, engine **e)
{
    int rc = 0;
#ifdef CLI_FORK_UNSAFE_MALLOC
    if (workers) rc = cli_start_engine(workers, cpus, shm_mib, e);
    par_start(t, fn, ud);
#else
    par_start(t, fn, ud);
    if (workers) rc = cli_start_engine(workers, cpus, shm_mib, e);
#endif
    return rc;
}

/* ---------------------------------------------------------------- interrupts */

atomic_int cli_interrupt;

static void on_interrupt(int sig)
{
    /* relaxed: a flag the same process's loops poll (pairs with their
     * relaxed loads); nothing else is published through it */
    atomic_store_explicit(&cli_interrupt, sig, memory_order_relaxed);
    /* a second one ends vox at once */
    struct sigaction dfl = {.sa_handler = SIG_DFL};
    sigaction(sig, &dfl, NULL);
}

void cli_catch_interrupts(void)
{
    /* without SA_RESTART: a blocking call returns EINTR and its loop sees
     * the flag */
    struct sigaction sa = {.sa_handler = on_interrupt};
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
}

int cli_interrupted(void)
{
    return atomic_load_explicit(&cli_interrupt, memory_order_relaxed);
}

_Noreturn void cli_end_interrupted(const char *out)
{
    int sig = cli_interrupted();
    cli_error("interrupted (%s); %s not written", sig == SIGINT ? "SIGINT" : "SIGTERM", out);
    fflush(NULL);
    struct sigaction dfl = {.sa_handler = SIG_DFL};
    sigaction(sig, &dfl, NULL);
    raise(sig);
    _exit(128 + sig);
}
