/* csg_pack — a CSG tree and its file leaves' bytes as one buffer, and
 * back: how vox_mpi broadcasts a job's tree to its ranks and how voxd
 * hands its CSG jobs to vox_mpi (a file in the job's directory).  The
 * buffer is the program's own structures (nodes, text, leaves' bytes):
 * the same build reads what it wrote.  Unpacking checks it as any input
 * is: counts, lengths, children below their parent, text references
 * inside the text, every file leaf with its bytes. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "csg_pack.h"

typedef struct {
    uint32_t n, node_bytes;
    uint64_t text_len;
    uint64_t data_len[CSG_MAX_NODES];
} csg_head;

int csg_tree_pack(const csg_tree *t, uint8_t **out, size_t *len)
{
    csg_head h = {.n = t->n, .node_bytes = sizeof(csg_node), .text_len = t->text_len};
    size_t n = sizeof h + (size_t)t->n * sizeof(csg_node) + t->text_len;
    for (uint32_t i = 0; i < t->n; i++) {
        h.data_len[i] = t->data[i] ? t->data_len[i] : 0;
        n += h.data_len[i];
    }
    uint8_t *b = malloc(n);
    if (!b) return -ENOMEM;
    size_t at = sizeof h;
    memcpy(b, &h, sizeof h);
    memcpy(b + at, t->node, (size_t)t->n * sizeof(csg_node));
    at += (size_t)t->n * sizeof(csg_node);
    if (t->text_len) memcpy(b + at, t->text, t->text_len);
    at += t->text_len;
    for (uint32_t i = 0; i < t->n; i++) {
        if (h.data_len[i]) memcpy(b + at, t->data[i], h.data_len[i]);
        at += h.data_len[i];
    }
    *out = b;
    *len = n;
    return 0;
}

/* 1 when node i's children and text references are inside the tree. */
static int node_ok(const csg_tree *t, uint32_t i)
{
    const csg_node *c = &t->node[i];
    if ((unsigned)c->kind >= CSG_KIND_COUNT || c->a >= (int32_t)i || c->b >= (int32_t)i)
        return 0;
    if (c->kind == CSG_IMPLICIT &&
        ((uint64_t)c->expr_off + c->expr_len > t->text_len))
        return 0;
    if ((c->kind == CSG_MESH || c->kind == CSG_VOD) &&
        ((uint64_t)c->path_off + c->path_len > t->text_len || !t->data[i]))
        return 0;
    return 1;
}

int csg_tree_unpack(const uint8_t *buf, size_t len, csg_tree **out)
{
    csg_head h;
    if (len < sizeof h) return -EPROTO;
    memcpy(&h, buf, sizeof h);
    if (!h.n || h.n > CSG_MAX_NODES || h.node_bytes != sizeof(csg_node) ||
        h.text_len > CSG_MAX_SOURCE)
        return -EPROTO;
    uint64_t need = sizeof h + (uint64_t)h.n * sizeof(csg_node) + h.text_len;
    for (uint32_t i = 0; i < h.n; i++) {
        if (h.data_len[i] > CSG_MAX_LEAF_FILE) return -EPROTO;
        need += h.data_len[i];
    }
    if (need != len) return -EPROTO;
    csg_tree *t = calloc(1, sizeof *t);
    if (!t || !(t->text = malloc(h.text_len + 1))) {
        free(t);
        return -ENOMEM;
    }
    size_t at = sizeof h;
    t->n = h.n;
    memcpy(t->node, buf + at, (size_t)h.n * sizeof(csg_node));
    at += (size_t)h.n * sizeof(csg_node);
    if (h.text_len) memcpy(t->text, buf + at, h.text_len);
    t->text[h.text_len] = '\0';
    t->text_len = h.text_len;
    at += h.text_len;
    int rc = 0;
    for (uint32_t i = 0; i < h.n && !rc; i++) {
        if (!h.data_len[i]) continue;
        if (!(t->data[i] = malloc(h.data_len[i]))) rc = -ENOMEM;
        else memcpy(t->data[i], buf + at, h.data_len[i]);
        t->data_len[i] = h.data_len[i];
        at += h.data_len[i];
    }
    for (uint32_t i = 0; i < h.n && !rc; i++)
        if (!node_ok(t, i)) rc = -EPROTO;
    if (rc) {
        csg_tree_free(t);
        return rc;
    }
    *out = t;
    return 0;
}
