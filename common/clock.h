/* clock — the time the project measures with. */
#ifndef VOXD_CLOCK_H
#define VOXD_CLOCK_H

/* Seconds on the monotonic clock (intervals, timeouts, timings). */
double clock_now(void);
/* CPU seconds the calling thread has used. */
double clock_thread_cpu(void);

#endif
