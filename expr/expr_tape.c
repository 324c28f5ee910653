/* expr_tape — register allocation, the tape block's accessors and checks. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "expr_impl.h"

typedef struct {
    expr_ra_scratch *s;
    uint32_t nfixed, cap, next, nfree;
    int overflow;
} ra_state;

/* The register of an input: allocated at its last use (we walk backward). */
static uint32_t ra_use(ra_state *ra, uint32_t id)
{
    if (id < ra->nfixed) return id;
    uint32_t *r = &ra->s->regof[id - ra->nfixed];
    if (*r == EXPR_NOREG) {
        if (ra->nfree) {
            *r = ra->s->freelist[--ra->nfree];
        } else if (ra->next < ra->cap) {
            *r = ra->next++;
        } else {
            ra->overflow = 1;
            *r = 0;
        }
    }
    return *r;
}

int expr_regalloc(const expr_ra_input *in, expr_ra_scratch *s, expr_insn *out_end,
                  expr_ra_output *out)
{
    const expr_ssa *ssa = in->ssa;
    uint32_t nfixed = in->nfixed;
    ra_state ra = {s, nfixed, in->cap, nfixed, 0, 0};
    for (uint32_t i = 0; i < in->nids - nfixed; i++) s->regof[i] = EXPR_NOREG;
    out->result_reg = ra_use(&ra, in->result);
    expr_insn *w = out_end;
    for (uint32_t k = in->n; k-- > 0 && !ra.overflow;) {
        const expr_ssa *i = &ssa[k];
        if (i->op == EXPR_OP_NOP) continue;
        uint32_t o = s->regof[i->out - nfixed];
        if (o == EXPR_NOREG) continue; /* dead */
        /* before this instruction the value does not exist: its register is
         * free, and may be an input's (the evaluators read before writing) */
        s->freelist[ra.nfree++] = (uint16_t)o;
        int ar = expr_op_arity(i->op);
        uint32_t a = ar >= 1 ? ra_use(&ra, i->a) : 0;
        uint32_t b = ar >= 2 ? ra_use(&ra, i->b) : (uint16_t)i->imm;
        *--w = (expr_insn){i->op, 0, (uint16_t)o, (uint16_t)a, (uint16_t)b};
    }
    if (ra.overflow) return -E2BIG;
    out->len = (uint32_t)(out_end - w);
    out->nregs = ra.next;
    return 0;
}

void expr_tape_free(expr_tape *t) { free(t); }
size_t expr_tape_bytes(const expr_tape *t) { return (size_t)t->bytes; }
uint32_t expr_tape_length(const expr_tape *t) { return t->len; }

static int check_code(const expr_tape *t)
{
    uint32_t nfixed = EXPR_NVARS + t->nconst, nminmax = 0;
    uint8_t *defined = calloc(t->nregs, 1);
    if (!defined) return -ENOMEM;
    memset(defined, 1, nfixed);
    const expr_insn *c = expr_tape_code(t);
    int rc = 0;
    for (uint32_t i = 0; i < t->len && !rc; i++) {
        int op = c[i].op, ar = expr_op_arity(op);
        if (op == EXPR_OP_NOP || op >= EXPR_OP_COUNT || c[i].out < nfixed ||
            c[i].out >= t->nregs || (ar >= 1 && (c[i].a >= t->nregs || !defined[c[i].a])) ||
            (ar >= 2 && (c[i].b >= t->nregs || !defined[c[i].b])))
            rc = -EINVAL;
        else
            defined[c[i].out] = 1;
        nminmax += op == EXPR_OP_MIN || op == EXPR_OP_MAX;
    }
    if (!rc && (!defined[t->result] || nminmax != t->nminmax)) rc = -EINVAL;
    free(defined);
    return rc;
}

int expr_tape_validate(const void *buf, size_t size)
{
    const expr_tape *t = buf;
    if (size < sizeof *t || t->magic != EXPR_TAPE_MAGIC || t->version != EXPR_TAPE_VERSION)
        return -EINVAL;
    uint64_t need = sizeof *t + (uint64_t)t->nconst * sizeof(expr_const) +
                    (uint64_t)t->len * sizeof(expr_insn);
    if (t->bytes != need || need > size || t->nregs > EXPR_MAX_REGS ||
        t->nconst > EXPR_MAX_REGS || t->nregs < EXPR_NVARS + t->nconst ||
        t->result >= t->nregs)
        return -EINVAL;
    return check_code(t);
}
