/* csg_ops — the ICVG algebra on one pair of densities and the primitives'
 * virtual volume sampling functions at one point (docs/csg.md). */
#include <math.h>

#include "csg.h"

static const char *const names[CSG_KIND_COUNT] = {
    [CSG_CUBOID] = "cuboid", [CSG_ELLIPSOID] = "ellipsoid", [CSG_CYLINDER] = "cylinder",
    [CSG_CONE] = "cone", [CSG_IMPLICIT] = "implicit", [CSG_MESH] = "mesh", [CSG_VOD] = "vod", [CSG_UNION] = "union",
    [CSG_INTERSECTION] = "intersection", [CSG_TRIM] = "trim", [CSG_CAP] = "cap",
    [CSG_DIFFERENCE_A] = "differenceA", [CSG_DIFFERENCE_B] = "differenceB",
    [CSG_DIFFERENCE] = "difference", [CSG_ADD] = "add", [CSG_MODULATE] = "modulate",
    [CSG_DIVIDE_A] = "divideA", [CSG_DIVIDE] = "divide", [CSG_INVERSE] = "inverse",
    [CSG_SCALAR_ADD] = "scale_add", [CSG_SCALAR_MUL] = "scale_mul", [CSG_ERODE] = "erode",
    [CSG_DILATE] = "dilate",
};

const char *csg_kind_name(csg_kind k)
{
    return (unsigned)k < CSG_KIND_COUNT ? names[k] : "?";
}

/* A real result clamped to [L, H] and truncated towards L (floor). */
static uint8_t clamp_floor(double v)
{
    if (!(v > CSG_L)) return CSG_L; /* NaN too */
    if (v >= CSG_H) return CSG_H;
    return (uint8_t)floor(v);
}

static uint8_t sub_floor(int a, int b, int floor_value)
{
    int d = a - b;
    return (uint8_t)(d > floor_value ? d : floor_value);
}

uint8_t csg_apply(csg_kind op, uint8_t a, uint8_t b, double param)
{
    switch (op) {
    case CSG_UNION: return a > b ? a : b;
    case CSG_INTERSECTION: return a < b ? a : b;
    case CSG_TRIM: return a >= b ? a : CSG_L;
    case CSG_CAP: return a <= b ? a : CSG_L;
    case CSG_DIFFERENCE_A: return sub_floor(a, b, CSG_L);
    case CSG_DIFFERENCE_B: return b >= CSG_S ? sub_floor(a, b, CSG_L) : a;
    case CSG_DIFFERENCE:
        return a >= CSG_S && b < CSG_S ? sub_floor(a, b, CSG_S) : sub_floor(a, b, CSG_L);
    case CSG_ADD: return a + b < (int)CSG_H ? (uint8_t)(a + b) : CSG_H;
    case CSG_MODULATE: return a * b < (int)CSG_H ? (uint8_t)(a * b) : CSG_H;
    case CSG_DIVIDE_A: return b > 0 ? (uint8_t)(a / b) : CSG_H;
    case CSG_DIVIDE: return b > 0 ? clamp_floor(a / (b * param)) : CSG_H;
    case CSG_INVERSE: return (uint8_t)(CSG_H - a);
    case CSG_SCALAR_ADD: return clamp_floor(a + param);
    case CSG_SCALAR_MUL: return clamp_floor(a * param);
    default: return a;
    }
}

void csg_node_rotation(csg_node *n)
{
    double cx = cos(n->rot[0]), sx = sin(n->rot[0]), cy = cos(n->rot[1]),
           sy = sin(n->rot[1]), cz = cos(n->rot[2]), sz = sin(n->rot[2]);
    /* R = Rz Ry Rx (x first); world -> local is its transpose. */
    double r[3][3] = {
        {cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx},
        {sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx},
        {-sy, cy * sx, cy * cx},
    };
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) n->m[i][j] = r[j][i];
}

/* Sum of P_i^2 / R_i^2 over n axes: the ellipsoid / ellipse body. */
static double body(const double *p, const double *r, int n)
{
    double s = 0;
    for (int i = 0; i < n; i++) s += p[i] * p[i] / (r[i] * r[i]);
    return s;
}

/* The ramp of an ellipsoid-like body at t, with u the unit vector of t:
 * H one voxel further out still inside, L one voxel nearer still outside,
 * else floor(S / body(t)).  Returns -1 when neither (the caller's layer). */
static int ramp(const double *t, const double *r, int n, int *h_inside)
{
    double len = 0, out[3], in[3];
    for (int i = 0; i < n; i++) len += t[i] * t[i];
    len = sqrt(len);
    for (int i = 0; i < n; i++) {
        double u = len > 0 ? t[i] / len : 0;
        out[i] = t[i] + u;
        in[i] = t[i] - u;
    }
    *h_inside = body(out, r, n) <= 1;
    if (body(in, r, n) > 1) return CSG_L;
    return -1;
}

static uint8_t ramp_value(const double *t, const double *r, int n)
{
    return clamp_floor(CSG_S / body(t, r, n));
}

uint8_t csg_prim_sample(const csg_node *nd, const double p[3], double vs)
{
    double d[3], q[3], e[3];
    for (int i = 0; i < 3; i++) d[i] = p[i] - nd->center[i];
    for (int i = 0; i < 3; i++) {
        q[i] = (nd->m[i][0] * d[0] + nd->m[i][1] * d[1] + nd->m[i][2] * d[2]) / vs;
        e[i] = nd->size[i] / (2 * vs);
    }
    int hin;
    if (nd->kind == CSG_CUBOID) {
        double t = INFINITY;
        for (int i = 0; i < 3; i++) { /* fmin, without the call: nothing here is NaN */
            double ti = e[i] - fabs(q[i]);
            t = ti < t ? ti : t;
        }
        return t < 0 ? CSG_L : t < 1 ? CSG_S : CSG_H;
    }
    if (nd->kind == CSG_ELLIPSOID) {
        if (ramp(q, e, 3, &hin) == (int)CSG_L) return CSG_L;
        return hin ? CSG_H : ramp_value(q, e, 3);
    }
    int ax = nd->axis, c1 = (ax + 1) % 3, c2 = (ax + 2) % 3;
    double t2[2] = {q[c1], q[c2]}, r2[2] = {e[c1], e[c2]};
    double s; /* voxels from the end cap (cylinder: the nearer; cone: the base) */
    if (nd->kind == CSG_CONE) {
        s = q[ax] + e[ax];
        double h = 1 - s / (2 * e[ax]);
        if (s < 0 || !(h > 0)) return CSG_L;
        r2[0] *= h;
        r2[1] *= h;
    } else {
        s = e[ax] - fabs(q[ax]);
        if (s < 0) return CSG_L;
    }
    if (ramp(t2, r2, 2, &hin) == (int)CSG_L) return CSG_L;
    if (hin) return s < 1 ? CSG_S : CSG_H;
    return ramp_value(t2, r2, 2);
}
