/* expr_eval — the vm: point, interval and gradient evaluators over a tape,
 * and pruning of min/max branches per subdivision depth.
 *
 * Each depth d has its tape: depth 0 is the compiled tape itself; depth d+1
 * is written by expr_vm_prune(d) into a buffer preallocated at expr_vm_new,
 * or simply points at tape d when nothing was decided.  The interval
 * evaluator records, per min/max instruction, which side can win on the box;
 * pruning renames the decided min/max to the winning operand (no copy is
 * emitted), drops what became dead and allocates registers again.
 */
#include <errno.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include "expr_impl.h"

/* ---- per-op semantics (for folding; the loops below inline the same) ---- */

double expr_pt_op(int op, int imm, double a, double b)
{
    switch (op) {
    case EXPR_OP_NEG: return -a;
    case EXPR_OP_SQR: return a * a;
    case EXPR_OP_SQRT: return sqrt(a);
    case EXPR_OP_ABS: return fabs(a);
    case EXPR_OP_SIN: return sin(a);
    case EXPR_OP_COS: return cos(a);
    case EXPR_OP_TAN: return tan(a);
    case EXPR_OP_ASIN: return asin(a);
    case EXPR_OP_ACOS: return acos(a);
    case EXPR_OP_ATAN: return atan(a);
    case EXPR_OP_EXP: return exp(a);
    case EXPR_OP_LOG: return log(a);
    case EXPR_OP_POWI: return pow(a, (double)imm);
    case EXPR_OP_ADD: return a + b;
    case EXPR_OP_SUB: return a - b;
    case EXPR_OP_MUL: return a * b;
    case EXPR_OP_DIV: return a / b;
    case EXPR_OP_MIN: return expr_min_left(a, b) ? a : b;
    case EXPR_OP_MAX: return expr_max_left(a, b) ? a : b;
    case EXPR_OP_ATAN2: return atan2(a, b);
    case EXPR_OP_POW: return expr_pt_pow(a, b);
    case EXPR_OP_BLEND: return expr_pt_blend(a, b);
    default: return NAN;
    }
}

ival expr_iv_op(int op, int imm, ival a, ival b)
{
    switch (op) {
    case EXPR_OP_NEG: return ival_neg(a);
    case EXPR_OP_SQR: return ival_sqr(a);
    case EXPR_OP_SQRT: return ival_sqrt(a);
    case EXPR_OP_ABS: return ival_abs(a);
    case EXPR_OP_SIN: return ival_sin(a);
    case EXPR_OP_COS: return ival_cos(a);
    case EXPR_OP_TAN: return ival_tan(a);
    case EXPR_OP_ASIN: return ival_asin(a);
    case EXPR_OP_ACOS: return ival_acos(a);
    case EXPR_OP_ATAN: return ival_atan(a);
    case EXPR_OP_EXP: return ival_exp(a);
    case EXPR_OP_LOG: return ival_log(a);
    case EXPR_OP_POWI: return ival_powi(a, imm);
    case EXPR_OP_ADD: return ival_add(a, b);
    case EXPR_OP_SUB: return ival_sub(a, b);
    case EXPR_OP_MUL: return ival_mul(a, b);
    case EXPR_OP_DIV: return ival_div(a, b);
    case EXPR_OP_MIN: return ival_min(a, b);
    case EXPR_OP_MAX: return ival_max(a, b);
    case EXPR_OP_ATAN2: return ival_atan2(a, b);
    case EXPR_OP_POW: return ival_pow(a, b);
    case EXPR_OP_BLEND: return ival_blend(a, b);
    default: return ival_make(NAN, NAN);
    }
}

/* ---- vm ---- */

static void preload(expr_vm *vm)
{
    const expr_const *c = expr_tape_consts(vm->t);
    for (uint32_t j = 0; j < vm->t->nconst; j++) {
        uint32_t r = EXPR_NVARS + j;
        vm->ir[r] = ival_make(c[j].lo, c[j].hi);
        vm->pr[r] = c[j].v;
        vm->gr[r] = (expr_grad_reg){c[j].v, {0, 0, 0}};
        vm->igr[r] = (expr_igrad_reg){vm->ir[r], {{0, 0}, {0, 0}, {0, 0}}};
        for (int l = 0; l < EXPR_LANES; l++) {
            vm->ir8[r].lo[l] = c[j].lo;
            vm->ir8[r].hi[l] = c[j].hi;
            vm->gr8[r].v[l] = c[j].v;
            for (int a = 0; a < 3; a++) vm->gr8[r].d[a][l] = 0;
        }
    }
    /* x, y, z: their derivatives are the unit vectors, set once */
    for (int a = 0; a < 3; a++)
        for (int j = 0; j < 3; j++)
            for (int l = 0; l < EXPR_LANES; l++) vm->gr8[a].d[j][l] = j == a;
}

/* Zeroed memory aligned for the lane registers' vector loads. */
static void *calloc_aligned(size_t n, size_t size)
{
    size_t bytes = n * size, align = 64;
    if (size && n > SIZE_MAX / size) return NULL;
    bytes = (bytes + align - 1) / align * align;
    void *p = aligned_alloc(align, bytes ? bytes : align);
    if (p) memset(p, 0, bytes);
    return p;
}

static int vm_alloc(expr_vm *vm)
{
    uint32_t n = vm->n0 ? vm->n0 : 1;
    vm->ir = calloc(vm->nregs, sizeof *vm->ir);
    vm->pr = calloc(vm->nregs, sizeof *vm->pr);
    vm->gr = calloc(vm->nregs, sizeof *vm->gr);
    vm->ir8 = calloc_aligned(vm->nregs, sizeof *vm->ir8);
    vm->gr8 = calloc_aligned(vm->nregs, sizeof *vm->gr8);
    vm->igr = calloc(vm->nregs, sizeof *vm->igr);
    vm->ssa = calloc(n, sizeof *vm->ssa);
    vm->cur = calloc(vm->nregs, sizeof *vm->cur);
    vm->ra.regof = calloc(n, sizeof *vm->ra.regof);
    vm->ra.freelist = calloc(vm->nregs, sizeof *vm->ra.freelist);
    if (!vm->ir || !vm->pr || !vm->gr || !vm->ir8 || !vm->gr8 || !vm->igr || !vm->ssa || !vm->cur || !vm->ra.regof ||
        !vm->ra.freelist)
        return -ENOMEM;
    for (int d = 0; d <= vm->max_depth; d++) {
        expr_vm_depth *dp = &vm->dep[d];
        dp->code = expr_tape_code(vm->t);
        dp->len = vm->t->len;
        dp->result = vm->t->result;
        if (!(dp->choice = calloc(n, 1))) return -ENOMEM;
        if (!(dp->choice8 = calloc(n, EXPR_LANES))) return -ENOMEM;
        if (d > 0 && !(dp->buf = calloc(n, sizeof *dp->buf))) return -ENOMEM;
    }
    return 0;
}

void expr_vm_free(expr_vm *vm)
{
    if (!vm) return;
    free(vm->ir);
    free(vm->pr);
    free(vm->gr);
    free(vm->ir8);
    free(vm->gr8);
    free(vm->igr);
    free(vm->ssa);
    free(vm->cur);
    free(vm->ra.regof);
    free(vm->ra.freelist);
    for (int d = 0; d <= EXPR_VM_MAX_DEPTH; d++) {
        free(vm->dep[d].choice);
        free(vm->dep[d].choice8);
        free(vm->dep[d].buf);
    }
    free(vm);
}

int expr_vm_new(const expr_tape *t, int max_depth, expr_vm **out)
{
    *out = NULL;
    if (max_depth < 0 || max_depth > EXPR_VM_MAX_DEPTH) return -EINVAL;
    int rc = expr_tape_validate(t, expr_tape_bytes(t));
    if (rc) return rc;
    expr_vm *vm = calloc(1, sizeof *vm);
    if (!vm) return -ENOMEM;
    vm->t = t;
    vm->max_depth = max_depth;
    vm->nregs = t->nregs;
    vm->nfixed = EXPR_NVARS + t->nconst;
    vm->n0 = t->len;
    if ((rc = vm_alloc(vm))) {
        expr_vm_free(vm);
        return rc;
    }
    preload(vm);
    *out = vm;
    return 0;
}

uint32_t expr_vm_length(const expr_vm *vm, int d)
{
    return vm->dep[expr_vm_clamp(vm, d)].len;
}

/* ---- interval evaluation: the hot loop ---- */

#define IV1(OP, F) case OP: R[in.out] = F(R[in.a]); break
#define IV2(OP, F) case OP: R[in.out] = F(R[in.a], R[in.b]); break

ival expr_vm_ival(expr_vm *vm, int d, ival x, ival y, ival z)
{
    expr_vm_depth *dp = &vm->dep[expr_vm_clamp(vm, d)];
    const expr_insn *c = dp->code;
    uint8_t *ch = dp->choice;
    uint32_t n = dp->len, decided = 0;
    ival *R = vm->ir;
    R[0] = x;
    R[1] = y;
    R[2] = z;
    for (uint32_t i = 0; i < n; i++) {
        const expr_insn in = c[i];
        switch (in.op) {
        IV2(EXPR_OP_ADD, ival_add);
        IV2(EXPR_OP_SUB, ival_sub);
        IV2(EXPR_OP_MUL, ival_mul);
        IV2(EXPR_OP_DIV, ival_div);
        IV1(EXPR_OP_SQR, ival_sqr);
        IV1(EXPR_OP_SQRT, ival_sqrt);
        IV1(EXPR_OP_NEG, ival_neg);
        IV1(EXPR_OP_ABS, ival_abs);
        case EXPR_OP_MIN: {
            ival a = R[in.a], b = R[in.b];
            uint8_t k = a.hi < b.lo ? EXPR_CH_LEFT : b.hi < a.lo ? EXPR_CH_RIGHT : EXPR_CH_BOTH;
            ch[i] = k;
            decided += k != EXPR_CH_BOTH;
            R[in.out] = k == EXPR_CH_LEFT ? a : k == EXPR_CH_RIGHT ? b : ival_min(a, b);
            break;
        }
        case EXPR_OP_MAX: {
            ival a = R[in.a], b = R[in.b];
            uint8_t k = a.lo > b.hi ? EXPR_CH_LEFT : b.lo > a.hi ? EXPR_CH_RIGHT : EXPR_CH_BOTH;
            ch[i] = k;
            decided += k != EXPR_CH_BOTH;
            R[in.out] = k == EXPR_CH_LEFT ? a : k == EXPR_CH_RIGHT ? b : ival_max(a, b);
            break;
        }
        IV1(EXPR_OP_SIN, ival_sin);
        IV1(EXPR_OP_COS, ival_cos);
        IV1(EXPR_OP_TAN, ival_tan);
        IV1(EXPR_OP_ASIN, ival_asin);
        IV1(EXPR_OP_ACOS, ival_acos);
        IV1(EXPR_OP_ATAN, ival_atan);
        IV1(EXPR_OP_EXP, ival_exp);
        IV1(EXPR_OP_LOG, ival_log);
        IV2(EXPR_OP_ATAN2, ival_atan2);
        IV2(EXPR_OP_POW, ival_pow);
        IV2(EXPR_OP_BLEND, ival_blend);
        case EXPR_OP_POWI: R[in.out] = ival_powi(R[in.a], (int16_t)in.b); break;
        case EXPR_OP_R: R[in.out] = ival_r(R[0], R[1], R[2]); break;
        case EXPR_OP_THETA: R[in.out] = ival_theta(R[0], R[1]); break;
        case EXPR_OP_PHI: R[in.out] = ival_phi(R[0], R[1], R[2]); break;
        default: break;
        }
    }
    dp->decided = decided;
    return R[dp->result];
}

/* ---- interval evaluation of eight boxes at once ---- */

/* Every lane computes exactly the operations of the one-box function in
 * ival.h (same expressions, same order; C11 mode does not contract a*b+c
 * into an fma), so a lane's result is bit for bit the one-box result.  On
 * x86-64 the common operations run two lanes per SSE2 instruction: minpd
 * and maxpd compute "a < b ? a : b" and "a > b ? a : b" exactly (the second
 * operand when either is NaN), and the other selects are and/andnot/or on
 * compare masks.  Rare cases (NaN products, divisors containing 0) and the
 * libm-based operations go lane by lane through the one-box functions; so
 * does everything where SSE2 is missing.
 *
 * out may be the register of a or b (register reuse), never partially
 * overlapping: each pair of lanes is read before it is written. */
#define LANES EXPR_LANES

static inline ival lane(const ival8 *a, int l) { return ival_make(a->lo[l], a->hi[l]); }
static inline void set_lane(ival8 *o, int l, ival v)
{
    o->lo[l] = v.lo;
    o->hi[l] = v.hi;
}

#ifdef __SSE2__
typedef __m128d v2;
#define LD(p) _mm_load_pd(p)
#define ST(p, v) _mm_store_pd((p), (v))
#define V2(c) _mm_set1_pd(c)
#define FOR_PAIRS _Pragma("GCC unroll 4") for (int l = 0; l < LANES; l += 2)

static inline v2 v_sel(v2 m, v2 a, v2 b) { return _mm_or_pd(_mm_and_pd(m, a), _mm_andnot_pd(m, b)); }
static inline v2 v_abs(v2 a) { return _mm_andnot_pd(V2(-0.0), a); }
static inline v2 v_neg(v2 a) { return _mm_xor_pd(V2(-0.0), a); }

/* ival_widen's two bounds (the proof is in ival.h). */
static inline v2 v_widen_lo(v2 lo)
{
    lo = _mm_min_pd(V2(DBL_MAX), lo); /* lo > DBL_MAX ? DBL_MAX : lo */
    v2 e = _mm_mul_pd(V2(IVAL_PHI_), v_abs(lo));
    e = _mm_add_pd(e, V2(DBL_TRUE_MIN));
    return _mm_sub_pd(lo, e);
}

static inline v2 v_widen_hi(v2 hi)
{
    hi = _mm_max_pd(V2(-DBL_MAX), hi); /* hi < -DBL_MAX ? -DBL_MAX : hi */
    v2 e = _mm_mul_pd(V2(IVAL_PHI_), v_abs(hi));
    e = _mm_add_pd(e, V2(DBL_TRUE_MIN));
    return _mm_add_pd(hi, e);
}

static inline void add8(ival8 *o, const ival8 *a, const ival8 *b)
{
    FOR_PAIRS {
        v2 lo = _mm_add_pd(LD(&a->lo[l]), LD(&b->lo[l]));
        v2 hi = _mm_add_pd(LD(&a->hi[l]), LD(&b->hi[l]));
        ST(&o->lo[l], v_widen_lo(lo));
        ST(&o->hi[l], v_widen_hi(hi));
    }
}

static inline void sub8(ival8 *o, const ival8 *a, const ival8 *b)
{
    FOR_PAIRS {
        v2 lo = _mm_sub_pd(LD(&a->lo[l]), LD(&b->hi[l]));
        v2 hi = _mm_sub_pd(LD(&a->hi[l]), LD(&b->lo[l]));
        ST(&o->lo[l], v_widen_lo(lo));
        ST(&o->hi[l], v_widen_hi(hi));
    }
}

static inline void neg8(ival8 *o, const ival8 *a)
{
    FOR_PAIRS {
        v2 lo = v_neg(LD(&a->hi[l])), hi = v_neg(LD(&a->lo[l]));
        ST(&o->lo[l], lo);
        ST(&o->hi[l], hi);
    }
}

/* ival_abs: m = alo < -ahi ? -ahi : alo, M = -alo < ahi ? ahi : -alo,
 * then m <= 0 ? 0 : m (NaN stays). */
static inline void v_absb(v2 alo, v2 ahi, v2 *m, v2 *M)
{
    v2 mm = _mm_max_pd(v_neg(ahi), alo);
    *M = _mm_max_pd(ahi, v_neg(alo));
    *m = _mm_andnot_pd(_mm_cmple_pd(mm, V2(0)), mm);
}

static inline void abs8(ival8 *o, const ival8 *a)
{
    FOR_PAIRS {
        v2 m, M;
        v_absb(LD(&a->lo[l]), LD(&a->hi[l]), &m, &M);
        ST(&o->lo[l], m);
        ST(&o->hi[l], M);
    }
}

static inline void sqr8(ival8 *o, const ival8 *a)
{
    FOR_PAIRS {
        v2 m, M;
        v_absb(LD(&a->lo[l]), LD(&a->hi[l]), &m, &M);
        v2 lo = v_widen_lo(_mm_mul_pd(m, m)), hi = v_widen_hi(_mm_mul_pd(M, M));
        ST(&o->lo[l], _mm_andnot_pd(_mm_cmplt_pd(lo, V2(0)), lo)); /* lo < 0 ? 0 : lo */
        ST(&o->hi[l], hi);
    }
}

static inline void mul8(ival8 *o, const ival8 *a, const ival8 *b)
{
    ival8 a0, b0; /* the inputs, for lanes that take the slow path */
    int bad = 0;
    FOR_PAIRS {
        v2 alo = LD(&a->lo[l]), ahi = LD(&a->hi[l]), blo = LD(&b->lo[l]), bhi = LD(&b->hi[l]);
        v2 p0 = _mm_mul_pd(alo, blo), p1 = _mm_mul_pd(alo, bhi);
        v2 p2 = _mm_mul_pd(ahi, blo), p3 = _mm_mul_pd(ahi, bhi);
        v2 lo = _mm_min_pd(_mm_min_pd(p0, p1), _mm_min_pd(p2, p3));
        v2 hi = _mm_max_pd(_mm_max_pd(p0, p1), _mm_max_pd(p2, p3));
        v2 sum = _mm_add_pd(_mm_add_pd(_mm_add_pd(p0, p1), p2), p3);
        bad |= _mm_movemask_pd(_mm_cmpunord_pd(sum, sum)) << l;
        ST(&a0.lo[l], alo), ST(&a0.hi[l], ahi), ST(&b0.lo[l], blo), ST(&b0.hi[l], bhi);
        ST(&o->lo[l], v_widen_lo(lo));
        ST(&o->hi[l], v_widen_hi(hi));
    }
    if (__builtin_expect(bad != 0, 0))
        for (int l = 0; l < LANES; l++)
            if (bad >> l & 1) set_lane(o, l, ival_mul_special_(lane(&a0, l), lane(&b0, l)));
}

/* The usual case, every divisor of one sign (ival_div's first two
 * branches); anything else lane by lane. */
static inline void div8(ival8 *o, const ival8 *a, const ival8 *b)
{
    int pos = 0, neg = 0;
    FOR_PAIRS {
        pos |= _mm_movemask_pd(_mm_cmpgt_pd(LD(&b->lo[l]), V2(0))) << l;
        neg |= _mm_movemask_pd(_mm_cmplt_pd(LD(&b->hi[l]), V2(0))) << l;
    }
    if (pos != 0xff && !(neg == 0xff && pos == 0)) {
        for (int l = 0; l < LANES; l++) set_lane(o, l, ival_div(lane(a, l), lane(b, l)));
        return;
    }
    ival8 a0, b0;
    int bad = 0;
    FOR_PAIRS {
        v2 alo = LD(&a->lo[l]), ahi = LD(&a->hi[l]), blo = LD(&b->lo[l]), bhi = LD(&b->hi[l]);
        v2 lo, hi;
        if (pos == 0xff) {
            lo = _mm_div_pd(alo, v_sel(_mm_cmpge_pd(alo, V2(0)), bhi, blo));
            hi = _mm_div_pd(ahi, v_sel(_mm_cmpge_pd(ahi, V2(0)), blo, bhi));
        } else {
            lo = _mm_div_pd(ahi, v_sel(_mm_cmpge_pd(ahi, V2(0)), bhi, blo));
            hi = _mm_div_pd(alo, v_sel(_mm_cmpge_pd(alo, V2(0)), blo, bhi));
        }
        bad |= _mm_movemask_pd(_mm_or_pd(_mm_cmpunord_pd(lo, lo), _mm_cmpunord_pd(hi, hi))) << l;
        ST(&a0.lo[l], alo), ST(&a0.hi[l], ahi), ST(&b0.lo[l], blo), ST(&b0.hi[l], bhi);
        ST(&o->lo[l], v_widen_lo(lo));
        ST(&o->hi[l], v_widen_hi(hi));
    }
    if (__builtin_expect(bad != 0, 0))
        for (int l = 0; l < LANES; l++)
            if (bad >> l & 1) set_lane(o, l, ival_div_special_(lane(&a0, l), lane(&b0, l)));
}

/* ival_sqrt: NaN for a NaN box or one below 0, else the widened roots of
 * the part >= 0 (sqrtpd is IEEE sqrt), clamped at 0. */
static inline void sqrt8(ival8 *o, const ival8 *a)
{
    FOR_PAIRS {
        v2 alo = LD(&a->lo[l]), ahi = LD(&a->hi[l]);
        v2 bad = _mm_or_pd(_mm_cmpunord_pd(alo, ahi), _mm_cmplt_pd(ahi, V2(0)));
        v2 slo = _mm_sqrt_pd(_mm_andnot_pd(bad, _mm_max_pd(alo, V2(0)))); /* alo > 0 ? alo : 0 */
        v2 shi = _mm_sqrt_pd(_mm_andnot_pd(bad, ahi));
        v2 lo = v_widen_lo(slo), hi = v_widen_hi(shi);
        lo = _mm_andnot_pd(_mm_cmplt_pd(lo, V2(0)), lo); /* clamp at 0 */
        ST(&o->lo[l], v_sel(bad, V2(NAN), lo));
        ST(&o->hi[l], v_sel(bad, V2(NAN), hi));
    }
}

/* min/max with each lane's choice recorded, as expr_vm_ival does:
 * left when a is below (min) / above (max) b, right the other way, else
 * both, NaN when either low bound is. */
static inline void minmax8(ival8 *o, const ival8 *a, const ival8 *b, int is_min,
                           uint8_t *ch, uint32_t *decided)
{
    FOR_PAIRS {
        v2 alo = LD(&a->lo[l]), ahi = LD(&a->hi[l]), blo = LD(&b->lo[l]), bhi = LD(&b->hi[l]);
        v2 left, right, mlo, mhi;
        if (is_min) {
            left = _mm_cmplt_pd(ahi, blo);
            right = _mm_andnot_pd(left, _mm_cmplt_pd(bhi, alo));
            mlo = _mm_min_pd(alo, blo);
            mhi = _mm_min_pd(ahi, bhi);
        } else {
            left = _mm_cmpgt_pd(alo, bhi);
            right = _mm_andnot_pd(left, _mm_cmpgt_pd(blo, ahi));
            mlo = _mm_max_pd(alo, blo);
            mhi = _mm_max_pd(ahi, bhi);
        }
        v2 nan = _mm_cmpunord_pd(alo, blo);
        mlo = v_sel(nan, V2(NAN), mlo);
        mhi = v_sel(nan, V2(NAN), mhi);
        ST(&o->lo[l], v_sel(left, alo, v_sel(right, blo, mlo)));
        ST(&o->hi[l], v_sel(left, ahi, v_sel(right, bhi, mhi)));
        int ml = _mm_movemask_pd(left), mr = _mm_movemask_pd(right);
        for (int j = 0; j < 2; j++) {
            uint8_t k = (uint8_t)((ml >> j & 1) * EXPR_CH_LEFT + (mr >> j & 1) * EXPR_CH_RIGHT);
            ch[l + j] = k;
            decided[l + j] += k != EXPR_CH_BOTH;
        }
    }
}

#else /* no SSE2: the one-box functions lane by lane */

#define LANEWISE2(NAME, F)                                                    \
    static inline void NAME(ival8 *o, const ival8 *a, const ival8 *b)         \
    {                                                                         \
        for (int l = 0; l < LANES; l++) set_lane(o, l, F(lane(a, l), lane(b, l))); \
    }
#define LANEWISE1(NAME, F)                                                    \
    static inline void NAME(ival8 *o, const ival8 *a)                         \
    {                                                                         \
        for (int l = 0; l < LANES; l++) set_lane(o, l, F(lane(a, l)));        \
    }
LANEWISE2(add8, ival_add)
LANEWISE2(sub8, ival_sub)
LANEWISE2(mul8, ival_mul)
LANEWISE2(div8, ival_div)
LANEWISE1(neg8, ival_neg)
LANEWISE1(abs8, ival_abs)
LANEWISE1(sqr8, ival_sqr)
LANEWISE1(sqrt8, ival_sqrt)

static inline void minmax8(ival8 *o, const ival8 *a, const ival8 *b, int is_min,
                           uint8_t *ch, uint32_t *decided)
{
    for (int l = 0; l < LANES; l++) {
        ival x = lane(a, l), y = lane(b, l);
        uint8_t k;
        if (is_min)
            k = x.hi < y.lo ? EXPR_CH_LEFT : y.hi < x.lo ? EXPR_CH_RIGHT : EXPR_CH_BOTH;
        else
            k = x.lo > y.hi ? EXPR_CH_LEFT : y.lo > x.hi ? EXPR_CH_RIGHT : EXPR_CH_BOTH;
        ch[l] = k;
        decided[l] += k != EXPR_CH_BOTH;
        set_lane(o, l, k == EXPR_CH_LEFT ? x : k == EXPR_CH_RIGHT ? y
                       : is_min ? ival_min(x, y) : ival_max(x, y));
    }
}
#endif

#define LN1(OP, F)                                                            \
    case OP:                                                                  \
        for (int l = 0; l < LANES; l++) set_lane(o, l, F(lane(&R[in.a], l)));  \
        break
#define LN2(OP, F)                                                            \
    case OP:                                                                  \
        for (int l = 0; l < LANES; l++)                                       \
            set_lane(o, l, F(lane(&R[in.a], l), lane(&R[in.b], l)));          \
        break

ival8 *expr_vm_ival8_args(expr_vm *vm) { return vm->ir8; }

void expr_vm_ival8(expr_vm *vm, int d, const ival8 *x, const ival8 *y,
                   const ival8 *z, ival8 *out)
{
    ival8 *R = vm->ir8;
    R[0] = *x;
    R[1] = *y;
    R[2] = *z;
    *out = *expr_vm_ival8_in(vm, d);
}

const ival8 *expr_vm_ival8_in(expr_vm *vm, int d)
{
    expr_vm_depth *dp = &vm->dep[expr_vm_clamp(vm, d)];
    const expr_insn *c = dp->code;
    uint8_t *ch = dp->choice8;
    uint32_t n = dp->len;
    ival8 *R = vm->ir8;
    for (int l = 0; l < LANES; l++) dp->decided8[l] = 0;
    for (uint32_t i = 0; i < n; i++) {
        const expr_insn in = c[i];
        ival8 *o = &R[in.out];
        switch (in.op) {
        case EXPR_OP_ADD: add8(o, &R[in.a], &R[in.b]); break;
        case EXPR_OP_SUB: sub8(o, &R[in.a], &R[in.b]); break;
        case EXPR_OP_MUL: mul8(o, &R[in.a], &R[in.b]); break;
        case EXPR_OP_DIV: div8(o, &R[in.a], &R[in.b]); break;
        case EXPR_OP_SQR: sqr8(o, &R[in.a]); break;
        case EXPR_OP_SQRT: sqrt8(o, &R[in.a]); break;
        case EXPR_OP_NEG: neg8(o, &R[in.a]); break;
        case EXPR_OP_ABS: abs8(o, &R[in.a]); break;
        case EXPR_OP_MIN: minmax8(o, &R[in.a], &R[in.b], 1, &ch[(size_t)i * LANES], dp->decided8); break;
        case EXPR_OP_MAX: minmax8(o, &R[in.a], &R[in.b], 0, &ch[(size_t)i * LANES], dp->decided8); break;
        LN1(EXPR_OP_SIN, ival_sin);
        LN1(EXPR_OP_COS, ival_cos);
        LN1(EXPR_OP_TAN, ival_tan);
        LN1(EXPR_OP_ASIN, ival_asin);
        LN1(EXPR_OP_ACOS, ival_acos);
        LN1(EXPR_OP_ATAN, ival_atan);
        LN1(EXPR_OP_EXP, ival_exp);
        LN1(EXPR_OP_LOG, ival_log);
        LN2(EXPR_OP_ATAN2, ival_atan2);
        LN2(EXPR_OP_POW, ival_pow);
        LN2(EXPR_OP_BLEND, ival_blend);
        case EXPR_OP_POWI:
            for (int l = 0; l < LANES; l++)
                set_lane(o, l, ival_powi(lane(&R[in.a], l), (int16_t)in.b));
            break;
        case EXPR_OP_R:
            for (int l = 0; l < LANES; l++)
                set_lane(o, l, ival_r(lane(&R[0], l), lane(&R[1], l), lane(&R[2], l)));
            break;
        case EXPR_OP_THETA:
            for (int l = 0; l < LANES; l++)
                set_lane(o, l, ival_theta(lane(&R[0], l), lane(&R[1], l)));
            break;
        case EXPR_OP_PHI:
            for (int l = 0; l < LANES; l++)
                set_lane(o, l, ival_phi(lane(&R[0], l), lane(&R[1], l), lane(&R[2], l)));
            break;
        default: break;
        }
    }
    return &R[dp->result];
}

/* ---- point evaluation ---- */

#define PT1(OP, E) case OP: { double a = R[in.a]; R[in.out] = (E); break; }
#define PT2(OP, E) case OP: { double a = R[in.a], b = R[in.b]; R[in.out] = (E); break; }

double expr_vm_point(expr_vm *vm, int d, double x, double y, double z)
{
    const expr_vm_depth *dp = &vm->dep[expr_vm_clamp(vm, d)];
    const expr_insn *c = dp->code;
    double *R = vm->pr;
    R[0] = x;
    R[1] = y;
    R[2] = z;
    for (uint32_t i = 0, n = dp->len; i < n; i++) {
        const expr_insn in = c[i];
        switch (in.op) {
        PT2(EXPR_OP_ADD, a + b);
        PT2(EXPR_OP_SUB, a - b);
        PT2(EXPR_OP_MUL, a * b);
        PT2(EXPR_OP_DIV, a / b);
        PT1(EXPR_OP_SQR, a * a);
        PT1(EXPR_OP_SQRT, sqrt(a));
        PT1(EXPR_OP_NEG, -a);
        PT1(EXPR_OP_ABS, fabs(a));
        PT2(EXPR_OP_MIN, expr_min_left(a, b) ? a : b);
        PT2(EXPR_OP_MAX, expr_max_left(a, b) ? a : b);
        PT1(EXPR_OP_SIN, sin(a));
        PT1(EXPR_OP_COS, cos(a));
        PT1(EXPR_OP_TAN, tan(a));
        PT1(EXPR_OP_ASIN, asin(a));
        PT1(EXPR_OP_ACOS, acos(a));
        PT1(EXPR_OP_ATAN, atan(a));
        PT1(EXPR_OP_EXP, exp(a));
        PT1(EXPR_OP_LOG, log(a));
        PT2(EXPR_OP_ATAN2, atan2(a, b));
        PT2(EXPR_OP_POW, expr_pt_pow(a, b));
        PT2(EXPR_OP_BLEND, expr_pt_blend(a, b));
        PT1(EXPR_OP_POWI, pow(a, (double)(int16_t)in.b));
        case EXPR_OP_R: R[in.out] = expr_pt_r(x, y, z); break;
        case EXPR_OP_THETA: R[in.out] = atan2(y, x); break;
        case EXPR_OP_PHI: R[in.out] = expr_pt_phi(x, y, z); break;
        default: break;
        }
    }
    return R[dp->result];
}

/* ---- pruning ---- */

/* Tape d -> SSA with every decided min/max renamed to its winner, then a
 * backward pass drops the dead and allocates registers into dst->buf. */
static int prune_into(expr_vm *vm, const expr_vm_depth *src, expr_vm_depth *dst,
                      const uint8_t *choice, size_t stride)
{
    uint32_t nf = vm->nfixed, *cur = vm->cur;
    expr_ssa *ssa = vm->ssa;
    for (uint32_t r = 0; r < nf; r++) cur[r] = r;
    for (uint32_t i = 0; i < src->len; i++) {
        const expr_insn in = src->code[i];
        int ar = expr_op_arity(in.op);
        uint32_t a = ar >= 1 ? cur[in.a] : 0, b = ar >= 2 ? cur[in.b] : 0;
        uint8_t k = choice[i * stride];
        if ((in.op == EXPR_OP_MIN || in.op == EXPR_OP_MAX) && k != EXPR_CH_BOTH) {
            cur[in.out] = k == EXPR_CH_LEFT ? a : b;
            ssa[i].op = EXPR_OP_NOP;
            continue;
        }
        ssa[i] = (expr_ssa){in.op, in.op == EXPR_OP_POWI ? (int16_t)in.b : 0, nf + i, a, b};
        cur[in.out] = nf + i;
    }
    expr_ra_input ri = {ssa, src->len, nf + src->len, nf, cur[src->result], vm->nregs};
    expr_ra_output ro;
    int rc = expr_regalloc(&ri, &vm->ra, dst->buf + vm->n0, &ro);
    if (rc) return rc;
    dst->code = dst->buf + vm->n0 - ro.len;
    dst->len = ro.len;
    dst->result = ro.result_reg;
    return 0;
}

void expr_vm_prune(expr_vm *vm, int d)
{
    if (d < 0 || d >= vm->max_depth) return; /* deeper boxes keep tape max_depth */
    const expr_vm_depth *src = &vm->dep[d];
    expr_vm_depth *dst = &vm->dep[d + 1];
    /* nothing decided (or, in theory, registers ran short): share tape d */
    if (!src->decided || prune_into(vm, src, dst, src->choice, 1)) {
        dst->code = src->code;
        dst->len = src->len;
        dst->result = src->result;
    }
}

int expr_vm_prune8_writes(const expr_vm *vm, int d, int lane)
{
    if (d < 0 || d >= vm->max_depth || lane < 0 || lane >= LANES) return 0;
    return vm->dep[d].decided8[lane] != 0;
}

int expr_vm_same_tape(const expr_vm *vm, int d1, int d2)
{
    const expr_vm_depth *a = &vm->dep[expr_vm_clamp(vm, d1)];
    const expr_vm_depth *b = &vm->dep[expr_vm_clamp(vm, d2)];
    return a->code == b->code && a->len == b->len && a->result == b->result;
}

void expr_vm_prune8(expr_vm *vm, int d, int lane)
{
    if (d < 0 || d >= vm->max_depth || lane < 0 || lane >= LANES) return;
    const expr_vm_depth *src = &vm->dep[d];
    expr_vm_depth *dst = &vm->dep[d + 1];
    if (!src->decided8[lane] ||
        prune_into(vm, src, dst, src->choice8 + lane, LANES)) {
        dst->code = src->code;
        dst->len = src->len;
        dst->result = src->result;
    }
}

/* ---- convenience wrappers ---- */

double expr_eval_point(const expr_tape *t, double x, double y, double z)
{
    expr_vm *vm;
    if (expr_vm_new(t, 0, &vm)) return NAN;
    double v = expr_vm_point(vm, 0, x, y, z);
    expr_vm_free(vm);
    return v;
}

ival expr_eval_ival(const expr_tape *t, ival x, ival y, ival z)
{
    expr_vm *vm;
    if (expr_vm_new(t, 0, &vm)) return ival_make(NAN, NAN);
    ival v = expr_vm_ival(vm, 0, x, y, z);
    expr_vm_free(vm);
    return v;
}
