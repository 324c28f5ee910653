/* expr_impl — private declarations shared by expr/expr*.c.
 *
 * Register model.  Registers 0, 1, 2 hold x, y, z; registers 3 .. nfixed-1
 * hold the tape's constants (preloaded once per vm, never written); the
 * registers from nfixed on are scratch, reused as soon as a value is dead.
 * Every instruction reads registers and writes one scratch register, so a
 * tape is a straight-line program that any of the evaluators can run.
 *
 * SSA form (compile time and expr_vm_prune): the same instructions, but each
 * value has its own 32-bit id (ids < nfixed are the fixed registers);
 * expr_regalloc() turns SSA into registers, dropping dead instructions.
 */
#ifndef VOXD_EXPR_IMPL_H
#define VOXD_EXPR_IMPL_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>

#include "expr.h"

enum expr_op {
    EXPR_OP_NOP = 0,
    /* nullary: read registers 0..2 */
    EXPR_OP_R,
    EXPR_OP_THETA,
    EXPR_OP_PHI,
    /* unary: a */
    EXPR_OP_NEG,
    EXPR_OP_SQR,
    EXPR_OP_SQRT,
    EXPR_OP_ABS,
    EXPR_OP_SIN,
    EXPR_OP_COS,
    EXPR_OP_TAN,
    EXPR_OP_ASIN,
    EXPR_OP_ACOS,
    EXPR_OP_ATAN,
    EXPR_OP_EXP,
    EXPR_OP_LOG,
    EXPR_OP_POWI, /* a ^ (int16_t)b: b is the exponent, not a register */
    /* binary: a, b */
    EXPR_OP_ADD,
    EXPR_OP_SUB,
    EXPR_OP_MUL,
    EXPR_OP_DIV,
    EXPR_OP_MIN,
    EXPR_OP_MAX,
    EXPR_OP_ATAN2, /* atan2(a = y, b = x) */
    EXPR_OP_POW,
    EXPR_OP_BLEND, /* blend(a = d, b = R) */
    EXPR_OP_COUNT
};

/* Operands that are registers: 0 (nullary), 1 or 2. */
static inline int expr_op_arity(int op)
{
    if (op >= EXPR_OP_ADD) return 2;
    if (op >= EXPR_OP_NEG) return 1;
    return 0;
}

/* One instruction of a register tape: 8 bytes. */
typedef struct {
    uint8_t op;
    uint8_t pad;
    uint16_t out, a, b;
} expr_insn;

/* One instruction in SSA form. */
typedef struct {
    uint8_t op;
    int16_t imm; /* EXPR_OP_POWI exponent */
    uint32_t out, a, b;
} expr_ssa;

/* A constant: its double value (point and gradient evaluators) and an
 * interval that contains the exact real value (pi, folded sin(1), ...). */
typedef struct {
    double v, lo, hi;
} expr_const;

#define EXPR_TAPE_MAGIC 0x54505845u /* "EXPT" */
#define EXPR_TAPE_VERSION 1u
#define EXPR_NVARS 3u
#define EXPR_MAX_REGS 65535u
#define EXPR_VM_MAX_DEPTH 32

/* The tape block: this header, expr_const[nconst], expr_insn[len].  Only
 * sizes and indices inside, so the bytes may be moved anywhere. */
struct expr_tape {
    uint32_t magic, version;
    uint64_t bytes;   /* the whole block */
    uint32_t len;     /* instructions */
    uint32_t nconst;  /* constants: registers 3 .. 3+nconst-1 */
    uint32_t nregs;   /* registers the tape needs, fixed ones included */
    uint32_t result;  /* register holding F after the last instruction */
    uint32_t nminmax; /* min/max instructions */
    uint32_t reserved;
};

static inline const expr_const *expr_tape_consts(const expr_tape *t)
{
    return (const expr_const *)(const void *)(t + 1);
}

static inline const expr_insn *expr_tape_code(const expr_tape *t)
{
    return (const expr_insn *)(const void *)(expr_tape_consts(t) + t->nconst);
}

/* ---- point semantics, shared by the evaluators and constant folding ---- */

/* min/max propagate NaN (unlike fmin): F is undefined where an operand is.
 * That is what the interval evaluator assumes (ival evaluates a function on
 * the part of a box where it is defined), so a min that ignored a NaN
 * operand could take a value outside the enclosure.  Ties go to the right
 * operand; the gradient follows the same choice. */
static inline int expr_min_left(double a, double b) { return a < b || a != a; }
static inline int expr_max_left(double a, double b) { return a > b || a != a; }

/* NaN in, NaN out (see min/max). */
static inline double expr_pt_blend(double d, double R)
{
    if (fabs(d) > R) return 0.0;
    double t = d * d - R * R, t2 = t * t;
    double r2 = R * R, r4 = r2 * r2;
    return (t2 * t2) / (r4 * r4);
}

/* pow as the interval evaluator sees it: NaN in, NaN out (C's pow(1, NaN)
 * and pow(NaN, 0) are 1), and a negative base only with an integer
 * exponent (C's pow(-inf, 0.5) is +inf). */
static inline double expr_pt_pow(double a, double b)
{
    if (a != a || b != b || (a < 0 && b != floor(b))) return NAN;
    return pow(a, b);
}

static inline double expr_pt_r(double x, double y, double z)
{
    return sqrt(x * x + y * y + z * z);
}

/* phi = acos(z/r) written as atan2(rho, z): the same angle, defined at the
 * origin (0) and free of z/r rounding past 1. */
static inline double expr_pt_phi(double x, double y, double z)
{
    return atan2(sqrt(x * x + y * y), z);
}

double expr_pt_op(int op, int imm, double a, double b);
ival expr_iv_op(int op, int imm, ival a, ival b);

/* ---- parser: source -> syntax tree ---- */

enum expr_ast_kind {
    EXPR_AST_NUM,  /* num */
    EXPR_AST_PI,
    EXPR_AST_VAR,  /* index 0..2 */
    EXPR_AST_NAME, /* index: named value */
    EXPR_AST_OP,   /* op with nargs args (min/max: >= 2) */
};

typedef struct expr_ast expr_ast;
struct expr_ast {
    uint8_t kind, op;
    uint16_t height;
    uint32_t nargs;
    uint32_t index;
    int line, col;
    double num;
    expr_ast **args;
};

/* + - * / chain: a+b-c+... is a left-deep tree of these nodes, which the
 * parser builds in a loop and the compiler walks in a loop down its left
 * spine (operands first to last, as recursion would), so a chain of any
 * length is one level of nesting.  The height of a chaining node counts
 * its left operand at one level less when that operand chains too: the
 * height is then the compiler's recursion depth on the subtree. */
static inline int expr_ast_chains(const expr_ast *n)
{
    return n->kind == EXPR_AST_OP && n->nargs == 2 &&
           (n->op == EXPR_OP_ADD || n->op == EXPR_OP_SUB || n->op == EXPR_OP_MUL ||
            n->op == EXPR_OP_DIV);
}

typedef struct expr_arena_chunk expr_arena_chunk;

typedef struct {
    expr_ast **defs; /* named values, in order of definition */
    uint32_t ndefs, capdefs;
    expr_ast *final;
    expr_arena_chunk *arena;
} expr_program;

int expr_parse(const char *src, size_t len, const expr_limits *lim,
               expr_program *prog, expr_error *err);
void expr_program_free(expr_program *prog);
/* err's message, code rc and position line:col; rc returned. */
int expr_set_error(expr_error *err, int rc, int line, int col, const char *fmt, ...)
    __attribute__((format(printf, 5, 6)));

/* ---- register allocation ---- */

typedef struct {
    uint32_t *regof;    /* [nids - nfixed] scratch, set to EXPR_NOREG inside */
    uint16_t *freelist; /* [cap] scratch */
} expr_ra_scratch;

#define EXPR_NOREG 0xffffffffu

/* What expr_regalloc allocates: ssa[0..n) whose ids below nfixed are the
 * fixed registers, result the id of the value wanted, at most cap
 * registers; nids - nfixed must be >= every non-fixed id + 1 - nfixed. */
typedef struct {
    const expr_ssa *ssa;
    uint32_t n, nids, nfixed, result, cap;
} expr_ra_input;

/* Its answer: len instructions ending at out_end, the result's register,
 * the registers used. */
typedef struct {
    uint32_t len, result_reg, nregs;
} expr_ra_output;

/* Backward pass over in->ssa (topological order; NOP entries skipped):
 * drops instructions whose value is dead, assigns registers (reusing one as
 * soon as its value is dead, so the count is the peak number of live
 * values) and writes the register code so that it ends at out_end.
 * Returns 0, or -E2BIG when more than cap registers would be needed. */
int expr_regalloc(const expr_ra_input *in, expr_ra_scratch *s, expr_insn *out_end,
                  expr_ra_output *out);

/* ---- the vm (expr_eval.c, expr_grad.c) ---- */

enum { EXPR_CH_BOTH = 0, EXPR_CH_LEFT = 1, EXPR_CH_RIGHT = 2 };

typedef struct {
    double v, d[3];
} expr_grad_reg;

/* A register of the interval gradient (expr_igrad.c). */
typedef struct {
    ival v, d[3];
} expr_igrad_reg;

typedef struct {
    const expr_insn *code;
    uint32_t len, result;
    uint32_t decided; /* min/max decided by the last interval evaluation */
    uint8_t *choice;  /* per instruction of code */
    expr_insn *buf;   /* this depth's own storage (depth >= 1) */
    /* The same for the last expr_vm_ival8: choice8[i * EXPR_LANES + lane]. */
    uint32_t decided8[EXPR_LANES];
    uint8_t *choice8;
} expr_vm_depth;

struct expr_vm {
    const expr_tape *t;
    int max_depth;
    uint32_t nregs, nfixed, n0;
    ival *ir;
    double *pr;
    expr_grad_reg *gr;
    ival8 *ir8;       /* the batched evaluators' registers (64-byte aligned) */
    expr_grad8 *gr8;
    expr_igrad_reg *igr; /* expr_vm_ival_grad's registers */
    expr_ssa *ssa;
    uint32_t *cur;
    expr_ra_scratch ra;
    expr_vm_depth dep[EXPR_VM_MAX_DEPTH + 1];
};

/* Depths outside 0..max_depth use the nearest tape: a tape pruned for a box
 * stays valid in every box inside it. */
static inline int expr_vm_clamp(const expr_vm *vm, int d)
{
    return d < 0 ? 0 : d > vm->max_depth ? vm->max_depth : d;
}

#endif
