/* ival_fixture — what the interval suites (test_ival*.c) share: long-double
 * points, whether an interval holds one, equality and nearness. */
#ifndef VOXD_TEST_IVAL_FIXTURE_H
#define VOXD_TEST_IVAL_FIXTURE_H

#include <criterion/criterion.h>
#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "ival.h"

typedef long double ld;

static inline bool in_iv(ival a, ld v) { return (ld)a.lo <= v && v <= (ld)a.hi; }

static inline bool iv_eq(ival a, double lo, double hi)
{
    return a.lo == lo && a.hi == hi;
}

/* |got - want| <= rel * |want| + abs_tol */
static inline bool near(double got, ld want, double rel, double abs_tol)
{
    return fabsl((ld)got - want) <= rel * fabsl(want) + abs_tol;
}

/* ---------------------------------------------- point-sample properties */

typedef ival (*un_iv)(ival);

typedef ld (*un_ld)(ld);

typedef ival (*bin_iv)(ival, ival);

typedef ld (*bin_ld)(ld, ld);

static inline double pred(double x) { return nextafter(x, -INFINITY); }

#endif
