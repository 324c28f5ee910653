/* mesh_gltf_scene — a glTF's scene into triangles (mesh_gltf.h): the
 * default scene's nodes (else scene 0's, else every node no other names as
 * a child), their transforms composed down the hierarchy (a matrix, or
 * translation * rotation * scale), and every triangle primitive of their
 * meshes (mode 4, the default, and the strips and fans 5 and 6) through
 * its accessors: POSITION (VEC3 of floats, or the integer types
 * KHR_mesh_quantization allows, normalized or not) and the optional
 * indices (SCALAR of u8, u16 or u32).  The accessors' rules are the
 * specification's: every offset aligned to its component, byteStride 4 to
 * 252 and a multiple of 4 (vertex attributes only), the last element
 * inside its bufferView, the view inside its buffer, the buffer's
 * byteLength inside its bytes.  A node whose transform mirrors (negative
 * determinant) has its triangles' order reversed, as the specification
 * says renderers do, so that they still face outwards. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_gltf.h"

enum { C_I8 = 5120, C_U8 = 5121, C_I16 = 5122, C_U16 = 5123, C_U32 = 5125, C_F32 = 5126 };

/* An accessor, resolved and checked: element i's components at p + i stride. */
typedef struct {
    const uint8_t *p;   /* NULL: no bufferView, every component 0 */
    uint64_t count, stride;
    unsigned comp, size, n; /* component type, its bytes, components an element */
    int normalized;
} view;

static unsigned comp_size(uint64_t c)
{
    switch (c) {
    case C_I8: case C_U8: return 1;
    case C_I16: case C_U16: return 2;
    case C_U32: case C_F32: return 4;
    default: return 0;
    }
}

/* The bufferView of accessor `what`: the bytes from byte offset `off` on,
 * elements of elem bytes, count of them. */
static int bind_view(gltf *g, uint64_t bv, uint64_t off, view *v, int vertex, const char *what)
{
    json_object *o;
    uint64_t buffer, boff, blen, stride;
    const mesh_gltf_buffer *bf;
    int rc = mesh_gltf_item(g, "bufferViews", bv, &o);
    gltf_obj at = {o, what};
    if (!rc) rc = mesh_gltf_uint(g, at, "buffer", -1, UINT32_MAX, &buffer);
    if (!rc) rc = mesh_gltf_uint(g, at, "byteOffset", 0, UINT64_MAX >> 2, &boff);
    if (!rc) rc = mesh_gltf_uint(g, at, "byteLength", -1, UINT64_MAX >> 2, &blen);
    if (!rc) rc = mesh_gltf_uint(g, at, "byteStride", 0, 252, &stride);
    if (!rc) rc = mesh_gltf_buffer_get(g, buffer, &bf);
    if (rc) return rc;
    uint64_t elem = (uint64_t)v->size * v->n;
    if (stride && (!vertex || stride < 4 || stride % 4 || stride < elem))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: bufferView %llu's byteStride %llu %s", what,
                       (unsigned long long)bv, (unsigned long long)stride,
                       vertex ? "(4 to 252, a multiple of 4, at least the element)"
                              : "on indices (not allowed)");
    if (boff > bf->len || blen > bf->len - boff)
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE,
                       "%s: bufferView %llu (%llu bytes at %llu) overflows buffer %llu (%llu bytes)",
                       what, (unsigned long long)bv, (unsigned long long)blen,
                       (unsigned long long)boff, (unsigned long long)buffer,
                       (unsigned long long)bf->len);
    v->stride = stride ? stride : elem;
    if (off % v->size || (boff + off) % v->size)
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: byte offset %llu is not aligned to its "
                       "%u-byte components", what, (unsigned long long)(boff + off), v->size);
    /* the last element's end: off + stride (count - 1) + elem, count < 2^32 */
    if (off > blen || v->stride * (v->count - 1) + elem > blen - off)
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE,
                       "%s: %llu elements of %llu bytes every %llu from byte %llu overflow "
                       "bufferView %llu (%llu bytes)", what, (unsigned long long)v->count,
                       (unsigned long long)elem, (unsigned long long)v->stride,
                       (unsigned long long)off, (unsigned long long)bv, (unsigned long long)blen);
    v->p = bf->data + boff + off;
    return 0;
}

/* Accessor a as POSITION (vertex 1: VEC3) or indices (SCALAR). */
static int accessor(gltf *g, uint64_t a, int vertex, view *v)
{
    char what[40];
    snprintf(what, sizeof what, "accessor %llu", (unsigned long long)a);
    json_object *o, *t, *x;
    uint64_t comp, off, bv;
    int rc = mesh_gltf_item(g, "accessors", a, &o);
    gltf_obj at = {o, what};
    if (!rc) rc = mesh_gltf_uint(g, at, "componentType", -1, UINT32_MAX, &comp);
    if (!rc) rc = mesh_gltf_uint(g, at, "count", -1, UINT32_MAX, &v->count);
    if (!rc) rc = mesh_gltf_uint(g, at, "byteOffset", 0, UINT64_MAX >> 2, &off);
    if (rc) return rc;
    const char *type = json_object_object_get_ex(o, "type", &t) ? json_object_get_string(t) : "";
    if (strcmp(type ? type : "", vertex ? "VEC3" : "SCALAR"))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: type %.16s, %s wanted", what, type ? type : "",
                       vertex ? "VEC3 (POSITION)" : "SCALAR (indices)");
    v->comp = (unsigned)comp, v->size = comp_size(comp), v->n = vertex ? 3 : 1;
    if (!v->size || (vertex && comp == C_U32) ||
        (!vertex && (comp == C_I8 || comp == C_I16 || comp == C_F32)))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: componentType %llu is not for %s", what,
                       (unsigned long long)comp,
                       vertex ? "positions (float; i8, u8, i16, u16 quantized)"
                              : "indices (u8, u16, u32)");
    v->normalized = json_object_object_get_ex(o, "normalized", &x) && json_object_get_boolean(x);
    if (json_object_object_get_ex(o, "sparse", &x))
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s is sparse (not read)", what);
    if (!v->count) return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: count 0", what);
    v->p = NULL;
    if (!json_object_object_get_ex(o, "bufferView", &x)) return 0; /* all zeros */
    if ((rc = mesh_gltf_uint(g, at, "bufferView", -1, UINT32_MAX, &bv))) return rc;
    return bind_view(g, bv, off, v, vertex, what);
}

/* Component k of element i, as the number it stands for. */
static double component(const view *v, uint64_t i, unsigned k)
{
    if (!v->p) return 0;
    const uint8_t *q = v->p + i * v->stride + (uint64_t)k * v->size;
    uint32_t u = v->size == 1 ? q[0] : v->size == 2 ? (uint32_t)(q[0] | q[1] << 8)
                 : (uint32_t)q[0] | (uint32_t)q[1] << 8 | (uint32_t)q[2] << 16 | (uint32_t)q[3] << 24;
    float f;
    switch (v->comp) {
    case C_F32: memcpy(&f, &u, 4); return f;
    case C_I8: return v->normalized ? fmax((int8_t)u / 127.0, -1) : (int8_t)u;
    case C_U8: return v->normalized ? u / 255.0 : u;
    case C_I16: return v->normalized ? fmax((int16_t)u / 32767.0, -1) : (int16_t)u;
    case C_U16: return v->normalized ? u / 65535.0 : u;
    default: return u; /* u32: indices only */
    }
}

/* The positions of v, transformed by the column-major m, appended to b. */
static int add_positions(gltf *g, const view *v, const double m[16])
{
    int rc = mesh_build_reserve_vertices(g->b, v->count, MESH_BUILD_NOWHERE);
    for (uint64_t i = 0; !rc && i < v->count; i++) {
        double p[3] = {component(v, i, 0), component(v, i, 1), component(v, i, 2)};
        float q[3];
        for (int r = 0; r < 3; r++)
            q[r] = (float)(m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r]);
        rc = mesh_build_vertex(g->b, q, MESH_BUILD_NOWHERE);
    }
    return rc;
}

/* Vertex j of the primitive: indices[j], or j without indices. */
static uint64_t corner(const view *ix, int indexed, uint64_t j)
{
    return indexed ? (uint64_t)component(ix, j, 0) : j;
}

/* A triangle primitive as read: its indices (ix, when indexed), its mode
 * (4, 5 or 6), its positions (nv of them, the first at vertex base of the
 * mesh), whether the node's transform mirrors it (flip: each triangle's
 * winding reversed) and its name in a message. */
typedef struct {
    const view *ix;
    int indexed;
    uint64_t mode;
    uint32_t base;
    uint64_t nv;
    int flip;
    const char *what;
} prim;

/* The triangles of primitive p over its corners (its indices, or its
 * positions in order). */
static int add_triangles(gltf *g, const prim *p)
{
    const view *ix = p->ix;
    int indexed = p->indexed, flip = p->flip;
    uint64_t mode = p->mode, nv = p->nv, n = indexed ? ix->count : nv;
    uint32_t base = p->base;
    const char *what = p->what;
    if (mode == 4 && n % 3)
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: %llu corners, not a multiple of 3", what,
                       (unsigned long long)n);
    uint64_t nt = mode == 4 ? n / 3 : n >= 3 ? n - 2 : 0;
    int rc = mesh_build_reserve_triangles(g->b, nt, MESH_BUILD_NOWHERE);
    for (uint64_t t = 0; !rc && t < nt; t++) {
        uint64_t c[3];
        if (mode == 4) c[0] = 3 * t, c[1] = 3 * t + 1, c[2] = 3 * t + 2;
        else if (mode == 5) c[0] = t, c[1] = t + 1 + t % 2, c[2] = t + 2 - t % 2;
        else c[0] = t + 1, c[1] = t + 2, c[2] = 0;
        uint64_t v[3];
        for (int k = 0; k < 3; k++)
            if ((v[k] = corner(ix, indexed, c[k])) >= nv)
                return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE,
                               "%s: index %llu out of range (%llu positions)", what,
                               (unsigned long long)v[k], (unsigned long long)nv);
        rc = flip ? mesh_build_triangle(g->b, base + (uint32_t)v[0], base + (uint32_t)v[2],
                                base + (uint32_t)v[1], MESH_BUILD_NOWHERE)
                  : mesh_build_triangle(g->b, base + (uint32_t)v[0], base + (uint32_t)v[1],
                                base + (uint32_t)v[2], MESH_BUILD_NOWHERE);
    }
    return rc;
}

static int primitive(gltf *g, json_object *p, const double m[16], int flip, const char *what)
{
    json_object *attr, *pos;
    uint64_t mode, a;
    int rc = mesh_gltf_uint(g, (gltf_obj){p, what}, "mode", 4, 6, &mode);
    if (rc) return rc;
    if (mode < 4 || !json_object_object_get_ex(p, "attributes", &attr) ||
        !json_object_object_get_ex(attr, "POSITION", &pos)) {
        g->skipped++; /* points and lines; or nothing to draw */
        return 0;
    }
    view v, ix = {0};
    if ((rc = mesh_gltf_uint(g, (gltf_obj){attr, what}, "POSITION", -1, UINT32_MAX, &a)) ||
        (rc = accessor(g, a, 1, &v)))
        return rc;
    int indexed = json_object_object_get_ex(p, "indices", &pos);
    if (indexed && ((rc = mesh_gltf_uint(g, (gltf_obj){p, what}, "indices", -1, UINT32_MAX, &a)) ||
                    (rc = accessor(g, a, 0, &ix))))
        return rc;
    uint32_t base = g->b->nv;
    if ((rc = add_positions(g, &v, m))) return rc;
    prim pr = {&ix, indexed, mode, base, v.count, flip, what};
    return add_triangles(g, &pr);
}

static int mesh_of(gltf *g, uint64_t mi, const double m[16])
{
    json_object *o, *prims;
    char what[64];
    int rc = mesh_gltf_item(g, "meshes", mi, &o);
    if (!rc) rc = mesh_gltf_array(g, (gltf_obj){o, "a mesh"}, "primitives", 1, &prims);
    double det = m[0] * (m[5] * m[10] - m[9] * m[6]) - m[4] * (m[1] * m[10] - m[9] * m[2]) +
                 m[8] * (m[1] * m[6] - m[5] * m[2]);
    for (size_t i = 0; !rc && i < json_object_array_length(prims); i++) {
        json_object *p = json_object_array_get_idx(prims, i);
        snprintf(what, sizeof what, "mesh %llu primitive %zu", (unsigned long long)mi, i);
        rc = json_object_is_type(p, json_type_object)
                 ? primitive(g, p, m, det < 0, what)
                 : mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s is not an object", what);
    }
    return rc;
}

/* ----------------------------------------------------------- the nodes */

static void mat_mul(const double a[16], const double b[16], double out[16])
{
    for (int c = 0; c < 4; c++)
        for (int r = 0; r < 4; r++) {
            double s = 0;
            for (int k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
            out[c * 4 + r] = s;
        }
}

/* Node o's local transform: its matrix, or T * R * S. */
static int local(gltf *g, json_object *o, const char *what, double m[16])
{
    double t[3] = {0, 0, 0}, q[4] = {0, 0, 0, 1}, s[3] = {1, 1, 1};
    int has_m, has_t, has_r, has_s;
    gltf_obj at = {o, what};
    int rc = mesh_gltf_numbers(g, at, "matrix", 16, m, &has_m);
    if (!rc) rc = mesh_gltf_numbers(g, at, "translation", 3, t, &has_t);
    if (!rc) rc = mesh_gltf_numbers(g, at, "rotation", 4, q, &has_r);
    if (!rc) rc = mesh_gltf_numbers(g, at, "scale", 3, s, &has_s);
    if (rc || has_m) {
        if (!rc && (has_t || has_r || has_s))
            return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s has both a matrix and TRS", what);
        return rc;
    }
    double n = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (!(n > 0)) return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: a zero rotation", what);
    double x = q[0] / n, y = q[1] / n, z = q[2] / n, w = q[3] / n;
    double r[9] = {1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w),
                   2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w),
                   2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)};
    for (int c = 0; c < 3; c++) {
        for (int k = 0; k < 3; k++) m[c * 4 + k] = r[c * 3 + k] * s[c];
        m[c * 4 + 3] = 0;
    }
    m[12] = t[0], m[13] = t[1], m[14] = t[2], m[15] = 1;
    return 0;
}

/* Depth first from the roots, with a stack of (node, parent's transform);
 * a node reached twice (a cycle, or two parents) is refused. */
typedef struct {
    uint64_t node;
    double m[16];
} frame;

/* The walk: the stack (stack[0, top), room for n_nodes frames) and the
 * nodes seen (n_nodes flags). */
typedef struct {
    frame *stack;
    size_t top;
    uint8_t *seen;
    size_t n_nodes;
} walk;

/* Node `node` under its parent's transform: its mesh read, its children
 * pushed on w's stack. */
static int visit(gltf *g, walk *w, uint64_t node, const double parent[16])
{
    frame *stack = w->stack;
    size_t *top = &w->top, n_nodes = w->n_nodes;
    uint8_t *seen = w->seen;
    json_object *o, *kids, *x;
    char what[48];
    snprintf(what, sizeof what, "node %llu", (unsigned long long)node);
    int rc = mesh_gltf_item(g, "nodes", node, &o);
    if (rc) return rc;
    if (seen[node]++)
        return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s is reached twice (a cycle, or two parents)",
                       what);
    double l[16], m[16];
    if ((rc = local(g, o, what, l))) return rc;
    mat_mul(parent, l, m);
    uint64_t mi;
    if (json_object_object_get_ex(o, "mesh", &x) &&
        ((rc = mesh_gltf_uint(g, (gltf_obj){o, what}, "mesh", -1, UINT32_MAX, &mi)) || (rc = mesh_of(g, mi, m))))
        return rc;
    if ((rc = mesh_gltf_array(g, (gltf_obj){o, what}, "children", 0, &kids)) || !kids) return rc;
    /* pushed last first: popped, and so read, in the file's order */
    for (size_t i = json_object_array_length(kids); i-- > 0;) {
        json_object *k = json_object_array_get_idx(kids, i);
        int64_t c = json_object_is_type(k, json_type_int) ? json_object_get_int64(k) : -1;
        if (c < 0 || (uint64_t)c >= n_nodes)
            return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "%s: child %zu is not a node", what, i);
        if (*top == n_nodes) /* more pushes than nodes: one is reached twice */
            return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "node %lld is reached twice", (long long)c);
        stack[*top].node = (uint64_t)c;
        memcpy(stack[(*top)++].m, m, sizeof m);
    }
    return 0;
}

/* The roots: the scene's nodes, or (no scene) every node no node names as a
 * child.  roots[0, *n). */
static int roots_of(gltf *g, size_t n_nodes, uint64_t *roots, size_t *n)
{
    json_object *scenes, *sc, *list;
    uint64_t which;
    int rc = mesh_gltf_array(g, (gltf_obj){g->root, "the glTF"}, "scenes", 0, &scenes);
    if (!rc && scenes && json_object_array_length(scenes)) {
        if ((rc = mesh_gltf_uint(g, (gltf_obj){g->root, "the glTF"}, "scene", 0, UINT32_MAX, &which)) ||
            (rc = mesh_gltf_item(g, "scenes", which, &sc)) ||
            (rc = mesh_gltf_array(g, (gltf_obj){sc, "the scene"}, "nodes", 0, &list)))
            return rc;
        *n = 0;
        for (size_t i = 0; list && i < json_object_array_length(list); i++) {
            json_object *k = json_object_array_get_idx(list, i);
            int64_t c = json_object_is_type(k, json_type_int) ? json_object_get_int64(k) : -1;
            if (c < 0 || (uint64_t)c >= n_nodes || *n == n_nodes)
                return mesh_build_fail(g->b, -EINVAL, MESH_BUILD_NOWHERE, "scene %llu: node %zu is not a node "
                               "(or named twice)", (unsigned long long)which, i);
            roots[(*n)++] = (uint64_t)c;
        }
        return 0;
    }
    uint8_t *child = calloc(n_nodes + 1, 1);
    if (!child) return mesh_build_fail(g->b, -ENOMEM, MESH_BUILD_NOWHERE, "out of memory for %zu nodes", n_nodes);
    for (size_t i = 0; !rc && i < n_nodes; i++) {
        json_object *o = json_object_array_get_idx(json_object_object_get(g->root, "nodes"), i), *kids;
        if (!json_object_is_type(o, json_type_object) || mesh_gltf_array(g, (gltf_obj){o, "a node"}, "children", 0, &kids) ||
            !kids)
            continue;
        for (size_t j = 0; j < json_object_array_length(kids); j++) {
            int64_t c = json_object_get_int64(json_object_array_get_idx(kids, j));
            if (c >= 0 && (uint64_t)c < n_nodes) child[c] = 1;
        }
    }
    *n = 0;
    for (size_t i = 0; i < n_nodes; i++)
        if (!child[i]) roots[(*n)++] = i;
    free(child);
    return 0;
}

int mesh_gltf_read_scene(gltf *g)
{
    json_object *nodes;
    int rc = mesh_gltf_array(g, (gltf_obj){g->root, "the glTF"}, "nodes", 0, &nodes);
    size_t n = nodes ? json_object_array_length(nodes) : 0, n_roots = 0;
    frame *stack = malloc((n + 1) * sizeof *stack);
    uint64_t *roots = malloc((n + 1) * sizeof *roots);
    uint8_t *seen = calloc(n + 1, 1);
    if (!rc && (!stack || !roots || !seen))
        rc = mesh_build_fail(g->b, -ENOMEM, MESH_BUILD_NOWHERE, "out of memory for %zu nodes", n);
    if (!rc) rc = roots_of(g, n, roots, &n_roots);
    static const double id[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    walk w = {stack, 0, seen, n};
    for (size_t r = 0; !rc && r < n_roots; r++) {
        w.top = 0;
        rc = visit(g, &w, roots[r], id);
        while (!rc && w.top) {
            frame f = stack[--w.top];
            rc = visit(g, &w, f.node, f.m);
        }
    }
    free(stack);
    free(roots);
    free(seen);
    return rc;
}

int mesh_parse_gltf(const char *buf, size_t len, mbuild *b)
{
    gltf g = {.b = b};
    b->binary = 1; /* errors name byte offsets (of the JSON's syntax) or none */
    int rc = mesh_gltf_open(&g, buf, len);
    if (!rc) rc = mesh_gltf_read_scene(&g);
    if (!rc && g.skipped)
        mesh_build_warn(b, MESH_BUILD_NOWHERE, "glTF: %llu primitives that are not triangles (points, lines) "
                "skipped", (unsigned long long)g.skipped);
    mesh_gltf_close(&g);
    return rc;
}
