/* expr_compile — syntax tree -> SSA (folding, sharing) -> register tape.
 *
 * Values are references: a variable, a constant or an instruction.  Every
 * constant and instruction goes through one hash table, so identical
 * subtrees (and repeated uses of a named value) become one value; operations
 * on constants are folded at once, both as doubles (what the point evaluator
 * would compute) and as intervals (an enclosure of the exact value, so that
 * pi or sin(1) stay rigorous in the interval evaluator).
 */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "expr_impl.h"

enum { TAG_VAR = 0, TAG_CONST = 1, TAG_INSN = 2 };
#define REF(tag, i) ((uint32_t)(tag) << 30 | (uint32_t)(i))
#define REF_TAG(r) ((r) >> 30)
#define REF_IDX(r) ((r) & 0x3fffffffu)

typedef struct {
    uint8_t op;
    int16_t imm;
    uint32_t a, b; /* references */
} binsn;

typedef struct {
    expr_const *consts;
    uint32_t nconst, capconst;
    binsn *ins;
    uint32_t nins, capins;
    uint32_t *slots; /* reference + 1; 0 = empty */
    uint32_t nslots, nused;
    uint32_t *named; /* reference of each named value */
    expr_error *err;
} builder;

static uint64_t mix(uint64_t h, uint64_t v)
{
    h ^= v + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
    return h * 0xff51afd7ed558ccdull;
}

static uint64_t dbits(double d)
{
    uint64_t u;
    memcpy(&u, &d, sizeof u);
    return u;
}

static uint64_t hash_ref(const builder *b, uint32_t ref)
{
    if (REF_TAG(ref) == TAG_CONST) {
        const expr_const *c = &b->consts[REF_IDX(ref)];
        return mix(mix(mix(1, dbits(c->v)), dbits(c->lo)), dbits(c->hi));
    }
    const binsn *i = &b->ins[REF_IDX(ref)];
    return mix(mix(mix(mix(2, i->op), (uint16_t)i->imm), i->a), i->b);
}

static int same(const builder *b, uint32_t r1, uint32_t r2)
{
    if (REF_TAG(r1) != REF_TAG(r2)) return 0;
    if (REF_TAG(r1) == TAG_CONST)
        return !memcmp(&b->consts[REF_IDX(r1)], &b->consts[REF_IDX(r2)], sizeof(expr_const));
    const binsn *x = &b->ins[REF_IDX(r1)], *y = &b->ins[REF_IDX(r2)];
    return x->op == y->op && x->imm == y->imm && x->a == y->a && x->b == y->b;
}

static int grow_slots(builder *b)
{
    uint32_t ns = b->nslots ? b->nslots * 2 : 1024;
    uint32_t *slots = calloc(ns, sizeof *slots);
    if (!slots) return -ENOMEM;
    for (uint32_t i = 0; i < b->nslots; i++) {
        uint32_t r = b->slots[i];
        if (!r) continue;
        uint32_t k = (uint32_t)hash_ref(b, r - 1) & (ns - 1);
        while (slots[k]) k = (k + 1) & (ns - 1);
        slots[k] = r;
    }
    free(b->slots);
    b->slots = slots;
    b->nslots = ns;
    return 0;
}

/* The candidate `ref` was just appended to its array: return the existing
 * equal value (and drop the candidate) or keep and index it. */
static int intern(builder *b, uint32_t ref, uint32_t *out)
{
    if ((b->nused + 1) * 2 > b->nslots && grow_slots(b)) return -ENOMEM;
    uint32_t mask = b->nslots - 1, k = (uint32_t)hash_ref(b, ref) & mask;
    for (; b->slots[k]; k = (k + 1) & mask) {
        if (same(b, b->slots[k] - 1, ref)) {
            if (REF_TAG(ref) == TAG_CONST) b->nconst--;
            else b->nins--;
            *out = b->slots[k] - 1;
            return 0;
        }
    }
    b->slots[k] = ref + 1;
    b->nused++;
    *out = ref;
    return 0;
}

static int mk_const(builder *b, double v, double lo, double hi, uint32_t *out)
{
    if (b->nconst == b->capconst) {
        uint32_t cap = b->capconst ? b->capconst * 2 : 64;
        expr_const *c = realloc(b->consts, cap * sizeof *c);
        if (!c) return -ENOMEM;
        b->consts = c;
        b->capconst = cap;
    }
    /* the enclosure must hold the point value too (the oracle's value) */
    if (v == v && lo == lo && hi == hi) {
        if (v < lo) lo = v;
        if (v > hi) hi = v;
    }
    b->consts[b->nconst] = (expr_const){v, lo, hi};
    return intern(b, REF(TAG_CONST, b->nconst++), out);
}

static int mk_insn(builder *b, int op, int imm, uint32_t x, uint32_t y, uint32_t *out)
{
    if (b->nins == b->capins) {
        uint32_t cap = b->capins ? b->capins * 2 : 256;
        binsn *n = realloc(b->ins, cap * sizeof *n);
        if (!n) return -ENOMEM;
        b->ins = n;
        b->capins = cap;
    }
    b->ins[b->nins] = (binsn){(uint8_t)op, (int16_t)imm, x, y};
    return intern(b, REF(TAG_INSN, b->nins++), out);
}

static const expr_const *cval(const builder *b, uint32_t ref)
{
    return REF_TAG(ref) == TAG_CONST ? &b->consts[REF_IDX(ref)] : NULL;
}

static int fold(builder *b, int op, int imm, const expr_const *x, const expr_const *y,
                uint32_t *out)
{
    expr_const zero = {0, 0, 0};
    if (!y) y = &zero;
    ival r = expr_iv_op(op, imm, ival_make(x->lo, x->hi), ival_make(y->lo, y->hi));
    return mk_const(b, expr_pt_op(op, imm, x->v, y->v), r.lo, r.hi, out);
}

static int mk_op(builder *b, int op, int imm, uint32_t x, uint32_t y, uint32_t *out)
{
    const expr_const *cx = cval(b, x), *cy = cval(b, y);
    int ar = expr_op_arity(op);
    if (ar >= 1 && cx && (ar == 1 || cy)) return fold(b, op, imm, cx, ar == 2 ? cy : NULL, out);
    if (ar < 2) y = 0;
    if (ar < 1) x = 0;
    if ((op == EXPR_OP_MIN || op == EXPR_OP_MAX) && x == y) {
        *out = x;
        return 0;
    }
    /* exactly commutative in IEEE arithmetic: share x+1 and 1+x */
    if ((op == EXPR_OP_ADD || op == EXPR_OP_MUL) && x > y) {
        uint32_t t = x;
        x = y;
        y = t;
    }
    return mk_insn(b, op, imm, x, y, out);
}

/* a ^ e: an integer constant exponent becomes an integer power. */
static int mk_pow(builder *b, uint32_t a, uint32_t e, uint32_t *out)
{
    const expr_const *ce = cval(b, e);
    if (!ce || cval(b, a) || !(fabs(ce->v) <= 32767.0) || ce->v != floor(ce->v))
        return mk_op(b, EXPR_OP_POW, 0, a, e, out);
    int n = (int)ce->v;
    if (n == 0) return mk_const(b, 1.0, 1.0, 1.0, out); /* pow(anything, 0) = 1 */
    if (n == 1) {
        *out = a;
        return 0;
    }
    if (n == 2) return mk_op(b, EXPR_OP_SQR, 0, a, 0, out);
    return mk_op(b, EXPR_OP_POWI, n, a, 0, out);
}

static int emit(builder *b, const expr_ast *n, uint32_t *out);

/* min/max of many: a balanced tree, so each instruction splits the
 * arguments in halves (pruning can drop half of what is left per step). */
static int emit_nary(builder *b, int op, const uint32_t *refs, uint32_t n, uint32_t *out)
{
    if (n == 1) {
        *out = refs[0];
        return 0;
    }
    uint32_t l, r;
    int rc = emit_nary(b, op, refs, n / 2, &l);
    if (!rc) rc = emit_nary(b, op, refs + n / 2, n - n / 2, &r);
    return rc ? rc : mk_op(b, op, 0, l, r, out);
}

static int emit_blend(builder *b, const expr_ast *n, uint32_t d, uint32_t R, uint32_t *out)
{
    const expr_const *c = cval(b, R);
    if (!c || !(c->v > 0) || !isfinite(c->v) || !(c->lo > 0) || !isfinite(c->hi)) {
        const expr_ast *at = n->args[1];
        return expr_set_error(b->err, -EINVAL, at->line, at->col,
                              "the radius of blend must be a positive finite constant");
    }
    return mk_op(b, EXPR_OP_BLEND, 0, d, R, out);
}

static int emit_op(builder *b, const expr_ast *n, uint32_t *out)
{
    uint32_t small[8], *refs = n->nargs <= 8 ? small : malloc(n->nargs * sizeof *refs);
    if (!refs) return -ENOMEM;
    int rc = 0;
    for (uint32_t i = 0; i < n->nargs && !rc; i++) rc = emit(b, n->args[i], &refs[i]);
    if (rc) goto done;
    switch (n->op) {
    case EXPR_OP_MIN:
    case EXPR_OP_MAX: rc = emit_nary(b, n->op, refs, n->nargs, out); break;
    case EXPR_OP_POW: rc = mk_pow(b, refs[0], refs[1], out); break;
    case EXPR_OP_BLEND: rc = emit_blend(b, n, refs[0], refs[1], out); break;
    default:
        rc = mk_op(b, n->op, 0, n->nargs > 0 ? refs[0] : 0, n->nargs > 1 ? refs[1] : 0, out);
    }
done:
    if (refs != small) free(refs);
    return rc;
}

/* A chain a+b-c*d/...: its left spine of + - * / nodes in a loop, in the
 * order the recursion of emit_op would take (the leftmost operand, then
 * each right operand and its operation, bottom up), so the SSA and the tape
 * are the same, and a sum of 10,000 terms recurses once per term's own
 * nesting, not per term. */
static int emit_chain(builder *b, const expr_ast *n, uint32_t *out)
{
    uint32_t len = 0;
    const expr_ast *p;
    for (p = n; expr_ast_chains(p); p = p->args[0]) len++;
    const expr_ast *small[16], **spine = len <= 16 ? small : malloc(len * sizeof *spine);
    if (!spine) return -ENOMEM;
    uint32_t k = len;
    for (p = n; k; p = p->args[0]) spine[--k] = p; /* spine[0]: the lowest */
    uint32_t acc, r;
    int rc = emit(b, p, &acc);
    for (uint32_t i = 0; i < len && !rc; i++) {
        rc = emit(b, spine[i]->args[1], &r);
        if (!rc) rc = mk_op(b, spine[i]->op, 0, acc, r, &acc);
    }
    if (spine != small) free(spine);
    if (!rc) *out = acc;
    return rc;
}

/* Recursion depth is bounded by the tree height (the parser's limit). */
static int emit(builder *b, const expr_ast *n, uint32_t *out)
{
    switch (n->kind) {
    case EXPR_AST_NUM: return mk_const(b, n->num, n->num, n->num, out);
    case EXPR_AST_PI: return mk_const(b, M_PI, M_PI, nextafter(M_PI, INFINITY), out);
    case EXPR_AST_VAR: *out = REF(TAG_VAR, n->index); return 0;
    case EXPR_AST_NAME: *out = b->named[n->index]; return 0;
    default: return expr_ast_chains(n) ? emit_chain(b, n, out) : emit_op(b, n, out);
    }
}

/* ---- SSA -> tape ---- */

typedef struct {
    uint32_t *newc;   /* constant index -> register, or EXPR_NOREG if unused */
    uint8_t *live;    /* per instruction */
    uint32_t nfixed;
} layout;

static void mark(layout *L, uint32_t ref)
{
    if (REF_TAG(ref) == TAG_CONST) L->newc[REF_IDX(ref)] = 0;
    else if (REF_TAG(ref) == TAG_INSN) L->live[REF_IDX(ref)] = 1;
}

/* Keep the constants that a live instruction (or the result) uses. */
static void mark_live(const builder *b, layout *L, uint32_t result)
{
    for (uint32_t j = 0; j < b->nconst; j++) L->newc[j] = EXPR_NOREG;
    mark(L, result);
    for (uint32_t k = b->nins; k-- > 0;) {
        if (!L->live[k]) continue;
        int ar = expr_op_arity(b->ins[k].op);
        if (ar >= 1) mark(L, b->ins[k].a);
        if (ar >= 2) mark(L, b->ins[k].b);
    }
    L->nfixed = EXPR_NVARS;
    for (uint32_t j = 0; j < b->nconst; j++)
        if (L->newc[j] != EXPR_NOREG) L->newc[j] = L->nfixed++;
}

static uint32_t ssa_id(const layout *L, uint32_t ref)
{
    switch (REF_TAG(ref)) {
    case TAG_VAR: return REF_IDX(ref);
    case TAG_CONST: return L->newc[REF_IDX(ref)];
    default: return L->nfixed + REF_IDX(ref);
    }
}

static expr_tape *build_tape(const builder *b, const layout *L, const expr_insn *code,
                             uint32_t len, uint32_t result, uint32_t nregs)
{
    uint32_t nc = L->nfixed - EXPR_NVARS;
    size_t bytes = sizeof(expr_tape) + nc * sizeof(expr_const) + len * sizeof(expr_insn);
    expr_tape *t = malloc(bytes);
    if (!t) return NULL;
    *t = (expr_tape){.magic = EXPR_TAPE_MAGIC, .version = EXPR_TAPE_VERSION,
                     .bytes = bytes, .len = len, .nconst = nc, .nregs = nregs,
                     .result = result};
    expr_const *c = (expr_const *)(void *)(t + 1);
    for (uint32_t j = 0; j < b->nconst; j++)
        if (L->newc[j] != EXPR_NOREG) c[L->newc[j] - EXPR_NVARS] = b->consts[j];
    memcpy((void *)expr_tape_code(t), code, len * sizeof *code);
    for (uint32_t i = 0; i < len; i++)
        t->nminmax += code[i].op == EXPR_OP_MIN || code[i].op == EXPR_OP_MAX;
    return t;
}

static int finish(const builder *b, uint32_t result, expr_tape **out)
{
    uint32_t n = b->nins ? b->nins : 1;
    layout L = {malloc((b->nconst + 1) * sizeof(uint32_t)), calloc(n, 1), 0};
    expr_ssa *ssa = malloc(n * sizeof *ssa);
    expr_insn *code = malloc(n * sizeof *code);
    expr_ra_scratch s = {malloc(n * sizeof(uint32_t)), malloc(EXPR_MAX_REGS * sizeof(uint16_t))};
    int rc = -ENOMEM;
    if (!L.newc || !L.live || !ssa || !code || !s.regof || !s.freelist) goto done;
    mark_live(b, &L, result);
    rc = -E2BIG;
    if (L.nfixed > EXPR_MAX_REGS) goto done;
    for (uint32_t k = 0; k < b->nins; k++) {
        const binsn *i = &b->ins[k];
        int ar = expr_op_arity(i->op);
        ssa[k] = (expr_ssa){L.live[k] ? i->op : EXPR_OP_NOP, i->imm, L.nfixed + k,
                            ar >= 1 ? ssa_id(&L, i->a) : 0, ar >= 2 ? ssa_id(&L, i->b) : 0};
    }
    expr_ra_input ri = {ssa, b->nins, L.nfixed + n, L.nfixed, ssa_id(&L, result), EXPR_MAX_REGS};
    expr_ra_output ro;
    rc = expr_regalloc(&ri, &s, code + n, &ro);
    if (rc) goto done;
    *out = build_tape(b, &L, code + n - ro.len, ro.len, ro.result_reg, ro.nregs);
    rc = *out ? 0 : -ENOMEM;
done:
    free(L.newc);
    free(L.live);
    free(ssa);
    free(code);
    free(s.regof);
    free(s.freelist);
    return rc;
}

static int emit_program(builder *b, const expr_program *prog, uint32_t *result)
{
    int rc = 0;
    if (prog->ndefs && !(b->named = malloc(prog->ndefs * sizeof *b->named))) return -ENOMEM;
    /* named values in order: a reference is then a lookup, never a walk */
    for (uint32_t i = 0; i < prog->ndefs && !rc; i++) rc = emit(b, prog->defs[i], &b->named[i]);
    return rc ? rc : emit(b, prog->final, result);
}

int expr_compile(const char *src, size_t len, const expr_limits *lim,
                 expr_tape **out, expr_error *err)
{
    expr_program prog;
    expr_error dummy;
    if (!err) err = &dummy;
    *out = NULL;
    int rc = expr_parse(src, len, lim, &prog, err);
    if (rc) return rc;
    builder b = {.err = err};
    uint32_t result;
    rc = emit_program(&b, &prog, &result);
    if (!rc) rc = finish(&b, result, out);
    if (rc == -ENOMEM && !err->msg[0]) expr_set_error(err, rc, 0, 0, "out of memory");
    if (rc == -E2BIG && !err->msg[0])
        expr_set_error(err, rc, 0, 0, "expression needs too many registers (limit %u)",
                       EXPR_MAX_REGS);
    expr_program_free(&prog);
    free(b.consts);
    free(b.ins);
    free(b.slots);
    free(b.named);
    return rc;
}
