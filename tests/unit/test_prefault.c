/* prefault: copies into fresh memory, whole and alone, by one thread or
 * by several in parts (prefault_copy_par), against the bytes the test
 * wrote and guard bytes around each copy that no part may touch. */
#include <criterion/criterion.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "prefault.h"

#define GUARD 64

/* Fresh pages (as the engine's segment's are) for n bytes between guards. */
static uint8_t *fresh(size_t n)
{
    void *p = mmap(NULL, n + 2 * GUARD, PROT_READ | PROT_WRITE, MAP_SHARED | MAP_ANONYMOUS, -1, 0);
    cr_assert_neq(p, MAP_FAILED);
    memset(p, 0xA5, n + 2 * GUARD);
    return (uint8_t *)p + GUARD;
}

static uint8_t *pattern(size_t n, unsigned seed)
{
    uint8_t *p = malloc(n ? n : 1);
    cr_assert(p);
    for (size_t i = 0; i < n; i++) p[i] = (uint8_t)(i * 131u + seed * 7u + (i >> 9));
    return p;
}

static void assert_copied(const uint8_t *to, const uint8_t *from, size_t n, const char *what)
{
    cr_assert(!memcmp(to, from, n), "%s: the copy differs", what);
    for (int g = 1; g <= GUARD; g++) {
        cr_assert_eq(to[-g], 0xA5, "%s: %d bytes before the copy written", what, g);
        cr_assert_eq(to[n + (size_t)g - 1], 0xA5, "%s: %d bytes after the copy written", what, g);
    }
}

Test(prefault, one_copy_is_the_bytes_and_nothing_around_them)
{
    size_t sizes[] = {0, 1, 4095, 4096, 4097, 1 << 20};
    for (size_t s = 0; s < sizeof sizes / sizeof *sizes; s++) {
        uint8_t *to = fresh(sizes[s]), *from = pattern(sizes[s], (unsigned)s);
        prefault_copy(to, from, sizes[s]);
        assert_copied(to, from, sizes[s], "prefault_copy");
        munmap(to - GUARD, sizes[s] + 2 * GUARD);
        free(from);
    }
}

/* Spans of sizes that do not divide by the threads (and fewer bytes than
 * threads), by 1 to 7 threads: every byte of each, none beside. */
Test(prefault, copies_in_parts_are_every_span_whole)
{
    size_t sizes[] = {0, 3, 12 * 437645 + 5, 8 * 151, 65536};
    enum { N = sizeof sizes / sizeof *sizes };
    for (unsigned threads = 1; threads <= 7; threads++) {
        prefault_span spans[N];
        uint8_t *from[N];
        for (int i = 0; i < N; i++) {
            from[i] = pattern(sizes[i], threads * 10u + (unsigned)i);
            spans[i] = (prefault_span){fresh(sizes[i]), from[i], sizes[i]};
        }
        prefault_copy_par(spans, N, threads);
        for (int i = 0; i < N; i++) {
            char what[64];
            snprintf(what, sizeof what, "span %d of %zu bytes, %u threads", i, sizes[i], threads);
            assert_copied(spans[i].to, from[i], sizes[i], what);
            munmap((uint8_t *)spans[i].to - GUARD, sizes[i] + 2 * GUARD);
            free(from[i]);
        }
    }
}
