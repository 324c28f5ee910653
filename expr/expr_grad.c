/* expr_grad — forward-mode gradient: each register carries its value and
 * its three partial derivatives.  Values are computed exactly as the point
 * evaluator does.  Where a derivative does not exist (abs at 0, min/max
 * ties, r/theta/phi on the axis or at the origin, sqrt at 0) a finite
 * one-sided or zero derivative is produced instead of inf/NaN.
 */
#include "expr_impl.h"

#ifdef __SSE2__
#include <emmintrin.h>
#endif

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

/* ---- eight points at once ---- */

/* Lane l computes exactly what expr_vm_grad computes for point l (the same
 * expressions in the same order), so the results are bit for bit equal.
 * On x86-64 the arithmetic ops run two lanes per SSE2 instruction; the rest
 * goes lane by lane through the one-point helpers above.  out may be an
 * input's register (exactly, never partially): each pair of lanes is read
 * before it is written. */
#define LANES EXPR_LANES

typedef expr_grad8 G8;

static inline G lane_get(const G8 *r, int l)
{
    return (G){r->v[l], {r->d[0][l], r->d[1][l], r->d[2][l]}};
}

static inline void lane_set(G8 *r, int l, G g)
{
    r->v[l] = g.v;
    for (int j = 0; j < 3; j++) r->d[j][l] = g.d[j];
}

#ifdef __SSE2__
typedef __m128d v2;
#define LD(p) _mm_load_pd(p)
#define ST(p, v) _mm_store_pd((p), (v))
#define FOR_PAIRS for (int l = 0; l < nl; l += 2)

static inline v2 v_sel(v2 m, v2 a, v2 b) { return _mm_or_pd(_mm_and_pd(m, a), _mm_andnot_pd(m, b)); }

/* One op of the arithmetic ops inline in expr_vm_grad, for two lanes. */
static inline __attribute__((always_inline)) void arith2(int op, G8 *o, const G8 *a, const G8 *b, int l)
{
    v2 av = LD(&a->v[l]), bv = LD(&b->v[l]), ov, od[3];
    v2 ad[3] = {LD(&a->d[0][l]), LD(&a->d[1][l]), LD(&a->d[2][l])};
    switch (op) {
    case EXPR_OP_ADD:
        ov = _mm_add_pd(av, bv);
        for (int j = 0; j < 3; j++) od[j] = _mm_add_pd(ad[j], LD(&b->d[j][l]));
        break;
    case EXPR_OP_SUB:
        ov = _mm_sub_pd(av, bv);
        for (int j = 0; j < 3; j++) od[j] = _mm_sub_pd(ad[j], LD(&b->d[j][l]));
        break;
    case EXPR_OP_MUL:
        ov = _mm_mul_pd(av, bv);
        for (int j = 0; j < 3; j++)
            od[j] = _mm_add_pd(_mm_mul_pd(bv, ad[j]), _mm_mul_pd(av, LD(&b->d[j][l])));
        break;
    case EXPR_OP_NEG: {
        v2 sign = _mm_set1_pd(-0.0);
        ov = _mm_xor_pd(sign, av);
        for (int j = 0; j < 3; j++) od[j] = _mm_xor_pd(sign, ad[j]);
        break;
    }
    case EXPR_OP_SQR: {
        v2 k = _mm_mul_pd(_mm_set1_pd(2), av); /* 2 * a.v * a.d[j] */
        ov = _mm_mul_pd(av, av);
        for (int j = 0; j < 3; j++) od[j] = _mm_mul_pd(k, ad[j]);
        break;
    }
    case EXPR_OP_SQRT: {
        /* sqrtpd is IEEE sqrt; k = s > 0 ? 0.5 / s : 0 */
        v2 s = _mm_sqrt_pd(av);
        v2 k = _mm_and_pd(_mm_cmpgt_pd(s, _mm_setzero_pd()), _mm_div_pd(_mm_set1_pd(0.5), s));
        ov = s;
        for (int j = 0; j < 3; j++) od[j] = _mm_mul_pd(k, ad[j]);
        break;
    }
    default: { /* MIN, MAX: the winner's whole register */
        v2 left = op == EXPR_OP_MIN
                      ? _mm_or_pd(_mm_cmplt_pd(av, bv), _mm_cmpunord_pd(av, av))
                      : _mm_or_pd(_mm_cmpgt_pd(av, bv), _mm_cmpunord_pd(av, av));
        ov = v_sel(left, av, bv);
        for (int j = 0; j < 3; j++) od[j] = v_sel(left, ad[j], LD(&b->d[j][l]));
        break;
    }
    }
    ST(&o->v[l], ov);
    for (int j = 0; j < 3; j++) ST(&o->d[j][l], od[j]);
}

/* One loop per op, so that the op's switch folds away. */
#define ARITH8(NAME, OP)                                                      \
    static void NAME(G8 *o, const G8 *a, const G8 *b, int nl)                 \
    {                                                                         \
        FOR_PAIRS arith2(OP, o, a, b, l);                                     \
    }
ARITH8(add8, EXPR_OP_ADD)
ARITH8(sub8, EXPR_OP_SUB)
ARITH8(mul8, EXPR_OP_MUL)
ARITH8(neg8, EXPR_OP_NEG)
ARITH8(sqr8, EXPR_OP_SQR)
ARITH8(sqrt8, EXPR_OP_SQRT)
ARITH8(min8, EXPR_OP_MIN)
ARITH8(max8, EXPR_OP_MAX)

/* scale(k, d) for two lanes: k * d, or 0 where k or d is 0 (k != 0 holds
 * for NaN, as in scale). */
static inline v2 v_scale(v2 k, v2 d)
{
    v2 z = _mm_setzero_pd();
    return _mm_and_pd(_mm_and_pd(_mm_cmpneq_pd(k, z), _mm_cmpneq_pd(d, z)), _mm_mul_pd(k, d));
}

/* chain1 (o = f(a), f'(a) = k) with value and factor already in lanes. */
static void chain1_8(G8 *o, const G8 *a, const double *v, const double *k, int nl)
{
    FOR_PAIRS {
        v2 kk = LD(&k[l]);
        for (int j = 0; j < 3; j++) ST(&o->d[j][l], v_scale(kk, LD(&a->d[j][l])));
        ST(&o->v[l], LD(&v[l]));
    }
}

/* g_binary's division: chain2(x / y, 1 / y, a, -x / (y * y), b). */
static void div8(G8 *o, const G8 *a, const G8 *b, int nl)
{
    FOR_PAIRS {
        v2 x = LD(&a->v[l]), y = LD(&b->v[l]);
        v2 ka = _mm_div_pd(_mm_set1_pd(1), y);
        v2 kb = _mm_div_pd(_mm_xor_pd(_mm_set1_pd(-0.0), x), _mm_mul_pd(y, y));
        v2 v = _mm_div_pd(x, y);
        for (int j = 0; j < 3; j++)
            ST(&o->d[j][l], _mm_add_pd(v_scale(ka, LD(&a->d[j][l])), v_scale(kb, LD(&b->d[j][l]))));
        ST(&o->v[l], v);
    }
}

/* exp and log: libm lane by lane, the chain rule two lanes at a time
 * (g_unary: chain1(e, e, a) and chain1(log(v), 1 / v, a)). */
static int explog8(int op, G8 *o, const G8 *a, int nl)
{
    _Alignas(16) double v[LANES], k[LANES];
    if (op == EXPR_OP_EXP) {
        for (int l = 0; l < nl; l++) v[l] = k[l] = exp(a->v[l]);
    } else if (op == EXPR_OP_LOG) {
        for (int l = 0; l < nl; l++) v[l] = log(a->v[l]);
        FOR_PAIRS ST(&k[l], _mm_div_pd(_mm_set1_pd(1), LD(&a->v[l])));
    } else {
        return 0;
    }
    chain1_8(o, a, v, k, nl);
    return 1;
}

static inline void arith8(int op, G8 *o, const G8 *a, const G8 *b, int nl)
{
    switch (op) {
    case EXPR_OP_ADD: add8(o, a, b, nl); break;
    case EXPR_OP_SUB: sub8(o, a, b, nl); break;
    case EXPR_OP_MUL: mul8(o, a, b, nl); break;
    case EXPR_OP_NEG: neg8(o, a, b, nl); break;
    case EXPR_OP_SQR: sqr8(o, a, b, nl); break;
    case EXPR_OP_SQRT: sqrt8(o, a, b, nl); break;
    case EXPR_OP_MIN: min8(o, a, b, nl); break;
    default: max8(o, a, b, nl); break;
    }
}
#define GRAD8_SPECIAL 1
#else
static inline void arith8(int op, G8 *o, const G8 *a, const G8 *b, int nl)
{
    for (int l = 0; l < nl; l++) {
        G x = lane_get(a, l), y = lane_get(b, l), r;
        switch (op) {
        case EXPR_OP_ADD: r.v = x.v + y.v; for (int j = 0; j < 3; j++) r.d[j] = x.d[j] + y.d[j]; break;
        case EXPR_OP_SUB: r.v = x.v - y.v; for (int j = 0; j < 3; j++) r.d[j] = x.d[j] - y.d[j]; break;
        case EXPR_OP_MUL: r.v = x.v * y.v; for (int j = 0; j < 3; j++) r.d[j] = y.v * x.d[j] + x.v * y.d[j]; break;
        case EXPR_OP_NEG: r.v = -x.v; for (int j = 0; j < 3; j++) r.d[j] = -x.d[j]; break;
        case EXPR_OP_SQR: r.v = x.v * x.v; for (int j = 0; j < 3; j++) r.d[j] = 2 * x.v * x.d[j]; break;
        case EXPR_OP_SQRT: {
            double s = sqrt(x.v), k = s > 0 ? 0.5 / s : 0;
            r.v = s;
            for (int j = 0; j < 3; j++) r.d[j] = k * x.d[j];
            break;
        }
        case EXPR_OP_MIN: r = expr_min_left(x.v, y.v) ? x : y; break;
        default: r = expr_max_left(x.v, y.v) ? x : y; break;
        }
        lane_set(o, l, r);
    }
}
#endif

/* Lanes 0 .. nl-1 (nl even) of the points p; registers 0..2 keep their
 * unit derivatives from expr_vm_new (no instruction writes them), only
 * their values are set. */
static void grad_lanes(expr_vm *vm, int d, const expr_pts8 *p, expr_grad8 *out, int nl)
{
    const double *x = p->x, *y = p->y, *z = p->z;
    const expr_vm_depth *dp = &vm->dep[expr_vm_clamp(vm, d)];
    const expr_insn *c = dp->code;
    G8 *R = vm->gr8;
    for (int l = 0; l < nl; l++) {
        R[0].v[l] = x[l];
        R[1].v[l] = y[l];
        R[2].v[l] = z[l];
    }
    for (uint32_t i = 0, n = dp->len; i < n; i++) {
        const expr_insn in = c[i];
        G8 *o = &R[in.out];
        const G8 *a = &R[in.a], *b = expr_op_arity(in.op) == 2 ? &R[in.b] : a;
        switch (in.op) {
        case EXPR_OP_ADD:
        case EXPR_OP_SUB:
        case EXPR_OP_MUL:
        case EXPR_OP_MIN:
        case EXPR_OP_MAX:
            arith8(in.op, o, a, b, nl);
            break;
        case EXPR_OP_NEG:
        case EXPR_OP_SQR:
        case EXPR_OP_SQRT:
            arith8(in.op, o, a, b, nl); /* b is a: not read */
            break;
#ifdef GRAD8_SPECIAL
        case EXPR_OP_DIV: div8(o, a, b, nl); break;
        case EXPR_OP_EXP:
        case EXPR_OP_LOG: explog8(in.op, o, a, nl); break;
#endif
        case EXPR_OP_R:
            for (int l = 0; l < nl; l++) lane_set(o, l, g_r(x[l], y[l], z[l]));
            break;
        case EXPR_OP_THETA:
            for (int l = 0; l < nl; l++) lane_set(o, l, g_theta(x[l], y[l]));
            break;
        case EXPR_OP_PHI:
            for (int l = 0; l < nl; l++) lane_set(o, l, g_phi(x[l], y[l], z[l]));
            break;
        default:
            if (expr_op_arity(in.op) == 2) {
                for (int l = 0; l < nl; l++) {
                    G ga = lane_get(a, l), gb = lane_get(b, l);
                    lane_set(o, l, g_binary(in.op, &ga, &gb));
                }
            } else {
                for (int l = 0; l < nl; l++) {
                    G ga = lane_get(a, l);
                    lane_set(o, l, g_unary(in.op, (int16_t)in.b, &ga));
                }
            }
        }
    }
    const G8 *res = &R[dp->result];
    for (int l = 0; l < nl; l++) {
        out->v[l] = res->v[l];
        for (int j = 0; j < 3; j++) out->d[j][l] = res->d[j][l];
    }
}

void expr_vm_grad8(expr_vm *vm, int d, const expr_pts8 *p, expr_grad8 *out)
{
    grad_lanes(vm, d, p, out, EXPR_LANES);
}

void expr_vm_grad8n(expr_vm *vm, int d, int n, const expr_pts8 *p, expr_grad8 *out)
{
    n = n < 1 ? 1 : n > EXPR_LANES ? EXPR_LANES : n;
    grad_lanes(vm, d, p, out, (n + 1) & ~1);
}
