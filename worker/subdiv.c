/* The subdivision kernel: Figure 1 of Stolte–Kaufman with an explicit stack,
 * the per-octant step of Figure 3's slave, and the chain bookkeeping that
 * makes every box's test independent of the schedule (see subdiv.h). */
#include "subdiv.h"

#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>

#include "voxel.h"

static const char axis_name[3] = {'x', 'y', 'z'};

static int depth_for(uint32_t res)
{
    int d = 1;
    while ((1u << d) < res) d++;
    return d;
}

static int check_domain(const double lo[3], const double hi[3], char *err,
                        size_t errlen)
{
    for (int a = 0; a < 3; a++) {
        if (!isfinite(lo[a]) || !isfinite(hi[a])) {
            snprintf(err, errlen, "domain bound on %c is not finite",
                     axis_name[a]);
            return -EINVAL;
        }
        if (!(hi[a] > lo[a])) {
            snprintf(err, errlen, "domain is empty on %c: low %g >= high %g",
                     axis_name[a], lo[a], hi[a]);
            return -EINVAL;
        }
        if (!isfinite(hi[a] - lo[a])) {
            snprintf(err, errlen, "domain is too large on %c", axis_name[a]);
            return -EINVAL;
        }
    }
    return 0;
}

/* Voxels along axis a: the fewest that cover hi (ceil(extent / vs) up to
 * rounding), at least 1, never more than res. */
static uint32_t axis_voxels(const subdiv_grid *g, const double hi[3], int a,
                            uint32_t res)
{
    double n = ceil((hi[a] - g->lo[a]) / g->vs);
    uint32_t v = n < 1.0 ? 1u : n > (double)res ? res : (uint32_t)n;
    while (v > 1 && subdiv_coord(g, a, v - 1) >= hi[a]) v--;
    while (v < res && subdiv_coord(g, a, v) < hi[a]) v++;
    return v;
}

int subdiv_grid_make(const double lo[3], const double hi[3], uint32_t res,
                     subdiv_grid *g, char *err, size_t errlen)
{
    if (res < 1 || res > SUBDIV_MAX_RES) {
        snprintf(err, errlen, "resolution %u is outside 1..%u", res,
                 SUBDIV_MAX_RES);
        return -EINVAL;
    }
    int rc = check_domain(lo, hi, err, errlen);
    if (rc) return rc;
    int longest = 0;
    for (int a = 1; a < 3; a++)
        if (hi[a] - lo[a] > hi[longest] - lo[longest]) longest = a;
    for (int a = 0; a < 3; a++) g->lo[a] = lo[a];
    g->vs = (hi[longest] - lo[longest]) / res;
    /* Round vs up until the grid reaches hi: the voxels cover the domain. */
    while (subdiv_coord(g, longest, res) < hi[longest])
        g->vs = nextafter(g->vs, INFINITY);
    for (int a = 0; a < 3; a++) {
        if (!(g->vs > 0.0) || subdiv_coord(g, a, 1) == lo[a]) {
            snprintf(err, errlen,
                     "domain is too small for its position on %c: a voxel "
                     "would be narrower than the floating-point spacing",
                     axis_name[a]);
            return -EINVAL;
        }
        g->res[a] = a == longest ? res : axis_voxels(g, hi, a, res);
    }
    g->depth = depth_for(res);
    return 0;
}

int subdiv_grid_check(const subdiv_grid *g)
{
    uint32_t m = 0;
    for (int a = 0; a < 3; a++) {
        if (g->res[a] < 1 || g->res[a] > SUBDIV_MAX_RES) return -EINVAL;
        if (!isfinite(g->lo[a])) return -EINVAL;
        if (!isfinite(subdiv_coord(g, a, g->res[a]))) return -EINVAL;
        if (g->res[a] > m) m = g->res[a];
    }
    if (!(g->vs > 0.0) || !isfinite(g->vs)) return -EINVAL;
    if (g->depth != depth_for(m)) return -EINVAL;
    return 0;
}

void subdiv_box(const subdiv_grid *g, subdiv_octant o, ival *x, ival *y,
                ival *z)
{
    double n = (double)(1u << o.level);
    *x = ival_make(subdiv_coord(g, 0, o.x), subdiv_coord(g, 0, o.x + n));
    *y = ival_make(subdiv_coord(g, 1, o.y), subdiv_coord(g, 1, o.y + n));
    *z = ival_make(subdiv_coord(g, 2, o.z), subdiv_coord(g, 2, o.z + n));
}

void subdiv_kernel_init(subdiv_kernel *k, expr_vm *vm, const subdiv_grid *g)
{
    k->vm = vm;
    k->g = g;
    k->valid = 0;
    k->tested = 0;
    k->rebuilt = 0;
    k->poll_left = SUBDIV_POLL_TESTS;
}

static inline subdiv_octant child_of(subdiv_octant o, unsigned i)
{
    uint16_t h = (uint16_t)(1u << (o.level - 1));
    return (subdiv_octant){(uint16_t)(o.x + (i & 1u) * h),
                           (uint16_t)(o.y + ((i >> 1) & 1u) * h),
                           (uint16_t)(o.z + ((i >> 2) & 1u) * h),
                           (uint16_t)(o.level - 1)};
}

static inline subdiv_octant ancestor(subdiv_octant o, int level)
{
    uint16_t m = (uint16_t)~((1u << level) - 1u);
    return (subdiv_octant){(uint16_t)(o.x & m), (uint16_t)(o.y & m),
                           (uint16_t)(o.z & m), (uint16_t)level};
}

static inline bool same_octant(subdiv_octant a, subdiv_octant b)
{
    return a.x == b.x && a.y == b.y && a.z == b.z && a.level == b.level;
}

/* An octant whose low corner is outside res holds no voxel. */
static inline bool outside(const subdiv_grid *g, subdiv_octant o)
{
    return o.x >= g->res[0] || o.y >= g->res[1] || o.z >= g->res[2];
}

static inline bool test_box(subdiv_kernel *k, int t, subdiv_octant o)
{
    ival x, y, z;
    subdiv_box(k->g, o, &x, &y, &z);
    return ival_contains_zero(expr_vm_ival(k->vm, t, x, y, z));
}

/* Record that tape t+1 is now pruned for o (just tested with tape t). */
static inline void prune_for(subdiv_kernel *k, int t, subdiv_octant o)
{
    expr_vm_prune(k->vm, t);
    k->chain[t] = o;
    k->valid = t + 1;
}

/* Make tapes 1..depth-o.level the ones pruned by o's ancestors and o, so
 * that o's children can be tested with tape depth-o.level.  Re-tests only
 * the part of the chain the vm does not hold already. */
static void ensure_chain(subdiv_kernel *k, subdiv_octant o)
{
    int depth = k->g->depth;
    for (int t = 0; t < depth - o.level; t++) {
        subdiv_octant a = ancestor(o, depth - 1 - t);
        if (t < k->valid && same_octant(k->chain[t], a)) continue;
        (void)test_box(k, t, a); /* its keep decision was made before */
        k->rebuilt++;
        prune_for(k, t, a);
    }
}

/* The gradient at the voxel's centre with tape t (the tape its test used).
 * Packing keeps only the direction (it divides by the L1 norm), so the
 * gradient is not normalized first; it is only scaled by a power of two
 * (exact) when its size is extreme, so that the packing's norm neither
 * overflows nor underflows. */
static int emit_voxel(subdiv_kernel *k, int t, subdiv_octant c,
                      const subdiv_sink *s)
{
    const subdiv_grid *g = k->g;
    double gr[3];
    expr_vm_grad(k->vm, t, subdiv_coord(g, 0, c.x + 0.5),
                 subdiv_coord(g, 1, c.y + 0.5), subdiv_coord(g, 2, c.z + 0.5),
                 gr);
    double m = fabs(gr[0]);
    if (fabs(gr[1]) > m) m = fabs(gr[1]);
    if (fabs(gr[2]) > m) m = fabs(gr[2]);
    if (!(m > 0.0) || !isfinite(m)) {
        gr[0] = gr[1] = gr[2] = 0.0; /* no direction: packs as +z */
    } else if (m > 0x1p500 || m < 0x1p-500) {
        int e;
        frexp(m, &e);
        double f = ldexp(1.0, -e);
        for (int a = 0; a < 3; a++) gr[a] *= f;
    }
    subdiv_voxel v = {c.x, c.y, c.z, 0, voxel_surface(gr)};
    return s->voxel(s->ud, &v);
}

/* The 3 distinct bounds per axis of o's 8 children (the one formula):
 * child i spans b[a][bit] .. b[a][bit + 1] on axis a. */
typedef struct {
    double b[3][3];
} child_bounds;

static inline void bounds_of(const subdiv_grid *g, subdiv_octant o,
                             child_bounds *cb)
{
    double h = (double)(1u << o.level) * 0.5;
    const uint16_t lo[3] = {o.x, o.y, o.z};
    for (int a = 0; a < 3; a++) {
        cb->b[a][0] = subdiv_coord(g, a, lo[a]);
        cb->b[a][1] = subdiv_coord(g, a, lo[a] + h);
        cb->b[a][2] = subdiv_coord(g, a, lo[a] + 2.0 * h);
    }
}

static inline bool test_child(subdiv_kernel *k, int t, const child_bounds *cb,
                              unsigned i)
{
    unsigned bx = i & 1u, by = (i >> 1) & 1u, bz = (i >> 2) & 1u;
    ival x = ival_make(cb->b[0][bx], cb->b[0][bx + 1]);
    ival y = ival_make(cb->b[1][by], cb->b[1][by + 1]);
    ival z = ival_make(cb->b[2][bz], cb->b[2][bz + 1]);
    return ival_contains_zero(expr_vm_ival(k->vm, t, x, y, z));
}

int subdiv_children(subdiv_kernel *k, subdiv_octant o, const subdiv_sink *s)
{
    if (o.level < 1 || o.level > k->g->depth) return -EINVAL;
    ensure_chain(k, o);
    int t = k->g->depth - o.level;
    child_bounds cb;
    bounds_of(k->g, o, &cb);
    for (unsigned i = 0; i < 8; i++) {
        subdiv_octant c = child_of(o, i);
        if (outside(k->g, c)) continue;
        k->tested++;
        if (!test_child(k, t, &cb, i)) continue;
        int rc = o.level == 1 ? emit_voxel(k, t, c, s) : s->octant(s->ud, &c);
        if (rc) return rc;
    }
    return 0;
}

static inline int poll_sink(subdiv_kernel *k, const subdiv_sink *s)
{
    if (!s->poll || --k->poll_left) return 0;
    k->poll_left = SUBDIV_POLL_TESTS;
    return s->poll(s->ud);
}

/* The last level of the depth-first walk: o.level == 1, its children are
 * voxels, tested with tape t; no frame is pushed for them. */
static int leaf_children(subdiv_kernel *k, subdiv_octant o, int t,
                         const subdiv_sink *s)
{
    child_bounds cb;
    bounds_of(k->g, o, &cb);
    for (unsigned i = 0; i < 8; i++) {
        subdiv_octant c = child_of(o, i);
        if (outside(k->g, c)) continue;
        k->tested++;
        int rc = poll_sink(k, s);
        if (!rc && test_child(k, t, &cb, i)) rc = emit_voxel(k, t, c, s);
        if (rc) return rc;
    }
    return 0;
}

int subdiv_subtree(subdiv_kernel *k, subdiv_octant o, const subdiv_sink *s)
{
    const int depth = k->g->depth;
    if (o.level > depth) return -EINVAL;
    if (o.level == 0) {
        ensure_chain(k, ancestor(o, 1));
        return emit_voxel(k, depth - 1, o, s);
    }
    ensure_chain(k, o);
    struct {
        subdiv_octant o;
        unsigned next;
        child_bounds cb;
    } st[SUBDIV_MAX_DEPTH + 1];
    int top = 0, rc;
    st[0].o = o;
    st[0].next = 0;
    bounds_of(k->g, o, &st[0].cb);
    while (top >= 0) {
        if (st[top].next == 8) {
            top--;
            continue;
        }
        unsigned i = st[top].next++;
        subdiv_octant c = child_of(st[top].o, i);
        if (outside(k->g, c)) continue;
        int t = depth - 1 - c.level;
        k->tested++;
        if ((rc = poll_sink(k, s))) return rc;
        if (!test_child(k, t, &st[top].cb, i)) continue;
        if (c.level == 0) {
            if ((rc = emit_voxel(k, t, c, s))) return rc;
            continue;
        }
        prune_for(k, t, c);
        if (c.level == 1) {
            if ((rc = leaf_children(k, c, t + 1, s))) return rc;
            continue;
        }
        top++;
        st[top].o = c;
        st[top].next = 0;
        bounds_of(k->g, c, &st[top].cb);
    }
    return 0;
}

static int store_voxel(void *ud, const subdiv_voxel *v)
{
    return octree_store(ud, v->x, v->y, v->z, v->value);
}

int subdiv_serial(const expr_tape *tape, const subdiv_grid *g, octree *t)
{
    if (subdiv_grid_check(g) || t->depth != g->depth) return -EINVAL;
    expr_vm *vm;
    int rc = expr_vm_new(tape, g->depth, &vm);
    if (rc) return rc;
    subdiv_kernel k;
    subdiv_kernel_init(&k, vm, g);
    subdiv_sink sink = {.voxel = store_voxel, .ud = t};
    rc = subdiv_subtree(&k, subdiv_root(g), &sink);
    expr_vm_free(vm);
    return rc;
}
