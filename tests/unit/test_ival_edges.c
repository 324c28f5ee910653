/* ival's edge cases, each against what it must give: tight arithmetic,
 * infinities that make no NaN, NaN kept with its box, sin and cos, tan around
 * its poles, division by intervals with zero, powi's signs, pow of real and
 * negative bases, the domains of sqrt, log and exp, atan2 and theta at the cut,
 * r and phi on the axes, blend around the radius. */
#include <criterion/criterion.h>
#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "ival.h"

#include "ival_fixture.h"

/* ------------------------------------------------------- targeted cases */

#define ASSERT_HAS(iv, v)                                                   \
    cr_assert(in_iv((iv), (v)), "[%a, %a] should contain %La", (iv).lo,     \
              (iv).hi, (ld)(v))

/* Bounds within rel of the true range [lo, hi]. */
#define ASSERT_TIGHT(iv, tlo, thi, rel, abs_tol)                            \
    cr_assert(near((iv).lo, (tlo), (rel), (abs_tol)) &&                     \
                  near((iv).hi, (thi), (rel), (abs_tol)) &&                 \
                  in_iv((iv), (tlo)) && in_iv((iv), (thi)),                 \
              "[%a, %a] vs true [%La, %La]", (iv).lo, (iv).hi, (ld)(tlo),   \
              (ld)(thi))

Test(ival_edges, arithmetic_is_tight)
{
    ival r = ival_add(ival_make(1, 2), ival_make(3, 4));
    cr_assert(r.lo <= 4 && r.lo >= 4 - 4 * DBL_EPSILON);
    cr_assert(r.hi >= 6 && r.hi <= 6 + 8 * DBL_EPSILON);
    ASSERT_TIGHT(ival_sub(ival_make(1, 2), ival_make(3, 4)), -3.0L, -1.0L,
                 1e-15, 0);
    ASSERT_TIGHT(ival_mul(ival_make(-2, 3), ival_make(-5, 7)), -15.0L, 21.0L,
                 1e-15, 0);
    ASSERT_TIGHT(ival_mul(ival_make(-2, -1), ival_make(3, 5)), -10.0L, -3.0L,
                 1e-15, 0);
    ASSERT_TIGHT(ival_div(ival_make(1, 2), ival_make(4, 8)), 0.125L, 0.5L,
                 1e-15, 0);
    ASSERT_TIGHT(ival_div(ival_make(-1, 2), ival_make(-4, -2)), -1.0L, 0.5L,
                 1e-15, 0);
    ASSERT_TIGHT(ival_sqr(ival_make(-3, 2)), 0.0L, 9.0L, 1e-15, 0);
    cr_assert_eq(ival_sqr(ival_make(-3, 2)).lo, 0.0);
    ASSERT_TIGHT(ival_sqr(ival_make(-3, -2)), 4.0L, 9.0L, 1e-15, 0);
    cr_assert(iv_eq(ival_abs(ival_make(-3, 2)), 0, 3));
    cr_assert(iv_eq(ival_abs(ival_make(-3, -2)), 2, 3));
    cr_assert(iv_eq(ival_neg(ival_make(-3, 2)), -2, 3));
    cr_assert(iv_eq(ival_min(ival_make(-3, 2), ival_make(0, 1)), -3, 1));
    cr_assert(iv_eq(ival_max(ival_make(-3, 2), ival_make(0, 1)), 0, 2));
}

Test(ival_edges, infinities_do_not_make_nan)
{
    ival whole = ival_make(-INFINITY, INFINITY);
    ival r = ival_mul(ival_make(0, 1), whole);

    cr_assert(iv_eq(r, -INFINITY, INFINITY));
    r = ival_mul(ival_make(0, 0), whole);
    cr_assert(!ival_is_nan(r) && r.lo <= 0 && r.hi >= 0 && r.hi < 1e-300);
    r = ival_mul(ival_make(0, 1), ival_make(1, INFINITY));
    cr_assert(r.lo <= 0 && r.lo > -1e-300 && r.hi == INFINITY);
    r = ival_add(whole, ival_make(1, 2));
    cr_assert(iv_eq(r, -INFINITY, INFINITY));
    r = ival_sub(ival_make(1, INFINITY), ival_make(1, INFINITY));
    cr_assert(iv_eq(r, -INFINITY, INFINITY));
    /* overflow: the lower bound stays finite so that later sub is not NaN */
    r = ival_mul(ival_point(1e300), ival_point(1e300));
    cr_assert(iv_eq(r, pred(DBL_MAX), INFINITY));
    r = ival_sub(r, r);
    cr_assert(iv_eq(r, -INFINITY, INFINITY));
    r = ival_div(ival_make(1, INFINITY), ival_make(1, INFINITY));
    cr_assert(!ival_is_nan(r) && r.lo <= 0 && r.hi == INFINITY);
}

Test(ival_edges, nan_propagates_and_keeps_the_box)
{
    ival n = ival_nan(), a = ival_make(1, 2);

    cr_assert(ival_contains_zero(n));
    cr_assert(!ival_contains(n, 0));
    cr_assert(ival_is_nan(ival_add(n, a)) && ival_is_nan(ival_sub(a, n)));
    cr_assert(ival_is_nan(ival_mul(n, a)) && ival_is_nan(ival_mul(a, n)));
    cr_assert(ival_is_nan(ival_div(n, a)) && ival_is_nan(ival_div(a, n)));
    cr_assert(ival_is_nan(ival_min(a, n)) && ival_is_nan(ival_max(n, a)));
    cr_assert(ival_is_nan(ival_min(n, a)) && ival_is_nan(ival_max(a, n)));
    cr_assert(ival_is_nan(ival_sqr(n)) && ival_is_nan(ival_abs(n)));
    cr_assert(ival_is_nan(ival_neg(n)) && ival_is_nan(ival_sqrt(n)));
    cr_assert(ival_is_nan(ival_exp(n)) && ival_is_nan(ival_log(n)));
    cr_assert(ival_is_nan(ival_sin(n)) && ival_is_nan(ival_cos(n)));
    cr_assert(ival_is_nan(ival_tan(n)) && ival_is_nan(ival_asin(n)));
    cr_assert(ival_is_nan(ival_acos(n)) && ival_is_nan(ival_atan(n)));
    cr_assert(ival_is_nan(ival_atan2(n, a)) && ival_is_nan(ival_atan2(a, n)));
    cr_assert(ival_is_nan(ival_powi(n, 3)) && ival_is_nan(ival_pow(a, n)));
    cr_assert(ival_is_nan(ival_pow(n, a)) && ival_is_nan(ival_blend(n, a)));
    cr_assert(ival_is_nan(ival_r(n, a, a)) && ival_is_nan(ival_phi(a, a, n)));
    cr_assert(ival_is_nan(ival_theta(a, n)));
    cr_assert(!ival_contains_zero(a) && ival_contains_zero(ival_make(-1, 0)));
}

Test(ival_edges, sin_and_cos)
{
    ival r = ival_sin(ival_make(0, 2 * M_PI));
    cr_assert(iv_eq(r, -1, 1));
    r = ival_cos(ival_make(0, 2 * M_PI));
    cr_assert(iv_eq(r, -1, 1));
    r = ival_sin(ival_make(0.1, 0.2));
    ASSERT_TIGHT(r, sinl(0.1), sinl(0.2), 0, 1e-12);
    r = ival_cos(ival_make(0.1, 0.2));
    ASSERT_TIGHT(r, cosl(0.2), cosl(0.1), 0, 1e-12);
    /* across the maximum of sin at pi/2 */
    r = ival_sin(ival_make(M_PI_2 - 1e-12, M_PI_2 + 1e-12));
    cr_assert(r.hi == 1 && r.lo < 1 && r.lo > 1 - 1e-15);
    r = ival_cos(ival_make(M_PI_2 - 1e-12, M_PI_2 + 1e-12));
    ASSERT_HAS(r, 0);
    cr_assert(r.lo > -1.1e-12 && r.hi < 1.1e-12);
    /* across pi: cos min, sin zero */
    r = ival_cos(ival_make(3, 3.5));
    cr_assert(r.lo == -1 && near(r.hi, cosl(3.5L), 1e-14, 0));
    r = ival_sin(ival_make(3, 3.5));
    ASSERT_TIGHT(r, sinl(3.5L), sinl(3.0L), 1e-14, 0);
    /* wider than a turn, huge, infinite */
    cr_assert(iv_eq(ival_sin(ival_make(-1, 6.3)), -1, 1));
    cr_assert(iv_eq(ival_cos(ival_make(1, 8)), -1, 1));
    cr_assert(iv_eq(ival_sin(ival_make(1e300, 1e301)), -1, 1));
    cr_assert(iv_eq(ival_cos(ival_make(1e300, 1e301)), -1, 1));
    cr_assert(iv_eq(ival_sin(ival_make(0, INFINITY)), -1, 1));
    cr_assert(iv_eq(ival_cos(ival_make(-INFINITY, 0)), -1, 1));
    /* a point far out: the exact value of libm, widened */
    r = ival_sin(ival_point(1e300));
    ASSERT_HAS(r, sinl(1e300));
    cr_assert(r.hi - r.lo < 1e-15);
    /* width just under a turn, starting just after the sin max: no max */
    double a0 = M_PI_2 + 0.01, a1 = M_PI_2 + 6.2;
    r = ival_sin(ival_make(a0, a1));
    cr_assert(r.lo == -1 && r.hi < 1 && near(r.hi, sinl(a0), 1e-14, 0));
    /* same quadrant, a full turn later: everything */
    cr_assert(iv_eq(ival_sin(ival_make(0.1, 0.2 + 2 * M_PI)), -1, 1));
}

Test(ival_edges, tan_around_poles)
{
    ival r = ival_tan(ival_make(M_PI_2 - 0.1, M_PI_2 + 0.1));
    cr_assert(iv_eq(r, -INFINITY, INFINITY));
    r = ival_tan(ival_make(-M_PI_2 - 0.1, -M_PI_2 + 0.1));
    cr_assert(iv_eq(r, -INFINITY, INFINITY));
    /* the arguments as doubles: tan is steep here */
    double a[4] = {M_PI_2 - 0.1, M_PI_2 - 0.01, M_PI_2 + 0.01, M_PI_2 + 0.1};
    r = ival_tan(ival_make(a[0], a[1]));
    ASSERT_TIGHT(r, tanl(a[0]), tanl(a[1]), 1e-14, 0);
    r = ival_tan(ival_make(a[2], a[3]));
    ASSERT_TIGHT(r, tanl(a[2]), tanl(a[3]), 1e-14, 0);
    /* across pi: no pole */
    r = ival_tan(ival_make(3, 3.3));
    ASSERT_TIGHT(r, tanl(3.0L), tanl(3.3), 1e-13, 0);
    r = ival_tan(ival_point(M_PI_2)); /* the double below pi/2: huge, finite */
    cr_assert(r.lo > 1e15 && isfinite(r.hi));
    cr_assert(iv_eq(ival_tan(ival_make(0, 3.2)), -INFINITY, INFINITY));
    cr_assert(iv_eq(ival_tan(ival_make(1e300, 1e301)), -INFINITY, INFINITY));
}

Test(ival_edges, division_by_intervals_with_zero)
{
    ival one = ival_point(1);
    ival r = ival_div(one, ival_make(0, 1));
    cr_assert(r.hi == INFINITY && near(r.lo, 1.0L, 1e-15, 0) && r.lo <= 1);
    r = ival_div(one, ival_make(-1, 0));
    cr_assert(r.lo == -INFINITY && near(r.hi, -1.0L, 1e-15, 0) && r.hi >= -1);
    r = ival_div(ival_make(-2, -1), ival_make(0, 4));
    cr_assert(r.lo == -INFINITY && near(r.hi, -0.25L, 1e-15, 0));
    r = ival_div(ival_make(-2, -1), ival_make(-4, 0));
    cr_assert(r.hi == INFINITY && near(r.lo, 0.25L, 1e-15, 0));
    cr_assert(iv_eq(ival_div(one, ival_make(-1, 1)), -INFINITY, INFINITY));
    cr_assert(iv_eq(ival_div(one, ival_make(0, 0)), -INFINITY, INFINITY));
    cr_assert(iv_eq(ival_div(ival_make(-1, 1), ival_make(0, 1)), -INFINITY,
                    INFINITY));
    cr_assert(iv_eq(ival_div(ival_make(0, 0), ival_make(0, 0)), -INFINITY,
                    INFINITY));
    cr_assert(iv_eq(ival_div(ival_make(0, 0), ival_make(-1, 1)), 0, 0));
    r = ival_div(ival_make(0, 3), ival_make(0, 1));
    cr_assert(r.lo <= 0 && r.lo > -1e-300 && r.hi == INFINITY);
}

Test(ival_edges, powi_signs_and_zero)
{
    ival a = ival_make(-2, 3), r;

    r = ival_powi(a, 2);
    cr_assert(r.lo == 0);
    ASSERT_TIGHT(r, 0.0L, 9.0L, 1e-15, 0);
    r = ival_powi(a, 3);
    ASSERT_TIGHT(r, -8.0L, 27.0L, 1e-15, 0);
    cr_assert(iv_eq(ival_powi(a, -1), -INFINITY, INFINITY));
    r = ival_powi(a, -2);
    cr_assert(r.hi == INFINITY && near(r.lo, 1.0L / 9, 1e-15, 0));
    cr_assert(iv_eq(ival_powi(a, 0), 1, 1));
    r = ival_powi(ival_make(-3, -2), 3);
    ASSERT_TIGHT(r, -27.0L, -8.0L, 1e-15, 0);
    r = ival_powi(ival_make(-3, -2), 4);
    ASSERT_TIGHT(r, 16.0L, 81.0L, 1e-15, 0);
    r = ival_powi(ival_make(-3, -2), -3);
    ASSERT_TIGHT(r, -1.0L / 8, -1.0L / 27, 1e-15, 0);
    r = ival_powi(ival_make(1.5, 2), 40);
    ASSERT_TIGHT(r, powl(1.5L, 40), powl(2.0L, 40), 1e-14, 0);
    r = ival_powi(ival_make(0.5, 2), INT_MIN);
    cr_assert(r.lo <= 0 && r.lo > -1e-300 && r.hi == INFINITY);
    r = ival_powi(ival_make(-1, -1), INT_MAX);
    ASSERT_TIGHT(r, -1.0L, -1.0L, 1e-12, 0);
    r = ival_powi(ival_make(0, 2), -1);
    cr_assert(r.hi == INFINITY && near(r.lo, 0.5L, 1e-15, 0));
}

Test(ival_edges, pow_real_and_negative_bases)
{
    ival r = ival_pow(ival_make(-2, 3), ival_point(2));
    ASSERT_TIGHT(r, 0.0L, 9.0L, 1e-15, 0);
    r = ival_pow(ival_make(-2, -1), ival_point(3));
    ASSERT_TIGHT(r, -8.0L, -1.0L, 1e-15, 0);
    /* negative base, non-integer exponent: defined nowhere */
    cr_assert(ival_is_nan(ival_pow(ival_make(-2, -1), ival_point(0.5))));
    cr_assert(ival_is_nan(ival_pow(ival_make(-2, -1), ival_make(0.2, 0.8))));
    /* only the part x >= 0 counts */
    r = ival_pow(ival_make(-2, 4), ival_point(0.5));
    ASSERT_TIGHT(r, 0.0L, 2.0L, 1e-14, 0);
    r = ival_pow(ival_make(2, 4), ival_make(0.5, 2));
    ASSERT_TIGHT(r, sqrtl(2), 16.0L, 1e-14, 0);
    r = ival_pow(ival_make(0.25, 0.5), ival_make(0.5, 2));
    ASSERT_TIGHT(r, 0.0625L, sqrtl(0.5L), 1e-14, 0);
    /* exponent interval with one integer: the negative part is powi */
    r = ival_pow(ival_make(-2, -1), ival_make(2.5, 3.5));
    ASSERT_TIGHT(r, -8.0L, -1.0L, 1e-14, 0);
    /* with several integers: a symmetric hull */
    r = ival_pow(ival_make(-2, -1), ival_make(1, 2));
    ASSERT_HAS(r, -2.0L);
    ASSERT_HAS(r, 4.0L);
    /* pow(0, negative) is +inf in C */
    ASSERT_HAS(ival_pow(ival_make(0, 1), ival_point(-0.5)), INFINITY);
}

Test(ival_edges, sqrt_log_exp_domains)
{
    cr_assert(ival_is_nan(ival_sqrt(ival_make(-2, -1))));
    cr_assert(ival_is_nan(ival_log(ival_make(-2, -1))));
    ival r = ival_sqrt(ival_make(-1, 4));
    cr_assert(r.lo == 0 && near(r.hi, 2.0L, 1e-15, 0));
    r = ival_sqrt(ival_make(0, 0));
    cr_assert(r.lo == 0 && r.hi >= 0 && r.hi < 1e-300);
    r = ival_log(ival_make(0, 1));
    cr_assert(r.lo == -INFINITY && r.hi >= 0 && r.hi < 1e-300);
    r = ival_log(ival_make(-1, M_E));
    cr_assert(r.lo == -INFINITY && near(r.hi, 1.0L, 1e-15, 0));
    r = ival_log(ival_make(-1, 0));
    cr_assert(r.lo == -INFINITY && r.hi <= -1e300);
    r = ival_log(ival_make(1, M_E));
    ASSERT_TIGHT(r, 0.0L, logl(M_E), 1e-15, 1e-300);
    r = ival_exp(ival_make(0, 1));
    ASSERT_TIGHT(r, 1.0L, expl(1), 1e-15, 0);
    r = ival_exp(ival_make(-INFINITY, 800));
    cr_assert(r.lo == 0 && r.hi == INFINITY);
    r = ival_asin(ival_make(-2, 0.5));
    ASSERT_TIGHT(r, -M_PI_2, asinl(0.5L), 1e-15, 0);
    r = ival_acos(ival_make(-2, 2));
    ASSERT_TIGHT(r, 0.0L, acosl(-1.0L), 1e-15, 0);
    cr_assert(ival_is_nan(ival_acos(ival_make(1.5, 2))));
    cr_assert(ival_is_nan(ival_asin(ival_make(-3, -1.5))));
    r = ival_atan(ival_make(-INFINITY, 1));
    ASSERT_TIGHT(r, -M_PI_2, atanl(1), 1e-15, 0);
}

Test(ival_edges, atan2_and_theta_at_the_cut)
{
    ld pi = acosl(-1);
    /* straddling the negative x axis */
    ival r = ival_atan2(ival_make(-1, 1), ival_make(-3, -2));
    ASSERT_TIGHT(r, -pi, pi, 1e-15, 0);
    /* touching it from above */
    r = ival_atan2(ival_make(0, 1), ival_make(-3, -2));
    ASSERT_HAS(r, pi);
    ASSERT_HAS(r, -pi);
    /* containing the origin */
    r = ival_theta(ival_make(-1, 1), ival_make(-1, 1));
    ASSERT_TIGHT(r, -pi, pi, 1e-15, 0);
    /* straddling the positive x axis: tight */
    r = ival_atan2(ival_make(-1, 1), ival_make(2, 3));
    ASSERT_TIGHT(r, atan2l(-1, 2), atan2l(1, 2), 1e-15, 0);
    r = ival_theta(ival_make(2, 3), ival_make(-1, 1));
    ASSERT_TIGHT(r, atan2l(-1, 2), atan2l(1, 2), 1e-15, 0);
    /* upper half plane, straddling the y axis */
    r = ival_atan2(ival_make(1, 2), ival_make(-1, 1));
    ASSERT_TIGHT(r, atan2l(1, 1), atan2l(1, -1), 1e-15, 0);
    /* lower left quadrant */
    r = ival_atan2(ival_make(-2, -1), ival_make(-2, -1));
    ASSERT_TIGHT(r, atan2l(-1, -2), atan2l(-2, -1), 1e-15, 0);
    /* a quarter plane to infinity */
    r = ival_atan2(ival_make(1, INFINITY), ival_make(1, INFINITY));
    ASSERT_TIGHT(r, 0.0L, pi / 2, 1e-15, 1e-300);
}

Test(ival_edges, r_and_phi_on_axes)
{
    ld pi = acosl(-1);
    ival u = ival_make(-1, 1);

    ival r = ival_r(u, u, u);
    cr_assert(r.lo == 0 && near(r.hi, sqrtl(3), 1e-15, 0));
    r = ival_r(ival_make(3, 4), ival_make(0, 0), ival_make(0, 0));
    ASSERT_TIGHT(r, 3.0L, 4.0L, 1e-15, 0);
    /* the z axis above the origin: phi from 0 */
    ival p = ival_phi(u, u, ival_make(1, 2));
    cr_assert(p.lo == 0);
    ASSERT_TIGHT(p, 0.0L, acosl(1 / sqrtl(3)), 1e-14, 0);
    /* below: up to pi */
    p = ival_phi(u, u, ival_make(-2, -1));
    ASSERT_TIGHT(p, acosl(-1 / sqrtl(3)), pi, 1e-14, 0);
    /* the origin: everything */
    p = ival_phi(u, u, u);
    ASSERT_TIGHT(p, 0.0L, pi, 1e-15, 0);
    /* off the axis, z straddling 0 */
    p = ival_phi(ival_make(1, 2), ival_make(1, 2), ival_make(-1, 1));
    ASSERT_TIGHT(p, acosl(1 / sqrtl(3)), acosl(-1 / sqrtl(3)), 1e-14, 0);
    /* off the axis, above: min at the inner top corner, max at outer bottom */
    p = ival_phi(ival_make(1, 2), ival_make(0, 0), ival_make(1, 3));
    ASSERT_TIGHT(p, acosl(3 / sqrtl(10)), acosl(1 / sqrtl(5)), 1e-14, 0);
    /* off the axis, below */
    p = ival_phi(ival_make(1, 2), ival_make(0, 0), ival_make(-3, -1));
    ASSERT_TIGHT(p, acosl(-1 / sqrtl(5)), acosl(-3 / sqrtl(10)), 1e-14, 0);
}

Test(ival_edges, blend_around_the_radius)
{
    ival R = ival_point(2);
    ival r = ival_blend(ival_make(-1, 1), R); /* straddling 0: max 1 */
    ASSERT_TIGHT(r, powl(0.75L, 4), 1.0L, 1e-14, 0);
    cr_assert(r.hi == 1);
    r = ival_blend(ival_make(1.9, 2.1), R); /* around |d| = R */
    ld d19 = 1.9;
    cr_assert(r.lo == 0 && near(r.hi, powl(1 - d19 * d19 / 4, 4), 1e-13, 0));
    ASSERT_HAS(r, powl(1 - d19 * d19 / 4, 4));
    r = ival_blend(ival_make(3, 4), R); /* beyond R */
    cr_assert(iv_eq(r, 0, 0));
    r = ival_blend(ival_make(-4, -3), R);
    cr_assert(iv_eq(r, 0, 0));
    r = ival_blend(ival_make(0.5, 1), R);
    ASSERT_TIGHT(r, powl(0.75L, 4), powl(1 - 0.0625L, 4), 1e-14, 0);
    r = ival_blend(ival_make(-INFINITY, INFINITY), R);
    cr_assert(iv_eq(r, 0, 1));
    /* at the point d = R exactly: 0 */
    r = ival_blend(ival_point(2), R);
    cr_assert(iv_eq(r, 0, 0));
}
