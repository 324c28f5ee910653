/* The config file: defaults, a full file, every error with its exact
 * "FILE:LINE: reason", units, lists, print/load round trip, and
 * config/voxd.conf itself (it must load to the defaults, also with every
 * documented "#key default" line uncommented).  Also the log (tiny). */
#include <criterion/criterion.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "config.h"
#include "expr.h"
#include "log.h"

static int load_text(const char *text, voxd_config *c, err_info *err)
{
    FILE *f = fmemopen((void *)text, strlen(text), "r");
    cr_assert_not_null(f);
    int rc = config_load_stream(f, "t.conf", c, err);
    fclose(f);
    return rc;
}

static void load_ok(const char *text, voxd_config *c)
{
    err_info err = {0};
    int rc = load_text(text, c, &err);
    cr_assert_eq(rc, 0, "refused: %s", err.msg);
}

static void load_fails(const char *text, const char *want)
{
    voxd_config c;
    config_defaults(&c);
    c.max_res = 12345; /* must survive a failed load */
    err_info err = {0};
    int rc = load_text(text, &c, &err);
    cr_assert_eq(rc, -EINVAL, "accepted:\n%s", text);
    cr_assert_str_eq(err.msg, want);
    cr_assert_eq(c.max_res, 12345, "a failed load changed the config");
}

/* The printed form of a config, to compare two configs field by field. */
static char *printed(const voxd_config *c)
{
    char *s = NULL;
    size_t n = 0;
    FILE *f = open_memstream(&s, &n);
    config_print(f, c);
    fclose(f);
    return s;
}

static void assert_same(const voxd_config *a, const voxd_config *b)
{
    char *pa = printed(a), *pb = printed(b);
    cr_assert_str_eq(pa, pb);
    free(pa);
    free(pb);
}

static const char *root_path(const char *rel, char *buf, size_t len)
{
    const char *root = getenv("VOXD_ROOT");
    snprintf(buf, len, "%s/%s", root ? root : ".", rel);
    return buf;
}

/* ---------------------------------------------------------------- defaults */

Test(config, defaults)
{
    voxd_config c;
    config_defaults(&c);
    cr_assert_str_eq(c.socket, "/run/voxd/voxd.sock");
    cr_assert_eq(c.socket_mode, 0660);
    cr_assert_eq(c.has_socket_group, 0);
    cr_assert_eq(c.allow_any, 0);
    cr_assert_eq(c.n_allow_uids, 0);
    cr_assert_eq(c.workers, 0);
    cr_assert_eq(c.n_cpus, 0);
    cr_assert_eq(c.shm_size, 2ull << 30);
    cr_assert_str_eq(c.log_file, "");
    cr_assert_eq(c.log_level, LOG_LEVEL_INFO);
    cr_assert_str_eq(c.pidfile, "");
    cr_assert_eq(c.max_frame, 1u << 20);
    cr_assert_eq(c.max_expr_bytes, 65536);
    cr_assert_eq(c.max_expr_depth, 256);
    cr_assert_eq(c.max_res, 4096);
    cr_assert_eq(c.max_csg_nodes, 256);
    cr_assert_eq(c.max_queued_jobs, 64);
    cr_assert_eq(c.max_jobs_per_uid, 16);
    cr_assert_eq(c.max_clients, 128);
    cr_assert_eq(c.max_clients_per_uid, 0, "auto");
    cr_assert_eq(config_clients_per_uid(&c), 32);
    cr_assert_eq(c.client_timeout, 30);
    cr_assert_eq(c.worker_stall_timeout, 10);
    cr_assert_eq(c.max_memory, 0, "auto");
    cr_assert_geq(config_max_memory(&c), c.shm_size + CONFIG_RESULT_ROOM);
    cr_assert_eq(config_max_memory(&c) % (1u << 20), 0);
    cr_assert_eq(c.job_timeout, 600);
    cr_assert_eq(c.max_result_bytes, 4ull << 30);
    cr_assert_eq(c.chunk_size, 256u << 10);
    cr_assert_eq(c.max_input_bytes, 64ull << 20);

    /* The validator's defaults are the config's. */
    proto_limits a, b;
    proto_limits_default(&a);
    config_proto_limits(&c, &b);
    cr_assert_eq(memcmp(&a, &b, sizeof a), 0);
}

Test(config, empty_file_and_comments_give_defaults)
{
    voxd_config c, d;
    config_defaults(&d);
    load_ok("", &c);
    assert_same(&c, &d);
    load_ok("# only a comment\n\n   \t\n   # indented comment\n", &c);
    assert_same(&c, &d);
}

/* ---------------------------------------------------------------- a full file */

static const char full[] =
    "# every option, none at its default\n"
    "socket /tmp/voxd-test/sock\n"
    "socket_mode 0600\n"
    "socket_group 0\n"
    "allow_uids 0, 1000 2000\n"
    "  workers   3  \n"
    "cpus 0-2,5\n"
    "shm_size 512M\n"
    "log_file /var/log/voxd #1.log\n"
    "log_level debug\n"
    "pidfile /run/voxd.pid\r\n"
    "max_frame 2M\n"
    "max_expr_bytes 100000\n"
    "max_expr_depth 100\n"
    "max_res 2048\n"
    "max_csg_nodes 50\n"
    "max_queued_jobs 10\n"
    "max_jobs_per_uid 2\n"
    "max_clients 7\n"
    "max_clients_per_uid 3\n"
    "client_timeout 2m\n"
    "job_timeout 90s\n"
    "max_result_bytes 1G\n"
    "chunk_size 64K\n"
    "max_input_bytes 8M\n";

Test(config, full_valid_file)
{
    voxd_config c;
    load_ok(full, &c);
    cr_assert_str_eq(c.socket, "/tmp/voxd-test/sock");
    cr_assert_eq(c.socket_mode, 0600);
    cr_assert_eq(c.has_socket_group, 1);
    cr_assert_eq(c.socket_gid, 0);
    cr_assert_eq(c.n_allow_uids, 3);
    cr_assert_eq(c.allow_uids[0], 0);
    cr_assert_eq(c.allow_uids[1], 1000);
    cr_assert_eq(c.allow_uids[2], 2000);
    cr_assert_eq(c.workers, 3);
    cr_assert_eq(c.n_cpus, 4);
    cr_assert_eq(c.cpus[0], 0);
    cr_assert_eq(c.cpus[2], 2);
    cr_assert_eq(c.cpus[3], 5);
    cr_assert_eq(c.shm_size, 512ull << 20);
    cr_assert_str_eq(c.log_file, "/var/log/voxd #1.log", "'#' inside a value is kept");
    cr_assert_eq(c.log_level, LOG_LEVEL_DEBUG);
    cr_assert_str_eq(c.pidfile, "/run/voxd.pid", "CR of a CRLF line is trimmed");
    cr_assert_eq(c.max_frame, 2u << 20);
    cr_assert_eq(c.max_expr_bytes, 100000);
    cr_assert_eq(c.max_expr_depth, 100);
    cr_assert_eq(c.max_res, 2048);
    cr_assert_eq(c.max_csg_nodes, 50);
    cr_assert_eq(c.max_queued_jobs, 10);
    cr_assert_eq(c.max_jobs_per_uid, 2);
    cr_assert_eq(c.max_clients, 7);
    cr_assert_eq(c.max_clients_per_uid, 3);
    cr_assert_eq(config_clients_per_uid(&c), 3);
    cr_assert_eq(c.client_timeout, 120);
    cr_assert_eq(c.job_timeout, 90);
    cr_assert_eq(c.max_result_bytes, 1ull << 30);
    cr_assert_eq(c.chunk_size, 64u << 10);
    cr_assert_eq(c.max_input_bytes, 8u << 20);
    cr_assert_eq(config_workers(&c), 3);

    proto_limits l;
    config_proto_limits(&c, &l);
    cr_assert_eq(l.max_frame, 2u << 20);
    cr_assert_eq(l.max_expr_bytes, 100000);
    cr_assert_eq(l.max_res, 2048);
    cr_assert_eq(l.max_csg_nodes, 50);
    cr_assert_eq(l.chunk_size, 64u << 10);
    cr_assert_eq(l.max_result_bytes, 1ull << 30);
    cr_assert_eq(l.max_input_bytes, 8u << 20);
    cr_assert_eq(l.max_queued_jobs, 10);
    cr_assert_eq(l.job_timeout, 90);
}

/* Every limit of the table is an option: its key, its default, its range
 * (from the table, with the config's own words at the edges). */
Test(config, every_limit_of_the_table_is_an_option)
{
    voxd_config d;
    config_defaults(&d);
    proto_limits def, dl;
    config_proto_limits(&d, &def);
    for (size_t i = 0; i < proto_n_limits; i++) {
        const proto_limit_info *row = &proto_limit_table[i];
        cr_expect_eq(proto_limit_get(&def, i), row->def, "%s default", row->name);
        char text[128];
        err_info err = {0};
        voxd_config c;
        /* The range's edges load (alone, they may not fit with the
         * defaults of others: max_frame's lowest needs a smaller chunk). */
        const char *extra = !strcmp(row->name, "max_frame") ? "chunk_size 1K\nmax_expr_bytes 1K\n" : "";
        snprintf(text, sizeof text, "%s%s %llu\n", extra, row->name, (unsigned long long)row->min);
        load_ok(text, &c);
        config_proto_limits(&c, &dl);
        cr_expect_eq(proto_limit_get(&dl, i), row->min, "%s min", row->name);
        snprintf(text, sizeof text, "%s %llu\n", row->name, (unsigned long long)row->max);
        if (!strcmp(row->name, "chunk_size")) /* needs a frame around it */
            snprintf(text, sizeof text, "max_frame 64M\nchunk_size %llu\n",
                     (unsigned long long)row->max - 64);
        if (!strcmp(row->name, "max_expr_bytes")) /* so does a long expression */
            snprintf(text, sizeof text, "max_frame 64M\nmax_expr_bytes %llu\n",
                     (unsigned long long)row->max);
        cr_expect_eq(load_text(text, &c, &err), 0, "%s: %s", text, err.msg);
        /* One past either edge is refused with the range. */
        snprintf(text, sizeof text, "%s %llu\n", row->name, (unsigned long long)row->max + 1);
        cr_expect_eq(load_text(text, &c, &err), -EINVAL, "%s", text);
        cr_expect(strstr(err.msg, "is out of range"), "%s: %s", row->name, err.msg);
        if (row->min == 0) continue;
        snprintf(text, sizeof text, "%s %llu\n", row->name, (unsigned long long)row->min - 1);
        cr_expect_eq(load_text(text, &c, &err), -EINVAL, "%s", text);
        cr_expect(strstr(err.msg, "is out of range"), "%s: %s", row->name, err.msg);
    }
}

Test(config, print_loads_back_to_the_same_config)
{
    voxd_config c, d;
    load_ok(full, &c);
    char *text = printed(&c);
    load_ok(text, &d);
    assert_same(&c, &d);
    cr_assert(strstr(text, "cpus 0-2,5\n"), "%s", text);
    cr_assert(strstr(text, "chunk_size 64K\n"));
    cr_assert(strstr(text, "max_expr_bytes 100000\n"));
    cr_assert(strstr(text, "socket_mode 0600\n"));
    cr_assert(strstr(text, "client_timeout 120\n"), "%s", text);
    cr_assert(strstr(text, "max_input_bytes 8M\n"), "%s", text);
    cr_assert(strstr(text, "\nmax_clients_per_uid 3\n"), "%s", text);
    /* Each limit says what it bounds, from the table. */
    cr_assert(strstr(text, "# max_res: voxels along a job's longest axis\nmax_res 2048\n"), "%s",
              text);
    free(text);

    config_defaults(&c);
    text = printed(&c);
    cr_assert(strstr(text, "workers auto\n"));
    cr_assert(strstr(text, "client_timeout 30\n"), "voxd --check-config shows it: %s", text);
    cr_assert(strstr(text, "# max_clients_per_uid auto: 32 with max_clients 128\n"
                           "max_clients_per_uid auto\n"), "%s", text);
    cr_assert(strstr(text, "# log_file: not set, so stderr\n"));
    load_ok(text, &d);
    assert_same(&c, &d);
    free(text);
}

/* ---------------------------------------------------------------- units, lists */

Test(config, size_units)
{
    voxd_config c;
    load_ok("shm_size 64m\nmax_frame 4096\nchunk_size 1k\nmax_expr_bytes 2K\n", &c);
    cr_assert_eq(c.shm_size, 64ull << 20);
    cr_assert_eq(c.max_frame, 4096);
    cr_assert_eq(c.chunk_size, 1024);
    cr_assert_eq(c.max_expr_bytes, 2048);
    load_ok("shm_size 1T\nmax_result_bytes 4g\n", &c);
    cr_assert_eq(c.shm_size, 1ull << 40);
    cr_assert_eq(c.max_result_bytes, 4ull << 30);
    load_ok("shm_size 20000000\n", &c);
    cr_assert_eq(c.shm_size, 20000000);
}

Test(config, duration_units)
{
    const struct { const char *v; uint32_t s; } cases[] = {
        {"0", 0}, {"45", 45}, {"45s", 45}, {"10m", 600}, {"2h", 7200}, {"7d", 604800}};
    for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
        char text[64];
        snprintf(text, sizeof text, "job_timeout %s\n", cases[i].v);
        voxd_config c;
        load_ok(text, &c);
        cr_assert_eq(c.job_timeout, cases[i].s, "%s", cases[i].v);
    }
    voxd_config c;
    load_ok("client_timeout 1\n", &c);
    cr_assert_eq(c.client_timeout, 1);
    load_ok("client_timeout 1d\n", &c);
    cr_assert_eq(c.client_timeout, 86400);
    load_fails("client_timeout 5M\n",
               "t.conf:1: bad value '5M' for client_timeout: want a duration like 600, 10m, 2h");
}

/* max_expr_depth reaches exactly as far as the expression parser does. */
/* The liveness and memory keys: their units, auto, and every bad value. */
Test(config, stall_timeout_and_max_memory)
{
    voxd_config c;
    load_ok("worker_stall_timeout 2s\nmax_memory 8G\n", &c);
    cr_assert_eq(c.worker_stall_timeout, 2);
    cr_assert_eq(c.max_memory, 8ull << 30);
    cr_assert_eq(config_max_memory(&c), 8ull << 30);
    load_ok("worker_stall_timeout 0\nmax_memory auto\n", &c);
    cr_assert_eq(c.worker_stall_timeout, 0, "0: never");
    cr_assert_eq(c.max_memory, 0);
    load_ok("worker_stall_timeout 1h\nshm_size 16M\nmax_memory 80M\n", &c);
    cr_assert_eq(c.worker_stall_timeout, 3600);
    cr_assert_eq(config_max_memory(&c), 80ull << 20);
    /* auto is half the machine, but never below the segment and some room */
    load_ok("shm_size 1T\n", &c);
    cr_assert_geq(config_max_memory(&c), (1ull << 40) + CONFIG_RESULT_ROOM);
    char *text = printed(&c);
    cr_assert(strstr(text, "\nmax_memory auto\n") && strstr(text, "# max_memory auto: "),
              "%s", text);
    cr_assert(strstr(text, "\nworker_stall_timeout 10\n"), "%s", text);
    free(text);

    load_fails("worker_stall_timeout -1\n", "t.conf:1: bad value '-1' for "
               "worker_stall_timeout: want a duration like 600, 10m, 2h");
    load_fails("worker_stall_timeout soon\n", "t.conf:1: bad value 'soon' for "
               "worker_stall_timeout: want a duration like 600, 10m, 2h");
    load_fails("worker_stall_timeout 2G\n", "t.conf:1: bad value '2G' for "
               "worker_stall_timeout: want a duration like 600, 10m, 2h");
    load_fails("worker_stall_timeout 2h\n", "t.conf:1: worker_stall_timeout 2h is out of "
               "range (0 to 3600 seconds)");
    load_fails("worker_stall_timeout\n", "t.conf:1: 'worker_stall_timeout' needs a value");
    load_fails("max_memory lots\n",
               "t.conf:1: bad value 'lots' for max_memory: want auto or a size like 512M, 8G");
    load_fails("max_memory -1G\n",
               "t.conf:1: bad value '-1G' for max_memory: want auto or a size like 512M, 8G");
    load_fails("max_memory 10s\n",
               "t.conf:1: bad value '10s' for max_memory: want auto or a size like 512M, 8G");
    load_fails("max_memory 1M\n", "t.conf:1: max_memory 1M is out of range (64M to 1024T)");
    load_fails("max_memory 2048T\n", "t.conf:1: max_memory 2048T is out of range (64M to 1024T)");
    load_fails("max_memory 2G\n", "t.conf:1: max_memory 2G leaves no room for results beside "
               "shm_size 2G (it must be at least 64 MiB more)");
    load_fails("max_memory 1G\nshm_size 1000M\n", "t.conf:2: max_memory 1G leaves no room for "
               "results beside shm_size 1000M (it must be at least 64 MiB more)");
}

Test(config, max_expr_depth_is_the_parsers_range)
{
    voxd_config c;
    cr_assert_eq(EXPR_MAX_DEPTH_CAP, 1024);
    load_ok("max_expr_depth 1\n", &c);
    cr_assert_eq(c.max_expr_depth, 1);
    load_ok("max_expr_depth 1024\n", &c);
    cr_assert_eq(c.max_expr_depth, EXPR_MAX_DEPTH_CAP);
    load_fails("max_expr_depth 0\n", "t.conf:1: max_expr_depth 0 is out of range (1 to 1024)");
    load_fails("max_expr_depth 1025\n",
               "t.conf:1: max_expr_depth 1025 is out of range (1 to 1024)");
    /* and the parser honours the largest: 1024 levels pass, 1025 do not */
    char src[2 * 1100 + 2];
    for (int depth = 1024; depth <= 1025; depth++) {
        int n = 0;
        for (int i = 0; i < depth - 1; i++) src[n++] = '(';
        src[n++] = 'x';
        for (int i = 0; i < depth - 1; i++) src[n++] = ')';
        src[n] = '\0';
        expr_limits lim;
        expr_limits_default(&lim);
        lim.max_depth = c.max_expr_depth;
        expr_tape *t = NULL;
        expr_error ee = {0};
        int rc = expr_compile(src, (size_t)n, &lim, &t, &ee);
        cr_assert_eq(rc, depth <= 1024 ? 0 : -E2BIG, "depth %d: %d %s", depth, rc, ee.msg);
        expr_tape_free(t);
    }
}

Test(config, lists)
{
    voxd_config c;
    load_ok("cpus 7, 0-2 4\n", &c);
    int want[] = {7, 0, 1, 2, 4};
    cr_assert_eq(c.n_cpus, 5);
    for (int i = 0; i < 5; i++) cr_assert_eq(c.cpus[i], want[i]);
    load_ok("cpus 0-1023\n", &c);
    cr_assert_eq(c.n_cpus, 1024);
    cr_assert_eq(c.cpus[1023], 1023);
    load_ok("cpus auto\n", &c);
    cr_assert_eq(c.n_cpus, 0);

    load_ok("allow_uids root,4242\n", &c);
    cr_assert_eq(c.n_allow_uids, 2);
    cr_assert_eq(c.allow_uids[0], 0);
    cr_assert_eq(c.allow_uids[1], 4242);
    cr_assert(config_uid_allowed(&c, 4242));
    cr_assert(config_uid_allowed(&c, 0));
    cr_assert_not(config_uid_allowed(&c, 4243));

    load_ok("allow_uids any\n", &c);
    cr_assert(c.allow_any);
    cr_assert(config_uid_allowed(&c, 31337));

    config_defaults(&c); /* not set: our uid and root */
    cr_assert(config_uid_allowed(&c, getuid()));
    cr_assert(config_uid_allowed(&c, 0));
    cr_assert_eq(config_uid_allowed(&c, getuid() + 1), getuid() + 1 == 0);
}

Test(config, keywords)
{
    voxd_config c;
    load_ok("workers auto\nsocket_group none\nlog_level error\n", &c);
    cr_assert_eq(c.workers, 0);
    cr_assert_geq(config_workers(&c), 1);
    cr_assert_leq(config_workers(&c), CONFIG_MAX_WORKERS);
    cr_assert_eq(c.has_socket_group, 0);
    cr_assert_eq(c.log_level, LOG_LEVEL_ERROR);
    load_ok("socket_group root\n", &c);
    cr_assert_eq(c.has_socket_group, 1);
    cr_assert_eq(c.socket_gid, 0);
}

/* ---------------------------------------------------------------- errors */

Test(config, unknown_key)
{
    load_fails("max_res 100\n\nwokers 4\n", "t.conf:3: unknown key 'wokers'");
    load_fails("MAX_RES 100\n", "t.conf:1: unknown key 'MAX_RES'");
    load_fails("max_res 1 # trailing\n",
               "t.conf:1: bad value '1 # trailing' for max_res: want a whole number");
}

Test(config, missing_value)
{
    load_fails("# c\nworkers\n", "t.conf:2: 'workers' needs a value");
    load_fails("socket   \t \n", "t.conf:1: 'socket' needs a value");
}

Test(config, duplicate_key)
{
    load_fails("# one\nmax_res 100\n\nmax_clients 3\nmax_res 100\n",
               "t.conf:5: duplicate key 'max_res' (first set on line 2)");
}

Test(config, bad_values)
{
    load_fails("workers many\n", "t.conf:1: bad value 'many' for workers: want auto or 1 to 256");
    load_fails("workers -1\n", "t.conf:1: bad value '-1' for workers: want auto or 1 to 256");
    load_fails("workers 4K\n", "t.conf:1: bad value '4K' for workers: want a whole number");
    load_fails("max_res 12x\n", "t.conf:1: bad value '12x' for max_res: want a whole number");
    load_fails("max_res +5\n", "t.conf:1: bad value '+5' for max_res: want a whole number");
    load_fails("shm_size 2X\n",
               "t.conf:1: bad value '2X' for shm_size: want a size like 65536, 256K, 2G");
    load_fails("shm_size 2GB\n",
               "t.conf:1: bad value '2GB' for shm_size: want a size like 65536, 256K, 2G");
    load_fails("job_timeout 10M\n",
               "t.conf:1: bad value '10M' for job_timeout: want a duration like 600, 10m, 2h");
    load_fails("log_level loud\n",
               "t.conf:1: bad value 'loud' for log_level: want error, warn, info or debug");
    load_fails("socket_mode 0999\n",
               "t.conf:1: bad value '0999' for socket_mode: want octal permissions like 0660");
    load_fails("socket_mode rw\n",
               "t.conf:1: bad value 'rw' for socket_mode: want octal permissions like 0660");
    load_fails("cpus 3-1\n",
               "t.conf:1: bad value '3-1' in cpus: want a CPU like 3 or a range like 0-3");
    load_fails("cpus 1,x\n",
               "t.conf:1: bad value 'x' in cpus: want a CPU like 3 or a range like 0-3");
    load_fails("socket relative/voxd.sock\n",
               "t.conf:1: socket must be an absolute path, got 'relative/voxd.sock'");
    load_fails("pidfile voxd.pid\n", "t.conf:1: pidfile must be an absolute path, got 'voxd.pid'");
    load_fails("socket_group no_such_group_xyz\n",
               "t.conf:1: unknown group 'no_such_group_xyz' for socket_group");
    load_fails("allow_uids 0, no_such_user_xyz\n",
               "t.conf:1: allow_uids: unknown user 'no_such_user_xyz'");
}

Test(config, out_of_range)
{
    load_fails("max_res 0\n", "t.conf:1: max_res 0 is out of range (1 to 65536)");
    load_fails("max_res 65537\n", "t.conf:1: max_res 65537 is out of range (1 to 65536)");
    load_fails("workers 0\n", "t.conf:1: workers 0 is out of range (1 to 256)");
    load_fails("workers 257\n", "t.conf:1: workers 257 is out of range (1 to 256)");
    load_fails("max_frame 2K\n", "t.conf:1: max_frame 2K is out of range (4K to 64M)");
    load_fails("shm_size 2T\n", "t.conf:1: shm_size 2T is out of range (16M to 1T)");
    load_fails("max_result_bytes 5G\n",
               "t.conf:1: max_result_bytes 5G is out of range (64K to 4G)");
    load_fails("shm_size 99999999999999999999\n",
               "t.conf:1: shm_size 99999999999999999999 is out of range (16M to 1T)");
    load_fails("shm_size 17179869184T\n", /* overflows when multiplied */
               "t.conf:1: shm_size 17179869184T is out of range (16M to 1T)");
    load_fails("job_timeout 8d\n",
               "t.conf:1: job_timeout 8d is out of range (0 to 604800 seconds)");
    load_fails("client_timeout 0\n",
               "t.conf:1: client_timeout 0 is out of range (1 to 86400 seconds)");
    load_fails("client_timeout 2d\n",
               "t.conf:1: client_timeout 2d is out of range (1 to 86400 seconds)");
    load_fails("socket_mode 01777\n", "t.conf:1: socket_mode 01777 is out of range (0 to 0777)");
    load_fails("cpus 0,1024\n", "t.conf:1: cpus: CPU 1024 is out of range (0 to 1023)");
    load_fails("cpus 0-1023,5\n", "t.conf:1: cpus lists more than 1024 CPUs");
    load_fails("allow_uids 4294967295\n", "t.conf:1: allow_uids: uid 4294967295 is out of range");

    char text[1024] = "allow_uids";
    for (int i = 0; i < 65; i++) snprintf(text + strlen(text), 16, " %d", i);
    strcat(text, "\n");
    load_fails(text, "t.conf:1: allow_uids lists more than 64 users");

    char sock[256] = "socket /";
    memset(sock + 8, 'a', 120);
    strcpy(sock + 128, "\n");
    load_fails(sock, "t.conf:1: socket is longer than 107 bytes");
}

Test(config, options_that_do_not_fit_together)
{
    load_fails("# big chunks\nchunk_size 1M\n",
               "t.conf:2: chunk_size 1M does not fit in max_frame 1M (a chunk needs 64 bytes more)");
    load_fails("chunk_size 32K\nmax_frame 32K\n",
               "t.conf:2: chunk_size 32K does not fit in max_frame 32K (a chunk needs 64 bytes more)");
    /* An expression of max_expr_bytes must go inline or as input. */
    load_fails("max_frame 64K\nchunk_size 16K\nmax_input_bytes 4K\n",
               "t.conf:3: max_expr_bytes 64K fits neither in max_frame 64K (a request needs 256 "
               "bytes more) nor in max_input_bytes 4K");
    load_fails("max_expr_bytes 2M\nmax_input_bytes 1M\n",
               "t.conf:2: max_expr_bytes 2M fits neither in max_frame 1M (a request needs 256 "
               "bytes more) nor in max_input_bytes 1M");
    voxd_config c;
    load_ok("max_frame 64K\nchunk_size 16K\n", &c); /* as input: 64M */
    load_ok("max_expr_bytes 16M\n", &c);
    load_ok("max_frame 64K\nchunk_size 16K\nmax_expr_bytes 65280\n", &c);
    load_ok("max_frame 4K\nchunk_size 4032\nmax_expr_bytes 3840\n", &c);
}

/* max_clients_per_uid: auto follows max_clients; a number is one uid's
 * share, never over max_clients. */
Test(config, max_clients_per_uid)
{
    voxd_config c;
    load_ok("max_clients 10\n", &c);
    cr_assert_eq(config_clients_per_uid(&c), 2);
    load_ok("max_clients 3\nmax_clients_per_uid auto\n", &c);
    cr_assert_eq(config_clients_per_uid(&c), 1, "at least 1");
    load_ok("max_clients 1\n", &c);
    cr_assert_eq(config_clients_per_uid(&c), 1);
    load_ok("max_clients 5\nmax_clients_per_uid 5\n", &c);
    cr_assert_eq(config_clients_per_uid(&c), 5);
    load_ok("max_clients_per_uid 1\n", &c);
    cr_assert_eq(config_clients_per_uid(&c), 1);
    load_fails("max_clients_per_uid many\n",
               "t.conf:1: bad value 'many' for max_clients_per_uid: want auto or 1 to 65536");
    load_fails("max_clients_per_uid -1\n",
               "t.conf:1: bad value '-1' for max_clients_per_uid: want auto or 1 to 65536");
    load_fails("max_clients_per_uid 4K\n",
               "t.conf:1: bad value '4K' for max_clients_per_uid: want a whole number");
    load_fails("max_clients_per_uid 0\n",
               "t.conf:1: max_clients_per_uid 0 is out of range (1 to 65536)");
    load_fails("max_clients_per_uid 65537\n",
               "t.conf:1: max_clients_per_uid 65537 is out of range (1 to 65536)");
    load_fails("max_clients_per_uid 129\n",
               "t.conf:1: max_clients_per_uid 129 is over max_clients 128 (one uid's share of "
               "the connections; at most all of them)");
    load_fails("max_clients_per_uid 8\n# fewer\nmax_clients 4\n",
               "t.conf:3: max_clients_per_uid 8 is over max_clients 4 (one uid's share of "
               "the connections; at most all of them)");
    load_fails("max_clients_per_uid 2\nmax_clients_per_uid 3\n",
               "t.conf:2: duplicate key 'max_clients_per_uid' (first set on line 1)");
    load_fails("max_clients_per_uid\n", "t.conf:1: 'max_clients_per_uid' needs a value");
}

/* Whatever a line holds, its error quotes at most 40 bytes of it: no error
 * line is long. */
Test(config, long_values_are_cut_in_messages)
{
    static const char *const keys[] = {"max_res", "workers", "shm_size", "socket_mode",
                                       "log_level", "cpus", "allow_uids", "socket",
                                       "max_clients_per_uid", "job_timeout", "socket_group"};
    char text[3000];
    err_info err = {0};
    for (size_t k = 0; k < sizeof keys / sizeof *keys; k++) {
        for (int digits = 0; digits < 2; digits++) {
            int n = snprintf(text, sizeof text, "%s ", keys[k]);
            memset(text + n, digits ? '9' : 'x', 2000);
            strcpy(text + n + 2000, "\n");
            voxd_config c;
            cr_assert_eq(load_text(text, &c, &err), -EINVAL, "%s", keys[k]);
            cr_expect_leq(strlen(err.msg), 160, "%s: %s", keys[k], err.msg);
            cr_expect(strstr(err.msg, "...") || strstr(err.msg, "too long"), "%s", err.msg);
        }
    }
    memset(text, 'k', 2000);
    strcpy(text + 2000, " 1\n");
    voxd_config c;
    cr_assert_eq(load_text(text, &c, &err), -EINVAL);
    cr_expect_str_eq(err.msg, "t.conf:1: unknown key 'kkkkkkkkkkkkkkkkkkkkkkkkkkkkkkkkkkkkkkkk...'");
}

Test(config, line_too_long)
{
    size_t n = CONFIG_MAX_LINE + 10;
    char *text = malloc(n + 32);
    strcpy(text, "max_res 1\n# ");
    memset(text + 12, 'x', n);
    strcpy(text + 12 + n, "\n");
    load_fails(text, "t.conf:2: line is longer than 4096 bytes");
    /* Exactly at the limit is fine. */
    memset(text + 12, 'x', n);
    strcpy(text + 10 + CONFIG_MAX_LINE, "\n");
    voxd_config c;
    load_ok(text, &c);
    free(text);
}

Test(config, file_errors)
{
    voxd_config c;
    err_info err = {0};
    cr_assert_eq(config_load("/nonexistent/voxd.conf", &c, &err), -ENOENT);
    cr_assert_str_eq(err.msg, "/nonexistent/voxd.conf: No such file or directory");
    cr_assert_eq(config_load("/", &c, &err), -EISDIR);
    cr_assert_str_eq(err.msg, "/: Is a directory");

    char path[] = "/tmp/voxd-config-XXXXXX";
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    const char text[] = "max_res 8\nbogus 1\n";
    cr_assert_eq(write(fd, text, sizeof text - 1), (ssize_t)sizeof text - 1);
    close(fd);
    cr_assert_eq(config_load(path, &c, &err), -EINVAL);
    char want[600];
    snprintf(want, sizeof want, "%s:2: unknown key 'bogus'", path);
    cr_assert_str_eq(err.msg, want);
    unlink(path);
}

/* ---------------------------------------------------------------- voxd.conf */

Test(config, shipped_file_loads_to_the_defaults)
{
    char path[4096];
    err_info err = {0};
    voxd_config c, d;
    config_defaults(&d);
    int rc = config_load(root_path("config/voxd.conf", path, sizeof path), &c, &err);
    cr_assert_eq(rc, 0, "%s", err.msg);
    assert_same(&c, &d);
}

/* Every "#key value" line shows a default: uncommented, nothing changes. */
Test(config, shipped_file_documents_the_true_defaults)
{
    /* The options outside the table of limits, then every row of it. */
    static const char *const keys[] = {
        "socket", "socket_mode", "socket_group", "allow_uids", "workers", "cpus",
        "shm_size", "log_file", "log_level", "pidfile", "max_clients", "max_clients_per_uid",
        "client_timeout", "worker_stall_timeout", "max_memory",
#define KEY(name, type, def, min, max, unit, doc) #name,
        VOX_LIMITS(KEY)
#undef KEY
    };
    char path[4096];
    FILE *f = fopen(root_path("config/voxd.conf", path, sizeof path), "r");
    cr_assert_not_null(f);
    char *text = NULL;
    size_t tn = 0;
    FILE *out = open_memstream(&text, &tn);
    char line[8192];
    int uncommented = 0;
    size_t nkeys = sizeof keys / sizeof *keys;
    int documented[sizeof keys / sizeof *keys] = {0};
    while (fgets(line, sizeof line, f)) {
        for (size_t k = 0; k < nkeys; k++) {
            size_t kl = strlen(keys[k]);
            /* "# key ..." heading, or "#key default" */
            const char *p = line + 1 + (line[1] == ' ');
            if (line[0] == '#' && strncmp(p, keys[k], kl) == 0 && p[kl] == ' ')
                documented[k] = 1;
        }
        if (line[0] == '#' && line[1] >= 'a' && line[1] <= 'z') {
            fputs(line + 1, out);
            uncommented++;
        } else {
            fputs(line, out);
        }
    }
    fclose(f);
    fclose(out);
    for (size_t k = 0; k < nkeys; k++)
        cr_assert(documented[k], "option %s is not documented in voxd.conf", keys[k]);
    cr_assert_geq(uncommented, 18, "only %d defaults shown", uncommented);

    voxd_config c, d;
    config_defaults(&d);
    load_ok(text, &c);
    assert_same(&c, &d);
    free(text);
}

/* ---------------------------------------------------------------- log */

static char *slurp(const char *path)
{
    FILE *f = fopen(path, "r");
    cr_assert_not_null(f);
    static char buf[8192];
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    buf[n] = '\0';
    fclose(f);
    return buf;
}

Test(log, lines_levels_and_reopen)
{
    char path[] = "/tmp/voxd-log-XXXXXX";
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    close(fd);
    cr_assert_eq(log_open(path, "voxd-test", LOG_LEVEL_INFO), 0);
    log_info("hello %d", 42);
    log_debug("not written at info");
    log_error("two\nlines\x1b[0m");
    char *s = slurp(path);
    char want[64];
    snprintf(want, sizeof want, "Z voxd-test[%ld] info: hello 42\n", (long)getpid());
    cr_assert(strstr(s, want), "log is:\n%s", s);
    cr_assert_null(strstr(s, "not written"));
    cr_assert(strstr(s, " error: two?lines?[0m\n"), "control characters escaped:\n%s", s);
    cr_assert_eq(s[4], '-');
    cr_assert_eq(s[10], 'T');

    /* logrotate: move the file, reopen, new lines go to the new file. */
    char moved[64];
    snprintf(moved, sizeof moved, "%s.1", path);
    cr_assert_eq(rename(path, moved), 0);
    cr_assert_eq(log_reopen(), 0);
    log_set_level(LOG_LEVEL_DEBUG);
    cr_assert_eq(log_get_level(), LOG_LEVEL_DEBUG);
    log_debug("after %s", "reopen");
    cr_assert(strstr(slurp(path), "debug: after reopen\n"));
    cr_assert_null(strstr(slurp(moved), "after reopen"));

    /* A long message is cut, still one line. */
    char big[5000];
    memset(big, 'm', sizeof big - 1);
    big[sizeof big - 1] = '\0';
    log_warn("%s", big);
    s = slurp(path);
    char *w = strstr(s, "warn: ");
    cr_assert_not_null(w);
    char *nl = strchr(w, '\n');
    cr_assert_not_null(nl);
    cr_assert_lt(nl - s, LOG_MAX_LINE * 2);
    log_close();
    unlink(path);
    unlink(moved);
}

Test(log, level_names)
{
    cr_assert_eq(log_level_parse("error"), LOG_LEVEL_ERROR);
    cr_assert_eq(log_level_parse("warn"), LOG_LEVEL_WARN);
    cr_assert_eq(log_level_parse("info"), LOG_LEVEL_INFO);
    cr_assert_eq(log_level_parse("debug"), LOG_LEVEL_DEBUG);
    cr_assert_eq(log_level_parse("INFO"), -1);
    cr_assert_str_eq(log_level_name(LOG_LEVEL_WARN), "warn");
    cr_assert_eq(log_open("/nonexistent/dir/voxd.log", "x", LOG_LEVEL_INFO), -ENOENT);
    cr_assert_eq(log_reopen(), 0, "stderr needs no reopening");
}

/* ---------------------------------------------------------------- MPI */

Test(config, mpi_keys)
{
    voxd_config c, d;
    config_defaults(&c);
    cr_assert_str_empty(c.mpi_hostfile, "off unless set");
    cr_assert_eq(c.mpi_min_res, 1024);
    cr_assert_str_eq(c.mpirun_args, CONFIG_MPIRUN_ARGS);
    load_ok("mpi_hostfile /etc/voxd/hosts\nmpi_min_res 512\nmpi_ranks 4\nmpi_workers 0\n"
            "mpirun /opt/ompi/bin/mpirun\nmpirun_args none\nvox_mpi /opt/vox/vox_mpi\n",
            &c);
    cr_assert_str_eq(c.mpi_hostfile, "/etc/voxd/hosts");
    cr_assert_eq(c.mpi_min_res, 512);
    cr_assert_eq(c.mpi_ranks, 4);
    cr_assert_eq(c.mpi_workers, 0);
    cr_assert_str_eq(c.mpirun, "/opt/ompi/bin/mpirun");
    cr_assert_str_empty(c.mpirun_args);
    cr_assert_str_eq(c.vox_mpi, "/opt/vox/vox_mpi");
    char *text = printed(&c);
    cr_assert(strstr(text, "\nmpirun_args none\n"), "%s", text);
    load_ok(text, &d);
    assert_same(&c, &d);
    free(text);
    load_ok("mpirun_args --mca btl self,tcp --bind-to none\n", &c);
    cr_assert_str_eq(c.mpirun_args, "--mca btl self,tcp --bind-to none");
    load_fails("mpi_hostfile hosts\n", "t.conf:1: mpi_hostfile must be an absolute path, got 'hosts'");
    load_fails("mpi_ranks 0\n", "t.conf:1: mpi_ranks 0 is out of range (1 to 4096)");
    load_fails("mpi_workers 257\n", "t.conf:1: mpi_workers 257 is out of range (0 to 256)");
    load_fails("mpirun_args --mca\x01\n", "t.conf:1: mpirun_args contains a control character");
}

/* The connection limits at both ends of their ranges: 1 and 65536 taken,
 * 0 and 65537 refused with the range (a daemon with max_clients 0 would
 * refuse everyone). */
Test(config, connection_limits_at_their_ends)
{
    static const char *const keys[] = {"max_clients", "max_clients_per_uid"};
    for (size_t i = 0; i < 2; i++) {
        char text[128], want[160];
        voxd_config c;
        config_defaults(&c);
        /* max_clients_per_uid may not exceed max_clients: give both */
        const char *room = i ? "max_clients 65536\n" : "";
        snprintf(text, sizeof text, "%s%s 1\n", room, keys[i]);
        load_ok(text, &c);
        cr_assert_eq(i ? c.max_clients_per_uid : c.max_clients, 1u, "%s", text);
        snprintf(text, sizeof text, "%s%s 65536\n", room, keys[i]);
        load_ok(text, &c);
        cr_assert_eq(i ? c.max_clients_per_uid : c.max_clients, 65536u, "%s", text);
        snprintf(text, sizeof text, "%s 0\n", keys[i]);
        snprintf(want, sizeof want, "t.conf:1: %s 0 is out of range (1 to 65536)", keys[i]);
        load_fails(text, want);
        snprintf(text, sizeof text, "%s 65537\n", keys[i]);
        snprintf(want, sizeof want, "t.conf:1: %s 65537 is out of range (1 to 65536)", keys[i]);
        load_fails(text, want);
    }
}
