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

static int sgn128(mv_i128 v) { return (v > 0) - (v < 0); }
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
static int sample_range(const mv_block *b, int a, int64_t lo, int64_t hi,
                        int64_t *i0, int64_t *i1)
{
    int64_t s = mv_ceildiv(lo - MV_H, MV_L), e = mv_floordiv(hi - MV_H, MV_L);
    if (s < b->s0[a]) s = b->s0[a];
    if (e > b->s0[a] + b->n[a] - 1) e = b->s0[a] + b->n[a] - 1;
    *i0 = s, *i1 = e;
    return s <= e ? 0 : -1;
}

/* Sample (iu, iv) on axis ray crosses the triangle just below sample k. */
static inline void emit(const mv_target *t, int axis, int64_t iu, int64_t iv,
                        int64_t k)
{
    const mv_block *b = t->b;
    size_t n1 = (size_t)b->n[1], nw = b->nw;
    if (axis == 2) {
        int64_t z = k - b->s0[2];
        if (z < 0) {
            if (!t->first_z) return;
            z = 0;
        }
        if (z >= b->n[2]) return;
        size_t x = (size_t)(iu - b->s0[0]), y = (size_t)(iv - b->s0[1]);
        t->bits[((size_t)z * n1 + y) * nw + x / 64] ^= 1ull << (x & 63);
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
    mv_i128 nx = (mv_i128)e1[1] * e2[2] - (mv_i128)e1[2] * e2[1];
    mv_i128 ny = (mv_i128)e1[2] * e2[0] - (mv_i128)e1[0] * e2[2];
    mv_i128 nz = (mv_i128)e1[0] * e2[1] - (mv_i128)e1[1] * e2[0];
    int sx = sgn128(nx), sy = sgn128(ny), sz = sgn128(nz);
    /* along x: x moves by eps^2 against the plane's x at (y + eps^3,
     * z + eps): dx/dz = -nz/nx comes first, then eps^2 itself */
    if (axis == 0) return sz == 0 || sz == sx;
    /* along y: y + eps^3 against y at (z + eps, x + eps^2) */
    if (sz != 0) return sz == sy;
    return sx == 0 || sx == sy;
}

/* The crossing's first sample past it, for a covered sample: kf in
 * [kmin, kmax] with X(k) = (k L + L/2 - r0) W - B + tie > 0 from kf on.
 * kd: a guess, exact or one off; the loops walk to the exact answer. */
static inline int64_t first_past(int64_t kd, int64_t kmin, int64_t kmax,
                                 int64_t r0, mv_i128 W, mv_i128 LW, mv_i128 B,
                                 int tie)
{
    if (kd < kmin) kd = kmin;
    if (kd > kmax) kd = kmax;
    mv_i128 X = (mv_i128)(kd * MV_L + MV_H - r0) * W - B + tie;
    if (X > 0) {
        while (kd > kmin && X - LW > 0) kd--, X -= LW;
    } else {
        while (X <= 0) kd++, X += LW; /* X(kmax) > 0 */
    }
    return kd;
}

void mv_raster(const int64_t P[3][3], int axis, const mv_target *t)
{
    const mv_block *b = t->b;
    int ua = AX_U[axis], va = AX_V[axis];
    int64_t u[3], v[3], r[3];
    for (int i = 0; i < 3; i++) u[i] = P[i][ua], v[i] = P[i][va], r[i] = P[i][axis];
    int64_t iu0, iu1, iv0, iv1;
    if (sample_range(b, ua, min3(u), max3(u), &iu0, &iu1) ||
        sample_range(b, va, min3(v), max3(v), &iv0, &iv1))
        return;
    mv_i128 W = (mv_i128)(u[1] - u[0]) * (v[2] - v[0]) -
                (mv_i128)(v[1] - v[0]) * (u[2] - u[0]);
    if (W == 0) return; /* edge-on: the moved sample never meets it */
    int tie = tie_past(P, axis);
    if (W < 0) { /* counter-clockwise in (u, v) from here on */
        int64_t s;
        s = u[1], u[1] = u[2], u[2] = s;
        s = v[1], v[1] = v[2], v[2] = s;
        s = r[1], r[1] = r[2], r[2] = s;
        W = -W;
    }
    /* Edge j runs from vertex j to j + 1; E_j(p) = du (pv - vj) - dv (pu - uj)
     * is > 0 inside.  On the edge (E_j = 0) the move decides: x-rays move
     * (u, v) = (y, z) by (eps^3, eps), the others (u, v) by (eps^a, eps^b)
     * with a < b, so the term of dE/du = -dv or dE/dv = du comes first. */
    int64_t du[3], dv[3];
    mv_i128 thr[3], step[3];
    for (int j = 0; j < 3; j++) {
        du[j] = u[(j + 1) % 3] - u[j];
        dv[j] = v[(j + 1) % 3] - v[j];
        bool in = axis == 0 ? du[j] > 0 || (du[j] == 0 && dv[j] < 0)
                            : dv[j] < 0 || (dv[j] == 0 && du[j] > 0);
        thr[j] = in ? 0 : 1; /* inside: E_j >= thr_j */
        step[j] = -(mv_i128)dv[j] * MV_L;
    }
    /* Along the ray, r(p) W = r0 W + B(p), B = (r1 - r0) E_2 + (r2 - r0) E_0
     * (E_1, E_2, E_0 are the barycentric weights of vertices 0, 1, 2). */
    int64_t dr1 = r[1] - r[0], dr2 = r[2] - r[0];
    int64_t kmin = mv_ceildiv(min3(r) - MV_H, MV_L);
    int64_t kmax = mv_ceildiv(max3(r) - MV_H, MV_L) + 1;
    mv_i128 LW = W * MV_L;
    /* the guess: the plane r = r0 + gu (pu - u0) + gv (pv - v0) in double */
    double Wd = (double)(u[1] - u[0]) * (double)(v[2] - v[0]) -
                (double)(v[1] - v[0]) * (double)(u[2] - u[0]);
    double gu = -((double)(v[1] - v[0]) * (double)dr2 - (double)dr1 * (double)(v[2] - v[0])) / Wd;
    double gv = -((double)dr1 * (double)(u[2] - u[0]) - (double)(u[1] - u[0]) * (double)dr2) / Wd;
    double kdmin = (double)kmin, kdmax = (double)kmax;
    for (int64_t iv = iv0; iv <= iv1; iv++) {
        int64_t pv = iv * MV_L + MV_H, pu = iu0 * MV_L + MV_H;
        mv_i128 E[3];
        for (int j = 0; j < 3; j++)
            E[j] = (mv_i128)du[j] * (pv - v[j]) - (mv_i128)dv[j] * (pu - u[j]);
        for (int64_t iu = iu0; iu <= iu1; iu++) {
            if (E[0] >= thr[0] && E[1] >= thr[1] && E[2] >= thr[2]) {
                double rd = (double)r[0] + gu * (double)(iu * MV_L + MV_H - u[0]) +
                            gv * (double)(pv - v[0]);
                double kg = (rd - MV_H) / MV_L;
                kg = kg >= kdmin ? kg : kdmin; /* also NaN: an edge-on */
                kg = kg <= kdmax ? kg : kdmax; /* plane's guess is void */
                mv_i128 B = (mv_i128)dr1 * E[2] + (mv_i128)dr2 * E[0];
                int64_t k = first_past((int64_t)kg, kmin, kmax, r[0], W, LW, B, tie);
                emit(t, axis, iu, iv, k);
            }
            E[0] += step[0], E[1] += step[1], E[2] += step[2];
        }
    }
}

void mv_prefix_z(const mv_block *b, uint64_t *bits, uint64_t *carry, bool first)
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

void mv_prefix_x(const mv_block *b, uint64_t *bits, const uint64_t *carry)
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

void mv_prefix_y(const mv_block *b, uint64_t *bits, const uint64_t *carry)
{
    size_t nw = b->nw, slice = (size_t)b->n[1] * nw;
    for (int32_t z = 0; z < b->n[2]; z++) {
        uint64_t *s = bits + (size_t)z * slice;
        for (size_t i = 0; i < nw; i++) s[i] ^= carry[(size_t)z * nw + i];
        for (size_t i = nw; i < slice; i++) s[i] ^= s[i - nw];
    }
}
