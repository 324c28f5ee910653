/* expr_grad — forward-mode gradient: each register carries its value and
 * its three partial derivatives.  Values are computed exactly as the point
 * evaluator does.  Where a derivative does not exist (abs at 0, min/max
 * ties, r/theta/phi on the axis or at the origin, sqrt at 0) a finite
 * one-sided or zero derivative is produced instead of inf/NaN.
 */
#include "expr_impl.h"

typedef expr_grad_reg G;

/* k * d where a zero factor wins: an infinite k on a constant operand, or an
 * inf/NaN partial under a function that is flat there (atan2 of an infinite
 * argument), give 0 rather than NaN. */
static inline double scale(double k, double d) { return k != 0 && d != 0 ? k * d : 0; }

/* out = f(a) with f'(a) = k. */
static G chain1(double v, double k, const G *a)
{
    G r = {v, {0, 0, 0}};
    for (int j = 0; j < 3; j++) r.d[j] = scale(k, a->d[j]);
    return r;
}

/* out = f(a, b) with partials ka, kb. */
static G chain2(double v, double ka, const G *a, double kb, const G *b)
{
    G r = {v, {0, 0, 0}};
    for (int j = 0; j < 3; j++) r.d[j] = scale(ka, a->d[j]) + scale(kb, b->d[j]);
    return r;
}

static G g_sqrt(const G *a)
{
    double s = sqrt(a->v);
    return chain1(s, s > 0 ? 0.5 / s : 0, a);
}

static G g_pow(const G *a, const G *b)
{
    double v = expr_pt_pow(a->v, b->v);
    double ka = b->v == 0 ? 0 : b->v * pow(a->v, b->v - 1);
    double kb = a->v > 0 ? v * log(a->v) : 0;
    return chain2(v, ka, a, kb, b);
}

static G g_blend(const G *d, const G *R)
{
    double v = expr_pt_blend(d->v, R->v);
    if (v == 0) return (G){0, {0, 0, 0}};
    double t = d->v * d->v - R->v * R->v, r2 = R->v * R->v, r8 = r2 * r2 * r2 * r2;
    /* d/dd (t^4/R^8) = 8 d t^3 / R^8; R is a compile-time constant */
    return chain1(v, 8 * d->v * t * t * t / r8, d);
}

/* r, theta, phi from x, y, z (whose partials are the unit vectors). */
static G g_r(double x, double y, double z)
{
    double r = expr_pt_r(x, y, z);
    if (!(r > 0)) return (G){r, {0, 0, 0}};
    return (G){r, {x / r, y / r, z / r}};
}

static G g_theta(double x, double y)
{
    double q = x * x + y * y;
    if (!(q > 0)) return (G){atan2(y, x), {0, 0, 0}};
    return (G){atan2(y, x), {-y / q, x / q, 0}};
}

static G g_phi(double x, double y, double z)
{
    double q = x * x + y * y, rho = sqrt(q), r2 = q + z * z;
    double v = expr_pt_phi(x, y, z);
    if (!(rho > 0) || !(r2 > 0)) return (G){v, {0, 0, 0}};
    double k = z / (r2 * rho);
    return (G){v, {x * k, y * k, -rho / r2}};
}

static G g_unary(int op, int imm, const G *a)
{
    double v = a->v;
    switch (op) {
    case EXPR_OP_SQRT: return g_sqrt(a);
    case EXPR_OP_ABS: return chain1(fabs(v), v < 0 ? -1 : 1, a);
    case EXPR_OP_SIN: return chain1(sin(v), cos(v), a);
    case EXPR_OP_COS: return chain1(cos(v), -sin(v), a);
    case EXPR_OP_TAN: { double t = tan(v); return chain1(t, 1 + t * t, a); }
    case EXPR_OP_ASIN: return chain1(asin(v), 1 / sqrt(1 - v * v), a);
    case EXPR_OP_ACOS: return chain1(acos(v), -1 / sqrt(1 - v * v), a);
    case EXPR_OP_ATAN: return chain1(atan(v), 1 / (1 + v * v), a);
    case EXPR_OP_EXP: { double e = exp(v); return chain1(e, e, a); }
    case EXPR_OP_LOG: return chain1(log(v), 1 / v, a);
    case EXPR_OP_POWI: return chain1(pow(v, imm), imm * pow(v, imm - 1), a);
    default: return (G){NAN, {NAN, NAN, NAN}};
    }
}

static G g_binary(int op, const G *a, const G *b)
{
    double x = a->v, y = b->v;
    switch (op) {
    case EXPR_OP_DIV: return chain2(x / y, 1 / y, a, -x / (y * y), b);
    case EXPR_OP_ATAN2: {
        double q = x * x + y * y;
        /* flat at the origin (no derivative) and at infinity */
        if (!(q > 0) || isinf(q)) return (G){atan2(x, y), {0, 0, 0}};
        return chain2(atan2(x, y), y / q, a, -x / q, b);
    }
    case EXPR_OP_POW: return g_pow(a, b);
    case EXPR_OP_BLEND: return g_blend(a, b);
    default: return (G){NAN, {NAN, NAN, NAN}};
    }
}

/* The arithmetic ops inline (plain products: a zero-times-infinite partial
 * only arises where the value is infinite too); the rest through g_unary,
 * g_binary with the guarded chain rule. */
#define GD(E) for (int j = 0; j < 3; j++) o->d[j] = (E)

double expr_vm_grad(expr_vm *vm, int d, double x, double y, double z, double grad[3])
{
    const expr_vm_depth *dp = &vm->dep[expr_vm_clamp(vm, d)];
    const expr_insn *c = dp->code;
    G *R = vm->gr;
    R[0] = (G){x, {1, 0, 0}};
    R[1] = (G){y, {0, 1, 0}};
    R[2] = (G){z, {0, 0, 1}};
    for (uint32_t i = 0, n = dp->len; i < n; i++) {
        const expr_insn in = c[i];
        const G a = R[in.a]; /* copies: out may be an input's register */
        G b, *o = &R[in.out];
        switch (in.op) {
        case EXPR_OP_ADD: b = R[in.b]; o->v = a.v + b.v; GD(a.d[j] + b.d[j]); break;
        case EXPR_OP_SUB: b = R[in.b]; o->v = a.v - b.v; GD(a.d[j] - b.d[j]); break;
        case EXPR_OP_MUL: b = R[in.b]; o->v = a.v * b.v; GD(b.v * a.d[j] + a.v * b.d[j]); break;
        case EXPR_OP_NEG: o->v = -a.v; GD(-a.d[j]); break;
        case EXPR_OP_SQR: o->v = a.v * a.v; GD(2 * a.v * a.d[j]); break;
        case EXPR_OP_SQRT: {
            double s = sqrt(a.v), k = s > 0 ? 0.5 / s : 0; /* 0 at 0: finite */
            o->v = s;
            GD(k * a.d[j]);
            break;
        }
        case EXPR_OP_MIN: b = R[in.b]; *o = expr_min_left(a.v, b.v) ? a : b; break;
        case EXPR_OP_MAX: b = R[in.b]; *o = expr_max_left(a.v, b.v) ? a : b; break;
        case EXPR_OP_R: *o = g_r(x, y, z); break;
        case EXPR_OP_THETA: *o = g_theta(x, y); break;
        case EXPR_OP_PHI: *o = g_phi(x, y, z); break;
        default:
            if (expr_op_arity(in.op) == 2) {
                b = R[in.b];
                *o = g_binary(in.op, &a, &b);
            } else {
                *o = g_unary(in.op, (int16_t)in.b, &a);
            }
        }
    }
    const G *res = &R[dp->result];
    for (int j = 0; j < 3; j++) grad[j] = res->d[j];
    return res->v;
}
