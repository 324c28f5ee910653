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
    uint64_t first[PAR_PARTS + 1]; /* newlines in part k, then its first line's record */
    atomic_uint next; /* the next part to take (relaxed: a counter) */
    atomic_int bad;   /* a part gave up (relaxed: read after par_run's join) */
} par_off;

static const char *part_start(const par_off *po, uint32_t k)
{
    return mesh_text_part_start(po->data, po->end, k, PAR_PARTS);
}

static void count_parts(void *ud, unsigned k, unsigned n)
{
    (void)k, (void)n;
    par_off *po = ud;
    for (uint32_t i; (i = atomic_fetch_add_explicit(&po->next, 1, memory_order_relaxed)) < PAR_PARTS;)
        po->first[i] = mesh_text_count_newlines(part_start(po, i), part_start(po, i + 1));
}

/* Record g, the line t: a vertex, a triangle, or (past the last face)
 * blanks; -1: give up. */
static int record(par_off *po, mtext *t, uint64_t g)
{
    mesh_text_skip_blank(t);
    if (g >= po->nv + po->nf) return t->p == t->end ? 0 : -1;
    if (t->p == t->end || *t->p == '#') return -1; /* a blank or comment line */
    if (g < po->nv) {
        float *v = po->b->v[g];
        for (int k = 0; k < 3; k++) {
            mesh_text_skip_blank(t);
            if (mesh_text_float(t, &v[k])) return -1;
        }
        return mesh_build_finite(v) ? 0 : -1;
    }
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

static int parse_part(par_off *po, uint32_t i)
{
    const char *p = part_start(po, i), *stop = part_start(po, i + 1);
    for (uint64_t g = po->first[i]; p < stop; g++) {
        const char *nl = memchr(p, '\n', (size_t)(stop - p));
        mtext t = {p, nl ? nl : stop, po->data};
        p = nl ? nl + 1 : stop;
        /* relaxed: only a hint to stop early; par_run's join orders the result */
        if (record(po, &t, g) || (!(g & 4095) && atomic_load_explicit(&po->bad, memory_order_relaxed)))
            return -1;
    }
    return 0;
}

static void parse_parts(void *ud, unsigned k, unsigned n)
{
    (void)k, (void)n;
    par_off *po = ud;
    for (uint32_t i; (i = atomic_fetch_add_explicit(&po->next, 1, memory_order_relaxed)) < PAR_PARTS;)
        if (parse_part(po, i)) atomic_store_explicit(&po->bad, 1, memory_order_relaxed);
}

int mesh_off_par(const char *data, const char *end, uint64_t nv, uint64_t nf, mbuild *b)
{
    unsigned cpus = par_cpus();
    if ((size_t)(end - data) < mesh_off_par_min_bytes || cpus < 2 || b->nv || b->nt ||
        b->cap_v < nv || b->cap_t < nf || !nv || !nf || data == end)
        return 0;
    par_off *po = calloc(1, sizeof *po); /* 2 KiB of counts: off the stack */
    if (!po) return 0;
    po->b = b, po->data = data, po->end = end, po->nv = nv, po->nf = nf;
    atomic_init(&po->next, 0);
    atomic_init(&po->bad, 0);
    par_run(cpus, count_parts, po);
    uint64_t lines = 0;
    for (uint32_t i = 0; i <= PAR_PARTS; i++) {
        uint64_t c = i < PAR_PARTS ? po->first[i] : 0;
        po->first[i] = lines;
        lines += c;
    }
    lines += end[-1] != '\n'; /* a last line without its line end */
    int ok = lines >= nv + nf;
    if (ok) {
        atomic_store_explicit(&po->next, 0, memory_order_relaxed); /* before par_run's threads */
        par_run(cpus, parse_parts, po);
        ok = !atomic_load_explicit(&po->bad, memory_order_relaxed); /* after the join */
    }
    free(po);
    if (!ok) return 0;
    b->nv = (uint32_t)nv, b->nt = (uint32_t)nf;
    /* relaxed: a count for the tests, which read it after the parse */
    atomic_fetch_add_explicit(&mesh_off_par_runs, 1, memory_order_relaxed);
    return 1;
}
