/* ival — interval arithmetic that never lies (the non-inline part).
 *
 * Rounding: every bound computed by an IEEE operation (+ - * / sqrt, all
 * correctly rounded) is widened by ival_widen(), >= 1 ulp outward (proof in
 * ival.h).  libm's transcendental functions are not correctly rounded: glibc
 * documents errors of 1-2 ulps for sin, cos, tan, exp, log, asin, acos, atan,
 * atan2 and pow in double on x86-64 and AArch64, and other libms are within a
 * few ulps too.  Their results are widened by IVAL_LIBM_ULPS (4) steps, each
 * >= 1 ulp, which covers an error of up to 3 ulps of the true result even
 * across a binade boundary.  The interval logic of sin/cos/tan also relies on
 * libm getting the *sign* of sin and cos right, which any implementation with
 * a bounded relative error does.
 *
 * Where the true range is known (sqrt >= 0, exp >= 0, |sin| <= 1, asin within
 * +-pi/2, ...) the widened bounds are clamped to it, with pi bounds taken as
 * the doubles just outside the true pi and pi/2.
 */
#include "ival.h"

#include <limits.h>
#include <math.h>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

_Static_assert(FLT_EVAL_METHOD == 0, "ival needs double evaluated in double");

#define IVAL_LIBM_ULPS 4

/* The doubles just above pi and pi/2 (M_PI and M_PI_2 are just below). */
#define IVAL_PI_UP 0x1.921fb54442d19p+1
#define IVAL_PI_2_UP 0x1.921fb54442d19p+0

#ifdef __SSE2__
/* The same IVAL_LIBM_ULPS ival_widen steps, both bounds in one SSE2 register
 * as (-lo, hi): ival_widen's lower bound is lo > DBL_MAX ? DBL_MAX : lo,
 * then lo - e(lo); negated that is max(-DBL_MAX, -lo) + e(-lo), the upper
 * bound's own formula (e depends on |.| only, negation is exact and
 * rounding to nearest is symmetric), so the bits are ival_widen's. */
static ival ival_widen_libm(ival a)
{
    const __m128d sign = _mm_set_pd(0.0, -0.0); /* flips lo only */
    __m128d v = _mm_xor_pd(_mm_set_pd(a.hi, a.lo), sign);
    for (int i = 0; i < IVAL_LIBM_ULPS; i++) {
        v = _mm_max_pd(_mm_set1_pd(-DBL_MAX), v); /* x < -DBL_MAX ? -DBL_MAX : x */
        __m128d e = _mm_mul_pd(_mm_set1_pd(IVAL_PHI_), _mm_andnot_pd(_mm_set1_pd(-0.0), v));
        e = _mm_add_pd(e, _mm_set1_pd(DBL_TRUE_MIN));
        v = _mm_add_pd(v, e);
    }
    v = _mm_xor_pd(v, sign);
    return (ival){_mm_cvtsd_f64(v), _mm_cvtsd_f64(_mm_unpackhi_pd(v, v))};
}
#else
static ival ival_widen_libm(ival a)
{
    for (int i = 0; i < IVAL_LIBM_ULPS; i++)
        a = ival_widen(a);
    return a;
}
#endif

static ival ival_clamp(ival a, double lo, double hi)
{
    if (a.lo < lo)
        a.lo = lo;
    if (a.hi > hi)
        a.hi = hi;
    return a;
}

static inline double ival_fmin_(double x, double y) { return x < y ? x : y; }
static inline double ival_fmax_(double x, double y) { return x > y ? x : y; }

static const ival ival_whole = {-INFINITY, INFINITY};

/* ------------------------------------------- multiplication, division */

ival ival_mul_special_(ival a, ival b)
{
    double p[4] = {a.lo * b.lo, a.lo * b.hi, a.hi * b.lo, a.hi * b.hi};
    double lo = INFINITY, hi = -INFINITY;

    if (ival_is_nan(a) || ival_is_nan(b))
        return ival_nan();
    for (int i = 0; i < 4; i++) {
        double v = isnan(p[i]) ? 0 : p[i]; /* 0 * inf: the limit 0 * y */
        lo = ival_fmin_(lo, v);
        hi = ival_fmax_(hi, v);
    }
    return ival_widen((ival){lo, hi});
}

/* Min and max of a/b over the four corners, for b not containing 0.  A corner
 * inf/inf is a limit point whose neighbours along the edges give 0 and inf,
 * so it is skipped (it is NaN only when every corner is, e.g. [inf]/[inf]). */
static ival ival_div_corners(ival a, ival b)
{
    double q[4] = {a.lo / b.lo, a.lo / b.hi, a.hi / b.lo, a.hi / b.hi};
    double lo = NAN, hi = NAN;

    for (int i = 0; i < 4; i++) {
        if (isnan(q[i]))
            continue;
        lo = isnan(lo) ? q[i] : ival_fmin_(lo, q[i]);
        hi = isnan(hi) ? q[i] : ival_fmax_(hi, q[i]);
    }
    return ival_widen((ival){lo, hi});
}

/* b = [0, h] with h > 0, or b = [l, 0] with l < 0: a half-line when a has
 * one sign, else the whole line. */
static ival ival_div_half(ival a, ival b)
{
    double q;

    if (b.lo == 0) { /* y in (0, h] */
        if (a.lo >= 0) {
            q = a.lo / b.hi;
            return ival_widen((ival){isnan(q) ? 0 : q, INFINITY});
        }
        if (a.hi <= 0) {
            q = a.hi / b.hi;
            return ival_widen((ival){-INFINITY, isnan(q) ? 0 : q});
        }
        return ival_whole;
    }
    /* y in [l, 0) */
    if (a.lo >= 0) {
        q = a.lo / b.lo;
        return ival_widen((ival){-INFINITY, isnan(q) ? 0 : q});
    }
    if (a.hi <= 0) {
        q = a.hi / b.lo;
        return ival_widen((ival){isnan(q) ? 0 : q, INFINITY});
    }
    return ival_whole;
}

ival ival_div_special_(ival a, ival b)
{
    if (ival_is_nan(a) || ival_is_nan(b))
        return ival_nan();
    if (b.lo > 0 || b.hi < 0)
        return ival_div_corners(a, b); /* an inf/inf corner */
    if (b.lo == 0 && b.hi == 0)
        return ival_whole;
    if (a.lo == 0 && a.hi == 0)
        return ival_point(0); /* 0/y = 0 for every y != 0 in b */
    if (b.lo == 0 || b.hi == 0)
        return ival_div_half(a, b);
    return ival_whole;
}

/* ---------------------------------------------------- sqrt, exp, log */

ival ival_sqrt(ival a)
{
    ival r;

    if (ival_is_nan(a) || a.hi < 0)
        return ival_nan();
    r = ival_widen((ival){sqrt(ival_fmax_(a.lo, 0)), sqrt(a.hi)});
    return ival_clamp(r, 0, INFINITY);
}

ival ival_exp(ival a)
{
    if (ival_is_nan(a))
        return ival_nan();
    return ival_clamp(ival_widen_libm((ival){exp(a.lo), exp(a.hi)}), 0,
                      INFINITY);
}

ival ival_log(ival a)
{
    double lo;

    if (ival_is_nan(a) || a.hi < 0)
        return ival_nan();
    lo = a.lo > 0 ? log(a.lo) : -INFINITY;
    return ival_widen_libm((ival){lo, log(a.hi)});
}

/* ---------------------------------------------------- sin, cos, tan */

/* Quadrant of x from the signs of sin x and cos x: 0 for angles in
 * [0, pi/2), 1 for [pi/2, pi), 2 for [pi, 3pi/2), 3 for [3pi/2, 2pi).
 * libm never returns an exact 0 for a nonzero double, and its sign is right
 * (bounded relative error), so this is exact. */
static int ival_quadrant(double s, double c)
{
    if (s >= 0)
        return c > 0 ? 0 : 1;
    return c < 0 ? 2 : 3;
}

/* Which quadrant boundaries the interval [lo, hi] (finite, hi - lo < 6.283)
 * crosses: bit k set when it contains an angle (k+1)*pi/2 (mod 2pi), i.e.
 * bit 0: pi/2 (sin max), bit 1: pi (cos min), bit 2: 3pi/2 (sin min),
 * bit 3: 0 (cos max).  s and c are sin and cos at both ends. */
static unsigned ival_crossings(double w, const double s[2], const double c[2])
{
    int q0 = ival_quadrant(s[0], c[0]);
    int q1 = ival_quadrant(s[1], c[1]);
    int m = (q1 - q0 + 4) % 4;
    unsigned bits = 0;

    /* Same quadrant: either no crossing (width < pi/2) or a full turn
     * (width > 3pi/2); pi splits the two with a wide margin. */
    if (m == 0 && w > M_PI)
        return 0xf;
    for (int i = 0; i < m; i++)
        bits |= 1u << ((q0 + i) % 4);
    return bits;
}

/* Width below which the quadrant count is unambiguous for sin/cos (< 2pi
 * with a margin far above the rounding of hi - lo). */
#define IVAL_TURN 6.283

static ival ival_sincos(ival a, bool want_cos)
{
    double s[2], c[2], w = a.hi - a.lo;
    unsigned bits;
    ival r;

    if (ival_is_nan(a))
        return ival_nan();
    if (!isfinite(a.lo) || !isfinite(a.hi) || !(w < IVAL_TURN))
        return ival_make(-1, 1);
    sincos(a.lo, &s[0], &c[0]);
    sincos(a.hi, &s[1], &c[1]);
    bits = ival_crossings(w, s, c);
    if (want_cos) {
        r = ival_widen_libm((ival){ival_fmin_(c[0], c[1]),
                                   ival_fmax_(c[0], c[1])});
        if (bits & 2u)
            r.lo = -1;
        if (bits & 8u)
            r.hi = 1;
    } else {
        r = ival_widen_libm((ival){ival_fmin_(s[0], s[1]),
                                   ival_fmax_(s[0], s[1])});
        if (bits & 1u)
            r.hi = 1;
        if (bits & 4u)
            r.lo = -1;
    }
    return ival_clamp(r, -1, 1);
}

ival ival_sin(ival a) { return ival_sincos(a, false); }
ival ival_cos(ival a) { return ival_sincos(a, true); }

ival ival_tan(ival a)
{
    double s[2], c[2], w = a.hi - a.lo;
    unsigned bits;

    if (ival_is_nan(a))
        return ival_nan();
    /* 3.14 < pi: a true width >= pi always lands here, and below it the
     * quadrant count cannot wrap. */
    if (!isfinite(a.lo) || !isfinite(a.hi) || !(w < 3.14))
        return ival_whole;
    sincos(a.lo, &s[0], &c[0]);
    sincos(a.hi, &s[1], &c[1]);
    bits = ival_crossings(w, s, c);
    if (bits & 5u) /* a pole pi/2 or 3pi/2 inside */
        return ival_whole;
    return ival_widen_libm((ival){tan(a.lo), tan(a.hi)});
}

/* ------------------------------------------------ asin, acos, atan */

ival ival_asin(ival a)
{
    ival r;

    if (ival_is_nan(a) || a.hi < -1 || a.lo > 1)
        return ival_nan();
    r = (ival){asin(ival_fmax_(a.lo, -1)), asin(ival_fmin_(a.hi, 1))};
    return ival_clamp(ival_widen_libm(r), -IVAL_PI_2_UP, IVAL_PI_2_UP);
}

ival ival_acos(ival a)
{
    ival r;

    if (ival_is_nan(a) || a.hi < -1 || a.lo > 1)
        return ival_nan();
    r = (ival){acos(ival_fmin_(a.hi, 1)), acos(ival_fmax_(a.lo, -1))};
    return ival_clamp(ival_widen_libm(r), 0, IVAL_PI_UP);
}

ival ival_atan(ival a)
{
    if (ival_is_nan(a))
        return ival_nan();
    return ival_clamp(ival_widen_libm((ival){atan(a.lo), atan(a.hi)}),
                      -IVAL_PI_2_UP, IVAL_PI_2_UP);
}

/* Off the closed ray {x <= 0, y = 0} atan2 is continuous, and the extreme
 * directions of a box that does not contain the origin are at its corners
 * (with C's atan2 giving the limit directions of infinite corners). */
ival ival_atan2(ival y, ival x)
{
    double t[4];
    ival r;

    if (ival_is_nan(y) || ival_is_nan(x))
        return ival_nan();
    if (x.lo <= 0 && y.lo <= 0 && y.hi >= 0)
        return ival_make(-IVAL_PI_UP, IVAL_PI_UP);
    t[0] = atan2(y.lo, x.lo);
    t[1] = atan2(y.lo, x.hi);
    t[2] = atan2(y.hi, x.lo);
    t[3] = atan2(y.hi, x.hi);
    r.lo = ival_fmin_(ival_fmin_(t[0], t[1]), ival_fmin_(t[2], t[3]));
    r.hi = ival_fmax_(ival_fmax_(t[0], t[1]), ival_fmax_(t[2], t[3]));
    return ival_clamp(ival_widen_libm(r), -IVAL_PI_UP, IVAL_PI_UP);
}

ival ival_theta(ival x, ival y) { return ival_atan2(y, x); }

/* ------------------------------------------------------------- powers */

/* Exponents up to this use a chain of products, each widened outward; the
 * guard compounds along the chain (relative error ~ n ulps), so larger ones
 * use libm's pow (a few ulps whatever n) and the libm widening. */
#define IVAL_POW_CHAIN_MAX 8u

/* x^n for x >= 0, n >= 1, rounded outward in direction dir (-1 down, +1 up).
 * A chain of products each rounded outward in the same direction bounds
 * x^n because multiplication of nonnegatives is monotone. */
static double ival_pow_mag(double x, unsigned n, int dir)
{
    double r = x;
    ival p;

    if (n > IVAL_POW_CHAIN_MAX) {
        p = ival_widen_libm(ival_point(pow(x, (double)n)));
        return dir < 0 ? ival_fmax_(p.lo, 0) : p.hi;
    }
    for (unsigned i = 1; i < n; i++) {
        p = ival_widen(ival_point(r * x));
        r = dir < 0 ? ival_fmax_(p.lo, 0) : p.hi;
    }
    return r;
}

/* x^n with the sign of x kept (odd n), rounded in direction dir. */
static double ival_pow_odd(double x, unsigned n, int dir)
{
    if (x >= 0)
        return ival_pow_mag(x, n, dir);
    return -ival_pow_mag(-x, n, -dir);
}

static ival ival_powu(ival a, unsigned n)
{
    ival m;

    if (n == 1)
        return a;
    if (n == 2)
        return ival_sqr(a);
    if (n & 1u)
        return (ival){ival_pow_odd(a.lo, n, -1), ival_pow_odd(a.hi, n, 1)};
    m = ival_abs(a);
    return (ival){ival_pow_mag(m.lo, n, -1), ival_pow_mag(m.hi, n, 1)};
}

ival ival_powi(ival a, int n)
{
    unsigned un;

    if (ival_is_nan(a))
        return ival_nan();
    if (n == 0)
        return ival_point(1);
    /* |n| without overflow for INT_MIN */
    un = n > 0 ? (unsigned)n : 0u - (unsigned)n;
    if (n > 0)
        return ival_powu(a, un);
    return ival_div(ival_point(1), ival_powu(a, un));
}

/* Hull of C's pow over x in [a] (a >= 0) and y in [b]: x^y = exp(y ln x)
 * and y ln x is bilinear in (y, ln x), so the extremes are at corners
 * (pow's special cases 0^0 = 1^inf = inf^0 = 1 are the limits 0 * inf = 0
 * of the exponent, as in ival_mul). */
static ival ival_pow_corners(ival a, ival b)
{
    double lo = a.lo <= 0 ? 0 : a.lo; /* no -0: pow(-0, -1) = -inf */
    double t[4] = {pow(lo, b.lo), pow(lo, b.hi), pow(a.hi, b.lo),
                   pow(a.hi, b.hi)};
    ival r;

    r.lo = ival_fmin_(ival_fmin_(t[0], t[1]), ival_fmin_(t[2], t[3]));
    r.hi = ival_fmax_(ival_fmax_(t[0], t[1]), ival_fmax_(t[2], t[3]));
    return ival_clamp(ival_widen_libm(r), 0, INFINITY);
}

static ival ival_hull(ival a, ival b)
{
    if (ival_is_nan(a))
        return b;
    if (ival_is_nan(b))
        return a;
    return (ival){ival_fmin_(a.lo, b.lo), ival_fmax_(a.hi, b.hi)};
}

/* pow(x, y) for x < 0 in an (an.hi <= 0) is defined only at integer y. */
static ival ival_pow_negative(ival an, ival b)
{
    double k0 = ceil(b.lo), k1 = floor(b.hi);
    ival mag;

    if (k0 > k1)
        return ival_nan(); /* no integer in b */
    if (k0 == k1) {
        if (fabs(k0) <= INT_MAX)
            return ival_powi(an, (int)k0);
        /* beyond int: |x|^k, negated for odd k */
        mag = ival_pow_corners(ival_abs(an), ival_point(k0));
        return fmod(k0, 2) == 0 ? mag : ival_neg(mag);
    }
    /* several integers of both parities: +-|x|^k */
    mag = ival_pow_corners(ival_abs(an), ival_make(k0, k1));
    return (ival){-mag.hi, mag.hi};
}

ival ival_pow(ival a, ival b)
{
    ival r = ival_nan();

    if (ival_is_nan(a) || ival_is_nan(b))
        return ival_nan();
    if (b.lo == b.hi && b.lo == trunc(b.lo) && fabs(b.lo) <= INT_MAX)
        return ival_powi(a, (int)b.lo);
    if (a.hi >= 0)
        r = ival_pow_corners(ival_make(ival_fmax_(a.lo, 0), a.hi), b);
    if (a.lo < 0)
        r = ival_hull(r, ival_pow_negative(
                             ival_make(a.lo, ival_fmin_(a.hi, 0)), b));
    return r;
}

/* ------------------------------------------------------------- blend */

/* Bound of (1 - (d/R)^2)^4 for |d| = d < R = R, side -1 lower / +1 upper. */
static double ival_blend_at(double d, double R, int side)
{
    ival u = ival_div(ival_sqr(ival_point(d)), ival_sqr(ival_point(R)));
    ival w = ival_clamp(ival_sub(ival_point(1), u), 0, 1);
    ival g = ival_powu(w, 4);

    return side < 0 ? g.lo : g.hi;
}

/* g is a non-increasing function of |d| (1 at 0, 0 from |d| = R on) and
 * non-decreasing in R > 0, so its range over the box is
 * [g(max|d|, min R), g(min|d|, max R)]. */
ival ival_blend(ival d, ival R)
{
    ival ad, r;

    if (ival_is_nan(d) || ival_is_nan(R))
        return ival_nan();
    if (R.lo <= 0)
        return ival_make(0, 1);
    ad = ival_abs(d);
    r.lo = ad.hi >= R.lo ? 0 : ival_blend_at(ad.hi, R.lo, -1);
    r.hi = ad.lo >= R.hi ? 0 : ival_blend_at(ad.lo, R.hi, 1);
    return ival_clamp(r, 0, 1);
}

/* ---------------------------------------------- spherical coordinates */

ival ival_r(ival x, ival y, ival z)
{
    return ival_sqrt(ival_add(ival_add(ival_sqr(x), ival_sqr(y)),
                              ival_sqr(z)));
}

/* An enclosure of z / sqrt(p + z^2) for the point z and rho^2 = p. */
static ival ival_cosphi(double z, double p)
{
    ival zz = ival_point(z);

    return ival_div(zz, ival_sqrt(ival_add(ival_point(p), ival_sqr(zz))));
}

/* Upper bound of g = z / sqrt(rho^2 + z^2) at z = zh, over rho^2 in [P]:
 * for z > 0 g falls with rho (take the least rho^2), for z < 0 it rises
 * (take the largest).  Used with z -> -z for the lower bound. */
static double ival_cosphi_max(double zh, ival P)
{
    double g;

    if (zh == 0)
        return 0;
    if (zh > 0) {
        if (P.lo <= 0 || isinf(zh))
            return 1;
        g = ival_cosphi(zh, P.lo).hi;
        return isnan(g) ? 1 : ival_fmin_(g, 1);
    }
    g = ival_cosphi(zh, P.hi).hi;
    return isnan(g) ? 0 : ival_fmax_(g, -1);
}

/* phi = acos(z / r) is decreasing in g = z / r, which is increasing in z,
 * and (z, rho = |(x,y)|) ranges over the product [z] x [rho] of the box. */
ival ival_phi(ival x, ival y, ival z)
{
    ival P;
    double gmax, gmin;

    if (ival_is_nan(x) || ival_is_nan(y) || ival_is_nan(z))
        return ival_nan();
    P = ival_add(ival_sqr(x), ival_sqr(y));
    if (P.lo <= 0 && z.lo <= 0 && z.hi >= 0)
        return ival_make(0, IVAL_PI_UP); /* the origin: every direction */
    gmax = ival_cosphi_max(z.hi, P);
    gmin = -ival_cosphi_max(-z.lo, P);
    return ival_acos(ival_make(gmin, gmax));
}
