/* cli — the subcommands of `vox` and the small parsers they share. */
#ifndef VOXD_CLI_H
#define VOXD_CLI_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "csg.h"
#include "engine.h"
#include "exit_status.h"
#include "mesh_vox.h"
#include "par.h"
#include "source.h"
#include "vod.h"
#include "vox.h"

/* The exit status of every command: cli_exit, CLI_EXIT_* (exit_status.h). */

/* sock: the daemon's socket (vox --socket, $VOXD_SOCKET, the default). */
int cli_voxelize(int argc, char **argv, const char *sock);
int cli_submit(int argc, char **argv, const char *sock);
int cli_status(int argc, char **argv, const char *sock);
int cli_cancel(int argc, char **argv, const char *sock);
int cli_ping(int argc, char **argv, const char *sock);
int cli_info(int argc, char **argv);
int cli_render(int argc, char **argv);
int cli_mesh_info(int argc, char **argv);
int cli_csg(int argc, char **argv);
/* A .csg text from path ("-": standard input) parsed, its errors printed
 * as path:line:col: node 'NAME': message.  0 and *t (csg_tree_free) with
 * the text's size in *bytes, or CLI_EXIT_USAGE. */
int cli_csg_load(const char *path, csg_tree **t, uint64_t *bytes);
/* vox csg's options (vox_mpi csg takes them too). */
typedef struct {
    const char *in, *out;
    uint32_t res, workers;
    int workers_given;
    int channel, quiet, comp;
    uint32_t band;             /* --band K (channel distance), 0: the default */
    double lo[3], hi[3];
} cli_csg_opts;
/* 0, CLI_EXIT_USAGE after a message, or -1 after --help's usage. */
int cli_csg_parse(int argc, char **argv, cli_csg_opts *o);
int cli_export(int argc, char **argv);
int cli_mesh(int argc, char **argv);

/* ---- a voxelization job's options (vox voxelize, vox submit) ---- */

typedef enum { CLI_MODE_AUTO, CLI_MODE_EMBEDDED, CLI_MODE_DAEMON } cli_mode;

typedef struct {
    const char *expr, *file, *out, *cpus;
    const char *mesh;          /* --mesh FILE: a mesh job */
    const char *csg;           /* --csg FILE: a CSG job (vox submit) */
    mesh_vox_opts mesh_opts;   /* --mode, --repair, --supersample */
    uint32_t pad;              /* --pad */
    double weld;               /* --weld EPS; -1: none */
    int mesh_opts_given;       /* one of those (they need --mesh) */
    int channel_given;         /* --channel (a mesh job's default is occupancy) */
    double lo[3], hi[3];
    int has_domain;
    uint32_t res;
    const char *res_arg;       /* --res as written, for messages */
    uint32_t workers, shm_mib;
    int engine_opts;           /* -w, --cpus, --shm-size or --compress-level given */
    engine_schedule schedule;
    vod_params vod;            /* channel, brick, comp, hash */
    int progress, quiet;
    cli_mode mode;             /* --embedded / --daemon */
} cli_job_opts;

enum { CLI_CMD_VOXELIZE, CLI_CMD_SUBMIT };

/* The defaults of both commands. */
void cli_job_defaults(cli_job_opts *o);
/* Parse the options of cmd (CLI_CMD_*): voxelize also takes the embedded
 * engine's and --embedded/--daemon.  0, or CLI_EXIT_USAGE after a message;
 * --help prints the usage and exits 0. */
int cli_job_parse(int cmd, int argc, char **argv, cli_job_opts *o);
void cli_job_usage(int cmd, FILE *f);
/* Load and compile the job's source (messages with file:line:col), apply
 * its "#@ domain".  0 or CLI_EXIT_USAGE.  *tape (when tape is not NULL)
 * is the compiled expression, to free with expr_tape_free. */
int cli_job_source(cli_job_opts *o, source *src, expr_tape **tape);

/* ---- the daemon (cli_submit.c) ---- */

/* Connect to voxd at sock.  On failure *err says why and the return is
 * the connect error (-ENOENT / -ECONNREFUSED: no daemon there). */
int cli_connect(const char *sock, int timeout_ms, vox_client **c, vox_error *err);
/* Print "no voxd answering on SOCK (why); start one ..." for a failed
 * connect; returns CLI_EXIT_NO_DAEMON. */
int cli_no_daemon(const char *sock, int rc, const vox_error *err);
/* Run the job on the daemon: submit, receive into o->out with the progress
 * line, print the summary.  src is the expression, NULL for a mesh job
 * (o->mesh: its file goes as it is, the daemon parses it).  Returns an
 * exit code.  *refused (may be NULL)
 * is set to the VOX_E* code when the daemon refused the job before
 * accepting it (nothing printed for BUSY and SHUTTING_DOWN when
 * quiet_refusal is set, so that the caller may fall back). */
int cli_daemon_job(vox_client *c, const cli_job_opts *o, const source *src,
                   int quiet_refusal, int *refused);

/* ---- mesh files (cli_meshfile.c) ---- */

/* Load the mesh at path (format AUTO: told from its contents) into *m, its
 * loader's warning said on stderr, and weld it at weld (mesh_weld) unless
 * weld < 0 (*merged: the vertices merged away, when not NULL).  0, or
 * CLI_EXIT_USAGE after the loader's message. */
int cli_mesh_load(const char *path, mesh_format format, double weld, mesh *m, uint32_t *merged);
/* --weld EPS: 0, or MESH_WELD_MIN..MESH_WELD_MAX.  0, or -1 after a message. */
int cli_parse_weld(const char *s, double *eps);
#define CLI_WELD_HELP \
    "      --weld EPS         merge the vertices within EPS of each other (the mesh's\n" \
    "                         units; 0: exactly equal positions) before anything else,\n" \
    "                         so that a file that repeats vertices is judged closed\n"


/* ---- parsers ---- */

/* Parse "a,b" (a cube [a,b]^3) or "x0,x1,y0,y1,z0,z1" into lo/hi. */
int cli_parse_domain(const char *s, double lo[3], double hi[3]);
/* Parse a CPU list "0,2,4-7" into cpus (up to cap); returns the count or -1. */
int cli_parse_cpus(const char *s, int *cpus, int cap);
/* Parse a whole decimal number in [min, max]; -1 on error. */
int cli_parse_uint(const char *s, uint32_t min, uint32_t max, uint32_t *out);
/* Read a whole file (at most max bytes) into a NUL-terminated buffer. */
int cli_read_file(const char *path, size_t max, char **out, size_t *len);
/* The CPUs online, at least 1: the threads a command opens a VOD file with
 * (vod_open_threads) when it has no worker count of its own. */
uint32_t cli_cores(void);
/* The embedded engine with workers workers, on the CPUs of the list cpus
 * (NULL: the engine's own placement) and a segment of shm_mib MiB (0: the
 * engine's default); errors said on stderr.  0 or a negative errno. */
int cli_start_engine(uint32_t workers, const char *cpus, uint32_t shm_mib, engine **e);
/* fn(ud) on thread t (par_join it) and, with workers, the engine started
 * beside it as cli_start_engine does: the thread first, so that the
 * workers' fork overlaps its work, except under AddressSanitizer, whose
 * allocator (GCC 12's libasan, clang's before 17) does not take its locks around a fork as
 * glibc's malloc does: a worker forked while the thread was inside malloc
 * waited on the lock forever, until the stall timeout killed it (10 s of
 * vox mesh in the asan build, one run in three).  0 or cli_start_engine's
 * error (the thread runs in any case). */
int cli_start_engine_beside(par_task *t, void *(*fn)(void *ud), void *ud, uint32_t workers,
                            const char *cpus, uint32_t shm_mib, engine **e);
/* ---- interrupts ---- */

/* SIGINT and SIGTERM only set cli_interrupt to the signal's number (a
 * second one ends vox at once); the commands that write a file poll it
 * (the engine as its job's cancel flag, the writers between chunks), drop
 * the file and end with cli_end_interrupted. */
extern atomic_int cli_interrupt;
void cli_catch_interrupts(void);
/* The signal that came, 0 if none. */
int cli_interrupted(void);
/* "interrupted; OUT not written", then the process ends by the signal
 * (its default action), as it would have without the handler. */
_Noreturn void cli_end_interrupted(const char *out);

/* ---- messages (cli_msg.c): every error and warning of vox, one line ---- */

struct option;
/* "vox: message" on stderr. */
void cli_error(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
/* "vox: message" on stderr, for what is not an error (a job's id). */
void cli_note(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
/* "vox: warning: message" on stderr. */
void cli_warn(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
/* "vox: CMD: message; see 'vox CMD --help'" (cmd NULL: vox's own); returns
 * CLI_EXIT_USAGE. */
int cli_usage_error(const char *cmd, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));
/* The usage error for an unknown option arg, with the nearest of names
 * (NULL-terminated, "--output", "-o") when it is a slip away, or the
 * options an ambiguous abbreviation begins.  Returns CLI_EXIT_USAGE. */
int cli_unknown_option(const char *cmd, const char *arg, const char *const names[]);
/* The same for an unknown command (names: vox's commands). */
int cli_unknown_command(const char *cmd, const char *const names[]);
/* getopt_long for command cmd, its errors said by cli_unknown_option and
 * cli_usage_error (getopt's own messages off): '?' after a message. */
int cli_getopt(const char *cmd, int argc, char **argv, const char *shorts,
               const struct option *longs);
/* A place in a named text (an expression, a .csg tree): text[0, len),
 * called name in messages; line and col 1-based (line 0: none). */
typedef struct {
    const char *name;
    const char *text;
    size_t len;
    int line, col;
} cli_text_at;

/* A parse error at a place in a text, compiler-style:
 * "name:line:col: message", then the line and a caret under the column
 * (line 0: "name: message" alone). */
void cli_error_at(const cli_text_at *at, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* "s" unless n is 1: "%u worker%s". */
const char *cli_plural(uint64_t n);
/* "PROG VERSION (commit HASH)" on stdout, from the build's -D flags. */
void cli_version(const char *prog);

#endif
