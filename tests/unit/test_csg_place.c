/* CSG placement against an oracle that does not call the code: each
 * primitive's inside is written here from docs/csg.md's definitions (the
 * rotation as three turns about x, then y, then z, undone one at a time,
 * not as a matrix), evaluated at every voxel centre, and compared with the
 * densities csg_eval_brick gives (density >= S exactly inside).  Moved and
 * rotated cuboids, ellipsoids, cylinders and cones, every axis.
 *
 * A cone's tip is the one place where a centre inside is L: docs/csg.md's
 * rule takes L where the point one voxel nearer the axis is outside, and
 * where the cone is under two voxels across that point lies past the axis,
 * outside; the oracle applies the rule as the table writes it.
 *
 * Only a centre within EPS voxel of the surface may differ: the code maps
 * a centre into the local frame with a matrix, the oracle with three
 * rotations, and the two differ by the rounding of a few operations on
 * numbers below 100 (voxel units): about 1e-13 voxel.  EPS = 1e-6 voxel is
 * far above that and far below what a misplacement moves a centre by (a
 * rotation order, a centre or an axis wrong by even a degree or a
 * thousandth of the domain moves the surface by more than 0.01 voxel over
 * many centres).  The test also demands that few centres fall in that band,
 * so that it cannot pass by calling everything ambiguous. */
#include <criterion/criterion.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "csg.h"
#include "csg_fixture.h"

#define RES 48
#define EPS 1e-6 /* voxels */

typedef struct {
    const char *kind;      /* cuboid, ellipsoid, cylinder, cone */
    double c[3], size[3];  /* centre; cuboid: full sizes; others: radii (x, y, z) or r1, r2, height */
    double rot[3];         /* degrees about x, then y, then z */
    char axis;             /* cylinder, cone */
} shape;

/* Turn v by angle a (radians) about axis k (right-handed). */
static void turn(double v[3], int k, double a)
{
    int i = (k + 1) % 3, j = (k + 2) % 3;
    double c = cos(a), s = sin(a), vi = v[i], vj = v[j];
    v[i] = c * vi - s * vj;
    v[j] = s * vi + c * vj;
}

/* World point p into the shape's frame, in voxels: the shape was turned
 * about x, then y, then z, so undo z, then y, then x. */
static void to_local(const shape *s, const double p[3], double vs, double t[3])
{
    for (int a = 0; a < 3; a++) t[a] = p[a] - s->c[a];
    for (int k = 2; k >= 0; k--) turn(t, k, -s->rot[k] * M_PI / 180);
    for (int a = 0; a < 3; a++) t[a] /= vs;
}

/* Inside the ellipse(oid) of radii r (n axes, voxels) grown by grow: the
 * body sum t_i^2 / r_i^2 at most 1 at t, and at the point one voxel
 * nearer along the ray from the centre (t - t/|t|): docs/csg.md's L rule.
 * That point is inside whenever t is, but where the body is less than a
 * voxel across (a cone's tip), where it passes the centre and leaves the
 * body on the other side: such a centre is L though inside. */
static int in_ellipse(const double *t, const double *r, int n, double grow)
{
    double len = 0, b = 0, bin = 0;
    for (int i = 0; i < n; i++) len += t[i] * t[i];
    len = sqrt(len);
    for (int i = 0; i < n; i++) {
        double ri = r[i] + grow, ti = t[i], tin = len > 0 ? t[i] - t[i] / len : 0;
        if (!(ri > 0)) return 0;
        b += ti * ti / (ri * ri);
        bin += tin * tin / (ri * ri);
    }
    return b <= 1 && bin <= 1;
}

/* Inside the shape (local point t, voxels) with every half size, radius
 * and half height grown by grow voxels: 1 or 0. */
static int inside(const shape *s, const double t[3], double vs, double grow)
{
    if (!strcmp(s->kind, "cuboid")) {
        for (int a = 0; a < 3; a++)
            if (fabs(t[a]) > s->size[a] / (2 * vs) + grow) return 0;
        return 1;
    }
    if (!strcmp(s->kind, "ellipsoid")) {
        double r[3] = {s->size[0] / vs, s->size[1] / vs, s->size[2] / vs};
        return in_ellipse(t, r, 3, grow);
    }
    /* cylinder, cone: radii r1, r2 across the axis (the next two axes in
     * x, y, z order after it), the height along it, centred on c; a cone's
     * base at the low end, its apex at the high end */
    int ax = s->axis - 'x';
    double h = s->size[2] / vs, along = t[ax] + h / 2; /* from the base */
    double f = 1;
    if (!strcmp(s->kind, "cylinder")) {
        if (fabs(t[ax]) > h / 2 + grow) return 0;
    } else {
        if (along < -grow || along > h + grow) return 0;
        f = fmax(0, 1 - along / h); /* the radii shrink to 0 at the apex */
    }
    double across[2] = {t[(ax + 1) % 3], t[(ax + 2) % 3]};
    double r[2] = {s->size[0] / vs * f, s->size[1] / vs * f};
    return in_ellipse(across, r, 2, grow);
}

static void text_of(const shape *s, char *buf, size_t cap)
{
    int n = snprintf(buf, cap, "p = %s center %.17g,%.17g,%.17g rotate %.17g,%.17g,%.17g ",
                     s->kind, s->c[0], s->c[1], s->c[2], s->rot[0], s->rot[1], s->rot[2]);
    if (!strcmp(s->kind, "cuboid"))
        snprintf(buf + n, cap - n, "size %.17g,%.17g,%.17g\nresult p\n", s->size[0], s->size[1],
                 s->size[2]);
    else if (!strcmp(s->kind, "ellipsoid"))
        snprintf(buf + n, cap - n, "radii %.17g,%.17g,%.17g\nresult p\n", s->size[0], s->size[1],
                 s->size[2]);
    else
        snprintf(buf + n, cap - n, "radii %.17g,%.17g height %.17g axis %c\nresult p\n",
                 s->size[0], s->size[1], s->size[2], s->axis);
}

/* Every voxel of the RES^3 grid on [-1, 1]^3: density >= S where the
 * oracle says inside, < S outside, but for centres within EPS of the
 * surface. */
static void check_shape(const shape *s)
{
    char src[512];
    text_of(s, src, sizeof src);
    csg_tree *t = parse(src);
    grid_spec g = grid(RES);
    csg_eval *e;
    cr_assert_eq(csg_eval_new(t, &g, 8, NULL, &e), 0);
    uint8_t buf[512];
    uint64_t in = 0, wrong = 0, band = 0;
    for (uint32_t k = 0; k < (RES / 8) * (RES / 8) * (RES / 8); k++) {
        uint32_t b[3] = {k % (RES / 8), k / (RES / 8) % (RES / 8), k / (RES / 8 * (RES / 8))};
        int uni;
        uint8_t v;
        cr_assert_eq(csg_eval_brick(e, b, buf, &uni, &v), 0);
        for (uint32_t j = 0; j < 512; j++) {
            uint32_t X[3] = {b[0] * 8 + j % 8, b[1] * 8 + j / 8 % 8, b[2] * 8 + j / 64};
            double p[3], q[3];
            for (int a = 0; a < 3; a++) p[a] = -1 + (X[a] + 0.5) * (2.0 / RES);
            to_local(s, p, 2.0 / RES, q);
            int outer = inside(s, q, 2.0 / RES, EPS), inner = inside(s, q, 2.0 / RES, -EPS);
            int got = (uni ? v : buf[j]) >= CSG_S;
            in += inner;
            if (outer != inner) {
                band++;
                continue;
            }
            if (got != inner && wrong++ < 5)
                cr_log_error("%s: voxel %u %u %u: density %u, the oracle says %s", src, X[0],
                             X[1], X[2], uni ? v : buf[j], inner ? "inside" : "outside");
        }
    }
    cr_assert_eq(wrong, 0, "%s: %llu voxels placed wrong", src, (unsigned long long)wrong);
    cr_assert_gt(in, 500, "%s: only %llu voxels inside", src, (unsigned long long)in);
    cr_assert_lt(band, 4, "%s: %llu centres within %g voxel of the surface", src,
                 (unsigned long long)band, EPS);
    csg_eval_free(e);
    csg_tree_free(t);
}

Test(csg_place, cuboids_moved_and_rotated)
{
    static const shape s[] = {
        {"cuboid", {0.13, -0.21, 0.07}, {0.9, 0.5, 0.3}, {30, 0, 0}, 0},
        {"cuboid", {-0.11, 0.17, 0.05}, {0.9, 0.5, 0.3}, {0, 40, 0}, 0},
        {"cuboid", {0.05, 0.09, -0.19}, {0.9, 0.5, 0.3}, {0, 0, 50}, 0},
        {"cuboid", {0.12, -0.08, 0.16}, {1.1, 0.6, 0.35}, {25, 40, 65}, 0},
        {"cuboid", {-0.2, 0.1, -0.05}, {0.7, 0.8, 0.45}, {-70, 15, 110}, 0},
    };
    for (size_t i = 0; i < sizeof s / sizeof *s; i++) check_shape(&s[i]);
}

Test(csg_place, ellipsoids_moved_and_rotated)
{
    static const shape s[] = {
        {"ellipsoid", {0.1, -0.15, 0.2}, {0.7, 0.35, 0.2}, {35, 0, 0}, 0},
        {"ellipsoid", {-0.12, 0.05, 0.1}, {0.7, 0.35, 0.2}, {0, -50, 0}, 0},
        {"ellipsoid", {0.15, 0.12, -0.1}, {0.7, 0.35, 0.2}, {0, 0, 75}, 0},
        {"ellipsoid", {-0.07, 0.14, -0.16}, {0.65, 0.4, 0.22}, {20, -35, 50}, 0},
    };
    for (size_t i = 0; i < sizeof s / sizeof *s; i++) check_shape(&s[i]);
}

Test(csg_place, cylinders_on_every_axis)
{
    static const shape s[] = {
        {"cylinder", {0.1, -0.05, 0.12}, {0.3, 0.18, 1.2}, {0, 0, 0}, 'x'},
        {"cylinder", {-0.08, 0.11, 0.03}, {0.3, 0.18, 1.2}, {0, 0, 0}, 'y'},
        {"cylinder", {0.06, 0.02, -0.13}, {0.3, 0.18, 1.2}, {0, 0, 0}, 'z'},
        {"cylinder", {0.1, -0.1, 0.05}, {0.3, 0.18, 1.1}, {20, 35, -40}, 'x'},
        {"cylinder", {-0.05, 0.1, 0.1}, {0.25, 0.2, 1.1}, {60, -20, 10}, 'z'},
    };
    for (size_t i = 0; i < sizeof s / sizeof *s; i++) check_shape(&s[i]);
}

Test(csg_place, cones_on_every_axis)
{
    static const shape s[] = {
        {"cone", {0.1, -0.05, 0.12}, {0.45, 0.3, 1.3}, {0, 0, 0}, 'x'},
        {"cone", {-0.08, 0.11, 0.03}, {0.45, 0.3, 1.3}, {0, 0, 0}, 'y'},
        {"cone", {0.06, 0.02, -0.13}, {0.45, 0.3, 1.3}, {0, 0, 0}, 'z'},
        {"cone", {0.05, -0.1, 0.08}, {0.4, 0.3, 1.2}, {30, -25, 55}, 'y'},
        {"cone", {-0.1, 0.05, 0.02}, {0.4, 0.35, 1.2}, {-45, 60, 20}, 'z'},
    };
    for (size_t i = 0; i < sizeof s / sizeof *s; i++) check_shape(&s[i]);
}
