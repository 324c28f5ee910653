/* csg_eval — the tree on one brick, bottom-up, deciding whole operand
 * subtrees from a uniform operand where the operator allows. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "csg_eval_int.h"
#include "voxel.h"

#define CSG_ARENA (64u << 10)

typedef struct {
    int32_t lo[3];
    uint32_t n; /* voxels per axis */
} box;

static int build_tables(csg_eval *e, uint32_t i)
{
    const csg_node *n = &e->t->node[i];
    e->lut[i] = malloc(65536);
    e->force_a[i] = malloc(256 * sizeof(int16_t));
    e->force_b[i] = malloc(256 * sizeof(int16_t));
    if (!e->lut[i] || !e->force_a[i] || !e->force_b[i]) return -ENOMEM;
    for (int a = 0; a < 256; a++)
        for (int b = 0; b < 256; b++)
            e->lut[i][a * 256 + b] = csg_apply(n->kind, (uint8_t)a, (uint8_t)b, n->param);
    for (int v = 0; v < 256; v++) {
        e->force_a[i][v] = e->lut[i][v * 256];
        e->force_b[i][v] = e->lut[i][v];
        for (int o = 1; o < 256; o++) {
            if (e->lut[i][v * 256 + o] != e->force_a[i][v]) e->force_a[i][v] = -1;
            if (e->lut[i][o * 256 + v] != e->force_b[i][v]) e->force_b[i][v] = -1;
        }
    }
    return 0;
}

int csg_eval_new(const csg_tree *t, const grid_spec *g, uint32_t side,
                 const vod_volume *const *leaves, csg_eval **out)
{
    *out = NULL;
    if (!t->n || side < 1 || side > 256) return -EINVAL;
    csg_eval *e = calloc(1, sizeof *e);
    if (!e) return -ENOMEM;
    e->t = t, e->g = *g, e->side = side;
    e->arena_cap = CSG_ARENA;
    for (uint32_t i = 0; i < CSG_MAX_NODES; i++) e->known[i] = -1;
    int rc = (e->arena = malloc(e->arena_cap)) ? 0 : -ENOMEM;
    for (uint32_t i = 0; i < t->n && !rc; i++) {
        const csg_node *n = &t->node[i];
        e->has_morph |= n->kind == CSG_ERODE || n->kind == CSG_DILATE;
        if (n->kind == CSG_MESH || n->kind == CSG_VOD) {
            e->leaf[i] = leaves ? leaves[i] : NULL;
            rc = e->leaf[i] ? 0 : -EINVAL;
        } else if (n->kind == CSG_IMPLICIT) {
            expr_error ee;
            rc = expr_compile(t->text + n->expr_off, n->expr_len, NULL, &e->tape[i], &ee);
            if (!rc) rc = expr_vm_new(e->tape[i], 0, &e->vm[i]);
            e->igrad[i] = 1; /* until the first interval evaluation says otherwise */
        } else if (n->b >= 0) {
            rc = build_tables(e, i);
        }
    }
    if (rc) {
        csg_eval_free(e);
        return rc;
    }
    *out = e;
    return 0;
}

void csg_eval_free(csg_eval *e)
{
    if (!e) return;
    for (uint32_t i = 0; i < e->t->n; i++) {
        expr_vm_free(e->vm[i]);
        expr_tape_free(e->tape[i]);
        free(e->lut[i]);
        free(e->force_a[i]);
        free(e->force_b[i]);
    }
    csg_deval_free(e);
    free(e->arena);
    free(e);
}

const csg_stats *csg_eval_stats(const csg_eval *e)
{
    return &e->st;
}

static double centre(const csg_eval *e, int a, int32_t X)
{
    return grid_coord(&e->g, a, X + 0.5);
}

/* Margins of the bounds below, in voxels: far above the rounding of the
 * samples' arithmetic (about 1e-12 voxel), far below a voxel. */
#define CSG_BOUND_MARGIN 0.01

/* The box's voxel centres in the primitive's local frame, in voxels: the
 * centre c and the half-extent r along each local axis (every centre q has
 * abs(q_i - c_i) <= r_i: the box's corners are its extremes). */
static void prim_box(const csg_eval *e, const csg_node *n, const box *b, double c[3],
                     double r[3])
{
    double vs = e->g.vs, d[3], h = (b->n - 1) / 2.0;
    for (int a = 0; a < 3; a++) d[a] = grid_coord(&e->g, a, b->lo[a] + b->n / 2.0) - n->center[a];
    for (int i = 0; i < 3; i++) {
        c[i] = (n->m[i][0] * d[0] + n->m[i][1] * d[1] + n->m[i][2] * d[2]) / vs;
        r[i] = (fabs(n->m[i][0]) + fabs(n->m[i][1]) + fabs(n->m[i][2])) * h;
    }
}

/* Over a box with centre c, half-extents r (two or three axes ax[]): 1
 * when every point q has body(q / R) > 1 (outside the ellipse(oid) of
 * radii R), 2 when every one has it <= 1, else 0.  The box lies in the
 * ball of radius abs(r / R) around c / R in the scaled space. */
static int ellipse_side(const double *c, const double *r, const double *R, const int *ax,
                        int dims)
{
    double cc = 0, rr = 0;
    for (int k = 0; k < dims; k++) {
        if (!(R[k] > 0)) return 0;
        cc += c[ax[k]] * c[ax[k]] / (R[k] * R[k]);
        rr += r[ax[k]] * r[ax[k]] / (R[k] * R[k]);
    }
    double cl = sqrt(cc), rl = sqrt(rr);
    return cl - rl > 1 ? 1 : cl + rl <= 1 ? 2 : 0;
}

/* The radii R + grow of the ellipse across axes ax[]. */
static void radii(const double *e, const int *ax, int dims, double scale, double grow,
                  double *R)
{
    for (int k = 0; k < dims; k++) R[k] = e[ax[k]] * scale + grow;
}

/* The primitive's value over the whole box when its bounds show it
 * uniform (CSG_L, CSG_H), else -1.  L: outside by more than the L layer
 * (cuboid: t < 0; the others: one voxel inwards along the ray from the
 * centre is still outside, which holds outside the body with radii grown
 * by one voxel, as a power mean of order -2 of the radii is superadditive);
 * H: inside the body shrunk by one voxel likewise (the end caps one voxel
 * in).  Each with CSG_BOUND_MARGIN to spare. */
static int prim_bound(const csg_eval *e, const csg_node *n, const box *b)
{
    const double m = CSG_BOUND_MARGIN, in = 1 + CSG_BOUND_MARGIN;
    double c[3], r[3], ei[3], R[3];
    prim_box(e, n, b, c, r);
    for (int i = 0; i < 3; i++) ei[i] = n->size[i] / (2 * e->g.vs);
    if (n->kind == CSG_CUBOID) {
        int h = 1;
        for (int i = 0; i < 3; i++) {
            if (fabs(c[i]) - r[i] > ei[i] + m) return CSG_L;
            h &= fabs(c[i]) + r[i] <= ei[i] - in;
        }
        return h ? (int)CSG_H : -1;
    }
    if (n->kind == CSG_ELLIPSOID) {
        static const int all[3] = {0, 1, 2};
        radii(ei, all, 3, 1, in, R);
        if (ellipse_side(c, r, R, all, 3) == 1) return CSG_L;
        radii(ei, all, 3, 1, -in, R);
        return ellipse_side(c, r, R, all, 3) == 2 ? (int)CSG_H : -1;
    }
    int ax = n->axis, cross[2] = {(ax + 1) % 3, (ax + 2) % 3};
    /* s: voxels from the nearer end cap (cylinder) or from the base (cone) */
    double smin, smax, scale_lo = 1, scale_hi = 1;
    if (n->kind == CSG_CYLINDER) {
        smin = ei[ax] - fabs(c[ax]) - r[ax], smax = ei[ax] - fabs(c[ax]) + r[ax];
        if (smax < -m) return CSG_L;
    } else { /* cone: radii times 1 - s / height, L below the base and from the apex */
        smin = c[ax] - r[ax] + ei[ax], smax = c[ax] + r[ax] + ei[ax];
        if (smax < -m || smin > 2 * ei[ax] + m) return CSG_L;
        scale_hi = fmin(1, fmax(0, 1 - smin / (2 * ei[ax])));
        scale_lo = 1 - smax / (2 * ei[ax]);
    }
    radii(ei, cross, 2, scale_hi, in, R);
    if (ellipse_side(c, r, R, cross, 2) == 1) return CSG_L;
    if (smin < in || !(scale_lo > 0)) return -1;
    radii(ei, cross, 2, scale_lo, -in, R);
    return ellipse_side(c, r, R, cross, 2) == 2 ? (int)CSG_H : -1;
}

/* The density of F and its gradient at a point (docs/csg.md). */
static uint8_t implicit_value(const csg_eval *e, double f, const double gr[3])
{
    double len = sqrt(gr[0] * gr[0] + gr[1] * gr[1] + gr[2] * gr[2]);
    /* t: the signed distance estimate, in voxels, positive inside. */
    double t = -f / len / e->g.vs;
    double v = CSG_S + t * (CSG_H - CSG_S) / CSG_IMPLICIT_RAMP;
    if (!(v > CSG_L)) return CSG_L;
    return v >= CSG_H ? CSG_H : (uint8_t)floor(v);
}

static int implicit_all_l(const csg_eval *e, const csg_node *n, const box *b)
{
    if (!n->has_domain) return 0;
    for (int a = 0; a < 3; a++)
        if (centre(e, a, b->lo[a]) > n->dom_hi ||
            centre(e, a, b->lo[a] + (int32_t)b->n - 1) < n->dom_lo)
            return 1;
    return 0;
}

static int box_in_domain(const csg_eval *e, const csg_node *n, const box *b)
{
    if (n->has_domain)
        for (int a = 0; a < 3; a++)
            if (!(centre(e, a, b->lo[a]) >= n->dom_lo &&
                  centre(e, a, b->lo[a] + (int32_t)b->n - 1) <= n->dom_hi))
                return 0;
    return 1;
}

/* Relative slack of the interval decisions: covers the rounding of the few
 * operations of implicit_value that the intervals do not (1e-16 each). */
#define CSG_IVAL_SLACK 1e-9

/* An implicit leaf's value over the box when intervals of F and of its
 * gradient decide it, else -1: with F in [flo, fhi] and abs(grad F) <= G
 * on the box, t = -F / abs(grad F) / vs is at most -flo / (G vs) (L where
 * that puts the density at or below L: at a NaN point too) and at least
 * -fhi / (G vs) (H where that is at or above H, when F and its gradient
 * are defined everywhere in the box and it lies in the domain). */
static int implicit_bound(csg_eval *e, uint32_t i, const box *b)
{
    const csg_node *n = &e->t->node[i];
    if (implicit_all_l(e, n, b)) return CSG_L;
    if (!e->igrad[i]) return -1;
    ival x[3];
    for (int a = 0; a < 3; a++)
        x[a] = ival_make(centre(e, a, b->lo[a]), centre(e, a, b->lo[a] + (int32_t)b->n - 1));
    expr_igrad ig;
    if (expr_vm_ival_grad(e->vm[i], x[0], x[1], x[2], &ig)) {
        e->igrad[i] = 0; /* an op without an interval gradient: never decided */
        return -1;
    }
    double g2 = 0;
    for (int j = 0; j < 3; j++) {
        double m = fmax(fabs(ig.grad[j].lo), fabs(ig.grad[j].hi));
        g2 += m * m;
    }
    /* the density is L at t <= -S ramp / (H - S), H at t >= ramp */
    double step = sqrt(g2) * e->g.vs * (1 + CSG_IVAL_SLACK) * CSG_IMPLICIT_RAMP;
    if (ig.f.lo > 0 && ig.f.lo > step * CSG_S / (CSG_H - CSG_S)) return CSG_L;
    if (ig.total && ig.f.hi < 0 && -ig.f.hi > step && box_in_domain(e, n, b)) return CSG_H;
    return -1;
}

/* A leaf's value over the box from its bounds (no sample), else -1. */
static int leaf_bound(csg_eval *e, uint32_t i, const box *b)
{
    const csg_node *n = &e->t->node[i];
    return n->kind == CSG_IMPLICIT ? implicit_bound(e, i, b) : prim_bound(e, n, b);
}

static int in_domain(const csg_node *n, const double p[3])
{
    if (n->has_domain)
        for (int a = 0; a < 3; a++)
            if (!(p[a] >= n->dom_lo && p[a] <= n->dom_hi)) return 0;
    return 1;
}

/* An implicit leaf over the box, each row's points eight at a time
 * (expr_vm_grad8n: lane for lane expr_vm_grad's values, bit for bit). */
static void sample_implicit(csg_eval *e, uint32_t i, const box *b, uint8_t *buf)
{
    const csg_node *n = &e->t->node[i];
    expr_pts8 p8;
    expr_grad8 out;
    size_t k = 0;
    for (uint32_t z = 0; z < b->n; z++)
        for (uint32_t y = 0; y < b->n; y++)
            for (uint32_t x0 = 0; x0 < b->n; x0 += EXPR_LANES) {
                uint32_t cnt = b->n - x0 < EXPR_LANES ? b->n - x0 : EXPR_LANES;
                for (uint32_t l = 0; l < EXPR_LANES; l++) {
                    uint32_t x = x0 + (l < cnt ? l : 0); /* unused lanes: a copy */
                    p8.x[l] = centre(e, 0, b->lo[0] + (int32_t)x);
                    p8.y[l] = centre(e, 1, b->lo[1] + (int32_t)y);
                    p8.z[l] = centre(e, 2, b->lo[2] + (int32_t)z);
                }
                expr_vm_grad8n(e->vm[i], 0, (int)cnt, &p8, &out);
                for (uint32_t l = 0; l < cnt; l++) {
                    double p[3] = {p8.x[l], p8.y[l], p8.z[l]},
                           gr[3] = {out.d[0][l], out.d[1][l], out.d[2][l]};
                    buf[k++] = in_domain(n, p) ? implicit_value(e, out.v[l], gr) : CSG_L;
                }
            }
    e->st.voxel_evals += k;
}

static void sample_leaf(csg_eval *e, uint32_t i, const box *b, uint8_t *buf)
{
    const csg_node *n = &e->t->node[i];
    if (n->kind == CSG_IMPLICIT) {
        sample_implicit(e, i, b, buf);
        return;
    }
    size_t k = 0;
    for (uint32_t z = 0; z < b->n; z++)
        for (uint32_t y = 0; y < b->n; y++)
            for (uint32_t x = 0; x < b->n; x++) {
                double p[3] = {centre(e, 0, b->lo[0] + (int32_t)x),
                               centre(e, 1, b->lo[1] + (int32_t)y),
                               centre(e, 2, b->lo[2] + (int32_t)z)};
                buf[k++] = csg_prim_sample(n, p, e->g.vs);
            }
    e->st.voxel_evals += k;
}

/* A primitive or implicit leaf over the box in cubes of CSG_SUB voxels: a
 * cube its bounds show all L or all H is filled without sampling (the same
 * values the samples would give: the bounds are the brick-level ones), the
 * others likewise in cubes of 2 (a primitive's bounds cost less than 8
 * samples; an implicit leaf's intervals about as much) or sampled.  Boxes
 * of other sides are sampled whole. */
#define CSG_SUB 4u
static void sample_in_cubes(csg_eval *e, uint32_t i, const box *b, uint8_t *buf)
{
    uint32_t c = b->n % CSG_SUB == 0 && b->n > CSG_SUB ? CSG_SUB
                 : e->t->node[i].kind != CSG_IMPLICIT && b->n == CSG_SUB ? CSG_SUB / 2
                                                                        : 0;
    if (!c) {
        sample_leaf(e, i, b, buf);
        return;
    }
    uint8_t sub[CSG_SUB * CSG_SUB * CSG_SUB];
    for (uint32_t z0 = 0; z0 < b->n; z0 += c)
        for (uint32_t y0 = 0; y0 < b->n; y0 += c)
            for (uint32_t x0 = 0; x0 < b->n; x0 += c) {
                box sb = {{b->lo[0] + (int32_t)x0, b->lo[1] + (int32_t)y0,
                           b->lo[2] + (int32_t)z0}, c};
                int v = leaf_bound(e, i, &sb);
                if (v < 0) sample_in_cubes(e, i, &sb, sub);
                for (uint32_t z = 0; z < c; z++)
                    for (uint32_t y = 0; y < c; y++) {
                        uint8_t *row = buf + x0 + (size_t)b->n * (y0 + y + (size_t)b->n * (z0 + z));
                        if (v >= 0) memset(row, v, c);
                        else memcpy(row, sub + c * (y + c * z), c);
                    }
            }
}

/* A file leaf's volume over the box: uniform from its table, or read. */
static int volume_leaf(csg_eval *e, uint32_t i, const box *b, uint8_t *buf, uint8_t *v)
{
    const vod_volume *vol = e->leaf[i];
    int64_t lo[3] = {b->lo[0], b->lo[1], b->lo[2]};
    uint32_t u;
    if (vod_volume_box_uniform(vol, lo, b->n, &u)) return *v = (uint8_t)u, 1;
    size_t k = 0;
    for (uint32_t z = 0; z < b->n; z++)
        for (uint32_t y = 0; y < b->n; y++)
            for (uint32_t x = 0; x < b->n; x++) {
                int64_t p[3] = {lo[0] + x, lo[1] + y, lo[2] + z};
                buf[k++] = p[0] < 0 || p[1] < 0 || p[2] < 0
                               ? 0
                               : (uint8_t)vod_volume_get(vol, (uint32_t)p[0], (uint32_t)p[1],
                                                         (uint32_t)p[2]);
            }
    e->st.voxel_evals += k;
    return 0;
}

/* 1 and *v when buf's count bytes are all one value. */
static int all_same(const uint8_t *buf, size_t count, uint8_t *v)
{
    for (size_t k = 1; k < count; k++)
        if (buf[k] != buf[0]) return 0;
    *v = buf[0];
    return 1;
}

static int eval(csg_eval *e, uint32_t i, const box *b, uint8_t *buf, uint8_t *v);

/* n bytes of scratch from the arena (the heap when it is full); give them
 * back with scratch_give, last taken first. */
static uint8_t *scratch_take(csg_eval *e, size_t n)
{
    if (n > e->arena_cap - e->arena_top) return malloc(n);
    uint8_t *p = e->arena + e->arena_top;
    e->arena_top += n;
    return p;
}

static void scratch_give(csg_eval *e, uint8_t *p, size_t n)
{
    if (p >= e->arena && p < e->arena + e->arena_cap) e->arena_top -= n;
    else free(p);
}

/* o[x] := max (dilate) or min of o[x] and t[x] for x < n, eight bytes at
 * a time: a byte of o is at least t's where their high bits say so, or,
 * when those are equal, where (o | 0x80) - (t & 0x7f) keeps its high bit
 * (no borrow crosses a byte). */
static void fold_row(uint8_t *o, const uint8_t *t, uint32_t n, int dilate)
{
    const uint64_t hi = 0x8080808080808080ull;
    uint32_t x = 0;
    for (; x + 8 <= n; x += 8) {
        uint64_t a, b;
        memcpy(&a, o + x, 8);
        memcpy(&b, t + x, 8);
        uint64_t low_ge = (a | hi) - (b & ~hi);
        uint64_t ge = ((a & ~b) | (~(a ^ b) & low_ge)) & hi;
        uint64_t m = (ge >> 7) * 0xff; /* 0xff where a >= b */
        uint64_t r = dilate ? (a & m) | (b & ~m) : (b & m) | (a & ~m);
        memcpy(o + x, &r, 8);
    }
    for (; x < n; x++) o[x] = dilate ? (t[x] > o[x] ? t[x] : o[x]) : (t[x] < o[x] ? t[x] : o[x]);
}

/* One axis of a separable min (erode) or max (dilate) filter of half-width
 * k: src has dims sd (x fastest), dst the same with axis a shrunk by 2k.
 * Row by row: each output row is the first of its 2k+1 source rows, then
 * folded with the others (loops over x without a branch). */
static void filter_axis(const uint8_t *src, const uint32_t sd[3], int a, uint32_t k,
                        int dilate, uint8_t *dst)
{
    uint32_t dd[3] = {sd[0], sd[1], sd[2]};
    dd[a] -= 2 * k;
    size_t stride = a == 0 ? 1 : a == 1 ? sd[0] : (size_t)sd[0] * sd[1];
    for (uint32_t z = 0; z < dd[2]; z++)
        for (uint32_t y = 0; y < dd[1]; y++) {
            const uint8_t *s = src + (size_t)sd[0] * (y + (size_t)sd[1] * z);
            uint8_t *o = dst + (size_t)dd[0] * (y + (size_t)dd[1] * z);
            memcpy(o, s, dd[0]);
            for (uint32_t j = 1; j <= 2 * k; j++) fold_row(o, s + j * stride, dd[0], dilate);
        }
}

static int morph(csg_eval *e, uint32_t i, const box *b, uint8_t *buf, uint8_t *v)
{
    const csg_node *n = &e->t->node[i];
    box cb = {{b->lo[0] - (int32_t)n->k, b->lo[1] - (int32_t)n->k, b->lo[2] - (int32_t)n->k},
              b->n + 2 * n->k};
    size_t cn = (size_t)cb.n * cb.n * cb.n;
    uint8_t *c = scratch_take(e, cn), *tmp = c ? scratch_take(e, cn) : NULL;
    int rc = tmp ? eval(e, (uint32_t)n->a, &cb, c, v) : -ENOMEM;
    if (rc == 0) {
        int dil = n->kind == CSG_DILATE;
        uint32_t d0[3] = {cb.n, cb.n, cb.n}, d1[3] = {b->n, cb.n, cb.n},
                 d2[3] = {b->n, b->n, cb.n};
        filter_axis(c, d0, 0, n->k, dil, tmp);
        filter_axis(tmp, d1, 1, n->k, dil, c);
        filter_axis(c, d2, 2, n->k, dil, buf);
    }
    if (tmp) scratch_give(e, tmp, cn);
    if (c) scratch_give(e, c, cn);
    return rc;
}

/* The operands of binary node i over the box: a into a, b into buf, and
 * their uniform values into uv[0] (a's) and uv[1] (b's).  1 and uv[0] the
 * result when it is uniform; else 2 (both filled), 3 (b uniform, uv[1]), 4
 * (a uniform, uv[0]); or a negative errno. */
static int binary_in(csg_eval *e, uint32_t i, const box *b, uint8_t *a, uint8_t *buf,
                     uint8_t uv[2])
{
    uint8_t *va = &uv[0], *vb = &uv[1];
    const csg_node *n = &e->t->node[i];
    int ua = eval(e, (uint32_t)n->a, b, a, va);
    if (ua < 0) return ua;
    if (ua == 1 && e->force_a[i][*va] >= 0) {
        *va = (uint8_t)e->force_a[i][*va];
        e->st.skipped++;
        return 1;
    }
    int ub = eval(e, (uint32_t)n->b, b, buf, vb);
    if (ub < 0) return ub;
    if (ub == 1 && (ua == 1 || e->force_b[i][*vb] >= 0)) {
        *va = ua == 1 ? e->lut[i][*va * 256 + *vb] : (uint8_t)e->force_b[i][*vb];
        return 1;
    }
    return ua ? 4 : ub ? 3 : 2;
}

static int binary_op(csg_eval *e, uint32_t i, const box *b, uint8_t *buf, uint8_t *v)
{
    size_t count = (size_t)b->n * b->n * b->n;
    uint8_t *a = scratch_take(e, count), uv[2];
    if (!a) return -ENOMEM;
    int rc = binary_in(e, i, b, a, buf, uv);
    uint8_t va = uv[0], vb = uv[1];
    if (rc == 2) { /* both operands there: the table */
        const uint8_t *lut = e->lut[i];
        for (size_t k = 0; k < count; k++) buf[k] = lut[a[k] * 256 + buf[k]];
        rc = 0;
    } else if (rc == 3) { /* b uniform */
        const uint8_t *row = e->lut[i] + vb;
        for (size_t k = 0; k < count; k++) buf[k] = row[a[k] * 256];
        rc = 0;
    } else if (rc == 4) { /* a uniform */
        const uint8_t *row = e->lut[i] + va * 256;
        for (size_t k = 0; k < count; k++) buf[k] = row[buf[k]];
        rc = 0;
    } else if (rc == 1) {
        *v = va;
    }
    scratch_give(e, a, count);
    return rc;
}

/* Node i over box b: 1 and *v when uniform (buf untouched), 0 with buf
 * filled (b->n^3 bytes), or a negative errno. */
static int eval(csg_eval *e, uint32_t i, const box *b, uint8_t *buf, uint8_t *v)
{
    const csg_node *n = &e->t->node[i];
    size_t count = (size_t)b->n * b->n * b->n;
    int rc;
    switch (n->kind) {
    case CSG_CUBOID: case CSG_ELLIPSOID: case CSG_CYLINDER: case CSG_CONE:
    case CSG_IMPLICIT:
        if (e->known[i] >= 0) return *v = (uint8_t)e->known[i], 1;
        if ((rc = leaf_bound(e, i, b)) >= 0) return *v = (uint8_t)rc, 1;
        sample_in_cubes(e, i, b, buf);
        rc = 0;
        break;
    case CSG_MESH: case CSG_VOD:
        rc = volume_leaf(e, i, b, buf, v);
        if (rc == 1) return 1;
        break;
    case CSG_ERODE: case CSG_DILATE:
        rc = morph(e, i, b, buf, v);
        break;
    case CSG_INVERSE: case CSG_SCALAR_ADD: case CSG_SCALAR_MUL:
        rc = eval(e, (uint32_t)n->a, b, buf, v);
        if (rc == 1) *v = csg_apply(n->kind, *v, 0, n->param);
        if (rc == 0)
            for (size_t k = 0; k < count; k++) buf[k] = csg_apply(n->kind, buf[k], 0, n->param);
        break;
    default:
        rc = binary_op(e, i, b, buf, v);
        break;
    }
    if (rc == 0 && all_same(buf, count, v)) rc = 1;
    return rc;
}

/* Node i's value over the whole box when its bounds alone decide it (the
 * checks eval makes before sampling, and the operators' forcing tables),
 * else -1.  Nothing is sampled. */
static int probe(csg_eval *e, uint32_t i, const box *b)
{
    const csg_node *n = &e->t->node[i];
    int va, vb;
    switch (n->kind) {
    case CSG_CUBOID: case CSG_ELLIPSOID: case CSG_CYLINDER: case CSG_CONE:
    case CSG_IMPLICIT:
        return leaf_bound(e, i, b);
    case CSG_MESH: case CSG_VOD: {
        int64_t lo[3] = {b->lo[0], b->lo[1], b->lo[2]};
        uint32_t u;
        return vod_volume_box_uniform(e->leaf[i], lo, b->n, &u) ? (int)u : -1;
    }
    case CSG_ERODE: case CSG_DILATE: {
        box cb = {{b->lo[0] - (int32_t)n->k, b->lo[1] - (int32_t)n->k, b->lo[2] - (int32_t)n->k},
                  b->n + 2 * n->k};
        return probe(e, (uint32_t)n->a, &cb); /* a uniform operand: the same value */
    }
    case CSG_INVERSE: case CSG_SCALAR_ADD: case CSG_SCALAR_MUL:
        va = probe(e, (uint32_t)n->a, b);
        return va < 0 ? -1 : csg_apply(n->kind, (uint8_t)va, 0, n->param);
    default:
        va = probe(e, (uint32_t)n->a, b);
        if (va >= 0 && e->force_a[i][va] >= 0) return e->force_a[i][va];
        vb = probe(e, (uint32_t)n->b, b);
        if (vb >= 0 && e->force_b[i][vb] >= 0) return e->force_b[i][vb];
        return va >= 0 && vb >= 0 ? e->lut[i][va * 256 + vb] : -1;
    }
}

/* The brick in cubes of CSG_SUB voxels, each through the tree with its
 * own uniform shortcuts (a leaf or an operand uniform over a cube is not
 * sampled there): the voxels eval gives the whole brick, computed where
 * the surfaces are.  1 and *v when the brick came out uniform. */
static void forget_known(csg_eval *e)
{
    for (uint32_t i = 0; i < e->t->n; i++) e->known[i] = -1;
}

static int eval_in_cubes(csg_eval *e, const box *bx, uint8_t *out, uint8_t *v)
{
    uint8_t sub[CSG_SUB * CSG_SUB * CSG_SUB], sv;
    /* a leaf uniform over the brick is so over each cube: decided once */
    for (uint32_t i = 0; i < e->t->n; i++)
        if (e->t->node[i].kind <= CSG_IMPLICIT) e->known[i] = (int16_t)leaf_bound(e, i, bx);
    for (uint32_t z0 = 0; z0 < bx->n; z0 += CSG_SUB)
        for (uint32_t y0 = 0; y0 < bx->n; y0 += CSG_SUB)
            for (uint32_t x0 = 0; x0 < bx->n; x0 += CSG_SUB) {
                box sb = {{bx->lo[0] + (int32_t)x0, bx->lo[1] + (int32_t)y0,
                           bx->lo[2] + (int32_t)z0}, CSG_SUB};
                int rc = eval(e, e->t->n - 1, &sb, sub, &sv);
                if (rc < 0) return forget_known(e), rc;
                for (uint32_t z = 0; z < CSG_SUB; z++)
                    for (uint32_t y = 0; y < CSG_SUB; y++) {
                        uint8_t *row = out + x0 + (size_t)bx->n * (y0 + y + (size_t)bx->n * (z0 + z));
                        if (rc == 1) memset(row, sv, CSG_SUB);
                        else memcpy(row, sub + CSG_SUB * (y + CSG_SUB * z), CSG_SUB);
                    }
            }
    forget_known(e);
    return all_same(out, (size_t)bx->n * bx->n * bx->n, v);
}

int csg_eval_brick(csg_eval *e, const uint32_t b[3], uint8_t *out, int *uniform,
                   uint8_t *value)
{
    box bx = {{(int32_t)(b[0] * e->side), (int32_t)(b[1] * e->side), (int32_t)(b[2] * e->side)},
              e->side};
    int rc, pv;
    if ((pv = probe(e, e->t->n - 1, &bx)) >= 0)
        rc = 1, *value = (uint8_t)pv;
    else if (e->has_morph || e->side % CSG_SUB || e->side == CSG_SUB)
        rc = eval(e, e->t->n - 1, &bx, out, value);
    else
        rc = eval_in_cubes(e, &bx, out, value);
    if (rc < 0) return rc;
    *uniform = rc;
    e->st.bricks++;
    e->st.uniform_bricks += (uint64_t)rc;
    return 0;
}

/* The bytes of row[0, n) at or above S (127), eight at a time: a byte's
 * high bit after adding 1 to its low seven bits, or its own. */
static uint32_t count_solid(const uint8_t *row, uint32_t n)
{
    _Static_assert(CSG_S == 127, "the carry trick counts bytes >= 127");
    const uint64_t low7 = 0x7f7f7f7f7f7f7f7full, ones = 0x0101010101010101ull;
    uint32_t c = 0, x = 0;
    for (; x + 8 <= n; x += 8) {
        uint64_t w;
        memcpy(&w, row + x, 8);
        uint64_t hi = (((w & low7) + ones) | w) & ~low7;
        c += (uint32_t)(((hi >> 7) * ones) >> 56);
    }
    for (; x < n; x++) c += row[x] >= CSG_S;
    return c;
}

/* Brick b's voxels past the grid := 0, the voxels at or above S inside it
 * counted; densities to occupancy if asked. */
static void finish(csg_eval *e, const uint32_t b[3], uint8_t *buf, int occupancy)
{
    uint32_t s = e->side, n[3];
    for (int a = 0; a < 3; a++) n[a] = e->g.res[a] - b[a] * s < s ? e->g.res[a] - b[a] * s : s;
    uint64_t solid = 0;
    for (uint32_t z = 0; z < s; z++)
        for (uint32_t y = 0; y < s; y++) {
            uint8_t *row = buf + (size_t)s * (y + (size_t)s * z);
            if (z >= n[2] || y >= n[1]) {
                memset(row, 0, s);
                continue;
            }
            memset(row + n[0], 0, s - n[0]);
            solid += count_solid(row, n[0]);
            if (occupancy)
                for (uint32_t x = 0; x < n[0]; x++) row[x] = row[x] >= CSG_S;
        }
    e->st.solid_voxels += solid;
}

/* Brick b into vol: buf's voxels, or (uv >= 0) uv in every voxel. */
static int put(csg_eval *e, vod_volume *vol, const uint32_t b[3], uint8_t *buf, int uv, int occupancy)
{
    int uniform = uv >= 0;
    uint8_t v = uniform ? (uint8_t)uv : 0;
    uint32_t s = e->side;
    int inside = 1;
    for (int a = 0; a < 3; a++) inside &= (b[a] + 1) * s <= e->g.res[a];
    if (uniform && inside) {
        if (v >= CSG_S) e->st.solid_voxels += (uint64_t)s * s * s;
        return vod_volume_put_uniform(vol, b, occupancy ? v >= CSG_S : v);
    }
    if (uniform && v == 0) return vod_volume_put_uniform(vol, b, 0);
    if (uniform) memset(buf, v, (size_t)s * s * s);
    finish(e, b, buf, occupancy);
    return vod_volume_put_brick(vol, b, buf);
}

/* The surface channel's brick b: the tree over the brick grown by one
 * voxel each side, then every voxel at or above S (inside the grid) as an
 * occupied voxel whose normal is minus the density's central-difference
 * gradient (outward: the density grows inwards; a zero gradient, inside a
 * uniform region, encodes +z). */
static int surface_brick(csg_eval *e, vod_volume *vol, const uint32_t b[3], uint32_t *out)
{
    uint32_t s = e->side, n = s + 2;
    box gb = {{(int32_t)(b[0] * s) - 1, (int32_t)(b[1] * s) - 1, (int32_t)(b[2] * s) - 1}, n};
    uint8_t *g = malloc((size_t)n * n * n), v;
    if (!g) return -ENOMEM;
    int rc = eval(e, e->t->n - 1, &gb, g, &v);
    if (rc < 0) {
        free(g);
        return rc;
    }
    e->st.bricks++;
    int inside = 1;
    for (int a = 0; a < 3; a++) inside &= (b[a] + 1) * s <= e->g.res[a];
    if (rc == 1 && (v < CSG_S || inside)) {
        e->st.uniform_bricks++;
        free(g);
        if (v < CSG_S) return vod_volume_put_uniform(vol, b, 0);
        e->st.solid_voxels += (uint64_t)s * s * s;
        const double zero[3] = {0, 0, 0};
        return vod_volume_put_uniform(vol, b, voxel_surface(zero));
    }
    if (rc == 1) memset(g, v, (size_t)n * n * n);
    size_t sy = n, sz = (size_t)n * n, k = 0;
    for (uint32_t z = 0; z < s; z++)
        for (uint32_t y = 0; y < s; y++)
            for (uint32_t x = 0; x < s; x++, k++) {
                const uint8_t *c = g + (x + 1) + sy * (y + 1) + sz * (z + 1);
                out[k] = 0;
                if (b[0] * s + x >= e->g.res[0] || b[1] * s + y >= e->g.res[1] ||
                    b[2] * s + z >= e->g.res[2] || *c < CSG_S)
                    continue;
                double nrm[3] = {(double)c[-1] - c[1], (double)c[-(ptrdiff_t)sy] - c[sy],
                                 (double)c[-(ptrdiff_t)sz] - c[sz]};
                out[k] = voxel_surface(nrm);
                e->st.solid_voxels++;
            }
    free(g);
    return vod_volume_put_brick(vol, b, out);
}

int csg_eval_store(csg_eval *e, vod_volume *vol, const uint32_t b[3], void *buf, int channel)
{
    if (channel == VOXEL_CH_SURFACE) return surface_brick(e, vol, b, buf);
    if (channel == VOXEL_CH_DISTANCE) return csg_deval_store(e, vol, b, buf);
    int uniform;
    uint8_t v;
    int rc = csg_eval_brick(e, b, buf, &uniform, &v);
    return rc ? rc : put(e, vol, b, buf, uniform ? v : -1, channel == VOXEL_CH_OCCUPANCY);
}

int csg_eval_bricks(const csg_tree *t, const grid_spec *g, const vod_volume *const *leaves,
                    const csg_bricks *p, csg_stats *st)
{
    vod_volume *vol = p->vol;
    vod_volume_info in;
    vod_volume_get_info(vol, &in);
    if (in.bits != csg_channel_bits(p->channel)) return -EINVAL;
    for (int a = 0; a < 3; a++)
        if (in.dims[a] != g->res[a]) return -EINVAL;
    csg_eval *e;
    int rc = csg_eval_new(t, g, in.sbrick, leaves, &e);
    if (rc) return rc;
    uint8_t *buf = malloc((size_t)in.sbrick * in.sbrick * in.sbrick * in.bits / 8);
    if (!buf) rc = -ENOMEM;
    uint32_t nb[3];
    for (int a = 0; a < 3; a++) {
        nb[a] = (g->res[a] + in.sbrick - 1) / in.sbrick;
        if (p->hi[a] < nb[a]) nb[a] = p->hi[a];
    }
    uint32_t b[3];
    for (b[2] = p->lo[2]; b[2] < nb[2] && !rc; b[2]++)
        for (b[1] = p->lo[1]; b[1] < nb[1] && !rc; b[1]++)
            for (b[0] = p->lo[0]; b[0] < nb[0] && !rc; b[0]++)
                rc = csg_eval_store(e, vol, b, buf, p->channel);
    if (st) *st = e->st;
    free(buf);
    csg_eval_free(e);
    return rc;
}

int csg_eval_volume(const csg_tree *t, const grid_spec *g, const vod_volume *const *leaves,
                    vod_volume *vol, int channel, csg_stats *st)
{
    csg_bricks all = {.vol = vol, .channel = channel,
                      .hi = {UINT32_MAX, UINT32_MAX, UINT32_MAX}};
    return csg_eval_bricks(t, g, leaves, &all, st);
}

uint32_t csg_channel_bits(int channel)
{
    if (channel == VOXEL_CH_DISTANCE) return VOD_VOLUME_F32;
    return channel == VOXEL_CH_SURFACE ? 32 : channel == VOXEL_CH_DENSITY ||
                                                      channel == VOXEL_CH_OCCUPANCY
                                                  ? 8
                                                  : 0;
}
