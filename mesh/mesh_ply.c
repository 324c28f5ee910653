/* mesh_ply — PLY (Turk's polygon file format), ascii and binary little and
 * big endian.  The header declares elements (a name and a count) and their
 * properties (a numeric type, or a list: a count type and an item type).
 * The mesh is the element "vertex" (scalar properties x, y, z of any
 * numeric type, rounded to float) and the element "face" (an integer list
 * "vertex_indices" or "vertex_index", fan triangulated).  Every other
 * element and property is skipped by its declared type.
 *
 * Before anything is allocated, every element's count is checked against
 * the least number of bytes its items could take (binary: the sizes of
 * its scalars and list counts, a face at least three indices; ascii: two
 * bytes a token), and the vertex and face counts against the limits. */
#include <errno.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_load.h"
#include "par.h"

enum { T_CHAR, T_UCHAR, T_SHORT, T_USHORT, T_INT, T_UINT, T_FLOAT, T_DOUBLE, T_NONE };

static const struct {
    const char *name, *alias;
    unsigned size;
} types[] = {
    [T_CHAR] = {"char", "int8", 1},      [T_UCHAR] = {"uchar", "uint8", 1},
    [T_SHORT] = {"short", "int16", 2},   [T_USHORT] = {"ushort", "uint16", 2},
    [T_INT] = {"int", "int32", 4},       [T_UINT] = {"uint", "uint32", 4},
    [T_FLOAT] = {"float", "float32", 4}, [T_DOUBLE] = {"double", "float64", 8},
};
/* The largest value of an integer type (a list count's bound). */
static const uint64_t type_max[] = {127, 255, 32767, 65535, INT32_MAX, UINT32_MAX, 0, 0};

enum { R_NONE, R_X, R_Y, R_Z, R_INDICES };
enum { E_OTHER, E_VERTEX, E_FACE };
#define MAX_ELEMS 32
#define MAX_PROPS 64

typedef struct {
    uint8_t type, count_type, list, role;
} ply_prop;

typedef struct {
    const char *name;
    size_t name_len;
    uint64_t count, at; /* at: where it is declared */
    int kind;
    uint32_t nprops;
    ply_prop props[MAX_PROPS];
} ply_elem;

typedef struct {
    mbuild *b;
    int ascii, be;
    uint32_t nelems;
    ply_elem elems[MAX_ELEMS];
    uint64_t n_vertices; /* declared: what face indices are checked against */
    const char *data;    /* first byte after end_header */
    uint64_t unknown;    /* header lines with no keyword of the format, skipped */
} ply;

/* ------------------------------------------------------------------ header */

static int type_of(mtext *t)
{
    size_t n = mesh_text_toklen(t);
    for (int i = 0; i < T_NONE; i++)
        if ((strlen(types[i].name) == n && !memcmp(t->p, types[i].name, n)) ||
            (strlen(types[i].alias) == n && !memcmp(t->p, types[i].alias, n))) {
            t->p += n;
            return i;
        }
    return T_NONE;
}

static int is_name(const mtext *t, size_t n, const char *w)
{
    return strlen(w) == n && !memcmp(t->p, w, n);
}

static int header_property(ply *y, mtext *t)
{
    mbuild *b = y->b;
    char tok[32];
    if (!y->nelems) return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "a property before any element");
    ply_elem *e = &y->elems[y->nelems - 1];
    if (e->nprops == MAX_PROPS)
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "more than %d properties in an element", MAX_PROPS);
    ply_prop *p = &e->props[e->nprops];
    *p = (ply_prop){.count_type = T_NONE};
    mesh_text_skip_blank(t);
    if (mesh_text_word(t, "list", 0)) {
        p->list = 1;
        mesh_text_skip_blank(t);
        if ((p->count_type = (uint8_t)type_of(t)) == T_NONE)
            return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "unknown list count type %s", mesh_text_tokstr(t, tok));
        if (p->count_type >= T_FLOAT)
            return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "a list count of type %s (an integer type needed)",
                           types[p->count_type].name);
    }
    mesh_text_skip_blank(t);
    if ((p->type = (uint8_t)type_of(t)) == T_NONE)
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "unknown property type %s", mesh_text_tokstr(t, tok));
    mesh_text_skip_blank(t);
    size_t n = mesh_text_toklen(t);
    if (!n) return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "a property without a name");
    if (e->kind == E_VERTEX && !p->list)
        p->role = is_name(t, n, "x") ? R_X : is_name(t, n, "y") ? R_Y : is_name(t, n, "z") ? R_Z : 0;
    if (e->kind == E_FACE && p->list &&
        (is_name(t, n, "vertex_indices") || is_name(t, n, "vertex_index"))) {
        if (p->type >= T_FLOAT)
            return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "vertex indices of type %s (an integer type needed)",
                           types[p->type].name);
        p->role = R_INDICES;
    }
    for (uint32_t i = 0; p->role && i < e->nprops; i++)
        if (e->props[i].role == p->role)
            return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "property %.*s declared twice", (int)n, t->p);
    e->nprops++;
    t->p += n;
    return 0;
}

static int header_element(ply *y, mtext *t)
{
    mbuild *b = y->b;
    char tok[32];
    if (y->nelems == MAX_ELEMS)
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "more than %d elements", MAX_ELEMS);
    ply_elem *e = &y->elems[y->nelems];
    memset(e, 0, sizeof *e);
    mesh_text_skip_blank(t);
    e->name = t->p;
    e->name_len = mesh_text_toklen(t);
    e->at = mesh_text_at(t);
    if (!e->name_len) return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "an element without a name");
    e->kind = is_name(t, e->name_len, "vertex") ? E_VERTEX : is_name(t, e->name_len, "face") ? E_FACE : E_OTHER;
    for (uint32_t i = 0; e->kind != E_OTHER && i < y->nelems; i++)
        if (y->elems[i].kind == e->kind)
            return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "element %.*s declared twice", (int)e->name_len,
                           e->name);
    t->p += e->name_len;
    mesh_text_skip_blank(t);
    int rc = mesh_text_uint_token(t, UINT64_MAX, &e->count);
    if (rc)
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "element %.*s: the count %s is not a whole number",
                       (int)e->name_len, e->name, mesh_text_tokstr(t, tok));
    y->nelems++;
    return 0;
}

static int header_format(ply *y, mtext *t)
{
    mesh_text_skip_blank(t);
    if (mesh_text_word(t, "ascii", 0)) y->ascii = 1;
    else if (mesh_text_word(t, "binary_little_endian", 0)) y->be = 0;
    else if (mesh_text_word(t, "binary_big_endian", 0)) y->be = 1;
    else {
        char tok[32];
        return mesh_build_fail(y->b, -EINVAL, mesh_text_at(t), "unknown format %s", mesh_text_tokstr(t, tok));
    }
    mesh_text_skip_blank(t);
    if (!mesh_text_word(t, "1.0", 0)) {
        char tok[32];
        return mesh_build_fail(y->b, -EINVAL, mesh_text_at(t), "format version %s (1.0 is known)",
                       mesh_text_tokstr(t, tok));
    }
    return 0;
}

/* A header line that starts with no keyword of the format: skipped with a
 * warning, as common readers do (Blender 2.47 wrote its "Created by
 * Blender3D ..." line without "comment").  It cannot hide an error: the
 * elements, properties and the format are only what their own lines say. */
static void unknown_line(ply *y, mtext *t)
{
    char tok[32];
    if (!y->unknown++)
        mesh_build_warn(y->b, mesh_text_at(t), "PLY header: unknown line starting %s skipped", mesh_text_tokstr(t, tok));
    mesh_text_next_line(t);
}

#define NO_FORMAT(b, t) mesh_build_fail(b, -EINVAL, mesh_text_at(t), "no format line after 'ply'")

static int parse_header(ply *y, mtext *t)
{
    mbuild *b = y->b;
    int have_format = 0, rc = 0;
    mesh_text_next_line(t); /* "ply", checked by the caller */
    for (;;) {
        if (t->p == t->end) return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "no end_header");
        mesh_text_skip_blank(t);
        if (mesh_text_word(t, "end_header", 0)) break;
        if (mesh_text_word(t, "format", 0)) {
            if (have_format++) return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "a second format line");
            rc = header_format(y, t);
        } else if (mesh_text_word(t, "element", 0)) {
            rc = have_format ? header_element(y, t) : NO_FORMAT(b, t);
        } else if (mesh_text_word(t, "property", 0)) {
            rc = have_format ? header_property(y, t) : NO_FORMAT(b, t);
        } else if (mesh_text_word(t, "comment", 0) || mesh_text_word(t, "obj_info", 0) || mesh_text_eol(t)) {
            mesh_text_next_line(t);
            continue;
        } else {
            unknown_line(y, t);
            continue;
        }
        if (rc) return rc;
        mesh_text_skip_blank(t);
        if (!mesh_text_eol(t)) {
            char tok[32];
            return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "unexpected %s", mesh_text_tokstr(t, tok));
        }
        mesh_text_next_line(t);
    }
    if (!have_format) return NO_FORMAT(b, t);
    if (y->unknown > 1) {
        size_t n = strlen(b->warning);
        snprintf(b->warning + n, sizeof b->warning - n, " (and %llu more unknown header lines)",
                 (unsigned long long)(y->unknown - 1));
    }
    /* end_header, then exactly one line end: the binary data begins after it. */
    mesh_text_skip_blank(t);
    if (t->p == t->end || *t->p != '\n')
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "end_header not followed by a line end");
    t->p++;
    y->data = t->p;
    return 0;
}

/* The roles the mesh needs, and the least bytes of each element's data. */
static int check_elements(ply *y, size_t avail)
{
    mbuild *b = y->b;
    int have[R_INDICES + 1] = {0};
    const ply_elem *vert = NULL, *face = NULL;
    /* ascii: n tokens take at least 2n - 1 bytes */
    uint64_t room = y->ascii ? (uint64_t)avail + 1 : avail;
    for (uint32_t i = 0; i < y->nelems; i++) {
        const ply_elem *e = &y->elems[i];
        if (e->kind == E_VERTEX) vert = e;
        if (e->kind == E_FACE) face = e;
        if (!e->nprops && e->count)
            return mesh_build_fail(b, -EINVAL, e->at, "element %.*s has no properties", (int)e->name_len,
                           e->name);
        uint64_t least = 0;
        for (uint32_t k = 0; k < e->nprops; k++) {
            const ply_prop *p = &e->props[k];
            have[p->role] = 1;
            uint64_t n = p->role == R_INDICES ? 3 : 0; /* a face: three indices at least */
            if (y->ascii) least += 2 * (1 + n);
            else least += p->list ? types[p->count_type].size + n * types[p->type].size
                                  : types[p->type].size;
        }
        if (least && e->count > room / least)
            return mesh_build_fail(b, -EINVAL, e->at,
                           "element %.*s: %llu of them need at least %llu bytes; %llu are left",
                           (int)e->name_len, e->name, (unsigned long long)e->count,
                           (unsigned long long)(e->count > UINT64_MAX / least ? UINT64_MAX
                                                                              : e->count * least),
                           (unsigned long long)room);
        room -= e->count * least;
    }
    if (!vert) return mesh_build_fail(b, -EINVAL, MESH_BUILD_NOWHERE, "no vertex element");
    if (!have[R_X] || !have[R_Y] || !have[R_Z])
        return mesh_build_fail(b, -EINVAL, vert->at, "the vertex element lacks x, y or z");
    if (!face) return mesh_build_fail(b, -EINVAL, MESH_BUILD_NOWHERE, "no face element");
    if (!have[R_INDICES])
        return mesh_build_fail(b, -EINVAL, face->at, "the face element has no vertex_indices list");
    y->n_vertices = vert->count;
    int rc = mesh_build_reserve_vertices(b, vert->count, vert->at);
    /* at least one triangle a face */
    return rc ? rc : mesh_build_reserve_triangles(b, face->count, face->at);
}

/* A face's fan, ASCII or binary: its first and latest vertex; from its
 * third on, a triangle each (first, latest, this one). */
typedef struct {
    uint32_t first, prev;
} fan;

/* Vertex index v, the j-th of face item's list, read at at (a byte). */
static int fan_add(ply *y, fan *f, uint64_t item, uint64_t j, int64_t v, uint64_t at)
{
    if (v < 0 || (uint64_t)v >= y->n_vertices)
        return mesh_build_fail(y->b, -EINVAL, at,
                       "face %llu: vertex index %lld out of range (%llu vertices)",
                       (unsigned long long)item, (long long)v,
                       (unsigned long long)y->n_vertices);
    if (j >= 2) {
        int rc = mesh_build_triangle(y->b, f->first, f->prev, (uint32_t)v, at);
        if (rc) return rc;
    }
    if (j == 0) f->first = (uint32_t)v;
    f->prev = (uint32_t)v;
    return 0;
}

/* ------------------------------------------------------------------- ascii */

static int ascii_error(ply *y, mtext *t, const ply_elem *e, uint64_t item, const char *what)
{
    char tok[32];
    return mesh_build_fail(y->b, -EINVAL, mesh_text_at(t), "%.*s %llu: %s %s", (int)e->name_len, e->name,
                   (unsigned long long)item, what, mesh_text_tokstr(t, tok));
}

/* A face's index list: count, then the indices, fanned into triangles. */
static int ascii_indices(ply *y, mtext *t, const ply_elem *e, uint64_t item, uint64_t cnt)
{
    if (cnt < 3) return ascii_error(y, t, e, item, "has fewer than 3 vertices; at");
    fan f = {0, 0};
    for (uint64_t j = 0; j < cnt; j++) {
        mesh_text_skip_space(t);
        int64_t v;
        if (mesh_text_int(t, &v) || (t->p < t->end && !mesh_text_space(*t->p)))
            return ascii_error(y, t, e, item, "a vertex index expected, found");
        int rc = fan_add(y, &f, item, j, v, mesh_text_at(t));
        if (rc) return rc;
    }
    return 0;
}

static int ascii_item(ply *y, mtext *t, const ply_elem *e, uint64_t item)
{
    float pos[3] = {0, 0, 0};
    for (uint32_t k = 0; k < e->nprops; k++) {
        const ply_prop *p = &e->props[k];
        mesh_text_skip_space(t);
        if (p->list) {
            uint64_t cnt;
            if (mesh_text_uint_token(t, type_max[p->count_type], &cnt))
                return ascii_error(y, t, e, item, "a list count expected, found");
            if (p->role == R_INDICES) {
                int rc = ascii_indices(y, t, e, item, cnt);
                if (rc) return rc;
                continue;
            }
            for (uint64_t j = 0; j < cnt; j++) {
                mesh_text_skip_space(t);
                size_t n = mesh_text_toklen(t);
                if (!n) return ascii_error(y, t, e, item, "a list item expected, found");
                t->p += n;
            }
        } else if (p->role) {
            int rc = mesh_text_float(t, &pos[p->role - R_X]);
            if (rc)
                return ascii_error(y, t, e, item, rc == -ERANGE ? "not a finite number:"
                                                                : "a number expected, found");
        } else {
            size_t n = mesh_text_toklen(t);
            if (!n) return ascii_error(y, t, e, item, "a value expected, found");
            t->p += n;
        }
    }
    return e->kind == E_VERTEX ? mesh_build_vertex(y->b, pos, mesh_text_at(t)) : 0;
}

static int parse_ascii(ply *y, mtext *t)
{
    for (uint32_t i = 0; i < y->nelems; i++) {
        const ply_elem *e = &y->elems[i];
        for (uint64_t j = 0; j < e->count; j++) {
            int rc = ascii_item(y, t, e, j);
            if (rc) return rc;
        }
    }
    mesh_text_skip_space(t);
    if (t->p != t->end) {
        char tok[32];
        return mesh_build_fail(y->b, -EINVAL, mesh_text_at(t), "%s after the last element", mesh_text_tokstr(t, tok));
    }
    return 0;
}

/* ------------------------------------------------------ ascii on every CPU */

/* A large ASCII file is parsed by every CPU when its layout is the common
 * one: each item of every element on a line of its own, every face a
 * triangle, nothing but blanks after the last item.  The lines are counted
 * in parts first, so that each part knows the element and item of its
 * first line and writes its vertices and triangles straight into the
 * builder's arrays, sized by check_elements (no per-thread buffers, no
 * copy, no allocation on the threads).  Each line is read by the serial
 * parser's own token readers (mesh_text_float, mesh_text_int, mesh_text_uint_token), so what it
 * takes it reads to the same bits.  Anything else (an item over two lines,
 * a blank line, a polygon, any error) makes a part give up, and the whole
 * file is parsed again by parse_ascii: its mesh, or its error and line,
 * are then the serial parser's. */
#define PAR_MIN_BYTES (1u << 20) /* below this, one thread */
#define PAR_PARTS 256            /* parts, taken in turn by the threads */

_Atomic uint64_t mesh_ply_par_runs;

typedef struct {
    ply *y;
    const char *data, *end;
    uint64_t ebase[MAX_ELEMS + 1]; /* the index of each element's first line */
    uint64_t first[PAR_PARTS + 1]; /* each part's first line's index */
} par_ply;

/* Part k's first byte: the start of the line at or after its share of the
 * data (so part k - 1's last byte is found the same way). */
static const char *part_start(const par_ply *pp, uint32_t k)
{
    return mesh_text_part_start(pp->data, pp->end, k, PAR_PARTS);
}

/* One line [t->p, t->end) as item `item` of element e: 0, or -1 when the
 * fast path does not take it. */
static int line_item(ply *y, mtext *t, const ply_elem *e, uint64_t item)
{
    float pos[3] = {0, 0, 0};
    uint32_t tri[3];
    for (uint32_t k = 0; k < e->nprops; k++) {
        const ply_prop *p = &e->props[k];
        mesh_text_skip_blank(t);
        uint64_t cnt = 1;
        if (p->list && mesh_text_uint_token(t, type_max[p->count_type], &cnt)) return -1;
        if (p->role == R_INDICES) {
            if (cnt != 3) return -1;
            for (int j = 0; j < 3; j++) {
                int64_t v;
                mesh_text_skip_blank(t);
                if (mesh_text_int(t, &v) || (t->p < t->end && !mesh_text_blank(*t->p))) return -1;
                if (v < 0 || (uint64_t)v >= y->n_vertices) return -1;
                tri[j] = (uint32_t)v;
            }
        } else if (p->role) {
            if (mesh_text_float(t, &pos[p->role - R_X])) return -1;
        } else {
            for (uint64_t j = 0; j < cnt; j++) { /* skipped, as parse_ascii does */
                mesh_text_skip_blank(t);
                size_t n = mesh_text_toklen(t);
                if (!n) return -1;
                t->p += n;
            }
        }
    }
    mesh_text_skip_blank(t);
    if (t->p != t->end) return -1;
    if (e->kind == E_VERTEX) memcpy(y->b->v[item], pos, sizeof pos);
    if (e->kind == E_FACE) memcpy(y->b->t[item], tri, sizeof tri);
    return 0;
}

/* The lines of part i (mesh_text_each_part's fn); -1: give up. */
static int parse_part(void *ud, uint32_t i)
{
    par_ply *pp = ud;
    ply *y = pp->y;
    const char *p = part_start(pp, i), *stop = part_start(pp, i + 1);
    uint32_t ei = 0;
    for (uint64_t g = pp->first[i]; p < stop; g++) {
        mtext t = mesh_text_line(&p, stop, y->b->buf);
        while (ei < y->nelems && g >= pp->ebase[ei + 1]) ei++;
        if (ei == y->nelems) { /* past the last item: blanks only */
            mesh_text_skip_blank(&t);
            if (t.p != t.end) return -1;
        } else if (line_item(y, &t, &y->elems[ei], g - pp->ebase[ei])) {
            return -1;
        }
    }
    return 0;
}

/* 1 when the data was parsed on every CPU into y's builder, 0 when
 * parse_ascii must parse it (the builder left empty). */
static int parse_ascii_par(ply *y, const char *end)
{
    size_t len = (size_t)(end - y->data);
    if (len < PAR_MIN_BYTES || par_cpus() < 2) return 0;
    par_ply *pp = calloc(1, sizeof *pp); /* 2 KiB of part bounds: off the stack */
    if (!pp) return 0;
    pp->y = y, pp->data = y->data, pp->end = end;
    for (uint32_t i = 0; i < y->nelems; i++)
        pp->ebase[i + 1] = pp->ebase[i] + y->elems[i].count;
    uint64_t lines = mesh_text_first_lines(pp->data, end, PAR_PARTS, pp->first);
    int ok = lines >= pp->ebase[y->nelems] && !mesh_text_each_part(PAR_PARTS, parse_part, pp);
    free(pp);
    if (!ok) return 0;
    /* relaxed: a count for the tests, which read it after the parse */
    atomic_fetch_add_explicit(&mesh_ply_par_runs, 1, memory_order_relaxed);
    y->b->nv = (uint32_t)y->n_vertices;
    for (uint32_t i = 0; i < y->nelems; i++)
        if (y->elems[i].kind == E_FACE) y->b->nt = (uint32_t)y->elems[i].count;
    return 1;
}

/* ------------------------------------------------------------------ binary */

/* size bytes at p in the file's byte order (the fixed-size forms compile
 * to one load, with a byte swap where the orders differ). */
static inline uint64_t rd_bits(const unsigned char *p, unsigned size, int be)
{
    switch (size) {
    case 1: return p[0];
    case 2: return be ? (uint64_t)p[0] << 8 | p[1] : (uint64_t)p[1] << 8 | p[0];
    case 4:
        return be ? (uint64_t)p[0] << 24 | (uint64_t)p[1] << 16 | (uint64_t)p[2] << 8 | p[3]
                  : (uint64_t)p[3] << 24 | (uint64_t)p[2] << 16 | (uint64_t)p[1] << 8 | p[0];
    default: {
        uint64_t v = 0;
        for (unsigned i = 0; i < 8; i++) v |= (uint64_t)p[be ? 7 - i : i] << (8 * i);
        return v;
    }
    }
}

/* An integer type's value (signed ones sign-extended). */
static inline int64_t rd_int(const unsigned char *p, int type, int be)
{
    uint64_t v = rd_bits(p, types[type].size, be);
    switch (type) {
    case T_CHAR: return (int8_t)v;
    case T_SHORT: return (int16_t)v;
    case T_INT: return (int32_t)v;
    default: return (int64_t)v;
    }
}

static inline float rd_float(const unsigned char *p, int type, int be)
{
    if (type == T_FLOAT) {
        uint32_t u = (uint32_t)rd_bits(p, 4, be);
        float f;
        memcpy(&f, &u, 4);
        return f;
    }
    if (type == T_DOUBLE) {
        uint64_t u = rd_bits(p, 8, be);
        double d;
        memcpy(&d, &u, 8);
        return (float)d; /* to nearest; beyond FLT_MAX it is Inf, refused */
    }
    return (float)rd_int(p, type, be);
}

typedef struct {
    const unsigned char *base;
    size_t pos, len;
} bcur;

static int truncated(ply *y, const bcur *c, const ply_elem *e, uint64_t item)
{
    return mesh_build_fail(y->b, -EINVAL, c->pos, "truncated in %.*s %llu of %llu", (int)e->name_len,
                   e->name, (unsigned long long)item, (unsigned long long)e->count);
}

static int binary_list(ply *y, bcur *c, const ply_elem *e, const ply_prop *p, uint64_t item)
{
    unsigned cs = types[p->count_type].size, is = types[p->type].size;
    if (c->len - c->pos < cs) return truncated(y, c, e, item);
    int64_t cnt = rd_int(c->base + c->pos, p->count_type, y->be);
    if (cnt < 0)
        return mesh_build_fail(y->b, -EINVAL, c->pos, "%.*s %llu: a list of %lld items", (int)e->name_len,
                       e->name, (unsigned long long)item, (long long)cnt);
    size_t at = c->pos;
    c->pos += cs;
    if ((uint64_t)cnt > (c->len - c->pos) / is) return truncated(y, c, e, item);
    if (p->role != R_INDICES) {
        c->pos += (size_t)cnt * is;
        return 0;
    }
    if (cnt < 3)
        return mesh_build_fail(y->b, -EINVAL, at, "face %llu has %lld vertices (at least 3)",
                       (unsigned long long)item, (long long)cnt);
    fan f = {0, 0};
    for (int64_t j = 0; j < cnt; j++, c->pos += is) {
        int64_t v = rd_int(c->base + c->pos, p->type, y->be);
        int rc = fan_add(y, &f, item, (uint64_t)j, v, c->pos);
        if (rc) return rc;
    }
    return 0;
}

static int binary_item(ply *y, bcur *c, const ply_elem *e, uint64_t item)
{
    float pos[3] = {0, 0, 0};
    size_t start = c->pos;
    for (uint32_t k = 0; k < e->nprops; k++) {
        const ply_prop *p = &e->props[k];
        if (p->list) {
            int rc = binary_list(y, c, e, p, item);
            if (rc) return rc;
            continue;
        }
        unsigned sz = types[p->type].size;
        if (c->len - c->pos < sz) return truncated(y, c, e, item);
        if (p->role) pos[p->role - R_X] = rd_float(c->base + c->pos, p->type, y->be);
        c->pos += sz;
    }
    return e->kind == E_VERTEX ? mesh_build_vertex(y->b, pos, start) : 0;
}

static int parse_binary(ply *y, const char *buf, size_t len)
{
    y->b->binary = 1;
    bcur c = {(const unsigned char *)buf, (size_t)(y->data - buf), len};
    for (uint32_t i = 0; i < y->nelems; i++) {
        const ply_elem *e = &y->elems[i];
        for (uint64_t j = 0; j < e->count; j++) {
            int rc = binary_item(y, &c, e, j);
            if (rc) return rc;
        }
    }
    if (c.pos != len)
        return mesh_build_fail(y->b, -EINVAL, c.pos, "%zu bytes after the last element", len - c.pos);
    return 0;
}

int mesh_parse_ply(const char *buf, size_t len, mbuild *b)
{
    mtext t = {buf, buf + len, buf};
    if (!mesh_text_word(&t, "ply", 0)) return mesh_build_fail(b, -EINVAL, 0, "not a PLY file (no 'ply' line)");
    mesh_text_skip_blank(&t);
    if (!mesh_text_eol(&t)) return mesh_build_fail(b, -EINVAL, 0, "not a PLY file (no 'ply' line)");
    ply y = {.b = b}; /* about 10 KiB */
    int rc = parse_header(&y, &t);
    if (!rc) rc = check_elements(&y, len - (size_t)(y.data - buf));
    if (rc) return rc;
    if (!y.ascii) return parse_binary(&y, buf, len);
    return parse_ascii_par(&y, buf + len) ? 0 : parse_ascii(&y, &t);
}
