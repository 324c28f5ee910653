/* heap: see heap.h. */
#include "heap.h"

#include <malloc.h>
#include <stdlib.h>

#define HEAP_MMAP_BYTES (32 << 20) /* glibc's largest mmap threshold */
#define HEAP_TRIM_BYTES (1L << 30)
/* A free this large makes glibc try to trim its arena's top. */
#define HEAP_TRIM_FREE (128 << 10)

void heap_keep(void)
{
#ifdef M_TRIM_THRESHOLD
    mallopt(M_ARENA_MAX, 1);
    mallopt(M_MMAP_THRESHOLD, HEAP_MMAP_BYTES);
    mallopt(M_TRIM_THRESHOLD, HEAP_TRIM_BYTES);
#endif
}

/* malloc_trim gives back the free blocks inside every arena, but the free
 * top only of the main arena's heap.  A thread other than the process's
 * first may allocate in an arena of its own (and so does a process forked
 * from such a thread: voxd's workers, forked by its engine thread, kept
 * 57 MiB after the dragon's distance at 512^3 before heap_keep gave voxd
 * one arena), whose top glibc trims only at a free of 64 KiB or more with
 * the top above the trim threshold: so the threshold is 0 for one such
 * free (through a volatile pointer: the compiler drops a free of a malloc
 * it can see). */
void heap_give_back(void)
{
#ifdef M_TRIM_THRESHOLD
    malloc_trim(0);
    mallopt(M_TRIM_THRESHOLD, 0);
    void *volatile probe = malloc(HEAP_TRIM_FREE);
    free(probe);
    mallopt(M_TRIM_THRESHOLD, HEAP_TRIM_BYTES);
#endif
}
