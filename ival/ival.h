/* ival — interval arithmetic that never lies.
 *
 * Every function returns an interval that contains f(a) for every a in the
 * argument intervals, including floating-point rounding: results are widened
 * outward by at least one ulp (no rounding-mode switch per operation), so the
 * enclosure holds whatever the FPU rounds to.  Empty intervals do not occur:
 * a function undefined on part of its argument (sqrt, log of negatives,
 * asin/acos outside [-1,1]) is evaluated on the part where it is defined;
 * where it is defined nowhere, the result is the NaN interval (lo = hi = NaN),
 * which ival_contains_zero() treats as "may contain zero" so that the caller
 * keeps the box (conservative).  Infinite bounds are allowed.
 *
 * Conventions: lo <= hi always (or both NaN).  Intervals are sets of extended
 * reals: the sign of a zero bound carries no meaning.  Results of rounded
 * operations never have lo = +inf or hi = -inf (an overflowed bound is pulled
 * back to +-DBL_MAX), so that inf - inf cannot arise from add/sub of results.
 *
 * Requirements: IEEE-754 binary64 evaluated in double (FLT_EVAL_METHOD 0, as
 * on x86-64 SSE and AArch64), round-to-nearest mode (the default; nothing in
 * voxd changes it).
 *
 * The hot operations (those the expression tape runs per instruction) are
 * static inline below: widen, neg, add, sub, mul, sqr, abs, min, max, the
 * predicates and the common case of div.  The rest live in ival.c.
 */
#ifndef VOXD_IVAL_H
#define VOXD_IVAL_H

#include <float.h>
#include <math.h>
#include <stdbool.h>

typedef struct {
    double lo, hi;
} ival;

static inline ival ival_make(double lo, double hi) { return (ival){lo, hi}; }
static inline ival ival_point(double v) { return (ival){v, v}; }
static inline ival ival_nan(void) { return (ival){NAN, NAN}; }

static inline bool ival_is_nan(ival a)
{
    return isnan(a.lo) || isnan(a.hi);
}

/* True when 0 may lie in a (a NaN interval may: conservative). */
static inline bool ival_contains_zero(ival a)
{
    return !(a.lo > 0 || a.hi < 0);
}

/* True when v lies in a (for tests).  False when v or a is NaN. */
static inline bool ival_contains(ival a, double v)
{
    return a.lo <= v && v <= a.hi;
}

/* Outward rounding guard.  For a finite double c let
 *     e = fl(fl(PHI * |c|) + ETA),  PHI = 2^-53 (1 + 2^-52),  ETA = 2^-1074;
 * then fl(c + e) >= succ(c) and fl(c - e) <= pred(c) (Rump, Zimmermann,
 * Boldo, Melquiond, "Computing predecessor and successor in rounding to
 * nearest", BIT 2009).  Proof sketch: the neighbour of c on either side is at
 * distance s <= ulp(c) <= 2^-52 |c| (normal c) or s = ETA (subnormal c), and
 * RN(c + e) reaches it as soon as e > s/2.
 *   - If 2^-53 |c| is normal it is exact, and its successor is
 *     2^-53|c| + 2^-53 ulp(c) <= 2^-53|c| (1 + 2^-52) = PHI|c|, so
 *     fl(PHI|c|) > 2^-53|c| >= s/2 by monotonicity of rounding; adding ETA
 *     can only increase it.
 *   - Otherwise fl(PHI|c|) >= PHI|c| - ETA/2 (absolute error in the
 *     subnormal range), the sum with ETA is exact there, so
 *     e >= PHI|c| + ETA/2 > 2^-53 |c| >= s/2 (this also covers c = 0).
 * The same holds if a compiler fuses PHI*|c| + ETA into an fma.  The exact
 * result X of one correctly rounded operation x = RN(X) lies in
 * [pred(x), succ(x)], so widening x this way encloses X.  Infinite bounds
 * stay put; a lower bound of +inf (overflow) becomes pred(DBL_MAX) and an
 * upper bound of -inf becomes -pred(DBL_MAX), which still enclose the
 * overflowed value.  NaN propagates.  Branch-free: 2 min/max, 2 fabs, 2 mul,
 * 4 add/sub. */
#define IVAL_PHI_ 0x1.0000000000001p-53
static inline ival ival_widen(ival a)
{
    /* Overflowed bounds first (kept NaN-preserving: the test is false for
     * NaN), so that inf - inf cannot occur below. */
    double lo = a.lo > DBL_MAX ? DBL_MAX : a.lo;
    double hi = a.hi < -DBL_MAX ? -DBL_MAX : a.hi;
    double el = IVAL_PHI_ * fabs(lo);
    double eh = IVAL_PHI_ * fabs(hi);

    el = el + DBL_TRUE_MIN;
    eh = eh + DBL_TRUE_MIN;
    return (ival){lo - el, hi + eh};
}

static inline ival ival_neg(ival a) { return (ival){-a.hi, -a.lo}; }

static inline ival ival_add(ival a, ival b)
{
    return ival_widen((ival){a.lo + b.lo, a.hi + b.hi});
}

static inline ival ival_sub(ival a, ival b)
{
    return ival_widen((ival){a.lo - b.hi, a.hi - b.lo});
}

/* Out of line, for ival_mul: NaN inputs, and products of bounds 0 * inf
 * (which stand for the limit of 0 * y = 0). */
ival ival_mul_special_(ival a, ival b);

static inline ival ival_mul(ival a, ival b)
{
    double p0 = a.lo * b.lo, p1 = a.lo * b.hi;
    double p2 = a.hi * b.lo, p3 = a.hi * b.hi;
    double l01 = p0 < p1 ? p0 : p1, l23 = p2 < p3 ? p2 : p3;
    double h01 = p0 > p1 ? p0 : p1, h23 = p2 > p3 ? p2 : p3;

    /* One test for all four: the sum is NaN when a product is (and, rarely,
     * for inf - inf, which the slow path handles as well). */
    if (__builtin_expect(isnan(p0 + p1 + p2 + p3), 0))
        return ival_mul_special_(a, b);
    return ival_widen((ival){l01 < l23 ? l01 : l23, h01 > h23 ? h01 : h23});
}

/* m = min |x| over a (0 if a straddles 0), M = max |x|.  The comparisons are
 * ordered so that a NaN in a.lo propagates. */
static inline ival ival_abs(ival a)
{
    double m = a.lo < -a.hi ? -a.hi : a.lo;
    double M = -a.lo < a.hi ? a.hi : -a.lo;

    m = m <= 0 ? 0 : m; /* also turns -0 into +0 (pow(-0, -1) = -inf) */
    return (ival){m, M};
}

static inline ival ival_sqr(ival a)
{
    ival m = ival_abs(a);
    ival r = ival_widen((ival){m.lo * m.lo, m.hi * m.hi});

    r.lo = r.lo < 0 ? 0 : r.lo; /* squares are >= 0: no widening below 0 */
    return r;
}

static inline ival ival_min(ival a, ival b)
{
    if (__builtin_expect(isnan(a.lo) || isnan(b.lo), 0))
        return ival_nan();
    return (ival){a.lo < b.lo ? a.lo : b.lo, a.hi < b.hi ? a.hi : b.hi};
}

static inline ival ival_max(ival a, ival b)
{
    if (__builtin_expect(isnan(a.lo) || isnan(b.lo), 0))
        return ival_nan();
    return (ival){a.lo > b.lo ? a.lo : b.lo, a.hi > b.hi ? a.hi : b.hi};
}

/* Division by an interval that contains 0 returns the hull of both branches
 * (usually [-inf, +inf]); a one-sided zero divisor gives a half-line when the
 * numerator has one sign; 0/0-type cases and division by [0,0] give the
 * whole line.  The value at a divisor of exactly 0 is a pole: the result
 * encloses a/y for the nonzero y of b.  Inline: the usual case of a divisor
 * of one sign, two divisions (the extreme corners picked by signs). */
ival ival_div_special_(ival a, ival b); /* out of line: 0 in b, NaN, inf/inf */

static inline ival ival_div(ival a, ival b)
{
    double lo, hi;

    if (b.lo > 0) {
        lo = a.lo / (a.lo >= 0 ? b.hi : b.lo);
        hi = a.hi / (a.hi >= 0 ? b.lo : b.hi);
    } else if (b.hi < 0) {
        lo = a.hi / (a.hi >= 0 ? b.hi : b.lo);
        hi = a.lo / (a.lo >= 0 ? b.lo : b.hi);
    } else {
        return ival_div_special_(a, b);
    }
    if (__builtin_expect(isnan(lo) || isnan(hi), 0))
        return ival_div_special_(a, b);
    return ival_widen((ival){lo, hi});
}

ival ival_sqrt(ival a);
ival ival_exp(ival a);
ival ival_log(ival a);
ival ival_sin(ival a);
ival ival_cos(ival a);
ival ival_tan(ival a);
ival ival_asin(ival a);
ival ival_acos(ival a);
ival ival_atan(ival a);
/* atan2(y, x), with the branch cut on the negative x axis: a box that
 * straddles or touches it (or contains the origin) gets [-pi, pi]. */
ival ival_atan2(ival y, ival x);
/* a^n for an integer n (any sign): exact even/odd handling of negative bases;
 * a negative n is 1 / a^|n| with the division rules above; a^0 = 1. */
ival ival_powi(ival a, int n);
/* a^b for real b: for a constant integer b this is ival_powi; otherwise it
 * encloses C's pow(x, y) wherever that is not NaN: x >= 0 (exp(b log a)), and
 * x < 0 only at the integers y in b. */
ival ival_pow(ival a, ival b);
/* The Stolte polynomial blend g(d) = (d^2-R^2)^4 / R^8 for |d| <= R, else 0
 * (R > 0 constant; an R that reaches 0 or below gives [0, 1]). */
ival ival_blend(ival d, ival R);

/* Spherical coordinates of a box: r = |p|, theta = atan2(y, x) in [-pi, pi]
 * (azimuth in the xy-plane), phi = acos(z / r) in [0, pi] (angle from +z).
 * Boxes containing the z-axis, the origin or straddling the cut are handled. */
ival ival_r(ival x, ival y, ival z);
ival ival_theta(ival x, ival y);
ival ival_phi(ival x, ival y, ival z);

#endif
