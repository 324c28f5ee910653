/* mesh_stl — STL, binary and ASCII.  Binary: an 80-byte header, a
 * little-endian uint32 count n, then n records of 50 bytes (normal, three
 * vertices as little-endian floats, a 16-bit attribute): a file of exactly
 * 84 + 50 n bytes.  That arithmetic tells the forms apart, not the word
 * "solid" (binary headers often begin with it).  ASCII: solid / facet
 * normal / outer loop / vertex x y z ... / endloop / endfacet / endsolid,
 * keywords in any case, several solids in a row allowed; a loop of more
 * than three vertices is fan triangulated.  The normals are not read: the
 * orientation is the vertices' order.
 *
 * STL repeats each position once per triangle; the positions are welded
 * into shared vertices (mesh_build_weld) so that the mesh's edges are real.
 * A large binary file is parsed and welded on every CPU instead
 * (mesh_stl_par.c), into the same mesh. */
#include <errno.h>
#include <stdint.h>
#include <string.h>

#include "bits.h"
#include "mesh_load.h"

static float lef32(const unsigned char *p)
{
    uint32_t u = bits_le32(p);
    float f;
    memcpy(&f, &u, 4);
    return f;
}

static int parse_binary(const unsigned char *u, size_t len, mbuild *b)
{
    b->binary = 1;
    if (len < 84)
        return mesh_build_fail(b, -EINVAL, MESH_BUILD_NOWHERE,
                       "neither ASCII STL (no 'solid') nor binary STL (%zu bytes, less than "
                       "the 84 of the header and count)", len);
    uint64_t n = bits_le32(u + 80);
    if (84 + 50 * n != len)
        return mesh_build_fail(b, -EINVAL, 80,
                       "binary STL of %llu triangles must be %llu bytes, the file has %zu "
                       "(and is not ASCII STL: no 'solid')",
                       (unsigned long long)n, (unsigned long long)(84 + 50 * n), len);
    int rc;
    if ((rc = mesh_build_reserve_triangles(b, n, 80)) || (rc = mesh_build_reserve_vertices(b, 3 * n, 80)))
        return rc;
    for (uint32_t i = 0; i < n; i++) {
        const unsigned char *r = u + 84 + 50 * (size_t)i + 12;
        for (int k = 0; k < 3; k++) {
            float p[3] = {lef32(r + 12 * k), lef32(r + 12 * k + 4), lef32(r + 12 * k + 8)};
            if ((rc = mesh_build_vertex(b, p, (uint64_t)(r + 12 * k - u)))) return rc;
        }
        if ((rc = mesh_build_triangle(b, 3 * i, 3 * i + 1, 3 * i + 2, (uint64_t)(r - 12 - u)))) return rc;
    }
    return 0;
}

/* The keyword w next (after blanks and newlines), or an error naming what is there. */
static int expect(mtext *t, mbuild *b, const char *w)
{
    mesh_text_skip_space(t);
    if (mesh_text_word(t, w, 1)) return 0;
    char tok[32];
    return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "expected '%s', found %s", w, mesh_text_tokstr(t, tok));
}

/* "outer loop", the vertices, "endloop": fan triangles of the raw vertices. */
static int parse_loop(mtext *t, mbuild *b)
{
    int rc;
    if ((rc = expect(t, b, "outer")) || (rc = expect(t, b, "loop"))) return rc;
    uint32_t first = b->nv, n = 0;
    char tok[32];
    for (;; n++) {
        mesh_text_skip_space(t);
        if (!mesh_text_word(t, "vertex", 1)) break;
        float p[3];
        for (int k = 0; k < 3; k++) {
            mesh_text_skip_blank(t);
            if ((rc = mesh_text_float(t, &p[k])))
                return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "vertex: %s is not a %snumber",
                               mesh_text_tokstr(t, tok), rc == -ERANGE ? "finite " : "");
        }
        if ((rc = mesh_build_vertex(b, p, mesh_text_at(t)))) return rc;
        if (n >= 2 && (rc = mesh_build_triangle(b, first, b->nv - 2, b->nv - 1, mesh_text_at(t)))) return rc;
    }
    if (n < 3)
        return mesh_build_fail(b, -EINVAL, mesh_text_at(t), "a facet of %u vertices (at least 3), then %s", n,
                       mesh_text_tokstr(t, tok));
    if ((rc = expect(t, b, "endloop")) || (rc = expect(t, b, "endfacet"))) return rc;
    return 0;
}

static int parse_ascii(const char *buf, size_t len, mbuild *b)
{
    mtext t = {buf, buf + len, buf};
    int rc = expect(&t, b, "solid");
    if (rc) return rc;
    mesh_text_next_line(&t); /* the solid's name */
    for (;;) {
        mesh_text_skip_space(&t);
        if (mesh_text_word(&t, "facet", 1)) {
            /* "normal nx ny nz": not used (the vertices' order is the orientation) */
            if ((rc = expect(&t, b, "normal"))) return rc;
            for (int k = 0; k < 3; k++) {
                mesh_text_skip_blank(&t);
                t.p += mesh_text_toklen(&t);
            }
            if ((rc = parse_loop(&t, b))) return rc;
        } else if (mesh_text_word(&t, "endsolid", 1)) {
            mesh_text_next_line(&t);
            mesh_text_skip_space(&t);
            if (t.p == t.end) return 0;
            if ((rc = expect(&t, b, "solid"))) return rc;
            mesh_text_next_line(&t);
        } else {
            char tok[32];
            return mesh_build_fail(b, -EINVAL, mesh_text_at(&t), "expected 'facet' or 'endsolid', found %s",
                           mesh_text_tokstr(&t, tok));
        }
    }
}

/* ASCII when it begins with "solid" and is not exactly the size of a
 * binary file; the raw vertices are not held to the vertex cap (each
 * triangle has its own), the welded ones are. */
int mesh_parse_stl(const char *buf, size_t len, mbuild *b)
{
    const unsigned char *u = (const unsigned char *)buf;
    /* exactly the size of a binary file of its count */
    int sized = len >= 84 && 84 + 50 * (uint64_t)bits_le32(u + 80) == len, binary = sized;
    if (!binary) {
        mtext t = {buf, buf + len, buf};
        mesh_text_skip_space(&t);
        binary = !mesh_text_word(&t, "solid", 1);
    }
    if (sized && mesh_stl_binary_par(u, bits_le32(u + 80), b)) { /* parsed and welded on every CPU */
        b->binary = 1;
        return 0;
    }
    uint32_t cap = b->max_vert;
    b->max_vert = UINT32_MAX;
    int rc = binary ? parse_binary(u, len, b) : parse_ascii(buf, len, b);
    b->max_vert = cap;
    /* A binary file whose header begins with "solid" and whose size is
     * wrong fails as ASCII: say what it more likely is. */
    if (rc == -EINVAL && !binary && len >= 84 && memchr(buf, 0, len < 4096 ? len : 4096)) {
        uint64_t n = bits_le32(u + 80);
        b->binary = 1;
        rc = mesh_build_fail(b, -EINVAL, 80,
                     "binary STL of %llu triangles must be %llu bytes, the file has %zu "
                     "(and it is not ASCII STL: NUL bytes)",
                     (unsigned long long)n, (unsigned long long)(84 + 50 * n), len);
    }
    if (rc) return rc;
    return mesh_build_weld(b);
}
