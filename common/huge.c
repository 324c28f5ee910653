/* huge: see huge.h. */
#include "huge.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#define HUGE_PAGE ((uintptr_t)2 << 20)

void huge_advise(void *p, size_t n)
{
#ifdef MADV_HUGEPAGE
    /* the whole huge pages inside the block: the advice is a hint, its
     * failure (no THP in this kernel) changes nothing */
    uintptr_t a = ((uintptr_t)p + HUGE_PAGE - 1) & ~(HUGE_PAGE - 1);
    uintptr_t e = ((uintptr_t)p + n) & ~(HUGE_PAGE - 1);
    if (e > a) madvise((void *)a, e - a, MADV_HUGEPAGE);
#else
    (void)p, (void)n;
#endif
}

void *huge_malloc(size_t n)
{
    void *p = malloc(n);
    if (p) huge_advise(p, n);
    return p;
}

void *huge_calloc(size_t n, size_t size)
{
    if (size && n > SIZE_MAX / size) return NULL;
    void *p = huge_malloc(n * size);
    if (p) memset(p, 0, n * size);
    return p;
}
