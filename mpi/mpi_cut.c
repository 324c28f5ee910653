/* The cut of a job into subtrees, and rank 0's book of bricks
 * (mpi_part.h). */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include <xxhash.h>

#include "mpi_part.h"
#include "subdiv.h"

uint32_t mpi_node_level(const vod_layout *L, int depth, int s)
{
    if (s >= depth || s <= (int)L->brick_log2) return L->height - 1;
    return (uint32_t)s - L->brick_log2;
}

typedef struct {
    grid_octant *v;
    size_t n, cap;
    int rc;
} octants;

static int keep_octant(void *ud, const grid_octant *o)
{
    octants *a = ud;
    if (a->n == a->cap) {
        size_t cap = a->cap ? 2 * a->cap : 64;
        grid_octant *v = realloc(a->v, cap * sizeof *v);
        if (!v) return a->rc = -ENOMEM;
        a->v = v, a->cap = cap;
    }
    a->v[a->n++] = *o;
    return 0;
}

/* The kept children of every octant of cur, in preorder (cur is). */
static int next_level(subdiv_kernel *k, const octants *cur, octants *next)
{
    subdiv_sink sink = {.octant = keep_octant, .ud = next};
    for (size_t i = 0; i < cur->n; i++) {
        int rc = subdiv_children(k, cur->v[i], &sink);
        if (rc) return next->rc ? next->rc : rc;
    }
    return 0;
}

int mpi_cut_make(const expr_tape *tape, const grid_spec *g, const vod_layout *L,
                 size_t target, mpi_cut *out)
{
    memset(out, 0, sizeof *out);
    expr_vm *vm;
    int rc = expr_vm_new(tape, g->depth, &vm);
    if (rc) return rc;
    subdiv_kernel k;
    subdiv_kernel_init(&k, vm, g);
    octants cur = {0};
    rc = keep_octant(&cur, &(grid_octant){0, 0, 0, (uint16_t)g->depth});
    int level = g->depth;
    /* children of level >= brick_log2 + 1 only, so level > brick_log2 + 1 */
    while (!rc && cur.n && cur.n < target && level > (int)L->brick_log2 + 1) {
        octants next = {0};
        rc = next_level(&k, &cur, &next);
        free(cur.v);
        cur = next;
        level--;
    }
    out->tested = k.tested;
    expr_vm_free(vm);
    if (rc) {
        free(cur.v);
        return rc;
    }
    out->oct = cur.v;
    out->n = cur.n;
    out->level = level;
    out->node_level = mpi_node_level(L, g->depth, level);
    return 0;
}

/* Octants of level s meeting the grid along axis a. */
static uint32_t along(const grid_spec *g, int a, int s)
{
    return (g->res[a] + (1u << s) - 1) >> s;
}

static uint64_t grid_tasks(const grid_spec *g, int s, int columns)
{
    return (uint64_t)along(g, 0, s) * along(g, 1, s) * (columns ? 1 : along(g, 2, s));
}

int mpi_cut_grid(const grid_spec *g, const vod_layout *L, size_t target, int min_level,
                 int columns, mpi_cut *out)
{
    memset(out, 0, sizeof *out);
    int s = g->depth, floor_level = (int)L->brick_log2 + 1;
    if (floor_level < min_level) floor_level = min_level;
    while (s - 1 >= floor_level && grid_tasks(g, s, columns) < target) s--;
    uint64_t n = grid_tasks(g, s, columns);
    if (!(out->oct = malloc(n * sizeof *out->oct))) return -ENOMEM;
    uint32_t nz = columns ? 1 : along(g, 2, s);
    for (uint32_t z = 0; z < nz; z++)
        for (uint32_t y = 0; y < along(g, 1, s); y++)
            for (uint32_t x = 0; x < along(g, 0, s); x++)
                out->oct[out->n++] = (grid_octant){(uint16_t)(x << s), (uint16_t)(y << s),
                                                   (uint16_t)(z << s), (uint16_t)s};
    out->level = s;
    out->node_level = mpi_node_level(L, g->depth, s);
    return 0;
}

void mpi_cut_free(mpi_cut *c)
{
    free(c->oct);
    memset(c, 0, sizeof *c);
}

/* ---- the book ---- */

void mpi_key(const uint8_t *data, size_t n, uint64_t key[2])
{
    XXH128_hash_t h = XXH3_128bits(data, n);
    key[0] = h.low64;
    key[1] = h.high64;
}

void mpi_book_init(mpi_book *b)
{
    memset(b, 0, sizeof *b);
}

void mpi_book_free(mpi_book *b)
{
    free(b->slot);
    memset(b, 0, sizeof *b);
}

static int same(const mpi_book_entry *e, const mpi_rec *r)
{
    return e->key[0] == r->key[0] && e->key[1] == r->key[1] && e->hash == r->hash &&
           e->size == r->size;
}

static mpi_book_entry *probe(mpi_book_entry *slot, size_t cap, const mpi_rec *r)
{
    size_t j = (size_t)(r->key[0] ^ r->key[1] >> 17) & (cap - 1);
    while (slot[j].state && !same(&slot[j], r)) j = (j + 1) & (cap - 1);
    return &slot[j];
}

/* Twice the slots, every entry moved; kept at most half full so that a
 * probe always ends on a free slot. */
static int grow(mpi_book *b)
{
    size_t cap = b->cap ? 2 * b->cap : 4096;
    mpi_book_entry *slot = calloc(cap, sizeof *slot);
    if (!slot) return -ENOMEM;
    for (size_t i = 0; i < b->cap; i++) {
        if (!b->slot[i].state) continue;
        mpi_rec r = {.key = {b->slot[i].key[0], b->slot[i].key[1]},
                     .hash = b->slot[i].hash, .size = b->slot[i].size};
        *probe(slot, cap, &r) = b->slot[i];
    }
    free(b->slot);
    b->slot = slot;
    b->cap = cap;
    return 0;
}

mpi_book_entry *mpi_book_get(mpi_book *b, const mpi_rec *r, int *fresh)
{
    *fresh = 0;
    if (2 * (b->used + 1) > b->cap && grow(b)) return NULL;
    mpi_book_entry *e = probe(b->slot, b->cap, r);
    if (e->state) return e;
    *e = (mpi_book_entry){.key = {r->key[0], r->key[1]}, .hash = r->hash,
                          .size = r->size, .state = 1};
    b->used++;
    *fresh = 1;
    return e;
}
