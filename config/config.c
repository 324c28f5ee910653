/* config — the daemon's configuration file.  See config.h. */
#include "config.h"

#include <ctype.h>
#include <errno.h>
#include <grp.h>
#include <pwd.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "err.h"
#include "expr.h"
#include "frame.h"
#include "log.h"

#define KIB ((uint64_t)1 << 10)
#define MIB ((uint64_t)1 << 20)
#define GIB ((uint64_t)1 << 30)
#define TIB ((uint64_t)1 << 40)

enum kind {
    K_PATH,    /* absolute path, bounded by its field */
    K_MODE,    /* octal permission bits */
    K_GROUP,   /* none | name | gid */
    K_UIDS,    /* any | list of names or uids */
    K_WORKERS, /* auto | count */
    K_AUTO,    /* auto (stored as 0) | count */
    K_CPUS,    /* auto | list of CPUs and ranges */
    K_BYTES,   /* bytes with K/M/G/T */
    K_COUNT,   /* plain number */
    K_SECONDS, /* with s/m/h/d */
    K_LEVEL,   /* log level name */
    K_MEMORY,  /* auto | bytes with K/M/G/T */
    K_TEXT,    /* words, bounded by their field; none = empty */
};

typedef struct {
    const char *key;
    enum kind kind;
    size_t off, size; /* the field in voxd_config */
    uint64_t min, max;
    const char *doc;  /* the limits': a comment for config_print */
} option;

/* Constants of other modules the table's ranges must agree with. */
_Static_assert(EXPR_MAX_DEPTH_CAP == 1024, "max_expr_depth's range in VOX_LIMITS");
_Static_assert(PROTO_FRAME_MIN_MAX == 4096 && PROTO_FRAME_LIMIT_MAX == 64u << 20 &&
                   PROTO_FRAME_DEFAULT_MAX == 1u << 20,
               "max_frame's default and range in VOX_LIMITS");

#define F(m) offsetof(voxd_config, m), sizeof(((voxd_config *)0)->m)
static const option options[] = {
    {"socket", K_PATH, F(socket), 0, 0, NULL},
    {"socket_mode", K_MODE, F(socket_mode), 0, 0777, NULL},
    {"socket_group", K_GROUP, F(socket_group), 0, 0, NULL},
    {"allow_uids", K_UIDS, F(allow_uids), 0, 0, NULL},
    {"workers", K_WORKERS, F(workers), 1, CONFIG_MAX_WORKERS, NULL},
    {"cpus", K_CPUS, F(cpus), 0, CONFIG_MAX_CPUS - 1, NULL},
    {"shm_size", K_BYTES, F(shm_size), 16 * MIB, TIB, NULL},
    {"log_file", K_PATH, F(log_file), 0, 0, NULL},
    {"log_level", K_LEVEL, F(log_level), 0, 0, NULL},
    {"pidfile", K_PATH, F(pidfile), 0, 0, NULL},
    {"max_clients", K_COUNT, F(max_clients), 1, 65536, NULL},
    {"max_clients_per_uid", K_AUTO, F(max_clients_per_uid), 1, 65536, NULL},
    {"client_timeout", K_SECONDS, F(client_timeout), 1, 86400, NULL},
    {"worker_stall_timeout", K_SECONDS, F(worker_stall_timeout), 0, 3600, NULL},
    {"max_memory", K_MEMORY, F(max_memory), 64 * MIB, 1024 * TIB, NULL},
    {"mpi_hostfile", K_PATH, F(mpi_hostfile), 0, 0, NULL},
    {"mpi_min_res", K_COUNT, F(mpi_min_res), 1, 65536, NULL},
    {"mpi_ranks", K_COUNT, F(mpi_ranks), 1, 4096, NULL},
    {"mpi_workers", K_COUNT, F(mpi_workers), 0, CONFIG_MAX_WORKERS, NULL},
    {"mpirun", K_PATH, F(mpirun), 0, 0, NULL},
    {"mpirun_args", K_TEXT, F(mpirun_args), 0, 0, NULL},
    {"vox_mpi", K_PATH, F(vox_mpi), 0, 0, NULL},
#define LIMIT_OPTION(name, type, def, min, max, unit, doc) \
    {#name, K_##unit, F(name), (min), (max), doc},
    VOX_LIMITS(LIMIT_OPTION)
#undef LIMIT_OPTION
};
#define N_OPTIONS (sizeof options / sizeof *options)

void config_defaults(voxd_config *c)
{
    memset(c, 0, sizeof *c);
    snprintf(c->socket, sizeof c->socket, "/run/voxd/voxd.sock");
    c->socket_mode = 0660;
    c->shm_size = 2 * GIB;
    c->log_level = LOG_LEVEL_INFO;
    c->max_clients = 128;
    c->client_timeout = 30;
    c->worker_stall_timeout = 10;
    c->mpi_min_res = 1024;
    c->mpi_ranks = 2;
    c->mpi_workers = 1;
    snprintf(c->mpirun_args, sizeof c->mpirun_args, "%s", CONFIG_MPIRUN_ARGS);
#define LIMIT_DEFAULT(name, type, def, min, max, unit, doc) c->name = (def);
    VOX_LIMITS(LIMIT_DEFAULT)
#undef LIMIT_DEFAULT
}

/* ---------------------------------------------------------------- values */

/* Why a value was refused, filled by the parsers below (err_set, -EINVAL). */
typedef err_info reason;

/* A value of the file in a message: at most SHOWN_MAX bytes of it, then
 * "...", so that no error line runs long whatever the file holds. */
#define SHOWN_MAX 40
#define SHOWN_LEN(s, n) ((n) > SHOWN_MAX ? SHOWN_MAX : (int)(n)), (s), ((n) > SHOWN_MAX ? "..." : "")
#define SHOWN(s) SHOWN_LEN(s, strlen(s))

/* Decimal digits at *s (no sign, no blanks); -ERANGE on overflow. */
static int parse_digits(const char **s, uint64_t *v)
{
    const char *p = *s;
    uint64_t n = 0;
    if (!isdigit((unsigned char)*p)) return -EINVAL;
    for (; isdigit((unsigned char)*p); p++) {
        unsigned d = (unsigned)(*p - '0');
        if (n > (UINT64_MAX - d) / 10) return -ERANGE;
        n = n * 10 + d;
    }
    *s = p;
    *v = n;
    return 0;
}

static void fmt_size(uint64_t v, char *buf, size_t len)
{
    static const struct { uint64_t unit; char c; } units[] = {
        {TIB, 'T'}, {GIB, 'G'}, {MIB, 'M'}, {KIB, 'K'}};
    for (size_t i = 0; i < 4; i++)
        if (v && v % units[i].unit == 0) {
            snprintf(buf, len, "%llu%c", (unsigned long long)(v / units[i].unit), units[i].c);
            return;
        }
    snprintf(buf, len, "%llu", (unsigned long long)v);
}

/* The multiplier of a unit letter; 0 if the letter is not a unit here. */
static uint64_t unit_of(const option *o, char c)
{
    if (o->kind == K_SECONDS) {
        switch (c) {
        case 's': return 1;
        case 'm': return 60;
        case 'h': return 3600;
        case 'd': return 86400;
        }
    } else if (o->kind == K_BYTES || o->kind == K_MEMORY) {
        switch (toupper((unsigned char)c)) {
        case 'K': return KIB;
        case 'M': return MIB;
        case 'G': return GIB;
        case 'T': return TIB;
        }
    }
    return 0;
}

static int out_of_range(const option *o, const char *val, reason *r)
{
    char lo[32], hi[32];
    if (o->kind == K_BYTES || o->kind == K_MEMORY) {
        fmt_size(o->min, lo, sizeof lo);
        fmt_size(o->max, hi, sizeof hi);
    } else {
        snprintf(lo, sizeof lo, "%llu", (unsigned long long)o->min);
        snprintf(hi, sizeof hi, "%llu", (unsigned long long)o->max);
    }
    return err_set(r, -EINVAL, "%s %.*s%s is out of range (%s to %s%s)", o->key, SHOWN(val), lo, hi,
                  o->kind == K_SECONDS ? " seconds" : "");
}

/* A number with an optional unit letter, checked against [o->min, o->max]. */
static int parse_number(const option *o, const char *val, uint64_t *out, reason *r)
{
    const char *p = val;
    uint64_t v, unit = 1;
    int rc = parse_digits(&p, &v);
    if (rc == -ERANGE) return out_of_range(o, val, r);
    if (rc == 0 && *p && !p[1] && (unit = unit_of(o, *p))) p++;
    if (rc || *p)
        return err_set(r, -EINVAL, "bad value '%.*s%s' for %s: want %s", SHOWN(val), o->key,
                      o->kind == K_BYTES      ? "a size like 65536, 256K, 2G"
                      : o->kind == K_MEMORY  ? "auto or a size like 512M, 8G"
                      : o->kind == K_SECONDS ? "a duration like 600, 10m, 2h"
                                             : "a whole number");
    if (v > UINT64_MAX / unit || v * unit < o->min || v * unit > o->max)
        return out_of_range(o, val, r);
    *out = v * unit;
    return 0;
}

static void store_uint(void *field, size_t size, uint64_t v)
{
    if (size == sizeof(uint64_t)) *(uint64_t *)field = v;
    else *(uint32_t *)field = (uint32_t)v;
}

static int parse_path(const option *o, const char *val, char *field, reason *r)
{
    if (val[0] != '/')
        return err_set(r, -EINVAL, "%s must be an absolute path, got '%.*s%s'", o->key, SHOWN(val));
    if (strlen(val) >= o->size)
        return err_set(r, -EINVAL, "%s is longer than %zu bytes", o->key, o->size - 1);
    memcpy(field, val, strlen(val) + 1);
    return 0;
}

/* Printable words (no control character), or none for no words. */
static int parse_text(const option *o, const char *val, char *field, reason *r)
{
    if (strcmp(val, "none") == 0) val = "";
    if (strlen(val) >= o->size)
        return err_set(r, -EINVAL, "%s is longer than %zu bytes", o->key, o->size - 1);
    for (const char *p = val; *p; p++)
        if (!isprint((unsigned char)*p) && *p != '\t')
            return err_set(r, -EINVAL, "%s contains a control character", o->key);
    memcpy(field, val, strlen(val) + 1);
    return 0;
}

static int parse_mode(const option *o, const char *val, unsigned *mode, reason *r)
{
    size_t n = strlen(val);
    if (n == 0 || n > 6 || strspn(val, "01234567") != n)
        return err_set(r, -EINVAL, "bad value '%.*s%s' for %s: want octal permissions like 0660", SHOWN(val),
                      o->key);
    unsigned long m = strtoul(val, NULL, 8);
    if (m > o->max)
        return err_set(r, -EINVAL, "%s %.*s%s is out of range (0 to 0777)", o->key, SHOWN(val));
    *mode = (unsigned)m;
    return 0;
}

static int parse_group(const char *val, voxd_config *c, reason *r)
{
    if (strcmp(val, "none") == 0) {
        c->has_socket_group = 0;
        c->socket_group[0] = '\0';
        return 0;
    }
    if (strlen(val) >= sizeof c->socket_group)
        return err_set(r, -EINVAL, "socket_group '%.*s%s' is too long", SHOWN(val));
    const char *p = val;
    uint64_t gid;
    if (parse_digits(&p, &gid) == 0 && !*p) {
        if (gid >= (gid_t)-1) return err_set(r, -EINVAL, "socket_group %.*s%s is out of range", SHOWN(val));
        c->socket_gid = (gid_t)gid;
    } else {
        struct group gr, *res = NULL;
        char buf[4096];
        if (getgrnam_r(val, &gr, buf, sizeof buf, &res) != 0 || !res)
            return err_set(r, -EINVAL, "unknown group '%s' for socket_group", val);
        c->socket_gid = gr.gr_gid;
    }
    c->has_socket_group = 1;
    snprintf(c->socket_group, sizeof c->socket_group, "%s", val);
    return 0;
}

/* Split a list at commas and blanks; fn is called for each item (NUL-ended
 * in a copy). */
static int for_each_item(const char *val, reason *r, voxd_config *c,
                         int (*fn)(const char *item, voxd_config *c, reason *r))
{
    char item[256];
    const char *p = val;
    while (*p) {
        size_t n = strcspn(p, ", \t");
        if (n >= sizeof item) return err_set(r, -EINVAL, "list item '%.32s...' is too long", p);
        if (n) {
            memcpy(item, p, n);
            item[n] = '\0';
            int rc = fn(item, c, r);
            if (rc) return rc;
        }
        p += n;
        p += strspn(p, ", \t");
    }
    return 0;
}

static int add_uid(const char *item, voxd_config *c, reason *r)
{
    const char *p = item;
    uint64_t uid;
    if (c->n_allow_uids == CONFIG_MAX_UIDS)
        return err_set(r, -EINVAL, "allow_uids lists more than %d users", CONFIG_MAX_UIDS);
    if (parse_digits(&p, &uid) == 0 && !*p) {
        if (uid >= (uid_t)-1) return err_set(r, -EINVAL, "allow_uids: uid %.*s%s is out of range", SHOWN(item));
    } else {
        struct passwd pw, *res = NULL;
        char buf[4096];
        if (getpwnam_r(item, &pw, buf, sizeof buf, &res) != 0 || !res)
            return err_set(r, -EINVAL, "allow_uids: unknown user '%.*s%s'", SHOWN(item));
        uid = pw.pw_uid;
    }
    c->allow_uids[c->n_allow_uids++] = (uid_t)uid;
    return 0;
}

static int parse_uids(const char *val, voxd_config *c, reason *r)
{
    c->allow_any = strcmp(val, "any") == 0;
    c->n_allow_uids = 0;
    if (c->allow_any) return 0;
    return for_each_item(val, r, c, add_uid);
}

static int add_cpus(const char *item, voxd_config *c, reason *r)
{
    const char *p = item;
    uint64_t lo, hi;
    if (parse_digits(&p, &lo)) goto bad;
    hi = lo;
    if (*p == '-') {
        p++;
        if (parse_digits(&p, &hi)) goto bad;
    }
    if (*p || lo > hi) goto bad;
    if (hi >= CONFIG_MAX_CPUS)
        return err_set(r, -EINVAL, "cpus: CPU %llu is out of range (0 to %d)",
                      (unsigned long long)hi, CONFIG_MAX_CPUS - 1);
    for (uint64_t cpu = lo; cpu <= hi; cpu++) {
        if (c->n_cpus == CONFIG_MAX_CPUS)
            return err_set(r, -EINVAL, "cpus lists more than %d CPUs", CONFIG_MAX_CPUS);
        c->cpus[c->n_cpus++] = (int)cpu;
    }
    return 0;
bad:
    return err_set(r, -EINVAL, "bad value '%.*s%s' in cpus: want a CPU like 3 or a range like 0-3", SHOWN(item));
}

static int parse_cpus(const char *val, voxd_config *c, reason *r)
{
    c->n_cpus = 0;
    if (strcmp(val, "auto") == 0) return 0;
    return for_each_item(val, r, c, add_cpus);
}

static int parse_value(const option *o, const char *val, voxd_config *c, reason *r)
{
    char *field = (char *)c + o->off;
    uint64_t v;
    int rc;
    switch (o->kind) {
    case K_PATH: return parse_path(o, val, field, r);
    case K_TEXT: return parse_text(o, val, field, r);
    case K_MODE: return parse_mode(o, val, &c->socket_mode, r);
    case K_GROUP: return parse_group(val, c, r);
    case K_UIDS: return parse_uids(val, c, r);
    case K_CPUS: return parse_cpus(val, c, r);
    case K_LEVEL:
        if ((rc = log_level_parse(val)) < 0)
            return err_set(r, -EINVAL, "bad value '%.*s%s' for log_level: want error, warn, info or debug",
                          SHOWN(val));
        c->log_level = rc;
        return 0;
    case K_WORKERS:
        if (strcmp(val, "auto") == 0) {
            c->workers = 0;
            return 0;
        }
        if (!isdigit((unsigned char)val[0]))
            return err_set(r, -EINVAL, "bad value '%.*s%s' for workers: want auto or 1 to %d", SHOWN(val),
                          CONFIG_MAX_WORKERS);
        if ((rc = parse_number(o, val, &v, r))) return rc;
        c->workers = (int)v;
        return 0;
    case K_AUTO:
        if (strcmp(val, "auto") == 0) {
            store_uint(field, o->size, 0);
            return 0;
        }
        if (!isdigit((unsigned char)val[0]))
            return err_set(r, -EINVAL, "bad value '%.*s%s' for %s: want auto or %llu to %llu", SHOWN(val),
                          o->key, (unsigned long long)o->min, (unsigned long long)o->max);
        if ((rc = parse_number(o, val, &v, r))) return rc;
        store_uint(field, o->size, v);
        return 0;
    case K_MEMORY:
        if (strcmp(val, "auto") == 0) v = 0;
        else if ((rc = parse_number(o, val, &v, r))) return rc;
        store_uint(field, o->size, v);
        return 0;
    default:
        if ((rc = parse_number(o, val, &v, r))) return rc;
        store_uint(field, o->size, v);
        return 0;
    }
}

/* ---------------------------------------------------------------- lines */

typedef struct {
    const char *name;
    int line;
    int set[N_OPTIONS]; /* line where each option was set, 0 = not */
    err_info *err;
} parser;

__attribute__((format(printf, 3, 4)))
static int fail_at(parser *p, int line, const char *fmt, ...)
{
    char why[512];
    va_list ap;
    va_start(ap, fmt);
    err_vfmt(why, sizeof why, -EINVAL, fmt, ap);
    va_end(ap);
    if (line > 0) return err_set(p->err, -EINVAL, "%s:%d: %s", p->name, line, why);
    return err_set(p->err, -EINVAL, "%s: %s", p->name, why);
}

static const option *find_option(const char *key, size_t len)
{
    for (size_t i = 0; i < N_OPTIONS; i++)
        if (strlen(options[i].key) == len && memcmp(options[i].key, key, len) == 0)
            return &options[i];
    return NULL;
}

static int parse_line(parser *p, char *s, voxd_config *c)
{
    size_t n = strlen(s);
    while (n && isspace((unsigned char)s[n - 1])) s[--n] = '\0';
    s += strspn(s, " \t");
    if (!*s || *s == '#') return 0;

    size_t klen = strcspn(s, " \t");
    char *val = s + klen;
    val += strspn(val, " \t");
    const option *o = find_option(s, klen);
    if (!o) return fail_at(p, p->line, "unknown key '%.*s%s'", SHOWN_LEN(s, klen));
    size_t i = (size_t)(o - options);
    if (p->set[i])
        return fail_at(p, p->line, "duplicate key '%s' (first set on line %d)", o->key,
                       p->set[i]);
    if (!*val) return fail_at(p, p->line, "'%s' needs a value", o->key);
    reason r;
    if (parse_value(o, val, c, &r)) return fail_at(p, p->line, "%s", r.msg);
    p->set[i] = p->line;
    if (o->off == offsetof(voxd_config, shm_size)) c->shm_size_set = 1;
    return 0;
}

/* The line of the later of two options (for errors about both), 0 if
 * neither came from the file. */
static int later_line(const parser *p, const char *a, const char *b)
{
    int la = p->set[find_option(a, strlen(a)) - options];
    int lb = p->set[find_option(b, strlen(b)) - options];
    return la > lb ? la : lb;
}

static int check_together(parser *p, const voxd_config *c)
{
    char f[32], x[32];
    if (c->max_clients_per_uid > c->max_clients)
        return fail_at(p, later_line(p, "max_clients_per_uid", "max_clients"),
                       "max_clients_per_uid %u is over max_clients %u (one uid's share of "
                       "the connections; at most all of them)",
                       c->max_clients_per_uid, c->max_clients);
    /* The budget holds the segment and at least some results. */
    if (c->max_memory && c->max_memory < c->shm_size + CONFIG_RESULT_ROOM) {
        char m[32];
        fmt_size(c->max_memory, x, sizeof x);
        fmt_size(c->shm_size, m, sizeof m);
        return fail_at(p, later_line(p, "max_memory", "shm_size"),
                       "max_memory %s leaves no room for results beside shm_size %s "
                       "(it must be at least %llu MiB more)",
                       x, m, (unsigned long long)(CONFIG_RESULT_ROOM >> 20));
    }
    fmt_size(c->max_frame, f, sizeof f);
    if (c->chunk_size > c->max_frame - PROTO_FRAME_CHUNK_OVERHEAD) {
        fmt_size(c->chunk_size, x, sizeof x);
        return fail_at(p, later_line(p, "chunk_size", "max_frame"),
                       "chunk_size %s does not fit in max_frame %s (a chunk needs %u bytes more)",
                       x, f, PROTO_FRAME_CHUNK_OVERHEAD);
    }
    /* An expression of max_expr_bytes must be sendable: inline in a
     * Submit, or as the job's input. */
    if (c->max_expr_bytes > c->max_frame - CONFIG_REQUEST_OVERHEAD &&
        c->max_expr_bytes > c->max_input_bytes) {
        char in[32];
        fmt_size(c->max_expr_bytes, x, sizeof x);
        fmt_size(c->max_input_bytes, in, sizeof in);
        int line = later_line(p, "max_expr_bytes", "max_frame");
        int l2 = later_line(p, "max_expr_bytes", "max_input_bytes");
        return fail_at(p, l2 > line ? l2 : line,
                       "max_expr_bytes %s fits neither in max_frame %s (a request needs %u "
                       "bytes more) nor in max_input_bytes %s",
                       x, f, CONFIG_REQUEST_OVERHEAD, in);
    }
    return 0;
}

int config_load_stream(FILE *f, const char *name, voxd_config *c, err_info *err)
{
    parser p = {.name = name, .err = err};
    voxd_config *tmp = malloc(sizeof *tmp);
    char line[CONFIG_MAX_LINE + 2];
    int rc = 0;
    if (!tmp) return err_set(err, -ENOMEM, "%s: out of memory", name);
    config_defaults(tmp);
    while (rc == 0 && fgets(line, sizeof line, f)) {
        p.line++;
        size_t n = strlen(line);
        if (n - (n && line[n - 1] == '\n') > CONFIG_MAX_LINE)
            rc = fail_at(&p, p.line, "line is longer than %d bytes", CONFIG_MAX_LINE);
        else
            rc = parse_line(&p, line, tmp);
    }
    if (rc == 0 && ferror(f)) {
        rc = errno ? -errno : -EIO;
        err_set(err, rc, "%s: %s", name, strerror(-rc));
    }
    if (rc == 0) rc = check_together(&p, tmp);
    if (rc == 0) *c = *tmp;
    free(tmp);
    return rc;
}

int config_load(const char *path, voxd_config *c, err_info *err)
{
    FILE *f = fopen(path, "re");
    if (!f) {
        int rc = -errno;
        return err_set(err, rc, "%s: %s", path, strerror(-rc));
    }
    errno = 0;
    int rc = config_load_stream(f, path, c, err);
    fclose(f);
    return rc;
}

/* ---------------------------------------------------------------- output */

static void print_cpus(FILE *out, const voxd_config *c)
{
    fputs("cpus ", out);
    if (c->n_cpus == 0) fputs("auto", out);
    for (int i = 0; i < c->n_cpus;) {
        int j = i;
        while (j + 1 < c->n_cpus && c->cpus[j + 1] == c->cpus[j] + 1) j++;
        fprintf(out, i ? ",%d" : "%d", c->cpus[i]);
        if (j > i) fprintf(out, "-%d", c->cpus[j]);
        i = j + 1;
    }
    fputc('\n', out);
}

static void print_uids(FILE *out, const voxd_config *c)
{
    if (c->allow_any) {
        fputs("allow_uids any\n", out);
        return;
    }
    if (c->n_allow_uids == 0) {
        fprintf(out, "# allow_uids: not set, so uid %u (this daemon's) and root\n",
                (unsigned)getuid());
        return;
    }
    fputs("allow_uids ", out);
    for (int i = 0; i < c->n_allow_uids; i++)
        fprintf(out, i ? ",%u" : "%u", (unsigned)c->allow_uids[i]);
    fputc('\n', out);
}

static void print_option(FILE *out, const option *o, const voxd_config *c)
{
    const char *field = (const char *)c + o->off;
    char buf[32];
    uint64_t v = o->size == sizeof(uint64_t) ? *(const uint64_t *)field
                                             : *(const uint32_t *)field;
    if (o->doc) fprintf(out, "# %s: %s\n", o->key, o->doc);
    switch (o->kind) {
    case K_PATH:
        if (*field) fprintf(out, "%s %s\n", o->key, field);
        else fprintf(out, "# %s: not set, so %s\n", o->key,
                     strcmp(o->key, "log_file") == 0   ? "stderr"
                     : strcmp(o->key, "mpi_hostfile") == 0 ? "no job runs through MPI"
                     : strcmp(o->key, "mpirun") == 0   ? "mpirun on the PATH"
                     : strcmp(o->key, "vox_mpi") == 0  ? "vox_mpi beside voxd, else on the PATH"
                                                       : "none");
        break;
    case K_TEXT: fprintf(out, "%s %s\n", o->key, *field ? field : "none"); break;
    case K_MODE: fprintf(out, "%s 0%03o\n", o->key, c->socket_mode); break;
    case K_GROUP:
        fprintf(out, "%s %s\n", o->key, c->has_socket_group ? c->socket_group : "none");
        break;
    case K_UIDS: print_uids(out, c); break;
    case K_CPUS: print_cpus(out, c); break;
    case K_LEVEL: fprintf(out, "%s %s\n", o->key, log_level_name(c->log_level)); break;
    case K_WORKERS:
        if (c->workers) fprintf(out, "workers %d\n", c->workers);
        else fprintf(out, "# workers auto: %d on this machine\nworkers auto\n", config_workers(c));
        break;
    case K_AUTO:
        if (v) fprintf(out, "%s %llu\n", o->key, (unsigned long long)v);
        else fprintf(out, "# %s auto: %u with max_clients %u\n%s auto\n", o->key,
                     config_clients_per_uid(c), c->max_clients, o->key);
        break;
    case K_BYTES:
        fmt_size(v, buf, sizeof buf);
        fprintf(out, "%s %s\n", o->key, buf);
        break;
    case K_MEMORY:
        fmt_size(config_max_memory(c), buf, sizeof buf);
        if (v) fprintf(out, "%s %s\n", o->key, buf);
        else fprintf(out, "# %s auto: %s on this machine\n%s auto\n", o->key, buf, o->key);
        break;
    default: fprintf(out, "%s %llu\n", o->key, (unsigned long long)v); break;
    }
}

void config_print(FILE *out, const voxd_config *c)
{
    fputs("# voxd: effective configuration\n", out);
    for (size_t i = 0; i < N_OPTIONS; i++) print_option(out, &options[i], c);
}

/* ---------------------------------------------------------------- effective */

int config_workers(const voxd_config *c)
{
    if (c->workers > 0) return c->workers;
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    if (n < 1) n = 1;
    return n > CONFIG_MAX_WORKERS ? CONFIG_MAX_WORKERS : (int)n;
}

/* One uid may hold a quarter of the connections unless told otherwise:
 * enough for a user's vox commands in parallel, and three more users
 * always find room. */
uint32_t config_clients_per_uid(const voxd_config *c)
{
    if (c->max_clients_per_uid) return c->max_clients_per_uid;
    return c->max_clients >= 4 ? c->max_clients / 4 : 1;
}

uint64_t config_max_memory(const voxd_config *c)
{
    if (c->max_memory) return c->max_memory;
    long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
    uint64_t half = pages > 0 && page > 0 ? (uint64_t)pages * (uint64_t)page / 2 : 0;
    uint64_t least = c->shm_size + CONFIG_RESULT_ROOM;
    return (half > least ? half : least) / MIB * MIB;
}

int config_uid_allowed(const voxd_config *c, uid_t uid)
{
    if (c->allow_any) return 1;
    if (c->n_allow_uids == 0) return uid == 0 || uid == getuid();
    for (int i = 0; i < c->n_allow_uids; i++)
        if (c->allow_uids[i] == uid) return 1;
    return 0;
}

void config_proto_limits(const voxd_config *c, proto_limits *lim)
{
#define LIMIT_COPY(name, type, def, min, max, unit, doc) lim->name = c->name;
    VOX_LIMITS(LIMIT_COPY)
#undef LIMIT_COPY
}
