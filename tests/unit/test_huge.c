/* huge (common/huge.c): huge_calloc refuses a count whose bytes overflow
 * and zeroes what it gives (a block that malloc hands out again, written
 * before, reads back zero); huge_advise asks for huge pages on exactly the
 * whole 2 MiB pages inside the block, as the kernel's own record of the
 * mapping (/proc/self/smaps, its "hg" flag) shows; on a kernel without
 * transparent huge pages (no /sys/kernel/mm/transparent_hugepage), which
 * refuses the advice, the mapping stays whole and unflagged. */
#include <criterion/criterion.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

#include "huge.h"

#define MIB ((size_t)1 << 20)

Test(huge, a_count_whose_bytes_overflow_is_refused)
{
    cr_assert_null(huge_calloc(SIZE_MAX / 8 + 1, 8));
    cr_assert_null(huge_calloc(2, SIZE_MAX / 2 + 1));
    void *p = huge_calloc(0, 8); /* nothing asked: malloc(0)'s answer, freeable */
    free(p);
}

Test(huge, calloc_zeroes_a_block_given_out_again)
{
    /* below malloc's mmap threshold, so the block comes from the heap and
     * the same chunk is handed out again after its free */
    size_t n = 16 * 1024;
    for (int round = 0; round < 4; round++) {
        uint8_t *dirty = malloc(n);
        cr_assert_not_null(dirty);
        memset(dirty, 0xab, n);
        free(dirty);
        uint64_t *z = huge_calloc(n / 8, 8);
        cr_assert_not_null(z);
        for (size_t i = 0; i < n / 8; i++) cr_assert_eq(z[i], 0, "word %zu of round %d", i, round);
        free(z);
    }
}

/* The mapping of /proc/self/smaps that holds address at: its bounds, and
 * whether its VmFlags hold "hg" (MADV_HUGEPAGE). */
typedef struct {
    uintptr_t lo, hi;
    bool hg;
} vma;

static vma vma_of(uintptr_t at)
{
    FILE *f = fopen("/proc/self/smaps", "r");
    cr_assert_not_null(f);
    char line[512];
    vma v = {0, 0, false};
    bool in = false;
    while (fgets(line, sizeof line, f)) {
        unsigned long a, b;
        char c;
        if (sscanf(line, "%lx-%lx%c", &a, &b, &c) == 3 && c == ' ') {
            in = a <= at && at < b;
            if (in) v.lo = a, v.hi = b;
        } else if (in && !strncmp(line, "VmFlags:", 8)) {
            v.hg = strstr(line, " hg") != NULL;
        }
    }
    fclose(f);
    cr_assert_neq(v.hi, 0, "no mapping holds %#lx", (unsigned long)at);
    return v;
}

/* The kernel takes MADV_HUGEPAGE (it has transparent huge pages, whatever
 * their mode: "never" still records the advice). */
static bool kernel_has_thp(void)
{
    return access("/sys/kernel/mm/transparent_hugepage", F_OK) == 0;
}

Test(huge, advise_covers_exactly_the_whole_huge_pages_inside)
{
    /* base, 2 MiB-aligned, in a 12 MiB mapping; the block from base + 4
     * KiB, 6 MiB long: its whole huge pages are [base + 2, base + 6) MiB */
    size_t len = 12 * MIB;
    uint8_t *m = mmap(NULL, len, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    cr_assert_neq(m, MAP_FAILED);
    uintptr_t base = ((uintptr_t)m + 2 * MIB - 1) & ~(uintptr_t)(2 * MIB - 1);
    huge_advise((void *)(base + 4096), 6 * MIB);
    vma in = vma_of(base + 3 * MIB), before = vma_of(base + 4096), after = vma_of(base + 6 * MIB);
    if (kernel_has_thp()) {
        cr_assert(in.lo == base + 2 * MIB && in.hi == base + 6 * MIB && in.hg,
                  "the whole pages advised, in a mapping of their own: %#lx-%#lx hg %d",
                  (unsigned long)in.lo, (unsigned long)in.hi, in.hg);
        cr_assert(before.hi == base + 2 * MIB && !before.hg, "the partial page before not advised");
        cr_assert(after.lo == base + 6 * MIB && !after.hg, "the partial page after not advised");
    } else { /* refused: the mapping as it was */
        cr_assert(in.lo <= (uintptr_t)m && in.hi >= (uintptr_t)m + len && !in.hg,
                  "no huge pages in this kernel: the mapping whole and unflagged");
    }
    /* a block holding no whole huge page: no advice, nothing split */
    huge_advise((void *)(base + 6 * MIB + 4096), 2 * MIB);
    vma still = vma_of(base + 8 * MIB);
    cr_assert(!still.hg &&
              (kernel_has_thp() ? still.lo == base + 6 * MIB : still.lo <= (uintptr_t)m));
    munmap(m, len);
}
