/* csg_parse — the .csg text (docs/csg.md) into a flat node list.
 *
 * Pass 1 finds every line's definition "NAME = ..." and the "result NAME"
 * line.  Pass 2 walks from the result: a definition is parsed when first
 * referenced, its references first, so every child gets a smaller index and
 * a reference back into a definition being parsed is a cycle.  Unreferenced
 * definitions are parsed too (after the result's), so their errors show,
 * but are not part of the tree.
 */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "err.h"

typedef struct {
    char name[CSG_NAME_MAX];
    size_t start, end;  /* the text after '=', to the line's end or '#' */
    int line, col;      /* of that text */
    int state;          /* 0 not yet, 1 being parsed, 2 done */
    int32_t index;      /* its node */
} def;

typedef struct {
    const char *src;
    size_t len;
    def defs[CSG_MAX_NODES];
    uint32_t ndefs;
    csg_tree *t;
    csg_error *err;
    /* the cursor inside one definition */
    const def *cur;
    size_t pos, end;
    uint32_t depth;
    char text[CSG_MAX_SOURCE + CSG_MAX_NODES];
    size_t text_len;
} parser;

/* A place in the text: a line and column (1-based; 0 when none) and the
 * definition's name (NULL when none). */
typedef struct {
    int line, col;
    const char *node;
} src_pos;

#define NOWHERE ((src_pos){0, 0, NULL})

static int fail_at(parser *p, int rc, src_pos at, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    err_vset(&p->err->info, rc, fmt, ap);
    va_end(ap);
    p->err->line = at.line;
    p->err->col = at.col;
    snprintf(p->err->node, sizeof p->err->node, "%s", at.node ? at.node : "");
    return rc;
}

/* An error at the cursor, in the definition being parsed. */
static int fail(parser *p, int rc, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    char msg[sizeof p->err->msg];
    err_vfmt(msg, sizeof msg, rc, fmt, ap);
    va_end(ap);
    src_pos at = {p->cur->line, p->cur->col + (int)(p->pos - p->cur->start), p->cur->name};
    return fail_at(p, rc, at, "%s", msg);
}

static void skip_space(parser *p)
{
    while (p->pos < p->end && (p->src[p->pos] == ' ' || p->src[p->pos] == '\t' ||
                               p->src[p->pos] == '\r'))
        p->pos++;
}

static int is_name_char(char c, int first)
{
    return isalpha((unsigned char)c) || c == '_' || (!first && isdigit((unsigned char)c));
}

/* A word [A-Za-z_][A-Za-z0-9_]* at the cursor into w (0), or -EINVAL. */
static int word(parser *p, char w[CSG_NAME_MAX])
{
    skip_space(p);
    size_t s = p->pos;
    while (p->pos < p->end && is_name_char(p->src[p->pos], p->pos == s)) p->pos++;
    if (p->pos == s) return fail(p, -EINVAL, "expected a name");
    if (p->pos - s >= CSG_NAME_MAX) {
        p->pos = s;
        return fail(p, -EINVAL, "a name longer than %u bytes", CSG_NAME_MAX - 1);
    }
    memcpy(w, p->src + s, p->pos - s);
    w[p->pos - s] = 0;
    return 0;
}

static int expect(parser *p, char c)
{
    skip_space(p);
    if (p->pos < p->end && p->src[p->pos] == c) {
        p->pos++;
        return 0;
    }
    return fail(p, -EINVAL, "expected '%c'", c);
}

static int number(parser *p, double *v)
{
    skip_space(p);
    char buf[64];
    size_t n = 0;
    while (p->pos + n < p->end && n < sizeof buf - 1 &&
           strchr("0123456789+-.eE", p->src[p->pos + n]))
        n++;
    memcpy(buf, p->src + p->pos, n);
    buf[n] = 0;
    char *e;
    double x = n ? strtod(buf, &e) : 0;
    if (!n || *e || !isfinite(x)) return fail(p, -EINVAL, "expected a finite number");
    p->pos += n;
    *v = x;
    return 0;
}

/* n numbers separated by commas. */
static int numbers(parser *p, double *v, int n)
{
    for (int i = 0; i < n; i++) {
        if (i && expect(p, ',')) return -EINVAL;
        if (number(p, &v[i])) return -EINVAL;
    }
    return 0;
}

static int new_node(parser *p, csg_kind k, csg_node **out)
{
    if (p->t->n >= CSG_MAX_NODES)
        return fail(p, -E2BIG, "more than %u nodes", CSG_MAX_NODES);
    csg_node *n = &p->t->node[p->t->n];
    memset(n, 0, sizeof *n);
    n->kind = k;
    n->a = n->b = -1;
    n->axis = 2;
    snprintf(n->name, sizeof n->name, "%s", p->cur->name);
    for (int i = 0; i < 3; i++) n->m[i][i] = 1;
    *out = n;
    return 0;
}

static int parse_def(parser *p, def *d);

static int find_def(parser *p, const char *name)
{
    for (uint32_t i = 0; i < p->ndefs; i++)
        if (!strcmp(p->defs[i].name, name)) return (int)i;
    return -1;
}

/* The node a reference to name stands for: its definition parsed first. */
static int reference(parser *p, const char *name, size_t at, int32_t *idx)
{
    int i = find_def(p, name);
    size_t after = p->pos;
    p->pos = at;
    if (i < 0) return fail(p, -EINVAL, "unknown node '%s'", name);
    def *d = &p->defs[i];
    if (d->state == 1) return fail(p, -EINVAL, "a cycle: '%s' depends on itself", name);
    p->pos = after;
    if (d->state == 0) {
        const def *cur = p->cur;
        size_t pos = p->pos, end = p->end;
        int rc = parse_def(p, d);
        p->cur = cur, p->pos = pos, p->end = end;
        if (rc) return rc;
    }
    *idx = d->index;
    return 0;
}

static const csg_kind binary[] = {CSG_UNION, CSG_INTERSECTION, CSG_TRIM, CSG_CAP,
                                  CSG_DIFFERENCE_A, CSG_DIFFERENCE_B, CSG_DIFFERENCE,
                                  CSG_ADD, CSG_MODULATE, CSG_DIVIDE_A, CSG_DIVIDE};

static int kind_of(const char *w, csg_kind *k)
{
    for (int i = 0; i < CSG_KIND_COUNT; i++)
        if (!strcmp(w, csg_kind_name((csg_kind)i))) {
            *k = (csg_kind)i;
            return 0;
        }
    return -1;
}

static int is_binary(csg_kind k)
{
    for (size_t i = 0; i < sizeof binary / sizeof *binary; i++)
        if (binary[i] == k) return 1;
    return 0;
}

static int call(parser *p, csg_kind k, int32_t *idx);

/* An operand: a node's name or a nested call. */
static int operand(parser *p, int32_t *idx)
{
    char w[CSG_NAME_MAX];
    skip_space(p);
    size_t at = p->pos;
    if (word(p, w)) return -EINVAL;
    skip_space(p);
    csg_kind k;
    if (p->pos < p->end && p->src[p->pos] == '(') {
        if (kind_of(w, &k) || csg_is_leaf(k)) {
            p->pos = at;
            return fail(p, -EINVAL, "unknown operator '%s'", w);
        }
        return call(p, k, idx);
    }
    return reference(p, w, at, idx);
}

/* op(args) after its name; the cursor on '('. */
static int call(parser *p, csg_kind k, int32_t *idx)
{
    if (++p->depth > CSG_MAX_DEPTH)
        return fail(p, -E2BIG, "nested deeper than %u", CSG_MAX_DEPTH);
    size_t at = p->pos;
    int32_t a = -1, b = -1;
    double param = 0;
    /* an operand's code as it is: a leaf below may be past a limit or
     * out of memory (-E2BIG, -ENOMEM), not only malformed */
    int rc = expect(p, '(');
    if (rc || (rc = operand(p, &a))) return rc;
    int nodes = 1, nums = 0;
    if (is_binary(k)) {
        if ((rc = expect(p, ',')) || (rc = operand(p, &b))) return rc;
        nodes = 2;
    }
    if (k == CSG_DIVIDE || k == CSG_SCALAR_ADD || k == CSG_SCALAR_MUL || k == CSG_ERODE ||
        k == CSG_DILATE) {
        skip_space(p);
        if (p->pos >= p->end || p->src[p->pos] != ',') {
            p->pos = at;
            return fail(p, -EINVAL, "%s takes %d node%s and a number", csg_kind_name(k),
                        nodes, nodes > 1 ? "s" : "");
        }
        p->pos++;
        if (number(p, &param)) return -EINVAL;
        nums = 1;
    }
    skip_space(p);
    if (p->pos < p->end && p->src[p->pos] == ',') {
        p->pos = at;
        return fail(p, -EINVAL, "%s takes %d node%s%s", csg_kind_name(k), nodes,
                    nodes > 1 ? "s" : "", nums ? " and a number" : "");
    }
    if (expect(p, ')')) return -EINVAL;
    if (k == CSG_DIVIDE && !(param > 0 && param <= 1)) {
        p->pos = at;
        return fail(p, -EINVAL, "divide's S_L must be in (0, 1]");
    }
    if ((k == CSG_ERODE || k == CSG_DILATE) &&
        !(param >= 1 && param <= CSG_MAX_MORPH && param == floor(param))) {
        p->pos = at;
        return fail(p, -EINVAL, "%s's k must be a whole number of voxels 1..%u",
                    csg_kind_name(k), CSG_MAX_MORPH);
    }
    csg_node *n;
    if (new_node(p, k, &n)) return -E2BIG;
    n->a = a, n->b = b, n->param = param;
    if (k == CSG_ERODE || k == CSG_DILATE) n->k = (uint32_t)param;
    *idx = (int32_t)p->t->n++;
    p->depth--;
    return 0;
}

static int positive(parser *p, const double *v, int n, const char *what)
{
    for (int i = 0; i < n; i++)
        if (!(v[i] > 0)) return fail(p, -EINVAL, "%s must be positive", what);
    return 0;
}

/* An implicit leaf's "source" into the tree's text. */
static int implicit(parser *p, csg_node *n)
{
    skip_space(p);
    if (p->pos >= p->end || p->src[p->pos] != '"')
        return fail(p, -EINVAL, "implicit needs its expression in double quotes");
    size_t s = ++p->pos;
    while (p->pos < p->end && p->src[p->pos] != '"') p->pos++;
    if (p->pos >= p->end) return fail(p, -EINVAL, "the expression's quote is not closed");
    size_t len = p->pos++ - s;
    expr_tape *tape;
    expr_error ee;
    int rc = expr_compile(p->src + s, len, NULL, &tape, &ee);
    if (rc < 0) { /* the compiler's code: -EINVAL, -E2BIG past a limit, -ENOMEM */
        p->pos = s + (size_t)(ee.col > 0 ? ee.col - 1 : 0);
        return fail(p, rc, "in the expression: %s", ee.msg);
    }
    expr_tape_free(tape);
    n->expr_off = (uint32_t)p->text_len;
    n->expr_len = (uint32_t)len;
    memcpy(p->text + p->text_len, p->src + s, len);
    p->text[p->text_len + len] = 0;
    p->text_len += len + 1;
    return 0;
}

/* A mesh or vod leaf's "file name" into the tree's text (the caller reads
 * the file: the parser does no I/O). */
static int file_name(parser *p, csg_node *n)
{
    skip_space(p);
    if (p->pos >= p->end || p->src[p->pos] != '"')
        return fail(p, -EINVAL, "%s needs its file's name in double quotes",
                    csg_kind_name(n->kind));
    size_t s = ++p->pos;
    while (p->pos < p->end && p->src[p->pos] != '"') p->pos++;
    if (p->pos >= p->end) return fail(p, -EINVAL, "the file name's quote is not closed");
    size_t len = p->pos++ - s;
    if (!len) return fail(p, -EINVAL, "the file name is empty");
    n->path_off = (uint32_t)p->text_len;
    n->path_len = (uint32_t)len;
    n->scale = 1;
    memcpy(p->text + p->text_len, p->src + s, len);
    p->text[p->text_len + len] = 0;
    p->text_len += len + 1;
    return 0;
}

/* One "key value" of a leaf.  A cylinder's or cone's sizes are read as
 * if its axis were z (size[2] the height) and moved to its axis after. */
static int leaf_param(parser *p, csg_node *n, const char *key, int *sized)
{
    double v[3];
    if (n->kind == CSG_MESH) {
        if (!strcmp(key, "fit")) return n->has_fit = 1, numbers(p, n->fit, 3);
        if (strcmp(key, "scale"))
            return fail(p, -EINVAL, "mesh takes fit and scale, not '%s'", key);
        return number(p, &n->scale) || positive(p, &n->scale, 1, "scale") ? -EINVAL : 0;
    }
    if (n->kind == CSG_VOD)
        return fail(p, -EINVAL, "vod takes only its file's name, not '%s'", key);
    if (!strcmp(key, "center")) return numbers(p, n->center, 3);
    if (!strcmp(key, "rotate")) {
        if (numbers(p, v, 3)) return -EINVAL;
        for (int i = 0; i < 3; i++) n->rot[i] = v[i] * M_PI / 180;
        return 0;
    }
    if (n->kind == CSG_IMPLICIT) {
        if (strcmp(key, "domain")) return fail(p, -EINVAL, "implicit takes domain, not '%s'", key);
        if (numbers(p, v, 2)) return -EINVAL;
        if (!(v[0] < v[1])) return fail(p, -EINVAL, "the domain's low end must be below its high end");
        n->has_domain = 1, n->dom_lo = v[0], n->dom_hi = v[1];
        return 0;
    }
    int round = n->kind != CSG_CUBOID, axial = n->kind == CSG_CYLINDER || n->kind == CSG_CONE;
    if (!strcmp(key, "size") && !round) {
        if (numbers(p, n->size, 3) || positive(p, n->size, 3, "size")) return -EINVAL;
        *sized |= 7;
    } else if (!strcmp(key, "radius") && round) {
        if (number(p, v) || positive(p, v, 1, "radius")) return -EINVAL;
        for (int i = 0; i < 3; i++)
            if (!axial || i != 2) n->size[i] = 2 * v[0];
        *sized |= axial ? 3 : 7;
    } else if (!strcmp(key, "radii") && round) {
        int k = axial ? 2 : 3;
        if (numbers(p, v, k) || positive(p, v, k, "radii")) return -EINVAL;
        for (int i = 0, j = 0; i < 3; i++)
            if (!axial || i != 2) n->size[i] = 2 * v[j++];
        *sized |= axial ? 3 : 7;
    } else if (!strcmp(key, "height") && axial) {
        if (number(p, v) || positive(p, v, 1, "height")) return -EINVAL;
        n->size[2] = v[0];
        *sized |= 4;
    } else if (!strcmp(key, "axis") && axial) {
        char w[CSG_NAME_MAX];
        if (word(p, w)) return -EINVAL;
        if (strlen(w) != 1 || w[0] < 'x' || w[0] > 'z')
            return fail(p, -EINVAL, "axis is x, y or z");
        n->axis = w[0] - 'x';
    } else {
        return fail(p, -EINVAL, "%s has no parameter '%s'", csg_kind_name(n->kind), key);
    }
    return 0;
}

static int leaf(parser *p, csg_kind k, int32_t *idx)
{
    csg_node *n;
    if (new_node(p, k, &n)) return -E2BIG;
    int sized = 0, rc = 0;
    if (k == CSG_IMPLICIT) rc = implicit(p, n); /* -EINVAL, -E2BIG, -ENOMEM */
    if (k == CSG_MESH || k == CSG_VOD) rc = file_name(p, n);
    if (rc) return rc;
    for (;;) {
        skip_space(p);
        if (p->pos >= p->end) break;
        char key[CSG_NAME_MAX];
        if (word(p, key) || leaf_param(p, n, key, &sized)) return -EINVAL;
    }
    if (k <= CSG_CONE && sized != 7)
        return fail(p, -EINVAL, "%s needs its %s", csg_kind_name(k),
                    k == CSG_CUBOID ? "size" : k == CSG_ELLIPSOID ? "radius or radii"
                                                                   : "radius and height");
    if (n->axis != 2) { /* sizes were read as if the axis were z */
        double r[3] = {n->size[0], n->size[1], n->size[2]};
        n->size[(n->axis + 1) % 3] = r[0];
        n->size[(n->axis + 2) % 3] = r[1];
        n->size[n->axis] = r[2];
    }
    csg_node_rotation(n);
    *idx = (int32_t)p->t->n++;
    return 0;
}

static int parse_def(parser *p, def *d)
{
    d->state = 1;
    p->cur = d, p->pos = d->start, p->end = d->end;
    if (++p->depth > CSG_MAX_DEPTH)
        return fail(p, -E2BIG, "references nested deeper than %u", CSG_MAX_DEPTH);
    char w[CSG_NAME_MAX];
    size_t at = (skip_space(p), p->pos);
    if (word(p, w)) return -EINVAL;
    csg_kind k;
    int rc;
    if (kind_of(w, &k)) {
        p->pos = at;
        return fail(p, -EINVAL, "unknown primitive or operator '%s'", w);
    }
    if (csg_is_leaf(k)) {
        rc = leaf(p, k, &d->index);
    } else {
        rc = call(p, k, &d->index);
        skip_space(p);
        if (!rc && p->pos < p->end) rc = fail(p, -EINVAL, "unexpected text after the node");
    }
    if (rc) return rc;
    p->depth--;
    d->state = 2;
    return 0;
}

/* Pass 1: one line (without its comment) at [s, e), line number ln. */
static int scan_line(parser *p, size_t s, size_t e, int ln, int *result)
{
    def tmp = {.start = s, .end = e, .line = ln, .col = 1};
    p->cur = &tmp, p->pos = s, p->end = e;
    skip_space(p);
    if (p->pos >= e) return 0;
    char w[CSG_NAME_MAX];
    if (word(p, w)) return -EINVAL;
    if (!strcmp(w, "result")) {
        if (*result >= 0) return fail(p, -EINVAL, "a second result line");
        size_t at = (skip_space(p), p->pos);
        if (word(p, w)) return -EINVAL;
        skip_space(p);
        if (p->pos < e) return fail(p, -EINVAL, "unexpected text after the result's name");
        int i = find_def(p, w);
        p->pos = at;
        if (i < 0) return fail(p, -EINVAL, "the result '%s' is not defined above", w);
        *result = i;
        return 0;
    }
    snprintf(tmp.name, sizeof tmp.name, "%s", w);
    if (find_def(p, w) >= 0) return fail(p, -EINVAL, "'%s' is defined twice", w);
    if (expect(p, '=')) return -EINVAL;
    if (p->ndefs >= CSG_MAX_NODES) return fail(p, -E2BIG, "more than %u nodes", CSG_MAX_NODES);
    tmp.col = (int)(p->pos - s) + 1;
    tmp.start = p->pos;
    p->defs[p->ndefs++] = tmp;
    return 0;
}

/* The end of the line's text: its '#' (outside quotes) or its newline. */
static size_t line_end(const char *src, size_t s, size_t len, size_t *next)
{
    size_t e = s, cut = (size_t)-1;
    int quoted = 0;
    while (e < len && src[e] != '\n') {
        if (src[e] == '"') quoted = !quoted;
        else if (src[e] == '#' && !quoted && cut == (size_t)-1) cut = e;
        e++;
    }
    *next = e + 1;
    return cut != (size_t)-1 ? cut : e;
}

/* The tree's depth and the widest erode / dilate margin along a path. */
static int check_shape(parser *p)
{
    uint32_t depth[CSG_MAX_NODES], margin[CSG_MAX_NODES];
    const csg_tree *t = p->t;
    for (uint32_t i = 0; i < t->n; i++) {
        const csg_node *n = &t->node[i];
        uint32_t d = 0, m = 0;
        if (n->a >= 0) d = depth[n->a], m = margin[n->a];
        if (n->b >= 0) d = d > depth[n->b] ? d : depth[n->b],
                       m = m > margin[n->b] ? m : margin[n->b];
        depth[i] = d + 1;
        margin[i] = m + n->k;
        if (depth[i] > CSG_MAX_DEPTH)
            return fail_at(p, -E2BIG, (src_pos){0, 0, n->name}, "the tree is deeper than %u",
                           CSG_MAX_DEPTH);
        if (margin[i] > CSG_MAX_MARGIN)
            return fail_at(p, -E2BIG, (src_pos){0, 0, n->name},
                           "erosions and dilations along one path pass %u voxels", CSG_MAX_MARGIN);
    }
    return 0;
}

static int parse_all(parser *p)
{
    if (p->len > CSG_MAX_SOURCE)
        return fail_at(p, -E2BIG, NOWHERE, "the text is over %u bytes", CSG_MAX_SOURCE);
    if (memchr(p->src, 0, p->len))
        return fail_at(p, -EINVAL, NOWHERE, "the text holds a NUL byte");
    int result = -1, ln = 1;
    for (size_t s = 0, next; s < p->len; s = next, ln++) {
        size_t e = line_end(p->src, s, p->len, &next);
        int rc = scan_line(p, s, e, ln, &result);
        if (rc) return rc;
    }
    if (result < 0) return fail_at(p, -EINVAL, NOWHERE, "no 'result NAME' line");
    int rc = parse_def(p, &p->defs[result]);
    if (rc) return rc;
    uint32_t used = p->t->n;
    for (uint32_t i = 0; i < p->ndefs && !rc; i++)
        if (p->defs[i].state == 0) rc = parse_def(p, &p->defs[i]);
    /* The result last: drop what only unreferenced definitions made. */
    p->t->n = used;
    return rc ? rc : check_shape(p);
}

int csg_parse(const char *src, size_t len, csg_tree **out, csg_error *err)
{
    memset(err, 0, sizeof *err);
    *out = NULL;
    parser *p = calloc(1, sizeof *p);
    csg_tree *t = calloc(1, sizeof *t);
    if (!p || !t) {
        free(p);
        free(t);
        return err_set(&err->info, -ENOMEM, "out of memory");
    }
    p->src = src, p->len = len, p->t = t, p->err = err;
    int rc = parse_all(p);
    if (!rc) {
        t->text = malloc(p->text_len + 1);
        if (!t->text) rc = fail_at(p, -ENOMEM, NOWHERE, "out of memory");
        else memcpy(t->text, p->text, p->text_len), t->text_len = p->text_len;
    }
    free(p);
    if (rc) {
        csg_tree_free(t);
        return rc;
    }
    *out = t;
    return 0;
}

void csg_tree_free(csg_tree *t)
{
    if (!t) return;
    for (uint32_t i = 0; i < CSG_MAX_NODES; i++) free(t->data[i]);
    free(t->text);
    free(t);
}
