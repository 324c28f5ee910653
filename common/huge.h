/* huge — a large array whose pages are the kernel's huge pages (2 MiB)
 * where it spans them (MADV_HUGEPAGE; where the kernel has them): one page
 * fault where there were 512.  A fault costs about 5 us on this project's
 * virtual machines, as much as writing 20 KiB, so an array written once
 * soon after its allocation (a mesh's, a loader's or a binning's) costs
 * its faults as much as its writes. */
#ifndef VOXD_HUGE_H
#define VOXD_HUGE_H

#include <stddef.h>

/* malloc(n) (free() frees it), advised to be backed by huge pages; NULL
 * when there is no memory. */
void *huge_malloc(size_t n);
/* huge_malloc of n items of size bytes, zeroed; NULL when there is no
 * memory or n * size overflows. */
void *huge_calloc(size_t n, size_t size);
/* The same advice for a block already allocated, [p, p + n) (after a
 * realloc, say). */
void huge_advise(void *p, size_t n);

#endif
