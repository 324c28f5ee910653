/* daemon_mpi — a job at or above mpi_min_res runs through `mpirun ...
 * vox_mpi voxelize` or `vox_mpi csg` (docs/mpi.md, "voxd"), on the engine
 * thread in place of the local engine: the queue, the per-user rules, the
 * memory budget, cancel and job_timeout apply as to any job, and the loop
 * never waits on it.
 *
 * The job runs from a private directory (mkdtemp, 0700): its input (the
 * expression as job.vx, the mesh file as job.mesh, the CSG tree packed as
 * job.csgp), the output as out.vod.  mpirun is started in a session of
 * its own (posix_spawn: no fork of this threaded process) with the signals
 * the daemon blocks unblocked; a cancel sends mpirun SIGTERM, then every
 * process of the session SIGKILL after DAEMON_MPI_KILL_GRACE_S.  vox_mpi unlinks its ranks'
 * shared memory as soon as it is mapped and its workers die with their
 * rank (docs/mpi.md, "Failures"), so killing the group leaves nothing. */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "clock.h"
#include "csg_pack.h"
#include "daemon.h"
#include "mesh.h"
#include "pipeline.h"
#include "vod.h"
#include "voxel.h"

#define DAEMON_MPI_POLL_NS 20000000L   /* 20 ms between looks at the child and the cancel flag */
#define DAEMON_MPI_PROGRESS_TURNS 5     /* polls between looks at the progress line */
#define DAEMON_MPI_KILL_GRACE_S 2.0    /* SIGTERM, then this long, then SIGKILL */
#define DAEMON_MPI_MAX_ARGS 96
#define DAEMON_MPI_ERR_LINES 4          /* lines of its output an error gives ... */
#define DAEMON_MPI_ERR_CHARS 340        /* ... at most this many characters, the last */
#define DAEMON_MPI_OUT_MAX 8192        /* bytes of mpirun's output kept for messages */

extern char **environ;

int daemon_mpi_wants(const daemon_mpi *m, const daemon_job *j)
{
    return m->hostfile[0] && j->res >= m->min_res;
}

/* ---------------------------------------------------------------- the command */

typedef struct {
    char *argv[DAEMON_MPI_MAX_ARGS + 1];
    int n;
    char words[sizeof ((daemon_mpi *)0)->args];
    char num[10][32];               /* numbers formatted for argv */
    char dom[160];
    char file[PATH_MAX + 16], out[PATH_MAX + 16], exe[PATH_MAX];
} cmdline;

static int add(cmdline *c, const char *a)
{
    if (c->n >= DAEMON_MPI_MAX_ARGS) return -E2BIG;
    c->argv[c->n++] = (char *)a;
    c->argv[c->n] = NULL;
    return 0;
}

static int add_all(cmdline *c, const char *const *a, size_t n)
{
    int rc = 0;
    for (size_t i = 0; i < n && !rc; i++) rc = a[i] ? add(c, a[i]) : 0;
    return rc;
}

/* a in order, a NULL option dropping the value after it too */
static int add_pairs(cmdline *c, const char *const *a, size_t n)
{
    int rc = 0;
    for (size_t i = 0; i < n && !rc; i++)
        if (a[i]) rc = add(c, a[i]);
        else i++;
    return rc;
}

/* vox_mpi: the configured path, else the one beside this voxd (a build
 * tree), else plain vox_mpi, which mpirun looks for on the PATH of each
 * host (make install puts voxd in sbin and vox_mpi in bin). */
static int vox_mpi_path(const daemon_mpi *m, char *buf, size_t len)
{
    if (m->vox_mpi[0]) return snprintf(buf, len, "%s", m->vox_mpi) < (int)len ? 0 : -ENAMETOOLONG;
    char self[PATH_MAX];
    ssize_t n = readlink("/proc/self/exe", self, sizeof self - 1);
    if (n < 0) return -errno;
    self[n] = '\0';
    char *slash = strrchr(self, '/');
    if (slash) *slash = '\0';
    if (snprintf(buf, len, "%s/vox_mpi", self) < (int)len && access(buf, X_OK) == 0) return 0;
    snprintf(buf, len, "vox_mpi");
    return 0;
}

static const char *channel_name(int ch)
{
    return ch == VOXEL_CH_OCCUPANCY ? "occupancy" : ch == VOXEL_CH_DENSITY ? "density"
           : ch == VOXEL_CH_DISTANCE ? "distance" : "surface";
}

/* The job's input file's name in dir: the expression, the mesh file's
 * bytes, the packed CSG tree (csg_pack.h). */
static void input_name(cmdline *c, const daemon_job *j, const char *dir)
{
    snprintf(c->file, sizeof c->file, "%s/%s", dir,
             j->kind == &engine_kind_mesh ? "job.mesh" : j->kind == &engine_kind_csg ? "job.csgp"
                                                                           : "job.vx");
}

/* vox_mpi's subcommand and what its kind takes: vox voxelize -f's,
 * vox voxelize --mesh's, vox csg's with voxd's extras (docs/mpi.md). */
static int kind_args(cmdline *c, const daemon_job *j)
{
    static const char *const modes[] = {"solid", "surface", "surface6", "conservative",
                                        "interior"};
    static const char *const repairs[] = {"none", "vote", "winding"};
    const mesh_vox_opts *o = &j->mesh_opts;
    snprintf(c->num[4], sizeof c->num[4], "%u", j->pad);
    snprintf(c->num[5], sizeof c->num[5], "%u", o->supersample);
    snprintf(c->num[6], sizeof c->num[6], "%u", j->band); /* every kind's */
    snprintf(c->num[7], sizeof c->num[7], "%.17g", j->weld_eps);
    snprintf(c->num[8], sizeof c->num[8], "%llu", (unsigned long long)j->csg_source_bytes);
    int is_mesh = j->kind == &engine_kind_mesh, dist = j->channel == VOXEL_CH_DISTANCE;
    const char *implicit[] = {"voxelize", "-f", c->file, "--schedule",
                              j->schedule == ENGINE_SCHED_PAPER ? "paper" : "subtree",
                              j->band && dist ? "--band" : NULL, c->num[6]};
    const char *msh[] = {
        "voxelize", "--mesh", c->file, "--mode", modes[o->mode % 5], "--repair",
        repairs[o->repair % 3], "--pad", c->num[4],
        o->supersample && !dist ? "--supersample" : NULL, c->num[5],
        j->band && dist ? "--band" : NULL, c->num[6],
        j->weld ? "--weld" : NULL, c->num[7],
        j->mesh_format ? "--mesh-format" : NULL, mesh_format_name(j->mesh_format)};
    const char *csg[] = {"csg", c->file, "--packed", "--source-bytes", c->num[8],
                         j->band && dist ? "--band" : NULL, c->num[6]};
    if (j->kind == &engine_kind_csg) return add_pairs(c, csg, sizeof csg / sizeof *csg);
    if (!is_mesh) return add_pairs(c, implicit, sizeof implicit / sizeof *implicit);
    return add_pairs(c, msh, sizeof msh / sizeof *msh);
}

/* mpirun ARGS -np R --hostfile H vox_mpi KIND... -o DIR/out.vod ... */
static int build_cmd(cmdline *c, const daemon_mpi *m, const daemon_job *j, const char *dir)
{
    int rc;
    c->n = 0;
    if ((rc = add(c, m->mpirun[0] ? m->mpirun : "mpirun"))) return rc;
    snprintf(c->words, sizeof c->words, "%s", m->args);
    for (char *save = NULL, *w = strtok_r(c->words, " \t", &save); w;
         w = strtok_r(NULL, " \t", &save))
        if ((rc = add(c, w))) return rc;
    if ((rc = vox_mpi_path(m, c->exe, sizeof c->exe))) return rc;
    snprintf(c->num[0], sizeof c->num[0], "%u", m->ranks);
    snprintf(c->num[1], sizeof c->num[1], "%u", m->workers);
    snprintf(c->num[2], sizeof c->num[2], "%u", j->res);
    snprintf(c->num[3], sizeof c->num[3], "%u", j->brick);
    snprintf(c->dom, sizeof c->dom, "%.17g,%.17g,%.17g,%.17g,%.17g,%.17g", j->lo[0],
             j->hi[0], j->lo[1], j->hi[1], j->lo[2], j->hi[2]);
    input_name(c, j, dir);
    snprintf(c->out, sizeof c->out, "%s/out.vod", dir);
    const char *head[] = {"-np", c->num[0], "--hostfile", m->hostfile, c->exe};
    /* a mesh fitted to its bounding box has no domain */
    int domain = j->kind != &engine_kind_mesh || !j->fit;
    const char *rest[] = {
        "--source-name", j->source_name ? j->source_name : "",
        "-o", c->out, "-r", c->num[2], "-w", c->num[1],
        "--channel", channel_name(j->channel), "--brick", c->num[3],
        "--compress", j->comp == VOD_COMP_RUNL ? "runl" : j->comp == VOD_COMP_NONE ? "none" : "zlib",
        "--hash", j->hash == VOD_HASH_XX32 ? "xx32" : "sfhs",
        "--progress", domain ? "-d" : NULL, domain ? c->dom : NULL,
    };
    if ((rc = add_all(c, head, sizeof head / sizeof *head))) return rc;
    if ((rc = kind_args(c, j))) return rc;
    return add_all(c, rest, sizeof rest / sizeof *rest);
}

/* The daemon's environment, and as root what lets mpirun run as root
 * (docs/mpi.md, "As root"): a daemon started as root means it.  The
 * strings are static or environ's; the array is the caller's to free. */
static char **child_env(void)
{
    size_t n = 0;
    while (environ[n]) n++;
    char **env = calloc(n + 3, sizeof *env);
    if (!env) return NULL;
    size_t k = 0;
    for (size_t i = 0; i < n; i++) env[k++] = environ[i];
    if (geteuid() == 0) {
        env[k++] = "OMPI_ALLOW_RUN_AS_ROOT=1";
        env[k++] = "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1";
    }
    return env;
}

/* ---------------------------------------------------------------- the run */

/* Start argv in a session of its own (its ranks' too: see kill_session),
 * stdout and stderr into fd. */
static int spawn(cmdline *c, int fd, pid_t *pid)
{
    posix_spawnattr_t at;
    posix_spawn_file_actions_t fa;
    sigset_t none, dfl;
    sigemptyset(&none);
    sigemptyset(&dfl);
    /* the loop's uv_signal handlers and the blocked mask are not mpirun's */
    int sigs[] = {SIGTERM, SIGINT, SIGQUIT, SIGHUP, SIGUSR1, SIGPIPE, SIGCHLD};
    for (size_t i = 0; i < sizeof sigs / sizeof *sigs; i++) sigaddset(&dfl, sigs[i]);
    posix_spawnattr_init(&at);
    posix_spawnattr_setflags(&at, POSIX_SPAWN_SETSID | POSIX_SPAWN_SETSIGMASK |
                                      POSIX_SPAWN_SETSIGDEF);
    posix_spawnattr_setsigmask(&at, &none);
    posix_spawnattr_setsigdefault(&at, &dfl);
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_adddup2(&fa, fd, 1);
    posix_spawn_file_actions_adddup2(&fa, fd, 2);
    char **env = child_env();
    int rc = env ? posix_spawnp(pid, c->argv[0], &fa, &at, c->argv, env) : ENOMEM;
    free(env);
    posix_spawn_file_actions_destroy(&fa);
    posix_spawnattr_destroy(&at);
    return -rc;
}

/* The last len - 1 bytes of what mpirun and vox_mpi printed, each line
 * as a terminal would show it (what a '\r' went back over left out). */
static void output_tail(int fd, char *buf, size_t len)
{
    off_t end = lseek(fd, 0, SEEK_END);
    off_t from = end > (off_t)len - 1 ? end - (off_t)len + 1 : 0;
    ssize_t n = pread(fd, buf, len - 1, from);
    buf[n > 0 ? n : 0] = '\0';
    char *w = buf, *line = buf;
    for (const char *r = buf; *r; r++) {
        if (*r == '\r') {
            w = line;
            continue;
        }
        *w++ = *r;
        if (*r == '\n') line = w;
    }
    *w = '\0';
}

/* vox_mpi --progress's latest line ("\r  level L  NN.N%  V voxels ..."),
 * to h->progress. */
static void read_progress(int fd, const daemon_mpi_hooks *h)
{
    char buf[256];
    off_t end = lseek(fd, 0, SEEK_END);
    off_t from = end > (off_t)sizeof buf - 1 ? end - (off_t)sizeof buf + 1 : 0;
    ssize_t n = pread(fd, buf, sizeof buf - 1, from);
    if (n <= 0) return;
    buf[n] = '\0';
    char *p = strrchr(buf, '\r');
    int level;
    double pct;
    unsigned long long voxels;
    if (p && sscanf(p + 1, " level %d %lf%% %llu voxels", &level, &pct, &voxels) == 3)
        h->progress(h->ud, pct / 100.0, voxels);
}



/* Signal every process of session sid: mpirun puts each rank in a
 * process group of its own, but in mpirun's session, and the ranks'
 * workers with them.  The number signalled. */
static int kill_session(pid_t sid, int sig)
{
    DIR *dp = opendir("/proc");
    if (!dp) return 0;
    int n = 0;
    struct dirent *e;
    while ((e = readdir(dp))) {
        char *end;
        long pid = strtol(e->d_name, &end, 10);
        if (*end || pid <= 0) continue;
        char path[64], buf[512];
        snprintf(path, sizeof path, "/proc/%ld/stat", pid);
        int fd = open(path, O_RDONLY | O_CLOEXEC);
        if (fd < 0) continue;
        ssize_t len = read(fd, buf, sizeof buf - 1);
        close(fd);
        if (len <= 0) continue;
        buf[len] = '\0';
        /* "pid (comm) state ppid pgrp session": comm may hold anything */
        char *p = strrchr(buf, ')');
        int ppid, pgrp, session;
        if (p && sscanf(p + 1, " %*c %d %d %d", &ppid, &pgrp, &session) == 3 &&
            session == sid && kill((pid_t)pid, sig) == 0)
            n++;
    }
    closedir(dp);
    return n;
}

/* Wait for mpirun; on a cancel, SIGTERM (mpirun ends its ranks), then
 * SIGKILL to its whole session.  Whatever is left in the session once
 * mpirun is gone is killed too.  Returns mpirun's wait status. */
static int wait_child(pid_t pid, atomic_int *cancel, int out, const daemon_mpi_hooks *h)
{
    double t_kill = 0;
    int st = 0, sent = 0;
    for (unsigned turn = 1;; turn++) {
        if (turn % DAEMON_MPI_PROGRESS_TURNS == 0) read_progress(out, h);
        pid_t r = waitpid(pid, &st, WNOHANG);
        if (r == pid || (r < 0 && errno != EINTR)) break;
        /* relaxed: a flag, see engine_job.cancel */
        if (!sent && atomic_load_explicit(cancel, memory_order_relaxed)) {
            kill(pid, SIGTERM);
            sent = 1;
            t_kill = clock_now() + DAEMON_MPI_KILL_GRACE_S;
        } else if (sent == 1 && clock_now() > t_kill) {
            kill_session(pid, SIGKILL);
            sent = 2;
        }
        struct timespec ts = {0, DAEMON_MPI_POLL_NS};
        nanosleep(&ts, NULL);
    }
    /* what mpirun left behind (a rank it lost track of) */
    kill_session(pid, SIGKILL);
    return st;
}

static int write_all(int fd, const char *p, size_t n)
{
    while (n) {
        ssize_t w = write(fd, p, n);
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) return w < 0 ? -errno : -EIO;
        p += w;
        n -= (size_t)w;
    }
    return 0;
}

/* vox_mpi's summary: "...: V voxels on a ... grid in T s on R ranks ...,
 * VOD written in T s" (a CSG job's "V voxels at or above S on a ...") and
 * "  B bytes, K bricks (N non-empty nodes), CRC X". */
static void parse_summary(const char *text, daemon_job *j)
{
    const char *p = strstr(text, " voxels on a ");
    if (!p) p = strstr(text, " voxels at or above S on a ");
    if (!p) return;
    const char *start = p;
    while (start > text && start[-1] >= '0' && start[-1] <= '9') start--;
    unsigned long long v = 0, bytes = 0, bricks = 0, nodes = 0;
    unsigned crc = 0;
    double tj = 0, tw = 0;
    const char *g = strstr(p, " grid in ");
    if (sscanf(start, "%llu", &v) == 1 && g && sscanf(g, " grid in %lf s", &tj) == 1) {
        j->voxels = v;
        j->t_voxelize = tj;
    }
    const char *w = strstr(start, "VOD written in ");
    if (w && sscanf(w, "VOD written in %lf s", &tw) == 1) j->t_write = tw;
    const char *b = w ? strchr(w, '\n') : NULL;
    if (b && sscanf(b + 1, " %llu bytes, %llu bricks (%llu non-empty nodes), CRC %x", &bytes,
                    &bricks, &nodes, &crc) == 4) {
        j->st.bricks = bricks;
        j->st.nonempty_nodes = nodes;
        j->st.crc32 = crc;
        j->st.file_bytes = bytes;
    }
}

/* Remove the job's directory and what is in it (vox_mpi's temporary name
 * too, where the filesystem had no O_TMPFILE). */
static void remove_dir(const char *dir)
{
    DIR *dp = opendir(dir);
    if (dp) {
        struct dirent *e;
        while ((e = readdir(dp)))
            if (strcmp(e->d_name, ".") && strcmp(e->d_name, ".."))
                unlinkat(dirfd(dp), e->d_name, 0);
        closedir(dp);
    }
    rmdir(dir);
}

/* The error for a run that did not end with a file. */
static void run_failed(daemon_job *j, int st, const char *cmd, int out)
{
    char tail[DAEMON_MPI_OUT_MAX];
    output_tail(out, tail, sizeof tail);
    /* the last lines: vox_mpi's message, or mpirun's */
    size_t n = strlen(tail);
    while (n && (tail[n - 1] == '\n' || tail[n - 1] == ' ')) tail[--n] = '\0';
    const char *t = tail + n;
    for (int lines = 0; t > tail; t--)
        if (t[-1] == '\n' && ++lines == DAEMON_MPI_ERR_LINES) break;
    char how[64];
    if (WIFSIGNALED(st)) snprintf(how, sizeof how, "was killed by signal %d", WTERMSIG(st));
    else if (WEXITSTATUS(st) == 127) snprintf(how, sizeof how, "could not be started");
    else snprintf(how, sizeof how, "exited with status %d", WEXITSTATUS(st));
    size_t tl = strlen(t);
    if (tl > DAEMON_MPI_ERR_CHARS) t += tl - DAEMON_MPI_ERR_CHARS; /* the end says most */
    snprintf(j->message, sizeof j->message, "the MPI run (%.80s) %.40s: %.340s", cmd, how,
             t[0] ? t : "it printed nothing");
    j->code = VOXD__ERROR_CODE__INTERNAL;
}

/* The job's input as vox_mpi reads it: the expression's text, the mesh
 * file's bytes (kept for this), the CSG tree packed (csg_pack.h) with its
 * leaves' files.  0, or a negative errno. */
static int write_input(const cmdline *c, const daemon_job *j)
{
    uint8_t *packed = NULL;
    size_t len = j->source_len;
    int rc = j->kind == &engine_kind_csg ? csg_tree_pack(j->csg, &packed, &len) : 0;
    int fd = rc ? -1 : open(c->file, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
    if (!rc && fd < 0) rc = -errno;
    if (!rc) rc = write_all(fd, packed ? (const char *)packed : j->source, len);
    if (fd >= 0) close(fd);
    free(packed);
    return rc;
}

/* The job's file and mpirun started: 0, or a negative errno. */
static int start_run(cmdline *c, const daemon_mpi *m, const daemon_job *j, const char *dir, int out,
                     pid_t *pid)
{
    int rc = build_cmd(c, m, j, dir);
    if (!rc) rc = write_input(c, j);
    return rc ? rc : spawn(c, out, pid);
}

/* mpirun has ended (st) or been stopped: the file, or j's error. */
static int end_run(const cmdline *c, daemon_job *j, int st, int out)
{
    /* relaxed: a flag, see engine_job.cancel; the caller says why it stopped */
    if (atomic_load_explicit(&j->cancel, memory_order_relaxed)) return -ECANCELED;
    int fd = WIFEXITED(st) && WEXITSTATUS(st) == 0 ? open(c->out, O_RDONLY | O_CLOEXEC) : -1;
    if (fd < 0) {
        run_failed(j, st, c->argv[0], out);
        return -1;
    }
    char text[DAEMON_MPI_OUT_MAX];
    output_tail(out, text, sizeof text);
    parse_summary(text, j);
    return fd;
}

int daemon_mpi_run(const daemon_mpi *m, daemon_job *j, int *result, const daemon_mpi_hooks *h)
{
    *result = -1;
    const char *tmp = getenv("TMPDIR");
    char dir[PATH_MAX];
    snprintf(dir, sizeof dir, "%s/voxd-mpi-XXXXXX", tmp && tmp[0] == '/' ? tmp : "/tmp");
    if (!mkdtemp(dir)) {
        snprintf(j->message, sizeof j->message, "cannot make the MPI job's directory: %s",
                 strerror(errno));
        return j->code = VOXD__ERROR_CODE__INTERNAL, -1;
    }
    cmdline c;
    c.argv[0] = m->mpirun[0] ? (char *)m->mpirun : "mpirun"; /* for a message before build_cmd */
    pid_t pid = 0;
    int out = memfd_create("voxd-mpi-output", MFD_CLOEXEC);
    int rc = out < 0 ? -errno : start_run(&c, m, j, dir, out, &pid);
    if (rc) {
        snprintf(j->message, sizeof j->message, "cannot start the MPI run (%s): %s",
                 rc == -E2BIG ? "mpirun_args has too many words" : c.argv[0], strerror(-rc));
        j->code = VOXD__ERROR_CODE__INTERNAL;
    } else {
        char line[PATH_MAX + 128];
        snprintf(line, sizeof line,
                 "job %llu runs through MPI: %s -np %u (pid %d), %u worker%s per rank",
                 (unsigned long long)j->id, c.argv[0], m->ranks, (int)pid, m->workers,
                 m->workers == 1 ? "" : "s");
        h->started(h->ud, line);
        rc = end_run(&c, j, wait_child(pid, &j->cancel, out, h), out);
        *result = rc >= 0 ? rc : -1;
    }
    if (out >= 0) close(out);
    remove_dir(dir); /* an open result stays readable */
    return *result >= 0 ? 0 : rc == -ECANCELED ? rc : -1;
}
