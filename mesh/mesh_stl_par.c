/* mesh_stl_par — a large binary STL read and welded on several threads
 * (mesh_stl_binary_par in mesh_load.h), into the mesh that the one-thread
 * path (mesh_stl.c's parse_binary, then mesh_build_weld) makes, bit for
 * bit: the distinct positions (-0 as +0) in the order of their first
 * corners, each with its first corner's bits, and every triangle's
 * corners renumbered to them.
 *
 * The positions are split by their hash into P parts, one a thread.  Each
 * thread reads every corner in the file's order and welds those of its
 * part: a table of its distinct positions, each corner's distinct index in
 * order, each distinct position's first corner, and a bit per corner set
 * for the first ones.  A position's first corner is the first of its
 * part's corners, so it is the first in the file whatever P is.  Thread k
 * also notes the part of each corner of its k-th share of the file.  Then
 * the parts' bits are merged and counted per 64 corners: a first corner's
 * rank among all first corners, its vertex's index, is a sum and a
 * popcount.  Each part turns its first corners into ranks; last, ranges of
 * triangles are written in parallel, each corner's index read at its
 * part's cursor and the first corners' positions put at their ranks.
 *
 * The probes' cache misses are what the weld costs: each thread asks for
 * a batch of slots before it probes them, so that the misses overlap; the
 * page faults of the arrays, written once, are the rest (huge_malloc).
 * The CPU this costs on this project's 2-core machine is the one-thread
 * path's or less (no array of 3n raw vertices), plus every thread's read
 * of every position to find its part: hence at most STL_PAR_MAX threads. */
#include <errno.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "bits.h"
#include "huge.h"
#include "mesh_load.h"
#include "par.h"

#define STL_PAR_MIN 16384 /* triangles: fewer go to the one-thread path */
#define STL_PAR_MAX 8     /* threads at most: each reads every corner */
#define STL_RANGES 64     /* ranges of triangles written in turn */
#define STL_BATCH 16      /* triangles whose misses are asked for at once */

_Atomic uint64_t mesh_stl_par_runs;

/* A slot of a part's table: a distinct position's index in the part + 1
 * (0: the slot is empty) and the low half of its key's hash, so that most
 * probes that miss read no position. */
typedef struct {
    uint32_t id, tag;
} stl_slot;

/* A distinct position of a part: its key, and its first corner (then its
 * rank: its vertex's index). */
typedef struct {
    uint32_t key[3], first;
} stl_pos;

typedef struct {
    stl_slot *slot;
    uint64_t mask;
    int bits;
    uint32_t *idx;     /* per corner of the part, in order: its distinct index */
    size_t n_idx, cap_idx;
    stl_pos *pos;      /* the distinct positions, in the order of their first corners */
    size_t n_pos, cap_pos;
    uint64_t *firsts;  /* a bit per corner of the file: the first of its position */
    uint32_t start[STL_RANGES + 1]; /* idx's length at each range's first triangle */
    int fail;          /* a coordinate not finite, or no memory */
} stl_part;

typedef struct {
    const unsigned char *u;
    uint32_t n;        /* triangles */
    unsigned parts;
    stl_part part[STL_PAR_MAX];
    uint8_t *part_of;  /* per corner: its part */
    const uint64_t *firsts; /* the parts' bits merged (part 0's) */
    uint32_t *rank;    /* per 64 corners: the first corners before them */
    float (*v)[3];
    uint32_t (*t)[3];
    atomic_uint next;  /* the next range to write */
} stl_par;

/* Triangle i's corner c: its position's bits into x, its welding key (the
 * bits, -0 as +0: mesh_build_weld's) into key; -1 when a coordinate is
 * not finite. */
static inline int corner(const stl_par *s, uint32_t i, int c, uint32_t x[3], uint32_t key[3])
{
    const unsigned char *q = s->u + 84 + 50 * (size_t)i + 12 + 12 * c;
    int bad = 0;
    for (int a = 0; a < 3; a++) {
        x[a] = bits_le32(q + 4 * a);
        bad |= (x[a] & 0x7f800000u) == 0x7f800000u;
        key[a] = x[a] == 0x80000000u ? 0 : x[a];
    }
    return -bad;
}

/* The part of a key's hash: its low half (the table's index is its top
 * bits, at most 40). */
static unsigned part_of(uint64_t h, unsigned parts)
{
    return (unsigned)((uint32_t)h * (uint64_t)parts >> 32);
}

static uint32_t range_lo(const stl_par *s, unsigned r)
{
    return (uint32_t)((uint64_t)s->n * r / STL_RANGES);
}

/* The first corners before corner c. */
static uint32_t rank_of(const stl_par *s, uint32_t c)
{
    return s->rank[c >> 6] + bits_popcount64(s->firsts[c >> 6] & ((1ull << (c & 63)) - 1));
}

/* arr (of *cap items of sz bytes, n used) with room for one more: itself,
 * or twice the room; NULL when there is no memory (arr is kept). */
static void *room(void *arr, size_t *cap, size_t n, size_t sz)
{
    if (n < *cap) return arr;
    void *p = realloc(arr, 2 * *cap * sz);
    if (p) *cap *= 2;
    return p;
}

/* The slot of key (hash h): its own, or the empty one where it goes. */
static stl_slot *slot_find(const stl_part *p, const uint32_t key[3], uint64_t h)
{
    uint32_t tag = (uint32_t)h;
    for (uint64_t i = h >> (64 - p->bits);; i = (i + 1) & p->mask) {
        stl_slot *s = &p->slot[i];
        if (!s->id) return s;
        const uint32_t *k = p->pos[s->id - 1].key;
        if (s->tag == tag && k[0] == key[0] && k[1] == key[1] && k[2] == key[2]) return s;
    }
}

static int slot_alloc(stl_part *p, int bits)
{
    p->bits = bits;
    p->mask = ((uint64_t)1 << bits) - 1;
    size_t bytes = ((size_t)p->mask + 1) * sizeof *p->slot;
    if (!(p->slot = huge_malloc(bytes))) return -ENOMEM;
    memset(p->slot, 0, bytes);
    return 0;
}

/* Twice the slots, the distinct positions so far put back. */
static int slot_grow(stl_part *p)
{
    stl_part bigger = *p;
    if (slot_alloc(&bigger, p->bits + 1)) return -ENOMEM;
    for (size_t j = 0; j < p->n_pos; j++) {
        const uint32_t *k = p->pos[j].key;
        uint64_t h = mesh_build_key_hash(k);
        *slot_find(&bigger, k, h) = (stl_slot){(uint32_t)j + 1, (uint32_t)h};
    }
    free(p->slot);
    p->slot = bigger.slot, p->mask = bigger.mask, p->bits = bigger.bits;
    return 0;
}

/* Corner c (key, hash h) of the part: its distinct index appended. */
static int part_add(stl_part *p, const uint32_t key[3], uint64_t h, uint32_t c)
{
    stl_slot *s = slot_find(p, key, h);
    uint32_t j = s->id - 1;
    if (!s->id) {
        stl_pos *ps = room(p->pos, &p->cap_pos, p->n_pos, sizeof *p->pos);
        if (!ps) return -ENOMEM;
        p->pos = ps;
        j = (uint32_t)p->n_pos;
        p->pos[p->n_pos++] = (stl_pos){{key[0], key[1], key[2]}, c};
        p->firsts[c >> 6] |= 1ull << (c & 63);
        *s = (stl_slot){j + 1, (uint32_t)h};
        if ((uint64_t)p->n_pos * 2 > p->mask + 1 && slot_grow(p)) return -ENOMEM;
    }
    uint32_t *x = room(p->idx, &p->cap_idx, p->n_idx, sizeof *p->idx);
    if (!x) return -ENOMEM;
    p->idx = x;
    p->idx[p->n_idx++] = j;
    return 0;
}

/* A part's arrays, sized for its share of n triangles' corners: about a
 * sixth of them distinct on a closed mesh, the table twice that. */
static int part_alloc(stl_part *p, uint32_t n, unsigned parts)
{
    uint64_t corners = 3 * (uint64_t)n, share = corners / parts;
    int bits = 10;
    while (bits < 40 && ((uint64_t)1 << bits) < share / 3) bits++;
    p->cap_idx = share + share / 8 + 1024;
    p->cap_pos = share / 4 + 1024;
    p->idx = huge_malloc(p->cap_idx * sizeof *p->idx);
    p->pos = huge_malloc(p->cap_pos * sizeof *p->pos);
    p->firsts = calloc(corners / 64 + 1, sizeof *p->firsts);
    return p->idx && p->pos && p->firsts && !slot_alloc(p, bits) ? 0 : -ENOMEM;
}

/* A corner of a part, its slot asked for ahead of its probe. */
typedef struct {
    uint32_t key[3], c;
    uint64_t h;
} stl_corner;

/* Part k's corners of triangles [lo, end) welded in order, a batch of
 * slots asked for before they are probed; the part of each corner of
 * [mine_lo, mine_end) noted.  0, -1 (a coordinate not finite), -ENOMEM. */
static int weld_range(stl_par *s, unsigned k, uint32_t lo, uint32_t end)
{
    stl_part *p = &s->part[k];
    uint32_t mine_lo = (uint32_t)((uint64_t)s->n * k / s->parts) * 3,
             mine_end = (uint32_t)((uint64_t)s->n * (k + 1) / s->parts) * 3;
    stl_corner b[STL_BATCH * 3];
    unsigned nb = 0;
    for (uint32_t i = lo; i < end; i++) {
        for (int c = 0; c < 3; c++) {
            uint32_t x[3];
            stl_corner *q = &b[nb];
            if (corner(s, i, c, x, q->key)) return -1;
            q->h = mesh_build_key_hash(q->key);
            q->c = 3 * i + (uint32_t)c;
            unsigned part = part_of(q->h, s->parts);
            if (q->c - mine_lo < mine_end - mine_lo) s->part_of[q->c] = (uint8_t)part;
            if (part != k) continue;
            __builtin_prefetch(&p->slot[q->h >> (64 - p->bits)]);
            nb++;
        }
        if (nb + 3 <= 3 * STL_BATCH && i + 1 < end) continue;
        for (unsigned j = 0; j < nb; j++)
            if (part_add(p, b[j].key, b[j].h, b[j].c)) return -ENOMEM;
        nb = 0;
    }
    return 0;
}

/* Thread k: every corner read, part k's welded. */
static void weld_part(void *ud, unsigned k, unsigned n)
{
    (void)n;
    stl_par *s = ud;
    stl_part *p = &s->part[k];
    if (part_alloc(p, s->n, s->parts)) {
        p->fail = 1;
        return;
    }
    for (unsigned r = 0; r < STL_RANGES; r++) {
        p->start[r] = (uint32_t)p->n_idx;
        if (weld_range(s, k, range_lo(s, r), range_lo(s, r + 1))) {
            p->fail = 1;
            return;
        }
    }
    p->start[STL_RANGES] = (uint32_t)p->n_idx;
}

/* Thread k: part k's first corners turned into their ranks. */
static void rank_part(void *ud, unsigned k, unsigned n)
{
    (void)n;
    stl_par *s = ud;
    stl_part *p = &s->part[k];
    for (size_t j = 0; j < p->n_pos; j++) p->pos[j].first = rank_of(s, p->pos[j].first);
}

/* Range r's triangles: each corner's vertex, and the positions of the
 * first corners at their ranks; a batch of corners' distinct positions
 * asked for before their ranks are read. */
static void write_range(const stl_par *s, unsigned r)
{
    uint32_t at[STL_PAR_MAX], lo = range_lo(s, r), end = range_lo(s, r + 1);
    for (unsigned q = 0; q < s->parts; q++) at[q] = s->part[q].start[r];
    uint32_t next = rank_of(s, 3 * lo);
    const stl_pos *b[3 * STL_BATCH];
    for (uint32_t c0 = 3 * lo, c1; c0 < 3 * end; c0 = c1) {
        c1 = 3 * end - c0 < 3 * STL_BATCH ? 3 * end : c0 + 3 * STL_BATCH;
        for (uint32_t c = c0; c < c1; c++) {
            const stl_part *p = &s->part[s->part_of[c]];
            b[c - c0] = &p->pos[p->idx[at[s->part_of[c]]++]];
            __builtin_prefetch(b[c - c0]);
        }
        for (uint32_t c = c0; c < c1; c++) {
            s->t[c / 3][c % 3] = b[c - c0]->first;
            uint32_t x[3], key[3];
            if (s->firsts[c >> 6] >> (c & 63) & 1 && !corner(s, c / 3, (int)(c % 3), x, key))
                memcpy(s->v[next++], x, sizeof x);
        }
    }
}

/* Ranges of triangles taken in turn by the threads. */
static void write_ranges(void *ud, unsigned k, unsigned n)
{
    (void)k, (void)n;
    stl_par *s = ud;
    /* relaxed: a counter; the ranges are disjoint, par_run's join orders the results */
    for (unsigned r; (r = atomic_fetch_add_explicit(&s->next, 1, memory_order_relaxed)) < STL_RANGES;)
        write_range(s, r);
}

/* The parts' bits merged into part 0's, counted per 64 corners into
 * s->rank; the distinct positions' count (or -ENOMEM). */
static int64_t merge_firsts(stl_par *s)
{
    size_t words = 3 * (size_t)s->n / 64 + 1;
    uint64_t *f = s->part[0].firsts;
    if (!(s->rank = malloc(words * sizeof *s->rank))) return -ENOMEM;
    uint64_t sum = 0;
    for (size_t w = 0; w < words; w++) {
        for (unsigned q = 1; q < s->parts; q++) f[w] |= s->part[q].firsts[w];
        s->rank[w] = (uint32_t)sum;
        sum += bits_popcount64(f[w]);
    }
    s->firsts = f;
    return (int64_t)sum;
}

static void par_free(stl_par *s)
{
    for (unsigned q = 0; q < s->parts; q++) {
        free(s->part[q].slot);
        free(s->part[q].idx);
        free(s->part[q].pos);
        free(s->part[q].firsts);
    }
    free(s->part_of);
    free(s->rank);
    free(s->v);
    free(s->t);
    free(s);
}

/* The parts welded, the arrays made: 1 when b holds the mesh. */
static int weld_all(stl_par *s, mbuild *b)
{
    if (!(s->part_of = huge_malloc(3 * (size_t)s->n))) return 0;
    par_run(s->parts, weld_part, s);
    for (unsigned q = 0; q < s->parts; q++)
        if (s->part[q].fail) return 0;
    int64_t u = merge_firsts(s);
    if (u < 0 || u > b->max_vert) return 0; /* the one-thread path says why */
    s->v = huge_malloc((size_t)(u ? u : 1) * sizeof *s->v);
    s->t = huge_malloc((size_t)s->n * sizeof *s->t);
    if (!s->v || !s->t) return 0;
    par_run(s->parts, rank_part, s);
    atomic_init(&s->next, 0);
    par_run(s->parts, write_ranges, s);
    b->v = s->v, b->nv = (uint32_t)u, b->cap_v = (size_t)u;
    b->t = s->t, b->nt = s->n, b->cap_t = s->n;
    s->v = NULL, s->t = NULL; /* b's now */
    return 1;
}

int mesh_stl_binary_par(const unsigned char *u, uint32_t n, mbuild *b)
{
    unsigned threads = b->stl_threads ? b->stl_threads : par_cpus();
    if (threads == MESH_STL_SERIAL || n < STL_PAR_MIN || n > b->max_tri || n > UINT32_MAX / 3 ||
        b->nv || b->nt)
        return 0;
    if (threads > STL_PAR_MAX) threads = STL_PAR_MAX;
    stl_par *s = calloc(1, sizeof *s);
    if (!s) return 0;
    s->u = u, s->n = n, s->parts = threads;
    int done = weld_all(s, b);
    par_free(s);
    if (done) /* relaxed: a count for the tests, which read it after the parse */
        atomic_fetch_add_explicit(&mesh_stl_par_runs, 1, memory_order_relaxed);
    return done;
}
