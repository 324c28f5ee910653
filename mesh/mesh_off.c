/* mesh_off — OFF (Object File Format, as Geomview writes it).  A keyword
 * line ("OFF", or with the prefixes ST, C, N of per-vertex texture
 * coordinates, colours and normals: STCNOFF and the like), the counts
 * "nv nf [ne]" on the same line or the next, nv vertex lines (x y z, then
 * whatever the prefixes add, skipped), nf face lines (k i0 .. ik-1, then an
 * optional colour, skipped), indices from 0.  '#' starts a comment line;
 * blank lines are skipped.  One record a line; binary OFF is not read. */
#include <errno.h>
#include <stdint.h>
#include <string.h>

#include "mesh_load.h"

int mesh_off_keyword(const char *p, size_t n)
{
    if (n < 3 || memcmp(p + n - 3, "OFF", 3)) return 0;
    size_t i = 0;
    if (n - 3 >= 2 && !memcmp(p, "ST", 2)) i += 2;
    if (i < n - 3 && p[i] == 'C') i++;
    if (i < n - 3 && p[i] == 'N') i++;
    return i == n - 3;
}

/* To the next record: past blank lines and comment lines. */
static void next_record(mtext *t)
{
    for (;;) {
        mesh_text_skip_space(t);
        if (t->p < t->end && *t->p == '#') mesh_text_next_line(t);
        else return;
    }
}

/* The rest of a line is blank or a comment. */
static int line_done(mtext *t)
{
    mesh_text_skip_blank(t);
    return mesh_text_eol(t) || *t->p == '#';
}

static int parse_counts(mtext *t, mbuild *b, uint64_t *nv, uint64_t *nf)
{
    char tok[32];
    if (line_done(t)) next_record(t); /* the counts on a line of their own */
    uint64_t ne;
    if (mesh_text_uint_token(t, UINT64_MAX, nv) || (mesh_text_skip_blank(t), mesh_text_uint_token(t, UINT64_MAX, nf)))
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "expected the counts 'vertices faces [edges]', found %s",
                       mesh_text_tokstr(t, tok));
    mesh_text_skip_blank(t);
    if (!line_done(t) && mesh_text_uint_token(t, UINT64_MAX, &ne))
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "the edge count %s is not a whole number",
                       mesh_text_tokstr(t, tok));
    if (!line_done(t)) return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "unexpected %s after the counts",
                                      mesh_text_tokstr(t, tok));
    /* The least bytes: "0 0 0\n" a vertex, "3 0 1 2\n" a face (the last
     * line end may be missing). */
    uint64_t room = (uint64_t)(t->end - t->p) + 1;
    if (*nv > room / 6 || *nf > (room - *nv * 6) / 8)
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t),
                       "%llu vertices and %llu faces cannot fit in the %llu bytes left",
                       (unsigned long long)*nv, (unsigned long long)*nf,
                       (unsigned long long)(room - 1));
    int rc = mesh_build_reserve_vertices(b, *nv, mesh_text_at(t));
    return rc ? rc : mesh_build_reserve_triangles(b, *nf, mesh_text_at(t));
}

static int parse_vertex(mtext *t, mbuild *b, uint64_t i)
{
    float p[3];
    char tok[32];
    next_record(t);
    uint64_t at = mesh_text_at(t);
    for (int k = 0; k < 3; k++) {
        mesh_text_skip_blank(t);
        int rc = mesh_text_float(t, &p[k]);
        if (rc)
            return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "vertex %llu: %s%s", (unsigned long long)i,
                           rc == -ERANGE ? "not a finite number: " : "a coordinate expected, found ",
                           mesh_text_tokstr(t, tok));
    }
    mesh_text_next_line(t); /* colour, normal, texture coordinates */
    return mesh_build_vertex(b, p, at);
}

static int parse_face(mtext *t, mbuild *b, uint64_t i, uint64_t nv)
{
    char tok[32];
    next_record(t);
    uint64_t k;
    uint64_t at = mesh_text_at(t);
    if (mesh_text_uint_token(t, UINT32_MAX, &k))
        return mesh_build_fail(b, -EINVAL, at, "face %llu: a vertex count expected, found %s",
                       (unsigned long long)i, mesh_text_tokstr(t, tok));
    if (k < 3)
        return mesh_build_fail(b, -EINVAL, at, "face %llu has %llu vertices (at least 3)",
                       (unsigned long long)i, (unsigned long long)k);
    uint32_t first = 0, prev = 0;
    for (uint64_t j = 0; j < k; j++) {
        mesh_text_skip_blank(t);
        uint64_t v;
        int rc = mesh_text_uint_token(t, UINT64_MAX, &v);
        if (rc) return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "face %llu: a vertex index expected, found %s",
                               (unsigned long long)i, mesh_text_tokstr(t, tok));
        if (v >= nv)
            return mesh_build_fail(b, -EINVAL, mesh_text_at(t),
                           "face %llu: vertex index %llu out of range (%llu vertices)",
                           (unsigned long long)i, (unsigned long long)v, (unsigned long long)nv);
        if (j >= 2 && (rc = mesh_build_triangle(b, first, prev, (uint32_t)v, mesh_text_at(t)))) return rc;
        if (j == 0) first = (uint32_t)v;
        prev = (uint32_t)v;
    }
    mesh_text_next_line(t); /* an optional colour */
    return 0;
}

int mesh_parse_off(const char *buf, size_t len, mbuild *b)
{
    mtext t = {buf, buf + len, buf};
    char tok[32];
    next_record(&t);
    size_t n = mesh_text_toklen(&t);
    if (!mesh_off_keyword(t.p, n))
        return mesh_build_fail(b, -EINVAL, mesh_text_at(&t), "not an OFF file: %s", mesh_text_tokstr(&t, tok));
    t.p += n;
    mesh_text_skip_blank(&t);
    if (mesh_text_word(&t, "BINARY", 0)) return mesh_build_fail(b, -EINVAL, mesh_text_at(&t), "binary OFF is not supported");
    uint64_t nv, nf;
    int rc = parse_counts(&t, b, &nv, &nf);
    mesh_text_next_line(&t);
    if (!rc && mesh_off_par(t.p, t.end, nv, nf, b)) return 0;
    for (uint64_t i = 0; !rc && i < nv; i++) rc = parse_vertex(&t, b, i);
    for (uint64_t i = 0; !rc && i < nf; i++) rc = parse_face(&t, b, i, nv);
    if (rc) return rc;
    next_record(&t);
    if (t.p != t.end)
        return mesh_build_fail(b, -EINVAL, mesh_text_at(&t), "%s after the last face", mesh_text_tokstr(&t, tok));
    return 0;
}
