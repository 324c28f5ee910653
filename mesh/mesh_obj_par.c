/* mesh_obj_par — a large Wavefront OBJ parsed on every CPU (mesh_obj.c's
 * fast path), as a large ASCII PLY is (mesh_ply.c): one thread took the
 * dragon's 33 MB OBJ in 73-77 ms, alone, before the job could start.
 *
 * The text is cut into parts at line starts.  A first pass counts each
 * part's vertices (`v`) and triangles (a face of k vertices is k - 2), so
 * that each part knows how many vertices came before it (what a relative
 * index counts back from, and how far an index may reach) and where its
 * vertices and triangles go in the builder's arrays, sized once (no
 * per-thread buffers, no copy).  A second pass parses the parts with the
 * serial parser's own token readers (mesh_text_float, mesh_text_int), so
 * what it takes it reads to the same bits, in the same order.  Anything
 * else (a line continued by a backslash, a face of fewer than 3 vertices,
 * an index out of range, a number that does not read, a limit passed, no
 * memory) makes the fast path give up, and the file is parsed again by
 * one thread: its mesh, or its error and line, are then mesh_obj.c's. */
#include <assert.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "mesh_load.h"
#include "par.h"

#define PAR_PARTS 256 /* parts, taken in turn by the threads */

_Atomic uint64_t mesh_obj_par_runs;
size_t mesh_obj_par_min_bytes = (size_t)1 << 20;

typedef struct {
    mbuild *b;
    const char *data, *end;
    uint64_t nv[PAR_PARTS + 1], nt[PAR_PARTS + 1]; /* counts, then the parts' first */
} par_obj;

/* Part k's first byte: the start of the line at or after its share. */
static const char *part_start(const par_obj *po, uint32_t k)
{
    return mesh_text_part_start(po->data, po->end, k, PAR_PARTS);
}

/* The line at p (up to its '\n' or stop) as t; p moved past it.  False
 * when the line is continued by a backslash (the fast path gives up). */
static int next_line(const char **p, const char *stop, const char *base, mtext *t)
{
    *t = mesh_text_line(p, stop, base);
    const char *e = t->end;
    while (e > t->p && e[-1] == '\r') e--;
    return !(e > t->p && e[-1] == '\\');
}

/* A face's vertices, counted as tokens up to the line's end or a '#'. */
static uint32_t face_tokens(mtext *t)
{
    uint32_t n = 0;
    for (;;) {
        mesh_text_skip_blank(t);
        if (t->p == t->end || *t->p == '#') return n;
        t->p += mesh_text_toklen(t);
        n++;
    }
}

/* Part i's vertices and triangles counted into nv[i], nt[i]
 * (mesh_text_each_part's fn); -1: give up. */
static int count_part(void *ud, uint32_t i)
{
    par_obj *po = ud;
    const char *p = part_start(po, i), *stop = part_start(po, i + 1);
    uint64_t nv = 0, nt = 0;
    while (p < stop) {
        mtext t;
        if (!next_line(&p, stop, po->data, &t)) return -1;
        mesh_text_skip_blank(&t);
        if (mesh_text_word(&t, "v", 0)) {
            nv++;
        } else if (mesh_text_word(&t, "f", 0)) {
            uint32_t k = face_tokens(&t);
            if (k < 3) return -1;
            nt += k - 2;
        }
    }
    po->nv[i] = nv, po->nt[i] = nt;
    return 0;
}

/* One face vertex "i[/[t][/n]]" of a file with `so_far` vertices before
 * it: its 0-based index, as mesh_obj.c's face_vertex reads it; -1: give up. */
static int face_vertex(mtext *t, uint64_t so_far, uint32_t *out)
{
    int64_t i, ignored;
    if (mesh_text_int(t, &i) || i == 0 || i > (int64_t)so_far || i < -(int64_t)so_far) return -1;
    *out = i > 0 ? (uint32_t)(i - 1) : (uint32_t)((int64_t)so_far + i);
    for (int k = 0; k < 2 && t->p < t->end && *t->p == '/'; k++) {
        t->p++;
        if (t->p < t->end && (*t->p == '/' || mesh_text_space(*t->p))) continue; /* "i//n", "i/" */
        if (mesh_text_int(t, &ignored)) break;
    }
    return t->p < t->end && !mesh_text_space(*t->p) ? -1 : 0;
}

/* A face, fan triangulated into b->t from *tri on; -1: give up. */
static int take_face(mtext *t, mbuild *b, uint64_t so_far, uint64_t *tri)
{
    uint32_t first = 0, prev = 0, n = 0;
    for (;; n++) {
        mesh_text_skip_blank(t);
        if (t->p == t->end || *t->p == '#') break;
        uint32_t v;
        if (face_vertex(t, so_far, &v)) return -1;
        if (n >= 2) {
            uint32_t *q = b->t[(*tri)++];
            q[0] = first, q[1] = prev, q[2] = v;
        }
        if (n == 0) first = v;
        prev = v;
    }
    return n >= 3 ? 0 : -1;
}

/* Part i parsed into the builder's arrays from its first vertex and
 * triangle on (mesh_text_each_part's fn); -1: give up. */
static int parse_part(void *ud, uint32_t i)
{
    par_obj *po = ud;
    const char *p = part_start(po, i), *stop = part_start(po, i + 1);
    uint64_t v = po->nv[i], tri = po->nt[i];
    mbuild *b = po->b;
    while (p < stop) {
        mtext t;
        if (!next_line(&p, stop, po->data, &t)) return -1;
        mesh_text_skip_blank(&t);
        int rc = 0;
        if (mesh_text_word(&t, "v", 0)) rc = mesh_text_xyz(&t, b->v[v++]);
        else if (mesh_text_word(&t, "f", 0)) rc = take_face(&t, b, v, &tri);
        if (rc) return -1;
    }
    /* what count_part counted: the same lines, the same tokens */
    assert(v == po->nv[i + 1] && tri == po->nt[i + 1]);
    return 0;
}

/* The counts made the parts' first vertex and triangle (prefix sums);
 * whether the totals are within the limits and the arrays were sized. */
static int lay_out(par_obj *po)
{
    uint64_t v = 0, t = 0;
    for (uint32_t i = 0; i <= PAR_PARTS; i++) {
        uint64_t cv = i < PAR_PARTS ? po->nv[i] : 0, ct = i < PAR_PARTS ? po->nt[i] : 0;
        po->nv[i] = v, po->nt[i] = t;
        v += cv, t += ct;
    }
    mbuild *b = po->b;
    if (v > b->max_vert || t > b->max_tri || !v || !t) return 0;
    if (!mesh_build_reserve_vertices(b, v, 0) && !mesh_build_reserve_triangles(b, t, 0)) return 1;
    *b->err = (mesh_error){0}; /* no memory: the one-thread parser's turn, and its message */
    return 0;
}

int mesh_obj_par(const char *buf, size_t len, mbuild *b)
{
    if (len < mesh_obj_par_min_bytes || par_cpus() < 2 || b->nv || b->nt) return 0;
    par_obj *po = calloc(1, sizeof *po); /* 4 KiB of counts: off the stack */
    if (!po) return 0;
    po->b = b, po->data = buf, po->end = buf + len;
    int ok = !mesh_text_each_part(PAR_PARTS, count_part, po) && lay_out(po) &&
             !mesh_text_each_part(PAR_PARTS, parse_part, po);
    if (ok) {
        b->nv = (uint32_t)po->nv[PAR_PARTS], b->nt = (uint32_t)po->nt[PAR_PARTS];
        /* relaxed: a count for the tests, which read it after the parse */
        atomic_fetch_add_explicit(&mesh_obj_par_runs, 1, memory_order_relaxed);
    }
    free(po);
    return ok;
}
