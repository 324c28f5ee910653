/* ival against long-double point evaluation: every point of the argument
 * intervals (endpoints, their inward neighbours, random interior points, special
 * points) must map inside the interval result; random expression trees likewise;
 * tightness, so that a lazy [-inf, inf] fails; the rounding guard against
 * error-free transformations.  Targeted edge cases: test_ival_edges.c. */
#include <criterion/criterion.h>
#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include "ival.h"

#include "ival_fixture.h"

/* ------------------------------------------------------------ helpers */

static uint64_t rng_state;

static void rng_seed(uint64_t s) { rng_state = s * 0x9e3779b97f4a7c15ull + 1; }

static uint64_t rng_u64(void)
{
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return rng_state * 0x2545f4914f6cdd1dull;
}

static double rng_unit(void) { return (double)(rng_u64() >> 11) * 0x1p-53; }

static int rng_int(int n) { return (int)(rng_u64() % (uint64_t)n); }

static double rng_range(double a, double b) { return a + (b - a) * rng_unit(); }

static double rng_sign(void) { return rng_u64() & 1 ? 1.0 : -1.0; }

/* A random double of any magnitude. */
static double rand_magnitude(void)
{
    return rng_sign() * pow(10.0, rng_range(-20, 20));
}

/* Random interval of one of several shapes. */
static ival rand_ival(void)
{
    double c, w, a, b;
    int k;

    switch (rng_int(11)) {
    case 0: /* small */
        c = rng_range(-4, 4);
        w = pow(10.0, rng_range(-12, 0.5));
        return ival_make(c - w * rng_unit(), c + w * rng_unit());
    case 1: /* wide */
        a = rng_range(-1e6, 1e6), b = rng_range(-1e6, 1e6);
        return ival_make(fmin(a, b), fmax(a, b));
    case 2: /* straddling zero */
        w = pow(10.0, rng_range(-6, 3));
        return ival_make(-w * rng_unit(), w * rng_unit());
    case 3: /* near a multiple of pi/2 */
        k = rng_int(17) - 8;
        c = k * M_PI_2;
        w = pow(10.0, rng_range(-16, -1));
        return ival_make(c - w * rng_unit(), c + w * rng_unit());
    case 4: /* near +-1 or 0 (asin/acos/log/sqrt domains) */
        c = (double)(rng_int(3) - 1);
        w = pow(10.0, rng_range(-16, 0));
        return ival_make(c - w * rng_unit(), c + w * rng_unit());
    case 5: /* huge */
        a = rng_sign() * pow(10.0, rng_range(15, 308));
        b = rng_u64() & 1 ? a * rng_range(1, 10) : rng_sign() * DBL_MAX;
        if (!isfinite(b))
            b = a;
        return ival_make(fmin(a, b), fmax(a, b));
    case 6: /* infinite end(s) */
        a = rand_magnitude();
        switch (rng_int(3)) {
        case 0:
            return ival_make(-INFINITY, a);
        case 1:
            return ival_make(a, INFINITY);
        default:
            return ival_make(-INFINITY, INFINITY);
        }
    case 7: /* point */
        a = rng_u64() & 1 ? rng_range(-10, 10) : rand_magnitude();
        return ival_point(a);
    case 8: /* a zero end */
        a = rand_magnitude();
        return a > 0 ? ival_make(0, a) : ival_make(a, 0);
    case 9: /* tiny, subnormal */
        a = rng_sign() * pow(10.0, rng_range(-322, -290));
        b = rng_sign() * pow(10.0, rng_range(-322, -290));
        return ival_make(fmin(a, b), fmax(a, b));
    default: /* general */
        a = rand_magnitude(), b = rand_magnitude();
        return ival_make(fmin(a, b), fmax(a, b));
    }
}

#define MAX_SAMPLES 32

/* Points of a: both ends, their inward neighbours, interior points, 0 and
 * multiples of pi/2 when inside. */
static int samples(ival a, double *s)
{
    int n = 0;
    double lo = a.lo, hi = a.hi;

    s[n++] = lo;
    s[n++] = hi;
    s[n++] = nextafter(lo, hi);
    s[n++] = nextafter(hi, lo);
    for (int i = 0; i < 10; i++) {
        double t = rng_unit(), v;
        if (isinf(lo) || isinf(hi))
            v = isinf(lo) && isinf(hi) ? rand_magnitude()
                : isinf(lo)            ? hi - fabs(rand_magnitude())
                                       : lo + fabs(rand_magnitude());
        else
            v = lo * (1 - t) + hi * t;
        if (v >= lo && v <= hi)
            s[n++] = v;
    }
    if (lo <= 0 && hi >= 0)
        s[n++] = 0;
    /* integers (pow of negative bases is defined only there) */
    if (isfinite(lo) && isfinite(hi) && fabs(lo) < 1e15)
        for (double k = ceil(lo); k <= hi && k < ceil(lo) + 3; k++)
            s[n++] = k;
    /* critical points of sin/cos/tan near the interval */
    if (isfinite(lo) && isfinite(hi) && hi - lo < 100 && fabs(lo) < 1e6) {
        double k0 = ceil(lo / M_PI_2) - 1;
        for (int i = 0; i < 4 && n < MAX_SAMPLES; i++) {
            double v = (k0 + i) * M_PI_2;
            for (int j = -1; j <= 1 && n < MAX_SAMPLES; j++) {
                double w = j < 0 ? nextafter(v, -INFINITY)
                         : j > 0 ? nextafter(v, INFINITY) : v;
                if (w >= lo && w <= hi)
                    s[n++] = w;
            }
        }
    }
    return n;
}

static void fail_unary(const char *name, ival a, ival r, double x, ld v)
{
    cr_assert_fail("%s([%a, %a]) = [%a, %a] misses f(%a) = %La", name, a.lo,
                   a.hi, r.lo, r.hi, x, v);
}

/* ------------------------------------------------------------ oracles */

static ld ld_neg(ld x) { return -x; }

static ld ld_sqr(ld x) { return x * x; }

static ld ld_abs(ld x) { return fabsl(x); }

static ld ld_sqrt(ld x) { return sqrtl(x); }

static ld ld_exp(ld x) { return expl(x); }

static ld ld_log(ld x) { return logl(x); }

static ld ld_sin(ld x) { return sinl(x); }

static ld ld_cos(ld x) { return cosl(x); }

static ld ld_tan(ld x) { return tanl(x); }

static ld ld_asin(ld x) { return asinl(x); }

static ld ld_acos(ld x) { return acosl(x); }

static ld ld_atan(ld x) { return atanl(x); }

static ld ld_add(ld x, ld y) { return x + y; }

static ld ld_sub(ld x, ld y) { return x - y; }

static ld ld_mul(ld x, ld y) { return x * y; }

static ld ld_div(ld x, ld y) { return y == 0 ? NAN : x / y; } /* pole */

static ld ld_min(ld x, ld y) { return fminl(x, y); }

static ld ld_max(ld x, ld y) { return fmaxl(x, y); }

static ld ld_atan2(ld y, ld x) { return atan2l(y, x); }

static ld ld_theta(ld x, ld y) { return atan2l(y, x); }

/* NaN where a NaN enters (C's pow(NaN, 0) = 1 would hide it), at the pole
 * x = 0, y < 0, and at x = -inf with y not an integer (C gives a value by
 * convention, but x^y is defined at no negative x there). */
static ld ld_pow(ld x, ld y)
{
    if (isnan(x) || isnan(y) || (x == 0 && y < 0))
        return NAN;
    if (x == -INFINITY && y != truncl(y))
        return NAN;
    return powl(x, y);
}

static ld ld_powi(ld x, int n)
{
    if (isnan(x) || (x == 0 && n < 0))
        return NAN; /* NaN in, or the pole */
    return powl(x, n);
}

/* (d^2 - R^2)^4 / R^8 for |d| <= R, else 0, straight from the definition */
static ld ld_blend(ld d, ld R)
{
    ld s, r2;

    if (isnan(d))
        return NAN;
    if (!(fabsl(d) <= R))
        return 0;
    s = d * d - R * R;
    s = s * s;
    r2 = R * R;
    r2 = r2 * r2;
    return (s * s) / (r2 * r2);
}

static ld ld_r(ld x, ld y, ld z) { return sqrtl(x * x + y * y + z * z); }

static ld ld_phi(ld x, ld y, ld z) { return acosl(z / ld_r(x, y, z)); }

/* Wrappers of the inline ops (function pointers). */
static ival iv_neg(ival a) { return ival_neg(a); }

static ival iv_sqr(ival a) { return ival_sqr(a); }

static ival iv_abs(ival a) { return ival_abs(a); }

static ival iv_add(ival a, ival b) { return ival_add(a, b); }

static ival iv_sub(ival a, ival b) { return ival_sub(a, b); }

static ival iv_mul(ival a, ival b) { return ival_mul(a, b); }

static ival iv_min(ival a, ival b) { return ival_min(a, b); }

static ival iv_max(ival a, ival b) { return ival_max(a, b); }

/* Every non-NaN f(x), x in a, lies in the result; a NaN result only where
 * f is defined at no sample. */
static void check_unary_on(const char *name, un_iv fi, un_ld fl, ival a)
{
    double s[MAX_SAMPLES];
    int n = samples(a, s);
    ival r = fi(a);

    cr_assert(ival_is_nan(r) || r.lo <= r.hi, "%s: lo > hi", name);
    for (int i = 0; i < n; i++) {
        ld v = fl(s[i]);
        if (isnan(v))
            continue;
        if (!in_iv(r, v))
            fail_unary(name, a, r, s[i], v);
    }
}

static void check_unary(const char *name, un_iv fi, un_ld fl, uint64_t seed)
{
    rng_seed(seed);
    for (int k = 0; k < 8000; k++)
        check_unary_on(name, fi, fl, rand_ival());
}

static void check_binary_on(const char *name, bin_iv fi, bin_ld fl, ival a,
                            ival b)
{
    double sa[MAX_SAMPLES], sb[MAX_SAMPLES];
    int na = samples(a, sa), nb = samples(b, sb);
    ival r = fi(a, b);

    cr_assert(ival_is_nan(r) || r.lo <= r.hi, "%s: lo > hi", name);
    for (int i = 0; i < na; i++)
        for (int j = 0; j < nb; j++) {
            ld v = fl(sa[i], sb[j]);
            if (isnan(v) || in_iv(r, v))
                continue;
            cr_assert_fail("%s([%a, %a], [%a, %a]) = [%a, %a] misses "
                           "f(%a, %a) = %La",
                           name, a.lo, a.hi, b.lo, b.hi, r.lo, r.hi, sa[i],
                           sb[j], v);
        }
}

static void check_binary(const char *name, bin_iv fi, bin_ld fl,
                         uint64_t seed)
{
    rng_seed(seed);
    for (int k = 0; k < 3000; k++)
        check_binary_on(name, fi, fl, rand_ival(), rand_ival());
}

Test(ival_props, unary_functions_enclose_every_point)
{
    check_unary("neg", iv_neg, ld_neg, 1);
    check_unary("sqr", iv_sqr, ld_sqr, 2);
    check_unary("abs", iv_abs, ld_abs, 3);
    check_unary("sqrt", ival_sqrt, ld_sqrt, 4);
    check_unary("exp", ival_exp, ld_exp, 5);
    check_unary("log", ival_log, ld_log, 6);
    check_unary("atan", ival_atan, ld_atan, 7);
    check_unary("asin", ival_asin, ld_asin, 8);
    check_unary("acos", ival_acos, ld_acos, 9);
}

Test(ival_props, trig_functions_enclose_every_point)
{
    check_unary("sin", ival_sin, ld_sin, 11);
    check_unary("cos", ival_cos, ld_cos, 12);
    check_unary("tan", ival_tan, ld_tan, 13);
}

Test(ival_props, arithmetic_encloses_every_point)
{
    check_binary("add", iv_add, ld_add, 21);
    check_binary("sub", iv_sub, ld_sub, 22);
    check_binary("mul", iv_mul, ld_mul, 23);
    check_binary("div", ival_div, ld_div, 24);
}

Test(ival_props, binary_functions_enclose_every_point)
{
    check_binary("min", iv_min, ld_min, 31);
    check_binary("max", iv_max, ld_max, 32);
    check_binary("atan2", ival_atan2, ld_atan2, 33);
    check_binary("theta", ival_theta, ld_theta, 34);
}

/* Tightness on random finite intervals inside the domain: a monotone f has
 * its range at the ends, and the result must be within ~1e-14 of it (a few
 * ulps), so that a lazy enclosure fails. */
static void check_tight_unary(const char *name, un_iv fi, un_ld fl, double dlo,
                              double dhi, uint64_t seed)
{
    rng_seed(seed);
    for (int k = 0; k < 4000; k++) {
        ival a = rand_ival(), r;
        ld f0, f1, lo, hi;

        if (!(a.lo >= dlo && a.hi <= dhi && isfinite(a.lo) && isfinite(a.hi)))
            continue;
        f0 = fl(a.lo), f1 = fl(a.hi);
        lo = fminl(f0, f1), hi = fmaxl(f0, f1);
        if (!(fabsl(lo) <= DBL_MAX / 4 && fabsl(hi) <= DBL_MAX / 4))
            continue;
        r = fi(a);
        if (!near(r.lo, lo, 1e-14, 1e-300) || !near(r.hi, hi, 1e-14, 1e-300))
            cr_assert_fail("%s([%a, %a]) = [%a, %a], true [%La, %La]", name,
                           a.lo, a.hi, r.lo, r.hi, lo, hi);
    }
}

static void check_tight_binary(const char *name, bin_iv fi, bin_ld fl,
                               bool nonzero_b, uint64_t seed)
{
    rng_seed(seed);
    for (int k = 0; k < 4000; k++) {
        ival a = rand_ival(), b = rand_ival(), r;
        ld c[4], lo, hi;

        if (!isfinite(a.lo) || !isfinite(a.hi) || !isfinite(b.lo) ||
            !isfinite(b.hi) || (nonzero_b && ival_contains_zero(b)))
            continue;
        c[0] = fl(a.lo, b.lo), c[1] = fl(a.lo, b.hi);
        c[2] = fl(a.hi, b.lo), c[3] = fl(a.hi, b.hi);
        lo = fminl(fminl(c[0], c[1]), fminl(c[2], c[3]));
        hi = fmaxl(fmaxl(c[0], c[1]), fmaxl(c[2], c[3]));
        /* near DBL_MAX one ulp outward is infinity */
        if (!(fabsl(lo) <= DBL_MAX / 4 && fabsl(hi) <= DBL_MAX / 4))
            continue;
        r = fi(a, b);
        if (!near(r.lo, lo, 1e-15, 1e-300) || !near(r.hi, hi, 1e-15, 1e-300))
            cr_assert_fail("%s([%a, %a], [%a, %a]) = [%a, %a], true [%La, %La]",
                           name, a.lo, a.hi, b.lo, b.hi, r.lo, r.hi, lo, hi);
    }
}

Test(ival_props, results_are_tight)
{
    check_tight_unary("exp", ival_exp, ld_exp, -INFINITY, INFINITY, 101);
    check_tight_unary("log", ival_log, ld_log, DBL_MIN, INFINITY, 102);
    check_tight_unary("sqrt", ival_sqrt, ld_sqrt, 0, INFINITY, 103);
    check_tight_unary("atan", ival_atan, ld_atan, -INFINITY, INFINITY, 104);
    check_tight_unary("asin", ival_asin, ld_asin, -1, 1, 105);
    check_tight_unary("acos", ival_acos, ld_acos, -1, 1, 106);
    check_tight_unary("sin", ival_sin, ld_sin, 0.01, 1.5, 107);
    check_tight_unary("cos", ival_cos, ld_cos, 0.01, 3.1, 108);
    check_tight_unary("tan", ival_tan, ld_tan, -1.5, 1.5, 109);
    check_tight_unary("sqr", iv_sqr, ld_sqr, 0, INFINITY, 110);
    check_tight_binary("add", iv_add, ld_add, false, 111);
    check_tight_binary("sub", iv_sub, ld_sub, false, 112);
    check_tight_binary("mul", iv_mul, ld_mul, false, 113);
    check_tight_binary("div", ival_div, ld_div, true, 114);
}

/* Exponent intervals for pow: point integers, point non-integers, intervals
 * with and without integers inside, some beyond int. */
static ival rand_exponent(void)
{
    double a;

    switch (rng_int(5)) {
    case 0:
        return ival_point(rng_int(13) - 6);
    case 1:
        return ival_point(rng_range(-5, 5));
    case 2:
        a = rng_range(-5, 5);
        return ival_make(a, a + rng_range(0, 3));
    case 3:
        a = rng_range(-5, 5);
        return ival_make(a, a + rng_range(0, 0.3));
    default:
        return ival_point(rng_sign() * (double)(1ll << 40) + rng_int(2));
    }
}

Test(ival_props, pow_and_powi_enclose_every_point)
{
    rng_seed(41);
    for (int k = 0; k < 1500; k++) {
        ival a = rand_ival(), b = rand_exponent();
        check_binary_on("pow", ival_pow, ld_pow, a, b);
    }
    for (int n = -9; n <= 9; n++) {
        rng_seed(42 + (uint64_t)n);
        for (int k = 0; k < 300; k++) {
            ival a = rand_ival(), r = ival_powi(a, n);
            double s[MAX_SAMPLES];
            int m = samples(a, s);
            for (int i = 0; i < m; i++) {
                ld v = ld_powi(s[i], n);
                if (!isnan(v) && !in_iv(r, v))
                    cr_assert_fail("powi([%a, %a], %d) = [%a, %a] misses %La"
                                   " at %a", a.lo, a.hi, n, r.lo, r.hi, v, s[i]);
            }
        }
    }
}

Test(ival_props, blend_encloses_every_point)
{
    rng_seed(51);
    for (int k = 0; k < 1500; k++) {
        double R = pow(10.0, rng_range(-3, 3));
        ival Ri = rng_int(4) ? ival_point(R) : ival_make(R, R * rng_range(1, 2));
        ival d;
        if (rng_int(2)) {
            double c = rng_sign() * R * rng_range(0, 1.5);
            double w = R * pow(10.0, rng_range(-12, 0.5));
            d = ival_make(c - w * rng_unit(), c + w * rng_unit());
        } else {
            d = rand_ival();
        }
        check_binary_on("blend", ival_blend, ld_blend, d, Ri);
    }
}

/* r, theta, phi on random boxes, some placed around the axes and origin. */
static ival rand_coord(void)
{
    double w;

    switch (rng_int(4)) {
    case 0: /* around 0 */
        w = pow(10.0, rng_range(-8, 1));
        return ival_make(-w * rng_unit(), w * rng_unit());
    case 1: /* one side of 0, touching it */
        w = pow(10.0, rng_range(-8, 1));
        return rng_int(2) ? ival_make(0, w) : ival_make(-w, 0);
    default:
        return rand_ival();
    }
}

Test(ival_props, spherical_coordinates_enclose_every_point)
{
    rng_seed(61);
    for (int k = 0; k < 700; k++) {
        ival x = rand_coord(), y = rand_coord(), z = rand_coord();
        ival r = ival_r(x, y, z), p = ival_phi(x, y, z);
        double sx[MAX_SAMPLES], sy[MAX_SAMPLES], sz[MAX_SAMPLES];
        int nx = samples(x, sx), ny = samples(y, sy), nz = samples(z, sz);

        for (int i = 0; i < nx; i += 2)
            for (int j = 0; j < ny; j += 2)
                for (int l = 0; l < nz; l += 2) {
                    ld vr = ld_r(sx[i], sy[j], sz[l]);
                    ld vp = ld_phi(sx[i], sy[j], sz[l]);
                    if (!isnan(vr) && !in_iv(r, vr))
                        cr_assert_fail("r misses %La at (%a,%a,%a)", vr, sx[i],
                                       sy[j], sz[l]);
                    if (!isnan(vp) && !in_iv(p, vp))
                        cr_assert_fail("phi([%a,%a],[%a,%a],[%a,%a]) = [%a,%a]"
                                       " misses %La at (%a,%a,%a)",
                                       x.lo, x.hi, y.lo, y.hi, z.lo, z.hi,
                                       p.lo, p.hi, vp, sx[i], sy[j], sz[l]);
                }
        cr_assert(ival_is_nan(p) || (p.lo >= 0 && p.hi <= 3.2));
    }
}

/* ------------------------------------------------- random expression trees */

enum {
    T_X, T_Y, T_Z, T_CONST,                          /* leaves */
    T_NEG, T_SQR, T_SQRT, T_ABS, T_EXP, T_LOG, T_SIN, T_COS, T_TAN, T_ASIN,
    T_ACOS, T_ATAN, T_POWI,                          /* unary */
    T_ADD, T_SUB, T_MUL, T_DIV, T_MIN, T_MAX, T_POW, T_ATAN2, T_BLEND,
                                                     /* binary */
    T_R, T_THETA, T_PHI,                             /* spherical */
    T_COUNT
};

#define T_FIRST_UNARY T_NEG

#define T_FIRST_BINARY T_ADD

typedef struct {
    int op, kid[3];
    double c; /* constant, powi exponent, blend radius */
} tnode;

#define TREE_MAX 128

typedef struct {
    tnode n[TREE_MAX];
    int count;
} tree;

static int tree_gen(tree *t, int depth)
{
    int i = t->count++, op;
    tnode *n = &t->n[i];

    if (depth == 0 || rng_int(5) == 0)
        op = rng_int(4);
    else
        op = T_FIRST_UNARY + rng_int(T_COUNT - T_FIRST_UNARY);
    n->op = op;
    n->c = op == T_CONST ? rng_range(-3, 3)
         : op == T_POWI  ? rng_int(9) - 4
         : op == T_BLEND ? rng_range(0.2, 4)
                         : 0;
    if (op < T_FIRST_UNARY)
        return i;
    n->kid[0] = tree_gen(t, depth - 1);
    if (op >= T_FIRST_BINARY && op != T_BLEND)
        n->kid[1] = tree_gen(t, depth - 1);
    if (op == T_R || op == T_PHI)
        n->kid[2] = tree_gen(t, depth - 1);
    return i;
}

static ival tree_iv(const tree *t, int i, const ival v[3])
{
    const tnode *n = &t->n[i];
    ival a, b, c;

    if (n->op <= T_Z)
        return v[n->op];
    if (n->op == T_CONST)
        return ival_point(n->c);
    a = tree_iv(t, n->kid[0], v);
    if (n->op >= T_FIRST_BINARY && n->op != T_BLEND)
        b = tree_iv(t, n->kid[1], v);
    if (n->op == T_R || n->op == T_PHI)
        c = tree_iv(t, n->kid[2], v);
    switch (n->op) {
    case T_NEG: return ival_neg(a);
    case T_SQR: return ival_sqr(a);
    case T_SQRT: return ival_sqrt(a);
    case T_ABS: return ival_abs(a);
    case T_EXP: return ival_exp(a);
    case T_LOG: return ival_log(a);
    case T_SIN: return ival_sin(a);
    case T_COS: return ival_cos(a);
    case T_TAN: return ival_tan(a);
    case T_ASIN: return ival_asin(a);
    case T_ACOS: return ival_acos(a);
    case T_ATAN: return ival_atan(a);
    case T_POWI: return ival_powi(a, (int)n->c);
    case T_ADD: return ival_add(a, b);
    case T_SUB: return ival_sub(a, b);
    case T_MUL: return ival_mul(a, b);
    case T_DIV: return ival_div(a, b);
    case T_MIN: return ival_min(a, b);
    case T_MAX: return ival_max(a, b);
    case T_POW: return ival_pow(a, b);
    case T_ATAN2: return ival_atan2(a, b);
    case T_BLEND: return ival_blend(a, ival_point(n->c));
    case T_R: return ival_r(a, b, c);
    case T_THETA: return ival_theta(a, b);
    default: return ival_phi(a, b, c);
    }
}

/* The point value; NaN where undefined or at a pole (skipped). */
static ld tree_ld(const tree *t, int i, const ld v[3])
{
    const tnode *n = &t->n[i];
    ld a, b = 0, c = 0;

    if (n->op <= T_Z)
        return v[n->op];
    if (n->op == T_CONST)
        return n->c;
    a = tree_ld(t, n->kid[0], v);
    if (n->op >= T_FIRST_BINARY && n->op != T_BLEND)
        b = tree_ld(t, n->kid[1], v);
    if (n->op == T_R || n->op == T_PHI)
        c = tree_ld(t, n->kid[2], v);
    switch (n->op) {
    case T_NEG: return -a;
    case T_SQR: return a * a;
    case T_SQRT: return sqrtl(a);
    case T_ABS: return fabsl(a);
    case T_EXP: return expl(a);
    case T_LOG: return logl(a);
    case T_SIN: return sinl(a);
    case T_COS: return cosl(a);
    case T_TAN: return tanl(a);
    case T_ASIN: return asinl(a);
    case T_ACOS: return acosl(a);
    case T_ATAN: return atanl(a);
    case T_POWI: return ld_powi(a, (int)n->c);
    case T_ADD: return a + b;
    case T_SUB: return a - b;
    case T_MUL: return a * b;
    case T_DIV: return ld_div(a, b);
    case T_MIN: return isnan(a) || isnan(b) ? NAN : fminl(a, b);
    case T_MAX: return isnan(a) || isnan(b) ? NAN : fmaxl(a, b);
    case T_POW: return ld_pow(a, b);
    case T_ATAN2: return atan2l(a, b);
    case T_BLEND: return ld_blend(a, n->c);
    case T_R: return ld_r(a, b, c);
    case T_THETA: return atan2l(b, a);
    default: return ld_phi(a, b, c);
    }
}

static void tree_dump(const tree *t, int i, const ival v[3], const ld p[3],
                      int ind)
{
    const tnode *n = &t->n[i];
    ival r = tree_iv(t, i, v);
    fprintf(stderr, "%*sop %d c %g: [%a, %a] pt %La\n", ind, "", n->op, n->c,
            r.lo, r.hi, tree_ld(t, i, p));
    if (n->op < T_FIRST_UNARY)
        return;
    tree_dump(t, n->kid[0], v, p, ind + 2);
    if (n->op >= T_FIRST_BINARY && n->op != T_BLEND)
        tree_dump(t, n->kid[1], v, p, ind + 2);
    if (n->op == T_R || n->op == T_PHI)
        tree_dump(t, n->kid[2], v, p, ind + 2);
}

static ival rand_box_side(void)
{
    double c = rng_range(-3, 3), w = pow(10.0, rng_range(-6, 0.7));

    if (rng_int(4) == 0)
        return ival_make(-w * rng_unit(), w * rng_unit()); /* around 0 */
    return ival_make(c - w * rng_unit(), c + w * rng_unit());
}

Test(ival_props, random_expression_trees_enclose_every_point)
{
    static tree t;
    int checked = 0;

    rng_seed(71);
    for (int k = 0; k < 2000; k++) {
        t.count = 0;
        tree_gen(&t, 1 + rng_int(5));
        for (int b = 0; b < 6; b++) {
            ival box[3] = {rand_box_side(), rand_box_side(), rand_box_side()};
            ival r = tree_iv(&t, 0, box);
            for (int s = 0; s < 12; s++) {
                ld p[3];
                for (int d = 0; d < 3; d++) {
                    double u = s < 8 ? (double)((s >> d) & 1) : rng_unit();
                    p[d] = box[d].lo * (1 - u) + box[d].hi * u;
                    if (p[d] > box[d].hi)
                        p[d] = box[d].hi;
                }
                ld v = tree_ld(&t, 0, p);
                if (isnan(v))
                    continue;
                checked++;
                if (in_iv(r, v))
                    continue;
                tree_dump(&t, 0, box, p, 0);
                cr_assert_fail("tree %d box %d: [%a, %a] misses %La at "
                               "(%La, %La, %La)", k, b, r.lo, r.hi, v, p[0],
                               p[1], p[2]);
            }
        }
    }
    cr_assert_gt(checked, 50000, "too few defined points: %d", checked);
}

/* ------------------------------------------------------ rounding guard */

/* x + y = s + e exactly (Knuth's TwoSum). */
static void two_sum(double x, double y, double *s, double *e)
{
    double z, bb;

    *s = x + y;
    bb = *s - x;
    z = *s - bb;
    *e = (x - z) + (y - bb);
}

/* a contains the exact real s + e (|e| tiny next to s). */
static bool contains_exact(ival a, double s, double e)
{
    bool lo_ok = a.lo < s || (a.lo == s && e >= 0);
    bool hi_ok = a.hi > s || (a.hi == s && e <= 0);
    return lo_ok && hi_ok;
}

Test(ival_round, exact_sums_and_products_are_enclosed)
{
    double s, e;
    ival r = ival_add(ival_point(0.1), ival_point(0.2));

    two_sum(0.1, 0.2, &s, &e);
    cr_assert_neq(e, 0.0); /* 0.1 + 0.2 is inexact */
    cr_assert(contains_exact(r, s, e));
    cr_assert(r.hi - r.lo <= 4 * DBL_EPSILON * 0.3);

    rng_seed(81);
    for (int k = 0; k < 100000; k++) {
        double x = rng_sign() * ldexp(rng_range(1, 2), rng_int(200) - 100);
        double y = rng_sign() * ldexp(rng_range(1, 2), rng_int(200) - 100);
        double p = x * y, pe = fma(x, y, -p);

        two_sum(x, y, &s, &e);
        cr_assert(contains_exact(ival_add(ival_point(x), ival_point(y)), s, e));
        two_sum(x, -y, &s, &e);
        cr_assert(contains_exact(ival_sub(ival_point(x), ival_point(y)), s, e));
        cr_assert(contains_exact(ival_mul(ival_point(x), ival_point(y)), p, pe));
        cr_assert(contains_exact(ival_sqr(ival_point(x)), x * x,
                                 fma(x, x, -(x * x))));
        /* the remainder of the quotient: x = q*y + rem exactly */
        double q = x / y, rem = fma(-q, y, x);
        ival qi = ival_div(ival_point(x), ival_point(y));
        cr_assert(qi.lo < q || (qi.lo == q && rem * y >= 0));
        cr_assert(qi.hi > q || (qi.hi == q && rem * y <= 0));
        /* sqrt: s*s vs x */
        double ax = fabs(x), sq = sqrt(ax), sr = fma(-sq, sq, ax);
        ival si = ival_sqrt(ival_point(ax));
        cr_assert(si.lo < sq || (si.lo == sq && sr >= 0));
        cr_assert(si.hi > sq || (si.hi == sq && sr <= 0));
    }
}

static double succ(double x) { return nextafter(x, INFINITY); }

Test(ival_round, widen_moves_at_least_one_and_at_most_two_ulps)
{
    static const double fixed[] = {0.0, -0.0, DBL_TRUE_MIN, -DBL_TRUE_MIN,
                                   DBL_MIN, -DBL_MIN, 0x1p-969, 0x1p-970,
                                   0x1.fffffffffffffp-970, 1.0, -1.0, 2.0,
                                   0x1.fffffffffffffp0, DBL_MAX / 2, 1e300};
    rng_seed(91);
    for (int k = 0; k < 200000; k++) {
        double c;
        if (k < (int)(sizeof fixed / sizeof fixed[0]))
            c = fixed[k];
        else if (k & 1)
            c = rng_sign() * ldexp(rng_range(1, 2), rng_int(2098) - 1074);
        else { /* random bit patterns, including subnormals */
            uint64_t u = rng_u64();
            memcpy(&c, &u, sizeof c);
            if (!isfinite(c))
                continue;
        }
        ival w = ival_widen(ival_point(c));
        cr_assert(w.lo < c && w.hi > c, "widen(%a) = [%a, %a]", c, w.lo, w.hi);
        cr_assert(w.lo >= pred(pred(c)) && w.hi <= succ(succ(c)),
                  "widen(%a) = [%a, %a] too wide", c, w.lo, w.hi);
    }
    /* overflowed bounds: a lower bound +inf comes back to DBL_MAX */
    cr_assert(iv_eq(ival_widen(ival_point(INFINITY)), pred(DBL_MAX), INFINITY));
    cr_assert(iv_eq(ival_widen(ival_point(-INFINITY)), -INFINITY, -pred(DBL_MAX)));
    cr_assert(iv_eq(ival_widen(ival_point(DBL_MAX)), pred(DBL_MAX), INFINITY));
    cr_assert(ival_is_nan(ival_widen(ival_nan())));
}
