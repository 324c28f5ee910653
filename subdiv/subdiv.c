/* The subdivision kernel: Figure 1 of Stolte–Kaufman with an explicit stack,
 * the per-octant step of Figure 3's slave, and the chain bookkeeping that
 * makes every box's test independent of the schedule (see subdiv.h). */
#include "subdiv.h"

#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>

#include "voxel.h"

#ifdef __SSE2__
#include <emmintrin.h>
#endif


void subdiv_box(const grid_spec *g, grid_octant o, ival *x, ival *y,
                ival *z)
{
    double n = (double)(1u << o.level);
    *x = ival_make(grid_coord(g, 0, o.x), grid_coord(g, 0, o.x + n));
    *y = ival_make(grid_coord(g, 1, o.y), grid_coord(g, 1, o.y + n));
    *z = ival_make(grid_coord(g, 2, o.z), grid_coord(g, 2, o.z + n));
}

void subdiv_kernel_init(subdiv_kernel *k, expr_vm *vm, const grid_spec *g)
{
    k->vm = vm;
    k->g = g;
    k->valid = 0;
    k->tested = 0;
    k->rebuilt = 0;
    k->poll_left = SUBDIV_POLL_TESTS;
}

static inline grid_octant child_of(grid_octant o, unsigned i)
{
    uint16_t h = (uint16_t)(1u << (o.level - 1));
    return (grid_octant){(uint16_t)(o.x + (i & 1u) * h),
                           (uint16_t)(o.y + ((i >> 1) & 1u) * h),
                           (uint16_t)(o.z + ((i >> 2) & 1u) * h),
                           (uint16_t)(o.level - 1)};
}

static inline grid_octant ancestor(grid_octant o, int level)
{
    uint16_t m = (uint16_t)~((1u << level) - 1u);
    return (grid_octant){(uint16_t)(o.x & m), (uint16_t)(o.y & m),
                           (uint16_t)(o.z & m), (uint16_t)level};
}

static inline bool same_octant(grid_octant a, grid_octant b)
{
    return a.x == b.x && a.y == b.y && a.z == b.z && a.level == b.level;
}

/* An octant whose low corner is outside res holds no voxel. */
static inline bool outside(const grid_spec *g, grid_octant o)
{
    return o.x >= g->res[0] || o.y >= g->res[1] || o.z >= g->res[2];
}

/* Boxes are tested eight at a time (expr_vm_ival8: one pass over the tape
 * for eight boxes).  Each lane computes exactly what expr_vm_ival computes
 * for its box, so a box's keep decision, its min/max choices and the tape
 * pruned for it do not depend on which lane or which batch it was in. */

/* The boxes of o's 8 children in lanes 0..7 (the one formula: the 3
 * distinct bounds per axis, child i taking the upper half on axis a when
 * bit a of i is set). */
static inline void child_boxes(const grid_spec *g, grid_octant o, ival8 box[3])
{
    double h = (double)(1u << o.level) * 0.5;
    const uint16_t lo[3] = {o.x, o.y, o.z};
    double b[3][3];
    for (int a = 0; a < 3; a++) {
        b[a][0] = grid_coord(g, a, lo[a]);
        b[a][1] = grid_coord(g, a, lo[a] + h);
        b[a][2] = grid_coord(g, a, lo[a] + 2.0 * h);
    }
#ifdef __SSE2__
    /* x alternates every lane, y every 2 lanes, z every 4 */
    __m128d xl = _mm_set_pd(b[0][1], b[0][0]), xh = _mm_set_pd(b[0][2], b[0][1]);
    __m128d y0 = _mm_set1_pd(b[1][0]), y1 = _mm_set1_pd(b[1][1]), y2 = _mm_set1_pd(b[1][2]);
    __m128d z0 = _mm_set1_pd(b[2][0]), z1 = _mm_set1_pd(b[2][1]), z2 = _mm_set1_pd(b[2][2]);
    for (int l = 0; l < 8; l += 2) {
        _mm_store_pd(&box[0].lo[l], xl);
        _mm_store_pd(&box[0].hi[l], xh);
        _mm_store_pd(&box[1].lo[l], l & 2 ? y1 : y0);
        _mm_store_pd(&box[1].hi[l], l & 2 ? y2 : y1);
        _mm_store_pd(&box[2].lo[l], l & 4 ? z1 : z0);
        _mm_store_pd(&box[2].hi[l], l & 4 ? z2 : z1);
    }
#else
    for (unsigned i = 0; i < 8; i++) {
        box[0].lo[i] = b[0][i & 1u];
        box[0].hi[i] = b[0][(i & 1u) + 1];
        box[1].lo[i] = b[1][(i >> 1) & 1u];
        box[1].hi[i] = b[1][((i >> 1) & 1u) + 1];
        box[2].lo[i] = b[2][i >> 2];
        box[2].hi[i] = b[2][(i >> 2) + 1];
    }
#endif
}

/* Bits set in an 8-bit mask (no popcnt instruction in the baseline ISA). */
static inline unsigned count8(unsigned m)
{
    m = m - ((m >> 1) & 0x55u);
    m = (m & 0x33u) + ((m >> 2) & 0x33u);
    return (m + (m >> 4)) & 0x0fu;
}

/* Bit i set when child i of o has its low corner inside res (an octant
 * outside holds no voxel and is never tested). */
static inline unsigned inside_children(const grid_spec *g, grid_octant o)
{
    uint32_t h = 1u << (o.level - 1);
    const uint32_t lo[3] = {o.x, o.y, o.z};
    unsigned m = 0xffu;
    static const unsigned upper[3] = {0xaau, 0xccu, 0xf0u}; /* children with bit a set */
    for (int a = 0; a < 3; a++) {
        if (lo[a] >= g->res[a]) return 0;
        if (lo[a] + h >= g->res[a]) m &= ~upper[a];
    }
    return m;
}

/* Test o's children with tape t: bit i of the result is set when child i
 * is kept.  The lanes of children outside res are evaluated too (the lanes
 * come for free) but never counted or kept. */
static inline unsigned test_children(subdiv_kernel *k, int t, grid_octant o,
                                     unsigned inside)
{
    child_boxes(k->g, o, expr_vm_ival8_args(k->vm));
    const ival8 *r = expr_vm_ival8_in(k->vm, t);
    unsigned out = 0; /* lanes where 0 is outside (ival_contains_zero false) */
#ifdef __SSE2__
    for (int l = 0; l < 8; l += 2) {
        __m128d m = _mm_or_pd(_mm_cmpgt_pd(_mm_load_pd(&r->lo[l]), _mm_setzero_pd()),
                              _mm_cmplt_pd(_mm_load_pd(&r->hi[l]), _mm_setzero_pd()));
        out |= (unsigned)_mm_movemask_pd(m) << l;
    }
#else
    for (unsigned i = 0; i < 8; i++)
        out |= (unsigned)((r->lo[i] > 0) | (r->hi[i] < 0)) << i;
#endif
    unsigned keep = ~out & 0xffu;
    k->tested += count8(inside);
    return keep & inside;
}

/* Record that tape t+1 is now pruned for o, which was lane `lane` of the
 * last batch tested with tape t. */
static inline void prune_for(subdiv_kernel *k, int t, grid_octant o, unsigned lane)
{
    expr_vm_prune8(k->vm, t, (int)lane);
    k->chain[t] = o;
    k->valid = t + 1;
}

/* Make tapes 1..depth-o.level the ones pruned by o's ancestors and o, so
 * that o's children can be tested with tape depth-o.level.  Re-tests only
 * the part of the chain the vm does not hold already (the box in every
 * lane: the same evaluation as in a batch of its siblings). */
static void ensure_chain(subdiv_kernel *k, grid_octant o)
{
    int depth = k->g->depth;
    for (int t = 0; t < depth - o.level; t++) {
        grid_octant a = ancestor(o, depth - 1 - t);
        if (t < k->valid && same_octant(k->chain[t], a)) continue;
        ival x, y, z;
        ival8 box[3], r;
        subdiv_box(k->g, a, &x, &y, &z);
        const ival b[3] = {x, y, z};
        for (int j = 0; j < 3; j++)
            for (int l = 0; l < EXPR_LANES; l++) {
                box[j].lo[l] = b[j].lo;
                box[j].hi[l] = b[j].hi;
            }
        /* its keep decision was made before */
        expr_vm_ival8(k->vm, t, &box[0], &box[1], &box[2], &r);
        k->rebuilt++;
        prune_for(k, t, a, 0);
    }
}

/* Emit the voxels c[0..n) (1 <= n <= 8, in this order), all tested with
 * tape t, each with the gradient at its centre, taken for all of them in
 * one pass (expr_vm_grad8; lane for lane the same as expr_vm_grad).
 * Packing keeps only the direction (it divides by the L1 norm), so the
 * gradient is not normalized first; it is only scaled by a power of two
 * (exact) when its size is extreme, so that the packing's norm neither
 * overflows nor underflows. */
static int emit_voxels(subdiv_kernel *k, int t, const grid_octant *c,
                       unsigned n, const subdiv_sink *s)
{
    const grid_spec *g = k->g;
    expr_pts8 p;
    for (unsigned l = 0; l < EXPR_LANES; l++) {
        const grid_octant *v = &c[l < n ? l : 0]; /* spare lanes: copies */
        p.x[l] = grid_coord(g, 0, v->x + 0.5);
        p.y[l] = grid_coord(g, 1, v->y + 0.5);
        p.z[l] = grid_coord(g, 2, v->z + 0.5);
    }
    expr_grad8 gr8;
    expr_vm_grad8n(k->vm, t, (int)n, &p, &gr8);
    for (unsigned l = 0; l < n; l++) {
        double gr[3] = {gr8.d[0][l], gr8.d[1][l], gr8.d[2][l]};
        double m = fabs(gr[0]);
        if (fabs(gr[1]) > m) m = fabs(gr[1]);
        if (fabs(gr[2]) > m) m = fabs(gr[2]);
        if (m >= 0x1p-500 && m <= 0x1p500) continue; /* the usual case */
        if (!(m > 0.0) || !isfinite(m)) {
            gr[0] = gr[1] = gr[2] = 0.0; /* no direction: packs as +z */
        } else {
            int e;
            frexp(m, &e);
            double f = ldexp(1.0, -e);
            for (int a = 0; a < 3; a++) gr[a] *= f;
        }
        for (int a = 0; a < 3; a++) gr8.d[a][l] = gr[a];
    }
    uint32_t value[EXPR_LANES];
    voxel_surfaces(gr8.d[0], gr8.d[1], gr8.d[2], n, value);
    for (unsigned l = 0; l < n; l++) {
        grid_voxel v = {c[l].x, c[l].y, c[l].z, 0, value[l]};
        int rc = s->voxel(s->ud, &v);
        if (rc) return rc;
    }
    return 0;
}

/* The kept children of a level-1 octant o (tested with tape t) as voxels. */
static inline int emit_children(subdiv_kernel *k, int t, grid_octant o,
                                unsigned keep, const subdiv_sink *s)
{
    grid_octant c[8];
    unsigned n = 0;
    for (; keep; keep &= keep - 1) c[n++] = child_of(o, (unsigned)__builtin_ctz(keep));
    return n ? emit_voxels(k, t, c, n, s) : 0;
}

int subdiv_children(subdiv_kernel *k, grid_octant o, const subdiv_sink *s)
{
    if (o.level < 1 || o.level > k->g->depth) return -EINVAL;
    ensure_chain(k, o);
    int t = k->g->depth - o.level;
    unsigned inside = inside_children(k->g, o);
    if (!inside) return 0;
    unsigned keep = test_children(k, t, o, inside);
    if (o.level == 1) return emit_children(k, t, o, keep, s);
    for (; keep; keep &= keep - 1) {
        grid_octant c = child_of(o, (unsigned)__builtin_ctz(keep));
        int rc = s->octant(s->ud, &c);
        if (rc) return rc;
    }
    return 0;
}

/* Voxels waiting for their gradients, so that one gradient pass serves up
 * to 8 of them across level-1 octants (4 per octant on average).  All were
 * tested with tape depth-1, which stays what it was when they were queued:
 * the walk flushes them before any prune that would change that tape or
 * overwrite the memory it lives in (pending_prune).  They are emitted in
 * the order queued, so the output order is unchanged. */
typedef struct {
    grid_octant v[EXPR_LANES];
    unsigned n;
} pending;

static inline int flush(subdiv_kernel *k, pending *p, const subdiv_sink *s)
{
    unsigned n = p->n;
    p->n = 0;
    return n ? emit_voxels(k, k->g->depth - 1, p->v, n, s) : 0;
}

/* Before prune_for(k, t, c, lane): flush when the prune overwrites a
 * tape buffer (tape depth-1 may live in it), or when it makes tape depth-1
 * a different tape (t == depth-2: it becomes tape depth-2). */
static inline int pending_prune(subdiv_kernel *k, pending *p, int t, unsigned lane,
                                const subdiv_sink *s)
{
    int depth = k->g->depth;
    if (!p->n) return 0;
    if (expr_vm_prune8_writes(k->vm, t, (int)lane) ||
        (t == depth - 2 && !expr_vm_same_tape(k->vm, depth - 2, depth - 1)))
        return flush(k, p, s);
    return 0;
}

/* The kept children of a level-1 octant o (tested with tape depth-1) onto
 * the pending voxels. */
static inline int queue_children(subdiv_kernel *k, grid_octant o, unsigned keep,
                                 pending *p, const subdiv_sink *s)
{
    for (; keep; keep &= keep - 1) {
        p->v[p->n++] = child_of(o, (unsigned)__builtin_ctz(keep));
        if (p->n == EXPR_LANES) {
            int rc = flush(k, p, s);
            if (rc) return rc;
        }
    }
    return 0;
}

/* Counts n box tests towards the next poll. */
static inline int poll_sink(subdiv_kernel *k, const subdiv_sink *s, unsigned n)
{
    if (!s->poll) return 0;
    if (k->poll_left > n) {
        k->poll_left -= n;
        return 0;
    }
    k->poll_left = SUBDIV_POLL_TESTS;
    return s->poll(s->ud);
}

/* Test o's children with tape t (after a poll); a level-1 o emits its kept
 * children as voxels right away and keeps nothing to descend into. */
static inline int expand(subdiv_kernel *k, int t, grid_octant o,
                         const subdiv_sink *s, unsigned *keep, pending *p)
{
    *keep = 0;
    unsigned inside = inside_children(k->g, o);
    if (!inside) return 0;
    int rc = poll_sink(k, s, count8(inside));
    if (rc) return rc;
    unsigned m = test_children(k, t, o, inside);
    if (o.level == 1) return queue_children(k, o, m, p, s);
    *keep = m;
    return 0;
}

int subdiv_subtree(subdiv_kernel *k, grid_octant o, const subdiv_sink *s)
{
    const int depth = k->g->depth;
    if (o.level > depth) return -EINVAL;
    if (o.level == 0) {
        ensure_chain(k, ancestor(o, 1));
        return emit_voxels(k, depth - 1, &o, 1, s);
    }
    ensure_chain(k, o);
    /* A frame per octant being walked: its kept children not visited yet
     * (tested in one batch with tape depth - level, whose lane choices stay
     * valid while the subtrees below use deeper tapes). */
    struct {
        grid_octant o;
        unsigned keep;
    } st[GRID_MAX_DEPTH + 1];
    int top = 0, rc;
    pending p = {.n = 0};
    st[0].o = o;
    if ((rc = expand(k, depth - o.level, o, s, &st[0].keep, &p))) return rc;
    while (top >= 0) {
        if (!st[top].keep) {
            top--;
            continue;
        }
        unsigned i = (unsigned)__builtin_ctz(st[top].keep);
        st[top].keep &= st[top].keep - 1;
        grid_octant c = child_of(st[top].o, i);
        int t = depth - 1 - c.level; /* the tape c was tested with */
        if ((rc = pending_prune(k, &p, t, i, s))) return rc;
        prune_for(k, t, c, i);
        unsigned keep;
        if ((rc = expand(k, t + 1, c, s, &keep, &p))) return rc;
        if (keep) {
            top++;
            st[top].o = c;
            st[top].keep = keep;
        }
    }
    return flush(k, &p, s);
}

static int store_voxel(void *ud, const grid_voxel *v)
{
    return octree_store(ud, v->x, v->y, v->z, v->value);
}

int subdiv_serial(const expr_tape *tape, const grid_spec *g, octree *t)
{
    if (grid_check(g) || t->depth != g->depth) return -EINVAL;
    expr_vm *vm;
    int rc = expr_vm_new(tape, g->depth, &vm);
    if (rc) return rc;
    subdiv_kernel k;
    subdiv_kernel_init(&k, vm, g);
    subdiv_sink sink = {.voxel = store_voxel, .ud = t};
    rc = subdiv_subtree(&k, grid_root(g), &sink);
    expr_vm_free(vm);
    return rc;
}
