/* mesh_load_core — what the format loaders share (mesh_load.h): the mesh
 * being built (limits, degenerate triangles, bounding box, STL's welding)
 * and the bounded text parsers.  The loaders call this file and nothing
 * else of the module; mesh_load.c calls them. */
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "huge.h"
#include "mesh_load.h"
#include "par.h"

#ifdef __SSE2__
#include <emmintrin.h>
#endif

/* ------------------------------------------------------------------ builder */

/* The line of byte offset at in a text file. */
static uint64_t line_of(const mbuild *b, uint64_t at)
{
    uint64_t line = 1;
    for (const char *q = b->buf, *e = b->buf + at; (q = memchr(q, '\n', (size_t)(e - q))); q++)
        line++;
    return line;
}

int mesh_build_fail(mbuild *b, int rc, uint64_t at, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    err_vset(&b->err->info, rc, fmt, ap);
    va_end(ap);
    b->err->line = b->err->offset = 0;
    if (at == MESH_BUILD_NOWHERE) return rc;
    if (b->binary) b->err->offset = at;
    else b->err->line = line_of(b, at);
    return rc;
}

void mesh_build_warn(mbuild *b, uint64_t at, const char *fmt, ...)
{
    if (b->warning[0]) return;
    size_t n = 0;
    if (at != MESH_BUILD_NOWHERE)
        n = (size_t)snprintf(b->warning, sizeof b->warning, "%s %llu: ",
                             b->binary ? "byte" : "line",
                             (unsigned long long)(b->binary ? at : line_of(b, at)));
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(b->warning + n, sizeof b->warning - n, fmt, ap);
    va_end(ap);
}

/* Capacity for need items of size sz in *arr (cap: its capacity): exact
 * when asked, else at least doubled, never past max. */
static int grow(void **arr, size_t *cap, uint64_t need, uint64_t max, size_t sz, int exact)
{
    if (need <= *cap) return 0;
    uint64_t n = need;
    if (!exact) {
        n = *cap * 2 > need ? *cap * 2 : need;
        if (n < 1024) n = 1024;
        if (n > max) n = max;
    }
    void *p = realloc(*arr, (size_t)n * sz);
    if (!p) return -ENOMEM;
    huge_advise(p, (size_t)n * sz); /* written soon, once (huge.h) */
    *arr = p;
    *cap = (size_t)n;
    return 0;
}

int mesh_build_reserve_vertices(mbuild *b, uint64_t n, uint64_t at)
{
    if (n > b->max_vert - b->nv)
        return mesh_build_fail(b, -E2BIG, at, "%llu vertices: more than the limit of %u",
                       (unsigned long long)(b->nv + n), b->max_vert);
    if (grow((void **)&b->v, &b->cap_v, b->nv + n, b->max_vert, sizeof *b->v, 1))
        return mesh_build_fail(b, -ENOMEM, at, "out of memory for %llu vertices",
                       (unsigned long long)(b->nv + n));
    return 0;
}

int mesh_build_reserve_triangles(mbuild *b, uint64_t n, uint64_t at)
{
    if (n > b->max_tri - b->nt)
        return mesh_build_fail(b, -E2BIG, at, "%llu triangles: more than the limit of %u",
                       (unsigned long long)(b->nt + n), b->max_tri);
    if (grow((void **)&b->t, &b->cap_t, b->nt + n, b->max_tri, sizeof *b->t, 1))
        return mesh_build_fail(b, -ENOMEM, at, "out of memory for %llu triangles",
                       (unsigned long long)(b->nt + n));
    return 0;
}

int mesh_build_vertex_slow(mbuild *b, const float p[3], uint64_t at)
{
    if (!mesh_build_finite(p))
        return mesh_build_fail(b, -EINVAL, at, "vertex %u: a coordinate is not a finite number", b->nv);
    if (b->nv >= b->max_vert)
        return mesh_build_fail(b, -E2BIG, at, "more than the limit of %u vertices", b->max_vert);
    if (grow((void **)&b->v, &b->cap_v, (uint64_t)b->nv + 1, b->max_vert, sizeof *b->v, 0))
        return mesh_build_fail(b, -ENOMEM, at, "out of memory for %u vertices", b->nv + 1);
    return mesh_build_vertex(b, p, at);
}

int mesh_build_triangle_slow(mbuild *b, uint32_t a, uint32_t c, uint32_t d, uint64_t at)
{
    if (b->nt >= b->max_tri)
        return mesh_build_fail(b, -E2BIG, at, "more than the limit of %u triangles", b->max_tri);
    if (grow((void **)&b->t, &b->cap_t, (uint64_t)b->nt + 1, b->max_tri, sizeof *b->t, 0))
        return mesh_build_fail(b, -ENOMEM, at, "out of memory for %u triangles", b->nt + 1);
    return mesh_build_triangle(b, a, c, d, at);
}

/* Zero area: the cross product of two edges is zero.  The edges are
 * differences of floats taken in double (exact unless the exponents are
 * far apart), the products and sums rounded once more: a triangle whose
 * three positions are collinear (or two equal) gives exactly zero. */
static int zero_area(const float *a, const float *b, const float *c)
{
    double u0 = (double)b[0] - a[0], u1 = (double)b[1] - a[1], u2 = (double)b[2] - a[2];
    double v0 = (double)c[0] - a[0], v1 = (double)c[1] - a[1], v2 = (double)c[2] - a[2];
    return u1 * v2 - u2 * v1 == 0.0 && u2 * v0 - u0 * v2 == 0.0 && u0 * v1 - u1 * v0 == 0.0;
}

int mesh_build_degenerate(float (*v)[3], uint32_t a, uint32_t b, uint32_t c)
{
    return a == b || b == c || a == c || zero_area(v[a], v[b], v[c]);
}

/* A box of positions: lo[a] <= x[a] <= hi[a]. */
typedef struct {
    float lo[3], hi[3];
} part_box;

/* The triangles a keep pass reads and compacts: t[0 .. nt) over the
 * positions v. */
typedef struct {
    float (*v)[3];
    uint32_t (*t)[3];
    uint32_t nt;
} tri_set;

/* Triangles [from, to) of s: the box of those kept (not degenerate) grown
 * in lo, hi and the number kept returned; each kept one copied to
 * out[0, kept) when out is not NULL (out may be s->t + from: each goes to
 * or below its own place), and keep[i - from] set to whether triangle i
 * is kept when keep is not NULL.  The box takes the first of equal values
 * (-0 and +0): folding parts in order gives what one pass gives. */
static uint32_t finish_part(const tri_set *s, uint32_t from, uint32_t to, float lo[3],
                            float hi[3], uint32_t (*out)[3], uint8_t *keep)
{
    /* the box in scalars, so that they stay in registers */
    float lx = lo[0], ly = lo[1], lz = lo[2], hx = hi[0], hy = hi[1], hz = hi[2];
    uint32_t kept = 0;
    for (uint32_t i = from; i < to; i++) {
        uint32_t t0 = s->t[i][0], t1 = s->t[i][1], t2 = s->t[i][2];
        const float *p[3] = {s->v[t0], s->v[t1], s->v[t2]};
        int k = !mesh_build_degenerate(s->v, t0, t1, t2);
        if (keep) keep[i - from] = (uint8_t)k;
        if (!k) continue;
        for (int c = 0; c < 3; c++) {
            float x = p[c][0], y = p[c][1], z = p[c][2];
            lx = x < lx ? x : lx, ly = y < ly ? y : ly, lz = z < lz ? z : lz;
            hx = x > hx ? x : hx, hy = y > hy ? y : hy, hz = z > hz ? z : hz;
        }
        if (out) out[kept][0] = t0, out[kept][1] = t1, out[kept][2] = t2;
        kept++;
    }
    lo[0] = lx, lo[1] = ly, lo[2] = lz, hi[0] = hx, hi[1] = hy, hi[2] = hz;
    return kept;
}

/* mesh_build_keep on every CPU for a large mesh: each part's box, count and
 * kept flags; then, when some triangles are degenerate, one pass moves the
 * kept ones down in place by the flags (a copy into a new array by every
 * CPU cost more than it saved: its fresh pages' faults). */
#define FINISH_PAR_MIN 65536 /* triangles: fewer are finished by one thread */
#define FINISH_PARTS 64

typedef struct {
    const tri_set *s;
    uint8_t *keep;      /* a triangle's flag: kept */
    atomic_uint next;   /* the next part to take */
    part_box box[FINISH_PARTS];
    uint32_t kept[FINISH_PARTS];
} finish_par;

static void finish_parts(void *ud, unsigned k, unsigned n)
{
    (void)k, (void)n;
    finish_par *fp = ud;
    uint64_t nt = fp->s->nt;
    /* relaxed: a counter; the parts are disjoint, par_run's join orders the results */
    for (uint32_t i; (i = atomic_fetch_add_explicit(&fp->next, 1, memory_order_relaxed)) <
                     FINISH_PARTS;) {
        uint32_t from = (uint32_t)(nt * i / FINISH_PARTS), to = (uint32_t)(nt * (i + 1) / FINISH_PARTS);
        part_box *box = &fp->box[i];
        box->lo[0] = box->lo[1] = box->lo[2] = FLT_MAX;
        box->hi[0] = box->hi[1] = box->hi[2] = -FLT_MAX;
        fp->kept[i] = finish_part(fp->s, from, to, box->lo, box->hi, NULL, fp->keep + from);
    }
}

uint32_t mesh_build_keep(float (*v)[3], uint32_t (*t)[3], uint32_t nt, float lo[3],
                         float hi[3])
{
    tri_set s = {v, t, nt};
    unsigned cpus = par_cpus();
    finish_par *fp = nt >= FINISH_PAR_MIN && cpus > 1 ? calloc(1, sizeof *fp) : NULL;
    if (fp && !(fp->keep = malloc(nt))) {
        free(fp);
        fp = NULL;
    }
    if (!fp) return finish_part(&s, 0, nt, lo, hi, t, NULL); /* one thread */
    fp->s = &s;
    atomic_init(&fp->next, 0);
    par_run(cpus, finish_parts, fp);
    uint32_t sum = 0;
    for (int i = 0; i < FINISH_PARTS; i++) { /* in order: the first of equal values */
        for (int a = 0; a < 3; a++) {
            const part_box *p = &fp->box[i];
            lo[a] = p->lo[a] < lo[a] ? p->lo[a] : lo[a];
            hi[a] = p->hi[a] > hi[a] ? p->hi[a] : hi[a];
        }
        sum += fp->kept[i];
    }
    if (sum < nt) { /* each kept one goes to or below its own place */
        const uint8_t *first = memchr(fp->keep, 0, nt);
        uint32_t k = (uint32_t)(first - fp->keep);
        for (uint32_t i = k; i < nt; i++)
            if (fp->keep[i]) memcpy(t[k++], t[i], sizeof *t);
    }
    free(fp->keep);
    free(fp);
    return sum;
}

int mesh_build_finish(mbuild *b, mesh_format f, mesh *out)
{
    part_box box = {{FLT_MAX, FLT_MAX, FLT_MAX}, {-FLT_MAX, -FLT_MAX, -FLT_MAX}};
    uint32_t kept = mesh_build_keep(b->v, b->t, b->nt, box.lo, box.hi);
    uint32_t dropped = b->nt - kept;
    if (!kept)
        return b->nt ? mesh_build_fail(b, -EINVAL, MESH_BUILD_NOWHERE, "no triangles: all %u are degenerate", b->nt)
                     : mesh_build_fail(b, -EINVAL, MESH_BUILD_NOWHERE, "no triangles");
    /* Give back what growth over-allocated (shrinking cannot fail the load). */
    void *p = b->cap_t > kept ? realloc(b->t, (size_t)kept * sizeof *b->t) : NULL;
    if (p) b->t = p;
    if (b->cap_v > b->nv && (p = realloc(b->v, (size_t)b->nv * sizeof *b->v))) b->v = p;
    *out = (mesh){.n_vertices = b->nv, .n_triangles = kept, .vertices = b->v,
                  .triangles = b->t, .n_degenerate = dropped, .format = f};
    memcpy(out->warning, b->warning, sizeof out->warning);
    memcpy(out->lo, box.lo, sizeof box.lo);
    memcpy(out->hi, box.hi, sizeof box.hi);
    b->v = NULL; /* *out owns the arrays now */
    b->t = NULL;
    mesh_build_free(b);
    return 0;
}

void mesh_build_free(mbuild *b)
{
    free(b->v);
    free(b->t);
    b->v = NULL;
    b->t = NULL;
    b->nv = b->nt = 0;
    b->cap_v = b->cap_t = 0;
}

/* A position's bits, -0 taken as +0 (-0 + 0 is +0), so the two zeros weld. */
static void position_bits(const float p[3], uint32_t bits[3])
{
    for (int k = 0; k < 3; k++) {
        float x = p[k] + 0.0f;
        memcpy(&bits[k], &x, 4);
    }
}

/* The welding table: open addressing, linear probing; a slot holds a
 * unique vertex's index and 32 bits of its hash, so that most probes that
 * miss do not read the vertex. */
typedef struct {
    uint32_t idx, tag;
} weld_slot;

typedef struct {
    weld_slot *slot;
    int bits;
    uint64_t mask;
} weld_table;

static int weld_alloc(weld_table *w, int bits)
{
    w->bits = bits;
    w->mask = ((uint64_t)1 << bits) - 1;
    w->slot = malloc((size_t)(w->mask + 1) * sizeof *w->slot);
    if (!w->slot) return -ENOMEM;
    memset(w->slot, 0xff, (size_t)(w->mask + 1) * sizeof *w->slot);
    return 0;
}

/* The slot of the vertex with these bits and hash: its own, or the empty
 * one where it goes. */
static weld_slot *weld_find(const weld_table *w, float (*v)[3], const uint32_t key[3], uint64_t h)
{
    uint32_t tag = (uint32_t)h;
    for (uint64_t i = h >> (64 - w->bits);; i = (i + 1) & w->mask) {
        weld_slot *s = &w->slot[i];
        if (s->idx == UINT32_MAX) return s;
        uint32_t other[3];
        if (s->tag == tag && (position_bits(v[s->idx], other), !memcmp(key, other, sizeof other)))
            return s;
    }
}

/* Twice the slots, the u unique vertices so far put back. */
static int weld_grow(weld_table *w, float (*v)[3], uint32_t u)
{
    weld_table bigger;
    if (weld_alloc(&bigger, w->bits + 1)) return -ENOMEM;
    for (uint32_t i = 0; i < u; i++) {
        uint32_t key[3];
        position_bits(v[i], key);
        uint64_t h = mesh_build_key_hash(key);
        *weld_find(&bigger, v, key, h) = (weld_slot){i, (uint32_t)h};
    }
    free(w->slot);
    *w = bigger;
    return 0;
}

int mesh_build_weld(mbuild *b)
{
    uint32_t n = b->nv;
    /* a closed mesh has about a sixth as many vertices as corners: start
     * there, and double when half full */
    int bits = 10;
    while (bits < 40 && ((uint64_t)1 << bits) < (uint64_t)n / 3) bits++;
    weld_table w;
    uint32_t *map = malloc((size_t)(n ? n : 1) * sizeof *map);
    if (!map || weld_alloc(&w, bits)) {
        free(map);
        return mesh_build_fail(b, -ENOMEM, MESH_BUILD_NOWHERE, "out of memory welding %u vertices", n);
    }
    /* Unique positions move down in place, in order of first appearance
     * (u <= i: a slot below i is never needed again). */
    uint32_t u = 0;
    for (uint32_t i = 0; i < n; i++) {
        uint32_t key[3];
        position_bits(b->v[i], key);
        uint64_t h = mesh_build_key_hash(key);
        weld_slot *s = weld_find(&w, b->v, key, h);
        if (s->idx != UINT32_MAX) {
            map[i] = s->idx;
            continue;
        }
        memmove(b->v[u], b->v[i], sizeof *b->v);
        *s = (weld_slot){u, (uint32_t)h};
        map[i] = u++;
        if ((uint64_t)u * 2 > w.mask + 1 && weld_grow(&w, b->v, u)) {
            free(map);
            return mesh_build_fail(b, -ENOMEM, MESH_BUILD_NOWHERE, "out of memory welding %u vertices", n);
        }
    }
    free(w.slot);
    for (uint32_t i = 0; i < b->nt; i++)
        for (int k = 0; k < 3; k++) b->t[i][k] = map[b->t[i][k]];
    free(map);
    b->nv = u;
    if (u > b->max_vert)
        return mesh_build_fail(b, -E2BIG, MESH_BUILD_NOWHERE, "%u distinct vertices: more than the limit of %u", u,
                       b->max_vert);
    return 0;
}

/* --------------------------------------------------------------------- text */

void mesh_text_next_line(mtext *t)
{
    const char *nl = memchr(t->p, '\n', (size_t)(t->end - t->p));
    t->p = nl ? nl + 1 : t->end;
}

size_t mesh_text_toklen(const mtext *t)
{
    const char *q = t->p;
    while (q < t->end && !mesh_text_space(*q)) q++;
    return (size_t)(q - t->p);
}

int mesh_text_word(mtext *t, const char *w, int nocase)
{
    size_t n = strlen(w);
    if ((size_t)(t->end - t->p) < n) return 0;
    if (nocase ? strncasecmp(t->p, w, n) : memcmp(t->p, w, n)) return 0;
    if (t->p + n < t->end && !mesh_text_space(t->p[n])) return 0;
    t->p += n;
    return 1;
}

const char *mesh_text_tokstr(const mtext *t, char buf[32])
{
    if (t->p == t->end) return "the end of the file";
    if (*t->p == '\n') return "the end of the line";
    size_t n = mesh_text_toklen(t), i;
    buf[0] = '\'';
    for (i = 0; i < n && i < 24; i++) {
        char c = t->p[i];
        buf[i + 1] = c >= 32 && c < 127 ? c : '?';
    }
    if (n > 24) buf[i++ + 1] = '~';
    buf[i + 1] = '\'';
    buf[i + 2] = '\0';
    return buf;
}

/* strtof on a terminated copy of the token: correctly rounded (glibc). */
int mesh_text_float_slow(mtext *t, float *out)
{
    size_t n = mesh_text_toklen(t);
    char tok[MESH_TEXT_TOKEN_MAX + 1];
    if (n == 0 || n > MESH_TEXT_TOKEN_MAX) return -EINVAL;
    memcpy(tok, t->p, n);
    tok[n] = '\0';
    char *e;
    float f = strtof(tok, &e);
    if (e != tok + n) return -EINVAL;
    if (!isfinite(f)) return -ERANGE;
    *out = f;
    t->p += n;
    return 0;
}

const double mesh_text_pow10[23] = {
    1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,  1e8,  1e9,  1e10, 1e11,
    1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};
const double mesh_text_pow10_neg[23] = {
    1e-0,  1e-1,  1e-2,  1e-3,  1e-4,  1e-5,  1e-6,  1e-7,  1e-8,  1e-9,  1e-10, 1e-11,
    1e-12, 1e-13, 1e-14, 1e-15, 1e-16, 1e-17, 1e-18, 1e-19, 1e-20, 1e-21, 1e-22};

int mesh_text_uint_token(mtext *t, uint64_t max, uint64_t *out)
{
    const char *s = t->p;
    if (!(s < t->end && mesh_text_digit(*s))) return -EINVAL;
    uint64_t v = 0;
    int over = 0;
    for (; s < t->end && mesh_text_digit(*s); s++) {
        uint64_t d = (uint64_t)(*s - '0');
        if (v > (UINT64_MAX - d) / 10) over = 1;
        else v = v * 10 + d;
    }
    if (s < t->end && !mesh_text_space(*s)) return -EINVAL;
    if (over || v > max) return -ERANGE;
    *out = v;
    t->p = s;
    return 0;
}

/* The '\n' bytes in [p, end).  SSE2 (every x86-64): 16 bytes compared at
 * once, the matches (-1 bytes) subtracted into byte counters that are
 * summed (psadbw) before they could wrap; elsewhere eight bytes at a time,
 * each '\n' byte made 0 and every zero byte's top bit set (exactly: no
 * carries), the top bits summed by a multiply. */
uint64_t mesh_text_count_newlines(const char *p, const char *end)
{
    uint64_t n = 0;
#ifdef __SSE2__
    const __m128i nl = _mm_set1_epi8('\n'), zero = _mm_setzero_si128();
    while (end - p >= 16) {
        __m128i acc = zero;
        for (int i = 0; i < 255 && end - p >= 16; i++, p += 16)
            acc = _mm_sub_epi8(acc, _mm_cmpeq_epi8(_mm_loadu_si128((const __m128i *)p), nl));
        __m128i s = _mm_sad_epu8(acc, zero);
        n += (uint64_t)_mm_cvtsi128_si64(s) + (uint64_t)_mm_cvtsi128_si64(_mm_unpackhi_epi64(s, s));
    }
#else
    const uint64_t lo7 = 0x7f7f7f7f7f7f7f7full, nl = 0x0a0a0a0a0a0a0a0aull;
    for (; end - p >= 8; p += 8) {
        uint64_t w;
        memcpy(&w, p, 8);
        w ^= nl;
        uint64_t zero = ~(((w & lo7) + lo7) | w | lo7) >> 7; /* 1 in each '\n' byte */
        n += zero * 0x0101010101010101ull >> 56;
    }
#endif
    for (; p < end; p++) n += *p == '\n';
    return n;
}

const char *mesh_text_part_start(const char *data, const char *end, uint32_t k, uint32_t parts)
{
    size_t len = (size_t)(end - data), at = (size_t)((uint64_t)len * k / parts);
    if (at == 0) return data;
    if (at >= len) return end;
    const char *nl = memchr(data + at - 1, '\n', len - at + 1);
    return nl ? nl + 1 : end;
}

/* What mesh_text_each_part's threads share. */
typedef struct {
    uint32_t nparts;
    int (*fn)(void *ud, uint32_t part);
    void *ud;
    /* The next part to take, and whether a part failed.  Relaxed: the
     * counter only hands out parts, the flag only stops the others early;
     * what the parts wrote, and the flag, are read after par_run's join. */
    atomic_uint next;
    atomic_int bad;
} parts_job;

static void parts_run(void *arg, unsigned k, unsigned n)
{
    (void)k, (void)n; /* the threads share one counter of parts */
    parts_job *j = arg;
    for (uint32_t i; !atomic_load_explicit(&j->bad, memory_order_relaxed) &&
                     (i = atomic_fetch_add_explicit(&j->next, 1, memory_order_relaxed)) < j->nparts;)
        if (j->fn(j->ud, i)) atomic_store_explicit(&j->bad, 1, memory_order_relaxed);
}

int mesh_text_each_part(uint32_t nparts, int (*fn)(void *ud, uint32_t part), void *ud)
{
    parts_job j = {.nparts = nparts, .fn = fn, .ud = ud};
    atomic_init(&j.next, 0);
    atomic_init(&j.bad, 0);
    par_run(par_cpus(), parts_run, &j);
    return atomic_load_explicit(&j.bad, memory_order_relaxed) ? -1 : 0;
}

typedef struct {
    const char *data, *end;
    uint32_t parts;
    uint64_t *first;
} lines_job;

static int count_lines(void *ud, uint32_t i)
{
    lines_job *l = ud;
    l->first[i] = mesh_text_count_newlines(mesh_text_part_start(l->data, l->end, i, l->parts),
                                           mesh_text_part_start(l->data, l->end, i + 1, l->parts));
    return 0;
}

uint64_t mesh_text_first_lines(const char *data, const char *end, uint32_t parts, uint64_t *first)
{
    lines_job l = {data, end, parts, first};
    (void)mesh_text_each_part(parts, count_lines, &l); /* counting never fails */
    uint64_t lines = 0;
    for (uint32_t i = 0; i <= parts; i++) {
        uint64_t c = i < parts ? first[i] : 0;
        first[i] = lines;
        lines += c;
    }
    return lines + (end > data && end[-1] != '\n'); /* a last line without its line end */
}
