/* voxserial — runs one command and measures, from outside its processes,
 * how much of its time is serial:
 *
 *   voxserial [-p USEC] [-n N] [-t FRACTION] [-l MS [-w]] [-o FILE] -- COMMAND [ARG...]
 *   voxserial -S THREADS:SECONDS
 *
 * Every USEC microseconds (default 5000) it reads /proc/PID/task/TID/stat and
 * /proc/PID/task/TID/schedstat of every thread of the command's whole
 * process tree (the command, its threads, its children found through
 * /proc/PID/task/TID/children, theirs: the engine's forked workers) and
 * classes the window since the last sample twice:
 *
 *   - by the threads that were runnable at the sample (state R: on a CPU or
 *     waiting on a run queue for one): the job's own parallelism, which
 *     other users' load on a shared machine does not change.  Over many
 *     samples, the share of windows with at most one runnable thread is
 *     the share of the time the job could use at most one CPU.
 *   - by the threads that ran: whose time on a CPU (schedstat's first
 *     field) grew by at least FRACTION (default 0.5) of the window.  What
 *     a quiet machine shows; on a loaded one a thread of the job that waits
 *     for a CPU does not count, and the others' load looks serial.
 *
 * A window with at most one such thread is serial, one with two or more
 * parallel.  When the command ends, one line goes to FILE (default stderr):
 *
 *   wall_s=W serial_s=S idle_s=I parallel_s=P share=F cap16=A cap64=B
 *   ran_serial_s=S2 ran_parallel_s=P2 ran_share=F2 cpu_s=C samples=K
 *   threads=T procs=Q
 *
 *   serial_s   seconds of the windows with at most one runnable thread
 *   idle_s     the part of serial_s with none (all asleep: I/O, waits)
 *   parallel_s seconds of the windows with two or more
 *   share      serial_s / (serial_s + N x parallel_s): the serial part of
 *              the job's work when a parallel second is N workers' work
 *              (-n N, default 2)
 *   cap16/64   Amdahl's cap on the yield at 16 and 64 workers,
 *              1 / (1 + (W - 1) share)
 *   ran_*      the same by the threads that ran
 *   cpu_s      the threads' time on a CPU, summed
 *   threads    the threads seen over the run, procs the most processes in
 *              one sample
 *
 * A second line tells the job's parallelism over the run, where a serial
 * share alone does not (with many workers, a window with 2 of 16 runnable
 * counts as parallel): the seconds of the windows by their number of
 * runnable threads, K:SECONDS for each K seen (K = RUNNABLE_MAX: that many
 * or more), so that N workers' unused CPU time is sum (N - K) x SECONDS
 * over the K below N:
 *
 *   runnable_s=0:S0,1:S1,...
 *
 * With -l MS a line "serial_spans=" follows: the runs of consecutive serial
 * windows (runnable threads) of at least MS milliseconds, as START-END in
 * seconds from the fork, to put beside the command's own stage times.
 *
 * With -w (and -l MS) the tool also says where the serial time went: each
 * serial window is charged to the thread that was runnable in it, or, in
 * an idle one, to the thread that ran most in it (else the command's own
 * first thread), as "COMM PID/TID (ROLE) STATE [SYSCALL WCHAN]": its name,
 * its process and thread, ROLE "command" for the command's process or
 * "child of PPID" for one of the tree below it, its state letter at the
 * sample (R runnable, S asleep, D in uninterruptible I/O) and, when it was
 * not runnable, the system call it waited in and the kernel function
 * (/proc/PID/task/TID/syscall and wchan; a runnable thread's "syscall"
 * file says only "running").  Then one line per serial span of at least
 * MS ms, and the totals over the whole run, largest first:
 *
 *   serial_span=START-END MS ms: MS ms WHO; MS ms WHO; ...
 *   serial_by=SECONDS s WHO
 *
 * Before the exec the child is still called voxserial; the command's
 * threads and processes may name themselves (vox does: its stages and
 * workers), which is what makes the charge say which stage it was.
 * -S runs THREADS threads that keep a CPU busy for SECONDS: a known load
 * for the tests.  A thread that starts and ends between two samples is not
 * seen.  The exit status is the command's (128 + the signal that ended
 * it).  Linux only (/proc); a benchmark helper, not installed. */
#include <ctype.h>
#include <dirent.h>
#include <errno.h>
#include <poll.h>
#include <pthread.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "bench_util.h"

#define MAX_THREADS 16384
#define MAX_SPANS 64
#define MAX_WHO 512  /* distinct (thread, name, state, wait) charged */
#define WHO_LEN 160
#define RUNNABLE_MAX 256 /* runnable_s's last count: that many or more */

/* Serial seconds charged to one description of a thread. */
typedef struct {
    char who[WHO_LEN];
    double s;
} charge;

/* -w: the charges over the whole run, and over the serial span open now. */
typedef struct {
    int on;
    charge total[MAX_WHO], span[MAX_WHO];
    int ntotal, nspan;
} where;

typedef struct {
    int tid, pid, ppid;     /* ppid: the process above it in the tree (0: none) */
    unsigned gen;           /* the last sample that saw it (0: never) */
    unsigned long long run; /* its ns on a CPU then */
    unsigned long long d;   /* its ns on a CPU in this sample's window */
    char state;             /* at this sample */
    char comm[16];
} thread_seen;

/* The sampler's state across samples, and this sample's counts. */
typedef struct {
    thread_seen th[MAX_THREADS];
    int nth, procs;
    unsigned gen;
    double fraction;
    unsigned long long thresh_ns; /* ran at least this long: counted */
    int runnable, ran;
    unsigned long long cpu_ns;
    int root;                  /* the command's pid */
    thread_seen *busy, *most;  /* a runnable thread, the one that ran most */
    thread_seen *blocked;      /* a thread in uninterruptible sleep (D) */
    thread_seen *last;         /* the last to run, over the samples */
} sampler;

/* Seconds of windows: at most one thread (serial; none: idle), more. */
typedef struct {
    double serial, idle, parallel;
} split;

typedef struct {
    double wall, cpu;
    split st, ran; /* by the runnable threads, by the threads that ran */
    double by_runnable[RUNNABLE_MAX + 1]; /* seconds by runnable threads */
    int samples, procs;
    double span_start[MAX_SPANS], span_end[MAX_SPANS];
    char *span_where[MAX_SPANS]; /* -w: where the span's time went */
    int nspans;
} result;

static where W; /* -w's charges */

static void die(const char *what, const char *why)
{
    fprintf(stderr, "voxserial: %s: %s\n", what, why);
    exit(125);
}

static void usage(void)
{
    fprintf(stderr, "usage: voxserial [-p USEC] [-n N] [-t FRACTION] [-l MS [-w]] "
                    "[-o FILE] -- COMMAND [ARG...]\n"
                    "       voxserial -S THREADS:SECONDS\n");
    exit(125);
}

/* The thread's record, made (gen 0) when it is new; NULL when full. */
static thread_seen *find_thread(sampler *s, int tid)
{
    for (int i = 0; i < s->nth; i++)
        if (s->th[i].tid == tid) return &s->th[i];
    if (s->nth == MAX_THREADS) return NULL;
    s->th[s->nth] = (thread_seen){.tid = tid};
    return &s->th[s->nth++];
}

/* One thread's name, state letter (/proc/PID/task/TID/stat: the name
 * between the first '(' and the last ')', which may hold any, the state
 * after it) and its ns on a CPU (schedstat). */
static int read_thread(int pid, int tid, char comm[16], char *state,
                       unsigned long long *run)
{
    char path[96], buf[512];
    snprintf(path, sizeof path, "/proc/%d/task/%d/stat", pid, tid);
    const char *p = proc_stat_fields(path, buf, sizeof buf);
    if (!p || sscanf(p, " %c", state) != 1) return -1;
    const char *c = strchr(buf, '(');
    size_t n = c && p - 1 > c ? (size_t)(p - 1 - (c + 1)) : 0;
    if (n > 15) n = 15;
    memcpy(comm, c ? c + 1 : "", n);
    comm[n] = '\0';
    snprintf(path, sizeof path, "/proc/%d/task/%d/schedstat", pid, tid);
    FILE *f = fopen(path, "r");
    if (!f) return -1;
    int k = fscanf(f, "%llu", run);
    fclose(f);
    return k == 1 ? 0 : -1;
}

static void account(sampler *s, int pid, int ppid, int tid)
{
    char state, comm[16];
    unsigned long long run;
    if (read_thread(pid, tid, comm, &state, &run)) return; /* gone meanwhile */
    thread_seen *t = find_thread(s, tid);
    if (!t || t->gen == s->gen) return; /* full, or seen in this sample */
    /* a new thread started inside this window: all its time is in it */
    unsigned long long d = t->gen && run >= t->run ? run - t->run : run;
    if (state == 'R') s->runnable++;
    if (d >= s->thresh_ns) s->ran++;
    s->cpu_ns += d;
    t->run = run;
    t->gen = s->gen;
    t->d = d;
    t->pid = pid;
    t->ppid = ppid;
    t->state = state;
    memcpy(t->comm, comm, sizeof comm);
    if (state == 'R') s->busy = t;
    if (state == 'D') s->blocked = t;
    if (d && (!s->most || d > s->most->d)) s->most = t;
}

static void walk(sampler *s, int pid, int ppid, int depth);

/* The children of one thread (/proc/PID/task/TID/children). */
static void walk_children(sampler *s, int pid, int tid, int depth)
{
    char path[96];
    snprintf(path, sizeof path, "/proc/%d/task/%d/children", pid, tid);
    FILE *f = fopen(path, "r");
    if (!f) return;
    int child;
    while (fscanf(f, "%d", &child) == 1) walk(s, child, pid, depth + 1);
    fclose(f);
}

/* Every thread of PID and of its descendants. */
static void walk(sampler *s, int pid, int ppid, int depth)
{
    char path[64];
    if (depth > 64) return;
    snprintf(path, sizeof path, "/proc/%d/task", pid);
    DIR *d = opendir(path);
    if (!d) return;
    s->procs++;
    struct dirent *e;
    while ((e = readdir(d))) {
        if (!isdigit((unsigned char)e->d_name[0])) continue;
        int tid = atoi(e->d_name);
        account(s, pid, ppid, tid);
        walk_children(s, pid, tid, depth);
    }
    closedir(d);
}

/* The name of an x86-64 system call a thread may wait in; NULL when it is
 * not one of these. */
static const char *syscall_name(long nr)
{
#ifdef __x86_64__
    static const struct { long nr; const char *name; } t[] = {
        {0, "read"}, {1, "write"}, {3, "close"}, {7, "poll"}, {9, "mmap"},
        {11, "munmap"}, {17, "pread64"}, {18, "pwrite64"}, {20, "writev"},
        {23, "select"}, {28, "madvise"}, {35, "nanosleep"}, {56, "clone"},
        {57, "fork"}, {59, "execve"}, {60, "exit"}, {61, "wait4"},
        {74, "fsync"}, {75, "fdatasync"}, {82, "rename"}, {87, "unlink"},
        {202, "futex"}, {230, "clock_nanosleep"}, {231, "exit_group"},
        {232, "epoll_wait"}, {247, "waitid"}, {257, "openat"},
        {271, "ppoll"}, {277, "sync_file_range"}, {281, "epoll_pwait"},
        {285, "fallocate"}, {316, "renameat2"}, {435, "clone3"},
    };
    for (size_t i = 0; i < sizeof t / sizeof t[0]; i++)
        if (t[i].nr == nr) return t[i].name;
#else
    (void)nr;
#endif
    return NULL;
}

/* What a thread that is not runnable waits in: "SYSCALL WCHAN", from
 * /proc/PID/task/TID/syscall and wchan; "" when they cannot be read. */
static void waits_in(const thread_seen *t, char *out, size_t len)
{
    char path[96], sys[64] = "", wchan[64] = "";
    snprintf(path, sizeof path, "/proc/%d/task/%d/syscall", t->pid, t->tid);
    FILE *f = fopen(path, "r");
    long nr;
    if (f && fscanf(f, "%ld", &nr) == 1) {
        const char *name = nr < 0 ? "user" : syscall_name(nr);
        if (name) snprintf(sys, sizeof sys, " %s", name);
        else snprintf(sys, sizeof sys, " syscall %ld", nr);
    }
    if (f) fclose(f);
    snprintf(path, sizeof path, "/proc/%d/task/%d/wchan", t->pid, t->tid);
    f = fopen(path, "r");
    if (f && fscanf(f, "%63s", wchan + 1) == 1 && strcmp(wchan + 1, "0")) wchan[0] = ' ';
    else wchan[0] = '\0';
    if (f) fclose(f);
    snprintf(out, len, "%s%s", sys, wchan);
}

/* One thread as the charges name it. */
static void describe(const sampler *s, const thread_seen *t, char *out, size_t len)
{
    char role[32] = "command", wait[136] = "";
    if (t->pid != s->root) snprintf(role, sizeof role, "child of %d", t->ppid);
    if (t->state != 'R') waits_in(t, wait, sizeof wait);
    snprintf(out, len, "%s %d/%d (%s) %c%s", t->comm, t->pid, t->tid, role,
             t->state, wait);
}

static void charge_add(charge *c, int *n, const char *who, double dt)
{
    for (int i = 0; i < *n; i++)
        if (!strcmp(c[i].who, who)) {
            c[i].s += dt;
            return;
        }
    if (*n == MAX_WHO) return; /* too many: the rest is not charged */
    snprintf(c[*n].who, sizeof c[*n].who, "%s", who);
    c[(*n)++].s = dt;
}

static int charge_cmp(const void *a, const void *b)
{
    double x = ((const charge *)a)->s, y = ((const charge *)b)->s;
    return (x < y) - (x > y);
}

/* -w: charges a serial window of dt seconds to the thread that was
 * runnable in it; an idle one to the thread that ran most in it, else to
 * one in uninterruptible sleep (I/O), else to the last that ran before (a
 * child the others wait for), else to the command's first thread. */
static void charge_window(sampler *s, double dt)
{
    thread_seen *t = s->runnable == 1 ? s->busy : s->most;
    if (!t) t = s->blocked;
    if (!t && s->last && s->last->gen == s->gen) t = s->last;
    if (!t) {
        thread_seen *m = find_thread(s, s->root);
        if (m && m->gen == s->gen) t = m;
    }
    char who[WHO_LEN] = "nothing seen";
    if (t) describe(s, t, who, sizeof who);
    charge_add(W.span, &W.nspan, who, dt);
    charge_add(W.total, &W.ntotal, who, dt);
}

/* The span's charges, largest first, on one line (malloc'd; NULL when
 * there are none or no memory). */
static char *span_text(void)
{
    if (!W.nspan) return NULL;
    qsort(W.span, (size_t)W.nspan, sizeof W.span[0], charge_cmp);
    size_t len = (size_t)W.nspan * (WHO_LEN + 32), at = 0;
    char *t = malloc(len);
    for (int i = 0; t && i < W.nspan; i++)
        at += (size_t)snprintf(t + at, len - at, "%s%.0f ms %s", i ? "; " : "",
                               1e3 * W.span[i].s, W.span[i].who);
    return t;
}

static void add_span(result *r, double start, double end, double min_s)
{
    int keep = min_s > 0 && end - start >= min_s && r->nspans < MAX_SPANS;
    if (keep) {
        r->span_where[r->nspans] = W.on ? span_text() : NULL;
        r->span_start[r->nspans] = start;
        r->span_end[r->nspans++] = end;
    }
    W.nspan = 0;
}

static int add_window(split *sp, int threads, double dt)
{
    if (threads >= 2) {
        sp->parallel += dt;
        return 0;
    }
    sp->serial += dt;
    if (!threads) sp->idle += dt;
    return 1;
}

/* One sample, ending a window of dt seconds; 1 when it was serial (by the
 * runnable threads). */
static int sample(sampler *s, int pid, double dt, result *r)
{
    s->gen++;
    s->runnable = s->ran = s->procs = 0;
    s->cpu_ns = 0;
    s->busy = s->most = s->blocked = NULL;
    s->thresh_ns = (unsigned long long)(dt * 1e9 * s->fraction);
    walk(s, pid, 0, 0);
    if (s->most) s->last = s->most;
    if (s->procs > r->procs) r->procs = s->procs;
    r->samples++;
    r->cpu += 1e-9 * (double)s->cpu_ns;
    add_window(&r->ran, s->ran, dt);
    r->by_runnable[s->runnable < RUNNABLE_MAX ? s->runnable : RUNNABLE_MAX] += dt;
    int serial = add_window(&r->st, s->runnable, dt);
    if (serial && W.on) charge_window(s, dt);
    return serial;
}

/* Samples PID's tree every period_us until it exits; the last sample is
 * taken once it has (a zombie's threads still answer). */
static void sample_until_exit(int pid, long period_us, sampler *s, result *r,
                              double t_fork, double min_span_s)
{
    int pfd = (int)syscall(SYS_pidfd_open, pid, 0);
    if (pfd < 0) die("pidfd_open", strerror(errno));
    double prev = t_fork, span0 = -1;
    for (int rc = 0; rc == 0;) {
        struct pollfd pf = {.fd = pfd, .events = POLLIN};
        struct timespec ts = {period_us / 1000000, (period_us % 1000000) * 1000};
        rc = ppoll(&pf, 1, &ts, NULL);
        if (rc < 0 && errno != EINTR) die("ppoll", strerror(errno));
        if (rc < 0) rc = 0;
        double t = now();
        if (sample(s, pid, t - prev, r)) {
            if (span0 < 0) span0 = prev - t_fork;
        } else if (span0 >= 0) {
            add_span(r, span0, prev - t_fork, min_span_s);
            span0 = -1;
        }
        prev = t;
    }
    if (span0 >= 0) add_span(r, span0, prev - t_fork, min_span_s);
    close(pfd);
}

static double share_of(const split *sp, int n)
{
    double work = sp->serial + n * sp->parallel;
    return work > 0 ? sp->serial / work : 0;
}

static void report(FILE *out, const result *r, int n, int nth, double min_span_s)
{
    double share = share_of(&r->st, n);
    fprintf(out,
            "wall_s=%.6f serial_s=%.6f idle_s=%.6f parallel_s=%.6f share=%.6f "
            "cap16=%.4f cap64=%.4f ran_serial_s=%.6f ran_parallel_s=%.6f "
            "ran_share=%.6f cpu_s=%.6f samples=%d threads=%d procs=%d\n",
            r->wall, r->st.serial, r->st.idle, r->st.parallel, share,
            1 / (1 + 15 * share), 1 / (1 + 63 * share), r->ran.serial,
            r->ran.parallel, share_of(&r->ran, n), r->cpu, r->samples, nth,
            r->procs);
    fprintf(out, "runnable_s=");
    for (int k = 0, first = 1; k <= RUNNABLE_MAX; k++)
        if (r->by_runnable[k] > 0) {
            fprintf(out, "%s%d:%.6f", first ? "" : ",", k, r->by_runnable[k]);
            first = 0;
        }
    fprintf(out, "\n");
    if (min_span_s <= 0) return;
    fprintf(out, "serial_spans=");
    for (int i = 0; i < r->nspans; i++)
        fprintf(out, "%s%.3f-%.3f", i ? "," : "", r->span_start[i], r->span_end[i]);
    fprintf(out, "\n");
    if (!W.on) return;
    for (int i = 0; i < r->nspans; i++)
        fprintf(out, "serial_span=%.3f-%.3f %.0f ms: %s\n", r->span_start[i],
                r->span_end[i], 1e3 * (r->span_end[i] - r->span_start[i]),
                r->span_where[i] ? r->span_where[i] : "");
    qsort(W.total, (size_t)W.ntotal, sizeof W.total[0], charge_cmp);
    for (int i = 0; i < W.ntotal; i++)
        fprintf(out, "serial_by=%.3f s %s\n", W.total[i].s, W.total[i].who);
}

/* -S THREADS:SECONDS: threads that keep a CPU busy (when they get one)
 * until SECONDS of wall time have passed. */
static void *spin(void *arg)
{
    double end = *(const double *)arg;
    volatile unsigned long x = 0;
    while (now() < end)
        for (int i = 0; i < 100000; i++) x += (unsigned long)i;
    return NULL;
}

static int spin_main(const char *spec)
{
    int threads;
    double seconds;
    if (sscanf(spec, "%d:%lf", &threads, &seconds) != 2 || threads < 1 ||
        threads > 64 || seconds < 0)
        usage();
    double end = now() + seconds;
    pthread_t t[64];
    for (int i = 1; i < threads; i++)
        if (pthread_create(&t[i], NULL, spin, &end)) die("pthread_create", "failed");
    spin(&end);
    for (int i = 1; i < threads; i++) pthread_join(t[i], NULL);
    return 0;
}

static int run_command(char **argv, long period_us, sampler *s, int n,
                       double min_span_s, FILE *out)
{
    static result r;
    double t0 = now();
    pid_t pid = fork();
    s->root = pid;
    if (pid < 0) die("fork", strerror(errno));
    if (pid == 0) {
        execvp(argv[0], argv);
        fprintf(stderr, "voxserial: %s: %s\n", argv[0], strerror(errno));
        _exit(127);
    }
    sample_until_exit(pid, period_us, s, &r, t0, min_span_s);
    int status;
    while (waitpid(pid, &status, 0) < 0)
        if (errno != EINTR) die("waitpid", strerror(errno));
    r.wall = now() - t0;
    report(out, &r, n, s->nth, min_span_s);
    if (WIFSIGNALED(status)) return 128 + WTERMSIG(status);
    return WEXITSTATUS(status);
}

int main(int argc, char **argv)
{
    static sampler s = {.fraction = 0.5};
    long period_us = 5000;
    int n = 2, c;
    double min_span_s = 0;
    const char *outpath = NULL;
    while ((c = getopt(argc, argv, "+p:n:t:l:o:S:w")) != -1) {
        if (c == 'p') period_us = strtol(optarg, NULL, 10);
        else if (c == 'n') n = atoi(optarg);
        else if (c == 't') s.fraction = atof(optarg);
        else if (c == 'l') min_span_s = atof(optarg) / 1000;
        else if (c == 'o') outpath = optarg;
        else if (c == 'w') W.on = 1;
        else if (c == 'S') return spin_main(optarg);
        else usage();
    }
    if (optind >= argc || period_us < 100 || n < 1 || s.fraction <= 0 ||
        s.fraction > 1 || (W.on && min_span_s <= 0))
        usage();
    FILE *out = outpath ? fopen(outpath, "w") : stderr;
    if (!out) die(outpath, strerror(errno));
    int rc = run_command(argv + optind, period_us, &s, n, min_span_s, out);
    if (out != stderr) fclose(out);
    return rc;
}
