/* libFuzzer harness for the expression language: compile the input with
 * small limits; when it compiles, check the tape, move it with memcpy, and
 * run every evaluator on it with the properties that must always hold:
 *   - the interval of a box encloses the point values at its corners and
 *     centre (NaN points, points on a pole and NaN intervals excepted);
 *   - the gradient evaluator's value is the point evaluator's, bit for bit;
 *   - after a prune, the tape of depth 1 gives the same point values inside
 *     the box (where F is defined and off poles) and is no longer than
 *     tape 0.
 * A failure aborts (the replay driver and libFuzzer both report it). */
#include <errno.h>
#include <fenv.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "expr.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define CHECK(c)                                                                \
    do {                                                                        \
        if (!(c)) {                                                             \
            fprintf(stderr, "fuzz_expr: %s:%d: check failed: %s\n", __FILE__,   \
                    __LINE__, #c);                                              \
            abort();                                                            \
        }                                                                       \
    } while (0)

static int same(double a, double b)
{
    return (a != a && b != b) || !memcmp(&a, &b, sizeof a);
}

/* F at p, or NaN where the evaluation hit a pole exactly (x/0, log(0)):
 * the sign of that infinity comes from the sign of a zero, which intervals
 * do not carry; such points are outside F's domain, like NaN points. */
static double defined_point(expr_vm *vm, const double p[3])
{
    feclearexcept(FE_DIVBYZERO);
    double v = expr_vm_point(vm, 0, p[0], p[1], p[2]);
    return fetestexcept(FE_DIVBYZERO) ? NAN : v;
}

static void corner(const ival box[3], int k, double p[3])
{
    for (int j = 0; j < 3; j++)
        p[j] = k == 8 ? 0.5 * (box[j].lo + box[j].hi) : (k >> j) & 1 ? box[j].hi : box[j].lo;
}

static void check_box(expr_vm *vm, const ival box[3])
{
    ival I = expr_vm_ival(vm, 0, box[0], box[1], box[2]);
    CHECK(ival_is_nan(I) || I.lo <= I.hi);
    double p[3], g[3];
    for (int k = 0; k < 9; k++) {
        corner(box, k, p);
        double v = defined_point(vm, p);
        CHECK(isnan(v) || ival_is_nan(I) || (I.lo <= v && v <= I.hi));
        CHECK(isnan(v) || same(v, expr_vm_grad(vm, 0, p[0], p[1], p[2], g)));
    }
    expr_vm_prune(vm, 0);
    CHECK(expr_vm_length(vm, 1) <= expr_vm_length(vm, 0));
    for (int k = 0; k < 9; k++) {
        corner(box, k, p);
        double v0 = defined_point(vm, p);
        CHECK(isnan(v0) || same(v0, expr_vm_point(vm, 1, p[0], p[1], p[2])));
    }
    /* a sub-box with the pruned tape, and one level further */
    ival sub[3] = {{box[0].lo, 0.5 * (box[0].lo + box[0].hi)}, box[1], box[2]};
    ival J = expr_vm_ival(vm, 1, sub[0], sub[1], sub[2]);
    corner(sub, 8, p);
    double v = defined_point(vm, p);
    CHECK(isnan(v) || ival_is_nan(J) || (J.lo <= v && v <= J.hi));
    expr_vm_prune(vm, 1);
    CHECK(isnan(v) || same(v, expr_vm_point(vm, 2, p[0], p[1], p[2])));
}

static void run(const expr_tape *t)
{
    static const ival boxes[][3] = {
        {{-1, 1}, {-1, 1}, {-1, 1}},
        {{0.25, 0.375}, {-0.5, -0.25}, {0.75, 1}},
        {{0, 0.125}, {0, 0.125}, {0, 0.125}},       /* a corner at the origin */
        {{-0.5, -0.25}, {-0.125, 0.125}, {-2, 2}},  /* straddles theta's cut */
        {{1e-3, 1e-3}, {2, 2}, {-3, -3}},           /* a point box */
    };
    expr_vm *vm;
    CHECK(expr_vm_new(t, 4, &vm) == 0);
    for (size_t b = 0; b < sizeof boxes / sizeof boxes[0]; b++) check_box(vm, boxes[b]);
    expr_vm_free(vm);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    expr_limits lim = {.max_source_bytes = 4096, .max_depth = 48, .max_nodes = 1500};
    char *src = malloc(size + 1);
    if (!src) return 0;
    memcpy(src, data, size);
    src[size] = 0;
    expr_tape *t = NULL;
    expr_error err;
    int rc = expr_compile(src, size, &lim, &t, &err);
    free(src);
    if (rc) {
        CHECK(rc == -EINVAL || rc == -E2BIG || rc == -ENOMEM);
        CHECK(t == NULL && err.msg[0] && memchr(err.msg, 0, sizeof err.msg));
        CHECK(err.code == rc);
        CHECK(err.line >= 0 && err.col >= 0 && (size_t)err.line <= size + 1);
        return 0;
    }
    size_t n = expr_tape_bytes(t);
    CHECK(expr_tape_validate(t, n) == 0);
    /* evaluate a moved copy, the original scribbled over and freed */
    void *copy = malloc(n);
    CHECK(copy != NULL);
    memcpy(copy, t, n);
    memset(t, 0x5a, n);
    expr_tape_free(t);
    run(copy);
    free(copy);
    return 0;
}
