#include "progress.h"

#include <stdio.h>
#include <time.h>
#include <unistd.h>

static double monotonic(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

void progress_init(progress *p, int force)
{
    p->enabled = force || isatty(STDERR_FILENO);
    p->shown = 0;
    p->start = monotonic();
    p->last = 0;
}

void progress_update(progress *p, double fraction, int level, uint64_t voxels)
{
    if (!p->enabled) return;
    double t = monotonic();
    if (p->shown && t - p->last < 0.1) return;
    p->last = t;
    p->shown = 1;
    double el = t - p->start;
    fprintf(stderr, "\r  level %2d  %5.1f%%  %11llu voxels  %7.2f Mvoxels/s  %6.1f s ",
            level, fraction * 100.0, (unsigned long long)voxels,
            el > 0 ? voxels / el / 1e6 : 0.0, el);
    fflush(stderr);
}

void progress_done(progress *p)
{
    if (p->enabled && p->shown) fputc('\n', stderr);
    p->shown = 0;
}
