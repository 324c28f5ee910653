/* The CSG evaluator's shortcuts (bricks and 4^3 cubes decided from a
 * primitive's bounds in its own frame, or from intervals of an implicit
 * leaf's F and gradient) against a slow dense evaluation, on shapes whose
 * surfaces and ramp ends pass through or near voxel centres, so that every
 * decision is a close one. */
#include <criterion/criterion.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"
#include "csg_fixture.h"

#define RES 48

/* ---- the reference: every voxel from the definitions (docs/csg.md) ---- */

typedef struct {
    const csg_tree *t;
    const grid_spec *g;
    expr_vm *vm[CSG_MAX_NODES];
    expr_tape *tape[CSG_MAX_NODES];
} dense_ctx;

/* An implicit leaf at a voxel: L outside its domain; else S + 128 t with
 * t = -F / |grad F| / vs (F and its gradient as the expression module
 * defines them), floored and clamped to [L, H], NaN as L. */
static uint8_t dense_implicit(dense_ctx *d, int i, const double p[3])
{
    const csg_node *n = &d->t->node[i];
    if (n->has_domain)
        for (int a = 0; a < 3; a++)
            if (!(p[a] >= n->dom_lo && p[a] <= n->dom_hi)) return 0;
    double gr[3], f = expr_vm_grad(d->vm[i], 0, p[0], p[1], p[2], gr);
    double t = -f / sqrt(gr[0] * gr[0] + gr[1] * gr[1] + gr[2] * gr[2]) / d->g->vs;
    double v = 127 + t * 128;
    return !(v > 0) ? 0 : v >= 255 ? 255 : (uint8_t)floor(v);
}

static uint8_t dense(dense_ctx *d, int i, int X, int Y, int Z)
{
    const csg_node *n = &d->t->node[i];
    double p[3] = {grid_coord(d->g, 0, X + 0.5), grid_coord(d->g, 1, Y + 0.5),
                   grid_coord(d->g, 2, Z + 0.5)};
    if (n->kind <= CSG_CONE) return csg_prim_sample(n, p, d->g->vs);
    if (n->kind == CSG_IMPLICIT) return dense_implicit(d, i, p);
    uint8_t a = dense(d, n->a, X, Y, Z), b = n->b >= 0 ? dense(d, n->b, X, Y, Z) : 0;
    return csg_apply(n->kind, a, b, n->param);
}

/* Every brick of side `side` against the dense evaluation; the voxels the
 * leaves sampled (the shortcuts must have spared most). */
static uint64_t check(const char *src, uint32_t side)
{
    csg_tree *t = parse(src);
    grid_spec g = grid(RES);
    dense_ctx d = {.t = t, .g = &g};
    for (uint32_t i = 0; i < t->n; i++)
        if (t->node[i].kind == CSG_IMPLICIT) {
            expr_error ee;
            cr_assert_eq(expr_compile(t->text + t->node[i].expr_off, t->node[i].expr_len, NULL,
                                      &d.tape[i], &ee), 0);
            cr_assert_eq(expr_vm_new(d.tape[i], 0, &d.vm[i]), 0);
        }
    csg_eval *e;
    cr_assert_eq(csg_eval_new(t, &g, side, NULL, &e), 0);
    uint8_t *buf = malloc((size_t)side * side * side);
    uint32_t nb = (RES + side - 1) / side;
    uint64_t differ = 0;
    for (uint32_t bz = 0; bz < nb; bz++)
        for (uint32_t by = 0; by < nb; by++)
            for (uint32_t bx = 0; bx < nb; bx++) {
                uint32_t b[3] = {bx, by, bz};
                int uni;
                uint8_t v;
                cr_assert_eq(csg_eval_brick(e, b, buf, &uni, &v), 0);
                for (uint32_t k = 0; k < side * side * side; k++) {
                    int X = (int)(bx * side + k % side), Y = (int)(by * side + k / side % side),
                        Z = (int)(bz * side + k / (side * side));
                    if (X >= RES || Y >= RES || Z >= RES) continue;
                    uint8_t want = dense(&d, (int)t->n - 1, X, Y, Z), got = uni ? v : buf[k];
                    if (got != want && differ++ < 3)
                        cr_log_error("%s: voxel %d,%d,%d: %u, dense %u", src, X, Y, Z, got, want);
                }
            }
    cr_assert_eq(differ, 0, "%s (bricks of %u): %llu voxels differ", src, side,
                 (unsigned long long)differ);
    uint64_t evals = csg_eval_stats(e)->voxel_evals;
    free(buf);
    csg_eval_free(e);
    for (uint32_t i = 0; i < t->n; i++) {
        expr_vm_free(d.vm[i]);
        expr_tape_free(d.tape[i]);
    }
    csg_tree_free(t);
    return evals;
}

/* A length of k half voxels (RES voxels over 2 units), so that faces and
 * radii land on voxel centres or on the faces between voxels. */
static double halves(int k) { return k * (1.0 / RES); }

Test(csg_bounds, primitives_on_and_near_voxel_centres, .timeout = 120)
{
    static const char *const kinds[] = {"cuboid", "ellipsoid", "cylinder", "cone"};
    static const char *const rots[] = {"0,0,0", "0,0,90", "90,0,0", "0,45,0", "10,20,30",
                                       "0,0,10", "33,0,71"};
    srand(11);
    uint64_t evals = 0, voxels = 0;
    for (int s = 0; s < 28; s++) {
        const char *k = kinds[s % 4];
        int a = 20 + rand() % 40, b = 14 + rand() % 40, c = 10 + rand() % 40;
        /* centres on a voxel centre, a face between voxels, or anywhere */
        double cx = halves(rand() % 9 - 4), cy = halves(rand() % 9 - 4),
               cz = s % 3 == 2 ? (rand() % 1000) / 4000.0 - 0.125 : halves(rand() % 9 - 4);
        char src[400];
        const char *rot = rots[s % 7];
        if (s % 4 == 0)
            snprintf(src, sizeof src, "p = cuboid center %.17g,%.17g,%.17g size %.17g,%.17g,%.17g "
                     "rotate %s\nresult p\n", cx, cy, cz, halves(2 * a), halves(2 * b),
                     halves(2 * c), rot);
        else if (s % 4 == 1)
            snprintf(src, sizeof src, "p = ellipsoid center %.17g,%.17g,%.17g radii %.17g,%.17g,"
                     "%.17g rotate %s\nresult p\n", cx, cy, cz, halves(a), halves(b), halves(c),
                     rot);
        else
            snprintf(src, sizeof src, "p = %s center %.17g,%.17g,%.17g radii %.17g,%.17g height "
                     "%.17g axis %c rotate %s\nresult p\n", k, cx, cy, cz, halves(a), halves(b),
                     halves(2 * c), "xyz"[s % 3], rot);
        evals += check(src, 16) + check(src, 8);
        voxels += 2 * RES * RES * RES;
    }
    cr_assert_lt(evals, voxels / 3, "the bounds spared few samples: %llu of %llu",
                 (unsigned long long)evals, (unsigned long long)voxels);
}

Test(csg_bounds, a_tree_of_rotated_primitives)
{
    const char *src =
        "base = cuboid size 1.6,1.0,0.6 rotate 0,0,10\n"
        "boss = ellipsoid center 0,0,0.3 radii 0.35,0.3,0.25\n"
        "hole = cylinder center -0.45,0,0 radius 0.2 height 2 axis z\n"
        "peg = cone center 0,-0.3,0.3 radius 0.12 height 0.5 axis z rotate 5,0,0\n"
        "out = difference(union(union(base, boss), peg), hole)\n"
        "result out\n";
    check(src, 16);
    check(src, 8);
}

/* Planes whose L and H ends of the ramp (t = -127/128 and t = 1 voxel)
 * pass through voxel centres, and curved, partial and unsupported
 * expressions. */
Test(csg_bounds, implicit_leaves_decided_by_intervals, .timeout = 120)
{
    double vs = 2.0 / RES, c20 = -1 + 20.5 * vs, c30 = -1 + 30.5 * vs;
    char plane_h[200], plane_l[200], tilted[200];
    snprintf(plane_h, sizeof plane_h, "p = implicit \"x - %.17g\"\nresult p\n", c20 + vs);
    snprintf(plane_l, sizeof plane_l, "p = implicit \"x - %.17g\"\nresult p\n",
             c30 - vs * 127 / 128);
    snprintf(tilted, sizeof tilted, "p = implicit \"(x + y) * 3 - %.17g\"\nresult p\n",
             c20 * 6 + 3 * vs);
    const char *const srcs[] = {
        plane_h, plane_l, tilted,
        "p = implicit \"x^2 + y^2 + z^2 - 0.5\"\nresult p\n",
        "p = implicit \"sqrt(x^2 + y^2 + z^2) - 0.6\"\nresult p\n",
        "p = implicit \"r - 0.7\"\nresult p\n",
        "p = implicit \"min(sqrt(x*x + y*y + z*z) - 0.5, abs(z) - 0.2)\"\nresult p\n",
        "p = implicit \"max(abs(x), abs(y)) - 0.55\"\nresult p\n",
        "p = implicit \"z - 0.3 * sin(4 * x) * cos(3 * y)\"\nresult p\n",
        "p = implicit \"exp(x) - 1.5 + y^3\"\nresult p\n",
        "p = implicit \"x / (1.5 + y) - 0.2\"\nresult p\n",
        "p = implicit \"-(x^2 + y^2 + z^2) + 0.3\"\nresult p\n", /* inside out */
        "p = implicit \"x^2 + y^2 + z^2 - 0.3\" domain -0.5,0.4\nresult p\n",
        "p = implicit \"sqrt(0.5 - x^2 - y^2) - 0.2\"\nresult p\n", /* NaN outside */
        "p = implicit \"atan(x) - 0.3\"\nresult p\n", /* no interval gradient: sampled */
        "a = implicit \"x^2 + y^2 + z^2 - 0.4\"\nb = cuboid size 0.8,0.8,0.8 rotate 0,30,0\n"
        "c = difference(a, b)\nresult c\n",
    };
    uint64_t evals = 0, voxels = 0;
    for (size_t k = 0; k < sizeof srcs / sizeof *srcs; k++) {
        evals += check(srcs[k], 16) + check(srcs[k], 8);
        voxels += 2 * RES * RES * RES;
    }
    cr_assert_lt(evals, voxels / 2, "the intervals spared few samples: %llu of %llu",
                 (unsigned long long)evals, (unsigned long long)voxels);
}

/* Samples of an implicit leaf's brick b alone (res 64, bricks of 16),
 * whose value must be want (-1: not uniform). */
static uint64_t brick_samples(const char *src, uint32_t bx, uint32_t by, uint32_t bz, int want)
{
    csg_tree *t = parse(src);
    grid_spec g = grid(64);
    csg_eval *e;
    cr_assert_eq(csg_eval_new(t, &g, 16, NULL, &e), 0);
    uint8_t buf[4096], v;
    int uni;
    uint32_t b[3] = {bx, by, bz};
    cr_assert_eq(csg_eval_brick(e, b, buf, &uni, &v), 0);
    cr_assert_eq(uni ? v : -1, want, "%s: brick %u,%u,%u", src, bx, by, bz);
    uint64_t ev = csg_eval_stats(e)->voxel_evals;
    csg_eval_free(e);
    csg_tree_free(t);
    return ev;
}

/* A brick wholly inside or outside an implicit leaf's ramp costs no
 * sample; one across its surface is sampled in cubes, near the surface. */
Test(csg_bounds, an_implicit_brick_off_the_surface_costs_no_sample)
{
    const char *big = "p = implicit \"x^2 + y^2 + z^2 - 0.81\"\nresult p\n",
               *small = "p = implicit \"x^2 + y^2 + z^2 - 0.04\"\nresult p\n";
    cr_assert_eq(brick_samples(big, 1, 1, 1, CSG_H), 0); /* [-0.5, 0]^3, r <= 0.84 */
    cr_assert_eq(brick_samples(small, 0, 0, 0, CSG_L), 0);
    uint64_t ev = brick_samples(small, 1, 1, 1, -1);
    cr_assert(ev > 0 && ev < 4096, "%llu samples", (unsigned long long)ev);
}
