/* voxdbench — the daemon's benchmarks (issue 3), beside voxbench's embedded ones.
 *
 *   voxdbench latency [-n MAX]             round trip of a small job: voxd vs embedded
 *   voxdbench clients [-n MAX]             jobs per second with 1, 4 and 16 clients
 *   voxdbench table1  [-r RES] [-n MAX]    the paper's Table 1 through voxd, both schedules
 *   voxdbench all     [-r RES] [-n MAX]    the three
 *   every command takes --voxd PATH (default: the voxd beside this binary)
 *
 * voxdbench starts its own voxd on a socket in a temporary directory, with a
 * configuration written there (workers, socket, log, pidfile, limits high
 * enough for the benchmarks), waits for it to answer a ping, and stops it
 * (SIGQUIT, then TERM and KILL if it lingers) and removes the directory at the
 * end: also when a benchmark fails and on SIGINT/TERM/HUP.  latency and
 * clients run on one voxd with MAX workers; table1 starts one voxd per worker
 * count.  Every table is Markdown on stdout, its header names the core count
 * and the CPU model; a failure is a message on stderr (with the end of voxd's
 * log) and exit status 1, bad usage exit status 2. */
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "bench_util.h"
#include "engine.h"
#include "expr.h"
#include "pipeline.h"
#include "vod.h"
#include "vox.h"
#include "voxel.h"

#define REPEATS 3          /* Table 1: median of this many jobs */
#define LAT_JOBS 50        /* latency: jobs measured per path */
#define LAT_WARMUP 3       /* latency: jobs run first, not measured */
#define CLIENT_SECONDS 2.0 /* clients: each client submits for this long */
#define CLIENT_MIN_JOBS 4  /* ... and at least this many jobs */
#define SMALL_EXPR "sqrt(x^2+y^2+z^2) - 0.8"
#define SMALL_RES 64u

/* ---------------------------------------------------------------- the daemon */

/* The voxd this process runs, and its files (in static memory: the signal
 * handler removes them). */
static struct {
    char voxd[PATH_MAX];
    char dir[256], conf[300], sock[300], lock[300], log[300], pidfile[300];
    volatile sig_atomic_t child; /* voxd's pid, 0 when none runs */
} D;

/* Async-signal-safe: unlink and rmdir only. */
static int remove_files(void)
{
    if (!D.dir[0]) return 0;
    const char *files[] = {D.conf, D.sock, D.lock, D.log, D.pidfile};
    for (size_t i = 0; i < sizeof files / sizeof files[0]; i++) unlink(files[i]);
    int rc = rmdir(D.dir);
    if (rc == 0) D.dir[0] = '\0';
    return rc;
}

static void show_log(void)
{
    FILE *f = D.dir[0] ? fopen(D.log, "r") : NULL;
    if (!f) return;
    static char buf[2048];
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    fseek(f, size > (long)sizeof buf - 1 ? size - (long)sizeof buf + 1 : 0, SEEK_SET);
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = '\0';
    if (n) fprintf(stderr, "voxdbench: the end of voxd's log (%s):\n%s", D.log, buf);
}

__attribute__((format(printf, 1, 2), noreturn))
static void die(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fputs("voxdbench: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
    show_log();
    exit(1); /* cleanup() stops voxd and removes its directory */
}

static void status_text(int st, char *buf, size_t cap)
{
    if (WIFEXITED(st)) snprintf(buf, cap, "exit status %d", WEXITSTATUS(st));
    else if (WIFSIGNALED(st)) snprintf(buf, cap, "killed by signal %d (%s)", WTERMSIG(st),
                                       strsignal(WTERMSIG(st)));
    else snprintf(buf, cap, "wait status %#x", (unsigned)st);
}

/* Wait up to secs for pid to end: 1 and its status when it did. */
static int reap(pid_t pid, double secs, int *st)
{
    double t0 = now();
    for (;;) {
        pid_t r = waitpid(pid, st, WNOHANG);
        if (r == pid) return 1;
        if (r < 0 && errno != EINTR) return *st = 0, 1;
        if (now() - t0 >= secs) return 0;
        usleep(10000);
    }
}

/* QUIT: finish what runs and exit; TERM after 10 s, KILL 5 s later.
 * Returns voxd's wait status (0: it exited 0), -1 when none ran. */
static int stop_daemon(void)
{
    pid_t pid = D.child;
    if (pid <= 0) return -1;
    static const int sigs[] = {SIGQUIT, SIGTERM, SIGKILL};
    static const double waits[] = {10, 5, 5};
    int st = 0, done = 0;
    for (int i = 0; i < 3 && !done; i++) {
        kill(pid, sigs[i]);
        done = reap(pid, waits[i], &st);
    }
    if (!done) waitpid(pid, &st, 0);
    D.child = 0;
    return st;
}

static void cleanup(void)
{
    stop_daemon();
    if (remove_files() && errno != ENOENT)
        fprintf(stderr, "voxdbench: cannot remove %s: %s\n", D.dir, strerror(errno));
}

static void on_signal(int sig)
{
    pid_t pid = D.child;
    if (pid > 0) {
        kill(pid, SIGTERM);
        waitpid(pid, NULL, 0);
    }
    remove_files();
    signal(sig, SIG_DFL);
    raise(sig);
}

static void catch_signals(void)
{
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    sigaction(SIGHUP, &sa, NULL);
}

/* voxd: --voxd PATH, else the voxd beside this binary. */
static void find_voxd(const char *argv0, const char *given)
{
    char self[PATH_MAX] = "";
    if (given) {
        snprintf(D.voxd, sizeof D.voxd, "%s", given);
    } else {
        if (strchr(argv0, '/')) snprintf(self, sizeof self, "%s", argv0);
        else if (readlink("/proc/self/exe", self, sizeof self - 1) < 0) self[0] = '\0';
        char *slash = strrchr(self, '/');
        if (slash) slash[1] = '\0';
        else snprintf(self, sizeof self, "./");
        snprintf(D.voxd, sizeof D.voxd, "%.4000svoxd", self);
    }
    if (access(D.voxd, X_OK))
        die("no voxd to run at %s (%s): build it with make, or give --voxd PATH", D.voxd,
            strerror(errno));
}

static void path_in_dir(char *out, size_t cap, const char *name)
{
    if ((size_t)snprintf(out, cap, "%s/%s", D.dir, name) >= cap) die("%s: path too long", D.dir);
}

static void make_dir(void)
{
    const char *tmp = getenv("TMPDIR");
    char dir[sizeof D.dir];
    if (!tmp || !*tmp) tmp = "/tmp";
    if ((size_t)snprintf(dir, sizeof dir, "%s/voxdbench-XXXXXX", tmp) >= sizeof dir)
        die("TMPDIR %s is too long a path", tmp);
    if (!mkdtemp(dir)) die("cannot make a directory %s: %s", dir, strerror(errno));
    memcpy(D.dir, dir, sizeof dir);
    path_in_dir(D.conf, sizeof D.conf, "voxd.conf");
    path_in_dir(D.sock, sizeof D.sock, "voxd.sock");
    path_in_dir(D.lock, sizeof D.lock, "voxd.sock.lock");
    path_in_dir(D.log, sizeof D.log, "voxd.log");
    path_in_dir(D.pidfile, sizeof D.pidfile, "voxd.pid");
    if (strlen(D.sock) >= 108)
        die("the socket path %s is too long for a Unix socket; set TMPDIR to a shorter directory",
            D.sock);
}

/* Limits high enough for every benchmark here: 16 clients with a job each,
 * Table 1 at up to 4096^3, no job stopped before an hour. */
static void write_config(int workers)
{
    FILE *f = fopen(D.conf, "w");
    if (!f) die("cannot write %s: %s", D.conf, strerror(errno));
    fprintf(f, "# written by voxdbench\nsocket %s\nworkers %d\nlog_file %s\nlog_level info\n"
               "pidfile %s\nmax_queued_jobs 4096\nmax_jobs_per_uid 4096\nmax_clients 1024\n"
               "max_res 4096\njob_timeout 1h\nmax_result_bytes 4G\n",
            D.sock, workers, D.log, D.pidfile);
    if (fclose(f)) die("cannot write %s: %s", D.conf, strerror(errno));
}

__attribute__((noreturn))
static void exec_voxd(pid_t parent)
{
    /* voxd stops (and removes its socket and shared memory) if we die. */
    prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (getppid() != parent) _exit(127);
    dup2(STDERR_FILENO, STDOUT_FILENO); /* stdout is the tables' */
    execl(D.voxd, "voxd", "--config", D.conf, (char *)NULL);
    fprintf(stderr, "voxdbench: cannot run %s: %s\n", D.voxd, strerror(errno));
    _exit(127);
}

static vox_client *try_connect(int timeout_ms, vox_error *err, int *rc)
{
    vox_options o = {.timeout_ms = timeout_ms, .client_name = "voxdbench"};
    vox_client *c = NULL;
    *rc = vox_connect(D.sock, &o, &c, err);
    return *rc ? NULL : c;
}

/* Until voxd answers a ping (it listens once its workers run). */
static void wait_ready(int workers)
{
    double t0 = now();
    for (;;) {
        int st, rc;
        char why[100];
        if (waitpid(D.child, &st, WNOHANG) == D.child) {
            D.child = 0;
            status_text(st, why, sizeof why);
            die("%s exited before answering on %s (%s)", D.voxd, D.sock, why);
        }
        vox_error err;
        vox_client *c = try_connect(5000, &err, &rc);
        if (c) {
            vox_server_info si;
            vox_server(c, &si);
            rc = vox_ping(c, NULL, &err);
            vox_close(c);
            if (rc) die("voxd on %s does not answer a ping: %s", D.sock, err.message);
            if ((int)si.workers != workers)
                die("voxd has %u workers, %d asked for", si.workers, workers);
            return;
        }
        if (now() - t0 > 60)
            die("voxd did not answer on %s within 60 s: %s", D.sock, err.message);
        usleep(20000);
    }
}

static void start_daemon(int workers)
{
    write_config(workers);
    fflush(stdout);
    fflush(stderr);
    pid_t parent = getpid(), pid = fork();
    if (pid < 0) die("fork: %s", strerror(errno));
    if (pid == 0) exec_voxd(parent);
    D.child = pid;
    wait_ready(workers);
}

static void stop_daemon_checked(void)
{
    int st = stop_daemon();
    if (st != 0) {
        char why[100];
        status_text(st, why, sizeof why);
        die("voxd did not stop cleanly: %s", why);
    }
}

/* ---------------------------------------------------------------- jobs */

typedef struct {
    uint64_t voxels, bytes;
    uint32_t crc;
    double t_voxelize, t_write;
} job_out;

static const char *err_text(int rc, const vox_error *err, char *buf, size_t cap)
{
    const char *name = vox_error_name(rc);
    snprintf(buf, cap, "%s%s%s", name ? name : "", name ? ": " : "",
             err->message[0] ? err->message : vox_strerror(rc));
    return buf;
}

static vox_client *connect_daemon(void)
{
    vox_error err;
    int rc;
    vox_client *c = try_connect(60000, &err, &rc);
    if (!c) die("cannot connect to voxd on %s: %s", D.sock, err.message);
    return c;
}

/* Submit, and receive the VOD into a buffer (length and CRC checked by libvox). */
static int daemon_job(vox_client *c, const vox_implicit_job *j, job_out *o, vox_error *err)
{
    uint64_t id;
    uint8_t *buf;
    size_t len;
    vox_summary s;
    int rc = vox_submit(c, j, &id, NULL, err);
    if (rc == 0) rc = vox_receive_to_buffer(c, id, &buf, &len, &(vox_receive_opts){.sum = &s}, err);
    if (rc) return rc;
    free(buf);
    *o = (job_out){s.voxels, len, s.crc32, s.seconds_voxelize, s.seconds_write};
    return 0;
}

static void daemon_job_or_die(vox_client *c, const vox_implicit_job *j, job_out *o)
{
    vox_error err;
    char why[1300];
    int rc = daemon_job(c, j, o, &err);
    if (rc) die("job through voxd failed: %s", err_text(rc, &err, why, sizeof why));
}

/* The same job gives the same bytes (any path, schedule, worker count). */
static int same_result(const job_out *a, const job_out *b)
{
    return a->voxels == b->voxels && a->crc == b->crc && a->bytes == b->bytes;
}

static void check_result(const job_out *got, const job_out *ref, const char *what)
{
    if (!same_result(got, ref))
        die("%s: %llu voxels, %llu bytes, CRC %08x; the first job gave %llu voxels, "
            "%llu bytes, CRC %08x", what, (unsigned long long)got->voxels,
            (unsigned long long)got->bytes, got->crc, (unsigned long long)ref->voxels,
            (unsigned long long)ref->bytes, ref->crc);
}

static vox_implicit_job small_job(void)
{
    return (vox_implicit_job){.source = SMALL_EXPR, .domain = {-1, 1, -1, 1, -1, 1},
                              .res = SMALL_RES};
}

/* ---------------------------------------------------------------- headers */

static void cpu_model(char *buf, size_t cap)
{
    snprintf(buf, cap, "unknown CPU");
    FILE *f = fopen("/proc/cpuinfo", "r");
    char line[512];
    while (f && fgets(line, sizeof line, f)) {
        char *colon = strchr(line, ':');
        if (strncmp(line, "model name", 10) || !colon) continue;
        colon += 1 + strspn(colon + 1, " \t");
        snprintf(buf, cap, "%.*s", (int)strcspn(colon, "\n"), colon);
        break;
    }
    if (f) fclose(f);
}

static void header(const char *title, uint32_t res, const char *how)
{
    char cpu[256];
    cpu_model(cpu, sizeof cpu);
    printf("\n### %s (%u^3, %ld cores, %s, %s)\n\n", title, res,
           sysconf(_SC_NPROCESSORS_ONLN), cpu, how);
}

/* ---------------------------------------------------------------- latency */

/* vox voxelize's VOD parameters and metadata (cli_voxelize.c), so the
 * embedded file is byte for byte the daemon's. */
/* The job as `vox voxelize --embedded` runs it: compile, then the one job
 * pipeline (voxelize, write the VOD in memory, as voxd holds a result). */
static void embedded_job(engine *e, job_out *o)
{
    expr_tape *t;
    expr_error xe;
    if (expr_compile(SMALL_EXPR, strlen(SMALL_EXPR), NULL, &t, &xe))
        die("%s: %s", SMALL_EXPR, xe.msg);
    engine_pipeline_job job = {
        .kind = &engine_kind_implicit,
        .implicit = {.tape = t, .source = SMALL_EXPR, .source_len = strlen(SMALL_EXPR)},
        .lo = {-1, -1, -1}, .hi = {1, 1, 1}, .res = SMALL_RES,
        .schedule = ENGINE_SCHED_SUBTREE,
    };
    vod_params_default(&job.vod);
    job.vod.channel = VOXEL_CH_SURFACE;
    vod_membuf m = {0};
    vod_sink sink = {vod_mem_write, &m};
    engine_pipeline_report r;
    int rc = engine_pipeline_run(e, &job, &sink, &r);
    free(m.p);
    if (rc) die("embedded job failed: %s", r.err.msg);
    o->voxels = r.voxels;
    o->t_voxelize = r.t_voxelize;
    o->bytes = r.st.file_bytes;
    o->crc = r.st.crc32;
    expr_tape_free(t);
}

static engine *make_engine(int workers)
{
    engine_opts o = {.workers = workers};
    engine *e;
    err_info err = {0};
    int rc = engine_create(&o, &e, &err);
    if (rc) die("cannot start the embedded engine: %s", err.msg[0] ? err.msg : strerror(-rc));
    return e;
}

typedef enum { P_EMBEDDED_KEPT, P_EMBEDDED_NEW, P_DAEMON_KEPT, P_DAEMON_NEW, NPATHS } lat_path;

static const char *const path_names[NPATHS] = {
    "embedded engine, kept between jobs",
    "embedded engine, started per job (as `vox voxelize --embedded`)",
    "voxd, one connection for all jobs",
    "voxd, a connection per job (as `vox submit`)",
};

/* One job by path p; its round trip in seconds. */
static double lat_one(lat_path p, engine *kept, vox_client *c, int workers, job_out *o)
{
    vox_implicit_job j = small_job();
    double t0 = now();
    if (p == P_EMBEDDED_KEPT) {
        embedded_job(kept, o);
    } else if (p == P_EMBEDDED_NEW) {
        engine *e = make_engine(workers);
        embedded_job(e, o);
        engine_destroy(e);
    } else if (p == P_DAEMON_KEPT) {
        daemon_job_or_die(c, &j, o);
    } else {
        vox_client *fresh = connect_daemon();
        daemon_job_or_die(fresh, &j, o);
        vox_close(fresh);
    }
    return now() - t0;
}

typedef struct {
    double med, p90;
} lat_stats;

static lat_stats lat_path_run(lat_path p, engine *kept, vox_client *c, int workers,
                              const job_out *ref)
{
    double ms[LAT_JOBS];
    job_out o;
    for (int i = 0; i < LAT_WARMUP; i++) lat_one(p, kept, c, workers, &o);
    for (int i = 0; i < LAT_JOBS; i++) {
        ms[i] = 1e3 * lat_one(p, kept, c, workers, &o);
        check_result(&o, ref, path_names[p]);
    }
    return (lat_stats){percentile(ms, LAT_JOBS, 0.5), percentile(ms, LAT_JOBS, 0.9)};
}

static void bench_latency(int workers)
{
    vox_client *c = connect_daemon();
    vox_implicit_job j = small_job();
    job_out ref;
    daemon_job_or_die(c, &j, &ref);
    engine *kept = make_engine(workers);
    lat_stats s[NPATHS];
    for (int p = 0; p < NPATHS; p++) s[p] = lat_path_run((lat_path)p, kept, c, workers, &ref);
    engine_destroy(kept);
    vox_close(c);
    char how[128];
    snprintf(how, sizeof how, "%d workers, %d jobs a row after %d unmeasured", workers,
             LAT_JOBS, LAT_WARMUP);
    header("Round trip of a small job: voxd vs embedded, `" SMALL_EXPR "`", SMALL_RES, how);
    printf("| path | median (ms) | p90 (ms) | median vs embedded | p90 vs embedded |\n");
    printf("|---|---:|---:|---:|---:|\n");
    for (int p = 0; p < NPATHS; p++)
        printf("| %s | %.2f | %.2f | %.2fx | %.2fx |\n", path_names[p], s[p].med, s[p].p90,
               s[p].med / s[0].med, s[p].p90 / s[0].p90);
    printf("\nEvery job: %llu voxels, a VOD of %llu bytes with CRC %08x, the same embedded "
           "and through voxd. voxd (one connection) / embedded (engine kept): median %.2fx, "
           "p90 %.2fx.\n", (unsigned long long)ref.voxels, (unsigned long long)ref.bytes,
           ref.crc, s[P_DAEMON_KEPT].med / s[0].med, s[P_DAEMON_KEPT].p90 / s[0].p90);
}

/* ---------------------------------------------------------------- clients */

typedef struct {
    pthread_barrier_t *go;
    const double *start;
    const job_out *ref;
    int jobs;
    double end, busy;
    char error[1400];
} client_arg;

static void client_loop(vox_client *c, client_arg *a)
{
    vox_implicit_job j = small_job();
    while (a->jobs < CLIENT_MIN_JOBS || now() - *a->start < CLIENT_SECONDS) {
        job_out o;
        vox_error err;
        char why[1300];
        double t0 = now();
        int rc = daemon_job(c, &j, &o, &err);
        if (rc) {
            snprintf(a->error, sizeof a->error, "%s", err_text(rc, &err, why, sizeof why));
            return;
        }
        a->end = now();
        a->busy += a->end - t0;
        if (!same_result(&o, a->ref)) {
            snprintf(a->error, sizeof a->error, "a result differs from the first job's: "
                     "%llu voxels, CRC %08x", (unsigned long long)o.voxels, o.crc);
            return;
        }
        a->jobs++;
    }
}

static void *client_main(void *p)
{
    client_arg *a = p;
    vox_options o = {.timeout_ms = 60000, .client_name = "voxdbench"};
    vox_client *c = NULL;
    vox_error err;
    int rc = vox_connect(D.sock, &o, &c, &err);
    if (rc) snprintf(a->error, sizeof a->error, "cannot connect: %s", err.message);
    pthread_barrier_wait(a->go);
    if (c) client_loop(c, a);
    vox_close(c);
    return NULL;
}

typedef struct {
    int clients, jobs;
    double seconds, busy;
} clients_row;

static clients_row clients_run(int n, const job_out *ref)
{
    pthread_barrier_t go;
    pthread_t th[16];
    client_arg args[16];
    double start = 0;
    pthread_barrier_init(&go, NULL, (unsigned)n + 1);
    for (int i = 0; i < n; i++) {
        args[i] = (client_arg){.go = &go, .start = &start, .ref = ref};
        if (pthread_create(&th[i], NULL, client_main, &args[i])) die("pthread_create failed");
    }
    start = now();
    pthread_barrier_wait(&go);
    clients_row r = {n, 0, 0, 0};
    for (int i = 0; i < n; i++) pthread_join(th[i], NULL);
    pthread_barrier_destroy(&go);
    for (int i = 0; i < n; i++) {
        if (args[i].error[0]) die("client %d of %d: %s", i + 1, n, args[i].error);
        r.jobs += args[i].jobs;
        r.busy += args[i].busy;
        if (args[i].end - start > r.seconds) r.seconds = args[i].end - start;
    }
    return r;
}

static void bench_clients(int workers)
{
    static const int counts[] = {1, 4, 16};
    vox_client *c = connect_daemon();
    vox_implicit_job j = small_job();
    job_out ref;
    daemon_job_or_die(c, &j, &ref);
    vox_close(c);
    clients_row rows[3];
    for (int i = 0; i < 3; i++) rows[i] = clients_run(counts[i], &ref);
    char how[160];
    snprintf(how, sizeof how, "%d workers, each client submitting for %.0f s, "
             "a connection and a thread each", workers, CLIENT_SECONDS);
    header("voxd with concurrent clients, `" SMALL_EXPR "`", SMALL_RES, how);
    printf("| clients | jobs | seconds | jobs/s | mean round trip (ms) |\n");
    printf("|---:|---:|---:|---:|---:|\n");
    for (int i = 0; i < 3; i++)
        printf("| %d | %d | %.2f | %.1f | %.1f |\n", rows[i].clients, rows[i].jobs,
               rows[i].seconds, rows[i].jobs / rows[i].seconds, 1e3 * rows[i].busy / rows[i].jobs);
    printf("\nEvery result checked: length and CRC-32 by libvox, then %llu voxels and CRC %08x "
           "as the first job's.\n", (unsigned long long)ref.voxels, ref.crc);
}

/* ---------------------------------------------------------------- Table 1 */

/* The domains are voxbench's (the files' "#@ domain" lines). */
typedef struct {
    const char *name, *file;
    double lo, hi;
    char *text;
    size_t len;
} scene;

static scene scenes[3] = {
    {"scene1", "examples/scene1.vx", -1, 1, NULL, 0},
    {"scene2", "examples/scene2.vx", -1.05, 1.05, NULL, 0},
    {"scene3", "examples/scene3.vx", -1.05, 1.05, NULL, 0},
};

static void load_scene(scene *s)
{
    FILE *f = fopen(s->file, "rb");
    if (!f) die("%s: %s (run voxdbench from the repository's root)", s->file, strerror(errno));
    static char buf[1 << 16];
    s->len = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[s->len] = '\0';
    s->text = strdup(buf);
    if (!s->text) die("out of memory");
}

typedef struct {
    job_out job;   /* the median run's */
    double seconds; /* median seconds_voxelize */
} t1_cell;

static t1_cell t1_measure(vox_client *c, const scene *s, uint32_t res, int k)
{
    vox_implicit_job j = {.source = s->text, .source_len = s->len,
                          .domain = {s->lo, s->hi, s->lo, s->hi, s->lo, s->hi}, .res = res,
                          .schedule = k ? VOX_SCHEDULE_PAPER : VOX_SCHEDULE_SUBTREE};
    job_out runs[REPEATS];
    double secs[REPEATS];
    for (int i = 0; i < REPEATS; i++) {
        daemon_job_or_die(c, &j, &runs[i]);
        secs[i] = runs[i].t_voxelize;
        check_result(&runs[i], &runs[0], s->name);
    }
    double m = percentile(secs, REPEATS, 0.5);
    for (int i = 0; i < REPEATS; i++)
        if (runs[i].t_voxelize == m) return (t1_cell){runs[i], m};
    return (t1_cell){runs[0], m};
}

/* One voxd with n workers: every scene, both schedules. */
static void t1_workers(int n, uint32_t res, t1_cell cells[3][2])
{
    start_daemon(n);
    vox_client *c = connect_daemon();
    for (int s = 0; s < 3; s++)
        for (int k = 0; k < 2; k++) cells[s][k] = t1_measure(c, &scenes[s], res, k);
    vox_close(c);
    stop_daemon_checked();
}

/* voxbench's layout: yield = t1 / (n tn). */
static void table1_print(uint32_t res, int maxw, t1_cell (*all)[3][2])
{
    for (int k = 0; k < 2; k++) {
        header(k == 0 ? "Table 1 through voxd, subtree schedule (default)"
                      : "Table 1 through voxd, paper schedule", res, "median of 3 runs");
        printf("| workers | Scene 1 time | yield | Scene 2 time | yield | Scene 3 time | yield |\n");
        printf("|---:|---:|---:|---:|---:|---:|---:|\n");
        for (int n = 1; n <= maxw; n++) {
            printf("| %d |", n);
            for (int s = 0; s < 3; s++) {
                double tn = all[n][s][k].seconds, t1 = all[1][s][k].seconds;
                if (n == 1) printf(" %.3f s | - |", tn);
                else printf(" %.3f s | %.0f%% |", tn, 100 * t1 / (n * tn));
            }
            printf("\n");
        }
    }
}

static void table1_detail(uint32_t res, int maxw, t1_cell (*all)[3][2])
{
    static const char *const names[2] = {"subtree (default)", "paper"};
    header("Table 1 through voxd, voxels, rate and result", res, "median of 3 runs");
    printf("| schedule | workers | scene | voxels | Mvoxels/s | VOD write (s) | VOD bytes |\n");
    printf("|---|---:|---|---:|---:|---:|---:|\n");
    for (int k = 0; k < 2; k++)
        for (int n = 1; n <= maxw; n++)
            for (int s = 0; s < 3; s++) {
                const t1_cell *c = &all[n][s][k];
                printf("| %s | %d | %s | %llu | %.2f | %.3f | %llu |\n", names[k], n,
                       scenes[s].name, (unsigned long long)c->job.voxels,
                       c->job.voxels / c->seconds / 1e6, c->job.t_write,
                       (unsigned long long)c->job.bytes);
            }
}

/* The same job gives the same bytes whatever the workers and the schedule. */
static void t1_check(int maxw, t1_cell (*all)[3][2])
{
    for (int n = 1; n <= maxw; n++)
        for (int s = 0; s < 3; s++)
            for (int k = 0; k < 2; k++)
                if (!same_result(&all[n][s][k].job, &all[1][s][0].job))
                    die("%s with %d workers, %s schedule: %llu voxels, CRC %08x; with 1 "
                        "worker, subtree: %llu voxels, CRC %08x", scenes[s].name, n,
                        k ? "paper" : "subtree", (unsigned long long)all[n][s][k].job.voxels,
                        all[n][s][k].job.crc, (unsigned long long)all[1][s][0].job.voxels,
                        all[1][s][0].job.crc);
}

static void bench_table1(uint32_t res, int maxw)
{
    t1_cell (*all)[3][2] = calloc((size_t)maxw + 1, sizeof *all);
    if (!all) die("out of memory");
    for (int n = 1; n <= maxw; n++) t1_workers(n, res, all[n]);
    t1_check(maxw, all);
    table1_print(res, maxw, all);
    table1_detail(res, maxw, all);
    free(all);
    for (int s = 0; s < 3; s++) free(scenes[s].text), scenes[s].text = NULL;
}

/* ---------------------------------------------------------------- main */

static const char usage[] =
    "usage: voxdbench latency|clients|table1|all [-r RES] [-n MAXWORKERS] [--voxd PATH]\n"
    "  latency   round trip of a 64^3 sphere job, through voxd and embedded\n"
    "  clients   jobs per second through voxd with 1, 4 and 16 concurrent clients\n"
    "  table1    the paper's Table 1 (Scenes 1-3) through voxd, 1..MAXWORKERS workers\n"
    "  all       the three\n"
    "  -r RES        Table 1's resolution, 1..4096 (default 512)\n"
    "  -n MAX        workers: Table 1 runs 1..MAX, latency and clients MAX (default: cores)\n"
    "  --voxd PATH   the voxd to start (default: the one beside voxdbench)\n"
    "Run from the repository's root (Table 1 reads examples/scene*.vx).\n";

typedef struct {
    const char *cmd, *voxd;
    uint32_t res;
    int maxw;
} bench_opts;

static long parse_num(const char *s, long lo, long hi, const char *what)
{
    char *end;
    errno = 0;
    long v = strtol(s, &end, 10);
    if (errno || end == s || *end || v < lo || v > hi) {
        fprintf(stderr, "voxdbench: bad %s '%s': want %ld..%ld\n%s", what, s, lo, hi, usage);
        exit(2);
    }
    return v;
}

static void parse_args(int argc, char **argv, bench_opts *o)
{
    static const struct option longs[] = {
        {"voxd", 1, 0, 'V'}, {"help", 0, 0, 'h'}, {0, 0, 0, 0}};
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    *o = (bench_opts){argc > 1 ? argv[1] : "", NULL, 512, cores > 0 ? (int)cores : 1};
    if (argc > 1 && strcmp(argv[1], "--help") == 0) fputs(usage, stdout), exit(0);
    int c;
    optind = 2;
    while (argc > 1 && (c = getopt_long(argc, argv, "r:n:h", longs, NULL)) != -1) {
        switch (c) {
        case 'r': o->res = (uint32_t)parse_num(optarg, 1, 4096, "-r"); break;
        case 'n': o->maxw = (int)parse_num(optarg, 1, ENGINE_MAX_WORKERS, "-n"); break;
        case 'V': o->voxd = optarg; break;
        case 'h': fputs(usage, stdout); exit(0);
        default: fputs(usage, stderr); exit(2);
        }
    }
    int known = !strcmp(o->cmd, "latency") || !strcmp(o->cmd, "clients") ||
                !strcmp(o->cmd, "table1") || !strcmp(o->cmd, "all");
    if (!known || optind < argc) {
        if (argc > 1) fprintf(stderr, "voxdbench: unknown command or argument '%s'\n",
                              known ? argv[optind] : o->cmd);
        fputs(usage, stderr);
        exit(2);
    }
}

int main(int argc, char **argv)
{
    bench_opts o;
    parse_args(argc, argv, &o);
    find_voxd(argv[0], o.voxd);
    catch_signals();
    atexit(cleanup);
    make_dir();
    int all = !strcmp(o.cmd, "all");
    if (all || !strcmp(o.cmd, "table1")) /* before anything runs: a missing file fails at once */
        for (int s = 0; s < 3; s++) load_scene(&scenes[s]);
    if (all || !strcmp(o.cmd, "latency") || !strcmp(o.cmd, "clients")) {
        start_daemon(o.maxw);
        if (all || !strcmp(o.cmd, "latency")) bench_latency(o.maxw);
        if (all || !strcmp(o.cmd, "clients")) bench_clients(o.maxw);
        stop_daemon_checked();
    }
    if (all || !strcmp(o.cmd, "table1")) bench_table1(o.res, o.maxw);
    fflush(stdout);
    if (remove_files()) die("cannot remove %s: %s", D.dir, strerror(errno));
    return 0;
}
