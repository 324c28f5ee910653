/* expr_fixture — what the expression suites (test_expr*.c) share: compiling a
 * source that must compile, comparing doubles, and a seeded random generator. */
#ifndef VOXD_TEST_EXPR_FIXTURE_H
#define VOXD_TEST_EXPR_FIXTURE_H

#include <criterion/criterion.h>
#include <errno.h>
#include <fenv.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "expr.h"
#include "expr_impl.h" /* tape layout, for the corruption tests only */

/* ---- helpers ---- */

static inline expr_tape *compile_ok(const char *src)
{
    expr_tape *t = NULL;
    expr_error e;
    int rc = expr_compile(src, strlen(src), NULL, &t, &e);
    cr_assert_eq(rc, 0, "compile \"%s\": rc %d at %d:%d: %s", src, rc, e.line, e.col, e.msg);
    cr_assert_not_null(t);
    return t;
}

/* Same double, NaNs equal: the evaluators must agree bit for bit. */
static inline int same_double(double a, double b)
{
    return (a != a && b != b) || !memcmp(&a, &b, sizeof a);
}

static inline int close_to(double got, double want, double rel)
{
    if (isnan(want)) return isnan(got);
    if (isinf(want)) return got == want;
    return fabs(got - want) <= rel * fmax(1.0, fabs(want));
}

/* xorshift64*: deterministic random numbers for every test. */
static uint64_t rng_state;

/* EXPR_TEST_SEED=n in the environment varies every random test (stress runs). */
static inline void rng_seed(uint64_t s)
{
    const char *env = getenv("EXPR_TEST_SEED");
    if (env) s += 1000 * strtoull(env, NULL, 10);
    rng_state = s * 0x9e3779b97f4a7c15ull + 1;
}

static inline uint64_t rng_next(void)
{
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return rng_state * 2685821657736338717ull;
}

static inline double urand(double lo, double hi)
{
    return lo + (hi - lo) * (double)(rng_next() >> 11) * 0x1p-53;
}

#endif
