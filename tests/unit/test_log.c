/* The log's rate limit: the token bucket on a simulated clock (burst, then
 * one line a second, the held-back lines counted), and the lines it writes
 * to a real log file (the summary, its level, lines below the log level). */
#include <criterion/criterion.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "clock.h"
#include "log.h"

Test(log_limit, burst_then_one_a_second)
{
    log_limit l = LOG_LIMIT_INIT("test");
    double t = 1000;
    for (int i = 0; i < LOG_LIMIT_BURST; i++)
        cr_expect_eq(log_limit_take(&l, t, LOG_LEVEL_INFO), 1, "line %d of the burst", i);
    cr_expect_eq(log_limit_take(&l, t, LOG_LEVEL_INFO), 0);
    cr_expect_eq(log_limit_take(&l, t + 0.5, LOG_LEVEL_WARN), 0);
    cr_expect_eq(l.suppressed, 2);
    cr_expect_eq(l.level, LOG_LEVEL_WARN, "the most severe held back");
    cr_expect_eq(log_limit_take(&l, t + 1.01, LOG_LEVEL_INFO), 1);
    cr_expect_eq(log_limit_take(&l, t + 1.02, LOG_LEVEL_INFO), 0);
    /* a quiet while refills the burst, no more */
    t += 3600;
    int n = 0;
    for (int i = 0; i < 100; i++) n += log_limit_take(&l, t, LOG_LEVEL_INFO);
    cr_expect_eq(n, LOG_LIMIT_BURST);
}

Test(log_limit, a_flood_is_a_few_lines)
{
    /* 2,000 events spread over 10 s: the burst, then about one a second */
    log_limit l = LOG_LIMIT_INIT("test");
    int n = 0;
    for (int i = 0; i < 2000; i++) n += log_limit_take(&l, 50 + i * 0.005, LOG_LEVEL_INFO);
    cr_expect_geq(n, LOG_LIMIT_BURST + 9);
    cr_expect_leq(n, LOG_LIMIT_BURST + 11);
    cr_expect_eq(l.suppressed + (unsigned long)n, 2000);
}

static int count_lines(const char *path, const char *needle)
{
    FILE *f = fopen(path, "r");
    cr_assert_not_null(f);
    char line[4096];
    int n = 0;
    while (fgets(line, sizeof line, f)) n += !needle || strstr(line, needle) != NULL;
    fclose(f);
    return n;
}

Test(log_limit, the_summary_line)
{
    char path[] = "/tmp/test_log_XXXXXX";
    int fd = mkstemp(path);
    cr_assert_geq(fd, 0);
    close(fd);
    cr_assert_eq(log_open(path, "test", LOG_LEVEL_INFO), 0);
    log_limit l = LOG_LIMIT_INIT("refused connections: test");
    for (int i = 0; i < 100; i++) log_limited(&l, LOG_LEVEL_INFO, "refused connection %d", i);
    /* below the log level: neither written nor counted */
    for (int i = 0; i < 10; i++) log_limited(&l, LOG_LEVEL_DEBUG, "a debug line");
    log_limited(&l, LOG_LEVEL_WARN, "a warning held back");
    cr_expect_eq(count_lines(path, NULL), LOG_LIMIT_BURST);
    cr_expect_eq(l.suppressed, 100 - LOG_LIMIT_BURST + 1);
    /* no token yet: the flush waits */
    log_limit_flush(&l, clock_now());
    cr_expect_eq(count_lines(path, NULL), LOG_LIMIT_BURST);
    log_limit_flush(&l, clock_now() + 2);
    cr_expect_eq(count_lines(path, NULL), LOG_LIMIT_BURST + 1);
    cr_expect_eq(count_lines(path, "warn: 96 similar messages suppressed "
                                   "(refused connections: test)"), 1);
    cr_expect_eq(l.suppressed, 0);
    log_limit_flush(&l, clock_now() + 4); /* nothing held back: nothing written */
    cr_expect_eq(count_lines(path, NULL), LOG_LIMIT_BURST + 1);
    /* the next line let through carries the summary before it */
    l.tokens = 0;
    l.t = clock_now();
    log_limited(&l, LOG_LEVEL_INFO, "held");
    l.tokens = 1;
    log_limited(&l, LOG_LEVEL_INFO, "let through");
    cr_expect_eq(count_lines(path, "info: 1 similar message suppressed"), 1);
    cr_expect_eq(count_lines(path, "info: let through"), 1);
    cr_expect_eq(count_lines(path, "held"), 0);
    log_close();
    unlink(path);
}
