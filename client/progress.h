/* progress — the one-line progress display of long jobs on a terminal. */
#ifndef VOXD_PROGRESS_H
#define VOXD_PROGRESS_H

#include <stdint.h>

typedef struct {
    int enabled;     /* stderr is a terminal, or --progress */
    int shown;       /* a line is on the screen */
    double start, last;
} progress;

/* force: show even when stderr is not a terminal. */
void progress_init(progress *p, int force);
/* Redraw (at most 10 times a second): "level L, NN.N%, V voxels, R Mvoxels/s". */
void progress_update(progress *p, double fraction, int level, uint64_t voxels);
/* End the line, if one was drawn. */
void progress_done(progress *p);

#endif
