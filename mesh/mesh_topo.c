/* mesh_topo — a mesh's edges, boundary, manifoldness, orientation,
 * components and volume (mesh_topology in mesh.h).
 *
 * Each triangle gives three edge uses.  They are grouped by edge with a
 * counting sort on the lower vertex index (one bucket a vertex), then a
 * sort of each bucket by the higher index (mesh_edges: a stamped slot per
 * higher vertex instead): buckets hold a vertex's edges towards higher
 * vertices, a handful in a usual mesh, so the whole is O(n) and touches
 * memory in two streaming passes and one scatter.  Triangles
 * that share an edge are joined in a union-find for the components;
 * mesh_edges, for jobs, does without. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "huge.h"
#include "mesh.h"

/* One use of edge (lo, hi), filed under lo: the triangle, and whether it
 * goes from lo to hi (bit 0 of td: td = tri << 1 | forward). */
typedef struct {
    uint32_t hi, td;
} edge_use;

static int cmp_use(const void *a, const void *b)
{
    const edge_use *x = a, *y = b;
    if (x->hi != y->hi) return x->hi < y->hi ? -1 : 1;
    return (x->td > y->td) - (x->td < y->td);
}

static void sort_bucket(edge_use *e, size_t n)
{
    if (n > 32) {
        qsort(e, n, sizeof *e, cmp_use);
        return;
    }
    for (size_t i = 1; i < n; i++) {
        edge_use x = e[i];
        size_t j = i;
        for (; j > 0 && e[j - 1].hi > x.hi; j--) e[j] = e[j - 1];
        e[j] = x;
    }
}

static uint32_t find(uint32_t *parent, uint32_t i)
{
    while (parent[i] != i) {
        parent[i] = parent[parent[i]]; /* path halving */
        i = parent[i];
    }
    return i;
}

static void join(uint32_t *parent, uint32_t a, uint32_t b)
{
    a = find(parent, a);
    b = find(parent, b);
    /* the lower root wins: deterministic, and the trees stay shallow
     * enough with path halving */
    if (a < b) parent[b] = a;
    else if (b < a) parent[a] = b;
}

/* The edges of one lower vertex's bucket, sorted: count them. */
static void count_bucket(const edge_use *e, size_t n, uint32_t *parent, mesh_topo *out)
{
    for (size_t i = 0; i < n;) {
        size_t j = i + 1;
        while (j < n && e[j].hi == e[i].hi) j++;
        size_t k = j - i;
        out->edges++;
        if (k == 1) out->open++;
        else if (k > 2) out->nonmanifold++;
        else if ((e[i].td & 1) == (e[i + 1].td & 1))
            out->inconsistent++;
        for (size_t x = i + 1; x < j; x++) join(parent, e[i].td >> 1, e[x].td >> 1);
        i = j;
    }
}

/* Signed volume by the divergence theorem: the sum of the tetrahedra from
 * the centre of the bounding box (near the mesh: less cancellation than
 * from the origin) to each triangle. */
static double signed_volume(const mesh *m)
{
    double c[3], sum = 0;
    for (int k = 0; k < 3; k++) c[k] = ((double)m->lo[k] + m->hi[k]) / 2;
    for (uint32_t i = 0; i < m->n_triangles; i++) {
        double p[3][3];
        for (int v = 0; v < 3; v++)
            for (int k = 0; k < 3; k++) p[v][k] = m->vertices[m->triangles[i][v]][k] - c[k];
        sum += p[0][0] * (p[1][1] * p[2][2] - p[1][2] * p[2][1]) +
               p[0][1] * (p[1][2] * p[2][0] - p[1][0] * p[2][2]) +
               p[0][2] * (p[1][0] * p[2][1] - p[1][1] * p[2][0]);
    }
    return sum / 6;
}

/* mesh_edges: the same grouping with 4-byte uses, the higher vertex and
 * the direction (hi << 1 | forward), and no triangle: what a job reports
 * needs no components, so no union-find, and half the memory to scatter.
 *
 * The uses of an edge (lo, hi) all lie in lo's bucket, and the buckets are
 * read in order of lo: so a slot per higher vertex hi, stamped with the lo
 * whose bucket last wrote it, tells an edge's first use (a stale stamp)
 * from its later ones and counts them, with no sort and no branch on the
 * keys (a sort of a handful of keys mispredicts most of its compares).
 * A slot: lo << 32 | same-way-twice << 3 | uses (3 for more) << 1 | the
 * first use's direction.  Each use adds what its count changes: the first
 * an edge, open; the second closes it (inconsistent when both go the same
 * way); the third makes it non-manifold (and no longer inconsistent). */
typedef struct {
    int64_t edges, open, nonmanifold, inconsistent;
} edge_counts;

static void count_stamped(const uint32_t *e, size_t n, uint64_t lo, uint64_t *slot,
                          edge_counts *c)
{
    for (size_t i = 0; i < n; i++) {
        uint32_t hi = e[i] >> 1, dir = e[i] & 1;
        uint64_t s = slot[hi], live = (s >> 32) == lo;
        uint64_t uses = live ? s >> 1 & 3 : 0, first_dir = live ? s & 1 : dir;
        uint64_t same_way = uses == 1 && dir == first_dir;
        uint64_t was_same = uses == 2 && (s >> 3 & 1);
        c->edges += uses == 0;
        c->open += (int64_t)(uses == 0) - (uses == 1);
        c->nonmanifold += uses == 2;
        c->inconsistent += (int64_t)same_way - (int64_t)was_same;
        slot[hi] = lo << 32 | same_way << 3 | (uses + (uses < 3)) << 1 | first_dir;
    }
}

int mesh_edges(const mesh *m, mesh_topo *out)
{
    uint32_t nv = m->n_vertices, nt = m->n_triangles;
    if (nv > INT32_MAX || (uint64_t)3 * nt > UINT32_MAX) { /* past 4-byte keys */
        int rc = mesh_topology(m, out);
        out->components = 0;
        out->volume = 0;
        return rc;
    }
    memset(out, 0, sizeof *out);
    uint32_t *start = huge_calloc((size_t)nv + 1, sizeof *start);
    uint32_t *use = huge_malloc((size_t)3 * nt * sizeof *use + 1);
    uint64_t *slot = huge_malloc((size_t)nv * sizeof *slot + 1);
    if (!start || !use || !slot) {
        free(start);
        free(use);
        free(slot);
        return -ENOMEM;
    }
    /* stamped with no vertex: lo < 2^31 - 1 */
    memset(slot, 0xff, (size_t)nv * sizeof *slot);
    for (uint32_t i = 0; i < nt; i++) {
        uint32_t a = m->triangles[i][0], b = m->triangles[i][1], c = m->triangles[i][2];
        start[(a < b ? a : b) + 1]++;
        start[(b < c ? b : c) + 1]++;
        start[(c < a ? c : a) + 1]++;
    }
    for (uint32_t v = 0; v < nv; v++) start[v + 1] += start[v];
    /* start[v] is bucket v's next free slot while filling, then its end */
    for (uint32_t i = 0; i < nt; i++)
        for (int k = 0; k < 3; k++) {
            uint32_t a = m->triangles[i][k], b = m->triangles[i][k == 2 ? 0 : k + 1];
            use[start[a < b ? a : b]++] = (a < b ? b : a) << 1 | (a < b);
        }
    uint32_t begin = 0;
    edge_counts c = {0};
    for (uint32_t v = 0; v < nv; v++) {
        count_stamped(use + begin, start[v] - begin, v, slot, &c);
        begin = start[v];
    }
    out->edges = (uint64_t)c.edges;
    out->open = (uint64_t)c.open;
    out->nonmanifold = (uint64_t)c.nonmanifold;
    out->inconsistent = (uint64_t)c.inconsistent;
    out->watertight = !out->open && !out->nonmanifold && !out->inconsistent;
    free(start);
    free(use);
    free(slot);
    return 0;
}

int mesh_topology(const mesh *m, mesh_topo *out)
{
    memset(out, 0, sizeof *out);
    uint32_t nv = m->n_vertices, nt = m->n_triangles;
    if (nt > INT32_MAX) return -E2BIG;
    uint64_t *start = huge_calloc((size_t)nv + 1, sizeof *start);
    edge_use *use = huge_malloc((size_t)3 * nt * sizeof *use + 1);
    uint32_t *parent = huge_malloc((size_t)nt * sizeof *parent + 1);
    if (!start || !use || !parent) {
        free(start);
        free(use);
        free(parent);
        return -ENOMEM;
    }
    for (uint32_t i = 0; i < nt; i++) {
        const uint32_t *t = m->triangles[i];
        for (int k = 0; k < 3; k++) {
            uint32_t a = t[k], b = t[(k + 1) % 3];
            start[(a < b ? a : b) + 1]++;
        }
        parent[i] = i;
    }
    for (uint32_t v = 0; v < nv; v++) start[v + 1] += start[v];
    /* start[v] is bucket v's next free slot while filling, then its end */
    for (uint32_t i = 0; i < nt; i++) {
        const uint32_t *t = m->triangles[i];
        for (int k = 0; k < 3; k++) {
            uint32_t a = t[k], b = t[(k + 1) % 3];
            use[start[a < b ? a : b]++] = (edge_use){a < b ? b : a, i << 1 | (a < b)};
        }
    }
    uint64_t begin = 0;
    for (uint32_t v = 0; v < nv; v++) {
        size_t n = (size_t)(start[v] - begin);
        sort_bucket(use + begin, n);
        count_bucket(use + begin, n, parent, out);
        begin = start[v];
    }
    for (uint32_t i = 0; i < nt; i++) out->components += parent[i] == i;
    out->watertight = !out->open && !out->nonmanifold && !out->inconsistent;
    out->volume = signed_volume(m);
    free(start);
    free(use);
    free(parent);
    return 0;
}
