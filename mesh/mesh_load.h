/* mesh_load — what the format loaders (mesh_obj.c, mesh_stl.c, mesh_ply.c,
 * mesh_off.c) share: the mesh being built, the checks every loader makes
 * through it, and a bounded text cursor with its number parsers (in
 * mesh_load_core.c, so that mesh_load.c's dispatch and the loaders form no
 * cycle).  Internal to mesh/; the interface is mesh.h.
 *
 * The input is a mapped file: it is not NUL-terminated, so nothing here
 * reads past `end`, and no libc parser is called on it directly (strtof
 * runs on a bounded, terminated copy of one token).
 */
#ifndef VOXD_MESH_LOAD_H
#define VOXD_MESH_LOAD_H

#include <errno.h>
#include <float.h>
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "mesh.h"

/* ---- the mesh being built ---- */

typedef struct {
    uint32_t max_tri, max_vert; /* the limits, resolved (never 0) */
    int binary;                 /* errors say byte offsets, not lines */
    const char *buf;            /* the input: a text error's line is counted there */
    mesh_error *err;
    float (*v)[3];
    uint32_t nv;
    size_t cap_v;
    uint32_t (*t)[3];
    uint32_t nt;                /* triangles made so far, degenerate included */
    size_t cap_t;
    char warning[200];          /* mesh_build_warn's first line, into mesh.warning */
    const char *dir;            /* the file's folder (glTF's external buffers); NULL: none */
    unsigned stl_threads;       /* a large binary STL's parse and weld: its threads, 0 one a
                                 * CPU; MESH_STL_SERIAL: parse_binary, mesh_build_weld */
} mbuild;

/* Fill the error and return rc.  at: the byte offset of the trouble, told
 * as a line for text (b->binary 0), or MESH_BUILD_NOWHERE. */
#define MESH_BUILD_NOWHERE UINT64_MAX
int mesh_build_fail(mbuild *b, int rc, uint64_t at, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
/* Keep the first warning (told at `at` as mesh_build_fail tells an error); later
 * ones are dropped: the loader counts them itself if it says so. */
void mesh_build_warn(mbuild *b, uint64_t at, const char *fmt, ...) __attribute__((format(printf, 3, 4)));
/* Room for n more vertices / triangles, checked against the limits first:
 * -E2BIG past one, -ENOMEM. */
int mesh_build_reserve_vertices(mbuild *b, uint64_t n, uint64_t at);
int mesh_build_reserve_triangles(mbuild *b, uint64_t n, uint64_t at);
/* Add a vertex: -EINVAL when not finite, -E2BIG past the vertex cap. */
int mesh_build_vertex_slow(mbuild *b, const float p[3], uint64_t at);
/* Add triangle (a, c, d): the caller has checked the indices (below the
 * vertex count the file declares); -E2BIG past the triangle cap. */
int mesh_build_triangle_slow(mbuild *b, uint32_t a, uint32_t c, uint32_t d, uint64_t at);

static inline int mesh_build_finite(const float p[3])
{
    return isfinite(p[0]) && isfinite(p[1]) && isfinite(p[2]);
}

static inline int mesh_build_vertex(mbuild *b, const float p[3], uint64_t at)
{
    if (b->nv < b->cap_v && mesh_build_finite(p)) {
        float *q = b->v[b->nv++];
        q[0] = p[0], q[1] = p[1], q[2] = p[2];
        return 0;
    }
    return mesh_build_vertex_slow(b, p, at);
}

static inline int mesh_build_triangle(mbuild *b, uint32_t a, uint32_t c, uint32_t d, uint64_t at)
{
    if (b->nt < b->cap_t) {
        uint32_t *q = b->t[b->nt++];
        q[0] = a, q[1] = c, q[2] = d;
        return 0;
    }
    return mesh_build_triangle_slow(b, a, c, d, at);
}

/* Triangle (a, b, c) of the positions v is degenerate: two equal indices,
 * or zero area (the cross product of two edges, the edges taken in double,
 * is exactly zero: three collinear positions, two equal). */
int mesh_build_degenerate(float (*v)[3], uint32_t a, uint32_t b, uint32_t c);
/* Drop the degenerate triangles, take the bounding box, and move the
 * arrays into *out (b is empty after).  -EINVAL when no triangle is left. */
int mesh_build_finish(mbuild *b, mesh_format f, mesh *out);
/* The triangles t[0 .. nt) of the positions v with the degenerate ones
 * (two equal indices, or zero area) dropped in place, the others in their
 * order; how many are kept, and their box grown into lo, hi (the first of
 * equal values kept).  On every CPU for a large mesh (mesh_build_finish's
 * step, and the weld's after it renumbers the triangles). */
uint32_t mesh_build_keep(float (*v)[3], uint32_t (*t)[3], uint32_t nt, float lo[3],
                         float hi[3]);
void mesh_build_free(mbuild *b);

/* STL's vertices are per triangle: merge bit-equal positions (-0 as 0)
 * into one vertex and renumber the triangles.  0 or -ENOMEM; -E2BIG when
 * the merged vertices are still past the cap. */
int mesh_build_weld(mbuild *b);

/* The hash of a position's welding key (its bits, -0 taken as +0). */
static inline uint64_t mesh_build_key_hash(const uint32_t bits[3])
{
    uint64_t h = ((uint64_t)bits[0] << 32 | bits[1]) * 0x9e3779b97f4a7c15ull;
    h ^= (h >> 29) ^ bits[2] * 0xc2b2ae3d27d4eb4full;
    return h * 0x94d049bb133111ebull;
}

/* ---- the loaders: buf[0, len), format already told ---- */

int mesh_parse_obj(const char *buf, size_t len, mbuild *b);
int mesh_parse_stl(const char *buf, size_t len, mbuild *b);
int mesh_parse_ply(const char *buf, size_t len, mbuild *b);
int mesh_parse_off(const char *buf, size_t len, mbuild *b);
int mesh_parse_gltf(const char *buf, size_t len, mbuild *b);
/* ASCII PLY files parsed on every CPU so far (mesh_ply.c's fast path; the
 * others are parsed by one thread): the tests check which path ran. */
extern _Atomic uint64_t mesh_ply_par_runs;
/* A binary STL of n triangles (u: the whole file) parsed and welded on
 * b->stl_threads threads (mesh_stl_par.c) into the mesh that mesh_stl.c's
 * serial path (parse_binary, then mesh_build_weld) makes: 1 when done, 0
 * when that path must do it (fewer than 16384 triangles, MESH_STL_SERIAL,
 * a coordinate not finite, a limit passed, no memory: b left empty).  The
 * runs so far are counted for the tests. */
#define MESH_STL_SERIAL UINT32_MAX
int mesh_stl_binary_par(const unsigned char *u, uint32_t n, mbuild *b);
extern _Atomic uint64_t mesh_stl_par_runs;
/* Welds with eps = 0 run on every CPU so far (mesh_weld.c; smaller meshes
 * and other eps are merged by one thread): the tests check which ran. */
extern _Atomic uint64_t mesh_weld_par_runs;
/* A large OBJ (1 MiB or more) parsed on every CPU (mesh_obj_par.c) into
 * the mesh mesh_obj.c's one-thread parser makes: 1 when done, 0 when that
 * parser must do it (b left empty).  The runs so far are counted for the
 * tests. */
int mesh_obj_par(const char *buf, size_t len, mbuild *b);
extern _Atomic uint64_t mesh_obj_par_runs;
/* The size from which an OBJ is parsed on every CPU (1 MiB); fuzz_mesh
 * sets it to 0 and to SIZE_MAX, to hold one path's answer to the other's. */
extern size_t mesh_obj_par_min_bytes;
/* An OFF's records [data, end) after its counts (nv, nf; b's arrays sized
 * for them) parsed on every CPU (mesh_off_par.c) when their layout is the
 * common one: 1 when done, 0 when mesh_off.c must parse them (b left
 * empty).  Runs counted, and the size from which it runs (1 MiB), as for
 * OBJ. */
int mesh_off_par(const char *data, const char *end, uint64_t nv, uint64_t nf, mbuild *b);
extern _Atomic uint64_t mesh_off_par_runs;
extern size_t mesh_off_par_min_bytes;
/* p[0, n) is an OFF keyword: [ST][C][N]OFF (3-D; 4OFF and nOFF are not). */
int mesh_off_keyword(const char *p, size_t n);

/* ---- text ---- */

/* Line numbers are not kept while parsing (the hot loops stay plain): an
 * error counts the newlines before its byte offset (mesh_build_fail). */
typedef struct {
    const char *p, *end, *base;
} mtext;

/* p's byte offset: where an error is (mesh_build_fail makes it a line). */
static inline uint64_t mesh_text_at(const mtext *t) { return (uint64_t)(t->p - t->base); }

/* A blank within a line (the line ends at '\n'; "\r\n" is a blank and a newline). */
static inline int mesh_text_blank(char c)
{
    return c == ' ' || c == '\t' || c == '\r' || c == '\f' || c == '\v';
}
static inline int mesh_text_space(char c) { return mesh_text_blank(c) || c == '\n'; }

static inline void mesh_text_skip_blank(mtext *t)
{
    while (t->p < t->end && mesh_text_blank(*t->p)) t->p++;
}
/* Blanks and newlines. */
static inline void mesh_text_skip_space(mtext *t)
{
    while (t->p < t->end && mesh_text_space(*t->p)) t->p++;
}
/* At the end of the line (or of the text), after mesh_text_skip_blank. */
static inline int mesh_text_eol(const mtext *t) { return t->p == t->end || *t->p == '\n'; }
/* Past the next newline. */
void mesh_text_next_line(mtext *t);
/* The parallel parsers' line: [*p, its '\n' or stop) as an mtext over
 * base, *p moved past it. */
static inline mtext mesh_text_line(const char **p, const char *stop, const char *base)
{
    const char *nl = memchr(*p, '\n', (size_t)(stop - *p));
    mtext t = {*p, nl ? nl : stop, base};
    *p = nl ? nl + 1 : stop;
    return t;
}
/* The '\n' bytes in [p, end) (the parallel parsers' first pass). */
uint64_t mesh_text_count_newlines(const char *p, const char *end);
/* Part k of [data, end) cut into `parts` at line starts: the start of the
 * line at or after its share (so part k - 1 ends where it starts). */
const char *mesh_text_part_start(const char *data, const char *end, uint32_t k, uint32_t parts);
/* fn(ud, part) for parts 0 .. nparts - 1 on every CPU, the threads taking
 * them in turn, no part taken once one has failed (fn non-zero): 0 when
 * every part ran and none failed, else -1. */
int mesh_text_each_part(uint32_t nparts, int (*fn)(void *ud, uint32_t part), void *ud);
/* [data, end) cut into `parts` (mesh_text_part_start): first[k] the index
 * of part k's first line, first[parts] the lines before the end (first
 * holds parts + 1); the lines, a last one without its '\n' counted. */
uint64_t mesh_text_first_lines(const char *data, const char *end, uint32_t parts, uint64_t *first);
/* The length of the token at p (up to a blank, newline or the end). */
size_t mesh_text_toklen(const mtext *t);
/* The token at p is w (ASCII case ignored when nocase): consume it. */
int mesh_text_word(mtext *t, const char *w, int nocase);

/* The longest number token read (longer ones are refused). */
#define MESH_TEXT_TOKEN_MAX 127
int mesh_text_float_slow(mtext *t, float *out);
extern const double mesh_text_pow10[23], mesh_text_pow10_neg[23];

static inline int mesh_text_digit(char c) { return (unsigned)(c - '0') < 10; }

/* The number token at p into *out; p moves past it.  The token must end at
 * a blank, a newline or the end.  Correctly rounded to float.  0, -EINVAL
 * not a number (p unmoved), -ERANGE not finite (NaN, Inf, beyond FLT_MAX).
 *
 * The fast path reads a decimal m * 10^e with m < 2^53 and |e| <= 22, and
 * takes d = m * 10^e in double: exact operands and one rounding for e >= 0;
 * for e < 0, m times the double nearest 10^e, within 2 units of the last
 * place (ulp) of d from the true value x.  d rounds to the same float as x
 * unless a point halfway between two floats lies within 3 ulp of d (the 29
 * bits a float drops are then near 1000...0): those, and anything else
 * (more digits, NaN and Inf spellings, hex floats, subnormal or overflowing
 * floats), go to strtof on a terminated copy of the token. */
static inline int mesh_text_float(mtext *t, float *out)
{
#if FLT_EVAL_METHOD == 0
    /* at most MESH_TEXT_TOKEN_MAX characters scanned: the exponent stays small */
    const char *s = t->p, *end = t->end - t->p > MESH_TEXT_TOKEN_MAX ? t->p + MESH_TEXT_TOKEN_MAX : t->end;
    int neg = 0, e10 = 0, nd = 0, inexact = 0;
    uint64_t m = 0;
    if (s < end && (*s == '+' || *s == '-')) neg = *s++ == '-';
    for (; s < end && mesh_text_digit(*s); s++, nd++) {
        if (m < 1000000000000000000ull) m = m * 10 + (uint64_t)(*s - '0');
        else e10++, inexact |= *s != '0';
    }
    if (s < end && *s == '.')
        for (s++; s < end && mesh_text_digit(*s); s++, nd++) {
            if (m < 1000000000000000000ull) m = m * 10 + (uint64_t)(*s - '0'), e10--;
            else inexact |= *s != '0';
        }
    if (nd && s < end && (*s == 'e' || *s == 'E')) {
        const char *x = s + 1;
        int eneg = 0, ev = 0;
        if (x < end && (*x == '+' || *x == '-')) eneg = *x++ == '-';
        if (!(x < end && mesh_text_digit(*x))) return mesh_text_float_slow(t, out); /* "1e": refused there */
        for (; x < end && mesh_text_digit(*x); x++)
            if (ev < 100000) ev = ev * 10 + (*x - '0');
        e10 += eneg ? -ev : ev;
        s = x;
    }
    if (!nd || inexact || (s < t->end && !mesh_text_space(*s))) return mesh_text_float_slow(t, out);
    if (m == 0) {
        *out = neg ? -0.0f : 0.0f;
        t->p = s;
        return 0;
    }
    while ((m >= (1ull << 53) || e10 < -22) && m % 10 == 0) m /= 10, e10++;
    if (m >= (1ull << 53) || e10 < -22 || e10 > 22) return mesh_text_float_slow(t, out);
    double d = e10 < 0 ? (double)m * mesh_text_pow10_neg[-e10] : (double)m * mesh_text_pow10[e10];
    uint64_t bits;
    memcpy(&bits, &d, 8);
    if (d > FLT_MAX || d < FLT_MIN || (bits + 3 - 0x10000000u) % 0x20000000u <= 6)
        return mesh_text_float_slow(t, out);
    float f = (float)d;
    *out = neg ? -f : f;
    t->p = s;
    return 0;
#else
    return mesh_text_float_slow(t, out);
#endif
}

/* A vertex's three coordinates, each after blanks, all finite, into v:
 * the parallel parsers' reading (0, or -1: the one-thread parser says
 * what is wrong). */
static inline int mesh_text_xyz(mtext *t, float v[3])
{
    for (int k = 0; k < 3; k++) {
        mesh_text_skip_blank(t);
        if (mesh_text_float(t, &v[k])) return -1;
    }
    return mesh_build_finite(v) ? 0 : -1;
}

/* A decimal integer with an optional sign, ending wherever its digits end
 * (the caller checks what follows).  0, -EINVAL, -ERANGE (past int64). */
static inline int mesh_text_int(mtext *t, int64_t *out)
{
    const char *s = t->p;
    int neg = 0;
    if (s < t->end && (*s == '+' || *s == '-')) neg = *s++ == '-';
    if (!(s < t->end && mesh_text_digit(*s))) return -EINVAL;
    uint64_t v = 0;
    for (; s < t->end && mesh_text_digit(*s); s++) {
        if (v >= 922337203685477580ull) return -ERANGE; /* INT64_MAX / 10: no overflow below */
        v = v * 10 + (uint64_t)(*s - '0');
    }
    *out = neg ? -(int64_t)v : (int64_t)v;
    t->p = s;
    return 0;
}
/* A whole token that is a decimal integer in [0, max]: 0, -EINVAL, -ERANGE. */
int mesh_text_uint_token(mtext *t, uint64_t max, uint64_t *out);

/* For messages: the token at p, at most 24 characters, printable. */
const char *mesh_text_tokstr(const mtext *t, char buf[32]);

#endif
