/* A CSG job's tree from its checked Csg message (proto_check_request made
 * sure of every op, arity, child index, number and name): the csg.h nodes,
 * each implicit leaf's expression compiled once here under the daemon's
 * expression limits, so a bad tree is refused when it is submitted, never
 * when it runs.  The nodes get the values `vox csg` gives them from the
 * text (the rotation travels in radians: the same doubles, the same
 * matrix), so the daemon's file has the same bytes. */
#include "daemon.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "expr.h"
#include "proto_check.h"

static int kind_of(const Voxd__CsgNode *n, csg_kind *k)
{
    static const csg_kind prims[] = {
        [VOXD__PRIMITIVE__PRIMITIVE_CUBOID] = CSG_CUBOID,
        [VOXD__PRIMITIVE__PRIMITIVE_ELLIPSOID] = CSG_ELLIPSOID,
        [VOXD__PRIMITIVE__PRIMITIVE_CYLINDER] = CSG_CYLINDER,
        [VOXD__PRIMITIVE__PRIMITIVE_CONE] = CSG_CONE,
    };
    switch (n->op) {
    case VOXD__CSG_OP__CSG_PRIMITIVE: *k = prims[n->primitive]; return 0;
    case VOXD__CSG_OP__CSG_IMPLICIT: *k = CSG_IMPLICIT; return 0;
    case VOXD__CSG_OP__CSG_UNION: *k = CSG_UNION; return 0;
    case VOXD__CSG_OP__CSG_INTERSECTION: *k = CSG_INTERSECTION; return 0;
    case VOXD__CSG_OP__CSG_DIFFERENCE: *k = CSG_DIFFERENCE; return 0;
    case VOXD__CSG_OP__CSG_TRIM: *k = CSG_TRIM; return 0;
    case VOXD__CSG_OP__CSG_CAP: *k = CSG_CAP; return 0;
    case VOXD__CSG_OP__CSG_ADD: *k = CSG_ADD; return 0;
    case VOXD__CSG_OP__CSG_MODULATE: *k = CSG_MODULATE; return 0;
    case VOXD__CSG_OP__CSG_DIVIDE: *k = CSG_DIVIDE; return 0;
    case VOXD__CSG_OP__CSG_DIFFERENCE_A: *k = CSG_DIFFERENCE_A; return 0;
    case VOXD__CSG_OP__CSG_DIFFERENCE_B: *k = CSG_DIFFERENCE_B; return 0;
    case VOXD__CSG_OP__CSG_DIVIDE_A: *k = CSG_DIVIDE_A; return 0;
    case VOXD__CSG_OP__CSG_INVERSE: *k = CSG_INVERSE; return 0;
    case VOXD__CSG_OP__CSG_SCALAR_ADD: *k = CSG_SCALAR_ADD; return 0;
    case VOXD__CSG_OP__CSG_SCALAR_MUL: *k = CSG_SCALAR_MUL; return 0;
    case VOXD__CSG_OP__CSG_ERODE: *k = CSG_ERODE; return 0;
    case VOXD__CSG_OP__CSG_DILATE: *k = CSG_DILATE; return 0;
    case VOXD__CSG_OP__CSG_MESH: *k = CSG_MESH; return 0;
    case VOXD__CSG_OP__CSG_VOD: *k = CSG_VOD; return 0;
    default: return -EINVAL;
    }
}

/* Node i's expression (its message m) compiled under the daemon's limits,
 * then appended to the tree's text pool (t->text_len its bytes so far).
 * 0, or the compiler's errno with msg filled. */
static int implicit_leaf(csg_tree *t, const Voxd__CsgNode *m, size_t i, const expr_limits *lim,
                         char *msg, size_t len)
{
    csg_node *n = &t->node[i];
    expr_tape *tape = NULL;
    expr_error xe = {0};
    int rc = expr_compile((const char *)m->source.data, m->source.len, lim, &tape, &xe);
    expr_tape_free(tape);
    if (rc) {
        char at[32] = ""; /* where in the expression; none for out of memory */
        if (xe.line > 0) snprintf(at, sizeof at, ":%d:%d", xe.line, xe.col);
        snprintf(msg, len, "CSG node %zu ('%s'): expression%s: %s", i, n->name, at,
                 xe.msg[0] ? xe.msg : strerror(-rc));
        return rc;
    }
    n->expr_off = (uint32_t)t->text_len;
    n->expr_len = (uint32_t)m->source.len;
    memcpy(t->text + t->text_len, m->source.data, m->source.len);
    t->text[t->text_len + m->source.len] = 0;
    t->text_len += m->source.len + 1;
    if (m->n_domain == 2) n->has_domain = 1, n->dom_lo = m->domain[0], n->dom_hi = m->domain[1];
    return 0;
}

/* A mesh or vod leaf: its file's bytes copied into the tree (which frees
 * them), its placement; the daemon parses them when the job runs. */
static int file_leaf(csg_tree *t, csg_node *n, const Voxd__CsgNode *m, size_t i, char *msg,
                     size_t len)
{
    if (m->data_bytes) { /* the job's input, cut into the leaves when it runs */
        t->data_len[i] = (size_t)m->data_bytes;
    } else {
        if (!(t->data[i] = malloc(m->data.len))) {
            snprintf(msg, len, "out of memory");
            return -ENOMEM;
        }
        memcpy(t->data[i], m->data.data, m->data.len);
        t->data_len[i] = m->data.len;
    }
    n->has_fit = m->n_fit == 3;
    for (int a = 0; a < 3 && n->has_fit; a++) n->fit[a] = m->fit[a];
    n->scale = m->scale > 0 ? m->scale : 1;
    return 0;
}

static void node_fields(csg_node *n, const Voxd__CsgNode *m)
{
    n->a = m->n_children > 0 ? (int32_t)m->children[0] : -1;
    n->b = m->n_children > 1 ? (int32_t)m->children[1] : -1;
    n->param = m->scalar;
    n->k = m->k;
    n->axis = m->axis ? (int)m->axis - 1 : 2;
    for (int a = 0; a < 3; a++) {
        if (m->n_center == 3) n->center[a] = m->center[a];
        if (m->n_size == 3) n->size[a] = m->size[a];
        if (m->n_rotate == 3) n->rot[a] = m->rotate[a];
    }
    csg_node_rotation(n);
}

int daemon_csg_input(csg_tree *t, const char *input, size_t len)
{
    size_t off = 0;
    for (uint32_t i = 0; i < t->n; i++) {
        if (t->data[i] || !t->data_len[i]) continue;
        if (t->data_len[i] > len - off || !(t->data[i] = malloc(t->data_len[i])))
            return t->data_len[i] > len - off ? -EINVAL : -ENOMEM;
        memcpy(t->data[i], input + off, t->data_len[i]);
        off += t->data_len[i];
    }
    return off == len ? 0 : -EINVAL;
}

int daemon_csg_tree(const Voxd__Csg *c, uint32_t max_expr_bytes, uint32_t max_expr_depth,
                csg_tree **out, char *msg, size_t len)
{
    *out = NULL;
    size_t text = 1;
    for (size_t i = 0; i < c->n_nodes; i++) text += c->nodes[i]->source.len + 1;
    csg_tree *t = calloc(1, sizeof *t);
    if (t) t->text = malloc(text);
    if (!t || !t->text) {
        csg_tree_free(t);
        snprintf(msg, len, "out of memory");
        return -ENOMEM;
    }
    expr_limits lim;
    expr_limits_default(&lim);
    lim.max_source_bytes = max_expr_bytes;
    lim.max_depth = max_expr_depth;
    int rc = 0;
    for (size_t i = 0; i < c->n_nodes && !rc; i++) {
        const Voxd__CsgNode *m = c->nodes[i];
        csg_node *n = &t->node[i];
        memset(n, 0, sizeof *n);
        if (kind_of(m, &n->kind)) {
            snprintf(msg, len, "CSG node %zu: op %d is not supported", i, (int)m->op);
            rc = -EINVAL;
            break;
        }
        snprintf(n->name, sizeof n->name, "%.*s", (int)m->name.len, (const char *)m->name.data);
        node_fields(n, m);
        if (n->kind == CSG_IMPLICIT)
            rc = implicit_leaf(t, m, i, &lim, msg, len);
        if (n->kind == CSG_MESH || n->kind == CSG_VOD)
            rc = file_leaf(t, n, m, i, msg, len);
    }
    t->n = (uint32_t)c->n_nodes;
    if (rc) {
        csg_tree_free(t);
        return rc;
    }
    *out = t;
    return 0;
}
