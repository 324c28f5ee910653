/* mesh_obj — Wavefront OBJ: `v x y z [w]` vertices and `f` polygons, fan
 * triangulated; a face's vertex is `i`, `i/t`, `i/t/n` or `i//n`, with i
 * counted from 1 or, negative, back from the last vertex so far.  Other
 * statements (vt, vn, g, o, s, usemtl, l, p, ...) are skipped, and so are
 * the texture and normal indices.  A backslash at the end of a line joins
 * the next one. */
#include <errno.h>
#include <stdint.h>
#include <string.h>

#include "mesh_load.h"

/* Blanks, and line continuations ("\\\n"). */
static void skip_blank(mtext *t)
{
    for (;;) {
        mesh_text_skip_blank(t);
        const char *q = t->p;
        if (q < t->end && *q == '\\') {
            q++;
            while (q < t->end && *q == '\r') q++;
            if (q < t->end && *q == '\n') {
                t->p = q + 1;
                                continue;
            }
        }
        return;
    }
}

/* Past the end of the statement, continuation lines included. */
static void next_statement(mtext *t)
{
    for (;;) {
        const char *nl = memchr(t->p, '\n', (size_t)(t->end - t->p));
        if (!nl) {
            t->p = t->end;
            return;
        }
        const char *q = nl;
        while (q > t->p && q[-1] == '\r') q--;
        int joined = q > t->p && q[-1] == '\\';
        t->p = nl + 1;
                if (!joined) return;
    }
}

static int parse_v(mtext *t, mbuild *b)
{
    float p[3];
    for (int k = 0; k < 3; k++) {
        skip_blank(t);
        char tok[32];
        int rc = mesh_text_float(t, &p[k]);
        if (rc == -ERANGE)
            return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "vertex %u: %s is not a finite number", b->nv + 1,
                           mesh_text_tokstr(t, tok));
        if (rc)
            return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "vertex %u: coordinate %c: %s is not a number",
                           b->nv + 1, "xyz"[k], mesh_text_tokstr(t, tok));
    }
    return mesh_build_vertex(b, p, mesh_text_at(t));
}

/* One face vertex "i[/[t][/n]]": the 0-based vertex index. */
static int face_vertex(mtext *t, mbuild *b, uint32_t *out)
{
    char tok[32];
    const char *at = t->p;
    int64_t i, ignored;
    if (mesh_text_int(t, &i))
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "face: %s is not a vertex index", mesh_text_tokstr(t, tok));
    if (i == 0 || i > (int64_t)b->nv || i < -(int64_t)b->nv) {
        t->p = at;
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t),
                       "face: vertex index %lld out of range (%u vertices so far)", (long long)i,
                       b->nv);
    }
    *out = i > 0 ? (uint32_t)(i - 1) : (uint32_t)((int64_t)b->nv + i);
    for (int k = 0; k < 2 && t->p < t->end && *t->p == '/'; k++) {
        t->p++;
        if (t->p < t->end && (*t->p == '/' || mesh_text_space(*t->p))) continue; /* "i//n", "i/" */
        if (mesh_text_int(t, &ignored)) break;
    }
    if (t->p < t->end && !mesh_text_space(*t->p)) {
        t->p = at;
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "face: %s is not a vertex (i, i/t, i/t/n or i//n)",
                       mesh_text_tokstr(t, tok));
    }
    return 0;
}

static int parse_f(mtext *t, mbuild *b)
{
    uint32_t first = 0, prev = 0, n = 0;
    for (;; n++) {
        skip_blank(t);
        if (mesh_text_eol(t) || *t->p == '#') break; /* a comment ends the statement */
        uint32_t v = 0;
        int rc = face_vertex(t, b, &v);
        if (rc) return rc;
        if (n >= 2 && (rc = mesh_build_triangle(b, first, prev, v, mesh_text_at(t)))) return rc;
        if (n == 0) first = v;
        prev = v;
    }
    if (n < 3) return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "face with %u vertices (at least 3)", n);
    return 0;
}

int mesh_parse_obj(const char *buf, size_t len, mbuild *b)
{
    if (mesh_obj_par(buf, len, b)) return 0;
    mtext t = {buf, buf + len, buf};
    while (t.p < t.end) {
        skip_blank(&t);
        int rc = 0;
        if (mesh_text_word(&t, "v", 0)) rc = parse_v(&t, b);
        else if (mesh_text_word(&t, "f", 0)) rc = parse_f(&t, b);
        if (rc) return rc;
        next_statement(&t); /* the rest: a vertex's w or colour, or a skipped statement */
    }
    return 0;
}
