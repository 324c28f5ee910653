/* Zeroing a range: see zero.h. */
#include "zero.h"

#include <stdint.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

void zero_range(void *p, size_t n)
{
    uintptr_t page = (uintptr_t)sysconf(_SC_PAGESIZE);
    uintptr_t lo = ((uintptr_t)p + page - 1) & ~(page - 1), hi = ((uintptr_t)p + n) & ~(page - 1);
    if (n < ZERO_PUNCH_MIN || hi <= lo) {
        memset(p, 0, n);
        return;
    }
    /* A private or anonymous mapping refuses the punch (EINVAL, EACCES),
     * as does a locked one or a huge page's partial range: memset then. */
    if (madvise((void *)lo, hi - lo, MADV_REMOVE)) memset((void *)lo, 0, hi - lo);
    memset(p, 0, lo - (uintptr_t)p);
    memset((void *)hi, 0, (uintptr_t)p + n - hi);
}
