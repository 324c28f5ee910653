#include "prefault.h"

#include <stdint.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "par.h"

#ifndef MADV_POPULATE_WRITE
#define MADV_POPULATE_WRITE 23 /* Linux 5.14; older headers lack it */
#endif

void prefault_write(void *p, size_t n)
{
    long page = sysconf(_SC_PAGESIZE);
    if (page <= 0) return;
    /* every page the range touches: the call maps pages, it writes
     * nothing, so a page shared with other data is left as it was */
    uintptr_t a = (uintptr_t)p & ~((uintptr_t)page - 1);
    if (n) (void)madvise((void *)a, (uintptr_t)p + n - a, MADV_POPULATE_WRITE);
}

void prefault_copy(void *to, const void *src, size_t n)
{
    prefault_write(to, n);
    if (n) memcpy(to, src, n);
}

typedef struct {
    const prefault_span *spans;
    int count;
} span_set;

static void copy_part(void *ud, unsigned k, unsigned parts)
{
    const span_set *set = ud;
    for (int i = 0; i < set->count; i++) {
        const prefault_span *s = &set->spans[i];
        size_t lo = s->bytes * k / parts, hi = s->bytes * (k + 1) / parts;
        prefault_copy((uint8_t *)s->to + lo, (const uint8_t *)s->from + lo, hi - lo);
    }
}

void prefault_copy_par(const prefault_span *spans, int count, unsigned threads)
{
    span_set set = {spans, count};
    par_run(threads, copy_part, &set);
}
