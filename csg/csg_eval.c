/* csg_eval — the tree on one brick, bottom-up, deciding whole operand
 * subtrees from a uniform operand where the operator allows. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "voxel.h"

struct csg_eval {
    const csg_tree *t;
    grid_spec g;
    uint32_t side;
    const vod_volume *leaf[CSG_MAX_NODES]; /* mesh and vod leaves' volumes */
    expr_tape *tape[CSG_MAX_NODES];
    expr_vm *vm[CSG_MAX_NODES];
    /* Binary operators: the table op(a, b), and for each value of one
     * operand the result it forces whatever the other, or -1. */
    uint8_t *lut[CSG_MAX_NODES];
    int16_t *force_a[CSG_MAX_NODES], *force_b[CSG_MAX_NODES];
    csg_stats st;
    int has_morph;      /* erode or dilate in the tree: bricks are evaluated whole */
};

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
    int rc = 0;
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

/* 1 when the box's voxel centres all lie inside the convex set where the
 * primitive is H (cone: never claimed), else 0. */
static int prim_all_h(const csg_eval *e, const csg_node *n, const box *b)
{
    double vs = e->g.vs, ei[3];
    for (int i = 0; i < 3; i++) ei[i] = n->size[i] / (2 * vs);
    if (n->kind == CSG_CONE) return 0;
    for (int c = 0; c < 8; c++) {
        double d[3], q[3];
        for (int a = 0; a < 3; a++)
            d[a] = centre(e, a, b->lo[a] + ((c >> a) & 1 ? (int32_t)b->n - 1 : 0)) - n->center[a];
        for (int i = 0; i < 3; i++)
            q[i] = (n->m[i][0] * d[0] + n->m[i][1] * d[1] + n->m[i][2] * d[2]) / vs;
        if (n->kind == CSG_CUBOID) {
            for (int i = 0; i < 3; i++)
                if (fabs(q[i]) > ei[i] - 1.01) return 0;
        } else if (n->kind == CSG_ELLIPSOID) {
            double r = fmin(ei[0], fmin(ei[1], ei[2])) - 1.01;
            if (!(r > 0) || q[0] * q[0] + q[1] * q[1] + q[2] * q[2] > r * r) return 0;
        } else {
            int ax = n->axis, c1 = (ax + 1) % 3, c2 = (ax + 2) % 3;
            double r = fmin(ei[c1], ei[c2]) - 1.01;
            if (!(r > 0) || fabs(q[ax]) > ei[ax] - 1.01 ||
                q[c1] * q[c1] + q[c2] * q[c2] > r * r)
                return 0;
        }
    }
    return 1;
}

/* 1 when the box's voxel centres all lie 2 voxels or more outside the
 * world box around the primitive's rotated local box (L there). */
static int prim_all_l(const csg_eval *e, const csg_node *n, const box *b)
{
    double vs = e->g.vs;
    for (int a = 0; a < 3; a++) {
        double half = 0; /* world half-extent along a: |R| applied to the half sizes */
        for (int i = 0; i < 3; i++) half += fabs(n->m[i][a]) * n->size[i] / 2;
        half += 2 * vs;
        double lo = centre(e, a, b->lo[a]), hi = centre(e, a, b->lo[a] + (int32_t)b->n - 1);
        if (lo > n->center[a] + half || hi < n->center[a] - half) return 1;
    }
    return 0;
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
    _Alignas(64) double px[EXPR_LANES], py[EXPR_LANES], pz[EXPR_LANES];
    expr_grad8 out;
    size_t k = 0;
    for (uint32_t z = 0; z < b->n; z++)
        for (uint32_t y = 0; y < b->n; y++)
            for (uint32_t x0 = 0; x0 < b->n; x0 += EXPR_LANES) {
                uint32_t cnt = b->n - x0 < EXPR_LANES ? b->n - x0 : EXPR_LANES;
                for (uint32_t l = 0; l < EXPR_LANES; l++) {
                    uint32_t x = x0 + (l < cnt ? l : 0); /* unused lanes: a copy */
                    px[l] = centre(e, 0, b->lo[0] + (int32_t)x);
                    py[l] = centre(e, 1, b->lo[1] + (int32_t)y);
                    pz[l] = centre(e, 2, b->lo[2] + (int32_t)z);
                }
                expr_vm_grad8n(e->vm[i], 0, (int)cnt, px, py, pz, &out);
                for (uint32_t l = 0; l < cnt; l++) {
                    double p[3] = {px[l], py[l], pz[l]},
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

/* A primitive over the box in cubes of CSG_SUB voxels: a cube its bounds
 * show all L or all H is filled without sampling (the same values the
 * samples would give: the bounds are the brick-level ones), the others
 * sampled.  Boxes whose side is not a multiple of CSG_SUB are sampled
 * whole. */
#define CSG_SUB 4u
static void sample_prim(csg_eval *e, uint32_t i, const box *b, uint8_t *buf)
{
    const csg_node *n = &e->t->node[i];
    if (b->n % CSG_SUB || b->n == CSG_SUB) {
        sample_leaf(e, i, b, buf);
        return;
    }
    uint8_t sub[CSG_SUB * CSG_SUB * CSG_SUB];
    for (uint32_t z0 = 0; z0 < b->n; z0 += CSG_SUB)
        for (uint32_t y0 = 0; y0 < b->n; y0 += CSG_SUB)
            for (uint32_t x0 = 0; x0 < b->n; x0 += CSG_SUB) {
                box sb = {{b->lo[0] + (int32_t)x0, b->lo[1] + (int32_t)y0,
                           b->lo[2] + (int32_t)z0}, CSG_SUB};
                int v = prim_all_l(e, n, &sb) ? (int)CSG_L : prim_all_h(e, n, &sb) ? (int)CSG_H
                                                                                     : -1;
                if (v < 0) sample_leaf(e, i, &sb, sub);
                for (uint32_t z = 0; z < CSG_SUB; z++)
                    for (uint32_t y = 0; y < CSG_SUB; y++) {
                        uint8_t *row = buf + x0 + (size_t)b->n * (y0 + y + (size_t)b->n * (z0 + z));
                        if (v >= 0) memset(row, v, CSG_SUB);
                        else memcpy(row, sub + CSG_SUB * (y + CSG_SUB * z), CSG_SUB);
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

/* One axis of a separable min (erode) or max (dilate) filter of half-width
 * k: src has dims sd (x fastest), dst the same with axis a shrunk by 2k. */
static void filter_axis(const uint8_t *src, const uint32_t sd[3], int a, uint32_t k,
                        int dilate, uint8_t *dst)
{
    uint32_t dd[3] = {sd[0], sd[1], sd[2]};
    dd[a] -= 2 * k;
    size_t stride = a == 0 ? 1 : a == 1 ? sd[0] : (size_t)sd[0] * sd[1];
    size_t o = 0;
    for (uint32_t z = 0; z < dd[2]; z++)
        for (uint32_t y = 0; y < dd[1]; y++)
            for (uint32_t x = 0; x < dd[0]; x++) {
                const uint8_t *s = src + x + (size_t)sd[0] * (y + (size_t)sd[1] * z);
                uint8_t m = s[0];
                for (uint32_t j = 1; j <= 2 * k; j++) {
                    uint8_t w = s[j * stride];
                    if (dilate ? w > m : w < m) m = w;
                }
                dst[o++] = m;
            }
}

static int morph(csg_eval *e, uint32_t i, const box *b, uint8_t *buf, uint8_t *v)
{
    const csg_node *n = &e->t->node[i];
    box cb = {{b->lo[0] - (int32_t)n->k, b->lo[1] - (int32_t)n->k, b->lo[2] - (int32_t)n->k},
              b->n + 2 * n->k};
    size_t cn = (size_t)cb.n * cb.n * cb.n;
    uint8_t *c = malloc(cn), *tmp = malloc(cn);
    if (!c || !tmp) {
        free(c);
        free(tmp);
        return -ENOMEM;
    }
    int rc = eval(e, (uint32_t)n->a, &cb, c, v);
    if (rc == 0) {
        int dil = n->kind == CSG_DILATE;
        uint32_t d0[3] = {cb.n, cb.n, cb.n}, d1[3] = {b->n, cb.n, cb.n},
                 d2[3] = {b->n, b->n, cb.n};
        filter_axis(c, d0, 0, n->k, dil, tmp);
        filter_axis(tmp, d1, 1, n->k, dil, c);
        filter_axis(c, d2, 2, n->k, dil, buf);
    }
    free(c);
    free(tmp);
    return rc;
}

static int binary_op(csg_eval *e, uint32_t i, const box *b, uint8_t *buf, uint8_t *v)
{
    const csg_node *n = &e->t->node[i];
    size_t count = (size_t)b->n * b->n * b->n;
    uint8_t *a = malloc(count), va, vb;
    if (!a) return -ENOMEM;
    int ua = eval(e, (uint32_t)n->a, b, a, &va);
    if (ua < 0 || (ua == 1 && e->force_a[i][va] >= 0)) {
        if (ua == 1) *v = (uint8_t)e->force_a[i][va], e->st.skipped++;
        free(a);
        return ua;
    }
    int ub = eval(e, (uint32_t)n->b, b, buf, &vb);
    if (ub < 0 || (ub == 1 && e->force_b[i][vb] >= 0) || (ub == 1 && ua == 1)) {
        if (ub == 1) *v = ua == 1 ? e->lut[i][va * 256 + vb] : (uint8_t)e->force_b[i][vb];
        free(a);
        return ub;
    }
    const uint8_t *lut = e->lut[i];
    for (size_t k = 0; k < count; k++) {
        uint8_t x = ua ? va : a[k], y = ub ? vb : buf[k];
        buf[k] = lut[x * 256 + y];
    }
    free(a);
    return 0;
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
        if (prim_all_l(e, n, b)) return *v = CSG_L, 1;
        if (prim_all_h(e, n, b)) return *v = CSG_H, 1;
        sample_prim(e, i, b, buf);
        rc = 0;
        break;
    case CSG_IMPLICIT:
        if (implicit_all_l(e, n, b)) return *v = CSG_L, 1;
        sample_leaf(e, i, b, buf);
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
        return prim_all_l(e, n, b) ? (int)CSG_L : prim_all_h(e, n, b) ? (int)CSG_H : -1;
    case CSG_IMPLICIT:
        return implicit_all_l(e, n, b) ? (int)CSG_L : -1;
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
static int eval_in_cubes(csg_eval *e, const box *bx, uint8_t *out, uint8_t *v)
{
    uint8_t sub[CSG_SUB * CSG_SUB * CSG_SUB], sv;
    for (uint32_t z0 = 0; z0 < bx->n; z0 += CSG_SUB)
        for (uint32_t y0 = 0; y0 < bx->n; y0 += CSG_SUB)
            for (uint32_t x0 = 0; x0 < bx->n; x0 += CSG_SUB) {
                box sb = {{bx->lo[0] + (int32_t)x0, bx->lo[1] + (int32_t)y0,
                           bx->lo[2] + (int32_t)z0}, CSG_SUB};
                int rc = eval(e, e->t->n - 1, &sb, sub, &sv);
                if (rc < 0) return rc;
                for (uint32_t z = 0; z < CSG_SUB; z++)
                    for (uint32_t y = 0; y < CSG_SUB; y++) {
                        uint8_t *row = out + x0 + (size_t)bx->n * (y0 + y + (size_t)bx->n * (z0 + z));
                        if (rc == 1) memset(row, sv, CSG_SUB);
                        else memcpy(row, sub + CSG_SUB * (y + CSG_SUB * z), CSG_SUB);
                    }
            }
    return all_same(out, (size_t)bx->n * bx->n * bx->n, v);
}

int csg_eval_brick(csg_eval *e, const uint32_t b[3], uint8_t *out, int *uniform,
                   uint8_t *value)
{
    box bx = {{(int32_t)(b[0] * e->side), (int32_t)(b[1] * e->side), (int32_t)(b[2] * e->side)},
              e->side};
    int rc, pv;
    if (e->has_morph || e->side % CSG_SUB || e->side == CSG_SUB)
        rc = eval(e, e->t->n - 1, &bx, out, value);
    else if ((pv = probe(e, e->t->n - 1, &bx)) >= 0)
        rc = 1, *value = (uint8_t)pv;
    else
        rc = eval_in_cubes(e, &bx, out, value);
    if (rc < 0) return rc;
    *uniform = rc;
    e->st.bricks++;
    e->st.uniform_bricks += (uint64_t)rc;
    return 0;
}

/* Brick b's voxels past the grid := 0, the voxels at or above S inside it
 * counted; densities to occupancy if asked. */
static void finish(csg_eval *e, const uint32_t b[3], uint8_t *buf, int occupancy)
{
    uint32_t s = e->side;
    uint64_t solid = 0;
    for (uint32_t z = 0; z < s; z++)
        for (uint32_t y = 0; y < s; y++)
            for (uint32_t x = 0; x < s; x++) {
                uint8_t *p = buf + x + (size_t)s * (y + (size_t)s * z);
                if (b[0] * s + x >= e->g.res[0] || b[1] * s + y >= e->g.res[1] ||
                    b[2] * s + z >= e->g.res[2]) {
                    *p = 0;
                    continue;
                }
                solid += *p >= CSG_S;
                if (occupancy) *p = *p >= CSG_S;
            }
    e->st.solid_voxels += solid;
}

static int put(csg_eval *e, vod_volume *vol, const uint32_t b[3], uint8_t *buf, int uniform,
               uint8_t v, int occupancy)
{
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
    int uniform;
    uint8_t v;
    int rc = csg_eval_brick(e, b, buf, &uniform, &v);
    return rc ? rc : put(e, vol, b, buf, uniform, v, channel == VOXEL_CH_OCCUPANCY);
}

int csg_eval_bricks(const csg_tree *t, const grid_spec *g, const vod_volume *const *leaves,
                    vod_volume *vol, int channel, const uint32_t lo[3], const uint32_t hi[3],
                    csg_stats *st)
{
    vod_volume_info in;
    vod_volume_get_info(vol, &in);
    if (in.bits != csg_channel_bits(channel)) return -EINVAL;
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
        if (hi && hi[a] < nb[a]) nb[a] = hi[a];
    }
    uint32_t b[3];
    for (b[2] = lo ? lo[2] : 0; b[2] < nb[2] && !rc; b[2]++)
        for (b[1] = lo ? lo[1] : 0; b[1] < nb[1] && !rc; b[1]++)
            for (b[0] = lo ? lo[0] : 0; b[0] < nb[0] && !rc; b[0]++)
                rc = csg_eval_store(e, vol, b, buf, channel);
    if (st) *st = e->st;
    free(buf);
    csg_eval_free(e);
    return rc;
}

int csg_eval_volume(const csg_tree *t, const grid_spec *g, const vod_volume *const *leaves,
                    vod_volume *vol, int channel, csg_stats *st)
{
    return csg_eval_bricks(t, g, leaves, vol, channel, NULL, NULL, st);
}

uint32_t csg_channel_bits(int channel)
{
    return channel == VOXEL_CH_SURFACE ? 32 : channel == VOXEL_CH_DENSITY ||
                                                      channel == VOXEL_CH_OCCUPANCY
                                                  ? 8
                                                  : 0;
}
