/* clock — the time the project measures with. */
#ifndef VOXD_CLOCK_H
#define VOXD_CLOCK_H

/* Seconds on the monotonic clock (intervals, timeouts, timings). */
double clock_now(void);

#endif
