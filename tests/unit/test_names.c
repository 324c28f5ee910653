/* Thread names (common/thread_name) and the flushes behind a file's
 * writers (common/syncbehind), seen from outside as /proc shows them: a
 * name changes only once the names are on, as "PROGRAM WHAT" cut to the
 * kernel's 15 bytes; the sync thread is there (by its name) from
 * syncbehind_start to syncbehind_stop and gone after, leaves the file's
 * bytes as written, and stops at once on a pipe or on a closed fd. */
#include <criterion/criterion.h>
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "clock.h"
#include "syncbehind.h"
#include "thread_name.h"

#include "tmpdir_fixture.h"

static void my_name(char *out, size_t len)
{
    char path[64];
    snprintf(path, sizeof path, "/proc/self/task/%d/comm", gettid());
    FILE *f = fopen(path, "r");
    cr_assert_not_null(f);
    cr_assert_not_null(fgets(out, (int)len, f));
    fclose(f);
    out[strcspn(out, "\n")] = '\0';
}

/* The name thread_name(what) gives (the program's name: Criterion's
 * worker may have its own). */
static void name_of(const char *what, char out[16])
{
    snprintf(out, 16, "%s %s", program_invocation_short_name, what);
}

/* How many threads of this process are called name. */
static int threads_named(const char *name)
{
    DIR *d = opendir("/proc/self/task");
    cr_assert_not_null(d);
    struct dirent *e;
    int n = 0;
    while ((e = readdir(d))) {
        if (e->d_name[0] == '.') continue;
        char path[300], comm[32] = "";
        snprintf(path, sizeof path, "/proc/self/task/%s/comm", e->d_name);
        FILE *f = fopen(path, "r");
        if (!f) continue;
        if (fgets(comm, sizeof comm, f)) comm[strcspn(comm, "\n")] = '\0';
        fclose(f);
        n += !strcmp(comm, name);
    }
    closedir(d);
    return n;
}

Test(thread_name, off_until_enabled)
{
    char before[32], after[32];
    my_name(before, sizeof before);
    thread_name("stage");
    my_name(after, sizeof after);
    cr_assert_str_eq(after, before, "named without thread_name_enable");
}

Test(thread_name, the_program_then_the_stage_cut_to_15_bytes)
{
    thread_name_enable();
    char got[32], want[16];
    thread_name("main");
    my_name(got, sizeof got);
    name_of("main", want);
    cr_assert_str_eq(got, want);
    thread_name("a stage with a long name");
    my_name(got, sizeof got);
    cr_assert_eq(strlen(got), 15, "'%s': cut to 15 bytes", got);
}

static void write_all(int fd, const char *p, size_t n)
{
    while (n) {
        ssize_t k = write(fd, p, n);
        cr_assert_gt(k, 0);
        p += k, n -= (size_t)k;
    }
}

Test(syncbehind, there_while_started_and_the_bytes_as_written)
{
    tmpdir_make("syncbehind");
    thread_name_enable();
    char path[128];
    snprintf(path, sizeof path, "%s/f", dir);
    int fd = open(path, O_RDWR | O_CREAT | O_TRUNC, 0600);
    cr_assert_geq(fd, 0);
    char sync_name[16];
    name_of("sync", sync_name);
    int others = threads_named(sync_name);
    syncbehind s;
    syncbehind_start(&s, fd);
    cr_assert(s.started);
    /* it names itself first thing: a moment after its start */
    for (int i = 0; i < 200 && threads_named(sync_name) == others; i++) {
        struct timespec ts = {0, 5000000L};
        nanosleep(&ts, NULL);
    }
    cr_assert_eq(threads_named(sync_name), others + 1, "'%s' started", sync_name);
    size_t part = 3u << 20; /* over SYNCBEHIND_BYTES each */
    char *buf = malloc(part);
    cr_assert_not_null(buf);
    for (int i = 0; i < 3; i++) {
        memset(buf, 'a' + i, part);
        write_all(fd, buf, part);
        struct timespec ts = {0, 4 * SYNCBEHIND_PERIOD_MS * 1000000L};
        nanosleep(&ts, NULL);
    }
    /* the file grew past SYNCBEHIND_BYTES: flushed while open (a loaded
     * machine may run the thread late: up to 10 s) */
    for (int i = 0; i < 2000 && !atomic_load_explicit(&s.flushes, memory_order_relaxed); i++) {
        struct timespec ts = {0, 5000000L};
        nanosleep(&ts, NULL);
    }
    cr_assert_geq(atomic_load_explicit(&s.flushes, memory_order_relaxed), 1, "no fdatasync");
    syncbehind_stop(&s);
    cr_assert_not(s.started);
    cr_assert_eq(threads_named(sync_name), others, "joined");
    syncbehind_stop(&s); /* stopped already: nothing */
    for (int i = 0; i < 3; i++) {
        cr_assert_eq(pread(fd, buf, part, (off_t)i * (off_t)part), (ssize_t)part);
        for (size_t k = 0; k < part; k += 4099)
            cr_assert_eq(buf[k], 'a' + i, "byte %zu of part %d", k, i);
    }
    free(buf);
    close(fd);
    tmpdir_remove();
}

/* A pipe never grows (its size is 0: never flushed); a closed fd ends the
 * thread at its first look.  Either way the stop is at once. */
Test(syncbehind, a_pipe_or_a_closed_fd_stops_at_once)
{
    int p[2];
    cr_assert_eq(pipe(p), 0);
    syncbehind s;
    syncbehind_start(&s, p[1]);
    char buf[4096] = {0};
    for (int i = 0; i < 8; i++) cr_assert_eq(write(p[1], buf, sizeof buf), (ssize_t)sizeof buf);
    double t0 = clock_now();
    syncbehind_stop(&s);
    cr_assert_lt(clock_now() - t0, 0.5);
    cr_assert_eq(atomic_load_explicit(&s.flushes, memory_order_relaxed), 0, "a pipe flushed");
    close(p[0]), close(p[1]);

    syncbehind_start(&s, p[0]); /* closed now */
    struct timespec ts = {0, 3 * SYNCBEHIND_PERIOD_MS * 1000000L};
    nanosleep(&ts, NULL);
    t0 = clock_now();
    syncbehind_stop(&s);
    cr_assert_lt(clock_now() - t0, 0.5);
}
