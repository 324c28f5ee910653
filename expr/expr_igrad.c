/* expr_igrad — forward-mode gradient over intervals: each register carries
 * an interval of its value and one of each partial derivative, enclosing
 * what expr_vm_grad computes at every point of the box where that is not
 * NaN (its conventions included: a zero derivative of sqrt at 0, abs's +1
 * at 0, a min/max tie's either side, r's zero gradient at the origin).
 * Only the ops below are supported; a tape with another gives -ENOTSUP.
 */
#include <errno.h>

#include "expr_impl.h"

typedef expr_igrad_reg IG;

/* The hull of a and b (a NaN in either: NaN). */
static ival hull(ival a, ival b)
{
    if (ival_is_nan(a) || ival_is_nan(b)) return ival_nan();
    return ival_make(a.lo < b.lo ? a.lo : b.lo, a.hi > b.hi ? a.hi : b.hi);
}

/* o->d = k * a->d (the chain rule of a unary op with derivative k). */
static void chain(IG *o, ival k, const IG *a)
{
    for (int j = 0; j < 3; j++) o->d[j] = ival_mul(k, a->d[j]);
}

/* A min or max: the side that wins on the whole box, else the hull. */
static IG pick(int op, const IG *a, const IG *b)
{
    int left = op == EXPR_OP_MIN ? a->v.hi < b->v.lo : a->v.lo > b->v.hi;
    int right = op == EXPR_OP_MIN ? b->v.hi <= a->v.lo : b->v.lo >= a->v.hi;
    if (left) return *a;
    if (right) return *b;
    IG o = {op == EXPR_OP_MIN ? ival_min(a->v, b->v) : ival_max(a->v, b->v), {{0, 0}}};
    for (int j = 0; j < 3; j++) o.d[j] = hull(a->d[j], b->d[j]);
    return o;
}

/* r = |(x, y, z)|, its partials x / r ... in [-1, 1] (0 at the origin). */
static IG radius(const IG *x, const IG *y, const IG *z)
{
    IG o = {ival_r(x->v, y->v, z->v), {{0, 0}}};
    const ival unit = ival_make(-1 - 0x1p-40, 1 + 0x1p-40), zero = ival_point(0);
    const IG *c[3] = {x, y, z};
    for (int j = 0; j < 3; j++) {
        ival q = hull(ival_div(c[j]->v, o.v), zero);
        o.d[j] = ival_make(q.lo < unit.lo ? unit.lo : q.lo, q.hi > unit.hi ? unit.hi : q.hi);
    }
    return o;
}

static int bounded(ival a) { return isfinite(a.lo) && isfinite(a.hi); }

/* One instruction; 0, or -ENOTSUP for an op without an interval gradient
 * here.  *partial := 1 where the op may be undefined (NaN) on part of the
 * box. */
static int step(const expr_insn in, IG *R, int *partial)
{
    const IG a = R[in.a], b = expr_op_arity(in.op) == 2 ? R[in.b] : a;
    IG o = {ival_point(0), {{0, 0}}};
    switch (in.op) {
    case EXPR_OP_ADD:
        o.v = ival_add(a.v, b.v);
        for (int j = 0; j < 3; j++) o.d[j] = ival_add(a.d[j], b.d[j]);
        break;
    case EXPR_OP_SUB:
        o.v = ival_sub(a.v, b.v);
        for (int j = 0; j < 3; j++) o.d[j] = ival_sub(a.d[j], b.d[j]);
        break;
    case EXPR_OP_MUL:
        o.v = ival_mul(a.v, b.v);
        for (int j = 0; j < 3; j++)
            o.d[j] = ival_add(ival_mul(b.v, a.d[j]), ival_mul(a.v, b.d[j]));
        break;
    case EXPR_OP_DIV:
        *partial |= ival_contains_zero(b.v);
        o.v = ival_div(a.v, b.v);
        for (int j = 0; j < 3; j++)
            o.d[j] = ival_add(ival_mul(ival_div(ival_point(1), b.v), a.d[j]),
                              ival_mul(ival_div(ival_neg(a.v), ival_sqr(b.v)), b.d[j]));
        break;
    case EXPR_OP_NEG:
        o.v = ival_neg(a.v);
        for (int j = 0; j < 3; j++) o.d[j] = ival_neg(a.d[j]);
        break;
    case EXPR_OP_SQR:
        o.v = ival_sqr(a.v);
        chain(&o, ival_mul(ival_point(2), a.v), &a);
        break;
    case EXPR_OP_SQRT: {
        *partial |= !(a.v.lo >= 0);
        o.v = ival_sqrt(a.v);
        ival k = ival_div(ival_point(0.5), o.v);
        chain(&o, o.v.lo > 0 ? k : hull(k, ival_point(0)), &a);
        break;
    }
    case EXPR_OP_ABS:
        o.v = ival_abs(a.v);
        chain(&o, a.v.lo >= 0 ? ival_point(1) : a.v.hi < 0 ? ival_point(-1) : ival_make(-1, 1),
              &a);
        break;
    case EXPR_OP_SIN:
        o.v = ival_sin(a.v);
        chain(&o, ival_cos(a.v), &a);
        break;
    case EXPR_OP_COS:
        o.v = ival_cos(a.v);
        chain(&o, ival_neg(ival_sin(a.v)), &a);
        break;
    case EXPR_OP_EXP:
        o.v = ival_exp(a.v);
        chain(&o, o.v, &a);
        break;
    case EXPR_OP_POWI: {
        int n = (int16_t)in.b;
        if (n < 1) return -ENOTSUP;
        o.v = ival_powi(a.v, n);
        chain(&o, ival_mul(ival_point(n), ival_powi(a.v, n - 1)), &a);
        break;
    }
    case EXPR_OP_MIN: case EXPR_OP_MAX: o = pick(in.op, &a, &b); break;
    case EXPR_OP_R: o = radius(&R[0], &R[1], &R[2]); break;
    default: return -ENOTSUP;
    }
    /* an infinite bound may hide a NaN (inf - inf, 0 * inf) at a point */
    *partial |= !bounded(o.v) || !bounded(o.d[0]) || !bounded(o.d[1]) || !bounded(o.d[2]);
    R[in.out] = o;
    return 0;
}

int expr_vm_ival_grad(expr_vm *vm, ival x, ival y, ival z, expr_igrad *out)
{
    const expr_vm_depth *dp = &vm->dep[0];
    IG *R = vm->igr;
    const ival one = ival_point(1), zero = ival_point(0);
    R[0] = (IG){x, {one, zero, zero}};
    R[1] = (IG){y, {zero, one, zero}};
    R[2] = (IG){z, {zero, zero, one}};
    int partial = 0;
    for (uint32_t i = 0; i < dp->len; i++) {
        int rc = step(dp->code[i], R, &partial);
        if (rc) return rc;
    }
    const IG *res = &R[dp->result];
    out->f = res->v;
    for (int j = 0; j < 3; j++) out->grad[j] = res->d[j];
    out->total = !partial;
    return 0;
}
