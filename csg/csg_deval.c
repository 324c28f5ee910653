/* csg_deval — channel 4 of a tree: its signed distance, brick by brick
 * (docs/csg.md, "Signed distance").
 *
 * Every leaf gives its signed distance in world units, negative inside,
 * within a band of W = K vs and +-W beyond (the same float W for every
 * leaf): an implicit leaf by csg_dist (a certified upper bound of the
 * distance to F = 0), a mesh leaf from the f32 volume of its exact
 * distance that csg_leaf_build made once per job (mesh_dist's per-brick
 * closest points).  The operators combine them voxel by voxel:
 *   union        min(a, b)
 *   intersection max(a, b)
 *   difference   max(a, -b)
 *   inverse      -a
 * Clamping to [-W, W] is monotone and odd, so it commutes with min, max
 * and negation: the result is the clamp of the combination of the
 * unclamped distances, and its band (|value| < W) is recomputed from the
 * combined values, not taken from the leaves' (a leaf's band voxel that
 * the other operand covers goes to +-W).  The sign is the CSG membership
 * of the voxel centre, exactly, whenever the leaves' signs are; where the
 * magnitude is exact and where it is a lower bound is docs/csg.md's.
 *
 * A uniform operand (a brick beyond one leaf's band) that decides the
 * operator (-W for a union, +W for an intersection or difference's first
 * operand) decides the brick without evaluating the other one.  A brick is
 * a pure function of (tree, grid, band, brick): any worker, the same
 * bytes. */
#include <assert.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "csg_eval_int.h"
#include "voxel.h"

static const char *no_distance(const csg_node *n)
{
    switch (n->kind) {
    case CSG_IMPLICIT:
        return n->has_domain ? "an implicit leaf with a domain has no signed distance (the "
                               "domain's cut faces are not a surface of F)"
                             : NULL;
    case CSG_MESH: case CSG_UNION: case CSG_INTERSECTION: case CSG_DIFFERENCE: case CSG_INVERSE:
        return NULL;
    case CSG_CUBOID: case CSG_ELLIPSOID: case CSG_CYLINDER: case CSG_CONE:
        return "a primitive has no signed distance yet (write it as an implicit leaf)";
    case CSG_VOD:
        return "a vod leaf has no signed distance";
    default:
        return "this operator does not combine distances (union, intersection, difference "
               "and inverse do)";
    }
}

int csg_dist_check(const csg_tree *t, err_info *err)
{
    assert(t->n > 0); /* the parser and proto_check refuse a tree without a node */
    uint8_t used[CSG_MAX_NODES] = {0};
    used[t->n - 1] = 1;
    for (uint32_t i = t->n; i-- > 0;) { /* children come before their parents */
        if (!used[i]) continue;
        const csg_node *n = &t->node[i];
        const char *why = no_distance(n);
        if (why)
            return err_set(err, -ENOTSUP, "node '%s' (%s): %s", n->name,
                           csg_kind_name(n->kind), why);
        if (n->a >= 0) used[n->a] = 1;
        if (n->b >= 0) used[n->b] = 1;
    }
    return 0;
}

void csg_tree_set_band(csg_tree *t, uint32_t band)
{
    for (uint32_t i = 0; i < t->n; i++)
        if (t->node[i].kind == CSG_IMPLICIT || t->node[i].kind == CSG_MESH) t->node[i].k = band;
}

uint32_t csg_leaf_bits(const csg_node *n)
{
    return n->kind == CSG_MESH && n->k ? VOD_VOLUME_F32 : 8;
}

void csg_deval_free(csg_eval *e)
{
    for (uint32_t i = 0; i < CSG_MAX_NODES; i++) csg_dist_free(e->dist[i]);
    for (uint32_t i = 0; i <= CSG_MAX_DEPTH; i++) free(e->dscratch[i]);
}

static uint32_t band_of(const csg_node *n) { return n->k ? n->k : VOXEL_BAND_DEFAULT; }

/* The band's width as the leaves store it beyond the band (their k, one
 * band for the tree: csg_tree_set_band). */
static float width(const csg_eval *e)
{
    for (uint32_t i = 0; i < e->t->n; i++)
        if (e->t->node[i].kind == CSG_IMPLICIT || e->t->node[i].kind == CSG_MESH)
            return (float)(band_of(&e->t->node[i]) * e->g.vs);
    return 0;
}

/* 1 and *u when the brick's voxels inside the grid all hold one value. */
static int uniform_in_grid(const csg_eval *e, const uint32_t lo[3], const float *v, float *u)
{
    uint32_t s = e->side, n[3];
    for (int a = 0; a < 3; a++) n[a] = e->g.res[a] - lo[a] < s ? e->g.res[a] - lo[a] : s;
    for (uint32_t z = 0; z < n[2]; z++)
        for (uint32_t y = 0; y < n[1]; y++)
            for (uint32_t x = 0; x < n[0]; x++)
                if (memcmp(&v[x + s * (y + (size_t)s * z)], v, sizeof *v)) return 0;
    *u = v[0];
    return 1;
}

static int implicit_leaf(csg_eval *e, uint32_t i, const uint32_t lo[3], float *out, float *u)
{
    int rc = 0;
    if (!e->dist[i]) rc = csg_dist_new(e->tape[i], &e->g, band_of(&e->t->node[i]), &e->dist[i]);
    if (rc) return rc;
    uint64_t v0 = csg_dist_get_stats(e->dist[i])->band_voxels;
    if ((rc = csg_dist_brick(e->dist[i], lo, e->side, out))) return rc;
    e->st.voxel_evals += csg_dist_get_stats(e->dist[i])->band_voxels - v0;
    return uniform_in_grid(e, lo, out, u);
}

/* A mesh leaf's distance volume over the brick: uniform from its table, or
 * read (0 past the grid). */
static int mesh_leaf(csg_eval *e, uint32_t i, const uint32_t lo[3], float *out, float *u)
{
    const vod_volume *vol = e->leaf[i];
    int64_t at[3] = {lo[0], lo[1], lo[2]};
    uint32_t bits, s = e->side;
    if (vod_volume_box_uniform(vol, at, s, &bits)) {
        memcpy(u, &bits, sizeof *u);
        return 1;
    }
    size_t k = 0;
    for (uint32_t z = 0; z < s; z++)
        for (uint32_t y = 0; y < s; y++)
            for (uint32_t x = 0; x < s; x++, k++) {
                bits = vod_volume_get(vol, lo[0] + x, lo[1] + y, lo[2] + z);
                memcpy(&out[k], &bits, sizeof bits);
            }
    return uniform_in_grid(e, lo, out, u);
}

/* The operator's value when its first operand is uniformly a (+-W): the
 * result whatever the other, or 0 when it depends on it. */
static int forced(csg_kind op, float a, float w, float *r)
{
    if ((op == CSG_UNION && a <= -w) || (op != CSG_UNION && a >= w)) {
        *r = a;
        return 1;
    }
    return 0;
}

static float combine(csg_kind op, float a, float b)
{
    switch (op) {
    case CSG_UNION: return b < a ? b : a;
    case CSG_INTERSECTION: return b > a ? b : a;
    default: return -b > a ? -b : a; /* difference: max(a, -b) */
    }
}

static int deval(csg_eval *e, uint32_t i, const uint32_t lo[3], uint32_t depth, float *out,
                 float *u);

/* A binary operator: operand a into out, b into this depth's scratch. */
static int binary(csg_eval *e, uint32_t i, const uint32_t lo[3], uint32_t depth, float *out,
                  float *u)
{
    const csg_node *n = &e->t->node[i];
    size_t nv = (size_t)e->side * e->side * e->side;
    if (depth > CSG_MAX_DEPTH) return -EINVAL;
    if (!e->dscratch[depth] && !(e->dscratch[depth] = malloc(nv * sizeof(float))))
        return -ENOMEM;
    float *tmp = e->dscratch[depth], ua, ub;
    int ra = deval(e, (uint32_t)n->a, lo, depth + 1, out, &ua);
    if (ra < 0) return ra;
    if (ra == 1 && forced(n->kind, ua, e->dwidth, u)) {
        e->st.skipped++;
        return 1;
    }
    int rb = deval(e, (uint32_t)n->b, lo, depth + 1, tmp, &ub);
    if (rb < 0) return rb;
    if (ra == 1 && rb == 1) {
        *u = combine(n->kind, ua, ub);
        return 1;
    }
    for (size_t k = 0; k < nv; k++)
        out[k] = combine(n->kind, ra ? ua : out[k], rb ? ub : tmp[k]);
    return uniform_in_grid(e, lo, out, u);
}

/* Node i over the brick from voxel lo: 1 and *u when uniform (out then
 * undefined), 0 with out filled, or a negative errno. */
static int deval(csg_eval *e, uint32_t i, const uint32_t lo[3], uint32_t depth, float *out,
                 float *u)
{
    const csg_node *n = &e->t->node[i];
    switch (n->kind) {
    case CSG_IMPLICIT:
        return n->has_domain ? -ENOTSUP : implicit_leaf(e, i, lo, out, u);
    case CSG_MESH:
        return csg_leaf_bits(n) == VOD_VOLUME_F32 ? mesh_leaf(e, i, lo, out, u) : -EINVAL;
    case CSG_INVERSE: {
        int rc = deval(e, (uint32_t)n->a, lo, depth + 1, out, u);
        if (rc == 1) *u = -*u;
        if (rc) return rc;
        for (size_t k = 0, nv = (size_t)e->side * e->side * e->side; k < nv; k++) out[k] = -out[k];
        return 0;
    }
    case CSG_UNION: case CSG_INTERSECTION: case CSG_DIFFERENCE:
        return binary(e, i, lo, depth, out, u);
    default:
        return -ENOTSUP;
    }
}

/* Brick b's voxels past the grid := 0 (the file's and vod_volume's rule),
 * the voxels inside with a negative value counted. */
static void finish(csg_eval *e, const uint32_t lo[3], float *out)
{
    uint32_t s = e->side;
    size_t k = 0;
    for (uint32_t z = 0; z < s; z++)
        for (uint32_t y = 0; y < s; y++)
            for (uint32_t x = 0; x < s; x++, k++) {
                if (lo[0] + x >= e->g.res[0] || lo[1] + y >= e->g.res[1] ||
                    lo[2] + z >= e->g.res[2])
                    out[k] = 0;
                else
                    e->st.solid_voxels += out[k] < 0;
            }
}

int csg_deval_store(csg_eval *e, vod_volume *vol, const uint32_t b[3], void *buf)
{
    float *out = buf, u;
    uint32_t s = e->side, lo[3] = {b[0] * s, b[1] * s, b[2] * s};
    size_t nv = (size_t)s * s * s;
    if (!e->dwidth) e->dwidth = width(e);
    int rc = deval(e, e->t->n - 1, lo, 0, out, &u);
    if (rc < 0) return rc;
    if (rc == 1)
        for (size_t k = 0; k < nv; k++) out[k] = u;
    finish(e, lo, out);
    e->st.bricks++;
    size_t k = 1;
    while (k < nv && !memcmp(&out[k], &out[0], sizeof *out)) k++;
    e->st.uniform_bricks += k == nv;
    return vod_volume_put_brick(vol, b, out);
}
