/* The pieces welded into one mesh, and the serial run.  Vertices come piece
 * by piece in task order, each piece's edge vertices (in key order) then
 * its centre vertices; a triangle's reference to another piece's vertex is
 * found by key: the owner task from the key's sample, the vertex by binary
 * search in the owner's keys.  Pieces may come from other processes: each
 * is checked before it is used. */
#include <errno.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "clock.h"
#include "err.h"
#include "iso.h"
#include "par.h"

#define KEY_LOW ((1ull << 58) - 1)

/* ---- packing ---- */

size_t iso_piece_bytes(const iso_params *p, const iso_piece *pc)
{
    size_t f = p->normals ? 6 : 3;
    return 8 * ((size_t)pc->nv + pc->ne) + 4 * f * ((size_t)pc->nv + pc->nc) +
           12 * (size_t)pc->nt;
}

/* Copy n bytes to *o and step past them. */
static void put(uint8_t **o, const void *src, size_t n)
{
    if (n) memcpy(*o, src, n);
    *o += n;
}

void iso_piece_pack(const iso_params *p, const iso_piece *pc, void *to)
{
    uint8_t *o = to;
    put(&o, pc->keys, 8 * (size_t)pc->nv);
    put(&o, pc->ext, 8 * (size_t)pc->ne);
    put(&o, pc->pos, 12 * (size_t)pc->nv);
    if (p->normals) put(&o, pc->nrm, 12 * (size_t)pc->nv);
    put(&o, pc->cpos, 12 * (size_t)pc->nc);
    if (p->normals) put(&o, pc->cnrm, 12 * (size_t)pc->nc);
    put(&o, pc->tri, 12 * (size_t)pc->nt);
}

int iso_piece_view(const iso_params *p, const void *from, size_t bytes, iso_piece *pc)
{
    uint32_t nv = pc->nv, nc = pc->nc, ne = pc->ne;
    *pc = (iso_piece){.key = pc->key, .nv = nv, .nc = nc, .nt = pc->nt, .ne = ne};
    if (iso_piece_bytes(p, pc) > bytes) return -EINVAL;
    const uint8_t *o = from;
    pc->keys = (const uint64_t *)o;
    pc->ext = (const uint64_t *)(o += 8 * (size_t)nv);
    pc->pos = (const float *)(o += 8 * (size_t)ne);
    o += 12 * (size_t)nv;
    if (p->normals) {
        pc->nrm = (const float *)o;
        o += 12 * (size_t)nv;
    }
    pc->cpos = (const float *)o;
    o += 12 * (size_t)nc;
    if (p->normals) {
        pc->cnrm = (const float *)o;
        o += 12 * (size_t)nc;
    }
    pc->tri = (const uint32_t *)o;
    return 0;
}

/* ---- welding ---- */

/* A vertex key's task key, or UINT64_MAX when it names no edge. */
static uint64_t owner_of(const iso_params *p, uint64_t key)
{
    uint32_t l = (uint32_t)(key >> 58), g[3];
    uint64_t lin = (key & KEY_LOW) >> 2, u[3], W[3];
    if (l >= p->height || (key & 3u) == 3) return UINT64_MAX;
    for (int a = 0; a < 3; a++) W[a] = (uint64_t)p->dims[l][a] + 2;
    u[0] = lin % W[0];
    u[1] = lin / W[0] % W[1];
    u[2] = lin / W[0] / W[1];
    if (u[2] >= W[2]) return UINT64_MAX;
    iso_task_grid(p, l, g);
    uint64_t b[3];
    for (int a = 0; a < 3; a++) {
        b[a] = u[a] / p->brick;
        if (b[a] >= g[a]) return UINT64_MAX;
    }
    return iso_brick_key(l, (b[2] * g[1] + b[1]) * g[0] + b[0]);
}

static int64_t find_u64(const uint64_t *v, uint64_t n, uint64_t key)
{
    uint64_t lo = 0, hi = n;
    while (lo < hi) {
        uint64_t mid = lo + (hi - lo) / 2;
        if (v[mid] < key) lo = mid + 1;
        else hi = mid;
    }
    return lo < n && v[lo] == key ? (int64_t)lo : -1;
}

static int64_t find_piece(const iso_piece *pc, uint64_t n, uint64_t key)
{
    uint64_t lo = 0, hi = n;
    while (lo < hi) {
        uint64_t mid = lo + (hi - lo) / 2;
        if (pc[mid].key < key) lo = mid + 1;
        else hi = mid;
    }
    return lo < n && pc[lo].key == key ? (int64_t)lo : -1;
}

/* Piece i's keys: increasing (the binary searches need it), the first and
 * the last an edge of its own brick.  A key between them that is not
 * (only a broken worker makes one) cannot make the weld read or write out
 * of bounds: at worst a reference finds no vertex, and fails.  Its
 * triangles' references: each inside its kind's count. */
static int check_piece(const iso_params *p, const iso_piece *pcs, uint64_t i, err_info *e)
{
    const iso_piece *pc = &pcs[i];
    unsigned long long id = (unsigned long long)i;
    if (i && pc->key <= pcs[i - 1].key) return err_set(e, -EPROTO, "the pieces are not in task order");
    for (uint32_t k = 1; k < pc->nv; k++)
        if (pc->keys[k] <= pc->keys[k - 1])
            return err_set(e, -EPROTO, "piece %llu: its vertices are not in key order", id);
    if (pc->nv && (owner_of(p, pc->keys[0]) != pc->key ||
                   owner_of(p, pc->keys[pc->nv - 1]) != pc->key))
        return err_set(e, -EPROTO, "piece %llu: its vertices are not on its brick's edges", id);
    for (uint64_t k = 0; k < 3 * (uint64_t)pc->nt; k++) {
        uint32_t r = pc->tri[k], x = r & ISO_REF_INDEX, kind = r & ~ISO_REF_INDEX;
        if (!(kind == 0 && x < pc->nv) && !(kind == ISO_REF_CENTRE && x < pc->nc) &&
            !(kind == ISO_REF_EXT && x < pc->ne))
            return err_set(e, -EPROTO, "piece %llu: triangle %llu refers to no vertex", id,
                       (unsigned long long)(k / 3));
    }
    return 0;
}

/* The pieces checked in chunks of about equal work (a piece's vertices
 * and triangle corners, which is what the check reads), in piece order:
 * chunk k is pieces start[k] .. start[k + 1], taken by the threads in
 * turn from a counter.  Not one part a thread: what a part costs is
 * mostly its first touches of the workers' pages, which no count of
 * vertices foretells (two parts of equal work on Scene 1 at 512^3 ended
 * 20-27 ms apart, the second thread alone meanwhile); with many chunks
 * the threads end within a chunk of each other.  Each chunk stops at its
 * first bad piece; the first of those in piece order is the error, as
 * one thread finds. */
#define CHECK_CHUNKS 256u
typedef struct {
    const iso_params *p;
    const iso_piece *pc;
    uint64_t n;
    unsigned chunks;
    atomic_uint next;        /* the next chunk to take */
    uint64_t start[CHECK_CHUNKS + 1];
    uint64_t bad[CHECK_CHUNKS];   /* each chunk's first bad piece, or n */
    err_info err[CHECK_CHUNKS];   /* and what is wrong with it */
} check_ctx;

static uint64_t check_work(const iso_piece *pc)
{
    return 1 + (uint64_t)pc->nv + 3 * (uint64_t)pc->nt;
}

/* c->start for c->chunks chunks of about equal work. */
static void check_cut(check_ctx *c)
{
    uint64_t total = 0, cum = 0, i = 0;
    for (uint64_t j = 0; j < c->n; j++) total += check_work(&c->pc[j]);
    for (unsigned k = 0; k < c->chunks; k++) {
        c->start[k] = i;
        /* chunk k ends where the work before it reaches (k + 1) / chunks
         * (the last one at the end: every piece's work is at least 1) */
        while (i < c->n && cum < total * (k + 1) / c->chunks) cum += check_work(&c->pc[i++]);
    }
    c->start[c->chunks] = c->n;
}

static void check_part(void *ud, unsigned k, unsigned parts)
{
    check_ctx *c = ud;
    (void)k, (void)parts;
    /* relaxed: a counter that hands out disjoint chunks; par_run's join
     * orders every chunk's results before they are read */
    for (unsigned j; (j = atomic_fetch_add_explicit(&c->next, 1, memory_order_relaxed)) <
                     c->chunks;) {
        c->bad[j] = c->n;
        for (uint64_t i = c->start[j]; i < c->start[j + 1]; i++)
            if (check_piece(c->p, c->pc, i, &c->err[j])) {
                c->bad[j] = i;
                break;
            }
    }
}

/* Pieces per chunk at least: a chunk is worth taking. */
#define CHECK_CHUNK_MIN 64u

int iso_weld_bases(const iso_weld *w, unsigned threads, err_info *e)
{
    const iso_piece *pc = w->pc;
    uint64_t n = w->n, *vbase = w->vbase, *tbase = w->tbase;
    check_ctx *c = malloc(sizeof *c);
    if (!c) return -ENOMEM;
    c->p = w->p, c->pc = pc, c->n = n;
    uint64_t most = n / CHECK_CHUNK_MIN + 1;
    c->chunks = most < CHECK_CHUNKS ? (unsigned)most : CHECK_CHUNKS;
    atomic_init(&c->next, 0);
    check_cut(c);
    unsigned parts = threads < 1 ? 1 : threads > PAR_MAX ? PAR_MAX : threads;
    if (parts > c->chunks) parts = c->chunks;
    par_run(parts, check_part, c);
    int rc = 0;
    for (unsigned k = 0; k < c->chunks && !rc; k++)
        if (c->bad[k] < n) /* the chunks are in piece order */
            rc = err_set(e, c->err[k].code, "%s", c->err[k].msg);
    free(c);
    if (rc) return rc;
    uint64_t nv = 0, nt = 0;
    for (uint64_t i = 0; i < n; i++) {
        vbase[i] = nv;
        tbase[i] = nt;
        nv += (uint64_t)pc[i].nv + pc[i].nc;
        nt += pc[i].nt;
    }
    vbase[n] = nv;
    tbase[n] = nt;
    if (nv <= UINT32_MAX) return 0;
    return err_set(e, -E2BIG, "%llu vertices: more than a mesh of 32-bit indices holds",
                   (unsigned long long)nv);
}

/* The global index of each of piece i's external references. */
static int resolve_ext(const iso_weld *w, uint64_t i, uint32_t *out, err_info *e)
{
    const iso_piece *pc = &w->pc[i];
    for (uint32_t k = 0; k < pc->ne; k++) {
        uint64_t owner = owner_of(w->p, pc->ext[k]);
        int64_t j = owner == UINT64_MAX ? -1 : find_piece(w->pc, w->n, owner);
        int64_t v = j < 0 ? -1 : find_u64(w->pc[j].keys, w->pc[j].nv, pc->ext[k]);
        if (v < 0)
            return err_set(e, -EPROTO, "piece %llu refers to a vertex no piece has (key %llx)",
                       (unsigned long long)i, (unsigned long long)pc->ext[k]);
        out[k] = (uint32_t)(w->vbase[j] + (uint64_t)v);
    }
    return 0;
}

/* n float triples (an empty piece's arrays may be NULL) */
static void copy3(float *to, const float *from, uint32_t n)
{
    if (n) memcpy(to, from, 12 * (size_t)n);
}

int iso_weld_piece(const iso_weld *w, uint64_t i, err_info *e)
{
    const iso_piece *pc = &w->pc[i];
    uint32_t *ext = malloc(((size_t)pc->ne + 1) * sizeof *ext);
    if (!ext) return -ENOMEM;
    int rc = resolve_ext(w, i, ext, e);
    uint64_t base = w->vbase[i];
    uint32_t *to = w->tri + 3 * w->tbase[i];
    for (uint64_t k = 0; k < 3 * (uint64_t)pc->nt && !rc; k++) {
        uint32_t r = pc->tri[k], x = r & ISO_REF_INDEX, kind = r & ~ISO_REF_INDEX;
        /* in range: iso_weld_bases checked every reference */
        to[k] = kind == ISO_REF_EXT ? ext[x]
                                    : (uint32_t)(base + (kind ? pc->nv : 0) + x);
    }
    free(ext);
    if (rc) return rc;
    copy3(w->pos + 3 * base, pc->pos, pc->nv);
    copy3(w->pos + 3 * (base + pc->nv), pc->cpos, pc->nc);
    if (w->nrm) {
        copy3(w->nrm + 3 * base, pc->nrm, pc->nv);
        copy3(w->nrm + 3 * (base + pc->nv), pc->cnrm, pc->nc);
    }
    return 0;
}

int iso_merge(const iso_params *p, const iso_piece *pieces, uint64_t n, iso_mesh *out,
              err_info *e)
{
    memset(out, 0, sizeof *out);
    uint64_t *vbase = malloc((n + 1) * sizeof *vbase), *tbase = malloc((n + 1) * sizeof *tbase);
    iso_weld w = {p, pieces, n, vbase, tbase, NULL, NULL, NULL};
    int rc = vbase && tbase ? iso_weld_bases(&w, 1, e) : -ENOMEM;
    if (!rc) {
        out->n_vertices = vbase[n];
        out->n_triangles = tbase[n];
        out->pos = malloc(12 * (size_t)(vbase[n] ? vbase[n] : 1));
        out->nrm = p->normals ? malloc(12 * (size_t)(vbase[n] ? vbase[n] : 1)) : NULL;
        out->tri = malloc(12 * (size_t)(tbase[n] ? tbase[n] : 1));
        if (!out->pos || !out->tri || (p->normals && !out->nrm)) rc = -ENOMEM;
    }
    w.pos = out->pos, w.nrm = out->nrm, w.tri = out->tri;
    for (uint64_t i = 0; i < n && !rc; i++) rc = iso_weld_piece(&w, i, e);
    if (rc == -ENOMEM) err_set(e, rc, "out of memory for the mesh");
    if (rc) iso_mesh_free(out);
    free(vbase);
    free(tbase);
    return rc;
}

void iso_mesh_free(iso_mesh *m)
{
    if (!m->borrowed) {
        free(m->pos);
        free(m->nrm);
        free(m->tri);
    }
    memset(m, 0, sizeof *m);
}

/* ---- the serial run ---- */

static int run_tasks(const iso_params *p, const iso_input *in, const iso_task *t,
                     uint64_t n, iso_piece *pc, uint8_t **own)
{
    iso_work *w = NULL;
    int rc = iso_work_new(p, &w);
    for (uint64_t i = 0; i < n && !rc; i++) {
        iso_piece v;
        rc = iso_task_run(w, p, in, &t[i], &v);
        size_t bytes = rc ? 0 : iso_piece_bytes(p, &v);
        if (!rc && !(own[i] = malloc(bytes ? bytes : 1))) rc = -ENOMEM;
        if (rc) break;
        iso_piece_pack(p, &v, own[i]);
        pc[i] = v;
        iso_piece_view(p, own[i], bytes, &pc[i]);
    }
    iso_work_free(w);
    return rc;
}

int iso_run_serial(const iso_params *p, const iso_input *in, iso_mesh *m, err_info *e)
{
    iso_task *t;
    uint64_t n;
    memset(m, 0, sizeof *m);
    double t0 = clock_now();
    int rc = iso_tasks(p, in, &t, &n);
    double t1 = clock_now();
    if (rc) return err_set(e, rc, "out of memory for the tasks");
    iso_piece *pc = calloc(n + 1, sizeof *pc);
    uint8_t **own = calloc(n + 1, sizeof *own);
    rc = pc && own ? run_tasks(p, in, t, n, pc, own) : -ENOMEM;
    double t2 = clock_now();
    if (rc) err_set(e, rc, "%s", rc == -ENOMEM ? "out of memory" : "bad task");
    else rc = iso_merge(p, pc, n, m, e);
    m->t_setup = t1 - t0;
    m->t_tasks = t2 - t1;
    m->t_weld = clock_now() - t2;
    for (uint64_t i = 0; own && i < n; i++) free(own[i]);
    free(own);
    free(pc);
    free(t);
    return rc;
}
