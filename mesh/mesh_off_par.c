/* mesh_off_par — a large OFF parsed on every CPU (mesh_off.c's fast
 * path), as a large ASCII PLY is (mesh_ply.c): the common layout alone,
 * each vertex and each face on a line of its own from the line after the
 * counts, every face a triangle ("3 i j k", then anything: a colour),
 * nothing but blanks after the last face.  The lines are counted in parts
 * first, so that each part knows the record of its first line and writes
 * its vertices and triangles straight into the builder's arrays (sized by
 * the counts), each read by the one-thread parser's own token readers, so
 * to the same bits.  Anything else (a blank or comment line among the
 * records, a polygon, an index out of range, a number that does not read)
 * makes the fast path give up, and mesh_off.c parses the records again
 * from the counts on: its mesh, or its error and line, are the answer. */
#include <stdatomic.h>
#include <stdlib.h>

#include "mesh_load.h"
#include "par.h"

#define PAR_PARTS 256 /* parts, taken in turn by the threads */

_Atomic uint64_t mesh_off_par_runs;
size_t mesh_off_par_min_bytes = (size_t)1 << 20;

typedef struct {
    mbuild *b;
    const char *data, *end;
    uint64_t nv, nf;
    uint64_t first[PAR_PARTS + 1]; /* each part's first line's record */
} par_off;

static const char *part_start(const par_off *po, uint32_t k)
{
    return mesh_text_part_start(po->data, po->end, k, PAR_PARTS);
}

/* Record g, the line t: a vertex, a triangle, or (past the last face)
 * blanks; -1: give up. */
static int record(par_off *po, mtext *t, uint64_t g)
{
    mesh_text_skip_blank(t);
    if (g >= po->nv + po->nf) return t->p == t->end ? 0 : -1;
    if (t->p == t->end || *t->p == '#') return -1; /* a blank or comment line */
    if (g < po->nv) return mesh_text_xyz(t, po->b->v[g]);
    uint64_t k, idx[3];
    if (mesh_text_uint_token(t, UINT32_MAX, &k) || k != 3) return -1;
    for (int j = 0; j < 3; j++) {
        mesh_text_skip_blank(t);
        if (mesh_text_uint_token(t, UINT64_MAX, &idx[j]) || idx[j] >= po->nv) return -1;
    }
    uint32_t *q = po->b->t[g - po->nv];
    q[0] = (uint32_t)idx[0], q[1] = (uint32_t)idx[1], q[2] = (uint32_t)idx[2];
    return 0;
}

/* The lines of part i (mesh_text_each_part's fn); -1: give up. */
static int parse_part(void *ud, uint32_t i)
{
    par_off *po = ud;
    const char *p = part_start(po, i), *stop = part_start(po, i + 1);
    for (uint64_t g = po->first[i]; p < stop; g++) {
        mtext t = mesh_text_line(&p, stop, po->data);
        if (record(po, &t, g)) return -1;
    }
    return 0;
}

int mesh_off_par(const char *data, const char *end, uint64_t nv, uint64_t nf, mbuild *b)
{
    if ((size_t)(end - data) < mesh_off_par_min_bytes || par_cpus() < 2 || b->nv || b->nt ||
        b->cap_v < nv || b->cap_t < nf || !nv || !nf || data == end)
        return 0;
    par_off *po = calloc(1, sizeof *po); /* 2 KiB of counts: off the stack */
    if (!po) return 0;
    po->b = b, po->data = data, po->end = end, po->nv = nv, po->nf = nf;
    uint64_t lines = mesh_text_first_lines(data, end, PAR_PARTS, po->first);
    int ok = lines >= nv + nf && !mesh_text_each_part(PAR_PARTS, parse_part, po);
    free(po);
    if (!ok) return 0;
    b->nv = (uint32_t)nv, b->nt = (uint32_t)nf;
    /* relaxed: a count for the tests, which read it after the parse */
    atomic_fetch_add_explicit(&mesh_off_par_runs, 1, memory_order_relaxed);
    return 1;
}
