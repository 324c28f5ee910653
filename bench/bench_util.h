/* bench_util — what the benchmark programs share: a monotonic clock,
 * order statistics over their repeated runs, and /proc's stat files. */
#ifndef VOXD_BENCH_UTIL_H
#define VOXD_BENCH_UTIL_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static inline double now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static inline int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Nearest rank: the smallest value with at least p of the values <= it
 * (sorts v). */
static inline double percentile(double *v, int n, double p)
{
    qsort(v, (size_t)n, sizeof *v, cmp_double);
    int i = (int)ceil(p * n) - 1;
    return v[i < 0 ? 0 : i >= n ? n - 1 : i];
}

/* The middle value (the upper one of an even count; sorts v). */
static inline double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, cmp_double);
    return v[n / 2];
}

/* The fields of a /proc stat file (/proc/PID/stat, /proc/PID/task/TID/stat)
 * after the command's name, which ends at the last ')' (a name may hold
 * spaces and parentheses); the file is read into buf.  NULL when it cannot
 * be read (the process or thread is gone). */
static inline const char *proc_stat_fields(const char *path, char *buf, size_t len)
{
    FILE *f = fopen(path, "r");
    if (!f) return NULL;
    size_t n = fread(buf, 1, len - 1, f);
    fclose(f);
    buf[n] = '\0';
    const char *p = strrchr(buf, ')');
    return p ? p + 1 : NULL;
}

#endif
