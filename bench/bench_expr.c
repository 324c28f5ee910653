/* bench_expr — ns per evaluation of the expression vm (built and run by
 * `make bench`; alone: make build/release/bench_expr).
 *
 * Prints, per expression: tape length, then ns per interval evaluation
 * (random boxes of one octree level), per point and per gradient
 * evaluation, and for min/max scenes the same after pruning to a small box,
 * and the cost of expr_vm_prune.  Each figure is the best of 5 runs.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bench_util.h"
#include "expr.h"

#define NBOX 1024

static double urand(void) { return rand() / (RAND_MAX + 1.0); }

static ival boxes[NBOX][3];

static void make_boxes(double lo, double hi, double w)
{
    for (int i = 0; i < NBOX; i++)
        for (int j = 0; j < 3; j++) {
            double c = lo + (hi - lo) * urand();
            boxes[i][j] = ival_make(c, c + w);
        }
}

/* Each figure is the best of REPS runs: the machine is shared. */
#define REPS 5

static double bench_ival1(expr_vm *vm, int d, long n)
{
    double sink = 0, t0 = now();
    for (long i = 0; i < n; i++) {
        const ival *b = boxes[i & (NBOX - 1)];
        ival v = expr_vm_ival(vm, d, b[0], b[1], b[2]);
        sink += v.lo;
    }
    double t = now() - t0;
    if (sink == 12345.678) puts("");
    return t / n * 1e9;
}

static double bench_ival(expr_vm *vm, int d, long n)
{
    double best = 1e300;
    for (int r = 0; r < REPS; r++) {
        double t = bench_ival1(vm, d, n / REPS);
        best = t < best ? t : best;
    }
    return best;
}

static double bench_point1(expr_vm *vm, int d, long n, int grad)
{
    double sink = 0, g[3], t0 = now();
    for (long i = 0; i < n; i++) {
        const ival *b = boxes[i & (NBOX - 1)];
        sink += grad ? expr_vm_grad(vm, d, b[0].lo, b[1].lo, b[2].lo, g)
                     : expr_vm_point(vm, d, b[0].lo, b[1].lo, b[2].lo);
    }
    double t = now() - t0;
    if (sink == 12345.678) puts("");
    return t / n * 1e9;
}

static double bench_point(expr_vm *vm, int d, long n, int grad)
{
    double best = 1e300;
    for (int r = 0; r < REPS; r++) {
        double t = bench_point1(vm, d, n / REPS, grad);
        best = t < best ? t : best;
    }
    return best;
}

static void run(const char *name, const char *src, const ival small[3])
{
    expr_tape *t;
    expr_error e;
    expr_vm *vm;
    if (expr_compile(src, strlen(src), NULL, &t, &e) || expr_vm_new(t, 4, &vm)) {
        fprintf(stderr, "%s: %d:%d: %s\n", name, e.line, e.col, e.msg);
        exit(1);
    }
    long n = 2000000 / (1 + expr_tape_length(t) / 8);
    printf("%-22s len %4u  ival %7.1f ns  point %7.1f ns  grad %7.1f ns\n", name,
           expr_tape_length(t), bench_ival(vm, 0, n), bench_point(vm, 0, n, 0),
           bench_point(vm, 0, n, 1));
    if (small) {
        /* prune cost: evaluate the small box at depth 0, prune into depth 1 */
        double t0 = now();
        long np = n / 4;
        for (long i = 0; i < np; i++) {
            expr_vm_ival(vm, 0, small[0], small[1], small[2]);
            expr_vm_prune(vm, 0);
        }
        double tp = (now() - t0) / np * 1e9;
        printf("%-22s len %4u  ival %7.1f ns  point %7.1f ns  grad %7.1f ns"
               "  (eval+prune %.0f ns)\n", "  pruned to small box", expr_vm_length(vm, 1),
               bench_ival(vm, 1, n), bench_point(vm, 1, n, 0), bench_point(vm, 1, n, 1), tp);
    }
    expr_vm_free(vm);
    expr_tape_free(t);
}

int main(void)
{
    srand(1);
    make_boxes(-1, 1, 2.0 / 64);
    run("sphere", "sqrt(x^2+y^2+z^2)-0.8", NULL);
    run("scene 2", "sin(4*theta)*sin(8*phi) - r", NULL);

    static char src[1 << 16];
    char *p = src + sprintf(src, "min(");
    double c0[3] = {0};
    for (int i = 0; i < 64; i++) {
        double c[3] = {2 * urand() - 1, 2 * urand() - 1, 2 * urand() - 1};
        if (!i) memcpy(c0, c, sizeof c);
        p += sprintf(p, "%ssqrt((x-%.4f)^2+(y-%.4f)^2+(z-%.4f)^2)-%.3f", i ? ", " : "", c[0],
                     c[1], c[2], 0.05 + 0.1 * urand());
    }
    strcpy(p, ")");
    ival small[3];
    for (int j = 0; j < 3; j++) small[j] = ival_make(c0[j] - 0.01, c0[j] + 0.01);
    run("min of 64 spheres", src, small);
    return 0;
}
