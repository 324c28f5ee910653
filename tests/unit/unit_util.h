/* unit_util — what several unit suites share: a growing memory sink for the
 * VOD writers (whose nth write may be made to fail) and the xorshift
 * generator of their random fixtures (each suite keeps its own seed, so
 * its fixtures stay what they were). */
#ifndef VOXD_TEST_UNIT_UTIL_H
#define VOXD_TEST_UNIT_UTIL_H

#include <criterion/criterion.h>
#include <errno.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    uint8_t *p;
    size_t n, cap;
    int calls, fail_at; /* fail_at > 0: that call fails with -EIO */
} membuf;

/* A vod_sink's write into a membuf; no write may follow a failure. */
static inline int mem_write(void *ud, const void *buf, size_t n)
{
    membuf *m = ud;
    if (++m->calls == m->fail_at) return -EIO;
    cr_assert_eq(m->fail_at && m->calls > m->fail_at, 0, "a write after the failure");
    if (m->cap - m->n < n) {
        size_t cap = m->cap ? m->cap : 4096;
        while (cap - m->n < n) cap *= 2;
        m->p = realloc(m->p, cap);
        cr_assert(m->p);
        m->cap = cap;
    }
    memcpy(m->p + m->n, buf, n);
    m->n += n;
    return 0;
}

/* Marsaglia's xorshift64 (13, 7, 17), its high bits. */
static inline uint32_t xorshift32(uint64_t *state)
{
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    return (uint32_t)(*state >> 16);
}

#endif
