/* thread_name — the calling thread's name as others see it from outside
 * (/proc/PID/task/TID/comm: top -H, bench/voxserial -w), so that a serial
 * stretch of a command says which of its stages or threads it was: "vox
 * NAME", the program's own name first, cut to the 15 bytes the kernel
 * keeps.  Off unless the program turns it on (vox does; the daemon and
 * the libraries' callers keep their threads' names). */
#ifndef VOXD_THREAD_NAME_H
#define VOXD_THREAD_NAME_H

/* Turns the names on, before any thread or process is made: those made
 * after see it (pthread_create and fork order it before them). */
void thread_name_enable(void);

/* Names the calling thread "PROGRAM WHAT" when the names are on. */
void thread_name(const char *what);

#endif
