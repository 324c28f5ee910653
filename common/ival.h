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
 * Conventions: lo <= hi always (or both NaN).
 */
#ifndef VOXD_IVAL_H
#define VOXD_IVAL_H

#include <stdbool.h>

typedef struct {
    double lo, hi;
} ival;

static inline ival ival_make(double lo, double hi) { return (ival){lo, hi}; }
static inline ival ival_point(double v) { return (ival){v, v}; }
bool ival_is_nan(ival a);
/* True when 0 may lie in a (a NaN interval may: conservative). */
bool ival_contains_zero(ival a);
/* True when v lies in a (for tests). */
bool ival_contains(ival a, double v);

/* Widen one ulp outward (the rounding guard every operation applies). */
ival ival_widen(ival a);

ival ival_neg(ival a);
ival ival_add(ival a, ival b);
ival ival_sub(ival a, ival b);
ival ival_mul(ival a, ival b);
/* Division by an interval that contains 0 returns the hull of both branches
 * (usually [-inf, +inf]); 0/0-type cases give the whole line. */
ival ival_div(ival a, ival b);
ival ival_sqr(ival a);
ival ival_sqrt(ival a);
ival ival_abs(ival a);
ival ival_min(ival a, ival b);
ival ival_max(ival a, ival b);
ival ival_exp(ival a);
ival ival_log(ival a);
ival ival_sin(ival a);
ival ival_cos(ival a);
ival ival_tan(ival a);
ival ival_asin(ival a);
ival ival_acos(ival a);
ival ival_atan(ival a);
/* atan2(y, x), with the branch cut on the negative x axis: a box that
 * straddles it gets [-pi, pi]. */
ival ival_atan2(ival y, ival x);
/* a^n for an integer n (any sign): exact even/odd handling of negative bases. */
ival ival_powi(ival a, int n);
/* a^b for real b: for a constant integer b this is ival_powi; otherwise
 * defined for a >= 0 only (exp(b log a)), like C's pow. */
ival ival_pow(ival a, ival b);
/* The Stolte polynomial blend g(d) = (d^2-R^2)^4 / R^8 for |d| <= R, else 0
 * (R > 0 constant). */
ival ival_blend(ival d, ival R);

/* Spherical coordinates of a box: r = |p|, theta = atan2(y, x) in [-pi, pi]
 * (azimuth in the xy-plane), phi = acos(z / r) in [0, pi] (angle from +z).
 * Boxes containing the z-axis, the origin or straddling the cut are handled. */
ival ival_r(ival x, ival y, ival z);
ival ival_theta(ival x, ival y);
ival ival_phi(ival x, ival y, ival z);

#endif
