/* expr_parse — lexer and recursive-descent parser: source -> syntax tree.
 *
 *   program   := { NAME '=' expr ';' } expr [ ';' ]
 *   expr      := term { ('+' | '-') term }
 *   term      := unary { ('*' | '/') unary }
 *   unary     := ('-' | '+') unary | power
 *   power     := primary [ '^' unary ]        (right-associative; -x^2 = -(x^2))
 *   primary   := NUMBER | NAME | NAME '(' [ expr { ',' expr } ] ')' | '(' expr ')'
 *
 * Recursion goes through parse_unary only, which counts nesting
 * (parentheses, function arguments, unary signs, exponents), so no input
 * can take the parser deeper than lim->max_depth levels.  The chains of
 * expr and term are loops: a flat sum of 10,000 terms, as programs write
 * them, is one level.  Every node also carries its height, so the
 * compiler, which recurses over the tree (but loops along a chain, see
 * expr_ast_chains), is bounded by the same limit.
 */
#include <errno.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "expr_impl.h"

/* ---- arena: every node of a program lives here, freed at once ---- */

struct expr_arena_chunk {
    expr_arena_chunk *next;
    size_t used, cap;
    max_align_t data[];
};

static void *arena_alloc(expr_program *prog, size_t n)
{
    n = (n + 15) & ~(size_t)15;
    expr_arena_chunk *c = prog->arena;
    if (!c || c->cap - c->used < n) {
        size_t cap = n > 65536 ? n : 65536;
        c = malloc(sizeof *c + cap);
        if (!c) return NULL;
        c->next = prog->arena;
        c->used = 0;
        c->cap = cap;
        prog->arena = c;
    }
    void *p = (char *)c->data + c->used;
    c->used += n;
    return p;
}

void expr_program_free(expr_program *prog)
{
    expr_arena_chunk *c = prog->arena;
    while (c) {
        expr_arena_chunk *next = c->next;
        free(c);
        c = next;
    }
    free(prog->defs);
    memset(prog, 0, sizeof *prog);
}

int expr_set_error(expr_error *err, int rc, int line, int col, const char *fmt, ...)
{
    if (!err) return rc;
    va_list ap;
    err->line = line;
    err->col = col;
    va_start(ap, fmt);
    err_vset(&err->info, rc, fmt, ap);
    va_end(ap);
    return rc;
}

/* ---- lexer ---- */

typedef enum {
    TK_EOF, TK_ERROR, TK_NUM, TK_IDENT, TK_PLUS, TK_MINUS, TK_STAR, TK_SLASH,
    TK_CARET, TK_LPAREN, TK_RPAREN, TK_COMMA, TK_ASSIGN, TK_SEMI
} tk_kind;

typedef struct {
    tk_kind kind;
    const char *s;
    uint32_t len;
    int line, col;
    double num;
    const char *msg; /* TK_ERROR: what is wrong (the text follows in s/len) */
} token;

typedef struct {
    const char *src;
    size_t len, pos, line_start;
    int line;
} lexer;

static int is_alpha(int c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_'; }
static int is_digit(int c) { return c >= '0' && c <= '9'; }
static int lx_at(const lexer *l, size_t i) { return i < l->len ? (unsigned char)l->src[i] : -1; }

static void skip_space(lexer *l)
{
    while (l->pos < l->len) {
        int c = lx_at(l, l->pos);
        if (c == '\n') {
            l->line++;
            l->line_start = ++l->pos;
        } else if (c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v') {
            l->pos++;
        } else if (c == '#') {
            while (l->pos < l->len && l->src[l->pos] != '\n') l->pos++;
        } else {
            break;
        }
    }
}

/* digits [ '.' digits ] [ (e|E) [+|-] digits ], at least one mantissa digit. */
static size_t scan_number(const lexer *l, size_t i, int *ok)
{
    size_t digits = 0;
    while (is_digit(lx_at(l, i))) i++, digits++;
    if (lx_at(l, i) == '.') {
        i++;
        while (is_digit(lx_at(l, i))) i++, digits++;
    }
    *ok = digits > 0;
    int c = lx_at(l, i);
    if (c == 'e' || c == 'E') {
        size_t j = i + 1;
        if (lx_at(l, j) == '+' || lx_at(l, j) == '-') j++;
        if (!is_digit(lx_at(l, j))) {
            *ok = 0;
            return j;
        }
        while (is_digit(lx_at(l, j))) j++;
        i = j;
    }
    return i;
}

static void lex_number(lexer *l, token *t)
{
    int ok;
    size_t end = scan_number(l, l->pos, &ok);
    /* "1.2.3", "2x", "1e": swallow the rest of the word for the message */
    int c;
    while ((c = lx_at(l, end)) >= 0 && (is_alpha(c) || is_digit(c) || c == '.')) {
        end++;
        ok = 0;
    }
    t->len = (uint32_t)(end - l->pos);
    l->pos = end;
    if (!ok) {
        t->kind = TK_ERROR;
        t->msg = "malformed number";
        return;
    }
    char buf[64];
    if (t->len >= sizeof buf) {
        t->kind = TK_ERROR;
        t->msg = "number too long";
        return;
    }
    memcpy(buf, t->s, t->len);
    buf[t->len] = 0;
    t->num = strtod(buf, NULL);
    t->kind = TK_NUM;
    if (isinf(t->num)) {
        t->kind = TK_ERROR;
        t->msg = "number out of range";
    }
}

static tk_kind punct(int c)
{
    switch (c) {
    case '+': return TK_PLUS;
    case '-': return TK_MINUS;
    case '*': return TK_STAR;
    case '/': return TK_SLASH;
    case '^': return TK_CARET;
    case '(': return TK_LPAREN;
    case ')': return TK_RPAREN;
    case ',': return TK_COMMA;
    case '=': return TK_ASSIGN;
    case ';': return TK_SEMI;
    default: return TK_ERROR;
    }
}

static const char msg_unexpected[] = "unexpected character";

static void lex(lexer *l, token *t)
{
    skip_space(l);
    memset(t, 0, sizeof *t);
    t->s = l->src + l->pos;
    t->line = l->line;
    t->col = (int)(l->pos - l->line_start) + 1;
    int c = lx_at(l, l->pos);
    if (c < 0) {
        t->kind = TK_EOF;
    } else if (is_digit(c) || (c == '.' && is_digit(lx_at(l, l->pos + 1)))) {
        lex_number(l, t);
    } else if (is_alpha(c)) {
        size_t end = l->pos;
        while (is_alpha(lx_at(l, end)) || is_digit(lx_at(l, end))) end++;
        t->kind = TK_IDENT;
        t->len = (uint32_t)(end - l->pos);
        l->pos = end;
    } else {
        t->kind = punct(c);
        t->len = 1;
        l->pos++;
        if (t->kind == TK_ERROR) t->msg = msg_unexpected;
    }
}

/* ---- names ---- */

typedef struct {
    const char *name;
    uint8_t op;
    uint8_t min_args, max_args; /* max 0: no upper bound */
} func_def;

static const func_def funcs[] = {
    {"sin", EXPR_OP_SIN, 1, 1},     {"cos", EXPR_OP_COS, 1, 1},
    {"tan", EXPR_OP_TAN, 1, 1},     {"asin", EXPR_OP_ASIN, 1, 1},
    {"acos", EXPR_OP_ACOS, 1, 1},   {"atan", EXPR_OP_ATAN, 1, 1},
    {"exp", EXPR_OP_EXP, 1, 1},     {"log", EXPR_OP_LOG, 1, 1},
    {"sqrt", EXPR_OP_SQRT, 1, 1},   {"abs", EXPR_OP_ABS, 1, 1},
    {"atan2", EXPR_OP_ATAN2, 2, 2}, {"pow", EXPR_OP_POW, 2, 2},
    {"blend", EXPR_OP_BLEND, 2, 2}, {"min", EXPR_OP_MIN, 2, 0},
    {"max", EXPR_OP_MAX, 2, 0},
};

static int tok_is(const token *t, const char *s)
{
    return t->kind == TK_IDENT && strlen(s) == t->len && !memcmp(t->s, s, t->len);
}

static const func_def *find_func(const token *t)
{
    for (size_t i = 0; i < sizeof funcs / sizeof funcs[0]; i++)
        if (tok_is(t, funcs[i].name)) return &funcs[i];
    return NULL;
}

/* x y z -> 0..2; r theta phi -> ops; pi -> constant. */
static int find_var(const token *t)
{
    static const char *const v[] = {"x", "y", "z"};
    for (int i = 0; i < 3; i++)
        if (tok_is(t, v[i])) return i;
    return -1;
}

static int find_sph(const token *t)
{
    if (tok_is(t, "r")) return EXPR_OP_R;
    if (tok_is(t, "theta")) return EXPR_OP_THETA;
    if (tok_is(t, "phi")) return EXPR_OP_PHI;
    return -1;
}

/* ---- named values: an open-addressing table of name -> index ---- */

typedef struct {
    const char *s;
    uint32_t len;
    int line, col;
} name_def;

typedef struct {
    name_def *defs;  /* index = named value index */
    uint32_t *slots; /* index + 1, 0 empty */
    uint32_t n, cap, nslots;
} name_table;

static uint32_t name_hash(const char *s, uint32_t len)
{
    uint32_t h = 2166136261u;
    for (uint32_t i = 0; i < len; i++) h = (h ^ (unsigned char)s[i]) * 16777619u;
    return h;
}

static int64_t name_find(const name_table *nt, const token *t)
{
    if (!nt->nslots) return -1;
    uint32_t mask = nt->nslots - 1;
    for (uint32_t i = name_hash(t->s, t->len) & mask;; i = (i + 1) & mask) {
        uint32_t s = nt->slots[i];
        if (!s) return -1;
        const name_def *d = &nt->defs[s - 1];
        if (d->len == t->len && !memcmp(d->s, t->s, t->len)) return s - 1;
    }
}

static int name_rehash(name_table *nt)
{
    uint32_t ns = nt->nslots ? nt->nslots * 2 : 64;
    uint32_t *slots = calloc(ns, sizeof *slots);
    if (!slots) return -ENOMEM;
    for (uint32_t k = 0; k < nt->n; k++) {
        uint32_t i = name_hash(nt->defs[k].s, nt->defs[k].len) & (ns - 1);
        while (slots[i]) i = (i + 1) & (ns - 1);
        slots[i] = k + 1;
    }
    free(nt->slots);
    nt->slots = slots;
    nt->nslots = ns;
    return 0;
}

static int name_add(name_table *nt, const token *t)
{
    if (nt->n == nt->cap) {
        uint32_t cap = nt->cap ? nt->cap * 2 : 16;
        name_def *d = realloc(nt->defs, cap * sizeof *d);
        if (!d) return -ENOMEM;
        nt->defs = d;
        nt->cap = cap;
    }
    if ((nt->n + 1) * 2 > nt->nslots && name_rehash(nt)) return -ENOMEM;
    nt->defs[nt->n] = (name_def){t->s, t->len, t->line, t->col};
    uint32_t mask = nt->nslots - 1, i = name_hash(t->s, t->len) & mask;
    while (nt->slots[i]) i = (i + 1) & mask;
    nt->slots[i] = ++nt->n;
    return 0;
}

/* ---- parser ---- */

typedef struct {
    lexer lx;
    token tok;
    expr_program *prog;
    expr_error *err;
    int rc;
    uint32_t depth, max_depth, nodes, max_nodes;
    name_table *names;
} parser;

static name_table *names_of(parser *p) { return p->names; }

/* A token for messages: 'foo', number '1.5', end of input. */
static const char *tok_desc(const token *t, char *buf, size_t n)
{
    int len = t->len > 40 ? 40 : (int)t->len;
    const char *dots = t->len > 40 ? "..." : "";
    if (t->kind == TK_EOF) return "end of input";
    if (t->kind == TK_NUM) snprintf(buf, n, "number '%.*s%s'", len, t->s, dots);
    else snprintf(buf, n, "'%.*s%s'", len, t->s, dots);
    return buf;
}

#define PERR(p, rc_, line_, col_, ...)                                       \
    do {                                                                     \
        if (!(p)->rc) {                                                      \
            (p)->rc = (rc_);                                                 \
            expr_set_error((p)->err, (rc_), (line_), (col_), __VA_ARGS__);   \
        }                                                                    \
    } while (0)

static void lex_error(parser *p, const token *t)
{
    int c = (unsigned char)t->s[0];
    if (t->msg == msg_unexpected && (c < 0x20 || c > 0x7e))
        PERR(p, -EINVAL, t->line, t->col,
             "unexpected byte 0x%02x (expressions are ASCII)", c);
    else
        PERR(p, -EINVAL, t->line, t->col, "%s '%.*s%s'", t->msg,
             t->len > 40 ? 40 : (int)t->len, t->s, t->len > 40 ? "..." : "");
}

static void advance(parser *p)
{
    lex(&p->lx, &p->tok);
    if (p->tok.kind == TK_ERROR) lex_error(p, &p->tok);
}

static tk_kind peek_kind(const parser *p)
{
    lexer l = p->lx;
    token t;
    lex(&l, &t);
    return t.kind;
}

static expr_ast *new_node(parser *p, int kind, int op, const token *at,
                          uint32_t nargs)
{
    if (++p->nodes > p->max_nodes) {
        PERR(p, -E2BIG, at->line, at->col,
             "expression is too large (more than %u syntax nodes)", p->max_nodes);
        return NULL;
    }
    expr_ast *n = arena_alloc(p->prog, sizeof *n + nargs * sizeof(expr_ast *));
    if (!n) {
        PERR(p, -ENOMEM, 0, 0, "out of memory");
        return NULL;
    }
    memset(n, 0, sizeof *n);
    n->kind = (uint8_t)kind;
    n->op = (uint8_t)op;
    n->nargs = nargs;
    n->height = 1;
    n->line = at->line;
    n->col = at->col;
    n->args = nargs ? (expr_ast **)(n + 1) : NULL;
    return n;
}

/* Set the children and check the height limit (a chain's left operand
 * that chains too is one level less: see expr_ast_chains). */
static expr_ast *set_args(parser *p, expr_ast *n, expr_ast *const *args)
{
    uint32_t h = 0;
    for (uint32_t i = 0; i < n->nargs; i++) {
        n->args[i] = args[i];
        uint32_t hi = args[i]->height;
        if (i == 0 && expr_ast_chains(n) && expr_ast_chains(args[0])) hi--;
        if (hi > h) h = hi;
    }
    if (h + 1 > p->max_depth) {
        PERR(p, -E2BIG, n->line, n->col,
             "expression nests too deeply (limit %u levels)", p->max_depth);
        return NULL;
    }
    n->height = (uint16_t)(h + 1);
    return n;
}

static expr_ast *op_node(parser *p, int op, const token *at, expr_ast *a, expr_ast *b)
{
    expr_ast *args[2] = {a, b};
    expr_ast *n = new_node(p, EXPR_AST_OP, op, at, b ? 2 : 1);
    return n ? set_args(p, n, args) : NULL;
}

static expr_ast *parse_expr(parser *p);
static expr_ast *parse_unary(parser *p);

/* ---- grammar ---- */

#define MAX_SHOWN 40
#define SHOW(t) ((t)->len > MAX_SHOWN ? MAX_SHOWN : (int)(t)->len), (t)->s, \
                ((t)->len > MAX_SHOWN ? "..." : "")

/* '(' already current.  Arguments go to a growing scratch array. */
static expr_ast *parse_call(parser *p, const func_def *f, token name)
{
    expr_ast *small[4] = {0}, **args = small;
    uint32_t n = 0, cap = 4;
    advance(p);
    if (p->tok.kind != TK_RPAREN) {
        for (;;) {
            expr_ast *a = parse_expr(p);
            if (!a) goto fail;
            if (n == cap) {
                expr_ast **g = malloc(2 * cap * sizeof *g);
                if (!g) {
                    PERR(p, -ENOMEM, 0, 0, "out of memory");
                    goto fail;
                }
                memcpy(g, args, n * sizeof *g);
                if (args != small) free(args);
                args = g;
                cap *= 2;
            }
            args[n++] = a;
            if (p->tok.kind != TK_COMMA) break;
            advance(p);
        }
        if (p->tok.kind != TK_RPAREN) {
            PERR(p, -EINVAL, p->tok.line, p->tok.col, "expected ')' after argument list");
            goto fail;
        }
    }
    if (n < f->min_args || (f->max_args && n > f->max_args)) {
        if (!f->max_args)
            PERR(p, -EINVAL, name.line, name.col, "%s takes at least %u arguments",
                 f->name, f->min_args);
        else
            PERR(p, -EINVAL, name.line, name.col, "%s takes %u argument%s", f->name,
                 f->min_args, f->min_args == 1 ? "" : "s");
        goto fail;
    }
    advance(p);
    expr_ast *node = new_node(p, EXPR_AST_OP, f->op, &name, n);
    if (node) node = set_args(p, node, args);
    if (args != small) free(args);
    return node;
fail:
    if (args != small) free(args);
    return NULL;
}

static expr_ast *parse_name(parser *p)
{
    token t = p->tok;
    const func_def *f = find_func(&t);
    int64_t named = name_find(names_of(p), &t);
    int var = find_var(&t), sph = find_sph(&t), pi = tok_is(&t, "pi");
    advance(p);
    if (p->rc) return NULL;
    if (p->tok.kind == TK_LPAREN) {
        if (f) return parse_call(p, f, t);
        if (var >= 0 || sph >= 0 || pi || named >= 0)
            PERR(p, -EINVAL, t.line, t.col, "'%.*s%s' is not a function", SHOW(&t));
        else
            PERR(p, -EINVAL, t.line, t.col, "unknown function '%.*s%s'", SHOW(&t));
        return NULL;
    }
    if (f) {
        PERR(p, -EINVAL, t.line, t.col, "expected '(' after function name '%s'", f->name);
        return NULL;
    }
    expr_ast *n = NULL;
    if (var >= 0) {
        if ((n = new_node(p, EXPR_AST_VAR, 0, &t, 0))) n->index = (uint32_t)var;
    } else if (sph >= 0) {
        n = new_node(p, EXPR_AST_OP, sph, &t, 0);
    } else if (pi) {
        n = new_node(p, EXPR_AST_PI, 0, &t, 0);
    } else if (named >= 0) {
        if ((n = new_node(p, EXPR_AST_NAME, 0, &t, 0))) n->index = (uint32_t)named;
    } else {
        PERR(p, -EINVAL, t.line, t.col, "'%.*s%s' is not defined", SHOW(&t));
    }
    return n;
}

static expr_ast *parse_primary(parser *p)
{
    token t = p->tok;
    char buf[96];
    if (t.kind == TK_NUM) {
        expr_ast *n = new_node(p, EXPR_AST_NUM, 0, &t, 0);
        if (n) n->num = t.num;
        advance(p);
        return n;
    }
    if (t.kind == TK_IDENT) return parse_name(p);
    if (t.kind == TK_LPAREN) {
        advance(p);
        expr_ast *n = parse_expr(p);
        if (!n) return NULL;
        if (p->tok.kind != TK_RPAREN) {
            PERR(p, -EINVAL, p->tok.line, p->tok.col,
                 "expected ')' to close the '(' at %d:%d", t.line, t.col);
            return NULL;
        }
        advance(p);
        return n;
    }
    if (t.kind != TK_ERROR)
        PERR(p, -EINVAL, t.line, t.col, "expected an expression, found %s",
             tok_desc(&t, buf, sizeof buf));
    return NULL;
}

static expr_ast *parse_power(parser *p)
{
    expr_ast *base = parse_primary(p);
    if (!base || p->tok.kind != TK_CARET) return base;
    token op = p->tok;
    advance(p);
    expr_ast *e = parse_unary(p);
    return e ? op_node(p, EXPR_OP_POW, &op, base, e) : NULL;
}

static expr_ast *parse_unary(parser *p)
{
    if (p->rc) return NULL;
    if (++p->depth > p->max_depth) {
        PERR(p, -E2BIG, p->tok.line, p->tok.col,
             "expression nests too deeply (limit %u levels)", p->max_depth);
        return NULL;
    }
    token t = p->tok;
    expr_ast *n;
    if (t.kind == TK_MINUS || t.kind == TK_PLUS) {
        advance(p);
        n = parse_unary(p);
        if (n && t.kind == TK_MINUS) n = op_node(p, EXPR_OP_NEG, &t, n, NULL);
    } else {
        n = parse_power(p);
    }
    p->depth--;
    return n;
}

static expr_ast *parse_term(parser *p)
{
    expr_ast *n = parse_unary(p);
    while (n && (p->tok.kind == TK_STAR || p->tok.kind == TK_SLASH)) {
        token t = p->tok;
        advance(p);
        expr_ast *b = parse_unary(p);
        n = b ? op_node(p, t.kind == TK_STAR ? EXPR_OP_MUL : EXPR_OP_DIV, &t, n, b) : NULL;
    }
    return n;
}

static expr_ast *parse_expr(parser *p)
{
    expr_ast *n = parse_term(p);
    while (n && (p->tok.kind == TK_PLUS || p->tok.kind == TK_MINUS)) {
        token t = p->tok;
        advance(p);
        expr_ast *b = parse_term(p);
        n = b ? op_node(p, t.kind == TK_PLUS ? EXPR_OP_ADD : EXPR_OP_SUB, &t, n, b) : NULL;
    }
    return n;
}

/* ---- program ---- */

static int check_new_name(parser *p, const token *t)
{
    int64_t k;
    if (find_var(t) >= 0 || find_sph(t) >= 0)
        PERR(p, -EINVAL, t->line, t->col, "cannot redefine variable '%.*s%s'", SHOW(t));
    else if (find_func(t))
        PERR(p, -EINVAL, t->line, t->col, "cannot redefine function '%.*s%s'", SHOW(t));
    else if (tok_is(t, "pi"))
        PERR(p, -EINVAL, t->line, t->col, "cannot redefine constant 'pi'");
    else if ((k = name_find(names_of(p), t)) >= 0)
        PERR(p, -EINVAL, t->line, t->col, "'%.*s%s' is already defined at %d:%d",
             SHOW(t), names_of(p)->defs[k].line, names_of(p)->defs[k].col);
    return p->rc;
}

static int add_def(parser *p, const token *name, expr_ast *e)
{
    expr_program *prog = p->prog;
    if (prog->ndefs == prog->capdefs) {
        uint32_t cap = prog->capdefs ? prog->capdefs * 2 : 16;
        expr_ast **d = realloc(prog->defs, cap * sizeof *d);
        if (!d) return -ENOMEM;
        prog->defs = d;
        prog->capdefs = cap;
    }
    if (name_add(names_of(p), name)) return -ENOMEM;
    prog->defs[prog->ndefs++] = e;
    return 0;
}

/* NAME '=' expr ';' with NAME current and '=' next. */
static void parse_definition(parser *p)
{
    token name = p->tok;
    if (check_new_name(p, &name)) return;
    advance(p);
    advance(p);
    expr_ast *e = parse_expr(p);
    if (!e) return;
    if (p->tok.kind != TK_SEMI) {
        char buf[96];
        PERR(p, -EINVAL, p->tok.line, p->tok.col,
             "expected ';' after the definition of '%.*s%s', found %s", SHOW(&name),
             tok_desc(&p->tok, buf, sizeof buf));
        return;
    }
    advance(p);
    if (add_def(p, &name, e)) PERR(p, -ENOMEM, 0, 0, "out of memory");
}

static void parse_program(parser *p)
{
    char buf[96];
    advance(p);
    if (p->tok.kind == TK_EOF) {
        PERR(p, -EINVAL, p->tok.line, p->tok.col, "empty expression");
        return;
    }
    while (!p->rc && p->tok.kind == TK_IDENT && peek_kind(p) == TK_ASSIGN)
        parse_definition(p);
    if (p->rc) return;
    if (p->tok.kind == TK_EOF) {
        PERR(p, -EINVAL, p->tok.line, p->tok.col,
             "expected an expression after the definitions");
        return;
    }
    p->prog->final = parse_expr(p);
    if (p->rc) return;
    if (p->tok.kind == TK_SEMI) advance(p);
    if (!p->rc && p->tok.kind != TK_EOF)
        PERR(p, -EINVAL, p->tok.line, p->tok.col, "unexpected %s after the expression",
             tok_desc(&p->tok, buf, sizeof buf));
}

static void nul_position(const char *src, size_t at, int *line, int *col)
{
    size_t start = 0;
    *line = 1;
    for (size_t i = 0; i < at; i++)
        if (src[i] == '\n') (*line)++, start = i + 1;
    *col = (int)(at - start) + 1;
}

void expr_limits_default(expr_limits *lim)
{
    lim->max_source_bytes = EXPR_DEFAULT_MAX_SOURCE;
    lim->max_depth = EXPR_DEFAULT_MAX_DEPTH;
    lim->max_nodes = EXPR_DEFAULT_MAX_NODES;
}

int expr_parse(const char *src, size_t len, const expr_limits *lim,
               expr_program *prog, expr_error *err)
{
    expr_limits l;
    expr_limits_default(&l);
    if (lim) {
        if (lim->max_source_bytes) l.max_source_bytes = lim->max_source_bytes;
        if (lim->max_depth)
            l.max_depth = lim->max_depth < EXPR_MAX_DEPTH_CAP ? lim->max_depth : EXPR_MAX_DEPTH_CAP;
        if (lim->max_nodes) l.max_nodes = lim->max_nodes;
    }
    memset(prog, 0, sizeof *prog);
    if (err) memset(err, 0, sizeof *err);
    if (len > l.max_source_bytes) {
        return expr_set_error(err, -E2BIG, 0, 0, "expression is too long (%zu bytes, limit %u)",
                              len, l.max_source_bytes);
    }
    const char *nul = len ? memchr(src, 0, len) : NULL;
    if (nul) {
        int line, col;
        nul_position(src, (size_t)(nul - src), &line, &col);
        return expr_set_error(err, -EINVAL, line, col, "NUL byte in expression");
    }
    name_table names = {0};
    parser p = {.lx = {.src = src, .len = len, .line = 1}, .prog = prog, .err = err,
                .max_depth = l.max_depth, .max_nodes = l.max_nodes, .names = &names};
    parse_program(&p);
    free(names.defs);
    free(names.slots);
    if (p.rc) expr_program_free(prog);
    return p.rc;
}
