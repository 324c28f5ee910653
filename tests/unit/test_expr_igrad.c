/* expr_vm_ival_grad: its intervals of F and of the gradient enclose what
 * expr_vm_grad computes at points of the box (corners, faces, random
 * points), for every op it supports; "total" boxes have no NaN point;
 * other ops are refused. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "expr.h"

static expr_vm *vm_of(const char *src, expr_tape **t)
{
    expr_error err;
    cr_assert_eq(expr_compile(src, strlen(src), NULL, t, &err), 0, "%s: %s", src, err.msg);
    expr_vm *vm;
    cr_assert_eq(expr_vm_new(*t, 0, &vm), 0);
    return vm;
}

static double pick(double lo, double hi, int k)
{
    if (k == 0) return lo;
    if (k == 1) return hi;
    if (k == 2) return (lo + hi) / 2;
    return lo + (hi - lo) * (rand() / (double)RAND_MAX);
}

/* 200 boxes of sizes 1e-3 .. 1 around [-1.5, 1.5]^3, 40 points each. */
static void enclose(const char *src)
{
    expr_tape *t;
    expr_vm *vm = vm_of(src, &t);
    for (int b = 0; b < 200; b++) {
        double lo[3], hi[3], w = pow(10, -3 + 3 * (rand() / (double)RAND_MAX));
        for (int a = 0; a < 3; a++) {
            lo[a] = -1.5 + 3 * (rand() / (double)RAND_MAX);
            hi[a] = lo[a] + w * (b % 3 == a ? 0.5 : 1);
        }
        if (b % 17 == 0) lo[0] = -w / 2, hi[0] = w / 2; /* across 0 */
        expr_igrad ig;
        cr_assert_eq(expr_vm_ival_grad(vm, ival_make(lo[0], hi[0]), ival_make(lo[1], hi[1]),
                                       ival_make(lo[2], hi[2]), &ig), 0, "%s", src);
        const ival f = ig.f, *g = ig.grad;
        const int total = ig.total;
        for (int k = 0; k < 40; k++) {
            double p[3], d[3];
            for (int a = 0; a < 3; a++) p[a] = pick(lo[a], hi[a], k < 8 ? (k >> a) & 1 : 3);
            double v = expr_vm_grad(vm, 0, p[0], p[1], p[2], d);
            if (total) cr_assert(!isnan(v) && !isnan(d[0]) && !isnan(d[1]) && !isnan(d[2]),
                                 "%s: NaN at a point of a total box", src);
            if (!isnan(v))
                cr_assert(ival_contains(f, v) || (isinf(v) && (v > 0 ? f.hi : f.lo) == v),
                          "%s at %g,%g,%g: F %.17g not in [%.17g, %.17g]", src, p[0], p[1], p[2],
                          v, f.lo, f.hi);
            for (int j = 0; j < 3; j++)
                if (!isnan(d[j]) && !isnan(v))
                    cr_assert(ival_contains(g[j], d[j]) || isinf(d[j]),
                              "%s at %g,%g,%g: dF/d%c %.17g not in [%.17g, %.17g]", src, p[0],
                              p[1], p[2], "xyz"[j], d[j], g[j].lo, g[j].hi);
        }
    }
    expr_vm_free(vm);
    expr_tape_free(t);
}

Test(expr_igrad, encloses_the_point_gradient_for_every_supported_op, .timeout = 60)
{
    static const char *const srcs[] = {
        "x + y - z", "x * y * z - 0.3", "x / (y + 2.5)", "x / y", "-x + 0.5 * y",
        "x^2 + y^2 + z^2 - 0.5", "sqrt(x^2 + y^2 + z^2) - 0.6", "sqrt(x)", "abs(x) + abs(y - 0.1)",
        "min(x, y) - max(z, 0.2)", "min(x*x, y) + max(x, -x)", "sin(4 * x) * cos(3 * y) - z",
        "exp(x) - 1.5 + y^3", "x^5 - y", "r - 0.7", "r", "sqrt(0.5 - x^2 - y^2) - 0.2",
        "exp(40 * x) * y",
    };
    srand(7);
    for (size_t k = 0; k < sizeof srcs / sizeof *srcs; k++) enclose(srcs[k]);
}

Test(expr_igrad, refuses_ops_it_has_no_interval_gradient_for)
{
    static const char *const srcs[] = {"atan(x) - 0.3", "log(x + 2)", "tan(x)", "atan2(y, x)",
                                       "x^y", "asin(x / 3)", "theta - 1", "phi - 1",
                                       "blend(x, 0.5)"};
    for (size_t k = 0; k < sizeof srcs / sizeof *srcs; k++) {
        expr_tape *t;
        expr_vm *vm = vm_of(srcs[k], &t);
        expr_igrad ig;
        ival b = ival_make(0.1, 0.2);
        cr_assert_eq(expr_vm_ival_grad(vm, b, b, b, &ig), -ENOTSUP, "%s", srcs[k]);
        expr_vm_free(vm);
        expr_tape_free(t);
    }
}

Test(expr_igrad, total_only_where_defined_everywhere)
{
    expr_tape *t;
    expr_vm *vm = vm_of("sqrt(x) + 1 / y", &t);
    expr_igrad ig;
    const ival *g = ig.grad;
    cr_assert_eq(expr_vm_ival_grad(vm, ival_make(0.5, 1), ival_make(1, 2), ival_make(0, 1), &ig),
                 0);
    cr_assert_eq(ig.total, 1);
    cr_assert(ig.f.lo > 1.1 && ig.f.hi < 2.1 && g[0].lo > 0.4 && g[0].hi < 0.8 &&
                  g[2].lo > -1e-300 && g[2].hi < 1e-300,
              "[%g, %g] [%g, %g]", ig.f.lo, ig.f.hi, g[0].lo, g[0].hi);
    cr_assert_eq(expr_vm_ival_grad(vm, ival_make(-0.5, 1), ival_make(1, 2), ival_make(0, 1), &ig),
                 0);
    cr_assert_eq(ig.total, 0); /* sqrt of a negative */
    cr_assert_eq(expr_vm_ival_grad(vm, ival_make(0.5, 1), ival_make(-1, 2), ival_make(0, 1), &ig),
                 0);
    cr_assert_eq(ig.total, 0); /* 1 / 0 */
    expr_vm_free(vm);
    expr_tape_free(t);
}
