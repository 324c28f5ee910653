/* mesh_raster — the parity kernel: where a triangle crosses the rays
 * through a block's samples, decided exactly, and the prefix XOR passes
 * that turn crossings into parities (Eisemann and Décoret's XOR into bit
 * columns, 64 columns per word operation).
 *
 * A ray along axis r runs through the sample's centre from -infinity; the
 * triangle's projection on the plane (u, v) across r covers the ray or not,
 * and if it does, the first sample past the crossing gets a flip.  The
 * parity of a sample is the XOR of the flips at or below it.
 *
 * Ties are decided once for all three directions, as if the sample were
 * moved by (eps^2, eps^3, eps) for an infinitesimal eps (simulation of
 * simplicity): a sample exactly on an edge of a projection is inside when
 * the edge function grows along that move (z first, then x, then y: the
 * top-left rule of rasterizers, derived rather than chosen), and a sample
 * exactly on a triangle counts as past it when the move carries it past.
 * The moved point lies on no triangle, edge or vertex of the snapped mesh,
 * so on a closed mesh every ray crosses it an even number of times and the
 * parities along x, y and z are the same: the inside of the moved point. */
#include "mesh_vox_int.h"

#include <string.h>

/* The plane of projection of ray axis r: u = AX_U[r], v = AX_V[r]. */
static const int AX_U[3] = {1, 2, 0}, AX_V[3] = {2, 0, 1};

static int sgn128(mesh_vox_i128 v) { return (v > 0) - (v < 0); }
static int64_t min3(const int64_t a[3])
{
    int64_t m = a[0] < a[1] ? a[0] : a[1];
    return m < a[2] ? m : a[2];
}
static int64_t max3(const int64_t a[3])
{
    int64_t m = a[0] > a[1] ? a[0] : a[1];
    return m > a[2] ? m : a[2];
}

/* Samples i of the block along axis a whose centres lie in [lo, hi]: 0 and
 * [*i0, *i1], or -1 when none. */
static inline int sample_range(const mesh_vox_block *b, int a, int64_t lo, int64_t hi,
                               int64_t *i0, int64_t *i1)
{
    int64_t s = mesh_vox_ceil_l(lo - MESH_VOX_H), e = mesh_vox_floor_l(hi - MESH_VOX_H);
    if (s < b->s0[a]) s = b->s0[a];
    if (e > b->s0[a] + b->n[a] - 1) e = b->s0[a] + b->n[a] - 1;
    *i0 = s, *i1 = e;
    return s <= e ? 0 : -1;
}

/* Sample (iu, iv) on axis ray crosses the triangle just below sample k;
 * sign: +1 where the triangle faces down (its normal's z < 0), else -1,
 * for the z counts. */
__attribute__((always_inline)) static inline void emit(const mesh_vox_target *t, int axis, int64_t iu, int64_t iv,
                        int64_t k, int sign)
{
    const mesh_vox_block *b = t->b;
    size_t n1 = (size_t)b->n[1], nw = b->nw;
    if (axis == 2) {
        int64_t z = k - b->s0[2];
        if (z < 0) {
            if (!t->first_z) return;
            z = 0;
        }
        if (z >= b->n[2]) return;
        size_t x = (size_t)(iu - b->s0[0]), y = (size_t)(iv - b->s0[1]);
        size_t i = ((size_t)z * n1 + y) * nw + x / 64;
        if (t->count) { /* modulo 2^16: see mesh_vox_target */
            t->count[i * 64 + (x & 63)] += (uint16_t)sign;
            if (!t->bits) return;
        }
        t->bits[i] ^= 1ull << (x & 63);
    } else if (axis == 0) {
        size_t y = (size_t)(iu - b->s0[1]), z = (size_t)(iv - b->s0[2]);
        int64_t x = k - b->s0[0];
        if (x >= b->n[0]) return;
        if (x < 0) {
            size_t bit = z * n1 + y;
            t->carry[bit / 64] ^= 1ull << (bit & 63);
            return;
        }
        t->bits[(z * n1 + y) * nw + (size_t)x / 64] ^= 1ull << (x & 63);
    } else {
        size_t z = (size_t)(iu - b->s0[2]), x = (size_t)(iv - b->s0[0]);
        int64_t y = k - b->s0[1];
        if (y >= b->n[1]) return;
        if (y < 0) {
            t->carry[z * nw + x / 64] ^= 1ull << (x & 63);
            return;
        }
        t->bits[(z * n1 + (size_t)y) * nw + x / 64] ^= 1ull << (x & 63);
    }
}

/* Whether a sample exactly on the triangle's plane counts as past it, for
 * ray axis: the sign of the move (eps^2, eps^3, eps) against the plane's
 * slope along the ray (n: the plane's normal, any orientation). */
static int tie_past(const int64_t P[3][3], int axis)
{
    if (axis == 2) return 1; /* the move's largest part, eps, is along z */
    int64_t e1[3], e2[3];
    for (int a = 0; a < 3; a++) e1[a] = P[1][a] - P[0][a], e2[a] = P[2][a] - P[0][a];
    mesh_vox_i128 nx = (mesh_vox_i128)e1[1] * e2[2] - (mesh_vox_i128)e1[2] * e2[1];
    mesh_vox_i128 ny = (mesh_vox_i128)e1[2] * e2[0] - (mesh_vox_i128)e1[0] * e2[2];
    mesh_vox_i128 nz = (mesh_vox_i128)e1[0] * e2[1] - (mesh_vox_i128)e1[1] * e2[0];
    int sx = sgn128(nx), sy = sgn128(ny), sz = sgn128(nz);
    /* along x: x moves by eps^2 against the plane's x at (y + eps^3,
     * z + eps): dx/dz = -nz/nx comes first, then eps^2 itself */
    if (axis == 0) return sz == 0 || sz == sx;
    /* along y: y + eps^3 against y at (z + eps, x + eps^2) */
    if (sz != 0) return sz == sy;
    return sx == 0 || sx == sy;
}

/* One triangle projected along a ray axis, counter-clockwise in (u, v). */
typedef struct {
    const mesh_vox_target *t;
    int axis, tie;
    int64_t u[3], v[3], r[3], du[3], dv[3];
    int64_t thr[3];         /* inside: E_j >= thr_j */
    mesh_vox_i128 W, LW;          /* twice the projected area, and L W */
    int64_t dr1, dr2;
    int64_t kmin, kmax;     /* the crossings' first samples past them lie here */
    int sign;               /* emit's: +1 when clockwise in (u, v) as given */
    double gu, gv;          /* the plane r = r0 + gu (pu - u0) + gv (pv - v0) */
    bool guess;             /* gu, gv, kmin, kmax made */
} proj;

/* Covered sample (iu, iv), E_0 and E_2 its edge functions: the first sample
 * past the crossing along the ray, kf = the least k with
 *     X(k) = (k L + L/2 - r0) W - B + tie > 0,
 * where r(p) W = r0 W + B(p), B = (r1 - r0) E_2 + (r2 - r0) E_0 (E_1, E_2,
 * E_0 are the barycentric weights of vertices 0, 1, 2).  A guess from the
 * plane in double, then the exact X walks to kf (0 or 1 steps but for
 * planes nearly along the ray).  kf lies in [kmin, kmax]: X(kmax) > 0 and
 * X(kmin - 1) <= 0 since r(p) lies between the vertices' r. */
static void hit(proj *T, int64_t iu, int64_t iv, mesh_vox_i128 E0, mesh_vox_i128 E2)
{
    if (!T->guess) {
        const int64_t *u = T->u, *v = T->v;
        double Wd = (double)(u[1] - u[0]) * (double)(v[2] - v[0]) -
                    (double)(v[1] - v[0]) * (double)(u[2] - u[0]);
        T->gu = -((double)(v[1] - v[0]) * (double)T->dr2 -
                  (double)T->dr1 * (double)(v[2] - v[0])) / Wd;
        T->gv = -((double)T->dr1 * (double)(u[2] - u[0]) -
                  (double)(u[1] - u[0]) * (double)T->dr2) / Wd;
        T->kmin = mesh_vox_ceil_l(min3(T->r) - MESH_VOX_H);
        T->kmax = mesh_vox_ceil_l(max3(T->r) - MESH_VOX_H) + 1;
        T->guess = true;
    }
    double rd = (double)T->r[0] + T->gu * (double)(iu * MESH_VOX_L + MESH_VOX_H - T->u[0]) +
                T->gv * (double)(iv * MESH_VOX_L + MESH_VOX_H - T->v[0]);
    double kg = (rd - MESH_VOX_H) / MESH_VOX_L, kdmin = (double)T->kmin, kdmax = (double)T->kmax;
    kg = kg >= kdmin ? kg : kdmin; /* also NaN: the guess of a plane */
    kg = kg <= kdmax ? kg : kdmax; /* nearly along the ray is void */
    int64_t k = (int64_t)kg;
    mesh_vox_i128 B = (mesh_vox_i128)T->dr1 * E2 + (mesh_vox_i128)T->dr2 * E0;
    mesh_vox_i128 X = (mesh_vox_i128)(k * MESH_VOX_L + MESH_VOX_H - T->r[0]) * T->W - B + T->tie;
    if (X > 0) {
        while (k > T->kmin && X - T->LW > 0) k--, X -= T->LW;
    } else {
        while (X <= 0) k++, X += T->LW;
    }
    emit(T->t, T->axis, iu, iv, k, T->sign);
}

/* The samples of [iu0, iu1] x [iv0, iv1] inside the projection, edge
 * functions in 64 bits: for projections less than 2^30 lattice units wide
 * (2^14 samples: every triangle of a sane mesh), where each product of a
 * difference by a difference stays below 2^60. */
static void scan64(proj *T, int64_t iu0, int64_t iu1, int64_t iv0, int64_t iv1)
{
    int64_t step[3];
    for (int j = 0; j < 3; j++) step[j] = -T->dv[j] * MESH_VOX_L;
    for (int64_t iv = iv0; iv <= iv1; iv++) {
        int64_t pv = iv * MESH_VOX_L + MESH_VOX_H, pu = iu0 * MESH_VOX_L + MESH_VOX_H, E[3];
        for (int j = 0; j < 3; j++)
            E[j] = T->du[j] * (pv - T->v[j]) - T->dv[j] * (pu - T->u[j]);
        for (int64_t iu = iu0; iu <= iu1; iu++) {
            if (((E[0] - T->thr[0]) | (E[1] - T->thr[1]) | (E[2] - T->thr[2])) >= 0)
                hit(T, iu, iv, E[0], E[2]);
            E[0] += step[0], E[1] += step[1], E[2] += step[2];
        }
    }
}

/* The same in 128 bits, for any triangle. */
static void scan128(proj *T, int64_t iu0, int64_t iu1, int64_t iv0, int64_t iv1)
{
    mesh_vox_i128 step[3];
    for (int j = 0; j < 3; j++) step[j] = -(mesh_vox_i128)T->dv[j] * MESH_VOX_L;
    for (int64_t iv = iv0; iv <= iv1; iv++) {
        int64_t pv = iv * MESH_VOX_L + MESH_VOX_H, pu = iu0 * MESH_VOX_L + MESH_VOX_H;
        mesh_vox_i128 E[3];
        for (int j = 0; j < 3; j++)
            E[j] = (mesh_vox_i128)T->du[j] * (pv - T->v[j]) - (mesh_vox_i128)T->dv[j] * (pu - T->u[j]);
        for (int64_t iu = iu0; iu <= iu1; iu++) {
            if (E[0] >= T->thr[0] && E[1] >= T->thr[1] && E[2] >= T->thr[2])
                hit(T, iu, iv, E[0], E[2]);
            E[0] += step[0], E[1] += step[1], E[2] += step[2];
        }
    }
}

/* A triangle less than 2^19 lattice units (8 samples) wide along every
 * axis, the usual case, in 64 bits throughout: edge functions below 2^40,
 * B below 2^60, and the crossing by one exact division.  With r0 = k0 L +
 * rho (0 <= rho < L) and k = k0 + j, X(k) > 0 reads
 *     j L W > Q = B - tie - (L/2 - rho) W,  so  j = floor(Q / (L W)) + 1. */
__attribute__((always_inline)) static inline void
raster_tiny(const int64_t P[3][3], int axis, const mesh_vox_target *t, const int64_t iu[2],
            const int64_t iv[2])
{
    int ua = AX_U[axis], va = AX_V[axis], o1 = 1, o2 = 2;
    int64_t W = (P[1][ua] - P[0][ua]) * (P[2][va] - P[0][va]) -
                (P[1][va] - P[0][va]) * (P[2][ua] - P[0][ua]);
    if (W == 0) return; /* edge-on: the moved sample never meets it */
    int sign = W < 0 ? 1 : -1;
    if (W < 0) o1 = 2, o2 = 1, W = -W; /* counter-clockwise in (u, v) */
    int64_t u[3] = {P[0][ua], P[o1][ua], P[o2][ua]}, v[3] = {P[0][va], P[o1][va], P[o2][va]};
    int64_t du[3], dv[3], thr[3];
    for (int j = 0; j < 3; j++) {
        du[j] = u[(j + 1) % 3] - u[j], dv[j] = v[(j + 1) % 3] - v[j];
        /* 1 where a sample on the edge is outside (no branches: the signs
         * of edges are random) */
        int64_t a = axis == 0 ? du[j] : -dv[j], c = axis == 0 ? -dv[j] : du[j];
        thr[j] = (a < 0) | ((a == 0) & (c <= 0));
    }
    int64_t r0 = P[0][axis], dr1 = P[o1][axis] - r0, dr2 = P[o2][axis] - r0;
    int64_t k0 = mesh_vox_floor_l(r0), rho = r0 - k0 * MESH_VOX_L, LW = W * MESH_VOX_L;
    int64_t base = tie_past(P, axis) + (MESH_VOX_H - rho) * W;
    double inv = 1.0 / (double)LW;
    for (int64_t sv = iv[0]; sv <= iv[1]; sv++) {
        int64_t pv = sv * MESH_VOX_L + MESH_VOX_H;
        for (int64_t su = iu[0]; su <= iu[1]; su++) {
            int64_t pu = su * MESH_VOX_L + MESH_VOX_H, E[3];
            for (int j = 0; j < 3; j++) E[j] = du[j] * (pv - v[j]) - dv[j] * (pu - u[j]);
            if (((E[0] - thr[0]) | (E[1] - thr[1]) | (E[2] - thr[2])) < 0) continue;
            /* floor(Q / LW): a guess in double (|Q| < 2^61), made exact */
            int64_t Q = dr1 * E[2] + dr2 * E[0] - base, j = (int64_t)((double)Q * inv);
            int64_t rem = Q - j * LW;
            j += (rem >= LW) - (rem < 0);
            emit(t, axis, su, sv, k0 + j + 1, sign);
        }
    }
}

/* The body of mesh_vox_raster, inlined with a constant axis: the indexing by
 * axis folds away. */
__attribute__((always_inline)) static inline void
raster_axis(const int64_t P[3][3], int axis, const mesh_vox_target *t)
{
    /* most small triangles cover no sample: out before anything else */
    int ua = AX_U[axis], va = AX_V[axis];
    int64_t u0 = P[0][ua], u1 = P[1][ua], u2 = P[2][ua], v0 = P[0][va], v1 = P[1][va],
            v2 = P[2][va];
    int64_t umin = u0 < u1 ? u0 : u1, umax = u0 < u1 ? u1 : u0;
    int64_t vmin = v0 < v1 ? v0 : v1, vmax = v0 < v1 ? v1 : v0;
    umin = u2 < umin ? u2 : umin, umax = u2 > umax ? u2 : umax;
    vmin = v2 < vmin ? v2 : vmin, vmax = v2 > vmax ? v2 : vmax;
    int64_t iu[2], iv[2]; /* the samples' ranges, inclusive */
    if (sample_range(t->b, ua, umin, umax, &iu[0], &iu[1]) ||
        sample_range(t->b, va, vmin, vmax, &iv[0], &iv[1]))
        return;
    const int64_t tiny = (int64_t)1 << 19;
    int64_t r0 = P[0][axis], r1 = P[1][axis], r2 = P[2][axis];
    int64_t rmin = r0 < r1 ? r0 : r1, rmax = r0 < r1 ? r1 : r0;
    rmin = r2 < rmin ? r2 : rmin, rmax = r2 > rmax ? r2 : rmax;
    if (umax - umin < tiny && vmax - vmin < tiny && rmax - rmin < tiny) {
        raster_tiny(P, axis, t, iu, iv);
        return;
    }
    proj T;
    T.t = t;
    T.axis = axis;
    for (int i = 0; i < 3; i++) T.u[i] = P[i][ua], T.v[i] = P[i][va], T.r[i] = P[i][axis];
    int64_t *u = T.u, *v = T.v, *r = T.r;
    T.W = (mesh_vox_i128)(u[1] - u[0]) * (v[2] - v[0]) - (mesh_vox_i128)(v[1] - v[0]) * (u[2] - u[0]);
    if (T.W == 0) return; /* edge-on: the moved sample never meets it */
    T.tie = tie_past(P, axis);
    T.sign = T.W < 0 ? 1 : -1;
    if (T.W < 0) { /* counter-clockwise in (u, v) from here on */
        int64_t s;
        s = u[1], u[1] = u[2], u[2] = s;
        s = v[1], v[1] = v[2], v[2] = s;
        s = r[1], r[1] = r[2], r[2] = s;
        T.W = -T.W;
    }
    /* Edge j runs from vertex j to j + 1; E_j(p) = du (pv - vj) - dv (pu - uj)
     * is > 0 inside.  On the edge (E_j = 0) the move decides: x-rays move
     * (u, v) = (y, z) by (eps^3, eps), the others (u, v) by (eps^a, eps^b)
     * with a < b, so the term of dE/du = -dv or dE/dv = du comes first. */
    for (int j = 0; j < 3; j++) {
        int64_t du = u[(j + 1) % 3] - u[j], dv = v[(j + 1) % 3] - v[j];
        bool in = axis == 0 ? du > 0 || (du == 0 && dv < 0) : dv < 0 || (dv == 0 && du > 0);
        T.du[j] = du, T.dv[j] = dv;
        T.thr[j] = in ? 0 : 1;
    }
    T.dr1 = r[1] - r[0], T.dr2 = r[2] - r[0];
    T.LW = T.W * MESH_VOX_L;
    T.guess = false;
    if (umax - umin <= (int64_t)1 << 30 && vmax - vmin <= (int64_t)1 << 30)
        scan64(&T, iu[0], iu[1], iv[0], iv[1]);
    else
        scan128(&T, iu[0], iu[1], iv[0], iv[1]);
}

void mesh_vox_raster(const int64_t P[3][3], int axis, const mesh_vox_target *t)
{
    switch (axis) {
    case 0: raster_axis(P, 0, t); break;
    case 1: raster_axis(P, 1, t); break;
    default: raster_axis(P, 2, t); break;
    }
}

void mesh_vox_prefix_z(const mesh_vox_block *b, uint64_t *bits, uint64_t *carry, bool first)
{
    size_t slice = (size_t)b->n[1] * b->nw;
    if (carry && !first)
        for (size_t i = 0; i < slice; i++) bits[i] ^= carry[i];
    for (int32_t z = 1; z < b->n[2]; z++) {
        uint64_t *c = bits + (size_t)z * slice, *p = c - slice;
        for (size_t i = 0; i < slice; i++) c[i] ^= p[i];
    }
    if (carry) memcpy(carry, bits + (size_t)(b->n[2] - 1) * slice, slice * 8);
}

/* Bit i := XOR of bits 0..i. */
static inline uint64_t prefix_xor(uint64_t w)
{
    w ^= w << 1;
    w ^= w << 2;
    w ^= w << 4;
    w ^= w << 8;
    w ^= w << 16;
    w ^= w << 32;
    return w;
}

void mesh_vox_prefix_x(const mesh_vox_block *b, uint64_t *bits, const uint64_t *carry)
{
    size_t rows = (size_t)b->n[2] * (size_t)b->n[1], nw = b->nw;
    unsigned tail = (unsigned)b->n[0] & 63;
    uint64_t last = tail ? (1ull << tail) - 1 : ~0ull;
    for (size_t r = 0; r < rows; r++) {
        uint64_t c = 0 - (carry[r / 64] >> (r & 63) & 1), *w = bits + r * nw;
        for (size_t i = 0; i < nw; i++) {
            w[i] = prefix_xor(w[i]) ^ c;
            c = 0 - (w[i] >> 63);
        }
        w[nw - 1] &= last; /* bits past n[0] stay 0 */
    }
}

void mesh_vox_prefix_y(const mesh_vox_block *b, uint64_t *bits, const uint64_t *carry)
{
    size_t nw = b->nw, slice = (size_t)b->n[1] * nw;
    for (int32_t z = 0; z < b->n[2]; z++) {
        uint64_t *s = bits + (size_t)z * slice;
        for (size_t i = 0; i < nw; i++) s[i] ^= carry[(size_t)z * nw + i];
        for (size_t i = nw; i < slice; i++) s[i] ^= s[i - nw];
    }
}
