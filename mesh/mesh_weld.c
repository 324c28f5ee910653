/* mesh_weld — merge the vertices of a loaded mesh that lie within eps of
 * each other (mesh_weld in mesh.h), so that its topology is judged on the
 * geometry rather than on how the file numbered its vertices.
 *
 * The merge is greedy in the file's order: vertex i goes to the first
 * earlier kept vertex (the lowest index) within eps of it, or is kept.
 * "Within eps" is dx^2 + dy^2 + dz^2 <= eps^2, the differences of the
 * float positions taken in double.  The kept vertices are more than eps
 * apart from each other, and the result depends on nothing but the
 * vertices' order.
 *
 * The kept vertices are found through a hash grid of cells of side h, a
 * hair over 2 eps (h = 2 eps (1 + 2^-10)), keyed by floor(x / h) on each
 * axis: a vertex within eps of another lies in one of the 8 cells nearest
 * it (merge_map), and since kept vertices are more than eps apart, a cell
 * holds a few of them at most, so the whole is O(n).  x / h is exact to
 * within 2^-13 of a cell while |x / h| < 2^40, inside the margin; beyond,
 * the floats on that axis are more than eps apart, so vertices within eps
 * have the same coordinate there and the same key.  That is why eps must
 * be 0 or at least MESH_WELD_MIN: below it, floats near 0 could crowd a
 * cell.  eps = 0 merges exactly equal positions (-0 equal to 0): a cell
 * is then a position, and only its own cell is looked in. */
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "huge.h"
#include "mesh_load.h"
#include "par.h"

/* A cell of the grid: its key, and its kept vertices as a list through
 * next[] (first and last, in index order). */
typedef struct {
    double key[3];
    uint32_t first, last;
} cell;

/* A slot of the table: a cell's index + 1 (0: empty) and the high half of
 * its key's hash, so that most probes that miss read no cell. */
typedef struct {
    uint32_t cell, tag;
} slot;

typedef struct {
    cell *cells; /* room for one per vertex */
    uint32_t n_cells;
    slot *slot;
    uint64_t mask;
    uint32_t *next; /* per kept vertex (its old index): the next in its cell */
} grid;

/* splitmix64's finaliser: every bit of x moves every bit of the result
 * (the keys' low mantissa bits are mostly zero: floats widened, or whole
 * numbers). */
static uint64_t mix(uint64_t x)
{
    x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
    x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
    return x ^ (x >> 31);
}

static uint64_t key_hash(const double k[3])
{
    uint64_t h = 0, b;
    for (int i = 0; i < 3; i++) {
        double x = k[i] + 0.0; /* -0 as 0 */
        memcpy(&b, &x, 8);
        h = mix(h ^ b);
    }
    return h;
}

/* The slot of the cell with key k (hash h): its own, or the empty one
 * where it goes. */
static slot *find_slot(const grid *g, const double k[3], uint64_t h)
{
    uint32_t tag = (uint32_t)(h >> 32);
    for (uint64_t i = h & g->mask;; i = (i + 1) & g->mask) {
        slot *s = &g->slot[i];
        if (!s->cell) return s;
        const double *c = g->cells[s->cell - 1].key;
        if (s->tag == tag && c[0] == k[0] && c[1] == k[1] && c[2] == k[2]) return s;
    }
}

static int grow_slots(grid *g)
{
    uint64_t size = (g->mask + 1) * 2;
    slot *sl = huge_calloc((size_t)size, sizeof *sl);
    if (!sl) return -ENOMEM;
    free(g->slot);
    g->slot = sl;
    g->mask = size - 1;
    for (uint32_t c = 0; c < g->n_cells; c++) {
        uint64_t h = key_hash(g->cells[c].key);
        *find_slot(g, g->cells[c].key, h) = (slot){c + 1, (uint32_t)(h >> 32)};
    }
    return 0;
}

/* File kept vertex v under key k (hash h). */
static int add_kept(grid *g, const double k[3], uint64_t h, uint32_t v)
{
    slot *s = find_slot(g, k, h);
    g->next[v] = UINT32_MAX;
    if (s->cell) {
        cell *c = &g->cells[s->cell - 1];
        g->next[c->last] = v;
        c->last = v;
        return 0;
    }
    cell *c = &g->cells[g->n_cells++];
    memcpy(c->key, k, sizeof c->key);
    c->first = c->last = v;
    *s = (slot){g->n_cells, (uint32_t)(h >> 32)};
    return (uint64_t)g->n_cells * 2 > g->mask + 1 ? grow_slots(g) : 0;
}

static double dist2(const float a[3], const float b[3])
{
    double dx = (double)a[0] - b[0], dy = (double)a[1] - b[1], dz = (double)a[2] - b[2];
    return dx * dx + dy * dy + dz * dz;
}

/* The lowest kept vertex within eps of v[i] in cell k, below best. */
static uint32_t in_cell(const grid *g, float (*v)[3], uint32_t i, const double k[3],
                        double eps2, uint32_t best)
{
    const slot *s = find_slot(g, k, key_hash(k));
    if (!s->cell) return best;
    /* the list is in index order: its first match is its lowest */
    for (uint32_t j = g->cells[s->cell - 1].first; j < best; j = g->next[j])
        if (dist2(v[j], v[i]) <= eps2) return j;
    return best;
}

/* map[i]: the kept vertex (old index) vertex i merges into.  Cells of side
 * h = 2 eps (1 + 2^-10): the ball of radius eps about a point reaches at
 * most one neighbour on each axis, the one on the side of the cell's
 * middle the point lies, so 8 cells are looked in (1 for eps = 0). */
static int merge_map(float (*v)[3], uint32_t n, double eps, uint32_t *map)
{
    grid g = {0};
    int bits = 10;
    while (bits < 40 && ((uint64_t)1 << bits) < 2 * (uint64_t)n) bits++;
    g.mask = ((uint64_t)1 << bits) - 1;
    /* a cell for each vertex at most; huge pages: the arrays are written
     * once, their faults would cost as much as the writes (huge.h) */
    g.slot = huge_calloc((size_t)g.mask + 1, sizeof *g.slot);
    g.next = huge_malloc((size_t)(n ? n : 1) * sizeof *g.next);
    g.cells = huge_malloc((size_t)(n ? n : 1) * sizeof *g.cells);
    int rc = g.slot && g.next && g.cells ? 0 : -ENOMEM;
    double h = 2 * eps * (1 + 0x1p-10), eps2 = eps * eps;
    for (uint32_t i = 0; !rc && i < n; i++) {
        double k[3], side[3] = {0, 0, 0};
        for (int a = 0; a < 3; a++) {
            double q = v[i][a] / h;
            k[a] = eps > 0 ? floor(q) : v[i][a] + 0.0;
            if (eps > 0) side[a] = q - k[a] < 0.5 ? -1 : 1;
        }
        uint32_t best = UINT32_MAX;
        for (int c = 0; c < (eps > 0 ? 8 : 1); c++) {
            double nk[3] = {k[0] + (c & 1) * side[0], k[1] + (c >> 1 & 1) * side[1],
                            k[2] + (c >> 2) * side[2]};
            best = in_cell(&g, v, i, nk, eps2, best);
        }
        map[i] = best == UINT32_MAX ? i : best;
        if (best == UINT32_MAX) rc = add_kept(&g, k, key_hash(k), i);
    }
    free(g.cells);
    free(g.slot);
    free(g.next);
    return rc;
}

/* ---- eps = 0 on every CPU ----
 * Exactly equal positions, split by their key's hash into one part a
 * thread: each thread reads every vertex in order, files those of its part
 * in a table of its own (a slot: the first vertex of a position + 1, and
 * its hash's high half) and sets map[i] for them alone.  A position's
 * vertices are all in one part, met in index order, so its first is the
 * lowest index: the map is the one-thread merge's, whatever the number of
 * parts. */
#define WELD_PAR_MIN 65536u /* vertices: fewer are merged on one thread */
#define WELD_PAR_MAX 8u     /* threads at most: each reads every vertex */

_Atomic uint64_t mesh_weld_par_runs;

typedef struct {
    float (*v)[3];
    uint32_t n;
    uint32_t *map;
    atomic_int failed; /* a part's table could not be had */
} exact_par;

static void exact_key(const float p[3], double k[3])
{
    for (int a = 0; a < 3; a++) k[a] = p[a] + 0.0; /* -0 as 0 */
}

static void exact_part(void *ud, unsigned part, unsigned parts)
{
    exact_par *x = ud;
    uint64_t size = 16;
    while (size < 2 * ((uint64_t)x->n / parts + 1)) size *= 2;
    slot *sl = huge_calloc((size_t)size, sizeof *sl);
    if (!sl) {
        /* relaxed: read after par_run's join */
        atomic_store_explicit(&x->failed, 1, memory_order_relaxed);
        return;
    }
    uint64_t mask = size - 1;
    for (uint32_t i = 0; i < x->n; i++) {
        double k[3];
        exact_key(x->v[i], k);
        uint64_t h = key_hash(k);
        /* the part from the hash's high half, the slot from its low bits */
        if ((((h >> 32) * parts) >> 32) != part) continue;
        uint32_t tag = (uint32_t)(h >> 32), j = i;
        for (uint64_t q = h & mask;; q = (q + 1) & mask) {
            slot *s = &sl[q];
            if (!s->cell) {
                *s = (slot){i + 1, tag};
                break;
            }
            double c[3];
            exact_key(x->v[s->cell - 1], c);
            if (s->tag == tag && c[0] == k[0] && c[1] == k[1] && c[2] == k[2]) {
                j = s->cell - 1;
                break;
            }
        }
        x->map[i] = j;
    }
    free(sl);
}

/* merge_map for eps = 0 on several threads; 1 when it could not run
 * (the caller merges on one). */
static int merge_exact_par(float (*v)[3], uint32_t n, uint32_t *map)
{
    unsigned cpus = par_cpus();
    if (n < WELD_PAR_MIN || cpus < 2) return 1;
    exact_par x = {.v = v, .n = n, .map = map};
    atomic_init(&x.failed, 0);
    par_run(cpus < WELD_PAR_MAX ? cpus : WELD_PAR_MAX, exact_part, &x);
    /* relaxed: par_run's join orders the parts' stores before it */
    if (atomic_load_explicit(&x.failed, memory_order_relaxed)) return 1;
    /* relaxed: a counter for the tests */
    atomic_fetch_add_explicit(&mesh_weld_par_runs, 1, memory_order_relaxed);
    return 0;
}

/* Whether a triangle is left once merged (map: old indices). */
static int any_left(const mesh *m, const uint32_t *map)
{
    for (uint32_t i = 0; i < m->n_triangles; i++) {
        const uint32_t *t = m->triangles[i];
        if (!mesh_build_degenerate(m->vertices, map[t[0]], map[t[1]], map[t[2]])) return 1;
    }
    return 0;
}

/* In place: the kept vertices moved down in order (map[i] becomes vertex
 * i's new index), the triangles renumbered, then the degenerate ones
 * dropped and the box taken again on every CPU (mesh_build_keep: the
 * dragon's 871,000 triangles took 10-15 ms of one thread here, the largest
 * serial window of its distance job's start). */
static void apply(mesh *m, uint32_t *map)
{
    uint32_t u = 0;
    for (uint32_t i = 0; i < m->n_vertices; i++) {
        if (map[i] != i) {
            map[i] = map[map[i]]; /* its kept vertex, earlier: renumbered already */
            continue;
        }
        memmove(m->vertices[u], m->vertices[i], sizeof *m->vertices);
        map[i] = u++;
    }
    for (uint32_t i = 0; i < m->n_triangles; i++)
        for (int k = 0; k < 3; k++) m->triangles[i][k] = map[m->triangles[i][k]];
    float lo[3] = {FLT_MAX, FLT_MAX, FLT_MAX}, hi[3] = {-FLT_MAX, -FLT_MAX, -FLT_MAX};
    uint32_t kept = mesh_build_keep(m->vertices, m->triangles, m->n_triangles, lo, hi);
    m->n_degenerate += m->n_triangles - kept;
    m->n_vertices = u;
    m->n_triangles = kept;
    memcpy(m->lo, lo, sizeof lo);
    memcpy(m->hi, hi, sizeof hi);
}

int mesh_weld(mesh *m, double eps, uint32_t *merged)
{
    if (!(eps == 0 || (eps >= MESH_WELD_MIN && eps <= MESH_WELD_MAX))) return -EINVAL;
    uint32_t *map = huge_malloc((size_t)m->n_vertices * sizeof *map + 1);
    if (!map) return -ENOMEM;
    int rc = eps == 0 && !merge_exact_par(m->vertices, m->n_vertices, map)
                 ? 0
                 : merge_map(m->vertices, m->n_vertices, eps, map);
    if (!rc && !any_left(m, map)) rc = -EINVAL; /* the mesh stays as it was */
    if (rc) {
        free(map);
        return rc;
    }
    uint32_t n = m->n_vertices;
    apply(m, map);
    free(map);
    if (merged) *merged = n - m->n_vertices;
    /* give back what the merge freed (shrinking cannot fail the weld) */
    void *p = realloc(m->vertices, (size_t)m->n_vertices * sizeof *m->vertices);
    if (p) m->vertices = p;
    if ((p = realloc(m->triangles, (size_t)m->n_triangles * sizeof *m->triangles)))
        m->triangles = p;
    return 0;
}
