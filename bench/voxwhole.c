/* voxwhole — runs one command as a user would and measures the whole of it:
 *
 *   voxwhole [-s USEC] [-o FILE] -- COMMAND [ARG...]
 *
 * The command's stdin, stdout and stderr are this program's.  When it ends,
 * one line goes to FILE (default stderr):
 *
 *   wall_s=W maxrss_kib=R tree_peak_kib=P shm_peak_kib=S shm_exact=E
 *   samples=N procs=M
 *
 *   wall_s         fork to the end of wait4, CLOCK_MONOTONIC
 *   maxrss_kib     wait4's ru_maxrss: the peak resident set of the largest
 *                  single process of the tree (the command or one of its
 *                  waited-for descendants).  On Linux it is a maximum, not
 *                  a sum, and it counts the shared pages that one process
 *                  touched.
 *   tree_peak_kib  with -s: the largest, over samples taken every USEC
 *                  microseconds, of the memory of the command and every
 *                  descendant alive at that moment: the sum of their
 *                  private resident pages (RssAnon + RssFile) plus the
 *                  resident pages of the shared memory they map (the
 *                  engine's segment, tmpfs pages under /dev/shm), counted
 *                  once.  A peak shorter than USEC can be missed.
 *   shm_peak_kib   the largest shared-memory part of one sample
 *   shm_exact      1: the shared part is the allocated blocks of the
 *                  shared objects, exact; 0: /proc/PID/map_files was not
 *                  readable (it needs CAP_SYS_ADMIN) and the largest
 *                  RssShmem of one process stood in, a lower bound
 *   samples, procs the samples taken, the most processes seen in one
 *
 * Without -s the last five are 0.  The exit status is the command's (128 +
 * the signal that ended it).  Linux only (/proc); a benchmark helper, not
 * installed. */
#include <ctype.h>
#include <errno.h>
#include <linux/magic.h>
#include <dirent.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/statfs.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "bench_util.h"

#define MAX_PROCS 8192

typedef struct {
    int pid, ppid;
} proc_link;

static void die(const char *what, const char *why)
{
    fprintf(stderr, "voxwhole: %s: %s\n", what, why);
    exit(125);
}

/* The parent of PID from /proc/PID/stat: the field after the state, which
 * follows the last ')' (the command name may hold spaces and parentheses).
 * -1 when the process is gone. */
static int read_ppid(int pid)
{
    char path[64], buf[512];
    snprintf(path, sizeof path, "/proc/%d/stat", pid);
    const char *p = proc_stat_fields(path, buf, sizeof buf);
    char state;
    int ppid;
    if (!p || sscanf(p, " %c %d", &state, &ppid) != 2) return -1;
    return ppid;
}

/* Every process on the machine with its parent; returns the count. */
static int scan_procs(proc_link *out, int max)
{
    DIR *d = opendir("/proc");
    if (!d) return 0;
    int n = 0;
    struct dirent *e;
    while ((e = readdir(d)) && n < max) {
        if (!isdigit((unsigned char)e->d_name[0])) continue;
        int pid = atoi(e->d_name), ppid = read_ppid(pid);
        if (ppid >= 0) out[n++] = (proc_link){pid, ppid};
    }
    closedir(d);
    return n;
}

/* Marks the descendants of ROOT in IN[] (ROOT included), returns how many.
 * Passes until nothing changes: a grandchild may be listed before its
 * parent. */
static int mark_tree(const proc_link *p, int n, int root, unsigned char *in)
{
    int count = 0, changed = 1;
    memset(in, 0, (size_t)n);
    while (changed) {
        changed = 0;
        for (int i = 0; i < n; i++) {
            if (in[i]) continue;
            int hit = p[i].pid == root;
            for (int j = 0; j < n && !hit; j++) hit = in[j] && p[j].pid == p[i].ppid;
            if (hit) in[i] = 1, count++, changed = 1;
        }
    }
    return count;
}

/* The resident counters of /proc/PID/status, in KiB: cheap to read (no
 * page-table walk, unlike smaps_rollup, whose cost and mmap_lock slowed a
 * 4096^3 job 2.5x when sampled every 20 ms).  Zeros once the process is
 * gone or a zombie. */
typedef struct {
    long anon, file, shmem;
} rss_kib;

static rss_kib read_rss(int pid)
{
    char path[64], line[256];
    snprintf(path, sizeof path, "/proc/%d/status", pid);
    rss_kib r = {0, 0, 0};
    FILE *f = fopen(path, "r");
    if (!f) return r;
    while (fgets(line, sizeof line, f)) {
        if (sscanf(line, "RssAnon: %ld kB", &r.anon) == 1) continue;
        if (sscanf(line, "RssFile: %ld kB", &r.file) == 1) continue;
        sscanf(line, "RssShmem: %ld kB", &r.shmem);
    }
    fclose(f);
    return r;
}

/* Distinct shared-memory files seen in one sample, by inode. */
typedef struct {
    unsigned long ino[64];
    int n;
    long kib;
    int ok; /* every /dev/shm mapping could be measured */
} shm_set;

/* Adds the pages of every shared-memory object PID maps (a POSIX segment,
 * a memfd, an anonymous shared mapping, System V: any shared mapping of a
 * tmpfs file).  stat through /proc/PID/map_files gives the object's
 * allocated blocks, which are its resident pages (tmpfs without swap),
 * counted once however many processes map it.  map_files needs
 * CAP_SYS_ADMIN (or CAP_CHECKPOINT_RESTORE); without it ok drops to 0. */
static void add_shm(int pid, shm_set *s)
{
    char path[96], line[512];
    snprintf(path, sizeof path, "/proc/%d/maps", pid);
    FILE *f = fopen(path, "r");
    if (!f) return;
    while (fgets(line, sizeof line, f)) {
        char range[64], perms[8];
        struct stat st;
        struct statfs fs;
        if (sscanf(line, "%63s %7s", range, perms) != 2 || perms[3] != 's') continue;
        snprintf(path, sizeof path, "/proc/%d/map_files/%s", pid, range);
        if (statfs(path, &fs) != 0 || stat(path, &st) != 0) {
            /* ENOENT, ESRCH: unmapped or exited meanwhile, not a refusal */
            if (errno != ENOENT && errno != ESRCH) s->ok = 0;
            continue;
        }
        if (fs.f_type != TMPFS_MAGIC) continue; /* a disk file: page cache */
        int seen = 0;
        for (int i = 0; i < s->n && !seen; i++) seen = s->ino[i] == st.st_ino;
        if (seen) continue;
        if (s->n == (int)(sizeof s->ino / sizeof s->ino[0])) {
            s->ok = 0; /* too many to tell apart */
            continue;
        }
        s->ino[s->n++] = st.st_ino;
        s->kib += (long)st.st_blocks / 2;
    }
    fclose(f);
}

typedef struct {
    long peak_kib, peak_shm_kib;
    int samples, procs, shm_exact;
} tree_stats;

/* One sample: the private pages of every process of the tree (RssAnon +
 * RssFile; the file pages of shared libraries are counted once per
 * process, a few MiB) plus the shared segments counted once. */
static void sample_tree(int root, tree_stats *st)
{
    static proc_link p[MAX_PROCS];
    static unsigned char in[MAX_PROCS];
    int n = scan_procs(p, MAX_PROCS), count = mark_tree(p, n, root, in);
    long priv = 0, max_shmem = 0;
    shm_set shm = {.ok = 1};
    for (int i = 0; i < n; i++) {
        if (!in[i]) continue;
        rss_kib r = read_rss(p[i].pid);
        priv += r.anon + r.file;
        if (r.shmem > max_shmem) max_shmem = r.shmem;
    }
    /* The objects after every RssShmem: their pages only grow while they
     * are mapped, so an object read last is not behind a process read
     * before it. */
    for (int i = 0; i < n; i++)
        if (in[i]) add_shm(p[i].pid, &shm);
    /* The largest RssShmem (what one process maps) is a lower bound of the
     * shared part: it stands in when the objects cannot be measured, and
     * when a process unmapped between the two passes. */
    long seg = shm.kib > max_shmem ? shm.kib : max_shmem;
    if (priv + seg > st->peak_kib) st->peak_kib = priv + seg;
    if (seg > st->peak_shm_kib) st->peak_shm_kib = seg;
    if (count > st->procs) st->procs = count;
    if (st->samples++ == 0) st->shm_exact = 1;
    if (!shm.ok) st->shm_exact = 0;
}

/* Waits for PID; with a sampling period, samples its tree until it exits.
 * A pidfd wakes the poll the moment the child ends, so the wall time is not
 * rounded up to the period. */
static int wait_child(int pid, long period_us, tree_stats *st, int *status,
                      struct rusage *ru)
{
    int pfd = period_us > 0 ? (int)syscall(SYS_pidfd_open, pid, 0) : -1;
    if (period_us > 0 && pfd < 0) die("pidfd_open", strerror(errno));
    while (pfd >= 0) {
        sample_tree(pid, st);
        struct pollfd pf = {.fd = pfd, .events = POLLIN};
        struct timespec ts = {period_us / 1000000, (period_us % 1000000) * 1000};
        int r = ppoll(&pf, 1, &ts, NULL);
        if (r < 0 && errno != EINTR) die("ppoll", strerror(errno));
        if (r > 0) break;
    }
    if (pfd >= 0) close(pfd);
    while (wait4(pid, status, 0, ru) < 0)
        if (errno != EINTR) die("wait4", strerror(errno));
    return 0;
}

static void usage(void)
{
    fprintf(stderr, "usage: voxwhole [-s USEC] [-o FILE] -- COMMAND [ARG...]\n");
    exit(125);
}

int main(int argc, char **argv)
{
    long period_us = 0;
    const char *outpath = NULL;
    int c;
    while ((c = getopt(argc, argv, "+s:o:")) != -1) {
        if (c == 's') period_us = strtol(optarg, NULL, 10);
        else if (c == 'o') outpath = optarg;
        else usage();
    }
    if (optind >= argc || period_us < 0) usage();
    FILE *out = outpath ? fopen(outpath, "w") : stderr;
    if (!out) die(outpath, strerror(errno));

    tree_stats st = {0};
    double t0 = now();
    pid_t pid = fork();
    if (pid < 0) die("fork", strerror(errno));
    if (pid == 0) {
        execvp(argv[optind], argv + optind);
        fprintf(stderr, "voxwhole: %s: %s\n", argv[optind], strerror(errno));
        _exit(127);
    }
    int status;
    struct rusage ru;
    wait_child(pid, period_us, &st, &status, &ru);
    double wall = now() - t0;
    fprintf(out,
            "wall_s=%.6f maxrss_kib=%ld tree_peak_kib=%ld shm_peak_kib=%ld "
            "shm_exact=%d samples=%d procs=%d\n",
            wall, ru.ru_maxrss, st.peak_kib, st.peak_shm_kib, st.shm_exact,
            st.samples, st.procs);
    if (out != stderr) fclose(out);
    if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
    return WEXITSTATUS(status);
}
