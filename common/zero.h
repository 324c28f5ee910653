/* zero — a range of memory set to zero, without touching the pages of a
 * shared memory segment that nobody needs yet. */
#ifndef VOXD_ZERO_H
#define VOXD_ZERO_H

#include <stddef.h>

/* Zeroes [p, p + n).  In a shared mapping of a file that can punch holes
 * (the engine's POSIX shm segment, tmpfs) the whole pages inside the range
 * are punched out (MADV_REMOVE) instead of written: a page never touched
 * costs nothing, a dirty one is freed, and the page's first touch (the
 * kernel's fault and clear) happens later, in whichever process writes it
 * first: the engine's workers, in parallel, rather than the master before
 * them.  Anywhere else (a private mapping, the heap), or for a range of
 * less than ZERO_PUNCH_MIN bytes, a plain memset. */
#define ZERO_PUNCH_MIN (256u << 10)
void zero_range(void *p, size_t n);

#endif
