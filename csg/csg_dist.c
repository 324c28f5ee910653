/* csg_dist — the signed distance to an implicit surface F = 0 in a narrow
 * band, brick by brick (csg.h says what a brick holds; docs/expressions.md
 * the method and its bound).
 *
 * The band is found by the interval octree: a cube of voxel centres whose
 * box, grown by the band's width W on every side, has an interval of F
 * that excludes 0 holds no centre within W of the surface (the grown box
 * holds the ball of radius W around each of them), and every voxel in it
 * is W with the interval's sign.  Otherwise the cube is split in 8, down
 * to single voxels.  A voxel's value:
 *   - its sign is F's at the centre, decided by interval arithmetic on the
 *     point (so never wrong); a centre whose sign rounding leaves open is 0;
 *   - its magnitude is the length of a segment from the centre to a point
 *     where F's sign is the opposite one, decided by intervals too: the
 *     segment holds a zero of F, so the value is never below the distance
 *     (an upper bound), and at most W.  The segment goes to the foot point
 *     found by projection (Newton steps F / |grad F| onto the surface,
 *     then the centre projected onto the tangent plane there, repeated),
 *     plus CSG_DIST_EPS voxel; where that is not certified, a march along
 *     27 directions with bisection gives the shortest certified segment.
 * A brick is a pure function of (tape, grid, band, brick): any worker, any
 * order, the same bytes.
 */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "csg.h"

#define DIST_OUTER 12     /* foot-point iterations */
#define DIST_NEWTON 6     /* Newton steps onto F = 0 in each */
#define DIST_MARCH 8      /* march steps per voxel in the fallback */
#define DIST_BISECT 40    /* bisections of a certified bracket */

struct csg_dist {
    expr_vm *vm;
    grid_spec g;
    double w;             /* the band's width, world units */
    float wf;             /* the same as stored */
    csg_dist_stats st;
};

int csg_dist_new(const expr_tape *t, const grid_spec *g, uint32_t band, csg_dist **out)
{
    *out = NULL;
    if (band < 1 || band > CSG_DIST_MAX_BAND) return -EINVAL;
    csg_dist *d = calloc(1, sizeof *d);
    if (!d) return -ENOMEM;
    int rc = expr_vm_new(t, 0, &d->vm);
    if (rc) {
        free(d);
        return rc;
    }
    d->g = *g;
    d->wf = (float)(band * g->vs);
    d->w = d->wf;
    *out = d;
    return 0;
}

void csg_dist_free(csg_dist *d)
{
    if (!d) return;
    expr_vm_free(d->vm);
    free(d);
}

const csg_dist_stats *csg_dist_get_stats(const csg_dist *d) { return &d->st; }

/* F's sign at p, decided by intervals: +1, -1, or 0 when the interval
 * holds 0; a point where F is undefined (NaN) is outside its domain,
 * never on F = 0: +1. */
static int sign_at(csg_dist *d, const double p[3])
{
    ival f = expr_vm_ival(d->vm, 0, ival_point(p[0]), ival_point(p[1]), ival_point(p[2]));
    if (ival_is_nan(f)) return 1;
    return f.lo > 0 ? 1 : f.hi < 0 ? -1 : 0;
}

static double norm3(const double v[3]) { return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }

/* Newton steps from q onto F = 0 (q moved); 0, or -1 where the gradient
 * vanishes or F is undefined. */
static int newton(csg_dist *d, double q[3], double tol)
{
    for (int i = 0; i < DIST_NEWTON; i++) {
        double gr[3], f = expr_vm_grad(d->vm, 0, q[0], q[1], q[2], gr);
        double g2 = gr[0] * gr[0] + gr[1] * gr[1] + gr[2] * gr[2];
        if (!isfinite(f) || !(g2 > 0) || !isfinite(g2)) return -1;
        double k = f / g2;
        for (int a = 0; a < 3; a++) q[a] -= k * gr[a];
        if (fabs(k) * sqrt(g2) < tol) return 0;
    }
    return 0;
}

/* The foot point of c on F = 0 into p: Newton onto the surface, then c
 * projected onto the tangent plane there and Newton again, until the point
 * stays.  0, or -1 when it does not settle or wanders off the band. */
static int foot_point(csg_dist *d, const double c[3], double p[3])
{
    double tol = CSG_DIST_EPS * 0.01 * d->g.vs, q[3] = {c[0], c[1], c[2]};
    for (int it = 0; it < DIST_OUTER; it++) {
        if (newton(d, q, tol)) return -1;
        double gr[3], dq[3];
        expr_vm_grad(d->vm, 0, q[0], q[1], q[2], gr);
        double gn = norm3(gr);
        if (!(gn > 0) || !isfinite(gn)) return -1;
        double moved = it ? sqrt((q[0] - p[0]) * (q[0] - p[0]) + (q[1] - p[1]) * (q[1] - p[1]) +
                                 (q[2] - p[2]) * (q[2] - p[2]))
                          : INFINITY;
        memcpy(p, q, sizeof q);
        if (norm3((double[3]){p[0] - c[0], p[1] - c[1], p[2] - c[2]}) > 2 * d->w) return -1;
        if (moved < tol) return 0;
        double dot = 0;
        for (int a = 0; a < 3; a++) dq[a] = c[a] - q[a], dot += dq[a] * gr[a] / gn;
        for (int a = 0; a < 3; a++) q[a] = c[a] - dot * gr[a] / gn;
    }
    return 0; /* the last point, unsettled: the certification decides */
}

/* The point c + t u. */
static void along(const double c[3], const double u[3], double t, double p[3])
{
    for (int a = 0; a < 3; a++) p[a] = c[a] + t * u[a];
}

/* Given sign s at t0 and -s at t1 along u, the bracket shrunk by
 * bisection (certified signs only); returns its upper end. */
static double bisect(csg_dist *d, const double c[3], const double u[3], int s, double t0,
                     double t1)
{
    double p[3];
    for (int i = 0; i < DIST_BISECT && t1 - t0 > CSG_DIST_EPS * 0.1 * d->g.vs; i++) {
        double tm = 0.5 * (t0 + t1);
        along(c, u, tm, p);
        int sm = sign_at(d, p);
        if (sm == -s) t1 = tm;
        else if (sm == s) t0 = tm;
        else return tm; /* a point whose sign rounding leaves open: on F = 0 */
    }
    return t1;
}

/* The shortest certified segment from c (sign s) along 27 directions
 * (minus the gradient's, and the 26 of the voxel's neighbours), marched in
 * steps of W / DIST_MARCH up to W; INFINITY when none reaches a sign change. */
static double march(csg_dist *d, const double c[3], int s)
{
    double best = INFINITY, gr[3], p[3];
    expr_vm_grad(d->vm, 0, c[0], c[1], c[2], gr);
    for (int k = -1; k < 27; k++) {
        double u[3];
        if (k < 0) {
            double gn = norm3(gr);
            if (!(gn > 0) || !isfinite(gn)) continue;
            for (int a = 0; a < 3; a++) u[a] = -s * gr[a] / gn;
        } else {
            if (k == 13) continue; /* (0, 0, 0) */
            u[0] = k % 3 - 1, u[1] = k / 3 % 3 - 1, u[2] = k / 9 - 1;
            double n = norm3(u);
            for (int a = 0; a < 3; a++) u[a] /= n;
        }
        double h = d->w / DIST_MARCH;
        for (int i = 1; i <= DIST_MARCH && i * h < best; i++) {
            along(c, u, i * h, p);
            int si = sign_at(d, p);
            if (si == s) continue;
            double t = si == 0 ? i * h : bisect(d, c, u, s, (i - 1) * h, i * h);
            if (t < best) best = t;
            break;
        }
    }
    return best;
}

/* |value| of the centre c of sign s (not 0): a certified upper bound of
 * its distance, capped at W. */
static double magnitude(csg_dist *d, const double c[3], int s)
{
    double p[3], u[3], q[3];
    if (foot_point(d, c, p) == 0) {
        for (int a = 0; a < 3; a++) u[a] = p[a] - c[a];
        double t = norm3(u);
        if (t > 0 && isfinite(t)) {
            for (int a = 0; a < 3; a++) u[a] /= t;
            double t1 = t + CSG_DIST_EPS * d->g.vs;
            along(c, u, t1, q);
            int s1 = sign_at(d, q);
            if (s1 == 0) return t1;
            if (s1 == -s) {
                d->st.projected++;
                return t1;
            }
        }
    }
    d->st.marched++;
    return march(d, c, s);
}

/* The stored value: s * m rounded up in magnitude, at most W. */
static float stored(const csg_dist *d, int s, double m)
{
    if (!(m < d->w)) return s < 0 ? -d->wf : d->wf;
    float f = (float)m;
    if ((double)f < m) f = nextafterf(f, INFINITY);
    return s < 0 ? -f : f;
}

float csg_dist_voxel(csg_dist *d, const double c[3])
{
    int s = sign_at(d, c);
    d->st.band_voxels++;
    if (s == 0) return 0.0f;
    return stored(d, s, magnitude(d, c, s));
}

typedef struct {
    csg_dist *d;
    uint32_t lo[3], n; /* the brick: voxels lo .. lo + n - 1 per axis */
    float *out;
} brick_job;

/* Voxels [v, v + size) per axis of the brick (inside the grid: the caller
 * clips) := value. */
static void fill_cube(brick_job *b, const uint32_t v[3], uint32_t size, float value)
{
    const uint32_t *res = b->d->g.res;
    for (uint32_t z = v[2]; z < v[2] + size && z < res[2]; z++)
        for (uint32_t y = v[1]; y < v[1] + size && y < res[1]; y++)
            for (uint32_t x = v[0]; x < v[0] + size && x < res[0]; x++)
                b->out[((size_t)(z - b->lo[2]) * b->n + (y - b->lo[1])) * b->n + (x - b->lo[0])] =
                    value;
}

/* The cube of size^3 voxels from v: decided whole by the interval of F on
 * its centres' box grown by W, or split. */
static void cube(brick_job *b, const uint32_t v[3], uint32_t size)
{
    csg_dist *d = b->d;
    const grid_spec *g = &d->g;
    for (int a = 0; a < 3; a++)
        if (v[a] >= g->res[a]) return; /* past the grid: stays 0 */
    ival box[3];
    for (int a = 0; a < 3; a++)
        box[a] = ival_make(grid_coord(g, a, v[a] + 0.5) - d->w,
                           grid_coord(g, a, v[a] + size - 0.5) + d->w);
    ival f = expr_vm_ival(d->vm, 0, box[0], box[1], box[2]);
    if (!ival_contains_zero(f)) {
        fill_cube(b, v, size, f.lo > 0 ? d->wf : -d->wf);
        return;
    }
    if (size == 1) {
        double c[3];
        for (int a = 0; a < 3; a++) c[a] = grid_coord(g, a, v[a] + 0.5);
        b->out[((size_t)(v[2] - b->lo[2]) * b->n + (v[1] - b->lo[1])) * b->n + (v[0] - b->lo[0])] =
            csg_dist_voxel(d, c);
        return;
    }
    uint32_t h = size / 2;
    for (unsigned i = 0; i < 8; i++) {
        uint32_t w[3] = {v[0] + (i & 1u) * h, v[1] + (i >> 1 & 1u) * h, v[2] + (i >> 2 & 1u) * h};
        cube(b, w, h);
    }
}

int csg_dist_brick(csg_dist *d, const uint32_t lo[3], uint32_t n, float *out)
{
    if (n < 1 || (n & (n - 1))) return -EINVAL;
    memset(out, 0, (size_t)n * n * n * sizeof *out); /* past the grid: 0 */
    brick_job b = {.d = d, .lo = {lo[0], lo[1], lo[2]}, .n = n, .out = out};
    cube(&b, lo, n);
    return 0;
}
