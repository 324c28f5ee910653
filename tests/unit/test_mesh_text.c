/* The parallel text parsers' shared helpers (mesh_load.h): the newline
 * count, the cut into parts at line starts, the parts' first lines and
 * their scheduling, against answers the test counts byte by byte. */
#include <criterion/criterion.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "mesh_load.h"
#include "par.h"

static uint64_t rng = 88172645463325252ull;
static uint32_t rnd(void)
{
    rng ^= rng << 13, rng ^= rng >> 7, rng ^= rng << 17;
    return (uint32_t)(rng >> 16);
}

/* n bytes of lines of 0 to 2 * mean bytes, '\n' ends some, others ends
 * none (the text's last line), and a few bytes that are '\n' + 128 or
 * '\n' ^ 0x80 (what a word trick could take for a newline). */
static char *text(size_t n, uint32_t mean)
{
    char *t = malloc(n + 1);
    cr_assert(t);
    for (size_t i = 0; i < n; i++) {
        uint32_t r = rnd();
        t[i] = r % (2 * mean + 1) == 0 ? '\n' : r % 97 == 0 ? (char)0x8a : (char)('a' + r % 26);
    }
    return t;
}

static uint64_t newlines(const char *p, const char *end)
{
    uint64_t n = 0;
    for (; p < end; p++) n += *p == '\n';
    return n;
}

Test(mesh_text, newlines_are_counted_at_every_length_and_offset)
{
    char *t = text(4096, 5);
    for (size_t off = 0; off < 17; off++)
        for (size_t len = 0; off + len <= 4096; len += len < 80 ? 1 : 61)
            cr_assert_eq(mesh_text_count_newlines(t + off, t + off + len),
                         newlines(t + off, t + off + len), "offset %zu, %zu bytes", off, len);
    free(t);
}

/* Parts tile the text, each from a line start (the text's own, or just
 * after a '\n'), and first_lines numbers their first lines. */
Test(mesh_text, parts_start_at_lines_and_first_lines_number_them)
{
    size_t sizes[] = {0, 1, 7, 100, 5000};
    uint32_t means[] = {0, 3, 40, 4000};
    for (size_t s = 0; s < sizeof sizes / sizeof *sizes; s++)
        for (size_t m = 0; m < sizeof means / sizeof *means; m++)
            for (uint32_t parts = 1; parts <= 9; parts += 4) {
                char *t = text(sizes[s], means[m]);
                const char *end = t + sizes[s], *prev = t;
                uint64_t first[10];
                uint64_t lines = mesh_text_first_lines(t, end, parts, first);
                for (uint32_t k = 0; k <= parts; k++) {
                    const char *p = mesh_text_part_start(t, end, k, parts);
                    cr_assert(p >= prev && p <= end, "part %u of %u", k, parts);
                    cr_assert(p == t || p == end || p[-1] == '\n', "part %u not at a line", k);
                    /* the first line start at or after its share of the bytes */
                    const char *share = t + (size_t)((uint64_t)sizes[s] * k / parts);
                    for (const char *q = share; q < p; q++)
                        cr_assert(q != t && q[-1] != '\n', "part %u of %u passes a line", k, parts);
                    cr_assert_eq(first[k], newlines(t, p), "part %u of %u's first line", k, parts);
                    prev = p;
                }
                cr_assert_eq(mesh_text_part_start(t, end, 0, parts), t);
                cr_assert_eq(mesh_text_part_start(t, end, parts, parts), end);
                cr_assert_eq(lines, newlines(t, end) + (sizes[s] && end[-1] != '\n'));
                free(t);
            }
}

typedef struct {
    atomic_uint runs[256];
    uint32_t fail_at; /* UINT32_MAX: none */
    atomic_bool failed; /* the failing part has returned */
} parts_seen;

/* A part after the failing one, taken while it ran, ends only once it has
 * failed and 20 ms more (the scheduler's flag is set as its fn returns):
 * so its thread looks for the next part after the failure, whatever the
 * load. */
static int each(void *ud, uint32_t part)
{
    parts_seen *s = ud;
    atomic_fetch_add(&s->runs[part], 1);
    if (part == s->fail_at) {
        atomic_store(&s->failed, true);
        return 1;
    }
    if (part > s->fail_at) {
        while (!atomic_load(&s->failed)) nanosleep(&(struct timespec){0, 100000}, NULL);
        nanosleep(&(struct timespec){0, 20000000}, NULL);
    }
    return 0;
}

Test(mesh_text, each_part_runs_once_and_none_is_taken_after_a_failure)
{
    parts_seen s = {.fail_at = UINT32_MAX};
    cr_assert_eq(mesh_text_each_part(256, each, &s), 0);
    for (int i = 0; i < 256; i++) cr_assert_eq(atomic_load(&s.runs[i]), 1, "part %d", i);

    parts_seen f = {.fail_at = 10};
    cr_assert_eq(mesh_text_each_part(256, each, &f), -1);
    unsigned after = 0;
    for (int i = 0; i < 256; i++) {
        cr_assert_leq(atomic_load(&f.runs[i]), 1, "part %d", i);
        if (i <= 10) cr_assert_eq(atomic_load(&f.runs[i]), 1, "part %d before the failure", i);
        else after += atomic_load(&f.runs[i]);
    }
    /* the other threads finish the part each holds, and take no more */
    cr_assert_leq(after, par_cpus() - 1, "%u parts after the failure", after);
}
