/* zero_range: every byte of the range zero and not one byte beside it
 * changed, in a shared memory mapping (the engine's segment: the pages
 * punched out) and in private memory (memset); mincore, the kernel's own
 * record of which pages are in memory, says the punch touched no page. */
#include <criterion/criterion.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "zero.h"

#define PAGES 256

static size_t page_size(void)
{
    return (size_t)sysconf(_SC_PAGESIZE);
}

/* A shared mapping of a fresh memfd (tmpfs, as /dev/shm), PAGES pages. */
static uint8_t *shared_map(size_t *bytes)
{
    *bytes = PAGES * page_size();
    int fd = memfd_create("test_zero", 0);
    cr_assert_geq(fd, 0);
    cr_assert_eq(ftruncate(fd, (off_t)*bytes), 0);
    void *p = mmap(NULL, *bytes, PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
    close(fd);
    cr_assert_neq(p, MAP_FAILED);
    return p;
}

static unsigned resident(uint8_t *p, size_t bytes)
{
    unsigned char vec[PAGES];
    cr_assert_eq(mincore(p, bytes, vec), 0);
    unsigned n = 0;
    for (size_t i = 0; i < bytes / page_size(); i++) n += vec[i] & 1;
    return n;
}

/* [lo, hi) zero, the rest 0xA5. */
static void expect_zeroed(const uint8_t *p, size_t bytes, size_t lo, size_t hi)
{
    for (size_t i = 0; i < bytes; i++)
        cr_assert_eq(p[i], i >= lo && i < hi ? 0 : 0xA5, "byte %zu of %zu (range %zu-%zu)", i,
                     bytes, lo, hi);
}

Test(zero, a_dirty_shared_range_is_zero_to_the_byte_and_its_pages_freed)
{
    size_t bytes, lo = 100, hi;
    uint8_t *p = shared_map(&bytes);
    hi = bytes - 4000;
    memset(p, 0xA5, bytes);
    cr_assert_eq(resident(p, bytes), PAGES);
    zero_range(p + lo, hi - lo);
    expect_zeroed(p, bytes, lo, hi); /* reading faults zero pages back in */
    munmap(p, bytes);
}

Test(zero, a_dirty_shared_range_leaves_its_inner_pages_out_of_memory)
{
    size_t bytes, lo = 100, hi;
    uint8_t *p = shared_map(&bytes);
    hi = bytes - 4000;
    memset(p, 0xA5, bytes);
    zero_range(p + lo, hi - lo);
    /* the first and last pages are partly outside the range: written */
    cr_assert_eq(resident(p, bytes), 2, "pages in memory after the punch");
    munmap(p, bytes);
}

Test(zero, an_untouched_shared_range_stays_untouched)
{
    size_t bytes;
    uint8_t *p = shared_map(&bytes);
    zero_range(p, bytes);
    cr_assert_eq(resident(p, bytes), 0);
    munmap(p, bytes);
}

Test(zero, private_memory_and_small_ranges_are_zero_to_the_byte)
{
    size_t bytes = PAGES * page_size();
    uint8_t *p = malloc(bytes);
    cr_assert_not_null(p);
    size_t cases[][2] = {{0, bytes}, {1, bytes - 1}, {4096, 4096 + 100}, {0, 0}, {77, 77 + (300u << 10)}};
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
        memset(p, 0xA5, bytes);
        zero_range(p + cases[c][0], cases[c][1] - cases[c][0]);
        expect_zeroed(p, bytes, cases[c][0], cases[c][1]);
    }
    free(p);
    size_t sbytes;
    uint8_t *s = shared_map(&sbytes);
    memset(s, 0xA5, sbytes);
    zero_range(s + 10, 5000); /* under ZERO_PUNCH_MIN: memset */
    expect_zeroed(s, sbytes, 10, 5010);
    munmap(s, sbytes);
}
