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
#include <stdlib.h>
#include <string.h>

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
    }
}

static int vm_alloc(expr_vm *vm)
{
    uint32_t n = vm->n0 ? vm->n0 : 1;
    vm->ir = calloc(vm->nregs, sizeof *vm->ir);
    vm->pr = calloc(vm->nregs, sizeof *vm->pr);
    vm->gr = calloc(vm->nregs, sizeof *vm->gr);
    vm->ssa = calloc(n, sizeof *vm->ssa);
    vm->cur = calloc(vm->nregs, sizeof *vm->cur);
    vm->ra.regof = calloc(n, sizeof *vm->ra.regof);
    vm->ra.freelist = calloc(vm->nregs, sizeof *vm->ra.freelist);
    if (!vm->ir || !vm->pr || !vm->gr || !vm->ssa || !vm->cur || !vm->ra.regof ||
        !vm->ra.freelist)
        return -ENOMEM;
    for (int d = 0; d <= vm->max_depth; d++) {
        expr_vm_depth *dp = &vm->dep[d];
        dp->code = expr_tape_code(vm->t);
        dp->len = vm->t->len;
        dp->result = vm->t->result;
        if (!(dp->choice = calloc(n, 1))) return -ENOMEM;
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
    free(vm->ssa);
    free(vm->cur);
    free(vm->ra.regof);
    free(vm->ra.freelist);
    for (int d = 0; d <= EXPR_VM_MAX_DEPTH; d++) {
        free(vm->dep[d].choice);
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
static int prune_into(expr_vm *vm, const expr_vm_depth *src, expr_vm_depth *dst)
{
    uint32_t nf = vm->nfixed, *cur = vm->cur;
    expr_ssa *ssa = vm->ssa;
    for (uint32_t r = 0; r < nf; r++) cur[r] = r;
    for (uint32_t i = 0; i < src->len; i++) {
        const expr_insn in = src->code[i];
        int ar = expr_op_arity(in.op);
        uint32_t a = ar >= 1 ? cur[in.a] : 0, b = ar >= 2 ? cur[in.b] : 0;
        uint8_t k = src->choice[i];
        if ((in.op == EXPR_OP_MIN || in.op == EXPR_OP_MAX) && k != EXPR_CH_BOTH) {
            cur[in.out] = k == EXPR_CH_LEFT ? a : b;
            ssa[i].op = EXPR_OP_NOP;
            continue;
        }
        ssa[i] = (expr_ssa){in.op, in.op == EXPR_OP_POWI ? (int16_t)in.b : 0, nf + i, a, b};
        cur[in.out] = nf + i;
    }
    uint32_t len, result, nregs;
    int rc = expr_regalloc(ssa, src->len, nf + src->len, nf, cur[src->result], vm->nregs,
                           &vm->ra, dst->buf + vm->n0, &len, &result, &nregs);
    if (rc) return rc;
    dst->code = dst->buf + vm->n0 - len;
    dst->len = len;
    dst->result = result;
    return 0;
}

void expr_vm_prune(expr_vm *vm, int d)
{
    if (d < 0 || d >= vm->max_depth) return; /* deeper boxes keep tape max_depth */
    const expr_vm_depth *src = &vm->dep[d];
    expr_vm_depth *dst = &vm->dep[d + 1];
    /* nothing decided (or, in theory, registers ran short): share tape d */
    if (!src->decided || prune_into(vm, src, dst)) {
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
