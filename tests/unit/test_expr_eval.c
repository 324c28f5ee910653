/* The tape and the evaluators against independent oracles: tape relocation and
 * validation, intervals against dense point samples, gradients against finite
 * differences, pruned tapes against the full tape (bit for bit) on random
 * min/max scenes, the batch's lanes against one box at a time, and the paper's
 * scenes. */
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

#include "expr_fixture.h"

static int irand(int n) { return (int)(rng_next() % (uint64_t)n); }

/* ---- relocation and validation ---- */

Test(expr_tape, memcpy_relocation)
{
    const char *src = "a = min(sqrt((x-0.5)^2+y^2+z^2)-0.3, sqrt((x+0.5)^2+y^2+z^2)-0.3);"
                      "max(a, -z) + 0.1*sin(3*theta)*phi";
    expr_tape *t = compile_ok(src), *ref = compile_ok(src);
    size_t n = expr_tape_bytes(t);
    cr_assert_gt(n, sizeof(struct expr_tape));
    /* an odd offset inside a bigger block, then the original is gone */
    char *block = aligned_alloc(64, (n + 128 + 63) / 64 * 64);
    void *copy = block + 40;
    memcpy(copy, t, n);
    memset(t, 0xa5, n);
    expr_tape_free(t);
    cr_assert_eq(expr_tape_validate(copy, n), 0);
    const expr_tape *c = copy;
    cr_expect_eq(expr_tape_length(c), expr_tape_length(ref));
    rng_seed(3);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(c, 3, &vm), 0);
    for (int k = 0; k < 50; k++) {
        double x = urand(-1, 1), y = urand(-1, 1), z = urand(-1, 1), g1[3], g2[3];
        cr_expect(same_double(expr_vm_point(vm, 0, x, y, z), expr_eval_point(ref, x, y, z)));
        double v1 = expr_vm_grad(vm, 0, x, y, z, g1);
        expr_vm *vr;
        cr_assert_eq(expr_vm_new(ref, 0, &vr), 0);
        double v2 = expr_vm_grad(vr, 0, x, y, z, g2);
        expr_vm_free(vr);
        cr_expect(same_double(v1, v2) && !memcmp(g1, g2, sizeof g1));
        ival X = ival_make(x, x + 0.1), Y = ival_make(y, y + 0.2), Z = ival_make(z, z + 0.05);
        ival a = expr_vm_ival(vm, 0, X, Y, Z), b = expr_eval_ival(ref, X, Y, Z);
        cr_expect(same_double(a.lo, b.lo) && same_double(a.hi, b.hi));
    }
    expr_vm_free(vm);
    free(block);
    expr_tape_free(ref);
}

Test(expr_tape, validate_rejects_corruption)
{
    expr_tape *t = compile_ok("min(x*y, sin(z)) + 2");
    size_t n = expr_tape_bytes(t);
    cr_expect_eq(expr_tape_validate(t, n), 0);
    cr_expect_eq(expr_tape_validate(t, n - 1), -EINVAL);
    cr_expect_eq(expr_tape_validate(t, 8), -EINVAL);
    expr_tape *c = malloc(n);
    expr_insn *code;
    struct { int field; uint16_t v; } bad[] = {
        {0, 200},            /* op out of range */
        {1, 0},              /* writes x */
        {1, 60000},          /* register out of range */
        {2, 60000},          /* reads out of range */
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        memcpy(c, t, n);
        code = (expr_insn *)expr_tape_code(c);
        if (bad[i].field == 0) code[0].op = (uint8_t)bad[i].v;
        if (bad[i].field == 1) code[0].out = bad[i].v;
        if (bad[i].field == 2) code[1].a = bad[i].v;
        cr_expect_eq(expr_tape_validate(c, n), -EINVAL, "case %zu", i);
        expr_vm *vm = NULL;
        cr_expect_eq(expr_vm_new(c, 0, &vm), -EINVAL);
        cr_expect_null(vm);
    }
    /* reading a scratch register before anything wrote it */
    memcpy(c, t, n);
    code = (expr_insn *)expr_tape_code(c);
    code[0].a = (uint16_t)(c->nregs - 1);
    cr_expect_eq(expr_tape_validate(c, n), -EINVAL);
    memcpy(c, t, n);
    c->magic ^= 1;
    cr_expect_eq(expr_tape_validate(c, n), -EINVAL);
    memcpy(c, t, n);
    c->len += 1;
    cr_expect_eq(expr_tape_validate(c, n), -EINVAL);
    expr_vm *vm;
    cr_expect_eq(expr_vm_new(t, 33, &vm), -EINVAL);
    cr_expect_eq(expr_vm_new(t, -1, &vm), -EINVAL);
    free(c);
    expr_tape_free(t);
}

/* ---- random expressions, as source text ---- */

typedef struct {
    char *buf;
    size_t len, cap;
    int smooth; /* only differentiable functions (gradient test) */
} gen;

static void put(gen *g, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static void put(gen *g, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(g->buf + g->len, g->cap - g->len, fmt, ap);
    va_end(ap);
    cr_assert(n >= 0 && g->len + (size_t)n < g->cap, "generator buffer");
    g->len += (size_t)n;
}

static void gen_expr(gen *g, int depth);

static void gen_leaf(gen *g)
{
    static const char *const leaves[] = {"x", "y", "z", "r", "theta", "phi", "pi", "x", "y", "z"};
    if (irand(3) == 0) put(g, "%.2f", urand(-3, 3));
    else put(g, "%s", leaves[irand(10)]);
}

static void gen_unary(gen *g, int depth)
{
    static const char *const any[] = {"sin", "cos", "tan", "asin", "acos", "atan", "exp",
                                      "log", "sqrt", "abs"};
    static const char *const smooth[] = {"sin", "cos", "atan", "exp"};
    int k = irand(g->smooth ? 7 : 14);
    if (k < 4 && g->smooth) {
        put(g, "%s(", smooth[k]);
        gen_expr(g, depth - 1);
        put(g, ")");
        return;
    }
    if (k >= 10 || (g->smooth && k >= 4)) {
        static const char *const pw[] = {"2", "3", "-1", "0.5", "(-2)", "4"};
        put(g, "(");
        gen_expr(g, depth - 1);
        put(g, ")^%s", pw[irand(g->smooth ? 3 : 6)]);
        return;
    }
    put(g, k == 9 && irand(2) ? "-(" : "%s(", any[k]);
    gen_expr(g, depth - 1);
    put(g, ")");
}

static void gen_binary(gen *g, int depth)
{
    static const char *const ops[] = {"+", "-", "*", "/"};
    int k = irand(g->smooth ? 5 : 9);
    if (k < 4) {
        put(g, "(");
        gen_expr(g, depth - 1);
        put(g, " %s ", ops[k]);
        gen_expr(g, depth - 1);
        put(g, ")");
        return;
    }
    static const char *const fn[] = {"atan2", "min", "max", "pow", "blend"};
    k = g->smooth ? 0 : k - 4;
    put(g, "%s(", fn[k]);
    gen_expr(g, depth - 1);
    put(g, ", ");
    if (k == 4) put(g, "%.2f", urand(0.1, 2));
    else gen_expr(g, depth - 1);
    if ((k == 1 || k == 2) && irand(2)) {
        put(g, ", ");
        gen_expr(g, depth - 1);
    }
    put(g, ")");
}

static void gen_expr(gen *g, int depth)
{
    int k = depth <= 0 ? 0 : irand(5);
    if (k == 0) gen_leaf(g);
    else if (k <= 2) gen_unary(g, depth);
    else gen_binary(g, depth);
}

static char *random_source(int depth, int smooth)
{
    gen g = {malloc(1 << 16), 0, 1 << 16, smooth};
    if (irand(3) == 0) {
        put(&g, "t = ");
        gen_expr(&g, depth - 1);
        put(&g, "; ");
        gen_expr(&g, depth - 1);
        put(&g, " + t*");
        gen_expr(&g, 1);
    } else {
        gen_expr(&g, depth);
    }
    return g.buf;
}

/* ---- interval soundness against the point evaluator ---- */

static void random_box(ival box[3], double maxw)
{
    for (int j = 0; j < 3; j++) {
        double c = urand(-2, 2), w = maxw * pow(10, urand(-3, 0));
        box[j] = ival_make(c - w, c + w);
        if (irand(8) == 0) box[j] = ival_make(0, w); /* touch an axis */
        if (irand(16) == 0) box[j] = ival_make(-w, w); /* straddle it */
    }
}

static void sample(const ival box[3], int k, double p[3])
{
    for (int j = 0; j < 3; j++) {
        double u = k < 8 ? (double)((k >> j) & 1) : urand(0, 1);
        p[j] = fmin(fmax(box[j].lo + u * (box[j].hi - box[j].lo), box[j].lo), box[j].hi);
    }
}

/* v from a point in the box must lie in I (NaN points and NaN intervals say
 * nothing). */
static int encloses(ival I, double v)
{
    return isnan(v) || ival_is_nan(I) || (I.lo <= v && v <= I.hi);
}

/* F at p, or NaN where the evaluation hit a pole exactly (x/0, log(0)):
 * there the sign of the infinity comes from the sign of a zero, which
 * intervals (sets of reals) do not carry, e.g. 1/min(x, 0) at x > 0 is
 * +inf while [-1, 0] gives 1/[-1, 0] = [-inf, -1].  Like NaN points, such
 * points are outside F's domain and never on the surface F = 0. */
static double defined_point(expr_vm *vm, int d, const double p[3])
{
    feclearexcept(FE_DIVBYZERO);
    double v = expr_vm_point(vm, d, p[0], p[1], p[2]);
    return fetestexcept(FE_DIVBYZERO) ? NAN : v;
}

Test(expr_eval, interval_encloses_point_samples)
{
    rng_seed(4);
    int checked = 0;
    for (int e = 0; e < 300; e++) {
        char *src = random_source(2 + e % 4, 0);
        expr_tape *t = compile_ok(src);
        expr_vm *vm;
        cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
        for (int b = 0; b < 8; b++) {
            ival box[3];
            random_box(box, 1.0);
            ival I = expr_vm_ival(vm, 0, box[0], box[1], box[2]);
            cr_assert(ival_is_nan(I) || I.lo <= I.hi, "%s: [%g, %g]", src, I.lo, I.hi);
            for (int k = 0; k < 48; k++) {
                double p[3];
                sample(box, k, p);
                double v = defined_point(vm, 0, p);
                checked += !isnan(v) && !ival_is_nan(I);
                cr_assert(encloses(I, v),
                          "%s\n box [%.17g,%.17g]x[%.17g,%.17g]x[%.17g,%.17g]\n"
                          " F(%.17g,%.17g,%.17g) = %.17g not in [%.17g, %.17g]",
                          src, box[0].lo, box[0].hi, box[1].lo, box[1].hi, box[2].lo,
                          box[2].hi, p[0], p[1], p[2], v, I.lo, I.hi);
            }
        }
        expr_vm_free(vm);
        expr_tape_free(t);
        free(src);
    }
    cr_expect_gt(checked, 300 * 8 * 48 / 4, "too few informative samples: %d", checked);
}

Test(expr_eval, interval_on_a_point_box_is_tight)
{
    expr_tape *t = compile_ok("sqrt(x^2+y^2+z^2)-0.8");
    ival v = expr_eval_ival(t, ival_point(0.3), ival_point(0.4), ival_point(0.5));
    double p = expr_eval_point(t, 0.3, 0.4, 0.5);
    cr_expect(v.lo <= p && p <= v.hi && v.hi - v.lo < 1e-14);
    expr_tape_free(t);
}

/* ---- gradient against finite differences ---- */

/* Central difference; *noise gets its rounding error bound. */
static double fd(expr_vm *vm, const double p[3], int j, double h, double *noise)
{
    double a[3] = {p[0], p[1], p[2]}, b[3] = {p[0], p[1], p[2]};
    a[j] += h;
    b[j] -= h;
    double fa = expr_vm_point(vm, 0, a[0], a[1], a[2]), fb = expr_vm_point(vm, 0, b[0], b[1], b[2]);
    *noise = 64 * DBL_EPSILON * fmax(fabs(fa), fabs(fb)) / (2 * (a[j] - b[j]));
    return (fa - fb) / (a[j] - b[j]);
}

Test(expr_eval, gradient_matches_finite_differences)
{
    rng_seed(5);
    int checked = 0, tried = 0;
    for (int e = 0; e < 250; e++) {
        char *src = random_source(2 + e % 3, 1);
        expr_tape *t = compile_ok(src);
        expr_vm *vm;
        cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
        for (int k = 0; k < 10; k++) {
            double p[3] = {urand(-2, 2), urand(-2, 2), urand(-2, 2)}, g[3];
            double v = expr_vm_grad(vm, 0, p[0], p[1], p[2], g);
            cr_assert(same_double(v, expr_vm_point(vm, 0, p[0], p[1], p[2])), "%s", src);
            for (int j = 0; j < 3; j++) {
                double h = 1e-5 * fmax(1, fabs(p[j]));
                double n1, n2, d1 = fd(vm, p, j, h, &n1), d2 = fd(vm, p, j, h / 2, &n2);
                double tol = 1e-6 * fmax(1, fabs(d2));
                tried++;
                /* skip kinks and poles (the two estimates disagree) and values
                 * so large that rounding swamps the difference */
                if (!isfinite(d1) || !isfinite(d2) || fabs(d1 - d2) > tol || n2 > tol)
                    continue;
                checked++;
                cr_assert(fabs(g[j] - d2) <= 1e-5 * fmax(1, fabs(d2)),
                          "%s at (%.17g,%.17g,%.17g): d/d%c = %.17g, finite differences %.17g",
                          src, p[0], p[1], p[2], "xyz"[j], g[j], d2);
            }
        }
        expr_vm_free(vm);
        expr_tape_free(t);
        free(src);
    }
    cr_expect_gt(checked, tried / 2, "only %d of %d derivatives checked", checked, tried);
}

Test(expr_eval, gradient_special_points)
{
    expr_vm *vm;
    double g[3];
    expr_tape *t = compile_ok("sqrt(x^2+y^2+z^2) - 1");
    cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
    expr_vm_grad(vm, 0, 0.6, 0, 0.8, g);
    cr_expect(close_to(g[0], 0.6, 1e-15) && close_to(g[1], 0, 0) && close_to(g[2], 0.8, 1e-15));
    expr_vm_grad(vm, 0, 0, 0, 0, g); /* finite, not NaN */
    cr_expect(isfinite(g[0]) && isfinite(g[1]) && isfinite(g[2]));
    expr_vm_free(vm);
    expr_tape_free(t);
    /* r, theta, phi on the z axis and at the origin */
    const char *sph[] = {"r", "theta", "phi", "sin(4*theta)*sin(8*phi) - r"};
    double pts[][3] = {{0, 0, 0}, {0, 0, 1}, {0, 0, -2}, {1e-300, 0, 1}, {-1, 0, 0}};
    for (int i = 0; i < 4; i++) {
        t = compile_ok(sph[i]);
        cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
        for (int k = 0; k < 5; k++) {
            double v = expr_vm_grad(vm, 0, pts[k][0], pts[k][1], pts[k][2], g);
            cr_expect(isfinite(v) && isfinite(g[0]) && isfinite(g[1]) && isfinite(g[2]),
                      "%s at point %d: %g (%g %g %g)", sph[i], k, v, g[0], g[1], g[2]);
        }
        expr_vm_free(vm);
        expr_tape_free(t);
    }
    /* r gradient is the unit vector; theta's is (-y, x)/rho^2; phi's points south */
    t = compile_ok("r + 10*theta + 100*phi");
    cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
    expr_vm_grad(vm, 0, 1, 1, 0, g);
    double s = sqrt(0.5);
    cr_expect(close_to(g[0], s - 5, 1e-14) && close_to(g[1], s + 5, 1e-14) &&
              close_to(g[2], -100 / sqrt(2), 1e-14), "%g %g %g", g[0], g[1], g[2]);
    expr_vm_free(vm);
    expr_tape_free(t);
    /* abs, min, max follow the active branch */
    t = compile_ok("abs(x) + min(y, 2*z) + max(3*x, z)");
    cr_assert_eq(expr_vm_new(t, 0, &vm), 0);
    expr_vm_grad(vm, 0, -1, 1, 1, g); /* -x + y + z */
    cr_expect(g[0] == -1 && g[1] == 1 && g[2] == 1);
    expr_vm_grad(vm, 0, 2, 3, 1, g); /* x + 2z + 3x */
    cr_expect(g[0] == 4 && g[1] == 0 && g[2] == 2);
    expr_vm_free(vm);
    expr_tape_free(t);
}

/* ---- pruning ---- */

static void put_sphere(gen *g, double cx, double cy, double cz, double r)
{
    put(g, "sqrt((x-%.3f)^2+(y-%.3f)^2+(z-%.3f)^2)-%.3f", cx, cy, cz, r);
}

/* A pruned tape is F inside its box: point values and gradients bit for
 * bit equal to the full tape's (where F is defined: a dropped branch may
 * have been NaN there), intervals on sub-boxes still enclose. */
static void check_pruned(expr_vm *vm, int d, const ival box[3], const char *src)
{
    for (int k = 0; k < 24; k++) {
        double p[3], g0[3], g1[3];
        sample(box, k, p);
        double v0 = expr_vm_point(vm, 0, p[0], p[1], p[2]);
        double v1 = expr_vm_point(vm, d, p[0], p[1], p[2]);
        if (isnan(v0)) continue;
        cr_assert(same_double(v0, v1), "%s: depth %d %.17g vs %.17g", src, d, v1, v0);
        double w0 = expr_vm_grad(vm, 0, p[0], p[1], p[2], g0);
        double w1 = expr_vm_grad(vm, d, p[0], p[1], p[2], g1);
        cr_assert(same_double(w0, w1) && same_double(g0[0], g1[0]) &&
                  same_double(g0[1], g1[1]) && same_double(g0[2], g1[2]), "%s", src);
    }
}

static void child_box(const ival box[3], int c, ival out[3])
{
    for (int j = 0; j < 3; j++) {
        double m = 0.5 * (box[j].lo + box[j].hi);
        out[j] = (c >> j) & 1 ? ival_make(m, box[j].hi) : ival_make(box[j].lo, m);
    }
}

/* Evaluate box at depth d, prune, check depth d+1 inside it, recurse into
 * two children.  Returns how many prunes shortened the tape. */
static int prune_walk(expr_vm *vm, int d, const ival box[3], int levels, const char *src)
{
    ival I = expr_vm_ival(vm, d, box[0], box[1], box[2]);
    for (int k = 0; k < 16; k++) {
        double p[3];
        sample(box, k, p);
        double v = defined_point(vm, 0, p);
        cr_assert(encloses(I, v), "%s: depth %d: %.17g not in [%.17g, %.17g]", src, d, v,
                  I.lo, I.hi);
    }
    if (!levels) return 0;
    uint32_t before = expr_vm_length(vm, d), decided = vm->dep[d].decided;
    expr_vm_prune(vm, d);
    uint32_t after = expr_vm_length(vm, d + 1);
    /* a decided min/max is dropped (renamed to its winner), at least */
    if (decided) cr_assert_lt(after, before, "%s: %u decided", src, decided);
    else cr_assert(after == before && vm->dep[d + 1].code == vm->dep[d].code, "%s", src);
    check_pruned(vm, d + 1, box, src);
    int shortened = after < before;
    for (int c = 0; c < 2; c++) {
        ival sub[3];
        child_box(box, irand(8), sub);
        shortened += prune_walk(vm, d + 1, sub, levels - 1, src);
    }
    return shortened;
}

static char *spheres_source(int n)
{
    gen g = {malloc(1 << 16), 0, 1 << 16, 0};
    put(&g, "min(");
    for (int i = 0; i < n; i++) {
        if (i) put(&g, ",\n    ");
        put_sphere(&g, urand(-1, 1), urand(-1, 1), urand(-1, 1), urand(0.05, 0.25));
    }
    put(&g, ")");
    return g.buf;
}

Test(expr_prune, min_of_spheres_is_bit_exact)
{
    rng_seed(6);
    char *src = spheres_source(64);
    expr_tape *t = compile_ok(src);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(t, 6, &vm), 0);
    int shortened = 0;
    for (int b = 0; b < 40; b++) {
        ival box[3];
        for (int j = 0; j < 3; j++) {
            double c = urand(-1.1, 1.1), w = pow(10, urand(-2, -0.5));
            box[j] = ival_make(c - w, c + w);
        }
        shortened += prune_walk(vm, 0, box, 3, src);
    }
    cr_expect_gt(shortened, 40, "pruning hardly ever shortened the tape (%d)", shortened);
    expr_vm_free(vm);
    expr_tape_free(t);
    free(src);
}

/* Well separated spheres: around one centre every min is decided, and what
 * is left is exactly that sphere's own tape. */
Test(expr_prune, decided_min_leaves_the_winner_only)
{
    gen g = {malloc(1 << 16), 0, 1 << 16, 0};
    put(&g, "min(");
    for (int i = 0; i < 64; i++) {
        if (i) put(&g, ", ");
        put_sphere(&g, i % 4, (i / 4) % 4, i / 16, 0.3);
    }
    put(&g, ")");
    expr_tape *t = compile_ok(g.buf);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(t, 2, &vm), 0);
    rng_seed(7);
    for (int k = 0; k < 64; k += 7) {
        double c[3] = {k % 4, (k / 4) % 4, k / 16};
        ival box[3];
        for (int j = 0; j < 3; j++) box[j] = ival_make(c[j] - 0.1, c[j] + 0.1);
        expr_vm_ival(vm, 0, box[0], box[1], box[2]);
        expr_vm_prune(vm, 0);
        gen one = {malloc(256), 0, 256, 0};
        put_sphere(&one, c[0], c[1], c[2], 0.3);
        expr_tape *alone = compile_ok(one.buf);
        cr_expect_eq(expr_vm_length(vm, 1), expr_tape_length(alone), "sphere %d", k);
        cr_expect_lt(expr_vm_length(vm, 1), expr_vm_length(vm, 0));
        for (int s = 0; s < 20; s++) {
            double p[3];
            sample(box, s, p);
            cr_expect(same_double(expr_vm_point(vm, 1, p[0], p[1], p[2]),
                                  expr_eval_point(alone, p[0], p[1], p[2])));
        }
        check_pruned(vm, 1, box, g.buf);
        expr_tape_free(alone);
        free(one.buf);
    }
    expr_vm_free(vm);
    expr_tape_free(t);
    free(g.buf);
}

static void gen_csg(gen *g, int depth)
{
    if (depth == 0 || irand(4) == 0) {
        if (irand(3))
            put_sphere(g, urand(-1, 1), urand(-1, 1), urand(-1, 1), urand(0.1, 0.6));
        else
            put(g, "(x*%.2f + y*%.2f + z*%.2f - %.2f)", urand(-1, 1), urand(-1, 1),
                urand(-1, 1), urand(-1, 1));
        return;
    }
    int k = irand(3), n = 2 + irand(2);
    put(g, k == 0 ? "min(" : "max(");
    for (int i = 0; i < n; i++) {
        if (i) put(g, ", ");
        if (k == 2 && i) put(g, "-(");
        gen_csg(g, depth - 1);
        if (k == 2 && i) put(g, ")");
    }
    put(g, ")");
}

Test(expr_prune, nested_min_max_is_bit_exact_and_sound)
{
    rng_seed(8);
    int shortened = 0;
    for (int e = 0; e < 60; e++) {
        gen g = {malloc(1 << 16), 0, 1 << 16, 0};
        gen_csg(&g, 4);
        if (e % 3 == 0) put(&g, " + 0.05*sin(9*x)*blend(y, 0.5)");
        expr_tape *t = compile_ok(g.buf);
        expr_vm *vm;
        cr_assert_eq(expr_vm_new(t, 5, &vm), 0);
        for (int b = 0; b < 6; b++) {
            ival box[3];
            random_box(box, 0.5);
            shortened += prune_walk(vm, 0, box, 3, g.buf);
        }
        expr_vm_free(vm);
        expr_tape_free(t);
        free(g.buf);
    }
    cr_expect_gt(shortened, 60, "pruning hardly ever shortened the tape (%d)", shortened);
}

Test(expr_prune, nothing_decided_and_depth_clamping)
{
    expr_tape *t = compile_ok("min(sqrt(x^2+y^2+z^2)-0.5, x+0.2)");
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(t, 2, &vm), 0);
    uint32_t n = expr_tape_length(t);
    /* the box straddles both: nothing decided, same tape */
    expr_vm_ival(vm, 0, ival_make(-0.5, -0.3), ival_make(-0.1, 0.1), ival_make(-0.1, 0.1));
    expr_vm_prune(vm, 0);
    cr_expect_eq(expr_vm_length(vm, 1), n);
    /* far left: x+0.2 wins (one instruction); deeper depths clamp to 2 */
    ival X = ival_make(-0.8, -0.7), Y = ival_make(0, 0.05), Z = ival_make(0, 0.05);
    expr_vm_ival(vm, 1, X, Y, Z);
    expr_vm_prune(vm, 1);
    cr_expect_eq(expr_vm_length(vm, 2), 1);
    expr_vm_prune(vm, 2); /* no deeper tape: a no-op */
    cr_expect_eq(expr_vm_length(vm, 9), 1);
    cr_expect(same_double(expr_vm_point(vm, 9, -0.75, 0.01, 0.02), -0.75 + 0.2));
    ival I = expr_vm_ival(vm, 30, X, Y, Z);
    cr_expect(I.lo <= -0.6 && I.hi >= -0.5 && I.hi < 0);
    cr_expect_eq(expr_vm_length(vm, -4), n);
    /* a tape that is a single register (x): depth tapes stay empty */
    expr_tape *tx = compile_ok("min(x, 5)");
    expr_vm *vx;
    cr_assert_eq(expr_vm_new(tx, 3, &vx), 0);
    expr_vm_ival(vx, 0, ival_make(0, 1), ival_make(0, 1), ival_make(0, 1));
    expr_vm_prune(vx, 0);
    cr_expect_eq(expr_vm_length(vx, 1), 0);
    cr_expect_eq(expr_vm_point(vx, 1, 0.25, 0, 0), 0.25);
    ival J = expr_vm_ival(vx, 1, ival_make(0, 0.5), ival_make(0, 1), ival_make(0, 1));
    cr_expect(J.lo == 0 && J.hi == 0.5);
    expr_vm_free(vx);
    expr_tape_free(tx);
    expr_vm_free(vm);
    expr_tape_free(t);
}

/* ---- batched evaluators: every lane is the one-box evaluation ---- */

static int same_ival(ival a, ival b) { return same_double(a.lo, b.lo) && same_double(a.hi, b.hi); }

/* Random boxes with the awkward cases mixed in: huge and infinite bounds
 * (overflow, 0 * inf products), zero-width boxes, exact zeros (divisors
 * touching 0). */
static void batch_box(ival box[3])
{
    random_box(box, 1.0);
    for (int j = 0; j < 3; j++) {
        switch (irand(24)) {
        case 0: box[j] = ival_make(-INFINITY, box[j].hi); break;
        case 1: box[j] = ival_make(box[j].lo, INFINITY); break;
        case 2: box[j] = ival_make(1e300, 1e308); break;
        case 3: box[j] = ival_make(-DBL_MAX, -1e200); break;
        case 4: box[j] = ival_point(box[j].lo); break;
        case 5: box[j] = ival_point(0); break;
        case 6: box[j] = ival_make(-0.0, 0.0); break;
        default: break;
        }
    }
}

static int same_tape(const expr_vm *a, const expr_vm *b, int d)
{
    const expr_vm_depth *x = &a->dep[d], *y = &b->dep[d];
    return x->len == y->len && x->result == y->result &&
           !memcmp(x->code, y->code, x->len * sizeof *x->code);
}

static void check_batch(const char *src, int nbatches)
{
    expr_tape *t = compile_ok(src);
    expr_vm *v8, *v1;
    cr_assert_eq(expr_vm_new(t, 2, &v8), 0);
    cr_assert_eq(expr_vm_new(t, 2, &v1), 0);
    for (int b = 0; b < nbatches; b++) {
        ival box[EXPR_LANES][3];
        ival8 X, Y, Z, I8;
        for (int l = 0; l < EXPR_LANES; l++) {
            if (l && irand(4) == 0) memcpy(box[l], box[irand(l)], sizeof box[l]);
            else batch_box(box[l]);
            X.lo[l] = box[l][0].lo, X.hi[l] = box[l][0].hi;
            Y.lo[l] = box[l][1].lo, Y.hi[l] = box[l][1].hi;
            Z.lo[l] = box[l][2].lo, Z.hi[l] = box[l][2].hi;
        }
        expr_vm_ival8(v8, 0, &X, &Y, &Z, &I8);
        for (int l = 0; l < EXPR_LANES; l++) {
            ival I = expr_vm_ival(v1, 0, box[l][0], box[l][1], box[l][2]);
            cr_assert(same_ival(I, ival_make(I8.lo[l], I8.hi[l])),
                      "%s\n lane %d: [%.17g, %.17g] vs one box [%.17g, %.17g]", src, l,
                      I8.lo[l], I8.hi[l], I.lo, I.hi);
            /* pruning for the lane builds the one-box tape; lanes in any order */
            expr_vm_prune(v1, 0);
            expr_vm_prune8(v8, 0, l);
            cr_assert(same_tape(v8, v1, 1), "%s: lane %d prunes differently", src, l);
        }
        /* gradients at a point of each box */
        expr_pts8 p8;
        double *px = p8.x, *py = p8.y, *pz = p8.z;
        for (int l = 0; l < EXPR_LANES; l++) {
            double p[3];
            sample(box[l], 8 + irand(2) * 8, p);
            if (irand(8) == 0) p[irand(3)] = 0;
            px[l] = p[0], py[l] = p[1], pz[l] = p[2];
        }
        int d = irand(2);
        expr_grad8 g8;
        expr_vm_grad8(v8, d, &p8, &g8);
        for (int l = 0; l < EXPR_LANES; l++) {
            double g[3], v = expr_vm_grad(v8, d, px[l], py[l], pz[l], g);
            cr_assert(same_double(v, g8.v[l]) && same_double(g[0], g8.d[0][l]) &&
                          same_double(g[1], g8.d[1][l]) && same_double(g[2], g8.d[2][l]),
                      "%s: gradient lane %d at (%.17g, %.17g, %.17g)", src, l, px[l], py[l],
                      pz[l]);
        }
        /* a partial batch: the same lanes */
        int n = 1 + irand(EXPR_LANES);
        expr_grad8 gn;
        expr_vm_grad8n(v8, d, n, &p8, &gn);
        for (int l = 0; l < n; l++)
            cr_assert(same_double(gn.v[l], g8.v[l]) && same_double(gn.d[0][l], g8.d[0][l]) &&
                          same_double(gn.d[1][l], g8.d[1][l]) &&
                          same_double(gn.d[2][l], g8.d[2][l]),
                      "%s: partial batch of %d, lane %d", src, n, l);
    }
    expr_vm_free(v8);
    expr_vm_free(v1);
    expr_tape_free(t);
}

Test(expr_batch, lanes_are_the_one_box_evaluation)
{
    rng_seed(11);
    for (int e = 0; e < 300; e++) {
        char *src = random_source(2 + e % 4, e % 2);
        check_batch(src, 6);
        free(src);
    }
    for (int e = 0; e < 40; e++) {
        gen g = {malloc(1 << 16), 0, 1 << 16, 0};
        gen_csg(&g, 4);
        check_batch(g.buf, 6);
        free(g.buf);
    }
    const char *fixed[] = {"sqrt(x^2 + y^2 + z^2) - 0.8", "x*y - z", "x/y + z/(x+1)",
                           "min(x, y, z) - max(x*y, -z)", "abs(x) - sqrt(y) + -z",
                           "-log(exp(-44*x) + exp(-44*y)) / 44"};
    for (size_t i = 0; i < sizeof fixed / sizeof *fixed; i++) check_batch(fixed[i], 50);
}

/* ---- the paper's scenes ---- */

static double scene(double x, double y, double z, int a, int b)
{
    double r = sqrt(x * x + y * y + z * z);
    return sin(a * atan2(y, x)) * sin(b * acos(z / r)) - r;
}

Test(expr_scenes, stolte_kaufman_scenes_2_and_3)
{
    const char *src[] = {"sin(4*theta)*sin(8*phi) - r", "sin(3*theta)*sin(4*phi) - r"};
    int ab[][2] = {{4, 8}, {3, 4}};
    rng_seed(9);
    for (int s = 0; s < 2; s++) {
        expr_tape *t = compile_ok(src[s]);
        /* theta, mul, sin, phi, mul, sin, mul, r, sub */
        cr_expect_eq(expr_tape_length(t), 9u);
        expr_vm *vm;
        cr_assert_eq(expr_vm_new(t, 8, &vm), 0);
        for (int k = 0; k < 200; k++) {
            double x = urand(-1, 1), y = urand(-1, 1), z = urand(-1, 1);
            cr_expect(close_to(expr_vm_point(vm, 0, x, y, z), scene(x, y, z, ab[s][0], ab[s][1]),
                               1e-12));
        }
        for (int b = 0; b < 200; b++) {
            ival box[3];
            random_box(box, 0.5);
            ival I = expr_vm_ival(vm, 0, box[0], box[1], box[2]);
            for (int k = 0; k < 24; k++) {
                double p[3];
                sample(box, k, p);
                double v = defined_point(vm, 0, p);
                cr_assert(encloses(I, v), "%s: %.17g not in [%.17g, %.17g]", src[s], v, I.lo,
                          I.hi);
            }
        }
        expr_vm_free(vm);
        expr_tape_free(t);
    }
}
