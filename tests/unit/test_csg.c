/* Volume CSG: the operators against the thesis's formulas (written here
 * again, not taken from the code), identities, the primitives' volumes,
 * brick-by-brick evaluation against a slow dense one, and parse errors. */
#include <criterion/criterion.h>
#include <errno.h>
#include <stdio.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "csg_fixture.h"
#include "voxel.h"

/* ICVG section 3.3 and its appendix, L = 0, S = 127, H = 255. */
static int ref_op(csg_kind op, int a, int b, double p)
{
    int L = 0, S = 127, H = 255;
    switch (op) {
    case CSG_UNION: return a > b ? a : b;
    case CSG_INTERSECTION: return a < b ? a : b;
    case CSG_TRIM: return a >= b ? a : L;
    case CSG_CAP: return a <= b ? a : L;
    case CSG_DIFFERENCE_A: return a - b > L ? a - b : L;
    case CSG_DIFFERENCE_B: return b >= S ? (a - b > L ? a - b : L) : a;
    case CSG_DIFFERENCE:
        if (a >= S && b < S) return a - b > S ? a - b : S;
        return a - b > L ? a - b : L;
    case CSG_ADD: return a + b < H ? a + b : H;
    case CSG_MODULATE: return a * b < H ? a * b : H;
    case CSG_DIVIDE_A: return b != 0 ? a / b : H;
    case CSG_DIVIDE: {
        if (b == 0) return H;
        double q = floor(a / (b * p));
        return q < H ? (int)q : H;
    }
    default: return -1;
    }
}

Test(csg, binary_operators_on_every_pair)
{
    const csg_kind ops[] = {CSG_UNION, CSG_INTERSECTION, CSG_TRIM, CSG_CAP,
                            CSG_DIFFERENCE_A, CSG_DIFFERENCE_B, CSG_DIFFERENCE, CSG_ADD,
                            CSG_MODULATE, CSG_DIVIDE_A, CSG_DIVIDE};
    const double sl[] = {1, 0.5, 0.3};
    for (size_t o = 0; o < sizeof ops / sizeof *ops; o++)
        for (size_t s = 0; s < (ops[o] == CSG_DIVIDE ? 3u : 1u); s++)
            for (int a = 0; a < 256; a++)
                for (int b = 0; b < 256; b++)
                    cr_assert_eq(csg_apply(ops[o], (uint8_t)a, (uint8_t)b, sl[s]),
                                 ref_op(ops[o], a, b, sl[s]), "%s(%d, %d)",
                                 csg_kind_name(ops[o]), a, b);
}

Test(csg, unary_operators)
{
    for (int a = 0; a < 256; a++) {
        cr_assert_eq(csg_apply(CSG_INVERSE, (uint8_t)a, 0, 0), 255 - a);
        cr_assert_eq(csg_apply(CSG_INVERSE, csg_apply(CSG_INVERSE, (uint8_t)a, 0, 0), 0, 0), a);
        int add = a + 40 > 255 ? 255 : a + 40, sub = a - 40 < 0 ? 0 : a - 40;
        cr_assert_eq(csg_apply(CSG_SCALAR_ADD, (uint8_t)a, 0, 40), add);
        cr_assert_eq(csg_apply(CSG_SCALAR_ADD, (uint8_t)a, 0, -40), sub);
        int mul = (int)floor(a * 1.5);
        cr_assert_eq(csg_apply(CSG_SCALAR_MUL, (uint8_t)a, 0, 1.5), mul > 255 ? 255 : mul);
        /* identities */
        cr_assert_eq(csg_apply(CSG_UNION, (uint8_t)a, (uint8_t)a, 0), a);
        cr_assert_eq(csg_apply(CSG_DIFFERENCE, (uint8_t)a, 0, 0), a);
        cr_assert_eq(csg_apply(CSG_INTERSECTION, (uint8_t)a, 255, 0), a);
    }
}

/* The slow dense evaluator: node i at voxel (X, Y, Z), recursively. */
static uint8_t dense(const csg_tree *t, const grid_spec *g, int i, int X, int Y, int Z)
{
    const csg_node *n = &t->node[i];
    if (n->kind <= CSG_CONE) {
        double p[3] = {grid_coord(g, 0, X + 0.5), grid_coord(g, 1, Y + 0.5),
                       grid_coord(g, 2, Z + 0.5)};
        return csg_prim_sample(n, p, g->vs);
    }
    if (n->kind == CSG_ERODE || n->kind == CSG_DILATE) {
        int k = (int)n->k, m = n->kind == CSG_ERODE ? 255 : 0;
        for (int dz = -k; dz <= k; dz++)
            for (int dy = -k; dy <= k; dy++)
                for (int dx = -k; dx <= k; dx++) {
                    int v = dense(t, g, n->a, X + dx, Y + dy, Z + dz);
                    m = n->kind == CSG_ERODE ? (v < m ? v : m) : (v > m ? v : m);
                }
        return (uint8_t)m;
    }
    uint8_t a = dense(t, g, n->a, X, Y, Z);
    uint8_t b = n->b >= 0 ? dense(t, g, n->b, X, Y, Z) : 0;
    return csg_apply(n->kind, a, b, n->param);
}

static const char tree_src[] =
    "# a tree of every primitive\n"
    "box = cuboid center 0.1,0,0 size 1.2,0.9,0.7 rotate 10,20,30\n"
    "ball = ellipsoid center 0.3,0.2,0.1 radii 0.5,0.4,0.35\n"
    "rod = cylinder center 0,0,0 radius 0.2 height 1.8 axis x rotate 0,0,15\n"
    "tip = cone center -0.4,-0.3,0.3 radius 0.3 height 0.8 axis y\n"
    "a = difference(union(box, tip), rod)\n"
    "b = dilate(intersection(ball, inverse(rod)), 2)\n"
    "c = erode(differenceA(a, ball), 1)\n"
    "out = union(c, trim(b, scale_add(tip, 10)))\n"
    "result out\n";

Test(csg, bricks_equal_dense_evaluation)
{
    csg_tree *t = parse(tree_src);
    grid_spec g = grid(40);
    csg_eval *e;
    cr_assert_eq(csg_eval_new(t, &g, 8, NULL, &e), 0);
    uint8_t buf[512];
    uint64_t differ = 0;
    for (uint32_t bz = 0; bz < 5; bz++)
        for (uint32_t by = 0; by < 5; by++)
            for (uint32_t bx = 0; bx < 5; bx++) {
                uint32_t b[3] = {bx, by, bz};
                int uni;
                uint8_t v;
                cr_assert_eq(csg_eval_brick(e, b, buf, &uni, &v), 0);
                for (int z = 0; z < 8; z++)
                    for (int y = 0; y < 8; y++)
                        for (int x = 0; x < 8; x++) {
                            uint8_t got = uni ? v : buf[x + 8 * (y + 8 * z)];
                            differ += got != dense(t, &g, (int)t->n - 1, (int)(bx * 8) + x,
                                                   (int)(by * 8) + y, (int)(bz * 8) + z);
                        }
            }
    cr_assert_eq(differ, 0, "%llu voxels differ", (unsigned long long)differ);
    cr_assert_gt(csg_eval_stats(e)->uniform_bricks, 0);
    cr_assert_gt(csg_eval_stats(e)->skipped, 0);
    csg_eval_free(e);
    csg_tree_free(t);
}

static vod_volume *density_volume(const grid_spec *g, void **arena)
{
    size_t bytes = vod_volume_bytes(g->res, 8, CSG_VOLUME_BRICK, UINT64_MAX);
    vod_volume *v;
    cr_assert(bytes && (*arena = malloc(bytes)));
    cr_assert_eq(vod_volume_init(&v, *arena, bytes, g->res, 8, CSG_VOLUME_BRICK), 0);
    return v;
}

/* csg_eval_bricks stores its part's bricks as csg_eval_volume does and
 * leaves the others alone (a hi past the volume's end stops there). */
Test(csg, some_bricks_as_the_whole_volume_has_them)
{
    csg_tree *t = parse(tree_src);
    grid_spec g = grid(40); /* 3 storage bricks of 16 per axis, the last short */
    void *wa, *pa;
    vod_volume *whole = density_volume(&g, &wa), *part = density_volume(&g, &pa);
    cr_assert_eq(csg_eval_volume(t, &g, NULL, whole, VOXEL_CH_DENSITY, NULL), 0);
    csg_bricks p = {.vol = part, .channel = VOXEL_CH_DENSITY, .lo = {1, 0, 1},
                    .hi = {3, 1, UINT32_MAX}};
    csg_stats st;
    cr_assert_eq(csg_eval_bricks(t, &g, NULL, &p, &st), 0);
    cr_assert_eq(st.bricks, 2 * 1 * 2, "%llu bricks", (unsigned long long)st.bricks);
    uint64_t in = 0, out = 0;
    for (uint32_t z = 0; z < 40; z++)
        for (uint32_t y = 0; y < 40; y++)
            for (uint32_t x = 0; x < 40; x++) {
                uint32_t w = vod_volume_get(whole, x, y, z), got = vod_volume_get(part, x, y, z);
                int inside = x >= 16 && y < 16 && z >= 16;
                cr_assert_eq(got, inside ? w : 0, "(%u,%u,%u): %u, the whole volume's %u", x, y,
                             z, got, w);
                in += inside && w, out += !inside && w;
            }
    cr_assert(in > 0 && out > 0, "%llu, %llu", (unsigned long long)in, (unsigned long long)out);
    free(wa);
    free(pa);
    csg_tree_free(t);
}

/* Wider erode and dilate (rows of the filter longer than eight bytes),
 * on bricks of 16 and of an odd side. */
Test(csg, wide_erode_and_dilate_equal_dense_evaluation, .timeout = 60)
{
    csg_tree *t = parse("a = ellipsoid center 0.1,0,0 radii 0.5,0.4,0.3 rotate 0,30,0\n"
                        "b = cuboid size 1.0,0.7,0.9 rotate 20,0,0\n"
                        "c = union(dilate(a, 4), erode(b, 3))\nresult c\n");
    grid_spec g = grid(24);
    static const uint32_t sides[] = {16, 7};
    for (int s = 0; s < 2; s++) {
        uint32_t side = sides[s], nb = (24 + side - 1) / side;
        csg_eval *e;
        cr_assert_eq(csg_eval_new(t, &g, side, NULL, &e), 0);
        uint8_t buf[4096];
        uint64_t differ = 0;
        for (uint32_t k = 0; k < nb * nb * nb; k++) {
            uint32_t b[3] = {k % nb, k / nb % nb, k / (nb * nb)};
            int uni;
            uint8_t v;
            cr_assert_eq(csg_eval_brick(e, b, buf, &uni, &v), 0);
            for (uint32_t j = 0; j < side * side * side; j++) {
                int X = (int)(b[0] * side + j % side), Y = (int)(b[1] * side + j / side % side),
                    Z = (int)(b[2] * side + j / (side * side));
                if (X < 24 && Y < 24 && Z < 24)
                    differ += (uni ? v : buf[j]) != dense(t, &g, (int)t->n - 1, X, Y, Z);
            }
        }
        cr_assert_eq(differ, 0, "bricks of %u: %llu voxels differ", side,
                     (unsigned long long)differ);
        csg_eval_free(e);
    }
    csg_tree_free(t);
}

/* Voxels >= S lie inside the primitive, > S farther in: the counts bound
 * its analytic volume (in voxels). */
static void volume_bound(const char *src, double volume)
{
    csg_tree *t = parse(src);
    grid_spec g = grid(64);
    uint64_t ge = 0, gt = 0;
    for (int z = 0; z < 64; z++)
        for (int y = 0; y < 64; y++)
            for (int x = 0; x < 64; x++) {
                double p[3] = {grid_coord(&g, 0, x + 0.5), grid_coord(&g, 1, y + 0.5),
                               grid_coord(&g, 2, z + 0.5)};
                uint8_t d = csg_prim_sample(&t->node[0], p, g.vs);
                ge += d >= CSG_S;
                gt += d > CSG_S;
            }
    double v = volume / (g.vs * g.vs * g.vs);
    /* centres inside estimate the volume within about half a voxel of
     * surface; allow 10% plus a voxel shell */
    cr_assert(fabs((double)ge - v) < 0.1 * v, "%s: %llu voxels >= S, volume %.0f", src,
              (unsigned long long)ge, v);
    cr_assert_leq(gt, ge);
    cr_assert_lt(gt, v, "%s: %llu voxels > S, volume %.0f", src, (unsigned long long)gt, v);
    csg_tree_free(t);
}

Test(csg, primitive_volumes)
{
    volume_bound("p = cuboid center 0,0,0 size 1.2,1,0.8 rotate 30,0,20\nresult p\n",
                 1.2 * 1 * 0.8);
    volume_bound("p = ellipsoid center 0.1,0,0 radii 0.7,0.5,0.4\nresult p\n",
                 4.0 / 3 * M_PI * 0.7 * 0.5 * 0.4);
    volume_bound("p = cylinder center 0,0,0 radius 0.4 height 1.4 axis y rotate 0,0,45\nresult p\n",
                 M_PI * 0.4 * 0.4 * 1.4);
    volume_bound("p = cone center 0,0,0 radii 0.6,0.5 height 1.5\nresult p\n",
                 M_PI * 0.6 * 0.5 * 1.5 / 3);
}

Test(csg, erode_of_dilate_contains)
{
    csg_tree *t = parse("s = ellipsoid center 0,0,0 radius 0.5\n"
                        "d = erode(dilate(s, 2), 2)\nresult d\n");
    grid_spec g = grid(24);
    for (int z = 0; z < 24; z++)
        for (int y = 0; y < 24; y++)
            for (int x = 0; x < 24; x++)
                cr_assert_geq(dense(t, &g, 2, x, y, z), dense(t, &g, 0, x, y, z));
    csg_tree_free(t);
}

static void bad(const char *src, int line, const char *msg)
{
    csg_tree *t;
    csg_error err;
    int rc = csg_parse(src, strlen(src), &t, &err);
    cr_assert_neq(rc, 0, "%s", src);
    cr_assert_eq(err.code, rc, "%s: code %d, returned %d", src, err.code, rc);
    cr_assert_eq(err.line, line, "%s: line %d (%s)", src, err.line, err.msg);
    cr_assert(strstr(err.msg, msg), "%s: '%s' lacks '%s'", src, err.msg, msg);
}

/* A limit's error is -E2BIG through every level of the tree: an
 * expression nested past its depth in an implicit leaf, operators nested
 * past CSG_MAX_DEPTH (each operand's code passed up, not made -EINVAL). */
Test(csg, parse_errors_keep_their_codes)
{
    char src[4096];
    int n = snprintf(src, sizeof src, "a = implicit \"");
    for (int i = 0; i < 300; i++) src[n++] = '(';
    src[n++] = 'x';
    for (int i = 0; i < 300; i++) src[n++] = ')';
    snprintf(src + n, sizeof src - (size_t)n, "\"\nresult a\n");
    csg_tree *t;
    csg_error err;
    cr_assert_eq(csg_parse(src, strlen(src), &t, &err), -E2BIG, "%s", err.msg);
    cr_assert(strstr(err.msg, "in the expression"), "%s", err.msg);
    n = snprintf(src, sizeof src, "b = sphere radius 1\na = ");
    for (unsigned i = 0; i < CSG_MAX_DEPTH + 2; i++)
        n += snprintf(src + n, sizeof src - (size_t)n, "inverse(");
    n += snprintf(src + n, sizeof src - (size_t)n, "b");
    for (unsigned i = 0; i < CSG_MAX_DEPTH + 2; i++) src[n++] = ')';
    snprintf(src + n, sizeof src - (size_t)n, "\nresult a\n");
    cr_assert_eq(csg_parse(src, strlen(src), &t, &err), -E2BIG, "%s", err.msg);
    cr_assert_eq(err.code, -E2BIG);
    cr_assert(strstr(err.msg, "nested deeper"), "%s", err.msg);
    bad("a = implicit \"x +* y\"\nresult a\n", 1, "expression");
    const char *malformed = "a = implicit \"x +* y\"\nresult a\n";
    cr_assert_eq(csg_parse(malformed, strlen(malformed), &t, &err), -EINVAL);
}

Test(csg, parse_errors)
{
    bad("a = union(b, a)\nb = cuboid size 1,1,1\nresult a\n", 1, "cycle");
    bad("a = union(b, c)\nb = cuboid size 1,1,1\nresult a\n", 1, "unknown node 'c'");
    bad("a = cuboid size 1,1,1\nb = union(a)\nresult b\n", 2, "expected ','");
    bad("a = cuboid size 1,1,1\nb = inverse(a, a)\nresult b\n", 2, "takes 1 node");
    bad("a = cuboid size 1,-1,1\nresult a\n", 1, "positive");
    bad("a = cuboid size 1,1,1\nb = divide(a, a, 2)\nresult b\n", 2, "S_L");
    bad("a = cuboid size 1,1,1\nb = dilate(a, 99)\nresult b\n", 2, "whole number");
    bad("a = implicit \"x +* y\"\nresult a\n", 1, "expression");
    bad("a = cuboid size 1,1,1\n", 0, "result");
    bad("a = cuboid size 1,1,1\na = cuboid size 1,1,1\nresult a\n", 2, "twice");
    bad("a = frob size 1\nresult a\n", 1, "unknown");
    bad("a = mesh x.ply\nresult a\n", 1, "mesh needs its file's name in double quotes");
    bad("a = mesh \"x.ply\" fit 1,2\nresult a\n", 1, "");
    bad("a = mesh \"x.ply\" scale -1\nresult a\n", 1, "scale must be positive");
    bad("a = mesh \"x.ply\" center 0,0,0\nresult a\n", 1, "mesh takes fit and scale, not 'center'");
    bad("a = vod \"x.vod\" scale 2\nresult a\n", 1, "vod takes only its file's name");
    bad("a = vod \"\"\nresult a\n", 1, "the file name is empty");
    bad("a = vod \"x.vod\nresult a\n", 1, "quote is not closed");
    bad("a = cuboid\nresult a\n", 1, "needs its size");
    /* the node's name comes with the error */
    csg_tree *t;
    csg_error err;
    const char *s = "ok = cuboid size 1,1,1\nhole = cylinder radius 0 height 1\nresult ok\n";
    cr_assert_neq(csg_parse(s, strlen(s), &t, &err), 0);
    cr_assert_str_eq(err.node, "hole");
    cr_assert_gt(err.col, 16); /* within the cylinder's parameters */
}
