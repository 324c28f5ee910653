/* heap: see heap.h. */
#include "heap.h"

#include <malloc.h>

#define HEAP_MMAP_BYTES (32 << 20) /* glibc's largest mmap threshold */
#define HEAP_TRIM_BYTES (1L << 30)

void heap_keep(void)
{
#ifdef M_TRIM_THRESHOLD
    mallopt(M_ARENA_MAX, 1);
    mallopt(M_MMAP_THRESHOLD, HEAP_MMAP_BYTES);
    mallopt(M_TRIM_THRESHOLD, HEAP_TRIM_BYTES);
#endif
}

/* malloc_trim gives back the free blocks of every arena, but the free top
 * of the main arena's heap alone: what a thread with an arena of its own
 * freed at its top stays (voxd forked its workers from its engine thread,
 * and they kept 57 MiB after the dragon's distance at 512^3).  heap_keep's
 * one arena puts every thread's top there. */
void heap_give_back(void)
{
#ifdef M_TRIM_THRESHOLD
    malloc_trim(0);
#endif
}
